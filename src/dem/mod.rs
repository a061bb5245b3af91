//! Digital elevation models: one in-memory description for every source format, the
//! georeferencing of its pixel grid, the void policy, and interpolation at a latitude/longitude.
//!
//! Pixel convention: `(col, row)` are pixel *centres*; pixel (0, 0) is the first sample in the
//! file, its centre at CRS coordinates (`x0`, `y0`); `x` grows by `dx` per column and `y`
//! shrinks by `dy` per row (north-up rasters have `dy > 0`).
//!
//! Void policy (docs/formats.md): a sample equal to the format's no-data value, or NaN/±inf, is
//! a void. Voids are never read as zero. Each void within `max_fill_px` pixels of measured data
//! is filled once, at load, by onion peeling: in pass k every void that touches (8-neighbours)
//! a measured or already filled sample takes the mean of those neighbours. Filled samples are
//! reported by [`Dem::sample`] so tiles can record them in their mask. Voids farther than
//! `max_fill_px` from data stay NaN and count as "no data".

pub mod exrdem;
#[cfg(feature = "gdal")]
pub mod gdal;
pub mod geotiff;
pub mod limits;
pub mod pds3;
mod raster;
pub mod raw;
pub mod relief;
pub mod sidecar;
pub mod srtm;
pub(crate) mod types;

pub(crate) use self::raster::floor_fast;
pub use self::raster::{Dem, HeightAt, HeightExtremes};
pub use self::types::*;

use std::path::Path;

use crate::body::Body;
use crate::error::{Error, Result};
/// Which reader opens a DEM.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DemFormat {
    /// The native reader the file name chooses ([`open`]); GDAL for names none knows, in a
    /// build with GDAL.
    #[default]
    Auto,
    /// Any raster GDAL opens (ISIS cubes, PDS4, JPEG 2000, VRT mosaics …): needs a build with
    /// `--features gdal`.
    Gdal,
}

impl DemFormat {
    /// Whether this is the default (`auto`).
    pub fn is_auto(&self) -> bool {
        *self == DemFormat::Auto
    }

    /// Whether this build reads DEMs through GDAL.
    pub fn gdal_available() -> bool {
        cfg!(feature = "gdal")
    }
}

impl std::str::FromStr for DemFormat {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(DemFormat::Auto),
            "gdal" => Ok(DemFormat::Gdal),
            _ => Err(format!("unknown DEM format '{s}': use auto or gdal")),
        }
    }
}

/// Open a DEM with the reader `format` names ([`DemFormat::Auto`]: as [`open`]).
pub fn open_as(path: &Path, format: DemFormat, max_fill_px: u32) -> Result<Dem> {
    match format {
        DemFormat::Auto => open(path, max_fill_px),
        DemFormat::Gdal => {
            if !path.exists() {
                return Err(Error::io(
                    path,
                    std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
                ));
            }
            Dem::new(read_gdal(path)?, max_fill_px)
        }
    }
}

#[cfg(feature = "gdal")]
fn read_gdal(path: &Path) -> Result<DemParts> {
    self::gdal::read(path)
}

/// A name no native reader claims, tried through GDAL: where GDAL cannot open it either, the
/// error says both (what the native readers expect, and GDAL's refusal).
#[cfg(feature = "gdal")]
fn read_unknown_through_gdal(path: &Path) -> Result<DemParts> {
    self::gdal::read_or(path, |e| {
        Error::unsupported(
            path,
            format!("{UNKNOWN_FORMAT}; GDAL cannot open it as a raster either ({e})"),
        )
    })
}

#[cfg(not(feature = "gdal"))]
fn read_unknown_through_gdal(path: &Path) -> Result<DemParts> {
    read_gdal(path)
}

/// What the native readers take, for a file none of them claims.
const UNKNOWN_FORMAT: &str = "unknown DEM format: expected .LBL/.IMG (PDS3), .hgt (SRTM), .tif \
     (GeoTIFF), .exr, or a raw file with a JSON sidecar (see docs/formats.md)";

/// Without GDAL, nothing but the shared message ([`Error::no_gdal`]; keep this trivial: CI
/// builds with GDAL and does not compile it).
#[cfg(not(feature = "gdal"))]
fn read_gdal(path: &Path) -> Result<DemParts> {
    Err(Error::no_gdal(format_args!(
        "{} (read through GDAL)",
        path.display()
    )))
}

