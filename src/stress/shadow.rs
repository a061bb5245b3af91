//! Shadow cases: the ray-marching methods (`shadow::trace`) and the horizon lookup's disc
//! models (`fourier::sun::lit_fraction`) with the sun at and below the horizon, overhead, and
//! grazing texel edges, axes and diagonals, on small and huge bodies and over voids.

use crate::cube::Face;
use crate::fourier::sun::{lit_fraction, segment_fraction, Model, Sun};
use crate::horizon::Context;
use crate::shadow::trace::{Method, Tracer};

use super::geometry::*;
use super::types::{Case, Row, Size, Weaken};

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

pub(super) fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "sun-at-0",
            area: "shadow",
            about: "bare sphere, the sun's centre at 0° and ±r/2: the disc's segment above 0° \
                    (½ at 0°)",
            run: sun_at_0,
        },
        Case {
            name: "sun-below-0",
            area: "shadow",
            about: "bare sphere, the sun at −r (its top on the horizon), −1°, −45°, −90°: lit 0",
            run: sun_below_0,
        },
        Case {
            name: "sun-at-90",
            area: "shadow",
            about: "the sun overhead over a vertical cliff (86° from its foot): lit 1",
            run: sun_at_90,
        },
        Case {
            name: "grazing-texel-edges",
            area: "shadow",
            about: "point suns along the 4 axes, rays on the texel edge beside a 300 m wall \
                    (lit 1), and ±1e-4° about a spike's tip (lit 1 / 0)",
            run: grazing_texel_edges,
        },
        Case {
            name: "shadow-axes-diagonals",
            area: "shadow",
            about: "a 100 m spike 20 px off along the axes and diagonals: the horizon found is \
                    the tip's elevation",
            run: shadow_axes_diagonals,
        },
        Case {
            name: "shadow-small-and-huge-bodies",
            area: "shadow",
            about: "from a spike on a 10 km body and on a Jupiter-size sphere, the sun's centre \
                    at the dip: horizon = dip, lit ½",
            run: small_and_huge,
        },
        Case {
            name: "shadow-voids",
            area: "shadow",
            about: "bare sphere with NaN holes, the sun at 0.1°: every observer with data lit as \
                    the bare sphere, none NaN",
            run: shadow_voids,
        },
    ]
}

fn bare(n: usize, face: Face) -> Context {
    let s = face_pixels(MOON_R, 20.0);
    build(face, MOON_R, s, centred(s, n, n), (n, n), |_, _| 0.0)
}

/// The horizon lookup's lit fraction for a horizon constant at `alpha` degrees.
fn lookup(ctx: &Context, x: usize, y: usize, sun: &Sun, m: Model, alpha: f64, w: Weaken) -> f64 {
    lit_fraction(&frame(ctx, x, y), &sun_for(*sun, w), m, &|_| alpha)
}

/// Rows comparing every soft method and the lookup's exact and segment models with the
/// answer `want(el)` over `suns` = (x, y, phi, el) on `ctx` (horizon `alpha` for the lookup);
/// `bounds` in that order (reference, dp, dp-dda, extrema-soft, lookup exact, segment).
fn lit_rows(
    ctx: &Context,
    suns: &[(usize, usize, f64, f64)],
    want: &dyn Fn(f64) -> f64,
    alpha: f64,
    bounds: [f64; 6],
    weaken: Weaken,
) -> Vec<Row> {
    let tr = Tracer::new(ctx, 0.0);
    let mut rows: Vec<Row> = soft_methods()
        .iter()
        .zip(bounds)
        .map(|(m, bound)| {
            let e: Vec<f64> = suns
                .iter()
                .map(|&(x, y, phi, el)| {
                    let sun = sun_toward(ctx, x, y, phi, el, SUN_R);
                    (trace(&tr, x, y, &sun, m, weaken).0 - want(el)).abs()
                })
                .collect();
            Row::of(format!("lit {}", m.label()), "lit", &e, bound)
        })
        .collect();
    for (model, bound) in [(Model::Exact, bounds[4]), (Model::Segment, bounds[5])] {
        let e: Vec<f64> = suns
            .iter()
            .map(|&(x, y, phi, el)| {
                let sun = sun_toward(ctx, x, y, phi, el, SUN_R);
                (lookup(ctx, x, y, &sun, model, alpha, weaken) - want(el)).abs()
            })
            .collect();
        rows.push(Row::of(
            format!("lit lookup {}", model.name()),
            "lit",
            &e,
            bound,
        ));
    }
    rows
}

/// Observers and sun azimuths: an axis, a diagonal and an oblique one, at three pixels.
fn spots(n: usize) -> Vec<(usize, usize, f64)> {
    let mut v = Vec::new();
    for (x, y) in [(n / 2, n / 2), (n / 5, 4 * n / 5), (4 * n / 5, n / 5)] {
        for phi in [0.0, FRAC_PI_4, FRAC_PI_2 + 0.3, PI + 1.0] {
            v.push((x, y, phi));
        }
    }
    v
}

