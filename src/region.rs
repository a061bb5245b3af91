/*!
Regions of a body and the tiles they need (docs/regions.md).

- [`tiles_touching`]: every tile of one level whose area (the halo does not count) meets a
  [`Shape`] — the whole body, a latitude/longitude box, a cap (a point and a radius) or a
  polygon with great-circle edges. Conservative: no tile that meets the shape is missed; a tile
  that only comes within about 1e-9 rad of it may be included. The walk descends the quadtree
  from level 0 and refines only tiles that meet the shape, so its cost grows with the shape's
  area and perimeter in tiles, not with the 6·4^level tiles of the level.
- [`path_tiles`]: the tiles a viewer draws along a camera path ([`PathPoint`]s, from a CSV by
  [`parse_path_csv`] or [`read_path_csv`]) at a frame size and texel-per-pixel rule, with
  their ancestors, by the walk of [`crate::lod`] with an all-directions view.
- [`with_ancestors`]: a set of tiles closed under parent.

Geometry: a tile's area is a spherical quadrilateral whose edges are great-circle arcs (lines of
constant face coordinate are great circles in both projections), convex and within 55° of its
centre. A cap meets it when the largest dot product of the cap's centre with the tile's points
reaches the cap's cosine; a box meets it when the tile, cut by the planes of the box's bounding
meridians, still reaches the box's latitudes; a polygon meets it when, in the gnomonic plane of
the polygon's mean direction, the tile's image and the polygon overlap (an edge crosses, or one
holds a vertex of the other, even–odd rule).
*/

use std::collections::BTreeSet;
use std::path::Path;

use rayon::prelude::*;

use crate::camera::{Camera, FOV_RANGE};
use crate::cube::{self, cross, dot, norm, normalize, scale, Face, Vec3};
use crate::layout::{Layout, TileId};
use crate::lod::{LodParams, Quadtree, View};
use crate::{Error, Result};

/// A region of the body. Latitudes and longitudes are planetocentric degrees.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// The whole body.
    Body,
    /// Latitudes `lat.0..=lat.1` (in [−90, 90], lowest first) and the longitudes eastward
    /// from `lon.0` to `lon.1` (each in [−360, 360]): `(170, −170)` and `(170, 190)` are the same
    /// 20° across the antimeridian, `(−170, 170)` the other 340°; 360° or more is every
    /// longitude. Equal bounds are a parallel or a meridian segment.
    LatLonBox {
        /// Southern and northern latitude (degrees).
        lat: (f64, f64),
        /// Western and eastern longitude (degrees), eastward from the first.
        lon: (f64, f64),
    },
    /// The points within `radius_m` (measured along the reference sphere) of a point.
    Cap {
        /// Latitude of the centre (degrees).
        lat_deg: f64,
        /// Longitude of the centre (degrees).
        lon_deg: f64,
        /// Radius along the reference sphere (m, ≥ 0; half the circumference or more is the
        /// whole body).
        radius_m: f64,
    },
    /// A polygon: its vertices (latitude, longitude in degrees), joined in order and back to
    /// the first by the shorter great-circle arc; inside by the even–odd rule, so it may be
    /// concave (or cross itself). It must lie within 89° of its vertices' mean direction (a
    /// larger region: several polygons, or a box).
    Polygon {
        /// (latitude, longitude) of each vertex (degrees), at least three.
        vertices: Vec<(f64, f64)>,
    },
}

/// Most vertices of a [`Shape::Polygon`].
pub const MAX_POLYGON_VERTICES: usize = 100_000;

/// Margin (rad) a shape is widened by so that rounding never loses a tile that meets it.
const MARGIN_RAD: f64 = 1e-9;

/// Largest angle (degrees) of a polygon's vertices from their mean direction.
const MAX_POLYGON_SPREAD_DEG: f64 = 89.0;

fn check_lat(param: &'static str, v: f64) -> Result<()> {
    if !(v.is_finite() && (-90.0..=90.0).contains(&v)) {
        return Err(Error::param(
            param,
            format!("latitude {v} is outside [-90, 90] degrees"),
        ));
    }
    Ok(())
}

fn check_lon(param: &'static str, v: f64) -> Result<()> {
    if !(v.is_finite() && (-360.0..=360.0).contains(&v)) {
        return Err(Error::param(
            param,
            format!("longitude {v} is outside [-360, 360] degrees"),
        ));
    }
    Ok(())
}

fn dir_deg(lat: f64, lon: f64) -> Vec3 {
    cube::latlon_to_dir(lat.to_radians(), lon.to_radians())
}

/// A shape made ready for testing tiles.
enum Prepared {
    Body,
    Cap {
        centre: Vec3,
        /// Cosine of the (widened) angular radius.
        cos_r: f64,
        /// The (widened) angular radius.
        angle: f64,
    },
    Box {
        /// sin of the (widened) latitudes.
        z: (f64, f64),
        /// Each wedge of longitudes (at most 180° wide) as the normals of its two bounding
        /// planes through the axis; empty: every longitude.
        wedges: Vec<[Vec3; 2]>,
    },
    Polygon(PlanarPolygon),
}

/// A polygon in the gnomonic plane of its mean direction `c` (basis `e1`, `e2`,
/// `e1 × e2 = c`).
struct PlanarPolygon {
    c: Vec3,
    e1: Vec3,
    e2: Vec3,
    /// Half-width of the square cone about `c` (in the plane) that holds the polygon.
    rho: f64,
    /// Largest angle of a vertex from `c` (rad).
    spread: f64,
    pts: Vec<(f64, f64)>,
    /// Coordinate scale of the plane (for the tolerances).
    tol: f64,
}

impl Shape {
    /// Whether the shape is well formed: every coordinate in range, a polygon of at least three
    /// vertices within 89° of their mean direction. Errors name the field.
    pub fn check(&self, radius_m: f64) -> Result<()> {
        self.prepare(radius_m).map(|_| ())
    }

    fn prepare(&self, radius_m: f64) -> Result<Prepared> {
        if !(radius_m.is_finite() && radius_m > 0.0) {
            return Err(Error::param(
                "radius_m",
                format!("{radius_m} is not a positive body radius (m)"),
            ));
        }
        match self {
            Shape::Body => Ok(Prepared::Body),
            Shape::Cap {
                lat_deg,
                lon_deg,
                radius_m: r,
            } => {
                check_lat("lat_deg", *lat_deg)?;
                check_lon("lon_deg", *lon_deg)?;
                if !(r.is_finite() && *r >= 0.0) {
                    return Err(Error::param(
                        "radius_m",
                        format!("cap radius {r} is not a distance in metres (0 or more)"),
                    ));
                }
                let angle = r / radius_m + MARGIN_RAD;
                if angle >= std::f64::consts::PI {
                    return Ok(Prepared::Body);
                }
                Ok(Prepared::Cap {
                    centre: dir_deg(*lat_deg, *lon_deg),
                    cos_r: angle.cos(),
                    angle,
                })
            }
            Shape::LatLonBox { lat, lon } => {
                check_lat("lat", lat.0)?;
                check_lat("lat", lat.1)?;
                if lat.0 > lat.1 {
                    return Err(Error::param(
                        "lat",
                        format!("({}, {}): the southern latitude comes first", lat.0, lat.1),
                    ));
                }
                check_lon("lon", lon.0)?;
                check_lon("lon", lon.1)?;
                let m = MARGIN_RAD.to_degrees();
                let z = (
                    (lat.0 - m).max(-90.0).to_radians().sin(),
                    (lat.1 + m).min(90.0).to_radians().sin(),
                );
                let mut width = lon.1 - lon.0;
                if width < 0.0 {
                    width += 360.0;
                }
                let (west, width) = (lon.0 - m, width + 2.0 * m);
                let wedges = if width >= 360.0 {
                    Vec::new()
                } else {
                    let pieces = if width <= 180.0 { 1 } else { 2 };
                    let w = width / pieces as f64;
                    (0..pieces)
                        .map(|k| {
                            let a = (west + k as f64 * w).to_radians();
                            let b = (west + (k + 1) as f64 * w).to_radians();
                            // East of meridian a, west of meridian b.
                            [[-a.sin(), a.cos(), 0.0], [b.sin(), -b.cos(), 0.0]]
                        })
                        .collect()
                };
                Ok(Prepared::Box { z, wedges })
            }
            Shape::Polygon { vertices } => prepare_polygon(vertices).map(Prepared::Polygon),
        }
    }
}

