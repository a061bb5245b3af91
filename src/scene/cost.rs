//! The plan's model of the horizon stage's work (fast method), from the tiling and the sources
//! alone — no tileset is read. The stage's time per tile and azimuth is not a constant per pixel:
//! besides each observer's own work (its exact near field, the exact search of its guesses),
//! every azimuth sweeps lines across the tile's full-resolution context and across each far
//! ring of coarser levels, and each ring raises every pixel's horizon once more. How many
//! samples those lines hold depends on the tile size, on how far the body's relief reaches in
//! pixels of the tile's level, and on where the level's tiles stop (contexts are clipped to
//! them). [`horizon_work`] counts these quantities per tile as the horizon stage lays its
//! rasters out (`horizon::stage::{margin_for, tile_rasters, far_rings}`, followed here without a
//! tileset); the plan's `Rates` price them.

use std::collections::{BTreeSet, HashMap};

use serde::Serialize;

use crate::cube::{self, Face};
use crate::dem::{mask, Dem, Resampling};
use crate::horizon::stage::{coverage_box_of, ring_steps, window_on};
use crate::layout::{Layout, TileId};

/// Interior points per tile side sampled for its data fraction and highest point.
const GRID: i64 = 32;
/// Plane azimuths over which the line samples are averaged.
const AZ_SAMPLES: usize = 16;
/// Most tiles evaluated one by one; beyond, an evenly spaced subset stands for the rest.
const MAX_EVALUATED: usize = 512;

/// A global pixel box (x0, y0, x1, y1), half-open.
type PxBox = (i64, i64, i64, i64);

/// The horizon stage's work over a set of tiles, per azimuth (sums over the tiles).
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct HorizonWork {
    /// Tiles.
    pub tiles: f64,
    /// Interior pixels, and those with data (estimated from a 32 × 32 grid per tile).
    pub px: f64,
    pub data_px: f64,
    /// Line samples the sweeps visit in one azimuth: over the full-resolution contexts, and
    /// over the far rings.
    pub context_samples: f64,
    pub ring_samples: f64,
    /// Interior pixels times the far rings each is raised to.
    pub ring_px: f64,
}

impl HorizonWork {
    fn add(&mut self, o: &HorizonWork, w: f64) {
        self.tiles += o.tiles * w;
        self.px += o.px * w;
        self.data_px += o.data_px * w;
        self.context_samples += o.context_samples * w;
        self.ring_samples += o.ring_samples * w;
        self.ring_px += o.ring_px * w;
    }
}

/// What the model needs to know of the scene besides the tiles.
pub struct WorkInputs<'a> {
    pub layout: &'a Layout,
    pub radius_m: f64,
    /// The sources in priority order, each with its height shift (datum radius − body radius).
    pub sources: Vec<(&'a Dem, f64)>,
    /// The sources' lowest and highest heights ([`terrain_range`]).
    pub range: (f64, f64),
    /// The fast method's full-resolution margin and the largest context margin (pixels).
    pub fine_margin_px: u64,
    pub max_margin_px: u64,
    /// Whether the method sees far rings beyond the full-resolution margin.
    pub far_rings: bool,
}

