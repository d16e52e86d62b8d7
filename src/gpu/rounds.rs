//! The round loop (docs/ARCHITECTURE.md, The round loop): a batch's rays are traced in rounds of
//! `trace` (each live ray runs at most `step_budget` loop iterations, then saves its state) and
//! `args` (the count of rays still live becomes the next round's indirect dispatch). With a
//! distributed cache, every round's faults are read back and served (`dc::policy` decides,
//! the block source fetches, the store and the row table are updated) before the next round;
//! without one, several rounds go in one submission.

use super::batch::{Batch, TILE_RAYS, fault_bytes};
use super::frame::Rect;
use super::kernels::Dispatch;
use super::layout::{FaultHeader, NONE, Params, Pixel, RoundReadback, Stats};
use super::tracer::{
    BoundKernels, FrameStats, Gen, MAX_STACK, MIN_FIT_PIXELS, Next, RectSource, Tracer,
};
use crate::dc::CacheMap;
use crate::dc::trace::Round;
use crate::error::{Error, Result};
use crate::mirror::tiles::{TILE, Tiling, tile_pixel};
use crate::scene::CameraBasis;
use std::collections::{HashSet, VecDeque};
use std::mem::{offset_of, size_of};
use std::ops::{Range, RangeInclusive};
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
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        self.clear_faults(&mut enc);
        self.record_start(&mut enc, 0, gen_);
        self.run_rounds(enc, stats)
    }

    /// The batch buffers, parameter buffer and bind groups of lane `l`: 0 is the current lane,
    /// 1.. the spares (`Tracer::swap_lanes`).
    fn lane(&self, l: usize) -> (&Batch, &wgpu::Buffer, &BoundKernels) {
        match l.checked_sub(1).and_then(|i| self.spares.get(i)) {
            Some(s) => (&s.batch, &s.params_buf, &s.bound),
            None => (&self.batch, &self.params_buf, &self.bound),
        }
    }

    /// Starts a batch in lane `l`: writes `Params` into its buffer, clears its counters and
    /// stats, and records ray generation (or a wave's spawn) into list 0, `args` on counter 0 and
    /// the copy of the started count into the lane's read-back.
    fn record_start(&self, enc: &mut wgpu::CommandEncoder, l: usize, gen_: Gen) {
        let (b, params_buf, bound) = self.lane(l);
        let params = Params {
            lane: l as u32,
            ..self.params
        };
        self.gpu.write(params_buf, &params);
        for c in &b.counters {
            enc.clear_buffer(c, 0, None);
        }
        enc.clear_buffer(&b.stats, 0, None);
        let k = &self.kernels;
        match (gen_, &k.spawn, &bound.spawn) {
            (Gen::Secondary { fan }, Some(spawn), Some(sb)) => {
                let groups = Dispatch::Direct((self.params.batch_rays * fan).div_ceil(WORKGROUP));
                spawn.dispatch(enc, sb, groups, None);
            }
            _ => {
                let groups = Dispatch::Direct(self.params.batch_rays.div_ceil(WORKGROUP));
                k.raygen.dispatch(enc, &bound.raygen, groups, None);
            }
        }
        k.args
            .dispatch(enc, &bound.args[0], Dispatch::Direct(1), None);
        let (at, _) = member!(started, u32);
        enc.copy_buffer_to_buffer(&b.counters[0], 0, &b.readback, at, 4);
    }

    /// Records one round of lane `l` (its rays in list `cur`) and the copies of the new live
    /// count and the stats into the lane's read-back; timestamps as `stamps` says. Returns the
    /// list the next round reads.
    fn record_round(
        &self,
        enc: &mut wgpu::CommandEncoder,
        l: usize,
        cur: usize,
        (first, last): (bool, bool),
    ) -> usize {
        let (b, _, bound) = self.lane(l);
        let k = &self.kernels;
        let o = 1 - cur;
        let ind = Dispatch::Indirect(&b.counters[cur]);
        // A frame that sets nothing aside runs the kernel without the set-aside code.
        let (trace, trace_bound) = match (&k.trace_suspending, &bound.trace_suspending) {
            (Some(t), Some(b)) if self.params.dc_defer == 0 => (t, &b[cur]),
            _ => (&k.trace, &bound.trace[cur]),
        };
        trace.dispatch(enc, trace_bound, ind, self.stamps(first, false));
        let groups = Dispatch::Direct(1);
        k.args
            .dispatch(enc, &bound.args[o], groups, self.stamps(false, last));
        let (at, size) = member!(counter, super::layout::Counter);
        enc.copy_buffer_to_buffer(&b.counters[o], 0, &b.readback, at, size);
        let (at, size) = member!(stats, super::layout::Stats);
        enc.copy_buffer_to_buffer(&b.stats, 0, &b.readback, at, size);
        o
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
        // The batch's steps and live rays after the last round: `stalled`.
        let mut last = (0u32, u32::MAX);
        loop {
            for i in 0..per_check {
                cur = self.record_round(&mut enc, 0, cur, (i == 0, i + 1 == per_check));
            }
            let b = &self.batch;
            if let Some((q, resolve)) = &b.timestamps {
                let (at, size) = member!(timestamps, [u64; 2]);
                enc.resolve_query_set(q, 0..2, resolve, 0);
                enc.copy_buffer_to_buffer(resolve, 0, &b.readback, at, size);
            }
            stats.rounds += per_check;
            live_rounds += per_check;
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
            let gpu_ms = self.round_gpu_ms(&r, stats);
            self.check_overflows(&s)?;
            enc = gpu.device.create_command_encoder(&Default::default());
            if self.dc.is_some() {
                let mut faults = self.read_faults()?;
                // One batch: its faults by requester ray slot, as `render_overlapped` serves them.
                let keys: Vec<u64> = faults
                    .requesters
                    .iter()
                    .map(|&who| {
                        requester_lane(who).map_or(u64::MAX, |(_, ray)| serve_order(0, ray))
                    })
                    .collect();
                faults.order_by(&keys);
                let moved = (s.steps, r.counter.count) != last;
                if stalled(r.counter.count, moved, faults.header.count) {
                    return Err(stall_error(r.counter.count, live_rounds));
                }
                last = (s.steps, r.counter.count);
                let waiters = gpu.map_read(&self.batch.waiter_readback)?;
                let when = (submitted, waited, gpu_ms);
                self.serve_faults(&faults, &waiters, r.counter.count, live_rounds, when, stats)?;
                self.clear_faults(&mut enc);
            }
            if r.counter.count == 0 {
                add_batch_stats(stats, &s, live_rounds);
                return Ok(started.unwrap_or(0));
            }
            if self.dc.is_none() {
                per_check = (per_check * 2).min(16);
            }
        }
    }

    /// A round's GPU time from its read-back timestamps, added to the frame's; `None` when the
    /// adapter has no timestamps.
    fn round_gpu_ms(&self, r: &RoundReadback, stats: &mut FrameStats) -> Option<f64> {
        self.batch.timestamps.as_ref()?;
        let period = f64::from(self.gpu.queue.get_timestamp_period());
        let t = r.timestamps;
        let secs = t[1].saturating_sub(t[0]) as f64 * period * 1e-9;
        stats.gpu_seconds += secs;
        Some(secs * 1e3)
    }

    /// A stack overflow in any ray of a round is an error naming the BVH depth.
    fn check_overflows(&self, s: &Stats) -> Result<()> {
        if s.overflows == 0 {
            return Ok(());
        }
        Err(Error::Gpu(format!(
            "traversal stack overflow in {} rays: the BVH is deeper than the {}-entry stack (the \
             model declares depth {}, the stack holds at most {MAX_STACK})",
            s.overflows,
            self.stack_size(),
            self.depth
        )))
    }

    /// Traces and shades the rectangles `source` hands out, batches of them overlapping
    /// (docs/ARCHITECTURE.md, Overlapping batches): when the live rays of every batch in flight
    /// are down to a `TAIL_SHARE`th of those it started with (and, unless the cache is `lru`,
    /// the last round used at most half the cache's lines), the next batch (of this rectangle, or of the next one the source
    /// has) starts in a free lane, and each round dispatches `trace` in every lane with a batch
    /// and serves their faults together. A batch whose rays are all done is resolved, shaded and
    /// read back in its lane; a rectangle whose batches are all done goes to `source.done`. With
    /// `passes`, each finished batch is reported to the progress callback.
    pub(super) fn render_overlapped(
        &mut self,
        basis: &CameraBasis,
        background: [f32; 3],
        source: &mut dyn RectSource,
        passes: Option<u64>,
        stats: &mut FrameStats,
    ) -> Result<()> {
        let gpu = self.gpu;
        let mut runs: Vec<Option<LaneRun>> = (0..=self.spares.len()).map(|_| None).collect();
        // Batches not started yet, and the pixels of rectangles with batches left.
        let mut pending: VecDeque<LaneRun> = VecDeque::new();
        let mut open: Vec<Option<OpenRect>> = Vec::new();
        let mut ended = false;
        let mut round = 0;
        // Tiles handed out and done, for the progress callback.
        let (mut total_tiles, mut done_tiles) = (0u64, 0u64);
        // Lines the last round used, and whether its faults that got no line are few enough for
        // a new batch to start beside them (`next_batch_may_start`, `few_left_waiting`).
        let mut used_lines = 0;
        let mut all_served = false;
        // Batches started this frame: a batch's age.
        let mut started_batches = 0u64;
        let lines = self.dc.as_ref().map_or(0, |dc| dc.policy.lines());
        let keeps_tails = self
            .dc
            .as_ref()
            .is_some_and(|dc| dc.policy.map() == CacheMap::Lru);
        let nodes_resident = self
            .dc
            .as_ref()
            .is_some_and(|dc| dc.policy.nodes_resident());
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.clear_faults(&mut enc);
        loop {
            let t = Instant::now();
            let busy = runs.iter().any(Option::is_some);
            let in_tail = runs.iter().flatten().all(LaneRun::in_tail);
            let tails = next_batch_may_start(
                busy,
                in_tail,
                keeps_tails && all_served,
                keeps_tails,
                (used_lines, lines),
            );
            let free = runs.iter().position(Option::is_none);
            if tails && free.is_some() && pending.is_empty() && !ended {
                match source.next(busy)? {
                    Next::Rect(rect) => {
                        let plan = self.begin_rect(basis, background, rect)?;
                        let slot = open.len();
                        // All its tiles, waiting; each batch takes its share when it starts.
                        let mut all = LaneRun::new(rect, plan.tiling, slot, 0, plan.tiles);
                        all.per_batch = plan.per_batch;
                        pending.push_back(all);
                        total_tiles += u64::from(plan.tiles);
                        let pixels = vec![Pixel::default(); rect.pixels()];
                        open.push(Some(OpenRect { pixels, batches: 1 }));
                        stats.rays += rect.pixels() as u64;
                        stats.samples = self.params.spp;
                        self.several_batches |= open.len() > 1;
                    }
                    Next::Later => {}
                    Next::End => ended = true,
                }
            }
            let start = free.filter(|_| tails);
            if let Some((l, mut run)) = start.and_then(|l| pending.pop_front().map(|r| (l, r))) {
                let lane_rays = self.lane(l).0.rays_cap;
                let n = self.batch_tiles(&run, lane_rays);
                // A batch past its lane's buffers would lose rays silently: refuse it.
                if u64::from(n) * u64::from(TILE_RAYS) > u64::from(lane_rays) {
                    return Err(Error::Gpu(format!(
                        "a batch of {n} tiles does not fit lane {l} of {lane_rays} rays"
                    )));
                }
                if n < run.tiles {
                    let mut rest =
                        LaneRun::new(run.rect, run.tiling, run.slot, run.first + n, run.tiles - n);
                    rest.per_batch = run.per_batch;
                    pending.push_front(rest);
                    run.tiles = n;
                    if let Some(r) = open[run.slot].as_mut() {
                        r.batches += 1;
                    }
                }
                self.set_rect(run.rect, run.tiling);
                self.params.first_tile = run.first;
                self.params.batch_rays = run.tiles * TILE_RAYS;
                self.record_start(&mut enc, l, Gen::Primary);
                run.age = started_batches;
                started_batches += 1;
                runs[l] = Some(run);
            }
            let active: Vec<usize> = (0..runs.len()).filter(|&l| runs[l].is_some()).collect();
            if active.is_empty() {
                if ended && pending.is_empty() {
                    return Ok(());
                }
                // The source had nothing at hand while nothing was in flight: ask again.
                continue;
            }
            for (i, &l) in active.iter().enumerate() {
                let run = runs[l].as_mut().expect("an active lane has a batch");
                let ends = (i == 0, i + 1 == active.len());
                run.list = self.record_round(&mut enc, l, run.list, ends);
                run.rounds += 1;
            }
            // The timestamps (lane 0's queries) go into the first active lane's read-back.
            if let (Some((q, resolve)), Some(&l)) = (&self.batch.timestamps, active.first()) {
                let (at, size) = member!(timestamps, [u64; 2]);
                enc.resolve_query_set(q, 0..2, resolve, 0);
                enc.copy_buffer_to_buffer(resolve, 0, &self.lane(l).0.readback, at, size);
            }
            self.copy_faults(&mut enc);
            let submitted = Instant::now();
            gpu.queue.submit([enc.finish()]);
            round += 1;
            stats.rounds += active.len() as u32;
            stats.shared_rounds += u32::from(active.len() > 1);
            let mut live = 0;
            let mut gpu_ms = None;
            let mut done = Vec::new();
            let mut dispatched = Vec::new();
            let mut moved = false;
            for &l in &active {
                let data = gpu.map_read(&self.lane(l).0.readback)?;
                let r: RoundReadback = bytemuck::pod_read_unaligned(&data);
                self.check_overflows(&r.stats)?;
                if Some(&l) == active.first() {
                    gpu_ms = self.round_gpu_ms(&r, stats);
                }
                let run = runs[l].as_mut().expect("an active lane has a batch");
                // The rays this round traced in the lane.
                let traced = if run.started.is_none() {
                    r.started
                } else {
                    run.live
                };
                dispatched.push((l, traced));
                run.started.get_or_insert(r.started);
                moved |= (r.stats.steps, r.counter.count) != (run.steps, run.live);
                run.steps = r.stats.steps;
                run.live = r.counter.count;
                live += run.live;
                if run.live == 0 {
                    add_batch_stats(stats, &r.stats, run.rounds);
                    stats.traced_rays += u64::from(run.started.unwrap_or(0));
                    done.push(l);
                }
            }
            let waited = submitted.elapsed();
            let mut faults = self.read_faults()?;
            if stalled(live, moved, faults.header.count) {
                return Err(stall_error(live, round));
            }
            let waiters = gpu.map_read(&self.batch.waiter_readback)?;
            let used: &[u8] = &waiters[4 * lines as usize..8 * lines as usize];
            used_lines = used.chunks(4).filter(|u| u != &[0; 4]).count() as u32;
            // Each listed block counts to the tile of its least requester, and the oldest
            // batch's blocks get lines first (`serve_order`): its rays hold a lane, and its
            // faults would otherwise wait behind those of every newer batch.
            let mut ages = Vec::with_capacity(faults.blocks.len());
            for (&block, &who) in faults.blocks.iter().zip(&faults.requesters) {
                let run = requester_lane(who)
                    .and_then(|(l, ray)| Some((runs.get_mut(l)?.as_mut()?, ray)));
                ages.push(run.map_or(u64::MAX, |(run, ray)| {
                    run.note_fault(block, ray / TILE_RAYS);
                    serve_order(run.age, ray)
                }));
            }
            faults.order_by(&ages);
            for &l in &done {
                let run = runs[l].as_ref().expect("a finished lane has a batch");
                let tiles = run.first..run.first + run.tiles;
                self.note_batch_faults(run.rect, run.tiling, tiles, &run.tile_faults);
            }
            let waiting = self.serve_faults(
                &faults,
                &waiters,
                live,
                round,
                (submitted, waited, gpu_ms),
                stats,
            )?;
            all_served = few_left_waiting(waiting, lines, nodes_resident);
            stats.trace_seconds += t.elapsed().as_secs_f64();
            for l in done {
                let t = Instant::now();
                let run = runs[l].take().expect("a finished lane had a batch");
                let rect = open[run.slot]
                    .as_mut()
                    .expect("a batch's rectangle is open");
                self.set_rect(run.rect, run.tiling);
                self.params.first_tile = run.first;
                self.params.batch_rays = run.tiles * TILE_RAYS;
                self.swap_lanes(l);
                let shaded = self.shade_batch(&run, &mut rect.pixels, stats);
                self.swap_lanes(l);
                shaded?;
                rect.batches -= 1;
                if rect.batches == 0 {
                    let pixels = std::mem::take(&mut rect.pixels);
                    open[run.slot] = None;
                    source.done(run.rect, pixels)?;
                }
                stats.shade_seconds += t.elapsed().as_secs_f64();
                done_tiles += u64::from(run.tiles);
                if let (Some(p), Some(n)) = (self.progress.as_mut(), passes) {
                    // Batches vary in size: the share of tiles done, in passes.
                    p((done_tiles * n).div_ceil(total_tiles.max(1)), n);
                }
            }
            enc = gpu.device.create_command_encoder(&Default::default());
            self.clear_faults(&mut enc);
        }
    }

    /// The last frame's faults per 8x8 tile of its rectangle, row by row (`FaultDensity`): of the
    /// blocks each tile's batch faulted on, how many had a ray of the tile as least requester.
    /// `None` until a frame has been traced in batches sized to a short cache.
    pub fn tile_faults(&self) -> Option<(Rect, Vec<f64>)> {
        let d = self.density.as_ref()?;
        Some((d.rect, d.per_tile.clone()))
    }

    /// The tiles the next batch of `run`'s rectangle takes. With a short cache and last frame's
    /// fault density of the rectangle, as many as are expected to fault `fill_share` times the
    /// cache's lines (`FaultDensity::batch`), so that a batch over a dense part of the image is
    /// smaller than one over a sparse part; otherwise the rectangle's even share
    /// (`RectPlan::per_batch`). Never more than the `lane_rays` of the lane it starts in.
    fn batch_tiles(&self, run: &LaneRun, lane_rays: u32) -> u32 {
        let lane_tiles = (lane_rays / TILE_RAYS).max(1);
        let even = run.per_batch.min(run.tiles).min(lane_tiles);
        let (Some(d), Some(dc)) = (&self.density, &self.dc) else {
            return even;
        };
        if d.rect != run.rect || !self.fits_by_batches() {
            return even;
        }
        let target = f64::from(dc.policy.lines()) * fill_share(self.spares.len());
        let most = run.tiles.min(lane_tiles);
        let least = MIN_FIT_PIXELS / TILE_RAYS;
        d.batch(run.tiling, run.first, least..=most, target)
    }

    /// Records the faults of a finished batch (per tile of `tiles` of `rect` in `tiling`'s order)
    /// into this frame's fault density, for the next frame's `batch_tiles`.
    fn note_batch_faults(&mut self, rect: Rect, tiling: Tiling, tiles: Range<u32>, faults: &[u32]) {
        if self.dc.is_none() || !self.fits_by_batches() {
            return;
        }
        let d = self
            .next_density
            .get_or_insert_with(|| FaultDensity::new(rect, tiling));
        if d.rect != rect {
            *d = FaultDensity::new(rect, tiling);
        }
        d.note(tiling, tiles, faults);
    }

    /// Resolves albedos, shades and reads back the current lane's traced batch.
    fn shade_batch(
        &mut self,
        run: &LaneRun,
        pixels: &mut [Pixel],
        stats: &mut FrameStats,
    ) -> Result<()> {
        self.resolve_albedos(stats)?;
        self.run(&self.kernels.shade, &self.bound.shade);
        self.read_pixels(run.first, run.tiles, (run.rect, run.tiling), 1, pixels)?;
        stats.batches += 1;
        Ok(())
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
            let faults = self.read_faults()?;
            let waiters = gpu.map_read(&self.batch.waiter_readback)?;
            let waited = submitted.elapsed();
            let when = (submitted, waited, None);
            if faults.header.count == 0 {
                // Nothing to load; this counts the blocks the dispatch found in lines.
                return self
                    .serve_faults(&faults, &waiters, 0, round, when, stats)
                    .map(drop);
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

    /// Records the `requesters` kernel (each listed block's least requester into the fault list,
    /// its `requested` word cleared), then copies the round's fault list, the lines' waiting rays
    /// and which lines the round used and which its rays still live keep into the readback
    /// buffers `serve_faults` reads.
    fn copy_faults(&self, enc: &mut wgpu::CommandEncoder) {
        let Some(dc) = &self.dc else {
            return;
        };
        let (bufs, b) = (&self.dc_bufs, &self.batch);
        let k = &self.kernels.requesters;
        k.dispatch(enc, &self.bound.requesters, Dispatch::Direct(1), None);
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
    fn read_faults(&self) -> Result<FaultList> {
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
    fn serve_faults(
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
        rec.fetched_bytes = (plan.loads.len() * bw * 4) as u64;
        rec.fetch_us = fetch * 1e6;
        rec.upload_us = upload * 1e6;
        stats.fetched_blocks += u64::from(rec.fetched_blocks);
        stats.fetched_bytes += rec.fetched_bytes;
        stats.fetch_seconds += fetch;
        stats.upload_seconds += upload;
        stats.fault_rounds += 1;
        dc.trace.rounds.push(rec);
        Ok(header.count - loaded)
    }
}

/// A batch's statistics into the frame's, once its last ray is done after `rounds` rounds.
fn add_batch_stats(stats: &mut FrameStats, s: &Stats, rounds: u32) {
    stats.steps += u64::from(s.steps);
    stats.tri_tests += u64::from(s.tri_tests);
    stats.lookups += u64::from(s.hits) + u64::from(s.misses);
    stats.hits += u64::from(s.hits);
    stats.misses += u64::from(s.misses);
    stats.node_visits += u64::from(s.node_visits);
    stats.block_entries += u64::from(s.block_entries);
    stats.tri_block_entries += u64::from(s.tri_block_entries);
    stats.lane_steps += u64::from(s.subgroup_steps) * u64::from(s.subgroup_size);
    stats.max_live_rounds = stats.max_live_rounds.max(rounds);
}

/// Whether the next batch may start: nothing is in flight; or every fault of the last round got
/// a line, or few did not (`few_left_waiting`), and the cache keeps the lines of the batches in
/// flight (`resuming`), so that they resume next round while the new batch's first faults are
/// served; or every batch in flight is down to its tail (`in_tail`) and, with a direct-mapped cache, the last round used at
/// most half of the lines (`used_lines`, `lines`: a new batch's blocks would evict, by their
/// place, those the tails wait for).
///
/// A cache that keeps the tails' lines (`lru`, `CachePolicy::mark_used`) needs no room: waiting
/// for it left a round of a few hundred rays after every batch (rm 3M at 1024x1024, rank 0 of 8,
/// nodes replicated, 1/8: 14.0 fault rounds a frame with the wait, 12.0 without). Starting where
/// the batches in flight resume lets a batch take about one round of its own where the image is
/// sparse (1/32, nodes replicated: 43.5 fault rounds a warm frame without, 38.3 with; docs/notes).
fn next_batch_may_start(
    busy: bool,
    in_tail: bool,
    resuming: bool,
    keeps_tails: bool,
    (used_lines, lines): (u32, u32),
) -> bool {
    !busy || resuming || (in_tail && (keeps_tails || used_lines * 2 <= lines))
}

/// Whether the `waiting` faults a round left without a line (of `lines`) let the next batch
/// start beside them (`next_batch_may_start`'s `resuming`): none may wait, or, when every node
/// block is resident, at most a `WAIT_SHARE`th of the lines. A ray then waits for triangle blocks
/// only, a round's leftovers are the last faults of batches that are mostly done, and waiting
/// for them alone took a round of a few dozen blocks several times a frame. With only the root
/// replicated the leftovers are node blocks on chains of faults, and a new batch's blocks evict
/// those the chains need next (docs/notes).
fn few_left_waiting(waiting: u32, lines: u32, nodes_resident: bool) -> bool {
    waiting == 0
        || (nodes_resident && u64::from(waiting) * u64::from(WAIT_SHARE) <= u64::from(lines))
}

/// `few_left_waiting`: with the nodes resident, up to half the lines' worth of faults may wait.
/// `rm` 3M at 1024x1024, rank 0 of 8, nodes replicated, 6-frame orbits, mean of frames 1-5:
/// at 1/32 32.2 fault rounds a frame with none waiting, 29.2 with a quarter, 27.8 with half
/// (blocks fetched +0.9% and +1.6%); at 1/8 11.4, 11.6 and 11.2.
const WAIT_SHARE: u32 = 2;

/// A round's fault list as read back: the blocks (at most the list's capacity) and each one's
/// requester (`requester_lane`).
struct FaultList {
    header: FaultHeader,
    blocks: Vec<u32>,
    requesters: Vec<u32>,
}

impl FaultList {
    /// Parses the fault buffer's bytes (`batch::fault_bytes(cap)`: the header, `cap` block words,
    /// then `cap` words of the blocks' least requesters as the `requesters` kernel copied them
    /// from `requested`: the complement of the requester, 1 for a kernel without rays).
    fn read(bytes: &[u8], cap: u32) -> FaultList {
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
    fn order_by(&mut self, keys: &[u64]) {
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
fn serve_order(age: u64, ray: u32) -> u64 {
    (age << 32) | u64::from(ray)
}

/// Bits of a fault's requester below the lane (`REQUESTER_LANE_SHIFT` in
/// shaders/shared/dc.wgsl).
const REQUESTER_LANE_SHIFT: u32 = 28;

/// The lane and ray slot of a fault's requester, as `requester` in shaders/shared/dc.wgsl packs
/// them; `None` for a fault no ray slot listed (the colour-by-data kernel's).
fn requester_lane(who: u32) -> Option<(usize, u32)> {
    let slot_mask = (1 << REQUESTER_LANE_SHIFT) - 1;
    (who != NONE).then_some(((who >> REQUESTER_LANE_SHIFT) as usize, who & slot_mask))
}

/// Whether a round left its `live` rays where they were: no ray took a step or ended (`moved`)
/// and none asked for a block (`listed`, the fault list's count, dropped faults included). Rays
/// that wait renew their requests every round, so the next round would be the same, and the
/// frame would never end: an internal error, reported rather than waited on.
fn stalled(live: u32, moved: bool, listed: u32) -> bool {
    live > 0 && !moved && listed == 0
}

fn stall_error(live: u32, round: u32) -> Error {
    Error::Gpu(format!(
        "trace round {round}: {live} rays still live, but none moved and none asked for a block \
         (an internal error: the frame could never end)"
    ))
}

/// The next batch starts when every batch in flight is down to this share of its rays (1/16):
/// the last rounds of a batch carry few rays, each climbing its own chain of absent blocks.
const TAIL_SHARE: u32 = 16;

/// A batch in one lane, or waiting for one (`Tracer::render_overlapped`).
struct LaneRun {
    /// Its rectangle, the order of the rectangle's tiles and its place in the open rectangles.
    rect: Rect,
    tiling: Tiling,
    slot: usize,
    /// Its first tile and tile count within the rectangle.
    first: u32,
    tiles: u32,
    /// The live list its next round reads.
    list: usize,
    /// The rays it started with (known after its first round) and those still live.
    started: Option<u32>,
    live: u32,
    rounds: u32,
    /// Its steps so far (`Stats::steps`), to tell a round that moved no ray (`stalled`).
    steps: u32,
    /// Tiles a batch of the rectangle takes where no fault density is known.
    per_batch: u32,
    /// The blocks its rays listed (each once), and per tile how many a ray of the tile listed
    /// first.
    seen: HashSet<u32>,
    tile_faults: Vec<u32>,
    /// Batches of the frame started before it.
    age: u64,
}

/// A rectangle with batches in flight or waiting: its pixels so far and the batches left.
struct OpenRect {
    pixels: Vec<Pixel>,
    batches: u32,
}

impl LaneRun {
    fn new(rect: Rect, tiling: Tiling, slot: usize, first: u32, tiles: u32) -> LaneRun {
        LaneRun {
            rect,
            tiling,
            slot,
            first,
            tiles,
            list: 0,
            started: None,
            live: 0,
            rounds: 0,
            steps: 0,
            per_batch: tiles,
            seen: HashSet::new(),
            tile_faults: Vec::new(),
            age: 0,
        }
    }

    /// Counts a fault on `block` to the batch's tile `tile`, unless the batch listed the block
    /// before (a block that got no line is listed again next round).
    fn note_fault(&mut self, block: u32, tile: u32) {
        if tile < self.tiles && self.seen.insert(block) {
            self.tile_faults.resize(self.tiles as usize, 0);
            self.tile_faults[tile as usize] += 1;
        }
    }

    /// Whether the batch is down to its last rays.
    fn in_tail(&self) -> bool {
        self.started
            .is_some_and(|s| u64::from(self.live) * u64::from(TAIL_SHARE) <= u64::from(s))
    }
}

/// How many times the cache's lines a batch is sized to fault on (`Tracer::batch_tiles`), with
/// `spares` spare lanes. A batch lists most of its blocks in its first round and then holds its
/// lane for several rounds while its last rays climb chains of blocks.
/// - With few lanes, tails fill them and a batch can start only every second round or so, so
///   batches are larger than the cache (lines are reused as their rays finish).
/// - With `MANY_SPARES` or more, a batch can start every round, and one whose first round fits
///   the lines beside the rounds of those before it gets all its blocks at once.
///
/// rm 3M at 1024x1024, rank 0 of 8, 8-frame orbits, mean fault rounds of frames 2-7, two runs
/// each (docs/notes): at 1/32 with 6 spares, 1.2 took 35.3-35.7 and 0.85 33.5-33.8 with
/// the nodes replicated; at 1/8 with 2 spares, 1.2 took 11.2-11.3 and 0.85 12.3-12.5.
fn fill_share(spares: usize) -> f64 {
    if spares >= MANY_SPARES { 0.85 } else { 1.2 }
}

/// Spare lanes from which a batch is sized to start every round (`fill_share`).
const MANY_SPARES: usize = 4;

/// Where a rectangle's blocks are dense: per 8x8 tile (by position, whatever the batch order),
/// how many of the blocks its batch faulted on in the last frame had a ray of the tile as least
/// requester.
pub(super) struct FaultDensity {
    rect: Rect,
    tiles_x: u32,
    per_tile: Vec<f64>,
}

impl FaultDensity {
    fn new(rect: Rect, tiling: Tiling) -> FaultDensity {
        FaultDensity {
            rect,
            tiles_x: tiling.tiles_x,
            per_tile: vec![0.0; tiling.tiles() as usize],
        }
    }

    /// The slot of batch tile `t` of `tiling`.
    fn slot(&self, tiling: Tiling, t: u32) -> usize {
        let (x, y) = tile_pixel(t, tiling, 0);
        ((y / TILE) * self.tiles_x + x / TILE) as usize
    }

    /// The faults of a batch's `tiles` of `tiling`, the first tile's at `faults[0]` (tiles past
    /// the end of `faults` had none).
    fn note(&mut self, tiling: Tiling, tiles: Range<u32>, faults: &[u32]) {
        for (i, t) in tiles.enumerate() {
            let slot = self.slot(tiling, t);
            if let Some(p) = self.per_tile.get_mut(slot) {
                *p = f64::from(faults.get(i).copied().unwrap_or(0));
            }
        }
    }

    /// The tiles a batch starting at tile `first` of `tiling` takes: until their faults reach
    /// `target`, within `size` (its end also where the rectangle's tiles end).
    fn batch(&self, tiling: Tiling, first: u32, size: RangeInclusive<u32>, target: f64) -> u32 {
        let (least, most) = (*size.start(), *size.end());
        let (mut n, mut expected) = (0, 0.0);
        while n < most && (n < least || expected < target) {
            expected += self
                .per_tile
                .get(self.slot(tiling, first + n))
                .copied()
                .unwrap_or(0.0);
            n += 1;
        }
        n
    }
}

#[cfg(test)]
mod tests;
