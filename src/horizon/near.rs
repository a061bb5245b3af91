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

    #[test]
    fn row_kernel_equals_the_f64_cell_walk() {
        // Earth-like at 30 m near the face centre; the Moon at 7.6 km pixels near a face
        // corner (strong gnomonic distortion, ψ up to 0.1 rad within the near field); a 10 km body.
        let cases = [
            (424_734.0, (212_000, 212_000), 6_371_008.8),
            (256.0, (180, 190), 1_737_400.0),
            (600.0, (250, 240), 10_000.0),
        ];
        let mut worst = 0.0f64;
        for (face_pixels, origin, radius) in cases {
            let ctx = rough(64, 56, face_pixels, origin, radius);
            let rect = Rect {
                x0: 0,
                y0: 0,
                w: 64,
                h: 56,
            };
            let geo = pixel_geometry(&ctx, rect);
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
