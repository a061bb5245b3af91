/*!
Which tiles to draw: a quadtree walk over the cube faces that refines a tile while its texels
look larger than [`LodParams::max_texel_px`] on screen, skipping tiles outside the view
frustum or behind the body's horizon. The viewer (`penumbra-view`) draws what it chooses, and
[`crate::region::path_tiles`] plans a camera path's tiles by the same walk, so the two agree by
construction (docs/regions.md).

Tiles are bounded without reading them: a sphere around the tile's corners and centre at the
lowest and highest terrain. A tile outside the coverage (no data in its interior) is walked
through when finer tiles lie below it (a small DEM has no tiles at coarse levels) and dropped
otherwise; a quadtree without a coverage ([`Quadtree::from_layout`] with `None`: a planner
choosing tiles before any exist) treats every tile of the layout as present. The walk refines
the tile of largest screen error first, so a tile budget keeps the detail where the eye is.

A view may have no frustum ([`View::all_directions`]): a camera whose orientation is not known
(a lander's camera that pans) draws, at each tile, what some orientation would draw — the same
texel-per-pixel rule and horizon culling, no frustum culling. Without a tile budget the tiles
it draws, with their ancestors, hold every tile a frustum walk from the same eye draws, whatever
its heading and pitch.
*/

use std::collections::{BTreeSet, BinaryHeap, HashSet};

use crate::camera::Camera;
use crate::cube::{self, add, dot, norm, scale, sub, Face, Vec3};
use crate::layout::{Layout, TileId};

/// How the walk chooses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LodParams {
    /// Refine while a texel spans more than this many screen pixels.
    pub max_texel_px: f64,
    /// Most tiles drawn (refinement stops when another split would exceed it; `usize::MAX`
    /// for no budget).
    pub max_tiles: usize,
    /// Coarsest level drawn: coarser tiles are always split.
    pub min_level: u8,
    /// Finest level drawn: finer tiles are never drawn.
    pub max_level: u8,
}

/// A tile's bounding sphere (body frame, m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Centre (m).
    pub centre: Vec3,
    /// Radius (m).
    pub radius: f64,
}

/// The tiles that may be drawn and their ancestors, to walk the quadtree without reading
/// tiles.
pub struct Quadtree {
    layout: Layout,
    radius_m: f64,
    /// Lowest and highest terrain (m above the reference sphere).
    pub terrain_m: (f64, f64),
    /// The tiles that exist; `None`: every tile of the layout may.
    present: Option<BTreeSet<TileId>>,
    /// Every present tile and every ancestor of one (empty when `present` is `None`).
    reachable: HashSet<TileId>,
}

/// A tile visible in a frame, with its screen error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chosen {
    /// The tile.
    pub tile: TileId,
    /// Screen pixels a texel spans at the tile's nearest point.
    pub texel_px: f64,
}

/// The view the walk culls against.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// The eye, its orientation and its vertical field of view.
    pub camera: Camera,
    /// Frame size (pixels).
    pub width: u32,
    /// Frame height (pixels): with the field of view, the pixels per radian of the texel rule.
    pub height: u32,
    /// Near plane distance (m): no tile counts as nearer than this.
    pub near: f64,
    /// No frustum: every direction from the eye is seen (the camera's heading and pitch are
    /// not used); tiles are still culled by the horizon.
    pub all_directions: bool,
}

impl Quadtree {
    /// The quadtree of a tile grid on a body of radius `radius_m` with terrain between
    /// `terrain_m.0` and `terrain_m.1` metres above the reference sphere (finite, lowest
    /// first). `present`: the tiles that exist (a tileset's coverage; tiles of levels the
    /// layout lacks are ignored), or `None` when every tile of the layout may exist.
    pub fn from_layout(
        layout: Layout,
        radius_m: f64,
        terrain_m: (f64, f64),
        present: Option<BTreeSet<TileId>>,
    ) -> Quadtree {
        let mut reachable = HashSet::new();
        for t in present.iter().flatten() {
            let mut c = Some(*t);
            while let Some(id) = c {
                if !reachable.insert(id) {
                    break;
                }
                c = id.parent();
            }
        }
        Quadtree {
            layout,
            radius_m,
            terrain_m,
            present,
            reachable,
        }
    }

