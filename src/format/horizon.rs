//! The raw horizon maps on disk (docs/horizons.md): one EXR per height tile, `A` planes of `n²`
//! elevations (degrees) stacked vertically, one channel `elevation` in f16 or f32; their path
//! pattern, conventions, the method names the manifest records, and the manifest entry.

use std::io::Write;
use std::path::{Path, PathBuf};

use std::borrow::Cow;

use exr::prelude::f16;

use crate::error::{Error, IoContext, Result};
use crate::exrcodec::TileCompression;
use crate::exrcodec::{self, Channel, Samples, ZipLevel};
use crate::format::{check_channels, exr_channels, exr_identity, ChannelLabel, Identity};
use crate::fsio::write_staged;
use crate::layout::TileId;
use serde::{Deserialize, Serialize};

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

/// Write one tile's raw maps: `a` planes of `n²` elevations (degrees) stacked vertically, with
/// the file's identity in the header when given (the horizon stage always gives it).
pub fn write_horizon_exr(
    path: &Path,
    n: usize,
    a: usize,
    elev: &[f32],
    precision: HorizonPrecision,
    compression: TileCompression,
    identity: Option<&Identity>,
) -> Result<()> {
    let bytes = encode_horizon_exr_identified(
        n,
        a,
        elev,
        precision,
        compression,
        ZipLevel::DEFAULT,
        identity,
    )
    .map_err(|e| Error::invalid(path, format!("EXR encoding failed: {e}")))?;
    write_staged(path, |f| f.write_all(&bytes).at(path))
}

/// The bytes of a horizon file without an identity, at a given deflate level.
pub fn encode_horizon_exr(
    n: usize,
    a: usize,
    elev: &[f32],
    precision: HorizonPrecision,
    compression: TileCompression,
    level: ZipLevel,
) -> std::result::Result<Vec<u8>, String> {
    encode_horizon_exr_identified(n, a, elev, precision, compression, level, None)
}

