//! `penumbra-bench sweep` (issue 34): the sweep method's error against the reference on a
//! block of each shared real DEM, with its time and the fast and exact methods' in the same
//! run.

use std::path::Path;
use std::time::Instant;

use anyhow::Result;
use serde::Serialize;

use penumbra::horizon::device::{horizons_sweep_on, SweepDevice};
use penumbra::horizon::{horizons, Method, Rect};

use crate::cases::{peer_context, real_cases};
use crate::common::{in_pool, random_pixels, read_npy_f32};

/// Error of one method against a truth, over every finite pixel·azimuth.
#[derive(Serialize, Clone)]
pub(crate) struct Error {
    pub(crate) samples: usize,
    pub(crate) rms_deg: f64,
    pub(crate) mean_deg: f64,
    pub(crate) p99_deg: f64,
    pub(crate) max_deg: f64,
    /// Share of samples more than 0.1° above the truth.
    pub(crate) share_above_0_1: f64,
}

pub(crate) fn error(got: &[f32], truth: &[f32]) -> Error {
    let mut d: Vec<f64> = got
        .iter()
        .zip(truth)
        .filter(|(g, t)| g.is_finite() && t.is_finite())
        .map(|(g, t)| *g as f64 - *t as f64)
        .collect();
    let n = d.len().max(1) as f64;
    let mean = d.iter().sum::<f64>() / n;
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let above = d.iter().filter(|v| **v > 0.1).count() as f64 / n;
    for v in d.iter_mut() {
        *v = v.abs();
    }
    d.sort_unstable_by(f64::total_cmp);
    let p99 = d.get(((d.len() as f64 * 0.99) as usize).min(d.len().saturating_sub(1)));
    Error {
        samples: d.len(),
        rms_deg: rms,
        mean_deg: mean,
        p99_deg: p99.copied().unwrap_or(0.0),
        max_deg: d.last().copied().unwrap_or(0.0),
        share_above_0_1: above,
    }
}

#[derive(Serialize)]
struct Row {
    case: String,
    truth: &'static str,
    method: &'static str,
    pixels: usize,
    azimuths: usize,
    wall_s: f64,
    core_ns_per_px_az: f64,
    error: Error,
}

/// `f()` timed, or what an earlier run stored under `key` in `$PENUMBRA_BENCH_CACHE` (a
/// folder; development runs only: the truth takes minutes and does not change with the
/// method), whose time is then unknown (NaN).
fn cached(key: &str, f: impl FnOnce() -> Result<Vec<f32>>) -> Result<(Vec<f32>, f64)> {
    let timed = |f: Box<dyn FnOnce() -> Result<Vec<f32>> + '_>| -> Result<(Vec<f32>, f64)> {
        let t0 = Instant::now();
        let v = f()?;
        Ok((v, t0.elapsed().as_secs_f64()))
    };
    let Some(dir) = std::env::var_os("PENUMBRA_BENCH_CACHE") else {
        return timed(Box::new(f));
    };
    let name: String = key
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    let path = Path::new(&dir).join(format!("{name}.f32"));
    if let Ok(b) = std::fs::read(&path) {
        let v = b
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        return Ok((v, f64::NAN));
    }
    let (v, t) = timed(Box::new(f))?;
    std::fs::create_dir_all(&dir)?;
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(&path, bytes)?;
    Ok((v, t))
}

/// The peers' synthetic 30 m DEM as a patch at the centre of face +X (as `bench horizon`).
fn synthetic(peers: &Path) -> Result<Option<penumbra::horizon::Context>> {
    let npy = peers.join("data/dem1024.npy");
    if !npy.exists() {
        return Ok(None);
    }
    let (h, w, heights) = read_npy_f32(&npy)?;
    Ok(Some(peer_context(h, w, heights)))
}

