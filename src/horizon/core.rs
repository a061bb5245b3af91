//! The two horizon algorithms over a [`Context`] raster: the brute-force [`reference`] search
//! and the fast method (exact near field in [`super::near`], per-azimuth upper-hull [`sweep`]
//! beyond). Conventions and error analysis: docs/horizons.md.

use rayon::prelude::*;

use super::near;
use crate::cube::{Face, Vec3};

/// Heights on a rectangle of one face's *extended gnomonic plane* at one level's pixel spacing,
/// reaching past the face edges (there the neighbouring faces' tiles are resampled). On a
/// gnomonic plane straight lines are great circles, which both algorithms rely on.
#[derive(Clone, Debug)]
pub struct Context {
    pub face: Face,
    /// Pixels across the face at this level (S).
    pub face_pixels: f64,
    /// Global face pixel (column, row) of raster pixel (0, 0); may be negative or ≥ S.
    pub origin: (i64, i64),
    pub width: usize,
    pub height: usize,
    /// Row-major heights above the reference sphere (m); NaN = no terrain.
    pub heights: Vec<f32>,
    /// Reference sphere radius (m).
    pub radius_m: f64,
}

/// A rectangle of observer pixels in raster coordinates (half-open).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x0: usize,
    pub y0: usize,
    pub w: usize,
    pub h: usize,
}

/// Which algorithm computes the horizons.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Each pixel's own ray searched exactly out to a near field (`near_px`, default 24 px),
    /// beyond that a per-azimuth sweep of parallel great circles with an upper convex hull
    /// per line.
    #[default]
    Fast,
    /// Brute force: each pixel's own ray walked cell by cell to the end of the context, the
    /// maximum over the continuous bilinear surface.
    Reference,
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "fast" => Ok(Method::Fast),
            "reference" => Ok(Method::Reference),
            _ => Err(format!("unknown method '{s}' (fast, reference)")),
        }
    }
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Fast => "fast",
            Method::Reference => "reference",
        }
    }
}

/// Plane azimuth of sample k of `a`: counter-clockwise from the face's +U axis, radians.
#[inline]
pub fn plane_azimuth(k: usize, a: usize) -> f64 {
    std::f64::consts::TAU * k as f64 / a as f64
}

impl Context {
    /// Gnomonic plane coordinates (u, v) of fractional raster pixel (x, y).
    #[inline]
    pub fn uv(&self, x: f64, y: f64) -> (f64, f64) {
        let s = self.face_pixels;
        (
            -1.0 + 2.0 * (self.origin.0 as f64 + x + 0.5) / s,
            1.0 - 2.0 * (self.origin.1 as f64 + y + 0.5) / s,
        )
    }

    /// The (unnormalised) plane point n + u·U + v·V of raster pixel (x, y).
    #[inline]
    pub fn plane_point(&self, x: f64, y: f64) -> Vec3 {
        let (u, v) = self.uv(x, y);
        let (n, a, b) = self.face.axes();
        [
            n[0] + u * a[0] + v * b[0],
            n[1] + u * a[1] + v * b[1],
            n[2] + u * a[2] + v * b[2],
        ]
    }

    /// Unit direction of raster pixel (x, y).
    #[inline]
    pub fn dir(&self, x: f64, y: f64) -> Vec3 {
        normalize(self.plane_point(x, y))
    }

    /// Height of raster pixel (x, y); NaN outside the raster.
    #[inline]
    pub fn at(&self, x: i64, y: i64) -> f32 {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            return f32::NAN;
        }
        self.heights[y as usize * self.width + x as usize]
    }

    /// Bilinear height at fractional raster pixel (x, y), in f64 (near the observer the height
    /// differences are millimetres, below an f32's resolution of a height): taps with zero weight and no-data
    /// taps are left out and the rest renormalised; NaN when none is left or (x, y) is outside.
    #[inline]
    pub fn bilinear64(&self, x: f64, y: f64) -> f64 {
        // A point computed to lie on the raster's edge may land a rounding error outside.
        let (wm, hm) = ((self.width - 1) as f64, (self.height - 1) as f64);
        let (x, y) = (snap(x, wm), snap(y, hm));
        if !(x >= 0.0 && y >= 0.0 && x <= wm && y <= hm) {
            return f64::NAN;
        }
        // x, y ≥ 0 here, so truncation is floor (and needs no libm call on baseline x86-64).
        let (xi, yi) = (x as i64, y as i64);
        let (fx, fy) = (x - xi as f64, y - yi as f64);
        let mut acc = 0.0f64;
        let mut wsum = 0.0f64;
        for (dx, dy, w) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            if w == 0.0 {
                continue;
            }
            let v = self.at(xi + dx, yi + dy);
            if v.is_nan() {
                continue;
            }
            acc += w * v as f64;
            wsum += w;
        }
        if wsum > 0.0 {
            acc / wsum
        } else {
            f64::NAN
        }
    }

    /// Largest height in the raster (NaN-free), or −∞ when it holds no terrain.
    pub fn max_height(&self) -> f32 {
        self.heights
            .iter()
            .fold(f32::NEG_INFINITY, |m, &v| if v > m { v } else { m })
    }

    /// Slope (tan of elevation) of the terrain leaving pixel (x0, y0) along plane azimuth φ,
    /// in the limit of zero distance: the one-sided directional derivative of the bilinear
    /// surface at the pixel centre (the curvature drop vanishes there), with `g` the ground
    /// metres per plane pixel along φ. NaN when a needed neighbour has no data. Both methods
    /// include it, so a bare sphere reads 0 at h = 0.
    #[inline]
    pub(super) fn slope0_g(&self, x0: usize, y0: usize, cos: f64, sin: f64, g: f64) -> f64 {
        let (cx, cy) = (cos, -sin);
        let (x, y) = (x0 as i64, y0 as i64);
        let h0 = self.at(x, y) as f64;
        let mut dh = 0.0;
        if cx.abs() > 1e-12 {
            let hx = self.at(x + cx.signum() as i64, y) as f64;
            dh += (hx - h0) * cx.abs();
        }
        if cy.abs() > 1e-12 {
            let hy = self.at(x, y + cy.signum() as i64) as f64;
            dh += (hy - h0) * cy.abs();
        }
        dh / g
    }
}

