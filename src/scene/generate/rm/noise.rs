//! Improved (quintic) gradient noise, evaluated a column at a time.

/// floor() without a libm call on targets without SSE4.1 (|x| < 2^52).
#[inline]
pub(super) fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

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
pub(super) struct PerlinColumn {
    ix: i32,
    iy: i32,
    fx: f64,
    fy: f64,
    w: [f64; 4],
    seed: u32,
}

impl PerlinColumn {
    pub(super) fn new(qx: f64, qy: f64, seed: u32) -> Self {
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
    pub(super) fn coefficients(&self, iz: i32) -> [f64; 4] {
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

pub(super) fn perlin(x: f64, y: f64, z: f64, seed: u32) -> f64 {
    let col = PerlinColumn::new(x, y, seed);
    let fl = floor(z);
    column_noise(&col.coefficients(fl as i32), z - fl)
}
