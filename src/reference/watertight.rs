//! The watertight ray/triangle test (Woop, Benthin, Wald, JCGT 2013) in f64, and the ray as
//! traversal uses it: the test's per-ray constants and the conservative slab test of node boxes.

use super::bvh::Node;
use super::exact::triangle_is_hittable;
use super::{PAD_REL, TFAR_SCALE, max_abs, sub};
use crate::scene::ray::Ray;

/// Watertight ray/triangle test (Woop, Benthin, Wald, JCGT 2013) in f64; returns (t, u, v) with t
/// in (0, tmax].
///
/// `u` and `v` are the barycentric coordinates of `tri[1]` and `tri[2]` (the hit point is
/// `(1 - u - v) tri[0] + u tri[1] + v tri[2]`); `t` is in units of `dir`'s length. Points on edges
/// and vertices count as inside, so a ray through a shared edge or vertex of a closed mesh hits at
/// least one of the triangles that share it. Returns `None` when the origin or direction has a
/// non-finite component, the direction is zero, `tmax` is NaN or not positive, the triangle has a
/// non-finite vertex or exactly zero area (collinear or repeated vertices, decided exactly for
/// inputs whose pairwise products neither overflow nor underflow, e.g. all `f32` values), or the
/// ray is parallel to the triangle's plane (edge-on).
pub fn intersect_triangle(
    origin: [f64; 3],
    dir: [f64; 3],
    tmax: f64,
    tri: &[[f64; 3]; 3],
) -> Option<(f64, f64, f64)> {
    let hit = Watertight::new(origin, dir)?.intersect(tri, tmax)?;
    // Validity of the triangle is checked after the (cheap) test rejected most triangles.
    triangle_is_hittable(tri).then_some(hit)
}

/// Per-ray constants of the watertight test.
#[derive(Clone, Copy, Debug)]
pub(super) struct Watertight {
    origin: [f64; 3],
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f64,
    sy: f64,
    sz: f64,
}

impl Watertight {
    /// `None` for a non-finite origin or direction or a zero direction.
    fn new(origin: [f64; 3], dir: [f64; 3]) -> Option<Watertight> {
        if !origin.iter().chain(&dir).all(|c| c.is_finite()) {
            return None;
        }
        // kz: dimension where the ray direction is maximal.
        let mut kz = 0;
        if dir[1].abs() > dir[kz].abs() {
            kz = 1;
        }
        if dir[2].abs() > dir[kz].abs() {
            kz = 2;
        }
        if dir[kz] == 0.0 {
            return None;
        }
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Swap kx and ky to preserve the winding direction of triangles.
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        Some(Watertight {
            origin,
            kx,
            ky,
            kz,
            sx: dir[kx] / dir[kz],
            sy: dir[ky] / dir[kz],
            sz: 1.0 / dir[kz],
        })
    }

    /// The test proper; `Some((t, u, v))` with `0 < t <= tmax`. Does not check the triangle for
    /// degeneracy beyond rejecting `det == 0`.
    #[inline]
    pub(super) fn intersect(&self, tri: &[[f64; 3]; 3], tmax: f64) -> Option<(f64, f64, f64)> {
        let Watertight {
            origin,
            kx,
            ky,
            kz,
            sx,
            sy,
            sz,
        } = *self;
        // Vertices relative to the ray origin.
        let a = sub(tri[0], origin);
        let b = sub(tri[1], origin);
        let c = sub(tri[2], origin);
        // Shear and scale of the vertices.
        let ax = a[kx] - sx * a[kz];
        let ay = a[ky] - sy * a[kz];
        let bx = b[kx] - sx * b[kz];
        let by = b[ky] - sy * b[kz];
        let cx = c[kx] - sx * c[kz];
        let cy = c[ky] - sy * c[kz];
        // Scaled barycentric coordinates (edge functions).
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        // Outside if the signs of the nonzero edge functions differ.
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 || det.is_nan() {
            return None;
        }
        // Scaled z-coordinates of the vertices and the scaled hit distance.
        let az = sz * a[kz];
        let bz = sz * b[kz];
        let cz = sz * c[kz];
        let t_scaled = u * az + v * bz + w * cz;
        // Sign test of the paper: t = T / det must be positive (det may have either sign).
        if (det > 0.0 && t_scaled <= 0.0) || (det < 0.0 && t_scaled >= 0.0) {
            return None;
        }
        let t = t_scaled / det;
        if !(t > 0.0 && t <= tmax) {
            return None;
        }
        Some((t, v / det, w / det))
    }
}