    /// The tile grid.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The reference sphere's radius (m).
    pub fn radius_m(&self) -> f64 {
        self.radius_m
    }

    /// Whether `id` exists (is in the coverage, or, without one, is a tile of the layout).
    pub fn has(&self, id: TileId) -> bool {
        match &self.present {
            Some(p) => p.contains(&id),
            None => self.in_layout(id),
        }
    }

    fn in_layout(&self, id: TileId) -> bool {
        id.level < self.layout.levels && id.x < (1 << id.level) && id.y < (1 << id.level)
    }

    /// Whether `id` exists or lies above a tile that does.
    fn reachable(&self, id: TileId) -> bool {
        match &self.present {
            Some(_) => self.reachable.contains(&id),
            None => self.in_layout(id),
        }
    }

    /// The near plane distance (m) for an eye at `eye`: [`Camera::near_m`] of its height above
    /// the highest terrain. The viewer's frames and the planner's paths both use it.
    pub fn near_for(&self, eye: Vec3) -> f64 {
        Camera::near_m(norm(eye) - self.radius_m - self.terrain_m.1)
    }

    /// The levels that hold at least one tile.
    pub fn levels(&self) -> BTreeSet<u8> {
        match &self.present {
            Some(p) => p.iter().map(|t| t.level).collect(),
            None => (0..self.layout.levels).collect(),
        }
    }

    /// The tiles of `level` that exist, sorted (without a coverage, all 6·4^level of them).
    pub fn tiles_at(&self, level: u8) -> Vec<TileId> {
        match &self.present {
            Some(p) => p.iter().filter(|t| t.level == level).copied().collect(),
            None if level >= self.layout.levels => Vec::new(),
            None => {
                let k = 1u32 << level;
                let mut v = Vec::with_capacity(6 * (k as usize) * (k as usize));
                // In `TileId` order, as a coverage's tiles come.
                for face in Face::ALL {
                    for x in 0..k {
                        for y in 0..k {
                            v.push(TileId { level, face, x, y });
                        }
                    }
                }
                v
            }
        }
    }

    /// The bounding sphere of `id`: its corners, edge midpoints and centre at the lowest and
    /// highest terrain, with 1 % to spare for the sphere's bulge between them.
    pub fn bounds(&self, id: TileId) -> Bounds {
        let n = self.layout.tile_size as f64;
        let mut pts = [[0.0; 3]; 18];
        let mut k = 0;
        for (a, b) in [
            (0.0, 0.0),
            (0.5, 0.0),
            (1.0, 0.0),
            (0.0, 0.5),
            (0.5, 0.5),
            (1.0, 0.5),
            (0.0, 1.0),
            (0.5, 1.0),
            (1.0, 1.0),
        ] {
            let d = self.dir_at(id, a * n - 0.5, b * n - 0.5);
            for h in [self.terrain_m.0, self.terrain_m.1] {
                pts[k] = scale(d, self.radius_m + h);
                k += 1;
            }
        }
        let mut c = [0.0; 3];
        for p in &pts {
            c = add(c, *p);
        }
        let c = scale(c, 1.0 / pts.len() as f64);
        let r = pts.iter().map(|p| norm(sub(*p, c))).fold(0.0, f64::max);
        Bounds {
            centre: c,
            radius: r * 1.01 + 1.0,
        }
    }

    /// Unit direction of fractional tile pixel (i, j) of `id` (pixel centres at integers; the
    /// tile's edges at −½ and n − ½).
    pub fn dir_at(&self, id: TileId, i: f64, j: f64) -> Vec3 {
        let n = self.layout.tile_size as f64;
        let (s, t) = self
            .layout
            .global_st(id.level, id.x as f64 * n + i, id.y as f64 * n + j);
        self.layout.st_to_dir(id.face, s, t)
    }

