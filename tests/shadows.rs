//! Shadow methods through the CLI: `query shadow --method` for every method against the exact
//! reference on the embedded scene, `penumbra shadow` over a tile and a latitude/longitude box
//! (PNG, relief, EXR, JSON), determinism across thread counts, and bad input (a method whose
//! product is missing, suns below −90°, boxes outside the coverage, malformed flags): exit 2
//! and nothing written.

use std::path::Path;
use std::process::Output;

use crate::util::{penumbra_bin, snapshot};

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

/// The embedded scene at 1024 px, 32-px tiles, 4 levels, with raw horizon maps of 36 azimuths
/// and their pyramids at level 3.
fn baked(dir: &Path) -> String {
    let o = dir.join("tiles");
    let s = o.to_str().unwrap().to_string();
    json(&run(&[
        "bake",
        "--out",
        &s,
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--tile-size",
        "32",
        "--horizon-levels",
        "3",
        "--keep-raw",
        "--json",
    ]));
    s
}

fn lit(o: &str, lat: f64, lon: f64, az: f64, el: f64, method: &[&str]) -> (f64, serde_json::Value) {
    let q = json(&run(&[
        &[
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
            "--json",
        ][..],
        method,
    ]
    .concat()));
    (q["lit_fraction"].as_f64().unwrap(), q)
}

#[test]
fn every_method_answers_a_point_and_agrees_with_the_reference() {
    let d = tempfile::tempdir().unwrap();
    let o = baked(d.path());
    let points = [
        (-89.9, 0.0),
        (-89.8, 200.0),
        (-89.85, 300.0),
        (-89.95, 100.0),
    ];
    let methods: [&[&str]; 7] = [
        &["--method", "uniform", "--steps", "400"],
        &["--method", "dp"],
        &["--method", "dp", "--dp-levels", "5,5,5,3"],
        &["--method", "dp-dda"],
        &["--method", "extrema"],
        &["--method", "smap"],
        &["--method", "horizon", "--from", "raw"],
    ];
    let mut err = vec![0.0f64; methods.len()];
    let mut wrong = vec![0usize; methods.len()];
    let mut n = 0usize;
    for &(lat, lon) in &points {
        for az in [0.0, 100.0, 215.0, 300.0] {
            for el in [1.0, 5.0, 15.0] {
                let (r, q) = lit(&o, lat, lon, az, el, &["--method", "reference"]);
                assert!((0.0..=1.0).contains(&r), "{q}");
                assert_eq!(q["method"], "reference");
                assert_eq!(q["source"], "traced");
                n += 1;
                for (k, m) in methods.iter().enumerate() {
                    let (v, q) = lit(&o, lat, lon, az, el, m);
                    assert!((0.0..=1.0).contains(&v), "{m:?}: {q}");
                    if m[1] == "extrema" || m[1] == "smap" {
                        assert!(v == 0.0 || v == 1.0, "hard method gave {v}");
                        assert_eq!(q["method"], m[1]);
                    }
                    err[k] += (v - r).abs();
                    if (v >= 0.5) != (r >= 0.5) {
                        wrong[k] += 1;
                    }
                }
            }
        }
    }
    for (k, m) in methods.iter().enumerate() {
        let mae = err[k] / n as f64;
        let per = wrong[k] as f64 / n as f64;
        // Extrema and the 360-sample... (36 here) raw maps decide as the reference does
        // except within a pixel's rounding; DP and uniform stepping estimate.
        let (mae_max, per_max) = match m[1] {
            "extrema" | "smap" => (0.1, 0.05),
            "horizon" => (0.1, 0.1),
            _ => (0.1, 0.1),
        };
        assert!(
            mae <= mae_max,
            "{m:?}: mean |error| {mae} over {n} suns and points"
        );
        assert!(per <= per_max, "{m:?}: {wrong:?} wrong decisions of {n}");
    }
}

