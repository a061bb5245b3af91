//! The mipmap stage: per height tile a maximum pyramid and a (min, max) extrema pyramid, per
//! face and tile level a coarse pyramid of whole-tile extrema, and the body's global extrema.
//! Specified in docs/mipmaps.md.
//!
//! Texel convention: level-0 texel (i, j) of a tile is interior pixel (i, j) and bounds the
//! *bilinearly interpolated* height over that pixel's footprint [i−½, i+½]×[j−½, j+½] (pixel
//! centres at integers). That footprint straddles four bilinear cells whose corners are the
//! stored samples i−1..=i+1, j−1..=j+1, so the level-0 max (min) is the extreme of those 3×3
//! samples — the halo supplies the ring outside the interior. Level k texel (x, y) is the
//! extreme of its 2×2 children (one child, or two, at an odd edge), down to 1×1.
//!
//! No data: a NaN sample never becomes an extreme; a texel whose whole footprint is NaN is
//! NaN ("no terrain here").
//!
//! The kernels fold raw samples into a NaN-free accumulator with `if v > acc { v } else { acc }`
//! (one `maxps` on x86: a NaN `v` leaves `acc`), starting from −∞ (+∞ for the minimum), and
//! turn a −∞ (+∞) result back into NaN. Heights are finite or NaN, never ±∞.
//!
//! `kernels`: level sizes, directed f16 rounding and the pyramid computation (SIMD on x86-64);
//! `io`: the mip-mapped EXR files; `schema`: the storage [`Precision`] (a leaf, also used by
//! the manifest); `stage`: the stage over a tileset and the point query.

mod kernels;
mod stage;

pub use self::kernels::{
    f16_down, f16_up, face_pyramid, level_sizes, max_pyramid, max_pyramid_into, minmax_pyramid,
    minmax_pyramid_into, MaxPyramid, MinMaxPyramid,
};
pub use self::stage::{build_mips, MipOptions, MipReport, MipStage, STAGE};
pub use crate::format::mip::{
    decode_mip_exr, encode_mip_exr, encode_mip_exr_exr_crate, face_chunk_path, face_path,
    read_mip_exr, tile_paths, write_mip_exr, MipFile, Precision, FACE_CHUNK_PATTERN,
    FACE_CHUNK_TILES, FACE_PATTERN, MAX_PATTERN, MINMAX_PATTERN, MIP_FORMAT, TEXEL_CONVENTION,
};
