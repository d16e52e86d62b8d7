//! The `dcrt` command line: render, info, bench.

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use dcrt::blocks::Format;
use dcrt::bvh::Preset;
use dcrt::dc::{CacheMap, CacheSize};
use dcrt::gpu::Gpu;
use dcrt::gpu::shaders::Store;
use dcrt::gpu::tracer::{DEFAULT_STEP_BUDGET, MAX_STEP_BUDGET, Settings};
use dcrt::output::{self, Aov};
use dcrt::render::{DcOptions, Loaded, Prepared, render_frame};
use dcrt::scene::generate::Generator;
use dcrt::scene::{Scene, check_image_size};
use dcrt::shading::{Mode, Overrides, Shading};
use std::path::{Path, PathBuf};

mod bench_shading;
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
    Render(RenderArgs),
    /// Show the GPU adapters, the one dcrt would use, its limits and features.
    Info {
        /// Use the first adapter whose name contains this text.
        #[arg(long)]
        adapter: Option<String>,
    },
    /// Build the BVH and blocks once and write them to a block file (.dcb).
    Prepare(PrepareArgs),
    /// Measure BVH build time and primary-ray throughput.
    Bench(BenchArgs),
}

#[derive(Args)]
struct PrepareArgs {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Output block file.
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long, value_enum, default_value_t = Preset::Fast)]
    bvh_preset: Preset,
    #[arg(long, default_value_t = dcrt::blocks::DEFAULT_BLOCK_BYTES)]
    block_size: u32,
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
struct RenderArgs {
    /// Scene file (TOML) or prepared block file (.dcb).
    scene: PathBuf,
    /// Output PNG.
    #[arg(short, long, default_value = "out.png")]
    output: PathBuf,
    /// Also write linear OpenEXR with R, G, B and the requested AOVs.
    #[arg(long)]
    exr: Option<PathBuf>,
    /// EXR AOVs, comma separated.
    #[arg(long, value_enum, value_delimiter = ',')]
    aov: Vec<Aov>,
    #[arg(long)]
    width: Option<u32>,
    #[arg(long)]
    height: Option<u32>,
    /// Frames to render, orbiting the camera about the focal point (one turn in all); outputs
    /// are numbered (out_0000.png ...). The cache persists between frames.
    #[arg(long, default_value_t = 1)]
    frames: u32,
    /// Write each frame's fault/fetch trace (JSON Lines) into this directory.
    #[arg(long)]
    trace: Option<PathBuf>,
    /// PNG exposure in stops (the EXR stays linear).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    exposure: f32,
    #[command(flatten)]
    shade: ShadeArgs,
    #[command(flatten)]
    gpu: GpuArgs,
    #[command(flatten)]
    dc: DcArgs,
    #[command(flatten)]
    cluster: ClusterArgs,
}

/// Options of cluster mode (under mpirun or srun with 2 ranks or more).
#[derive(Args, Clone)]
struct ClusterArgs {
    /// Threads the display copies received pixels into the frame with.
    #[arg(long, default_value_t = 2)]
    copy_threads: u32,
    /// Side in pixels of the balancer's large tiles.
    #[arg(long, default_value_t = 128)]
    tile: u32,
    /// Side of the smallest tiles the balancer splits them into toward the end of a frame.
    #[arg(long, default_value_t = 16)]
    min_tile: u32,
    /// Target size in bytes of a pixel message to the display.
    #[arg(long, default_value_t = 32 * 1024)]
    message_bytes: usize,
    /// Seconds any rank may wait (for a message, for its GPU) before the job is aborted.
    #[arg(long, default_value_t = 300)]
    timeout: u64,
    /// Display benchmark (chapter 5.5): the camera looks away from the model, tiles are traced
    /// once and then resent, and the MPI bandwidth to the display is measured after the frames.
    #[arg(long)]
    display_bench: bool,
    /// Write the run's figures (frame times, per-rank statistics) as JSON to this file.
    #[arg(long)]
    stats: Option<PathBuf>,
}

