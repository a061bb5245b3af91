/*!
A camera in the body frame (docs/conventions.md): an f64 eye position in metres, a compass
heading clockwise from local north and a pitch above the local horizontal, and a vertical field
of view. [`crate::lod`] chooses tiles for it; the viewer (`penumbra-view`) draws them and moves
it (orbit about a *target* on the terrain's mean sphere, fly, zoom). The GPU's matrices stay in
the viewer.
*/

use crate::cube::{self, add, cross, dot, norm, normalize, scale, sub, Vec3};

/// The local (east, north, up) frame at direction `d` (need not be unit). North is the
/// direction towards +Z along the meridian; at the poles it is the limit along the 0° meridian
/// (docs/conventions.md).
pub fn enu(d: Vec3) -> (Vec3, Vec3, Vec3) {
    let up = normalize(d);
    let h = (up[0] * up[0] + up[1] * up[1]).sqrt();
    let (so, co) = if h > 1e-12 {
        (up[1] / h, up[0] / h)
    } else {
        (0.0, 1.0)
    };
    let east = [-so, co, 0.0];
    let north = cross(up, east);
    (east, north, up)
}

/// The unit direction of compass azimuth `az_deg` and elevation `el_deg` at direction `d`.
pub fn local_dir(d: Vec3, az_deg: f64, el_deg: f64) -> Vec3 {
    let (e, n, u) = enu(d);
    let (sa, ca) = az_deg.to_radians().sin_cos();
    let (se, ce) = el_deg.to_radians().sin_cos();
    add(add(scale(e, ce * sa), scale(n, ce * ca)), scale(u, se))
}

/// Compass azimuth and elevation (degrees) of direction `v` at direction `d`; azimuth in
/// [0, 360).
pub fn local_az_el(d: Vec3, v: Vec3) -> (f64, f64) {
    let (e, n, u) = enu(d);
    let v = normalize(v);
    let el = dot(v, u).clamp(-1.0, 1.0).asin().to_degrees();
    let az = dot(v, e).atan2(dot(v, n)).to_degrees().rem_euclid(360.0);
    (az, el)
}

/// The eye, where it looks and how wide.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position, body frame (m).
    pub eye: Vec3,
    /// Compass heading of the view direction at the eye (degrees).
    pub heading_deg: f64,
    /// Elevation of the view direction above the eye's local horizontal (degrees; −90 looks
    /// straight down).
    pub pitch_deg: f64,
    /// Vertical field of view (degrees).
    pub fov_y_deg: f64,
}

/// The camera's orthonormal basis, body frame.
#[derive(Clone, Copy, Debug)]
pub struct Basis {
    /// The view direction.
    pub forward: Vec3,
    /// Right on screen (along the local horizontal).
    pub right: Vec3,
    /// Up on screen (right × forward).
    pub up: Vec3,
}

/// Smallest and largest vertical field of view (degrees).
pub const FOV_RANGE: (f64, f64) = (1.0, 120.0);

impl Camera {
    /// A camera at latitude/longitude (degrees) and `alt_m` above the reference sphere of
    /// radius `radius_m`, looking at `heading_deg`, `pitch_deg`.
    pub fn at(
        radius_m: f64,
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
        heading_deg: f64,
        pitch_deg: f64,
        fov_y_deg: f64,
    ) -> Camera {
        let d = cube::latlon_to_dir(lat_deg.to_radians(), lon_deg.to_radians());
        Camera {
            eye: scale(d, radius_m + alt_m),
            heading_deg,
            pitch_deg: pitch_deg.clamp(-90.0, 90.0),
            fov_y_deg: fov_y_deg.clamp(FOV_RANGE.0, FOV_RANGE.1),
        }
    }

    /// Latitude, longitude (degrees) and height above a sphere of radius `radius_m` of the eye.
    pub fn lat_lon_alt(&self, radius_m: f64) -> (f64, f64, f64) {
        let (lat, lon) = cube::dir_to_latlon(normalize(self.eye));
        (
            lat.to_degrees(),
            lon.to_degrees(),
            norm(self.eye) - radius_m,
        )
    }

    /// The view basis: forward from heading and pitch, right along the horizon, up completing
    /// a right-handed frame (right × forward = up). Straight down, "up" on screen is the
    /// heading.
    pub fn basis(&self) -> Basis {
        let (e, n, u) = enu(self.eye);
        let (sh, ch) = self.heading_deg.to_radians().sin_cos();
        let (sp, cp) = self.pitch_deg.to_radians().sin_cos();
        let horiz = add(scale(e, sh), scale(n, ch));
        let forward = add(scale(horiz, cp), scale(u, sp));
        let right = sub(scale(e, ch), scale(n, sh));
        let up = cross(right, forward);
        Basis { forward, right, up }
    }

    /// The near plane distance (m) for an eye `alt_m` above the highest terrain: far enough for
    /// depth precision, close enough not to clip terrain under the eye.
    pub fn near_m(alt_above_terrain_m: f64) -> f64 {
        (alt_above_terrain_m * 0.05).clamp(0.25, 5000.0)
    }

    /// Pixels per radian at the screen centre for a viewport `height_px` tall.
    pub fn px_per_rad(&self, height_px: u32) -> f64 {
        height_px as f64 / (2.0 * (self.fov_y_deg.to_radians() / 2.0).tan())
    }

