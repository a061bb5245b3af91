//! The JSON sidecar of raw and EXR DEMs: its schema, parsing and checks, and where a
//! raster's sidecar (or a sidecar's raster) is found. A leaf shared by [`super::raw`] and
//! [`super::exrdem`].
//!
//! # Sidecar schema
//!
//! ```json
//! {
//!   "width": 897, "height": 897,          // or "size": 897 for a square raster
//!   "sample_type": "u16",                  // u8 i16 u16 i32 u32 f32 f64 (also int16, float32 …)
//!   "byte_order": "little",                // little | big (not needed for u8)
//!     // or both at once: "format": "uint16-le" / "int16-be" / "float32-le" …
//!   "header_bytes": 0,                     // bytes to skip before the first sample
//!   "scale": 1.0, "offset": 0.0,           // height (m) = DN · scale + offset
//!     // or, for unsigned integers: "elevationMin": -4648, "elevationMax": 2002, meaning
//!     // height = min + DN · (max − min) / (2^bits − 1)   (uint16: / 65535)
//!   "nodata": -32768,                      // raw DN of voids (optional; NaN is always void)
//!   "crs": "geographic",                   // default; or a full CRS object:
//!     // {"kind": "equirectangular", "lat_ts_deg": 0, "lon0_deg": 0, "radius_m": 3396190}
//!     // {"kind": "polar-stereographic", "north": false, "lon0_deg": 0,
//!     //  "lat_ts_deg": -90, "radius_m": 1737400}
//!   "bounds": {"north": -1.8984375, "south": -8.90625,
//!              "west": 134.296875, "east": 141.3046875},
//!     // the outer *edges* of the raster (degrees for geographic, metres otherwise), or
//!     // "x0", "y0", "dx", "dy": CRS coordinates of the *centre* of the first pixel and the
//!     // spacing (dy > 0 when rows run north to south)
//!   "datum_radius_m": 3396190,             // optional: sphere the heights refer to
//!   "target": "mars",                      // optional: body name
//!   "data": "gale-mola.bin"                // optional: the raw file, beside the sidecar
//! }
//! ```
//!
//! Informational keys (`source`, `note`, `description`, `comment`, `origin`, `metresPerPixelLat`,
//! `metresPerPixelLon`, anything starting with `_`) are ignored; any other unknown key is an
//! error, so that a misspelt key is not silently dropped. For a geographic raster whose `east`
//! is not greater than `west`, the raster crosses the antimeridian and `east` is read as
//! `east + 360`.
//!
//! An EXR DEM uses the same sidecar for its georeferencing and `scale`/`offset`/`nodata`; it
//! must not give a sample encoding (the EXR has its own), and `width`/`height`, if given, must
//! match the image.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::dem::limits;
use crate::dem::types::{ByteOrder, Crs, GeoRef, SampleType};
use crate::error::{Error, IoContext, Result};

/// Sidecars larger than this are refused (they are a few hundred bytes).
const MAX_SIDECAR_BYTES: u64 = 1 << 20;

/// Keys that carry information for people and are ignored.
const INFORMATIONAL: &[&str] = &[
    "source",
    "note",
    "notes",
    "description",
    "comment",
    "origin",
    "metresPerPixelLat",
    "metresPerPixelLon",
    "metersPerPixelLat",
    "metersPerPixelLon",
];

/// Pixel-edge bounds of a raster in CRS units.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bounds {
    pub north: f64,
    pub south: f64,
    pub west: f64,
    pub east: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
enum CrsSpec {
    Name(String),
    Full(Crs),
}

/// The JSON sidecar of a raw or EXR DEM (see the module documentation).
#[derive(Clone, Debug, Deserialize)]
pub struct Sidecar {
    pub width: Option<u64>,
    pub height: Option<u64>,
    pub size: Option<u64>,
    pub format: Option<String>,
    pub sample_type: Option<String>,
    pub byte_order: Option<String>,
    pub header_bytes: Option<u64>,
    pub scale: Option<f64>,
    pub offset: Option<f64>,
    #[serde(rename = "elevationMin", alias = "elevation_min")]
    pub elevation_min: Option<f64>,
    #[serde(rename = "elevationMax", alias = "elevation_max")]
    pub elevation_max: Option<f64>,
    pub nodata: Option<f64>,
    crs: Option<CrsSpec>,
    pub bounds: Option<Bounds>,
    pub x0: Option<f64>,
    pub y0: Option<f64>,
    pub dx: Option<f64>,
    pub dy: Option<f64>,
    pub datum_radius_m: Option<f64>,
    pub target: Option<String>,
    pub data: Option<String>,
    #[serde(flatten)]
    extra: BTreeMap<String, serde_json::Value>,
}

