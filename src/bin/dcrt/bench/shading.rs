//! `dcrt bench shading`: time against error for AO and path tracing on the rm and assembly
//! generators with both samplers, the time each takes to reach given errors, and the cost and
//! error of the accuracy knobs; with `--peer mitsuba`, Mitsuba 3 on the same path-traced scenes
//! against the same references. A table, `--json`, and a PNG plot.

mod mitsuba;

use super::{MODELS, Table, check_model, emit};
use anyhow::{Context, Result, bail};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::bvh::Build;
use dcrt::gpu::Gpu;
use dcrt::gpu::frame::{Frame, FrameStats};
use dcrt::gpu::tracer::Settings;
use dcrt::render::Prepared;
use dcrt::scene::Scene;
use dcrt::shading::{Mode, Offset, Sampler, Shading};
use std::path::{Path, PathBuf};

#[derive(serde::Serialize, Clone)]
pub struct Point {
    scene: String,
    mode: String,
    sampler: String,
    spp: u32,
    ms: f64,
    rmse: f64,
    rel_mse: f64,
}

/// How long a sampler takes to reach an RMSE: interpolated log-log between the two curve points
/// around it (`None`: not reached by the largest spp).
#[derive(serde::Serialize)]
pub struct TimeTo {
    scene: String,
    mode: String,
    sampler: String,
    rmse: f64,
    spp: Option<f64>,
    ms: Option<f64>,
}

/// A reference: the mean of two renders with the independent sampler and other seeds; `noise`
/// estimates its own RMSE from their difference.
#[derive(serde::Serialize)]
pub struct RefInfo {
    scene: String,
    mode: String,
    spp: u32,
    noise: f64,
}

/// One peer run (per scene): what the script reports about itself.
#[derive(serde::Serialize)]
pub struct PeerRun {
    scene: String,
    #[serde(flatten)]
    output: mitsuba::Output,
}

/// A converged peer render against dcrt's reference: image means, their relative difference,
/// and the per-pixel RMSE between the two.
#[derive(serde::Serialize)]
pub struct Agreement {
    scene: String,
    mode: String,
    peer_spp: u32,
    reference_spp: u32,
    dcrt_mean: f64,
    peer_mean: f64,
    mean_rel_diff: f64,
    rmse: f64,
}

/// At one spp: each dcrt sampler's RMSE and time beside the peer's.
#[derive(serde::Serialize)]
pub struct Versus {
    scene: String,
    mode: String,
    spp: u32,
    sobol_rmse: f64,
    independent_rmse: f64,
    peer_rmse: f64,
    sobol_ms: f64,
    independent_ms: f64,
    peer_ms: f64,
}

/// Time-to-error ratio at an RMSE level: dcrt's Sobol' time over the peer's.
#[derive(serde::Serialize)]
pub struct TimeRatio {
    scene: String,
    mode: String,
    rmse: f64,
    sobol_ms: Option<f64>,
    peer_ms: Option<f64>,
    ratio: Option<f64>,
}

#[derive(serde::Serialize)]
pub struct Knob {
    scene: String,
    mode: String,
    knob: String,
    ms: f64,
    steps: u64,
    traced_rays: u64,
    rmse: f64,
    /// Whether the image is bit-identical to the default setting's.
    same_image: bool,
}

#[derive(serde::Serialize)]
pub struct Report {
    adapter: String,
    width: u32,
    height: u32,
    triangles: u64,
    ao_rays: u32,
    max_depth: u32,
    references: Vec<RefInfo>,
    curve: Vec<Point>,
    time_to: Vec<TimeTo>,
    knobs: Vec<Knob>,
    peer: Vec<PeerRun>,
    agreement: Vec<Agreement>,
    versus: Vec<Versus>,
    time_ratio: Vec<TimeRatio>,
}

/// The RMSE levels of the time-to-error table.
const LEVELS: [f64; 4] = [0.04, 0.02, 0.01, 0.005];

