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

use anyhow::Result;
use clap::{Args, Parser, Subcommand};
use dcrt::bvh::Preset;
use dcrt::dc::{CacheMap, Replicate};
use dcrt::gpu::shaders::Store;
use dcrt::gpu::tracer::{DEFAULT_STEP_BUDGET, FaultMode, OverlapMode, Settings};
use dcrt::shading::{Mode, Overrides, Sampler, Shading};
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
    /// Measure BVH build time and primary-ray throughput.
    Bench(BenchArgs),
    /// Read trace directories: summary, Perfetto timeline, plot.
    Trace(trace::TraceArgs),
    /// Predict frame times at K ranks from a cluster run's traces.
    Simulate(simulate::SimulateArgs),
}

#[derive(Args, Clone)]
struct GpuArgs {
    /// Use the first adapter whose name contains this text (default: the best GPU, else lavapipe).
    #[arg(long)]
    adapter: Option<String>,
    /// Loop iterations a ray may run per trace dispatch (1..=60000).
    #[arg(long, default_value_t = DEFAULT_STEP_BUDGET)]
    step_budget: u32,
    /// obvhs build preset.
    #[arg(long, value_enum, default_value_t = Preset::Fast)]
    bvh_preset: Preset,
    /// Block size in bytes.
    #[arg(long, default_value_t = dcrt::blocks::DEFAULT_BLOCK_BYTES)]
    block_size: u32,
    /// Where the GPU keeps blocks.
    #[arg(long, value_enum, default_value_t = Store::Texture)]
    store: Store,
    /// With a distributed cache: when a ray sets absent blocks aside and goes on with the
    /// blocks its GPU holds, instead of suspending at the fault.
    #[arg(long, value_enum, default_value_t = FaultMode::Fit)]
    faults: FaultMode,
    /// With a distributed cache: when the next batch of rays starts while the last rays of the
    /// current one still wait for blocks, so that the two share fault rounds.
    #[arg(long, value_enum, default_value_t = OverlapMode::Auto)]
    overlap_batches: OverlapMode,
    /// Count node visits and node- and triangle-block entries in every frame (`--stats`
    /// `node_visits`, `block_entries`, `tri_block_entries`; 0 without). The counts slow the trace.
    #[arg(long)]
    block_counts: bool,
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
    /// Offset secondary-ray origins by this fixed distance instead of integer ulps (for
    /// comparison).
    #[arg(long)]
    epsilon: Option<f32>,
    /// Shadow and occlusion rays find the closest hit instead of stopping at any (for
    /// comparison).
    #[arg(long)]
    closest_hit_shadows: bool,
    /// Trace primary rays that miss the model's box too (for comparison).
    #[arg(long)]
    no_cull: bool,
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
            epsilon: self.epsilon,
            closest_hit_shadows: self.closest_hit_shadows,
            no_cull: self.no_cull,
        }
    }

    fn apply(&self, base: Shading) -> Result<Shading> {
        Ok(self.overrides().apply(base)?)
    }
}

