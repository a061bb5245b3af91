//! `penumbra-bench tiling`: throughput and peak RSS of `penumbra tile` on the shared DEMs,
//! against gdalwarp reprojecting the same DEM to a gnomonic cube face at the same pixel spacing.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use serde::Serialize;

use penumbra::manifest::Tileset;

use crate::common::{penumbra_exe, tempfile_dir, timed};

/// Runs of each tiling case and of its gdalwarp peer, the best reported.
const TILING_REPS: usize = 3;

struct Case {
    name: &'static str,
    file: &'static str,
    body: &'static str,
    levels: Option<u8>,
    extra: &'static [&'static str],
}

const CASES: &[Case] = &[
    Case {
        name: "LDEM_4 Moon global 0.25° (PDS3 int16)",
        file: "lola_ldem4/LDEM_4.LBL",
        body: "moon",
        levels: None,
        extra: &[],
    },
    Case {
        name: "LDEM_4, 4 levels (8× oversampled)",
        file: "lola_ldem4/LDEM_4.LBL",
        body: "moon",
        levels: Some(4),
        extra: &[],
    },
    Case {
        name: "LDEM_4, 4 levels, --prefilter point",
        file: "lola_ldem4/LDEM_4.LBL",
        body: "moon",
        levels: Some(4),
        extra: &["--prefilter", "point"],
    },
    Case {
        name: "LDEM_4, 4 levels, point, --compression none",
        file: "lola_ldem4/LDEM_4.LBL",
        body: "moon",
        levels: Some(4),
        extra: &["--prefilter", "point", "--compression", "none"],
    },
    Case {
        name: "MEGDR Mars global 0.25° (PDS3 MSB int16)",
        file: "mola_megt90n000cb/megt90n000cb.lbl",
        body: "mars",
        levels: None,
        extra: &[],
    },
    Case {
        name: "SRTM3 N19W156 Hawaiʻi (.hgt)",
        file: "srtm3/N19W156.hgt",
        body: "earth",
        levels: None,
        extra: &[],
    },
    Case {
        name: "Shoemaker 5 m polar (GeoTIFF f32)",
        file: "lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif",
        body: "moon",
        levels: None,
        extra: &[],
    },
    Case {
        name: "Gale MOLA 128 px/° (raw u16 + JSON)",
        file: "mola_gale_128ppd_crop/gale-mola.bin",
        body: "mars",
        levels: None,
        extra: &[],
    },
];

#[derive(Serialize, Default)]
struct Row {
    case: String,
    source_mpx: f64,
    levels: u8,
    tiles: u64,
    output_mpx: f64,
    wall_s: f64,
    peak_rss_mib: f64,
    source_mpx_per_s: f64,
    output_mpx_per_s: f64,
    gdalwarp_output_mpx: Option<f64>,
    gdalwarp_wall_s: Option<f64>,
    gdalwarp_peak_rss_mib: Option<f64>,
    gdalwarp_output_mpx_per_s: Option<f64>,
    /// Penumbra output Mpx/s ÷ gdalwarp output Mpx/s.
    ratio_vs_gdalwarp: Option<f64>,
    note: String,
}