#[test]
fn a_tile_and_a_box_render_with_every_method_the_same_at_any_thread_count() {
    let d = tempfile::tempdir().unwrap();
    let o = baked(d.path());
    let out = d.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    for m in [
        "reference",
        "uniform",
        "dp",
        "dp-dda",
        "dp-jung",
        "extrema",
        "smap",
        "horizon",
    ] {
        let png = out.join(format!("{m}.png"));
        let relief = out.join(format!("{m}-relief.png"));
        let p = png.to_str().unwrap();
        let args = [
            "shadow",
            &o,
            "--level",
            "3",
            "--tile",
            "nz/3/3",
            "--sun-lat",
            "-4",
            "--sun-lon",
            "40",
            "--method",
            m,
            "--out",
            p,
            "--relief",
            relief.to_str().unwrap(),
            "--exr",
            "--json",
        ];
        let j = json(&run(&args));
        let total: u64 = [
            "lit_pixels",
            "dark_pixels",
            "partial_pixels",
            "no_data_pixels",
        ]
        .iter()
        .map(|k| j[k].as_u64().unwrap())
        .sum();
        assert_eq!(total, 32 * 32, "{j}");
        let img = image::open(&png).unwrap();
        assert_eq!((img.width(), img.height()), (32, 32));
        assert!(png.with_extension("exr").metadata().unwrap().len() > 0);
        assert!(relief.exists());
        if m == "extrema" || m == "smap" {
            assert_eq!(j["partial_pixels"], 0, "a hard method has no penumbra: {j}");
        }
        if m == "smap" {
            let f = j["smap"]["marked_fraction"].as_f64().unwrap();
            assert!(f > 0.0 && f < 1.0, "marked fraction {f}: {j}");
            assert!(j["smap"]["samples"].as_u64().unwrap() >= 32 * 32, "{j}");
        } else {
            assert!(j.get("smap").is_none(), "{m}: {j}");
        }
        // Same bytes on one thread.
        let png1 = out.join(format!("{m}-1.png"));
        let mut a1: Vec<&str> = args.to_vec();
        let at = a1.iter().position(|a| *a == p).unwrap();
        a1[at] = png1.to_str().unwrap();
        a1.retain(|a| *a != "--exr");
        a1.extend(["--threads", "1"]);
        json(&run(&a1));
        assert_eq!(
            std::fs::read(&png).unwrap(),
            std::fs::read(&png1).unwrap(),
            "{m}: 1 thread and the default differ"
        );
    }
    // A box over the pole from every tile of level 3 it touches.
    let png = out.join("box.png");
    let j = json(&run(&[
        "shadow",
        &o,
        "--level",
        "3",
        "--bbox=-90,-89.4,0,360",
        "--sun-lat",
        "-3",
        "--sun-lon",
        "40",
        "--method",
        "dp",
        "--out",
        png.to_str().unwrap(),
        "--json",
    ]));
    let (w, h) = (j["width"].as_u64().unwrap(), j["height"].as_u64().unwrap());
    assert!(w > h && h >= 1, "{j}");
    let counted: u64 = [
        "lit_pixels",
        "dark_pixels",
        "partial_pixels",
        "no_data_pixels",
    ]
    .iter()
    .map(|k| j[k].as_u64().unwrap())
    .sum();
    assert_eq!(counted, w * h, "{j}");
    let img = image::open(&png).unwrap();
    assert_eq!((img.width() as u64, img.height() as u64), (w, h));
    assert!(j["lit_pixels"].as_u64().unwrap() > 0, "{j}");
}

