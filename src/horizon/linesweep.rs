//! The sweep method (`--method sweep`, docs/horizons.md "Sweep"): Timonen & Westerholm's
//! linear-time horizon extraction (Computer Graphics Forum 29(2), 2010) brought to the sphere.
//!
//! Per plane azimuth the raster is covered with the fast method's parallel lines (straight
//! lines of the gnomonic plane are great circles; one pixel apart along the minor axis; samples
//! where a line crosses pixel columns and rows, exact bilinear values), each sample placed in
//! its line's great-circle plane with the body centre at the origin (curvature exact). Each
//! line is swept once from each end (azimuths φ and φ + π share the lines) keeping the upper
//! convex hull of what it has passed; a sample that lies on an observer column is an observer
//! itself, and the vertex it sees highest is what popping the hull for it leaves on top
//! (Timonen's observation: the query and the insertion are one operation), so a line costs
//! amortised O(1) per sample.
//!
//! A line's observer at a pixel column lies between that column's pixels. Each pixel takes
//! the horizon vertex of the two lines that bracket it at its own column, evaluated from its
//! own position and height (the vertex moved across to the pixel's ray at the same distance),
//! and interpolates the two slopes linearly by the lines' offsets. Nothing is searched on the
//! pixel's own ray, so the method is not bounded by the reference from either side; its error
//! is measured and recorded (the stage's error budget, docs/horizons.md).

use rayon::prelude::*;

use super::geometry::{pixel_geometry, plane_azimuth, Context, Rect};
use super::reference::reference;
use super::sweep::{degrees, Grid, Lines};

/// Sweep-method horizons of every pixel of `rect` in `a` plane azimuths (layout as
/// [`super::horizons`]): degrees, NaN where the observer has no data, −90 where no terrain
/// lies in a direction.
pub(super) fn horizons_sweep(ctx: &Context, rect: Rect, a: usize) -> Vec<f32> {
    let plane = rect.w * rect.h;
    let mut out = vec![0.0f32; plane * a];
    if plane == 0 {
        return out;
    }
    // The raster transposed: lines along rows (major axis y) then walk memory in order too.
    let (w, h) = (ctx.width, ctx.height);
    let mut tr = vec![0.0f32; w * h];
    for (y, row) in ctx.heights.chunks_exact(w).enumerate() {
        for (x, v) in row.iter().enumerate() {
            tr[x * h + y] = *v;
        }
    }
    let tr = &tr[..];
    let hmax = ctx.max_height();
    let pair = |k: usize, b: &mut Buffers, d0: &mut [f32], d1: Option<&mut [f32]>| {
        pair(ctx, hmax, tr, rect, plane_azimuth(k, a), b, d0, d1)
    };
    if a % 2 == 0 {
        let (lo, hi) = out.split_at_mut(plane * (a / 2));
        lo.par_chunks_mut(plane)
            .zip(hi.par_chunks_mut(plane))
            .enumerate()
            .for_each_init(
                || Buffers::new(plane),
                |b, (k, (d0, d1))| pair(k, b, d0, Some(d1)),
            );
    } else {
        out.par_chunks_mut(plane)
            .enumerate()
            .for_each_init(|| Buffers::new(plane), |b, (k, d)| pair(k, b, d, None));
    }
    out
}

/// How many column crossings of its own ray next to it each pixel evaluates.
const NEAR_COLS: usize = 4;

/// Lines per pixel along the minor axis: at 2 a pixel is at most ¼ px from a line. Against
/// 1 (development runs of 2026-12-04 on the six real-DEM blocks, 36 azimuths) the RMS error
/// falls by about 30 % (LDEM_4 0.084° → 0.060°, Gale 0.032° → 0.022°) for ≈ 1.3× the time.
const LINES_PER_PX: usize = 2;

/// Column crossings on either side of a candidate's distance that are evaluated too: a crest
/// crossing the ray obliquely peaks a little nearer or farther on the ray than on the line
/// (synthetic DEM 0.065° → 0.048° RMS, worst 6.6° → 3.9°).
const WINDOW_COLS: i64 = 1;

/// Per-thread buffers, one azimuth pair at a time.
struct Buffers {
    /// Best slope per pixel for `phi` and for `phi` + π.
    ahead: Vec<f64>,
    back: Vec<f64>,
    p: Vec<f64>,
    h: Vec<f32>,
    x: Vec<f64>,
    y: Vec<f64>,
    ux: Vec<f64>,
    uy: Vec<f64>,
    cols: Vec<Col>,
    /// Unit directions in the line's plane at each column of the line's span.
    cu: Vec<(f64, f64)>,
    hull: Vec<(f64, f64, u32)>,
    deg: Vec<f32>,
}

