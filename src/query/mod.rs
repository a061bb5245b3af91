//! Point queries against a tileset, one per product, all through the [`Store`]: which tile and
//! pixel a latitude/longitude falls in, and the stored products there.

mod horizon;
mod mip;

pub use self::horizon::{horizon, shadow, HorizonAnswer, HorizonFrom, ShadowAnswer};
pub use self::mip::{face_texel, mip, FaceTexel, MipAnswer};

use std::path::Path;

use serde::Serialize;

use crate::cube;
use crate::error::{Error, Result};
use crate::layout::TileId;
use crate::manifest::Tileset;
use crate::tileset::Store;

#[derive(Clone, Debug, Serialize)]
pub struct HeightAnswer {
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Bilinear height from the stored tile, metres above `radius_m`.
    pub height_m: f64,
    pub radius_m: f64,
    pub level: u8,
    pub face: String,
    pub tile: [u32; 2],
    /// Fractional interior pixel (centres at integers).
    pub pixel: [f64; 2],
    /// Mask of the nearest stored pixel: 0 measured, 1 filled void, 2 no data.
    pub mask: u8,
    /// Ground size of a pixel at this level at the face centre.
    pub level_pixel_m: f64,
    pub file: String,
}

/// Check and normalise a latitude/longitude given in degrees (longitude −180..360).
pub fn check_latlon(lat: f64, lon: f64) -> Result<()> {
    if !(lat.is_finite() && (-90.0..=90.0).contains(&lat)) {
        return Err(Error::usage(format!(
            "latitude {lat} is outside −90..90 degrees"
        )));
    }
    if !(lon.is_finite() && (-180.0..=360.0).contains(&lon)) {
        return Err(Error::usage(format!(
            "longitude {lon} is outside −180..360 degrees"
        )));
    }
    Ok(())
}

/// Resolve a requested level against a tileset (default: the finest).
pub fn pick_level(ts: &Tileset, level: Option<u8>) -> Result<u8> {
    let finest = ts.layout.levels - 1;
    match level {
        None => Ok(finest),
        Some(l) if l <= finest => Ok(l),
        Some(l) => Err(Error::usage(format!(
            "level {l} does not exist: this tileset has levels 0..={finest}"
        ))),
    }
}

/// The tile containing (lat, lon) at `level`, with the fractional interior pixel.
pub fn locate(ts: &Tileset, lat: f64, lon: f64, level: u8) -> (TileId, f64, f64) {
    let d = cube::latlon_to_dir(lat.to_radians(), lon.to_radians());
    let loc = ts.layout.locate(level, d);
    (loc.tile, loc.px, loc.py)
}

pub fn height(dir: &Path, lat: f64, lon: f64, level: Option<u8>) -> Result<HeightAnswer> {
    check_latlon(lat, lon)?;
    let store = Store::open(dir)?;
    let ts = store.manifest();
    let level = pick_level(ts, level)?;
    let (tile, px, py) = locate(ts, lat, lon, level);
    if !ts.has_tile(tile) {
        return Err(Error::usage(format!(
            "no height tile covers {lat}°, {lon}° at level {level} (tile {tile}): the source DEM \
             does not reach there; `penumbra info {}` lists the coverage",
            dir.display()
        )));
    }
    let file = store.height_path(tile)?;
    let t = store.read_height(tile)?;
    let h = ts.layout.halo as f64;
    let (x, y) = (px + h, py + h);
    let height_m = t.bilinear(x, y) as f64;
    let (xi, yi) = (x.round() as usize, y.round() as usize);
    let mask = t.mask[yi.min(t.size - 1) * t.size + xi.min(t.size - 1)];
    Ok(HeightAnswer {
        lat_deg: lat,
        lon_deg: lon,
        height_m,
        radius_m: ts.body.radius_m,
        level,
        face: tile.face.name().into(),
        tile: [tile.x, tile.y],
        pixel: [px, py],
        mask,
        level_pixel_m: ts.layout.centre_pixel_m(level, ts.body.radius_m),
        file: file.display().to_string(),
    })
}
