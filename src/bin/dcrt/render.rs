//! `dcrt render`: the options checked before any work, then a cluster role under an MPI launcher,
//! or the frames of one process.

use crate::bench::Switches;
use crate::checks::check_budget;
use crate::{GpuArgs, ShadeArgs, settings};
use anyhow::{Context, Result, bail};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::dc::{CacheMap, CacheSize, Replicate};
use dcrt::files;
use dcrt::gpu::Gpu;
use dcrt::gpu::tracer::{Settings, Tracer};
use dcrt::output;
use dcrt::output::Aov;
use dcrt::progress::{Progress, say};
use dcrt::render::frames::{FramePlan, Role, View, hit_rate, run_images};
use dcrt::render::{DcOptions, Loaded, memory, mib};
use dcrt::scene::{Scene, check_image_size, pvcc};
use dcrt::shading::Shading;
use std::path::Path;
use std::path::PathBuf;

#[derive(Args)]
pub struct RenderArgs {
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
    /// Draw a colour legend (a scalar bar with the array's name and range) on the PNG, for each
    /// array whose values colour the image (`color_by`).
    #[arg(long)]
    legend: bool,
    /// The camera of a ParaView camera file (.pvcc, saved by ParaView's Adjust Camera dialog):
    /// position, focal point, view up, view angle, and parallel projection when set.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Off a terminal, print how far a frame is every this many seconds (a long render with
    /// many samples); on a terminal a progress bar shows it.
    #[arg(long, default_value_t = 5.0, allow_hyphen_values = true)]
    progress_every: f64,
    /// No progress bar and no progress lines.
    #[arg(long, short)]
    quiet: bool,
    #[command(flatten)]
    shade: ShadeArgs,
    #[command(flatten)]
    gpu: GpuArgs,
    #[command(flatten)]
    dc: DcArgs,
    #[command(flatten)]
    cluster: ClusterArgs,
    /// Under mpirun: write the run's figures (frame times, per-rank statistics) as JSON to this
    /// file.
    #[arg(long)]
    stats: Option<PathBuf>,
}

/// Options of cluster mode (under mpirun or srun with 2 ranks or more).
#[derive(Args, Clone)]
pub struct ClusterArgs {
    /// Threads the display copies received pixels into the frame with.
    #[arg(long, default_value_t = 2)]
    pub copy_threads: u32,
    /// Side in pixels of the balancer's large tiles.
    #[arg(long, default_value_t = 128)]
    pub tile: u32,
    /// Side of the smallest tiles the balancer splits them into toward the end of a frame.
    #[arg(long, default_value_t = 16)]
    pub min_tile: u32,
    /// Target size in bytes of a pixel message to the display.
    #[arg(long, default_value_t = 32 * 1024)]
    pub message_bytes: usize,
    /// Seconds any rank may wait (for a message, for its GPU) before the job is aborted.
    #[arg(long, default_value_t = 300)]
    pub timeout: u64,
}

impl ClusterArgs {
    /// Checked in one process too, so that a typo is not found only on the cluster.
    pub fn check(&self) -> Result<()> {
        if self.copy_threads == 0 || self.tile == 0 || self.min_tile == 0 || self.message_bytes == 0
        {
            bail!("--copy-threads, --tile, --min-tile and --message-bytes must be at least 1");
        }
        if self.timeout == 0 {
            bail!("--timeout must be at least 1 second");
        }
        Ok(())
    }
}

#[derive(Args, Clone)]
pub struct DcArgs {
    /// Split the model over N in-process ranks and render through a distributed cache.
    #[arg(long)]
    pub virtual_ranks: Option<u32>,
    /// The rank this process renders as (with --virtual-ranks).
    #[arg(long, default_value_t = 0)]
    rank: u32,
    /// Cache size: a fraction of the model (1/8), lines (64lines) or bytes (256MiB). Default 1/8
    /// with --virtual-ranks; under mpirun, giving it turns the distributed cache on.
    #[arg(long)]
    cache: Option<String>,
    /// How borrowed blocks map to cache lines (default lru: with the root block replicated, the
    /// fastest or tied in every sweep measured).
    #[arg(long, value_enum)]
    cache_map: Option<CacheMap>,
    /// Everything resident, no cache (the default without --virtual-ranks).
    #[arg(long, conflicts_with = "virtual_ranks")]
    replicate: bool,
    /// With a distributed cache: the blocks every rank holds besides its own. `nodes` costs the
    /// BVH's blocks on every rank (about a sixth of a model) and leaves only triangle blocks to
    /// fault.
    #[arg(long, value_enum, default_value_t = Replicate::Root)]
    replicate_blocks: Replicate,
}

