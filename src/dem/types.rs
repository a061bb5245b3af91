//! The types every DEM reader fills in: sample types and byte orders, the samples (owned or
//! memory-mapped), the CRS and georeferencing of the pixel grid, resampling kinds, the mask
//! values, [`DemParts`], and the checks every reader shares. A leaf: it uses no reader.

use std::path::{Path, PathBuf};

use memmap2::Mmap;
use serde::{Deserialize, Serialize};

use crate::error::{Error, IoContext, Result};

/// Refuse rasters larger than this many samples before allocating anything (2^34 = 16 Gi).
pub const MAX_SAMPLES: u64 = 1 << 34;
/// A DEM's datum radius may differ from the body's radius by at most this fraction of it
/// ([`Dem::check_plausible`]).
pub const MAX_DATUM_MISMATCH: f64 = 0.5;
/// Default distance (pixels) up to which voids are filled from neighbours.
pub const DEFAULT_MAX_FILL_PX: u32 = 64;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SampleType {
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl SampleType {
    /// The name people and sidecars use: uint8, int16, uint16, int32, uint32, float32, float64.
    pub fn name(self) -> &'static str {
        match self {
            SampleType::U8 => "uint8",
            SampleType::I16 => "int16",
            SampleType::U16 => "uint16",
            SampleType::I32 => "int32",
            SampleType::U32 => "uint32",
            SampleType::F32 => "float32",
            SampleType::F64 => "float64",
        }
    }

    pub fn size(self) -> usize {
        match self {
            SampleType::U8 => 1,
            SampleType::I16 | SampleType::U16 => 2,
            SampleType::I32 | SampleType::U32 | SampleType::F32 => 4,
            SampleType::F64 => 8,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ByteOrder {
    Little,
    Big,
}

/// Where the samples live.
pub enum Samples {
    /// A memory-mapped file: `width × height` samples of `ty` starting at byte `offset`, rows
    /// `row_stride` bytes apart.
    Mapped {
        map: Mmap,
        offset: usize,
        row_stride: usize,
        ty: SampleType,
        order: ByteOrder,
    },
    /// Decoded samples (compressed formats, EXR, generated scenes), row-major.
    Owned(Vec<f32>),
}

/// Map a whole file read-only.
///
/// The file must not be modified while the map lives; sources are inputs that Penumbra only
/// reads, and a concurrent writer would be a user error we cannot detect.
pub fn map_file(path: &Path) -> Result<Mmap> {
    let file = std::fs::File::open(path).at(path)?;
    // SAFETY: read-only map of an input file; see the function's doc for the caveat.
    unsafe { Mmap::map(&file) }.at(path)
}

/// Coordinate reference system of a raster grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Crs {
    /// x = east longitude, y = planetocentric latitude, both in degrees.
    Geographic,
    /// Spherical equirectangular in metres: x = R·(λ − λ0)·cos φts, y = R·φ.
    Equirectangular {
        lat_ts_deg: f64,
        lon0_deg: f64,
        radius_m: f64,
    },
    /// Spherical polar stereographic in metres, true scale at `lat_ts_deg` (±90 = at the pole).
    PolarStereographic {
        north: bool,
        lon0_deg: f64,
        lat_ts_deg: f64,
        radius_m: f64,
    },
}

/// Georeferencing of a raster: CRS plus the affine placement of pixel centres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeoRef {
    pub crs: Crs,
    /// CRS coordinates of the centre of pixel (0, 0).
    pub x0: f64,
    pub y0: f64,
    /// Pixel spacing; x grows with the column, y shrinks with the row when `dy > 0`.
    pub dx: f64,
    pub dy: f64,
}

impl GeoRef {
    /// CRS coordinates of latitude/longitude (degrees). For geographic rasters `x` is the
    /// longitude wrapped to lie within 180° of `x_centre`.
    pub fn forward(&self, lat_deg: f64, lon_deg: f64, x_centre: f64) -> (f64, f64) {
        match self.crs {
            Crs::Geographic => {
                let x = lon_deg + 360.0 * ((x_centre - lon_deg) / 360.0).round();
                (x, lat_deg)
            }
            Crs::Equirectangular {
                lat_ts_deg,
                lon0_deg,
                radius_m,
            } => {
                let dl = wrap180(lon_deg - lon0_deg);
                (
                    radius_m * dl.to_radians() * lat_ts_deg.to_radians().cos(),
                    radius_m * lat_deg.to_radians(),
                )
            }
            Crs::PolarStereographic {
                north,
                lon0_deg,
                lat_ts_deg,
                radius_m,
            } => {
                let k0 = (1.0 + lat_ts_deg.to_radians().abs().sin()) / 2.0;
                let phi = lat_deg.to_radians();
                let dl = (lon_deg - lon0_deg).to_radians();
                let q = std::f64::consts::FRAC_PI_4;
                if north {
                    let rho = 2.0 * radius_m * k0 * (q - phi / 2.0).tan();
                    (rho * dl.sin(), -rho * dl.cos())
                } else {
                    let rho = 2.0 * radius_m * k0 * (q + phi / 2.0).tan();
                    (rho * dl.sin(), rho * dl.cos())
                }
            }
        }
    }

    /// CRS coordinates of a unit direction in the body frame. The same as [`GeoRef::forward`]
    /// of its latitude/longitude, but polar stereographic needs no trigonometry this way
    /// (ρ·sin λ = 2Rk0·y/(1 ∓ z) on the unit sphere), which is most of the tiling cost.
    #[inline]
    pub fn forward_dir(&self, d: [f64; 3], x_centre: f64) -> (f64, f64) {
        match self.crs {
            Crs::PolarStereographic {
                north,
                lon0_deg,
                lat_ts_deg,
                radius_m,
            } => {
                let k0 = (1.0 + lat_ts_deg.to_radians().abs().sin()) / 2.0;
                let (s0, c0) = lon0_deg.to_radians().sin_cos();
                // Rotate so that lon0 is the x axis: (x', y') = (ρ cos(λ−λ0), ρ sin(λ−λ0))/…
                let xr = d[0] * c0 + d[1] * s0;
                let yr = d[1] * c0 - d[0] * s0;
                if north {
                    let q = 2.0 * radius_m * k0 / (1.0 + d[2]);
                    (q * yr, -q * xr)
                } else {
                    let q = 2.0 * radius_m * k0 / (1.0 - d[2]);
                    (q * yr, q * xr)
                }
            }
            _ => {
                let (lat, lon) = crate::cube::dir_to_latlon(d);
                self.forward(lat.to_degrees(), lon.to_degrees(), x_centre)
            }
        }
    }

    /// Latitude/longitude (degrees) of CRS coordinates.
    pub fn inverse(&self, x: f64, y: f64) -> (f64, f64) {
        match self.crs {
            Crs::Geographic => (y, x),
            Crs::Equirectangular {
                lat_ts_deg,
                lon0_deg,
                radius_m,
            } => (
                (y / radius_m).to_degrees(),
                lon0_deg + (x / (radius_m * lat_ts_deg.to_radians().cos())).to_degrees(),
            ),
            Crs::PolarStereographic {
                north,
                lon0_deg,
                lat_ts_deg,
                radius_m,
            } => {
                let k0 = (1.0 + lat_ts_deg.to_radians().abs().sin()) / 2.0;
                let rho = x.hypot(y);
                let c = 2.0 * (rho / (2.0 * radius_m * k0)).atan();
                let h = std::f64::consts::FRAC_PI_2;
                if north {
                    ((h - c).to_degrees(), lon0_deg + x.atan2(-y).to_degrees())
                } else {
                    ((c - h).to_degrees(), lon0_deg + x.atan2(y).to_degrees())
                }
            }
        }
    }
}

/// Wrap an angle in degrees to (−180, 180].
pub fn wrap180(a: f64) -> f64 {
    let r = a.rem_euclid(360.0);
    if r > 180.0 {
        r - 360.0
    } else {
        r
    }
}

/// Interpolation used when resampling a DEM.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Resampling {
    #[default]
    Bilinear,
    /// Catmull-Rom (a = −½), falls back to bilinear where a tap is no data.
    Bicubic,
}

