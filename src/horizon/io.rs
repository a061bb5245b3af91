//! The raw horizon maps on disk: one EXR per height tile, `A` planes of `n²` elevations (degrees)
//! stacked vertically, one channel `elevation` in f16 or f32.

use std::io::Write;
use std::path::Path;

use exr::prelude::*;

use crate::error::{Error, IoContext, Result};
use crate::tileio::{self, TileCompression};
use serde::Serialize;

/// Storage precision of the raw maps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HorizonPrecision {
    /// Half floats: 0.0078° steps below 16°, 0.031° below 64°, 0.0625° up to 90°.
    #[default]
    F16,
    F32,
}

impl std::str::FromStr for HorizonPrecision {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "f16" => Ok(HorizonPrecision::F16),
            "f32" => Ok(HorizonPrecision::F32),
            _ => Err(format!("unknown precision '{s}' (f16, f32)")),
        }
    }
}

impl HorizonPrecision {
    pub fn name(self) -> &'static str {
        match self {
            HorizonPrecision::F16 => "f16",
            HorizonPrecision::F32 => "f32",
        }
    }
}

/// Write one tile's raw maps: `a` planes of `n²` elevations (degrees) stacked vertically.
pub fn write_horizon_exr(
    path: &Path,
    n: usize,
    a: usize,
    elev: &[f32],
    precision: HorizonPrecision,
    compression: TileCompression,
) -> Result<()> {
    assert_eq!(elev.len(), n * n * a);
    let samples = match precision {
        HorizonPrecision::F32 => FlatSamples::F32(elev.to_vec()),
        HorizonPrecision::F16 => FlatSamples::F16(elev.iter().map(|&v| f16::from_f32(v)).collect()),
    };
    let layer = Layer::new(
        (n, n * a),
        LayerAttributes::named("penumbra-horizon"),
        match compression {
            TileCompression::Zip => Encoding::SMALL_LOSSLESS,
            TileCompression::None => Encoding::UNCOMPRESSED,
        },
        AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(
            "elevation",
            samples,
        )])),
    );
    let image = Image::from_layer(layer);
    tileio::write_atomic(path, |f| {
        let mut buf = std::io::Cursor::new(Vec::with_capacity(n * n * a * 2));
        image
            .write()
            .to_buffered(&mut buf)
            .map_err(|e| Error::invalid(path, format!("EXR encoding failed: {e}")))?;
        f.write_all(buf.get_ref()).at(path)
    })
}

/// Read a file of [`write_horizon_exr`] for tiles of `n` pixels: the `a` planes as f32.
pub fn read_horizon_exr(path: &Path, n: usize) -> Result<(usize, Vec<f32>)> {
    let bytes = std::fs::read(path).at(path)?;
    let bad = |msg: String| {
        Error::invalid(
            path,
            format!("{msg}; delete it and rerun `penumbra horizon`"),
        )
    };
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| bad(format!("not a readable horizon EXR ({e})")))?;
    let layer = &image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    if w != n || h % n != 0 || h == 0 {
        return Err(bad(format!(
            "horizon map is {w}×{h}, not {n} wide and a multiple of {n} high"
        )));
    }
    let ch = layer
        .channel_data
        .list
        .iter()
        .find(|c| c.name.to_string() == "elevation")
        .ok_or_else(|| bad("no 'elevation' channel".into()))?;
    Ok((h / n, ch.sample_data.values_as_f32().collect()))
}
