//! Horizons: the fast sweep against the brute-force reference and against analytic answers.

use penumbra::cube::Face;
use penumbra::horizon::{self, Context, Method, Rect};

use crate::util::{diff_stats, rough, shared_data};

/// A raster of `w × h` pixels of `pixel_m` metres centred on face `face` of a body of radius
/// `radius_m`, offset by `(dx, dy)` pixels from the face centre.
fn context(
    face: Face,
    radius_m: f64,
    pixel_m: f64,
    w: usize,
    h: usize,
    heights: Vec<f32>,
) -> Context {
    let s = (2.0 * radius_m / pixel_m).round();
    Context {
        face,
        face_pixels: s,
        origin: ((s as i64 - w as i64) / 2, (s as i64 - h as i64) / 2),
        width: w,
        height: h,
        heights,
        radius_m,
    }
}

/// Heights of a whole DEM in `../shared/data` as a raster (row-major), or None (skip).
fn shared_raster(rel: &str) -> Option<(usize, usize, Vec<f32>)> {
    let p = shared_data()?.join(rel);
    let d = penumbra::dem::open(&p, 64).unwrap();
    let (w, h) = (d.width(), d.height());
    let mut v = vec![0.0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            v[r * w + c] = d.value(c, r).0;
        }
    }
    Some((w, h, v))
}

/// Fast against reference on one block: every fast value is the elevation of a real point of
/// the observer's own ray, so it never exceeds the exact reference; returns (rms, max).
fn compare(ctx: &Context, rect: Rect, a: usize, label: &str) -> (f64, f64) {
    let fast = horizon::horizons(ctx, rect, a, Method::Fast);
    let reference = horizon::horizons(ctx, rect, a, Method::Reference);
    let mut over = 0.0f32;
    for (f, r) in fast.iter().zip(&reference) {
        assert_eq!(f.is_nan(), r.is_nan());
        over = over.max(f - r);
    }
    let (rms, max, n) = diff_stats(&fast, &reference);
    let worse = fast
        .iter()
        .zip(&reference)
        .filter(|(f, r)| (*f - *r).abs() > 0.5)
        .count();
    eprintln!(
        "{label}: fast vs reference over {n} pixel·azimuths: RMS {rms:.4}°, max {max:.3}°, \
         {worse} above 0.5°, fast above reference by at most {over:.1e}°"
    );
    assert!(
        over <= 1e-3,
        "{label}: fast exceeds the exact reference by {over}°"
    );
    // The exact method (max-pyramid walk) is the reference's answer, not an approximation.
    let exact = horizon::horizons(ctx, rect, a, Method::Exact);
    let (_, emax, en) = diff_stats(&exact, &reference);
    for (e, r) in exact.iter().zip(&reference) {
        assert_eq!(
            e.is_nan(),
            r.is_nan(),
            "{label}: exact and reference disagree on no data"
        );
    }
    let worst = (0..exact.len())
        .filter(|&i| exact[i].is_finite())
        .max_by(|&i, &j| {
            (exact[i] - reference[i])
                .abs()
                .total_cmp(&(exact[j] - reference[j]).abs())
        })
        .map(|i| {
            (
                i / (rect.w * rect.h),
                i % (rect.w * rect.h),
                exact[i],
                reference[i],
            )
        });
    assert!(
        en == n && emax <= 5e-4,
        "{label}: exact differs from the reference by {emax}° ({en} of {n} values); worst \
         (azimuth, pixel, exact, reference) {worst:?}"
    );
    (rms, max)
}

#[test]
fn reference_is_the_continuous_maximum() {
    // Against a march sampling every 1/64 px the exact cell-by-cell search is never lower (it
    // is the maximum of the same continuous surface) and never much higher.
    let (w, h) = (96, 96);
    let ctx = context(
        Face::Px,
        1_737_400.0,
        100.0,
        w,
        h,
        rough(w, h, 800.0, (64, 1), 0.0, 3),
    );
    let rect = Rect {
        x0: 40,
        y0: 40,
        w: 12,
        h: 12,
    };
    let exact = horizon::horizons(&ctx, rect, 24, Method::Reference);
    let dense = horizon::horizons_reference_step(&ctx, rect, 24, 1.0 / 64.0);
    let half = horizon::horizons_reference_step(&ctx, rect, 24, 0.5);
    let mut below = 0.0f32;
    for (e, d) in exact.iter().zip(&dense) {
        below = below.max(d - e);
    }
    let (rms, max, _) = diff_stats(&exact, &dense);
    let (rms2, max2, _) = diff_stats(&exact, &half);
    eprintln!(
        "exact vs 1/64-px march: RMS {rms:.4}° max {max:.3}° (dense above exact by {below:.1e}°); \
         vs ½-px march: RMS {rms2:.3}° max {max2:.2}°"
    );
    assert!(
        below <= 1e-3,
        "a dense sample beats the exact maximum by {below}°"
    );
    // Above it by what 1/64-px sampling misses of sharp bilinear ridges.
    assert!(max <= 0.25 && rms <= 0.02, "exact vs dense: {rms} {max}");
    // The ½-px march the issue allowed is visibly coarser on rough terrain.
    assert!(max2 > max);
}