fn prepare_polygon(vertices: &[(f64, f64)]) -> Result<PlanarPolygon> {
    if vertices.len() < 3 || vertices.len() > MAX_POLYGON_VERTICES {
        return Err(Error::param(
            "vertices",
            format!(
                "a polygon needs 3 to {MAX_POLYGON_VERTICES} vertices, not {}",
                vertices.len()
            ),
        ));
    }
    let mut dirs = Vec::with_capacity(vertices.len());
    for (k, &(lat, lon)) in vertices.iter().enumerate() {
        check_lat("vertices", lat).map_err(|e| Error::param("vertices", format!("[{k}]: {e}")))?;
        check_lon("vertices", lon).map_err(|e| Error::param("vertices", format!("[{k}]: {e}")))?;
        dirs.push(dir_deg(lat, lon));
    }
    let mut sum = [0.0; 3];
    for d in &dirs {
        sum = cube::add(sum, *d);
    }
    let too_wide = || {
        Error::param(
            "vertices",
            format!(
                "the polygon does not lie within {MAX_POLYGON_SPREAD_DEG}° of its vertices' \
                 mean direction: split it into smaller polygons, or use a box"
            ),
        )
    };
    if norm(sum) < 1e-9 * dirs.len() as f64 {
        return Err(too_wide());
    }
    let c = normalize(sum);
    let spread = dirs
        .iter()
        .map(|d| cube::angle_between(*d, c))
        .fold(0.0, f64::max);
    if spread > MAX_POLYGON_SPREAD_DEG.to_radians() {
        return Err(too_wide());
    }
    // A basis of the plane tangent at c: e1 along the axis least aligned with c.
    let k = (0..3)
        .min_by(|&a, &b| c[a].abs().total_cmp(&c[b].abs()))
        .unwrap_or(0);
    let mut axis = [0.0; 3];
    axis[k] = 1.0;
    let e1 = normalize(cross(axis, c));
    let e2 = cross(c, e1);
    let pts: Vec<(f64, f64)> = dirs
        .iter()
        .map(|d| {
            let z = dot(*d, c);
            (dot(*d, e1) / z, dot(*d, e2) / z)
        })
        .collect();
    let rho = (spread + MARGIN_RAD).tan() * (1.0 + 1e-9) + 1e-12;
    Ok(PlanarPolygon {
        c,
        e1,
        e2,
        rho,
        spread,
        pts,
        tol: 1e-12 * (1.0 + rho),
    })
}

/// The corners of `id`'s area (no halo), counter-clockwise seen from outside the body.
fn tile_corners(layout: &Layout, id: TileId) -> [Vec3; 4] {
    let k = layout.tiles_per_side(id.level) as f64;
    let s0 = -1.0 + 2.0 * id.x as f64 / k;
    let s1 = -1.0 + 2.0 * (id.x + 1) as f64 / k;
    let t0 = 1.0 - 2.0 * (id.y + 1) as f64 / k;
    let t1 = 1.0 - 2.0 * id.y as f64 / k;
    [
        layout.st_to_dir(id.face, s0, t0),
        layout.st_to_dir(id.face, s1, t0),
        layout.st_to_dir(id.face, s1, t1),
        layout.st_to_dir(id.face, s0, t1),
    ]
}

/// The part of the convex cone polygon `poly` (vertices need not be unit) where `n · p ≥ 0`
/// (Sutherland–Hodgman: a plane through the origin cuts a cone polygon into a cone polygon).
fn clip(poly: &[Vec3], n: Vec3) -> Vec<Vec3> {
    let mut out = Vec::with_capacity(poly.len() + 2);
    for i in 0..poly.len() {
        let p = poly[i];
        let q = poly[(i + 1) % poly.len()];
        let (dp, dq) = (dot(n, p), dot(n, q));
        if dp >= 0.0 {
            out.push(p);
        }
        if (dp >= 0.0) != (dq >= 0.0) {
            let t = dp / (dp - dq);
            out.push(cube::add(p, scale(cube::sub(q, p), t)));
        }
    }
    out
}

/// The largest `w · p` over the points `p` of the unit sphere within the convex spherical
/// polygon `poly` (vertices counter-clockwise seen from outside; any length; fewer than three:
/// a point or an arc). Rounding errs upwards.
fn max_dot(poly: &[Vec3], w: Vec3) -> f64 {
    let unit: Vec<Vec3> = poly.iter().map(|v| normalize(*v)).collect();
    let n = unit.len();
    let mut best = f64::NEG_INFINITY;
    for v in &unit {
        best = best.max(dot(*v, w));
    }
    // The edges' great circles (unit normals); edges shorter than rounding have none.
    let normals: Vec<Option<(Vec3, usize)>> = (0..n)
        .map(|i| {
            let m = cross(unit[i], unit[(i + 1) % n]);
            let mn = norm(m);
            (mn > 1e-14).then(|| (scale(m, 1.0 / mn), i))
        })
        .collect();
    // w inside a polygon with an area (three edges at least): the largest is w itself.
    let edges: Vec<(Vec3, usize)> = normals.into_iter().flatten().collect();
    if edges.len() >= 3 && edges.iter().all(|(m, _)| dot(*m, w) >= -1e-12) {
        return 1.0;
    }
    for (m, i) in edges {
        let (a, b) = (unit[i], unit[(i + 1) % n]);
        // The point of the edge's great circle nearest w, if it lies on the arc.
        let q = cube::sub(w, scale(m, dot(w, m)));
        let qn = norm(q);
        if qn < 1e-15 {
            continue;
        }
        let p = scale(q, 1.0 / qn);
        if dot(cross(a, p), m) >= -1e-12 && dot(cross(p, b), m) >= -1e-12 {
            best = best.max(qn);
        }
    }
    best
}

/// The centre and angular radius of a cap holding the convex spherical polygon `poly`.
fn bounding_cap(poly: &[Vec3]) -> (Vec3, f64) {
    let mut sum = [0.0; 3];
    for v in poly {
        sum = cube::add(sum, normalize(*v));
    }
    let c = normalize(sum);
    let r = poly
        .iter()
        .map(|v| cube::angle_between(normalize(*v), c))
        .fold(0.0, f64::max);
    (c, r)
}

fn orient(a: (f64, f64), b: (f64, f64), c: (f64, f64)) -> f64 {
    (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)
}

fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt()
}

/// Whether segments ab and cd meet, counting near misses (within `tol`) as meeting.
fn segments_meet(a: (f64, f64), b: (f64, f64), c: (f64, f64), d: (f64, f64), tol: f64) -> bool {
    let e_cd = tol * (dist(c, d) + tol);
    let e_ab = tol * (dist(a, b) + tol);
    let (d1, d2) = (orient(c, d, a), orient(c, d, b));
    let (d3, d4) = (orient(a, b, c), orient(a, b, d));
    if (d1 > e_cd && d2 > e_cd) || (d1 < -e_cd && d2 < -e_cd) {
        return false;
    }
    if (d3 > e_ab && d4 > e_ab) || (d3 < -e_ab && d4 < -e_ab) {
        return false;
    }
    if d1.abs() <= e_cd && d2.abs() <= e_cd && d3.abs() <= e_ab && d4.abs() <= e_ab {
        // Collinear: do their extents overlap?
        let overlap = |p: f64, q: f64, r: f64, s: f64| {
            p.min(q) <= r.max(s) + tol && r.min(s) <= p.max(q) + tol
        };
        return overlap(a.0, b.0, c.0, d.0) && overlap(a.1, b.1, c.1, d.1);
    }
    true
}

/// Even–odd point-in-polygon.
fn inside_even_odd(pts: &[(f64, f64)], p: (f64, f64)) -> bool {
    let mut inside = false;
    let n = pts.len();
    for i in 0..n {
        let (a, b) = (pts[i], pts[(i + 1) % n]);
        if (a.1 > p.1) != (b.1 > p.1) {
            let x = a.0 + (p.1 - a.1) / (b.1 - a.1) * (b.0 - a.0);
            if p.0 < x {
                inside = !inside;
            }
        }
    }
    inside
}

