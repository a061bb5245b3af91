//! The cases the fourier and shadows benchmarks share: a block of observers at the centre of a
//! DEM, in a context raster reaching as far as a horizon could see, on a face plane whose
//! pixels are the map's; the shared real DEMs as such cases.

use std::path::Path;

use anyhow::Result;

use penumbra::cube::Face;
use penumbra::fourier::sun::Frame;
use penumbra::horizon::{Context as HzContext, Rect};

use crate::common::{EARTH_RADIUS_M, MARS_RADIUS_M, MOON_RADIUS_M};

/// One case: a context raster and the block of observers in it.
pub(crate) struct Case {
    pub(crate) name: String,
    pub(crate) real: bool,
    pub(crate) body: &'static str,
    pub(crate) pixel_m: f64,
    pub(crate) ctx: HzContext,
    pub(crate) rect: Rect,
    /// Lowest terrain of the context (the encoder's floor).
    pub(crate) terrain_min_m: f64,
    /// Pixels (block coordinates) the stiff check must include.
    pub(crate) special: Vec<(usize, usize)>,
    /// Extra frames the stiff check must include (exact pole or corner), with the block pixel
    /// whose horizon they use.
    pub(crate) extra_frames: Vec<(Frame, (usize, usize))>,
    pub(crate) note: String,
}

fn body_radius(body: &str) -> f64 {
    match body {
        "moon" => MOON_RADIUS_M,
        "mars" => MARS_RADIUS_M,
        _ => EARTH_RADIUS_M,
    }
}

/// Horizon reach in plane pixels: an observer on the highest terrain sees down to the tangent
/// of the lowest sphere, and terrain beyond it can rise above that floor again.
fn reach_px(radius_m: f64, relief_m: f64, pixel_m: f64) -> usize {
    (2.0 * (2.0 * radius_m * relief_m.max(0.0)).sqrt() / pixel_m).ceil() as usize + 2
}

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
    let dems: [(&str, &str, &'static str); 6] = [
        ("LDEM_4 (Moon)", "lola_ldem4/LDEM_4.LBL", "moon"),
        ("MEGDR (Mars)", "mola_megt90n000cb/megt90n000cb.lbl", "mars"),
        (
            "Gale (MOLA 463 m)",
            "mola_gale_128ppd_crop/gale-mola.bin",
            "mars",
        ),
        (
            "Shoemaker (LOLA 5 m)",
            "lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif",
            "moon",
        ),
        ("Hawaiʻi (SRTM3)", "srtm3/N19W156.hgt", "earth"),
        ("White Mts (SRTM3)", "srtm3/N44W072.hgt", "earth"),
    ];
    let mut cases = Vec::new();
    let mut notes = Vec::new();
    for (label, rel, body) in dems {
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

/// A case from a DEM: a `block`² block of observers at the map's centre, in a context reaching
/// as far as a horizon could see, on a face plane whose pixels are the map's.
pub(crate) fn dem_case(
    label: &str,
    dem: &penumbra::dem::Dem,
    body: &'static str,
    block: usize,
) -> Case {
    let (w, h) = (dem.width(), dem.height());
    let radius_m = body_radius(body);
    let pixel_m = dem.pixel_size_m(radius_m);
    let b = block.min(w).min(h);
    let mut all = vec![0.0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            all[r * w + c] = dem.value(c, r).0;
        }
    }
    let (lo, hi) = all
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, u), &v| {
            (l.min(v), u.max(v))
        });
    let margin = reach_px(radius_m, (hi - lo) as f64, pixel_m);
    let (bx, by) = ((w - b) / 2, (h - b) / 2);
    let (cx0, cy0) = (bx.saturating_sub(margin), by.saturating_sub(margin));
    let (cx1, cy1) = ((bx + b + margin).min(w), (by + b + margin).min(h));
    let (cw, ch) = (cx1 - cx0, cy1 - cy0);
    let mut heights = Vec::with_capacity(cw * ch);
    for r in cy0..cy1 {
        heights.extend_from_slice(&all[r * w + cx0..r * w + cx1]);
    }
    let terrain_min_m = heights
        .iter()
        .filter(|v| v.is_finite())
        .fold(f64::INFINITY, |m, &v| m.min(v as f64));
    let s = (2.0 * radius_m / pixel_m).round();
    let si = s as i64;
    let ctx = HzContext {
        face: Face::Px,
        face_pixels: s,
        origin: ((si - cw as i64) / 2, (si - ch as i64) / 2),
        width: cw,
        height: ch,
        heights,
        radius_m,
    };
    let rect = Rect {
        x0: bx - cx0,
        y0: by - cy0,
        w: b,
        h: b,
    };
    let note = if b < block {
        format!("the whole {w}×{h} map (smaller than the block)")
    } else {
        format!(
            "{b}² block at the map's centre (pixel {bx}, {by} of {w}×{h}), context \
             {cw}×{ch} (reach {margin} px)"
        )
    };
    Case {
        name: label.into(),
        real: true,
        body,
        pixel_m,
        ctx,
        rect,
        terrain_min_m,
        special: Vec::new(),
        extra_frames: Vec::new(),
        note,
    }
}
