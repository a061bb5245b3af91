//! The fast method's far field: sweeps of parallel great circles, each keeping the upper convex
//! hull of its profile. Over a tile's own raster, [`sweep_pair`] serves two opposite azimuths
//! at once and leaves [`Guesses`] that [`finish_pair`] searches exactly on each observer's own
//! ray; over a far ring, [`sweep`] evaluates its winners on the ring observers' rays itself
//! (docs/horizons.md).

use super::far::FarPass;
use super::geometry::{dot, normalize, snap, Azimuth, Context, PixelGeo, Ray, Rect, TAP_EPS};
use super::near;
use crate::cube::Vec3;

/// How far (in slope, tan of elevation) below an observer's best so far a line's estimate of a
/// far candidate may lie and still be evaluated on the observer's own ray (≈ 1.7° at the
/// horizontal). The lines pass up to ½ px beside the ray; beyond the near field that moves an
/// elevation by far less (docs/horizons.md).
pub(super) const SKIP: f64 = 0.03;

/// `dst` (degrees, as [`finish_pair`] without the zero-distance slope gives them, then raised by
/// far rings) raised to the zero-distance slope where that is higher: the same bytes as
/// [`finish_pair`] with it, since the degrees of a maximum are the maximum of the degrees.
pub(super) fn ground_slope(
    ctx: &Context,
    rect: Rect,
    az: &Azimuth,
    geo: &[PixelGeo],
    dst: &mut [f32],
) {
    let (cos, sin) = (az.cos, az.sin);
    let mut slopes = vec![0.0f64; rect.w];
    let mut deg = vec![0.0f32; rect.w];
    for j in 0..rect.h {
        let row = &mut dst[j * rect.w..(j + 1) * rect.w];
        for (i, slope) in slopes.iter_mut().enumerate() {
            let (x, y) = (rect.x0 + i, rect.y0 + j);
            *slope = if row[i].is_nan() {
                0.0
            } else {
                let ray = Ray::from_parts(ctx, x, y, &geo[j * rect.w + i], az);
                ctx.slope0_g(x, y, cos, sin, ray.ground_per_px())
            };
        }
        degrees(&slopes, &mut deg);
        for (d, s0) in row.iter_mut().zip(&deg) {
            if *s0 > *d {
                *d = *s0;
            }
        }
    }
}

