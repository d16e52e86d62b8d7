//! Failure injection for the tests of what a dying rank does to the job: `DCRT_TEST_FAIL` set to
//! `panic@R`, `kill@R` or `stop@R` makes rank R panic, kill itself with SIGKILL, or stop itself
//! with SIGSTOP (a hung rank), when it starts tracing in its first frame (mid-frame for the
//! others); `hang@R` stops rank R once its work is done, before the job's last barrier.
//! Anything else in the variable does nothing.

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum How {
    Panic,
    Kill,
    Stop,
    Hang,
}

/// What this rank is to do, read from the environment once at start-up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Failure(Option<How>);

impl Failure {
    pub fn from_env(rank: u32) -> Failure {
        Failure::parse(std::env::var("DCRT_TEST_FAIL").ok().as_deref(), rank)
    }

    fn parse(spec: Option<&str>, rank: u32) -> Failure {
        let how = spec
            .and_then(|s| s.split_once('@'))
            .filter(|(_, r)| r.parse() == Ok(rank))
            .and_then(|(what, _)| match what {
                "panic" => Some(How::Panic),
                "kill" => Some(How::Kill),
                "stop" => Some(How::Stop),
                "hang" => Some(How::Hang),
                _ => None,
            });
        Failure(how)
    }

    /// Called by rank `rank` as it starts a tile of frame `frame`.
    pub fn at_tile(self, rank: u32, frame: u32) {
        if frame != 0 {
            return;
        }
        match self.0 {
            None | Some(How::Hang) => {}
            Some(How::Panic) => panic!("DCRT_TEST_FAIL: rank {rank} panics mid-frame"),
            Some(How::Kill) => signal_self("-KILL"),
            Some(How::Stop) => signal_self("-STOP"),
        }
    }
}

impl Failure {
    /// Called by every rank once its role is done, before the job's last barrier.
    pub fn at_end(self) {
        if self.0 == Some(How::Hang) {
            signal_self("-STOP");
        }
    }
}

fn signal_self(signal: &str) {
    let _ = std::process::Command::new("kill")
        .args([signal, &std::process::id().to_string()])
        .status();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_named_rank_fails() {
        assert_eq!(
            Failure::parse(Some("panic@3"), 3),
            Failure(Some(How::Panic))
        );
        assert_eq!(Failure::parse(Some("kill@2"), 2), Failure(Some(How::Kill)));
        assert_eq!(Failure::parse(Some("stop@4"), 4), Failure(Some(How::Stop)));
        assert_eq!(Failure::parse(Some("hang@2"), 2), Failure(Some(How::Hang)));
        assert_eq!(Failure::parse(Some("panic@3"), 2), Failure::default());
        assert_eq!(Failure::parse(Some("burn@3"), 3), Failure::default());
        assert_eq!(Failure::parse(Some("panic"), 3), Failure::default());
        assert_eq!(Failure::parse(None, 3), Failure::default());
        Failure::default().at_tile(3, 0);
        Failure(Some(How::Panic)).at_tile(3, 1);
    }
}
