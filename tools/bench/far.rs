//! `penumbra-bench far-field`: the fast method's far rings (issue 15, item 1) — error against
//! run time and peak memory for several full-resolution margins (`--fine-margin-px`), on real
//! DEMs whose horizon reach is wider than the margins, against the exact method and the fast
//! method at full resolution over the whole reach, each a fresh `penumbra horizon` process.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Result};
use serde::Serialize;

use penumbra::layout::TileId;
use penumbra::manifest::Tileset;

use crate::common::{penumbra_exe, tempfile_dir, timed};

/// One DEM, how it is tiled, and the level whose horizons are computed (its finest).
struct Case {
    name: &'static str,
    dem: &'static str,
    tile_args: &'static [&'static str],
}

const CASES: &[Case] = &[
    Case {
        name: "Gale (MOLA 463 m/px), 128-px tiles",
        dem: "mola_gale_128ppd_crop/gale-mola.bin",
        tile_args: &["--body", "mars", "--tile-size", "128"],
    },
    Case {
        name: "Hawaiʻi (SRTM3 N19W156), 128-px tiles",
        dem: "srtm3/N19W156.hgt",
        tile_args: &["--tile-size", "128"],
    },
];

#[derive(Serialize)]
struct Row {
    case: String,
    level: u8,
    tiles: usize,
    /// `exact`, `fast (whole reach)` or `fast, fine margin N px`.
    run: String,
    fine_margin_px: Option<u64>,
    tiles_with_far_rings: u64,
    wall_s: f64,
    rss_mib: f64,
    /// Against the exact method, degrees, over samples where both see terrain.
    rms_deg: f64,
    p99_deg: f64,
    max_deg: f64,
    /// Share of samples more than 0.01° below / above the exact method.
    below_pct: f64,
    above_pct: f64,
    /// The same against the fast method at full resolution: what the rings alone change.
    rings_rms_deg: f64,
    rings_p99_deg: f64,
    rings_max_deg: f64,
}

/// Error statistics of `got` against `want` (degrees; −90 = nothing in that direction, NaN =
/// no observer: pairs where either is left out).
fn stats(want: &[f32], got: &[f32]) -> (f64, f64, f64, f64, f64) {
    let mut d: Vec<f64> = want
        .iter()
        .zip(got)
        .filter(|(a, b)| a.is_finite() && b.is_finite() && **a > -89.9 && **b > -89.9)
        .map(|(a, b)| *b as f64 - *a as f64)
        .collect();
    if d.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN, f64::NAN, f64::NAN);
    }
    let n = d.len() as f64;
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let below = d.iter().filter(|v| **v < -0.01).count() as f64 / n * 100.0;
    let above = d.iter().filter(|v| **v > 0.01).count() as f64 / n * 100.0;
    for v in &mut d {
        *v = v.abs();
    }
    d.sort_unstable_by(f64::total_cmp);
    let p99 = d[((n * 0.99) as usize).min(d.len() - 1)];
    (rms, p99, d[d.len() - 1], below, above)
}

/// Every horizon map of `level`, in tile order, concatenated.
fn maps(dir: &Path, level: u8) -> Result<(Vec<f32>, usize, u64)> {
    let ts = Tileset::load(dir)?;
    let n = ts.layout.tile_size as usize;
    let ids: Vec<TileId> = ts
        .tile_set()
        .into_iter()
        .filter(|t| t.level == level)
        .collect();
    let mut all = Vec::new();
    for &id in &ids {
        let (_, m) =
            penumbra::horizon::read_horizon_exr(&penumbra::horizon::tile_path(dir, id), n)?;
        all.extend_from_slice(&m);
    }
    let rings = ts
        .products
        .horizon
        .as_ref()
        .and_then(|h| h.distances.iter().find(|d| d.level == level))
        .map_or(0, |d| d.tiles_with_far_rings);
    Ok((all, ids.len(), rings))
}

