//! A render rank: tiles from the balancer, through the GPU, to the display. With a distributed
//! cache it exposes its own blocks in an MPI window and reads borrowed ones from their owners'.

use super::display_bench;
use super::failure::Failure;
use super::mailbox::{poll_from, send, wait_from};
use super::pixels::{Packer, Wire};
use super::protocol::{Ask, FrameReport, Tag, Work, malformed};
use super::startup::RenderSetup;
use super::{Options, Roles, rma};
use crate::dc::Ranks;
use crate::dc::source::BlockSource;
use crate::dc::trace::FrameTrace;
use crate::error::Result;
use crate::gpu::Idle;
use crate::gpu::tracer::{DcSetup, FrameStats, Rect, Tracer, ms};
use crate::render::frames::{FrameBody, FrameCtx, FramePlan, Role, View, run_frames};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use serde_json::json;
use std::collections::{BTreeMap, VecDeque};
use std::time::Instant;

/// Borrowed blocks read from their owners' windows, a whole round in one epoch.
struct MpiBlocks {
    window: rma::Window,
    ranks: Ranks,
    words: usize,
}

impl BlockSource for MpiBlocks {
    fn fetch(&mut self, blocks: &[u32], out: &mut [u32]) -> Result<()> {
        let gets: Vec<(u32, u64)> = blocks
            .iter()
            .map(|&k| {
                (
                    self.ranks.owner(k),
                    u64::from(self.ranks.slot(k)) * self.words as u64,
                )
            })
            .collect();
        self.window.get_all(&gets, self.words, out)
    }

    fn name(&self) -> &'static str {
        "mpi"
    }
}

fn mib(b: u64) -> f64 {
    b as f64 / 1048576.0
}

/// Runs render rank `rank`: builds its tracer (and block window), then renders every frame.
pub fn run(
    world: &SimpleCommunicator,
    comm: &SimpleCommunicator,
    roles: Roles,
    rank: u32,
    opts: &Options,
    setup: RenderSetup,
) -> Result<()> {
    let RenderSetup {
        loaded,
        gpu,
        dc,
        settings,
    } = setup;
    let format = loaded.format();
    let bw = format.words() as usize;
    let mut tracer: Tracer<'_> = match dc {
        None => {
            eprintln!(
                "rank {rank} (render): replicated, {:.1} MiB of blocks",
                mib(loaded.model_bytes())
            );
            loaded.tracer(&gpu, settings, None)?
        }
        Some((ranks, resident, size, map)) => {
            let owned = ranks.owned(loaded.block_count()) as usize;
            let window = rma::Window::create(comm, &resident[..owned * bw])?;
            let lines = size.lines(loaded.block_count(), format.block_bytes);
            eprintln!(
                "rank {rank} (render {} of {}): {:.1} MiB resident ({} own blocks + root), \
                 {:.1} MiB exposed to the others, {:.1} MiB cache ({lines} lines, {map:?}) of a \
                 {:.1} MiB model",
                ranks.rank,
                ranks.n,
                mib((resident.len() * 4) as u64),
                owned,
                mib(window.exposed_bytes()),
                mib(u64::from(lines) * u64::from(format.block_bytes)),
                mib(loaded.model_bytes())
            );
            let setup = DcSetup {
                ranks,
                lines,
                map,
                source: Box::new(MpiBlocks {
                    window,
                    ranks,
                    words: bw,
                }),
            };
            // From here the window exists, and freeing it is collective: an error must abort
            // the job rather than unwind into a free the other ranks never join.
            or_abort(rank, loaded.dc_tracer(&gpu, settings, &resident, setup))
        }
    };
    // While the GPU works, keep MPI progressing: over TCP a passive Get from another rank is
    // only served while this rank is inside MPI.
    gpu.set_idle(Some(Idle {
        hook: Box::new(rma::poll_world),
        limit: opts.timeout,
    }));
    let wire = if opts.exr.is_some() {
        Wire::Full
    } else {
        Wire::Rgb8
    };
    let mut me = RenderRank {
        world,
        roles,
        rank,
        opts,
        size: (
            opts.width.unwrap_or(loaded.width),
            opts.height.unwrap_or(loaded.height),
        ),
        background: loaded.background,
        packer: Packer::new(wire, opts.message_bytes, opts.exposure),
        start: super::clock::epoch(),
        kept: BTreeMap::new(),
        failure: Failure::from_env(rank),
        sent: Sent::default(),
    };
    let plan = FramePlan {
        frames: opts.frames,
        view: if opts.display_bench {
            View::Fixed(loaded.camera.turned_around())
        } else {
            View::Orbit(loaded.camera)
        },
        role: Role {
            name: roles.name(rank),
            rank,
            ranks: roles.size,
        },
        trace_dir: opts.trace.as_deref(),
    };
    or_abort(rank, run_frames(&mut tracer, &plan, &mut me));
    if opts.display_bench {
        // Only once the display has every frame: the stream must not mix with pixels.
        world.barrier();
        or_abort(rank, display_bench::send_bandwidth(world, opts));
    }
    gpu.set_idle(None);
    // Dropping the tracer frees the block window: collective over the render ranks, after
    // which no rank reads another's blocks.
    drop(tracer);
    Ok(())
}

