//! `penumbra bench`: throughput against a baseline measured in the same run, printed as a table
//! (markdown with `--markdown`, for docs/benchmarks.md) or JSON.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use clap::Subcommand;
use serde::Serialize;

use penumbra::manifest::Tileset;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Tiling throughput and peak RSS on the shared DEMs, against gdalwarp reprojecting the same
    /// DEM to a gnomonic cube face at the same pixel spacing (skipped when gdalwarp is absent).
    Tiling {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Scratch folder for outputs (removed afterwards).
        #[arg(long)]
        work: Option<PathBuf>,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
    /// Max and (min, max) pyramid throughput on a synthetic 2048² tile and on a whole LDEM_4
    /// tileset, against a plain memcpy of the same buffers measured in the same run.
    Mip {
        /// Folder holding the shared DEMs.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Scratch folder for the LDEM_4 tileset (removed afterwards).
        #[arg(long)]
        work: Option<PathBuf>,
        /// Repetitions per measurement (the best is reported).
        #[arg(long, default_value_t = 7)]
        reps: usize,
        #[arg(long)]
        markdown: bool,
        #[arg(long)]
        json: bool,
    },
}

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

/// Run `cmd` under GNU time; (wall seconds, peak RSS MiB).
fn timed(cmd: &mut Command, scratch: &Path) -> Result<(f64, f64)> {
    let tf = scratch.join("time.txt");
    let prog = cmd.get_program().to_owned();
    let args: Vec<_> = cmd.get_args().map(|a| a.to_owned()).collect();
    let t0 = std::time::Instant::now();
    let out = if Path::new("/usr/bin/time").exists() {
        Command::new("/usr/bin/time")
            .arg("-f")
            .arg("%e %M")
            .arg("-o")
            .arg(&tf)
            .arg(&prog)
            .args(&args)
            .output()?
    } else {
        cmd.output()?
    };
    let wall = t0.elapsed().as_secs_f64();
    if !out.status.success() {
        bail!(
            "{} failed: {}",
            prog.to_string_lossy(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let rss = std::fs::read_to_string(&tf)
        .ok()
        .and_then(|s| {
            s.split_whitespace()
                .nth(1)
                .and_then(|k| k.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |k| k / 1024.0);
    Ok((wall, rss))
}

fn gdalwarp_available() -> bool {
    Command::new("gdalwarp")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Reproject with gdalwarp onto the gnomonic plane of the face that holds most of penumbra's
/// finest-level tiles, over those tiles' bounding box, at the same pixel spacing.
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

pub fn run(cmd: BenchCommand, quiet: bool) -> Result<()> {
    match cmd {
        BenchCommand::Tiling {
            data,
            work,
            markdown,
            json,
        } => run_tiling(data, work, markdown, json, quiet),
        BenchCommand::Mip {
            data,
            work,
            reps,
            markdown,
            json,
        } => run_mip(&data, work, reps.max(1), markdown, json, quiet),
    }
}

fn run_tiling(
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
    let tmp = tempfile_dir(work)?;
    let exe = std::env::current_exe()?;
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
        let _ = std::fs::remove_dir_all(&out);
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
        let (wall, rss) = timed(&mut c, &tmp)?;
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
            match gdalwarp_case(&src, &ts, &tmp) {
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
        return crate::output::print_json(&rows);
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
        println!("{threads} threads; wall and peak RSS from GNU time around each whole process.");
    }
    Ok(())
}

fn tempfile_dir(work: Option<PathBuf>) -> Result<PathBuf> {
    let base = work.unwrap_or_else(std::env::temp_dir);
    let p = base.join(format!("penumbra-bench-{}", std::process::id()));
    std::fs::create_dir_all(&p).with_context(|| format!("creating {}", p.display()))?;
    Ok(p)
}

// ---------------------------------------------------------------------------------------------
// bench mip

/// Best wall time of `reps` runs of `f`, in seconds.
fn best_of(reps: usize, mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    let mut best = f64::INFINITY;
    for _ in 0..reps {
        let t0 = std::time::Instant::now();
        f()?;
        best = best.min(t0.elapsed().as_secs_f64());
    }
    Ok(best)
}

/// A deterministic synthetic tile: ridges, craters and xorshift noise, with a no-data hole.
fn synthetic_tile(s: usize) -> Vec<f32> {
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut v = Vec::with_capacity(s * s);
    for j in 0..s {
        for i in 0..s {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let noise = (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
            let (x, y) = (i as f32 / s as f32, j as f32 / s as f32);
            let hole = (x - 0.7).powi(2) + (y - 0.3).powi(2) < 0.0004;
            v.push(if hole {
                f32::NAN
            } else {
                3000.0 * (9.0 * x).sin() * (7.0 * y).cos() - 1500.0 * (40.0 * x * y).sin()
                    + 50.0 * noise
            });
        }
    }
    v
}

#[derive(Serialize)]
struct MipRow {
    case: String,
    threads: usize,
    input_mb: f64,
    best_s: f64,
    input_gb_s: f64,
    /// input GB/s ÷ one-core memcpy GB/s of the same buffers.
    ratio_vs_memcpy: f64,
    /// Speed-up over the same case on 1 thread.
    scaling: Option<f64>,
}

fn mip_row(case: &str, threads: usize, bytes: f64, t: f64, memcpy_gb_s: f64) -> MipRow {
    let gb_s = bytes / t / 1e9;
    MipRow {
        case: case.into(),
        threads,
        input_mb: bytes / 1e6,
        best_s: t,
        input_gb_s: gb_s,
        ratio_vs_memcpy: gb_s / memcpy_gb_s,
        scaling: None,
    }
}

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    Ok(rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?
        .install(f))
}

/// Forget a tileset's mipmaps so `build_mips` does the whole stage again.
fn reset_mips(dir: &Path) -> Result<()> {
    for sub in ["maxmip", "minmax"] {
        let _ = std::fs::remove_dir_all(dir.join(sub));
    }
    let mut ts = Tileset::load(dir)?;
    ts.products.mip = None;
    penumbra::tileio::write_atomic_bytes(
        &dir.join(penumbra::manifest::MANIFEST),
        serde_json::to_string_pretty(&ts)?.as_bytes(),
    )?;
    Ok(())
}

fn run_mip(
    data: &Path,
    work: Option<PathBuf>,
    reps: usize,
    markdown: bool,
    json: bool,
    quiet: bool,
) -> Result<()> {
    use penumbra::mip::{self, MaxPyramid, MinMaxPyramid, MipOptions};
    use rayon::prelude::*;

    // (a) One 2048² tile with a 2-px halo, on this thread.
    let (n, halo) = (2048usize, 2usize);
    let s = n + 2 * halo;
    let src = synthetic_tile(s);
    let bytes = (s * s * 4) as f64;
    let mut dst = vec![0.0f32; s * s];
    let mut maxp = MaxPyramid::new(n);
    let mut mmp = MinMaxPyramid::new(n);
    // Warm up every buffer so no run pays for page faults.
    dst.copy_from_slice(&src);
    mip::max_pyramid_into(&src, s, halo, &mut maxp)?;
    mip::minmax_pyramid_into(&src, s, halo, &mut mmp)?;
    let reps_a = reps.max(5) * 3;
    let t_copy = best_of(reps_a, || {
        dst.copy_from_slice(std::hint::black_box(&src));
        std::hint::black_box(&dst);
        Ok(())
    })?;
    let t_max = best_of(reps_a, || {
        mip::max_pyramid_into(std::hint::black_box(&src), s, halo, &mut maxp)?;
        std::hint::black_box(&maxp);
        Ok(())
    })?;
    let t_mm = best_of(reps_a, || {
        mip::minmax_pyramid_into(std::hint::black_box(&src), s, halo, &mut mmp)?;
        std::hint::black_box(&mmp);
        Ok(())
    })?;
    let t_mm_alloc = best_of(reps_a, || {
        std::hint::black_box(mip::minmax_pyramid(std::hint::black_box(&src), s, halo)?);
        Ok(())
    })?;
    let memcpy_gb_s = bytes / t_copy / 1e9;
    let tile_case = format!("{n}² f32 tile ({s}² stored)");
    let mut rows_a = vec![
        mip_row(
            &format!("{tile_case}: memcpy"),
            1,
            bytes,
            t_copy,
            memcpy_gb_s,
        ),
        mip_row(
            &format!("{tile_case}: max pyramid"),
            1,
            bytes,
            t_max,
            memcpy_gb_s,
        ),
        mip_row(
            &format!("{tile_case}: min/max pyramid"),
            1,
            bytes,
            t_mm,
            memcpy_gb_s,
        ),
        mip_row(
            &format!("{tile_case}: min/max pyramid, fresh output buffers"),
            1,
            bytes,
            t_mm_alloc,
            memcpy_gb_s,
        ),
    ];
    rows_a.iter_mut().for_each(|r| r.scaling = None);

    // (b) A whole LDEM_4 tileset.
    let mut rows_b = Vec::new();
    let mut note_b = String::new();
    let src_dem = data.join("lola_ldem4/LDEM_4.LBL");
    if !src_dem.exists() {
        note_b = format!(
            "skipped the LDEM_4 tileset: {} not found",
            src_dem.display()
        );
        if !quiet {
            eprintln!("{note_b}");
        }
    } else {
        let tmp = tempfile_dir(work)?;
        let out = tmp.join("ldem4");
        if !quiet {
            eprintln!("bench mip: tiling LDEM_4 (--tile-size 256 --levels 4)");
        }
        let exe = std::env::current_exe()?;
        let status = Command::new(&exe)
            .args(["--quiet", "tile"])
            .arg(&src_dem)
            .args([
                "--body",
                "moon",
                "--tile-size",
                "256",
                "--levels",
                "4",
                "--out",
            ])
            .arg(&out)
            .stdout(std::process::Stdio::null())
            .status()?;
        if !status.success() {
            bail!("tiling LDEM_4 for the benchmark failed");
        }
        let ts = Tileset::load(&out)?;
        let pattern = ts
            .products
            .height
            .as_ref()
            .context("no heights")?
            .path
            .clone();
        let (tn, th) = (ts.layout.tile_size as usize, ts.layout.halo as usize);
        let ts_s = ts.layout.stored_size();
        let mut tiles = Vec::new();
        for id in ts.tile_set() {
            let p =
                penumbra::tileio::tile_path(&out, &pattern, id.level, id.face.name(), id.x, id.y);
            tiles.push(penumbra::tileio::read_height_tile(&p)?.height);
        }
        let total = (tiles.len() * ts_s * ts_s * 4) as f64;
        let case = format!(
            "LDEM_4 tileset: {} tiles of {ts_s}² ({tn} + 2·{th} halo), 4 levels",
            tiles.len()
        );
        // memcpy of every tile into a reused buffer, one core.
        let mut buf = vec![0.0f32; ts_s * ts_s];
        let t_copy = best_of(reps, || {
            for t in &tiles {
                buf.copy_from_slice(std::hint::black_box(t));
                std::hint::black_box(&buf);
            }
            Ok(())
        })?;
        let memcpy_b = total / t_copy / 1e9;
        rows_b.push(mip_row(
            &format!("{case}: memcpy"),
            1,
            total,
            t_copy,
            memcpy_b,
        ));
        let mut one = [0.0f64; 5];
        for threads in [1usize, 2] {
            let t_max = in_pool(threads, || {
                best_of(reps, || {
                    tiles.par_iter().try_for_each_init(
                        || MaxPyramid::new(tn),
                        |p, t| mip::max_pyramid_into(t, ts_s, th, p),
                    )?;
                    Ok(())
                })
            })??;
            let t_mm = in_pool(threads, || {
                best_of(reps, || {
                    tiles.par_iter().try_for_each_init(
                        || MinMaxPyramid::new(tn),
                        |p, t| mip::minmax_pyramid_into(t, ts_s, th, p),
                    )?;
                    Ok(())
                })
            })??;
            let stage = |compression| {
                let opts = MipOptions {
                    compression,
                    ..Default::default()
                };
                in_pool(threads, || {
                    best_of(reps.min(3), || {
                        reset_mips(&out)?;
                        mip::build_mips(&out, &opts, &penumbra::progress::NoProgress)?;
                        Ok(())
                    })
                })?
            };
            let t_zip = stage(penumbra::tileio::TileCompression::Zip)?;
            let t_raw = stage(penumbra::tileio::TileCompression::None)?;
            let cases = [
                ("max pyramid, compute only", t_max),
                ("min/max pyramid, compute only", t_mm),
                (
                    "`build_mips` whole stage, zip (read, both pyramids, EXR writes)",
                    t_zip,
                ),
                ("`build_mips` whole stage, `--compression none`", t_raw),
            ];
            for (k, (what, t)) in cases.into_iter().enumerate() {
                let mut r = mip_row(&format!("{case}: {what}"), threads, total, t, memcpy_b);
                if threads == 1 {
                    one[k] = t;
                } else {
                    r.scaling = Some(one[k] / t);
                }
                rows_b.push(r);
            }
        }
        let _ = std::fs::remove_dir_all(&tmp);
    }

    if json {
        return crate::output::print_json(&serde_json::json!({
            "tile": rows_a,
            "tileset": rows_b,
            "note": note_b,
        }));
    }
    let print = |rows: &[MipRow]| {
        if markdown {
            println!("| case | threads | input MB | best ms | input GB/s | ÷ memcpy (1 core) | scaling vs 1 thread |");
            println!("|---|---:|---:|---:|---:|---:|---:|");
        }
        for r in rows {
            let sc = r.scaling.map_or("–".to_string(), |v| format!("{v:.2}×"));
            if markdown {
                println!(
                    "| {} | {} | {:.1} | {:.2} | {:.2} | {:.2} | {} |",
                    r.case,
                    r.threads,
                    r.input_mb,
                    r.best_s * 1e3,
                    r.input_gb_s,
                    r.ratio_vs_memcpy,
                    sc
                );
            } else {
                println!(
                    "{:<100} {} thr {:>8.1} MB {:>9.2} ms {:>7.2} GB/s {:>5.2}× memcpy  scaling {}",
                    r.case,
                    r.threads,
                    r.input_mb,
                    r.best_s * 1e3,
                    r.input_gb_s,
                    r.ratio_vs_memcpy,
                    sc
                );
            }
        }
    };
    print(&rows_a);
    println!();
    if rows_b.is_empty() {
        println!("{note_b}");
    } else {
        print(&rows_b);
    }
    if markdown {
        println!();
        println!(
            "Best of {} runs (tile) / {reps} runs (tileset; 3 for the whole stage); input GB/s = \
             stored f32 height bytes (halo included) ÷ time; memcpy = `copy_from_slice` of the \
             same buffers into a reused buffer on one core, in the same run. Pyramids write into \
             reused buffers except the \"fresh output buffers\" row.",
            reps.max(5) * 3
        );
    }
    Ok(())
}
