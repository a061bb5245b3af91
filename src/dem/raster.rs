//! [`Dem`]: a georeferenced raster ready for sampling — void filling at load, footprint, and
//! interpolation at a pixel or a direction (docs/formats.md).

use std::collections::HashMap;
use std::path::PathBuf;

use super::limits;
use super::types::*;
use crate::error::{Error, Result};

/// A georeferenced elevation raster, ready for sampling.
pub struct Dem {
    p: DemParts,
    /// Filled voids: (row-major index, height), sorted by index.
    fills: Vec<(u64, f32)>,
    void_count: u64,
    unfilled_count: u64,
    global_lon: bool,
    global_lat: bool,
    x_centre: f64,
    /// A spherical cap (centre direction, angular radius) that contains the whole raster,
    /// for rasters well inside a hemisphere.
    cap: Option<([f64; 3], f64)>,
}

impl Dem {
    /// Check the parts and fill voids up to `max_fill_px` pixels from measured data.
    pub fn new(parts: DemParts, max_fill_px: u32) -> Result<Dem> {
        let path = parts.sources.first().cloned().unwrap_or_default();
        let (w, h) = (parts.width, parts.height);
        check_dimensions(&path, w as u64, h as u64)?;
        match &parts.samples {
            Samples::Mapped {
                map,
                offset,
                row_stride,
                ty,
                ..
            } => {
                let need = (*offset as u128)
                    + (*row_stride as u128) * (h as u128 - 1)
                    + (w as u128) * (ty.size() as u128);
                if *row_stride < w * ty.size() {
                    return Err(Error::invalid(&path, "row stride is shorter than a row"));
                }
                if need > map.len() as u128 {
                    return Err(Error::invalid(
                        &path,
                        format!(
                            "file is truncated: {w}×{h} samples of {} bytes from byte {offset} \
                             need {need} bytes, the file has {}",
                            ty.size(),
                            map.len()
                        ),
                    ));
                }
            }
            Samples::Owned(v) => {
                if v.len() != w * h {
                    return Err(Error::invalid(
                        &path,
                        format!("{} samples decoded, {w}×{h} expected", v.len()),
                    ));
                }
            }
        }
        // The readers check each key as they parse it; this catches what they combined (and
        // DEMs built by code rather than read from a file).
        let g = &parts.georef;
        limits::check_georef(&path, g, w, h, "the georeferencing")?;
        let ty = match &parts.samples {
            Samples::Mapped { ty, .. } => Some(*ty),
            Samples::Owned(_) => None,
        };
        limits::scale_offset(&path, ("scale", parts.scale), ("offset", parts.offset), ty)?;
        if let Some(r) = parts.datum_radius_m {
            limits::radius(&path, "datum radius", r)?;
        }
        let (global_lon, global_lat) = match g.crs {
            Crs::Geographic => {
                let span_x = g.dx * w as f64;
                let span_y = g.dy * h as f64;
                let glon = (span_x - 360.0).abs() < 1e-6 * 360.0;
                let top = g.y0 + g.dy / 2.0;
                let glat = glon
                    && w % 2 == 0
                    && (span_y - 180.0).abs() < 1e-6 * 180.0
                    && (top - 90.0).abs() < 1e-6;
                (glon, glat)
            }
            _ => (false, false),
        };
        let x_centre = g.x0 + g.dx * (w as f64 - 1.0) / 2.0;
        let mut dem = Dem {
            p: parts,
            fills: Vec::new(),
            void_count: 0,
            unfilled_count: 0,
            global_lon,
            global_lat,
            x_centre,
            cap: None,
        };
        dem.cap = dem.bounding_cap();
        dem.fill_voids(max_fill_px)?;
        Ok(dem)
    }

    pub fn width(&self) -> usize {
        self.p.width
    }
    pub fn height(&self) -> usize {
        self.p.height
    }
    pub fn georef(&self) -> &GeoRef {
        &self.p.georef
    }
    pub fn datum_radius_m(&self) -> Option<f64> {
        self.p.datum_radius_m
    }
    pub fn target(&self) -> Option<&str> {
        self.p.target.as_deref()
    }
    pub fn sources(&self) -> &[PathBuf] {
        &self.p.sources
    }
    pub fn format(&self) -> &str {
        &self.p.format
    }
    /// Voids in the file, and how many of them stayed no data after filling.
    pub fn void_counts(&self) -> (u64, u64) {
        (self.void_count, self.unfilled_count)
    }
    /// Whether the raster wraps around in longitude / covers both poles.
    pub fn is_global(&self) -> (bool, bool) {
        (self.global_lon, self.global_lat)
    }