/// `dst[k] = slope[k].atan().to_degrees() as f32`, the same bytes, for a row at once: a
/// branch-free arc tangent (Cephes' `atan`, relative error below 2.2e-16, i.e. ≈ 1 ulp)
/// that the compiler vectorises, checked per value: where the f32 it rounds to could differ
/// from the one the libm arc tangent gives (the degrees within 1e-13, relatively, of a
/// midpoint between two f32s), or the slope is not finite, libm's is taken. NaN slopes give
/// `f32::NAN`.
pub(super) fn degrees(slope: &[f64], dst: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F, checked just above.
            unsafe { degrees_avx512(slope, dst) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            unsafe { degrees_avx2(slope, dst) };
            return;
        }
    }
    degrees_generic(slope, dst)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn degrees_avx512(slope: &[f64], dst: &mut [f32]) {
    degrees_generic(slope, dst)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn degrees_avx2(slope: &[f64], dst: &mut [f32]) {
    degrees_generic(slope, dst)
}

#[inline(always)]
fn degrees_generic(slope: &[f64], dst: &mut [f32]) {
    const DEG: f64 = 180.0 / std::f64::consts::PI;
    let dst = &mut dst[..slope.len()];
    // Whether `v`, the degrees of finite slope `x`, rounds to the same f32 anywhere within the
    // arc tangent's error.
    let sure = |x: f64, v: f64| {
        let (lo, hi) = (v * (1.0 - 1e-13), v * (1.0 + 1e-13));
        x.is_finite() & ((lo as f32).to_bits() == (hi as f32).to_bits())
    };
    let mut all_sure = true;
    for (d, &x) in dst.iter_mut().zip(slope) {
        let v = atan_cephes(x) * DEG;
        *d = v as f32;
        all_sure &= sure(x, v);
    }
    if all_sure {
        return;
    }
    for (d, &x) in dst.iter_mut().zip(slope) {
        if !sure(x, atan_cephes(x) * DEG) {
            *d = if x.is_nan() {
                f32::NAN
            } else {
                x.atan().to_degrees() as f32
            };
        }
    }
}

/// `dst[k]` = the tangent of `deg[k]` degrees (|deg| ≤ 90; NaN stays NaN) for a row at once,
/// branch-free so that the compiler vectorises it (Cephes' `tan`, within a few ulp of libm's):
/// the slopes that stored degrees stand for, where only ≈ 1e-7 (an f32 ulp) matters.
pub(super) fn tangents(deg: &[f32], dst: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F, checked just above.
            unsafe { tangents_avx512(deg, dst) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            unsafe { tangents_avx2(deg, dst) };
            return;
        }
    }
    tangents_generic(deg, dst)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn tangents_avx512(deg: &[f32], dst: &mut [f64]) {
    tangents_generic(deg, dst)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn tangents_avx2(deg: &[f32], dst: &mut [f64]) {
    tangents_generic(deg, dst)
}

#[inline(always)]
fn tangents_generic(deg: &[f32], dst: &mut [f64]) {
    // Cephes `tan` reduced to |x| ≤ π/2: x = π/2·y + z with y = 0 or 2 (j = 2: −1/tan z).
    const DP1: f64 = 7.853_981_554_508_209e-1;
    const DP2: f64 = 7.946_627_356_147_928e-9;
    const DP3: f64 = 3.061_616_997_868_383e-17;
    const P: [f64; 3] = [
        -1.309_369_391_813_837_8e4,
        1.153_516_648_385_874_2e6,
        -1.795_652_519_764_848_8e7,
    ];
    const Q: [f64; 4] = [
        1.368_129_634_706_929_6e4,
        -1.320_892_344_402_109_7e6,
        2.500_838_018_233_579e7,
        -5.386_957_559_294_546e7,
    ];
    for (t, &d) in dst[..deg.len()].iter_mut().zip(deg) {
        let x = f64::from(d).to_radians();
        let a = x.abs();
        let far = a * std::f64::consts::FRAC_2_PI * 2.0 >= 1.0;
        let y = if far { 2.0 } else { 0.0 };
        let z = ((a - y * DP1) - y * DP2) - y * DP3;
        let zz = z * z;
        let p = (P[0] * zz + P[1]) * zz + P[2];
        let q = (((zz + Q[0]) * zz + Q[1]) * zz + Q[2]) * zz + Q[3];
        let r = if zz > 1e-14 { z + z * (zz * p / q) } else { z };
        let r = if far { -1.0 / r } else { r };
        *t = r.copysign(x);
    }
}

/// Arc tangent, branch-free (Cephes `atan`: reduction to |x| ≤ 0.66 and a (4, 5) rational
/// approximation, relative error below 2.2e-16); not for non-finite x.
#[inline(always)]
fn atan_cephes(x: f64) -> f64 {
    const T3P8: f64 = 2.414_213_562_373_095; // tan(3π/8)
    const MOREBITS: f64 = 6.123_233_995_736_766e-17;
    const P: [f64; 5] = [
        -8.750_608_600_031_904e-1,
        -1.615_753_718_733_365e1,
        -7.500_855_792_314_705e1,
        -1.228_866_684_490_136e2,
        -6.485_021_904_942_025e1,
    ];
    const Q: [f64; 5] = [
        2.485_846_490_142_306e1,
        1.650_270_098_316_988_5e2,
        4.328_810_604_912_903e2,
        4.853_903_996_359_137e2,
        1.945_506_571_482_614e2,
    ];
    let a = x.abs();
    let big = a > T3P8;
    let mid = a > 0.66;
    let (y0, m, r) = if big {
        (std::f64::consts::FRAC_PI_2, MOREBITS, -1.0 / a)
    } else if mid {
        (
            std::f64::consts::FRAC_PI_4,
            0.5 * MOREBITS,
            (a - 1.0) / (a + 1.0),
        )
    } else {
        (0.0, 0.0, a)
    };
    let z = r * r;
    let p = (((P[0] * z + P[1]) * z + P[2]) * z + P[3]) * z + P[4];
    let q = ((((z + Q[0]) * z + Q[1]) * z + Q[2]) * z + Q[3]) * z + Q[4];
    let y = y0 + ((r * (z * p / q) + r) + m);
    y.copysign(x)
}

/// Half-width (plane pixels) of the window searched exactly around the sweep's winner.
const WINDOW: f64 = 0.75;

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
        hull_push(self.pts, q);
    }

    /// The profile point seen highest from observer `o`, or None when the profile is empty.
    /// `finger` is where the last search on this line ended.
    #[inline]
    fn query(&self, o: Pt, finger: &mut usize) -> Option<usize> {
        if self.pts.is_empty() {
            return None;
        }
        Some(query_hull(self.pts, o, finger))
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
pub(super) struct Grid<'a> {
    pub(super) h: &'a [f32],
    /// Index steps for +1 in p and in q.
    pub(super) sp: usize,
    pub(super) sq: usize,
    pub(super) np: i64,
    pub(super) nq: i64,
}

impl Grid<'_> {
    #[inline(always)]
    pub(super) fn at(&self, p: i64, q: i64) -> f32 {
        self.h[p as usize * self.sp + q as usize * self.sq]
    }

    /// Bilinear height at (p, q) in the raster (callers check the range), no-data taps left
    /// out (as [`Context::bilinear`]).
    #[inline(always)]
    fn bilinear(&self, p: f64, q: f64) -> f32 {
        self.sample(p, q).0
    }

    /// [`Grid::bilinear`], and whether (p, q) is a good guide for the exact search
    /// ([`Ray::max_over`]) on a ray through it: on a grid line, where a ray crosses from cell
    /// to cell, or inside a cell whose four corners hold data. Inside a cell with a no-data
    /// corner the renormalised surface is a plateau of its data corners that no method
    /// reports, so a sweep candidate there would guide the search to a point it never finds.
    /// (Looser than [`Context::on_complete_cell`], which decides what is reported: a ray
    /// along a grid line is only guided here, then searched exactly around the candidate.)
    #[inline(always)]
    pub(super) fn sample(&self, p: f64, q: f64) -> (f32, bool) {
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
            let v = (wa * a as f64 + wb * b as f64 + wc * c as f64 + wd * d as f64) as f32;
            return (v, true);
        }
        let on_line = fp == 0.0 || fq == 0.0;
        let (mut acc, mut ws) = (0.0, 0.0);
        for (v, w) in [(a, wa), (b, wb), (c, wc), (d, wd)] {
            // (Rounding-error weights count as none, as in [`Context::bilinear64`].)
            if w >= TAP_EPS && !v.is_nan() {
                acc += w * v as f64;
                ws += w;
            }
        }
        if ws > 0.0 {
            ((acc / ws) as f32, on_line)
        } else {
            (f32::NAN, on_line)
        }
    }

    /// Where the ray q = q_o + t·(p − p_o) (t ≠ 0) enters and leaves the cell that holds its
    /// point (p, q) off the grid lines: on the cell's columns or rows, exactly.
    fn crossings(&self, p_o: f64, q_o: f64, t: f64, p: f64, q: f64) -> [(f64, f64); 2] {
        let (pc, qc) = (p.floor(), q.floor());
        let at_row = |qr: f64| (p_o + (qr - q_o) / t, qr);
        let at_col = |pc: f64| (pc, q_o + t * (pc - p_o));
        let (r0, r1) = (at_row(qc), at_row(qc + 1.0));
        let (lo, hi) = if r0.0 < r1.0 { (r0, r1) } else { (r1, r0) };
        let enter = if lo.0 > pc { lo } else { at_col(pc) };
        let leave = if hi.0 < pc + 1.0 {
            hi
        } else {
            at_col(pc + 1.0)
        };
        [enter, leave]
    }

    #[inline(always)]
    pub(super) fn inside(&self, p: f64, q: f64) -> bool {
        p >= 0.0 && q >= 0.0 && p <= (self.np - 1) as f64 && q <= (self.nq - 1) as f64
    }
}

