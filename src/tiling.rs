//! The tiling stage: resample a DEM (and optionally an albedo image) into cube-face tiles.
//!
//! Every stored pixel — interior and halo — is a function of its own global face position
//! alone, so neighbouring tiles and faces agree wherever they overlap, to within resampling
//! error. Finest-level pixels are interpolated from the source at their own direction. With the
//! box prefilter, a pixel at `finest − d` is the mean of the `2^d × 2^d` finest-level pixel
//! centres it covers (d ≤ 2, [`MAX_BOX`]): those levels are averaged from one block of
//! finest-level samples per group of tiles ([`group_depth`]), which costs what point sampling
//! costs instead of 2–3× that; coarser levels take `4 × 4` source samples per pixel each.
//! Units of work (groups and single tiles) are rendered in parallel and every tile is written
//! atomically; the output does not depend on the thread count. A rerun with the same run key
//! keeps tiles already on disk.

use std::borrow::Cow;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use crate::albedo::AlbedoSource;
use crate::body::Body;
use crate::cube::{self, Projection};
use crate::dem::{floor_fast, mask, Dem, Resampling};
use crate::error::{Error, Result};
use crate::format::albedo::{write_albedo_tile, AlbedoTile};
use crate::format::height::{self, HeightTile};
use crate::layout::{Layout, TileId, MAX_LEVELS};
use crate::manifest::{self, Tileset};
use crate::progress::Progress;
use crate::runner::{self, StageSpec, Start};

mod mosaic;
use crate::tileset::writer::Writer;
use crate::tileset::{Product, STATE_DIR};

/// The tiling stage writes the height (and albedo) tiles every later product derives from.
pub const STAGE: StageSpec = StageSpec {
    name: "tile",
    writes: Cow::Borrowed(&[Product::Height, Product::Albedo]),
    reads: Cow::Borrowed(&[]),
    format: Cow::Borrowed(&[]),
};

/// Refuse to tile into a folder that holds something other than a tileset: a commit replaces
/// the product folders (`height/`, …) of its output, which must never be a user's own.
fn refuse_foreign_folder(out: &Path) -> Result<()> {
    if out.exists() && !out.is_dir() {
        return Err(Error::usage(format!(
            "{} exists and is not a folder: give a new or tileset folder as the output",
            out.display()
        )));
    }
    let Ok(rd) = std::fs::read_dir(out) else {
        return Ok(());
    };
    let mut names: Vec<String> = rd
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    if names.is_empty()
        || names
            .iter()
            .any(|n| n == manifest::MANIFEST || n == STATE_DIR)
    {
        return Ok(());
    }
    names.sort();
    names.truncate(3);
    Err(Error::usage(format!(
        "{} is not empty and holds no tileset ({}…): penumbra writes only into a new folder, an \
         empty one or a tileset it made; choose another output folder",
        out.display(),
        names.join(", ")
    )))
}

/// What the user chose.
#[derive(Clone, Debug, Serialize)]
pub struct TileOptions {
    pub tile_size: u32,
    pub halo: u32,
    pub projection: Projection,
    /// Number of levels; `None` derives it from the source resolution.
    pub levels: Option<u8>,
    pub resampling: Resampling,
    /// How levels coarser than the finest are filtered.
    pub prefilter: Prefilter,
    pub compression: crate::format::TileCompression,
    pub max_fill_px: u32,
    /// Equirectangular albedo image and the longitude of its left edge.
    pub albedo: Option<(PathBuf, f64)>,
    /// Refuse a run whose tiles would exceed this many GiB before compression (not part of
    /// the run's identity: it changes no byte of the output).
    #[serde(skip)]
    pub max_output_gib: f64,
    /// Heights (m above the body's sphere, `(min, max)`) the caller says the terrain really
    /// reaches, instead of the body's known relief with its margin
    /// ([`crate::body::Body::relief_accepted_m`]): the plausibility check then refuses only
    /// heights outside this range. Not part of the run's identity: it changes no byte.
    #[serde(skip)]
    pub allow_relief_m: Option<(f64, f64)>,
    /// With a wanted set: keep only its tiles, removing those earlier bakes into the same
    /// tileset added (another scene's). False: a bake adds its tiles to what is there. Not
    /// part of the run's identity (a tile's bytes do not depend on which others are cut).
    #[serde(skip)]
    pub prune: bool,
}

impl Default for TileOptions {
    fn default() -> Self {
        TileOptions {
            tile_size: 512,
            halo: 2,
            projection: Projection::Gnomonic,
            levels: None,
            resampling: Resampling::Bilinear,
            prefilter: Prefilter::Box,
            compression: crate::format::TileCompression::Zip,
            max_fill_px: crate::dem::DEFAULT_MAX_FILL_PX,
            albedo: None,
            max_output_gib: runner::DEFAULT_MAX_OUTPUT_GIB,
            allow_relief_m: None,
            prune: false,
        }
    }
}

impl TileOptions {
    pub fn validate(&self) -> Result<()> {
        runner::check_output_cap("max_output_gib", self.max_output_gib)?;
        if !(8..=8192).contains(&self.tile_size) || self.tile_size % 2 != 0 {
            return Err(Error::param(
                "tile_size",
                format!(
                    "{} is not usable: give an even size from 8 to 8192 (default 512)",
                    self.tile_size
                ),
            ));
        }
        if self.halo < 1 || self.halo >= self.tile_size / 2 {
            return Err(Error::param(
                "halo",
                format!(
                    "{} is not usable: give 1 .. {} pixels (default 2)",
                    self.halo,
                    self.tile_size / 2 - 1
                ),
            ));
        }
        if let Some((lo, hi)) = self.allow_relief_m {
            if !(lo.is_finite() && hi.is_finite() && lo < hi && lo >= -1e9 && hi <= 1e9) {
                return Err(Error::param(
                    "allow_relief",
                    format!(
                        "{lo},{hi} is not a relief: give MIN,MAX in metres above the body's \
                         sphere, finite, MIN < MAX, within ± the body's radius"
                    ),
                ));
            }
        }
        if let Some(l) = self.levels {
            if l == 0 || l > MAX_LEVELS {
                return Err(Error::param(
                    "levels",
                    format!("{l} is not usable: give 1 .. {MAX_LEVELS}"),
                ));
            }
        }
        Ok(())
    }
}

/// Anti-aliasing of the coarser levels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Prefilter {
    /// Each pixel is the mean of a k×k grid of interpolated source samples spread over its
    /// footprint, k = 2^(finest level − level) capped at [`MAX_BOX`]: a box filter that keeps
    /// coarse levels from aliasing (a 90 m peak no longer decides a 25 km pixel).
    #[default]
    Box,
    /// One interpolated sample at the pixel centre on every level.
    Point,
}

/// Largest box-filter grid per axis (16 samples per pixel).
pub const MAX_BOX: u32 = 4;

impl std::str::FromStr for Prefilter {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "box" => Ok(Prefilter::Box),
            "point" => Ok(Prefilter::Point),
            _ => Err(format!("unknown prefilter '{s}': use box or point")),
        }
    }
}

/// What a run did.
#[derive(Clone, Debug, Serialize)]
pub struct TileReport {
    pub out: PathBuf,
    pub levels: u8,
    pub tiles_written: u64,
    pub tiles_kept: u64,
    pub candidates: u64,
    /// Samples in the source raster.
    pub source_pixels: u64,
    /// Pixels written (halos included).
    pub output_pixels: u64,
    pub up_to_date: bool,
}

/// Identity of a source that is not a file (the embedded scene): a label and a content hash.
#[derive(Clone, Debug, Serialize)]
pub struct Embedded {
    pub label: String,
    pub blake3: String,
}

/// Default feather (source pixels) of a mosaic source ([`MosaicSource::feather_px`]); with one
/// source it changes nothing.
pub const DEFAULT_FEATHER_PX: f64 = 4.0;

/// One source of a mosaic ([`tile_sources`]).
#[derive(Clone, Copy)]
pub struct MosaicSource<'a> {
    pub dem: &'a Dem,
    /// Width, in this source's pixels, of the zone inward from the edge of its data (its
    /// raster's border and the voids it leaves unfilled) over which it is blended into the
    /// sources below it (0: a hard seam). Ignored for the lowest source and for one source.
    pub feather_px: f64,
}

/// Tile `dem` for `body` into `out`: [`tile_sources`] with one source and every tile.
pub fn tile_dem(
    dem: &Dem,
    body: &Body,
    out: &Path,
    opts: &TileOptions,
    embedded: Option<&Embedded>,
    progress: &dyn Progress,
) -> Result<TileReport> {
    let one = [MosaicSource {
        dem,
        feather_px: DEFAULT_FEATHER_PX,
    }];
    tile_sources(&one, body, out, opts, embedded, None, progress)
}

/// Whether two sources name different bodies (`TARGET_NAME`) or datums more than 2 % apart
/// (the closest bodies with presets, the Moon and Io, are 4.8 % apart; datums of one body
/// differ by far less).
fn other_body(a: &Dem, b: &Dem) -> Option<String> {
    let name = |t: &str| {
        crate::body::Body::preset(t)
            .map(|p| p.name.to_lowercase())
            .unwrap_or_else(|_| t.trim().to_lowercase())
    };
    if let (Some(x), Some(y)) = (a.target(), b.target()) {
        if name(x) != name(y) {
            return Some(format!("target {x} against {y}"));
        }
    }
    if let (Some(x), Some(y)) = (a.datum_radius_m(), b.datum_radius_m()) {
        let off = (x - y).abs() / x.max(y);
        if off.is_nan() || off > 0.02 {
            return Some(format!(
                "datum radius {} m against {} m ({:.1} % apart)",
                crate::dem::limits::show(x),
                crate::dem::limits::show(y),
                100.0 * off
            ));
        }
    }
    None
}

