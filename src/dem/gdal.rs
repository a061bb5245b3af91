//! Any raster GDAL opens (ISIS cubes, PDS3/PDS4, JPEG 2000, VRT mosaics, GeoTIFFs …) as a DEM
//! (`--features gdal`; chosen with `format = "gdal"` in a scene source or `--dem-format gdal`,
//! and the fallback for extensions no native reader knows). docs/formats.md, "GDAL input".
//!
//! What is read, through GDAL:
//! - band 1 as f32 (a raster of several bands is refused: a DEM has one), its no-data value,
//!   scale and offset (height = DN·scale + offset; an offset above 100 km is the radius of
//!   the reference sphere, as the PDS3 reader reads LOLA's `OFFSET`);
//! - the geotransform (north-up, not rotated): the centre of pixel (0, 0) half a pixel in from
//!   its corner;
//! - the CRS: geographic (degrees), equirectangular (`eqc`) or polar stereographic (`stere` on
//!   a pole), on a sphere or an ellipsoid; a projected CRS must be on a sphere (a flattened
//!   ellipsoid would need geodetic latitudes Penumbra does not model). The ellipsoid's
//!   semi-major axis names the body when it is within 0.5 % of a body preset's radius (WGS 84 →
//!   earth, the IAU Moon sphere → moon), so that a DEM of one body is refused for another;
//! - an equirectangular raster all round the body is read in degrees (geographic), as the
//!   native PDS3 reader reads such grids: its columns wrap across the antimeridian;
//! - the files GDAL read (a VRT's sources, a label's data file), hashed into the manifest.

use std::ffi::CStr;
use std::path::{Path, PathBuf};

use gdal::raster::GdalDataType;
use gdal::spatial_ref::SpatialRef;
use gdal::Dataset;

use crate::body::Body;
use crate::dem::limits;
use crate::dem::types::{check_dimensions, Crs, DemParts, GeoRef, Samples};
use crate::error::{Error, Result};

/// An offset above this (metres) is a reference radius, not a height offset.
const RADIUS_OFFSET_M: f64 = 100_000.0;

/// A semi-major axis within this fraction of a body preset's radius names that body.
const BODY_MATCH: f64 = 0.005;

/// Read `path` through GDAL.
pub fn read(path: &Path) -> Result<DemParts> {
    read_or(path, |e| {
        Error::unsupported(path, format!("GDAL cannot open it as a raster: {e}"))
    })
}