/// The value, or the error reported and the job aborted.
fn or_abort<T>(rank: u32, r: Result<T>) -> T {
    r.unwrap_or_else(|e| {
        eprintln!("rank {rank}: error: {e}");
        rma::abort_world(1)
    })
}

/// A render rank's state between frames.
struct RenderRank<'a> {
    world: &'a SimpleCommunicator,
    roles: Roles,
    rank: u32,
    opts: &'a Options,
    /// The image's width and height.
    size: (u32, u32),
    background: [f32; 3],
    packer: Packer,
    /// When the rank started rendering: the origin of the tile records' times.
    start: Instant,
    /// The display benchmark keeps the first frame's tiles to send again.
    kept: BTreeMap<(u32, u32, u32, u32), Vec<u8>>,
    failure: Failure,
    /// What the frame being rendered sent, for its report.
    sent: Sent,
}

/// The tiles, messages and bytes a frame sent to the display.
#[derive(Default)]
struct Sent {
    events: Vec<serde_json::Value>,
    messages: u32,
    bytes: u64,
}

impl FrameBody for RenderRank<'_> {
    /// Asks for tiles until the balancer ends the frame, traces them and sends their pixels.
    fn trace(&mut self, ctx: FrameCtx<'_, '_>) -> Result<()> {
        let (world, opts, rank) = (self.world, self.opts, self.rank);
        let FrameCtx {
            frame,
            camera,
            tracer,
            stats,
        } = ctx;
        let basis = camera.basis(self.size.0, self.size.1);
        let balancer = self.roles.balancer();
        let ask = Ask { frame }.encode();
        let mut events = Vec::new();
        let mut queue: VecDeque<Rect> = VecDeque::new();
        send(world, balancer, Tag::Ask, &ask);
        let mut asked = true;
        let mut ended = false;
        let (mut sent_bytes, mut messages) = (0u64, 0u32);
        loop {
            // Take in an answer: blocking when there is nothing left to trace.
            while asked {
                let msg = match (poll_from(world, balancer, Tag::Work), queue.is_empty()) {
                    (Some(msg), _) => msg,
                    (None, true) => wait_from(
                        world,
                        balancer,
                        Tag::Work,
                        "answer from the balancer",
                        opts.timeout,
                    )?,
                    (None, false) => break,
                };
                asked = false;
                let work = Work::decode(balancer, &msg)?;
                if work.frame != frame {
                    return Err(malformed(
                        Tag::Work,
                        balancer,
                        format!(
                            "tiles of frame {} while rendering frame {frame}",
                            work.frame
                        ),
                    ));
                }
                if work.tiles.is_empty() {
                    ended = true;
                }
                queue.extend(work.tiles);
            }
            let Some(rect) = queue.pop_front() else {
                if ended {
                    break;
                }
                if !asked {
                    send(world, balancer, Tag::Ask, &ask);
                    asked = true;
                }
                continue;
            };
            // Ask for the next tile while one is still queued, so that the answer is in before
            // the queue runs dry.
            if queue.len() <= 1 && !ended && !asked {
                send(world, balancer, Tag::Ask, &ask);
                asked = true;
            }
            self.failure.at_tile(rank, frame);
            let t0 = self.start.elapsed();
            let key = (rect.x, rect.y, rect.w, rect.h);
            let encoded = match self.kept.get(&key) {
                Some(p) => p.clone(),
                None => {
                    let p = tracer.render_rect(&basis, self.background, rect, stats)?;
                    let e = self.packer.encode(&p);
                    if opts.display_bench {
                        self.kept.insert(key, e.clone());
                    }
                    e
                }
            };
            let t1 = self.start.elapsed();
            for m in self.packer.push_encoded(frame, rect, &encoded) {
                sent_bytes += m.len() as u64;
                messages += 1;
                send(world, Roles::DISPLAY, Tag::Pixels, &m);
            }
            events.push(json!({
                "type": "tile", "x": rect.x, "y": rect.y, "w": rect.w, "h": rect.h,
                "start_ms": ms(t0), "trace_ms": ms(t1 - t0),
                "send_ms": ms(self.start.elapsed() - t1),
            }));
        }
        if let Some(m) = self.packer.flush() {
            sent_bytes += m.len() as u64;
            messages += 1;
            send(world, Roles::DISPLAY, Tag::Pixels, &m);
        }
        self.sent = Sent {
            events,
            messages,
            bytes: sent_bytes,
        };
        Ok(())
    }

    /// Sends the frame's report to the display; the tile records go into the frame's trace.
    fn finish(&mut self, frame: u32, stats: &FrameStats, trace: &mut FrameTrace) -> Result<()> {
        let sent = std::mem::take(&mut self.sent);
        let report = FrameReport {
            frame,
            rank: self.rank,
            tiles: sent.events.len() as u64,
            messages: sent.messages,
            bytes: sent.bytes,
            stats,
        };
        send(self.world, Roles::DISPLAY, Tag::Done, &report.encode()?);
        trace.events = sent.events;
        Ok(())
    }
}
