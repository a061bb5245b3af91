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
use crate::tileio::{self, AlbedoTile, HeightTile};

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
        }
    }
}

impl TileOptions {
    pub fn validate(&self) -> Result<()> {
        if !(8..=8192).contains(&self.tile_size) || self.tile_size % 2 != 0 {
            return Err(Error::usage(format!(
                "tile size {} is not usable: give an even size from 8 to 8192 (default 512)",
                self.tile_size
            )));
        }
        if self.halo < 1 || self.halo >= self.tile_size / 2 {
            return Err(Error::usage(format!(
                "halo {} is not usable: give 1 .. {} pixels (default 2)",
                self.halo,
                self.tile_size / 2 - 1
            )));
        }
        if let Some(l) = self.levels {
            if l == 0 || l > MAX_LEVELS {
                return Err(Error::usage(format!(
                    "{l} levels is not usable: give 1 .. {MAX_LEVELS}"
                )));
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
    let run_key = {
        let mut h = blake3::Hasher::new();
        h.update(env!("CARGO_PKG_VERSION").as_bytes());
        h.update(serde_json::to_string(&files).unwrap_or_default().as_bytes());
        h.update(
            serde_json::to_string(&albedo_file)
                .unwrap_or_default()
                .as_bytes(),
        );
        h.update(parameters.to_string().as_bytes());
        h.finalize().to_hex().to_string()
    };

    // Resume or start afresh.
    let manifest_path = out.join(manifest::MANIFEST);
    let partial_path = out.join(manifest::PARTIAL);
    if let Ok(existing) = Tileset::load(out) {
        if existing.run_key == run_key && !partial_path.exists() {
            let n = existing.coverage.iter().map(|c| c.tiles).sum();
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
    }
    let previous_key = std::fs::read_to_string(&partial_path)
        .ok()
        .and_then(|s| serde_json::from_str::<serde_json::Value>(&s).ok())
        .and_then(|v| v["run_key"].as_str().map(str::to_string));
    let resume = previous_key.as_deref() == Some(run_key.as_str());
    if !resume && (manifest_path.exists() || partial_path.exists()) {
        // A tileset made with other inputs or parameters: its tiles are stale.
        for sub in ["height", "albedo"] {
            let p = out.join(sub);
            if p.exists() {
                std::fs::remove_dir_all(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
        let _ = std::fs::remove_file(&manifest_path);
    }
    tileio::write_atomic_bytes(
        &partial_path,
        serde_json::json!({ "run_key": run_key })
            .to_string()
            .as_bytes(),
    )?;

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
                out,
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
        return Err(Error::usage(
            "the DEM covers no tile: check its georeferencing (docs/formats.md)",
        ));
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
        },
        coverage: manifest::coverage_of(&present, levels),
        parameters,
        run_key,
    };
    let json = serde_json::to_string_pretty(&tileset).expect("manifest serialises");
    tileio::write_atomic_bytes(&manifest_path, json.as_bytes())?;
    std::fs::remove_file(&partial_path).map_err(|e| Error::io(&partial_path, e))?;
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
    let mut height = Vec::with_capacity(size * size);
    let mut m = Vec::with_capacity(size * size);
    for j in 0..size as i64 {
        for i in 0..size as i64 {
            let (mut sum, mut n, mut filled) = (0.0f64, 0u32, false);
            for &oj in &offsets {
                for &oi in &offsets {
                    let (s, t) =
                        layout.pixel_st_f(id, (i - halo) as f64 + oi, (j - halo) as f64 + oj);
                    let (h, mk) = dem.sample_dir(layout.st_to_dir(id.face, s, t), resampling);
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
    let face = id.face.name();
    let hpath = tileio::tile_path(out, manifest::HEIGHT_PATTERN, id.level, face, id.x, id.y);
    let apath = tileio::tile_path(out, manifest::ALBEDO_PATTERN, id.level, face, id.x, id.y);
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
