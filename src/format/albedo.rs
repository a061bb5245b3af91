//! The albedo tiles: PNG files of 8- or 16-bit samples, 1–4 channels, halo included, in the
//! height tiles' layout (docs/tileset.md), and their manifest entry.

use std::io::Write;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{exr_identity, Identity, SourceFile};
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

impl AlbedoTile {
    /// The tile as an image of its bit depth and channel count (None when `data` does not hold
    /// `size`² pixels of `channels` samples).
    pub fn to_image(&self) -> Option<image::DynamicImage> {
        use image::{DynamicImage, ImageBuffer};
        let (w, h) = (self.size as u32, self.size as u32);
        Some(if self.sixteen_bit {
            let d = self.data.clone();
            match self.channels {
                1 => DynamicImage::ImageLuma16(ImageBuffer::from_raw(w, h, d)?),
                2 => DynamicImage::ImageLumaA16(ImageBuffer::from_raw(w, h, d)?),
                3 => DynamicImage::ImageRgb16(ImageBuffer::from_raw(w, h, d)?),
                _ => DynamicImage::ImageRgba16(ImageBuffer::from_raw(w, h, d)?),
            }
        } else {
            let d: Vec<u8> = self.data.iter().map(|&v| v as u8).collect();
            match self.channels {
                1 => DynamicImage::ImageLuma8(ImageBuffer::from_raw(w, h, d)?),
                2 => DynamicImage::ImageLumaA8(ImageBuffer::from_raw(w, h, d)?),
                3 => DynamicImage::ImageRgb8(ImageBuffer::from_raw(w, h, d)?),
                _ => DynamicImage::ImageRgba8(ImageBuffer::from_raw(w, h, d)?),
            }
        })
    }
}

/// Write an albedo tile as PNG, with its identity in a text chunk when given (the tiling stage
/// always gives it).
pub fn write_albedo_tile(
    path: &Path,
    tile: &AlbedoTile,
    identity: Option<&Identity>,
) -> Result<()> {
    let bytes = encode_albedo_tile(tile, identity).map_err(|e| Error::invalid(path, e))?;
    write_staged(path, |f| f.write_all(&bytes).at(path))
}

/// The bytes of an albedo tile file: a PNG (the `png` crate, default compression) with
/// `identity` as a `tEXt` chunk [`IDENTITY_KEYWORD`], which the encoder writes right after the
/// image header (the pixels' chunks are the same bytes with or without it).
pub fn encode_albedo_tile(
    tile: &AlbedoTile,
    identity: Option<&Identity>,
) -> std::result::Result<Vec<u8>, String> {
    let n = tile.size;
    if tile.data.len() != n * n * tile.channels {
        return Err("albedo tile buffer has the wrong length".into());
    }
    let color = match tile.channels {
        1 => png::ColorType::Grayscale,
        2 => png::ColorType::GrayscaleAlpha,
        3 => png::ColorType::Rgb,
        4 => png::ColorType::Rgba,
        c => return Err(format!("albedo tile has {c} channels, not 1 to 4")),
    };
    let samples: Vec<u8> = if tile.sixteen_bit {
        tile.data.iter().flat_map(|v| v.to_be_bytes()).collect()
    } else {
        tile.data.iter().map(|&v| v as u8).collect()
    };
    let fail = |e: png::EncodingError| format!("PNG encoding failed: {e}");
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, n as u32, n as u32);
    enc.set_color(color);
    enc.set_depth(if tile.sixteen_bit {
        png::BitDepth::Sixteen
    } else {
        png::BitDepth::Eight
    });
    if let Some(id) = identity {
        enc.add_text_chunk(IDENTITY_KEYWORD.into(), id.text())
            .map_err(fail)?;
    }
    let mut w = enc.write_header().map_err(fail)?;
    w.write_image_data(&samples).map_err(fail)?;
    w.finish().map_err(fail)?;
    Ok(out)
}

/// The keyword of the `tEXt` chunk that holds an albedo tile's identity.
pub const IDENTITY_KEYWORD: &str = "penumbraIdentity";

/// What an albedo tile's PNG header says, read without inflating a pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PngFacts {
    /// The text of its [`IDENTITY_KEYWORD`] chunk (None: it has none).
    pub identity: Option<String>,
    pub width: u32,
    pub height: u32,
    pub bit_depth: u8,
    /// Samples per pixel by the colour type (grey 1, grey + alpha 2, RGB 3, RGBA 4; a palette
    /// image 0: no albedo tile is one).
    pub channels: u8,
}

/// A PNG decoder over a file's bytes in memory.
type PngReader<'a> = png::Reader<std::io::Cursor<&'a [u8]>>;

