//! Sun visibility from a horizon: the lit fraction of the sun's disc seen from a surface point.
//!
//! # Conventions
//! - Directions are unit [`Vec3`]s in the body-fixed frame. A surface point is the gnomonic
//!   plane point (u, v) of a cube face; its up vector is p = normalize(n + u·U + v·V) with the
//!   face's (n, U, V) from [`Face::axes`]. Any finite (u, v) works, past the face edges too.
//! - Horizons are functions of the **plane azimuth** φ (radians, counter-clockwise from the
//!   face's +U axis towards +V in the face's gnomonic plane; docs/horizons.md) returning the
//!   horizon's **elevation in degrees** above the local horizontal (the plane perpendicular to
//!   p). [`Frame::plane_azimuth`] maps a direction to φ with the formula of docs/horizons.md.
//! - Compass azimuths are degrees clockwise from local north: north is +Z projected onto the
//!   tangent plane (at the poles the limit along the 0° meridian: −X at the north pole, +X at
//!   the south pole) and east = north × up, as in [`crate::horizon::compass_azimuth_deg`].
//! - The sun is a uniform disc of angular radius r around its centre direction s. Its *disc
//!   frame* is e_h (horizontal, perpendicular to the sun's vertical plane: normalize(s × up),
//!   to the right when facing the sun; the frame's east when the sun is at the zenith or nadir,
//!   where that plane is undefined) and e_v = e_h × s (perpendicular to s in the vertical plane,
//!   pointing up). Disc coordinates (x, y) are in units of the radius, x along e_h, y along e_v.
//!   The lit fraction is the part of the disc's area **above** the horizon, in [0, 1].
//!
//! # Models (Fritsch et al. 2025, "Fast planetary shadows using Fourier-compressed horizon maps")
//! - [`Model::Constant`] (Max 1988, the paper's default): the horizon at the sun centre's own
//!   azimuth, α, held constant across the disc: lit = [`segment_fraction`]((α − el)/r).
//! - [`Model::Segment`]: the horizon linear across the disc between its values at the disc's
//!   left and right extremes (the directions at angular offset ±r along e_h). At each extreme the
//!   horizon crosses the disc's vertical at y = (α − el)/r, with the extreme's own elevation
//!   (which near the zenith is below the centre's); the lit part is the disc above the chord line
//!   through the two crossings, a circular segment.
//! - [`Model::Slices`]: 8 vertical strips of equal width across the disc; in each the horizon is
//!   taken at the strip's midpoint (on the disc's horizontal diameter) and held constant across
//!   the strip, and the strip's lit part is the **exact area** of the strip above that level
//!   (closed form, [`strip_area_above`]), so the strips' areas sum to the disc's exactly.
//! - [`Model::Exact`]: the reference. 256 vertical strips of exact area; in each, the boundary
//!   between sky and terrain is located on true 3-D directions along the strip's middle vertical
//!   by bisection (each sample direction's own elevation against the horizon at its own plane
//!   azimuth), assuming one crossing per strip, and the strip's exact area above (or below) it is
//!   lit. Directions are parametrised on the disc's gnomonic tangent plane,
//!   d = normalize(s + R·x·e_h + R·y·e_v) with R = tan r, where the unit circle is exactly the
//!   disc's rim; areas are taken in that plane (they differ from solid angles by O(r²), ≈ 2e-5
//!   for the Sun seen from 1 AU).
//!
//! A radius of 0 is a point sun for every model: 1 above the horizon, 0 below, ½ exactly on it.
//! Radii are clamped to [0°, 60°]. Horizon values are clamped to [−90°, 90°]. The result is
//! clamped to [0, 1] and is never NaN, except that a horizon returning NaN (no data) at any
//! azimuth a model evaluates makes the result NaN.

use crate::cube::{dot, Face, Vec3};
use serde::Serialize;
use std::f64::consts::{PI, TAU};
use std::fmt;
use std::str::FromStr;

/// The local frame at a surface point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub face: Face,
    /// Gnomonic plane coordinates of the point on `face`.
    pub u: f64,
    pub v: f64,
    /// Unit up vector (the point's direction from the body centre).
    pub up: Vec3,
    /// Unit local north (tangent); at the poles the limit along the 0° meridian.
    pub north: Vec3,
    /// Unit local east = north × up.
    pub east: Vec3,
    /// The face's normal and gnomonic plane axes.
    pub n: Vec3,
    pub ua: Vec3,
    pub va: Vec3,
}