fn time_to(points: &[&Point], level: f64) -> (Option<f64>, Option<f64>) {
    let lg = |v: f64| v.max(1e-12).ln();
    for w in points.windows(2) {
        let (a, b) = (w[0], w[1]);
        if a.rmse <= level {
            return (Some(f64::from(a.spp)), Some(a.ms));
        }
        if b.rmse <= level {
            let t = (lg(a.rmse) - lg(level)) / (lg(a.rmse) - lg(b.rmse));
            let at = |x: f64, y: f64| (lg(x) + t * (lg(y) - lg(x))).exp();
            return (
                Some(at(f64::from(a.spp), f64::from(b.spp))),
                Some(at(a.ms, b.ms)),
            );
        }
    }
    match points {
        [p] if p.rmse <= level => (Some(f64::from(p.spp)), Some(p.ms)),
        _ => (None, None),
    }
}

/// RMSE and relative MSE of an image against a reference (linear RGB per pixel).
fn error(f: &Frame, r: &[[f64; 3]]) -> (f64, f64) {
    let img: Vec<[f32; 3]> = f.pixels.iter().map(|p| p.rgb).collect();
    error_rgb(&img, r)
}

fn error_rgb(img: &[[f32; 3]], r: &[[f64; 3]]) -> (f64, f64) {
    let (mut se, mut rel) = (0.0, 0.0);
    let n = (3 * img.len()) as f64;
    for (p, q) in img.iter().zip(r) {
        for (c, r) in p.iter().zip(q) {
            let d = f64::from(*c) - r;
            se += d * d;
            rel += d * d / (r.powi(2) + 1e-2);
        }
    }
    ((se / n).sqrt(), rel / n)
}

fn rgb(f: &Frame) -> Vec<[f64; 3]> {
    f.pixels.iter().map(|p| p.rgb.map(f64::from)).collect()
}

fn bits(f: &Frame) -> Vec<u8> {
    bytemuck::cast_slice(&f.pixels).to_vec()
}

/// Small images and models: every curve point is a render, and the references thousands of
/// samples.
#[derive(Args)]
pub struct ShadingArgs {
    #[arg(long, default_value_t = 32)]
    width: u32,
    #[arg(long, default_value_t = 32)]
    height: u32,
    /// Triangles of each generated model.
    #[arg(long, default_value_t = 50_000)]
    triangles: u64,
    /// The largest spp of the curves (powers of two from 1).
    #[arg(long, default_value_t = 1024)]
    max_spp: u32,
    /// Samples per pixel of the path references (AO: a quarter), two renders with the
    /// independent sampler and other seeds; a multiple of 8.
    #[arg(long, default_value_t = 4096)]
    reference_spp: u32,
    /// Also draw the curves into this PNG.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// A peer renderer run beside dcrt in the same run: `mitsuba` renders the path-traced
    /// scenes against the same references (scripts/mitsuba-peer.sh, which installs Mitsuba 3
    /// into its own venv on first use).
    #[arg(long, value_enum)]
    peer: Option<Peer>,
    /// One JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Use the first adapter whose name contains this text (default: the best GPU, else lavapipe).
    #[arg(long)]
    adapter: Option<String>,
}

/// A peer renderer run beside dcrt in the same bench run, on the same cores.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Peer {
    /// Mitsuba 3 (`llvm_ad_rgb`, `path`, independent sampler) on the same path-traced scenes,
    /// through `scripts/mitsuba-peer.sh`: time against error.
    Mitsuba,
}

/// `bench shading`: the checks, then the curves.
pub fn bench(a: &ShadingArgs) -> Result<()> {
    check_model(a.width, a.height, a.triangles, None)?;
    if a.max_spp == 0 {
        bail!("--max-spp must be at least 1");
    }
    // Two halves of the path reference, and of AO's quarter, need whole samples.
    if a.reference_spp < 8 || !a.reference_spp.is_multiple_of(8) {
        bail!(
            "--reference-spp must be a multiple of 8 (two renders of half each; AO's are a quarter), got {}",
            a.reference_spp
        );
    }
    let gpu = Gpu::new(a.adapter.as_deref())?;
    run(&gpu, a)
}

