//! Test fixtures of the reference tracer: a small deterministic generator, random triangle
//! soups and rays, and the brute-force loop over all triangles that the BVH must reproduce.

use super::{Hit, Reference, intersect_triangle, sub, to_f64_tri};
use crate::scene::ray::Ray;

/// SplitMix64.
pub(super) struct Rng(pub(super) u64);

impl Rng {
    pub(super) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub(super) fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
    pub(super) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }
    pub(super) fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
    /// Uniform on the unit sphere.
    pub(super) fn unit(&mut self) -> [f64; 3] {
        loop {
            let p = [0, 1, 2].map(|_| self.range(-1.0, 1.0));
            let l2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
            if l2 > 1e-6 && l2 <= 1.0 {
                let l = l2.sqrt();
                return p.map(|c| c / l);
            }
        }
    }
}

pub(super) fn f32v(p: [f64; 3]) -> [f32; 3] {
    p.map(|c| c as f32)
}

pub(super) fn ray(origin: [f32; 3], dir: [f32; 3], tmax: f32) -> Ray {
    Ray { origin, dir, tmax }
}

/// Brute force over all triangles, in primitive order (ties: lowest id wins).
pub(super) fn brute_closest(tris: &[[[f32; 3]; 3]], r: &Ray) -> Option<(u32, f64, f64, f64)> {
    let o = r.origin.map(f64::from);
    let d = r.dir.map(f64::from);
    let mut best: Option<(u32, f64, f64, f64)> = None;
    for (i, t) in tris.iter().enumerate() {
        let limit = best.map_or(f64::from(r.tmax), |b| b.1);
        if let Some((t, u, v)) = intersect_triangle(o, d, limit, &to_f64_tri(t))
            && best.is_none_or(|b| t < b.1)
        {
            best = Some((i as u32, t, u, v));
        }
    }
    best
}

pub(super) fn brute_any(tris: &[[[f32; 3]; 3]], r: &Ray) -> bool {
    let o = r.origin.map(f64::from);
    let d = r.dir.map(f64::from);
    let tmax = f64::from(r.tmax);
    tris.iter()
        .any(|t| intersect_triangle(o, d, tmax, &to_f64_tri(t)).is_some_and(|(t, _, _)| t < tmax))
}

pub(super) fn key(h: &Option<Hit>) -> Option<(u32, u64, u64, u64)> {
    h.map(|h| (h.prim, h.t.to_bits(), h.u.to_bits(), h.v.to_bits()))
}

pub(super) fn brute_key(b: &Option<(u32, f64, f64, f64)>) -> Option<(u32, u64, u64, u64)> {
    b.map(|(p, t, u, v)| (p, t.to_bits(), u.to_bits(), v.to_bits()))
}

/// Random soup in `[0, 1]^3 * scale + offset`, triangle sizes log-uniform in [1e-3, 0.3].
pub(super) fn soup(rng: &mut Rng, n: usize, scale: f64, offset: f64) -> Vec<[[f32; 3]; 3]> {
    (0..n)
        .map(|_| {
            let c = [0, 1, 2].map(|_| rng.f64());
            let size = 10f64.powf(rng.range(-3.0, -0.5));
            [0, 1, 2].map(|_| {
                let p = [0, 1, 2].map(|k| c[k] + size * rng.range(-0.5, 0.5));
                f32v(p.map(|x| x * scale + offset))
            })
        })
        .collect()
}

/// Random rays around the unit cube scaled and translated like `soup`.
pub(super) fn random_rays(rng: &mut Rng, n: usize, scale: f64, offset: f64) -> Vec<Ray> {
    (0..n)
        .map(|_| {
            let o = [0, 1, 2].map(|_| rng.range(-0.2, 1.2));
            let mut d = match rng.below(6) {
                0 => {
                    // Axis-aligned.
                    let mut d = [0.0; 3];
                    d[rng.below(3)] = if rng.f64() < 0.5 { -1.0 } else { 1.0 };
                    d
                }
                1 => {
                    // One zero component.
                    let mut d = rng.unit();
                    d[rng.below(3)] = 0.0;
                    d
                }
                _ => {
                    let target = [0, 1, 2].map(|_| rng.f64());
                    sub(target, o)
                }
            };
            // Non-unit directions of various lengths.
            let len = 10f64.powf(rng.range(-3.0, 3.0));
            d = d.map(|c| c * len);
            let dir = f32v(d.map(|c| c * scale));
            let tmax = if rng.f64() < 0.5 {
                f32::INFINITY
            } else {
                (rng.range(0.0, 2.0) / len) as f32
            };
            ray(f32v(o.map(|c| c * scale + offset)), dir, tmax)
        })
        .collect()
}

pub(super) fn check_against_brute_force(tris: &[[[f32; 3]; 3]], rays: &[Ray]) -> usize {
    let reference = Reference::new(tris);
    let mut hits = 0;
    for r in rays {
        let h = reference.closest_hit(r);
        let b = brute_closest(tris, r);
        assert_eq!(key(&h), brute_key(&b), "ray {r:?}");
        assert_eq!(reference.any_hit(r), brute_any(tris, r), "ray {r:?}");
        hits += usize::from(h.is_some());
    }
    let par = reference.closest_hits(rays);
    let seq: Vec<_> = rays.iter().map(|r| reference.closest_hit(r)).collect();
    assert_eq!(par, seq);
    hits
}
