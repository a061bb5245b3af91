//! Cube-face projection of a sphere, in f64.
//!
//! Body-fixed frame: +X at (lat 0°, lon 0°), +Y at (lat 0°, lon 90°E), +Z at the north pole.
//! Faces are numbered in the GPU cube-map order (+X, −X, +Y, −Y, +Z, −Z) so that face index =
//! array layer. Each face has an outward normal `n` and texture axes `U` (right) and `V` (up)
//! with `U × V = n`; on the four equatorial faces V points north. A point on a face is the
//! plane point `n + u·U + v·V` (u, v ∈ [−1, 1]), its direction the normalised plane point
//! (gnomonic: great circles are straight lines on a face). The *face coordinate* (s, t) that
//! tiles are laid out on equals (u, v) for the gnomonic projection and
//! (4/π)·atan(u), (4/π)·atan(v) for the equal-angle one. Both extend past ±1 (for halos),
//! gnomonic up to any finite value and equal-angle up to |s| < 2.
//! See docs/conventions.md for the table and pictures.

use serde::{Deserialize, Serialize};
use std::f64::consts::FRAC_PI_4;
use std::fmt;
use std::str::FromStr;

pub type Vec3 = [f64; 3];

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Face {
    Px = 0,
    Nx = 1,
    Py = 2,
    Ny = 3,
    Pz = 4,
    Nz = 5,
}

impl Face {
    pub const ALL: [Face; 6] = [Face::Px, Face::Nx, Face::Py, Face::Ny, Face::Pz, Face::Nz];

    pub fn index(self) -> usize {
        self as usize
    }

    pub fn from_index(i: usize) -> Option<Face> {
        Face::ALL.get(i).copied()
    }

    pub fn name(self) -> &'static str {
        match self {
            Face::Px => "px",
            Face::Nx => "nx",
            Face::Py => "py",
            Face::Ny => "ny",
            Face::Pz => "pz",
            Face::Nz => "nz",
        }
    }

    /// (normal, U, V) with U × V = normal.
    pub fn axes(self) -> (Vec3, Vec3, Vec3) {
        match self {
            Face::Px => ([1., 0., 0.], [0., 1., 0.], [0., 0., 1.]),
            Face::Nx => ([-1., 0., 0.], [0., -1., 0.], [0., 0., 1.]),
            Face::Py => ([0., 1., 0.], [-1., 0., 0.], [0., 0., 1.]),
            Face::Ny => ([0., -1., 0.], [1., 0., 0.], [0., 0., 1.]),
            Face::Pz => ([0., 0., 1.], [0., 1., 0.], [-1., 0., 0.]),
            Face::Nz => ([0., 0., -1.], [0., 1., 0.], [1., 0., 0.]),
        }
    }
}

impl fmt::Display for Face {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Face {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Face::ALL
            .iter()
            .copied()
            .find(|f| f.name() == s)
            .ok_or_else(|| format!("unknown face '{s}': use px, nx, py, ny, pz or nz"))
    }
}

/// How the face coordinate (s, t) maps to the gnomonic plane coordinate (u, v).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Projection {
    /// s = u: straight lines on a face are great circles (Jung et al.: tex = ½·xy/z + ½).
    #[default]
    Gnomonic,
    /// s = (4/π)·atan(u): equal angular spacing along each axis, pixel sizes vary less.
    EqualAngle,
}

impl Projection {
    #[inline]
    pub fn s_to_u(self, s: f64) -> f64 {
        match self {
            Projection::Gnomonic => s,
            Projection::EqualAngle => (s * FRAC_PI_4).tan(),
        }
    }
    #[inline]
    pub fn u_to_s(self, u: f64) -> f64 {
        match self {
            Projection::Gnomonic => u,
            Projection::EqualAngle => u.atan() / FRAC_PI_4,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Projection::Gnomonic => "gnomonic",
            Projection::EqualAngle => "equal-angle",
        }
    }
    /// Largest |s| for which the face coordinate still names a direction in the face's
    /// open hemisphere (halo sampling must stay below this).
    pub fn max_s(self) -> f64 {
        match self {
            Projection::Gnomonic => f64::INFINITY,
            Projection::EqualAngle => 2.0,
        }
    }
}