/// Exit 2, a message containing `needle`, nothing new in `out_dir` and the tileset unchanged.
fn refused(args: &[&str], tiles: &Path, out_dir: &Path, needle: &str) {
    let before = snapshot(tiles);
    let out_before = snapshot(out_dir);
    let o = run(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
    assert!(e.contains(needle), "{args:?}: {e:?} lacks {needle:?}");
    assert!(!e.contains("panicked"), "{e}");
    assert_eq!(snapshot(tiles), before, "{args:?} altered the tileset");
    assert_eq!(snapshot(out_dir), out_before, "{args:?} wrote output");
}

#[test]
fn bad_shadow_input_exits_2_and_writes_nothing() {
    let d = tempfile::tempdir().unwrap();
    let o = d.path().join("tiles");
    let os = o.to_str().unwrap();
    json(&run(&[
        "bake",
        "--out",
        os,
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--tile-size",
        "32",
        "--no-horizons",
        "--json",
    ]));
    let out = d.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let png = out.join("lit.png");
    let p = png.to_str().unwrap();
    let tile = |extra: &[&str]| -> Vec<String> {
        // The sub-solar point unless the case gives its own.
        let mut v: Vec<String> = ["shadow", os, "--level", "2", "--tile", "nz/1/1", "--out", p]
            .iter()
            .map(|s| s.to_string())
            .collect();
        if !extra.contains(&"--sun-lat") {
            v.extend(["--sun-lat".into(), "-3".into()]);
        }
        if !extra.contains(&"--sun-lon") {
            v.extend(["--sun-lon".into(), "40".into()]);
        }
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let cases: Vec<(Vec<String>, &str)> = vec![
        // A method whose product the tileset lacks: say what to run first.
        (tile(&["--method", "horizon"]), "penumbra horizon --fourier"),
        (
            tile(&["--method", "horizon", "--from", "raw"]),
            "penumbra horizon",
        ),
        // Suns that are not suns.
        (tile(&["--method", "dp", "--sun-lat", "-91"]), "--sun-lat"),
        (tile(&["--method", "dp", "--sun-lon", "NaN"]), "--sun-lon"),
        (
            tile(&["--method", "dp", "--sun-distance-au", "0"]),
            "sun-distance-au",
        ),
        // Malformed method flags.
        (tile(&["--method", "smoke"]), "unknown shadow method"),
        (tile(&["--method", "uniform", "--steps", "0"]), "steps"),
        (tile(&["--method", "dp", "--dp-levels", "0,5"]), "dp-levels"),
        (tile(&["--method", "dp", "--dp-levels", "17"]), "dp-levels"),
        (tile(&["--method", "dp", "--dp-levels", "5;5"]), "dp-levels"),
        (tile(&["--method", "dp", "--from", "raw"]), "--from"),
        // A tile that is not there.
        (
            vec![
                "shadow",
                os,
                "--level",
                "2",
                "--tile",
                "px/0/0",
                "--sun-lat",
                "0",
                "--sun-lon",
                "0",
                "--method",
                "dp",
                "--out",
                p,
            ]
            .iter()
            .map(|s| s.to_string())
            .collect(),
            "no tile",
        ),
    ];
    for (args, needle) in &cases {
        let a: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
        refused(&a, &o, &out, needle);
    }
    let bx = |b: &str| -> Vec<String> {
        [
            "shadow",
            os,
            "--level",
            "2",
            &format!("--bbox={b}"),
            "--sun-lat",
            "-3",
            "--sun-lon",
            "40",
            "--method",
            "dp",
            "--out",
            p,
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    };
    for (b, needle) in [
        ("10,20,0,10", "no tile of level 2 covers"),
        ("20,10,0,10", "LAT0 < LAT1"),
        ("-95,-80,0,10", "LAT0 < LAT1"),
        ("-90,-80,10,0", "LON0 < LON1"),
        ("-90,-80,0", "four numbers"),
        ("-90,-80,0,x", "four numbers"),
        ("-90,-80,NaN,10", "not a number"),
    ] {
        let a = bx(b);
        let a: Vec<&str> = a.iter().map(|s| s.as_str()).collect();
        refused(&a, &o, &out, needle);
    }
    // The point query: a sun below −90°, and a method whose product is missing.
    for (extra, needle) in [
        (&["--sun-el", "-91", "--method", "dp"][..], "--sun-el"),
        (
            &["--sun-el", "5", "--method", "horizon"][..],
            "Fourier pyramids",
        ),
        (
            &["--sun-el", "5", "--method", "extrema", "--from", "raw"][..],
            "--from",
        ),
    ] {
        let a = [
            &[
                "query", "shadow", os, "--lat", "-89.9", "--lon", "0", "--sun-az", "10",
            ][..],
            extra,
        ]
        .concat();
        refused(&a, &o, &out, needle);
    }
    // --exr beside an --out that already ends in .exr would overwrite it.
    let exr = out.join("lit.exr");
    refused(
        &[
            "shadow",
            os,
            "--level",
            "2",
            "--tile",
            "nz/1/1",
            "--sun-lat",
            "-3",
            "--sun-lon",
            "40",
            "--method",
            "dp",
            "--out",
            exr.to_str().unwrap(),
            "--exr",
        ],
        &o,
        &out,
        "--out",
    );
}