impl Buffers {
    fn new(plane: usize) -> Buffers {
        Buffers {
            ahead: vec![f64::NEG_INFINITY; plane],
            back: vec![f64::NEG_INFINITY; plane],
            p: Vec::new(),
            h: Vec::new(),
            x: Vec::new(),
            y: Vec::new(),
            ux: Vec::new(),
            uy: Vec::new(),
            cols: Vec::new(),
            cu: Vec::new(),
            hull: Vec::new(),
            deg: Vec::new(),
        }
    }
}

/// An observer column of one line: its sample's index, the line's minor coordinate there and
/// the ground metres per plane pixel along the ray per metre of radius (dψ/ds).
#[derive(Clone, Copy)]
struct Col {
    at: usize,
    p: i64,
    y: f64,
    dpsi: f64,
}

/// One line's samples: line parameters, heights, positions and unit directions in the line's
/// plane.
struct Samples<'a> {
    p: &'a [f64],
    h: &'a [f32],
    x: &'a [f64],
    y: &'a [f64],
    ux: &'a [f64],
    uy: &'a [f64],
    /// Unit directions (ux, uy) at column `c0 + i`, every column of the line's span.
    cu: &'a [(f64, f64)],
    c0: i64,
}

/// Plane azimuth `phi` into `dst` and, where given, `phi` + π into `back_dst`.
#[allow(clippy::too_many_arguments)]
fn pair(
    ctx: &Context,
    hmax: f32,
    transposed: &[f32],
    rect: Rect,
    phi: f64,
    b: &mut Buffers,
    dst: &mut [f32],
    back_dst: Option<&mut [f32]>,
) {
    b.ahead.fill(f64::NEG_INFINITY);
    b.back.fill(f64::NEG_INFINITY);
    let mut lines = Lines::new(ctx, rect, phi);
    if !lines.xmajor {
        // Major axis y: the transposed raster, and the pixels' findings transposed too.
        lines.g = Grid {
            h: transposed,
            sp: 1,
            sq: ctx.height,
            np: ctx.height as i64,
            nq: ctx.width as i64,
        };
        lines.si = 1;
        lines.sj = rect.h;
    }
    let lines = lines;
    let g = &lines.g;
    let radius = ctx.radius_m;
    let both = back_dst.is_some();
    let (cos, sin) = (phi.cos(), phi.sin());
    let adp = lines.dp.abs();
    let per = LINES_PER_PX as i64;
    for m in lines.m_lo * per..=lines.m_hi * per {
        let mf = m as f64 / per as f64;
        let Some((start, stop)) = lines.span(mf, 0, g.np - 1) else {
            continue;
        };
        let (a0, a1, b0, b1) = lines.frame(mf, start, stop);
        let cross = (a0 * b1 - a1 * b0).abs();
        b.p.clear();
        b.h.clear();
        b.cols.clear();
        let cols = &mut b.cols;
        lines.samples(mf, start, stop, &mut b.p, &mut b.h, |at, p, y, own| {
            if own {
                let (a, bb) = (a0 + p as f64 * a1, b0 + p as f64 * b1);
                cols.push(Col {
                    at,
                    p,
                    y,
                    dpsi: cross / (a * a + bb * bb) * adp,
                });
            }
        });
        if b.cols.is_empty() {
            continue;
        }
        let len = b.p.len();
        b.x.resize(len, 0.0);
        b.y.resize(len, 0.0);
        b.ux.resize(len, 0.0);
        b.uy.resize(len, 0.0);
        for i in 0..len {
            let pp = b.p[i];
            let (a, bb) = (a0 + pp * a1, b0 + pp * b1);
            let inv = 1.0 / (a * a + bb * bb).sqrt();
            let k = (radius + b.h[i] as f64) * inv;
            b.ux[i] = bb * inv;
            b.uy[i] = a * inv;
            b.x[i] = bb * k;
            b.y[i] = a * k;
        }
        let c0 = start.min(stop);
        b.cu.clear();
        b.cu.extend((c0..=start.max(stop)).map(|p| {
            let (a, bb) = (a0 + p as f64 * a1, b0 + p as f64 * b1);
            let inv = 1.0 / (a * a + bb * bb).sqrt();
            (bb * inv, a * inv)
        }));
        let smp = Samples {
            p: &b.p,
            h: &b.h,
            x: &b.x,
            y: &b.y,
            ux: &b.ux,
            uy: &b.uy,
            cu: &b.cu,
            c0,
        };
        let view = View {
            ctx,
            lines: &lines,
            smp: &smp,
            cos,
            sin,
        };
        line_sweep(&view, &b.cols, 1.0, &mut b.hull, &mut b.ahead);
        if both {
            line_sweep(&view, &b.cols, -1.0, &mut b.hull, &mut b.back);
        }
    }
    let tr = !lines.xmajor;
    finish(ctx, rect, hmax, &b.ahead, tr, phi, &mut b.deg, dst);
    if let Some(d) = back_dst {
        let back = phi + std::f64::consts::PI;
        finish(ctx, rect, hmax, &b.back, tr, back, &mut b.deg, d);
    }
}

