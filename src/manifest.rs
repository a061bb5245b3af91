//! `tileset.json`: what a tileset holds and how it was made. Specified in docs/tileset.md.
//! Later stages add their products here; readers must ignore keys they do not know.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::body::Body;
use crate::cube::Face;
use crate::dem::{GeoRef, Resampling};
use crate::error::{IoContext, Result};
use crate::layout::{Layout, TileId};

pub mod consistency;
pub mod validate;

// Each product's entry is defined with its file format (`crate::format`); the manifest gathers
// them.
pub use crate::format::albedo::{AlbedoProduct, ALBEDO_PATTERN};
pub use crate::format::fourier::{FourierGroup, FourierProduct};
pub use crate::format::height::{HeightProduct, HEIGHT_PATTERN};
pub use crate::format::horizon::{HorizonLevelDistance, HorizonProduct};
pub use crate::format::mip::{MipLevelRange, MipProduct};
pub use crate::format::SourceFile;

pub const MANIFEST: &str = "tileset.json";
pub const FORMAT: &str = "penumbra-tileset";
/// 2: every product file carries its identity (`format::Identity`) and every index its files'
/// blake3; a v1 tileset is refused with what to rerun (docs/tileset.md).
pub const FORMAT_VERSION: u32 = 2;

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

/// One source of a mosaic (several DEMs tiled together, `tiling::tile_sources`): what it is
/// and how wide its feathered seam is.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MosaicSource {
    pub source: SourceInfo,
    /// Width (pixels of this source) of the zone, inward from the edge of its data, over which
    /// it is blended into the sources below it.
    pub feather_px: f64,
}

/// Most sources one mosaic may list.
pub const MAX_MOSAIC_SOURCES: usize = 64;
/// Widest feather (source pixels) a mosaic source may ask for.
pub const MAX_FEATHER_PX: f64 = 4096.0;

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
    /// Products the registry does not list ([`crate::tileset::Product::Other`]), by name:
    /// kept as they are, and removed with their folders (`dirs`) when a product they `reads`
    /// is rewritten.
    #[serde(flatten)]
    pub extra: BTreeMap<String, serde_json::Value>,
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
    /// Every source of a mosaic in priority order, highest first (the first is `source`);
    /// empty (and absent from the file) when the heights come from one source.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub mosaic: Vec<MosaicSource>,
    pub products: Products,
    pub coverage: Vec<LevelCoverage>,
    /// Tiles a scene's bake asked for and cut that hold no data (levels with none left out;
    /// absent from the file when empty): a later bake of the same tiles knows them tried.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub no_data: Vec<LevelCoverage>,
    /// Every parameter that shaped the output.
    pub parameters: serde_json::Value,
    /// Hash of the tool version, the source hashes and the parameters: equal keys mean
    /// identical output.
    pub run_key: String,
}

impl Tileset {
    pub fn tile_set(&self) -> BTreeSet<TileId> {
        tiles_of(&self.coverage)
    }

    /// The tiles [`Tileset::no_data`] lists.
    pub fn no_data_set(&self) -> BTreeSet<TileId> {
        tiles_of(&self.no_data)
    }
}

/// The tiles a coverage lists.
pub fn tiles_of(coverage: &[LevelCoverage]) -> BTreeSet<TileId> {
    let mut set = BTreeSet::new();
    for lc in coverage {
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

impl Tileset {
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

/// Largest manifest read (a 24-level global tileset's coverage is a few MiB).
pub const MAX_MANIFEST_BYTES: u64 = 64 << 20;

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
