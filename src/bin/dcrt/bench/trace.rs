//! `dcrt bench`: BVH build time and primary-ray throughput, per obvhs preset and block store.

use super::{Table, emit, frame_stats, median};
use crate::{BenchArgs, settings};
use anyhow::Result;
use dcrt::blocks::Format;
use dcrt::bvh::Preset;
use dcrt::gpu::Gpu;
use dcrt::gpu::shaders::Store;
use dcrt::gpu::tracer::Settings;
use dcrt::render::Prepared;
use dcrt::render::frames::View;
use dcrt::scene::{Camera, Model, Scene};

#[derive(serde::Serialize)]
struct BenchRow {
    preset: String,
    store: Store,
    bvh_build_ms: f64,
    bvh_depth: u32,
    trace_ms_median: f64,
    trace_ms_min: f64,
    trace_ms_max: f64,
    mrays_per_s: f64,
    steps_per_ray: f64,
    tri_tests_per_ray: f64,
    /// Of the last run: share of the frame in raygen + trace rounds, and in shade + readback.
    trace_share: f64,
    shade_share: f64,
}

#[derive(serde::Serialize)]
struct BenchReport {
    adapter: String,
    scene: String,
    triangles: usize,
    width: u32,
    height: u32,
    runs: usize,
    bvh_preset: String,
    bvh_build_ms: f64,
    trace_ms_median: f64,
    mrays_per_s: f64,
    rows: Vec<BenchRow>,
}

pub fn run(
    a: &BenchArgs,
    gpu: &Gpu,
    scene: &Scene,
    model: Model,
    camera: Camera,
    format: Format,
) -> Result<()> {
    let presets: Vec<Preset> = if a.bvh_presets {
        vec![
            Preset::Fastest,
            Preset::VeryFast,
            Preset::Fast,
            Preset::Medium,
        ]
    } else {
        vec![a.gpu.bvh_preset]
    };
    let mut rows = Vec::new();
    let rays = f64::from(a.width) * f64::from(a.height);
    let stores = if a.stores {
        Store::ALL.to_vec()
    } else {
        vec![a.gpu.store]
    };
    for preset in presets {
        let prepared = Prepared::from_model(model.clone(), preset, format, 0.0)?;
        for &store in &stores {
            let s = Settings {
                store,
                ..settings(&a.gpu)
            };
            let mut tracer = prepared.tracer(gpu, s)?;
            // A warm-up frame (pipeline compilation and first-touch of buffers), then the runs.
            let frames = u32::try_from(a.runs).map_or(u32::MAX, |r| r.saturating_add(1));
            let size = (a.width, a.height);
            let runs = frame_stats(
                &mut tracer,
                View::Fixed(camera),
                frames,
                size,
                scene.background,
            )?;
            let mut times: Vec<f64> = runs[1..].iter().map(|s| s.seconds * 1e3).collect();
            let s = runs.last().cloned().unwrap_or_default();
            let med = median(&mut times);
            rows.push(BenchRow {
                preset: format!("{preset:?}").to_lowercase(),
                store,
                bvh_build_ms: prepared.bvh.build_time.as_secs_f64() * 1e3,
                bvh_depth: prepared.bvh.depth,
                trace_ms_median: med,
                trace_ms_min: times[0],
                trace_ms_max: times[times.len() - 1],
                mrays_per_s: rays / (med * 1e-3) / 1e6,
                steps_per_ray: s.steps as f64 / rays,
                tri_tests_per_ray: s.tri_tests as f64 / rays,
                trace_share: s.trace_seconds / s.seconds,
                shade_share: s.shade_seconds / s.seconds,
            });
        }
    }
    let main_row = rows
        .iter()
        .find(|r| {
            r.preset == format!("{:?}", a.gpu.bvh_preset).to_lowercase() && r.store == a.gpu.store
        })
        .unwrap_or(&rows[0]);
    let report = BenchReport {
        adapter: gpu.describe(),
        scene: scene.path.display().to_string(),
        triangles: model.triangles.len(),
        width: a.width,
        height: a.height,
        runs: a.runs,
        bvh_preset: main_row.preset.clone(),
        bvh_build_ms: main_row.bvh_build_ms,
        trace_ms_median: main_row.trace_ms_median,
        mrays_per_s: main_row.mrays_per_s,
        rows: Vec::new(),
    };
    let report = BenchReport { rows, ..report };
    emit(a.json, &report, print)
}

fn print(report: &BenchReport) {
    println!("adapter   {}", report.adapter);
    println!(
        "scene     {} ({} triangles), {}x{}, median of {} runs after a warm-up",
        report.scene, report.triangles, report.width, report.height, report.runs
    );
    let t = Table(&[
        ("preset", -9),
        ("store", -8),
        ("build ms", 10),
        ("depth", 6),
        ("trace ms", 12),
        ("min", 10),
        ("max", 10),
        ("Mrays/s", 9),
        ("steps/ray", 9),
        ("trace%", 7),
        ("shade%", 7),
    ]);
    t.header();
    for r in &report.rows {
        t.row(&[
            r.preset.clone(),
            format!("{:?}", r.store).to_lowercase(),
            format!("{:.1}", r.bvh_build_ms),
            r.bvh_depth.to_string(),
            format!("{:.1}", r.trace_ms_median),
            format!("{:.1}", r.trace_ms_min),
            format!("{:.1}", r.trace_ms_max),
            format!("{:.2}", r.mrays_per_s),
            format!("{:.1}", r.steps_per_ray),
            format!("{:.0}", r.trace_share * 100.0),
            format!("{:.0}", r.shade_share * 100.0),
        ]);
    }
}
