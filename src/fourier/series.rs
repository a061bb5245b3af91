//! The per-pixel truncated Fourier series of a horizon: the real DFT of its `A` samples over
//! the plane azimuths (rustfft, one plan per size), the kept coefficients, their taper, and
//! the series' evaluation at any azimuth.
//!
//! Convention (docs/fourier.md): coefficient `c_k = w_k · X_k`, with `X_k` the DFT bin
//! `Σ_n α_n e^{−2πikn/A}` and `w_k = 1/A` for k = 0 and (A even) k = A/2, `2/A` otherwise, so
//! that the horizon is read back as Fritsch et al. write it:
//!
//! `α(θ) = Σ_{k<K} Re(c_k) cos kθ − Im(c_k) sin kθ`
//!
//! with θ the plane azimuth in radians. With K = A/2 + 1 this reproduces every sample.

use std::sync::Arc;

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

pub use crate::format::fourier::{max_coefficients, Sigma};

impl Sigma {
    /// Factor of coefficient `k` of `kk` kept.
    pub fn factor(self, k: usize, kk: usize) -> f64 {
        match self {
            Sigma::None => 1.0,
            Sigma::Lanczos => {
                if k == 0 {
                    1.0
                } else {
                    let x = std::f64::consts::PI * k as f64 / kk as f64;
                    x.sin() / x
                }
            }
        }
    }
}

/// A forward real DFT of `A` samples, shared by the threads of a stage (each brings its own
/// scratch).
#[derive(Clone)]
pub struct Transform {
    a: usize,
    fft: Arc<dyn Fft<f64>>,
}

impl std::fmt::Debug for Transform {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Transform({})", self.a)
    }
}

/// Per-thread buffers of a [`Transform`].
#[derive(Default)]
pub struct Scratch {
    buf: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
}

impl Transform {
    pub fn new(a: usize) -> Transform {
        assert!(a >= 1);
        Transform {
            a,
            fft: FftPlanner::new().plan_fft_forward(a),
        }
    }

    pub fn azimuths(&self) -> usize {
        self.a
    }

    /// Coefficients `c_0..c_K` (see the module doc) of `m` horizons. Sample `s` of horizon `i`
    /// is `sample(i, s)`; `out` receives horizon `i`'s coefficients at `out[i·K..(i+1)·K]` as
    /// (re, im) in f32, tapered by `sigma`. Computed in f64.
    pub fn forward(
        &self,
        m: usize,
        sample: impl Fn(usize, usize) -> f64,
        k: usize,
        sigma: Sigma,
        out: &mut [[f32; 2]],
        scratch: &mut Scratch,
    ) {
        let a = self.a;
        assert!(k >= 1 && k <= max_coefficients(a));
        assert_eq!(out.len(), m * k);
        scratch.buf.clear();
        scratch.buf.resize(m * a, Complex::new(0.0, 0.0));
        // Azimuth outer: raw maps are plane-major, so this reads them row by row.
        for s in 0..a {
            for i in 0..m {
                scratch.buf[i * a + s].re = sample(i, s);
            }
        }
        let need = self.fft.get_inplace_scratch_len();
        if scratch.scratch.len() < need {
            scratch.scratch.resize(need, Complex::new(0.0, 0.0));
        }
        if m > 0 {
            self.fft
                .process_with_scratch(&mut scratch.buf, &mut scratch.scratch[..need]);
        }
        let factors: Vec<f64> = (0..k).map(|j| weight(j, a) * sigma.factor(j, k)).collect();
        for i in 0..m {
            let bins = &scratch.buf[i * a..(i + 1) * a];
            for (j, o) in out[i * k..(i + 1) * k].iter_mut().enumerate() {
                let c = bins[j] * factors[j];
                *o = [c.re as f32, c.im as f32];
            }
        }
    }

    /// Sum over k ≥ `keep` of the mean square the dropped terms add (Parseval), per unit of
    /// `bins` from [`Transform::forward`] run with K = A/2+1 and no taper: the truncation's
    /// mean square error over all azimuths (degrees²) when only `keep` coefficients are kept.
    pub fn tail_energy(coef: &[[f32; 2]], a: usize, keep: usize) -> f64 {
        coef.iter()
            .enumerate()
            .skip(keep)
            .map(|(k, &c)| term_energy(c, k, a))
            .sum()
    }
}

/// Mean square over azimuths of series term `k` with coefficient `c`: |c|²/2, except the
/// mean (k = 0) and the Nyquist term (k = A/2, A even): |c|².
pub fn term_energy(c: [f32; 2], k: usize, a: usize) -> f64 {
    let m = c[0] as f64 * c[0] as f64 + c[1] as f64 * c[1] as f64;
    if k == 0 || 2 * k == a {
        m
    } else {
        m / 2.0
    }
}

/// `w_k`: 1/A for the mean and the Nyquist bin, 2/A for the others.
fn weight(k: usize, a: usize) -> f64 {
    if k == 0 || 2 * k == a {
        1.0 / a as f64
    } else {
        2.0 / a as f64
    }
}