impl FromStr for Projection {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "gnomonic" => Ok(Projection::Gnomonic),
            "equal-angle" | "equalangle" => Ok(Projection::EqualAngle),
            _ => Err(format!(
                "unknown projection '{s}': use gnomonic or equal-angle"
            )),
        }
    }
}

/// `a / |a|`.
#[inline]
pub fn normalize(p: Vec3) -> Vec3 {
    let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / n, p[1] / n, p[2] / n]
}

/// `a · b`.
#[inline]
pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a + b`.
#[inline]
pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a − b`.
#[inline]
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a · k`.
#[inline]
pub fn scale(a: Vec3, k: f64) -> Vec3 {
    [a[0] * k, a[1] * k, a[2] * k]
}

/// `a × b`.
#[inline]
pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Length of `a`.
#[inline]
pub fn norm(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}

/// Unit direction of the gnomonic plane point (u, v) on `face`.
#[inline]
pub fn face_uv_to_dir(face: Face, u: f64, v: f64) -> Vec3 {
    let (n, a, b) = face.axes();
    normalize([
        n[0] + u * a[0] + v * b[0],
        n[1] + u * a[1] + v * b[1],
        n[2] + u * a[2] + v * b[2],
    ])
}

/// Gnomonic plane coordinates of direction `d` on `face`, or `None` when `d` is not in the
/// face's open hemisphere. Works beyond the face's edges (used for halos and seams).
#[inline]
pub fn dir_to_uv_on(face: Face, d: Vec3) -> Option<(f64, f64)> {
    let (n, a, b) = face.axes();
    let z = dot(d, n);
    if z <= 1e-300 {
        return None;
    }
    Some((dot(d, a) / z, dot(d, b) / z))
}

/// The face that contains direction `d` (largest absolute component; ties go to the lower
/// face index) and its gnomonic plane coordinates, each in [−1, 1].
#[inline]
pub fn dir_to_face_uv(d: Vec3) -> (Face, f64, f64) {
    let (ax, ay, az) = (d[0].abs(), d[1].abs(), d[2].abs());
    let face = if ax >= ay && ax >= az {
        if d[0] >= 0.0 {
            Face::Px
        } else {
            Face::Nx
        }
    } else if ay >= az {
        if d[1] >= 0.0 {
            Face::Py
        } else {
            Face::Ny
        }
    } else if d[2] >= 0.0 {
        Face::Pz
    } else {
        Face::Nz
    };
    let (u, v) = dir_to_uv_on(face, d).expect("dominant face always contains the direction");
    (face, u.clamp(-1.0, 1.0), v.clamp(-1.0, 1.0))
}

/// Unit direction of planetocentric latitude/longitude, in radians.
#[inline]
pub fn latlon_to_dir(lat: f64, lon: f64) -> Vec3 {
    let (sl, cl) = lat.sin_cos();
    let (so, co) = lon.sin_cos();
    [cl * co, cl * so, sl]
}

/// Planetocentric (latitude, longitude) in radians of a unit direction; longitude in (−π, π].
#[inline]
pub fn dir_to_latlon(d: Vec3) -> (f64, f64) {
    let h = (d[0] * d[0] + d[1] * d[1]).sqrt();
    (d[2].atan2(h), d[1].atan2(d[0]))
}

/// Angle in radians between two unit vectors, accurate for tiny angles.
pub fn angle_between(a: Vec3, b: Vec3) -> f64 {
    let c = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let s = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    s.atan2(dot(a, b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_are_right_handed_and_faces_continue() {
        for f in Face::ALL {
            let (n, a, b) = f.axes();
            let c = [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ];
            assert_eq!(c, n, "{f}");
            let d = face_uv_to_dir(f, 0.0, 0.0);
            assert_eq!(dir_to_face_uv(d).0, f);
        }
        // +X's top edge is +Z's bottom edge with the same u.
        let d = face_uv_to_dir(Face::Px, 0.3, 1.0);
        let (u, v) = dir_to_uv_on(Face::Pz, d).unwrap();
        assert!((u - 0.3).abs() < 1e-15 && (v + 1.0).abs() < 1e-15);
    }

    #[test]
    fn equal_angle_inverts() {
        for i in -190..=190 {
            let s = i as f64 / 100.0;
            let p = Projection::EqualAngle;
            assert!((p.u_to_s(p.s_to_u(s)) - s).abs() < 1e-14);
        }
    }
}
