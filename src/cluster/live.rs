//! The display rank of a live view (`dcrt view` under mpirun; docs/ARCHITECTURE.md, Live view):
//! the frames are not known in advance, so the display makes them one at a time as its clients
//! ask: it sends every render rank the frame's `JOB`, answers `ASK`s when it also balances (2
//! ranks), and assembles the pixels until every render rank's `DONE` is in. It says `ALIVE` to
//! every rank each quarter of the timeout, between frames and during them, so that neither a
//! user who only looks nor a long frame is taken for a dead display by a rank waiting for its
//! next `JOB`.
//! The view itself (server, encoder, what to render next) is above this module and drives it.

use super::balancer::Balancer;
use super::liveness::{Heartbeat, Liveness};
use super::mailbox::{next_within, send, wait_from};
use super::pixels::{Copiers, FrameBuf, Wire};
use super::protocol::{FrameReport, Job, Message, Tag};
use super::startup::Image;
use super::{Options, Roles};
use crate::error::{Error, Result};
use crate::gpu::frame::Frame;
use crate::scene::Camera;
use crate::shading::Shading;
use mpi::topology::SimpleCommunicator;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How long one wait for a message lasts before the display looks for silent ranks.
const SLICE: Duration = Duration::from_millis(20);

/// A frame's pixels as they travelled.
pub enum Pixels {
    /// Linear, whole pixels (`Job::whole_pixels`).
    Whole(Frame),
    /// sRGB 8 bits, as the PNG stores them.
    Rgb8(image::RgbImage),
}

/// A frame made by the render ranks.
pub struct Assembled {
    pub pixels: Pixels,
    /// Every render rank's report, in rank order.
    pub reports: Vec<FrameReport>,
    /// From the job sent to the last pixel copied.
    pub seconds: f64,
}

pub struct LiveDisplay<'a> {
    world: &'a SimpleCommunicator,
    roles: Roles,
    opts: &'a Options,
    image: Image,
    shading: Shading,
    /// The model's camera, from the first render rank.
    home: Camera,
    /// With 2 ranks the display also balances.
    balancer: Option<Balancer>,
    copiers: Copiers,
    live: Liveness,
    heart: Heartbeat,
    /// The next frame's number.
    frame: u32,
}

