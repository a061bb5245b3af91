//! Albedo/colour sources: an 8- or 16-bit equirectangular image of the whole body (PNG), sampled
//! bilinearly into tiles of the same layout as the heights (halo included).

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

pub struct AlbedoSource {
    pub path: PathBuf,
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub sixteen_bit: bool,
    /// Longitude (east, degrees) of the left edge of column 0.
    pub west_lon_deg: f64,
    data: Vec<u16>,
}

impl AlbedoSource {
    /// Load an equirectangular global image whose left edge is at `west_lon_deg` and whose rows
    /// span 90°N (top edge) to 90°S (bottom edge).
    pub fn open(path: &Path, west_lon_deg: f64) -> Result<AlbedoSource> {
        let reader = image::ImageReader::open(path)
            .map_err(|e| Error::io(path, e))?
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))?;
        let (w, h) = reader.into_dimensions().map_err(|e| {
            Error::invalid(
                path,
                format!("not a readable albedo image (PNG expected): {e}"),
            )
        })?;
        crate::dem::check_dimensions(path, w as u64, h as u64)?;
        let img = image::ImageReader::open(path)
            .map_err(|e| Error::io(path, e))?
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))?
            .decode()
            .map_err(|e| Error::invalid(path, format!("albedo image does not decode: {e}")))?;
        use image::DynamicImage as D;
        let (channels, sixteen_bit, data): (usize, bool, Vec<u16>) = match img {
            D::ImageLuma8(b) => (1, false, b.into_raw().into_iter().map(u16::from).collect()),
            D::ImageLumaA8(b) => (2, false, b.into_raw().into_iter().map(u16::from).collect()),
            D::ImageRgb8(b) => (3, false, b.into_raw().into_iter().map(u16::from).collect()),
            D::ImageRgba8(b) => (4, false, b.into_raw().into_iter().map(u16::from).collect()),
            D::ImageLuma16(b) => (1, true, b.into_raw()),
            D::ImageLumaA16(b) => (2, true, b.into_raw()),
            D::ImageRgb16(b) => (3, true, b.into_raw()),
            D::ImageRgba16(b) => (4, true, b.into_raw()),
            other => {
                return Err(Error::unsupported(
                    path,
                    format!(
                        "albedo pixel type {:?}: give an 8- or 16-bit image",
                        other.color()
                    ),
                ))
            }
        };
        if (w as f64 / h as f64 - 2.0).abs() > 0.01 {
            return Err(Error::invalid(
                path,
                format!(
                    "albedo image is {w}×{h}: an equirectangular global image is twice as wide as it is high"
                ),
            ));
        }
        Ok(AlbedoSource {
            path: path.to_path_buf(),
            width: w as usize,
            height: h as usize,
            channels,
            sixteen_bit,
            west_lon_deg,
            data,
        })
    }

    /// Bilinear sample at latitude/longitude (degrees) into `out` (one value per channel),
    /// wrapping in longitude and clamping at the poles.
    pub fn sample(&self, lat_deg: f64, lon_deg: f64, out: &mut [u16]) {
        let (w, h) = (self.width as f64, self.height as f64);
        let x = (lon_deg - self.west_lon_deg).rem_euclid(360.0) / 360.0 * w - 0.5;
        let y = ((90.0 - lat_deg) / 180.0 * h - 0.5).clamp(0.0, h - 1.0);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let xi = |d: i64| ((x0 as i64 + d).rem_euclid(self.width as i64)) as usize;
        let yi = |d: i64| ((y0 as i64 + d).clamp(0, self.height as i64 - 1)) as usize;
        let c = self.channels;
        for (ch, o) in out.iter_mut().enumerate().take(c) {
            let at = |xx: usize, yy: usize| self.data[(yy * self.width + xx) * c + ch] as f64;
            let v = (1.0 - fx) * (1.0 - fy) * at(xi(0), yi(0))
                + fx * (1.0 - fy) * at(xi(1), yi(0))
                + (1.0 - fx) * fy * at(xi(0), yi(1))
                + fx * fy * at(xi(1), yi(1));
            *o = v.round() as u16;
        }
    }
}