/// The bytes of a horizon file (what [`write_horizon_exr`] stores) at a given deflate level.
pub fn encode_horizon_exr_identified(
    n: usize,
    a: usize,
    elev: &[f32],
    precision: HorizonPrecision,
    compression: TileCompression,
    level: ZipLevel,
    identity: Option<&Identity>,
) -> std::result::Result<Vec<u8>, String> {
    assert_eq!(elev.len(), n * n * a);
    let samples = match precision {
        HorizonPrecision::F32 => Samples::F32(Cow::Borrowed(elev)),
        HorizonPrecision::F16 => {
            Samples::F16(Cow::Owned(elev.iter().map(|&v| f16::from_f32(v)).collect()))
        }
    };
    exrcodec::encode_identified(
        "penumbra-horizon",
        identity.map(Identity::text).as_deref(),
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

/// Read a file of [`write_horizon_exr`] for tiles of `n` pixels: the `a` planes as f32, whatever
/// its identity, no larger than [`max_file_bytes`] allows (the store reads with
/// [`decode_horizon_exr_as`], checked against the index and the file's identity).
pub fn read_horizon_exr(path: &Path, n: usize) -> Result<(usize, Vec<f32>)> {
    let root = path.parent().unwrap_or(Path::new("."));
    let bytes = crate::fsio::read_product_file(
        root,
        path,
        crate::fsio::Expect::AtMost(max_file_bytes(n, MAX_AZIMUTHS)),
        "a horizon map",
    )?;
    decode_horizon_exr(&bytes, n).map_err(|msg| {
        Error::invalid(
            path,
            format!("{msg}; delete it and rerun `penumbra horizon`"),
        )
    })
}

/// The most azimuths a tileset's horizon maps may have (the manifest's limit).
pub const MAX_AZIMUTHS: usize = 4096;

/// The largest horizon file of `a` planes of `n`² f32 elevations: every sample stored raw, its
/// offset table and a header of at most 64 KiB. A file the index does not know is refused
/// above it before it is read.
pub fn max_file_bytes(n: usize, a: usize) -> u64 {
    let (n, a) = (n as u64, a as u64);
    n * n * a * 4 + n * a * 8 + (64 << 10)
}

/// Decode the bytes of a horizon file, whatever its identity; the error says what is wrong
/// (without the path).
pub fn decode_horizon_exr(
    bytes: &[u8],
    n: usize,
) -> std::result::Result<(usize, Vec<f32>), String> {
    decode(bytes, n).map(|(a, e, _, _)| (a, e))
}

/// Decode the bytes of a horizon file that must be `expected` (its identity is checked) and
/// hold the channel `labels` says ([`labels`]).
pub fn decode_horizon_exr_as(
    bytes: &[u8],
    n: usize,
    expected: &Identity,
    labels: &[ChannelLabel],
) -> std::result::Result<(usize, Vec<f32>), String> {
    let (a, e, id, found) = decode(bytes, n)?;
    Identity::check(expected, exr_identity(id))?;
    check_channels(&found, labels)?;
    Ok((a, e))
}

/// What a horizon file must hold by the manifest: the one channel `products.horizon.channel`
/// names, in the sample type `products.horizon.precision` gives.
pub fn labels(h: &HorizonProduct) -> Vec<ChannelLabel> {
    vec![ChannelLabel::of(
        &h.channel,
        &h.precision,
        "products.horizon.channel",
        "products.horizon.precision",
    )]
}

type Decoded = (usize, Vec<f32>, Option<String>, Vec<(String, &'static str)>);

fn decode(bytes: &[u8], n: usize) -> std::result::Result<Decoded, String> {
    let mut image =
        exrcodec::decode(bytes, true).map_err(|e| format!("not a readable horizon EXR ({e})"))?;
    let found = exr_channels(image.channels.iter().map(|(n, t, _)| (n, *t)));
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
    Ok((h / n, elev, image.identity, found))
}
pub const PATTERN: &str = "horizon/{level}/{face}/{y}/{x}.exr";
/// Version of the horizon products' layout and convention (part of the run key).
/// 2: every file carries its identity (`format::Identity`).
pub const FORMAT: &str = "penumbra-horizon-2";
/// The product name of the raw maps' identities.
pub const ID: &str = "horizon";
pub const AZIMUTH_CONVENTION: &str = "plane azimuth on the tile's cube face: counter-clockwise \
     from the face's +U axis towards +V, degrees; plane k = 360*k/A; compass azimuth differs per \
     pixel (docs/horizons.md)";
pub const LAYOUT: &str = "image tile_size wide and A*tile_size high: rows k*n..(k+1)*n hold \
     plane k, row-major like the height tile's interior (no halo)";
/// Path of a tile's raw maps below `dir`.
pub fn tile_path(dir: &Path, id: TileId) -> PathBuf {
    super::tile_path(dir, PATTERN, id)
}

/// Which algorithm computes the horizons.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Each pixel's own ray searched exactly out to a near field (`near_px`, default 24 px),
    /// beyond that a per-azimuth sweep of parallel great circles with an upper convex hull
    /// per line.
    #[default]
    Fast,
    /// Timonen & Westerholm's line sweep on the sphere (`horizon::linesweep`): each line's
    /// observers read their horizon off its upper hull as it passes, and each pixel
    /// interpolates the two lines that bracket it. Not bounded by the reference; its error is
    /// measured as it runs and recorded in the manifest.
    Sweep,
    /// Exact, as `Reference`, but each ray walked over a maximum pyramid of the context that
    /// skips whatever provably cannot rise above the best slope found so far, seeded with the
    /// neighbours' horizons (`horizon::pyramid`): the reference's answer at a fraction of its
    /// time.
    Exact,
    /// Brute force: each pixel's own ray walked cell by cell to the end of the context, the
    /// maximum over the continuous bilinear surface.
    Reference,
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "fast" => Ok(Method::Fast),
            "sweep" => Ok(Method::Sweep),
            "exact" => Ok(Method::Exact),
            "reference" => Ok(Method::Reference),
            _ => Err(format!(
                "unknown method '{s}' (fast, sweep, exact, reference)"
            )),
        }
    }
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Fast => "fast",
            Method::Sweep => "sweep",
            Method::Exact => "exact",
            Method::Reference => "reference",
        }
    }

    /// Whether the method sees the reach beyond its fine margin through far rings of coarser
    /// levels (docs/horizons.md, "Far rings"); the others see it all at full resolution.
    pub fn sees_far_rings(self) -> bool {
        matches!(self, Method::Fast | Method::Sweep)
    }
}

