//! The round loop (docs/ARCHITECTURE.md, The round loop): a batch's rays are traced in rounds of
//! `trace` (each live ray runs at most `step_budget` loop iterations, then saves its state) and
//! `args` (the count of rays still live becomes the next round's indirect dispatch). With a
//! distributed cache, every round's faults are read back and served (`dc::policy` decides,
//! the block source fetches, the store and the row table are updated) before the next round;
//! without one, several rounds go in one submission.

use super::batch::fault_bytes;
use super::kernels::Dispatch;
use super::layout::{FaultHeader, RoundReadback};
use super::tracer::{FrameStats, Gen, MAX_STACK, Tracer};
use crate::dc::trace::Round;
use crate::error::{Error, Result};
use std::mem::{offset_of, size_of};
use std::time::Instant;

const WORKGROUP: u32 = 64;

/// Byte offset and size of a `RoundReadback` member.
macro_rules! member {
    ($field:ident, $ty:ty) => {
        (
            offset_of!(RoundReadback, $field) as u64,
            size_of::<$ty>() as u64,
        )
    };
}

impl Tracer<'_> {
    /// Generates the batch's rays (primary, or a wave of secondary rays) and runs trace rounds
    /// until none is live: secondary rays fault, suspend and resume exactly as primary rays do.
    /// Returns how many rays entered traversal.
    pub(super) fn trace_batch(&mut self, stats: &mut FrameStats, gen_: Gen) -> Result<u32> {
        let gpu = self.gpu;
        gpu.write(&self.params_buf, &self.params);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        {
            let b = &self.batch;
            for c in &b.counters {
                enc.clear_buffer(c, 0, None);
            }
            enc.clear_buffer(&b.stats, 0, None);
            self.clear_faults(&mut enc);
            let k = &self.kernels;
            match (gen_, &k.spawn, &self.bound.spawn) {
                (Gen::Secondary { fan }, Some(spawn), Some(bound)) => {
                    let groups =
                        Dispatch::Direct((self.params.batch_rays * fan).div_ceil(WORKGROUP));
                    spawn.dispatch(&mut enc, bound, groups, None);
                }
                _ => {
                    let groups = Dispatch::Direct(self.params.batch_rays.div_ceil(WORKGROUP));
                    k.raygen
                        .dispatch(&mut enc, &self.bound.raygen, groups, None);
                }
            }
            k.args
                .dispatch(&mut enc, &self.bound.args[0], Dispatch::Direct(1), None);
            let (at, _) = member!(started, u32);
            enc.copy_buffer_to_buffer(&b.counters[0], 0, &b.readback, at, 4);
        }
        self.run_rounds(enc, stats)
    }

    /// Trace rounds until no ray is live, starting from the live list and counter 0 that `enc`
    /// has already prepared (with the first `args` dispatch recorded). Returns the live count
    /// the first round started with (`RoundReadback::started`, which ray generation copies).
    pub(super) fn run_rounds(
        &mut self,
        mut enc: wgpu::CommandEncoder,
        stats: &mut FrameStats,
    ) -> Result<u32> {
        let gpu = self.gpu;
        let mut started = None;
        // `cur` is the counter holding the live rays of the next round. With a cache, faults are
        // served after every round; without, several rounds go in one submission.
        let mut cur = 0usize;
        let mut per_check = if self.dc.is_some() { 1 } else { 2u32 };
        let mut live_rounds = 0u32;
        loop {
            let b = &self.batch;
            let k = &self.kernels;
            for i in 0..per_check {
                let o = 1 - cur;
                let ind = Dispatch::Indirect(&b.counters[cur]);
                let (first, last) = (i == 0, i + 1 == per_check);
                let trace = &self.bound.trace[cur];
                k.trace
                    .dispatch(&mut enc, trace, ind, self.stamps(first, false));
                let args = &self.bound.args[o];
                k.args.dispatch(
                    &mut enc,
                    args,
                    Dispatch::Direct(1),
                    self.stamps(false, last),
                );
                cur = o;
            }
            if let Some((q, resolve)) = &b.timestamps {
                let (at, size) = member!(timestamps, [u64; 2]);
                enc.resolve_query_set(q, 0..2, resolve, 0);
                enc.copy_buffer_to_buffer(resolve, 0, &b.readback, at, size);
            }
            stats.rounds += per_check;
            live_rounds += per_check;
            let (at, size) = member!(counter, super::layout::Counter);
            enc.copy_buffer_to_buffer(&b.counters[cur], 0, &b.readback, at, size);
            let (at, size) = member!(stats, super::layout::Stats);
            enc.copy_buffer_to_buffer(&b.stats, 0, &b.readback, at, size);
            self.copy_faults(&mut enc);
            let submitted = Instant::now();
            gpu.queue.submit([enc.finish()]);
            let data = gpu.map_read(&b.readback)?;
            let waited = submitted.elapsed();
            // Mapped bytes carry no alignment promise: read them unaligned.
            let r: RoundReadback = bytemuck::pod_read_unaligned(&data);
            let s = r.stats;
            if started.is_none() {
                started = Some(r.started);
            }
            let mut gpu_ms = None;
            if b.timestamps.is_some() {
                let period = f64::from(gpu.queue.get_timestamp_period());
                let t = r.timestamps;
                let secs = t[1].saturating_sub(t[0]) as f64 * period * 1e-9;
                stats.gpu_seconds += secs;
                gpu_ms = Some(secs * 1e3);
            }
            if s.overflows > 0 {
                return Err(Error::Gpu(format!(
                    "traversal stack overflow in {} rays: the BVH is deeper than the {}-entry \
                     stack (the model declares depth {}, the stack holds at most {MAX_STACK})",
                    s.overflows,
                    self.stack_size(),
                    self.depth
                )));
            }
            enc = gpu.device.create_command_encoder(&Default::default());
            if self.dc.is_some() {
                let faults = gpu.map_read(&self.batch.fault_readback)?;
                let waiters = gpu.map_read(&self.batch.waiter_readback)?;
                let when = (submitted, waited, gpu_ms);
                self.serve_faults(&faults, &waiters, r.counter.count, live_rounds, when, stats)?;
                self.clear_faults(&mut enc);
            }
            if r.counter.count == 0 {
                stats.steps += u64::from(s.steps);
                stats.tri_tests += u64::from(s.tri_tests);
                stats.lookups += u64::from(s.lookups);
                stats.hits += u64::from(s.hits);
                stats.misses += u64::from(s.misses);
                stats.node_visits += u64::from(s.node_visits);
                stats.block_entries += u64::from(s.block_entries);
                stats.tri_block_entries += u64::from(s.tri_block_entries);
                stats.max_live_rounds = stats.max_live_rounds.max(live_rounds);
                return Ok(started.unwrap_or(0));
            }
            if self.dc.is_none() {
                per_check = (per_check * 2).min(16);
            }
        }
    }

    /// Colour by data: the albedo of every hit on a mesh coloured by data, from the attribute
    /// blocks, for the ray slots `Params::albedo_stride` names (docs/ARCHITECTURE.md, Colour by
    /// data). With a distributed cache an absent attribute block is a fault: the round's faults
    /// are served as the trace rounds' are and the kernel runs again, skipping the slots already
    /// resolved, until a dispatch faults on nothing. A model without attributes does nothing.
    pub(super) fn resolve_albedos(&mut self, stats: &mut FrameStats) -> Result<()> {
        if self.kernels.albedo.is_none() {
            return Ok(());
        }
        let gpu = self.gpu;
        gpu.write(&self.params_buf, &self.params);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.batch.albedos, 0, None);
        let groups = self.params.batch_rays.div_ceil(WORKGROUP);
        for round in 0.. {
            self.clear_faults(&mut enc);
            if let (Some(k), Some(b)) = (&self.kernels.albedo, &self.bound.albedo) {
                k.dispatch(&mut enc, b, Dispatch::Direct(groups), None);
            }
            let Some(dc) = &self.dc else {
                gpu.queue.submit([enc.finish()]);
                return Ok(());
            };
            let wait_bytes = 4 * u64::from(dc.policy.lines());
            self.copy_faults(&mut enc);
            let submitted = Instant::now();
            gpu.queue.submit([enc.finish()]);
            let faults = gpu.map_read(&self.batch.fault_readback)?;
            let waiters = gpu.map_read(&self.batch.waiter_readback)?;
            let waited = submitted.elapsed();
            let header: FaultHeader =
                bytemuck::pod_read_unaligned(&faults[..size_of::<FaultHeader>()]);
            let when = (submitted, waited, None);
            if header.count == 0 {
                // Nothing to load; this counts the blocks the dispatch found in lines.
                return self.serve_faults(&faults, &waiters, 0, round, when, stats);
            }
            let waiting: u32 =
                bytemuck::pod_collect_to_vec::<u8, u32>(&waiters[..wait_bytes as usize])
                    .iter()
                    .sum();
            self.serve_faults(&faults, &waiters, waiting, round, when, stats)?;
            enc = gpu.device.create_command_encoder(&Default::default());
        }
        Ok(())
    }

    /// GPU timestamps at a pass's (beginning, end), when the adapter has them: the rounds' GPU
    /// time is measured from the first trace pass to the last `args` pass.
    fn stamps(&self, begin: bool, end: bool) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let (q, _) = self.batch.timestamps.as_ref()?;
        (begin || end).then_some(wgpu::ComputePassTimestampWrites {
            query_set: q,
            beginning_of_pass_write_index: begin.then_some(0),
            end_of_pass_write_index: end.then_some(1),
        })
    }

    /// Copies a round's fault list, the lines' waiting rays and then which lines the round used
    /// into the readback buffers `serve_faults` reads.
    fn copy_faults(&self, enc: &mut wgpu::CommandEncoder) {
        let Some(dc) = &self.dc else {
            return;
        };
        let (bufs, b) = (&self.dc_bufs, &self.batch);
        let bytes = fault_bytes(self.params.dc_fault_cap);
        enc.copy_buffer_to_buffer(&bufs.faults, 0, &b.fault_readback, 0, bytes);
        let wait_bytes = 4 * u64::from(dc.policy.lines());
        let r = &b.waiter_readback;
        enc.copy_buffer_to_buffer(&bufs.waiters, 0, r, 0, wait_bytes);
        enc.copy_buffer_to_buffer(&bufs.line_used, 0, r, wait_bytes, wait_bytes);
    }

    pub(super) fn clear_faults(&self, enc: &mut wgpu::CommandEncoder) {
        if self.dc.is_some() {
            let b = &self.dc_bufs;
            enc.clear_buffer(&b.faults, 0, Some(size_of::<FaultHeader>() as u64));
            enc.clear_buffer(&b.requested, 0, None);
            enc.clear_buffer(&b.waiters, 0, None);
            enc.clear_buffer(&b.line_used, 0, None);
        }
    }

    /// Serves a round's faults: the cache policy plans the loads, the block source fetches them
    /// in one call, and they are written into their cache rows and the row table.
    fn serve_faults(
        &mut self,
        faults: &[u8],
        waiters: &[u8],
        live: u32,
        round: u32,
        (submitted, waited, gpu_ms): (Instant, std::time::Duration, Option<f64>),
        stats: &mut FrameStats,
    ) -> Result<()> {
        let cap = self.params.dc_fault_cap;
        let Some(dc) = self.dc.as_mut() else {
            return Ok(());
        };
        let head = size_of::<FaultHeader>();
        let header: FaultHeader = bytemuck::pod_read_unaligned(&faults[..head]);
        let n = header.count.min(cap) as usize;
        let list: Vec<u32> = bytemuck::pod_collect_to_vec(&faults[head..head + 4 * n]);
        let lines = dc.policy.lines() as usize;
        let used: Vec<u32> = bytemuck::pod_collect_to_vec(&waiters[4 * lines..8 * lines]);
        // The frame's distinct borrowed blocks: those found in a line and those faulted on,
        // counted here (before the lines change) rather than marked by the GPU at every lookup.
        let in_lines = used.iter().enumerate().filter(|(_, u)| **u != 0);
        for block in in_lines.filter_map(|(line, _)| dc.policy.tag(line as u32)) {
            dc.looked_up[block as usize] = true;
        }
        for &block in &list {
            dc.looked_up[block as usize] = true;
        }
        if n == 0 {
            return Ok(());
        }
        let waiting: Vec<u32> = bytemuck::pod_collect_to_vec(&waiters[..4 * lines]);
        dc.policy.mark_used(&used);
        let plan = dc.policy.plan_round(&list, &waiting);
        let mut rec = Round {
            batch: stats.batches,
            round,
            live,
            dropped: header.dropped,
            source: dc.source.name().into(),
            faults: plan.faults,
            start_ms: Some(crate::dc::trace::ms_since_epoch(submitted)),
            wait_ms: Some(waited.as_secs_f64() * 1e3),
            gpu_ms,
            used_lines: used.iter().filter(|&&u| u != 0).count() as u32,
            ..Round::default()
        };
        let bw = self.format.words() as usize;
        let blocks: Vec<u32> = plan.loads.iter().map(|l| l.block).collect();
        let mut data = vec![0u32; blocks.len() * bw];
        let t = Instant::now();
        dc.source.fetch(&blocks, &mut data)?;
        let fetch = t.elapsed().as_secs_f64();
        let t = Instant::now();
        for (load, words) in plan.loads.iter().zip(data.chunks(bw)) {
            self.store.write_row(self.gpu, self.format, load.row, words);
        }
        for &(block, row) in &plan.rows {
            let at = u64::from(block) * 4;
            let rows = &self.dc_bufs.rows;
            self.gpu
                .queue
                .write_buffer(rows, at, bytemuck::bytes_of(&row));
        }
        let upload = t.elapsed().as_secs_f64();
        rec.fetched_blocks = plan.loads.len() as u32;
        rec.fetched_bytes = (plan.loads.len() * bw * 4) as u64;
        rec.fetch_us = fetch * 1e6;
        rec.upload_us = upload * 1e6;
        stats.fetched_blocks += u64::from(rec.fetched_blocks);
        stats.fetched_bytes += rec.fetched_bytes;
        stats.fetch_seconds += fetch;
        stats.upload_seconds += upload;
        stats.fault_rounds += 1;
        dc.trace.rounds.push(rec);
        Ok(())
    }
}
