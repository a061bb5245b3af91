//! The mip stage over a tileset (every tile's pyramids, the face pyramids, the manifest entry)
//! and the query of the texel containing a point. Specified in docs/mipmaps.md.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use super::io::{read_mip_exr, write_mip_exr};
use super::kernels::{
    f16_down, f16_up, face_pyramid, fmax, fmin, level_sizes, minmax_pyramid, minmax_pyramid_into,
    nan_if, MinMaxPyramid, NEG_INF, POS_INF,
};
use super::schema::Precision;
use crate::cube::Face;
use crate::error::{Error, Result};
use crate::layout::TileId;
use crate::manifest::{self, MipLevelRange, MipProduct, Tileset};
use crate::progress::Progress;
use crate::query;
use crate::tileio::{self, TileCompression};

pub const MAX_PATTERN: &str = "maxmip/{level}/{face}/{y}/{x}.exr";
pub const MINMAX_PATTERN: &str = "minmax/{level}/{face}/{y}/{x}.exr";
pub const FACE_PATTERN: &str = "minmax/{level}/{face}/face.exr";
/// Written at the start of a mip run and removed at its end; a rerun with the same key resumes.
pub const PARTIAL: &str = ".penumbra-mip-partial.json";
/// Version of the mip products' layout and convention (part of the run key).
pub const MIP_FORMAT: &str = "penumbra-mip-1";
/// One-line statement of the texel convention, recorded in the manifest.
pub const TEXEL_CONVENTION: &str =
    "level-0 texel (i,j) = interior pixel (i,j), bounds the bilinear \
     surface over [i-1/2,i+1/2]x[j-1/2,j+1/2] = extreme of stored samples i-1..i+1, j-1..j+1; \
     level k texel = extreme of its 2x2 children (sizes halve rounding up); NaN = no data";

// ---------------------------------------------------------------------------------------------
// Stage

/// What the user chose.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MipOptions {
    pub precision: Precision,
    pub compression: TileCompression,
}

/// What a run did.
#[derive(Clone, Debug, Serialize)]
pub struct MipReport {
    pub out: PathBuf,
    pub tiles: u64,
    pub tiles_written: u64,
    pub tiles_kept: u64,
    pub face_pyramids: u64,
    pub precision: Precision,
    pub global_min_m: f64,
    pub global_max_m: f64,
    /// Height samples read (halos included) × 4 bytes.
    pub input_bytes: u64,
    pub up_to_date: bool,
}

fn nan_to_none(v: f32) -> Option<f64> {
    (!v.is_nan()).then_some(v as f64)
}

/// Paths of a tile's two products.
pub fn tile_paths(dir: &Path, id: TileId) -> (PathBuf, PathBuf) {
    let f = id.face.name();
    (
        tileio::tile_path(dir, MAX_PATTERN, id.level, f, id.x, id.y),
        tileio::tile_path(dir, MINMAX_PATTERN, id.level, f, id.x, id.y),
    )
}

/// Path of a face pyramid.
pub fn face_path(dir: &Path, level: u8, face: Face) -> PathBuf {
    tileio::tile_path(dir, FACE_PATTERN, level, face.name(), 0, 0)
}

/// Read a height tile and compute its (min, max) pyramid, checking the tile's size.
pub fn tile_pyramid(path: &Path, stored_size: usize, halo: usize) -> Result<MinMaxPyramid> {
    let t = tileio::read_height_tile(path)?;
    if t.size != stored_size {
        return Err(Error::invalid(
            path,
            format!("tile is {}² but the manifest says {stored_size}²", t.size),
        ));
    }
    minmax_pyramid(&t.height, t.size, halo)
}

