//! Export of a tileset's products onto a map grid that GIS tools read: a raster in a CRS on
//! the body's sphere (polar stereographic near a pole, equirectangular elsewhere, or the
//! gnomonic projection of one cube face), each pixel holding what the point query answers at
//! its centre (docs/packaging.md, "GeoTIFF export (GDAL)").
//!
//! [`render`] resamples: for every output pixel, its centre's CRS coordinates → a direction on
//! the sphere (the inverse projections in f64, here) → the product there, exactly as
//! `penumbra query` computes it — the bilinear height of the stored tile (`query::height`), or
//! the lit fraction of the sun's disc / the mean horizon elevation of the tile pixel that
//! contains the point (`query::shadow`, `query::horizon`). [`cog`] (`--features gdal`) writes
//! the raster as a Cloud-Optimized GeoTIFF with GDAL's COG driver. The library's API holds no
//! GDAL type: the CRS travels as WKT and PROJ text.

#[cfg(feature = "gdal")]
pub mod cog;

use std::collections::{BTreeSet, HashMap};
use std::path::Path;
use std::sync::Arc;

use rayon::prelude::*;
use serde::Serialize;

use crate::cube::{self, Face, Vec3};
use crate::dem::{Crs, GeoRef};
use crate::error::{Error, Result};
use crate::fourier::sun::{self, Model};
use crate::layout::TileId;
use crate::manifest;
use crate::query::{floor_samples, sun_at_pixel, Profile};
use crate::shadow::HorizonSource;
use crate::tileset::Store;

/// Default cap on an export's raster (GiB of f32 samples), refused above before anything is
/// sampled.
pub const DEFAULT_MAX_OUTPUT_GIB: f64 = 4.0;

/// A region whose every point lies within this many degrees of a pole is exported in polar
/// stereographic by default; any other in equirectangular.
pub const POLAR_CAP_DEG: f64 = 30.0;

/// What an exported raster holds per pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExportProduct {
    /// Metres above the body's reference sphere: the stored tiles' bilinear height at the
    /// pixel centre (as `penumbra query height`).
    Height,
    /// The lit fraction of the sun's disc, 0..=1, at the tile pixel containing the pixel
    /// centre (as `penumbra query shadow` with `--method horizon`).
    Lit,
    /// The mean horizon elevation over azimuth (degrees) of the tile pixel containing the pixel
    /// centre: the Fourier series' constant term, or the mean of the raw maps' samples (the
    /// mean of what `penumbra query horizon` lists).
    HorizonMean,
}

impl ExportProduct {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            ExportProduct::Height => "height",
            ExportProduct::Lit => "lit",
            ExportProduct::HorizonMean => "horizon-mean",
        }
    }

    /// What a pixel holds, in words (the band's description), and its unit.
    pub fn description(self) -> (&'static str, &'static str) {
        match self {
            ExportProduct::Height => ("height above the reference sphere", "metre"),
            ExportProduct::Lit => ("lit fraction of the sun's disc", "fraction"),
            ExportProduct::HorizonMean => ("mean horizon elevation over azimuth", "degree"),
        }
    }
}

impl std::str::FromStr for ExportProduct {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "height" => Ok(ExportProduct::Height),
            "lit" => Ok(ExportProduct::Lit),
            "horizon-mean" => Ok(ExportProduct::HorizonMean),
            _ => Err(format!(
                "unknown product '{s}': use height, lit or horizon-mean"
            )),
        }
    }
}

/// The projection asked for (`None` in [`ExportOptions::crs`]: chosen from the region).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CrsKind {
    /// Polar stereographic about the nearer pole, true scale at the pole.
    Stere,
    /// Equirectangular (plate carrée in metres, true scale at the equator).
    Eqc,
    /// Gnomonic about the region's centre (a cube face's centre for a face).
    Gnom,
}

impl std::str::FromStr for CrsKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "stere" => Ok(CrsKind::Stere),
            "eqc" => Ok(CrsKind::Eqc),
            "gnom" => Ok(CrsKind::Gnom),
            _ => Err(format!("unknown CRS '{s}': use stere, eqc or gnom")),
        }
    }
}

/// The CRS of an exported raster, on the body's sphere, in metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum MapCrs {
    /// `+proj=eqc +lat_ts=0 +lat_0=0 +lon_0=L`: x = R·(λ − L), y = R·φ.
    Equirectangular { lon0_deg: f64 },
    /// `+proj=stere +lat_0=±90 +lon_0=0 +k=1`.
    PolarStereographic { north: bool },
    /// `+proj=gnom +lat_0=.. +lon_0=..`: x, y = R·(tangent-plane coordinates), x east and y
    /// north at the centre (at a pole, with lon_0 = 0: x towards 90°E, y away from (north
    /// pole) or towards (south pole) the 0° meridian — a cube face's U and V axes).
    Gnomonic { lat0_deg: f64, lon0_deg: f64 },
}