fn run(gpu: &Gpu, a: &ShadingArgs) -> Result<()> {
    // A plot that cannot be drawn is refused before the renders, not after.
    if let Some(p) = a.plot.as_deref() {
        dcrt::chart::Format::of(p, None)?;
        dcrt::chart::font()?;
    }
    let (w, h) = (a.width, a.height);
    // AO with few rays per hit, so that spp, not rays, carry the convergence.
    let (ao_rays, max_depth) = (4u32, 3u32);
    let mut curve = Vec::new();
    let mut knobs = Vec::new();
    let mut references = Vec::new();
    let (mut peer, mut agreement) = (Vec::new(), Vec::new());
    for g in MODELS {
        let scene = Scene::generated(g, a.triangles, w, h);
        let model = scene.load_model()?;
        let camera = scene.camera_or_default(&model);
        let basis = camera.basis(w, h);
        let p = Prepared::from_model(model, Build::default(), Format::default(), 0.0)?;
        for mode in [Mode::Ao, Mode::Path] {
            let base = Shading {
                mode,
                ao_rays,
                ao_distance: 0.25 * p.model.bounds.diagonal() as f32,
                max_depth,
                sky: [1.0; 3],
                sun: [0.0; 3],
                ..Shading::default()
            };
            let mut t = p.tracer(
                gpu,
                Settings {
                    shading: base,
                    ..Settings::default()
                },
            )?;
            let go = |t: &mut dcrt::gpu::tracer::Tracer<'_>, sh: Shading| {
                t.set_shading(sh)?;
                t.render(&basis, scene.background)
            };
            // Warm-up, then a converged reference from the independent sampler with other
            // seeds: unbiased per pixel, and unrelated to either sampler's curve.
            go(&mut t, Shading { spp: 1, ..base })?;
            let ref_spp = match mode {
                Mode::Ao => a.reference_spp / 4,
                _ => a.reference_spp,
            };
            let mut half = Shading {
                spp: ref_spp / 2,
                seed: 1000,
                sampler: Sampler::Independent,
                ..base
            };
            let ra = rgb(&go(&mut t, half)?.0);
            half.seed = 1001;
            let rb = rgb(&go(&mut t, half)?.0);
            let reference: Vec<[f64; 3]> = ra
                .iter()
                .zip(&rb)
                .map(|(x, y)| std::array::from_fn(|c| 0.5 * (x[c] + y[c])))
                .collect();
            let name = g.name().to_string();
            let diff: f64 = ra
                .iter()
                .zip(&rb)
                .flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).powi(2)))
                .sum::<f64>()
                / (3 * ra.len()) as f64;
            references.push(RefInfo {
                scene: name.clone(),
                mode: mode.name().into(),
                spp: ref_spp,
                // Var(mean of two) = Var(a - b) / 4.
                noise: (diff / 4.0).sqrt(),
            });
            for sampler in [Sampler::Sobol, Sampler::Independent] {
                let mut spp = 1;
                while spp <= a.max_spp {
                    let (f, s) = go(
                        &mut t,
                        Shading {
                            spp,
                            sampler,
                            ..base
                        },
                    )?;
                    let (rmse, rel_mse) = error(&f, &reference);
                    curve.push(Point {
                        scene: name.clone(),
                        mode: mode.name().into(),
                        sampler: sampler.name().into(),
                        spp,
                        ms: s.seconds * 1e3,
                        rmse,
                        rel_mse,
                    });
                    spp *= 2;
                }
            }
            if let (Some(Peer::Mitsuba), Mode::Path) = (a.peer, mode) {
                let (run, converged) =
                    mitsuba_curve(&p.model, &basis, &base, a.max_spp, ref_spp, &reference)?;
                for (spp, ms, (rmse, rel_mse)) in run.1 {
                    curve.push(Point {
                        scene: name.clone(),
                        mode: mode.name().into(),
                        sampler: PEER.into(),
                        spp,
                        ms,
                        rmse,
                        rel_mse,
                    });
                }
                let mean = |v: &mut dyn Iterator<Item = f64>| {
                    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
                    s / n.max(1) as f64
                };
                let dcrt_mean = mean(&mut reference.iter().flatten().copied());
                let peer_mean = mean(&mut converged.iter().flatten().map(|&x| f64::from(x)));
                agreement.push(Agreement {
                    scene: name.clone(),
                    mode: mode.name().into(),
                    peer_spp: ref_spp,
                    reference_spp: ref_spp,
                    dcrt_mean,
                    peer_mean,
                    mean_rel_diff: (peer_mean - dcrt_mean) / dcrt_mean,
                    rmse: error_rgb(&converged, &reference).0,
                });
                peer.push(PeerRun {
                    scene: name.clone(),
                    output: run.0,
                });
            }
            // Knobs at 4 spp against the default setting.
            let k = Shading { spp: 4, ..base };
            let (f0, s0) = go(&mut t, k)?;
            let mut knob = |label: &str, f: &Frame, s: &FrameStats| {
                knobs.push(Knob {
                    scene: name.clone(),
                    mode: mode.name().into(),
                    knob: label.into(),
                    ms: s.seconds * 1e3,
                    steps: s.steps,
                    traced_rays: s.traced_rays,
                    rmse: error(f, &reference).0,
                    same_image: bits(f) == bits(&f0),
                });
            };
            knob("default (any-hit, ulp offset, cull, budget 4096)", &f0, &s0);
            let variants: Vec<(&str, Shading)> = vec![
                (
                    "closest-hit shadow rays",
                    Shading {
                        any_hit: false,
                        ..k
                    },
                ),
                (
                    "fixed epsilon 1e-4",
                    Shading {
                        offset: Offset::Epsilon(1e-4),
                        ..k
                    },
                ),
                (
                    "fixed epsilon 1e-2",
                    Shading {
                        offset: Offset::Epsilon(1e-2),
                        ..k
                    },
                ),
                (
                    "no offset",
                    Shading {
                        offset: Offset::Epsilon(0.0),
                        ..k
                    },
                ),
                ("no box culling", Shading { cull: false, ..k }),
            ];
            for (label, sh) in variants {
                let (f, s) = go(&mut t, sh)?;
                knob(label, &f, &s);
            }
            let mut tb = p.tracer(
                gpu,
                Settings {
                    shading: k,
                    step_budget: 256,
                    ..Settings::default()
                },
            )?;
            tb.render(&basis, scene.background)?;
            let (f, s) = tb.render(&basis, scene.background)?;
            knob("step budget 256", &f, &s);
        }
    }
    let mut time_to_rows = Vec::new();
    let (mut versus, mut time_ratio) = (Vec::new(), Vec::new());
    for g in MODELS {
        for mode in [Mode::Ao, Mode::Path] {
            let pts = |sampler: &str| -> Vec<&Point> {
                curve
                    .iter()
                    .filter(|p| {
                        p.scene == g.name() && p.mode == mode.name() && p.sampler == sampler
                    })
                    .collect()
            };
            let peer_pts = pts(PEER);
            for sampler in [Sampler::Sobol.name(), Sampler::Independent.name(), PEER] {
                let pts = pts(sampler);
                if pts.is_empty() {
                    continue;
                }
                for level in LEVELS {
                    let (spp, ms) = time_to(&pts, level);
                    time_to_rows.push(TimeTo {
                        scene: g.name().into(),
                        mode: mode.name().into(),
                        sampler: sampler.into(),
                        rmse: level,
                        spp,
                        ms,
                    });
                }
            }
            if peer_pts.is_empty() {
                continue;
            }
            let (sobol, independent) =
                (pts(Sampler::Sobol.name()), pts(Sampler::Independent.name()));
            for m in &peer_pts {
                let at = |v: &[&Point]| v.iter().find(|p| p.spp == m.spp).map(|p| (p.rmse, p.ms));
                if let (Some(s), Some(i)) = (at(&sobol), at(&independent)) {
                    versus.push(Versus {
                        scene: g.name().into(),
                        mode: mode.name().into(),
                        spp: m.spp,
                        sobol_rmse: s.0,
                        independent_rmse: i.0,
                        peer_rmse: m.rmse,
                        sobol_ms: s.1,
                        independent_ms: i.1,
                        peer_ms: m.ms,
                    });
                }
            }
            for level in LEVELS {
                let (s, m) = (time_to(&sobol, level).1, time_to(&peer_pts, level).1);
                time_ratio.push(TimeRatio {
                    scene: g.name().into(),
                    mode: mode.name().into(),
                    rmse: level,
                    sobol_ms: s,
                    peer_ms: m,
                    ratio: s.zip(m).map(|(s, m)| s / m),
                });
            }
        }
    }
    let report = Report {
        adapter: gpu.describe(),
        width: w,
        height: h,
        triangles: a.triangles,
        ao_rays,
        max_depth,
        references,
        curve,
        time_to: time_to_rows,
        knobs,
        peer,
        agreement,
        versus,
        time_ratio,
    };
    if let Some(path) = a.plot.as_deref() {
        plot(&report.curve, path)?;
    }
    emit(a.json, &report, print)
}

