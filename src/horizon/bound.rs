//! A conservative upper bound of a tile's horizon elevation, over every pixel the horizon maps
//! store and every azimuth, from the heights around the tile and the maximum mipmaps of the
//! whole body — without computing a horizon (docs/horizons.md, "Tiles a scene's sun never
//! needs"). A tile whose bound is below a scene's lowest sun (less its radius) is fully lit for
//! every sun of the scene, and the horizon stage leaves it out (`HorizonOptions::lit_above_deg`).
//!
//! The bound is the largest of three, each exact on the sphere and an upper bound by
//! construction (a point of height H at central angle θ from an observer at height h is at
//! elevation atan2((R+H)·cos θ − (R+h), (R+H)·sin θ), which rises with H, falls with h, and
//! over θ ≥ θ₀ is largest at θ₀ when H ≥ h, else at the tangent point acos((R+H)/(R+h))
//! clamped to θ ≥ θ₀ — [`max_elevation_beyond`]):
//!
//! - **Near field**, per pixel, within [`NEAR_PX`] plane pixels, in distance bands (0, 1],
//!   (1, 2], (2, 4], …: the lesser of (a) the highest sample within the band's reach (every
//!   point a method evaluates is a convex combination of its cell's data corners) at the band's
//!   least distance, and (b) a slope bound: along a ray through complete cells the bilinear
//!   surface rises at most by the largest gradient of the cells it crosses (a bilinear cell's
//!   gradient is affine, so its norm is largest at a corner), over the least ground distance
//!   the gnomonic plane allows there (an angle per plane unit of at least 1/(1 + u² + v²)). A
//!   cell with a no-data corner near a pixel voids (b): only (a) bounds it, so a pixel next to
//!   a data edge below a higher neighbour bounds at 90°.
//! - **Far field**, per block of [`BLOCK_PX`]² observers at their lowest height, for all
//!   terrain at least [`NEAR_PX`] plane pixels away: a best-first descent of the maximum
//!   mipmaps, from each face pyramid's top through the face pyramids into the tiles' own
//!   pyramids, each texel a spherical cap around its footprint (widened by the cells that
//!   resampling across face edges reaches), with the least central angle between the block
//!   and the cap. Texels whose bound cannot raise the tile's are never opened, and texels
//!   small against their distance are not refined further. For the fast and sweep methods'
//!   far rings the coarser levels' pyramids are descended too, beyond what the finer rasters
//!   hold (their surface is not the tile level's).
//! - The **floor** every reader puts under the horizon (the tangent to the sphere of the
//!   lowest terrain) at the tile's lowest observer.
//!
//! [`MARGIN_DEG`] is added for what the methods and the stored precision may add above the
//! exact surface (the sweep method's placement of points, f16 rounding).

use std::collections::{BinaryHeap, HashMap};
use std::f64::consts::{FRAC_PI_2, PI, SQRT_2};
use std::sync::Arc;

use super::geometry::{Context, Rect};
use crate::cube::{self, Face, Vec3};
use crate::error::{Error, Result};
use crate::layout::TileId;
use crate::tileset::{self, Store};

/// Added to every bound (degrees): the sweep method may place a point up to 0.03° above the
/// exact surface on 14-km cells (docs/horizons.md), f16 maps round up to half a step (0.031°
/// above 64°), the fast method's f32 kernels 1e-4°.
pub const MARGIN_DEG: f64 = 0.1;
/// Radius of the per-pixel near field (plane pixels of the tile's level; a power of two).
pub const NEAR_PX: usize = 16;
/// Side of the far field's observer blocks (pixels).
pub const BLOCK_PX: usize = 8;
/// A texel is not refined once its angular radius is at most this share of its least distance.
const REFINE: f64 = 0.125;
/// Bytes of mipmaps a [`MipCache`] keeps before it starts again.
const CACHE_BYTES: usize = 256 << 20;

/// Elevation (radians) above the local horizontal of an observer at height `h` of a point at
/// height `hh` and central angle `theta`, on a sphere of `radius` (exact).
#[inline]
pub fn elevation_rad(radius: f64, h: f64, hh: f64, theta: f64) -> f64 {
    let (r, r0) = (radius + hh, radius + h);
    (r * theta.cos() - r0).atan2(r * theta.sin())
}