    /// The DN stored at (`col`, `row`), before scaling and the void test.
    #[inline]
    fn dn(&self, col: usize, row: usize) -> f64 {
        match &self.p.samples {
            Samples::Owned(v) => v[row * self.p.width + col] as f64,
            Samples::Mapped {
                map,
                offset,
                row_stride,
                ty,
                order,
            } => {
                let at = offset + row * row_stride + col * ty.size();
                decode(&map[at..at + ty.size()], *ty, *order)
            }
        }
    }

    /// Height in metres of the sample at (`col`, `row`), NaN for a void, before filling.
    #[inline]
    pub fn raw(&self, col: usize, row: usize) -> f32 {
        let v = self.dn(col, row);
        if !v.is_finite() || self.p.nodata == Some(v) {
            return f32::NAN;
        }
        (v * self.p.scale + self.p.offset) as f32
    }

    /// [`Dem::sample_pixel`] for a row of positions, the same values: bilinear samples whose
    /// four taps are inside the raster and measured are read with the sample type and byte
    /// order dispatched once for the row (the tiler's inner loop); everything else goes through
    /// [`Dem::sample_pixel`].
    pub fn sample_row(
        &self,
        coords: &[(f64, f64)],
        method: Resampling,
        height: &mut [f32],
        mask_out: &mut [u8],
    ) {
        debug_assert!(coords.len() == height.len() && coords.len() == mask_out.len());
        if method != Resampling::Bilinear {
            return self.sample_each(coords, method, height, mask_out);
        }
        let w = self.p.width;
        match &self.p.samples {
            Samples::Owned(v) => {
                self.bilinear_row(coords, height, mask_out, |c, r| owned_quad(v, w, r * w + c))
            }
            Samples::Mapped {
                map,
                offset,
                row_stride,
                ty,
                order,
            } => {
                let (map, offset, row_stride) = (&map[..], *offset, *row_stride);
                macro_rules! rows {
                    ($t:ty, $n:expr, $from:ident) => {
                        self.bilinear_row(coords, height, mask_out, |c, r| {
                            let a = offset + r * row_stride + c * $n;
                            mapped_quad::<$n>(map, a, a + row_stride, |x| <$t>::$from(x) as f64)
                        })
                    };
                }
                match (ty, order) {
                    (SampleType::U8, _) => rows!(u8, 1, from_le_bytes),
                    (SampleType::I16, ByteOrder::Big) => rows!(i16, 2, from_be_bytes),
                    (SampleType::I16, ByteOrder::Little) => rows!(i16, 2, from_le_bytes),
                    (SampleType::U16, ByteOrder::Big) => rows!(u16, 2, from_be_bytes),
                    (SampleType::U16, ByteOrder::Little) => rows!(u16, 2, from_le_bytes),
                    (SampleType::F32, ByteOrder::Big) => rows!(f32, 4, from_be_bytes),
                    (SampleType::F32, ByteOrder::Little) => rows!(f32, 4, from_le_bytes),
                    _ => self.sample_each(coords, method, height, mask_out),
                }
            }
        }
    }

    /// [`Dem::sample_pixel`] at each position of a row.
    fn sample_each(
        &self,
        coords: &[(f64, f64)],
        method: Resampling,
        height: &mut [f32],
        mask_out: &mut [u8],
    ) {
        for ((h, m), &(c, r)) in height.iter_mut().zip(mask_out.iter_mut()).zip(coords) {
            (*h, *m) = self.sample_pixel(c, r, method);
        }
    }

    /// The bilinear fast path of [`Dem::sample_pixel`] over a row, `raw4(c, r)` giving the raw
    /// samples of (c, r), (c+1, r), (c, r+1), (c+1, r+1) as [`Dem::quad`] reads them.
    #[inline(always)]
    fn bilinear_row(
        &self,
        coords: &[(f64, f64)],
        height: &mut [f32],
        mask_out: &mut [u8],
        raw4: impl Fn(usize, usize) -> [f64; 4],
    ) {
        let (w, h) = (self.p.width, self.p.height);
        for ((ho, mo), &(col, row)) in height.iter_mut().zip(mask_out.iter_mut()).zip(coords) {
            if !(col.is_finite() && row.is_finite() && self.covers(col, row)) {
                (*ho, *mo) = (f32::NAN, mask::NO_DATA);
                continue;
            }
            let (c0, r0) = (floor_fast(col), floor_fast(row));
            let (fc, fr) = (col - c0, row - r0);
            let (c0, r0) = (c0 as i64, r0 as i64);
            if c0 >= 0 && r0 >= 0 && ((c0 + 1) as usize) < w && ((r0 + 1) as usize) < h {
                if let Some(q) = self.scaled(raw4(c0 as usize, r0 as usize)) {
                    (*ho, *mo) = (bilerp4(q, fc, fr), mask::MEASURED);
                    continue;
                }
            }
            (*ho, *mo) = self.sample_pixel(col, row, Resampling::Bilinear);
        }
    }

