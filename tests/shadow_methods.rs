//! The shadow ray-marching methods (`penumbra::shadow::trace`) in stiff cases, each with a known
//! answer: a bare sphere (the disc's circular segment), a vertical cliff and a one-pixel spike
//! (their tops' elevations from exact spherical geometry), rays exactly along grid axes and
//! diagonals, observers on the raster's, a face's and the cube's edges, the pole, a 10 km body,
//! voids, and a crater block against the reference. Every method (reference, uniform 100, dp
//! auto, dp 5,5,5, dp-dda auto, extrema, and the SMap) must answer finite values in [0, 1]
//! (extrema and smap exactly 0 or 1) everywhere, and each tolerance below says where it comes from. Measured errors are
//! printed (`cargo test --test shadow_methods -- --nocapture`).

use penumbra::cube::{angle_between, Face, Vec3};
use penumbra::fourier::sun::{segment_fraction, Frame, Sun};
use penumbra::horizon::Context;
use penumbra::horizon::Rect;
use penumbra::shadow::smap::SMap;
use penumbra::shadow::trace::{Method, Runs, Traced, Tracer, Work};
use std::f64::consts::{FRAC_1_SQRT_2, FRAC_PI_2, FRAC_PI_4, PI, TAU};

const MOON_R: f64 = 1_737_400.0;
/// The Sun's angular radius from 1 AU (degrees).
const SUN_R: f64 = 0.2666;

// Indices into `methods()`.
const REF: usize = 0;
const UNIFORM: usize = 1;
const DP: usize = 2;
const DP555: usize = 3;
const DDA: usize = 4;
const EXTREMA: usize = 5;
/// Sakalauskas' SMap, built for the sun over the observer's own pixel (a hard method).
const SMAP: usize = 6;
/// The tracer's methods (`methods()`), then the SMap.
const N_TRACE: usize = 6;
const N_METHODS: usize = 7;

fn methods() -> [Method; N_TRACE] {
    [
        Method::Reference,
        Method::Uniform { steps: 100 },
        Method::Dp {
            runs: Runs::Auto,
            dda: false,
        },
        Method::Dp {
            runs: Runs::Fixed(vec![5, 5, 5]),
            dda: false,
        },
        Method::Dp {
            runs: Runs::Auto,
            dda: true,
        },
        Method::Extrema,
    ]
}

fn labels() -> [String; N_METHODS] {
    let m = methods();
    std::array::from_fn(|i| m.get(i).map_or("smap".into(), |m| m.label()))
}

/// The SMap's answer at raster pixel (x, y): a map built over the tracer's raster for the
/// pixel alone (the beams it needs, from the raster's sunward edge).
fn smap_lit(tr: &Tracer, x: usize, y: usize, sun: &Sun) -> f64 {
    let one = Rect {
        x0: x,
        y0: y,
        w: 1,
        h: 1,
    };
    SMap::build(tr.ctx, sun.dir, one, tr.terrain_min_m).lit(tr.ctx, x, y)
}

// ------------------------------------------------------------------------------------------
// Helpers
// ------------------------------------------------------------------------------------------

/// Pixels across a face whose centre pixel is `pixel_m` metres wide.
fn face_pixels(radius_m: f64, pixel_m: f64) -> f64 {
    (2.0 * radius_m / pixel_m).round()
}

/// Origin that puts the face pixel nearest gnomonic point (u, v) at raster pixel (cx, cy).
fn origin_at(s: f64, u: f64, v: f64, cx: usize, cy: usize) -> (i64, i64) {
    let gx = ((u + 1.0) * s / 2.0 - 0.5).round() as i64;
    let gy = ((1.0 - v) * s / 2.0 - 0.5).round() as i64;
    (gx - cx as i64, gy - cy as i64)
}

/// A context whose height at raster pixel (x, y) is `f(x, y)`.
fn build(
    face: Face,
    radius_m: f64,
    s: f64,
    origin: (i64, i64),
    w: usize,
    h: usize,
    f: impl Fn(usize, usize) -> f64,
) -> Context {
    Context {
        face,
        face_pixels: s,
        origin,
        width: w,
        height: h,
        heights: (0..w * h).map(|i| f(i % w, i / w) as f32).collect(),
        radius_m,
    }
}

fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn lin(a: f64, p: Vec3, b: f64, q: Vec3) -> Vec3 {
    [
        a * p[0] + b * q[0],
        a * p[1] + b * q[1],
        a * p[2] + b * q[2],
    ]
}

fn normalize(p: Vec3) -> Vec3 {
    let n = dot(p, p).sqrt();
    [p[0] / n, p[1] / n, p[2] / n]
}

/// The horizontal unit direction at `f` whose plane azimuth is `phi`: the plane direction
/// cos φ·U + sin φ·V with its vertical part removed.
fn tangent(f: &Frame, phi: f64) -> Vec3 {
    let w = lin(phi.cos(), f.ua, phi.sin(), f.va);
    normalize(lin(1.0, w, -dot(w, f.up), f.up))
}

/// The frame at raster pixel (x, y).
fn frame(ctx: &Context, x: usize, y: usize) -> Frame {
    let (u, v) = ctx.uv(x as f64, y as f64);
    Frame::at(ctx.face, u, v)
}

/// A sun of radius `r` (degrees) seen from raster pixel (x, y) in plane azimuth `phi` at
/// elevation `el` (degrees); the tracer is checked to see it there.
fn sun_toward(tr: &Tracer, x: usize, y: usize, phi: f64, el: f64, r: f64) -> Sun {
    let f = frame(tr.ctx, x, y);
    let (se, ce) = el.to_radians().sin_cos();
    let sun = Sun {
        dir: lin(ce, tangent(&f, phi), se, f.up),
        radius_deg: r,
    };
    let at = tr.sun_at(x, y, &sun);
    assert!(
        (at.elevation_deg - el).abs() < 1e-9,
        "sun built at {el}° reads {}°",
        at.elevation_deg
    );
    if el.abs() < 89.0 {
        let d = (at.phi - phi).rem_euclid(TAU);
        assert!(
            d.min(TAU - d) < 1e-9,
            "sun built at φ {phi} reads {}",
            at.phi
        );
    }
    sun
}

/// Elevation (degrees) of a point at radius `r` and angular distance `psi` seen from radius
/// `r0`: atan((r cos ψ − r0)/(r sin ψ)), with r cos ψ − r0 written as (r − r0) − 2r sin²(ψ/2).
fn elevation(r0: f64, r: f64, psi: f64) -> f64 {
    let hs = (0.5 * psi).sin();
    ((r - r0) - 2.0 * r * hs * hs)
        .atan2(r * psi.sin())
        .to_degrees()
}

/// Elevation (degrees) from raster pixel (x0, y0), at its own height, of the fractional raster
/// point (x, y) at height `h`.
fn elevation_to(ctx: &Context, x0: usize, y0: usize, x: f64, y: f64, h: f64) -> f64 {
    let r0 = ctx.radius_m + ctx.at(x0 as i64, y0 as i64) as f64;
    let psi = angle_between(ctx.dir(x0 as f64, y0 as f64), ctx.dir(x, y));
    elevation(r0, ctx.radius_m + h, psi)
}

/// Geometric dip (degrees, negative) of the horizon from height `h` over a sphere of radius
/// `r`: −acos(r/(r+h)), as an atan for accuracy.
fn dip_deg(r: f64, h: f64) -> f64 {
    -((2.0 * r * h + h * h).sqrt() / r).atan().to_degrees()
}

/// Bilinear height at fractional raster point (x, y) (written here, not the library's); NaN
/// outside or next to no data.
fn bilinear(ctx: &Context, x: f64, y: f64) -> f64 {
    let (wm, hm) = ((ctx.width - 1) as f64, (ctx.height - 1) as f64);
    if !(x >= 0.0 && y >= 0.0 && x <= wm && y <= hm) {
        return f64::NAN;
    }
    let (x0, y0) = (x.floor().min(wm - 1.0), y.floor().min(hm - 1.0));
    let (fx, fy) = (x - x0, y - y0);
    let (i, j) = (x0 as i64, y0 as i64);
    let h = |a: i64, b: i64| ctx.at(a, b) as f64;
    h(i, j) * (1.0 - fx) * (1.0 - fy)
        + h(i + 1, j) * fx * (1.0 - fy)
        + h(i, j + 1) * (1.0 - fx) * fy
        + h(i + 1, j + 1) * fx * fy
}