/// [`read`], with `cannot_open` making the error where GDAL cannot open the file at all.
pub fn read_or(
    path: &Path,
    cannot_open: impl FnOnce(gdal::errors::GdalError) -> Error,
) -> Result<DemParts> {
    let ds = Dataset::open(path).map_err(cannot_open)?;
    let (w, h) = ds.raster_size();
    check_dimensions(path, w as u64, h as u64)?;
    match ds.raster_count() {
        1 => {}
        0 => return Err(Error::invalid(path, "GDAL finds no raster band in it")),
        n => {
            return Err(Error::unsupported(
                path,
                format!("it has {n} bands: a DEM has one band of heights (extract it first, e.g. gdal_translate -b 1)"),
            ))
        }
    }
    let band = ds
        .rasterband(1)
        .map_err(|e| Error::invalid(path, format!("GDAL cannot open its band: {e}")))?;
    let ty = band.band_type();
    if matches!(ty, GdalDataType::Unknown) {
        return Err(Error::unsupported(
            path,
            "its band has a sample type GDAL does not name",
        ));
    }
    let gt = ds.geo_transform().map_err(|_| {
        Error::invalid(
            path,
            "GDAL finds no geotransform: the raster cannot be placed on the body",
        )
    })?;
    if gt[2] != 0.0 || gt[4] != 0.0 {
        return Err(Error::unsupported(
            path,
            "its geotransform rotates the raster: warp it to a north-up grid (gdalwarp)",
        ));
    }
    let usable = gt[1].is_finite()
        && gt[1] > 0.0
        && gt[5].is_finite()
        && gt[5] != 0.0
        && gt[0].is_finite()
        && gt[3].is_finite();
    if !usable {
        return Err(Error::invalid(
            path,
            format!("geotransform {gt:?} is not usable: finite, pixel width > 0, height ≠ 0"),
        ));
    }
    let srs = ds.spatial_ref().map_err(|_| {
        Error::invalid(
            path,
            "GDAL finds no CRS: the raster cannot be placed on the body",
        )
    })?;
    let (crs, target, crs_desc) = crs_of(path, &srs)?;
    let (dx, dy) = (gt[1], -gt[5]);
    match &crs {
        Crs::Geographic => {
            limits::pixel_deg(path, "geotransform x pixel size", dx)?;
            limits::pixel_deg(path, "geotransform y pixel size", dy.abs())?;
        }
        Crs::Equirectangular { radius_m, .. } | Crs::PolarStereographic { radius_m, .. } => {
            limits::pixel_m(path, "geotransform x pixel size", dx, Some(*radius_m))?;
            limits::pixel_m(path, "geotransform y pixel size", dy.abs(), Some(*radius_m))?;
        }
    }
    let mut georef = GeoRef {
        crs,
        x0: gt[0] + 0.5 * gt[1],
        y0: gt[3] + 0.5 * gt[5],
        dx,
        dy,
    };
    // An equirectangular raster all round the body (w pixels spanning the circle at its true-
    // scale latitude to 1% of a pixel) is read in degrees, as the native PDS3 reader reads
    // LDEM-style grids: its columns then wrap across the antimeridian (a projected grid does
    // not), and a label's rounded MAP_SCALE (LDEM_4: 7580.84 for 7580.8398… m, which GDAL's
    // PDS driver takes) no longer shifts the far columns. Metres become degrees by the factor
    // that makes the span exactly 360°.
    if let Crs::Equirectangular {
        lat_ts_deg,
        lon0_deg,
        radius_m,
    } = georef.crs
    {
        let circle = std::f64::consts::TAU * radius_m * lat_ts_deg.to_radians().cos();
        let span = dx * w as f64;
        if (span - circle).abs() < 0.01 * dx {
            let deg_x = 360.0 / span;
            let deg_y = deg_x * lat_ts_deg.to_radians().cos();
            georef = GeoRef {
                crs: Crs::Geographic,
                x0: lon0_deg + georef.x0 * deg_x,
                y0: georef.y0 * deg_y,
                dx: 360.0 / w as f64,
                // Pole to pole, too: exactly 180° (as rounded as the width).
                dy: if (dy * deg_y * h as f64 - 180.0).abs() < 0.01 * dy * deg_y {
                    180.0 / h as f64
                } else {
                    dy * deg_y
                },
            };
        }
    }
    limits::check_georef(path, &georef, w, h, "the GDAL geotransform")?;

    let scale = band.scale().unwrap_or(1.0);
    let mut offset = band.offset().unwrap_or(0.0);
    if !(scale.is_finite() && scale != 0.0 && offset.is_finite()) {
        return Err(Error::invalid(
            path,
            format!("band scale {scale} / offset {offset} are not usable (finite, scale ≠ 0)"),
        ));
    }
    let mut datum_radius_m = None;
    if offset.abs() > RADIUS_OFFSET_M {
        datum_radius_m = Some(offset);
        offset = 0.0;
    }
    let nodata = band
        .no_data_value()
        .filter(|v| !v.is_nan())
        .map(|v| v as f32 as f64);
    let buf = band
        .read_as::<f32>((0, 0), (w, h), (w, h), None)
        .map_err(|e| Error::invalid(path, format!("GDAL cannot read its samples: {e}")))?;
    let (_, samples) = buf.into_shape_and_vec();
    let driver = ds.driver().short_name();
    let mut sources = file_list(&ds);
    if sources.is_empty() {
        sources.push(path.to_path_buf());
    }
    Ok(DemParts {
        width: w,
        height: h,
        samples: Samples::Owned(samples),
        scale,
        offset,
        nodata,
        georef,
        datum_radius_m,
        target,
        sources,
        format: format!("GDAL {driver} {}, {crs_desc}", ty.name()),
    })
}

/// The files GDAL read for the dataset (the one opened first).
fn file_list(ds: &Dataset) -> Vec<PathBuf> {
    let mut out = Vec::new();
    // SAFETY: GDALGetFileList returns a NULL-terminated list of C strings owned by the caller
    // (freed with CSLDestroy), or NULL; the dataset handle is live for the call.
    unsafe {
        let list = gdal_sys::GDALGetFileList(ds.c_dataset());
        if list.is_null() {
            return out;
        }
        let mut k = 0;
        while !(*list.add(k)).is_null() {
            let s = CStr::from_ptr(*list.add(k)).to_string_lossy().into_owned();
            out.push(PathBuf::from(s));
            k += 1;
        }
        gdal_sys::CSLDestroy(list);
    }
    out
}

/// The body preset whose radius the semi-major axis `a` is, if any.
fn body_of_radius(a: f64) -> Option<String> {
    Body::preset_names()
        .into_iter()
        .filter_map(|n| Body::preset(n).ok())
        .find(|b| ((a - b.radius_m) / b.radius_m).abs() <= BODY_MATCH)
        .map(|b| b.name)
}