/// Open a DEM, choosing the reader from the file name and contents:
/// `.lbl`/`.img` → PDS3, `.hgt` → SRTM, `.tif`/`.tiff` → GeoTIFF, `.exr` → EXR (needs a JSON
/// sidecar for its georeferencing), `.bin`/`.raw`/`.dat` or anything with a
/// `<file>.json`/`<stem>.json` sidecar → raw (a `.json` sidecar opens the raster it describes);
/// any other name through GDAL in a build with `--features gdal` ([`DemFormat::Gdal`]).
pub fn open(path: &Path, max_fill_px: u32) -> Result<Dem> {
    if !path.exists() {
        return Err(Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let parts = match ext.as_str() {
        "lbl" | "img" => pds3::read(path)?,
        "hgt" => srtm::read(path)?,
        "tif" | "tiff" => geotiff::read(path)?,
        "exr" => exrdem::read(path)?,
        "bin" | "raw" | "dat" => raw::read(path)?,
        _ => match sidecar::sidecar_for(path) {
            Some(_) => read_with_sidecar(path)?,
            None if DemFormat::gdal_available() => read_unknown_through_gdal(path)?,
            None => return Err(Error::unsupported(path, UNKNOWN_FORMAT)),
        },
    };
    Dem::new(parts, max_fill_px)
}

/// A raster found through its JSON sidecar: a `.json` sidecar opens the raster it describes,
/// read as EXR when that is an `.exr`, else as raw.
fn read_with_sidecar(path: &Path) -> Result<DemParts> {
    if sidecar::is_json(path) {
        let sc = sidecar::Sidecar::load(path)?;
        let data = sidecar::data_for_sidecar(path, &sc)?;
        if data
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
        {
            return exrdem::read(&data);
        }
    }
    raw::read(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::testutil::{global_georef as global, synthetic_dem as synthetic};

    #[test]
    fn bilinear_reproduces_planes_and_wraps() {
        let dem = synthetic(360, 180, global(360, 180), |c, r| (2 * c + 3 * r) as f32);
        let (v, m) = dem.sample_pixel(10.25, 20.5, Resampling::Bilinear);
        assert_eq!(m, mask::MEASURED);
        assert!((v - (2.0 * 10.25 + 3.0 * 20.5)).abs() < 1e-4);
        // Across the antimeridian the plane wraps: halfway between col 359 and col 0.
        let (v, _) = dem.sample_pixel(359.5, 5.0, Resampling::Bilinear);
        assert!((v - (0.5 * (718.0 + 15.0) + 0.5 * 15.0)).abs() < 1e-3);
        // Longitudes 0..360 and −180..180 name the same point.
        let a = dem.sample(10.0, 200.0, Resampling::Bilinear);
        let b = dem.sample(10.0, -160.0, Resampling::Bilinear);
        assert_eq!(a, b);
    }

    /// The row sampler the tiler uses gives `sample_pixel`'s bits for every stored sample type
    /// and byte order (its own per-type loops, and the fallback for the others), at positions
    /// inside, on the edges of and off the raster, next to no-data samples (filled and not), for
    /// non-finite positions and for both resampling methods.
    #[test]
    fn sample_row_equals_sample_pixel() {
        let (w, h) = (37usize, 23usize);
        let g = GeoRef {
            crs: Crs::Geographic,
            x0: 10.0,
            y0: 5.0,
            dx: 0.1,
            dy: 0.1,
        };
        let value = |c: usize, r: usize| ((c * 7 + r * 13) % 61) as f64 + 3.0;
        // Two lone voids (filled) and a block too large to fill at 1 px.
        let void = |c: usize, r: usize| {
            (c, r) == (4, 4) || (c, r) == (30, 2) || ((15..22).contains(&c) && (8..16).contains(&r))
        };
        let dir = std::env::temp_dir().join(format!("penumbra-sample-row-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut rnd = crate::testutil::rng(0x5EED_1234);
        let mut coords: Vec<(f64, f64)> = (0..4000)
            .map(|_| {
                (
                    rnd() * (w as f64 + 4.0) - 2.0,
                    rnd() * (h as f64 + 4.0) - 2.0,
                )
            })
            .collect();
        coords.extend([
            (0.0, 0.0),
            (-0.5, -0.5),
            (w as f64 - 0.5, h as f64 - 0.5),
            (w as f64 - 1.0, 3.0),
            (f64::NAN, 1.0),
            (1.0, f64::INFINITY),
        ]);
        let types = [
            (SampleType::U8, ByteOrder::Little),
            (SampleType::I16, ByteOrder::Big),
            (SampleType::I16, ByteOrder::Little),
            (SampleType::U16, ByteOrder::Big),
            (SampleType::U16, ByteOrder::Little),
            (SampleType::F32, ByteOrder::Big),
            (SampleType::F32, ByteOrder::Little),
            (SampleType::I32, ByteOrder::Little),
            (SampleType::F64, ByteOrder::Big),
        ];
        let mut dems = Vec::new();
        for (k, &(ty, order)) in types.iter().enumerate() {
            let nodata = 250.0;
            let mut bytes = vec![0u8; 5]; // a header to skip
            for r in 0..h {
                for c in 0..w {
                    let v = if void(c, r) { nodata } else { value(c, r) };
                    macro_rules! put {
                        ($t:ty) => {{
                            let x = v as $t;
                            match order {
                                ByteOrder::Little => bytes.extend(x.to_le_bytes()),
                                ByteOrder::Big => bytes.extend(x.to_be_bytes()),
                            }
                        }};
                    }
                    match ty {
                        SampleType::U8 => bytes.push(v as u8),
                        SampleType::I16 => put!(i16),
                        SampleType::U16 => put!(u16),
                        SampleType::I32 => put!(i32),
                        SampleType::U32 => put!(u32),
                        SampleType::F32 => put!(f32),
                        SampleType::F64 => put!(f64),
                    }
                }
            }
            let path = dir.join(format!("{k}.bin"));
            std::fs::write(&path, &bytes).unwrap();
            let parts = DemParts {
                width: w,
                height: h,
                samples: Samples::Mapped {
                    map: map_file(&path).unwrap(),
                    offset: 5,
                    row_stride: w * ty.size(),
                    ty,
                    order,
                },
                scale: 0.5,
                offset: -10.0,
                nodata: Some(nodata),
                georef: g.clone(),
                datum_radius_m: None,
                target: None,
                sources: vec![path.clone()],
                format: "test".into(),
            };
            dems.push((format!("{ty:?} {order:?}"), Dem::new(parts, 1).unwrap()));
        }
        let owned = synthetic(w, h, g.clone(), |c, r| {
            if void(c, r) {
                f32::NAN
            } else {
                value(c, r) as f32
            }
        });
        dems.push(("owned f32".into(), owned));
        let _ = std::fs::remove_dir_all(&dir);
        for (name, dem) in &dems {
            for method in [Resampling::Bilinear, Resampling::Bicubic] {
                let n = coords.len();
                let (mut hs, mut ms) = (vec![0f32; n], vec![0u8; n]);
                dem.sample_row(&coords, method, &mut hs, &mut ms);
                let mut kinds = [0usize; 3];
                for (i, &(c, r)) in coords.iter().enumerate() {
                    let (v, m) = dem.sample_pixel(c, r, method);
                    assert_eq!(
                        (hs[i].to_bits(), ms[i]),
                        (v.to_bits(), m),
                        "{name} {method:?} at ({c}, {r})"
                    );
                    kinds[(m as usize).min(2)] += 1;
                }
                assert!(kinds.iter().all(|&k| k > 0), "{name} {method:?}: {kinds:?}");
            }
        }
    }

    #[test]
    fn bicubic_reproduces_cubics_in_one_axis() {
        let dem = synthetic(64, 32, global(64, 32), |c, _| {
            let x = c as f32;
            0.01 * x * x * x - 0.5 * x * x + 2.0 * x
        });
        let x = 20.3f64;
        let (v, _) = dem.sample_pixel(x, 10.0, Resampling::Bicubic);
        let e = 0.01 * x * x * x - 0.5 * x * x + 2.0 * x;
        // Catmull-Rom reproduces quadratics exactly; the cubic term leaves a small residual.
        assert!((v as f64 - e).abs() < 0.01, "{v} vs {e}");
    }

    #[test]
    fn poles_reflect_with_half_turn() {
        let dem = synthetic(8, 4, global(8, 4), |c, r| (c + 10 * r) as f32);
        // Row −1 is row 0 on the far side: col 1 → col 5.
        let (c, r) = dem.resolve(1, -1);
        assert_eq!((c, r), (5, 0));
        let (c, r) = dem.resolve(7, 4);
        assert_eq!((c, r), (3, 3));
    }

    #[test]
    fn voids_are_filled_never_zero() {
        let g = GeoRef {
            crs: Crs::Geographic,
            x0: 0.0,
            y0: 10.0,
            dx: 0.1,
            dy: 0.1,
        };
        let dem = synthetic(20, 20, g, |c, r| {
            if (5..8).contains(&c) && (5..8).contains(&r) {
                f32::NAN
            } else {
                1000.0
            }
        });
        assert_eq!(dem.void_counts(), (9, 0));
        let (v, filled) = dem.value(6, 6);
        assert!(filled);
        assert!((v - 1000.0).abs() < 1e-3);
        let (v, m) = dem.sample_pixel(6.5, 6.5, Resampling::Bilinear);
        assert_eq!(m, mask::FILLED);
        assert!((v - 1000.0).abs() < 1e-3);
        // Off the raster: no data.
        assert_eq!(
            dem.sample_pixel(-0.6, 3.0, Resampling::Bilinear).1,
            mask::NO_DATA
        );
    }

    #[test]
    fn footprint_cap_contains_every_pixel() {
        for (crs, x0, y0, d) in [
            (
                Crs::PolarStereographic {
                    north: false,
                    lon0_deg: 0.0,
                    lat_ts_deg: -90.0,
                    radius_m: 1_737_400.0,
                },
                -30_000.0,
                50_000.0,
                400.0,
            ),
            (Crs::Geographic, 170.0, 30.0, 0.2),
        ] {
            let g = GeoRef {
                crs,
                x0,
                y0,
                dx: d,
                dy: d,
            };
            let dem = synthetic(100, 60, g, |_, _| 1.0);
            let (c, r) = dem.footprint_cap().expect("regional raster has a cap");
            for row in 0..60 {
                for col in 0..100 {
                    for (dc, dr) in [(-0.5, -0.5), (0.5, 0.5), (0.0, 0.0)] {
                        let (la, lo) = dem.to_latlon(col as f64 + dc, row as f64 + dr);
                        let p = crate::cube::latlon_to_dir(la.to_radians(), lo.to_radians());
                        assert!(crate::cube::angle_between(c, p) <= r);
                    }
                }
            }
        }
        assert!(synthetic(36, 18, global(36, 18), |_, _| 0.0)
            .footprint_cap()
            .is_none());
    }

    #[test]
    fn polar_stereographic_round_trips() {
        for north in [true, false] {
            let g = GeoRef {
                crs: Crs::PolarStereographic {
                    north,
                    lon0_deg: 0.0,
                    lat_ts_deg: if north { 90.0 } else { -90.0 },
                    radius_m: 1_737_400.0,
                },
                x0: 0.0,
                y0: 0.0,
                dx: 1.0,
                dy: 1.0,
            };
            let lat = if north { 87.2 } else { -87.2 };
            let (x, y) = g.forward(lat, 33.0, 0.0);
            let (la, lo) = g.inverse(x, y);
            assert!((la - lat).abs() < 1e-10 && (lo - 33.0).abs() < 1e-10);
            // The trigonometry-free direction path agrees, also with a rotated lon0.
            let d = crate::cube::latlon_to_dir(lat.to_radians(), 33f64.to_radians());
            let (xd, yd) = g.forward_dir(d, 0.0);
            assert!(
                (xd - x).abs() < 1e-6 && (yd - y).abs() < 1e-6,
                "{xd} {x} {yd} {y}"
            );
            let mut g2 = g.clone();
            if let Crs::PolarStereographic { lon0_deg, .. } = &mut g2.crs {
                *lon0_deg = -70.0;
            }
            let (x2, y2) = g2.forward(lat, 33.0, 0.0);
            let (xd2, yd2) = g2.forward_dir(d, 0.0);
            assert!((xd2 - x2).abs() < 1e-6 && (yd2 - y2).abs() < 1e-6);
            // Scale at the pole is 1: 0.001° of latitude ≈ R·dφ.
            let (_, y1) = g.forward(if north { 89.999 } else { -89.999 }, 0.0, 0.0);
            let arc = 1_737_400.0 * 0.001f64.to_radians();
            assert!((y1.abs() - arc).abs() < 1e-3 * arc);
        }
    }
}

/// The body to tile a DEM for, as the caller gave it: a preset name, a radius (which forces
/// that radius whatever the file says), both, or neither (the body the file names).
#[derive(Clone, Debug, Default)]
pub struct BodyChoice {
    pub name: Option<String>,
    pub radius_m: Option<f64>,
}

/// The body to tile `dem` for. A radius given by the caller is taken as it is (with the preset's
/// name when one is named too). A preset name alone is checked against the body the file names
/// (PDS3 TARGET_NAME): tiling Mars heights on the Moon is refused. Neither: the named body.
pub fn body_for(dem: &Dem, given: &BodyChoice) -> Result<Body> {
    let path = dem.sources().first().cloned().unwrap_or_default();
    if given.radius_m.is_some() {
        return Body::resolve(given.name.as_deref(), given.radius_m);
    }
    match (&given.name, dem.target()) {
        (Some(n), t) => {
            let b = Body::preset(n)?;
            match t {
                Some(t) if Body::preset(t).is_ok_and(|tb| tb.name != b.name) => {
                    Err(Error::usage(format!(
                        "{} is a DEM of {t} but the body {} was given: leave the body out, or give \
                         a radius to force one",
                        path.display(),
                        b.name
                    )))
                }
                _ => Ok(b),
            }
        }
        (None, Some(t)) => Body::preset(t).map_err(|_| {
            Error::usage(format!(
                "{} names the body '{t}', which has no preset: name a body or give a radius",
                path.display()
            ))
        }),
        (None, None) => Err(Error::usage(format!(
            "{} does not say which body it belongs to: name one (moon, mars, earth, …) or give a \
             radius",
            path.display()
        ))),
    }
}