/// A source's name for messages: its first file, or its format for one built in memory.
fn source_name(dem: &Dem) -> String {
    match dem.sources().first() {
        Some(p) => p.display().to_string(),
        None => format!("the {} terrain", dem.format()),
    }
}

/// What a source is, for the manifest.
fn source_info(dem: &Dem, files: Vec<manifest::SourceFile>, radius: f64) -> manifest::SourceInfo {
    let (voids, voids_unfilled) = dem.void_counts();
    manifest::SourceInfo {
        files,
        format: dem.format().to_string(),
        width: dem.width(),
        height: dem.height(),
        georef: dem.georef().clone(),
        pixel_size_m: dem.pixel_size_m(radius),
        datum_radius_m: dem.datum_radius_m(),
        height_shift_m: dem.datum_radius_m().map_or(0.0, |r0| r0 - radius),
        voids,
        voids_unfilled,
    }
}

/// Check a wanted tile set against the layout: every tile on it, and its parent in the set.
fn check_wanted(wanted: &BTreeSet<TileId>, layout: &Layout) -> Result<()> {
    for t in wanted {
        if t.level >= layout.levels
            || t.x >= layout.tiles_per_side(t.level)
            || t.y >= layout.tiles_per_side(t.level)
        {
            return Err(Error::param(
                "wanted",
                format!(
                    "tile {t} is not on this tileset's grid ({} levels; level L has 2^L tiles \
                     per face side): ask for tiles of the layout the tiling uses",
                    layout.levels
                ),
            ));
        }
        if let Some(p) = t.parent() {
            if !wanted.contains(&p) {
                return Err(Error::param(
                    "wanted",
                    format!(
                        "holds tile {t} but not its parent {p}: a wanted set must hold the \
                         parent of each of its tiles (the coarser levels are made from the same \
                         ground)"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Tile several `sources` for `body` into `out`, mosaicked per sample: `sources` in priority
/// order, highest first; at each sample the highest source with data wins, blended into the
/// sources below it over its [`MosaicSource::feather_px`] (see `tiling::mosaic`). Levels (when
/// `opts.levels` is `None`) follow the finest source. With `wanted`, only the tiles of that set
/// (closed under parent) are cut and listed in the coverage. One source and no `wanted` give
/// the bytes, manifest and run key of a single-DEM run. `embedded` names the primary source
/// when it is not a file.
pub fn tile_sources(
    sources: &[MosaicSource],
    body: &Body,
    out: &Path,
    opts: &TileOptions,
    embedded: Option<&Embedded>,
    wanted: Option<&BTreeSet<TileId>>,
    progress: &dyn Progress,
) -> Result<TileReport> {
    opts.validate()?;
    let Some(primary) = sources.first() else {
        return Err(Error::usage(
            "no elevation source to tile: give at least one DEM",
        ));
    };
    let dem = primary.dem;
    if sources.len() > manifest::MAX_MOSAIC_SOURCES {
        return Err(Error::param(
            "sources",
            format!(
                "{} sources: a mosaic takes at most {}",
                sources.len(),
                manifest::MAX_MOSAIC_SOURCES
            ),
        ));
    }
    for s in sources {
        if !(s.feather_px.is_finite() && (0.0..=manifest::MAX_FEATHER_PX).contains(&s.feather_px)) {
            return Err(Error::param(
                "feather_px",
                format!(
                    "{} for {} is not usable: give 0 ..= {} source pixels (default {})",
                    s.feather_px,
                    source_name(s.dem),
                    manifest::MAX_FEATHER_PX,
                    DEFAULT_FEATHER_PX
                ),
            ));
        }
    }
    // Every source of one body, before anything else is read or written.
    for (k, a) in sources.iter().enumerate() {
        for b in &sources[k + 1..] {
            if let Some(why) = other_body(a.dem, b.dem) {
                return Err(Error::usage(format!(
                    "{} and {} are not of the same body ({why}): a mosaic's sources must all \
                     describe one body; drop the one that does not belong",
                    source_name(a.dem),
                    source_name(b.dem)
                )));
            }
        }
    }
    let albedo = match &opts.albedo {
        Some((p, west)) => Some(AlbedoSource::open(p, *west)?),
        None => None,
    };
    let radius = body.radius_m;
    let source_px_m = dem.pixel_size_m(radius);
    let finest_px_m = sources
        .iter()
        .map(|s| s.dem.pixel_size_m(radius))
        .fold(source_px_m, f64::min);
    let levels = opts.levels.unwrap_or_else(|| {
        Layout::levels_for(opts.projection, opts.tile_size, radius, finest_px_m)
    });
    let layout = Layout {
        projection: opts.projection,
        tile_size: opts.tile_size,
        halo: opts.halo,
        levels,
    };
    if let Some(w) = wanted {
        check_wanted(w, &layout)?;
    }
    let height_shift = dem.datum_radius_m().map_or(0.0, |r0| r0 - radius);
    // Implausible input (heights, relief, pixel size, datum for this body) is refused before
    // `out` is touched.
    for s in sources {
        s.dem.check_for_body(body, opts.allow_relief_m)?;
    }
    let layers: Vec<mosaic::Layer> = sources
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let shift = s.dem.datum_radius_m().map_or(0.0, |r0| r0 - radius) - height_shift;
            let shift = if k == 0 { 0.0 } else { shift };
            mosaic::Layer::new(s.dem, s.feather_px, shift, k + 1 == sources.len())
        })
        .collect();

    // Identity of this run.
    let mut files = Vec::new();
    for p in dem.sources() {
        files.push(manifest::hash_file(p)?);
    }
    if let Some(e) = embedded {
        files.push(manifest::SourceFile {
            path: format!("embedded:{}", e.label),
            bytes: 0,
            blake3: e.blake3.clone(),
        });
    }
    let mut infos = vec![source_info(dem, files.clone(), radius)];
    for s in &sources[1..] {
        let mut fs = Vec::new();
        for p in s.dem.sources() {
            fs.push(manifest::hash_file(p)?);
        }
        infos.push(source_info(s.dem, fs, radius));
    }
    let mosaic_entries: Vec<manifest::MosaicSource> = if sources.len() > 1 {
        infos
            .iter()
            .zip(sources)
            .map(|(i, s)| manifest::MosaicSource {
                source: i.clone(),
                feather_px: s.feather_px,
            })
            .collect()
    } else {
        Vec::new()
    };
    let albedo_file = match &albedo {
        Some(a) => Some(manifest::hash_file(&a.path)?),
        None => None,
    };
    let mut parameters = serde_json::json!({
        "body": body,
        "options": opts,
        "levels": levels,
    });
    // Only a mosaic adds keys: one source keeps today's parameters (and run key). serde_json's
    // maps are sorted, so the keys' order does not depend on this. A wanted set is not part of
    // the key: a tile's bytes do not depend on which other tiles are cut (tiles cut in a group
    // equal tiles cut alone, bit for bit), so tiles of one run stay valid in the next whatever
    // it selects; the coverage says which there are.
    if !mosaic_entries.is_empty() {
        parameters["mosaic"] = manifest::consistency::mosaic_parameters(&mosaic_entries);
    }
    let run_key = runner::run_key(
        &STAGE,
        &[],
        &[
            serde_json::to_string(&files).unwrap_or_default().as_bytes(),
            serde_json::to_string(&albedo_file)
                .unwrap_or_default()
                .as_bytes(),
            parameters.to_string().as_bytes(),
        ],
    );
    refuse_foreign_folder(out)?;

    // Candidate tiles: with a wanted set, its tiles (those without data are not written: a
    // source's footprint points are too sparse where its pixels are larger than the tiles);
    // otherwise every finest-level tile a footprint point of a source falls in, and their
    // ancestors.
    let finest = levels - 1;
    let mut candidates = BTreeSet::new();
    for s in sources.iter().filter(|_| wanted.is_none()) {
        candidates.extend(footprint_tiles(s.dem, &layout, finest, radius));
    }
    // With a wanted set, the tiles an earlier run of this key made stay (and are kept, not
    // cut again) unless pruned; tiles it found without data are not tried again.
    let previous = Tileset::load(out).ok().filter(|e| e.run_key == run_key);
    let (old_present, old_empty) = previous
        .as_ref()
        .map(|e| (e.tile_set(), e.no_data_set()))
        .unwrap_or_default();
    let mut units_current = true;
    if let Some(w) = wanted {
        candidates = w.difference(&old_empty).copied().collect();
        if !opts.prune {
            candidates.extend(old_present.iter().copied());
        }
        units_current = previous.is_none()
            || (candidates.is_subset(&old_present)
                && (!opts.prune || old_present.is_subset(&candidates)));
    }
    let source_pixels: u64 = sources
        .iter()
        .map(|s| (s.dem.width() * s.dem.height()) as u64)
        .sum();
    let candidates: Vec<TileId> = candidates.into_iter().collect();
    let side = layout.stored_size() as f64;
    let per_tile =
        side * side * (4.0 + 2.0 + albedo.as_ref().map_or(0.0, |a| a.channels as f64 * 2.0));
    let gib = candidates.len() as f64 * per_tile / (1u64 << 30) as f64;
    if gib > opts.max_output_gib {
        return Err(Error::param(
            "max_output_gib",
            format!(
                "is {}, but {} levels of {}-px tiles over this DEM would write up to {gib:.3} GiB \
                 before compression ({} tiles): use fewer levels or raise the cap",
                opts.max_output_gib,
                levels,
                opts.tile_size,
                candidates.len()
            ),
        ));
    }

    // Only now, with the input read and the plan known, touch the output folder.
    let writer = Writer::begin(out)?;
    let existing = Tileset::load(out).ok();
    let run = match runner::start_units(writer, STAGE, &run_key, existing.as_ref(), units_current)?
    {
        Start::UpToDate => {
            let n = existing.map_or(0, |e| e.coverage.iter().map(|c| c.tiles).sum());
            return Ok(TileReport {
                out: out.to_path_buf(),
                levels,
                tiles_written: 0,
                tiles_kept: n,
                candidates: n,
                source_pixels,
                output_pixels: 0,
                up_to_date: true,
            });
        }
        Start::Run(run) => run,
    };
    let (stage_out, mut resume) = (run.out().to_path_buf(), run.resume());
    if wanted.is_some() && previous.is_some() {
        // The committed tiles this run keeps, linked into its staging folder (the sink then
        // keeps them as it keeps a resumed run's).
        let store = crate::tileset::Store::open_unlocked(out)?;
        for p in [
            crate::tileset::Product::Height,
            crate::tileset::Product::Albedo,
        ] {
            let Some(ix) = store.index(p)? else { continue };
            let pattern = match p {
                crate::tileset::Product::Height => manifest::HEIGHT_PATTERN,
                _ => manifest::ALBEDO_PATTERN,
            };
            for id in candidates.iter().filter(|t| old_present.contains(t)) {
                let path = crate::tileset::tile_path(out, pattern, *id);
                let rel = crate::tileset::tile_path(Path::new(""), pattern, *id);
                let rel = rel.to_string_lossy().replace('\\', "/");
                if let Some((_, h)) = ix.files.get(&rel) {
                    run.staging_link(&path, &rel, &blake3::Hash::from(*h))?;
                }
            }
        }
        resume = true;
    }

    progress.start("tiling", candidates.len() as u64);
    let sink = TileSink {
        layout: &layout,
        opts,
        albedo: albedo.as_ref(),
        out: &stage_out,
        resume,
        run_key: &run_key,
    };
    let units = plan_units(&candidates, finest, group_depth(&layout, opts.prefilter));
    let mut results: std::collections::BTreeMap<TileId, Result<Option<TileStats>>> = units
        .par_iter()
        .flat_map_iter(|u| run_unit(&layers, &sink, u, height_shift, progress))
        .collect();
    progress.finish();

    let mut present = BTreeSet::new();
    let (mut min, mut max) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut filled, mut no_data, mut written, mut kept) = (0u64, 0u64, 0u64, 0u64);
    for id in &candidates {
        let r = results
            .remove(id)
            .expect("every candidate belongs to exactly one unit");
        if let Some(s) = r? {
            present.insert(*id);
            min = min.min(s.min as f64);
            max = max.max(s.max as f64);
            filled += s.filled;
            no_data += s.no_data;
            if s.kept {
                kept += 1;
            } else {
                written += 1;
            }
        }
    }
    if present.is_empty() {
        let msg = match (wanted, sources.len()) {
            (Some(_), _) => {
                "covers none of the wanted tiles: no pixel of those tiles falls on \
                             the sources' data; ask for tiles over the data (docs/formats.md)"
            }
            (None, 1) => {
                "covers no tile: no tile pixel falls on its data; check its \
                          georeferencing (docs/formats.md) or use more levels"
            }
            (None, _) => {
                "and the other sources cover no tile: no tile pixel falls on their \
                          data; check their georeferencing (docs/formats.md) or use more levels"
            }
        };
        return Err(match dem.sources().first() {
            Some(source) => Error::invalid(source, msg),
            None => Error::usage(format!("the terrain {msg}")),
        });
    }
    let tileset = Tileset {
        format: manifest::FORMAT.into(),
        format_version: manifest::FORMAT_VERSION,
        tool: manifest::Tool::this(),
        body: body.clone(),
        layout,
        resampling: opts.resampling,
        source: infos.swap_remove(0),
        mosaic: mosaic_entries,
        products: manifest::Products {
            height: Some(manifest::HeightProduct {
                path: manifest::HEIGHT_PATTERN.into(),
                channels: vec!["height".into(), "mask".into()],
                min_m: min,
                max_m: max,
                filled_pixels: filled,
                no_data_pixels: no_data,
            }),
            albedo: albedo
                .as_ref()
                .zip(albedo_file)
                .map(|(a, f)| manifest::AlbedoProduct {
                    path: manifest::ALBEDO_PATTERN.into(),
                    source: f,
                    bit_depth: if a.sixteen_bit { 16 } else { 8 },
                    channels: a.channels as u8,
                    west_lon_deg: a.west_lon_deg,
                }),
            // Products made from an earlier run of this key stay (their stages redo only the
            // tiles whose inputs this run changed); a new key drops them at the commit.
            mip: previous.as_ref().and_then(|p| p.products.mip.clone()),
            horizon: previous.as_ref().and_then(|p| p.products.horizon.clone()),
            fourier: previous.as_ref().and_then(|p| p.products.fourier.clone()),
            extra: previous
                .as_ref()
                .map(|p| p.products.extra.clone())
                .unwrap_or_default(),
        },
        coverage: manifest::coverage_of(&present, levels),
        no_data: match wanted {
            Some(w) => {
                let mut empty: BTreeSet<TileId> = candidates
                    .iter()
                    .filter(|t| !present.contains(t))
                    .copied()
                    .collect();
                empty.extend(old_empty.iter().filter(|t| !opts.prune || w.contains(t)));
                manifest::coverage_of(&empty, levels)
                    .into_iter()
                    .filter(|c| c.tiles > 0)
                    .collect()
            }
            None => Vec::new(),
        },
        parameters,
        run_key,
    };
    run.commit(tileset)?;
    let side = layout.stored_size() as u64;
    Ok(TileReport {
        out: out.to_path_buf(),
        levels,
        tiles_written: written,
        tiles_kept: kept,
        candidates: candidates.len() as u64,
        source_pixels,
        output_pixels: written * side * side,
        up_to_date: false,
    })
}

struct TileStats {
    min: f32,
    max: f32,
    filled: u64,
    no_data: u64,
    kept: bool,
}

fn interior_stats(layout: &Layout, t: &HeightTile, kept: bool) -> Option<TileStats> {
    let (h, n) = (layout.halo as usize, layout.tile_size as usize);
    // Eight lanes of minima, maxima and counts, so that the loop runs in vector registers
    // rather than through one minimum's and one maximum's latency per sample (10 % of the
    // tiling stage's CPU time on LDEM_4 at 4 levels). No-data samples enter as ±∞.
    const L: usize = 8;
    let (mut lo, mut hi) = ([f32::INFINITY; L], [f32::NEG_INFINITY; L]);
    let (mut filled, mut no_data) = (0u64, 0u64);
    for j in h..h + n {
        let row = j * t.size + h;
        let (hs, ms) = (&t.height[row..row + n], &t.mask[row..row + n]);
        let (mut f, mut z) = ([0u32; L], [0u32; L]);
        let (hc, mc) = (hs.chunks_exact(L), ms.chunks_exact(L));
        let (hr, mr) = (hc.remainder(), mc.remainder());
        for (hv, mv) in hc.zip(mc) {
            for q in 0..L {
                let valid = mv[q] != mask::NO_DATA;
                z[q] += u32::from(!valid);
                f[q] += u32::from(mv[q] == mask::FILLED);
                lo[q] = lo[q].min(if valid { hv[q] } else { f32::INFINITY });
                hi[q] = hi[q].max(if valid { hv[q] } else { f32::NEG_INFINITY });
            }
        }
        for (&v, &m) in hr.iter().zip(mr) {
            if m == mask::NO_DATA {
                z[0] += 1;
            } else {
                f[0] += u32::from(m == mask::FILLED);
                lo[0] = lo[0].min(v);
                hi[0] = hi[0].max(v);
            }
        }
        filled += f.iter().map(|&c| u64::from(c)).sum::<u64>();
        no_data += z.iter().map(|&c| u64::from(c)).sum::<u64>();
    }
    let mut s = TileStats {
        min: lo.iter().fold(f32::INFINITY, |a, &b| a.min(b)),
        max: hi.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b)),
        filled,
        no_data,
        kept,
    };
    if s.min == 0.0 || s.max == 0.0 {
        // Which zero (+0 or −0) a minimum keeps depends on the order the samples were met in:
        // take them in raster order, as before, so that the manifest's bytes do not change.
        (s.min, s.max) = (f32::INFINITY, f32::NEG_INFINITY);
        for j in h..h + n {
            for i in h..h + n {
                let k = j * t.size + i;
                if t.mask[k] != mask::NO_DATA {
                    s.min = s.min.min(t.height[k]);
                    s.max = s.max.max(t.height[k]);
                }
            }
        }
    }
    (s.no_data < (n * n) as u64).then_some(s)
}

/// Samples per axis of the box prefilter for a tile at `level`.
pub fn box_samples(layout: &Layout, level: u8, prefilter: Prefilter) -> u32 {
    match prefilter {
        Prefilter::Point => 1,
        Prefilter::Box => {
            let below = (layout.levels - 1).saturating_sub(level).min(8) as u32;
            (1u32 << below).min(MAX_BOX)
        }
    }
}

/// Spacing in pixels of the lattice on which source coordinates are computed exactly.
const LATTICE: i64 = 8;
/// How far (source pixels) beyond one edge of the raster all four corners of an interpolable
/// lattice cell must lie for the cell to be called off the source ([`Dem::beyond_one_edge`]).
const OFF_EDGE_MARGIN_PX: f64 = 1.0;
const EXACT: u8 = 0;
const INTERP: u8 = 1;
const OUTSIDE: u8 = 2;
const SPLIT: u8 = 3;
/// Largest error (source pixels) allowed where source coordinates are interpolated.
pub const APPROX_TOL_PX: f64 = 1e-3;

/// Source pixel coordinates of face positions around one tile: exact on a lattice every
/// [`LATTICE`] global face pixels, bilinear in between where that is within [`APPROX_TOL_PX`]
/// (checked at each cell's centre and edge midpoints), exact elsewhere — cells that touch the edge of the source,
/// straddle the antimeridian of a global raster or a pole. GDAL's approximate transformer does
/// the same with a 0.125 px tolerance. The lattice is aligned to the global face grid, so the
/// coordinates of a point are the same whichever tile computes them.
struct SourceGrid<'a> {
    dem: &'a Dem,
    layout: &'a Layout,
    face: crate::cube::Face,
    level: u8,
    m0: (i64, i64),
    cells: (usize, usize),
    /// Exact coordinates at lattice points, row-major, `(cells.0 + 1) × (cells.1 + 1)`.
    pts: Vec<(f64, f64)>,
    /// Per cell: [`EXACT`], [`INTERP`], [`SPLIT`] or [`OUTSIDE`] (wholly off the source).
    ok: Vec<u8>,
    /// Per [`SPLIT`] cell, the index of its halves in `split`.
    split_at: Vec<u32>,
    split: Vec<Split>,
}

/// Bilinear interpolation of source coordinates between cell corners `a` (top left), `b` (top
/// right), `c` (bottom left), `d` (bottom right) at fractions (wx, wy) of the cell.
#[inline]
fn bilerp([a, b, c, d]: [(f64, f64); 4], wx: f64, wy: f64) -> (f64, f64) {
    let lerp = |p: f64, q: f64, r: f64, s: f64| {
        (p * (1.0 - wx) + q * wx) * (1.0 - wy) + (r * (1.0 - wx) + s * wx) * wy
    };
    (lerp(a.0, b.0, c.0, d.0), lerp(a.1, b.1, c.1, d.1))
}

/// Whether bilinear interpolation between `corners` (as in [`bilerp`]) is within
/// [`APPROX_TOL_PX`] of `exact(wx, wy)` at the cell's centre and its four edge midpoints (the
/// centre alone misses maps whose second derivatives cancel there, f_xx ≈ −f_yy).
fn interpolates(
    [a, b, c, d]: [(f64, f64); 4],
    mut exact: impl FnMut(f64, f64) -> (f64, f64),
) -> bool {
    let lerp = |p: f64, q: f64, w: f64| p + (q - p) * w;
    [(0.5, 0.5), (0.5, 0.0), (0.5, 1.0), (0.0, 0.5), (1.0, 0.5)]
        .iter()
        .all(|&(wx, wy)| {
            let e = exact(wx, wy);
            let col = lerp(lerp(a.0, b.0, wx), lerp(c.0, d.0, wx), wy);
            let row = lerp(lerp(a.1, b.1, wx), lerp(c.1, d.1, wx), wy);
            (e.0 - col).abs() <= APPROX_TOL_PX && (e.1 - row).abs() <= APPROX_TOL_PX
        })
}

/// A lattice cell too curved to interpolate whole, cut into 2 × 2 sub-cells (half the
/// spacing, a quarter of the interpolation error): exact coordinates at the 3 × 3 sub-lattice
/// points, and per sub-cell whether it interpolates within the tolerance (else it is exact).
struct Split {
    pts: [(f64, f64); 9],
    ok: [bool; 4],
}

impl Split {
    /// The corners of sub-cell (sx, sy), in [`bilerp`]'s order.
    fn corners(&self, sx: usize, sy: usize) -> [(f64, f64); 4] {
        let q = |i: usize, j: usize| self.pts[(sy + j) * 3 + sx + i];
        [q(0, 0), q(1, 0), q(0, 1), q(1, 1)]
    }
}

impl<'a> SourceGrid<'a> {
    fn exact(&self, gx: f64, gy: f64) -> (f64, f64) {
        let (s, t) = self.layout.global_st(self.level, gx, gy);
        self.dem
            .dir_to_pixel(self.layout.st_to_dir(self.face, s, t))
    }

    /// The grid around one tile (halo and one pixel more included).
    fn new(dem: &'a Dem, layout: &'a Layout, id: TileId) -> SourceGrid<'a> {
        let h = layout.halo as i64 + 1;
        let (g0x, g0y) = layout.global_pixel(id, -h, -h);
        let n = layout.tile_size as i64 + 2 * h;
        Self::region(dem, layout, id.face, id.level, (g0x, g0y), (n, n))
    }

    /// The grid over global face pixels `g0 .. g0 + n` (and up to a lattice cell more) of
    /// `face` at `level`. A point's coordinates do not depend on the region asked for.
    fn region(
        dem: &'a Dem,
        layout: &'a Layout,
        face: crate::cube::Face,
        level: u8,
        (g0x, g0y): (i64, i64),
        (nx, ny): (i64, i64),
    ) -> SourceGrid<'a> {
        let m0 = (g0x.div_euclid(LATTICE), g0y.div_euclid(LATTICE));
        let m1 = (
            (g0x + nx).div_euclid(LATTICE) + 1,
            (g0y + ny).div_euclid(LATTICE) + 1,
        );
        let cells = ((m1.0 - m0.0) as usize, (m1.1 - m0.1) as usize);
        let mut grid = SourceGrid {
            dem,
            layout,
            face,
            level,
            m0,
            cells,
            pts: Vec::new(),
            ok: Vec::with_capacity(cells.0 * cells.1),
            split_at: Vec::new(),
            split: Vec::new(),
        };
        // Cells wholly off the source (for sources with a bounding cap): the cell's own cap does
        // not meet the source's. Tested per block of cells first, then per cell in the blocks
        // that may touch the source; a cell called off the source only saves work, since its
        // pixels would sample no data anyway.
        let mut outside = vec![false; cells.0 * cells.1];
        if let Some((cc, cr)) = dem.footprint_cap() {
            let off = |mx: usize, my: usize, nx: usize, ny: usize| -> bool {
                let corner = |dx: usize, dy: usize| {
                    let (s, t) = layout.global_st(
                        level,
                        ((m0.0 + (mx + dx) as i64) * LATTICE) as f64,
                        ((m0.1 + (my + dy) as i64) * LATTICE) as f64,
                    );
                    layout.st_to_dir(face, s, t)
                };
                let ds = [corner(0, 0), corner(nx, 0), corner(0, ny), corner(nx, ny)];
                let mut mid = [0.0; 3];
                for d in &ds {
                    for k in 0..3 {
                        mid[k] += d[k];
                    }
                }
                let n = (mid[0] * mid[0] + mid[1] * mid[1] + mid[2] * mid[2]).sqrt();
                let mid = [mid[0] / n, mid[1] / n, mid[2] / n];
                // Cell edges are great circles for gnomonic, nearly so for equal-angle:
                // 1% margin on the corner radius.
                let r = ds
                    .iter()
                    .map(|d| crate::cube::angle_between(mid, *d))
                    .fold(0.0f64, f64::max)
                    * 1.01;
                crate::cube::angle_between(mid, cc) > r + cr
            };
            const BLOCK: usize = 8;
            for by in (0..cells.1).step_by(BLOCK) {
                for bx in (0..cells.0).step_by(BLOCK) {
                    let (ex, ey) = ((bx + BLOCK).min(cells.0), (by + BLOCK).min(cells.1));
                    let whole = off(bx, by, ex - bx, ey - by);
                    for my in by..ey {
                        for mx in bx..ex {
                            outside[my * cells.0 + mx] = whole || off(mx, my, 1, 1);
                        }
                    }
                }
            }
        }
        // Exact coordinates at the lattice points of cells that may touch the source.
        let w = cells.0 + 1;
        grid.pts = vec![(f64::NAN, f64::NAN); w * (cells.1 + 1)];
        for my in 0..cells.1 {
            for mx in 0..cells.0 {
                if outside[my * cells.0 + mx] {
                    continue;
                }
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let k = (my + dy) * w + mx + dx;
                    if grid.pts[k].0.is_nan() && grid.pts[k].1.is_nan() {
                        grid.pts[k] = grid.exact(
                            ((m0.0 + (mx + dx) as i64) * LATTICE) as f64,
                            ((m0.1 + (my + dy) as i64) * LATTICE) as f64,
                        );
                    }
                }
            }
        }
        let half_width = dem.width() as f64 / 4.0;
        // Exact coordinates at the midpoints of horizontal and vertical lattice edges.
        let mut h_mid: Vec<Option<(f64, f64)>> = vec![None; cells.0 * (cells.1 + 1)];
        let mut v_mid: Vec<Option<(f64, f64)>> = vec![None; (cells.0 + 1) * cells.1];
        for my in 0..cells.1 {
            for mx in 0..cells.0 {
                if outside[my * cells.0 + mx] {
                    grid.ok.push(OUTSIDE);
                    continue;
                }
                let c = grid.corners(mx, my);
                let finite = c.iter().all(|p| p.0.is_finite() && p.1.is_finite());
                let inside = finite && c.iter().all(|p| dem.covers(p.0, p.1));
                let cols = c.iter().map(|p| p.0);
                let spread = cols.clone().fold(f64::NEG_INFINITY, f64::max)
                    - cols.fold(f64::INFINITY, f64::min);
                // A cell off the raster's rectangle inside its bounding cap (a regional DEM's
                // cap is a circle round a rectangle: ≈ 57 % more area): beyond one edge with
                // all four corners, by a margin far above the interpolation tolerance, it is
                // wholly off once it is shown to interpolate.
                let beyond = !inside && finite && dem.beyond_one_edge(&c, OFF_EDGE_MARGIN_PX);
                if !((inside || beyond) && spread < half_width) {
                    grid.ok.push(EXACT);
                    continue;
                }
                let (bx, by) = (
                    ((m0.0 + mx as i64) * LATTICE) as f64,
                    ((m0.1 + my as i64) * LATTICE) as f64,
                );
                let l = LATTICE as f64;
                // Exact coordinates at (wx, wy) of the cell; edge midpoints are shared with the
                // neighbouring cell and computed once.
                let mut mid = |wx: f64, wy: f64| -> (f64, f64) {
                    let memo = match (wx, wy) {
                        (0.5, 0.0) | (0.5, 1.0) => {
                            Some(&mut h_mid[(my + wy as usize) * cells.0 + mx])
                        }
                        (0.0, 0.5) | (1.0, 0.5) => {
                            Some(&mut v_mid[my * (cells.0 + 1) + mx + wx as usize])
                        }
                        _ => None,
                    };
                    let at = (bx + wx * l, by + wy * l);
                    match memo {
                        None => grid.exact(at.0, at.1),
                        Some(m) => *m.get_or_insert_with(|| grid.exact(at.0, at.1)),
                    }
                };
                if interpolates(c, &mut mid) {
                    grid.ok.push(if inside { INTERP } else { OUTSIDE });
                    continue;
                }
                if !inside {
                    grid.ok.push(EXACT);
                    continue;
                }
                // Too curved for one cell: try its four halves, whose corners are the cell's
                // corners, edge midpoints and centre (mostly computed above).
                let pts = [
                    c[0],
                    mid(0.5, 0.0),
                    c[1],
                    mid(0.0, 0.5),
                    mid(0.5, 0.5),
                    mid(1.0, 0.5),
                    c[2],
                    mid(0.5, 1.0),
                    c[3],
                ];
                // Midpoints of the inner edges: on the cell's horizontal centre line (left and
                // right half) and on its vertical centre line (top and bottom half).
                let on_h = [mid(0.25, 0.5), mid(0.75, 0.5)];
                let on_v = [mid(0.5, 0.25), mid(0.5, 0.75)];
                let mut split = Split {
                    pts,
                    ok: [false; 4],
                };
                for k in 0..4 {
                    let (sx, sy) = (k % 2, k / 2);
                    let (ox, oy) = (sx as f64 / 2.0, sy as f64 / 2.0);
                    split.ok[k] = interpolates(split.corners(sx, sy), |wx, wy| match (wx, wy) {
                        // The edges shared by two halves, computed once.
                        (0.5, 1.0) if sy == 0 => on_h[sx],
                        (0.5, 0.0) if sy == 1 => on_h[sx],
                        (1.0, 0.5) if sx == 0 => on_v[sy],
                        (0.0, 0.5) if sx == 1 => on_v[sy],
                        _ => mid(ox + wx / 2.0, oy + wy / 2.0),
                    });
                }
                if split.ok.iter().any(|&o| o) {
                    if grid.split_at.is_empty() {
                        grid.split_at = vec![u32::MAX; cells.0 * cells.1];
                    }
                    grid.split_at[my * cells.0 + mx] = grid.split.len() as u32;
                    grid.split.push(split);
                    grid.ok.push(SPLIT);
                    continue;
                }
                grid.ok.push(EXACT);
            }
        }
        grid
    }

    /// [`SourceGrid::at`] for the whole pixels `gx0 ..` of row `gy`, the same values, with the
    /// cell looked up once per run of pixels in one lattice cell.
    fn row(&self, gx0: i64, gy: i64, out: &mut [(f64, f64)]) {
        let fy = gy as f64 / LATTICE as f64;
        let cy = floor_fast(fy);
        let my = cy as i64 - self.m0.1;
        let wy = fy - cy;
        let end = gx0 + out.len() as i64;
        let mut gx = gx0;
        while gx < end {
            let cx = gx.div_euclid(LATTICE);
            let run = gx..((cx + 1) * LATTICE).min(end);
            let slots = &mut out[(gx - gx0) as usize..(run.end - gx0) as usize];
            let mx = cx - self.m0.0;
            let inside =
                my >= 0 && (my as usize) < self.cells.1 && mx >= 0 && (mx as usize) < self.cells.0;
            let (my_, mx_) = (my as usize, mx as usize);
            let code = if inside {
                self.ok[my_ * self.cells.0 + mx_]
            } else {
                EXACT
            };
            if code == OUTSIDE {
                slots.fill((f64::NAN, f64::NAN));
            } else if code == INTERP {
                let corners = self.corners(mx_, my_);
                for (x, o) in run.clone().zip(slots.iter_mut()) {
                    // (x − 8·cx)/8 is exactly at()'s fx − floor(fx).
                    let wx = (x - cx * LATTICE) as f64 / LATTICE as f64;
                    *o = bilerp(corners, wx, wy);
                }
            } else {
                for (x, o) in run.clone().zip(slots.iter_mut()) {
                    *o = self.at(x as f64, gy as f64);
                }
            }
            gx = run.end;
        }
    }

    /// Source (col, row) of fractional global face pixel (gx, gy).
    #[inline]
    fn at(&self, gx: f64, gy: f64) -> (f64, f64) {
        let (fx, fy) = (gx / LATTICE as f64, gy / LATTICE as f64);
        let (cx, cy) = (floor_fast(fx), floor_fast(fy));
        let (mx, my) = (cx as i64 - self.m0.0, cy as i64 - self.m0.1);
        if mx < 0 || my < 0 || mx as usize >= self.cells.0 || my as usize >= self.cells.1 {
            return self.exact(gx, gy);
        }
        let (mx, my) = (mx as usize, my as usize);
        match self.ok[my * self.cells.0 + mx] {
            INTERP => {}
            OUTSIDE => return (f64::NAN, f64::NAN),
            SPLIT => {
                let sp = &self.split[self.split_at[my * self.cells.0 + mx] as usize];
                let (wx, wy) = (2.0 * (fx - cx), 2.0 * (fy - cy));
                let (sx, sy) = ((wx >= 1.0) as usize, (wy >= 1.0) as usize);
                if !sp.ok[sy * 2 + sx] {
                    return self.exact(gx, gy);
                }
                return bilerp(sp.corners(sx, sy), wx - sx as f64, wy - sy as f64);
            }
            _ => return self.exact(gx, gy),
        }
        bilerp(self.corners(mx, my), fx - cx, fy - cy)
    }

    /// The exact coordinates at the four corners of cell (mx, my), in [`bilerp`]'s order.
    #[inline]
    fn corners(&self, mx: usize, my: usize) -> [(f64, f64); 4] {
        let w = self.cells.0 + 1;
        [
            self.pts[my * w + mx],
            self.pts[my * w + mx + 1],
            self.pts[(my + 1) * w + mx],
            self.pts[(my + 1) * w + mx + 1],
        ]
    }
}

