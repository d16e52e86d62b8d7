//! CPU reference ray tracer: the oracle GPU kernels are tested against.
//!
//! Deliberately simple and independent of the GPU code: its own BVH, its own traversal and its
//! own ray/triangle test, all arithmetic in `f64`. Depends only on `std` and `rayon`.
//!
//! * Inputs (`f32` vertices and rays) enter every computation converted exactly to `f64`
//!   (`f32 -> f64` is lossless; vertices are kept as the given `f32` values, which halves the
//!   memory and cache footprint, and widened where they are used).
//! * Intersection: the watertight test of Woop, Benthin and Wald (JCGT 2013) in `f64`, see
//!   [`intersect_triangle`]. Edges and vertices count as inside, so rays through shared edges
//!   and vertices of a closed mesh never slip through. Triangles with a non-finite vertex or
//!   exactly zero area (collinear or repeated vertices; decided with exact arithmetic) are never
//!   hit.
//! * BVH: binned SAH on the longest centroid axis (median splits below depth 48 or when SAH
//!   cannot separate), leaves of at most 4 triangles, built iteratively with an explicit stack
//!   (no recursion; below the top of the tree, subtrees are built in parallel) into a flat array
//!   of sibling pairs. Traversal: explicit stack, nearer child first, culled by the current
//!   closest `t`, `f64` slab test with explicit handling of zero direction components.
//!   [`Reference::closest_hits`] traces in parallel, in a spatially sorted order.
//! * Exactness of the BVH: node boxes are padded by `1e-8` times the largest absolute coordinate
//!   of the box and of the ray origin (then rounded outwards to `f32`), and the far slab distance
//!   is scaled by Ize's `1 + 2 gamma(3)`. That is far more than the rounding errors of the slab
//!   test and of the triangle test, so the BVH never culls a triangle that the triangle test
//!   reports: [`Reference::closest_hit`] returns exactly what a brute-force loop over all
//!   triangles with [`intersect_triangle`] returns (same primitive, bit-identical `t`, `u`, `v`)
//!   as long as the distance from the ray origin to a triangle is below ~1e6 times the
//!   triangle's size. (Beyond that, the triangle test's own result is dominated by rounding.)
//!
//! Here: the API and traversal; `bvh`: the build; `watertight`: the triangle and slab tests;
//! `exact`: the degeneracy decisions; `shade`: the shading reference image.

mod bvh;
mod exact;
#[cfg(test)]
mod fixtures;
pub mod shade;
mod watertight;

pub use watertight::intersect_triangle;

use crate::scene::ray::Ray;
use bvh::{Aabb, Node, NodePair, PrimRef, build_bvh};
use exact::{triangle_is_hittable, triangle_normal};
use rayon::prelude::*;
use watertight::PreparedRay;

/// The closest intersection of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit, in `(0, tmax]`.
    pub t: f64,
    /// Primitive id: index of the triangle in the slice given to [`Reference::new`].
    pub prim: u32,
    /// Unit geometric normal `normalize((v1 - v0) x (v2 - v0))`, not flipped towards the ray.
    pub normal: [f64; 3],
    /// Barycentric coordinate of `v1` (the hit point is `(1 - u - v) v0 + u v1 + v v2`).
    pub u: f64,
    /// Barycentric coordinate of `v2`.
    pub v: f64,
}

/// Reference scene: the hittable triangles and a BVH over them.
#[derive(Clone, Debug)]
pub struct Reference {
    /// Flat node array, as pairs of siblings sharing a cache line. Node id `i` is
    /// `pairs[i / 2].0[i % 2]`; node 0 is the root (no pairs when no triangle can be hit), node 1
    /// is unused.
    pairs: Vec<NodePair>,
    /// Hittable triangles in leaf order, with their primitive ids.
    tris: Vec<LeafTri>,
}

/// Relative padding of node boxes (times the box's largest absolute coordinate) and of the ray
/// (times the origin's largest absolute coordinate). Rounding moves the triangle test's edges by
/// about 10 ulps (1.1e-16 each) of the origin-to-vertex distance `D` times `D / size` of the
/// triangle; the slab test's errors are a few ulps of the same distances. The padding covers
/// both up to `D / size` of ~1e6.
const PAD_REL: f64 = 1e-8;
/// gamma(3) = 3u / (1 - 3u) with u = 2^-53 (Pharr, Jakob, Humphreys, PBRT 3rd ed., 3.9).
const GAMMA3: f64 = 3.0 * (f64::EPSILON * 0.5) / (1.0 - 3.0 * (f64::EPSILON * 0.5));
/// Ize's conservative factor for the far slab distance: `1 + 2 gamma(3)`.
const TFAR_SCALE: f64 = 1.0 + 2.0 * GAMMA3;

