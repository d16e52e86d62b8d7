//! The round loop (docs/ARCHITECTURE.md, The round loop): a batch's rays are traced in rounds of
//! `traverse` (each live ray runs at most `step_budget` loop iterations, then saves its state) and
//! `args` (the count of rays still live becomes the next round's indirect dispatch). A batch of
//! primary rays starts with `traverse_first`, which makes the camera rays itself, and a wave of
//! secondary rays with `traverse_spawn`, which makes them from the paths (or, for a wave whose
//! live rays `spawn` listed, `traverse_listed`, which makes those). With a
//! distributed cache, every round's faults are read back and served (`dc::policy` decides,
//! the block source fetches, the store and the row table are updated) before the next round;
//! without one, several rounds go in one submission.

use super::faults::{requester_lane, serve_order};
use super::frame::FrameStats;
use super::kernels::Dispatch;
use super::layout::{Params, RoundReadback, Stats};
use super::tracer::{MAX_STACK, Tracer};
use crate::error::{Error, Result};
use std::time::Instant;

/// What a batch's traversal rounds report once no ray is live.
#[derive(Clone, Copy, Debug)]
pub(super) struct Traced {
    /// Rays that entered traversal (`Stats::started`).
    pub started: u32,
    /// Of primary rays, those the first round left live (`RoundReadback::opened`).
    pub opened: Option<u32>,
    /// Rays that do not stop at any hit and found one (`Stats::closest_hits`), counted in modes
    /// with secondary rays (0 in `cast`): without any, no path goes on past these rays.
    pub closest_hits: u32,
}

/// What starts a batch's traversal rounds.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum Gen {
    /// Camera rays, made by the first round.
    Primary,
    /// A wave of `fan` secondary rays a pixel slot, made by the first round: a wave in which
    /// nearly every path is alive (ambient occlusion, shadows, a path's first bounce).
    Secondary { fan: u32 },
    /// A wave whose live rays the `spawn` kernel lists, compacted, and its first round makes: a
    /// path's later waves, whose dead paths are scattered through the slots
    /// (docs/ARCHITECTURE.md, The round loop).
    Spawned { fan: u32 },
}