#[derive(Args, Clone)]
struct DcArgs {
    /// Split the model over N in-process ranks and render through a distributed cache.
    #[arg(long)]
    virtual_ranks: Option<u32>,
    /// The rank this process renders as (with --virtual-ranks).
    #[arg(long, default_value_t = 0)]
    rank: u32,
    /// Cache size: a fraction of the model (1/8), lines (64lines) or bytes (256MiB). Default 1/8
    /// with --virtual-ranks; under mpirun, giving it turns the distributed cache on.
    #[arg(long)]
    cache: Option<String>,
    #[arg(long, value_enum, default_value_t = CacheMap::Ize)]
    cache_map: CacheMap,
    /// Everything resident, no cache (the default without --virtual-ranks).
    #[arg(long, conflicts_with = "virtual_ranks")]
    replicate: bool,
}

impl DcArgs {
    fn options(&self) -> Result<Option<DcOptions>> {
        let Some(n) = self.virtual_ranks else {
            return Ok(None);
        };
        dcrt::dc::Ranks::new(n, self.rank)?;
        Ok(Some(DcOptions {
            ranks: n,
            rank: self.rank,
            cache: CacheSize::parse(self.cache.as_deref().unwrap_or("1/8"))?,
            map: self.cache_map,
        }))
    }
}

