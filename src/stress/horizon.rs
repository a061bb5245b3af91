//! Horizon cases: the four horizon methods (reference, exact, fast, sweep) against exact
//! spherical geometry, and against themselves over another rectangle at a tile seam.

use crate::cube::Face;
use crate::horizon::{plane_azimuth, Context, Method, Rect};

use super::geometry::*;
use super::types::{Case, Row, Size, Weaken};

pub(super) fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "flat-sphere",
            area: "horizon",
            about: "bare sphere (h = 0) on the Moon: every horizon is 0°",
            run: flat_sphere,
        },
        Case {
            name: "spike-1px",
            area: "horizon",
            about: "observer on a 1-px spike: the geometric dip −acos(R/(R+H)) in every azimuth",
            run: spike_1px,
        },
        Case {
            name: "vertical-cliff",
            area: "horizon",
            about: "a 300 m step between two columns: from its foot the top edge's elevation, \
                    from its top edge the raster's far edge, looking away 0°",
            run: vertical_cliff,
        },
        Case {
            name: "axes-diagonals",
            area: "horizon",
            about: "a cone seen along the 4 axes and 4 diagonals: the apex's elevation",
            run: axes_diagonals,
        },
        Case {
            name: "cube-corner",
            area: "horizon",
            about: "a raster over face px's corner (u, v) = (1, 1): bare sphere 0°, a spike on \
                    the corner pixel sees the dip",
            run: cube_corner,
        },
        Case {
            name: "north-pole",
            area: "horizon",
            about: "face pz with the pole on a pixel centre: bare sphere 0°, the dip from a spike \
                    on the pole",
            run: north_pole,
        },
        Case {
            name: "ten-km-body",
            area: "horizon",
            about: "a body of radius 10 km: bare sphere 0°, a 500 m spike's dip of −17.6°",
            run: ten_km_body,
        },
        Case {
            name: "jupiter-sphere",
            area: "horizon",
            about: "a sphere of Jupiter's radius (71 492 km): bare sphere 0°, a 16 m spike's dip",
            run: jupiter_sphere,
        },
        Case {
            name: "mars-relief-f16",
            area: "horizon",
            about: "Mars relief (−8.3 to +21 km) with heights rounded to f16: f16 within half an \
                    ulp, horizons against the f32 heights', fast against reference",
            run: mars_relief_f16,
        },
        Case {
            name: "voids-nan",
            area: "horizon",
            about: "bare sphere with NaN holes: voids are no terrain, every observer with data \
                    reads 0°, none NaN",
            run: voids_nan,
        },
        Case {
            name: "constant-tile",
            area: "horizon",
            about: "a tile at a constant 1234.5 m: every horizon is 0°",
            run: constant_tile,
        },
        Case {
            name: "tile-seam",
            area: "horizon",
            about: "a rough raster's horizons over four quadrant tiles against one rectangle: the \
                    same value on both sides of every tile seam",
            run: tile_seam,
        },
        Case {
            name: "face-seam",
            area: "horizon",
            about: "a spike one side of face px's edge seen along a row from the other: the \
                    spike's top elevation",
            run: face_seam,
        },
    ]
}

/// Rows of a bare (or constant-height) raster: every method's largest |horizon| over `rect`.
fn zero_rows(ctx: &Context, rect: Rect, a: usize, weaken: Weaken, what: &str) -> Vec<Row> {
    HORIZON_METHODS
        .iter()
        .map(|&m| {
            let out = horizons(ctx, rect, a, m, weaken);
            let e: Vec<f64> = out.iter().map(|&v| (v as f64).abs()).collect();
            // Float noise only: the zero-distance slope is 0 and everything else lies below.
            Row::of(format!("{what} {}", m.name()), "deg", &e, 1e-6)
        })
        .collect()
}