impl Sidecar {
    /// Read and check a sidecar file.
    pub fn load(path: &Path) -> Result<Sidecar> {
        let len = std::fs::metadata(path).at(path)?.len();
        if len > MAX_SIDECAR_BYTES {
            return Err(Error::invalid(
                path,
                format!("sidecar is {len} bytes: not a DEM sidecar (they are a few hundred)"),
            ));
        }
        let bytes = std::fs::read(path).at(path)?;
        let sc: Sidecar = serde_json::from_slice(&bytes).map_err(|e| {
            Error::invalid(path, format!("sidecar is not valid JSON for a DEM: {e}"))
        })?;
        let unknown: Vec<&str> = sc
            .extra
            .keys()
            .map(String::as_str)
            .filter(|k| !k.starts_with('_') && !INFORMATIONAL.contains(k))
            .collect();
        if !unknown.is_empty() {
            return Err(Error::invalid(
                path,
                format!(
                    "unknown sidecar key(s) {}: known keys are width, height, size, format, \
                     sample_type, byte_order, header_bytes, scale, offset, elevationMin, \
                     elevationMax, nodata, crs, bounds, x0, y0, dx, dy, datum_radius_m, target, \
                     data (prefix a key with _ to keep a comment)",
                    unknown.join(", ")
                ),
            ));
        }
        Ok(sc)
    }

    /// Width and height, if the sidecar gives them.
    pub fn dimensions(&self, path: &Path) -> Result<Option<(u64, u64)>> {
        match (self.size, self.width, self.height) {
            (None, None, None) => Ok(None),
            (Some(s), None, None) => Ok(Some((s, s))),
            (None, Some(w), Some(h)) => Ok(Some((w, h))),
            (Some(_), _, _) => Err(Error::invalid(
                path,
                "give either \"size\" (square raster) or \"width\" and \"height\", not both",
            )),
            _ => Err(Error::invalid(path, "give both \"width\" and \"height\"")),
        }
    }

    /// Whether the sidecar describes how samples are encoded (raw files only).
    pub fn has_encoding(&self) -> bool {
        self.format.is_some()
            || self.sample_type.is_some()
            || self.byte_order.is_some()
            || self.header_bytes.is_some()
    }

    /// Sample type and byte order.
    pub fn encoding(&self, path: &Path) -> Result<(SampleType, ByteOrder)> {
        if self.format.is_some() && (self.sample_type.is_some() || self.byte_order.is_some()) {
            return Err(Error::invalid(
                path,
                "give either \"format\" (e.g. \"int16-le\") or \"sample_type\" + \
                 \"byte_order\", not both",
            ));
        }
        let (ty, order) = match (&self.format, &self.sample_type) {
            (Some(f), None) => {
                let f = f.trim().to_ascii_lowercase();
                match f.rsplit_once(['-', '_']) {
                    Some((t, o)) if parse_order(o).is_some() => {
                        (t.to_string(), Some(o.to_string()))
                    }
                    _ => (f, None),
                }
            }
            (None, Some(t)) => (t.trim().to_ascii_lowercase(), self.byte_order.clone()),
            _ => {
                return Err(Error::invalid(
                    path,
                    "the sidecar gives no sample type: add \"format\": \"int16-le\" (or \
                     \"sample_type\": \"i16\" and \"byte_order\": \"little\")",
                ))
            }
        };
        let st = parse_type(&ty).ok_or_else(|| {
            Error::unsupported(
                path,
                format!(
                    "sample type '{ty}': use u8, i16, u16, i32, u32, f32 or f64 (or uint8, \
                     int16, uint16, int32, uint32, float32, float64)"
                ),
            )
        })?;
        let order = match order {
            Some(o) => parse_order(&o).ok_or_else(|| {
                Error::invalid(
                    path,
                    format!("byte order '{o}': use little (le) or big (be)"),
                )
            })?,
            None if st.size() == 1 => ByteOrder::Little,
            None => {
                return Err(Error::invalid(
                    path,
                    format!(
                        "sample type '{ty}' needs a byte order: \"format\": \"{ty}-le\" or \
                         \"{ty}-be\" (or \"byte_order\": \"little\" / \"big\")"
                    ),
                ))
            }
        };
        Ok((st, order))
    }

