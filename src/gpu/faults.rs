//! The distributed cache's GPU half (docs/ARCHITECTURE.md, The distributed cache): the buffers
//! the kernels record faults in, and, between traversal rounds, the service of a round's faults: the
//! fault list read back, `dc::policy` plans the loads, the block source fetches them, the store
//! and the row table are updated.

use super::Gpu;
use super::batch::fault_bytes;
use super::frame::FrameStats;
use super::kernels::Dispatch;
use super::layout::{FaultHeader, NONE, Params};
use super::row_table::RowTable;
use super::store::Rows;
use super::tracer::{DcSetup, FaultMode, Settings, Tracer};
use crate::dc::CacheMap;
use crate::dc::policy::CachePolicy;
use crate::dc::source::BlockSource;
use crate::error::{Error, Result};
use crate::traces::record::{FrameTrace, Round};
use std::mem::size_of;
use std::time::Instant;

/// Stack entries a ray with a distributed cache may set aside for absent blocks while it goes on
/// with what the GPU holds (`DEFER_SLOTS` in shaders/traverse.wgsl); its faults go out together.
pub const DEFER_SLOTS: u32 = 4;

/// A rank's cache while it traces: the policy, the block source and this frame's trace.
pub(super) struct Dc {
    pub policy: CachePolicy,
    pub source: Box<dyn BlockSource>,
    pub trace: FrameTrace,
    /// The borrowed blocks the frame has looked up so far: the blocks of the lines its rounds
    /// used and the blocks they faulted on (`serve_faults`).
    pub looked_up: Vec<bool>,
}

/// The distributed cache's GPU buffers (small placeholders, never read, when replicated).
pub(super) struct DcBuffers {
    pub rows: RowTable,
    pub faults: wgpu::Buffer,
    /// Per block, the complement of its least requester this round (`request` in
    /// shaders/shared/dc.wgsl); the `requesters` kernel moves the listed blocks' words into the
    /// fault list and clears them.
    pub requested: wgpu::Buffer,
    /// Whether `requested` may hold words the `requesters` kernel did not clear (blocks requested
    /// past the fault list's capacity): the next round then starts by clearing it whole.
    pub requested_dirty: std::cell::Cell<bool>,
    pub waiters: wgpu::Buffer,
    pub line_used: wgpu::Buffer,
}

impl Dc {
    /// A rank's cache and its GPU buffers, with its fields of `params` set; and whether the
    /// cache holds every borrowed block (then batches fit it from the first frame).
    pub fn new(
        gpu: &Gpu,
        d: DcSetup,
        rows: &Rows<'_>,
        settings: Settings,
        (blocks, node_blocks): (u32, u32),
        params: &mut Params,
    ) -> Result<(Dc, DcBuffers, bool)> {
        use wgpu::BufferUsages as U;
        let resident = rows.resident_rows();
        let expect = d.ranks.resident_rows(blocks);
        if resident != expect {
            return Err(Error::Invalid(format!(
                "rank {} of {} should hold {expect} resident blocks, was given {resident}",
                d.ranks.rank, d.ranks.n
            )));
        }
        let policy = CachePolicy::new(d.ranks, d.map, d.lines, blocks, node_blocks)
            .with_fetch_ahead(settings.fetch_ahead);
        params.dc_ranks = d.ranks.n;
        params.dc_rank = d.ranks.rank;
        params.dc_lines = d.lines;
        params.dc_map = match d.map {
            CacheMap::Ize => 0,
            CacheMap::Demarle | CacheMap::Lru => 1,
        };
        params.dc_cache_row = policy.cache_row();
        params.dc_root_row = d.ranks.root_row(blocks);
        params.dc_fault_cap = settings.fault_cap;
        // Until a frame shows its blocks, set aside only when the cache holds every borrowed
        // block.
        let fits = d.lines >= blocks - resident;
        params.dc_defer = defer_slots(settings, fits);
        let buffer =
            |label, bytes| gpu.buffer(label, bytes, U::STORAGE | U::COPY_SRC | U::COPY_DST);
        let bufs = DcBuffers {
            rows: RowTable::new(gpu, policy.block_rows())?,
            faults: buffer("faults", fault_bytes(settings.fault_cap)),
            requested: buffer("requested", 4 * u64::from(blocks)),
            requested_dirty: true.into(),
            waiters: buffer("waiters", 4 * u64::from(d.lines)),
            line_used: buffer("line used", 8 * u64::from(d.lines)),
        };
        let dc = Dc {
            policy,
            source: d.source,
            trace: FrameTrace::default(),
            looked_up: vec![false; blocks as usize],
        };
        Ok((dc, bufs, fits))
    }
}

