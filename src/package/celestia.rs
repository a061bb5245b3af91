//! A Celestia addon made from a tileset (docs/packaging.md): virtual textures of the albedo and
//! of a normal map derived from the heights, in Celestia's equirectangular tile addressing, and
//! the `.ctx`/`.ssc` files that hand them to a body.
//!
//! - **Addressing** ([`VtTile`]): at level L (`BaseSplit 0`) the globe is 2^(L+1) × 2^L square
//!   tiles of 180°/2^L; column 0 starts at 180° W, row 0 at the north pole
//!   (`VirtualTexture::getTile`/`getUTileCount` in Celestia's `src/celengine/virtualtex.cpp`,
//!   texture coordinates in `LODSphereMesh::renderSection`, `src/celengine/lodspheremesh.cpp`,
//!   longitudes in `Body::planetocentricToCartesian`, `src/celengine/body.cpp`).
//! - **Levels** ([`vt_level_for`], [`level_plan`]): each cube level's data goes to the coarsest
//!   VT level whose equatorial pixel is no larger than the cube level's largest pixel (the face
//!   centre's), capped at Celestia's 13 levels; every VT level from 0 up to the finest is written,
//!   each from the coarsest cube level at least as fine, and only its tiles that meet that cube
//!   level's coverage ([`vt_tiles`]): Celestia falls back to a coarser level where a tile is
//!   missing.
//! - **Pixels** ([`Sampler`], [`render_tile`]): each VT pixel's centre is looked up on the cube
//!   through [`Layout::locate`] and sampled bilinearly in the stored tile, halo included, so that
//!   samples across tile and face edges come from the same lattice the tiling stage wrote; where
//!   the cube level has no tile (or no data) there, the next coarser level that does answers.
//! - **Normals** ([`tangent_normal`]): the surface r = (R + h)·d differentiated along east and
//!   north, stored as Celestia's shaders read them: R = east, G = **south**, B = up, each
//!   (n + 1)/2 (`TangentSpaceTransform` in `src/celengine/shadermanager.cpp`: x = T (the sphere
//!   mesh's tangent, towards increasing longitude), y = −(N × T), z = N).

use std::collections::{BTreeSet, HashMap};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use crate::cube::{self, Vec3};
use crate::error::{Error, Result};
use crate::format::albedo::AlbedoTile;
use crate::format::height::HeightTile;
use crate::format::vt;
use crate::layout::{Layout, TileId};
use crate::manifest::Tileset;
use crate::progress::Progress;
use crate::tileset::Store;

use super::ssc;

/// Levels a Celestia virtual texture can hold (`MaxResolutionLevels` in `virtualtex.cpp`):
/// levels 0..=12.
pub const MAX_VT_LEVEL: u8 = 12;

/// One tile of a Celestia virtual texture with `BaseSplit 0`: column `x` (0 at 180° W,
/// eastwards) and row `y` (0 at the north pole, southwards) at `level`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct VtTile {
    pub level: u8,
    pub x: u32,
    pub y: u32,
}

/// A latitude/longitude box in degrees: south ≤ lat ≤ north, west ≤ lon ≤ east (west < east,
/// both within −180..180).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LatLonBox {
    pub south_deg: f64,
    pub north_deg: f64,
    pub west_deg: f64,
    pub east_deg: f64,
}

impl VtTile {
    /// Tiles around the globe at `level`: 2^(level+1).
    pub fn columns(level: u8) -> u32 {
        2u32 << level
    }

    /// Tiles from pole to pole at `level`: 2^level.
    pub fn rows(level: u8) -> u32 {
        1u32 << level
    }

    /// Side of a tile at `level` in degrees (tiles are square in degrees): 180°/2^level.
    pub fn span_deg(level: u8) -> f64 {
        180.0 / f64::from(1u32 << level)
    }

    /// The tile (level, x, y), refused where Celestia has no such tile.
    pub fn new(level: u8, x: u32, y: u32) -> Result<VtTile> {
        if level > MAX_VT_LEVEL {
            return Err(Error::param(
                "vt_level",
                format!("level {level} is beyond Celestia's virtual textures (0..={MAX_VT_LEVEL})"),
            ));
        }
        if x >= Self::columns(level) || y >= Self::rows(level) {
            return Err(Error::param(
                "vt_tile",
                format!(
                    "tile ({x}, {y}) is outside level {level}, which is {} × {} tiles",
                    Self::columns(level),
                    Self::rows(level)
                ),
            ));
        }
        Ok(VtTile { level, x, y })
    }

    /// The latitude/longitude box the tile covers.
    pub fn bounds(self) -> LatLonBox {
        let s = Self::span_deg(self.level);
        LatLonBox {
            north_deg: 90.0 - self.y as f64 * s,
            south_deg: 90.0 - (self.y + 1) as f64 * s,
            west_deg: -180.0 + self.x as f64 * s,
            east_deg: -180.0 + (self.x + 1) as f64 * s,
        }
    }

    /// The tile at `level` that holds latitude/longitude (degrees). Boxes are closed on their
    /// west and north edges: longitude 180° is −180° (column 0), latitude 90° is row 0, −90° the
    /// last row.
    pub fn containing(level: u8, lat_deg: f64, lon_deg: f64) -> VtTile {
        let s = Self::span_deg(level);
        let lon = (lon_deg + 180.0).rem_euclid(360.0);
        let x = ((lon / s).floor() as i64).clamp(0, Self::columns(level) as i64 - 1) as u32;
        let y = (((90.0 - lat_deg) / s).floor() as i64).clamp(0, Self::rows(level) as i64 - 1);
        VtTile {
            level,
            x,
            y: y as u32,
        }
    }

    /// Latitude and longitude (degrees) of the centre of pixel (i, j) of the tile when it is
    /// `size` pixels across (i eastwards, j southwards; fractional positions allowed).
    pub fn pixel_latlon_deg(self, size: u32, i: f64, j: f64) -> (f64, f64) {
        let b = self.bounds();
        let s = Self::span_deg(self.level) / size as f64;
        (b.north_deg - (j + 0.5) * s, b.west_deg + (i + 0.5) * s)
    }

    /// The tile's file below the texture's `ImageDirectory`: `level{L}/tx_{x}_{y}.{ext}`
    /// (`VirtualTexture::requestTile`).
    pub fn rel_path(self, ext: &str) -> String {
        format!("level{}/tx_{}_{}.{ext}", self.level, self.x, self.y)
    }
}

/// Angular size (radians) of a pixel at the equator at VT `level` with `tile_size` pixels a
/// tile: π / (tile_size · 2^level).
pub fn vt_pixel_rad(level: u8, tile_size: u32) -> f64 {
    PI / (tile_size as f64 * f64::from(1u32 << level))
}

/// Angular size (radians) of the largest pixel of cube `level` (at a face's centre).
pub fn cube_pixel_rad(layout: &Layout, level: u8) -> f64 {
    layout.centre_pixel_m(level, 1.0)
}

/// The VT level that holds cube `level`'s data: the coarsest whose equatorial pixel is no
/// larger than the cube level's largest pixel, so that no cube pixel is averaged away; capped
/// at [`MAX_VT_LEVEL`]. With equal tile sizes this is the cube level + 1 (π/2 > 1).
pub fn vt_level_for(layout: &Layout, level: u8, vt_tile_size: u32) -> u8 {
    let want = cube_pixel_rad(layout, level) * (1.0 + 1e-9);
    (0..=MAX_VT_LEVEL)
        .find(|&l| vt_pixel_rad(l, vt_tile_size) <= want)
        .unwrap_or(MAX_VT_LEVEL)
}

/// One level of the virtual textures and the cube level its pixels are sampled from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelSource {
    pub vt_level: u8,
    pub cube_level: u8,
}

/// The levels of the virtual textures of tileset `ts`: every VT level from 0 up to that of the
/// finest cube level with data, each sampled from the coarsest cube level with data whose VT
/// level is at least as fine (the finest cube level with data beyond it). Empty when the
/// tileset lists no tile.
pub fn level_plan(ts: &Tileset, vt_tile_size: u32) -> Vec<LevelSource> {
    let levels: Vec<u8> = ts
        .coverage
        .iter()
        .filter(|lc| lc.tiles > 0)
        .map(|lc| lc.level)
        .collect();
    let Some(&finest) = levels.iter().max() else {
        return Vec::new();
    };
    let top = vt_level_for(&ts.layout, finest, vt_tile_size);
    (0..=top)
        .map(|vt_level| LevelSource {
            vt_level,
            cube_level: levels
                .iter()
                .copied()
                .filter(|&c| vt_level_for(&ts.layout, c, vt_tile_size) >= vt_level)
                .min()
                .unwrap_or(finest),
        })
        .collect()
}