impl MapCrs {
    /// The PROJ string of the CRS on a sphere of `radius_m`.
    pub fn proj4(&self, radius_m: f64) -> String {
        match *self {
            MapCrs::Equirectangular { lon0_deg } => format!(
                "+proj=eqc +lat_ts=0 +lat_0=0 +lon_0={lon0_deg} +x_0=0 +y_0=0 +R={radius_m} \
                 +units=m +no_defs"
            ),
            MapCrs::PolarStereographic { north } => format!(
                "+proj=stere +lat_0={} +lon_0=0 +k=1 +x_0=0 +y_0=0 +R={radius_m} +units=m \
                 +no_defs",
                if north { 90 } else { -90 }
            ),
            MapCrs::Gnomonic { lat0_deg, lon0_deg } => format!(
                "+proj=gnom +lat_0={lat0_deg} +lon_0={lon0_deg} +x_0=0 +y_0=0 +R={radius_m} \
                 +units=m +no_defs"
            ),
        }
    }

    /// OGC WKT 1 of the CRS, naming the body in its datum and ellipsoid (a sphere of
    /// `radius_m`: inverse flattening 0).
    pub fn wkt(&self, body: &str, radius_m: f64) -> String {
        let b = body_title(body);
        let geog = format!(
            "GEOGCS[\"GCS_{b}\",DATUM[\"D_{b}\",SPHEROID[\"{b}\",{radius_m},0]],\
             PRIMEM[\"Reference_Meridian\",0],UNIT[\"degree\",0.0174532925199433]]"
        );
        let (name, proj, params) = match *self {
            MapCrs::Equirectangular { lon0_deg } => (
                "Equirectangular",
                "Equirectangular",
                vec![("standard_parallel_1", 0.0), ("central_meridian", lon0_deg)],
            ),
            MapCrs::PolarStereographic { north } => (
                if north {
                    "North Polar Stereographic"
                } else {
                    "South Polar Stereographic"
                },
                "Polar_Stereographic",
                vec![
                    ("latitude_of_origin", if north { 90.0 } else { -90.0 }),
                    ("central_meridian", 0.0),
                    ("scale_factor", 1.0),
                ],
            ),
            MapCrs::Gnomonic { lat0_deg, lon0_deg } => (
                "Gnomonic",
                "Gnomonic",
                vec![
                    ("latitude_of_origin", lat0_deg),
                    ("central_meridian", lon0_deg),
                ],
            ),
        };
        let mut p: String = params
            .iter()
            .map(|(k, v)| format!(",PARAMETER[\"{k}\",{v}]"))
            .collect();
        p.push_str(",PARAMETER[\"false_easting\",0],PARAMETER[\"false_northing\",0]");
        format!(
            "PROJCS[\"{b} {name}\",{geog},PROJECTION[\"{proj}\"]{p},UNIT[\"metre\",1],\
             AXIS[\"Easting\",EAST],AXIS[\"Northing\",NORTH]]"
        )
    }

    /// The direction (unit vector, body frame) of CRS coordinates (x, y) on a sphere of
    /// `radius_m`; None off the projection's domain (beyond the poles in equirectangular).
    pub fn inverse_dir(&self, radius_m: f64, x: f64, y: f64) -> Option<Vec3> {
        match *self {
            MapCrs::Equirectangular { .. } | MapCrs::PolarStereographic { .. } => {
                let g = GeoRef {
                    crs: self.dem_crs(radius_m)?,
                    x0: 0.0,
                    y0: 0.0,
                    dx: 1.0,
                    dy: 1.0,
                };
                let (lat, lon) = g.inverse(x, y);
                if !(lat.is_finite() && lon.is_finite() && lat.abs() <= 90.0) {
                    return None;
                }
                Some(cube::latlon_to_dir(lat.to_radians(), lon.to_radians()))
            }
            MapCrs::Gnomonic { lat0_deg, lon0_deg } => {
                let (c, e, n) = tangent_basis(lat0_deg, lon0_deg);
                let p = cube::add(
                    c,
                    cube::add(cube::scale(e, x / radius_m), cube::scale(n, y / radius_m)),
                );
                Some(cube::normalize(p))
            }
        }
    }

    /// CRS coordinates of a direction; None where the projection cannot show it (the far
    /// hemisphere in gnomonic, the opposite pole in polar stereographic).
    pub fn forward_dir(&self, radius_m: f64, d: Vec3) -> Option<(f64, f64)> {
        match *self {
            MapCrs::Equirectangular { lon0_deg } => {
                let (lat, lon) = cube::dir_to_latlon(d);
                let dl = crate::dem::wrap180(lon.to_degrees() - lon0_deg);
                Some((radius_m * dl.to_radians(), radius_m * lat))
            }
            MapCrs::PolarStereographic { north } => {
                if (north && d[2] < -0.985) || (!north && d[2] > 0.985) {
                    return None;
                }
                let g = GeoRef {
                    crs: self.dem_crs(radius_m)?,
                    x0: 0.0,
                    y0: 0.0,
                    dx: 1.0,
                    dy: 1.0,
                };
                Some(g.forward_dir(d, 0.0))
            }
            MapCrs::Gnomonic { lat0_deg, lon0_deg } => {
                let (c, e, n) = tangent_basis(lat0_deg, lon0_deg);
                let k = cube::dot(d, c);
                // Within about 84° of the centre: farther, the plane runs off to infinity.
                if k < 0.1 {
                    return None;
                }
                Some((
                    radius_m * cube::dot(d, e) / k,
                    radius_m * cube::dot(d, n) / k,
                ))
            }
        }
    }

