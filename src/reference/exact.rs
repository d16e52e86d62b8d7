//! Exact degeneracy decisions on f64 triangles: whether a triangle has nonzero area (exact
//! cross products as Shewchuk expansions of error-free products) and its unit normal, accurate
//! for slivers too.

use super::{max_abs, sub};

/// Pairs of axes (p, q) of the cross product components: n[i] = e1[p] e2[q] - e1[q] e2[p].
const CROSS_AXES: [(usize, usize); 3] = [(1, 2), (2, 0), (0, 1)];

/// `(v1 - v0) x (v2 - v0)` in plain f64 and, per component, `|e1[p] e2[q]| + |e1[q] e2[p]|`.
/// The error of component `i` is below `2 eps * mag[i]` (differences, products and the final
/// subtraction each round once).
fn naive_cross(tri: &[[f64; 3]; 3]) -> ([f64; 3], [f64; 3]) {
    let e1 = sub(tri[1], tri[0]);
    let e2 = sub(tri[2], tri[0]);
    let mut n = [0.0; 3];
    let mut mag = [0.0; 3];
    for (i, &(p, q)) in CROSS_AXES.iter().enumerate() {
        let a = e1[p] * e2[q];
        let b = e1[q] * e2[p];
        n[i] = a - b;
        mag[i] = a.abs() + b.abs();
    }
    (n, mag)
}

/// Component `(p, q)` of `(b - a) x (c - a)` as an exact expansion: expanded into six products of
/// coordinates, each split exactly into value and rounding error with an FMA.
fn exact_cross_component(tri: &[[f64; 3]; 3], p: usize, q: usize) -> Expansion {
    let [a, b, c] = tri;
    let mut e = Expansion::default();
    for (x, y) in [
        (b[p], c[q]),
        (-b[p], a[q]),
        (-a[p], c[q]),
        (-b[q], c[p]),
        (b[q], a[p]),
        (a[q], c[p]),
    ] {
        e.add_product(x, y);
    }
    e
}

/// Whether a triangle can ever be hit: finite vertices and nonzero area (exact decision).
pub(super) fn triangle_is_hittable(tri: &[[f64; 3]; 3]) -> bool {
    if !tri.iter().flatten().all(|c| c.is_finite()) {
        return false;
    }
    let (n, mag) = naive_cross(tri);
    // Fast filter: a component clearly larger than its error bound is nonzero.
    if (0..3).any(|i| n[i].abs() > 4.0 * f64::EPSILON * mag[i]) {
        return true;
    }
    CROSS_AXES
        .iter()
        .any(|&(p, q)| !exact_cross_component(tri, p, q).is_zero())
}

/// Unit geometric normal `normalize((v1 - v0) x (v2 - v0))` of a non-degenerate triangle, with a
/// relative error of at most ~1e-12 (exact arithmetic for slivers where plain f64 is not enough).
pub(super) fn triangle_normal(tri: &[[f64; 3]; 3]) -> [f64; 3] {
    let (mut n, mag) = naive_cross(tri);
    let nmax = max_abs(&n);
    // Per-component error <= 2 eps * mag; accept if that is <= ~1e-12 of the largest component.
    if nmax < 1e-3 * (mag[0] + mag[1] + mag[2]) {
        n = CROSS_AXES.map(|(p, q)| exact_cross_component(tri, p, q).estimate());
    }
    // Scale before squaring to avoid overflow / underflow.
    let m = max_abs(&n);
    let s = n.map(|c| c / m);
    let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
    s.map(|c| c / len)
}

/// Error-free transformation: `a + b = s + e` exactly.
#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    let e = (a - (s - bb)) + (b - bb);
    (s, e)
}

/// Nonoverlapping expansion (Shewchuk 1997): an exact sum of floats, components in increasing
/// magnitude, zero components eliminated. Capacity: 12 components (six exact products).
#[derive(Clone, Copy, Debug, Default)]
struct Expansion {
    c: [f64; 12],
    n: usize,
}

impl Expansion {
    /// Grow-Expansion with zero elimination: adds `b` exactly.
    fn add(&mut self, b: f64) {
        let mut q = b;
        let mut m = 0;
        for i in 0..self.n {
            let (s, e) = two_sum(q, self.c[i]);
            if e != 0.0 {
                self.c[m] = e;
                m += 1;
            }
            q = s;
        }
        if q != 0.0 {
            self.c[m] = q;
            m += 1;
        }
        self.n = m;
    }

    /// Adds `x * y` exactly (the FMA residual is exact unless the product under/overflows).
    fn add_product(&mut self, x: f64, y: f64) {
        let p = x * y;
        let e = x.mul_add(y, -p);
        self.add(e);
        self.add(p);
    }

    /// The exact sum is zero iff there is no (nonzero) component.
    fn is_zero(&self) -> bool {
        self.n == 0
    }