/// The dip rows of an observer on a spike at (c, c) of a square raster: every method in `a`
/// azimuths against −acos(R/(R+H)); each method's bound from `bounds`.
fn dip_rows(ctx: &Context, c: usize, a: usize, weaken: Weaken, bounds: [f64; 4]) -> Vec<Row> {
    let want = dip_deg(ctx.radius_m, ctx.at(c as i64, c as i64) as f64);
    HORIZON_METHODS
        .iter()
        .zip(bounds)
        .map(|(&m, b)| {
            let out = horizons(ctx, pixel(c, c), a, m, weaken);
            let e: Vec<f64> = out.iter().map(|&v| (v as f64 - want).abs()).collect();
            Row::of(format!("spike dip {}", m.name()), "deg", &e, b).note(format!("dip {want:.5}°"))
        })
        .collect()
}

/// A bare raster of `n`² with a spike of `hs` m on its centre pixel.
fn spike_raster(face: Face, r: f64, s: f64, origin: (i64, i64), n: usize, hs: f64) -> Context {
    let c = n / 2;
    build(face, r, s, origin, (n, n), |x, y| {
        if (x, y) == (c, c) {
            hs
        } else {
            0.0
        }
    })
}

fn interior(n: usize) -> Rect {
    Rect {
        x0: 1,
        y0: 1,
        w: n - 2,
        h: n - 2,
    }
}

fn flat_sphere(_: Size, weaken: Weaken) -> Vec<Row> {
    let s = face_pixels(MOON_R, 20.0);
    let ctx = build(Face::Px, MOON_R, s, centred(s, 40, 40), (40, 40), |_, _| {
        0.0
    });
    zero_rows(&ctx, interior(40), 12, weaken, "bare")
}

fn spike_1px(_: Size, weaken: Weaken) -> Vec<Row> {
    // R = 50 km, 10 m pixels, H = 2 m: dip 0.51°, tangent distance √(2RH) ≈ 45 px < 64.
    let (r, n) = (50_000.0, 128);
    let s = face_pixels(r, 10.0);
    let ctx = spike_raster(Face::Px, r, s, centred(s, n, n), n, 2.0);
    dip_rows(&ctx, n / 2, 16, weaken, [1e-6, 1e-6, 1e-6, 7e-5])
}

fn vertical_cliff(_: Size, weaken: Weaken) -> Vec<Row> {
    // Moon, 20 m pixels; 0 m west of column 60, 300 m from it on: the step is as vertical as a
    // raster's bilinear surface gets (one pixel).
    let (n, xc, hc) = (96usize, 60usize, 300.0);
    let s = face_pixels(MOON_R, 20.0);
    let ctx = build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, _| {
        if x >= xc {
            hc
        } else {
            0.0
        }
    });
    let a = 8;
    let y = n / 2;
    let mut rows = Vec::new();
    for m in HORIZON_METHODS {
        let (mut foot, mut away, mut top) = (Vec::new(), Vec::new(), Vec::new());
        // From the foot (any distance) toward the cliff (k = 0): the highest point of the
        // one-pixel ramp (x = 59 + t, height t·H), which is its top edge from afar; from the
        // ramp's own foot (x0 = 59) the ramp points all lie on one line from the observer and
        // curvature lowers the farther ones, so the answer is the limit t → 0, atan(H/Δ) in
        // the local frame: the maximum over t = 1e-9 and t = 1/1000 … 1 (the plateau beyond is
        // farther and lower). Looking away (k = 4): the bare sphere's 0°.
        for x0 in [20usize, 40, 52, 57, 59] {
            let out = horizons(&ctx, pixel(x0, y), a, m, weaken);
            let ramp = |t: f64| elevation_to(&ctx, x0, y, xc as f64 - 1.0 + t, y as f64, t * hc);
            let want = (1..=1000)
                .map(|i| ramp(i as f64 / 1000.0))
                .fold(ramp(1e-9), f64::max);
            foot.push((out[0] as f64 - want).abs());
            away.push((out[4] as f64).abs());
        }
        // From the top edge looking off the cliff (k = 4): the plain below rises toward the
        // tangent point 32 km off, beyond the raster: its far edge (x = 0) is the horizon.
        let out = horizons(&ctx, pixel(xc, y), a, m, weaken);
        let want = elevation_to(&ctx, xc, y, 0.0, y as f64, 0.0);
        top.push((out[4] as f64 - want).abs());
        rows.push(Row::of(
            format!("foot → cliff {}", m.name()),
            "deg",
            &foot,
            // ½ ulp of f32 at 86° is 3.8e-6°, which is what every method measures: twice it.
            8e-6,
        ));
        rows.push(Row::of(
            format!("foot, away {}", m.name()),
            "deg",
            &away,
            1e-6,
        ));
        rows.push(
            Row::of(
                format!("top edge → far plain {}", m.name()),
                "deg",
                &top,
                1e-6,
            )
            .note(format!("{want:.4}°")),
        );
    }
    rows
}

