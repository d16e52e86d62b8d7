//! `dcrt bench rays`: BVH build time and ray throughput per obvhs preset, block store and
//! shading mode, with the traversal's counts (steps, node visits per node block, blocks
//! entered), and optionally a native peer tracing the same camera rays in the same run (`--peer
//! embree`).

use super::{
    ReportArgs, SceneArgs, Table, block_count_frame, emit, format_of, frame_stats, median,
};
use crate::{GpuArgs, settings};
use anyhow::{Context, Result, bail};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::bvh::{Build, Preset};
use dcrt::gpu::Gpu;
use dcrt::gpu::shaders::Store;
use dcrt::gpu::tracer::{Settings, Tracer};
use dcrt::progress::Progress;
use dcrt::render::Prepared;
use dcrt::render::frames::View;
use dcrt::scene::{Camera, Model, Scene};
use dcrt::shading::{Mode, Shading};
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct RaysArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Timed frames after one warm-up frame; the median is reported.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Also build and trace with every obvhs preset, side by side.
    #[arg(long)]
    bvh_presets: bool,
    /// Also build and trace with each of these node costs (`--bvh-node-cost`), side by side:
    /// the trade of tree size for traversal steps.
    #[arg(long, value_delimiter = ',')]
    bvh_node_costs: Vec<f32>,
    /// Trace with both block stores (texture, buffer), side by side.
    #[arg(long)]
    stores: bool,
    /// Shading modes to measure rays/s in (primary and secondary rays over the frame time);
    /// `ao` traces 4 rays per hit and `path` at most 3 bounces, to keep a frame short.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "cast")]
    modes: Vec<Mode>,
    /// A peer renderer run beside dcrt in the same run: `embree` traces the same camera rays on
    /// every core, in `ao` and `path` modes the same kinds and counts of secondary rays too, and
    /// reports both rates per mode, their ratio and how often the camera rays' hits agree
    /// (scripts/embree-peer.sh; no peer for `shadows`).
    #[arg(long, value_enum)]
    peer: Option<Peer>,
    #[command(flatten)]
    report: ReportArgs,
    #[command(flatten)]
    gpu: GpuArgs,
}

/// A peer renderer run beside dcrt in the same bench run, on the same cores.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Peer {
    /// Embree 3 (`rtcIntersect8` and `rtcOccluded8` packets, a thread per core) on the same
    /// camera rays, through `scripts/embree-peer.sh`: the throughput of cast, AO and path rays.
    Embree,
}

/// `bench rays`: a block file traced as it is, else the scene's model built with each preset.
pub fn bench(a: &RaysArgs) -> Result<()> {
    let format = a.scene.check(&a.gpu)?;
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    if let Some(path) = a.scene.block_file() {
        let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
        return run_file(a, &gpu, path);
    }
    let (scene, model, camera) = a.scene.load()?;
    let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
    run(a, &gpu, &scene, model, camera, format)
}

/// The bench's AO rays per hit and path bounces: enough secondary rays to measure, few enough
/// that a 1024x1024 frame stays short on a CPU adapter.
const BENCH_AO_RAYS: u32 = 4;
const BENCH_MAX_DEPTH: u32 = 3;

#[derive(serde::Serialize)]
struct BenchRow {
    preset: String,
    /// The build's node cost (`--bvh-node-cost`; 0 for a block file's tree) and the model's
    /// blocks in MiB.
    node_cost: f32,
    model_mib: f64,
    store: Store,
    mode: Mode,
    bvh_build_ms: f64,
    bvh_depth: u32,
    trace_ms_median: f64,
    trace_ms_min: f64,
    trace_ms_max: f64,
    /// Primary and secondary rays of one frame, over its median time.
    rays: u64,
    mrays_per_s: f64,
    /// Per ray of `rays` (primary rays culled by the model's box count, with 0 steps).
    steps_per_ray: f64,
    tri_tests_per_ray: f64,
    /// Inner-node visits per node block entered, and node and triangle blocks entered per ray
    /// (an entry is a read from another block than the ray's previous one of its kind).
    nodes_per_node_block: f64,
    node_blocks_per_ray: f64,
    tri_blocks_per_ray: f64,
    /// Steps over the loop iterations the trace's lanes ran, busy or idle (`FrameStats::
    /// lane_steps`, from the block-count frame): the share of lanes doing work.
    lane_use: f64,
    /// Of the last run: share of the frame in traversal rounds (submission, waits and host work
    /// included), and in shade + readback.
    trace_share: f64,
    shade_share: f64,
    /// Of the last run: share of the frame the GPU spent in traversal rounds, from its
    /// timestamps (first trace pass to last `args` pass of each check); 0 without timestamps.
    gpu_share: f64,
}