/// The VT tiles at `src.vt_level` that meet the coverage of cube level `src.cube_level`: every
/// tile holding a direction of a covered cube tile, found from each covered tile's pixel
/// centres along its four edges (every pixel) and on a 17 × 17 grid inside (finer than a VT
/// tile of that level), plus the whole polar row where a covered tile holds a pole.
pub fn vt_tiles(ts: &Tileset, src: LevelSource) -> BTreeSet<VtTile> {
    let lay = &ts.layout;
    let n = lay.tile_size as f64;
    let l = src.vt_level;
    let mut out = BTreeSet::new();
    let at = |d: Vec3| {
        let (lat, lon) = cube::dir_to_latlon(d);
        VtTile::containing(l, lat.to_degrees(), lon.to_degrees())
    };
    for t in ts
        .tile_set()
        .into_iter()
        .filter(|t| t.level == src.cube_level)
    {
        // Pixel coordinates −0.5 and n − 0.5 are the tile's edges: sampled a hair inside, so
        // that a VT tile that only touches the tile's edge does not count.
        let (lo, hi) = (-0.5 + 1e-6, n - 0.5 - 1e-6);
        for k in 0..=lay.tile_size {
            let f = (k as f64 - 0.5).clamp(lo, hi);
            for (i, j) in [(f, lo), (f, hi), (lo, f), (hi, f)] {
                out.insert(at(tile_dir(lay, t, i, j)));
            }
        }
        for a in 0..=16 {
            for b in 0..=16 {
                let (i, j) = (a as f64 / 16.0 * n - 0.5, b as f64 / 16.0 * n - 0.5);
                let (i, j) = (i.clamp(lo, hi), j.clamp(lo, hi));
                out.insert(at(tile_dir(lay, t, i, j)));
            }
        }
        // A pole strictly inside the tile (at level 0; deeper, poles are tile corners).
        for (pole, y) in [
            ([0.0, 0.0, 1.0], 0),
            ([0.0, 0.0, -1.0], VtTile::rows(l) - 1),
        ] {
            let loc = lay.locate(t.level, pole);
            let inside = |p: f64| p > lo && p < hi;
            if loc.tile == t && inside(loc.px) && inside(loc.py) {
                out.extend((0..VtTile::columns(l)).map(|x| VtTile { level: l, x, y }));
            }
        }
    }
    out
}

/// Unit direction of fractional interior pixel (i, j) of tile `t`.
fn tile_dir(lay: &Layout, t: TileId, i: f64, j: f64) -> Vec3 {
    let (gx, gy) = lay.global_pixel(t, 0, 0);
    let (s, u) = lay.global_st(t.level, gx as f64 + i, gy as f64 + j);
    lay.st_to_dir(t.face, s, u)
}

/// Unit direction of latitude/longitude in degrees.
pub fn latlon_deg_to_dir(lat_deg: f64, lon_deg: f64) -> Vec3 {
    cube::latlon_to_dir(lat_deg.to_radians(), lon_deg.to_radians())
}

/// A height field on the body: what the normal map is derived from.
pub trait HeightField {
    /// The body's reference radius in metres.
    fn radius_m(&self) -> f64;
    /// Height in metres above the reference sphere at unit direction `d`; None where there is
    /// no data.
    fn height_m(&self, d: Vec3) -> Result<Option<f64>>;
}

/// Samples a tileset's heights and albedo through its [`Store`] at a chosen cube level,
/// falling back to coarser levels where the level has no tile or no data.
pub struct Sampler<'a> {
    store: &'a Store,
    /// Albedo tiles decoded so far (the store caches heights but not albedo).
    albedo: Mutex<HashMap<TileId, Option<Arc<AlbedoTile>>>>,
}

/// The last tile read at each level, absent ones included.
type LastTiles = Vec<Option<(TileId, Option<Arc<HeightTile>>)>>;

/// The heights of a [`Sampler`] at one cube level, as a [`HeightField`]. It remembers the
/// last tile it read at each level (one per thread: it is not `Sync`), so that the five
/// samples of a pixel's normal, its neighbours', and the fallbacks to coarser levels where a
/// finer tile is absent skip the store's shared cache (its lock and hash were half of a VT
/// tile's time on one level).
pub struct LevelHeights<'s, 'a> {
    pub sampler: &'s Sampler<'a>,
    pub level: u8,
    last: std::cell::RefCell<LastTiles>,
}

impl<'s, 'a> LevelHeights<'s, 'a> {
    pub fn new(sampler: &'s Sampler<'a>, level: u8) -> Self {
        LevelHeights {
            sampler,
            level,
            last: std::cell::RefCell::new(vec![None; usize::from(level) + 1]),
        }
    }

    /// The store's tile `id` (None: absent), from the memo when it is its level's last read.
    fn tile(&self, id: TileId) -> Result<Option<Arc<HeightTile>>> {
        let l = usize::from(id.level);
        if let Some(Some((last, t))) = self.last.borrow().get(l) {
            if *last == id {
                return Ok(t.clone());
            }
        }
        let t = self.sampler.store.height(id)?;
        if let Some(slot) = self.last.borrow_mut().get_mut(l) {
            *slot = Some((id, t.clone()));
        }
        Ok(t)
    }
}

impl HeightField for LevelHeights<'_, '_> {
    fn radius_m(&self) -> f64 {
        self.sampler.store.manifest().body.radius_m
    }
    fn height_m(&self, d: Vec3) -> Result<Option<f64>> {
        self.sampler.height_by(d, self.level, |id| self.tile(id))
    }
}

impl<'a> Sampler<'a> {
    /// A sampler of `store`'s tileset.
    pub fn new(store: &'a Store) -> Sampler<'a> {
        Sampler {
            store,
            albedo: Mutex::new(HashMap::new()),
        }
    }

    /// The tileset's manifest.
    pub fn manifest(&self) -> &Tileset {
        self.store.manifest()
    }

    /// Height (m above the reference sphere) at unit direction `d`: bilinear in the stored tile
    /// (halo included) of `level` that holds `d`, or of the finest coarser level that has data
    /// there; None where no level has.
    pub fn height(&self, d: Vec3, level: u8) -> Result<Option<f64>> {
        self.height_by(d, level, |id| self.store.height(id))
    }

    /// [`Sampler::height`] with the tiles from `tile`.
    fn height_by(
        &self,
        d: Vec3,
        level: u8,
        tile: impl Fn(TileId) -> Result<Option<Arc<HeightTile>>>,
    ) -> Result<Option<f64>> {
        let lay = self.store.manifest().layout;
        for l in (0..=level.min(lay.levels.saturating_sub(1))).rev() {
            let loc = lay.locate(l, d);
            // The store's cache remembers absent tiles too.
            let Some(t) = tile(loc.tile)? else {
                continue;
            };
            let h = lay.halo as f64;
            let v = t.bilinear(loc.px + h, loc.py + h);
            if v.is_finite() {
                return Ok(Some(v as f64));
            }
        }
        Ok(None)
    }

    /// Albedo (RGB, 0..1) at unit direction `d`: bilinear in the albedo tile of `level` that
    /// holds `d`, or of the finest coarser level that has one; None where none has (or the
    /// tileset has no albedo). Grey tiles give equal channels; an alpha channel is left out.
    pub fn albedo(&self, d: Vec3, level: u8) -> Result<Option<[f64; 3]>> {
        let lay = self.store.manifest().layout;
        for l in (0..=level.min(lay.levels.saturating_sub(1))).rev() {
            let loc = lay.locate(l, d);
            let Some(t) = self.albedo_tile(loc.tile)? else {
                continue;
            };
            let h = lay.halo as f64;
            return Ok(Some(albedo_bilinear(&t, loc.px + h, loc.py + h)));
        }
        Ok(None)
    }

    fn albedo_tile(&self, id: TileId) -> Result<Option<Arc<AlbedoTile>>> {
        if let Some(t) = self
            .albedo
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&id)
        {
            return Ok(t.clone());
        }
        let t = self.store.albedo(id)?.map(Arc::new);
        let mut m = self.albedo.lock().unwrap_or_else(|e| e.into_inner());
        if m.len() > 4096 {
            m.clear();
        }
        m.insert(id, t.clone());
        Ok(t)
    }
}