/// A ray prepared for traversal.
#[derive(Clone, Copy, Debug)]
pub(super) struct PreparedRay {
    pub(super) wt: Watertight,
    pub(super) tmax: f64,
    /// Per axis: the direction component is zero (the ray is parallel to the slabs).
    parallel: [bool; 3],
    /// Per axis: the direction component is negative (the near plane is `hi`).
    negative: [bool; 3],
    /// `1 / dir` (unused on parallel axes).
    inv_dir: [f64; 3],
    /// Absolute padding of node boxes for this ray (relative to the origin's magnitude).
    pad: f64,
    /// `pad` in units of t per axis: `pad * |1 / dir[i]|` (0 on parallel axes).
    pad_t: [f64; 3],
}

impl PreparedRay {
    pub(super) fn new(ray: &Ray) -> Option<PreparedRay> {
        let origin = ray.origin.map(f64::from);
        let dir = ray.dir.map(f64::from);
        let tmax = f64::from(ray.tmax);
        let wt = Watertight::new(origin, dir)?;
        if tmax.is_nan() || tmax <= 0.0 {
            return None;
        }
        let parallel = dir.map(|d| d == 0.0);
        let inv_dir = dir.map(|d| if d == 0.0 { 0.0 } else { 1.0 / d });
        let pad = PAD_REL * max_abs(&origin);
        Some(PreparedRay {
            wt,
            tmax,
            parallel,
            negative: dir.map(|d| d < 0.0),
            inv_dir,
            pad,
            pad_t: inv_dir.map(|i| pad * i.abs()),
        })
    }

