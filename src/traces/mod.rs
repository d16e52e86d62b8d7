//! The per-frame traces that `--trace DIR` writes (docs/ARCHITECTURE.md, Traces; the records in
//! Contracts, Trace records): `record` is every record's type and the run clock, used by the
//! writers (the tracer, the cluster roles) and the readers; `read` loads and checks a
//! directory, `summary` tabulates it per frame and rank, `perfetto` turns it into a timeline,
//! `plot` into a picture (PNG or SVG) in `chart`'s look (Charts).

pub mod perfetto;
pub mod plot;
pub mod read;
pub mod record;
pub mod summary;