/// Brute-force horizon (degrees) from (x0, y0) in plane azimuth `phi`: the bilinear surface
/// sampled every 1/128 pixel along the plane line (x0 + s cos φ, y0 − s sin φ) (a great
/// circle) out to the raster's edge, then every 1/2¹⁴ pixel within a coarse step of the best
/// sample. A lower bound of the true horizon, short of it by at most the elevation's rate ×
/// 2⁻¹⁵ px (≤ 1e-4° here).
fn brute_horizon(ctx: &Context, x0: usize, y0: usize, phi: f64) -> f64 {
    let (c, s) = (phi.cos(), -phi.sin());
    let at = |d: f64| {
        let (x, y) = (x0 as f64 + d * c, y0 as f64 + d * s);
        let h = bilinear(ctx, x, y);
        if h.is_finite() {
            elevation_to(ctx, x0, y0, x, y, h)
        } else {
            f64::NEG_INFINITY
        }
    };
    let (mut best, mut best_d) = (f64::NEG_INFINITY, 0.0);
    let coarse = 1.0 / 128.0;
    let mut k = 1.0;
    loop {
        let d = k * coarse;
        let (x, y) = (x0 as f64 + d * c, y0 as f64 + d * s);
        if !(x >= 0.0 && y >= 0.0 && x <= (ctx.width - 1) as f64 && y <= (ctx.height - 1) as f64) {
            break;
        }
        let e = at(d);
        if e > best {
            (best, best_d) = (e, d);
        }
        k += 1.0;
    }
    let fine = coarse / 128.0;
    for i in -128..=128 {
        let d = best_d + i as f64 * fine;
        if d > 0.0 {
            best = best.max(at(d));
        }
    }
    best
}

/// Every method at raster pixel (x, y), each checked to answer a finite value in [0, 1] (0 or
/// 1 for the hard method).
fn trace_all(tr: &Tracer, x: usize, y: usize, sun: &Sun, label: &str) -> [Traced; N_METHODS] {
    let m = methods();
    let names = labels();
    std::array::from_fn(|i| {
        let t = match m.get(i) {
            Some(m) => tr.trace(x, y, sun, m, &mut Work::default()),
            None => Traced {
                lit: smap_lit(tr, x, y, sun),
                horizon_deg: f64::NAN,
            },
        };
        assert!(
            t.lit.is_finite() && (0.0..=1.0).contains(&t.lit),
            "{label}: {} at ({x}, {y}) answers {}",
            names[i],
            t.lit
        );
        if i >= EXTREMA {
            assert!(
                t.lit == 0.0 || t.lit == 1.0,
                "{label}: {} at ({x}, {y}) answers {}",
                names[i],
                t.lit
            );
        }
        t
    })
}

/// The soft methods whose lit fraction, over a horizon they find exactly and that is constant
/// across the disc, is the segment formula: dp in all three forms (uniform samples the ray, so
/// it may step over the horizon's top).
const EXACT_SOFT: [usize; 3] = [DP, DP555, DDA];

/// The lit fraction of a sun of radius `r` at elevation `el` over a horizon at `alpha` constant
/// across the disc: the circular segment (a point sun: 1 above, 0 below).
fn segment_lit(alpha: f64, el: f64, r: f64) -> f64 {
    if r > 0.0 {
        segment_fraction((alpha - el) / r)
    } else if el > alpha {
        1.0
    } else {
        0.0
    }
}

/// Checks a known answer: a horizon at `alpha` degrees constant across the disc (the sun of
/// radius `r` at elevation `el`). The reference within `ref_tol` (the Exact disc model's 1e-3
/// and what the horizon varies across the disc) plus the bend of the line of constant elevation
/// α across the disc, which the segment formula takes as straight (a small circle of radius
/// 90° − α: its sagitta over the disc is r/(2(90° − α)) radii, moving the lit fraction by at
/// most 2/π of that; 0 for α = 0); the dp forms within `soft_tol` of the segment; uniform, which
/// samples the ray and so may step over the horizon's top, between the segments of α and of
/// `uniform_lo` (the lowest horizon its samples can find); extrema exactly (the centre against
/// α) unless the centre is within 1e-6° of α. Methods in `skip` are left out.
#[allow(clippy::too_many_arguments)]
fn check_known(
    got: &[Traced; N_METHODS],
    alpha: f64,
    el: f64,
    r: f64,
    ref_tol: f64,
    soft_tol: f64,
    uniform_lo: f64,
    skip: &[usize],
    label: &str,
) {
    let want = segment_lit(alpha, el, r);
    let names = labels();
    let mut tol = [soft_tol; N_METHODS];
    tol[REF] = ref_tol + 2.0 / PI * r / (2.0 * (90.0 - alpha.abs()));
    for i in [REF, DP, DP555, DDA] {
        if skip.contains(&i) {
            continue;
        }
        assert!(
            (got[i].lit - want).abs() <= tol[i],
            "{label}: {} lit {} but the horizon at {alpha:.6}° and the sun at {el:.6}° (r {r}) give {want}",
            names[i],
            got[i].lit
        );
    }
    if !skip.contains(&UNIFORM) {
        let hi = segment_lit(uniform_lo, el, r);
        let u = got[UNIFORM].lit;
        assert!(
            u >= want - 1e-9 && u <= hi + 1e-9,
            "{label}: uniform lit {u}, outside [{want}, {hi}] (horizons {alpha:.6}°, {uniform_lo:.6}°)"
        );
    }
    if (el - alpha).abs() > 1e-6 {
        let hard = if el > alpha { 1.0 } else { 0.0 };
        for i in [EXTREMA, SMAP] {
            if !skip.contains(&i) {
                assert_eq!(
                    got[i].lit, hard,
                    "{label}: {} with the horizon at {alpha:.6}° and the sun's centre at {el:.6}°",
                    names[i]
                );
            }
        }
    }
}

/// Per-method comparison against the reference over observers: mean and max |lit − reference|
/// and the share of pixels whose decision (lit ≥ ½) differs from the reference's.
#[derive(Default, Clone, Copy, Debug)]
struct Cmp {
    n: usize,
    sum: [f64; N_METHODS],
    max: [f64; N_METHODS],
    flips: [usize; N_METHODS],
}

impl Cmp {
    fn add(&mut self, got: &[Traced; N_METHODS]) {
        self.n += 1;
        let r = got[REF].lit;
        for (i, t) in got.iter().enumerate() {
            let d = (t.lit - r).abs();
            self.sum[i] += d;
            self.max[i] = self.max[i].max(d);
            if (t.lit >= 0.5) != (r >= 0.5) {
                self.flips[i] += 1;
            }
        }
    }

    fn merge(&mut self, o: &Cmp) {
        self.n += o.n;
        for i in 0..N_METHODS {
            self.sum[i] += o.sum[i];
            self.max[i] = self.max[i].max(o.max[i]);
            self.flips[i] += o.flips[i];
        }
    }

    fn mean(&self, i: usize) -> f64 {
        self.sum[i] / self.n.max(1) as f64
    }

    fn per(&self, i: usize) -> f64 {
        self.flips[i] as f64 / self.n.max(1) as f64
    }

    fn print(&self, label: &str) {
        let names = labels();
        let parts: Vec<String> = (1..N_METHODS)
            .map(|i| {
                format!(
                    "{} mean {:.4} max {:.3} PER {:.2}%",
                    names[i],
                    self.mean(i),
                    self.max[i],
                    100.0 * self.per(i)
                )
            })
            .collect();
        eprintln!("{label} ({} px): {}", self.n, parts.join("; "));
    }
}

/// The block bounds: every soft method (dp auto, as the issue asks, and uniform 100, dp 5,5,5
/// and dp-dda with it: none is measured above 0.046 in these tests) within 0.05 mean
/// |lit − reference|, and extrema's decisions differing from the reference's (lit ≥ ½) on
/// ≤ 1 % of the pixels.
fn assert_block(c: &Cmp, label: &str) {
    let names = labels();
    for i in [UNIFORM, DP, DP555, DDA] {
        assert!(
            c.mean(i) <= 0.05,
            "{label}: {} mean |lit − reference| {}",
            names[i],
            c.mean(i)
        );
    }
    for i in [EXTREMA, SMAP] {
        assert!(
            c.per(i) <= 0.01,
            "{label}: {}'s decisions differ from the reference's on {} of the pixels",
            names[i],
            c.per(i)
        );
    }
}

/// Every method over the observers `pts` (no-data observers must read NaN in every method and
/// are left out of the comparison).
fn compare(tr: &Tracer, pts: &[(usize, usize)], sun: &Sun, label: &str) -> Cmp {
    let mut c = Cmp::default();
    for &(x, y) in pts {
        if tr.ctx.at(x as i64, y as i64).is_nan() {
            for m in methods() {
                let t = tr.trace(x, y, sun, &m, &mut Work::default());
                assert!(
                    t.lit.is_nan(),
                    "{label}: {} over no data at ({x}, {y}): {}",
                    m.label(),
                    t.lit
                );
            }
            let v = smap_lit(tr, x, y, sun);
            assert!(v.is_nan(), "{label}: smap over no data at ({x}, {y}): {v}");
            continue;
        }
        c.add(&trace_all(tr, x, y, sun, label));
    }
    c
}