    /// Conservative ray/box test against `[0, tlimit]`; returns the entry distance.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // one loop over the axes of several per-axis arrays
    pub(super) fn slab(&self, node: &Node, tlimit: f64) -> Option<f64> {
        let o = self.wt.origin;
        let mut tnear = 0.0f64;
        let mut tfar = tlimit;
        for i in 0..3 {
            let (lo, hi) = (f64::from(node.lo[i]), f64::from(node.hi[i]));
            if self.parallel[i] {
                // Parallel to the slab: inside iff the origin is between the planes. Handled
                // explicitly because (plane - origin) * inf is NaN when the origin is on a plane.
                if o[i] < lo - self.pad || o[i] > hi + self.pad {
                    return None;
                }
            } else {
                let (near, far) = if self.negative[i] { (hi, lo) } else { (lo, hi) };
                let tn = (near - o[i]) * self.inv_dir[i] - self.pad_t[i];
                let tf = (far - o[i]) * self.inv_dir[i] + self.pad_t[i];
                // Finite values: plain comparisons.
                if tn > tnear {
                    tnear = tn;
                }
                if tf < tfar {
                    tfar = tf;
                }
            }
        }
        (tnear <= tfar * TFAR_SCALE).then_some(tnear)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::Reference;
    use crate::reference::fixtures::*;

    /// UV sphere with shared vertices (no degenerate triangles at the poles).
    fn uv_sphere(nu: usize, nv: usize, radius: f64, center: [f64; 3]) -> Vec<[[f32; 3]; 3]> {
        let mut verts = vec![[0.0, 0.0, radius]];
        for j in 1..nv {
            let theta = std::f64::consts::PI * j as f64 / nv as f64;
            for i in 0..nu {
                let phi = 2.0 * std::f64::consts::PI * i as f64 / nu as f64;
                verts.push([
                    radius * theta.sin() * phi.cos(),
                    radius * theta.sin() * phi.sin(),
                    radius * theta.cos(),
                ]);
            }
        }
        verts.push([0.0, 0.0, -radius]);
        let verts: Vec<[f32; 3]> = verts
            .iter()
            .map(|p| f32v([p[0] + center[0], p[1] + center[1], p[2] + center[2]]))
            .collect();
        let south = verts.len() - 1;
        let ring = |j: usize, i: usize| 1 + (j - 1) * nu + i % nu;
        let mut tris = Vec::new();
        for i in 0..nu {
            tris.push([verts[0], verts[ring(1, i)], verts[ring(1, i + 1)]]);
            tris.push([
                verts[south],
                verts[ring(nv - 1, i + 1)],
                verts[ring(nv - 1, i)],
            ]);
        }
        for j in 1..nv - 1 {
            for i in 0..nu {
                let (a, b) = (ring(j, i), ring(j, i + 1));
                let (c, d) = (ring(j + 1, i), ring(j + 1, i + 1));
                tris.push([verts[a], verts[c], verts[d]]);
                tris.push([verts[a], verts[d], verts[b]]);
            }
        }
        tris
    }

    #[test]
    fn closed_sphere_is_watertight() {
        let mut rng = Rng(3);
        for (radius, center) in [
            (1.0, [0.0; 3]),
            (1e3, [1e4, -2e4, 3e3]),
            (1e-4, [0.0, 1e-3, 0.0]),
        ] {
            let tris = uv_sphere(200, 100, radius, center);
            assert_eq!(tris.len(), 2 * 200 * 99);
            let reference = Reference::new(&tris);
            let mut rays = Vec::new();
            for k in 0..20_000 {
                let p = rng.unit().map(|c| c * radius * 0.95 * rng.f64().cbrt());
                let origin = f32v([0, 1, 2].map(|i| p[i] + center[i]));
                let dir = match k % 10 {
                    0 => {
                        // Towards the poles and axis-aligned: through the shared pole vertices.
                        let mut d = [0.0f32; 3];
                        d[rng.below(3)] = if rng.f64() < 0.5 { -1.0 } else { 1.0 };
                        d
                    }
                    1 => {
                        // Exactly towards a mesh vertex (shared by several triangles).
                        let v = tris[rng.below(tris.len())][rng.below(3)];
                        [0, 1, 2].map(|i| v[i] - origin[i])
                    }
                    _ => f32v(rng.unit()),
                };
                rays.push(ray(origin, dir, f32::INFINITY));
            }
            // Rays from the exact center (through poles along z).
            let c = f32v(center);
            for d in [
                [0.0, 0.0, 1.0],
                [0.0, 0.0, -1.0],
                [1.0, 0.0, 0.0],
                [0.0, -1.0, 0.0],
            ] {
                rays.push(ray(c, d, f32::INFINITY));
            }
            let hits = reference.closest_hits(&rays);
            let misses = hits.iter().filter(|h| h.is_none()).count();
            assert_eq!(misses, 0, "radius {radius}");
            assert!(rays.iter().all(|r| reference.any_hit(r)));
            for h in hits.iter().flatten() {
                // Outward normals, points near the surface (the chords are within 2.5e-4 r).
                assert!(h.t > 0.0);
                assert!(h.normal.iter().all(|c| c.is_finite()));
            }
        }
    }

    /// Grid of `n` x `n` unit quads on the plane z = a x + b y (exact in f32), shared vertices.
    fn grid(n: usize, a: f32, b: f32) -> Vec<[[f32; 3]; 3]> {
        let v = |x: usize, y: usize| {
            let (x, y) = (x as f32, y as f32);
            [x, y, a * x + b * y]
        };
        let mut tris = Vec::new();
        for x in 0..n {
            for y in 0..n {
                tris.push([v(x, y), v(x + 1, y), v(x + 1, y + 1)]);
                tris.push([v(x, y), v(x + 1, y + 1), v(x, y + 1)]);
            }
        }
        tris
    }

    /// Dyadic offset (exact in f32 sums) not nearly parallel to the plane z = a x + b y.
    fn dyadic_offset(rng: &mut Rng, a: f32, b: f32) -> [f32; 3] {
        loop {
            let off = [
                rng.below(65) as f32 / 16.0 - 2.0,
                rng.below(65) as f32 / 16.0 - 2.0,
                (1 + rng.below(32)) as f32 / 8.0 * if rng.f64() < 0.5 { -1.0 } else { 1.0 },
            ];
            if (off[2] - a * off[0] - b * off[1]).abs() > 0.1 {
                return off;
            }
        }
    }

    #[test]
    fn rays_through_shared_edges_and_vertices_hit() {
        let mut rng = Rng(4);
        for (a, b) in [(0.0f32, 0.0f32), (1.0, 2.0), (-0.5, 0.25)] {
            let n = 10;
            let tris = grid(n, a, b);
            let reference = Reference::new(&tris);
            let mut count = 0;
            for _ in 0..4000 {
                // Target: an interior vertex, an edge midpoint (horizontal, vertical, diagonal)
                // or a quarter point of an edge; all exactly representable.
                let x = 1 + rng.below(n - 2);
                let y = 1 + rng.below(n - 2);
                let (fx, fy) = match rng.below(5) {
                    0 => (0.0, 0.0),
                    1 => (0.5, 0.0),
                    2 => (0.0, 0.5),
                    3 => (0.5, 0.5),
                    _ => (0.25, 0.25),
                };
                let (tx, ty) = (x as f32 + fx, y as f32 + fy);
                let target = [tx, ty, a * tx + b * ty];
                // Dyadic offsets keep origin = target + offset and dir = -offset exact, so the
                // ray passes exactly through the target at t = 1.
                let off = dyadic_offset(&mut rng, a, b);
                let origin = [0, 1, 2].map(|i| target[i] + off[i]);
                let dir = off.map(|c| -c);
                let r = ray(origin, dir, f32::INFINITY);
                let h = reference.closest_hit(&r);
                let h = h.unwrap_or_else(|| panic!("miss through {target:?}: {r:?}"));
                assert!((h.t - 1.0).abs() < 1e-12, "{h:?}");
                assert!(reference.any_hit(&r));
                count += 1;
            }
            assert_eq!(count, 4000);
        }
        // Irregular fan around a vertex in a tilted plane: rays at the center and at spokes.
        let center = [0.25f32, -0.5, 0.75];
        let angles = [0.0, 0.7, 1.5, 2.0, 3.3, 4.1, 5.0];
        let rim: Vec<[f32; 3]> = angles
            .iter()
            .map(|&t: &f64| {
                f32v([
                    0.25 + t.cos(),
                    -0.5 + t.sin(),
                    0.75 + 0.3 * t.cos() - 0.2 * t.sin(),
                ])
            })
            .collect();
        let tris: Vec<_> = (0..rim.len())
            .map(|i| [center, rim[i], rim[(i + 1) % rim.len()]])
            .collect();
        let reference = Reference::new(&tris);
        for _ in 0..2000 {
            let off = dyadic_offset(&mut rng, 0.3, -0.2);
            let origin = [0, 1, 2].map(|i| center[i] + off[i]);
            let r = ray(origin, off.map(|c| -c), f32::INFINITY);
            assert!(reference.closest_hit(&r).is_some(), "{r:?}");
            // Points on the spokes (shared edges), rounded to f32: still well inside the fan.
            let k = rng.below(rim.len());
            let s = rng.range(0.05, 0.95);
            let p = [0, 1, 2].map(|i| f64::from(center[i]) + s * f64::from(rim[k][i] - center[i]));
            let origin = f32v([0, 1, 2].map(|i| p[i] + f64::from(off[i])));
            let dir = f32v([0, 1, 2].map(|i| p[i] - f64::from(origin[i])));
            let r = ray(origin, dir, f32::INFINITY);
            assert!(reference.closest_hit(&r).is_some(), "{r:?}");
        }
    }

    #[test]
    fn axis_aligned_rays_hit_axis_aligned_quads() {
        // Unit quads in the planes x = 2, y = -3, z = 0.5 (flat, zero-volume boxes).
        let quad = |axis: usize, c: f32| {
            let p = |u: f32, v: f32| {
                let mut p = [0.0f32; 3];
                p[axis] = c;
                p[(axis + 1) % 3] = u;
                p[(axis + 2) % 3] = v;
                p
            };
            [
                [p(0.0, 0.0), p(1.0, 0.0), p(1.0, 1.0)],
                [p(0.0, 0.0), p(1.0, 1.0), p(0.0, 1.0)],
            ]
        };
        let mut rng = Rng(6);
        for (axis, c) in [(0, 2.0f32), (1, -3.0), (2, 0.5)] {
            let tris = quad(axis, c);
            let reference = Reference::new(&tris);
            for k in 0..2000 {
                let (u, v) = match k % 4 {
                    // On the quad's boundary planes and its diagonal (origin on a slab plane).
                    0 => (rng.below(3) as f32 * 0.5, rng.f64() as f32),
                    1 => (rng.f64() as f32, rng.below(3) as f32 * 0.5),
                    2 => {
                        let s = rng.f64() as f32;
                        (s, s)
                    }
                    _ => (rng.f64() as f32, rng.f64() as f32),
                };
                for sign in [1.0f32, -1.0] {
                    let mut origin = [0.0f32; 3];
                    origin[axis] = c - 4.0 * sign;
                    origin[(axis + 1) % 3] = u;
                    origin[(axis + 2) % 3] = v;
                    let mut dir = [0.0f32; 3];
                    dir[axis] = 2.0 * sign;
                    let r = ray(origin, dir, f32::INFINITY);
                    let h = reference.closest_hit(&r).unwrap_or_else(|| panic!("{r:?}"));
                    assert_eq!(h.t, 2.0);
                    assert_eq!(key(&Some(h)), brute_key(&brute_closest(&tris, &r)));
                    assert!(reference.any_hit(&r));
                    // Just outside the quad: miss.
                    origin[(axis + 1) % 3] = -0.01;
                    assert_eq!(
                        reference.closest_hit(&ray(origin, dir, f32::INFINITY)),
                        None
                    );
                }
            }
        }
    }

    #[test]
    fn slab_handles_zero_direction_and_flat_boxes() {
        let node = Node {
            lo: [0.0, 0.0, 1.0],
            hi: [1.0, 1.0, 1.0],
            first: 0,
            count: 0,
        };
        let prep = |o: [f32; 3], d: [f32; 3]| PreparedRay::new(&ray(o, d, f32::INFINITY)).unwrap();
        // Origin exactly on the x = 0 and y = 1 slab planes, direction zero in x and y.
        let r = prep([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        assert_eq!(r.slab(&node, f64::INFINITY), Some(1.0 - r.pad_t[2]));
        // Origin exactly on the flat box (z = 1), moving in it.
        let r = prep([0.5, 0.5, 1.0], [1.0, 0.0, 0.0]);
        assert_eq!(r.slab(&node, f64::INFINITY), Some(0.0));
        // Outside in a zero-direction axis.
        let r = prep([1.5, 0.5, 0.0], [0.0, 0.0, 1.0]);
        assert_eq!(r.slab(&node, f64::INFINITY), None);
        // Box behind the origin, beyond tlimit.
        let r = prep([0.5, 0.5, 2.0], [0.0, 0.0, 1.0]);
        assert_eq!(r.slab(&node, f64::INFINITY), None);
        let r = prep([0.5, 0.5, 0.0], [0.0, 0.0, 1.0]);
        assert_eq!(r.slab(&node, 0.5), None);
        assert!(r.slab(&node, 1.0).is_some());
    }
}
