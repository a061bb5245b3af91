//! `penumbra-bench horizon`: horizon throughput on the peers' synthetic 30 m UTM DEM (the whole
//! map as observers and as context, 1 thread and all cores), the brute-force reference on
//! random pixels, the fast sweep's error against it (there and on blocks of the shared real
//! DEMs), the peers' horizon tools from their results.tsv, and an extrapolation to a Mars
//! 800 m/px whole-body bake.

use std::path::Path;

use anyhow::{bail, Result};
use serde::Serialize;

use crate::cases::{peer_context, PEER_PIXEL_M};
use crate::common::{best_of, in_pool, random_pixels, read_npy_f32, EARTH_RADIUS_M, MARS_RADIUS_M};

/// Fritsch et al.'s Mars whole-body bake: 800 m/px, ≈150 CPU-hours.
const MARS_PIXEL_M: f64 = 800.0;
const MARS_HMIN_M: f64 = -8_200.0;
const MARS_HMAX_M: f64 = 21_200.0;
const MARS_TILE_PX: f64 = 512.0;
const FRITSCH_CPU_HOURS: f64 = 150.0;

#[derive(Serialize)]
struct HzRow {
    case: String,
    threads: usize,
    observers: usize,
    azimuths: usize,
    wall_s: f64,
    /// Measured for the fast sweep; core-ns per pixel·azimuth × the whole DEM ÷ threads for
    /// the reference.
    whole_dem_wall_s: f64,
    /// Million pixel·azimuths per second of wall time.
    mpx_az_per_s: f64,
    /// Wall × threads per pixel·azimuth, ns.
    core_ns_per_px_az: f64,
    /// Speed-up over the same case on 1 thread.
    scaling: Option<f64>,
    /// Reference time per pixel·azimuth ÷ the fast sweep's, on the same threads.
    fast_speedup: Option<f64>,
}

#[derive(Serialize)]
struct HzAccuracy {
    comparison: String,
    pixels: usize,
    /// Pixel·azimuths where both are finite.
    samples: usize,
    rms_deg: f64,
    mean_deg: f64,
    max_abs_deg: f64,
    share_over_0_5_deg: f64,
    share_over_0_1_deg: f64,
    worst: String,
}

#[derive(Serialize)]
struct HzPeer {
    peer: String,
    /// Row name in results.tsv; None when the peer was not measured.
    name: Option<String>,
    directions: Option<f64>,
    wall_s: Option<f64>,
    cpu_pct: String,
    load1_before: String,
    /// wall × azimuths ÷ directions.
    scaled_wall_s: Option<f64>,
    /// Scaled peer wall ÷ penumbra's fast wall on all cores (> 1: penumbra is faster).
    ratio_vs_all_cores: Option<f64>,
    /// Scaled peer wall ÷ penumbra's fast wall on 1 thread.
    ratio_vs_1_thread: Option<f64>,
    notes: String,
}

#[derive(Serialize)]
struct HzMars {
    pixels: f64,
    azimuths: usize,
    core_ns_per_px_az: f64,
    raw_cpu_hours: f64,
    margin_px: f64,
    context_factor: f64,
    adjusted_cpu_hours: f64,
    /// Context factor fitted to the centre-observers check (see the notes).
    fitted_context_factor: f64,
    fitted_cpu_hours: f64,
    fritsch_cpu_hours: f64,
}

/// Fast − reference over `pix` (both laid out pixel-major, `a` values per pixel).
/// One near-field size of the fast method on one real-DEM block: time and error.
#[derive(Serialize)]
struct HzNear {
    dem: String,
    near_px: f64,
    wall_s: f64,
    core_ns_per_px_az: f64,
    rms_deg: f64,
    max_abs_deg: f64,
    share_over_0_5_deg: f64,
}

