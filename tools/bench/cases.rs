//! The cases the fourier and shadows benchmarks share: a block of observers at the centre of a
//! DEM, in a context raster reaching as far as a horizon could see, on a face plane whose
//! pixels are the map's; the shared real DEMs as such cases.

use std::path::Path;

use anyhow::Result;

use penumbra::cube::Face;
use penumbra::horizon::Context as HzContext;
use penumbra_cli::measure::{dem_case, Case, EARTH_RADIUS_M, REAL_DEMS};

/// Pixel spacing of the peers' synthetic UTM DEMs (m).
pub(crate) const PEER_PIXEL_M: f64 = 30.0;

/// The peers' synthetic DEM (`h` × `w`, row-major) as a patch at the centre of face +X, on
/// Earth's sphere at their 30 m spacing: there the gnomonic plane's scale error is below 1e-5
/// over ~30 km.
pub(crate) fn peer_context(h: usize, w: usize, heights: Vec<f32>) -> HzContext {
    let s = (2.0 * EARTH_RADIUS_M / PEER_PIXEL_M).round();
    let si = s as i64;
    HzContext {
        face: Face::Px,
        face_pixels: s,
        origin: ((si - w as i64) / 2, (si - h as i64) / 2),
        width: w,
        height: h,
        heights,
        radius_m: EARTH_RADIUS_M,
    }
}

pub(crate) fn real_cases(
    data: &Path,
    block: usize,
    say: &dyn Fn(String),
) -> Result<(Vec<Case>, Vec<String>)> {
    let mut cases = Vec::new();
    let mut notes = Vec::new();
    for (label, rel, body) in REAL_DEMS {
        let path = data.join(rel);
        if !path.exists() {
            notes.push(format!("{label}: {} not found, skipped.", path.display()));
            continue;
        }
        say(format!("reading {}", path.display()));
        let dem = penumbra::dem::open(&path, 64)?;
        cases.push(dem_case(label, &dem, body, block));
    }
    Ok((cases, notes))
}