impl PlanarPolygon {
    fn meets(&self, tile: &[Vec3]) -> bool {
        // Cut the tile to the square cone about c that holds the polygon, then project it.
        let mut t = tile.to_vec();
        for n in [
            cube::sub(scale(self.c, self.rho), self.e1),
            cube::add(scale(self.c, self.rho), self.e1),
            cube::sub(scale(self.c, self.rho), self.e2),
            cube::add(scale(self.c, self.rho), self.e2),
        ] {
            t = clip(&t, n);
            if t.is_empty() {
                return false;
            }
        }
        let tp: Vec<(f64, f64)> = t
            .iter()
            .map(|v| {
                let z = dot(*v, self.c);
                (dot(*v, self.e1) / z, dot(*v, self.e2) / z)
            })
            .collect();
        let (np, nt) = (self.pts.len(), tp.len());
        for i in 0..nt {
            let (a, b) = (tp[i], tp[(i + 1) % nt]);
            for j in 0..np {
                if segments_meet(a, b, self.pts[j], self.pts[(j + 1) % np], self.tol) {
                    return true;
                }
            }
        }
        if inside_even_odd(&self.pts, tp[0]) {
            return true;
        }
        // The polygon inside the (convex, counter-clockwise) tile.
        let p = self.pts[0];
        nt >= 3 && (0..nt).all(|i| orient(tp[i], tp[(i + 1) % nt], p) >= -self.tol)
    }
}

impl Prepared {
    /// Whether the tile of corners `tile` meets the shape (conservatively).
    fn meets(&self, tile: &[Vec3; 4]) -> bool {
        match self {
            Prepared::Body => true,
            Prepared::Cap {
                centre,
                cos_r,
                angle,
            } => {
                let (c, r) = bounding_cap(tile);
                if cube::angle_between(c, *centre) > r + angle + MARGIN_RAD {
                    return false;
                }
                max_dot(tile, *centre) >= cos_r - 1e-15
            }
            Prepared::Box { z, wedges } => {
                let ez = [0.0, 0.0, 1.0];
                let meets_z = |poly: &[Vec3]| {
                    let top = max_dot(poly, ez);
                    let bottom = -max_dot(poly, scale(ez, -1.0));
                    top >= z.0 - 1e-15 && bottom <= z.1 + 1e-15
                };
                if wedges.is_empty() {
                    return meets_z(tile);
                }
                wedges.iter().any(|[a, b]| {
                    let t = clip(&clip(tile, *a), *b);
                    !t.is_empty() && meets_z(&t)
                })
            }
            Prepared::Polygon(p) => {
                let (c, r) = bounding_cap(tile);
                if cube::angle_between(c, p.c) > r + p.spread + 2.0 * MARGIN_RAD {
                    return false;
                }
                p.meets(tile)
            }
        }
    }
}

/// Every tile of `level` whose area (the halo does not count) meets `shape` on a body of
/// radius `radius_m`. Conservative (a tile within about 1e-9 rad of the shape may be
/// included); the whole body is all 6·4^level tiles. The walk refines only the tiles that
/// meet the shape, from level 0 down. Errors: a malformed shape (naming the field), a level
/// beyond the layout's finest.
pub fn tiles_touching(
    shape: &Shape,
    layout: &Layout,
    radius_m: f64,
    level: u8,
) -> Result<BTreeSet<TileId>> {
    if level >= layout.levels {
        return Err(Error::param(
            "level",
            format!(
                "{level} is beyond the layout's finest level {}",
                layout.levels.saturating_sub(1)
            ),
        ));
    }
    let prepared = shape.prepare(radius_m)?;
    let mut out = BTreeSet::new();
    let mut stack: Vec<TileId> = Face::ALL
        .iter()
        .rev()
        .map(|&face| TileId {
            level: 0,
            face,
            x: 0,
            y: 0,
        })
        .collect();
    while let Some(id) = stack.pop() {
        if !prepared.meets(&tile_corners(layout, id)) {
            continue;
        }
        if id.level == level {
            out.insert(id);
            continue;
        }
        for (dx, dy) in [(1, 1), (0, 1), (1, 0), (0, 0)] {
            stack.push(TileId {
                level: id.level + 1,
                face: id.face,
                x: id.x * 2 + dx,
                y: id.y * 2 + dy,
            });
        }
    }
    Ok(out)
}

/// `tiles` and every ancestor of each (the set closed under [`TileId::parent`]).
pub fn with_ancestors(tiles: &BTreeSet<TileId>) -> BTreeSet<TileId> {
    let mut out = BTreeSet::new();
    for t in tiles {
        let mut c = Some(*t);
        while let Some(id) = c {
            if !out.insert(id) {
                break;
            }
            c = id.parent();
        }
    }
    out
}

/// One position of a camera path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathPoint {
    /// Latitude (degrees, [−90, 90]).
    pub lat_deg: f64,
    /// Longitude (degrees, [−360, 360]).
    pub lon_deg: f64,
    /// Height above the reference sphere (m, [−20 km, 1e9 m]).
    pub height_m: f64,
}

/// Most rows of a camera path.
pub const MAX_PATH_POINTS: usize = 1_000_000;
/// Lowest and highest camera height (m above the reference sphere).
pub const PATH_HEIGHT_RANGE_M: (f64, f64) = (-20_000.0, 1e9);
/// Largest camera path file read by [`read_path_csv`].
pub const MAX_PATH_FILE_BYTES: u64 = 256 << 20;
/// The columns a camera path CSV starts with.
pub const PATH_COLUMNS: [&str; 3] = ["lat_deg", "lon_deg", "height_m"];

impl PathPoint {
    /// What is wrong with the point, naming the column; `None` when it is in range.
    fn problem(&self) -> Option<(&'static str, String)> {
        let checks = [
            (PATH_COLUMNS[0], self.lat_deg, (-90.0, 90.0)),
            (PATH_COLUMNS[1], self.lon_deg, (-360.0, 360.0)),
            (PATH_COLUMNS[2], self.height_m, PATH_HEIGHT_RANGE_M),
        ];
        for (col, v, (lo, hi)) in checks {
            if !v.is_finite() {
                return Some((col, format!("{v} is not a finite number")));
            }
            if !(lo..=hi).contains(&v) {
                return Some((col, format!("{v} is outside [{lo}, {hi}]")));
            }
        }
        None
    }
}

/// Parse a camera path: CSV text whose header starts with the columns `lat_deg,lon_deg,height_m`
/// (planetocentric degrees, metres above the reference sphere). Further columns (a time, a
/// velocity) may follow in the header; each row then has as many fields, and their values are
/// not read. Blank lines and lines starting with `#` are skipped; fields are trimmed. Errors
/// name the line (from 1) and the column: a missing or wrong header, a wrong field count, a
/// value that is not a finite number or out of range (latitude [−90, 90], longitude
/// [−360, 360], height [−20 km, 1e9 m]), no rows, more than 1,000,000 rows.
/// [`parse_path_poses`] reads the optional view columns as well.
pub fn parse_path_csv(text: &str) -> Result<Vec<PathPoint>> {
    parse_path(text)
        .map(points_of)
        .map_err(|m| Error::usage(format!("camera path: {m}")))
}

/// [`parse_path_csv`] of the file at `path` (a regular file of at most 256 MiB, UTF-8).
pub fn read_path_csv(path: &Path) -> Result<Vec<PathPoint>> {
    read_path_poses(path).map(points_of)
}

/// One row of a camera path with its optional view columns, for a viewer that flies it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathPose {
    pub point: PathPoint,
    /// The `heading_deg` column (compass degrees, [−360, 360]), where the header has it and
    /// the row's field is not empty.
    pub heading_deg: Option<f64>,
    /// The `pitch_deg` column (degrees above the horizontal, [−90, 90]; −90 looks straight
    /// down), likewise.
    pub pitch_deg: Option<f64>,
    /// The row's line in the text (from 1), for errors found later (a point inside the body).
    pub line: usize,
}

