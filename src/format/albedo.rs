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

/// The bytes of an albedo tile file: the PNG the `image` crate encodes, with `identity` as a
/// `tEXt` chunk [`IDENTITY_KEYWORD`] right after the image header (the pixels' chunks are the
/// same bytes with or without it).
pub fn encode_albedo_tile(
    tile: &AlbedoTile,
    identity: Option<&Identity>,
) -> std::result::Result<Vec<u8>, String> {
    let img = tile
        .to_image()
        .ok_or("albedo tile buffer has the wrong length")?;
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png)
        .map_err(|e| format!("PNG encoding failed: {e}"))?;
    let mut png = buf.into_inner();
    if let Some(id) = identity {
        // The signature, then IHDR: 4 bytes of length (13), its type, 13 bytes, its CRC.
        if png.len() < IHDR_END || &png[12..16] != b"IHDR" {
            return Err("PNG encoder wrote no image header first".into());
        }
        let chunk = text_chunk(IDENTITY_KEYWORD, &id.text());
        png.splice(IHDR_END..IHDR_END, chunk);
    }
    Ok(png)
}

/// The PNG signature.
const SIGNATURE: &[u8; 8] = b"\x89PNG\r\n\x1a\n";
/// Where the image header chunk ends (signature, length, type, 13 bytes, CRC).
const IHDR_END: usize = 8 + 4 + 4 + 13 + 4;
/// The keyword of the `tEXt` chunk that holds an albedo tile's identity.
pub const IDENTITY_KEYWORD: &str = "penumbraIdentity";

/// A `tEXt` chunk of `keyword` and `text` (both ASCII here).
fn text_chunk(keyword: &str, text: &str) -> Vec<u8> {
    let mut data = Vec::with_capacity(keyword.len() + 1 + text.len());
    data.extend_from_slice(keyword.as_bytes());
    data.push(0);
    data.extend_from_slice(text.as_bytes());
    let mut c = Vec::with_capacity(data.len() + 12);
    c.extend_from_slice(&(data.len() as u32).to_be_bytes());
    c.extend_from_slice(b"tEXt");
    c.extend_from_slice(&data);
    c.extend_from_slice(&crc32(&c[4..]).to_be_bytes());
    c
}

/// CRC-32 (ISO 3309, as PNG chunks use it) of `bytes`.
fn crc32(bytes: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut t = [0u32; 256];
        let mut n = 0;
        while n < 256 {
            let mut c = n as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
                k += 1;
            }
            t[n] = c;
            n += 1;
        }
        t
    };
    let mut c = 0xFFFF_FFFFu32;
    for &b in bytes {
        c = TABLE[((c ^ b as u32) & 0xFF) as usize] ^ (c >> 8);
    }
    c ^ 0xFFFF_FFFF
}

/// What an albedo tile's PNG header says, read from its chunks' headers without inflating a
/// pixel.
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

/// Read a PNG's header and text chunks (the chunks' lengths and CRCs checked); the error says
/// what is wrong (without the path).
pub fn read_header(bytes: &[u8]) -> std::result::Result<PngFacts, String> {
    if bytes.len() < IHDR_END || &bytes[..8] != SIGNATURE || &bytes[12..16] != b"IHDR" {
        return Err("not a PNG file (bad signature or no image header first)".into());
    }
    let be = |o: usize| u32::from_be_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let mut facts = PngFacts {
        identity: None,
        width: be(16),
        height: be(20),
        bit_depth: bytes[24],
        channels: match bytes[25] {
            0 => 1,
            2 => 3,
            4 => 2,
            6 => 4,
            _ => 0,
        },
    };
    let mut at = 8;
    loop {
        if at + 12 > bytes.len() {
            return Err("PNG ends before its IEND chunk".into());
        }
        let len = be(at) as usize;
        let end = at + 12 + len;
        if end > bytes.len() {
            return Err(format!("PNG chunk at byte {at} runs past the end"));
        }
        let kind = &bytes[at + 4..at + 8];
        let data = &bytes[at + 8..at + 8 + len];
        if (kind == b"IHDR" || kind == b"tEXt")
            && crc32(&bytes[at + 4..at + 8 + len]) != be(at + 8 + len)
        {
            return Err(format!(
                "PNG chunk {} at byte {at} fails its CRC",
                String::from_utf8_lossy(kind)
            ));
        }
        if kind == b"tEXt" {
            if let Some(text) = data.strip_prefix(IDENTITY_KEYWORD.as_bytes()) {
                if let Some(text) = text.strip_prefix(b"\0") {
                    facts.identity = Some(String::from_utf8_lossy(text).into_owned());
                }
            }
        }
        if kind == b"IEND" {
            return Ok(facts);
        }
        at = end;
    }
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
    let facts = read_header(bytes)?;
    Identity::check(expected, exr_identity(facts.identity.clone()))?;
    check_labels(&facts, a)?;
    if (facts.width as usize, facts.height as usize) != (size, size) {
        return Err(format!(
            "albedo tile is {}×{} but the manifest's layout makes tiles {size}²",
            facts.width, facts.height
        ));
    }
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .map_err(|e| format!("not a readable PNG albedo tile ({e})"))?;
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
            return Err(format!(
                "albedo tile decodes to {:?}, not 8/16-bit grey, grey + alpha, RGB or RGBA",
                other.color()
            ))
        }
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
