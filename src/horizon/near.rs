//! The fast method's near field: the exact maximum over the continuous bilinear surface along
//! each observer's own ray out to a few tens of plane pixels ([`DEFAULT_NEAR_PX`]), for a whole
//! row of observers at once.
//!
//! Pixel centres are grid points of the raster and every observer's ray has the same raster
//! direction (cos φ, −sin φ), so the cells a ray crosses, in offsets from its observer, and the
//! distances at which it enters and leaves each of them are the same for every observer. That
//! walk is made once per azimuth ([`NearWalk`]); along each of its segments the bilinear height
//! is a quadratic whose coefficients are fixed combinations of the cell's four corners. The
//! row kernel then runs branch-free over contiguous slices of the height raster, in f32, which
//! the compiler vectorises (16 lanes where AVX-512 is present, chosen at run time).
//!
//! Precision: heights enter relative to the observer's (Δh) and the slope is written so that
//! nothing cancels but the heights themselves (below); the f32 result is within ≈ 1e-4° of the
//! f64 reference search ([`super::geometry`]'s `Ray::max_over`) on 30 m pixels, the size of an f32
//! ulp of a 1 km height over one pixel, and far below what an f16 map stores. Observers whose
//! walk would leave the raster or touch no-data are handed to that f64 search instead.

use super::geometry::{Axis, Azimuth, Context, PixelGeo, Ray, Rect};

/// Default distance (plane pixels) from the observer that the fast method searches exactly.
/// Within it the sweep's lines, up to ½ px beside the observer's own ray, see terrain at a
/// visibly different angle (docs/horizons.md, accuracy; `penumbra bench horizon` measures
/// error against run time for other values).
pub const DEFAULT_NEAR_PX: f64 = 24.0;
/// The largest near field accepted.
pub const MAX_NEAR_PX: f64 = 1024.0;

/// One cell of the walk: its offset from the observer, the distances (plane pixels) at which the
/// ray enters and leaves it, and the weights that give the height along it from the cell's
/// corners: h(s_lo + σ) = d0 + d1·σ + d2·σ², d_k = Σ w[k][c]·h_c over (h00, h10, h01, h11).
#[derive(Clone, Copy, Debug)]
struct Seg {
    dx: i64,
    dy: i64,
    s_lo: f32,
    s_hi: f32,
    w: [[f32; 4]; 3],
}

/// The walk out to `near` plane pixels from any grid point along one azimuth.
pub(super) struct NearWalk {
    pub(super) near: f64,
    segs: Vec<Seg>,
    /// The pixels the walk's cells touch, as offsets from the observer: [x0, x1) × [y0, y1).
    bbox: [i64; 4],
}

impl NearWalk {
    /// The walk along `az`'s raster direction (cos φ, −sin φ), out to `near` plane pixels.
    pub(super) fn new(az: &Azimuth, near: f64) -> NearWalk {
        let (cx, cy) = (az.cos, -az.sin);
        // Ray::max_over's cell walk, from a grid point.
        let mut ax = Axis::new(0.0, cx, 0.0);
        let mut ay = Axis::new(0.0, cy, 0.0);
        let mut segs = Vec::new();
        let mut s = 0.0f64;
        while s < near {
            let s_next = ax.next.min(ay.next).min(near);
            let (ix, iy) = (ax.i, ay.i);
            // Where the ray enters the cell, in the cell's own coordinates ∈ [0, 1].
            let fx0 = (s * cx - ix as f64).clamp(0.0, 1.0);
            let fy0 = (s * cy - iy as f64).clamp(0.0, 1.0);
            let (gx, gy) = (1.0 - fx0, 1.0 - fy0);
            let m = cx * cy;
            let w = [
                [gx * gy, fx0 * gy, gx * fy0, fx0 * fy0],
                [
                    -cx * gy - cy * gx,
                    cx * gy - cy * fx0,
                    -cx * fy0 + cy * gx,
                    cx * fy0 + cy * fx0,
                ],
                [m, -m, -m, m],
            ];
            segs.push(Seg {
                dx: ix,
                dy: iy,
                s_lo: s as f32,
                s_hi: s_next as f32,
                w: w.map(|r| r.map(|v| v as f32)),
            });
            s = s_next;
            ax.advance(s);
            ay.advance(s);
        }
        // The observer's own pixel at least (a walk of length 0 has no cells).
        let bbox = segs.iter().fold([0, 1, 0, 1], |b, sg| {
            [
                b[0].min(sg.dx),
                b[1].max(sg.dx + 2),
                b[2].min(sg.dy),
                b[3].max(sg.dy + 2),
            ]
        });
        NearWalk { near, segs, bbox }
    }
}