/// The CRS of a GDAL spatial reference, the body its ellipsoid names, and a description.
fn crs_of(path: &Path, srs: &SpatialRef) -> Result<(Crs, Option<String>, String)> {
    let a = srs
        .semi_major()
        .map_err(|e| Error::invalid(path, format!("its CRS has no ellipsoid: {e}")))?;
    let b = srs.semi_minor().unwrap_or(a);
    if !(a.is_finite() && a > 0.0 && b.is_finite() && b > 0.0) {
        return Err(Error::invalid(
            path,
            format!("its CRS's ellipsoid ({a}, {b} m) is not usable"),
        ));
    }
    let flat = 1.0 - b / a;
    let target = body_of_radius(a);
    let on = match &target {
        Some(t) => format!(
            "on {t}'s {}",
            if flat > 1e-9 { "ellipsoid" } else { "sphere" }
        ),
        None => format!("on a sphere of {a} m"),
    };
    if srs.is_geographic() {
        let unit = srs.angular_units();
        if (unit - 1f64.to_radians()).abs() > 1e-12 {
            return Err(Error::unsupported(
                path,
                format!("its geographic CRS counts angles in units of {unit} rad: only degrees are read"),
            ));
        }
        return Ok((Crs::Geographic, target, format!("geographic {on}")));
    }
    if !srs.is_projected() {
        return Err(Error::unsupported(
            path,
            "its CRS is neither geographic nor projected (a local or compound CRS)",
        ));
    }
    let proj4 = srs
        .to_proj4()
        .map_err(|e| Error::unsupported(path, format!("GDAL cannot state its CRS as PROJ: {e}")))?;
    if flat > 1e-9 {
        return Err(Error::unsupported(
            path,
            format!(
                "its projected CRS is on a flattened ellipsoid ({proj4}): Penumbra projects on a \
                 sphere; reproject it onto the body's sphere (gdalwarp -t_srs with +R=)"
            ),
        ));
    }
    let units = srs.linear_units();
    if (units - 1.0).abs() > 1e-12 {
        return Err(Error::unsupported(
            path,
            format!("its CRS counts in units of {units} m: only metres are read"),
        ));
    }
    let p = Proj4::parse(&proj4);
    let num = |k: &str, d: f64| p.num(k).unwrap_or(d);
    if num("x_0", 0.0) != 0.0 || num("y_0", 0.0) != 0.0 {
        return Err(Error::unsupported(
            path,
            format!("its CRS has a false easting/northing ({proj4}): reproject it without one"),
        ));
    }
    let crs = match p.get("proj") {
        Some("eqc") => {
            if num("lat_0", 0.0) != 0.0 {
                return Err(Error::unsupported(
                    path,
                    format!("its equirectangular CRS has an origin latitude ({proj4}): only lat_0=0 is read"),
                ));
            }
            Crs::Equirectangular {
                lat_ts_deg: num("lat_ts", 0.0),
                lon0_deg: num("lon_0", 0.0),
                radius_m: a,
            }
        }
        Some("stere") | Some("ups") if num("lat_0", 0.0).abs() == 90.0 => {
            let lat0 = num("lat_0", 0.0);
            let lat_ts = match (p.num("lat_ts"), p.num("k").or(p.num("k_0"))) {
                (Some(t), _) => t,
                // sin |φts| = 2k₀ − 1 (k₀ = 1: true scale at the pole).
                (None, Some(k)) => {
                    lat0.signum() * (2.0 * k - 1.0).clamp(-1.0, 1.0).asin().to_degrees()
                }
                (None, None) => lat0,
            };
            Crs::PolarStereographic {
                north: lat0 > 0.0,
                lon0_deg: num("lon_0", 0.0),
                lat_ts_deg: lat_ts,
                radius_m: a,
            }
        }
        _ => {
            return Err(Error::unsupported(
                path,
                format!(
                    "its CRS ({proj4}) is none Penumbra reads: geographic, equirectangular (eqc) \
                     or polar stereographic (stere on a pole); warp it to one (gdalwarp -t_srs)"
                ),
            ))
        }
    };
    let desc = match &crs {
        Crs::Equirectangular { lat_ts_deg, .. } => {
            format!("equirectangular true scale at {lat_ts_deg}° {on}")
        }
        Crs::PolarStereographic {
            north, lat_ts_deg, ..
        } => format!(
            "polar stereographic ({} pole, true scale at {lat_ts_deg}°) {on}",
            if *north { "north" } else { "south" }
        ),
        Crs::Geographic => unreachable!(),
    };
    Ok((crs, target, desc))
}

/// The `+key=value` terms of a PROJ string.
struct Proj4(Vec<(String, String)>);

impl Proj4 {
    fn parse(s: &str) -> Proj4 {
        Proj4(
            s.split_whitespace()
                .filter_map(|t| t.strip_prefix('+'))
                .map(|t| match t.split_once('=') {
                    Some((k, v)) => (k.to_string(), v.to_string()),
                    None => (t.to_string(), String::new()),
                })
                .collect(),
        )
    }
    fn get(&self, k: &str) -> Option<&str> {
        self.0.iter().find(|(a, _)| a == k).map(|(_, v)| v.as_str())
    }
    fn num(&self, k: &str) -> Option<f64> {
        self.get(k).and_then(|v| v.parse().ok())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn proj4_terms() {
        let p = Proj4::parse("+proj=stere +lat_0=-90 +k=1 +R=1737400 +units=m +no_defs");
        assert_eq!(p.get("proj"), Some("stere"));
        assert_eq!(p.num("lat_0"), Some(-90.0));
        assert_eq!(p.get("no_defs"), Some(""));
        assert_eq!(body_of_radius(6_378_137.0).as_deref(), Some("earth"));
        assert_eq!(body_of_radius(1_737_400.0).as_deref(), Some("moon"));
        assert_eq!(body_of_radius(1_000.0), None);
    }
}
