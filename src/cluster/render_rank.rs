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
use crate::scene::CameraBasis;
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
        background: loaded.background,
        packer: Packer::new(wire, opts.message_bytes, opts.exposure),
        start: Instant::now(),
        kept: BTreeMap::new(),
        failure: Failure::from_env(rank),
    };
    let (width, height) = (
        opts.width.unwrap_or(loaded.width),
        opts.height.unwrap_or(loaded.height),
    );
    let frames = (0..opts.frames).try_for_each(|frame| {
        let camera = if opts.display_bench {
            loaded.camera.turned_around()
        } else {
            loaded
                .camera
                .orbit(std::f64::consts::TAU * f64::from(frame) / f64::from(opts.frames))
        };
        me.frame(&mut tracer, frame, &camera.basis(width, height))
    });
    or_abort(rank, frames);
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
    background: [f32; 3],
    packer: Packer,
    /// When the rank started rendering: the origin of the tile records' times.
    start: Instant,
    /// The display benchmark keeps the first frame's tiles to send again.
    kept: BTreeMap<(u32, u32, u32, u32), Vec<u8>>,
    failure: Failure,
}

impl RenderRank<'_> {
    /// Frame `frame` seen through `basis`: asks for tiles until the balancer ends the frame,
    /// traces them and sends their pixels, then the frame's report.
    fn frame(&mut self, tracer: &mut Tracer<'_>, frame: u32, basis: &CameraBasis) -> Result<()> {
        let (world, opts, rank) = (self.world, self.opts, self.rank);
        let balancer = self.roles.balancer();
        let ask = Ask { frame }.encode();
        let mut stats = tracer.begin_frame();
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
                    let p = tracer.render_rect(basis, self.background, rect, &mut stats)?;
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
        tracer.end_frame(&mut stats);
        let mut trace = tracer.take_trace();
        fill_summary(&mut trace, frame, rank, self.roles, &stats);
        let report = FrameReport {
            frame,
            rank,
            tiles: events.len() as u64,
            messages,
            bytes: sent_bytes,
            stats: &stats,
        };
        send(world, Roles::DISPLAY, Tag::Done, &report.encode()?);
        if let Some(dir) = &opts.trace {
            trace.events = events;
            trace.write(dir)?;
        }
        Ok(())
    }
}

fn fill_summary(trace: &mut FrameTrace, frame: u32, rank: u32, roles: Roles, stats: &FrameStats) {
    let s = &mut trace.summary;
    s.frame = frame;
    s.rank = rank;
    s.ranks = roles.size;
    s.role = roles.name(rank).into();
    s.frame_ms = stats.seconds * 1e3;
    s.trace_ms = stats.trace_seconds * 1e3;
    s.shade_ms = stats.shade_seconds * 1e3;
    s.rounds = stats.rounds;
    if s.lookups == 0 {
        s.hit_rate = 1.0;
    }
}