/// The lowest and highest heights of `sources` (each with its height shift), read on a grid of
/// at most 512 × 512 of each one's pixels; None when no pixel has data.
pub fn terrain_range(sources: &[(&Dem, f64)]) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (dem, shift) in sources {
        let (w, h) = (dem.width(), dem.height());
        let (sx, sy) = (w.div_ceil(512).max(1), h.div_ceil(512).max(1));
        for r in (0..h).step_by(sy) {
            for c in (0..w).step_by(sx) {
                let v = dem.value(c, r).0;
                if v.is_finite() {
                    lo = lo.min(f64::from(v) + shift);
                    hi = hi.max(f64::from(v) + shift);
                }
            }
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// The horizon stage's work for `tiles` (those of one scene's horizon levels), where `all`
/// holds every tile of the tiling (the contexts stop where a level's tiles stop). At most
/// [`MAX_EVALUATED`] tiles are evaluated: an evenly spaced subset stands for the rest.
pub fn horizon_work(
    inp: &WorkInputs,
    tiles: &BTreeSet<TileId>,
    all: &BTreeSet<TileId>,
) -> HorizonWork {
    let mut covers: HashMap<(u8, Face), Option<PxBox>> = HashMap::new();
    let step = tiles.len().div_ceil(MAX_EVALUATED).max(1);
    let mut out = HorizonWork::default();
    let picked: Vec<TileId> = tiles.iter().step_by(step).copied().collect();
    let w = tiles.len() as f64 / picked.len().max(1) as f64;
    for id in picked {
        out.add(&tile_work(inp, id, all, &mut covers), w);
    }
    out
}

/// One tile's work per azimuth.
pub fn tile_work(
    inp: &WorkInputs,
    id: TileId,
    all: &BTreeSet<TileId>,
    covers: &mut HashMap<(u8, Face), Option<PxBox>>,
) -> HorizonWork {
    let lay = inp.layout;
    let n = lay.tile_size as i64;
    // Data fraction and highest point on a grid of interior pixel centres.
    let (mut hits, mut top) = (0u32, f64::NEG_INFINITY);
    for gj in 0..GRID {
        for gi in 0..GRID {
            let (i, j) = ((2 * gi + 1) * n / (2 * GRID), (2 * gj + 1) * n / (2 * GRID));
            let d = lay.pixel_dir(id, i, j);
            if let Some(h) = inp.sources.iter().find_map(|(dem, shift)| {
                let (h, m) = dem.sample_dir(d, Resampling::Bilinear);
                (m != mask::NO_DATA && h.is_finite()).then_some(f64::from(h) + shift)
            }) {
                hits += 1;
                top = top.max(h);
            }
        }
    }
    let px = (n * n) as f64;
    let mut work = HorizonWork {
        tiles: 1.0,
        px,
        data_px: px * f64::from(hits) / (GRID * GRID) as f64,
        ..Default::default()
    };
    if hits == 0 {
        // The stage writes no-data horizons without a context.
        return work;
    }
    let (lo, hi) = inp.range;
    let rad = crate::horizon::reach_rad(inp.radius_m, lo, hi.max(top), top);
    // The reach in pixels of the tile's level: the angle over one pixel at the tile's centre.
    let c = lay.pixel_dir(id, n / 2, n / 2);
    let px_rad = cube::angle_between(c, lay.pixel_dir(id, n / 2 + 1, n / 2));
    let needed = (rad / px_rad * 1.01 + 2.0).ceil() as u64;
    let margin = needed.min(inp.max_margin_px.max(1));
    let fine = if inp.far_rings {
        margin.min(inp.fine_margin_px)
    } else {
        margin
    };
    let (tx, ty) = (i64::from(id.x) * n, i64::from(id.y) * n);
    let cover = *covers
        .entry((id.level, id.face))
        .or_insert_with(|| coverage_box_of(lay, all, id.level, id.face));
    let win = window_on(lay, id.level, (tx, ty, tx + n, ty + n), fine as i64, cover);
    work.context_samples = line_samples(win, (tx, ty, tx + n, ty + n));
    if !(inp.far_rings && fine < needed) {
        return work;
    }
    // The far rings, as `horizon::stage::far_rings` plans them.
    let mut prev = win;
    for r in ring_steps(id, lay.tile_size, fine, needed, inp.fine_margin_px) {
        let cover = *covers
            .entry((r.level, id.face))
            .or_insert_with(|| coverage_box_of(lay, all, r.level, id.face));
        let rwin = window_on(lay, r.level, r.foot, r.margin, cover);
        // A ring with no terrain beyond what the finer window holds is not built.
        if ring_has_terrain(inp, r.level, id.face, rwin, prev) {
            work.ring_samples += line_samples(rwin, r.foot);
            work.ring_px += px;
        }
        prev = rwin;
    }
    work
}

/// Whether any of `inp`'s sources has data in the window `win` (global pixels of `level` on
/// `face`'s extended plane) outside what the finer window `prev` (pixels of `level + 1`) holds,
/// on a [`GRID`] × [`GRID`] lattice of the window (a ring's terrain narrower than the
/// lattice's spacing is missed: the estimate then leaves out that ring's work).
fn ring_has_terrain(inp: &WorkInputs, level: u8, face: Face, win: PxBox, prev: PxBox) -> bool {
    let s = inp.layout.face_pixels(level) as f64;
    let inner = (
        prev.0.div_euclid(2) + prev.0.rem_euclid(2),
        prev.1.div_euclid(2) + prev.1.rem_euclid(2),
        prev.2.div_euclid(2),
        prev.3.div_euclid(2),
    );
    let (w, h) = ((win.2 - win.0) as f64, (win.3 - win.1) as f64);
    for gj in 0..GRID {
        for gi in 0..GRID {
            let gx = win.0 as f64 + (gi as f64 + 0.5) * w / GRID as f64;
            let gy = win.1 as f64 + (gj as f64 + 0.5) * h / GRID as f64;
            let (px, py) = (gx.floor() as i64, gy.floor() as i64);
            if px >= inner.0 && px < inner.2 && py >= inner.1 && py < inner.3 {
                continue;
            }
            let d = cube::face_uv_to_dir(face, -1.0 + 2.0 * gx / s, 1.0 - 2.0 * gy / s);
            if inp
                .sources
                .iter()
                .any(|(dem, _)| dem.sample_dir(d, Resampling::Bilinear).1 != mask::NO_DATA)
            {
                return true;
            }
        }
    }
    false
}

/// The samples one azimuth's sweep visits, averaged over [`AZ_SAMPLES`] azimuths: the lines one
/// pixel apart (along the minor axis) that pass through the observers' box `obs`, each over
/// the whole raster `win` (global boxes), sampled where it crosses pixel columns and rows —
/// the layout of `horizon::sweep::Lines`.
pub fn line_samples(win: PxBox, obs: PxBox) -> f64 {
    let (w, h) = ((win.2 - win.0) as f64, (win.3 - win.1) as f64);
    let (rx0, ry0) = ((obs.0 - win.0) as f64, (obs.1 - win.1) as f64);
    let (rx1, ry1) = ((obs.2 - win.0) as f64, (obs.3 - win.1) as f64);
    let mut total = 0.0;
    for k in 0..AZ_SAMPLES {
        let phi = std::f64::consts::TAU * (k as f64 + 0.5) / AZ_SAMPLES as f64;
        let (dx, dy) = (phi.cos(), -phi.sin());
        // Major axis p, minor q.
        let (np, nq, p0, p1, q0, q1, t) = if dx.abs() >= dy.abs() {
            (w, h, rx0, rx1, ry0, ry1, dy / dx)
        } else {
            (h, w, ry0, ry1, rx0, rx1, dx / dy)
        };
        // Lines q = m + t·p through the observers: m over the box's corners.
        let ms = [q0 - t * p0, q0 - t * p1, q1 - t * p0, q1 - t * p1];
        let m_lo = ms.iter().copied().fold(f64::INFINITY, f64::min).floor() as i64 - 1;
        let m_hi = ms.iter().copied().fold(f64::NEG_INFINITY, f64::max).ceil() as i64 + 1;
        for m in m_lo..=m_hi {
            let mf = m as f64;
            // The part of the line inside the raster: p in [0, np − 1], q in [−1, nq].
            let (mut pa, mut pb) = (0.0, np - 1.0);
            if t != 0.0 {
                let (e0, e1) = ((-1.0 - mf) / t, (nq - mf) / t);
                pa = f64::max(pa, e0.min(e1).floor());
                pb = f64::min(pb, e0.max(e1).ceil());
            } else if mf < -1.0 || mf > nq {
                continue;
            }
            if pb >= pa {
                total += (pb - pa + 1.0) * (1.0 + t.abs());
            }
        }
    }
    total / AZ_SAMPLES as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_raster_swept_whole_gives_its_area_times_the_crossings() {
        // Lines one pixel apart across the whole raster cover its area once; each pixel column
        // crossed adds a sample and so does each row, |t| per column.
        let n = 1024i64;
        let got = line_samples((0, 0, n, n), (0, 0, n, n));
        let want: f64 = (0..AZ_SAMPLES)
            .map(|k| {
                let phi = std::f64::consts::TAU * (k as f64 + 0.5) / AZ_SAMPLES as f64;
                let (c, s) = (phi.cos().abs(), phi.sin().abs());
                1.0 + c.min(s) / c.max(s)
            })
            .sum::<f64>()
            / AZ_SAMPLES as f64
            * (n * n) as f64;
        assert!((got / want - 1.0).abs() < 0.01, "{got} against {want}");
        // Observers in a corner of the same raster sweep fewer lines, each as long.
        let corner = line_samples((0, 0, n, n), (0, 0, n / 4, n / 4));
        assert!(corner < got / 2.0, "{corner} against {got}");
    }
}
