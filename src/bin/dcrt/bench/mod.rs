//! `dcrt bench`: the measurements behind docs/benchmarks.md, one subcommand each: ray
//! throughput per BVH preset, block store and shading mode (`rays`), the distributed-cache sweep
//! (`dc`), shading time against error (`shading`), cluster jobs under mpirun (`cluster`, with
//! the jobs' runner in `jobs`), the chapter's Figures 6-8 (`figures`), memory over a long orbit
//! (`soak`), the live view's latency and frame rate (`view`), the mesh loaders' fuzzing (`fuzz`),
//! and `job`, the render path with the
//! measurement switches (`switches`) that the cluster bench and the figures run under mpirun.

mod cluster;
mod dc;
mod figures;
mod fuzz;
mod jobs;
mod rays;
pub mod shading;
mod soak;
mod switches;
mod view;

pub use switches::Switches;

use crate::checks::check_budget;
use crate::render::RenderArgs;
use crate::{BuildArgs, GpuArgs};
use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use dcrt::blocks::Format;
use dcrt::gpu::frame::FrameStats;
use dcrt::gpu::tracer::Tracer;
use dcrt::render::frames::{FramePlan, Role, View, run_images};
use dcrt::scene::MAX_GENERATED_TRIANGLES;
use dcrt::scene::generate::Generator;
use dcrt::scene::{Camera, Model, Scene, check_image_size};
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum Bench {
    /// BVH build time and rays per second (primary, and secondary with --modes) per obvhs
    /// preset, block store and shading mode, with the traversal's counts; optionally Embree on
    /// the same camera rays in the same run.
    Rays(rays::RaysArgs),
    /// Distributed-cache sweep in one process: replicated against caches of each size, mapping
    /// and replicated blocks, over an orbit, as one rank of virtual ranks; memory per rank.
    Dc(dc::DcArgs),
    /// Time against error of AO and path tracing on the rm and assembly generators, and the
    /// cost and error of the accuracy switches; optionally Mitsuba 3 on the same scenes.
    Shading(shading::ShadingArgs),
    /// mpirun jobs of this binary, replicated and with distributed caches, beside one process;
    /// block fetch costs per transport; then the display benchmark per copy-thread count.
    Cluster(cluster::ClusterArgs),
    /// The chapter's Figures 6-8: traced mpirun jobs, their replays to 60 nodes, memory per
    /// node, the display benchmark (figure6.png, figure7.png, figure8.png, figures.json).
    Figures(figures::FiguresArgs),
    /// Memory soak: an orbit of many frames in one process; resident memory at intervals and
    /// its slope in bytes per frame.
    Soak(soak::SoakArgs),
    /// The live view as its user meets it: latency from a camera change to its frame, frames a
    /// second while dragging, the encoder's share, per frame size and cache; or with --minutes
    /// the view's memory over a long session of dragging.
    View(view::ViewArgs),
    /// Fuzz every mesh loader with mutations of the shipped files (scenes/meshes/,
    /// tests/data/vtk/; run from the repository); any input that panics, breaks a loader's
    /// promise or takes over a second is saved in fuzz-crashes/.
    Fuzz(fuzz::FuzzArgs),
    /// One job of `bench cluster` and `bench figures`: `dcrt render` (the same options, the same
    /// path) with the measurement switches. For the benches, not for users.
    #[command(hide = true)]
    Job(JobArgs),
}

/// `dcrt bench job`: the render options, and the switches.
#[derive(Args)]
pub struct JobArgs {
    #[command(flatten)]
    render: RenderArgs,
    #[command(flatten)]
    switches: Switches,
}

/// The model of `rays`, `dc` and `soak`: a scene, or a generated one; and the image size.
#[derive(Args)]
pub struct SceneArgs {
    /// Scene file (`rays`: or a prepared block file, .dcb, traced as it is); without it, a
    /// generated scene (--generator, --triangles).
    scene: Option<PathBuf>,
    /// The generator of the scene when none is given.
    #[arg(long, default_value = "rm")]
    generator: String,
    /// Triangles of the generated scene.
    #[arg(long, default_value_t = 1_000_000)]
    triangles: u64,
    #[arg(long, default_value_t = 1024)]
    width: u32,
    #[arg(long, default_value_t = 1024)]
    height: u32,
}

/// How a bench reports.
#[derive(Args)]
pub struct ReportArgs {
    /// One JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// No progress bars (they are drawn on stderr when it is a terminal).
    #[arg(long, short)]
    quiet: bool,
}

