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

pub mod shade;

use rayon::prelude::*;

/// A ray: origin and direction in f32 as the GPU gets them (the direction need not be unit).
///
/// Hits are reported at `origin + t * dir` for `t` in `(0, tmax]` ([`Reference::closest_hit`]) or
/// `(0, tmax)` ([`Reference::any_hit`]); `t` is in units of `dir`'s length. A ray whose origin or
/// direction has a NaN or infinite component, whose direction is zero, or whose `tmax` is NaN or
/// not positive hits nothing. `tmax` may be `f32::INFINITY`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
    pub tmax: f32,
}

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

/// Maximum number of triangles in a leaf.
const LEAF_SIZE: usize = 4;
/// Number of SAH bins.
const NUM_BINS: usize = 32;
/// Below this depth splits are binned SAH; deeper, median splits bound the depth of the tree
/// (and the build time) even for pathological inputs.
const MAX_SAH_DEPTH: u32 = 48;
/// Ranges at least this long are binned in parallel.
const PAR_BIN_THRESHOLD: usize = 1 << 16;
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
struct Watertight {
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
    fn intersect(&self, tri: &[[f64; 3]; 3], tmax: f64) -> Option<(f64, f64, f64)> {
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
struct PreparedRay {
    wt: Watertight,
    tmax: f64,
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
    fn new(ray: &Ray) -> Option<PreparedRay> {
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
    fn slab(&self, node: &Node, tlimit: f64) -> Option<f64> {
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

/// BVH node (32 bytes). Interior nodes have `count == 0` and children `2 first` and
/// `2 first + 1` (the pair `first`); leaves have `1..=LEAF_SIZE` triangles `first..first + count`.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C)]
struct Node {
    /// Padded bounds, rounded outwards to f32 (the slab test itself is in f64).
    lo: [f32; 3],
    hi: [f32; 3],
    first: u32,
    count: u32,
}

impl Node {
    /// The node with its child link (if interior) shifted by `shift` pairs.
    fn relinked(mut self, shift: u32) -> Node {
        if self.count == 0 {
            self.first += shift;
        }
        self
    }
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

/// Two sibling nodes in one 64-byte cache line.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
struct NodePair([Node; 2]);

#[derive(Clone, Copy, Debug)]
struct Aabb {
    lo: [f64; 3],
    hi: [f64; 3],
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: [f64::INFINITY; 3],
        hi: [f64::NEG_INFINITY; 3],
    };

    fn of_triangle(tri: &[[f64; 3]; 3]) -> Aabb {
        let mut b = Aabb::EMPTY;
        for p in tri {
            b.grow(*p);
        }
        b
    }

    fn grow(&mut self, p: [f64; 3]) {
        for ((lo, hi), c) in self.lo.iter_mut().zip(&mut self.hi).zip(p) {
            *lo = lo.min(c);
            *hi = hi.max(c);
        }
    }

    fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            lo: std::array::from_fn(|i| self.lo[i].min(o.lo[i])),
            hi: std::array::from_fn(|i| self.hi[i].max(o.hi[i])),
        }
    }

    fn is_empty(&self) -> bool {
        self.lo[0] > self.hi[0]
    }

    fn half_area(&self) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        let d = sub(self.hi, self.lo);
        d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
    }

    /// Node with these bounds padded by `PAD_REL` times the largest absolute coordinate, then
    /// rounded outwards to f32.
    fn padded_node(&self) -> Node {
        let pad = PAD_REL * max_abs(&self.lo).max(max_abs(&self.hi));
        Node {
            lo: self.lo.map(|c| f32_down(c - pad)),
            hi: self.hi.map(|c| f32_up(c + pad)),
            first: 0,
            count: 0,
        }
    }
}

/// A triangle during the build: its bounds and primitive id.
#[derive(Clone, Copy, Debug)]
struct PrimRef {
    bounds: Aabb,
    id: u32,
}

impl PrimRef {
    fn centroid(&self, axis: usize) -> f64 {
        (self.bounds.lo[axis] + self.bounds.hi[axis]) * 0.5
    }

    fn centroid3(&self) -> [f64; 3] {
        std::array::from_fn(|i| self.centroid(i))
    }
}

#[derive(Clone, Copy, Debug)]
struct Bin {
    bounds: Aabb,
    cbounds: Aabb,
    count: usize,
}

impl Bin {
    const EMPTY: Bin = Bin {
        bounds: Aabb::EMPTY,
        cbounds: Aabb::EMPTY,
        count: 0,
    };

    fn merge(&self, o: &Bin) -> Bin {
        Bin {
            bounds: self.bounds.union(&o.bounds),
            cbounds: self.cbounds.union(&o.cbounds),
            count: self.count + o.count,
        }
    }
}

/// Bounds and centroid bounds of a range of primitives.
fn range_bounds(prims: &[PrimRef]) -> Bin {
    let fold = |chunk: &[PrimRef]| {
        let mut b = Bin::EMPTY;
        for p in chunk {
            b.bounds = b.bounds.union(&p.bounds);
            b.cbounds.grow(p.centroid3());
        }
        b.count = chunk.len();
        b
    };
    if prims.len() >= PAR_BIN_THRESHOLD {
        prims
            .par_chunks(PAR_BIN_THRESHOLD / 4)
            .map(fold)
            .reduce(|| Bin::EMPTY, |a, b| a.merge(&b))
    } else {
        fold(prims)
    }
}

/// The SAH bin of a primitive (the same computation for binning and partitioning).
#[inline]
fn bin_index(p: &PrimRef, axis: usize, lo: f64, scale: f64) -> usize {
    // `as usize` saturates (negative -> 0).
    (((p.centroid(axis) - lo) * scale) as usize).min(NUM_BINS - 1)
}

/// A node to build: node id `node` over `prims[start..end]` with bounds `info`.
#[derive(Clone, Copy, Debug)]
struct BuildTask {
    node: usize,
    start: usize,
    end: usize,
    info: Bin,
    depth: u32,
}

/// Builds the BVH over `prims`, reordering them into leaf order. Iterative (explicit stack): the
/// top of the tree is built first, down to subtrees of at most ~1/64 of the triangles, which are
/// then built independently in parallel and appended to the node array.
fn build_bvh(prims: &mut [PrimRef]) -> Vec<NodePair> {
    if prims.is_empty() {
        return Vec::new();
    }
    let mut pairs = Vec::with_capacity(prims.len() / 2 + 1);
    pairs.push(NodePair::default());
    let root = BuildTask {
        node: 0,
        start: 0,
        end: prims.len(),
        info: range_bounds(prims),
        depth: 0,
    };
    let mut subtrees = Vec::new();
    let defer = (prims.len() / 64).max(1 << 12);
    build_nodes(prims, 0, root, &mut pairs, defer, &mut subtrees);

    // Disjoint slices of `prims` for the subtrees.
    subtrees.sort_by_key(|t| t.start);
    let mut slices = Vec::with_capacity(subtrees.len());
    let (mut rest, mut pos) = (&mut *prims, 0);
    for t in &subtrees {
        let (_, tail) = std::mem::take(&mut rest).split_at_mut(t.start - pos);
        let (mine, tail) = tail.split_at_mut(t.end - t.start);
        slices.push(mine);
        (rest, pos) = (tail, t.end);
    }
    let built: Vec<Vec<NodePair>> = subtrees
        .par_iter()
        .zip(slices)
        .map(|(t, slice)| {
            let mut local = vec![NodePair::default()];
            let root = BuildTask {
                node: 0,
                start: 0,
                end: slice.len(),
                ..*t
            };
            build_nodes(slice, t.start, root, &mut local, 0, &mut Vec::new());
            local
        })
        .collect();

    // Append each subtree: its root goes to the reserved slot, its pairs 1.. to the end (child
    // links shifted accordingly).
    for (t, local) in subtrees.iter().zip(built) {
        let shift = u32::try_from(pairs.len() - 1).expect("BVH node count exceeds u32");
        pairs[t.node / 2].0[t.node % 2] = local[0].0[0].relinked(shift);
        pairs.extend(
            local[1..]
                .iter()
                .map(|p| NodePair(p.0.map(|n| n.relinked(shift)))),
        );
    }
    assert!(
        u32::try_from(2 * pairs.len()).is_ok(),
        "BVH node count exceeds u32"
    );
    pairs
}

/// Builds the subtree `root` over `prims` (whose first element is triangle `offset` of the
/// whole array) into `pairs`. Nodes with at most `defer` (and more than `LEAF_SIZE`) triangles
/// are not built but returned in `deferred` (their slot in `pairs` is reserved).
fn build_nodes(
    prims: &mut [PrimRef],
    offset: usize,
    root: BuildTask,
    pairs: &mut Vec<NodePair>,
    defer: usize,
    deferred: &mut Vec<BuildTask>,
) {
    let mut stack = vec![root];
    while let Some(task) = stack.pop() {
        let count = task.end - task.start;
        let mut node = task.info.bounds.padded_node();
        if count <= LEAF_SIZE {
            node.first = u32::try_from(offset + task.start).expect("at most u32::MAX triangles");
            node.count = count as u32;
            pairs[task.node / 2].0[task.node % 2] = node;
            continue;
        }
        if count <= defer {
            deferred.push(task);
            continue;
        }
        let range = &mut prims[task.start..task.end];
        let (mid, left, right) = split(range, &task.info.cbounds, task.depth < MAX_SAH_DEPTH);
        let pair = pairs.len();
        pairs.push(NodePair::default());
        node.first = u32::try_from(pair).expect("BVH node count exceeds u32");
        pairs[task.node / 2].0[task.node % 2] = node;
        let child = 2 * pair;
        stack.push(BuildTask {
            node: child + 1,
            start: task.start + mid,
            end: task.end,
            info: right,
            depth: task.depth + 1,
        });
        stack.push(BuildTask {
            node: child,
            start: task.start,
            end: task.start + mid,
            info: left,
            depth: task.depth + 1,
        });
    }
}

/// Splits `prims` (more than `LEAF_SIZE` of them) into two non-empty parts: binned SAH on the
/// longest centroid axis, or a median split when `sah` is false or SAH cannot separate them.
/// Returns the split position and the bounds of both parts.
fn split(prims: &mut [PrimRef], cbounds: &Aabb, sah: bool) -> (usize, Bin, Bin) {
    let ext = sub(cbounds.hi, cbounds.lo);
    let axis = if ext[0] >= ext[1] && ext[0] >= ext[2] {
        0
    } else if ext[1] >= ext[2] {
        1
    } else {
        2
    };
    let lo = cbounds.lo[axis];
    let extent = ext[axis];
    if sah && extent > 0.0 && extent.is_finite() {
        let scale = NUM_BINS as f64 / extent;
        let fold = |chunk: &[PrimRef]| {
            let mut bins = [Bin::EMPTY; NUM_BINS];
            for p in chunk {
                let b = &mut bins[bin_index(p, axis, lo, scale)];
                b.bounds = b.bounds.union(&p.bounds);
                b.cbounds.grow(p.centroid3());
                b.count += 1;
            }
            bins
        };
        let bins = if prims.len() >= PAR_BIN_THRESHOLD {
            prims.par_chunks(PAR_BIN_THRESHOLD / 4).map(fold).reduce(
                || [Bin::EMPTY; NUM_BINS],
                |a, b| std::array::from_fn(|i| a[i].merge(&b[i])),
            )
        } else {
            fold(prims)
        };
        // Sweep: right[i] = union of bins i.. ; left accumulated on the fly.
        let mut right = [Bin::EMPTY; NUM_BINS];
        let mut acc = Bin::EMPTY;
        for i in (0..NUM_BINS).rev() {
            acc = acc.merge(&bins[i]);
            right[i] = acc;
        }
        let mut best: Option<(f64, usize)> = None;
        let mut left = Bin::EMPTY;
        for i in 0..NUM_BINS - 1 {
            left = left.merge(&bins[i]);
            let r = &right[i + 1];
            if left.count == 0 || r.count == 0 {
                continue;
            }
            let cost =
                left.bounds.half_area() * left.count as f64 + r.bounds.half_area() * r.count as f64;
            if best.is_none_or(|(c, _)| cost < c) {
                best = Some((cost, i));
            }
        }
        if let Some((_, s)) = best {
            let mid = partition(prims, |p| bin_index(p, axis, lo, scale) <= s);
            let left = bins[..=s].iter().fold(Bin::EMPTY, |a, b| a.merge(b));
            debug_assert_eq!(mid, left.count);
            return (mid, left, right[s + 1]);
        }
    }
    let mid = prims.len() / 2;
    if extent > 0.0 {
        prims.select_nth_unstable_by(mid, |a, b| a.centroid(axis).total_cmp(&b.centroid(axis)));
    }
    let (l, r) = prims.split_at(mid);
    (mid, range_bounds(l), range_bounds(r))
}

/// In-place partition; returns the number of elements satisfying `pred` (now at the front).
fn partition(s: &mut [PrimRef], pred: impl Fn(&PrimRef) -> bool) -> usize {
    let (mut i, mut j) = (0, s.len());
    while i < j {
        if pred(&s[i]) {
            i += 1;
        } else {
            j -= 1;
            s.swap(i, j);
        }
    }
    i
}

/// Largest f32 <= x (-inf if there is none).
fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) > x { f.next_down() } else { f }
}

