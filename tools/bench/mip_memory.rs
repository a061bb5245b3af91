//! `penumbra-bench mip-memory`: peak RSS and wall time of `penumbra mip` and `penumbra horizon`
//! on the same DEM tiled with more and more levels, each run a fresh child process under GNU
//! time (issue #13, item 3).

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use serde::Serialize;

use penumbra::manifest::Tileset;

use crate::common::{penumbra_exe, tempfile_dir, timed};

#[derive(Serialize)]
struct MemRow {
    levels: u8,
    tiles: u64,
    finest_tiles: u64,
    /// Face-pyramid chunk files written by mip.
    face_chunks: u64,
    tile_wall_s: f64,
    tile_rss_mib: f64,
    mip_wall_s: f64,
    mip_rss_mib: f64,
    /// Horizon of the finest level (its tiles grow ~4× per level on this DEM).
    horizon_level: u8,
    horizon_wall_s: f64,
    horizon_rss_mib: f64,
    /// Horizon of one fixed level (the first run's finest) in every tileset: the same work.
    fixed_level: u8,
    fixed_wall_s: f64,
    fixed_rss_mib: f64,
    /// The finest-level horizon run by the `--against` build, just before this build's.
    #[serde(skip_serializing_if = "Option::is_none")]
    against_wall_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    against_rss_mib: Option<f64>,
}

