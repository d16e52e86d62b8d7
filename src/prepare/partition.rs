//! The out-of-core prepare's partition: the spilled triangles cut into parts of at most `cap`
//! triangles, and the binary tree of the cuts, which becomes the top of the BVH
//! (docs/ARCHITECTURE.md, Out-of-core prepare).
//!
//! One pass counts the triangles' box centres in the cells of a 64^3 grid over the centres'
//! bounds. The cells are then cut in two, again and again, to an even depth `d` at which
//! `2^d` parts hold at most `cap` each: each cut is across the longest side of the occupied
//! cells, at the cell boundary nearest to the median count. The cuts form a complete binary tree,
//! so collapsed to 4-wide nodes every top node is full, as the levels of a tree built whole are.
//! A second pass writes each triangle, with its primitive id, to its part's file. A part that
//! still holds more than `cap` (a cell too full to cut) is cut again the same way over its own
//! centres, its tree in its place; centres no grid separates (all equal) are cut by order.

use super::budget::Budget;
use super::spill::{Reader, Record, Triangle, Writer};
pub use crate::bvh::join::Cuts;
use crate::error::Result;
use crate::files::Scratch;
use indicatif::ProgressBar;
use obvhs::aabb::Aabb;
use std::path::PathBuf;

/// Grid cells per axis.
const GRID: usize = 64;
const CELLS: usize = GRID * GRID * GRID;
/// Part files written at once; more parts are written in several passes.
const MAX_OPEN: usize = 256;
/// Cuts of a part over its own centres before its triangles are cut by order.
const MAX_DEPTH: u32 = 4;
/// Parts are planned to this share of `cap`: cuts fall on cell boundaries, so halves are not
/// exact.
const SLACK: f64 = 0.85;

/// Triangles in a temporary file: the spill (36-byte triangles whose index is their id) or a
/// part (`Record`s).
#[derive(Clone, Debug)]
pub enum TriangleFile {
    Spill { path: PathBuf, count: u64 },
    Part(Part),
}

/// A part: its file of `Record`s, how many, the bounds of its triangles and of their box
/// centres.
#[derive(Clone, Debug)]
pub struct Part {
    pub path: PathBuf,
    pub count: u64,
    pub bounds: Aabb,
    pub centres: Aabb,
}

impl TriangleFile {
    fn count(&self) -> u64 {
        match self {
            TriangleFile::Spill { count, .. } => *count,
            TriangleFile::Part(p) => p.count,
        }
    }

    /// Calls `f` with every triangle and its primitive id, in file order.
    fn each(&self, f: &mut dyn FnMut(&Triangle, u32) -> Result<()>) -> Result<()> {
        match self {
            TriangleFile::Spill { path, count } => {
                let mut r = Reader::<Triangle>::open(path, *count)?;
                let mut id = 0u32;
                while let Some(chunk) = r.next_chunk()? {
                    for t in chunk {
                        f(t, id)?;
                        id += 1;
                    }
                }
            }
            TriangleFile::Part(p) => {
                let mut r = Reader::<Record>::open(&p.path, p.count)?;
                while let Some(chunk) = r.next_chunk()? {
                    for rec in chunk {
                        f(&rec.tri, rec.id)?;
                    }
                }
            }
        }
        Ok(())
    }
}

/// The box centre of a triangle, the point the partition sorts by.
pub fn centre(t: &Triangle) -> [f32; 3] {
    std::array::from_fn(|a| {
        let lo = t[0][a].min(t[1][a]).min(t[2][a]);
        let hi = t[0][a].max(t[1][a]).max(t[2][a]);
        lo * 0.5 + hi * 0.5
    })
}

fn point_box(p: [f32; 3]) -> Aabb {
    let v = glam::Vec3A::from_array(p);
    Aabb { min: v, max: v }
}

/// The grid over a set of centres.
struct Grid {
    lo: [f32; 3],
    /// Cells per unit length on each axis (0 for an axis the centres do not spread along).
    scale: [f32; 3],
}

impl Grid {
    fn over(centres: &Aabb) -> Grid {
        let (lo, hi) = (centres.min.to_array(), centres.max.to_array());
        Grid {
            lo,
            scale: std::array::from_fn(|a| {
                let e = hi[a] - lo[a];
                if e > 0.0 && e.is_finite() {
                    GRID as f32 / e
                } else {
                    0.0
                }
            }),
        }
    }