/// Whole-map timing of `m` on `threads`, best of `repeat`, and the values at `pix`.
fn whole_map(
    ctx: &penumbra::horizon::Context,
    a: usize,
    m: Method,
    threads: usize,
    repeat: usize,
    pix: &[(usize, usize)],
) -> Result<(f64, Vec<f32>)> {
    let full = Rect {
        x0: 0,
        y0: 0,
        w: ctx.width,
        h: ctx.height,
    };
    let plane = ctx.width * ctx.height;
    let mut best = f64::INFINITY;
    let mut at = Vec::new();
    for _ in 0..repeat {
        let (t, out) = in_pool(threads, || {
            let t0 = Instant::now();
            let out = horizons(ctx, full, a, m);
            (t0.elapsed().as_secs_f64(), out)
        })?;
        best = best.min(t);
        at = at_pixels(&out, ctx.width, plane, a, pix);
    }
    Ok((best, at))
}

/// The values of `out` (plane-major maps `width` wide) at `pix`, pixel-major.
fn at_pixels(
    out: &[f32],
    width: usize,
    plane: usize,
    a: usize,
    pix: &[(usize, usize)],
) -> Vec<f32> {
    pix.iter()
        .flat_map(|&(x, y)| (0..a).map(move |k| (k, x, y)))
        .map(|(k, x, y)| out[k * plane + y * width + x])
        .collect()
}

/// The reference at `pix` only, 360 azimuths, pixel-major as [`whole_map`] gathers.
fn reference_at(ctx: &penumbra::horizon::Context, a: usize, pix: &[(usize, usize)]) -> Vec<f32> {
    use rayon::prelude::*;
    pix.par_iter()
        .flat_map_iter(|&(x, y)| {
            let r = Rect {
                x0: x,
                y0: y,
                w: 1,
                h: 1,
            };
            horizons(ctx, r, a, Method::Reference)
        })
        .collect()
}

