//! The ray-marching shadow methods over one [`Context`] raster (a face's extended gnomonic
//! plane, where the shadow ray of a surface point projects to a straight line: the great circle
//! through the point and the sub-solar point). Each method estimates the horizon's elevation in
//! the sun's azimuth (as a slope, tan of the elevation) out to where the ray leaves the terrain
//! volume, and turns it into the lit fraction of the sun's disc:
//!
//! - [`Method::Reference`]: the exact search of the continuous bilinear surface (the horizon
//!   reference's cell walk) in [`REFERENCE_AZIMUTHS`] azimuths across the disc, and the exact
//!   disc visibility over that horizon (the Fourier issue's `--model exact`);
//! - [`Method::Uniform`]: `steps` equal steps out to where the ray leaves the terrain volume
//!   (Jung et al.'s baseline), bilinear samples;
//! - [`Method::Dp`]: Jung et al.'s Algorithm 1 over a maximum mipmap: runs of N′ levels,
//!   coarse to fine, at each level the (at most three) texels the ray crosses inside the chosen
//!   parent, the one that could rise highest kept; the chosen finest cell is searched exactly;
//!   runs are concatenated ({5,5,5}, {5,5,5,3}, or `auto`: each run as long as the distance
//!   already covered, until the ray leaves the terrain volume). `dda` samples two points per
//!   level instead (the canonical DDA of their Fig. 4a, which misses corner texels). The texels
//!   the descent passed over are refined where their bound still beats what it found (the
//!   penumbra refinement: the plain DP misses the horizon where a texel beside the ray holds the
//!   higher maximum); [`Method::JungDp`] is the plain DP as published;
//! - [`Method::Extrema`]: Timokhin & Mikhaylyuk's min/max traversal (hard shadow): texels the
//!   ray passes above are skipped, a texel whose minimum already reaches the ray ends the walk
//!   as shadowed, the rest are refined down to exact cells.
//!
//! The soft methods (uniform, dp) use Jung et al.'s disc occlusion (Eq. 6–7): a horizon at
//! elevation α hides the circular segment of the disc below α. Every horizon is floored at the
//! tangent to the sphere of the lowest terrain, as the horizon products are.

use crate::fourier::sun::{self, Frame, Model, Sun};
use crate::horizon::{Axis, Context, Ray};

/// Azimuths across the sun's disc in which the reference searches the exact horizon.
pub const REFERENCE_AZIMUTHS: usize = 7;
/// The exact near field of the ray-marching methods (plane pixels): inside it the observer's
/// own cells' bounds are useless (they contain the observer), so every method searches it
/// exactly, as the reference does.
pub const NEAR_PX: f64 = 1.5;
/// Largest N′ of one DP run, and most runs.
pub const MAX_DP_LEVELS: usize = 16;
pub const MAX_DP_RUNS: usize = 16;
/// Most texels a refined DP run keeps waiting: along the path being searched, at most 3 from the
/// run's first level (4 candidates kept) and 2 from each finer one (a straight line crosses at
/// most three texels of a parent), 3 + 2 · 15 = 33 for 16 levels.
pub const DP_STACK: usize = 40;
/// Most uniform steps.
pub const MAX_STEPS: usize = 1 << 20;

/// How Jung et al.'s DP concatenates its runs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Runs {
    /// Runs of these N′, one after the other (`5,5,5`).
    Fixed(Vec<usize>),
    /// Each run reaches as far again as the distance covered so far (at least N′ = 5), until
    /// the ray leaves the terrain volume.
    Auto,
}

impl std::fmt::Display for Runs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Runs::Auto => f.write_str("auto"),
            Runs::Fixed(v) => {
                let s: Vec<String> = v.iter().map(|n| n.to_string()).collect();
                f.write_str(&s.join(","))
            }
        }
    }
}

impl std::str::FromStr for Runs {
    type Err = String;
    fn from_str(s: &str) -> Result<Runs, String> {
        if s == "auto" {
            return Ok(Runs::Auto);
        }
        let v: Vec<usize> = s
            .split(',')
            .map(|p| p.trim().parse::<usize>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("'{s}' is not a list of DP levels such as 5,5,5 (or auto)"))?;
        if v.is_empty() || v.len() > MAX_DP_RUNS {
            return Err(format!("'{s}': give 1..={MAX_DP_RUNS} runs"));
        }
        if let Some(bad) = v.iter().find(|&&n| !(1..=MAX_DP_LEVELS).contains(&n)) {
            return Err(format!(
                "'{s}': a run has {bad} levels; each needs 1..={MAX_DP_LEVELS}"
            ));
        }
        Ok(Runs::Fixed(v))
    }
}

/// A ray-marching shadow method.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Method {
    Reference,
    Uniform {
        steps: usize,
    },
    Dp {
        runs: Runs,
        dda: bool,
    },
    /// Jung et al.'s DP as published: one texel kept per level, no refinement (what `Dp` was
    /// before the penumbra refinement; kept to compare with the paper's method).
    JungDp {
        runs: Runs,
        dda: bool,
    },
    Extrema,
    /// The min/max traversal turned into a soft shadow: the exact horizon in the sun's azimuth
    /// within the disc's band (texels that cannot rise above the best found or the disc's
    /// bottom are skipped, the walk stops once the disc's top is hidden), with the same disc
    /// occlusion as DP.
    ExtremaSoft,
}

impl Method {
    /// Whether the method answers 0 or 1 only.
    pub fn is_hard(&self) -> bool {
        matches!(self, Method::Extrema)
    }

