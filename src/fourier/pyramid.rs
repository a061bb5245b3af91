//! Building a tile's coefficient pyramid from its pixels' coefficients (multires means or
//! least-squares fits) and sampling it as a GPU does; the pyramid and its file are
//! [`crate::format::fourier`].

use super::series::{evaluate, Sigma};
use crate::format::fourier::{groups, quantise, Encoding, Group, Layout, Pyramid, Reduce, GROUP};

/// The r × n least-squares projection P = (UᵀU)⁻¹Uᵀ of the 1-D linear interpolation U (n × r)
/// from r texels to the centres of n pixels, clamp to edge, as a GPU samples: texel values
/// P·x interpolate to the closest values to x.
fn fit_projection(n: usize, r: usize) -> Vec<f64> {
    // U as (texel a, weight a, texel b, weight b) per pixel.
    let last = r as i64 - 1;
    let u: Vec<(usize, f64, usize, f64)> = (0..n)
        .map(|i| {
            let x = (i as f64 + 0.5) * r as f64 / n as f64 - 0.5;
            let x0 = x.floor();
            let f = x - x0;
            let a = (x0 as i64).clamp(0, last) as usize;
            let b = (x0 as i64 + 1).clamp(0, last) as usize;
            (a, 1.0 - f, b, f)
        })
        .collect();
    // M = UᵀU (r × r) and Uᵀ (r × n).
    let mut m = vec![0.0f64; r * r];
    let mut ut = vec![0.0f64; r * n];
    for (i, &(a, wa, b, wb)) in u.iter().enumerate() {
        m[a * r + a] += wa * wa;
        m[a * r + b] += wa * wb;
        m[b * r + a] += wb * wa;
        m[b * r + b] += wb * wb;
        ut[a * n + i] += wa;
        ut[b * n + i] += wb;
    }
    // Solve M P = Uᵀ by Gauss-Jordan with partial pivoting (M is symmetric positive definite
    // when every texel is reached, which n ≥ r guarantees; r ≤ n is small).
    let mut p = ut;
    for col in 0..r {
        let piv = (col..r)
            .max_by(|&x, &y| m[x * r + col].abs().total_cmp(&m[y * r + col].abs()))
            .expect("rows");
        if piv != col {
            for k in 0..r {
                m.swap(col * r + k, piv * r + k);
            }
            for k in 0..n {
                p.swap(col * n + k, piv * n + k);
            }
        }
        let d = m[col * r + col];
        for k in 0..r {
            m[col * r + k] /= d;
        }
        for k in 0..n {
            p[col * n + k] /= d;
        }
        for row in 0..r {
            if row != col {
                let f = m[row * r + col];
                if f != 0.0 {
                    for k in 0..r {
                        m[row * r + k] -= f * m[col * r + k];
                    }
                    for k in 0..n {
                        p[row * n + k] -= f * p[col * n + k];
                    }
                }
            }
        }
    }
    p
}

/// Replace the mean texels `vals` of group `g` (res² texels × 4 slots) by the least-squares
/// fit of the pixels' coefficients (no-data pixels take their texel's mean).
#[allow(clippy::too_many_arguments)]
fn fit_group(
    vals: &mut [[f32; 2]],
    coef: &[[f32; 2]],
    k_full: usize,
    k: usize,
    g: usize,
    n: usize,
    res: usize,
    valid: &[bool],
) {
    let p = fit_projection(n, res);
    let mut fine = vec![0.0f64; n * n];
    let mut half = vec![0.0f64; n * res];
    for c in 0..GROUP {
        let kk = g * GROUP + c;
        if kk >= k {
            break;
        }
        for part in 0..2 {
            for j in 0..n {
                let ty = (2 * j + 1) * res / (2 * n);
                for i in 0..n {
                    fine[j * n + i] = if valid[j * n + i] {
                        coef[(j * n + i) * k_full + kk][part] as f64
                    } else {
                        let tx = (2 * i + 1) * res / (2 * n);
                        vals[(ty * res + tx) * GROUP + c][part] as f64
                    };
                }
            }
            // Along x: half[j][t] = Σ_i fine[j][i] P[t][i]; along y: T[s][t] = Σ_j P[s][j] half[j][t].
            for j in 0..n {
                let row = &fine[j * n..(j + 1) * n];
                for t in 0..res {
                    let pr = &p[t * n..(t + 1) * n];
                    half[j * res + t] = row.iter().zip(pr).map(|(a, b)| a * b).sum();
                }
            }
            for s in 0..res {
                let pr = &p[s * n..(s + 1) * n];
                for t in 0..res {
                    let v: f64 = (0..n).map(|j| pr[j] * half[j * res + t]).sum();
                    vals[(s * res + t) * GROUP + c][part] = v as f32;
                }
            }
        }
    }
}

