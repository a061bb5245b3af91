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
            .ok_or_else(|| {
                format!("unknown sun model '{s}': use constant, segment, slices or exact")
            })
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
            let (mut lit, mut whole) = (0.0, 0);
            for i in 0..SLICES {
                let (a, b) = strip_bounds(i, SLICES);
                let d = disc.dir((a + b) / 2.0, 0.0);
                let c = (hor(d) - frame.elevation_deg(d)) / disc.r_deg;
                whole += usize::from(c <= -1.0);
                lit += strip_area_above(a, b, c);
            }
            // Every strip lit: exactly 1 (the strips' areas sum to π within rounding).
            if whole == SLICES {
                1.0
            } else {
                lit / PI
            }
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
    let (mut lit, mut whole) = (0.0, 0);
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
                whole += 1;
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
    // Every strip lit: exactly 1 (the strips' areas sum to π within rounding).
    if whole == EXACT_STRIPS {
        1.0
    } else {
        lit / PI
    }
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

/// Exact area of the part of the unit disc with a ≤ x ≤ b (−1 ≤ a ≤ b ≤ 1) and y ≥ c; NaN
/// when c is NaN.
pub fn strip_area_above(a: f64, b: f64, c: f64) -> f64 {
    if c.is_nan() {
        return c;
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::horizon::compass_azimuth_deg;
    use crate::testutil::rng;

    /// The Sun's angular radius from the Moon (1 AU), degrees.
    const R_MOON: f64 = 0.2666;

    /// Observer points: equator, both poles, a cube corner, an edge, extended planes.
    fn points() -> Vec<(Face, f64, f64)> {
        vec![
            (Face::Px, 0.0, 0.0),
            (Face::Pz, 0.0, 0.0),
            (Face::Nz, 0.0, 0.0),
            (Face::Px, 1.0, 1.0),
            (Face::Ny, -1.0, -1.0),
            (Face::Py, 0.3, -0.7),
            (Face::Nx, 2.5, -0.3),
            (Face::Pz, -3.0, 3.0),
        ]
    }

    /// Signed difference a − b wrapped to [−π, π).
    fn wrap_pi(d: f64) -> f64 {
        (d + PI).rem_euclid(TAU) - PI
    }

    fn sun_at(frame: &Frame, az: f64, el: f64, r: f64) -> Sun {
        Sun {
            dir: frame.direction(az, el),
            radius_deg: r,
        }
    }

    #[test]
    fn segment_fraction_values_symmetry_and_area() {
        assert!((segment_fraction(0.0) - 0.5).abs() < 1e-15);
        assert_eq!(segment_fraction(-1.0), 1.0);
        assert_eq!(segment_fraction(1.0), 0.0);
        assert_eq!(segment_fraction(-7.0), 1.0);
        assert_eq!(segment_fraction(3.0), 0.0);
        assert_eq!(segment_fraction(f64::INFINITY), 0.0);
        assert_eq!(segment_fraction(f64::NEG_INFINITY), 1.0);
        for i in 0..=200 {
            let d = -1.2 + 2.4 * i as f64 / 200.0;
            let (f, g) = (segment_fraction(d), segment_fraction(-d));
            assert!((f + g - 1.0).abs() < 1e-14, "d {d}: {f} + {g}");
            assert!(segment_fraction(d + 1e-3) <= f, "not decreasing at {d}");
        }
        // Brute force: cell centres of an n×n grid over the disc's bounding square.
        let n = 1500;
        for &d in &[-0.9, -0.5, -0.1, 0.0, 0.3, 0.77, 0.95] {
            let (mut inside, mut above) = (0u64, 0u64);
            for j in 0..n {
                let y = -1.0 + 2.0 * (j as f64 + 0.5) / n as f64;
                for i in 0..n {
                    let x = -1.0 + 2.0 * (i as f64 + 0.5) / n as f64;
                    if x * x + y * y <= 1.0 {
                        inside += 1;
                        if y > d {
                            above += 1;
                        }
                    }
                }
            }
            let brute = above as f64 / inside as f64;
            assert!(
                (brute - segment_fraction(d)).abs() < 1e-3,
                "d {d}: brute {brute}, formula {}",
                segment_fraction(d)
            );
        }
    }

    #[test]
    fn strip_areas_sum_to_the_disc_and_to_segments() {
        for &n in &[1usize, 8, 256] {
            for &c in &[-1.5, -0.6, 0.0, 0.25, 0.9, 1.0] {
                let s: f64 = (0..n)
                    .map(|i| {
                        let (a, b) = strip_bounds(i, n);
                        strip_area_above(a, b, c)
                    })
                    .sum();
                assert!(
                    (s / PI - segment_fraction(c)).abs() < 1e-13,
                    "{n} strips, c {c}: {} vs {}",
                    s / PI,
                    segment_fraction(c)
                );
            }
        }
    }

    #[test]
    fn flat_horizon_all_models_match_the_segment_formula() {
        for (face, u, v) in points() {
            let frame = Frame::at(face, u, v);
            for &az in &[0.0, 73.0, 180.0, 291.0] {
                for &a0 in &[-3.0, 0.0, 10.0] {
                    let hor = move |_: f64| a0;
                    for k in 0..=30 {
                        let el = a0 + R_MOON * (-1.5 + 3.0 * k as f64 / 30.0);
                        let want = segment_fraction((a0 - el) / R_MOON);
                        let sun = sun_at(&frame, az, el, R_MOON);
                        for m in Model::ALL {
                            let got = lit_fraction(&frame, &sun, m, &hor);
                            assert!(
                                (got - want).abs() < 1e-3,
                                "{m} at {face} ({u}, {v}), az {az}, α {a0}, el {el}: {got} vs {want}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_disc_wholly_above_or_below_the_horizon_is_exactly_lit_or_dark() {
        // Sums of strip areas are π only within rounding; a whole disc must still read
        // exactly 1 or 0 (callers compare with 1.0 and 0.0, and a shadow mask must not show
        // 0.9999999999999999 as partly lit).
        for (face, u, v) in points() {
            let frame = Frame::at(face, u, v);
            for &az in &[0.0, 123.0, 359.99] {
                for &(el, a0, want) in &[(1.0, -0.6, 1.0), (45.0, 3.0, 1.0), (-2.0, 4.0, 0.0)] {
                    let hor = move |phi: f64| a0 + 0.3 * (2.0 * phi).sin();
                    let sun = sun_at(&frame, az, el, R_MOON);
                    for m in Model::ALL {
                        let got = lit_fraction(&frame, &sun, m, &hor);
                        assert_eq!(got, want, "{m} at {face} ({u}, {v}), az {az}, el {el}");
                    }
                }
            }
        }
    }

    /// The horizontal tangent direction at plane azimuth φ.
    fn tangent(f: &Frame, phi: f64) -> Vec3 {
        let w = add(scale(f.ua, phi.cos()), scale(f.va, phi.sin()));
        add(w, scale(f.up, -dot(w, f.up)))
    }

    #[test]
    fn linear_horizon_segment_matches_exact_and_constant_does_not() {
        for (face, u, v) in points() {
            let frame = Frame::at(face, u, v);
            for &(az, el) in &[(40.0, 20.0), (200.0, 5.0), (310.0, 35.0)] {
                let sun = sun_at(&frame, az, el, R_MOON);
                let disc = Disc::new(&frame, &sun);
                let hs = disc.horizontal(&frame);
                // A horizon linear across the disc: at the horizontal angle β from the sun's
                // azimuth (towards e_h) the disc's horizontal diameter is at
                // x = tan β·cos(el)/tan r, and there the horizon is 0.5 + k·x radii above the
                // centre. (Linear in the plane azimuth instead, the gnomonic distortion at cube
                // corners bends it across the disc by ≈ 1e-3.)
                let k = 2.0;
                let hor = move |phi: f64| {
                    let t = tangent(&frame, phi);
                    let beta = dot(t, disc.e_h).atan2(dot(t, hs));
                    let x = beta.tan() * el.to_radians().cos() / R_MOON.to_radians().tan();
                    el + R_MOON * (0.5 + k * x)
                };
                let (seg, ex, con, sl) = (
                    lit_fraction(&frame, &sun, Model::Segment, &hor),
                    lit_fraction(&frame, &sun, Model::Exact, &hor),
                    lit_fraction(&frame, &sun, Model::Constant, &hor),
                    lit_fraction(&frame, &sun, Model::Slices, &hor),
                );
                let want = segment_fraction(0.5 / (1.0f64 + k * k).sqrt());
                let at = format!("{face} ({u}, {v}) az {az} el {el}");
                assert!(
                    (seg - want).abs() < 1e-3,
                    "{at}: segment {seg}, want {want}"
                );
                assert!((seg - ex).abs() < 1e-3, "{at}: segment {seg}, exact {ex}");
                assert!((sl - ex).abs() < 1e-2, "{at}: slices {sl}, exact {ex}");
                assert!(
                    (con - segment_fraction(0.5)).abs() < 1e-2 && (con - ex).abs() > 0.1,
                    "{at}: constant {con}, exact {ex}"
                );
            }
        }
    }

    #[test]
    fn step_horizon_exact_and_slices() {
        // Sun at 10°; horizon 10° on the side of larger plane azimuth, −5° on the other. The
        // −5° half of the disc is all lit; on the other the 10° horizon runs through the disc's
        // centre (to O(r·tan el) ≈ 1e-3 radii of curvature), so half of that half is lit:
        // 1/2 + 1/4 = 0.75.
        for (face, u, v) in points() {
            let frame = Frame::at(face, u, v);
            for &az in &[15.0, 100.0, 260.0] {
                let sun = sun_at(&frame, az, 10.0, R_MOON);
                let phi_s = frame.plane_azimuth(sun.dir);
                let hor = move |phi: f64| {
                    if wrap_pi(phi - phi_s) >= 0.0 {
                        10.0
                    } else {
                        -5.0
                    }
                };
                let ex = lit_fraction(&frame, &sun, Model::Exact, &hor);
                let sl = lit_fraction(&frame, &sun, Model::Slices, &hor);
                let at = format!("{face} ({u}, {v}) az {az}");
                assert!((ex - 0.75).abs() < 2e-3, "{at}: exact {ex}");
                assert!((sl - 0.75).abs() < 0.07, "{at}: slices {sl}");
            }
        }
    }

    #[test]
    fn lit_fraction_never_decreases_as_the_sun_rises() {
        for (face, u, v) in points() {
            let frame = Frame::at(face, u, v);
            let hor = |phi: f64| 3.0 + 2.0 * (phi - 0.4).sin() + 0.5 * (3.0 * phi).cos();
            for &az in &[30.0, 222.0] {
                for &r in &[R_MOON, 2.0] {
                    let a_s = hor(frame.plane_azimuth(frame.direction(az, 0.0)));
                    // Finely through the transition, then coarsely over the whole sky.
                    let fine = (0..=300).map(|i| a_s + r * (-3.0 + 6.0 * i as f64 / 300.0));
                    let coarse = (0..=180).map(|i| -90.0 + i as f64);
                    for els in [fine.collect::<Vec<_>>(), coarse.collect()] {
                        for m in Model::ALL {
                            let mut prev = -1.0;
                            for &el in &els {
                                let f = lit_fraction(&frame, &sun_at(&frame, az, el, r), m, &hor);
                                assert!(
                                    f >= prev - 1e-9,
                                    "{m} at {face} ({u}, {v}) az {az} r {r}: {prev} then {f} at el {el}"
                                );
                                prev = f;
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn frame_round_trips_and_matches_compass_azimuth() {
        let mut rnd = rng(7);
        for (face, u, v) in points() {
            let f = Frame::at(face, u, v);
            // Orthonormal, right-handed as documented.
            for (a, b) in [(f.up, f.north), (f.up, f.east), (f.north, f.east)] {
                assert!(dot(a, b).abs() < 1e-12);
            }
            for a in [f.up, f.north, f.east] {
                assert!((dot(a, a) - 1.0).abs() < 1e-12);
            }
            let c = cross(f.north, f.up);
            assert!((dot(c, f.east) - 1.0).abs() < 1e-12);
            for _ in 0..200 {
                let az = 360.0 * rnd();
                let el = -89.0 + 178.0 * rnd();
                let d = f.direction(az, el);
                let daz = (f.compass_deg(d) - az + 180.0).rem_euclid(360.0) - 180.0;
                assert!(
                    daz.abs() < 1e-9,
                    "{face} ({u}, {v}): az {az} → {}",
                    f.compass_deg(d)
                );
                assert!((f.elevation_deg(d) - el).abs() < 1e-9, "el {el}");
                // The sun's plane azimuth and compass azimuth describe the same bearing.
                let phi = f.plane_azimuth(d);
                let caz = compass_azimuth_deg(face, u, v, phi);
                let dz = (caz - az + 180.0).rem_euclid(360.0) - 180.0;
                assert!(dz.abs() < 1e-8, "{face} ({u}, {v}): az {az}, via φ {caz}");
            }
            for _ in 0..200 {
                let phi = TAU * rnd();
                let t = tangent(&f, phi);
                let dphi = wrap_pi(f.plane_azimuth(t) - phi);
                assert!(dphi.abs() < 1e-10, "{face} ({u}, {v}): φ {phi} → {dphi}");
                let want = compass_azimuth_deg(face, u, v, phi);
                let dz = (f.compass_deg(t) - want + 180.0).rem_euclid(360.0) - 180.0;
                assert!(
                    dz.abs() < 1e-9,
                    "{face} ({u}, {v}): φ {phi}: {want} vs {}",
                    f.compass_deg(t)
                );
            }
            let p = f.plane_azimuth(f.up);
            assert!((0.0..TAU).contains(&p));
        }
        // North at the poles is the 0° meridian's limit.
        assert_eq!(Frame::at(Face::Pz, 0.0, 0.0).north, [-1.0, 0.0, 0.0]);
        assert_eq!(Frame::at(Face::Nz, 0.0, 0.0).north, [1.0, 0.0, 0.0]);
    }

    #[test]
    fn stiff_cases_stay_in_range() {
        let horizons = [-90.0, 0.0, 89.99, 90.0];
        let mut pts = points();
        pts.extend([(Face::Px, -1.0, 1.0), (Face::Nz, 1.0, -1.0)]);
        for (face, u, v) in pts {
            let frame = Frame::at(face, u, v);
            for &el in &[-90.0, -1.0, 0.0, 0.1, 45.0, 89.9, 90.0] {
                for &r in &[0.0, 0.27, 5.0] {
                    for &a in &horizons {
                        let hor = move |_: f64| a;
                        for m in Model::ALL {
                            for az in [0.0, 135.0] {
                                let f = lit_fraction(&frame, &sun_at(&frame, az, el, r), m, &hor);
                                assert!(
                                    (0.0..=1.0).contains(&f),
                                    "{m} at {face} ({u}, {v}) el {el} r {r} α {a}: {f}"
                                );
                            }
                        }
                    }
                }
            }
            // Straight up and down, exactly.
            for dir in [frame.up, scale(frame.up, -1.0)] {
                for m in Model::ALL {
                    let f = lit_fraction(
                        &frame,
                        &Sun {
                            dir,
                            radius_deg: 0.27,
                        },
                        m,
                        &|_| 10.0,
                    );
                    assert!((0.0..=1.0).contains(&f), "{m} at ±up: {f}");
                }
            }
        }
    }

    #[test]
    fn point_sun_and_missing_horizon() {
        let frame = Frame::at(Face::Py, 0.2, 0.1);
        for m in Model::ALL {
            let at = |el: f64| lit_fraction(&frame, &sun_at(&frame, 50.0, el, 0.0), m, &|_| 5.0);
            assert_eq!(at(5.001), 1.0, "{m}");
            assert_eq!(at(4.999), 0.0, "{m}");
            let el = frame.elevation_deg(frame.direction(50.0, 5.0));
            let f = lit_fraction(&frame, &sun_at(&frame, 50.0, 5.0, 0.0), m, &|_| el);
            assert_eq!(f, 0.5, "{m}");
            let sun = sun_at(&frame, 50.0, 5.0, R_MOON);
            assert!(lit_fraction(&frame, &sun, m, &|_| f64::NAN).is_nan(), "{m}");
            assert!(
                lit_fraction(&frame, &sun_at(&frame, 50.0, 5.0, 0.0), m, &|_| f64::NAN).is_nan()
            );
            // No data only far from the sun does not matter to the models (none looks there).
            let phi_s = frame.plane_azimuth(sun.dir);
            let hor = move |phi: f64| {
                if wrap_pi(phi - phi_s).abs() > 1.0 {
                    f64::NAN
                } else {
                    0.0
                }
            };
            assert!(
                (lit_fraction(&frame, &sun, m, &hor) - 1.0).abs() < 1e-12,
                "{m}"
            );
        }
    }

    #[test]
    fn sun_radius_and_distances() {
        assert!(
            (sun_radius_deg(1.0) - 0.2666).abs() < 1e-3,
            "{}",
            sun_radius_deg(1.0)
        );
        let mars = sun_radius_deg(sun_distance_au("mars").unwrap());
        assert!((mars - 0.175).abs() < 1e-3, "{mars}");
        assert_eq!(sun_distance_au("moon"), Some(1.0));
        assert_eq!(sun_distance_au("custom"), None);
        for m in Model::ALL {
            assert_eq!(m.name().parse::<Model>(), Ok(m));
            assert_eq!(
                serde_json::to_string(&m).unwrap(),
                format!("\"{}\"", m.name())
            );
        }
        assert!("hard".parse::<Model>().is_err());
    }
}
