//! `penumbra`: the command-line front end. Parses arguments, draws progress on stderr, prints
//! tables or JSON, and turns every error into a message and exit code 2.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use clap::{Args, CommandFactory, FromArgMatches, Parser, Subcommand};

use penumbra::bake::{self, BodyChoice, Input, Plan, Stage};
use penumbra::body::Body;
use penumbra::cube::Projection;
use penumbra::dem::Resampling;
use penumbra::error::Error;
use penumbra::format::TileCompression;
use penumbra::fourier::sun::Model;
use penumbra::fourier::{Encoding, FourierOptions, Layout, Reduce, Sigma};
use penumbra::graph::{self, Node};
use penumbra::horizon::device::DeviceChoice;
use penumbra::horizon::{HorizonOptions, HorizonPrecision, Method};
use penumbra::mip::{MipOptions, Precision};
use penumbra::query::HorizonFrom;
use penumbra::synthetic::SyntheticSpec;
use penumbra::tiling::{Prefilter, TileOptions};
use penumbra_cli::output;

#[derive(Parser)]
#[command(
    name = "penumbra",
    version,
    about = "Prepare planetary terrain for fast, accurate shadows"
)]
struct Cli {
    /// No progress bars.
    #[arg(long, short, global = true)]
    quiet: bool,
    /// Worker threads (default: all cores). Output does not depend on it.
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Cut a DEM into cube-face tiles.
    Tile(TileArgs),
    /// Make exactly what a scene file plans (docs/scenes.md): its regions' tiles from its
    /// sources' mosaic, and the products its renderer's methods read. With no scene, the
    /// embedded one; with --dem, one DEM whole: tiling, then mipmaps, then horizons compressed
    /// into Fourier pyramids for --horizon-levels.
    Bake(BakeArgs),
    /// Show what baking a scene would make and leave out, per product and level, with bytes and
    /// estimated CPU time, before anything is written (docs/scenes.md).
    Plan {
        /// Scene file (TOML); default: the embedded scene `penumbra bake` bakes.
        scene: Option<PathBuf>,
        /// A tileset holding this scene's heights and mipmaps (a bake of it, or one stopped
        /// after the mip stage): count the horizons the sun rule leaves out exactly, as the
        /// horizon stage will decide (without it the stage decides after the mipmaps).
        #[arg(long)]
        tileset: Option<PathBuf>,
        /// Also cut the sharded stages (mip, horizon) into N shards as `bake --stage S --shard
        /// I/N` will: per shard its units and estimated CPU time, and the slowest shard over
        /// the mean.
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=penumbra::runner::MAX_SHARDS as i64))]
        shards: Option<u32>,
        /// With --shards: write the bake as a chain of Slurm jobs into this folder (created;
        /// or one a previous `plan --slurm` wrote, replaced): tiling as one job, each sharded
        /// stage as a job array of N tasks and its finish, and submit.sh (docs/cluster.md).
        #[arg(
            long,
            value_name = "DIR",
            requires = "shards",
            conflicts_with = "tileset"
        )]
        slurm: Option<PathBuf>,
        #[command(flatten)]
        slurm_flags: SlurmFlags,
        /// Print the plan as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Compute the raw horizon maps of a tileset: per pixel the horizon elevation in A azimuths,
    /// seeing across tiles and faces as far as any terrain could rise above it.
    Horizon {
        /// Tileset folder.
        dir: PathBuf,
        /// Tile levels to compute, comma-separated (default: every level).
        #[arg(long, value_delimiter = ',')]
        levels: Option<Vec<u8>>,
        #[command(flatten)]
        flags: HorizonFlags,
        #[command(flatten)]
        device: DeviceFlag,
        /// Sample type of the stored maps: f16 (default) or f32.
        #[arg(long, default_value = "f16")]
        precision: HorizonPrecision,
        /// EXR compression of the maps: zip (lossless) or none.
        #[arg(long, default_value = "zip")]
        compression: TileCompression,
        /// Refuse a run whose maps would exceed this many GiB before compression.
        #[arg(long, default_value_t = 8.0, allow_hyphen_values = true)]
        max_output_gib: f64,
        /// Compress each tile's horizons into Fourier pyramids as they are computed (raw maps
        /// are then written only with --keep-raw).
        #[arg(long)]
        fourier: bool,
        /// With --fourier: also write the raw maps.
        #[arg(long)]
        keep_raw: bool,
        /// Leave out the tiles whose horizon can never rise to DEG degrees (a scene's lowest sun
        /// less the sun's radius), by a conservative bound from the mipmaps: they are recorded
        /// fully lit (no maps; fully-lit pyramids with --fourier) and not computed.
        #[arg(long, value_name = "DEG", allow_hyphen_values = true)]
        lit_above: Option<f64>,
        #[command(flatten)]
        fourier_flags: FourierFlags,
        #[command(flatten)]
        shard: ShardFlag,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Compress a tileset's raw horizon maps into 16-bit truncated-Fourier pyramids
    /// (docs/fourier.md).
    Fourier {
        /// Tileset folder.
        dir: PathBuf,
        /// Tile levels to compress, comma-separated (default: every level with horizon maps).
        #[arg(long, value_delimiter = ',')]
        levels: Option<Vec<u8>>,
        #[command(flatten)]
        flags: FourierFlags,
        #[command(flatten)]
        shard: ShardFlag,
        /// Refuse a run whose pyramids would exceed this many GiB.
        #[arg(long, default_value_t = penumbra::runner::DEFAULT_MAX_OUTPUT_GIB, allow_hyphen_values = true)]
        max_output_gib: f64,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Build the maximum and (min, max) mipmaps of a tileset's height tiles.
    Mip {
        /// Tileset folder.
        dir: PathBuf,
        #[command(flatten)]
        flags: MipFlags,
        #[command(flatten)]
        shard: ShardFlag,
        /// EXR compression of the mipmaps: zip (lossless) or none (fastest).
        #[arg(long, default_value = "zip")]
        compression: TileCompression,
        /// Refuse a run whose pyramids would exceed this many GiB before compression.
        #[arg(long, default_value_t = penumbra::runner::DEFAULT_MAX_OUTPUT_GIB, allow_hyphen_values = true)]
        max_output_gib: f64,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Shadows of one tile for a sun over a sub-solar point: the lit fraction of the sun's disc
    /// per pixel (grey PNG) and a shaded relief with those shadows, from the horizon products.
    Shadow {
        /// Tileset folder.
        dir: PathBuf,
        /// Tile level.
        #[arg(long)]
        level: u8,
        /// The tile: FACE/Y/X (e.g. nz/31/32; faces px, nx, py, ny, pz, nz).
        #[arg(long, required_unless_present = "bbox", conflicts_with = "bbox")]
        tile: Option<String>,
        /// Or a latitude/longitude box LAT0,LAT1,LON0,LON1 (degrees), resampled onto a grid at
        /// the level's pixel size from every tile it touches.
        #[arg(long, allow_hyphen_values = true)]
        bbox: Option<String>,
        /// Sub-solar latitude, degrees.
        #[arg(long, allow_hyphen_values = true)]
        sun_lat: f64,
        /// Sub-solar east longitude, degrees.
        #[arg(long, allow_hyphen_values = true)]
        sun_lon: f64,
        /// The body's distance from the Sun (AU; default: the body preset's).
        #[arg(long, allow_hyphen_values = true)]
        sun_distance_au: Option<f64>,
        #[command(flatten)]
        shadow: ShadowFlags,
        /// With --method horizon: fourier (the pyramids) or raw (the stored maps).
        #[arg(long)]
        from: Option<penumbra::shadow::HorizonSource>,
        /// With --method horizon: the disc model, constant (the paper's cheapest), segment,
        /// slices or exact.
        #[arg(long, default_value = "constant")]
        model: Model,
        /// Lit-fraction image to write (PNG, white = fully lit).
        #[arg(long)]
        out: PathBuf,
        /// Also write a shaded relief with the shadows here (PNG).
        #[arg(long)]
        relief: Option<PathBuf>,
        /// Also write the lit fraction as a float EXR (channel `lit`, NaN = no data) beside
        /// --out, with the extension .exr.
        #[arg(long)]
        exr: bool,
        #[arg(long)]
        json: bool,
    },
    /// Export a product onto a map grid as a Cloud-Optimized GeoTIFF that GIS tools open
    /// (docs/packaging.md, "GeoTIFF export (GDAL)"): polar stereographic near a pole,
    /// equirectangular elsewhere, a face's gnomonic grid with --face; nodata where the tileset
    /// has none. Needs a build with `--features gdal`.
    Export(ExportArgs),
    /// Package a tileset as a Celestia addon folder (docs/packaging.md): the catalog, virtual
    /// textures of the albedo and of a normal map derived from the heights, the tileset itself
    /// as the addon's cube-face products (linked where it can be, checked against its indexes)
    /// and a README; with --zip, an archive of it too. A rerun replaces the package.
    Package(PackageArgs),
    /// Describe a tileset.
    Info {
        /// Tileset folder.
        dir: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Check every file of a tileset against its index (present, a regular file inside the
    /// tileset, the recorded size and blake3) and its identity (the product, tile and run it
    /// says it is). Exit 0: every file sound; 1: a table (or `--json`) of the files that are
    /// not; 2: the tileset cannot be opened.
    Verify {
        /// Tileset folder.
        dir: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Error against run time on your own terrain (docs/report.md): on a deterministic sample
    /// of a tileset's pixels, every horizon method, Fourier variant and shadow method against
    /// the exact reference at the scene's suns, with the Pareto front and a recommendation per
    /// product for the error budget. Writes report.html, report.md and report.json.
    Report(ReportArgs),
    /// Ask a tileset about one point.
    #[command(subcommand)]
    Query(QueryCommand),
    /// Run the catalogue of stiff and extreme cases (docs/stress.md): per case and quantity the
    /// error against an analytic or brute-force answer and its bound. Exit 0: every bound
    /// holds; 1: a bound is exceeded or a NaN/Inf appeared (the failing rows are named).
    Stress {
        /// The real sizes (a 16384² tile): about 12 s and 2.8 GiB instead of 3 s.
        #[arg(long)]
        full: bool,
        /// Only the cases whose name contains this.
        #[arg(long, value_name = "SUBSTRING")]
        only: Option<String>,
        /// Test-only: run a deliberately weakened kernel (horizon-floor-zero, shadow-point-sun,
        /// fourier-drop-term) to see the bounds fail.
        #[arg(long, value_name = "NAME", hide = true)]
        weaken: Option<String>,
        /// Where the sweep method's rows run (the other methods' run on the CPU): cpu (the
        /// default here), gpu or auto, as `horizon --device`.
        #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(DeviceChoice::NAMES))]
        device: Option<String>,
        /// Print the rows as JSON.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Args)]
struct ReportArgs {
    /// A tileset folder, or a scene file (TOML) whose bake --tileset names; neither: the
    /// embedded scene, with --tileset.
    input: Option<PathBuf>,
    /// The tileset a scene was baked into (with a scene file or the embedded scene).
    #[arg(long)]
    tileset: Option<PathBuf>,
    /// Folder the report is written into (created).
    #[arg(long, default_value = "report")]
    out: PathBuf,
    /// Wall-clock seconds the measurements may take (the sample grows to fill them).
    #[arg(long, default_value_t = 60.0, conflicts_with = "blocks")]
    budget_s: f64,
    /// A fixed sample instead of the budget's: this many blocks (the same pixels on any
    /// machine; report.json records the budget's sample as `blocks`).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=penumbra_cli::report::MAX_BLOCKS as i64))]
    blocks: Option<u32>,
    /// With --blocks: each block's side in pixels (24, 32, 64, 96, 128 or 192).
    #[arg(long, requires = "blocks", default_value_t = 64)]
    block_px: usize,
    /// Pixel error rate (percent) the scene can afford: the recommendations meet it.
    #[arg(long, default_value_t = 0.5)]
    max_per: f64,
    /// Horizon error (degrees RMS against the reference) the scene can afford.
    #[arg(long, default_value_t = 0.05)]
    max_error_deg: f64,
    /// Seed of the pixel sample (another seed: an independent sample).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Tile level to sample (default: the scene's finest horizon level, else the finest).
    #[arg(long)]
    level: Option<u8>,
    /// Print the report as JSON instead of the summary table.
    #[arg(long)]
    json: bool,
    /// Measure nothing: write the report of this report.json again, its recommendations for
    /// --max-per and --max-error-deg (another error budget without another sample).
    #[arg(long, value_name = "REPORT_JSON", conflicts_with_all = ["input", "tileset", "blocks", "budget_s", "seed", "level"])]
    from: Option<PathBuf>,
}

#[derive(Args)]
struct ExportArgs {
    /// Tileset folder.
    dir: PathBuf,
    /// What each pixel holds: height (m above the reference sphere, bilinear as `query
    /// height`), lit (lit fraction of the sun's disc, as `query shadow`; needs --sun-az and
    /// --sun-el) or horizon-mean (mean horizon elevation over azimuth, degrees).
    #[arg(long)]
    product: penumbra::export::ExportProduct,
    /// Output format: cog (Cloud-Optimized GeoTIFF, written by GDAL's COG driver).
    #[arg(long, default_value = "cog")]
    format: String,
    /// A latitude/longitude box LAT0,LAT1,LON0,LON1 (degrees): the smallest grid holding it.
    /// Default: every tile of the level.
    #[arg(long, allow_hyphen_values = true, conflicts_with = "face")]
    bbox: Option<String>,
    /// One cube face whole (px, nx, py, ny, pz, nz): its gnomonic grid, pixel for pixel the
    /// level's tiles.
    #[arg(long)]
    face: Option<String>,
    /// Tile level to sample (default: the finest holding the product); the output's pixel is
    /// the level's pixel at a face centre.
    #[arg(long)]
    level: Option<u8>,
    /// Projection: stere (polar stereographic, the default for a region within 30° of a pole),
    /// eqc (equirectangular, the default elsewhere) or gnom (gnomonic, the default for --face).
    #[arg(long)]
    crs: Option<penumbra::export::CrsKind>,
    /// For lit: sun azimuth, degrees clockwise from local north, at every pixel.
    #[arg(long, allow_hyphen_values = true)]
    sun_az: Option<f64>,
    /// For lit: sun elevation above the local horizontal, degrees, at every pixel.
    #[arg(long, allow_hyphen_values = true)]
    sun_el: Option<f64>,
    /// For lit: the body's distance from the Sun (AU; default: the body preset's).
    #[arg(long, allow_hyphen_values = true)]
    sun_distance_au: Option<f64>,
    /// For lit: the disc model, constant, segment, slices or exact.
    #[arg(long, default_value = "exact")]
    model: Model,
    /// For lit and horizon-mean: read the horizons from the Fourier pyramids or the raw maps.
    #[arg(long, default_value = "fourier")]
    from: penumbra::shadow::HorizonSource,
    /// The GeoTIFF to write (replaced atomically).
    #[arg(long)]
    out: PathBuf,
    /// Refuse a raster above this many GiB of f32 samples.
    #[arg(long, default_value_t = penumbra::export::DEFAULT_MAX_OUTPUT_GIB, allow_hyphen_values = true)]
    max_output_gib: f64,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct PackageArgs {
    /// A tileset folder, or a scene file (TOML, docs/scenes.md) whose bake to package: the
    /// folder `penumbra bake SCENE --out DIR` made (--tileset), which must be that scene's
    /// latest bake (nothing is baked here).
    input: PathBuf,
    /// With a scene: the folder it was baked into [default: tiles, as for `penumbra bake`].
    #[arg(long, value_name = "DIR")]
    tileset: Option<PathBuf>,
    /// The addon folder to write: new, empty, or a package written before (replaced).
    #[arg(long, value_name = "OUT")]
    celestia: PathBuf,
    /// Also write a ZIP archive of the folder: --zip alone writes OUT.zip beside it,
    /// --zip=FILE names it (its folder must exist). Deterministic: the same package gives the
    /// same bytes.
    #[arg(long, value_name = "FILE", num_args = 0..=1, require_equals = true)]
    zip: Option<Option<PathBuf>>,
    /// Pixels per side of a virtual-texture tile: a power of two from 64 to 4096.
    #[arg(long, default_value_t = 512)]
    vt_tile_size: u32,
    /// The finest virtual-texture level written (0..=12): finer data stays in the cube-face
    /// products. Polar data needs whole rows of tiles around the pole at every level
    /// (docs/packaging.md, "Sizes and times"); a cap bounds them.
    #[arg(long, default_value_t = penumbra::package::celestia::MAX_VT_LEVEL)]
    vt_max_level: u8,
    /// The body as Celestia's catalogs name it (such as "Moon"), with --celestia-parent; by
    /// default from the tileset's body (moon, mercury, venus, earth, mars, pluto, ceres, vesta).
    #[arg(long, requires = "celestia_parent")]
    celestia_body: Option<String>,
    /// The body's parent path in Celestia (such as "Sol/Earth"), with --celestia-body.
    #[arg(long, requires = "celestia_body")]
    celestia_parent: Option<String>,
    /// The alternate surface's name, where the tileset covers part of the body.
    #[arg(long, default_value = "Penumbra")]
    alt_surface: String,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

impl ExportArgs {
    /// The library's options, every flag checked.
    fn options(&self) -> Result<penumbra::export::ExportOptions> {
        use penumbra::export::{ExportProduct, Region, SunSpec};
        let region = match (&self.bbox, &self.face) {
            (Some(b), _) => Region::Bbox(parse_bbox(b)?),
            (None, Some(f)) => Region::Face(
                (0..6)
                    .filter_map(penumbra::cube::Face::from_index)
                    .find(|x| x.name() == f)
                    .ok_or_else(|| {
                        Error::param(
                            "face",
                            format!("'{f}' is no face: use px, nx, py, ny, pz or nz"),
                        )
                    })?,
            ),
            (None, None) => Region::Coverage,
        };
        let sun =
            match (self.sun_az, self.sun_el) {
                (Some(az), Some(el)) => Some(SunSpec {
                    azimuth_deg: az,
                    elevation_deg: el,
                    distance_au: self.sun_distance_au,
                    model: self.model,
                }),
                (None, None) if self.sun_distance_au.is_none() => None,
                _ => return Err(Error::usage(
                    "give the sun as --sun-az and --sun-el together (and --sun-distance-au only \
                     with them)",
                )
                .into()),
            };
        if self.product == ExportProduct::Lit && sun.is_none() {
            return Err(Error::usage(
                "--product lit needs the sun: give --sun-az and --sun-el (degrees, as for \
                 `penumbra query shadow`)",
            )
            .into());
        }
        if self.product != ExportProduct::Lit && sun.is_some() {
            return Err(Error::usage(format!(
                "--sun-az/--sun-el are for --product lit, not {}",
                self.product.name()
            ))
            .into());
        }
        Ok(penumbra::export::ExportOptions {
            product: self.product,
            region,
            level: self.level,
            crs: self.crs,
            sun,
            from: self.from,
            max_output_gib: self.max_output_gib,
        })
    }
}

fn export(a: &ExportArgs) -> Result<()> {
    let opts = a.options()?;
    if a.format != "cog" {
        return Err(Error::param(
            "format",
            format!(
                "'{}' is not a format export writes: cog is the one there is",
                a.format
            ),
        )
        .into());
    }
    penumbra::export::check_out(&a.out)?;
    write_export(a, &opts)
}

#[cfg(feature = "gdal")]
fn write_export(a: &ExportArgs, opts: &penumbra::export::ExportOptions) -> Result<()> {
    let t0 = std::time::Instant::now();
    let raster = penumbra::export::render(&a.dir, opts)?;
    let rep = penumbra::export::cog::write(&raster, &a.out)?;
    output::print_export(
        &raster,
        &rep.path,
        rep.bytes,
        &rep.gdal,
        t0.elapsed().as_secs_f64(),
        a.json,
    )
}

/// Without GDAL, nothing but the library's message (`Error::no_gdal`, unit-tested in every
/// build; keep this trivial: CI builds with GDAL and does not compile it).
#[cfg(not(feature = "gdal"))]
fn write_export(_: &ExportArgs, _: &penumbra::export::ExportOptions) -> Result<()> {
    Err(Error::no_gdal("penumbra export").into())
}

/// How `plan --slurm` jobs run: each figure overrides the plan's estimate.
#[derive(Args, Clone, Debug)]
struct SlurmFlags {
    /// With --slurm: the tileset folder the jobs bake into.
    #[arg(long, value_name = "DIR", default_value = "tiles", requires = "slurm")]
    out: PathBuf,
    /// With --slurm: CPUs per task (default: from the plan's estimate of the slowest shard).
    #[arg(long, value_name = "N", requires = "slurm")]
    cpus_per_task: Option<u32>,
    /// With --slurm: memory per task in Slurm's syntax (4G, 1500M; default: the plan's model).
    #[arg(long, value_name = "SIZE", requires = "slurm")]
    mem: Option<String>,
    /// With --slurm: time limit per task in Slurm's syntax (90, 1:30:00, 2-00:00:00; default:
    /// the plan's estimate with a safety factor).
    #[arg(long, value_name = "TIME", requires = "slurm")]
    time: Option<String>,
    /// With --slurm: the Slurm partition to submit to.
    #[arg(long, requires = "slurm")]
    partition: Option<String>,
    /// With --slurm: the Slurm account to charge.
    #[arg(long, requires = "slurm")]
    account: Option<String>,
    /// With --slurm: the penumbra binary the jobs run (an absolute path the nodes see;
    /// default: this one).
    #[arg(long, value_name = "PATH", requires = "slurm")]
    penumbra: Option<PathBuf>,
}

/// Run part of a stage: the selection of its units (docs/architecture.md, "Units").
#[derive(Args, Clone, Debug)]
struct ShardFlag {
    /// Run only shard K of N (0-based) of the stage's units, about a N-th of its cost; the
    /// units stay staged and the run commits when the last units left are done, by whichever
    /// run of the same options completes them.
    #[arg(long, value_name = "K/N", value_parser = penumbra::runner::Select::shard)]
    shard: Option<penumbra::runner::Select>,
}

impl ShardFlag {
    fn select(&self) -> penumbra::runner::Select {
        self.shard.clone().unwrap_or_default()
    }
}

#[derive(Subcommand)]
enum QueryCommand {
    /// Height (m above the body's reference radius) at a latitude/longitude.
    Height {
        dir: PathBuf,
        /// Planetocentric latitude, degrees.
        #[arg(long, allow_hyphen_values = true)]
        lat: f64,
        /// East longitude, degrees (−180..360).
        #[arg(long, allow_hyphen_values = true)]
        lon: f64,
        /// Level to read (0 = coarsest; default the finest).
        #[arg(long)]
        level: Option<u8>,
        #[arg(long)]
        json: bool,
    },
    /// The (min, max) mipmap texel that contains a latitude/longitude.
    Mip {
        dir: PathBuf,
        /// Planetocentric latitude, degrees.
        #[arg(long, allow_hyphen_values = true)]
        lat: f64,
        /// East longitude, degrees (−180..360).
        #[arg(long, allow_hyphen_values = true)]
        lon: f64,
        /// Mip level (0 = finest: one texel per pixel); past the tile's 1×1 the face pyramid.
        #[arg(long)]
        level: u32,
        /// Tile level whose tiles to use (0 = coarsest; default the finest).
        #[arg(long)]
        tile_level: Option<u8>,
        #[arg(long)]
        json: bool,
    },
    /// The horizon of the pixel that contains a latitude/longitude: elevation per azimuth,
    /// azimuths clockwise from local north (read from stored maps, else computed on demand).
    Horizon {
        dir: PathBuf,
        /// Planetocentric latitude, degrees.
        #[arg(long, allow_hyphen_values = true)]
        lat: f64,
        /// East longitude, degrees (−180..360).
        #[arg(long, allow_hyphen_values = true)]
        lon: f64,
        /// Tile level (0 = coarsest; default the finest).
        #[arg(long)]
        level: Option<u8>,
        #[command(flatten)]
        flags: HorizonFlags,
        /// auto (stored raw maps of this method and azimuth count, else computed), raw,
        /// fourier (reconstructed from the pyramids) or reference (computed exactly).
        #[arg(long, default_value = "auto")]
        from: HorizonFrom,
        #[arg(long)]
        json: bool,
    },
    /// The lit fraction of the sun's disc at the pixel that contains a latitude/longitude.
    Shadow {
        dir: PathBuf,
        /// Planetocentric latitude, degrees.
        #[arg(long, allow_hyphen_values = true)]
        lat: f64,
        /// East longitude, degrees (−180..360).
        #[arg(long, allow_hyphen_values = true)]
        lon: f64,
        /// Tile level (0 = coarsest; default the finest).
        #[arg(long)]
        level: Option<u8>,
        /// Sun azimuth, degrees clockwise from local north.
        #[arg(long, allow_hyphen_values = true)]
        sun_az: f64,
        /// Sun elevation above the local horizontal of the sphere, degrees.
        #[arg(long, allow_hyphen_values = true)]
        sun_el: f64,
        /// The body's distance from the Sun (AU; default: the body preset's), which sets the
        /// sun's apparent radius.
        #[arg(long, allow_hyphen_values = true)]
        sun_distance_au: Option<f64>,
        #[command(flatten)]
        shadow: ShadowFlags,
        /// With --method horizon: fourier, raw, reference or auto (as for `query horizon`;
        /// default fourier).
        #[arg(long)]
        from: Option<HorizonFrom>,
        /// With --method horizon: the disc model, constant, segment, slices (Fritsch et al.)
        /// or exact.
        #[arg(long, default_value = "exact")]
        model: Model,
        /// With --from auto|reference: azimuth samples of a computed horizon.
        #[arg(long, default_value_t = 360)]
        azimuths: usize,
        /// With --from auto|reference: fast, exact or reference horizon computation.
        #[arg(long, default_value = "fast")]
        horizon_method: Method,
        /// Largest context margin searched around the pixel's tile, in pixels of its level.
        #[arg(long, default_value_t = 4096)]
        max_margin_px: u64,
        #[arg(long)]
        json: bool,
    },
}

/// How a shadow is found: `--method` and its settings.
#[derive(Args, Clone)]
struct ShadowFlags {
    /// horizon (look the baked horizons up), reference (exact search of the terrain, exact
    /// disc), uniform (fixed steps), dp (Jung et al. over a maximum mipmap, the texels its
    /// descent passed over refined where they could still rise higher), dp-dda (the same with a
    /// canonical DDA that skips texels), dp-jung and dp-dda-jung (Jung et al.'s DP as
    /// published, one texel per level, no refinement), extrema (Timokhin & Mikhaylyuk, hard),
    /// extrema-soft (their traversal finding the exact horizon within the sun's disc) or smap
    /// (Sakalauskas' silhouette map for the sun's direction, hard).
    #[arg(long, default_value = "horizon")]
    method: String,
    /// With --method uniform: steps along the ray (1..=1048576).
    #[arg(long, default_value_t = 100)]
    steps: usize,
    /// With --method dp|dp-dda|dp-jung|dp-dda-jung: N′ of each concatenated run (e.g. 5,5,5 or 5,5,5,3), or auto
    /// (each run reaches as far again as the ray has come, until it leaves the terrain).
    #[arg(long, default_value = "auto")]
    dp_levels: String,
}

impl ShadowFlags {
    /// The method, unless it is `horizon` (whose source and model come from other flags).
    fn search(&self) -> Result<Option<penumbra::shadow::ShadowMethod>> {
        use penumbra::shadow::trace::{Method as T, MAX_STEPS};
        use penumbra::shadow::ShadowMethod;
        let runs = || -> Result<penumbra::shadow::Runs> {
            self.dp_levels
                .parse()
                .map_err(|e: String| Error::param("dp_levels", e).into())
        };
        if !(1..=MAX_STEPS).contains(&self.steps) {
            return Err(Error::param(
                "steps",
                format!("{} is outside 1..={MAX_STEPS}", self.steps),
            )
            .into());
        }
        Ok(Some(ShadowMethod::Trace(match self.method.as_str() {
            "horizon" => return Ok(None),
            "smap" => return Ok(Some(ShadowMethod::SMap)),
            "reference" => T::Reference,
            "uniform" => T::Uniform { steps: self.steps },
            "dp" => T::Dp {
                runs: runs()?,
                dda: false,
            },
            "dp-dda" => T::Dp {
                runs: runs()?,
                dda: true,
            },
            "dp-jung" => T::JungDp {
                runs: runs()?,
                dda: false,
            },
            "dp-dda-jung" => T::JungDp {
                runs: runs()?,
                dda: true,
            },
            "extrema" => T::Extrema,
            "extrema-soft" => T::ExtremaSoft,
            other => {
                return Err(Error::param(
                    "method",
                    format!(
                        "unknown shadow method '{other}': use horizon, reference, uniform, dp, \
                         dp-dda, dp-jung, dp-dda-jung, extrema, extrema-soft or smap"
                    ),
                )
                .into())
            }
        })))
    }
}

#[derive(Args, Clone)]
struct FourierFlags {
    /// Complex coefficients kept per pixel (K), 1..=A/2+1.
    #[arg(long, default_value_t = 16)]
    coefficients: usize,
    /// multires (groups of 4 coefficients at 1, 1/2, 1/4, … resolution) or full.
    #[arg(long, default_value = "multires")]
    layout: Layout,
    /// f16 (as in the paper) or snorm16 (per-tile, per-group scale).
    #[arg(long, default_value = "f16")]
    encoding: Encoding,
    /// none, or lanczos σ-factors against Gibbs ringing.
    #[arg(long, default_value = "none")]
    sigma: Sigma,
    /// How multires groups are reduced: mean (the finer pixels' mean, as in the paper) or fit
    /// (least squares for bilinear sampling: lower error at the same size).
    #[arg(long, default_value = "mean")]
    reduce: Reduce,
    /// Choose K per tile: the fewest coefficients (up to --coefficients) whose truncation
    /// error (99th percentile of per-pixel RMS) is within this many degrees.
    #[arg(long, allow_hyphen_values = true)]
    max_error_deg: Option<f64>,
    /// Store tiles whose horizon never rises above this sun elevation (minus the sun's radius)
    /// as fully lit, without coefficients.
    #[arg(long, allow_hyphen_values = true)]
    min_sun_el: Option<f64>,
    /// The body's distance from the Sun in AU for --min-sun-el (default: the body preset's).
    #[arg(long, allow_hyphen_values = true)]
    sun_distance_au: Option<f64>,
}

impl FourierFlags {
    fn options(&self, levels: Option<Vec<u8>>, max_output_gib: f64) -> FourierOptions {
        FourierOptions {
            levels,
            coefficients: self.coefficients,
            layout: self.layout,
            encoding: self.encoding,
            sigma: self.sigma,
            reduce: self.reduce,
            max_error_deg: self.max_error_deg,
            min_sun_el_deg: self.min_sun_el,
            sun_distance_au: self.sun_distance_au,
            max_output_gib,
        }
    }
}

#[derive(Args, Clone)]
struct DeviceFlag {
    /// Where the sweep method runs: cpu, gpu (any adapter, Mesa's software lavapipe included;
    /// an error where there is none) or auto (a hardware GPU where one is present, else the
    /// CPU). The other methods run on the CPU. A GPU's maps are within the sweep's error budget
    /// of the CPU's, not the same bytes (docs/horizons.md, "On the GPU"). Needs a build with
    /// `--features penumbra-cli/gpu` (without it, auto is the CPU).
    /// [default: a scene's `[horizon] device`, else auto]
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(DeviceChoice::NAMES))]
    device: Option<String>,
}

impl DeviceFlag {
    /// The device the sweep runs on for `method` (None: the CPU); `scene` is the scene's
    /// choice, which `--device` overrides.
    fn open(
        &self,
        method: Method,
        scene: Option<DeviceChoice>,
    ) -> anyhow::Result<Option<penumbra::horizon::device::SharedDevice>> {
        let given = self.device.as_deref().and_then(DeviceChoice::parse);
        let choice = given.or(scene).unwrap_or_default();
        if choice == DeviceChoice::Cpu {
            return Ok(None);
        }
        if method != Method::Sweep {
            if choice == DeviceChoice::Gpu {
                return Err(penumbra::Error::param(
                    "device",
                    format!(
                        "gpu runs the sweep method only, and this run's method is {}: add \
                         --method sweep, or use --device cpu",
                        method.name()
                    ),
                )
                .into());
            }
            return Ok(None);
        }
        open_gpu(choice)
    }
}

/// What `--device gpu` says in a build without the GPU sweep.
#[cfg_attr(feature = "gpu", allow(dead_code))]
const NO_GPU: &str = "--device gpu: this build of penumbra has no GPU sweep (the `gpu` feature \
     of penumbra-cli); rebuild with `cargo build --release --features penumbra-cli/gpu` (wgpu, \
     and a Vulkan driver at run time), or run the sweep on the CPU with --device cpu";

#[cfg(feature = "gpu")]
fn open_gpu(
    choice: DeviceChoice,
) -> anyhow::Result<Option<penumbra::horizon::device::SharedDevice>> {
    match penumbra_gpu::GpuSweep::open(choice) {
        Ok(Some(g)) => Ok(Some(std::sync::Arc::new(g))),
        Ok(None) => Ok(None),
        Err(e) => Err(penumbra::Error::usage(e.to_string()).into()),
    }
}

#[cfg(not(feature = "gpu"))]
fn open_gpu(
    choice: DeviceChoice,
) -> anyhow::Result<Option<penumbra::horizon::device::SharedDevice>> {
    if choice == DeviceChoice::Gpu {
        return Err(penumbra::Error::usage(NO_GPU).into());
    }
    Ok(None)
}

#[derive(Args, Clone)]
struct HorizonFlags {
    /// Azimuth samples per pixel (plane azimuths 360·k/A from the face's +U axis).
    #[arg(long, default_value_t = 360)]
    azimuths: usize,
    /// sweep (each pixel's own ray exact over 24 columns, Timonen & Westerholm's line hulls
    /// beyond; ≤ 0.03° RMS from the reference, measured as it runs and recorded; ≈ 3–4× faster
    /// than fast), fast (exact within --near-px, upper-hull sweep beyond; ≈ 0.001° RMS), exact
    /// (the reference's answer: every ray walked over a maximum pyramid that skips what cannot
    /// win; ≈ 2–4× slower than fast) or reference (brute-force cell-by-cell search of every ray;
    /// ≈ 35× slower). [default: sweep with --fourier (the pyramids' own error is 6–25× the
    /// sweep's), fast for raw maps]
    #[arg(long)]
    method: Option<Method>,
    /// Largest context margin around a tile, in pixels of its level.
    #[arg(long, default_value_t = 4096)]
    max_margin_px: u64,
    /// How far (pixels) the fast method searches each pixel's own ray exactly before its sweep
    /// takes over: larger is slower and more accurate (0..=1024; `penumbra-bench horizon`
    /// measures the trade).
    /// [default: 24]
    #[arg(long)]
    near_px: Option<f64>,
    /// How far (pixels) around a tile the fast and sweep methods read its level's terrain; beyond that,
    /// out to the whole reach, they see far rings of coarser levels, each ring pixel no wider
    /// seen from the tile than a pixel at this distance (16..=65536; larger is slower, closer
    /// to the exact method and needs more memory; default two tile widths, at least 1024).
    #[arg(long)]
    fine_margin_px: Option<u64>,
}

impl HorizonFlags {
    /// `--method`, or the default for what is kept: sweep where only the Fourier pyramids are
    /// (`fourier`), fast where raw maps are.
    fn method(&self, fourier: bool) -> Method {
        self.method
            .unwrap_or(if fourier { Method::Sweep } else { Method::Fast })
    }

    fn options(&self) -> penumbra::Result<HorizonOptions> {
        let method = self.method(false);
        Ok(HorizonOptions {
            azimuths: self.azimuths,
            method,
            max_margin_px: self.max_margin_px,
            near_px: self.near_px(method)?,
            fine_margin_px: self.fine_margin_px(method)?,
            ..Default::default()
        })
    }

    /// `--near-px`, which only the fast method takes (the others would silently ignore it);
    /// `method` is the one in effect (given or by default).
    fn near_px(&self, method: Method) -> penumbra::Result<f64> {
        match self.near_px {
            Some(_) if method != Method::Fast => Err(penumbra::Error::param(
                "near-px",
                format!(
                    "is the fast method's only: the {} method{} has no near field to set \
                     (drop --near-px, or use --method fast)",
                    method.name(),
                    if self.method.is_none() {
                        " (the default with --fourier)"
                    } else {
                        ""
                    }
                ),
            )),
            v => Ok(v.unwrap_or(penumbra::horizon::DEFAULT_NEAR_PX)),
        }
    }

    /// `--fine-margin-px`, which only the methods with far rings take (fast and sweep; the
    /// others see the whole reach at full resolution, up to --max-margin-px).
    fn fine_margin_px(&self, method: Method) -> penumbra::Result<Option<u64>> {
        match self.fine_margin_px {
            Some(_) if !method.sees_far_rings() => Err(penumbra::Error::param(
                "fine-margin-px",
                format!(
                    "is for the methods with far rings: --method {} sees the whole reach at \
                     full resolution (drop --fine-margin-px, or use --method fast or sweep)",
                    method.name()
                ),
            )),
            v => Ok(v),
        }
    }
}

#[derive(Args, Clone)]
struct MipFlags {
    /// Sample type of the mipmaps: f32, or f16 with max rounded up and min rounded down.
    #[arg(long, default_value = "f32")]
    precision: Precision,
}

impl MipFlags {
    fn options(&self, compression: TileCompression, max_output_gib: f64) -> MipOptions {
        MipOptions {
            precision: self.precision,
            compression,
            max_output_gib,
            ..Default::default()
        }
    }
}

#[derive(Args, Clone)]
struct BodyArgs {
    /// Body preset (moon, mars, earth, mercury, venus, pluto, ceres, vesta); default: the body
    /// the DEM names.
    #[arg(long)]
    body: Option<String>,
    /// Reference radius in metres (overrides the preset's).
    #[arg(long)]
    radius_m: Option<f64>,
}

#[derive(Args, Clone)]
struct TileFlags {
    /// Interior pixels per tile side.
    #[arg(long, default_value_t = 512)]
    tile_size: u32,
    /// Halo pixels on each side, sampled from the true neighbours.
    #[arg(long, default_value_t = 2)]
    halo: u32,
    #[arg(long, default_value = "gnomonic")]
    projection: Projection,
    /// Number of levels (default: from the source resolution).
    #[arg(long)]
    levels: Option<u8>,
    #[arg(long, default_value = "bilinear")]
    resampling: Resampling,
    /// Anti-aliasing of coarser levels: box (mean of up to 4×4 samples per pixel) or point.
    #[arg(long, default_value = "box")]
    prefilter: Prefilter,
    /// EXR height-tile compression: zip (lossless, about half the size) or none (fastest).
    #[arg(long, default_value = "zip")]
    compression: TileCompression,
    /// Fill voids up to this many source pixels from measured data; farther voids are no data.
    #[arg(long, default_value_t = penumbra::dem::DEFAULT_MAX_FILL_PX)]
    void_fill_px: u32,
    /// 8/16-bit equirectangular global albedo image (PNG) to tile in the same layout.
    #[arg(long)]
    albedo: Option<PathBuf>,
    /// East longitude of the albedo image's left edge.
    #[arg(long, default_value_t = -180.0, allow_hyphen_values = true)]
    albedo_west: f64,
    /// Refuse a tiling whose tiles would exceed this many GiB before compression (the estimate
    /// is made before anything is written).
    #[arg(
        long = "max-output-gib",
        default_value_t = penumbra::runner::DEFAULT_MAX_OUTPUT_GIB,
        allow_hyphen_values = true
    )]
    max_output_gib: f64,
    /// Heights MIN,MAX in metres above the body's sphere that the terrain really reaches, when
    /// they go beyond the body's known relief and its margin (e.g. -20000,70000); without it
    /// such a DEM is refused (docs/formats.md, "Relief of the body").
    #[arg(long, value_name = "MIN,MAX", allow_hyphen_values = true)]
    allow_relief: Option<String>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

/// MIN,MAX in metres.
fn parse_relief(s: &str) -> Result<(f64, f64)> {
    let bad = || {
        Error::param(
            "allow_relief",
            format!("'{s}' is not two numbers MIN,MAX (metres above the body's sphere)"),
        )
    };
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad())?;
    match v[..] {
        [lo, hi] => Ok((lo, hi)),
        _ => Err(bad().into()),
    }
}

impl TileFlags {
    fn options(&self) -> Result<TileOptions> {
        Ok(TileOptions {
            tile_size: self.tile_size,
            halo: self.halo,
            projection: self.projection,
            levels: self.levels,
            resampling: self.resampling,
            prefilter: self.prefilter,
            compression: self.compression,
            max_fill_px: self.void_fill_px,
            albedo: self.albedo.clone().map(|p| (p, self.albedo_west)),
            max_output_gib: self.max_output_gib,
            allow_relief_m: self.allow_relief.as_deref().map(parse_relief).transpose()?,
            prune: false,
        })
    }
}

#[derive(Args)]
struct TileArgs {
    /// The DEM: PDS3 .LBL or .IMG, SRTM .hgt, GeoTIFF, EXR or raw with a JSON sidecar (any
    /// raster GDAL opens with --dem-format gdal, in a build with `--features gdal`).
    dem: PathBuf,
    /// Reader of the DEM: auto (the native reader its name chooses) or gdal.
    #[arg(long, default_value = "auto")]
    dem_format: penumbra::dem::DemFormat,
    #[command(flatten)]
    body: BodyArgs,
    /// Output tileset folder.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    flags: TileFlags,
}

#[derive(Args)]
struct BakeArgs {
    /// Scene file (TOML, docs/scenes.md) to bake; default: the embedded scene.
    #[arg(conflicts_with_all = ["dem", "scene_size", "horizon_levels", "no_horizons", "no_fourier", "keep_raw"])]
    scene: Option<PathBuf>,
    /// A DEM to bake whole instead of a scene.
    #[arg(long)]
    dem: Option<PathBuf>,
    /// Reader of --dem: auto (the native reader its name chooses) or gdal.
    #[arg(long, default_value = "auto", requires = "dem")]
    dem_format: penumbra::dem::DemFormat,
    #[command(flatten)]
    body: BodyArgs,
    /// Output tileset folder.
    #[arg(long, default_value = "tiles")]
    out: PathBuf,
    /// Pixels per side of the embedded scene (20 m/px).
    #[arg(long, default_value_t = 2048)]
    scene_size: usize,
    #[command(flatten)]
    flags: TileFlags,
    #[command(flatten)]
    mip: MipFlags,
    /// Compute horizons for these tile levels (comma-separated; 360 azimuths, fast method)
    /// and compress them into Fourier pyramids. Default: level 6 of the embedded scene, none
    /// for a --dem (give levels to get horizons).
    #[arg(long, value_delimiter = ',')]
    horizon_levels: Option<Vec<u8>>,
    /// No horizons at all (tiles and mipmaps only).
    #[arg(long, conflicts_with = "horizon_levels")]
    no_horizons: bool,
    /// Write raw horizon maps instead of Fourier pyramids.
    #[arg(long)]
    no_fourier: bool,
    /// Write raw horizon maps beside the Fourier pyramids.
    #[arg(long, conflicts_with = "no_fourier")]
    keep_raw: bool,
    /// When a later stage fails in a folder this bake created, keep what the earlier stages
    /// committed (a valid tileset) instead of removing the folder.
    #[arg(long)]
    keep_partial: bool,
    /// With a scene: keep only the scene's tiles in the output folder, removing those that
    /// bakes of other scenes added there (by default a bake adds its tiles and keeps theirs).
    #[arg(long, conflicts_with = "stage")]
    prune: bool,
    /// Run only this stage of the scene's bake (tile, mip or horizon), after the stages it
    /// reads have committed: whole, or with --shard / --finish (docs/cluster.md).
    #[arg(long, value_name = "STAGE", conflicts_with_all = ["dem", "scene_size", "horizon_levels", "no_horizons", "no_fourier", "keep_raw"])]
    stage: Option<String>,
    /// With --stage: run only shard I of N (0-based) of the stage's units, at the same time as
    /// the others (here or on other hosts sharing the folder); it never commits: --finish does.
    #[arg(long, value_name = "I/N", requires = "stage", value_parser = penumbra::runner::Select::shard)]
    shard: Option<penumbra::runner::Select>,
    /// With --stage: once every shard has run, check their work (every unit recorded, every
    /// file with its size and blake3) and commit the stage; a shard missing or damaged is
    /// named and nothing is committed (exit 2).
    #[arg(long, requires = "stage", conflicts_with = "shard")]
    finish: bool,
    #[command(flatten)]
    device: DeviceFlag,
    #[command(flatten)]
    fourier: FourierFlags,
}

/// Horizon level of the embedded scene's default bake (or its finest level when it has fewer):
/// 4 tiles of 512² at 106 m/px; finer levels cost many times more horizon time.
const EMBEDDED_HORIZON_LEVEL: u8 = 6;

/// A tile given as FACE/Y/X at `level`.
/// LAT0,LAT1,LON0,LON1 in degrees.
fn parse_bbox(b: &str) -> Result<[f64; 4]> {
    let v: Vec<f64> = b
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| {
            Error::param(
                "bbox",
                format!("'{b}' is not four numbers LAT0,LAT1,LON0,LON1 (degrees)"),
            )
        })?;
    let a: [f64; 4] = v.try_into().map_err(|_| {
        Error::param(
            "bbox",
            format!("'{b}' is not four numbers LAT0,LAT1,LON0,LON1 (degrees)"),
        )
    })?;
    penumbra::shadow::check_bbox(a)?;
    Ok(a)
}

fn parse_tile(level: u8, s: &str) -> Result<penumbra::layout::TileId> {
    let parts: Vec<&str> = s.split('/').collect();
    let bad = || {
        anyhow::anyhow!(
            "--tile {s}: give FACE/Y/X, e.g. nz/31/32 (faces px, nx, py, ny, pz, nz; Y and X \
             the tile's row and column at --level)"
        )
    };
    if parts.len() != 3 {
        return Err(bad());
    }
    let face = (0..6)
        .filter_map(penumbra::cube::Face::from_index)
        .find(|f| f.name() == parts[0])
        .ok_or_else(bad)?;
    let y: u32 = parts[1].parse().map_err(|_| bad())?;
    let x: u32 = parts[2].parse().map_err(|_| bad())?;
    Ok(penumbra::layout::TileId { level, face, x, y })
}

fn body_arg(b: &BodyArgs) -> Result<BodyChoice> {
    // An unknown name or a bad radius is refused before any file is read.
    if b.body.is_some() || b.radius_m.is_some() {
        Body::resolve(b.body.as_deref(), b.radius_m)?;
    }
    Ok(BodyChoice {
        name: b.body.clone(),
        radius_m: b.radius_m,
    })
}

/// A DEM input read by `format`'s reader.
fn dem_input(
    path: PathBuf,
    b: &BodyArgs,
    format: penumbra::dem::DemFormat,
) -> Result<Input<'static>> {
    let body = body_arg(b)?;
    Ok(match format {
        penumbra::dem::DemFormat::Auto => Input::Dem { path, body },
        format => Input::DemWith { path, body, format },
    })
}

/// `penumbra report`: check the flags and the input, measure, write the files.
fn report(a: &ReportArgs, progress: &output::Bars) -> Result<penumbra_cli::report::Report> {
    use penumbra_cli::report as rp;
    let check = |name: &'static str, v: f64, r: std::ops::RangeInclusive<f64>| -> Result<()> {
        if !(v.is_finite() && r.contains(&v)) {
            return Err(
                Error::param(name, format!("{v} is outside {}..={}", r.start(), r.end())).into(),
            );
        }
        Ok(())
    };
    check("budget_s", a.budget_s, rp::BUDGET_S)?;
    check("max_per", a.max_per, rp::MAX_PER_PCT)?;
    check("max_error_deg", a.max_error_deg, rp::MAX_ERROR_DEG)?;
    if let Some(from) = &a.from {
        let mut r = rp::read(from)?;
        rp::rebudget(&mut r, a.max_per, a.max_error_deg);
        rp::render::write(&r, &a.out)?;
        return Ok(r);
    }
    let (scene, tileset) = match (&a.input, &a.tileset) {
        (Some(p), None) if p.is_dir() => (None, p.clone()),
        (Some(p), Some(_)) if p.is_dir() => {
            return Err(Error::invalid(
                p,
                "is a tileset folder: give --tileset only with a scene file",
            )
            .into())
        }
        (Some(p), Some(t)) => (Some(penumbra::scene::load(p)?), t.clone()),
        (None, Some(t)) => (Some(penumbra::scene::embedded()), t.clone()),
        (Some(p), None) => {
            if !p.exists() {
                return Err(Error::invalid(
                    p,
                    "no such file or folder: give a tileset folder or a scene file",
                )
                .into());
            }
            return Err(Error::invalid(
                p,
                "a scene file needs the tileset it was baked into: add --tileset DIR \
                 (penumbra bake SCENE --out DIR makes it)",
            )
            .into());
        }
        (None, None) => {
            return Err(Error::param(
                "tileset",
                "is needed: give a tileset folder, or --tileset DIR with a scene (none: the \
                 embedded scene's bake)",
            )
            .into())
        }
    };
    let store = penumbra::tileset::Store::open_unlocked(&tileset)?;
    let input = rp::Input {
        store: &store,
        tileset: tileset.clone(),
        scene: scene.as_ref(),
    };
    let opts = rp::Options {
        budget_s: a.budget_s,
        max_per_pct: a.max_per,
        max_error_deg: a.max_error_deg,
        seed: a.seed,
        level: a.level,
        fixed: a.blocks.map(|b| (b as usize, a.block_px)),
    };
    let r = rp::report(&input, &opts, progress)?;
    rp::render::write(&r, &a.out)?;
    Ok(r)
}

fn run(cli: Cli, legacy_bake: bool) -> Result<()> {
    penumbra_cli::set_threads(cli.threads)?;
    let progress = output::Bars::new(cli.quiet);
    match cli.command {
        Command::Tile(a) => {
            let plan = Plan {
                stages: vec![Stage::Tile],
                tile: a.flags.options()?,
                mip: MipOptions::default(),
                horizon: HorizonOptions::default(),
                fourier: None,
                keep_raw: false,
                horizon_level_at_most: None,
                keep_partial: false,
            };
            let input = dem_input(a.dem.clone(), &a.body, a.dem_format)?;
            let t0 = std::time::Instant::now();
            let report = bake::bake(&input, &a.out, &plan, &progress)?;
            output::print_bake(&report, t0.elapsed().as_secs_f64(), a.flags.json)?;
        }
        Command::Bake(a) if a.scene.is_some() || !legacy_bake => {
            let t0 = std::time::Instant::now();
            let scene = match &a.scene {
                Some(p) => penumbra::scene::load(p)?,
                None => penumbra::scene::embedded(),
            };
            if let Some(stage) = &a.stage {
                let role = match (&a.shard, a.finish) {
                    (_, true) => penumbra::runner::Role::Finish,
                    (Some(_), false) => penumbra::runner::Role::Shard,
                    (None, false) => penumbra::runner::Role::Writer,
                };
                let select = a.shard.clone().unwrap_or_default();
                let plan = penumbra::scene::plan::plan(&scene)?;
                let device = a
                    .device
                    .open(plan.scene.horizon.method, Some(plan.scene.horizon.device))?;
                let ran = penumbra::scene::bake::bake_stage(
                    &plan, &a.out, stage, &select, role, device, &progress,
                )?;
                output::print_ran(&ran, t0.elapsed().as_secs_f64(), a.flags.json)?;
                return Ok(());
            }
            let how = penumbra::scene::bake::BakeOptions {
                keep_partial: a.keep_partial,
                prune: a.prune,
                device: a
                    .device
                    .open(scene.horizon.method, Some(scene.horizon.device))?,
            };
            if let Some(r) = penumbra::scene::bake::unchanged(&scene, &a.out, &how)? {
                output::print_bake(&r, t0.elapsed().as_secs_f64(), a.flags.json)?;
                return Ok(());
            }
            let plan = penumbra::scene::plan::plan(&scene)?;
            let report = penumbra::scene::bake::bake_scene(&plan, &a.out, &how, &progress)?;
            output::print_bake(&report, t0.elapsed().as_secs_f64(), a.flags.json)?;
        }
        Command::Plan {
            scene,
            tileset,
            shards,
            slurm,
            slurm_flags,
            json,
        } => {
            let t0 = std::time::Instant::now();
            if let Some(dir) = &slurm {
                // Refused before the plan is computed: a folder that is not ours, no parent.
                penumbra::scene::slurm::check_dir(dir)?;
            }
            let mut plan = match &scene {
                Some(p) => penumbra::scene::plan::plan_file(p)?,
                None => penumbra::scene::plan::plan(&penumbra::scene::embedded())?,
            };
            if let Some(dir) = &tileset {
                penumbra::scene::plan::decide_pruning(&mut plan, dir)?;
            }
            match shards {
                None => output::print_plan(&plan, t0.elapsed().as_secs_f64(), json)?,
                Some(n) => {
                    let table = penumbra::scene::shards::table(&plan, n as usize);
                    if let Some(dir) = &slurm {
                        let f = &slurm_flags;
                        let penumbra = match &f.penumbra {
                            Some(p) => p.clone(),
                            None => std::env::current_exe()
                                .and_then(std::fs::canonicalize)
                                .map_err(|e| {
                                    anyhow::anyhow!(
                                        "cannot find this binary's path ({e}); give --penumbra"
                                    )
                                })?,
                        };
                        let opts = penumbra::scene::slurm::SlurmOptions {
                            dir: dir.clone(),
                            shards: n as usize,
                            out: f.out.clone(),
                            scene_file: scene.clone(),
                            penumbra,
                            cpus_per_task: f.cpus_per_task,
                            mem: f.mem.clone(),
                            time: f.time.clone(),
                            partition: f.partition.clone(),
                            account: f.account.clone(),
                        };
                        let jobs = penumbra::scene::slurm::jobs(&plan, &table, &opts)?;
                        let files = penumbra::scene::slurm::files(&plan, &table, &opts)?;
                        penumbra::scene::slurm::write(dir, &files)?;
                        output::print_slurm(dir, &jobs, &table, t0.elapsed().as_secs_f64(), json)?
                    } else {
                        output::print_plan_shards(&plan, &table, t0.elapsed().as_secs_f64(), json)?
                    }
                }
            }
        }
        Command::Bake(a) => {
            let mut plan = Plan {
                tile: a.flags.options()?,
                mip: a.mip.options(a.flags.compression, a.flags.max_output_gib),
                keep_partial: a.keep_partial,
                ..Plan::default()
            };
            let levels = match (&a.horizon_levels, &a.dem) {
                _ if a.no_horizons => None,
                (Some(l), _) => Some(l.clone()),
                (None, None) => {
                    plan.horizon_level_at_most = Some(EMBEDDED_HORIZON_LEVEL);
                    Some(Vec::new())
                }
                (None, Some(_)) => None,
            };
            if let Some(levels) = levels {
                plan.stages.push(Stage::Horizon);
                plan.horizon.levels = Some(levels);
                plan.horizon.compression = a.flags.compression;
                if !a.no_fourier {
                    plan.fourier = Some(a.fourier.options(None, a.flags.max_output_gib));
                    plan.keep_raw = a.keep_raw;
                    // Only the pyramids are kept: the sweep method's error is a few per cent
                    // of theirs (docs/horizons.md, "Methods at a glance").
                    if !a.keep_raw {
                        plan.horizon.method = Method::Sweep;
                    }
                }
                plan.horizon.device = a.device.open(plan.horizon.method, None)?;
            }
            let input = match &a.dem {
                Some(p) => dem_input(p.clone(), &a.body, a.dem_format)?,
                None => {
                    if a.scene_size < 1024 || a.scene_size > 16384 {
                        anyhow::bail!("--scene-size {} is outside 1024..16384", a.scene_size);
                    }
                    Input::Embedded(SyntheticSpec {
                        size: a.scene_size,
                        ..SyntheticSpec::default()
                    })
                }
            };
            let t0 = std::time::Instant::now();
            let report = bake::bake(&input, &a.out, &plan, &progress)?;
            output::print_bake(&report, t0.elapsed().as_secs_f64(), a.flags.json)?;
        }
        Command::Mip {
            dir,
            flags,
            compression,
            max_output_gib,
            shard,
            json,
        } => {
            let t0 = std::time::Instant::now();
            let node = graph::mip(flags.options(compression, max_output_gib));
            let ran = node.run(&dir, &shard.select(), &progress)?;
            output::print_ran(&ran, t0.elapsed().as_secs_f64(), json)?;
        }
        Command::Horizon {
            dir,
            levels,
            flags,
            precision,
            compression,
            max_output_gib,
            fourier,
            keep_raw,
            lit_above,
            fourier_flags,
            shard,
            json,
            device,
        } => {
            let method = flags.method(fourier && !keep_raw);
            let device = device.open(method, None)?;
            let opts = HorizonOptions {
                levels,
                azimuths: flags.azimuths,
                method,
                precision,
                compression,
                max_margin_px: flags.max_margin_px,
                max_output_gib,
                near_px: flags.near_px(method)?,
                fine_margin_px: flags.fine_margin_px(method)?,
                lit_above_deg: lit_above,
                terrain_range_m: None,
                device,
            };
            let fourier = fourier
                .then(|| fourier_flags.options(None, penumbra::runner::DEFAULT_MAX_OUTPUT_GIB));
            let t0 = std::time::Instant::now();
            let ran = graph::horizons(
                &dir,
                &opts,
                fourier.as_ref(),
                keep_raw,
                &shard.select(),
                &progress,
            )?;
            output::print_ran(&ran, t0.elapsed().as_secs_f64(), json)?;
        }
        Command::Fourier {
            dir,
            levels,
            flags,
            max_output_gib,
            shard,
            json,
        } => {
            let t0 = std::time::Instant::now();
            let node = graph::fourier(flags.options(levels, max_output_gib));
            let ran = node.run(&dir, &shard.select(), &progress)?;
            output::print_ran(&ran, t0.elapsed().as_secs_f64(), json)?;
        }
        Command::Shadow {
            dir,
            level,
            tile,
            sun_lat,
            sun_lon,
            sun_distance_au,
            shadow,
            from,
            model,
            out,
            relief,
            exr,
            bbox,
            json,
        } => {
            let method = match shadow.search()? {
                Some(m) => {
                    if from.is_some() {
                        return Err(Error::usage(
                            "--from chooses the horizons of --method horizon; ray-marching \
                             methods search the terrain itself",
                        )
                        .into());
                    }
                    m
                }
                None => penumbra::shadow::ShadowMethod::Horizon(
                    from.unwrap_or(penumbra::shadow::HorizonSource::Fourier),
                    model,
                ),
            };
            let exr_path = exr.then(|| out.with_extension("exr"));
            if exr_path.as_ref() == Some(&out) {
                return Err(Error::param(
                    "out",
                    "--out names the PNG; with --exr the EXR goes beside it: give a .png name",
                )
                .into());
            }
            let t0 = std::time::Instant::now();
            match (tile, bbox) {
                (Some(tile), _) => {
                    let id = parse_tile(level, &tile)?;
                    let sh = penumbra::shadow::tile_shadows(
                        &dir,
                        id,
                        sun_lat,
                        sun_lon,
                        sun_distance_au,
                        &method,
                    )?;
                    penumbra::shadow::write_images(
                        sh.n,
                        sh.n,
                        &sh.lit,
                        &sh.relief,
                        &out,
                        relief.as_deref(),
                        exr_path.as_deref(),
                    )?;
                    output::print_shadows(
                        &sh,
                        &out,
                        relief.as_deref(),
                        t0.elapsed().as_secs_f64(),
                        json,
                    )?;
                }
                (None, Some(b)) => {
                    let bbox = parse_bbox(&b)?;
                    let sh = penumbra::shadow::region_shadows(
                        &dir,
                        level,
                        bbox,
                        sun_lat,
                        sun_lon,
                        sun_distance_au,
                        &method,
                    )?;
                    penumbra::shadow::write_images(
                        sh.width,
                        sh.height,
                        &sh.lit,
                        &sh.relief,
                        &out,
                        relief.as_deref(),
                        exr_path.as_deref(),
                    )?;
                    output::print_region_shadows(
                        &sh,
                        &out,
                        relief.as_deref(),
                        t0.elapsed().as_secs_f64(),
                        json,
                    )?;
                }
                (None, None) => unreachable!("clap requires --tile or --bbox"),
            }
        }
        Command::Export(a) => export(&a)?,
        Command::Package(a) => {
            let t0 = std::time::Instant::now();
            let report = package(&a, &progress)?;
            output::print_package(&report, t0.elapsed().as_secs_f64(), a.json)?;
        }
        Command::Report(a) => {
            let r = report(&a, &progress)?;
            output::print_report(&r, &a.out, a.json)?;
        }
        Command::Info { dir, json } => output::print_info(&dir, json)?,
        Command::Verify { dir, json } => {
            let r = penumbra::tileset::verify::verify(&dir)?;
            output::print_verify(&r, json)?;
            if !r.clean() {
                std::process::exit(1);
            }
        }
        Command::Stress {
            full,
            only,
            weaken,
            device,
            json,
        } => {
            // The CPU unless --device says otherwise.
            let dev = DeviceFlag { device }.open(Method::Sweep, Some(DeviceChoice::Cpu))?;
            let key = dev.as_ref().map(|d| d.key());
            penumbra::stress::set_sweep_device(dev);
            if !stress(
                full,
                only.as_deref(),
                weaken.as_deref(),
                key.as_deref(),
                json,
                cli.quiet,
            )? {
                std::process::exit(1);
            }
        }
        Command::Query(QueryCommand::Height {
            dir,
            lat,
            lon,
            level,
            json,
        }) => {
            let ans = penumbra::query::height(&dir, lat, lon, level)?;
            output::print_height(&ans, json)?;
        }
        Command::Query(QueryCommand::Mip {
            dir,
            lat,
            lon,
            level,
            tile_level,
            json,
        }) => {
            let ans = penumbra::query::mip(&dir, lat, lon, level, tile_level)?;
            output::print_mip_answer(&ans, json)?;
        }
        Command::Query(QueryCommand::Horizon {
            dir,
            lat,
            lon,
            level,
            flags,
            from,
            json,
        }) => {
            let opts = flags.options()?;
            let ans = penumbra::query::horizon(&dir, lat, lon, level, &opts, from)?;
            output::print_horizon_answer(&ans, json)?;
        }
        Command::Query(QueryCommand::Shadow {
            dir,
            lat,
            lon,
            level,
            sun_az,
            sun_el,
            sun_distance_au,
            shadow,
            from,
            model,
            azimuths,
            horizon_method,
            max_margin_px,
            json,
        }) => {
            let search = shadow.search()?;
            if search.is_some() && from.is_some() {
                return Err(Error::usage(
                    "--from chooses the horizons of --method horizon; ray-marching methods \
                     search the terrain itself",
                )
                .into());
            }
            let opts = HorizonOptions {
                azimuths,
                method: horizon_method,
                max_margin_px,
                ..Default::default()
            };
            let ans = penumbra::query::shadow(
                &dir,
                lat,
                lon,
                level,
                sun_az,
                sun_el,
                sun_distance_au,
                model,
                from.unwrap_or(HorizonFrom::Fourier),
                &opts,
                search.as_ref(),
            )?;
            output::print_shadow_answer(&ans, json)?;
        }
    }
    Ok(())
}

/// `penumbra package`: the tileset to package (a folder, or a scene's up-to-date bake), then
/// the package.
fn package(
    a: &PackageArgs,
    progress: &dyn penumbra::progress::Progress,
) -> Result<penumbra::package::bundle::PackageReport> {
    use penumbra::package::bundle;
    let dir = match std::fs::metadata(&a.input) {
        Ok(m) if m.is_dir() => {
            if let Some(t) = &a.tileset {
                return Err(Error::usage(format!(
                    "--tileset {} names the bake of a scene, but {} is a tileset folder \
                     already: drop --tileset",
                    t.display(),
                    a.input.display()
                ))
                .into());
            }
            a.input.clone()
        }
        Ok(_) => {
            let scene = penumbra::scene::load(&a.input)?;
            let dir = a.tileset.clone().unwrap_or_else(|| PathBuf::from("tiles"));
            // The scene's latest bake there, as `bake` would find it with or without --prune.
            let baked = [false, true].into_iter().any(|prune| {
                let how = penumbra::scene::bake::BakeOptions {
                    keep_partial: false,
                    prune,
                    device: None,
                };
                matches!(
                    penumbra::scene::bake::unchanged(&scene, &dir, &how),
                    Ok(Some(_))
                )
            });
            if !baked {
                return Err(Error::usage(format!(
                    "{} holds no up-to-date bake of the scene {} (never baked there, or the \
                     scene, its sources or the tileset changed since): run `penumbra bake {} \
                     --out {}` first (package bakes nothing itself)",
                    dir.display(),
                    a.input.display(),
                    a.input.display(),
                    dir.display()
                ))
                .into());
            }
            dir
        }
        Err(e) => {
            return Err(Error::usage(format!(
                "{}: {e}: give a tileset folder or a scene file",
                a.input.display()
            ))
            .into())
        }
    };
    let zip = a.zip.as_ref().map(|z| {
        z.clone()
            .unwrap_or_else(|| bundle::default_zip_path(&a.celestia))
    });
    let opts = bundle::PackageOptions {
        addon: penumbra::package::celestia::AddonOptions {
            vt_tile_size: a.vt_tile_size,
            body: a.celestia_body.clone().zip(a.celestia_parent.clone()),
            alt_surface: a.alt_surface.clone(),
            max_vt_level: a.vt_max_level,
        },
        zip,
        command: package_command(a),
    };
    Ok(bundle::package(&dir, &a.celestia, &opts, progress)?)
}

/// The `penumbra package` command line that makes this package (what changes its bytes: not
/// --threads, --quiet or --json), for its README.
fn package_command(a: &PackageArgs) -> String {
    let q = |p: &std::ffi::OsStr| {
        let s = p.to_string_lossy();
        if s.is_empty() || s.contains(|c: char| c.is_whitespace() || "'\"$`\\".contains(c)) {
            format!("'{}'", s.replace('\'', "'\\''"))
        } else {
            s.into_owned()
        }
    };
    let mut v = vec![
        "penumbra".to_string(),
        "package".into(),
        q(a.input.as_os_str()),
    ];
    if let Some(t) = &a.tileset {
        v.extend(["--tileset".into(), q(t.as_os_str())]);
    }
    v.extend(["--celestia".into(), q(a.celestia.as_os_str())]);
    match &a.zip {
        Some(None) => v.push("--zip".into()),
        Some(Some(z)) => v.push(format!("--zip={}", q(z.as_os_str()))),
        None => {}
    }
    if a.vt_tile_size != 512 {
        v.push(format!("--vt-tile-size={}", a.vt_tile_size));
    }
    if a.vt_max_level != penumbra::package::celestia::MAX_VT_LEVEL {
        v.push(format!("--vt-max-level={}", a.vt_max_level));
    }
    if let (Some(b), Some(p)) = (&a.celestia_body, &a.celestia_parent) {
        v.extend([
            "--celestia-body".into(),
            q(b.as_ref()),
            "--celestia-parent".into(),
            q(p.as_ref()),
        ]);
    }
    if a.alt_surface != "Penumbra" {
        v.extend(["--alt-surface".into(), q(a.alt_surface.as_ref())]);
    }
    v.join(" ")
}

/// `penumbra stress`: runs the selected cases (progress per case on stderr unless quiet),
/// prints the rows; whether every row passed. Bad flags are errors (exit 2).
fn stress(
    full: bool,
    only: Option<&str>,
    weaken: Option<&str>,
    device: Option<&str>,
    json: bool,
    quiet: bool,
) -> Result<bool> {
    use penumbra::stress::{self, Size, Weaken};
    let weaken = match weaken {
        None => Weaken::None,
        Some(w) => Weaken::parse(w).ok_or_else(|| {
            Error::param(
                "weaken",
                format!(
                    "'{w}' is no weakened kernel: use one of {}",
                    Weaken::ALL.map(|w| w.name()).join(", ")
                ),
            )
        })?,
    };
    let cases = stress::select(only);
    if cases.is_empty() {
        return Err(Error::param(
            "only",
            format!(
                "'{}' matches no case: use part of one of {}",
                only.unwrap_or_default(),
                stress::catalogue()
                    .iter()
                    .map(|c| c.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )
        .into());
    }
    let size = if full { Size::Full } else { Size::Short };
    let t0 = std::time::Instant::now();
    let rows = stress::run(&cases, size, weaken, &|c, rows, secs| {
        if !quiet {
            let failed = rows.iter().filter(|r| !r.pass).count();
            let verdict = if failed == 0 {
                "pass".to_string()
            } else {
                format!("FAIL ({failed} rows)")
            };
            eprintln!("stress: {:<28} {:>7.2} s  {verdict}", c.name, secs);
        }
    });
    output::print_stress(
        &rows,
        size,
        weaken,
        device,
        t0.elapsed().as_secs_f64(),
        json,
    )?;
    Ok(rows.iter().all(|r| r.pass))
}

fn main() -> ExitCode {
    let matches = Cli::command().get_matches();
    let legacy = legacy_bake(&matches);
    let result = Cli::from_arg_matches(&matches)
        .map_err(anyhow::Error::from)
        .and_then(|cli| run(cli, legacy));
    penumbra_cli::exit_code("penumbra", result)
}

/// Whether `bake` was given flags of the one-DEM (or sized embedded) bake rather than a scene:
/// then it runs as before scenes existed; otherwise it bakes the scene (the embedded one when
/// none is named), which makes the same files.
fn legacy_bake(m: &clap::ArgMatches) -> bool {
    const SCENE_FLAGS: &[&str] = &[
        "scene",
        "out",
        "keep_partial",
        "prune",
        "stage",
        "shard",
        "finish",
        "json",
        "quiet",
        "threads",
    ];
    let Some(("bake", b)) = m.subcommand() else {
        return false;
    };
    b.ids().any(|id| {
        !SCENE_FLAGS.contains(&id.as_str())
            && b.value_source(id.as_str()) == Some(clap::parser::ValueSource::CommandLine)
    })
}