#[derive(Clone, serde::Serialize, serde::Deserialize)]
struct PeerReport {
    peer: String,
    /// The shading mode whose rays it traced (`cast`, `ao`, `path`).
    mode: String,
    threads: u32,
    build_ms: f64,
    trace_ms_median: f64,
    trace_ms_min: f64,
    trace_ms_max: f64,
    /// Rays traced in a frame, camera and secondary.
    rays: u64,
    mrays_per_s: f64,
    /// dcrt's rate in this mode (the main preset and store) over the peer's.
    #[serde(default)]
    ratio: f64,
    /// Pixels where dcrt and the peer agree on hit or miss and on the primitive id; pixels where
    /// they agree on hit or miss.
    #[serde(default)]
    hit_agreement: f64,
    #[serde(default)]
    hit_miss_agreement: f64,
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
    steps_per_ray: f64,
    nodes_per_node_block: f64,
    node_blocks_per_ray: f64,
    tri_blocks_per_ray: f64,
    lane_use: f64,
    /// The peer on the first mode's rays (the main row's), and on each mode it has.
    peer: Option<PeerReport>,
    peers: Vec<PeerReport>,
    rows: Vec<BenchRow>,
}

/// The block stores and shading modes each tree is measured with.
fn stores_and_modes(a: &RaysArgs) -> (Vec<Store>, Vec<Mode>) {
    let stores = if a.stores {
        Store::ALL.to_vec()
    } else {
        vec![a.gpu.store]
    };
    let modes = if a.modes.is_empty() {
        vec![Mode::Cast]
    } else {
        a.modes.clone()
    };
    (stores, modes)
}

fn shading_for(mode: Mode) -> Shading {
    Shading {
        mode,
        ao_rays: BENCH_AO_RAYS,
        max_depth: BENCH_MAX_DEPTH,
        ..Shading::default()
    }
}

fn run(
    a: &RaysArgs,
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
        vec![a.gpu.build.bvh_preset]
    };
    let main = a.gpu.build.tree()?;
    let mut costs = vec![main.node_cost];
    for &c in &a.bvh_node_costs {
        if !costs.contains(&crate::node_cost("--bvh-node-costs", c)?) {
            costs.push(c);
        }
    }
    let builds: Vec<Build> = presets
        .iter()
        .flat_map(|&preset| {
            costs
                .iter()
                .map(move |&node_cost| Build { preset, node_cost })
        })
        .collect();
    let mut rows = Vec::new();
    let (stores, modes) = stores_and_modes(a);
    let mut peer_ids = None;
    let bar = Progress {
        quiet: a.report.quiet,
    }
    .bar(
        (builds.len() * stores.len() * modes.len()) as u64,
        "bench rows",
    );
    for build in builds {
        let prepared = Prepared::from_model(model.clone(), build, format, 0.0)?;
        let tree = Tree {
            name: format!("{:?}", build.preset).to_lowercase(),
            node_cost: build.node_cost,
            model_mib: prepared.blocks.bytes() as f64 / (1u64 << 20) as f64,
            build_ms: prepared.bvh.build_time.as_secs_f64() * 1e3,
            depth: prepared.bvh.depth,
        };
        for &store in &stores {
            let s = Settings {
                store,
                ..settings(&a.gpu)
            };
            let mut tracer = prepared.tracer(gpu, s)?;
            for &mode in &modes {
                tracer.set_shading(shading_for(mode))?;
                bar.inc(1);
                rows.push(measure(
                    a,
                    &mut tracer,
                    scene.background,
                    camera,
                    &tree,
                    store,
                    mode,
                )?);
            }
            if a.peer.is_some() && build == main && store == a.gpu.store {
                tracer.set_shading(shading_for(Mode::Cast))?;
                let (frame, _) = tracer.render(
                    &camera.basis(a.scene.width, a.scene.height),
                    scene.background,
                )?;
                peer_ids = Some(frame.pixels.iter().map(|p| p.id).collect::<Vec<u32>>());
            }
        }
    }
    bar.finish_and_clear();
    let main_row = rows
        .iter()
        .find(|r| {
            r.preset == format!("{:?}", main.preset).to_lowercase()
                && r.node_cost == main.node_cost
                && r.store == a.gpu.store
                && r.mode == modes[0]
        })
        .unwrap_or(&rows[0]);
    let mut peers = Vec::new();
    if let (Some(Peer::Embree), Some(ids)) = (a.peer, peer_ids) {
        let sun = camera.basis(a.scene.width, a.scene.height).key_light();
        for &mode in &modes {
            let Some(line) = peer_mode(mode, sun) else {
                dcrt::report!(
                    "--peer embree: no peer for {} rays; their row stands alone",
                    mode.name()
                );
                continue;
            };
            let mut p = embree(a, &model, &camera, &line, &ids)?;
            let row = rows.iter().find(|r| {
                r.preset == main_row.preset
                    && r.node_cost == main_row.node_cost
                    && r.store == main_row.store
                    && r.mode == mode
            });
            p.ratio = row.map_or(f64::NAN, |r| r.mrays_per_s) / p.mrays_per_s;
            peers.push(p);
        }
    }
    let peer = peers.first().filter(|p| p.mode == modes[0].name()).cloned();
    let report = BenchReport {
        adapter: gpu.describe(),
        scene: scene.path.display().to_string(),
        triangles: model.triangles.len(),
        width: a.scene.width,
        height: a.scene.height,
        runs: a.runs,
        bvh_preset: main_row.preset.clone(),
        bvh_build_ms: main_row.bvh_build_ms,
        trace_ms_median: main_row.trace_ms_median,
        mrays_per_s: main_row.mrays_per_s,
        steps_per_ray: main_row.steps_per_ray,
        nodes_per_node_block: main_row.nodes_per_node_block,
        node_blocks_per_ray: main_row.node_blocks_per_ray,
        tri_blocks_per_ray: main_row.tri_blocks_per_ray,
        lane_use: main_row.lane_use,
        peer,
        peers,
        rows: Vec::new(),
    };
    let report = BenchReport { rows, ..report };
    emit(a.report.json, &report, print)
}