    /// The cell of `t`'s centre.
    fn cell(&self, t: &Triangle) -> usize {
        let c = centre(t);
        let q: [usize; 3] =
            std::array::from_fn(|a| (((c[a] - self.lo[a]) * self.scale[a]) as usize).min(GRID - 1));
        q[0] + GRID * (q[1] + GRID * q[2])
    }

    /// A cell's side on axis `a`, in model units (0 where the centres do not spread).
    fn side(&self, a: usize) -> f32 {
        if self.scale[a] > 0.0 {
            1.0 / self.scale[a]
        } else {
            0.0
        }
    }
}

/// A box of cells, `lo..hi` per axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Region {
    lo: [usize; 3],
    hi: [usize; 3],
}

impl Region {
    fn cells(&self) -> impl Iterator<Item = usize> + '_ {
        (self.lo[2]..self.hi[2]).flat_map(move |z| {
            (self.lo[1]..self.hi[1])
                .flat_map(move |y| (self.lo[0]..self.hi[0]).map(move |x| x + GRID * (y + GRID * z)))
        })
    }

    fn coord(cell: usize) -> [usize; 3] {
        [cell % GRID, (cell / GRID) % GRID, cell / (GRID * GRID)]
    }

    /// The smallest region around the region's occupied cells, and their count.
    fn occupied(&self, hist: &[u32]) -> (Region, u64) {
        let mut r = Region {
            lo: [GRID; 3],
            hi: [0; 3],
        };
        let mut n = 0u64;
        for c in self.cells() {
            if hist[c] > 0 {
                n += u64::from(hist[c]);
                for (a, q) in Region::coord(c).into_iter().enumerate() {
                    r.lo[a] = r.lo[a].min(q);
                    r.hi[a] = r.hi[a].max(q + 1);
                }
            }
        }
        (r, n)
    }

    /// The region cut in two across its longest side (in model units) at the cell boundary
    /// nearest its median count; `None` for a single cell.
    fn cut(&self, hist: &[u32], grid: &Grid) -> Option<(Region, Region)> {
        let a = (0..3)
            .filter(|&a| self.hi[a] - self.lo[a] > 1)
            .max_by(|&a, &b| {
                let len = |a: usize| (self.hi[a] - self.lo[a]) as f32 * grid.side(a);
                len(a).total_cmp(&len(b))
            })?;
        let mut slabs = vec![0u64; self.hi[a] - self.lo[a]];
        for c in self.cells() {
            slabs[Region::coord(c)[a] - self.lo[a]] += u64::from(hist[c]);
        }
        let total: u64 = slabs.iter().sum();
        // The boundary (1..len) whose left count is nearest half.
        let mut left = 0u64;
        let mut best = (u64::MAX, 1);
        for (s, &n) in slabs.iter().enumerate().take(slabs.len() - 1) {
            left += n;
            let off = (2 * left).abs_diff(total);
            if off < best.0 {
                best = (off, s + 1);
            }
        }
        let at = self.lo[a] + best.1;
        let (mut l, mut r) = (*self, *self);
        l.hi[a] = at;
        r.lo[a] = at;
        Some((l, r))
    }
}

/// The cuts of the cells `hist` counts, `depth` levels deep: the regions of the parts, left to
/// right, and the tree. A region that cannot be cut (a single cell) stops early; an empty half
/// is dropped.
fn plan(hist: &[u32], grid: &Grid, depth: u32) -> (Vec<Region>, Cuts) {
    fn go(
        region: Region,
        hist: &[u32],
        grid: &Grid,
        depth: u32,
        out: &mut Vec<Region>,
    ) -> Option<Cuts> {
        let (region, n) = region.occupied(hist);
        if n == 0 {
            return None;
        }
        let halves = if depth > 0 {
            region.cut(hist, grid)
        } else {
            None
        };
        let Some((l, r)) = halves else {
            out.push(region);
            return Some(Cuts::Part(out.len() - 1));
        };
        match (
            go(l, hist, grid, depth - 1, out),
            go(r, hist, grid, depth - 1, out),
        ) {
            (Some(a), Some(b)) => Some(Cuts::Two(Box::new(a), Box::new(b))),
            (Some(a), None) | (None, Some(a)) => Some(a),
            (None, None) => None,
        }
    }
    let all = Region {
        lo: [0; 3],
        hi: [GRID; 3],
    };
    let mut regions = Vec::new();
    let cuts = go(all, hist, grid, depth, &mut regions).unwrap_or(Cuts::Part(0));
    if regions.is_empty() {
        regions.push(all);
    }
    (regions, cuts)
}

