//! The height tiles: EXR files of f32 `height` + f16 `mask` (docs/tileset.md), their manifest
//! entry and path pattern, written into a run's staging folder through [`crate::fsio::write_staged`] (temp file,
//! rename; made durable by the run's commit), so a reader or a killed run never sees half a
//! file.

use std::borrow::Cow;
use std::io::Write;
use std::path::Path;

use exr::prelude::f16;

use serde::{Deserialize, Serialize};

use crate::error::{Error, IoContext, Result};
use crate::exrcodec::{self, Channel, Samples};

use crate::format::{check_channels, exr_channels, exr_identity, ChannelLabel, Identity};
use crate::fsio::write_staged;

/// A square height tile including its halo.
#[derive(Clone, Debug, PartialEq)]
pub struct HeightTile {
    /// Side length in pixels, halo included.
    pub size: usize,
    /// Row-major heights in metres above the body's reference sphere; NaN = no data.
    pub height: Vec<f32>,
    /// Row-major mask values (see `dem::mask`).
    pub mask: Vec<u8>,
}

impl HeightTile {
    /// Bilinear height at fractional pixel (x, y) of the stored array (halo included).
    /// No-data taps are left out; NaN when all four are no data.
    pub fn bilinear(&self, x: f64, y: f64) -> f32 {
        let n = self.size as i64;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let mut acc = 0.0f64;
        let mut wsum = 0.0f64;
        for (dx, dy, w) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            let (xi, yi) = ((x0 + dx).clamp(0, n - 1), (y0 + dy).clamp(0, n - 1));
            let v = self.height[(yi * n + xi) as usize];
            if v.is_nan() || w == 0.0 {
                continue;
            }
            acc += w * v as f64;
            wsum += w;
        }
        if wsum > 0.0 {
            (acc / wsum) as f32
        } else {
            f32::NAN
        }
    }
}

pub use crate::exrcodec::TileCompression;

/// Write a height tile as a single-part scanline EXR, channels `height` (f32) and `mask`
/// (f16 holding 0, 1 or 2), ZIP blocks of 16 lines (see [`crate::exrcodec`]), with its
/// identity in the header when given (the tiling stage always gives it).
pub fn write_height_tile(
    path: &Path,
    tile: &HeightTile,
    compression: TileCompression,
    identity: Option<&Identity>,
) -> Result<()> {
    let bytes = encode_height_tile_stored(tile, compression, identity)
        .map_err(|e| Error::invalid(path, format!("EXR encoding failed: {e}")))?;
    write_staged(path, |f| f.write_all(&bytes).at(path))
}

/// The bytes [`write_height_tile`] stores for `tile` (a plan measures its sizes with them).
pub fn encode_height_tile_stored(
    tile: &HeightTile,
    compression: TileCompression,
    identity: Option<&Identity>,
) -> std::result::Result<Vec<u8>, String> {
    encode_height_tile_identified(tile, compression, exrcodec::ZipLevel::HEIGHT_TILE, identity)
}

/// The bytes of a height tile file without an identity, at a given deflate level.
pub fn encode_height_tile(
    tile: &HeightTile,
    compression: TileCompression,
    level: exrcodec::ZipLevel,
) -> std::result::Result<Vec<u8>, String> {
    encode_height_tile_identified(tile, compression, level, None)
}

/// The bytes of a height tile file (what [`write_height_tile`] stores), at a given deflate level.
pub fn encode_height_tile_identified(
    tile: &HeightTile,
    compression: TileCompression,
    level: exrcodec::ZipLevel,
    identity: Option<&Identity>,
) -> std::result::Result<Vec<u8>, String> {
    let mask: Vec<f16> = tile.mask.iter().map(|&m| f16::from_f32(m as f32)).collect();
    exrcodec::encode_identified(
        "penumbra-height",
        identity.map(Identity::text).as_deref(),
        (tile.size, tile.size),
        &[
            Channel {
                name: "height",
                levels: vec![Samples::F32(Cow::Borrowed(&tile.height))],
            },
            Channel {
                name: "mask",
                levels: vec![Samples::F16(Cow::Owned(mask))],
            },
        ],
        &exrcodec::Encoding {
            level,
            ..exrcodec::Encoding::scanlines(compression)
        },
    )
}

/// The bytes the `exr` crate's own writer produced for a height tile before
/// [`crate::exrcodec`] (ZIP at level 4, one block after another). Kept to prove that the codec
/// stores the same samples, and as the baseline of `penumbra-bench codec`.
pub fn encode_height_tile_exr_crate(
    tile: &HeightTile,
    compression: TileCompression,
) -> std::result::Result<Vec<u8>, String> {
    use exr::prelude::*;
    let size = (tile.size, tile.size);
    let mask: Vec<f16> = tile.mask.iter().map(|&m| f16::from_f32(m as f32)).collect();
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![
        AnyChannel::new("height", FlatSamples::F32(tile.height.clone())),
        AnyChannel::new("mask", FlatSamples::F16(mask)),
    ]));
    let layer = Layer::new(
        size,
        LayerAttributes::named("penumbra-height"),
        match compression {
            TileCompression::Zip => Encoding::SMALL_LOSSLESS,
            TileCompression::None => Encoding::UNCOMPRESSED,
        },
        channels,
    );
    let image = Image::from_layer(layer);
    let mut buf = std::io::Cursor::new(Vec::with_capacity(tile.size * tile.size * 3));
    image
        .write()
        .non_parallel()
        .to_buffered(&mut buf)
        .map_err(|e| e.to_string())?;
    Ok(buf.into_inner())
}

