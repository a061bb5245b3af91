//! GeoTIFF DEMs: one band of 8/16/32-bit integers or 16/32/64-bit floats, striped or tiled,
//! with any compression the `tiff` crate decodes (none, LZW, Deflate, PackBits, with or without
//! predictors). Samples are decoded chunk by chunk into one `f32` buffer (float32 strips are
//! decoded straight into it).
//!
//! # Georeferencing
//!
//! * Placement: `ModelPixelScale` (33550) + `ModelTiepoint` (33922), or a non-rotated
//!   `ModelTransformation` (34264). With `GTRasterTypeGeoKey` = PixelIsArea (1, the default)
//!   raster point (0, 0) is the outer *corner* of the first pixel, whose centre is therefore
//!   half a pixel further in; with PixelIsPoint (2) it is the centre.
//! * CRS from the GeoKeyDirectory (34735, with GeoDoubleParams 34736):
//!   - `GTModelType` 2 (geographic) → longitude/latitude in degrees;
//!   - `GTModelType` 1 (projected), user-defined (`ProjectedCSTypeGeoKey` absent or 32767) with
//!     `ProjCoordTransGeoKey`:
//!     - 15 polar stereographic (or 14 stereographic centred on a pole): the pole from the sign
//!       of `ProjNatOriginLatGeoKey`; `lon0` from `ProjStraightVertPoleLongGeoKey`, else
//!       `ProjNatOriginLongGeoKey`, else `ProjCenterLongGeoKey`; the latitude of true scale
//!       from `ProjStdParallel1GeoKey` if given, else from the origin latitude when it is not
//!       ±90 (GDAL stores "variant B" that way), else from `ProjScaleAtNatOriginGeoKey` k₀
//!       (sin |φts| = 2k₀ − 1; k₀ = 1 → ±90);
//!     - 17 equirectangular: true-scale latitude `ProjStdParallel1GeoKey` (default 0), `lon0`
//!       from `ProjCenterLongGeoKey` / `ProjNatOriginLongGeoKey`, an origin latitude
//!       (`ProjCenterLatGeoKey` / `ProjNatOriginLatGeoKey`) shifts y to the equator;
//!     - false easting/northing (3082/3083) are removed from the coordinates; linear units must be
//!       metres;
//!     - the sphere radius is `GeogSemiMajorAxisGeoKey` (2057); a flattened ellipsoid or an
//!       EPSG Earth CRS (3031, 3413, 32661, 32761 …) is reported as unsupported.
//! * `GDAL_NODATA` (42113, ASCII) is the void value.

use std::collections::HashMap;
use std::io::BufReader;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use tiff::decoder::{ChunkType, Decoder, DecodingResult, DecodingSampleType, Limits};
use tiff::tags::Tag;
use tiff::{ColorType, TiffError, TiffFormatError};

use crate::dem::limits;
use crate::dem::types::{check_dimensions, damaged_or_io, Crs, DemParts, GeoRef, Samples};
use crate::error::{Error, IoContext, Result};

/// Decoded samples may be at most this many bytes per byte of file (guards allocations driven
/// by forged headers; real compression ratios of height data are far lower).
const MAX_EXPANSION: u64 = 4096;

const USER_DEFINED: u16 = 32767;

fn tiff_error(path: &Path, e: TiffError) -> Error {
    match e {
        TiffError::UnsupportedError(u) => Error::unsupported(path, format!("TIFF feature: {u}")),
        TiffError::IoError(io) => damaged_or_io(path, io, "TIFF"),
        TiffError::FormatError(f) => Error::invalid(path, format!("damaged TIFF: {f}")),
        other => Error::invalid(path, format!("cannot decode the TIFF: {other}")),
    }
}

pub fn read(path: &Path) -> Result<DemParts> {
    match catch_unwind(AssertUnwindSafe(|| read_inner(path))) {
        Ok(r) => r,
        Err(_) => Err(Error::invalid(
            path,
            "the TIFF is damaged (the decoder gave up on it)",
        )),
    }
}

/// GeoKeyDirectory contents.
#[derive(Default)]
struct GeoKeys {
    shorts: HashMap<u16, u16>,
    doubles: HashMap<u16, f64>,
}