/// Where the row kernel may run: a summed-area table of the raster's no-data pixels, so that
/// per azimuth an observer is taken when the cells its walk touches are all inside the raster
/// and on data (the others go to the f64 search, which handles both).
pub(super) struct NoData {
    sat: Vec<u32>,
    w: usize,
    h: usize,
}

impl NoData {
    pub(super) fn new(ctx: &Context) -> NoData {
        let (w, h) = (ctx.width, ctx.height);
        let mut sat = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += ctx.heights[y * w + x].is_nan() as u32;
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        NoData { sat, w, h }
    }

    /// Whether observer (x, y)'s walk stays on data.
    #[inline]
    fn clean(&self, walk: &NearWalk, x: usize, y: usize) -> bool {
        let [x0, x1, y0, y1] = walk.bbox;
        let (x0, x1, y0, y1) = (x as i64 + x0, x as i64 + x1, y as i64 + y0, y as i64 + y1);
        if x0 < 0 || y0 < 0 || x1 > self.w as i64 || y1 > self.h as i64 {
            return false;
        }
        let (x0, x1, y0, y1) = (x0 as usize, x1 as usize, y0 as usize, y1 as usize);
        let s = |x: usize, y: usize| self.sat[y * (self.w + 1) + x];
        s(x1, y1) + s(x0, y0) - s(x1, y0) - s(x0, y1) == 0
    }
}

/// Reused per-row buffers.
#[derive(Default)]
pub(super) struct NearScratch {
    h0: Vec<f32>,
    r0: Vec<f32>,
    alpha: Vec<f32>,
    beta: Vec<f32>,
    kappa: Vec<f32>,
    best: Vec<f32>,
}

impl NearScratch {
    /// The per-observer inputs of the row kernel for the run of observers at raster index
    /// `base..` whose geometry is `geo`, along `az`; `best` reset.
    fn load(&mut self, ctx: &Context, az: &Azimuth, base: usize, geo: &[PixelGeo]) {
        self.h0.clear();
        self.r0.clear();
        self.alpha.clear();
        self.beta.clear();
        self.kappa.clear();
        for (k, g) in geo.iter().enumerate() {
            let h0 = ctx.heights[base + k] as f64;
            let r0 = ctx.radius_m + h0;
            let (a1, b1) = az.along(g);
            // Along the ray tan ψ = s·β / (1 + s·α) (ψ: angle at the body's centre).
            let (alpha, beta) = (a1 / g.n0, b1 / g.n0);
            let gm = r0 * beta;
            self.h0.push(h0 as f32);
            self.r0.push(r0 as f32);
            self.alpha.push(alpha as f32);
            self.beta.push(beta as f32);
            self.kappa.push((gm * gm / (2.0 * r0)) as f32);
        }
        self.best.clear();
        self.best.resize(geo.len(), f32::NEG_INFINITY);
    }
}

/// The largest slope (tan of elevation) over (0, walk.near] of every observer of `rect` along
/// azimuth `az`, written to `out` (row-major over `rect`); −∞ for no-data observers.
#[allow(clippy::too_many_arguments)]
pub(super) fn near_field(
    ctx: &Context,
    rect: Rect,
    az: &Azimuth,
    walk: &NearWalk,
    geo: &[PixelGeo],
    nodata: &NoData,
    sc: &mut NearScratch,
    out: &mut [f64],
) {
    for j in 0..rect.h {
        let y = rect.y0 + j;
        let mut i = 0;
        while i < rect.w {
            let o = j * rect.w + i;
            let x = rect.x0 + i;
            if !nodata.clean(walk, x, y) {
                out[o] = if ctx.at(x as i64, y as i64).is_nan() {
                    f64::NEG_INFINITY
                } else {
                    Ray::from_parts(ctx, x, y, &geo[o], az)
                        .max_over(ctx, 0.0, walk.near, f64::NEG_INFINITY)
                        .0
                };
                i += 1;
                continue;
            }
            // A run of clean observers.
            let mut e = i + 1;
            while e < rect.w && nodata.clean(walk, rect.x0 + e, y) {
                e += 1;
            }
            let n = e - i;
            let base = y * ctx.width + rect.x0 + i;
            sc.load(ctx, az, base, &geo[o..o + n]);
            row(&ctx.heights, ctx.width, base, walk, sc);
            for (d, &b) in out[o..o + n].iter_mut().zip(&sc.best) {
                *d = b as f64;
            }
            i = e;
        }
    }
}

