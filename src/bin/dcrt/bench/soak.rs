//! `dcrt bench soak --frames FRAMES`: one process renders a long orbit, as a real-time session
//! would (each frame converted to 8-bit sRGB and dropped), and reports resident memory at
//! intervals and its slope in bytes per frame. A leak of a few KiB a frame shows over thousands of frames.

use super::switches::TracerSwitches;
use super::{ReportArgs, SceneArgs, Table, emit, settings};
use crate::GpuArgs;
use anyhow::{Context, Result, bail};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::dc::{CacheMap, CacheSize, Replicate};
use dcrt::gpu::Gpu;
use dcrt::progress::Progress;
use dcrt::render::frames::{FramePlan, Role, View, run_images};
use dcrt::render::memory::resident;
use dcrt::render::{DcOptions, Prepared, mib};
use dcrt::scene::{Camera, Model, Scene};
use std::time::Instant;

#[derive(Args)]
pub struct SoakArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Frames of the orbit, at least 20.
    #[arg(long)]
    frames: u32,
    /// The in-process ranks the model is split over.
    #[arg(long, default_value_t = 8)]
    virtual_ranks: u32,
    /// The rank this process renders as.
    #[arg(long, default_value_t = 0)]
    rank: u32,
    /// Cache size (a fraction of the model, lines or bytes; the `ize` mapping), or `none` to
    /// replicate the model.
    #[arg(long, default_value = "1/32")]
    cache: String,
    /// What every rank replicates besides its own blocks.
    #[arg(long, value_enum, default_value_t = Replicate::Root)]
    replicate_blocks: Replicate,
    #[command(flatten)]
    report: ReportArgs,
    #[command(flatten)]
    gpu: GpuArgs,
    #[command(flatten)]
    switches: TracerSwitches,
}

/// `bench soak`: the checks, the scene's model, the orbit.
pub fn bench(a: &SoakArgs) -> Result<()> {
    let format = a.scene.check(&a.gpu)?;
    if a.frames < 20 {
        bail!(
            "--frames must be at least 20 for bench soak, got {}",
            a.frames
        );
    }
    a.scene.refuse_block_file("soak")?;
    let (scene, model, camera) = a.scene.load()?;
    let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
    run(a, &gpu, &scene, model, camera, format)
}

#[derive(serde::Serialize)]
struct Sample {
    frame: u32,
    seconds: f64,
    rss_bytes: u64,
}

#[derive(serde::Serialize)]
struct SoakReport {
    adapter: String,
    scene: String,
    triangles: usize,
    width: u32,
    height: u32,
    frames: u32,
    /// `None` when replicated.
    cache: Option<String>,
    ranks: u32,
    rank: u32,
    samples: Vec<Sample>,
    /// Least-squares slope of RSS over the samples after the first tenth of the run (warm-up:
    /// the cache fills, the allocator settles).
    bytes_per_frame: f64,
    rss_start_mib: f64,
    rss_end_mib: f64,
    rss_peak_mib: f64,
    frames_per_second: f64,
    /// Live GPU objects (wgpu's counters) after the first tenth of the run and at its end:
    /// equal unless the session leaks GPU objects.
    gpu_objects_warm: dcrt::gpu::Live,
    gpu_objects_end: dcrt::gpu::Live,
}

/// Least-squares slope of y over x.
fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    if points.len() < 2 {
        return 0.0;
    }
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), &(x, y)| (a + x / n, b + y / n));
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), &(x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    if sxx > 0.0 { sxy / sxx } else { 0.0 }
}