#[test]
fn fast_on_rough_synthetic_terrain() {
    // 1-px value noise on top of larger octaves: rougher than any real DEM at its own
    // resolution, so looser bounds than the real-data acceptance.
    let (w, h) = (128, 128);
    let ctx = context(
        Face::Px,
        1_737_400.0,
        100.0,
        w,
        h,
        rough(w, h, 800.0, (64, 1), 0.0, 7),
    );
    let (rms, max) = compare(
        &ctx,
        Rect {
            x0: 50,
            y0: 50,
            w: 20,
            h: 20,
        },
        36,
        "rough",
    );
    assert!(rms <= 0.2 && max <= 4.0, "rms {rms} max {max}");

    // The near field trades time for accuracy: with none the fast method rests on the sweep's
    // lines alone, with a wide one it is the reference out to there; both stay ≤ reference.
    let block = Rect {
        x0: 50,
        y0: 50,
        w: 20,
        h: 20,
    };
    let reference = horizon::horizons(&ctx, block, 36, Method::Reference);
    let mut rms_by = Vec::new();
    for near_px in [0.0, 8.0, 64.0] {
        let fast = horizon::horizons_with(&ctx, block, 36, Method::Fast, near_px);
        for (f, r) in fast.iter().zip(&reference) {
            assert!(
                *f <= r + 1e-3,
                "near {near_px}: fast {f} above reference {r}"
            );
        }
        rms_by.push(diff_stats(&fast, &reference).0);
    }
    eprintln!("rough: RMS with near field 0 / 8 / 64 px: {rms_by:?}");
    assert!(rms_by[0] > rms_by[1] && rms_by[1] > rms_by[2], "{rms_by:?}");
}

/// The acceptance on a real DEM read as a raster: fast within RMS 0.05°, max 0.5° of the
/// exact reference over a 24×24 block from (x0, y0), 36 azimuths.
fn acceptance_on(rel: &str, radius_m: f64, pixel_m: f64, blocks: &[Rect], label: &str) {
    let Some((w, h, v)) = shared_raster(rel) else {
        return;
    };
    let ctx = context(Face::Px, radius_m, pixel_m, w, h, v);
    for &rect in blocks {
        let label = format!("{label} {}² at ({}, {})", rect.w, rect.x0, rect.y0);
        let (rms, max) = compare(&ctx, rect, 36, &label);
        assert!(rms <= 0.05 && max <= 0.5, "{label}: rms {rms} max {max}");
    }
}

fn block(x0: usize, y0: usize, n: usize) -> Rect {
    Rect { x0, y0, w: n, h: n }
}

#[test]
fn fast_matches_reference_on_gale_crater() {
    // MOLA 128 px/deg: 463 m pixels; Mars radius. The block holds Aeolis Mons' flank.
    acceptance_on(
        "mola_gale_128ppd_crop/gale-mola.bin",
        3_396_190.0,
        463.0,
        &[block(390, 330, 24), block(300, 300, 48)],
        "Gale",
    );
}

#[test]
fn fast_matches_reference_on_hawaii() {
    // SRTM3: 3″ ≈ 92 m (north-south); Mauna Kea's summit area near row 240, column 630.
    acceptance_on(
        "srtm3/N19W156.hgt",
        6_371_008.8,
        92.0,
        &[block(610, 225, 24), block(560, 200, 64)],
        "Hawaii",
    );
}