    pub fn label(&self) -> String {
        match self {
            Method::Reference => "reference".into(),
            Method::Uniform { steps } => format!("uniform {steps}"),
            Method::Dp { runs, dda: false } => format!("dp {runs}"),
            Method::Dp { runs, dda: true } => format!("dp-dda {runs}"),
            Method::JungDp { runs, dda: false } => format!("dp-jung {runs}"),
            Method::JungDp { runs, dda: true } => format!("dp-dda-jung {runs}"),
            Method::Extrema => "extrema".into(),
            Method::ExtremaSoft => "extrema-soft".into(),
        }
    }
}

/// Level `m` of the min/max pyramid over the raster's *cells* (cell (i, j) spans the pixel
/// centres (i..=i+1, j..=j+1), so its extrema bound the bilinear surface there exactly);
/// texel (X, Y) of level m covers cells [X·2^m, (X+1)·2^m).
struct Level {
    w: usize,
    h: usize,
    /// Highest terrain in the texel (−∞: none).
    max: Vec<f32>,
    /// Lowest terrain in the texel (−∞ when part of it has none: no guarantee then).
    min: Vec<f32>,
}

/// The min/max pyramid of a context raster's cells.
pub struct Extrema {
    levels: Vec<Level>,
}

impl Extrema {
    pub fn new(ctx: &Context) -> Extrema {
        use rayon::prelude::*;
        let (w, h) = (ctx.width.max(2) - 1, ctx.height.max(2) - 1);
        let mut max = vec![f32::NEG_INFINITY; w * h];
        let mut min = vec![f32::NEG_INFINITY; w * h];
        max.par_chunks_mut(w)
            .zip(min.par_chunks_mut(w))
            .enumerate()
            .for_each(|(j, (mx, mn))| {
                let (r0, r1) = (
                    &ctx.heights[j * ctx.width..][..ctx.width],
                    &ctx.heights[(j + 1).min(ctx.height - 1) * ctx.width..][..ctx.width],
                );
                for i in 0..w {
                    let i1 = (i + 1).min(ctx.width - 1);
                    let c = [r0[i], r0[i1], r1[i], r1[i1]];
                    let (mut hi, mut lo, mut all) = (f32::NEG_INFINITY, f32::INFINITY, true);
                    for v in c {
                        if v.is_nan() {
                            all = false;
                        } else {
                            hi = hi.max(v);
                            lo = lo.min(v);
                        }
                    }
                    // With a no-data corner the bilinear surface still lies below the present
                    // corners, but part of the cell may hold no terrain: no lower bound then.
                    mx[i] = hi;
                    if all {
                        mn[i] = lo;
                    }
                }
            });
        let mut levels = vec![Level { w, h, max, min }];
        while levels.last().is_some_and(|l| l.w > 1 || l.h > 1) {
            let p = levels.last().expect("one level");
            let (w2, h2) = (p.w.div_ceil(2), p.h.div_ceil(2));
            let mut max = vec![f32::NEG_INFINITY; w2 * h2];
            let mut min = vec![f32::INFINITY; w2 * h2];
            max.par_chunks_mut(w2)
                .zip(min.par_chunks_mut(w2))
                .enumerate()
                .for_each(|(y2, (mx, mn))| {
                    for y in [2 * y2, 2 * y2 + 1] {
                        if y >= p.h {
                            // A texel hanging over the raster's edge covers cells without
                            // terrain.
                            mn.iter_mut().for_each(|v| *v = f32::NEG_INFINITY);
                            continue;
                        }
                        for x in 0..p.w {
                            mx[x / 2] = mx[x / 2].max(p.max[y * p.w + x]);
                            mn[x / 2] = mn[x / 2].min(p.min[y * p.w + x]);
                        }
                    }
                    if p.w % 2 == 1 {
                        mn[w2 - 1] = f32::NEG_INFINITY;
                    }
                });
            levels.push(Level {
                w: w2,
                h: h2,
                max,
                min,
            });
        }
        Extrema { levels }
    }

    /// Number of levels (level 0: cells).
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// (max, min) of texel (x, y) of level m; (−∞, −∞) outside.
    #[inline]
    fn get(&self, m: usize, x: i64, y: i64) -> (f32, f32) {
        let l = &self.levels[m];
        if x < 0 || y < 0 || x >= l.w as i64 || y >= l.h as i64 {
            return (f32::NEG_INFINITY, f32::NEG_INFINITY);
        }
        let o = y as usize * l.w + x as usize;
        (l.max[o], l.min[o])
    }

    /// Level `m` as (width, height, max, min), row-major (−∞: no terrain / no lower bound),
    /// for copies elsewhere (the viewer's GPU twins upload it).
    pub fn level(&self, m: usize) -> (usize, usize, &[f32], &[f32]) {
        let l = &self.levels[m];
        (l.w, l.h, &l.max, &l.min)
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.levels.iter().map(|l| 8 * l.w * l.h).sum()
    }
}

/// The sun at one surface point.
#[derive(Clone, Copy, Debug)]
pub struct SunAt {
    pub frame: Frame,
    /// Plane azimuth of the sun's vertical plane (radians) and its centre's elevation and
    /// radius (degrees).
    pub phi: f64,
    pub elevation_deg: f64,
    pub radius_deg: f64,
}

/// Counters of the work a method did (texels or samples visited), summed over pixels.
#[derive(Clone, Copy, Debug, Default)]
pub struct Work {
    pub visits: u64,
}

