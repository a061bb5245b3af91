//! Sakalauskas' SMap (silhouette map; "Hybrid Terrain Shadow Ray Casting",
//! `../shared/papers/`) for one sun over one [`Context`] raster: hard shadows (1 lit, 0 the sun's
//! centre hidden, as the tracer's `extrema` method answers) from terrain prepared once per
//! light direction, after which a pixel's test reads one black sample and searches a few
//! pixels next to it.
//!
//! # Geometry (exact on the sphere)
//! The sun is a direction S at infinity. The shadow ray Q + t·S of a surface point Q lies in the
//! great-circle plane of Q and S, so on the face's gnomonic plane every shadow ray runs along a
//! line through the sun's vanishing point v_S = (S·U/S·N, S·V/S·N): the *beams*. In raster
//! coordinates that point is the homogeneous (X, Y, W) with W = S·N, and the direction towards
//! the sun at raster point p is (X − x·W, Y − y·W) whatever the sign of W: towards v_S (the
//! sub-solar point) when S·N > 0, away from it (it is then the anti-solar point, the
//! projection of −S) when S·N < 0, and the constant plane direction of S when S·N = 0
//! (parallel beams). A beam is the half-line from that point through the pixel (the half great
//! circle from S to −S), along which the angle β from S grows monotonically away from the sun.
//!
//! In one such plane, with r = R + h, the ray from Q keeps w = r·sin β: it is at radius
//! w_Q/sin β′ at every angle β′ in (0, β_Q), each once. So Q is shadowed iff some terrain
//! sunward of it on its beam has g = (R + h)·sin β ≥ g_Q. That holds past β_Q = 90° too (the
//! sun below Q's horizontal): the ray then first passes the angles between β_Q and 90°, and
//! at 90° the sphere of the body's lowest terrain (g = R + terrain_min) hides the sun unless
//! (R + h_Q)·cos e > R + terrain_min, which is exactly the tracer's floor
//! e > −acos((R + terrain_min)/(R + h_Q)); the floor stands for that sphere beyond the raster.
//! g is a point's distance from the line through the body's centre along S, so it also
//! compares between neighbouring beams. One sun's shadows are thus a prefix-maximum problem
//! along every beam, ordered from the sun's end outwards.
//!
//! # The map ([`SMap::build`])
//! - **Beams**: lines of the pencil through the vanishing point, at most [`BEAM_PX`] apart
//!   wherever a pixel of the region or terrain sunward of it lies (the pencil converges towards
//!   the sun when S·N > 0, so the region's far side sets the spacing; it diverges when S·N < 0,
//!   so the whole raster does). When the vanishing point is within two raster radii of the
//!   region's centre the beams are spaced by angle around it (a *fan*: all round when it lies
//!   in the region); otherwise by where they cross the line through the region's centre across
//!   the sun's direction (a *sheaf*, which becomes parallel lines as S·N → 0 with no special
//!   case).
//! - **Samples**: every beam has a sample every [`STEP_PX`] from where it enters the raster on
//!   the sun's side to where it leaves the region (grown by a pixel) on the other; nothing
//!   beyond is ever asked for. A sample's g is the largest over the beam since the previous
//!   sample, found exactly on the bilinear surface (its values at the grid-line crossings and
//!   inside cells, as the tracer's cell walk finds them), so no crest between samples is
//!   missed. No-data terrain blocks nothing (g = −∞).
//! - **Black marks**: the samples whose g exceeds that of every sample nearer the sun on their
//!   beam: the beam's silhouette seen from the sun (Sakalauskas' Eq. 1 marks the local
//!   silhouettes, the samples standing above both neighbours along the light; for a light at
//!   infinity over a sphere only the prefix-maximum records among them can ever block). Only
//!   the blacks' g is kept (f64).
//! - **Links**: for every sample, the nearest black at or before it towards the sun
//!   (Sakalauskas' NextV). They are made in the same single pass along the beam that marks the
//!   blacks: O(n) and the same links as his log₂ N pointer-doubling passes (which suit a GPU's
//!   data-parallel passes; a test checks the two agree).
//!
//! # The test ([`SMap::lit`])
//! The pixel's own height gives g_Q, its sun elevation and the floor exactly as
//! [`super::trace`] takes them (a sun at or below `floor_deg(R, terrain_min, h0)` is dark).
//! Far field: the pixel's *nearest* beam; the link of the last sample at least [`EXACT_PX`]
//! sunward of the pixel's projection onto it names the black to compare with. The blacks are
//! prefix maxima, so their g grows away from the sun and the first black reached is the
//! highest of all those sunward: Sakalauskas' walk along the links ends at its first step
//! (shadowed if g_black ≥ g_Q; otherwise no black farther on is higher). Near field (out to
//! that sample, [`EXACT_PX`] to [`EXACT_PX`] + [`STEP_PX`]): searched exactly along the pixel's
//! own ray as the tracer's methods search theirs (the directional derivative at the pixel and
//! the bilinear surface cell by cell), because there a beam up to half a pixel beside the ray
//! sees other terrain at a very different angle. Past the tracer's own 1.5-pixel near field
//! the search only visits the pieces of the ray where the highest terrain around (per block
//! of 4×4 pixels) could reach the sun.
//!
//! The answer is the exact ray search's up to the beam spacing: beyond [`EXACT_PX`] a pixel's
//! beam runs within half a pixel of its true ray (closer towards the sun when the beams
//! converge). Against the `extrema` tracer on rough synthetic terrain (hills with pixel-scale
//! noise, a crater, a cliff, no-data holes; suns 1° to 45° high, every kind of pencil) that
//! decides differently for 0.06 % of the pixels, 0.51 % in the worst of 400 cases, in both
//! directions (the tests).

use rayon::prelude::*;

use super::trace::{ray_toward, NEAR_PX};
use crate::cube::{dot, Vec3};
use crate::horizon::{Axis, Context, Rect};

/// Largest distance (raster pixels) between neighbouring beams where they are used.
pub const BEAM_PX: f64 = 1.0;
/// Distance (raster pixels) between the samples along a beam.
pub const STEP_PX: f64 = 1.0;
/// The near field (raster pixels) searched exactly along a pixel's own ray: nearer than this,
/// a beam up to half a pixel beside the ray sees other terrain at a very different angle (at
/// 4 pixels the tests' disagreement with the exact search grows by a third to a half).
pub const EXACT_PX: f64 = 8.0;
/// How far the near field overlaps the far field's first sample (the pixel's ray and its beam
/// differ in direction by milliradians at most, their distances by less).
const NEAR_OVERLAP_PX: f64 = 0.01;

/// Side (raster pixels) of the blocks whose highest terrain bounds the near field.
const BLOCK_PX: usize = 4;

/// Side (pixels) of the tiles in which [`SMap::lit_region`] answers.
pub const TILE_PX: usize = 32;

/// A link to no black: no terrain sunward of the sample on its beam.
const NONE: u32 = u32::MAX;

/// One beam: sample j lies at (x0, y0) + j·(dx, dy), sample 0 at the sun's end.
#[derive(Clone, Copy, Debug)]
struct Beam {
    x0: f64,
    y0: f64,
    /// Step per sample, away from the sun (length [`STEP_PX`]).
    dx: f64,
    dy: f64,
    n: u32,
    /// The beam's first sample in [`SMap::links`] and first black in [`SMap::blacks`].
    link0: usize,
    black0: usize,
}

