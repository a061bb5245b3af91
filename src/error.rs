//! One error type for the library. Every variant that concerns a file names it, says what is
//! wrong and, where there is one, what to do about it. The CLI prints the chain and exits 2.

use std::path::{Path, PathBuf};

/// What a build without `--features gdal` answers when asked for something that needs GDAL
/// ([`Error::no_gdal`]).
pub const NO_GDAL: &str =
    "this build has no GDAL: rebuild with `cargo build --features gdal` (needs libgdal-dev)";

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
    /// `what` (the command, file or option that asked) needs GDAL, which this build lacks: a
    /// usage error saying how to rebuild ([`NO_GDAL`]). Compiled in every build, so that its
    /// text is tested where CI builds with GDAL; the `cfg(not(feature = "gdal"))` branches do
    /// nothing but return it.
    pub fn no_gdal(what: impl std::fmt::Display) -> Self {
        Error::Usage(format!("{what}: {NO_GDAL}"))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The message of a build without GDAL names the feature that both packages have (the
    /// library's and the CLI's, which `cargo build --features gdal` at the root turns on), and
    /// is a usage error (the CLI exits 2).
    #[test]
    fn no_gdal_says_how_to_build_it() {
        let e = Error::no_gdal("penumbra export");
        assert!(matches!(e, Error::Usage(_)));
        let m = e.to_string();
        assert!(
            m.starts_with("penumbra export: this build has no GDAL"),
            "{m}"
        );
        assert!(
            m.contains("`cargo build --features gdal`") && m.contains("libgdal-dev"),
            "{m}"
        );
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        for toml in ["Cargo.toml", "tools/penumbra/Cargo.toml"] {
            let t = std::fs::read_to_string(root.join(toml)).unwrap();
            let features = t.split("[features]").nth(1).unwrap_or("");
            assert!(
                features.lines().any(|l| l.starts_with("gdal = [")),
                "{toml} has no `gdal` feature"
            );
        }
    }
}