/// `x` moved onto [0, hi] when it is within 1e-9 of it.
#[inline(always)]
fn snap(x: f64, hi: f64) -> f64 {
    if x < 0.0 && x > -1e-9 {
        0.0
    } else if x > hi && x < hi + 1e-9 {
        hi
    } else {
        x
    }
}

#[inline]
fn normalize(p: Vec3) -> Vec3 {
    let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / n, p[1] / n, p[2] / n]
}

#[inline]
fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Horizons of every pixel of `rect` in `a` plane azimuths: `a` planes of `rect.w × rect.h`
/// elevation angles in degrees (row-major), plane k at plane azimuth 2πk/a. NaN where the
/// observer has no data; −90 where nothing at all lies in a direction.
pub fn horizons(ctx: &Context, rect: Rect, a: usize, method: Method) -> Vec<f32> {
    horizons_with(ctx, rect, a, method, near::DEFAULT_NEAR_PX)
}

/// [`horizons`] with the fast method's exact near field reaching `near_px` plane pixels
/// (0..=[`near::MAX_NEAR_PX`]; the reference ignores it): larger is slower and closer to the
/// reference.
pub fn horizons_with(
    ctx: &Context,
    rect: Rect,
    a: usize,
    method: Method,
    near_px: f64,
) -> Vec<f32> {
    assert!(rect.x0 + rect.w <= ctx.width && rect.y0 + rect.h <= ctx.height);
    assert!(
        (0.0..=near::MAX_NEAR_PX).contains(&near_px),
        "near field of {near_px} px outside 0..={}",
        near::MAX_NEAR_PX
    );
    let plane = rect.w * rect.h;
    let mut out = vec![0.0f32; plane * a];
    if plane == 0 {
        return out;
    }
    match method {
        Method::Fast => {
            let geo = pixel_geometry(ctx, rect);
            let nodata = near::NoData::new(ctx);
            out.par_chunks_mut(plane).enumerate().for_each_init(
                || FastBuffers::new(plane),
                |b, (k, dst)| {
                    let phi = plane_azimuth(k, a);
                    let az = Azimuth::new(ctx, phi);
                    let walk = near::NearWalk::new(&az, near_px);
                    near::near_field(ctx, rect, &az, &walk, &geo, &nodata, &mut b.ns, &mut b.near);
                    b.acc.fill(f64::NEG_INFINITY);
                    b.acc_s.fill(f64::NAN);
                    sweep(
                        ctx,
                        rect,
                        phi,
                        &b.near,
                        &mut b.acc,
                        &mut b.acc_s,
                        &mut b.sweep,
                    );
                    finish(
                        ctx, rect, &az, near_px, &geo, &b.near, &b.acc, &b.acc_s, dst,
                    );
                },
            )
        }
        Method::Reference => {
            let hmax = ctx.max_height();
            let geo = pixel_geometry(ctx, rect);
            out.par_chunks_mut(plane).enumerate().for_each(|(k, dst)| {
                reference(ctx, rect, plane_azimuth(k, a), hmax, 0.0, &geo, dst)
            })
        }
    }
    out
}

/// The reference sampling every `step` plane pixels instead of the exact cell-by-cell search
/// (tests: how far a sampled march is from the continuous answer).
#[doc(hidden)]
pub fn horizons_reference_step(ctx: &Context, rect: Rect, a: usize, step: f64) -> Vec<f32> {
    let plane = rect.w * rect.h;
    let mut out = vec![0.0f32; plane * a];
    let hmax = ctx.max_height();
    let geo = pixel_geometry(ctx, rect);
    out.par_chunks_mut(plane)
        .enumerate()
        .for_each(|(k, dst)| reference(ctx, rect, plane_azimuth(k, a), hmax, step, &geo, dst));
    out
}

/// Per-thread buffers of the fast method, one azimuth at a time.
struct FastBuffers {
    /// Exact maximum slope within the near field of each observer.
    near: Vec<f64>,
    /// The sweep's best slope per observer beyond that, and its distance (plane pixels).
    acc: Vec<f64>,
    acc_s: Vec<f64>,
    sweep: Scratch,
    ns: near::NearScratch,
}

impl FastBuffers {
    fn new(plane: usize) -> FastBuffers {
        FastBuffers {
            near: vec![0.0; plane],
            acc: vec![0.0; plane],
            acc_s: vec![0.0; plane],
            sweep: Scratch::default(),
            ns: near::NearScratch::default(),
        }
    }
}

/// How far (in slope, tan of elevation) below an observer's best so far a line's estimate of a
/// far candidate may lie and still be evaluated on the observer's own ray (≈ 1.7° at the
/// horizontal). The lines pass up to ½ px beside the ray; beyond the near field that moves an
/// elevation by far less (docs/horizons.md).
const SKIP: f64 = 0.03;

/// Elevations (degrees) from the near field, the sweep's winners evaluated exactly on each
/// observer's own ray, an exact search of that ray around the winner, and the zero-distance
/// slope.
#[allow(clippy::too_many_arguments)]
fn finish(
    ctx: &Context,
    rect: Rect,
    az: &Azimuth,
    near_px: f64,
    geo: &[PixelGeo],
    near: &[f64],
    acc: &[f64],
    acc_s: &[f64],
    dst: &mut [f32],
) {
    let (cos, sin) = (az.cos, az.sin);
    for j in 0..rect.h {
        for i in 0..rect.w {
            let (x, y) = (rect.x0 + i, rect.y0 + j);
            let o = j * rect.w + i;
            let h0 = ctx.at(x as i64, y as i64);
            if h0.is_nan() {
                dst[o] = f32::NAN;
                continue;
            }
            let ray = Ray::from_parts(ctx, x, y, &geo[o], az);
            let mut t = near[o];
            let sw = acc_s[o];
            if sw.is_finite() {
                // Every value reported is the elevation of a real point of this ray, evaluated
                // exactly (so fast ≤ reference). The lines pass up to ½ px beside the ray:
                // around the sweep's winner the ray is searched exactly, which includes the
                // winner itself, unless the near field is far ahead; then the winner alone.
                if acc[o] >= t - SKIP {
                    t = t.max(
                        ray.max_over(ctx, (sw - WINDOW).max(near_px), sw + WINDOW, t)
                            .0,
                    );
                } else {
                    t = t.max(ray.slope_at(ctx, sw));
                }
            }
            let s0 = ctx.slope0_g(x, y, cos, sin, ray.ground_per_px());
            if s0 > t {
                t = s0;
            }
            dst[o] = t.atan().to_degrees() as f32;
        }
    }
}

