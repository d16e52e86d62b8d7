//! Extraction in chunks of layers: worker threads take chunks in order, and each finished chunk
//! is appended to the mesh as soon as its predecessors are, its seam vertices resolved.

use super::march::{Plane, eval_plane, march_layer, scan_cross, scan_plane};
use super::tables::tables;
use super::{ColumnField, Grid};
use crate::scene::mesh::Mesh;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Marks a vertex index that belongs to the next chunk's first plane.
pub(super) const TAG: u32 = 1 << 31;

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

#[derive(Default)]
pub(super) struct ChunkOut {
    pub(super) positions: Vec<[f32; 3]>,
    pub(super) triangles: Vec<[u32; 3]>,
    /// Vertices on the first plane (numbered first, in scan order).
    pub(super) first_plane: u32,
    /// Vertices referenced on the next chunk's first plane.
    pub(super) foreign: u32,
    pub(super) count: u64,
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

/// Appends finished chunks in order, resolving their vertex indices, and frees them.
struct Sink {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    pending: Vec<Option<ChunkOut>>,
    next: usize,
    /// Vertices the previous chunk referenced on this one's first plane.
    seam: u32,
}

impl Sink {
    fn accept(&mut self, chunk: usize, out: ChunkOut) {
        self.pending[chunk] = Some(out);
        while let Some(out) = self.pending.get_mut(self.next).and_then(Option::take) {
            assert!(
                self.next == 0 || self.seam == out.first_plane,
                "chunk {} disagrees with its predecessor on their shared plane",
                self.next
            );
            let own = self.positions.len() as u64;
            let next = own + out.positions.len() as u64;
            assert!(
                next + u64::from(out.foreign) <= u64::from(u32::MAX),
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
            self.seam = out.foreign;
            self.next += 1;
        }
    }
}

/// The whole isosurface of `field` on `grid`, in `chunks` chunks of layers that the workers
/// take in order; each finished chunk is appended to the mesh as soon as its predecessors are,
/// so at most a few chunks exist besides the mesh. `expected` sizes the mesh's buffers.
pub(super) fn extract(field: &impl ColumnField, grid: &Grid, chunks: usize, expected: f64) -> Mesh {
    let chunks = chunks.clamp(1, grid.n);
    let ranges: Vec<(usize, usize)> = (0..chunks)
        .map(|c| (c * grid.n / chunks, (c + 1) * grid.n / chunks))
        .collect();
    let expected = expected.max(0.0) as usize;
    let sink = Mutex::new(Sink {
        positions: Vec::with_capacity(expected / 2 + expected / 16),
        triangles: Vec::with_capacity(expected + expected / 8),
        pending: (0..chunks).map(|_| None).collect(),
        next: 0,
        seam: 0,
    });
    let claimed = AtomicUsize::new(0);
    let workers = rayon::current_num_threads().clamp(1, chunks);
    rayon::scope(|s| {
        for _ in 0..workers {
            s.spawn(|_| {
                let mut work = Work::new(grid);
                loop {
                    let c = claimed.fetch_add(1, Ordering::Relaxed);
                    let Some(&(i0, i1)) = ranges.get(c) else {
                        break;
                    };
                    let out = run_chunk(field, grid, i0, i1, true, &mut work);
                    sink.lock().expect("a worker panicked").accept(c, out);
                }
            });
        }
    });
    let sink = sink.into_inner().expect("a worker panicked");
    assert_eq!(sink.next, chunks, "chunks missing");
    let (mut positions, mut triangles) = (sink.positions, sink.triangles);
    positions.shrink_to_fit();
    triangles.shrink_to_fit();
    Mesh {
        positions,
        triangles,
    }
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
}