/// Sample one height tile (halo included) on its own: each pixel is the mean of the
/// [`box_samples`]² interpolated source samples at the centres of the level-`level + log2 k`
/// pixels it covers (one at its own centre for k = 1).
pub fn render_height_tile(
    dem: &Dem,
    layout: &Layout,
    id: TileId,
    resampling: Resampling,
    prefilter: Prefilter,
    height_shift: f64,
) -> HeightTile {
    let one = [mosaic::Layer::new(dem, 0.0, 0.0, true)];
    render_tile(&one, layout, id, resampling, prefilter, height_shift)
}

/// The tiles at `level` that `dem`'s footprint reaches, and their ancestors: its footprint
/// points (every boundary pixel and an interior grid fine enough for the level's tiles)
/// located at `level`. The tiling stage's candidates; a scene's plan finds each source's reach
/// with it.
pub fn footprint_tiles(dem: &Dem, layout: &Layout, level: u8, radius: f64) -> BTreeSet<TileId> {
    let tile_ground_m = 0.4 * layout.tile_size as f64 * layout.centre_pixel_m(level, radius);
    let stride = ((tile_ground_m / dem.pixel_size_m(radius)) / 2.0)
        .floor()
        .max(1.0) as usize;
    let mut out = BTreeSet::new();
    for (lat, lon) in dem.footprint_points(stride) {
        let d = cube::latlon_to_dir(lat.to_radians(), lon.to_radians());
        let mut t = layout.locate(level, d).tile;
        while out.insert(t) {
            match t.parent() {
                Some(p) => t = p,
                None => break,
            }
        }
    }
    out
}