    /// The DEM readers' CRS for the two projections they share.
    fn dem_crs(&self, radius_m: f64) -> Option<Crs> {
        match *self {
            MapCrs::Equirectangular { lon0_deg } => Some(Crs::Equirectangular {
                lat_ts_deg: 0.0,
                lon0_deg,
                radius_m,
            }),
            MapCrs::PolarStereographic { north } => Some(Crs::PolarStereographic {
                north,
                lon0_deg: 0.0,
                lat_ts_deg: if north { 90.0 } else { -90.0 },
                radius_m,
            }),
            MapCrs::Gnomonic { .. } => None,
        }
    }
}

/// The body's name as a CRS name shows it ("moon" → "Moon").
fn body_title(body: &str) -> String {
    let mut c = body.chars();
    match c.next() {
        Some(f) => f.to_uppercase().chain(c).collect(),
        None => "Body".into(),
    }
}

/// The centre direction and the east and north unit vectors of the tangent plane there (at a
/// pole, east and north as PROJ's polar gnomonic has them for `lon0_deg`).
fn tangent_basis(lat0_deg: f64, lon0_deg: f64) -> (Vec3, Vec3, Vec3) {
    let (sp, cp) = lat0_deg.to_radians().sin_cos();
    let (sl, cl) = lon0_deg.to_radians().sin_cos();
    (
        [cp * cl, cp * sl, sp],
        [-sl, cl, 0.0],
        [-sp * cl, -sp * sl, cp],
    )
}

/// The part of the body to export.
#[derive(Clone, Debug, PartialEq)]
pub enum Region {
    /// Every tile the tileset holds at the level.
    Coverage,
    /// A latitude/longitude box [lat0, lat1, lon0, lon1] in degrees (as `penumbra shadow
    /// --bbox`): the smallest grid of the CRS that contains it.
    Bbox([f64; 4]),
    /// One cube face whole: by default its gnomonic grid, pixel for pixel the level's tiles.
    Face(Face),
}

/// The sun of a `lit` export, given as `penumbra query shadow` takes it: at the same compass
/// azimuth and elevation above the local horizontal at every pixel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SunSpec {
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    /// The body's distance from the Sun (AU); None: the body preset's.
    pub distance_au: Option<f64>,
    /// The disc model (the shadow query's default is exact).
    pub model: Model,
}

/// What to export.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    pub product: ExportProduct,
    pub region: Region,
    /// Tile level to sample (None: the finest level holding the product).
    pub level: Option<u8>,
    /// The projection (None: gnomonic for a face, polar stereographic for a region within
    /// [`POLAR_CAP_DEG`] of a pole, else equirectangular).
    pub crs: Option<CrsKind>,
    /// The sun of a `lit` export (required for it, refused for the others).
    pub sun: Option<SunSpec>,
    /// Where `lit` and `horizon-mean` read horizons: the Fourier pyramids or the raw maps.
    pub from: HorizonSource,
    /// Refuse a raster above this many GiB of f32 samples.
    pub max_output_gib: f64,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            product: ExportProduct::Height,
            region: Region::Coverage,
            level: None,
            crs: None,
            sun: None,
            from: HorizonSource::Fourier,
            max_output_gib: DEFAULT_MAX_OUTPUT_GIB,
        }
    }
}

/// A product resampled onto a map grid, ready to be written.
#[derive(Clone, Debug, Serialize)]
pub struct Raster {
    pub product: ExportProduct,
    /// The tile level sampled.
    pub level: u8,
    pub width: usize,
    pub height: usize,
    pub crs: MapCrs,
    /// The body's name and reference radius (the CRS's sphere).
    pub body: String,
    pub radius_m: f64,
    /// GDAL's geotransform: x of the left edge, pixel width, 0, y of the top edge, 0, −pixel
    /// height (CRS metres).
    pub geo_transform: [f64; 6],
    /// Row-major samples, row 0 at the top; [`Raster::NODATA`] where the tileset has no data.
    #[serde(skip)]
    pub values: Vec<f32>,
    /// Pixels with a value.
    pub data_pixels: u64,
    /// Pixels without: outside the tileset's tiles or the projection, or a no-data height.
    pub nodata_pixels: u64,
    /// Of those, pixels of tiles recorded fully lit for higher suns only (their horizon is not
    /// kept), for `lit` and `horizon-mean`.
    pub unknown_pixels: u64,
    /// Smallest and largest value written (NaN when none).
    pub min: f64,
    pub max: f64,
    /// The sun of a `lit` export, and its apparent radius (degrees).
    pub sun: Option<SunSpec>,
    pub sun_radius_deg: Option<f64>,
    /// Where horizons were read (`fourier` or `raw`) for `lit` and `horizon-mean`.
    pub from: Option<String>,
}

