//! Telling a rank that works from one that has stopped (docs/ARCHITECTURE.md, Cluster). A frozen
//! node (SIGSTOP, swap, a stuck driver, a paused VM) still holds its MPI connections, so nothing
//! fails: the ranks that wait on it would wait for ever while the others keep the message
//! traffic going. So the display counts, for each rank, the time since it last heard from it,
//! and a rank that a frame waits for and that has said nothing for the job's timeout ends the
//! job. A render rank busy on its GPU says `ALIVE` every `beat` so that a long tile is not
//! taken for silence.

use std::time::{Duration, Instant};

/// How often a busy render rank says `ALIVE`: four times within the timeout, so that one late
/// message is not silence.
pub fn beat(timeout: Duration) -> Duration {
    (timeout / 4).max(Duration::from_millis(50))
}

/// When a busy rank is next to say `ALIVE`.
pub struct Heartbeat {
    beat: Duration,
    said: Instant,
}

impl Heartbeat {
    pub fn new(timeout: Duration) -> Heartbeat {
        Heartbeat {
            beat: beat(timeout),
            said: Instant::now(),
        }
    }

    /// Whether it is time to say `ALIVE` (and if so, the clock starts again).
    pub fn due(&mut self) -> bool {
        let due = self.said.elapsed() >= self.beat;
        if due {
            self.said = Instant::now();
        }
        due
    }

    /// Says `ALIVE` to the display when it is time (from a render rank's waits, which have no
    /// communicator at hand: MPI_COMM_WORLD is the job's).
    pub fn beat(&mut self) {
        if self.due() {
            let world = mpi::topology::SimpleCommunicator::world();
            super::mailbox::send(
                &world,
                super::Roles::DISPLAY,
                super::protocol::Tag::Alive,
                &[],
            );
        }
    }
}

/// When each world rank was last heard from.
pub struct Liveness {
    heard: Vec<Instant>,
    timeout: Duration,
}

impl Liveness {
    /// Every rank counts as heard at `now` (the start of the roles, right after a barrier).
    pub fn new(ranks: u32, timeout: Duration, now: Instant) -> Liveness {
        Liveness {
            heard: vec![now; ranks as usize],
            timeout,
        }
    }

    pub fn heard(&mut self, rank: u32, now: Instant) {
        if let Some(h) = self.heard.get_mut(rank as usize) {
            *h = now;
        }
    }

    /// Of the ranks `waited_on`, the one silent the longest and for how long, if that is more
    /// than the timeout. The longest: a rank that waits on a stopped one (a one-sided read over
    /// TCP) goes silent after it, and the stopped one is the one to name.
    pub fn silent(
        &self,
        waited_on: impl IntoIterator<Item = u32>,
        now: Instant,
    ) -> Option<(u32, Duration)> {
        waited_on
            .into_iter()
            .filter_map(|r| {
                Some((
                    r,
                    now.saturating_duration_since(*self.heard.get(r as usize)?),
                ))
            })
            .max_by_key(|&(_, quiet)| quiet)
            .filter(|&(_, quiet)| quiet > self.timeout)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rank_silent_longest_past_the_timeout_is_named() {
        let t0 = Instant::now();
        let s = |x: u64| t0 + Duration::from_secs(x);
        let mut l = Liveness::new(5, Duration::from_secs(5), t0);
        assert_eq!(l.silent([2, 3, 4], s(5)), None, "not past the timeout");
        l.heard(2, s(4));
        l.heard(4, s(3));
        // Rank 3 has said nothing since 0, rank 4 since 3, rank 2 since 4.
        assert_eq!(l.silent([2, 3, 4], s(6)), Some((3, Duration::from_secs(6))));
        assert_eq!(l.silent([2, 4], s(6)), None, "rank 3 is not waited on");
        assert_eq!(l.silent([2, 4], s(9)), Some((4, Duration::from_secs(6))));
        assert_eq!(l.silent([], s(100)), None);
        assert_eq!(l.silent([7], s(100)), None, "not a rank of the job");
        assert_eq!(beat(Duration::from_secs(300)), Duration::from_secs(75));
        assert_eq!(beat(Duration::from_millis(40)), Duration::from_millis(50));
    }
}