/// Observers of the square block [x0, x0 + n) × [y0, y0 + n), every `step` pixels.
fn block(x0: usize, y0: usize, n: usize, step: usize) -> Vec<(usize, usize)> {
    let mut v = Vec::new();
    for y in (y0..y0 + n).step_by(step) {
        for x in (x0..x0 + n).step_by(step) {
            v.push((x, y));
        }
    }
    v
}

/// A crater centred on raster point (cx, cy) of radius `rc` pixels: a parabolic bowl from
/// −`depth` at the centre up to a rim crest of `rim` at ρ = rc, and outside a Gaussian fall-off
/// of the rim (width 0.3·rc).
fn crater(x: f64, y: f64, cx: f64, cy: f64, rc: f64, depth: f64, rim: f64) -> f64 {
    let q = (x - cx).hypot(y - cy) / rc;
    if q < 1.0 {
        -depth + (depth + rim) * q * q
    } else {
        rim * (-((q - 1.0) / 0.3).powi(2)).exp()
    }
}

/// A repeatable pseudo-random number in [0, 1) for pixel (x, y).
fn hash01(x: usize, y: usize, seed: u64) -> f64 {
    let mut h = (x as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
        .wrapping_add(seed.wrapping_mul(0x1656_67B1_9E37_79F9));
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

// ------------------------------------------------------------------------------------------
// 1. Bare sphere
// ------------------------------------------------------------------------------------------

/// Heights all equal to the body's lowest terrain (or above it): the horizon is the local
/// horizontal, 0° (the observer's own zero-distance slope is 0 and the sphere falls away), so
/// the lit fraction of a sun at elevation e and radius r is the circular segment
/// `segment_fraction(−e/r)`: ½ at 0°, 0 from −r down to the nadir, 1 from r up to the zenith,
/// the exact partial disc between. The reference's Exact disc model is within 1e-3 of it (its
/// own documented accuracy); the dp forms use the segment itself over the exact near field, so
/// they are exact to rounding (1e-9). Uniform has no near field: its first sample, ds ≤ 23/100
/// px (4.6 m) out, lies 4.6/(2R) rad ≈ 8e-5° below the horizontal, which the floor hides when
/// the body's lowest terrain is the observer's (floor 0°) and which otherwise moves the lit
/// fraction by ≤ 8e-5°/r × 2/π ≈ 2e-4 (1e-3 allowed). With the body's lowest terrain 2 km below
/// (floor −2.75°) a sun at −1° is still hidden by the local horizontal, not by the floor.
#[test]
fn bare_sphere_is_the_disc_segment() {
    let s = face_pixels(MOON_R, 20.0);
    let els = [
        -89.9, -30.0, -1.0, -0.2, -0.1, 0.0, 0.1, 0.2, SUN_R, 1.0, 10.0, 45.0, 89.9, 90.0,
    ];
    for (face, u, v) in [
        (Face::Px, 0.0, 0.0),
        (Face::Nz, 0.3, -0.5),
        (Face::Py, 0.9, 0.6),
    ] {
        for (h, tmin) in [(0.0, 0.0), (0.0, -2000.0), (500.0, 500.0)] {
            let ctx = build(face, MOON_R, s, origin_at(s, u, v, 8, 8), 16, 16, |_, _| h);
            let tr = Tracer::new(&ctx, tmin);
            for (x, y) in [(8, 8), (3, 12)] {
                for phi in [0.0, 1.0, 1.9, 4.0] {
                    for el in els {
                        let label = format!(
                            "{face} ({u}, {v}) h {h} min {tmin} ({x}, {y}) φ {phi} el {el}"
                        );
                        let sun = sun_toward(&tr, x, y, phi, el, SUN_R);
                        let got = trace_all(&tr, x, y, &sun, &label);
                        check_known(&got, 0.0, el, SUN_R, 1e-3, 1e-9, -1e-4, &[], &label);
                        // A point sun: 1 above, 0 below.
                        if el != 0.0 {
                            let sun = sun_toward(&tr, x, y, phi, el, 0.0);
                            let got = trace_all(&tr, x, y, &sun, &label);
                            check_known(&got, 0.0, el, 0.0, 0.0, 0.0, -1e-4, &[], &label);
                        }
                    }
                }
            }
            // The sun exactly at the zenith and the nadir.
            let f = frame(&ctx, 8, 8);
            for (dir, want) in [(f.up, 1.0), (lin(-1.0, f.up, 0.0, f.up), 0.0)] {
                let sun = Sun {
                    dir,
                    radius_deg: SUN_R,
                };
                let got = trace_all(&tr, 8, 8, &sun, "zenith/nadir");
                for (i, t) in got.iter().enumerate() {
                    assert!(
                        (t.lit - want).abs() <= 1e-3,
                        "{face}: {} with the sun at {} reads {}",
                        labels()[i],
                        if want == 1.0 {
                            "the zenith"
                        } else {
                            "the nadir"
                        },
                        t.lit
                    );
                }
            }
        }
    }
}

// ------------------------------------------------------------------------------------------
// 2. A vertical cliff
// ------------------------------------------------------------------------------------------

/// A step: H = 100 m for x ≥ 120, 0 before (20 m pixels, the Moon), so along a row the
/// bilinear profile is flat, one ramp cell up to the top edge at x = 120, flat on top. Seen
/// from the ground d pixels in front, the elevation climbs the ramp (slope 5 ≫ H/d) and falls
/// across the top (h/s decreases), so the horizon straight over the cliff is the top edge's
/// elevation e_c = atan((cos ψ·(R+H) − R)/(sin ψ·(R+H))), ψ the angle to the top edge. Across
/// the disc (±r in azimuth) the wall is farther by 1/cos β − 1 ≤ 1e-5: the horizon is constant.
/// One pixel ahead the ramp starts at the observer and h/s along it is constant while the
/// horizontal distance at the ramp's height grows by h/R, so the elevation falls along the
/// ramp: the horizon is its zero-distance limit, atan(H/g) with g the ground metres per pixel
/// at the observer (5.8e-5 relative above e_c there: 6.5e-4°). With the sun at e_c + k·r
/// (e_c: that horizon) the lit fraction is `segment_fraction(−k)`:
/// - the reference within 2e-3 (the Exact model's 1e-3, and 1e-3 for its 7 azimuths);
/// - the dp forms, which search the chosen finest cell exactly and whose nearest top texel
///   bounds highest, within 1e-6 of it and (as asked) within 0.05 of the reference — except
///   dp 5,5,5, whose three runs of 16 px reach 49.5 px only, for the cliff 110 px away;
/// - uniform, whose 100 samples out to where the disc's bottom leaves the terrain (at most the
///   raster's edge: steps ds ≤ (191 − x0)/100 px) have one on the top within ds beyond the
///   edge whenever they reach the cliff: its lit fraction lies between the segments of e_c and
///   of the top's elevation at d + ds (when they stop short of the cliff, the disc's bottom is
///   above the top and both segments are 1);
/// - extrema: lit exactly when the centre is above e_c.
///
/// Point suns 1e-4° above and below e_c decide exactly (the reference, dp and extrema). With
/// the disc centred on e_c (so that no search stops early: they stop once the disc is known
/// hidden or whole) the horizon the reference and the dp forms report is e_c (1e-5°: the
/// reference reports it in f32).
///
/// On the top, 5 px back, looking away and back: the local horizontal, as on a bare sphere
/// (uniform's first sample, ≤ 125/100 px = 25 m out, lies ≤ 25/(2R) rad = 4e-4° below it).
/// On the top edge looking down: the ground inside the raster stays below the dip of the
/// sphere of the lowest terrain seen from 100 m (−0.59°, 18.6 km away, far outside), so the
/// horizon is that floor: lit = segment_fraction((dip − e)/r).
#[test]
fn cliff_top_edge_decides() {
    let (xc, hc) = (120usize, 100.0);
    let s = face_pixels(MOON_R, 20.0);
    let (w, h, y0) = (192, 16, 8);
    let ctx = build(
        Face::Px,
        MOON_R,
        s,
        origin_at(s, 0.01, 0.02, 96, 8),
        w,
        h,
        |x, _| if x >= xc { hc } else { 0.0 },
    );
    let tr = Tracer::new(&ctx, 0.0);
    let mut worst = [0.0f64; N_METHODS];
    for d in [1usize, 2, 5, 20, 45, 110] {
        let x0 = xc - d;
        let mut ec = elevation_to(&ctx, x0, y0, xc as f64, y0 as f64, hc);
        if d == 1 {
            let eps = 1e-4;
            let g = MOON_R
                * angle_between(
                    ctx.dir(x0 as f64, y0 as f64),
                    ctx.dir(x0 as f64 + eps, y0 as f64),
                )
                / eps;
            ec = (hc / g).atan().to_degrees();
        }
        let skip: &[usize] = if d > 45 { &[DP555] } else { &[] };
        for k in [-2.0, -1.0, -0.5, -0.2, 0.0, 0.2, 0.5, 1.0, 2.0] {
            let el = ec + k * SUN_R;
            let label = format!("cliff {d} px ahead (e_c {ec:.4}°), sun at e_c {k:+} r");
            let sun = sun_toward(&tr, x0, y0, 0.0, el, SUN_R);
            let got = trace_all(&tr, x0, y0, &sun, &label);
            let ds = (w - 1 - x0) as f64 / 100.0;
            let e_lo = elevation_to(&ctx, x0, y0, xc as f64 + ds, y0 as f64, hc);
            check_known(&got, ec, el, SUN_R, 2e-3, 1e-6, e_lo, skip, &label);
            let want = segment_fraction(-k);
            for i in 0..N_METHODS {
                if i != EXTREMA && !skip.contains(&i) {
                    worst[i] = worst[i].max((got[i].lit - want).abs());
                }
            }
            for i in EXACT_SOFT {
                if !skip.contains(&i) {
                    assert!(
                        (got[i].lit - got[REF].lit).abs() <= 0.05,
                        "{label}: {} {} vs reference {}",
                        labels()[i],
                        got[i].lit,
                        got[REF].lit
                    );
                }
            }
        }
        for delta in [-1e-4, 1e-4] {
            let label = format!("cliff {d} px ahead, point sun at e_c {delta:+}°");
            let sun = sun_toward(&tr, x0, y0, 0.0, ec + delta, 0.0);
            let got = trace_all(&tr, x0, y0, &sun, &label);
            let want = if delta > 0.0 { 1.0 } else { 0.0 };
            for i in [REF, DP, DP555, DDA, EXTREMA, SMAP] {
                if !skip.contains(&i) {
                    assert_eq!(got[i].lit, want, "{label}: {}", labels()[i]);
                }
            }
        }
        let sun = sun_toward(&tr, x0, y0, 0.0, ec, SUN_R);
        let got = trace_all(&tr, x0, y0, &sun, "cliff");
        for i in [REF, DP, DP555, DDA] {
            if !skip.contains(&i) {
                assert!(
                    (got[i].horizon_deg - ec).abs() <= 1e-5,
                    "cliff {d} px ahead: {} finds the horizon at {}°, the top edge is at {ec}°",
                    labels()[i],
                    got[i].horizon_deg
                );
            }
        }
    }
    let names = labels();
    eprintln!(
        "cliff: worst |lit − segment| {}",
        (0..EXTREMA)
            .map(|i| format!("{} {:.2e}", names[i], worst[i]))
            .collect::<Vec<_>>()
            .join(", ")
    );
    // On the top, looking away from the edge and back over it: the local horizontal.
    for phi in [0.0, PI] {
        for el in [-0.5, -0.1, 0.0, 0.1, 0.5] {
            let label = format!("on the top 5 px back, φ {phi}, el {el}");
            let sun = sun_toward(&tr, xc + 5, y0, phi, el, SUN_R);
            let got = trace_all(&tr, xc + 5, y0, &sun, &label);
            check_known(&got, 0.0, el, SUN_R, 1e-3, 1e-9, -1e-3, &[], &label);
        }
    }
    // On the top edge looking down: the floor.
    let dip = dip_deg(MOON_R, hc);
    for k in [-2.0, -0.5, 0.0, 0.5, 2.0] {
        let el = dip + k * SUN_R;
        let label = format!("on the top edge looking down, sun at dip {k:+} r");
        let sun = sun_toward(&tr, xc, y0, PI, el, SUN_R);
        let got = trace_all(&tr, xc, y0, &sun, &label);
        check_known(&got, dip, el, SUN_R, 1e-3, 1e-6, dip, &[], &label);
    }
}

// ------------------------------------------------------------------------------------------
// 3. A one-pixel spike on the sun's ray and just off it
// ------------------------------------------------------------------------------------------

/// One pixel H = 50 m high at (25, 16) on flat ground (20 m pixels), the observer at (5, 16),
/// 20 px (400 m) away; the bilinear surface is a tent 2 px wide.
/// - On the ray (φ = 0, along the row): the horizon is the tip's elevation e_s. Point suns
///   1e-4° above and below it decide exactly (the reference, the dp forms and extrema). With
///   the disc centred on e_s (no search stops early) the reference and dp report e_s (1e-5°).
///   Uniform's samples land within ds/2 of the tip, ds ≤ 59/100 px, on a tent that falls H
///   per pixel: its horizon lies between e_s and the elevation of H(1 − ds/2) at 20 + ds/2 px.
///   With the Sun's disc: across it (±r) the ray passes ≤ 20·tan r = 0.093 px off the tip,
///   where the tent still stands ≥ 0.9 H (≈ 0.9 e_s), so a disc below 0.85·e_s is hidden, one
///   whose bottom is above e_s is whole.
/// - Half a pixel off (the ray through (25, 16.5), φ = −atan(0.5/20)): along it the tent rises
///   to 0.5 H at x = 25 and falls after, faster than h/s on both sides, so the horizon is that
///   kink's elevation: point suns 1e-4° either side decide.
/// - A whole pixel off (the spike at (25, 17), the ray along row 16): the tent is 0 on the ray,
///   the horizon is the local horizontal: point suns at ±0.01° decide, and the reference and dp
///   report 0° — though every pyramid texel the ray crosses there holds the spike.
#[test]
fn one_pixel_spike_on_and_off_the_ray() {
    let s = face_pixels(MOON_R, 20.0);
    let (w, h, hs) = (64, 32, 50.0);
    let (x0, y0) = (5usize, 16usize);
    let names = labels();
    let spiked = |sx: usize, sy: usize| {
        build(
            Face::Px,
            MOON_R,
            s,
            origin_at(s, -0.03, 0.05, 32, 16),
            w,
            h,
            move |x, y| if (x, y) == (sx, sy) { hs } else { 0.0 },
        )
    };
    // On the ray.
    let ctx = spiked(25, 16);
    let tr = Tracer::new(&ctx, 0.0);
    let es = elevation_to(&ctx, x0, y0, 25.0, 16.0, hs);
    for delta in [-1e-4, 1e-4] {
        let label = format!("spike on the ray, point sun at e_s {delta:+}°");
        let got = trace_all(
            &tr,
            x0,
            y0,
            &sun_toward(&tr, x0, y0, 0.0, es + delta, 0.0),
            &label,
        );
        let want = if delta > 0.0 { 1.0 } else { 0.0 };
        for i in [REF, DP, DP555, DDA, EXTREMA, SMAP] {
            assert_eq!(got[i].lit, want, "{label}: {}", names[i]);
        }
    }
    let got = trace_all(
        &tr,
        x0,
        y0,
        &sun_toward(&tr, x0, y0, 0.0, es, SUN_R),
        "spike",
    );
    for i in [REF, DP, DP555, DDA] {
        assert!(
            (got[i].horizon_deg - es).abs() <= 1e-5,
            "spike on the ray: {} horizon {} vs the tip {es}",
            names[i],
            got[i].horizon_deg
        );
    }
    let ds = 59.0 / 100.0;
    let low = elevation_to(&ctx, x0, y0, 25.0 + ds / 2.0, 16.0, hs * (1.0 - ds / 2.0));
    let u = got[UNIFORM].horizon_deg;
    eprintln!("spike on the ray: tip {es:.4}°, uniform {u:.4}° (≥ {low:.4}°)");
    assert!(
        u >= low - 1e-9 && u <= es + 1e-9,
        "spike on the ray: uniform horizon {u} outside [{low}, {es}]"
    );
    for (el, want) in [(es + 2.0 * SUN_R + 0.01, 1.0), (0.85 * es - SUN_R, 0.0)] {
        let label = format!("spike on the ray, the Sun at {el:.3}° (tip {es:.3}°)");
        let got = trace_all(
            &tr,
            x0,
            y0,
            &sun_toward(&tr, x0, y0, 0.0, el, SUN_R),
            &label,
        );
        for i in [REF, DP, DP555, DDA, EXTREMA, SMAP] {
            assert!(
                (got[i].lit - want).abs() <= 1e-3,
                "{label}: {} {}",
                names[i],
                got[i].lit
            );
        }
    }
    // Half a pixel off.
    let phi = -(0.5f64).atan2(20.0);
    let ek = elevation_to(&ctx, x0, y0, 25.0, 16.5, 0.5 * hs);
    for delta in [-1e-4, 1e-4] {
        let label = format!("spike half a pixel off the ray, point sun at the kink {delta:+}°");
        let got = trace_all(
            &tr,
            x0,
            y0,
            &sun_toward(&tr, x0, y0, phi, ek + delta, 0.0),
            &label,
        );
        let want = if delta > 0.0 { 1.0 } else { 0.0 };
        for i in [REF, DP, DP555, DDA, EXTREMA, SMAP] {
            assert_eq!(got[i].lit, want, "{label}: {}", names[i]);
        }
    }
    // A whole pixel off.
    let ctx = spiked(25, 17);
    let tr = Tracer::new(&ctx, 0.0);
    for el in [-0.01, 0.01] {
        let label = format!("spike a pixel off the ray, point sun at {el}°");
        let got = trace_all(&tr, x0, y0, &sun_toward(&tr, x0, y0, 0.0, el, 0.0), &label);
        check_known(&got, 0.0, el, 0.0, 0.0, 0.0, -1e-4, &[], &label);
    }
    let got = trace_all(
        &tr,
        x0,
        y0,
        &sun_toward(&tr, x0, y0, 0.0, 0.0, SUN_R),
        "spike",
    );
    for i in [REF, DP, DP555, DDA] {
        assert!(
            got[i].horizon_deg.abs() <= 1e-9,
            "spike a pixel off the ray: {} horizon {}",
            names[i],
            got[i].horizon_deg
        );
    }
}

// ------------------------------------------------------------------------------------------
// 4. Rays exactly along grid axes and diagonals
// ------------------------------------------------------------------------------------------

/// A crater raster (n × n, 20 m pixels, on face px) with the sun exactly along ±U, ±V or a
/// diagonal ±U ± V of the face's plane: a direction d in the U–V plane has no part along the
/// face normal, so its plane azimuth at every pixel is exactly atan2(d·V, d·U) (docs/horizons
/// .md's formula) — every ray of the raster runs exactly along a row, a column, or through
/// the texel corners of every level, the cases of the cell walk's ties. The raster is centred
/// at (u, v) = tan e·(d·U, d·V), where the sun's elevation is e. The crater: radius 16 px,
/// bowl 150 m deep, rim 40 m, so its walls shadow their floors at e = 5°.
fn axis_case(a: f64, b: f64, el: f64) -> (Context, Sun) {
    let s = face_pixels(MOON_R, 20.0);
    let n = 96;
    let t = el.to_radians().tan();
    let ctx = build(
        Face::Px,
        MOON_R,
        s,
        origin_at(s, t * a, t * b, n / 2, n / 2),
        n,
        n,
        |x, y| {
            let c = (n / 2) as f64;
            crater(x as f64, y as f64, c, c, 16.0, 150.0, 40.0)
        },
    );
    let (_, ua, va) = Face::Px.axes();
    let sun = Sun {
        dir: lin(a, ua, b, va),
        radius_deg: SUN_R,
    };
    (ctx, sun)
}

/// Over the 48 × 48 block around the crater (every third pixel), for each of the 8
/// directions: every method finite and in range, and the block bounds (`assert_block`: dp auto
/// within 0.05 mean |lit − reference|, extrema's decisions within 1 % of the reference's). And
/// the walk's ties are harmless: turning the sun by 1e-7 rad off the axis moves each ray
/// ≤ 1e-5 px over the raster, so the horizon
/// the reference reports (exact, continuous in the azimuth) may move by the terrain's slope ×
/// 1e-5 px over the 20 m pixels ≈ 1e-5°, and its lit fraction by less than 1e-3 (1e-4° of
/// horizon is ≤ 3e-4 of the disc): an on-line walk that took the wrong cell, or skipped one,
/// would show as a jump of a whole pixel's relief.
#[test]
fn rays_along_grid_axes_and_diagonals() {
    let h = FRAC_1_SQRT_2;
    let cases = [
        ("+U", 1.0, 0.0, 0.0),
        ("+V", 0.0, 1.0, FRAC_PI_2),
        ("-U", -1.0, 0.0, PI),
        ("-V", 0.0, -1.0, 3.0 * FRAC_PI_2),
        ("+U+V", h, h, FRAC_PI_4),
        ("-U+V", -h, h, 3.0 * FRAC_PI_4),
        ("-U-V", -h, -h, 5.0 * FRAC_PI_4),
        ("+U-V", h, -h, 7.0 * FRAC_PI_4),
    ];
    // Every third pixel: rows and columns of both parities (even ones lie on texel edges).
    let pts = block(24, 24, 48, 3);
    let mut all = Cmp::default();
    for (name, a, b, phi) in cases {
        let (ctx, sun) = axis_case(a, b, 5.0);
        let tr = Tracer::new(&ctx, 0.0);
        for &(x, y) in &pts {
            let at = tr.sun_at(x, y, &sun);
            let dphi = (at.phi - phi).rem_euclid(TAU);
            assert!(
                dphi.min(TAU - dphi) < 1e-15,
                "{name}: plane azimuth {} at ({x}, {y}), want {phi}",
                at.phi
            );
            if a == 0.0 || b == 0.0 {
                // Along an axis the minor step is below the walk's 1e-12 threshold.
                assert!(at.phi.cos().abs().min(at.phi.sin().abs()) < 1e-12);
            }
            assert!(
                (at.elevation_deg - 5.0).abs() < 0.1,
                "{name}: {}",
                at.elevation_deg
            );
        }
        let c = compare(&tr, &pts, &sun, name);
        c.print(&format!("crater, sun exactly along {name} at 5°"));
        assert_block(&c, name);
        all.merge(&c);
        // The same sun turned 1e-7 rad off the axis: the reference barely moves.
        let eps: f64 = 1e-7;
        let (_, ua, va) = Face::Px.axes();
        let (ae, be) = (a * eps.cos() - b * eps.sin(), a * eps.sin() + b * eps.cos());
        let turned = Sun {
            dir: lin(ae, ua, be, va),
            radius_deg: SUN_R,
        };
        let (mut dh, mut dl) = (0.0f64, 0.0f64);
        for &(x, y) in &pts {
            let r0 = tr.trace(x, y, &sun, &Method::Reference, &mut Work::default());
            let r1 = tr.trace(x, y, &turned, &Method::Reference, &mut Work::default());
            dh = dh.max((r0.horizon_deg - r1.horizon_deg).abs());
            dl = dl.max((r0.lit - r1.lit).abs());
        }
        eprintln!(
            "{name}: turned by 1e-7 rad, reference horizon moves ≤ {dh:.2e}°, lit ≤ {dl:.2e}"
        );
        assert!(
            dh <= 1e-4 && dl <= 1e-3,
            "{name}: turned 1e-7 rad, horizon moves {dh}°, lit {dl}"
        );
    }
    all.print("crater, all 8 axis and diagonal suns");
}

// ------------------------------------------------------------------------------------------
// 5. Raster, face and cube edges
// ------------------------------------------------------------------------------------------

/// Bare rasters straddling face px's u = −1 edge and its (u, v) = (−1, 1) corner (origins
/// negative: the raster reaches past the face on its extended gnomonic plane, where the heights
/// are simply given). Observers exactly on face pixel 0 (column, and row and column at the
/// corner; the face-edge one is on row S/2, the boundary of a two-tile split too: a tile's
/// edge is no edge of its context raster, which has the margin around the tile), one pixel
/// beyond the face, and on the raster's own edge and corner (where rays leave the raster at
/// once and near-field neighbours are missing): in 8 azimuths (the axes, the diagonals) and 3
/// more, each reads the bare-sphere answer (as in the bare-sphere test).
/// Then a 50 m spike 20 px from an observer with the face edge (and the cube corner, along the
/// diagonal) between them: point suns 1e-4° either side of the tip's exact elevation decide.
#[test]
fn face_edge_and_cube_corner() {
    let s = face_pixels(MOON_R, 20.0);
    let mid = s as i64 / 2;
    let edge_o = (-20, mid - 20);
    let corner_o = (-20, -20);
    let names = labels();
    for (what, o, obs) in [
        (
            "face edge",
            edge_o,
            vec![(20usize, 20usize), (19, 20), (0, 20), (39, 39)],
        ),
        (
            "cube corner",
            corner_o,
            vec![(20, 20), (19, 19), (0, 0), (39, 0)],
        ),
    ] {
        let ctx = build(Face::Px, MOON_R, s, o, 40, 40, |_, _| 0.0);
        let (u, v) = ctx.uv(20.0, 20.0);
        assert!(
            (u + 1.0 - 1.0 / s).abs() < 1e-12,
            "{what}: pixel 0 is at u {u}"
        );
        if what == "cube corner" {
            assert!(
                (v - 1.0 + 1.0 / s).abs() < 1e-12,
                "{what}: pixel 0 is at v {v}"
            );
        }
        let tr = Tracer::new(&ctx, 0.0);
        let phis: Vec<f64> = (0..8)
            .map(|k| k as f64 * FRAC_PI_4)
            .chain([0.3, 2.0, 4.4])
            .collect();
        for &(x, y) in &obs {
            for &phi in &phis {
                for el in [-1.0, -0.1, 0.0, 0.1, 1.0, 30.0] {
                    let label = format!("{what} ({x}, {y}) φ {phi:.3} el {el}");
                    let sun = sun_toward(&tr, x, y, phi, el, SUN_R);
                    let got = trace_all(&tr, x, y, &sun, &label);
                    check_known(&got, 0.0, el, SUN_R, 1e-3, 1e-9, -1e-4, &[], &label);
                }
            }
        }
    }
    // A spike across the face edge, and across the corner along the diagonal.
    let hs = 50.0;
    for (what, o, (x0, y0), (sx, sy), phi) in [
        (
            "face edge",
            edge_o,
            (10usize, 20usize),
            (30usize, 20usize),
            0.0,
        ),
        ("cube corner", corner_o, (10, 10), (30, 30), 7.0 * FRAC_PI_4),
    ] {
        let ctx = build(Face::Px, MOON_R, s, o, 40, 40, |x, y| {
            if (x, y) == (sx, sy) {
                hs
            } else {
                0.0
            }
        });
        let tr = Tracer::new(&ctx, 0.0);
        let es = elevation_to(&ctx, x0, y0, sx as f64, sy as f64, hs);
        for delta in [-1e-4, 1e-4] {
            let label = format!("spike across the {what}, point sun at e_s {delta:+}°");
            let got = trace_all(
                &tr,
                x0,
                y0,
                &sun_toward(&tr, x0, y0, phi, es + delta, 0.0),
                &label,
            );
            let want = if delta > 0.0 { 1.0 } else { 0.0 };
            for i in [REF, DP, DP555, DDA, EXTREMA, SMAP] {
                assert_eq!(got[i].lit, want, "{label} ({es:.4}°): {}", names[i]);
            }
        }
    }
}

/// Rays exactly along the raster's own first and last rows and columns (observers on the
/// raster's edge, as on a tile's edge when its context has no margin left), towards a 100 m
/// cliff 20 px ahead (20 m pixels): the top edge's elevation e_c decides point suns 0.01°
/// either side, for the reference, the dp forms and extrema, as from a row in the middle.
/// (Along a row or column the plane direction's minor part is cos or sin of a multiple of π/2:
/// ±1e-16, which on the first row or column puts the ray a rounding error outside the raster,
/// and on the last one the ray lies on the far edge of the last texels.)
#[test]
fn rays_along_the_raster_edges() {
    let s = face_pixels(MOON_R, 20.0);
    let hc = 100.0;
    let names = labels();
    let (long, short) = (64usize, 16usize);
    // (along x?, cliff towards +?, plane azimuth)
    for (along_x, forward, phi) in [
        (true, true, 0.0),
        (true, false, PI),
        (false, false, FRAC_PI_2),
        (false, true, 3.0 * FRAC_PI_2),
    ] {
        let (w, h) = if along_x {
            (long, short)
        } else {
            (short, long)
        };
        let cliff = move |t: usize| if forward { t >= 40 } else { t <= 23 };
        let ctx = build(
            Face::Px,
            MOON_R,
            s,
            origin_at(s, 0.01, 0.02, w / 2, h / 2),
            w,
            h,
            |x, y| {
                if cliff(if along_x { x } else { y }) {
                    hc
                } else {
                    0.0
                }
            },
        );
        let tr = Tracer::new(&ctx, 0.0);
        let (t0, tc) = if forward {
            (20usize, 40usize)
        } else {
            (43, 23)
        };
        for across in [0usize, short / 2, short - 1] {
            let (x0, y0, xt, yt) = if along_x {
                (t0, across, tc as f64, across as f64)
            } else {
                (across, t0, across as f64, tc as f64)
            };
            let ec = elevation_to(&ctx, x0, y0, xt, yt, hc);
            for delta in [-0.01, 0.01] {
                let label = format!(
                    "ray along {} {across} (φ {phi:.4}), cliff top at {ec:.4}°, point sun {delta:+}°",
                    if along_x { "row" } else { "column" }
                );
                let sun = sun_toward(&tr, x0, y0, phi, ec + delta, 0.0);
                let got = trace_all(&tr, x0, y0, &sun, &label);
                let want = if delta > 0.0 { 1.0 } else { 0.0 };
                for i in [REF, DP, DP555, DDA, EXTREMA, SMAP] {
                    assert_eq!(got[i].lit, want, "{label}: {}", names[i]);
                }
            }
        }
    }
}

// ------------------------------------------------------------------------------------------
// 6. The pole
// ------------------------------------------------------------------------------------------

/// Face pz (normal +Z) with an odd S, so that the north pole is the centre of face pixel
/// ((S−1)/2, (S−1)/2), here raster pixel (48, 48) of 97 × 97. The local frame there is the
/// documented limit (north = −X); suns from 8 compass azimuths.
/// - Bare: the disc segment, as in the bare-sphere test.
/// - A crater centred on the pole (radius 20 px, bowl 150 m deep, rim 40 m), the observer at
///   its bottom: in each sun's plane azimuth the brute-force horizon (the raster's bilinear
///   surface along the great circle, written here) is the rim's elevation, ≈ 25°. Point suns
///   0.01° either side decide for the reference and extrema (the brute force is within 1e-4°
///   of the truth). With the Sun's disc at that horizon + k·r the reference's lit fraction
///   lies between the segments of the lowest and the highest brute-force horizon across the
///   disc's azimuths (the pixelated rim's horizon varies by a few 0.01° there), within 2e-3 +
///   the bend of the 25° almucantar; uniform and extrema see the centre's. The dp forms keep one
///   texel per level, the one whose maximum could rise highest, which here is often a nearer
///   texel holding rim the ray does not cross: they may miss the rim (Jung et al.'s
///   approximation; the count is printed), but whatever they report is the elevation of terrain
///   on the ray, so never above the true horizon (1e-4°), and they are never darker than it.
#[test]
fn north_pole() {
    let s = face_pixels(MOON_R, 20.0) + 1.0;
    assert_eq!(s as i64 % 2, 1);
    let (n, c) = (97usize, 48usize);
    let o = ((s as i64 - 1) / 2 - c as i64, (s as i64 - 1) / 2 - c as i64);
    let names = labels();
    let bare = build(Face::Pz, MOON_R, s, o, n, n, |_, _| 0.0);
    assert!(angle_between(bare.dir(c as f64, c as f64), [0.0, 0.0, 1.0]) < 1e-15);
    let f = frame(&bare, c, c);
    assert_eq!(f.north, [-1.0, 0.0, 0.0]);
    let tr = Tracer::new(&bare, 0.0);
    for k in 0..8 {
        let az = 45.0 * k as f64;
        for el in [-1.0, -0.1, 0.0, 0.1, 5.0] {
            let label = format!("bare pole, az {az} el {el}");
            let sun = Sun {
                dir: f.direction(az, el),
                radius_deg: SUN_R,
            };
            let got = trace_all(&tr, c, c, &sun, &label);
            check_known(&got, 0.0, el, SUN_R, 1e-3, 1e-9, -1e-4, &[], &label);
        }
    }
    let ctx = build(Face::Pz, MOON_R, s, o, n, n, |x, y| {
        crater(x as f64, y as f64, c as f64, c as f64, 20.0, 150.0, 40.0)
    });
    let tr = Tracer::new(&ctx, 0.0);
    let mut spread = (f64::INFINITY, f64::NEG_INFINITY);
    let mut dp_right = [0usize; N_METHODS];
    let mut across = 0.0f64;
    for k in 0..8 {
        let az = 45.0 * k as f64 + 10.0;
        let phi = tr
            .sun_at(
                c,
                c,
                &Sun {
                    dir: f.direction(az, 10.0),
                    radius_deg: SUN_R,
                },
            )
            .phi;
        let e = brute_horizon(&ctx, c, c, phi);
        spread = (spread.0.min(e), spread.1.max(e));
        for delta in [-0.01, 0.01] {
            let label = format!("crater at the pole, az {az}: point sun at {e:.4}° {delta:+}°");
            let sun = Sun {
                dir: f.direction(az, e + delta),
                radius_deg: 0.0,
            };
            let got = trace_all(&tr, c, c, &sun, &label);
            let want = if delta > 0.0 { 1.0 } else { 0.0 };
            for i in [REF, EXTREMA] {
                assert_eq!(got[i].lit, want, "{label}: {}", names[i]);
            }
            // The SMap answers from the beam nearest the pixel, up to half a pixel beside its
            // ray; the bilinear surface's rim (a crease between pixel centres, faceted) varies
            // there by up to a couple of metres, which is 0.1–0.2° at 400 m: decided 0.3°
            // either side.
            let sun = Sun {
                dir: f.direction(az, e + 30.0 * delta),
                radius_deg: 0.0,
            };
            assert_eq!(smap_lit(&tr, c, c, &sun), want, "{label}, ×30: smap");
            for i in [DP, DP555, DDA] {
                assert!(got[i].lit >= want, "{label}: {} darker", names[i]);
                dp_right[i] += (got[i].lit == want) as usize;
            }
        }
        for kr in [-1.5, -0.5, 0.0, 0.5, 1.5] {
            let el = e + kr * SUN_R;
            let label = format!("crater at the pole, az {az}: the Sun at {e:.4}° {kr:+} r");
            let sun = Sun {
                dir: f.direction(az, el),
                radius_deg: SUN_R,
            };
            let got = trace_all(&tr, c, c, &sun, &label);
            check_known(
                &got,
                e,
                el,
                SUN_R,
                0.0,
                0.0,
                e - 1.0,
                &[REF, DP, DP555, DDA],
                &label,
            );
            // The horizon across the disc: its plane azimuths span ±r/cos(el) about the
            // centre's (the plane azimuth at the pole is the compass one turned).
            let span = 1.05 * SUN_R.to_radians() / el.to_radians().cos();
            let (lo, hi) = (-4..=4)
                .map(|j| brute_horizon(&ctx, c, c, phi + span * j as f64 / 4.0))
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), h| {
                    (a.min(h), b.max(h))
                });
            across = across.max(hi - lo);
            let tol = 2e-3 + 2.0 / PI * SUN_R / (2.0 * (90.0 - e));
            let r = got[REF].lit;
            assert!(
                r >= segment_lit(hi, el, SUN_R) - tol && r <= segment_lit(lo, el, SUN_R) + tol,
                "{label}: reference {r}, horizon across the disc {lo:.4}°..{hi:.4}°"
            );
            for i in [DP, DP555, DDA] {
                assert!(
                    got[i].horizon_deg <= e + 1e-4
                        && got[i].lit >= segment_lit(e + 1e-4, el, SUN_R) - 1e-9,
                    "{label}: {} reports the horizon at {}° (lit {})",
                    names[i],
                    got[i].horizon_deg,
                    got[i].lit
                );
            }
        }
    }
    eprintln!(
        "crater at the pole: rim horizon {:.4}°..{:.4}°, across a disc ≤ {across:.4}°; point suns decided right of 16: dp auto {}, dp 5,5,5 {}, dp-dda {}",
        spread.0, spread.1, dp_right[DP], dp_right[DP555], dp_right[DDA]
    );
}