/// The highest elevation (radians) of any point no higher than `hh` at a central angle of at
/// least `theta_lo` from an observer no lower than `h`: at `theta_lo` when `hh ≥ h` (the
/// elevation falls with distance), else at the tangent point acos((R+hh)/(R+h)) clamped to at
/// least `theta_lo` (it rises to there and falls after).
#[inline]
pub fn max_elevation_beyond(radius: f64, h: f64, hh: f64, theta_lo: f64) -> f64 {
    if hh == f64::NEG_INFINITY {
        return -FRAC_PI_2;
    }
    let theta = if hh >= h {
        theta_lo
    } else {
        theta_lo.max(((radius + hh) / (radius + h)).clamp(-1.0, 1.0).acos())
    };
    elevation_rad(radius, h, hh, theta.clamp(0.0, PI))
}

fn angle(a: Vec3, b: Vec3) -> f64 {
    cube::angle_between(a, b)
}

/// Direction of the point at edge coordinates (x, y) (pixel i spans [i, i+1]) of a face whose
/// side is `s` pixels, on its extended plane.
fn edge_dir(face: Face, s: f64, x: f64, y: f64) -> Vec3 {
    cube::face_uv_to_dir(face, -1.0 + 2.0 * x / s, 1.0 - 2.0 * y / s)
}

/// A cap around the box [x0, x1] × [y0, y1] (edge coordinates of a face of side `s`): its
/// centre and the largest angle from it to a corner (a spherical quadrilateral is farthest from
/// a point at a vertex).
fn cap(face: Face, s: f64, x0: f64, y0: f64, x1: f64, y1: f64) -> (Vec3, f64) {
    let c = edge_dir(face, s, 0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let rho = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
        .iter()
        .map(|&(x, y)| angle(c, edge_dir(face, s, x, y)))
        .fold(0.0, f64::max);
    (c, rho)
}

/// Max over a square window of half-width `r` (separable), `pad` outside the image.
fn box_max(img: &[f64], w: usize, h: usize, r: usize, pad: f64) -> Vec<f64> {
    let mut tmp = vec![pad; w * h];
    for y in 0..h {
        let row = &img[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b) = (x as i64 - r as i64, x + r);
            let mut m = if a < 0 || b >= w {
                pad
            } else {
                f64::NEG_INFINITY
            };
            for v in &row[a.max(0) as usize..=b.min(w - 1)] {
                m = m.max(*v);
            }
            tmp[y * w + x] = m;
        }
    }
    let mut out = vec![pad; w * h];
    for y in 0..h {
        let (a, b) = (y as i64 - r as i64, y + r);
        for x in 0..w {
            let mut m = if a < 0 || b >= h {
                pad
            } else {
                f64::NEG_INFINITY
            };
            for yy in a.max(0) as usize..=b.min(h - 1) {
                m = m.max(tmp[yy * w + x]);
            }
            out[y * w + x] = m;
        }
    }
    out
}