impl Raster {
    /// The value of a pixel without data.
    pub const NODATA: f32 = f32::NAN;

    /// CRS coordinates of the centre of pixel (col, row).
    pub fn pixel_centre(&self, col: usize, row: usize) -> (f64, f64) {
        let g = &self.geo_transform;
        (
            g[0] + (col as f64 + 0.5) * g[1],
            g[3] + (row as f64 + 0.5) * g[5],
        )
    }
}

/// Checks an output path before anything is computed: its folder exists, and it is not a
/// folder itself.
pub fn check_out(out: &Path) -> Result<()> {
    if out.as_os_str().is_empty() || out.is_dir() {
        return Err(Error::param(
            "out",
            format!(
                "{} is a folder: give the GeoTIFF's file name",
                out.display()
            ),
        ));
    }
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        return Err(Error::param(
            "out",
            format!(
                "{}: its folder {} does not exist (create it first)",
                out.display(),
                parent.display()
            ),
        ));
    }
    Ok(())
}

/// Sample points of a region (directions), from which its CRS and extent are chosen.
fn region_points(store: &Store, region: &Region, level: u8, tiles: &BTreeSet<TileId>) -> Vec<Vec3> {
    let lay = store.manifest().layout;
    let k = 64usize;
    let f = |a: usize| a as f64 / k as f64;
    let mut pts = Vec::new();
    match region {
        Region::Bbox([lat0, lat1, lon0, lon1]) => {
            for a in 0..=k {
                for b in 0..=k {
                    let lat = lat0 + (lat1 - lat0) * f(a);
                    let lon = lon0 + (lon1 - lon0) * f(b);
                    pts.push(cube::latlon_to_dir(lat.to_radians(), lon.to_radians()));
                }
            }
        }
        Region::Face(face) => {
            for a in 0..=k {
                for b in 0..=k {
                    let (u, v) = (2.0 * f(a) - 1.0, 2.0 * f(b) - 1.0);
                    pts.push(cube::face_uv_to_dir(*face, u, v));
                }
            }
        }
        Region::Coverage => {
            let per = lay.tiles_per_side(level) as f64;
            for t in tiles.iter().filter(|t| t.level == level) {
                // 9×9 points a tile: at level 0 (a face a tile) about 11° apart.
                for a in 0..=8 {
                    for b in 0..=8 {
                        let s = -1.0 + 2.0 * (t.x as f64 + a as f64 / 8.0) / per;
                        let tt = 1.0 - 2.0 * (t.y as f64 + b as f64 / 8.0) / per;
                        pts.push(lay.st_to_dir(t.face, s, tt));
                    }
                }
            }
        }
    }
    pts
}

/// The centre of the smallest arc of longitudes (degrees) holding the region, and whether that
/// is the whole circle: a box's own longitudes; for sampled points, the circle less the largest
/// gap between them — unless that gap is under 30° (samples of a region that goes all round).
fn lon_arc(region: &Region, pts: &[Vec3]) -> (f64, bool) {
    if let Region::Bbox([_, _, lon0, lon1]) = region {
        return (
            crate::dem::wrap180((lon0 + lon1) / 2.0),
            lon1 - lon0 >= 360.0,
        );
    }
    let c = lon_centre(pts);
    (if c.is_nan() { 0.0 } else { c }, c.is_nan())
}

/// The centre of the smallest arc of longitudes (degrees) holding every point; NaN when the
/// largest gap between them is under 30° (all round).
fn lon_centre(pts: &[Vec3]) -> f64 {
    let mut lons: Vec<f64> = pts
        .iter()
        .filter(|d| d[2].abs() < 1.0 - 1e-12)
        .map(|d| cube::dir_to_latlon(*d).1.to_degrees())
        .collect();
    if lons.is_empty() {
        return 0.0;
    }
    lons.sort_by(f64::total_cmp);
    // The largest gap between neighbours (around the circle) is what the arc leaves out.
    let (mut gap, mut after) = (lons[0] + 360.0 - lons[lons.len() - 1], lons[0]);
    for w in lons.windows(2) {
        if w[1] - w[0] > gap {
            gap = w[1] - w[0];
            after = w[1];
        }
    }
    if gap < 30.0 {
        return f64::NAN;
    }
    let span = 360.0 - gap;
    let c = crate::dem::wrap180(after + span / 2.0);
    // A round number for the CRS when the region spans much, else to 1e-6° (so that the CRS
    // reads as 3, not 3.0000000000000004).
    if span > 90.0 {
        c.round()
    } else {
        (c * 1e6).round() / 1e6
    }
}

