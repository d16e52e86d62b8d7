//! `dcrt bench figures DIR`: the chapter's Figures 6-8 redone (docs/ARCHITECTURE.md, Traces).
//! Traced mpirun jobs at the given rank counts, replicated and with each cache, for the rm and
//! the occluded assembly model; `simulate` replays each configuration's traces of the
//! largest rank count at 2..60 nodes of one render rank each on the chapter's network (its
//! bandwidth, and the median fetch time of a fault round here as each round's latency); memory
//! per node from the ownership and cache sizes the ranks allocate; the display benchmark per
//! copy-thread count. Writes `figure6.png`, `figure7.png`, `figure8.png` and `figures.json`
//! (every point drawn, with its source: `run`, `simulated`, `model` or `chapter`).

use super::jobs::{JOB, Plan, Transport, mpirun, run as run_job};
use super::{DisplayArgs, MODELS, check_model, format_of};
use crate::BuildArgs;
use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::blocks::ranks::Ranks;
use dcrt::chart::{self, Area, Entry, Mark, Swatch};
use dcrt::cluster::Roles;
use dcrt::dc::CacheSize;
use dcrt::progress::{Progress, say};
use dcrt::render::{Prepared, mib};
use dcrt::scene::Scene;
use dcrt::simulate::{ClusterModel, Sharing, simulate};
use dcrt::traces::read::Traces;
use plotters::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The chapter's interconnect: 4x DDR InfiniBand, 1868 MB/s measured by `ib_read_bw`.
const CHAPTER_BANDWIDTH: f64 = 1868e6;
/// Nodes of the simulated points (one runs the display and the balancer, as in the chapter).
const NODES: [u32; 6] = [2, 4, 8, 16, 32, 60];
/// Bytes a pixel of ours takes to the display (RGB8; the chapter's also carry a 4-byte place).
const PIXEL_BYTES: f64 = 3.0;
/// The tiles of the runs and of their replays: small images need small tiles to share out.
const TILE: u32 = 32;
const MIN_TILE: u32 = 8;

/// Where the chapter gives numbers (its section 5 text and captions of Figures 4-8): frame rates
/// at 60 nodes (RM and the Boeing 777, the occluded model our assembly stands in for; its DC
/// figures are for 1/8 of the data per node), memory per node, and the display's frame rate
/// by copy threads (55 fps with one, up to 1.6x with two, 2.3x with three, no more after).
const CHAPTER_FPS: [(&str, &str, u32, f64); 4] = [
    ("rm", "replicated", 60, 101.0),
    ("rm", "1/8", 60, 16.0),
    ("assembly", "replicated", 60, 96.0),
    ("assembly", "1/8", 60, 77.0),
];
/// RM: 21,326 MB replicated (all of it on one render node), 2,666 MB per node with the DC.
const CHAPTER_MEMORY: [(&str, u32, f64); 3] = [
    ("replicated", 2, 21326.0),
    ("replicated", 60, 21326.0),
    ("1/8", 60, 2666.0),
];
const CHAPTER_RM_MB: f64 = 21326.0;
const CHAPTER_DISPLAY: [(u32, f64); 7] = [
    (1, 55.0),
    (2, 88.0),
    (3, 127.0),
    (4, 127.0),
    (5, 127.0),
    (6, 127.0),
    (7, 127.0),
];

#[derive(Serialize)]
struct RatePoint {
    model: String,
    cache: String,
    source: &'static str,
    nodes: u32,
    /// MPI ranks (`mpirun -n`); 0 for the chapter's.
    ranks: u32,
    fps: f64,
    /// For a run: `dcrt simulate`'s prediction of its own frame rate (of the median run).
    #[serde(skip_serializing_if = "Option::is_none")]
    predicted_fps: Option<f64>,
    /// For a run: the frame rate of each of the `--runs` jobs, ascending; `fps` is the median.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    runs: Vec<f64>,
}

#[derive(Serialize)]
struct MemoryPoint {
    cache: String,
    source: &'static str,
    nodes: u32,
    mib: f64,
    /// Of the replicated model.
    fraction: f64,
}

