//! The distributed cache (docs/ARCHITECTURE.md, The distributed cache; chapter 5.3): block
//! ownership and the rows a rank's GPU holds, the direct-mapped cache mapping, the host's cache
//! policy between rounds, where borrowed blocks come from, and what each frame's faults cost.

pub mod policy;
pub mod source;

use crate::blocks::ranks::Ranks;
use crate::error::{Error, Result};

/// No block, no row: the empty entry of the cache's tags and of the GPU's block-row table (WGSL's
/// `NONE`, which `gpu::layout::NONE` is).
pub const NONE: u32 = u32::MAX;

/// Which cache line a borrowed block goes to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CacheMap {
    /// `(k - floor((k + (N - rank)) / N)) mod lines`: only blocks the rank does not own are
    /// counted, so no line is wasted (Ize et al.).
    #[default]
    Ize,
    /// `k mod lines` (DeMarle et al.).
    Demarle,
    /// Any line: a round's faults take the lines used least recently, never one loaded or used
    /// in the same round (an associative cache; the GPU finds blocks through the row table, so
    /// where a block lies costs it nothing).
    Lru,
}

/// Which blocks every rank holds besides its own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Replicate {
    /// The root block alone: every ray starts without a fault.
    #[default]
    Root,
    /// Every node block (the BVH, about a sixth of a model): only triangle and attribute blocks
    /// fault, so a ray waits for one block level instead of one per treelet on its path.
    Nodes,
}

impl Replicate {
    /// How many of the first block ids are on every rank, for a model of `node_blocks` node
    /// blocks.
    pub fn blocks(self, node_blocks: u32) -> u32 {
        match self {
            Replicate::Root => 1,
            Replicate::Nodes => node_blocks.max(1),
        }
    }
}

/// The cache line of a block the rank does not own under a direct mapping (`Lru` counts waiting
/// rays in the same `k mod lines` buckets; its blocks go to any line). Mirrors `cache_line` in
/// shaders/shared/dc.wgsl.
pub fn cache_line(map: CacheMap, ranks: Ranks, lines: u32, k: u32) -> u32 {
    match map {
        CacheMap::Ize => {
            let n = ranks.n;
            (k - (k + (n - ranks.rank)) / n) % lines
        }
        CacheMap::Demarle | CacheMap::Lru => k % lines,
    }
}

/// How big the cache is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CacheSize {
    /// A fraction of the model's blocks (`1/8`).
    Fraction(f64),
    Lines(u32),
    Bytes(u64),
}

impl CacheSize {
    /// Parses `1/8`, `0.125`, `64` + `lines`, or a byte size like `256MiB`, `4096KiB`, `1GiB`.
    pub fn parse(s: &str) -> Result<CacheSize> {
        let bad = || {
            Error::Invalid(format!(
                "cache size '{s}': give a fraction of the model (1/8, 0.25), a line count \
                 (64lines) or bytes (256MiB)"
            ))
        };
        let t = s.trim();
        if let Some((a, b)) = t.split_once('/') {
            let (a, b): (f64, f64) = (
                a.trim().parse().map_err(|_| bad())?,
                b.trim().parse().map_err(|_| bad())?,
            );
            return CacheSize::fraction(a / b).ok_or_else(bad);
        }
        if let Some(n) = t.strip_suffix("lines").or_else(|| t.strip_suffix("line")) {
            let n: u32 = n.trim().parse().map_err(|_| bad())?;
            return if n > 0 {
                Ok(CacheSize::Lines(n))
            } else {
                Err(bad())
            };
        }
        if t.ends_with('B') {
            let bytes = crate::size::parse_size(t).map_err(|_| bad())?;
            return Ok(CacheSize::Bytes(bytes));
        }
        let f: f64 = t.parse().map_err(|_| bad())?;
        CacheSize::fraction(f).ok_or_else(bad)
    }

    fn fraction(f: f64) -> Option<CacheSize> {
        (f.is_finite() && f > 0.0 && f <= 1.0).then_some(CacheSize::Fraction(f))
    }

