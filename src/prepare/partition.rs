//! The out-of-core prepare's partition: the spilled triangles cut into parts of at most `cap`
//! triangles, by the Morton code of their box centres (docs/ARCHITECTURE.md, Out-of-core
//! prepare).
//!
//! One pass counts the triangles per cell of a 64^3 grid over the centres' bounds, in Morton
//! order; the cells are grouped top-down by halving the code range (each half a box of the grid)
//! until a group fits, and neighbouring groups are merged while they fit, so a part is a run of
//! Morton order of compact boxes. A second pass writes each triangle, with its primitive id, to
//! its part's file. A single cell holding more than `cap` becomes a part of its own that is cut
//! again the same way over its own centres; centres that no grid separates (all equal) are cut
//! by order.

use super::budget::Budget;
use super::spill::{Reader, Record, Triangle, Writer};
use crate::error::Result;
use crate::output::Scratch;
use indicatif::ProgressBar;
use obvhs::aabb::Aabb;
use std::path::PathBuf;

/// Grid cells per axis, as Morton bits.
const BITS: u32 = 6;
const CELLS: usize = 1 << (3 * BITS);
/// Part files written at once; more parts are written in several passes.
const MAX_OPEN: usize = 256;
/// Refinements of a cell before its triangles are cut by order.
const MAX_DEPTH: u32 = 6;

/// Triangles in a temporary file: the spill (36-byte triangles whose index is their id) or a
/// part (`Record`s).
#[derive(Clone, Debug)]
pub enum Source {
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

impl Source {
    fn count(&self) -> u64 {
        match self {
            Source::Spill { count, .. } => *count,
            Source::Part(p) => p.count,
        }
    }

    /// Calls `f` with every triangle and its primitive id, in file order.
    fn each(&self, f: &mut dyn FnMut(&Triangle, u32) -> Result<()>) -> Result<()> {
        match self {
            Source::Spill { path, count } => {
                let mut r = Reader::<Triangle>::open(path, *count)?;
                let mut id = 0u32;
                while let Some(chunk) = r.next_chunk()? {
                    for t in chunk {
                        f(t, id)?;
                        id += 1;
                    }
                }
            }
            Source::Part(p) => {
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
                    (1u32 << BITS) as f32 / e
                } else {
                    0.0
                }
            }),
        }
    }

    /// The Morton code of the cell of `t`'s centre.
    fn cell(&self, t: &Triangle) -> usize {
        let c = centre(t);
        let max = (1u32 << BITS) - 1;
        let q: [u32; 3] =
            std::array::from_fn(|a| (((c[a] - self.lo[a]) * self.scale[a]) as u32).min(max));
        let mut code = 0usize;
        for b in 0..BITS {
            for (a, q) in q.iter().enumerate() {
                code |= (((q >> b) & 1) as usize) << (3 * b + a as u32);
            }
        }
        code
    }
}

/// Runs of cells that make the parts: `part_of[cell]`, and the count of each part.
fn plan(hist: &[u32], cap: u64) -> (Vec<u32>, Vec<u64>) {
    let mut prefix = vec![0u64; hist.len() + 1];
    for (i, &h) in hist.iter().enumerate() {
        prefix[i + 1] = prefix[i] + u64::from(h);
    }
    let count = |a: usize, b: usize| prefix[b] - prefix[a];
    // Groups of cells, top-down halving the code range until a range fits.
    let mut groups: Vec<(usize, usize)> = Vec::new();
    let mut stack = vec![(0usize, hist.len())];
    while let Some((a, b)) = stack.pop() {
        let n = count(a, b);
        if n == 0 {
            continue;
        }
        if n <= cap || b - a == 1 {
            groups.push((a, b));
        } else {
            let mid = (a + b) / 2;
            stack.push((mid, b));
            stack.push((a, mid));
        }
    }
    // Neighbouring groups merged while they fit.
    let mut part_of = vec![u32::MAX; hist.len()];
    let mut counts: Vec<u64> = Vec::new();
    let mut open = 0u64;
    for (a, b) in groups {
        let n = count(a, b);
        if counts.is_empty() || open + n > cap {
            counts.push(0);
            open = 0;
        }
        open += n;
        let p = counts.len() - 1;
        counts[p] += n;
        let p = p as u32;
        part_of[a..b].fill(p);
    }
    (part_of, counts)
}