#[allow(clippy::too_many_arguments)]
pub fn run(
    data: &Path,
    peers: &Path,
    repeat: usize,
    skip_fast: bool,
    whole_azimuths: usize,
    block: usize,
    a: usize,
    truth: Method,
    device: Option<&dyn SweepDevice>,
    markdown: bool,
    json: bool,
    quiet: bool,
) -> Result<()> {
    let say = |m: String| {
        if !quiet {
            eprintln!("bench sweep: {m}");
        }
    };
    // The sweep on `device` (`--device gpu`), timed wall-clock with its read-back.
    let on_device =
        |ctx: &penumbra::horizon::Context, rect: Rect, a: usize| -> Result<(Vec<f32>, f64)> {
            let d = device.expect("asked only with a device");
            let t0 = Instant::now();
            let out = horizons_sweep_on(d, ctx, rect, a)?;
            Ok((out, t0.elapsed().as_secs_f64()))
        };
    let threads = rayon::current_num_threads();
    let (cases, notes) = if block == 0 {
        (Vec::new(), Vec::new())
    } else {
        real_cases(data, block, &say)?
    };
    let mut rows = Vec::new();
    if let Some(ctx) = synthetic(peers)? {
        let a = whole_azimuths;
        let pix = random_pixels(ctx.width, ctx.height, 1024);
        say("synthetic 1024²: reference at 1024 pixels".into());
        let (want, t_ref) = cached(&format!("synthetic-reference-{a}"), || {
            in_pool(threads, || reference_at(&ctx, a, &pix))
        })?;
        let plane = ctx.width * ctx.height;
        let ns = |t: f64, thr: usize, n: usize| t * thr as f64 / (n * a) as f64 * 1e9;
        rows.push(Row {
            case: "synthetic 1024² (30 m)".into(),
            truth: "reference",
            method: "reference (1024 px)",
            pixels: pix.len(),
            azimuths: a,
            wall_s: t_ref,
            core_ns_per_px_az: ns(t_ref, threads, pix.len()),
            error: error(&want, &want),
        });
        for (m, thr) in [
            (Method::Sweep, threads),
            (Method::Sweep, 1),
            (Method::Fast, threads),
        ] {
            if skip_fast && m == Method::Fast {
                continue;
            }
            say(format!(
                "synthetic 1024²: {} whole map, {thr} thread(s)",
                m.name()
            ));
            let (t, got) = whole_map(&ctx, a, m, thr, repeat, &pix)?;
            rows.push(Row {
                case: format!("synthetic 1024² (30 m), {thr} thr"),
                truth: "reference",
                method: m.name(),
                pixels: plane,
                azimuths: a,
                wall_s: t,
                core_ns_per_px_az: ns(t, thr, plane),
                error: error(&got, &want),
            });
        }
        if device.is_some() {
            say("synthetic 1024²: sweep whole map on the GPU".into());
            let full = Rect {
                x0: 0,
                y0: 0,
                w: ctx.width,
                h: ctx.height,
            };
            let mut best = f64::INFINITY;
            let mut at = Vec::new();
            for _ in 0..repeat.max(1) {
                let (out, t) = on_device(&ctx, full, a)?;
                best = best.min(t);
                at = at_pixels(&out, ctx.width, plane, a, &pix);
            }
            rows.push(Row {
                case: "synthetic 1024² (30 m), GPU".into(),
                truth: "reference",
                method: "sweep (gpu)",
                pixels: plane,
                azimuths: a,
                wall_s: best,
                core_ns_per_px_az: f64::NAN,
                error: error(&at, &want),
            });
        }
    }
    for case in &cases {
        let plane = case.rect.w * case.rect.h;
        say(format!(
            "{}: {} truth, {a} azimuths",
            case.name,
            truth.name()
        ));
        let (want, t_truth) = cached(&format!("{}-{}-{a}", case.name, truth.name()), || {
            in_pool(threads, || horizons(&case.ctx, case.rect, a, truth))
        })?;
        let mut methods = vec![(Method::Sweep, Vec::new(), 0.0)];
        if truth != Method::Fast && !skip_fast {
            methods.push((Method::Fast, Vec::new(), 0.0));
        }
        for (m, out, t) in methods.iter_mut() {
            say(format!("{}: {}", case.name, m.name()));
            let t0 = Instant::now();
            *out = in_pool(threads, || horizons(&case.ctx, case.rect, a, *m))?;
            *t = t0.elapsed().as_secs_f64();
        }
        let ns = |t: f64| t * threads as f64 / (plane * a) as f64 * 1e9;
        rows.push(Row {
            case: case.name.clone(),
            truth: truth.name(),
            method: truth.name(),
            pixels: plane,
            azimuths: a,
            wall_s: t_truth,
            core_ns_per_px_az: ns(t_truth),
            error: error(&want, &want),
        });
        let cpu_sweep = methods[0].1.clone();
        for (m, out, t) in methods {
            rows.push(Row {
                case: case.name.clone(),
                truth: truth.name(),
                method: m.name(),
                pixels: plane,
                azimuths: a,
                wall_s: t,
                core_ns_per_px_az: ns(t),
                error: error(&out, &want),
            });
        }
        if device.is_some() {
            say(format!("{}: sweep on the GPU", case.name));
            let (out, t) = on_device(&case.ctx, case.rect, a)?;
            for (against, e) in [
                (truth.name(), error(&out, &want)),
                ("sweep (cpu)", error(&out, &cpu_sweep)),
            ] {
                rows.push(Row {
                    case: case.name.clone(),
                    truth: against,
                    method: "sweep (gpu)",
                    pixels: plane,
                    azimuths: a,
                    wall_s: t,
                    core_ns_per_px_az: f64::NAN,
                    error: e,
                });
            }
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    let _ = markdown;
    if let Some(d) = device {
        println!("GPU: {}\n", d.key());
    }
    println!(
        "| case | method | against | wall s | core-ns/px·az | RMS ° | mean ° | p99 ° | max ° | > +0.1° |"
    );
    println!("|---|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in &rows {
        println!(
            "| {} | {} | {} | {:.2} | {:.1} | {:.5} | {:+.5} | {:.4} | {:.3} | {:.3} % |",
            r.case,
            r.method,
            r.truth,
            r.wall_s,
            r.core_ns_per_px_az,
            r.error.rms_deg,
            r.error.mean_deg,
            r.error.p99_deg,
            r.error.max_deg,
            100.0 * r.error.share_above_0_1
        );
    }
    for n in notes {
        println!("\n{n}");
    }
    Ok(())
}

/// One row of the product comparison: the paper's Fourier product built from one method's
/// horizons, against the exact method's raw maps.
#[derive(Serialize)]
struct ProductRow {
    case: String,
    method: &'static str,
    azimuths: usize,
    horizon_wall_s: f64,
    raw: Error,
    product_rms_deg: f64,
    lit_mae: f64,
    per_pct: f64,
    /// Against the same product built from the exact method's horizons.
    d_lit_mae: f64,
    d_per_pp: f64,
}

/// Issue 34's product acceptance: Fourier-16 multires f16 built from `sweep` (and `fast`)
/// horizons against the same built from `exact` horizons, lit-fraction MAE and PER at the
/// suns of `penumbra-bench fourier`, the exact raw maps as truth, on every real DEM block.
pub fn run_product(
    data: &Path,
    block: usize,
    a: usize,
    lit_pixels: usize,
    json: bool,
    quiet: bool,
) -> Result<()> {
    let say = |m: String| {
        if !quiet {
            eprintln!("bench sweep --product: {m}");
        }
    };
    anyhow::ensure!(
        a >= 64,
        "--azimuths must be at least 64 for a 16-term series"
    );
    let threads = rayon::current_num_threads();
    let (cases, notes) = real_cases(data, block, &say)?;
    let mut rows = Vec::new();
    for case in &cases {
        say(format!("{}: exact, {a} azimuths", case.name));
        let (exact, t_exact) = cached(&format!("{}-exact-{a}", case.name), || {
            in_pool(threads, || horizons(&case.ctx, case.rect, a, Method::Exact))
        })?;
        let mut maps = vec![(Method::Exact, exact, t_exact)];
        for m in [Method::Sweep, Method::Fast] {
            say(format!("{}: {}", case.name, m.name()));
            let t0 = Instant::now();
            let v = in_pool(threads, || horizons(&case.ctx, case.rect, a, m))?;
            maps.push((m, v, t0.elapsed().as_secs_f64()));
        }
        say(format!("{}: products", case.name));
        let elevs: Vec<&[f32]> = maps.iter().map(|(_, v, _)| &v[..]).collect();
        let exact = elevs[0];
        let got = crate::fourier::paper_product_errors(case, exact, &elevs, a, lit_pixels);
        let (base_mae, base_per) = (got[0].lit_mae, got[0].per_all);
        for ((m, v, t), p) in maps.iter().zip(got) {
            rows.push(ProductRow {
                case: case.name.clone(),
                method: m.name(),
                azimuths: a,
                horizon_wall_s: *t,
                raw: error(v, exact),
                product_rms_deg: p.rms_deg,
                lit_mae: p.lit_mae,
                per_pct: 100.0 * p.per_all,
                d_lit_mae: p.lit_mae - base_mae,
                d_per_pp: 100.0 * (p.per_all - base_per),
            });
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "| case | horizons from | wall s | raw RMS ° | raw p99 ° | product RMS ° | lit MAE | PER % | Δ lit MAE | Δ PER pp |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in &rows {
        println!(
            "| {} | {} | {:.2} | {:.4} | {:.3} | {:.4} | {:.5} | {:.3} | {:+.5} | {:+.3} |",
            r.case,
            r.method,
            r.horizon_wall_s,
            r.raw.rms_deg,
            r.raw.p99_deg,
            r.product_rms_deg,
            r.lit_mae,
            r.per_pct,
            r.d_lit_mae,
            r.d_per_pp
        );
    }
    for n in notes {
        println!("\n{n}");
    }
    Ok(())
}
