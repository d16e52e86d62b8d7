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

use super::SplitMix64;
use crate::scene::mesh::Mesh;
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};

/// Half the height of the sampled slab: the surface stays within z in [-Z_HALF, Z_HALF].
const Z_HALF: f64 = 0.35;
/// Amplitude of the large modes (half their range over the domain).
const MODE_AMPLITUDE: f64 = 0.14;
/// Number of large modes and their wavelengths.
const MODES: usize = 8;
const MODE_WAVELENGTH: (f64, f64) = (0.35, 0.9);
/// Bubble/spike asymmetry: the modes' sum goes through exp(SPIKE * g).
const SPIKE: f64 = 2.2;
/// Amplitude, frequency (lattice cells per unit), gain and lacunarity of the turbulence octaves.
const TURB_AMPLITUDE: f64 = 0.14;
const TURB_FREQUENCY: f64 = 3.5;
const TURB_GAIN: f64 = 0.55;
const TURB_LACUNARITY: f64 = 2.03;
/// Vertical stretch of the turbulence (z frequency / horizontal frequency): < 1 makes fingers.
const TURB_Z_STRETCH: f64 = 0.8;
/// The finest octave still has this many grid cells per wavelength.
const CELLS_PER_WAVELENGTH: f64 = 5.0;
const MAX_OCTAVES: usize = 9;
/// How far an octave and all finer ones together are taken to move the field, in units of their
/// summed amplitudes. Gradient noise seldom goes beyond ~0.7 of its reach; a node further than
/// this from zero keeps its sign whatever the remaining octaves do, so they are skipped.
const NOISE_REACH: f64 = 0.6;
/// |noise| is about this on average.
const RIDGE_OFFSET: f64 = 0.22;
/// Nodes within this many cells (in field units) of the surface get every octave.
const EXACT_MARGIN_CELLS: f64 = 2.0;
/// Domain warp of the turbulence in x and y.
const WARP_AMPLITUDE: f64 = 0.12;
const WARP_FREQUENCY: f64 = 1.3;
/// Turbulence envelope: E in [ENV_MIN, ENV_MAX].
const ENV_MIN: f64 = 0.45;
const ENV_MAX: f64 = 1.15;
const ENV_FREQUENCY: f64 = 1.1;
/// Vertices are kept at least this fraction of an edge away from its ends, so no triangle
/// collapses onto a grid node.
const T_EPS: f32 = 0.01;
/// Marks a vertex index that belongs to the next chunk's first plane.
const TAG: u32 = 1 << 31;
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
    let target = triangles.clamp(16, MAX_TRIANGLES) as f64;
    let n0 = ((target / TRIANGLES_PER_COLUMN).sqrt().round() as usize).clamp(MIN_N, MAX_N);
    let field = MixingLayer::new(seed, octaves_for(n0));
    let (grid, expected) = calibrate(&field, target, n0);
    extract(&field, &grid, chunk_count(&grid), expected)
}

