//! The fast method's far field: each observer's own ray walked over a **maximum pyramid** of the
//! context, skipping every block whose highest terrain provably cannot rise above the best
//! slope found so far, and searching exactly ([`Ray::max_over`]) only the cells that could.
//!
//! Level 0 holds, per cell of the raster, the highest of its four corners: the bilinear surface
//! inside a cell is a convex combination of them (no-data corners left out), so no point of the
//! cell is higher. Level k holds the maximum over 2ᵏ × 2ᵏ cells. For a block the ray crosses
//! over distances [s₀, s₁] and an observer at radius r₀ whose best slope so far is t, terrain at
//! radius r and geocentric angle ψ from the observer is seen at a slope above t only if
//! r·(cos ψ − t·sin ψ) > r₀; the left side grows with r and, along the ray, ψ grows with s, so
//! the least radius that could win is at ψ* = atan(−t) clamped into the block's range (t < 0),
//! or at its start (t ≥ 0). A block whose maximum is below that radius is skipped whole; that
//! test is exact, so the result is the exact maximum over the continuous surface, the same
//! answer as the brute-force reference (up to rounding), and never above it.
//!
//! The walk climbs one level after every skipped block and descends where a block could win,
//! so a ray whose horizon is near costs a few tests per octave of distance, whatever the
//! context's size: far terrain is seen only through coarse blocks unless it matters.

use super::geometry::{Azimuth, Context, PixelGeo, Ray, Rect};

/// Half-width (plane pixels) of the stretch searched exactly round a neighbour's horizon.
const SEED_WINDOW: f64 = 1.5;

/// Blocks this size (cells) or smaller are searched exactly when they could win, rather than
/// split further.
const EXACT_CELLS: usize = 2;

/// The maximum pyramid of a context raster: level 0 per cell, level k per 2ᵏ × 2ᵏ cells.
pub(super) struct MaxPyramid {
    levels: Vec<Level>,
}

struct Level {
    w: usize,
    h: usize,
    max: Vec<f32>,
}

impl MaxPyramid {
    pub(super) fn new(ctx: &Context) -> MaxPyramid {
        let (w, h) = (ctx.width, ctx.height);
        let at = |x: usize, y: usize| -> f32 {
            if x < w && y < h {
                let v = ctx.heights[y * w + x];
                if v.is_nan() {
                    f32::NEG_INFINITY
                } else {
                    v
                }
            } else {
                f32::NEG_INFINITY
            }
        };
        // Cell (i, j) spans [i, i+1] × [j, j+1]; the last column and row are the raster's edge
        // lines (their missing corners are outside, as in `Context::bilinear64`).
        let mut max = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                max.push(
                    at(i, j)
                        .max(at(i + 1, j))
                        .max(at(i, j + 1))
                        .max(at(i + 1, j + 1)),
                );
            }
        }
        let mut levels = vec![Level { w, h, max }];
        while {
            let l = levels.last().unwrap();
            l.w > 1 || l.h > 1
        } {
            let l = levels.last().unwrap();
            let (nw, nh) = (l.w.div_ceil(2), l.h.div_ceil(2));
            let mut m = Vec::with_capacity(nw * nh);
            for j in 0..nh {
                for i in 0..nw {
                    let mut v = f32::NEG_INFINITY;
                    for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (x, y) = (2 * i + di, 2 * j + dj);
                        if x < l.w && y < l.h {
                            v = v.max(l.max[y * l.w + x]);
                        }
                    }
                    m.push(v);
                }
            }
            levels.push(Level {
                w: nw,
                h: nh,
                max: m,
            });
        }
        MaxPyramid { levels }
    }
}

/// Counters of one walk (tests and benchmarks).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct WalkStats {
    pub(super) tests: u64,
    pub(super) exact: u64,
}

