//! The frame loop (docs/ARCHITECTURE.md, Frame loop): what every renderer of a sequence of frames
//! repeats, in one place. Per frame: its camera, `Tracer::begin_frame`, the caller's tracing (the
//! whole image in one process, the balancer's tiles on a cluster render rank),
//! `Tracer::end_frame`, the cache trace with its frame summary, the caller's outputs, then the
//! trace file.

use crate::dc::CacheMap;
use crate::error::Result;
use crate::gpu::frame::{Frame, FrameStats, Rect};
use crate::gpu::layout::Pixel;
use crate::gpu::tracer::Tracer;
use crate::scene::Camera;
use crate::traces::record::{FrameSummary, FrameTrace};
use std::path::Path;

/// Where the camera of each frame is.
#[derive(Clone, Copy, Debug)]
pub enum View {
    /// One turn about the focal point over the frames: frame `i` of `n` at TAU * i / n.
    Orbit(Camera),
    /// The same camera in every frame (benchmarks, the display benchmark's turned camera).
    Fixed(Camera),
}

impl View {
    pub fn camera(&self, frame: u32, frames: u32) -> Camera {
        match self {
            View::Orbit(c) => c.orbit(std::f64::consts::TAU * f64::from(frame) / f64::from(frames)),
            View::Fixed(c) => *c,
        }
    }
}

/// Who renders the frames, as their traces name it: the summary's role, rank and rank count, and
/// the rank in the trace file's name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Role {
    pub name: &'static str,
    pub rank: u32,
    pub ranks: u32,
}

impl Role {
    /// A render in one process: `single` when replicated; through a distributed cache of virtual
    /// ranks, `render` as the rank it renders as.
    pub fn one_process(tracer: &Tracer<'_>) -> Role {
        match tracer.cache() {
            None => Role {
                name: "single",
                rank: 0,
                ranks: 1,
            },
            Some((ranks, _, _)) => Role {
                name: "render",
                rank: ranks.rank,
                ranks: ranks.n,
            },
        }
    }
}

/// A sequence of frames: how many, their cameras, who renders them, and where their traces go.
#[derive(Clone, Copy, Debug)]
pub struct FramePlan<'a> {
    pub frames: u32,
    pub view: View,
    pub role: Role,
    /// Write each frame's fault/fetch trace (JSON Lines) into this directory.
    pub trace_dir: Option<&'a Path>,
}

/// One frame being traced: its number and camera, the tracer, and the frame's statistics that
/// `Tracer::render_rect` adds to.
pub struct FrameCtx<'a, 'g> {
    pub frame: u32,
    pub camera: Camera,
    pub tracer: &'a mut Tracer<'g>,
    pub stats: &'a mut FrameStats,
}

impl FrameCtx<'_, '_> {
    /// Traces and shades the whole image at `width` x `height`, as `Tracer::render` does.
    pub fn render_whole(&mut self, width: u32, height: u32, background: [f32; 3]) -> Result<Frame> {
        let basis = self.camera.basis(width, height);
        let rect = Rect::whole(width, height);
        let pixels = self
            .tracer
            .render_rect(&basis, background, rect, self.stats)?;
        Ok(Frame {
            width,
            height,
            pixels,
        })
    }
}

/// What a caller does in each frame of `run_frames`.
pub trait FrameBody {
    /// Traces the frame. Only this is inside the frame's clock.
    fn trace(&mut self, ctx: FrameCtx<'_, '_>) -> Result<()>;

    /// After the clock stopped: the frame's final statistics, and its trace (summary filled)
    /// before it is written; events may be added to it.
    fn finish(&mut self, frame: u32, stats: &FrameStats, trace: &mut FrameTrace) -> Result<()>;
}

/// Renders the frames of `plan` with `tracer`, `body` tracing each and taking its results.
pub fn run_frames(
    tracer: &mut Tracer<'_>,
    plan: &FramePlan<'_>,
    body: &mut dyn FrameBody,
) -> Result<()> {
    for frame in 0..plan.frames {
        let camera = plan.view.camera(frame, plan.frames);
        run_frame(tracer, plan, frame, camera, body)?;
    }
    Ok(())
}