/// What a line's sweep needs to hand its findings to the pixels.
struct View<'a> {
    ctx: &'a Context,
    lines: &'a Lines<'a>,
    smp: &'a Samples<'a>,
    cos: f64,
    sin: f64,
}

/// One line swept in sample order (`mirror` = 1) or backwards with x mirrored (−1), the
/// observers' horizon vertices evaluated on the rays of the pixels the line brackets.
#[inline(always)]
fn line_sweep(
    v: &View,
    cols: &[Col],
    mirror: f64,
    hull: &mut Vec<(f64, f64, u32)>,
    acc: &mut [f64],
) {
    hull.clear();
    let s = v.smp;
    let len = s.p.len();
    let mut visit = |i: usize, col: Option<&Col>| {
        if s.h[i].is_nan() {
            return;
        }
        let q = (mirror * s.x[i], s.y[i], i as u32);
        while hull.len() >= 2 {
            let n = hull.len();
            let (o, a) = (hull[n - 2], hull[n - 1]);
            if (a.0 - o.0) * (q.1 - o.1) - (a.1 - o.1) * (q.0 - o.0) >= 0.0 {
                hull.pop();
            } else {
                break;
            }
        }
        if let Some(c) = col {
            hand_out(v, c, mirror, hull, acc);
        }
        hull.push(q);
    };
    if mirror > 0.0 {
        let mut ci = 0;
        for i in 0..len {
            let col = if ci < cols.len() && cols[ci].at == i {
                ci += 1;
                Some(&cols[ci - 1])
            } else {
                None
            };
            visit(i, col);
        }
    } else {
        let mut ci = cols.len();
        for i in (0..len).rev() {
            let col = if ci > 0 && cols[ci - 1].at == i {
                ci -= 1;
                Some(&cols[ci])
            } else {
                None
            };
            visit(i, col);
        }
    }
}