/// The near field's bound (radians) over the observers of `rect` in `ctx` (see the module's
/// header) for terrain within `near_px` plane pixels (a power of two), on a body whose lowest
/// terrain is `tmin`, and the least central angle per plane pixel around the observers; None
/// when no observer holds data. `ctx` should reach `near_px + 2` pixels around `rect` (what it
/// does not hold counts as no data).
pub fn near_bound(ctx: &Context, rect: Rect, tmin: f64, near_px: usize) -> Option<(f64, f64)> {
    let (w, h) = (ctx.width, ctx.height);
    let radius = ctx.radius_m;
    let hm: Vec<f64> = ctx
        .heights
        .iter()
        .map(|&v| {
            if v.is_nan() {
                f64::NEG_INFINITY
            } else {
                v as f64
            }
        })
        .collect();
    // Largest gradient norm (m per plane pixel) over each cell; +∞ for cells with a corner
    // without data or outside the raster.
    let mut gc = vec![f64::INFINITY; w * h];
    for y in 0..h.saturating_sub(1) {
        for x in 0..w - 1 {
            let (h00, h10) = (ctx.at(x as i64, y as i64), ctx.at(x as i64 + 1, y as i64));
            let (h01, h11) = (
                ctx.at(x as i64, y as i64 + 1),
                ctx.at(x as i64 + 1, y as i64 + 1),
            );
            if [h00, h10, h01, h11].iter().any(|v| v.is_nan()) {
                continue;
            }
            let (h00, h10, h01, h11) = (h00 as f64, h10 as f64, h01 as f64, h11 as f64);
            let gx = (h10 - h00).abs().max((h11 - h01).abs());
            let gy = (h01 - h00).abs().max((h11 - h10).abs());
            gc[y * w + x] = (gx * gx + gy * gy).sqrt();
        }
    }
    // The least angle per plane pixel within `m` pixels of (x, y): 1/(1 + u² + v²) plane units
    // per radian at the box's farthest corner from the face centre (the gnomonic plane's
    // radial scale, its least).
    let per_px = 2.0 / ctx.face_pixels;
    let least = |x: f64, y: f64, m: f64| -> f64 {
        let r2 = [
            (x - m, y - m),
            (x + m, y - m),
            (x - m, y + m),
            (x + m, y + m),
        ]
        .iter()
        .map(|&(x, y)| {
            let (u, v) = ctx.uv(x, y);
            u * u + v * v
        })
        .fold(0.0, f64::max);
        per_px / (1.0 + r2)
    };
    let theta_max = (near_px + 1) as f64 * per_px;
    // tan(elevation) ≤ rise / ((R + H)·sin θ) with rise ≤ G·d, θ ≥ c·d, sin θ ≥ θ(1 − θ²/6).
    let slope_per_gc = 1.0 / ((radius + tmin) * (1.0 - theta_max * theta_max / 6.0));
    let mut bands = Vec::new();
    let (mut inner, mut outer) = (0usize, 1usize);
    while outer <= near_px {
        let mx = box_max(&hm, w, h, outer + 1, f64::NEG_INFINITY);
        let gx = box_max(&gc, w, h, outer + 1, f64::INFINITY);
        bands.push((inner as f64, outer as f64 + 2.0, mx, gx));
        inner = outer;
        outer *= 2;
    }
    let c = least(
        rect.x0 as f64 + rect.w as f64 / 2.0,
        rect.y0 as f64 + rect.h as f64 / 2.0,
        (rect.w.max(rect.h) / 2 + near_px + 2) as f64,
    );
    let mut best: Option<f64> = None;
    for j in rect.y0..rect.y0 + rect.h {
        for i in rect.x0..rect.x0 + rect.w {
            let h0 = ctx.at(i as i64, j as i64);
            if h0.is_nan() {
                continue;
            }
            let h0 = h0 as f64;
            let k = j * w + i;
            let mut el = -FRAC_PI_2;
            for (inner, reach, mx, gx) in &bands {
                // The band's rays stay within `reach` pixels of the pixel.
                let cb = least(i as f64, j as f64, *reach);
                let a = max_elevation_beyond(radius, h0, mx[k], inner * cb);
                let b = (gx[k] * slope_per_gc / cb).atan();
                el = el.max(a.min(b));
            }
            best = Some(best.map_or(el, |b: f64| b.max(el)));
        }
    }
    best.map(|b| (b, c))
}

/// One level's terrain seen from a tile at least `floor_rad` away (central angle).
#[derive(Clone, Copy, Debug)]
pub struct FarLevel {
    pub level: u8,
    pub floor_rad: f64,
}

/// Maximum mipmaps read for bounds, kept from tile to tile (up to 256 MiB).
#[derive(Default)]
pub struct MipCache {
    tiles: HashMap<TileId, Arc<Levels>>,
    faces: HashMap<FaceKey, Option<Arc<Levels>>>,
    bytes: usize,
}

/// A face pyramid (tile level, face) or a chunk of one.
type FaceKey = (u8, Face, Option<(u32, u32)>);

