//! What the `penumbra` command and the `penumbra-bench` benchmarks share: how results are shown
//! ([`output`]: progress bars, tables, JSON), how a run starts and ends (the thread pool, the
//! error message and exit code 2), and how error is measured against the references
//! ([`measure`]), which the benchmarks use on the shared DEMs and [`report`] on a user's tileset. It lives in this package's small library so that neither
//! binary copies it; it is no API of its own (that is the `penumbra` library).

pub mod measure;
pub mod output;
pub mod report;

use std::process::ExitCode;

use anyhow::{Context, Result};

/// Sizes rayon's global pool to `threads` (at least 1); all cores when `None`.
pub fn set_threads(threads: Option<usize>) -> Result<()> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global()
            .context("setting up the thread pool")?;
    }
    Ok(())
}

/// Whether the error is a write to a closed pipe (`penumbra info DIR | head -1`), however it
/// was wrapped: an I/O error, or the JSON writer's error around one.
fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            || c.downcast_ref::<serde_json::Error>()
                .is_some_and(|j| j.io_error_kind() == Some(std::io::ErrorKind::BrokenPipe))
    })
}

/// The exit status of a run of the binary `name`: success, or the error chain on stderr as
/// `name: error: …` and exit code 2. A broken pipe (output piped into `head`) is success.
pub fn exit_code(name: &str, result: Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if is_broken_pipe(&e) {
                return ExitCode::SUCCESS;
            }
            // The library names an out-of-range option by its field; show the flag instead.
            let flag = |p: &str| p.replace('_', "-");
            if let Some(penumbra::Error::Param { param, msg }) = e.downcast_ref() {
                eprintln!("{name}: error: --{} {msg}", flag(param));
            } else if let Some(outer @ penumbra::Error::AfterCommit { source, .. }) =
                e.downcast_ref()
            {
                // A later stage of a bake refused an option after earlier stages committed.
                match source.as_ref() {
                    penumbra::Error::Param { param, msg } => {
                        eprintln!("{name}: error: {outer}: --{} {msg}", flag(param))
                    }
                    _ => eprintln!("{name}: error: {e:#}"),
                }
            } else {
                eprintln!("{name}: error: {e:#}");
            }
            ExitCode::from(2)
        }
    }
}
