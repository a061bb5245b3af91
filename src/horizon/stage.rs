//! The horizon stage over a tileset: a context raster per tile (the tile, its neighbours and
//! the neighbouring faces as far as any terrain could rise above the horizon), the horizons of
//! its pixels, and the raw maps on disk; plus the on-demand query of one point.

use super::bound::{self, FarLevel, MipCache, NEAR_PX};
use super::budget::Tally;
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::device::{horizons_sweep_on, SharedDevice, SweepDevice};
use super::far::FarRing;
use super::geometry::{Context, Rect};
use super::method::{horizons_with, FarHorizons, Method};
use super::near::{DEFAULT_NEAR_PX, MAX_NEAR_PX};
use crate::cube::{Face, Projection};
use crate::error::{Error, Result};
use crate::format::height::HeightTile;
use crate::format::horizon::ID as HORIZON_ID;
use crate::format::horizon::{
    tile_path, write_horizon_exr, HorizonPrecision, HorizonPruned, AZIMUTH_CONVENTION, FORMAT,
    LAYOUT, PATTERN,
};
use crate::format::TileCompression;
use crate::format::{Identity, KeyBasis};
use crate::layout::TileId;
use crate::manifest::{self, HorizonLevelDistance, HorizonProduct, Tileset};
use crate::progress::Progress;
use crate::runner::{self, Cx, Finished, Order, Reads, Select, Stage, StageSpec, Unit};
use crate::sink::{HorizonSink, HorizonSource, HorizonTile, SinkRun};
use crate::tileset::{Product, Store};

/// Revision of the algorithms' results (part of the run key: a rerun after a change that moves
/// the values recomputes instead of keeping maps made the old way). 2: the fast method's exact
/// near field reaches 24 px instead of 4, and far candidates at the raster's edge are clamped.
/// 3: beyond `fine_margin_px` the fast method sees far rings of coarser levels. 4: its sweep
/// serves opposite azimuths at once and leaves guesses that are searched exactly afterwards.
const ALGORITHM: &str = "4";
/// A global pixel window or box (x0, y0, x1, y1), half-open.
type PxBox = (i64, i64, i64, i64);
/// Each (level, face)'s coverage box, computed once per run.
pub(crate) type Covers = HashMap<(u8, Face), Option<PxBox>>;

/// The fast method's full-resolution margin (`--fine-margin-px`) when none is given: two tile
/// widths, at least 1024 px (1024 px around the default 512-px tiles). The far rings' error
/// grows as the margin shrinks, with the terrain's relief: at 256 px around 128-px tiles it
/// was 0.002° RMS on Gale but 0.033° RMS (3.1° worst) on Hawaiʻi's volcanoes, at 1024 px
/// 0.0007° and 0.0017° (docs/benchmarks.md, far rings re-run 2026-12-04), so small tiles get
/// the default tiles' margin rather than one that scales down with them.
pub fn default_fine_margin_px(tile_size: u32) -> u64 {
    (2 * u64::from(tile_size)).max(1024)
}
/// Bounds of `--fine-margin-px`.
pub const FINE_MARGIN_PX: std::ops::RangeInclusive<u64> = 16..=65536;

/// How many of a tile's far rings (the nearest) keep their height tiles cached for the next
/// tile; the farther rings' tiles are read again for every tile.
const CACHED_RINGS: usize = 2;

/// Largest |u|, |v| a context reaches on a face's extended plane (71.6° from the face centre
/// along an axis).
const PLANE_LIMIT: f64 = 3.0;

/// What the user chose.
#[derive(Clone, Debug, Serialize)]
pub struct HorizonOptions {
    /// Tile levels to compute (None: every level).
    pub levels: Option<Vec<u8>>,
    pub azimuths: usize,
    pub method: Method,
    pub precision: HorizonPrecision,
    pub compression: TileCompression,
    /// Largest context margin around a tile, in pixels of its level.
    pub max_margin_px: u64,
    /// Refuse a run whose raw maps would exceed this many GiB (uncompressed).
    pub max_output_gib: f64,
    /// The fast method's exact near field, plane pixels (0..=MAX_NEAR_PX).
    pub near_px: f64,
    /// The fast and sweep methods' full-resolution margin around a tile (pixels of its level); beyond
    /// it, out to the whole reach, far rings of coarser levels ([`FarRing`]). None:
    /// [`default_fine_margin_px`].
    pub fine_margin_px: Option<u64>,
    /// Leave out the tiles whose horizon can never rise to this elevation (degrees: a scene's
    /// lowest sun less the sun's angular radius) by a conservative bound
    /// ([`super::bound::tile_bound_deg`]): they are recorded fully lit and not computed.
    /// None: every tile is computed (and the run key is what it was before the option).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lit_above_deg: Option<f64>,
    /// The terrain range (metres, lowest and highest) the search distance and the encoders
    /// assume, widened to the tileset's own where that is larger. None: the tileset's. A scene
    /// bake gives its sources' range, so that tiles added later leave it as it was and the
    /// horizons already made stay valid (an incremental bake redoes only what the new tiles
    /// change).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub terrain_range_m: Option<(f64, f64)>,
    /// Where the sweep method runs (None: the CPU, as every other method): a device
    /// ([`super::device`]) the front end made. Its key is part of the run key (a device's maps
    /// are within the method's budget of the CPU's, not the same bytes).
    #[serde(skip_serializing_if = "Option::is_none", serialize_with = "device_key")]
    pub device: Option<SharedDevice>,
}

fn device_key<S: serde::Serializer>(
    d: &Option<SharedDevice>,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    match d {
        Some(d) => s.serialize_str(&d.key()),
        None => s.serialize_none(),
    }
}