#[allow(clippy::too_many_arguments)]
pub fn run_mip_memory(
    data: &Path,
    work: Option<PathBuf>,
    levels: &[u8],
    tile_size: u32,
    azimuths: usize,
    against: Option<&Path>,
    (mirror, same_levels): (usize, &[u8]),
    markdown: bool,
    json: bool,
    quiet: bool,
) -> Result<()> {
    if let Some(a) = against {
        if !a.is_file() {
            bail!(
                "{}: --against names no file; give another build's penumbra",
                a.display()
            );
        }
    }
    if levels.is_empty() {
        bail!("give at least one level count");
    }
    if levels.iter().chain(same_levels).any(|&l| l == 0) {
        bail!("--levels / --same-terrain-levels: a tileset has at least one level");
    }
    if mirror > 16 {
        bail!("--same-terrain {mirror}: at most 16 (the crop mirrored 16×16 is 4096² samples)");
    }
    let src = data.join("lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif");
    if !src.exists() {
        bail!("{}: not found; give --data", src.display());
    }
    let exe = penumbra_exe()?;
    let tmp = tempfile_dir(work)?;
    let threads = rayon::current_num_threads().to_string();
    let fixed = levels[0] - 1;
    let pen = |args: &[&str], dir: &Path| pen_cmd(&exe, &threads, args, dir);
    let mut rows = Vec::new();
    for &l in levels {
        let out = tmp.join(format!("shoemaker-{l}"));
        let _ = std::fs::remove_dir_all(&out);
        if !quiet {
            eprintln!("bench mip-memory: {l} levels");
        }
        let mut c = Command::new(&exe);
        c.args(["--quiet", "--threads", &threads, "tile"])
            .arg(&src)
            .args(["--body", "moon", "--tile-size", &tile_size.to_string()])
            .args(["--levels", &l.to_string(), "--out"])
            .arg(&out);
        let (tile_wall, tile_rss) = timed(&mut c, &tmp)?;
        let (mip_wall, mip_rss) = timed(&mut pen(&["mip"], &out), &tmp)?;
        let ts = Tileset::load(&out)?;
        let finest = ts.layout.levels - 1;
        let hz_args = |level: u8| {
            let (lv, az) = (level.to_string(), azimuths.to_string());
            ["horizon", "--levels", &lv, "--azimuths", &az].map(String::from)
        };
        let hz = |level: u8| {
            let args = hz_args(level);
            let args: Vec<&str> = args.iter().map(String::as_str).collect();
            timed(&mut pen(&args, &out), &tmp)
        };
        // The other build first, on a copy (a second run in the same tileset is up to date).
        let (against_wall, against_rss) = match against {
            Some(exe) => {
                let copy = tmp.join(format!("shoemaker-{l}-against"));
                let st = Command::new("cp").arg("-r").arg(&out).arg(&copy).status()?;
                if !st.success() {
                    bail!("cp -r {} {}: failed", out.display(), copy.display());
                }
                let mut c = Command::new(exe);
                c.args(["--quiet", "--threads", &threads])
                    .args(hz_args(finest))
                    .arg(&copy);
                let r = timed(&mut c, &tmp)?;
                let _ = std::fs::remove_dir_all(&copy);
                (Some(r.0), Some(r.1))
            }
            None => (None, None),
        };
        let (hz_wall, hz_rss) = hz(finest)?;
        // A second run of the same level would be "up to date": reuse the finest's figures.
        let (fixed_wall, fixed_rss) = if fixed == finest {
            (hz_wall, hz_rss)
        } else {
            hz(fixed)?
        };
        let face_chunks = walk_count(&out.join("minmax"), &|p: &Path| {
            p.components().any(|c| c.as_os_str() == "face")
        });
        rows.push(MemRow {
            levels: ts.layout.levels,
            tiles: ts.coverage.iter().map(|c| c.tiles).sum(),
            finest_tiles: ts
                .coverage
                .iter()
                .find(|c| c.level == finest)
                .map_or(0, |c| c.tiles),
            face_chunks,
            tile_wall_s: tile_wall,
            tile_rss_mib: tile_rss,
            mip_wall_s: mip_wall,
            mip_rss_mib: mip_rss,
            horizon_level: finest,
            horizon_wall_s: hz_wall,
            horizon_rss_mib: hz_rss,
            fixed_level: fixed,
            fixed_wall_s: fixed_wall,
            fixed_rss_mib: fixed_rss,
            against_wall_s: against_wall,
            against_rss_mib: against_rss,
        });
        let _ = std::fs::remove_dir_all(&out);
    }
    let same = if mirror > 0 {
        let ctx = MemCtx {
            exe: &exe,
            threads: &threads,
            tmp: &tmp,
            tile_size,
            azimuths,
            quiet,
        };
        same_terrain(&ctx, &src, same_levels, mirror)?
    } else {
        Vec::new()
    };
    let _ = std::fs::remove_dir_all(&tmp);
    if json {
        #[derive(Serialize)]
        struct Out<'a> {
            one_dem: &'a [MemRow],
            same_terrain: &'a [DepthRow],
        }
        return penumbra_cli::output::print_json(&Out {
            one_dem: &rows,
            same_terrain: &same,
        });
    }
    let base = &rows[0];
    let ratio = |v: f64, b: f64| v / b;
    if markdown {
        println!("| levels | tiles | finest-level tiles | face chunk files | tile RSS MiB | mip wall s | mip RSS MiB | mip RSS ÷ first | horizon level | horizon wall s | horizon RSS MiB | horizon RSS ÷ first | horizon L{fixed} wall s | horizon L{fixed} RSS MiB | L{fixed} RSS ÷ first |");
        println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    }
    for r in &rows {
        let (rm, rh, rf) = (
            ratio(r.mip_rss_mib, base.mip_rss_mib),
            ratio(r.horizon_rss_mib, base.horizon_rss_mib),
            ratio(r.fixed_rss_mib, base.fixed_rss_mib),
        );
        if markdown {
            println!(
                "| {} | {} | {} | {} | {:.1} | {:.2} | {:.1} | {:.2} | {} | {:.2} | {:.1} | {:.2} | {:.2} | {:.1} | {:.2} |",
                r.levels, r.tiles, r.finest_tiles, r.face_chunks, r.tile_rss_mib, r.mip_wall_s,
                r.mip_rss_mib, rm, r.horizon_level, r.horizon_wall_s, r.horizon_rss_mib, rh,
                r.fixed_wall_s, r.fixed_rss_mib, rf
            );
        } else {
            println!(
                "{:>2} levels, {:>5} tiles ({:>4} finest), {:>2} chunks: mip {:>6.2} s {:>6.1} MiB (×{:.2}); horizon L{} {:>6.2} s {:>6.1} MiB (×{:.2}); horizon L{} {:>5.2} s {:>6.1} MiB (×{:.2})",
                r.levels, r.tiles, r.finest_tiles, r.face_chunks, r.mip_wall_s, r.mip_rss_mib,
                rm, r.horizon_level, r.horizon_wall_s, r.horizon_rss_mib, rh, r.fixed_level,
                r.fixed_wall_s, r.fixed_rss_mib, rf
            );
        }
    }
    if markdown {
        println!();
        println!(
            "{threads} threads, {tile_size}-px tiles, {azimuths} azimuths; wall and peak RSS from \
             GNU time around each whole process; ratios against the {}-level run.",
            base.levels
        );
    }
    if let Some(b) = same.first() {
        if markdown {
            println!();
            println!("| levels | finest-level pixel m | tiles | finest-level tiles | mip wall s | mip RSS MiB | mip RSS ÷ first | finest-level horizon wall s | horizon RSS MiB | horizon RSS ÷ first |");
            println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        } else {
            println!("same terrain at each finest level:");
        }
        for r in &same {
            let (rm, rh) = (
                r.mip_rss_mib / b.mip_rss_mib,
                r.horizon_rss_mib / b.horizon_rss_mib,
            );
            if markdown {
                println!(
                    "| {} | {:.3} | {} | {} | {:.2} | {:.1} | {rm:.2} | {:.2} | {:.1} | {rh:.2} |",
                    r.levels,
                    r.finest_pixel_m,
                    r.tiles,
                    r.finest_tiles,
                    r.mip_wall_s,
                    r.mip_rss_mib,
                    r.horizon_wall_s,
                    r.horizon_rss_mib
                );
            } else {
                println!(
                    "{:>2} levels at {:.3} m/px, {:>5} tiles ({:>4} finest): mip {:>6.2} s {:>6.1} MiB (×{rm:.2}); horizon L{} {:>6.2} s {:>6.1} MiB (×{rh:.2})",
                    r.levels, r.finest_pixel_m, r.tiles, r.finest_tiles, r.mip_wall_s,
                    r.mip_rss_mib, r.levels - 1, r.horizon_wall_s, r.horizon_rss_mib
                );
            }
        }
        if markdown {
            println!();
            println!(
                "Same terrain at every finest level: the crop mirrored {mirror}×{mirror} times, \
                 centred on the south pole, with the finest level's pixel spacing as its own; \
                 {threads} threads, {tile_size}-px tiles, {azimuths} azimuths; ratios against \
                 the {}-level run.",
                b.levels
            );
        }
    }
    if let Some(exe) = against {
        if markdown {
            println!();
            println!("| levels | horizon level | other build wall s | other build RSS MiB | this build wall s | this build RSS MiB | RSS ÷ other | wall ÷ other |");
            println!("|---:|---:|---:|---:|---:|---:|---:|---:|");
        }
        for r in &rows {
            let (aw, ar) = (
                r.against_wall_s.unwrap_or(f64::NAN),
                r.against_rss_mib.unwrap_or(f64::NAN),
            );
            let (rr, rw) = (r.horizon_rss_mib / ar, r.horizon_wall_s / aw);
            if markdown {
                println!(
                    "| {} | {} | {aw:.2} | {ar:.1} | {:.2} | {:.1} | {rr:.2} | {rw:.2} |",
                    r.levels, r.horizon_level, r.horizon_wall_s, r.horizon_rss_mib
                );
            } else {
                println!(
                    "{:>2} levels, horizon L{}: this build {:.2} s {:.1} MiB, other {aw:.2} s {ar:.1} MiB (RSS ×{rr:.2}, wall ×{rw:.2})",
                    r.levels, r.horizon_level, r.horizon_wall_s, r.horizon_rss_mib
                );
            }
        }
        if markdown {
            println!();
            println!(
                "The finest-level horizon of each tileset by the other build ({}) on a copy, \
                 just before this build's run.",
                exe.display()
            );
        }
    }
    Ok(())
}