/// Per observer pixel: its unit direction and the length of its plane point.
#[derive(Clone, Copy)]
pub(super) struct PixelGeo {
    ph: Vec3,
    pub(super) n0: f64,
}

/// Per azimuth: cos φ, sin φ and the plane step per pixel w = (2/S)(cos φ·U + sin φ·V).
pub(super) struct Azimuth {
    pub(super) cos: f64,
    pub(super) sin: f64,
    w: Vec3,
    w2: f64,
}

impl Azimuth {
    pub(super) fn new(ctx: &Context, phi: f64) -> Azimuth {
        let (cos, sin) = (phi.cos(), phi.sin());
        let (_, u, v) = ctx.face.axes();
        let k = 2.0 / ctx.face_pixels;
        let w = [
            k * (cos * u[0] + sin * v[0]),
            k * (cos * u[1] + sin * v[1]),
            k * (cos * u[2] + sin * v[2]),
        ];
        Azimuth {
            cos,
            sin,
            w,
            w2: dot(w, w),
        }
    }

    /// The plane step per pixel split along the observer's direction and across it: the
    /// plane point at distance s is (n0 + s·a1, s·b1) in the ray's great-circle plane.
    #[inline]
    pub(super) fn along(&self, g: &PixelGeo) -> (f64, f64) {
        let a1 = dot(self.w, g.ph);
        (a1, (self.w2 - a1 * a1).max(0.0).sqrt())
    }
}

pub(super) fn pixel_geometry(ctx: &Context, rect: Rect) -> Vec<PixelGeo> {
    let mut v = Vec::with_capacity(rect.w * rect.h);
    for j in 0..rect.h {
        for i in 0..rect.w {
            let p = ctx.plane_point((rect.x0 + i) as f64, (rect.y0 + j) as f64);
            let n0 = dot(p, p).sqrt();
            v.push(PixelGeo {
                ph: [p[0] / n0, p[1] / n0, p[2] / n0],
                n0,
            });
        }
    }
    v
}

/// Half-width (plane pixels) of the window searched exactly around the sweep's winner.
const WINDOW: f64 = 0.75;

/// An observer's ray in a context raster: the plane line (x0, y0) + s·(cos φ, −sin φ), s in
/// plane pixels, which is a great circle.
pub(super) struct Ray {
    x0: f64,
    y0: f64,
    cx: f64,
    cy: f64,
    h0: f64,
    r0: f64,
    /// The ray's great-circle plane, with the observer's direction as first axis: the plane
    /// point at distance s is (a0 + s·a1, s·b1) there.
    a0: f64,
    a1: f64,
    b1: f64,
    /// Curvature drop per plane pixel², metres (for locating maxima inside a cell only).
    kappa: f64,
}

impl Ray {
    /// The ray from pixel (x, y), whose unit direction `ph` and plane-point length `n0` are
    /// given (they do not depend on the azimuth), along plane step `w` per pixel (which does
    /// not depend on the pixel).
    #[inline]
    pub(super) fn from_parts(ctx: &Context, x: usize, y: usize, g: &PixelGeo, az: &Azimuth) -> Ray {
        let h0 = ctx.at(x as i64, y as i64) as f64;
        let r0 = ctx.radius_m + h0;
        let (a1, b1) = az.along(g);
        let gm = r0 * b1 / g.n0;
        Ray {
            x0: x as f64,
            y0: y as f64,
            cx: az.cos,
            cy: -az.sin,
            h0,
            r0,
            a0: g.n0,
            a1,
            b1,
            kappa: gm * gm / (2.0 * r0),
        }
    }

    /// Ground metres per plane pixel along the ray at the observer: r0·dψ/ds = r0·b1/a0.
    #[inline]
    pub(super) fn ground_per_px(&self) -> f64 {
        self.r0 * self.b1 / self.a0
    }

    /// Slope (tan of elevation) of the terrain at distance `s`: bilinear height, exact
    /// spherical geometry — with cos ψ = a/‖(a,b)‖ and sin ψ = b/‖(a,b)‖ the slope
    /// (r cos ψ − r0)/(r sin ψ) is (r·a − r0·‖(a,b)‖)/(r·b); −∞ outside the raster or over no
    /// data.
    #[inline]
    fn slope_at(&self, ctx: &Context, s: f64) -> f64 {
        let v = ctx.bilinear64(self.x0 + s * self.cx, self.y0 + s * self.cy);
        if v.is_nan() {
            return f64::NEG_INFINITY;
        }
        let (a, b) = (self.a0 + s * self.a1, s * self.b1);
        let n = (a * a + b * b).sqrt();
        let r = ctx.radius_m + v;
        (r * a - self.r0 * n) / (r * b)
    }

    /// Slope of terrain of height `h` at distance `s` (as [`Ray::slope_at`]).
    #[inline]
    fn slope_of(&self, ctx: &Context, s: f64, h: f64) -> f64 {
        let (a, b) = (self.a0 + s * self.a1, s * self.b1);
        let n = (a * a + b * b).sqrt();
        let r = ctx.radius_m + h;
        (r * a - self.r0 * n) / (r * b)
    }