/// How the beams are laid out.
#[derive(Clone, Copy, Debug)]
enum Pencil {
    /// Half-lines from (vx, vy) at angles `theta_ref + delta0 + k·dtheta`, k < n; `full`: all
    /// round (indices wrap); `outward`: the sun is at (vx, vy) (S·N > 0), so samples run away
    /// from it, otherwise towards it from the raster's far edge.
    Fan {
        vx: f64,
        vy: f64,
        theta_ref: f64,
        delta0: f64,
        dtheta: f64,
        n: usize,
        full: bool,
        outward: bool,
    },
    /// Lines crossing the line (cx, cy) + c·f at c = c0 + k·dc, k < n, with f = (−ey, ex)
    /// across the sun's unit direction e at (cx, cy); beam c runs along e − c·κ·f, with
    /// κ = W/|d(C)| (0: parallel beams).
    Sheaf {
        cx: f64,
        cy: f64,
        ex: f64,
        ey: f64,
        kappa: f64,
        c0: f64,
        dc: f64,
        n: usize,
    },
}

/// Sakalauskas' SMap of one context raster for one sun.
pub struct SMap {
    /// Unit sun direction, body frame.
    sun: Vec3,
    radius_m: f64,
    /// Lowest terrain for the floor: the caller's, or the raster's own when lower.
    terrain_min_m: f64,
    region: Rect,
    pencil: Pencil,
    beams: Vec<Beam>,
    /// Per sample: the beam-local index of the nearest black at or before it ([`NONE`]).
    links: Vec<u32>,
    /// g (m) of every black sample, beam after beam, increasing along each beam.
    blacks: Vec<f64>,
    /// Samples that are strict local maxima of g along their beam (Sakalauskas' Eq. 1
    /// silhouettes), for comparison with the black share.
    silhouettes: u64,
    /// Highest terrain of every [`BLOCK_PX`]² block of raster pixels (−∞: none), row-major,
    /// `block_w` blocks a row: a bound that spares most pixels the exact near-field search.
    block_max: Vec<f32>,
    block_w: usize,
}

/// `a` (an angle in (−3π, 3π), such as a difference of two atan2s) wrapped into (−π, π].
#[inline]
fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    if a > std::f64::consts::PI {
        a - t
    } else if a <= -std::f64::consts::PI {
        a + t
    } else {
        a
    }
}

/// ⌊x⌋ of a finite `x` within i64's range (without a libm call on baseline x86-64).
#[inline]
fn floor_i(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i - 1
    } else {
        i
    }
}

/// Whether a sun at elevation e (given by sin e) is at or below the tracer's floor for a pixel
/// at height `h0`: e ≤ `floor_deg(R, terrain_min, h0)` = −acos k
/// ([`crate::fourier::stage::floor_deg`]), that is sin e ≤ −√(1 − k²), without the
/// trigonometry (e and the floor lie in [−90°, 90°], where sin is increasing).
#[inline]
fn below_floor(sin_e: f64, radius_m: f64, terrain_min_m: f64, h0: f64) -> bool {
    let k = ((radius_m + terrain_min_m) / (radius_m + h0.max(terrain_min_m))).clamp(-1.0, 1.0);
    sin_e <= -(1.0 - k * k).sqrt()
}

/// sin of the angle between plane point `p` (unnormalised) and unit `s`.
#[inline]
fn sin_beta(p: Vec3, s: Vec3) -> f64 {
    let c = [
        p[1] * s[2] - p[2] * s[1],
        p[2] * s[0] - p[0] * s[2],
        p[0] * s[1] - p[1] * s[0],
    ];
    (dot(c, c) / dot(p, p)).sqrt()
}

/// Distance (raster pixels) from pixel (x, y) along the unit direction (cx, cy) to the
/// raster's edge.
fn raster_edge(ctx: &Context, x: usize, y: usize, cx: f64, cy: f64) -> f64 {
    let to = |p: f64, d: f64, hi: f64| {
        if d > 0.0 {
            (hi - p) / d
        } else if d < 0.0 {
            -p / d
        } else {
            f64::INFINITY
        }
    };
    let (w1, h1) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
    to(x as f64, cx, w1).min(to(y as f64, cy, h1)).max(0.0)
}

/// The part [t0, t1] of the line p + t·d (t within [t0, t1]) inside the box
/// [xa, xb] × [ya, yb] (Liang–Barsky).
#[allow(clippy::too_many_arguments)]
fn clip(
    p: (f64, f64),
    d: (f64, f64),
    xa: f64,
    xb: f64,
    ya: f64,
    yb: f64,
    mut t0: f64,
    mut t1: f64,
) -> Option<(f64, f64)> {
    for (q, dq, lo, hi) in [(p.0, d.0, xa, xb), (p.1, d.1, ya, yb)] {
        if dq == 0.0 {
            if q < lo || q > hi {
                return None;
            }
        } else {
            let (a, b) = ((lo - q) / dq, (hi - q) / dq);
            let (a, b) = if a < b { (a, b) } else { (b, a) };
            t0 = t0.max(a);
            t1 = t1.min(b);
        }
    }
    (t0 <= t1).then_some((t0, t1))
}

/// Calls `emit`, for every sample j of beam `b` in order, with the largest g (m) over the
/// beam from sample j − 1 to sample j (sample 0: its own). Along a line the bilinear surface is
/// a quadratic inside each cell, so its values at the samples, at the grid-line crossings and
/// at the quadratic's vertex where it is concave are its maxima over the segment (g then
/// follows up to sin β's variation inside a cell, millimetres); a cell with a no-data corner
/// reads the general bilinear at its exit, as the tracer's cell walk does.
fn beam_g(ctx: &Context, sun: Vec3, b: &Beam, mut emit: impl FnMut(f64)) {
    let n = b.n as usize;
    if n == 0 {
        return;
    }
    let r = ctx.radius_m;
    let p0 = ctx.plane_point(b.x0, b.y0);
    let p1 = ctx.plane_point(b.x0 + b.dx, b.y0 + b.dy);
    let dp = [p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]];
    let g_at = |t: f64, h: f64| -> f64 {
        if h.is_nan() {
            return f64::NEG_INFINITY;
        }
        let p = [p0[0] + t * dp[0], p0[1] + t * dp[1], p0[2] + t * dp[2]];
        (r + h) * sin_beta(p, sun)
    };
    let h_at = |t: f64| ctx.bilinear64(b.x0 + t * b.dx, b.y0 + t * b.dy);
    emit(g_at(0.0, h_at(0.0)));
    // Sample 0 lies on the raster (to rounding).
    let mut ax = Axis::new(b.x0.max(0.0), b.dx, 0.0);
    let mut ay = Axis::new(b.y0.max(0.0), b.dy, 0.0);
    let (mut t, mut seg, mut j) = (0.0f64, f64::NEG_INFINITY, 1usize);
    // The current cell and its polynomial h(t) = c0 + c1·t + c2·t² (None: a no-data corner).
    let mut cell = (i64::MIN, i64::MIN);
    let mut poly = None;
    while j < n {
        let jt = j as f64;
        let next = ax.next.min(ay.next).min(jt);
        if next > t {
            let (ix, iy) = (ax.i, ay.i);
            if (ix, iy) != cell {
                cell = (ix, iy);
                let (h00, h10, h01, h11) = (
                    ctx.at(ix, iy) as f64,
                    ctx.at(ix + 1, iy) as f64,
                    ctx.at(ix, iy + 1) as f64,
                    ctx.at(ix + 1, iy + 1) as f64,
                );
                poly = if h00.is_nan() || h10.is_nan() || h01.is_nan() || h11.is_nan() {
                    None
                } else {
                    let (a, bb, c) = (h10 - h00, h01 - h00, h11 - h10 - h01 + h00);
                    let (ex, ey) = (b.x0 - ix as f64, b.y0 - iy as f64);
                    Some((
                        h00 + a * ex + bb * ey + c * ex * ey,
                        a * b.dx + bb * b.dy + c * (ex * b.dy + ey * b.dx),
                        c * b.dx * b.dy,
                    ))
                };
            }
            match poly {
                None => seg = seg.max(g_at(next, h_at(next))),
                Some((c0, c1, c2)) => {
                    seg = seg.max(g_at(next, c0 + next * (c1 + next * c2)));
                    if c2 < 0.0 {
                        let ts = -c1 / (2.0 * c2);
                        if ts > t && ts < next {
                            seg = seg.max(g_at(ts, c0 + ts * (c1 + ts * c2)));
                        }
                    }
                }
            }
        }
        t = next;
        if t >= jt {
            emit(seg);
            seg = f64::NEG_INFINITY;
            j += 1;
        }
        ax.advance(t);
        ay.advance(t);
    }
}

