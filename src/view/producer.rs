//! The frames of the live view (docs/ARCHITECTURE.md, Live view): what the newest wish asks,
//! made by a `Frames` (the tracer of one process, or the render ranks of an mpirun job through
//! the display rank). While the camera moves, frames at a reduced size chosen to hold
//! `TARGET_FPS`; at rest, the full frame, one sample pass at a time up to the requested samples
//! per pixel, starting over when a newer wish comes. The passes are parts of one progressive
//! render (`Shading::part_of_spp`) whose sums, added in sample order and divided as the tracer
//! divides, are the bits `dcrt render` writes.

use super::state::{RawFrame, Shared, StillFrame, Wish, lock};
use crate::error::{Error, Result};
use crate::gpu::frame::{Frame, FrameStats};
use crate::gpu::tracer::Tracer;
use crate::output::to_rgb8;
use crate::render::frames::{FramePlan, Role, View, run_images};
use crate::scene::Camera;
use crate::shading::Shading;
use std::sync::Arc;
use std::time::Duration;

/// The frame rate the reduced frames aim at while the camera moves.
pub const TARGET_FPS: f64 = 20.0;
/// The smallest side of a reduced frame.
const MIN_SIDE: u32 = 16;

/// The full image and what is rendered at rest.
pub struct Still {
    pub width: u32,
    pub height: u32,
    /// The shading at rest (mode and spp come from the wish).
    pub shading: Shading,
}

/// What makes the view's frames.
pub trait Frames {
    /// One frame of `camera` at `size` (width, height) with `shading` (one sample pass).
    /// `sums`: the caller adds it to other passes, so its pixels must come linear.
    fn render(
        &mut self,
        camera: &Camera,
        shading: Shading,
        size: (u32, u32),
        sums: bool,
    ) -> Result<Made>;

    /// Takes a frame's pixels back once they were converted, for the next frame of the size to
    /// write over (`Tracer::recycle_pixels`).
    fn recycle(&mut self, _frame: Frame) {}

    /// How long the view may wait for a wish before calling `between`; `None`: as long as it
    /// likes.
    fn slice(&self) -> Option<Duration> {
        None
    }

    /// Between frames, every `slice` while no frame is wanted.
    fn between(&mut self) -> Result<()> {
        Ok(())
    }
}

/// A frame as made, and what it cost.
pub enum Made {
    /// Linear pixels.
    Linear(Frame, Figures),
    /// sRGB 8 bits, as `to_rgb8` makes them.
    Rgb8(image::RgbImage, Figures),
}

impl Made {
    fn figures(&self) -> &Figures {
        match self {
            Made::Linear(_, f) | Made::Rgb8(_, f) => f,
        }
    }
}

/// What a frame cost, for the overlay and `GET /stats`: its time, the phases (of the slowest
/// render rank), the cache's figures (the most fault rounds of any rank; fetches, lookups and
/// hits summed), and each render rank's part.
#[derive(Clone, Debug, Default)]
pub struct Figures {
    pub seconds: f64,
    pub trace_seconds: f64,
    pub shade_seconds: f64,
    pub fetch_seconds: f64,
    pub upload_seconds: f64,
    pub fault_rounds: u64,
    pub fetched_bytes: u64,
    pub lookups: u64,
    pub hits: u64,
    pub shares: Vec<Share>,
}

/// A render rank's part of a frame.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Share {
    pub rank: u32,
    pub tiles: u64,
    pub pixels: u64,
}

impl Figures {
    /// The figures of one process's frame of `pixels` pixels.
    pub fn of(s: &FrameStats, pixels: u64) -> Figures {
        Figures {
            seconds: s.seconds,
            trace_seconds: s.trace_seconds,
            shade_seconds: s.shade_seconds,
            fetch_seconds: s.fetch_seconds,
            upload_seconds: s.upload_seconds,
            fault_rounds: u64::from(s.fault_rounds),
            fetched_bytes: s.fetched_bytes,
            lookups: s.lookups,
            hits: s.hits,
            shares: vec![Share {
                rank: 0,
                tiles: 1,
                pixels,
            }],
        }
    }

    fn hit_rate(&self) -> f64 {
        if self.lookups > 0 {
            self.hits as f64 / self.lookups as f64
        } else {
            1.0
        }
    }
}

/// The frames of one process: its tracer, each frame through the frame loop (`run_images`, as
/// `dcrt render` renders a frame).
pub struct OneProcess<'t, 'g> {
    pub tracer: &'t mut Tracer<'g>,
    pub background: [f32; 3],
}

impl Frames for OneProcess<'_, '_> {
    fn render(
        &mut self,
        camera: &Camera,
        shading: Shading,
        (width, height): (u32, u32),
        _sums: bool,
    ) -> Result<Made> {
        let tracer = &mut *self.tracer;
        tracer.set_shading(shading)?;
        let plan = FramePlan {
            frames: 1,
            view: View::Fixed(*camera),
            role: Role::one_process(tracer),
            trace_dir: None,
        };
        let mut out = None;
        run_images(
            tracer,
            &plan,
            width,
            height,
            self.background,
            &mut |_, frame, stats| {
                out = Some((std::mem::take(frame), stats.clone()));
                Ok(())
            },
        )?;
        let (frame, stats) =
            out.ok_or_else(|| Error::Internal("the frame loop gave no frame".into()))?;
        let pixels = u64::from(width) * u64::from(height);
        Ok(Made::Linear(frame, Figures::of(&stats, pixels)))
    }