/// The row kernel, compiled for AVX-512 too and chosen at run time. Both builds compute the
/// same IEEE operations in the same order (Rust never fuses a multiply and an add on its own),
/// so the output is the same bytes on every machine.
fn row(heights: &[f32], width: usize, base: usize, walk: &NearWalk, sc: &mut NearScratch) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F, checked just above.
            unsafe { row_avx512(heights, width, base, walk, sc) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            unsafe { row_avx2(heights, width, base, walk, sc) };
            return;
        }
    }
    row_generic(heights, width, base, walk, sc)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn row_avx512(
    heights: &[f32],
    width: usize,
    base: usize,
    walk: &NearWalk,
    sc: &mut NearScratch,
) {
    row_generic(heights, width, base, walk, sc)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn row_avx2(
    heights: &[f32],
    width: usize,
    base: usize,
    walk: &NearWalk,
    sc: &mut NearScratch,
) {
    row_generic(heights, width, base, walk, sc)
}

#[inline(always)]
fn row_generic(heights: &[f32], width: usize, base: usize, walk: &NearWalk, sc: &mut NearScratch) {
    let n = sc.best.len();
    let (h0, r0, alpha, beta, kappa) = (
        &sc.h0[..n],
        &sc.r0[..n],
        &sc.alpha[..n],
        &sc.beta[..n],
        &sc.kappa[..n],
    );
    let best = &mut sc.best[..n];
    for sg in &walk.segs {
        let b = (base as i64 + sg.dy * width as i64 + sg.dx) as usize;
        let (t00, t10) = (&heights[b..b + n], &heights[b + 1..b + 1 + n]);
        let (t01, t11) = (
            &heights[b + width..b + width + n],
            &heights[b + width + 1..b + width + 1 + n],
        );
        let [w0, w1, w2] = sg.w;
        let (s_lo, s_hi) = (sg.s_lo, sg.s_hi);
        let len = s_hi - s_lo;
        for k in 0..n {
            let hz = h0[k];
            let e = [t00[k] - hz, t10[k] - hz, t01[k] - hz, t11[k] - hz];
            let d0 = w0[0] * e[0] + w0[1] * e[1] + w0[2] * e[2] + w0[3] * e[3];
            let d1 = w1[0] * e[0] + w1[1] * e[1] + w1[2] * e[2] + w1[3] * e[3];
            let d2 = w2[0] * e[0] + w2[1] * e[1] + w2[2] * e[2] + w2[3] * e[3];
            let (al, be, rr) = (alpha[k], beta[k], r0[k]);
            // Where the cell leaves the ray.
            let end = slope(s_hi, d0 + len * (d1 + len * d2), al, be, rr);
            // Inside the cell the slope (A + B·s + C·s²)/s, with the curvature drop in C,
            // peaks only at s* = √(A/C) (as in Ray::max_over).
            let ca = d0 - s_lo * (d1 - s_lo * d2);
            let cc = d2 - kappa[k];
            let q = ca / cc;
            let st = q.max(0.0).sqrt();
            let inside = q > 0.0 && st > s_lo && st < s_hi;
            let sg_ = if inside { st } else { s_hi };
            let sig = sg_ - s_lo;
            let mid = slope(sg_, d0 + sig * (d1 + sig * d2), al, be, rr);
            best[k] = best[k].max(end).max(mid);
        }
    }
}

/// One observer's inputs to [`slope`] (as [`NearScratch::load`] computes them for a row).
#[derive(Clone, Copy, Debug)]
pub(super) struct Observer {
    h0: f32,
    r0: f32,
    alpha: f32,
    beta: f32,
    kappa: f32,
}

impl Observer {
    /// The inputs for the observer of `ray`.
    #[inline]
    pub(super) fn of(ray: &Ray) -> Observer {
        let (h0, r0, n0) = (ray.height(), ray.r0, ray.a0);
        let (alpha, beta) = (ray.a1 / n0, ray.b1 / n0);
        let gm = r0 * beta;
        Observer {
            h0: h0 as f32,
            r0: r0 as f32,
            alpha: alpha as f32,
            beta: beta as f32,
            kappa: (gm * gm / (2.0 * r0)) as f32,
        }
    }
}

/// Lanes of [`window`]'s kernel: the cells of an interval are taken eight at a time.
const LANES: usize = 8;

/// A walk from a grid point out to the far side of a raster (as [`NearWalk`]), its cells laid
/// out lane by lane for [`window`]: per cell its offset (dx, dy) from the observer and that
/// offset in the raster (dy·width + dx), where the ray enters and leaves it, and its twelve
/// weights. [`LANES`] copies of the last of its `len` cells pad the end, so that a chunk of
/// lanes never reads past it.
pub(super) struct WindowWalk {
    len: usize,
    /// Per whole plane pixel d of distance, the first cell that reaches beyond d (s_hi > d):
    /// where [`WindowWalk::cells`] starts looking for an interval's cells.
    first: Vec<u32>,
    dxy: Vec<(i64, i64)>,
    off: Vec<i64>,
    s_lo: Vec<f32>,
    s_hi: Vec<f32>,
    w: [Vec<f32>; 12],
}

impl WindowWalk {
    /// The walk along `az` across `ctx` (out to its width + height, beyond which no ray in it
    /// reaches).
    pub(super) fn new(ctx: &Context, az: &Azimuth) -> WindowWalk {
        let reach = (ctx.width + ctx.height) as f64;
        let segs = NearWalk::new(az, reach).segs;
        let len = segs.len();
        let mut first = Vec::with_capacity(reach as usize + 1);
        let mut k = 0;
        for d in 0..=reach as usize {
            while k < len && f64::from(segs[k].s_hi) <= d as f64 {
                k += 1;
            }
            first.push(k as u32);
        }
        let n = len + LANES;
        let pad = |k: usize| &segs[k.min(len - 1)];
        let width = ctx.width as i64;
        let dxy = segs.iter().map(|sg| (sg.dx, sg.dy)).collect();
        let off = (0..n).map(|k| pad(k).dy * width + pad(k).dx).collect();
        let s_lo = (0..n).map(|k| pad(k).s_lo).collect();
        let s_hi = (0..n).map(|k| pad(k).s_hi).collect();
        let w = std::array::from_fn(|c| (0..n).map(|k| pad(k).w[c / 4][c % 4]).collect());
        WindowWalk {
            len,
            first,
            dxy,
            off,
            s_lo,
            s_hi,
            w,
        }
    }

    /// The cells k0..k1 that the interval [`from`, `to`] meets, with the cell before (whose
    /// end is where the first of them meets the ray: each point is then evaluated as the end
    /// of its own cell, or its peak, whatever interval holds it, so overlapping windows give
    /// its slope to the same bits); `None` for an empty interval.
    fn cells(&self, from: f64, to: f64) -> Option<(usize, usize)> {
        // The first cell with s_hi > from, and the first after it with s_lo ≥ to: from the
        // lookup by whole pixels, a pixel holds at most three cells.
        let at = |s: f64| self.first[(s.max(0.0) as usize).min(self.first.len() - 1)] as usize;
        let mut k0 = at(from);
        while k0 < self.len && f64::from(self.s_hi[k0]) <= from {
            k0 += 1;
        }
        let mut k1 = at(to).max(k0);
        while k1 < self.len && f64::from(self.s_lo[k1]) < to {
            k1 += 1;
        }
        (k0 < k1).then_some((k0.saturating_sub(1), k1))
    }
}

/// The largest slope along the ray of observer (x, y) (raster pixel, inputs `ob`) over every
/// cell of `ww` that the interval [`from`, `to`] of plane pixels meets, by the row kernel's
/// f32 evaluation of each whole cell (where the ray leaves it and the slope's peak inside it):
/// the points [`Ray::max_over`] evaluates over those cells, which are those it evaluates over
/// the interval but its start (mid-cell; that start matters only where the parabolic curvature
/// model misplaces a cell's peak, as on 14-km pixels of the Moon, where the whole-ray
/// reference misses it too). −∞ for an empty interval; `None` where those cells leave the
/// raster or touch no data, or the interval starts in the observer's own cell: the f64 search
/// handles those.
#[inline]
pub(super) fn window(
    ctx: &Context,
    ww: &WindowWalk,
    x: usize,
    y: usize,
    ob: &Observer,
    from: f64,
    to: f64,
) -> Option<f32> {
    if from < f64::from(ww.s_hi[0]) && from < to {
        // The observer's own cell, where the slope may peak at the interval's start (towards
        // the zero-distance limit) with no cell before whose end would hold it.
        return None;
    }
    let Some((k0, k1)) = ww.cells(from, to) else {
        return Some(f32::NEG_INFINITY);
    };
    // Along a walk each of dx, dy moves one way only: the first and last cells bound them.
    let ((dx0, dy0), (dx1, dy1)) = (ww.dxy[k0], ww.dxy[k1 - 1]);
    let (x, y) = (x as i64, y as i64);
    let (xa, xb) = (x + dx0.min(dx1), x + dx0.max(dx1) + 1);
    let (ya, yb) = (y + dy0.min(dy1), y + dy0.max(dy1) + 1);
    let (w, h) = (ctx.width as i64, ctx.height as i64);
    if xa < 0 || ya < 0 || xb >= w || yb >= h {
        return None;
    }
    let base = (y * w + x) as usize;
    let (v, any) = window_cells(&Cells {
        hs: &ctx.heights,
        width: ctx.width,
        base,
        ww,
        ob,
        k0,
        k1,
    });
    if any.is_nan() {
        return None;
    }
    Some(v)
}

/// One window for [`window_cells`]: cells k0..k1 of `ww` seen from observer `ob` at index
/// `base` of the raster `hs` (row length `width`).
#[derive(Clone, Copy)]
struct Cells<'a> {
    hs: &'a [f32],
    width: usize,
    base: usize,
    ww: &'a WindowWalk,
    ob: &'a Observer,
    k0: usize,
    k1: usize,
}

