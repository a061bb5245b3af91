//! The raw horizon maps on disk: one EXR per height tile, `A` planes of `n²` elevations (degrees)
//! stacked vertically, one channel `elevation` in f16 or f32.

use std::io::Write;
use std::path::Path;

use std::borrow::Cow;

use exr::prelude::f16;

use crate::error::{Error, IoContext, Result};
use crate::exrcodec::{self, Channel, Samples, ZipLevel};
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
    let bytes = encode_horizon_exr(n, a, elev, precision, compression, ZipLevel::DEFAULT)
        .map_err(|e| Error::invalid(path, format!("EXR encoding failed: {e}")))?;
    tileio::write_staged(path, |f| f.write_all(&bytes).at(path))
}

/// The bytes of a horizon file (what [`write_horizon_exr`] stores) at a given deflate level.
pub fn encode_horizon_exr(
    n: usize,
    a: usize,
    elev: &[f32],
    precision: HorizonPrecision,
    compression: TileCompression,
    level: ZipLevel,
) -> std::result::Result<Vec<u8>, String> {
    assert_eq!(elev.len(), n * n * a);
    let samples = match precision {
        HorizonPrecision::F32 => Samples::F32(Cow::Borrowed(elev)),
        HorizonPrecision::F16 => {
            Samples::F16(Cow::Owned(elev.iter().map(|&v| f16::from_f32(v)).collect()))
        }
    };
    exrcodec::encode(
        "penumbra-horizon",
        (n, n * a),
        &[Channel {
            name: "elevation",
            levels: vec![samples],
        }],
        &exrcodec::Encoding {
            level,
            ..exrcodec::Encoding::scanlines(compression)
        },
    )
}

/// The bytes the `exr` crate's own writer produced for a horizon file before
/// [`crate::exrcodec`]; kept for the equality tests and `penumbra-bench codec`.
pub fn encode_horizon_exr_exr_crate(
    n: usize,
    a: usize,
    elev: &[f32],
    precision: HorizonPrecision,
    compression: TileCompression,
) -> std::result::Result<Vec<u8>, String> {
    use exr::prelude::*;
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
    let mut buf = std::io::Cursor::new(Vec::with_capacity(n * n * a * 2));
    Image::from_layer(layer)
        .write()
        .non_parallel()
        .to_buffered(&mut buf)
        .map_err(|e| e.to_string())?;
    Ok(buf.into_inner())
}

/// Read a file of [`write_horizon_exr`] for tiles of `n` pixels: the `a` planes as f32.
pub fn read_horizon_exr(path: &Path, n: usize) -> Result<(usize, Vec<f32>)> {
    let bytes = std::fs::read(path).at(path)?;
    decode_horizon_exr(&bytes, n).map_err(|msg| {
        Error::invalid(
            path,
            format!("{msg}; delete it and rerun `penumbra horizon`"),
        )
    })
}

/// Decode the bytes of a horizon file; the error says what is wrong (without the path).
pub fn decode_horizon_exr(
    bytes: &[u8],
    n: usize,
) -> std::result::Result<(usize, Vec<f32>), String> {
    let mut image =
        exrcodec::decode(bytes, true).map_err(|e| format!("not a readable horizon EXR ({e})"))?;
    let (w, h) = image.size();
    if w != n || h % n != 0 || h == 0 {
        return Err(format!(
            "horizon map is {w}×{h}, not {n} wide and a multiple of {n} high"
        ));
    }
    let elev = image
        .take("elevation")
        .and_then(|mut l| l.drain(..).next())
        .ok_or_else(|| "no 'elevation' channel".to_string())?;
    Ok((h / n, elev))
}
