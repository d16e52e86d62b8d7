//! The reference tracer's own BVH: binned SAH over triangle bounds, built iteratively (the top
//! of the tree first, then its subtrees in parallel) into a flat array of sibling pairs, with
//! node boxes padded and rounded outwards so that traversal never culls a reported hit.

use super::{PAD_REL, max_abs, sub};
use rayon::prelude::*;

/// Maximum number of triangles in a leaf.
const LEAF_SIZE: usize = 4;
/// Number of SAH bins.
const NUM_BINS: usize = 32;
/// Below this depth splits are binned SAH; deeper, median splits bound the depth of the tree
/// (and the build time) even for pathological inputs.
const MAX_SAH_DEPTH: u32 = 48;
/// Ranges at least this long are binned in parallel.
const PAR_BIN_THRESHOLD: usize = 1 << 16;

/// BVH node (32 bytes). Interior nodes have `count == 0` and children `2 first` and
/// `2 first + 1` (the pair `first`); leaves have `1..=LEAF_SIZE` triangles `first..first + count`.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C)]
pub(super) struct Node {
    /// Padded bounds, rounded outwards to f32 (the slab test itself is in f64).
    pub(super) lo: [f32; 3],
    pub(super) hi: [f32; 3],
    pub(super) first: u32,
    pub(super) count: u32,
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

/// Two sibling nodes in one 64-byte cache line.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
pub(super) struct NodePair(pub(super) [Node; 2]);

#[derive(Clone, Copy, Debug)]
pub(super) struct Aabb {
    pub(super) lo: [f64; 3],
    pub(super) hi: [f64; 3],
}

impl Aabb {
    pub(super) const EMPTY: Aabb = Aabb {
        lo: [f64::INFINITY; 3],
        hi: [f64::NEG_INFINITY; 3],
    };

    pub(super) fn of_triangle(tri: &[[f64; 3]; 3]) -> Aabb {
        let mut b = Aabb::EMPTY;
        for p in tri {
            b.grow(*p);
        }
        b
    }

    pub(super) fn grow(&mut self, p: [f64; 3]) {
        for ((lo, hi), c) in self.lo.iter_mut().zip(&mut self.hi).zip(p) {
            *lo = lo.min(c);
            *hi = hi.max(c);
        }
    }

    pub(super) fn union(&self, o: &Aabb) -> Aabb {
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
pub(super) struct PrimRef {
    pub(super) bounds: Aabb,
    pub(super) id: u32,
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
pub(super) fn build_bvh(prims: &mut [PrimRef]) -> Vec<NodePair> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::fixtures::*;
    use crate::reference::{Ray, Reference, to_f64_tri};

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
