//! `dcrt bench dc`: the distributed cache in one process against the replicated model, over an
//! orbit, for cache sizes and both mappings; and memory per rank against the rank count.

use super::switches::TracerSwitches;
use super::{ReportArgs, SceneArgs, Table, block_count_frame, emit, frame_stats, median, settings};
use crate::GpuArgs;
use anyhow::{Result, bail};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::dc::{CacheMap, CacheSize, Replicate};
use dcrt::gpu::Gpu;
use dcrt::gpu::frame::FrameStats;
use dcrt::progress::Progress;
use dcrt::render::frames::View;
use dcrt::render::{DcOptions, Prepared, mib};
use dcrt::scene::{Camera, Model, Scene};

#[derive(Args)]
pub struct DcArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Frames of the orbit (the first warms the cache and is reported apart).
    #[arg(long, default_value_t = 4)]
    frames: u32,
    /// Degrees the camera turns about the focal point from one frame to the next (default: one
    /// turn over the frames, 360/frames). A user turning a view moves a few degrees a frame,
    /// and the cache lives on what consecutive frames share.
    #[arg(long)]
    step: Option<f64>,
    /// The in-process ranks the model is split over.
    #[arg(long, default_value_t = 8)]
    virtual_ranks: u32,
    /// The rank this process renders as.
    #[arg(long, default_value_t = 0)]
    rank: u32,
    /// Cache sizes: fractions of the model (1/8), lines (64lines) or bytes (256MiB).
    #[arg(long, value_delimiter = ',', default_value = "1/32,1/8,1/4,1/2,1/1")]
    caches: Vec<String>,
    /// Cache mappings.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "ize,demarle,lru"
    )]
    cache_maps: Vec<CacheMap>,
    /// What every rank replicates (`root,nodes` sweeps both).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "root")]
    replicate_blocks: Vec<Replicate>,
    /// Run the replicated configuration and then every cache configuration this many times in
    /// turn; frame times and ratios to replicated are medians over the repeats, each ratio
    /// against the replicated frame of its own repeat (the host's speed drifts).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    repeats: u32,
    #[command(flatten)]
    report: ReportArgs,
    #[command(flatten)]
    gpu: GpuArgs,
    #[command(flatten)]
    switches: TracerSwitches,
}

/// `bench dc`: the checks, the scene's model, the sweep.
pub fn bench(a: &DcArgs) -> Result<()> {
    let format = a.scene.check(&a.gpu)?;
    if let Some(s) = a.step
        && !(0.0..=360.0).contains(&s)
    {
        bail!("--step must be between 0 and 360 degrees, got {s}");
    }
    if a.frames < 2 {
        bail!("--frames must be at least 2 for bench dc (the first frame warms the cache)");
    }
    a.scene.refuse_block_file("dc")?;
    let (scene, model, camera) = a.scene.load()?;
    let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
    run(a, &gpu, &scene, model, camera, format)
}

#[derive(serde::Serialize)]
struct DcRow {
    config: String,
    cache: Option<String>,
    cache_map: Option<CacheMap>,
    /// What every rank holds besides its own blocks (`--replicate-blocks`).
    replicate: Option<Replicate>,
    cache_lines: u32,
    /// Mean over the frames after the first (warm cache), and the first (cold); with
    /// `--repeats`, medians over the repeats.
    frame_ms: f64,
    first_frame_ms: f64,
    /// The replicated model's warm frame rendered beside this configuration's (each of its
    /// frames just before the same frame here; median over the repeats).
    replicated_frame_ms: f64,
    /// The warm frame over the replicated frames rendered beside it (median over the repeats),
    /// and the least and largest such ratio.
    frame_over_replicated: f64,
    frame_over_replicated_min: f64,
    frame_over_replicated_max: f64,
    fetched_bytes_per_frame: f64,
    /// Distinct borrowed blocks the warm frames looked up, and blocks fetched per such block
    /// (above 1: blocks fetched more than once in a frame).
    distinct_blocks_per_frame: f64,
    fetches_per_distinct_block: f64,
    rounds_per_frame: f64,
    fault_rounds_per_frame: f64,
    /// The fewest fault rounds any schedule could take for each warm frame's blocks through
    /// this cache (`CachePolicy::fault_round_bound`), mean over the frames.
    fault_round_bound_per_frame: f64,
    misses_per_fault_round: f64,
    hit_rate: f64,
    nodes_per_block_entry: f64,
    /// Traversal loop iterations a ray (warm frames), and of the lanes' iterations the share that
    /// did work (block-counted frame): a suspended ray's resumptions and a fault round's sparse
    /// subgroups show here against the replicated row.
    steps_per_ray: f64,
    lane_use: f64,
    resident_mib: f64,
    cache_mib: f64,
    /// The batch buffers of the tracer's lanes after the last frame (`Tracer::batch_bytes`): the
    /// rays, stacks and pixels in flight, beside the blocks and the cache.
    lanes_mib: f64,
    /// Of the warm frames' time: GPU traversal rounds (timestamps), submission and readback waits,
    /// CPU fetch, upload, shading.
    gpu_share: f64,
    sync_share: f64,
    fetch_share: f64,
    upload_share: f64,
    shade_share: f64,
}

