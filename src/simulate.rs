//! Replays a cluster run's traces at another number of ranks (docs/ARCHITECTURE.md, Traces).
//!
//! The model: a frame's cost is spread over the image as the run measured it, each recorded
//! tile's time (GPU traversal rounds and shading, its fetches, sending its pixels) over its pixels.
//! The fetch part is the tile's share (by GPU time) of its rank's `fetch_ms`; with `bandwidth`
//! or `latency` given it becomes `latency x rounds + bytes / bandwidth` for the tile's share of
//! the rank's fault rounds and bytes. K ranks have the render ranks `cluster::Roles` gives
//! them, and the balancer's own `Schedule` hands out the tiles: each rank takes its static
//! tiles, then the next tile whenever it is free, and goes on to the next frame as soon as the
//! current one has none left for it (frames overlap as on the cluster). A frame is complete
//! when its last tile is sent, plus the display's measured wait for its copies. A render rank's
//! first tile also pays a one-time GPU set-up (pipelines, first dispatches): the excess of the
//! first tiles over the frame's median cost per pixel, which every simulated rank pays at its
//! start instead.
//!
//! Tiles cost a fixed part plus a part per pixel: at more ranks the balancer cuts the image into
//! more, smaller tiles, and each costs its GPU rounds' dispatch and readback whatever its area
//! (on lavapipe about 1 ms of a 1024-pixel tile's 10 ms at 4 ranks here). A least-squares line through
//! the run's tiles (cost against pixels, frame 0 left out for its set-up) gives the fixed part;
//! a recorded tile's cost above it is spread over its pixels as before.
//!
//! Core sharing: on lavapipe a GPU round is a submission, the kernels on the CPU's cores and a
//! readback, and with more ranks than cores each round waits longer for a core. The traces'
//! rounds carry their submission and wait, so the run tells how a round's wait grows with the
//! render ranks tracing at the same moment: a least-squares line `a + b x c` through every
//! round's wait against `c` (itself and the other ranks whose tiles span its middle: a rank
//! tracing a tile wants a core for its rounds, and for its fetches, which poll MPI). The
//! traced run's mean `c` gives the share of its time a rank spends tracing, `f = (c - 1) /
//! (R - 1)`; at R' render ranks sharing one machine a round sees `1 + (R' - 1) f` and waits
//! `(a + b c') / (a + b c)` times as long. Every shared cost (GPU rounds, sending, measured
//! fetches) stretches by that; re-priced fetches are a network's and do not.
//!
//! The distributed cache: at more render ranks each owns a smaller share of the model and sees
//! fewer, smaller tiles, so a pixel takes more fault rounds (rounds a frame at R = 2, 3, 4
//! render ranks: 90, 157, 260 here, R^1.5 to within 5%, each holding fewer rays). The traces of
//! one run cannot tell this; with a cache, shared costs per pixel grow as `(R' / R)^w`, `w` the
//! model's `work_exponent`. `dcrt simulate` takes 0.5: fitted on this project's 2-core machine
//! to runs at 4 ranks predicting 5 and 6 (shared memory and TCP; docs/benchmarks.md has the table
//! and how it was fitted); 0 keeps the work per pixel as traced. Replicated runs (no cache
//! lookups) do not fault and keep it.
//!
//! What it assumes, and where it breaks: the growth of work per pixel with the render ranks is
//! one power law, measured on one model, image and cache (1/8); it cannot hold far beyond the
//! ranks it was measured at (fault rounds per pixel are bounded by the misses), so extrapolating
//! a cached run to many nodes should use `w = 0`; the fixed part of a tile is the same for every
//! tile; a round's wait is linear in the ranks tracing at once, measured over the counts the
//! traced run had (a run of 2 render ranks sees 1 and 2; more is extrapolation); rounds are
//! where ranks compete, shading and host work between rounds stretch as rounds do; requests and
//! grants cost nothing; the display is never the bottleneck beyond its measured copy wait; the
//! machine has no other load than the run (here it had: single runs of one configuration varied
//! by 2x, and a prediction from one 4-rank run missed the 6-rank run next to it by up to 60%;
//! the medians of 5 runs came within 25%).

use crate::cluster::Roles;
use crate::cluster::schedule::Schedule;
use crate::error::{Error, Result};
use crate::gpu::frame::Rect;
use crate::traces::read::{RankFrame, Traces};
use crate::traces::record::Tile;
use serde::Serialize;

