//! The batch scheduler (docs/ARCHITECTURE.md, Overlapping batches): with a distributed cache,
//! the next batch starts in a spare lane while the last rays of those in flight still wait for
//! blocks, every round dispatches `traverse` in each lane with a batch, and their faults are served
//! together; a batch whose rays are done is shaded and read back in its lane.

use super::batch::TILE_RAYS;
use super::faults::{FaultList, requester_lane, serve_order};
use super::frame::{FrameStats, Rect};
use super::layout::{Pixel, RoundReadback};
use super::rounds::{Gen, add_batch_stats, stall_error, stalled};
use super::tracer::{MIN_FIT_PIXELS, Tracer};
use crate::dc::CacheMap;
use crate::error::{Error, Result};
use crate::mirror::tiles::Tiling;
use crate::scene::CameraBasis;
use std::collections::{HashSet, VecDeque};
use std::time::Instant;

/// Where `Tracer::render_rects` takes rectangles from and gives their pixels to.
pub trait RectSource {
    /// The next rectangle to trace. `busy`: rectangles are in flight, so answer `Next::Later`
    /// rather than wait when none is at hand; when not busy, wait for one.
    fn next(&mut self, busy: bool) -> Result<Next>;
    /// A rectangle's pixels, row-major within it, once all its rays are done.
    fn done(&mut self, rect: Rect, pixels: Vec<Pixel>) -> Result<()>;
}

/// What a `RectSource` has next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Next {
    Rect(Rect),
    /// None at hand yet.
    Later,
    /// None left this frame.
    End,
}

/// `render_rect`'s one rectangle as a source.
pub(super) struct OneRect {
    pub rect: Option<Rect>,
    pub pixels: Option<Vec<Pixel>>,
}

impl RectSource for OneRect {
    fn next(&mut self, _busy: bool) -> Result<Next> {
        Ok(self.rect.take().map_or(Next::End, Next::Rect))
    }

    fn done(&mut self, _rect: Rect, pixels: Vec<Pixel>) -> Result<()> {
        self.pixels = Some(pixels);
        Ok(())
    }
}

/// How `begin_rect` cuts a rectangle: its 8x8 tiles, tiles a row, tiles a batch.
#[derive(Clone, Copy, Debug)]
pub(super) struct RectPlan {
    pub tiles: u32,
    pub tiling: Tiling,
    pub per_batch: u32,
}

/// The state of one `render_overlapped` call: the batches in the lanes and those waiting, the
/// rectangles with batches left, and what the last round said about the cache.
struct Scheduler {
    /// Per lane, the batch it holds.
    runs: Vec<Option<LaneRun>>,
    /// Batches not started yet (the rest of a rectangle's tiles first).
    pending: VecDeque<LaneRun>,
    /// The pixels of rectangles with batches left, by `LaneRun::slot`.
    open: Vec<Option<OpenRect>>,
    /// The source has no rectangle left this frame.
    ended: bool,
    /// Rounds so far.
    round: u32,
    /// Tiles handed out and done, for the progress callback (in `passes`).
    total_tiles: u64,
    done_tiles: u64,
    passes: Option<u64>,
    /// Lines the last round used, and whether its faults that got no line are few enough for a
    /// new batch to start beside them (`next_batch_may_start`, `few_left_waiting`).
    used_lines: u32,
    all_served: bool,
    /// Batches started this frame: a batch's age.
    started_batches: u64,
    /// The cache's lines, whether it keeps the tails' lines (`lru`), whether every node block is
    /// resident.
    lines: u32,
    keeps_tails: bool,
    nodes_resident: bool,
}

/// What one round's read-backs said of the lanes it traced.
struct RoundOutcome {
    /// Rays still live in every lane.
    live: u32,
    /// Whether any ray took a step or ended (`stalled`).
    moved: bool,
    /// Lanes whose batch has no live ray left.
    done: Vec<usize>,
    /// The round's GPU time, when the adapter has timestamps.
    gpu_ms: Option<f64>,
}

impl Scheduler {
    fn new(tracer: &Tracer<'_>, passes: Option<u64>) -> Scheduler {
        let dc = tracer.dc.as_ref();
        Scheduler {
            runs: (0..=tracer.spares.len()).map(|_| None).collect(),
            pending: VecDeque::new(),
            open: Vec::new(),
            ended: false,
            round: 0,
            total_tiles: 0,
            done_tiles: 0,
            passes,
            used_lines: 0,
            all_served: false,
            started_batches: 0,
            lines: dc.map_or(0, |dc| dc.policy.lines()),
            keeps_tails: dc.is_some_and(|dc| dc.policy.map() == CacheMap::Lru),
            nodes_resident: dc.is_some_and(|dc| dc.policy.nodes_resident()),
        }
    }

