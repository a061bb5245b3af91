//! Plausibility limits on the georeferencing and scaling keys of DEM files.
//!
//! Every reader range-checks each key where it parses it (so the message names the key), and
//! [`check_georef`] checks the grid a reader built as a whole (pixel centres on the sphere,
//! spacing, CRS parameters). The limits are body-independent: they only refuse values that no
//! body from 1 m to 1e9 m in radius could make sense of. [`crate::dem::Dem::check_plausible`]
//! adds the checks that need the body. The table of limits is in docs/formats.md
//! ("Plausibility limits"); keep both in step.

use std::f64::consts::PI;
use std::path::Path;

use crate::dem::types::{Crs, GeoRef, SampleType};
use crate::error::{Error, Result};

/// Latitudes (degrees) lie within ±this.
pub const MAX_LAT_DEG: f64 = 90.0;
/// Longitudes (degrees) lie within `MIN_LON_DEG ..= MAX_LON_DEG`: any of the usual
/// conventions (−180..180, 0..360) and a raster starting up to a turn before or after them.
pub const MIN_LON_DEG: f64 = -360.0;
pub const MAX_LON_DEG: f64 = 720.0;
/// Sphere radii (datum, projection sphere): the same range `--radius-m` accepts.
pub const MIN_RADIUS_M: f64 = 1.0;
pub const MAX_RADIUS_M: f64 = 1.0e9;
/// Smallest pixel in metres: below a millimetre a DEM is a mistake (a unit or an exponent off).
pub const MIN_PIXEL_M: f64 = 1.0e-3;
/// Smallest geographic pixel in degrees: 1 mm on the largest sphere accepted (≈ 5.7e-11°).
pub const MIN_PIXEL_DEG: f64 = MIN_PIXEL_M / MAX_RADIUS_M * 180.0 / PI;
/// Largest geographic pixel in degrees: one pixel cannot be wider than a turn.
pub const MAX_PIXEL_DEG: f64 = 360.0;
/// |scale| (metres per DN) lies within `MIN_SCALE ..= MAX_SCALE`.
pub const MIN_SCALE: f64 = 1.0e-9;
pub const MAX_SCALE: f64 = 1.0e9;
/// |offset| (metres) is at most the largest radius accepted.
pub const MAX_OFFSET_M: f64 = MAX_RADIUS_M;
/// A polar stereographic grid may reach this far from its pole (degrees of colatitude, 60°
/// into the other hemisphere; the scale there is already 15× the scale at the pole).
pub const MAX_POLAR_COLAT_DEG: f64 = 150.0;
/// An equirectangular true-scale latitude must leave a usable longitude scale.
pub const MAX_LAT_TS_DEG: f64 = 89.0;
/// Pixels may be at most this many times longer than wide (or wider than long) on the ground;
/// a geographic raster passes when either its spacing in degrees or its pixels at its latitude
/// nearest the equator are within this ratio (rasters square in degrees near a pole, and
/// rasters square on the ground at high latitude, both pass). Beyond it the spacing keys
/// contradict each other (a 57:1 GeoTIFF pixel scale).
pub const MAX_PIXEL_ASPECT: f64 = 10.0;
/// Relative slack on comparisons of grid positions with the limits (rounding in the files).
const SLACK: f64 = 1e-9;

const SEE: &str = "see docs/formats.md, \"Plausibility limits\"";