/// The largest slope along `ray` over (s_from, end of the raster] and where it is (NaN when
/// nothing there beats `best`), given `best`, the largest slope already known (real points of
/// this ray, so a valid floor: the higher, the more the walk skips).
pub(super) fn far_max(
    ctx: &Context,
    pyr: &MaxPyramid,
    ray: &Ray,
    s_from: f64,
    mut best: f64,
    stats: &mut WalkStats,
) -> (f64, f64) {
    let mut at = f64::NAN;
    let (w1, h1) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
    // Where the ray leaves the raster's points [0, w−1] × [0, h−1].
    let exit = |x0: f64, c: f64, hi: f64| -> f64 {
        if c > 1e-12 {
            (hi - x0) / c
        } else if c < -1e-12 {
            -x0 / c
        } else {
            f64::INFINITY
        }
    };
    let s_end = exit(ray.x0, ray.cx, w1).min(exit(ray.y0, ray.cy, h1));
    let top = pyr.levels.len() - 1;
    let r_earth = ctx.radius_m;
    // ψ* (as a distance along the ray) for the current best, where the least winning radius
    // is lowest; +∞ when the ray never gets there.
    let s_star = |t: f64| -> f64 {
        if t >= 0.0 {
            return 0.0;
        }
        let t = t.max(-1e12);
        let den = ray.b1 + t * ray.a1;
        if den > 0.0 {
            -t * ray.a0 / den
        } else {
            f64::INFINITY
        }
    };
    let mut t_eff = if best.is_finite() { best } else { -1e12 };
    let mut sstar = s_star(t_eff);
    let mut s = s_from;
    // Start at the level whose blocks are about a quarter of the distance already covered.
    let mut k = {
        let mut k = 0;
        while k < top && ((1usize << (k + 2)) as f64) < s_from.max(1.0) {
            k += 1;
        }
        k
    };
    let inv = |c: f64| if c.abs() > 1e-12 { 1.0 / c } else { 0.0 };
    let (icx, icy) = (inv(ray.cx), inv(ray.cy));
    // The far side of a block along each axis: block index + 1 moving up, + 0 moving down.
    let (fx, fy) = ((ray.cx > 1e-12) as usize, (ray.cy > 1e-12) as usize);
    let r02 = ray.r0 * ray.r0;
    while s < s_end {
        let lvl = &pyr.levels[k];
        let size = (1usize << k) as f64;
        let isize = 1.0 / size; // exact: a power of two
                                // The block the ray is in just after s.
        let sp = s + 1e-7 * (1.0 + s);
        let (x, y) = (ray.x0 + sp * ray.cx, ray.y0 + sp * ray.cy);
        let bx = ((x.max(0.0) * isize) as usize).min(lvl.w - 1);
        let by = ((y.max(0.0) * isize) as usize).min(lvl.h - 1);
        let ex = if icx != 0.0 {
            ((bx + fx) as f64 * size - ray.x0) * icx
        } else {
            f64::INFINITY
        };
        let ey = if icy != 0.0 {
            ((by + fy) as f64 * size - ray.y0) * icy
        } else {
            f64::INFINITY
        };
        let se = ex.min(ey).min(s_end).max(sp);
        let hmax = lvl.max[by * lvl.w + bx];
        stats.tests += 1;
        // Could any terrain of the block, over [s, se], rise above `best`? Only if
        // (R + hmax)·(a − t·b) > r0·‖(a, b)‖ at the clamped ψ*, compared squared.
        let sc = sstar.clamp(s, se);
        let (a, b) = (ray.a0 + sc * ray.a1, sc * ray.b1);
        let lhs = (r_earth + hmax as f64) * (a - t_eff * b);
        if lhs <= 0.0 || lhs * lhs <= r02 * (a * a + b * b) {
            s = se;
            if k < top {
                k += 1;
            }
            continue;
        }
        if (1usize << k) <= EXACT_CELLS {
            stats.exact += 1;
            let (m, where_) = ray.max_over(ctx, s, se, best);
            if m > best {
                best = m;
                at = where_;
                t_eff = m;
                sstar = s_star(t_eff);
            }
            s = se;
            continue;
        }
        k -= 1;
    }
    (best, at)
}

