//! The GPU thread of the live view (docs/ARCHITECTURE.md, Live view): it owns the tracer and
//! renders what the newest wish asks. While the camera moves, frames at a reduced size chosen to
//! hold `TARGET_FPS`; at rest, the full frame, one sample pass at a time up to the requested
//! samples per pixel, starting over when a newer wish comes. The passes are parts of one
//! progressive render (`Shading::part_of_spp`) whose sums, added in sample order and divided as
//! the tracer divides, are the bits `dcrt render` writes.

use super::state::{RawFrame, Shared, StillFrame, Wish, lock};
use crate::error::Result;
use crate::gpu::frame::{Frame, FrameStats};
use crate::gpu::tracer::Tracer;
use crate::output::to_rgb8;
use crate::render::frames::{FramePlan, Role, View, hit_rate, run_images};
use crate::shading::Shading;
use std::sync::Arc;

/// The frame rate the reduced frames aim at while the camera moves.
pub const TARGET_FPS: f64 = 20.0;
/// The smallest side of a reduced frame.
const MIN_SIDE: u32 = 16;

/// The full image and what is rendered at rest.
pub struct Still {
    pub width: u32,
    pub height: u32,
    pub background: [f32; 3],
    /// The shading at rest (mode and spp come from the wish).
    pub shading: Shading,
}

/// Running totals for `GET /stats`.
#[derive(Default)]
struct Totals {
    frames: u64,
    still_frames: u64,
    fault_rounds: u64,
    fetched_bytes: u64,
    lookups: u64,
    hits: u64,
}

/// Renders for the clients until an error (the process ends on a signal).
pub fn produce(tracer: &mut Tracer<'_>, shared: &Arc<Shared>, still: &Still) -> Result<()> {
    let mut scale: f64 = 0.5;
    let (mut done, mut drawn) = (None, None);
    let mut totals = Totals::default();
    loop {
        let (wish, at_rest) = shared.next_job(done, drawn);
        if !at_rest {
            let w = (f64::from(still.width) * scale).round() as u32;
            let h = (f64::from(still.height) * scale).round() as u32;
            let (w, h) = (
                w.clamp(MIN_SIDE.min(still.width), still.width),
                h.clamp(MIN_SIDE.min(still.height), still.height),
            );
            let shading = Shading {
                mode: wish.mode,
                spp: 1,
                ..still.shading
            };
            let (frame, stats) = render(tracer, &wish, shading, (w, h), still.background)?;
            // The size whose frame takes 1/TARGET_FPS, from this frame's time per pixel.
            let want = (1.0 / TARGET_FPS / stats.seconds.max(1e-4)).sqrt();
            scale = (scale * want.clamp(0.5, 2.0)).clamp(0.05, 1.0);
            totals.add(&stats, false);
            publish(shared, &frame, &stats, &wish, (1, 1), false, &totals);
            drawn = Some(wish.seq);
            continue;
        }
        // At rest: sample passes, each added to the sums in sample order.
        let spp = wish.spp;
        let mut sums: Vec<[f32; 3]> = Vec::new();
        let mut finished = true;
        for s in 0..spp {
            let shading = Shading {
                mode: wish.mode,
                spp: 1,
                first_sample: s,
                part_of_spp: Some(spp),
                ..still.shading
            };
            let (mut frame, stats) = render(
                tracer,
                &wish,
                shading,
                (still.width, still.height),
                still.background,
            )?;
            if s == 0 {
                sums = frame.pixels.iter().map(|p| p.rgb).collect();
            } else {
                for (sum, p) in sums.iter_mut().zip(&frame.pixels) {
                    for (c, v) in sum.iter_mut().zip(p.rgb) {
                        *c += v;
                    }
                }
            }
            // Divided as the tracer divides a render's sums (`read_pixels`): by a multiply.
            let scale = 1.0 / (s + 1) as f32;
            for (p, sum) in frame.pixels.iter_mut().zip(&sums) {
                p.rgb = sum.map(|c| c * scale);
            }
            totals.add(&stats, s + 1 == spp);
            publish(shared, &frame, &stats, &wish, (s + 1, spp), true, &totals);
            if s + 1 == spp {
                shared.still.send_replace(Some(Arc::new(StillFrame {
                    seq: wish.seq,
                    image: to_rgb8(&frame),
                })));
            }
            if shared.superseded(wish.seq) {
                finished = s + 1 == spp;
                break;
            }
        }
        if finished {
            done = Some(wish.seq);
        }
    }
}

/// One frame through the frame loop (`run_images`, as `dcrt render` renders a frame).
fn render(
    tracer: &mut Tracer<'_>,
    wish: &Wish,
    shading: Shading,
    (width, height): (u32, u32),
    background: [f32; 3],
) -> Result<(Frame, FrameStats)> {
    tracer.set_shading(shading)?;
    let plan = FramePlan {
        frames: 1,
        view: View::Fixed(wish.camera),
        role: Role::one_process(tracer),
        trace_dir: None,
    };
    let mut out = None;
    run_images(
        tracer,
        &plan,
        width,
        height,
        background,
        &mut |_, frame, stats| {
            out = Some((frame, stats.clone()));
            Ok(())
        },
    )?;
    out.ok_or_else(|| crate::Error::Internal("the frame loop gave no frame".into()))
}

impl Totals {
    fn add(&mut self, s: &FrameStats, still: bool) {
        self.frames += 1;
        self.still_frames += u64::from(still);
        self.fault_rounds += u64::from(s.fault_rounds);
        self.fetched_bytes += s.fetched_bytes;
        self.lookups += s.lookups;
        self.hits += s.hits;
    }
}

const MIB: f64 = 1024.0 * 1024.0;

/// Hands the frame to the encoder and updates the statistics.
fn publish(
    shared: &Shared,
    frame: &Frame,
    stats: &FrameStats,
    wish: &Wish,
    (samples, spp): (u32, u32),
    full: bool,
    totals: &Totals,
) {
    let ms = |s: f64| s * 1e3;
    let info = serde_json::json!({
        "seq": wish.seq,
        "width": frame.width,
        "height": frame.height,
        "full": full,
        "mode": wish.mode.name(),
        "samples": samples,
        "spp": spp,
        "frame_ms": ms(stats.seconds),
        "phases_ms": {
            "trace": ms(stats.trace_seconds),
            "shade": ms(stats.shade_seconds),
            "fetch": ms(stats.fetch_seconds),
            "upload": ms(stats.upload_seconds),
        },
        "fault_rounds": stats.fault_rounds,
        "hit_rate": hit_rate(stats),
        "fetched_mib": stats.fetched_bytes as f64 / MIB,
        "camera": super::camera::CameraJson::of(&wish.camera),
    });
    {
        let mut s = lock(&shared.stats);
        let total_hit_rate = if totals.lookups > 0 {
            totals.hits as f64 / totals.lookups as f64
        } else {
            1.0
        };
        let spp_reached = if full { samples } else { 0 };
        *s = serde_json::json!({
            "frames": totals.frames,
            "still_frames": totals.still_frames,
            "seq": wish.seq,
            "spp_reached": spp_reached,
            "spp": spp,
            "last": info,
            "fault_rounds": totals.fault_rounds,
            "hit_rate": total_hit_rate,
            "fetched_mib": totals.fetched_bytes as f64 / MIB,
        });
    }
    shared.raw.put(RawFrame {
        image: to_rgb8(frame),
        info,
    });
}