fn axes_diagonals(_: Size, weaken: Weaken) -> Vec<Row> {
    // A cone 1500 m high, 1000 m in base radius (50 px of 20 m) on the Moon; observers 60 px
    // from the apex along the axes and diagonals, outside the base: the apex is the highest
    // point seen (each flank point is lower and nearer by a slope Hc/B above the apex's).
    let (n, c, a) = (128usize, 64usize, 8usize);
    let (hc, base_m) = (1500.0f64, 1000.0f64);
    let s = face_pixels(MOON_R, 20.0);
    let ctx = build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, y| {
        let apex = (c as f64, c as f64);
        let d = crate::cube::angle_between(
            // Ground distance on the sphere, metres.
            raster_dir(s, centred(s, n, n), x as f64, y as f64),
            raster_dir(s, centred(s, n, n), apex.0, apex.1),
        ) * MOON_R;
        hc * (1.0 - d / base_m).max(0.0)
    });
    let d = 120usize;
    let mut rows = Vec::new();
    // Measured: axes 6.0e-7° by every method; diagonals 1.6e-6 (reference, exact), 6.5e-6
    // (fast), 2.5e-6 (sweep).
    for (m, diag_bound) in HORIZON_METHODS.into_iter().zip([4e-6, 4e-6, 1.3e-5, 5e-6]) {
        let (mut axes, mut diag) = (Vec::new(), Vec::new());
        for (dx, dy) in AXES_AND_DIAGONALS {
            let (x0, y0) = (
                (c as i64 - dx * d as i64 / 2) as usize,
                (c as i64 - dy * d as i64 / 2) as usize,
            );
            let phi = azimuth_of(dx as f64, dy as f64);
            let k = (phi / plane_azimuth(1, a)).round() as usize % a;
            let out = horizons(&ctx, pixel(x0, y0), a, m, weaken);
            let want = elevation_to(&ctx, x0, y0, c as f64, c as f64, hc);
            let e = (out[k] as f64 - want).abs();
            if dx == 0 || dy == 0 {
                axes.push(e);
            } else {
                diag.push(e);
            }
        }
        // Along an axis the apex pixel centre is sampled itself: float accuracy. Along a
        // diagonal the ½-px samples may miss it by ¼ px, where the bilinear cone is lower by
        // √2·(Hc/B)·¼ px ≈ 10 m out of 1500 (≤ 0.1° at 85 px); the methods do far better, and
        // the bounds are twice what they do.
        rows.push(Row::of(format!("axes {}", m.name()), "deg", &axes, 2e-6));
        rows.push(Row::of(
            format!("diagonals {}", m.name()),
            "deg",
            &diag,
            diag_bound,
        ));
    }
    rows
}

/// Unit direction of raster pixel (x, y) of a px raster of `s` face pixels at `origin`.
fn raster_dir(s: f64, origin: (i64, i64), x: f64, y: f64) -> crate::cube::Vec3 {
    let probe = Context {
        face: Face::Px,
        face_pixels: s,
        origin,
        width: 1,
        height: 1,
        heights: Vec::new(),
        radius_m: 1.0,
    };
    probe.dir(x, y)
}