/// A pyramid's `max` channel: level sizes (largest first) and texels.
struct Levels {
    sizes: Vec<usize>,
    max: Vec<Vec<f32>>,
}

impl Levels {
    fn of(f: crate::format::mip::MipFile, path: &std::path::Path) -> Result<Levels> {
        let max = f.channel(path, "max")?.clone();
        Ok(Levels {
            sizes: f.sizes,
            max,
        })
    }
    fn bytes(&self) -> usize {
        self.max.iter().map(|l| l.len() * 4).sum()
    }
    fn at(&self, k: usize, x: usize, y: usize) -> f32 {
        self.max[k][y * self.sizes[k] + x]
    }
}

impl MipCache {
    fn room(&mut self, more: usize) {
        if self.bytes + more > CACHE_BYTES {
            self.tiles.clear();
            self.faces.clear();
            self.bytes = 0;
        }
        self.bytes += more;
    }

    fn tile(&mut self, store: &Store, id: TileId) -> Result<Arc<Levels>> {
        if let Some(l) = self.tiles.get(&id) {
            // Read by an earlier unit: noted for this one as read.
            if store.deps().active() {
                if let Some(m) = store.manifest().products.mip.as_ref() {
                    store.note_file(
                        crate::tileset::Product::Mip,
                        &tileset::tile_path(store.dir(), &m.max_path, id),
                    );
                }
            }
            return Ok(l.clone());
        }
        let m = store.mip(id, true)?;
        let path = store.dir().join("maxmip");
        let l = Arc::new(Levels::of(m, &path)?);
        self.room(l.bytes());
        self.tiles.insert(id, l.clone());
        Ok(l)
    }

    /// The face pyramid of `face` at tile `level`, or chunk `chunk` of it; None: no file (no
    /// terrain there).
    fn face(
        &mut self,
        store: &Store,
        level: u8,
        face: Face,
        chunk: Option<(u32, u32)>,
    ) -> Result<Option<Arc<Levels>>> {
        if let Some(l) = self.faces.get(&(level, face, chunk)) {
            return Ok(l.clone());
        }
        let mp = store
            .manifest()
            .products
            .mip
            .as_ref()
            .ok_or_else(|| store.missing("tileset has no mipmaps: run the mip stage first"))?;
        let path = match (chunk, &mp.face_chunk_path) {
            (Some((cx, cy)), Some(p)) => {
                tileset::face_chunk_file_path(store.dir(), p, level, face, cx, cy)
            }
            _ => tileset::face_file_path(store.dir(), &mp.face_path, level, face),
        };
        // Not a dependency as a whole: each texel read is ([`MipCache::face_texel`]), so that
        // tiles added far away leave a unit's bound valid.
        let l = if path.exists() {
            let f = store
                .deps()
                .paused(|| store.face_mip(&path, level, face, chunk))?;
            let l = Arc::new(Levels::of(f, &path)?);
            self.room(l.bytes());
            Some(l)
        } else {
            None
        };
        self.faces.insert((level, face, chunk), l.clone());
        Ok(l)
    }

    /// Texel max of face-pyramid level `fl` at texel (x, y) (in units of 2^fl tiles) of tile
    /// level `level`, wherever it is stored (docs/mipmaps.md); NaN: no terrain. Recorded as a
    /// dependency of the unit running now ([`face_texel_value`] recomputes it).
    fn face_texel(
        &mut self,
        store: &Store,
        level: u8,
        face: Face,
        fl: u32,
        x: u32,
        y: u32,
    ) -> Result<f32> {
        let v = self.face_texel_in(store, level, face, fl, x, y)?;
        if store.deps().active() {
            store.deps().note(crate::tileset::deps::Dep::Value {
                name: format!("facetexel {level} {} {fl} {x} {y}", face.name()),
                value: v.to_bits().to_string(),
            });
        }
        Ok(v)
    }