    /// Heights of pixels (c, r), (c+1, r), (c, r+1), (c+1, r+1), all inside the raster, or
    /// `None` when any of them is a void. One dispatch on the sample type for all four.
    #[inline]
    fn quad(&self, c: usize, r: usize) -> Option<[f32; 4]> {
        let w = self.p.width;
        let raw: [f64; 4] = match &self.p.samples {
            Samples::Owned(v) => owned_quad(v, w, r * w + c),
            Samples::Mapped {
                map,
                offset,
                row_stride,
                ty,
                order,
            } => {
                let sz = ty.size();
                let a = offset + r * row_stride + c * sz;
                let b = a + row_stride;
                macro_rules! four {
                    ($t:ty, $n:expr) => {
                        match order {
                            ByteOrder::Little => {
                                mapped_quad::<$n>(map, a, b, |x| <$t>::from_le_bytes(x) as f64)
                            }
                            ByteOrder::Big => {
                                mapped_quad::<$n>(map, a, b, |x| <$t>::from_be_bytes(x) as f64)
                            }
                        }
                    };
                }
                match ty {
                    SampleType::U8 => [
                        map[a] as f64,
                        map[a + 1] as f64,
                        map[b] as f64,
                        map[b + 1] as f64,
                    ],
                    SampleType::I16 => four!(i16, 2),
                    SampleType::U16 => four!(u16, 2),
                    SampleType::I32 => four!(i32, 4),
                    SampleType::U32 => four!(u32, 4),
                    SampleType::F32 => four!(f32, 4),
                    SampleType::F64 => four!(f64, 8),
                }
            }
        };
        self.scaled(raw)
    }

    /// Heights of four raw samples, or `None` when any of them is a void.
    #[inline(always)]
    fn scaled(&self, raw: [f64; 4]) -> Option<[f32; 4]> {
        let mut out = [0f32; 4];
        for (o, v) in out.iter_mut().zip(raw) {
            if !v.is_finite() || self.p.nodata == Some(v) {
                return None;
            }
            *o = (v * self.p.scale + self.p.offset) as f32;
        }
        Some(out)
    }

    /// Height after void filling and whether it was filled; NaN when it stayed no data.
    #[inline]
    pub fn value(&self, col: usize, row: usize) -> (f32, bool) {
        let v = self.raw(col, row);
        if !v.is_nan() {
            return (v, false);
        }
        let idx = (row * self.p.width + col) as u64;
        match self.fills.binary_search_by_key(&idx, |f| f.0) {
            Ok(i) => (self.fills[i].1, true),
            Err(_) => (f32::NAN, false),
        }
    }

    fn fill_voids(&mut self, max_fill_px: u32) -> Result<()> {
        let (w, h) = (self.p.width, self.p.height);
        let mut voids = Vec::new();
        for r in 0..h {
            for c in 0..w {
                if self.raw(c, r).is_nan() {
                    voids.push((r * w + c) as u64);
                }
            }
        }
        self.void_count = voids.len() as u64;
        if voids.len() as u64 == (w * h) as u64 {
            // Name the samples' file; the no-data value may come from the label or sidecar.
            let data = self.p.sources.last().cloned().unwrap_or_default();
            let first = self.p.sources.first().cloned().unwrap_or_default();
            let also = if first != data {
                format!(" (no-data value from {})", first.display())
            } else {
                String::new()
            };
            return Err(Error::invalid(
                data,
                format!("every sample is a void (no-data value or NaN{also}): nothing to tile"),
            ));
        }
        let mut filled: HashMap<u64, f32> = HashMap::new();
        let mut remaining = voids;
        for _pass in 0..max_fill_px {
            if remaining.is_empty() {
                break;
            }
            let mut newly = Vec::new();
            let mut next = Vec::new();
            for &idx in &remaining {
                let (c, r) = ((idx % w as u64) as i64, (idx / w as u64) as i64);
                let (mut sum, mut n) = (0.0f64, 0u32);
                for dr in -1..=1i64 {
                    for dc in -1..=1i64 {
                        let (cc, rr) = (c + dc, r + dr);
                        if (dc == 0 && dr == 0)
                            || cc < 0
                            || rr < 0
                            || cc >= w as i64
                            || rr >= h as i64
                        {
                            continue;
                        }
                        let v = self.raw(cc as usize, rr as usize);
                        let v = if v.is_nan() {
                            match filled.get(&((rr as u64) * w as u64 + cc as u64)) {
                                Some(f) => *f,
                                None => continue,
                            }
                        } else {
                            v
                        };
                        sum += v as f64;
                        n += 1;
                    }
                }
                if n > 0 {
                    newly.push((idx, (sum / n as f64) as f32));
                } else {
                    next.push(idx);
                }
            }
            if newly.is_empty() {
                break;
            }
            filled.extend(newly);
            remaining = next;
        }
        self.unfilled_count = remaining.len() as u64;
        let mut fills: Vec<(u64, f32)> = filled.into_iter().collect();
        fills.sort_unstable_by_key(|f| f.0);
        self.fills = fills;
        Ok(())
    }

