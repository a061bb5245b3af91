//! The lit-fraction maps the shadow methods write: an 8-bit grey PNG for people (shaded relief
//! too) and a one-channel f32 EXR (`lit`, NaN = no data) for scripts, written atomically
//! (docs/shadow-methods.md).

use std::path::Path;

use crate::error::{Error, Result};

/// Colour of pixels without data in the images (dark blue: neither lit nor shadowed).
pub const NO_DATA_RGB: [u8; 3] = [40, 60, 110];

/// Write a row-major `w`×`h` image of values in [0, 1] as an 8-bit grey PNG (NaN, no data:
/// [`NO_DATA_RGB`]), atomically.
pub fn write_grey_png(path: &Path, w: usize, h: usize, v: &[f32]) -> Result<()> {
    assert_eq!(v.len(), w * h);
    let bytes: Vec<u8> = v
        .iter()
        .flat_map(|&x| {
            if x.is_finite() {
                let g = (x.clamp(0.0, 1.0) * 255.0).round() as u8;
                [g, g, g]
            } else {
                NO_DATA_RGB
            }
        })
        .collect();
    let img = image::RgbImage::from_raw(w as u32, h as u32, bytes).expect("w·h pixels");
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png)
        .map_err(|e| Error::invalid(path, format!("PNG encoding failed: {e}")))?;
    crate::fsio::write_atomic_bytes(path, buf.get_ref())
}

/// Write a row-major `w`×`h` lit-fraction image as a single-part EXR with one f32 channel
/// `lit` (NaN: no data), atomically.
pub fn write_lit_exr(path: &Path, w: usize, h: usize, v: &[f32]) -> Result<()> {
    use crate::exrcodec::{self, Channel, Samples};
    use std::io::Write;
    assert_eq!(v.len(), w * h);
    let bytes = exrcodec::encode(
        "penumbra-lit-fraction",
        (w, h),
        &[Channel {
            name: "lit",
            levels: vec![Samples::F32(std::borrow::Cow::Borrowed(v))],
        }],
        &exrcodec::Encoding::scanlines(crate::exrcodec::TileCompression::Zip),
    )
    .map_err(|e| crate::error::Error::invalid(path, format!("EXR encoding failed: {e}")))?;
    crate::fsio::write_atomic(path, |f| {
        f.write_all(&bytes)
            .map_err(|e| crate::error::Error::io(path, e))
    })
}
