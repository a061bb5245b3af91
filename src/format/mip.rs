//! The mipmaps' files (docs/mipmaps.md): mip-mapped EXRs of one channel `max` (and `min`), all
//! levels, their precision, path patterns, texel convention and manifest entry.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;
use std::path::PathBuf;

use std::borrow::Cow;

use crate::exrcodec::{self, Blocks, Channel, Samples, ZipLevel};

use serde::{Deserialize, Serialize};

use crate::cube::Face;
use crate::error::{Error, IoContext, Result};
use crate::exrcodec::TileCompression;
use crate::format::{check_channels, exr_channels, exr_identity, ChannelLabel, Identity};
use crate::fsio::write_staged;
use crate::layout::TileId;

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
    encode_mip_exr_identified(size, min, max, precision, compression, level, name, None)
}

/// [`encode_mip_exr`] with the file's identity in the header.
#[allow(clippy::too_many_arguments)]
pub fn encode_mip_exr_identified(
    size: usize,
    min: Option<&[Vec<f32>]>,
    max: &[Vec<f32>],
    precision: Precision,
    compression: TileCompression,
    level: ZipLevel,
    name: &str,
    identity: Option<&Identity>,
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
    exrcodec::encode_identified(
        name,
        identity.map(Identity::text).as_deref(),
        (size, size),
        &list,
        &exrcodec::Encoding {
            compression,
            level,
            blocks: Blocks::MipTiles(64),
        },
    )
}

/// Write a mip-mapped EXR with channel `max` and, when `min` is given, channel `min`, and its
/// identity in the header when given (the mip stage always gives it).
#[allow(clippy::too_many_arguments)]
pub fn write_mip_exr(
    path: &Path,
    size: usize,
    min: Option<&[Vec<f32>]>,
    max: &[Vec<f32>],
    precision: Precision,
    compression: TileCompression,
    name: &str,
    identity: Option<&Identity>,
) -> Result<()> {
    let bytes = encode_mip_exr_stored(size, min, max, precision, compression, name, identity)
        .map_err(|e| Error::invalid(path, format!("EXR encoding failed: {e}")))?;
    write_staged(path, |f| f.write_all(&bytes).at(path))
}

/// The bytes [`write_mip_exr`] stores (a plan measures its sizes with them).
#[allow(clippy::too_many_arguments)]
pub fn encode_mip_exr_stored(
    size: usize,
    min: Option<&[Vec<f32>]>,
    max: &[Vec<f32>],
    precision: Precision,
    compression: TileCompression,
    name: &str,
    identity: Option<&Identity>,
) -> std::result::Result<Vec<u8>, String> {
    encode_mip_exr_identified(
        size,
        min,
        max,
        precision,
        compression,
        ZipLevel::DEFAULT,
        name,
        identity,
    )
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

/// Read a file written by [`write_mip_exr`], whatever its identity, no larger than
/// [`max_file_bytes`] of the largest tile (the store and the queries read with
/// [`decode_mip_exr_as`], checked against the index and the file's identity).
pub fn read_mip_exr(path: &Path) -> Result<MipFile> {
    let root = path.parent().unwrap_or(Path::new("."));
    let bytes = crate::fsio::read_product_file(
        root,
        path,
        crate::fsio::Expect::AtMost(max_file_bytes(8192, 2)),
        "a mipmap file",
    )?;
    decode_mip_exr(&bytes)
        .map_err(|msg| Error::invalid(path, format!("{msg}; delete it and rerun `penumbra mip`")))
}

/// The largest mip file whose level 0 is `n`² texels of `channels` f32 channels: every level
/// stored raw (at most 4/3 of level 0, plus a tile's rounding), its offset table and a header
/// of at most 64 KiB. A file the index does not know is refused above it before it is read.
pub fn max_file_bytes(n: usize, channels: usize) -> u64 {
    let n = n as u64 + 64;
    n * n * 4 * channels as u64 * 4 / 3 + n * n / 64 + (64 << 10)
}

/// Decode the bytes of a mip file, whatever its identity; the error says what is wrong
/// (without the path).
pub fn decode_mip_exr(bytes: &[u8]) -> std::result::Result<MipFile, String> {
    decode(bytes).map(|(f, _, _)| f)
}

/// Decode the bytes of a mip file that must be `expected` (its identity is checked) and hold
/// the channels `labels` says ([`labels`]).
pub fn decode_mip_exr_as(
    bytes: &[u8],
    expected: &Identity,
    labels: &[ChannelLabel],
) -> std::result::Result<MipFile, String> {
    let (f, id, found) = decode(bytes)?;
    Identity::check(expected, exr_identity(id))?;
    check_channels(&found, labels)?;
    Ok(f)
}

/// The three kinds of mip file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MipKind {
    /// A tile's maximum pyramid.
    Max,
    /// A tile's (min, max) pyramid.
    MinMax,
    /// A face pyramid or a chunk of one.
    Face,
}

