//! A render rank: tiles from the balancer, through the GPU, to the display. With a distributed
//! cache it exposes its own blocks in an MPI window and reads borrowed ones from their owners'.

use super::display_bench;
use super::failure::Failure;
use super::liveness::Heartbeat;
use super::mailbox::{poll_from, send, wait_from};
use super::pixels::{Packer, Wire};
use super::protocol::{Ask, FrameReport, Job, Tag, Work, malformed};
use super::startup::RenderSetup;
use super::{Options, Roles, rma};
use crate::blocks::ranks::Ranks;
use crate::dc::source::BlockSource;
use crate::error::{Error, Result};
use crate::gpu::Idle;
use crate::gpu::frame::{FrameStats, Rect, ms};
use crate::gpu::layout::Pixel;
use crate::gpu::scheduler::{Next, RectSource};
use crate::gpu::tracer::{DcSetup, Tracer};
use crate::render::frames::{FrameBody, FrameCtx, FramePlan, Role, View, run_frame, run_frames};
use crate::shading::Shading;
use crate::traces::record::{Event, FrameTrace, Tile};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

/// Borrowed blocks read from their owners' windows, a whole round in one epoch.
struct MpiBlocks {
    window: rma::Window,
    ranks: Ranks,
    words: usize,
    roles: Roles,
    /// This rank, and how long a read may wait for its owner.
    rank: u32,
    timeout: Duration,
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
        // While an owner has not answered, tell the display that this rank waits (it is not
        // the silent one), and give up after the timeout naming the owner.
        let (start, mut heart) = (Instant::now(), Heartbeat::new(self.timeout));
        let (roles, me, timeout) = (self.roles, self.rank, self.timeout);
        let mut waiting = |owed: &[u32]| -> Result<()> {
            heart.beat();
            if start.elapsed() > timeout {
                let owners: Vec<String> = owed
                    .iter()
                    .map(|&i| roles.render_rank(i).to_string())
                    .collect();
                return Err(Error::Timeout {
                    what: format!(
                        "block read answered by rank {} (render), which rank {me} waits for,",
                        owners.join(", ")
                    ),
                    seconds: timeout.as_secs_f64(),
                    likely: Some("it has stopped, hung or died"),
                });
            }
            std::thread::yield_now();
            Ok(())
        };
        self.window.get_all(&gets, self.words, out, &mut waiting)
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
    let base = settings.shading;
    let mut tracer: Tracer<'_> = match dc {
        None => {
            crate::report!(
                "rank {rank} (render): replicated, {:.1} MiB of blocks",
                mib(loaded.model_bytes())
            );
            loaded.tracer(&gpu, settings, None)?
        }
        Some((ranks, resident, size, map)) => {
            let owned = ranks.owned(loaded.block_count()) as usize;
            let window = rma::Window::create(comm, &resident[..owned * bw])?;
            let lines = size.lines(loaded.block_count(), format.block_bytes);
            crate::report!(
                "rank {rank} (render {} of {}): {:.1} MiB resident ({} own blocks + {} replicated), \
                 {:.1} MiB exposed to the others, {:.1} MiB cache ({lines} lines, {map:?}) of a \
                 {:.1} MiB model",
                ranks.rank,
                ranks.n,
                mib((resident.len() * 4) as u64),
                owned,
                resident.len() / bw - owned,
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
                    roles,
                    rank,
                    timeout: opts.timeout,
                }),
            };
            // From here the window exists, and freeing it is collective: an error must abort
            // the job rather than unwind into a free the other ranks never join.
            or_abort(rank, loaded.dc_tracer(&gpu, settings, &resident, setup))
        }
    };
    // While the GPU works, keep MPI progressing (over TCP a passive Get from another rank is
    // only served while this rank is inside MPI), and tell the display that this rank works.
    let mut heart = Heartbeat::new(opts.timeout);
    gpu.set_idle(Some(Idle {
        hook: Box::new(move || {
            rma::poll_world();
            heart.beat();
        }),
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
    if opts.live {
        if roles.render_index(rank) == Some(0) {
            let home = serde_json::to_vec(&loaded.camera)
                .map_err(|e| Error::Internal(format!("the model's camera: {e}")));
            send(world, Roles::DISPLAY, Tag::Home, &or_abort(rank, home));
        }
        or_abort(rank, me.live_frames(&mut tracer, &plan, base));
    }
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
        crate::report!("rank {rank}: error: {e}");
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

impl RenderRank<'_> {
    /// A live view's frames: each `JOB` of the display rendered as it says, for as long as the
    /// job runs (a signal ends it: mpirun ends every rank).
    fn live_frames(
        &mut self,
        tracer: &mut Tracer<'_>,
        plan: &FramePlan<'_>,
        base: Shading,
    ) -> Result<std::convert::Infallible> {
        loop {
            let job = self.next_job()?;
            self.size = (job.width, job.height);
            self.packer.set_wire(match job.whole_pixels {
                true => Wire::Full,
                false => Wire::Rgb8,
            });
            tracer.set_shading(Shading {
                mode: job.mode,
                spp: job.spp,
                first_sample: job.first_sample,
                part_of_spp: job.part_of_spp,
                ..base
            })?;
            run_frame(tracer, plan, job.frame, job.camera, self)?;
        }
    }

    /// Waits for the display's next `JOB`. While its user only looks, the display says `ALIVE`
    /// every quarter of the timeout; silence for the whole timeout ends the job.
    fn next_job(&self) -> Result<Job> {
        let display = Roles::DISPLAY;
        let mut heard = Instant::now();
        loop {
            if let Some(msg) = poll_from(self.world, display, Tag::Job) {
                return Job::decode(display, &msg);
            }
            if poll_from(self.world, display, Tag::Alive).is_some() {
                heard = Instant::now();
                continue;
            }
            if heard.elapsed() > self.opts.timeout {
                return Err(Error::Timeout {
                    what: format!(
                        "word from rank {display} (display), which rank {} waits for,",
                        self.rank
                    ),
                    seconds: self.opts.timeout.as_secs_f64(),
                    likely: Some("it has stopped, hung or died"),
                });
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

/// A frame's tiles as the tracer takes them: asked of the balancer one ahead, so that the answer
/// is in before the queue runs dry; their pixels are sent to the display as each is done.
struct RankTiles<'r, 'a> {
    rank: &'r mut RenderRank<'a>,
    frame: u32,
    balancer: u32,
    ask: Vec<u8>,
    queue: VecDeque<Rect>,
    /// An answer from the balancer is due; the balancer has ended the frame.
    asked: bool,
    ended: bool,
    /// Tiles handed to the tracer and when; when the last tile's pixels were sent.
    handed: Vec<(Rect, Duration)>,
    last_end: Duration,
    sent: Sent,
}

impl RankTiles<'_, '_> {
    /// Takes in the balancer's answers: waiting for one only when `wait`.
    fn take_answers(&mut self, wait: bool) -> Result<()> {
        let r = &*self.rank;
        while self.asked {
            let msg = match (poll_from(r.world, self.balancer, Tag::Work), wait) {
                (Some(msg), _) => msg,
                (None, true) => wait_from(
                    r.world,
                    self.balancer,
                    Tag::Work,
                    "answer from the balancer",
                    r.opts.timeout,
                )?,
                (None, false) => break,
            };
            self.asked = false;
            let work = Work::decode(self.balancer, &msg)?;
            if work.frame != self.frame {
                return Err(malformed(
                    Tag::Work,
                    self.balancer,
                    format!(
                        "tiles of frame {} while rendering frame {}",
                        work.frame, self.frame
                    ),
                ));
            }
            if work.tiles.is_empty() {
                self.ended = true;
            }
            self.queue.extend(work.tiles);
        }
        Ok(())
    }

    fn ask(&mut self) {
        if !self.asked && !self.ended {
            send(self.rank.world, self.balancer, Tag::Ask, &self.ask);
            self.asked = true;
        }
    }

    /// Sends a tile's encoded pixels and records the tile: its span starts when it was handed
    /// to the tracer or when the last tile was sent, whichever is later, so that the spans of a
    /// rank's tiles follow each other even where their rounds overlap.
    fn send_tile(&mut self, rect: Rect, handed: Duration, encoded: &[u8]) {
        let r = &mut *self.rank;
        let t0 = handed.max(self.last_end);
        let t1 = r.start.elapsed().max(t0);
        self.sent.pixels += u64::from(rect.w) * u64::from(rect.h);
        for m in r.packer.push_encoded(self.frame, rect, encoded) {
            self.sent.bytes += m.len() as u64;
            self.sent.messages += 1;
            send(r.world, Roles::DISPLAY, Tag::Pixels, &m);
        }
        self.last_end = r.start.elapsed();
        self.sent.events.push(Event::Tile(Tile {
            x: rect.x,
            y: rect.y,
            w: rect.w,
            h: rect.h,
            start_ms: ms(t0),
            trace_ms: ms(t1 - t0),
            send_ms: ms(self.last_end - t1),
        }));
    }
}

impl RectSource for RankTiles<'_, '_> {
    fn next(&mut self, busy: bool) -> Result<Next> {
        loop {
            self.take_answers(self.queue.is_empty() && !busy)?;
            let Some(rect) = self.queue.pop_front() else {
                if self.ended {
                    return Ok(Next::End);
                }
                self.ask();
                if busy {
                    return Ok(Next::Later);
                }
                continue;
            };
            // Ask for the next tile while one is still queued, so that the answer is in before
            // the queue runs dry.
            if self.queue.len() <= 1 {
                self.ask();
            }
            self.rank.failure.at_tile(self.rank.rank, self.frame);
            let handed = self.rank.start.elapsed();
            let key = (rect.x, rect.y, rect.w, rect.h);
            if let Some(encoded) = self.rank.kept.get(&key).cloned() {
                self.send_tile(rect, handed, &encoded);
                continue;
            }
            self.handed.push((rect, handed));
            return Ok(Next::Rect(rect));
        }
    }

    fn done(&mut self, rect: Rect, pixels: Vec<Pixel>) -> Result<()> {
        let Some(at) = self.handed.iter().position(|(r, _)| *r == rect) else {
            return Err(crate::error::Error::Invalid(format!(
                "the tracer finished tile {rect:?}, which was not handed to it"
            )));
        };
        let handed = self.handed.swap_remove(at).1;
        let encoded = self.rank.packer.encode(&pixels);
        if self.rank.opts.display_bench {
            let key = (rect.x, rect.y, rect.w, rect.h);
            self.rank.kept.insert(key, encoded.clone());
        }
        self.send_tile(rect, handed, &encoded);
        Ok(())
    }
}

/// The tiles, messages and bytes a frame sent to the display.
#[derive(Default)]
struct Sent {
    events: Vec<Event>,
    pixels: u64,
    messages: u32,
    bytes: u64,
}

impl FrameBody for RenderRank<'_> {
    /// Asks for tiles until the balancer ends the frame, traces them and sends their pixels.
    fn trace(&mut self, ctx: FrameCtx<'_, '_>) -> Result<()> {
        let FrameCtx {
            frame,
            camera,
            tracer,
            stats,
        } = ctx;
        let basis = camera.basis(self.size.0, self.size.1);
        let background = self.background;
        let balancer = self.roles.balancer();
        let ask = Ask {
            frame,
            width: self.size.0,
            height: self.size.1,
        }
        .encode();
        send(self.world, balancer, Tag::Ask, &ask);
        let mut tiles = RankTiles {
            rank: self,
            frame,
            balancer,
            ask,
            queue: VecDeque::new(),
            asked: true,
            ended: false,
            handed: Vec::new(),
            last_end: Duration::ZERO,
            sent: Sent::default(),
        };
        tracer.render_rects(&basis, background, &mut tiles, stats)?;
        let mut sent = tiles.sent;
        if let Some(m) = self.packer.flush() {
            sent.bytes += m.len() as u64;
            sent.messages += 1;
            send(self.world, Roles::DISPLAY, Tag::Pixels, &m);
        }
        self.sent = sent;
        Ok(())
    }

    /// Sends the frame's report to the display; the tile records go into the frame's trace.
    fn finish(&mut self, frame: u32, stats: &FrameStats, trace: &mut FrameTrace) -> Result<()> {
        let sent = std::mem::take(&mut self.sent);
        let report = FrameReport {
            frame,
            rank: self.rank,
            tiles: sent.events.len() as u64,
            pixels: sent.pixels,
            messages: sent.messages,
            bytes: sent.bytes,
            stats,
        };
        send(self.world, Roles::DISPLAY, Tag::Done, &report.encode()?);
        trace.events = sent.events;
        Ok(())
    }
}