/// `penumbra --quiet --threads N <args> <dir>`.
fn pen_cmd(exe: &Path, threads: &str, args: &[&str], dir: &Path) -> Command {
    let mut c = Command::new(exe);
    c.args(["--quiet", "--threads", threads])
        .args(args)
        .arg(dir);
    c
}

/// What the same-terrain runs of `mip-memory` share.
struct MemCtx<'a> {
    exe: &'a Path,
    threads: &'a str,
    tmp: &'a Path,
    tile_size: u32,
    azimuths: usize,
    quiet: bool,
}

/// One level count of `mip-memory`'s same-terrain rows.
#[derive(Serialize)]
struct DepthRow {
    levels: u8,
    /// Pixel spacing of the finest level at the face centre, which the source DEM is given.
    finest_pixel_m: f64,
    tiles: u64,
    finest_tiles: u64,
    mip_wall_s: f64,
    mip_rss_mib: f64,
    horizon_wall_s: f64,
    horizon_rss_mib: f64,
}

/// Memory against level count with the work per level held fixed: the Shoemaker crop mirrored
/// `mirror`×`mirror` times into one raster centred on the south pole whose pixel spacing is,
/// for each level count, that of its finest level. Every tileset's finest level then holds the
/// same terrain pixels and tiles (enough to fill the horizon's context windows); only the depth
/// of the pyramid above it, and so the number of far rings, changes.
fn same_terrain(ctx: &MemCtx, src: &Path, levels: &[u8], mirror: usize) -> Result<Vec<DepthRow>> {
    let dem = penumbra::dem::open(src, 0)?;
    let (w, h) = (dem.width(), dem.height());
    let (sw, sh) = (w * mirror, h * mirror);
    // Mirror so that the copies meet without a step.
    let fold = |i: usize, n: usize| {
        let (k, r) = (i / n, i % n);
        if k % 2 == 0 {
            r
        } else {
            n - 1 - r
        }
    };
    let mut bytes = Vec::with_capacity(sw * sh * 4);
    for row in 0..sh {
        for col in 0..sw {
            let (v, _) = dem.value(fold(col, w), fold(row, h));
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    let body = penumbra::body::Body::preset("moon").context("the moon preset")?;
    let raw = ctx.tmp.join("same-terrain.bin");
    std::fs::write(&raw, &bytes).with_context(|| format!("writing {}", raw.display()))?;
    let mut rows = Vec::new();
    for &l in levels {
        let layout = penumbra::layout::Layout {
            projection: Default::default(),
            tile_size: ctx.tile_size,
            halo: 0,
            levels: l,
        };
        let dx = layout.centre_pixel_m(l - 1, body.radius_m);
        let sidecar = serde_json::json!({
            "width": sw, "height": sh, "sample_type": "f32", "byte_order": "little",
            "crs": {"kind": "polar-stereographic", "north": false, "lon0_deg": 0.0,
                    "lat_ts_deg": -90.0, "radius_m": body.radius_m},
            "x0": -dx * (sw as f64 - 1.0) / 2.0, "y0": dx * (sh as f64 - 1.0) / 2.0,
            "dx": dx, "dy": dx, "target": "moon",
        });
        let side = ctx.tmp.join("same-terrain.json");
        std::fs::write(&side, sidecar.to_string())
            .with_context(|| format!("writing {}", side.display()))?;
        let out = ctx.tmp.join(format!("same-terrain-{l}"));
        let _ = std::fs::remove_dir_all(&out);
        if !ctx.quiet {
            eprintln!("bench mip-memory: same terrain, {l} levels ({dx:.3} m/px)");
        }
        let size = ctx.tile_size.to_string();
        let lv = l.to_string();
        let mut tile = Command::new(ctx.exe);
        tile.args(["--quiet", "--threads", ctx.threads, "tile"])
            .arg(&raw)
            .args(["--tile-size", &size, "--levels", &lv, "--out"])
            .arg(&out);
        timed(&mut tile, ctx.tmp)?;
        let (mip_wall, mip_rss) =
            timed(&mut pen_cmd(ctx.exe, ctx.threads, &["mip"], &out), ctx.tmp)?;
        let finest = (l - 1).to_string();
        let az = ctx.azimuths.to_string();
        let hz = ["horizon", "--levels", &finest, "--azimuths", &az];
        let (hz_wall, hz_rss) = timed(&mut pen_cmd(ctx.exe, ctx.threads, &hz, &out), ctx.tmp)?;
        let ts = Tileset::load(&out)?;
        rows.push(DepthRow {
            levels: l,
            finest_pixel_m: dx,
            tiles: ts.coverage.iter().map(|c| c.tiles).sum(),
            finest_tiles: ts
                .coverage
                .iter()
                .find(|c| c.level == l - 1)
                .map_or(0, |c| c.tiles),
            mip_wall_s: mip_wall,
            mip_rss_mib: mip_rss,
            horizon_wall_s: hz_wall,
            horizon_rss_mib: hz_rss,
        });
        let _ = std::fs::remove_dir_all(&out);
    }
    Ok(rows)
}

/// Files below `dir` (recursively) whose path satisfies `keep`.
fn walk_count(dir: &Path, keep: &dyn Fn(&Path) -> bool) -> u64 {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    rd.flatten()
        .map(|e| {
            let p = e.path();
            if p.is_dir() {
                walk_count(&p, keep)
            } else {
                u64::from(keep(&p))
            }
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `--against` that names no file is refused before any work, naming the path.
    #[test]
    fn mip_memory_refuses_a_missing_other_build() {
        let dir = std::env::temp_dir().join(format!("no-such-penumbra-{}", std::process::id()));
        let err = run_mip_memory(
            Path::new("/nonexistent-data"),
            None,
            &[12],
            64,
            16,
            Some(&dir),
            (0, &[]),
            false,
            false,
            true,
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains(&dir.display().to_string()) && err.contains("--against"),
            "{err}"
        );
    }

    #[test]
    fn mip_memory_refuses_bad_same_terrain_options_before_any_work() {
        let run = |levels: &[u8], mirror: usize, same: &[u8]| {
            run_mip_memory(
                Path::new("/nonexistent-data"),
                None,
                levels,
                64,
                16,
                None,
                (mirror, same),
                false,
                false,
                true,
            )
            .unwrap_err()
            .to_string()
        };
        assert!(run(&[12], 17, &[12]).contains("--same-terrain 17"));
        assert!(run(&[12], 3, &[0, 12]).contains("at least one level"));
        assert!(run(&[0], 0, &[]).contains("at least one level"));
        // Good options get as far as the missing data.
        assert!(run(&[12], 3, &[12, 20]).contains("give --data"));
    }
}