/// Build every mip product of the tileset in `dir` and record them in its manifest.
pub fn build_mips(dir: &Path, opts: &MipOptions, progress: &dyn Progress) -> Result<MipReport> {
    let mut ts = Tileset::load(dir)?;
    let manifest_path = dir.join(manifest::MANIFEST);
    let height = ts.products.height.clone().ok_or_else(|| {
        Error::invalid(
            &manifest_path,
            "tileset has no height product to build mipmaps from",
        )
    })?;
    let lay = ts.layout;
    if lay.halo < 1 {
        return Err(Error::unsupported(
            &manifest_path,
            "mipmaps need a halo of at least 1 pixel: retile with --halo 1 or more",
        ));
    }
    let (n, s, halo) = (lay.tile_size as usize, lay.stored_size(), lay.halo as usize);
    let run_key = {
        let mut h = blake3::Hasher::new();
        h.update(env!("CARGO_PKG_VERSION").as_bytes());
        h.update(MIP_FORMAT.as_bytes());
        h.update(ts.run_key.as_bytes());
        h.update(height.path.as_bytes());
        h.update(serde_json::to_string(opts).unwrap_or_default().as_bytes());
        h.finalize().to_hex().to_string()
    };
    let tiles: Vec<TileId> = ts.tile_set().into_iter().collect();
    let tile_bytes = (s * s * 4) as u64;
    let partial_path = dir.join(PARTIAL);
    if let Some(m) = &ts.products.mip {
        if m.run_key == run_key && !partial_path.exists() {
            return Ok(MipReport {
                out: dir.to_path_buf(),
                tiles: tiles.len() as u64,
                tiles_written: 0,
                tiles_kept: tiles.len() as u64,
                face_pyramids: 0,
                precision: opts.precision,
                global_min_m: m.global_min_m,
                global_max_m: m.global_max_m,
                input_bytes: 0,
                up_to_date: true,
            });
        }
    }
    let previous = manifest::partial_run_key(&partial_path);
    let resume = previous.as_deref() == Some(run_key.as_str());
    if !resume {
        // Products of other heights or options are stale.
        for sub in ["maxmip", "minmax"] {
            let p = dir.join(sub);
            if p.exists() {
                std::fs::remove_dir_all(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
    }
    manifest::write_partial(&partial_path, &run_key)?;

    progress.start("mipmaps", tiles.len() as u64);
    let results: Vec<Result<(f32, f32, bool)>> = tiles
        .par_iter()
        // One pyramid per worker, reused from tile to tile: fresh level buffers would cost a
        // page fault per 4 KiB written, more than computing the pyramid.
        .map_init(
            || MinMaxPyramid::new(n),
            |pyr, &id| {
                let r = mip_tile(dir, &ts, id, n, s, halo, opts, resume, pyr);
                progress.inc(1);
                r
            },
        )
        .collect();
    progress.finish();
    let mut tops = BTreeMap::new();
    let (mut written, mut kept) = (0u64, 0u64);
    for (id, r) in tiles.iter().zip(results) {
        let (lo, hi, k) = r?;
        if k {
            kept += 1;
        } else {
            written += 1;
        }
        tops.insert(*id, (lo, hi));
    }

    // Face pyramids of whole-tile extrema, and per-level and global ranges.
    let mut ranges = Vec::new();
    let mut face_pyramids = 0u64;
    let (mut gmin, mut gmax) = (POS_INF, NEG_INF);
    for level in 0..lay.levels {
        let g = lay.tiles_per_side(level) as usize;
        let (mut lmin, mut lmax) = (POS_INF, NEG_INF);
        for face in Face::ALL {
            let mut lo = vec![f32::NAN; g * g];
            let mut hi = vec![f32::NAN; g * g];
            let mut any = false;
            for (id, &(a, b)) in tops.range(
                TileId {
                    level,
                    face,
                    x: 0,
                    y: 0,
                }..=TileId {
                    level,
                    face,
                    x: u32::MAX,
                    y: u32::MAX,
                },
            ) {
                let k = id.y as usize * g + id.x as usize;
                lo[k] = a;
                hi[k] = b;
                any = true;
            }
            if !any {
                continue;
            }
            let p = face_pyramid(g, lo, hi);
            let (a, b) = p.top();
            lmin = fmin(lmin, a);
            lmax = fmax(lmax, b);
            write_mip_exr(
                &face_path(dir, level, face),
                g,
                Some(&p.min),
                &p.max,
                Precision::F32,
                opts.compression,
                "penumbra-face-minmax",
            )?;
            face_pyramids += 1;
        }
        gmin = fmin(gmin, lmin);
        gmax = fmax(gmax, lmax);
        ranges.push(MipLevelRange {
            level,
            min_m: nan_to_none(nan_if(lmin, POS_INF)),
            max_m: nan_to_none(nan_if(lmax, NEG_INF)),
        });
    }
    if !(gmin.is_finite() && gmax.is_finite()) {
        return Err(Error::invalid(
            &manifest_path,
            "every height tile is no data: nothing to build mipmaps from",
        ));
    }
    let product = MipProduct {
        products: vec!["max".into(), "minmax".into()],
        max_path: MAX_PATTERN.into(),
        max_channels: vec!["max".into()],
        minmax_path: MINMAX_PATTERN.into(),
        minmax_channels: vec!["min".into(), "max".into()],
        face_path: FACE_PATTERN.into(),
        precision: opts.precision,
        face_precision: Precision::F32,
        level_rounding: "up".into(),
        texel: TEXEL_CONVENTION.into(),
        global_min_m: gmin as f64,
        global_max_m: gmax as f64,
        levels: ranges,
        run_key,
    };
    let (gmin, gmax) = (product.global_min_m, product.global_max_m);
    ts.products.mip = Some(product);
    let json = serde_json::to_string_pretty(&ts).expect("manifest serialises");
    tileio::write_atomic_bytes(&manifest_path, json.as_bytes())?;
    std::fs::remove_file(&partial_path).map_err(|e| Error::io(&partial_path, e))?;
    Ok(MipReport {
        out: dir.to_path_buf(),
        tiles: tiles.len() as u64,
        tiles_written: written,
        tiles_kept: kept,
        face_pyramids,
        precision: opts.precision,
        global_min_m: gmin,
        global_max_m: gmax,
        input_bytes: written * tile_bytes,
        up_to_date: false,
    })
}

/// One tile: (1×1 min, 1×1 max, kept from an earlier run).
#[allow(clippy::too_many_arguments)]
fn mip_tile(
    dir: &Path,
    ts: &Tileset,
    id: TileId,
    n: usize,
    s: usize,
    halo: usize,
    opts: &MipOptions,
    resume: bool,
    p: &mut MinMaxPyramid,
) -> Result<(f32, f32, bool)> {
    let (pmax, pmm) = tile_paths(dir, id);
    if resume && pmax.exists() && pmm.exists() {
        if let Ok(f) = read_mip_exr(&pmm) {
            if f.sizes[0] == n {
                if let (Some(lo), Some(hi)) = (f.channels.get("min"), f.channels.get("max")) {
                    return Ok((lo.last().unwrap()[0], hi.last().unwrap()[0], true));
                }
            }
        }
    }
    let pattern = &ts.products.height.as_ref().expect("checked").path;
    let hpath = tileio::tile_path(dir, pattern, id.level, id.face.name(), id.x, id.y);
    let t = tileio::read_height_tile(&hpath)?;
    if t.size != s {
        return Err(Error::invalid(
            &hpath,
            format!("tile is {}² but the manifest says {s}²", t.size),
        ));
    }
    minmax_pyramid_into(&t.height, s, halo, p)?;
    write_mip_exr(
        &pmax,
        n,
        None,
        &p.max,
        opts.precision,
        opts.compression,
        "penumbra-maxmip",
    )?;
    write_mip_exr(
        &pmm,
        n,
        Some(&p.min),
        &p.max,
        opts.precision,
        opts.compression,
        "penumbra-minmax",
    )?;
    let (lo, hi) = p.top();
    // f16 files hold rounded bounds: the face pyramid uses the same rounded values.
    Ok(match opts.precision {
        Precision::F32 => (lo, hi, false),
        Precision::F16 => (f16_down(lo).to_f32(), f16_up(hi).to_f32(), false),
    })
}

// ---------------------------------------------------------------------------------------------
// Query

/// The texel of a mip level that contains a point.
#[derive(Clone, Debug, Serialize)]
pub struct MipAnswer {
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Tile level whose tiles the pyramid belongs to.
    pub tile_level: u8,
    /// Mip level asked for: 0..=`tile_mip_levels`−1 inside the tile, above that the face
    /// pyramid (`tile_mip_levels`−1 + f is face-pyramid level f).
    pub level: u32,
    /// Levels of a tile's own pyramid (tile_size … 1).
    pub tile_mip_levels: u32,
    /// Highest level accepted (the face's 1×1).
    pub max_level: u32,
    /// `tile` or `face`.
    pub scope: String,
    pub face: String,
    pub tile: [u32; 2],
    /// Fractional interior pixel at `tile_level` (centres at integers).
    pub pixel: [f64; 2],
    /// Texel (column, row) at this level, in the tile (`scope` tile) or the face grid (face).
    pub texel: [u32; 2],
    /// Texels per side at this level.
    pub texels: u32,
    /// Lower and upper bound of the interpolated surface over the texel (null: no data).
    pub min_m: Option<f64>,
    pub max_m: Option<f64>,
    pub file: String,
}

/// The texel containing (lat, lon) at mip `level` of the tiles at `tile_level` (default the
/// finest).
pub fn query(
    dir: &Path,
    lat: f64,
    lon: f64,
    level: u32,
    tile_level: Option<u8>,
) -> Result<MipAnswer> {
    query::check_latlon(lat, lon)?;
    let ts = Tileset::load(dir)?;
    let tl = query::pick_level(&ts, tile_level)?;
    let mp = ts.products.mip.as_ref().ok_or_else(|| {
        Error::usage(format!(
            "{} has no mipmaps: run `penumbra mip {}` first",
            dir.display(),
            dir.display()
        ))
    })?;
    let n = ts.layout.tile_size as usize;
    let m = level_sizes(n).len() as u32;
    let max_level = m - 1 + tl as u32;
    if level > max_level {
        return Err(Error::usage(format!(
            "mip level {level} does not exist: tile level {tl} has mip levels 0..={max_level} \
             (0..={} inside a {n}-px tile, then the face pyramid up to the face's 1×1)",
            m - 1
        )));
    }
    let (tile, px, py) = query::locate(&ts, lat, lon, tl);
    let clampi = |p: f64| ((p + 0.5).floor().max(0.0) as u64).min(n as u64 - 1) as u32;
    let (i0, j0) = (clampi(px), clampi(py));
    let (scope, file, texel, texels, lo, hi);
    if level < m {
        if !ts.has_tile(tile) {
            return Err(Error::usage(format!(
                "no height tile covers {lat}°, {lon}° at level {tl} (tile {tile}): the source DEM \
                 does not reach there; `penumbra info {}` lists the coverage",
                dir.display()
            )));
        }
        let path = tileio::tile_path(dir, &mp.minmax_path, tl, tile.face.name(), tile.x, tile.y);
        let f = read_mip_exr(&path)?;
        if f.sizes[0] != n {
            return Err(Error::invalid(
                &path,
                format!("mipmap is {}² but tiles are {n}²", f.sizes[0]),
            ));
        }
        let k = level as usize;
        let w = f.sizes[k];
        let (x, y) = (i0 >> level, j0 >> level);
        let idx = y as usize * w + x as usize;
        scope = "tile";
        texel = [x, y];
        texels = w as u32;
        lo = f.channel(&path, "min")?[k][idx];
        hi = f.channel(&path, "max")?[k][idx];
        file = path;
    } else {
        let fl = level - (m - 1);
        let path = tileio::tile_path(dir, &mp.face_path, tl, tile.face.name(), 0, 0);
        if !path.exists() {
            return Err(Error::usage(format!(
                "no tile of face {} at level {tl} has data: no face pyramid there",
                tile.face
            )));
        }
        let f = read_mip_exr(&path)?;
        let g = ts.layout.tiles_per_side(tl) as usize;
        if f.sizes[0] != g {
            return Err(Error::invalid(
                &path,
                format!(
                    "face pyramid is {}² but level {tl} has {g}² tiles",
                    f.sizes[0]
                ),
            ));
        }
        let k = fl as usize;
        let w = f.sizes[k];
        let (x, y) = (tile.x >> fl, tile.y >> fl);
        let idx = y as usize * w + x as usize;
        scope = "face";
        texel = [x, y];
        texels = w as u32;
        lo = f.channel(&path, "min")?[k][idx];
        hi = f.channel(&path, "max")?[k][idx];
        file = path;
    }
    Ok(MipAnswer {
        lat_deg: lat,
        lon_deg: lon,
        tile_level: tl,
        level,
        tile_mip_levels: m,
        max_level,
        scope: scope.into(),
        face: tile.face.name().into(),
        tile: [tile.x, tile.y],
        pixel: [px, py],
        texel,
        texels,
        min_m: nan_to_none(lo),
        max_m: nan_to_none(hi),
        file: file.display().to_string(),
    })
}