impl GeoKeys {
    fn parse(path: &Path, dir: &[u16], doubles: &[f64]) -> Result<GeoKeys> {
        let bad = |m: &str| Error::invalid(path, format!("GeoKeyDirectory is damaged: {m}"));
        if dir.len() < 4 {
            return Err(bad("shorter than its header"));
        }
        let n = dir[3] as usize;
        if dir.len() < 4 + 4 * n {
            return Err(bad(&format!(
                "it lists {n} keys but holds {}",
                (dir.len() - 4) / 4
            )));
        }
        let mut keys = GeoKeys::default();
        for k in 0..n {
            let e = &dir[4 + 4 * k..8 + 4 * k];
            let (key, loc, count, val) = (e[0], e[1], e[2] as usize, e[3] as usize);
            match loc {
                0 => {
                    keys.shorts.insert(key, e[3]);
                }
                34736 => {
                    let v = doubles
                        .get(val..val + count.max(1))
                        .ok_or_else(|| bad(&format!("key {key} points past GeoDoubleParams")))?;
                    keys.doubles.insert(key, v[0]);
                }
                34735 => {
                    if let Some(&v) = dir.get(val) {
                        keys.shorts.insert(key, v);
                    }
                }
                _ => {} // ASCII citations and unknown locations carry nothing we need
            }
        }
        Ok(keys)
    }

    fn short(&self, key: u16) -> Option<u16> {
        self.shorts.get(&key).copied()
    }
    fn dbl(&self, key: u16) -> Option<f64> {
        self.doubles.get(&key).copied()
    }
    fn first_dbl(&self, keys: &[u16]) -> Option<f64> {
        keys.iter().find_map(|&k| self.dbl(k))
    }
}

