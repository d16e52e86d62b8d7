//! Extraction in chunks of layers: worker threads take chunks in order, and each finished chunk
//! is handed on as soon as its predecessors are: appended to the mesh, its seam vertices
//! resolved, or passed on as a piece of its own (`stream`).

use super::chunk::{ChunkOut, TAG};
use super::march::{Plane, eval_plane, march_layer, scan_cross, scan_plane};
use super::tables::tables;
use super::{ColumnField, Grid};
use crate::error::{Error, Result};
use crate::scene::mesh::Mesh;
use std::sync::{Condvar, Mutex};

/// Bytes per triangle of a finished chunk: 12 of indices, about 6 of positions, and its piece.
const CHUNK_BYTES_PER_TRIANGLE: f64 = 20.0;
/// Finished chunks held at most, in bytes (besides each worker's own).
const IN_FLIGHT_BYTES: usize = 256 << 20;

/// A worker's buffers: two planes, the layer's crossing-edge indices (+x, +x+y, +x+z, +x+y+z)
/// and bit masks of the valid nodes / cells in a row.
pub(super) struct Work {
    a: Plane,
    b: Plane,
    cross: Vec<u32>,
    lt_nz: Vec<u64>,
    or: Vec<u64>,
    and: Vec<u64>,
}

impl Work {
    pub(super) fn new(grid: &Grid) -> Self {
        let words = grid.words();
        let mask = |limit: usize| -> Vec<u64> {
            (0..words)
                .map(|w| {
                    (0..64)
                        .filter(|b| w * 64 + b < limit)
                        .fold(0u64, |m, b| m | 1 << b)
                })
                .collect()
        };
        Work {
            a: Plane::new(grid),
            b: Plane::new(grid),
            cross: vec![0; 4 * grid.nodes_per_plane()],
            lt_nz: mask(grid.nz),
            or: vec![0; words],
            and: vec![0; words],
        }
    }
}

/// Layers i0..i1 (cells between x-planes i0 and i1). With `emit`, the mesh of those layers,
/// with the vertices of plane i0 first and tagged references to plane i1 unless it is the last
/// plane; without, only the triangle count.
pub(super) fn run_chunk(
    field: &impl ColumnField,
    grid: &Grid,
    i0: usize,
    i1: usize,
    emit: bool,
    work: &mut Work,
) -> ChunkOut {
    let tables = tables();
    let mut out = ChunkOut::default();
    let Work {
        a,
        b,
        cross,
        lt_nz,
        or,
        and,
    } = work;
    eval_plane(field, grid, i0, a);
    if emit {
        scan_plane(grid, i0, a, lt_nz, true, &mut out);
        out.first_plane = out.positions.len() as u32;
    }
    for i in i0..i1 {
        eval_plane(field, grid, i + 1, b);
        if emit {
            let owned = i + 1 < i1 || i1 == grid.n;
            scan_plane(grid, i + 1, b, lt_nz, owned, &mut out);
            scan_cross(grid, i, a, b, cross, lt_nz, &mut out);
        }
        march_layer(grid, tables, a, b, cross, lt_nz, or, and, emit, &mut out);
        std::mem::swap(a, b);
    }
    assert!(
        out.positions.len() < TAG as usize,
        "too many vertices in one chunk"
    );
    out
}

/// Appends finished chunks in order, resolving their vertex indices.
struct Sink {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    /// Vertices the previous chunk referenced on this one's first plane.
    seam: u32,
}

impl Sink {
    fn accept(&mut self, chunk: usize, out: ChunkOut) {
        assert!(
            chunk == 0 || self.seam == out.first_plane,
            "chunk {chunk} disagrees with its predecessor on their shared plane"
        );
        let own = self.positions.len() as u64;
        let next = own + out.positions.len() as u64;
        assert!(
            next + out.far.len() as u64 <= u64::from(u32::MAX),
            "too many vertices for 32-bit indices"
        );
        let (own, next) = (own as u32, next as u32);
        self.positions.extend_from_slice(&out.positions);
        self.triangles.extend(out.triangles.iter().map(|t| {
            t.map(|v| {
                if v & TAG != 0 {
                    next + (v & !TAG)
                } else {
                    own + v
                }
            })
        }));
        self.seam = out.far.len() as u32;
    }
}