/// The CRS for a region's points.
fn choose_crs(kind: Option<CrsKind>, region: &Region, pts: &[Vec3]) -> Result<MapCrs> {
    let lat = |d: &Vec3| cube::dir_to_latlon(*d).0.to_degrees();
    let lo = pts.iter().map(lat).fold(f64::INFINITY, f64::min);
    let hi = pts.iter().map(lat).fold(f64::NEG_INFINITY, f64::max);
    let kind = match (kind, region) {
        (Some(k), _) => k,
        (None, Region::Face(_)) => CrsKind::Gnom,
        (None, _) if lo >= 90.0 - POLAR_CAP_DEG || hi <= -90.0 + POLAR_CAP_DEG => CrsKind::Stere,
        (None, _) => CrsKind::Eqc,
    };
    Ok(match kind {
        CrsKind::Eqc => MapCrs::Equirectangular {
            lon0_deg: lon_arc(region, pts).0,
        },
        CrsKind::Stere => MapCrs::PolarStereographic {
            north: lo + hi >= 0.0,
        },
        CrsKind::Gnom => match region {
            Region::Face(f) => {
                let (n, _, _) = f.axes();
                let (la, lo) = cube::dir_to_latlon(n);
                MapCrs::Gnomonic {
                    lat0_deg: la.to_degrees().round(),
                    lon0_deg: if n[2].abs() > 0.5 {
                        0.0
                    } else {
                        lo.to_degrees().round()
                    },
                }
            }
            _ => {
                let c = cube::normalize(pts.iter().fold([0.0; 3], |a, d| cube::add(a, *d)));
                let (la, lo) = cube::dir_to_latlon(c);
                let (la, lo) = (la.to_degrees(), lo.to_degrees());
                // Round the centre to 1e-6° so that the CRS reads as given.
                let r = |v: f64| (v * 1e6).round() / 1e6;
                MapCrs::Gnomonic {
                    lat0_deg: r(la),
                    lon0_deg: if la.abs() > 89.999999 { 0.0 } else { r(lo) },
                }
            }
        },
    })
}

/// The tile level to sample: the one asked, or the finest holding the product.
fn pick_level(store: &Store, opts: &ExportOptions) -> Result<u8> {
    let ts = store.manifest();
    let dir = store.dir();
    let held: Option<Vec<u8>> = match opts.product {
        ExportProduct::Height => None,
        _ => Some(match opts.from {
            HorizonSource::Fourier => ts
                .products
                .fourier
                .as_ref()
                .ok_or_else(|| {
                    store.missing(
                        "tileset has no Fourier pyramids, which lit and horizon-mean exports \
                         read: make them with `penumbra fourier` or `penumbra horizon \
                         --fourier` (or read the raw maps)",
                    )
                })?
                .levels
                .clone(),
            HorizonSource::Raw => ts
                .products
                .horizon
                .as_ref()
                .ok_or_else(|| {
                    store.missing(
                        "tileset has no raw horizon maps, which lit and horizon-mean exports \
                         read from raw: compute them with `penumbra horizon` (or read the \
                         Fourier pyramids)",
                    )
                })?
                .levels
                .clone(),
        }),
    };
    let finest = ts.layout.levels - 1;
    match (opts.level, held) {
        (Some(l), _) if l > finest => Err(Error::param(
            "level",
            format!(
                "{l} does not exist: {} has levels 0..={finest}",
                dir.display()
            ),
        )),
        (Some(l), Some(h)) if !h.contains(&l) => Err(Error::param(
            "level",
            format!(
                "{l} has no {} in {} (levels {h:?})",
                source_name(opts.from),
                dir.display()
            ),
        )),
        (Some(l), _) => Ok(l),
        (None, None) => Ok(finest),
        (None, Some(h)) => h.iter().max().copied().ok_or_else(|| {
            store.missing(&format!(
                "tileset has no {} at any level",
                source_name(opts.from)
            ))
        }),
    }
}

fn source_name(from: HorizonSource) -> &'static str {
    match from {
        HorizonSource::Fourier => "Fourier pyramids",
        HorizonSource::Raw => "raw horizon maps",
    }
}

/// Checks the options alone, before the tileset is read.
fn check_options(opts: &ExportOptions) -> Result<()> {
    if !(opts.max_output_gib.is_finite() && opts.max_output_gib > 0.0) {
        return Err(Error::param(
            "max_output_gib",
            format!("{} is not a positive size in GiB", opts.max_output_gib),
        ));
    }
    if let Region::Bbox(b) = &opts.region {
        crate::shadow::check_bbox(*b)?;
    }
    match (opts.product, &opts.sun) {
        (ExportProduct::Lit, None) => Err(Error::usage(
            "a lit export needs a sun: give its azimuth and elevation (as for the shadow query)",
        )),
        (ExportProduct::Lit, Some(s)) => {
            if !(s.azimuth_deg.is_finite() && (-360.0..=720.0).contains(&s.azimuth_deg)) {
                return Err(Error::param(
                    "sun_az",
                    format!("{} is not an azimuth in degrees (−360..720)", s.azimuth_deg),
                ));
            }
            if !(s.elevation_deg.is_finite() && (-90.0..=90.0).contains(&s.elevation_deg)) {
                return Err(Error::param(
                    "sun_el",
                    format!(
                        "{} is not an elevation in −90..=90 degrees",
                        s.elevation_deg
                    ),
                ));
            }
            if s.distance_au.is_some() {
                crate::fourier::stage::sun_distance(s.distance_au, "")?;
            }
            Ok(())
        }
        (p, Some(_)) => Err(Error::usage(format!(
            "a {} export takes no sun (only lit does)",
            p.name()
        ))),
        (_, None) => Ok(()),
    }
}