/// Frame `frame` of `plan` with `camera`: one turn of `run_frames`, for a caller that learns its
/// frames one at a time (a render rank of a live view).
pub fn run_frame(
    tracer: &mut Tracer<'_>,
    plan: &FramePlan<'_>,
    frame: u32,
    camera: Camera,
    body: &mut dyn FrameBody,
) -> Result<()> {
    let started = crate::traces::record::ms_since_epoch(std::time::Instant::now());
    let mut stats = tracer.begin_frame();
    body.trace(FrameCtx {
        frame,
        camera,
        tracer: &mut *tracer,
        stats: &mut stats,
    })?;
    tracer.end_frame(&mut stats)?;
    let mut trace = tracer.take_trace();
    let cache = tracer.cache().map(|(_, lines, map)| (lines, map));
    trace.summary = summarize(&stats, cache, frame, plan.role);
    trace.summary.start_ms = Some(started);
    body.finish(frame, &stats, &mut trace)?;
    if let Some(dir) = plan.trace_dir {
        trace.write(dir)?;
    }
    Ok(())
}

/// The frames of one process: each the whole image at `width` x `height`, handed to `done` with
/// its statistics once its clock stopped. `done` may keep a frame (`std::mem::take`); the pixels
/// it leaves are written over by the next frame's, which saves a fresh allocation's page faults
/// in every frame (docs/ARCHITECTURE.md, Frame loop).
pub fn run_images(
    tracer: &mut Tracer<'_>,
    plan: &FramePlan<'_>,
    width: u32,
    height: u32,
    background: [f32; 3],
    done: &mut dyn FnMut(u32, &mut Frame, &FrameStats) -> Result<()>,
) -> Result<()> {
    struct Images<'d> {
        size: (u32, u32, [f32; 3]),
        image: Option<Frame>,
        /// The last frame's pixels, unless `done` took them.
        spare: Vec<Pixel>,
        done: &'d mut dyn FnMut(u32, &mut Frame, &FrameStats) -> Result<()>,
    }
    impl FrameBody for Images<'_> {
        fn trace(&mut self, mut ctx: FrameCtx<'_, '_>) -> Result<()> {
            let (w, h, bg) = self.size;
            if !self.spare.is_empty() {
                ctx.tracer.recycle_pixels(std::mem::take(&mut self.spare));
            }
            self.image = Some(ctx.render_whole(w, h, bg)?);
            Ok(())
        }
        fn finish(&mut self, frame: u32, stats: &FrameStats, _: &mut FrameTrace) -> Result<()> {
            match self.image.take() {
                Some(mut image) => {
                    (self.done)(frame, &mut image, stats)?;
                    self.spare = image.pixels;
                    Ok(())
                }
                None => Ok(()),
            }
        }
    }
    super::memory::check_image(width, height)?;
    let mut images = Images {
        size: (width, height, background),
        image: None,
        spare: Vec::new(),
        done,
    };
    run_frames(tracer, plan, &mut images)
}

/// Cache hits per lookup; 1 without lookups (no cache, or nothing looked up).
pub fn hit_rate(stats: &FrameStats) -> f64 {
    if stats.lookups > 0 {
        stats.hits as f64 / stats.lookups as f64
    } else {
        1.0
    }
}