/// [`render_height_tile`] of a mosaic's `layers` (highest priority first).
fn render_tile(
    layers: &[mosaic::Layer],
    layout: &Layout,
    id: TileId,
    resampling: Resampling,
    prefilter: Prefilter,
    height_shift: f64,
) -> HeightTile {
    let k = box_samples(layout, id.level, prefilter);
    let depth = k.trailing_zeros() as u8;
    if block_fits(layout, depth) {
        // The taps are the pixel centres of the level `depth` finer: sample that level once
        // over the tile's footprint, on its own (finer) lattice, and average.
        let s = sample_block(layers, layout, id, id.level + depth, resampling);
        return tile_from_samples(&s, layout, id, id.level + depth, height_shift);
    }
    // Tiles too large to hold k² samples per pixel: interpolate each tap's coordinates on this
    // level's lattice instead.
    render_taps(layers, layout, id, resampling, k, height_shift)
}

/// Tile `id` with each pixel the mean of `k × k` source samples spread over its footprint, their
/// coordinates interpolated on the tile's own level's lattice.
fn render_taps(
    layers: &[mosaic::Layer],
    layout: &Layout,
    id: TileId,
    resampling: Resampling,
    k: u32,
    height_shift: f64,
) -> HeightTile {
    let size = layout.stored_size();
    let halo = layout.halo as i64;
    let offsets: Vec<f64> = (0..k).map(|a| (a as f64 + 0.5) / k as f64 - 0.5).collect();
    let grids: Vec<SourceGrid> = layers
        .iter()
        .map(|l| SourceGrid::new(l.dem, layout, id))
        .collect();
    let mut rows: Vec<mosaic::LayerRow> = layers.iter().map(|_| Default::default()).collect();
    rows.iter_mut().for_each(|r| r.resize(1));
    let mut out = TileBuilder::new(size);
    for j in 0..size as i64 {
        for i in 0..size as i64 {
            let (gx, gy) = layout.global_pixel(id, i - halo, j - halo);
            let mut acc = BoxSum::default();
            for &oj in &offsets {
                for &oi in &offsets {
                    let (gxf, gyf) = (gx as f64 + oi, gy as f64 + oj);
                    let (h, mk) = if let [layer] = layers {
                        let (col, row) = grids[0].at(gxf, gyf);
                        layer.dem.sample_pixel(col, row, resampling)
                    } else {
                        // Each layer down to the first that settles the tap.
                        let mut top = layers.len();
                        for (l, ((layer, grid), r)) in
                            layers.iter().zip(&grids).zip(rows.iter_mut()).enumerate()
                        {
                            let (col, row) = grid.at(gxf, gyf);
                            (r.height[0], r.mask[0]) = layer.dem.sample_pixel(col, row, resampling);
                            r.weigh(layer, &[(col, row)]);
                            if mosaic::settles(r, 0) {
                                top = l + 1;
                                break;
                            }
                        }
                        mosaic::compose(&layers[..top], &rows[..top], 0)
                    };
                    acc.add(h, mk);
                }
            }
            out.push(acc, height_shift);
        }
    }
    out.finish()
}

