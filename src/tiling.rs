//! The tiling stage: resample a DEM (and optionally an albedo image) into cube-face tiles.
//!
//! Every stored pixel — interior and halo — is sampled from the source at its own direction,
//! so neighbouring tiles and faces agree wherever they overlap, to within resampling error.
//! Tiles are independent, rendered in parallel and written atomically; the output does not
//! depend on the thread count. A rerun with the same run key keeps tiles already on disk.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use crate::albedo::AlbedoSource;
use crate::body::Body;
use crate::cube::{self, Projection};
use crate::dem::{mask, Dem, Resampling};
use crate::error::{Error, Result};
use crate::layout::{Layout, TileId, MAX_LEVELS};
use crate::manifest::{self, Tileset};
use crate::progress::Progress;
use crate::runner::{self, StageSpec, Start};
use crate::tileio::{self, AlbedoTile, HeightTile};
use crate::tileset::writer::Writer;
use crate::tileset::{Product, STATE_DIR};

/// The tiling stage writes the height (and albedo) tiles every later product derives from.
pub const STAGE: StageSpec = StageSpec {
    name: "tile",
    writes: &[Product::Height, Product::Albedo],
    format: &[],
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
    pub compression: tileio::TileCompression,
    pub max_fill_px: u32,
    /// Equirectangular albedo image and the longitude of its left edge.
    pub albedo: Option<(PathBuf, f64)>,
    /// Refuse a run whose tiles would exceed this many GiB before compression (not part of
    /// the run's identity: it changes no byte of the output).
    #[serde(skip)]
    pub max_output_gib: f64,
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
            compression: tileio::TileCompression::Zip,
            max_fill_px: crate::dem::DEFAULT_MAX_FILL_PX,
            albedo: None,
            max_output_gib: runner::DEFAULT_MAX_OUTPUT_GIB,
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

/// Tile `dem` for `body` into `out`.
pub fn tile_dem(
    dem: &Dem,
    body: &Body,
    out: &Path,
    opts: &TileOptions,
    embedded: Option<&Embedded>,
    progress: &dyn Progress,
) -> Result<TileReport> {
    opts.validate()?;
    let albedo = match &opts.albedo {
        Some((p, west)) => Some(AlbedoSource::open(p, *west)?),
        None => None,
    };
    let radius = body.radius_m;
    let source_px_m = dem.pixel_size_m(radius);
    let levels = opts.levels.unwrap_or_else(|| {
        Layout::levels_for(opts.projection, opts.tile_size, radius, source_px_m)
    });
    let layout = Layout {
        projection: opts.projection,
        tile_size: opts.tile_size,
        halo: opts.halo,
        levels,
    };
    let height_shift = dem.datum_radius_m().map_or(0.0, |r0| r0 - radius);
    // Implausible input (heights, pixel size, datum for this body) is refused before `out`
    // is touched.
    dem.check_plausible(radius)?;

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
    let albedo_file = match &albedo {
        Some(a) => Some(manifest::hash_file(&a.path)?),
        None => None,
    };
    let parameters = serde_json::json!({
        "body": body,
        "options": opts,
        "levels": levels,
    });
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

    // Candidate tiles: every finest-level tile a footprint point falls in, and their ancestors.
    let finest = levels - 1;
    let tile_ground_m = 0.4 * opts.tile_size as f64 * layout.centre_pixel_m(finest, radius);
    let stride = ((tile_ground_m / source_px_m) / 2.0).floor().max(1.0) as usize;
    let mut candidates = BTreeSet::new();
    for (lat, lon) in dem.footprint_points(stride) {
        let d = cube::latlon_to_dir(lat.to_radians(), lon.to_radians());
        let mut t = layout.locate(finest, d).tile;
        loop {
            if !candidates.insert(t) {
                break;
            }
            match t.parent() {
                Some(p) => t = p,
                None => break,
            }
        }
    }
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
    let run = match runner::start(writer, STAGE, &run_key, existing.as_ref())? {
        Start::UpToDate => {
            let n = existing.map_or(0, |e| e.coverage.iter().map(|c| c.tiles).sum());
            return Ok(TileReport {
                out: out.to_path_buf(),
                levels,
                tiles_written: 0,
                tiles_kept: n,
                candidates: n,
                source_pixels: (dem.width() * dem.height()) as u64,
                output_pixels: 0,
                up_to_date: true,
            });
        }
        Start::Run(run) => run,
    };
    let (stage_out, resume) = (run.out().to_path_buf(), run.resume());

    progress.start("tiling", candidates.len() as u64);
    let results: Vec<Result<Option<TileStats>>> = candidates
        .par_iter()
        .map(|&id| {
            let r = make_tile(
                dem,
                &layout,
                id,
                opts,
                height_shift,
                albedo.as_ref(),
                &stage_out,
                resume,
            );
            progress.inc(1);
            r
        })
        .collect();
    progress.finish();

    let mut present = BTreeSet::new();
    let (mut min, mut max) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut filled, mut no_data, mut written, mut kept) = (0u64, 0u64, 0u64, 0u64);
    for (id, r) in candidates.iter().zip(results) {
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
        let msg = "covers no tile: no tile pixel falls on its data; check its georeferencing \
                   (docs/formats.md) or use more levels";
        return Err(match dem.sources().first() {
            Some(source) => Error::invalid(source, msg),
            None => Error::usage(format!("the terrain {msg}")),
        });
    }
    let (voids, voids_unfilled) = dem.void_counts();
    let tileset = Tileset {
        format: manifest::FORMAT.into(),
        format_version: manifest::FORMAT_VERSION,
        tool: manifest::Tool::this(),
        body: body.clone(),
        layout,
        resampling: opts.resampling,
        source: manifest::SourceInfo {
            files,
            format: dem.format().to_string(),
            width: dem.width(),
            height: dem.height(),
            georef: dem.georef().clone(),
            pixel_size_m: source_px_m,
            datum_radius_m: dem.datum_radius_m(),
            height_shift_m: height_shift,
            voids,
            voids_unfilled,
        },
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
            mip: None,
            horizon: None,
            fourier: None,
        },
        coverage: manifest::coverage_of(&present, levels),
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
        source_pixels: (dem.width() * dem.height()) as u64,
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
    let mut s = TileStats {
        min: f32::INFINITY,
        max: f32::NEG_INFINITY,
        filled: 0,
        no_data: 0,
        kept,
    };
    for j in h..h + n {
        for i in h..h + n {
            let k = j * t.size + i;
            match t.mask[k] {
                mask::NO_DATA => s.no_data += 1,
                m => {
                    s.filled += (m == mask::FILLED) as u64;
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
const EXACT: u8 = 0;
const INTERP: u8 = 1;
const OUTSIDE: u8 = 2;
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
    /// Per cell: [`EXACT`], [`INTERP`] or [`OUTSIDE`] (wholly off the source).
    ok: Vec<u8>,
}

impl<'a> SourceGrid<'a> {
    fn exact(&self, gx: f64, gy: f64) -> (f64, f64) {
        let (s, t) = self.layout.global_st(self.level, gx, gy);
        self.dem
            .dir_to_pixel(self.layout.st_to_dir(self.face, s, t))
    }

    fn new(dem: &'a Dem, layout: &'a Layout, id: TileId) -> SourceGrid<'a> {
        let h = layout.halo as i64 + 1;
        let (g0x, g0y) = layout.global_pixel(id, -h, -h);
        let n = layout.tile_size as i64 + 2 * h;
        let m0 = (g0x.div_euclid(LATTICE), g0y.div_euclid(LATTICE));
        let m1 = (
            (g0x + n).div_euclid(LATTICE) + 1,
            (g0y + n).div_euclid(LATTICE) + 1,
        );
        let cells = ((m1.0 - m0.0) as usize, (m1.1 - m0.1) as usize);
        let mut grid = SourceGrid {
            dem,
            layout,
            face: id.face,
            level: id.level,
            m0,
            cells,
            pts: Vec::with_capacity((cells.0 + 1) * (cells.1 + 1)),
            ok: Vec::with_capacity(cells.0 * cells.1),
        };
        for my in 0..=cells.1 as i64 {
            for mx in 0..=cells.0 as i64 {
                let p = grid.exact(
                    ((m0.0 + mx) * LATTICE) as f64,
                    ((m0.1 + my) * LATTICE) as f64,
                );
                grid.pts.push(p);
            }
        }
        let half_width = dem.width() as f64 / 4.0;
        let cap = dem.footprint_cap();
        for my in 0..cells.1 {
            for mx in 0..cells.0 {
                if let Some((cc, cr)) = cap {
                    // Wholly off the source: the cell's own cap does not meet the source's.
                    let corner = |dx: i64, dy: i64| {
                        let (s, t) = layout.global_st(
                            id.level,
                            ((m0.0 + mx as i64 + dx) * LATTICE) as f64,
                            ((m0.1 + my as i64 + dy) * LATTICE) as f64,
                        );
                        layout.st_to_dir(id.face, s, t)
                    };
                    let ds = [corner(0, 0), corner(1, 0), corner(0, 1), corner(1, 1)];
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
                    if crate::cube::angle_between(mid, cc) > r + cr {
                        grid.ok.push(OUTSIDE);
                        continue;
                    }
                }
                let c = [
                    grid.pts[my * (cells.0 + 1) + mx],
                    grid.pts[my * (cells.0 + 1) + mx + 1],
                    grid.pts[(my + 1) * (cells.0 + 1) + mx],
                    grid.pts[(my + 1) * (cells.0 + 1) + mx + 1],
                ];
                let inside = c
                    .iter()
                    .all(|p| p.0.is_finite() && p.1.is_finite() && dem.covers(p.0, p.1));
                let cols = c.iter().map(|p| p.0);
                let spread = cols.clone().fold(f64::NEG_INFINITY, f64::max)
                    - cols.fold(f64::INFINITY, f64::min);
                let mut ok = inside && spread < half_width;
                if ok {
                    // Check the centre and the four edge midpoints: the centre alone misses
                    // maps whose second derivatives cancel there (f_xx ≈ −f_yy).
                    let (bx, by) = (
                        ((m0.0 + mx as i64) * LATTICE) as f64,
                        ((m0.1 + my as i64) * LATTICE) as f64,
                    );
                    let l = LATTICE as f64;
                    let lerp = |p: f64, q: f64, w: f64| p + (q - p) * w;
                    let checks = [(0.5, 0.5), (0.5, 0.0), (0.5, 1.0), (0.0, 0.5), (1.0, 0.5)];
                    ok = checks.iter().all(|&(wx, wy)| {
                        let e = grid.exact(bx + wx * l, by + wy * l);
                        let col = lerp(lerp(c[0].0, c[1].0, wx), lerp(c[2].0, c[3].0, wx), wy);
                        let row = lerp(lerp(c[0].1, c[1].1, wx), lerp(c[2].1, c[3].1, wx), wy);
                        (e.0 - col).abs() <= APPROX_TOL_PX && (e.1 - row).abs() <= APPROX_TOL_PX
                    });
                }
                grid.ok.push(if ok { INTERP } else { EXACT });
            }
        }
        grid
    }

    /// Source (col, row) of fractional global face pixel (gx, gy).
    #[inline]
    fn at(&self, gx: f64, gy: f64) -> (f64, f64) {
        let (fx, fy) = (gx / LATTICE as f64, gy / LATTICE as f64);
        let (cx, cy) = (fx.floor(), fy.floor());
        let (mx, my) = (cx as i64 - self.m0.0, cy as i64 - self.m0.1);
        if mx < 0 || my < 0 || mx as usize >= self.cells.0 || my as usize >= self.cells.1 {
            return self.exact(gx, gy);
        }
        let (mx, my) = (mx as usize, my as usize);
        match self.ok[my * self.cells.0 + mx] {
            INTERP => {}
            OUTSIDE => return (f64::NAN, f64::NAN),
            _ => return self.exact(gx, gy),
        }
        let (wx, wy) = (fx - cx, fy - cy);
        let w = self.cells.0 + 1;
        let (a, b) = (self.pts[my * w + mx], self.pts[my * w + mx + 1]);
        let (c, d) = (self.pts[(my + 1) * w + mx], self.pts[(my + 1) * w + mx + 1]);
        let lerp = |p: f64, q: f64, r: f64, s: f64| {
            (p * (1.0 - wx) + q * wx) * (1.0 - wy) + (r * (1.0 - wx) + s * wx) * wy
        };
        (lerp(a.0, b.0, c.0, d.0), lerp(a.1, b.1, c.1, d.1))
    }
}

/// Sample one height tile (halo included).
pub fn render_height_tile(
    dem: &Dem,
    layout: &Layout,
    id: TileId,
    resampling: Resampling,
    prefilter: Prefilter,
    height_shift: f64,
) -> HeightTile {
    let size = layout.stored_size();
    let halo = layout.halo as i64;
    let k = box_samples(layout, id.level, prefilter);
    let offsets: Vec<f64> = (0..k).map(|a| (a as f64 + 0.5) / k as f64 - 0.5).collect();
    let grid = SourceGrid::new(dem, layout, id);
    let mut height = Vec::with_capacity(size * size);
    let mut m = Vec::with_capacity(size * size);
    for j in 0..size as i64 {
        for i in 0..size as i64 {
            let (gx, gy) = layout.global_pixel(id, i - halo, j - halo);
            let (mut sum, mut n, mut filled) = (0.0f64, 0u32, false);
            for &oj in &offsets {
                for &oi in &offsets {
                    let (col, row) = grid.at(gx as f64 + oi, gy as f64 + oj);
                    let (h, mk) = dem.sample_pixel(col, row, resampling);
                    if mk != mask::NO_DATA {
                        sum += h as f64;
                        n += 1;
                        filled |= mk == mask::FILLED;
                    }
                }
            }
            if n == 0 {
                height.push(f32::NAN);
                m.push(mask::NO_DATA);
            } else {
                height.push((sum / n as f64 + height_shift) as f32);
                m.push(if filled { mask::FILLED } else { mask::MEASURED });
            }
        }
    }
    HeightTile {
        size,
        height,
        mask: m,
    }
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

#[allow(clippy::too_many_arguments)]
fn make_tile(
    dem: &Dem,
    layout: &Layout,
    id: TileId,
    opts: &TileOptions,
    height_shift: f64,
    albedo: Option<&AlbedoSource>,
    out: &Path,
    resume: bool,
) -> Result<Option<TileStats>> {
    let hpath = crate::tileset::tile_path(out, manifest::HEIGHT_PATTERN, id);
    let apath = crate::tileset::tile_path(out, manifest::ALBEDO_PATTERN, id);
    if resume && hpath.exists() && (albedo.is_none() || apath.exists()) {
        if let Ok(t) = tileio::read_height_tile(&hpath) {
            if t.size == layout.stored_size() {
                return Ok(interior_stats(layout, &t, true));
            }
        }
    }
    let tile = render_height_tile(
        dem,
        layout,
        id,
        opts.resampling,
        opts.prefilter,
        height_shift,
    );
    let Some(stats) = interior_stats(layout, &tile, false) else {
        return Ok(None);
    };
    tileio::write_height_tile(&hpath, &tile, opts.compression)?;
    if let Some(a) = albedo {
        tileio::write_albedo_tile(&apath, &render_albedo_tile(a, layout, id))?;
    }
    Ok(Some(stats))
}