    fn face_texel_in(
        &mut self,
        store: &Store,
        level: u8,
        face: Face,
        fl: u32,
        x: u32,
        y: u32,
    ) -> Result<f32> {
        let mp = store.manifest().products.mip.as_ref();
        let g = store.manifest().layout.tiles_per_side(level);
        let chunk_tiles = mp.and_then(|m| m.face_chunk_tiles);
        let (levels, k, tx, ty) = match (mp.and_then(|m| m.face_chunk_path.as_ref()), chunk_tiles) {
            (Some(_), Some(c)) if g > c => {
                let kc = c.trailing_zeros();
                if fl < kc {
                    let (tx, ty) = (x << fl, y << fl);
                    let ch = (tx / c, ty / c);
                    match self.face(store, level, face, Some(ch))? {
                        Some(l) => (l, fl, (tx % c) >> fl, (ty % c) >> fl),
                        None => return Ok(f32::NAN),
                    }
                } else {
                    match self.face(store, level, face, None)? {
                        Some(l) => (l, fl - kc, x, y),
                        None => return Ok(f32::NAN),
                    }
                }
            }
            _ => match self.face(store, level, face, None)? {
                Some(l) => (l, fl, x, y),
                None => return Ok(f32::NAN),
            },
        };
        let k = k as usize;
        if k >= levels.sizes.len()
            || tx as usize >= levels.sizes[k]
            || ty as usize >= levels.sizes[k]
        {
            return Err(Error::invalid(
                store.dir().join("minmax"),
                format!(
                    "the face pyramid of face {face} at tile level {level} has no texel \
                     ({tx}, {ty}) at its level {k}: rerun `penumbra mip`"
                ),
            ));
        }
        Ok(levels.at(k, tx as usize, ty as usize))
    }
}

/// A node of the descent: a face-pyramid texel (`k` levels of tiles up from one tile) or a
/// texel of a tile's own pyramid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Node {
    Face {
        fl: u32,
        x: u32,
        y: u32,
    },
    Tile {
        tx: u32,
        ty: u32,
        k: u32,
        i: u32,
        j: u32,
    },
}

#[derive(Clone, Copy, Debug)]
struct Item {
    bound: f64,
    theta_lo: f64,
    face: Face,
    node: Node,
    /// Not refined further (a texel of level 0, or small against its distance).
    leaf: bool,
}

impl PartialEq for Item {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == std::cmp::Ordering::Equal
    }
}
impl Eq for Item {}
impl PartialOrd for Item {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Item {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.bound
            .total_cmp(&o.bound)
            .then_with(|| self.face.cmp(&o.face))
            .then_with(|| self.node.cmp(&o.node))
    }
}

/// A block of observers: its cap and its lowest height.
struct Block {
    centre: Vec3,
    rho: f64,
    hmin: f64,
    /// Least central angle to terrain beyond the near field on the tile's own level.
    near_rad: f64,
}

