//! `dcrt view` (docs/ARCHITECTURE.md, Live view): the frames in a browser as they are made, the
//! camera under the user's hand, from one process or from the display rank of an mpirun job.
//! Three kinds of thread: the caller's, which makes the frames (`producer`, through the tracer
//! it owns or the render ranks, `cluster`); an encoder, which turns the newest frame into JPEG;
//! the server's (`server`, axum on tokio), which serve the page, the API and the WebSockets.
//! They share only `state::Shared`, where each thing is kept in its newest version.

pub mod camera;
#[cfg(feature = "mpi")]
mod cluster;
mod producer;
pub mod server;
pub mod state;

pub use producer::{Figures, Frames, Made, OneProcess, Share, Still, TARGET_FPS};

use crate::error::{Error, Result};
use crate::scene::Camera;
use state::{LiveFrame, Shared, Wish};
use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;

/// JPEG quality of the frames sent to the page (`jpeg-encoder`, its SIMD paths chosen at run
/// time: 13 ms for 1920x1080 where `image`'s encoder took 50, docs/benchmarks.md).
pub const JPEG_QUALITY: u8 = 85;

/// Where the view listens and what it shows first.
pub struct Options {
    pub bind: IpAddr,
    /// 0: a free port, which the printed URL names.
    pub port: u16,
    pub camera: Camera,
    /// The most samples per pixel a client may ask for.
    pub max_spp: u32,
}

/// A random token of 128 bits, in hex.
fn random_token() -> Result<String> {
    let mut b = [0u8; 16];
    getrandom::fill(&mut b)
        .map_err(|e| Error::Internal(format!("no random numbers for the view's token: {e}")))?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// The URL to open: the bound address (a host's name or address for an unspecified one), with
/// the token when there is one.
pub fn url(addr: SocketAddr, token: Option<&str>) -> String {
    let q = token.map(|t| format!("?token={t}")).unwrap_or_default();
    format!("http://{addr}/{q}")
}

/// Serves the view and makes its frames on this thread (which owns the tracer, or at the display
/// rank the MPI calls) until an error; a signal ends the process (`files::remove_on_interrupt`).
/// `listening` is told the URL once the port is open.
pub fn run(
    frames: &mut dyn Frames,
    opts: &Options,
    still: &Still,
    listening: &mut dyn FnMut(&str, SocketAddr),
) -> Result<()> {
    let token = if opts.bind.is_loopback() {
        None
    } else {
        Some(random_token()?)
    };
    let first = Wish {
        seq: 0,
        camera: opts.camera,
        mode: still.shading.mode,
        spp: still.shading.spp,
        interactive: false,
    };
    let shared = Shared::new(first, token.clone(), opts.max_spp);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("dcrt-view")
        .enable_all()
        .build()
        .map_err(|e| Error::Internal(format!("cannot start the view's server threads: {e}")))?;
    let at = SocketAddr::new(opts.bind, opts.port);
    let listener = rt
        .block_on(tokio::net::TcpListener::bind(at))
        .map_err(|e| Error::Invalid(format!("cannot listen on {at}: {e}")))?;
    let addr = listener
        .local_addr()
        .map_err(|e| Error::Internal(format!("the view's address: {e}")))?;
    let app = server::router(shared.clone());
    // Without TCP_NODELAY a frame's JPEG, sent right after its description, waits for the
    // client's delayed ACK: 40 ms a frame.
    let listener = axum::serve::ListenerExt::tap_io(listener, |tcp| {
        if let Err(e) = tcp.set_nodelay(true) {
            crate::report!("warning: the view cannot set TCP_NODELAY: {e}");
        }
    });
    rt.spawn(async move {
        if let Err(e) = axum::serve(listener, app).await {
            crate::report!("error: the view's server stopped: {e}");
        }
    });
    let enc = shared.clone();
    std::thread::Builder::new()
        .name("dcrt-encode".into())
        .spawn(move || encode_frames(&enc))
        .map_err(|e| Error::Internal(format!("cannot start the encoder thread: {e}")))?;
    listening(&url(addr, token.as_deref()), addr);
    producer::produce(frames, &shared, still)
}

/// The encoder thread: the newest frame to JPEG, for every page.
fn encode_frames(shared: &Arc<Shared>) {
    loop {
        let raw = shared.raw.take();
        let t = std::time::Instant::now();
        let mut jpeg = Vec::new();
        let (w, h) = raw.image.dimensions();
        let encoded = match (u16::try_from(w), u16::try_from(h)) {
            (Ok(w), Ok(h)) => jpeg_encoder::Encoder::new(&mut jpeg, JPEG_QUALITY)
                .encode(raw.image.as_raw(), w, h, jpeg_encoder::ColorType::Rgb)
                .map_err(|e| e.to_string()),
            _ => Err(format!("{w}x{h} is beyond JPEG's 65535 a side")),
        };
        if let Err(e) = encoded {
            crate::report!("error: JPEG encoding of a frame failed: {e}");
            continue;
        }
        let mut info = raw.info;
        info["encode_ms"] = serde_json::json!(t.elapsed().as_secs_f64() * 1e3);
        info["jpeg_bytes"] = serde_json::json!(jpeg.len());
        shared
            .live
            .send_replace(Some(Arc::new(LiveFrame { jpeg, info })));
    }
}