    /// The largest slope over the continuous bilinear surface along the ray for s in
    /// [s_from, s_to] (s = 0 itself left out), and where it is. Cell by cell: along the ray
    /// the bilinear height is a quadratic in s, so with the curvature drop the slope
    /// (A + B·s + C·s²)/(g·s) peaks inside a cell only at s* = √(A/C); the interval's start,
    /// the crossings and s* are evaluated exactly.
    pub(super) fn max_over(&self, ctx: &Context, s_from: f64, s_to: f64, floor: f64) -> (f64, f64) {
        let (mut best, mut at) = (floor, f64::NAN);
        let (w1, h1) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
        let (x, y) = (self.x0 + s_from * self.cx, self.y0 + s_from * self.cy);
        if !(x >= 0.0 && y >= 0.0 && x <= w1 && y <= h1) || s_from >= s_to {
            return (best, at);
        }
        let mut ax = Axis::new(x, self.cx, s_from);
        let mut ay = Axis::new(y, self.cy, s_from);
        let (nx, ny) = (ctx.width as i64, ctx.height as i64);
        // The walk evaluates where the ray leaves each cell; inside the first cell the slope may
        // peak where the interval starts (a window around a sweep winner begins mid-cell).
        if s_from > 0.0 {
            let sl = self.slope_at(ctx, s_from);
            if sl > best {
                best = sl;
                at = s_from;
            }
        }
        let mut s = s_from;
        while s < s_to && ax.i >= 0 && ay.i >= 0 && ax.i < nx && ay.i < ny {
            let (ix, iy) = (ax.i, ay.i);
            let s_next = ax.next.min(ay.next).min(s_to);
            let (h00, h10, h01, h11) = (
                ctx.at(ix, iy) as f64,
                ctx.at(ix + 1, iy) as f64,
                ctx.at(ix, iy + 1) as f64,
                ctx.at(ix + 1, iy + 1) as f64,
            );
            if !(h00.is_nan() || h10.is_nan() || h01.is_nan() || h11.is_nan()) {
                // Along the ray the cell's bilinear surface is h(s) = c0 + c1·s + c2·s².
                let (a, b, c) = (h10 - h00, h01 - h00, h11 - h10 - h01 + h00);
                let (ex, ey) = (self.x0 - ix as f64, self.y0 - iy as f64);
                let c0 = h00 + a * ex + b * ey + c * ex * ey;
                let c1 = a * self.cx + b * self.cy + c * (ex * self.cy + ey * self.cx);
                let c2 = c * self.cx * self.cy;
                let mut try_at = |st: f64| {
                    let sl = self.slope_of(ctx, st, c0 + st * (c1 + st * c2));
                    if sl > best {
                        best = sl;
                        at = st;
                    }
                };
                try_at(s_next);
                let (ca, cc) = (c0 - self.h0, c2 - self.kappa);
                if ca != 0.0 && cc != 0.0 && ca / cc > 0.0 {
                    let st = (ca / cc).sqrt();
                    if st > s && st < s_next {
                        try_at(st);
                    }
                }
            } else {
                // No-data corners, or the raster's last row/column: the general bilinear
                // (no-data taps left out, outside the raster none).
                let sl = self.slope_at(ctx, s_next);
                if sl > best {
                    best = sl;
                    at = s_next;
                }
            }
            s = s_next;
            ax.advance(s);
            ay.advance(s);
        }
        (best, at)
    }
}

/// One axis of an Amanatides–Woo cell walk along a ray: the cell index, its step (±1, 0) and
/// the distances (along the ray) of the next grid-line crossing and between crossings.
pub(super) struct Axis {
    pub(super) i: i64,
    step: i64,
    pub(super) next: f64,
    delta: f64,
}

impl Axis {
    /// At coordinate `x` ≥ 0, reached at distance `s0`, moving `d` per unit distance: the cell
    /// the ray is in just after (leaving a grid line backwards, the cell below it).
    #[inline]
    pub(super) fn new(x: f64, d: f64, s0: f64) -> Axis {
        // x ≥ 0: truncation is floor.
        let fl = (x as i64) as f64;
        let (i, step, next, delta) = if d > 1e-12 {
            (fl as i64, 1, (fl + 1.0 - x) / d, 1.0 / d)
        } else if d < -1e-12 {
            let c = if fl == x { fl - 1.0 } else { fl };
            (c as i64, -1, (x - c) / -d, -1.0 / d)
        } else {
            (fl as i64, 0, f64::INFINITY, f64::INFINITY)
        };
        Axis {
            i,
            step,
            next: next + s0,
            delta,
        }
    }

    /// Steps into the next cell when the walk has reached this axis' crossing.
    #[inline]
    pub(super) fn advance(&mut self, s: f64) {
        if self.next <= s {
            self.i += self.step;
            self.next += self.delta;
        }
    }
}

/// `x.ceil()` without a libm call on baseline x86-64 (|x| < 2⁶³).
#[inline(always)]
fn ceil(x: f64) -> f64 {
    let t = (x as i64) as f64;
    if t < x {
        t + 1.0
    } else {
        t
    }
}

