//! The horizon of the pixel over a point: read from the stored maps, or computed on demand.

use std::path::Path;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::horizon::stage::{
    check_layout, check_options, context_for, coverage_box, interior_max, margin_for, reach_rad,
    terrain_range, HorizonOptions,
};
use crate::horizon::{compass_azimuth_deg, horizons_with, plane_azimuth, Method, Rect};
use crate::manifest;
use crate::tileset::Store;

/// The horizon of the pixel that contains a point.
#[derive(Clone, Debug, Serialize)]
pub struct HorizonAnswer {
    /// The point asked for.
    pub query_lat_deg: f64,
    pub query_lon_deg: f64,
    /// Centre of the pixel whose horizon this is.
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub height_m: f64,
    pub level: u8,
    pub face: String,
    pub tile: [u32; 2],
    /// Interior pixel (column, row) of the tile.
    pub pixel: [u32; 2],
    pub method: Method,
    /// `stored` (read from the horizon maps) or `computed` (on demand).
    pub source: String,
    pub azimuths: usize,
    /// Compass azimuth of each sample, degrees clockwise from local north, ascending.
    pub azimuth_deg: Vec<f64>,
    /// Horizon elevation above the local horizontal, degrees, for each azimuth.
    pub elevation_deg: Vec<f64>,
    /// The same samples' plane azimuths (the stored convention), degrees.
    pub plane_azimuth_deg: Vec<f64>,
    /// Context searched around the pixel's tile when computed (pixels; 0 when stored).
    pub margin_px: u64,
    pub needed_margin_px: u64,
}

pub fn horizon(
    dir: &Path,
    lat: f64,
    lon: f64,
    level: Option<u8>,
    opts: &HorizonOptions,
) -> Result<HorizonAnswer> {
    let (method, azimuths) = (opts.method, opts.azimuths);
    super::check_latlon(lat, lon)?;
    check_options(opts)?;
    let store = Store::open(dir)?;
    let ts = store.manifest();
    check_layout(dir, ts)?;
    let level = super::pick_level(ts, level)?;
    let (tile, px, py) = super::locate(ts, lat, lon, level);
    if !ts.has_tile(tile) {
        return Err(Error::usage(format!(
            "no height tile covers {lat}°, {lon}° at level {level} (tile {tile}): the source DEM \
             does not reach there; `penumbra info {}` lists the coverage",
            dir.display()
        )));
    }
    let lay = ts.layout;
    let n = lay.tile_size as usize;
    let (i, j) = (
        (px.round().max(0.0) as usize).min(n - 1),
        (py.round().max(0.0) as usize).min(n - 1),
    );
    let t = store.height(tile)?.expect("covered");
    let h = lay.halo as usize;
    let height = t.height[(j + h) * t.size + i + h];
    if height.is_nan() {
        return Err(Error::usage(format!(
            "the pixel at {lat}°, {lon}° (level {level}, tile {tile}, pixel {i},{j}) has no data: \
             it has no horizon"
        )));
    }
    // Stored maps of the same method, azimuth count and (fast) near field.
    let near = (method == Method::Fast).then_some(opts.near_px);
    let stored = ts.products.horizon.as_ref().filter(|p| {
        p.azimuths == azimuths
            && p.method == method.name()
            && p.near_px == near
            && p.levels.contains(&level)
    });
    let (elev, source, margin, needed) = match stored {
        Some(_) => {
            let planes = store.horizon(tile)?;
            let e: Vec<f32> = (0..azimuths)
                .map(|k| planes[k * n * n + j * n + i])
                .collect();
            (e, "stored", 0, 0)
        }
        None => {
            let (tmin, tmax) = terrain_range(ts).ok_or_else(|| {
                Error::invalid(
                    dir.join(manifest::MANIFEST),
                    "tileset records no height range",
                )
            })?;
            let top = interior_max(&t, h, n).unwrap_or(height);
            let rad = reach_rad(ts.body.radius_m, tmin, tmax, top as f64);
            let reach = margin_for(ts, tile, rad, opts.max_margin_px);
            let cover = coverage_box(ts, level, tile.face);
            let (ctx, rect) = context_for(&store, tile, reach.margin_px, cover)?;
            let one = Rect {
                x0: rect.x0 + i,
                y0: rect.y0 + j,
                w: 1,
                h: 1,
            };
            (
                horizons_with(&ctx, one, azimuths, method, opts.near_px),
                "computed",
                reach.margin_px,
                reach.needed_px,
            )
        }
    };
    let (s, tt) = lay.pixel_st(tile, i as i64, j as i64);
    let d = lay.st_to_dir(tile.face, s, tt);
    let (plat, plon) = crate::cube::dir_to_latlon(d);
    let mut rows: Vec<(f64, f64, f64)> = (0..azimuths)
        .map(|k| {
            let phi = plane_azimuth(k, azimuths);
            (
                compass_azimuth_deg(tile.face, s, tt, phi),
                elev[k] as f64,
                phi.to_degrees(),
            )
        })
        .collect();
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(HorizonAnswer {
        query_lat_deg: lat,
        query_lon_deg: lon,
        lat_deg: plat.to_degrees(),
        lon_deg: plon.to_degrees(),
        height_m: height as f64,
        level,
        face: tile.face.name().into(),
        tile: [tile.x, tile.y],
        pixel: [i as u32, j as u32],
        method,
        source: source.into(),
        azimuths,
        azimuth_deg: rows.iter().map(|r| r.0).collect(),
        elevation_deg: rows.iter().map(|r| r.1).collect(),
        plane_azimuth_deg: rows.iter().map(|r| r.2).collect(),
        margin_px: margin,
        needed_margin_px: needed,
    })
}
