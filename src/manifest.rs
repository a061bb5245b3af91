//! `tileset.json`: what a tileset holds and how it was made. Specified in docs/tileset.md.
//! Later stages add their products here; readers must ignore keys they do not know.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::body::Body;
use crate::cube::Face;
use crate::dem::{GeoRef, Resampling};
use crate::error::{Error, IoContext, Result};
use crate::layout::{Layout, TileId};

pub mod validate;

pub const MANIFEST: &str = "tileset.json";
pub const FORMAT: &str = "penumbra-tileset";
pub const FORMAT_VERSION: u32 = 1;
pub const HEIGHT_PATTERN: &str = "height/{level}/{face}/{y}/{x}.exr";
pub const ALBEDO_PATTERN: &str = "albedo/{level}/{face}/{y}/{x}.png";

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Tool {
    pub name: String,
    pub version: String,
}

impl Tool {
    pub fn this() -> Tool {
        Tool {
            name: "penumbra".into(),
            version: env!("CARGO_PKG_VERSION").into(),
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SourceFile {
    pub path: String,
    pub bytes: u64,
    pub blake3: String,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SourceInfo {
    pub files: Vec<SourceFile>,
    pub format: String,
    pub width: usize,
    pub height: usize,
    pub georef: GeoRef,
    /// Nominal source pixel size on the body (m).
    pub pixel_size_m: f64,
    /// Radius the source heights refer to, when the source says.
    pub datum_radius_m: Option<f64>,
    /// Added to every source height to make it relative to the body's radius.
    pub height_shift_m: f64,
    /// Void samples in the source, and how many stayed no data after filling.
    pub voids: u64,
    pub voids_unfilled: u64,
}

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

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AlbedoProduct {
    pub path: String,
    pub source: SourceFile,
    pub bit_depth: u8,
    pub channels: u8,
    /// Longitude of the image's left edge (east-positive degrees).
    pub west_lon_deg: f64,
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
    pub precision: crate::mip::schema::Precision,
    /// Sample type of the face pyramids.
    pub face_precision: crate::mip::schema::Precision,
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
}

#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct Products {
    pub height: Option<HeightProduct>,
    pub albedo: Option<AlbedoProduct>,
    /// Absent in tilesets made before the mipmap stage existed.
    #[serde(default)]
    pub mip: Option<MipProduct>,
    /// Raw horizon maps (docs/horizons.md); absent unless the horizon stage ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub horizon: Option<HorizonProduct>,
    /// Fourier-compressed horizon pyramids (docs/fourier.md); absent unless made.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fourier: Option<FourierProduct>,
}

/// One group of a Fourier pyramid: coefficients `first..first + count` at `resolution`² texels.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FourierGroup {
    pub first: usize,
    pub count: usize,
    pub resolution: usize,
}

/// Fourier-compressed horizon pyramids: per height tile one file of coefficient groups.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FourierProduct {
    /// Path pattern, one file per height tile of the levels listed.
    pub path: String,
    /// File format name and version (docs/fourier.md).
    pub format: String,
    /// Tile levels that have pyramids.
    pub levels: Vec<u8>,
    /// Azimuth samples the series come from (A); the series' variable is the plane azimuth.
    pub azimuths: usize,
    /// The azimuth convention in one line (the raw maps').
    pub azimuth: String,
    /// Coefficients kept per pixel (K; the most any tile keeps when `max_error_deg` is set).
    pub coefficients: usize,
    /// `multires` or `full`.
    pub layout: String,
    /// `f16` or `snorm16`.
    pub encoding: String,
    /// `none` or `lanczos`.
    pub sigma: String,
    /// How reduced groups were made: `mean` or `fit` (docs/fourier.md).
    pub reduce: String,
    /// The groups of a tile holding `coefficients`.
    pub groups: Vec<FourierGroup>,
    /// Bytes of a tile's file holding `coefficients`.
    pub bytes_per_tile: u64,
    /// What the stored series approximate: the raw horizon floored at the tangent to the sphere
    /// of the lowest terrain (a body does not end where its DEM does).
    pub floor: String,
    /// Error budget that chose K per tile (degrees, 99th percentile of per-pixel RMS), if any,
    /// and then each tile's K (`level/face/x/y` → K).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_error_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tile_coefficients: Option<BTreeMap<String, usize>>,
    /// Tiles marked fully lit for suns whose centre is at or above `min_sun_el_deg` (their
    /// horizon never rises above `min_sun_el_deg − sun_radius_deg`): no coefficients stored.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_sun_el_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sun_radius_deg: Option<f64>,
    pub tiles_fully_lit: u64,
    /// `raw` (from the stored horizon maps) or `streamed` (compressed as the horizon stage
    /// computed them).
    pub source: String,
    /// How the horizons were computed: `fast`, `exact` or `reference`, the fast method's near
    /// field, the terrain range bounding the search, and the per-level distances.
    pub horizon_method: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub horizon_near_px: Option<f64>,
    pub terrain_min_m: f64,
    pub terrain_max_m: f64,
    pub distances: Vec<HorizonLevelDistance>,
    /// Hash of the tool version, the inputs' run keys and the options.
    pub run_key: String,
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
    /// Tile levels that have horizon maps.
    pub levels: Vec<u8>,
    /// Lowest and highest terrain of the body used to bound the distance searched (m).
    pub terrain_min_m: f64,
    pub terrain_max_m: f64,
    /// Per level: the distance any terrain could still rise above the horizon (km, at the
    /// largest tile maximum) and the context margin actually searched (px), with the number
    /// of tiles whose margin was capped by `max_margin_px`.
    pub distances: Vec<HorizonLevelDistance>,
    /// Hash of the tool version, the height tiles' run key and the horizon options.
    pub run_key: String,
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

/// Tiles present at one level, as row runs `[y, x_first, x_last]` per face.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct LevelCoverage {
    pub level: u8,
    pub tiles: u64,
    /// Tiles per face at this level (4^level), so `tiles` < 6 × this means partial coverage.
    pub tiles_per_face: u64,
    pub faces: BTreeMap<Face, Vec<[u32; 3]>>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Tileset {
    pub format: String,
    pub format_version: u32,
    pub tool: Tool,
    pub body: Body,
    pub layout: Layout,
    pub resampling: Resampling,
    pub source: SourceInfo,
    pub products: Products,
    pub coverage: Vec<LevelCoverage>,
    /// Every parameter that shaped the output.
    pub parameters: serde_json::Value,
    /// Hash of the tool version, the source hashes and the parameters: equal keys mean
    /// identical output.
    pub run_key: String,
}

impl Tileset {
    /// Read and validate the manifest of the tileset in `dir` (see [`validate`]).
    pub fn load(dir: &Path) -> Result<Tileset> {
        let path = dir.join(MANIFEST);
        if !path.exists() {
            return Err(Error::invalid(
                &path,
                "no tileset manifest here: point at a folder made by `penumbra tile` or `penumbra bake`",
            ));
        }
        let bytes = crate::fsio::read_capped(
            &path,
            self::validate::MAX_MANIFEST_BYTES,
            "a tileset manifest",
        )?;
        let de = &mut serde_json::Deserializer::from_slice(&bytes);
        let t: Tileset = serde_path_to_error::deserialize(de).map_err(|e| {
            let field = e.path().to_string();
            Error::invalid(
                &path,
                format!(
                    "manifest is not valid at field `{field}`: {}; restore it, or rerun \
                     `penumbra tile`/`bake` into a fresh folder",
                    e.inner()
                ),
            )
        })?;
        if t.format != FORMAT || t.format_version > FORMAT_VERSION {
            return Err(Error::unsupported(
                &path,
                format!(
                    "format {} v{} (this penumbra reads {FORMAT} up to v{FORMAT_VERSION})",
                    t.format, t.format_version
                ),
            ));
        }
        self::validate::check(&t, &path)?;
        Ok(t)
    }

    pub fn tile_set(&self) -> BTreeSet<TileId> {
        let mut set = BTreeSet::new();
        for lc in &self.coverage {
            for (face, runs) in &lc.faces {
                for r in runs {
                    for x in r[1]..=r[2] {
                        set.insert(TileId {
                            level: lc.level,
                            face: *face,
                            x,
                            y: r[0],
                        });
                    }
                }
            }
        }
        set
    }

    pub fn has_tile(&self, id: TileId) -> bool {
        self.coverage.iter().any(|lc| {
            lc.level == id.level
                && lc.faces.get(&id.face).is_some_and(|runs| {
                    runs.iter()
                        .any(|r| r[0] == id.y && (r[1]..=r[2]).contains(&id.x))
                })
        })
    }
}

/// Row-run coverage of a set of tiles, one entry per level 0..levels.
pub fn coverage_of(tiles: &BTreeSet<TileId>, levels: u8) -> Vec<LevelCoverage> {
    (0..levels)
        .map(|level| {
            let mut faces: BTreeMap<Face, Vec<[u32; 3]>> = BTreeMap::new();
            let mut count = 0;
            for t in tiles.iter().filter(|t| t.level == level) {
                count += 1;
                let runs = faces.entry(t.face).or_default();
                match runs.last_mut() {
                    Some(r) if r[0] == t.y && r[2] + 1 == t.x => r[2] = t.x,
                    _ => runs.push([t.y, t.x, t.x]),
                }
            }
            LevelCoverage {
                level,
                tiles: count,
                tiles_per_face: 1u64 << (2 * level as u32),
                faces,
            }
        })
        .collect()
}

/// blake3 of a file, streamed through a memory map.
pub fn hash_file(path: &Path) -> Result<SourceFile> {
    let meta = std::fs::metadata(path).at(path)?;
    let mut h = blake3::Hasher::new();
    if meta.len() > 0 {
        let map = crate::dem::map_file(path)?;
        h.update(&map);
    }
    Ok(SourceFile {
        path: path.display().to_string(),
        bytes: meta.len(),
        blake3: h.finalize().to_hex().to_string(),
    })
}