    /// Scale and offset turning a DN into metres, range-checked (`st`: the sample type, float
    /// when unknown).
    pub fn scale_offset(&self, path: &Path, st: Option<SampleType>) -> Result<(f64, f64)> {
        let (scale, offset) = self.scale_offset_unchecked(path, st)?;
        if self.elevation_min.is_some() {
            limits::scale_offset(
                path,
                ("(elevationMax − elevationMin) / (2^bits − 1)", scale),
                ("elevationMin", offset),
                st,
            )?;
        } else {
            limits::scale_offset(path, ("scale", scale), ("offset", offset), st)?;
        }
        Ok((scale, offset))
    }

    fn scale_offset_unchecked(&self, path: &Path, st: Option<SampleType>) -> Result<(f64, f64)> {
        let explicit = self.scale.is_some() || self.offset.is_some();
        match (self.elevation_min, self.elevation_max) {
            (None, None) => Ok((self.scale.unwrap_or(1.0), self.offset.unwrap_or(0.0))),
            (Some(_), Some(_)) if explicit => Err(Error::invalid(
                path,
                "give either scale/offset or elevationMin/elevationMax, not both",
            )),
            (Some(lo), Some(hi)) => {
                let qmax = match st {
                    Some(SampleType::U8) => 255.0,
                    Some(SampleType::U16) => 65535.0,
                    Some(SampleType::U32) => 4_294_967_295.0,
                    _ => {
                        return Err(Error::invalid(
                            path,
                            "elevationMin/elevationMax apply to unsigned integer samples only \
                             (height = min + DN·(max − min)/(2^bits − 1)); use scale/offset",
                        ))
                    }
                };
                if hi <= lo {
                    return Err(Error::invalid(
                        path,
                        format!(
                            "elevationMax {} is not above elevationMin {}",
                            limits::show(hi),
                            limits::show(lo)
                        ),
                    ));
                }
                Ok(((hi - lo) / qmax, lo))
            }
            _ => Err(Error::invalid(
                path,
                "give both elevationMin and elevationMax",
            )),
        }
    }

    /// The datum radius, range-checked.
    pub fn datum_radius(&self, path: &Path) -> Result<Option<f64>> {
        match self.datum_radius_m {
            None => Ok(None),
            Some(r) => Ok(Some(limits::radius(path, "datum_radius_m", r)?)),
        }
    }

    /// The CRS (geographic unless given), its parameters range-checked.
    pub fn crs(&self, path: &Path) -> Result<Crs> {
        match &self.crs {
            None => Ok(Crs::Geographic),
            Some(CrsSpec::Full(c)) => {
                match *c {
                    Crs::Geographic => {}
                    Crs::Equirectangular {
                        lat_ts_deg,
                        lon0_deg,
                        radius_m,
                    } => {
                        limits::radius(path, "crs radius_m", radius_m)?;
                        limits::longitude(path, "crs lon0_deg", lon0_deg)?;
                        if !(lat_ts_deg.is_finite() && lat_ts_deg.abs() <= limits::MAX_LAT_TS_DEG) {
                            return Err(Error::invalid(
                                path,
                                format!(
                                    "crs lat_ts_deg = {} leaves no usable longitude scale: an \
                                     equirectangular true-scale latitude must lie within ±{}°",
                                    limits::show(lat_ts_deg),
                                    limits::MAX_LAT_TS_DEG
                                ),
                            ));
                        }
                    }
                    Crs::PolarStereographic {
                        lon0_deg,
                        lat_ts_deg,
                        radius_m,
                        ..
                    } => {
                        limits::radius(path, "crs radius_m", radius_m)?;
                        limits::longitude(path, "crs lon0_deg", lon0_deg)?;
                        limits::latitude(path, "crs lat_ts_deg", lat_ts_deg)?;
                    }
                }
                Ok(c.clone())
            }
            Some(CrsSpec::Name(n)) if n.eq_ignore_ascii_case("geographic") => Ok(Crs::Geographic),
            Some(CrsSpec::Name(n)) => Err(Error::invalid(
                path,
                format!(
                    "crs '{n}': use \"geographic\" or an object such as {{\"kind\": \
                     \"polar-stereographic\", \"north\": false, \"lon0_deg\": 0, \"lat_ts_deg\": \
                     -90, \"radius_m\": 1737400}} or {{\"kind\": \"equirectangular\", \
                     \"lat_ts_deg\": 0, \"lon0_deg\": 0, \"radius_m\": 3396190}}"
                ),
            )),
        }
    }

