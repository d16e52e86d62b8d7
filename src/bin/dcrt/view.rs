//! `dcrt view`: the model in a browser, the camera under the mouse (docs/ARCHITECTURE.md, Live
//! view). In one process the model and tracer are set up as `render` sets them up; under mpirun
//! the ranks start as a cluster render's do and the display rank serves. The view itself is
//! `dcrt::view`.

use crate::checks::check_budget;
use crate::render::{ClusterArgs, DcArgs, open_model, say_model};
use crate::{GpuArgs, ShadeArgs, settings};
use anyhow::{Result, bail};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::gpu::Gpu;
use dcrt::gpu::tracer::Settings;
use dcrt::scene::check_image_size;
use dcrt::shading::{MAX_SPP, Shading};
use std::net::IpAddr;
use std::path::PathBuf;

#[derive(Args)]
pub struct ViewArgs {
    /// Scene file (TOML) or prepared block file (.dcb).
    scene: PathBuf,
    /// Port to listen on; 0 takes a free one (the printed URL names it).
    #[arg(long, default_value_t = 8080)]
    port: u16,
    /// Address to listen on. Off loopback every request needs the token the printed URL carries.
    #[arg(long, default_value = "127.0.0.1")]
    bind: IpAddr,
    /// Width of the full frame (default: the scene's).
    #[arg(long)]
    width: Option<u32>,
    /// Height of the full frame (default: the scene's).
    #[arg(long)]
    height: Option<u32>,
    /// The first camera, from a ParaView camera file (.pvcc).
    #[arg(long)]
    camera: Option<PathBuf>,
    #[command(flatten)]
    shade: ShadeArgs,
    #[command(flatten)]
    gpu: GpuArgs,
    #[command(flatten)]
    dc: DcArgs,
    #[command(flatten)]
    cluster: ClusterArgs,
}

pub fn view(a: ViewArgs) -> Result<()> {
    check_budget(a.gpu.step_budget)?;
    a.shade.overrides().apply(Shading::default())?;
    a.cluster.check()?;
    if let Some(k) = dcrt::cluster::launched_ranks().filter(|&k| k > 1) {
        return view_cluster(&a, k);
    }
    let format = Format::new(a.gpu.build.block_size)?;
    let (dc, loaded) = open_model(&a.scene, a.camera.as_deref(), &a.gpu, &a.dc, format)?;
    let width = a.width.unwrap_or(loaded.width);
    let height = a.height.unwrap_or(loaded.height);
    check_image_size(width, height)?;
    dcrt::render::memory::check_image(width, height)?;
    let gpu = Gpu::new(a.gpu.adapter.as_deref())?;
    dcrt::report!("adapter: {}", gpu.describe());
    let shading = a.shade.overrides().apply(loaded.shading)?;
    let s = Settings {
        shading: shading.widest_mode(),
        ..settings(&a.gpu)
    }
    .for_image(width, height);
    let mut tracer = loaded.tracer(&gpu, Settings { shading, ..s }, dc.as_ref())?;
    say_model(dc.as_ref(), &loaded, &tracer)?;
    let opts = options(&a, loaded.camera);
    let still = dcrt::view::Still {
        width,
        height,
        shading,
    };
    let mut frames = dcrt::view::OneProcess {
        tracer: &mut tracer,
        background: loaded.background,
    };
    dcrt::view::run(&mut frames, &opts, &still, &mut say_url)?;
    Ok(())
}

fn options(a: &ViewArgs, camera: dcrt::scene::Camera) -> dcrt::view::Options {
    dcrt::view::Options {
        bind: a.bind,
        port: a.port,
        camera,
        max_spp: MAX_SPP,
    }
}

fn say_url(url: &str, addr: std::net::SocketAddr) {
    dcrt::report!("view: listening on {addr}");
    if addr.ip().is_unspecified() {
        dcrt::report!(
            "view: open {url} with this host's name or address in place of {}",
            addr.ip()
        );
    } else {
        dcrt::report!("view: open {url}");
    }
}

/// Under mpirun: every rank's role of a live view; rank 0 serves.
#[cfg(feature = "mpi")]
fn view_cluster(a: &ViewArgs, k: u32) -> Result<()> {
    if a.dc.virtual_ranks.is_some() {
        bail!("--virtual-ranks is for one process; under mpirun the {k} ranks are the ranks");
    }
    let c = &a.cluster;
    let opts = dcrt::cluster::Options {
        input: a.scene.clone(),
        output: PathBuf::new(),
        exr: None,
        aovs: Vec::new(),
        width: a.width,
        height: a.height,
        frames: 1,
        trace: None,
        adapter: a.gpu.adapter.clone(),
        settings: settings(&a.gpu),
        shade: a.shade.overrides(),
        exposure: 0.0,
        build: a.gpu.build.tree()?,
        format: Format::new(a.gpu.build.block_size)?,
        cache: a.dc.cluster_cache()?,
        copy_threads: c.copy_threads,
        tile: c.tile,
        min_tile: c.min_tile,
        message_bytes: c.message_bytes,
        timeout: std::time::Duration::from_secs(c.timeout),
        display_bench: false,
        live: true,
        stats: None,
        legend: false,
        camera: a
            .camera
            .as_deref()
            .map(dcrt::scene::pvcc::load_pvcc)
            .transpose()?,
    };
    dcrt::cluster::view(&opts, &mut |display| {
        let (width, height) = display.image();
        dcrt::report!(
            "view: {width}x{height}, {} render ranks",
            display.render_ranks()
        );
        let still = dcrt::view::Still {
            width,
            height,
            shading: display.shading(),
        };
        let opts = options(a, display.home());
        dcrt::view::run(display, &opts, &still, &mut say_url)
    })?;
    Ok(())
}

#[cfg(not(feature = "mpi"))]
fn view_cluster(_: &ViewArgs, k: u32) -> Result<()> {
    bail!(
        "started by an MPI launcher with {k} ranks, but this dcrt was built without the `mpi` feature"
    )
}