#[derive(Serialize)]
struct DisplayPoint {
    copy_threads: u32,
    source: &'static str,
    fps: f64,
    /// The link's limit: the job's measured MPI bandwidth (runs), the chapter's (chapter).
    #[serde(skip_serializing_if = "Option::is_none")]
    ceiling_fps: Option<f64>,
}

#[derive(Serialize)]
struct Figures {
    width: u32,
    height: u32,
    triangles: u64,
    frames: u32,
    ranks: Vec<u32>,
    caches: Vec<String>,
    network_mb_s: f64,
    model_mib: Vec<(String, f64)>,
    figure6: Vec<RatePoint>,
    figure7: Vec<MemoryPoint>,
    figure8: Vec<DisplayPoint>,
}

/// Small images and models: every point is an mpirun job, each configuration `--runs` times.
#[derive(Args)]
pub struct FiguresArgs {
    /// The directory the figures and the runs' traces go into.
    out: PathBuf,
    #[arg(long, default_value_t = 128)]
    width: u32,
    #[arg(long, default_value_t = 96)]
    height: u32,
    /// Triangles of each generated model (rm and assembly).
    #[arg(long, default_value_t = 50_000)]
    triangles: u64,
    /// Frames of each traced job (the first is not timed).
    #[arg(long, default_value_t = 4)]
    frames: u32,
    /// MPI rank counts of the traced jobs, at least 3 each (a display, a balancer, render ranks).
    #[arg(long, value_delimiter = ',', default_value = "3,4,5")]
    ranks: Vec<u32>,
    /// Cache sizes of the traced jobs, beside the replicated model.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "1/32,1/16,1/8,1/4,1/2,1/1"
    )]
    caches: Vec<String>,
    /// Jobs of each configuration; the median frame rate is drawn.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    #[command(flatten)]
    display: DisplayArgs,
    /// No progress bar (it is drawn on stderr when it is a terminal).
    #[arg(long, short)]
    quiet: bool,
    #[command(flatten)]
    build: BuildArgs,
}