impl SMap {
    /// The SMap of `ctx` for a sun in direction `sun_dir` (body frame, any length), for the
    /// pixels of `region` (which must lie in the raster). `terrain_min_m`: the lowest terrain of
    /// the body as far as known, for the floor (the raster's own lowest when that is lower, as
    /// [`super::Tracer::new`] takes it).
    pub fn build(ctx: &Context, sun_dir: Vec3, region: Rect, terrain_min_m: f64) -> SMap {
        assert!(
            region.w > 0
                && region.h > 0
                && region.x0 + region.w <= ctx.width
                && region.y0 + region.h <= ctx.height,
            "region {region:?} outside the {}×{} raster",
            ctx.width,
            ctx.height
        );
        let l = dot(sun_dir, sun_dir).sqrt();
        assert!(l.is_finite() && l > 0.0, "sun direction {sun_dir:?}");
        let sun = [sun_dir[0] / l, sun_dir[1] / l, sun_dir[2] / l];
        let pencil = Self::pencil(ctx, sun, region);
        let nb = match pencil {
            Pencil::Fan { n, .. } | Pencil::Sheaf { n, .. } => n,
        };
        // Beam geometry, then the samples of every beam in parallel.
        let mut beams: Vec<Beam> = (0..nb)
            .map(|k| Self::beam(ctx, &pencil, region, k))
            .collect();
        let mut total = 0usize;
        for b in &mut beams {
            b.link0 = total;
            total += b.n as usize;
        }
        let mut links = vec![NONE; total];
        let mut slices: Vec<&mut [u32]> = Vec::with_capacity(nb);
        let mut rest = links.as_mut_slice();
        for b in &beams {
            let (head, tail) = rest.split_at_mut(b.n as usize);
            slices.push(head);
            rest = tail;
        }
        let per_beam: Vec<(Vec<f64>, u64)> = slices
            .into_par_iter()
            .zip(beams.par_iter())
            .map(|(lk, b)| {
                let mut blacks = Vec::new();
                let mut best = f64::NEG_INFINITY;
                let (mut g2, mut g1) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
                let mut sil = 0u64;
                let mut links = lk.iter_mut();
                let mut j = 0usize;
                beam_g(ctx, sun, b, |g| {
                    if g > best {
                        best = g;
                        blacks.push(g);
                    }
                    let link = links.next().expect("one link per sample");
                    if !blacks.is_empty() {
                        *link = (blacks.len() - 1) as u32;
                    }
                    if j >= 2 && g1 > g2 && g1 > g {
                        sil += 1;
                    }
                    (g2, g1) = (g1, g);
                    j += 1;
                });
                (blacks, sil)
            })
            .collect();
        let mut blacks = Vec::with_capacity(per_beam.iter().map(|p| p.0.len()).sum());
        let mut silhouettes = 0;
        for (b, (bl, sil)) in beams.iter_mut().zip(per_beam) {
            b.black0 = blacks.len();
            blacks.extend(bl);
            silhouettes += sil;
        }
        // The blocks' highest terrain, and the raster's lowest.
        let block_w = ctx.width.div_ceil(BLOCK_PX);
        let mut block_max = vec![f32::NEG_INFINITY; block_w * ctx.height.div_ceil(BLOCK_PX)];
        let tmin = block_max
            .par_chunks_mut(block_w)
            .enumerate()
            .map(|(by, row)| {
                let mut lo = f32::INFINITY;
                for y in by * BLOCK_PX..((by + 1) * BLOCK_PX).min(ctx.height) {
                    let line = &ctx.heights[y * ctx.width..(y + 1) * ctx.width];
                    for (x, &v) in line.iter().enumerate() {
                        // NaN (no data) compares false.
                        if v > row[x / BLOCK_PX] {
                            row[x / BLOCK_PX] = v;
                        }
                        if v < lo {
                            lo = v;
                        }
                    }
                }
                lo
            })
            .reduce(|| f32::INFINITY, f32::min) as f64;
        SMap {
            sun,
            radius_m: ctx.radius_m,
            terrain_min_m: terrain_min_m.min(tmin),
            region,
            pencil,
            beams,
            links,
            blacks,
            silhouettes,
            block_max,
            block_w,
        }
    }

    /// Highest terrain (m) of the raster pixels [xa, xb] × [ya, yb] and around, by blocks.
    fn highest(&self, xa: usize, xb: usize, ya: usize, yb: usize) -> f64 {
        let mut h = f32::NEG_INFINITY;
        for by in ya / BLOCK_PX..=yb / BLOCK_PX {
            let row = &self.block_max[by * self.block_w..(by + 1) * self.block_w];
            for &v in &row[xa / BLOCK_PX..=xb / BLOCK_PX] {
                h = h.max(v);
            }
        }
        h as f64
    }

