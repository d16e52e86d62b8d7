//! The ranks that do not render: rank 0 (the display, and the balancer with 2 ranks) and rank 1
//! (the balancer). Each takes messages as they come and hands them to its roles.

use super::balancer::Balancer;
use super::display::{Display, write_events};
use super::mailbox::{send, wait_any};
use super::protocol::{Message, Tag};
use super::startup::Image;
use super::{Options, Roles};
use crate::error::{Error, Result};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;

pub fn run(
    world: &SimpleCommunicator,
    roles: Roles,
    rank: u32,
    opts: &Options,
    image: Image,
    legend: Option<crate::legend::Legend>,
) -> Result<()> {
    let mut balancer = (rank == roles.balancer()).then(|| Balancer::new(roles, opts, image));
    let mut display =
        (rank == Roles::DISPLAY).then(|| Display::new(roles, rank, opts, image, legend));
    while balancer.as_ref().is_some_and(|b| !b.finished())
        || display.as_ref().is_some_and(|d| !d.finished())
    {
        let (bytes, from, tag) = wait_any(world, opts.timeout)?;
        match (
            Message::decode(tag, from, bytes)?,
            &mut balancer,
            &mut display,
        ) {
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