pub fn bench(a: &FiguresArgs) -> Result<()> {
    let out = a.out.as_path();
    let (width, height, triangles) = (a.width, a.height, a.triangles);
    check_model(width, height, triangles, None)?;
    let (display_frames, display_ranks) = (a.display.display_frames, a.display.display_ranks);
    let copy_threads = &a.display.copy_threads.0;
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    if a.frames < 2 || display_frames < 4 {
        bail!("--frames must be at least 2 and --display-frames at least 4: frame 0 is not timed");
    }
    if a.ranks.is_empty() || a.ranks.iter().any(|&k| k < 3) || display_ranks < 2 {
        bail!(
            "bench figures: --ranks counts MPI ranks, at least 3 each (a display, a balancer, render ranks); --display-ranks at least 2"
        );
    }
    let mut caches = vec!["replicated".to_string()];
    for c in &a.caches {
        CacheSize::parse(c).with_context(|| format!("--caches: {c}"))?;
        caches.push(c.clone());
    }
    let format = format_of(&a.build)?;
    // Every figure needs a font: say so before the hours of runs, not after.
    chart::font()?;
    let runs = out.join("runs");
    std::fs::create_dir_all(&runs).with_context(|| format!("{}: cannot create", runs.display()))?;
    let exe = std::env::current_exe().context("the path of this dcrt")?;
    let max_k = a.ranks.iter().copied().max().unwrap_or(3);
    let mut figs = Figures {
        width,
        height,
        triangles,
        frames: a.frames,
        ranks: a.ranks.clone(),
        caches: caches.clone(),
        network_mb_s: CHAPTER_BANDWIDTH / 1e6,
        model_mib: Vec::new(),
        figure6: Vec::new(),
        figure7: Vec::new(),
        figure8: Vec::new(),
    };
    let mut display_model = None;
    let jobs = MODELS.len() * caches.len() * a.ranks.len() * a.runs;
    let bar = Progress { quiet: a.quiet }.bar(jobs as u64, "traced jobs");
    for g in MODELS {
        let name = g.name().to_string();
        let scene = Scene::generated(g, triangles, width, height);
        let p = Prepared::new(&scene, a.build.tree()?, format)?;
        let camera = scene.camera_or_default(&p.model);
        let dcb = runs.join(format!("{name}.dcb"));
        dcrt::blocks::file::write(&dcb, &p.blocks, &p.meta(&scene, camera, width, height))?;
        let blocks = p.blocks.count();
        figs.model_mib.push((name.clone(), mib(p.blocks.bytes())));
        say(
            &bar,
            format!(
                "{name}: {} triangles, {:.1} MiB of blocks",
                p.model.triangles.len(),
                mib(p.blocks.bytes())
            ),
        );
        let mut traced = Vec::new();
        for cache in &caches {
            let mut largest = None;
            for &k in &a.ranks {
                // `--runs` jobs of each; the run of the median frame rate stands for them.
                let mut done = Vec::new();
                for run in 0..a.runs {
                    let tag = format!("{name}-k{k}-{}-r{run}", cache.replace('/', "of"));
                    let traces = runs.join(&tag);
                    let _ = std::fs::remove_dir_all(&traces);
                    let png = runs.join(format!("{tag}.png"));
                    job(&exe, k, &dcb, cache, &traces, &png, a)?;
                    bar.inc(1);
                    let t = Traces::read(&traces)?;
                    let own = simulate(&t, &model(k, None, None, 0.0))?;
                    let measured = own.measured_mean_frame_ms.ok_or_else(|| {
                        anyhow!("{tag}: the display's traces have no frame times")
                    })?;
                    done.push((1000.0 / measured, 1000.0 / own.mean_frame_ms, t));
                }
                done.sort_by(|x, y| x.0.total_cmp(&y.0));
                let all: Vec<f64> = done.iter().map(|d| d.0).collect();
                let (fps, predicted, t) = done.swap_remove(done.len() / 2);
                let render = Roles::new(k)?.render_ranks();
                figs.figure6.push(RatePoint {
                    model: name.clone(),
                    cache: cache.clone(),
                    source: "run",
                    nodes: render + 1,
                    ranks: k,
                    fps,
                    predicted_fps: Some(predicted),
                    runs: all,
                });
                if name == "rm" {
                    let lines = t
                        .get(t.frames()[0], Roles::new(k)?.render_rank(0))
                        .map_or(0, |f| f.frame.cache_lines);
                    let rows = if cache == "replicated" {
                        blocks
                    } else {
                        Ranks::new(render, 0)?.resident_rows(blocks) + lines
                    };
                    figs.figure7
                        .push(memory_point(cache, "run", render + 1, rows, blocks, format));
                }
                if k == max_k {
                    largest = Some((k, t));
                }
            }
            if let Some(l) = largest {
                traced.push((cache.clone(), l));
            }
        }
        // A replicated run never faults, so it has no rounds to fit core sharing on: it takes
        // the fit of the cached runs' at the same ranks with the median stretch to one rank.
        let fits: Vec<Sharing> = {
            let mut v: Vec<(f64, Sharing)> = traced
                .iter()
                .filter_map(|(_, (k, t))| {
                    let render = Roles::new(*k).ok()?.render_ranks();
                    Sharing::fit(t, render).map(|s| (s.stretch(1), s))
                })
                .collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            v.into_iter().map(|x| x.1).collect()
        };
        let borrowed = fits.get(fits.len() / 2).copied();
        for (cache, (k, t)) in &traced {
            let (cache, k) = (cache.clone(), *k);
            for nodes in NODES {
                let ranks = nodes + 1;
                let mut m = model(ranks, Some(CHAPTER_BANDWIDTH), Some(1), 0.0);
                m.latency = round_latency(t);
                m.sharing = borrowed;
                let p = simulate(t, &m)?;
                // The display cannot take pixels faster than the network brings them.
                let ceiling = CHAPTER_BANDWIDTH / (PIXEL_BYTES * f64::from(width * height));
                figs.figure6.push(RatePoint {
                    model: name.clone(),
                    cache: cache.clone(),
                    source: "simulated",
                    nodes,
                    ranks,
                    fps: (1000.0 / p.mean_frame_ms).min(ceiling),
                    predicted_fps: None,
                    runs: Vec::new(),
                });
            }
            dcrt::report!(
                "{name} {cache}: runs at {:?} ranks, simulated from {k}",
                a.ranks
            );
        }
        if name == "rm" {
            for cache in &caches {
                for nodes in 2..=60u32 {
                    let render = nodes - 1;
                    // A single render rank owns every block and runs without a cache.
                    let rows = match CacheSize::parse(cache) {
                        Ok(c) if cache != "replicated" && render > 1 => {
                            Ranks::new(render, 0)?.resident_rows(blocks)
                                + c.lines(blocks, format.block_bytes)
                        }
                        _ => blocks,
                    };
                    figs.figure7
                        .push(memory_point(cache, "model", nodes, rows, blocks, format));
                }
            }
        }
        display_model.get_or_insert(dcb);
    }
    for &(model, cache, nodes, fps) in &CHAPTER_FPS {
        figs.figure6.push(RatePoint {
            model: model.into(),
            cache: cache.into(),
            source: "chapter",
            nodes,
            ranks: 0,
            fps,
            predicted_fps: None,
            runs: Vec::new(),
        });
    }
    for &(cache, nodes, mb) in &CHAPTER_MEMORY {
        figs.figure7.push(MemoryPoint {
            cache: cache.into(),
            source: "chapter",
            nodes,
            mib: mb * 1e6 / (1024.0 * 1024.0),
            fraction: mb / CHAPTER_RM_MB,
        });
    }
    if let Some(dcb) = display_model
        && !copy_threads.is_empty()
    {
        let plan = Plan {
            exe: exe.clone(),
            dir: runs.clone(),
            models: Vec::new(),
            ranks: Vec::new(),
            caches: Vec::new(),
            transports: vec![Transport::Shm],
            frames: display_frames,
            width: 1920,
            height: 1080,
            copy_threads: copy_threads.clone(),
            display_ranks,
            timeout_seconds: 600,
        };
        for d in plan.display(&dcb)? {
            let num = |k: &str| {
                d[k].as_f64()
                    .ok_or_else(|| anyhow!("the display benchmark's {k} is missing: {d}"))
            };
            figs.figure8.push(DisplayPoint {
                copy_threads: num("copy_threads")? as u32,
                source: "run",
                fps: num("fps")?,
                ceiling_fps: Some(num("ceiling_fps")?),
            });
        }
    }
    for &(threads, fps) in &CHAPTER_DISPLAY {
        figs.figure8.push(DisplayPoint {
            copy_threads: threads,
            source: "chapter",
            fps,
            ceiling_fps: Some(127.0),
        });
    }
    let json = out.join("figures.json");
    dcrt::files::write_bytes(&json, serde_json::to_string_pretty(&figs)?.as_bytes())?;
    draw_rates(&figs, &out.join("figure6.png"))?;
    draw_memory(&figs, &out.join("figure7.png"))?;
    draw_display(&figs, &out.join("figure8.png"))?;
    println!(
        "wrote {}, figure6.png, figure7.png, figure8.png in {}",
        json.display(),
        out.display()
    );
    Ok(())
}

