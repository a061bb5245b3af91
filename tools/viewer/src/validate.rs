/*!
`--validate`: the GPU's lit fractions against the CPU at exactly the texels a headless frame
shows. The id target says which tile texel each pixel shows; each distinct texel is evaluated
once on the CPU (in parallel, tile by tile) by the CPU twin of the same method and by the exact
`reference` ([`TileShadow::cpu_lit`](crate::shadow::TileShadow::cpu_lit)), and every pixel is
compared with its texel's CPU values.

Numbers (over the pixels that show terrain): the mean and largest absolute lit-fraction
error, and PER, the share of pixels whose lit/unlit decision at 0.5 differs (as
docs/shadows.md defines it). A pixel with data on one side and none on the other counts as a
decision error.
*/

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use anyhow::Result;
use penumbra::fourier::sun::{Model, Sun};
use penumbra::tileset::Store;
use serde::Serialize;

use crate::render::{GpuTile, Readback};
use crate::shadow::{CpuTwin, GpuMethod};

/// One comparison's numbers.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Errors {
    /// What the GPU was compared with (`dp auto (cpu)`, `reference (cpu)`).
    pub against: String,
    /// Pixels compared (showing terrain with data on both sides).
    pub pixels: u64,
    /// Mean absolute lit-fraction error.
    pub mean_abs: f64,
    /// Largest absolute error.
    pub max_abs: f64,
    /// Share of pixels whose decision at 0.5 differs, percent.
    pub per_percent: f64,
    /// Pixels with data on one side only (counted in PER).
    pub data_mismatch: u64,
}

/// The validation report.
#[derive(Clone, Debug, Serialize)]
pub struct Validation {
    /// Distinct texels evaluated on the CPU.
    pub texels: usize,
    /// GPU against the CPU twin of the same method.
    pub same: Errors,
    /// GPU against the CPU reference.
    pub reference: Errors,
    /// The CPU twin against the CPU reference at the same texels (what the method itself
    /// costs in accuracy, GPU aside).
    pub cpu_same_vs_reference: Errors,
    /// For `fourier` with an O(K) disc model: the GPU against the CPU's exact disc model over
    /// the same coefficients (what the cheap model costs); null otherwise.
    pub exact_model: Option<Errors>,
    /// The same comparisons over the penumbral pixels only: those whose texel has the sun
    /// within ±3° of its own horizon in the sun's azimuth, where shadows are decided and the
    /// all-pixel means hide a method's errors (the shadow bench's penumbra metric).
    pub penumbra: Penumbra,
    /// CPU seconds (both evaluations, all threads).
    pub cpu_s: f64,
}

/// [`Validation::penumbra`].
#[derive(Clone, Debug, Serialize)]
pub struct Penumbra {
    /// Penumbral pixels (showing terrain) and distinct texels.
    pub pixels: u64,
    pub texels: usize,
    /// GPU against the CPU twin, and against the reference.
    pub same: Errors,
    pub reference: Errors,
}

/// Per pixel, the CPU values of the texel it shows: same method, reference, and for an O(K)
/// Fourier model the exact disc model.
pub struct CpuValues {
    pub same: Vec<f32>,
    pub reference: Vec<f32>,
    pub exact_model: Option<Vec<f32>>,
}

