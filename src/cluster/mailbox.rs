//! Sending and waiting for messages over MPI. Waits probe without blocking, so that they can give
//! up after the job's timeout and leave the cores to the ranks that work (ranks outnumber cores).

use super::protocol::Tag;
use crate::error::{Error, Result};
use mpi::point_to_point::MatchedReceiveVec;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::time::{Duration, Instant};

pub fn send(world: &SimpleCommunicator, to: u32, tag: Tag, bytes: &[u8]) {
    world
        .process_at_rank(to as i32)
        .send_with_tag(bytes, tag.raw());
}

/// Between two empty probes: give the core away at once, and after a millisecond of waiting
/// sleep, so that waiting ranks leave the cores to the ones that work.
fn idle(probes: u32, since: Instant) {
    if probes < 8 || since.elapsed() < Duration::from_millis(1) {
        std::thread::yield_now();
    } else {
        std::thread::sleep(Duration::from_micros(100));
    }
}

/// Waits for the next message (any source, any tag) for at most `timeout`: its bytes, sender and
/// tag.
pub fn wait_any(world: &SimpleCommunicator, timeout: Duration) -> Result<(Vec<u8>, u32, i32)> {
    next_within(world, timeout).ok_or_else(|| Error::Timeout {
        what: "message from any rank".into(),
        seconds: timeout.as_secs_f64(),
        likely: Some("a rank has hung or died"),
    })
}

/// The next message (any source, any tag) if one comes within `slice`: its bytes, sender and
/// tag.
pub fn next_within(world: &SimpleCommunicator, slice: Duration) -> Option<(Vec<u8>, u32, i32)> {
    let start = Instant::now();
    let mut empty = 0u32;
    loop {
        if let Some(probed) = world.any_process().immediate_matched_probe() {
            let (data, status) = probed.matched_receive_vec::<u8>();
            return Some((data, status.source_rank() as u32, status.tag()));
        }
        empty += 1;
        idle(empty, start);
        if start.elapsed() > slice {
            return None;
        }
    }
}

/// The next `tag` message from rank `from`, if one is in.
pub fn poll_from(world: &SimpleCommunicator, from: u32, tag: Tag) -> Option<Vec<u8>> {
    let probed = world
        .process_at_rank(from as i32)
        .immediate_matched_probe_with_tag(tag.raw())?;
    Some(probed.matched_receive_vec::<u8>().0)
}

/// Waits for a `tag` message from rank `from` for at most `timeout`; `what` names it in the
/// error.
pub fn wait_from(
    world: &SimpleCommunicator,
    from: u32,
    tag: Tag,
    what: &str,
    timeout: Duration,
) -> Result<Vec<u8>> {
    let start = Instant::now();
    let mut empty = 0u32;
    loop {
        if let Some(msg) = poll_from(world, from, tag) {
            return Ok(msg);
        }
        empty += 1;
        idle(empty, start);
        if start.elapsed() > timeout {
            return Err(Error::Timeout {
                what: what.into(),
                seconds: timeout.as_secs_f64(),
                likely: None,
            });
        }
    }
}
