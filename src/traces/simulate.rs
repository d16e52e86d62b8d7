//! Replays a cluster run's traces at another number of ranks (docs/ARCHITECTURE.md, Traces).
//!
//! The model: a frame's cost is spread over the image as the run measured it, each recorded
//! tile's time (GPU trace rounds and shading, its fetches, sending its pixels) over its pixels.
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
//! What it assumes, and where it breaks: the work per pixel does not depend on K (with a
//! distributed cache, more ranks own smaller shares and see fewer tiles each, so their hit rate
//! changes; this is not modelled); a tile's cost scales with its area (small tiles at many ranks
//! pay a fixed cost per dispatch that the model spreads instead); requests and grants cost
//! nothing; the display is never the bottleneck beyond its measured copy wait; ranks do not share
//! cores (on an oversubscribed machine measured GPU times already include the sharing of the
//! run they came from, and a run at another K shares differently).

use super::read::{RankFrame, Traces};
use crate::cluster::Roles;
use crate::cluster::schedule::Schedule;
use crate::error::{Error, Result};
use crate::gpu::tracer::Rect;
use serde::Serialize;

#[derive(Clone, Debug)]
pub struct Model {
    /// Total MPI ranks, as `mpirun -n K`.
    pub ranks: u32,
    /// Bytes per second of block fetches; `None` keeps the measured fetch times.
    pub bandwidth: Option<f64>,
    /// Seconds per fault round's fetch; `None` keeps the measured fetch times.
    pub latency: Option<f64>,
    /// The balancer's `--tile` and `--min-tile` of the run.
    pub tile: u32,
    pub min_tile: u32,
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
}

/// A recorded tile and what a millisecond of each of its pixels costs under the model.
struct Cost {
    rect: Rect,
    per_pixel_ms: f64,
}

/// The costs of a frame's recorded tiles. A rank's first tile of the run also pays a one-time
/// set-up (the GPU's first dispatches); its excess over the frame's median cost per pixel is
/// taken out and returned, the mean over ranks, as a delay every simulated rank starts with.
fn frame_costs(t: &Traces, frame: u32, m: &Model, first: bool) -> (Vec<Cost>, f64) {
    let mut out = Vec::new();
    let mut firsts = Vec::new();
    for f in t.files.iter().filter(|f| f.frame.frame == frame) {
        let gpu: f64 = f.tiles.iter().map(|x| x.trace_ms).sum();
        let earliest = f
            .tiles
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.start_ms.total_cmp(&b.1.start_ms))
            .map(|(i, _)| out.len() + i);
        firsts.extend(earliest);
        for tile in &f.tiles {
            let share = if gpu > 0.0 { tile.trace_ms / gpu } else { 0.0 };
            let ms =
                tile.trace_ms + tile.send_ms - share * f.frame.fetch_ms + share * fetch_ms(f, m);
            let rect = Rect {
                x: tile.x,
                y: tile.y,
                w: tile.w,
                h: tile.h,
            };
            out.push(Cost {
                per_pixel_ms: ms.max(0.0) / rect.pixels().max(1) as f64,
                rect,
            });
        }
    }
    let mut setup = 0.0;
    if first && !out.is_empty() {
        let mut per: Vec<f64> = out.iter().map(|c| c.per_pixel_ms).collect();
        per.sort_by(f64::total_cmp);
        let median = per[per.len() / 2];
        for &i in &firsts {
            let c = &mut out[i];
            let excess = (c.per_pixel_ms - median).max(0.0) * c.rect.pixels() as f64;
            c.per_pixel_ms = c.per_pixel_ms.min(median);
            setup += excess / firsts.len() as f64;
        }
    }
    (out, setup)
}

/// A rank's fetch time in a frame under the model.
fn fetch_ms(f: &RankFrame, m: &Model) -> f64 {
    if m.bandwidth.is_none() && m.latency.is_none() {
        return f.frame.fetch_ms;
    }
    let lat = m.latency.unwrap_or(0.0) * f64::from(f.frame.fault_rounds);
    let bw = m
        .bandwidth
        .map_or(0.0, |b| f.frame.fetched_bytes as f64 / b);
    1000.0 * (lat + bw)
}

fn cost(costs: &[Cost], r: Rect) -> f64 {
    costs
        .iter()
        .map(|c| {
            let x0 = c.rect.x.max(r.x);
            let y0 = c.rect.y.max(r.y);
            let x1 = (c.rect.x + c.rect.w).min(r.x + r.w);
            let y1 = (c.rect.y + c.rect.h).min(r.y + r.h);
            if x1 > x0 && y1 > y0 {
                c.per_pixel_ms * f64::from((x1 - x0) * (y1 - y0))
            } else {
                0.0
            }
        })
        .sum()
}

pub fn simulate(t: &Traces, m: &Model) -> Result<Prediction> {
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
            let (c, s) = frame_costs(t, f, m, i == 0);
            setup += s;
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
                free[r] += cost(&costs[fi], rect);
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
    })
}

/// The display's completion time of every frame, if every frame has it.
fn measured_completes(t: &Traces, frames: &[u32]) -> Option<Vec<f64>> {
    frames
        .iter()
        .map(|&f| t.get(f, 0)?.displays.first().map(|d| d.complete_ms))
        .collect()
}