fn model(ranks: u32, bandwidth: Option<f64>, per_node: Option<u32>, w: f64) -> ClusterModel {
    ClusterModel {
        ranks,
        bandwidth,
        latency: None,
        tile: TILE,
        min_tile: MIN_TILE,
        ranks_per_node: per_node,
        work_exponent: w,
        sharing: None,
    }
}

/// The median fetch time of the traced fault rounds that fetched, in seconds: MPI's cost per
/// round as measured here, which a faster wire does not remove (`None` without such rounds).
fn round_latency(t: &Traces) -> Option<f64> {
    let mut us: Vec<f64> = t
        .files
        .iter()
        .flat_map(|f| &f.rounds)
        .filter(|r| r.fetched_blocks > 0)
        .map(|r| r.fetch_us)
        .collect();
    (!us.is_empty()).then(|| super::median(&mut us) * 1e-6)
}

fn memory_point(
    cache: &str,
    source: &'static str,
    nodes: u32,
    rows: u32,
    blocks: u32,
    format: Format,
) -> MemoryPoint {
    let bytes = u64::from(rows) * u64::from(format.block_bytes);
    MemoryPoint {
        cache: cache.into(),
        source,
        nodes,
        mib: mib(bytes),
        fraction: f64::from(rows) / f64::from(blocks.max(1)),
    }
}