impl Frame {
    /// The frame at gnomonic point (u, v) of `face`.
    pub fn at(face: Face, u: f64, v: f64) -> Frame {
        let (n, ua, va) = face.axes();
        let up = normalize(add(n, add(scale(ua, u), scale(va, v))));
        // North as in horizon::compass_azimuth_deg, so that the two agree exactly.
        let kz = up[2];
        let mut north = [-kz * up[0], -kz * up[1], 1.0 - kz * up[2]];
        if dot(north, north) < 1e-24 {
            north = if up[2] > 0.0 {
                [-1.0, 0.0, 0.0]
            } else {
                [1.0, 0.0, 0.0]
            };
        }
        let north = normalize(north);
        let east = cross(north, up);
        Frame {
            face,
            u,
            v,
            up,
            north,
            east,
            n,
            ua,
            va,
        }
    }

    /// Plane azimuth (radians, in [0, 2π)) of a direction's tangent component (docs/horizons.md,
    /// "From a direction to a plane azimuth"). Only the tangent component of `d` matters; a
    /// direction along ±up (no tangent component) gets 0.
    pub fn plane_azimuth(&self, d: Vec3) -> f64 {
        let (np, nt) = (dot(self.n, self.up), dot(self.n, d));
        let x = dot(self.ua, d) * np - dot(self.ua, self.up) * nt;
        let y = dot(self.va, d) * np - dot(self.va, self.up) * nt;
        wrap_tau(y.atan2(x))
    }

    /// Unit direction of compass azimuth (degrees clockwise from north) and elevation (degrees
    /// above the local horizontal).
    pub fn direction(&self, azimuth_deg: f64, elevation_deg: f64) -> Vec3 {
        let (sa, ca) = azimuth_deg.to_radians().sin_cos();
        let (se, ce) = elevation_deg.to_radians().sin_cos();
        normalize(add(
            add(scale(self.north, ce * ca), scale(self.east, ce * sa)),
            scale(self.up, se),
        ))
    }

    /// Elevation (degrees) of a direction above the local horizontal, in [−90, 90].
    pub fn elevation_deg(&self, d: Vec3) -> f64 {
        let (x, y, z) = (dot(d, self.north), dot(d, self.east), dot(d, self.up));
        z.atan2(x.hypot(y)).to_degrees()
    }

    /// Compass azimuth (degrees clockwise from north, in [0, 360)) of a direction; 0 for ±up.
    pub fn compass_deg(&self, d: Vec3) -> f64 {
        let a = dot(d, self.east)
            .atan2(dot(d, self.north))
            .to_degrees()
            .rem_euclid(360.0);
        if a >= 360.0 {
            0.0
        } else {
            a
        }
    }
}

/// How the sun disc's intersection with the horizon is approximated (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    Constant,
    Segment,
    Slices,
    Exact,
}

impl Model {
    pub const ALL: [Model; 4] = [Model::Constant, Model::Segment, Model::Slices, Model::Exact];

    pub fn name(self) -> &'static str {
        match self {
            Model::Constant => "constant",
            Model::Segment => "segment",
            Model::Slices => "slices",
            Model::Exact => "exact",
        }
    }
}

impl fmt::Display for Model {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Model {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Model::ALL
            .iter()
            .copied()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown sun model '{s}': use constant, segment, slices or exact"))
    }
}

/// The sun as seen from the body.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sun {
    /// Direction of the sun's centre, body frame (normalised on use; must be finite, non-zero).
    pub dir: Vec3,
    /// Angular radius of the disc, degrees (clamped to [0, 60]).
    pub radius_deg: f64,
}

/// Number of vertical strips of [`Model::Slices`].
pub const SLICES: usize = 8;
/// Number of vertical strips of [`Model::Exact`].
pub const EXACT_STRIPS: usize = 256;
/// Largest radius used (degrees); the gnomonic disc parametrisation needs r < 90°.
const MAX_RADIUS_DEG: f64 = 60.0;
/// Below this radius (radians) the sun is a point.
const POINT_RADIUS_RAD: f64 = 1e-15;

/// The sun disc at a frame: its centre, elevation, disc axes and radius.
struct Disc {
    s: Vec3,
    el: f64,
    e_h: Vec3,
    e_v: Vec3,
    /// Radius, degrees and radians, and tan of it.
    r_deg: f64,
    r: f64,
    tan_r: f64,
}

