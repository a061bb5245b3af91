//! The albedo tiles: PNG files of 8- or 16-bit samples, 1–4 channels, halo included, in the
//! height tiles' layout (docs/tileset.md), and their manifest entry.

use std::io::Write;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::SourceFile;
use crate::error::{Error, IoContext, Result};
use crate::fsio::write_staged;

/// Path pattern of the albedo tiles below a tileset.
pub const ALBEDO_PATTERN: &str = "albedo/{level}/{face}/{y}/{x}.png";

/// An albedo/colour tile: 8- or 16-bit samples, 1–4 channels, halo included.
#[derive(Clone, Debug, PartialEq)]
pub struct AlbedoTile {
    pub size: usize,
    pub channels: usize,
    pub sixteen_bit: bool,
    /// Row-major interleaved samples scaled to the bit depth's full range.
    pub data: Vec<u16>,
}

/// Write an albedo tile as PNG.
pub fn write_albedo_tile(path: &Path, tile: &AlbedoTile) -> Result<()> {
    use image::{DynamicImage, ImageBuffer};
    let (w, h) = (tile.size as u32, tile.size as u32);
    let bad = || Error::invalid(path, "albedo tile buffer has the wrong length");
    let img: DynamicImage = if tile.sixteen_bit {
        let d = tile.data.clone();
        match tile.channels {
            1 => DynamicImage::ImageLuma16(ImageBuffer::from_raw(w, h, d).ok_or_else(bad)?),
            2 => DynamicImage::ImageLumaA16(ImageBuffer::from_raw(w, h, d).ok_or_else(bad)?),
            3 => DynamicImage::ImageRgb16(ImageBuffer::from_raw(w, h, d).ok_or_else(bad)?),
            _ => DynamicImage::ImageRgba16(ImageBuffer::from_raw(w, h, d).ok_or_else(bad)?),
        }
    } else {
        let d: Vec<u8> = tile.data.iter().map(|&v| v as u8).collect();
        match tile.channels {
            1 => DynamicImage::ImageLuma8(ImageBuffer::from_raw(w, h, d).ok_or_else(bad)?),
            2 => DynamicImage::ImageLumaA8(ImageBuffer::from_raw(w, h, d).ok_or_else(bad)?),
            3 => DynamicImage::ImageRgb8(ImageBuffer::from_raw(w, h, d).ok_or_else(bad)?),
            _ => DynamicImage::ImageRgba8(ImageBuffer::from_raw(w, h, d).ok_or_else(bad)?),
        }
    };
    write_staged(path, |f| {
        let mut buf = std::io::Cursor::new(Vec::new());
        img.write_to(&mut buf, image::ImageFormat::Png)
            .map_err(|e| Error::invalid(path, format!("PNG encoding failed: {e}")))?;
        f.write_all(buf.get_ref()).at(path)
    })
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AlbedoProduct {
    pub path: String,
    pub source: SourceFile,
    pub bit_depth: u8,
    pub channels: u8,
    /// Longitude of the image's left edge (east-positive degrees).
    pub west_lon_deg: f64,
}