fn cube_corner(_: Size, weaken: Weaken) -> Vec<Row> {
    // R = 50 km, 30 m pixels at the face centre (≈ 14 m at the corner, where the gnomonic
    // grid is ≈ 0.47× as fine): the 2 m spike's tangent distance, 447 m ≈ 32 px, stays inside.
    // The raster's centre pixel (64, 64) is face px's corner pixel (S − 1, 0): the raster
    // reaches past both edges onto the extended gnomonic plane.
    let (r, n) = (50_000.0, 128usize);
    let s = face_pixels(r, 30.0);
    let si = s as i64;
    let o = (si - 1 - 64, -64);
    let mut rows = zero_rows(
        &build(Face::Px, r, s, o, (n, n), |_, _| 0.0),
        Rect {
            x0: 44,
            y0: 44,
            w: 40,
            h: 40,
        },
        12,
        weaken,
        "bare",
    );
    let ctx = spike_raster(Face::Px, r, s, o, n, 2.0);
    rows.extend(dip_rows(&ctx, n / 2, 16, weaken, [3e-5, 4e-5, 4e-5, 1e-4]));
    rows
}

fn north_pole(_: Size, weaken: Weaken) -> Vec<Row> {
    // R = 50 km, ≈ 10 m pixels, odd S: the pole is the centre of pixel 63 of 127.
    let r = 50_000.0;
    let s = face_pixels(r, 10.0) + 1.0;
    let n = 127usize;
    let o = ((s as i64 - 1) / 2 - 63, (s as i64 - 1) / 2 - 63);
    let mut rows = zero_rows(
        &build(Face::Pz, r, s, o, (n, n), |_, _| 0.0),
        Rect {
            x0: 43,
            y0: 43,
            w: 40,
            h: 40,
        },
        12,
        weaken,
        "bare",
    );
    let ctx = spike_raster(Face::Pz, r, s, o, n, 2.0);
    rows.extend(dip_rows(&ctx, 63, 16, weaken, [1e-6, 1e-6, 1e-6, 7e-5]));
    rows
}

fn ten_km_body(_: Size, weaken: Weaken) -> Vec<Row> {
    // R = 10 km, 50 m pixels, a 500 m spike: dip −17.6°, tangent 3.2 km = 63 px < 80.
    bare_then_spike(10_000.0, 50.0, 161, 500.0, weaken, [4e-5, 8e-4, 8e-4, 8e-4])
}

fn jupiter_sphere(_: Size, weaken: Weaken) -> Vec<Row> {
    // 1 km pixels, a 16 m spike: tangent √(2RH) ≈ 48 km = 48 px < 64.
    bare_then_spike(
        JUPITER_R,
        1000.0,
        128,
        16.0,
        weaken,
        [1e-6, 1e-6, 1e-6, 2e-6],
    )
}

/// A body of radius `r` in an `n`² raster of `pixel_m` pixels: the bare sphere reads 0
/// everywhere, and from a `spike_m` spike at the centre every method sees the geometric dip
/// (bounds per method, as [`dip_rows`] takes them).
fn bare_then_spike(
    r: f64,
    pixel_m: f64,
    n: usize,
    spike_m: f64,
    weaken: Weaken,
    bounds: [f64; 4],
) -> Vec<Row> {
    let s = face_pixels(r, pixel_m);
    let o = centred(s, n, n);
    let mut rows = zero_rows(
        &build(Face::Px, r, s, o, (n, n), |_, _| 0.0),
        interior(n),
        12,
        weaken,
        "bare",
    );
    let ctx = spike_raster(Face::Px, r, s, o, n, spike_m);
    rows.extend(dip_rows(&ctx, n / 2, 16, weaken, bounds));
    rows
}

/// Mars relief: a 21 km dome and a −8.3 km basin (Olympus Mons and Hellas in height) with
/// value noise, 1 km pixels.
fn mars_relief(n: usize) -> Context {
    let s = face_pixels(MARS_R, 1000.0);
    let o = centred(s, n, n);
    let dome = raster_dir(s, o, 0.3 * n as f64, 0.5 * n as f64);
    let basin = raster_dir(s, o, 0.75 * n as f64, 0.5 * n as f64);
    build(Face::Py, MARS_R, s, o, (n, n), |x, y| {
        let d = raster_dir(s, o, x as f64, y as f64);
        let gd = MARS_R * crate::cube::angle_between(d, dome) / 30_000.0;
        let gb = MARS_R * crate::cube::angle_between(d, basin) / 25_000.0;
        let noise = 150.0 * value_noise(x as f64, y as f64, 16.0, 7)
            + 40.0 * value_noise(x as f64, y as f64, 4.0, 8);
        21_000.0 * (-gd * gd).exp() - 8_300.0 * (-gb * gb).exp() + noise
    })
}