    /// Fractional pixel position (col, row) of latitude/longitude in degrees.
    #[inline]
    pub fn to_pixel(&self, lat_deg: f64, lon_deg: f64) -> (f64, f64) {
        let g = &self.p.georef;
        let (x, y) = g.forward(lat_deg, lon_deg, self.x_centre);
        ((x - g.x0) / g.dx, (g.y0 - y) / g.dy)
    }

    /// Latitude/longitude in degrees of a fractional pixel position.
    pub fn to_latlon(&self, col: f64, row: f64) -> (f64, f64) {
        let g = &self.p.georef;
        g.inverse(g.x0 + col * g.dx, g.y0 - row * g.dy)
    }

    /// Nominal ground size of one pixel in metres on a sphere of `radius_m` (the latitude
    /// spacing for geographic rasters).
    pub fn pixel_size_m(&self, radius_m: f64) -> f64 {
        let g = &self.p.georef;
        match g.crs {
            Crs::Geographic => g.dy.abs().to_radians() * radius_m,
            _ => g.dx.abs().min(g.dy.abs()),
        }
    }

    /// Refuse a DEM that cannot be terrain on a sphere of `radius_m` (the body it is tiled
    /// for), before anything is written:
    ///
    /// * a datum radius that differs from `radius_m` by more than half of it
    ///   ([`MAX_DATUM_MISMATCH`]): every height would move by more than half the body, which
    ///   only happens when the DEM belongs to another body or its radius is in the wrong unit;
    /// * a pixel smaller than 1 mm or larger than the body's circumference on the body;
    /// * a raster that covers less than one of its own pixels of the sphere (rows beyond a
    ///   pole);
    /// * a measured sample whose height above the body's sphere — `DN · scale + offset`, plus
    ///   the datum shift `datum_radius − radius_m` — is not finite or beyond ±`radius_m`.
    ///
    /// Reads every sample once (in parallel by rows); voids are skipped. Returns the extremes
    /// of the heights it found (the datum shift included).
    pub fn check_plausible(&self, radius_m: f64) -> Result<HeightExtremes> {
        let first = self.p.sources.first().cloned().unwrap_or_default();
        let data = self.p.sources.last().cloned().unwrap_or_default();
        let see = "see docs/formats.md, \"Plausibility limits\"";
        let show = limits::show;
        let shift = match self.p.datum_radius_m {
            None => 0.0,
            Some(r0) => {
                let off = (r0 - radius_m).abs();
                if !(off.is_finite() && off <= MAX_DATUM_MISMATCH * radius_m) {
                    return Err(Error::invalid(
                        &first,
                        format!(
                            "datum radius {} m (PDS3 OFFSET above 100 km, or sidecar \
                             datum_radius_m) is more than 50 % away from the body's radius {} m: \
                             heights would move by more than half the body. The DEM is of \
                             another body, or the radius is in the wrong unit; give the right \
                             --body/--radius-m or fix the datum ({see})",
                            show(r0),
                            show(radius_m)
                        ),
                    ));
                }
                r0 - radius_m
            }
        };

        let g = &self.p.georef;
        let (px, py) = match g.crs {
            Crs::Geographic => (
                g.dx.abs().to_radians() * radius_m,
                g.dy.abs().to_radians() * radius_m,
            ),
            Crs::Equirectangular { radius_m: rc, .. }
            | Crs::PolarStereographic { radius_m: rc, .. } => {
                (g.dx.abs() * radius_m / rc, g.dy.abs() * radius_m / rc)
            }
        };
        let circumference = 2.0 * std::f64::consts::PI * radius_m;
        for (axis, v) in [("x", px), ("y", py)] {
            if !(v.is_finite() && (limits::MIN_PIXEL_M..=circumference).contains(&v)) {
                return Err(Error::invalid(
                    &first,
                    format!(
                        "pixel size along {axis} is {} m on a body of radius {} m: it must lie \
                         within 1 mm .. the body's circumference ({} m); check the pixel \
                         spacing / resolution keys and the body ({see})",
                        show(v),
                        show(radius_m),
                        show(circumference)
                    ),
                ));
            }
        }

        // Latitude extent of the raster's edges on the sphere, against one pixel.
        let lat_of = |y: f64| match g.crs {
            Crs::Equirectangular { radius_m: rc, .. } => Some((y / rc).to_degrees()),
            Crs::Geographic => Some(y),
            Crs::PolarStereographic { .. } => None,
        };
        let top = g.y0 + g.dy / 2.0;
        let bottom = g.y0 - (self.p.height as f64 - 0.5) * g.dy;
        if let (Some(a), Some(b), Some(d0), Some(d1)) =
            (lat_of(top), lat_of(bottom), lat_of(0.0), lat_of(g.dy.abs()))
        {
            let (a, b) = (a.clamp(-90.0, 90.0), b.clamp(-90.0, 90.0));
            let extent = (a - b).abs();
            if !(extent.is_finite() && extent >= (d1 - d0) * (1.0 - 1e-9)) {
                return Err(Error::invalid(
                    &first,
                    format!(
                        "the raster covers less than one pixel of the sphere (its rows lie \
                         beyond a pole: edges at latitude {} and {}); fix the georeferencing \
                         ({see})",
                        show(lat_of(top).unwrap_or(f64::NAN)),
                        show(lat_of(bottom).unwrap_or(f64::NAN))
                    ),
                ));
            }
        }

        // One pass over the samples: the measured height farthest from the sphere, and the
        // lowest and highest (for the relief check, [`Dem::check_for_body`]).
        let ext = self.height_extremes(shift);
        if let Some(w) = ext.farthest {
            if !(w.height_m.is_finite() && w.height_m.abs() <= radius_m) {
                let (c, r) = (w.col, w.row);
                let dn = self.dn(c, r);
                let (scale, offset) = (self.p.scale, self.p.offset);
                let h = dn * scale + offset + shift;
                let also = if first != data {
                    format!(" and the scale/offset in {}", first.display())
                } else {
                    String::new()
                };
                return Err(Error::invalid(
                    &data,
                    format!(
                        "sample (column {c}, row {r}) is DN {} → {} m above the body's sphere \
                         (DN × scale {} + offset {} + datum shift {} m): heights must be finite \
                         and within ± the body's radius {} m. Check the samples (a void value \
                         not declared as no-data?){also} ({see})",
                        show(dn),
                        show(h),
                        show(scale),
                        show(offset),
                        show(shift),
                        show(radius_m)
                    ),
                ));
            }
        }
        Ok(ext)
    }

