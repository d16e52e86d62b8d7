//! Which render rank owns which block (chapter 5.3): block k is owned by rank `k mod N` at slot
//! `k / N` of its resident array; the first `replicated` blocks are on every rank. The block file
//! reads a rank's share by it, and the distributed cache maps the rest to cache lines.

use crate::error::{Error, Result};

/// This rank's place among the render ranks, and the blocks every rank holds: ids below
/// `replicated` (the root block, or every node block: `Replicate`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ranks {
    pub n: u32,
    pub rank: u32,
    pub replicated: u32,
}

impl Ranks {
    /// Rank `rank` of `n`, with the root block replicated.
    pub fn new(n: u32, rank: u32) -> Result<Ranks> {
        if n == 0 || rank >= n {
            return Err(Error::Invalid(format!(
                "rank {rank} of {n} render ranks: need 0 <= rank < ranks"
            )));
        }
        Ok(Ranks {
            n,
            rank,
            replicated: 1,
        })
    }
    /// The same rank with blocks `0..replicated` on every rank (at least the root).
    pub fn replicating(self, replicated: u32) -> Ranks {
        Ranks {
            replicated: replicated.max(1),
            ..self
        }
    }
    pub fn owner(&self, k: u32) -> u32 {
        k % self.n
    }
    pub fn owns(&self, k: u32) -> bool {
        self.owner(k) == self.rank
    }
    /// Slot of block `k` in its owner's resident array.
    pub fn slot(&self, k: u32) -> u32 {
        k / self.n
    }
    /// Blocks this rank owns out of `count`.
    pub fn owned(&self, count: u32) -> u32 {
        count.saturating_sub(self.rank).div_ceil(self.n)
    }
    /// Whether block `k` is on this rank's GPU without the cache: owned or replicated.
    pub fn resident(&self, k: u32) -> bool {
        k < self.replicated || self.owns(k)
    }

    // The resident rows of a rank's GPU, for a model of `count` blocks: its own blocks by slot,
    // then the replicated blocks it does not own, in id order. The cache lines follow.

    /// The replicated blocks of a model of `count` blocks (never more than it has).
    fn replicated_of(&self, count: u32) -> u32 {
        self.replicated.min(count)
    }

    /// Resident rows: owned blocks, plus the replicated ones borrowed.
    pub fn resident_rows(&self, count: u32) -> u32 {
        let r = self.replicated_of(count);
        self.owned(count) + r - self.owned(r)
    }

    /// The block in each resident row, in row order.
    pub fn resident_blocks(&self, count: u32) -> impl Iterator<Item = u32> + use<> {
        let me = *self;
        let replicated = (0..self.replicated_of(count)).filter(move |&k| !me.owns(k));
        (self.rank..count)
            .step_by(self.n as usize)
            .chain(replicated)
    }

    /// The row of the root block.
    pub fn root_row(&self, count: u32) -> u32 {
        if self.owns(0) { 0 } else { self.owned(count) }
    }

    /// The row of block `k` without the cache: its slot when owned, its row among the borrowed
    /// replicated blocks, or `None`.
    pub fn resident_row(&self, k: u32, count: u32) -> Option<u32> {
        if self.owns(k) {
            Some(self.slot(k))
        } else if k < self.replicated_of(count) {
            Some(self.owned(count) + k - self.owned(k))
        } else {
            None
        }
    }
}