/// A PNG's decoder past its header and the chunks before the first image data (the `png`
/// crate checks every CRC), and what they say; the error says what is wrong (without the
/// path).
fn open(bytes: &[u8]) -> std::result::Result<(PngFacts, PngReader<'_>), String> {
    // A damaged ancillary chunk (the identity's) is an error, not a chunk to skip.
    let mut options = png::DecodeOptions::default();
    options.set_skip_ancillary_crc_failures(false);
    let reader = png::Decoder::new_with_options(std::io::Cursor::new(bytes), options)
        .read_info()
        .map_err(|e| format!("not a readable PNG header ({e})"))?;
    let info = reader.info();
    let facts = PngFacts {
        identity: info
            .uncompressed_latin1_text
            .iter()
            .find(|t| t.keyword == IDENTITY_KEYWORD)
            .map(|t| t.text.clone()),
        width: info.width,
        height: info.height,
        bit_depth: info.bit_depth as u8,
        channels: match info.color_type {
            png::ColorType::Grayscale => 1,
            png::ColorType::GrayscaleAlpha => 2,
            png::ColorType::Rgb => 3,
            png::ColorType::Rgba => 4,
            png::ColorType::Indexed => 0,
        },
    };
    Ok((facts, reader))
}

/// Read a PNG's header and the text chunks before its image data; the error says what is
/// wrong (without the path).
pub fn read_header(bytes: &[u8]) -> std::result::Result<PngFacts, String> {
    open(bytes).map(|(facts, _)| facts)
}

/// What an albedo tile must hold by the manifest (`bit_depth`, `channels`) against what its
/// header says; the error names the label and says what the file holds (without the path).
pub fn check_labels(found: &PngFacts, a: &AlbedoProduct) -> std::result::Result<(), String> {
    if found.bit_depth != a.bit_depth {
        return Err(format!(
            "holds {}-bit samples, but the manifest's `products.albedo.bit_depth` says {}; {}",
            found.bit_depth, a.bit_depth, RELABEL
        ));
    }
    if found.channels != a.channels {
        return Err(format!(
            "holds {} channels per pixel, but the manifest's `products.albedo.channels` says \
             {}; {RELABEL}",
            found.channels, a.channels
        ));
    }
    Ok(())
}

/// What to do about a tile whose contents are not what the manifest's labels say.
const RELABEL: &str = "the file was rewritten or the manifest edited after `penumbra tile` made \
                       them: restore the manifest, or rerun `penumbra tile` with the same albedo \
                       into a fresh folder (`penumbra verify DIR` lists every such file)";

/// The largest albedo tile file of `stored` pixels per side: every sample stored raw (4
/// channels of 16 bits, a filter byte per row), deflate's stored-block overhead and 64 KiB of
/// other chunks. A file the index does not know is refused above it before it is read.
pub fn max_file_bytes(stored: usize) -> u64 {
    let n = stored as u64;
    let raw = n * (n * 8 + 1);
    raw + raw / 16_000 * 5 + (64 << 10)
}

/// Decode the bytes of tile `expected`'s albedo PNG of `size` pixels per side: its identity
/// (the `tEXt` chunk [`IDENTITY_KEYWORD`]) must be `expected`, its bit depth and channels those
/// the manifest entry `a` says, its size `size`, all checked on the header before a pixel is
/// inflated; the error says what is wrong (without the path).
pub fn decode_albedo_tile_as(
    bytes: &[u8],
    expected: &Identity,
    a: &AlbedoProduct,
    size: usize,
) -> std::result::Result<AlbedoTile, String> {
    let (facts, mut reader) = open(bytes)?;
    Identity::check(expected, exr_identity(facts.identity.clone()))?;
    check_labels(&facts, a)?;
    if (facts.width as usize, facts.height as usize) != (size, size) {
        return Err(format!(
            "albedo tile is {}×{} but the manifest's layout makes tiles {size}²",
            facts.width, facts.height
        ));
    }
    let (channels, sixteen_bit) = (facts.channels as usize, facts.bit_depth == 16);
    let mut raw = vec![0u8; size * size * channels * if sixteen_bit { 2 } else { 1 }];
    reader
        .next_frame(&mut raw)
        .map_err(|e| format!("not a readable PNG albedo tile ({e})"))?;
    let data: Vec<u16> = if sixteen_bit {
        raw.chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect()
    } else {
        raw.into_iter().map(u16::from).collect()
    };
    Ok(AlbedoTile {
        size,
        channels,
        sixteen_bit,
        data,
    })
}

/// The product name of the albedo tiles' identities.
pub const ID: &str = "albedo";

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AlbedoProduct {
    pub path: String,
    pub source: SourceFile,
    pub bit_depth: u8,
    pub channels: u8,
    /// Longitude of the image's left edge (east-positive degrees).
    pub west_lon_deg: f64,
}