impl DcBuffers {
    /// A replicated model binds small placeholders the kernels never read.
    pub fn placeholder(gpu: &Gpu) -> DcBuffers {
        let p = || gpu.buffer("unused", 32, wgpu::BufferUsages::STORAGE);
        DcBuffers {
            rows: RowTable::placeholder(gpu),
            faults: p(),
            requested: p(),
            requested_dirty: false.into(),
            waiters: p(),
            line_used: p(),
        }
    }
}

/// Set-aside slots a ray may use in a frame (`Params::dc_defer`). Only when the frame's blocks fit
/// the cache: a ray that goes on past an absent block also faults on blocks a nearer hit would
/// have culled, and where the cache is short those extra fetches evict blocks other rays need
/// (measured: at a 1/8 cache, 8-25% more fetches and no fewer rounds; at 1/1, 45% fewer rounds).
pub(super) fn defer_slots(settings: Settings, fits: bool) -> u32 {
    let on = match settings.faults {
        FaultMode::Fit => fits,
        FaultMode::Never => false,
        FaultMode::Always => true,
    };
    if on { DEFER_SLOTS } else { 0 }
}

impl Tracer<'_> {
    /// Records the `requesters` kernel (each listed block's least requester into the fault list,
    /// its `requested` word cleared), then copies the round's fault list, the lines' waiting rays
    /// and which lines the round used and which its rays still live keep into the readback
    /// buffers `serve_faults` reads.
    pub(super) fn copy_faults(&self, enc: &mut wgpu::CommandEncoder) {
        let Some(dc) = &self.dc else {
            return;
        };
        let (bufs, b) = (&self.dc_bufs, &self.batch);
        let k = &self.kernels.requesters;
        k.dispatch(enc, &self.bound.requesters, Dispatch::Groups(1), None);
        let bytes = fault_bytes(self.params.dc_fault_cap);
        enc.copy_buffer_to_buffer(&bufs.faults, 0, &b.fault_readback, 0, bytes);
        let wait_bytes = 4 * u64::from(dc.policy.lines());
        let r = &b.waiter_readback;
        enc.copy_buffer_to_buffer(&bufs.waiters, 0, r, 0, wait_bytes);
        enc.copy_buffer_to_buffer(&bufs.line_used, 0, r, wait_bytes, 2 * wait_bytes);
    }

    pub(super) fn clear_faults(&self, enc: &mut wgpu::CommandEncoder) {
        if self.dc.is_some() {
            let b = &self.dc_bufs;
            enc.clear_buffer(&b.faults, 0, Some(size_of::<FaultHeader>() as u64));
            // The `requesters` kernel cleared every listed block's word; only a round that
            // dropped faults leaves others set, and a set word would never list its block again.
            if b.requested_dirty.replace(false) {
                enc.clear_buffer(&b.requested, 0, None);
            }
            enc.clear_buffer(&b.waiters, 0, None);
            enc.clear_buffer(&b.line_used, 0, None);
        }
    }

    /// Reads back a round's fault list and its blocks' least requesters (`copy_faults`).
    pub(super) fn read_faults(&self) -> Result<FaultList> {
        let bytes = self.gpu.map_read(&self.batch.fault_readback)?;
        let faults = FaultList::read(&bytes, self.params.dc_fault_cap);
        if faults.header.dropped > 0 {
            self.dc_bufs.requested_dirty.set(true);
        }
        Ok(faults)
    }

    /// Serves a round's faults, in the list's order: the cache policy plans the loads, the block
    /// source fetches them in one call, and they are written into their cache rows and the row
    /// table. Returns how many of the faults got no line this round (they fault again).
    pub(super) fn serve_faults(
        &mut self,
        faults: &FaultList,
        waiters: &[u8],
        live: u32,
        round: u32,
        (submitted, waited, gpu_ms): (Instant, std::time::Duration, Option<f64>),
        stats: &mut FrameStats,
    ) -> Result<u32> {
        let Some(dc) = self.dc.as_mut() else {
            return Ok(0);
        };
        let (header, list) = (faults.header, &faults.blocks);
        let lines = dc.policy.lines() as usize;
        let used: Vec<u32> = bytemuck::pod_collect_to_vec(&waiters[4 * lines..8 * lines]);
        // The frame's distinct borrowed blocks: those found in a line and those faulted on,
        // counted here (before the lines change) rather than marked by the GPU at every lookup.
        let in_lines = used.iter().enumerate().filter(|(_, u)| **u != 0);
        for block in in_lines.filter_map(|(line, _)| dc.policy.tag(line as u32)) {
            dc.looked_up[block as usize] = true;
        }
        for &block in list {
            dc.looked_up[block as usize] = true;
        }
        if list.is_empty() {
            return Ok(header.count);
        }
        let waiting: Vec<u32> = bytemuck::pod_collect_to_vec(&waiters[..4 * lines]);
        let kept: Vec<u32> = bytemuck::pod_collect_to_vec(&waiters[8 * lines..12 * lines]);
        dc.policy.mark_used(&used, &kept);
        let plan = dc.policy.plan_round(list, &waiting);
        let demand = plan.served();
        let mut rec = Round {
            batch: stats.batches,
            round,
            live,
            dropped: header.dropped,
            source: dc.source.name().into(),
            faults: plan.faults,
            start_ms: Some(crate::traces::record::ms_since_epoch(submitted)),
            wait_ms: Some(waited.as_secs_f64() * 1e3),
            gpu_ms,
            used_lines: used.iter().filter(|&&u| u != 0).count() as u32,
            kept_lines: kept.iter().filter(|&&u| u != 0).count() as u32,
            ..Round::default()
        };
        let bw = self.format.words() as usize;
        // In row order, so that loads into adjacent lines go up in one write.
        let mut loads = plan.loads.clone();
        loads.sort_unstable_by_key(|l| l.row);
        let blocks: Vec<u32> = loads.iter().map(|l| l.block).collect();
        let mut data = vec![0u32; blocks.len() * bw];
        let t = Instant::now();
        dc.source.fetch(&blocks, &mut data)?;
        let fetch = t.elapsed().as_secs_f64();
        for (i, l) in loads.iter().enumerate() {
            if dc.policy.wants_children(l.block) {
                let words = &data[i * bw..(i + 1) * bw];
                let node_blocks = self.params.node_blocks;
                let children = self.format.child_blocks(l.block, words, node_blocks);
                dc.policy.learn_children(l.block, children)?;
            }
        }
        let t = Instant::now();
        let mut i = 0;
        while i < loads.len() {
            let run = 1 + loads[i + 1..]
                .iter()
                .zip(&loads[i..])
                .take_while(|(next, prev)| next.row == prev.row + 1)
                .count();
            let words = &data[i * bw..(i + run) * bw];
            self.store
                .write_rows(self.gpu, self.format, loads[i].row, words);
            i += run;
        }
        let mut changed: Vec<u32> = plan.rows.iter().map(|&(block, _)| block).collect();
        let table = dc.policy.block_rows();
        self.dc_bufs.rows.update(self.gpu, &mut changed, table);
        let upload = t.elapsed().as_secs_f64();
        let loaded = plan.loads.len() as u32;
        rec.fetched_blocks = loaded;
        rec.ahead = plan.loads[demand..].iter().map(|l| l.block).collect();
        rec.fetched_bytes = (plan.loads.len() * bw * 4) as u64;
        rec.fetch_us = fetch * 1e6;
        rec.upload_us = upload * 1e6;
        stats.fetched_blocks += u64::from(rec.fetched_blocks);
        stats.fetched_bytes += rec.fetched_bytes;
        stats.fetch_seconds += fetch;
        stats.upload_seconds += upload;
        stats.fault_rounds += 1;
        dc.trace.rounds.push(rec);
        Ok(header.count - demand as u32)
    }
}

