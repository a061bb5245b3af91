//! The sweep method on the GPU against the CPU: the reference (or the exact method, equal to it
//! within 1.1e-4°) and the CPU sweep, on rough synthetic terrain with holes, the shared real
//! DEMs' 256² blocks and the stress catalogue's stiff horizon cases. In CI on Mesa's lavapipe
//! (`.ci/run` installs it); without any adapter the tests say so and pass, except under
//! `CI=true`, where they fail.

use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use penumbra::cube::Face;
use penumbra::horizon::device::{horizons_sweep_on, DeviceChoice, SweepDevice};
use penumbra::horizon::{horizons, Context, Method, Rect};
use penumbra_gpu::GpuSweep;

/// The GPU, opened once for the whole test binary (any adapter, lavapipe included).
fn gpu() -> Option<Arc<GpuSweep>> {
    static GPU: OnceLock<Option<Arc<GpuSweep>>> = OnceLock::new();
    GPU.get_or_init(|| match GpuSweep::open(DeviceChoice::Gpu) {
        Ok(Some(g)) => {
            eprintln!("GPU: {}", g.describe());
            Some(Arc::new(g))
        }
        Ok(None) => unreachable!("--device gpu opens a device or fails"),
        Err(e) => {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "CI=true and no GPU adapter: {e}"
            );
            eprintln!("skipped: {e}");
            None
        }
    })
    .clone()
}

/// Error statistics of `got` against `want` over samples finite in both, as the benchmarks
/// tally them ([`penumbra_cli::measure::ErrStats`]): RMS, p99 of |Δ| (the upper edge of its
/// 1e-4° bin), max |Δ|, count; both must agree on where the data is.
fn stats(got: &[f32], want: &[f32]) -> (f64, f64, f64, u64) {
    let mut e = penumbra_cli::measure::ErrStats::new(0);
    for (g, w) in got.iter().zip(want) {
        assert_eq!(g.is_nan(), w.is_nan(), "no data where the CPU has none");
        if g.is_finite() && w.is_finite() {
            e.add(*g as f64 - *w as f64);
        }
    }
    (e.rms(), e.p99(), e.max, e.n)
}

/// A raster of `w` × `h` heights at the centre of face +X on the Moon, `pixel_m` apart.
fn moon(w: usize, h: usize, heights: Vec<f32>, pixel_m: f64) -> Context {
    let radius_m = penumbra_cli::measure::body_radius("moon");
    let s = (2.0 * radius_m / pixel_m).round();
    let si = s as i64;
    Context {
        face: Face::Px,
        face_pixels: s,
        origin: ((si - w as i64) / 2, (si - h as i64) / 2),
        width: w,
        height: h,
        heights,
        radius_m,
    }
}

/// Rough terrain: smooth waves plus 1-px noise, with holes (no data) where `holes`.
fn rough(w: usize, h: usize, seed: u64, holes: bool) -> Vec<f32> {
    let mut x = seed;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut v = Vec::with_capacity(w * h);
    for y in 0..h {
        for xx in 0..w {
            let (xf, yf) = (xx as f64, y as f64);
            let base = 800.0 * (xf / 17.0).sin() * (yf / 23.0).cos() + 300.0 * (xf / 5.3).cos();
            let mut z = (base + 40.0 * (rnd() - 0.5)) as f32;
            if holes && (xx / 9 + y / 7) % 11 == 0 && (xx * 7 + y * 3) % 5 == 0 {
                z = f32::NAN;
            }
            v.push(z);
        }
    }
    v
}

/// On rough terrain with and without holes, odd and even azimuth counts: the GPU within the
/// sweep's budget of the reference and within 0.01° RMS of the CPU sweep; the same bytes twice.
#[test]
fn rough_terrain_matches_the_cpu_sweep() {
    let Some(gpu) = gpu() else { return };
    let (w, h) = (120, 100);
    for (seed, holes, a) in [
        (0x5EE9u64, false, 24usize),
        (0xA11, true, 16),
        (0xB0B, false, 9),
    ] {
        let ctx = moon(w, h, rough(w, h, seed, holes), 60.0);
        let rect = Rect {
            x0: 30,
            y0: 20,
            w: 56,
            h: 48,
        };
        let cpu = horizons(&ctx, rect, a, Method::Sweep);
        let reference = horizons(&ctx, rect, a, Method::Reference);
        let got = horizons_sweep_on(gpu.as_ref(), &ctx, rect, a).expect("GPU sweep");
        let again = horizons_sweep_on(gpu.as_ref(), &ctx, rect, a).expect("GPU sweep");
        assert!(
            got.iter()
                .zip(&again)
                .all(|(x, y)| x.to_bits() == y.to_bits()),
            "the same bytes on a second run"
        );
        let (rms_c, p99_c, max_c, n) = stats(&got, &cpu);
        let (rms_r, p99_r, max_r, _) = stats(&got, &reference);
        let (rms_cr, _, _, _) = stats(&cpu, &reference);
        eprintln!(
            "seed {seed:x} holes {holes} a {a}: GPU − CPU sweep rms {rms_c:.5}° p99 {p99_c:.5}° \
             max {max_c:.4}° over {n}; GPU − reference rms {rms_r:.4}° p99 {p99_r:.4}° max \
             {max_r:.3}° (CPU sweep − reference rms {rms_cr:.4}°)"
        );
        assert!(rms_c <= 0.01, "GPU against CPU sweep: rms {rms_c}°");
        // Rougher than any DEM (as the CPU sweep's own test): its budget there, with room.
        assert!(
            rms_r <= rms_cr + 0.01,
            "GPU against reference: rms {rms_r}°"
        );
    }
}