/// Brute-force horizons of `rect` in plane azimuth `phi`: from each pixel centre along the
/// straight plane line (a great circle), exact spherical geometry; with `step` = 0 the
/// continuous bilinear surface cell by cell ([`Ray::max_over`]), else samples every `step`
/// plane pixels. Stops where no terrain up to `hmax` could rise above the best so far.
fn reference(
    ctx: &Context,
    rect: Rect,
    phi: f64,
    hmax: f32,
    step: f64,
    geo: &[PixelGeo],
    dst: &mut [f32],
) {
    let az = Azimuth::new(ctx, phi);
    let (cos, sin) = (az.cos, az.sin);
    let r_max = ctx.radius_m + hmax as f64;
    for j in 0..rect.h {
        for i in 0..rect.w {
            let (x0, y0) = (rect.x0 + i, rect.y0 + j);
            let o = j * rect.w + i;
            if ctx.at(x0 as i64, y0 as i64).is_nan() {
                dst[o] = f32::NAN;
                continue;
            }
            let ray = Ray::from_parts(ctx, x0, y0, &geo[o], &az);
            let s0 = ctx.slope0_g(x0, y0, cos, sin, ray.ground_per_px());
            let mut best = if s0.is_nan() { f64::NEG_INFINITY } else { s0 };
            // Chunks of 8 pixels (or `step` samples), each preceded by the stopping test.
            let chunk = if step > 0.0 { step } else { 8.0 };
            let mut s = 0.0;
            loop {
                let (x, y) = (ray.x0 + s * ray.cx, ray.y0 + s * ray.cy);
                if !(x >= 0.0
                    && y >= 0.0
                    && x <= (ctx.width - 1) as f64
                    && y <= (ctx.height - 1) as f64)
                {
                    break;
                }
                if s > 0.0 {
                    // Highest conceivable terrain here, as a slope: it only falls with
                    // distance, so nothing farther can beat `best`.
                    let (a, b) = (ray.a0 + s * ray.a1, s * ray.b1);
                    let n = (a * a + b * b).sqrt();
                    if (r_max * a - ray.r0 * n) <= best * r_max * b {
                        break;
                    }
                }
                if step > 0.0 {
                    let sl = ray.slope_at(ctx, s + step);
                    if sl > best {
                        best = sl;
                    }
                } else {
                    best = best.max(ray.max_over(ctx, s, s + chunk, best).0);
                }
                s += chunk;
            }
            dst[o] = best.atan().to_degrees() as f32;
        }
    }
}

/// A point of a line's profile in the line's great-circle plane: `x` along the sweep, `y` up
/// (the body centre is the origin).
#[derive(Clone, Copy, Debug)]
struct Pt {
    x: f64,
    y: f64,
    /// Line parameter (major-axis coordinate) of the sample.
    p: f64,
    /// 1 / |A + p·B|: the sample's direction without its height, for re-placing it at
    /// another height.
    inv: f64,
}

#[inline]
fn cross(o: Pt, a: Pt, b: Pt) -> f64 {
    (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x)
}

/// One line's profile: the upper hull of the samples seen so far, and the line's plane frame.
struct Line<'a> {
    pts: &'a mut Vec<Pt>,
    a0: f64,
    a1: f64,
    b0: f64,
    b1: f64,
}

impl Line<'_> {
    /// Position of line parameter `p` at radius `r`.
    #[inline]
    fn pos(&self, p: f64, r: f64) -> Pt {
        let a = self.a0 + p * self.a1;
        let b = self.b0 + p * self.b1;
        let inv = 1.0 / (a * a + b * b).sqrt();
        let k = r * inv;
        Pt {
            x: b * k,
            y: a * k,
            p,
            inv,
        }
    }

    /// Point `v`'s direction at radius `r`.
    #[inline]
    fn at_radius(&self, v: Pt, r: f64) -> Pt {
        let a = self.a0 + v.p * self.a1;
        let b = self.b0 + v.p * self.b1;
        let k = r * v.inv;
        Pt {
            x: b * k,
            y: a * k,
            p: v.p,
            inv: v.inv,
        }
    }

    #[inline]
    fn push(&mut self, q: Pt) {
        // Pop while the top is on the body's side of (or on) the segment from the one below it
        // to the new point: the chain keeps turning clockwise.
        while self.pts.len() >= 2 {
            let n = self.pts.len();
            if cross(self.pts[n - 2], self.pts[n - 1], q) >= 0.0 {
                self.pts.pop();
            } else {
                break;
            }
        }
        self.pts.push(q);
    }

    /// The profile point seen highest from observer `o`, or None when the profile is empty.
    /// `finger` is where the last search on this line ended.
    #[inline]
    fn query(&self, o: Pt, finger: &mut usize) -> Option<usize> {
        let h = &self.pts[..];
        if h.is_empty() {
            return None;
        }
        // `better(a, b)`: a is seen higher than b from o.
        let better = |a: Pt, b: Pt| cross(o, a, b) > 0.0;
        // Seen from o the elevation along the hull is unimodal: climb from the finger.
        let mut i = (*finger).min(h.len() - 1);
        if i + 1 < h.len() && better(h[i + 1], h[i]) {
            while i + 1 < h.len() && better(h[i + 1], h[i]) {
                i += 1;
            }
        } else {
            while i > 0 && better(h[i - 1], h[i]) {
                i -= 1;
            }
        }
        *finger = i;
        Some(i)
    }
}

/// Slope (tan of elevation above the local horizontal) of `q` seen from `o`, both in one line's
/// frame, looking against the sweep.
#[inline]
fn slope(o: Pt, q: Pt) -> f64 {
    let (up, hor) = up_hor(o, q);
    if hor > 0.0 {
        up / hor
    } else {
        f64::NEG_INFINITY
    }
}

/// Whether `q` seen from `o` is at a slope below `thr` (no division).
#[inline]
fn below(o: Pt, q: Pt, thr: f64) -> bool {
    let (up, hor) = up_hor(o, q);
    !(hor > 0.0 && up >= thr * hor)
}

/// The offset from `o` to `q` along `o`'s up and along the horizontal towards the look
/// direction (against the sweep), both scaled by |o| (their ratio is the slope).
#[inline]
fn up_hor(o: Pt, q: Pt) -> (f64, f64) {
    let (vx, vy) = (q.x - o.x, q.y - o.y);
    // Up ∝ (o.x, o.y); horizontal ∝ (−o.y, o.x).
    (vx * o.x + vy * o.y, vy * o.x - vx * o.y)
}

/// Raster access in (major, minor) = (p, q) coordinates of one sweep.
struct Grid<'a> {
    h: &'a [f32],
    /// Index steps for +1 in p and in q.
    sp: usize,
    sq: usize,
    np: i64,
    nq: i64,
}

