//! `penumbra-bench mip`: max and (min, max) pyramid throughput on a synthetic tile and on a whole
//! LDEM_4 tileset, against a plain memcpy of the same buffers measured in the same run.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::Serialize;

use penumbra::manifest::Tileset;

use crate::common::{best_of, in_pool, tempfile_dir, tile_ldem4};

/// Runs of the whole mip stage with each compression (alternating), the best reported.
const STAGE_REPS: usize = 5;

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

/// Forget a tileset's mipmaps so `build_mips` does the whole stage again.
fn reset_mips(dir: &Path) -> Result<()> {
    for sub in ["maxmip", "minmax"] {
        let _ = std::fs::remove_dir_all(dir.join(sub));
    }
    let mut ts = Tileset::load(dir)?;
    ts.products.mip = None;
    penumbra::fsio::write_atomic_bytes(
        &dir.join(penumbra::manifest::MANIFEST),
        serde_json::to_string_pretty(&ts)?.as_bytes(),
    )?;
    Ok(())
}

pub fn run_mip(
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
    // (threads, whole stage zip time ÷ none time)
    let mut stage_ratio: Vec<(usize, f64)> = Vec::new();
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
        tile_ldem4(&src_dem, &out)?;
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
            let p = penumbra::tileset::tile_path(&out, &pattern, id);
            tiles.push(penumbra::format::height::read_height_tile(&p)?.height);
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
            // The whole stage with and without compression, alternating run by run so that
            // both see the same state of the host's file system, each from a tileset without
            // mips whose earlier writes and removals are on disk already (outside the timer):
            // otherwise one run's write-back lands in the next one's commit (`syncfs`).
            let (mut t_zip, mut t_raw) = (f64::INFINITY, f64::INFINITY);
            in_pool(threads, || -> Result<()> {
                for _ in 0..STAGE_REPS {
                    for compression in [
                        penumbra::format::TileCompression::Zip,
                        penumbra::format::TileCompression::None,
                    ] {
                        let opts = MipOptions {
                            compression,
                            ..Default::default()
                        };
                        reset_mips(&out)?;
                        penumbra::fsio::sync_staged(&out)?;
                        let t0 = std::time::Instant::now();
                        mip::build_mips(&out, &opts, &penumbra::progress::NoProgress)?;
                        let t = t0.elapsed().as_secs_f64();
                        let best = match compression {
                            penumbra::format::TileCompression::Zip => &mut t_zip,
                            penumbra::format::TileCompression::None => &mut t_raw,
                        };
                        *best = best.min(t);
                    }
                }
                Ok(())
            })??;
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
            stage_ratio.push((threads, t_zip / t_raw));
        }
        let _ = std::fs::remove_dir_all(&tmp);
    }

    if json {
        return penumbra_cli::output::print_json(&serde_json::json!({
            "tile": rows_a,
            "tileset": rows_b,
            "whole_stage": stage_ratio
                .iter()
                .map(|&(threads, r)| serde_json::json!({"threads": threads, "zip_over_none": r}))
                .collect::<Vec<_>>(),
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
        let ratios: Vec<String> = stage_ratio
            .iter()
            .map(|(threads, r)| format!("{r:.2}× on {threads} thread(s)"))
            .collect();
        println!();
        println!("Whole stage, zip ÷ none: {}", ratios.join(", "));
    }
    if markdown {
        println!();
        println!(
            "Best of {} runs (tile) / {reps} runs (tileset; {STAGE_REPS} for the whole stage, zip and none alternating, each from a synced tileset); input GB/s = \
             stored f32 height bytes (halo included) ÷ time; memcpy = `copy_from_slice` of the \
             same buffers into a reused buffer on one core, in the same run. Pyramids write into \
             reused buffers except the \"fresh output buffers\" row.",
            reps.max(5) * 3
        );
    }
    Ok(())
}