/// Read a height tile written by [`write_height_tile`] (or by the `exr` crate's writer before
/// it, or by any OpenEXR writer: blocks in other compressions are decoded by `exr`), whatever
/// its identity; no larger than [`max_file_bytes`] of its own size. The store reads tiles with
/// [`decode_height_tile_as`], checked against the index and their identity.
pub fn read_height_tile(path: &Path) -> Result<HeightTile> {
    let root = path.parent().unwrap_or(Path::new("."));
    let bytes = crate::fsio::read_product_file(
        root,
        path,
        crate::fsio::Expect::AtMost(max_file_bytes(LARGEST_STORED)),
        "a height tile",
    )?;
    decode_height_tile(&bytes).map_err(|e| Error::invalid(path, e))
}

/// The largest stored tile side a tileset may have (tile size 8192, halo below half a tile).
const LARGEST_STORED: usize = 2 * 8192;

/// The largest height tile file of `stored` pixels per side: every sample stored raw (6 bytes
/// a pixel), its offset table and a header of at most 64 KiB. A file the index does not know is
/// refused above it before it is read.
pub fn max_file_bytes(stored: usize) -> u64 {
    let n = stored as u64;
    n * n * 6 + n * 8 + (64 << 10)
}

/// Decode the bytes of a height tile file, whatever its identity; the error says what is wrong
/// (without the path).
pub fn decode_height_tile(bytes: &[u8]) -> std::result::Result<HeightTile, String> {
    decode(bytes).map(|(t, _, _)| t)
}

/// Decode the bytes of a height tile file that must be `expected` (its identity attribute is
/// checked; [`Identity::check`] says what is wrong otherwise) and hold the channels `labels`
/// says ([`labels`]; [`check_channels`] says what is wrong otherwise).
pub fn decode_height_tile_as(
    bytes: &[u8],
    expected: &Identity,
    labels: &[ChannelLabel],
) -> std::result::Result<HeightTile, String> {
    let (t, id, found) = decode(bytes)?;
    Identity::check(expected, exr_identity(id))?;
    check_channels(&found, labels)?;
    Ok(t)
}

/// The sample type the height tile format gives a channel (docs/tileset.md): `height` f32,
/// `mask` f16.
fn sample_of(channel: &str) -> &'static str {
    match channel {
        "mask" => "f16",
        _ => "f32",
    }
}

/// What a height tile must hold by the manifest: the channels `products.height.channels`
/// lists, each of the sample type the format gives it.
pub fn labels(p: &HeightProduct) -> Vec<ChannelLabel> {
    p.channels
        .iter()
        .map(|c| ChannelLabel {
            name: c.clone(),
            sample: sample_of(c).to_string(),
            names_by: "the manifest's `products.height.channels`".into(),
            sample_by: "the height tile format (docs/tileset.md)".into(),
        })
        .collect()
}

type Decoded = (HeightTile, Option<String>, Vec<(String, &'static str)>);

fn decode(bytes: &[u8]) -> std::result::Result<Decoded, String> {
    let mut image = exrcodec::decode(bytes, true).map_err(|e| {
        format!("not a readable EXR height tile ({e}); delete it and rerun the stage")
    })?;
    let found = exr_channels(image.channels.iter().map(|(n, t, _)| (n, *t)));
    let (w, h) = image.size();
    if w != h {
        return Err(format!("height tile is {w}×{h}, not square"));
    }
    let height = image
        .take("height")
        .and_then(|mut l| l.drain(..).next())
        .ok_or_else(|| "EXR has no 'height' channel".to_string())?;
    let mask = match image.take("mask").and_then(|mut l| l.drain(..).next()) {
        Some(m) => m.iter().map(|m| m.clamp(0.0, 255.0) as u8).collect(),
        None => vec![0; height.len()],
    };
    Ok((
        HeightTile {
            size: w,
            height,
            mask,
        },
        image.identity,
        found,
    ))
}

/// The product name of the height tiles' identities.
pub const ID: &str = "height";

/// Path pattern of the height tiles below a tileset.
pub const HEIGHT_PATTERN: &str = "height/{level}/{face}/{y}/{x}.exr";

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct HeightProduct {
    pub path: String,
    /// EXR channels: `height` f32 metres above `body.radius_m`, `mask` f16 (0 measured,
    /// 1 void filled from neighbours, 2 no data: height NaN).
    pub channels: Vec<String>,
    pub min_m: f64,
    pub max_m: f64,
    /// Interior pixels over all written tiles whose mask is 1 / 2.
    pub filled_pixels: u64,
    pub no_data_pixels: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn height_tile_round_trips_bit_exact() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a/b/t.exr");
        let n = 37;
        let tile = HeightTile {
            size: n,
            height: (0..n * n)
                .map(|i| {
                    if i == 5 {
                        f32::NAN
                    } else {
                        (i as f32).sin() * 1234.5
                    }
                })
                .collect(),
            mask: (0..n * n)
                .map(|i| if i == 5 { 2 } else { (i % 2) as u8 })
                .collect(),
        };
        for c in [TileCompression::Zip, TileCompression::None] {
            write_height_tile(&p, &tile, c, None).unwrap();
            let back = read_height_tile(&p).unwrap();
            assert_eq!(back.size, n);
            assert_eq!(back.mask, tile.mask);
            for (a, b) in back.height.iter().zip(&tile.height) {
                assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()));
            }
        }
        // No temp file is left behind.
        let names: Vec<_> = std::fs::read_dir(p.parent().unwrap()).unwrap().collect();
        assert_eq!(names.len(), 1);
        // A corrupt tile is an error that names the file.
        std::fs::write(&p, b"not an exr").unwrap();
        let e = read_height_tile(&p).unwrap_err().to_string();
        assert!(e.contains("t.exr"), "{e}");
    }
}
