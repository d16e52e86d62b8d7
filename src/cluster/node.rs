//! The MPI side of cluster mode: start-up and agreement, then each role's loop. All messages go
//! over MPI_COMM_WORLD as bytes; only the main thread calls MPI (`Threading::Funneled`).
//!
//! Protocol, per frame f (DESIGN.md section 4):
//! - a render rank sends `ASK(f)` to the balancer; the first answer of a frame is the rank's
//!   static tiles, later ones one tile each, and an empty `WORK` ends the rank's frame. A rank
//!   asks again as soon as it starts its last queued tile, so the answer travels while it traces.
//! - finished tiles go to the display in `PIXELS` messages; `DONE(f)` (with the rank's frame
//!   statistics) follows the rank's last pixels of the frame, in order, since MPI keeps the
//!   order of messages between two ranks.
//! - the display writes frame f once every render rank's `DONE(f)` is in and every pixel copied.

use super::balance::Schedule;
use super::pixels::{Copiers, FrameBuf, Packer, Wire, message_frame};
use super::{Options, Roles, rma};
use crate::dc::source::BlockSource;
use crate::dc::trace::FrameTrace;
use crate::dc::{CacheMap, CacheSize, Ranks};
use crate::error::{Error, Result};
use crate::gpu::tracer::{DcSetup, FrameStats, Rect, Settings, Tracer, ms};
use crate::gpu::{Gpu, Idle};
use crate::output;
use crate::render::Loaded;
use crate::scene::check_image_size;
use mpi::Threading;
use mpi::point_to_point::MatchedReceiveVec;
use mpi::topology::{Color, SimpleCommunicator};
use mpi::traits::*;
use serde_json::json;
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

const TAG_ASK: i32 = 1;
const TAG_WORK: i32 = 2;
const TAG_PIXELS: i32 = 3;
const TAG_DONE: i32 = 4;
const TAG_BANDWIDTH: i32 = 5;

/// The image every rank agrees on.
#[derive(Clone, Copy, Debug)]
struct Image {
    width: u32,
    height: u32,
}

pub fn run(opts: &Options) -> Result<()> {
    let (universe, _) = mpi::initialize_with_threading(Threading::Funneled)
        .ok_or_else(|| Error::Invalid("MPI is already initialised".into()))?;
    let world = universe.world();
    let rank = world.rank() as u32;
    let roles = Roles::new(world.size() as u32)?;
    // From here a panic anywhere must take the job down, not leave the others waiting.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        default_hook(info);
        eprintln!("rank {rank}: panic: aborting the job");
        rma::abort_world(101);
    }));

    // Every rank opens what it needs; then all agree that everyone could, before any
    // collective that a failed rank would never join.
    let opened = open(opts, roles, rank);
    // Said before anything else: once any rank exits non-zero, mpirun may kill the others
    // before they print.
    if let Err(e) = &opened {
        eprintln!("error: rank {rank}: {e}");
    }
    let check = match &opened {
        Ok(o) => [
            1,
            o.image.width,
            o.image.height,
            opts.frames,
            o.fp_lo(),
            o.fp_hi(),
        ],
        Err(_) => [0; 6],
    };
    let mut all = vec![[0u32; 6]; roles.size as usize];
    world.all_gather_into(&check[..], flatten_mut(&mut all));
    let Ok(opened) = opened else {
        drop(universe);
        std::process::exit(1);
    };
    if let Some(problem) = disagreement(&all, roles) {
        if rank == 0 || problem.0 == rank {
            eprintln!("error: {}", problem.1);
        }
        drop(universe);
        std::process::exit(1);
    }

    // Render ranks get a communicator of their own for the block window.
    let color = match roles.render_index(rank) {
        Some(_) => Color::with_value(0),
        None => Color::undefined(),
    };
    let render_comm = world.split_by_color(color);
    let result = match (opened.role, render_comm) {
        (Role::Render(r), Some(comm)) => render(&world, &comm, roles, rank, opts, *r),
        (Role::Coordinator, _) => coordinate(&world, roles, rank, opts, opened.image),
        _ => Err(Error::Invalid(
            "a render rank without its communicator".into(),
        )),
    };
    if let Err(e) = result {
        eprintln!("rank {rank}: error: {e}");
        rma::abort_world(1);
    }
    world.barrier();
    Ok(())
}