#[allow(clippy::too_many_arguments)]
pub fn run(
    data: &Path,
    work: Option<PathBuf>,
    margins: &[u64],
    azimuths: usize,
    only: Option<&str>,
    markdown: bool,
    json: bool,
    quiet: bool,
) -> Result<()> {
    let exe = penumbra_exe()?;
    let tmp = tempfile_dir(work)?;
    let threads = rayon::current_num_threads().to_string();
    let mut rows = Vec::new();
    for case in CASES {
        if let Some(o) = only {
            if !case.name.to_lowercase().contains(&o.to_lowercase()) {
                continue;
            }
        }
        let src = data.join(case.dem);
        if !src.exists() {
            bail!("{}: not found; give --data", src.display());
        }
        let out = tmp.join("case");
        let _ = std::fs::remove_dir_all(&out);
        let mut c = Command::new(&exe);
        c.args(["--quiet", "--threads", &threads, "tile"])
            .arg(&src)
            .args(case.tile_args)
            .arg("--out")
            .arg(&out);
        timed(&mut c, &tmp)?;
        let level = Tileset::load(&out)?.layout.levels - 1;
        let horizon = |extra: &[String]| -> Result<(f64, f64)> {
            let mut c = Command::new(&exe);
            c.args(["--quiet", "--threads", &threads, "horizon"])
                .arg(&out)
                .args(["--levels", &level.to_string()])
                .args(["--azimuths", &azimuths.to_string(), "--precision", "f32"])
                .args(extra);
            timed(&mut c, &tmp)
        };
        let say = |what: &str| {
            if !quiet {
                eprintln!("bench far-field: {}, level {level}: {what}", case.name);
            }
        };
        say("exact");
        let (ex_wall, ex_rss) = horizon(&["--method".into(), "exact".into()])?;
        let (exact, tiles, _) = maps(&out, level)?;
        say("fast, whole reach at full resolution");
        let whole = *penumbra::horizon::FINE_MARGIN_PX.end();
        let (fw_wall, fw_rss) = horizon(&["--fine-margin-px".into(), whole.to_string()])?;
        let (full, _, _) = maps(&out, level)?;
        let (rms, p99, max, below, above) = stats(&exact, &full);
        let nan = f64::NAN;
        rows.push(Row {
            case: case.name.into(),
            level,
            tiles,
            run: "exact".into(),
            fine_margin_px: None,
            tiles_with_far_rings: 0,
            wall_s: ex_wall,
            rss_mib: ex_rss,
            rms_deg: 0.0,
            p99_deg: 0.0,
            max_deg: 0.0,
            below_pct: 0.0,
            above_pct: 0.0,
            rings_rms_deg: nan,
            rings_p99_deg: nan,
            rings_max_deg: nan,
        });
        rows.push(Row {
            case: case.name.into(),
            level,
            tiles,
            run: "fast, whole reach at full resolution".into(),
            fine_margin_px: Some(whole),
            tiles_with_far_rings: 0,
            wall_s: fw_wall,
            rss_mib: fw_rss,
            rms_deg: rms,
            p99_deg: p99,
            max_deg: max,
            below_pct: below,
            above_pct: above,
            rings_rms_deg: 0.0,
            rings_p99_deg: 0.0,
            rings_max_deg: 0.0,
        });
        for &m in margins {
            say(&format!("fast, fine margin {m} px"));
            let (wall, rss) = horizon(&["--fine-margin-px".into(), m.to_string()])?;
            let (got, _, rings) = maps(&out, level)?;
            let (rms, p99, max, below, above) = stats(&exact, &got);
            let (rr, rp, rm, _, _) = stats(&full, &got);
            rows.push(Row {
                case: case.name.into(),
                level,
                tiles,
                run: format!("fast, fine margin {m} px"),
                fine_margin_px: Some(m),
                tiles_with_far_rings: rings,
                wall_s: wall,
                rss_mib: rss,
                rms_deg: rms,
                p99_deg: p99,
                max_deg: max,
                below_pct: below,
                above_pct: above,
                rings_rms_deg: rr,
                rings_p99_deg: rp,
                rings_max_deg: rm,
            });
        }
        let _ = std::fs::remove_dir_all(&out);
    }
    let _ = std::fs::remove_dir_all(&tmp);
    if json {
        return penumbra_cli::output::print_json(&rows);
    }
    if markdown {
        println!("| DEM | level | tiles | run | tiles with far rings | wall s | peak RSS MiB | wall ÷ whole-reach fast | RMS ° | p99 ° | max ° | < −0.01° % | > +0.01° % | rings alone: RMS ° | p99 ° | max ° |");
        println!("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    }
    let mut base = f64::NAN;
    for r in &rows {
        if r.run.starts_with("fast, whole") {
            base = r.wall_s;
        }
        let ratio = if r.run == "exact" {
            String::from("–")
        } else {
            format!("{:.2}", r.wall_s / base)
        };
        let f = |v: f64, p: usize| {
            if v.is_nan() {
                "–".to_string()
            } else {
                format!("{v:.p$}")
            }
        };
        if markdown {
            println!(
                "| {} | {} | {} | {} | {} | {:.1} | {:.1} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.case,
                r.level,
                r.tiles,
                r.run,
                r.tiles_with_far_rings,
                r.wall_s,
                r.rss_mib,
                ratio,
                f(r.rms_deg, 4),
                f(r.p99_deg, 4),
                f(r.max_deg, 2),
                f(r.below_pct, 2),
                f(r.above_pct, 2),
                f(r.rings_rms_deg, 4),
                f(r.rings_p99_deg, 4),
                f(r.rings_max_deg, 2)
            );
        } else {
            println!(
                "{:<40} L{} {:<38} rings {:>4} {:>7.1} s {:>6.1} MiB ×{:<5} rms {} p99 {} max {} | rings alone rms {} p99 {} max {}",
                r.case,
                r.level,
                r.run,
                r.tiles_with_far_rings,
                r.wall_s,
                r.rss_mib,
                ratio,
                f(r.rms_deg, 4),
                f(r.p99_deg, 4),
                f(r.max_deg, 2),
                f(r.rings_rms_deg, 4),
                f(r.rings_p99_deg, 4),
                f(r.rings_max_deg, 2)
            );
        }
    }
    if markdown {
        println!();
        println!(
            "{threads} threads, {azimuths} azimuths, f32 maps; wall and peak RSS from GNU time \
             around each `penumbra horizon` process; errors over every sample where both runs see \
             terrain (−90° and no-data left out)."
        );
    }
    Ok(())
}

/// One extrapolated bake: a body, its pixel size, the area covered and the terrain range that
/// sets the reach.
struct Bake {
    name: &'static str,
    radius_m: f64,
    pixel_m: f64,
    /// Fraction of the body's surface covered.
    area_fraction: f64,
    hmin_m: f64,
    hmax_m: f64,
    /// Fritsch et al.'s figure, where they give one.
    published_cpu_hours: Option<f64>,
}

const BAKES: &[Bake] = &[
    Bake {
        name: "Mars 800 m/px, whole body",
        radius_m: 3_396_190.0,
        pixel_m: 800.0,
        area_fraction: 1.0,
        hmin_m: -8_200.0,
        hmax_m: 21_200.0,
        published_cpu_hours: Some(150.0),
    },
    Bake {
        name: "Moon 5 m/px, 80–90°S",
        radius_m: 1_737_400.0,
        pixel_m: 5.0,
        // 2πR²(1 − cos 10°) of 4πR².
        area_fraction: 0.007_596,
        hmin_m: -9_130.0,
        hmax_m: 10_790.0,
        published_cpu_hours: None,
    },
];

/// Synthetic terrain at global plane pixel (gx, gy) of a level with `px_m`-metre pixels:
/// sinusoidal octaves from 200 km down to two pixels, amplitude ∝ wavelength^0.8 (3 km at
/// 200 km), each at its own direction and phase: the same surface at every level, smoothed
/// where a level's pixels are too coarse for an octave.
fn synth(gx: f64, gy: f64, px_m: f64) -> f32 {
    let (x, y) = (gx * px_m, gy * px_m);
    let mut h = 0.0;
    let mut lambda = 200_000.0f64;
    let mut i = 0.0f64;
    while lambda >= 2.0 * px_m && i < 24.0 {
        let th = 2.399_963 * i; // golden angle: no two octaves aligned
        let amp = 3000.0 * (lambda / 200_000.0).powf(0.8);
        let k = std::f64::consts::TAU / lambda;
        h += amp * (k * (x * th.cos() + y * th.sin()) + 1.7 * i).sin();
        lambda *= 0.5;
        i += 1.0;
    }
    h as f32
}

/// A context of `level_px_m`-metre pixels on face +X with `s` pixels across, over the global
/// window `win`, filled with [`synth`].
fn synth_context(
    s: f64,
    win: (i64, i64, i64, i64),
    px_m: f64,
    radius_m: f64,
) -> penumbra::horizon::Context {
    let (w, h) = ((win.2 - win.0) as usize, (win.3 - win.1) as usize);
    let mut heights = vec![0.0f32; w * h];
    use rayon::prelude::*;
    heights.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
        for (c, v) in row.iter_mut().enumerate() {
            *v = synth((win.0 + c as i64) as f64, (win.1 + r as i64) as f64, px_m);
        }
    });
    penumbra::horizon::Context {
        face: penumbra::cube::Face::Px,
        face_pixels: s,
        origin: (win.0, win.1),
        width: w,
        height: h,
        heights,
        radius_m,
    }
}