/// Elevations (degrees) of every observer of `rect` along `az`: the near field's exact maximum
/// (`near`, over (0, near_px]), the pyramid walk beyond it, and the zero-distance slope.
#[allow(clippy::too_many_arguments)]
pub(super) fn finish(
    ctx: &Context,
    pyr: &MaxPyramid,
    rect: Rect,
    az: &Azimuth,
    near_px: f64,
    geo: &[PixelGeo],
    near: &[f64],
    dst: &mut [f32],
    stats: &mut WalkStats,
) {
    // Where the neighbours' horizons are (the observer before in this row, the one above in
    // this column): terrain that high is usually about as high from here. The ray searched
    // exactly round there first gives the walk a floor close to the answer, and the walk then
    // skips nearly everything else.
    let mut above = vec![f64::NAN; rect.w];
    for j in 0..rect.h {
        let mut left = f64::NAN;
        for (i, seed_above) in above.iter_mut().enumerate() {
            let (x, y) = (rect.x0 + i, rect.y0 + j);
            let o = j * rect.w + i;
            if ctx.at(x as i64, y as i64).is_nan() {
                dst[o] = f32::NAN;
                continue;
            }
            let ray = Ray::from_parts(ctx, x, y, &geo[o], az);
            let s0 = ctx.slope0_g(x, y, az.cos, az.sin, ray.ground_per_px());
            let mut floor = if s0 > near[o] { s0 } else { near[o] };
            for seed in [left, *seed_above] {
                if seed.is_finite() && seed + SEED_WINDOW > near_px {
                    stats.exact += 1;
                    let lo = (seed - SEED_WINDOW).max(near_px);
                    floor = floor.max(ray.max_over(ctx, lo, seed + SEED_WINDOW, floor).0);
                }
            }
            let (t, at) = far_max(ctx, pyr, &ray, near_px, floor, stats);
            // The seeds themselves are not where the maximum is unless the walk found nothing
            // higher; then the old seed stays the best guess for the next observer.
            if at.is_finite() {
                left = at;
                *seed_above = at;
            }
            dst[o] = t.atan().to_degrees() as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::horizon::geometry::plane_azimuth;

    fn context(w: usize, h: usize, relief: f32, pixel_m: f64, seed: u64) -> Context {
        let mut rnd = crate::testutil::rng(seed);
        // Smooth hills plus noise, a few spikes and a no-data hole.
        let mut heights = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f64 / w as f64, y as f64 / h as f64);
                let v = (fx * 9.0).sin() * (fy * 7.0).cos() * 0.5 + rnd() * 0.2;
                heights[y * w + x] = (v as f32) * relief;
            }
        }
        for _ in 0..20 {
            let i = (rnd() * (w * h) as f64) as usize;
            heights[i] += relief * 2.0;
        }
        for y in h / 3..h / 3 + 5 {
            for x in w / 2..w / 2 + 7 {
                heights[y * w + x] = f32::NAN;
            }
        }
        crate::horizon::geometry::lunar_context(w, h, heights, pixel_m)
    }

    /// The walk gives the exact search's answer over the same stretch of ray, from floors
    /// below, at and above it, on rough terrain with spikes and no data, in every direction
    /// (axes and diagonals included), and skips most of the ray.
    #[test]
    fn walk_equals_the_exact_search() {
        for (relief, pixel_m, seed) in [(500.0, 100.0, 7), (4000.0, 30.0, 11), (5.0, 1000.0, 3)] {
            let ctx = context(200, 170, relief, pixel_m, seed);
            let pyr = MaxPyramid::new(&ctx);
            let mut st = WalkStats::default();
            let mut rays = 0u64;
            for k in 0..64 {
                let phi = plane_azimuth(k, 64) + if k % 3 == 0 { 0.0 } else { 0.013 * k as f64 };
                for (x, y) in [(100, 85), (3, 3), (199, 0), (57, 160), (150, 60)] {
                    if ctx.at(x, y).is_nan() {
                        continue;
                    }
                    let ray = Ray::toward(&ctx, x as usize, y as usize, phi);
                    for s_from in [0.5, 3.0, 24.0] {
                        let (exact, _) = ray.max_over(&ctx, s_from, 1e9, f64::NEG_INFINITY);
                        for floor in [f64::NEG_INFINITY, exact - 0.01, exact, exact + 0.01] {
                            let got = far_max(&ctx, &pyr, &ray, s_from, floor, &mut st).0;
                            let want = exact.max(floor);
                            assert!(
                                (got - want).abs() <= 1e-12 * (1.0 + want.abs()) || (got == want),
                                "relief {relief} φ {phi} ({x}, {y}) from {s_from} floor \
                                 {floor}: walk {got}, exact {want}"
                            );
                            rays += 1;
                        }
                    }
                }
            }
            assert!(
                st.tests > 0 && st.exact < rays * 40,
                "{st:?} over {rays} rays"
            );
        }
    }
}