fn sun_at_0(_: Size, weaken: Weaken) -> Vec<Row> {
    let ctx = bare(64, Face::Px);
    let mut suns = Vec::new();
    for (x, y, phi) in spots(64) {
        for el in [0.0, 0.5 * SUN_R, -0.5 * SUN_R] {
            suns.push((x, y, phi, el));
        }
    }
    // The horizon is 0° across the disc (the bare sphere from h = 0): the segment above it.
    lit_rows(
        &ctx,
        &suns,
        &|el| segment_fraction(-el / SUN_R),
        0.0,
        // Measured 1.5e-6 (reference, lookup exact), 3.0e-6 (segment), 2e-16 (the others).
        [3e-6, 1e-9, 1e-9, 1e-9, 3e-6, 6e-6],
        weaken,
    )
}

fn sun_below_0(_: Size, weaken: Weaken) -> Vec<Row> {
    let ctx = bare(64, Face::Nx);
    let mut suns = Vec::new();
    for (x, y, phi) in spots(64) {
        for el in [-SUN_R, -1.0, -45.0, -90.0] {
            suns.push((x, y, phi, el));
        }
    }
    // Measured 0 but for the segment model's 2.1e-8 with the disc's top on the horizon.
    lit_rows(
        &ctx,
        &suns,
        &|_| 0.0,
        0.0,
        [1e-9, 1e-9, 1e-9, 1e-9, 1e-9, 5e-8],
        weaken,
    )
}

fn sun_at_90(_: Size, weaken: Weaken) -> Vec<Row> {
    // A 300 m step between columns 47 and 48 (20 m pixels): from its foot the top edge stands
    // at atan(300/20) ≈ 86° (less curvature), below the overhead disc's bottom (89.73°).
    let n = 96usize;
    let s = face_pixels(MOON_R, 20.0);
    let ctx = build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, _| {
        if x >= 48 {
            300.0
        } else {
            0.0
        }
    });
    let suns: Vec<_> = [(47usize, 48usize), (46, 10), (30, 80), (48, 48), (70, 20)]
        .iter()
        .flat_map(|&(x, y)| [(x, y, 0.0, 90.0), (x, y, PI, 90.0)])
        .collect();
    lit_rows(&ctx, &suns, &|_| 1.0, 86.2, [1e-9; 6], weaken)
}

fn grazing_texel_edges(_: Size, weaken: Weaken) -> Vec<Row> {
    // A 300 m wall on the cells right beside the observer's row (or column): a point sun
    // along the axis runs exactly along the texel edge where the bilinear surface is still 0;
    // at 1e-3° above the bare horizon it is lit. A walk taking the wall's cell sees ≈ 86°.
    let (n, c) = (96usize, 48usize);
    let s = face_pixels(MOON_R, 20.0);
    let mut methods: Vec<Method> = soft_methods().to_vec();
    methods.push(Method::Extrema);
    let mut edge: Vec<Vec<f64>> = vec![Vec::new(); methods.len()];
    // (plane azimuth, wall beside a row (true) or a column).
    for (phi, row, side) in [
        (0.0, true, 1i64),
        (PI, true, -1),
        (FRAC_PI_2, false, 1),
        (3.0 * FRAC_PI_2, false, -1),
    ] {
        let ctx = build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, y| {
            let d = if row {
                y as i64 - c as i64
            } else {
                x as i64 - c as i64
            };
            if d * side >= 1 {
                300.0
            } else {
                0.0
            }
        });
        let tr = Tracer::new(&ctx, 0.0);
        for (i, m) in methods.iter().enumerate() {
            for (x, y) in [(c, c), (c - 20, c - 20), (c + 20, c + 20)] {
                let (x, y) = if row { (x, c) } else { (c, y) };
                let sun = sun_toward(&ctx, x, y, phi, 1e-3, 0.0);
                edge[i].push((1.0 - trace(&tr, x, y, &sun, m, weaken).0).abs());
            }
        }
    }
    // Point suns 1e-4° above and below a 100 m spike's tip 20 px off along +U and +U+V.
    let ctx = spike_at(n, c, 100.0);
    let tr = Tracer::new(&ctx, 0.0);
    let mut tip: Vec<Vec<f64>> = vec![Vec::new(); methods.len()];
    for (dx, dy) in [(20usize, 0usize), (20, 20)] {
        let (x0, y0) = (c - dx, c + dy);
        let phi = azimuth_of(dx as f64, -(dy as f64));
        let e = elevation_to(&ctx, x0, y0, c as f64, c as f64, 100.0);
        for (i, m) in methods.iter().enumerate() {
            for (d, want) in [(1e-4, 1.0), (-1e-4, 0.0)] {
                let sun = sun_toward(&ctx, x0, y0, phi, e + d, 0.0);
                tip[i].push((trace(&tr, x0, y0, &sun, m, weaken).0 - want).abs());
            }
        }
    }
    let mut rows = Vec::new();
    for (i, m) in methods.iter().enumerate() {
        rows.push(Row::of(
            format!("along the wall's edge {}", m.label()),
            "lit",
            &edge[i],
            1e-9,
        ));
    }
    for (i, m) in methods.iter().enumerate() {
        rows.push(Row::of(
            format!("spike tip ±1e-4° {}", m.label()),
            "lit",
            &tip[i],
            1e-9,
        ));
    }
    rows
}