impl Default for HorizonOptions {
    fn default() -> Self {
        HorizonOptions {
            levels: None,
            azimuths: 360,
            method: Method::Fast,
            precision: HorizonPrecision::F16,
            compression: TileCompression::Zip,
            max_margin_px: 4096,
            max_output_gib: 8.0,
            near_px: DEFAULT_NEAR_PX,
            fine_margin_px: None,
            lit_above_deg: None,
            terrain_range_m: None,
            device: None,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct HorizonReport {
    pub out: PathBuf,
    pub levels: Vec<u8>,
    pub azimuths: usize,
    pub method: Method,
    pub tiles: u64,
    pub tiles_written: u64,
    pub tiles_kept: u64,
    /// Observer pixels × azimuths computed in this run.
    pub pixel_azimuths: u64,
    pub distances: Vec<HorizonLevelDistance>,
    pub up_to_date: bool,
    /// Whether raw maps were written.
    pub raw: bool,
    /// What each sink the horizons streamed into made (`fourier`: the pyramids' summary),
    /// by sink name.
    #[serde(flatten)]
    pub streamed: BTreeMap<String, serde_json::Value>,
    /// Seconds spent computing horizons and handing them to the sinks (compressing them;
    /// this run's tiles).
    pub horizon_s: f64,
    pub compress_s: f64,
    /// With `lit_above_deg`: tiles left out (this run's and kept ones), and the seconds this
    /// run spent bounding tiles.
    pub tiles_pruned: u64,
    pub bound_s: f64,
}

// ---------------------------------------------------------------------------------------------
// Context

/// How far a tile's context reaches.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Reach {
    /// Margin around the tile holding everything within `reach_rad` of it, and the margin
    /// used (capped by `--max-margin-px`), in pixels.
    pub needed_px: u64,
    pub margin_px: u64,
}

/// The terrain range used to bound distances: the mipmaps' global extrema when the mip stage
/// ran, else the height product's range.
pub fn terrain_range(ts: &Tileset) -> Option<(f64, f64)> {
    if let Some(m) = &ts.products.mip {
        return Some((m.global_min_m, m.global_max_m));
    }
    ts.products.height.as_ref().map(|h| (h.min_m, h.max_m))
}

/// The terrain range a run with `opts` assumes: the tileset's, widened to
/// [`HorizonOptions::terrain_range_m`].
fn run_range(ts: &Tileset, opts: &HorizonOptions, manifest_path: &Path) -> Result<(f64, f64)> {
    let range = terrain_range(ts)
        .ok_or_else(|| Error::invalid(manifest_path, "tileset records no height range"))?;
    Ok(match opts.terrain_range_m {
        Some((lo, hi)) => {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(Error::param(
                    "terrain_range_m",
                    format!("({lo}, {hi}) is not a range of heights: give lowest ≤ highest"),
                ));
            }
            (lo.min(range.0), hi.max(range.1))
        }
        None => range,
    })
}

/// The distance beyond which no terrain can rise above the horizon of a pixel at most
/// `top_m` high: the tangent from the highest observer grazing the lowest terrain reaches
/// the lowest sphere after acos((R+min)/(R+top)) and climbs out to the highest terrain after
/// another acos((R+min)/(R+max)). Any pixel's horizon is at least that tangent's elevation.
pub fn reach_rad(radius: f64, min_m: f64, max_m: f64, top_m: f64) -> f64 {
    let a = ((radius + min_m) / (radius + top_m.max(min_m)))
        .min(1.0)
        .acos();
    let b = ((radius + min_m) / (radius + max_m.max(min_m)))
        .min(1.0)
        .acos();
    a + b
}

/// Margin (px) around tile `id` that holds every point within angular distance `rad` of the
/// tile, measured on `id.face`'s extended plane: from points along the tile's border, the
/// points `rad` away in 64 directions, projected onto the plane (a point within `rad` of the
/// tile is within `rad` of its border or inside it); the sampling gap between directions is
/// covered by a 1 % + 2 px allowance.
pub(crate) fn margin_for(ts: &Tileset, id: TileId, rad: f64, cap: u64) -> Reach {
    let lay = ts.layout;
    let s = lay.face_pixels(id.level) as f64;
    let n = lay.tile_size as i64;
    let (n3, u3, v3) = id.face.axes();
    let mut need = 0.0f64;
    const EDGE: i64 = 16;
    const DIRS: usize = 64;
    for e in 0..4 * EDGE {
        let (i, j) = match e / EDGE {
            0 => ((e % EDGE) * n / EDGE, 0),
            1 => (n, (e % EDGE) * n / EDGE),
            2 => (n - (e % EDGE) * n / EDGE, n),
            _ => (0, n - (e % EDGE) * n / EDGE),
        };
        // Corner of pixel (i, j): global pixel edge coordinates.
        let (gx, gy) = (
            id.x as f64 * n as f64 + i as f64,
            id.y as f64 * n as f64 + j as f64,
        );
        let (u, v) = (-1.0 + 2.0 * gx / s, 1.0 - 2.0 * gy / s);
        let p = crate::cube::face_uv_to_dir(id.face, u, v);
        // A tangent basis at p.
        let a = {
            let k = u3[0] * p[0] + u3[1] * p[1] + u3[2] * p[2];
            let t = [u3[0] - k * p[0], u3[1] - k * p[1], u3[2] - k * p[2]];
            let l = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
            [t[0] / l, t[1] / l, t[2] / l]
        };
        let b = [
            p[1] * a[2] - p[2] * a[1],
            p[2] * a[0] - p[0] * a[2],
            p[0] * a[1] - p[1] * a[0],
        ];
        for k in 0..DIRS {
            let th = std::f64::consts::TAU * k as f64 / DIRS as f64;
            let (c, sn) = (th.cos(), th.sin());
            let q = [
                p[0] * rad.cos() + (a[0] * c + b[0] * sn) * rad.sin(),
                p[1] * rad.cos() + (a[1] * c + b[1] * sn) * rad.sin(),
                p[2] * rad.cos() + (a[2] * c + b[2] * sn) * rad.sin(),
            ];
            let z = q[0] * n3[0] + q[1] * n3[1] + q[2] * n3[2];
            let (qu, qv) = if z > 1e-9 {
                (
                    ((q[0] * u3[0] + q[1] * u3[1] + q[2] * u3[2]) / z)
                        .clamp(-PLANE_LIMIT, PLANE_LIMIT),
                    ((q[0] * v3[0] + q[1] * v3[1] + q[2] * v3[2]) / z)
                        .clamp(-PLANE_LIMIT, PLANE_LIMIT),
                )
            } else {
                (PLANE_LIMIT, PLANE_LIMIT)
            };
            let (qx, qy) = ((qu + 1.0) / 2.0 * s, (1.0 - qv) / 2.0 * s);
            let (tx0, ty0) = (id.x as f64 * n as f64, id.y as f64 * n as f64);
            let dxm = (tx0 - qx).max(qx - (tx0 + n as f64)).max(0.0);
            let dym = (ty0 - qy).max(qy - (ty0 + n as f64)).max(0.0);
            need = need.max(dxm).max(dym);
        }
    }
    let needed = (need * 1.01 + 2.0).ceil() as u64;
    Reach {
        needed_px: needed,
        margin_px: needed.min(cap.max(1)),
    }
}

/// Bounding box (global pixels of `face` at `level`, half-open) of every tile of the level
/// projected onto `face`'s plane, or None when none projects there.
pub(crate) fn coverage_box(ts: &Tileset, level: u8, face: Face) -> Option<(i64, i64, i64, i64)> {
    coverage_box_of(&ts.layout, &ts.tile_set(), level, face)
}

/// [`coverage_box`] of the tiles `all` (those of other levels ignored) on `lay`.
pub(crate) fn coverage_box_of(
    lay: &crate::layout::Layout,
    all: &std::collections::BTreeSet<TileId>,
    level: u8,
    face: Face,
) -> Option<PxBox> {
    let s = lay.face_pixels(level) as f64;
    let n = lay.tile_size as i64;
    let mut bx = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
    let mut grow = |x: i64, y: i64| {
        bx.0 = bx.0.min(x);
        bx.1 = bx.1.min(y);
        bx.2 = bx.2.max(x);
        bx.3 = bx.3.max(y);
    };
    for &id in all.iter().filter(|t| t.level == level) {
        if id.face == face {
            let (x, y) = (id.x as i64 * n, id.y as i64 * n);
            grow(x, y);
            grow(x + n, y + n);
            continue;
        }
        // Another face: a lattice over the tile, projected where it is in front of `face`.
        for j in 0..=8 {
            for i in 0..=8 {
                let d = lay.pixel_dir(id, (i * n) / 8, (j * n) / 8);
                if let Some((u, v)) = crate::cube::dir_to_uv_on(face, d) {
                    if u.abs() <= PLANE_LIMIT && v.abs() <= PLANE_LIMIT {
                        let gx = ((u + 1.0) / 2.0 * s).floor() as i64;
                        let gy = ((1.0 - v) / 2.0 * s).floor() as i64;
                        grow(gx - n / 8 - 2, gy - n / 8 - 2);
                        grow(gx + n / 8 + 2, gy + n / 8 + 2);
                    }
                }
            }
        }
    }
    (bx.0 <= bx.2).then_some(bx)
}

/// The context raster of tile `id` with `margin` pixels around it (clipped to the level's
/// coverage and to the face plane's usable part), and the tile's interior within it.
pub fn context_for(
    src: &Store,
    id: TileId,
    margin: u64,
    cover: Option<(i64, i64, i64, i64)>,
) -> Result<(Context, Rect)> {
    let n = src.manifest().layout.tile_size as i64;
    let (tx, ty) = (id.x as i64 * n, id.y as i64 * n);
    let win = window(
        src,
        id.level,
        id.face,
        (tx, ty, tx + n, ty + n),
        margin as i64,
        cover,
    );
    let ctx = context_window(src, id.level, id.face, win)?;
    let rect = Rect {
        x0: (tx - win.0) as usize,
        y0: (ty - win.1) as usize,
        w: n as usize,
        h: n as usize,
    };
    Ok((ctx, rect))
}

/// The context `penumbra report` measures tile `id`'s horizons over: the heights within the
/// tile's reach (as the horizon stage computes it from the tileset's terrain range), at most
/// the fast and sweep methods' default full-resolution margin around the tile, and the tile's
/// interior within it. Every method the report compares sees this same raster (the far rings
/// beyond it, which the fast and sweep methods share in a bake, are left out). Errors: the
/// tile's heights cannot be read, or the tileset records no height range.
pub fn report_context(store: &Store, id: TileId) -> Result<(Context, Rect)> {
    let ts = store.manifest();
    let lay = ts.layout;
    let range = terrain_range(ts)
        .ok_or_else(|| Error::invalid(store.manifest_path(), "tileset records no height range"))?;
    let tile = store.height(id)?.ok_or_else(|| {
        Error::invalid(
            store.manifest_path(),
            format!("tile {id} is listed but absent"),
        )
    })?;
    let top =
        interior_max(&tile, lay.halo as usize, lay.tile_size as usize).unwrap_or(range.1 as f32);
    let rad = reach_rad(ts.body.radius_m, range.0, range.1, top as f64);
    let opts = HorizonOptions::default();
    let reach = margin_for(ts, id, rad, opts.max_margin_px);
    let margin = reach.margin_px.min(default_fine_margin_px(lay.tile_size));
    let cover = coverage_box(ts, id.level, id.face);
    context_for(store, id, margin, cover)
}

/// One far ring ([`FarRing`]) of a tile, planned but not read: level `level`'s heights in the
/// global window `win` around the tile's footprint `foot` (pixels of that level), with what the
/// previous (finer) window `prev` holds blanked out; `factor` pixels of the tile's level per
/// ring pixel.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RingSpec {
    level: u8,
    face: Face,
    foot: (i64, i64, i64, i64),
    win: (i64, i64, i64, i64),
    prev: (i64, i64, i64, i64),
    factor: u32,
}

