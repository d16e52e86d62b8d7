//! The library's error type. Every message names what is wrong and where (file, line, element).

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A file's contents are malformed. `location` is e.g. "line 12" or "vertex 7".
    #[error("{}{}: {message}", path.display(), location.as_ref().map(|l| format!(": {l}")).unwrap_or_default())]
    Format {
        path: PathBuf,
        location: Option<String>,
        message: String,
    },
    /// A value given by the user (command line or scene) is out of range or inconsistent.
    #[error("{0}")]
    Invalid(String),
    /// The GPU could not be used as asked (no adapter, a limit exceeded, a lost device).
    #[error("gpu: {0}")]
    Gpu(String),
    /// An MPI call failed, or MPI could not be set up.
    #[error("{0}")]
    Mpi(String),
    /// Another rank sent a message this one cannot make sense of; the message names its tag and
    /// sender.
    #[error("{0}")]
    Protocol(String),
    /// Nothing came for `seconds`: no `what`; `likely` says what that usually means.
    #[error(
        "no {what} for {seconds:.0} s{}",
        likely.map(|l| format!(": {l}")).unwrap_or_default()
    )]
    Timeout {
        what: String,
        seconds: f64,
        likely: Option<&'static str>,
    },
    /// dcrt broke one of its own rules (a thread died, a buffer of the wrong size): a bug, not a
    /// problem of the input.
    #[error("{0}")]
    Internal(String),
}

impl Error {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    pub fn format(
        path: impl Into<PathBuf>,
        location: Option<String>,
        message: impl Into<String>,
    ) -> Self {
        Error::Format {
            path: path.into(),
            location,
            message: message.into(),
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timeouts_say_what_did_not_come() {
        let e = Error::Timeout {
            what: "message from any rank".into(),
            seconds: 300.0,
            likely: Some("a rank has hung or died"),
        };
        assert_eq!(
            e.to_string(),
            "no message from any rank for 300 s: a rank has hung or died"
        );
        let e = Error::Timeout {
            what: "answer from the balancer".into(),
            seconds: 2.4,
            likely: None,
        };
        assert_eq!(e.to_string(), "no answer from the balancer for 2 s");
    }
}