/// The shared real DEMs' 256² blocks (whole DEM as context, 36 azimuths), as `penumbra-bench
/// sweep` measures the CPU sweep: against the exact method (the reference within 1.1e-4°)
/// RMS ≤ 0.03° and p99 ≤ 0.3°, against the CPU sweep RMS ≤ 0.01°.
#[test]
fn real_dem_blocks_within_the_sweep_budget() {
    let Some(gpu) = gpu() else { return };
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let a = 36;
    let mut seen = 0;
    for (label, rel, body) in penumbra_cli::measure::REAL_DEMS {
        let path = data.join(rel);
        if !path.exists() {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "CI=true and {} is missing",
                path.display()
            );
            eprintln!("skipped {label}: {} not found", path.display());
            continue;
        }
        seen += 1;
        let dem = penumbra::dem::open(&path, 64).expect("DEM");
        let case = penumbra_cli::measure::dem_case(label, &dem, body, 256);
        let (ctx, rect) = (&case.ctx, case.rect);
        let t0 = std::time::Instant::now();
        let got = horizons_sweep_on(gpu.as_ref(), ctx, rect, a).expect("GPU sweep");
        let gpu_s = t0.elapsed().as_secs_f64();
        let cpu = horizons(ctx, rect, a, Method::Sweep);
        let truth = horizons(ctx, rect, a, Method::Exact);
        let (rms_c, p99_c, max_c, n) = stats(&got, &cpu);
        let (rms, p99, max, _) = stats(&got, &truth);
        let (rms_cpu, p99_cpu, max_cpu, _) = stats(&cpu, &truth);
        eprintln!(
            "{label} ({}×{} context, {gpu_s:.2} s on the GPU): GPU − exact rms {rms:.4}° p99 \
             {p99:.4}° max {max:.3}°; CPU sweep − exact rms {rms_cpu:.4}° p99 {p99_cpu:.4}° max \
             {max_cpu:.3}°; GPU − CPU sweep rms {rms_c:.5}° p99 {p99_c:.5}° max {max_c:.4}° over \
             {n}",
            ctx.width, ctx.height
        );
        assert!(rms <= 0.03 && p99 <= 0.3, "{label}: rms {rms}° p99 {p99}°");
        assert!(rms_c <= 0.01, "{label}: against the CPU sweep rms {rms_c}°");
    }
    eprintln!("{seen} real DEMs compared");
}

/// The device's key names the adapter; a tile's GPU memory at the peak is bounded by the budget
/// (plus its heights) for every tile size, whatever the number of tiles (docs/horizons.md
/// prints this table).
#[test]
fn key_names_the_adapter_and_memory_is_per_tile() {
    use penumbra_gpu::TileShape;
    if let Some(gpu) = gpu() {
        let key = gpu.key();
        assert!(key.starts_with("gpu: "), "{key}");
    }
    let mib = |b: u64| b as f64 / (1u64 << 20) as f64;
    let budget = penumbra_gpu::DEFAULT_MEMORY_MIB << 20;
    // An adapter that binds 2 GiB (discrete GPUs; lavapipe binds 128 MiB and cuts batches
    // smaller).
    let cap = 2u64 << 30;
    eprintln!("| tile | context | per job | jobs a batch | peak |");
    for (tile, margin) in [
        (128u64, 1024u64),
        (256, 1024),
        (512, 319),
        (512, 1024),
        (1024, 2048),
    ] {
        let shape = TileShape::square(tile, margin);
        let batch = shape.batch(budget, cap).expect("fits a 2 GiB binding");
        let peak = shape.peak_bytes(batch);
        eprintln!(
            "| {tile}² | {0}² | {1:.1} MiB | {batch} | {2:.0} MiB |",
            tile + 2 * margin,
            mib(shape.per_job_bytes()),
            mib(peak)
        );
        assert!(
            peak <= budget.max(shape.peak_bytes(1)),
            "{tile}²: {peak} bytes"
        );
    }
}

/// The stress catalogue's horizon cases (docs/stress.md: bare spheres, a 1-px spike's dip, a
/// vertical cliff, a cone along axes and diagonals, a cube corner, the north pole, a 10-km
/// body, Jupiter, Mars relief in f16, voids, a constant tile, tile and face seams) with their
/// sweep rows on the GPU: every row within the bound the CPU sweep is held to.
#[test]
fn stress_horizon_cases_hold_on_the_gpu() {
    let Some(gpu) = gpu() else { return };
    use penumbra::stress::{self, Size, Weaken};
    stress::set_sweep_device(Some(gpu));
    let cases: Vec<_> = stress::catalogue()
        .into_iter()
        .filter(|c| c.area == "horizon")
        .collect();
    let mut failed = Vec::new();
    for c in &cases {
        for r in stress::run_case(c, Size::Short, Weaken::None) {
            if r.quantity.contains("sweep") {
                eprintln!(
                    "{:<16} {:<36} {:.3e} (bound {:.1e}) {}",
                    r.case,
                    r.quantity,
                    r.error,
                    r.bound,
                    if r.pass { "ok" } else { "FAIL" }
                );
            }
            if !r.pass {
                failed.push(format!(
                    "{} / {}: {} > {}",
                    r.case, r.quantity, r.error, r.bound
                ));
            }
        }
    }
    stress::set_sweep_device(None);
    assert!(failed.is_empty(), "rows over their bounds: {failed:#?}");
}