fn read_inner(path: &Path) -> Result<DemParts> {
    let file = std::fs::File::open(path).at(path)?;
    let file_len = file.metadata().at(path)?.len();
    let mut limits = Limits::default();
    limits.decoding_buffer_size = 1 << 31;
    let mut dec = Decoder::new(BufReader::new(file))
        .map_err(|e| match e {
            TiffError::FormatError(
                TiffFormatError::TiffSignatureNotFound | TiffFormatError::TiffSignatureInvalid,
            ) => Error::invalid(
                path,
                "not a TIFF file: a GeoTIFF DEM starts with II*\\0 or MM\\0*",
            ),
            e => tiff_error(path, e),
        })?
        .with_limits(limits);
    let te = |e| tiff_error(path, e);
    let (w, h) = dec.dimensions().map_err(te)?;
    check_dimensions(path, w as u64, h as u64)?;
    let bits = match dec.colortype().map_err(te)? {
        ColorType::Gray(b) => b,
        ColorType::Multiband {
            num_samples: 1,
            bit_depth,
        } => bit_depth,
        other => {
            return Err(Error::unsupported(
                path,
                format!("the TIFF is {other:?}: a DEM has one band of heights"),
            ))
        }
    };
    let need_bytes = (w as u64) * (h as u64) * (bits as u64).div_ceil(8);
    if need_bytes > file_len.saturating_mul(MAX_EXPANSION) {
        return Err(Error::invalid(
            path,
            format!("the TIFF claims {w}×{h} samples, impossible for a {file_len}-byte file"),
        ));
    }

    // Georeferencing tags.
    let f64s = |dec: &mut Decoder<_>, tag: Tag| -> Result<Option<Vec<f64>>> {
        match dec.find_tag(tag).map_err(te)? {
            None => Ok(None),
            Some(v) => v.into_f64_vec().map(Some).map_err(|e| {
                Error::invalid(
                    path,
                    format!("GeoTIFF tag {tag:?} is not a list of numbers: {e}"),
                )
            }),
        }
    };
    let scale = f64s(&mut dec, Tag::ModelPixelScaleTag)?;
    let tie = f64s(&mut dec, Tag::ModelTiepointTag)?;
    let transform = f64s(&mut dec, Tag::ModelTransformationTag)?;
    let doubles = f64s(&mut dec, Tag::GeoDoubleParamsTag)?.unwrap_or_default();
    let keys = match dec.find_tag(Tag::GeoKeyDirectoryTag).map_err(te)? {
        None => None,
        Some(v) => {
            let dir = v.into_u16_vec().map_err(|e| {
                Error::invalid(
                    path,
                    format!("GeoKeyDirectory is not a list of shorts: {e}"),
                )
            })?;
            Some(GeoKeys::parse(path, &dir, &doubles)?)
        }
    };
    let nodata = match dec.find_tag(Tag::GdalNodata).map_err(te)? {
        None => None,
        Some(v) => {
            let s = v.into_string().unwrap_or_default();
            let s = s.trim_matches(|c: char| c == '\0' || c.is_whitespace());
            match s.to_ascii_lowercase().as_str() {
                "" | "nan" | "-nan" | "none" => None,
                t => Some(t.parse::<f64>().map_err(|_| {
                    Error::invalid(path, format!("GDAL_NODATA '{s}' is not a number"))
                })? as f32 as f64),
            }
        }
    };
    let (georef, crs_desc) = georef(path, keys.as_ref(), scale, tie, transform, (w, h))?;

    // Samples.
    let (w, h) = (w as usize, h as usize);
    let mut out: Vec<f32> = Vec::new();
    out.try_reserve_exact(w * h)
        .map_err(|_| Error::invalid(path, format!("cannot allocate {w}×{h} samples")))?;
    out.resize(w * h, f32::NAN);
    let (cw, ch) = dec.chunk_dimensions();
    let (cw, ch) = (cw as usize, ch as usize);
    if cw == 0 || ch == 0 {
        return Err(Error::invalid(path, "the TIFF's strips or tiles are empty"));
    }
    let chunk_type = dec.get_chunk_type();
    let (count, across) = match chunk_type {
        ChunkType::Strip => (dec.strip_count().map_err(te)? as usize, 1),
        ChunkType::Tile => (dec.tile_count().map_err(te)? as usize, w.div_ceil(cw)),
    };
    let expected = w.div_ceil(cw) * h.div_ceil(ch);
    let expected = if chunk_type == ChunkType::Strip {
        h.div_ceil(ch)
    } else {
        expected
    };
    if count < expected {
        return Err(Error::invalid(
            path,
            format!("the TIFF has {count} strips/tiles, {expected} expected for {w}×{h}"),
        ));
    }
    let mut sample_name = "";
    for i in 0..expected {
        let (x0, y0) = ((i % across) * cw, (i / across) * ch);
        let (dw, dh) = (cw.min(w - x0), ch.min(h - y0));
        let layout = dec.image_chunk_buffer_layout(i as u32).map_err(te)?;
        if chunk_type == ChunkType::Strip
            && layout.sample_type == Some(DecodingSampleType::F32)
            && dw == w
        {
            sample_name = "float32";
            let dst = &mut out[y0 * w..(y0 + dh) * w];
            // SAFETY: any byte pattern is a valid f32 and u8 has alignment 1; the byte view
            // covers exactly the same memory as `dst` and is dropped before `dst` is used again.
            let bytes = unsafe {
                std::slice::from_raw_parts_mut(dst.as_mut_ptr() as *mut u8, dst.len() * 4)
            };
            dec.read_chunk_bytes(i as u32, bytes).map_err(te)?;
            continue;
        }
        let chunk = dec.read_chunk(i as u32).map_err(te)?;
        let (name, ok) = match &chunk {
            DecodingResult::U8(v) => ("uint8", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32)),
            DecodingResult::I8(v) => ("int8", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32)),
            DecodingResult::U16(v) => ("uint16", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32)),
            DecodingResult::I16(v) => ("int16", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32)),
            DecodingResult::U32(v) => ("uint32", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32)),
            DecodingResult::I32(v) => ("int32", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32)),
            DecodingResult::U64(v) => ("uint64", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32)),
            DecodingResult::I64(v) => ("int64", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32)),
            DecodingResult::F16(v) => (
                "float16",
                put(&mut out, w, x0, y0, dw, dh, v, |s| s.to_f32()),
            ),
            DecodingResult::F32(v) => ("float32", put(&mut out, w, x0, y0, dw, dh, v, |s| s)),
            DecodingResult::F64(v) => {
                ("float64", put(&mut out, w, x0, y0, dw, dh, v, |s| s as f32))
            }
        };
        sample_name = name;
        if !ok {
            return Err(Error::invalid(
                path,
                format!("strip/tile {i} decoded to fewer samples than its {dw}×{dh} pixels"),
            ));
        }
    }
    let layout = match chunk_type {
        ChunkType::Strip => "striped",
        ChunkType::Tile => "tiled",
    };
    Ok(DemParts {
        width: w,
        height: h,
        samples: Samples::Owned(out),
        scale: 1.0,
        offset: 0.0,
        nodata,
        georef,
        datum_radius_m: None,
        target: None,
        sources: vec![path.to_path_buf()],
        format: format!("GeoTIFF {sample_name} {layout}, {crs_desc}"),
    })
}