#[derive(Args)]
struct BenchArgs {
    /// Scene file; without it, a generated scene (--generator, --triangles).
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
    /// --shading: the largest spp of the curve.
    #[arg(long, default_value_t = 32)]
    max_spp: u32,
    /// --shading: also draw the curves into this PNG.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Cache sizes for --dc.
    #[arg(long, value_delimiter = ',', default_value = "1/32,1/8,1/4,1/2,1/1")]
    caches: Vec<String>,
    /// Cluster sweep: mpirun jobs of this binary with --ranks ranks, replicated and with the
    /// distributed cache (--cluster-caches), beside one process; block fetch costs on every
    /// --transports; then the display benchmark for each --copy-threads. Runs the rm and the
    /// occluded assembly model unless a scene is given.
    #[arg(long)]
    cluster: bool,
    #[arg(long, value_delimiter = ',', default_value = "2,3,4,5,6")]
    ranks: Vec<u32>,
    /// `none` replicates.
    #[arg(long, value_delimiter = ',', default_value = "none,1/8")]
    cluster_caches: Vec<String>,
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "shm,tcp-pt2pt,ucx"
    )]
    transports: Vec<dcrt::cluster::bench::Transport>,
    /// Copy-thread counts of the display benchmark (an HD frame); empty skips it.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3,4")]
    copy_threads: Vec<u32>,
    #[arg(long, default_value_t = 4)]
    display_ranks: u32,
    #[arg(long, default_value_t = 60)]
    display_frames: u32,
    /// Only the display benchmark.
    #[arg(long)]
    display_only: bool,
    #[command(flatten)]
    gpu: GpuArgs,
}

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(a) => render(a),
        Command::Info { adapter } => info(adapter.as_deref()),
        Command::Prepare(a) => prepare(a),
        Command::Bench(a) => bench(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn settings(g: &GpuArgs) -> Settings {
    Settings {
        step_budget: g.step_budget,
        store: g.store,
        ..Settings::default()
    }
}

fn render(a: RenderArgs) -> Result<()> {
    check_budget(a.gpu.step_budget)?;
    if !a.aov.is_empty() && a.exr.is_none() {
        bail!("--aov needs --exr FILE: the AOVs are EXR channels");
    }
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if !a.exposure.is_finite() {
        bail!("--exposure must be finite, got {}", a.exposure);
    }
    // Options are checked before the scene is loaded.
    a.shade.apply(Shading::default())?;
    for out in std::iter::once(&a.output).chain(a.exr.as_ref()) {
        check_writable(out)?;
    }
    if let Some(dir) = &a.trace {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create the trace directory", dir.display()))?;
    }
    let format = Format::new(a.gpu.block_size)?;
    // Checked in one process too, so that a typo is not found only on the cluster.
    let c = &a.cluster;
    if c.copy_threads == 0 || c.tile == 0 || c.min_tile == 0 || c.message_bytes == 0 {
        bail!("--copy-threads, --tile, --min-tile and --message-bytes must be at least 1");
    }
    if c.timeout == 0 {
        bail!("--timeout must be at least 1 second");
    }
    if let Some(k) = dcrt::cluster::launched_ranks().filter(|&k| k > 1) {
        return render_cluster(&a, format, k);
    }
    if a.cluster.display_bench {
        bail!(
            "--display-bench measures the display of a cluster: run it under mpirun with 2 or more ranks"
        );
    }
    let dc = a.dc.options()?;
    let loaded = Loaded::open(&a.scene, a.gpu.bvh_preset, format)?;
    let mut report = Vec::new();
    let width = a.width.unwrap_or(loaded.width);
    let height = a.height.unwrap_or(loaded.height);
    check_image_size(width, height)?;
    let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
    eprintln!("adapter: {}", gpu.describe());
    let shading = a.shade.apply(loaded.shading)?;
    let s = Settings {
        shading,
        ..settings(&a.gpu)
    };
    let mut tracer = loaded.tracer(&gpu, s, dc.as_ref())?;
    match &dc {
        Some(o) => {
            let m = o.memory(loaded.block_count(), loaded.format())?;
            eprintln!(
                "rank {} of {}: {:.1} MiB resident + {:.1} MiB cache ({} lines, {:?}) of a {:.1} MiB \
                 model",
                o.rank,
                o.ranks,
                m.resident_bytes as f64 / 1048576.0,
                m.cache_bytes as f64 / 1048576.0,
                o.cache
                    .lines(loaded.block_count(), loaded.format().block_bytes),
                o.map,
                loaded.model_bytes() as f64 / 1048576.0
            );
        }
        None => eprintln!(
            "replicated: {:.1} MiB of blocks",
            loaded.model_bytes() as f64 / 1048576.0
        ),
    }
    for i in 0..a.frames {
        let camera = loaded
            .camera
            .orbit(std::f64::consts::TAU * f64::from(i) / f64::from(a.frames));
        let (frame, stats) = render_frame(&mut tracer, &camera, width, height, loaded.background)?;
        let numbered = |p: &Path| output::numbered(p, i, a.frames);
        report.push(
            serde_json::json!({"frame": i, "frame_ms": stats.seconds * 1e3, "stats": &stats}),
        );
        let png = numbered(&a.output);
        output::write_png_exposed(&png, &frame, a.exposure)?;
        if let Some(exr) = &a.exr {
            output::write_exr(&numbered(exr), &frame, &a.aov)?;
        }
        let mut trace = tracer.take_trace();
        if let Some(dir) = &a.trace {
            trace.summary.frame = i;
            if dc.is_none() {
                trace.summary.frame_ms = stats.seconds * 1e3;
                trace.summary.trace_ms = stats.trace_seconds * 1e3;
                trace.summary.shade_ms = stats.shade_seconds * 1e3;
                trace.summary.rounds = stats.rounds;
                trace.summary.ranks = 1;
                trace.summary.role = "single".into();
                trace.summary.hit_rate = 1.0;
            }
            trace.write(dir)?;
        }
        eprintln!(
            "frame {i}: {} {} spp, {} triangles{}, {}x{} in {:.1} ms, {} rounds{}, wrote {}",
            shading.mode.name(),
            shading.spp,
            loaded.triangles,
            loaded
                .build_seconds
                .filter(|_| i == 0)
                .map(|s| format!(", BVH {:.0} ms (depth {})", s * 1e3, loaded.depth))
                .unwrap_or_default(),
            width,
            height,
            stats.seconds * 1e3,
            stats.max_live_rounds,
            if dc.is_some() {
                format!(
                    ", {} faults rounds, hit rate {:.3}, {} blocks fetched",
                    stats.fault_rounds,
                    if stats.lookups > 0 {
                        stats.hits as f64 / stats.lookups as f64
                    } else {
                        1.0
                    },
                    stats.fetched_blocks
                )
            } else {
                String::new()
            },
            png.display()
        );
    }
    if let Some(path) = &a.cluster.stats {
        let all =
            serde_json::json!({"ranks": 1, "width": width, "height": height, "frames": report});
        std::fs::write(path, all.to_string())
            .with_context(|| format!("{}: cannot write the statistics", path.display()))?;
    }
    Ok(())
}

/// `render` under an MPI launcher with `k` > 1 ranks: this process's role of the cluster.
fn render_cluster(a: &RenderArgs, format: Format, k: u32) -> Result<()> {
    if a.dc.virtual_ranks.is_some() {
        bail!("--virtual-ranks is for one process; under mpirun the {k} ranks are the ranks");
    }
    let c = &a.cluster;
    let cache = match &a.dc.cache {
        Some(s) => Some((CacheSize::parse(s)?, a.dc.cache_map)),
        None => None,
    };
    let opts = dcrt::cluster::Options {
        input: a.scene.clone(),
        output: a.output.clone(),
        exr: a.exr.clone(),
        aovs: a.aov.clone(),
        width: a.width,
        height: a.height,
        frames: a.frames,
        trace: a.trace.clone(),
        adapter: a.gpu.adapter.clone(),
        settings: settings(&a.gpu),
        shade: a.shade.overrides(),
        exposure: a.exposure,
        preset: a.gpu.bvh_preset,
        format,
        cache,
        copy_threads: c.copy_threads,
        tile: c.tile,
        min_tile: c.min_tile,
        message_bytes: c.message_bytes,
        timeout: std::time::Duration::from_secs(c.timeout),
        display_bench: c.display_bench,
        stats: c.stats.clone(),
    };
    dcrt::cluster::run(&opts)?;
    Ok(())
}

/// `bench --cluster`: prepares the models once, then runs the jobs of `cluster::bench`.
fn bench_cluster(a: &BenchArgs, format: Format) -> Result<()> {
    use dcrt::cluster::bench::{Plan, table};
    if a.frames < 2 || a.display_frames < 4 {
        bail!("--frames must be at least 2 and --display-frames at least 4: frame 0 is not timed");
    }
    if a.ranks.iter().any(|&k| k < 2) || a.display_ranks < 2 {
        bail!("--ranks and --display-ranks count MPI ranks: at least 2");
    }
    let dir = std::env::temp_dir().join(format!("dcrt-bench-cluster-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let scenes: Vec<(String, Scene)> = match &a.scene {
        Some(p) => vec![(
            p.file_stem()
                .map_or("scene".into(), |s| s.to_string_lossy().into_owned()),
            Scene::load(p)?,
        )],
        None => [Generator::Rm, Generator::Assembly]
            .into_iter()
            .map(|g| {
                let scene = Scene::generated(g, a.triangles, a.width, a.height);
                (g.name().to_string(), scene)
            })
            .collect(),
    };
    let mut models = Vec::new();
    for (name, scene) in &scenes {
        let p = Prepared::new(scene, a.gpu.bvh_preset, format)?;
        let camera = scene.camera_or_default(&p.model);
        let path = dir.join(format!("{name}.dcb"));
        dcrt::blocks::file::write(&path, &p.blocks, &p.meta(scene, camera, a.width, a.height))?;
        eprintln!(
            "{name}: {} triangles, {:.1} MiB of blocks",
            p.model.triangles.len(),
            p.blocks.words.len() as f64 * 4.0 / 1048576.0
        );
        models.push((name.clone(), path));
    }
    let caches = a
        .cluster_caches
        .iter()
        .map(|c| match c.as_str() {
            "none" => Ok(None),
            other => CacheSize::parse(other).map(|_| Some(other.to_string())),
        })
        .collect::<dcrt::Result<Vec<_>>>()?;
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
        copy_threads: a.copy_threads.clone(),
        display_ranks: a.display_ranks,
        timeout_seconds: 600,
    };
    let rows = if a.display_only {
        Vec::new()
    } else {
        plan.frame_times()?
    };
    let display_plan = Plan {
        frames: a.display_frames,
        width: 1920,
        height: 1080,
        ..plan
    };
    let display = match models.first() {
        Some((_, m)) if !a.copy_threads.is_empty() => display_plan.display(m)?,
        _ => Vec::new(),
    };
    let _ = std::fs::remove_dir_all(&dir);
    if a.json {
        let all = serde_json::json!({"frame_times": rows, "display": display});
        println!("{}", serde_json::to_string_pretty(&all)?);
    } else {
        print!("{}", table(&rows));
        println!(
            "\ndisplay benchmark ({} ranks, 1920x1080, {} frames):",
            a.display_ranks, a.display_frames
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
    }
    Ok(())
}

fn prepare(a: PrepareArgs) -> Result<()> {
    check_writable(&a.output)?;
    let format = Format::new(a.block_size)?;
    let scene = Scene::load(&a.scene)?;
    let p = Prepared::new(&scene, a.bvh_preset, format)?;
    let camera = scene.camera_or_default(&p.model);
    let meta = p.meta(&scene, camera, scene.width, scene.height);
    // Write beside the target and rename, so a failed write never leaves a half file behind.
    let tmp = a.output.with_extension("dcb.partial");
    dcrt::blocks::file::write(&tmp, &p.blocks, &meta)?;
    std::fs::rename(&tmp, &a.output)
        .with_context(|| format!("{}: cannot rename into place", a.output.display()))?;
    eprintln!(
        "{} triangles, {} node + {} triangle blocks of {} bytes ({} MiB), BVH depth {}, wrote {}",
        p.model.triangles.len(),
        p.blocks.node_blocks,
        p.blocks.tri_blocks,
        format.block_bytes,
        p.blocks.bytes() >> 20,
        p.bvh.depth,
        a.output.display()
    );
    Ok(())
}

fn check_budget(b: u32) -> Result<()> {
    if !(1..=MAX_STEP_BUDGET).contains(&b) {
        bail!(
            "--step-budget {b} is out of range 1..={MAX_STEP_BUDGET} (lavapipe stops loops at 65,535)"
        );
    }
    Ok(())
}

/// Fails before any work if an output cannot be created, so no render is lost to a typo.
fn check_writable(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!(
            "{}: the output directory {} does not exist",
            path.display(),
            dir.display()
        );
    }
    Ok(())
}

fn info(adapter: Option<&str>) -> Result<()> {
    println!("adapters found:");
    for a in dcrt::gpu::adapters() {
        println!("  {}", dcrt::gpu::describe(&a.get_info()));
    }
    let gpu = Gpu::new(adapter)?;
    println!("using: {}", gpu.describe());
    let l = &gpu.limits;
    println!("limits:");
    println!(
        "  max_storage_buffer_binding_size {} MiB",
        l.max_storage_buffer_binding_size >> 20
    );
    println!("  max_buffer_size {} MiB", l.max_buffer_size >> 20);
    println!("  max_texture_dimension_2d {}", l.max_texture_dimension_2d);
    println!("  max_texture_array_layers {}", l.max_texture_array_layers);
    println!(
        "  max_compute_workgroups_per_dimension {}",
        l.max_compute_workgroups_per_dimension
    );
    println!(
        "  max_compute_invocations_per_workgroup {}",
        l.max_compute_invocations_per_workgroup
    );
    println!(
        "  max_storage_buffers_per_shader_stage {}",
        l.max_storage_buffers_per_shader_stage
    );
    println!("features: {:?}", gpu.features);
    // Cluster mode's MPI, when built in (the default `mpi` feature).
    #[cfg(feature = "mpi")]
    match mpi::environment::library_version() {
        Ok(v) => println!(
            "mpi: {}",
            v.trim_end_matches(char::from(0))
                .lines()
                .next()
                .unwrap_or("")
                .trim()
        ),
        Err(e) => println!("mpi: version unreadable ({e})"),
    }
    #[cfg(not(feature = "mpi"))]
    println!("mpi: not built in (build with the default `mpi` feature)");
    Ok(())
}

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

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

fn bench(a: BenchArgs) -> Result<()> {
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    check_image_size(a.width, a.height)?;
    check_budget(a.gpu.step_budget)?;
    if a.shading {
        if a.max_spp == 0 {
            bail!("--max-spp must be at least 1");
        }
        let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
        let small = |v: u32| if v == 1024 { 32 } else { v };
        let args = bench_shading::Args {
            width: small(a.width),
            height: small(a.height),
            triangles: if a.triangles == 1_000_000 {
                50_000
            } else {
                a.triangles
            },
            max_spp: a.max_spp,
            json: a.json,
            plot: a.plot.as_deref(),
        };
        return bench_shading::run(&gpu, &args);
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
        return bench_cluster(&a, format);
    }
    let model = scene.load_model()?;
    let camera = scene.camera_or_default(&model);
    let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
    if a.dc {
        return bench_dc(&a, &gpu, &scene, model, camera, format);
    }
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
            let mut tracer = prepared.tracer(&gpu, s)?;
            // Warm-up: pipeline compilation and first-touch of buffers.
            let (_, _) = render_frame(&mut tracer, &camera, a.width, a.height, scene.background)?;
            let mut times = Vec::new();
            let mut last = None;
            for _ in 0..a.runs {
                let (_, s) =
                    render_frame(&mut tracer, &camera, a.width, a.height, scene.background)?;
                times.push(s.seconds * 1e3);
                last = Some(s);
            }
            let s = last.unwrap_or_default();
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
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!("adapter   {}", report.adapter);
    println!(
        "scene     {} ({} triangles), {}x{}, median of {} runs after a warm-up",
        report.scene, report.triangles, report.width, report.height, report.runs
    );
    println!(
        "{:<9} {:<8} {:>10} {:>6} {:>12} {:>10} {:>10} {:>9} {:>9} {:>7} {:>7}",
        "preset",
        "store",
        "build ms",
        "depth",
        "trace ms",
        "min",
        "max",
        "Mrays/s",
        "steps/ray",
        "trace%",
        "shade%"
    );
    for r in &report.rows {
        println!(
            "{:<9} {:<8} {:>10.1} {:>6} {:>12.1} {:>10.1} {:>10.1} {:>9.2} {:>9.1} {:>7.0} {:>7.0}",
            r.preset,
            format!("{:?}", r.store).to_lowercase(),
            r.bvh_build_ms,
            r.bvh_depth,
            r.trace_ms_median,
            r.trace_ms_min,
            r.trace_ms_max,
            r.mrays_per_s,
            r.steps_per_ray,
            r.trace_share * 100.0,
            r.shade_share * 100.0
        );
    }
    Ok(())
}

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

fn bench_dc(
    a: &BenchArgs,
    gpu: &Gpu,
    scene: &Scene,
    model: dcrt::scene::Model,
    camera: dcrt::scene::Camera,
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
        let mut warm: Vec<dcrt::gpu::tracer::FrameStats> = Vec::new();
        let mut first_ms = 0.0;
        for i in 0..a.frames {
            let cam = camera.orbit(std::f64::consts::TAU * f64::from(i) / f64::from(a.frames));
            let (_, s) = render_frame(&mut tracer, &cam, a.width, a.height, scene.background)?;
            if i == 0 {
                first_ms = s.seconds * 1e3;
            } else {
                warm.push(s);
            }
        }
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
