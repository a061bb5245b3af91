//! The brute-force reference: each observer's own ray searched to the end of the context
//! raster (docs/horizons.md).

use super::geometry::{snap, Azimuth, Context, PixelGeo, Ray, Rect};

/// Brute-force horizons of `rect` in plane azimuth `phi`: from each pixel centre along the
/// straight plane line (a great circle), exact spherical geometry; with `step` = 0 the
/// continuous bilinear surface cell by cell ([`Ray::max_over`]), else samples every `step`
/// plane pixels. Stops where no terrain up to `hmax` could rise above the best so far.
pub(super) fn reference(
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
                // Snapped as the search snaps it (a ray along the raster's edge row).
                let (x, y) = (
                    snap(ray.x0 + s * ray.cx, (ctx.width - 1) as f64),
                    snap(ray.y0 + s * ray.cy, (ctx.height - 1) as f64),
                );
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