impl std::str::FromStr for Resampling {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "bilinear" => Ok(Resampling::Bilinear),
            "bicubic" => Ok(Resampling::Bicubic),
            _ => Err(format!("unknown resampling '{s}': use bilinear or bicubic")),
        }
    }
}

/// Mask values carried with each resampled height (and stored in tiles).
pub mod mask {
    /// Every tap was a measured sample.
    pub const MEASURED: u8 = 0;
    /// At least one tap was a void filled from its neighbours.
    pub const FILLED: u8 = 1;
    /// No data: outside the raster, or only unfilled voids; the height is NaN.
    pub const NO_DATA: u8 = 2;
}

/// Everything a reader knows about a raster; [`Dem::new`] checks it and builds the void fill.
pub struct DemParts {
    pub width: usize,
    pub height: usize,
    pub samples: Samples,
    /// height (m above `datum_radius_m`) = DN · scale + offset
    pub scale: f64,
    pub offset: f64,
    /// Raw DN value that marks a void, compared before scaling.
    pub nodata: Option<f64>,
    pub georef: GeoRef,
    /// Radius of the sphere the heights refer to, when the file says (LOLA's OFFSET).
    pub datum_radius_m: Option<f64>,
    /// Body named by the file (PDS3 TARGET_NAME), lower case.
    pub target: Option<String>,
    /// The files the raster was read from (label first); hashed into the manifest.
    pub sources: Vec<PathBuf>,
    /// One line for people: format, sample type, CRS.
    pub format: String,
}