/// The even depth (a whole number of 4-wide levels) at which `count` triangles cut in halves
/// make parts of at most `cap` (with `SLACK`).
fn depth_for(count: u64, cap: u64) -> u32 {
    let target = (cap as f64 * SLACK).max(1.0);
    let mut d = 0;
    while count as f64 / f64::powi(2.0, d as i32) > target && d < 40 {
        d += 2;
    }
    d
}

/// Cuts `source` into parts of at most `cap` triangles, in files of `scratch`: the parts and
/// the tree of the cuts over them. `bar` counts the triangles read.
pub fn split(
    source: &TriangleFile,
    centres: &Aabb,
    cap: u64,
    scratch: &Scratch,
    budget: &Budget,
    bar: &ProgressBar,
) -> Result<(Vec<Part>, Cuts)> {
    let cutter = Cutter {
        cap,
        scratch,
        budget,
        bar,
    };
    let mut parts = Vec::new();
    let cuts = cutter.split(source, centres, 0, &mut parts)?;
    Ok((parts, cuts))
}

/// What every cut works with.
struct Cutter<'a> {
    cap: u64,
    scratch: &'a Scratch,
    budget: &'a Budget,
    bar: &'a ProgressBar,
}

impl Cutter<'_> {
    /// Cuts `source` (whose centres have the bounds `centres`; cut `level` times before) into
    /// parts, appended to `out`; the tree of the cuts over their indices in `out`.
    fn split(
        &self,
        source: &TriangleFile,
        centres: &Aabb,
        level: u32,
        out: &mut Vec<Part>,
    ) -> Result<Cuts> {
        let grid = Grid::over(centres);
        let separable = grid.scale.iter().any(|&s| s > 0.0);
        let count = source.count();
        let (part_of, cuts, pieces) = if separable && level < MAX_DEPTH {
            let mut hist = vec![0u32; CELLS];
            source.each(&mut |t, _| {
                hist[grid.cell(t)] += 1;
                Ok(())
            })?;
            self.bar.inc(count);
            let (regions, cuts) = plan(&hist, &grid, depth_for(count, self.cap));
            let mut part_of = vec![u32::MAX; CELLS];
            for (p, r) in regions.iter().enumerate() {
                for c in r.cells() {
                    part_of[c] = p as u32;
                }
            }
            (part_of, cuts, regions.len())
        } else {
            // No grid separates these centres: cut by order, the pieces under a balanced tree.
            let pieces = count.div_ceil(self.cap).max(1) as usize;
            fn balanced(a: usize, b: usize) -> Cuts {
                if b - a == 1 {
                    return Cuts::Part(a);
                }
                let m = (a + b) / 2;
                Cuts::Two(Box::new(balanced(a, m)), Box::new(balanced(m, b)))
            }
            (Vec::new(), balanced(0, pieces), pieces)
        };
        let parts = self.scatter(source, &grid, &part_of, pieces)?;
        self.bar.inc(count);
        // Parts still over the cap are cut again; every part gets its place in `out`.
        let mut sub = Vec::with_capacity(parts.len());
        for p in parts {
            if p.count > self.cap {
                let centres = p.centres;
                let c = self.split(&TriangleFile::Part(p.clone()), &centres, level + 1, out)?;
                std::fs::remove_file(&p.path).map_err(|e| crate::Error::io(&p.path, e))?;
                sub.push(c);
            } else {
                out.push(p);
                sub.push(Cuts::Part(out.len() - 1));
            }
        }
        let mut cuts = cuts;
        graft(&mut cuts, &sub);
        Ok(cuts)
    }

    /// Writes each triangle of `source` to its part's file: by its cell (`part_of`), or, without
    /// a plan, `cap` at a time in order. At most `MAX_OPEN` files are open: more parts take more
    /// passes.
    fn scatter(
        &self,
        source: &TriangleFile,
        grid: &Grid,
        part_of: &[u32],
        parts: usize,
    ) -> Result<Vec<Part>> {
        static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let mut out = Vec::with_capacity(parts);
        for first in (0..parts).step_by(MAX_OPEN) {
            let last = (first + MAX_OPEN).min(parts);
            let buffer = self.budget.buffer_bytes(last - first);
            let mut writers = Vec::with_capacity(last - first);
            for _ in first..last {
                let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                writers.push((
                    Writer::<Record>::create(&self.scratch.path(&format!("part-{n}")), buffer)?,
                    Aabb::INVALID,
                    Aabb::INVALID,
                    Vec::<Record>::with_capacity(64),
                ));
            }
            let mut index = 0u64;
            source.each(&mut |t, id| {
                let p = if part_of.is_empty() {
                    (index / self.cap) as usize
                } else {
                    part_of[grid.cell(t)] as usize
                };
                index += 1;
                if !(first..last).contains(&p) {
                    return Ok(());
                }
                let (w, bounds, centres, pending) = &mut writers[p - first];
                *bounds = bounds.union(&crate::bvh::triangle_box(t));
                *centres = centres.union(&point_box(centre(t)));
                pending.push(Record { tri: *t, id });
                if pending.len() == pending.capacity() {
                    w.push(pending)?;
                    pending.clear();
                }
                Ok(())
            })?;
            for (mut w, bounds, centres, pending) in writers {
                w.push(&pending)?;
                let (path, count) = w.finish()?;
                out.push(Part {
                    path,
                    count,
                    bounds,
                    centres,
                });
            }
        }
        Ok(out)
    }
}

