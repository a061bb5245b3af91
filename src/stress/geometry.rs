//! What the cases share: synthetic contexts, exact spherical geometry for their answers, the
//! kernels as the catalogue calls them (with the [`Weaken`] switch applied to their output).

use crate::cube::{angle_between, Face, Vec3};
use crate::fourier::sun::{Frame, Sun};
use crate::horizon::{self, Context, Method, Rect};
use crate::shadow::trace::{self, Runs, Tracer, Work};

use super::types::Weaken;

pub(crate) const MOON_R: f64 = 1_737_400.0;
pub(crate) const MARS_R: f64 = 3_396_190.0;
/// Jupiter's equatorial radius (IAU 2015), metres.
pub(crate) const JUPITER_R: f64 = 71_492_000.0;
/// The Sun's angular radius from 1 AU, degrees.
pub(crate) const SUN_R: f64 = 0.2666;

/// The four horizon methods.
pub(crate) const HORIZON_METHODS: [Method; 4] = [
    Method::Reference,
    Method::Exact,
    Method::Fast,
    Method::Sweep,
];

/// The soft ray-marching methods (their lit fraction is a disc fraction).
pub(crate) fn soft_methods() -> [trace::Method; 4] {
    [
        trace::Method::Reference,
        trace::Method::Dp {
            runs: Runs::Auto,
            dda: false,
        },
        trace::Method::Dp {
            runs: Runs::Auto,
            dda: true,
        },
        trace::Method::ExtremaSoft,
    ]
}

/// Pixels across a face whose centre pixel is `pixel_m` metres wide.
pub(crate) fn face_pixels(radius_m: f64, pixel_m: f64) -> f64 {
    (2.0 * radius_m / pixel_m).round()
}

/// Origin that centres a `w × h` raster on the face centre.
pub(crate) fn centred(s: f64, w: usize, h: usize) -> (i64, i64) {
    let s = s as i64;
    ((s - w as i64).div_euclid(2), (s - h as i64).div_euclid(2))
}

/// A context whose height at raster pixel (x, y) is `f(x, y)`.
pub(crate) fn build(
    face: Face,
    radius_m: f64,
    s: f64,
    origin: (i64, i64),
    (w, h): (usize, usize),
    f: impl Fn(usize, usize) -> f64 + Sync,
) -> Context {
    use rayon::prelude::*;
    let mut heights = vec![0.0f32; w * h];
    heights.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, v) in row.iter_mut().enumerate() {
            *v = f(x, y) as f32;
        }
    });
    Context {
        face,
        face_pixels: s,
        origin,
        width: w,
        height: h,
        heights,
        radius_m,
    }
}

pub(crate) fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn lin(a: f64, p: Vec3, b: f64, q: Vec3) -> Vec3 {
    [
        a * p[0] + b * q[0],
        a * p[1] + b * q[1],
        a * p[2] + b * q[2],
    ]
}

pub(crate) fn normalize(p: Vec3) -> Vec3 {
    let n = dot(p, p).sqrt();
    [p[0] / n, p[1] / n, p[2] / n]
}

/// Elevation (degrees) of a point at radius `r` and angular distance `psi` seen from radius
/// `r0`: atan((r cos ψ − r0)/(r sin ψ)), with r cos ψ − r0 written as (r − r0) − 2r sin²(ψ/2).
pub(crate) fn elevation(r0: f64, r: f64, psi: f64) -> f64 {
    let hs = (0.5 * psi).sin();
    ((r - r0) - 2.0 * r * hs * hs)
        .atan2(r * psi.sin())
        .to_degrees()
}

/// Elevation (degrees) from raster pixel (x0, y0), at its own height, of the fractional raster
/// point (x, y) at height `h`.
pub(crate) fn elevation_to(ctx: &Context, x0: usize, y0: usize, x: f64, y: f64, h: f64) -> f64 {
    let r0 = ctx.radius_m + ctx.at(x0 as i64, y0 as i64) as f64;
    let psi = angle_between(ctx.dir(x0 as f64, y0 as f64), ctx.dir(x, y));
    elevation(r0, ctx.radius_m + h, psi)
}

/// Geometric dip (degrees, negative) of the horizon from height `h` over a sphere of radius
/// `r`: −acos(r/(r+h)), as an atan for accuracy.
pub(crate) fn dip_deg(r: f64, h: f64) -> f64 {
    -((2.0 * r * h + h * h).sqrt() / r).atan().to_degrees()
}

/// Plane azimuth (radians, [0, 2π)) of the raster step (dx, dy) (raster y grows downwards).
pub(crate) fn azimuth_of(dx: f64, dy: f64) -> f64 {
    (-dy).atan2(dx).rem_euclid(std::f64::consts::TAU)
}

/// The one-pixel rectangle at (x, y).
pub(crate) fn pixel(x: usize, y: usize) -> Rect {
    Rect {
        x0: x,
        y0: y,
        w: 1,
        h: 1,
    }
}