/// The far field's descent for one block over one level's pyramids, raising `best` (radians)
/// to the bound of every texel that could raise it; stops once `best` reaches `stop`.
#[allow(clippy::too_many_arguments)]
fn descend(
    store: &Store,
    cache: &mut MipCache,
    level: u8,
    floor: f64,
    b: &Block,
    best: &mut f64,
    stop: f64,
) -> Result<()> {
    let ts = store.manifest();
    let (n, radius) = (ts.layout.tile_size, ts.body.radius_m);
    let s = ts.layout.face_pixels(level) as f64;
    // Resampling across a face edge reaches one context cell (√2 plane pixels ≥ its angle).
    let widen = 2.0 * SQRT_2 / s * 1.01;
    let item = |face: Face, node: Node, hmax: f32, parent_lo: f64| -> Option<Item> {
        if hmax.is_nan() {
            return None;
        }
        let (x0, y0, x1, y1) = match node {
            Node::Face { fl, x, y } => {
                let t = (n as u64) << fl;
                let g = ts.layout.face_pixels(level);
                (
                    x as u64 * t,
                    y as u64 * t,
                    ((x as u64 + 1) * t).min(g),
                    ((y as u64 + 1) * t).min(g),
                )
            }
            Node::Tile { tx, ty, k, i, j } => {
                let (ox, oy) = (tx as u64 * n as u64, ty as u64 * n as u64);
                let w = 1u64 << k;
                (
                    ox + i as u64 * w,
                    oy + j as u64 * w,
                    ox + ((i as u64 + 1) * w).min(n as u64),
                    oy + ((j as u64 + 1) * w).min(n as u64),
                )
            }
        };
        let (c, rho) = cap(face, s, x0 as f64, y0 as f64, x1 as f64, y1 as f64);
        let geo = angle(b.centre, c) - b.rho - rho - widen;
        let theta_lo = geo.max(floor).max(parent_lo);
        let bound = max_elevation_beyond(radius, b.hmin, hmax as f64, theta_lo);
        let leaf = matches!(node, Node::Tile { k: 0, .. }) || (geo > 0.0 && rho <= REFINE * geo);
        Some(Item {
            bound,
            theta_lo,
            face,
            node,
            leaf,
        })
    };
    let mut heap = BinaryHeap::new();
    for face in Face::ALL {
        let top = cache.face_texel(store, level, face, level as u32, 0, 0)?;
        let node = Node::Face {
            fl: level as u32,
            x: 0,
            y: 0,
        };
        if let Some(it) = item(face, node, top, 0.0) {
            heap.push(it);
        }
    }
    while let Some(it) = heap.pop() {
        if it.bound <= *best || *best >= stop {
            break;
        }
        if it.leaf {
            *best = it.bound;
            continue;
        }
        let mut children: Vec<(Node, f32)> = Vec::with_capacity(4);
        match it.node {
            Node::Face { fl, x, y } if fl > 0 => {
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (cx, cy) = (2 * x + dx, 2 * y + dy);
                    let v = cache.face_texel(store, level, it.face, fl - 1, cx, cy)?;
                    children.push((
                        Node::Face {
                            fl: fl - 1,
                            x: cx,
                            y: cy,
                        },
                        v,
                    ));
                }
            }
            Node::Face { x, y, .. } => {
                let id = TileId {
                    level,
                    face: it.face,
                    x,
                    y,
                };
                if !store.has_tile(id) {
                    continue;
                }
                let l = cache.tile(store, id)?;
                let k = l.sizes.len() - 1;
                children.push((
                    Node::Tile {
                        tx: x,
                        ty: y,
                        k: k as u32,
                        i: 0,
                        j: 0,
                    },
                    l.at(k, 0, 0),
                ));
            }
            Node::Tile { tx, ty, k, i, j } => {
                let id = TileId {
                    level,
                    face: it.face,
                    x: tx,
                    y: ty,
                };
                let l = cache.tile(store, id)?;
                let km = k as usize - 1;
                let size = l.sizes[km] as u32;
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (ci, cj) = (2 * i + dx, 2 * j + dy);
                    if ci < size && cj < size {
                        children.push((
                            Node::Tile {
                                tx,
                                ty,
                                k: k - 1,
                                i: ci,
                                j: cj,
                            },
                            l.at(km, ci as usize, cj as usize),
                        ));
                    }
                }
            }
        }
        for (node, v) in children {
            if let Some(c) = item(it.face, node, v, it.theta_lo) {
                if c.bound > *best {
                    heap.push(c);
                }
            }
        }
    }
    Ok(())
}

