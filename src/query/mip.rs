//! The (min, max) mipmap texel over a point: inside a tile's own pyramid, then the face pyramid.

use std::path::Path;

use serde::Serialize;

use crate::cube::Face;
use crate::error::{Error, Result};
use crate::mip::level_sizes;
use crate::tileset::{self, Store};

fn nan_to_none(v: f32) -> Option<f64> {
    (!v.is_nan()).then_some(v as f64)
}

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
pub fn mip(
    dir: &Path,
    lat: f64,
    lon: f64,
    level: u32,
    tile_level: Option<u8>,
) -> Result<MipAnswer> {
    super::check_latlon(lat, lon)?;
    let store = Store::open(dir)?;
    let ts = store.manifest();
    let tl = super::pick_level(ts, tile_level)?;
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
    let (tile, px, py) = super::locate(ts, lat, lon, tl);
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
        let path = tileset::tile_path(dir, &mp.minmax_path, tile);
        let f = store.mip(tile, false)?;
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
        let t = face_texel(&store, tl, tile.face, fl, tile.x, tile.y)?;
        scope = "face";
        texel = [tile.x >> fl, tile.y >> fl];
        texels = t.texels;
        lo = t.min;
        hi = t.max;
        file = t.file;
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

/// One texel of a face pyramid, wherever it is stored.
#[derive(Clone, Debug)]
pub struct FaceTexel {
    /// NaN: no tile with data below it.
    pub min: f32,
    pub max: f32,
    /// Texels per side of the face pyramid at this level.
    pub texels: u32,
    /// The file read (the face file for a texel inside a chunk that has no file: no tiles).
    pub file: std::path::PathBuf,
}

/// Texel (tx >> `fl`, ty >> `fl`) of level `fl` of the face pyramid of `face` at tile level
/// `tl` (level 0: one texel per tile), for tile (tx, ty): from the face file, or, at the
/// levels inside a chunk of a chunked face, from the chunk's file (docs/mipmaps.md).
pub fn face_texel(
    store: &Store,
    tl: u8,
    face: Face,
    fl: u32,
    tx: u32,
    ty: u32,
) -> Result<FaceTexel> {
    let (dir, ts) = (store.dir(), store.manifest());
    let mp = ts
        .products
        .mip
        .as_ref()
        .ok_or_else(|| Error::usage(format!("{} has no mipmaps", dir.display())))?;
    let g = ts.layout.tiles_per_side(tl);
    if fl > tl as u32 || tx >= g || ty >= g {
        return Err(Error::usage(format!(
            "face-pyramid level {fl} texel of tile ({tx}, {ty}) does not exist at tile level {tl}"
        )));
    }
    let face_file = tileset::face_file_path(dir, &mp.face_path, tl, face);
    if !face_file.exists() {
        return Err(Error::usage(format!(
            "no tile of face {face} at level {tl} has data: no face pyramid there"
        )));
    }
    // (file, its chunk if it is one, its level-0 size, level in it, texel x, y in it).
    let (path, chunk, size, k, x, y) = match (&mp.face_chunk_path, mp.face_chunk_tiles) {
        (Some(pattern), Some(c)) if g > c => {
            let kc = c.trailing_zeros();
            if fl < kc {
                let (cx, cy) = (tx / c, ty / c);
                let p = tileset::face_chunk_file_path(dir, pattern, tl, face, cx, cy);
                if !p.exists() {
                    // No tile in this chunk: no terrain (as the chunk's texel in the face file).
                    return Ok(FaceTexel {
                        min: f32::NAN,
                        max: f32::NAN,
                        texels: g >> fl,
                        file: face_file,
                    });
                }
                (p, Some((cx, cy)), c, fl, (tx % c) >> fl, (ty % c) >> fl)
            } else {
                (face_file, None, g / c, fl - kc, tx >> fl, ty >> fl)
            }
        }
        _ => (face_file, None, g, fl, tx >> fl, ty >> fl),
    };
    let f = store.face_mip(&path, tl, face, chunk)?;
    if f.sizes[0] != size as usize {
        return Err(Error::invalid(
            &path,
            format!(
                "face pyramid is {}² but should be {size}² at tile level {tl}",
                f.sizes[0]
            ),
        ));
    }
    let k = k as usize;
    let w = f.sizes[k];
    let idx = y as usize * w + x as usize;
    Ok(FaceTexel {
        min: f.channel(&path, "min")?[k][idx],
        max: f.channel(&path, "max")?[k][idx],
        texels: g >> fl,
        file: path,
    })
}
