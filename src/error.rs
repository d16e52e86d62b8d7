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