impl DemParts {
    /// A raster held in memory: `width × height` heights in metres (row-major, NaN for voids)
    /// placed by `georef`, with no datum, no target body and no source files. `label` is what
    /// reports call its format.
    pub fn in_memory(
        georef: GeoRef,
        width: usize,
        height: usize,
        heights: Vec<f32>,
        label: &str,
    ) -> DemParts {
        DemParts {
            width,
            height,
            samples: Samples::Owned(heights),
            scale: 1.0,
            offset: 0.0,
            nodata: None,
            georef,
            datum_radius_m: None,
            target: None,
            sources: vec![],
            format: label.into(),
        }
    }
}

/// Reject absurd raster sizes before anything is allocated.
pub fn check_dimensions(path: &Path, width: u64, height: u64) -> Result<()> {
    if width < 2 || height < 2 {
        return Err(Error::invalid(
            path,
            format!("raster is {width}×{height}: a DEM needs at least 2×2 samples"),
        ));
    }
    if width.saturating_mul(height) > MAX_SAMPLES || width > (1 << 24) || height > (1 << 24) {
        return Err(Error::invalid(
            path,
            format!("raster is {width}×{height}: larger than Penumbra accepts (2^34 samples)"),
        ));
    }
    Ok(())
}

/// Decoders report corrupt or truncated streams as I/O errors; those are damaged files
/// (Invalid), not failures of the operating system.
pub(crate) fn damaged_or_io(path: &Path, io: std::io::Error, what: &str) -> Error {
    use std::io::ErrorKind::{InvalidData, InvalidInput, Other, UnexpectedEof};
    match io.kind() {
        UnexpectedEof => Error::invalid(
            path,
            format!("truncated {what}: the file ends inside its data"),
        ),
        InvalidData | InvalidInput | Other => {
            Error::invalid(path, format!("damaged {what} data: {io}"))
        }
        _ => Error::io(path, io),
    }
}