/// Running mean of the samples that have data, and whether any of them was filled.
#[derive(Clone, Copy, Default)]
struct BoxSum {
    sum: f64,
    n: u32,
    filled: bool,
}

impl BoxSum {
    /// Add one sample unless it has no data. Branch-free: a sample without data adds +0.0,
    /// which leaves the sum's bits unchanged (it starts at +0.0 and round-to-nearest never
    /// makes it −0.0).
    #[inline]
    fn add(&mut self, h: f32, mk: u8) {
        let valid = mk != mask::NO_DATA;
        self.sum += if valid { h as f64 } else { 0.0 };
        self.n += valid as u32;
        self.filled |= mk == mask::FILLED;
    }
}

struct TileBuilder {
    size: usize,
    height: Vec<f32>,
    mask: Vec<u8>,
}

impl TileBuilder {
    fn new(size: usize) -> Self {
        TileBuilder {
            size,
            height: Vec::with_capacity(size * size),
            mask: Vec::with_capacity(size * size),
        }
    }

    #[inline]
    fn push(&mut self, acc: BoxSum, height_shift: f64) {
        if acc.n == 0 {
            self.height.push(f32::NAN);
            self.mask.push(mask::NO_DATA);
        } else {
            // One sample (the finest level, or point sampling): x / 1 is x, without a division.
            let mean = if acc.n == 1 {
                acc.sum
            } else {
                acc.sum / acc.n as f64
            };
            self.height.push((mean + height_shift) as f32);
            self.mask.push(if acc.filled {
                mask::FILLED
            } else {
                mask::MEASURED
            });
        }
    }