/// The pixels line column `c` brackets evaluate the line's horizon vertices (`cand`, sample
/// indices) on their own rays at the same distance, and the pixel at or above the line the
/// zero-distance slope too: every value is a point of the pixel's own ray.
///
/// An evaluation places the height found on the pixel's ray at the line's direction there
/// (the line's plane stands in for the ray's, as everywhere in this method): at a column the
/// direction comes from the line's column table and the height from the two taps of that
/// column, so no evaluation takes a square root and most read two heights, not four.
#[inline(always)]
fn hand_out(v: &View, c: &Col, mirror: f64, hull: &[(f64, f64, u32)], acc: &mut [f64]) {
    let (lines, s) = (v.lines, v.smp);
    let g = &lines.g;
    let radius = v.ctx.radius_m;
    let qa = c.y.ceil();
    let f = qa - c.y;
    let qa = qa as i64;
    let (upx, upy) = (mirror * s.ux[c.at], s.uy[c.at]);
    let spacing = 1.0 / LINES_PER_PX as f64;
    let qmax = (g.nq - 1) as f64;
    for (side, (q0, w)) in [(qa, spacing - f), (qa - 1, f + spacing - 1.0)]
        .into_iter()
        .enumerate()
    {
        if w <= 0.0 || q0 < lines.rq0 || q0 >= lines.rq1 {
            continue;
        }
        let h0 = g.at(c.p, q0) as f64;
        if h0.is_nan() {
            continue;
        }
        let idx = (c.p - lines.rp0) as usize * lines.si + (q0 - lines.rq0) as usize * lines.sj;
        let r0 = radius + h0;
        // Best (up, hor) so far: compared by cross-multiplying, divided once at the end.
        let prev = acc[idx];
        let (mut bu, mut bh) = if prev == f64::NEG_INFINITY {
            (-1.0, 0.0)
        } else {
            (prev, 1.0)
        };
        // A point of the pixel's ray at height `hv` in direction (ux, uy) of the line plane.
        let mut take = |hv: f64, ux: f64, uy: f64| {
            let k = radius + hv;
            let up = k * (mirror * ux * upx + uy * upy) - r0;
            let hor = k * (uy * upx - mirror * ux * upy);
            if hor > 0.0 && up * bh > bu * hor {
                bu = up;
                bh = hor;
            }
        };
        // The pixel's ray where it crosses column `pw`: two taps along the column.
        let at_col = |pw: i64| -> Option<(f64, f64, f64)> {
            let qv = q0 as f64 + lines.t * (pw - c.p) as f64;
            let ci = pw - s.c0;
            if !(qv >= 0.0 && qv <= qmax) || ci < 0 || ci as usize >= s.cu.len() {
                return None;
            }
            let (hv, ok) = g.sample(pw as f64, qv);
            if !ok || hv.is_nan() {
                return None;
            }
            let (ux, uy) = s.cu[ci as usize];
            Some((hv as f64, ux, uy))
        };
        // The hull vertex the pixel, placed on the line at its own height, sees highest: at
        // or below the line observer's (a higher observer sees farther back; what the line
        // observer popped lies below its own chord and stays hidden from above).
        let o = (mirror * s.ux[c.at] * r0, s.uy[c.at] * r0);
        let better = |a: (f64, f64, u32), b: (f64, f64, u32)| {
            (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0) > 0.0
        };
        let n = hull.len();
        // Columns evaluated so far (each at most once): the candidates' windows overlap.
        let mut done = [i64::MIN; 3 * (2 * WINDOW_COLS as usize + 1)];
        let mut nd = 0;
        if n > 0 {
            let mut top = n - 1;
            while top > 0 && better(hull[top - 1], hull[top]) {
                top -= 1;
            }
            let cand = [
                Some(top),
                (top + 1 < n).then_some(top + 1),
                top.checked_sub(1),
            ];
            for k in cand.into_iter().flatten() {
                let iv = hull[k].2 as usize;
                let pv = s.p[iv];
                let pc = pv.round() as i64;
                if pv != pc as f64 {
                    // A row crossing: its own direction, four taps on the pixel's ray.
                    let qv = q0 as f64 + lines.t * (pv - c.p as f64);
                    if g.inside(pv, qv) {
                        let (hv, ok) = g.sample(pv, qv);
                        if ok && !hv.is_nan() {
                            take(hv as f64, s.ux[iv], s.uy[iv]);
                        }
                    }
                }
                for d in -WINDOW_COLS..=WINDOW_COLS {
                    let pw = pc + d;
                    if pw == c.p || done[..nd].contains(&pw) {
                        continue;
                    }
                    done[nd] = pw;
                    nd += 1;
                    if let Some((hv, ux, uy)) = at_col(pw) {
                        take(hv, ux, uy);
                    }
                }
            }
        }
        if side == 0 {
            // The pixel's own ray where it crosses the next columns.
            let look = -lines.step * mirror as i64;
            for k in 1..=NEAR_COLS as i64 {
                let pw = c.p + look * k;
                if done[..nd].contains(&pw) {
                    continue;
                }
                if let Some((hv, ux, uy)) = at_col(pw) {
                    take(hv, ux, uy);
                }
            }
        }
        let mut best = if bh > 0.0 { bu / bh } else { f64::NEG_INFINITY };
        if side == 0 {
            let (x, y) = if lines.xmajor {
                (c.p as usize, q0 as usize)
            } else {
                (q0 as usize, c.p as usize)
            };
            let s0 = v
                .ctx
                .slope0_g(x, y, mirror * v.cos, mirror * v.sin, r0 * c.dpsi);
            if s0 > best {
                best = s0;
            }
        }
        acc[idx] = best;
    }
}