fn run(
    a: &SoakArgs,
    gpu: &Gpu,
    scene: &Scene,
    model: Model,
    camera: Camera,
    format: Format,
) -> Result<()> {
    let frames = a.frames;
    let triangles = model.triangles.len();
    let prepared = Prepared::from_model(model, a.gpu.build.tree()?, format, 0.0)?;
    // `--cache none` replicates; else as rank --rank of --virtual-ranks.
    let cache = Some(&a.cache).filter(|c| c.as_str() != "none");
    let dc = match cache {
        Some(c) => Some(DcOptions {
            ranks: a.virtual_ranks,
            rank: a.rank,
            cache: CacheSize::parse(c)?,
            map: CacheMap::Ize,
            replicate: a.replicate_blocks,
        }),
        None => None,
    };
    let mut tracer = prepared.tracer_with(gpu, settings(&a.gpu, &a.switches), dc.as_ref())?;
    let every = (frames / 50).max(1);
    let start = Instant::now();
    let mut samples = Vec::with_capacity(52);
    let sample = |frame: u32| -> dcrt::Result<Sample> {
        let (rss, _) = resident()
            .ok_or_else(|| dcrt::Error::Internal("cannot read /proc/self/status".into()))?;
        Ok(Sample {
            frame,
            seconds: start.elapsed().as_secs_f64(),
            rss_bytes: rss,
        })
    };
    let plan = FramePlan {
        frames,
        view: View::Orbit(camera),
        role: Role::one_process(&tracer),
        trace_dir: None,
    };
    let mut live_warm = gpu.live();
    let bar = Progress {
        quiet: a.report.quiet,
    }
    .bar(u64::from(frames), "soak frames");
    let table = Table(&[("frame", 7), ("seconds", 9), ("RSS MiB", 9)]);
    if !a.report.json {
        table.header();
    }
    run_images(
        &mut tracer,
        &plan,
        a.scene.width,
        a.scene.height,
        scene.background,
        &mut |i, frame, _| {
            std::hint::black_box(dcrt::output::to_rgb8(frame));
            bar.inc(1);
            if i == frames / 10 {
                live_warm = gpu.live();
            }
            if i % every == 0 || i + 1 == frames {
                let s = sample(i)?;
                if !a.report.json {
                    bar.suspend(|| {
                        table.row(&[
                            s.frame.to_string(),
                            format!("{:.1}", s.seconds),
                            format!("{:.1}", mib(s.rss_bytes)),
                        ])
                    });
                }
                samples.push(s);
            }
            Ok(())
        },
    )?;
    let seconds = start.elapsed().as_secs_f64();
    let (_, peak) = resident().context("cannot read /proc/self/status")?;
    let warm: Vec<(f64, f64)> = samples
        .iter()
        .filter(|s| s.frame >= frames / 10)
        .map(|s| (f64::from(s.frame), s.rss_bytes as f64))
        .collect();
    let report = SoakReport {
        adapter: gpu.describe(),
        scene: scene.path.display().to_string(),
        triangles,
        width: a.scene.width,
        height: a.scene.height,
        frames,
        cache: cache.cloned(),
        ranks: a.virtual_ranks,
        rank: a.rank,
        bytes_per_frame: slope(&warm),
        rss_start_mib: mib(samples[0].rss_bytes),
        rss_end_mib: mib(samples.last().expect("sampled").rss_bytes),
        rss_peak_mib: mib(peak),
        frames_per_second: f64::from(frames) / seconds,
        gpu_objects_warm: live_warm,
        gpu_objects_end: gpu.live(),
        samples,
    };
    emit(a.report.json, &report, |r| {
        println!(
            "{} frames at {:.1} frames/s: RSS {:.1} MiB at frame 0, {:.1} MiB at the end (peak \
             {:.1}); slope after frame {}: {:.0} bytes per frame; GPU objects {}",
            r.frames,
            r.frames_per_second,
            r.rss_start_mib,
            r.rss_end_mib,
            r.rss_peak_mib,
            r.frames / 10,
            r.bytes_per_frame,
            if r.gpu_objects_warm == r.gpu_objects_end {
                format!("flat ({:?})", r.gpu_objects_end)
            } else {
                format!("{:?} -> {:?}", r.gpu_objects_warm, r.gpu_objects_end)
            }
        );
    })
}

#[cfg(test)]
mod tests {
    use super::slope;

    #[test]
    fn slope_of_a_line_and_of_noise_around_it() {
        let line: Vec<(f64, f64)> = (0..10).map(|x| (x as f64, 3.0 * x as f64 + 7.0)).collect();
        assert!((slope(&line) - 3.0).abs() < 1e-9);
        let flat: Vec<(f64, f64)> = (0..10).map(|x| (x as f64, (x % 2) as f64)).collect();
        assert!(slope(&flat).abs() < 0.2);
        assert_eq!(slope(&[(1.0, 2.0)]), 0.0);
    }
}