impl Grid<'_> {
    #[inline(always)]
    fn at(&self, p: i64, q: i64) -> f32 {
        self.h[p as usize * self.sp + q as usize * self.sq]
    }

    /// Bilinear height at (p, q) in the raster (callers check the range), no-data taps left
    /// out (as [`Context::bilinear`]).
    #[inline(always)]
    fn bilinear(&self, p: f64, q: f64) -> f32 {
        let (p0, q0) = (p as i64, q as i64);
        let (fp, fq) = (p - p0 as f64, q - q0 as f64);
        let i = p0 as usize * self.sp + q0 as usize * self.sq;
        let p1 = if p0 + 1 < self.np { self.sp } else { 0 };
        let q1 = if q0 + 1 < self.nq { self.sq } else { 0 };
        let (a, b, c, d) = (
            self.h[i],
            self.h[i + p1],
            self.h[i + q1],
            self.h[i + p1 + q1],
        );
        let (wa, wb, wc, wd) = (
            (1.0 - fp) * (1.0 - fq),
            fp * (1.0 - fq),
            (1.0 - fp) * fq,
            fp * fq,
        );
        if !(a.is_nan() || b.is_nan() || c.is_nan() || d.is_nan()) {
            return (wa * a as f64 + wb * b as f64 + wc * c as f64 + wd * d as f64) as f32;
        }
        let (mut acc, mut ws) = (0.0, 0.0);
        for (v, w) in [(a, wa), (b, wb), (c, wc), (d, wd)] {
            if w > 0.0 && !v.is_nan() {
                acc += w * v as f64;
                ws += w;
            }
        }
        if ws > 0.0 {
            (acc / ws) as f32
        } else {
            f32::NAN
        }
    }

    #[inline(always)]
    fn inside(&self, p: f64, q: f64) -> bool {
        p >= 0.0 && q >= 0.0 && p <= (self.np - 1) as f64 && q <= (self.nq - 1) as f64
    }
}

