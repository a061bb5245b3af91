/*!
Files the viewer writes: frames and difference images as PNG, the lit fraction as float EXR
(the library's writer, as `penumbra shadow --exr` writes it), each atomically.
*/

use std::path::Path;

use anyhow::{Context as _, Result};

/// Write `w × h` RGB8 pixels as PNG, atomically.
pub fn write_rgb_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    let img = image::RgbImage::from_raw(w, h, rgb.to_vec())
        .context("an image buffer of the wrong size")?;
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png)
        .with_context(|| format!("{}: PNG encoding failed", path.display()))?;
    penumbra::fsio::write_atomic_bytes(path, buf.get_ref())?;
    Ok(())
}

/// Write `w × h` RGBA8 pixels as an RGB PNG (alpha dropped), atomically.
pub fn write_rgba_as_png(path: &Path, w: u32, h: u32, rgba: &[u8]) -> Result<()> {
    let rgb: Vec<u8> = rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    write_rgb_png(path, w, h, &rgb)
}

/// Check that the folder `path` would be written into exists, before any rendering.
pub fn check_parent(path: &Path, flag: &str) -> Result<()> {
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        anyhow::bail!(
            "{flag} {}: the folder {} does not exist",
            path.display(),
            parent.display()
        );
    }
    Ok(())
}

/// `path` with `./` in front when it names a file in the current folder, so that every writer
/// (the library's atomic writes sync the file's folder) sees a folder.
pub fn in_folder(path: &Path) -> std::path::PathBuf {
    match path.parent() {
        Some(p) if p.as_os_str().is_empty() => Path::new(".").join(path),
        _ => path.to_path_buf(),
    }
}