/// Copy a decoded `dw × dh` chunk into the raster at (`x0`, `y0`). False when `src` is short.
#[allow(clippy::too_many_arguments)]
fn put<T: Copy>(
    out: &mut [f32],
    w: usize,
    x0: usize,
    y0: usize,
    dw: usize,
    dh: usize,
    src: &[T],
    conv: impl Fn(T) -> f32,
) -> bool {
    if src.len() < dw * dh {
        return false;
    }
    for r in 0..dh {
        let d = &mut out[(y0 + r) * w + x0..(y0 + r) * w + x0 + dw];
        for (o, &s) in d.iter_mut().zip(&src[r * dw..(r + 1) * dw]) {
            *o = conv(s);
        }
    }
    true
}

fn georef(
    path: &Path,
    keys: Option<&GeoKeys>,
    scale: Option<Vec<f64>>,
    tie: Option<Vec<f64>>,
    transform: Option<Vec<f64>>,
    (w, h): (u32, u32),
) -> Result<(GeoRef, String)> {
    // Raster point (0, 0) in CRS units, and the pixel size.
    let placed_by = if scale.is_some() && tie.is_some() {
        "ModelPixelScale and ModelTiepoint"
    } else {
        "ModelTransformation"
    };
    let (cx, cy, sx, sy) = match (scale, tie, transform) {
        // With several tiepoints and a pixel scale, the first tiepoint places the grid.
        (Some(s), Some(t), _) if s.len() >= 2 && t.len() >= 6 => {
            (t[3] - t[0] * s[0], t[4] + t[1] * s[1], s[0], s[1])
        }
        (_, _, Some(m)) if m.len() >= 16 => {
            if m[1] != 0.0 || m[4] != 0.0 {
                return Err(Error::unsupported(
                    path,
                    "the ModelTransformation rotates the raster: reproject it to a north-up grid",
                ));
            }
            (m[3], m[7], m[0], -m[5])
        }
        (None, Some(_), None) => {
            return Err(Error::unsupported(
                path,
                "the GeoTIFF is placed by tiepoints only (no ModelPixelScale): warp it to a \
                 regular grid first",
            ))
        }
        _ => {
            return Err(Error::invalid(
                path,
                "no georeferencing (ModelTiepoint/ModelPixelScale): the TIFF cannot be placed \
                 on the body",
            ))
        }
    };
    if !(cx.is_finite() && cy.is_finite()) {
        return Err(Error::invalid(
            path,
            format!(
                "the raster's origin ({}, {}) from {placed_by} is not finite",
                limits::show(cx),
                limits::show(cy)
            ),
        ));
    }
    if !(sx.is_finite() && sy.is_finite()) || sx <= 0.0 || sy == 0.0 {
        return Err(Error::invalid(
            path,
            format!(
                "pixel scale ({}, {}) from {placed_by} is not usable: it must be finite, x > 0, \
                 y ≠ 0",
                limits::show(sx),
                limits::show(sy)
            ),
        ));
    }
    let Some(keys) = keys else {
        return Err(Error::invalid(
            path,
            "no GeoKeyDirectory: the TIFF is placed but its CRS is unknown",
        ));
    };
    let point = keys.short(1025) == Some(2);
    let (mut x0, mut y0) = if point {
        (cx, cy)
    } else {
        (cx + 0.5 * sx, cy - 0.5 * sy)
    };
    let registration = if point { "PixelIsPoint" } else { "PixelIsArea" };
    let model = keys.short(1024);
    let crs = match model {
        Some(2) => {
            if let Some(u) = keys.short(2054) {
                if u != 9102 {
                    return Err(Error::unsupported(
                        path,
                        format!("geographic angular unit EPSG:{u}: only degrees (9102) are read"),
                    ));
                }
            }
            limits::pixel_deg(path, &format!("{placed_by} x pixel size"), sx)?;
            limits::pixel_deg(path, &format!("{placed_by} y pixel size"), sy)?;
            Crs::Geographic
        }
        Some(1) => {
            let crs = projected(path, keys, &mut x0, &mut y0)?;
            if let Crs::Equirectangular { radius_m, .. }
            | Crs::PolarStereographic { radius_m, .. } = crs
            {
                limits::pixel_m(
                    path,
                    &format!("{placed_by} x pixel size"),
                    sx,
                    Some(radius_m),
                )?;
                limits::pixel_m(
                    path,
                    &format!("{placed_by} y pixel size"),
                    sy,
                    Some(radius_m),
                )?;
            }
            crs
        }
        Some(m) => {
            return Err(Error::unsupported(
                path,
                format!("GTModelType {m}: only projected (1) and geographic (2) rasters are read"),
            ))
        }
        None => {
            return Err(Error::invalid(
                path,
                "the GeoKeyDirectory has no GTModelType: the CRS is unknown",
            ))
        }
    };
    let desc = match &crs {
        Crs::Geographic => format!("geographic {} deg/px ({registration})", sx),
        Crs::Equirectangular { lat_ts_deg, .. } => {
            format!("equirectangular true scale at {lat_ts_deg}°, {sx} m/px ({registration})")
        }
        Crs::PolarStereographic {
            north, lat_ts_deg, ..
        } => format!(
            "polar stereographic ({} pole, true scale at {lat_ts_deg}°), {sx} m/px ({registration})",
            if *north { "north" } else { "south" }
        ),
    };
    let g = GeoRef {
        crs,
        x0,
        y0,
        dx: sx,
        dy: sy,
    };
    limits::check_georef(path, &g, w as usize, h as usize, placed_by)?;
    Ok((g, desc))
}