/// A number as people read it: plain, or in exponent form when very large or small.
pub fn show(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

fn bad(path: &Path, field: &str, v: f64, what: &str) -> Error {
    Error::invalid(path, format!("{field} = {} {what} ({SEE})", show(v)))
}

/// A latitude in degrees: finite and within ±90.
pub fn latitude(path: &Path, field: &str, v: f64) -> Result<f64> {
    if !(v.is_finite() && v.abs() <= MAX_LAT_DEG * (1.0 + SLACK)) {
        return Err(bad(
            path,
            field,
            v,
            "is not a latitude: it must lie within −90..90 degrees",
        ));
    }
    Ok(v)
}

/// A longitude in degrees: finite and within −360..720.
pub fn longitude(path: &Path, field: &str, v: f64) -> Result<f64> {
    if !(v.is_finite() && (MIN_LON_DEG..=MAX_LON_DEG).contains(&v)) {
        return Err(bad(
            path,
            field,
            v,
            "is not a longitude: give east longitudes within −360..720 degrees (−180..180 or \
             0..360 as usual)",
        ));
    }
    Ok(v)
}

/// A sphere radius in metres: finite and within 1 m .. 1e9 m.
pub fn radius(path: &Path, field: &str, v: f64) -> Result<f64> {
    if !(v.is_finite() && (MIN_RADIUS_M..=MAX_RADIUS_M).contains(&v)) {
        return Err(bad(
            path,
            field,
            v,
            "m is not a sphere radius: it must lie within 1 m .. 1e9 m (check the sign and the \
             unit: km given as m, or m as km)",
        ));
    }
    Ok(v)
}

/// A geographic pixel spacing in degrees: finite and within 5.7e-11° (1 mm on the largest
/// sphere) .. 360°.
pub fn pixel_deg(path: &Path, field: &str, v: f64) -> Result<f64> {
    if !(v.is_finite() && (MIN_PIXEL_DEG..=MAX_PIXEL_DEG).contains(&v.abs())) {
        return Err(bad(
            path,
            field,
            v,
            &format!(
                "degrees is not a pixel spacing: it must lie within {MIN_PIXEL_DEG:.1e} .. 360 \
                 degrees (1 mm on the largest body .. one turn)"
            ),
        ));
    }
    Ok(v)
}

/// A projected pixel size in metres: finite and within 1 mm .. the circumference of the
/// projection's sphere (`radius_m`, or the largest radius accepted when unknown).
pub fn pixel_m(path: &Path, field: &str, v: f64, radius_m: Option<f64>) -> Result<f64> {
    let max = 2.0 * PI * radius_m.unwrap_or(MAX_RADIUS_M);
    if !(v.is_finite() && (MIN_PIXEL_M..=max).contains(&v.abs())) {
        return Err(bad(
            path,
            field,
            v,
            &format!(
                "m is not a pixel size: it must lie within 1 mm .. {} m (the circumference of \
                 the sphere)",
                show(max)
            ),
        ));
    }
    Ok(v)
}

/// Any finite number (positions whose range is checked once the grid is built).
pub fn finite(path: &Path, field: &str, v: f64) -> Result<f64> {
    if !v.is_finite() {
        return Err(bad(path, field, v, "is not a finite number"));
    }
    Ok(v)
}

/// Largest |DN| a sample type holds; float samples count up to f32::MAX (heights are kept as
/// f32, so a larger float DN could never become a height).
pub fn max_dn(ty: SampleType) -> f64 {
    match ty {
        SampleType::U8 => u8::MAX as f64,
        SampleType::I16 => 32768.0,
        SampleType::U16 => u16::MAX as f64,
        SampleType::I32 => 2_147_483_648.0,
        SampleType::U32 => u32::MAX as f64,
        SampleType::F32 | SampleType::F64 => f32::MAX as f64,
    }
}

/// `height = DN · scale + offset`: scale finite, nonzero, 1e-9 ≤ |scale| ≤ 1e9 m per DN with
/// |scale · largest DN| finite; |offset| ≤ 1e9 m. `ty` is the sample type (float when unknown).
pub fn scale_offset(
    path: &Path,
    (scale_field, scale): (&str, f64),
    (offset_field, offset): (&str, f64),
    ty: Option<SampleType>,
) -> Result<()> {
    if !(scale.is_finite() && (MIN_SCALE..=MAX_SCALE).contains(&scale.abs())) {
        return Err(bad(
            path,
            scale_field,
            scale,
            "is not a usable scale: heights are DN × scale metres, and |scale| must lie within \
             1e-9 .. 1e9 m per DN (check the unit and the exponent)",
        ));
    }
    if scale < 0.0 {
        return Err(bad(
            path,
            scale_field,
            scale,
            "is negative: it would turn the terrain upside down (peaks into pits). Heights \
             are DN × scale + offset metres, up positive; give a positive scale",
        ));
    }
    let top = scale.abs() * max_dn(ty.unwrap_or(SampleType::F32));
    if !top.is_finite() {
        return Err(bad(
            path,
            scale_field,
            scale,
            "overflows: the largest sample would be an infinite height",
        ));
    }
    if !(offset.is_finite() && offset.abs() <= MAX_OFFSET_M) {
        return Err(bad(
            path,
            offset_field,
            offset,
            "m is not a usable height offset: it must lie within ±1e9 m",
        ));
    }
    Ok(())
}

/// The grid a reader built, as a whole: spacing, CRS parameters, and every pixel centre on
/// the sphere (latitudes within ±90, a geographic raster at most a turn wide, a polar
/// stereographic one within 150° of its pole). `keys` names what placed the grid, for the
/// message.
pub fn check_georef(path: &Path, g: &GeoRef, w: usize, h: usize, keys: &str) -> Result<()> {
    let placed = |what: String| {
        Error::invalid(
            path,
            format!("the grid placed by {keys} {what}: fix the georeferencing ({SEE})"),
        )
    };
    for (name, v) in [("x0", g.x0), ("y0", g.y0), ("dx", g.dx), ("dy", g.dy)] {
        if !v.is_finite() {
            return Err(placed(format!("has a non-finite {name} ({v})")));
        }
    }
    if !(g.dx > 0.0 && g.dy != 0.0) {
        return Err(placed(format!(
            "has pixel spacing ({}, {}): it must be dx > 0 and dy ≠ 0",
            show(g.dx),
            show(g.dy)
        )));
    }
    let (w1, h1) = ((w.max(1) - 1) as f64, (h.max(1) - 1) as f64);
    let y_first = g.y0;
    let y_last = g.y0 - h1 * g.dy;
    let x_last = g.x0 + w1 * g.dx;
    // Latitudes of the first and last rows and longitudes of the first and last columns, for
    // the cylindrical CRSs.
    let cyl = match g.crs {
        Crs::Geographic => {
            for (what, v) in [("dx", g.dx), ("dy", g.dy)] {
                if !(MIN_PIXEL_DEG..=MAX_PIXEL_DEG).contains(&v.abs()) {
                    return Err(placed(format!(
                        "has a pixel spacing {what} = {}°, outside {MIN_PIXEL_DEG:.1e} .. 360°",
                        show(v)
                    )));
                }
            }
            Some((y_first, y_last, g.x0, x_last))
        }
        Crs::Equirectangular {
            lat_ts_deg,
            lon0_deg,
            radius_m,
        } => {
            crs_params(path, radius_m, lon0_deg, lat_ts_deg, MAX_LAT_TS_DEG)?;
            projected_pixels(path, g, radius_m, keys)?;
            let kx = radius_m * lat_ts_deg.to_radians().cos();
            let lat = |y: f64| (y / radius_m).to_degrees();
            let lon = |x: f64| lon0_deg + (x / kx).to_degrees();
            Some((lat(y_first), lat(y_last), lon(g.x0), lon(x_last)))
        }
        Crs::PolarStereographic {
            north,
            lon0_deg,
            lat_ts_deg,
            radius_m,
        } => {
            crs_params(path, radius_m, lon0_deg, lat_ts_deg, MAX_LAT_DEG)?;
            if (north && lat_ts_deg < 0.0) || (!north && lat_ts_deg > 0.0) {
                return Err(bad(
                    path,
                    "crs lat_ts_deg (GeoTIFF ProjStdParallel1 3078)",
                    lat_ts_deg,
                    &format!(
                        "is a true-scale latitude in the other hemisphere from the projection's \
                         {} pole (crs north = {north}; GeoTIFF: the origin latitude's sign): \
                         one of the two is wrong",
                        if north { "north" } else { "south" }
                    ),
                ));
            }
            projected_pixels(path, g, radius_m, keys)?;
            // The farthest pixel centre from the pole is a corner of the grid.
            let pole = if north { 90.0 } else { -90.0 };
            for (x, y) in [
                (g.x0, y_first),
                (x_last, y_first),
                (g.x0, y_last),
                (x_last, y_last),
            ] {
                let (lat, _) = g.inverse(x, y);
                let colat = (pole - lat).abs();
                if !(colat.is_finite() && colat <= MAX_POLAR_COLAT_DEG) {
                    return Err(placed(format!(
                        "reaches {colat:.1}° from the {} pole (corner at x {}, y {} m): a polar \
                         stereographic grid must stay within {MAX_POLAR_COLAT_DEG}° of its pole",
                        if north { "north" } else { "south" },
                        show(x),
                        show(y)
                    )));
                }
            }
            None
        }
    };
    if let Some((lat_a, lat_b, lon_a, lon_b)) = cyl {
        let lim = MAX_LAT_DEG * (1.0 + SLACK);
        for (row, lat) in [(0, lat_a), (h.max(1) - 1, lat_b)] {
            if !(lat.is_finite() && lat.abs() <= lim) {
                return Err(placed(format!(
                    "puts the centre of row {row} at latitude {}: pixel centres must lie within \
                     −90..90",
                    show(lat)
                )));
            }
        }
        if !(MIN_LON_DEG..=MAX_LON_DEG).contains(&lon_a) {
            return Err(placed(format!(
                "puts the centre of column 0 at longitude {}: it must lie within −360..720",
                show(lon_a)
            )));
        }
        if lon_b - lon_a > 360.0 * (1.0 + SLACK) {
            return Err(placed(format!(
                "spans {}° of longitude between its first and last pixel centres: at most a \
                 turn (360°)",
                show(lon_b - lon_a)
            )));
        }
    }
    let ratio = |a: f64| if a >= 1.0 { a } else { 1.0 / a };
    let deg_ratio = ratio(g.dx.abs() / g.dy.abs());
    let ground_ratio = match (&g.crs, cyl) {
        (Crs::Geographic, Some((lat_a, lat_b, _, _))) => {
            let (a, b) = (lat_a.clamp(-90.0, 90.0), lat_b.clamp(-90.0, 90.0));
            let nearest = if a.signum() != b.signum() {
                0.0
            } else {
                a.abs().min(b.abs())
            };
            ratio(g.dx.abs() * nearest.to_radians().cos() / g.dy.abs())
        }
        _ => deg_ratio,
    };
    if deg_ratio.min(ground_ratio) > MAX_PIXEL_ASPECT {
        return Err(placed(format!(
            "has pixels {:.1} times longer one way than the other (dx {}, dy {}): more than \
             {MAX_PIXEL_ASPECT}:1, so the spacing keys contradict each other",
            deg_ratio.min(ground_ratio),
            show(g.dx),
            show(g.dy)
        )));
    }
    Ok(())
}

fn crs_params(path: &Path, r: f64, lon0: f64, lat_ts: f64, max_ts: f64) -> Result<()> {
    radius(path, "crs radius_m", r)?;
    longitude(path, "crs lon0_deg", lon0)?;
    if !(lat_ts.is_finite() && lat_ts.abs() <= max_ts) {
        return Err(bad(
            path,
            "crs lat_ts_deg",
            lat_ts,
            &format!("is not a usable true-scale latitude: it must lie within ±{max_ts}°"),
        ));
    }
    Ok(())
}

fn projected_pixels(path: &Path, g: &GeoRef, r: f64, keys: &str) -> Result<()> {
    for (what, v) in [("dx", g.dx), ("dy", g.dy)] {
        pixel_m(
            path,
            &format!("pixel size {what} (from {keys})"),
            v,
            Some(r),
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geo(x0: f64, y0: f64, d: f64) -> GeoRef {
        GeoRef {
            crs: Crs::Geographic,
            x0,
            y0,
            dx: d,
            dy: d,
        }
    }

    /// Pixels beyond [`MAX_PIXEL_ASPECT`]:1 are refused; square-in-degrees caps near a pole and
    /// ground-square high-latitude rasters (dx = dy / cos φ) pass.
    #[test]
    fn pixel_aspect() {
        let p = Path::new("x");
        let g = |x0: f64, y0: f64, dx: f64, dy: f64, crs: Crs| GeoRef {
            crs,
            x0,
            y0,
            dx,
            dy,
        };
        let ok = |g: GeoRef, w, h| check_georef(p, &g, w, h, "k").is_ok();
        assert!(ok(g(0.0, 89.9, 0.1, 0.1, Crs::Geographic), 3600, 50));
        // 85..90°N, 11.5:1 in degrees: square on the ground at 85°.
        assert!(ok(g(0.0, 89.95, 1.15, 0.1, Crs::Geographic), 300, 50));
        // The same spacing at the equator is 11.5:1 on the ground: refused.
        assert!(!ok(g(0.0, 2.45, 1.15, 0.1, Crs::Geographic), 300, 50));
        assert!(!ok(g(0.0, 10.0, 0.1, 5.7, Crs::Geographic), 10, 3));
        let polar = Crs::PolarStereographic {
            north: false,
            lon0_deg: 0.0,
            lat_ts_deg: -90.0,
            radius_m: 1_737_400.0,
        };
        assert!(ok(g(-640.0, 640.0, 5.0, 5.0, polar.clone()), 256, 256));
        assert!(ok(g(-640.0, 640.0, 50.0, 5.0, polar.clone()), 25, 256));
        let e = check_georef(
            p,
            &g(-640.0, 640.0, 285.0, 5.0, polar),
            4,
            256,
            "ModelPixelScale",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("ModelPixelScale") && e.contains("57.0 times"),
            "{e}"
        );
    }

    /// A polar stereographic true-scale latitude in the other hemisphere, and a negative
    /// scale, are refused by name.
    #[test]
    fn hemisphere_and_sign() {
        let p = Path::new("x");
        for (north, lat_ts, ok) in [
            (false, -90.0, true),
            (false, -71.0, true),
            (false, 0.0, true),
            (false, 90.0, false),
            (true, 90.0, true),
            (true, -71.0, false),
        ] {
            let g = GeoRef {
                crs: Crs::PolarStereographic {
                    north,
                    lon0_deg: 0.0,
                    lat_ts_deg: lat_ts,
                    radius_m: 1_737_400.0,
                },
                x0: -1000.0,
                y0: 1000.0,
                dx: 20.0,
                dy: 20.0,
            };
            let r = check_georef(p, &g, 100, 100, "k");
            assert_eq!(r.is_ok(), ok, "{north} {lat_ts}: {r:?}");
            if let Err(e) = r {
                assert!(e.to_string().contains("lat_ts_deg"), "{e}");
            }
        }
        let e = scale_offset(p, ("SCALING_FACTOR", -1.0), ("OFFSET", 0.0), None).unwrap_err();
        assert!(
            e.to_string().contains("SCALING_FACTOR = -1 is negative"),
            "{e}"
        );
        assert!(scale_offset(p, ("scale", 0.5), ("offset", -10.0), None).is_ok());
    }

    #[test]
    fn grids_on_and_off_the_sphere() {
        let p = Path::new("x");
        // Pixel- and corner-registered global grids are fine.
        assert!(check_georef(p, &geo(0.125, 89.875, 0.25), 1440, 720, "k").is_ok());
        assert!(check_georef(p, &geo(0.0, 90.0, 0.25), 1441, 721, "k").is_ok());
        // A row beyond the pole, a grid wider than a turn, a far-away start.
        assert!(check_georef(p, &geo(0.125, 90.125, 0.25), 1440, 720, "k").is_err());
        assert!(check_georef(p, &geo(0.0, 89.0, 0.25), 1442, 10, "k").is_err());
        assert!(check_georef(p, &geo(800.0, 0.0, 0.25), 10, 10, "k").is_err());
        assert!(check_georef(p, &geo(0.0, 0.0, 1e-12), 10, 10, "k").is_err());
        let polar = |x0: f64| GeoRef {
            crs: Crs::PolarStereographic {
                north: false,
                lon0_deg: 0.0,
                lat_ts_deg: -90.0,
                radius_m: 1_737_400.0,
            },
            x0,
            y0: 1000.0,
            dx: 20.0,
            dy: 20.0,
        };
        assert!(check_georef(p, &polar(-1000.0), 100, 100, "k").is_ok());
        assert!(check_georef(p, &polar(-1e9), 100, 100, "k").is_err());
        let e = check_georef(p, &geo(0.0, 0.0, 400.0), 10, 10, "bounds").unwrap_err();
        assert!(e.to_string().contains("bounds"), "{e}");
    }

    #[test]
    fn keys_and_numbers() {
        let p = Path::new("x");
        assert!(latitude(p, "k", 1000.0).is_err());
        assert!(latitude(p, "k", -90.0).is_ok());
        assert!(longitude(p, "k", 720.5).is_err());
        assert!(radius(p, "k", -1737400.0).is_err());
        assert!(radius(p, "k", 1e300).is_err());
        assert!(scale_offset(p, ("s", 1e308), ("o", 0.0), Some(SampleType::I16)).is_err());
        assert!(scale_offset(p, ("s", 0.5), ("o", 0.0), Some(SampleType::I16)).is_ok());
        assert!(scale_offset(p, ("s", 1.0), ("o", f64::NAN), None).is_err());
        assert_eq!(show(1e300), "1e300");
        assert_eq!(show(0.25), "0.25");
    }
}
