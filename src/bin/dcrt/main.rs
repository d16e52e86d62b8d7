//! The `dcrt` command line: render, info, prepare, bench. The arguments and the dispatch; each
//! command is a module.

mod bench;
mod checks;
mod headless;
mod info;
mod prepare;
mod render;
mod simulate;
mod trace;
mod view;

use clap::{Args, Parser, Subcommand};
use dcrt::bvh::{Build, DEFAULT_NODE_COST, Preset};
use dcrt::gpu::shaders::Store;
use dcrt::gpu::tracer::{DEFAULT_STEP_BUDGET, Settings};
use dcrt::shading::{Mode, Overrides, Sampler};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "dcrt",
    version,
    about = "GPU-compute ray tracer for massive triangle models"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to PNG (and EXR).
    Render(render::RenderArgs),
    /// Show the GPU adapters, the one dcrt would use, its limits and features; or, given a
    /// mesh file, its points, triangles, bounds and data arrays (what `color_by` can name).
    Info {
        /// A mesh file to describe instead.
        file: Option<PathBuf>,
        /// Use the first adapter whose name contains this text.
        #[arg(long)]
        adapter: Option<String>,
    },
    /// Build the BVH and blocks once and write them to a block file (.dcb).
    Prepare(prepare::PrepareArgs),
    /// Measurements: ray throughput, the distributed cache, shading error against time, cluster
    /// jobs, the chapter's figures, memory over long runs, the loaders' fuzzing.
    #[command(subcommand)]
    Bench(bench::Bench),
    /// Read trace directories: summary, Perfetto timeline, plot.
    Trace(trace::TraceArgs),
    /// Predict frame times at K ranks from a cluster run's traces.
    Simulate(simulate::SimulateArgs),
    /// Serve a live view: the frames in a browser as they are made, the camera under the mouse,
    /// and an HTTP API for scripts (`/camera`, `/frame.png`, `/stats`).
    View(view::ViewArgs),
}

#[derive(Args, Clone)]
struct GpuArgs {
    /// Use the first adapter whose name contains this text (default: the best GPU, else lavapipe).
    #[arg(long)]
    adapter: Option<String>,
    /// Loop iterations a ray may run per traversal dispatch (1..=60000).
    #[arg(long, default_value_t = DEFAULT_STEP_BUDGET)]
    step_budget: u32,
    #[command(flatten)]
    build: BuildArgs,
    /// Where the GPU keeps blocks.
    #[arg(long, value_enum, default_value_t = Store::Texture)]
    store: Store,
}

/// How the model's BVH and blocks are built.
#[derive(Args, Clone)]
struct BuildArgs {
    /// obvhs build preset.
    #[arg(long, value_enum, default_value_t = Preset::Fast)]
    bvh_preset: Preset,
    /// What a node visit costs beside a triangle test when the build makes leaves (obvhs's
    /// collapse cost, above 0): lower makes smaller leaves, so rays run fewer traversal steps
    /// through a larger tree (1: about 12% fewer steps and a fifth more blocks than the default).
    #[arg(long, default_value_t = DEFAULT_NODE_COST, allow_negative_numbers = true)]
    bvh_node_cost: f32,
    /// Block size in bytes.
    #[arg(long, default_value_t = dcrt::blocks::DEFAULT_BLOCK_BYTES)]
    block_size: u32,
}

impl BuildArgs {
    fn tree(&self) -> anyhow::Result<Build> {
        Ok(Build {
            preset: self.bvh_preset,
            node_cost: node_cost("--bvh-node-cost", self.bvh_node_cost)?,
        })
    }
}

/// `c` if it is a node cost (`--bvh-node-cost`), else an error naming `option`.
fn node_cost(option: &str, c: f32) -> anyhow::Result<f32> {
    if c.is_finite() && c > 0.0 && c <= 1000.0 {
        Ok(c)
    } else {
        anyhow::bail!("{option} {c} is not a node cost: a number above 0 and at most 1000")
    }
}

/// Shading options; each overrides the scene's `[render]` value when given.
#[derive(Args, Clone, Default)]
struct ShadeArgs {
    /// Shading mode.
    #[arg(long, value_enum)]
    mode: Option<Mode>,
    /// Samples per pixel (accumulated; 1 traces pixel centres).
    #[arg(long)]
    spp: Option<u32>,
    /// Sampler seed: the same seed gives the same bits.
    #[arg(long)]
    seed: Option<u32>,
    /// Sampler: sobol (Owen-scrambled Sobol', the default) or independent (hashed uniform
    /// numbers, the unbiased baseline).
    #[arg(long, value_enum)]
    sampler: Option<Sampler>,
    /// Ambient occlusion rays per hit (default 36).
    #[arg(long)]
    ao_rays: Option<u32>,
    /// Ambient occlusion distance (default: unbounded).
    #[arg(long)]
    ao_distance: Option<f32>,
    /// Path tracing: most bounces.
    #[arg(long)]
    max_depth: Option<u32>,
}

impl ShadeArgs {
    fn overrides(&self) -> Overrides {
        Overrides {
            mode: self.mode,
            spp: self.spp,
            seed: self.seed,
            sampler: self.sampler,
            ao_rays: self.ao_rays,
            ao_distance: self.ao_distance,
            max_depth: self.max_depth,
            ..Overrides::default()
        }
    }
}

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    // Before any thread or GPU: a headless run must not print window-system noise.
    headless::rerun_quietly();
    // An interrupted command leaves none of its outputs (docs/ARCHITECTURE.md, Outputs).
    let grace = match dcrt::cluster::launched_ranks() {
        Some(k) if k > 1 => std::time::Duration::from_millis(500),
        _ => std::time::Duration::ZERO,
    };
    // The display (a job's only rank, alone) writes a line a frame, which must not fill its
    // stderr while mpirun stops the job and reads none of it (docs/ARCHITECTURE.md, Outputs).
    if dcrt::cluster::launched_rank() == Some(dcrt::cluster::Roles::DISPLAY) {
        dcrt::files::enlarge_stderr_pipe();
    }
    if let Err(e) = dcrt::files::remove_on_interrupt(grace) {
        dcrt::report!("error: {e}");
        return ExitCode::FAILURE;
    }
    let result = match cli.command {
        Command::Render(a) => render::render(a, &bench::Switches::default()),
        Command::Info {
            file: Some(file), ..
        } => info::mesh(&file),
        Command::Info { adapter, .. } => info::info(adapter.as_deref()),
        Command::Prepare(a) => prepare::prepare(a),
        Command::Bench(b) => bench::bench(b),
        Command::Trace(a) => trace::trace(a),
        Command::Simulate(a) => simulate::simulate(a),
        Command::View(a) => view::view(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            dcrt::report!("error: {}", message(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes, each once: a library error already quotes its source (`path:
/// cause`), so a cause whose text is already there is not repeated.
fn message(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let c = cause.to_string();
        if text.contains(&c) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&c);
    }
    text
}

fn settings(g: &GpuArgs) -> Settings {
    Settings {
        step_budget: g.step_budget,
        store: g.store,
        ..Settings::default()
    }
}