/// What a pixel of the output reads: the tile, and the fractional interior pixel.
type Source = Option<(TileId, f64, f64)>;

/// Resample `opts.product` of the tileset in `dir` onto a map grid. Refuses (before sampling)
/// a product or level the tileset lacks, a region without any of its tiles, a raster above
/// `max_output_gib`; and (after) a region where every pixel is no data.
pub fn render(dir: &Path, opts: &ExportOptions) -> Result<Raster> {
    check_options(opts)?;
    let store = Store::open(dir)?;
    let ts = store.manifest();
    let lay = ts.layout;
    let radius = ts.body.radius_m;
    let level = pick_level(&store, opts)?;
    let tiles: BTreeSet<TileId> = manifest::tiles_of(&ts.coverage)
        .into_iter()
        .filter(|t| t.level == level)
        .collect();
    if tiles.is_empty() {
        return Err(Error::usage(format!(
            "{} has no height tiles at level {level}",
            dir.display()
        )));
    }
    let pts = region_points(&store, &opts.region, level, &tiles);
    let crs = choose_crs(opts.crs, &opts.region, &pts)?;

    // The grid: the region's extent in the CRS, snapped outwards to whole pixels of the level's
    // face-centre size (a face: the face exactly, pixel for pixel).
    let (x0, y1, px, w, h) = match (&opts.region, crs) {
        (Region::Face(_), MapCrs::Gnomonic { .. }) => {
            let n = lay.face_pixels(level) as usize;
            (-radius, radius, 2.0 * radius / n as f64, n, n)
        }
        _ => {
            let mut xy = Vec::with_capacity(pts.len());
            for d in &pts {
                match crs.forward_dir(radius, *d) {
                    Some(p) => xy.push(p),
                    None => {
                        return Err(Error::usage(format!(
                            "the region reaches where the {} projection cannot show it: ask \
                             another CRS or a smaller region",
                            crs_name(&crs)
                        )))
                    }
                }
            }
            let px = lay.centre_pixel_m(level, radius);
            let (mut xmin, mut xmax, mut ymin, mut ymax) = (
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            );
            for (x, y) in xy {
                xmin = xmin.min(x);
                xmax = xmax.max(x);
                ymin = ymin.min(y);
                ymax = ymax.max(y);
            }
            // All round the body in equirectangular: the whole circle, whatever was sampled.
            if matches!(crs, MapCrs::Equirectangular { .. }) && lon_arc(&opts.region, &pts).1 {
                let half = std::f64::consts::PI * radius;
                (xmin, xmax) = (-half, half);
            }
            // Snapped to multiples of the pixel (a small tolerance keeps exact edges exact).
            let e = 1e-9;
            let (c0, c1) = ((xmin / px + e).floor(), (xmax / px - e).ceil());
            let (r0, r1) = ((ymin / px + e).floor(), (ymax / px - e).ceil());
            let (w, h) = ((c1 - c0).max(1.0), (r1 - r0).max(1.0));
            if w * h * 4.0 > opts.max_output_gib * (1u64 << 30) as f64 {
                return Err(Error::param(
                    "max_output_gib",
                    format!(
                        "the raster would be {w}×{h} pixels at level {level} ({:.2} GiB of \
                         f32), above {} GiB: ask a coarser level, a smaller region, or a \
                         larger cap",
                        w * h * 4.0 / (1u64 << 30) as f64,
                        opts.max_output_gib
                    ),
                ));
            }
            (c0 * px, r1 * px, px, w as usize, h as usize)
        }
    };
    if (w as f64) * (h as f64) * 4.0 > opts.max_output_gib * (1u64 << 30) as f64 {
        return Err(Error::param(
            "max_output_gib",
            format!(
                "the face is {w}×{h} pixels at level {level}, above {} GiB of f32: ask a \
                 coarser level or a larger cap",
                opts.max_output_gib
            ),
        ));
    }
    let geo_transform = [x0, px, 0.0, y1, 0.0, -px];

    // Sun and horizon source.
    let sun_radius = match &opts.sun {
        Some(s) => Some(sun::sun_radius_deg(crate::fourier::stage::sun_distance(
            s.distance_au,
            &ts.body.name,
        )?)),
        None => None,
    };

    let mut raster = Raster {
        product: opts.product,
        level,
        width: w,
        height: h,
        crs,
        body: ts.body.name.clone(),
        radius_m: radius,
        geo_transform,
        values: vec![Raster::NODATA; w * h],
        data_pixels: 0,
        nodata_pixels: 0,
        unknown_pixels: 0,
        min: f64::NAN,
        max: f64::NAN,
        sun: opts.sun,
        sun_radius_deg: sun_radius,
        from: (opts.product != ExportProduct::Height).then(|| {
            match opts.from {
                HorizonSource::Fourier => "fourier",
                HorizonSource::Raw => "raw",
            }
            .to_string()
        }),
    };

    // Bands of rows: locate every pixel, then sample each tile the band touches once.
    let band = 128usize;
    let mut unknown = 0u64;
    for r0 in (0..h).step_by(band) {
        let r1 = (r0 + band).min(h);
        let src: Vec<Source> = (r0 * w..r1 * w)
            .into_par_iter()
            .map(|p| {
                let (c, r) = (p % w, p / w);
                let x = x0 + (c as f64 + 0.5) * px;
                let y = y1 - (r as f64 + 0.5) * px;
                let d = crs.inverse_dir(radius, x, y)?;
                let loc = lay.locate(level, d);
                tiles
                    .contains(&loc.tile)
                    .then_some((loc.tile, loc.px, loc.py))
            })
            .collect();
        let mut by_tile: HashMap<TileId, Vec<usize>> = HashMap::new();
        for (k, s) in src.iter().enumerate() {
            if let Some((t, _, _)) = s {
                by_tile.entry(*t).or_default().push(k);
            }
        }
        let mut groups: Vec<(TileId, Vec<usize>)> = by_tile.into_iter().collect();
        groups.sort_by_key(|g| g.0);
        let sampled: Vec<Vec<(usize, f32, bool)>> = groups
            .par_iter()
            .map(|(tile, ks)| sample_tile(&store, opts, *tile, ks, &src, sun_radius))
            .collect::<Result<_>>()?;
        let out = &mut raster.values[r0 * w..r1 * w];
        for g in sampled {
            for (k, v, unk) in g {
                out[k] = v;
                unknown += unk as u64;
            }
        }
    }
    let (mut lo, mut hi, mut n) = (f64::INFINITY, f64::NEG_INFINITY, 0u64);
    for &v in &raster.values {
        if !v.is_nan() {
            n += 1;
            lo = lo.min(v as f64);
            hi = hi.max(v as f64);
        }
    }
    raster.data_pixels = n;
    raster.nodata_pixels = (w * h) as u64 - n;
    raster.unknown_pixels = unknown;
    if n > 0 {
        raster.min = lo;
        raster.max = hi;
    } else {
        let what = match &opts.region {
            Region::Bbox(b) => format!("the box {b:?}"),
            Region::Face(f) => format!("face {}", f.name()),
            Region::Coverage => "the tileset's coverage".into(),
        };
        return Err(Error::usage(format!(
            "{what} holds no data of {} at level {level}{}: `penumbra info {}` lists the \
             coverage",
            opts.product.name(),
            if unknown > 0 {
                " (its tiles keep no horizon for this sun)"
            } else {
                ""
            },
            dir.display()
        )));
    }
    Ok(raster)
}