/// Fast against the exact reference on a block at the centre of each shared real DEM the
/// horizon tests use (the default near field's row appended to `accuracy`, every near-field
/// size's time and error to `near`); returns notes (what was run or skipped).
fn hz_real_dems(
    data: &Path,
    threads: usize,
    accuracy: &mut Vec<HzAccuracy>,
    near: &mut Vec<HzNear>,
    say: &dyn Fn(String),
) -> Result<Vec<String>> {
    use penumbra::horizon::DEFAULT_NEAR_PX;
    use penumbra::horizon::{horizons, horizons_with, Context as HzContext, Method, Rect};
    use std::time::Instant;
    const BLOCK: usize = 256;
    const AZ: usize = 36;
    const NEAR_PX: [f64; 7] = [0.0, 4.0, 8.0, 16.0, 24.0, 32.0, 48.0];
    // Pixel sizes and radii as in tests/horizon.rs.
    let dems = [
        (
            "Gale crater (MOLA 463 m)",
            "mola_gale_128ppd_crop/gale-mola.bin",
            MARS_RADIUS_M,
            463.0,
        ),
        (
            "Hawaiʻi (SRTM3 92 m)",
            "srtm3/N19W156.hgt",
            EARTH_RADIUS_M,
            92.0,
        ),
    ];
    let mut notes = Vec::new();
    for (label, rel, radius_m, pixel_m) in dems {
        let path = data.join(rel);
        if !path.exists() {
            notes.push(format!("{label}: {} not found, skipped.", path.display()));
            continue;
        }
        let dem = penumbra::dem::open(&path, 64)?;
        let (w, h) = (dem.width(), dem.height());
        if w < BLOCK || h < BLOCK {
            notes.push(format!(
                "{label}: {w}×{h} is smaller than the {BLOCK}² block, skipped."
            ));
            continue;
        }
        let mut heights = vec![0.0f32; w * h];
        for r in 0..h {
            for c in 0..w {
                heights[r * w + c] = dem.value(c, r).0;
            }
        }
        let s = (2.0 * radius_m / pixel_m).round();
        let si = s as i64;
        let ctx = HzContext {
            face: penumbra::cube::Face::Px,
            face_pixels: s,
            origin: ((si - w as i64) / 2, (si - h as i64) / 2),
            width: w,
            height: h,
            heights,
            radius_m,
        };
        let rect = Rect {
            x0: (w - BLOCK) / 2,
            y0: (h - BLOCK) / 2,
            w: BLOCK,
            h: BLOCK,
        };
        say(format!(
            "{label}: {BLOCK}² block, {AZ} azimuths, reference and fast at {} near-field sizes",
            NEAR_PX.len()
        ));
        let t0 = Instant::now();
        let reference = in_pool(threads, || horizons(&ctx, rect, AZ, Method::Reference))?;
        let t_reference = t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let exact = in_pool(threads, || horizons(&ctx, rect, AZ, Method::Exact))?;
        let t_exact = t0.elapsed().as_secs_f64();
        // Plane-major (azimuth, pixel) to pixel-major, as hz_accuracy reads them.
        let plane = BLOCK * BLOCK;
        let by_pixel = |v: &[f32]| -> Vec<f32> {
            (0..plane)
                .flat_map(|p| (0..AZ).map(move |k| v[k * plane + p]))
                .collect()
        };
        let pix: Vec<(usize, usize)> = (0..plane)
            .map(|p| (rect.x0 + p % BLOCK, rect.y0 + p / BLOCK))
            .collect();
        let reference = by_pixel(&reference);
        accuracy.push(hz_accuracy(
            &format!(
                "exact (max-pyramid walk) − reference, {label}, {BLOCK}² block, {AZ} azimuths"
            ),
            &by_pixel(&exact),
            &reference,
            &pix,
            AZ,
        ));
        let mut t_fast = f64::NAN;
        for near_px in NEAR_PX {
            // Best of 3: a run is under a second, within this machine's timing noise.
            let (t, fast) = in_pool(threads, || {
                let mut best = (f64::INFINITY, Vec::new());
                for _ in 0..3 {
                    let t0 = Instant::now();
                    let out = horizons_with(&ctx, rect, AZ, Method::Fast, near_px);
                    let t = t0.elapsed().as_secs_f64();
                    if t < best.0 {
                        best = (t, out);
                    }
                }
                best
            })?;
            let acc = hz_accuracy(
                &format!(
                    "fast − reference, {label}, {BLOCK}² block at the DEM's centre, {AZ} azimuths"
                ),
                &by_pixel(&fast),
                &reference,
                &pix,
                AZ,
            );
            near.push(HzNear {
                dem: label.to_string(),
                near_px,
                wall_s: t,
                core_ns_per_px_az: t * threads as f64 / (plane * AZ) as f64 * 1e9,
                rms_deg: acc.rms_deg,
                max_abs_deg: acc.max_abs_deg,
                share_over_0_5_deg: acc.share_over_0_5_deg,
            });
            if near_px == DEFAULT_NEAR_PX {
                accuracy.push(acc);
                t_fast = t;
            }
        }
        notes.push(format!(
            "{label}: {} ({w}×{h}) as a patch at the centre of face +X (R = {radius_m} m, \
             {pixel_m} m pixels); observers the {BLOCK}² block from pixel ({}, {}), the whole DEM \
             as context; the near-field rows time the fast method best of 3 on all cores \
             (near field {DEFAULT_NEAR_PX} px is the default).",
            path.display(),
            rect.x0,
            rect.y0
        ));
        notes.push(format!(
            "{label}, exact method (`--method exact`, the max-pyramid walk): {t_exact:.2} s on \
             the block against the reference's {t_reference:.2} s ({:.1}× faster, one run each) \
             and the fast method's {t_fast:.2} s at {DEFAULT_NEAR_PX} px ({:.2}× its time).",
            t_reference / t_exact,
            t_exact / t_fast
        ));
    }
    Ok(notes)
}

