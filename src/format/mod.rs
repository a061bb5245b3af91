//! The formats layer: every product's file format and manifest entry, in one place below the
//! store (docs/architecture.md). Each module says what a product's files hold and how they are
//! named, writes them (staged, atomically) and reads them back checked; it knows no stage, no
//! runner and no tileset beyond the path patterns it is given. The store ([`crate::tileset`])
//! and the stages both use it.
//!
//! | module | product | files |
//! |---|---|---|
//! | [`height`] | height tiles | EXR: f32 `height` + f16 `mask`, halo included |
//! | [`albedo`] | albedo tiles | PNG, 8/16-bit, 1–4 channels |
//! | [`mip`] | max and (min, max) mipmaps | mip-mapped EXR per tile; face pyramids |
//! | [`horizon`] | raw horizon maps | EXR of `A` stacked planes, f16/f32 |
//! | [`fourier`] | Fourier horizon pyramids | `.fhm`: header, 16-bit groups, blake3 |
//! | [`lit`] | lit-fraction maps | grey PNG, f32 EXR |
//!
//! The EXR codec below them is [`crate::exrcodec`]; atomic writes are [`crate::fsio`].

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::cube::Face;
use crate::layout::TileId;

pub mod albedo;
pub mod fourier;
pub mod height;
pub mod horizon;
pub mod lit;
pub mod mip;

#[cfg(test)]
mod tests;

pub use crate::exrcodec::TileCompression;

/// The top-level folders the listed products own (`tileset::Product::dirs`); a product the
/// registry does not list may claim none of them.
pub const LISTED_DIRS: &[&str] = &["height", "albedo", "maxmip", "minmax", "horizon", "fourier"];

/// A source file a product was made from, as the manifest records it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SourceFile {
    pub path: String,
    pub bytes: u64,
    pub blake3: String,
}

/// Path of a tile's file below `root` from a product's path pattern (`{level}`, `{face}`,
/// `{x}`, `{y}`), e.g. `height/{level}/{face}/{y}/{x}.exr`.
pub fn tile_path(root: &Path, pattern: &str, id: TileId) -> PathBuf {
    root.join(
        pattern
            .replace("{level}", &id.level.to_string())
            .replace("{face}", id.face.name())
            .replace("{x}", &id.x.to_string())
            .replace("{y}", &id.y.to_string()),
    )
}

/// Path of a per-(level, face) file below `root` from a pattern with `{level}` and `{face}`.
pub fn face_file_path(root: &Path, pattern: &str, level: u8, face: Face) -> PathBuf {
    root.join(
        pattern
            .replace("{level}", &level.to_string())
            .replace("{face}", face.name()),
    )
}

/// Path of chunk (cx, cy) of a per-(level, face) file below `root` from a pattern with
/// `{level}`, `{face}`, `{cx}` and `{cy}`.
pub fn face_chunk_file_path(
    root: &Path,
    pattern: &str,
    level: u8,
    face: Face,
    cx: u32,
    cy: u32,
) -> PathBuf {
    root.join(
        pattern
            .replace("{level}", &level.to_string())
            .replace("{face}", face.name())
            .replace("{cx}", &cx.to_string())
            .replace("{cy}", &cy.to_string()),
    )
}