    /// The beams' layout for `sun` over `region`.
    fn pencil(ctx: &Context, s: Vec3, region: Rect) -> Pencil {
        let (n, ua, va) = ctx.face.axes();
        let (sn, su, sv) = (dot(s, n), dot(s, ua), dot(s, va));
        let half = ctx.face_pixels / 2.0;
        let (ox, oy) = (ctx.origin.0 as f64 + 0.5, ctx.origin.1 as f64 + 0.5);
        // The vanishing point in homogeneous raster coordinates (x = (u + 1)·S/2 − ox,
        // y = (1 − v)·S/2 − oy with u = S·U/S·N, v = S·V/S·N).
        let (hx, hy, hw) = ((su + sn) * half - ox * sn, (sn - sv) * half - oy * sn, sn);
        let (xa, xb) = (region.x0 as f64, (region.x0 + region.w - 1) as f64);
        let (ya, yb) = (region.y0 as f64, (region.y0 + region.h - 1) as f64);
        let (cx, cy) = (0.5 * (xa + xb), 0.5 * (ya + yb));
        let reg_corners = [(xa, ya), (xb, ya), (xa, yb), (xb, yb)];
        let (w1, h1) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
        let ras_corners = [(0.0, 0.0), (w1, 0.0), (0.0, h1), (w1, h1)];
        let r_ras = ras_corners
            .iter()
            .map(|&(x, y)| (x - cx).hypot(y - cy))
            .fold(1.0f64, f64::max);
        let (dcx, dcy) = (hx - cx * hw, hy - cy * hw);
        let dlen = dcx.hypot(dcy);
        if hw != 0.0 && dlen < 2.0 * r_ras * hw.abs() {
            let (vx, vy) = (hx / hw, hy / hw);
            let outward = hw > 0.0;
            // Converging towards the sun (outward): the region's far side sets the spacing;
            // diverging: the whole raster.
            let corners = if outward { reg_corners } else { ras_corners };
            let rho_max = corners
                .iter()
                .map(|&(x, y)| (x - vx).hypot(y - vy))
                .fold(BEAM_PX, f64::max);
            let dtheta = BEAM_PX / rho_max;
            let tau = std::f64::consts::TAU;
            if vx >= xa - 1.0 && vx <= xb + 1.0 && vy >= ya - 1.0 && vy <= yb + 1.0 {
                let n = (tau / dtheta).ceil() as usize;
                return Pencil::Fan {
                    vx,
                    vy,
                    theta_ref: 0.0,
                    delta0: -std::f64::consts::PI,
                    dtheta: tau / n as f64,
                    n,
                    full: true,
                    outward,
                };
            }
            // Outside the (convex) region the corners span less than π around the direction
            // to its centre.
            let theta_ref = (cy - vy).atan2(cx - vx);
            let (lo, hi) =
                reg_corners
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(x, y)| {
                        let d = wrap_pi((y - vy).atan2(x - vx) - theta_ref);
                        (lo.min(d), hi.max(d))
                    });
            return Pencil::Fan {
                vx,
                vy,
                theta_ref,
                delta0: lo - dtheta,
                dtheta,
                n: ((hi - lo) / dtheta).ceil() as usize + 3,
                full: false,
                outward,
            };
        }
        let (ex, ey) = (dcx / dlen, dcy / dlen);
        let kappa = hw / dlen;
        let ab = |x: f64, y: f64| {
            let (px, py) = (x - cx, y - cy);
            (px * ex + py * ey, -px * ey + py * ex)
        };
        // The spacing at e-coordinate a is dc·(1 − κa): largest on the region's far side when
        // the beams converge towards the sun (κ > 0), on the raster's sunward side otherwise.
        let grow = if kappa > 0.0 {
            reg_corners
                .iter()
                .map(|&(x, y)| 1.0 - kappa * ab(x, y).0)
                .fold(1.0f64, f64::max)
        } else {
            ras_corners
                .iter()
                .map(|&(x, y)| 1.0 - kappa * ab(x, y).0)
                .fold(1.0f64, f64::max)
        };
        let dc = BEAM_PX / grow;
        let (lo, hi) =
            reg_corners
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(x, y)| {
                    let (a, b) = ab(x, y);
                    let c = b / (1.0 - kappa * a);
                    (lo.min(c), hi.max(c))
                });
        Pencil::Sheaf {
            cx,
            cy,
            ex,
            ey,
            kappa,
            c0: lo - dc,
            dc,
            n: ((hi - lo) / dc).ceil() as usize + 3,
        }
    }

    /// Beam k of `pencil`: from the sun's end inside the raster to where it leaves the region
    /// grown by a pixel.
    fn beam(ctx: &Context, pencil: &Pencil, region: Rect, k: usize) -> Beam {
        let (w1, h1) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
        let (rxa, rxb) = (region.x0 as f64 - 1.0, (region.x0 + region.w) as f64);
        let (rya, ryb) = (region.y0 as f64 - 1.0, (region.y0 + region.h) as f64);
        // The line p + t·d (|d| = 1) with the sun towards +t, over t ≥ t_min.
        let (p, d, t_min) = match *pencil {
            Pencil::Fan {
                vx,
                vy,
                theta_ref,
                delta0,
                dtheta,
                outward,
                ..
            } => {
                let th = theta_ref + delta0 + k as f64 * dtheta;
                let (s, c) = th.sin_cos();
                if outward {
                    // Sunward is towards the vanishing point: t = −ρ, ρ ≥ 0.
                    ((vx, vy), (-c, -s), f64::NEG_INFINITY)
                } else {
                    ((vx, vy), (c, s), 0.0)
                }
            }
            Pencil::Sheaf {
                cx,
                cy,
                ex,
                ey,
                kappa,
                c0,
                dc,
                ..
            } => {
                let c = c0 + k as f64 * dc;
                let (fx, fy) = (-ey, ex);
                let (dx, dy) = (ex - c * kappa * fx, ey - c * kappa * fy);
                let l = dx.hypot(dy);
                (
                    (cx + c * fx, cy + c * fy),
                    (dx / l, dy / l),
                    f64::NEG_INFINITY,
                )
            }
        };
        let t_max = match *pencil {
            Pencil::Fan { outward: true, .. } => 0.0,
            _ => f64::INFINITY,
        };
        let empty = Beam {
            x0: p.0,
            y0: p.1,
            dx: -d.0 * STEP_PX,
            dy: -d.1 * STEP_PX,
            n: 0,
            link0: 0,
            black0: 0,
        };
        let Some((ta, tb)) = clip(p, d, 0.0, w1, 0.0, h1, t_min, t_max) else {
            return empty;
        };
        let Some((ra, _)) = clip(p, d, rxa, rxb, rya, ryb, t_min, t_max) else {
            return empty;
        };
        // Sample 0 at the raster's sunward edge tb, down to the region's far side.
        let lo = ra.max(ta);
        if lo > tb {
            return empty;
        }
        let n = ((tb - lo) / STEP_PX).floor() as usize + 1;
        Beam {
            x0: p.0 + tb * d.0,
            y0: p.1 + tb * d.1,
            n: u32::try_from(n).expect("beam length"),
            ..empty
        }
    }

    /// The fractional beam index of raster point (x, y).
    fn beam_coord(&self, x: f64, y: f64) -> f64 {
        match self.pencil {
            Pencil::Fan {
                vx,
                vy,
                theta_ref,
                delta0,
                dtheta,
                ..
            } => (wrap_pi((y - vy).atan2(x - vx) - theta_ref) - delta0) / dtheta,
            Pencil::Sheaf {
                cx,
                cy,
                ex,
                ey,
                kappa,
                c0,
                dc,
                ..
            } => {
                let (px, py) = (x - cx, y - cy);
                let (a, b) = (px * ex + py * ey, -px * ey + py * ex);
                (b / (1.0 - kappa * a) - c0) / dc
            }
        }
    }

    /// Beam k (wrapped round a full fan, else clamped).
    fn beam_k(&self, k: i64) -> &Beam {
        let n = self.beams.len() as i64;
        let full = matches!(self.pencil, Pencil::Fan { full: true, .. });
        let k = if full {
            k.rem_euclid(n)
        } else {
            k.clamp(0, n - 1)
        };
        &self.beams[k as usize]
    }

    /// The beam nearest raster point (x, y).
    fn beam_of(&self, x: f64, y: f64) -> &Beam {
        self.beam_k(floor_i(self.beam_coord(x, y) + 0.5))
    }

    /// The highest g (m) of the terrain on raster pixel (x, y)'s nearest beam from the sun's
    /// end to the last sample at least [`EXACT_PX`] sunward of the pixel's projection onto it
    /// (−∞: none), and that sample's distance from the projection (raster pixels; ∞ when there
    /// is none, and the exact search must go all the way). `edge`: how far the pixel's own ray
    /// runs to the raster's edge (raster pixels), which the beam must cover.
    fn far(&self, x: usize, y: usize, edge: f64) -> (f64, f64) {
        let (xf, yf) = (x as f64, y as f64);
        let b = self.beam_of(xf, yf);
        let none = (f64::NEG_INFINITY, f64::INFINITY);
        if b.n == 0 {
            return none;
        }
        let j = ((xf - b.x0) * b.dx + (yf - b.y0) * b.dy) / (STEP_PX * STEP_PX);
        let last = floor_i(j - EXACT_PX / STEP_PX);
        // A beam grazing the raster's edge (a pixel on the first or last row or column, the
        // sun along it) can be cut short by its clipping at either end: then it does not stand
        // for the pixel's ray, which is searched exactly all the way.
        if last < 0 || j * STEP_PX < edge - 1.5 || last > b.n as i64 {
            return none;
        }
        let at = (j - last as f64) * STEP_PX;
        // Inside the region the projection is within the beam (which reaches a pixel past it).
        let last = (last as usize).min(b.n as usize - 1);
        match self.links[b.link0 + last] {
            NONE => (f64::NEG_INFINITY, at),
            // The first black is the highest of all those sunward: the walk ends here.
            k => (self.blacks[b.black0 + k as usize], at),
        }
    }

    /// Whether the sun's centre is visible from raster pixel (x, y) of the region, in `ctx`
    /// (the raster the map was built from): 1 lit, 0 shadowed (or below the floor), NaN over no
    /// data.
    pub fn lit(&self, ctx: &Context, x: usize, y: usize) -> f64 {
        let reg = self.region;
        debug_assert!(
            (reg.x0..reg.x0 + reg.w).contains(&x) && (reg.y0..reg.y0 + reg.h).contains(&y),
            "pixel ({x}, {y}) outside the map's region {reg:?}"
        );
        let h0 = ctx.at(x as i64, y as i64);
        if h0.is_nan() {
            return f64::NAN;
        }
        let h0 = h0 as f64;
        let s = self.sun;
        // The sun's elevation e from the pixel's unit up vector: sin e = up·S, cos e = sin β.
        let p = ctx.plane_point(x as f64, y as f64);
        let pn = dot(p, p).sqrt();
        let up = [p[0] / pn, p[1] / pn, p[2] / pn];
        let sin_e = dot(up, s);
        let cos_e = sin_beta(up, s);
        let r = self.radius_m;
        if below_floor(sin_e, r, self.terrain_min_m, h0) {
            return 0.0;
        }

        // The near field, exactly along the pixel's own ray as the tracer searches it (its own
        // directional derivative and the bilinear surface cell by cell), out to where the far
        // field's samples begin. The sun's plane azimuth as Frame::plane_azimuth takes it.
        let t = if cos_e > 0.0 {
            sin_e / cos_e
        } else {
            f64::INFINITY
        };
        let (n, ua, va) = ctx.face.axes();
        let (np, nt) = (dot(n, up), dot(n, s));
        let (ax, ay) = (
            dot(ua, s) * np - dot(ua, up) * nt,
            dot(va, s) * np - dot(va, up) * nt,
        );
        let phi = ay.atan2(ax);
        // The tracer's ray (a direction component of ±1e-16 along a row or column made 0, or
        // on the raster's first row the ray would lie a rounding error outside it).
        let ray = ray_toward(ctx, x, y, phi);
        let g_q = (r + h0) * cos_e;
        let (g_far, near) = self.far(x, y, raster_edge(ctx, x, y, ray.cx, ray.cy));
        if g_far >= g_q {
            return 0.0;
        }
        let l = ax.hypot(ay);
        let (cs, sn) = if l > 0.0 {
            (ax / l, ay / l)
        } else {
            (1.0, 0.0)
        };
        let s0 = ctx.slope0_g(x, y, cs, sn, ray.ground_per_px());
        let best = if s0.is_nan() { f64::NEG_INFINITY } else { s0 };
        let to = near + NEAR_OVERLAP_PX;
        if ray.max_over(ctx, 0.0, NEAR_PX.min(to), best).0 >= t {
            return 0.0;
        }
        if to <= NEAR_PX {
            return 1.0;
        }
        if !to.is_finite() {
            // No far field (the pixel is within EXACT_PX of the raster's sunward edge, or of
            // the sub-solar point): all the way exactly.
            return if ray.max_over(ctx, NEAR_PX, to, f64::NEG_INFINITY).0 >= t {
                0.0
            } else {
                1.0
            };
        }
        // Beyond the tracer's own near field, in pieces doubling in length: terrain no higher
        // than the highest around a piece (its bilinear surface lies below its pixels) has a
        // slope below that of the highest at the piece's start when it stands above the pixel,
        // and a negative one when below; only the pieces that could reach t are searched.
        let (w1, h1) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
        let around = |a: f64, b: f64, hi: f64| {
            (
                a.min(b).clamp(0.0, hi) as usize,
                (a.max(b).clamp(0.0, hi) as usize + 1).min(hi as usize),
            )
        };
        let mut sa = NEAR_PX;
        while sa < to {
            let sb = (2.0 * sa).min(to);
            let (x0, x1) = around(x as f64 + sa * ray.cx, x as f64 + sb * ray.cx, w1);
            let (y0, y1) = around(y as f64 + sa * ray.cy, y as f64 + sb * ray.cy, h1);
            let top = self.highest(x0, x1, y0, y1);
            let bound = if top == f64::NEG_INFINITY {
                top
            } else if top >= h0 {
                ray.slope_of(ctx, sa, top)
            } else if t > 0.0 {
                f64::NEG_INFINITY
            } else {
                f64::INFINITY
            };
            if bound >= t && ray.max_over(ctx, sa, sb, f64::NEG_INFINITY).0 >= t {
                return 0.0;
            }
            sa = sb;
        }
        1.0
    }

    /// [`SMap::lit`] over the whole region the map was built for, row-major, in parallel
    /// (bands of [`TILE_PX`] rows, each answered tile by tile: neighbouring pixels read
    /// neighbouring beams, whose samples then stay in the caches).
    pub fn lit_region(&self, ctx: &Context) -> Vec<f32> {
        let r = self.region;
        let mut out = vec![0.0f32; r.w * r.h];
        out.par_chunks_mut(TILE_PX * r.w)
            .enumerate()
            .for_each(|(band, rows)| {
                let y0 = band * TILE_PX;
                let nrows = rows.len() / r.w;
                for tx in (0..r.w).step_by(TILE_PX) {
                    for j in 0..nrows {
                        for i in tx..(tx + TILE_PX).min(r.w) {
                            rows[j * r.w + i] = self.lit(ctx, r.x0 + i, r.y0 + y0 + j) as f32;
                        }
                    }
                }
            });
        out
    }

    /// Share of the samples marked black (prefix maxima of g along their beam).
    pub fn marked_fraction(&self) -> f64 {
        self.blacks.len() as f64 / self.links.len().max(1) as f64
    }

    /// Share of the samples that are strict local maxima of g along their beam (Sakalauskas'
    /// Eq. 1 silhouette points, which his marking keeps and which the walk would have to visit
    /// one by one).
    pub fn silhouette_fraction(&self) -> f64 {
        self.silhouettes as f64 / self.links.len().max(1) as f64
    }

    /// Number of beams and of samples.
    pub fn size(&self) -> (usize, usize) {
        (self.beams.len(), self.links.len())
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.beams.len() * std::mem::size_of::<Beam>()
            + self.block_max.len() * std::mem::size_of::<f32>()
            + self.links.len() * std::mem::size_of::<u32>()
            + self.blacks.len() * std::mem::size_of::<f64>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cube::Face;
    use crate::fourier::stage::floor_deg;
    use crate::fourier::sun::{Frame, Sun};
    use crate::shadow::trace::{Method, Tracer, Work};

    const MOON: f64 = 1_737_400.0;

    /// Where a test raster lies: its centre at gnomonic (u, v) of `face` at `sf` pixels across
    /// the face, on a body of `radius` m; terrain heights are in units of `amp` pixels' ground
    /// size.
    struct Place {
        name: &'static str,
        face: Face,
        sf: f64,
        u: f64,
        v: f64,
        radius: f64,
        amp: f64,
    }

    const PLACES: [Place; 4] = [
        // The Moon at 100 m near a face centre: the vanishing point far away (a sheaf).
        Place {
            name: "centre",
            face: Face::Px,
            sf: 34_748.0,
            u: 0.02,
            v: -0.03,
            radius: MOON,
            amp: 1.0,
        },
        // Past a face edge: a sun towards +U has S·N < 0 (beams diverge towards the sun).
        Place {
            name: "edge",
            face: Face::Pz,
            sf: 34_748.0,
            u: 1.1,
            v: 0.3,
            radius: MOON,
            amp: 1.0,
        },
        // A 20 km body at 160 m pixels: the sub-solar point near the raster for high suns (a
        // fan).
        Place {
            name: "coarse",
            face: Face::Nz,
            sf: 256.0,
            u: 0.1,
            v: 0.05,
            radius: 20_000.0,
            amp: 0.5,
        },
        // A raster spanning ±73° of arc.
        Place {
            name: "wide",
            face: Face::Ny,
            sf: 48.0,
            u: 0.0,
            v: 0.0,
            radius: 20_000.0,
            amp: 0.1,
        },
    ];

    const TERRAINS: [&str; 5] = ["sphere", "cliff", "crater", "rolling", "holes"];

    fn noise(x: usize, y: usize) -> f64 {
        let mut s = (x as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ (y as u64).wrapping_add(77);
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s = s.wrapping_mul(0x2545_f491_4f6c_dd1d);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Height of `kind` at raster pixel (x, y) of a w×h raster, in pixels' ground size.
    fn terrain(kind: &str, w: usize, h: usize, x: usize, y: usize) -> f64 {
        let (fx, fy) = (
            x as f64 - (w - 1) as f64 / 2.0,
            y as f64 - (h - 1) as f64 / 2.0,
        );
        // Hills with slopes up to about 45° and pixel-scale roughness.
        let rolling = || {
            2.0 * (0.21 * x as f64 + 0.3).sin()
                + 1.5 * (0.13 * y as f64 + 1.1).cos()
                + 1.2 * (0.07 * (x + y) as f64).sin()
                + 0.8 * (0.17 * (x as f64 - 0.6 * y as f64)).sin()
                + 0.6 * noise(x, y)
        };
        match kind {
            "sphere" => 0.0,
            // A 12-pixel step along a line at 30° to the axes.
            "cliff" => {
                if fx * 0.866 + fy * 0.5 < 3.3 {
                    12.0
                } else {
                    0.0
                }
            }
            "crater" => {
                let rc = w as f64 * 0.22;
                let r = fx.hypot(fy) / rc;
                let bowl = if r < 1.0 { -8.0 * (1.0 - r * r) } else { 0.0 };
                bowl + 3.0 * (-((r - 1.0) * 6.0).powi(2)).exp() + 0.3 * noise(x, y)
            }
            "rolling" => rolling(),
            // No data: two discs, a column and 1 % of single pixels.
            "holes" => {
                let hole = |cx: f64, cy: f64, r: f64| (x as f64 - cx).hypot(y as f64 - cy) < r;
                if hole(0.3 * w as f64, 0.4 * h as f64, 9.0)
                    || hole(0.7 * w as f64, 0.75 * h as f64, 4.0)
                    || noise(y, x) < 0.01
                    || x == w / 2
                {
                    f64::NAN
                } else {
                    rolling()
                }
            }
            _ => unreachable!(),
        }
    }

    fn context(p: &Place, w: usize, h: usize, kind: &str) -> Context {
        let ox = ((p.u + 1.0) * p.sf / 2.0 - 0.5 - (w - 1) as f64 / 2.0).round() as i64;
        let oy = ((1.0 - p.v) * p.sf / 2.0 - 0.5 - (h - 1) as f64 / 2.0).round() as i64;
        let px_m = 2.0 * p.radius / p.sf / (1.0 + p.u * p.u + p.v * p.v);
        let heights = (0..w * h)
            .map(|i| (p.amp * px_m * terrain(kind, w, h, i % w, i / w)) as f32)
            .collect();
        Context {
            face: p.face,
            face_pixels: p.sf,
            origin: (ox, oy),
            width: w,
            height: h,
            heights,
            radius_m: p.radius,
        }
    }

    /// The body's lowest terrain for a place: a little below the test terrains.
    fn terrain_min(p: &Place) -> f64 {
        -20.0 * p.amp * p.radius / p.sf
    }

    /// The sun at elevation `el` (degrees) in plane azimuth `az` (degrees from +U towards +V)
    /// seen from the raster's centre.
    fn sun_at_centre(ctx: &Context, el: f64, az: f64) -> Vec3 {
        let (u, v) = ctx.uv((ctx.width - 1) as f64 / 2.0, (ctx.height - 1) as f64 / 2.0);
        let f = Frame::at(ctx.face, u, v);
        let (s, c) = az.to_radians().sin_cos();
        let w = [
            c * f.ua[0] + s * f.va[0],
            c * f.ua[1] + s * f.va[1],
            c * f.ua[2] + s * f.va[2],
        ];
        let k = dot(w, f.up);
        let t = [w[0] - k * f.up[0], w[1] - k * f.up[1], w[2] - k * f.up[2]];
        let l = dot(t, t).sqrt();
        let (se, ce) = el.to_radians().sin_cos();
        let d = [
            ce * t[0] / l + se * f.up[0],
            ce * t[1] / l + se * f.up[1],
            ce * t[2] / l + se * f.up[2],
        ];
        if el < 89.9 {
            let back = f.plane_azimuth(d).to_degrees();
            assert!(
                wrap_pi((back - az).to_radians()).abs() < 1e-9,
                "{back} vs {az}"
            );
            assert!((f.elevation_deg(d) - el).abs() < 1e-9);
        }
        d
    }

    /// The raster less a margin of `MARGIN` pixels: a tile inside its context.
    fn region_of(ctx: &Context) -> Rect {
        Rect {
            x0: MARGIN,
            y0: MARGIN,
            w: ctx.width - 2 * MARGIN,
            h: ctx.height - 2 * MARGIN,
        }
    }

    const MARGIN: usize = 8;

    /// SMap decisions against the extrema tracer's over the map's region.
    #[derive(Debug, Default)]
    struct Cmp {
        pixels: usize,
        agree: usize,
        lit_smap: usize,
        lit_ref: usize,
    }

    impl Cmp {
        fn share(&self) -> f64 {
            self.agree as f64 / self.pixels.max(1) as f64
        }
    }

    fn compare(ctx: &Context, tr: &Tracer, map: &SMap, sun: Vec3) -> Cmp {
        let r = map.region;
        let got = map.lit_region(ctx);
        let s = Sun {
            dir: sun,
            radius_deg: 0.0,
        };
        let want: Vec<f64> = (0..r.w * r.h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (r.x0 + i % r.w, r.y0 + i / r.w);
                tr.trace(x, y, &s, &Method::Extrema, &mut Work::default())
                    .lit
            })
            .collect();
        let mut c = Cmp::default();
        for (i, (&g, &e)) in got.iter().zip(&want).enumerate() {
            let (x, y) = (r.x0 + i % r.w, r.y0 + i / r.w);
            let h = ctx.at(x as i64, y as i64);
            assert_eq!(g.is_nan(), h.is_nan(), "({x}, {y}): {g} over height {h}");
            assert_eq!(e.is_nan(), h.is_nan());
            if h.is_nan() {
                continue;
            }
            assert!(g == 0.0 || g == 1.0, "({x}, {y}): {g}");
            c.pixels += 1;
            c.agree += (g as f64 == e) as usize;
            c.lit_smap += (g == 1.0) as usize;
            c.lit_ref += (e == 1.0) as usize;
        }
        c
    }

    fn describe(map: &SMap) -> String {
        let (nb, ns) = map.size();
        let kind = match map.pencil {
            Pencil::Fan { full, outward, .. } => format!(
                "{} fan{}",
                if full { "full" } else { "partial" },
                if outward { "" } else { " (S·N < 0)" }
            ),
            Pencil::Sheaf { kappa, .. } => match kappa.partial_cmp(&0.0) {
                Some(std::cmp::Ordering::Equal) => "parallel sheaf".into(),
                Some(std::cmp::Ordering::Less) => "sheaf (S·N < 0)".into(),
                _ => "sheaf".into(),
            },
        };
        format!(
            "{kind}, {nb} beams, {ns} samples, black {:.2} %, silhouettes {:.2} %, {} kB",
            100.0 * map.marked_fraction(),
            100.0 * map.silhouette_fraction(),
            map.bytes() / 1024
        )
    }

    /// Compares every sun (elevation, azimuth at the raster centre, degrees, or a direction)
    /// on every terrain of `place` and prints the numbers; returns the worst agreement and the
    /// overall (agreeing, pixels).
    fn sweep(place: &Place, n: usize, suns: &[Vec3], label: &str) -> (f64, usize, usize) {
        let (mut worst, mut agree, mut pixels) = (1.0f64, 0, 0);
        for kind in TERRAINS {
            let ctx = context(place, n, n, kind);
            let tmin = terrain_min(place);
            let tr = Tracer::new(&ctx, tmin);
            for &sun in suns {
                let map = SMap::build(&ctx, sun, region_of(&ctx), tmin);
                let c = compare(&ctx, &tr, &map, sun);
                let (u, v) = ctx.uv((n - 1) as f64 / 2.0, (n - 1) as f64 / 2.0);
                let f = Frame::at(ctx.face, u, v);
                println!(
                    "{label} {:>6} {kind:>7} el {:>6.2} az {:>6.1}: agree {:>8.4} % ({} of {} \
                     differ), lit {} (extrema {}); {}",
                    place.name,
                    f.elevation_deg(sun),
                    f.plane_azimuth(sun).to_degrees(),
                    100.0 * c.share(),
                    c.pixels - c.agree,
                    c.pixels,
                    c.lit_smap,
                    c.lit_ref,
                    describe(&map)
                );
                worst = worst.min(c.share());
                agree += c.agree;
                pixels += c.pixels;
            }
        }
        (worst, agree, pixels)
    }

    const ELS: [f64; 4] = [1.0, 5.0, 15.0, 45.0];
    /// Along +U, along +V, diagonal, and two others.
    const AZS: [f64; 5] = [0.0, 90.0, 45.0, 200.0, 333.0];

    #[test]
    fn agrees_with_the_extrema_tracer() {
        let (mut worst, mut agree, mut pixels) = (1.0f64, 0, 0);
        for p in &PLACES {
            let ctx = context(p, 128, 128, "sphere");
            let suns: Vec<Vec3> = ELS
                .iter()
                .flat_map(|&e| AZS.iter().map(move |&a| (e, a)))
                .map(|(e, a)| sun_at_centre(&ctx, e, a))
                .collect();
            let (w, a, n) = sweep(p, 128, &suns, "sweep");
            worst = worst.min(w);
            agree += a;
            pixels += n;
        }
        println!(
            "sweep: {:.4} % of {pixels} pixels agree, worst case {:.4} %",
            100.0 * agree as f64 / pixels as f64,
            100.0 * worst
        );
        assert!(worst >= 0.99, "worst agreement {worst}");
    }

    /// The geometrically special suns: S·N = 0 (parallel beams), overhead (a full fan round
    /// the sub-solar point, exactly on a pixel or not), a partial fan, and a fan round the
    /// anti-solar point (S·N < 0).
    #[test]
    fn special_suns_agree_with_the_extrema_tracer() {
        let mut worst = 1.0f64;
        // Past the face edge, S = +U lies in the face plane.
        let edge = &PLACES[1];
        let u_axis = edge.face.axes().1;
        let ctx = context(edge, 128, 128, "sphere");
        let map = SMap::build(&ctx, u_axis, region_of(&ctx), 0.0);
        assert!(matches!(map.pencil, Pencil::Sheaf { kappa, .. } if kappa == 0.0));
        worst = worst.min(sweep(edge, 128, &[u_axis], "special").0);
        let centre = &PLACES[0];
        let ctx = context(centre, 128, 128, "sphere");
        let overhead = [
            sun_at_centre(&ctx, 90.0, 0.0),
            sun_at_centre(&ctx, 89.8, 30.0),
        ];
        for &s in &overhead {
            let map = SMap::build(&ctx, s, region_of(&ctx), 0.0);
            assert!(matches!(
                map.pencil,
                Pencil::Fan {
                    full: true,
                    outward: true,
                    ..
                }
            ));
        }
        worst = worst.min(sweep(centre, 128, &overhead, "special").0);
        let coarse = &PLACES[2];
        let ctx = context(coarse, 128, 128, "sphere");
        let partial = sun_at_centre(&ctx, 45.0, 120.0);
        let map = SMap::build(&ctx, partial, region_of(&ctx), 0.0);
        assert!(matches!(
            map.pencil,
            Pencil::Fan {
                full: false,
                outward: true,
                ..
            }
        ));
        worst = worst.min(sweep(coarse, 128, &[partial], "special").0);
        // 120° from the face's normal towards +U: the anti-solar point projects 41 pixels
        // from the centre, and the far side of the raster still sees the sun.
        let wide = &PLACES[3];
        let (n, u, _) = wide.face.axes();
        let (sn, cs) = 120f64.to_radians().sin_cos();
        let behind = [
            cs * n[0] + sn * u[0],
            cs * n[1] + sn * u[1],
            cs * n[2] + sn * u[2],
        ];
        let ctx = context(wide, 128, 128, "rolling");
        let map = SMap::build(&ctx, behind, region_of(&ctx), 0.0);
        assert!(matches!(map.pencil, Pencil::Fan { outward: false, .. }));
        assert!(map.lit_region(&ctx).contains(&1.0));
        worst = worst.min(sweep(wide, 128, &[behind], "special").0);
        assert!(worst >= 0.99, "worst agreement {worst}");
    }

    #[test]
    fn bare_sphere_is_lit_iff_the_sun_is_up() {
        for p in &PLACES {
            let ctx = context(p, 96, 96, "sphere");
            let region = region_of(&ctx);
            // Suns setting inside the raster, and higher ones.
            for (el, az) in [
                (0.05, 0.0),
                (0.3, 90.0),
                (1.0, 45.0),
                (15.0, 200.0),
                (45.0, 333.0),
                (89.5, 10.0),
                (90.0, 0.0),
            ] {
                let sun = sun_at_centre(&ctx, el, az);
                let map = SMap::build(&ctx, sun, region, 0.0);
                let (mut up, mut down) = (0, 0);
                for y in region.y0..region.y0 + region.h {
                    for x in region.x0..region.x0 + region.w {
                        let (u, v) = ctx.uv(x as f64, y as f64);
                        let e = Frame::at(ctx.face, u, v).elevation_deg(sun);
                        if e.abs() < 1e-9 {
                            continue;
                        }
                        let lit = map.lit(&ctx, x, y);
                        assert_eq!(lit == 1.0, e > 0.0, "{} ({x}, {y}) el {e}", p.name);
                        if e > 0.0 {
                            up += 1;
                        } else {
                            down += 1;
                        }
                    }
                }
                assert!(up > 0, "{} el {el}: the sun is up somewhere", p.name);
                let _ = down;
            }
        }
    }

    #[test]
    fn no_data_is_nan_and_blocks_nothing() {
        let p = &PLACES[0];
        let mut ctx = context(p, 96, 96, "cliff");
        let sun = sun_at_centre(&ctx, 5.0, 200.0);
        // No terrain at all: every answer is NaN, nothing is marked.
        let nan = Context {
            heights: vec![f32::NAN; 96 * 96],
            ..ctx.clone()
        };
        let map = SMap::build(&nan, sun, region_of(&nan), 0.0);
        assert!(map.lit_region(&nan).iter().all(|v| v.is_nan()));
        assert_eq!(map.marked_fraction(), 0.0);
        // The cliff's shadow shrinks where the cliff has no data.
        let region = region_of(&ctx);
        let before = map_lit(&ctx, sun, region);
        for (i, h) in ctx.heights.iter_mut().enumerate() {
            if *h > 0.0 && i % 96 < 60 {
                *h = f32::NAN;
            }
        }
        let after = map_lit(&ctx, sun, region);
        let dark = |v: &[f32]| v.iter().filter(|&&x| x == 0.0).count();
        assert!(
            dark(&after) < dark(&before),
            "{} vs {}",
            dark(&after),
            dark(&before)
        );
        let tr = Tracer::new(&ctx, 0.0);
        let c = compare(&ctx, &tr, &SMap::build(&ctx, sun, region, 0.0), sun);
        assert!(c.share() >= 0.99, "{c:?}");
    }

    fn map_lit(ctx: &Context, sun: Vec3, region: Rect) -> Vec<f32> {
        SMap::build(ctx, sun, region, 0.0).lit_region(ctx)
    }

    /// One thread or many, the same map and answers.
    #[test]
    fn deterministic() {
        let p = &PLACES[2];
        let ctx = context(p, 128, 128, "holes");
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("pool");
        for (el, az) in [(5.0, 30.0), (60.0, 200.0)] {
            let sun = sun_at_centre(&ctx, el, az);
            let a = SMap::build(&ctx, sun, region_of(&ctx), -500.0);
            let b = one.install(|| SMap::build(&ctx, sun, region_of(&ctx), -500.0));
            assert_eq!(a.links, b.links);
            assert_eq!(a.blacks, b.blacks);
            let (la, lb) = (a.lit_region(&ctx), one.install(|| b.lit_region(&ctx)));
            assert!(la
                .iter()
                .zip(&lb)
                .all(|(x, y)| x == y || x.is_nan() && y.is_nan()));
        }
    }

    /// The single-pass links are Sakalauskas' log₂ N doubling passes' NextV, and the blacks
    /// rise along every beam.
    #[test]
    fn links_are_the_doubling_passes() {
        let p = &PLACES[0];
        let ctx = context(p, 128, 128, "holes");
        for (el, az) in [(1.0, 0.0), (15.0, 200.0)] {
            let sun = sun_at_centre(&ctx, el, az);
            let map = SMap::build(&ctx, sun, region_of(&ctx), 0.0);
            for b in &map.beams {
                let n = b.n as usize;
                let links = &map.links[b.link0..b.link0 + n];
                // The marks: where the link moves on.
                let black: Vec<bool> = (0..n)
                    .map(|j| links[j] != NONE && (j == 0 || links[j] != links[j - 1]))
                    .collect();
                let pos: Vec<usize> = (0..n).filter(|&j| black[j]).collect();
                let g = &map.blacks[b.black0..b.black0 + pos.len()];
                assert!(g.windows(2).all(|w| w[0] < w[1]));
                // Sakalauskas' passes: blocks of 2·DIST linked at DIST = 1, 2, 4, …
                let mut next: Vec<Option<usize>> = (0..n).map(|j| black[j].then_some(j)).collect();
                let mut dist = 1;
                while dist < n {
                    for j in 0..n {
                        if (j / dist) % 2 == 1 && next[j].is_none() {
                            let look = j - j % dist - 1;
                            next[j] = if black[look] { Some(look) } else { next[look] };
                        }
                    }
                    dist *= 2;
                }
                for j in 0..n {
                    let ours = (links[j] != NONE).then(|| pos[links[j] as usize]);
                    assert_eq!(ours, next[j], "sample {j} of {n}");
                }
            }
        }
    }

    /// Every pixel of the region lies within half a beam spacing of its beam, which runs along
    /// its exact ray, and projects inside the beam's samples.
    #[test]
    fn beams_run_along_the_rays() {
        for p in &PLACES {
            let ctx = context(p, 96, 96, "sphere");
            let region = region_of(&ctx);
            for (el, az) in [
                (1.0, 0.0),
                (1.0, 200.0),
                (45.0, 90.0),
                (15.0, 333.0),
                (89.7, 5.0),
            ] {
                let sun = sun_at_centre(&ctx, el, az);
                let map = SMap::build(&ctx, sun, region, 0.0);
                for y in region.y0..region.y0 + region.h {
                    for x in region.x0..region.x0 + region.w {
                        let b = map.beam_of(x as f64, y as f64);
                        let (px, py) = (x as f64 - b.x0, y as f64 - b.y0);
                        let off = (px * b.dy - py * b.dx).abs() / STEP_PX;
                        assert!(off <= 0.5 * BEAM_PX + 1e-6, "{} ({x}, {y}): {off}", p.name);
                        let j = (px * b.dx + py * b.dy) / (STEP_PX * STEP_PX);
                        assert!(j <= b.n as f64, "{} ({x}, {y}): {j} of {}", p.name, b.n);
                        let (u, v) = ctx.uv(x as f64, y as f64);
                        let phi = Frame::at(ctx.face, u, v).plane_azimuth(sun);
                        // The ray runs (cos φ, −sin φ) in raster coordinates, the beam's steps
                        // away from the sun.
                        let along = -(b.dx * phi.cos() - b.dy * phi.sin()) / STEP_PX;
                        assert!(along > 0.9999, "{} ({x}, {y}): {along}", p.name);
                    }
                }
            }
        }
    }

    #[test]
    fn floor_is_the_tracers() {
        let r = MOON;
        for i in 0..20_000 {
            let (a, b, c) = (noise(i, 1), noise(i, 2), noise(i, 3));
            let tmin = -9000.0 + 2000.0 * a;
            let h0 = -9500.0 + 20_000.0 * b;
            let e = -3.5 + 4.0 * c;
            let f = floor_deg(r, tmin, h0);
            if (e - f).abs() < 1e-9 {
                continue;
            }
            assert_eq!(
                below_floor(e.to_radians().sin(), r, tmin, h0),
                e <= f,
                "e {e} floor {f}"
            );
        }
    }

    /// Build and answer times over a 2000² context and a 1024² region (release:
    /// `cargo test --release --lib shadow::smap -- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn timing() {
        use std::time::Instant;
        // Process CPU time (s) from /proc, where there is one.
        let cpu = || -> f64 {
            let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
            let f: Vec<&str> = s
                .rsplit(')')
                .next()
                .unwrap_or("")
                .split_whitespace()
                .collect();
            let t = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
            (t(11) + t(12)) / 100.0
        };
        let p = &PLACES[0];
        let n = 2000;
        let ctx = context(p, n, n, "rolling");
        let region = Rect {
            x0: (n - 1024) / 2,
            y0: (n - 1024) / 2,
            w: 1024,
            h: 1024,
        };
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("pool");
        let t0 = Instant::now();
        let tr = Tracer::new(&ctx, -1.0e4);
        let t_pyramid = t0.elapsed();
        for (el, az) in [
            (1.0, 0.0),
            (5.0, 30.0),
            (15.0, 30.0),
            (45.0, 200.0),
            (89.5, 0.0),
        ] {
            let sun = sun_at_centre(&ctx, el, az);
            // The extrema tracer over every 16th row, for scale (all threads).
            let s = Sun {
                dir: sun,
                radius_deg: 0.0,
            };
            let t0 = Instant::now();
            let rows: Vec<usize> = (region.y0..region.y0 + region.h).step_by(16).collect();
            let lit: usize = rows
                .par_iter()
                .map(|&y| {
                    let mut w = Work::default();
                    (region.x0..region.x0 + region.w)
                        .filter(|&x| tr.trace(x, y, &s, &Method::Extrema, &mut w).lit == 1.0)
                        .count()
                })
                .sum();
            println!(
                "el {el:>4} az {az:>5}: extrema {:.0} ms per 1024² (pyramid {:.0} ms), lit {:.1} %",
                t0.elapsed().as_secs_f64() * 1e3 * 16.0,
                t_pyramid.as_secs_f64() * 1e3,
                100.0 * lit as f64 / (rows.len() * region.w) as f64
            );
            for threads in [1, rayon::current_num_threads()] {
                let run = || {
                    let (t0, c0) = (Instant::now(), cpu());
                    let map = SMap::build(&ctx, sun, region, -1.0e4);
                    let (t1, c1) = (Instant::now(), cpu());
                    let lit = map.lit_region(&ctx);
                    let (t2, c2) = (Instant::now(), cpu());
                    (map, lit, [t1 - t0, t2 - t1], [c1 - c0, c2 - c1])
                };
                let (map, lit, t, c) = if threads == 1 {
                    one.install(run)
                } else {
                    run()
                };
                let share = lit.iter().filter(|&&v| v == 1.0).count() as f64 / lit.len() as f64;
                println!(
                    "el {el:>4} az {az:>5} threads {threads:>2}: build {:>6.1} ms, lit {:>6.1} ms, \
                     total {:>6.1} ms (CPU {:.2} + {:.2} s); lit {:.1} %; {}",
                    t[0].as_secs_f64() * 1e3,
                    t[1].as_secs_f64() * 1e3,
                    (t[0] + t[1]).as_secs_f64() * 1e3,
                    c[0],
                    c[1],
                    100.0 * share,
                    describe(&map)
                );
            }
        }
    }
}