#[derive(Args)]
struct BenchArgs {
    /// Scene file, or a prepared block file (.dcb) to trace as it is; without it, a generated
    /// scene (--generator, --triangles).
    scene: Option<PathBuf>,
    #[arg(long, default_value = "rm")]
    generator: String,
    #[arg(long, default_value_t = 1_000_000)]
    triangles: u64,
    #[arg(long, default_value_t = 1024)]
    width: u32,
    #[arg(long, default_value_t = 1024)]
    height: u32,
    /// Timed frames after one warm-up frame; the median is reported.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Also build and trace with every obvhs preset, side by side.
    #[arg(long)]
    bvh_presets: bool,
    /// Trace with both block stores (texture, buffer), side by side.
    #[arg(long)]
    stores: bool,
    /// One JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// No progress bars (they are drawn on stderr when it is a terminal).
    #[arg(long, short)]
    quiet: bool,
    /// Shading modes to measure rays/s in (primary and secondary rays over the frame time);
    /// `ao` traces 4 rays per hit and `path` at most 3 bounces, to keep a frame short.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "cast")]
    modes: Vec<Mode>,
    /// A peer renderer run beside dcrt in the same run: `embree` traces the same camera rays on
    /// every core and reports both rates, their ratio and how often the hits agree
    /// (scripts/embree-peer.sh); `mitsuba` (with --shading) renders the path-traced scenes
    /// against the same references (scripts/mitsuba-peer.sh, which installs Mitsuba 3 into its
    /// own venv on first use).
    #[arg(long, value_enum)]
    peer: Option<bench::Peer>,
    /// Distributed-cache sweep: replicated against caches of 1/32..1/1 with both mappings, over
    /// an orbit of --frames frames as rank --rank of --virtual-ranks.
    #[arg(long)]
    dc: bool,
    #[arg(long, default_value_t = 8)]
    virtual_ranks: u32,
    #[arg(long, default_value_t = 0)]
    rank: u32,
    #[arg(long, default_value_t = 4)]
    frames: u32,
    /// Time against error of AO and path tracing on the rm and assembly generators (small
    /// images: --width/--height default to 32 here), and the cost and error of accuracy knobs.
    #[arg(long)]
    shading: bool,
    /// --shading: the largest spp of the curves (powers of two from 1).
    #[arg(long, default_value_t = 1024)]
    max_spp: u32,
    /// --shading: samples per pixel of the path references (AO: a quarter), two renders with
    /// the independent sampler and other seeds.
    #[arg(long, default_value_t = 4096)]
    reference_spp: u32,
    /// --shading: also draw the curves into this PNG.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Fuzz every mesh loader for this many seconds each with mutations of the shipped files
    /// (scenes/meshes/, tests/data/vtk/; run from the repository): counts of inputs read and
    /// refused, and any input that panics, breaks a loader's promise or takes over a second,
    /// saved in fuzz-crashes/.
    #[arg(long)]
    fuzz_loaders: Option<f64>,
    /// Memory soak: render an orbit of this many frames in one process (rank --rank of
    /// --virtual-ranks with the first of --caches, `none` replicating) and report resident
    /// memory at intervals and its slope in bytes per frame.
    #[arg(long)]
    soak: Option<u32>,
    /// Cache sizes for --dc.
    #[arg(long, value_delimiter = ',', default_value = "1/32,1/8,1/4,1/2,1/1")]
    caches: Vec<String>,
    /// What every rank replicates in the --dc sweep (`root,nodes` sweeps both, and --soak takes
    /// the first).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "root")]
    replicate_blocks: Vec<Replicate>,
    /// Cache mappings for --dc.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "ize,demarle,lru"
    )]
    cache_maps: Vec<CacheMap>,
    /// --dc: run the replicated configuration and then every cache configuration this many
    /// times in turn; frame times and ratios to replicated are medians over the repeats, each
    /// ratio against the replicated frame of its own repeat (the host's speed drifts).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    repeats: u32,
    /// Cluster sweep: mpirun jobs of this binary with --ranks ranks, replicated and with the
    /// distributed cache (--cluster-caches), beside one process; block fetch costs on every
    /// --transports; then the display benchmark for each --copy-threads. Runs the rm and the
    /// occluded assembly model unless a scene is given.
    #[arg(long)]
    cluster: bool,
    #[arg(long, value_delimiter = ',', default_value = "2,3,4,5,6")]
    ranks: Vec<u32>,
    /// `none` replicates; a cache size, with `:MAP` for another mapping than `ize` (`1/8:lru`),
    /// `:OVERLAP` for another `--overlap-batches` than `auto` (`1/8:lru:never`) and `:REPLICATE`
    /// for another `--replicate-blocks` than `root` (`1/8:lru:auto:nodes`).
    #[arg(long, value_delimiter = ',', default_value = "none,1/8")]
    cluster_caches: Vec<String>,
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "shm,tcp-pt2pt,ucx"
    )]
    transports: Vec<dcrt::cluster::bench::Transport>,
    /// Copy-thread counts of the display benchmark (an HD frame), comma separated; an empty
    /// list ("") skips it.
    #[arg(long, value_parser = counts, default_value = "1,2,3,4")]
    copy_threads: Counts,
    #[arg(long, default_value_t = 4)]
    display_ranks: u32,
    #[arg(long, default_value_t = 60)]
    display_frames: u32,
    /// Only the display benchmark.
    #[arg(long)]
    display_only: bool,
    /// The chapter's Figures 6-8 into this directory: traced mpirun jobs at --ranks of the rm and
    /// assembly models, replicated and with each of --caches, each --runs times (the median
    /// drawn), simulated to 60 nodes on its 1868 MB/s network, memory per node, and the display benchmark per --copy-threads
    /// (figure6.png, figure7.png, figure8.png, figures.json). --width/--height default to
    /// 128x96 and --triangles to 50000 here.
    #[arg(long)]
    figures: Option<PathBuf>,
    #[command(flatten)]
    gpu: GpuArgs,
}

/// A comma-separated list of counts, possibly empty (`--copy-threads ""`).
#[derive(Clone, Debug)]
struct Counts(Vec<u32>);

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
    if let Err(e) = dcrt::files::remove_on_interrupt(grace) {
        dcrt::report!("error: {e}");
        return ExitCode::FAILURE;
    }
    let result = match cli.command {
        Command::Render(a) => render::render(a),
        Command::Info {
            file: Some(file), ..
        } => info::mesh(&file),
        Command::Info { adapter, .. } => info::info(adapter.as_deref()),
        Command::Prepare(a) => prepare::prepare(a),
        Command::Bench(a) => bench::bench(a),
        Command::Trace(a) => trace::trace(a),
        Command::Simulate(a) => simulate::simulate(a),
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
        faults: g.faults,
        overlap_batches: g.overlap_batches,
        block_counts: g.block_counts,
        ..Settings::default()
    }
}