impl RingSpec {
    /// The ring's heights read; None when no terrain is left in it.
    pub(crate) fn build(&self, src: &Store) -> Result<Option<FarRing>> {
        let ctx = context_window(src, self.level, self.face, self.win)?;
        Ok(FarRing::new(ctx, self.foot, self.prev, self.factor))
    }
}

/// The far rings of tile `id` beyond a full-resolution context over the global window `fine`
/// (pixels of `id.level`; `fine_margin` around the tile before clipping), out to `needed_px`
/// pixels of that level: ring k holds level L−k's heights `ring_px` ring pixels around the
/// tile's footprint (at level 0, whatever reach is left), with what the previous window holds
/// blanked out. Nothing is read: each ring is read when it is built ([`RingSpec::build`]), so
/// that a caller holds one at a time. `covers` caches each level's coverage box.
pub(crate) fn far_rings(
    src: &Store,
    id: TileId,
    fine: (i64, i64, i64, i64),
    fine_margin: u64,
    needed_px: u64,
    ring_px: u64,
    covers: &mut Covers,
) -> Vec<RingSpec> {
    let ts = src.manifest();
    let mut rings = Vec::new();
    let mut prev = fine;
    for r in ring_steps(id, ts.layout.tile_size, fine_margin, needed_px, ring_px) {
        let cover = *covers
            .entry((r.level, id.face))
            .or_insert_with(|| coverage_box(ts, r.level, id.face));
        let win = window(src, r.level, id.face, r.foot, r.margin, cover);
        rings.push(RingSpec {
            level: r.level,
            face: id.face,
            foot: r.foot,
            win,
            prev,
            factor: r.factor,
        });
        prev = win;
    }
    rings
}

/// One far ring of a tile before its window is clipped to the level's coverage.
pub(crate) struct RingStep {
    pub level: u8,
    /// Pixels of the tile's level per pixel of the ring's.
    pub factor: u32,
    /// The tile's footprint in global pixels of the ring's level.
    pub foot: PxBox,
    /// Ring pixels around the footprint.
    pub margin: i64,
}

/// The far rings of tile `id` (`tile_size` pixels a side) beyond its `fine_margin` pixels out
/// to `needed_px` (pixels of its level), `ring_px` ring pixels each (level 0 takes whatever
/// reach is left): what [`far_rings`] builds and the plan's cost model counts.
pub(crate) fn ring_steps(
    id: TileId,
    tile_size: u32,
    fine_margin: u64,
    needed_px: u64,
    ring_px: u64,
) -> Vec<RingStep> {
    let n = i64::from(tile_size);
    let (tx, ty) = (id.x as i64 * n, id.y as i64 * n);
    let mut steps = Vec::new();
    // Reach of the windows so far (before clipping), in pixels of the tile's level.
    let mut reach = fine_margin;
    let mut k = 0u32;
    while reach < needed_px && k < u32::from(id.level) {
        k += 1;
        let level = id.level - k as u8;
        let f = 1i64 << k;
        let foot = (
            tx.div_euclid(f),
            ty.div_euclid(f),
            (tx + n + f - 1).div_euclid(f),
            (ty + n + f - 1).div_euclid(f),
        );
        let rest = needed_px.div_ceil(f as u64);
        let margin = if level == 0 { rest } else { rest.min(ring_px) } as i64;
        reach = reach.max((margin * f) as u64);
        steps.push(RingStep {
            level,
            factor: 1 << k,
            foot,
            margin,
        });
    }
    steps
}

/// The rasters tile `id`'s horizons are computed over with `method`: the context `reach`
/// asks for at full resolution, except that the fast and sweep methods take at most `fine_margin_px`
/// there and see the rest of the reach through far rings (planned, not yet read).
pub(crate) fn tile_rasters(
    src: &Store,
    id: TileId,
    reach: Reach,
    method: Method,
    fine_margin_px: u64,
    covers: &mut Covers,
) -> Result<(Context, Rect, Vec<RingSpec>)> {
    let ts = src.manifest();
    let cover = *covers
        .entry((id.level, id.face))
        .or_insert_with(|| coverage_box(ts, id.level, id.face));
    let fine = if method.sees_far_rings() {
        reach.margin_px.min(fine_margin_px)
    } else {
        reach.margin_px
    };
    let (ctx, rect) = context_for(src, id, fine, cover)?;
    let rings = if method.sees_far_rings() && fine < reach.needed_px {
        let o = ctx.origin;
        let win = (o.0, o.1, o.0 + ctx.width as i64, o.1 + ctx.height as i64);
        far_rings(src, id, win, fine, reach.needed_px, fine_margin_px, covers)
    } else {
        Vec::new()
    };
    Ok((ctx, rect, rings))
}