/// One context raster prepared for the ray-marching methods.
pub struct Tracer<'a> {
    pub ctx: &'a Context,
    pub pyramid: Extrema,
    /// Highest terrain of the raster (m).
    pub hmax: f64,
    /// Lowest terrain of the body (or what stands for it), for the floor (m).
    pub terrain_min_m: f64,
}

impl<'a> Tracer<'a> {
    /// `terrain_min_m`: the lowest terrain of the body as far as known (the tileset's), below
    /// whose sphere's tangent no horizon is taken to lie (as the horizon products).
    pub fn new(ctx: &'a Context, terrain_min_m: f64) -> Tracer<'a> {
        let pyramid = Extrema::new(ctx);
        let hmax = ctx.max_height() as f64;
        let tmin = ctx
            .heights
            .iter()
            .filter(|v| v.is_finite())
            .fold(f64::INFINITY, |m, &v| m.min(v as f64));
        Tracer {
            ctx,
            pyramid,
            hmax,
            terrain_min_m: terrain_min_m.min(tmin),
        }
    }

    /// The sun seen from raster pixel (x, y).
    pub fn sun_at(&self, x: usize, y: usize, sun: &Sun) -> SunAt {
        let (u, v) = self.ctx.uv(x as f64, y as f64);
        let frame = Frame::at(self.ctx.face, u, v);
        let el = frame.elevation_deg(sun.dir);
        SunAt {
            frame,
            phi: frame.plane_azimuth(sun.dir),
            elevation_deg: el,
            radius_deg: sun.radius_deg.clamp(0.0, 60.0),
        }
    }

    /// Lit fraction of the sun's disc at raster pixel (x, y) by `method`; NaN over no data.
    pub fn lit(&self, x: usize, y: usize, sun: &Sun, method: &Method, work: &mut Work) -> f64 {
        self.trace(x, y, sun, method, work).lit
    }

    /// [`Tracer::lit`] and the horizon the method found in the sun's azimuth.
    pub fn trace(&self, x: usize, y: usize, sun: &Sun, method: &Method, work: &mut Work) -> Traced {
        let h0 = self.ctx.at(x as i64, y as i64);
        if h0.is_nan() {
            return Traced {
                lit: f64::NAN,
                horizon_deg: f64::NAN,
            };
        }
        let at = self.sun_at(x, y, sun);
        let floor =
            crate::fourier::stage::floor_deg(self.ctx.radius_m, self.terrain_min_m, h0 as f64);
        let (el, r) = (at.elevation_deg, at.radius_deg);
        // Bounds of the disc: a horizon below its bottom leaves it whole, one above its top
        // hides it; the searches stop there.
        let lo = tan_deg(el - r);
        let hi = tan_deg(el + r);
        let done = |lit: f64, a: f64| Traced {
            lit,
            horizon_deg: degrees(a, floor),
        };
        if el + r <= floor && !matches!(method, Method::Extrema) {
            // Below the body's own horizon whatever the terrain does.
            return done(0.0, f64::NEG_INFINITY);
        }
        match method {
            Method::Reference => {
                let (lit, a) = self.reference(x, y, sun, &at, floor, work);
                Traced {
                    lit,
                    horizon_deg: a,
                }
            }
            Method::Extrema => {
                if el <= floor {
                    return done(0.0, f64::NEG_INFINITY);
                }
                let ray = ray_toward(self.ctx, x, y, at.phi);
                let dark = self.extrema(&ray, x, y, &at, tan_deg(el), work);
                // The traversal decides without finding the horizon.
                Traced {
                    lit: if dark { 0.0 } else { 1.0 },
                    horizon_deg: f64::NAN,
                }
            }
            Method::Uniform { steps } => {
                let ray = ray_toward(self.ctx, x, y, at.phi);
                let a = self.uniform(&ray, *steps, lo, work);
                done(occlusion(a, floor, el, r), a)
            }
            Method::Dp { runs, dda } => {
                let ray = ray_toward(self.ctx, x, y, at.phi);
                let a = self.dp(&ray, x, y, &at, runs, *dda, true, lo, hi, work);
                done(occlusion(a, floor, el, r), a)
            }
            Method::JungDp { runs, dda } => {
                let ray = ray_toward(self.ctx, x, y, at.phi);
                let a = self.dp(&ray, x, y, &at, runs, *dda, false, lo, hi, work);
                done(occlusion(a, floor, el, r), a)
            }
            Method::ExtremaSoft => {
                let ray = ray_toward(self.ctx, x, y, at.phi);
                let a = self.extrema_soft(&ray, x, y, &at, lo, hi, work);
                done(occlusion(a, floor, el, r), a)
            }
        }
    }

    /// Whether the sun's centre at raster pixel (x, y) lies within [`PENUMBRA_BAND_DEG`] of the
    /// exact horizon in its azimuth: the penumbra metric's pixels (false over no data).
    pub fn penumbral(&self, x: usize, y: usize, sun: &Sun) -> bool {
        let (el, h) = self.band_horizon(x, y, sun, PENUMBRA_BAND_DEG);
        (el - h).abs() <= PENUMBRA_BAND_DEG
    }

    /// The sun's centre elevation at raster pixel (x, y) and the exact (floored) horizon in its
    /// azimuth, both in degrees, where that horizon lies within `band_deg` of the centre: the
    /// search stops outside the band, so a horizon beyond it reads somewhere beyond it on the
    /// same side. NaN over no data. The shadow bench's penumbra criterion
    /// (|elevation − horizon| ≤ 3°) is decided by it exactly.
    pub fn band_horizon(&self, x: usize, y: usize, sun: &Sun, band_deg: f64) -> (f64, f64) {
        let h0 = self.ctx.at(x as i64, y as i64);
        if h0.is_nan() {
            return (f64::NAN, f64::NAN);
        }
        let at = self.sun_at(x, y, sun);
        let floor =
            crate::fourier::stage::floor_deg(self.ctx.radius_m, self.terrain_min_m, h0 as f64);
        let el = at.elevation_deg;
        let ray = ray_toward(self.ctx, x, y, at.phi);
        let mut work = Work::default();
        let a = self.exact(
            &ray,
            x,
            y,
            &at,
            tan_deg(el - band_deg),
            tan_deg(el + band_deg),
            &mut work,
        );
        (el, degrees(a, floor))
    }

    /// Distance (plane pixels) at which the ray leaves the raster.
    fn raster_exit(&self, ray: &Ray) -> f64 {
        let (w1, h1) = ((self.ctx.width - 1) as f64, (self.ctx.height - 1) as f64);
        let ex = if ray.cx > 1e-12 {
            (w1 - ray.x0) / ray.cx
        } else if ray.cx < -1e-12 {
            ray.x0 / -ray.cx
        } else {
            f64::INFINITY
        };
        let ey = if ray.cy > 1e-12 {
            (h1 - ray.y0) / ray.cy
        } else if ray.cy < -1e-12 {
            ray.y0 / -ray.cy
        } else {
            f64::INFINITY
        };
        ex.min(ey).max(0.0)
    }

    /// Distance (plane pixels) beyond which no terrain of the raster can reach slope `t`: where
    /// the line at elevation atan(t) from the observer climbs above the highest terrain
    /// (r(ψ) = r0·cos e / cos(ψ + e)), capped at the raster's edge.
    fn exit(&self, ray: &Ray, t: f64) -> f64 {
        let edge = self.raster_exit(ray);
        let e = t.atan();
        let rmax = self.ctx.radius_m + self.hmax;
        let c = ray.r0 * e.cos() / rmax;
        if c.is_nan() || c >= 1.0 {
            return edge;
        }
        let psi = c.acos() - e;
        if psi.is_nan() || psi <= 0.0 {
            return 0.0;
        }
        if psi >= std::f64::consts::FRAC_PI_2 {
            return edge;
        }
        let tp = psi.tan();
        let den = ray.b1 - ray.a1 * tp;
        if den <= 0.0 {
            return edge;
        }
        (ray.a0 * tp / den).min(edge)
    }

    /// The largest slope terrain no higher than `h` can have over s ∈ [sa, sb] (sa > 0): the
    /// slope of height h falls with distance when h is above the observer; below it, it rises
    /// up to the tangent point ψ* = acos(r_h / r0) and falls after.
    #[inline]
    fn max_slope(&self, ray: &Ray, sa: f64, sb: f64, h: f64) -> f64 {
        if h == f64::NEG_INFINITY {
            return f64::NEG_INFINITY;
        }
        let rh = self.ctx.radius_m + h;
        if rh >= ray.r0 {
            return ray.slope_of(self.ctx, sa, h);
        }
        let tp = (1.0 - (rh / ray.r0).powi(2)).max(0.0).sqrt() / (rh / ray.r0);
        let den = ray.b1 - ray.a1 * tp;
        let s_star = if den > 0.0 {
            ray.a0 * tp / den
        } else {
            f64::INFINITY
        };
        ray.slope_of(self.ctx, s_star.clamp(sa, sb), h)
    }

    /// The exact horizon slope near the observer: its own directional derivative and the
    /// cells out to [`NEAR_PX`].
    fn near(&self, ray: &Ray, x: usize, y: usize, at: &SunAt, work: &mut Work) -> f64 {
        let (sn, cs) = at.phi.sin_cos();
        let s0 = self.ctx.slope0_g(x, y, cs, sn, ray.ground_per_px());
        let best = if s0.is_nan() { f64::NEG_INFINITY } else { s0 };
        work.visits += 3;
        ray.max_over(self.ctx, 0.0, NEAR_PX, best).0
    }

    /// The exact horizon slope along `ray`, searched until it reaches `hi` or nothing farther
    /// can rise above max(best, `lo`).
    #[allow(clippy::too_many_arguments)]
    fn exact(
        &self,
        ray: &Ray,
        x: usize,
        y: usize,
        at: &SunAt,
        lo: f64,
        hi: f64,
        work: &mut Work,
    ) -> f64 {
        let mut best = self.near(ray, x, y, at, work);
        let end = self.exit(ray, lo);
        let mut s = NEAR_PX;
        const CHUNK: f64 = 8.0;
        while s < end && best < hi {
            let to = (s + CHUNK).min(end);
            best = ray.max_over(self.ctx, s, to, best).0;
            work.visits += CHUNK as u64;
            s = to;
            if ray.slope_of(self.ctx, s, self.hmax) <= best.max(lo) {
                break;
            }
        }
        best
    }

    /// The exact lit fraction and the exact horizon (degrees, clamped to the disc's span) in
    /// the sun's azimuth.
    fn reference(
        &self,
        x: usize,
        y: usize,
        sun: &Sun,
        at: &SunAt,
        floor: f64,
        work: &mut Work,
    ) -> (f64, f64) {
        let (el, r) = (at.elevation_deg, at.radius_deg);
        let lo = tan_deg(el - r);
        let hi = tan_deg(el + r);
        let fl = floor as f32;
        let horizon_at = |phi: f64, work: &mut Work| -> f64 {
            let ray = ray_toward(self.ctx, x, y, phi);
            let a = self.exact(&ray, x, y, at, lo, hi, work);
            (a.atan().to_degrees() as f32).max(fl) as f64
        };
        let span = disc_span(at, sun);
        if span == 0.0 {
            let a = horizon_at(at.phi, work);
            return (sun::lit_fraction(&at.frame, sun, Model::Exact, &|_| a), a);
        }
        // Near the zenith the disc spans every azimuth.
        let q = if span >= 1.0 { 64 } else { REFERENCE_AZIMUTHS };
        let samples: Vec<f64> = (0..q)
            .map(|k| {
                let f = -1.0 + 2.0 * k as f64 / (q - 1) as f64;
                horizon_at(at.phi + f * span, work)
            })
            .collect();
        // The disc's points lie within its radius of the centre's elevation, and the
        // interpolated horizon within its samples' range: the plain answers need no model.
        let (smin, smax) = samples
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        if smax < el - r {
            return (1.0, samples[q / 2]);
        }
        if smin > el + r {
            return (0.0, samples[q / 2]);
        }
        let phi0 = at.phi;
        let hor = |phi: f64| -> f64 {
            let mut d = (phi - phi0) % std::f64::consts::TAU;
            if d > std::f64::consts::PI {
                d -= std::f64::consts::TAU;
            } else if d < -std::f64::consts::PI {
                d += std::f64::consts::TAU;
            }
            let f = ((d / span + 1.0) / 2.0 * (q - 1) as f64).clamp(0.0, (q - 1) as f64);
            let k = (f as usize).min(q - 2);
            let w = f - k as f64;
            samples[k] * (1.0 - w) + samples[k + 1] * w
        };
        (
            sun::lit_fraction(&at.frame, sun, Model::Exact, &hor),
            samples[q / 2],
        )
    }

    /// Uniform stepping: `steps` bilinear samples at equal spacing out to where the disc's
    /// bottom ray leaves the terrain volume.
    fn uniform(&self, ray: &Ray, steps: usize, lo: f64, work: &mut Work) -> f64 {
        let end = self.exit(ray, lo);
        let mut best = f64::NEG_INFINITY;
        if end <= 0.0 || steps == 0 {
            return best;
        }
        let ds = end / steps as f64;
        for k in 1..=steps {
            best = best.max(ray.slope_at(self.ctx, k as f64 * ds));
        }
        work.visits += steps as u64;
        best
    }

    /// Calls `f(tx, ty, s_in, s_out)` for every texel of level `m` the ray crosses for
    /// s ∈ [sa, sb], in order; stops when `f` returns true (and returns true then).
    #[inline]
    fn walk(
        &self,
        ray: &Ray,
        m: usize,
        sa: f64,
        sb: f64,
        f: &mut dyn FnMut(i64, i64, f64, f64) -> bool,
    ) -> bool {
        let q = (1u64 << m) as f64;
        let (x, y) = (ray.x0 + sa * ray.cx, ray.y0 + sa * ray.cy);
        if !(x >= 0.0 && y >= 0.0) {
            return false;
        }
        let mut ax = Axis::new(x / q, ray.cx / q, sa);
        let mut ay = Axis::new(y / q, ray.cy / q, sa);
        let l = &self.pyramid.levels[m];
        // A ray along the raster's last row or column lies on its last texels' far edge.
        if ray.cx == 0.0 && ax.i == l.w as i64 {
            ax.i -= 1;
        }
        if ray.cy == 0.0 && ay.i == l.h as i64 {
            ay.i -= 1;
        }
        let mut s = sa;
        while s < sb {
            if ax.i < 0 || ay.i < 0 || ax.i >= l.w as i64 || ay.i >= l.h as i64 {
                return false;
            }
            let next = ax.next.min(ay.next).min(sb);
            if next > s && f(ax.i, ay.i, s, next) {
                return true;
            }
            s = next;
            ax.advance(s);
            ay.advance(s);
        }
        false
    }

    /// Jung et al.'s DP: the horizon slope as found by runs of coarse-to-fine texel choices.
    #[allow(clippy::too_many_arguments)]
    fn dp(
        &self,
        ray: &Ray,
        x: usize,
        y: usize,
        at: &SunAt,
        runs: &Runs,
        dda: bool,
        refine: bool,
        lo: f64,
        hi: f64,
        work: &mut Work,
    ) -> f64 {
        let mut best = self.near(ray, x, y, at, work);
        let end = self.exit(ray, lo);
        // The refined runs' texels waiting (one stack for the pixel's runs, made when needed).
        let mut stack = None;
        // Plane pixels of ray per texel of the major axis.
        let major = ray.cx.abs().max(ray.cy.abs());
        let top = self.pyramid.len() - 1;
        let mut a = NEAR_PX;
        let mut k = 0;
        loop {
            if a >= end || best >= hi {
                break;
            }
            let levels = match runs {
                Runs::Fixed(v) => match v.get(k) {
                    Some(&n) => n,
                    None => break,
                },
                Runs::Auto => {
                    let covered = (a * major).max(1.0);
                    (covered.log2().floor() as usize + 1).max(5)
                }
            };
            k += 1;
            let m0 = (levels - 1).min(top);
            let len = (1u64 << m0) as f64 / major;
            let b = a + len;
            let run = if refine {
                // Lazily: an eager `get_or_insert` would build the 1.3 KB array on every run.
                #[allow(clippy::unnecessary_lazy_evaluations)]
                let stack =
                    stack.get_or_insert_with(|| [(0usize, 0.0f64, 0.0f64, 0.0f64); DP_STACK]);
                self.dp_run(ray, a, b.min(end), m0, dda, best.max(lo), hi, stack, work)
            } else {
                self.dp_run_plain(ray, a, b.min(end), m0, dda, best.max(lo), work)
            };
            best = best.max(run);
            a = b;
            if k > 4096 {
                break;
            }
        }
        best
    }

    /// The canonical DDA's texels of level `m` over s ∈ [sa, sb]: those under two points of the
    /// interval only, each handed to `f` as (bound, s_in, s_out) with the part of the ray
    /// inside it (not half of the interval, which may leave out the part of the texel where
    /// its terrain is), which the next level searches.
    fn dda_texels(
        &self,
        ray: &Ray,
        m: usize,
        sa: f64,
        sb: f64,
        work: &mut Work,
        mut f: impl FnMut((f64, f64, f64)),
    ) {
        let q = (1u64 << m) as f64;
        let mid = 0.5 * (sa + sb);
        for p in [0.5 * (sa + mid), 0.5 * (mid + sb)] {
            let (px, py) = (ray.x0 + p * ray.cx, ray.y0 + p * ray.cy);
            if !(px >= 0.0 && py >= 0.0) {
                continue;
            }
            // A point on the raster's far edge is in its last texel.
            let l = &self.pyramid.levels[m];
            let (tx, ty) = ((px / q) as i64, (py / q) as i64);
            let (tx, ty) = (tx.min(l.w as i64 - 1), ty.min(l.h as i64 - 1));
            let (hmax, _) = self.pyramid.get(m, tx, ty);
            work.visits += 1;
            let (s_in, s_out) = texel_span(ray, q, tx, ty, sa, sb, p);
            f((self.max_slope(ray, s_in, s_out, hmax as f64), s_in, s_out));
        }
    }

    /// One run of Algorithm 1 over s ∈ [a, b] starting at level `m0` as Jung et al. publish
    /// it (`dp-jung`): returns the exact horizon slope over the finest cell chosen (or −∞ when
    /// no texel could beat `floor`).
    #[allow(clippy::too_many_arguments)]
    fn dp_run_plain(
        &self,
        ray: &Ray,
        a: f64,
        b: f64,
        m0: usize,
        dda: bool,
        floor: f64,
        work: &mut Work,
    ) -> f64 {
        let (mut sa, mut sb) = (a, b);
        for m in (0..=m0).rev() {
            // The candidate with the largest bound.
            let mut cand = (floor, f64::NAN, f64::NAN);
            if dda {
                self.dda_texels(ray, m, sa, sb, work, |c| {
                    if c.0 > cand.0 {
                        cand = c;
                    }
                });
            } else {
                self.walk(ray, m, sa, sb, &mut |tx, ty, s_in, s_out| {
                    let (hmax, _) = self.pyramid.get(m, tx, ty);
                    work.visits += 1;
                    let bound = self.max_slope(ray, s_in, s_out, hmax as f64);
                    if bound > cand.0 {
                        cand = (bound, s_in, s_out);
                    }
                    false
                });
            }
            if cand.1.is_nan() {
                // Nothing under this part of the ray can rise above what is already known.
                return f64::NEG_INFINITY;
            }
            (sa, sb) = (cand.1, cand.2);
        }
        work.visits += 1;
        ray.max_over(self.ctx, sa, sb, f64::NEG_INFINITY).0
    }

    /// One run of Algorithm 1 over s ∈ [a, b] starting at level `m0`, refined (`dp`): the
    /// texels the descent passed over are not dropped: every candidate of
    /// every level whose bound beats `floor` is kept on a stack (at most [`DP_STACK`]; a fuller
    /// stack drops the weakest, as the plain DP would), and once the descent has reached its
    /// exact answer, those whose bound still beats the best found are descended into in turn
    /// (the best bound of a level first), until none is left or the best reaches `hi` (the
    /// disc's top: the sun is hidden whatever else lies on the ray). Jung et al.'s choice by
    /// cost stays the order of the search, and only where it was wrong — a texel beside the
    /// ray holding the higher maximum, the crater rims of the penumbra — does it cost more.
    #[allow(clippy::too_many_arguments)]
    fn dp_run(
        &self,
        ray: &Ray,
        a: f64,
        b: f64,
        m0: usize,
        dda: bool,
        floor: f64,
        hi: f64,
        stack: &mut [(usize, f64, f64, f64); DP_STACK],
        work: &mut Work,
    ) -> f64 {
        // Pending texels: (level, s_in, s_out, bound); the root is the run's whole stretch at
        // level m0 + 1 (walked at m0).
        stack[0] = (m0 + 1, a, b, f64::INFINITY);
        let mut depth = 1;
        let mut best = f64::NEG_INFINITY;
        while depth > 0 {
            depth -= 1;
            let (m1, sa0, sb0, bound0) = stack[depth];
            if bound0 <= best.max(floor) {
                continue;
            }
            if m1 == 0 {
                // A cell passed over at the finest level: searched exactly.
                work.visits += 1;
                best = best.max(ray.max_over(self.ctx, sa0, sb0, f64::NEG_INFINITY).0);
                if best >= hi {
                    break;
                }
                continue;
            }
            let (mut sa, mut sb) = (sa0, sb0);
            for m in (0..m1).rev() {
                // The candidates of this level, the one with the largest bound first.
                let mut cands = [(f64::NEG_INFINITY, 0.0f64, 0.0f64); 4];
                let mut nc = 0;
                let mut hidden = f64::NEG_INFINITY;
                let thr = best.max(floor);
                // Sorted on insertion, the largest bound first, the first along the ray among
                // equals; a fifth candidate drops the weakest.
                let mut keep = |c: (f64, f64, f64)| {
                    if c.0 <= thr || (nc == cands.len() && c.0 <= cands[nc - 1].0) {
                        return;
                    }
                    let mut k = nc.min(cands.len() - 1);
                    while k > 0 && cands[k - 1].0 < c.0 {
                        cands[k] = cands[k - 1];
                        k -= 1;
                    }
                    cands[k] = c;
                    nc = (nc + 1).min(cands.len());
                };
                if dda {
                    self.dda_texels(ray, m, sa, sb, work, &mut keep);
                } else {
                    self.walk(ray, m, sa, sb, &mut |tx, ty, s_in, s_out| {
                        let (hmax, hmin) = self.pyramid.get(m, tx, ty);
                        work.visits += 1;
                        let bound = self.max_slope(ray, s_in, s_out, hmax as f64);
                        // A texel whose lowest terrain already hides the disc's top
                        // ends the search with that terrain's slope (a horizon the terrain
                        // surely reaches: the sun is hidden, as extrema-soft stops).
                        if bound >= hi && hmin > f32::NEG_INFINITY {
                            let low = self.max_slope(ray, s_in, s_out, hmin as f64);
                            if low >= hi {
                                hidden = low;
                                return true;
                            }
                        }
                        keep((bound, s_in, s_out));
                        false
                    });
                }
                if hidden > f64::NEG_INFINITY {
                    return best.max(hidden);
                }
                if nc == 0 {
                    // Nothing under this part of the ray can rise above what is known.
                    break;
                }
                // The runners-up wait on the stack, the weakest deepest; a full stack drops the
                // weakest.
                for c in cands[1..nc].iter().rev() {
                    if depth < DP_STACK {
                        stack[depth] = (m, c.1, c.2, c.0);
                        depth += 1;
                    }
                }
                (sa, sb) = (cands[0].1, cands[0].2);
                if m == 0 {
                    work.visits += 1;
                    best = best.max(ray.max_over(self.ctx, sa, sb, f64::NEG_INFINITY).0);
                }
            }
            if best >= hi {
                break;
            }
        }
        best
    }

    /// Timokhin & Mikhaylyuk's traversal: whether the terrain reaches slope `t` anywhere along
    /// the ray (the sun's centre hidden).
    fn extrema(&self, ray: &Ray, x: usize, y: usize, at: &SunAt, t: f64, work: &mut Work) -> bool {
        if self.near(ray, x, y, at, work) >= t {
            return true;
        }
        let end = self.exit(ray, t);
        if end <= NEAR_PX {
            return false;
        }
        let top = (self.pyramid.len() - 1).min(7);
        self.walk(ray, top, NEAR_PX, end, &mut |tx, ty, sa, sb| {
            self.extrema_node(ray, top, tx, ty, sa, sb, t, work)
        })
    }

    /// The exact horizon slope in the ray's azimuth where it matters: clamped below at `lo`
    /// (anything lower leaves the disc whole) and found only up to `hi` (anything higher hides
    /// it), by the min/max traversal.
    #[allow(clippy::too_many_arguments)]
    fn extrema_soft(
        &self,
        ray: &Ray,
        x: usize,
        y: usize,
        at: &SunAt,
        lo: f64,
        hi: f64,
        work: &mut Work,
    ) -> f64 {
        let mut best = self.near(ray, x, y, at, work);
        if best >= hi {
            return best;
        }
        let end = self.exit(ray, lo);
        if end <= NEAR_PX {
            return best;
        }
        let top = (self.pyramid.len() - 1).min(7);
        self.walk(ray, top, NEAR_PX, end, &mut |tx, ty, sa, sb| {
            self.soft_node(ray, top, tx, ty, sa, sb, lo, hi, &mut best, work)
        });
        best
    }

    /// One texel of [`Tracer::extrema_soft`]; true when the disc is wholly hidden.
    #[allow(clippy::too_many_arguments)]
    fn soft_node(
        &self,
        ray: &Ray,
        m: usize,
        tx: i64,
        ty: i64,
        sa: f64,
        sb: f64,
        lo: f64,
        hi: f64,
        best: &mut f64,
        work: &mut Work,
    ) -> bool {
        let (hmax, hmin) = self.pyramid.get(m, tx, ty);
        work.visits += 1;
        if self.max_slope(ray, sa, sb, hmax as f64) <= best.max(lo) {
            return false;
        }
        if hmin > f32::NEG_INFINITY && self.max_slope(ray, sa, sb, hmin as f64) >= hi {
            *best = best.max(hi);
            return true;
        }
        if m == 0 {
            *best = ray.max_over(self.ctx, sa, sb, *best).0;
            return *best >= hi;
        }
        self.walk(ray, m - 1, sa, sb, &mut |cx, cy, s_in, s_out| {
            self.soft_node(ray, m - 1, cx, cy, s_in, s_out, lo, hi, best, work)
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn extrema_node(
        &self,
        ray: &Ray,
        m: usize,
        tx: i64,
        ty: i64,
        sa: f64,
        sb: f64,
        t: f64,
        work: &mut Work,
    ) -> bool {
        let (hmax, hmin) = self.pyramid.get(m, tx, ty);
        work.visits += 1;
        if self.max_slope(ray, sa, sb, hmax as f64) < t {
            return false;
        }
        if hmin > f32::NEG_INFINITY && self.max_slope(ray, sa, sb, hmin as f64) >= t {
            return true;
        }
        if m == 0 {
            return ray.max_over(self.ctx, sa, sb, f64::NEG_INFINITY).0 >= t;
        }
        self.walk(ray, m - 1, sa, sb, &mut |cx, cy, s_in, s_out| {
            self.extrema_node(ray, m - 1, cx, cy, s_in, s_out, t, work)
        })
    }
}

/// [`Ray::toward`], with a direction component below the cell walk's threshold (1e-12, under
/// which [`Axis`] does not step) made exactly 0: along a row or column it is cos or sin of a
/// multiple of π/2, ±1e-16, and on the raster's first row or column a negative one puts every
/// point of the ray a rounding error outside the raster, where the searches see nothing.
pub(crate) fn ray_toward(ctx: &Context, x: usize, y: usize, phi: f64) -> Ray {
    let mut ray = Ray::toward(ctx, x, y, phi);
    for c in [&mut ray.cx, &mut ray.cy] {
        if c.abs() <= 1e-12 {
            *c = 0.0;
        }
    }
    ray
}

/// The part of [sa, sb] where the ray lies inside texel (tx, ty) of side `q` cells, which holds
/// the ray's point at `p` (kept inside against rounding).
fn texel_span(ray: &Ray, q: f64, tx: i64, ty: i64, sa: f64, sb: f64, p: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (sa, sb);
    for (o, d, t) in [(ray.x0, ray.cx, tx), (ray.y0, ray.cy, ty)] {
        if d.abs() > 1e-12 {
            let (a, b) = ((t as f64 * q - o) / d, ((t + 1) as f64 * q - o) / d);
            lo = lo.max(a.min(b));
            hi = hi.min(a.max(b));
        }
    }
    (lo.min(p), hi.max(p))
}

/// Half-width (degrees) of the penumbra band: a (pixel, sun) pair is penumbral when the sun's
/// centre is within it of the exact horizon in its azimuth ([`Tracer::band_horizon`]), where
/// shadows are decided and all-pixel error means hide a method's misses (issue 40).
pub const PENUMBRA_BAND_DEG: f64 = 3.0;

/// What a method found at one pixel.
#[derive(Clone, Copy, Debug)]
pub struct Traced {
    /// Lit fraction of the disc in [0, 1] (NaN: no data).
    pub lit: f64,
    /// The horizon's elevation in the sun's azimuth (degrees, floored; the searches stop at the
    /// disc's top, so a higher horizon reads lower; NaN for `extrema`, which only decides).
    pub horizon_deg: f64,
}

fn degrees(a: f64, floor: f64) -> f64 {
    if a.is_nan() || a == f64::NEG_INFINITY {
        floor
    } else {
        a.atan().to_degrees().max(floor)
    }
}

#[inline]
fn tan_deg(d: f64) -> f64 {
    if d >= 90.0 {
        f64::INFINITY
    } else if d <= -90.0 {
        f64::NEG_INFINITY
    } else {
        d.to_radians().tan()
    }
}

/// Jung et al.'s disc occlusion (Eq. 6–7, the prism assumption): a horizon at slope `a`
/// (floored at `floor` degrees) hides the circular segment of the disc below it.
fn occlusion(a: f64, floor: f64, el: f64, r: f64) -> f64 {
    let alpha = degrees(a, floor);
    if r <= 0.0 {
        return if el > alpha {
            1.0
        } else if el < alpha {
            0.0
        } else {
            0.5
        };
    }
    sun::segment_fraction((alpha - el) / r)
}

/// Half the range of plane azimuths the sun's disc spans at a point (radians, 0 for a point
/// sun, π when the disc holds the zenith): the largest offset of 32 rim points from the
/// centre's plane azimuth, plus 2 %.
fn disc_span(at: &SunAt, sun: &Sun) -> f64 {
    use crate::cube::dot;
    let r = at.radius_deg.to_radians();
    if r <= 0.0 {
        return 0.0;
    }
    if at.elevation_deg + at.radius_deg >= 89.9 {
        return std::f64::consts::PI;
    }
    let n = |p: [f64; 3]| {
        let l = dot(p, p).sqrt();
        [p[0] / l, p[1] / l, p[2] / l]
    };
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let s = n(sun.dir);
    let up = at.frame.up;
    let eh = n(cross(s, up));
    let ev = n(cross(eh, s));
    let t = r.tan();
    let mut d: f64 = 0.0;
    for k in 0..32 {
        let th = std::f64::consts::TAU * k as f64 / 32.0;
        let (sn, cs) = th.sin_cos();
        let p = [
            s[0] + t * (cs * eh[0] + sn * ev[0]),
            s[1] + t * (cs * eh[1] + sn * ev[1]),
            s[2] + t * (cs * eh[2] + sn * ev[2]),
        ];
        let mut off = (at.frame.plane_azimuth(p) - at.phi) % std::f64::consts::TAU;
        if off > std::f64::consts::PI {
            off -= std::f64::consts::TAU;
        } else if off < -std::f64::consts::PI {
            off += std::f64::consts::TAU;
        }
        d = d.max(off.abs());
    }
    (d * 1.02).min(std::f64::consts::PI)
}