    /// Where the view centre meets the sphere of radius `r` (the terrain's mean sphere), or,
    /// when it misses, the point of that sphere under the eye.
    pub fn target(&self, r: f64) -> Vec3 {
        let f = self.basis().forward;
        ray_sphere(self.eye, f, r).unwrap_or_else(|| scale(normalize(self.eye), r))
    }

    /// Turn the eye about the target on the sphere of radius `r`: `d_az` degrees of compass
    /// azimuth and `d_el` degrees of elevation as seen from the target, then look at it.
    pub fn orbit(&mut self, r: f64, d_az: f64, d_el: f64) {
        let t = self.target(r);
        let v = sub(self.eye, t);
        let range = norm(v);
        let (az, el) = local_az_el(t, v);
        let el = (el + d_el).clamp(1.0, 89.9);
        self.eye = add(t, scale(local_dir(t, az + d_az, el), range));
        self.look_at(t);
    }

    /// Move the eye towards (factor < 1) or away from (> 1) the target on the sphere of radius
    /// `r`, staying at least `min_range_m` from it.
    pub fn zoom(&mut self, r: f64, factor: f64, min_range_m: f64) {
        let t = self.target(r);
        let v = sub(self.eye, t);
        let range = (norm(v) * factor).max(min_range_m);
        self.eye = add(t, scale(normalize(v), range));
        self.look_at(t);
    }

    /// Point the view at `p`.
    pub fn look_at(&mut self, p: Vec3) {
        let (az, el) = local_az_el(self.eye, sub(p, self.eye));
        self.heading_deg = az;
        self.pitch_deg = el;
    }

    /// Fly: move the eye `fwd`, `right` metres along the view's horizontal directions and
    /// `up` metres along the local vertical.
    pub fn fly(&mut self, fwd: f64, right: f64, up: f64) {
        let (e, n, u) = enu(self.eye);
        let (sh, ch) = self.heading_deg.to_radians().sin_cos();
        let horiz = add(scale(e, sh), scale(n, ch));
        let side = sub(scale(e, ch), scale(n, sh));
        // The heading and pitch stay as they are, relative to the new local frame.
        self.eye = add(
            self.eye,
            add(add(scale(horiz, fwd), scale(side, right)), scale(u, up)),
        );
    }
}

/// The nearest intersection of the ray `o + t·d` (t > 0, `d` unit) with the sphere of radius
/// `r` about the origin.
pub fn ray_sphere(o: Vec3, d: Vec3, r: f64) -> Option<Vec3> {
    let b = dot(o, d);
    let c = dot(o, o) - r * r;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t = if -b - s > 0.0 { -b - s } else { -b + s };
    (t > 0.0).then(|| add(o, scale(d, t)))
}

#[cfg(test)]
mod tests {
    use super::*;

    const R: f64 = 1_737_400.0;

    fn close(a: Vec3, b: Vec3, eps: f64) -> bool {
        norm(sub(a, b)) < eps
    }

    #[test]
    fn enu_is_right_handed_everywhere_and_north_points_to_the_pole() {
        for (lat, lon) in [
            (0.0, 0.0),
            (45.0, 30.0),
            (-89.0, 200.0),
            (90.0, 0.0),
            (-90.0, 0.0),
        ] {
            let d = cube::latlon_to_dir(f64::to_radians(lat), f64::to_radians(lon));
            let (e, n, u) = enu(d);
            assert!(close(cross(e, n), u, 1e-12), "{lat} {lon}");
            if lat.abs() < 90.0 {
                assert!(n[2] > 0.0);
            }
        }
        // At the south pole north is +X (towards lon 0° along the meridian), at the north pole −X.
        assert!(close(enu([0.0, 0.0, -1.0]).1, [1.0, 0.0, 0.0], 1e-12));
        assert!(close(enu([0.0, 0.0, 1.0]).1, [-1.0, 0.0, 0.0], 1e-12));
    }

    #[test]
    fn local_directions_round_trip() {
        let d = cube::latlon_to_dir(f64::to_radians(-70.0), f64::to_radians(123.0));
        for (az, el) in [(0.0, 0.0), (90.0, 10.0), (271.5, -3.0), (180.0, 45.0)] {
            let (a, e) = local_az_el(d, local_dir(d, az, el));
            assert!((a - az).abs() < 1e-9 && (e - el).abs() < 1e-9, "{az} {el}");
        }
    }

    #[test]
    fn a_camera_straight_down_looks_at_the_point_under_it() {
        let c = Camera::at(R, -89.0, 45.0, 5000.0, 30.0, -90.0, 45.0);
        let t = c.target(R);
        let under = scale(
            cube::latlon_to_dir(f64::to_radians(-89.0), f64::to_radians(45.0)),
            R,
        );
        assert!(close(t, under, 1e-3));
        let b = c.basis();
        assert!(close(cross(b.right, b.forward), b.up, 1e-12));
        assert!(dot(b.right, b.forward).abs() < 1e-12);
    }

    #[test]
    fn orbit_keeps_range_and_target() {
        let mut c = Camera::at(R, -88.0, 10.0, 20_000.0, 0.0, -50.0, 45.0);
        let t0 = c.target(R);
        let r0 = norm(sub(c.eye, t0));
        c.orbit(R, 40.0, 5.0);
        let t1 = c.target(R);
        assert!(close(t0, t1, 1e-3), "{:?}", sub(t0, t1));
        assert!((norm(sub(c.eye, t1)) - r0).abs() < 1e-3);
    }
}
