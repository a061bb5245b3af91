//! The two horizon algorithms over a [`Context`] raster: the brute-force [`reference`] march and
//! the per-azimuth upper-hull [`fast`] sweep. Conventions and error analysis: docs/horizons.md.

use rayon::prelude::*;

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
    /// Per-azimuth sweep of parallel great circles with an upper convex hull per line.
    #[default]
    Fast,
    /// Brute-force march from every pixel, ½-pixel steps, bilinear heights.
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

    /// Bilinear height at fractional raster pixel (x, y): taps with zero weight and no-data
    /// taps are left out and the rest renormalised; NaN when none is left or (x, y) is outside.
    #[inline]
    pub fn bilinear(&self, x: f64, y: f64) -> f32 {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f64 && y <= (self.height - 1) as f64)
        {
            return f32::NAN;
        }
        let (fx0, fy0) = (x.floor(), y.floor());
        let (fx, fy) = (x - fx0, y - fy0);
        let (xi, yi) = (fx0 as i64, fy0 as i64);
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
            (acc / wsum) as f32
        } else {
            f32::NAN
        }
    }

    /// Largest height in the raster (NaN-free), or −∞ when it holds no terrain.
    pub fn max_height(&self) -> f32 {
        self.heights
            .iter()
            .fold(f32::NEG_INFINITY, |m, &v| if v > m { v } else { m })
    }

    /// Ground metres per plane pixel along plane azimuth `phi` at raster pixel (x, y), at
    /// radius `r`.
    #[inline]
    fn metres_per_px(&self, x: f64, y: f64, phi: f64, r: f64) -> f64 {
        let (u, v) = self.uv(x, y);
        let rho2 = 1.0 + u * u + v * v;
        let wp = u * phi.cos() + v * phi.sin();
        r * (2.0 / self.face_pixels) * (1.0 - wp * wp / rho2).max(0.0).sqrt() / rho2.sqrt()
    }

    /// Slope (tan of elevation) of the terrain leaving pixel (x0, y0) along plane azimuth
    /// `phi`, in the limit of zero distance: the one-sided directional derivative of the
    /// bilinear surface at the pixel centre (the curvature drop vanishes there). NaN when a
    /// needed neighbour has no data. Both methods include it, so a bare sphere reads 0 at h = 0.
    #[inline]
    pub fn slope0(&self, x0: usize, y0: usize, phi: f64) -> f64 {
        let (cx, cy) = (phi.cos(), -phi.sin());
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
        dh / self.metres_per_px(x0 as f64, y0 as f64, phi, self.radius_m + h0)
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
    assert!(rect.x0 + rect.w <= ctx.width && rect.y0 + rect.h <= ctx.height);
    let plane = rect.w * rect.h;
    let mut out = vec![0.0f32; plane * a];
    if plane == 0 {
        return out;
    }
    match method {
        Method::Fast => out.par_chunks_mut(plane).enumerate().for_each_init(
            || (vec![0.0f64; plane], Vec::new()),
            |(acc, hull), (k, dst)| {
                let phi = plane_azimuth(k, a);
                acc.iter_mut().for_each(|v| *v = f64::NEG_INFINITY);
                sweep::<true>(ctx, rect, phi, acc, hull);
                finish(ctx, rect, phi, acc, dst);
            },
        ),
        Method::Reference => {
            let hmax = ctx.max_height();
            out.par_chunks_mut(plane)
                .enumerate()
                .for_each(|(k, dst)| reference(ctx, rect, plane_azimuth(k, a), hmax, 0.5, dst))
        }
    }
    out
}

/// The reference with another step than ½ pixel (tests: how far the ½-pixel reference is
/// from the continuous answer).
#[doc(hidden)]
pub fn horizons_reference_step(ctx: &Context, rect: Rect, a: usize, step: f64) -> Vec<f32> {
    let plane = rect.w * rect.h;
    let mut out = vec![0.0f32; plane * a];
    let hmax = ctx.max_height();
    out.par_chunks_mut(plane)
        .enumerate()
        .for_each(|(k, dst)| reference(ctx, rect, plane_azimuth(k, a), hmax, step, dst));
    out
}

/// The fast sweep with every line sample kept and scanned instead of the hull (same samples,
/// same blending): isolates the hull logic in tests. Quadratic per line; tests only.
#[doc(hidden)]
pub fn horizons_scan(ctx: &Context, rect: Rect, a: usize) -> Vec<f32> {
    let plane = rect.w * rect.h;
    let mut out = vec![0.0f32; plane * a];
    for (k, dst) in out.chunks_mut(plane).enumerate() {
        let phi = plane_azimuth(k, a);
        let (mut acc, mut pts) = (vec![f64::NEG_INFINITY; plane], Vec::new());
        sweep::<false>(ctx, rect, phi, &mut acc, &mut pts);
        finish(ctx, rect, phi, &acc, dst);
    }
    out
}