fn mars_relief_f16(_: Size, weaken: Weaken) -> Vec<Row> {
    let n = 96usize;
    let ctx = mars_relief(n);
    let mut half_ctx = ctx.clone();
    let mut ulps = Vec::new();
    let mut nonfinite = 0;
    for v in half_ctx.heights.iter_mut() {
        let h = half::f16::from_f32(*v);
        if !h.is_finite() {
            nonfinite += 1;
        }
        // One ulp of f16 at |v|: 2^(⌊log2 |v|⌋ − 10) (normal range), 2^−24 below 2^−14.
        let ulp = (v.abs() as f64).log2().floor().max(-14.0).exp2() / 1024.0;
        ulps.push((h.to_f32() as f64 - *v as f64).abs() / ulp);
        *v = h.to_f32();
    }
    let rect = Rect {
        x0: 8,
        y0: 24,
        w: 80,
        h: 48,
    };
    let a = 16;
    let r32 = horizons(&ctx, rect, a, Method::Reference, weaken);
    let r16 = horizons(&half_ctx, rect, a, Method::Reference, weaken);
    let f16 = horizons(&half_ctx, rect, a, Method::Fast, weaken);
    let rms = |a: &[f32], b: &[f32]| {
        let s: f64 = a
            .iter()
            .zip(b)
            .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
            .sum();
        (s / a.len() as f64).sqrt()
    };
    let bad = |v: &[f32]| v.iter().filter(|x| !x.is_finite()).count();
    vec![
        // Round to nearest: at most half an ulp (21 km: ulp 16 m).
        Row::of("f16 heights", "ulp", &ulps, 0.5).nonfinite(nonfinite),
        // Two heights each moved by ≤ ½ ulp (8 m above 16384 m) seen ≥ ½ px (500 m) apart
        // along a ray: atan(16 / 500).
        Row::new(
            "reference, f16 vs f32 heights",
            "deg",
            max_abs_diff(&r16, &r32),
            (16.0f64 / 500.0).atan().to_degrees(),
        )
        .nonfinite(bad(&r16) + bad(&r32))
        .note("atan(16 m / 500 m)"),
        // Twice the 4.6e-6° measured (the goal for the fast method is 0.05°).
        Row::new("fast vs reference rms, f16", "deg", rms(&f16, &r16), 1e-5).nonfinite(bad(&f16)),
    ]
}

fn voids_nan(_: Size, weaken: Weaken) -> Vec<Row> {
    // A 10 × 15 px void and scattered void pixels (5 %), all ≥ 4 px inside the raster.
    let n = 64usize;
    let s = face_pixels(MOON_R, 20.0);
    let void = |x: usize, y: usize| {
        (20..30).contains(&x) && (25..40).contains(&y)
            || (4..n - 4).contains(&x) && (4..n - 4).contains(&y) && hash01(x, y, 3) < 0.05
    };
    let ctx = build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, y| {
        if void(x, y) {
            f64::NAN
        } else {
            0.0
        }
    });
    let a = 12;
    let rect = Rect {
        x0: 2,
        y0: 2,
        w: n - 4,
        h: n - 4,
    };
    // Looking across a void where nothing rises beyond: the flat ground beyond it, at most
    // (chord + 1 px)·Δ/(2R) below 0, the longest chord being the block's diagonal √(10² + 15²)
    // px (the continuous answer is ≈ 0; a method that skips the fringe in the observer's first
    // cell sees the ground beyond the void first).
    let pixel_m = 2.0 * MOON_R / s;
    let chord = (10.0f64.hypot(15.0) + 1.0) * pixel_m;
    let across = (chord / (2.0 * MOON_R)).to_degrees();
    let mut rows = Vec::new();
    for m in HORIZON_METHODS {
        let out = horizons(&ctx, rect, a, m, weaken);
        let plane = rect.w * rect.h;
        let (mut e, mut not_nan) = (Vec::new(), 0usize);
        for k in 0..a {
            for i in 0..plane {
                let (x, y) = (rect.x0 + i % rect.w, rect.y0 + i / rect.w);
                let v = out[k * plane + i];
                if !void(x, y) {
                    e.push((v as f64).abs());
                } else if !v.is_nan() {
                    not_nan += 1;
                }
            }
        }
        rows.push(
            Row::of(
                format!("observers with data {}", m.name()),
                "deg",
                &e,
                across,
            )
            .note("(chord + 1 px)·Δ/(2R)"),
        );
        rows.push(Row::new(
            format!("void observers not NaN {}", m.name()),
            "count",
            not_nan as f64,
            0.0,
        ));
    }
    rows
}