/// The tree a row traces: the preset it was built with (or `file`) and its node cost, the
/// model's size, its build time and depth.
struct Tree {
    name: String,
    node_cost: f32,
    model_mib: f64,
    build_ms: f64,
    depth: u32,
}

/// A prepared block file traced as it is (its tree fixed, so no presets and no peer), per store
/// and mode: the same rows as a scene's, its file name as the preset.
fn run_file(a: &RaysArgs, gpu: &Gpu, path: &Path) -> Result<()> {
    if a.bvh_presets
        || !a.bvh_node_costs.is_empty()
        || a.peer.is_some()
        || a.gpu.build.tree()? != dcrt::bvh::Build::default()
        || format_of(&a.gpu.build)? != Format::default()
    {
        bail!(
            "{}: a block file holds its BVH and blocks; --bvh-preset(s), --bvh-node-cost(s), \
             --block-size and --peer need a scene",
            path.display()
        );
    }
    let loaded = dcrt::render::Loaded::from_dcb(path, None)?;
    let tree = Tree {
        name: "file".into(),
        node_cost: 0.0,
        // The file's size: its blocks and a small header.
        model_mib: std::fs::metadata(path)?.len() as f64 / (1u64 << 20) as f64,
        build_ms: 0.0,
        depth: loaded.depth,
    };
    let (stores, modes) = stores_and_modes(a);
    let mut rows = Vec::new();
    for &store in &stores {
        let s = Settings {
            store,
            ..settings(&a.gpu)
        };
        let mut tracer = loaded.tracer(gpu, s, None)?;
        for &mode in &modes {
            tracer.set_shading(shading_for(mode))?;
            rows.push(measure(
                a,
                &mut tracer,
                loaded.background,
                loaded.camera,
                &tree,
                store,
                mode,
            )?);
        }
    }
    let main = &rows[0];
    let report = BenchReport {
        adapter: gpu.describe(),
        scene: path.display().to_string(),
        triangles: loaded.triangles as usize,
        width: a.scene.width,
        height: a.scene.height,
        runs: a.runs,
        bvh_preset: main.preset.clone(),
        bvh_build_ms: 0.0,
        trace_ms_median: main.trace_ms_median,
        mrays_per_s: main.mrays_per_s,
        steps_per_ray: main.steps_per_ray,
        nodes_per_node_block: main.nodes_per_node_block,
        node_blocks_per_ray: main.node_blocks_per_ray,
        tri_blocks_per_ray: main.tri_blocks_per_ray,
        lane_use: main.lane_use,
        peer: None,
        peers: Vec::new(),
        rows: Vec::new(),
    };
    emit(a.report.json, &BenchReport { rows, ..report }, print)
}