/// Elevations (degrees) from the blended line slopes and the zero-distance slope.
fn finish(ctx: &Context, rect: Rect, phi: f64, acc: &[f64], dst: &mut [f32]) {
    for j in 0..rect.h {
        for i in 0..rect.w {
            let (x, y) = (rect.x0 + i, rect.y0 + j);
            let o = j * rect.w + i;
            if ctx.at(x as i64, y as i64).is_nan() {
                dst[o] = f32::NAN;
                continue;
            }
            let mut t = acc[o];
            let s0 = ctx.slope0(x, y, phi);
            if s0 > t {
                t = s0;
            }
            dst[o] = t.atan().to_degrees() as f32;
        }
    }
}

/// Brute-force horizons of `rect` in plane azimuth `phi`: from each pixel centre, samples every
/// ½ plane pixel along the straight plane line (a great circle), bilinear heights, exact
/// spherical geometry; stops where no terrain up to `hmax` could rise above the best so far.
fn reference(ctx: &Context, rect: Rect, phi: f64, hmax: f32, step: f64, dst: &mut [f32]) {
    let (cx, cy) = (phi.cos(), -phi.sin());
    let r_max = ctx.radius_m + hmax as f64;
    for j in 0..rect.h {
        for i in 0..rect.w {
            let (x0, y0) = (rect.x0 + i, rect.y0 + j);
            let h0 = ctx.at(x0 as i64, y0 as i64);
            let o = j * rect.w + i;
            if h0.is_nan() {
                dst[o] = f32::NAN;
                continue;
            }
            let r0 = ctx.radius_m + h0 as f64;
            let p = ctx.dir(x0 as f64, y0 as f64);
            let s0 = ctx.slope0(x0, y0, phi);
            let mut best = if s0.is_nan() { f64::NEG_INFINITY } else { s0 };
            let mut k = 1u32;
            loop {
                let (x, y) = (
                    x0 as f64 + step * k as f64 * cx,
                    y0 as f64 + step * k as f64 * cy,
                );
                k += 1;
                if !(x >= 0.0
                    && y >= 0.0
                    && x <= (ctx.width - 1) as f64
                    && y <= (ctx.height - 1) as f64)
                {
                    break;
                }
                let q = ctx.dir(x, y);
                let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
                let one_minus_cos = 0.5 * dot(d, d);
                let cr = [
                    p[1] * q[2] - p[2] * q[1],
                    p[2] * q[0] - p[0] * q[2],
                    p[0] * q[1] - p[1] * q[0],
                ];
                let sin = dot(cr, cr).sqrt();
                // Highest conceivable terrain here, as a slope: it only falls with distance.
                if ((r_max - r0) - r_max * one_minus_cos) <= best * r_max * sin {
                    break;
                }
                let v = ctx.bilinear(x, y);
                if v.is_nan() {
                    continue;
                }
                let r = ctx.radius_m + v as f64;
                let t = ((r - r0) - r * one_minus_cos) / (r * sin);
                if t > best {
                    best = t;
                }
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
}

#[inline]
fn cross(o: Pt, a: Pt, b: Pt) -> f64 {
    (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x)
}

/// One line's profile: the upper hull of the samples seen so far (or all of them when not
/// `HULL`), and the line's plane frame.
struct Line<'a, const HULL: bool> {
    pts: &'a mut Vec<Pt>,
    a0: f64,
    a1: f64,
    b0: f64,
    b1: f64,
    radius: f64,
}

impl<const HULL: bool> Line<'_, HULL> {
    /// Position of line parameter `p` at radius `r`.
    #[inline]
    fn pos(&self, p: f64, r: f64) -> Pt {
        let a = self.a0 + p * self.a1;
        let b = self.b0 + p * self.b1;
        let k = r / (a * a + b * b).sqrt();
        Pt {
            x: b * k,
            y: a * k,
            p,
        }
    }

    #[inline]
    fn push(&mut self, p: f64, h: f32) {
        if h.is_nan() {
            return;
        }
        let q = self.pos(p, self.radius + h as f64);
        if HULL {
            // Pop while the top is on the body's side of (or on) the segment from the one
            // below it to the new point: the chain keeps turning clockwise.
            while self.pts.len() >= 2 {
                let n = self.pts.len();
                if cross(self.pts[n - 2], self.pts[n - 1], q) >= 0.0 {
                    self.pts.pop();
                } else {
                    break;
                }
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
        Some(if HULL {
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
            i
        } else {
            let mut b = 0;
            for i in 1..h.len() {
                if better(h[i], h[b]) {
                    b = i;
                }
            }
            b
        })
    }
}

/// Slope (tan of elevation above the local horizontal) of `q` seen from `o`, both in one line's
/// frame, looking against the sweep.
#[inline]
fn slope(o: Pt, q: Pt) -> f64 {
    let (vx, vy) = (q.x - o.x, q.y - o.y);
    let len = (o.x * o.x + o.y * o.y).sqrt();
    let (ux, uy) = (o.x / len, o.y / len);
    // Up = (ux, uy); horizontal towards the look direction (against the sweep) = (−uy, ux).
    let up = vx * ux + vy * uy;
    let hor = -vx * uy + vy * ux;
    if hor > 0.0 {
        up / hor
    } else {
        f64::NEG_INFINITY
    }
}

const NB: usize = 1;
const SUB: i32 = 0;

/// The fast sweep for one plane azimuth: lines parallel to the look direction, one pixel apart
/// along the minor axis, swept from the far end of the raster towards the observers; each
/// observer queries the two lines that bracket it at its own column and blends their slopes by
/// distance. Accumulates into `acc_t` (weighted slopes) and `acc_w` (weights).
fn sweep<const HULL: bool>(
    ctx: &Context,
    rect: Rect,
    phi: f64,
    acc: &mut [f64],
    pts: &mut Vec<Pt>,
) {
    let (dx, dy) = (phi.cos(), -phi.sin());
    let xmajor = dx.abs() >= dy.abs();
    // (p, q) = (major, minor) raster axes.
    let (dp, dq) = if xmajor { (dx, dy) } else { (dy, dx) };
    let t = dq / dp;
    let look: i64 = if dp > 0.0 { 1 } else { -1 };
    let step = -look;
    let (np, nq) = if xmajor {
        (ctx.width as i64, ctx.height as i64)
    } else {
        (ctx.height as i64, ctx.width as i64)
    };
    let (rp0, rp1, rq0, rq1) = if xmajor {
        (rect.x0, rect.x0 + rect.w, rect.y0, rect.y0 + rect.h)
    } else {
        (rect.y0, rect.y0 + rect.h, rect.x0, rect.x0 + rect.w)
    };
    let (rp0, rp1, rq0, rq1) = (rp0 as i64, rp1 as i64, rq0 as i64, rq1 as i64);
    // Raster (x, y) of (p, q).
    let xy = |p: f64, q: f64| if xmajor { (p, q) } else { (q, p) };
    let at = |p: i64, q: i64| {
        if xmajor {
            ctx.at(p, q)
        } else {
            ctx.at(q, p)
        }
    };
    // Linear interpolation between two taps, a no-data tap left out.
    let lerp = |a: f32, b: f32, f: f64| -> f32 {
        if f == 0.0 {
            a
        } else if a.is_nan() {
            b
        } else if b.is_nan() {
            a
        } else {
            (a as f64 + (b as f64 - a as f64) * f) as f32
        }
    };
    // Sample at integer major coordinate p, minor coordinate y (exact bilinear there).
    let column_sample = |p: i64, y: f64| -> f32 {
        if !(y >= 0.0 && y <= (nq - 1) as f64) || p < 0 || p >= np {
            return f32::NAN;
        }
        let q0 = y.floor();
        let f = y - q0;
        let q0 = q0 as i64;
        lerp(at(p, q0), if f > 0.0 { at(p, q0 + 1) } else { f32::NAN }, f)
    };
    let row_sample = |pc: f64, q: i64| -> f32 {
        if !(pc >= 0.0 && pc <= (np - 1) as f64) || q < 0 || q >= nq {
            return f32::NAN;
        }
        let p0 = pc.floor();
        let f = pc - p0;
        let p0 = p0 as i64;
        lerp(at(p0, q), if f > 0.0 { at(p0 + 1, q) } else { f32::NAN }, f)
    };
    // Sweep range in p: from the raster's far end (in the look direction) to the observers'
    // last column.
    let (p_first, p_last) = if look > 0 {
        (np - 1, rp0)
    } else {
        (0, rp1 - 1)
    };
    // Lines: q_m(p) = m + t·p. Those that bracket an observer column.
    let m_at = |p: i64, q: f64| q - t * p as f64;
    let ms = [
        m_at(rp0, rq0 as f64),
        m_at(rp0, (rq1 - 1) as f64),
        m_at(rp1 - 1, rq0 as f64),
        m_at(rp1 - 1, (rq1 - 1) as f64),
    ];
    let m_lo = ms.iter().cloned().fold(f64::INFINITY, f64::min).floor() as i64 - 1;
    let m_hi = ms.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil() as i64 + 1;
    let (n, ua, va) = ctx.face.axes();
    // Plane point of (p, q): n + u U + v V with u, v affine in (x, y).
    let plane = |p: f64, q: f64| -> Vec3 {
        let (x, y) = xy(p, q);
        let (u, v) = ctx.uv(x, y);
        [
            n[0] + u * ua[0] + v * va[0],
            n[1] + u * ua[1] + v * va[1],
            n[2] + u * ua[2] + v * va[2],
        ]
    };
    let rw = rect.w as i64;
    for m in m_lo..=m_hi {
        let mf = m as f64;
        // Line frame: A + p·B spans a plane through the body centre; e1 = up at the middle of
        // the swept range, e2 = the sweep direction.
        let a_pt = plane(0.0, mf);
        let b_pt = plane(1.0, mf + t);
        let bv = [b_pt[0] - a_pt[0], b_pt[1] - a_pt[1], b_pt[2] - a_pt[2]];
        let pm = 0.5 * (p_first + p_last) as f64;
        let e1 = normalize(plane(pm, mf + t * pm));
        let sb = [step as f64 * bv[0], step as f64 * bv[1], step as f64 * bv[2]];
        let k = dot(sb, e1);
        let e2 = normalize([sb[0] - k * e1[0], sb[1] - k * e1[1], sb[2] - k * e1[2]]);
        pts.clear();
        let mut line = Line::<HULL> {
            pts: &mut *pts,
            a0: dot(a_pt, e1),
            a1: dot(bv, e1),
            b0: dot(a_pt, e2),
            b1: dot(bv, e2),
            radius: ctx.radius_m,
        };
        let (mut fa, mut fb) = (usize::MAX, usize::MAX);
        let mut p = p_first;
        let mut prev_y = f64::NAN;
        // The last crossing pushed (p, q): the bilinear surface is quadratic between two
        // crossings, so the midpoint of each such segment is sampled too.
        let mut last: Option<(f64, f64)> = None;
        let mut push = |line: &mut Line<HULL>, last: &mut Option<(f64, f64)>, pc: f64, qc: f64, v: f32| {
            if let Some((lp, lq)) = *last {
                let (mp, mq) = (0.5 * (lp + pc), 0.5 * (lq + qc));
                let (x, y) = xy(mp, mq);
                line.push(mp, ctx.bilinear(x, y));
            }
            *last = Some((pc, qc));
            line.push(pc, v);
        };
        loop {
            let y = mf + t * p as f64;
            // The row crossing between the previous column and this one lies ahead of this
            // column's observers (one at most as |t| ≤ 1; none when it falls within 1e-6 px of
            // a column, where it would duplicate the column's sample).
            if !prev_y.is_nan() {
                let (lo, hi) = if prev_y < y { (prev_y, y) } else { (y, prev_y) };
                let kq = lo.ceil();
                if kq > lo + 1e-6 && kq < hi - 1e-6 {
                    let pc = (kq - mf) / t;
                    push(&mut line, &mut last, pc, kq, row_sample(pc, kq as i64));
                }
            }
            prev_y = y;
            if p >= rp0 && p < rp1 {
                let qa = y.ceil();
                let f = qa - y;
                let qa = qa as i64;
                for (q0, w, finger) in [(qa, 1.0 - f, &mut fa), (qa - 1, f, &mut fb)] {
                    if w <= 0.0 || q0 < rq0 || q0 >= rq1 {
                        continue;
                    }
                    let h0 = at(p, q0);
                    if h0.is_nan() {
                        continue;
                    }
                    let o = line.pos(p as f64, ctx.radius_m + h0 as f64);
                    let Some(iv) = line.query(o, finger) else {
                        continue;
                    };
                    // The line only guides: the candidate is evaluated on the observer's own
                    // ray at the same distance (the vertex and its hull neighbours).
                    let mut best = f64::NEG_INFINITY;
                    let (nb, sub) = (NB, SUB);
                    let lo = iv.saturating_sub(nb);
                    let hi = (iv + nb).min(line.pts.len() - 1);
                    for c in lo..=hi {
                      for sdx in -sub..=sub {
                        let pv = line.pts[c].p + sdx as f64 * 0.25;
                        let (x, y) = xy(pv, q0 as f64 + t * (pv - p as f64));
                        let hv = ctx.bilinear(x, y);
                        if hv.is_nan() {
                            continue;
                        }
                        let sl = slope(o, line.pos(pv, ctx.radius_m + hv as f64));
                        if sl > best {
                            best = sl;
                        }
                      }
                    }
                    let (i, j) = if xmajor {
                        (p - rect.x0 as i64, q0 - rect.y0 as i64)
                    } else {
                        (q0 - rect.x0 as i64, p - rect.y0 as i64)
                    };
                    let idx = (j * rw + i) as usize;
                    if best > acc[idx] {
                        acc[idx] = best;
                    }
                }
            }
            push(&mut line, &mut last, p as f64, y, column_sample(p, y));
            if p == p_last {
                break;
            }
            p += step;
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
    dot(t, east).atan2(dot(t, north)).to_degrees().rem_euclid(360.0)
}
