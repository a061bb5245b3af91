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

use crate::bench::{penumbra_exe, tempfile_dir, timed};

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
