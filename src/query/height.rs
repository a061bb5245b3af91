//! The height query: the stored tile's bilinear height at a point.

use std::path::Path;

use serde::Serialize;

use super::locate::{check_latlon, locate, pick_level};
use crate::error::{Error, Result};
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