/// The peer's curve's name among the samplers.
const PEER: &str = "mitsuba";

/// The peer's run: `(spp, ms, (RMSE, relative MSE))` at spp 1, 2, 4, .. `max_spp` against the
/// reference, and its render at `ref_spp` (the converged comparison). The exchange directory is a
/// temporary one, removed after a successful run and kept (and named) after a failed one.
#[allow(clippy::type_complexity)]
fn mitsuba_curve(
    model: &dcrt::scene::Model,
    basis: &dcrt::scene::CameraBasis,
    sh: &Shading,
    max_spp: u32,
    ref_spp: u32,
    reference: &[[f64; 3]],
) -> Result<(
    (mitsuba::Output, Vec<(u32, f64, (f64, f64))>),
    Vec<[f32; 3]>,
)> {
    let mut spp: Vec<u32> = std::iter::successors(Some(1u32), |s| s.checked_mul(2))
        .take_while(|&s| s <= max_spp)
        .collect();
    if !spp.contains(&ref_spp) {
        spp.push(ref_spp);
    }
    let dir = std::env::temp_dir().join(format!("dcrt-mitsuba-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let kept = || format!("(exchange directory kept: {})", dir.display());
    mitsuba::write_dir(
        &dir,
        model,
        basis,
        (sh.sky, sh.max_depth, sh.rr_depth, sh.seed),
        &spp,
    )?;
    let out = mitsuba::run_script(&dir).with_context(kept)?;
    let mut points = Vec::new();
    let mut converged = None;
    for &s in &spp {
        let r = out
            .renders
            .iter()
            .find(|r| r.spp == s)
            .with_context(|| {
                format!(
                    "{} reported no render at {s} spp",
                    mitsuba::script().display()
                )
            })
            .with_context(kept)?;
        let img = mitsuba::read_image(&dir.join(&r.file), basis.width, basis.height)
            .with_context(kept)?;
        if s <= max_spp {
            points.push((s, r.seconds * 1e3, error_rgb(&img, reference)));
        }
        if s == ref_spp {
            converged = Some(img);
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    let converged = converged.context("no converged render")?;
    Ok(((out, points), converged))
}

fn print(report: &Report) {
    println!("adapter   {}", report.adapter);
    println!(
        "{}x{}, {} triangles per scene; AO {} rays per hit, path max depth {}, sky 1, no sun",
        report.width, report.height, report.triangles, report.ao_rays, report.max_depth
    );
    for r in &report.references {
        println!(
            "reference {} {}: {} spp, independent sampler, other seeds; its own RMSE ~{:.5}",
            r.scene, r.mode, r.spp, r.noise
        );
    }
    let t = Table(&[
        ("scene", -9),
        ("mode", -5),
        ("sampler", -12),
        ("spp", 5),
        ("ms", 10),
        ("RMSE", 10),
        ("relMSE", 10),
    ]);
    t.header();
    for p in &report.curve {
        t.row(&[
            p.scene.clone(),
            p.mode.clone(),
            p.sampler.clone(),
            p.spp.to_string(),
            format!("{:.1}", p.ms),
            format!("{:.5}", p.rmse),
            format!("{:.6}", p.rel_mse),
        ]);
    }
    println!();
    let t = Table(&[
        ("scene", -9),
        ("mode", -5),
        ("sampler", -12),
        ("to RMSE", 8),
        ("spp", 8),
        ("ms", 10),
    ]);
    t.header();
    for r in &report.time_to {
        let or = |v: Option<f64>, d: usize| v.map_or("-".into(), |v| format!("{v:.d$}"));
        t.row(&[
            r.scene.clone(),
            r.mode.clone(),
            r.sampler.clone(),
            format!("{}", r.rmse),
            or(r.spp, 0),
            or(r.ms, 1),
        ]);
    }
    if !report.peer.is_empty() {
        print_peer(report);
    }
    println!();
    let t = Table(&[
        ("scene", -9),
        ("mode", -5),
        ("knob (4 spp)", -50),
        ("ms", 9),
        ("steps", 11),
        ("rays", 9),
        ("RMSE", 9),
        ("same", 5),
    ]);
    t.header();
    for k in &report.knobs {
        t.row(&[
            k.scene.clone(),
            k.mode.clone(),
            k.knob.clone(),
            format!("{:.1}", k.ms),
            k.steps.to_string(),
            k.traced_rays.to_string(),
            format!("{:.5}", k.rmse),
            k.same_image.to_string(),
        ]);
    }
}

fn print_peer(report: &Report) {
    for r in &report.peer {
        let o = &r.output;
        println!(
            "\n{}: Mitsuba {} {}, path max_depth {} rr_depth {}, {} threads; timed: {}",
            r.scene, o.mitsuba, o.variant, o.max_depth, o.rr_depth, o.threads, o.timed
        );
    }
    let t = Table(&[
        ("scene", -9),
        ("spp", 5),
        ("sobol RMSE", 10),
        ("indep RMSE", 10),
        ("mitsuba RMSE", 12),
        ("sobol/mi", 8),
        ("indep/mi", 8),
        ("sobol ms", 10),
        ("indep ms", 10),
        ("mitsuba ms", 10),
    ]);
    t.header();
    for v in &report.versus {
        t.row(&[
            v.scene.clone(),
            v.spp.to_string(),
            format!("{:.5}", v.sobol_rmse),
            format!("{:.5}", v.independent_rmse),
            format!("{:.5}", v.peer_rmse),
            format!("{:.2}", v.sobol_rmse / v.peer_rmse),
            format!("{:.2}", v.independent_rmse / v.peer_rmse),
            format!("{:.1}", v.sobol_ms),
            format!("{:.1}", v.independent_ms),
            format!("{:.1}", v.peer_ms),
        ]);
    }
    println!();
    let t = Table(&[
        ("scene", -9),
        ("to RMSE", 8),
        ("sobol ms", 10),
        ("mitsuba ms", 10),
        ("ratio", 8),
    ]);
    t.header();
    for r in &report.time_ratio {
        let or = |v: Option<f64>, d: usize| v.map_or("-".into(), |v| format!("{v:.d$}"));
        t.row(&[
            r.scene.clone(),
            format!("{}", r.rmse),
            or(r.sobol_ms, 1),
            or(r.peer_ms, 1),
            or(r.ratio, 2),
        ]);
    }
    for a in &report.agreement {
        println!(
            "converged {} {}: dcrt reference ({} spp) mean {:.5}, Mitsuba {} spp mean {:.5}, \
             relative difference {:+.3}%, RMSE between them {:.5}",
            a.scene,
            a.mode,
            a.reference_spp,
            a.dcrt_mean,
            a.peer_spp,
            a.peer_mean,
            100.0 * a.mean_rel_diff,
            a.rmse
        );
    }
}

/// RMSE against spp (left) and against time (right), log-log, in `chart`'s look: a colour per
/// scene and mode; the Sobol' sampler with filled squares on a solid line, the independent one
/// with hollow squares, the peer (path only) with crosses. PNG or SVG by the name's extension.
fn plot(points: &[Point], path: &Path) -> Result<()> {
    use dcrt::chart::{self, Entry, Mark, Swatch};
    use plotters::prelude::*;
    let format = chart::Format::of(path, None)?;
    let series = [
        ("rm", "ao"),
        ("rm", "path"),
        ("assembly", "ao"),
        ("assembly", "path"),
    ];
    let samplers = [
        ("sobol", "Sobol'", Mark::Square, true),
        ("independent", "independent", Mark::Square, false),
        (PEER, PEER, Mark::Cross, false),
    ];
    let grey = RGBColor(90, 90, 90);
    let mut entries: Vec<Entry> = series
        .iter()
        .enumerate()
        .map(|(i, (s, m))| Entry::new(format!("{s} {m}"), chart::colour(i), Swatch::Box))
        .collect();
    for (_, label, m, filled) in samplers {
        entries.push(Entry::new(label, grey, Swatch::Mark(m, filled)));
    }
    let rmse = chart::log_range(points.iter().map(|p| p.rmse));
    type Panel = (&'static str, &'static str, fn(&Point) -> f64);
    let panels: [Panel; 2] = [
        ("RMSE against samples per pixel", "samples per pixel", |p| {
            f64::from(p.spp)
        }),
        ("RMSE against time", "time (ms)", |p| p.ms),
    ];
    chart::save(path, format, (1400, 620), |root| {
        let root =
            chart::titled_with_legend(root, "Shading: error against the reference", &entries)?;
        for (area, (title, x_desc, x)) in root.split_evenly((1, 2)).iter().zip(panels) {
            let area = chart::titled(area, title)?;
            let xr = chart::log_range(points.iter().map(x));
            let mut c = chart::log_log(&area, xr, rmse, (x_desc, "RMSE"))?;
            for (i, (scene, mode)) in series.iter().enumerate() {
                for (sampler, _, m, filled) in samplers {
                    let pts: Vec<(f64, f64)> = points
                        .iter()
                        .filter(|p| p.scene == *scene && p.mode == *mode && p.sampler == sampler)
                        .filter(|p| p.rmse > 0.0 && x(p) > 0.0)
                        .map(|p| (x(p), p.rmse))
                        .collect();
                    let colour = chart::colour(i);
                    let line = if filled {
                        colour.stroke_width(2)
                    } else {
                        colour.mix(0.6).stroke_width(1)
                    };
                    c.draw_series(LineSeries::new(pts.clone(), line))
                        .map_err(chart::fail)?;
                    c.draw_series(
                        pts.into_iter()
                            .map(|p| chart::marker(m, p, 9, colour, filled)),
                    )
                    .map_err(chart::fail)?;
                }
            }
        }
        Ok(())
    })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shading plot of made-up curves draws in `chart`'s look, as PNG and SVG.
    #[test]
    fn plot_draws_from_points() {
        let mut points = Vec::new();
        for (scene, mode) in [("rm", "ao"), ("rm", "path"), ("assembly", "ao")] {
            for sampler in ["sobol", "independent", PEER] {
                for k in 0..6 {
                    let spp = 1u32 << k;
                    points.push(Point {
                        scene: scene.into(),
                        mode: mode.into(),
                        sampler: sampler.into(),
                        spp,
                        ms: 3.0 * f64::from(spp),
                        rmse: 0.2 / f64::from(spp).sqrt(),
                        rel_mse: 0.0,
                    });
                }
            }
        }
        let dir = std::env::temp_dir().join(format!("dcrt-shading-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        plot(&points, &dir.join("curves.png")).unwrap();
        assert!(image::open(dir.join("curves.png")).is_ok());
        plot(&points, &dir.join("curves.svg")).unwrap();
        let svg = std::fs::read_to_string(dir.join("curves.svg")).unwrap();
        assert!(svg.contains("RMSE against samples per pixel") && svg.contains("Sobol&apos;"));
        assert!(plot(&points, &dir.join("curves.txt")).is_err());
        if std::env::var_os("DCRT_KEEP_FIGURES").is_none() {
            std::fs::remove_dir_all(&dir).unwrap();
        }
    }
}

#[cfg(test)]
mod defaults {
    use super::*;
    use clap::Parser;

    fn parsed(args: &[&str]) -> ShadingArgs {
        let all = [&["dcrt", "bench", "shading"][..], args].concat();
        match crate::Cli::try_parse_from(all).unwrap().command {
            crate::Command::Bench(crate::bench::Bench::Shading(a)) => a,
            _ => unreachable!("bench shading parses as itself"),
        }
    }

    /// The small sizes are the options' own defaults, and a value given is taken as it is (the
    /// old bench rewrote 1024 and 1000000 into them).
    #[test]
    fn small_sizes_are_defaults_and_given_sizes_are_kept() {
        let a = parsed(&[]);
        assert_eq!((a.width, a.height, a.triangles), (32, 32, 50_000));
        let a = parsed(&["--width", "1024", "--triangles", "1000000"]);
        assert_eq!((a.width, a.height, a.triangles), (1024, 32, 1_000_000));
    }
}