/// The chunks of layers `grid` is cut into.
fn ranges(grid: &Grid, chunks: usize) -> Vec<(usize, usize)> {
    let chunks = chunks.clamp(1, grid.n);
    (0..chunks)
        .map(|c| (c * grid.n / chunks, (c + 1) * grid.n / chunks))
        .collect()
}

/// Which chunks are claimed, finished and taken, shared by the workers and the taker.
struct Claims {
    claimed: usize,
    taken: usize,
    done: Vec<Option<ChunkOut>>,
    /// The taker is done or failed, or a worker died: no more chunks are started.
    stop: bool,
    died: bool,
}

/// Marks the progress as stopped if the worker holding it unwinds, so the taker does not wait
/// for its chunk forever.
struct Died<'a>(&'a (Mutex<Claims>, Condvar));

impl Drop for Died<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            let (m, cv) = self.0;
            let mut p = m.lock().unwrap_or_else(|e| e.into_inner());
            p.stop = true;
            p.died = true;
            cv.notify_all();
        }
    }
}

/// Extracts the chunks of `grid` on worker threads and hands each to `take` on the calling
/// thread, in chunk order. Workers run at most a few chunks ahead of `take`, so however large the
/// grid, only that many chunks exist at a time. An error of `take` stops the workers and is
/// returned.
fn for_each_chunk(
    field: &impl ColumnField,
    grid: &Grid,
    chunks: usize,
    expected: f64,
    take: &mut dyn FnMut(usize, ChunkOut) -> Result<()>,
) -> Result<()> {
    let ranges = ranges(grid, chunks);
    // Chunks that may be started beyond the one `take` waits for: two per worker, but no more
    // than `IN_FLIGHT_BYTES` of finished chunks, so that many cores do not hold many chunks of a
    // huge model.
    let chunk_bytes = (expected.max(0.0) / ranges.len() as f64 * CHUNK_BYTES_PER_TRIANGLE) as usize;
    let window = (2 * rayon::current_num_threads())
        .min((IN_FLIGHT_BYTES / chunk_bytes.max(1)).max(2))
        .max(1);
    let workers = rayon::current_num_threads()
        .min(window)
        .clamp(1, ranges.len());
    let shared = (
        Mutex::new(Claims {
            claimed: 0,
            taken: 0,
            done: (0..ranges.len()).map(|_| None).collect(),
            stop: false,
            died: false,
        }),
        Condvar::new(),
    );
    let lock = || shared.0.lock().unwrap_or_else(|e| e.into_inner());
    let wait = |p| shared.1.wait(p).unwrap_or_else(|e| e.into_inner());
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                let _died = Died(&shared);
                let mut work = Work::new(grid);
                loop {
                    let c = {
                        let mut p = lock();
                        while !p.stop && p.claimed < ranges.len() && p.claimed >= p.taken + window {
                            p = wait(p);
                        }
                        if p.stop || p.claimed >= ranges.len() {
                            break;
                        }
                        p.claimed += 1;
                        p.claimed - 1
                    };
                    let (i0, i1) = ranges[c];
                    let out = run_chunk(field, grid, i0, i1, true, &mut work);
                    lock().done[c] = Some(out);
                    shared.1.notify_all();
                }
            });
        }
        let mut result = Ok(());
        for c in 0..ranges.len() {
            let out = {
                let mut p = lock();
                while p.done[c].is_none() && !p.died {
                    p = wait(p);
                }
                let Some(out) = p.done[c].take() else {
                    result = Err(Error::Internal("a generator worker died".into()));
                    break;
                };
                p.taken = c + 1;
                out
            };
            shared.1.notify_all();
            result = take(c, out);
            if result.is_err() {
                break;
            }
        }
        lock().stop = true;
        shared.1.notify_all();
        result
    })
}