/// One plane azimuth's family of parallel lines q = m + t·p over a raster ((p, q) = (major,
/// minor) axes), one pixel apart along the minor axis, integer m: what both sweeps share.
pub(super) struct Lines<'a> {
    pub(super) ctx: &'a Context,
    pub(super) g: Grid<'a>,
    pub(super) xmajor: bool,
    /// The look direction's major component, and dq/dp.
    pub(super) dp: f64,
    pub(super) t: f64,
    /// −1 or +1: the sweep's direction along p (against the look direction).
    pub(super) step: i64,
    /// The observers' rect in (p, q), and an observer's index steps for +1 in p and in q.
    pub(super) rp0: i64,
    pub(super) rp1: i64,
    pub(super) rq0: i64,
    pub(super) rq1: i64,
    pub(super) si: usize,
    pub(super) sj: usize,
    /// The lines that bracket an observer.
    pub(super) m_lo: i64,
    pub(super) m_hi: i64,
}

impl<'a> Lines<'a> {
    pub(super) fn new(ctx: &'a Context, rect: Rect, phi: f64) -> Lines<'a> {
        let (dx, dy) = (phi.cos(), -phi.sin());
        let xmajor = dx.abs() >= dy.abs();
        let (dp, dq) = if xmajor { (dx, dy) } else { (dy, dx) };
        let t = dq / dp;
        let look: i64 = if dp > 0.0 { 1 } else { -1 };
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
        let (rp0, rp1, rq0, rq1) = if xmajor {
            (rect.x0, rect.x0 + rect.w, rect.y0, rect.y0 + rect.h)
        } else {
            (rect.y0, rect.y0 + rect.h, rect.x0, rect.x0 + rect.w)
        };
        let (rp0, rp1, rq0, rq1) = (rp0 as i64, rp1 as i64, rq0 as i64, rq1 as i64);
        let (si, sj) = if xmajor { (1, rect.w) } else { (rect.w, 1) };
        let m_at = |p: i64, q: i64| q as f64 - t * p as f64;
        let ms = [
            m_at(rp0, rq0),
            m_at(rp0, rq1 - 1),
            m_at(rp1 - 1, rq0),
            m_at(rp1 - 1, rq1 - 1),
        ];
        let m_lo = ms.iter().cloned().fold(f64::INFINITY, f64::min).floor() as i64 - 1;
        let m_hi = ms.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil() as i64 + 1;
        Lines {
            ctx,
            g,
            xmajor,
            dp,
            t,
            step: -look,
            rp0,
            rp1,
            rq0,
            rq1,
            si,
            sj,
            m_lo,
            m_hi,
        }
    }

    /// The observers (index in the rect, minor coordinate) that a line, passing observer
    /// column `p` at minor coordinate `y`, brackets there: the one at or above it (side 0)
    /// and the one below (side 1), where inside the rect; a line through an observer
    /// brackets it on side 0 only.
    #[inline(always)]
    fn observers(&self, p: i64, y: f64) -> [Option<(usize, i64)>; 2] {
        let qa = ceil(y);
        let f = qa - y;
        let qa = qa as i64;
        let mut out = [None, None];
        for (side, (q0, w)) in [(qa, 1.0 - f), (qa - 1, f)].into_iter().enumerate() {
            if w <= 0.0 || q0 < self.rq0 || q0 >= self.rq1 {
                continue;
            }
            let idx = (p - self.rp0) as usize * self.si + (q0 - self.rq0) as usize * self.sj;
            out[side] = Some((idx, q0));
        }
        out
    }

    /// The face-plane point (not normalised) of raster position (p, q).
    pub(super) fn plane(&self, p: f64, q: f64) -> Vec3 {
        let (n, ua, va) = self.ctx.face.axes();
        let (x, y) = if self.xmajor { (p, q) } else { (q, p) };
        let (u, v) = self.ctx.uv(x, y);
        [
            n[0] + u * ua[0] + v * va[0],
            n[1] + u * ua[1] + v * va[1],
            n[2] + u * ua[2] + v * va[2],
        ]
    }

    /// Where line `mf` runs within a pixel of the raster inside [lo, hi] along p, as (start,
    /// stop) in sweep order; None where nowhere.
    pub(super) fn span(&self, mf: f64, lo: i64, hi: i64) -> Option<(i64, i64)> {
        let (t, nq) = (self.t, self.g.nq);
        let (mut pa, mut pb) = (lo, hi);
        if t != 0.0 {
            let (e0, e1) = ((-1.0 - mf) / t, (nq as f64 - mf) / t);
            let (lo, hi) = (e0.min(e1), e0.max(e1));
            pa = pa.max(lo.floor() as i64);
            pb = pb.min(hi.ceil() as i64);
        } else if mf < -1.0 || mf > nq as f64 {
            return None;
        }
        if pa > pb {
            return None;
        }
        Some(if self.step < 0 { (pb, pa) } else { (pa, pb) })
    }

    /// Line `mf`'s frame between `start` and `stop`: A + p·B spans a plane through the body
    /// centre; e1 = up at the middle of the swept range, e2 = the sweep direction. Returns
    /// (A·e1, B·e1, A·e2, B·e2).
    pub(super) fn frame(&self, mf: f64, start: i64, stop: i64) -> (f64, f64, f64, f64) {
        let (t, step) = (self.t, self.step);
        let a_pt = self.plane(0.0, mf);
        let b_pt = self.plane(1.0, mf + t);
        let bv = [b_pt[0] - a_pt[0], b_pt[1] - a_pt[1], b_pt[2] - a_pt[2]];
        let pm = 0.5 * (start + stop) as f64;
        let e1 = normalize(self.plane(pm, mf + t * pm));
        let sb = [
            step as f64 * bv[0],
            step as f64 * bv[1],
            step as f64 * bv[2],
        ];
        let k = dot(sb, e1);
        let e2 = normalize([sb[0] - k * e1[0], sb[1] - k * e1[1], sb[2] - k * e1[2]]);
        (dot(a_pt, e1), dot(bv, e1), dot(a_pt, e2), dot(bv, e2))
    }

    /// Line `mf`'s samples from `start` to `stop` in sweep order, where it crosses pixel
    /// columns and rows (exact bilinear values), appended to `ps` (line parameter) and `hs`;
    /// `at_col(index, p, y, inside)` at each observer column p (y: the line's minor
    /// coordinate there), before its own sample, which is there where `inside`.
    pub(super) fn samples(
        &self,
        mf: f64,
        start: i64,
        stop: i64,
        ps: &mut Vec<f64>,
        hs: &mut Vec<f32>,
        mut at_col: impl FnMut(usize, i64, f64, bool),
    ) {
        let (g, t, nq) = (&self.g, self.t, self.g.nq);
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
                    ps.push(pc);
                    hs.push(g.bilinear(pc, kq));
                }
            }
            prev_y = y;
            let inside = y >= 0.0 && y <= (nq - 1) as f64;
            if p >= self.rp0 && p < self.rp1 {
                at_col(ps.len(), p, y, inside);
            }
            if inside {
                ps.push(p as f64);
                hs.push(g.bilinear(p as f64, y));
            }
            if p == stop {
                break;
            }
            p += self.step;
        }
    }
}