/// The fast sweep for one plane azimuth: lines parallel to the look direction, one pixel apart
/// along the minor axis, swept from the far end of the raster towards the observers, each
/// keeping the upper convex hull of its profile (samples where it crosses pixel columns and
/// rows: exact bilinear values). An observer asks the two lines that bracket it at its own
/// column for the hull vertex it sees highest; unless that is hopelessly below what the
/// observer already has (`near`, earlier lines), the vertex and its hull neighbours are then
/// evaluated on the observer's own ray at the same distance, and the highest wins. Writes the
/// best slope per observer into `acc` (max) and its distance into `acc_s`.
fn sweep(
    ctx: &Context,
    rect: Rect,
    phi: f64,
    near: &[f64],
    acc: &mut [f64],
    acc_s: &mut [f64],
    scratch: &mut Scratch,
) {
    let (dx, dy) = (phi.cos(), -phi.sin());
    let xmajor = dx.abs() >= dy.abs();
    let (dp, dq) = if xmajor { (dx, dy) } else { (dy, dx) };
    let t = dq / dp;
    let look: i64 = if dp > 0.0 { 1 } else { -1 };
    let step = -look;
    let g = if xmajor {
        Grid {
            h: &ctx.heights,
            sp: 1,
            sq: ctx.width,
            np: ctx.width as i64,
            nq: ctx.height as i64,
        }
    } else {
        Grid {
            h: &ctx.heights,
            sp: ctx.width,
            sq: 1,
            np: ctx.height as i64,
            nq: ctx.width as i64,
        }
    };
    let (np, nq) = (g.np, g.nq);
    let (rp0, rp1, rq0, rq1) = if xmajor {
        (rect.x0, rect.x0 + rect.w, rect.y0, rect.y0 + rect.h)
    } else {
        (rect.y0, rect.y0 + rect.h, rect.x0, rect.x0 + rect.w)
    };
    let (rp0, rp1, rq0, rq1) = (rp0 as i64, rp1 as i64, rq0 as i64, rq1 as i64);
    // (i, j) offsets of an observer in `acc`: index = i·si + j·sj with (p, q) relative.
    let (si, sj) = if xmajor { (1, rect.w) } else { (rect.w, 1) };
    // Sweep from the raster's far end (in the look direction) to the observers' last column.
    let (p_first, p_last) = if look > 0 {
        (np - 1, rp0)
    } else {
        (0, rp1 - 1)
    };
    // Lines q_m(p) = m + t·p that bracket an observer.
    let m_at = |p: i64, q: i64| q as f64 - t * p as f64;
    let ms = [
        m_at(rp0, rq0),
        m_at(rp0, rq1 - 1),
        m_at(rp1 - 1, rq0),
        m_at(rp1 - 1, rq1 - 1),
    ];
    let m_lo = ms.iter().cloned().fold(f64::INFINITY, f64::min).floor() as i64 - 1;
    let m_hi = ms.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil() as i64 + 1;
    let (n, ua, va) = ctx.face.axes();
    let plane = |p: f64, q: f64| -> Vec3 {
        let (x, y) = if xmajor { (p, q) } else { (q, p) };
        let (u, v) = ctx.uv(x, y);
        [
            n[0] + u * ua[0] + v * va[0],
            n[1] + u * ua[1] + v * va[1],
            n[2] + u * ua[2] + v * va[2],
        ]
    };
    let radius = ctx.radius_m;
    for m in m_lo..=m_hi {
        let mf = m as f64;
        // The part of the sweep where the line is within a pixel of the raster.
        let (mut pa, mut pb) = (p_first.min(p_last), p_first.max(p_last));
        if t != 0.0 {
            let (e0, e1) = ((-1.0 - mf) / t, (nq as f64 - mf) / t);
            let (lo, hi) = (e0.min(e1), e0.max(e1));
            pa = pa.max(lo.floor() as i64);
            pb = pb.min(hi.ceil() as i64);
        } else if mf < -1.0 || mf > nq as f64 {
            continue;
        }
        if pa > pb {
            continue;
        }
        let (start, stop) = if step < 0 { (pb, pa) } else { (pa, pb) };
        // Line frame: A + p·B spans a plane through the body centre; e1 = up at the middle of
        // the swept range, e2 = the sweep direction.
        let a_pt = plane(0.0, mf);
        let b_pt = plane(1.0, mf + t);
        let bv = [b_pt[0] - a_pt[0], b_pt[1] - a_pt[1], b_pt[2] - a_pt[2]];
        let pm = 0.5 * (start + stop) as f64;
        let e1 = normalize(plane(pm, mf + t * pm));
        let sb = [
            step as f64 * bv[0],
            step as f64 * bv[1],
            step as f64 * bv[2],
        ];
        let k = dot(sb, e1);
        let e2 = normalize([sb[0] - k * e1[0], sb[1] - k * e1[1], sb[2] - k * e1[2]]);
        let mut hull = std::mem::take(&mut scratch.hull);
        hull.clear();
        let mut line = Line {
            pts: &mut hull,
            a0: dot(a_pt, e1),
            a1: dot(bv, e1),
            b0: dot(a_pt, e2),
            b1: dot(bv, e2),
        };
        // 1. The line's samples in sweep order, and where each observer column comes.
        let sc = &mut *scratch;
        sc.p.clear();
        sc.h.clear();
        sc.marks.clear();
        let mut prev_y = f64::NAN;
        let mut p = start;
        loop {
            let y = mf + t * p as f64;
            // The row crossing between the previous column and this one lies ahead of this
            // column's observers (one at most as |t| ≤ 1; none within 1e-6 px of a column,
            // where it would duplicate the column's sample).
            if !prev_y.is_nan() {
                let (lo, hi) = if prev_y < y { (prev_y, y) } else { (y, prev_y) };
                let kq = ceil(lo);
                if kq > lo + 1e-6 && kq < hi - 1e-6 && kq >= 0.0 && kq <= (nq - 1) as f64 {
                    let pc = (kq - mf) / t;
                    sc.p.push(pc);
                    sc.h.push(g.bilinear(pc, kq));
                }
            }
            prev_y = y;
            if p >= rp0 && p < rp1 {
                sc.marks.push((sc.p.len(), p, y));
            }
            if y >= 0.0 && y <= (nq - 1) as f64 {
                sc.p.push(p as f64);
                sc.h.push(g.bilinear(p as f64, y));
            }
            if p == stop {
                break;
            }
            p += step;
        }
        // 2. Their positions in the line's plane (independent: vectorised, no latency chain).
        let len = sc.p.len();
        sc.x.resize(len, 0.0);
        sc.y.resize(len, 0.0);
        sc.inv.resize(len, 0.0);
        let (a0, a1, b0, b1) = (line.a0, line.a1, line.b0, line.b1);
        for i in 0..len {
            let pp = sc.p[i];
            let (a, b) = (a0 + pp * a1, b0 + pp * b1);
            let inv = 1.0 / (a * a + b * b).sqrt();
            let k = (radius + sc.h[i] as f64) * inv;
            sc.x[i] = b * k;
            sc.y[i] = a * k;
            sc.inv[i] = inv;
        }
        // 3. The hull, and the observers' queries where their columns come.
        let mut fingers = [usize::MAX; 2];
        let mut mi = 0;
        for i in 0..=len {
            while mi < sc.marks.len() && sc.marks[mi].0 == i {
                let (_, p, y) = sc.marks[mi];
                mi += 1;
                let qa = ceil(y);
                let f = qa - y;
                let qa = qa as i64;
                for (side, q0, w) in [(0, qa, 1.0 - f), (1, qa - 1, f)] {
                    if w <= 0.0 || q0 < rq0 || q0 >= rq1 {
                        continue;
                    }
                    let h0 = g.at(p, q0);
                    if h0.is_nan() {
                        continue;
                    }
                    let o = line.pos(p as f64, radius + h0 as f64);
                    let Some(iv) = line.query(o, &mut fingers[side]) else {
                        continue;
                    };
                    let idx = (p - rp0) as usize * si + (q0 - rq0) as usize * sj;
                    // The line only guides: where its best vertex, seen from the observer
                    // placed on the line, could beat what the observer has, the vertex and its
                    // hull neighbours are evaluated on the observer's own ray at the same
                    // distance.
                    if below(o, line.pts[iv], acc[idx].max(near[idx]) - SKIP) {
                        continue;
                    }
                    let hi = (iv + 1).min(line.pts.len() - 1);
                    let mut best: Option<Pt> = None;
                    for c in iv.saturating_sub(1)..=hi {
                        let v = line.pts[c];
                        let mut pv = v.p;
                        let mut qv = q0 as f64 + t * (pv - p as f64);
                        if !(qv >= 0.0 && qv <= (nq - 1) as f64) {
                            // Beyond where the observer's ray leaves the raster (the line
                            // runs on beside it): take that exit point instead.
                            qv = if qv < 0.0 { 0.0 } else { (nq - 1) as f64 };
                            pv = p as f64 + (qv - q0 as f64) / t;
                        }
                        if !g.inside(pv, qv) {
                            continue;
                        }
                        let hv = g.bilinear(pv, qv);
                        if hv.is_nan() {
                            continue;
                        }
                        let c = if pv == v.p {
                            line.at_radius(v, radius + hv as f64)
                        } else {
                            line.pos(pv, radius + hv as f64)
                        };
                        if best.is_none_or(|b| cross(o, c, b) > 0.0) {
                            best = Some(c);
                        }
                    }
                    if let Some(b) = best {
                        let sl = slope(o, b);
                        if sl > acc[idx] {
                            acc[idx] = sl;
                            // Distance along the ray, plane pixels.
                            acc_s[idx] = (b.p - p as f64) / dp;
                        }
                    }
                }
            }
            if i < len && !sc.h[i].is_nan() {
                line.push(Pt {
                    x: sc.x[i],
                    y: sc.y[i],
                    p: sc.p[i],
                    inv: sc.inv[i],
                });
            }
        }
        scratch.hull = hull;
    }
}

/// Per-line buffers of the sweep, reused from line to line.
#[derive(Default)]
pub(crate) struct Scratch {
    hull: Vec<Pt>,
    p: Vec<f64>,
    h: Vec<f32>,
    x: Vec<f64>,
    y: Vec<f64>,
    inv: Vec<f64>,
    marks: Vec<(usize, i64, f64)>,
}