fn projected(path: &Path, keys: &GeoKeys, x0: &mut f64, y0: &mut f64) -> Result<Crs> {
    if let Some(pcs) = keys.short(3072) {
        if pcs != USER_DEFINED && pcs != 0 {
            return Err(Error::unsupported(
                path,
                format!(
                    "ProjectedCSTypeGeoKey EPSG:{pcs}: Penumbra reads user-defined spherical \
                     projections (as planetary GeoTIFFs use); Earth EPSG projections such as 3031 \
                     or 32761 sit on an ellipsoid — reproject to geographic coordinates"
                ),
            ));
        }
    }
    let Some(ct) = keys.short(3075) else {
        return Err(match keys.short(3074) {
            Some(p) if p != USER_DEFINED => Error::unsupported(
                path,
                format!("ProjectionGeoKey EPSG:{p} (a predefined Earth projection) is not read"),
            ),
            _ => Error::invalid(
                path,
                "projected GeoTIFF without ProjCoordTransGeoKey: the projection is unknown",
            ),
        });
    };
    if let Some(u) = keys.short(3076) {
        if u != 9001 {
            return Err(Error::unsupported(
                path,
                format!("projected linear unit EPSG:{u}: only metres (9001) are read"),
            ));
        }
    }
    let Some(a) = keys.dbl(2057) else {
        let msg = match (keys.short(2048), keys.short(2056)) {
            (Some(g), _) if g != USER_DEFINED => Some(format!("geographic CRS EPSG:{g}")),
            (_, Some(e)) if e != USER_DEFINED => Some(format!("ellipsoid EPSG:{e}")),
            _ => None,
        };
        return Err(match msg {
            Some(m) => Error::unsupported(
                path,
                format!("{m}: Penumbra's projections are spherical; give GeogSemiMajorAxisGeoKey"),
            ),
            None => Error::invalid(
                path,
                "no GeogSemiMajorAxisGeoKey: the sphere's radius is unknown",
            ),
        });
    };
    limits::radius(path, "GeogSemiMajorAxisGeoKey (2057)", a)?;
    let b = keys.dbl(2058);
    let inv_f = keys.dbl(2059);
    let flattened = b.is_some_and(|b| (a - b).abs() > 1e-9 * a) || inv_f.is_some_and(|f| f != 0.0);
    if flattened {
        return Err(Error::unsupported(
            path,
            format!(
                "the ellipsoid is flattened (a = {a}, b = {b:?}, 1/f = {inv_f:?}): Penumbra's \
                 projections are spherical"
            ),
        ));
    }
    *x0 -= limits::finite(
        path,
        "ProjFalseEastingGeoKey (3082)",
        keys.dbl(3082).unwrap_or(0.0),
    )?;
    *y0 -= limits::finite(
        path,
        "ProjFalseNorthingGeoKey (3083)",
        keys.dbl(3083).unwrap_or(0.0),
    )?;
    // Every angle the projections below may read.
    for (key, name, lat) in [
        (3078, "ProjStdParallel1GeoKey (3078)", true),
        (3081, "ProjNatOriginLatGeoKey (3081)", true),
        (3085, "ProjFalseOriginLatGeoKey (3085)", true),
        (3089, "ProjCenterLatGeoKey (3089)", true),
        (3080, "ProjNatOriginLongGeoKey (3080)", false),
        (3088, "ProjCenterLongGeoKey (3088)", false),
        (3095, "ProjStraightVertPoleLongGeoKey (3095)", false),
    ] {
        if let Some(v) = keys.dbl(key) {
            if lat {
                limits::latitude(path, name, v)?;
            } else {
                limits::longitude(path, name, v)?;
            }
        }
    }
    match ct {
        15 | 14 => {
            let lat_origin = keys.first_dbl(&[3081, 3089, 3085]).unwrap_or(0.0);
            let std1 = keys.dbl(3078);
            let polar_origin = (lat_origin.abs() - 90.0).abs() < 1e-9;
            if ct == 14 && !polar_origin {
                return Err(Error::unsupported(
                    path,
                    format!(
                        "stereographic projection centred at latitude {lat_origin} (not a pole)"
                    ),
                ));
            }
            let sign_src = if lat_origin != 0.0 {
                lat_origin
            } else {
                std1.unwrap_or(0.0)
            };
            if sign_src == 0.0 {
                return Err(Error::invalid(
                    path,
                    "polar stereographic without an origin latitude: which pole is unknown",
                ));
            }
            let north = sign_src > 0.0;
            let pole = if north { 90.0 } else { -90.0 };
            let k0 = keys.first_dbl(&[3092, 3093]).unwrap_or(1.0);
            let lat_ts = if let Some(s) = std1 {
                s
            } else if !polar_origin {
                if (k0 - 1.0).abs() > 1e-12 {
                    return Err(Error::unsupported(
                        path,
                        "polar stereographic with both a true-scale latitude and a scale factor",
                    ));
                }
                lat_origin
            } else {
                if !(k0 > 0.0 && k0 <= 1.0) {
                    return Err(Error::invalid(
                        path,
                        format!("polar stereographic scale factor {k0} is not in (0, 1]"),
                    ));
                }
                (2.0 * k0 - 1.0).asin().to_degrees().copysign(pole)
            };
            let lon0 = keys.first_dbl(&[3095, 3080, 3088]).unwrap_or(0.0);
            Ok(Crs::PolarStereographic {
                north,
                lon0_deg: lon0,
                lat_ts_deg: lat_ts,
                radius_m: a,
            })
        }
        17 => {
            let lat_ts = keys.dbl(3078).unwrap_or(0.0);
            if lat_ts.abs() >= 89.0 {
                return Err(Error::invalid(
                    path,
                    format!("equirectangular true-scale latitude {lat_ts} is not usable"),
                ));
            }
            let lon0 = keys.first_dbl(&[3088, 3080]).unwrap_or(0.0);
            let lat0 = keys.first_dbl(&[3089, 3081]).unwrap_or(0.0);
            *y0 += a * lat0.to_radians();
            Ok(Crs::Equirectangular {
                lat_ts_deg: lat_ts,
                lon0_deg: lon0,
                radius_m: a,
            })
        }
        other => Err(Error::unsupported(
            path,
            format!(
                "ProjCoordTransGeoKey {other}: Penumbra reads polar stereographic (15) and \
                 equirectangular (17) GeoTIFFs; reproject others"
            ),
        )),
    }
}