/// One row: a warm-up frame (pipeline compilation, first touch of buffers), then `--runs`.
fn measure(
    a: &RaysArgs,
    tracer: &mut Tracer<'_>,
    background: [f32; 3],
    camera: Camera,
    tree: &Tree,
    store: Store,
    mode: Mode,
) -> Result<BenchRow> {
    let frames = u32::try_from(a.runs).map_or(u32::MAX, |r| r.saturating_add(1));
    let size = (a.scene.width, a.scene.height);
    let runs = frame_stats(tracer, View::Fixed(camera), frames, size, background)?;
    let mut times: Vec<f64> = runs[1..].iter().map(|s| s.seconds * 1e3).collect();
    let s = runs.last().cloned().unwrap_or_default();
    let counted = block_count_frame(tracer, camera, size, background)?;
    let med = median(&mut times);
    let rays = s.rays + s.secondary_rays;
    let per_ray = |v: u64| v as f64 / rays.max(1) as f64;
    Ok(BenchRow {
        preset: tree.name.clone(),
        node_cost: tree.node_cost,
        model_mib: tree.model_mib,
        store,
        mode,
        bvh_build_ms: tree.build_ms,
        bvh_depth: tree.depth,
        trace_ms_median: med,
        trace_ms_min: times[0],
        trace_ms_max: times[times.len() - 1],
        rays,
        mrays_per_s: rays as f64 / (med * 1e-3) / 1e6,
        steps_per_ray: per_ray(s.steps),
        tri_tests_per_ray: per_ray(s.tri_tests),
        nodes_per_node_block: counted.node_visits as f64 / counted.block_entries.max(1) as f64,
        node_blocks_per_ray: per_ray(counted.block_entries),
        tri_blocks_per_ray: per_ray(counted.tri_block_entries),
        lane_use: counted.steps as f64 / counted.lane_steps.max(1) as f64,
        trace_share: s.trace_seconds / s.seconds,
        shade_share: s.shade_seconds / s.seconds,
        gpu_share: s.gpu_seconds / s.seconds,
    })
}

/// The peer script: `DCRT_EMBREE_PEER`, else `scripts/embree-peer.sh` under the current
/// directory, else in the source tree the binary was built from.
fn peer_script() -> Result<PathBuf> {
    if let Some(p) = std::env::var_os("DCRT_EMBREE_PEER") {
        return Ok(PathBuf::from(p));
    }
    let candidates = [
        PathBuf::from("scripts/embree-peer.sh"),
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/embree-peer.sh"),
    ];
    candidates
        .into_iter()
        .find(|p| p.is_file())
        .context("--peer embree: scripts/embree-peer.sh not found (run from the source tree or set DCRT_EMBREE_PEER)")
}

/// The peer's mode line (scripts/embree_peer.c) for the rays dcrt traces in `mode` with the
/// bench's shading (`shading_for`), `sun` the direction towards the sun; `None` for shadows,
/// which the peer does not trace.
fn peer_mode(mode: Mode, sun: [f32; 3]) -> Option<String> {
    let sh = shading_for(mode);
    match mode {
        Mode::Cast => Some("cast".into()),
        Mode::Ao => Some(format!("ao {} {:e}", sh.ao_rays, sh.ao_distance)),
        // No sun, no sun rays: the peer skips a sun whose direction is zero.
        Mode::Path => {
            let sun = if sh.sun_on() { sun } else { [0.0; 3] };
            Some(format!(
                "path {} {:e} {:e} {:e}",
                sh.max_depth, sun[0], sun[1], sun[2]
            ))
        }
        Mode::Shadows => None,
    }
}