// ------------------------------------------------------------------------------------------
// 7. A 10 km body
// ------------------------------------------------------------------------------------------

/// A 10 km body (5 m pixels, 96² raster spanning 2.7° of arc, so the sun's elevation changes by
/// as much across it and the sphere drops 11 m over its half-width): a crater (radius 16 px,
/// bowl 40 m deep, rim 20 m), a cone 80 m high and ±2.5 m of noise — about 125 m of relief.
/// Over a 64² block (every second pixel) for suns at 2°, 10° and 30° from 8 azimuths (at the
/// block's centre): no NaN anywhere, every value in range, extrema's hard decisions agree with
/// the reference's (lit ≥ ½) on ≥ 99 % of the pixels, and the soft methods' mean
/// |lit − reference| is ≤ 0.05 (`assert_block`). dp's own decisions (lit ≥ ½) are held to 95 % only: it keeps one texel per level,
/// the one whose maximum could rise highest, and on a crater's ring that is often a texel whose
/// high rim lies beside the ray, so it misses the rim that shadows the pixel (≈ 4 % of the
/// decisions here; a branch-and-bound over every candidate texel instead agrees with the
/// reference to 1e-4 mean: the misses are that greedy choice, not the geometry).
#[test]
fn ten_km_body() {
    let r = 10_000.0;
    let s = face_pixels(r, 5.0);
    let n = 96;
    let ctx = build(
        Face::Nx,
        r,
        s,
        origin_at(s, 0.15, -0.2, n / 2, n / 2),
        n,
        n,
        |x, y| {
            let (x, y) = (x as f64, y as f64);
            let cone = 80.0 * (1.0 - (x - 70.0).hypot(y - 30.0) / 12.0).max(0.0);
            crater(x, y, 40.0, 52.0, 16.0, 40.0, 20.0)
                + cone
                + 5.0 * (hash01(x as usize, y as usize, 7) - 0.5)
        },
    );
    let tr = Tracer::new(&ctx, 0.0);
    let f = frame(&ctx, n / 2, n / 2);
    let pts = block(16, 16, 64, 2);
    let mut all = Cmp::default();
    for el in [2.0, 10.0, 30.0] {
        let mut c = Cmp::default();
        for k in 0..8 {
            let sun = Sun {
                dir: f.direction(45.0 * k as f64 + 20.0, el),
                radius_deg: SUN_R,
            };
            c.merge(&compare(
                &tr,
                &pts,
                &sun,
                &format!("10 km body, el {el}, az {k}"),
            ));
        }
        c.print(&format!("10 km body, sun at {el}°"));
        all.merge(&c);
    }
    all.print("10 km body, all suns");
    assert_block(&all, "10 km body");
    assert!(all.per(DP) <= 0.05, "dp auto PER {}", all.per(DP));
}