impl<'a> LiveDisplay<'a> {
    /// The display of a live view, once the first render rank has said the model's camera.
    pub(super) fn start(
        world: &'a SimpleCommunicator,
        roles: Roles,
        opts: &'a Options,
        image: Image,
        shading: Shading,
    ) -> Result<LiveDisplay<'a>> {
        let first = roles.render_rank(0);
        let msg = wait_from(
            world,
            first,
            Tag::Home,
            &format!("the model's camera from rank {first} (render)"),
            opts.timeout,
        )?;
        let Message::Home(home) = Message::decode(Tag::Home.raw(), first, msg)? else {
            unreachable!("a HOME message decodes as one")
        };
        Ok(LiveDisplay {
            world,
            roles,
            opts,
            image,
            shading,
            home,
            balancer: (roles.balancer() == Roles::DISPLAY).then(|| Balancer::new(roles, opts)),
            copiers: Copiers::new(opts.copy_threads),
            live: Liveness::new(roles.size, opts.timeout, Instant::now()),
            heart: Heartbeat::new(opts.timeout),
            frame: 0,
        })
    }

    /// The full image's width and height, as every rank agreed.
    pub fn image(&self) -> (u32, u32) {
        (self.image.width, self.image.height)
    }

    /// The shading at rest, as every rank applied the command line to the scene's.
    pub fn shading(&self) -> Shading {
        self.shading
    }

    /// The model's camera (or the `--camera` file's).
    pub fn home(&self) -> Camera {
        self.home
    }

    pub fn render_ranks(&self) -> u32 {
        self.roles.render_ranks()
    }

    /// The world rank of render rank `index`.
    pub fn render_rank(&self, index: u32) -> u32 {
        self.roles.render_rank(index)
    }

    /// Makes one frame as `job` says (its `frame` is replaced by the next number).
    pub fn render(&mut self, job: &Job) -> Result<Assembled> {
        let (w, h) = (job.width, job.height);
        if w == 0 || h == 0 || w > self.image.width || h > self.image.height {
            return Err(Error::Internal(format!(
                "a live frame of {w}x{h} in a {}x{} view",
                self.image.width, self.image.height
            )));
        }
        let frame = self.frame;
        self.frame += 1;
        let job = Job {
            frame,
            ..job.clone()
        };
        let msg = job.encode()?;
        let start = Instant::now();
        // The ranks said nothing while the user only looked: their silence counts from now.
        self.live = Liveness::new(self.roles.size, self.opts.timeout, start);
        let n = self.roles.render_ranks();
        for i in 0..n {
            send(self.world, self.roles.render_rank(i), Tag::Job, &msg);
        }
        let wire = match job.whole_pixels {
            true => Wire::Full,
            false => Wire::Rgb8,
        };
        let buf = Arc::new(FrameBuf::new(w, h, wire));
        let mut reports: Vec<FrameReport> = Vec::new();
        let mut last_check = Instant::now();
        while reports.len() < n as usize {
            // A rank done with its part waits for the next `JOB`: a long frame is not silence.
            self.say_alive();
            let next = next_within(self.world, SLICE);
            let now = Instant::now();
            if now - last_check >= SLICE {
                last_check = now;
                let waited_on = (0..n)
                    .map(|i| self.roles.render_rank(i))
                    .filter(|r| reports.iter().all(|d| d.rank != *r));
                if let Some((r, _)) = self.live.silent(waited_on, now) {
                    return Err(Error::Timeout {
                        what: format!(
                            "message from rank {r} (render) while live frame {frame} waits for it"
                        ),
                        seconds: self.opts.timeout.as_secs_f64(),
                        likely: Some("it has stopped, hung or died"),
                    });
                }
            }
            let Some((bytes, from, tag)) = next else {
                continue;
            };
            self.live.heard(from, now);
            match Message::decode(tag, from, bytes)? {
                Message::Alive => {}
                Message::Ask(ask) if self.balancer.is_some() => {
                    let b = self.balancer.as_mut().expect("checked");
                    let work = b.ask(from, ask)?;
                    send(self.world, from, Tag::Work, &work.encode());
                }
                Message::Pixels { frame: f, bytes } if f == frame => {
                    self.copiers.copy(&buf, from, bytes);
                }
                Message::Done(report) if report.frame == frame => reports.push(report),
                m => {
                    return Err(Error::Protocol(format!(
                        "unexpected {} message from rank {from} in live frame {frame}",
                        m.tag().name()
                    )));
                }
            }
        }
        self.copiers.fence()?;
        let want = u64::from(w) * u64::from(h);
        if buf.copied() != want {
            return Err(Error::Protocol(format!(
                "live frame {frame}: the render ranks sent {} pixels of {want}",
                buf.copied()
            )));
        }
        let buf = Arc::into_inner(buf)
            .ok_or_else(|| Error::Internal("frame still being copied".into()))?;
        let pixels = match wire {
            Wire::Full => Pixels::Whole(buf.into_frame()),
            Wire::Rgb8 => Pixels::Rgb8(
                image::RgbImage::from_raw(w, h, buf.into_bytes())
                    .ok_or_else(|| Error::Internal("frame buffer of the wrong size".into()))?,
            ),
        };
        reports.sort_by_key(|r| r.rank);
        Ok(Assembled {
            pixels,
            reports,
            seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// Between frames, for at most `slice`: says `ALIVE` to every other rank when it is time,
    /// and takes in what comes (only late `ALIVE`s may).
    pub fn wait(&mut self, slice: Duration) -> Result<()> {
        self.say_alive();
        if let Some((bytes, from, tag)) = next_within(self.world, slice) {
            self.live.heard(from, Instant::now());
            match Message::decode(tag, from, bytes)? {
                Message::Alive => {}
                m => {
                    return Err(Error::Protocol(format!(
                        "unexpected {} message from rank {from} between live frames",
                        m.tag().name()
                    )));
                }
            }
        }
        Ok(())
    }

    /// `ALIVE` to every other rank when it is time.
    fn say_alive(&mut self) {
        if self.heart.due() {
            for r in 1..self.roles.size {
                send(self.world, r, Tag::Alive, &[]);
            }
        }
    }
}