/// The upper bound (degrees, [`bound::tile_bound_deg`]) of tile `id`'s horizons as a run with
/// `opts` (its method and margins; `fine_margin` in effect) over the terrain `range` computes
/// them: the tile's own level beyond its near field, and, for the fast and sweep methods, the
/// far rings' coarser levels beyond the finer rasters, planned as [`tile_rasters`] plans them.
/// `stop`: see [`bound::tile_bound_deg`]. NaN for a tile without data.
#[allow(clippy::too_many_arguments)]
pub(crate) fn tile_bound(
    store: &Store,
    id: TileId,
    opts: &HorizonOptions,
    fine_margin: u64,
    range: (f64, f64),
    covers: &mut Covers,
    mips: &mut MipCache,
    stop: Option<f64>,
) -> Result<f32> {
    let ts = store.manifest();
    let lay = ts.layout;
    let n = lay.tile_size as i64;
    let tile = store.height(id)?.expect("listed tiles exist");
    let Some(top) = interior_max(&tile, lay.halo as usize, n as usize) else {
        return Ok(f32::NAN);
    };
    let rad = reach_rad(ts.body.radius_m, range.0, range.1, top as f64);
    let reach = margin_for(ts, id, rad, opts.max_margin_px);
    let cover = *covers
        .entry((id.level, id.face))
        .or_insert_with(|| coverage_box(ts, id.level, id.face));
    let (near, rect) = context_for(store, id, (NEAR_PX + 2) as u64, cover)?;
    let mut far = Vec::new();
    let fine = reach.margin_px.min(fine_margin);
    if opts.method.sees_far_rings() && fine < reach.needed_px {
        let (tx, ty) = (id.x as i64 * n, id.y as i64 * n);
        let win = window(
            store,
            id.level,
            id.face,
            (tx, ty, tx + n, ty + n),
            fine as i64,
            cover,
        );
        let s = lay.face_pixels(id.level) as f64;
        let tile_box = (tx as f64, ty as f64, (tx + n) as f64, (ty + n) as f64);
        for r in far_rings(store, id, win, fine, reach.needed_px, fine_margin, covers) {
            // A ring holds terrain only outside what the finer window before it holds (in
            // pixels of the level above the ring's), less the ring pixels that straddle its
            // border and the cell the ring's surface reaches from them (3 ring pixels).
            let sp = lay.face_pixels(r.level + 1) as f64;
            let p = r.prev;
            let gap = bound::gap_to_outside(
                id.face,
                s,
                tile_box,
                sp,
                (p.0 as f64, p.1 as f64, p.2 as f64, p.3 as f64),
            );
            let ring_px = 2.0 / lay.face_pixels(r.level) as f64;
            far.push(FarLevel {
                level: r.level,
                floor_rad: (gap - 3.0 * ring_px).max(0.0),
            });
        }
    }
    bound::tile_bound_deg(store, id, &near, rect, &far, range.0, mips, stop)
}

/// Whether a run with `opts` (its `lit_above_deg` set) leaves tile `id` out: its bound when it
/// is below the threshold. The stage's decision and [`prune_candidates`]'s.
#[allow(clippy::too_many_arguments)]
fn prune_decision(
    store: &Store,
    id: TileId,
    opts: &HorizonOptions,
    fine_margin: u64,
    range: (f64, f64),
    covers: &mut Covers,
    mips: &mut MipCache,
) -> Result<Option<f32>> {
    let Some(t) = opts.lit_above_deg else {
        return Ok(None);
    };
    let b = tile_bound(store, id, opts, fine_margin, range, covers, mips, Some(t))?;
    Ok(((b as f64) < t).then_some(b))
}

/// The tiles of `levels` that a horizon run given `lit_above_deg` (and otherwise the default
/// options) would leave out, with their bounds (degrees): the stage's own decision, for a
/// planner to count before horizons are baked. Needs the heights and the mipmaps.
pub fn prune_candidates(
    store: &Store,
    levels: &[u8],
    lit_above_deg: f64,
) -> Result<Vec<(TileId, f32)>> {
    prune_candidates_with(
        store,
        &HorizonOptions {
            levels: Some(levels.to_vec()),
            lit_above_deg: Some(lit_above_deg),
            ..Default::default()
        },
    )
}

/// [`prune_candidates`] for a run with `opts` (method, margins, levels, `lit_above_deg`).
pub fn prune_candidates_with(store: &Store, opts: &HorizonOptions) -> Result<Vec<(TileId, f32)>> {
    let Some(t) = opts.lit_above_deg else {
        return Err(Error::param(
            "lit_above_deg",
            "is needed: it is the threshold tiles are pruned below",
        ));
    };
    Ok(bounds_of(store, opts, Some(t))?
        .into_iter()
        .filter(|(_, b)| (*b as f64) < t)
        .collect())
}

/// Every tile of `opts`'s levels with the whole upper bound of its horizon (degrees, NaN for a
/// tile without data) for a run with `opts` (method, margins), not stopped at any threshold:
/// what [`prune_candidates`] compares with `lit_above_deg`. Needs the heights and the mipmaps.
pub fn tile_bounds(store: &Store, opts: &HorizonOptions) -> Result<Vec<(TileId, f32)>> {
    bounds_of(store, opts, None)
}

/// The bound of every tile of `opts`'s levels, each bounding stopped once it reaches `stop`
/// (as the stage's [`prune_decision`] does).
fn bounds_of(
    store: &Store,
    opts: &HorizonOptions,
    stop: Option<f64>,
) -> Result<Vec<(TileId, f32)>> {
    check_options(opts)?;
    let ts = store.manifest();
    check_layout(store.dir(), ts)?;
    check_prunable(store.dir(), ts)?;
    let range = run_range(ts, opts, &store.dir().join(manifest::MANIFEST))?;
    let levels = pick_levels(ts, &opts.levels)?;
    let fine = opts
        .fine_margin_px
        .unwrap_or_else(|| default_fine_margin_px(ts.layout.tile_size));
    let (mut covers, mut mips) = (HashMap::new(), MipCache::default());
    ts.tile_set()
        .into_iter()
        .filter(|t| levels.contains(&t.level))
        .map(|id| {
            let b = tile_bound(store, id, opts, fine, range, &mut covers, &mut mips, stop)?;
            Ok((id, b))
        })
        .collect()
}

/// Pruning bounds tiles from the mipmaps: refuse a tileset without them.
fn check_prunable(dir: &Path, ts: &Tileset) -> Result<()> {
    if ts.products.mip.is_none() {
        return Err(Error::invalid(
            dir.join(manifest::MANIFEST),
            "leaving out tiles whose horizon never reaches the sun (lit_above_deg) bounds them \
             from the maximum mipmaps, and this tileset has none: run `penumbra mip` first",
        ));
    }
    Ok(())
}

