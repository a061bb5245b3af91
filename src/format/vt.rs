//! The files of a renderer addon made from a tileset (docs/packaging.md): the PNG tiles of a
//! Celestia virtual texture and the addon's small text files (`.ssc`, `.ctx`, README). They
//! are not products of the tileset — nothing reads them back through the store — but, like
//! every file Penumbra writes, they are written through [`crate::fsio`] (temp file, rename), so
//! an addon never holds half a file.

use std::io::Write;
use std::path::Path;

use crate::error::{Error, IoContext, Result};
use crate::fsio::{write_atomic_bytes, write_staged};

/// Encode an 8-bit RGB image (`rgb`: row-major, 3 bytes a pixel, `w × h` pixels) as PNG.
pub fn encode_png_rgb8(w: u32, h: u32, rgb: &[u8]) -> std::result::Result<Vec<u8>, String> {
    if rgb.len() as u64 != w as u64 * h as u64 * 3 {
        return Err(format!(
            "an RGB image of {w}×{h} pixels needs {} bytes, not {}",
            w as u64 * h as u64 * 3,
            rgb.len()
        ));
    }
    let img = image::RgbImage::from_raw(w, h, rgb.to_vec())
        .ok_or_else(|| format!("{w}×{h} is not a valid image size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| format!("PNG encoding failed: {e}"))?;
    Ok(out.into_inner())
}

/// Decode a PNG into 8-bit RGB (width, height, bytes); the error says what is wrong (without
/// the path). For tests and checks of an addon's tiles.
pub fn decode_png_rgb8(bytes: &[u8]) -> std::result::Result<(u32, u32, Vec<u8>), String> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .map_err(|e| format!("not a readable PNG ({e})"))?
        .into_rgb8();
    Ok((img.width(), img.height(), img.into_raw()))
}

/// Write an 8-bit RGB tile of a virtual texture as PNG at `path`, making its folder.
pub fn write_png_rgb8(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    let bytes = encode_png_rgb8(w, h, rgb).map_err(|e| Error::invalid(path, e))?;
    make_parent(path)?;
    write_staged(path, |f| f.write_all(&bytes).at(path))
}

/// Write a small text file of the addon (a catalog, a virtual texture's description, the
/// README) atomically and durably, making its folder.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    make_parent(path)?;
    write_atomic_bytes(path, text.as_bytes())
}

fn make_parent(path: &Path) -> Result<()> {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => std::fs::create_dir_all(p).at(p),
        _ => Ok(()),
    }
}