impl Tracer<'_> {
    /// Runs traversal rounds over the batch's rays (primary, or a wave of secondary rays, made by
    /// the first round) until none is live: secondary rays fault, suspend and resume exactly as
    /// primary rays do.
    pub(super) fn traverse_batch(&mut self, stats: &mut FrameStats, gen_: Gen) -> Result<Traced> {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        self.clear_faults(&mut enc);
        let cur = self.record_start(&mut enc, 0, gen_);
        self.run_rounds(enc, cur, Some(gen_), stats)
    }

    /// Starts a batch in lane `l`: writes `Params` into its buffer and clears its counters and
    /// stats; for a spawned wave, records `spawn` into list 0, `args` on counter 0 and the copy
    /// of the listed count into `Stats::started`. Returns the list the first round reads (a
    /// round that makes its rays in every slot reads none, and leaves its live rays in list 0,
    /// the list after 1).
    pub(super) fn record_start(
        &self,
        enc: &mut wgpu::CommandEncoder,
        l: usize,
        gen_: Gen,
    ) -> usize {
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
        let (Gen::Spawned { fan }, Some(spawn), Some(sb)) = (gen_, &k.spawn, &bound.spawn) else {
            return 1;
        };
        spawn.dispatch(enc, sb, Dispatch::Over(self.params.batch_rays * fan), None);
        k.args
            .dispatch(enc, &bound.args[0], Dispatch::Over(1), None);
        let at = std::mem::offset_of!(Stats, started) as u64;
        enc.copy_buffer_to_buffer(&b.counters[0], 0, &b.stats, at, 4);
        0
    }

    /// Records one round of lane `l` (its rays in list `cur`; with `opening`, a first round,
    /// which makes them, in every slot or, for a spawned wave, those `cur` lists) and the copies of the new live count and the stats into the lane's
    /// read-back; timestamps as `stamps` says. Returns the list the next round reads.
    pub(super) fn record_round(
        &self,
        enc: &mut wgpu::CommandEncoder,
        l: usize,
        (cur, opening): (usize, Option<Gen>),
        (first, last): (bool, bool),
    ) -> usize {
        let (b, _, bound) = self.lane(l);
        let k = &self.kernels;
        let o = 1 - cur;
        let stamps = self.stamps(first, false);
        let rays = self.params.batch_rays;
        let spawn = (&k.traverse_spawn, &bound.traverse_spawn);
        let listed = (&k.traverse_listed, &bound.traverse_listed);
        if let Some(Gen::Primary) = opening {
            let slots = Dispatch::Over(rays);
            k.traverse_first
                .dispatch(enc, &bound.traverse_first, slots, stamps);
            let (at, _) = member!(opened, u32);
            enc.copy_buffer_to_buffer(&b.counters[o], 0, &b.readback, at, 4);
        } else if let (Some(Gen::Secondary { fan }), (Some(t), Some(tb))) = (opening, spawn) {
            t.dispatch(enc, tb, Dispatch::Over(rays * fan), stamps);
        } else if let (Some(Gen::Spawned { .. }), (Some(t), Some(tb))) = (opening, listed) {
            // Bound to read list 0, where `spawn` lists the wave (`record_start`).
            debug_assert_eq!(cur, 0, "a spawned wave's first round reads list 0");
            t.dispatch(enc, tb, Dispatch::Indirect(&b.counters[cur]), stamps);
        } else {
            let ind = Dispatch::Indirect(&b.counters[cur]);
            // A frame that sets nothing aside runs the kernel without the set-aside code.
            let (trace, trace_bound) = match (&k.traverse_suspending, &bound.traverse_suspending) {
                (Some(t), Some(b)) if self.params.dc_defer == 0 => (t, &b[cur]),
                _ => (&k.traverse, &bound.traverse[cur]),
            };
            trace.dispatch(enc, trace_bound, ind, stamps);
        }
        let groups = Dispatch::Over(1);
        k.args
            .dispatch(enc, &bound.args[o], groups, self.stamps(false, last));
        let (at, size) = member!(counter, super::layout::Counter);
        enc.copy_buffer_to_buffer(&b.counters[o], 0, &b.readback, at, size);
        let (at, size) = member!(stats, super::layout::Stats);
        enc.copy_buffer_to_buffer(&b.stats, 0, &b.readback, at, size);
        o
    }

    /// Trace rounds until no ray is live, starting from what `enc` has prepared (`cur`, the list
    /// the first round reads; `opening`: the rays the first round makes, if it makes them).
    pub(super) fn run_rounds(
        &mut self,
        mut enc: wgpu::CommandEncoder,
        mut cur: usize,
        opening: Option<Gen>,
        stats: &mut FrameStats,
    ) -> Result<Traced> {
        let gpu = self.gpu;
        let mut traced = None;
        // `cur` is the counter holding the live rays of the next round. With a cache, faults are
        // served after every round; without, several rounds go in one submission.
        let mut per_check = if self.dc.is_some() { 1 } else { 2u32 };
        let mut live_rounds = 0u32;
        // The batch's steps and live rays after the last round: `stalled`.
        let mut last = (0u32, u32::MAX);
        loop {
            for i in 0..per_check {
                let makes = opening.filter(|_| live_rounds + i == 0);
                let ends = (i == 0, i + 1 == per_check);
                cur = self.record_round(&mut enc, 0, (cur, makes), ends);
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
            let traced = *traced.get_or_insert(Traced {
                started: s.started,
                opened: (opening == Some(Gen::Primary)).then_some(r.opened),
                closest_hits: 0,
            });
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
                // The batch's stats count from its start: the last read-back has them all.
                let closest_hits = s.closest_hits;
                return Ok(Traced {
                    closest_hits,
                    ..traced
                });
            }
            if self.dc.is_none() {
                per_check = (per_check * 2).min(16);
            }
        }
    }

    /// A round's GPU time from its read-back timestamps, added to the frame's; `None` when the
    /// adapter has no timestamps.
    pub(super) fn round_gpu_ms(&self, r: &RoundReadback, stats: &mut FrameStats) -> Option<f64> {
        self.batch.timestamps.as_ref()?;
        let period = f64::from(self.gpu.queue.get_timestamp_period());
        let t = r.timestamps;
        let secs = t[1].saturating_sub(t[0]) as f64 * period * 1e-9;
        stats.gpu_seconds += secs;
        Some(secs * 1e3)
    }

    /// A stack overflow in any ray of a round is an error naming the BVH depth.
    pub(super) fn check_overflows(&self, s: &Stats) -> Result<()> {
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
}

/// A batch's statistics into the frame's, once its last ray is done after `rounds` rounds.
pub(super) fn add_batch_stats(stats: &mut FrameStats, s: &Stats, rounds: u32) {
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

/// Whether a round left its `live` rays where they were: no ray took a step or ended (`moved`)
/// and none asked for a block (`listed`, the fault list's count, dropped faults included). Rays
/// that wait renew their requests every round, so the next round would be the same, and the
/// frame would never end: an internal error, reported rather than waited on.
pub(super) fn stalled(live: u32, moved: bool, listed: u32) -> bool {
    live > 0 && !moved && listed == 0
}

pub(super) fn stall_error(live: u32, round: u32) -> Error {
    Error::Gpu(format!(
        "traversal round {round}: {live} rays still live, but none moved and none asked for a block \
         (an internal error: the frame could never end)"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_round_that_moved_no_ray_and_listed_no_block_is_a_stall() {
        assert!(stalled(5, false, 0));
        // Rays moved, or asked for blocks (served next round), or none is left.
        assert!(!stalled(5, true, 0));
        assert!(!stalled(5, false, 1));
        assert!(!stalled(0, false, 0));
    }
}