/// [`window_cells_generic`], compiled for AVX-512 and AVX2 too and chosen at run time (the
/// same IEEE operations in the same order in every build, as the row kernel's).
#[inline]
fn window_cells(c: &Cells) -> (f32, f32) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F, checked just above.
            return unsafe { window_cells_avx512(c) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { window_cells_avx2(c) };
        }
    }
    window_cells_generic(c)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn window_cells_avx512(c: &Cells) -> (f32, f32) {
    window_cells_generic(c)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn window_cells_avx2(c: &Cells) -> (f32, f32) {
    window_cells_generic(c)
}

/// The largest slope over cells k0..k1 of `ww` (where each leaves the ray, and its peak
/// inside), [`LANES`] cells at a time, and the sum of their corners (NaN where one has no
/// data). Lanes past k1 evaluate cell k1 − 1's corners again and are left out. (Indexed by
/// lane across several arrays, as the vectoriser wants it.)
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn window_cells_generic(cells: &Cells) -> (f32, f32) {
    let Cells {
        hs,
        width,
        base,
        ww,
        ob,
        k0,
        k1,
    } = *cells;
    let (hz, al, be, rr, kap) = (ob.h0, ob.alpha, ob.beta, ob.r0, ob.kappa);
    let mut best = [f32::NEG_INFINITY; LANES];
    let mut any = [0.0f32; LANES];
    let mut c = k0;
    while c < k1 {
        let mut t = [[0.0f32; LANES]; 4];
        for l in 0..LANES {
            let b = (base as i64 + ww.off[(c + l).min(k1 - 1)]) as usize;
            t[0][l] = hs[b];
            t[1][l] = hs[b + 1];
            t[2][l] = hs[b + width];
            t[3][l] = hs[b + width + 1];
        }
        let w = |i: usize| -> &[f32; LANES] { ww.w[i][c..c + LANES].try_into().unwrap() };
        let lo: &[f32; LANES] = ww.s_lo[c..c + LANES].try_into().unwrap();
        let hi: &[f32; LANES] = ww.s_hi[c..c + LANES].try_into().unwrap();
        for l in 0..LANES {
            let e = [t[0][l] - hz, t[1][l] - hz, t[2][l] - hz, t[3][l] - hz];
            any[l] += t[0][l] + t[1][l] + t[2][l] + t[3][l];
            let d0 = w(0)[l] * e[0] + w(1)[l] * e[1] + w(2)[l] * e[2] + w(3)[l] * e[3];
            let d1 = w(4)[l] * e[0] + w(5)[l] * e[1] + w(6)[l] * e[2] + w(7)[l] * e[3];
            let d2 = w(8)[l] * e[0] + w(9)[l] * e[1] + w(10)[l] * e[2] + w(11)[l] * e[3];
            let (s_lo, s_hi) = (lo[l], hi[l]);
            let len = s_hi - s_lo;
            // As the row kernel: where the cell leaves the ray, and the peak inside it.
            let end = slope(s_hi, d0 + len * (d1 + len * d2), al, be, rr);
            let ca = d0 - s_lo * (d1 - s_lo * d2);
            let cc = d2 - kap;
            let q = ca / cc;
            let st = q.max(0.0).sqrt();
            let inside = q > 0.0 && st > s_lo && st < s_hi;
            let sg = if inside { st } else { s_hi };
            let sig = sg - s_lo;
            let mid = slope(sg, d0 + sig * (d1 + sig * d2), al, be, rr);
            let v = end.max(mid);
            best[l] = if c + l < k1 { best[l].max(v) } else { best[l] };
        }
        c += LANES;
    }
    let v = best.iter().fold(f32::NEG_INFINITY, |m, &b| m.max(b));
    (v, any.iter().sum())
}

/// Slope (tan of elevation above the observer's horizontal) of terrain Δh above the observer's
/// height at distance `s`, with tan ψ = num/den = s·β/(1 + s·α): (Δh − D)/(r·tan ψ) with the
/// curvature drop D = r0·tan²ψ/(1 + √(1 + tan²ψ)), over one denominator.
#[inline(always)]
fn slope(s: f32, dh: f32, alpha: f32, beta: f32, r0: f32) -> f32 {
    let num = s * beta;
    let den = 1.0 + s * alpha;
    let e = den * den + den * (den * den + num * num).sqrt();
    (dh * e - r0 * num * num) * den / ((r0 + dh) * num * e)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cube::Face;
    use crate::horizon::geometry::{pixel_geometry, plane_azimuth};

    /// A rough raster with a few no-data holes, `origin` placing it on the face.
    fn rough(w: usize, h: usize, face_pixels: f64, origin: (i64, i64), radius_m: f64) -> Context {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut heights = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let smooth = 400.0 * ((x as f64 * 0.21).sin() + (y as f64 * 0.13).cos());
                heights[y * w + x] = (smooth + 300.0 * next()) as f32 - 200.0;
            }
        }
        for (x, y) in [(30, 30), (31, 30), (50, 12)] {
            heights[y * w + x] = f32::NAN;
        }
        Context {
            face: Face::Nz,
            face_pixels,
            origin,
            width: w,
            height: h,
            heights,
            radius_m,
        }
    }

    /// Rough 64 × 56 rasters, the whole of each as observers, with their pixel geometry:
    /// Earth-like at 30 m near the face centre; the Moon at 7.6 km pixels near a face corner
    /// (strong gnomonic distortion, ψ up to 0.1 rad within the near field); a 10 km body.
    fn bodies() -> Vec<(Context, Rect, Vec<PixelGeo>)> {
        let cases = [
            (424_734.0, (212_000, 212_000), 6_371_008.8),
            (256.0, (180, 190), 1_737_400.0),
            (600.0, (250, 240), 10_000.0),
        ];
        let rect = Rect {
            x0: 0,
            y0: 0,
            w: 64,
            h: 56,
        };
        cases
            .into_iter()
            .map(|(face_pixels, origin, radius)| {
                let ctx = rough(64, 56, face_pixels, origin, radius);
                let geo = pixel_geometry(&ctx, rect);
                (ctx, rect, geo)
            })
            .collect()
    }

    #[test]
    fn row_kernel_equals_the_f64_cell_walk() {
        let mut worst = 0.0f64;
        for (ctx, rect, geo) in bodies() {
            let radius = ctx.radius_m;
            let nodata = NoData::new(&ctx);
            let mut sc = NearScratch::default();
            let mut got = vec![0.0; rect.w * rect.h];
            let a = 72;
            let mut kernel = 0usize;
            for k in 0..a {
                let az = Azimuth::new(&ctx, plane_azimuth(k, a));
                let walk = NearWalk::new(&az, DEFAULT_NEAR_PX);
                near_field(&ctx, rect, &az, &walk, &geo, &nodata, &mut sc, &mut got);
                for y in 0..rect.h {
                    for x in 0..rect.w {
                        let o = y * rect.w + x;
                        kernel += nodata.clean(&walk, x, y) as usize;
                        if ctx.at(x as i64, y as i64).is_nan() {
                            assert_eq!(got[o], f64::NEG_INFINITY, "({x}, {y}) az {k}");
                            continue;
                        }
                        let ray = Ray::from_parts(&ctx, x, y, &geo[o], &az);
                        // Both with the zero-distance limit, as the fast method reports them
                        // (the f64 walk may also catch that limit a hair past the observer).
                        let s0 = ctx.slope0_g(x, y, az.cos, az.sin, ray.ground_per_px());
                        let want = ray
                            .max_over(&ctx, 0.0, DEFAULT_NEAR_PX, f64::NEG_INFINITY)
                            .0
                            .max(s0);
                        let d = (got[o].max(s0).atan() - want.atan()).to_degrees().abs();
                        // f32 heights: an ulp of a 1 km height over a 30 m pixel is 1e-4°.
                        assert!(
                            d < 2e-4,
                            "({x}, {y}) az {k} R {radius}: kernel {} vs f64 {} ({d}°)",
                            got[o],
                            want
                        );
                        worst = worst.max(d);
                    }
                }
            }
            // The kernel did the bulk, not the fallback.
            assert!(kernel > rect.w * rect.h * a / 8, "{kernel}");
        }
        eprintln!("near kernel vs f64 walk: worst {worst:.1e}°");
    }

    /// The window kernel against the f64 search: never below what the f64 search finds over
    /// the same cells, never above the whole ray's maximum (the reference), both within f32's
    /// resolution; `None` only where the cells leave the raster, touch no data or start at
    /// the observer (or the ray runs along grid lines or through grid corners, where the walk
    /// touches the cells beside them); the same bits from every build this machine runs.
    #[test]
    fn window_kernel_brackets_the_f64_search() {
        let mut rnd = crate::testutil::rng(0x57_1D0E);
        let (mut kernel, mut fallback, mut worst) = (0usize, 0usize, 0.0f64);
        let deg = |v: f64| v.atan().to_degrees();
        for (ctx, rect, geo) in bodies() {
            for k in 0..48 {
                let az = Azimuth::new(&ctx, plane_azimuth(k, 48));
                let ww = WindowWalk::new(&ctx, &az);
                for _ in 0..200 {
                    let x = (rnd() * 64.0) as usize;
                    let y = (rnd() * 56.0) as usize;
                    if ctx.at(x as i64, y as i64).is_nan() {
                        continue;
                    }
                    let from = 0.5 + rnd() * 24.0;
                    let to = from + rnd() * 4.0;
                    let o = y * rect.w + x;
                    let ray = Ray::from_parts(&ctx, x, y, &geo[o], &az);
                    let ob = Observer::of(&ray);
                    let got = window(&ctx, &ww, x, y, &ob, from, to);
                    // The f64 search over the same cells (from the end of the first, the cell
                    // before the interval's, whose start is the end of one not taken).
                    let want = match ww.cells(from, to) {
                        Some((k0, k1)) => {
                            let (a, b) = (f64::from(ww.s_hi[k0]), f64::from(ww.s_hi[k1 - 1]));
                            ray.max_over(&ctx, a.max(1e-9), b, f64::NEG_INFINITY).0
                        }
                        None => f64::NEG_INFINITY,
                    };
                    let Some(v) = got else {
                        // Only where a cell the interval meets is incomplete or outside.
                        let complete =
                            |s: f64| ctx.on_complete_cell(ray.x0 + s * ray.cx, ray.y0 + s * ray.cy);
                        // (A ray along a grid line walks the cells on one side of it, one
                        // through grid corners cells beside them for a rounding error.)
                        let (a, b, n) = (from - 1.5, to, 256);
                        let along = ray.cx.abs() < 1e-12
                            || ray.cy.abs() < 1e-12
                            || (ray.cx.abs() - ray.cy.abs()).abs() < 1e-9;
                        let own = from < 1.5;
                        assert!(
                            along
                                || own
                                || (0..=n).any(|q| !complete(a + (b - a) * q as f64 / n as f64)),
                            "({x}, {y}) az {k}: fell back over complete cells [{from}, {to}]"
                        );
                        fallback += 1;
                        continue;
                    };
                    kernel += 1;
                    let whole = ray.max_over(&ctx, 0.0, 1e9, f64::NEG_INFINITY).0;
                    let v = f64::from(v);
                    let mut within = |gap: f64, what: &str| {
                        assert!(gap < 2e-4, "({x}, {y}) az {k} [{from}, {to}]: {v} {what}");
                        worst = worst.max(gap);
                    };
                    if want > f64::NEG_INFINITY {
                        within(
                            deg(want) - deg(v),
                            &format!("below the f64 search's {want}"),
                        );
                    }
                    if v > f64::NEG_INFINITY {
                        within(
                            deg(v) - deg(whole),
                            &format!("above the whole ray's {whole}"),
                        );
                    }
                    // Every build gives the same bits.
                    #[cfg(target_arch = "x86_64")]
                    {
                        let (k0, k1) = ww.cells(from, to).expect("a kernel answer has cells");
                        let c = Cells {
                            hs: &ctx.heights,
                            width: ctx.width,
                            base: y * ctx.width + x,
                            ww: &ww,
                            ob: &ob,
                            k0,
                            k1,
                        };
                        let g = window_cells_generic(&c);
                        if std::arch::is_x86_feature_detected!("avx2") {
                            // SAFETY: AVX2 is present, checked just above.
                            let a = unsafe { window_cells_avx2(&c) };
                            assert_eq!(a.0.to_bits(), g.0.to_bits());
                        }
                        if std::arch::is_x86_feature_detected!("avx512f") {
                            // SAFETY: AVX-512F is present, checked just above.
                            let a = unsafe { window_cells_avx512(&c) };
                            assert_eq!(a.0.to_bits(), g.0.to_bits());
                        }
                    }
                }
            }
        }
        // Random observers in a 64 × 56 raster: a third of the windows reach its edge or a
        // hole and fall back.
        assert!(
            kernel > fallback && fallback > 0,
            "kernel {kernel}, fallback {fallback}"
        );
        eprintln!(
            "window kernel vs f64 search: worst {worst:.1e}° \
             ({kernel} windows, {fallback} fell back)"
        );
    }

    #[test]
    fn run_time_dispatch_is_bit_identical_to_the_generic_kernel() {
        let ctx = rough(64, 56, 256.0, (180, 190), 1_737_400.0);
        let rect = Rect {
            x0: 0,
            y0: 0,
            w: 64,
            h: 56,
        };
        let geo = pixel_geometry(&ctx, rect);
        let az = Azimuth::new(&ctx, 0.7);
        let walk = NearWalk::new(&az, DEFAULT_NEAR_PX);
        let mut sc = NearScratch::default();
        // Row 50, from x = 8: clear of holes and edges for this walk.
        let (y, x0, n) = (50usize, 8usize, 24usize);
        let nodata = NoData::new(&ctx);
        assert!((x0..x0 + n).all(|x| nodata.clean(&walk, x, y)));
        sc.load(&ctx, &az, y * ctx.width + x0, &geo[y * rect.w + x0..][..n]);
        row(&ctx.heights, ctx.width, y * ctx.width + x0, &walk, &mut sc);
        let dispatched = sc.best.clone();
        sc.best = vec![f32::NEG_INFINITY; n];
        row_generic(&ctx.heights, ctx.width, y * ctx.width + x0, &walk, &mut sc);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(dispatched.iter().all(|v| v.is_finite()));
        assert_eq!(bits(&dispatched), bits(&sc.best));
        // Every build this machine can run, not only the one dispatch picks.
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let generic = sc.best.clone();
            sc.best = vec![f32::NEG_INFINITY; n];
            // SAFETY: AVX2 is present, checked just above.
            unsafe { row_avx2(&ctx.heights, ctx.width, y * ctx.width + x0, &walk, &mut sc) };
            assert_eq!(bits(&generic), bits(&sc.best));
        }
    }
}
