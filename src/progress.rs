//! Progress bars on stderr for long work: `dcrt prepare`'s passes, a render's frames, a bench's
//! sweep (indicatif, with rate and ETA). They are drawn only when stderr is a terminal and the
//! command was not given `--quiet`; off a terminal a bar draws nothing (a render then prints its
//! `--progress-every` lines instead).

use indicatif::{HumanCount, ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle};
use std::io::IsTerminal;

/// How a command shows progress.
#[derive(Clone, Copy, Debug, Default)]
pub struct Progress {
    pub quiet: bool,
}

impl Progress {
    /// Whether bars are drawn: stderr is a terminal and `--quiet` was not given.
    pub fn drawn(&self) -> bool {
        !self.quiet && std::io::stderr().is_terminal()
    }

    fn target(&self) -> ProgressDrawTarget {
        if self.drawn() {
            ProgressDrawTarget::stderr()
        } else {
            ProgressDrawTarget::hidden()
        }
    }

    /// A bar for `len` steps of `what` (the message before the bar), with the rate and the
    /// time left.
    pub fn bar(&self, len: u64, what: &str) -> ProgressBar {
        let style = ProgressStyle::with_template(
            "{msg:28} [{bar:30}] {human_pos}/{human_len} ({rate}, {eta} left)",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .with_key("rate", rate)
        .progress_chars("=> ");
        ProgressBar::with_draw_target(Some(len), self.target())
            .with_style(style)
            .with_message(what.to_string())
    }

    /// A counter of steps whose total is not known, with the rate.
    pub fn counter(&self, what: &str) -> ProgressBar {
        let style = ProgressStyle::with_template("{msg:28} {spinner} {human_pos} ({rate})")
            .unwrap_or_else(|_| ProgressStyle::default_spinner())
            .with_key("rate", rate);
        ProgressBar::with_draw_target(None, self.target())
            .with_style(style)
            .with_message(what.to_string())
    }
}

/// Steps per second, whole.
fn rate(state: &ProgressState, w: &mut dyn std::fmt::Write) {
    let _ = write!(w, "{}/s", HumanCount(state.per_sec() as u64));
}

/// Prints a line on stderr above `bar` (or plainly when the bar is not drawn).
pub fn say(bar: &ProgressBar, line: String) {
    if bar.is_hidden() {
        stderr_line(&line);
    } else {
        bar.println(line);
    }
}

/// Writes `line` and a newline to stderr in one write. `eprintln!` writes a formatted line piece
/// by piece, and under mpirun the pieces of one rank's line can be forwarded apart, with Open
/// MPI's own messages between them (a user, or a test, then cannot find the line). One write of
/// under 4 KiB to a pipe is atomic.
pub fn stderr_line(line: &str) {
    use std::io::Write;
    let mut text = String::with_capacity(line.len() + 1);
    text.push_str(line);
    text.push('\n');
    // Nothing to do when stderr itself cannot be written.
    let _ = std::io::stderr().lock().write_all(text.as_bytes());
}

/// `eprintln!` in one write (see [`stderr_line`]); every message of the crate and the `dcrt`
/// binary goes through it (clippy.toml disallows `eprintln!`).
#[macro_export]
macro_rules! report {
    ($($arg:tt)*) => {
        $crate::progress::stderr_line(&format!($($arg)*))
    };
}
