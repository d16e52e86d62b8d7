//! The display role (rank 0): assembles each frame from the render ranks' pixel messages on its
//! copy threads, and once every render rank's report of the frame is in, writes the image (on a
//! thread of its own), the frame's trace and a line on stderr; at the end, the statistics file.

use super::balancer::Balancer;
use super::display_bench;
use super::pixels::{Copiers, FrameBuf, Wire};
use super::protocol::FrameReport;
use super::startup::Image;
use super::{Options, Roles};
use crate::error::{Error, Result};
use crate::files;
use crate::gpu::frame::ms;
use crate::output;
use crate::traces::record::{self, Event, FrameTrace};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use serde_json::json;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

/// One frame at the display.
struct Assembly {
    buf: Arc<FrameBuf>,
    done: u32,
    messages: u64,
    bytes: u64,
    first_ms: f64,
    render: Vec<FrameReport>,
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

pub struct Display<'a> {
    roles: Roles,
    rank: u32,
    opts: &'a Options,
    image: Image,
    wire: Wire,
    copiers: Copiers,
    frames: BTreeMap<u32, Assembly>,
    written: u32,
    writers: Vec<JoinHandle<Result<()>>>,
    start: Instant,
    /// When each frame was complete, in ms since `start`.
    shown: Vec<f64>,
    /// Each frame's figures, for the statistics file.
    report: Vec<serde_json::Value>,
    /// Drawn on every PNG (`--legend`).
    legend: Option<crate::legend::Legend>,
}

impl<'a> Display<'a> {
    pub fn new(
        roles: Roles,
        rank: u32,
        opts: &'a Options,
        image: Image,
        legend: Option<crate::legend::Legend>,
    ) -> Display<'a> {
        let wire = if opts.exr.is_some() {
            Wire::Full
        } else {
            Wire::Rgb8
        };
        Display {
            roles,
            rank,
            opts,
            image,
            wire,
            copiers: Copiers::new(opts.copy_threads),
            frames: BTreeMap::new(),
            written: 0,
            writers: Vec::new(),
            start: super::clock::epoch(),
            shown: Vec::new(),
            report: Vec::new(),
            legend,
        }
    }

    /// Whether every frame has been handed to its writer.
    pub fn finished(&self) -> bool {
        self.written >= self.opts.frames
    }

    /// The frame the display waits for (frames complete in order: each needs every render rank,
    /// and each rank renders them in order) and the world ranks whose `DONE` of it is not in.
    pub fn waiting_on(&self) -> (u32, Vec<u32>) {
        let frame = self.written;
        let done: Vec<u32> = self
            .frames
            .get(&frame)
            .map(|a| a.render.iter().map(|r| r.rank).collect())
            .unwrap_or_default();
        let ranks = (0..self.roles.render_ranks())
            .map(|i| self.roles.render_rank(i))
            .filter(|r| !done.contains(r))
            .collect();
        (frame, ranks)
    }

    fn assembly(&mut self, frame: u32) -> &mut Assembly {
        let (image, wire, start) = (self.image, self.wire, self.start);
        self.frames
            .entry(frame)
            .or_insert_with(|| Assembly::new(image, wire, start))
    }

    /// A `PIXELS` message of `frame` from rank `from`.
    pub fn pixels(&mut self, frame: u32, from: u32, bytes: Vec<u8>) {
        let a = self.assembly(frame);
        a.messages += 1;
        a.bytes += bytes.len() as u64;
        let buf = a.buf.clone();
        self.copiers.copy(&buf, from, bytes);
    }

    /// A render rank's `DONE`; with 2 ranks the display also balances, and the frame's grants go
    /// in its trace.
    pub fn done(&mut self, report: FrameReport, balancer: Option<&mut Balancer>) -> Result<()> {
        let f = report.frame;
        let a = self.assembly(f);
        a.done += 1;
        a.render.push(report);
        if a.done < self.roles.render_ranks() {
            return Ok(());
        }
        let (opts, image) = (self.opts, self.image);
        let a = self.frames.remove(&f).expect("present");
        let t = Instant::now();
        self.copiers.fence()?;
        let copy_wait = ms(t.elapsed());
        let copied = a.buf.copied();
        let want = u64::from(image.width) * u64::from(image.height);
        if copied != want {
            return Err(Error::Protocol(format!(
                "frame {f}: the render ranks sent {copied} pixels of {want}"
            )));
        }
        let buf = Arc::into_inner(a.buf)
            .ok_or_else(|| Error::Internal("frame still being copied".into()))?;
        let complete_ms = ms(self.start.elapsed());
        self.shown.push(complete_ms);
        summarize(f, &a.render, complete_ms - a.first_ms, opts);
        let render: Vec<serde_json::Value> = a.render.iter().map(FrameReport::to_json).collect();
        self.report.push(json!({
            "frame": f, "complete_ms": complete_ms,
            "span_ms": complete_ms - a.first_ms, "messages": a.messages,
            "bytes": a.bytes, "render": &render,
        }));
        let mut events: Vec<Event> = a
            .render
            .iter()
            .map(|r| Event::Render(r.to_record()))
            .collect();
        events.push(Event::Display(record::Display {
            messages: a.messages,
            bytes: a.bytes,
            pixels: copied,
            first_message_ms: a.first_ms,
            complete_ms,
            copy_wait_ms: copy_wait,
            copy_threads: opts.copy_threads,
        }));
        if let Some(b) = balancer {
            for (_, e) in b.take_finished_events() {
                events.extend(e);
            }
        }
        let (opts, rank, roles, wire) = (opts.clone(), self.rank, self.roles, self.wire);
        let legend = self.legend.clone();
        self.writers.push(std::thread::spawn(move || {
            // The display benchmark measures receiving and assembling frames; only its last
            // frame is encoded, to show what was received.
            if !opts.display_bench || f + 1 == opts.frames {
                let files = write_frame(&opts, f, buf, wire, legend.as_ref())?;
                let files: Vec<&std::path::Path> = files.iter().map(|p| p.as_path()).collect();
                files::keep_frame(f, &files);
            }
            if let Some(dir) = &opts.trace {
                write_events(dir, f, rank, roles, events)?;
            }
            Ok(())
        }));
        self.written += 1;
        Ok(())
    }

    /// After the last frame: waits for the writers, runs the display benchmark, writes the
    /// statistics file.
    pub fn finish(self, world: &SimpleCommunicator) -> Result<()> {
        for w in self.writers {
            w.join()
                .map_err(|_| Error::Internal("an image writer panicked".into()))??;
        }
        let (roles, opts, image) = (self.roles, self.opts, self.image);
        let bench = if opts.display_bench {
            world.barrier();
            Some(display_bench::measure(
                world,
                roles,
                opts,
                image,
                &self.shown,
            )?)
        } else {
            None
        };
        if let Some(path) = &opts.stats {
            let all = json!({
                "ranks": roles.size, "render_ranks": roles.render_ranks(),
                "width": image.width, "height": image.height,
                "cache": opts.cache.map(|c| format!("{:?} {:?} {:?}", c.size, c.map, c.replicate)),
                "frames": self.report, "display_bench": bench,
            });
            files::write_bytes(path, all.to_string().as_bytes())?;
        }
        Ok(())
    }
}