/// The display benchmark's jobs (`cluster`, `figures`): an HD frame, streamed to the display.
#[derive(Args)]
pub struct DisplayArgs {
    /// Copy-thread counts of the display benchmark, comma separated; an empty list ("") skips
    /// it.
    #[arg(long, value_parser = counts, default_value = "1,2,3,4")]
    copy_threads: Counts,
    /// MPI ranks of each display job.
    #[arg(long, default_value_t = 4)]
    display_ranks: u32,
    /// Frames of each display job (the first is not timed).
    #[arg(long, default_value_t = 60)]
    display_frames: u32,
}

/// A comma-separated list of counts, possibly empty (`--copy-threads ""`).
#[derive(Clone, Debug)]
pub struct Counts(Vec<u32>);

fn counts(s: &str) -> std::result::Result<Counts, String> {
    if s.trim().is_empty() {
        return Ok(Counts(Vec::new()));
    }
    s.split(',')
        .map(|c| {
            c.trim()
                .parse::<u32>()
                .map_err(|e| format!("{c:?} is not a count: {e}"))
        })
        .collect::<std::result::Result<Vec<u32>, String>>()
        .map(Counts)
}

pub fn bench(b: Bench) -> Result<()> {
    match b {
        Bench::Rays(a) => rays::bench(&a),
        Bench::Dc(a) => dc::bench(&a),
        Bench::Shading(a) => shading::bench(&a),
        Bench::Cluster(a) => cluster::bench(&a),
        Bench::Figures(a) => figures::bench(&a),
        Bench::Soak(a) => soak::bench(&a),
        Bench::View(a) => view::bench(&a),
        Bench::Fuzz(a) => fuzz::run(a.seconds, a.json),
        Bench::Job(a) => crate::render::render(a.render, &a.switches),
    }
}

/// The checks every bench with a model makes before any work: the image size, the generated
/// triangles, the step budget.
fn check_model(width: u32, height: u32, triangles: u64, gpu: Option<&GpuArgs>) -> Result<()> {
    check_image_size(width, height)?;
    if !(1..=MAX_GENERATED_TRIANGLES).contains(&triangles) {
        bail!("--triangles must be between 1 and {MAX_GENERATED_TRIANGLES}, got {triangles}");
    }
    if let Some(g) = gpu {
        check_budget(g.step_budget)?;
    }
    Ok(())
}

impl SceneArgs {
    /// The checks of `check_model`, and the block format of `build`.
    fn check(&self, gpu: &GpuArgs) -> Result<Format> {
        check_model(self.width, self.height, self.triangles, Some(gpu))?;
        Ok(Format::new(gpu.build.block_size)?)
    }

    /// A prepared block file given as the scene, if it is one.
    fn block_file(&self) -> Option<&Path> {
        self.scene
            .as_deref()
            .filter(|p| p.extension().is_some_and(|e| e == "dcb"))
    }

    /// `what` refuses a block file: its model is built from a scene.
    fn refuse_block_file(&self, what: &str) -> Result<()> {
        if let Some(path) = self.block_file() {
            bail!(
                "{}: bench {what} builds its model from a scene; a block file is benched as it \
                 is by bench rays",
                path.display()
            );
        }
        Ok(())
    }

    /// The scene, its model and camera.
    fn load(&self) -> Result<(Scene, Model, Camera)> {
        let scene = match &self.scene {
            Some(p) => Scene::load(p)?,
            None => {
                let g = Generator::parse(&self.generator).with_context(|| {
                    format!(
                        "unknown generator '{}' (known: {})",
                        self.generator,
                        Generator::NAMES.join(", ")
                    )
                })?;
                Scene::generated(g, self.triangles, self.width, self.height)
            }
        };
        dcrt::render::memory::check_generators(&scene)?;
        let model = scene.load_model()?;
        let camera = scene.camera_or_default(&model);
        Ok((scene, model, camera))
    }
}

/// The tracer settings of a bench: the GPU options, and the switches where it takes them.
fn settings(gpu: &GpuArgs, switches: &switches::TracerSwitches) -> dcrt::gpu::tracer::Settings {
    switches.apply(crate::settings(gpu))
}

/// The build options of `cluster` and `figures`, whose jobs read the model they prepare.
pub(crate) fn format_of(build: &BuildArgs) -> Result<Format> {
    Ok(Format::new(build.block_size)?)
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

/// The generated models of `shading` and `figures`, and of `cluster` without a scene: the open rm model
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