// ------------------------------------------------------------------------------------------
// 8. Voids
// ------------------------------------------------------------------------------------------

/// No data (NaN) is no terrain: it hides nothing, and an observer on it has no answer.
/// - A bare raster with holes: a 5-column band across every row, the observer's own
///   neighbour along the ray (so its zero-distance slope has no data), everything beyond the
///   observer on one row, and 10 % of the other pixels at random: the bare-sphere answer from
///   observers next to them, in 4 azimuths.
/// - An observer on no data: NaN from every method.
/// - The cliff of test 2 (100 m, 20 px ahead) behind a 6-column band of no data: its top edge
///   still decides exactly (point suns 1e-4° either side), and with the Sun's disc the lit
///   fractions are the cliff's.
/// - A crater block with 3 % of its pixels missing: no-data observers NaN in every method, all
///   others finite, within the block bounds (`assert_block`).
#[test]
fn voids_hide_nothing() {
    let s = face_pixels(MOON_R, 20.0);
    let (w, h) = (64usize, 32usize);
    let o = origin_at(s, 0.1, 0.1, 32, 16);
    let hole = |x: usize, y: usize| {
        (20..25).contains(&x)
            || (x, y) == (6, 16)
            || (y == 8 && x > 5)
            || ((x, y) != (5, 16) && (x, y) != (5, 8) && hash01(x, y, 3) < 0.1)
    };
    let ctx = build(Face::Px, MOON_R, s, o, w, h, |x, y| {
        if hole(x, y) {
            f64::NAN
        } else {
            0.0
        }
    });
    let tr = Tracer::new(&ctx, 0.0);
    for (x, y) in [(5usize, 16usize), (5, 8)] {
        for phi in [0.0, 0.3, PI, 4.0] {
            for el in [-0.1, 0.0, 0.1, 1.0] {
                let label = format!("bare with holes ({x}, {y}) φ {phi} el {el}");
                let got = trace_all(&tr, x, y, &sun_toward(&tr, x, y, phi, el, SUN_R), &label);
                check_known(&got, 0.0, el, SUN_R, 1e-3, 1e-9, -1e-4, &[], &label);
            }
        }
    }
    let sun = sun_toward(&tr, 5, 16, 0.0, 1.0, SUN_R);
    for m in methods() {
        let t = tr.trace(22, 16, &sun, &m, &mut Work::default());
        assert!(
            t.lit.is_nan() && t.horizon_deg.is_nan(),
            "{} over no data: {t:?}",
            m.label()
        );
    }
    // The cliff behind a band of no data.
    let (xc, hc, x0, y0) = (40usize, 100.0, 20usize, 16usize);
    let ctx = build(Face::Px, MOON_R, s, o, w, h, |x, _| {
        if (27..33).contains(&x) {
            f64::NAN
        } else if x >= xc {
            hc
        } else {
            0.0
        }
    });
    let tr = Tracer::new(&ctx, 0.0);
    let ec = elevation_to(&ctx, x0, y0, xc as f64, y0 as f64, hc);
    for delta in [-1e-4, 1e-4] {
        let label = format!("cliff behind no data, point sun at e_c {delta:+}°");
        let got = trace_all(
            &tr,
            x0,
            y0,
            &sun_toward(&tr, x0, y0, 0.0, ec + delta, 0.0),
            &label,
        );
        let want = if delta > 0.0 { 1.0 } else { 0.0 };
        for i in [REF, DP, DP555, DDA, EXTREMA, SMAP] {
            assert_eq!(got[i].lit, want, "{label}: {}", labels()[i]);
        }
    }
    for k in [-1.0, -0.5, 0.5, 1.0] {
        let el = ec + k * SUN_R;
        let label = format!("cliff behind no data, the Sun at e_c {k:+} r");
        let got = trace_all(
            &tr,
            x0,
            y0,
            &sun_toward(&tr, x0, y0, 0.0, el, SUN_R),
            &label,
        );
        let ds = (w - 1 - x0) as f64 / 100.0;
        let e_lo = elevation_to(&ctx, x0, y0, xc as f64 + ds, y0 as f64, hc);
        check_known(&got, ec, el, SUN_R, 2e-3, 1e-6, e_lo, &[], &label);
    }
    // A crater block with holes.
    let n = 96;
    let ctx = build(
        Face::Px,
        MOON_R,
        s,
        origin_at(s, -0.2, 0.3, n / 2, n / 2),
        n,
        n,
        |x, y| {
            if hash01(x, y, 11) < 0.03 {
                f64::NAN
            } else {
                crater(x as f64, y as f64, 48.0, 48.0, 16.0, 150.0, 40.0)
            }
        },
    );
    let tr = Tracer::new(&ctx, 0.0);
    let f = frame(&ctx, n / 2, n / 2);
    let pts = block(24, 24, 48, 3);
    let mut c = Cmp::default();
    for (az, el) in [(30.0, 5.0), (150.0, 10.0), (260.0, 2.0)] {
        let sun = Sun {
            dir: f.direction(az, el),
            radius_deg: SUN_R,
        };
        c.merge(&compare(&tr, &pts, &sun, "crater with holes"));
    }
    c.print("crater with 3 % holes");
    assert_block(&c, "crater with holes");
}