impl DcArgs {
    pub fn options(&self) -> Result<Option<DcOptions>> {
        let Some(n) = self.virtual_ranks else {
            if self.replicate_blocks != Replicate::Root {
                bail!(
                    "--replicate-blocks {} needs a distributed cache: give --virtual-ranks N \
                     (under mpirun, --cache); without one every block is resident",
                    self.replicate_name()
                );
            }
            // One rank under mpirun takes the cluster's command line: it owns every block.
            let alone = dcrt::cluster::launched_ranks().is_none();
            if let Some(what) = self.cache_option().filter(|_| alone) {
                bail!(
                    "{what} needs a distributed cache: give --virtual-ranks N (under mpirun, \
                     --cache); without one every block is resident"
                );
            }
            return Ok(None);
        };
        if n == 0 {
            bail!("--virtual-ranks must be at least 1");
        }
        if self.rank >= n {
            bail!(
                "--rank {} is out of range: --virtual-ranks {n} gives ranks 0..{n}",
                self.rank
            );
        }
        dcrt::blocks::ranks::Ranks::new(n, self.rank)?;
        Ok(Some(DcOptions {
            ranks: n,
            rank: self.rank,
            cache: CacheSize::parse(self.cache.as_deref().unwrap_or("1/8"))?,
            map: self.map(),
            replicate: self.replicate_blocks,
        }))
    }

    /// The distributed cache of a job under mpirun: `--cache` turns it on.
    pub fn cluster_cache(&self) -> Result<Option<dcrt::cluster::CacheOptions>> {
        Ok(match &self.cache {
            Some(s) => Some(dcrt::cluster::CacheOptions {
                size: CacheSize::parse(s)?,
                map: self.map(),
                replicate: self.replicate_blocks,
            }),
            None if self.replicate_blocks != Replicate::Root => bail!(
                "--replicate-blocks {} needs --cache under mpirun: without a cache every rank \
                 holds the whole model",
                self.replicate_name()
            ),
            None if self.cache_map.is_some() => bail!(
                "--cache-map needs --cache under mpirun: without a cache every rank holds the \
                 whole model"
            ),
            None => None,
        })
    }

    fn map(&self) -> CacheMap {
        self.cache_map.unwrap_or(CacheMap::Lru)
    }

    /// The cache option given, if any (`--cache` first), for a refusal where no cache is made.
    fn cache_option(&self) -> Option<String> {
        match (&self.cache, self.cache_map) {
            (Some(c), _) => Some(format!("--cache {c}")),
            (None, Some(_)) => Some("--cache-map".into()),
            (None, None) => None,
        }
    }

    fn replicate_name(&self) -> String {
        format!("{:?}", self.replicate_blocks).to_lowercase()
    }
}

/// `dcrt render` runs with the switches off (`Switches::default()`); `dcrt bench job` runs the
/// same path with those it was given.
pub fn render(a: RenderArgs, sw: &Switches) -> Result<()> {
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
    if !(a.progress_every >= 0.0 && a.progress_every.is_finite()) {
        bail!(
            "--progress-every must be a number of seconds, 0 or more, got {}",
            a.progress_every
        );
    }
    // Options are checked before the scene is loaded.
    sw.shade
        .apply(a.shade.overrides())
        .apply(Shading::default())?;
    // Every output path is checked before the scene is loaded, so a run never fails at the end
    // over a path, and no output replaces an input (docs/ARCHITECTURE.md, Outputs).
    let mut outputs = vec![("PNG", a.output.as_path(), a.frames)];
    if let Some(exr) = &a.exr {
        outputs.push(("EXR", exr.as_path(), a.frames));
    }
    if let Some(stats) = &a.stats {
        outputs.push(("statistics", stats.as_path(), 1));
    }
    let mut inputs = Scene::input_files(&a.scene)?;
    inputs.extend(a.camera.clone());
    files::check_outputs(&outputs, &inputs)?;
    if let Some(dir) = &a.trace {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create the trace directory", dir.display()))?;
    }
    let format = Format::new(a.gpu.build.block_size)?;
    a.cluster.check()?;
    if let Some(k) = dcrt::cluster::launched_ranks().filter(|&k| k > 1) {
        return render_cluster(&a, sw, format, k);
    }
    if sw.display_bench {
        bail!(
            "--display-bench measures the display of a cluster: run it under mpirun with 2 or more ranks"
        );
    }
    one_process(&a, sw, format)
}

