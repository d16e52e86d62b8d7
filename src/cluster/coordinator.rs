//! The ranks that do not render: rank 0 (the display, and the balancer with 2 ranks) and rank 1
//! (the balancer). Each takes messages as they come and hands them to its roles.

use super::balancer::Balancer;
use super::display::{Display, write_events};
use super::liveness::Liveness;
use super::mailbox::{next_within, send};
use super::protocol::{Message, Tag};
use super::startup::Image;
use super::{Options, Roles};
use crate::error::{Error, Result};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::time::{Duration, Instant};

/// How long one wait for a message lasts before the coordinator looks for silent ranks.
const SLICE: Duration = Duration::from_millis(50);

pub fn run(
    world: &SimpleCommunicator,
    roles: Roles,
    rank: u32,
    opts: &Options,
    image: Image,
    legend: Option<crate::legend::Legend>,
) -> Result<()> {
    let mut balancer = (rank == roles.balancer()).then(|| Balancer::new(roles, opts));
    let mut display =
        (rank == Roles::DISPLAY).then(|| Display::new(roles, rank, opts, image, legend));
    let mut live = Liveness::new(roles.size, opts.timeout, Instant::now());
    let (mut last_message, mut last_check) = (Instant::now(), Instant::now());
    while balancer.as_ref().is_some_and(|b| !b.finished())
        || display.as_ref().is_some_and(|d| !d.finished())
    {
        let next = next_within(world, SLICE);
        let now = Instant::now();
        // Checked between messages too: the ranks that still work keep them coming.
        if now - last_check >= SLICE {
            last_check = now;
            match &display {
                Some(d) => {
                    let (frame, waited_on) = d.waiting_on();
                    // The timeout, not the measured silence: the message is what it promises.
                    if let Some((r, _)) = live.silent(waited_on, now) {
                        return Err(Error::Timeout {
                            what: format!(
                                "message from rank {r} (render) while frame {frame} waits for it"
                            ),
                            seconds: opts.timeout.as_secs_f64(),
                            likely: Some("it has stopped, hung or died"),
                        });
                    }
                }
                // The balancer alone (the display watches the render ranks): no message from
                // any rank for the timeout.
                None if now - last_message > opts.timeout => {
                    return Err(Error::Timeout {
                        what: "message from any rank".into(),
                        seconds: opts.timeout.as_secs_f64(),
                        likely: Some("a rank has hung or died"),
                    });
                }
                None => {}
            }
        }
        let Some((bytes, from, tag)) = next else {
            continue;
        };
        last_message = now;
        live.heard(from, now);
        match (
            Message::decode(tag, from, bytes)?,
            &mut balancer,
            &mut display,
        ) {
            // From a busy render rank to the display; from a live view's waiting display.
            (Message::Alive, _, _) => {}
            (Message::Ask(ask), Some(b), display) => {
                let work = b.ask(from, ask)?;
                send(world, from, Tag::Work, &work.encode());
                if display.is_none()
                    && let Some(dir) = &opts.trace
                {
                    for (f, events) in b.take_finished_events() {
                        write_events(dir, f, rank, roles, events)?;
                    }
                }
            }
            (Message::Pixels { frame, bytes }, _, Some(d)) => d.pixels(frame, from, bytes),
            (Message::Done(report), b, Some(d)) => d.done(report, b.as_mut())?,
            (m, _, _) => {
                return Err(Error::Protocol(format!(
                    "unexpected {} message from rank {from} at rank {rank}",
                    m.tag().name()
                )));
            }
        }
    }
    match display {
        Some(d) => d.finish(world),
        None => {
            if opts.display_bench {
                world.barrier();
            }
            Ok(())
        }
    }
}
