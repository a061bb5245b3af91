//! One error type for the library. Every variant that concerns a file names it, says what is
//! wrong and, where there is one, what to do about it. The CLI prints the chain and exits 2.

use std::path::{Path, PathBuf};

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The operating system refused a read or write.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file exists but its contents are damaged, truncated or contradict themselves.
    #[error("{}: {msg}", path.display())]
    Invalid { path: PathBuf, msg: String },
    /// The file is well formed but uses a feature Penumbra does not read.
    #[error("{}: not supported: {msg}", path.display())]
    Unsupported { path: PathBuf, msg: String },
    /// A parameter given by the caller is out of range or inconsistent.
    #[error("{0}")]
    Usage(String),
    /// One named option of the caller's is out of range: `param` is the option's field name in
    /// the library (`near_px`, `tile_size`); a front end shows it as its own flag.
    #[error("{param} {msg}")]
    Param { param: &'static str, msg: String },
    /// A run of several stages (`bake`) failed after some of them committed: the stage that
    /// failed, those that had committed, and what became of the tileset (kept as the committed
    /// stages left it, or removed because the run created it); `source` says why the stage
    /// failed.
    #[error("the {stage} stage failed after {committed} committed; {outcome}")]
    AfterCommit {
        stage: &'static str,
        committed: String,
        outcome: String,
        #[source]
        source: Box<Error>,
    },
}

impl Error {
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
    pub fn invalid(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Invalid {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }
    pub fn unsupported(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Unsupported {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }
    pub fn usage(msg: impl Into<String>) -> Self {
        Error::Usage(msg.into())
    }
    /// `param` (an options field name) with what is wrong with its value, e.g.
    /// `Error::param("near_px", "2000 is outside 0..=1024")`.
    pub fn param(param: &'static str, msg: impl Into<String>) -> Self {
        Error::Param {
            param,
            msg: msg.into(),
        }
    }
}

/// Attach a path to an `io::Result`.
pub trait IoContext<T> {
    fn at(self, path: impl AsRef<Path>) -> Result<T>;
}

impl<T> IoContext<T> for std::io::Result<T> {
    fn at(self, path: impl AsRef<Path>) -> Result<T> {
        self.map_err(|e| Error::io(path, e))
    }
}