/// Bilinear RGB (0..1) of an albedo tile at fractional stored pixel (x, y).
fn albedo_bilinear(t: &AlbedoTile, x: f64, y: f64) -> [f64; 3] {
    let n = t.size as i64;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let full = if t.sixteen_bit { 65535.0 } else { 255.0 };
    let rgb = |xi: i64, yi: i64| -> [f64; 3] {
        let k = ((yi.clamp(0, n - 1) * n + xi.clamp(0, n - 1)) as usize) * t.channels;
        let v = |c: usize| t.data[k + c] as f64 / full;
        match t.channels {
            1 | 2 => [v(0); 3],
            _ => [v(0), v(1), v(2)],
        }
    };
    let (x0, y0) = (x0 as i64, y0 as i64);
    let mut out = [0.0; 3];
    for (dx, dy, w) in [
        (0, 0, (1.0 - fx) * (1.0 - fy)),
        (1, 0, fx * (1.0 - fy)),
        (0, 1, (1.0 - fx) * fy),
        (1, 1, fx * fy),
    ] {
        let p = rgb(x0 + dx, y0 + dy);
        for c in 0..3 {
            out[c] += w * p[c];
        }
    }
    out
}

/// East and north unit vectors at unit direction `d` (east along +Y at the poles).
pub fn east_north(d: Vec3) -> (Vec3, Vec3) {
    let h = (d[0] * d[0] + d[1] * d[1]).sqrt();
    let east = if h > 1e-12 {
        [-d[1] / h, d[0] / h, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    (east, cube::cross(d, east))
}

/// The surface normal of `field` at unit direction `d` in Celestia's tangent space
/// (x = east, y = south, z = up), from central differences of the heights at ±`step_rad`
/// along east and north (one-sided where one side has no data, level where neither has):
/// for the surface r = (R + h)·d, n ∝ (R + h)·up − ∂h/∂e·east − ∂h/∂n·north, with the
/// derivatives per radian. None where `field` has no data at `d`.
pub fn tangent_normal(field: &dyn HeightField, d: Vec3, step_rad: f64) -> Result<Option<Vec3>> {
    let Some(h0) = field.height_m(d)? else {
        return Ok(None);
    };
    let (east, north) = east_north(d);
    let a = step_rad.atan();
    let along = |v: Vec3, k: f64| cube::normalize(cube::add(d, cube::scale(v, k * step_rad)));
    let mut slope = [0.0; 2];
    for (s, axis) in slope.iter_mut().zip([east, north]) {
        let hp = field.height_m(along(axis, 1.0))?;
        let hm = field.height_m(along(axis, -1.0))?;
        *s = match (hp, hm) {
            (Some(p), Some(m)) => (p - m) / (2.0 * a),
            (Some(p), None) => (p - h0) / a,
            (None, Some(m)) => (h0 - m) / a,
            (None, None) => 0.0,
        };
    }
    let r = field.radius_m() + h0;
    Ok(Some(cube::normalize([-slope[0], slope[1], r])))
}

/// A normal's byte in a normal map: (n + 1)/2 of 255, as Celestia's shaders decode it
/// (`texture(normTex, …).xyz * 2.0 - 1.0`).
pub fn normal_byte(v: f64) -> u8 {
    ((v.clamp(-1.0, 1.0) + 1.0) * 127.5).round() as u8
}

/// What a virtual texture shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layer {
    /// The tileset's albedo, 8-bit RGB.
    Albedo,
    /// The tangent-space normal map of the heights.
    Normal,
}

impl Layer {
    /// The layer's name in the addon's files (`penumbra-albedo`, `penumbra-normal`).
    pub fn name(self) -> &'static str {
        match self {
            Layer::Albedo => "penumbra-albedo",
            Layer::Normal => "penumbra-normal",
        }
    }
}

/// Render VT `tile` of `layer` (`size` pixels across, sampled from cube level `cube_level` and
/// coarser) as 8-bit RGB rows; None when no pixel has data. Pixels without data at any level
/// are black (albedo) or flat (normal: 128, 128, 255). The same bytes for any thread count.
pub fn render_tile(
    sampler: &Sampler<'_>,
    layer: Layer,
    tile: VtTile,
    size: u32,
    cube_level: u8,
) -> Result<Option<Vec<u8>>> {
    let lay = sampler.manifest().layout;
    let step = cube_pixel_rad(&lay, cube_level);
    let rows: Vec<Result<(Vec<u8>, bool)>> = (0..size)
        .into_par_iter()
        .map(|j| {
            let heights = LevelHeights::new(sampler, cube_level);
            let mut row = Vec::with_capacity(size as usize * 3);
            let mut any = false;
            for i in 0..size {
                let (lat, lon) = tile.pixel_latlon_deg(size, i as f64, j as f64);
                let d = latlon_deg_to_dir(lat, lon);
                let px = match layer {
                    Layer::Albedo => sampler
                        .albedo(d, cube_level)?
                        .map(|c| c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)),
                    Layer::Normal => tangent_normal(&heights, d, step)?.map(|n| n.map(normal_byte)),
                };
                any |= px.is_some();
                row.extend(px.unwrap_or(match layer {
                    Layer::Albedo => [0, 0, 0],
                    Layer::Normal => [128, 128, 255],
                }));
            }
            Ok((row, any))
        })
        .collect();
    let mut out = Vec::with_capacity((size * size * 3) as usize);
    let mut any = false;
    for r in rows {
        let (row, a) = r?;
        any |= a;
        out.extend(row);
    }
    Ok(any.then_some(out))
}

/// The text of a `.ctx` file: a virtual texture of PNG tiles `tile_size` pixels across in
/// `image_directory` (relative to the `.ctx` file's folder), `BaseSplit 0`.
pub fn ctx_text(image_directory: &str, tile_size: u32) -> String {
    format!(
        "# Written by penumbra: a Celestia virtual texture (docs/packaging.md)\n\
         VirtualTexture\n\
         {{\n    \
         ImageDirectory \"{}\"\n    \
         BaseSplit 0\n    \
         TileSize {tile_size}\n    \
         TileType \"png\"\n\
         }}\n",
        escape(image_directory)
    )
}

/// How the addon's catalog hands its textures to the body.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SurfaceMode {
    /// `Modify "Name" "Parent" { … }`: the body's own surface takes the textures. For a
    /// tileset whose data covers the whole globe at its coarsest VT level.
    Modify,
    /// `AltSurface "name" "Parent/Name" { … }`: an alternate surface the user picks in
    /// Celestia's menu, leaving the stock surface as it is. For a tileset that covers part of
    /// the body (a Modify would show the rest of the body without a texture).
    AltSurface(String),
}

/// The `.ssc` catalog's facts.
#[derive(Clone, Debug, PartialEq)]
pub struct SscSpec {
    /// The body's name in Celestia's catalogs (`Moon`).
    pub body: String,
    /// The path of its parent (`Sol/Earth`).
    pub parent: String,
    pub mode: SurfaceMode,
    /// The albedo virtual texture's file name (a `.ctx` in the addon's `textures/medres/`).
    pub texture: Option<String>,
    /// The normal map's file name.
    pub normal_map: Option<String>,
    /// A comment line at the top (what the addon was made from).
    pub note: String,
}

/// The body and parent path of a body preset in stock Celestia's catalogs (`data/solarsys.ssc`
/// and `data/asteroids.ssc`), found by its name or an alias; None for a body Celestia's stock
/// catalogs do not hold under that name.
pub fn celestia_body(preset: &str) -> Option<(&'static str, &'static str)> {
    Some(match preset.to_ascii_lowercase().as_str() {
        "moon" => ("Moon", "Sol/Earth"),
        "mercury" => ("Mercury", "Sol"),
        "venus" => ("Venus", "Sol"),
        "earth" => ("Earth", "Sol"),
        "mars" => ("Mars", "Sol"),
        "pluto" => ("Pluto", "Sol"),
        "ceres" => ("Ceres", "Sol"),
        "vesta" => ("Vesta", "Sol"),
        _ => return None,
    })
}