/// One traced mpirun job of `k` ranks on shared memory.
fn job(
    exe: &Path,
    k: u32,
    dcb: &Path,
    cache: &str,
    traces: &Path,
    png: &Path,
    a: &FiguresArgs,
) -> Result<()> {
    let mut cmd = mpirun(exe, k, Transport::Shm);
    cmd.args(JOB)
        .arg(dcb)
        .arg("-o")
        .arg(png)
        .arg("--trace")
        .arg(traces)
        .args(["--frames", &a.frames.to_string()])
        .args([
            "--tile",
            &TILE.to_string(),
            "--min-tile",
            &MIN_TILE.to_string(),
        ])
        .args(["--timeout", "600"]);
    if cache != "replicated" {
        cmd.args(["--cache", cache]);
    }
    run_job(
        &mut cmd,
        &format!("mpirun -n {k} ({}, {cache})", dcb.display()),
    )
}

/// The caches of the runs in order, then those only the chapter's points have.
fn drawn_caches<'a>(f: &Figures, all: impl Iterator<Item = &'a String>) -> Vec<String> {
    let mut out = f.caches.clone();
    for c in all {
        if !out.contains(c) {
            out.push(c.clone());
        }
    }
    out
}

const W: u32 = 1400;
const H: u32 = 640;
/// The footnote's band at the bottom.
const FOOT: u32 = 34;

type Chart<'a, 'b> = chart::LogY<'a, 'b, plotters::coord::types::RangedCoordf64>;

/// One series in colour `c`: a line through `line`, dots at `runs` and triangles at `chapter`.
fn draw_series(
    chart: &mut Chart,
    c: RGBColor,
    line: Vec<(f64, f64)>,
    runs: Vec<(f64, f64)>,
    chapter: Vec<(f64, f64)>,
) -> dcrt::Result<()> {
    chart
        .draw_series(LineSeries::new(line, c.stroke_width(2)))
        .map_err(chart::fail)?;
    chart
        .draw_series(
            runs.into_iter()
                .map(|p| chart::marker(Mark::Circle, p, 9, c, true)),
        )
        .map_err(chart::fail)?;
    chart
        .draw_series(
            chapter
                .into_iter()
                .map(|p| chart::marker(Mark::Triangle, p, 12, c, true)),
        )
        .map_err(chart::fail)?;
    Ok(())
}

/// The legend of a figure: a colour per series, then what lines, dots and triangles are.
fn keys(series: &[String], line: &str) -> Vec<Entry> {
    let grey = RGBColor(90, 90, 90);
    let mut out: Vec<Entry> = series
        .iter()
        .enumerate()
        .map(|(i, s)| Entry::new(s.clone(), chart::colour(i), Swatch::Box))
        .collect();
    out.push(Entry::new(line, grey, Swatch::Line(None)));
    out.push(Entry::new(
        "run here",
        grey,
        Swatch::Mark(Mark::Circle, true),
    ));
    out.push(Entry::new(
        "the chapter",
        grey,
        Swatch::Mark(Mark::Triangle, true),
    ));
    out
}

/// The figure's footnote, in the band below its panels.
fn footnote(root: &Area, text: &str) -> dcrt::Result<()> {
    root.draw(&Text::new(
        text.to_string(),
        (12, H as i32 - FOOT as i32 + 8),
        chart::text(chart::TICK),
    ))
    .map_err(chart::fail)
}