/// Replaces each leaf `Part(i)` of `cuts` by `sub[i]`.
fn graft(cuts: &mut Cuts, sub: &[Cuts]) {
    match cuts {
        Cuts::Part(i) => *cuts = sub[*i].clone(),
        Cuts::Two(a, b) => {
            graft(a, sub);
            graft(b, sub);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn depth(c: &Cuts) -> (usize, usize) {
        match c {
            Cuts::Part(_) => (0, 0),
            Cuts::Two(a, b) => {
                let (a, b) = (depth(a), depth(b));
                (1 + a.0.min(b.0), 1 + a.1.max(b.1))
            }
        }
    }

    /// A sheet of centres over x and y: cut into a complete tree of the even depth that makes
    /// the parts fit, the halves near even, every occupied cell in exactly one part.
    #[test]
    fn cuts_make_a_complete_tree_of_near_even_parts() {
        let centres = Aabb {
            min: glam::Vec3A::new(-1.0, -1.0, -0.1),
            max: glam::Vec3A::new(1.0, 1.0, 0.1),
        };
        let grid = Grid::over(&centres);
        let mut hist = vec![0u32; CELLS];
        let mut s = 7u64;
        let mut total = 0u64;
        for _ in 0..200_000 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = |k: u32| ((s >> k) & 0xffff) as f32 / 65536.0;
            let t = [[-1.0 + 2.0 * u(16), -1.0 + 2.0 * u(32), 0.1 * (u(48) - 0.5)]; 3];
            hist[grid.cell(&t)] += 1;
            total += 1;
        }
        let cap = 15_000;
        let d = depth_for(total, cap);
        assert_eq!(d, 4, "16 parts of 12,500");
        let (regions, cuts) = plan(&hist, &grid, d);
        assert_eq!(depth(&cuts), (4, 4), "complete");
        assert_eq!(cuts.parts(), (0..16).collect::<Vec<_>>());
        let mut owner = vec![usize::MAX; CELLS];
        for (p, r) in regions.iter().enumerate() {
            let n: u64 = r.cells().map(|c| u64::from(hist[c])).sum();
            assert!(n <= cap && n > 9_000, "part {p}: {n}");
            for c in r.cells() {
                assert_eq!(owner[c], usize::MAX, "cell {c} in two parts");
                owner[c] = p;
            }
        }
        assert!((0..CELLS).all(|c| hist[c] == 0 || owner[c] != usize::MAX));
        // One full cell cannot be cut: it stays a part (the caller cuts it again).
        let mut one = vec![0u32; CELLS];
        one[5] = 1000;
        let (regions, cuts) = plan(&one, &grid, 4);
        assert_eq!((regions.len(), cuts), (1, Cuts::Part(0)));
    }

    #[test]
    fn depths_are_even_and_enough() {
        assert_eq!(depth_for(100, 1000), 0);
        assert_eq!(depth_for(2000, 1000), 2);
        assert_eq!(depth_for(4000, 1000), 4);
        assert_eq!(depth_for(300_000_000, 14_000_000), 6);
    }
}
