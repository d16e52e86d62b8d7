//! The synthetic mixing layer `f(x, y, z) = z - H(x, y) - E(x, y) * T(x, y, z)`, evaluated a
//! column at a time, with octaves skipped where they cannot change a node's sign.

use super::noise::{PerlinColumn, floor, perlin};
use super::{ColumnField, Grid, Z_HALF};
use crate::scene::generate::SplitMix64;

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

/// Octaves whose wavelength spans at least CELLS_PER_WAVELENGTH cells of an n-cell grid (one at
/// least).
pub(super) fn octaves_for(n: usize) -> usize {
    let finest = n as f64 / (2.0 * CELLS_PER_WAVELENGTH);
    let mut count = 0;
    let mut f = TURB_FREQUENCY;
    while f <= finest && count < MAX_OCTAVES {
        count += 1;
        f *= TURB_LACUNARITY;
    }
    count.max(1)
}

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

pub(super) struct MixingLayer {
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
    pub(super) fn new(seed: u64, octaves: usize) -> Self {
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

/// Folds the noise at its zero set: sharp crests (spikes of heavy fluid) between rounded troughs
/// (bubbles of light fluid), about zero on average.
fn ridge(n: f32) -> f32 {
    2.0 * (RIDGE_OFFSET as f32 - n.abs())
}

fn smoothstep(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn octaves_follow_resolution() {
        assert_eq!(octaves_for(10), 1);
        assert!(octaves_for(300) >= 3);
        assert!(octaves_for(3000) > octaves_for(300));
        assert!(octaves_for(1_000_000) <= MAX_OCTAVES);
    }
}