/// Smallest f32 >= x (+inf if there is none).
fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) < x { f.next_up() } else { f }
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
fn triangle_is_hittable(tri: &[[f64; 3]; 3]) -> bool {
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
fn triangle_normal(tri: &[[f64; 3]; 3]) -> [f64; 3] {
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

    /// SplitMix64.
    struct Rng(u64);

    impl Rng {
        fn next_u64(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        /// Uniform in [0, 1).
        fn f64(&mut self) -> f64 {
            (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
        }
        fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.f64()
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next_u64() % n as u64) as usize
        }
        /// Uniform on the unit sphere.
        fn unit(&mut self) -> [f64; 3] {
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

    fn f32v(p: [f64; 3]) -> [f32; 3] {
        p.map(|c| c as f32)
    }

    fn ray(origin: [f32; 3], dir: [f32; 3], tmax: f32) -> Ray {
        Ray { origin, dir, tmax }
    }

    /// Brute force over all triangles, in primitive order (ties: lowest id wins).
    fn brute_closest(tris: &[[[f32; 3]; 3]], r: &Ray) -> Option<(u32, f64, f64, f64)> {
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

    fn brute_any(tris: &[[[f32; 3]; 3]], r: &Ray) -> bool {
        let o = r.origin.map(f64::from);
        let d = r.dir.map(f64::from);
        let tmax = f64::from(r.tmax);
        tris.iter().any(|t| {
            intersect_triangle(o, d, tmax, &to_f64_tri(t)).is_some_and(|(t, _, _)| t < tmax)
        })
    }

    fn key(h: &Option<Hit>) -> Option<(u32, u64, u64, u64)> {
        h.map(|h| (h.prim, h.t.to_bits(), h.u.to_bits(), h.v.to_bits()))
    }

    fn brute_key(b: &Option<(u32, f64, f64, f64)>) -> Option<(u32, u64, u64, u64)> {
        b.map(|(p, t, u, v)| (p, t.to_bits(), u.to_bits(), v.to_bits()))
    }

    /// Random soup in `[0, 1]^3 * scale + offset`, triangle sizes log-uniform in [1e-3, 0.3].
    fn soup(rng: &mut Rng, n: usize, scale: f64, offset: f64) -> Vec<[[f32; 3]; 3]> {
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
    fn random_rays(rng: &mut Rng, n: usize, scale: f64, offset: f64) -> Vec<Ray> {
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

    fn check_against_brute_force(tris: &[[[f32; 3]; 3]], rays: &[Ray]) -> usize {
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

    #[test]
    fn bvh_matches_brute_force_on_random_soups() {
        let mut rng = Rng(1);
        for (scale, offset) in [
            (1.0, 0.0),
            (1e-6, 0.0),
            (1e6, 0.0),
            (1e-6, 1.0),
            (1e4, 1e7),
            (1.0, 1e7),
            (1e-30, 0.0),
            (1e30, -1e33),
        ] {
            let tris = soup(&mut rng, 1500, scale, offset);
            let rays = random_rays(&mut rng, 1500, scale, offset);
            let hits = check_against_brute_force(&tris, &rays);
            // (1.0, 1e7) is mostly degenerate after f32 rounding: ulp(1e7) = 1.
            if offset != 1e7 || scale != 1.0 {
                assert!(
                    hits > 200,
                    "scale {scale} offset {offset}: only {hits} hits"
                );
            }
        }
        // Larger than the parallel-subtree threshold (top of the tree + subtrees built in
        // parallel and stitched together).
        let tris = soup(&mut rng, 20_000, 1.0, 0.0);
        let rays = random_rays(&mut rng, 400, 1.0, 0.0);
        assert!(check_against_brute_force(&tris, &rays) > 100);
    }

    #[test]
    fn bvh_matches_brute_force_on_rays_grazing_vertices() {
        // Small triangles seen from far away (distance / size up to 1e6), rays aimed exactly at
        // vertices, which lie on faces and corners of the leaf boxes: the BVH must not cull
        // any triangle the triangle test reports (conservative padded boxes).
        let mut rng = Rng(12);
        for (size, dist) in [
            (1e-3, 10.0),
            (1e-4, 10.0),
            (1e-2, 1e3),
            (1e-5, 1.0),
            (1e-5, 10.0),
        ] {
            let tris = soup(&mut rng, 1000, 1.0, 0.0)
                .iter()
                .map(|t| {
                    let c = to_f64_tri(t)[0];
                    [0, 1, 2].map(|_| f32v(c.map(|x| x + size * rng.range(-1.0, 1.0))))
                })
                .collect::<Vec<_>>();
            let rays: Vec<Ray> = (0..2000)
                .map(|_| {
                    let v = tris[rng.below(tris.len())][rng.below(3)].map(f64::from);
                    let o = [0, 1, 2].map(|i| v[i] + dist * rng.unit()[i]);
                    let o = f32v(o);
                    let d = f32v([0, 1, 2].map(|i| v[i] - f64::from(o[i])));
                    ray(o, d, f32::INFINITY)
                })
                .collect();
            let hits = check_against_brute_force(&tris, &rays);
            assert!(hits > 200, "{hits}");
        }
        // Rays exactly through vertices (dyadic coordinates: origin = v + offset and
        // dir = -offset are exact), where the slab distances of a leaf's corner are equal up to
        // rounding.
        let tris: Vec<[[f32; 3]; 3]> = (0..3000)
            .map(|_| {
                let c = [0, 1, 2].map(|_| rng.below(1 << 12) as f32 / 4096.0);
                let s = 1 + rng.below(8);
                [0, 1, 2].map(|_| c.map(|x| x + (rng.below(2 * s + 1) as f32 - s as f32) / 65536.0))
            })
            .collect();
        let rays: Vec<Ray> = (0..3000)
            .map(|_| {
                let v = tris[rng.below(tris.len())][rng.below(3)];
                let off = [0, 1, 2].map(|_| (rng.below(1025) as f32 - 512.0) / 256.0);
                ray(
                    [0, 1, 2].map(|i| v[i] + off[i]),
                    off.map(|c| -c),
                    f32::INFINITY,
                )
            })
            .collect();
        let hits = check_against_brute_force(&tris, &rays);
        assert!(hits > 1500, "{hits}");
    }

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

    #[test]
    fn pathological_distributions_build_and_agree() {
        let mut rng = Rng(10);
        // Many copies of one triangle (identical centroids) plus triangles whose positions and
        // sizes grow exponentially, 2^(k/4) for k < 400 (very unbalanced SAH splits).
        let t = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let mut tris = vec![t; 3000];
        let scale = |k: usize| 2f64.powf(k as f64 / 4.0);
        for k in 0..400 {
            let s = scale(k);
            tris.push(
                [[1.0, 1.0, 1.0], [1.1, 1.0, 1.0], [1.0, 1.1, 1.05]]
                    .map(|p| f32v(p.map(|c| c * s))),
            );
        }
        let reference = Reference::new(&tris);
        let r = ray([0.1, 0.6, 1.0], [0.0, 0.0, -1.0], f32::INFINITY);
        assert_eq!(reference.closest_hit(&r).map(|h| h.prim), Some(0));
        // Rays starting near triangle k towards triangle j >= k or outwards (never passing
        // close to triangles much smaller than their distance, see the module docs).
        let mut rays = Vec::new();
        for _ in 0..1000 {
            let k = rng.below(400);
            let o = [0, 1, 2].map(|_| rng.range(0.9, 1.2) * scale(k));
            let dir = if rng.f64() < 0.5 {
                let j = k + rng.below(400 - k);
                let target = [1.03, 1.03, 1.015].map(|c| c * scale(j));
                sub(target, o)
            } else {
                rng.unit().map(f64::abs)
            };
            rays.push(ray(f32v(o), f32v(dir), f32::INFINITY));
        }
        rays.extend(random_rays(&mut rng, 200, 1.0, 0.0));
        let mut hits = 0;
        for r in &rays {
            let h = reference.closest_hit(r);
            assert_eq!(key(&h), brute_key(&brute_closest(&tris, r)), "{r:?}");
            hits += usize::from(h.is_some());
        }
        assert!(hits > 300, "{hits}");
    }
}