    fn finish(self) -> HeightTile {
        HeightTile {
            size: self.size,
            height: self.height,
            mask: self.mask,
        }
    }
}

/// Largest side (pixels) of the sample block one thread holds in memory: about 4096² samples,
/// 5 bytes each.
const BLOCK_MAX_SIDE: usize = 4200;

/// Whether a block sampled `depth` levels finer than a tile, over the tile's footprint, stays
/// within [`BLOCK_MAX_SIDE`].
fn block_fits(layout: &Layout, depth: u8) -> bool {
    (layout.stored_size() << depth) <= BLOCK_MAX_SIDE
}

/// How many levels above the finest are averaged from a group's finest-level samples (0: none,
/// every tile is sampled from the source on its own). With the box prefilter a pixel at
/// `finest − d` (d ≤ log2 [`MAX_BOX`]) is the mean of the 2^d × 2^d finest-level pixel centres
/// it covers, so sampling the finest level once over a level-`finest − d` tile (its halo
/// included) gives every tile below it at `d + 1` levels for the cost of one. Capped so the
/// sample block stays within [`BLOCK_MAX_SIDE`].
pub fn group_depth(layout: &Layout, prefilter: Prefilter) -> u8 {
    if prefilter == Prefilter::Point {
        return 0;
    }
    let finest = layout.levels - 1;
    let mut d = finest.min(MAX_BOX.trailing_zeros() as u8);
    while d > 0 && !block_fits(layout, d) {
        d -= 1;
    }
    d
}

/// Raw source heights (before the datum shift) and masks, one interpolated sample per global
/// face pixel of one level, over a rectangle.
struct SampleBlock {
    x0: i64,
    y0: i64,
    w: usize,
    height: Vec<f32>,
    mask: Vec<u8>,
}

/// Sample level `sample_level` (the finest, for a group) over the footprint of tile `root`
/// (halo included): the pixels every tile of the group is averaged from. Rows are sampled in
/// parallel.
fn sample_block(
    layers: &[mosaic::Layer],
    layout: &Layout,
    root: TileId,
    sample_level: u8,
    resampling: Resampling,
) -> SampleBlock {
    let k = 1i64 << (sample_level - root.level);
    let (n, halo) = (layout.tile_size as i64, layout.halo as i64);
    let (x0, y0) = (
        k * (root.x as i64 * n - halo),
        k * (root.y as i64 * n - halo),
    );
    let w = (k * (n + 2 * halo)) as usize;
    let grids: Vec<SourceGrid> = layers
        .iter()
        .map(|l| {
            SourceGrid::region(
                l.dem,
                layout,
                root.face,
                sample_level,
                (x0 - 1, y0 - 1),
                (w as i64 + 2, w as i64 + 2),
            )
        })
        .collect();
    let mut height = vec![0f32; w * w];
    let mut m = vec![0u8; w * w];
    if let ([layer], [grid]) = (layers, &grids[..]) {
        height
            .par_chunks_mut(w)
            .zip(m.par_chunks_mut(w))
            .enumerate()
            .for_each_init(
                || vec![(0.0, 0.0); w],
                |coords, (j, (hrow, mrow))| {
                    grid.row(x0, y0 + j as i64, coords);
                    layer.dem.sample_row(coords, resampling, hrow, mrow);
                },
            );
    } else {
        height
            .par_chunks_mut(w)
            .zip(m.par_chunks_mut(w))
            .enumerate()
            .for_each_init(
                || MosaicScratch::new(layers.len(), w),
                |scratch, (j, (hrow, mrow))| {
                    mosaic_row(
                        layers,
                        &grids,
                        (x0, y0 + j as i64),
                        resampling,
                        scratch,
                        (hrow, mrow),
                    );
                },
            );
    }
    SampleBlock {
        x0,
        y0,
        w,
        height,
        mask: m,
    }
}

/// One worker's buffers for [`mosaic_row`].
struct MosaicScratch {
    coords: Vec<(f64, f64)>,
    rows: Vec<mosaic::LayerRow>,
    settled: Vec<bool>,
}

impl MosaicScratch {
    fn new(layers: usize, w: usize) -> Self {
        let mut rows: Vec<mosaic::LayerRow> = (0..layers).map(|_| Default::default()).collect();
        rows.iter_mut().for_each(|r| r.resize(w));
        MosaicScratch {
            coords: vec![(0.0, 0.0); w],
            rows,
            settled: vec![false; w],
        }
    }
}

/// One row of a mosaic's samples at global pixels `g0.0 ..` of row `g0.1`: each layer sampled
/// (on its own grid) while some pixel of the row is not yet settled by a layer above it, then
/// every pixel composed from the layers down to the one that settles it
/// ([`mosaic::compose`]).
fn mosaic_row(
    layers: &[mosaic::Layer],
    grids: &[SourceGrid],
    (gx0, gy): (i64, i64),
    resampling: Resampling,
    scratch: &mut MosaicScratch,
    (hout, mout): (&mut [f32], &mut [u8]),
) {
    let MosaicScratch {
        coords,
        rows,
        settled,
    } = scratch;
    settled.fill(false);
    let mut sampled = 0;
    for (k, (layer, grid)) in layers.iter().zip(grids).enumerate() {
        if k > 0 && settled.iter().all(|&s| s) {
            break;
        }
        let row = &mut rows[k];
        grid.row(gx0, gy, coords);
        layer
            .dem
            .sample_row(coords, resampling, &mut row.height, &mut row.mask);
        row.weigh(layer, coords);
        for (p, s) in settled.iter_mut().enumerate() {
            *s |= mosaic::settles(row, p);
        }
        sampled = k + 1;
    }
    for (p, (h, m)) in hout.iter_mut().zip(mout.iter_mut()).enumerate() {
        let top = (0..sampled)
            .find(|&k| mosaic::settles(&rows[k], p))
            .map_or(sampled, |k| k + 1);
        (*h, *m) = mosaic::compose(&layers[..top], &rows[..top], p);
    }
}

/// Tile `id` from samples at level `sample_level`: each pixel the mean of the
/// `2^(sample_level − level)`² samples it covers that have data.
fn tile_from_samples(
    s: &SampleBlock,
    layout: &Layout,
    id: TileId,
    sample_level: u8,
    height_shift: f64,
) -> HeightTile {
    let size = layout.stored_size();
    let halo = layout.halo as i64;
    let k = 1usize << (sample_level - id.level);
    let mut out = TileBuilder::new(size);
    let mut acc = Vec::with_capacity(size);
    for j in 0..size as i64 {
        let (gx, gy) = layout.global_pixel(id, -halo, j - halo);
        let (sx, sy) = (
            (gx * k as i64 - s.x0) as usize,
            (gy * k as i64 - s.y0) as usize,
        );
        // The k sample rows under this output row, cut to its span.
        let span = sx..sx + size * k;
        let rows: Vec<(&[f32], &[u8])> = (0..k)
            .map(|b| {
                let r = (sy + b) * s.w;
                (
                    &s.height[r + span.start..r + span.end],
                    &s.mask[r + span.start..r + span.end],
                )
            })
            .collect();
        // The row's sums side by side, one sample row at a time: each pixel adds its samples
        // in the same order as alone (rows, then left to right), but the pixels' addition
        // chains are independent and overlap.
        acc.clear();
        acc.resize(size, BoxSum::default());
        for (h, m) in &rows {
            for ((a, h), m) in acc.iter_mut().zip(h.chunks_exact(k)).zip(m.chunks_exact(k)) {
                for (&h, &m) in h.iter().zip(m) {
                    a.add(h, m);
                }
            }
        }
        for &a in &acc {
            out.push(a, height_shift);
        }
    }
    out.finish()
}