/// The text of the addon's `.ssc` catalog.
pub fn ssc_text(spec: &SscSpec) -> String {
    let mut s = String::new();
    for l in spec.note.lines() {
        s.push_str("# ");
        s.push_str(l);
        s.push('\n');
    }
    match &spec.mode {
        SurfaceMode::Modify => s.push_str(&format!(
            "Modify \"{}\" \"{}\"\n{{\n",
            escape(&spec.body),
            escape(&spec.parent)
        )),
        SurfaceMode::AltSurface(name) => s.push_str(&format!(
            "AltSurface \"{}\" \"{}/{}\"\n{{\n",
            escape(name),
            escape(&spec.parent),
            escape(&spec.body)
        )),
    }
    if let Some(t) = &spec.texture {
        s.push_str(&format!("    Texture \"{}\"\n", escape(t)));
    }
    if let Some(t) = &spec.normal_map {
        s.push_str(&format!("    NormalMap \"{}\"\n", escape(t)));
    }
    s.push_str("}\n");
    s
}

/// A string as Celestia's tokenizer reads it back.
fn escape(s: &str) -> String {
    s.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// Where the addon keeps its textures: Celestia looks texture names up in an addon's
/// `textures/lores|medres|hires/` and falls back between them (`src/celengine/texmanager.cpp`).
pub const TEXTURES_DIR: &str = "textures/medres";

/// A file that marks a folder as an addon Penumbra wrote (a later package may replace it).
pub const MARKER: &str = "penumbra-addon.txt";

/// The choices of a Celestia addon.
#[derive(Clone, Debug, PartialEq)]
pub struct AddonOptions {
    /// Pixels per side of a virtual texture tile: a power of two, 64 to 4096 (Celestia needs
    /// ≥ 64 and a power of two; 512 is what its own virtual textures use).
    pub vt_tile_size: u32,
    /// The body's name and parent path in Celestia (`("Moon", "Sol/Earth")`); None: from the
    /// tileset's body preset ([`celestia_body`]).
    pub body: Option<(String, String)>,
    /// The alternate surface's name where the tileset covers part of the body.
    pub alt_surface: String,
    /// The finest VT level written (at most [`MAX_VT_LEVEL`]): finer data is left to the
    /// cube-face products. Near a pole every VT level is a whole row of 2^(L+1) tiles around
    /// the pole per 180°/2^L of latitude (equirectangular tiles oversample longitude by
    /// 1/cos(latitude)), so polar data costs far more tiles than its area: a cap bounds them.
    pub max_vt_level: u8,
}

impl Default for AddonOptions {
    fn default() -> Self {
        AddonOptions {
            vt_tile_size: 512,
            body: None,
            alt_surface: "Penumbra".into(),
            max_vt_level: MAX_VT_LEVEL,
        }
    }
}

/// What [`write_addon`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct AddonReport {
    /// The `.ssc` catalog.
    pub catalog: PathBuf,
    pub mode: SurfaceMode,
    /// The VT levels and the cube level each was sampled from.
    pub levels: Vec<LevelSource>,
    /// Tiles written per layer (albedo, normal).
    pub tiles: Vec<(Layer, u64)>,
}

/// Whether the tileset's data covers the whole body at its coarsest level with data.
pub fn covers_globe(ts: &Tileset) -> bool {
    ts.coverage
        .iter()
        .filter(|lc| lc.tiles > 0)
        .min_by_key(|lc| lc.level)
        .is_some_and(|lc| lc.tiles == 6 * lc.tiles_per_face)
}

/// Write a Celestia addon of the tileset `store` opened into folder `out` (new, empty, or an
/// addon this function wrote, whose textures are replaced): `penumbra-<body>.ssc`, and in
/// [`TEXTURES_DIR`] a `.ctx` and its tile folder per layer (albedo when the tileset has it, the
/// normal map of the heights). The catalog `Modify`es the body when the data covers the globe,
/// and adds an `AltSurface` otherwise ([`SurfaceMode`]).
/// `progress` counts the tiles rendered.
pub fn write_addon(
    store: &Store,
    out: &Path,
    opts: &AddonOptions,
    progress: &dyn Progress,
) -> Result<AddonReport> {
    let size = opts.vt_tile_size;
    if !(64..=4096).contains(&size) || !size.is_power_of_two() {
        return Err(Error::param(
            "vt_tile_size",
            format!("{size} is not usable: Celestia's virtual texture tiles are a power of two from 64 (give 64 to 4096; default 512)"),
        ));
    }
    let ts = store.manifest();
    let (body, parent) = match &opts.body {
        Some((b, p)) => (b.clone(), p.clone()),
        None => celestia_body(&ts.body.name)
            .map(|(b, p)| (b.to_string(), p.to_string()))
            .ok_or_else(|| {
                Error::param(
                    "celestia_body",
                    format!(
                        "the tileset's body '{}' is not one of Celestia's stock bodies this \
                         package knows: give its name and parent path as Celestia's catalogs \
                         spell them (such as \"Moon\" and \"Sol/Earth\")",
                        ts.body.name
                    ),
                )
            })?,
    };
    if body.is_empty() || parent.is_empty() || opts.alt_surface.is_empty() {
        return Err(Error::param(
            "celestia_body",
            "the body's name, its parent path and the alternate surface's name must not be empty",
        ));
    }
    if opts.max_vt_level > MAX_VT_LEVEL {
        return Err(Error::param(
            "max_vt_level",
            format!(
                "{} is beyond Celestia's virtual-texture levels 0..={MAX_VT_LEVEL}",
                opts.max_vt_level
            ),
        ));
    }
    let plan: Vec<LevelSource> = level_plan(ts, size)
        .into_iter()
        .filter(|l| l.vt_level <= opts.max_vt_level)
        .collect();
    if plan.is_empty() {
        return Err(store.missing("the tileset lists no tile: there is nothing to package"));
    }
    prepare_out(out)?;
    let mode = if covers_globe(ts) {
        SurfaceMode::Modify
    } else {
        SurfaceMode::AltSurface(opts.alt_surface.clone())
    };
    let mut layers = vec![Layer::Normal];
    if ts.products.albedo.is_some() {
        layers.insert(0, Layer::Albedo);
    }
    let sampler = Sampler::new(store);
    let tex = out.join(TEXTURES_DIR);
    let per_level: Vec<(LevelSource, BTreeSet<VtTile>)> =
        plan.iter().map(|&src| (src, vt_tiles(ts, src))).collect();
    let total: usize = per_level.iter().map(|(_, t)| t.len()).sum();
    progress.start("textures", (total * layers.len()) as u64);
    let mut tiles = Vec::new();
    for &layer in &layers {
        let dir = tex.join(layer.name());
        let mut n = 0u64;
        for (src, vts) in &per_level {
            for &t in vts {
                if let Some(rgb) = render_tile(&sampler, layer, t, size, src.cube_level)? {
                    vt::write_png_rgb8(&dir.join(t.rel_path("png")), size, size, &rgb)?;
                    n += 1;
                }
                progress.inc(1);
            }
        }
        vt::write_text(
            &tex.join(format!("{}.ctx", layer.name())),
            &ctx_text(layer.name(), size),
        )?;
        tiles.push((layer, n));
    }
    let catalog = out.join(format!(
        "penumbra-{}.ssc",
        ts.body.name.to_ascii_lowercase()
    ));
    let spec = SscSpec {
        body,
        parent,
        mode: mode.clone(),
        texture: layers
            .contains(&Layer::Albedo)
            .then(|| format!("{}.ctx", Layer::Albedo.name())),
        normal_map: Some(format!("{}.ctx", Layer::Normal.name())),
        note: format!(
            "Written by penumbra from a tileset of {} (run key {}): docs/packaging.md",
            ts.body.name, ts.run_key
        ),
    };
    vt::write_text(&catalog, &ssc_text(&spec))?;
    progress.finish();
    vt::write_text(
        &out.join(MARKER),
        "A Celestia addon written by penumbra (docs/packaging.md).\n",
    )?;
    Ok(AddonReport {
        catalog,
        mode,
        levels: plan,
        tiles,
    })
}