/// Figure 6: frame rate against nodes, one panel per model, a colour per cache; lines through
/// the simulated points, dots for runs here, triangles for the chapter's.
fn draw_rates(f: &Figures, path: &Path) -> Result<()> {
    chart::save(path, chart::Format::Png, (W, H), |root| {
        let (charts, _) = root.split_vertically(H - FOOT);
        let panels = charts.split_evenly((1, 2));
        let caches = drawn_caches(f, f.figure6.iter().map(|p| &p.cache));
        for (panel, g) in panels.iter().zip(MODELS) {
            let name = g.name();
            let pts: Vec<&RatePoint> = f.figure6.iter().filter(|p| p.model == name).collect();
            let title = format!(
                "Figure 6, {name}{}: frames/s against nodes ({}x{})",
                if name == "assembly" {
                    " (chapter: Boeing)"
                } else {
                    ""
                },
                f.width,
                f.height
            );
            let area = chart::titled_with_legend(panel, &title, &keys(&caches, "simulated"))?;
            let range = chart::log_range(pts.iter().map(|p| p.fps));
            let axes = ("nodes (one for display + balancer)", "frames per second");
            let mut c = chart::log_y(&area, 0.0..62.0, range, axes)?;
            for (i, cache) in caches.iter().enumerate() {
                let of = |source: &str| -> Vec<(f64, f64)> {
                    pts.iter()
                        .filter(|p| p.cache == *cache && p.source == source)
                        .map(|p| (f64::from(p.nodes), p.fps))
                        .collect()
                };
                let (line, runs, chapter) = (of("simulated"), of("run"), of("chapter"));
                draw_series(&mut c, chart::colour(i), line, runs, chapter)?;
            }
        }
        let note = format!(
            "lines: simulated on {:.0} MB/s + a fault round's median fetch here, a render rank per node; dots: runs here (median of --runs); triangles: the chapter (1920x1080)",
            f.network_mb_s
        );
        footnote(root, &note)
    })?;
    Ok(())
}

/// Figure 7: memory per node of rm against nodes, as a share of the replicated model.
fn draw_memory(f: &Figures, path: &Path) -> Result<()> {
    chart::save(path, chart::Format::Png, (W / 2 + 140, H), |root| {
        let rm_mib = f
            .model_mib
            .iter()
            .find(|m| m.0 == "rm")
            .map_or(0.0, |m| m.1);
        let (area, _) = root.split_vertically(H - FOOT);
        let caches = drawn_caches(f, f.figure7.iter().map(|p| &p.cache));
        let title = format!("Figure 7, rm: memory per node ({rm_mib:.1} MiB model = 1)");
        let area = chart::titled_with_legend(&area, &title, &keys(&caches, "model"))?;
        let range = chart::log_range(f.figure7.iter().map(|p| p.fraction));
        let axes = ("nodes", "blocks + cache per node / model");
        let mut c = chart::log_y(&area, 0.0..62.0, range, axes)?;
        for (i, cache) in caches.iter().enumerate() {
            let of = |source: &str| -> Vec<(f64, f64)> {
                f.figure7
                    .iter()
                    .filter(|p| p.cache == *cache && p.source == source)
                    .map(|p| (f64::from(p.nodes), p.fraction))
                    .collect()
            };
            let (line, runs, chapter) = (of("model"), of("run"), of("chapter"));
            draw_series(&mut c, chart::colour(i), line, runs, chapter)?;
        }
        footnote(
            root,
            "lines: owned blocks + root + cache lines; dots: runs here; triangles: the chapter (RM, 21,326 MB)",
        )
    })?;
    Ok(())
}