    /// Georeferencing of a `width × height` raster.
    pub fn georef(&self, path: &Path, width: u64, height: u64) -> Result<GeoRef> {
        let crs = self.crs(path)?;
        let crs_radius = match crs {
            Crs::Equirectangular { radius_m, .. } | Crs::PolarStereographic { radius_m, .. } => {
                Some(radius_m)
            }
            Crs::Geographic => None,
        };
        let affine = [self.x0, self.y0, self.dx, self.dy];
        let any_affine = affine.iter().any(Option::is_some);
        let geographic = crs == Crs::Geographic;
        let (w, h) = (width as f64, height as f64);
        let (x0, y0, dx, dy) =
            match (&self.bounds, any_affine) {
                (Some(_), true) => {
                    return Err(Error::invalid(
                        path,
                        "give either \"bounds\" or x0/y0/dx/dy, not both",
                    ))
                }
                (Some(b), false) => {
                    let mut east = b.east;
                    if geographic && east <= b.west {
                        east += 360.0;
                    }
                    let ok = [b.north, b.south, b.west, east]
                        .iter()
                        .all(|v| v.is_finite());
                    if !ok || b.north <= b.south || east <= b.west {
                        return Err(Error::invalid(
                            path,
                            format!(
                                "bounds north {} / south {} / west {} / east {} do not enclose an \
                             area (north must exceed south, east exceed west)",
                                b.north, b.south, b.west, b.east
                            ),
                        ));
                    }
                    if geographic && (b.north > 90.0 + 1e-9 || b.south < -90.0 - 1e-9) {
                        return Err(Error::invalid(
                            path,
                            format!(
                                "bounds north {} / south {} are not latitudes in degrees (they \
                                 must lie within −90..90)",
                                limits::show(b.north),
                                limits::show(b.south)
                            ),
                        ));
                    }
                    if geographic {
                        limits::longitude(path, "bounds west", b.west)?;
                        limits::longitude(path, "bounds east", b.east)?;
                    }
                    let dx = (east - b.west) / w;
                    let dy = (b.north - b.south) / h;
                    (b.west + dx / 2.0, b.north - dy / 2.0, dx, dy)
                }
                (None, true) => {
                    match affine {
                        [Some(x0), Some(y0), Some(dx), Some(dy)] => {
                            if geographic {
                                limits::longitude(path, "x0", x0)?;
                                limits::latitude(path, "y0", y0)?;
                                limits::pixel_deg(path, "dx", dx)?;
                                limits::pixel_deg(path, "dy", dy)?;
                            } else {
                                limits::finite(path, "x0", x0)?;
                                limits::finite(path, "y0", y0)?;
                                limits::pixel_m(path, "dx", dx, crs_radius)?;
                                limits::pixel_m(path, "dy", dy, crs_radius)?;
                            }
                            (x0, y0, dx, dy)
                        }
                        _ => return Err(Error::invalid(
                            path,
                            "x0, y0, dx and dy must all be given (centre of the first pixel and \
                         the spacing)",
                        )),
                    }
                }
                (None, false) => return Err(Error::invalid(
                    path,
                    "the sidecar has no georeferencing: add \"bounds\": {\"north\", \"south\", \
                     \"west\", \"east\"} (outer pixel edges) or x0, y0, dx, dy (centre of the \
                     first pixel and spacing)",
                )),
            };
        if !(dx > 0.0 && dx.is_finite() && dy != 0.0 && dy.is_finite()) {
            return Err(Error::invalid(
                path,
                format!(
                    "pixel spacing dx {} / dy {} is not usable (dx > 0, dy ≠ 0)",
                    limits::show(dx),
                    limits::show(dy)
                ),
            ));
        }
        let g = GeoRef {
            crs,
            x0,
            y0,
            dx,
            dy,
        };
        let keys = if self.bounds.is_some() {
            "the sidecar's bounds"
        } else {
            "the sidecar's x0, y0, dx, dy"
        };
        limits::check_georef(path, &g, width as usize, height as usize, keys)?;
        Ok(g)
    }
}

