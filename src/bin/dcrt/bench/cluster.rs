//! `dcrt bench cluster`: the driver of the mpirun jobs of `jobs`.

use super::jobs::{Plan, Transport, table};
use super::{DisplayArgs, MODELS, check_model, emit, format_of};
use crate::BuildArgs;
use anyhow::{Context, Result, bail};
use clap::Args;
use dcrt::dc::CacheSize;
use dcrt::gpu::tracer::OverlapMode;
use dcrt::render::{Prepared, mib};
use dcrt::scene::Scene;
use std::path::PathBuf;

#[derive(Args)]
pub struct ClusterArgs {
    /// Scene file; without it, the generated rm and occluded assembly models (--triangles).
    scene: Option<PathBuf>,
    /// Triangles of each generated model.
    #[arg(long, default_value_t = 1_000_000)]
    triangles: u64,
    #[arg(long, default_value_t = 1024)]
    width: u32,
    #[arg(long, default_value_t = 1024)]
    height: u32,
    /// Frames of each job (the first is not timed).
    #[arg(long, default_value_t = 4)]
    frames: u32,
    /// MPI rank counts of the jobs.
    #[arg(long, value_delimiter = ',', default_value = "2,3,4,5,6")]
    ranks: Vec<u32>,
    /// `none` replicates; a cache size, with `:MAP` for another mapping than `ize` (`1/8:lru`),
    /// `:OVERLAP` for another `--overlap-batches` than `auto` (`1/8:lru:never`) and `:REPLICATE`
    /// for another `--replicate-blocks` than `root` (`1/8:lru:auto:nodes`).
    #[arg(long, value_delimiter = ',', default_value = "none,1/8")]
    caches: Vec<String>,
    /// Open MPI transports the cached jobs at the largest rank count run over.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "shm,tcp-pt2pt,ucx"
    )]
    transports: Vec<Transport>,
    #[command(flatten)]
    display: DisplayArgs,
    /// Only the display benchmark.
    #[arg(long)]
    display_only: bool,
    /// One JSON object on stdout instead of the tables.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    build: BuildArgs,
}

/// `bench cluster`: prepares the models once, then runs the jobs of `jobs`.
pub fn bench(a: &ClusterArgs) -> Result<()> {
    check_model(a.width, a.height, a.triangles, None)?;
    let format = format_of(&a.build)?;
    let (display_frames, display_ranks) = (a.display.display_frames, a.display.display_ranks);
    let copy_threads = &a.display.copy_threads.0;
    if a.frames < 2 || display_frames < 4 {
        bail!("--frames must be at least 2 and --display-frames at least 4: frame 0 is not timed");
    }
    if a.ranks.iter().any(|&k| k < 2) || display_ranks < 2 {
        bail!("--ranks and --display-ranks count MPI ranks: at least 2");
    }
    let caches = a
        .caches
        .iter()
        .map(|c| match c.as_str() {
            "none" => Ok(None),
            other => {
                let mut parts = other.split(':');
                let size = parts.next().unwrap_or(other);
                CacheSize::parse(size)?;
                if let Some(map) = parts.next() {
                    <dcrt::dc::CacheMap as clap::ValueEnum>::from_str(map, true).map_err(|_| {
                        anyhow::anyhow!("--caches {other}: no cache mapping {map:?}")
                    })?;
                }
                if let Some(o) = parts.next() {
                    <OverlapMode as clap::ValueEnum>::from_str(o, true)
                        .map_err(|_| anyhow::anyhow!("--caches {other}: no overlap mode {o:?}"))?;
                }
                if let Some(r) = parts.next() {
                    <dcrt::dc::Replicate as clap::ValueEnum>::from_str(r, true).map_err(|_| {
                        anyhow::anyhow!("--caches {other}: no replicated blocks {r:?}")
                    })?;
                }
                if parts.next().is_some() {
                    bail!("--caches {other}: SIZE[:MAP[:OVERLAP[:REPLICATE]]]");
                }
                Ok(Some(other.to_string()))
            }
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let work =
        WorkDir(std::env::temp_dir().join(format!("dcrt-bench-cluster-{}", std::process::id())));
    let dir = &work.0;
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let scenes: Vec<(String, Scene)> = match &a.scene {
        Some(p) => vec![(
            p.file_stem()
                .map_or("scene".into(), |s| s.to_string_lossy().into_owned()),
            Scene::load(p)?,
        )],
        None => MODELS
            .into_iter()
            .map(|g| {
                let scene = Scene::generated(g, a.triangles, a.width, a.height);
                (g.name().to_string(), scene)
            })
            .collect(),
    };
    let mut models = Vec::new();
    for (name, scene) in &scenes {
        let p = Prepared::new(scene, a.build.tree()?, format)?;
        let camera = scene.camera_or_default(&p.model);
        let path = dir.join(format!("{name}.dcb"));
        dcrt::blocks::file::write(&path, &p.blocks, &p.meta(scene, camera, a.width, a.height))?;
        dcrt::report!(
            "{name}: {} triangles, {:.1} MiB of blocks",
            p.model.triangles.len(),
            mib(p.blocks.bytes())
        );
        models.push((name.clone(), path));
    }
    let plan = Plan {
        exe: std::env::current_exe().context("the path of this dcrt")?,
        dir: dir.clone(),
        models: models.clone(),
        ranks: a.ranks.clone(),
        caches,
        transports: a.transports.clone(),
        frames: a.frames,
        width: a.width,
        height: a.height,
        copy_threads: copy_threads.clone(),
        display_ranks,
        timeout_seconds: 600,
    };
    let rows = if a.display_only {
        Vec::new()
    } else {
        plan.frame_times()?
    };
    let display_plan = Plan {
        frames: display_frames,
        width: 1920,
        height: 1080,
        ..plan
    };
    let display = match models.first() {
        Some((_, m)) if !copy_threads.is_empty() => display_plan.display(m)?,
        _ => Vec::new(),
    };
    drop(work);
    let all = serde_json::json!({"frame_times": rows, "display": display});
    emit(a.json, &all, |_| {
        print!("{}", table(&rows));
        println!(
            "\ndisplay benchmark ({} ranks, 1920x1080, {} frames):",
            display_ranks, display_frames
        );
        println!(
            "{:>12} {:>8} {:>14} {:>14} {:>12} {:>8}",
            "copy threads", "fps", "Mpixels/s", "MPI MB/s", "ceiling fps", "ratio"
        );
        for d in &display {
            println!(
                "{:>12} {:>8.1} {:>14.1} {:>14.1} {:>12.1} {:>8.3}",
                d["copy_threads"],
                d["fps"].as_f64().unwrap_or(f64::NAN),
                d["pixels_per_s"].as_f64().unwrap_or(f64::NAN) / 1e6,
                d["mpi_bytes_per_s"].as_f64().unwrap_or(f64::NAN) / 1e6,
                d["ceiling_fps"].as_f64().unwrap_or(f64::NAN),
                d["ratio"].as_f64().unwrap_or(f64::NAN)
            );
        }
    })
}

/// The bench's working directory (block files, stats, images), removed however the bench ends.
struct WorkDir(std::path::PathBuf);

impl Drop for WorkDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
