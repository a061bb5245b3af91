//! Where a latitude/longitude falls: checked coordinates, the level asked, the tile and the
//! fractional pixel.

use crate::cube;
use crate::error::{Error, Result};
use crate::layout::TileId;
use crate::manifest::Tileset;

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
