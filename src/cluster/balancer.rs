//! The balancer role: answers the render ranks' `ASK`s from each frame's `Schedule`, and keeps
//! the grants of every frame for the traces. A frame's image size comes with its first `ASK`
//! (a live view changes it from frame to frame); every rank's must agree.

use super::protocol::{Ask, Tag, Work, malformed};
use super::schedule::Schedule;
use super::{Options, Roles};
use crate::error::Result;
use crate::gpu::frame::ms;
use crate::traces::record::{Event, Grant, GrantKind};
use std::collections::BTreeMap;
use std::time::Instant;

/// The balancer's state over all frames.
pub struct Balancer {
    roles: Roles,
    /// The frames of the job; a live view's never end.
    frames: u32,
    tile: u32,
    min_tile: u32,
    /// Each open frame's schedule and image size.
    schedules: BTreeMap<u32, (Schedule, (u32, u32))>,
    /// The last frame each render rank asked about, and the frames it was told are over.
    asked: Vec<Option<u32>>,
    ended: Vec<u32>,
    /// Grants per frame, for the traces.
    events: BTreeMap<u32, Vec<Event>>,
    start: Instant,
}

impl Balancer {
    pub fn new(roles: Roles, opts: &Options) -> Balancer {
        let frames = if opts.live { u32::MAX } else { opts.frames };
        Balancer::with(roles, frames, opts.tile, opts.min_tile)
    }

    fn with(roles: Roles, frames: u32, tile: u32, min_tile: u32) -> Balancer {
        let n = roles.render_ranks() as usize;
        Balancer {
            roles,
            frames,
            tile,
            min_tile,
            schedules: BTreeMap::new(),
            asked: vec![None; n],
            ended: vec![0; n],
            events: BTreeMap::new(),
            start: super::clock::epoch(),
        }
    }

    /// Whether every render rank has been told that the last frame is over.
    pub fn finished(&self) -> bool {
        self.ended.iter().all(|&e| e >= self.frames)
    }

    /// The answer to an `ASK` from world rank `from`.
    pub fn ask(&mut self, from: u32, ask: Ask) -> Result<Work> {
        let Some(i) = self.roles.render_index(from) else {
            return Err(malformed(Tag::Ask, from, "not from a render rank"));
        };
        let frame = ask.frame;
        if frame >= self.frames || frame < self.ended[i as usize] {
            return Err(malformed(
                Tag::Ask,
                from,
                format!("frame {frame} is over or beyond the last"),
            ));
        }
        let (w, h, r) = (ask.width, ask.height, self.roles.render_ranks());
        let (tile, min) = (self.tile, self.min_tile);
        let (sched, size) = self
            .schedules
            .entry(frame)
            .or_insert_with(|| (Schedule::new(w, h, r, tile, min), (w, h)));
        if *size != (w, h) {
            return Err(malformed(
                Tag::Ask,
                from,
                format!(
                    "frame {frame} at {w}x{h}, which another rank asked about at {}x{}",
                    size.0, size.1
                ),
            ));
        }
        let first = self.asked[i as usize] != Some(frame);
        self.asked[i as usize] = Some(frame);
        let (grant, kind) = if first {
            (sched.first(i), GrantKind::Static)
        } else {
            (sched.next_tile().into_iter().collect(), GrantKind::Dynamic)
        };
        let events = self.events.entry(frame).or_default();
        let t = ms(self.start.elapsed());
        for g in &grant {
            events.push(Event::Grant(Grant {
                rank: from,
                kind,
                t_ms: t,
                x: Some(g.x),
                y: Some(g.y),
                w: Some(g.w),
                h: Some(g.h),
            }));
        }
        if grant.is_empty() {
            events.push(Event::Grant(Grant {
                rank: from,
                kind: GrantKind::End,
                t_ms: t,
                x: None,
                y: None,
                w: None,
                h: None,
            }));
            self.ended[i as usize] = frame + 1;
            if self.ended.iter().all(|&e| e > frame) {
                self.schedules.remove(&frame);
            }
        }
        Ok(Work {
            frame,
            tiles: grant,
        })
    }

    /// The grants of frames every rank has finished asking about.
    pub fn take_finished_events(&mut self) -> Vec<(u32, Vec<Event>)> {
        let done = self.ended.iter().copied().min().unwrap_or(0);
        let frames: Vec<u32> = self.events.range(..done).map(|(&f, _)| f).collect();
        frames
            .into_iter()
            .filter_map(|f| self.events.remove(&f).map(|e| (f, e)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each frame's tiles cover that frame's size, as its first `ASK` gave it; a rank asking
    /// about the same frame at another size is refused, naming both.
    #[test]
    fn each_frame_is_scheduled_at_the_size_it_is_asked_at() {
        let roles = Roles::new(4).unwrap();
        let mut b = Balancer::with(roles, u32::MAX, 16, 8);
        for (frame, (w, h)) in [(0, (64, 48)), (1, (20, 12))] {
            let mut covered = 0u64;
            for rank in [2, 3] {
                loop {
                    let ask = Ask {
                        frame,
                        width: w,
                        height: h,
                    };
                    let work = b.ask(rank, ask).unwrap();
                    if work.tiles.is_empty() {
                        break;
                    }
                    for t in &work.tiles {
                        assert!(t.x + t.w <= w && t.y + t.h <= h, "{t:?} in {w}x{h}");
                        covered += u64::from(t.w) * u64::from(t.h);
                    }
                }
            }
            assert_eq!(covered, u64::from(w) * u64::from(h), "frame {frame}");
        }
        b.ask(
            2,
            Ask {
                frame: 2,
                width: 64,
                height: 48,
            },
        )
        .unwrap();
        let e = b
            .ask(
                3,
                Ask {
                    frame: 2,
                    width: 32,
                    height: 48,
                },
            )
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("frame 2 at 32x48, which another rank asked about at 64x48"),
            "{e}"
        );
    }
}
