//! `penumbra-bench`: throughput of penumbra's stages against baselines measured in the same run
//! (gdalwarp, memcpy, the peers' horizon tools), printed as tables for docs/benchmarks.md or as
//! JSON. A separate binary so that the `penumbra` command people prepare terrain with carries
//! no benchmark drivers.

mod bench;
mod cases;
mod codec;
mod common;
mod far;
mod fourier;
mod mip;
mod mip_memory;
mod shadows;
mod tiling;

use std::process::ExitCode;

use anyhow::Result;
use clap::Parser;

#[derive(Parser)]
#[command(
    name = "penumbra-bench",
    version,
    about = "Measure penumbra's throughput against baselines in the same run"
)]
struct Cli {
    /// No progress messages.
    #[arg(long, short, global = true)]
    quiet: bool,
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: bench::BenchCommand,
}

fn run(cli: Cli) -> Result<()> {
    penumbra_cli::set_threads(cli.threads)?;
    bench::run(cli.command, cli.quiet)
}

fn main() -> ExitCode {
    penumbra_cli::exit_code("penumbra-bench", run(Cli::parse()))
}