    fn recycle(&mut self, frame: Frame) {
        self.tracer.recycle_pixels(frame.pixels);
    }
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
pub fn produce(frames: &mut dyn Frames, shared: &Arc<Shared>, still: &Still) -> Result<()> {
    let mut scale: f64 = 0.5;
    let (mut done, mut drawn) = (None, None);
    let mut totals = Totals::default();
    loop {
        let Some((wish, at_rest)) = shared.next_job(done, drawn, frames.slice()) else {
            frames.between()?;
            continue;
        };
        if !at_rest {
            let w = (f64::from(still.width) * scale).round() as u32;
            let h = (f64::from(still.height) * scale).round() as u32;
            let size = (
                w.clamp(MIN_SIDE.min(still.width), still.width),
                h.clamp(MIN_SIDE.min(still.height), still.height),
            );
            let shading = Shading {
                mode: wish.mode,
                spp: 1,
                ..still.shading
            };
            let (image, f) = match frames.render(&wish.camera, shading, size, false)? {
                Made::Linear(frame, f) => {
                    let image = to_rgb8(&frame);
                    frames.recycle(frame);
                    (image, f)
                }
                Made::Rgb8(image, f) => (image, f),
            };
            // The size whose frame takes 1/TARGET_FPS, from this frame's time per pixel.
            let want = (1.0 / TARGET_FPS / f.seconds.max(1e-4)).sqrt();
            scale = (scale * want.clamp(0.5, 2.0)).clamp(0.05, 1.0);
            totals.add(&f, false);
            publish(shared, image, &f, &wish, (1, 1), false, &totals);
            drawn = Some(wish.seq);
            continue;
        }
        // At rest: sample passes, each added to the sums in sample order.
        let spp = wish.spp;
        let size = (still.width, still.height);
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
            let made = frames.render(&wish.camera, shading, size, spp > 1)?;
            let f = made.figures().clone();
            let image = match made {
                Made::Linear(mut frame, _) if spp > 1 => {
                    if s == 0 {
                        sums = frame.pixels.iter().map(|p| p.rgb).collect();
                    } else {
                        for (sum, p) in sums.iter_mut().zip(&frame.pixels) {
                            for (c, v) in sum.iter_mut().zip(p.rgb) {
                                *c += v;
                            }
                        }
                    }
                    // Divided as the tracer divides a render's sums (`read_pixels`): by a
                    // multiply.
                    let scale = 1.0 / (s + 1) as f32;
                    for (p, sum) in frame.pixels.iter_mut().zip(&sums) {
                        p.rgb = sum.map(|c| c * scale);
                    }
                    let image = to_rgb8(&frame);
                    frames.recycle(frame);
                    image
                }
                Made::Linear(frame, _) => {
                    let image = to_rgb8(&frame);
                    frames.recycle(frame);
                    image
                }
                Made::Rgb8(_, _) if spp > 1 => {
                    return Err(Error::Internal(
                        "a sample pass to be added came as RGB8".into(),
                    ));
                }
                Made::Rgb8(image, _) => image,
            };
            let last = s + 1 == spp;
            totals.add(&f, last);
            let still_image = last.then(|| image.clone());
            // The statistics first: a client that got the finished frame reads them after it.
            publish(shared, image, &f, &wish, (s + 1, spp), true, &totals);
            if let Some(image) = still_image {
                shared.still.send_replace(Some(Arc::new(StillFrame {
                    seq: wish.seq,
                    image,
                })));
            }
            if shared.superseded(wish.seq) {
                finished = last;
                break;
            }
        }
        if finished {
            done = Some(wish.seq);
        }
    }
}

impl Totals {
    fn add(&mut self, s: &Figures, still: bool) {
        self.frames += 1;
        self.still_frames += u64::from(still);
        self.fault_rounds += s.fault_rounds;
        self.fetched_bytes += s.fetched_bytes;
        self.lookups += s.lookups;
        self.hits += s.hits;
    }
}

const MIB: f64 = 1024.0 * 1024.0;

/// Hands the frame to the encoder and updates the statistics.
fn publish(
    shared: &Shared,
    image: image::RgbImage,
    stats: &Figures,
    wish: &Wish,
    (samples, spp): (u32, u32),
    full: bool,
    totals: &Totals,
) {
    let ms = |s: f64| s * 1e3;
    let info = serde_json::json!({
        "seq": wish.seq,
        "width": image.width(),
        "height": image.height(),
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
        "hit_rate": stats.hit_rate(),
        "fetched_mib": stats.fetched_bytes as f64 / MIB,
        "ranks": stats.shares,
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
            "render_ranks": stats.shares.len(),
            "fault_rounds": totals.fault_rounds,
            "hit_rate": total_hit_rate,
            "fetched_mib": totals.fetched_bytes as f64 / MIB,
        });
    }
    shared.raw.put(RawFrame { image, info });
}