fn hz_accuracy(
    comparison: &str,
    fast: &[f32],
    reference: &[f32],
    pix: &[(usize, usize)],
    a: usize,
) -> HzAccuracy {
    let (mut n, mut sum, mut sum2, mut over5, mut over1) = (0usize, 0.0f64, 0.0f64, 0usize, 0usize);
    let (mut max, mut worst) = (0.0f64, String::from("–"));
    for (i, (f, r)) in fast.iter().zip(reference).enumerate() {
        if !(f.is_finite() && r.is_finite()) {
            continue;
        }
        let d = *f as f64 - *r as f64;
        n += 1;
        sum += d;
        sum2 += d * d;
        over5 += (d.abs() > 0.5) as usize;
        over1 += (d.abs() > 0.1) as usize;
        if d.abs() > max {
            max = d.abs();
            let (x, y) = pix[i / a];
            worst = format!(
                "pixel ({x}, {y}), plane azimuth {:.1}°: {f:.3}° vs {r:.3}°",
                360.0 * (i % a) as f64 / a as f64
            );
        }
    }
    let nf = n.max(1) as f64;
    HzAccuracy {
        comparison: comparison.into(),
        pixels: pix.len(),
        samples: n,
        rms_deg: (sum2 / nf).sqrt(),
        mean_deg: sum / nf,
        max_abs_deg: max,
        share_over_0_5_deg: over5 as f64 / nf,
        share_over_0_1_deg: over1 as f64 / nf,
        worst,
    }
}

/// The peers' horizon rows for DEM `size` from `results.tsv` (one "not measured" row per
/// peer without any).
fn hz_peers(tsv: &Path, size: usize, a: usize, fast_all: f64, fast_1: f64) -> Vec<HzPeer> {
    const PEERS: [&str; 4] = ["GRASS r.horizon", "topocalc", "HORAYZON", "WhiteboxTools"];
    let classify = |tool: &str, op: &str| -> Option<&'static str> {
        let (tool, op) = (tool.to_lowercase(), op.to_lowercase());
        if op == "r.horizon" {
            Some(PEERS[0])
        } else if tool.contains("topocalc") {
            Some(PEERS[1])
        } else if tool.contains("horayzon") {
            Some(PEERS[2])
        } else if tool.contains("whitebox") && op.contains("horizon") {
            Some(PEERS[3])
        } else {
            None
        }
    };
    let text = std::fs::read_to_string(tsv).unwrap_or_default();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split('\t').collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split('\t').collect()).collect();
    let get = |r: &[&str], name: &str| -> String {
        col(name)
            .and_then(|i| r.get(i))
            .map_or(String::new(), |s| s.trim().to_string())
    };
    let names: Vec<String> = rows.iter().map(|r| get(r, "name")).collect();
    let mut out = Vec::new();
    for peer in PEERS {
        let mut any = false;
        for r in &rows {
            if classify(&get(r, "tool"), &get(r, "operation")) != Some(peer)
                || get(r, "dem") != size.to_string()
            {
                continue;
            }
            let name = get(r, "name");
            // Halves run concurrently are reported through their `_total` row.
            if let Some(stem) = name.strip_suffix("_a").or_else(|| name.strip_suffix("_b")) {
                if names.contains(&format!("{stem}_total")) {
                    continue;
                }
            }
            let Ok(dirs) = get(r, "directions").parse::<f64>() else {
                continue;
            };
            any = true;
            let wall = get(r, "wall_s").parse::<f64>().ok();
            let rc = get(r, "rc");
            let ok = rc.is_empty() || rc == "0";
            let scaled = wall.filter(|_| ok).map(|w| w * a as f64 / dirs);
            let mut notes = get(r, "notes");
            if !ok {
                notes = format!("failed (rc {rc}); {notes}");
            }
            out.push(HzPeer {
                peer: peer.into(),
                name: Some(name),
                directions: Some(dirs),
                wall_s: wall,
                cpu_pct: get(r, "cpu_pct"),
                load1_before: get(r, "load1_before"),
                scaled_wall_s: scaled,
                ratio_vs_all_cores: scaled.map(|s| s / fast_all),
                ratio_vs_1_thread: scaled.map(|s| s / fast_1),
                notes,
            });
        }
        if !any {
            out.push(HzPeer {
                peer: peer.into(),
                name: None,
                directions: None,
                wall_s: None,
                cpu_pct: String::new(),
                load1_before: String::new(),
                scaled_wall_s: None,
                ratio_vs_all_cores: None,
                ratio_vs_1_thread: None,
                notes: "not measured".into(),
            });
        }
    }
    out
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_string))
        .unwrap_or_else(|| "?".into())
}