    /// Whether `id`'s bounding sphere is behind the horizon of the sphere of the lowest
    /// terrain, seen from `eye`, or outside the view frustum (when the view has one).
    fn culled(&self, id: TileId, b: &Bounds, v: &View) -> bool {
        let eye = v.camera.eye;
        if !v.all_directions {
            let rel = sub(b.centre, eye);
            // Frustum (view space: x right, y up, z = −forward).
            let basis = v.camera.basis();
            let (x, y, z) = (
                dot(rel, basis.right),
                dot(rel, basis.up),
                -dot(rel, basis.forward),
            );
            let f = 1.0 / (v.camera.fov_y_deg.to_radians() / 2.0).tan();
            let fx = f * v.height as f64 / v.width as f64;
            if z - (-v.near) > b.radius {
                return true;
            }
            let nx = (fx * fx + 1.0).sqrt();
            let ny = (f * f + 1.0).sqrt();
            if (x * fx + z) / nx > b.radius || (-x * fx + z) / nx > b.radius {
                return true;
            }
            if (y * f + z) / ny > b.radius || (-y * f + z) / ny > b.radius {
                return true;
            }
        }
        // Horizon: every sample point of the tile at its highest terrain hidden by the sphere
        // of the lowest terrain (Cesium's horizon-culling test, per point).
        let rm = self.radius_m + self.terrain_m.0;
        let e2 = dot(eye, eye);
        let vh2 = e2 - rm * rm;
        if vh2 <= 0.0 {
            return false; // the eye is below the lowest terrain: nothing is hidden by it
        }
        let n = self.layout.tile_size as f64;
        let top = self.radius_m + self.terrain_m.1;
        let visible = |d: Vec3| {
            let vt = sub(scale(d, top), eye);
            let vt_dot_vc = -dot(vt, eye);
            !(vt_dot_vc > vh2 && vt_dot_vc * vt_dot_vc / dot(vt, vt) > vh2)
        };
        // The tile's point nearest the eye's nadir first: a tile much larger than the eye's
        // horizon (a low eye over a coarse tile) can have all nine samples below it while
        // the ground under the eye is in view.
        if let Some((u, v)) = cube::dir_to_uv_on(id.face, eye) {
            let proj = self.layout.projection;
            let (s, t) = (proj.u_to_s(u), proj.u_to_s(v));
            let side = self.layout.face_pixels(id.level) as f64;
            let i = (s + 1.0) / 2.0 * side - 0.5 - id.x as f64 * n;
            let j = (1.0 - t) / 2.0 * side - 0.5 - id.y as f64 * n;
            let (i, j) = (i.clamp(-0.5, n - 0.5), j.clamp(-0.5, n - 0.5));
            if visible(self.dir_at(id, i, j)) {
                return false;
            }
        }
        for a in [0.0, 0.5, 1.0] {
            for c in [0.0, 0.5, 1.0] {
                if visible(self.dir_at(id, a * n - 0.5, c * n - 0.5)) {
                    return false;
                }
            }
        }
        true
    }

    /// Screen pixels a texel of `id` spans at its bounding sphere's nearest point.
    fn texel_px(&self, id: TileId, b: &Bounds, v: &View) -> f64 {
        let d = (norm(sub(b.centre, v.camera.eye)) - b.radius).max(v.near);
        let texel = self.layout.centre_pixel_m(id.level, self.radius_m);
        texel / d * v.camera.px_per_rad(v.height)
    }