// ------------------------------------------------------------------------------------------
// 9. A crater block against the reference
// ------------------------------------------------------------------------------------------

/// The issue's acceptance check on an analytic crater (radius 16 px = 320 m, bowl 150 m deep,
/// rim 40 m; 20 m pixels, face px off-centre): over a 48² block (every third pixel) for suns
/// at 1°, 5°, 15° and 45° from 8 azimuths, dp auto's mean |lit − reference| ≤ 0.05 and
/// extrema's decisions (vs the reference's lit ≥ ½) differ on ≤ 1 % of the pixels, at each
/// elevation (`assert_block`, which holds the other soft methods to 0.05 mean as well).
#[test]
fn crater_block_against_the_reference() {
    let s = face_pixels(MOON_R, 20.0);
    let n = 160;
    let c0 = (n / 2) as f64;
    let ctx = build(
        Face::Px,
        MOON_R,
        s,
        origin_at(s, 0.2, -0.1, n / 2, n / 2),
        n,
        n,
        |x, y| crater(x as f64, y as f64, c0, c0, 16.0, 150.0, 40.0),
    );
    let tr = Tracer::new(&ctx, 0.0);
    let f = frame(&ctx, n / 2, n / 2);
    let pts = block(n / 2 - 24, n / 2 - 24, 48, 3);
    for el in [1.0, 5.0, 15.0, 45.0] {
        let mut c = Cmp::default();
        for k in 0..8 {
            let sun = Sun {
                dir: f.direction(45.0 * k as f64 + 7.0, el),
                radius_deg: SUN_R,
            };
            c.merge(&compare(&tr, &pts, &sun, &format!("crater el {el} az {k}")));
        }
        c.print(&format!("crater block, sun at {el}°"));
        assert_block(&c, &format!("crater block, sun at {el}°"));
    }
}