/// A bare Moon raster (20 m pixels) with a spike of `hs` m at (c, c).
fn spike_at(n: usize, c: usize, hs: f64) -> Context {
    let s = face_pixels(MOON_R, 20.0);
    build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, y| {
        if (x, y) == (c, c) {
            hs
        } else {
            0.0
        }
    })
}

fn shadow_axes_diagonals(_: Size, weaken: Weaken) -> Vec<Row> {
    let (n, c, d, hs) = (96usize, 48usize, 20i64, 100.0);
    let ctx = spike_at(n, c, hs);
    let tr = Tracer::new(&ctx, 0.0);
    // Measured 4.4e-7° (reference), 1.8e-11 (the others).
    soft_methods()
        .iter()
        .zip([1e-6, 1e-9, 1e-9, 1e-9])
        .map(|(m, bound)| {
            let mut e = Vec::new();
            for (dx, dy) in AXES_AND_DIAGONALS {
                let (x0, y0) = ((c as i64 - dx * d) as usize, (c as i64 - dy * d) as usize);
                let want = elevation_to(&ctx, x0, y0, c as f64, c as f64, hs);
                // The sun's centre on the tip, in its azimuth: the walks search the disc's
                // band and report the horizon there.
                let phi = azimuth_of(dx as f64, dy as f64);
                let sun = sun_toward(&ctx, x0, y0, phi, want, SUN_R);
                e.push((trace(&tr, x0, y0, &sun, m, weaken).1 - want).abs());
            }
            Row::of(format!("horizon {}", m.label()), "deg", &e, bound)
        })
        .collect()
}

fn small_and_huge(_: Size, weaken: Weaken) -> Vec<Row> {
    let mut rows = Vec::new();
    // Bounds twice the measured (reference: horizon 2.9e-7° and lit 1.6e-4 on the 10 km
    // body, 1.1e-9° and 3.3e-7 on Jupiter; the others ≤ 4e-11) or 1e-9.
    for (label, r, pixel_m, n, hs, ref_bounds) in [
        (
            "10 km body",
            10_000.0,
            50.0,
            161usize,
            500.0,
            (6e-7, 3.2e-4),
        ),
        ("Jupiter", JUPITER_R, 1000.0, 128, 16.0, (3e-9, 7e-7)),
    ] {
        let s = face_pixels(r, pixel_m);
        let c = n / 2;
        let ctx = build(Face::Px, r, s, centred(s, n, n), (n, n), |x, y| {
            if (x, y) == (c, c) {
                hs
            } else {
                0.0
            }
        });
        let tr = Tracer::new(&ctx, 0.0);
        let dip = dip_deg(r, hs);
        for m in soft_methods() {
            let (bh, bl) = if m == Method::Reference {
                ref_bounds
            } else {
                (1e-9, 1e-9)
            };
            let (mut eh, mut el) = (Vec::new(), Vec::new());
            for phi in [0.0, FRAC_PI_4, 2.0] {
                let sun = sun_toward(&ctx, c, c, phi, dip, SUN_R);
                let (lit, h) = trace(&tr, c, c, &sun, &m, weaken);
                eh.push((h - dip).abs());
                el.push((lit - 0.5).abs());
            }
            rows.push(
                Row::of(format!("{label} horizon {}", m.label()), "deg", &eh, bh)
                    .note(format!("dip {dip:.4}°")),
            );
            rows.push(Row::of(
                format!("{label} lit {}", m.label()),
                "lit",
                &el,
                bl,
            ));
        }
    }
    rows
}

fn shadow_voids(_: Size, weaken: Weaken) -> Vec<Row> {
    let n = 64usize;
    let s = face_pixels(MOON_R, 20.0);
    let void = |x: usize, y: usize| {
        (20..30).contains(&x) && (25..40).contains(&y) || hash01(x, y, 5) < 0.05
    };
    let ctx = build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, y| {
        if void(x, y) {
            f64::NAN
        } else {
            0.0
        }
    });
    let tr = Tracer::new(&ctx, 0.0);
    let el = 0.1;
    let want = segment_fraction(-el / SUN_R);
    // Measured 1.4e-6 (reference), 1e-16 (the others).
    soft_methods()
        .iter()
        .zip([3e-6, 1e-9, 1e-9, 1e-9])
        .map(|(m, bound)| {
            let mut e = Vec::new();
            for y in (2..n - 2).step_by(3) {
                for x in (2..n - 2).step_by(3) {
                    if void(x, y) {
                        continue;
                    }
                    for phi in [0.0, FRAC_PI_4, 2.5] {
                        let sun = sun_toward(&ctx, x, y, phi, el, SUN_R);
                        e.push((trace(&tr, x, y, &sun, m, weaken).0 - want).abs());
                    }
                }
            }
            Row::of(format!("lit over voids {}", m.label()), "lit", &e, bound)
        })
        .collect()
}
