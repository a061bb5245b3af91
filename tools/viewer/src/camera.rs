/*!
The camera and the sun, in the body frame (docs/conventions.md): f64 positions in metres,
compass headings clockwise from local north, elevations above the local horizontal.

The camera ([`Camera`], from `penumbra::camera`, where the tile selection of `penumbra::lod`
uses it) is an eye position with a heading and a pitch (a fly camera); orbiting turns the eye
about its *target*, the point of the terrain's mean sphere the view centre looks at. The sun is
its sub-solar point (latitude, longitude) as `penumbra shadow` takes it; the viewer's keys move
it in azimuth and elevation *at the target*, and [`SunPos::set_local`] turns those back into a
sub-solar point.

Rendering is relative to the eye: [`view_proj`] is a rotation and a reversed-Z infinite
perspective, and every tile adds its centre − eye (computed in f64) to its f32 vertices.
*/

pub use penumbra::camera::{enu, local_az_el, local_dir, ray_sphere, Basis, Camera, FOV_RANGE};
use penumbra::cube::{self, Vec3};
pub use penumbra::cube::{add, cross, norm, normalize, scale, sub};
use penumbra::fourier::sun::Sun;

/// Column-major view-projection of eye-relative positions for `camera`: the view rotation,
/// then a reversed-Z perspective with an infinite far plane (depth = near / distance, 1 at the
/// near plane, 0 at infinity).
pub fn view_proj(camera: &Camera, aspect: f64, near: f64) -> [[f32; 4]; 4] {
    let b = camera.basis();
    let f = 1.0 / (camera.fov_y_deg.to_radians() / 2.0).tan();
    // View: rows right, up, −forward (the camera looks down −Z).
    let rows = [b.right, b.up, scale(b.forward, -1.0)];
    // clip = (f/aspect·x, f·y, near, −z).
    let mut m = [[0.0f32; 4]; 4];
    for c in 0..3 {
        m[c][0] = (f / aspect * rows[0][c]) as f32;
        m[c][1] = (f * rows[1][c]) as f32;
        m[c][2] = 0.0;
        m[c][3] = (-rows[2][c]) as f32;
    }
    m[3] = [0.0, 0.0, near as f32, 0.0];
    m
}

/// The sun by its sub-solar point, as `penumbra shadow --sun-lat --sun-lon` takes it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunPos {
    /// Sub-solar latitude and longitude (degrees).
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Apparent radius of the disc (degrees), from the distance to the Sun.
    pub radius_deg: f64,
}

impl SunPos {
    /// The library's [`Sun`], built exactly as `penumbra::shadow::tile_shadows` builds it.
    pub fn sun(&self) -> Sun {
        Sun {
            dir: cube::latlon_to_dir(self.lat_deg.to_radians(), self.lon_deg.to_radians()),
            radius_deg: self.radius_deg,
        }
    }

    /// Compass azimuth and elevation of the sun's centre at direction `at` (degrees).
    pub fn local(&self, at: Vec3) -> (f64, f64) {
        local_az_el(at, self.sun().dir)
    }

    /// Move the sun so that it stands at compass azimuth `az_deg` and elevation `el_deg` at
    /// direction `at`: the new sub-solar point.
    pub fn set_local(&mut self, at: Vec3, az_deg: f64, el_deg: f64) {
        let d = local_dir(at, az_deg, el_deg.clamp(-90.0, 90.0));
        let (lat, lon) = cube::dir_to_latlon(d);
        self.lat_deg = lat.to_degrees();
        self.lon_deg = lon.to_degrees();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const R: f64 = 1_737_400.0;

    #[test]
    fn the_sun_moves_to_the_asked_azimuth_and_elevation() {
        let mut s = SunPos {
            lat_deg: 0.0,
            lon_deg: 0.0,
            radius_deg: 0.27,
        };
        let at = cube::latlon_to_dir(f64::to_radians(-89.5), f64::to_radians(10.0));
        s.set_local(at, 135.0, 2.5);
        let (az, el) = s.local(at);
        assert!((az - 135.0).abs() < 1e-9 && (el - 2.5).abs() < 1e-9);
    }

    #[test]
    fn reversed_z_maps_near_to_one_and_far_to_zero() {
        let c = Camera::at(R, 0.0, 0.0, 1000.0, 0.0, -90.0, 60.0);
        let m = view_proj(&c, 1.0, 2.0);
        let f = c.basis().forward;
        let clip = |d: f64| {
            let p = scale(f, d);
            let mut o = [0.0f64; 4];
            for (r, v) in o.iter_mut().enumerate() {
                *v = (0..3).map(|k| m[k][r] as f64 * p[k]).sum::<f64>() + m[3][r] as f64;
            }
            o
        };
        let n = clip(2.0);
        assert!((n[2] / n[3] - 1.0).abs() < 1e-6);
        let far = clip(1.0e7);
        assert!(far[2] / far[3] < 1e-6 && far[2] / far[3] > 0.0);
        assert!(far[0].abs() < 1e-3 && far[1].abs() < 1e-3);
    }
}