/// The frames of one process, replicated or as one virtual rank of a distributed cache: PNG (and
/// EXR) per frame, a line on stderr, traces and `--stats` when asked. Each file is written
/// atomically; if the run fails, the outputs of the frame it was on are removed and the
/// finished frames kept, so a failed run leaves nothing half done and loses no finished work.
fn one_process(a: &RenderArgs, sw: &Switches, format: Format) -> Result<()> {
    frames_of(a, sw, format).inspect_err(|_| say_kept(files::remove_written()))
}

/// After a failure: what the run keeps, if anything.
pub fn say_kept(kept: Option<String>) {
    if let Some(kept) = kept {
        dcrt::report!("note: the run failed {kept}");
    }
}

/// The distributed cache's options (checked first), then the model of `scene` with the camera of
/// the `--camera` file when given: what `render` and `view` open in one process.
pub fn open_model(
    scene: &Path,
    camera: Option<&Path>,
    gpu: &GpuArgs,
    dc: &DcArgs,
    format: Format,
) -> Result<(Option<DcOptions>, Loaded)> {
    let dc = dc.options()?;
    let camera = camera.map(pvcc::load_pvcc).transpose()?;
    let mut loaded = Loaded::open(scene, gpu.build.tree()?, format)?;
    if let Some(c) = camera {
        loaded.camera = c;
    }
    Ok((dc, loaded))
}

fn frames_of(a: &RenderArgs, sw: &Switches, format: Format) -> Result<()> {
    let (dc, loaded) = open_model(&a.scene, a.camera.as_deref(), &a.gpu, &a.dc, format)?;
    let legend = a
        .legend
        .then(|| dcrt::legend::Legend::new(&loaded.meshes.looks, loaded.background))
        .transpose()?;
    let mut report = Vec::new();
    let width = a.width.unwrap_or(loaded.width);
    let height = a.height.unwrap_or(loaded.height);
    check_image_size(width, height)?;
    let exr_channels = a.exr.as_ref().map_or(0, |_| memory::exr_channels(&a.aov));
    memory::check_image_with_exr(width, height, exr_channels, memory::available())?;
    let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
    dcrt::report!("adapter: {}", gpu.describe());
    let shading = sw.shade.apply(a.shade.overrides()).apply(loaded.shading)?;
    let s = Settings {
        shading,
        ..sw.tracer.apply(settings(&a.gpu))
    }
    .for_image(width, height);
    let mut tracer = loaded.tracer(&gpu, s, dc.as_ref())?;
    say_model(dc.as_ref(), &loaded, &tracer)?;
    // How far the render is: a bar over every frame's sample passes on a terminal; elsewhere a
    // long frame's line no more often than --progress-every; nothing with --quiet.
    let progress = Progress { quiet: a.quiet };
    let bar = progress.bar(u64::from(a.frames), "rendering");
    let frames_done = std::rc::Rc::new(std::cell::Cell::new(0u32));
    if bar.is_hidden() {
        let every = std::time::Duration::from_secs_f64(a.progress_every);
        let mut last = std::time::Instant::now();
        let quiet = a.quiet;
        tracer.set_progress(Some(Box::new(move |done, total| {
            if !quiet && done < total && last.elapsed() >= every {
                last = std::time::Instant::now();
                dcrt::report!("  {done} of {total} sample passes");
            }
        })));
    } else {
        let (bar, frames_done, frames) = (bar.clone(), frames_done.clone(), a.frames);
        tracer.set_progress(Some(Box::new(move |done, total| {
            bar.set_length(u64::from(frames) * total);
            bar.set_position(u64::from(frames_done.get()) * total + done);
        })));
    }
    let plan = FramePlan {
        frames: a.frames,
        view: View::Orbit(loaded.camera),
        role: Role::one_process(&tracer),
        trace_dir: a.trace.as_deref(),
    };
    let bg = loaded.background;
    run_images(
        &mut tracer,
        &plan,
        width,
        height,
        bg,
        &mut |i, frame, stats| {
            let numbered = |p: &Path| files::numbered(p, i, a.frames);
            // Kept only for --stats, and as the stats themselves: a JSON value per frame was
            // about 4 KiB, a leak in a long run (docs/ARCHITECTURE.md, Frame loop).
            if a.stats.is_some() {
                report.push(stats.clone());
            }
            let png = numbered(&a.output);
            output::write_png_legend(&png, frame, a.exposure, legend.as_ref())?;
            let exr = a.exr.as_deref().map(numbered);
            if let Some(exr) = &exr {
                output::write_exr(exr, frame, &a.aov)?;
            }
            let files: Vec<&Path> = [Some(png.as_path()), exr.as_deref()]
                .into_iter()
                .flatten()
                .collect();
            files::keep_frame(i, &files);
            frames_done.set(i + 1);
            say(
                &bar,
                format!(
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
                            ", {} fault rounds (at least {}), hit rate {:.3}, {} blocks fetched",
                            stats.fault_rounds,
                            stats.fault_round_bound,
                            hit_rate(stats),
                            stats.fetched_blocks
                        )
                    } else {
                        String::new()
                    },
                    png.display()
                ),
            );
            Ok(())
        },
    )?;
    bar.finish_and_clear();
    if let Some(path) = &a.stats {
        let frames: Vec<_> = report
            .iter()
            .enumerate()
            .map(|(i, s)| serde_json::json!({"frame": i, "frame_ms": s.seconds * 1e3, "stats": s}))
            .collect();
        let all =
            serde_json::json!({"ranks": 1, "width": width, "height": height, "frames": frames});
        files::write_bytes(path, all.to_string().as_bytes())?;
    }
    Ok(())
}

