//! `dcrt bench`: the measurements behind docs/benchmarks.md. Primary-ray throughput per BVH
//! preset and block store (`trace`), the distributed-cache sweep (`dc`), shading time against
//! error (`shading`), cluster jobs under mpirun (`cluster`), and the mesh loaders' fuzzing
//! (`fuzz`).

mod cluster;
mod dc;
mod figures;
mod fuzz;
pub mod shading;
mod soak;
mod trace;

/// A peer renderer run beside dcrt in the same bench run (`--peer`), on the same cores.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Peer {
    /// Embree 3 (`rtcIntersect8` packets, a thread per core) on the same camera rays, through
    /// `scripts/embree-peer.sh`: primary-ray throughput.
    Embree,
    /// Mitsuba 3 (`llvm_ad_rgb`, `path`, independent sampler) on the same path-traced scenes,
    /// through `scripts/mitsuba-peer.sh`: time against error (with `--shading`).
    Mitsuba,
}

use crate::BenchArgs;
use crate::checks::check_budget;
use anyhow::{Context, Result, bail};
use dcrt::blocks::Format;
use dcrt::gpu::Gpu;
use dcrt::gpu::frame::FrameStats;
use dcrt::gpu::tracer::Tracer;
use dcrt::render::frames::{FramePlan, Role, View, run_images};
use dcrt::scene::MAX_GENERATED_TRIANGLES;
use dcrt::scene::generate::Generator;
use dcrt::scene::{Camera, Scene, check_image_size};

pub fn bench(a: BenchArgs) -> Result<()> {
    if let Some(seconds) = a.fuzz_loaders {
        return fuzz::run(seconds, a.json);
    }
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    check_image_size(a.width, a.height)?;
    if !(1..=MAX_GENERATED_TRIANGLES).contains(&a.triangles) {
        bail!(
            "--triangles must be between 1 and {MAX_GENERATED_TRIANGLES}, got {}",
            a.triangles
        );
    }
    check_budget(a.gpu.step_budget)?;
    if let Some(frames) = a.soak
        && frames < 20
    {
        bail!("--soak needs at least 20 frames, got {frames}");
    }
    match a.peer {
        Some(Peer::Mitsuba) if !a.shading => bail!("--peer mitsuba needs --shading"),
        Some(Peer::Embree) if a.shading || a.dc || a.cluster || a.soak.is_some() => {
            bail!(
                "--peer embree measures primary rays: it goes without --shading, --dc, --cluster and --soak"
            )
        }
        _ => {}
    }
    if a.shading {
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
        let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
        let small = |v: u32| if v == 1024 { 32 } else { v };
        let args = shading::Args {
            width: small(a.width),
            height: small(a.height),
            triangles: if a.triangles == 1_000_000 {
                50_000
            } else {
                a.triangles
            },
            max_spp: a.max_spp,
            reference_spp: a.reference_spp,
            json: a.json,
            plot: a.plot.as_deref(),
            peer: a.peer,
        };
        return shading::run(&gpu, &args);
    }
    if let Some(dir) = &a.figures {
        return figures::run(&a, dir);
    }
    if let Some(path) = a
        .scene
        .as_ref()
        .filter(|p| p.extension().is_some_and(|e| e == "dcb"))
    {
        if a.dc || a.cluster || a.soak.is_some() {
            bail!(
                "{}: --dc, --cluster and --soak build their models from a scene; a block file is \
                 benched as it is (primary rays per store and mode)",
                path.display()
            );
        }
        let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
        return trace::run_file(&a, &gpu, path);
    }
    let scene = match &a.scene {
        Some(p) => Scene::load(p)?,
        None => {
            let g = Generator::parse(&a.generator).with_context(|| {
                format!(
                    "unknown generator '{}' (known: {})",
                    a.generator,
                    Generator::NAMES.join(", ")
                )
            })?;
            Scene::generated(g, a.triangles, a.width, a.height)
        }
    };
    let format = Format::new(a.gpu.block_size)?;
    if a.cluster {
        return cluster::run(&a, format);
    }
    dcrt::render::memory::check_generators(&scene)?;
    let model = scene.load_model()?;
    let camera = scene.camera_or_default(&model);
    let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
    if a.soak.is_some() {
        return soak::run(&a, &gpu, &scene, model, camera, format);
    }
    if a.dc {
        return dc::run(&a, &gpu, &scene, model, camera, format);
    }
    trace::run(&a, &gpu, &scene, model, camera, format)
}