fn parse_type(t: &str) -> Option<SampleType> {
    Some(match t {
        "u8" | "uint8" | "byte" => SampleType::U8,
        "i16" | "int16" | "short" => SampleType::I16,
        "u16" | "uint16" => SampleType::U16,
        "i32" | "int32" => SampleType::I32,
        "u32" | "uint32" => SampleType::U32,
        "f32" | "float32" | "float" => SampleType::F32,
        "f64" | "float64" | "double" => SampleType::F64,
        _ => return None,
    })
}

fn parse_order(o: &str) -> Option<ByteOrder> {
    match o.trim().to_ascii_lowercase().as_str() {
        "le" | "little" | "lsb" => Some(ByteOrder::Little),
        "be" | "big" | "msb" => Some(ByteOrder::Big),
        _ => None,
    }
}

pub(crate) fn crs_name(crs: &Crs) -> &'static str {
    match crs {
        Crs::Geographic => "geographic",
        Crs::Equirectangular { .. } => "equirectangular",
        Crs::PolarStereographic { .. } => "polar stereographic",
    }
}

pub(crate) fn is_json(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
}

/// `<file>.json`, then `<stem>.json`.
fn sidecar_candidates(path: &Path) -> [PathBuf; 2] {
    let mut a = path.as_os_str().to_owned();
    a.push(".json");
    [PathBuf::from(a), path.with_extension("json")]
}

/// The JSON sidecar of a raw (or EXR) raster, if there is one: `<file>.json`, else
/// `<stem>.json`. A `.json` file is its own sidecar.
pub fn sidecar_for(path: &Path) -> Option<PathBuf> {
    if is_json(path) {
        return path.is_file().then(|| path.to_path_buf());
    }
    sidecar_candidates(path).into_iter().find(|p| p.is_file())
}

/// The sidecar of `path`, or an error naming where it was expected and what it holds.
pub(crate) fn require_sidecar(path: &Path, kind: &str) -> Result<PathBuf> {
    sidecar_for(path).ok_or_else(|| {
        let [a, b] = sidecar_candidates(path);
        Error::invalid(
            path,
            format!(
                "no JSON sidecar: {kind} needs {} (or {}) giving its georeferencing{}; see \
                 docs/formats.md",
                b.display(),
                a.display(),
                if kind.contains("raw") {
                    ", size and sample type"
                } else {
                    ""
                }
            ),
        )
    })
}

/// The data file a sidecar describes, when the sidecar itself was opened.
pub(crate) fn data_for_sidecar(json: &Path, sc: &Sidecar) -> Result<PathBuf> {
    let dir = match json.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if let Some(d) = &sc.data {
        let p = dir.join(d);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(Error::invalid(
                json,
                format!("\"data\" names {}, which does not exist", p.display()),
            ))
        };
    }
    let stem = json.with_extension("");
    if stem.extension().is_some() && stem.is_file() {
        return Ok(stem); // X.bin.json → X.bin
    }
    for ext in ["bin", "raw", "dat", "exr"] {
        let p = json.with_extension(ext);
        if p.is_file() {
            return Ok(p);
        }
    }
    Err(Error::invalid(
        json,
        "cannot find the raster this sidecar describes: add \"data\": \"<file name>\" or put \
         <name>.bin beside it",
    ))
}