/// The model's line on stderr: replicated, or the rank's resident blocks and cache.
pub fn say_model(dc: Option<&DcOptions>, loaded: &Loaded, tracer: &Tracer<'_>) -> Result<()> {
    match dc {
        Some(o) => {
            let m = o.memory(loaded.block_count(), loaded.node_blocks(), loaded.format())?;
            dcrt::report!(
                "rank {} of {}: {:.1} MiB resident + {:.1} MiB cache ({} lines, {:?}; blocks in \
                 {}) of a {:.1} MiB model",
                o.rank,
                o.ranks,
                mib(m.resident_bytes),
                mib(m.cache_bytes),
                o.lines(loaded.block_count(), loaded.format()),
                o.map,
                tracer.store_description(),
                mib(loaded.model_bytes())
            );
        }
        None => dcrt::report!("replicated: {:.1} MiB of blocks", mib(loaded.model_bytes())),
    }
    Ok(())
}

/// `render` under an MPI launcher with `k` > 1 ranks: this process's role of the cluster.
fn render_cluster(a: &RenderArgs, sw: &Switches, format: Format, k: u32) -> Result<()> {
    if a.dc.virtual_ranks.is_some() {
        bail!("--virtual-ranks is for one process; under mpirun the {k} ranks are the ranks");
    }
    let c = &a.cluster;
    let cache = a.dc.cluster_cache()?;
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
        settings: sw.tracer.apply(settings(&a.gpu)),
        shade: sw.shade.apply(a.shade.overrides()),
        exposure: a.exposure,
        build: a.gpu.build.tree()?,
        format,
        cache,
        copy_threads: c.copy_threads,
        tile: c.tile,
        min_tile: c.min_tile,
        message_bytes: c.message_bytes,
        timeout: std::time::Duration::from_secs(c.timeout),
        display_bench: sw.display_bench,
        live: false,
        stats: a.stats.clone(),
        legend: a.legend,
        camera: a
            .camera
            .as_deref()
            .map(dcrt::scene::pvcc::load_pvcc)
            .transpose()?,
    };
    // A failed job leaves none of the frames this rank wrote, as in one process.
    dcrt::cluster::run(&opts).inspect_err(|_| say_kept(dcrt::files::remove_written()))?;
    Ok(())
}