    /// The tiles to draw for `view`, sorted by tile id.
    pub fn select(&self, view: &View, p: &LodParams) -> Vec<Chosen> {
        /// A tile in the walk's queue, ordered by screen error.
        #[derive(PartialEq)]
        struct Item(f64, TileId);
        impl Eq for Item {}
        impl PartialOrd for Item {
            fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
                Some(self.cmp(o))
            }
        }
        impl Ord for Item {
            fn cmp(&self, o: &Self) -> std::cmp::Ordering {
                self.0.total_cmp(&o.0).then(o.1.cmp(&self.1))
            }
        }
        let max_level = p.max_level.min(self.layout.levels.saturating_sub(1));
        let mut heap = BinaryHeap::new();
        let mut done = Vec::new();
        let visit = |id: TileId, heap: &mut BinaryHeap<Item>| {
            if !self.reachable(id) || id.level > max_level {
                return;
            }
            let b = self.bounds(id);
            if self.culled(id, &b, view) {
                return;
            }
            heap.push(Item(self.texel_px(id, &b, view), id));
        };
        for face in Face::ALL {
            visit(
                TileId {
                    level: 0,
                    face,
                    x: 0,
                    y: 0,
                },
                &mut heap,
            );
        }
        // Tiles drawn so far, and in the queue (a queued tile that is present counts).
        while let Some(Item(err, id)) = heap.pop() {
            let must = !self.has(id) || id.level < p.min_level;
            let count = done.len() + heap.len() + 1;
            let may = id.level < max_level
                && (must || (err > p.max_texel_px && count.saturating_add(3) <= p.max_tiles));
            if may {
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    visit(
                        TileId {
                            level: id.level + 1,
                            face: id.face,
                            x: id.x * 2 + dx,
                            y: id.y * 2 + dy,
                        },
                        &mut heap,
                    );
                }
            } else if self.has(id) && id.level >= p.min_level {
                done.push(Chosen {
                    tile: id,
                    texel_px: err,
                });
            }
        }
        done.sort_by_key(|c| c.tile);
        done
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cube::Projection;

    fn layout(levels: u8) -> Layout {
        Layout {
            projection: Projection::Gnomonic,
            tile_size: 64,
            halo: 2,
            levels,
        }
    }

    /// Every tile of `levels` levels, as a coverage.
    fn full(levels: u8) -> BTreeSet<TileId> {
        let mut present = BTreeSet::new();
        for level in 0..levels {
            let k = 1u32 << level;
            for face in Face::ALL {
                for y in 0..k {
                    for x in 0..k {
                        present.insert(TileId { level, face, x, y });
                    }
                }
            }
        }
        present
    }

    fn tree(levels: u8) -> Quadtree {
        Quadtree::from_layout(
            layout(levels),
            1_737_400.0,
            (-1000.0, 1000.0),
            Some(full(levels)),
        )
    }

    fn view(alt: f64, pitch: f64) -> View {
        View {
            camera: Camera::at(1_737_400.0, -89.0, 0.0, alt, 0.0, pitch, 45.0),
            width: 256,
            height: 256,
            near: 1.0,
            all_directions: false,
        }
    }

    #[test]
    fn a_close_eye_gets_fine_tiles_under_it_and_the_far_side_is_culled() {
        let q = tree(8);
        let p = LodParams {
            max_texel_px: 1.0,
            max_tiles: 200,
            min_level: 0,
            max_level: 7,
        };
        let near = q.select(&view(5_000.0, -90.0), &p);
        assert!(!near.is_empty());
        assert!(near.iter().all(|c| c.tile.face == Face::Nz), "{near:?}");
        assert_eq!(near.iter().map(|c| c.tile.level).max(), Some(7));
        let far = q.select(&view(5_000_000.0, -90.0), &p);
        assert!(far.iter().all(|c| c.tile.level <= 3), "{far:?}");
        // No face the eye cannot see (the north face is behind the body).
        assert!(far.iter().all(|c| c.tile.face != Face::Pz));
        assert!(near.len() <= 200 && far.len() <= 200);
    }

    #[test]
    fn a_low_eye_far_from_every_sample_of_a_coarse_tile_still_sees_the_ground_under_it() {
        // 20° from the south face's centre, 1 km above the lowest terrain: the horizon is
        // ~150 km away, every corner, edge middle and centre of the level-0 face farther.
        let q = tree(8);
        let p = LodParams {
            max_texel_px: 1.0,
            max_tiles: 200,
            min_level: 0,
            max_level: 7,
        };
        for (pitch, heading) in [(-90.0, 0.0), (-20.0, 137.0)] {
            let v = View {
                camera: Camera::at(1_737_400.0, -70.0, 20.0, 0.0, heading, pitch, 45.0),
                width: 256,
                height: 256,
                near: 1.0,
                all_directions: false,
            };
            let s = q.select(&v, &p);
            assert!(!s.is_empty(), "pitch {pitch}: nothing chosen");
            assert_eq!(s.iter().map(|c| c.tile.level).max(), Some(7));
        }
    }

    #[test]
    fn the_budget_and_the_level_range_hold() {
        let q = tree(8);
        let p = LodParams {
            max_texel_px: 0.01,
            max_tiles: 24,
            min_level: 2,
            max_level: 5,
        };
        let s = q.select(&view(20_000.0, -30.0), &p);
        assert!(s.len() <= 24 + 3, "{}", s.len());
        assert!(s.iter().all(|c| (2..=5).contains(&c.tile.level)));
        let fixed = LodParams {
            min_level: 4,
            max_level: 4,
            ..p
        };
        assert!(q
            .select(&view(20_000.0, -30.0), &fixed)
            .iter()
            .all(|c| c.tile.level == 4));
    }

    #[test]
    fn no_coverage_means_every_tile_and_chooses_as_a_full_coverage_does() {
        let all = Quadtree::from_layout(layout(8), 1_737_400.0, (-1000.0, 1000.0), None);
        let q = tree(8);
        assert_eq!(all.levels(), q.levels());
        assert_eq!(all.tiles_at(3), q.tiles_at(3));
        assert!(all.tiles_at(8).is_empty());
        for (alt, pitch) in [(5_000.0, -90.0), (20_000.0, -30.0), (3_000_000.0, -60.0)] {
            for omni in [false, true] {
                let v = View {
                    all_directions: omni,
                    ..view(alt, pitch)
                };
                let p = LodParams {
                    max_texel_px: 1.0,
                    max_tiles: 300,
                    min_level: 0,
                    max_level: 7,
                };
                assert_eq!(all.select(&v, &p), q.select(&v, &p), "{alt} {pitch} {omni}");
            }
        }
    }

    /// Closes `tiles` under parents.
    fn with_ancestors(tiles: impl IntoIterator<Item = TileId>) -> BTreeSet<TileId> {
        let mut s = BTreeSet::new();
        for t in tiles {
            let mut c = Some(t);
            while let Some(id) = c {
                if !s.insert(id) {
                    break;
                }
                c = id.parent();
            }
        }
        s
    }

    #[test]
    fn all_directions_hold_every_orientation_and_see_more_than_one() {
        let q = tree(9);
        let unlimited = LodParams {
            max_texel_px: 1.0,
            max_tiles: usize::MAX,
            min_level: 0,
            max_level: 8,
        };
        for alt in [2_000.0, 30_000.0, 400_000.0] {
            let omni = View {
                all_directions: true,
                ..view(alt, 0.0)
            };
            let all = q.select(&omni, &unlimited);
            let closed = with_ancestors(all.iter().map(|c| c.tile));
            let mut union = BTreeSet::new();
            for heading in (0..360).step_by(45) {
                for pitch in [-90.0, -45.0, 0.0, 30.0] {
                    let mut v = view(alt, pitch);
                    v.camera.heading_deg = heading as f64;
                    // With a budget (the viewer's) and without one.
                    for max_tiles in [96, usize::MAX] {
                        let p = LodParams {
                            max_tiles,
                            ..unlimited
                        };
                        for c in q.select(&v, &p) {
                            assert!(closed.contains(&c.tile), "{alt} {heading} {pitch}: {c:?}");
                            union.insert(c.tile);
                        }
                    }
                }
            }
            assert!(all.len() > 1);
            // An omnidirectional view draws no tile that no orientation draws at the same
            // error: each of its tiles is in the union or under one of it.
            let union_closed = with_ancestors(union.iter().copied());
            let extra = all
                .iter()
                .filter(|c| !union_closed.contains(&c.tile))
                .count();
            assert_eq!(extra, 0, "{alt}");
        }
    }
}
