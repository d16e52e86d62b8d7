//! The display benchmark (chapter 5.5), after its frames: the render ranks stream raw messages of
//! the pixel-message size to the display, which sets the frame rate it reached against the MPI
//! bandwidth it measured.

use super::mailbox::{send, wait_any};
use super::pixels::Wire;
use super::protocol::{Message, Tag};
use super::startup::Image;
use super::{Options, Roles};
use crate::error::{Error, Result};
use mpi::topology::SimpleCommunicator;
use serde_json::json;
use std::time::Instant;

/// Bytes each render rank streams to the display to measure the link.
const BANDWIDTH_BYTES: usize = 64 << 20;

/// A render rank's part: the stream, then an empty message to end it.
pub fn send_bandwidth(world: &SimpleCommunicator, opts: &Options) -> Result<()> {
    let msg = vec![0u8; opts.message_bytes.max(1)];
    let n = BANDWIDTH_BYTES / msg.len();
    for _ in 0..n {
        send(world, Roles::DISPLAY, Tag::Bandwidth, &msg);
    }
    send(world, Roles::DISPLAY, Tag::Bandwidth, &[]);
    Ok(())
}

/// The display benchmark's figures: frames per second and pixels per second over the frames
/// after the first, against the MPI bandwidth measured right after with the same message size.
/// `shown`: when each frame was complete, in ms.
pub fn measure(
    world: &SimpleCommunicator,
    roles: Roles,
    opts: &Options,
    image: Image,
    shown: &[f64],
) -> Result<serde_json::Value> {
    let start = Instant::now();
    let mut ended = 0;
    let mut bytes = 0u64;
    while ended < roles.render_ranks() {
        let (msg, from, tag) = wait_any(world, opts.timeout)?;
        let Message::Bandwidth(msg) = Message::decode(tag, from, msg)? else {
            return Err(Error::Protocol(format!(
                "unexpected message (tag {tag}) from rank {from} in the bandwidth test"
            )));
        };
        if msg.is_empty() {
            ended += 1;
        }
        bytes += msg.len() as u64;
    }
    let mpi_bps = bytes as f64 / start.elapsed().as_secs_f64();
    // The second half of the frames: by then every rank has traced the tiles it is given.
    let half = &shown[shown.len() / 2..];
    let steady = if half.len() >= 2 {
        (half[half.len() - 1] - half[0]) / 1e3 / (half.len() - 1) as f64
    } else {
        f64::NAN
    };
    let px = f64::from(image.width) * f64::from(image.height);
    let pps = px / steady;
    let bpp = if opts.exr.is_some() {
        Wire::Full.bytes()
    } else {
        Wire::Rgb8.bytes()
    } as f64;
    let report = json!({
        "bench": "display", "ranks": roles.size, "render_ranks": roles.render_ranks(),
        "copy_threads": opts.copy_threads, "width": image.width, "height": image.height,
        "frames": opts.frames, "message_bytes": opts.message_bytes,
        "fps": 1.0 / steady, "pixels_per_s": pps, "pixel_bytes_per_s": pps * bpp,
        "mpi_bytes_per_s": mpi_bps, "ceiling_fps": mpi_bps / (px * bpp),
        "ratio": pps * bpp / mpi_bps,
    });
    crate::report!("display benchmark: {report}");
    Ok(report)
}