/// Figure 8: the display's frame rate (1920x1080) against copy threads.
fn draw_display(f: &Figures, path: &Path) -> Result<()> {
    chart::save(path, chart::Format::Png, (W / 2 + 140, H), |root| {
        let range = chart::log_range(
            f.figure8
                .iter()
                .flat_map(|p| [Some(p.fps), p.ceiling_fps])
                .flatten(),
        );
        let (area, _) = root.split_vertically(H - FOOT);
        let title = "Figure 8: display frames/s (1920x1080) against copy threads";
        let series = [("run", "runs here"), ("chapter", "the chapter")];
        let mut entries: Vec<Entry> = series
            .iter()
            .enumerate()
            .map(|(i, s)| Entry::new(s.1, chart::colour(i), Swatch::Line(Some(Mark::Circle))))
            .collect();
        entries.push(Entry::new(
            "the link's limit",
            RGBColor(90, 90, 90),
            Swatch::Mark(Mark::Cross, false),
        ));
        let area = chart::titled_with_legend(&area, title, &entries)?;
        let axes = ("copy threads", "frames per second");
        let mut c = chart::log_y(&area, 0.5..7.5, range, axes)?;
        for (i, (source, _)) in series.into_iter().enumerate() {
            let colour = chart::colour(i);
            let pts: Vec<&DisplayPoint> = f.figure8.iter().filter(|p| p.source == source).collect();
            let fps: Vec<(f64, f64)> = pts
                .iter()
                .map(|p| (f64::from(p.copy_threads), p.fps))
                .collect();
            draw_series(&mut c, colour, fps.clone(), fps, Vec::new())?;
            c.draw_series(pts.iter().filter_map(|p| {
                p.ceiling_fps.map(|y| {
                    chart::marker(
                        Mark::Cross,
                        (f64::from(p.copy_threads), y),
                        10,
                        colour,
                        false,
                    )
                })
            }))
            .map_err(chart::fail)?;
        }
        footnote(
            root,
            "crosses: the link's limit (runs: the job's MPI bandwidth / 3 B a pixel; chapter: 127 fps)",
        )
    })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Figures 6-8 of made-up points draw in `chart`'s look (their numbers come from runs).
    #[test]
    fn figures_draw_from_points() {
        let dir = std::env::temp_dir().join(format!("dcrt-figures-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let rate =
            |model: &str, cache: &str, source: &'static str, nodes: u32, fps: f64| RatePoint {
                model: model.into(),
                cache: cache.into(),
                source,
                nodes,
                ranks: nodes + 1,
                fps,
                predicted_fps: None,
                runs: Vec::new(),
            };
        let mut figs = Figures {
            width: 128,
            height: 96,
            triangles: 50_000,
            frames: 4,
            ranks: vec![4, 5],
            caches: vec!["replicated".into(), "1/8".into()],
            network_mb_s: 1868.0,
            model_mib: vec![("rm".into(), 2.3)],
            figure6: Vec::new(),
            figure7: Vec::new(),
            figure8: Vec::new(),
        };
        for model in ["rm", "assembly"] {
            for (c, cache) in ["replicated", "1/8"].into_iter().enumerate() {
                for n in NODES {
                    let fps = 200.0 / (1.0 + c as f64) * f64::from(n).sqrt();
                    figs.figure6.push(rate(model, cache, "simulated", n, fps));
                }
                figs.figure6
                    .push(rate(model, cache, "run", 4, 90.0 / (1.0 + c as f64)));
            }
            figs.figure6.push(rate(model, "1/8", "chapter", 60, 16.0));
        }
        for n in 2..=60 {
            figs.figure7.push(MemoryPoint {
                cache: "1/8".into(),
                source: "model",
                nodes: n,
                mib: 2.3 / f64::from(n),
                fraction: 1.0 / f64::from(n) + 0.125,
            });
        }
        for t in 1..=4 {
            figs.figure8.push(DisplayPoint {
                copy_threads: t,
                source: "run",
                fps: 40.0 * f64::from(t),
                ceiling_fps: Some(150.0),
            });
        }
        draw_rates(&figs, &dir.join("figure6.png")).unwrap();
        draw_memory(&figs, &dir.join("figure7.png")).unwrap();
        draw_display(&figs, &dir.join("figure8.png")).unwrap();
        for f in ["figure6.png", "figure7.png", "figure8.png"] {
            let img = image::open(dir.join(f)).unwrap();
            assert!(img.width() >= 600 && img.height() >= 600, "{f}");
        }
        if std::env::var_os("DCRT_KEEP_FIGURES").is_none() {
            std::fs::remove_dir_all(&dir).unwrap();
        }
    }
}

#[cfg(test)]
mod defaults {
    use super::*;
    use clap::Parser;

    fn parsed(args: &[&str]) -> FiguresArgs {
        let all = [&["dcrt", "bench", "figures", "DIR"][..], args].concat();
        match crate::Cli::try_parse_from(all).unwrap().command {
            crate::Command::Bench(crate::bench::Bench::Figures(a)) => a,
            _ => unreachable!("bench figures parses as itself"),
        }
    }

    /// The figures' small jobs are the options' own defaults, and a value given is taken as it
    /// is (the old bench rewrote 1024 and 1000000 into them).
    #[test]
    fn small_jobs_are_defaults_and_given_sizes_are_kept() {
        let a = parsed(&[]);
        assert_eq!((a.width, a.height, a.triangles), (128, 96, 50_000));
        assert_eq!(a.ranks, [3, 4, 5]);
        let a = parsed(&[
            "--width",
            "1024",
            "--height",
            "1024",
            "--triangles",
            "1000000",
        ]);
        assert_eq!((a.width, a.height, a.triangles), (1024, 1024, 1_000_000));
    }
}