/// A horizon of `A` samples at plane azimuths 2πk/A read at plane azimuth `phi` (radians):
/// linear between the neighbouring samples, periodic. What the classic horizon maps do, and
/// how the raw maps are read between their samples.
pub fn interpolate_samples(samples: &[f32], phi: f64) -> f64 {
    let a = samples.len();
    let x = phi.rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU * a as f64;
    let k = (x.floor() as usize).min(a - 1);
    let f = x - k as f64;
    samples[k] as f64 * (1.0 - f) + samples[(k + 1) % a] as f64 * f
}

/// α(θ) = Σ Re(c_k) cos kθ − Im(c_k) sin kθ (degrees), θ in radians. The powers e^{ikθ} come
/// from one sin/cos and a rotation in f64 (error ≈ K·1e-16, stable at every K).
pub fn evaluate(c: &[[f64; 2]], theta: f64) -> f64 {
    sum_series(c.iter().map(|v| (v[0], v[1])), theta)
}

/// [`evaluate`] from f32 coefficients.
pub fn evaluate32(c: &[[f32; 2]], theta: f64) -> f64 {
    sum_series(c.iter().map(|v| (v[0] as f64, v[1] as f64)), theta)
}

fn sum_series(c: impl Iterator<Item = (f64, f64)>, theta: f64) -> f64 {
    let (s1, c1) = theta.sin_cos();
    let (mut cs, mut sn) = (1.0f64, 0.0f64);
    let mut sum = 0.0;
    for (k, (re, im)) in c.enumerate() {
        if k > 0 {
            let nc = cs * c1 - sn * s1;
            sn = sn * c1 + cs * s1;
            cs = nc;
            // Re-normalise now and then so that the rotation cannot drift for large K.
            if k % 64 == 0 {
                let r = (cs * cs + sn * sn).sqrt();
                cs /= r;
                sn /= r;
            }
        }
        sum += re * cs - im * sn;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rng(seed: &mut u64) -> f64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn full_series_reproduces_every_sample() {
        for a in [4usize, 5, 36, 359, 360, 1024] {
            let t = Transform::new(a);
            let mut seed = a as u64 * 77 + 1;
            let m = 7;
            let x: Vec<f64> = (0..m * a).map(|_| rng(&mut seed) * 120.0 - 30.0).collect();
            let k = max_coefficients(a);
            let mut out = vec![[0.0f32; 2]; m * k];
            t.forward(
                m,
                |i, s| x[i * a + s],
                k,
                Sigma::None,
                &mut out,
                &mut Scratch::default(),
            );
            let mut worst = 0.0f64;
            for i in 0..m {
                for s in 0..a {
                    let th = std::f64::consts::TAU * s as f64 / a as f64;
                    let v = evaluate32(&out[i * k..(i + 1) * k], th);
                    worst = worst.max((v - x[i * a + s]).abs());
                }
            }
            assert!(worst < 1e-5, "A = {a}: round trip off by {worst}");
        }
    }

    #[test]
    fn a_single_harmonic_is_one_coefficient() {
        let a = 360;
        let t = Transform::new(a);
        let mut out = vec![[0.0f32; 2]; 8];
        // 5 + 3 cos 2θ − 4 sin 3θ
        t.forward(
            1,
            |_, s| {
                let th = std::f64::consts::TAU * s as f64 / a as f64;
                5.0 + 3.0 * (2.0 * th).cos() - 4.0 * (3.0 * th).sin()
            },
            8,
            Sigma::None,
            &mut out,
            &mut Scratch::default(),
        );
        let want = [[5.0, 0.0], [0.0, 0.0], [3.0, 0.0], [0.0, 4.0]];
        for (k, w) in want.iter().enumerate() {
            assert!((out[k][0] - w[0]).abs() < 1e-5 && (out[k][1] - w[1]).abs() < 1e-5);
        }
        for c in &out[4..] {
            assert!(c[0].abs() < 1e-5 && c[1].abs() < 1e-5);
        }
    }

    #[test]
    fn parseval_tail_is_the_truncation_error() {
        let a = 360;
        let t = Transform::new(a);
        let mut seed = 5;
        let x: Vec<f64> = (0..a).map(|_| rng(&mut seed) * 40.0).collect();
        let kf = max_coefficients(a);
        let mut full = vec![[0.0f32; 2]; kf];
        t.forward(
            1,
            |_, s| x[s],
            kf,
            Sigma::None,
            &mut full,
            &mut Scratch::default(),
        );
        for keep in [1usize, 4, 16, 100, 181] {
            let ms: f64 = (0..a)
                .map(|s| {
                    let th = std::f64::consts::TAU * s as f64 / a as f64;
                    (evaluate32(&full[..keep], th) - x[s]).powi(2)
                })
                .sum::<f64>()
                / a as f64;
            let tail = Transform::tail_energy(&full, a, keep);
            assert!(
                (ms - tail).abs() <= 1e-6 * (1.0 + ms),
                "keep {keep}: {ms} vs {tail}"
            );
        }
    }

    #[test]
    fn evaluation_is_stable_at_large_k() {
        // A unit coefficient at k = 2000 evaluates to cos(2000 θ) everywhere.
        let mut c = vec![[0.0f64; 2]; 2049];
        c[2000] = [1.0, 0.0];
        for i in 0..100 {
            let th = i as f64 * 0.0617;
            assert!((evaluate(&c, th) - (2000.0 * th).cos()).abs() < 1e-10);
        }
    }
}