#[test]
fn fast_matches_reference_on_ldem4_polar_tiles() {
    let Some(data) = shared_data() else {
        return;
    };
    use penumbra::body::Body;
    use penumbra::layout::TileId;
    use penumbra::manifest::Tileset;
    use penumbra::progress::NoProgress;
    use penumbra::tiling::{tile_dem, TileOptions};
    let dir = tempfile::tempdir().unwrap();
    let dem = penumbra::dem::open(&data.join("lola_ldem4/LDEM_4.LBL"), 64).unwrap();
    let opts = TileOptions {
        tile_size: 128,
        levels: Some(2),
        ..Default::default()
    };
    tile_dem(
        &dem,
        &Body::preset("moon").unwrap(),
        dir.path(),
        &opts,
        None,
        &NoProgress,
    )
    .unwrap();
    let ts = Tileset::load(dir.path()).unwrap();
    let src = penumbra::tileset::Store::open(dir.path()).unwrap();
    let (lo, hi) = horizon::terrain_range(&ts).unwrap();
    // The south pole is the corner of four tiles of face nz at level 1; each polar tile's
    // context reaches across the pole into the others and into the equatorial faces.
    for (x, y) in [(0, 0), (1, 1)] {
        let id = TileId {
            level: 1,
            face: Face::Nz,
            x,
            y,
        };
        let reach = horizon::reach_rad(ts.body.radius_m, lo, hi, hi);
        let margin =
            (reach * ts.body.radius_m / (2.0 * ts.body.radius_m / 256.0)).ceil() as u64 * 3;
        let (ctx, rect) = horizon::context_for(&src, id, margin, None).unwrap();
        // The 16×16 pixels nearest the pole.
        let (ox, oy) = if x == 0 {
            (rect.x0 + 112, rect.y0 + 112)
        } else {
            (rect.x0, rect.y0)
        };
        let (rms, max) = compare(
            &ctx,
            Rect {
                x0: ox,
                y0: oy,
                w: 16,
                h: 16,
            },
            36,
            &format!("LDEM_4 level 1 nz tile {x},{y}"),
        );
        assert!(rms <= 0.05 && max <= 0.5, "rms {rms} max {max}");
    }
}