/// The far rings' sweep for one plane azimuth ([`super::far`]; a tile's own raster has
/// [`sweep_pair`]): lines parallel to the look direction, one pixel apart
/// along the minor axis, swept from the far end of the raster towards the observers, each
/// keeping the upper convex hull of its profile (samples where it crosses pixel columns and
/// rows: exact bilinear values). An observer asks the two lines that bracket it at its own
/// column for the hull vertex it sees highest; unless that is hopelessly below what the
/// observer already has (`near`, earlier lines), the vertex and its hull neighbours are then
/// evaluated on the observer's own ray at the same distance, and the highest wins. Writes the
/// best slope per observer into `acc` (max) and its distance into `acc_s`. The observers'
/// heights are the raster's, or `observers` (row-major over `rect`) where given: a far ring's
/// raster holds no terrain where finer data took over, its observers included.
#[allow(clippy::too_many_arguments)]
pub(super) fn sweep(
    ctx: &Context,
    rect: Rect,
    phi: f64,
    near: &[f64],
    acc: &mut [f64],
    acc_s: &mut [f64],
    scratch: &mut Scratch,
    observers: Option<&[f32]>,
) {
    let lines = Lines::new(ctx, rect, phi);
    let (g, dp, t, step) = (&lines.g, lines.dp, lines.t, lines.step);
    let (nq, rp0, rp1) = (g.nq, lines.rp0, lines.rp1);
    // Sweep from the raster's far end (in the look direction) to the observers' last column.
    let (p_first, p_last) = if step < 0 {
        (g.np - 1, rp0)
    } else {
        (0, rp1 - 1)
    };
    let radius = ctx.radius_m;
    for m in lines.m_lo..=lines.m_hi {
        let mf = m as f64;
        // The part of the sweep where the line is within a pixel of the raster.
        let Some((start, stop)) = lines.span(mf, p_first.min(p_last), p_first.max(p_last)) else {
            continue;
        };
        let (a0, a1, b0, b1) = lines.frame(mf, start, stop);
        let mut hull = std::mem::take(&mut scratch.hull);
        hull.clear();
        let mut line = Line {
            pts: &mut hull,
            a0,
            a1,
            b0,
            b1,
        };
        // 1. The line's samples in sweep order, and where each observer column comes.
        let sc = &mut *scratch;
        sc.p.clear();
        sc.h.clear();
        sc.marks.clear();
        let marks = &mut sc.marks;
        lines.samples(mf, start, stop, &mut sc.p, &mut sc.h, |i, p, y, _| {
            marks.push((i, p, y))
        });
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
                for (side, found) in lines.observers(p, y).into_iter().enumerate() {
                    let Some((idx, q0)) = found else {
                        continue;
                    };
                    let h0 = match observers {
                        Some(h) => h[idx],
                        None => g.at(p, q0),
                    };
                    if h0.is_nan() {
                        continue;
                    }
                    let o = line.pos(p as f64, radius + h0 as f64);
                    let Some(iv) = line.query(o, &mut fingers[side]) else {
                        continue;
                    };
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
                        // (A ray along the raster's edge row computes a rounding error
                        // outside it: snapped back, as the exact search snaps it.)
                        let mut qv = snap(q0 as f64 + t * (pv - p as f64), (nq - 1) as f64);
                        if !(qv >= 0.0 && qv <= (nq - 1) as f64) {
                            // Beyond where the observer's ray leaves the raster (the line
                            // runs on beside it): take that exit point instead.
                            qv = if qv < 0.0 { 0.0 } else { (nq - 1) as f64 };
                            pv = p as f64 + (qv - q0 as f64) / t;
                        }
                        if !g.inside(pv, qv) {
                            continue;
                        }
                        let mut consider = |pv: f64, hv: f32| {
                            if hv.is_nan() {
                                return;
                            }
                            let c = if pv == v.p {
                                line.at_radius(v, radius + hv as f64)
                            } else {
                                line.pos(pv, radius + hv as f64)
                            };
                            if best.is_none_or(|b| cross(o, c, b) > 0.0) {
                                best = Some(c);
                            }
                        };
                        let (hv, evaluated) = g.sample(pv, qv);
                        if evaluated && !hv.is_nan() {
                            consider(pv, hv);
                        } else if t != 0.0 {
                            // Inside a cell with a no-data corner: where the ray enters and
                            // leaves the cell instead, the points the exact search evaluates
                            // there. Over no data (the line runs on beside a data edge that
                            // the ray has already crossed): the same, stepping back towards the
                            // observer over up to three cells until the ray meets terrain,
                            // its last before the edge, where a view falling away peaks.
                            let over_nodata = evaluated && hv.is_nan();
                            let back = (p as f64 - pv).signum();
                            let (mut pb, mut found) = (pv, false);
                            for _ in 0..3 {
                                pb += back * 1e-6;
                                let qb = q0 as f64 + t * (pb - p as f64);
                                let ends = g.crossings(p as f64, q0 as f64, t, pb, qb);
                                for (pe, qe) in ends {
                                    if g.inside(pe, qe) {
                                        let he = g.bilinear(pe, qe);
                                        found |= !he.is_nan();
                                        consider(pe, he);
                                    }
                                }
                                if found || !over_nodata {
                                    break;
                                }
                                // The crossing nearer the observer.
                                pb = if back > 0.0 { ends[1].0 } else { ends[0].0 };
                            }
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

/// The sweep's guesses for one plane azimuth, per observer (row-major over the rect): the
/// best slope one of its two bracketing lines estimates (the observer placed on that line at
/// its own column and height) and where, in plane pixels along the ray, and the other line's.
/// Estimates only guide [`finish_pair`]'s exact searches on the observer's own ray.
pub(super) struct Guesses(Vec<Guess>);

/// One observer's [`Guesses`], kept together: the sweep offers them in the lines' order, which
/// crosses the rows, so one record is one cache line touched where six arrays were six.
#[derive(Clone, Copy)]
pub(super) struct Guess {
    pub(super) best: f32,
    pub(super) best_s: f32,
    pub(super) alt: f32,
    pub(super) alt_s: f32,
    /// The distances of the hull vertices on either side of each line's winner (farther,
    /// nearer): crests the line sees just below its winner.
    pub(super) best_nb: [f32; 2],
    pub(super) alt_nb: [f32; 2],
}

impl Guess {
    const NONE: Guess = Guess {
        best: f32::NEG_INFINITY,
        best_s: f32::NAN,
        alt: f32::NEG_INFINITY,
        alt_s: f32::NAN,
        best_nb: [f32::NAN; 2],
        alt_nb: [f32::NAN; 2],
    };
}

impl Guesses {
    pub(super) fn new(n: usize) -> Guesses {
        Guesses(vec![Guess::NONE; n])
    }

    fn reset(&mut self) {
        self.0.fill(Guess::NONE);
    }

    #[inline(always)]
    fn offer(&mut self, idx: usize, slope: f32, s: f32, nb: [f32; 2]) {
        let g = &mut self.0[idx];
        if slope > g.best {
            g.alt = g.best;
            g.alt_s = g.best_s;
            g.alt_nb = g.best_nb;
            g.best = slope;
            g.best_s = s;
            g.best_nb = nb;
        } else if slope > g.alt {
            g.alt = slope;
            g.alt_s = s;
            g.alt_nb = nb;
        }
    }
}

/// The sweep for plane azimuth `phi` and, where `back` is given, for `phi` + π at once: both
/// look along the same lines (one pixel apart along the minor axis, samples where each crosses
/// pixel columns and rows), so the samples and their places in each line's great-circle plane
/// are computed once and the line's upper hull is built twice, once from each end. Every
/// observer asks the two lines that bracket it at its own column for the hull vertex it sees
/// highest (placed on the line, at its own height) and keeps both answers as [`Guesses`]; no
/// evaluation on its own ray happens here. Lines span the whole raster whether `back` is
/// given or not, so `ahead`'s guesses are the same bytes either way.
pub(super) fn sweep_pair(
    ctx: &Context,
    rect: Rect,
    phi: f64,
    near_px: f64,
    ahead: &mut Guesses,
    mut back: Option<&mut Guesses>,
    scratch: &mut Scratch,
) {
    ahead.reset();
    if let Some(b) = back.as_deref_mut() {
        b.reset();
    }
    let lines = Lines::new(ctx, rect, phi);
    let (g, dp) = (&lines.g, lines.dp);
    let radius = ctx.radius_m;
    let inv_dp = 1.0 / dp.abs();
    // Samples nearer than the near field along the ray, in major-axis pixels.
    let lag = near_px * dp.abs();
    for m in lines.m_lo..=lines.m_hi {
        let mf = m as f64;
        let Some((start, stop)) = lines.span(mf, 0, g.np - 1) else {
            continue;
        };
        let (a0, a1, b0, b1) = lines.frame(mf, start, stop);
        // 1. The line's samples in the look direction's sweep order (from `phi`'s far end),
        // and where each observer column comes: its index, whether the column's own sample
        // is there, and the column's unit direction in the line's plane.
        let sc = &mut *scratch;
        sc.p.clear();
        sc.h.clear();
        sc.cols.clear();
        let cols = &mut sc.cols;
        lines.samples(mf, start, stop, &mut sc.p, &mut sc.h, |at, p, y, own| {
            let (a, b) = (a0 + p as f64 * a1, b0 + p as f64 * b1);
            let inv = 1.0 / (a * a + b * b).sqrt();
            cols.push(Col {
                at,
                own,
                p,
                y,
                ux: b * inv,
                uy: a * inv,
            });
        });
        if sc.cols.is_empty() {
            continue;
        }
        // 2. Their positions in the line's plane (vectorised).
        let len = sc.p.len();
        sc.x.resize(len, 0.0);
        sc.y.resize(len, 0.0);
        for i in 0..len {
            let pp = sc.p[i];
            let (a, b) = (a0 + pp * a1, b0 + pp * b1);
            let k = (radius + sc.h[i] as f64) / (a * a + b * b).sqrt();
            sc.x[i] = b * k;
            sc.y[i] = a * k;
        }
        // 3. The hull from `phi`'s far end, queries where the observer columns come: each
        // column's observers see the samples more than `near_px` along their ray (the near
        // field has the rest), so a sample joins the hull once the columns are that far past it.
        let mut hull = std::mem::take(&mut sc.hull);
        hull.clear();
        let mut fingers = [usize::MAX; 2];
        let mut next = 0;
        for c in &sc.cols {
            while next < c.at && (sc.p[next] - c.p as f64).abs() >= lag {
                if !sc.h[next].is_nan() {
                    hull_push(
                        &mut hull,
                        Pt {
                            x: sc.x[next],
                            y: sc.y[next],
                            p: sc.p[next],
                            inv: 0.0,
                        },
                    );
                }
                next += 1;
            }
            ask(&lines, &hull, c, 1.0, inv_dp, &mut fingers, ahead);
        }
        // 4. The same line from the other end for `phi` + π, mirrored (x → −x) so that the
        // hull is built the same way.
        if let Some(bk) = back.as_deref_mut() {
            hull.clear();
            let mut fingers = [usize::MAX; 2];
            let mut next = len;
            for c in sc.cols.iter().rev() {
                let first = c.at + c.own as usize;
                while next > first && (sc.p[next - 1] - c.p as f64).abs() >= lag {
                    next -= 1;
                    if !sc.h[next].is_nan() {
                        hull_push(
                            &mut hull,
                            Pt {
                                x: -sc.x[next],
                                y: sc.y[next],
                                p: sc.p[next],
                                inv: 0.0,
                            },
                        );
                    }
                }
                ask(&lines, &hull, c, -1.0, inv_dp, &mut fingers, bk);
            }
        }
        sc.hull = hull;
    }
}

/// An observer column of one line in [`sweep_pair`].
#[derive(Clone, Copy)]
struct Col {
    /// Index of the first sample at or beyond the column in `phi`'s sweep order.
    at: usize,
    /// Whether the column's own sample (at `at`) is on the line.
    own: bool,
    p: i64,
    /// The line's minor coordinate at the column.
    y: f64,
    /// The column's unit direction in the line's plane.
    ux: f64,
    uy: f64,
}

/// Pop while the top is on the body's side of (or on) the segment from the one below it to
/// `q` (the chain keeps turning clockwise), then push `q`.
#[inline(always)]
fn hull_push(pts: &mut Vec<Pt>, q: Pt) {
    while pts.len() >= 2 {
        let n = pts.len();
        if cross(pts[n - 2], pts[n - 1], q) >= 0.0 {
            pts.pop();
        } else {
            break;
        }
    }
    pts.push(q);
}

/// The observers of column `c` ask the hull (`mirror`: −1 for the reversed sweep) for the
/// vertex they see highest, placed on the line at their own height; the answers go to `out`.
#[inline(always)]
fn ask(
    lines: &Lines,
    hull: &[Pt],
    c: &Col,
    mirror: f64,
    inv_dp: f64,
    fingers: &mut [usize; 2],
    out: &mut Guesses,
) {
    if hull.is_empty() {
        return;
    }
    for (side, found) in lines.observers(c.p, c.y).into_iter().enumerate() {
        let Some((idx, q0)) = found else {
            continue;
        };
        let h0 = lines.g.at(c.p, q0);
        if h0.is_nan() {
            continue;
        }
        let r = lines.ctx.radius_m + h0 as f64;
        let o = Pt {
            x: mirror * c.ux * r,
            y: c.uy * r,
            p: c.p as f64,
            inv: 0.0,
        };
        let iv = query_hull(hull, o, &mut fingers[side]);
        let v = hull[iv];
        let dist = |v: Pt| ((v.p - c.p as f64).abs() * inv_dp) as f32;
        let nb = [
            if iv > 0 { dist(hull[iv - 1]) } else { f32::NAN },
            if iv + 1 < hull.len() {
                dist(hull[iv + 1])
            } else {
                f32::NAN
            },
        ];
        out.offer(idx, slope(o, v) as f32, dist(v), nb);
    }
}

/// The index of the hull vertex seen highest from observer `o` (`h` not empty), climbing from
/// `finger`, where the last search on this hull ended: seen from o the elevation along the
/// hull is unimodal.
#[inline(always)]
fn query_hull(h: &[Pt], o: Pt, finger: &mut usize) -> usize {
    let better = |a: Pt, b: Pt| cross(o, a, b) > 0.0;
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
}

/// How far (slope) below what the observer has the other line's guess may lie and still have
/// the observer's own ray searched around it too (where the two lines disagree on where).
const ALT_SKIP: f64 = 0.03;

/// How far (plane pixels) the search around a guess over no data reaches back towards the
/// observer: three cells, as far as a line beside the ray runs on past a data edge.
const BACK_PX: f64 = 3.0;

/// The longest gap (plane pixels) between close guesses that one exact search spans.
const BRIDGE_PX: f64 = 2.0;

/// Guesses nearer than this (plane pixels along the ray) have their hull neighbours
/// evaluated on the observer's own ray too: up to 2.5 × the default near field, where the
/// lines' ≤ 1 px lateral offset from the ray can still rank a crest below its neighbour.
const NEIGHBOURS_WITHIN: f64 = 64.0;

/// Elevations (degrees) of one azimuth from the near field and the sweep's [`Guesses`]
/// (docs/horizons.md): unless the near field is ahead of the best guess by more than
/// [`SKIP`] (then the guess alone is evaluated), the observer's own ray is searched exactly
/// within ±[`WINDOW`] of the best guess's distance, and of the other line's where that is
/// within [`ALT_SKIP`] of what the first search found or that found nothing (one window over
/// both where they overlap); for guesses within
/// [`NEIGHBOURS_WITHIN`] the winners' hull neighbours are evaluated on the ray, and searched
/// around where they beat what the observer has. A guess beyond where the ray leaves the
/// raster is taken at that exit. Then the far rings' terrain beyond the raster (`far`, as
/// the tests pass them all at once) and (`with_slope0`) the zero-distance slope. Every value
/// reported is a point of the observer's own ray, evaluated exactly.
#[allow(clippy::too_many_arguments)]
pub(super) fn finish_pair(
    ctx: &Context,
    rect: Rect,
    az: &Azimuth,
    near_px: f64,
    geo: &[PixelGeo],
    near: &[f64],
    guess: &Guesses,
    far: &[FarPass],
    with_slope0: bool,
    dst: &mut [f32],
) {
    let (cos, sin) = (az.cos, az.sin);
    let (w1, h1) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
    // Distance (plane pixels) at which the ray from (x, y) leaves the raster, with the 1e-9 px
    // the exact search snaps back onto an edge (a ray along the edge row, whose direction's
    // other component is a rounding error, runs on along it).
    let (cx, cy) = (cos, -sin);
    let exit = |x: f64, y: f64| -> f64 {
        let along = |z: f64, c: f64, hi: f64| {
            if c > 0.0 {
                (hi - z + 1e-9) / c
            } else if c < 0.0 {
                (-z - 1e-9) / c
            } else {
                f64::INFINITY
            }
        };
        along(x, cx, w1).min(along(y, cy, h1))
    };
    // The cell walk from a grid point out to the raster's far side, for the windows.
    let walk = near::WindowWalk::new(ctx, az);
    let mut slopes = vec![0.0f64; rect.w];
    for j in 0..rect.h {
        let row = &mut dst[j * rect.w..(j + 1) * rect.w];
        for (i, slope) in slopes.iter_mut().enumerate() {
            let (x, y) = (rect.x0 + i, rect.y0 + j);
            let o = j * rect.w + i;
            let h0 = ctx.at(x as i64, y as i64);
            if h0.is_nan() {
                *slope = f64::NAN;
                continue;
            }
            let ray = Ray::from_parts(ctx, x, y, &geo[o], az);
            let mut t = near[o];
            let gs = guess.0[o];
            let sw = f64::from(gs.best_s);
            if sw.is_finite() {
                let out = exit(x as f64, y as f64);
                let best = f64::from(gs.best);
                if best >= t - SKIP {
                    // The ray searched exactly over [lo − WINDOW, hi + WINDOW] beyond the near
                    // field, the interval's ends taken no farther than the ray's exit.
                    // A guess over no data or a cell with a no-data corner (the line runs on
                    // beside a data edge the ray has already crossed) widens the search back
                    // towards the observer by up to [`BACK_PX`], to the ray's last terrain before
                    // the edge, where a view falling away peaks.
                    // Over complete cells inside the raster by the near field's f32 kernel over
                    // the whole cells the interval meets (near::window), elsewhere in f64.
                    let ob = near::Observer::of(&ray);
                    let search = |lo: f64, hi: f64, t: f64| -> f64 {
                        let (mut lo, hi) = (lo.min(out), hi.min(out));
                        if !ctx.on_complete_cell(ray.x0 + lo * ray.cx, ray.y0 + lo * ray.cy) {
                            lo -= BACK_PX;
                        }
                        let (from, to) = ((lo - WINDOW).max(near_px), hi + WINDOW);
                        match near::window(ctx, &walk, x, y, &ob, from, to) {
                            Some(v) => t.max(f64::from(v)),
                            None => ray.max_over(ctx, from, to, t).0,
                        }
                    };
                    let (alt, sa) = (f64::from(gs.alt), f64::from(gs.alt_s));
                    if sw < NEIGHBOURS_WITHIN {
                        // Close guesses: both lines' winners and those of their hull
                        // neighbours that the ray sees above what it has (or cannot evaluate:
                        // a cell with a no-data corner), searched in spans that bridge gaps
                        // of up to [`BRIDGE_PX`] (the crest often lies between them).
                        let mut at = [f64::NAN; 6];
                        let mut n = 0;
                        let mut add = |s: f64| {
                            at[n] = s;
                            n += 1;
                        };
                        add(sw);
                        if sa.is_finite() && alt >= t - ALT_SKIP {
                            add(sa);
                        }
                        for nb in gs.best_nb.into_iter().chain(gs.alt_nb) {
                            let nb = f64::from(nb);
                            if nb > near_px {
                                let v = ray.slope_on_surface(ctx, nb.min(out));
                                if v > t || v == f64::NEG_INFINITY {
                                    add(nb);
                                }
                            }
                        }
                        let at = &mut at[..n];
                        at.sort_unstable_by(f64::total_cmp);
                        let mut lo = at[0];
                        for k in 0..at.len() {
                            if k + 1 == at.len() || at[k + 1] - at[k] > BRIDGE_PX {
                                t = search(lo, at[k], t);
                                if k + 1 < at.len() {
                                    lo = at[k + 1];
                                }
                            }
                        }
                    } else if sa.is_finite()
                        && alt >= t - ALT_SKIP
                        && (sa - sw).abs() <= 2.0 * WINDOW
                    {
                        t = search(sw.min(sa), sw.max(sa), t);
                    } else {
                        let before = t;
                        t = search(sw, sw, t);
                        // The other line's guess where it could beat what that found (the
                        // best line's estimate may be high: it passes beside the ray), or
                        // wherever the best one gave nothing on the ray (a line beside it ran
                        // over other terrain, as at a data edge).
                        if sa.is_finite() && (alt >= t - ALT_SKIP || t == before) {
                            t = search(sa, sa, t);
                        }
                    }
                } else {
                    t = t.max(ray.slope_on_surface(ctx, sw.min(out)));
                }
            }
            if !far.is_empty() {
                let ground = ray.ground_per_px();
                for f in far {
                    t = f.raise(i, j, h0 as f64, &geo[o], ground, t);
                }
            }
            if with_slope0 {
                let s0 = ctx.slope0_g(x, y, cos, sin, ray.ground_per_px());
                if s0 > t {
                    t = s0;
                }
            }
            *slope = t;
        }
        degrees(&slopes, row);
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
    cols: Vec<Col>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The row tangent is libm's within 1e-15 relatively (a few ulp) over the whole range of
    /// degrees, its reduction's boundary (45°) and ±90° included; NaN stays NaN.
    #[test]
    fn tangents_match_libm() {
        let mut rnd = crate::testutil::rng(0x7A4_6E47);
        let mut deg = vec![
            0.0f32, -0.0, 45.0, -45.0, 90.0, -90.0, 89.999_99, 1e-30, -1e-30,
        ];
        for k in -64i32..=64 {
            deg.push(f32::from_bits((45.0f32.to_bits() as i32 + k) as u32));
        }
        for _ in 0..400_000 {
            deg.push(((rnd() - 0.5) * 180.0) as f32);
        }
        deg.push(f32::NAN);
        let mut t = vec![0.0f64; deg.len()];
        tangents(&deg, &mut t);
        for (&d, &got) in deg.iter().zip(&t) {
            let want = f64::from(d).to_radians().tan();
            if d.is_nan() {
                assert!(got.is_nan());
                continue;
            }
            assert_eq!(got.is_sign_negative(), want.is_sign_negative(), "{d}°");
            let err = ((got - want) / want).abs();
            assert!(
                want == got || err < 1e-15,
                "{d}°: {got} against {want} ({err:e})"
            );
        }
    }

    /// The row arc tangent gives libm's bytes: random slopes over many scales, both signs,
    /// the reduction's boundaries, zeros, infinities and NaN.
    #[test]
    fn degrees_equal_libm() {
        let mut rnd = crate::testutil::rng(0x5EED_A7A9);
        let mut slopes = vec![
            0.0,
            -0.0,
            0.66,
            -0.66,
            2.414_213_562_373_095,
            2.414_213_562_373_096,
            1.0,
            -1.0,
            1e-300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        for i in 0..400_000 {
            let scale = 10f64.powi(i % 13 - 6);
            slopes.push((rnd() - 0.5) * 2.0 * scale);
        }
        for x in [0.66f64, 2.414_213_562_373_095] {
            for k in -50i64..=50 {
                slopes.push(f64::from_bits((x.to_bits() as i64 + k) as u64));
            }
        }
        let mut got = vec![0.0f32; slopes.len()];
        degrees(&slopes, &mut got);
        for (x, g) in slopes.iter().zip(&got) {
            let want = if x.is_nan() {
                f32::NAN
            } else {
                x.atan().to_degrees() as f32
            };
            assert_eq!(
                g.to_bits(),
                want.to_bits(),
                "slope {x:e}: {g} vs libm {want}"
            );
        }
    }

    /// The hull query finds the sample seen highest among *all* samples pushed so far, from
    /// observers beyond them at random heights, with the finger carried between queries.
    #[test]
    fn hull_query_equals_a_scan_of_every_sample() {
        let mut rnd = crate::testutil::rng(0x9E37_79B9_7F4A_7C15u64);
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