/// A tile's time (scaled to 360 azimuths): CPU seconds on one thread, and with a device its
/// wall seconds for the context's own horizons (the far rings are then the CPU seconds).
struct TileTime {
    core_s: f64,
    device_s: Option<f64>,
    reach_px: u64,
    rings: usize,
}

/// Core seconds per 512² tile at 360 azimuths for `bake`, measured on one thread over
/// synthetic terrain with the geometry of a tile at the face centre: the fine context and the
/// far rings `penumbra horizon` would build for that reach (`azimuths` timed, scaled to 360).
fn per_tile_core_s(
    bake: &Bake,
    azimuths: usize,
    method: penumbra::horizon::Method,
    device: Option<&dyn penumbra::horizon::device::SweepDevice>,
) -> Result<TileTime> {
    use penumbra::horizon::{FarRing, Rect};
    let n = 512i64;
    let fine = penumbra::horizon::default_fine_margin_px(n as u32) as i64;
    let reach_rad =
        penumbra::horizon::reach_rad(bake.radius_m, bake.hmin_m, bake.hmax_m, bake.hmax_m);
    // Pixels of arc at the face centre (a gnomonic pixel there is 2/S of the plane).
    let needed = (reach_rad * bake.radius_m / bake.pixel_m).ceil() as i64;
    let s =
        (std::f64::consts::FRAC_PI_2 * bake.radius_m / bake.pixel_m / n as f64).round() * n as f64;
    let t0 = (s as i64 / 2 / n) * n;
    let m = needed.min(fine);
    let win = (t0 - m, t0 - m, t0 + n + m, t0 + n + m);
    let ctx = synth_context(s, win, bake.pixel_m, bake.radius_m);
    let rect = Rect {
        x0: m as usize,
        y0: m as usize,
        w: n as usize,
        h: n as usize,
    };
    let mut rings = Vec::new();
    let (mut prev, mut reach, mut k) = (win, m, 0u32);
    while reach < needed {
        k += 1;
        let f = 1i64 << k;
        let foot = (t0 / f, t0 / f, (t0 + n + f - 1) / f, (t0 + n + f - 1) / f);
        let margin = fine.min((needed + f - 1) / f);
        let w = (
            foot.0 - margin,
            foot.1 - margin,
            foot.2 + margin,
            foot.3 + margin,
        );
        let c = synth_context(s / f as f64, w, bake.pixel_m * f as f64, bake.radius_m);
        rings.extend(FarRing::new(c, foot, prev, f as u32));
        reach = margin * f;
        prev = w;
    }
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let scale = 360.0 / azimuths as f64;
    let mut device_s = None;
    let own = match device {
        Some(d) => {
            let t = std::time::Instant::now();
            let own = penumbra::horizon::device::horizons_sweep_on(d, &ctx, rect, azimuths)?;
            device_s = Some(t.elapsed().as_secs_f64() * scale);
            Some(own)
        }
        None => None,
    };
    let t = std::time::Instant::now();
    pool.install(|| {
        let mut far = match own {
            Some(own) => penumbra::horizon::FarHorizons::from_own(&ctx, rect, azimuths, own),
            None => penumbra::horizon::FarHorizons::new(
                &ctx,
                rect,
                azimuths,
                penumbra::horizon::DEFAULT_NEAR_PX,
                method,
            ),
        };
        for r in &rings {
            far.add_ring(r);
        }
        far.finish()
    });
    Ok(TileTime {
        core_s: t.elapsed().as_secs_f64() * scale,
        device_s,
        reach_px: needed as u64,
        rings: rings.len(),
    })
}