impl Reference {
    /// Builds the reference from triangles in primitive-id order (index = primitive id).
    ///
    /// Triangles with a non-finite vertex or with zero area are left out: they are never hit.
    ///
    /// # Panics
    /// If there are more than `u32::MAX` triangles.
    pub fn new(triangles: &[[[f32; 3]; 3]]) -> Reference {
        assert!(
            triangles.len() <= u32::MAX as usize,
            "at most u32::MAX triangles are supported"
        );
        let mut prims: Vec<PrimRef> = triangles
            .par_iter()
            .enumerate()
            .filter_map(|(id, t)| {
                let tri = to_f64_tri(t);
                triangle_is_hittable(&tri).then(|| PrimRef {
                    bounds: Aabb::of_triangle(&tri),
                    id: id as u32,
                })
            })
            .collect();
        let pairs = build_bvh(&mut prims);
        let tris = prims
            .par_iter()
            .map(|p| LeafTri {
                v: triangles[p.id as usize],
                id: p.id,
            })
            .collect();
        Reference { pairs, tris }
    }

    /// Closest hit with `t` in `(0, tmax]`; among hits at the same `t`, the lowest primitive id.
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        self.closest_hit_with_stack(ray, &mut Vec::with_capacity(64))
    }

    /// Whether the ray hits any triangle with `t` in `(0, tmax)` (shadow / ambient occlusion).
    pub fn any_hit(&self, ray: &Ray) -> bool {
        let Some(r) = PreparedRay::new(ray) else {
            return false;
        };
        if self.pairs.is_empty() {
            return false;
        }
        let mut stack: Vec<(u32, f64)> = Vec::with_capacity(64);
        if let Some(tn) = r.slab(self.node(0), r.tmax) {
            stack.push((0, tn));
        }
        while let Some((ni, _)) = stack.pop() {
            let node = self.node(ni);
            if node.count > 0 {
                let first = node.first as usize;
                for tri in &self.tris[first..first + node.count as usize] {
                    if let Some((t, _, _)) = r.wt.intersect(&tri.f64(), r.tmax)
                        && t < r.tmax
                    {
                        return true;
                    }
                }
            } else {
                for child in [2 * node.first, 2 * node.first + 1] {
                    if let Some(tn) = r.slab(self.node(child), r.tmax) {
                        stack.push((child, tn));
                    }
                }
            }
        }
        false
    }

    /// [`Reference::closest_hit`] for every ray, in parallel (rayon).
    ///
    /// The rays are traced in a spatially coherent order (sorted by direction octant and Morton
    /// code of the origin) for better cache use; each result depends only on its own ray.
    pub fn closest_hits(&self, rays: &[Ray]) -> Vec<Option<Hit>> {
        let order = coherent_order(rays);
        let sorted: Vec<Option<Hit>> = order
            .par_iter()
            .map_init(
                || Vec::with_capacity(64),
                |stack, &i| self.closest_hit_with_stack(&rays[i as usize], stack),
            )
            .collect();
        let mut hits = vec![None; rays.len()];
        for (&i, h) in order.iter().zip(sorted) {
            hits[i as usize] = h;
        }
        hits
    }

    fn node(&self, id: u32) -> &Node {
        &self.pairs[id as usize / 2].0[id as usize % 2]
    }

    fn closest_hit_with_stack(&self, ray: &Ray, stack: &mut Vec<(u32, f64)>) -> Option<Hit> {
        let r = PreparedRay::new(ray)?;
        if self.pairs.is_empty() {
            return None;
        }
        // (t, index into tris, u, v)
        let mut best: Option<(f64, usize, f64, f64)> = None;
        let mut limit = r.tmax;
        stack.clear();
        if let Some(tn) = r.slab(self.node(0), limit) {
            stack.push((0, tn));
        }
        while let Some((ni, tnear)) = stack.pop() {
            // Cull by the current closest t (conservatively: ties must still be visited).
            if tnear > limit * TFAR_SCALE {
                continue;
            }
            let node = self.node(ni);
            if node.count > 0 {
                let first = node.first as usize;
                for k in first..first + node.count as usize {
                    let tri = &self.tris[k];
                    if let Some((t, u, v)) = r.wt.intersect(&tri.f64(), limit) {
                        let better = match best {
                            None => true,
                            Some((bt, bk, _, _)) => {
                                t < bt || (t == bt && tri.id < self.tris[bk].id)
                            }
                        };
                        if better {
                            best = Some((t, k, u, v));
                            limit = t;
                        }
                    }
                }
            } else {
                let (l, rc) = (2 * node.first, 2 * node.first + 1);
                let hl = r.slab(self.node(l), limit);
                let hr = r.slab(self.node(rc), limit);
                match (hl, hr) {
                    (Some(tl), Some(tr)) => {
                        // Push the farther child first so the nearer one is visited first.
                        if tl <= tr {
                            stack.push((rc, tr));
                            stack.push((l, tl));
                        } else {
                            stack.push((l, tl));
                            stack.push((rc, tr));
                        }
                    }
                    (Some(tl), None) => stack.push((l, tl)),
                    (None, Some(tr)) => stack.push((rc, tr)),
                    (None, None) => {}
                }
            }
        }
        best.map(|(t, k, u, v)| Hit {
            t,
            prim: self.tris[k].id,
            normal: triangle_normal(&self.tris[k].f64()),
            u,
            v,
        })
    }
}