fn flatten_mut(v: &mut [[u32; 6]]) -> &mut [u32] {
    bytemuck::cast_slice_mut(v)
}

/// What a rank opened before the agreement.
struct Opened {
    image: Image,
    fingerprint: u64,
    role: Role,
}

impl Opened {
    fn fp_lo(&self) -> u32 {
        self.fingerprint as u32
    }
    fn fp_hi(&self) -> u32 {
        (self.fingerprint >> 32) as u32
    }
}

enum Role {
    Coordinator,
    Render(Box<RenderSetup>),
}

/// A render rank's model and GPU, before the block window exists.
struct RenderSetup {
    loaded: Loaded,
    gpu: Gpu,
    /// With a distributed cache: this rank's place, its resident blocks and the cache.
    dc: Option<(Ranks, Vec<u32>, CacheSize, CacheMap)>,
    settings: Settings,
}

fn open(opts: &Options, roles: Roles, rank: u32) -> Result<Opened> {
    let of = Loaded::image_of(&opts.input)?;
    let image = Image {
        width: opts.width.unwrap_or(of.width),
        height: opts.height.unwrap_or(of.height),
    };
    check_image_size(image.width, image.height)?;
    let shading = opts.shade.apply(of.shading)?;
    let Some(index) = roles.render_index(rank) else {
        return Ok(Opened {
            image,
            fingerprint: 0,
            role: Role::Coordinator,
        });
    };
    let loaded = Loaded::open(&opts.input, opts.preset, opts.format)?;
    let gpu = Gpu::new(opts.adapter.as_deref())?;
    let dc = match opts.cache {
        // A single render rank owns every block: a cache would only slow its pipelines down.
        Some(_) if roles.render_ranks() == 1 => {
            eprintln!("rank {rank}: the only render rank owns every block: no cache needed");
            None
        }
        None => None,
        Some((size, map)) => {
            let ranks = Ranks::new(roles.render_ranks(), index)?;
            Some((ranks, loaded.resident(ranks)?, size, map))
        }
    };
    Ok(Opened {
        image,
        fingerprint: loaded.fingerprint(),
        role: Role::Render(Box::new(RenderSetup {
            loaded,
            gpu,
            dc,
            settings: Settings {
                shading,
                ..opts.settings
            },
        })),
    })
}

/// The first problem in what the ranks reported, and the rank it concerns.
fn disagreement(all: &[[u32; 6]], roles: Roles) -> Option<(u32, String)> {
    if let Some(r) = all.iter().position(|c| c[0] == 0) {
        return Some((
            u32::MAX,
            format!(
                "rank {r} could not open its input (its message above says why); every rank stops"
            ),
        ));
    }
    let first = roles.first_render() as usize;
    for (r, c) in all.iter().enumerate() {
        if c[1..4] != all[0][1..4] {
            return Some((
                r as u32,
                format!(
                    "rank {r} has a {}x{} image of {} frames, rank 0 {}x{} of {}: every rank must \
                     be given the same input and options",
                    c[1], c[2], c[3], all[0][1], all[0][2], all[0][3]
                ),
            ));
        }
        if r > first && c[4..] != all[first][4..] {
            return Some((
                r as u32,
                format!(
                    "rank {r}'s model differs from rank {first}'s (block fingerprints \
                     {:08x}{:08x} and {:08x}{:08x}): every rank must read the same model",
                    c[5], c[4], all[first][5], all[first][4]
                ),
            ));
        }
    }
    None
}

/// Between two empty probes: give the core away at once, and after a millisecond of waiting
/// sleep, so that waiting ranks leave the cores to the ones that work (ranks outnumber cores).
fn idle(probes: u32, since: Instant) {
    if probes < 8 || since.elapsed() < Duration::from_millis(1) {
        std::thread::yield_now();
    } else {
        std::thread::sleep(Duration::from_micros(100));
    }
}