fn json(o: &std::process::Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// A global lunar tileset of 32² tiles, 2 levels, in `dir`/t.
fn small_lunar_tileset(dir: &std::path::Path) -> std::path::PathBuf {
    use crate::util::global_dem;
    use penumbra::body::Body;
    use penumbra::progress::NoProgress;
    use penumbra::tiling::{tile_dem, TileOptions};
    let out = dir.join("t");
    let opts = TileOptions {
        tile_size: 32,
        halo: 2,
        levels: Some(2),
        ..Default::default()
    };
    tile_dem(
        &global_dem(360),
        &Body::preset("moon").unwrap(),
        &out,
        &opts,
        None,
        &NoProgress,
    )
    .unwrap();
    out
}

#[test]
fn cli_horizon_and_query_horizon() {
    use crate::util::penumbra_bin;
    let dir = tempfile::tempdir().unwrap();
    let out = small_lunar_tileset(dir.path());
    let o = out.to_str().unwrap();
    let run = |args: &[&str]| penumbra_bin().args(args).output().unwrap();
    // `penumbra [before] horizon o --levels 1 --azimuths 36 [after] --json`.
    let bake_level1 = |before: &[&str], after: &[&str]| {
        let args = [
            before,
            &["horizon", o, "--levels", "1", "--azimuths", "36"],
            after,
            &["--json"],
        ];
        json(&run(&args.concat()))
    };

    // Computed on demand (nothing stored yet): both methods, compass azimuths ascending.
    let q = |method: &str| {
        json(&run(&[
            "query",
            "horizon",
            o,
            "--lat",
            "-12.5",
            "--lon",
            "200",
            "--azimuths",
            "36",
            "--method",
            method,
            "--json",
        ]))
    };
    let fast = q("fast");
    let reference = q("reference");
    assert_eq!(fast["source"], "computed");
    let az: Vec<f64> = serde_json::from_value(fast["azimuth_deg"].clone()).unwrap();
    let ef: Vec<f64> = serde_json::from_value(fast["elevation_deg"].clone()).unwrap();
    let er: Vec<f64> = serde_json::from_value(reference["elevation_deg"].clone()).unwrap();
    assert_eq!((az.len(), ef.len(), er.len()), (36, 36, 36));
    assert!(az.windows(2).all(|w| w[0] < w[1]) && az[0] >= 0.0 && az[35] < 360.0);
    for (f, r) in ef.iter().zip(&er) {
        assert!(*f <= r + 1e-3 && r - f <= 0.5, "fast {f} reference {r}");
    }
    let exact = q("exact");
    assert_eq!(exact["source"], "computed");
    let ee: Vec<f64> = serde_json::from_value(exact["elevation_deg"].clone()).unwrap();
    for (e, r) in ee.iter().zip(&er) {
        assert!((e - r).abs() <= 5e-4, "exact {e} reference {r}");
    }
    // The pixel centre reported is within a pixel of the point asked for.
    let (lat, lon) = (
        fast["lat_deg"].as_f64().unwrap(),
        fast["lon_deg"].as_f64().unwrap(),
    );
    assert!(
        (lat + 12.5).abs() < 1.0
            && (lon - 200.0 + 360.0)
                .rem_euclid(360.0)
                .min((200.0 - lon).rem_euclid(360.0))
                < 1.0,
        "{lat} {lon}"
    );

    // Bake the maps of level 1; the query then reads them and agrees with the computed one
    // to f16 precision.
    let r = bake_level1(&[], &[]);
    assert_eq!(r["tiles_written"], 24);
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let hp = ts.products.horizon.as_ref().unwrap();
    assert_eq!(
        (hp.azimuths, hp.levels.clone(), hp.precision.as_str()),
        (36, vec![1], "f16")
    );
    let stored = q("fast");
    assert_eq!(stored["source"], "stored");
    let es: Vec<f64> = serde_json::from_value(stored["elevation_deg"].clone()).unwrap();
    for (s, f) in es.iter().zip(&ef) {
        assert!((s - f).abs() <= 0.05, "stored {s} computed {f}");
    }
    // Rerun: up to date; same bytes whatever the thread count.
    let r = bake_level1(&[], &[]);
    assert_eq!(r["up_to_date"], true);
    let before = crate::util::snapshot(&out.join("horizon"));
    std::fs::remove_dir_all(out.join("horizon")).unwrap();
    let r = bake_level1(&["--threads", "1"], &[]);
    assert_eq!(r["tiles_written"], 24);
    assert!(before == crate::util::snapshot(&out.join("horizon")));

    // The exact method's maps replace the fast ones (another run key), record no near field,
    // and are what the query then reads.
    let r = bake_level1(&[], &["--method", "exact"]);
    assert_eq!(r["tiles_written"], 24);
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let hp = ts.products.horizon.as_ref().unwrap();
    assert_eq!((hp.method.as_str(), hp.near_px), ("exact", None));
    let stored = q("exact");
    assert_eq!(stored["source"], "stored");
    let es: Vec<f64> = serde_json::from_value(stored["elevation_deg"].clone()).unwrap();
    for (s, e) in es.iter().zip(&ee) {
        assert!((s - e).abs() <= 0.05, "stored {s} computed {e}");
    }

    // The sweep method records its measured error beside the maps, and the query reports it.
    let r = bake_level1(&[], &["--method", "sweep"]);
    assert_eq!(r["tiles_written"], 24);
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let hp = ts.products.horizon.as_ref().unwrap();
    assert_eq!((hp.method.as_str(), hp.near_px), ("sweep", None));
    let err = hp
        .error
        .as_ref()
        .expect("the sweep method's error is recorded");
    assert_eq!(err.against, "reference");
    assert_eq!(err.pixels, 24 * 16);
    assert!(
        err.samples > 0 && err.rms_deg < 0.3 && err.max_above_deg < 0.1,
        "{err:?}"
    );
    let stored = q("sweep");
    assert_eq!(stored["source"], "stored");
    assert_eq!(stored["error"]["samples"], err.samples);
    let es: Vec<f64> = serde_json::from_value(stored["elevation_deg"].clone()).unwrap();
    let worst = es
        .iter()
        .zip(&ee)
        .map(|(s, e)| (s - e).abs())
        .fold(0.0, f64::max);
    assert!(
        worst <= err.max_deg + 0.05,
        "stored sweep {worst}° off exact"
    );
    let before = crate::util::snapshot(&out.join("horizon"));
    let manifest = std::fs::read(out.join("tileset.json")).unwrap();

    // Bad requests: exit 2, a reason, nothing written.
    for (args, says) in [
        (
            vec!["horizon", o, "--method", "exactly"],
            "fast, sweep, exact, reference",
        ),
        (
            vec!["horizon", o, "--method", "sweep", "--near-px", "8"],
            "--near-px",
        ),
        // With --fourier the method in effect is sweep by default: --near-px is refused too.
        (
            vec!["horizon", o, "--fourier", "--near-px", "8"],
            "the default with --fourier",
        ),
        (
            vec![
                "horizon",
                o,
                "--method",
                "exact",
                "--fine-margin-px",
                "1024",
            ],
            "--fine-margin-px",
        ),
        (vec!["horizon", o, "--azimuths", "2"], "outside 4..=4096"),
        (vec!["horizon", o, "--near-px=-1"], "outside 0..=1024"),
        (
            vec![
                "query",
                "horizon",
                o,
                "--lat",
                "0",
                "--lon",
                "0",
                "--near-px",
                "2000",
            ],
            "outside 0..=1024",
        ),
        (vec!["horizon", o, "--levels", "7"], "does not exist"),
        (
            vec!["horizon", o, "--levels", "1", "--max-output-gib", "0.001"],
            "GiB",
        ),
        (
            vec!["query", "horizon", o, "--lat", "95", "--lon", "0"],
            "latitude",
        ),
    ] {
        let e = run(&args);
        assert_eq!(e.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&e.stderr);
        assert!(err.contains(says), "{args:?}: {err}");
    }
    assert!(before == crate::util::snapshot(&out.join("horizon")));
    assert_eq!(manifest, std::fs::read(out.join("tileset.json")).unwrap());
    let e = run(&["horizon", dir.path().join("nothing").to_str().unwrap()]);
    assert_eq!(e.status.code(), Some(2));
}

#[test]
fn horizon_refuses_equal_angle_tilesets() {
    use crate::util::{global_dem, penumbra_bin};
    use penumbra::body::Body;
    use penumbra::cube::Projection;
    use penumbra::progress::NoProgress;
    use penumbra::tiling::{tile_dem, TileOptions};
    let dir = tempfile::tempdir().unwrap();
    let opts = TileOptions {
        tile_size: 16,
        levels: Some(1),
        projection: Projection::EqualAngle,
        ..Default::default()
    };
    tile_dem(
        &global_dem(90),
        &Body::preset("moon").unwrap(),
        dir.path(),
        &opts,
        None,
        &NoProgress,
    )
    .unwrap();
    let e = penumbra_bin()
        .args(["horizon", dir.path().to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(e.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&e.stderr).contains("gnomonic"));
    assert!(!dir.path().join("horizon").exists());
}

#[test]
fn bake_runs_the_horizon_stage_when_asked() {
    use crate::util::penumbra_bin;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles");
    let o = out.to_str().unwrap();
    let r = json(
        &penumbra_bin()
            .args([
                "bake",
                "--out",
                o,
                "--scene-size",
                "1024",
                "--tile-size",
                "64",
                "--levels",
                "3",
                "--horizon-levels",
                "0",
                "--no-fourier",
                "--json",
            ])
            .output()
            .unwrap(),
    );
    assert_eq!(r["stages"], serde_json::json!(["tile", "mip", "horizon"]));
    assert_eq!(r["horizon"]["levels"], serde_json::json!([0]));
    let written = r["horizon"]["tiles_written"].as_u64().unwrap();
    assert!(written >= 1, "{r}");
    // The distance bound came from the mipmaps' extrema: the manifest says so.
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let (m, h) = (ts.products.mip.unwrap(), ts.products.horizon.unwrap());
    assert_eq!(
        (h.terrain_min_m, h.terrain_max_m),
        (m.global_min_m, m.global_max_m)
    );
    assert!(h.distances[0].needed_km > 10.0, "{:?}", h.distances);
}

/// The fast method's far rings (`--fine-margin-px`): a 3 km mountain 20–40 km from a plain,
/// beyond a 64-px full-resolution margin. Through the coarser levels the plain's pixels still
/// see it, within a small error of the exact method over the whole reach, where the exact
/// method cut off at the same margin misses it by degrees; the manifest says which tiles used
/// rings, the bytes do not depend on the thread count, and bad margins exit 2.
#[test]
fn far_rings_see_a_distant_mountain() {
    use crate::util::{geographic_dem, penumbra_bin};
    use penumbra::body::Body;
    use penumbra::layout::TileId;
    use penumbra::progress::NoProgress;
    use penumbra::tiling::{tile_dem, TileOptions};
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t");
    // 1.2° × 1.2° at 0.006° (≈ 180 m) of 20 m ripples, the mountain's peak near the
    // north-east corner.
    let dem = geographic_dem(
        (10.0, 1.2),
        (200, 200),
        0.006,
        "plain and mountain",
        |_, _, lat, lon| {
            let r2 = ((lat - 0.95).powi(2) + (lon - 11.0).powi(2)) / 0.15f64.powi(2);
            (3000.0 * (-r2).exp() + 20.0 * (lat * 97.0).sin() * (lon * 89.0).cos()) as f32
        },
    );
    let opts = TileOptions {
        tile_size: 32,
        halo: 2,
        ..Default::default()
    };
    let moon = Body::preset("moon").unwrap();
    tile_dem(&dem, &moon, &out, &opts, None, &NoProgress).unwrap();
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let level = ts.layout.levels - 1;
    let n = ts.layout.tile_size as usize;
    let lv = level.to_string();
    let o = out.to_str().unwrap();
    let horizon = |before: &[&str], extra: &[&str]| {
        let r = penumbra_bin()
            .args(before)
            .args(["horizon", o, "--levels", &lv, "--azimuths", "32"])
            .args(["--precision", "f32"])
            .args(extra)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(r.status.success(), "{extra:?}: {err}");
    };
    // The maps of the level's tiles away from the data's edge (there the methods differ in
    // how they search cells with no-data corners, which is not what this test is about).
    let tiles: Vec<TileId> = {
        let all = ts.tile_set();
        all.iter()
            .filter(|t| t.level == level)
            .filter(|t| {
                (-1i64..=1).all(|dy| {
                    (-1i64..=1).all(|dx| {
                        all.contains(&TileId {
                            x: (t.x as i64 + dx) as u32,
                            y: (t.y as i64 + dy) as u32,
                            ..**t
                        })
                    })
                })
            })
            .copied()
            .collect()
    };
    assert!(tiles.len() >= 9, "{} interior tiles", tiles.len());
    let maps = || -> Vec<f32> {
        tiles
            .iter()
            .flat_map(|&id| {
                let p = penumbra::horizon::tile_path(&out, id);
                penumbra::horizon::read_horizon_exr(&p, n).unwrap().1
            })
            .collect()
    };
    horizon(&[], &["--method", "exact"]);
    let exact = maps();
    horizon(&[], &["--method", "exact", "--max-margin-px", "64"]);
    let cut = maps();
    horizon(&[], &["--fine-margin-px", "64"]);
    let rings = maps();
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let d = &ts.products.horizon.as_ref().unwrap().distances[0];
    assert!(
        d.tiles_with_far_rings > 0 && d.max_margin_px == 64 && d.tiles_capped == 0,
        "{d:?}"
    );
    // Against the exact method over the whole reach: RMS, worst, and how many of the samples
    // the cut context misses by over 1° a method finds within 0.25°.
    let against_exact = |got: &[f32]| {
        let (mut sq, mut count, mut worst) = (0.0, 0usize, 0.0f64);
        let (mut missed, mut recovered) = (0usize, 0usize);
        for ((&e, &c), &r) in exact.iter().zip(&cut).zip(got) {
            // Views falling away below −2° end at the edge of this small DEM, where the exact
            // method's surface reaches one pixel into no data and the rings' does not.
            if e.is_nan() || e < -2.0 {
                continue;
            }
            let err = (r - e) as f64;
            sq += err * err;
            count += 1;
            worst = worst.max(err.abs());
            // Where cutting the context off loses the mountain, the rings must find it.
            if e - c > 1.0 {
                missed += 1;
                if err.abs() < 0.25 {
                    recovered += 1;
                }
            }
        }
        ((sq / count as f64).sqrt(), worst, missed, recovered)
    };
    let (rms, worst, missed, recovered) = against_exact(&rings);
    assert!(
        missed > 1000,
        "the mountain must lie beyond the margin: {missed}"
    );
    assert!(
        recovered as f64 >= 0.99 * missed as f64,
        "rings recovered {recovered} of {missed} samples the cut context misses"
    );
    assert!(
        rms < 0.02 && worst < 1.5,
        "rings against exact: RMS {rms}°, max {worst}°"
    );

    // Same bytes on one thread.
    let before = crate::util::snapshot(&out.join("horizon"));
    std::fs::remove_dir_all(out.join("horizon")).unwrap();
    horizon(&["--threads", "1"], &["--fine-margin-px", "64"]);
    assert!(before == crate::util::snapshot(&out.join("horizon")));

    // The sweep method sees the mountain through the same rings, within its own budget.
    horizon(&[], &["--method", "sweep", "--fine-margin-px", "64"]);
    let swept = maps();
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let hp = ts.products.horizon.as_ref().unwrap();
    let d = &hp.distances[0];
    assert!(
        hp.method == "sweep" && d.tiles_with_far_rings > 0 && d.max_margin_px == 64,
        "{d:?}"
    );
    let (rms, worst, missed, recovered) = against_exact(&swept);
    eprintln!("sweep with rings against exact: RMS {rms}°, max {worst}°, recovered {recovered} of {missed}");
    assert!(
        recovered as f64 >= 0.99 * missed as f64,
        "sweep's rings recovered {recovered} of {missed} samples the cut context misses"
    );
    // This build: 0.0071° RMS, 1.07° at worst, 99.98 % recovered.
    assert!(
        rms < 0.015 && worst < 1.6,
        "sweep with rings against exact: RMS {rms}°, max {worst}°"
    );

    for bad in ["8", "100000", "-1", "x"] {
        let r = penumbra_bin()
            .args(["horizon", o, "--fine-margin-px", bad])
            .output()
            .unwrap();
        assert_eq!(r.status.code(), Some(2), "--fine-margin-px {bad}");
    }
}

/// A real DEM's edge: Gale tiled onto the cube (64-px tiles; level 6 holds its 50 tiles, most
/// cut by the DEM's curved footprint, with no data beyond it), horizons of the whole level in
/// 16 azimuths by the exact method and by the fast one (with its far rings). Where a ray's
/// terrain ends at the data edge the fast method used to pick points of the surface that no
/// exact search reports (up to 2.6° above the exact answer, 0.012° RMS); now it never exceeds
/// the exact method, and stays as close to it as inside the data.
#[test]
fn fast_stays_below_exact_at_a_real_data_edge() {
    use crate::util::penumbra_bin;
    let Some(data) = shared_data() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("gale");
    let o = out.to_str().unwrap();
    let run = |args: &[&str]| {
        let r = penumbra_bin().args(args).output().unwrap();
        assert!(
            r.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
    };
    let dem = data.join("mola_gale_128ppd_crop/gale-mola.bin");
    run(&[
        "tile",
        dem.to_str().unwrap(),
        "--body",
        "mars",
        "--out",
        o,
        "--tile-size",
        "64",
    ]);
    let horizon = |method: &str| -> Vec<(f32, bool)> {
        // A 256-px fine margin (the default is 1024) so that the fast method's far rings meet
        // the data edge too (the fast method's option only: the others refuse it).
        let mut args = vec![
            "horizon",
            o,
            "--levels",
            "6",
            "--azimuths",
            "16",
            "--precision",
            "f32",
            "--method",
            method,
        ];
        if method == "fast" {
            args.extend(["--fine-margin-px", "256"]);
        }
        run(&args);
        let ts = penumbra::manifest::Tileset::load(&out).unwrap();
        let mut v = Vec::new();
        for id in ts.tile_set().iter().filter(|t| t.level == 6) {
            let p = penumbra::horizon::tile_path(&out, *id);
            let tile = penumbra::horizon::read_horizon_exr(&p, 64).unwrap().1;
            // Whether the tile holds no-data pixels (the edge).
            let edge = tile.iter().any(|x| x.is_nan());
            v.extend(tile.into_iter().map(|x| (x, edge)));
        }
        std::fs::remove_dir_all(out.join("horizon")).unwrap();
        v
    };
    let exact = horizon("exact");
    let fast = horizon("fast");
    assert_eq!(exact.len(), 50 * 64 * 64 * 16);
    let (mut n, mut edge_n, mut sq, mut above, mut low) = (0usize, 0usize, 0.0f64, 0.0f32, 0usize);
    for (&(e, edge), &(f, _)) in exact.iter().zip(&fast) {
        assert_eq!(e.is_nan(), f.is_nan());
        if e.is_nan() {
            continue;
        }
        n += 1;
        edge_n += edge as usize;
        above = above.max(f - e);
        sq += ((f - e) as f64).powi(2);
        low += (e - f > 0.25) as usize;
    }
    let rms = (sq / n as f64).sqrt();
    eprintln!("Gale level 6 edge: {n} samples ({edge_n} in edge tiles): fast − exact RMS {rms:.5}°, most above {above:.2e}°, {low} more than 0.25° below");
    assert!(edge_n > n / 4, "{edge_n} of {n} samples in edge tiles");
    assert!(above <= 1e-3, "fast above exact by {above}°");
    assert!(
        rms <= 0.002 && low <= n / 500_000,
        "RMS {rms}°, {low} of {n} > 0.25° below"
    );
}

/// A build without the GPU sweep (the README's first command's): `--device gpu` exits 2 saying
/// how to build it, and `auto` is the CPU.
#[cfg(not(feature = "gpu"))]
#[test]
fn horizon_device_gpu_needs_the_feature() {
    use crate::util::penumbra_bin;
    let dir = tempfile::tempdir().unwrap();
    let e = penumbra_bin()
        .args([
            "horizon",
            dir.path().to_str().unwrap(),
            "--method",
            "sweep",
            "--device",
            "gpu",
        ])
        .output()
        .unwrap();
    assert_eq!(e.status.code(), Some(2));
    let err = String::from_utf8_lossy(&e.stderr);
    assert!(
        err.contains("--features penumbra-cli/gpu") && err.contains("--device cpu"),
        "{err}"
    );
}

/// Whether Mesa's software Vulkan driver (lavapipe) is installed: the GPU tests' adapter where
/// there is no GPU. Under `CI=true` it must be (`.ci/run` installs it).
#[cfg(feature = "gpu")]
fn lavapipe() -> bool {
    let here = ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d"]
        .iter()
        .any(|d| {
            std::fs::read_dir(d).is_ok_and(|r| {
                r.flatten()
                    .any(|e| e.file_name().to_string_lossy().starts_with("lvp_icd"))
            })
        });
    if !here {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true and no lavapipe (mesa-vulkan-drivers)"
        );
        eprintln!("skipped: no lavapipe (apt-get install mesa-vulkan-drivers)");
    }
    here
}

/// `horizon --device gpu` (issue 39): the sweep on the GPU (lavapipe here) writes maps within
/// the method's budget of the CPU sweep's (0.01° RMS), records the device in the run key (so the
/// CPU's maps are redone, and a rerun on the same device is up to date), and refuses what it
/// cannot do with exit 2: another method on the GPU, and no adapter at all (naming lavapipe and
/// `--device cpu`), leaving the maps as they were.
#[cfg(feature = "gpu")]
#[test]
fn horizon_device_gpu() {
    use crate::util::penumbra_bin;
    if !lavapipe() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = small_lunar_tileset(dir.path());
    let o = out.to_str().unwrap();
    let xdg = dir.path().join("xdg");
    std::fs::create_dir_all(&xdg).unwrap();
    let run = |args: &[&str], env: &[(&str, &str)]| {
        let mut c = penumbra_bin();
        c.args(args).env("XDG_RUNTIME_DIR", &xdg);
        for (k, v) in env {
            c.env(k, v);
        }
        c.output().unwrap()
    };
    let base = [
        "horizon",
        o,
        "--levels",
        "1",
        "--azimuths",
        "36",
        "--method",
        "sweep",
        "--precision",
        "f32",
        "--json",
    ];
    let maps = || -> Vec<f32> {
        let mut v = Vec::new();
        let dir = out.join("horizon");
        for f in crate::util::snapshot(&dir)
            .into_keys()
            .filter(|f| f.ends_with(".exr"))
        {
            let (a, data) = penumbra::horizon::read_horizon_exr(&dir.join(f), 32).unwrap();
            assert_eq!(a, 36);
            v.extend(data);
        }
        v
    };
    let cpu = json(&run(&[&base[..], &["--device", "cpu"]].concat(), &[]));
    assert_eq!(cpu["tiles_written"], 24);
    let cpu_maps = maps();
    let gpu = json(&run(&[&base[..], &["--device", "gpu"]].concat(), &[]));
    assert_eq!(
        gpu["tiles_written"], 24,
        "another device: the maps are redone"
    );
    let gpu_maps = maps();
    assert_eq!(cpu_maps.len(), gpu_maps.len());
    let (rms, max, n) = diff_stats(&gpu_maps, &cpu_maps);
    eprintln!("GPU − CPU sweep over {n} samples: rms {rms:.5}° max {max:.4}°");
    assert!(n > 0 && rms <= 0.01, "rms {rms}° max {max}°");
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let hp = ts.products.horizon.as_ref().unwrap();
    let basis = serde_json::to_string(&hp.run_key_basis).unwrap();
    assert!(basis.contains("\\\"device\\\":\\\"gpu: "), "{basis}");
    assert!(hp
        .error
        .as_ref()
        .is_some_and(|e| e.samples > 0 && e.rms_deg < 0.3));
    // The same device again: up to date, nothing rewritten.
    let again = json(&run(&[&base[..], &["--device", "gpu"]].concat(), &[]));
    assert_eq!(again["up_to_date"], true);
    let before = crate::util::snapshot(&out.join("horizon"));
    let manifest = std::fs::read(out.join("tileset.json")).unwrap();
    for (args, env, says) in [
        (
            vec!["horizon", o, "--method", "fast", "--device", "gpu"],
            vec![],
            vec!["--device gpu runs the sweep method only", "--device cpu"],
        ),
        (
            vec!["horizon", o, "--device", "tpu"],
            vec![],
            vec!["cpu, gpu, auto"],
        ),
        (
            [&base[..], &["--device", "gpu"]].concat(),
            vec![
                ("WGPU_BACKEND", "vulkan"),
                ("VK_ICD_FILENAMES", "/nonexistent.json"),
                ("VK_DRIVER_FILES", "/nonexistent.json"),
            ],
            vec!["no GPU adapter", "lavapipe", "--device cpu"],
        ),
        (
            [&base[..], &["--device", "gpu"]].concat(),
            vec![("PENUMBRA_GPU_MEMORY_MIB", "lots")],
            vec!["PENUMBRA_GPU_MEMORY_MIB=\"lots\"", "16..=1048576"],
        ),
        (
            [&base[..], &["--device", "gpu"]].concat(),
            vec![("PENUMBRA_GPU_MEMORY_MIB", "8")],
            vec!["PENUMBRA_GPU_MEMORY_MIB=\"8\"", "16..=1048576"],
        ),
    ] {
        let e = run(&args, &env);
        assert_eq!(e.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&e.stderr);
        for s in says {
            assert!(err.contains(s), "{args:?}: {err}");
        }
    }
    // Refused runs leave the maps and the manifest as they were.
    assert!(before == crate::util::snapshot(&out.join("horizon")));
    assert_eq!(manifest, std::fs::read(out.join("tileset.json")).unwrap());
    // `auto` on a machine whose only adapter is software: the CPU, whose maps these are not.
    let auto = json(&run(&[&base[..], &["--device", "auto"]].concat(), &[]));
    assert_eq!(
        auto["tiles_written"], 24,
        "auto ran on the CPU: another run key"
    );
    assert_eq!(maps(), cpu_maps, "auto on lavapipe is the CPU, to the bit");
}