impl Disc {
    fn new(frame: &Frame, sun: &Sun) -> Disc {
        let s = normalize(sun.dir);
        let r_deg = if sun.radius_deg > 0.0 {
            sun.radius_deg.min(MAX_RADIUS_DEG)
        } else {
            0.0
        };
        let c = cross(s, frame.up);
        // |s × up| = cos(el): exactly 0 only at the zenith and nadir, and normalising a tiny
        // cross product is still accurate, so the fallback is needed only there.
        let e_h = if dot(c, c) > 1e-200 {
            normalize(c)
        } else {
            frame.east
        };
        let e_v = normalize(cross(e_h, s));
        Disc {
            s,
            el: frame.elevation_deg(s),
            e_h,
            e_v,
            r_deg,
            r: r_deg.to_radians(),
            tan_r: r_deg.to_radians().tan(),
        }
    }

    /// Direction of disc point (x, y), in units of the radius on the gnomonic tangent plane.
    fn dir(&self, x: f64, y: f64) -> Vec3 {
        let (a, b) = (self.tan_r * x, self.tan_r * y);
        normalize(add(self.s, add(scale(self.e_h, a), scale(self.e_v, b))))
    }

    /// The horizontal direction of the sun's vertical plane (the tangent part of s, or the
    /// direction e_v points to at the zenith), whose plane azimuth is the sun's.
    fn horizontal(&self, frame: &Frame) -> Vec3 {
        cross(frame.up, self.e_h)
    }
}

/// Lit fraction in [0, 1] of the sun disc seen from the frame's point, for a horizon given as a
/// function of plane azimuth (radians, in [0, 2π)) returning elevation (degrees). NaN only
/// when the horizon returns NaN at an azimuth the model evaluates (no data). See the module doc
/// for the models and the degenerate cases.
pub fn lit_fraction(frame: &Frame, sun: &Sun, model: Model, horizon: &dyn Fn(f64) -> f64) -> f64 {
    let disc = Disc::new(frame, sun);
    let hor = |d: Vec3| -> f64 {
        let a = horizon(frame.plane_azimuth(d));
        if a.is_nan() {
            a
        } else {
            a.clamp(-90.0, 90.0)
        }
    };
    if disc.r <= POINT_RADIUS_RAD {
        let a = hor(disc.horizontal(frame));
        return if a.is_nan() {
            f64::NAN
        } else if disc.el > a {
            1.0
        } else if disc.el < a {
            0.0
        } else {
            0.5
        };
    }
    let f = match model {
        Model::Constant => {
            let a = hor(disc.horizontal(frame));
            segment_fraction((a - disc.el) / disc.r_deg)
        }
        Model::Segment => {
            let (dl, dr) = (disc.dir(-1.0, 0.0), disc.dir(1.0, 0.0));
            // Crossings of the horizon with the disc's left and right rims, in degrees above
            // the disc's horizontal diameter.
            let yl = hor(dl) - frame.elevation_deg(dl);
            let yr = hor(dr) - frame.elevation_deg(dr);
            // Line y = m + k·x (units of r): its distance above the centre is m/√(1+k²), here
            // with numerator and denominator scaled by r so that nothing overflows.
            let (m, k) = ((yl + yr) / 2.0, (yr - yl) / 2.0);
            segment_fraction(m / disc.r_deg.hypot(k))
        }
        Model::Slices => {
            let mut lit = 0.0;
            for i in 0..SLICES {
                let (a, b) = strip_bounds(i, SLICES);
                let d = disc.dir((a + b) / 2.0, 0.0);
                let c = (hor(d) - frame.elevation_deg(d)) / disc.r_deg;
                lit += strip_area_above(a, b, c);
            }
            lit / PI
        }
        Model::Exact => exact(frame, &disc, &hor),
    };
    if f.is_nan() {
        f
    } else {
        f.clamp(0.0, 1.0)
    }
}