/// The horizons of `rect` over `ctx` with `method` (as [`horizons_with`]), raised to what
/// the far rings `rings` (from [`tile_rasters`]) add: each ring is read, used and dropped
/// before the next ([`FarHorizons`]). The nearest rings' tiles stay cached for the next tile,
/// which reads nearly the same ones; the farther rings' tiles are dropped once read, so that
/// the cache does not grow with the level count.
#[allow(clippy::too_many_arguments)]
pub(crate) fn horizons_seeing_rings(
    src: &Store,
    ctx: &Context,
    rect: Rect,
    rings: &[RingSpec],
    azimuths: usize,
    method: Method,
    near_px: f64,
    budget: Option<TileId>,
    device: Option<&dyn SweepDevice>,
) -> Result<(Vec<f32>, Option<Tally>)> {
    // The sweep's error budget is its error on the full-resolution context, before the rings
    // (which add the same far terrain to any method) raise it.
    let tally = |elev: &[f32]| budget.map(|id| Tally::measure(ctx, rect, id, azimuths, elev));
    // The sweep on a device: the context's own horizons there, the rings on the CPU.
    let on_device = match device {
        Some(d) if method == Method::Sweep => Some(horizons_sweep_on(d, ctx, rect, azimuths)?),
        _ => None,
    };
    if rings.is_empty() {
        let elev = match on_device {
            Some(elev) => elev,
            None => horizons_with(ctx, rect, azimuths, method, near_px),
        };
        let t = tally(&elev);
        return Ok((elev, t));
    }
    let mut far = match on_device {
        Some(own) => FarHorizons::from_own(ctx, rect, azimuths, own),
        None => FarHorizons::new(ctx, rect, azimuths, near_px, method),
    };
    let t = tally(far.current());
    for (k, spec) in rings.iter().enumerate() {
        let read = src.cache().now();
        let ring = spec.build(src)?;
        if k >= CACHED_RINGS {
            src.cache().drop_since(read);
        }
        if let Some(ring) = ring {
            far.add_ring(&ring);
        }
    }
    Ok((far.finish(), t))
}

/// The window (global pixels of `level`, half-open) `margin` pixels around the footprint
/// `foot`, clipped to the coverage box `cover` (never into the footprint) and to |u|, |v| ≤
/// [`PLANE_LIMIT`].
fn window(
    src: &Store,
    level: u8,
    face: Face,
    foot: (i64, i64, i64, i64),
    margin: i64,
    cover: Option<(i64, i64, i64, i64)>,
) -> (i64, i64, i64, i64) {
    let w = window_on(&src.manifest().layout, level, foot, margin, cover);
    // The window depends on the level's coverage (the cover): a unit reading it is redone
    // when its window would differ ([`HorizonStage`]'s `revalue`).
    if cover.is_some() && src.deps().active() {
        src.deps().note(crate::tileset::deps::Dep::Value {
            name: format!(
                "window {level} {} {} {} {} {} {margin}",
                face.name(),
                foot.0,
                foot.1,
                foot.2,
                foot.3
            ),
            value: format!("{} {} {} {}", w.0, w.1, w.2, w.3),
        });
    }
    w
}

/// [`window`] itself on `lay`, not recorded.
pub(crate) fn window_on(
    lay: &crate::layout::Layout,
    level: u8,
    foot: PxBox,
    margin: i64,
    cover: Option<PxBox>,
) -> PxBox {
    let s = lay.face_pixels(level) as i64;
    let (fx0, fy0, fx1, fy1) = foot;
    let (mut x0, mut y0, mut x1, mut y1) = (fx0 - margin, fy0 - margin, fx1 + margin, fy1 + margin);
    if let Some((bx0, by0, bx1, by1)) = cover {
        x0 = x0.max(bx0.min(fx0));
        y0 = y0.max(by0.min(fy0));
        x1 = x1.min(bx1.max(fx1));
        y1 = y1.min(by1.max(fy1));
    }
    let lim = ((PLANE_LIMIT - 1.0) / 2.0 * s as f64) as i64;
    (x0.max(-lim), y0.max(-lim), x1.min(s + lim), y1.min(s + lim))
}

/// The heights of `level` on `face`'s extended plane over the global pixel window `win`: the
/// face's own tiles inside the face, the neighbouring faces' resampled beyond its edges.
fn context_window(
    src: &Store,
    level: u8,
    face: Face,
    win: (i64, i64, i64, i64),
) -> Result<Context> {
    let ts = src.manifest();
    let lay = ts.layout;
    let s = lay.face_pixels(level) as i64;
    let n = lay.tile_size as i64;
    let halo = lay.halo as f64;
    let (x0, y0, x1, y1) = win;
    let id = TileId {
        level,
        face,
        x: 0,
        y: 0,
    };
    let (w, h) = ((x1 - x0) as usize, (y1 - y0) as usize);
    let mut ctx = Context {
        face: id.face,
        face_pixels: s as f64,
        origin: (x0, y0),
        width: w,
        height: h,
        heights: vec![f32::NAN; w * h],
        radius_m: ts.body.radius_m,
    };
    let per = lay.tiles_per_side(id.level) as i64;
    let tile_at = |face: Face, x: i64, y: i64| TileId {
        level: id.level,
        face,
        x: x as u32,
        y: y as u32,
    };
    let rows: Vec<Result<()>> = {
        let mut heights = std::mem::take(&mut ctx.heights);
        let c = &ctx;
        let r = heights
            .par_chunks_mut(w)
            .enumerate()
            .map(|(r, row)| -> Result<()> {
                let gy = y0 + r as i64;
                let mut last: Option<(TileId, Option<Arc<HeightTile>>)> = None;
                let mut get = |t: TileId| -> Result<Option<Arc<HeightTile>>> {
                    if let Some((lt, a)) = &last {
                        if *lt == t {
                            return Ok(a.clone());
                        }
                    }
                    let a = src.height(t)?;
                    last = Some((t, a.clone()));
                    Ok(a)
                };
                let mut xi = 0usize;
                while xi < w {
                    let gx = x0 + xi as i64;
                    if (0..s).contains(&gx) && (0..s).contains(&gy) {
                        // The run of this row inside one tile, copied at once.
                        let t = tile_at(id.face, (gx / n).min(per - 1), (gy / n).min(per - 1));
                        let len = ((t.x as i64 + 1) * n).min(s).min(x1) - gx;
                        let len = len.max(1) as usize;
                        if let Some(tile) = get(t)? {
                            let (i, j) = (
                                (gx - t.x as i64 * n) as usize + lay.halo as usize,
                                (gy - t.y as i64 * n) as usize + lay.halo as usize,
                            );
                            let from = j * tile.size + i;
                            row[xi..xi + len].copy_from_slice(&tile.height[from..from + len]);
                        }
                        xi += len;
                    } else {
                        let d = c.dir(xi as f64, r as f64);
                        let loc = lay.locate(id.level, d);
                        if let Some(tile) = get(loc.tile)? {
                            row[xi] = tile.bilinear(loc.px + halo, loc.py + halo);
                        }
                        xi += 1;
                    }
                }
                Ok(())
            })
            .collect();
        ctx.heights = heights;
        r
    };
    for r in rows {
        r?;
    }
    Ok(ctx)
}

// ---------------------------------------------------------------------------------------------
// Stage