/// Refuse an output folder that exists, is not empty and is not an addon Penumbra wrote; clear
/// the textures an earlier package left.
fn prepare_out(out: &Path) -> Result<()> {
    match std::fs::read_dir(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(out, e)),
        Ok(mut entries) => {
            if entries.next().is_none() {
                return Ok(());
            }
            if !out.join(MARKER).is_file() {
                return Err(Error::usage(format!(
                    "{} is not empty and holds no addon penumbra wrote (no {MARKER}): choose a \
                     new or empty folder",
                    out.display()
                )));
            }
            for layer in [Layer::Albedo, Layer::Normal] {
                crate::fsio::remove_tree(&out.join(TEXTURES_DIR).join(layer.name()))?;
            }
            Ok(())
        }
    }
}

/// Texture keys of a catalog item that name image files (`fillInSurface` in Celestia's
/// `src/celengine/solarsys.cpp`).
pub const TEXTURE_KEYS: &[&str] = &[
    "Texture",
    "NormalMap",
    "BumpMap",
    "NightTexture",
    "SpecularTexture",
    "OverlayTexture",
];

/// What [`check_addon`] found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AddonCheck {
    /// Catalogs read.
    pub catalogs: Vec<PathBuf>,
    /// Virtual textures read, each with the tiles it holds.
    pub virtual_textures: Vec<(PathBuf, u64)>,
}

/// Check an addon folder as Celestia would read it: every `.ssc` at its top parses, every
/// texture it names is in the addon's `textures/lores|medres|hires/`, every `.ctx` among them
/// parses, its `ImageDirectory` exists and holds `level{L}/` folders (L ≤ 12) of tiles named
/// `tx_X_Y.<TileType>` inside the level's grid (2^(L+1) × 2^L), of which level 0 holds at
/// least one. The error names the file and what is wrong.
pub fn check_addon(dir: &Path) -> Result<AddonCheck> {
    let read = |p: &Path| std::fs::read_to_string(p).map_err(|e| Error::io(p, e));
    let mut check = AddonCheck::default();
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "ssc"))
        .collect();
    entries.sort();
    if entries.is_empty() {
        return Err(Error::invalid(
            dir,
            "holds no .ssc catalog: it is not a Celestia addon",
        ));
    }
    for cat in entries {
        let items =
            ssc::parse_ssc(&read(&cat)?).map_err(|e| Error::invalid(&cat, e.to_string()))?;
        for item in &items {
            for key in TEXTURE_KEYS {
                let Some(name) = item.body.get_str(key) else {
                    continue;
                };
                let found = ["lores", "medres", "hires"]
                    .iter()
                    .map(|r| dir.join("textures").join(r).join(name))
                    .find(|p| p.is_file())
                    .ok_or_else(|| {
                        Error::invalid(
                            &cat,
                            format!(
                                "line {}: {key} \"{name}\" is in none of the addon's \
                                 textures/lores, medres or hires folders",
                                item.line
                            ),
                        )
                    })?;
                if found.extension().is_some_and(|x| x == "ctx") {
                    let n = check_ctx(&found)?;
                    check.virtual_textures.push((found, n));
                }
            }
        }
        check.catalogs.push(cat);
    }
    Ok(check)
}