    /// The measured (non-void) samples' heights above the sphere, `DN · scale + offset +
    /// shift`: the lowest, the highest and the farthest from zero (a non-finite height counts
    /// as infinitely far), each with its pixel; ties go to the first sample in the file, so the
    /// answer does not depend on the thread count. One pass over the samples, by rows in
    /// parallel.
    pub(crate) fn height_extremes(&self, shift: f64) -> HeightExtremes {
        let (scale, offset, nodata) = (self.p.scale, self.p.offset, self.p.nodata);
        let of_row = |r: usize| -> HeightExtremes {
            // Plain locals in the loop (an Option per extreme cost 3× the pass); strict
            // comparisons keep the first sample of the row on ties.
            let (mut lo, mut hi, mut far) = (f64::INFINITY, f64::NEG_INFINITY, -1.0f64);
            let (mut lc, mut hc, mut fc) = (usize::MAX, usize::MAX, usize::MAX);
            let mut see = |c: usize, v: f64| {
                if v.is_finite() && nodata != Some(v) {
                    let h = v * scale + offset + shift;
                    let a = if h.is_finite() {
                        h.abs()
                    } else {
                        f64::INFINITY
                    };
                    if a > far {
                        (far, fc) = (a, c);
                    }
                    if h < lo {
                        (lo, lc) = (h, c);
                    }
                    if h > hi {
                        (hi, hc) = (h, c);
                    }
                }
            };
            match &self.p.samples {
                Samples::Owned(v) => {
                    let row = &v[r * self.p.width..(r + 1) * self.p.width];
                    for (c, &x) in row.iter().enumerate() {
                        see(c, x as f64);
                    }
                }
                Samples::Mapped {
                    map,
                    offset,
                    row_stride,
                    ty,
                    order,
                } => {
                    let at = offset + r * row_stride;
                    for_each_dn(&map[at..at + self.p.width * ty.size()], *ty, *order, see);
                }
            }
            let at = |h: f64, col: usize| {
                (col != usize::MAX).then_some(HeightAt {
                    height_m: h,
                    col,
                    row: r,
                })
            };
            // A non-finite farthest height is reported as the height it is.
            let far_h = if fc == usize::MAX {
                0.0
            } else {
                let v = self.dn(fc, r);
                v * scale + offset + shift
            };
            HeightExtremes {
                lowest: at(lo, lc),
                highest: at(hi, hc),
                farthest: at(far_h, fc),
            }
        };
        use rayon::prelude::*;
        (0..self.p.height)
            .into_par_iter()
            .map(of_row)
            .reduce(HeightExtremes::default, HeightExtremes::merge)
    }

