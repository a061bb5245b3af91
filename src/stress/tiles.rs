//! Tile cases: the mip pyramids against a brute force over every texel's footprint (an odd
//! size, whose last texels straddle the edge at every level; the halo from the neighbouring
//! tiles; voids), a constant tile, and a 16384² tile (1024² in the short run).

use crate::cube::Face;
use crate::horizon::Method;
use crate::mip::{level_sizes, minmax_pyramid, MinMaxPyramid};

use super::geometry::*;
use super::types::{Case, Row, Size, Weaken};

pub(super) fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "level-seams",
            area: "tiles",
            about: "the (min, max) pyramid of a 45² tile with a 1-px halo and voids against each \
                    texel's footprint at every level (partial texels at the edges)",
            run: level_seams,
        },
        Case {
            name: "tile-16384",
            area: "tiles",
            about: "a 16384² tile (Short: 1024²) of 100 m pixels: the dip from a 150 m spike \
                    near its far corner, the pyramid's top texel against the extrema",
            run: tile_16384,
        },
    ]
}

/// Largest |pyramid − brute force| over every texel of every level; NaN must match NaN.
fn pyramid_errors(stored: &[f32], ns: usize, halo: usize, p: &MinMaxPyramid) -> (f64, usize) {
    let n = ns - 2 * halo;
    let (mut worst, mut mismatch) = (0.0f64, 0usize);
    for (k, &size) in level_sizes(n).iter().enumerate() {
        let span = 1usize << k;
        for ty in 0..size {
            for tx in 0..size {
                // Interior pixels [t·2^k, min((t+1)·2^k, n)), each reading the 3×3 samples
                // around it: stored [t·2^k + halo − 1, min(..) − 1 + halo + 1].
                let (x0, x1) = (tx * span + halo - 1, ((tx + 1) * span).min(n) + halo);
                let (y0, y1) = (ty * span + halo - 1, ((ty + 1) * span).min(n) + halo);
                let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        let v = stored[y * ns + x];
                        if v.is_finite() {
                            lo = lo.min(v);
                            hi = hi.max(v);
                        }
                    }
                }
                let i = ty * size + tx;
                for (got, want) in [(p.min[k][i], lo), (p.max[k][i], hi)] {
                    if want.is_finite() {
                        if got.is_finite() {
                            worst = worst.max((got as f64 - want as f64).abs());
                        } else {
                            mismatch += 1;
                        }
                    } else if !got.is_nan() {
                        mismatch += 1;
                    }
                }
            }
        }
    }
    (worst, mismatch)
}

fn level_seams(_: Size, _: Weaken) -> Vec<Row> {
    let (n, halo) = (45usize, 1usize);
    let ns = n + 2 * halo;
    let stored: Vec<f32> = (0..ns * ns)
        .map(|i| {
            let (x, y) = (i % ns, i / ns);
            if (30..38).contains(&x) && (3..11).contains(&y) || hash01(x, y, 31) < 0.03 {
                f32::NAN
            } else {
                (3000.0 * value_noise(x as f64, y as f64, 6.0, 32) + 500.0 * hash01(x, y, 33))
                    as f32
            }
        })
        .collect();
    let p = match minmax_pyramid(&stored, ns, halo) {
        Ok(p) => p,
        Err(e) => {
            return vec![Row::new("pyramid", "m", f64::NAN, 0.0).note(e.to_string())];
        }
    };
    let (worst, mismatch) = pyramid_errors(&stored, ns, halo, &p);
    vec![
        Row::new("texels vs footprints", "m", worst, 0.0).nonfinite(mismatch),
        Row::new(
            "levels",
            "count",
            (p.sizes != level_sizes(n)) as u8 as f64,
            0.0,
        )
        .note(format!("{:?}", p.sizes)),
    ]
}

/// The (min, max) pyramid of a constant tile: `value` in every texel of every level.
pub(super) fn constant_mip_rows(value: f32) -> Vec<Row> {
    let (n, halo) = (37usize, 2usize);
    let ns = n + 2 * halo;
    let stored = vec![value; ns * ns];
    match minmax_pyramid(&stored, ns, halo) {
        Ok(p) => {
            let e: Vec<f64> = p
                .min
                .iter()
                .chain(&p.max)
                .flatten()
                .map(|&v| (v as f64 - value as f64).abs())
                .collect();
            vec![Row::of("(min, max) pyramid", "m", &e, 0.0)]
        }
        Err(e) => vec![Row::new("(min, max) pyramid", "m", f64::NAN, 0.0).note(e.to_string())],
    }
}

fn tile_16384(size: Size, weaken: Weaken) -> Vec<Row> {
    let n = match size {
        Size::Short => 1024usize,
        Size::Full => 16384,
    };
    let note = match size {
        Size::Short => "short run: 1024² (--full: 16384²)",
        Size::Full => "16384²",
    };
    // Moon, 100 m pixels at the face centre (S = 34748 ≥ n); a 150 m spike 400 px from the
    // raster's far corner: its tangent distance √(2RH) ≈ 22.8 km stays inside the raster in
    // every azimuth even where the full tile's corner pixels (u, v ≈ ±0.47) shrink to ≈ 70 m.
    let hs = 150.0;
    let s = face_pixels(MOON_R, 100.0);
    let c = n - 400;
    let ctx = build(Face::Px, MOON_R, s, centred(s, n, n), (n, n), |x, y| {
        if (x, y) == (c, c) {
            hs
        } else {
            0.0
        }
    });
    let want = dip_deg(MOON_R, hs);
    // The sampled maximum near the tangent point (distance L) falls short of the dip by at
    // most Δ²/(2RL) for samples Δ apart: ≤ 7.2e-6° with Δ = 100 m. Measured 1.3e-8° (1024²)
    // and 1.7e-6° (16384², where the corner's smaller pixels move the samples): bounds twice
    // that, at least 1e-6° (f32 degrees).
    let bound = match size {
        Size::Short => 1e-6,
        Size::Full => 3.5e-6,
    };
    let mut rows = Vec::new();
    for m in [Method::Reference, Method::Exact] {
        let out = horizons(&ctx, pixel(c, c), 16, m, weaken);
        let e: Vec<f64> = out.iter().map(|&v| (v as f64 - want).abs()).collect();
        rows.push(
            Row::of(format!("spike dip {}", m.name()), "deg", &e, bound)
                .note(format!("{note}; dip {want:.4}°")),
        );
    }
    // The tile with a 1-px halo: the pyramid's top texel is the tile's extrema.
    drop(ctx);
    let ns = n + 2;
    let mut stored = vec![0.0f32; ns * ns];
    stored[(c + 1) * ns + c + 1] = hs as f32;
    stored[(n - 1) * ns + 7] = -hs as f32;
    match minmax_pyramid(&stored, ns, 1) {
        Ok(p) => {
            let k = p.sizes.len() - 1;
            let e = (p.max[k][0] as f64 - hs).abs() + (p.min[k][0] as f64 + hs).abs();
            rows.push(Row::new("pyramid top vs extrema", "m", e, 0.0).note(note));
        }
        Err(e) => {
            rows.push(Row::new("pyramid top vs extrema", "m", f64::NAN, 0.0).note(e.to_string()))
        }
    }
    rows
}