/// The extrapolation table: per bake, the measured core seconds per tile and the CPU-hours.
pub fn extrapolate(
    azimuths: usize,
    device: Option<&dyn penumbra::horizon::device::SweepDevice>,
    markdown: bool,
    json: bool,
) -> Result<()> {
    #[derive(Serialize)]
    struct X {
        bake: &'static str,
        method: &'static str,
        /// With a device: its wall seconds per tile for the context's own horizons, and its
        /// minutes for the bake (the far rings stay in `core_s_per_tile`, on the CPU).
        device_s_per_tile: Option<f64>,
        device_minutes: Option<f64>,
        pixels: f64,
        tiles: f64,
        reach_px: u64,
        fine_margin_px: u64,
        rings: usize,
        core_s_per_tile: f64,
        cpu_hours: f64,
        published_cpu_hours: Option<f64>,
    }
    let mut rows = Vec::new();
    use penumbra::horizon::Method;
    type Device<'a> = Option<&'a dyn penumbra::horizon::device::SweepDevice>;
    let mut runs: Vec<(&Bake, Method, Device)> = Vec::new();
    for b in BAKES.iter() {
        runs.push((b, Method::Fast, None));
        runs.push((b, Method::Sweep, None));
        if device.is_some() {
            runs.push((b, Method::Sweep, device));
        }
    }
    for (b, method, on) in runs {
        let pixels = 4.0 * std::f64::consts::PI * b.radius_m * b.radius_m * b.area_fraction
            / (b.pixel_m * b.pixel_m);
        let tiles = pixels / (512.0 * 512.0);
        let t = per_tile_core_s(b, azimuths, method, on)?;
        rows.push(X {
            bake: b.name,
            method: if on.is_some() {
                "sweep (gpu)"
            } else {
                method.name()
            },
            device_s_per_tile: t.device_s,
            device_minutes: t.device_s.map(|s| tiles * s / 60.0),
            pixels,
            tiles,
            reach_px: t.reach_px,
            fine_margin_px: penumbra::horizon::default_fine_margin_px(512),
            rings: t.rings,
            core_s_per_tile: t.core_s,
            cpu_hours: tiles * t.core_s / 3600.0,
            published_cpu_hours: b.published_cpu_hours,
        });
    }
    if json {
        return penumbra_cli::output::print_json(&rows);
    }
    if markdown {
        println!("| bake | method | pixels | 512² tiles | reach px | fine margin px | far rings | core s per tile (360 az) | CPU-hours | GPU s per tile | GPU-minutes | published |");
        println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    }
    for r in &rows {
        let p = r
            .published_cpu_hours
            .map_or("–".into(), |h| format!("≈ {h:.0}"));
        if markdown {
            let dev = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.2}"));
            println!(
                "| {} | {} | {:.3e} | {:.0} | {} | {} | {} | {:.1} | {:.1} | {} | {} | {} |",
                r.bake,
                r.method,
                r.pixels,
                r.tiles,
                r.reach_px,
                r.fine_margin_px,
                r.rings,
                r.core_s_per_tile,
                r.cpu_hours,
                dev(r.device_s_per_tile),
                dev(r.device_minutes),
                p
            );
        } else {
            println!(
                "{:<28} {:<6} {:.3e} px, {:>7.0} tiles, reach {:>6} px, {} rings: {:.1} core-s/tile → {:.1} CPU-hours (published {p})",
                r.bake, r.method, r.pixels, r.tiles, r.reach_px, r.rings, r.core_s_per_tile, r.cpu_hours
            );
        }
    }
    if markdown {
        println!();
        println!(
            "One thread; {azimuths} azimuths timed and scaled to 360; synthetic terrain \
             (sinusoidal octaves 200 km … 2 px, 3 km amplitude at 200 km ∝ λ^0.8) on the context \
             and far rings `penumbra horizon` builds for a 512-px tile at the face centre with \
             the reach of the body's terrain range (worst case: the tile at the highest \
             terrain)."
        );
    }
    Ok(())
}
