//! Where borrowed blocks come from: one interface for the whole local file, in-process virtual
//! ranks and (in cluster mode) one-sided MPI. A round's faulted blocks are fetched in one call, so
//! a source can serve them in one epoch.

use crate::blocks::Blocks;
use crate::blocks::file::DcbFile;
use crate::blocks::ranks::Ranks;
use crate::error::{Error, Result};

pub trait BlockSource {
    /// Copies each block of `blocks` (none owned by `ranks.rank`) into the matching
    /// `block_words`-long piece of `out`.
    fn fetch(&mut self, blocks: &[u32], out: &mut [u32]) -> Result<()>;
    /// A short name for traces and reports.
    fn name(&self) -> &'static str;
}

/// N in-process stores, each holding what one rank owns (slot order), as the ranks of a cluster
/// would: fetching block k copies it from store `k mod N`.
pub struct VirtualRanks {
    pub ranks: u32,
    block_words: usize,
    stores: Vec<Vec<u32>>,
}

impl VirtualRanks {
    pub fn new(blocks: &Blocks, n: u32) -> Result<VirtualRanks> {
        if n == 0 {
            return Err(Error::Invalid("virtual ranks must be at least 1".into()));
        }
        let bw = blocks.format.words() as usize;
        let mut stores = vec![Vec::new(); n as usize];
        for k in 0..blocks.count() {
            stores[(k % n) as usize].extend_from_slice(blocks.block(k));
        }
        Ok(VirtualRanks {
            ranks: n,
            block_words: bw,
            stores,
        })
    }

    /// Bytes rank `r` holds as owner.
    pub fn store_bytes(&self, r: u32) -> u64 {
        self.stores[r as usize].len() as u64 * 4
    }
}

impl BlockSource for VirtualRanks {
    fn fetch(&mut self, blocks: &[u32], out: &mut [u32]) -> Result<()> {
        let bw = self.block_words;
        let ranks = Ranks {
            n: self.ranks,
            rank: 0,
            replicated: 1,
        };
        for (&k, dst) in blocks.iter().zip(out.chunks_mut(bw)) {
            let store = &self.stores[ranks.owner(k) as usize];
            let s = ranks.slot(k) as usize * bw;
            let src = store
                .get(s..s + bw)
                .ok_or_else(|| Error::Invalid(format!("block {k} is past the end of the model")))?;
            dst.copy_from_slice(src);
        }
        Ok(())
    }

    fn name(&self) -> &'static str {
        "virtual-ranks"
    }
}

/// Reads borrowed blocks from the block file on demand, checking each block's checksum.
pub struct LocalFile {
    file: DcbFile,
    ranks: Ranks,
}

impl LocalFile {
    pub fn new(file: DcbFile, ranks: Ranks) -> LocalFile {
        LocalFile { file, ranks }
    }
}

impl BlockSource for LocalFile {
    fn fetch(&mut self, blocks: &[u32], out: &mut [u32]) -> Result<()> {
        let bw = self.file.format.words() as usize;
        for (&k, dst) in blocks.iter().zip(out.chunks_mut(bw)) {
            self.file.read_block_into(k, self.ranks.owner(k), dst)?;
        }
        Ok(())
    }

    fn name(&self) -> &'static str {
        "file"
    }
}
