//! dcrt: a GPU-compute ray tracer for massive triangle models, after the distributed-cache
//! cluster ray tracer of Ize, Brownlee & Hansen (EGPGV 2011).
//!
//! Data flows `scene` (TOML, meshes, generators) → `bvh` (obvhs build, collapsed to our 4-wide quantized
//! 64-byte nodes in blocked layout) → `blocks` (8 KiB node and triangle blocks) → `gpu` (WGSL compute: ray
//! generation, budgeted traversal rounds, shading) → `output` (PNG, EXR). `reference` is an
//! independent f64 reference tracer used as the oracle in tests.

pub mod blocks;
pub mod bvh;
pub mod chart;
pub mod cluster;
pub mod colormap;
pub mod dc;
pub mod error;
pub mod files;
pub mod gpu;
pub mod legend;
pub mod mirror;
pub mod output;
pub mod prepare;
pub mod progress;
pub mod reference;
pub mod render;
pub mod scene;
pub mod shading;
pub mod simulate;
pub mod size;
pub mod traces;
pub mod view;

pub use error::{Error, Result};
