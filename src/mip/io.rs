//! The mip-mapped EXR files of the mip stage: one channel `max` (and `min`), all levels.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use std::borrow::Cow;

use crate::exrcodec::{self, Blocks, Channel, Samples, ZipLevel};

use super::kernels::{f16_down, f16_up, level_sizes};
use super::schema::Precision;
use crate::error::{Error, IoContext, Result};
use crate::tileio::{self, TileCompression};

fn samples(levels: &[Vec<f32>], precision: Precision, is_max: bool) -> Vec<Samples<'_>> {
    levels
        .iter()
        .map(|l| match precision {
            Precision::F32 => Samples::F32(Cow::Borrowed(l.as_slice())),
            Precision::F16 => Samples::F16(Cow::Owned(
                l.iter()
                    .map(|&v| if is_max { f16_up(v) } else { f16_down(v) })
                    .collect(),
            )),
        })
        .collect()
}

/// The bytes of a mip-mapped EXR (what [`write_mip_exr`] stores) at a given deflate level:
/// tiled, 64² tiles, all levels rounding up, ZIP per tile.
#[allow(clippy::too_many_arguments)]
pub fn encode_mip_exr(
    size: usize,
    min: Option<&[Vec<f32>]>,
    max: &[Vec<f32>],
    precision: Precision,
    compression: TileCompression,
    level: ZipLevel,
    name: &str,
) -> std::result::Result<Vec<u8>, String> {
    let mut list = vec![Channel {
        name: "max",
        levels: samples(max, precision, true),
    }];
    if let Some(m) = min {
        list.push(Channel {
            name: "min",
            levels: samples(m, precision, false),
        });
    }
    exrcodec::encode(
        name,
        (size, size),
        &list,
        &exrcodec::Encoding {
            compression,
            level,
            blocks: Blocks::MipTiles(64),
        },
    )
}

/// Write a mip-mapped EXR with channel `max` and, when `min` is given, channel `min`.
pub fn write_mip_exr(
    path: &Path,
    size: usize,
    min: Option<&[Vec<f32>]>,
    max: &[Vec<f32>],
    precision: Precision,
    compression: TileCompression,
    name: &str,
) -> Result<()> {
    let bytes = encode_mip_exr(
        size,
        min,
        max,
        precision,
        compression,
        ZipLevel::DEFAULT,
        name,
    )
    .map_err(|e| Error::invalid(path, format!("EXR encoding failed: {e}")))?;
    tileio::write_staged(path, |f| f.write_all(&bytes).at(path))
}

/// The bytes the `exr` crate's own writer produced for a mip file before
/// [`crate::exrcodec`]; kept for the equality tests and `penumbra-bench codec`.
pub fn encode_mip_exr_exr_crate(
    size: usize,
    min: Option<&[Vec<f32>]>,
    max: &[Vec<f32>],
    precision: Precision,
    compression: TileCompression,
    name: &str,
) -> std::result::Result<Vec<u8>, String> {
    use exr::prelude::{
        AnyChannel, AnyChannels, Blocks, Compression, Encoding, FlatSamples, Image, Layer,
        LayerAttributes, Levels, LineOrder, SmallVec, Vec2, WritableImage,
    };
    let channel = |name: &str, levels: &[Vec<f32>], is_max: bool| {
        let data = levels
            .iter()
            .map(|l| match precision {
                Precision::F32 => FlatSamples::F32(l.clone()),
                Precision::F16 => FlatSamples::F16(
                    l.iter()
                        .map(|&v| if is_max { f16_up(v) } else { f16_down(v) })
                        .collect(),
                ),
            })
            .collect();
        AnyChannel::new(
            name,
            Levels::Mip {
                rounding_mode: exr::math::RoundingMode::Up,
                level_data: data,
            },
        )
    };
    let mut list = vec![channel("max", max, true)];
    if let Some(m) = min {
        list.push(channel("min", m, false));
    }
    let encoding = Encoding {
        compression: match compression {
            TileCompression::Zip => Compression::ZIP16,
            TileCompression::None => Compression::Uncompressed,
        },
        blocks: Blocks::Tiles(Vec2(64, 64)),
        line_order: LineOrder::Increasing,
    };
    let layer = Layer::new(
        (size, size),
        LayerAttributes::named(name),
        encoding,
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    let mut buf = std::io::Cursor::new(Vec::with_capacity(size * size * 8));
    Image::from_layer(layer)
        .write()
        .non_parallel()
        .to_buffered(&mut buf)
        .map_err(|e| e.to_string())?;
    Ok(buf.into_inner())
}

/// The channels of a mip-mapped EXR, each as its levels (largest first) in f32.
#[derive(Clone, Debug)]
pub struct MipFile {
    pub sizes: Vec<usize>,
    pub channels: BTreeMap<String, Vec<Vec<f32>>>,
}

impl MipFile {
    pub fn channel(&self, path: &Path, name: &str) -> Result<&Vec<Vec<f32>>> {
        self.channels
            .get(name)
            .ok_or_else(|| Error::invalid(path, format!("mip EXR has no '{name}' channel")))
    }
}

/// Read a file written by [`write_mip_exr`].
pub fn read_mip_exr(path: &Path) -> Result<MipFile> {
    let bytes = std::fs::read(path).at(path)?;
    decode_mip_exr(&bytes)
        .map_err(|msg| Error::invalid(path, format!("{msg}; delete it and rerun `penumbra mip`")))
}

/// Decode the bytes of a mip file; the error says what is wrong (without the path).
pub fn decode_mip_exr(bytes: &[u8]) -> std::result::Result<MipFile, String> {
    let image =
        exrcodec::decode(bytes, false).map_err(|e| format!("not a readable mipmap EXR ({e})"))?;
    let (w, h) = image.size();
    if w != h {
        return Err(format!("mipmap is {w}×{h}, not square"));
    }
    let sizes = level_sizes(w);
    let mut channels = BTreeMap::new();
    for (name, _, levels) in image.channels {
        if levels.len() != sizes.len() || levels.iter().zip(&sizes).any(|(l, &s)| l.len() != s * s)
        {
            return Err(format!(
                "channel '{name}' does not hold the {} mip levels of a {w}² image",
                sizes.len()
            ));
        }
        channels.insert(name, levels);
    }
    Ok(MipFile { sizes, channels })
}