fn constant_tile(_: Size, weaken: Weaken) -> Vec<Row> {
    let n = 48usize;
    let s = face_pixels(MOON_R, 20.0);
    let ctx = build(Face::Nz, MOON_R, s, centred(s, n, n), (n, n), |_, _| 1234.5);
    let mut rows = zero_rows(&ctx, interior(n), 12, weaken, "constant");
    rows.extend(super::tiles::constant_mip_rows(1234.5));
    rows
}

fn tile_seam(_: Size, weaken: Weaken) -> Vec<Row> {
    let n = 96usize;
    let s = face_pixels(MOON_R, 20.0);
    let ctx = build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, y| {
        400.0 * value_noise(x as f64, y as f64, 24.0, 11)
            + 60.0 * value_noise(x as f64, y as f64, 5.0, 12)
    });
    let a = 16;
    // The 64² block at (16, 16) whole, and as four 32² tiles.
    let whole = Rect {
        x0: 16,
        y0: 16,
        w: 64,
        h: 64,
    };
    HORIZON_METHODS
        .iter()
        .map(|&m| {
            let one = horizons(&ctx, whole, a, m, weaken);
            let mut e = Vec::new();
            for (tx, ty) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let t = Rect {
                    x0: 16 + 32 * tx,
                    y0: 16 + 32 * ty,
                    w: 32,
                    h: 32,
                };
                let part = horizons(&ctx, t, a, m, weaken);
                for k in 0..a {
                    for j in 0..32 {
                        for i in 0..32 {
                            let p = part[k * 1024 + j * 32 + i];
                            let q = one[k * 4096 + (32 * ty + j) * 64 + 32 * tx + i];
                            e.push(if p.is_finite() && q.is_finite() {
                                (p as f64 - q as f64).abs()
                            } else {
                                f64::NAN
                            });
                        }
                    }
                }
            }
            Row::of(format!("tiles vs whole {}", m.name()), "deg", &e, 1e-6)
        })
        .collect()
}

fn face_seam(_: Size, weaken: Weaken) -> Vec<Row> {
    // Face px, 20 m pixels; the raster's column 48 is the first beyond the face's u = 1 edge.
    // A 100 m spike at column 58 (10 px past the edge), observers on the face 10 and 20 px
    // from the edge on the same row: along a row every method samples the spike's centre.
    let (n, a) = (96usize, 8usize);
    let s = face_pixels(MOON_R, 20.0);
    let o = (s as i64 - 48, centred(s, n, n).1);
    let (sx, sy, hs) = (58usize, 48usize, 100.0);
    let ctx = build(Face::Px, MOON_R, s, o, (n, n), |x, y| {
        if (x, y) == (sx, sy) {
            hs
        } else {
            0.0
        }
    });
    // Measured 7.4e-7° (reference, exact), 4.0e-6 (fast), 1.2e-6 (sweep): bounds twice that.
    HORIZON_METHODS
        .into_iter()
        .zip([2e-6, 2e-6, 8e-6, 3e-6])
        .map(|(m, bound)| {
            let e: Vec<f64> = [38usize, 28]
                .iter()
                .map(|&x0| {
                    let out = horizons(&ctx, pixel(x0, sy), a, m, weaken);
                    let want = elevation_to(&ctx, x0, sy, sx as f64, sy as f64, hs);
                    (out[0] as f64 - want).abs()
                })
                .collect();
            Row::of(format!("across the edge {}", m.name()), "deg", &e, bound)
        })
        .collect()
}