/// An upper bound (degrees) of every horizon elevation tile `id`'s maps can hold, with
/// [`MARGIN_DEG`] added, rounded up to f32 (see the module's header). `near` is the tile's
/// height raster reaching at least [`NEAR_PX`] + 2 pixels around it (`rect`: the tile in
/// it); `far` the coarser levels whose terrain the horizon method sees and how far away it
/// lies at least (far rings, beyond the rasters finer than them; the tile's own level is
/// always descended, beyond the near field); `tmin` the lowest terrain of the body. With `stop_deg` the descent stops
/// as soon as the bound reaches it (the answer is then only known to be at least that). NaN
/// when the tile has no pixel with data (no horizon to bound).
#[allow(clippy::too_many_arguments)]
pub fn tile_bound_deg(
    store: &Store,
    id: TileId,
    near: &Context,
    rect: Rect,
    far: &[FarLevel],
    tmin: f64,
    cache: &mut MipCache,
    stop_deg: Option<f64>,
) -> Result<f32> {
    let ts = store.manifest();
    let radius = ts.body.radius_m;
    let stop = stop_deg.map_or(f64::INFINITY, |d| (d - MARGIN_DEG).to_radians());
    let Some((mut best, _)) = near_bound(near, rect, tmin, NEAR_PX) else {
        return Ok(f32::NAN);
    };
    // The readers' floor at the lowest observer: the tangent to the lowest terrain's sphere.
    let lowest = (0..rect.h)
        .flat_map(|j| (0..rect.w).map(move |i| (i, j)))
        .map(|(i, j)| near.at((rect.x0 + i) as i64, (rect.y0 + j) as i64))
        .filter(|v| !v.is_nan())
        .fold(f32::INFINITY, f32::min) as f64;
    best = best.max(
        -((radius + tmin) / (radius + lowest.max(tmin)))
            .clamp(-1.0, 1.0)
            .acos(),
    );
    // Blocks of observers.
    let n = ts.layout.tile_size as usize;
    let s = ts.layout.face_pixels(id.level) as f64;
    let (gx0, gy0) = (id.x as f64 * n as f64, id.y as f64 * n as f64);
    let bs = BLOCK_PX.min(n);
    let mut blocks = Vec::new();
    for bj in (0..n).step_by(bs) {
        for bi in (0..n).step_by(bs) {
            let (i1, j1) = ((bi + bs).min(n), (bj + bs).min(n));
            let mut hmin = f64::INFINITY;
            for j in bj..j1 {
                for i in bi..i1 {
                    let v = near.at((rect.x0 + i) as i64, (rect.y0 + j) as i64);
                    if !v.is_nan() {
                        hmin = hmin.min(v as f64);
                    }
                }
            }
            if !hmin.is_finite() {
                continue;
            }
            // Observers sit at pixel centres.
            let (x0, y0) = (gx0 + bi as f64 + 0.5, gy0 + bj as f64 + 0.5);
            let (x1, y1) = (gx0 + i1 as f64 - 0.5, gy0 + j1 as f64 - 0.5);
            let (centre, rho) = cap(id.face, s, x0, y0, x1, y1);
            // A ray's first NEAR_PX plane pixels stay within that of the block, where the
            // plane's least scale is 1/(1 + u² + v²) at the farthest corner.
            let m = NEAR_PX as f64;
            let r2 = [
                (x0 - m, y0 - m),
                (x1 + m, y0 - m),
                (x0 - m, y1 + m),
                (x1 + m, y1 + m),
            ]
            .iter()
            .map(|&(x, y)| {
                let (u, v) = (-1.0 + 2.0 * x / s, 1.0 - 2.0 * y / s);
                u * u + v * v
            })
            .fold(0.0, f64::max);
            let near_rad = m * (2.0 / s) / (1.0 + r2);
            blocks.push(Block {
                centre,
                rho,
                hmin,
                near_rad,
            });
        }
    }
    // The tile's own level beyond the near field, then the far rings' levels.
    let own = FarLevel {
        level: id.level,
        floor_rad: f64::NAN,
    };
    for fl in std::iter::once(&own).chain(far) {
        for b in &blocks {
            if best >= stop {
                break;
            }
            let floor = if fl.floor_rad.is_nan() {
                b.near_rad
            } else {
                fl.floor_rad
            };
            descend(store, cache, fl.level, floor, b, &mut best, stop)?;
        }
    }
    let deg = best.to_degrees() + MARGIN_DEG;
    let mut f = deg as f32;
    if (f as f64) < deg {
        f = f32::from_bits(
            f.to_bits()
                .wrapping_add(if f >= 0.0 { 1 } else { u32::MAX }),
        );
    }
    Ok(f.min(90.0 + MARGIN_DEG as f32))
}