/// The optional view columns of a camera path that [`parse_path_poses`] reads, and their
/// ranges.
pub const PATH_VIEW_COLUMNS: [(&str, (f64, f64)); 2] = [
    ("heading_deg", (-360.0, 360.0)),
    ("pitch_deg", (-90.0, 90.0)),
];

/// [`parse_path_csv`] with the view columns: where the header has `heading_deg` and/or
/// `pitch_deg` (anywhere after the first three columns), each row's value is read (an empty
/// field means "not given"; anything else must be a finite number in range, or the error
/// names the line and the column), and every row keeps its line number.
pub fn parse_path_poses(text: &str) -> Result<Vec<PathPose>> {
    parse_path(text).map_err(|m| Error::usage(format!("camera path: {m}")))
}

/// [`parse_path_poses`] of the file at `path` (as [`read_path_csv`] reads it).
pub fn read_path_poses(path: &Path) -> Result<Vec<PathPose>> {
    let bytes = crate::fsio::read_capped(path, MAX_PATH_FILE_BYTES, "a camera path CSV")?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        Error::invalid(
            path,
            format!("not UTF-8 text ({e}): a camera path is a CSV text file"),
        )
    })?;
    parse_path(text).map_err(|m| Error::invalid(path, m))
}

fn points_of(rows: Vec<PathPose>) -> Vec<PathPoint> {
    rows.into_iter().map(|r| r.point).collect()
}

fn parse_path(text: &str) -> std::result::Result<Vec<PathPose>, String> {
    let mut header: Option<Vec<&str>> = None;
    let mut out = Vec::new();
    for (k, line) in text.split('\n').enumerate() {
        let ln = k + 1;
        let line = line.strip_suffix('\r').unwrap_or(line);
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = t.split(',').map(str::trim).collect();
        let Some(cols) = &header else {
            if fields.len() < 3 || fields[..3] != PATH_COLUMNS {
                return Err(format!(
                    "line {ln}: the header is '{t}'; it must start with the columns {}",
                    PATH_COLUMNS.join(",")
                ));
            }
            for (i, f) in fields.iter().enumerate() {
                if f.is_empty() {
                    return Err(format!("line {ln}: header column {} has no name", i + 1));
                }
                if fields[..i].contains(f) {
                    return Err(format!("line {ln}: header column '{f}' appears twice"));
                }
            }
            header = Some(fields);
            continue;
        };
        if fields.len() != cols.len() {
            return Err(format!(
                "line {ln}: {} fields where the header has {} ({})",
                fields.len(),
                cols.len(),
                cols.join(",")
            ));
        }
        if out.len() == MAX_PATH_POINTS {
            return Err(format!(
                "line {ln}: more than {MAX_PATH_POINTS} rows: thin the path"
            ));
        }
        let mut v = [0.0; 3];
        for (i, x) in v.iter_mut().enumerate() {
            *x = fields[i].parse::<f64>().map_err(|_| {
                format!(
                    "line {ln}, column {}: '{}' is not a number",
                    PATH_COLUMNS[i], fields[i]
                )
            })?;
        }
        let p = PathPoint {
            lat_deg: v[0],
            lon_deg: v[1],
            height_m: v[2],
        };
        if let Some((col, msg)) = p.problem() {
            return Err(format!("line {ln}, column {col}: {msg}"));
        }
        let mut view = [None; 2];
        for (slot, (name, (lo, hi))) in view.iter_mut().zip(PATH_VIEW_COLUMNS) {
            let Some(i) = cols.iter().position(|c| *c == name) else {
                continue;
            };
            if fields[i].is_empty() {
                continue;
            }
            let x = fields[i].parse::<f64>().map_err(|_| {
                format!("line {ln}, column {name}: '{}' is not a number", fields[i])
            })?;
            if !x.is_finite() {
                return Err(format!(
                    "line {ln}, column {name}: {x} is not a finite number"
                ));
            }
            if !(lo..=hi).contains(&x) {
                return Err(format!(
                    "line {ln}, column {name}: {x} is outside [{lo}, {hi}]"
                ));
            }
            *slot = Some(x);
        }
        out.push(PathPose {
            point: p,
            heading_deg: view[0],
            pitch_deg: view[1],
            line: ln,
        });
    }
    if header.is_none() {
        return Err(format!(
            "empty: the first line must be the header {}",
            PATH_COLUMNS.join(",")
        ));
    }
    if out.is_empty() {
        return Err("no rows after the header: a path needs at least one position".into());
    }
    Ok(out)
}

/// How a camera path is seen: the viewer's frame and texel rule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathView {
    /// Frame width and height (pixels).
    pub frame: (u32, u32),
    /// Vertical field of view (degrees, [1, 120]).
    pub fov_deg: f64,
    /// Refine while a texel spans more than this many pixels (the viewer's `max_texel_px`).
    pub max_texel_px: f64,
    /// Finest level drawn.
    pub max_level: u8,
}

/// Most camera positions [`path_tiles`] walks (path points and the positions between them).
pub const MAX_PATH_SAMPLES: usize = 4_000_000;

/// The tiles a viewer draws along a camera path, with their ancestors: the union over the
/// path's positions of [`Quadtree::select`] with an all-directions [`View`] (the camera may
/// look anywhere), the frame, field of view and texel rule of `view`, the viewer's near plane
/// ([`Quadtree::near_for`]) and no tile budget, then closed under parent.
///
/// The quadtree is the `layout` on a body of radius `radius_m` with terrain between
/// `terrain_m.0` and `terrain_m.1` (m above the reference sphere); `present` is a tileset's
/// coverage (tiles outside it are walked through, not drawn, and ancestors outside it are left
/// out) or `None` (every tile may exist: a plan before any tile is made).
///
/// Between consecutive points the camera moves along the great circle with its height
/// changing linearly, and is sampled every `max(h, d) / 5` metres, where h is its height above
/// the highest terrain where the step starts and d the distance at which a texel of
/// `max_level` spans `max_texel_px` (nearer than d every tile is at `max_level` already):
/// a step is at most a quarter of the height at either of its ends (docs/regions.md).
pub fn path_tiles(
    points: &[PathPoint],
    layout: &Layout,
    radius_m: f64,
    terrain_m: (f64, f64),
    view: &PathView,
    present: Option<&BTreeSet<TileId>>,
) -> Result<BTreeSet<TileId>> {
    if points.is_empty() {
        return Err(Error::param(
            "points",
            "a camera path needs at least one point",
        ));
    }
    for (k, p) in points.iter().enumerate() {
        if let Some((col, msg)) = p.problem() {
            return Err(Error::param("points", format!("[{k}].{col}: {msg}")));
        }
    }
    if !(radius_m.is_finite() && radius_m > 0.0) {
        return Err(Error::param(
            "radius_m",
            format!("{radius_m} is not a positive body radius (m)"),
        ));
    }
    let (lo, hi) = terrain_m;
    if !(lo.is_finite() && hi.is_finite() && lo <= hi && lo > -radius_m && hi < radius_m) {
        return Err(Error::param(
            "terrain_m",
            format!("({lo}, {hi}) is not a lowest and highest terrain height (m) on the body"),
        ));
    }
    let (w, h) = view.frame;
    if w == 0 || h == 0 || w > 65_536 || h > 65_536 {
        return Err(Error::param(
            "frame",
            format!("{w}×{h} is not a frame size (1 to 65536 pixels a side)"),
        ));
    }
    if !(view.fov_deg.is_finite() && (FOV_RANGE.0..=FOV_RANGE.1).contains(&view.fov_deg)) {
        return Err(Error::param(
            "fov_deg",
            format!(
                "{} is outside [{}, {}] degrees",
                view.fov_deg, FOV_RANGE.0, FOV_RANGE.1
            ),
        ));
    }
    if !(view.max_texel_px.is_finite() && view.max_texel_px > 0.0) {
        return Err(Error::param(
            "max_texel_px",
            format!("{} is not a positive number of pixels", view.max_texel_px),
        ));
    }
    if view.max_level >= layout.levels {
        return Err(Error::param(
            "max_level",
            format!(
                "{} is beyond the layout's finest level {}",
                view.max_level,
                layout.levels.saturating_sub(1)
            ),
        ));
    }
    let eyes = path_samples(points, layout, radius_m, hi, view)?;
    let tree = Quadtree::from_layout(*layout, radius_m, terrain_m, present.cloned());
    let params = LodParams {
        max_texel_px: view.max_texel_px,
        max_tiles: usize::MAX,
        min_level: 0,
        max_level: view.max_level,
    };
    let drawn = eyes
        .par_iter()
        .map(|eye| {
            let v = View {
                camera: Camera {
                    eye: *eye,
                    heading_deg: 0.0,
                    pitch_deg: -90.0,
                    fov_y_deg: view.fov_deg,
                },
                width: w,
                height: h,
                near: tree.near_for(*eye),
                all_directions: true,
            };
            tree.select(&v, &params)
                .into_iter()
                .map(|c| c.tile)
                .collect::<BTreeSet<TileId>>()
        })
        .reduce(BTreeSet::new, |mut a, b| {
            a.extend(b);
            a
        });
    let mut out = with_ancestors(&drawn);
    if let Some(p) = present {
        out.retain(|t| p.contains(t));
    }
    Ok(out)
}