/// Ray indices sorted by (direction octant, Morton code of the origin within the origins'
/// bounds).
fn coherent_order(rays: &[Ray]) -> Vec<u32> {
    assert!(
        rays.len() <= u32::MAX as usize,
        "at most u32::MAX rays per call"
    );
    let bounds = rays
        .par_iter()
        .fold(
            || Aabb::EMPTY,
            |mut b, r| {
                let o = r.origin.map(f64::from);
                if o.iter().all(|c| c.is_finite()) {
                    b.grow(o);
                }
                b
            },
        )
        .reduce(|| Aabb::EMPTY, |a, b| a.union(&b));
    let ext = sub(bounds.hi, bounds.lo);
    let scale = ext.map(|e| if e > 0.0 { 1048575.0 / e } else { 0.0 });
    let mut keys: Vec<(u64, u32)> = rays
        .par_iter()
        .enumerate()
        .map(|(i, r)| {
            let mut key = 0u64;
            for (k, (&o, &d)) in r.origin.iter().zip(&r.dir).enumerate() {
                // Saturating casts: NaN -> 0.
                let q = ((f64::from(o) - bounds.lo[k]) * scale[k]) as u64;
                key |= spread_bits(q.min(1048575)) << k;
                if d < 0.0 {
                    key |= 1 << (60 + k);
                }
            }
            (key, i as u32)
        })
        .collect();
    keys.par_sort_unstable();
    keys.into_iter().map(|(_, i)| i).collect()
}

/// Spreads the low 20 bits of `x` to every third bit (bit i to bit 3i).
fn spread_bits(x: u64) -> u64 {
    let mut r = 0;
    for i in 0..20 {
        r |= ((x >> i) & 1) << (3 * i);
    }
    r
}

/// A triangle as given (f32 vertices, converted exactly to f64 for every computation) and its
/// primitive id.
#[derive(Clone, Copy, Debug)]
struct LeafTri {
    v: [[f32; 3]; 3],
    id: u32,
}

impl LeafTri {
    #[inline(always)]
    fn f64(&self) -> [[f64; 3]; 3] {
        to_f64_tri(&self.v)
    }
}

fn to_f64_tri(t: &[[f32; 3]; 3]) -> [[f64; 3]; 3] {
    t.map(|p| p.map(f64::from))
}