/// Octaves whose wavelength spans at least CELLS_PER_WAVELENGTH cells of an n-cell grid (one at
/// least).
fn octaves_for(n: usize) -> usize {
    let finest = n as f64 / (2.0 * CELLS_PER_WAVELENGTH);
    let mut count = 0;
    let mut f = TURB_FREQUENCY;
    while f <= finest && count < MAX_OCTAVES {
        count += 1;
        f *= TURB_LACUNARITY;
    }
    count.max(1)
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

// ---------------------------------------------------------------------------------------------
// The field

struct Octave {
    freq: f64,
    amp: f64,
    off: [f64; 3],
    seed: u32,
    /// Summed amplitudes of this octave and all finer ones.
    rest: f64,
}

impl Octave {
    /// How far above and below zero a node can be and still change sign through this octave
    /// and the finer ones, with envelope `e`: ridge() is at most 2 RIDGE_OFFSET, so the rest can
    /// lower a node by at most 2 RIDGE_OFFSET * rest (exactly), and raise it by 2 (NOISE_REACH -
    /// RIDGE_OFFSET) * rest (in practice).
    fn window(&self, e: f64, margin: f64) -> (f64, f64) {
        (
            2.0 * RIDGE_OFFSET * e * self.rest + margin,
            2.0 * (NOISE_REACH - RIDGE_OFFSET) * e * self.rest + margin,
        )
    }
}

struct MixingLayer {
    /// kx, ky, phase, weight (weights sum to 1).
    modes: Vec<[f64; 4]>,
    /// Range of exp(SPIKE * g) over the domain, mapped to [-MODE_AMPLITUDE, MODE_AMPLITUDE].
    raw_lo: f64,
    raw_hi: f64,
    env_off: [f64; 2],
    env_seed: u32,
    warp_off: [f64; 4],
    warp_seed: [u32; 2],
    octaves: Vec<Octave>,
    /// Where the surface can be (see [`MixingLayer::new`]).
    z_range: (f64, f64),
}

/// The per-column quantities: height of the large modes, turbulence envelope, warp.
struct Column {
    h: f64,
    e: f64,
    wx: f64,
    wy: f64,
}

impl MixingLayer {
    fn new(seed: u64, octaves: usize) -> Self {
        let mut rng = SplitMix64::new(seed ^ 0x524d_5f66_6965_6c64);
        let mut modes: Vec<[f64; 4]> = (0..MODES)
            .map(|_| {
                let angle = rng.range(0.0, std::f64::consts::TAU);
                let k = std::f64::consts::TAU / rng.range(MODE_WAVELENGTH.0, MODE_WAVELENGTH.1);
                [
                    k * angle.cos(),
                    k * angle.sin(),
                    rng.range(0.0, std::f64::consts::TAU),
                    rng.range(0.5, 1.0),
                ]
            })
            .collect();
        let total: f64 = modes.iter().map(|m| m[3]).sum();
        for m in &mut modes {
            m[3] /= total;
        }
        let env_off = [rng.range(0.0, 64.0), rng.range(0.0, 64.0)];
        let env_seed = rng.next_u32();
        let warp_off = [
            rng.range(0.0, 64.0),
            rng.range(0.0, 64.0),
            rng.range(0.0, 64.0),
            rng.range(0.0, 64.0),
        ];
        let warp_seed = [rng.next_u32(), rng.next_u32()];
        let mut octs = Vec::with_capacity(octaves);
        let (mut freq, mut amp) = (TURB_FREQUENCY, TURB_AMPLITUDE);
        for _ in 0..octaves {
            octs.push(Octave {
                freq,
                amp,
                off: [
                    rng.range(0.0, 64.0),
                    rng.range(0.0, 64.0),
                    rng.range(0.0, 64.0),
                ],
                seed: rng.next_u32(),
                rest: 0.0,
            });
            freq *= TURB_LACUNARITY;
            amp *= TURB_GAIN;
        }
        let mut rest = 0.0;
        for o in octs.iter_mut().rev() {
            rest += o.amp;
            o.rest = rest;
        }
        let mut field = MixingLayer {
            modes,
            raw_lo: 0.0,
            raw_hi: 1.0,
            env_off,
            env_seed,
            warp_off,
            warp_seed,
            octaves: octs,
            z_range: (-Z_HALF, Z_HALF),
        };
        // Scale the large modes to their actual range over the domain.
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        const S: usize = 96;
        for a in 0..=S {
            for b in 0..=S {
                let r = field.raw_height(
                    -1.0 + 2.0 * a as f64 / S as f64,
                    -1.0 + 2.0 * b as f64 / S as f64,
                );
                lo = lo.min(r);
                hi = hi.max(r);
            }
        }
        field.raw_lo = lo;
        field.raw_hi = hi.max(lo + 1e-9);
        // The surface stays within the first octave's window around the large modes; sample
        // where that is, with some slack for the columns between the samples.
        let (mut zlo, mut zhi) = (f64::INFINITY, f64::NEG_INFINITY);
        for a in 0..=S {
            for b in 0..=S {
                let c = field.column(
                    -1.0 + 2.0 * a as f64 / S as f64,
                    -1.0 + 2.0 * b as f64 / S as f64,
                );
                let (above, below) = field.octaves[0].window(c.e, 0.0);
                zlo = zlo.min(c.h - below);
                zhi = zhi.max(c.h + above);
            }
        }
        let slack = 0.03 * (zhi - zlo);
        field.z_range = ((zlo - slack).max(-Z_HALF), (zhi + slack).min(Z_HALF));
        field
    }

    fn raw_height(&self, x: f64, y: f64) -> f64 {
        let g: f64 = self
            .modes
            .iter()
            .map(|m| m[3] * (m[0] * x + m[1] * y + m[2]).cos())
            .sum();
        (SPIKE * g).exp()
    }

    fn column(&self, x: f64, y: f64) -> Column {
        let u = (self.raw_height(x, y) - self.raw_lo) / (self.raw_hi - self.raw_lo);
        let h = MODE_AMPLITUDE * (2.0 * u.clamp(-0.1, 1.1) - 1.0);
        let en = perlin(
            x * ENV_FREQUENCY + self.env_off[0],
            y * ENV_FREQUENCY + self.env_off[1],
            0.5,
            self.env_seed,
        );
        let patch = smoothstep((0.5 + 1.8 * en).clamp(0.0, 1.0));
        // Stronger on the spikes (u near 1), weaker in the bubbles.
        let e = ENV_MIN + (ENV_MAX - ENV_MIN) * (0.55 * patch + 0.45 * u.clamp(0.0, 1.0));
        let wx = WARP_AMPLITUDE
            * perlin(
                x * WARP_FREQUENCY + self.warp_off[0],
                y * WARP_FREQUENCY + self.warp_off[1],
                0.25,
                self.warp_seed[0],
            );
        let wy = WARP_AMPLITUDE
            * perlin(
                x * WARP_FREQUENCY + self.warp_off[2],
                y * WARP_FREQUENCY + self.warp_off[3],
                0.75,
                self.warp_seed[1],
            );
        Column { h, e, wx, wy }
    }

    /// The field at one point, exactly as [`ColumnField::eval_column`] computes it at a node of
    /// a grid with spacing `h` (for tests).
    #[cfg(test)]
    fn value(&self, x: f64, y: f64, z: f64, h: f64) -> f64 {
        let c = self.column(x, y);
        let margin = EXACT_MARGIN_CELLS * h;
        let mut v = (z - c.h) as f32;
        for oct in &self.octaves {
            let (above, below) = oct.window(c.e, margin);
            if f64::from(v) > above || f64::from(v) < -below {
                break;
            }
            let n = perlin(
                (x + c.wx) * oct.freq + oct.off[0],
                (y + c.wy) * oct.freq + oct.off[1],
                z * TURB_Z_STRETCH * oct.freq + oct.off[2],
                oct.seed,
            );
            v -= (c.e * oct.amp) as f32 * ridge(n as f32);
        }
        f64::from(v)
    }
}

impl ColumnField for MixingLayer {
    fn eval_column(&self, x: f64, y: f64, grid: &Grid, out: &mut [f32]) {
        let c = self.column(x, y);
        let (z0, h) = (grid.z0, grid.h);
        let (base, hf) = ((z0 - c.h) as f32, h as f32);
        for (k, v) in out.iter_mut().enumerate() {
            *v = base + (k as i32 as f32) * hf;
        }
        let margin = EXACT_MARGIN_CELLS * h;
        // Only nodes within the first octave's reach of the large-mode height can change sign.
        let (above, below) = self.octaves[0].window(c.e, margin);
        let lo = ((c.h - below - z0) / h).floor().max(0.0) as usize;
        let hi = ((c.h + above - z0) / h + 2.0).max(0.0) as usize;
        let (mut lo, mut hi) = (lo.min(out.len()), hi.min(out.len()));
        for oct in &self.octaves {
            let (above, below) = oct.window(c.e, margin);
            let (above, below) = (above as f32, -below as f32);
            let inside = |v: f32| v >= below && v <= above;
            while lo < hi && !inside(out[lo]) {
                lo += 1;
            }
            while hi > lo && !inside(out[hi - 1]) {
                hi -= 1;
            }
            if lo >= hi {
                break;
            }
            let amp = (c.e * oct.amp) as f32;
            let col = PerlinColumn::new(
                (x + c.wx) * oct.freq + oct.off[0],
                (y + c.wy) * oct.freq + oct.off[1],
                oct.seed,
            );
            // The z lattice coordinate is qz = z * fz + off; walk it one lattice cell at a time.
            let fz = TURB_Z_STRETCH * oct.freq;
            let dt = (h * fz) as f32;
            let mut ka = lo;
            while ka < hi {
                let qa = (z0 + ka as f64 * h) * fz + oct.off[2];
                let cell = floor(qa);
                let end = -floor(-(((cell + 1.0 - oct.off[2]) / fz - z0) / h));
                let kb = (end.max(ka as f64 + 1.0) as usize).min(hi);
                let [c0, c1, c2, c3] = col.coefficients(cell as i32).map(|v| v as f32);
                let t0 = (qa - cell) as f32;
                for (i, v) in out[ka..kb].iter_mut().enumerate() {
                    let t = t0 + (i as i32 as f32) * dt;
                    let a = c0 + c1 * t;
                    let b = c2 + c3 * (t - 1.0);
                    let n = a + fade32(t) * (b - a);
                    let d = amp * ridge(n);
                    let old = *v;
                    *v = if inside(old) { old - d } else { old };
                }
                ka = kb;
            }
        }
        // Close the surface off at the top and bottom of the slab, should it ever get there.
        let cap = (0.25 * h) as f32;
        let last = out.len() - 1;
        out[0] = out[0].min(-cap);
        out[last] = out[last].max(cap);
    }

    fn z_range(&self) -> (f64, f64) {
        self.z_range
    }
}

fn fade32(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// floor() without a libm call on targets without SSE4.1 (|x| < 2^52).
#[inline]
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// Folds the noise at its zero set: sharp crests (spikes of heavy fluid) between rounded troughs
/// (bubbles of light fluid), about zero on average.
fn ridge(n: f32) -> f32 {
    2.0 * (RIDGE_OFFSET as f32 - n.abs())
}

fn smoothstep(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

// ---------------------------------------------------------------------------------------------
// Gradient noise, evaluated a column at a time

const GRAD: [[f64; 3]; 16] = [
    [1.0, 1.0, 0.0],
    [-1.0, 1.0, 0.0],
    [1.0, -1.0, 0.0],
    [-1.0, -1.0, 0.0],
    [1.0, 0.0, 1.0],
    [-1.0, 0.0, 1.0],
    [1.0, 0.0, -1.0],
    [-1.0, 0.0, -1.0],
    [0.0, 1.0, 1.0],
    [0.0, -1.0, 1.0],
    [0.0, 1.0, -1.0],
    [0.0, -1.0, -1.0],
    [1.0, 1.0, 0.0],
    [0.0, -1.0, 1.0],
    [-1.0, 1.0, 0.0],
    [0.0, -1.0, -1.0],
];

fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// One of the 16 gradients for a lattice point.
fn lattice_hash(x: i32, y: i32, z: i32, seed: u32) -> usize {
    let mut h = seed
        .wrapping_add((x as u32).wrapping_mul(0x9e37_79b1))
        .wrapping_add((y as u32).wrapping_mul(0x85eb_ca77))
        .wrapping_add((z as u32).wrapping_mul(0xc2b2_ae3d));
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    h = h.wrapping_mul(0x297a_2d39);
    h ^= h >> 15;
    (h & 15) as usize
}

/// Improved (quintic) Perlin noise along a vertical line: the x, y lattice cell and weights are
/// fixed, so within one z cell the noise is `A(t) + fade(t) (B(t) - A(t))` with A and B linear
/// in t, from four coefficients per cell.
struct PerlinColumn {
    ix: i32,
    iy: i32,
    fx: f64,
    fy: f64,
    w: [f64; 4],
    seed: u32,
}

impl PerlinColumn {
    fn new(qx: f64, qy: f64, seed: u32) -> Self {
        let (flx, fly) = (floor(qx), floor(qy));
        let (fx, fy) = (qx - flx, qy - fly);
        let (u, v) = (fade(fx), fade(fy));
        PerlinColumn {
            ix: flx as i32,
            iy: fly as i32,
            fx,
            fy,
            w: [(1.0 - u) * (1.0 - v), u * (1.0 - v), (1.0 - u) * v, u * v],
            seed,
        }
    }

    /// [A(0), A'(t), B(1), B'(t)] for the z cell starting at lattice z `iz`.
    fn coefficients(&self, iz: i32) -> [f64; 4] {
        let mut c = [0.0; 4];
        for (q, (da, db)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
            let (dx, dy) = (self.fx - f64::from(da), self.fy - f64::from(db));
            for dc in 0..2 {
                let g = GRAD[lattice_hash(self.ix + da, self.iy + db, iz + dc, self.seed)];
                c[2 * dc as usize] += self.w[q] * (g[0] * dx + g[1] * dy);
                c[2 * dc as usize + 1] += self.w[q] * g[2];
            }
        }
        c
    }
}

fn column_noise(c: &[f64; 4], t: f64) -> f64 {
    let a = c[0] + c[1] * t;
    let b = c[2] + c[3] * (t - 1.0);
    a + fade(t) * (b - a)
}

fn perlin(x: f64, y: f64, z: f64, seed: u32) -> f64 {
    let col = PerlinColumn::new(x, y, seed);
    let fl = floor(z);
    column_noise(&col.coefficients(fl as i32), z - fl)
}

// ---------------------------------------------------------------------------------------------
// Marching tetrahedra

/// Where a cube edge's vertex index lives: `src` 0 = the near plane's in-plane edges, 1 = the far
/// plane's, 2 = the edges crossing the layer; `kind` is the edge type within that array; the
/// edge starts at node (j + dj, k + dk).
#[derive(Clone, Copy, Debug)]
struct EdgeSlot {
    src: u8,
    kind: u8,
    dj: u8,
    dk: u8,
}

/// Per corner-sign mask of a cube (bit c set = corner c inside, c = dx + 2 dy + 4 dz), the
/// triangles of its six tetrahedra as cube-edge ids, facing the outside.
struct Tables {
    edges: Vec<EdgeSlot>,
    start: [u16; 257],
    tris: Vec<[u8; 3]>,
}

fn corner(c: usize) -> [i32; 3] {
    [(c & 1) as i32, ((c >> 1) & 1) as i32, ((c >> 2) & 1) as i32]
}

fn tables() -> &'static Tables {
    static TABLES: OnceLock<Tables> = OnceLock::new();
    TABLES.get_or_init(build_tables)
}

fn build_tables() -> Tables {
    // The six tetrahedra around the main diagonal 0-7, each ordered to be positively oriented.
    let mut tets = Vec::new();
    for p in [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ] {
        let c1 = 1usize << p[0];
        let c2 = c1 | (1usize << p[1]);
        let mut t = [0usize, c1, c2, 7];
        let [a, b, c, d] = t.map(corner);
        let e = |u: [i32; 3]| [u[0] - a[0], u[1] - a[1], u[2] - a[2]];
        let (u, v, w) = (e(b), e(c), e(d));
        let det = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
            + u[2] * (v[0] * w[1] - v[1] * w[0]);
        assert!(det != 0);
        if det < 0 {
            t.swap(2, 3);
        }
        tets.push(t);
    }
    let mut edges: Vec<EdgeSlot> = Vec::new();
    let mut ids = [[u8::MAX; 8]; 8];
    let mut edge_id = |c1: usize, c2: usize| -> u8 {
        let (lo, hi) = (c1.min(c2), c1.max(c2));
        if ids[lo][hi] == u8::MAX {
            let (b, t) = (corner(lo), corner(hi));
            let d = [t[0] - b[0], t[1] - b[1], t[2] - b[2]];
            assert!(d.iter().all(|&x| x == 0 || x == 1), "edge {lo}-{hi}");
            let (src, kind) = if d[0] == 1 {
                (2, d[1] + 2 * d[2])
            } else {
                let kind = match (d[1], d[2]) {
                    (1, 0) => 0,
                    (0, 1) => 1,
                    _ => 2,
                };
                (b[0], kind)
            };
            ids[lo][hi] = edges.len() as u8;
            edges.push(EdgeSlot {
                src: src as u8,
                kind: kind as u8,
                dj: b[1] as u8,
                dk: b[2] as u8,
            });
        }
        ids[lo][hi]
    };
    let parity = |p: [usize; 4]| {
        let mut inv = 0;
        for i in 0..4 {
            for j in i + 1..4 {
                if p[i] > p[j] {
                    inv += 1;
                }
            }
        }
        inv % 2
    };
    let mut start = [0u16; 257];
    let mut tris = Vec::new();
    for (mask, first) in start.iter_mut().enumerate().take(256) {
        *first = tris.len() as u16;
        for t in &tets {
            let inside: Vec<usize> = (0..4).filter(|&q| mask >> t[q] & 1 == 1).collect();
            let outside: Vec<usize> = (0..4).filter(|&q| mask >> t[q] & 1 == 0).collect();
            let mut e = |p: usize, q: usize| edge_id(t[p], t[q]);
            match inside.len() {
                1 | 3 => {
                    let lone = if inside.len() == 1 {
                        inside[0]
                    } else {
                        outside[0]
                    };
                    let mut o: Vec<usize> = (0..4).filter(|&q| q != lone).collect();
                    if parity([lone, o[0], o[1], o[2]]) == 1 {
                        o.swap(1, 2);
                    }
                    // Faces away from the lone corner; flip when the lone corner is outside.
                    let tri = [e(lone, o[0]), e(lone, o[1]), e(lone, o[2])];
                    tris.push(if inside.len() == 1 {
                        tri
                    } else {
                        [tri[0], tri[2], tri[1]]
                    });
                }
                2 => {
                    let (a, b) = (inside[0], inside[1]);
                    let (mut c, mut d) = (outside[0], outside[1]);
                    if parity([a, b, c, d]) == 1 {
                        std::mem::swap(&mut c, &mut d);
                    }
                    let (ac, ad, bd, bc) = (e(a, c), e(a, d), e(b, d), e(b, c));
                    tris.push([ac, ad, bd]);
                    tris.push([ac, bd, bc]);
                }
                _ => {}
            }
        }
    }
    start[256] = tris.len() as u16;
    assert_eq!(edges.len(), 19);
    Tables { edges, start, tris }
}

/// One x-plane of nodes: values, sign bits (set = negative) and the indices of the vertices on
/// its three in-plane edge types (+y, +z, +y+z) at each node.
struct Plane {
    vals: Vec<f32>,
    bits: Vec<u64>,
    idx: Vec<u32>,
}

impl Plane {
    fn new(grid: &Grid) -> Self {
        Plane {
            vals: vec![0.0; grid.nodes_per_plane()],
            bits: vec![0; (grid.n + 1) * grid.words()],
            idx: vec![0; 3 * grid.nodes_per_plane()],
        }
    }
}

/// A worker's buffers: two planes, the layer's crossing-edge indices (+x, +x+y, +x+z, +x+y+z)
/// and bit masks of the valid nodes / cells in a row.
struct Work {
    a: Plane,
    b: Plane,
    cross: Vec<u32>,
    lt_nz: Vec<u64>,
    or: Vec<u64>,
    and: Vec<u64>,
}

impl Work {
    fn new(grid: &Grid) -> Self {
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

/// The row's bits shifted down by one node (bit k = node k + 1).
#[inline]
fn shr1(row: &[u64], w: usize) -> u64 {
    let next = if w + 1 < row.len() {
        row[w + 1] << 63
    } else {
        0
    };
    (row[w] >> 1) | next
}

#[inline]
fn bit(row: &[u64], k: usize) -> usize {
    ((row[k >> 6] >> (k & 63)) & 1) as usize
}

/// Calls `f(k)` for every set bit of `word` (word `w` of a row).
#[inline]
fn for_bits(mut word: u64, w: usize, mut f: impl FnMut(usize)) {
    while word != 0 {
        f(w * 64 + word.trailing_zeros() as usize);
        word &= word - 1;
    }
}

#[derive(Default)]
struct ChunkOut {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    /// Vertices on the first plane (numbered first, in scan order).
    first_plane: u32,
    /// Vertices referenced on the next chunk's first plane.
    foreign: u32,
    count: u64,
}

fn eval_plane(field: &impl ColumnField, grid: &Grid, i: usize, plane: &mut Plane) {
    let (s, words) = (grid.stride(), grid.words());
    let x = grid.xy(i);
    for j in 0..=grid.n {
        let vals = &mut plane.vals[j * s..(j + 1) * s];
        field.eval_column(x, grid.xy(j), grid, vals);
        let row = &mut plane.bits[j * words..(j + 1) * words];
        for (word, chunk) in row.iter_mut().zip(vals.chunks_mut(64)) {
            let mut bits = 0u64;
            for (b, v) in chunk.iter_mut().enumerate() {
                if *v == 0.0 {
                    *v = f32::MIN_POSITIVE;
                }
                bits |= u64::from(v.to_bits() >> 31) << b;
            }
            *word = bits;
        }
    }
}

/// The vertex on the edge from node `pa` (value `va`) to `pb` (value `vb`), of opposite signs.
#[inline]
fn edge_vertex(pa: [f64; 3], va: f32, pb: [f64; 3], vb: f32) -> [f32; 3] {
    let t = f64::from((va / (va - vb)).clamp(T_EPS, 1.0 - T_EPS));
    [
        (pa[0] + t * (pb[0] - pa[0])) as f32,
        (pa[1] + t * (pb[1] - pa[1])) as f32,
        (pa[2] + t * (pb[2] - pa[2])) as f32,
    ]
}

/// Creates the vertices on plane `i`'s in-plane edges in a fixed scan order (row, edge type,
/// z), recording their indices. Owned vertices are appended to `out.positions`; the far plane of
/// a chunk that is not the last is owned by the next chunk, which numbers them the same way, so
/// they get tagged indices 0, 1, 2, ... in the same order.
fn scan_plane(
    grid: &Grid,
    i: usize,
    plane: &mut Plane,
    lt_nz: &[u64],
    owned: bool,
    out: &mut ChunkOut,
) {
    let (s, words) = (grid.stride(), grid.words());
    let x = grid.xy(i);
    let Plane { vals, bits, idx } = plane;
    let pos = |j: usize, k: usize| [x, grid.xy(j), grid.z(k)];
    let add = |out: &mut ChunkOut, na: (usize, usize), nb: (usize, usize)| -> u32 {
        if owned {
            let p = edge_vertex(
                pos(na.0, na.1),
                vals[na.0 * s + na.1],
                pos(nb.0, nb.1),
                vals[nb.0 * s + nb.1],
            );
            out.positions.push(p);
            (out.positions.len() - 1) as u32
        } else {
            out.foreign += 1;
            TAG | (out.foreign - 1)
        }
    };
    for j in 0..=grid.n {
        let r0 = &bits[j * words..(j + 1) * words];
        if j < grid.n {
            let r1 = &bits[(j + 1) * words..(j + 2) * words];
            for w in 0..words {
                for_bits(r0[w] ^ r1[w], w, |k| {
                    idx[3 * (j * s + k)] = add(out, (j, k), (j + 1, k));
                });
            }
        }
        for w in 0..words {
            for_bits((r0[w] ^ shr1(r0, w)) & lt_nz[w], w, |k| {
                idx[3 * (j * s + k) + 1] = add(out, (j, k), (j, k + 1));
            });
        }
        if j < grid.n {
            let r1 = &bits[(j + 1) * words..(j + 2) * words];
            for w in 0..words {
                for_bits((r0[w] ^ shr1(r1, w)) & lt_nz[w], w, |k| {
                    idx[3 * (j * s + k) + 2] = add(out, (j, k), (j + 1, k + 1));
                });
            }
        }
    }
}

/// Creates the vertices on the edges from plane `i` (`a`) to plane `i + 1` (`b`).
fn scan_cross(
    grid: &Grid,
    i: usize,
    a: &Plane,
    b: &Plane,
    work_cross: &mut [u32],
    lt_nz: &[u64],
    out: &mut ChunkOut,
) {
    let (s, words) = (grid.stride(), grid.words());
    let (xa, xb) = (grid.xy(i), grid.xy(i + 1));
    let mut add = |j: usize, k: usize, jb: usize, kb: usize| -> u32 {
        let p = edge_vertex(
            [xa, grid.xy(j), grid.z(k)],
            a.vals[j * s + k],
            [xb, grid.xy(jb), grid.z(kb)],
            b.vals[jb * s + kb],
        );
        out.positions.push(p);
        (out.positions.len() - 1) as u32
    };
    for j in 0..=grid.n {
        let a0 = &a.bits[j * words..(j + 1) * words];
        let b0 = &b.bits[j * words..(j + 1) * words];
        for w in 0..words {
            for_bits(a0[w] ^ b0[w], w, |k| {
                work_cross[4 * (j * s + k)] = add(j, k, j, k);
            });
        }
        if j < grid.n {
            let b1 = &b.bits[(j + 1) * words..(j + 2) * words];
            for w in 0..words {
                for_bits(a0[w] ^ b1[w], w, |k| {
                    work_cross[4 * (j * s + k) + 1] = add(j, k, j + 1, k);
                });
            }
        }
        for w in 0..words {
            for_bits((a0[w] ^ shr1(b0, w)) & lt_nz[w], w, |k| {
                work_cross[4 * (j * s + k) + 2] = add(j, k, j, k + 1);
            });
        }
        if j < grid.n {
            let b1 = &b.bits[(j + 1) * words..(j + 2) * words];
            for w in 0..words {
                for_bits((a0[w] ^ shr1(b1, w)) & lt_nz[w], w, |k| {
                    work_cross[4 * (j * s + k) + 3] = add(j, k, j + 1, k + 1);
                });
            }
        }
    }
}

/// Emits (or only counts) the triangles of the cells between planes `a` and `b`.
#[allow(clippy::too_many_arguments)]
fn march_layer(
    grid: &Grid,
    tables: &Tables,
    a: &Plane,
    b: &Plane,
    cross: &[u32],
    lt_nz: &[u64],
    or: &mut [u64],
    and: &mut [u64],
    emit: bool,
    out: &mut ChunkOut,
) {
    let (s, words) = (grid.stride(), grid.words());
    for j in 0..grid.n {
        let a0 = &a.bits[j * words..(j + 1) * words];
        let a1 = &a.bits[(j + 1) * words..(j + 2) * words];
        let b0 = &b.bits[j * words..(j + 1) * words];
        let b1 = &b.bits[(j + 1) * words..(j + 2) * words];
        for w in 0..words {
            or[w] = a0[w] | a1[w] | b0[w] | b1[w];
            and[w] = a0[w] & a1[w] & b0[w] & b1[w];
        }
        for w in 0..words {
            let mixed = (or[w] | shr1(or, w)) & !(and[w] & shr1(and, w)) & lt_nz[w];
            for_bits(mixed, w, |k| {
                let mask = bit(a0, k)
                    | bit(b0, k) << 1
                    | bit(a1, k) << 2
                    | bit(b1, k) << 3
                    | bit(a0, k + 1) << 4
                    | bit(b0, k + 1) << 5
                    | bit(a1, k + 1) << 6
                    | bit(b1, k + 1) << 7;
                let range = tables.start[mask] as usize..tables.start[mask + 1] as usize;
                if !emit {
                    out.count += range.len() as u64;
                    return;
                }
                let vertex = |e: u8| -> u32 {
                    let slot = tables.edges[e as usize];
                    let node = (j + slot.dj as usize) * s + k + slot.dk as usize;
                    match slot.src {
                        0 => a.idx[3 * node + slot.kind as usize],
                        1 => b.idx[3 * node + slot.kind as usize],
                        _ => cross[4 * node + slot.kind as usize],
                    }
                };
                for t in &tables.tris[range] {
                    out.triangles
                        .push([vertex(t[0]), vertex(t[1]), vertex(t[2])]);
                }
            });
        }
    }
}

/// Layers i0..i1 (cells between x-planes i0 and i1). With `emit`, the mesh of those layers,
/// with the vertices of plane i0 first and tagged references to plane i1 unless it is the last
/// plane; without, only the triangle count.
fn run_chunk(
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
fn extract(field: &impl ColumnField, grid: &Grid, chunks: usize, expected: f64) -> Mesh {
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
    use std::collections::HashMap;
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

    fn normal(m: &Mesh, i: usize) -> [f64; 3] {
        let c = m.corners(i).map(|p| p.map(f64::from));
        let e1 = [c[1][0] - c[0][0], c[1][1] - c[0][1], c[1][2] - c[0][2]];
        let e2 = [c[2][0] - c[0][0], c[2][1] - c[0][1], c[2][2] - c[0][2]];
        [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ]
    }

    #[test]
    fn no_repeated_indices_and_no_zero_area() {
        let m = rm(100_000, 4);
        let mut zero = 0;
        for (i, t) in m.triangles.iter().enumerate() {
            assert!(
                t[0] != t[1] && t[1] != t[2] && t[0] != t[2],
                "triangle {i}: {t:?}"
            );
            if normal(&m, i) == [0.0; 3] {
                zero += 1;
            }
        }
        assert!(
            zero * 10_000 <= m.triangle_count(),
            "{zero} zero-area triangles"
        );
    }

    /// Directed edge counts of a mesh.
    fn edges(m: &Mesh) -> HashMap<(u32, u32), u32> {
        let mut e = HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                *e.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        e
    }

    /// Every edge is used once in each direction (so there are no cracks and the orientation is
    /// consistent), except on the sides of the domain, where the sheet is cut off.
    #[test]
    fn crack_free_and_consistently_oriented() {
        let m = rm(20_000, 2);
        let on_side = |v: u32| {
            let p = m.positions[v as usize];
            [p[0] == -1.0, p[0] == 1.0, p[1] == -1.0, p[1] == 1.0]
        };
        let e = edges(&m);
        let mut border = 0;
        for (&(a, b), &n) in &e {
            assert_eq!(n, 1, "edge {a}-{b} used twice in the same direction");
            if !e.contains_key(&(b, a)) {
                let (sa, sb) = (on_side(a), on_side(b));
                assert!(
                    (0..4).any(|s| sa[s] && sb[s]),
                    "open edge {a}-{b} inside the domain: {:?} {:?}",
                    m.positions[a as usize],
                    m.positions[b as usize]
                );
                border += 1;
            }
        }
        assert!(border > 0);
    }

    #[test]
    fn faces_the_light_fluid() {
        let m = rm(50_000, 8);
        let (mut up, mut total) = (0.0, 0.0);
        for i in 0..m.triangle_count() {
            let n = normal(&m, i);
            up += n[2];
            total += (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        }
        assert!(up > 0.3 * total, "up {up} of {total}");
    }

    /// A ball, to check closure and orientation on a surface with no border.
    struct Ball;

    impl ColumnField for Ball {
        fn eval_column(&self, x: f64, y: f64, grid: &Grid, out: &mut [f32]) {
            for (k, v) in out.iter_mut().enumerate() {
                let (dx, dy, dz) = (x - 0.1, y + 0.05, grid.z(k) - 0.02);
                *v = ((dx * dx + dy * dy + dz * dz).sqrt() - 0.3) as f32;
            }
        }

        fn z_range(&self) -> (f64, f64) {
            (-0.28, 0.32)
        }
    }

    #[test]
    fn ball_is_closed_and_faces_out() {
        let grid = Grid::new(40, Ball.z_range());
        let m = extract(&Ball, &grid, 5, 0.0);
        let e = edges(&m);
        for (&(a, b), &n) in &e {
            assert_eq!(n, 1);
            assert!(
                e.contains_key(&(b, a)),
                "open edge {a}-{b} {:?} {:?}",
                m.positions[a as usize],
                m.positions[b as usize]
            );
        }
        // Signed volume by the divergence theorem: positive when the triangles face out.
        let volume: f64 = (0..m.triangle_count())
            .map(|i| {
                let c = m.corners(i).map(|p| p.map(f64::from));
                (c[0][0] * (c[1][1] * c[2][2] - c[1][2] * c[2][1])
                    - c[0][1] * (c[1][0] * c[2][2] - c[1][2] * c[2][0])
                    + c[0][2] * (c[1][0] * c[2][1] - c[1][1] * c[2][0]))
                    / 6.0
            })
            .sum();
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 0.3f64.powi(3);
        assert!((volume / exact - 1.0).abs() < 0.05, "{volume} vs {exact}");
    }

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

    #[test]
    fn estimate_counts_what_extraction_makes() {
        let field = MixingLayer::new(12, 3);
        let grid = Grid::new(ESTIMATE_LAYERS, field.z_range());
        let m = extract(&field, &grid, 4, 0.0);
        assert_eq!(estimate(&field, &grid), m.triangle_count() as f64);
    }

    #[test]
    fn column_evaluation_matches_pointwise() {
        let field = MixingLayer::new(13, 5);
        let grid = Grid::new(150, field.z_range());
        let mut out = vec![0.0; grid.stride()];
        let (mut checked, mut off) = (0, 0);
        for (a, b) in [(3, 7), (40, 99), (75, 75), (120, 12), (149, 140)] {
            let (x, y) = (grid.xy(a), grid.xy(b));
            field.eval_column(x, y, &grid, &mut out);
            for (k, v) in out.iter().enumerate().skip(1).take(grid.nz - 1) {
                let exact = field.value(x, y, grid.z(k), grid.h);
                checked += 1;
                if (f64::from(*v) - exact).abs() > 1e-4 {
                    off += 1;
                }
            }
        }
        // An octave may be taken or skipped differently right at a window's edge.
        assert!(off * 200 <= checked, "{off} of {checked} differ");
    }

    #[test]
    fn marching_tables_are_complete() {
        let t = tables();
        assert_eq!(t.start[1] - t.start[0], 0);
        assert_eq!(t.start[256] - t.start[255], 0);
        for mask in 1..255 {
            let n = t.start[mask + 1] - t.start[mask];
            assert!((1..=12).contains(&n), "mask {mask}: {n}");
        }
    }

    #[test]
    fn octaves_follow_resolution() {
        assert_eq!(octaves_for(10), 1);
        assert!(octaves_for(300) >= 3);
        assert!(octaves_for(3000) > octaves_for(300));
        assert!(octaves_for(1_000_000) <= MAX_OCTAVES);
    }
}