/// Writes the model, the camera and the peer's `mode` line to a temporary folder, runs the
/// Embree peer on it and compares its camera rays' primitive ids with dcrt's (`ids`, one per
/// pixel).
fn embree(
    a: &RaysArgs,
    model: &Model,
    camera: &Camera,
    mode: &str,
    ids: &[u32],
) -> Result<PeerReport> {
    let script = peer_script()?;
    let dir = std::env::temp_dir().join(format!("dcrt-peer-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let result = (|| {
        let n = u32::try_from(model.triangles.len()).context("too many triangles for the peer")?;
        let mut mesh = Vec::with_capacity(4 + model.triangles.len() * 36);
        mesh.extend_from_slice(&n.to_le_bytes());
        for v in model.triangles.iter().flatten().flatten() {
            mesh.extend_from_slice(&v.to_le_bytes());
        }
        std::fs::write(dir.join("mesh.bin"), mesh)?;
        let b = camera.basis(a.scene.width, a.scene.height);
        let v = |x: [f32; 3]| format!("{:e} {:e} {:e}", x[0], x[1], x[2]);
        let cam = format!(
            "{} {} {}\n{}\n{}\n{}\n{}\n{mode}\n",
            a.scene.width,
            a.scene.height,
            a.runs,
            v(b.origin),
            v(b.forward),
            v(b.right),
            v(b.up)
        );
        std::fs::write(dir.join("camera.txt"), cam)?;
        let out = std::process::Command::new("bash")
            .arg(&script)
            .arg(&dir)
            .stderr(std::process::Stdio::inherit())
            .output()
            .with_context(|| format!("running {}", script.display()))?;
        if !out.status.success() {
            bail!("{} failed ({})", script.display(), out.status);
        }
        let line = String::from_utf8_lossy(&out.stdout);
        let mut p: PeerReport = serde_json::from_str(line.trim())
            .with_context(|| format!("{}: unexpected output {line:?}", script.display()))?;
        let hits = std::fs::read(dir.join("hits.bin"))?;
        if hits.len() != ids.len() * 4 {
            bail!(
                "{}: {} bytes of hits for {} pixels",
                script.display(),
                hits.len(),
                ids.len()
            );
        }
        let theirs = hits
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]));
        let (mut same, mut same_kind) = (0u64, 0u64);
        for (&mine, other) in ids.iter().zip(theirs) {
            same += u64::from(mine == other);
            same_kind += u64::from((mine == u32::MAX) == (other == u32::MAX));
        }
        p.hit_agreement = same as f64 / ids.len() as f64;
        p.hit_miss_agreement = same_kind as f64 / ids.len() as f64;
        Ok(p)
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn print(report: &BenchReport) {
    println!("adapter   {}", report.adapter);
    println!(
        "scene     {} ({} triangles), {}x{}, median of {} runs after a warm-up",
        report.scene, report.triangles, report.width, report.height, report.runs
    );
    let t = Table(&[
        ("preset", -9),
        ("node", 5),
        ("MiB", 6),
        ("store", -8),
        ("mode", -7),
        ("build ms", 9),
        ("depth", 5),
        ("trace ms", 9),
        ("min", 8),
        ("max", 8),
        ("Mrays/s", 8),
        ("steps/ray", 9),
        ("nodes/blk", 9),
        ("nblk/ray", 8),
        ("tblk/ray", 8),
        ("lanes%", 6),
        ("trace%", 6),
        ("shade%", 6),
        ("gpu%", 5),
    ]);
    t.header();
    for r in &report.rows {
        t.row(&[
            r.preset.clone(),
            format!("{}", r.node_cost),
            format!("{:.1}", r.model_mib),
            format!("{:?}", r.store).to_lowercase(),
            format!("{:?}", r.mode).to_lowercase(),
            format!("{:.1}", r.bvh_build_ms),
            r.bvh_depth.to_string(),
            format!("{:.1}", r.trace_ms_median),
            format!("{:.1}", r.trace_ms_min),
            format!("{:.1}", r.trace_ms_max),
            format!("{:.3}", r.mrays_per_s),
            format!("{:.1}", r.steps_per_ray),
            format!("{:.2}", r.nodes_per_node_block),
            format!("{:.2}", r.node_blocks_per_ray),
            format!("{:.2}", r.tri_blocks_per_ray),
            format!("{:.0}", r.lane_use * 100.0),
            format!("{:.0}", r.trace_share * 100.0),
            format!("{:.0}", r.shade_share * 100.0),
            format!("{:.0}", r.gpu_share * 100.0),
        ]);
    }
    for p in &report.peers {
        println!(
            "peer      {} on {} threads, {}: build {:.1} ms, trace {:.1} ms (min {:.1}, max {:.1}), \
             {:.3} Mrays/s",
            p.peer,
            p.threads,
            p.mode,
            p.build_ms,
            p.trace_ms_median,
            p.trace_ms_min,
            p.trace_ms_max,
            p.mrays_per_s
        );
        println!(
            "ratio     dcrt / peer = {:.3} ({} rays); camera rays' hits agree on {:.4} of pixels \
             (hit or miss: {:.4})",
            p.ratio, p.mode, p.hit_agreement, p.hit_miss_agreement
        );
    }
}