fn gdalwarp_available() -> bool {
    Command::new("gdalwarp")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Reproject with gdalwarp onto the gnomonic plane of the face that holds most of penumbra's
/// finest-level tiles, over those tiles' bounding box, at the same pixel spacing.
/// [`gdalwarp_case`] [`TILING_REPS`] times, each after a sync of the scratch file system:
/// the best wall time, the largest peak RSS, and the output Mpx.
fn gdalwarp_best(src: &Path, ts: &Tileset, scratch: &Path) -> Result<(f64, f64, f64)> {
    let (mut wall, mut rss, mut mpx) = (f64::INFINITY, 0.0f64, 0.0);
    for _ in 0..TILING_REPS {
        penumbra::fsio::sync_staged(scratch)?;
        let (w, r, m) = gdalwarp_case(src, ts, scratch)?;
        (wall, rss, mpx) = (wall.min(w), rss.max(r), m);
    }
    Ok((wall, rss, mpx))
}

fn gdalwarp_case(src: &Path, ts: &Tileset, scratch: &Path) -> Result<(f64, f64, f64)> {
    let lay = ts.layout;
    let finest = lay.levels - 1;
    let cov = ts
        .coverage
        .iter()
        .find(|c| c.level == finest)
        .context("no finest level")?;
    let (face, runs) = cov
        .faces
        .iter()
        .max_by_key(|(_, r)| r.iter().map(|r| r[2] - r[1] + 1).sum::<u32>())
        .context("no tiles")?;
    let (mut x0, mut x1, mut y0, mut y1) = (u32::MAX, 0, u32::MAX, 0);
    for r in runs {
        y0 = y0.min(r[0]);
        y1 = y1.max(r[0]);
        x0 = x0.min(r[1]);
        x1 = x1.max(r[2]);
    }
    let per = lay.tiles_per_side(finest) as f64;
    let rad = ts.body.radius_m;
    let u = |x: u32| -1.0 + 2.0 * x as f64 / per;
    let v = |y: u32| 1.0 - 2.0 * y as f64 / per;
    let (lat0, lon0) = match face.name() {
        "px" => (0, 0),
        "nx" => (0, 180),
        "py" => (0, 90),
        "ny" => (0, -90),
        "pz" => (90, 0),
        _ => (-90, 0),
    };
    let w = (x1 - x0 + 1) * lay.tile_size;
    let h = (y1 - y0 + 1) * lay.tile_size;
    let t_srs = format!("+proj=gnom +lat_0={lat0} +lon_0={lon0} +R={rad} +units=m +no_defs");
    let out = scratch.join("gdalwarp.tif");
    let mut cmd = Command::new("gdalwarp");
    cmd.args([
        "-q",
        "-overwrite",
        "-r",
        "bilinear",
        "-ot",
        "Float32",
        "-multi",
    ])
    .args(["-wo", "NUM_THREADS=ALL_CPUS", "-t_srs", &t_srs, "-te"])
    .arg(format!("{}", rad * u(x0)))
    .arg(format!("{}", rad * v(y1 + 1)))
    .arg(format!("{}", rad * u(x1 + 1)))
    .arg(format!("{}", rad * v(y0)))
    .args(["-ts", &w.to_string(), &h.to_string()]);
    if !matches!(
        ts.source.georef.crs,
        penumbra::dem::Crs::PolarStereographic { .. }
    ) {
        cmd.args(["-s_srs", &format!("+proj=longlat +R={rad} +no_defs")]);
    }
    cmd.arg(src).arg(&out);
    let (wall, rss) = timed(&mut cmd, scratch)?;
    Ok((wall, rss, (w as f64 * h as f64) / 1e6))
}

pub fn run_tiling(
    data: PathBuf,
    work: Option<PathBuf>,
    markdown: bool,
    json: bool,
    quiet: bool,
) -> Result<()> {
    if !data.is_dir() {
        bail!(
            "{}: shared data folder not found; give --data",
            data.display()
        );
    }
    let exe = penumbra_exe()?;
    let tmp = tempfile_dir(work)?;
    let have_gdal = gdalwarp_available();
    let mut rows = Vec::new();
    for case in CASES {
        let src = data.join(case.file);
        if !src.exists() {
            if !quiet {
                eprintln!("skipping {}: {} not found", case.name, src.display());
            }
            continue;
        }
        if !quiet {
            eprintln!("bench: {}", case.name);
        }
        let out = tmp.join("tiles");
        // Best of TILING_REPS, each run from a fresh output folder with the earlier runs'
        // writes and removals on disk (outside the timer): otherwise the commit's `syncfs`
        // also flushes what the run before left (the previous case, gdalwarp's file).
        let (mut wall, mut rss) = (f64::INFINITY, 0.0f64);
        for _ in 0..TILING_REPS {
            let _ = std::fs::remove_dir_all(&out);
            penumbra::fsio::sync_staged(&tmp)?;
            let mut c = Command::new(&exe);
            c.args(["--quiet", "tile"])
                .arg(&src)
                .args(["--body", case.body, "--out"])
                .arg(&out)
                .arg("--json");
            c.args(case.extra);
            if let Some(l) = case.levels {
                c.args(["--levels", &l.to_string()]);
            }
            let (w, r) = timed(&mut c, &tmp)?;
            wall = wall.min(w);
            rss = rss.max(r);
        }
        let ts = Tileset::load(&out)?;
        let tiles: u64 = ts.coverage.iter().map(|c| c.tiles).sum();
        let side = ts.layout.stored_size() as f64;
        let out_mpx = tiles as f64 * side * side / 1e6;
        let src_mpx = (ts.source.width * ts.source.height) as f64 / 1e6;
        let mut row = Row {
            case: case.name.into(),
            source_mpx: src_mpx,
            levels: ts.layout.levels,
            tiles,
            output_mpx: out_mpx,
            wall_s: wall,
            peak_rss_mib: rss,
            source_mpx_per_s: src_mpx / wall,
            output_mpx_per_s: out_mpx / wall,
            ..Default::default()
        };
        if have_gdal {
            match gdalwarp_best(&src, &ts, &tmp) {
                Ok((gw, grss, gmpx)) => {
                    row.gdalwarp_output_mpx = Some(gmpx);
                    row.gdalwarp_wall_s = Some(gw);
                    row.gdalwarp_peak_rss_mib = Some(grss);
                    row.gdalwarp_output_mpx_per_s = Some(gmpx / gw);
                    row.ratio_vs_gdalwarp = Some((out_mpx / wall) / (gmpx / gw));
                }
                Err(e) => {
                    row.note = format!("gdalwarp: {e:#}")
                        .lines()
                        .next()
                        .unwrap_or("")
                        .into()
                }
            }
        } else {
            row.note = "gdalwarp not installed".into();
        }
        rows.push(row);
    }
    let _ = std::fs::remove_dir_all(&tmp);
    if json {
        return penumbra_cli::output::print_json(&rows);
    }
    let threads = rayon::current_num_threads();
    if markdown {
        println!("| DEM | source Mpx | levels | tiles | output Mpx | wall s | peak RSS MiB | source Mpx/s | output Mpx/s | gdalwarp output Mpx | gdalwarp wall s | gdalwarp RSS MiB | gdalwarp Mpx/s | penumbra ÷ gdalwarp |");
        println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    }
    for r in &rows {
        let f = |v: Option<f64>, p: usize| v.map_or("–".to_string(), |v| format!("{v:.p$}"));
        if markdown {
            println!(
                "| {} | {:.2} | {} | {} | {:.1} | {:.2} | {:.0} | {:.2} | {:.1} | {} | {} | {} | {} | {} |",
                r.case, r.source_mpx, r.levels, r.tiles, r.output_mpx, r.wall_s, r.peak_rss_mib,
                r.source_mpx_per_s, r.output_mpx_per_s, f(r.gdalwarp_output_mpx, 1),
                f(r.gdalwarp_wall_s, 2), f(r.gdalwarp_peak_rss_mib, 0),
                f(r.gdalwarp_output_mpx_per_s, 1), f(r.ratio_vs_gdalwarp, 2)
            );
        } else {
            println!(
                "{:<44} {:>7.2} Mpx in, {:>3} tiles, {:>7.1} Mpx out, {:>6.2} s, {:>5.0} MiB, {:>6.1} Mpx/s out; gdalwarp {} Mpx/s, ratio {} {}",
                r.case, r.source_mpx, r.tiles, r.output_mpx, r.wall_s, r.peak_rss_mib,
                r.output_mpx_per_s, f(r.gdalwarp_output_mpx_per_s, 1), f(r.ratio_vs_gdalwarp, 2), r.note
            );
        }
    }
    if markdown {
        println!();
        println!(
            "{threads} threads; wall (best of {TILING_REPS}) and peak RSS (largest) from GNU time \
             around each whole process, each run started after a sync of the scratch folder's \
             file system (penumbra's run ends with its own sync; gdalwarp's does not)."
        );
    }
    Ok(())
}