/// Unit steps along the 4 axes, then the 4 diagonals, of a raster.
pub(crate) const AXES_AND_DIAGONALS: [(i64, i64); 8] = [
    (1, 0),
    (0, 1),
    (-1, 0),
    (0, -1),
    (1, 1),
    (-1, 1),
    (-1, -1),
    (1, -1),
];

/// The horizon kernel as the catalogue runs it: `horizon::horizons`, weakened on request.
pub(crate) fn horizons(ctx: &Context, rect: Rect, a: usize, m: Method, weaken: Weaken) -> Vec<f32> {
    let device = SWEEP_DEVICE
        .read()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    let mut out = match device {
        Some(d) if m == Method::Sweep => {
            horizon::device::horizons_sweep_on(d.as_ref(), ctx, rect, a)
                .unwrap_or_else(|e| panic!("the sweep device failed: {e}"))
        }
        _ => horizon::horizons(ctx, rect, a, m),
    };
    if weaken == Weaken::HorizonFloorZero {
        out.iter_mut().for_each(|v| *v = v.max(0.0));
    }
    out
}

/// The sun as the shadow kernels see it: a point under [`Weaken::ShadowPointSun`].
pub(crate) fn sun_for(sun: Sun, weaken: Weaken) -> Sun {
    if weaken == Weaken::ShadowPointSun {
        Sun {
            radius_deg: 0.0,
            ..sun
        }
    } else {
        sun
    }
}

/// (lit, horizon) of a ray-marching method at raster pixel (x, y).
pub(crate) fn trace(
    tr: &Tracer,
    x: usize,
    y: usize,
    sun: &Sun,
    m: &trace::Method,
    weaken: Weaken,
) -> (f64, f64) {
    let t = tr.trace(x, y, &sun_for(*sun, weaken), m, &mut Work::default());
    (t.lit, t.horizon_deg)
}

/// The frame at raster pixel (x, y).
pub(crate) fn frame(ctx: &Context, x: usize, y: usize) -> Frame {
    let (u, v) = ctx.uv(x as f64, y as f64);
    Frame::at(ctx.face, u, v)
}

/// The horizontal unit direction at `f` whose plane azimuth is `phi`.
pub(crate) fn tangent(f: &Frame, phi: f64) -> Vec3 {
    let w = lin(phi.cos(), f.ua, phi.sin(), f.va);
    normalize(lin(1.0, w, -dot(w, f.up), f.up))
}

/// A sun of radius `r` (degrees) seen from raster pixel (x, y) in plane azimuth `phi` at
/// elevation `el` (degrees).
pub(crate) fn sun_toward(ctx: &Context, x: usize, y: usize, phi: f64, el: f64, r: f64) -> Sun {
    let f = frame(ctx, x, y);
    let (se, ce) = el.to_radians().sin_cos();
    Sun {
        dir: lin(ce, tangent(&f, phi), se, f.up),
        radius_deg: r,
    }
}

/// Largest |a − b| over paired values, NaN when any value is not finite.
pub(crate) fn max_abs_diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).fold(0.0f64, |m, (&x, &y)| {
        if !(x.is_finite() && y.is_finite()) {
            f64::NAN
        } else {
            m.max((x as f64 - y as f64).abs())
        }
    })
}

/// A deterministic value in [0, 1) for (x, y, seed) (splitmix64).
pub(crate) fn hash01(x: usize, y: usize, seed: u64) -> f64 {
    let mut z = (x as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
        .wrapping_add(seed.wrapping_mul(0x1656_67B1_9E37_79F9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in [−1, 1] with cells of `cell` pixels (bilinear between hashed corners).
pub(crate) fn value_noise(x: f64, y: f64, cell: f64, seed: u64) -> f64 {
    let (fx, fy) = (x / cell, y / cell);
    let (i, j) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - i, fy - j);
    let g = |a: f64, b: f64| 2.0 * hash01(a as usize, b as usize, seed) - 1.0;
    g(i, j) * (1.0 - tx) * (1.0 - ty)
        + g(i + 1.0, j) * tx * (1.0 - ty)
        + g(i, j + 1.0) * (1.0 - tx) * ty
        + g(i + 1.0, j + 1.0) * tx * ty
}

/// Where the catalogue's sweep rows run (`penumbra stress --device gpu`): None, the CPU.
static SWEEP_DEVICE: std::sync::RwLock<Option<horizon::device::SharedDevice>> =
    std::sync::RwLock::new(None);

/// Runs the catalogue's sweep-method rows on `device` from now on (None: on the CPU), for
/// the whole process: `penumbra stress --device` and the GPU crate's tests.
pub fn set_sweep_device(device: Option<horizon::device::SharedDevice>) {
    *SWEEP_DEVICE.write().unwrap_or_else(|e| e.into_inner()) = device;
}

/// Whether [`set_sweep_device`] set a device.
pub(crate) fn sweep_device_set() -> bool {
    SWEEP_DEVICE
        .read()
        .unwrap_or_else(|e| e.into_inner())
        .is_some()
}