/// Waits for the next message (any source, any tag) for at most `timeout`, sleeping between
/// probes so that a waiting rank leaves the cores to the ranks that work.
fn wait_message(world: &SimpleCommunicator, timeout: Duration) -> Result<(Vec<u8>, u32, i32)> {
    let start = Instant::now();
    let mut empty = 0u32;
    loop {
        if let Some(probed) = world.any_process().immediate_matched_probe() {
            let (data, status) = probed.matched_receive_vec::<u8>();
            return Ok((data, status.source_rank() as u32, status.tag()));
        }
        empty += 1;
        idle(empty, start);
        if start.elapsed() > timeout {
            return Err(Error::Invalid(format!(
                "no message from any rank for {:.0} s: a rank has hung or died",
                timeout.as_secs_f64()
            )));
        }
    }
}

fn words(v: &[u32]) -> Vec<u8> {
    bytemuck::cast_slice(v).to_vec()
}

fn read_words(b: &[u8]) -> Result<Vec<u32>> {
    if !b.len().is_multiple_of(4) {
        return Err(Error::Invalid(format!(
            "a {}-byte control message",
            b.len()
        )));
    }
    Ok(bytemuck::pod_collect_to_vec(b))
}

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

/// A render rank: tiles from the balancer, through the GPU, to the display.
fn render(
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
    or_abort(
        rank,
        render_frames(world, roles, rank, opts, &loaded, &mut tracer),
    );
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

fn render_frames(
    world: &SimpleCommunicator,
    roles: Roles,
    rank: u32,
    opts: &Options,
    loaded: &Loaded,
    tracer: &mut Tracer<'_>,
) -> Result<()> {
    let balancer = world.process_at_rank(roles.balancer() as i32);
    let display = world.process_at_rank(Roles::DISPLAY as i32);
    let (width, height) = (
        opts.width.unwrap_or(loaded.width),
        opts.height.unwrap_or(loaded.height),
    );
    let wire = if opts.exr.is_some() {
        Wire::Full
    } else {
        Wire::Rgb8
    };
    let mut packer = Packer::new(wire, opts.message_bytes, opts.exposure);
    let start = Instant::now();
    // The display benchmark keeps the first frame's tiles to send again.
    let mut kept: BTreeMap<(u32, u32, u32, u32), Vec<u8>> = BTreeMap::new();
    for frame in 0..opts.frames {
        let camera = if opts.display_bench {
            loaded.camera.turned_around()
        } else {
            loaded
                .camera
                .orbit(std::f64::consts::TAU * f64::from(frame) / f64::from(opts.frames))
        };
        let basis = camera.basis(width, height);
        let mut stats = tracer.begin_frame();
        let mut events = Vec::new();
        let mut queue: VecDeque<Rect> = VecDeque::new();
        balancer.send_with_tag(&words(&[frame])[..], TAG_ASK);
        let mut asked = true;
        let mut ended = false;
        let (mut sent_bytes, mut messages) = (0u64, 0u32);
        loop {
            // Take in an answer: blocking when there is nothing left to trace.
            while asked {
                let probe = world
                    .process_at_rank(roles.balancer() as i32)
                    .immediate_matched_probe_with_tag(TAG_WORK);
                let msg = match (probe, queue.is_empty()) {
                    (Some(probed), _) => probed.matched_receive_vec::<u8>().0,
                    (None, true) => wait_work(world, roles, opts.timeout)?,
                    (None, false) => break,
                };
                asked = false;
                let w = read_words(&msg)?;
                if w.first() != Some(&frame) || w.len() < 2 || w.len() != 2 + 4 * w[1] as usize {
                    return Err(Error::Invalid(format!(
                        "bad work message {w:?} for frame {frame}"
                    )));
                }
                if w[1] == 0 {
                    ended = true;
                }
                for t in w[2..].chunks_exact(4) {
                    queue.push_back(Rect {
                        x: t[0],
                        y: t[1],
                        w: t[2],
                        h: t[3],
                    });
                }
            }
            let Some(rect) = queue.pop_front() else {
                if ended {
                    break;
                }
                if !asked {
                    balancer.send_with_tag(&words(&[frame])[..], TAG_ASK);
                    asked = true;
                }
                continue;
            };
            // Ask for the next tile while one is still queued, so that the answer is in before
            // the queue runs dry.
            if queue.len() <= 1 && !ended && !asked {
                balancer.send_with_tag(&words(&[frame])[..], TAG_ASK);
                asked = true;
            }
            inject_failure(rank, frame);
            let t0 = start.elapsed();
            let key = (rect.x, rect.y, rect.w, rect.h);
            let encoded = match kept.get(&key) {
                Some(p) => p.clone(),
                None => {
                    let p = tracer.render_rect(&basis, loaded.background, rect, &mut stats)?;
                    let e = packer.encode(&p);
                    if opts.display_bench {
                        kept.insert(key, e.clone());
                    }
                    e
                }
            };
            let t1 = start.elapsed();
            for m in packer.push_encoded(frame, rect, &encoded) {
                sent_bytes += m.len() as u64;
                messages += 1;
                display.send_with_tag(&m[..], TAG_PIXELS);
            }
            events.push(json!({
                "type": "tile", "x": rect.x, "y": rect.y, "w": rect.w, "h": rect.h,
                "start_ms": ms(t0), "trace_ms": ms(t1 - t0), "send_ms": ms(start.elapsed() - t1),
            }));
        }
        if let Some(m) = packer.flush() {
            sent_bytes += m.len() as u64;
            messages += 1;
            display.send_with_tag(&m[..], TAG_PIXELS);
        }
        tracer.end_frame(&mut stats);
        let mut trace = tracer.take_trace();
        fill_summary(&mut trace, frame, rank, roles, &stats);
        let done = json!({
            "frame": frame, "rank": rank, "tiles": events.len(), "messages": messages,
            "bytes": sent_bytes, "stats": &stats,
        });
        let mut msg = words(&[frame]);
        msg.extend(serde_json::to_vec(&done).map_err(|e| Error::Invalid(e.to_string()))?);
        display.send_with_tag(&msg[..], TAG_DONE);
        if let Some(dir) = &opts.trace {
            trace.events = events;
            trace.write(dir)?;
        }
    }
    if opts.display_bench {
        // Only once the display has every frame: the stream must not mix with pixels.
        world.barrier();
        bandwidth_sender(world, opts)?;
    }
    Ok(())
}

/// Failure injection for the tests of what a dying rank does to the job: `DCRT_TEST_FAIL` set
/// to `panic@R` or `kill@R` makes rank R panic, or kill itself with SIGKILL, when it starts
/// tracing in its first frame (mid-frame for the others).
fn inject_failure(rank: u32, frame: u32) {
    let Ok(spec) = std::env::var("DCRT_TEST_FAIL") else {
        return;
    };
    let Some((what, r)) = spec.split_once('@') else {
        return;
    };
    if frame != 0 || r.parse() != Ok(rank) {
        return;
    }
    match what {
        "panic" => panic!("DCRT_TEST_FAIL: rank {rank} panics mid-frame"),
        "kill" => {
            let _ = std::process::Command::new("kill")
                .args(["-9", &std::process::id().to_string()])
                .status();
        }
        _ => {}
    }
}

/// Waits for the balancer's answer while letting MPI progress.
fn wait_work(world: &SimpleCommunicator, roles: Roles, timeout: Duration) -> Result<Vec<u8>> {
    let from = world.process_at_rank(roles.balancer() as i32);
    let start = Instant::now();
    let mut empty = 0u32;
    loop {
        if let Some(probed) = from.immediate_matched_probe_with_tag(TAG_WORK) {
            return Ok(probed.matched_receive_vec::<u8>().0);
        }
        empty += 1;
        idle(empty, start);
        if start.elapsed() > timeout {
            return Err(Error::Invalid(format!(
                "no answer from the balancer for {:.0} s",
                timeout.as_secs_f64()
            )));
        }
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

/// The balancer's state over all frames.
struct Balancer {
    roles: Roles,
    frames: u32,
    width: u32,
    height: u32,
    tile: u32,
    min_tile: u32,
    schedules: BTreeMap<u32, Schedule>,
    /// The last frame each render rank asked about, and the frames it was told are over.
    asked: Vec<Option<u32>>,
    ended: Vec<u32>,
    /// Grants per frame, for the traces.
    events: BTreeMap<u32, Vec<serde_json::Value>>,
    start: Instant,
}

impl Balancer {
    fn new(roles: Roles, opts: &Options, image: Image) -> Balancer {
        let n = roles.render_ranks() as usize;
        Balancer {
            roles,
            frames: opts.frames,
            width: image.width,
            height: image.height,
            tile: opts.tile,
            min_tile: opts.min_tile,
            schedules: BTreeMap::new(),
            asked: vec![None; n],
            ended: vec![0; n],
            events: BTreeMap::new(),
            start: Instant::now(),
        }
    }

    fn finished(&self) -> bool {
        self.ended.iter().all(|&e| e >= self.frames)
    }

    /// Answers an `ASK(frame)` from world rank `from`.
    fn ask(&mut self, world: &SimpleCommunicator, from: u32, msg: &[u8]) -> Result<()> {
        let w = read_words(msg)?;
        let (Some(i), &[frame]) = (self.roles.render_index(from), &w[..]) else {
            return Err(Error::Invalid(format!(
                "bad request {w:?} from rank {from}"
            )));
        };
        if frame >= self.frames || frame < self.ended[i as usize] {
            return Err(Error::Invalid(format!(
                "rank {from} asked for frame {frame}, which is over or beyond the last"
            )));
        }
        let (w, h, r) = (self.width, self.height, self.roles.render_ranks());
        let (tile, min) = (self.tile, self.min_tile);
        let sched = self
            .schedules
            .entry(frame)
            .or_insert_with(|| Schedule::new(w, h, r, tile, min));
        let first = self.asked[i as usize] != Some(frame);
        self.asked[i as usize] = Some(frame);
        let (grant, kind) = if first {
            (sched.first(i), "static")
        } else {
            (sched.next_tile().into_iter().collect(), "dynamic")
        };
        let mut reply = vec![frame, grant.len() as u32];
        for t in &grant {
            reply.extend([t.x, t.y, t.w, t.h]);
        }
        let events = self.events.entry(frame).or_default();
        let t = ms(self.start.elapsed());
        for g in &grant {
            events.push(
                json!({"type": "grant", "rank": from, "kind": kind, "t_ms": t,
                               "x": g.x, "y": g.y, "w": g.w, "h": g.h}),
            );
        }
        if grant.is_empty() {
            events.push(json!({"type": "grant", "rank": from, "kind": "end", "t_ms": t}));
            self.ended[i as usize] = frame + 1;
            if self.ended.iter().all(|&e| e > frame) {
                self.schedules.remove(&frame);
            }
        }
        world
            .process_at_rank(from as i32)
            .send_with_tag(&words(&reply)[..], TAG_WORK);
        Ok(())
    }

    /// The grants of frames every rank has finished asking about.
    fn take_finished_events(&mut self) -> Vec<(u32, Vec<serde_json::Value>)> {
        let done = self.ended.iter().copied().min().unwrap_or(0);
        let frames: Vec<u32> = self.events.range(..done).map(|(&f, _)| f).collect();
        frames
            .into_iter()
            .filter_map(|f| self.events.remove(&f).map(|e| (f, e)))
            .collect()
    }
}

/// One frame at the display.
struct Assembly {
    buf: Arc<FrameBuf>,
    done: u32,
    messages: u64,
    bytes: u64,
    first_ms: f64,
    render: Vec<serde_json::Value>,
}

impl Assembly {
    fn new(image: Image, wire: Wire, start: Instant) -> Assembly {
        Assembly {
            buf: Arc::new(FrameBuf::new(image.width, image.height, wire)),
            done: 0,
            messages: 0,
            bytes: 0,
            first_ms: ms(start.elapsed()),
            render: Vec::new(),
        }
    }
}

/// Rank 0 (display, and balancer with 2 ranks) or rank 1 (balancer).
fn coordinate(
    world: &SimpleCommunicator,
    roles: Roles,
    rank: u32,
    opts: &Options,
    image: Image,
) -> Result<()> {
    let mut balancer = (rank == roles.balancer()).then(|| Balancer::new(roles, opts, image));
    let display = rank == Roles::DISPLAY;
    let wire = if opts.exr.is_some() {
        Wire::Full
    } else {
        Wire::Rgb8
    };
    let mut copiers = Copiers::new(opts.copy_threads);
    let mut frames: BTreeMap<u32, Assembly> = BTreeMap::new();
    let mut written = 0u32;
    let mut writers: Vec<JoinHandle<Result<()>>> = Vec::new();
    let start = Instant::now();
    let mut shown = Vec::new();
    let mut report = Vec::new();
    while balancer.as_ref().is_some_and(|b| !b.finished()) || (display && written < opts.frames) {
        let (msg, from, tag) = wait_message(world, opts.timeout)?;
        match tag {
            TAG_ASK => {
                let b = balancer
                    .as_mut()
                    .ok_or_else(|| Error::Invalid(format!("rank {rank} is not the balancer")))?;
                b.ask(world, from, &msg)?;
                if !display && let Some(dir) = &opts.trace {
                    for (f, events) in b.take_finished_events() {
                        write_events(dir, f, rank, roles, events)?;
                    }
                }
            }
            TAG_PIXELS if display => {
                let f = message_frame(&msg)?;
                let a = frames
                    .entry(f)
                    .or_insert_with(|| Assembly::new(image, wire, start));
                a.messages += 1;
                a.bytes += msg.len() as u64;
                copiers.copy(&a.buf, msg);
            }
            TAG_DONE if display => {
                let f = message_frame(&msg)?;
                let stats: serde_json::Value = serde_json::from_slice(&msg[4..]).map_err(|e| {
                    Error::Invalid(format!("frame statistics from rank {from}: {e}"))
                })?;
                let a = frames
                    .entry(f)
                    .or_insert_with(|| Assembly::new(image, wire, start));
                a.done += 1;
                a.render.push(stats);
                if a.done == roles.render_ranks() {
                    let a = frames.remove(&f).expect("present");
                    let t = Instant::now();
                    copiers.fence()?;
                    let copy_wait = ms(t.elapsed());
                    let copied = a.buf.copied();
                    let want = u64::from(image.width) * u64::from(image.height);
                    if copied != want {
                        return Err(Error::Invalid(format!(
                            "frame {f}: the render ranks sent {copied} pixels of {want}"
                        )));
                    }
                    let buf = Arc::into_inner(a.buf)
                        .ok_or_else(|| Error::Invalid("frame still being copied".into()))?;
                    let complete_ms = ms(start.elapsed());
                    shown.push(complete_ms);
                    summarize(f, &a.render, complete_ms - a.first_ms, opts);
                    report.push(json!({
                        "frame": f, "complete_ms": complete_ms,
                        "span_ms": complete_ms - a.first_ms, "messages": a.messages,
                        "bytes": a.bytes, "render": &a.render,
                    }));
                    let mut events = a.render;
                    for e in &mut events {
                        e["type"] = "render".into();
                    }
                    events.push(json!({
                        "type": "display", "messages": a.messages, "bytes": a.bytes,
                        "pixels": copied, "first_message_ms": a.first_ms,
                        "complete_ms": complete_ms, "copy_wait_ms": copy_wait,
                        "copy_threads": opts.copy_threads,
                    }));
                    // With 2 ranks the display also balances: its grants go in the same file.
                    if let Some(b) = balancer.as_mut() {
                        for (_, e) in b.take_finished_events() {
                            events.extend(e);
                        }
                    }
                    let opts = opts.clone();
                    writers.push(std::thread::spawn(move || {
                        // The display benchmark measures receiving and assembling frames; only
                        // its last frame is encoded, to show what was received.
                        if !opts.display_bench || f + 1 == opts.frames {
                            write_frame(&opts, f, buf, wire)?;
                        }
                        if let Some(dir) = &opts.trace {
                            write_events(dir, f, rank, roles, events)?;
                        }
                        Ok(())
                    }));
                    written += 1;
                }
            }
            other => {
                return Err(Error::Invalid(format!(
                    "unexpected message (tag {other}) from rank {from} at rank {rank}"
                )));
            }
        }
    }
    for w in writers {
        w.join()
            .map_err(|_| Error::Invalid("an image writer panicked".into()))??;
    }
    if opts.display_bench {
        world.barrier();
    }
    if !display {
        return Ok(());
    }
    let bench = if opts.display_bench {
        Some(display_bench(world, roles, opts, image, &shown)?)
    } else {
        None
    };
    if let Some(path) = &opts.stats {
        let all = json!({
            "ranks": roles.size, "render_ranks": roles.render_ranks(),
            "width": image.width, "height": image.height,
            "cache": opts.cache.map(|(c, m)| format!("{c:?} {m:?}")),
            "frames": report, "display_bench": bench,
        });
        std::fs::write(path, all.to_string()).map_err(|e| Error::io(path, e))?;
    }
    Ok(())
}

/// One line per frame on stderr, from the render ranks' statistics.
fn summarize(f: u32, render: &[serde_json::Value], span_ms: f64, opts: &Options) {
    let get = |k: &str| -> f64 {
        render
            .iter()
            .map(|r| r["stats"][k].as_f64().unwrap_or(0.0))
            .sum()
    };
    let slowest = render
        .iter()
        .map(|r| r["stats"]["seconds"].as_f64().unwrap_or(0.0))
        .fold(0.0, f64::max);
    eprintln!(
        "frame {f}: {} render ranks, slowest {:.1} ms, pixels over {:.1} ms, {} tiles, {} fault \
         rounds, {} blocks fetched ({:.1} ms fetching), wrote {}",
        render.len(),
        slowest * 1e3,
        span_ms,
        render
            .iter()
            .map(|r| r["tiles"].as_u64().unwrap_or(0))
            .sum::<u64>(),
        get("fault_rounds"),
        get("fetched_blocks"),
        get("fetch_seconds") * 1e3,
        output::numbered(&opts.output, f, opts.frames).display()
    );
}

fn write_frame(opts: &Options, f: u32, buf: FrameBuf, wire: Wire) -> Result<()> {
    let png = output::numbered(&opts.output, f, opts.frames);
    match wire {
        Wire::Rgb8 => {
            let (w, h) = (buf.width, buf.height);
            let img = image::RgbImage::from_raw(w, h, buf.into_bytes())
                .ok_or_else(|| Error::Invalid("frame buffer of the wrong size".into()))?;
            output::save_png(&png, &img)
        }
        Wire::Full => {
            let frame = buf.into_frame();
            output::write_png_exposed(&png, &frame, opts.exposure)?;
            if let Some(exr) = &opts.exr {
                output::write_exr(&output::numbered(exr, f, opts.frames), &frame, &opts.aovs)?;
            }
            Ok(())
        }
    }
}

fn write_events(
    dir: &std::path::Path,
    frame: u32,
    rank: u32,
    roles: Roles,
    events: Vec<serde_json::Value>,
) -> Result<()> {
    let mut t = FrameTrace {
        events,
        ..FrameTrace::default()
    };
    t.summary.frame = frame;
    t.summary.rank = rank;
    t.summary.ranks = roles.size;
    t.summary.role = roles.name(rank).into();
    t.summary.hit_rate = 1.0;
    t.write(dir).map(|_| ())
}

/// Bytes each render rank streams to the display to measure the link.
const BANDWIDTH_BYTES: usize = 64 << 20;

/// After the frames of the display benchmark: stream raw messages of the pixel-message size.
fn bandwidth_sender(world: &SimpleCommunicator, opts: &Options) -> Result<()> {
    let display = world.process_at_rank(Roles::DISPLAY as i32);
    let msg = vec![0u8; opts.message_bytes.max(1)];
    let n = BANDWIDTH_BYTES / msg.len();
    for _ in 0..n {
        display.send_with_tag(&msg[..], TAG_BANDWIDTH);
    }
    display.send_with_tag(&[0u8; 0][..], TAG_BANDWIDTH);
    Ok(())
}

/// The display benchmark's figures: frames per second and pixels per second over the frames
/// after the first, against the MPI bandwidth measured right after with the same message size.
fn display_bench(
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
        let (msg, from, tag) = wait_message(world, opts.timeout)?;
        if tag != TAG_BANDWIDTH {
            return Err(Error::Invalid(format!(
                "unexpected message (tag {tag}) from rank {from} in the bandwidth test"
            )));
        }
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
    eprintln!("display benchmark: {report}");
    Ok(report)
}