/// A round's fault list as read back: the blocks (at most the list's capacity) and each one's
/// requester (`requester_lane`).
pub(super) struct FaultList {
    pub header: FaultHeader,
    pub blocks: Vec<u32>,
    pub requesters: Vec<u32>,
}

impl FaultList {
    /// Parses the fault buffer's bytes (`batch::fault_bytes(cap)`: the header, `cap` block words,
    /// then `cap` words of the blocks' least requesters as the `requesters` kernel copied them
    /// from `requested`: the complement of the requester, 1 for a kernel without rays).
    pub fn read(bytes: &[u8], cap: u32) -> FaultList {
        let head = size_of::<FaultHeader>();
        let header: FaultHeader = bytemuck::pod_read_unaligned(&bytes[..head]);
        let n = header.count.min(cap) as usize;
        let blocks: Vec<u32> = bytemuck::pod_collect_to_vec(&bytes[head..][..4 * n]);
        let keys: Vec<u32> =
            bytemuck::pod_collect_to_vec(&bytes[head + 4 * cap as usize..][..4 * n]);
        let requesters = keys
            .iter()
            .map(|&key| if key <= 1 { NONE } else { !key })
            .collect();
        FaultList {
            header,
            blocks,
            requesters,
        }
    }

    /// Orders the faults by `keys` (one a fault), ties by block: the order the GPU listed them
    /// in depends on how its threads interleaved.
    pub fn order_by(&mut self, keys: &[u64]) {
        let mut order: Vec<usize> = (0..self.blocks.len()).collect();
        order.sort_by_key(|&i| (keys[i], self.blocks[i]));
        self.blocks = order.iter().map(|&i| self.blocks[i]).collect();
        self.requesters = order.iter().map(|&i| self.requesters[i]).collect();
    }
}

