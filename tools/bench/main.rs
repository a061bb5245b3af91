//! `penumbra-bench`: throughput of penumbra's stages against baselines measured in the same run
//! (gdalwarp, memcpy, the peers' horizon tools), printed as tables for docs/benchmarks.md or as
//! JSON. A separate binary so that the `penumbra` command people prepare terrain with carries
//! no benchmark drivers.
//!
//! One module per benchmark: [`tiling`], [`mip`], [`codec`] (also `exr-crate-rewrite`),
//! [`mip_memory`], [`far`] (`far-field`), [`horizon`], [`shadows`], [`fourier`], [`integrity`]. What they
//! share is below them: [`common`] (scratch folder, the `penumbra` binary and GNU time, best-of
//! timing, thread pools, pseudo-random pixels, radii) and [`cases`] (the DEM blocks fourier and
//! shadows measure on); neither imports a benchmark, and no benchmark imports another. This file
//! parses the command line and dispatches.

mod cases;
mod codec;
mod common;
mod far;
mod fourier;
mod horizon;
mod integrity;
mod mip;
mod mip_memory;
mod shadows;
mod sweep;
mod tiling;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};

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
    command: BenchCommand,
}

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Tiling throughput and peak RSS on the shared DEMs, against gdalwarp reprojecting the same
    /// DEM to a gnomonic cube face at the same pixel spacing (skipped when gdalwarp is absent).
    Tiling {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Scratch folder for outputs (removed afterwards).
        #[arg(long)]
        work: Option<PathBuf>,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// What the files' identities, index hashes and bounded reads cost (issue 41): `verify` on
    /// the LDEM_4 4-level tileset, and the checks' share of the mip and horizon stages.
    Integrity {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Scratch folder for the LDEM_4 tileset (removed afterwards).
        #[arg(long)]
        work: Option<PathBuf>,
        /// Repetitions per measurement (the best is reported).
        #[arg(long, default_value_t = 5)]
        reps: usize,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// Max and (min, max) pyramid throughput on a synthetic 2048² tile and on a whole LDEM_4
    /// tileset, against a plain memcpy of the same buffers measured in the same run.
    Mip {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Scratch folder for the LDEM_4 tileset (removed afterwards).
        #[arg(long)]
        work: Option<PathBuf>,
        /// Repetitions per measurement (the best is reported).
        #[arg(long, default_value_t = 7)]
        reps: usize,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// Size and one-core speed of each EXR compression option (the `exr` crate's writer and
    /// reader as before, src/exrcodec.rs at several deflate levels, uncompressed) on the height
    /// tiles, mip files and horizon maps of LDEM_4 and SRTM N19W156, against memcpy (issue 14).
    Codec {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Scratch folder for the tilesets (removed afterwards).
        #[arg(long)]
        work: Option<PathBuf>,
        /// Repetitions per measurement (the best is reported).
        #[arg(long, default_value_t = 3)]
        reps: usize,
        /// At most this many files per product (spread over the set).
        #[arg(long, default_value_t = 48)]
        max_files: usize,
        /// miniz_oxide deflate levels of the codec to measure (0–10; what the codec used
        /// before libdeflate, and the `exr` crate's library).
        #[arg(long, value_delimiter = ',', default_values_t = [1u8, 2])]
        levels: Vec<u8>,
        /// libdeflate deflate levels of the codec to measure (1–12; what the stages write).
        #[arg(long, value_delimiter = ',', default_values_t = [1u8, 2, 3, 4, 6])]
        libdeflate_levels: Vec<u8>,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// Rewrite every EXR of a folder as the `exr` crate's writer (Penumbra's before
    /// src/exrcodec.rs) would have stored the same samples, copying other files: hashing the
    /// copy against tools/golden/hashes.txt proves a codec change kept every sample.
    ExrCrateRewrite {
        /// Folder to read (e.g. target/golden after `tools/golden/run.sh check`).
        from: PathBuf,
        /// Folder to write.
        to: PathBuf,
    },
    /// Peak RSS and wall time of `penumbra mip` and `penumbra horizon` on the same DEM tiled
    /// with more and more levels (issue #13, item 3): each run is a fresh child process under
    /// GNU time. Memory should not depend on the level count.
    MipMemory {
        /// Folder holding the shared DEMs (lola_shoemaker_1k/ is used).
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Scratch folder for the tilesets (removed afterwards).
        #[arg(long)]
        work: Option<PathBuf>,
        /// Level counts to tile with.
        #[arg(long, value_delimiter = ',', default_values_t = [12u8, 14, 16])]
        levels: Vec<u8>,
        /// Interior tile size.
        #[arg(long, default_value_t = 64)]
        tile_size: u32,
        /// Azimuths of the horizon runs.
        #[arg(long, default_value_t = 16)]
        azimuths: usize,
        /// Another build's `penumbra` to compare with: it runs the finest-level horizon on a
        /// copy of each tileset just before this build does, and the table gains its RSS and
        /// wall time and the ratios.
        #[arg(long)]
        against: Option<PathBuf>,
        /// Also measure level counts on the same terrain at their finest level: the crop
        /// mirrored N×N times and given the finest level's pixel spacing (0 = skip).
        #[arg(long, default_value_t = 3)]
        same_terrain: usize,
        /// Level counts of the same-terrain runs.
        #[arg(long, value_delimiter = ',', default_values_t = [12u8, 16, 20])]
        same_terrain_levels: Vec<u8>,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// The fast method's far rings: error against run time and peak RSS for several
    /// full-resolution margins (`--fine-margin-px`) on real DEMs whose horizon reach is wider,
    /// against the exact method and the fast method over the whole reach at full resolution.
    FarField {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Scratch folder for the tilesets (removed afterwards).
        #[arg(long)]
        work: Option<PathBuf>,
        /// Full-resolution margins to measure (pixels).
        #[arg(long, value_delimiter = ',', default_values_t = [128u64, 256, 512, 1024])]
        margins: Vec<u64>,
        /// Azimuths per pixel.
        #[arg(long, default_value_t = 16)]
        azimuths: usize,
        /// Only the cases whose name contains this (case-insensitive).
        #[arg(long)]
        only: Option<String>,
        /// Instead: per-tile core time at the tile size and reach of a Mars 800 m/px and a
        /// lunar south-pole 5 m/px bake, and the CPU-hours they extrapolate to.
        #[arg(long)]
        extrapolate: bool,
        /// With --extrapolate: also the sweep with its own horizons on this device (`gpu`),
        /// the far rings on the CPU, and the GPU-minutes the bakes extrapolate to.
        #[arg(long, value_parser = ["cpu", "gpu", "auto"], requires = "extrapolate")]
        device: Option<String>,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// Horizon throughput on the peers' synthetic 30 m UTM DEM (the whole map as observers and
    /// as context, 1 thread and all cores), the brute-force reference on random pixels, the
    /// fast sweep's error against it, the peers' horizon tools from their results.tsv, and an
    /// extrapolation to a Mars 800 m/px whole-body bake.
    Horizon {
        /// The peers' work folder (`bash ../shared/peers/run_peers.sh dem` fills it).
        #[arg(long, default_value = "../peers-work")]
        peers: PathBuf,
        /// Azimuths per pixel.
        #[arg(long, default_value_t = 360)]
        azimuths: usize,
        /// Which DEM: 1024 or 2048 (data/dem<size>.npy).
        #[arg(long, default_value_t = 1024)]
        size: usize,
        /// Random observer pixels for the reference (deterministic).
        #[arg(long, default_value_t = 1024)]
        ref_pixels: usize,
        /// Runs of each whole-DEM fast timing (1–20): the table reports the fastest, the
        /// notes every run (a shared host's noise reaches ±5–10 % between runs).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=20))]
        repeat: u32,
        /// The shared real DEMs: a block at the centre of Gale crater and of Hawaiʻi is
        /// checked against the exact reference too (skipped when absent).
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// The sweep horizon method (issue 34): its error against the reference (or another
    /// method) on a block of each shared real DEM, and its time beside the fast method's.
    Sweep {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Block side (pixels) of each case.
        #[arg(long, default_value_t = 256)]
        block: usize,
        /// Azimuths per pixel.
        #[arg(long, default_value_t = 36)]
        azimuths: usize,
        /// What the error is measured against: reference, exact or fast.
        #[arg(long, default_value = "reference")]
        truth: penumbra::horizon::Method,
        /// The peers' work folder (its data/dem1024.npy is timed whole; skipped when absent).
        #[arg(long, default_value = "../peers-work")]
        peers: PathBuf,
        /// Runs of each whole-map timing (the fastest is reported).
        #[arg(long, default_value_t = 1)]
        repeat: usize,
        /// Leave the fast method out (quicker runs).
        #[arg(long)]
        skip_fast: bool,
        /// Azimuths of the whole-map timing.
        #[arg(long, default_value_t = 360)]
        whole_azimuths: usize,
        /// Instead: the product a user keeps (Fourier-16 multires f16) built from sweep and
        /// fast horizons against the same built from exact horizons, lit-fraction MAE and PER
        /// on each real DEM block (use `--azimuths 360`).
        #[arg(long)]
        product: bool,
        /// Lit-fraction pixels per block for `--product`.
        #[arg(long, default_value_t = 512)]
        lit_pixels: usize,
        /// Also run the sweep on this device (`gpu`: any adapter, lavapipe included) and
        /// compare it with the CPU sweep and the truth.
        #[arg(long, value_parser = ["cpu", "gpu", "auto"])]
        device: Option<String>,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// Shadow methods side by side (issue 11): reference, uniform stepping, DP over max
    /// mipmaps (and its canonical-DDA variant), extrema, horizon lookups; error against the
    /// reference and time per megapixel on 1 and 2 threads, on the embedded scene and a block
    /// of each shared real DEM, suns at 1°, 5°, 15°, 45° × 8 azimuths; a hard-mask timing and
    /// pictures.
    Shadows {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Block side (pixels) of each case.
        #[arg(long, default_value_t = 128)]
        block: usize,
        /// Side of the hard-mask timing (pixels).
        #[arg(long, default_value_t = 1024)]
        mask: usize,
        /// Where to write the figure.
        #[arg(long, default_value = "docs/shadows-error.svg")]
        svg: PathBuf,
        /// Where to write the pictures.
        #[arg(long, default_value = "docs/images")]
        images: PathBuf,
        /// A 48² block, fewer methods, no pictures.
        #[arg(long)]
        quick: bool,
        /// Only the cases whose name contains this (case-insensitive).
        #[arg(long)]
        only: Option<String>,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// Error against bytes and compression time of Fourier-compressed horizon maps (issue 10):
    /// K ∈ {4, 8, 16, 32} × f16/snorm16 × full/multires × plain/Lanczos and classic 8- and
    /// 12-sample maps, on a block of each shared real DEM and on synthetic stiff cases (cliff,
    /// spike, crater rim, pole, cube corner); horizon RMS/p99/max, shadow pixel error rate,
    /// lit-fraction error, bytes and compression time per 256² tile; an SVG of error vs cost.
    Fourier {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Observer block side (pixels); 128 keeps the whole run near 10 minutes on 2 cores
        /// (bytes and times are reported per 256² tile whatever the block).
        #[arg(long, default_value_t = 128)]
        block: usize,
        /// Azimuths of the raw maps.
        #[arg(long, default_value_t = 360)]
        azimuths: usize,
        /// Pixels per case for the lit-fraction error (fixed pseudo-random subset).
        #[arg(long, default_value_t = 512)]
        lit_pixels: usize,
        /// Where to write the figure.
        #[arg(long, default_value = "docs/fourier-error.svg")]
        svg: PathBuf,
        /// A 64² block and at most 64 lit-fraction pixels, to try things quickly.
        #[arg(long)]
        quick: bool,
        /// Only the cases whose name contains this (case-insensitive), e.g. gale or spike.
        #[arg(long)]
        only: Option<String>,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
}

fn run(cli: Cli) -> Result<()> {
    penumbra_cli::set_threads(cli.threads)?;
    dispatch(cli.command, cli.quiet)
}

fn dispatch(cmd: BenchCommand, quiet: bool) -> Result<()> {
    match cmd {
        BenchCommand::Tiling {
            data,
            work,
            markdown,
            json,
        } => crate::tiling::run_tiling(data, work, markdown, json, quiet),
        BenchCommand::Integrity {
            data,
            work,
            reps,
            markdown,
            json,
        } => crate::integrity::run(&data, work, reps.max(1), markdown, json, quiet),
        BenchCommand::Mip {
            data,
            work,
            reps,
            markdown,
            json,
        } => crate::mip::run_mip(&data, work, reps.max(1), markdown, json, quiet),
        BenchCommand::Codec {
            data,
            work,
            reps,
            max_files,
            levels,
            libdeflate_levels,
            markdown,
            json,
        } => crate::codec::run_codec(
            &data,
            work,
            reps.max(1),
            max_files.max(1),
            &levels,
            &libdeflate_levels,
            markdown,
            json,
            quiet,
        ),
        BenchCommand::ExrCrateRewrite { from, to } => {
            crate::codec::run_exr_crate_rewrite(&from, &to)
        }
        BenchCommand::MipMemory {
            data,
            work,
            levels,
            tile_size,
            azimuths,
            against,
            same_terrain,
            same_terrain_levels,
            markdown,
            json,
        } => crate::mip_memory::run_mip_memory(
            &data,
            work,
            &levels,
            tile_size,
            azimuths,
            against.as_deref(),
            (same_terrain, &same_terrain_levels),
            markdown,
            json,
            quiet,
        ),
        BenchCommand::FarField {
            azimuths,
            extrapolate: true,
            device,
            markdown,
            json,
            ..
        } => {
            let gpu = open_device(device.as_deref(), quiet)?;
            crate::far::extrapolate(
                azimuths,
                gpu.as_ref()
                    .map(|g| g as &dyn penumbra::horizon::device::SweepDevice),
                markdown,
                json,
            )
        }
        BenchCommand::FarField {
            data,
            work,
            margins,
            azimuths,
            only,
            extrapolate: false,
            markdown,
            json,
            ..
        } => crate::far::run(
            &data,
            work,
            &margins,
            azimuths,
            only.as_deref(),
            markdown,
            json,
            quiet,
        ),
        BenchCommand::Horizon {
            peers,
            azimuths,
            size,
            ref_pixels,
            repeat,
            data,
            markdown,
            json,
        } => crate::horizon::run_horizon(
            &peers,
            &data,
            azimuths,
            size,
            ref_pixels,
            repeat as usize,
            markdown,
            json,
            quiet,
        ),
        BenchCommand::Sweep {
            data,
            block,
            azimuths,
            product: true,
            lit_pixels,
            json,
            ..
        } => crate::sweep::run_product(&data, block, azimuths, lit_pixels, json, quiet),
        BenchCommand::Sweep {
            data,
            block,
            azimuths,
            truth,
            peers,
            repeat,
            skip_fast,
            whole_azimuths,
            markdown,
            json,
            device,
            ..
        } => {
            let gpu = open_device(device.as_deref(), quiet)?;
            crate::sweep::run(
                &data,
                &peers,
                repeat,
                skip_fast,
                whole_azimuths,
                block,
                azimuths,
                truth,
                gpu.as_ref()
                    .map(|g| g as &dyn penumbra::horizon::device::SweepDevice),
                markdown,
                json,
                quiet,
            )
        }
        BenchCommand::Shadows {
            data,
            block,
            mask,
            svg,
            images,
            quick,
            only,
            markdown,
            json,
        } => crate::shadows::run(
            crate::shadows::Args {
                data,
                block,
                mask,
                markdown,
                json,
                svg,
                images,
                quick,
                only,
            },
            quiet,
        ),
        BenchCommand::Fourier {
            data,
            block,
            azimuths,
            lit_pixels,
            svg,
            quick,
            only,
            markdown,
            json,
        } => crate::fourier::run(
            crate::fourier::Args {
                data,
                block,
                azimuths,
                markdown,
                json,
                svg,
                quick,
                lit_pixels,
                only,
            },
            quiet,
        ),
    }
}

fn main() -> ExitCode {
    penumbra_cli::exit_code("penumbra-bench", run(Cli::parse()))
}

/// The GPU `--device` asks for (None: the CPU), named on stderr.
fn open_device(
    device: Option<&str>,
    quiet: bool,
) -> anyhow::Result<Option<penumbra_gpu::GpuSweep>> {
    let choice = device
        .and_then(penumbra::horizon::device::DeviceChoice::parse)
        .unwrap_or(penumbra::horizon::device::DeviceChoice::Cpu);
    let gpu = penumbra_gpu::GpuSweep::open(choice).map_err(|e| anyhow::anyhow!("{e}"))?;
    if let Some(g) = &gpu {
        if !quiet {
            eprintln!("penumbra-bench: GPU {}", g.describe());
        }
    }
    Ok(gpu)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `horizon --repeat` takes 1–20 and refuses anything else at parsing (clap: exit 2).
    #[test]
    fn horizon_repeat_is_bounded() {
        #[derive(clap::Parser)]
        struct Args {
            #[command(subcommand)]
            command: BenchCommand,
        }
        use clap::Parser;
        let parse = |v: &str| Args::try_parse_from(["penumbra-bench", "horizon", "--repeat", v]);
        for bad in ["0", "21", "-1", "two", ""] {
            let err = parse(bad)
                .err()
                .unwrap_or_else(|| panic!("--repeat {bad} accepted"));
            assert_eq!(err.exit_code(), 2, "--repeat {bad}: {err}");
        }
        for good in ["1", "3", "20"] {
            match parse(good) {
                Ok(Args {
                    command: BenchCommand::Horizon { repeat, .. },
                }) => assert_eq!(repeat.to_string(), good),
                _ => panic!("--repeat {good} refused"),
            }
        }
    }
}