/// The statistics of `frames` frames seen from `view` at `width` x `height`.
pub fn frame_stats(
    tracer: &mut Tracer<'_>,
    view: View,
    frames: u32,
    (width, height): (u32, u32),
    background: [f32; 3],
) -> Result<Vec<FrameStats>> {
    let plan = FramePlan {
        frames,
        view,
        role: Role::one_process(tracer),
        trace_dir: None,
    };
    let mut all = Vec::new();
    run_images(
        tracer,
        &plan,
        width,
        height,
        background,
        &mut |_, _, stats| {
            all.push(stats.clone());
            Ok(())
        },
    )?;
    Ok(all)
}

/// One more frame from `camera`, with the tracer counting node visits and block entries
/// (`Settings::block_counts`), which the timed frames leave out: they cost the trace loop time.
pub fn block_count_frame(
    tracer: &mut Tracer<'_>,
    camera: Camera,
    size: (u32, u32),
    background: [f32; 3],
) -> Result<FrameStats> {
    let was = tracer.settings().block_counts;
    tracer.set_block_counts(true);
    let counted = frame_stats(tracer, View::Fixed(camera), 1, size, background);
    tracer.set_block_counts(was);
    Ok(counted?.remove(0))
}

/// The generated models of `--shading`, and of `--cluster` without a scene: the open rm model
/// and the occluded assembly.
pub const MODELS: [Generator; 2] = [Generator::Rm, Generator::Assembly];

/// With `--json` the report as one JSON object on stdout, else the text `print` writes.
pub fn emit<R: serde::Serialize>(json: bool, report: &R, print: impl FnOnce(&R)) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(report)?);
    } else {
        print(report);
    }
    Ok(())
}

/// A text table: columns one space apart, each of a width and right-aligned, or left-aligned
/// when the width is negative (as printf's `%-9s`). The header and the rows share the widths;
/// cells come formatted.
pub struct Table(pub &'static [(&'static str, i32)]);

impl Table {
    pub fn header(&self) {
        let names: Vec<String> = self.0.iter().map(|c| c.0.to_string()).collect();
        self.row(&names);
    }

    pub fn row(&self, cells: &[String]) {
        println!("{}", self.line(cells));
    }

    fn line(&self, cells: &[String]) -> String {
        debug_assert_eq!(cells.len(), self.0.len());
        let padded: Vec<String> = self
            .0
            .iter()
            .zip(cells)
            .map(|(&(_, w), c)| {
                let n = w.unsigned_abs() as usize;
                if w < 0 {
                    format!("{c:<n$}")
                } else {
                    format!("{c:>n$}")
                }
            })
            .collect();
        padded.join(" ")
    }
}

pub fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_lines_pad_like_format_widths() {
        let t = Table(&[("name", -9), ("ms", 10), ("hit", 6), ("same", 5)]);
        let cells = [
            "rm".to_string(),
            format!("{:.1}", 12.345),
            format!("{:.3}", 0.5),
            true.to_string(),
        ];
        assert_eq!(
            t.line(&cells),
            format!("{:<9} {:>10.1} {:>6.3} {:>5}", "rm", 12.345, 0.5, true)
        );
        let long = [
            "a-name-longer-than-9".to_string(),
            "1".into(),
            "2".into(),
            "3".into(),
        ];
        assert_eq!(
            t.line(&long),
            "a-name-longer-than-9          1      2     3"
        );
    }

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
    }
}