    /// The DN of a sample as stored (before scaling).
    pub(crate) fn dn_at(&self, col: usize, row: usize) -> f64 {
        self.dn(col, row)
    }

    /// Resolve a possibly out-of-range integer pixel to one inside the raster: wrap in
    /// longitude and reflect across the poles for global rasters, clamp otherwise.
    #[inline]
    pub(crate) fn resolve(&self, c: i64, r: i64) -> (usize, usize) {
        let (w, h) = (self.p.width as i64, self.p.height as i64);
        let (mut c, mut r) = (c, r);
        if self.global_lat && (r < 0 || r >= h) {
            r = if r < 0 { -1 - r } else { 2 * h - 1 - r };
            r = r.clamp(0, h - 1);
            c += w / 2;
        }
        if self.global_lon {
            c = c.rem_euclid(w);
        } else {
            c = c.clamp(0, w - 1);
        }
        (c as usize, r.clamp(0, h - 1) as usize)
    }

    /// Whether a fractional pixel position lies on the raster (within half a pixel of the
    /// outermost centres; any position for the wrapped axes of global rasters).
    #[inline]
    pub fn covers(&self, col: f64, row: f64) -> bool {
        let (w, h) = (self.p.width as f64, self.p.height as f64);
        let col_ok = self.global_lon || (col >= -0.5 && col <= w - 0.5);
        let row_ok = self.global_lat || (row >= -0.5 && row <= h - 0.5);
        col_ok && row_ok
    }

    /// Whether every point of the convex hull of `pts` (source col, row) lies more than
    /// `margin` pixels beyond one and the same edge of the raster, so that [`Dem::covers`] fails
    /// everywhere in it. Never for an axis the raster wraps or spans whole.
    pub fn beyond_one_edge(&self, pts: &[(f64, f64)], margin: f64) -> bool {
        // All of one coordinate below the raster's first centre − ½ − margin, or all above its
        // last centre + ½ + margin.
        let off = |n: usize, coord: fn(&(f64, f64)) -> f64| {
            pts.iter().all(|p| coord(p) < -0.5 - margin)
                || pts.iter().all(|p| coord(p) > n as f64 - 0.5 + margin)
        };
        (!self.global_lon && off(self.p.width, |p| p.0))
            || (!self.global_lat && off(self.p.height, |p| p.1))
    }

    /// Interpolated height (m above the DEM's datum) at latitude/longitude in degrees, with its
    /// mask value (see [`mask`]). NaN with `NO_DATA` off the raster or on unfilled voids.
    #[inline]
    pub fn sample(&self, lat_deg: f64, lon_deg: f64, method: Resampling) -> (f32, u8) {
        let (col, row) = self.to_pixel(lat_deg, lon_deg);
        self.sample_pixel(col, row, method)
    }

    /// As [`Dem::sample`], for a unit direction in the body frame.
    #[inline]
    pub fn sample_dir(&self, d: [f64; 3], method: Resampling) -> (f32, u8) {
        let (col, row) = self.dir_to_pixel(d);
        self.sample_pixel(col, row, method)
    }

    /// Fractional pixel position (col, row) of a unit direction in the body frame.
    #[inline]
    pub fn dir_to_pixel(&self, d: [f64; 3]) -> (f64, f64) {
        let g = &self.p.georef;
        let (x, y) = g.forward_dir(d, self.x_centre);
        ((x - g.x0) / g.dx, (g.y0 - y) / g.dy)
    }

