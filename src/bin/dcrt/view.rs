//! `dcrt view`: the model in a browser, the camera under the mouse (docs/ARCHITECTURE.md, Live
//! view). The model and tracer are set up as `render` sets them up in one process; the view
//! itself is `dcrt::view`.

use crate::checks::check_budget;
use crate::render::{DcArgs, open_model, say_model};
use crate::{GpuArgs, ShadeArgs, settings};
use anyhow::{Result, bail};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::gpu::Gpu;
use dcrt::gpu::tracer::Settings;
use dcrt::scene::check_image_size;
use dcrt::shading::{MAX_SPP, Mode, Shading};
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
}

pub fn view(a: ViewArgs) -> Result<()> {
    check_budget(a.gpu.step_budget)?;
    a.shade.overrides().apply(Shading::default())?;
    if let Some(k) = dcrt::cluster::launched_ranks().filter(|&k| k > 1) {
        bail!(
            "dcrt view runs in one process for now: under an MPI launcher with {k} ranks it \
             has no display rank to serve from; run it without mpirun"
        );
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
    // Batches sized for the mode with the most secondary rays a pixel, so that a client may
    // switch to any mode.
    let mut widest = shading;
    for mode in [Mode::Cast, Mode::Shadows, Mode::Ao, Mode::Path] {
        let mut s = shading;
        s.mode = mode;
        if s.fan() > widest.fan() {
            widest = s;
        }
    }
    let s = Settings {
        shading: widest,
        ..settings(&a.gpu)
    }
    .for_image(width, height);
    let mut tracer = loaded.tracer(&gpu, Settings { shading, ..s }, dc.as_ref())?;
    say_model(dc.as_ref(), &loaded, &tracer)?;
    let opts = dcrt::view::Options {
        bind: a.bind,
        port: a.port,
        camera: loaded.camera,
        max_spp: MAX_SPP,
    };
    let still = dcrt::view::Still {
        width,
        height,
        background: loaded.background,
        shading,
    };
    dcrt::view::run(&mut tracer, &opts, &still, &mut |url, addr| {
        dcrt::report!("view: listening on {addr}");
        if addr.ip().is_unspecified() {
            dcrt::report!(
                "view: open {url} with this host's name or address in place of {}",
                addr.ip()
            );
        } else {
            dcrt::report!("view: open {url}");
        }
    })?;
    Ok(())
}
