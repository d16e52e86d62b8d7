//! A stand-in for the Richtmyer-Meshkov instability isosurface: the interface between a heavy
//! fluid (below) and a light one (above) after a shock has gone through it.
//!
//! The field is `f(x, y, z) = z - H(x, y) - E(x, y) * T(x, y, z)`:
//! - `H` is a few large modes pushed through an exponential, so the heavy fluid rises in narrow
//!   spikes and the light fluid sinks in broad rounded bubbles;
//! - `T` is multi-octave gradient noise (domain-warped in x and y, stretched in z) whose steep
//!   octaves fold the sheet into overhangs, pinch off blobs and crumple it down to the grid scale;
//! - `E` modulates the turbulence: stronger on the spikes and in some patches, calmer elsewhere.
//!
//! The surface `f = 0` is extracted by marching tetrahedra (six tetrahedra around each cube's main
//! diagonal, the same in every cube, so neighbouring cubes agree on every face: no cracks), with
//! cubic cells. The grid covers x, y in [-1, 1] and in z only the part of [-0.35, 0.35] where the
//! surface can be. The field is sampled two x-planes at a time, never as a whole grid: the x range
//! is cut into chunks of layers that worker threads take in order, each walking its planes and
//! welding every vertex on a grid edge through per-plane edge-index arrays. A chunk numbers the
//! vertices on its far plane the way the next chunk numbers them, so the chunks are stitched by
//! adding offsets as they are appended, in order, to the mesh; only a few chunks exist at a time
//! besides the mesh, so the peak memory is little more than the mesh itself.
//!
//! The triangle count is steered by the grid resolution: a first guess, then a count on a few
//! sampled layers, then the corrected resolution (the count grows as its square).
//!
//! The sign of each node is kept in bit rows, so whole runs of 64 cells that the surface does not
//! cross are skipped with a few word operations, and octaves of noise are only evaluated where
//! they can still change the node's sign (plus a margin of two cells, so values near the surface
//! are those of the full sum): far from the interface a node costs a subtraction. Every node's
//! value depends on the node alone, so neighbouring chunks agree on it.
//!
//! Here: the public generator, the grid and its calibration; `field`: the synthetic mixing
//! layer; `noise`: the gradient noise it is made of; `tables`: the marching-tetrahedra tables;
//! `march`: the extraction of one layer of cells; `chunks`: the layers in chunks on worker
//! threads, stitched in order into the mesh or handed on one by one (`rm_pieces`).

mod chunk;
mod chunks;
mod field;
mod march;
mod noise;
mod tables;

use crate::error::Result;
use crate::scene::mesh::Mesh;
use chunks::{Work, extract, run_chunk, stream};
use field::{MixingLayer, octaves_for};
use rayon::prelude::*;

/// Half the height of the sampled slab: the surface stays within z in [-Z_HALF, Z_HALF].
const Z_HALF: f64 = 0.35;
/// Initial guess of triangles per grid column (calibrated on the actual field before extraction).
const TRIANGLES_PER_COLUMN: f64 = 18.0;
const MIN_N: usize = 4;
const MAX_N: usize = 16_384;
/// Beyond this the 32-bit vertex indices would not do.
const MAX_TRIANGLES: u64 = 4_000_000_000;
/// Layers sampled to estimate the triangle count of a resolution.
const ESTIMATE_LAYERS: usize = 32;

/// The isosurface of the synthetic mixing layer with about `triangles` triangles (within a few
/// percent for targets above ~10,000), deterministic for `(triangles, seed)`. Positions lie in
/// x, y in [-1, 1] and z in [-0.35, 0.35]; about one vertex per two triangles; triangles face the
/// +z side (the light fluid). Open only along the sides x = +-1 and y = +-1.
pub fn rm(triangles: u64, seed: u64) -> Mesh {
    let (field, grid, expected) = setup(triangles, seed);
    extract(&field, &grid, chunk_count(&grid), expected)
}

/// The same surface as [`rm`], handed to `piece` a chunk of layers at a time, each chunk a mesh
/// of its own; the pieces' triangles, in order, are `rm`'s. Only a few chunks exist at a time,
/// so no whole model is held. An error of `piece` stops the extraction and is returned.
pub fn rm_pieces(
    triangles: u64,
    seed: u64,
    piece: &mut dyn FnMut(&Mesh) -> Result<()>,
) -> Result<()> {
    let (field, grid, expected) = setup(triangles, seed);
    stream(&field, &grid, chunk_count(&grid), expected, piece)
}

/// The field of `seed` and the grid that gives it about `triangles` triangles, with the count
/// expected there.
fn setup(triangles: u64, seed: u64) -> (MixingLayer, Grid, f64) {
    let target = triangles.clamp(16, MAX_TRIANGLES) as f64;
    let n0 = ((target / TRIANGLES_PER_COLUMN).sqrt().round() as usize).clamp(MIN_N, MAX_N);
    let field = MixingLayer::new(seed, octaves_for(n0));
    let (grid, expected) = calibrate(&field, target, n0);
    (field, grid, expected)
}