/// The key a fault is served by (lowest first): the age of its requester's batch, then the
/// requester's ray slot, which follows the batch's tiles. The GPU lists faults in the order its
/// workgroups ran, which a driver on several threads interleaves from run to run; in ray order
/// the lines go to whole tiles first, as a driver on one thread hands them out. `rm` 3M at 1/32
/// with the nodes replicated, rank 0 of 8, llvmpipe on two threads: 32.0 → 28.2 fault rounds a
/// warm frame and 11,295 → 10,674 blocks (on one thread 27.8 and 10,664 either way).
pub(super) fn serve_order(age: u64, ray: u32) -> u64 {
    (age << 32) | u64::from(ray)
}

/// Bits of a fault's requester below the lane, as shaders/shared/dc.wgsl declares them.
const REQUESTER_LANE_SHIFT: u32 = super::shaders::wgsl::REQUESTER_LANE_SHIFT;

/// The lane and ray slot of a fault's requester, as `requester` in shaders/shared/dc.wgsl packs
/// them; `None` for a fault no ray slot listed (the colour-by-data kernel's).
pub(super) fn requester_lane(who: u32) -> Option<(usize, u32)> {
    let slot_mask = (1 << REQUESTER_LANE_SHIFT) - 1;
    (who != NONE).then_some(((who >> REQUESTER_LANE_SHIFT) as usize, who & slot_mask))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fault_list_reads_its_requesters_and_serves_the_oldest_batch_first() {
        // Capacity 4, three faults listed, then the listed blocks' least requesters, complemented
        // (shaders/requesters.wgsl): block 1's a kernel without rays (1).
        let who = |lane: u32, ray: u32| (lane << REQUESTER_LANE_SHIFT) | ray;
        let header = FaultHeader {
            count: 3,
            ..Default::default()
        };
        let mut bytes = bytemuck::bytes_of(&header).to_vec();
        let words = [2u32, 1, 0, 7, !who(2, 5), 1, 0, !who(0, 3)];
        bytes.extend(words.iter().flat_map(|w| w.to_ne_bytes()));
        let mut f = FaultList::read(&bytes, 4);
        assert_eq!(f.blocks, [2, 1, 0]);
        assert_eq!(requester_lane(f.requesters[0]), Some((2, 5)));
        assert_eq!(requester_lane(f.requesters[1]), None);
        // Block 0 listed but never requested (cannot happen) reads as no requester.
        assert_eq!(requester_lane(f.requesters[2]), None);
        // Ages 3, none (last), none: the oldest first, ties by block.
        f.order_by(&[3, u64::MAX, u64::MAX]);
        assert_eq!(f.blocks, [2, 0, 1]);
        assert_eq!(f.requesters[0], who(2, 5));
    }

    #[test]
    fn faults_are_served_by_batch_age_then_ray_slot() {
        // An older batch's last ray before a newer batch's first; within a batch, by slot.
        assert!(serve_order(3, (1 << 28) - 1) < serve_order(4, 0));
        assert!(serve_order(4, 7) < serve_order(4, 8));
        // Listed as the GPU's threads interleaved them; one without a requester (u64::MAX)
        // last.
        let keys = [
            u64::MAX,
            serve_order(1, 900),
            serve_order(0, 5),
            serve_order(1, 2),
        ];
        let mut f = FaultList {
            header: FaultHeader::default(),
            blocks: vec![9, 10, 11, 12],
            requesters: vec![0; 4],
        };
        f.order_by(&keys);
        assert_eq!(f.blocks, [11, 12, 10, 9]);
    }
}
