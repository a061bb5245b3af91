//! The mip-mapped EXR files of the mip stage: one channel `max` (and `min`), all levels.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use exr::prelude::{
    AnyChannel, AnyChannels, Blocks, Compression, Encoding, FlatSamples, Image, Layer,
    LayerAttributes, Levels, LineOrder, ReadChannels, ReadLayers, SmallVec, Vec2, WritableImage,
};

use super::kernels::{f16_down, f16_up, level_sizes};
use super::schema::Precision;
use crate::error::{Error, IoContext, Result};
use crate::tileio::{self, TileCompression};

fn encoding(compression: TileCompression) -> Encoding {
    Encoding {
        compression: match compression {
            TileCompression::Zip => Compression::ZIP16,
            TileCompression::None => Compression::Uncompressed,
        },
        blocks: Blocks::Tiles(Vec2(64, 64)),
        line_order: LineOrder::Increasing,
    }
}

fn channel(
    name: &str,
    levels: &[Vec<f32>],
    precision: Precision,
    is_max: bool,
) -> AnyChannel<Levels<FlatSamples>> {
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
    let mut list = vec![channel("max", max, precision, true)];
    if let Some(m) = min {
        list.push(channel("min", m, precision, false));
    }
    let layer = Layer::new(
        (size, size),
        LayerAttributes::named(name),
        encoding(compression),
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    let image = Image::from_layer(layer);
    tileio::write_atomic(path, |f| {
        let mut buf = std::io::Cursor::new(Vec::with_capacity(size * size * 8));
        image
            .write()
            .non_parallel()
            .to_buffered(&mut buf)
            .map_err(|e| Error::invalid(path, format!("EXR encoding failed: {e}")))?;
        f.write_all(buf.get_ref()).at(path)
    })
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
    let bad =
        |msg: String| Error::invalid(path, format!("{msg}; delete it and rerun `penumbra mip`"));
    let image = exr::prelude::read()
        .no_deep_data()
        .all_resolution_levels()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| bad(format!("not a readable mipmap EXR ({e})")))?;
    let layer = &image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    if w != h {
        return Err(bad(format!("mipmap is {w}×{h}, not square")));
    }
    let sizes = level_sizes(w);
    let mut channels = BTreeMap::new();
    for ch in &layer.channel_data.list {
        let levels: Vec<Vec<f32>> = match &ch.sample_data {
            Levels::Singular(s) => vec![s.values_as_f32().collect()],
            Levels::Mip { level_data, .. } => level_data
                .iter()
                .map(|s| s.values_as_f32().collect())
                .collect(),
            Levels::Rip { .. } => return Err(bad("rip-mapped, not mip-mapped".into())),
        };
        if levels.len() != sizes.len() || levels.iter().zip(&sizes).any(|(l, &s)| l.len() != s * s)
        {
            return Err(bad(format!(
                "channel '{}' does not hold the {} mip levels of a {w}² image",
                ch.name,
                sizes.len()
            )));
        }
        channels.insert(ch.name.to_string(), levels);
    }
    Ok(MipFile { sizes, channels })
}