    /// As [`Dem::sample`], at a fractional pixel position.
    pub fn sample_pixel(&self, col: f64, row: f64, method: Resampling) -> (f32, u8) {
        if !(col.is_finite() && row.is_finite() && self.covers(col, row)) {
            return (f32::NAN, mask::NO_DATA);
        }
        let (c0, r0) = (floor_fast(col), floor_fast(row));
        let (fc, fr) = (col - c0, row - r0);
        let (c0, r0) = (c0 as i64, r0 as i64);
        if method == Resampling::Bicubic {
            let wc = catmull_rom(fc);
            let wr = catmull_rom(fr);
            let (mut acc, mut any_filled, mut ok) = (0.0f64, false, true);
            'taps: for (j, wy) in wr.iter().enumerate() {
                for (i, wx) in wc.iter().enumerate() {
                    let (c, r) = self.resolve(c0 - 1 + i as i64, r0 - 1 + j as i64);
                    let (v, f) = self.value(c, r);
                    if v.is_nan() {
                        ok = false;
                        break 'taps;
                    }
                    any_filled |= f;
                    acc += wx * wy * v as f64;
                }
            }
            if ok {
                let m = if any_filled {
                    mask::FILLED
                } else {
                    mask::MEASURED
                };
                return (acc as f32, m);
            }
        }
        // Fast path: all four taps inside the raster and measured (the common case).
        if c0 >= 0
            && r0 >= 0
            && ((c0 + 1) as usize) < self.p.width
            && ((r0 + 1) as usize) < self.p.height
        {
            if let Some(q) = self.quad(c0 as usize, r0 as usize) {
                return (bilerp4(q, fc, fr), mask::MEASURED);
            }
        }
        let taps = [
            (0, 0, (1.0 - fc) * (1.0 - fr)),
            (1, 0, fc * (1.0 - fr)),
            (0, 1, (1.0 - fc) * fr),
            (1, 1, fc * fr),
        ];
        let (mut acc, mut wsum, mut any_filled) = (0.0f64, 0.0f64, false);
        for (dc, dr, wt) in taps {
            let (c, r) = self.resolve(c0 + dc, r0 + dr);
            let (v, f) = self.value(c, r);
            if v.is_nan() || wt == 0.0 {
                continue;
            }
            any_filled |= f;
            acc += wt * v as f64;
            wsum += wt;
        }
        if wsum <= 0.0 {
            return (f32::NAN, mask::NO_DATA);
        }
        let m = if any_filled {
            mask::FILLED
        } else {
            mask::MEASURED
        };
        ((acc / wsum) as f32, m)
    }

    /// A cap containing the raster: centred on the mean of its outline, radius the largest
    /// angle to the outline plus two pixel diagonals. `None` for rasters that wrap or reach
    /// beyond 80° from their centre (no useful bound).
    pub fn footprint_cap(&self) -> Option<([f64; 3], f64)> {
        self.cap
    }

    fn bounding_cap(&self) -> Option<([f64; 3], f64)> {
        if self.global_lon || self.global_lat {
            return None;
        }
        let stride = self.p.width.max(self.p.height);
        let pts: Vec<[f64; 3]> = self
            .footprint_points(stride)
            .into_iter()
            .map(|(la, lo)| crate::cube::latlon_to_dir(la.to_radians(), lo.to_radians()))
            .collect();
        let mut c = [0.0; 3];
        for p in &pts {
            for k in 0..3 {
                c[k] += p[k];
            }
        }
        let n = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        if n.is_nan() || n <= 0.0 {
            return None;
        }
        let c = [c[0] / n, c[1] / n, c[2] / n];
        let r = pts
            .iter()
            .map(|p| crate::cube::angle_between(c, *p))
            .fold(0.0f64, f64::max);
        // Two pixel diagonals of margin: the outline runs through pixel edges.
        let (la0, lo0) = self.to_latlon(0.0, 0.0);
        let (la1, lo1) = self.to_latlon(2.0, 2.0);
        let margin = crate::cube::angle_between(
            crate::cube::latlon_to_dir(la0.to_radians(), lo0.to_radians()),
            crate::cube::latlon_to_dir(la1.to_radians(), lo1.to_radians()),
        );
        let r = r + margin;
        (r.is_finite() && r < 80f64.to_radians()).then_some((c, r))
    }

    /// Points (lat, lon in degrees) that outline the raster's footprint: every boundary pixel
    /// centre and an interior grid every `stride` pixels. Used to find candidate tiles.
    pub fn footprint_points(&self, stride: usize) -> Vec<(f64, f64)> {
        let (w, h) = (self.p.width, self.p.height);
        let stride = stride.max(1);
        let mut pts = Vec::new();
        let mut push = |c: f64, r: f64| pts.push(self.to_latlon(c, r));
        for c in 0..w {
            push(c as f64 - 0.5, -0.5);
            push(c as f64 - 0.5, h as f64 - 0.5);
        }
        push(w as f64 - 0.5, -0.5);
        push(w as f64 - 0.5, h as f64 - 0.5);
        for r in 0..h {
            push(-0.5, r as f64);
            push(w as f64 - 0.5, r as f64);
        }
        for r in (0..h).step_by(stride) {
            for c in (0..w).step_by(stride) {
                push(c as f64, r as f64);
            }
        }
        pts
    }
}

