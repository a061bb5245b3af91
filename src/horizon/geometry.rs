//! The geometry both horizon algorithms share: the [`Context`] raster on one face's extended
//! gnomonic plane, observer [`Rect`]s, plane and compass azimuths, and an observer's [`Ray`]
//! with the exact cell-by-cell search of the continuous bilinear surface along it (the
//! reference's search, and the near field's walk). Conventions: docs/horizons.md.

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

    /// Whether cell (ix, iy), spanning [ix, ix+1] × [iy, iy+1], has all four corners inside
    /// the raster and holding data: only there is the bilinear surface evaluated between the
    /// points where a ray leaves cells (see [`Ray::max_over`]).
    #[inline]
    fn cell_complete(&self, ix: i64, iy: i64) -> bool {
        [(0, 0), (1, 0), (0, 1), (1, 1)]
            .iter()
            .all(|&(dx, dy)| !self.at(ix + dx, iy + dy).is_nan())
    }

    /// Whether (x, y) lies in a complete cell or on the border of one ([`Context::cell_complete`];
    /// a point on a grid line belongs to the cells on both sides): the points of the bilinear
    /// surface the horizon methods evaluate anywhere, not only where a ray leaves a cell. Any
    /// point on a grid line would not do: a ray running along a grid line between two partial
    /// cells meets their renormalised plateau all the way, and [`Ray::max_over`] evaluates it
    /// only where the ray crosses the other grid lines (tried: the exact method then left the
    /// reference by degrees at data edges).
    #[inline]
    pub(crate) fn on_complete_cell(&self, x: f64, y: f64) -> bool {
        if !(x >= 0.0 && y >= 0.0) {
            return false;
        }
        let (xi, yi) = (x as i64, y as i64);
        let xs = if xi as f64 == x { xi - 1 } else { xi };
        let ys = if yi as f64 == y { yi - 1 } else { yi };
        if xs == xi && ys == yi {
            // Off the grid lines (nearly always): one cell.
            return self.cell_complete(xi, yi);
        }
        (xs..=xi).any(|cx| (ys..=yi).any(|cy| self.cell_complete(cx, cy)))
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
        let w = [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ];
        if xi + 1 < self.width as i64 && yi + 1 < self.height as i64 {
            // All four taps inside: without branches when they all hold data. A zero weight's
            // term adds ±0, which leaves the sums as skipping it would (they start at +0), so
            // the bytes are those of the general loop below.
            let i = yi as usize * self.width + xi as usize;
            let t = [
                self.heights[i],
                self.heights[i + 1],
                self.heights[i + self.width],
                self.heights[i + self.width + 1],
            ];
            if !t.iter().any(|v| v.is_nan()) {
                let (mut acc, mut wsum) = (0.0f64, 0.0f64);
                for (&wk, &tk) in w.iter().zip(&t) {
                    acc += wk * tk as f64;
                    wsum += wk;
                }
                return acc / wsum;
            }
        }
        let mut acc = 0.0f64;
        let mut wsum = 0.0f64;
        for ((dx, dy), w) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().zip(w) {
            // A tap whose weight is a rounding error (a point computed to lie on a grid line
            // may land 1e-14 px beside it) counts as none: renormalised alone, it would carry
            // its height across the whole cell to where the line's own taps have no data.
            if w < TAP_EPS {
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
    pub(crate) fn slope0_g(&self, x0: usize, y0: usize, cos: f64, sin: f64, g: f64) -> f64 {
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

/// Weights of a bilinear tap below this are rounding errors (see [`Context::bilinear64`]).
pub(super) const TAP_EPS: f64 = 1e-9;

/// `x` moved onto [0, hi] when it is within 1e-9 of it.
#[inline(always)]
pub(super) fn snap(x: f64, hi: f64) -> f64 {
    if x < 0.0 && x > -1e-9 {
        0.0
    } else if x > hi && x < hi + 1e-9 {
        hi
    } else {
        x
    }
}

#[inline]
pub(super) fn normalize(p: Vec3) -> Vec3 {
    let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / n, p[1] / n, p[2] / n]
}

#[inline]
pub(super) fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
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

/// An observer's ray in a context raster: the plane line (x0, y0) + s·(cos φ, −sin φ), s in
/// plane pixels, which is a great circle.
pub(crate) struct Ray {
    pub(crate) x0: f64,
    pub(crate) y0: f64,
    pub(crate) cx: f64,
    pub(crate) cy: f64,
    h0: f64,
    pub(crate) r0: f64,
    /// The ray's great-circle plane, with the observer's direction as first axis: the plane
    /// point at distance s is (a0 + s·a1, s·b1) there.
    pub(crate) a0: f64,
    pub(crate) a1: f64,
    pub(crate) b1: f64,
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
        Ray::from_point(ctx, x as f64, y as f64, h0, g, az)
    }

    /// The ray from fractional raster position (x, y) at height `h0`, whose plane point's
    /// direction and length are `g` (an observer of a finer raster of the same face plane seen
    /// in a coarser one: its position is not a pixel centre there, nor its height a sample).
    #[inline]
    pub(super) fn from_point(
        ctx: &Context,
        x: f64,
        y: f64,
        h0: f64,
        g: &PixelGeo,
        az: &Azimuth,
    ) -> Ray {
        let r0 = ctx.radius_m + h0;
        let (a1, b1) = az.along(g);
        let gm = r0 * b1 / g.n0;
        Ray {
            x0: x,
            y0: y,
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

    /// The ray from raster pixel (x, y) along plane azimuth `phi` (radians, counter-clockwise
    /// from +U): one pixel's [`Ray::from_parts`].
    pub(crate) fn toward(ctx: &Context, x: usize, y: usize, phi: f64) -> Ray {
        let p = ctx.plane_point(x as f64, y as f64);
        let n0 = dot(p, p).sqrt();
        let g = PixelGeo {
            ph: [p[0] / n0, p[1] / n0, p[2] / n0],
            n0,
        };
        Ray::from_parts(ctx, x, y, &g, &Azimuth::new(ctx, phi))
    }

    /// The observer's height above the reference sphere (m).
    #[inline]
    pub(crate) fn height(&self) -> f64 {
        self.h0
    }

    /// Ground metres per plane pixel along the ray at the observer: r0·dψ/ds = r0·b1/a0.
    #[inline]
    pub(crate) fn ground_per_px(&self) -> f64 {
        self.r0 * self.b1 / self.a0
    }

    /// Slope (tan of elevation) of the terrain at distance `s`: bilinear height, exact
    /// spherical geometry — with cos ψ = a/‖(a,b)‖ and sin ψ = b/‖(a,b)‖ the slope
    /// (r cos ψ − r0)/(r sin ψ) is (r·a − r0·‖(a,b)‖)/(r·b); −∞ outside the raster or over no
    /// data.
    #[inline]
    pub(crate) fn slope_at(&self, ctx: &Context, s: f64) -> f64 {
        let v = ctx.bilinear64(self.x0 + s * self.cx, self.y0 + s * self.cy);
        if v.is_nan() {
            return f64::NEG_INFINITY;
        }
        self.slope_of(ctx, s, v)
    }

    /// As [`Ray::slope_at`], but −∞ inside a cell with a no-data corner, where
    /// [`Ray::max_over`] evaluates only the ray's crossing out of the cell: the points every
    /// method agrees on ([`Context::on_complete_cell`]).
    #[inline]
    pub(crate) fn slope_on_surface(&self, ctx: &Context, s: f64) -> f64 {
        if !ctx.on_complete_cell(self.x0 + s * self.cx, self.y0 + s * self.cy) {
            return f64::NEG_INFINITY;
        }
        self.slope_at(ctx, s)
    }

    /// Slope of terrain of height `h` at distance `s` (as [`Ray::slope_at`]).
    #[inline]
    pub(crate) fn slope_of(&self, ctx: &Context, s: f64, h: f64) -> f64 {
        let (a, b) = (self.a0 + s * self.a1, s * self.b1);
        let n = (a * a + b * b).sqrt();
        let r = ctx.radius_m + h;
        (r * a - self.r0 * n) / (r * b)
    }

    /// [`Ray::slope_of`] of terrain of height `h` at distance `s` where it is above `best`,
    /// else `None`, mostly decided without its square root and division: with
    /// ‖(a,b)‖ ≥ a the slope is at most (h − h0)·a/(r·b), which lies above it by
    /// r0·(‖(a,b)‖ − a)/(r·b) ≈ ψ/2 (ψ: the angle at the body's centre). That bound is trusted
    /// only where ψ > 1e-7 (beyond 0.03 px on a 5 m/px Moon): there the gap is ≥ 25× what
    /// rounding can add to the exact formula's value (≈ 2e-16/ψ, from its r·a − r0·‖(a,b)‖),
    /// and the test leaves 1e-12 relative margin for its own rounding, so a point it drops is
    /// one whose exact slope would not have been above `best`.
    #[inline(always)]
    fn slope_if_above(&self, ctx: &Context, s: f64, h: f64, best: f64) -> Option<f64> {
        let (a, b) = (self.a0 + s * self.a1, s * self.b1);
        let rb = (ctx.radius_m + h) * b;
        let (num, lim) = ((h - self.h0) * a, best * rb);
        if b > 1e-7 * a && a > 0.0 && rb > 0.0 && num < lim - 1e-12 * (num.abs() + lim.abs()) {
            return None;
        }
        // Inlined, the compiler shares a, b and r with the screen above.
        let sl = self.slope_of(ctx, s, h);
        (sl > best).then_some(sl)
    }

    /// The largest slope over the continuous bilinear surface along the ray for s in
    /// [s_from, s_to] (s = 0 itself left out), and where it is. Cell by cell: along the ray
    /// the bilinear height is a quadratic in s, so with the curvature drop the slope
    /// (A + B·s + C·s²)/(g·s) peaks inside a cell only at s* = √(A/C); the interval's start,
    /// the crossings and s* are evaluated exactly.
    pub(crate) fn max_over(&self, ctx: &Context, s_from: f64, s_to: f64, floor: f64) -> (f64, f64) {
        let (mut best, mut at) = (floor, f64::NAN);
        let (w1, h1) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
        // A start computed to lie on the raster's edge may land a rounding error outside (a
        // ray along the edge row).
        let (x, y) = (
            snap(self.x0 + s_from * self.cx, w1),
            snap(self.y0 + s_from * self.cy, h1),
        );
        if !(x >= 0.0 && y >= 0.0 && x <= w1 && y <= h1) || s_from >= s_to {
            return (best, at);
        }
        let mut ax = Axis::new(x, self.cx, s_from);
        let mut ay = Axis::new(y, self.cy, s_from);
        let (nx, ny) = (ctx.width as i64, ctx.height as i64);
        // The walk evaluates where the ray leaves each cell; inside the first cell the slope may
        // peak where the interval starts (a window around a sweep winner begins mid-cell).
        // Only on a complete cell (see below): inside a partial one that point is no crossing.
        if s_from > 0.0 && ctx.on_complete_cell(x, y) {
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
            let (h00, h10, h01, h11) = if ix + 1 < nx && iy + 1 < ny {
                // The walk keeps ix, iy ≥ 0: the four corners are inside.
                let (i, w) = (iy as usize * ctx.width + ix as usize, ctx.width);
                let h = &ctx.heights;
                (
                    h[i] as f64,
                    h[i + 1] as f64,
                    h[i + w] as f64,
                    h[i + w + 1] as f64,
                )
            } else {
                (
                    ctx.at(ix, iy) as f64,
                    ctx.at(ix + 1, iy) as f64,
                    ctx.at(ix, iy + 1) as f64,
                    ctx.at(ix + 1, iy + 1) as f64,
                )
            };
            if !(h00.is_nan() || h10.is_nan() || h01.is_nan() || h11.is_nan()) {
                // Along the ray the cell's bilinear surface is h(s) = c0 + c1·s + c2·s².
                let (a, b, c) = (h10 - h00, h01 - h00, h11 - h10 - h01 + h00);
                let (ex, ey) = (self.x0 - ix as f64, self.y0 - iy as f64);
                let c0 = h00 + a * ex + b * ey + c * ex * ey;
                let c1 = a * self.cx + b * self.cy + c * (ex * self.cy + ey * self.cx);
                let c2 = c * self.cx * self.cy;
                let mut try_at = |st: f64| {
                    if let Some(sl) = self.slope_if_above(ctx, st, c0 + st * (c1 + st * c2), best) {
                        best = sl;
                        at = st;
                    }
                };
                try_at(s_next);
                let (ca, cc) = (c0 - self.h0, c2 - self.kappa);
                // s* = √(ca/cc) can lie in (s, s_next) only where ca/cc is in (s², s_next²):
                // tested first without the division and the root, widened by 0.1 % (far
                // beyond rounding) so that it never drops a cell the exact test takes.
                let (aa, ac) = (ca.abs(), cc.abs());
                let may = ac.is_nan()
                    || ac <= 1e-200
                    || ((ca > 0.0) == (cc > 0.0)
                        && aa >= 0.999 * s * s * ac
                        && aa <= 1.001 * s_next * s_next * ac);
                if may && ca != 0.0 && cc != 0.0 && ca / cc > 0.0 {
                    let st = (ca / cc).sqrt();
                    if st > s && st < s_next {
                        try_at(st);
                    }
                }
            } else if ax.next.min(ay.next) <= s_to + 1e-9 * (1.0 + s_to) {
                // No-data corners, or the raster's last row/column: the general bilinear
                // (no-data taps left out, outside the raster none) where the ray leaves the
                // cell, and only there. Inside such a cell the renormalised surface is a
                // plateau of its data corners reaching over the no-data; a window or chunk
                // ending there would see terrain that a walk over the whole ray, which meets
                // only crossings, does not: every method sees the same points this way. (An
                // interval computed to end at the crossing may end an ulp before it.)
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
pub(crate) struct Axis {
    pub(crate) i: i64,
    step: i64,
    pub(crate) next: f64,
    delta: f64,
}

impl Axis {
    /// At coordinate `x` ≥ 0, reached at distance `s0`, moving `d` per unit distance: the cell
    /// the ray is in just after (leaving a grid line backwards, the cell below it).
    #[inline]
    pub(crate) fn new(x: f64, d: f64, s0: f64) -> Axis {
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
    pub(crate) fn advance(&mut self, s: f64) {
        if self.next <= s {
            self.i += self.step;
            self.next += self.delta;
        }
    }
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

/// A horizon context of `w × h` heights (row-major, metres) with pixels of `pixel_m` on a Moon-sized
/// sphere, centred on face +X.
#[cfg(test)]
pub(crate) fn lunar_context(w: usize, h: usize, heights: Vec<f32>, pixel_m: f64) -> Context {
    let r = 1_737_400.0;
    let s = (2.0 * r / pixel_m).round();
    Context {
        face: crate::cube::Face::Px,
        face_pixels: s,
        origin: ((s as i64 - w as i64) / 2, (s as i64 - h as i64) / 2),
        width: w,
        height: h,
        heights,
        radius_m: r,
    }
}

#[cfg(test)]
mod poly_check {
    use super::*;

    /// The screen in [`Ray::slope_if_above`] never drops a point whose exact slope is above
    /// `best`, and keeps the exact slope's bytes: random bodies (a 5 m/px Moon to 10 km/px
    /// Mars pixels), observers across the face, distances from 1e-3 px to 5000 px, heights
    /// over ±10 km, and `best` just below, at and just above the exact slope, and far off.
    #[test]
    fn slope_screen_drops_only_points_below_best() {
        let mut rnd = crate::testutil::rng(0x51_09E5);
        let mut screened = 0usize;
        for trial in 0..400 {
            let (radius, pixel) = [
                (1_737_400.0, 5.0),
                (1_737_400.0, 7_600.0),
                (3_396_190.0, 463.0),
                (3_396_190.0, 10_000.0),
                (6_371_008.8, 30.0),
            ][trial % 5];
            let fp = (2.0f64 * radius / pixel).round();
            let ctx = Context {
                face: Face::Px,
                face_pixels: fp,
                origin: ((fp * rnd() * 0.9) as i64, (fp * rnd() * 0.9) as i64),
                width: 4,
                height: 4,
                heights: (0..16).map(|_| (rnd() * 4000.0 - 2000.0) as f32).collect(),
                radius_m: radius,
            };
            let ray = Ray::toward(&ctx, 1, 2, rnd() * std::f64::consts::TAU);
            for _ in 0..200 {
                let st = 10f64.powf(rnd() * 6.7 - 3.0);
                let h = rnd() * 20_000.0 - 10_000.0;
                let exact = ray.slope_of(&ctx, st, h);
                let off = exact.abs().max(1e-3) * 10f64.powf(rnd() * 4.0 - 6.0);
                for best in [
                    f64::NEG_INFINITY,
                    exact - off,
                    exact.next_down(),
                    exact,
                    exact + off,
                ] {
                    let got = ray.slope_if_above(&ctx, st, h, best);
                    let want = (exact > best).then_some(exact);
                    assert_eq!(
                        got.map(f64::to_bits),
                        want.map(f64::to_bits),
                        "R {radius}, {pixel} m/px, s {st}, h {h}, best {best}: exact {exact}"
                    );
                    screened += (got.is_none() && best < exact + off) as usize;
                }
            }
        }
        assert!(screened > 1000, "the screen took only {screened} points");
    }

    #[test]
    fn cell_polynomial_equals_bilinear() {
        let (w, h) = (32usize, 32usize);
        let mut rnd = crate::testutil::rng(99);
        let heights: Vec<f32> = (0..w * h).map(|_| (rnd() * 500.0) as f32).collect();
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