/// The least central angle from any point of the box [x0, x1] × [y0, y1] (edge coordinates of
/// `face` at side `s`) to any point outside the box `win` (edge coordinates at side `sw`, on
/// the same face's extended plane, containing the first): the distance from the inner box to
/// the outer box's border, found between their edges (great-circle arcs), endpoints against
/// arcs.
pub fn gap_to_outside(
    face: Face,
    s: f64,
    inner: (f64, f64, f64, f64),
    sw: f64,
    win: (f64, f64, f64, f64),
) -> f64 {
    let corners = |s: f64, b: (f64, f64, f64, f64)| -> [Vec3; 4] {
        [
            edge_dir(face, s, b.0, b.1),
            edge_dir(face, s, b.2, b.1),
            edge_dir(face, s, b.2, b.3),
            edge_dir(face, s, b.0, b.3),
        ]
    };
    let a = corners(s, inner);
    let w = corners(sw, win);
    let mut best = f64::INFINITY;
    for k in 0..4 {
        let (p, q) = (a[k], a[(k + 1) % 4]);
        for l in 0..4 {
            let (u, v) = (w[l], w[(l + 1) % 4]);
            best = best
                .min(point_arc(p, u, v))
                .min(point_arc(q, u, v))
                .min(point_arc(u, p, q))
                .min(point_arc(v, p, q));
        }
    }
    best
}

/// Central angle from `p` to the great-circle arc from `a` to `b` (shorter than π).
fn point_arc(p: Vec3, a: Vec3, b: Vec3) -> f64 {
    let nrm = cross(a, b);
    let l = cube::dot(nrm, nrm).sqrt();
    if l > 0.0 {
        let nrm = [nrm[0] / l, nrm[1] / l, nrm[2] / l];
        // p's foot on the great circle lies within the arc when it is on a's far side from
        // the plane through a and the normal, and on b's near side.
        let inside = cube::dot(cross(a, p), nrm) >= 0.0 && cube::dot(cross(p, b), nrm) >= 0.0;
        if inside {
            return cube::dot(p, nrm).abs().clamp(0.0, 1.0).asin();
        }
    }
    angle(p, a).min(angle(p, b))
}

fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// A face-pyramid texel a unit recorded (`facetexel LEVEL FACE FL X Y`), read from the tileset
/// as it is now (its bits as text); None: not such a name, or unreadable.
pub(crate) fn face_texel_value(store: &Store, cache: &mut MipCache, name: &str) -> Option<String> {
    let mut it = name.split(' ');
    if it.next()? != "facetexel" {
        return None;
    }
    let level: u8 = it.next()?.parse().ok()?;
    let face = it.next()?;
    let face = *Face::ALL.iter().find(|f| f.name() == face)?;
    let mut num = || it.next()?.parse::<u32>().ok();
    let (fl, x, y) = (num()?, num()?, num()?);
    let v = cache.face_texel_in(store, level, face, fl, x, y).ok()?;
    Some(v.to_bits().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_band_maximum_is_the_maximum_over_distance() {
        // Brute force over θ of the exact elevation against the closed form.
        let r = 1_737_400.0;
        for &(h, hh) in &[(0.0, 500.0), (500.0, 0.0), (1000.0, -3000.0), (0.0, 0.0)] {
            for &lo in &[0.0, 1e-5, 1e-3, 0.01, 0.2] {
                let got = max_elevation_beyond(r, h, hh, lo);
                let mut brute = f64::NEG_INFINITY;
                for k in 0..=200_000 {
                    let t = lo + k as f64 * 1e-6 * (1.0 + lo);
                    brute = brute.max(elevation_rad(r, h, hh, t));
                }
                assert!(got >= brute - 1e-12, "{h} {hh} {lo}: {got} < {brute}");
                assert!(got <= brute + 1e-9, "{h} {hh} {lo}: {got} ≫ {brute}");
            }
        }
    }

    #[test]
    fn point_to_arc_distances() {
        let a = cube::latlon_to_dir(0.0, 0.0);
        let b = cube::latlon_to_dir(0.0, 0.5);
        let p = cube::latlon_to_dir(0.1, 0.2);
        assert!((point_arc(p, a, b) - 0.1).abs() < 1e-12);
        let q = cube::latlon_to_dir(0.0, 0.7);
        assert!((point_arc(q, a, b) - 0.2).abs() < 1e-12);
        let q = cube::latlon_to_dir(0.0, -0.3);
        assert!((point_arc(q, a, b) - 0.3).abs() < 1e-12);
    }
}