#[allow(clippy::too_many_arguments)]
pub fn run_horizon(
    peers: &Path,
    data: &Path,
    a: usize,
    size: usize,
    ref_pixels: usize,
    repeat: usize,
    markdown: bool,
    json: bool,
    quiet: bool,
) -> Result<()> {
    use penumbra::horizon::{horizons, horizons_reference_step, Method, Rect};
    use rayon::prelude::*;
    use std::time::Instant;

    if size != 1024 && size != 2048 {
        bail!("--size must be 1024 or 2048 (the peers' dem1024.npy and dem2048.npy)");
    }
    if a == 0 {
        bail!("--azimuths must be at least 1");
    }
    let npy = peers.join(format!("data/dem{size}.npy"));
    if !npy.exists() {
        bail!(
            "{}: not found; run `bash ../shared/peers/run_peers.sh dem` (it fills $PEERS, \
             default ../peers-work) or give --peers",
            npy.display()
        );
    }
    let (h, w, heights) = read_npy_f32(&npy)?;
    let (hmin, hmax) = heights
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    let ctx = peer_context(h, w, heights);
    let s = ctx.face_pixels;
    let threads = rayon::current_num_threads();
    let load1 = load_average();
    let plane = w * h;
    let full = Rect { x0: 0, y0: 0, w, h };
    let pix = random_pixels(w, h, ref_pixels.max(1));
    let gather = |out: &[f32]| -> Vec<f32> {
        let mut v = Vec::with_capacity(pix.len() * a);
        for &(x, y) in &pix {
            for k in 0..a {
                v.push(out[k * plane + y * w + x]);
            }
        }
        v
    };
    let say = |m: String| {
        if !quiet {
            eprintln!("bench horizon: {m}");
        }
    };
    let px_az = (plane * a) as f64;
    let row = |case: String, thr: usize, obs: usize, wall: f64, whole: f64| HzRow {
        case,
        threads: thr,
        observers: obs,
        azimuths: a,
        wall_s: wall,
        whole_dem_wall_s: whole,
        mpx_az_per_s: (obs * a) as f64 / wall / 1e6,
        core_ns_per_px_az: wall * thr as f64 / (obs * a) as f64 * 1e9,
        scaling: None,
        fast_speedup: None,
    };
    let thread_counts: Vec<usize> = if threads > 1 {
        vec![1, threads]
    } else {
        vec![1]
    };

    // 1. Fast sweep, whole DEM as observers and context.
    let mut rows = Vec::new();
    let mut fast_at = Vec::new();
    let mut identical = true;
    let mut runs: Vec<(usize, Vec<f64>)> = Vec::new();
    for &thr in &thread_counts {
        let mut times = Vec::with_capacity(repeat);
        for r in 0..repeat {
            say(format!(
                "fast sweep, {w}×{h} observers, {a} azimuths, {thr} thread(s), run {}/{repeat}",
                r + 1
            ));
            let (t, at) = in_pool(thr, || {
                let t0 = Instant::now();
                let out = horizons(&ctx, full, a, Method::Fast);
                let t = t0.elapsed().as_secs_f64();
                (t, gather(&out))
            })?;
            times.push(t);
            if fast_at.is_empty() {
                fast_at = at;
            } else {
                identical &= fast_at
                    .iter()
                    .zip(&at)
                    .all(|(p, q)| p.to_bits() == q.to_bits());
            }
        }
        let t = times.iter().copied().fold(f64::INFINITY, f64::min);
        runs.push((thr, times));
        rows.push(row(
            format!("fast sweep, whole {w}×{h} DEM"),
            thr,
            plane,
            t,
            t,
        ));
    }
    let fast_1 = rows[0].wall_s;
    let fast_all = rows.last().map_or(fast_1, |r| r.wall_s);
    if rows.len() > 1 {
        rows[1].scaling = Some(fast_1 / fast_all);
    }
    let fast_ns_by: Vec<(usize, f64)> = rows
        .iter()
        .map(|r| (r.threads, r.core_ns_per_px_az))
        .collect();
    let fast_ns = |thr: usize| {
        fast_ns_by
            .iter()
            .find(|r| r.0 == thr)
            .map_or(f64::NAN, |r| r.1)
    };
    let (fast_ns_1, fast_ns_all) = (fast_ns(1), fast_ns(threads));

    // Context check: the centre quarter as observers, the whole DEM as context.
    let centre = Rect {
        x0: 3 * w / 8,
        y0: 3 * h / 8,
        w: w / 4,
        h: h / 4,
    };
    say(format!(
        "fast sweep, centre {}×{} observers, whole-DEM context, {threads} thread(s)",
        centre.w, centre.h
    ));
    let t_centre = in_pool(threads, || {
        let t0 = Instant::now();
        std::hint::black_box(horizons(&ctx, centre, a, Method::Fast));
        t0.elapsed().as_secs_f64()
    })?;
    let centre_obs = centre.w * centre.h;
    let centre_row = row(
        format!(
            "fast sweep, centre {}×{} observers, whole-DEM context",
            centre.w, centre.h
        ),
        threads,
        centre_obs,
        t_centre,
        f64::NAN,
    );
    let centre_ratio = centre_row.core_ns_per_px_az / fast_ns_all;

    // 2. Reference on random pixels, each its own 1×1 rectangle. Every call scans the raster
    // for its highest point once; that scan is timed and taken out.
    let t_hmax = best_of(20, || {
        std::hint::black_box(ctx.max_height());
        Ok(())
    })?;
    let reference = |step: f64, pix: &[(usize, usize)]| -> Vec<f32> {
        let v: Vec<Vec<f32>> = pix
            .par_iter()
            .map(|&(x, y)| {
                let r = Rect {
                    x0: x,
                    y0: y,
                    w: 1,
                    h: 1,
                };
                if step == 0.0 {
                    horizons(&ctx, r, a, Method::Reference)
                } else {
                    horizons_reference_step(&ctx, r, a, step)
                }
            })
            .collect();
        v.concat()
    };
    let n_ref = pix.len();
    let mut ref_at = Vec::new();
    let mut ref_one = f64::NAN;
    let mut ref_scan_share = Vec::new();
    for &thr in &thread_counts {
        say(format!(
            "reference (exact), {n_ref} random pixels, {a} azimuths, {thr} thread(s)"
        ));
        let (t, at) = in_pool(thr, || {
            let t0 = Instant::now();
            let at = reference(0.0, &pix);
            (t0.elapsed().as_secs_f64(), at)
        })?;
        if ref_at.is_empty() {
            ref_at = at;
        }
        let scan = n_ref as f64 * t_hmax / thr as f64;
        ref_scan_share.push(format!("{:.0}% on {thr} thread(s)", 100.0 * scan / t));
        let net = (t - scan).max(1e-9);
        let mut r = row(
            format!("reference (exact, continuous surface), {n_ref} random pixels"),
            thr,
            n_ref,
            net,
            f64::NAN,
        );
        r.whole_dem_wall_s = r.core_ns_per_px_az * 1e-9 * px_az / thr as f64;
        r.fast_speedup = Some(r.core_ns_per_px_az / fast_ns(thr));
        if thr == 1 {
            ref_one = net;
        } else {
            r.scaling = Some(ref_one / net);
        }
        rows.push(r);
    }
    rows.push(centre_row);

    // A march sampling every ½ px (what the issue allowed) on a subset: how far sampling is
    // from the exact maximum.
    let fine = &pix[..n_ref.min(256)];
    say(format!(
        "sampled march (½ px), {} random pixels, {threads} thread(s)",
        fine.len()
    ));
    let (t_fine, fine_at) = in_pool(threads, || {
        let t0 = Instant::now();
        let at = reference(0.5, fine);
        (t0.elapsed().as_secs_f64(), at)
    })?;
    let fine_net = (t_fine - fine.len() as f64 * t_hmax / threads as f64).max(1e-9);
    let mut r = row(
        format!("sampled march, ½-px steps, {} random pixels", fine.len()),
        threads,
        fine.len(),
        fine_net,
        f64::NAN,
    );
    r.whole_dem_wall_s = r.core_ns_per_px_az * 1e-9 * px_az / threads as f64;
    r.fast_speedup = Some(r.core_ns_per_px_az / fast_ns_all);
    rows.push(r);

    // 3. Accuracy.
    let nf = fine.len() * a;
    const EDGE: usize = 8;
    let inner: Vec<usize> = (0..pix.len())
        .filter(|&i| {
            let (x, y) = pix[i];
            x >= EDGE && y >= EDGE && x + EDGE < w && y + EDGE < h
        })
        .collect();
    let pick = |v: &[f32]| -> Vec<f32> {
        inner
            .iter()
            .flat_map(|&i| v[i * a..(i + 1) * a].iter().copied())
            .collect()
    };
    let inner_pix: Vec<(usize, usize)> = inner.iter().map(|&i| pix[i]).collect();
    let mut accuracy = vec![
        hz_accuracy("fast − reference", &fast_at, &ref_at, &pix, a),
        hz_accuracy(
            &format!("fast − reference, pixels ≥ {EDGE} px from the edges"),
            &pick(&fast_at),
            &pick(&ref_at),
            &inner_pix,
            a,
        ),
        hz_accuracy("fast − ½-px march", &fast_at[..nf], &fine_at, fine, a),
        hz_accuracy("½-px march − reference", &fine_at, &ref_at[..nf], fine, a),
    ];
    let mut near = Vec::new();
    let dem_notes = hz_real_dems(data, threads, &mut accuracy, &mut near, &say)?;

    // 4. Peers.
    let tsv = peers.join("results.tsv");
    let peer_rows = hz_peers(&tsv, size, a, fast_all, fast_1);

    // 5. Mars, 800 m/px, whole body.
    let mars_pixels =
        4.0 * std::f64::consts::PI * MARS_RADIUS_M * MARS_RADIUS_M / (MARS_PIXEL_M * MARS_PIXEL_M);
    let margin = 2.0
        * ((MARS_RADIUS_M + MARS_HMIN_M) / (MARS_RADIUS_M + MARS_HMAX_M)).acos()
        * MARS_RADIUS_M
        / MARS_PIXEL_M;
    let raw_h = mars_pixels * a as f64 * fast_ns_1 * 1e-9 / 3600.0;
    let factor = (MARS_TILE_PX + 2.0 * margin) / size as f64;
    let mut mars = HzMars {
        pixels: mars_pixels,
        azimuths: a,
        core_ns_per_px_az: fast_ns_1,
        raw_cpu_hours: raw_h,
        margin_px: margin,
        context_factor: factor,
        adjusted_cpu_hours: raw_h * factor,
        fitted_context_factor: f64::NAN,
        fitted_cpu_hours: f64::NAN,
        fritsch_cpu_hours: FRITSCH_CPU_HOURS,
    };

    let mut notes = vec![
        format!(
            "DEM: {} ({w}×{h}, {PEER_PIXEL_M} m pixels, heights {hmin:.0}…{hmax:.0} m) placed at \
             the centre of face +X with S = {s:.0} px across the face, R = {EARTH_RADIUS_M} m \
             (Earth, as r.horizon uses).",
            npy.display()
        ),
        if repeat == 1 {
            format!(
                "{threads} threads = all cores; 1-minute load average before the run: {load1}. \
                 One run per measurement (no repetitions; `--repeat` times the fast rows more \
                 often)."
            )
        } else {
            let list = runs
                .iter()
                .map(|(thr, ts)| {
                    let ts: Vec<String> = ts.iter().map(|t| format!("{t:.2}")).collect();
                    format!("{thr} thread(s) {} s", ts.join(", "))
                })
                .collect::<Vec<_>>()
                .join("; ");
            format!(
                "{threads} threads = all cores; 1-minute load average before the run: {load1}. \
                 The whole-DEM fast rows are the fastest of {repeat} runs ({list}); every other \
                 measurement is one run."
            )
        },
        format!(
            "Fast sweep: every pixel is an observer and sees the whole map (r.horizon's \
             default); its {n_ref}·{a} sampled values on 1 thread and on {threads} threads are \
             {}.",
            if identical { "bitwise identical" } else { "NOT identical" }
        ),
        format!(
            "Reference (exact): {n_ref} distinct random pixels (fixed-seed xorshift), each its own 1×1 \
             rectangle, parallel over pixels and azimuths; the raster max-height scan each call \
             makes ({:.2} ms, best of 20 timed separately) is subtracted ({}). Its whole-DEM wall is core-ns per \
             pixel·azimuth × {w}·{h}·{a} ÷ threads. Fast speed-up = reference ÷ fast time per \
             pixel·azimuth on the same threads.",
            t_hmax * 1e3,
            ref_scan_share.join(", ")
        ),
        format!(
            "Accuracy: Δ = first − second over the pixel·azimuths where both are finite; the \
             ½-px march rows use the first {} of the random pixels. The reference is the exact \
             maximum over the continuous bilinear surface (docs/horizons.md), so fast ≤ \
             reference and a sampled march ≤ reference.",
            fine.len()
        ),
        format!(
            "Context check: observers in the centre {}×{} with the whole DEM as context cost \
             {centre_ratio:.2}× the core time per pixel·azimuth of the whole-DEM run.",
            centre.w, centre.h
        ),
        format!(
            "Peers: from {}; \"scaled\" = peer wall × {a} ÷ its directions (shown when they \
             differ from {a}); ratio = scaled peer wall ÷ penumbra's fast wall (> 1: penumbra \
             is faster), against all cores and against 1 thread. cpu % and the load average \
             before each peer run are the peers' own columns.",
            tsv.display()
        ),
        format!(
            "Mars 800 m/px whole body: pixels = 4πR²/800² = {:.3e} (R = {MARS_RADIUS_M} m); \
             raw CPU-hours = pixels × {a} × {fast_ns_1:.1} ns (fast, 1 thread) = {raw_h:.1} h. \
             Context margin M = 2·acos((R + hmin)/(R + hmax))·R/800 = {margin:.0} px per side \
             (hmin = {MARS_HMIN_M} m, hmax = {MARS_HMAX_M} m) around a {MARS_TILE_PX}-px tile; \
             context factor = (512 + 2M)/{size} = {factor:.2} → {:.1} CPU-hours, against \
             Fritsch et al.'s ≈{FRITSCH_CPU_HOURS} CPU-hours.",
            mars_pixels,
            raw_h * factor
        ),
    ];
    notes.extend(dem_notes);
    // Per-observer cost ≈ α + β·ℓ, ℓ = swept line length per observer relative to the
    // whole-DEM run (1 there; (tile + look-side margin)/tile for a tile inside its context).
    let l_centre = (centre.w as f64 + 3.0 * w as f64 / 8.0) / centre.w as f64;
    let beta = (centre_ratio - 1.0) / (l_centre - 1.0);
    let l_mars = (MARS_TILE_PX + margin) / MARS_TILE_PX;
    let fitted = 1.0 + beta * (l_mars - 1.0);
    notes.push(format!(
        "Alternative context factor, from the context check: the sweep runs each line from the \
         context's far edge to the tile, so the samples per observer grow as ℓ = (tile + M)/tile \
         (here 1 for the whole DEM, {l_centre:.2} for the centre check); fitting cost ∝ 1 + \
         β(ℓ − 1) to the check gives β = {beta:.2} and, for ℓ = (512 + M)/512 = {l_mars:.2}, \
         ×{fitted:.2} → {:.1} CPU-hours.",
        raw_h * fitted
    ));
    mars.fitted_context_factor = fitted;
    mars.fitted_cpu_hours = raw_h * fitted;
    if !tsv.exists() {
        notes.push(format!("{}: not found; no peer rows.", tsv.display()));
    }

    if json {
        return penumbra_cli::output::print_json(&serde_json::json!({
            "dem": npy.display().to_string(),
            "width": w,
            "height": h,
            "azimuths": a,
            "threads": threads,
            "load1_before": load1,
            "fast_identical_across_threads": identical,
            "rows": rows,
            "accuracy": accuracy,
            "near_field": near,
            "peers": peer_rows,
            "mars": mars,
            "notes": notes,
        }));
    }
    print_horizon(
        &rows, &accuracy, &near, &peer_rows, &mars, &notes, a, markdown,
    );
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn print_horizon(
    rows: &[HzRow],
    accuracy: &[HzAccuracy],
    near: &[HzNear],
    peers: &[HzPeer],
    mars: &HzMars,
    notes: &[String],
    a: usize,
    markdown: bool,
) {
    let f = |v: Option<f64>, p: usize| v.map_or("–".to_string(), |v| format!("{v:.p$}"));
    let x = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.2}×"));
    if markdown {
        println!("| case | threads | observers | azimuths | wall s | whole-DEM wall s | Mpx·az/s | core-ns per px·az | scaling vs 1 thread | fast speed-up |");
        println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    }
    for r in rows {
        let whole = if r.whole_dem_wall_s.is_finite() {
            format!("{:.1}", r.whole_dem_wall_s)
        } else {
            "–".into()
        };
        if markdown {
            println!(
                "| {} | {} | {} | {} | {:.2} | {} | {:.2} | {:.1} | {} | {} |",
                r.case,
                r.threads,
                r.observers,
                r.azimuths,
                r.wall_s,
                whole,
                r.mpx_az_per_s,
                r.core_ns_per_px_az,
                x(r.scaling),
                x(r.fast_speedup)
            );
        } else {
            println!(
                "{:<58} {} thr {:>8} obs {:>4} az {:>9.2} s  whole DEM {:>9} s {:>8.2} Mpx·az/s {:>9.1} core-ns/px·az  scaling {}  fast speed-up {}",
                r.case,
                r.threads,
                r.observers,
                r.azimuths,
                r.wall_s,
                whole,
                r.mpx_az_per_s,
                r.core_ns_per_px_az,
                x(r.scaling),
                x(r.fast_speedup)
            );
        }
    }
    println!();
    if markdown {
        println!("| comparison | pixels | pixel·azimuths | RMS Δ ° | mean Δ ° | max abs Δ ° | share abs Δ > 0.5° | share abs Δ > 0.1° | worst |");
        println!("|---|---:|---:|---:|---:|---:|---:|---:|---|");
    }
    for r in accuracy {
        if markdown {
            println!(
                "| {} | {} | {} | {:.4} | {:+.4} | {:.3} | {:.3}% | {:.3}% | {} |",
                r.comparison,
                r.pixels,
                r.samples,
                r.rms_deg,
                r.mean_deg,
                r.max_abs_deg,
                100.0 * r.share_over_0_5_deg,
                100.0 * r.share_over_0_1_deg,
                r.worst
            );
        } else {
            println!(
                "{:<52} {:>5} px {:>8} px·az  RMS {:.4}°  mean {:+.4}°  max {:.3}°  >0.5°: {:.3}%  >0.1°: {:.3}%  worst: {}",
                r.comparison,
                r.pixels,
                r.samples,
                r.rms_deg,
                r.mean_deg,
                r.max_abs_deg,
                100.0 * r.share_over_0_5_deg,
                100.0 * r.share_over_0_1_deg,
                r.worst
            );
        }
    }
    println!();
    if !near.is_empty() {
        if markdown {
            println!("| fast method on | near field px | wall s | core-ns per px·az | RMS Δ ° | max abs Δ ° | share abs Δ > 0.5° |");
            println!("|---|---:|---:|---:|---:|---:|---:|");
        }
        for r in near {
            if markdown {
                println!(
                    "| {} | {} | {:.2} | {:.1} | {:.4} | {:.3} | {:.3}% |",
                    r.dem,
                    r.near_px,
                    r.wall_s,
                    r.core_ns_per_px_az,
                    r.rms_deg,
                    r.max_abs_deg,
                    100.0 * r.share_over_0_5_deg
                );
            } else {
                println!(
                    "{:<28} near {:>4} px {:>7.2} s {:>8.1} core-ns/px·az  RMS {:.4}°  max {:.3}°  >0.5°: {:.3}%",
                    r.dem,
                    r.near_px,
                    r.wall_s,
                    r.core_ns_per_px_az,
                    r.rms_deg,
                    r.max_abs_deg,
                    100.0 * r.share_over_0_5_deg
                );
            }
        }
        println!();
    }
    if markdown {
        println!("| peer | row | directions | wall s | cpu % | load1 before | wall s scaled to {a} az | peer ÷ penumbra (all cores) | peer ÷ penumbra (1 thread) | notes |");
        println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---|");
    }
    for p in peers {
        let scaled = match (p.scaled_wall_s, p.directions) {
            (Some(s), Some(d)) if d != a as f64 => format!("{s:.1} (scaled)"),
            (Some(s), _) => format!("{s:.1}"),
            _ => "–".into(),
        };
        let dash = |s: &str| {
            if s.is_empty() {
                "–".to_string()
            } else {
                s.to_string()
            }
        };
        if markdown {
            println!(
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                p.peer,
                p.name.as_deref().unwrap_or("–"),
                f(p.directions, 0),
                f(p.wall_s, 2),
                dash(&p.cpu_pct),
                dash(&p.load1_before),
                scaled,
                x(p.ratio_vs_all_cores),
                x(p.ratio_vs_1_thread),
                p.notes
            );
        } else {
            println!(
                "{:<16} {:<18} {:>4} dirs {:>9} s  cpu {:>5}  load {:>5}  {a}-az wall {:>16} s  ÷ penumbra: {} (all cores), {} (1 thread)  {}",
                p.peer,
                p.name.as_deref().unwrap_or("–"),
                f(p.directions, 0),
                f(p.wall_s, 2),
                dash(&p.cpu_pct),
                dash(&p.load1_before),
                scaled,
                x(p.ratio_vs_all_cores),
                x(p.ratio_vs_1_thread),
                p.notes
            );
        }
    }
    println!();
    println!(
        "Mars 800 m/px whole body, {} azimuths: {:.3e} pixels; raw {:.1} CPU-hours, context-adjusted (×{:.2}) {:.1} CPU-hours (fitted to the context check: ×{:.2}, {:.1} CPU-hours); Fritsch et al. ≈{:.0} CPU-hours.",
        mars.azimuths,
        mars.pixels,
        mars.raw_cpu_hours,
        mars.context_factor,
        mars.adjusted_cpu_hours,
        mars.fitted_context_factor,
        mars.fitted_cpu_hours,
        mars.fritsch_cpu_hours
    );
    println!();
    for n in notes {
        println!("- {n}");
    }
}