#[derive(serde::Serialize)]
struct MemoryRow {
    ranks: u32,
    resident_mib_max: f64,
    cache_mib: f64,
    total_mib: f64,
}

#[derive(serde::Serialize)]
struct DcReport {
    adapter: String,
    scene: String,
    triangles: usize,
    width: u32,
    height: u32,
    ranks: u32,
    rank: u32,
    frames: u32,
    /// Degrees the camera turned a frame.
    step: f64,
    repeats: u32,
    /// `--faults`: when rays went on past a fault.
    faults: dcrt::gpu::tracer::FaultMode,
    /// `--overlap-batches`: when a batch's last rounds shared rounds with the next batch.
    overlap_batches: dcrt::gpu::tracer::OverlapMode,
    fetch_ahead: bool,
    model_mib: f64,
    rows: Vec<DcRow>,
    memory: Vec<MemoryRow>,
}

fn run(
    a: &DcArgs,
    gpu: &Gpu,
    scene: &Scene,
    model: Model,
    camera: Camera,
    format: Format,
) -> Result<()> {
    let prepared = Prepared::from_model(model, a.gpu.build.tree()?, format, 0.0)?;
    let blocks = &prepared.blocks;
    let mut configs: Vec<(Option<DcOptions>, Option<String>)> = vec![(None, None)];
    for &replicate in &a.replicate_blocks {
        for &map in &a.cache_maps {
            for c in &a.caches {
                let o = DcOptions {
                    ranks: a.virtual_ranks,
                    rank: a.rank,
                    cache: CacheSize::parse(c)?,
                    map,
                    replicate,
                };
                configs.push((Some(o), Some(c.clone())));
            }
        }
    }
    // Per configuration (the replicated one first), the frames of each repeat; the block counts
    // of its first run (`block_count_frame`) and its lanes' bytes. Each configuration's frame
    // is rendered right after the replicated model's same frame (`paired`), so that a ratio
    // compares frames seconds apart: over a run, this host's speed drifts by more than most
    // changes (docs/notes). The replicated row holds every replicated orbit rendered.
    let size = (a.scene.width, a.scene.height);
    let mut runs: Vec<Vec<Vec<FrameStats>>> = vec![Vec::new(); configs.len()];
    let mut paired: Vec<Vec<Vec<FrameStats>>> = vec![Vec::new(); configs.len()];
    let mut counted = vec![FrameStats::default(); configs.len()];
    let mut lanes = vec![0; configs.len()];
    let total = configs.len().max(2) as u64 - 1;
    let bar = Progress {
        quiet: a.report.quiet,
    }
    .bar(total * u64::from(a.repeats), "cache configurations");
    let step = a.step.unwrap_or(360.0 / f64::from(a.frames));
    let render = |tracer: &mut dcrt::gpu::tracer::Tracer<'_>, f: u32| -> Result<FrameStats> {
        let at = View::Fixed(turned(camera, step, f));
        Ok(frame_stats(tracer, at, 1, size, scene.background)?.remove(0))
    };
    for repeat in 0..a.repeats {
        let mut replicated = prepared.tracer_with(gpu, settings(&a.gpu, &a.switches), None)?;
        if repeat == 0 {
            counted[0] = block_count_frame(&mut replicated, camera, size, scene.background)?;
        }
        if configs.len() == 1 {
            bar.inc(1);
            let frames = (0..a.frames).map(|f| render(&mut replicated, f));
            runs[0].push(frames.collect::<Result<Vec<_>>>()?);
        }
        for (i, (cfg, _)) in configs.iter().enumerate().skip(1) {
            bar.inc(1);
            let mut tracer =
                prepared.tracer_with(gpu, settings(&a.gpu, &a.switches), cfg.as_ref())?;
            let (mut with, mut own) = (Vec::new(), Vec::new());
            for f in 0..a.frames {
                with.push(render(&mut replicated, f)?);
                own.push(render(&mut tracer, f)?);
            }
            runs[0].push(with.clone());
            paired[i].push(with);
            runs[i].push(own);
            if repeat == 0 {
                counted[i] = block_count_frame(&mut tracer, camera, size, scene.background)?;
            }
            lanes[i] = tracer.batch_bytes();
        }
        lanes[0] = replicated.batch_bytes();
    }
    let warm_ms = |all: &[FrameStats]| {
        let warm = &all[1..];
        warm.iter().map(|s| s.seconds).sum::<f64>() / warm.len() as f64 * 1e3
    };
    let mut rows = Vec::new();
    for (i, (cfg, cache_name)) in configs.iter().enumerate() {
        let mut frame: Vec<f64> = runs[i].iter().map(|r| warm_ms(r)).collect();
        let mut cold: Vec<f64> = runs[i].iter().map(|r| r[0].seconds * 1e3).collect();
        // Over the replicated frames rendered beside them (the replicated row: 1).
        let beside = if i == 0 { &runs[0] } else { &paired[i] };
        let mut beside_ms: Vec<f64> = beside.iter().map(|r| warm_ms(r)).collect();
        let mut ratios: Vec<f64> = frame.iter().zip(&beside_ms).map(|(f, r)| f / r).collect();
        // The counts of every repeat's warm frames together (the same frames each time).
        let warm: Vec<FrameStats> = runs[i].iter().flat_map(|r| r[1..].to_vec()).collect();
        let n = warm.len() as f64;
        let sum = |f: &dyn Fn(&dcrt::gpu::frame::FrameStats) -> f64| -> f64 {
            warm.iter().map(f).sum::<f64>()
        };
        let secs = sum(&|s| s.seconds);
        let (resident, cache, lines) = match cfg {
            None => (blocks.bytes(), 0, 0),
            Some(o) => {
                let m = o.memory(blocks.count(), blocks.node_blocks, blocks.format)?;
                (
                    m.resident_bytes,
                    m.cache_bytes,
                    o.lines(blocks.count(), format),
                )
            }
        };
        let fault_rounds = sum(&|s| f64::from(s.fault_rounds));
        let counted = &counted[i];
        rows.push(DcRow {
            config: match cfg {
                None => "replicated".into(),
                Some(_) => "dc".into(),
            },
            cache: cache_name.clone(),
            cache_map: cfg.map(|o| o.map),
            replicate: cfg.map(|o| o.replicate),
            cache_lines: lines,
            frame_ms: median(&mut frame),
            replicated_frame_ms: median(&mut beside_ms),
            first_frame_ms: median(&mut cold),
            frame_over_replicated: median(&mut ratios),
            frame_over_replicated_min: ratios[0],
            frame_over_replicated_max: ratios[ratios.len() - 1],
            fetched_bytes_per_frame: sum(&|s| s.fetched_bytes as f64) / n,
            distinct_blocks_per_frame: sum(&|s| s.distinct_blocks as f64) / n,
            fetches_per_distinct_block: {
                let d = sum(&|s| s.distinct_blocks as f64);
                if d > 0.0 {
                    sum(&|s| s.fetched_blocks as f64) / d
                } else {
                    0.0
                }
            },
            rounds_per_frame: sum(&|s| f64::from(s.rounds)) / n,
            fault_rounds_per_frame: fault_rounds / n,
            fault_round_bound_per_frame: sum(&|s| f64::from(s.fault_round_bound)) / n,
            misses_per_fault_round: if fault_rounds > 0.0 {
                sum(&|s| s.misses as f64) / fault_rounds
            } else {
                0.0
            },
            hit_rate: {
                let l = sum(&|s| s.lookups as f64);
                if l > 0.0 {
                    sum(&|s| s.hits as f64) / l
                } else {
                    1.0
                }
            },
            nodes_per_block_entry: counted.node_visits as f64 / counted.block_entries.max(1) as f64,
            steps_per_ray: sum(&|s| s.steps as f64) / sum(&|s| s.rays as f64).max(1.0),
            lane_use: counted.steps as f64 / counted.lane_steps.max(1) as f64,
            resident_mib: mib(resident),
            cache_mib: mib(cache),
            lanes_mib: mib(lanes[i]),
            gpu_share: sum(&|s| s.gpu_seconds) / secs,
            sync_share: sum(&|s| {
                s.trace_seconds - s.gpu_seconds - s.fetch_seconds - s.upload_seconds
            }) / secs,
            fetch_share: sum(&|s| s.fetch_seconds) / secs,
            upload_share: sum(&|s| s.upload_seconds) / secs,
            shade_share: sum(&|s| s.shade_seconds) / secs,
        });
    }
    let cache_for_memory = CacheSize::parse("1/8")?;
    let memory = [1u32, 2, 4, 8, 16, 32, 64]
        .iter()
        .map(|&n| {
            let resident = (0..n)
                .map(|r| {
                    DcOptions {
                        ranks: n,
                        rank: r,
                        cache: cache_for_memory,
                        map: CacheMap::Ize,
                        replicate: a.replicate_blocks.first().copied().unwrap_or_default(),
                    }
                    .memory(blocks.count(), blocks.node_blocks, blocks.format)
                    .map(|m| m.resident_bytes)
                })
                .collect::<dcrt::Result<Vec<u64>>>()
                .map(|v| v.into_iter().max().unwrap_or(0));
            resident.map(|res| {
                let cache = if n == 1 {
                    0
                } else {
                    u64::from(cache_for_memory.lines(blocks.count(), format.block_bytes))
                        * u64::from(format.block_bytes)
                };
                MemoryRow {
                    ranks: n,
                    resident_mib_max: mib(res),
                    cache_mib: mib(cache),
                    total_mib: mib(res + cache),
                }
            })
        })
        .collect::<dcrt::Result<Vec<_>>>()?;
    let report = DcReport {
        adapter: gpu.describe(),
        scene: scene.path.display().to_string(),
        triangles: prepared.model.triangles.len(),
        width: a.scene.width,
        height: a.scene.height,
        ranks: a.virtual_ranks,
        rank: a.rank,
        frames: a.frames,
        step,
        repeats: a.repeats,
        faults: a.switches.faults,
        overlap_batches: a.switches.overlap_batches,
        fetch_ahead: !a.switches.no_fetch_ahead,
        model_mib: mib(blocks.bytes()),
        rows,
        memory,
    };
    emit(a.report.json, &report, print)
}