#[derive(Clone, Debug)]
pub struct ClusterModel {
    /// Total MPI ranks, as `mpirun -n K`.
    pub ranks: u32,
    /// Bytes per second of block fetches; `None` keeps the measured fetch times.
    pub bandwidth: Option<f64>,
    /// Seconds per fault round's fetch; `None` keeps the measured fetch times.
    pub latency: Option<f64>,
    /// The balancer's `--tile` and `--min-tile` of the run.
    pub tile: u32,
    pub min_tile: u32,
    /// Render ranks of the predicted run that share one machine's cores; `None`: all of them,
    /// as on the traced machine (1: a rank per node).
    pub ranks_per_node: Option<u32>,
    /// How shared costs per pixel grow with the render ranks in a cached run (module docs).
    pub work_exponent: f64,
    /// The sharing fit for traces without round times to fit (a replicated run never faults,
    /// so it records no rounds): e.g. a cached run's of the same model and ranks.
    pub sharing: Option<Sharing>,
}

/// How a round's wait grows with the ranks tracing at once, fitted from a run's rounds and
/// tiles (module docs).
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Sharing {
    /// ms of a round's wait: `alone_ms + per_rank_ms x c` at `c` ranks tracing (itself included).
    pub alone_ms: f64,
    pub per_rank_ms: f64,
    /// The mean number of ranks tracing during a round of the traced run.
    pub concurrency: f64,
    /// The share of a render rank's time spent tracing, `(concurrency - 1) / (R - 1)`.
    pub busy: f64,
    /// Rounds the fit used.
    pub rounds: usize,
}

impl Sharing {
    /// The fit of `t`'s rounds that carry their times; `None` when none do (older traces).
    pub fn fit(t: &Traces, render_ranks: u32) -> Option<Sharing> {
        let mut by_rank: Vec<(u32, f64, f64)> = Vec::new();
        for f in &t.files {
            for r in &f.rounds {
                if let (Some(s), Some(w)) = (r.start_ms, r.wait_ms) {
                    by_rank.push((f.frame.rank, s, w));
                }
            }
        }
        if by_rank.is_empty() {
            return None;
        }
        // What the others were doing: tracing a tile (its rounds, fetches, shading), each a
        // rank that wants a core.
        let tiles: Vec<(u32, f64, f64)> = t
            .files
            .iter()
            .flat_map(|f| {
                f.tiles
                    .iter()
                    .map(move |x| (f.frame.rank, x.start_ms, x.trace_ms))
            })
            .collect();
        let points: Vec<(f64, f64)> = by_rank
            .iter()
            .map(|&(rank, s, w)| {
                let mid = s + w / 2.0;
                let mut others: Vec<u32> = tiles
                    .iter()
                    .filter(|o| o.0 != rank && o.1 <= mid && mid <= o.1 + o.2)
                    .map(|o| o.0)
                    .collect();
                others.sort_unstable();
                others.dedup();
                (1.0 + others.len() as f64, w)
            })
            .collect();
        let (a, b) = line(&points);
        let concurrency = points.iter().map(|p| p.0).sum::<f64>() / points.len() as f64;
        let busy = if render_ranks > 1 {
            ((concurrency - 1.0) / f64::from(render_ranks - 1)).clamp(0.0, 1.0)
        } else {
            1.0
        };
        Some(Sharing {
            alone_ms: a,
            per_rank_ms: b,
            concurrency,
            busy,
            rounds: points.len(),
        })
    }

    /// How much longer than in the traced run a round waits with `ranks` render ranks sharing
    /// the cores.
    pub fn stretch(&self, ranks: u32) -> f64 {
        let c = 1.0 + (f64::from(ranks.max(1)) - 1.0) * self.busy;
        let wait = |c: f64| self.alone_ms + self.per_rank_ms * c;
        let traced = wait(self.concurrency);
        if traced > 0.0 { wait(c) / traced } else { 1.0 }
    }
}