/// Sample one albedo tile (halo included).
pub fn render_albedo_tile(src: &AlbedoSource, layout: &Layout, id: TileId) -> AlbedoTile {
    let size = layout.stored_size();
    let halo = layout.halo as i64;
    let c = src.channels;
    let mut data = vec![0u16; size * size * c];
    for j in 0..size as i64 {
        for i in 0..size as i64 {
            let d = layout.pixel_dir(id, i - halo, j - halo);
            let (lat, lon) = cube::dir_to_latlon(d);
            let k = (j as usize * size + i as usize) * c;
            src.sample(lat.to_degrees(), lon.to_degrees(), &mut data[k..k + c]);
        }
    }
    AlbedoTile {
        size,
        channels: c,
        sixteen_bit: src.sixteen_bit,
        data,
    }
}

/// Where a run's tiles go and what each needs besides its heights.
struct TileSink<'a> {
    layout: &'a Layout,
    opts: &'a TileOptions,
    albedo: Option<&'a AlbedoSource>,
    out: &'a Path,
    resume: bool,
    /// The run key: the height tiles' identity (`format::Identity`).
    run_key: &'a str,
}

impl TileSink<'_> {
    /// Statistics of tile `id` when a resumed run already wrote it (and its albedo tile).
    fn kept(&self, id: TileId) -> Option<TileStats> {
        if !self.resume {
            return None;
        }
        let hpath = crate::tileset::tile_path(self.out, manifest::HEIGHT_PATTERN, id);
        let apath = crate::tileset::tile_path(self.out, manifest::ALBEDO_PATTERN, id);
        if hpath.exists() && (self.albedo.is_none() || apath.exists()) {
            if let Ok(t) = height::read_height_tile(&hpath) {
                if t.size == self.layout.stored_size() {
                    return interior_stats(self.layout, &t, true);
                }
            }
        }
        None
    }

    /// Write tile `id` (and its albedo tile) unless it holds no data.
    fn write(&self, id: TileId, tile: HeightTile) -> Result<Option<TileStats>> {
        let Some(stats) = interior_stats(self.layout, &tile, false) else {
            return Ok(None);
        };
        let hpath = crate::tileset::tile_path(self.out, manifest::HEIGHT_PATTERN, id);
        let identity = crate::format::Identity::tile(height::ID, id, self.run_key);
        height::write_height_tile(&hpath, &tile, self.opts.compression, Some(&identity))?;
        if let Some(a) = self.albedo {
            let apath = crate::tileset::tile_path(self.out, manifest::ALBEDO_PATTERN, id);
            let identity =
                crate::format::Identity::tile(crate::format::albedo::ID, id, self.run_key);
            write_albedo_tile(
                &apath,
                &render_albedo_tile(a, self.layout, id),
                Some(&identity),
            )?;
        }
        Ok(Some(stats))
    }
}

/// What one worker renders: a tile on its own, or a group root with the tiles below it
/// (see [`group_depth`]).
enum Unit {
    Tile(TileId),
    Group(TileId, Vec<TileId>),
}

/// Cut the candidates into units: with a group depth d, each candidate at `finest − d` roots a
/// group holding it and its candidate descendants (coarse to fine); coarser candidates are
/// single tiles.
fn plan_units(candidates: &[TileId], finest: u8, depth: u8) -> Vec<Unit> {
    if depth == 0 {
        return candidates.iter().map(|&id| Unit::Tile(id)).collect();
    }
    let root_level = finest - depth;
    let mut members: std::collections::BTreeMap<TileId, Vec<TileId>> = Default::default();
    let mut units = Vec::new();
    for &id in candidates {
        if id.level < root_level {
            units.push(Unit::Tile(id));
        } else {
            let up = id.level - root_level;
            let root = TileId {
                level: root_level,
                face: id.face,
                x: id.x >> up,
                y: id.y >> up,
            };
            members.entry(root).or_default().push(id);
        }
    }
    for (root, mut tiles) in members {
        tiles.sort_by_key(|t| (t.level, t.y, t.x));
        units.push(Unit::Group(root, tiles));
    }
    units
}