/// One line per frame on stderr, from the render ranks' reports.
fn summarize(f: u32, render: &[FrameReport], span_ms: f64, opts: &Options) {
    let slowest = render.iter().map(|r| r.stats.seconds).fold(0.0, f64::max);
    crate::report!(
        "frame {f}: {} render ranks, slowest {:.1} ms, pixels over {:.1} ms, {} tiles, {} fault \
         rounds, {} blocks fetched ({:.1} ms fetching), wrote {}",
        render.len(),
        slowest * 1e3,
        span_ms,
        render.iter().map(|r| r.tiles).sum::<u64>(),
        render.iter().map(|r| r.stats.fault_rounds).sum::<u64>(),
        render.iter().map(|r| r.stats.fetched_blocks).sum::<u64>(),
        render.iter().map(|r| r.stats.fetch_seconds).sum::<f64>() * 1e3,
        files::numbered(&opts.output, f, opts.frames).display()
    );
}

/// Writes frame `f`'s PNG (and EXR): the paths written.
fn write_frame(
    opts: &Options,
    f: u32,
    buf: FrameBuf,
    wire: Wire,
    legend: Option<&crate::legend::Legend>,
) -> Result<Vec<std::path::PathBuf>> {
    let png = files::numbered(&opts.output, f, opts.frames);
    match wire {
        Wire::Rgb8 => {
            let (w, h) = (buf.width, buf.height);
            let mut img = image::RgbImage::from_raw(w, h, buf.into_bytes())
                .ok_or_else(|| Error::Internal("frame buffer of the wrong size".into()))?;
            if let Some(l) = legend {
                l.draw(&mut img)?;
            }
            files::write_rgb_png(&png, &img)?;
            Ok(vec![png])
        }
        Wire::Full => {
            let frame = buf.into_frame();
            output::write_png_legend(&png, &frame, opts.exposure, legend)?;
            let mut files = vec![png];
            if let Some(exr) = &opts.exr {
                let exr = files::numbered(exr, f, opts.frames);
                output::write_exr(&exr, &frame, &opts.aovs)?;
                files.push(exr);
            }
            Ok(files)
        }
    }
}

/// The trace file of frame `frame` at a rank that does not render (display, balancer).
pub fn write_events(
    dir: &std::path::Path,
    frame: u32,
    rank: u32,
    roles: Roles,
    events: Vec<Event>,
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