pub(crate) fn check_layout(dir: &Path, ts: &Tileset) -> Result<()> {
    if ts.layout.projection != Projection::Gnomonic {
        return Err(Error::unsupported(
            dir.join(manifest::MANIFEST),
            format!(
                "horizons need a gnomonic tileset (straight lines on a face are then great \
                 circles); this one is {}: retile with the gnomonic projection",
                ts.layout.projection.name()
            ),
        ));
    }
    Ok(())
}

pub(crate) fn check_options(opts: &HorizonOptions) -> Result<()> {
    runner::check_output_cap("max_output_gib", opts.max_output_gib)?;
    let a = opts.azimuths;
    if !(4..=4096).contains(&a) {
        return Err(Error::param("azimuths", format!("{a} is outside 4..=4096")));
    }
    if let Some(m) = opts.fine_margin_px.filter(|m| !FINE_MARGIN_PX.contains(m)) {
        return Err(Error::param(
            "fine_margin_px",
            format!(
                "{} is outside {}..={}",
                m,
                FINE_MARGIN_PX.start(),
                FINE_MARGIN_PX.end()
            ),
        ));
    }
    if let Some(t) = opts.lit_above_deg {
        if !(t.is_finite() && (-90.0..=90.0).contains(&t)) {
            return Err(Error::param(
                "lit_above_deg",
                format!("{t} is not an elevation in −90..=90 degrees"),
            ));
        }
    }
    if !(0.0..=MAX_NEAR_PX).contains(&opts.near_px) {
        return Err(Error::param(
            "near_px",
            format!("{} is outside 0..={MAX_NEAR_PX}", opts.near_px),
        ));
    }
    Ok(())
}

/// The horizon stage writing raw maps only.
pub const STAGE: StageSpec = StageSpec {
    name: "horizon",
    writes: Cow::Borrowed(&[Product::Horizon]),
    reads: Cow::Borrowed(&[Product::Height, Product::Mip]),
    format: Cow::Borrowed(&[FORMAT, ALGORITHM]),
};

/// The levels a run computes, checked against the tileset.
fn pick_levels(ts: &Tileset, asked: &Option<Vec<u8>>) -> Result<Vec<u8>> {
    let lay = ts.layout;
    Ok(match asked {
        None => (0..lay.levels).collect(),
        Some(l) => {
            let mut l = l.clone();
            l.sort_unstable();
            l.dedup();
            if let Some(&bad) = l.iter().find(|&&x| x >= lay.levels) {
                return Err(Error::usage(format!(
                    "level {bad} does not exist: this tileset has levels 0..={}",
                    lay.levels - 1
                )));
            }
            l
        }
    })
}

/// Refuse a run whose raw maps would exceed `opts.max_output_gib` before compression.
fn check_output_size(opts: &HorizonOptions, levels: &[u8], tiles: usize, n: usize) -> Result<()> {
    let bytes_per = match opts.precision {
        HorizonPrecision::F16 => 2.0,
        HorizonPrecision::F32 => 4.0,
    };
    let gib = tiles as f64 * (n * n * opts.azimuths) as f64 * bytes_per / (1u64 << 30) as f64;
    if gib > opts.max_output_gib {
        return Err(Error::param(
            "max_output_gib",
            format!(
                "is {}, but horizons for levels {levels:?} would write {gib:.3} GiB before \
                 compression ({tiles} tiles × {n}² pixels × {} azimuths × {bytes_per} bytes): \
                 choose fewer levels, fewer azimuths, or raise the cap",
                opts.max_output_gib, opts.azimuths
            ),
        ));
    }
    Ok(())
}

/// Compute and store the raw horizon maps of the levels asked (no sink: `horizon` without
/// `--fourier`; [`crate::graph`] composes the stage with the Fourier encoder).
pub fn build_horizons(
    dir: &Path,
    opts: &HorizonOptions,
    progress: &dyn Progress,
) -> Result<HorizonReport> {
    let stage = HorizonStage {
        opts: opts.clone(),
        raw: true,
        sinks: Vec::new(),
    };
    runner::execute(&stage, dir, &Select::All, progress)?.into_report("horizon")
}

/// The horizon stage as units, one per tile of the levels asked (in tile order, each using
/// every thread): each tile's maps are written as raw maps (`raw`) and/or handed to the
/// `sinks` the graph composed.
pub struct HorizonStage<'a> {
    pub opts: HorizonOptions,
    /// Write the raw maps.
    pub raw: bool,
    pub sinks: Vec<&'a dyn HorizonSink>,
}

/// What a horizon run knows once the tileset is checked.
pub struct HorizonPlan {
    levels: Vec<u8>,
    tiles: Vec<TileId>,
    /// The terrain range bounding the search distance.
    range: (f64, f64),
    fine_margin: u64,
    sinks: Vec<Box<dyn SinkRun>>,
    /// Coverage boxes and face pyramids for recomputing recorded values (`revalue`).
    covers: std::sync::Mutex<Covers>,
    mips: std::sync::Mutex<MipCache>,
}

/// What one tile's unit did (floats as bits: the record round-trips exactly).
#[derive(Serialize, Deserialize)]
pub struct TileDone {
    /// How far the tile's context reached (None: the tile is all no data).
    reach: Option<ReachDone>,
    /// Each sink's record, in the order of the stage's sinks.
    sinks: Vec<serde_json::Value>,
    pixel_azimuths: u64,
    horizon_s: f64,
    sink_s: f64,
    /// The sweep method's differences against the reference on the tile's checked pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    budget: Option<Tally>,
    /// Left out (`lit_above_deg`): the bound of its horizon, f32 bits.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pruned: Option<u32>,
    /// Seconds spent bounding the tile.
    #[serde(default, skip_serializing_if = "is_zero")]
    bound_s: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

#[derive(Serialize, Deserialize)]
struct ReachDone {
    /// The reach (radians) as bits.
    rad: u64,
    /// The margin searched at full resolution, px.
    margin_px: u64,
    far_rings: bool,
    capped: bool,
}

/// What one worker keeps from tile to tile.
pub struct HorizonScratch {
    covers: Covers,
    /// Maximum mipmaps read for bounds (`lit_above_deg`).
    mips: MipCache,
    /// The tile cache's clock at the previous tile.
    mark: u64,
}

impl HorizonStage<'_> {
    /// What the run key hashes besides the height tiles' run key: the height pattern, the
    /// options as JSON (the sinks' options appended as fields of the same object, and
    /// `keep_raw` when raw maps are written beside a sink), the terrain range bounding the
    /// search and the fine margin in effect (so that a changed default recomputes).
    fn basis(&self, ts: &Tileset, plan: &HorizonPlan) -> KeyBasis {
        let height_path = &ts.products.height.as_ref().expect("checked").path;
        let (tmin, tmax) = plan.range;
        let mut params = serde_json::to_string(&self.opts).unwrap_or_default();
        params.pop();
        for s in &self.sinks {
            for (name, json) in s.key_fields() {
                params.push_str(&format!(",\"{name}\":{json}"));
            }
        }
        if self.raw && !self.sinks.is_empty() {
            params.push_str(",\"keep_raw\":true");
        }
        params.push('}');
        runner::key_basis(
            &self.spec(),
            vec![
                height_path.clone(),
                params,
                format!("{tmin} {tmax}"),
                format!("fine margin {}", plan.fine_margin),
            ],
        )
    }