impl MipKind {
    /// The kind of the files whose identities are named `id` (`maxmip`, `minmax`, …).
    pub fn of_id(id: &str) -> Option<MipKind> {
        match id {
            MAX_ID => Some(MipKind::Max),
            MINMAX_ID => Some(MipKind::MinMax),
            FACE_ID | FACE_CHUNK_ID => Some(MipKind::Face),
            _ => None,
        }
    }
}

/// What a mip file of `kind` must hold by the manifest: the channels `max_channels` (or
/// `minmax_channels`, which the face pyramids have too) lists, in the sample type
/// `precision` (the face pyramids': `face_precision`) gives.
pub fn labels(m: &MipProduct, kind: MipKind) -> Vec<ChannelLabel> {
    let (names, names_field) = match kind {
        MipKind::Max => (&m.max_channels, "products.mip.max_channels"),
        _ => (&m.minmax_channels, "products.mip.minmax_channels"),
    };
    let (precision, field) = match kind {
        MipKind::Face => (m.face_precision, "products.mip.face_precision"),
        _ => (m.precision, "products.mip.precision"),
    };
    names
        .iter()
        .map(|n| ChannelLabel::of(n, precision.name(), names_field, field))
        .collect()
}

type Decoded = (MipFile, Option<String>, Vec<(String, &'static str)>);

fn decode(bytes: &[u8]) -> std::result::Result<Decoded, String> {
    let image =
        exrcodec::decode(bytes, false).map_err(|e| format!("not a readable mipmap EXR ({e})"))?;
    let found = exr_channels(image.channels.iter().map(|(n, t, _)| (n, *t)));
    let (w, h) = image.size();
    if w != h {
        return Err(format!("mipmap is {w}×{h}, not square"));
    }
    let sizes = level_sizes(w);
    let mut channels = BTreeMap::new();
    let identity = image.identity;
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
    Ok((MipFile { sizes, channels }, identity, found))
}
pub const MAX_PATTERN: &str = "maxmip/{level}/{face}/{y}/{x}.exr";
pub const MINMAX_PATTERN: &str = "minmax/{level}/{face}/{y}/{x}.exr";
pub const FACE_PATTERN: &str = "minmax/{level}/{face}/face.exr";
/// Chunks of the face pyramids of faces with more than [`FACE_CHUNK_TILES`] tiles per side.
pub const FACE_CHUNK_PATTERN: &str = "minmax/{level}/{face}/face/{cy}/{cx}.exr";
/// Tiles per side of a face-pyramid chunk: a face with more tiles per side than this keeps
/// the fine levels of its pyramid in chunks of this many tiles squared, so that building one
/// never holds more than a chunk (docs/mipmaps.md).
pub const FACE_CHUNK_TILES: u32 = 1024;
/// Version of the mip products' layout and convention (part of the run key). 2: every file
/// carries its identity (`format::Identity`).
pub const MIP_FORMAT: &str = "penumbra-mip-2";
/// The product names of the mip files' identities: a tile's maximum and (min, max) pyramids,
/// a face pyramid (x = y = 0) and a chunk of one (x, y: the chunk).
pub const MAX_ID: &str = "maxmip";
pub const MINMAX_ID: &str = "minmax";
pub const FACE_ID: &str = "minmax-face";
pub const FACE_CHUNK_ID: &str = "minmax-face-chunk";
/// One-line statement of the texel convention, recorded in the manifest.
pub const TEXEL_CONVENTION: &str =
    "level-0 texel (i,j) = interior pixel (i,j), bounds the bilinear \
     surface over [i-1/2,i+1/2]x[j-1/2,j+1/2] = extreme of stored samples i-1..i+1, j-1..j+1; \
     level k texel = extreme of its 2x2 children (sizes halve rounding up); NaN = no data";

/// Paths of a tile's two products.
pub fn tile_paths(dir: &Path, id: TileId) -> (PathBuf, PathBuf) {
    (
        super::tile_path(dir, MAX_PATTERN, id),
        super::tile_path(dir, MINMAX_PATTERN, id),
    )
}

/// Path of a face pyramid.
pub fn face_path(dir: &Path, level: u8, face: Face) -> PathBuf {
    super::face_file_path(dir, FACE_PATTERN, level, face)
}

/// Path of chunk (cx, cy) of a face pyramid.
pub fn face_chunk_path(dir: &Path, level: u8, face: Face, cx: u32, cy: u32) -> PathBuf {
    super::face_chunk_file_path(dir, FACE_CHUNK_PATTERN, level, face, cx, cy)
}

/// Storage precision of the pyramids.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// f32: the extrema of the f32 heights, exactly.
    #[default]
    F32,
    /// f16: max rounded up and min rounded down to the next f16, so bounds stay bounds.
    F16,
}

impl Precision {
    /// `f32` or `f16`, as the manifest writes it.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F16 => "f16",
        }
    }
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "f32" => Ok(Precision::F32),
            "f16" => Ok(Precision::F16),
            _ => Err(format!("unknown precision '{s}': use f32 or f16")),
        }
    }
}