    /// Lines for a model of `blocks` blocks of `block_bytes` (at least one).
    pub fn lines(&self, blocks: u32, block_bytes: u32) -> u32 {
        let l = match *self {
            CacheSize::Fraction(f) => (f64::from(blocks) * f).round() as u64,
            CacheSize::Lines(n) => u64::from(n),
            CacheSize::Bytes(b) => b / u64::from(block_bytes),
        };
        l.clamp(1, u64::from(u32::MAX)) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ize_mapping_is_dense_over_borrowed_blocks() {
        for n in 1..8 {
            for rank in 0..n {
                let r = Ranks::new(n, rank).unwrap();
                let mut dense = 0u32;
                for k in 0..500 {
                    if r.owns(k) {
                        continue;
                    }
                    // The k-th borrowed block gets index `dense` before the modulo.
                    assert_eq!(
                        cache_line(CacheMap::Ize, r, u32::MAX, k),
                        dense,
                        "n{n} r{rank} k{k}"
                    );
                    dense += 1;
                }
                // With as many lines as borrowed blocks, every line is used exactly once.
                let lines = dense;
                if lines > 0 {
                    let mut used = vec![0; lines as usize];
                    (0..500u32)
                        .filter(|&k| !r.owns(k))
                        .for_each(|k| used[cache_line(CacheMap::Ize, r, lines, k) as usize] += 1);
                    assert!(used.iter().all(|&u| u == 1));
                }
            }
        }
    }

    #[test]
    fn demarle_wastes_lines_ize_does_not() {
        // The chapter's example: 2 ranks, 2 lines: rank 0 never uses DeMarle's line 0.
        let r = Ranks::new(2, 0).unwrap();
        let borrowed: Vec<u32> = (0..100).filter(|&k| !r.owns(k)).collect();
        let lines = |m| {
            let mut s: Vec<u32> = borrowed.iter().map(|&k| cache_line(m, r, 2, k)).collect();
            s.sort();
            s.dedup();
            s
        };
        assert_eq!(lines(CacheMap::Demarle), vec![1]);
        assert_eq!(lines(CacheMap::Ize), vec![0, 1]);
    }

    #[test]
    fn ownership() {
        let r = Ranks::new(3, 1).unwrap();
        assert!(r.owns(4) && !r.owns(5));
        assert_eq!(r.slot(7), 2);
        assert_eq!(r.owned(10), 3); // 1, 4, 7
        assert_eq!(Ranks::new(3, 0).unwrap().owned(10), 4); // 0, 3, 6, 9
        assert!(r.resident(0) && r.resident(1) && !r.resident(2));
        assert!(Ranks::new(2, 2).is_err());
    }

    #[test]
    fn resident_rows_are_own_blocks_then_the_root() {
        // Rank 1 of 3, 10 blocks: owns 1, 4, 7 at rows 0..3; the root follows at row 3.
        let r = Ranks::new(3, 1).unwrap();
        assert_eq!(r.resident_rows(10), 4);
        assert_eq!(r.root_row(10), 3);
        assert_eq!(r.resident_blocks(10).collect::<Vec<_>>(), [1, 4, 7, 0]);
        let rows: Vec<Option<u32>> = (0..10).map(|k| r.resident_row(k, 10)).collect();
        let want = [
            Some(3),
            Some(0),
            None,
            None,
            Some(1),
            None,
            None,
            Some(2),
            None,
            None,
        ];
        assert_eq!(rows, want);
        // Rank 0 owns the root at row 0 and holds no extra row.
        let r0 = Ranks::new(3, 0).unwrap();
        assert_eq!((r0.resident_rows(10), r0.root_row(10)), (4, 0));
        assert_eq!(r0.resident_row(0, 10), Some(0));
        assert_eq!(r0.resident_row(9, 10), Some(3));
        assert_eq!(r0.resident_blocks(10).collect::<Vec<_>>(), [0, 3, 6, 9]);
    }

    #[test]
    fn replicated_blocks_follow_the_own_ones_in_id_order() {
        // Rank 1 of 3, 10 blocks, 5 replicated: owns 1, 4, 7 at rows 0..3; 0, 2, 3 follow.
        let r = Ranks::new(3, 1).unwrap().replicating(5);
        assert_eq!(r.resident_rows(10), 6);
        assert_eq!(
            r.resident_blocks(10).collect::<Vec<_>>(),
            [1, 4, 7, 0, 2, 3]
        );
        assert_eq!(r.root_row(10), 3);
        let rows: Vec<Option<u32>> = (0..10).map(|k| r.resident_row(k, 10)).collect();
        const NO: u32 = u32::MAX;
        let want = [3, 0, 4, 5, 1, NO, NO, 2, NO, NO].map(|row| (row != NO).then_some(row));
        assert_eq!(rows, want);
        assert!((0..5).all(|k| r.resident(k)) && !r.resident(5));
        // Every row is named once, and each block's row is where `resident_blocks` puts it.
        for (row, k) in r.resident_blocks(10).enumerate() {
            assert_eq!(r.resident_row(k, 10), Some(row as u32), "block {k}");
        }
        // More replicated blocks than the model has: all of it, once.
        let all = Ranks::new(3, 2).unwrap().replicating(99);
        assert_eq!(all.resident_rows(10), 10);
        let mut b: Vec<u32> = all.resident_blocks(10).collect();
        b.sort();
        assert_eq!(b, (0..10).collect::<Vec<_>>());
        assert_eq!(Replicate::Root.blocks(7), 1);
        assert_eq!(Replicate::Nodes.blocks(7), 7);
        assert_eq!(Replicate::Nodes.blocks(0), 1);
    }

    #[test]
    fn cache_sizes() {
        assert_eq!(CacheSize::parse("1/8").unwrap().lines(800, 8192), 100);
        assert_eq!(CacheSize::parse("0.5").unwrap().lines(10, 8192), 5);
        assert_eq!(CacheSize::parse("1line").unwrap().lines(10, 8192), 1);
        assert_eq!(CacheSize::parse("3 lines").unwrap().lines(10, 8192), 3);
        assert_eq!(CacheSize::parse("1MiB").unwrap().lines(10, 8192), 128);
        assert_eq!(CacheSize::parse("1/1000").unwrap().lines(10, 8192), 1);
        for bad in ["0", "2", "1/0", "x", "0lines", "-1/8", "lots"] {
            assert!(CacheSize::parse(bad).is_err(), "{bad}");
        }
    }
}