/// Cuts `source` into parts of at most `cap` triangles, in files of `scratch`. `bar` counts the
/// triangles read.
pub fn split(
    source: &Source,
    centres: &Aabb,
    cap: u64,
    scratch: &Scratch,
    budget: &Budget,
    bar: &ProgressBar,
) -> Result<Vec<Part>> {
    split_at(source, centres, cap, scratch, budget, bar, 0)
}

#[allow(clippy::too_many_arguments)]
fn split_at(
    source: &Source,
    centres: &Aabb,
    cap: u64,
    scratch: &Scratch,
    budget: &Budget,
    bar: &ProgressBar,
    depth: u32,
) -> Result<Vec<Part>> {
    let grid = Grid::over(centres);
    let separable = grid.scale.iter().any(|&s| s > 0.0);
    let (part_of, counts) = if separable && depth < MAX_DEPTH {
        let mut hist = vec![0u32; CELLS];
        source.each(&mut |t, _| {
            hist[grid.cell(t)] += 1;
            Ok(())
        })?;
        bar.inc(source.count());
        plan(&hist, cap)
    } else {
        // No grid separates these centres: cut by order (`scatter` numbers them itself).
        (Vec::new(), vec![cap; source.count().div_ceil(cap) as usize])
    };
    let parts = scatter(source, &grid, &part_of, &counts, cap, scratch, budget)?;
    bar.inc(source.count());
    let mut out = Vec::with_capacity(parts.len());
    for p in parts {
        if p.count > cap {
            let centres = p.centres;
            let sub = split_at(
                &Source::Part(p.clone()),
                &centres,
                cap,
                scratch,
                budget,
                bar,
                depth + 1,
            )?;
            std::fs::remove_file(&p.path).map_err(|e| crate::Error::io(&p.path, e))?;
            out.extend(sub);
        } else {
            out.push(p);
        }
    }
    Ok(out)
}

/// Writes each triangle of `source` to its part's file: by its cell (`part_of`), or, without a
/// plan, `cap` at a time in order. At most `MAX_OPEN` files are open: more parts take more
/// passes.
#[allow(clippy::too_many_arguments)]
fn scatter(
    source: &Source,
    grid: &Grid,
    part_of: &[u32],
    counts: &[u64],
    cap: u64,
    scratch: &Scratch,
    budget: &Budget,
) -> Result<Vec<Part>> {
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let mut parts = Vec::with_capacity(counts.len());
    for first in (0..counts.len()).step_by(MAX_OPEN) {
        let last = (first + MAX_OPEN).min(counts.len());
        let buffer = budget.buffer_bytes(last - first);
        let mut writers = Vec::with_capacity(last - first);
        for _ in first..last {
            let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            writers.push((
                Writer::<Record>::create(&scratch.path(&format!("part-{n}")), buffer)?,
                Aabb::INVALID,
                Aabb::INVALID,
                Vec::<Record>::with_capacity(64),
            ));
        }
        let mut index = 0u64;
        source.each(&mut |t, id| {
            let p = if part_of.is_empty() {
                (index / cap) as usize
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
            parts.push(Part {
                path,
                count,
                bounds,
                centres,
            });
        }
    }
    debug_assert!(
        parts
            .iter()
            .zip(counts)
            .all(|(p, &c)| p.count == c || part_of.is_empty())
    );
    Ok(parts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plans_fit_the_cap_and_cover_every_cell() {
        let mut hist = vec![0u32; CELLS];
        let mut s = 7u64;
        for _ in 0..20_000 {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
            hist[(s >> 40) as usize % 5000] += 1;
        }
        hist[4000] = 900; // one cell over the cap
        let (part_of, counts) = plan(&hist, 500);
        let total: u64 = hist.iter().map(|&h| u64::from(h)).sum();
        assert_eq!(counts.iter().sum::<u64>(), total);
        let mut per = vec![0u64; counts.len()];
        for (c, &h) in hist.iter().enumerate() {
            if h > 0 {
                per[part_of[c] as usize] += u64::from(h);
            }
        }
        assert_eq!(per, counts);
        let over: Vec<_> = counts.iter().filter(|&&c| c > 500).collect();
        assert_eq!(over, [&u64::from(hist[4000])], "only the big cell is over");
        // Parts are runs of cells in Morton order.
        let used: Vec<u32> = (0..CELLS)
            .filter(|&c| hist[c] > 0)
            .map(|c| part_of[c])
            .collect();
        assert!(used.windows(2).all(|w| w[0] <= w[1]));
        // Merged while they fit: no two neighbours would fit together.
        assert!(counts.windows(2).all(|w| w[0] + w[1] > 500));
    }
}