    /// Whether a batch may start now (`next_batch_may_start`).
    fn may_start(&self) -> bool {
        let busy = self.busy();
        let in_tail = self.runs.iter().flatten().all(LaneRun::in_tail);
        let resuming = self.keeps_tails && self.all_served;
        let lines = (self.used_lines, self.lines);
        next_batch_may_start(busy, in_tail, resuming, self.keeps_tails, lines)
    }

    fn busy(&self) -> bool {
        self.runs.iter().any(Option::is_some)
    }

    fn free_lane(&self) -> Option<usize> {
        self.runs.iter().position(Option::is_none)
    }

    /// The lanes with a batch, in order.
    fn active(&self) -> Vec<usize> {
        (0..self.runs.len())
            .filter(|&l| self.runs[l].is_some())
            .collect()
    }

    fn run(&mut self, l: usize) -> &mut LaneRun {
        self.runs[l].as_mut().expect("an active lane has a batch")
    }

    /// Orders a round's faults for service: each listed block counts to the tile of its least
    /// requester, and the oldest batch's blocks get lines first (`serve_order`): its rays hold a
    /// lane, and its faults would otherwise wait behind those of every newer batch.
    fn order_faults(&mut self, faults: &mut FaultList) {
        let mut ages = Vec::with_capacity(faults.blocks.len());
        for (&block, &who) in faults.blocks.iter().zip(&faults.requesters) {
            let run = requester_lane(who)
                .and_then(|(l, ray)| Some((self.runs.get_mut(l)?.as_mut()?, ray)));
            ages.push(run.map_or(u64::MAX, |(run, ray)| {
                run.note_fault(block, ray / TILE_RAYS);
                serve_order(run.age, ray)
            }));
        }
        faults.order_by(&ages);
    }
}