/// Frame `f`'s camera: `camera` turned `step` degrees a frame about its focal point.
fn turned(camera: Camera, step: f64, f: u32) -> Camera {
    camera.orbit((step * f64::from(f)).to_radians())
}

fn print(report: &DcReport) {
    println!("adapter   {}", report.adapter);
    println!(
        "scene     {} ({} triangles, {:.1} MiB of blocks), {}x{}, rank {} of {} virtual ranks, \
         {} orbit frames {}° apart (the first, cold, reported apart), {} repeat(s), --faults {:?}, \
         --overlap-batches {:?}, fetch ahead {}",
        report.scene,
        report.triangles,
        report.model_mib,
        report.width,
        report.height,
        report.rank,
        report.ranks,
        report.frames,
        report.step,
        report.repeats,
        report.faults,
        report.overlap_batches,
        if report.fetch_ahead { "on" } else { "off" }
    );
    let t = Table(&[
        ("config", -10),
        ("cache", -5),
        ("map", -8),
        ("repl", -5),
        ("lines", 6),
        ("frame ms", 9),
        ("cold ms", 9),
        ("x repl", 15),
        ("MiB/frame", 10),
        ("distinct", 9),
        ("fetch/d", 7),
        ("rounds", 7),
        ("faultR", 7),
        ("bound", 6),
        ("miss/rnd", 9),
        ("hit", 6),
        ("nod/blk", 7),
        ("steps/r", 7),
        ("lanes", 5),
        ("res MiB", 8),
        ("$ MiB", 7),
        ("lanes MiB", 9),
        ("gpu%", 6),
        ("sync%", 6),
        ("fetch%", 6),
        ("upl%", 6),
    ]);
    t.header();
    for r in &report.rows {
        t.row(&[
            r.config.clone(),
            r.cache.clone().unwrap_or_else(|| "-".into()),
            r.cache_map
                .map(|m| format!("{m:?}").to_lowercase())
                .unwrap_or_else(|| "-".into()),
            r.replicate
                .map(|m| format!("{m:?}").to_lowercase())
                .unwrap_or_else(|| "-".into()),
            r.cache_lines.to_string(),
            format!("{:.1}", r.frame_ms),
            format!("{:.1}", r.first_frame_ms),
            if report.repeats > 1 {
                format!(
                    "{:.3} {:.2}-{:.2}",
                    r.frame_over_replicated,
                    r.frame_over_replicated_min,
                    r.frame_over_replicated_max
                )
            } else {
                format!("{:.3}", r.frame_over_replicated)
            },
            format!("{:.2}", r.fetched_bytes_per_frame / 1048576.0),
            format!("{:.0}", r.distinct_blocks_per_frame),
            format!("{:.2}", r.fetches_per_distinct_block),
            format!("{:.1}", r.rounds_per_frame),
            format!("{:.1}", r.fault_rounds_per_frame),
            format!("{:.1}", r.fault_round_bound_per_frame),
            format!("{:.0}", r.misses_per_fault_round),
            format!("{:.3}", r.hit_rate),
            format!("{:.2}", r.nodes_per_block_entry),
            format!("{:.1}", r.steps_per_ray),
            format!("{:.2}", r.lane_use),
            format!("{:.1}", r.resident_mib),
            format!("{:.1}", r.cache_mib),
            format!("{:.1}", r.lanes_mib),
            format!("{:.0}", r.gpu_share * 100.0),
            format!("{:.0}", r.sync_share * 100.0),
            format!("{:.1}", r.fetch_share * 100.0),
            format!("{:.1}", r.upload_share * 100.0),
        ]);
    }
    println!("memory per rank against ranks (largest resident share + a 1/8 cache):");
    let t = Table(&[
        ("ranks", 6),
        ("resident", 12),
        ("cache", 10),
        ("total MiB", 10),
    ]);
    t.header();
    for m in &report.memory {
        t.row(&[
            m.ranks.to_string(),
            format!("{:.1}", m.resident_mib_max),
            format!("{:.1}", m.cache_mib),
            format!("{:.1}", m.total_mib),
        ]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_turn_by_the_step_and_by_default_once_round_the_orbit() {
        let camera = Camera {
            position: [3.0, 0.0, 0.0],
            focal_point: [0.0, 0.0, 0.0],
            view_up: [0.0, 0.0, 1.0],
            view_angle: 30.0,
            parallel_scale: None,
        };
        // The default step is the orbit's: frame f of n at 360 f / n degrees.
        for f in 0..4 {
            let orbit = View::Orbit(camera).camera(f, 4);
            let by_step = turned(camera, 90.0, f);
            for (a, b) in orbit.position.iter().zip(by_step.position) {
                assert!(
                    (a - b).abs() < 1e-12,
                    "frame {f}: {orbit:?} against {by_step:?}"
                );
            }
        }
        // Three degrees a frame: frame 30 is a quarter turn, at (0, 3, 0).
        let p = turned(camera, 3.0, 30).position;
        assert!(
            p[0].abs() < 1e-9 && (p[1] - 3.0).abs() < 1e-9 && p[2] == 0.0,
            "{p:?}"
        );
        assert_eq!(turned(camera, 0.0, 7).position, camera.position);
    }
}
