//! Progress reporting without printing: stages call a [`Progress`] the caller supplies (the CLI
//! draws indicatif bars on stderr; tests and `--quiet` pass [`NoProgress`]).

pub trait Progress: Sync {
    /// A new phase with `total` units of work.
    fn start(&self, _label: &str, _total: u64) {}
    /// `n` more units done.
    fn inc(&self, _n: u64) {}
    /// The phase is over.
    fn finish(&self) {}
}

/// Reports nothing.
pub struct NoProgress;

impl Progress for NoProgress {}