/// The least-squares line `y = a + b x` through `points`, with `a, b >= 0`: when the points do
/// not tell (one x, or y falling with x) `b = 0` and `a` the mean; a negative intercept is
/// raised to 0 with the slope through the means.
fn line(points: &[(f64, f64)]) -> (f64, f64) {
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if sxx <= 0.0 || sxy <= 0.0 {
        return (my, 0.0);
    }
    let b = sxy / sxx;
    let a = my - b * mx;
    if a < 0.0 { (0.0, my / mx) } else { (a, b) }
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct FramePrediction {
    pub frame: u32,
    /// When the frame is complete at the display, ms from the first frame's start.
    pub complete_ms: f64,
    /// Since the previous frame was complete (frame 0: since the start).
    pub frame_ms: f64,
    /// The same, measured in the traces (when they come from a run at the same K).
    pub measured_ms: Option<f64>,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Prediction {
    pub ranks: u32,
    pub render_ranks: u32,
    pub traced_ranks: u32,
    pub frames: Vec<FramePrediction>,
    /// The mean frame interval after the first frame (the first frame alone if there is one).
    pub mean_frame_ms: f64,
    pub measured_mean_frame_ms: Option<f64>,
    /// The rounds' waits against the ranks tracing at once in the traced run (`None`: the traces have
    /// no round times, and nothing stretches for sharing).
    pub sharing: Option<Sharing>,
    /// What shared costs are multiplied by: core sharing, and the cache's work per pixel.
    pub sharing_stretch: f64,
    pub work_stretch: f64,
    /// The fixed cost of a tile (ms, as measured at the traced run's sharing).
    pub tile_fixed_ms: f64,
}

/// A recorded tile and what a millisecond of each of its pixels costs under the model above the
/// fixed cost of a tile: `shared` the part that core sharing stretches (GPU rounds, sending,
/// measured fetches), `network` re-priced fetches.
struct Cost {
    rect: Rect,
    shared: f64,
    network: f64,
}

/// A recorded tile's cost split as `Cost` is, in ms.
fn tile_ms(f: &RankFrame, tile: &Tile, m: &ClusterModel) -> (f64, f64) {
    let gpu: f64 = f.tiles.iter().map(|x| x.trace_ms).sum();
    let share = if gpu > 0.0 { tile.trace_ms / gpu } else { 0.0 };
    let own = tile.trace_ms + tile.send_ms - share * f.frame.fetch_ms;
    match repriced(f, m) {
        None => ((own + share * f.frame.fetch_ms).max(0.0), 0.0),
        Some(net) => (own.max(0.0), share * net),
    }
}

/// The fixed cost of a tile: the intercept of the least-squares line through the tiles' shared
/// costs against their pixels, frame 0 left out when there are others (its first tiles pay the
/// set-up). Zero when the tiles do not tell (all of one size, or a line falling with area).
fn fixed_ms(t: &Traces, m: &ClusterModel) -> f64 {
    let first = t.frames().first().copied();
    let several = t.frames().len() > 1;
    let points: Vec<(f64, f64)> = t
        .files
        .iter()
        .filter(|f| !several || Some(f.frame.frame) != first)
        .flat_map(|f| {
            f.tiles
                .iter()
                .map(move |x| (f64::from(x.w * x.h), tile_ms(f, x, m).0))
        })
        .collect();
    if points.len() < 2 {
        return 0.0;
    }
    let (a, b) = line(&points);
    if b > 0.0 { a } else { 0.0 }
}

/// The costs of a frame's recorded tiles. A rank's first tile of the run also pays a one-time
/// set-up (the GPU's first dispatches); its excess over the frame's median cost per pixel is
/// taken out and returned, the mean over ranks, as a delay every simulated rank starts with.
fn frame_costs(
    t: &Traces,
    frame: u32,
    m: &ClusterModel,
    fixed: f64,
    first: bool,
) -> (Vec<Cost>, f64) {
    let mut out = Vec::new();
    let mut firsts = Vec::new();
    for f in t.files.iter().filter(|f| f.frame.frame == frame) {
        let earliest = f
            .tiles
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.start_ms.total_cmp(&b.1.start_ms))
            .map(|(i, _)| out.len() + i);
        firsts.extend(earliest);
        for tile in &f.tiles {
            let (shared, network) = tile_ms(f, tile, m);
            let rect = Rect {
                x: tile.x,
                y: tile.y,
                w: tile.w,
                h: tile.h,
            };
            let px = rect.pixels().max(1) as f64;
            out.push(Cost {
                shared: (shared - fixed).max(0.0) / px,
                network: network / px,
                rect,
            });
        }
    }
    let mut setup = 0.0;
    if first && !out.is_empty() {
        let mut per: Vec<f64> = out.iter().map(|c| c.shared).collect();
        per.sort_by(f64::total_cmp);
        let median = per[per.len() / 2];
        for &i in &firsts {
            let c = &mut out[i];
            let excess = (c.shared - median).max(0.0) * c.rect.pixels() as f64;
            c.shared = c.shared.min(median);
            setup += excess / firsts.len() as f64;
        }
    }
    (out, setup)
}

/// A rank's fetch time in a frame re-priced by the model's network; `None` keeps the measured.
fn repriced(f: &RankFrame, m: &ClusterModel) -> Option<f64> {
    if m.bandwidth.is_none() && m.latency.is_none() {
        return None;
    }
    let lat = m.latency.unwrap_or(0.0) * f64::from(f.frame.fault_rounds);
    let bw = m
        .bandwidth
        .map_or(0.0, |b| f.frame.fetched_bytes as f64 / b);
    Some(1000.0 * (lat + bw))
}

/// A rectangle's cost: the fixed part and the shared per-pixel parts under it stretched by
/// `stretch`, plus the network's.
fn cost(costs: &[Cost], r: Rect, fixed: f64, stretch: f64) -> f64 {
    let (shared, network) = costs
        .iter()
        .map(|c| {
            let x0 = c.rect.x.max(r.x);
            let y0 = c.rect.y.max(r.y);
            let x1 = (c.rect.x + c.rect.w).min(r.x + r.w);
            let y1 = (c.rect.y + c.rect.h).min(r.y + r.h);
            if x1 > x0 && y1 > y0 {
                let px = f64::from((x1 - x0) * (y1 - y0));
                (c.shared * px, c.network * px)
            } else {
                (0.0, 0.0)
            }
        })
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    (fixed + shared) * stretch + network
}

pub fn simulate(t: &Traces, m: &ClusterModel) -> Result<Prediction> {
    let roles = Roles::new(m.ranks)?;
    let render = roles.render_ranks();
    let frames = t.frames();
    let (mut width, mut height) = (0, 0);
    for f in &t.files {
        for tile in &f.tiles {
            width = width.max(tile.x + tile.w);
            height = height.max(tile.y + tile.h);
        }
    }
    if width == 0 {
        return Err(Error::format(
            &t.dir,
            None,
            "no tile records: simulate needs the traces of a cluster run (mpirun, --trace)",
        ));
    }
    let traced = t.files[0].frame.ranks;
    if !m.work_exponent.is_finite() || m.work_exponent < 0.0 {
        return Err(Error::format(
            &t.dir,
            None,
            format!(
                "the work exponent must be a finite number >= 0, got {}",
                m.work_exponent
            ),
        ));
    }
    let traced_render = Roles::new(traced)?.render_ranks();
    let sharing = Sharing::fit(t, traced_render).or(m.sharing);
    let sharing_stretch = sharing.map_or(1.0, |s| {
        s.stretch(m.ranks_per_node.map_or(render, |n| n.min(render)))
    });
    let cached = t.files.iter().any(|f| f.frame.lookups > 0);
    let work_stretch = if cached {
        (f64::from(render) / f64::from(traced_render)).powf(m.work_exponent)
    } else {
        1.0
    };
    let stretch = sharing_stretch * work_stretch;
    let fixed = fixed_ms(t, m);
    // Each render rank's clock and its frame; each frame's schedule and completion.
    let mut free = vec![0.0f64; render as usize];
    let mut at = vec![0usize; render as usize];
    let mut started = vec![false; render as usize];
    let mut schedules: Vec<Schedule> = frames
        .iter()
        .map(|_| Schedule::new(width, height, render, m.tile, m.min_tile))
        .collect();
    let mut setup = 0.0;
    let costs: Vec<Vec<Cost>> = frames
        .iter()
        .enumerate()
        .map(|(i, &f)| {
            let (c, s) = frame_costs(t, f, m, fixed, i == 0);
            setup += s * stretch;
            c
        })
        .collect();
    free.iter_mut().for_each(|f| *f = setup);
    let mut complete = vec![0.0f64; frames.len()];
    let mut queued: Vec<Vec<Rect>> = vec![Vec::new(); render as usize];
    // The rank that is free first and still has frames goes on.
    while let Some(r) = (0..render as usize)
        .filter(|&r| at[r] < frames.len())
        .min_by(|&a, &b| free[a].total_cmp(&free[b]))
    {
        let fi = at[r];
        if !started[r] {
            started[r] = true;
            queued[r] = schedules[fi].first(r as u32);
            queued[r].reverse();
        }
        let next = queued[r].pop().or_else(|| schedules[fi].next_tile());
        match next {
            Some(rect) => {
                free[r] += cost(&costs[fi], rect, fixed, stretch);
                complete[fi] = complete[fi].max(free[r]);
            }
            None => {
                at[r] += 1;
                started[r] = false;
            }
        }
    }
    let mut out = Vec::new();
    let mut prev = 0.0;
    let measured = measured_completes(t, &frames);
    for (i, &f) in frames.iter().enumerate() {
        let wait = t
            .get(f, 0)
            .and_then(|d| d.displays.first())
            .map_or(0.0, |d| d.copy_wait_ms);
        let c = complete[i].max(prev) + wait;
        out.push(FramePrediction {
            frame: f,
            complete_ms: c,
            frame_ms: c - prev,
            measured_ms: (traced == m.ranks && i > 0)
                .then(|| measured.as_ref().map(|v| v[i] - v[i - 1]))
                .flatten(),
        });
        prev = c;
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let tail: Vec<f64> = out.iter().skip(1).map(|p| p.frame_ms).collect();
    let mean_frame_ms = if tail.is_empty() {
        out[0].frame_ms
    } else {
        mean(&tail)
    };
    let measured_mean_frame_ms = (traced == m.ranks && frames.len() > 1)
        .then(|| measured.map(|v| (v[v.len() - 1] - v[0]) / (v.len() - 1) as f64))
        .flatten();
    Ok(Prediction {
        ranks: m.ranks,
        render_ranks: render,
        traced_ranks: traced,
        frames: out,
        mean_frame_ms,
        measured_mean_frame_ms,
        sharing,
        sharing_stretch,
        work_stretch,
        tile_fixed_ms: fixed,
    })
}

/// The display's completion time of every frame, if every frame has it.
fn measured_completes(t: &Traces, frames: &[u32]) -> Option<Vec<f64>> {
    frames
        .iter()
        .map(|&f| t.get(f, 0)?.displays.first().map(|d| d.complete_ms))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::traces::read::RankFrame;
    use crate::traces::record::{FrameRecord, Tile};
    use crate::traces::record::{FrameSummary, Round};
    use std::path::PathBuf;

    const FRAMES: u32 = 4;

    fn rank_frame(
        frame: u32,
        rank: u32,
        tiles: Vec<Tile>,
        rounds: Vec<Round>,
        lookups: u64,
    ) -> RankFrame {
        RankFrame {
            path: PathBuf::from(format!("frame_{frame:04}.rank{rank}.jsonl")),
            rounds,
            tiles,
            grants: Vec::new(),
            displays: Vec::new(),
            renders: Vec::new(),
            frame: FrameRecord {
                version: 1,
                run: Some("synthetic".into()),
                epoch_wtime: None,
                summary: FrameSummary {
                    frame,
                    role: "render".into(),
                    rank,
                    ranks: 4,
                    lookups,
                    ..FrameSummary::default()
                },
            },
        }
    }

    fn round(start: f64, wait: f64) -> Round {
        Round {
            start_ms: Some(start),
            wait_ms: Some(wait),
            ..Round::default()
        }
    }

    /// A 4-rank run (render ranks 2 and 3) of a 64x64 image in 16x16 tiles of 2 ms each, taken
    /// in turn. With `rounds`, frame 0 has rounds whose waits are 1 + 0.5 c ms at c ranks
    /// tracing at once: one alone at each rank, one at both at once.
    fn traces(rounds: bool, lookups: u64) -> Traces {
        let mut files = Vec::new();
        for frame in 0..FRAMES {
            for rank in [2, 3] {
                // Rank 2 traces from 0 ms, rank 3 from 10 ms, a tile every 10 ms.
                let tiles = (0..16)
                    .filter(|i| i % 2 == rank % 2)
                    .map(|i| Tile {
                        x: (i % 4) * 16,
                        y: (i / 4) * 16,
                        w: 16,
                        h: 16,
                        start_ms: f64::from(10 * (rank - 2) + 10 * (i / 2)),
                        trace_ms: 2.0,
                        send_ms: 0.0,
                    })
                    .collect();
                let r = if rounds && frame == 0 {
                    // While the other rank traces nothing, and at 10 ms while both do.
                    let alone = if rank == 2 { 0.0 } else { 85.0 };
                    vec![round(alone, 1.5), round(10.0, 2.0)]
                } else {
                    Vec::new()
                };
                files.push(rank_frame(frame, rank, tiles, r, lookups));
            }
        }
        Traces {
            dir: PathBuf::from("synthetic"),
            files,
        }
    }

    fn model(ranks: u32, work_exponent: f64, ranks_per_node: Option<u32>) -> ClusterModel {
        ClusterModel {
            ranks,
            bandwidth: None,
            latency: None,
            tile: 16,
            min_tile: 16,
            ranks_per_node,
            work_exponent,
            sharing: None,
        }
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * b.abs().max(1.0)
    }

    #[test]
    fn the_round_waits_fit_a_line_in_the_concurrent_ranks() {
        let s = Sharing::fit(&traces(true, 0), 2).unwrap();
        assert!(close(s.alone_ms, 1.0) && close(s.per_rank_ms, 0.5), "{s:?}");
        assert!(close(s.concurrency, 1.5) && close(s.busy, 0.5), "{s:?}");
        assert_eq!(s.rounds, 4);
        // 4 render ranks: 1 + 3 x 0.5 ranks tracing, 1 + 0.5 x 2.5 ms against 1.75.
        assert!(close(s.stretch(4), 2.25 / 1.75));
        assert!(close(s.stretch(2), 1.0));
        assert!(close(s.stretch(1), 1.5 / 1.75));
        assert!(Sharing::fit(&traces(false, 0), 2).is_none());
    }

    #[test]
    fn own_run_replays_the_traced_work() {
        let p = simulate(&traces(false, 0), &model(4, 1.0, None)).unwrap();
        // 32 ms of tiles a frame over 2 ranks, in whole 2 ms tiles.
        assert!((16.0..=18.0).contains(&p.mean_frame_ms), "{p:?}");
        assert_eq!(
            (p.sharing_stretch, p.work_stretch, p.tile_fixed_ms),
            (1.0, 1.0, 0.0)
        );
    }

    #[test]
    fn predictions_scale_with_the_sharing_and_the_cache_terms() {
        let base = simulate(&traces(false, 0), &model(6, 0.0, None)).unwrap();
        // Core sharing alone: every cost x 9/7, and so the frames.
        let shared = simulate(&traces(true, 0), &model(6, 1.0, None)).unwrap();
        assert!(close(shared.sharing_stretch, 2.25 / 1.75), "{shared:?}");
        assert_eq!(shared.work_stretch, 1.0, "replicated: no cache term");
        assert!(close(
            shared.mean_frame_ms,
            base.mean_frame_ms * 2.25 / 1.75
        ));
        // Traces without rounds take a given fit as if they had its rounds.
        let mut lent = model(6, 1.0, None);
        lent.sharing = Sharing::fit(&traces(true, 0), 2);
        let borrowed = simulate(&traces(false, 0), &lent).unwrap();
        assert!(close(borrowed.mean_frame_ms, shared.mean_frame_ms));
        // One rank per node: rounds wait as alone.
        let nodes = simulate(&traces(true, 0), &model(6, 1.0, Some(1))).unwrap();
        assert!(close(nodes.mean_frame_ms, base.mean_frame_ms * 1.5 / 1.75));
        // The cache term: (4 / 2)^w.
        for w in [0.5, 1.0, 1.5] {
            let cached = simulate(&traces(false, 100), &model(6, w, None)).unwrap();
            assert!(close(cached.work_stretch, 2f64.powf(w)));
            assert!(close(
                cached.mean_frame_ms,
                base.mean_frame_ms * 2f64.powf(w)
            ));
        }
        // More ranks without either term: shorter frames.
        assert!(
            base.mean_frame_ms
                < simulate(&traces(false, 0), &model(4, 0.0, None))
                    .unwrap()
                    .mean_frame_ms
        );
    }

    #[test]
    fn a_tile_costs_a_fixed_part_plus_its_pixels() {
        // Tiles of 256 and 64 pixels costing 1 + 0.01 ms a pixel: the fit finds the 1 ms.
        let mut t = traces(false, 0);
        for f in &mut t.files {
            for (i, tile) in f.tiles.iter_mut().enumerate() {
                if i % 2 == 0 {
                    tile.w = 8;
                    tile.h = 8;
                }
                tile.trace_ms = 1.0 + 0.01 * f64::from(tile.w * tile.h);
            }
        }
        assert!(close(fixed_ms(&t, &model(4, 0.0, None)), 1.0));
    }

    #[test]
    fn bad_exponents_are_refused() {
        for w in [-1.0, f64::NAN, f64::INFINITY] {
            let e = simulate(&traces(false, 0), &model(6, w, None)).unwrap_err();
            assert!(e.to_string().contains("work exponent"), "{e}");
        }
    }
}
