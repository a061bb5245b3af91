//! Fourier cases: the truncated series at its two limits, K = 1 (the mean; Parseval gives the
//! error) and K = A/2 + 1 (every sample reproduced), and f16 at its limits.

use crate::fourier::series::{evaluate32, Transform};
use crate::fourier::Sigma;
use crate::horizon::plane_azimuth;
use crate::mip::{f16_down, f16_up};

use super::geometry::hash01;
use super::types::{Case, Row, Size, Weaken};

pub(super) fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "k-1",
            area: "fourier",
            about: "K = 1: the coefficient is the mean of the samples, and the series' rms error \
                    is Parseval's tail",
            run: k_1,
        },
        Case {
            name: "k-a-half-plus-1",
            area: "fourier",
            about: "K = A/2 + 1 (A = 8, 45, 64, 360): the series reproduces every sample",
            run: k_full,
        },
        Case {
            name: "f16-limits",
            area: "fourier",
            about: "f16 horizons within ½ ulp over ±90°; directed rounding brackets every value \
                    up to ±65504 (subnormals included) within 1 ulp; 65504 exact, beyond it ±∞",
            run: f16_limits,
        },
    ]
}

/// Horizons (degrees) that are hard for a series: harmonics, a cliff (a step in azimuth) and
/// noise; `i` picks one.
fn horizon_samples(a: usize, i: usize) -> Vec<f32> {
    (0..a)
        .map(|k| {
            let t = plane_azimuth(k, a);
            let step = if (t - 1.0 - 0.3 * i as f64).rem_euclid(std::f64::consts::TAU) < 0.8 {
                25.0
            } else {
                0.0
            };
            (3.0 + 2.0 * t.cos() - 1.5 * (3.0 * t).sin()
                + 0.7 * (17.0 * t).cos()
                + step
                + 4.0 * (hash01(k, i, 21) - 0.5)) as f32
        })
        .collect()
}

/// Coefficients of `samples` with `k` kept, no taper; the last one dropped under
/// [`Weaken::FourierDropTerm`].
fn coefficients(samples: &[f32], k: usize, weaken: Weaken) -> Vec<[f32; 2]> {
    let a = samples.len();
    let t = Transform::new(a);
    let mut out = vec![[0.0f32; 2]; k];
    t.forward(
        1,
        |_, s| samples[s] as f64,
        k,
        Sigma::None,
        &mut out,
        &mut Default::default(),
    );
    if weaken == Weaken::FourierDropTerm {
        out[k - 1] = [0.0, 0.0];
    }
    out
}

fn k_1(_: Size, weaken: Weaken) -> Vec<Row> {
    let (mut mean_e, mut pars_e) = (Vec::new(), Vec::new());
    for (a, i) in [(8usize, 0usize), (64, 1), (360, 2), (45, 3)] {
        let s = horizon_samples(a, i);
        let mean = s.iter().map(|&v| v as f64).sum::<f64>() / a as f64;
        let c = coefficients(&s, 1, weaken);
        mean_e.push((c[0][0] as f64 - mean).abs() + (c[0][1] as f64).abs());
        // Parseval: the rms of the series' error over the samples is √(Σ_{k≥1} energy).
        let full = coefficients(
            &s,
            crate::fourier::series::max_coefficients(a),
            Weaken::None,
        );
        let tail = Transform::tail_energy(&full, a, 1).sqrt();
        let rms = (s
            .iter()
            .enumerate()
            .map(|(n, &v)| (evaluate32(&c, plane_azimuth(n, a)) - v as f64).powi(2))
            .sum::<f64>()
            / a as f64)
            .sqrt();
        pars_e.push((rms - tail).abs());
    }
    vec![
        // Twice the measured 1.3e-7° and 1.2e-7° (f32 coefficients).
        Row::of("c0 − mean", "deg", &mean_e, 3e-7).note("f32 coefficients"),
        Row::of("rms error − Parseval tail", "deg", &pars_e, 3e-7),
    ]
}

fn k_full(_: Size, weaken: Weaken) -> Vec<Row> {
    let mut rows = Vec::new();
    for (a, i) in [(8usize, 4usize), (45, 5), (64, 6), (360, 7)] {
        let kk = a / 2 + 1;
        let mut e = Vec::new();
        for j in 0..4 {
            let s = horizon_samples(a, i * 4 + j);
            let c = coefficients(&s, kk, weaken);
            for (n, &v) in s.iter().enumerate() {
                e.push((evaluate32(&c, plane_azimuth(n, a)) - v as f64).abs());
            }
        }
        // f32 coefficients of horizons up to ≈ 35°: measured 6e-7° to 7.4e-7° at every A.
        rows.push(Row::of(
            format!("A = {a}, K = {kk}: samples"),
            "deg",
            &e,
            1.5e-6,
        ));
    }
    rows
}

fn f16_limits(_: Size, _: Weaken) -> Vec<Row> {
    // Horizons over ±90° in f16 (the raw maps' default precision), every 1e-3°.
    let mut ulps = Vec::new();
    let mut nonfinite = 0;
    let mut x = -90.0f64;
    while x <= 90.0 {
        let v = x as f32;
        let h = half::f16::from_f32(v);
        if !h.is_finite() {
            nonfinite += 1;
        }
        let ulp = (v.abs() as f64).log2().floor().max(-14.0).exp2() / 1024.0;
        ulps.push((h.to_f32() as f64 - v as f64).abs() / ulp);
        x += 1e-3;
    }
    // Directed rounding (the f16 mipmaps' bounds): every f32 bit pattern of [−65504, 65504]
    // on a stride, and the subnormals, must be bracketed, each side within 1 f16 ulp.
    let mut wrong = 0usize;
    let mut checked = 0usize;
    // The next f16 toward +∞ (−0 and +0 both step to the smallest subnormal).
    let next = |h: half::f16| {
        let b = h.to_bits();
        half::f16::from_bits(match b {
            0x0000 | 0x8000 => 0x0001,
            b if b & 0x8000 == 0 => b + 1,
            b => b - 1,
        })
    };
    let mut check = |v: f32| {
        let (up, down) = (f16_up(v), f16_down(v));
        checked += 1;
        let (u, d) = (up.to_f32(), down.to_f32());
        let ok = u >= v
            && d <= v
            && u.is_finite()
            && d.is_finite()
            && (u == d || next(down).to_f32() == u);
        if !ok {
            wrong += 1;
        }
    };
    let mut b = 0u32;
    while b < 0x477F_E000 {
        check(f32::from_bits(b));
        check(-f32::from_bits(b));
        b += 4099;
    }
    for v in [65504.0f32, -65504.0, 6.0e-8, -6.0e-8, 6.1e-5, 0.0, -0.0] {
        check(v);
    }
    let over = [
        f16_up(65505.0).to_f32() == f32::INFINITY,
        f16_down(-65505.0).to_f32() == f32::NEG_INFINITY,
        f16_up(65504.0).to_f32() == 65504.0,
        f16_down(65504.0).to_f32() == 65504.0,
        f16_up(f32::NAN).is_nan(),
    ];
    vec![
        Row::of("f16 horizons, ±90°", "ulp", &ulps, 0.5).nonfinite(nonfinite),
        Row::new("directed rounding misses", "count", wrong as f64, 0.0)
            .note(format!("{checked} values")),
        Row::new(
            "65504 exact, beyond ±∞, NaN kept: misses",
            "count",
            over.iter().filter(|&&ok| !ok).count() as f64,
            0.0,
        ),
    ]
}