/// Render one unit's tiles; kept tiles of a resumed run are read, not rendered.
fn run_unit(
    layers: &[mosaic::Layer],
    sink: &TileSink,
    unit: &Unit,
    height_shift: f64,
    progress: &dyn Progress,
) -> Vec<(TileId, Result<Option<TileStats>>)> {
    let opts = sink.opts;
    match unit {
        Unit::Tile(id) => {
            let r = match sink.kept(*id) {
                Some(s) => Ok(Some(s)),
                None => sink.write(
                    *id,
                    render_tile(
                        layers,
                        sink.layout,
                        *id,
                        opts.resampling,
                        opts.prefilter,
                        height_shift,
                    ),
                ),
            };
            progress.inc(1);
            vec![(*id, r)]
        }
        Unit::Group(root, tiles) => {
            let finest = sink.layout.levels - 1;
            let mut samples = None;
            let mut out = Vec::with_capacity(tiles.len());
            for &id in tiles {
                let r = match sink.kept(id) {
                    Some(s) => Ok(Some(s)),
                    None => {
                        let s = samples.get_or_insert_with(|| {
                            sample_block(layers, sink.layout, *root, finest, opts.resampling)
                        });
                        sink.write(
                            id,
                            tile_from_samples(s, sink.layout, id, finest, height_shift),
                        )
                    }
                };
                progress.inc(1);
                out.push((id, r));
            }
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{global_georef, synthetic_dem};

    /// A smooth global geographic raster, `w × w/2` pixel-registered samples.
    fn global(w: usize) -> Dem {
        let g = global_georef(w, w / 2);
        synthetic_dem(w, w / 2, g.clone(), |c, r| {
            let (lat, lon) = (g.y0 - r as f64 * g.dy, g.x0 + c as f64 * g.dx);
            let p = cube::latlon_to_dir(lat.to_radians(), lon.to_radians());
            (1500.0 * (3.0 * p[0]).sin() * (2.0 * p[1]).cos() + 900.0 * p[2]) as f32
        })
    }

    /// Tiles averaged from a group's finest-level samples equal tiles rendered on their own bit
    /// for bit (the same positions on the same global lattice), and equal the fallback for
    /// huge tiles (box taps with coordinates interpolated on the tile's own, coarser lattice)
    /// within the lattice's interpolation tolerance (bit for bit at the finest level).
    #[test]
    fn group_tiles_match_tiles_sampled_on_their_own() {
        // 72: the tiles oversample the source 14× and some lattice cells interpolate;
        // 720: the source is finer than the tiles and most cells are exact.
        for (w, tile_size) in [(72, 64), (720, 16)] {
            group_tiles_match_per_tile_tiles(w, tile_size);
        }
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The eight-lane statistics are the raster-order loop's, bit for bit: on random tiles
    /// with no-data and filled samples, odd sizes (a remainder after the lanes), and tiles
    /// whose extremes are +0 and −0 met in either order.
    #[test]
    fn interior_stats_match_the_raster_order_loop() {
        let reference = |layout: &Layout, t: &HeightTile| {
            let (h, n) = (layout.halo as usize, layout.tile_size as usize);
            let (mut lo, mut hi, mut filled, mut no_data) =
                (f32::INFINITY, f32::NEG_INFINITY, 0u64, 0u64);
            for j in h..h + n {
                for i in h..h + n {
                    let k = j * t.size + i;
                    match t.mask[k] {
                        mask::NO_DATA => no_data += 1,
                        m => {
                            filled += u64::from(m == mask::FILLED);
                            lo = lo.min(t.height[k]);
                            hi = hi.max(t.height[k]);
                        }
                    }
                }
            }
            (no_data < (n * n) as u64).then_some((lo.to_bits(), hi.to_bits(), filled, no_data))
        };
        let mut rnd = crate::testutil::rng(41);
        for tile_size in [1u32, 7, 8, 13, 64] {
            let layout = Layout {
                projection: Projection::Gnomonic,
                tile_size,
                halo: 2,
                levels: 1,
            };
            let size = layout.stored_size();
            for case in 0..7 {
                let mut t = HeightTile {
                    size,
                    height: (0..size * size)
                        .map(|_| (rnd() * 2000.0 - 1000.0) as f32)
                        .collect(),
                    mask: (0..size * size)
                        .map(|_| match (rnd() * 10.0) as u8 {
                            0 => mask::NO_DATA,
                            1 => mask::FILLED,
                            _ => mask::MEASURED,
                        })
                        .collect(),
                };
                match case {
                    // Only zeros of both signs, in two orders.
                    1 | 2 => {
                        for (k, v) in t.height.iter_mut().enumerate() {
                            *v = if (k % 3 == 0) == (case == 1) {
                                -0.0
                            } else {
                                0.0
                            };
                        }
                    }
                    // Zero is the minimum (all other heights positive).
                    3 => {
                        for v in &mut t.height {
                            *v = v.abs();
                        }
                        t.height[size * size / 2] = -0.0;
                        t.height[size * size / 2 + 1] = 0.0;
                    }
                    // Nothing but no-data.
                    4 => t.mask.fill(mask::NO_DATA),
                    // The first interior sample has no data, the next is −0, every other +0:
                    // the first zero met in raster order is not the first of lane 0.
                    5 => {
                        t.height.fill(0.0);
                        t.mask.fill(mask::MEASURED);
                        let first = 2 * size + 2;
                        t.mask[first] = mask::NO_DATA;
                        if tile_size > 1 {
                            t.height[first + 1] = -0.0;
                        }
                    }
                    _ => {}
                }
                let got = interior_stats(&layout, &t, false)
                    .map(|s| (s.min.to_bits(), s.max.to_bits(), s.filled, s.no_data));
                assert_eq!(got, reference(&layout, &t), "tile {tile_size}, case {case}");
            }
        }
    }

    fn group_tiles_match_per_tile_tiles(w: usize, tile_size: u32) {
        let dem = global(w);
        let layout = Layout {
            projection: Projection::Gnomonic,
            tile_size,
            halo: 2,
            levels: 3,
        };
        assert_eq!(group_depth(&layout, Prefilter::Box), 2);
        assert_eq!(group_depth(&layout, Prefilter::Point), 0);
        // Largest height step between neighbouring source pixels bounds |dh| per source pixel
        // of position error.
        let mut step = 0f64;
        for r in 0..dem.height() {
            for c in 0..dem.width() - 1 {
                let (a, b) = (dem.value(c, r).0, dem.value(c + 1, r).0);
                step = step.max((a - b).abs() as f64);
                if r + 1 < dem.height() {
                    step = step.max((a - dem.value(c, r + 1).0).abs() as f64);
                }
            }
        }
        let bound = 4.0 * APPROX_TOL_PX * step;
        let (mut worst, mut compared, mut interp, mut cells) = (0f64, 0, 0, 0);
        for face in cube::Face::ALL {
            let root = TileId {
                level: 0,
                face,
                x: 0,
                y: 0,
            };
            let one = [mosaic::Layer::new(&dem, 0.0, 0.0, true)];
            let s = sample_block(&one, &layout, root, 2, Resampling::Bilinear);
            for (x, y) in (0..4).flat_map(|y| (0..4).map(move |x| (x, y))) {
                let g = SourceGrid::new(
                    &dem,
                    &layout,
                    TileId {
                        level: 2,
                        face,
                        x,
                        y,
                    },
                );
                interp += g.ok.iter().filter(|&&o| o == INTERP).count();
                cells += g.ok.len();
            }
            for level in 0..3u8 {
                for y in 0..1u32 << level {
                    for x in 0..1u32 << level {
                        let id = TileId { level, face, x, y };
                        let g = tile_from_samples(&s, &layout, id, 2, 0.0);
                        let own = render_height_tile(
                            &dem,
                            &layout,
                            id,
                            Resampling::Bilinear,
                            Prefilter::Box,
                            0.0,
                        );
                        assert_eq!(bits(&g.height), bits(&own.height), "{id:?}");
                        assert_eq!(g.mask, own.mask, "{id:?}");
                        let k = box_samples(&layout, level, Prefilter::Box);
                        let one = [mosaic::Layer::new(&dem, 0.0, 0.0, true)];
                        let t = render_taps(&one, &layout, id, Resampling::Bilinear, k, 0.0);
                        assert_eq!(g.mask, t.mask, "{id:?}");
                        for (a, b) in g.height.iter().zip(&t.height) {
                            if level == 2 {
                                assert_eq!(a.to_bits(), b.to_bits(), "{id:?}");
                            } else {
                                worst = worst.max((a - b).abs() as f64);
                                compared += 1;
                            }
                        }
                    }
                }
            }
        }
        let side = (tile_size + 4) as usize;
        assert_eq!(compared, 6 * 5 * side * side);
        eprintln!(
            "{w} px source: group vs per-tile box levels differ by {worst} m (bound {bound} m); \
             {interp} of {cells} lattice cells of finest tiles interpolated"
        );
        if w == 72 {
            assert!(interp > 0, "the case meant to interpolate does not");
        }
        assert!(
            worst <= bound,
            "group and per-tile box levels differ by {worst} m (bound {bound} m)"
        );
    }

    #[test]
    fn units_cover_every_candidate_once() {
        let layout = Layout {
            projection: Projection::Gnomonic,
            tile_size: 16,
            halo: 2,
            levels: 5,
        };
        let mut candidates = BTreeSet::new();
        for (x, y) in [(0u32, 0u32), (5, 9), (15, 15), (6, 9)] {
            let mut t = TileId {
                level: 4,
                face: cube::Face::ALL[1],
                x,
                y,
            };
            loop {
                candidates.insert(t);
                match t.parent() {
                    Some(p) => t = p,
                    None => break,
                }
            }
        }
        let candidates: Vec<TileId> = candidates.into_iter().collect();
        let depth = group_depth(&layout, Prefilter::Box);
        assert_eq!(depth, 2);
        let mut seen = Vec::new();
        for u in plan_units(&candidates, 4, depth) {
            match u {
                Unit::Tile(id) => {
                    assert!(id.level < 2);
                    seen.push(id);
                }
                Unit::Group(root, tiles) => {
                    assert_eq!(root.level, 2);
                    assert_eq!(tiles[0], root, "the root comes first");
                    for t in tiles {
                        let up = t.level - 2;
                        assert_eq!((t.face, t.x >> up, t.y >> up), (root.face, root.x, root.y));
                        seen.push(t);
                    }
                }
            }
        }
        seen.sort();
        assert_eq!(seen, candidates);
    }

    /// A regional raster's bounding cap is a circle round its rectangle. Lattice cells inside
    /// the cap but beyond one edge of the rectangle are called off the source (every pixel's
    /// exact coordinates there are off the raster), so only the cells along the rectangle's
    /// edges are computed pixel by pixel; the tiles stay what exact coordinates give.
    #[test]
    fn cells_beyond_a_regional_rasters_edges_are_off_the_source() {
        // 1° × 1° at 90 px per degree, its corner near the centre of face +X.
        let n = 90;
        let d = 1.0 / n as f64;
        let g = crate::dem::GeoRef {
            crs: crate::dem::Crs::Geographic,
            x0: -0.2 + d / 2.0,
            y0: 0.7 - d / 2.0,
            dx: d,
            dy: d,
        };
        let dem = synthetic_dem(n, n, g, |c, r| {
            (30.0 * (c as f64 * 0.1).sin() + r as f64) as f32
        });
        let layout = Layout {
            projection: Projection::Gnomonic,
            tile_size: 64,
            halo: 2,
            levels: 8,
        };
        let (mut counts, mut off_pixels) = ([0usize; 4], 0usize);
        for (x, y) in [(63, 63), (64, 63), (63, 64), (64, 64)] {
            let id = TileId {
                level: 7,
                face: cube::Face::Px,
                x,
                y,
            };
            let grid = SourceGrid::new(&dem, &layout, id);
            for &o in &grid.ok {
                counts[o as usize] += 1;
            }
            for j in -2..66 {
                for i in -2..66 {
                    let (gx, gy) = layout.global_pixel(id, i, j);
                    let (gx, gy) = (gx as f64 + 0.5, gy as f64 + 0.5);
                    let (a, e) = (grid.at(gx, gy), grid.exact(gx, gy));
                    if a.0.is_nan() {
                        off_pixels += 1;
                        assert!(
                            !dem.covers(e.0, e.1),
                            "{id:?} ({i}, {j}): {e:?} is on the raster"
                        );
                    }
                }
            }
        }
        // The rectangle is ≈ 91 face pixels a side (0.011° each): ≈ 12 cells per edge.
        eprintln!("cells exact/interp/outside/split {counts:?}, {off_pixels} pixels off");
        assert!(off_pixels > 0 && counts[INTERP as usize] > 0);
        assert!(
            counts[EXACT as usize] <= 4 * (12 + 3),
            "{} cells computed pixel by pixel: more than the rectangle's edges",
            counts[EXACT as usize]
        );
    }

    /// Wherever the grid interpolates (whole cells or halves of split ones), the coordinates are
    /// within twice the tolerance checked at the cells' centres and edge midpoints, and split
    /// cells do occur where whole ones are too curved (towards the poles of a geographic raster).
    #[test]
    fn interpolated_source_coordinates_stay_near_exact() {
        for (w, tile_size, levels) in [(1440, 512, 4u8), (72, 64, 3)] {
            let dem = global(w);
            let layout = Layout {
                projection: Projection::Gnomonic,
                tile_size,
                halo: 2,
                levels,
            };
            let finest = levels - 1;
            let (mut worst, mut counts) = (0f64, [0usize; 4]);
            for face in [cube::Face::Pz, cube::Face::Px] {
                // The tile whose corner is the face centre: the pole on face +Z.
                let c = (1u32 << finest) / 2 - 1;
                let id = TileId {
                    level: finest,
                    face,
                    x: c,
                    y: c,
                };
                let g = SourceGrid::new(&dem, &layout, id);
                for &o in &g.ok {
                    counts[o as usize] += 1;
                }
                for j in -2..tile_size as i64 + 2 {
                    for i in -2..tile_size as i64 + 2 {
                        let (gx, gy) = layout.global_pixel(id, i, j);
                        let (gx, gy) = (gx as f64 + 0.25, gy as f64 - 0.25);
                        let (a, e) = (g.at(gx, gy), g.exact(gx, gy));
                        worst = worst.max((a.0 - e.0).abs()).max((a.1 - e.1).abs());
                    }
                }
            }
            eprintln!(
                "{w} px source, {tile_size}-px tiles: cells exact/interp/outside/split {counts:?}, \
                 worst {worst:.2e} px"
            );
            assert!(worst <= 2.0 * APPROX_TOL_PX, "{worst} px off");
            if w == 1440 {
                assert!(counts[SPLIT as usize] > 0 && counts[INTERP as usize] > 0);
            }
        }
    }
}