impl Tracer<'_> {
    /// Traces and shades the rectangles `source` hands out, batches of them overlapping
    /// (docs/ARCHITECTURE.md, Overlapping batches): when the live rays of every batch in flight
    /// are down to a `TAIL_SHARE`th of those it started with (and, unless the cache is `lru`,
    /// the last round used at most half the cache's lines), the next batch (of this rectangle,
    /// or of the next one the source has) starts in a free lane, and each round dispatches
    /// `traverse` in every lane with a batch and serves their faults together. A batch whose rays
    /// are all done is resolved, shaded and read back in its lane; a rectangle whose batches
    /// are all done goes to `source.done`. With `passes`, each finished batch is reported to the
    /// progress callback.
    pub(super) fn render_overlapped(
        &mut self,
        basis: &CameraBasis,
        background: [f32; 3],
        source: &mut dyn RectSource,
        passes: Option<u64>,
        stats: &mut FrameStats,
    ) -> Result<()> {
        let gpu = self.gpu;
        let mut s = Scheduler::new(self, passes);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.clear_faults(&mut enc);
        loop {
            let t = Instant::now();
            let may_start = s.may_start();
            let free = s.free_lane();
            if may_start && free.is_some() && s.pending.is_empty() && !s.ended {
                self.take_rect(&mut s, basis, background, source, stats)?;
            }
            if let Some(l) = free.filter(|_| may_start) {
                self.start_batch(&mut s, l, &mut enc)?;
            }
            let active = s.active();
            if active.is_empty() {
                if s.ended && s.pending.is_empty() {
                    return Ok(());
                }
                // The source had nothing at hand while nothing was in flight: ask again.
                continue;
            }
            self.record_lanes(&mut s, &active, &mut enc);
            self.copy_faults(&mut enc);
            let submitted = Instant::now();
            gpu.queue.submit([enc.finish()]);
            s.round += 1;
            stats.rounds += active.len() as u32;
            stats.shared_rounds += u32::from(active.len() > 1);
            let out = self.read_lanes(&mut s, &active, stats)?;
            let waited = submitted.elapsed();
            let mut faults = self.read_faults()?;
            if stalled(out.live, out.moved, faults.header.count) {
                return Err(stall_error(out.live, s.round));
            }
            let waiters = gpu.map_read(&self.batch.waiter_readback)?;
            let used: &[u8] = &waiters[4 * s.lines as usize..8 * s.lines as usize];
            s.used_lines = used.chunks(4).filter(|u| u != &[0; 4]).count() as u32;
            s.order_faults(&mut faults);
            for &l in &out.done {
                let run = s.run(l);
                let (rect, tiling, tiles) =
                    (run.rect, run.tiling, run.first..run.first + run.tiles);
                let faults = std::mem::take(&mut run.tile_faults);
                self.note_batch_faults(rect, tiling, tiles, &faults);
            }
            let when = (submitted, waited, out.gpu_ms);
            let waiting = self.serve_faults(&faults, &waiters, out.live, s.round, when, stats)?;
            s.all_served = few_left_waiting(waiting, s.lines, s.nodes_resident);
            stats.trace_seconds += t.elapsed().as_secs_f64();
            for l in out.done {
                self.finish_batch(&mut s, l, source, stats)?;
            }
            enc = gpu.device.create_command_encoder(&Default::default());
            self.clear_faults(&mut enc);
        }
    }

    /// Asks the source for its next rectangle; a rectangle it has is planned and waits whole as
    /// one pending batch, which takes its share of the tiles when it starts.
    fn take_rect(
        &mut self,
        s: &mut Scheduler,
        basis: &CameraBasis,
        background: [f32; 3],
        source: &mut dyn RectSource,
        stats: &mut FrameStats,
    ) -> Result<()> {
        match source.next(s.busy())? {
            Next::Rect(rect) => {
                let plan = self.begin_rect(basis, background, rect)?;
                let slot = s.open.len();
                let mut all = LaneRun::new(rect, plan.tiling, slot, 0, plan.tiles);
                all.per_batch = plan.per_batch;
                s.pending.push_back(all);
                s.total_tiles += u64::from(plan.tiles);
                let pixels = self.take_pixels(rect.pixels());
                s.open.push(Some(OpenRect { pixels, batches: 1 }));
                stats.rays += rect.pixels() as u64;
                stats.samples = self.params.spp;
                self.several_batches |= s.open.len() > 1;
            }
            Next::Later => {}
            Next::End => s.ended = true,
        }
        Ok(())
    }

    /// Starts the next pending batch, if any, in free lane `l`: its tiles (`batch_tiles`; the
    /// rest of its rectangle's go back to the front of the queue) and its buffers; its first
    /// round makes its rays.
    fn start_batch(
        &mut self,
        s: &mut Scheduler,
        l: usize,
        enc: &mut wgpu::CommandEncoder,
    ) -> Result<()> {
        let Some(mut run) = s.pending.pop_front() else {
            return Ok(());
        };
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
            s.pending.push_front(rest);
            run.tiles = n;
            if let Some(r) = s.open[run.slot].as_mut() {
                r.batches += 1;
            }
        }
        self.set_rect(run.rect, run.tiling);
        self.params.first_tile = run.first;
        self.params.batch_rays = run.tiles * TILE_RAYS;
        run.list = self.record_start(enc, l, Gen::Primary);
        run.age = s.started_batches;
        s.started_batches += 1;
        s.runs[l] = Some(run);
        Ok(())
    }

    /// Records one round in every `active` lane; the timestamps (lane 0's queries) go into the
    /// first active lane's read-back.
    fn record_lanes(&self, s: &mut Scheduler, active: &[usize], enc: &mut wgpu::CommandEncoder) {
        for (i, &l) in active.iter().enumerate() {
            let run = s.run(l);
            let ends = (i == 0, i + 1 == active.len());
            let makes = (run.rounds == 0).then_some(Gen::Primary);
            run.list = self.record_round(enc, l, (run.list, makes), ends);
            run.rounds += 1;
        }
        if let (Some((q, resolve)), Some(&l)) = (&self.batch.timestamps, active.first()) {
            let (at, size) = member!(timestamps, [u64; 2]);
            enc.resolve_query_set(q, 0..2, resolve, 0);
            enc.copy_buffer_to_buffer(resolve, 0, &self.lane(l).0.readback, at, size);
        }
    }

    /// Reads back the round of every `active` lane: its live rays, whether they moved, the
    /// lanes whose batch is done (their statistics added to the frame's).
    fn read_lanes(
        &self,
        s: &mut Scheduler,
        active: &[usize],
        stats: &mut FrameStats,
    ) -> Result<RoundOutcome> {
        let mut out = RoundOutcome {
            live: 0,
            moved: false,
            done: Vec::new(),
            gpu_ms: None,
        };
        for &l in active {
            let data = self.gpu.map_read(&self.lane(l).0.readback)?;
            let r: RoundReadback = bytemuck::pod_read_unaligned(&data);
            self.check_overflows(&r.stats)?;
            if Some(&l) == active.first() {
                out.gpu_ms = self.round_gpu_ms(&r, stats);
            }
            let run = s.run(l);
            run.started.get_or_insert(r.stats.started);
            run.opened.get_or_insert(r.opened);
            out.moved |= (r.stats.steps, r.counter.count) != (run.steps, run.live);
            run.steps = r.stats.steps;
            run.live = r.counter.count;
            out.live += run.live;
            if run.live == 0 {
                add_batch_stats(stats, &r.stats, run.rounds);
                stats.traced_rays += u64::from(run.started.unwrap_or(0));
                out.done.push(l);
            }
        }
        Ok(out)
    }

    /// Shades and reads back the finished batch of lane `l` in its lane; gives its rectangle to
    /// the source when it was the rectangle's last batch, and reports progress.
    fn finish_batch(
        &mut self,
        s: &mut Scheduler,
        l: usize,
        source: &mut dyn RectSource,
        stats: &mut FrameStats,
    ) -> Result<()> {
        let t = Instant::now();
        let run = s.runs[l].take().expect("a finished lane had a batch");
        let rect = s.open[run.slot]
            .as_mut()
            .expect("a batch's rectangle is open");
        self.set_rect(run.rect, run.tiling);
        self.params.first_tile = run.first;
        self.params.batch_rays = run.tiles * TILE_RAYS;
        self.swap_lanes(l);
        let place = (run.rect, run.tiling);
        let (span, opened) = ((run.first, run.tiles), run.opened);
        let shaded = self.shade_batch(span, place, opened, &mut rect.pixels, stats);
        self.swap_lanes(l);
        shaded?;
        rect.batches -= 1;
        if rect.batches == 0 {
            let pixels = std::mem::take(&mut rect.pixels);
            s.open[run.slot] = None;
            source.done(run.rect, pixels)?;
        }
        stats.shade_seconds += t.elapsed().as_secs_f64();
        s.done_tiles += u64::from(run.tiles);
        if let (Some(p), Some(n)) = (self.progress.as_mut(), s.passes) {
            // Batches vary in size: the share of tiles done, in passes.
            p((s.done_tiles * n).div_ceil(s.total_tiles.max(1)), n);
        }
        Ok(())
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
    /// The rays it started with and those its first round left live (known after that round),
    /// and those still live.
    started: Option<u32>,
    opened: Option<u32>,
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
            opened: None,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::density::FaultDensity;

    #[test]
    fn only_a_direct_mapped_cache_waits_for_room() {
        // Nothing in flight: start. Batches in flight not yet down to their tails: wait.
        assert!(next_batch_may_start(false, false, false, false, (100, 100)));
        assert!(!next_batch_may_start(true, false, false, true, (0, 100)));
        // Tails whose last round used most of the lines: lru starts the next batch, a
        // direct-mapped cache waits until at most half the lines were used.
        assert!(next_batch_may_start(true, true, false, true, (90, 100)));
        assert!(!next_batch_may_start(true, true, false, false, (90, 100)));
        assert!(next_batch_may_start(true, true, false, false, (50, 100)));
    }

    #[test]
    fn a_batch_starts_beside_a_few_waiting_faults_only_when_the_nodes_are_resident() {
        // None waiting: always. Half the lines' worth: with the nodes resident only.
        assert!(few_left_waiting(0, 100, false));
        assert!(few_left_waiting(0, 100, true));
        assert!(few_left_waiting(50, 100, true));
        assert!(!few_left_waiting(50, 100, false));
        assert!(!few_left_waiting(51, 100, true));
        assert!(!few_left_waiting(1, 100, false));
    }

    #[test]
    fn a_batch_starts_where_those_in_flight_resume_in_full() {
        // Not down to their tails, but every fault of the last round got a line.
        assert!(next_batch_may_start(true, false, true, true, (100, 100)));
        assert!(!next_batch_may_start(true, false, false, true, (100, 100)));
    }

    #[test]
    fn a_batch_counts_each_block_once_to_the_tile_that_listed_it_first() {
        let rows = Tiling::new(64, 32, 32);
        let mut run = LaneRun::new(Rect::whole(64, 32), rows, 0, 4, 3);
        run.note_fault(9, 1);
        run.note_fault(9, 2);
        run.note_fault(8, 2);
        // A block listed again (it got no line) and a slot past the batch's tiles count nothing.
        run.note_fault(8, 0);
        run.note_fault(7, 3);
        assert_eq!(run.tile_faults, [0, 1, 1]);
        // Into the density at the batch's tiles (4..7); the others keep what they had.
        let mut d = FaultDensity::new(Rect::whole(64, 32), rows);
        d.note(rows, 0..8, &[5; 8]);
        d.note(rows, 4..7, &run.tile_faults);
        let got: Vec<f64> = (0..8).map(|t| d.per_tile[d.slot(rows, t)]).collect();
        assert_eq!(got, [5.0, 5.0, 5.0, 5.0, 0.0, 1.0, 1.0, 5.0]);
    }
}