#[inline]
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn max_abs(p: &[f64; 3]) -> f64 {
    p[0].abs().max(p[1].abs()).max(p[2].abs())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fixtures::*;

    #[test]
    fn bvh_matches_brute_force_with_exact_ties() {
        // Duplicated triangles (ties in t) with shuffled ids, coplanar neighbours and a grid of
        // axis-aligned quads: lowest id must win.
        let mut rng = Rng(2);
        let mut tris = soup(&mut rng, 300, 1.0, 0.0);
        let copies: Vec<_> = tris.iter().step_by(3).copied().collect();
        tris.extend(copies);
        for i in 0..tris.len() {
            let j = rng.below(tris.len());
            tris.swap(i, j);
        }
        for x in 0..4 {
            for y in 0..4 {
                let (x, y) = (x as f32 * 0.25, y as f32 * 0.25);
                let q = [
                    [x, y, 0.5],
                    [x + 0.25, y, 0.5],
                    [x + 0.25, y + 0.25, 0.5],
                    [x, y + 0.25, 0.5],
                ];
                tris.push([q[0], q[1], q[2]]);
                tris.push([q[0], q[2], q[3]]);
                tris.push([q[0], q[2], q[3]]);
            }
        }
        let mut rays = random_rays(&mut rng, 1500, 1.0, 0.0);
        // Vertical rays through the quads (some through grid vertices and edges exactly).
        for _ in 0..500 {
            let x = rng.below(17) as f32 / 16.0;
            let y = if rng.f64() < 0.5 {
                rng.f64() as f32
            } else {
                rng.below(17) as f32 / 16.0
            };
            rays.push(ray([x, y, -1.0], [0.0, 0.0, 1.0], f32::INFINITY));
        }
        check_against_brute_force(&tris, &rays);
    }

    #[test]
    fn duplicate_triangles_report_lowest_id() {
        let t = [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]];
        let mut tris = vec![[[5.0f32, 5.0, 5.0]; 3]; 10];
        tris[7] = t;
        tris[3] = t;
        tris[9] = t;
        let reference = Reference::new(&tris);
        let h = reference.closest_hit(&ray([0.25, 0.25, 0.0], [0.0, 0.0, 1.0], f32::INFINITY));
        assert_eq!(h.map(|h| (h.prim, h.t)), Some((3, 1.0)));
    }

    #[test]
    fn hit_fields() {
        let tris = [[[1.0f32, 0.0, 2.0], [3.0, 0.0, 2.0], [1.0, 4.0, 2.0]]];
        let reference = Reference::new(&tris);
        // Hit point (2, 1, 2) = 0.25 v0 + 0.5 v1 + 0.25 v2; dir has length 2.
        let h = reference
            .closest_hit(&ray([2.0, 1.0, 0.0], [0.0, 0.0, 2.0], f32::INFINITY))
            .unwrap();
        assert_eq!(h.prim, 0);
        assert_eq!(h.t, 1.0);
        assert!(
            (h.u - 0.5).abs() < 1e-15 && (h.v - 0.25).abs() < 1e-15,
            "{h:?}"
        );
        assert_eq!(h.normal, [0.0, 0.0, 1.0]);
        // Reversed winding flips the normal; the hit is the same from the other side.
        let tris = [[[1.0f32, 0.0, 2.0], [1.0, 4.0, 2.0], [3.0, 0.0, 2.0]]];
        let reference = Reference::new(&tris);
        let h = reference
            .closest_hit(&ray([2.0, 1.0, 4.0], [0.0, 0.0, -1.0], f32::INFINITY))
            .unwrap();
        assert_eq!(h.t, 2.0);
        assert_eq!(h.normal, [0.0, 0.0, -1.0]);
        assert!(
            (h.u - 0.25).abs() < 1e-15 && (h.v - 0.5).abs() < 1e-15,
            "{h:?}"
        );
        // Tilted triangle: unit normal, hit point reproduced by the barycentrics.
        let tri = [[0.1f32, 0.2, 0.3], [1.7, -0.4, 0.9], [-0.3, 1.1, 2.5]];
        let reference = Reference::new(&[tri]);
        let (o, d) = ([0.2f32, 0.3, -2.0], [0.3f32, 0.01, 3.25]);
        let h = reference.closest_hit(&ray(o, d, f32::INFINITY)).unwrap();
        let n = h.normal;
        assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-15);
        let t = to_f64_tri(&tri);
        let e1 = sub(t[1], t[0]);
        let e2 = sub(t[2], t[0]);
        let c = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let cl = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        for i in 0..3 {
            assert!((n[i] - c[i] / cl).abs() < 1e-14);
            let p = f64::from(o[i]) + h.t * f64::from(d[i]);
            let q = (1.0 - h.u - h.v) * t[0][i] + h.u * t[1][i] + h.v * t[2][i];
            assert!((p - q).abs() < 1e-12, "{p} {q}");
        }
    }

    #[test]
    fn invalid_rays_hit_nothing() {
        let mut rng = Rng(7);
        let mut tris = soup(&mut rng, 200, 1.0, 0.0);
        tris.push([[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5]]);
        tris.push([[1.0, 1.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5]]);
        let reference = Reference::new(&tris);
        let good = ray([0.5, 0.5, -1.0], [0.0, 0.0, 1.0], f32::INFINITY);
        assert!(reference.closest_hit(&good).is_some());
        let mut bad = Vec::new();
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            for i in 0..3 {
                let mut r = good;
                r.origin[i] = x;
                bad.push(r);
                let mut r = good;
                r.dir[i] = x;
                bad.push(r);
            }
            let mut r = good;
            r.tmax = x;
            if x != f32::INFINITY {
                bad.push(r);
            }
        }
        bad.push(ray([0.5, 0.5, -1.0], [0.0, 0.0, 0.0], f32::INFINITY));
        bad.push(ray([0.5, 0.5, -1.0], [0.0, 0.0, -0.0], 1.0));
        bad.push(ray([0.5, 0.5, -1.0], [0.0, 0.0, 1.0], 0.0));
        bad.push(ray([0.5, 0.5, -1.0], [0.0, 0.0, 1.0], -5.0));
        for r in &bad {
            assert_eq!(reference.closest_hit(r), None, "{r:?}");
            assert!(!reference.any_hit(r), "{r:?}");
            let o = r.origin.map(f64::from);
            let d = r.dir.map(f64::from);
            for t in &tris {
                assert_eq!(
                    intersect_triangle(o, d, f64::from(r.tmax), &to_f64_tri(t)),
                    None
                );
            }
        }
        assert!(reference.closest_hits(&bad).iter().all(Option::is_none));
    }

    #[test]
    fn tmax_is_respected() {
        let tris = [[[0.0f32, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]];
        let reference = Reference::new(&tris);
        let at = |tmax: f32| ray([0.25, 0.25, -1.0], [0.0, 0.0, 0.5], tmax);
        // Hit at t = 4 exactly.
        assert_eq!(reference.closest_hit(&at(4.0)).map(|h| h.t), Some(4.0));
        assert_eq!(reference.closest_hit(&at(4.0f32.next_down())), None);
        assert!(reference.closest_hit(&at(4.0f32.next_up())).is_some());
        // any_hit: open interval.
        assert!(!reference.any_hit(&at(4.0)));
        assert!(reference.any_hit(&at(4.0f32.next_up())));
        assert!(reference.any_hit(&at(f32::INFINITY)));
        // Behind the origin: t <= 0 is never a hit.
        let back = ray([0.25, 0.25, 2.0], [0.0, 0.0, 1.0], f32::INFINITY);
        assert_eq!(reference.closest_hit(&back), None);
        // Origin on the triangle: t = 0 is not a hit.
        let on = ray([0.25, 0.25, 1.0], [0.0, 0.0, 1.0], f32::INFINITY);
        assert_eq!(reference.closest_hit(&on), None);
        assert!(!reference.any_hit(&on));
        // Random soup: closest hit with tmax just below / at the found t.
        let mut rng = Rng(8);
        let tris = soup(&mut rng, 500, 1.0, 0.0);
        let reference = Reference::new(&tris);
        let mut checked = 0;
        for r in random_rays(&mut rng, 2000, 1.0, 0.0) {
            let Some(h) = reference.closest_hit(&r) else {
                continue;
            };
            assert!(h.t <= f64::from(r.tmax));
            let below = (h.t as f32).next_down();
            if f64::from(below) < h.t && below > 0.0 {
                let mut r2 = r;
                r2.tmax = below;
                assert!(
                    reference
                        .closest_hit(&r2)
                        .is_none_or(|h2| h2.t <= f64::from(below))
                );
                checked += 1;
            }
        }
        assert!(checked > 100);
    }

    #[test]
    fn any_hit_agrees_with_closest_hit() {
        let mut rng = Rng(9);
        let tris = soup(&mut rng, 3000, 1.0, 0.0);
        let reference = Reference::new(&tris);
        let rays = random_rays(&mut rng, 5000, 1.0, 0.0);
        let closest = reference.closest_hits(&rays);
        let mut hits = 0;
        for (r, h) in rays.iter().zip(&closest) {
            // Equal unless the closest hit is exactly at tmax (open vs closed interval).
            if h.is_some_and(|h| h.t == f64::from(r.tmax)) {
                continue;
            }
            assert_eq!(reference.any_hit(r), h.is_some(), "{r:?}");
            hits += usize::from(h.is_some());
        }
        assert!(hits > 500);
    }
}