/// [`Model::Exact`]: 256 strips, the sky/terrain boundary of each by bisection on 3-D
/// directions along the strip's middle vertical.
fn exact(frame: &Frame, disc: &Disc, hor: &dyn Fn(Vec3) -> f64) -> f64 {
    // Elevation above the horizon of disc point (x, y), degrees.
    let g = |x: f64, y: f64| {
        let d = disc.dir(x, y);
        frame.elevation_deg(d) - hor(d)
    };
    let mut lit = 0.0;
    for i in 0..EXACT_STRIPS {
        let (a, b) = strip_bounds(i, EXACT_STRIPS);
        let x = (a + b) / 2.0;
        let h = (1.0 - x * x).max(0.0).sqrt();
        let (gb, gt) = (g(x, -h), g(x, h));
        if gb.is_nan() || gt.is_nan() {
            return f64::NAN;
        }
        let (lit_b, lit_t) = (gb > 0.0, gt > 0.0);
        if lit_b == lit_t {
            if lit_b {
                lit += strip_area_above(a, b, -1.0);
            }
            continue;
        }
        // One crossing in (−h, h): bisect for it, keeping `lo` on the bottom's side.
        let (mut lo, mut hi) = (-h, h);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if mid <= lo || mid >= hi || hi - lo < 1e-12 {
                break;
            }
            let gm = g(x, mid);
            if gm.is_nan() {
                return f64::NAN;
            }
            if (gm > 0.0) == lit_b {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let c = 0.5 * (lo + hi);
        let above = strip_area_above(a, b, c);
        lit += if lit_t {
            above
        } else {
            strip_area_above(a, b, -1.0) - above
        };
    }
    lit / PI
}

/// Bounds (in units of the radius) of vertical strip `i` of `n` equal-width strips of the disc.
fn strip_bounds(i: usize, n: usize) -> (f64, f64) {
    let w = 2.0 / n as f64;
    (-1.0 + w * i as f64, -1.0 + w * (i + 1) as f64)
}

/// ∫₀ˣ √(1 − t²) dt for x in [−1, 1].
fn half_chord_integral(x: f64) -> f64 {
    let x = x.clamp(-1.0, 1.0);
    0.5 * (x * (1.0 - x * x).max(0.0).sqrt() + x.asin())
}

/// Exact area of the part of the unit disc with a ≤ x ≤ b (−1 ≤ a ≤ b ≤ 1) and y ≥ c.
pub fn strip_area_above(a: f64, b: f64, c: f64) -> f64 {
    let (a, b) = (a.clamp(-1.0, 1.0), b.clamp(-1.0, 1.0));
    if b <= a {
        return 0.0;
    }
    if c < 0.0 {
        // By symmetry the part below c is the part above −c.
        let whole = 2.0 * (half_chord_integral(b) - half_chord_integral(a));
        return (whole - strip_area_above(a, b, -c)).max(0.0);
    }
    if c >= 1.0 {
        return 0.0;
    }
    // Where the chord reaches above c: |x| < √(1 − c²); there the strip above c is √(1−x²) − c.
    let xc = (1.0 - c * c).sqrt();
    let (lo, hi) = (a.max(-xc), b.min(xc));
    if hi <= lo {
        return 0.0;
    }
    (half_chord_integral(hi) - half_chord_integral(lo) - c * (hi - lo)).max(0.0)
}

/// The fraction of a disc of radius 1 lying above a horizontal line at height `d` (in units of
/// the radius; 1 for d ≤ −1, 0 for d ≥ 1): the circular segment's area / π. NaN for NaN.
pub fn segment_fraction(d: f64) -> f64 {
    if d.is_nan() {
        return d;
    }
    if d <= -1.0 {
        return 1.0;
    }
    if d >= 1.0 {
        return 0.0;
    }
    ((d.acos() - d * (1.0 - d * d).sqrt()) / PI).clamp(0.0, 1.0)
}

/// Nominal solar radius, km (IAU 2015 Resolution B3).
pub const SUN_RADIUS_KM: f64 = 695_700.0;
/// The astronomical unit, km (IAU 2012 Resolution B2).
pub const AU_KM: f64 = 149_597_870.7;

/// The Sun's angular radius (degrees) seen from a distance in AU: asin(R_sun / d).
pub fn sun_radius_deg(distance_au: f64) -> f64 {
    (SUN_RADIUS_KM / (distance_au * AU_KM))
        .clamp(-1.0, 1.0)
        .asin()
        .to_degrees()
}

/// Mean distance from the Sun (AU) of a body preset (the names of `crate::body`), None for
/// others. The numbers are orbital semi-major axes, rounded: NASA NSSDCA planetary fact
/// sheets for Mercury, Venus, Earth (and the Moon, which shares it), Mars and Pluto; JPL's
/// Small-Body Database for Ceres and Vesta.
pub fn sun_distance_au(body: &str) -> Option<f64> {
    Some(match body {
        "mercury" => 0.387,
        "venus" => 0.723,
        "earth" | "moon" => 1.0,
        "mars" => 1.524,
        "ceres" => 2.767,
        "vesta" => 2.362,
        "pluto" => 39.48,
        _ => return None,
    })
}

#[inline]
fn wrap_tau(a: f64) -> f64 {
    let w = a.rem_euclid(TAU);
    if w >= TAU {
        0.0
    } else {
        w
    }
}

#[inline]
fn normalize(p: Vec3) -> Vec3 {
    let n = dot(p, p).sqrt();
    [p[0] / n, p[1] / n, p[2] / n]
}

#[inline]
fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline]
fn scale(a: Vec3, k: f64) -> Vec3 {
    [a[0] * k, a[1] * k, a[2] * k]
}

#[inline]
fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