/// The whole isosurface of `field` on `grid`, in `chunks` chunks of layers; each finished chunk
/// is appended to the mesh as soon as its predecessors are, so at most a few chunks exist
/// besides the mesh. `expected` sizes the mesh's buffers.
pub(super) fn extract(field: &impl ColumnField, grid: &Grid, chunks: usize, expected: f64) -> Mesh {
    let expected = expected.max(0.0) as usize;
    let mut sink = Sink {
        positions: Vec::with_capacity(expected / 2 + expected / 16),
        triangles: Vec::with_capacity(expected + expected / 8),
        seam: 0,
    };
    let mut taken = 0;
    let done = for_each_chunk(field, grid, chunks, expected as f64, &mut |c, out| {
        sink.accept(c, out);
        taken += 1;
        Ok(())
    });
    assert!(done.is_ok(), "{done:?}");
    assert_eq!(taken, ranges(grid, chunks).len(), "chunks missing");
    let (mut positions, mut triangles) = (sink.positions, sink.triangles);
    positions.shrink_to_fit();
    triangles.shrink_to_fit();
    Mesh {
        positions,
        triangles,
    }
}

/// The same surface as `extract`, chunk by chunk: each a mesh of its own (its triangles, in
/// order, with copies of the seam vertices it shares with the next), so that no whole mesh is
/// ever held. The triangles' corners are those of `extract`'s mesh, in the same order.
pub(super) fn stream(
    field: &impl ColumnField,
    grid: &Grid,
    chunks: usize,
    expected: f64,
    piece: &mut dyn FnMut(&Mesh) -> Result<()>,
) -> Result<()> {
    for_each_chunk(field, grid, chunks, expected, &mut |_, out| {
        piece(&out.piece())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::generate::rm::field::MixingLayer;

    /// The triangles as position triples, rotated to a canonical first corner and sorted.
    fn soup(m: &Mesh) -> Vec<[[u32; 3]; 3]> {
        let mut s: Vec<[[u32; 3]; 3]> = (0..m.triangle_count())
            .map(|i| {
                let c = m.corners(i).map(|p| p.map(f32::to_bits));
                let r = (0..3).min_by_key(|&k| c[k]).unwrap_or(0);
                [c[r], c[(r + 1) % 3], c[(r + 2) % 3]]
            })
            .collect();
        s.sort_unstable();
        s
    }

    #[test]
    fn chunk_seams_leave_no_trace() {
        let field = MixingLayer::new(11, 3);
        let grid = Grid::new(50, field.z_range());
        let one = extract(&field, &grid, 1, 0.0);
        let many = extract(&field, &grid, 9, 0.0);
        assert_eq!(one.positions.len(), many.positions.len());
        assert_eq!(soup(&one), soup(&many));
    }

    /// Streamed pieces hold the whole mesh's triangles, corner for corner and in order, each
    /// piece a valid mesh of its own.
    #[test]
    fn pieces_hold_the_mesh_s_triangles_in_order() {
        let field = MixingLayer::new(11, 3);
        let grid = Grid::new(50, field.z_range());
        let whole = extract(&field, &grid, 9, 0.0);
        let bits = |c: [[f32; 3]; 3]| c.map(|p| p.map(f32::to_bits));
        let want: Vec<_> = (0..whole.triangle_count())
            .map(|i| bits(whole.corners(i)))
            .collect();
        let (mut got, mut pieces) = (Vec::new(), 0);
        stream(&field, &grid, 9, 0.0, &mut |m| {
            m.validate(std::path::Path::new("piece"))?;
            got.extend((0..m.triangle_count()).map(|i| bits(m.corners(i))));
            pieces += 1;
            Ok(())
        })
        .unwrap();
        assert_eq!(pieces, 9);
        assert_eq!(got.len(), want.len());
        assert!(got == want, "the pieces' triangles differ from the mesh's");
    }

    /// A consumer that fails stops the extraction with its error.
    #[test]
    fn a_failing_consumer_stops_the_workers() {
        let field = MixingLayer::new(11, 3);
        let grid = Grid::new(80, field.z_range());
        let mut seen = 0;
        let e = stream(&field, &grid, 40, 0.0, &mut |_| {
            seen += 1;
            if seen == 3 {
                return Err(Error::Invalid("disk full".into()));
            }
            Ok(())
        })
        .unwrap_err();
        assert_eq!(seen, 3);
        assert!(e.to_string().contains("disk full"), "{e}");
    }
}
