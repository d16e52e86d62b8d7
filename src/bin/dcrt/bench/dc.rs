//! `dcrt bench --dc`: the distributed cache in one process against the replicated model, over an
//! orbit, for cache sizes and both mappings; and memory per rank against the rank count.

use super::frame_stats;
use crate::{BenchArgs, settings};
use anyhow::{Result, bail};
use dcrt::blocks::Format;
use dcrt::dc::{CacheMap, CacheSize};
use dcrt::gpu::Gpu;
use dcrt::render::frames::View;
use dcrt::render::{DcOptions, Prepared};
use dcrt::scene::{Camera, Model, Scene};

#[derive(serde::Serialize)]
struct DcRow {
    config: String,
    cache: Option<String>,
    cache_map: Option<CacheMap>,
    cache_lines: u32,
    /// Mean over the frames after the first (warm cache), and the first (cold).
    frame_ms: f64,
    first_frame_ms: f64,
    fetched_bytes_per_frame: f64,
    rounds_per_frame: f64,
    fault_rounds_per_frame: f64,
    misses_per_fault_round: f64,
    hit_rate: f64,
    nodes_per_block_entry: f64,
    resident_mib: f64,
    cache_mib: f64,
    /// Of the warm frames' time: GPU trace rounds (timestamps), submission and readback waits,
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
    model_mib: f64,
    rows: Vec<DcRow>,
    memory: Vec<MemoryRow>,
}

pub fn run(
    a: &BenchArgs,
    gpu: &Gpu,
    scene: &Scene,
    model: Model,
    camera: Camera,
    format: Format,
) -> Result<()> {
    if a.frames < 2 {
        bail!("--frames must be at least 2 for --dc (the first frame warms the cache)");
    }
    let prepared = Prepared::from_model(model, a.gpu.bvh_preset, format, 0.0)?;
    let blocks = &prepared.blocks;
    let mib = |b: u64| b as f64 / 1048576.0;
    let mut configs: Vec<Option<DcOptions>> = vec![None];
    for map in [CacheMap::Ize, CacheMap::Demarle] {
        for c in &a.caches {
            configs.push(Some(DcOptions {
                ranks: a.virtual_ranks,
                rank: a.rank,
                cache: CacheSize::parse(c)?,
                map,
            }));
        }
    }
    let mut rows = Vec::new();
    for (cfg, cache_name) in configs.iter().zip(
        std::iter::once(None).chain(
            [0, 1]
                .iter()
                .flat_map(|_| a.caches.iter().map(|c| Some(c.clone()))),
        ),
    ) {
        let mut tracer = match cfg {
            None => prepared.tracer(gpu, settings(&a.gpu))?,
            Some(o) => prepared.tracer_dc(gpu, settings(&a.gpu), o)?,
        };
        let size = (a.width, a.height);
        let all = frame_stats(
            &mut tracer,
            View::Orbit(camera),
            a.frames,
            size,
            scene.background,
        )?;
        let first_ms = all[0].seconds * 1e3;
        let warm = &all[1..];
        let n = warm.len() as f64;
        let sum = |f: &dyn Fn(&dcrt::gpu::tracer::FrameStats) -> f64| -> f64 {
            warm.iter().map(f).sum::<f64>()
        };
        let secs = sum(&|s| s.seconds);
        let (resident, cache, lines) = match cfg {
            None => (blocks.bytes(), 0, 0),
            Some(o) => {
                let m = o.memory(blocks.count(), blocks.format)?;
                (
                    m.resident_bytes,
                    m.cache_bytes,
                    o.cache.lines(blocks.count(), format.block_bytes),
                )
            }
        };
        let fault_rounds = sum(&|s| f64::from(s.fault_rounds));
        rows.push(DcRow {
            config: match cfg {
                None => "replicated".into(),
                Some(_) => "dc".into(),
            },
            cache: cache_name.clone(),
            cache_map: cfg.map(|o| o.map),
            cache_lines: lines,
            frame_ms: secs / n * 1e3,
            first_frame_ms: first_ms,
            fetched_bytes_per_frame: sum(&|s| s.fetched_bytes as f64) / n,
            rounds_per_frame: sum(&|s| f64::from(s.rounds)) / n,
            fault_rounds_per_frame: fault_rounds / n,
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
            nodes_per_block_entry: sum(&|s| s.node_visits as f64)
                / sum(&|s| s.block_entries as f64).max(1.0),
            resident_mib: mib(resident),
            cache_mib: mib(cache),
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
                    }
                    .memory(blocks.count(), blocks.format)
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
        width: a.width,
        height: a.height,
        ranks: a.virtual_ranks,
        rank: a.rank,
        frames: a.frames,
        model_mib: mib(blocks.bytes()),
        rows,
        memory,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!("adapter   {}", report.adapter);
    println!(
        "scene     {} ({} triangles, {:.1} MiB of blocks), {}x{}, rank {} of {} virtual ranks, \
         {} orbit frames (the first, cold, reported apart)",
        report.scene,
        report.triangles,
        report.model_mib,
        report.width,
        report.height,
        report.rank,
        report.ranks,
        report.frames
    );
    println!(
        "{:<10} {:<5} {:<8} {:>6} {:>9} {:>9} {:>10} {:>7} {:>7} {:>9} {:>6} {:>7} {:>8} {:>7} {:>6} {:>6} {:>6} {:>6}",
        "config",
        "cache",
        "map",
        "lines",
        "frame ms",
        "cold ms",
        "MiB/frame",
        "rounds",
        "faultR",
        "miss/rnd",
        "hit",
        "nod/blk",
        "res MiB",
        "$ MiB",
        "gpu%",
        "sync%",
        "fetch%",
        "upl%"
    );
    for r in &report.rows {
        println!(
            "{:<10} {:<5} {:<8} {:>6} {:>9.1} {:>9.1} {:>10.2} {:>7.1} {:>7.1} {:>9.0} {:>6.3} {:>7.2} {:>8.1} {:>7.1} {:>6.0} {:>6.0} {:>6.1} {:>6.1}",
            r.config,
            r.cache.as_deref().unwrap_or("-"),
            r.cache_map
                .map(|m| format!("{m:?}").to_lowercase())
                .unwrap_or_else(|| "-".into()),
            r.cache_lines,
            r.frame_ms,
            r.first_frame_ms,
            r.fetched_bytes_per_frame / 1048576.0,
            r.rounds_per_frame,
            r.fault_rounds_per_frame,
            r.misses_per_fault_round,
            r.hit_rate,
            r.nodes_per_block_entry,
            r.resident_mib,
            r.cache_mib,
            r.gpu_share * 100.0,
            r.sync_share * 100.0,
            r.fetch_share * 100.0,
            r.upload_share * 100.0
        );
    }
    println!("memory per rank against ranks (largest resident share + a 1/8 cache):");
    println!(
        "{:>6} {:>12} {:>10} {:>10}",
        "ranks", "resident", "cache", "total MiB"
    );
    for m in &report.memory {
        println!(
            "{:>6} {:>12.1} {:>10.1} {:>10.1}",
            m.ranks, m.resident_mib_max, m.cache_mib, m.total_mib
        );
    }
    Ok(())
}