#[inline]
fn catmull_rom(t: f64) -> [f64; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// Bilinear interpolation of (c, r), (c+1, r), (c, r+1), (c+1, r+1) at fractions (fc, fr).
#[inline(always)]
fn bilerp4(q: [f32; 4], fc: f64, fr: f64) -> f32 {
    let top = q[0] as f64 * (1.0 - fc) + q[1] as f64 * fc;
    let bottom = q[2] as f64 * (1.0 - fc) + q[3] as f64 * fc;
    (top * (1.0 - fr) + bottom * fr) as f32
}

/// The samples at index `i`, `i + 1` and the same two a row (`w`) below of decoded samples.
#[inline(always)]
fn owned_quad(v: &[f32], w: usize, i: usize) -> [f64; 4] {
    [
        v[i] as f64,
        v[i + 1] as f64,
        v[i + w] as f64,
        v[i + w + 1] as f64,
    ]
}

/// The raw samples at byte offsets `a`, `a + N` (row above) and `b`, `b + N` (row below) of a
/// mapped raster, each `N` bytes decoded by `conv`.
#[inline(always)]
fn mapped_quad<const N: usize>(
    map: &[u8],
    a: usize,
    b: usize,
    conv: impl Fn([u8; N]) -> f64,
) -> [f64; 4] {
    let rd = |at: usize| {
        conv(
            map[at..at + N]
                .try_into()
                .expect("slice length matches sample size"),
        )
    };
    [rd(a), rd(a + N), rd(b), rd(b + N)]
}

/// `x.floor()` for finite `x` of magnitude below 2^52, inline: without SSE4.1 (the baseline
/// x86-64 target) `f64::floor` is a call into libm, and the tiler calls it for every sample.
#[inline(always)]
pub(crate) fn floor_fast(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

#[inline]
fn decode(b: &[u8], ty: SampleType, order: ByteOrder) -> f64 {
    macro_rules! rd {
        ($t:ty, $n:expr) => {{
            let a: [u8; $n] = b.try_into().expect("slice length matches sample size");
            match order {
                ByteOrder::Little => <$t>::from_le_bytes(a) as f64,
                ByteOrder::Big => <$t>::from_be_bytes(a) as f64,
            }
        }};
    }
    match ty {
        SampleType::U8 => b[0] as f64,
        SampleType::I16 => rd!(i16, 2),
        SampleType::U16 => rd!(u16, 2),
        SampleType::I32 => rd!(i32, 4),
        SampleType::U32 => rd!(u32, 4),
        SampleType::F32 => rd!(f32, 4),
        SampleType::F64 => rd!(f64, 8),
    }
}

/// Call `f(column, DN)` for every sample of one row's bytes (one dispatch on the type).
#[inline]
fn for_each_dn(bytes: &[u8], ty: SampleType, order: ByteOrder, mut f: impl FnMut(usize, f64)) {
    macro_rules! go {
        ($t:ty, $n:expr) => {{
            for (c, b) in bytes.chunks_exact($n).enumerate() {
                let a: [u8; $n] = b.try_into().expect("chunk has the sample size");
                let v = match order {
                    ByteOrder::Little => <$t>::from_le_bytes(a),
                    ByteOrder::Big => <$t>::from_be_bytes(a),
                };
                f(c, v as f64);
            }
        }};
    }
    match ty {
        SampleType::U8 => bytes.iter().enumerate().for_each(|(c, &b)| f(c, b as f64)),
        SampleType::I16 => go!(i16, 2),
        SampleType::U16 => go!(u16, 2),
        SampleType::I32 => go!(i32, 4),
        SampleType::U32 => go!(u32, 4),
        SampleType::F32 => go!(f32, 4),
        SampleType::F64 => go!(f64, 8),
    }
}

/// One measured sample's height above the sphere and where it is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeightAt {
    /// Metres above the body's sphere (the datum shift included); may be non-finite.
    pub height_m: f64,
    pub col: usize,
    pub row: usize,
}

/// The extremes of a DEM's measured heights ([`Dem::height_extremes`]); `None` when every
/// sample is a void.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HeightExtremes {
    pub lowest: Option<HeightAt>,
    pub highest: Option<HeightAt>,
    /// The height farthest from the sphere (non-finite heights first).
    pub farthest: Option<HeightAt>,
}

impl HeightExtremes {
    /// Combine the extremes of two sets of rows, keeping the first in file order on ties.
    fn merge(a: Self, b: Self) -> Self {
        fn pick(
            a: Option<HeightAt>,
            b: Option<HeightAt>,
            better: impl Fn(f64, f64) -> bool,
        ) -> Option<HeightAt> {
            match (a, b) {
                (Some(x), Some(y)) => {
                    let first = |p: &HeightAt, q: &HeightAt| (p.row, p.col) < (q.row, q.col);
                    if better(y.height_m, x.height_m)
                        || (!better(x.height_m, y.height_m) && first(&y, &x))
                    {
                        Some(y)
                    } else {
                        Some(x)
                    }
                }
                (x, None) => x,
                (None, y) => y,
            }
        }
        let far = |a: f64| {
            if a.is_finite() {
                a.abs()
            } else {
                f64::INFINITY
            }
        };
        HeightExtremes {
            lowest: pick(a.lowest, b.lowest, |p, q| p < q),
            highest: pick(a.highest, b.highest, |p, q| p > q),
            farthest: pick(a.farthest, b.farthest, |p, q| far(p) > far(q)),
        }
    }
}
