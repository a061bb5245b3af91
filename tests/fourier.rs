//! Fourier pyramids through the CLI: streamed from the horizon stage and made from raw maps,
//! reconstruction against the raw maps, sun visibility on stiff cases, per-tile K, fully lit
//! tiles, determinism, and bad input (K out of range, no horizons, damaged files).

use std::path::Path;
use std::process::Output;

use crate::util::{copy_tree, penumbra_bin, snapshot};

fn run(args: &[&str]) -> Output {
    penumbra_bin().args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn json(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", stderr(o));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// Exit 2, a message containing `needle`, and the tileset byte for byte as it was.
fn refused(args: &[&str], dir: &Path, needle: &str) {
    let before = snapshot(dir);
    let o = run(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
    assert!(e.contains(needle), "{args:?}: {e:?} lacks {needle:?}");
    assert!(!e.contains("panicked"), "{e}");
    assert_eq!(snapshot(dir), before, "{args:?} altered the tileset");
}

/// A small tileset (32-px tiles of the embedded scene; level 3 ≈ 850 m/px) with raw maps of 36
/// azimuths and streamed pyramids.
fn baked(dir: &Path, extra: &[&str]) -> String {
    let o = dir.join("tiles");
    let s = o.to_str().unwrap().to_string();
    let mut args = vec![
        "bake",
        "--out",
        &s,
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--tile-size",
        "32",
        "--no-horizons",
    ];
    args.extend_from_slice(extra);
    json(&run(&[&args[..], &["--json"]].concat()));
    s
}

/// Points of the scene at the south pole, on the rim and inside craters.
const POINTS: &[(f64, f64)] = &[
    (-89.9, 0.0),
    (-89.95, 100.0),
    (-89.8, 200.0),
    (-89.85, 300.0),
    (-89.99, 45.0),
];

fn elevations(o: &str, lat: f64, lon: f64, from: &str) -> Vec<f64> {
    let q = json(&run(&[
        "query",
        "horizon",
        o,
        "--lat",
        &lat.to_string(),
        "--lon",
        &lon.to_string(),
        "--level",
        "3",
        "--azimuths",
        "36",
        "--from",
        from,
        "--json",
    ]));
    q["elevation_deg"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}

#[test]
fn streamed_and_stored_pyramids_reconstruct_the_raw_maps() {
    let tmp = tempfile::tempdir().unwrap();
    let o = baked(tmp.path(), &[]);
    // Streamed, keeping the raw maps: K = 19 = A/2 + 1 of 36 azimuths, full resolution.
    let r = json(&run(&[
        "horizon",
        &o,
        "--levels",
        "3",
        "--azimuths",
        "36",
        "--fourier",
        "--keep-raw",
        "--coefficients",
        "19",
        "--layout",
        "full",
        "--encoding",
        "snorm16",
        "--json",
    ]));
    assert_eq!(r["raw"], true);
    assert_eq!(r["fourier"]["coefficients"], 19);
    let ts = penumbra::manifest::Tileset::load(Path::new(&o)).unwrap();
    let f = ts.products.fourier.as_ref().unwrap();
    assert_eq!(
        (f.source.as_str(), f.azimuths, f.coefficients),
        ("streamed", 36, 19)
    );
    assert!(ts.products.horizon.is_some());
    // Every coefficient kept in 16 bits: the reconstruction at the samples is the raw map (f16,
    // floored) within the quantisation.
    let (mut worst, mut compared) = (0.0f64, 0usize);
    for &(lat, lon) in POINTS {
        let raw = elevations(&o, lat, lon, "raw");
        let fou = elevations(&o, lat, lon, "fourier");
        assert_eq!(raw.len(), 36);
        // The series approximate the horizon floored at the lowest sphere's tangent (≈ −2.7°
        // here; −90° means no mapped terrain): compare where no floor applies.
        for (a, b) in raw.iter().zip(&fou).filter(|(a, _)| **a >= 0.0) {
            worst = worst.max((a - b).abs());
            compared += 1;
        }
    }
    assert!(compared > 40, "{compared} samples above the floor");
    assert!(
        worst < 0.02,
        "K = A/2+1 snorm16 is {worst}° off the raw maps"
    );

    // From the stored raw maps with the paper's defaults (K = 16, multires, f16): a truncated,
    // spatially averaged series is close, not equal.
    let r = json(&run(&["fourier", &o, "--json"]));
    assert_eq!(r["tiles_written"], r["tiles"]);
    assert!(r["bytes_per_tile"].as_u64().unwrap() < r["raw_bytes_per_tile"].as_u64().unwrap());
    let ts = penumbra::manifest::Tileset::load(Path::new(&o)).unwrap();
    assert_eq!(ts.products.fourier.as_ref().unwrap().source, "raw");
    let (mut sum, mut count, mut worst) = (0.0f64, 0usize, 0.0f64);
    for &(lat, lon) in POINTS {
        let raw = elevations(&o, lat, lon, "raw");
        let fou = elevations(&o, lat, lon, "fourier");
        for (a, b) in raw.iter().zip(&fou).filter(|(a, _)| **a >= 0.0) {
            sum += (a - b).powi(2);
            count += 1;
            worst = worst.max((a - b).abs());
        }
    }
    let rms = (sum / count as f64).sqrt();
    assert!(
        rms < 1.0 && rms > 0.0,
        "K = 16 multires RMS {rms}° (max {worst}°)"
    );
    // A second run is a no-op; a rerun of the horizon stage makes the pyramids stale.
    let r = json(&run(&["fourier", &o, "--json"]));
    assert_eq!(r["up_to_date"], true);
    json(&run(&[
        "horizon",
        &o,
        "--levels",
        "3",
        "--azimuths",
        "12",
        "--json",
    ]));
    let ts = penumbra::manifest::Tileset::load(Path::new(&o)).unwrap();
    assert!(ts.products.fourier.is_none());
    assert!(!Path::new(&o).join("fourier").exists());
}

fn shadow(o: &str, lat: f64, lon: f64, az: f64, el: f64, from: &str, model: &str) -> Output {
    run(&[
        "query",
        "shadow",
        o,
        "--lat",
        &lat.to_string(),
        "--lon",
        &lon.to_string(),
        "--level",
        "3",
        "--sun-az",
        &az.to_string(),
        "--sun-el",
        &el.to_string(),
        "--from",
        from,
        "--model",
        model,
        "--azimuths",
        "36",
        "--json",
    ])
}

#[test]
fn sun_visibility_is_in_range_on_stiff_cases_and_agrees_between_sources() {
    let tmp = tempfile::tempdir().unwrap();
    let o = baked(tmp.path(), &[]);
    json(&run(&[
        "horizon",
        &o,
        "--levels",
        "3",
        "--azimuths",
        "36",
        "--fourier",
        "--keep-raw",
        "--json",
    ]));
    let mut checked = 0;
    for &(lat, lon) in POINTS {
        for el in [-90.0, -2.0, 0.0, 0.1, 1.0, 5.0, 45.0, 89.9, 90.0] {
            for az in [0.0, 123.0, 359.99] {
                for model in ["constant", "segment", "slices", "exact"] {
                    let a = json(&shadow(&o, lat, lon, az, el, "fourier", model));
                    let lit = a["lit_fraction"].as_f64().expect("a number, not NaN");
                    assert!((0.0..=1.0).contains(&lit), "{a}");
                    let h = a["horizon_deg"].as_f64().unwrap();
                    // Whole disc above or below the horizon: every model agrees.
                    let r = a["sun_radius_deg"].as_f64().unwrap();
                    if el - r > h + 1.0 {
                        assert_eq!(lit, 1.0, "{a}");
                    }
                    if el + r < h - 1.0 {
                        assert_eq!(lit, 0.0, "{a}");
                    }
                    checked += 1;
                }
            }
        }
        // The exact model from the raw maps and from the reference agree with the series at
        // a sun well clear of the horizon.
        let raw = json(&shadow(&o, lat, lon, 200.0, 30.0, "raw", "exact"));
        assert_eq!(raw["lit_fraction"], 1.0, "{raw}");
        assert_eq!(raw["source"], "stored");
    }
    assert_eq!(checked, POINTS.len() * 9 * 3 * 4);
    // The sun at the zenith is lit; deep below the horizontal it is not.
    let a = json(&shadow(&o, -89.9, 0.0, 0.0, 90.0, "reference", "exact"));
    assert_eq!(
        (a["lit_fraction"].as_f64(), a["source"].as_str()),
        (Some(1.0), Some("computed"))
    );
    let a = json(&shadow(&o, -89.9, 0.0, 0.0, -30.0, "raw", "segment"));
    assert_eq!(a["lit_fraction"], 0.0);
    // Bad sun positions and models: exit 2 naming the flag.
    let d = Path::new(&o);
    refused(
        &[
            "query", "shadow", &o, "--lat", "-89.9", "--lon", "0", "--sun-az", "0", "--sun-el",
            "91",
        ],
        d,
        "--sun-el",
    );
    refused(
        &[
            "query", "shadow", &o, "--lat", "-89.9", "--lon", "0", "--sun-az", "NaN", "--sun-el",
            "1",
        ],
        d,
        "--sun-az",
    );
    refused(
        &[
            "query",
            "shadow",
            &o,
            "--lat",
            "-89.9",
            "--lon",
            "0",
            "--sun-az",
            "0",
            "--sun-el",
            "1",
            "--sun-distance-au",
            "0",
        ],
        d,
        "--sun-distance-au",
    );
    let o2 = run(&[
        "query", "shadow", &o, "--lat", "-89.9", "--lon", "0", "--sun-az", "0", "--sun-el", "1",
        "--model", "magic",
    ]);
    assert_eq!(o2.status.code(), Some(2));
}

#[test]
fn bad_input_is_refused_and_nothing_is_half_written() {
    let tmp = tempfile::tempdir().unwrap();
    let o = baked(tmp.path(), &[]);
    let d = Path::new(&o);
    // No raw horizon maps to compress.
    refused(&["fourier", &o], d, "no raw horizon maps");
    json(&run(&[
        "horizon",
        &o,
        "--levels",
        "3",
        "--azimuths",
        "36",
        "--json",
    ]));
    // K outside 1..=A/2+1, other options out of range.
    refused(&["fourier", &o, "--coefficients", "0"], d, "--coefficients");
    refused(
        &["fourier", &o, "--coefficients", "20"],
        d,
        "--coefficients 20 is outside 1..=19",
    );
    refused(
        &["fourier", &o, "--max-error-deg", "-1"],
        d,
        "--max-error-deg",
    );
    refused(&["fourier", &o, "--min-sun-el", "95"], d, "--min-sun-el");
    refused(
        &["fourier", &o, "--levels", "2"],
        d,
        "level 2 has no horizon maps",
    );
    refused(&["fourier", &o, "--layout", "pyramid"], d, "pyramid");
    refused(
        &[
            "horizon",
            &o,
            "--levels",
            "3",
            "--azimuths",
            "36",
            "--keep-raw",
        ],
        d,
        "--keep-raw",
    );
    refused(
        &[
            "horizon",
            &o,
            "--levels",
            "3",
            "--azimuths",
            "36",
            "--fourier",
            "--coefficients",
            "40",
        ],
        d,
        "--coefficients",
    );
    // Pyramids asked of a shadow query before there are any.
    refused(
        &[
            "query", "shadow", &o, "--lat", "-89.9", "--lon", "0", "--sun-az", "0", "--sun-el",
            "1", "--level", "3",
        ],
        d,
        "no Fourier pyramids",
    );
    json(&run(&["fourier", &o, "--json"]));
    // Damaged files: a flipped byte, a truncated file, a file of another tileset's size.
    let files: Vec<String> = snapshot(d)
        .into_keys()
        .filter(|k| k.starts_with("fourier/"))
        .collect();
    assert!(!files.is_empty());
    let q = |o: &str| -> Output {
        run(&[
            "query", "shadow", o, "--lat", "-89.9", "--lon", "0", "--level", "3", "--sun-az", "10",
            "--sun-el", "2",
        ])
    };
    // Which file does (-89.9, 0) read? Damage each in turn until the query trips on it.
    let good = snapshot(d);
    let mut tripped = 0;
    for f in &files {
        for how in 0..3 {
            let case = tmp.path().join("case");
            let _ = std::fs::remove_dir_all(&case);
            copy_tree(d, &case);
            let p = case.join(f);
            let mut b = good[f].clone();
            match how {
                0 => {
                    let i = b.len() / 2;
                    b[i] ^= 1;
                }
                1 => b.truncate(b.len() - 7),
                _ => b = b"PNBRFHM\0".to_vec(),
            }
            std::fs::write(&p, &b).unwrap();
            let before = snapshot(&case);
            let out = q(case.to_str().unwrap());
            let e = stderr(&out);
            assert!(!e.contains("panicked"), "{e}");
            if out.status.code() == Some(2) {
                assert!(e.contains(f.as_str()), "{f}: {e}");
                tripped += 1;
            } else {
                assert!(out.status.success(), "{e}");
            }
            assert_eq!(snapshot(&case), before);
        }
    }
    assert_eq!(tripped, 3, "the queried pixel's file, damaged three ways");
}

#[test]
fn error_budget_fully_lit_tiles_and_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    let o = baked(tmp.path(), &[]);
    let d = Path::new(&o);
    json(&run(&[
        "horizon",
        &o,
        "--levels",
        "3",
        "--azimuths",
        "36",
        "--json",
    ]));
    // Per-tile K from an error budget: recorded per tile, within 1..=K; a tighter budget never
    // keeps fewer.
    json(&run(&[
        "fourier",
        &o,
        "--max-error-deg",
        "2",
        "--coefficients",
        "19",
        "--json",
    ]));
    let loose = penumbra::manifest::Tileset::load(d)
        .unwrap()
        .products
        .fourier
        .unwrap();
    json(&run(&[
        "fourier",
        &o,
        "--max-error-deg",
        "0.05",
        "--coefficients",
        "19",
        "--json",
    ]));
    let tight = penumbra::manifest::Tileset::load(d)
        .unwrap()
        .products
        .fourier
        .unwrap();
    let (lk, tk) = (
        loose.tile_coefficients.unwrap(),
        tight.tile_coefficients.unwrap(),
    );
    assert_eq!(lk.len(), tk.len());
    assert!(!lk.is_empty());
    for (t, k) in &lk {
        assert!((1..=19).contains(k) && tk[t] >= *k, "{t}: {k} vs {}", tk[t]);
    }
    assert!(
        tk.values().sum::<usize>() > lk.values().sum::<usize>(),
        "{lk:?} vs {tk:?}"
    );
    // Fully lit above 80°: no horizon of this scene rises that high, so every tile is marked
    // and answers 1 for a sun above, and refuses a sun below.
    let r = json(&run(&["fourier", &o, "--min-sun-el", "80", "--json"]));
    assert_eq!(r["tiles_fully_lit"], r["tiles"], "{r}");
    let a = json(&run(&[
        "query", "shadow", &o, "--lat", "-89.9", "--lon", "0", "--level", "3", "--sun-az", "0",
        "--sun-el", "85", "--json",
    ]));
    assert_eq!(a["lit_fraction"], 1.0);
    refused(
        &[
            "query", "shadow", &o, "--lat", "-89.9", "--lon", "0", "--level", "3", "--sun-az", "0",
            "--sun-el", "10",
        ],
        d,
        "fully lit",
    );
    // Same bytes on 1 thread and on all.
    json(&run(&["fourier", &o, "--sigma", "lanczos", "--json"]));
    let all = snapshot(d);
    std::fs::remove_dir_all(d.join("fourier")).unwrap();
    let r = json(&run(&[
        "--threads",
        "1",
        "fourier",
        &o,
        "--sigma",
        "lanczos",
        "--json",
    ]));
    assert_eq!(r["tiles_written"], r["tiles"]);
    let one = snapshot(d);
    let pick = |s: &std::collections::BTreeMap<String, Vec<u8>>| {
        s.iter()
            .filter(|(k, _)| k.starts_with("fourier/") || *k == "tileset.json")
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect::<Vec<_>>()
    };
    assert_eq!(pick(&all), pick(&one));
}

#[test]
fn bake_makes_pyramids_of_the_embedded_scene_by_default() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("tiles");
    let o = out.to_str().unwrap();
    let r = json(&run(&[
        "bake",
        "--out",
        o,
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--tile-size",
        "32",
        "--json",
    ]));
    assert_eq!(r["stages"], serde_json::json!(["tile", "mip", "horizon"]));
    // The default level (6) capped at the finest this tileset has.
    assert_eq!(r["horizon"]["levels"], serde_json::json!([3]));
    assert_eq!(r["horizon"]["raw"], false);
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let f = ts.products.fourier.unwrap();
    assert_eq!(
        (f.coefficients, f.layout.as_str(), f.encoding.as_str()),
        (16, "multires", "f16")
    );
    assert!(ts.products.horizon.is_none());
    assert!(!out.join("horizon").exists() && out.join("fourier").is_dir());
    let a = json(&run(&[
        "query", "shadow", o, "--lat", "-89.9", "--lon", "0", "--sun-az", "0", "--sun-el", "3",
        "--json",
    ]));
    assert!((0.0..=1.0).contains(&a["lit_fraction"].as_f64().unwrap()));
}

#[test]
fn tile_shadow_images_from_pyramids_and_raw_maps_agree() {
    let tmp = tempfile::tempdir().unwrap();
    // Level 7 of 64-px tiles is 333 m/px: the scene is about 60 px across the pole there.
    let out = tmp.path().join("tiles");
    let o = out.to_str().unwrap().to_string();
    json(&run(&[
        "bake",
        "--out",
        &o,
        "--scene-size",
        "1024",
        "--levels",
        "8",
        "--tile-size",
        "64",
        "--horizon-levels",
        "7",
        "--keep-raw",
        "--json",
    ]));
    // The tile holding the pole.
    let q = json(&run(&[
        "query", "height", &o, "--lat", "-89.95", "--lon", "0", "--level", "7", "--json",
    ]));
    let tile = format!(
        "{}/{}/{}",
        q["face"].as_str().unwrap(),
        q["tile"][1],
        q["tile"][0]
    );
    let images = |from: &str| -> (serde_json::Value, Vec<u8>, Vec<u8>) {
        let lit = tmp.path().join(format!("lit-{from}.png"));
        let rel = tmp.path().join(format!("relief-{from}.png"));
        let r = json(&run(&[
            "shadow",
            &o,
            "--level",
            "7",
            "--tile",
            &tile,
            "--sun-lat",
            "-2",
            "--sun-lon",
            "45",
            "--from",
            from,
            "--out",
            lit.to_str().unwrap(),
            "--relief",
            rel.to_str().unwrap(),
            "--json",
        ]));
        // Grey where there is data (R = G = B), the no-data colour elsewhere: keep the red channel.
        let red = |p: &Path| -> image::GrayImage {
            let im = image::open(p).unwrap().to_rgb8();
            image::GrayImage::from_fn(im.width(), im.height(), |x, y| {
                let px = im.get_pixel(x, y).0;
                image::Luma([if px[0] == px[1] && px[1] == px[2] {
                    px[0]
                } else {
                    0
                }])
            })
        };
        let l = red(&lit);
        let rl = red(&rel);
        assert_eq!((l.width(), l.height()), (64, 64));
        assert_eq!((rl.width(), rl.height()), (64, 64));
        (r, l.into_raw(), rl.into_raw())
    };
    let (rf, lf, _) = images("fourier");
    let (rr, lr, relief) = images("raw");
    let total = |r: &serde_json::Value| {
        [
            "lit_pixels",
            "dark_pixels",
            "partial_pixels",
            "no_data_pixels",
        ]
        .iter()
        .map(|k| r[k].as_u64().unwrap())
        .sum::<u64>()
    };
    assert_eq!((total(&rf), total(&rr)), (4096, 4096));
    // A low sun (about 2° at the pole): both shadowed and lit pixels.
    assert!(
        rr["dark_pixels"].as_u64().unwrap() > 0 && rr["lit_pixels"].as_u64().unwrap() > 0,
        "{rr}"
    );
    // Pyramids and raw maps agree on the lit/shadowed decision almost everywhere.
    let data = rr["lit_pixels"].as_u64().unwrap()
        + rr["dark_pixels"].as_u64().unwrap()
        + rr["partial_pixels"].as_u64().unwrap();
    let differ = lf
        .iter()
        .zip(&lr)
        .filter(|(a, b)| (**a >= 128) != (**b >= 128))
        .count();
    assert!(
        (differ as f64) <= 0.1 * data as f64,
        "{differ} of {data} pixels differ between fourier and raw"
    );
    // Shadowed pixels are dark in the relief (ambient only).
    for (l, r) in lr.iter().zip(&relief) {
        if *l == 0 {
            assert!(*r <= 26, "a shadowed pixel is {r}/255 in the relief");
        }
    }
    // Bad input: exit 2, no image written.
    let lit = tmp.path().join("bad.png");
    let l = lit.to_str().unwrap();
    for (level, t, sun_lat, needle) in [
        ("7", "nz/1", "-2", "FACE/Y/X"),
        ("7", "qq/1/1", "-2", "FACE/Y/X"),
        ("7", "nz/0/0", "-2", "has no tile"),
        ("7", tile.as_str(), "95", "--sun-lat"),
        // The parent of the pole's tile exists at level 6 but has no horizons.
        ("6", "nz/31/32", "-2", "level 6 has no"),
    ] {
        let a = vec![
            "shadow",
            &o,
            "--level",
            level,
            "--tile",
            t,
            "--sun-lat",
            sun_lat,
            "--sun-lon",
            "0",
            "--out",
            l,
        ];
        let out = run(&a);
        let e = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{a:?}: {e}");
        assert!(e.contains(needle), "{a:?}: {e}");
        assert!(!lit.exists());
    }
}