/// Smallest f16 ≥ `x` (NaN stays NaN; above 65504 gives +∞).
pub fn f16_up(x: f32) -> half::f16 {
    if x.is_nan() {
        return half::f16::NAN;
    }
    let h = half::f16::from_f32(x);
    if h.to_f32() >= x {
        return h;
    }
    let b = h.to_bits();
    half::f16::from_bits(match b {
        0x8000 => 0x0001,
        b if b & 0x8000 == 0 => b + 1,
        b => b - 1,
    })
}

/// Largest f16 ≤ `x` (NaN stays NaN; below −65504 gives −∞).
pub fn f16_down(x: f32) -> half::f16 {
    if x.is_nan() {
        return half::f16::NAN;
    }
    let h = half::f16::from_f32(x);
    if h.to_f32() <= x {
        return h;
    }
    let b = h.to_bits();
    half::f16::from_bits(match b {
        0x0000 => 0x8001,
        b if b & 0x8000 == 0 => b - 1,
        b => b + 1,
    })
}

/// Texels per side at each level for a `n`-texel level 0: n, ⌈n/2⌉, …, 1.
pub fn level_sizes(n: usize) -> Vec<usize> {
    let mut v = vec![n.max(1)];
    while *v.last().unwrap() > 1 {
        let s = *v.last().unwrap();
        v.push(s.div_ceil(2));
    }
    v
}

/// Extrema of one tile level over all its tiles (`null` when every texel is no data).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MipLevelRange {
    pub level: u8,
    pub min_m: Option<f64>,
    pub max_m: Option<f64>,
}

/// Maximum and (min, max) mipmaps (docs/mipmaps.md).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MipProduct {
    /// Products present: `max` (one-channel maximum pyramid), `minmax` (two-channel).
    pub products: Vec<String>,
    /// Path pattern of the maximum pyramids, one mip-mapped EXR per height tile.
    pub max_path: String,
    pub max_channels: Vec<String>,
    /// Path pattern of the (min, max) pyramids, one mip-mapped EXR per height tile.
    pub minmax_path: String,
    pub minmax_channels: Vec<String>,
    /// Path pattern of the face pyramids of whole-tile extrema, one per (tile level, face).
    pub face_path: String,
    /// Path pattern (`{level}`, `{face}`, `{cx}`, `{cy}`) of the chunks of the face pyramids of
    /// tile levels with more than `face_chunk_tiles` tiles per side: chunk (cx, cy) holds the
    /// pyramid of tiles `cx·c .. (cx+1)·c − 1` × `cy·c ..` down to its 1×1, and `face_path` then
    /// holds only the levels above, from one texel per chunk. Absent when no level is chunked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub face_chunk_path: Option<String>,
    /// Tiles per side of a face-pyramid chunk (1024), with `face_chunk_path`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub face_chunk_tiles: Option<u32>,
    /// Sample type of the tile pyramids (`f32`, or `f16` rounded outwards).
    pub precision: Precision,
    /// Sample type of the face pyramids.
    pub face_precision: Precision,
    /// How level sizes halve: `up` (⌈n/2⌉, OpenEXR's ROUND_UP).
    pub level_rounding: String,
    /// The texel convention in one line.
    pub texel: String,
    /// Extrema over every tile of every level (as stored, so rounded outwards for f16).
    pub global_min_m: f64,
    pub global_max_m: f64,
    /// Extrema per tile level.
    pub levels: Vec<MipLevelRange>,
    /// Hash of the tool version, the height tiles' run key and the mip options.
    pub run_key: String,
    /// What `run_key` hashes besides the run keys of the products it was made from (the tool
    /// version, the stage's format strings, its parameters as text), so that a reader
    /// recomputes it; absent in tilesets written before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_key_basis: Option<super::KeyBasis>,
}
