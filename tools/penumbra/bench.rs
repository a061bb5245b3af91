//! `penumbra bench`: throughput against baselines measured in the same run.

use anyhow::Result;
use clap::Subcommand;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Tiling throughput on the shared DEMs, against gdalwarp to a gnomonic face.
    Tiling,
}

pub fn run(_cmd: BenchCommand, _quiet: bool) -> Result<()> {
    anyhow::bail!("not implemented yet")
}