/// Evaluate the CPU twins at the texels of `rb` and compare.
pub fn validate(
    rb: &Readback,
    tiles: &[&GpuTile],
    sun: &Sun,
    method: &GpuMethod,
    store: &Store,
    max_margin_px: u64,
) -> Result<(Validation, CpuValues)> {
    let t0 = Instant::now();
    // Distinct texels, in a fixed order (first appearance in the frame).
    let mut index: HashMap<(u32, u32, u32), usize> = HashMap::new();
    let mut texels: Vec<(u32, u32, u32)> = Vec::new();
    let slot: Vec<Option<usize>> = rb
        .texel
        .iter()
        .map(|t| {
            t.map(|k| {
                *index.entry(k).or_insert_with(|| {
                    texels.push(k);
                    texels.len() - 1
                })
            })
        })
        .collect();
    // The exact disc model beside an O(K) Fourier model.
    let exact = match method {
        GpuMethod::Fourier { model } if *model != Model::Exact => Some(GpuMethod::Fourier {
            model: Model::Exact,
        }),
        _ => None,
    };
    // Per tile, the CPU twins over that tile's texels (each call runs in parallel).
    let mut values = vec![(f32::NAN, f32::NAN, f32::NAN); texels.len()];
    let mut penumbral = vec![false; texels.len()];
    let mut by_tile: HashMap<u32, Vec<usize>> = HashMap::new();
    for (k, t) in texels.iter().enumerate() {
        by_tile.entry(t.0).or_default().push(k);
    }
    let mut order: Vec<_> = by_tile.into_iter().collect();
    order.sort();
    for (t, ks) in order {
        let sh = &tiles[t as usize].shadow;
        let at: Vec<[i32; 2]> = ks
            .iter()
            .map(|&k| {
                let (_, i, j) = texels[k];
                [
                    (sh.rect.x0 + i as usize) as i32,
                    (sh.rect.y0 + j as usize) as i32,
                ]
            })
            .collect();
        let same = sh.cpu_lit_many(&at, sun, &CpuTwin::Same(method.clone()));
        let (reference, band) = sh.cpu_reference_and_band(store, &at, sun, max_margin_px)?;
        let model = exact
            .as_ref()
            .map(|m| sh.cpu_lit_many(&at, sun, &CpuTwin::Same(m.clone())));
        for (n, &k) in ks.iter().enumerate() {
            let e = model.as_ref().map_or(f32::NAN, |v| v[n] as f32);
            values[k] = (same[n] as f32, reference[n] as f32, e);
            penumbral[k] = band[n];
        }
    }
    let px = |pick: fn(&(f32, f32, f32)) -> f32| -> Vec<f32> {
        slot.iter()
            .map(|s| s.map_or(f32::NAN, |k| pick(&values[k])))
            .collect()
    };
    let cpu = CpuValues {
        same: px(|v| v.0),
        reference: px(|v| v.1),
        exact_model: exact.is_some().then(|| px(|v| v.2)),
    };
    let label = method.label();
    let on_surface: Vec<bool> = rb.texel.iter().map(|t| t.is_some()).collect();
    let in_band: Vec<bool> = slot
        .iter()
        .map(|s| s.is_some_and(|k| penumbral[k]))
        .collect();
    let v = Validation {
        texels: texels.len(),
        same: compare(&rb.lit, &cpu.same, &on_surface, format!("{label} (cpu)")),
        reference: compare(
            &rb.lit,
            &cpu.reference,
            &on_surface,
            "reference (cpu)".into(),
        ),
        cpu_same_vs_reference: compare(
            &cpu.same,
            &cpu.reference,
            &on_surface,
            format!("reference (cpu, for cpu {label})"),
        ),
        exact_model: cpu
            .exact_model
            .as_ref()
            .zip(exact.as_ref())
            .map(|(e, m)| compare(&rb.lit, e, &on_surface, format!("{} (cpu)", m.label()))),
        penumbra: Penumbra {
            pixels: in_band.iter().filter(|&&b| b).count() as u64,
            texels: penumbral.iter().filter(|&&b| b).count(),
            same: compare(&rb.lit, &cpu.same, &in_band, format!("{label} (cpu)")),
            reference: compare(&rb.lit, &cpu.reference, &in_band, "reference (cpu)".into()),
        },
        cpu_s: t0.elapsed().as_secs_f64(),
    };
    Ok((v, cpu))
}

/// Compare `a` with `b` over the pixels where `mask` holds (NaN: no data).
pub fn compare(a: &[f32], b: &[f32], mask: &[bool], against: String) -> Errors {
    let mut e = Errors {
        against,
        ..Errors::default()
    };
    let (mut sum, mut wrong, mut total) = (0.0f64, 0u64, 0u64);
    for ((&x, &y), &m) in a.iter().zip(b).zip(mask) {
        if !m {
            continue;
        }
        match (x.is_nan(), y.is_nan()) {
            (true, true) => continue,
            (false, false) => {
                let d = (x as f64 - y as f64).abs();
                sum += d;
                e.max_abs = e.max_abs.max(d);
                e.pixels += 1;
                if (x >= 0.5) != (y >= 0.5) {
                    wrong += 1;
                }
                total += 1;
            }
            _ => {
                e.data_mismatch += 1;
                wrong += 1;
                total += 1;
            }
        }
    }
    if e.pixels > 0 {
        e.mean_abs = sum / e.pixels as f64;
    }
    if total > 0 {
        e.per_percent = 100.0 * wrong as f64 / total as f64;
    }
    e
}

/// Colour of pixels without terrain in the difference image.
pub const DIFF_BACKGROUND: [u8; 3] = [24, 24, 24];

/// Write the difference image of `gpu − cpu`: grey where they agree (within 0.002), red where
/// the GPU is darker, blue where it is brighter, saturating at a difference of 0.25; yellow
/// where one side has data and the other none; dark where no terrain is shown.
pub fn write_diff_png(path: &Path, w: u32, h: u32, gpu: &[f32], cpu: &[f32]) -> Result<()> {
    let mut px = Vec::with_capacity((w * h * 3) as usize);
    for (&g, &c) in gpu.iter().zip(cpu) {
        let rgb = match (g.is_nan(), c.is_nan()) {
            (true, true) => DIFF_BACKGROUND,
            (false, false) => {
                let d = g - c;
                let k = ((d.abs() / 0.25).min(1.0) * 195.0) as u8;
                if d.abs() < 0.002 {
                    [60, 60, 60]
                } else if d < 0.0 {
                    [60 + k, 60, 60]
                } else {
                    [60, 60, 60 + k]
                }
            }
            _ => [230, 210, 40],
        };
        px.extend_from_slice(&rgb);
    }
    crate::output::write_rgb_png(path, w, h, &px)
}