    /// The products written and the version strings: the sinks' first, then the raw maps.
    fn writes(&self) -> Vec<Product> {
        let mut w: Vec<Product> = self
            .sinks
            .iter()
            .flat_map(|s| s.products().iter().copied())
            .collect();
        if self.raw {
            w.push(Product::Horizon);
        }
        w
    }
}

impl Stage for HorizonStage<'_> {
    type Plan = HorizonPlan;
    type Done = TileDone;
    type Scratch = HorizonScratch;
    type Report = HorizonReport;

    fn spec(&self) -> StageSpec {
        let mut format = vec![FORMAT, ALGORITHM];
        for s in &self.sinks {
            format.extend_from_slice(s.formats());
        }
        StageSpec {
            name: "horizon",
            writes: Cow::Owned(self.writes()),
            reads: Cow::Borrowed(&[Product::Height, Product::Mip]),
            format: Cow::Owned(format),
        }
    }

    fn check(&self) -> Result<()> {
        if !self.raw && self.sinks.is_empty() {
            return Err(Error::usage(
                "a horizon run that neither writes raw maps nor streams them anywhere makes \
                 nothing",
            ));
        }
        check_options(&self.opts)?;
        for s in &self.sinks {
            s.check(self.opts.azimuths)?;
        }
        Ok(())
    }

    fn plan(&self, dir: &Path, ts: &Tileset) -> Result<HorizonPlan> {
        let opts = &self.opts;
        let manifest_path = dir.join(manifest::MANIFEST);
        check_layout(dir, ts)?;
        if ts.products.height.is_none() {
            return Err(Error::invalid(
                &manifest_path,
                "tileset has no height product to compute horizons from",
            ));
        }
        let range = run_range(ts, opts, &manifest_path)?;
        if opts.lit_above_deg.is_some() {
            check_prunable(dir, ts)?;
        }
        let levels = pick_levels(ts, &opts.levels)?;
        let tiles: Vec<TileId> = ts
            .tile_set()
            .into_iter()
            .filter(|t| levels.contains(&t.level))
            .collect();
        let n = ts.layout.tile_size as usize;
        if self.raw {
            check_output_size(opts, &levels, tiles.len(), n)?;
        }
        let sinks = self
            .sinks
            .iter()
            .map(|s| s.prepare(ts, tiles.len(), opts.azimuths, range.0, opts.lit_above_deg))
            .collect::<Result<Vec<_>>>()?;
        Ok(HorizonPlan {
            levels,
            tiles,
            range,
            fine_margin: opts
                .fine_margin_px
                .unwrap_or_else(|| default_fine_margin_px(ts.layout.tile_size)),
            sinks,
            covers: Default::default(),
            mips: Default::default(),
        })
    }

    fn key(&self, ts: &Tileset, plan: &HorizonPlan) -> String {
        self.basis(ts, plan).key(&[&ts.run_key])
    }

    fn units(&self, ts: &Tileset, plan: &HorizonPlan) -> Result<Vec<Unit>> {
        let n = ts.layout.tile_size as u64;
        let margin = if self.opts.method.sees_far_rings() {
            plan.fine_margin.min(self.opts.max_margin_px)
        } else {
            self.opts.max_margin_px
        };
        Ok(plan
            .tiles
            .iter()
            .map(|&id| {
                let reads = vec![
                    Reads::Around {
                        product: Product::Height,
                        tile: id,
                        margin_px: margin,
                    },
                    Reads::Tile {
                        product: Product::Mip,
                        tile: id,
                    },
                ];
                Unit::tile(id, reads, (n * n * self.opts.azimuths as u64) as f64)
            })
            .collect())
    }

    fn order(&self) -> Order {
        // A tile's pixels are spread over the threads; the height tiles the previous tile
        // read stay cached for the next.
        Order::Sequential
    }

    fn scratch(&self, _plan: &HorizonPlan) -> HorizonScratch {
        HorizonScratch {
            covers: HashMap::new(),
            mips: MipCache::default(),
            mark: 0,
        }
    }

    fn run_unit(
        &self,
        cx: &Cx<HorizonPlan>,
        unit: &Unit,
        scratch: &mut HorizonScratch,
    ) -> Result<TileDone> {
        let (opts, store, plan) = (&self.opts, cx.store, cx.plan);
        let ts = store.manifest();
        let lay = ts.layout;
        let n = lay.tile_size as usize;
        let id = unit.tile;
        // The height tiles the previous tile read stay cached for this one, older ones go:
        // the cache holds about one tile's contexts, not the level.
        store.cache().keep_since(scratch.mark);
        scratch.mark = store.cache().now();
        let (tmin, tmax) = plan.range;
        let tile = store.height(id)?.expect("listed tiles exist");
        let top = interior_max(&tile, lay.halo as usize, n);
        let reach = top.map(|top| {
            let rad = reach_rad(ts.body.radius_m, tmin, tmax, top as f64);
            (rad, margin_for(ts, id, rad, opts.max_margin_px))
        });
        let tb = std::time::Instant::now();
        let pruned = if reach.is_some() {
            prune_decision(
                store,
                id,
                opts,
                plan.fine_margin,
                plan.range,
                &mut scratch.covers,
                &mut scratch.mips,
            )?
        } else {
            None
        };
        let bound_s = if opts.lit_above_deg.is_some() {
            tb.elapsed().as_secs_f64()
        } else {
            0.0
        };
        let t0 = std::time::Instant::now();
        let mut pixaz = 0;
        let mut budget = None;
        let elev = if pruned.is_some() {
            Vec::new()
        } else if let Some((_, reach)) = reach {
            let (ctx, rect, rings) = tile_rasters(
                store,
                id,
                reach,
                opts.method,
                plan.fine_margin,
                &mut scratch.covers,
            )?;
            pixaz = (n * n * opts.azimuths) as u64;
            let (elev, tally) = horizons_seeing_rings(
                store,
                &ctx,
                rect,
                &rings,
                opts.azimuths,
                opts.method,
                opts.near_px,
                (opts.method == Method::Sweep).then_some(id),
                opts.device.as_deref(),
            )?;
            budget = tally;
            elev
        } else {
            vec![f32::NAN; n * n * opts.azimuths]
        };
        let horizon_s = t0.elapsed().as_secs_f64();
        if self.raw && pruned.is_none() {
            write_horizon_exr(
                &tile_path(cx.out, id),
                n,
                opts.azimuths,
                &elev,
                opts.precision,
                opts.compression,
                Some(&Identity::tile(HORIZON_ID, id, cx.key)),
            )?;
        }
        let t1 = std::time::Instant::now();
        let sinks = plan
            .sinks
            .iter()
            .map(|s| {
                s.accept(
                    cx.out,
                    HorizonTile {
                        id,
                        run_key: cx.key,
                        planes: &elev,
                        height: &tile,
                        pruned,
                    },
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let reach = reach.map(|(rad, reach)| {
            let margin_px = if opts.method.sees_far_rings() {
                // Far rings see the rest of the reach.
                reach.margin_px.min(plan.fine_margin)
            } else {
                reach.margin_px
            };
            ReachDone {
                rad: rad.to_bits(),
                margin_px,
                far_rings: opts.method.sees_far_rings() && margin_px < reach.needed_px,
                capped: !opts.method.sees_far_rings() && reach.margin_px < reach.needed_px,
            }
        });
        Ok(TileDone {
            reach,
            sinks,
            pixel_azimuths: pixaz,
            horizon_s,
            sink_s: t1.elapsed().as_secs_f64(),
            budget,
            pruned: pruned.map(f32::to_bits),
            bound_s,
        })
    }

    fn finish(
        &self,
        cx: &Cx<HorizonPlan>,
        done: Vec<Finished<TileDone>>,
    ) -> Result<(Tileset, HorizonReport)> {
        let (opts, plan) = (&self.opts, cx.plan);
        let ts = cx.store.manifest();
        let (tmin, tmax) = plan.range;
        // The distances are recorded for every tile, kept ones too, so that a resumed run's
        // manifest is the uninterrupted run's.
        let mut dist: Vec<HorizonLevelDistance> = plan
            .levels
            .iter()
            .map(|&level| HorizonLevelDistance {
                level,
                needed_km: 0.0,
                max_margin_px: 0,
                tiles_capped: 0,
                tiles_with_far_rings: 0,
            })
            .collect();
        let mut report = self.up_to_date(cx.store, plan, &[]);
        report.up_to_date = false;
        report.tiles_kept = 0;
        report.tiles_pruned = 0;
        let mut records: Vec<Vec<(TileId, serde_json::Value, bool)>> =
            plan.sinks.iter().map(|_| Vec::new()).collect();
        let mut budget = Tally::default();
        let mut pruned = std::collections::BTreeMap::new();
        for f in done {
            let id = f.unit.tile;
            if let Some(b) = f.done.pruned {
                pruned.insert(crate::format::horizon::pruned_key(id), f32::from_bits(b));
                report.tiles_pruned += 1;
            }
            if let Some(b) = &f.done.budget {
                budget.add(b);
            }
            if let Some(r) = &f.done.reach {
                let d = dist.iter_mut().find(|d| d.level == id.level).unwrap();
                let rad = f64::from_bits(r.rad);
                d.needed_km = d.needed_km.max(rad * ts.body.radius_m / 1000.0);
                d.max_margin_px = d.max_margin_px.max(r.margin_px);
                d.tiles_with_far_rings += r.far_rings as u64;
                d.tiles_capped += r.capped as u64;
            }
            if f.here {
                report.tiles_written += 1;
                report.pixel_azimuths += f.done.pixel_azimuths;
                report.horizon_s += f.done.horizon_s;
                report.compress_s += f.done.sink_s;
                report.bound_s += f.done.bound_s;
            } else {
                report.tiles_kept += 1;
            }
            for (rec, v) in records.iter_mut().zip(f.done.sinks) {
                rec.push((id, v, f.here));
            }
        }
        let error = budget.error();
        let source = HorizonSource {
            levels: plan.levels.clone(),
            azimuths: opts.azimuths,
            method: opts.method.name().into(),
            near_px: (opts.method == Method::Fast).then_some(opts.near_px),
            error: error.clone(),
            terrain_min_m: tmin,
            terrain_max_m: tmax,
            distances: dist.clone(),
            basis: self.basis(ts, plan),
            lit_above_deg: opts.lit_above_deg,
        };
        let mut manifest = ts.clone();
        for ((sink, run), rec) in self.sinks.iter().zip(&plan.sinks).zip(records) {
            let summary = run.finish(&mut manifest, rec, &source, cx.key)?;
            report.streamed.insert(sink.name().to_string(), summary);
        }
        if self.raw {
            manifest.products.horizon = Some(HorizonProduct {
                path: PATTERN.into(),
                channel: "elevation".into(),
                precision: opts.precision.name().into(),
                azimuths: opts.azimuths,
                azimuth: AZIMUTH_CONVENTION.into(),
                layout: LAYOUT.into(),
                method: opts.method.name().into(),
                near_px: (opts.method == Method::Fast).then_some(opts.near_px),
                error,
                levels: plan.levels.clone(),
                terrain_min_m: tmin,
                terrain_max_m: tmax,
                distances: dist.clone(),
                pruned: opts.lit_above_deg.map(|t| HorizonPruned {
                    lit_above_deg: t,
                    tiles: pruned,
                }),
                run_key: cx.key.to_string(),
                run_key_basis: Some(source.basis.clone()),
            });
        }
        report.distances = dist;
        Ok((manifest, report))
    }

    /// A context window a unit recorded (`window L FACE x0 y0 x1 y1 MARGIN`), on the level's
    /// coverage as it is now.
    fn revalue(&self, store: &Store, plan: &HorizonPlan, name: &str) -> Option<String> {
        if name.starts_with("facetexel ") {
            let mut mips = plan.mips.lock().unwrap_or_else(|e| e.into_inner());
            return bound::face_texel_value(store, &mut mips, name);
        }
        let mut it = name.split(' ');
        if it.next()? != "window" {
            return None;
        }
        let level: u8 = it.next()?.parse().ok()?;
        let face = it.next()?;
        let face = *Face::ALL.iter().find(|f| f.name() == face)?;
        let mut num = || it.next()?.parse::<i64>().ok();
        let foot = (num()?, num()?, num()?, num()?);
        let margin = num()?;
        let cover = *plan
            .covers
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry((level, face))
            .or_insert_with(|| coverage_box(store.manifest(), level, face));
        cover?;
        let w = window_on(&store.manifest().layout, level, foot, margin, cover);
        Some(format!("{} {} {} {}", w.0, w.1, w.2, w.3))
    }

    fn up_to_date(&self, store: &Store, plan: &HorizonPlan, _units: &[Unit]) -> HorizonReport {
        let ts = store.manifest();
        let products = &ts.products;
        // The distances of the product the run's first write records.
        let distances = match (self.sinks.is_empty(), &products.fourier, &products.horizon) {
            (false, Some(f), _) => f.distances.clone(),
            (_, _, Some(h)) => h.distances.clone(),
            _ => Vec::new(),
        };
        let streamed = self
            .sinks
            .iter()
            .zip(&plan.sinks)
            .map(|(s, run)| (s.name().to_string(), run.up_to_date(ts)))
            .collect();
        HorizonReport {
            out: store.dir().to_path_buf(),
            levels: plan.levels.clone(),
            azimuths: self.opts.azimuths,
            method: self.opts.method,
            tiles: plan.tiles.len() as u64,
            tiles_written: 0,
            tiles_kept: plan.tiles.len() as u64,
            pixel_azimuths: 0,
            distances,
            up_to_date: true,
            raw: self.raw,
            streamed,
            horizon_s: 0.0,
            compress_s: 0.0,
            tiles_pruned: products
                .horizon
                .as_ref()
                .and_then(|h| h.pruned.as_ref())
                .map_or(0, |p| p.tiles.len() as u64),
            bound_s: 0.0,
        }
    }
}

/// Highest interior height of a stored tile (None when it is all no data).
pub(crate) fn interior_max(t: &HeightTile, halo: usize, n: usize) -> Option<f32> {
    let mut m = f32::NEG_INFINITY;
    for j in 0..n {
        for &v in &t.height[(j + halo) * t.size + halo..][..n] {
            if v > m {
                m = v;
            }
        }
    }
    m.is_finite().then_some(m)
}