/// Compass azimuth (degrees clockwise from local north, in [0, 360)) of plane azimuth `phi`
/// (radians, counter-clockwise from +U) at gnomonic point (u, v) of `face`. North is the
/// direction towards +Z along the meridian; at the poles themselves, where it is undefined,
/// north is the limit along the 0° meridian (−X at the north pole, +X at the south pole).
pub fn compass_azimuth_deg(face: Face, u: f64, v: f64, phi: f64) -> f64 {
    let (n, ua, va) = face.axes();
    let p = normalize([
        n[0] + u * ua[0] + v * va[0],
        n[1] + u * ua[1] + v * va[1],
        n[2] + u * ua[2] + v * va[2],
    ]);
    let w = [
        phi.cos() * ua[0] + phi.sin() * va[0],
        phi.cos() * ua[1] + phi.sin() * va[1],
        phi.cos() * ua[2] + phi.sin() * va[2],
    ];
    let k = dot(w, p);
    let t = [w[0] - k * p[0], w[1] - k * p[1], w[2] - k * p[2]];
    let z = [0.0, 0.0, 1.0];
    let kz = dot(z, p);
    let mut north = [z[0] - kz * p[0], z[1] - kz * p[1], z[2] - kz * p[2]];
    if dot(north, north) < 1e-24 {
        north = if p[2] > 0.0 {
            [-1.0, 0.0, 0.0]
        } else {
            [1.0, 0.0, 0.0]
        };
    }
    let north = normalize(north);
    // East = north × up.
    let east = [
        north[1] * p[2] - north[2] * p[1],
        north[2] * p[0] - north[0] * p[2],
        north[0] * p[1] - north[1] * p[0],
    ];
    dot(t, east)
        .atan2(dot(t, north))
        .to_degrees()
        .rem_euclid(360.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hull query finds the sample seen highest among *all* samples pushed so far, from
    /// observers beyond them at random heights, with the finger carried between queries.
    #[test]
    fn hull_query_equals_a_scan_of_every_sample() {
        let mut st = 0x9E37_79B9_7F4A_7C15u64;
        let mut rnd = || {
            st ^= st << 13;
            st ^= st >> 7;
            st ^= st << 17;
            (st >> 11) as f64 / (1u64 << 53) as f64
        };
        let r = 1_737_400.0;
        for trial in 0..200 {
            // A line through the body's plane: a = 1 (towards the observer), b = p·spacing.
            let spacing = [1e-5, 1e-3, 5e-2][trial % 3];
            let mut hull = Vec::new();
            let mut line = Line {
                pts: &mut hull,
                a0: 1.0,
                a1: 0.0,
                b0: 0.0,
                b1: spacing,
            };
            let mut all = Vec::new();
            let mut finger = usize::MAX;
            let relief = [10.0, 1000.0, 20_000.0][trial % 3];
            for i in 0..300 {
                let p = i as f64;
                let q = line.pos(p, r + relief * (rnd() - 0.5));
                line.push(q);
                all.push(q);
                if i % 7 == 6 {
                    let o = line.pos(p + 1.0 + rnd() * 3.0, r + relief * (rnd() - 0.5));
                    let iv = line.query(o, &mut finger).unwrap();
                    let best = all
                        .iter()
                        .map(|&v| slope(o, v))
                        .fold(f64::NEG_INFINITY, f64::max);
                    let got = slope(o, line.pts[iv]);
                    assert!(
                        (got - best).abs() <= 1e-9 * (1.0 + best.abs()),
                        "trial {trial} step {i}: hull {got} scan {best}"
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod poly_check {
    use super::*;

    #[test]
    fn cell_polynomial_equals_bilinear() {
        let (w, h) = (32usize, 32usize);
        let mut st = 99u64;
        let heights: Vec<f32> = (0..w * h)
            .map(|_| {
                st ^= st << 13;
                st ^= st >> 7;
                st ^= st << 17;
                ((st >> 11) as f64 / (1u64 << 53) as f64 * 500.0) as f32
            })
            .collect();
        let s = (2.0f64 * 1_737_400.0 / 100.0).round();
        let ctx = Context {
            face: Face::Px,
            face_pixels: s,
            origin: ((s as i64 - 32) / 2, (s as i64 - 32) / 2),
            width: w,
            height: h,
            heights,
            radius_m: 1_737_400.0,
        };
        for k in 0..16 {
            let phi = plane_azimuth(k, 16) + 0.1;
            let geo = pixel_geometry(
                &ctx,
                Rect {
                    x0: 15,
                    y0: 16,
                    w: 1,
                    h: 1,
                },
            );
            let ray = Ray::from_parts(&ctx, 15, 16, &geo[0], &Azimuth::new(&ctx, phi));
            let (e, at) = ray.max_over(&ctx, 0.5, 10.0, f64::NEG_INFINITY);
            let direct = ray.slope_at(&ctx, at);
            assert!(
                (e - direct).abs() < 1e-9,
                "k {k}: max_over {e} at {at}, slope_at there {direct}"
            );
            // Over intervals starting and ending anywhere inside cells (the fast method's
            // windows), the search is never below a fine sampling of the same interval, its
            // ends included (to 1e-8: inside a cell the peak is located with the curvature
            // drop as a parabola; above it only by what the samples step over at a kink).
            for j in 0..40 {
                let s_from = 0.37 + 0.29 * j as f64;
                let s_to = s_from + 0.2 + 0.05 * (j % 7) as f64;
                let (e, _) = ray.max_over(&ctx, s_from, s_to, f64::NEG_INFINITY);
                let n = 2000;
                let sampled = (0..=n)
                    .map(|i| ray.slope_at(&ctx, s_from + (s_to - s_from) * i as f64 / n as f64))
                    .fold(f64::NEG_INFINITY, f64::max);
                assert!(
                    e >= sampled - 1e-8 && e <= sampled + 1e-3,
                    "k {k}: max_over [{s_from}, {s_to}] = {e}, sampled {sampled}"
                );
            }
        }
    }
}