    /// The sum, rounded (components added from smallest to largest).
    fn estimate(&self) -> f64 {
        self.c[..self.n].iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::fixtures::*;
    use crate::reference::{Reference, intersect_triangle, to_f64_tri};

    #[test]
    fn degenerate_triangles_are_never_hit() {
        let degenerate: Vec<[[f32; 3]; 3]> = vec![
            [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.5, 0.5]], // collinear (midpoint)
            [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [3.0, 3.0, 3.0]], // collinear
            [[0.1, 0.2, 0.3], [0.1, 0.2, 0.3], [0.7, -0.2, 0.4]], // repeated vertex
            [[0.1, 0.2, 0.3], [0.7, -0.2, 0.4], [0.1, 0.2, 0.3]], // repeated vertex
            [[0.3, 0.3, 0.3]; 3],                                // a point
            [
                [1e7, 1e7, 0.0],
                [1e7 + 1.0, 1e7, 0.0],
                [1e7 + 3.0, 1e7, 0.0],
            ], // collinear, x axis
            [[-1.0, 2.0, 0.5], [1.0, -2.0, 0.5], [0.0, 0.0, 0.5]], // collinear through 0
            [
                [1e-30, 2e-30, 0.0],
                [2e-30, 4e-30, 0.0],
                [3e-30, 6e-30, 0.0],
            ], // collinear, tiny
            [[f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], // non-finite
            [[f32::INFINITY, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        ];
        // Collinear in f32 but with 3 distinct "random" points on a line: p = a + k (b - a) with
        // dyadic k and coordinates with few bits.
        let mut degenerate = degenerate;
        let mut rng = Rng(5);
        for _ in 0..200 {
            let a = [0, 1, 2].map(|_| (rng.below(2048) as f32 - 1024.0) / 64.0);
            let d = [0, 1, 2].map(|_| (rng.below(64) as f32 - 32.0) / 16.0);
            let k = [rng.below(16) as f32 / 4.0, rng.below(16) as f32 / 4.0 - 4.0];
            degenerate.push([
                a,
                [0, 1, 2].map(|i| a[i] + k[0] * d[i]),
                [0, 1, 2].map(|i| a[i] + k[1] * d[i]),
            ]);
        }
        for tri in &degenerate {
            assert!(!triangle_is_hittable(&to_f64_tri(tri)), "{tri:?}");
        }
        // A valid triangle far behind everything, id last.
        let mut tris = degenerate.clone();
        tris.push([
            [-1e9, -1e9, -100.0],
            [1e9, -1e9, -100.0],
            [0.0, 1e9, -100.0],
        ]);
        let backstop = (tris.len() - 1) as u32;
        let reference = Reference::new(&tris);
        for tri in &degenerate {
            let t = to_f64_tri(tri);
            if !t.iter().flatten().all(|c| c.is_finite()) {
                continue;
            }
            for _ in 0..200 {
                // Aim at a point of the segment / point from a random direction.
                let (w0, w1) = (rng.f64(), rng.f64());
                let target = [0, 1, 2]
                    .map(|i| t[0][i] + w0 * (t[1][i] - t[0][i]) + w1 * (t[2][i] - t[0][i]));
                let scale = max_abs(&target).max(1.0);
                let mut dir = rng.unit();
                if dir[2] > 0.0 {
                    dir[2] = -dir[2];
                }
                dir[2] -= 0.1;
                let origin = f32v([0, 1, 2].map(|i| target[i] - scale * dir[i]));
                let r = ray(origin, f32v(dir), f32::INFINITY);
                let o = origin.map(f64::from);
                let d = r.dir.map(f64::from);
                assert_eq!(
                    intersect_triangle(o, d, f64::INFINITY, &t),
                    None,
                    "{tri:?} {r:?}"
                );
                let h = reference.closest_hit(&r);
                assert!(h.is_none_or(|h| h.prim == backstop), "{tri:?} {r:?} {h:?}");
            }
            // Rays exactly through the vertices.
            for v in tri {
                let r = ray(
                    [v[0] + 0.5, v[1] + 0.25, v[2] + 1.0],
                    [-0.5, -0.25, -1.0],
                    f32::INFINITY,
                );
                let h = reference.closest_hit(&r);
                assert!(h.is_none_or(|h| h.prim == backstop), "{tri:?} {r:?} {h:?}");
            }
        }
        // Only the backstop is in the BVH.
        assert_eq!(
            reference.tris.iter().map(|t| t.id).collect::<Vec<_>>(),
            vec![backstop]
        );
        // Nearly degenerate but not degenerate: hittable.
        let sliver = [
            [0.0, 0.0, 0.0],
            [1.0, 1.0, 1.0],
            [0.5, 0.5, 0.5 + 1.0 / (1u32 << 24) as f64],
        ];
        assert!(triangle_is_hittable(&sliver));
        let n = triangle_normal(&sliver);
        let s = std::f64::consts::FRAC_1_SQRT_2;
        assert!(
            (n[0] - s).abs() < 1e-15 && (n[1] + s).abs() < 1e-15 && n[2] == 0.0,
            "{n:?}"
        );
        // A scene made only of degenerate triangles, and an empty scene.
        for scene in [&degenerate[..], &[]] {
            let reference = Reference::new(scene);
            let r = ray([0.2, 0.1, -1.0], [0.0, 0.0, 1.0], f32::INFINITY);
            assert_eq!(reference.closest_hit(&r), None);
            assert!(!reference.any_hit(&r));
            assert_eq!(reference.closest_hits(&[r, r]), vec![None, None]);
        }
    }
}