fn crs_name(c: &MapCrs) -> &'static str {
    match c {
        MapCrs::Equirectangular { .. } => "equirectangular",
        MapCrs::PolarStereographic { .. } => "polar stereographic",
        MapCrs::Gnomonic { .. } => "gnomonic",
    }
}

/// The values of the pixels `ks` (indices into `src`) that read `tile`: (index, value,
/// unknown: no horizon kept for this sun).
fn sample_tile(
    store: &Store,
    opts: &ExportOptions,
    tile: TileId,
    ks: &[usize],
    src: &[Source],
    sun_radius: Option<f64>,
) -> Result<Vec<(usize, f32, bool)>> {
    let ts = store.manifest();
    let lay = ts.layout;
    let n = lay.tile_size as usize;
    let halo = lay.halo as f64;
    let t: Arc<crate::format::height::HeightTile> = match store.height(tile)? {
        Some(t) => t,
        None => return Ok(Vec::new()),
    };
    let at = |k: usize| {
        let (_, px, py) = src[k].expect("grouped by tile");
        (px, py)
    };
    if opts.product == ExportProduct::Height {
        // As `query::height`: bilinear at the fractional stored pixel.
        return Ok(ks
            .iter()
            .map(|&k| {
                let (px, py) = at(k);
                (k, t.bilinear(px + halo, py + halo), false)
            })
            .collect());
    }
    // The tile pixel containing the point (as the horizon and shadow queries locate it), and
    // its own height: no data there is no data here.
    let h = lay.halo as usize;
    let pixel = |k: usize| -> Option<(usize, usize, f32)> {
        let (px, py) = at(k);
        let i = (px.round().max(0.0) as usize).min(n - 1);
        let j = (py.round().max(0.0) as usize).min(n - 1);
        let z = t.height[(j + h) * t.size + i + h];
        (!z.is_nan()).then_some((i, j, z))
    };
    // A tile recorded fully lit: lit for a sun above its threshold, unknown otherwise.
    let rec = crate::shadow::recorded_lit(store, tile, Some(opts.from))?;
    let lit_sun =
        |s: &SunSpec| rec.is_some_and(|r| r.lights(s.elevation_deg, sun_radius.unwrap_or(0.0)));
    if rec.is_some() {
        let lit = opts.product == ExportProduct::Lit && opts.sun.as_ref().is_some_and(lit_sun);
        return Ok(ks
            .iter()
            .filter_map(|&k| pixel(k).map(|_| k))
            .map(|k| {
                if lit {
                    (k, 1.0, false)
                } else {
                    (k, Raster::NODATA, true)
                }
            })
            .collect());
    }
    enum Horizons {
        Fourier(crate::fourier::Pyramid),
        Raw(Vec<f32>, usize),
    }
    let hz = match opts.from {
        HorizonSource::Fourier => {
            let p: crate::fourier::Pyramid = store.fourier(tile)?;
            if p.fully_lit {
                return Ok(ks
                    .iter()
                    .filter_map(|&k| pixel(k).map(|_| (k, Raster::NODATA, true)))
                    .collect());
            }
            Horizons::Fourier(p)
        }
        HorizonSource::Raw => {
            let a = ts.products.horizon.as_ref().map_or(0, |h| h.azimuths);
            Horizons::Raw(store.horizon(tile)?, a)
        }
    };
    let mut out = Vec::with_capacity(ks.len());
    let mut c = Vec::new();
    for &k in ks {
        let Some((i, j, z)) = pixel(k) else { continue };
        let prof = match &hz {
            Horizons::Fourier(p) => {
                p.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, &mut c);
                Profile::Series(c.clone())
            }
            Horizons::Raw(planes, a) => {
                Profile::Samples((0..*a).map(|q| planes[q * n * n + j * n + i]).collect())
            }
        };
        let v = match (opts.product, &opts.sun) {
            (ExportProduct::Lit, Some(s)) => {
                let mut prof = prof;
                if let Profile::Samples(e) = &mut prof {
                    floor_samples(ts, z, e);
                }
                let (frame, sun) = sun_at_pixel(
                    &lay,
                    tile,
                    (i, j),
                    (s.azimuth_deg, s.elevation_deg),
                    sun_radius.unwrap_or(0.0),
                );
                prof.lit(&frame, &sun, s.model)
            }
            _ => match &prof {
                Profile::Series(c) => c.first().map_or(f64::NAN, |c0| c0[0]),
                Profile::Samples(e) => {
                    e.iter().map(|&v| v as f64).sum::<f64>() / e.len().max(1) as f64
                }
            },
        };
        out.push((k, v as f32, false));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The inverse projections undo the forward ones, and the gnomonic grid of a face is the
    /// face's own (u, v) plane.
    #[test]
    fn projections_round_trip() {
        let r = 1_737_400.0;
        let crss = [
            MapCrs::Equirectangular { lon0_deg: 170.0 },
            MapCrs::PolarStereographic { north: true },
            MapCrs::PolarStereographic { north: false },
            MapCrs::Gnomonic {
                lat0_deg: -90.0,
                lon0_deg: 0.0,
            },
            MapCrs::Gnomonic {
                lat0_deg: 20.0,
                lon0_deg: -33.0,
            },
        ];
        let mut rnd = crate::testutil::rng(7);
        for crs in crss {
            for _ in 0..200 {
                let d = cube::normalize([rnd() - 0.5, rnd() - 0.5, rnd() - 0.5]);
                let Some((x, y)) = crs.forward_dir(r, d) else {
                    continue;
                };
                let e = crs.inverse_dir(r, x, y).unwrap();
                assert!(cube::angle_between(d, e) < 1e-12, "{crs:?} {d:?} {e:?}");
            }
        }
        for f in 0..6 {
            let face = Face::from_index(f).unwrap();
            let (n, _, _) = face.axes();
            let region = Region::Face(face);
            let crs = choose_crs(None, &region, &[n]).unwrap();
            for (u, v) in [(0.3, -0.7), (-1.0, 1.0), (0.0, 0.0)] {
                let d = crs.inverse_dir(r, u * r, v * r).unwrap();
                let e = cube::face_uv_to_dir(face, u, v);
                assert!(cube::angle_between(d, e) < 1e-12, "face {f}: {d:?} {e:?}");
            }
        }
    }

    #[test]
    fn crs_text_carries_the_sphere() {
        let c = MapCrs::PolarStereographic { north: false };
        assert!(c.proj4(1_737_400.0).contains("+R=1737400 "));
        let w = c.wkt("moon", 1_737_400.0);
        assert!(
            w.contains("SPHEROID[\"Moon\",1737400,0]") && w.contains("D_Moon"),
            "{w}"
        );
        assert_eq!(
            lon_centre(&[cube::latlon_to_dir(0.0, 3.0f64.to_radians())]),
            3.0
        );
        let across = [170.0f64, -170.0].map(|l| cube::latlon_to_dir(0.0, l.to_radians()));
        assert!((lon_centre(&across).abs() - 180.0).abs() < 1e-9);
        let round: Vec<Vec3> = (0..36)
            .map(|k| cube::latlon_to_dir(0.0, (10.0 * k as f64).to_radians()))
            .collect();
        assert!(lon_arc(&Region::Coverage, &round).1);
        assert_eq!(
            lon_arc(&Region::Bbox([0.0, 1.0, 170.0, 200.0]), &round),
            (-175.0, false)
        );
    }
}