/// Check one `.ctx` and its tiles; the number of tiles.
fn check_ctx(ctx: &Path) -> Result<u64> {
    let text = std::fs::read_to_string(ctx).map_err(|e| Error::io(ctx, e))?;
    let v = ssc::parse_ctx(&text).map_err(|e| Error::invalid(ctx, e.to_string()))?;
    let base = ctx.parent().unwrap_or(Path::new("."));
    let images = base.join(&v.image_directory);
    if !images.is_dir() {
        return Err(Error::invalid(
            ctx,
            format!("its ImageDirectory {} is not a folder", images.display()),
        ));
    }
    let mut count = 0u64;
    let mut level0 = 0u64;
    for e in std::fs::read_dir(&images).map_err(|e| Error::io(&images, e))? {
        let p = e.map_err(|e| Error::io(&images, e))?.path();
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        let level = name
            .strip_prefix("level")
            .and_then(|l| l.parse::<u8>().ok())
            .filter(|&l| l <= MAX_VT_LEVEL && p.is_dir())
            .ok_or_else(|| {
                Error::invalid(
                    &p,
                    format!(
                        "is not a level folder level0..level{MAX_VT_LEVEL} of a virtual texture"
                    ),
                )
            })?;
        for t in std::fs::read_dir(&p).map_err(|e| Error::io(&p, e))? {
            let f = t.map_err(|e| Error::io(&p, e))?.path();
            let n = f.file_name().and_then(|n| n.to_str()).unwrap_or_default();
            let xy = n
                .strip_prefix(v.tile_prefix.as_str())
                .and_then(|r| r.strip_suffix(&format!(".{}", v.tile_type)))
                .and_then(|r| r.split_once('_'))
                .and_then(|(x, y)| Some((x.parse::<u32>().ok()?, y.parse::<u32>().ok()?)));
            match xy {
                Some((x, y)) if VtTile::new(level, x, y).is_ok() && f.is_file() => {
                    count += 1;
                    level0 += u64::from(level == 0);
                }
                _ => {
                    return Err(Error::invalid(
                        &f,
                        format!(
                            "is not a tile {}X_Y.{} of level {level} (X < {}, Y < {})",
                            v.tile_prefix,
                            v.tile_type,
                            VtTile::columns(level),
                            VtTile::rows(level)
                        ),
                    ))
                }
            }
        }
    }
    if level0 == 0 {
        return Err(Error::invalid(
            ctx,
            "its virtual texture has no level-0 tile: Celestia draws nothing when the body is \
             small on screen",
        ));
    }
    Ok(count)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::Body;
    use crate::cube::{Face, Projection};
    use crate::progress::NoProgress;
    use crate::testutil::{global_georef, synthetic_dem};
    use crate::tiling::{tile_dem, TileOptions};

    /// Celestia's own texture coordinate of a point (`LODSphereMesh::renderSection` with
    /// `Body::planetocentricToCartesian`): u = 0.5 + lon/360 eastwards, v = 0.5 − lat/180
    /// southwards; its tile at a level is (⌊u·columns⌋, ⌊v·rows⌋).
    fn celestia_tile(level: u8, lat: f64, lon: f64) -> (u32, u32) {
        let u = 0.5 + lon / 360.0;
        let v = 0.5 - lat / 180.0;
        (
            (u * VtTile::columns(level) as f64).floor() as u32,
            (v * VtTile::rows(level) as f64).floor() as u32,
        )
    }

    #[test]
    fn vt_tiles_cover_the_boxes_celestia_gives_them() {
        // Worked examples.
        let b = VtTile::new(0, 0, 0).unwrap().bounds();
        assert_eq!(
            (b.west_deg, b.east_deg, b.south_deg, b.north_deg),
            (-180.0, 0.0, -90.0, 90.0)
        );
        let b = VtTile::new(1, 3, 1).unwrap().bounds();
        assert_eq!(
            (b.west_deg, b.east_deg, b.south_deg, b.north_deg),
            (90.0, 180.0, -90.0, 0.0)
        );
        let b = VtTile::new(2, 5, 1).unwrap().bounds();
        assert_eq!(
            (b.west_deg, b.east_deg, b.south_deg, b.north_deg),
            (45.0, 90.0, 0.0, 45.0)
        );
        assert_eq!((VtTile::columns(12), VtTile::rows(12)), (8192, 4096));
        assert_eq!(
            VtTile::new(3, 4, 2).unwrap().rel_path("png"),
            "level3/tx_4_2.png"
        );
        assert!(VtTile::new(2, 8, 0).is_err() && VtTile::new(2, 0, 4).is_err());
        assert!(VtTile::new(13, 0, 0).is_err());
        // Every tile of the first levels: its box is the one Celestia's texture coordinates
        // give, its centre and points just inside its corners round-trip, and the boxes tile
        // the globe (their areas sum to 4π).
        for level in 0..=6u8 {
            let mut area = 0.0;
            for y in 0..VtTile::rows(level) {
                for x in 0..VtTile::columns(level) {
                    let t = VtTile::new(level, x, y).unwrap();
                    let b = t.bounds();
                    let e = 1e-9;
                    for (lat, lon) in [
                        (
                            (b.north_deg + b.south_deg) / 2.0,
                            (b.west_deg + b.east_deg) / 2.0,
                        ),
                        (b.north_deg - e, b.west_deg + e),
                        (b.south_deg + e, b.east_deg - e),
                    ] {
                        assert_eq!(VtTile::containing(level, lat, lon), t);
                        assert_eq!(celestia_tile(level, lat, lon), (x, y), "{t:?} {lat} {lon}");
                    }
                    area += (b.east_deg - b.west_deg).to_radians()
                        * (b.north_deg.to_radians().sin() - b.south_deg.to_radians().sin());
                }
            }
            assert!((area - 4.0 * PI).abs() < 1e-9, "level {level}: {area}");
        }
        // Edges: ±180° is column 0 (west edge closed), just west of 180° the last column;
        // the poles are the first and last rows; longitudes wrap.
        for level in [0u8, 3, 12] {
            let last = VtTile::columns(level) - 1;
            assert_eq!(VtTile::containing(level, 10.0, 180.0).x, 0);
            assert_eq!(VtTile::containing(level, 10.0, -180.0).x, 0);
            assert_eq!(VtTile::containing(level, 10.0, 180.0 - 1e-9).x, last);
            assert_eq!(VtTile::containing(level, 10.0, 540.0 - 1e-9).x, last);
            assert_eq!(VtTile::containing(level, 90.0, 0.0).y, 0);
            assert_eq!(
                VtTile::containing(level, -90.0, 0.0).y,
                VtTile::rows(level) - 1
            );
        }
        // Pixel centres: half a pixel in from the tile's north-west corner.
        let (lat, lon) = VtTile::new(0, 0, 0).unwrap().pixel_latlon_deg(64, 0.0, 0.0);
        assert_eq!((lat, lon), (90.0 - 180.0 / 128.0, -180.0 + 180.0 / 128.0));
    }

    fn layout(projection: Projection, tile_size: u32) -> Layout {
        Layout {
            projection,
            tile_size,
            halo: 2,
            levels: 20,
        }
    }

    #[test]
    fn vt_levels_match_the_cube_levels_ground_resolution() {
        for (projection, tile, vt_size, offset) in [
            (Projection::Gnomonic, 512, 512, 1),
            (Projection::Gnomonic, 512, 256, 2),
            (Projection::Gnomonic, 256, 1024, -1),
            (Projection::EqualAngle, 512, 512, 1),
        ] {
            let lay = layout(projection, tile);
            for c in 0..16u8 {
                let l = vt_level_for(&lay, c, vt_size);
                let want = (c as i32 + offset).clamp(0, MAX_VT_LEVEL as i32) as u8;
                assert_eq!(l, want, "{projection:?} {tile} {vt_size} {c}");
                // The rule itself: no coarser than the cube pixel, and the level above is.
                if l < MAX_VT_LEVEL {
                    assert!(vt_pixel_rad(l, vt_size) <= cube_pixel_rad(&lay, c) * (1.0 + 1e-9));
                }
                if l > 0 && l < MAX_VT_LEVEL {
                    assert!(vt_pixel_rad(l - 1, vt_size) > cube_pixel_rad(&lay, c));
                }
            }
        }
        // LDEM_4 tiled at 512 px (one level, 6.8 km/px at a face centre) → VT level 1
        // (4 × 2 tiles of 512², 5.3 km/px at the equator).
        let lay = layout(Projection::Gnomonic, 512);
        let r = 1_737_400.0;
        assert_eq!(vt_level_for(&lay, 0, 512), 1);
        assert!(vt_pixel_rad(1, 512) * r < lay.centre_pixel_m(0, r));
        assert!(vt_pixel_rad(0, 512) * r > lay.centre_pixel_m(0, r));
    }

    /// A tileset of a smooth global terrain (and an albedo image), 64-px tiles, 3 levels.
    struct Fixture {
        _dir: tempfile::TempDir,
        path: PathBuf,
    }

    fn terrain(d: Vec3) -> f64 {
        // Slopes up to ~2° (wavelengths of ~9°, 18 DEM pixels).
        1500.0 * (40.0 * d[0]).sin() * (30.0 * d[1]).cos() + 900.0 * d[2]
    }

    fn albedo_of(lat: f64, lon: f64) -> [f64; 3] {
        latlon_deg_to_dir(lat, lon).map(|c| 0.5 + 0.3 * c)
    }

    fn fixture(georef: Option<crate::dem::GeoRef>, w: usize, h: usize) -> Fixture {
        let dir = tempfile::tempdir().unwrap();
        let g = georef.unwrap_or_else(|| global_georef(w, h));
        let dem = synthetic_dem(w, h, g.clone(), |c, r| {
            let (lat, lon) = (g.y0 - r as f64 * g.dy, g.x0 + c as f64 * g.dx);
            terrain(latlon_deg_to_dir(lat, lon)) as f32
        });
        // The albedo: a global equirectangular image from 180° W.
        let (aw, ah) = (720u32, 360u32);
        let mut rgb = Vec::new();
        for r in 0..ah {
            for c in 0..aw {
                let (lat, lon) = (
                    90.0 - (r as f64 + 0.5) / 2.0,
                    -180.0 + (c as f64 + 0.5) / 2.0,
                );
                rgb.extend(albedo_of(lat, lon).map(|v| (v * 255.0).round() as u8));
            }
        }
        let img = dir.path().join("albedo.png");
        vt::write_png_rgb8(&img, aw, ah, &rgb).unwrap();
        let out = dir.path().join("ts");
        let opts = TileOptions {
            tile_size: 64,
            levels: Some(3),
            albedo: Some((img, -180.0)),
            ..Default::default()
        };
        tile_dem(
            &dem,
            &Body::preset("moon").unwrap(),
            &out,
            &opts,
            None,
            &NoProgress,
        )
        .unwrap();
        Fixture {
            _dir: dir,
            path: out,
        }
    }

    #[test]
    fn level_plan_and_tiles_follow_the_coverage() {
        let f = fixture(None, 720, 360);
        let store = Store::open(&f.path).unwrap();
        let ts = store.manifest().clone();
        let plan = level_plan(&ts, 64);
        let pairs: Vec<(u8, u8)> = plan.iter().map(|p| (p.vt_level, p.cube_level)).collect();
        assert_eq!(pairs, vec![(0, 0), (1, 0), (2, 1), (3, 2)]);
        assert!(covers_globe(&ts));
        // Global coverage: every VT tile of every level.
        for p in &plan {
            let n = vt_tiles(&ts, *p).len() as u32;
            assert_eq!(n, VtTile::columns(p.vt_level) * VtTile::rows(p.vt_level));
        }
        // Without level 1: VT level 2 comes from cube level 2.
        let mut part = ts.clone();
        part.coverage.retain(|lc| lc.level != 1);
        let pairs: Vec<(u8, u8)> = level_plan(&part, 64)
            .iter()
            .map(|p| (p.vt_level, p.cube_level))
            .collect();
        assert_eq!(pairs, vec![(0, 0), (1, 0), (2, 2), (3, 2)]);
        // One tile of cube level 2 (on +X, and one holding the north pole): the VT tiles found
        // are those a dense brute-force sampling of every VT tile's box finds meeting it.
        for (keep, cube_level) in [
            (
                TileId {
                    level: 2,
                    face: Face::Px,
                    x: 1,
                    y: 2,
                },
                2,
            ),
            (
                TileId {
                    level: 2,
                    face: Face::Pz,
                    x: 2,
                    y: 1,
                },
                2,
            ),
            (
                TileId {
                    level: 2,
                    face: Face::Nz,
                    x: 1,
                    y: 1,
                },
                2,
            ),
            (
                TileId {
                    level: 0,
                    face: Face::Pz,
                    x: 0,
                    y: 0,
                },
                0,
            ),
        ] {
            let mut one = ts.clone();
            let tiles: BTreeSet<TileId> = [keep].into();
            one.coverage = crate::manifest::coverage_of(&tiles, 3);
            assert!(!covers_globe(&one));
            let src = LevelSource {
                vt_level: 3,
                cube_level,
            };
            let found = vt_tiles(&one, src);
            let mut brute = BTreeSet::new();
            for y in 0..VtTile::rows(3) {
                for x in 0..VtTile::columns(3) {
                    let t = VtTile { level: 3, x, y };
                    // Points strictly inside the box.
                    let k = 128;
                    'box_: for a in 0..k {
                        for b in 0..k {
                            let (lat, lon) = t.pixel_latlon_deg(k, a as f64, b as f64);
                            let d = latlon_deg_to_dir(lat, lon);
                            if one.layout.locate(cube_level, d).tile == keep {
                                brute.insert(t);
                                break 'box_;
                            }
                        }
                    }
                }
            }
            assert_eq!(found, brute, "{keep}");
            if keep.level == 0 {
                assert!((0..16).all(|x| found.contains(&VtTile { level: 3, x, y: 0 })));
            }
        }
    }

    /// The heights through the store are the terrain's, within the resampling error, also
    /// within a pixel of face edges and corners (the halo carries the lattice across).
    #[test]
    fn sampler_reads_heights_across_face_edges() {
        let f = fixture(None, 720, 360);
        let store = Store::open(&f.path).unwrap();
        let s = Sampler::new(&store);
        let lay = store.manifest().layout;
        let mut rnd = crate::testutil::rng(7);
        let mut worst_edge: f64 = 0.0;
        let mut worst_in: f64 = 0.0;
        let memo = LevelHeights::new(&s, 9);
        for _ in 0..400 {
            let face = Face::ALL[(rnd() * 6.0) as usize % 6];
            // Near an edge: u within a pixel of ±1; or anywhere.
            let px = 2.0 / lay.face_pixels(2) as f64;
            let u = if rnd() < 0.5 {
                1.0 - rnd() * px
            } else {
                -1.0 + rnd() * px
            };
            let v = rnd() * 2.0 - 1.0;
            for (d, worst) in [
                (cube::face_uv_to_dir(face, u, v), &mut worst_edge),
                (
                    cube::face_uv_to_dir(face, v, rnd() * 2.0 - 1.0),
                    &mut worst_in,
                ),
            ] {
                let h = s.height(d, 2).unwrap().unwrap();
                *worst = worst.max((h - terrain(d)).abs());
                // The per-level memo of a LevelHeights answers what the store answers, for
                // the same tile twice, at a level without tiles (coarser ones answer) and
                // after another tile.
                for _ in 0..2 {
                    assert_eq!(memo.height_m(d).unwrap(), s.height(d, 9).unwrap());
                }
                assert_eq!(LevelHeights::new(&s, 2).height_m(d).unwrap(), Some(h));
            }
        }
        // The terrain's slope is ≲ 5 m per mrad; the level-2 pixel is 7.8 mrad and the DEM's
        // 8.7 mrad: a few metres of resampling error, the same at the edges as inside.
        assert!(worst_in < 40.0, "{worst_in}");
        assert!(
            worst_edge < 40.0 && worst_edge < 2.0 * worst_in + 5.0,
            "{worst_edge} vs {worst_in}"
        );
        // Coarser levels answer where a level has no tile.
        let d = latlon_deg_to_dir(10.0, 20.0);
        assert_eq!(s.height(d, 9).unwrap(), s.height(d, 2).unwrap());
    }

    /// A height field for the analytic tests.
    struct Analytic<F: Fn(Vec3) -> Option<f64> + Sync>(F);

    const R: f64 = 1_737_400.0;

    impl<F: Fn(Vec3) -> Option<f64> + Sync> HeightField for Analytic<F> {
        fn radius_m(&self) -> f64 {
            R
        }
        fn height_m(&self, d: Vec3) -> Result<Option<f64>> {
            Ok((self.0)(d))
        }
    }

    /// A plane in space: its normal map is the plane's normal in each pixel's (east, south,
    /// up) frame, over a whole VT tile.
    #[test]
    fn a_tilted_plane_has_its_own_normal() {
        for (lat0, lon0, tilt) in [(30.0, 40.0, [0.2, 0.1]), (-75.0, 179.9, [-0.5, 0.3])] {
            let d0 = latlon_deg_to_dir(lat0, lon0);
            let (e0, n0) = east_north(d0);
            let normal = cube::normalize(cube::add(
                d0,
                cube::add(cube::scale(e0, tilt[0]), cube::scale(n0, tilt[1])),
            ));
            let c = cube::dot(normal, cube::scale(d0, R));
            let field = Analytic(|d: Vec3| Some(c / cube::dot(normal, d) - R));
            let tile = VtTile::containing(10, lat0, lon0);
            let step = 2e-6;
            let mut worst: f64 = 0.0;
            let mut spread: f64 = 0.0;
            let mut first = None;
            for j in 0..16 {
                for i in 0..16 {
                    let (lat, lon) = tile.pixel_latlon_deg(16, i as f64, j as f64);
                    let d = latlon_deg_to_dir(lat, lon);
                    let got = tangent_normal(&field, d, step).unwrap().unwrap();
                    let (e, n) = east_north(d);
                    let want = [
                        cube::dot(normal, e),
                        -cube::dot(normal, n),
                        cube::dot(normal, d),
                    ];
                    worst = worst.max(cube::angle_between(got, want));
                    let f = *first.get_or_insert(got);
                    spread = spread.max(cube::angle_between(got, f));
                }
            }
            assert!(worst < 1e-5, "{lat0} {lon0}: {worst} rad");
            // Over a tile (0.18°) the tangent-space normal turns only with the frame.
            let span = VtTile::span_deg(10).to_radians();
            assert!(spread < 1.5 * span, "{spread} vs {span}");
            // The bytes: east tilt → red above 128, north tilt → green below 128.
            let got = tangent_normal(&field, d0, step).unwrap().unwrap();
            assert_eq!(normal_byte(got[0]) > 128, tilt[0] > 0.0);
            assert_eq!(normal_byte(got[1]) < 128, tilt[1] > 0.0);
        }
        // A level surface: (128, 128, 255).
        let flat = Analytic(|_| Some(100.0));
        let n = tangent_normal(&flat, latlon_deg_to_dir(1.0, 2.0), 1e-4)
            .unwrap()
            .unwrap();
        assert_eq!(n.map(normal_byte), [128, 128, 255]);
    }

    /// A cone: normals lean away from the apex, by the cone's slope.
    #[test]
    fn a_cone_has_normals_pointing_away_from_its_apex() {
        let apex = latlon_deg_to_dir(-20.0, 100.0);
        let k = 0.3;
        let cone = Analytic(|d: Vec3| Some(5000.0 - k * R * cube::angle_between(d, apex)));
        let tile = VtTile::containing(8, -20.0, 100.0);
        let step = 1e-6;
        let mut checked = 0;
        for j in 0..32 {
            for i in 0..32 {
                let (lat, lon) = tile.pixel_latlon_deg(32, i as f64, j as f64);
                let d = latlon_deg_to_dir(lat, lon);
                if cube::angle_between(d, apex) < 10.0 * step {
                    continue;
                }
                let n = tangent_normal(&cone, d, step).unwrap().unwrap();
                let (e, no) = east_north(d);
                let away = cube::sub(d, apex);
                let (ax, ay) = (cube::dot(away, e), -cube::dot(away, no));
                let (hx, hy) = (n[0], n[1]);
                let cos =
                    (ax * hx + ay * hy) / ((ax * ax + ay * ay).sqrt() * (hx * hx + hy * hy).sqrt());
                assert!(cos > 0.9999, "({i}, {j}): {cos}");
                let h = 5000.0 - k * R * cube::angle_between(d, apex);
                let tan = (hx * hx + hy * hy).sqrt() / n[2];
                assert!((tan - k * R / (R + h)).abs() < 1e-4, "{tan}");
                checked += 1;
            }
        }
        assert!(checked > 1000);
    }

    /// Normal-map and albedo tiles rendered through the store agree with the terrain's own
    /// normals and the albedo image (within the resampling of two lattices and 8 bits).
    #[test]
    fn rendered_tiles_match_the_terrain_and_the_albedo() {
        let f = fixture(None, 720, 360);
        let store = Store::open(&f.path).unwrap();
        let s = Sampler::new(&store);
        let exact = Analytic(|d: Vec3| Some(terrain(d)));
        let step = cube_pixel_rad(&store.manifest().layout, 2);
        // Tiles at ±180°, at a pole, across several faces.
        for t in [
            VtTile {
                level: 3,
                x: 0,
                y: 3,
            },
            VtTile {
                level: 3,
                x: 15,
                y: 4,
            },
            VtTile {
                level: 3,
                x: 5,
                y: 0,
            },
            VtTile {
                level: 3,
                x: 9,
                y: 7,
            },
        ] {
            let size = 64;
            let nm = render_tile(&s, Layer::Normal, t, size, 2).unwrap().unwrap();
            let al = render_tile(&s, Layer::Albedo, t, size, 2).unwrap().unwrap();
            let (mut worst_n, mut worst_a, mut tilt): (f64, f64, f64) = (0.0, 0.0, 0.0);
            for j in 0..size {
                for i in 0..size {
                    let (lat, lon) = t.pixel_latlon_deg(size, i as f64, j as f64);
                    let d = latlon_deg_to_dir(lat, lon);
                    let k = ((j * size + i) * 3) as usize;
                    let got = cube::normalize([0, 1, 2].map(|c| nm[k + c] as f64 / 127.5 - 1.0));
                    let want = tangent_normal(&exact, d, step).unwrap().unwrap();
                    worst_n = worst_n.max(cube::angle_between(got, want));
                    tilt = tilt.max(want[2].acos());
                    let a = albedo_of(lat, lon);
                    for c in 0..3 {
                        worst_a = worst_a.max((al[k + c] as f64 / 255.0 - a[c]).abs());
                    }
                }
            }
            // The terrain leans up to ~0.3°; the bytes hold 0.45°; the lattices differ by a
            // third of their slope differences.
            assert!(
                worst_n.to_degrees() < 1.5,
                "{t:?}: {}°",
                worst_n.to_degrees()
            );
            assert!(worst_a < 0.03, "{t:?}: {worst_a}");
        }
    }

    #[test]
    fn writers_output_parses_back_and_names_only_files_that_exist() {
        let ctx = ctx_text("dir \"x\"", 256);
        let v = ssc::parse_ctx(&ctx).unwrap();
        assert_eq!(
            (
                v.image_directory.as_str(),
                v.base_split,
                v.tile_size,
                v.tile_type.as_str()
            ),
            ("dir \"x\"", 0, 256, "png")
        );
        for mode in [
            SurfaceMode::Modify,
            SurfaceMode::AltSurface("Pen\\umbra".into()),
        ] {
            let spec = SscSpec {
                body: "Moon".into(),
                parent: "Sol/Earth".into(),
                mode: mode.clone(),
                texture: Some("a.ctx".into()),
                normal_map: Some("b.ctx".into()),
                note: "two\nlines".into(),
            };
            let items = ssc::parse_ssc(&ssc_text(&spec)).unwrap();
            assert_eq!(items.len(), 1);
            let it = &items[0];
            match mode {
                SurfaceMode::Modify => {
                    assert_eq!(it.disposition, ssc::Disposition::Modify);
                    assert_eq!((it.item_type.as_str(), it.name.as_str()), ("Body", "Moon"));
                    assert_eq!(it.parent, "Sol/Earth");
                }
                SurfaceMode::AltSurface(n) => {
                    assert_eq!(
                        (it.item_type.as_str(), it.name.as_str()),
                        ("AltSurface", n.as_str())
                    );
                    assert_eq!(it.parent, "Sol/Earth/Moon");
                }
            }
            assert_eq!(it.body.get_str("Texture"), Some("a.ctx"));
            assert_eq!(it.body.get_str("NormalMap"), Some("b.ctx"));
        }

        // A whole addon of a global tileset: Modify, every file named exists, every tile the
        // plan lists is written and decodes.
        let f = fixture(None, 720, 360);
        let store = Store::open(&f.path).unwrap();
        let out = f.path.parent().unwrap().join("addon");
        let opts = AddonOptions {
            vt_tile_size: 64,
            ..Default::default()
        };
        let rep = write_addon(&store, &out, &opts, &NoProgress).unwrap();
        assert_eq!(rep.mode, SurfaceMode::Modify);
        let items = ssc::parse_ssc(&std::fs::read_to_string(&rep.catalog).unwrap()).unwrap();
        assert_eq!(
            (items[0].name.as_str(), items[0].parent.as_str()),
            ("Moon", "Sol/Earth")
        );
        let check = check_addon(&out).unwrap();
        assert_eq!(check.catalogs, vec![rep.catalog.clone()]);
        let per_layer: u64 = rep
            .levels
            .iter()
            .map(|&p| vt_tiles(store.manifest(), p).len() as u64)
            .sum();
        assert_eq!(check.virtual_textures.len(), 2);
        for ((_, n), (_, m)) in check.virtual_textures.iter().zip(&rep.tiles) {
            assert_eq!((*n, *m), (per_layer, per_layer));
        }
        let png = std::fs::read(
            out.join(TEXTURES_DIR)
                .join("penumbra-normal/level3/tx_15_7.png"),
        )
        .unwrap();
        let (w, h, _) = vt::decode_png_rgb8(&png).unwrap();
        assert_eq!((w, h), (64, 64));
        // Again into the same addon: replaced. Into a folder that is not an addon: refused.
        write_addon(&store, &out, &opts, &NoProgress).unwrap();
        let other = f.path.parent().unwrap().join("other");
        std::fs::create_dir_all(&other).unwrap();
        std::fs::write(other.join("x"), "x").unwrap();
        let e = write_addon(&store, &other, &opts, &NoProgress)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not empty"), "{e}");
        let bad = AddonOptions {
            vt_tile_size: 100,
            ..opts.clone()
        };
        assert!(write_addon(&store, &out, &bad, &NoProgress)
            .unwrap_err()
            .to_string()
            .contains("power of two"));
        // A cap on the VT levels: the coarser levels as before, none finer.
        let capped = AddonOptions {
            max_vt_level: 1,
            ..opts.clone()
        };
        let r = write_addon(&store, &out, &capped, &NoProgress).unwrap();
        assert_eq!(r.levels, rep.levels[..2].to_vec());
        assert!(!out
            .join(TEXTURES_DIR)
            .join("penumbra-normal/level2")
            .exists());
        let over = AddonOptions {
            max_vt_level: MAX_VT_LEVEL + 1,
            ..opts.clone()
        };
        assert!(write_addon(&store, &out, &over, &NoProgress)
            .unwrap_err()
            .to_string()
            .contains("0..=12"));
        write_addon(&store, &out, &opts, &NoProgress).unwrap();

        // The checker sees what is missing.
        std::fs::remove_file(out.join(TEXTURES_DIR).join("penumbra-albedo.ctx")).unwrap();
        let e = check_addon(&out).unwrap_err().to_string();
        assert!(
            e.contains("penumbra-albedo.ctx") && e.contains("none of"),
            "{e}"
        );
        write_addon(&store, &out, &opts, &NoProgress).unwrap();
        std::fs::remove_dir_all(out.join(TEXTURES_DIR).join("penumbra-normal/level0")).unwrap();
        let e = check_addon(&out).unwrap_err().to_string();
        assert!(e.contains("no level-0 tile"), "{e}");
        std::fs::write(
            out.join(TEXTURES_DIR)
                .join("penumbra-normal/level1/tx_9_0.png"),
            "",
        )
        .unwrap();
        let e = check_addon(&out).unwrap_err().to_string();
        assert!(e.contains("tx_9_0.png") || e.contains("level-0"), "{e}");
    }

    /// A regional tileset: an alternate surface, and tiles only where the region is.
    #[test]
    fn a_regional_tileset_becomes_an_alternate_surface() {
        let n = 120;
        let d = 0.25;
        let g = crate::dem::GeoRef {
            crs: crate::dem::Crs::Geographic,
            x0: 10.0 + d / 2.0,
            y0: 20.0 - d / 2.0,
            dx: d,
            dy: d,
        };
        let f = fixture(Some(g), n, n);
        let store = Store::open(&f.path).unwrap();
        assert!(!covers_globe(store.manifest()));
        let out = f.path.parent().unwrap().join("addon");
        let opts = AddonOptions {
            vt_tile_size: 64,
            ..Default::default()
        };
        let rep = write_addon(&store, &out, &opts, &NoProgress).unwrap();
        assert_eq!(rep.mode, SurfaceMode::AltSurface("Penumbra".into()));
        check_addon(&out).unwrap();
        // The finest level holds only tiles near the region (10..40° E, −10..20° N): within
        // the 27° of a level-2 cube tile of it, a few of the 128 tiles of the level.
        let top = rep.levels.last().unwrap();
        let tiles = vt_tiles(store.manifest(), *top);
        assert!(!tiles.is_empty() && tiles.len() < 32, "{}", tiles.len());
        for t in tiles {
            let b = t.bounds();
            assert!(
                b.east_deg > 10.0 - 27.0 && b.west_deg < 40.0 + 27.0,
                "{t:?}"
            );
            assert!(
                b.north_deg > -10.0 - 27.0 && b.south_deg < 20.0 + 27.0,
                "{t:?}"
            );
        }
    }
}