/// Issue 40, point 4: Jung et al.'s DP keeps one texel per level, so where a texel beside the
/// ray holds the higher maximum it follows that texel and misses the terrain on the ray. Here a
/// 300 m spike stands one row beside a ray along +U (the ray runs exactly on its row's edge, so
/// it adds nothing on the ray) in the level-3 texel after the one holding a 30 m wall across
/// the ray, both in DP's second run: the plain DP (`dp-jung auto`) chooses the side spike's
/// texel and sees the sun whole; `dp auto` refines the texel it passed over and finds the
/// wall's exact elevation, as the reference does, with the sun's centre on it (lit ½).
#[test]
fn dp_refines_the_texel_a_rim_beside_the_ray_hid() {
    let s = face_pixels(MOON_R, 20.0);
    let (w, h) = (64, 32);
    let (x0, y0) = (8usize, 16usize);
    let ctx = build(
        Face::Px,
        MOON_R,
        s,
        origin_at(s, -0.03, 0.05, 32, 16),
        w,
        h,
        |x, y| match (x, y) {
            (36, 4..=28) => 30.0,
            (42, 17) => 300.0,
            _ => 0.0,
        },
    );
    let tr = Tracer::new(&ctx, 0.0);
    let es = elevation_to(&ctx, x0, y0, 36.0, 16.0, 30.0);
    let sun = sun_toward(&tr, x0, y0, 0.0, es, SUN_R);
    let mut work = Work::default();
    let reference = tr.trace(x0, y0, &sun, &Method::Reference, &mut work);
    let dp = tr.trace(
        x0,
        y0,
        &sun,
        &Method::Dp {
            runs: Runs::Auto,
            dda: false,
        },
        &mut work,
    );
    let jung = tr.trace(
        x0,
        y0,
        &sun,
        &Method::JungDp {
            runs: Runs::Auto,
            dda: false,
        },
        &mut work,
    );
    println!(
        "wall at {es:.4}°: reference lit {:.4} (horizon {:.4}°), dp auto {:.4} ({:.4}°), \
         dp-jung auto {:.4} ({:.4}°)",
        reference.lit, reference.horizon_deg, dp.lit, dp.horizon_deg, jung.lit, jung.horizon_deg
    );
    // The reference's exact disc over the wall's horizon (which dips off the ray's azimuth)
    // differs from the prism model's ½ by 0.045.
    assert!((reference.lit - 0.5).abs() < 0.06, "{reference:?}");
    assert!(
        (dp.horizon_deg - es).abs() < 1e-6,
        "dp horizon {dp:?} vs {es}"
    );
    assert!((dp.lit - 0.5).abs() < 1e-3, "{dp:?}");
    // The case is one the plain DP gets wrong (else the test shows nothing).
    assert!(jung.lit > 0.99 && jung.horizon_deg < es - 1.0, "{jung:?}");
}