/// A frame's summary record: who rendered frame `frame` and what it cost; the cache's figures
/// when the tracer has a cache of `cache` = (lines, mapping), else zero (hit rate 1).
pub fn summarize(
    stats: &FrameStats,
    cache: Option<(u32, CacheMap)>,
    frame: u32,
    role: Role,
) -> FrameSummary {
    let mut s = FrameSummary {
        frame,
        role: role.name.into(),
        rank: role.rank,
        ranks: role.ranks,
        rounds: stats.rounds,
        hit_rate: 1.0,
        frame_ms: stats.seconds * 1e3,
        trace_ms: stats.trace_seconds * 1e3,
        shade_ms: stats.shade_seconds * 1e3,
        ..FrameSummary::default()
    };
    if let Some((lines, map)) = cache {
        s.cache_lines = lines;
        s.cache_map = format!("{map:?}").to_lowercase();
        s.fault_rounds = stats.fault_rounds;
        s.shared_rounds = stats.shared_rounds;
        s.lookups = stats.lookups;
        s.hits = stats.hits;
        s.misses = stats.misses;
        s.hit_rate = hit_rate(stats);
        s.fetched_blocks = stats.fetched_blocks;
        s.fetched_bytes = stats.fetched_bytes;
        s.distinct_blocks = stats.distinct_blocks;
        s.fault_round_bound = stats.fault_round_bound;
        s.fetch_ms = stats.fetch_seconds * 1e3;
        s.upload_ms = stats.upload_seconds * 1e3;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats() -> FrameStats {
        FrameStats {
            rounds: 7,
            fault_rounds: 5,
            shared_rounds: 3,
            lookups: 40,
            hits: 30,
            misses: 10,
            fetched_blocks: 9,
            fetched_bytes: 9 * 8192,
            distinct_blocks: 6,
            fault_round_bound: 2,
            seconds: 0.25,
            trace_seconds: 0.125,
            shade_seconds: 0.0625,
            fetch_seconds: 0.03125,
            upload_seconds: 0.015625,
            ..FrameStats::default()
        }
    }

    #[test]
    fn replicated_summary_has_no_cache_figures() {
        let role = Role {
            name: "single",
            rank: 0,
            ranks: 1,
        };
        let s = summarize(&stats(), None, 3, role);
        let want = FrameSummary {
            frame: 3,
            role: "single".into(),
            rank: 0,
            ranks: 1,
            rounds: 7,
            hit_rate: 1.0,
            frame_ms: 250.0,
            trace_ms: 125.0,
            shade_ms: 62.5,
            ..FrameSummary::default()
        };
        assert_eq!(s, want);
    }

    #[test]
    fn cache_summary_has_every_figure() {
        let role = Role {
            name: "render",
            rank: 2,
            ranks: 5,
        };
        let s = summarize(&stats(), Some((64, CacheMap::Demarle)), 1, role);
        let want = FrameSummary {
            frame: 1,
            role: "render".into(),
            rank: 2,
            ranks: 5,
            cache_lines: 64,
            cache_map: "demarle".into(),
            rounds: 7,
            fault_rounds: 5,
            shared_rounds: 3,
            lookups: 40,
            hits: 30,
            misses: 10,
            hit_rate: 0.75,
            fetched_blocks: 9,
            fetched_bytes: 9 * 8192,
            distinct_blocks: 6,
            fault_round_bound: 2,
            frame_ms: 250.0,
            trace_ms: 125.0,
            fetch_ms: 31.25,
            upload_ms: 15.625,
            shade_ms: 62.5,
            start_ms: None,
        };
        assert_eq!(s, want);
        let none = FrameStats {
            lookups: 0,
            hits: 0,
            ..stats()
        };
        let s = summarize(&none, Some((64, CacheMap::Ize)), 1, role);
        assert_eq!((s.hit_rate, s.cache_map.as_str()), (1.0, "ize"));
    }

    #[test]
    fn orbit_turns_once_and_fixed_stays() {
        let c = Camera {
            position: [0.0, -2.0, 1.0],
            focal_point: [0.0, 0.0, 0.0],
            view_up: [0.0, 0.0, 1.0],
            view_angle: 40.0,
            parallel_scale: None,
        };
        assert_eq!(View::Orbit(c).camera(0, 4), c.orbit(0.0));
        let half = View::Orbit(c).camera(2, 4);
        assert_eq!(half, c.orbit(std::f64::consts::PI));
        assert_ne!(half, c);
        for i in 0..4 {
            assert_eq!(View::Fixed(c).camera(i, 4), c);
        }
    }
}