/// The camera positions (body frame, m) [`path_tiles`] walks: every point, and between
/// consecutive points steps of `max(h, d) / 5` (see there).
fn path_samples(
    points: &[PathPoint],
    layout: &Layout,
    radius_m: f64,
    top_m: f64,
    view: &PathView,
) -> Result<Vec<Vec3>> {
    let px_per_rad = view.frame.1 as f64 / (2.0 * (view.fov_deg.to_radians() / 2.0).tan());
    let d_fine = layout.centre_pixel_m(view.max_level, radius_m) * px_per_rad / view.max_texel_px;
    let step_at = |height: f64| (height - top_m).max(d_fine) / 5.0;
    let eye = |d: Vec3, height: f64| scale(d, radius_m + height);
    let mut out = Vec::new();
    let too_many = || {
        Error::param(
            "points",
            format!(
                "the path needs more than {MAX_PATH_SAMPLES} camera positions at its steps \
                 (a fifth of the height above the terrain): shorten it or coarsen max_level"
            ),
        )
    };
    let first = points[0];
    out.push(eye(dir_deg(first.lat_deg, first.lon_deg), first.height_m));
    for pair in points.windows(2) {
        let (p, q) = (pair[0], pair[1]);
        let (a, b) = (dir_deg(p.lat_deg, p.lon_deg), dir_deg(q.lat_deg, q.lon_deg));
        let theta = cube::angle_between(a, b);
        let dh = q.height_m - p.height_m;
        // An upper bound of the segment's length in metres.
        let ground = theta * (radius_m + p.height_m.max(q.height_m)).max(0.0);
        let length = (ground * ground + dh * dh).sqrt();
        // Directions along the great circle (slerp); antipodal points have none: refuse.
        let sin_t = theta.sin();
        if theta > 1e-12 && sin_t < 1e-9 {
            return Err(Error::param(
                "points",
                format!(
                    "consecutive points ({}, {}) and ({}, {}) are antipodal: the great circle \
                     between them is not defined; add a point between them",
                    p.lat_deg, p.lon_deg, q.lat_deg, q.lon_deg
                ),
            ));
        }
        let at = |f: f64| -> Vec3 {
            let d = if theta <= 1e-12 {
                a
            } else {
                let (wa, wb) = (((1.0 - f) * theta).sin() / sin_t, (f * theta).sin() / sin_t);
                normalize(cube::add(scale(a, wa), scale(b, wb)))
            };
            eye(d, p.height_m + f * dh)
        };
        // Positions strictly between the two points (none for a zero-length segment).
        let mut f = 0.0;
        if length > 0.0 {
            loop {
                f += step_at(p.height_m + f * dh) / length;
                if f >= 1.0 {
                    break;
                }
                if out.len() >= MAX_PATH_SAMPLES {
                    return Err(too_many());
                }
                out.push(at(f));
            }
        }
        if out.len() >= MAX_PATH_SAMPLES {
            return Err(too_many());
        }
        out.push(eye(b, q.height_m));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cube::{Face, Projection};

    const R: f64 = 1_737_400.0;

    fn layout(projection: Projection, levels: u8) -> Layout {
        Layout {
            projection,
            tile_size: 64,
            halo: 2,
            levels,
        }
    }

    fn all_tiles(level: u8) -> Vec<TileId> {
        let k = 1u32 << level;
        let mut v = Vec::new();
        for face in Face::ALL {
            for y in 0..k {
                for x in 0..k {
                    v.push(TileId { level, face, x, y });
                }
            }
        }
        v
    }

    /// Whether some of `m`×`m` points spread over `id`'s area satisfies `inside`.
    fn sampled_hit(lay: &Layout, id: TileId, m: u32, inside: &dyn Fn(Vec3) -> bool) -> bool {
        let k = lay.tiles_per_side(id.level) as f64;
        for j in 0..m {
            for i in 0..m {
                let s = -1.0 + 2.0 * (id.x as f64 + (i as f64 + 0.5) / m as f64) / k;
                let t = 1.0 - 2.0 * (id.y as f64 + (j as f64 + 0.5) / m as f64) / k;
                if inside(lay.st_to_dir(id.face, s, t)) {
                    return true;
                }
            }
        }
        false
    }

    /// Checks `tiles_touching` against sampling of every tile of `level`: no tile a sample
    /// finds inside may be missing, and every tile chosen that no sample of a 256×256 grid
    /// finds inside (a conservative extra: the shape meets it in a sliver or a point, or only
    /// comes near) must lie next to a tile that one does. Returns the counts of both.
    fn against_sampling(
        shape: &Shape,
        lay: &Layout,
        level: u8,
        inside: &dyn Fn(Vec3) -> bool,
    ) -> (usize, usize) {
        let got = tiles_touching(shape, lay, R, level).unwrap();
        let mut hit = Vec::new();
        for id in all_tiles(level) {
            if sampled_hit(lay, id, 12, inside) {
                hit.push(id);
                assert!(got.contains(&id), "{shape:?} L{level}: {id} missed");
            }
        }
        let centre = |id: TileId| bounding_cap(&tile_corners(lay, id)).0;
        // Centres of neighbouring tiles are less than two tile diagonals apart.
        let near = 2.0 * 2f64.sqrt() * std::f64::consts::FRAC_PI_2 / (1u32 << level) as f64;
        let mut extra = 0;
        for id in &got {
            if sampled_hit(lay, *id, 12, inside) || sampled_hit(lay, *id, 256, inside) {
                continue;
            }
            extra += 1;
            let c = centre(*id);
            assert!(
                hit.iter()
                    .any(|h| cube::angle_between(centre(*h), c) < near),
                "{shape:?} L{level}: {id} is not next to the shape"
            );
        }
        (hit.len(), extra)
    }

    fn latlon_deg(d: Vec3) -> (f64, f64) {
        let (lat, lon) = cube::dir_to_latlon(d);
        (lat.to_degrees(), lon.to_degrees())
    }

    #[test]
    fn the_whole_body_is_every_tile() {
        let lay = layout(Projection::Gnomonic, 5);
        for level in 0..5 {
            let got = tiles_touching(&Shape::Body, &lay, R, level).unwrap();
            assert_eq!(got.len(), 6 << (2 * level));
            assert_eq!(got, all_tiles(level).into_iter().collect());
        }
        // A cap of half the circumference is the body too.
        let cap = Shape::Cap {
            lat_deg: 10.0,
            lon_deg: 20.0,
            radius_m: std::f64::consts::PI * R,
        };
        assert_eq!(tiles_touching(&cap, &lay, R, 2).unwrap().len(), 96);
    }

    #[test]
    fn caps_match_sampling() {
        for projection in [Projection::Gnomonic, Projection::EqualAngle] {
            let lay = layout(projection, 5);
            // The equator, a cube corner (35.26°N, 45°E), a face edge, the antimeridian, large
            // and small.
            for (lat, lon, r) in [
                (0.0, 0.0, 300_000.0),
                (35.264, 45.0, 500_000.0),
                (0.0, 45.0, 120_000.0),
                (-20.0, 180.0, 900_000.0),
                (60.0, -100.0, 2_500_000.0),
                (-75.0, 10.0, 150_000.0),
            ] {
                let shape = Shape::Cap {
                    lat_deg: lat,
                    lon_deg: lon,
                    radius_m: r,
                };
                let c = dir_deg(lat, lon);
                let inside = |d: Vec3| cube::angle_between(d, c) * R <= r;
                for level in [1, 3, 4] {
                    let (hits, extra) = against_sampling(&shape, &lay, level, &inside);
                    assert!(hits > 0);
                    assert!(
                        extra <= 8.max(hits / 20),
                        "{shape:?} L{level}: {extra} extra of {hits}"
                    );
                    eprintln!("{shape:?} L{level}: {hits} tiles hit, {extra} extra");
                }
            }
        }
    }

    /// The analytic answer for a cap about the south pole, the centre of face −Z: a tile of
    /// gnomonic plane extent [u0, u1]×[v0, v1] meets it when its point nearest the face
    /// centre is within the cap's angle: atan(|(u, v)|) ≤ r / R.
    fn polar_cap_tiles(lay: &Layout, level: u8, radius_m: f64) -> BTreeSet<TileId> {
        let k = lay.tiles_per_side(level);
        let angle = radius_m / R;
        // Only tiles of −Z within a square of half-width tan(angle) about the centre.
        let span = |e: f64| lay.projection.u_to_s(e);
        let reach = angle.tan();
        let lo = (((span(-reach) + 1.0) / 2.0 * k as f64).floor() as u32).saturating_sub(1);
        let hi = ((((span(reach) + 1.0) / 2.0 * k as f64).ceil() as u32) + 1).min(k);
        let mut out = BTreeSet::new();
        for y in lo..hi {
            for x in lo..hi {
                let u = |i: u32| lay.projection.s_to_u(-1.0 + 2.0 * i as f64 / k as f64);
                let (u0, u1) = (u(x), u(x + 1));
                // Rows run from +V down.
                let v = |j: u32| lay.projection.s_to_u(1.0 - 2.0 * j as f64 / k as f64);
                let (v1, v0) = (v(y), v(y + 1));
                let nu = 0.0f64.clamp(u0, u1);
                let nv = 0.0f64.clamp(v0, v1);
                if (nu * nu + nv * nv).sqrt().atan() <= angle {
                    out.insert(TileId {
                        level,
                        face: Face::Nz,
                        x,
                        y,
                    });
                }
            }
        }
        out
    }

    #[test]
    fn a_cap_at_the_pole_is_the_analytic_set() {
        for projection in [Projection::Gnomonic, Projection::EqualAngle] {
            let lay = layout(projection, 15);
            // Radii chosen away from tile edges (the known answer has no margin).
            for (level, r) in [
                (1, 700_000.0),
                (3, 333_333.0),
                (6, 123_457.0),
                (12, 5_000.0),
                (14, 5_000.0),
            ] {
                let cap = Shape::Cap {
                    lat_deg: -90.0,
                    lon_deg: 0.0,
                    radius_m: r,
                };
                let got = tiles_touching(&cap, &lay, R, level).unwrap();
                let want = polar_cap_tiles(&lay, level, r);
                assert!(!want.is_empty());
                assert_eq!(got, want, "{projection:?} L{level} r {r}");
                // The pole sits on the corner of four tiles: the set has the square's symmetry.
                let k = lay.tiles_per_side(level);
                for t in &got {
                    let turned = TileId {
                        x: t.y,
                        y: k - 1 - t.x,
                        ..*t
                    };
                    assert!(got.contains(&turned), "{t}");
                }
            }
        }
    }

    #[test]
    fn boxes_match_sampling_and_wrap_across_the_antimeridian() {
        let lay = layout(Projection::Gnomonic, 5);
        let in_box = |lat: (f64, f64), lon: (f64, f64)| {
            move |d: Vec3| {
                let (la, lo) = latlon_deg(d);
                let mut width = lon.1 - lon.0;
                if width < 0.0 {
                    width += 360.0;
                }
                let east = (lo - lon.0).rem_euclid(360.0);
                la >= lat.0 && la <= lat.1 && (width >= 360.0 || east <= width)
            }
        };
        for (lat, lon) in [
            ((-10.0, 10.0), (170.0, -170.0)),
            ((-90.0, -80.0), (0.0, 90.0)),
            ((-89.0, -60.0), (-30.0, 250.0)),
            ((20.0, 50.0), (-180.0, 180.0)),
            ((30.0, 40.0), (100.0, 110.0)),
            ((-5.0, 75.0), (40.0, 50.0)),
        ] {
            let shape = Shape::LatLonBox { lat, lon };
            for level in [2, 3, 4] {
                let (hits, extra) = against_sampling(&shape, &lay, level, &in_box(lat, lon));
                assert!(hits > 0);
                assert!(
                    extra <= 8.max(hits / 20),
                    "{shape:?} L{level}: {extra} extra of {hits}"
                );
                eprintln!("{shape:?} L{level}: {hits} tiles hit, {extra} extra");
            }
        }
        // Across ±180°: the same as the two halves, and as the box written past 180°.
        let lay = layout(Projection::Gnomonic, 8);
        let level = 6;
        let across = |lon| {
            tiles_touching(
                &Shape::LatLonBox {
                    lat: (-10.0, 10.0),
                    lon,
                },
                &lay,
                R,
                level,
            )
            .unwrap()
        };
        let wrapped = across((170.0, -170.0));
        assert_eq!(wrapped, across((170.0, 190.0)));
        let mut halves = across((170.0, 180.0));
        halves.extend(across((-180.0, -170.0)));
        assert_eq!(wrapped, halves);
        // The other way round is the rest of the band, sharing only the two edge columns.
        let rest = across((-170.0, 170.0));
        let band = across((-180.0, 180.0));
        let union: BTreeSet<_> = rest.union(&wrapped).copied().collect();
        assert_eq!(union, band);
    }

    /// Winding number of the spherical polygon about `q` (sum of the angles its edges subtend
    /// at q): ±2π inside, 0 outside.
    fn winding(poly: &[Vec3], q: Vec3) -> f64 {
        let n = poly.len();
        (0..n)
            .map(|i| {
                let (a, b) = (poly[i], poly[(i + 1) % n]);
                let ta = cube::sub(a, scale(q, dot(a, q)));
                let tb = cube::sub(b, scale(q, dot(b, q)));
                dot(q, cross(ta, tb)).atan2(dot(ta, tb))
            })
            .sum()
    }

    #[test]
    fn concave_polygons_match_point_in_polygon_sampling() {
        let lay = layout(Projection::Gnomonic, 5);
        // A "C" round the south pole (55°S to 75°S, 260° of longitude, over five faces) and a
        // "U" across the
        // antimeridian at the equator.
        let mut c_shape: Vec<(f64, f64)> =
            (0..=26).map(|k| (-55.0, -60.0 + 10.0 * k as f64)).collect();
        c_shape.extend((0..=26).rev().map(|k| (-75.0, -60.0 + 10.0 * k as f64)));
        let u_shape = vec![
            (-20.0, 160.0),
            (25.0, 160.0),
            (25.0, 172.0),
            (-8.0, 172.0),
            (-8.0, -168.0),
            (25.0, -168.0),
            (25.0, -155.0),
            (-20.0, -155.0),
        ];
        for vertices in [c_shape, u_shape] {
            let dirs: Vec<Vec3> = vertices.iter().map(|&(la, lo)| dir_deg(la, lo)).collect();
            // The winding number also counts the antipode of a point inside; the polygon lies
            // within 89° of its mean direction.
            let mean = normalize(dirs.iter().fold([0.0; 3], |a, d| cube::add(a, *d)));
            let inside =
                |d: Vec3| dot(d, mean) > 0.0 && winding(&dirs, d).abs() > std::f64::consts::PI;
            let shape = Shape::Polygon {
                vertices: vertices.clone(),
            };
            let mut total = (0, 0);
            for level in [2, 3, 4] {
                let (hits, extra) = against_sampling(&shape, &lay, level, &inside);
                assert!(hits > 0);
                assert!(
                    extra <= 8.max(hits / 20),
                    "L{level}: {extra} extra of {hits}"
                );
                total = (total.0 + hits, total.1 + extra);
            }
            // The hole of the C (or the notch of the U) holds tiles the polygon misses.
            let notches = if vertices[0].0 < -40.0 {
                // The gap of the C, and its middle (the pole).
                vec![dir_deg(-65.0, -110.0), dir_deg(-89.0, 0.0)]
            } else {
                vec![dir_deg(15.0, -178.0)]
            };
            let l4 = tiles_touching(&shape, &lay, R, 4).unwrap();
            for notch in notches {
                assert!(!inside(notch));
                assert!(!l4.contains(&lay.locate(4, notch).tile));
            }
            eprintln!(
                "polygon {:?}: {} tiles hit, {} extra",
                vertices[0], total.0, total.1
            );
        }
    }

    #[test]
    fn a_small_cap_at_a_fine_level_is_quick_and_bad_shapes_are_refused() {
        let lay = layout(Projection::Gnomonic, 20);
        let cap = Shape::Cap {
            lat_deg: -89.5,
            lon_deg: 45.0,
            radius_m: 5_000.0,
        };
        let got = tiles_touching(&cap, &lay, R, 19).unwrap();
        // About π·5000² / (tile side)² tiles.
        let side = lay.centre_pixel_m(19, R) * 64.0;
        let area = std::f64::consts::PI * 5000.0f64.powi(2) / (side * side);
        assert!((got.len() as f64) > area && (got.len() as f64) < 2.0 * area + 100.0);
        for (shape, field) in [
            (
                Shape::LatLonBox {
                    lat: (10.0, -10.0),
                    lon: (0.0, 1.0),
                },
                "lat",
            ),
            (
                Shape::LatLonBox {
                    lat: (0.0, 1.0),
                    lon: (0.0, 400.0),
                },
                "lon",
            ),
            (
                Shape::Cap {
                    lat_deg: 91.0,
                    lon_deg: 0.0,
                    radius_m: 1.0,
                },
                "lat_deg",
            ),
            (
                Shape::Cap {
                    lat_deg: 0.0,
                    lon_deg: 0.0,
                    radius_m: f64::NAN,
                },
                "radius_m",
            ),
            (
                Shape::Polygon {
                    vertices: vec![(0.0, 0.0), (1.0, 1.0)],
                },
                "vertices",
            ),
            (
                Shape::Polygon {
                    vertices: vec![(0.0, 0.0), (0.0, 120.0), (0.0, 240.0)],
                },
                "vertices",
            ),
        ] {
            let e = tiles_touching(&shape, &lay, R, 3).unwrap_err().to_string();
            assert!(e.starts_with(field), "{shape:?}: {e}");
        }
        let e = tiles_touching(&Shape::Body, &lay, R, 20)
            .unwrap_err()
            .to_string();
        assert!(e.contains("level 20") || e.starts_with("level"), "{e}");
    }

    #[test]
    fn path_csv_parses_and_errors_name_line_and_column() {
        let text = "# a descent\nlat_deg, lon_deg, height_m, time_s\r\n-89.0,10,1000,0\n\n-89.5,-350,0.5,12\n";
        let p = parse_path_csv(text).unwrap();
        assert_eq!(
            p,
            vec![
                PathPoint {
                    lat_deg: -89.0,
                    lon_deg: 10.0,
                    height_m: 1000.0
                },
                PathPoint {
                    lat_deg: -89.5,
                    lon_deg: -350.0,
                    height_m: 0.5
                }
            ]
        );
        for (text, want) in [
            ("", "header"),
            ("lat,lon,h\n1,2,3\n", "line 1: the header"),
            ("lat_deg,lon_deg,height_m\n", "no rows"),
            ("lat_deg,lon_deg,height_m\n1,2\n", "line 2: 2 fields"),
            (
                "lat_deg,lon_deg,height_m\n1,2,x\n",
                "line 2, column height_m",
            ),
            (
                "lat_deg,lon_deg,height_m\n1,2,3\n91,2,3\n",
                "line 3, column lat_deg",
            ),
            ("lat_deg,lon_deg,height_m\n1,-361,3\n", "column lon_deg"),
            ("lat_deg,lon_deg,height_m\n1,2,NaN\n", "column height_m"),
            ("lat_deg,lon_deg,height_m\n1,2,-20001\n", "column height_m"),
            ("lat_deg,lon_deg,height_m\n1,2,2e9\n", "column height_m"),
            ("lat_deg,lon_deg,height_m,lat_deg\n", "appears twice"),
        ] {
            let e = parse_path_csv(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
        let mut big = String::from("lat_deg,lon_deg,height_m\n");
        for _ in 0..=MAX_PATH_POINTS {
            big.push_str("0,0,0\n");
        }
        let e = parse_path_csv(&big).unwrap_err().to_string();
        assert!(e.contains("more than 1000000 rows"), "{e}");
        // From a file, the error names the file.
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("path.csv");
        std::fs::write(&f, "lat_deg,lon_deg,height_m\n1,2,x\n").unwrap();
        let e = read_path_csv(&f).unwrap_err().to_string();
        assert!(e.contains("path.csv") && e.contains("line 2"), "{e}");
        std::fs::write(&f, "lat_deg,lon_deg,height_m\n-89,0,100\n").unwrap();
        assert_eq!(read_path_csv(&f).unwrap().len(), 1);
    }

    #[test]
    fn path_poses_read_the_view_columns_and_keep_line_numbers() {
        let text = "lat_deg,lon_deg,height_m,time_s,pitch_deg,heading_deg\n\
                    # first\n-89,0,100,0,-30,45\n\n-89.1,0,90,1,,\n";
        let p = parse_path_poses(text).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(
            (p[0].line, p[0].heading_deg, p[0].pitch_deg),
            (3, Some(45.0), Some(-30.0))
        );
        assert_eq!(
            (p[1].line, p[1].heading_deg, p[1].pitch_deg),
            (5, None, None)
        );
        assert_eq!(p[1].point.height_m, 90.0);
        // The same rows as parse_path_csv reads.
        let points: Vec<PathPoint> = p.iter().map(|r| r.point).collect();
        assert_eq!(points, parse_path_csv(text).unwrap());
        for (text, want) in [
            (
                "lat_deg,lon_deg,height_m,pitch_deg\n1,2,3,-91\n",
                "line 2, column pitch_deg",
            ),
            (
                "lat_deg,lon_deg,height_m,heading_deg\n1,2,3,inf\n",
                "column heading_deg",
            ),
            (
                "lat_deg,lon_deg,height_m,heading_deg\n1,2,3,x\n",
                "'x' is not a number",
            ),
        ] {
            let e = parse_path_poses(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    fn view_of(max_level: u8) -> PathView {
        PathView {
            frame: (512, 384),
            fov_deg: 45.0,
            max_texel_px: 1.0,
            max_level,
        }
    }

    #[test]
    fn the_viewer_frustum_tiles_are_in_the_path_tiles_of_its_eye() {
        let lay = Layout {
            projection: Projection::Gnomonic,
            tile_size: 128,
            halo: 2,
            levels: 10,
        };
        let terrain = (-3000.0, 2000.0);
        // A coverage like a small DEM's: the tiles of a 40 km cap, at every level.
        let patch = Shape::Cap {
            lat_deg: -89.6,
            lon_deg: 20.0,
            radius_m: 40_000.0,
        };
        let mut coverage = BTreeSet::new();
        for level in 0..lay.levels {
            coverage.extend(tiles_touching(&patch, &lay, R, level).unwrap());
        }
        // The viewer's test camera, its default global camera, a grazing low one, a high
        // oblique one; the viewer's frame, field of view and texel rule.
        let cameras = [
            (-89.8, 30.0, 9000.0, 210.0, -60.0, 50.0),
            (0.0, 0.0, 2.2 * R, 0.0, -90.0, 45.0),
            (-89.7, 0.0, 2500.0, 90.0, 5.0, 60.0),
            (-87.0, 200.0, 150_000.0, 20.0, -20.0, 30.0),
        ];
        for present in [None, Some(&coverage)] {
            let tree = Quadtree::from_layout(lay, R, terrain, present.cloned());
            for (lat, lon, alt, heading, pitch, fov) in cameras {
                let camera = Camera::at(R, lat, lon, alt, heading, pitch, fov);
                let pv = PathView {
                    fov_deg: fov,
                    ..view_of(9)
                };
                let point = PathPoint {
                    lat_deg: lat,
                    lon_deg: lon,
                    height_m: alt,
                };
                let planned = path_tiles(&[point], &lay, R, terrain, &pv, present).unwrap();
                let v = View {
                    camera,
                    width: pv.frame.0,
                    height: pv.frame.1,
                    near: tree.near_for(camera.eye),
                    all_directions: false,
                };
                let mut drawn = 0;
                for max_tiles in [96, usize::MAX] {
                    let p = LodParams {
                        max_texel_px: pv.max_texel_px,
                        max_tiles,
                        min_level: 0,
                        max_level: pv.max_level,
                    };
                    for c in tree.select(&v, &p) {
                        assert!(planned.contains(&c.tile), "{lat} {lon} {alt}: {}", c.tile);
                        drawn += 1;
                    }
                }
                assert!(drawn > 0 || present.is_some(), "{lat} {lon} {alt}");
                assert!(planned == with_ancestors(&planned) || present.is_some());
            }
        }
    }

    #[test]
    fn the_path_steps_miss_few_tiles_of_a_denser_path() {
        let lay = Layout {
            projection: Projection::Gnomonic,
            tile_size: 128,
            halo: 2,
            levels: 10,
        };
        let terrain = (-3000.0, 2000.0);
        let view = view_of(9);
        // A low traverse, then a descent.
        let path = [
            PathPoint {
                lat_deg: -86.0,
                lon_deg: 0.0,
                height_m: 6_000.0,
            },
            PathPoint {
                lat_deg: -88.5,
                lon_deg: 60.0,
                height_m: 3_000.0,
            },
            PathPoint {
                lat_deg: -88.6,
                lon_deg: 62.0,
                height_m: 0.0,
            },
        ];
        let sparse = path_tiles(&path, &lay, R, terrain, &view, None).unwrap();
        // The same path with eight times the positions (the points as path_tiles samples it,
        // each step cut in eight).
        let eyes = path_samples(&path, &lay, R, terrain.1, &view).unwrap();
        let mut dense_points = Vec::new();
        for w in eyes.windows(2) {
            for k in 0..8 {
                let f = k as f64 / 8.0;
                let e = cube::add(scale(w[0], 1.0 - f), scale(w[1], f));
                let (lat, lon) = latlon_deg(normalize(e));
                // Heights from the interpolated radius of the two samples.
                let h = (1.0 - f) * norm(w[0]) + f * norm(w[1]) - R;
                dense_points.push(PathPoint {
                    lat_deg: lat,
                    lon_deg: lon,
                    height_m: h,
                });
            }
        }
        dense_points.push(path[2]);
        let dense = path_tiles(&dense_points, &lay, R, terrain, &view, None).unwrap();
        let missed = dense.difference(&sparse).count();
        eprintln!(
            "{} positions: {} tiles; {} positions: {} tiles, {missed} not in the first",
            eyes.len(),
            sparse.len(),
            dense_points.len(),
            dense.len()
        );
        assert!(
            (missed as f64) <= 0.01 * sparse.len() as f64,
            "{missed} of {} missed",
            dense.len()
        );
        // The step: at most a quarter of the height above the terrain at either end (or of
        // the distance where the finest level saturates).
        let d_fine = lay.centre_pixel_m(9, R) * 384.0 / (2.0 * 22.5f64.to_radians().tan());
        for w in eyes.windows(2) {
            let h = |e: Vec3| (norm(e) - R - terrain.1).max(d_fine);
            let step = norm(cube::sub(w[1], w[0]));
            assert!(step <= h(w[0]).max(h(w[1])) / 4.0 + 1e-6, "{step}");
        }
    }

    #[test]
    fn bad_paths_are_refused() {
        let lay = layout(Projection::Gnomonic, 8);
        let p = PathPoint {
            lat_deg: 0.0,
            lon_deg: 0.0,
            height_m: 1000.0,
        };
        let t = (-100.0, 100.0);
        let v = view_of(5);
        let err = |points: &[PathPoint], terrain, view: &PathView| {
            path_tiles(points, &lay, R, terrain, view, None)
                .unwrap_err()
                .to_string()
        };
        assert!(err(&[], t, &v).starts_with("points"));
        let bad = PathPoint { lat_deg: 95.0, ..p };
        assert!(err(&[p, bad], t, &v).contains("[1].lat_deg"));
        assert!(err(&[p], (100.0, -100.0), &v).starts_with("terrain_m"));
        assert!(err(
            &[p],
            t,
            &PathView {
                frame: (0, 10),
                ..v
            }
        )
        .starts_with("frame"));
        assert!(err(
            &[p],
            t,
            &PathView {
                fov_deg: 170.0,
                ..v
            }
        )
        .starts_with("fov_deg"));
        assert!(err(
            &[p],
            t,
            &PathView {
                max_texel_px: 0.0,
                ..v
            }
        )
        .starts_with("max_texel_px"));
        assert!(err(&[p], t, &PathView { max_level: 8, ..v }).starts_with("max_level"));
        let anti = PathPoint {
            lat_deg: 0.0,
            lon_deg: 180.0,
            height_m: 1000.0,
        };
        assert!(err(&[p, anti], t, &v).contains("antipodal"));
    }

    /// The numbers of docs/regions.md ("Cost"): run with
    /// `cargo test --release -p penumbra --lib -- --ignored region_costs --nocapture`.
    #[test]
    #[ignore = "a measurement: prints timings, asserts nothing about them"]
    fn region_costs() {
        let per_level = |s: &BTreeSet<TileId>| {
            let mut n = std::collections::BTreeMap::new();
            for t in s {
                *n.entry(t.level).or_insert(0usize) += 1;
            }
            n
        };
        let lay = Layout {
            projection: Projection::Gnomonic,
            tile_size: 512,
            halo: 8,
            levels: 15,
        };
        let cap = Shape::Cap {
            lat_deg: -89.5,
            lon_deg: 45.0,
            radius_m: 5_000.0,
        };
        let t = std::time::Instant::now();
        let got = tiles_touching(&cap, &lay, R, 14).unwrap();
        eprintln!(
            "tiles_touching 5 km cap at level 14: {} tiles in {:.3} ms",
            got.len(),
            t.elapsed().as_secs_f64() * 1e3
        );
        let lay = Layout { levels: 13, ..lay };
        // A descent over the south pole: 1000 points from 84°S, 100 km up, to 89.9°S on the
        // ground (height falling as the square of the remaining way).
        let points: Vec<PathPoint> = (0..1000)
            .map(|k| {
                let f = k as f64 / 999.0;
                PathPoint {
                    lat_deg: -84.0 - 5.9 * f,
                    lon_deg: 0.0,
                    height_m: 100_000.0 * (1.0 - f) * (1.0 - f),
                }
            })
            .collect();
        let view = PathView {
            frame: (1920, 1080),
            fov_deg: 60.0,
            max_texel_px: 1.0,
            max_level: 12,
        };
        let terrain = (-9_200.0, 10_800.0);
        let t = std::time::Instant::now();
        let eyes = path_samples(&points, &lay, R, terrain.1, &view).unwrap();
        let tiles = path_tiles(&points, &lay, R, terrain, &view, None).unwrap();
        eprintln!(
            "path_tiles 1000-point descent, 1920×1080, 60°, 1 texel/px, max level 12: {} \
             positions, {} tiles in {:.3} s ({} threads); per level {:?}",
            eyes.len(),
            tiles.len(),
            t.elapsed().as_secs_f64(),
            rayon::current_num_threads(),
            per_level(&tiles)
        );
        let t = std::time::Instant::now();
        let one = path_tiles(&points[999..], &lay, R, terrain, &view, None).unwrap();
        eprintln!(
            "the last point alone: {} tiles in {:.1} ms; per level {:?}",
            one.len(),
            t.elapsed().as_secs_f64() * 1e3,
            per_level(&one)
        );
    }
}