/// The penumbra of the crater (suns within 3° of each point's exact horizon, the shadow
/// bench's criterion), over the suns of `crater_block_against_the_reference` and more
/// elevations near the rim's: the refined `dp auto` at most half the plain DP's mean |error| and
/// no worse than uniform 100 (issue 40's acceptance, here on an analytic crater).
#[test]
fn dp_in_the_crater_penumbra() {
    let s = face_pixels(MOON_R, 20.0);
    let n = 160;
    let c0 = (n / 2) as f64;
    let ctx = build(
        Face::Px,
        MOON_R,
        s,
        origin_at(s, 0.2, -0.1, n / 2, n / 2),
        n,
        n,
        |x, y| crater(x as f64, y as f64, c0, c0, 16.0, 150.0, 40.0),
    );
    let tr = Tracer::new(&ctx, 0.0);
    let f = frame(&ctx, n / 2, n / 2);
    let pts = block(n / 2 - 24, n / 2 - 24, 48, 2);
    let ms = [
        Method::Dp {
            runs: Runs::Auto,
            dda: false,
        },
        Method::JungDp {
            runs: Runs::Auto,
            dda: false,
        },
        Method::Uniform { steps: 100 },
    ];
    let (mut err, mut count) = ([0.0f64; 3], 0usize);
    let mut work = Work::default();
    for el in [1.0, 3.0, 5.0, 8.0, 12.0, 15.0] {
        for k in 0..8 {
            let sun = Sun {
                dir: f.direction(45.0 * k as f64 + 7.0, el),
                radius_deg: SUN_R,
            };
            for &(x, y) in &pts {
                let (e, hz) = tr.band_horizon(x, y, &sun, 3.0);
                if (e - hz).abs() > 3.0 {
                    continue;
                }
                count += 1;
                let r = tr.lit(x, y, &sun, &Method::Reference, &mut work);
                for (m, e) in ms.iter().zip(err.iter_mut()) {
                    *e += (tr.lit(x, y, &sun, m, &mut work) - r).abs();
                }
            }
        }
    }
    let mean: Vec<f64> = err.iter().map(|e| e / count as f64).collect();
    println!(
        "crater penumbra, {count} pairs: dp auto {:.4}, dp-jung auto {:.4}, uniform 100 {:.4}",
        mean[0], mean[1], mean[2]
    );
    assert!(count >= 200, "{count} penumbral pairs");
    assert!(mean[0] <= 0.5 * mean[1], "{mean:?}");
    assert!(mean[0] <= mean[2], "{mean:?}");
}