/// The grid whose estimated triangle count is closest to `target`, and that count: the count
/// grows as n^2, so a correction or two from the initial guess suffice.
fn calibrate(field: &impl ColumnField, target: f64, n0: usize) -> (Grid, f64) {
    let mut n = n0;
    let mut expected = target;
    for _ in 0..4 {
        let estimate = estimate(field, &Grid::new(n, field.z_range()));
        let next = if estimate > 0.0 {
            (n as f64 * (target / estimate).sqrt()).round() as usize
        } else {
            n * 2
        }
        .clamp(MIN_N, MAX_N);
        expected = estimate * (next as f64 / n as f64).powi(2);
        let settled = next.abs_diff(n) as f64 <= 0.01 * n as f64;
        n = next;
        if settled {
            break;
        }
    }
    (Grid::new(n, field.z_range()), expected)
}

/// The triangle count at `grid`, from evenly spaced layers (all of them on small grids).
fn estimate(field: &impl ColumnField, grid: &Grid) -> f64 {
    let samples = grid.n.min(ESTIMATE_LAYERS);
    let layers: Vec<usize> = (0..samples)
        .map(|s| (2 * s + 1) * grid.n / (2 * samples))
        .collect();
    let count: u64 = layers
        .par_iter()
        .map_init(
            || Work::new(grid),
            |work, &i| run_chunk(field, grid, i, i + 1, false, work).count,
        )
        .sum();
    count as f64 * grid.n as f64 / samples as f64
}

/// Enough chunks to keep several cores busy, few enough that the repeated boundary planes cost
/// little. It depends on the grid only, not on the machine, so the vertex order is the same
/// everywhere.
fn chunk_count(grid: &Grid) -> usize {
    (grid.n / 40).clamp(8.min(grid.n), 256)
}

/// Cell layers and node spacing: n cells along x and y over [-1, 1], nz cells of the same size
/// along z over [z0, z0 + nz * h], covering the field's z range with a cell to spare each side
/// but never leaving [-Z_HALF, Z_HALF].
#[derive(Clone, Copy, Debug)]
struct Grid {
    n: usize,
    nz: usize,
    h: f64,
    z0: f64,
}

impl Grid {
    fn new(n: usize, (lo, hi): (f64, f64)) -> Self {
        let h = 2.0 / n as f64;
        let (lo, hi) = ((lo - h).max(-Z_HALF), (hi + h).min(Z_HALF));
        let nz = (((hi - lo) / h + 1e-6).floor() as usize).max(2);
        Grid { n, nz, h, z0: lo }
    }

    /// The coordinate of node `i` along x (or y), exactly -1 and 1 at the ends.
    fn xy(&self, i: usize) -> f64 {
        -1.0 + 2.0 * i as f64 / self.n as f64
    }

    fn z(&self, k: usize) -> f64 {
        self.z0 + k as f64 * self.h
    }

    /// Nodes in one column (one row of a plane's arrays).
    fn stride(&self) -> usize {
        self.nz + 1
    }

    /// 64-bit words per row of sign bits.
    fn words(&self) -> usize {
        (self.nz + 1).div_ceil(64)
    }

    fn nodes_per_plane(&self) -> usize {
        (self.n + 1) * self.stride()
    }
}

/// A scalar field sampled a column (fixed x, y; every z node of the grid) at a time.
trait ColumnField: Sync {
    /// Writes f(x, y, z_k) for k in 0..=nz into `out`; negative is inside (the heavy fluid).
    fn eval_column(&self, x: f64, y: f64, grid: &Grid, out: &mut [f32]);

    /// The z range that holds the whole surface.
    fn z_range(&self) -> (f64, f64);
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn deterministic_per_seed() {
        let (a, b, c) = (rm(30_000, 5), rm(30_000, 5), rm(30_000, 6));
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.triangles, b.triangles);
        assert!(a.positions != c.positions || a.triangles != c.triangles);
    }

    #[test]
    fn positions_within_bounds_and_welded() {
        let m = rm(200_000, 3);
        m.validate(Path::new("rm")).unwrap();
        for p in &m.positions {
            assert!(p.iter().all(|c| c.is_finite()));
            assert!(p[0].abs() <= 1.0 && p[1].abs() <= 1.0, "{p:?}");
            assert!(p[2].abs() <= Z_HALF as f32, "{p:?}");
        }
        // Shared grid edges share their vertex: about one vertex per two triangles.
        let per_triangle = m.positions.len() as f64 / m.triangle_count() as f64;
        assert!(per_triangle < 0.56, "{per_triangle} vertices per triangle");
        // The sheet fills the domain.
        let (lo, hi) = m
            .positions
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), p| {
                (lo.min(p[2]), hi.max(p[2]))
            });
        assert!(lo < -0.15 && hi > 0.12, "z range {lo}..{hi}");
    }

    #[test]
    fn estimate_counts_what_extraction_makes() {
        let field = MixingLayer::new(12, 3);
        let grid = Grid::new(ESTIMATE_LAYERS, field.z_range());
        let m = extract(&field, &grid, 4, 0.0);
        assert_eq!(estimate(&field, &grid), m.triangle_count() as f64);
    }
}