impl Pyramid {
    /// Build from full-resolution coefficients `coef` (pixel `j·n + i`, slot k at
    /// `[(j·n + i)·k_full + k]`, of which the first `k` are kept); pixels with `valid` false
    /// (no data) are left out of every mean and read as zero.
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        n: usize,
        azimuths: usize,
        coef: &[[f32; 2]],
        k_full: usize,
        k: usize,
        valid: &[bool],
        layout: Layout,
        encoding: Encoding,
        sigma: Sigma,
        reduce: Reduce,
        max_horizon_deg: f32,
    ) -> Pyramid {
        assert!(k >= 1 && k <= k_full);
        assert_eq!(coef.len(), n * n * k_full);
        assert_eq!(valid.len(), n * n);
        let mut out = Vec::with_capacity(groups(k));
        for g in 0..groups(k) {
            let res = layout.resolution(n, g);
            let mut sum = vec![[0.0f64; 2]; res * res * GROUP];
            let mut count = vec![0u32; res * res];
            for j in 0..n {
                let ty = (2 * j + 1) * res / (2 * n);
                for i in 0..n {
                    if !valid[j * n + i] {
                        continue;
                    }
                    let tx = (2 * i + 1) * res / (2 * n);
                    let t = ty * res + tx;
                    count[t] += 1;
                    for c in 0..GROUP {
                        let kk = g * GROUP + c;
                        if kk < k {
                            let v = coef[(j * n + i) * k_full + kk];
                            sum[t * GROUP + c][0] += v[0] as f64;
                            sum[t * GROUP + c][1] += v[1] as f64;
                        }
                    }
                }
            }
            let mut vals: Vec<[f32; 2]> = sum
                .iter()
                .enumerate()
                .map(|(s, v)| {
                    let c = count[s / GROUP];
                    if c == 0 {
                        [0.0, 0.0]
                    } else {
                        [(v[0] / c as f64) as f32, (v[1] / c as f64) as f32]
                    }
                })
                .collect();
            if reduce == Reduce::Fit && res < n {
                fit_group(&mut vals, coef, k_full, k, g, n, res, valid);
            }
            let scale = match encoding {
                Encoding::F16 => 1.0,
                Encoding::Snorm16 => {
                    let m = vals
                        .iter()
                        .flat_map(|v| [v[0].abs(), v[1].abs()])
                        .fold(0.0f32, f32::max);
                    if m > 0.0 && m.is_finite() {
                        m
                    } else {
                        1.0
                    }
                }
            };
            for v in &mut vals {
                *v = [
                    quantise(v[0], encoding, scale),
                    quantise(v[1], encoding, scale),
                ];
            }
            out.push(Group {
                res,
                scale,
                coef: vals,
            });
        }
        Pyramid {
            n,
            azimuths,
            k,
            layout,
            encoding,
            sigma,
            max_horizon_deg,
            fully_lit: false,
            groups: out,
        }
    }

    /// The `k` coefficients at tile position (x, y) in pixels (pixel (i, j)'s centre is at
    /// (i + ½, j + ½)), each group sampled bilinearly with clamp-to-edge at its own
    /// resolution, as a GPU samples mip level g of the texture array. Empty when fully lit.
    pub fn coefficients_at(&self, x: f64, y: f64, out: &mut Vec<[f64; 2]>) {
        out.clear();
        let n = self.n as f64;
        for (g, gr) in self.groups.iter().enumerate() {
            let r = gr.res as f64;
            let (fx, fy) = (x / n * r - 0.5, y / n * r - 0.5);
            let (x0, y0) = (fx.floor(), fy.floor());
            let (ax, ay) = (fx - x0, fy - y0);
            let last = gr.res as i64 - 1;
            let cl = |v: i64| v.clamp(0, last) as usize;
            let (xa, xb) = (cl(x0 as i64), cl(x0 as i64 + 1));
            let (ya, yb) = (cl(y0 as i64), cl(y0 as i64 + 1));
            for c in 0..GROUP {
                if g * GROUP + c >= self.k {
                    break;
                }
                let at = |tx: usize, ty: usize| gr.coef[(ty * gr.res + tx) * GROUP + c];
                let mut v = [0.0f64; 2];
                for (p, o) in v.iter_mut().enumerate() {
                    let top = at(xa, ya)[p] as f64 * (1.0 - ax) + at(xb, ya)[p] as f64 * ax;
                    let bot = at(xa, yb)[p] as f64 * (1.0 - ax) + at(xb, yb)[p] as f64 * ax;
                    *o = top * (1.0 - ay) + bot * ay;
                }
                out.push(v);
            }
        }
    }

    /// The horizon (degrees) at pixel-centre position (x, y) in plane azimuth `theta`
    /// (radians); None when the tile is marked fully lit.
    pub fn horizon_at(&self, x: f64, y: f64, theta: f64) -> Option<f64> {
        if self.fully_lit {
            return None;
        }
        let mut c = Vec::with_capacity(self.k);
        self.coefficients_at(x, y, &mut c);
        Some(evaluate(&c, theta))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn sample(n: usize, k: usize, layout: Layout, enc: Encoding) -> Pyramid {
        let mut coef = vec![[0.0f32; 2]; n * n * k];
        for (i, c) in coef.iter_mut().enumerate() {
            let x = i as f32 * 0.37;
            *c = [x.sin() * 20.0, (x * 1.3).cos() * 3.0];
        }
        let valid: Vec<bool> = (0..n * n).map(|i| i % 17 != 3).collect();
        Pyramid::build(
            n,
            360,
            &coef,
            k,
            k,
            &valid,
            layout,
            enc,
            Sigma::None,
            Reduce::Mean,
            12.5,
        )
    }

    #[test]
    fn files_round_trip_exactly() {
        for layout in [Layout::Full, Layout::Multires] {
            for enc in [Encoding::F16, Encoding::Snorm16] {
                for (n, k) in [(16usize, 16usize), (8, 5), (32, 1), (12, 32)] {
                    let p = sample(n, k, layout, enc);
                    let b = p.encode();
                    assert_eq!(b.len(), p.file_bytes());
                    let q = Pyramid::decode(&b, Path::new("t.fhm"), n, 360).unwrap();
                    assert_eq!(p, q, "{layout:?} {enc:?} n {n} k {k}");
                }
            }
        }
    }

    #[test]
    fn multires_levels_are_means_of_the_finer_pixels() {
        let n = 8;
        let k = 16;
        let coef: Vec<[f32; 2]> = (0..n * n * k)
            .map(|i| [(i / k) as f32, (i % k) as f32])
            .collect();
        let valid = vec![true; n * n];
        let p = Pyramid::build(
            n,
            64,
            &coef,
            k,
            k,
            &valid,
            Layout::Multires,
            Encoding::F16,
            Sigma::None,
            Reduce::Mean,
            0.0,
        );
        assert_eq!(
            p.groups.iter().map(|g| g.res).collect::<Vec<_>>(),
            [8, 4, 2, 1]
        );
        // Group 3 (1 texel): the mean pixel index 31.5 in re; im = the slot's own k.
        assert_eq!(p.groups[3].coef[0], [31.5, 12.0]);
        // Group 1, texel (1, 0): pixels (2..4) × (0..2): indices 2, 3, 10, 11 → 6.5.
        assert_eq!(p.groups[1].coef[GROUP], [6.5, 4.0]);
    }

    #[test]
    fn fitted_texels_interpolate_closer_than_means() {
        // A smooth ramp of coefficients across the tile: bilinear sampling of the fitted
        // texels reproduces it almost exactly (interior), the means are off by the ramp's
        // curvature and the clamped edges.
        let n = 32;
        let k = 8;
        let coef: Vec<[f32; 2]> = (0..n * n * k)
            .map(|i| {
                let p = i / k;
                let (x, y) = ((p % n) as f32, (p / n) as f32);
                [(x * 0.3).sin() * 5.0 + y * 0.1, (y * 0.2).cos() * 3.0]
            })
            .collect();
        let valid = vec![true; n * n];
        let err = |reduce| {
            let p = Pyramid::build(
                n,
                64,
                &coef,
                k,
                k,
                &valid,
                Layout::Multires,
                Encoding::F16,
                Sigma::None,
                reduce,
                0.0,
            );
            let mut c = Vec::new();
            let mut e = 0.0f64;
            for j in 0..n {
                for i in 0..n {
                    p.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, &mut c);
                    for s in 4..k {
                        let w = coef[(j * n + i) * k + s];
                        e += (c[s][0] - w[0] as f64).powi(2) + (c[s][1] - w[1] as f64).powi(2);
                    }
                }
            }
            (e / (n * n) as f64).sqrt()
        };
        let (mean, fit) = (err(Reduce::Mean), err(Reduce::Fit));
        assert!(fit < 0.7 * mean, "fit {fit} vs mean {mean}");
        // The projection reproduces texel values that are already a bilinear image.
        let p = fit_projection(16, 4);
        for t in 0..4 {
            let s: f64 = (0..16).map(|i| p[t * 16 + i]).sum();
            assert!((s - 1.0).abs() < 1e-9, "row {t} sums to {s}");
        }
    }

    #[test]
    fn every_damaged_byte_is_refused() {
        let p = sample(8, 6, Layout::Multires, Encoding::Snorm16);
        let b = p.encode();
        for i in 0..b.len() {
            let mut d = b.clone();
            d[i] ^= 0x5a;
            assert!(
                Pyramid::decode(&d, Path::new("t"), 8, 360).is_err(),
                "byte {i}"
            );
        }
        for len in [0, 10, 63, b.len() - 1] {
            assert!(Pyramid::decode(&b[..len], Path::new("t"), 8, 360).is_err());
        }
        assert!(Pyramid::decode(&b, Path::new("t"), 16, 360).is_err());
        assert!(Pyramid::decode(&b, Path::new("t"), 8, 36).is_err());
    }

    #[test]
    fn bilinear_sampling_is_exact_at_texel_centres() {
        let p = sample(16, 16, Layout::Multires, Encoding::F16);
        let mut c = Vec::new();
        // Group 2 has 4×4 texels of 4 pixels: texel (1, 2)'s centre is pixel position (6, 10).
        p.coefficients_at(6.0, 10.0, &mut c);
        let g = &p.groups[2];
        for s in 0..GROUP {
            let t = g.coef[(2 * 4 + 1) * GROUP + s];
            assert_eq!(c[8 + s], [t[0] as f64, t[1] as f64]);
        }
    }
}