/// The pixels' slopes (`acc`, row-major or, where `transposed`, column-major) as degrees:
/// NaN where the pixel has no data. Where a pixel found nothing at all (every line's vertex
/// fell outside its ray's raster or on cells it may not evaluate), its own ray is searched by
/// the reference instead: −90 there means no terrain in that direction.
#[allow(clippy::too_many_arguments)]
fn finish(
    ctx: &Context,
    rect: Rect,
    hmax: f32,
    acc: &[f64],
    transposed: bool,
    phi: f64,
    deg: &mut Vec<f32>,
    dst: &mut [f32],
) {
    deg.resize(acc.len(), 0.0);
    degrees(acc, deg);
    if transposed {
        // Blocks of 32 × 32: both sides stay in cache.
        const B: usize = 32;
        for j0 in (0..rect.h).step_by(B) {
            for i0 in (0..rect.w).step_by(B) {
                for j in j0..(j0 + B).min(rect.h) {
                    for i in i0..(i0 + B).min(rect.w) {
                        dst[j * rect.w + i] = deg[i * rect.h + j];
                    }
                }
            }
        }
    } else {
        dst.copy_from_slice(deg);
    }
    for j in 0..rect.h {
        let row = &ctx.heights[(rect.y0 + j) * ctx.width + rect.x0..][..rect.w];
        for (i, h0) in row.iter().enumerate() {
            let o = j * rect.w + i;
            if h0.is_nan() {
                dst[o] = f32::NAN;
            } else if dst[o] == -90.0 {
                let one = Rect {
                    x0: rect.x0 + i,
                    y0: rect.y0 + j,
                    w: 1,
                    h: 1,
                };
                let geo = pixel_geometry(ctx, one);
                reference(ctx, one, phi, hmax, 0.0, &geo, &mut dst[o..o + 1]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::geometry::lunar_context;
    use super::*;

    /// The reference's planes (as `horizons(.., Method::Reference)`, which this module may not
    /// import: the method module imports it).
    fn reference_planes(ctx: &Context, rect: Rect, a: usize) -> Vec<f32> {
        let plane = rect.w * rect.h;
        let geo = pixel_geometry(ctx, rect);
        let mut out = vec![0.0f32; plane * a];
        for (k, dst) in out.chunks_mut(plane).enumerate() {
            reference(
                ctx,
                rect,
                plane_azimuth(k, a),
                ctx.max_height(),
                0.0,
                &geo,
                dst,
            );
        }
        out
    }

    /// Rough terrain: smooth waves plus 1-px noise, with a few holes (no data).
    fn rough(w: usize, h: usize, seed: u64, holes: bool) -> Vec<f32> {
        let mut rnd = crate::testutil::rng(seed);
        let mut v = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let (xf, yf) = (x as f64, y as f64);
                let base = 800.0 * (xf / 17.0).sin() * (yf / 23.0).cos() + 300.0 * (xf / 5.3).cos();
                let mut z = (base + 150.0 * (rnd() - 0.5)) as f32;
                if holes && (x / 9 + y / 7) % 11 == 0 && (x * 7 + y * 3) % 5 == 0 {
                    z = f32::NAN;
                }
                v.push(z);
            }
        }
        v
    }

    /// Never above the reference by more than 0.01° (the lines' geometry stands in for the
    /// ray's), within bounds on very rough 1-px terrain with holes, no data exactly where the
    /// reference has none, and the same bytes on 1 and 3 threads.
    #[test]
    fn sweep_stays_below_the_reference_and_is_deterministic() {
        let (w, h) = (96, 80);
        for (seed, holes) in [(0x5EE9, false), (0xA11, true)] {
            let ctx = lunar_context(w, h, rough(w, h, seed, holes), 60.0);
            let rect = Rect {
                x0: 20,
                y0: 16,
                w: 48,
                h: 40,
            };
            let a = 24;
            let want = reference_planes(&ctx, rect, a);
            let run = |threads| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| horizons_sweep(&ctx, rect, a))
            };
            let got = run(1);
            let again = run(3);
            assert!(got
                .iter()
                .zip(&again)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
            let (mut n, mut sq, mut above, mut worst) = (0usize, 0.0f64, 0.0f64, 0.0f64);
            for (g, r) in got.iter().zip(&want) {
                assert_eq!(
                    g.is_nan(),
                    r.is_nan(),
                    "no data where the reference has none"
                );
                if g.is_nan() {
                    continue;
                }
                let d = f64::from(*g) - f64::from(*r);
                n += 1;
                sq += d * d;
                above = above.max(d);
                worst = worst.max(d.abs());
            }
            let rms = (sq / n as f64).sqrt();
            assert!(above < 0.01, "seed {seed:x}: {above}° above the reference");
            // 150 m of 1-px noise on 60 m pixels (slopes up to 2.5) is far rougher than any
            // real DEM: this build gives 0.36–0.45° RMS and 11.7–14.2° at worst here; the
            // bounds are about 1.4× that.
            assert!(rms < 0.6, "seed {seed:x}: RMS {rms}°");
            assert!(worst < 20.0, "seed {seed:x}: worst {worst}°");
        }
    }

    /// A bare sphere reads 0 (the zero-distance slope) wherever there is terrain, and −90
    /// nowhere inside the raster's reach.
    #[test]
    fn bare_sphere_reads_zero() {
        let (w, h) = (40, 36);
        let ctx = lunar_context(w, h, vec![0.0; w * h], 100.0);
        let rect = Rect {
            x0: 8,
            y0: 8,
            w: 24,
            h: 20,
        };
        let got = horizons_sweep(&ctx, rect, 16);
        for v in got {
            assert!(v.abs() < 1e-4, "{v}");
        }
    }
}