/// Raw horizon maps: per height tile one EXR of `azimuths` stacked planes.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct HorizonProduct {
    /// Path pattern, one EXR per height tile of the levels listed.
    pub path: String,
    /// The one channel: elevation angle in degrees above the local horizontal.
    pub channel: String,
    /// Sample type: `f16` or `f32`.
    pub precision: String,
    /// Azimuth samples per pixel (A); plane k holds plane azimuth 360·k/A degrees.
    pub azimuths: usize,
    /// The azimuth convention in one line.
    pub azimuth: String,
    /// How the planes are stored in the image.
    pub layout: String,
    /// `fast`, `exact` or `reference`.
    pub method: String,
    /// The fast method's exact near field (plane pixels); absent for the reference and in
    /// tilesets made before it was recorded (4 px then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub near_px: Option<f64>,
    /// The method's error against the reference, measured on pixels the stage checked as it
    /// ran (the sweep method; absent for the others, whose accuracy is documented).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<HorizonError>,
    /// Tile levels that have horizon maps.
    pub levels: Vec<u8>,
    /// Lowest and highest terrain of the body used to bound the distance searched (m).
    pub terrain_min_m: f64,
    pub terrain_max_m: f64,
    /// Per level: the distance any terrain could still rise above the horizon (km, at the
    /// largest tile maximum) and the context margin actually searched (px), with the number
    /// of tiles whose margin was capped by `max_margin_px`.
    pub distances: Vec<HorizonLevelDistance>,
    /// Tiles left out because their horizon can never reach a sun above the run's
    /// `lit_above_deg` (docs/horizons.md, "Tiles a scene's sun never needs"): they have no
    /// file and are fully lit for every sun whose lower limb is at or above the threshold;
    /// absent when the run was not given one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pruned: Option<HorizonPruned>,
    /// Hash of the tool version, the height tiles' run key and the horizon options.
    pub run_key: String,
    /// What `run_key` hashes besides the run keys of the products it was made from (the tool
    /// version, the stage's format strings, its parameters as text), so that a reader
    /// recomputes it; absent in tilesets written before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_key_basis: Option<super::KeyBasis>,
}

/// The tiles a horizon run left out, and why (`products.horizon.pruned`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct HorizonPruned {
    /// The threshold the run was given (degrees): a scene's lowest sun elevation less the
    /// sun's angular radius. A pruned tile is fully lit for a sun whose lower limb is at or
    /// above it, and has no answer for a lower one.
    pub lit_above_deg: f64,
    /// Each pruned tile (`level/face/x/y`) with the upper bound of its horizon elevation over
    /// every pixel and azimuth (degrees, below `lit_above_deg`).
    pub tiles: std::collections::BTreeMap<String, f32>,
}

impl HorizonPruned {
    /// The bound of tile `id` when it was pruned.
    pub fn bound(&self, id: TileId) -> Option<f32> {
        self.tiles.get(&pruned_key(id)).copied()
    }
}

impl HorizonProduct {
    /// Tile `id`'s threshold and bound when the run left it out (no file).
    pub fn pruned_tile(&self, id: TileId) -> Option<(f64, f32)> {
        let p = self.pruned.as_ref()?;
        p.bound(id).map(|b| (p.lit_above_deg, b))
    }
}

/// The key of tile `id` in `products.horizon.pruned.tiles`: `level/face/x/y`.
pub fn pruned_key(id: TileId) -> String {
    format!("{}/{}/{}/{}", id.level, id.face.name(), id.x, id.y)
}

/// The tile a key of `products.horizon.pruned.tiles` names; None when it names none.
pub fn parse_pruned_key(key: &str) -> Option<TileId> {
    let mut it = key.split('/');
    let level = it.next()?.parse().ok()?;
    let face = it.next()?;
    let face = crate::cube::Face::ALL
        .iter()
        .copied()
        .find(|f| f.name() == face)?;
    let x = it.next()?.parse().ok()?;
    let y = it.next()?.parse().ok()?;
    if it.next().is_some() {
        return None;
    }
    let id = TileId { level, face, x, y };
    (pruned_key(id) == key).then_some(id)
}

/// A horizon method's measured error against the reference (degrees, before the maps are
/// rounded to their precision): on a fixed sample of pixels of every tile a run computed, at
/// every azimuth (docs/horizons.md, "Error budget").
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct HorizonError {
    /// What it was measured against: `reference`.
    pub against: String,
    /// Pixels checked, and pixel·azimuths compared (both finite).
    pub pixels: u64,
    pub samples: u64,
    pub rms_deg: f64,
    /// Mean signed error (negative: below the reference).
    pub mean_deg: f64,
    /// 99th percentile of |error|, rounded up to the next edge of a histogram of 1/16-decade
    /// bins (an upper bound, at most 15.5 % above the true percentile).
    pub p99_deg: f64,
    pub max_deg: f64,
    /// The largest amount by which a sample exceeded the reference (0 when none did).
    pub max_above_deg: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct HorizonLevelDistance {
    pub level: u8,
    pub needed_km: f64,
    pub max_margin_px: u64,
    pub tiles_capped: u64,
    /// Tiles whose reach went beyond the fast method's full-resolution margin and was seen
    /// through far rings of coarser levels.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub tiles_with_far_rings: u64,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}
