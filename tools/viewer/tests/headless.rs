//! Headless frames of the embedded south-pole scene and of a real DEM (LOLA's 5 m Shoemaker
//! crater): a low sun gives lit and shadowed terrain, a sun at the zenith none; two runs give
//! the same bytes; and `--validate` holds the GPU to the CPU twin of its method (mean abs
//! ≤ 0.01, PER ≤ 0.5 %) on both, DP to the CPU reference (mean abs ≤ 0.05; PER ≤ 1 % on the
//! real DEM) and the hard extrema to it (PER ≤ 1 %). At the scene's 2.3° sun DP's own
//! error against the reference (5 % of decisions, CPU and GPU alike) exceeds the PER bound:
//! docs/viewer.md has those numbers; the tests hold the GPU to the CPU there.

use std::path::Path;

use serde_json::Value;

use crate::util::{gpu, json, read_png, run, scene, shoemaker, tmp};

/// A camera 9 km above the scene, 6 km from the pole, looking towards it 60° down.
const SCENE_CAMERA: &str = "--camera=-89.8,30,9000,210,-60,50";
/// A sun 2.5° above the pole's horizon.
const LOW_SUN: [&str; 4] = ["--sun-lat", "-2.5", "--sun-lon", "75"];

/// Render `dir` headless into `out` with `extra` flags; the JSON report.
fn frame(dir: &Path, out: &Path, extra: &[&str]) -> Value {
    let o = out.join("frame.png");
    let mut args = vec![
        dir.to_str().unwrap(),
        "--headless",
        "--out",
        o.to_str().unwrap(),
        "--size",
        "160x120",
        "--frames",
        "1",
        "--json",
    ];
    args.extend_from_slice(extra);
    json(&run(&args))
}

fn u(v: &Value, k: &str) -> u64 {
    v["pixels"][k].as_u64().unwrap()
}

fn f(v: &Value, path: &[&str]) -> f64 {
    let mut x = v;
    for k in path {
        x = &x[*k];
    }
    x.as_f64().unwrap_or_else(|| panic!("{path:?} in {v}"))
}

/// The validation numbers hold: GPU vs CPU twin always; vs the reference when `vs_ref` is
/// given (its largest mean and PER).
fn check_validation(v: &Value, what: &str, vs_ref: Option<(f64, f64)>) {
    let same_mean = f(v, &["validation", "same", "mean_abs"]);
    let same_per = f(v, &["validation", "same", "per_percent"]);
    let px = f(v, &["validation", "same", "pixels"]);
    assert!(px > 1000.0, "{what}: only {px} pixels compared");
    assert!(
        same_mean <= 0.01 && same_per <= 0.5,
        "{what}: GPU vs CPU {} mean {same_mean} PER {same_per} %",
        v["method"]
    );
    if let Some((mean, per)) = vs_ref {
        let m = f(v, &["validation", "reference", "mean_abs"]);
        let p = f(v, &["validation", "reference", "per_percent"]);
        assert!(
            m <= mean && p <= per,
            "{what}: GPU vs reference mean {m} PER {p} %"
        );
    }
}

/// Where shadows are decided (the sun within ±3° of a texel's horizon), GPU `extrema-soft` is
/// within mean 0.01 of the CPU reference, over at least 200 such pixels.
fn check_penumbra(v: &Value, what: &str) {
    let n = f(v, &["validation", "penumbra", "pixels"]);
    let m = f(v, &["validation", "penumbra", "reference", "mean_abs"]);
    eprintln!("{what}: {n} penumbral pixels, GPU vs reference mean {m}");
    assert!(n >= 200.0, "{what}: only {n} penumbral pixels");
    assert!(
        m <= 0.01,
        "{what}: penumbral GPU vs reference mean {m} > 0.01"
    );
}

#[test]
fn a_low_sun_lights_and_shadows_the_scene_and_dp_matches_the_cpu() {
    if !gpu() {
        return;
    }
    let d = tmp();
    let lit = d.path().join("lit.exr");
    let v = frame(
        scene(),
        d.path(),
        &[
            SCENE_CAMERA,
            LOW_SUN[0],
            LOW_SUN[1],
            LOW_SUN[2],
            LOW_SUN[3],
            "--lit",
            lit.to_str().unwrap(),
            "--validate",
        ],
    );
    let total = 160 * 120;
    assert!(u(&v, "surface") > total * 9 / 10, "{v}");
    assert!(
        u(&v, "dark") > total / 50,
        "too little shadow: {}",
        v["pixels"]
    );
    assert!(
        u(&v, "lit") > total / 20,
        "too little light: {}",
        v["pixels"]
    );
    assert!(v["method"].as_str().unwrap().starts_with("dp"));
    // DP's own error at a 2.3° sun on this scene (CPU DP against the CPU reference, 5 % of
    // decisions) is not the GPU's: only the twin is held here; the reference below.
    check_validation(&v, "embedded scene, dp", None);
    // The frame: sky black, terrain in many shades.
    let (w, h, px) = read_png(&d.path().join("frame.png"));
    assert_eq!((w, h), (160, 120));
    let mut shades: Vec<u8> = px.iter().map(|p| p[1]).collect();
    shades.sort();
    shades.dedup();
    assert!(shades.len() > 40, "{} shades", shades.len());
    // The lit fraction EXR and the difference images.
    assert!(lit.is_file());
    assert!(d.path().join("frame-diff.png").is_file());
    assert!(d.path().join("frame-diff-reference.png").is_file());
    // Timings.
    assert!(f(&v, &["timings", "wall_ms_median"]) > 0.0);
}

#[test]
fn every_method_matches_its_cpu_twin_on_the_scene() {
    if !gpu() {
        return;
    }
    for (m, extra) in [
        ("uniform", &["--steps", "50"][..]),
        ("dp-jung", &[][..]),
        ("extrema", &[][..]),
        ("extrema-soft", &[][..]),
        ("fourier", &[][..]),
        ("fourier", &["--fourier-model", "exact"][..]),
    ] {
        let d = tmp();
        let mut args = vec![
            SCENE_CAMERA,
            LOW_SUN[0],
            LOW_SUN[1],
            LOW_SUN[2],
            LOW_SUN[3],
            "--method",
            m,
            "--validate",
        ];
        args.extend_from_slice(extra);
        let v = frame(scene(), d.path(), &args);
        assert!(
            u(&v, "dark") > 0 && u(&v, "lit") > 0,
            "{m}: {}",
            v["pixels"]
        );
        // The min/max traversals decide as the exact reference does (hard PER ≤ 1 %), and the
        // soft one finds its lit fractions (mean ≤ 0.01).
        let vs_ref = match m {
            "extrema" => Some((0.05, 1.0)),
            "extrema-soft" => Some((0.01, 1.0)),
            _ => None,
        };
        check_validation(&v, m, vs_ref);
        if m == "extrema-soft" {
            check_penumbra(&v, "embedded scene, extrema-soft");
        }
        if m == "fourier" && extra.is_empty() {
            // The O(K) constant model against the exact disc model over the same coefficients.
            let e = f(&v, &["validation", "exact_model", "mean_abs"]);
            assert!(e <= 0.005, "fourier constant vs exact: mean {e}");
        }
        if m == "fourier" {
            // Drawn at the level that has pyramids.
            assert!(v["tiles"]
                .as_array()
                .unwrap()
                .iter()
                .all(|t| t.as_str().unwrap().starts_with("L9/")));
        }
    }
}

#[test]
fn dp_on_the_gpu_stays_within_the_reference_bounds_at_an_8_degree_sun() {
    if !gpu() {
        return;
    }
    let d = tmp();
    let v = frame(
        scene(),
        d.path(),
        &[
            SCENE_CAMERA,
            "--sun-lat=-8",
            "--sun-lon",
            "75",
            "--validate",
        ],
    );
    check_validation(&v, "embedded scene, dp, 8° sun", Some((0.05, 100.0)));
}

#[test]
fn level_changes_leave_no_cracks() {
    if !gpu() {
        return;
    }
    let d = tmp();
    // Coarse refinement: tiles of levels 7, 8 and 9 side by side in one view.
    let v = frame(
        scene(),
        d.path(),
        &[
            SCENE_CAMERA,
            "--sun-lat=-8",
            "--sun-lon",
            "75",
            "--max-texel-px",
            "8",
        ],
    );
    let mut levels: Vec<&str> = v["tiles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_str().unwrap().split('/').next().unwrap())
        .collect();
    levels.sort();
    levels.dedup();
    assert!(levels.len() >= 2, "one level only: {levels:?}");
    // Sky is pure black, terrain never is (ambient light): below the first terrain pixel of a
    // column, a black pixel is a crack.
    let (w, h, px) = read_png(&d.path().join("frame.png"));
    let mut cracks = 0;
    for c in 0..w as usize {
        let col: Vec<bool> = (0..h as usize)
            .map(|r| px[r * w as usize + c] != [0, 0, 0])
            .collect();
        if let Some(first) = col.iter().position(|&t| t) {
            cracks += col[first..].iter().filter(|&&t| !t).count();
        }
    }
    assert_eq!(
        cracks, 0,
        "{cracks} sky pixels inside the terrain (levels {levels:?})"
    );
}

#[test]
fn a_sun_at_the_zenith_casts_no_shadow() {
    if !gpu() {
        return;
    }
    let d = tmp();
    // The sub-solar point at the pole: the sun stands 89.4–90° high over the whole scene,
    // steeper than any slope in it.
    let v = frame(
        scene(),
        d.path(),
        &[
            SCENE_CAMERA,
            "--sun-lat=-90",
            "--sun-lon",
            "0",
            "--validate",
        ],
    );
    assert!(u(&v, "surface") > 10_000, "{v}");
    assert_eq!(u(&v, "dark"), 0, "{}", v["pixels"]);
    assert_eq!(u(&v, "partial"), 0, "{}", v["pixels"]);
    assert!(f(&v, &["sun", "elevation_deg"]) > 89.0);
}

#[test]
fn the_same_frame_twice_is_the_same_bytes() {
    if !gpu() {
        return;
    }
    let (a, b) = (tmp(), tmp());
    let go = |d: &Path| {
        let lit = d.join("lit.exr");
        frame(
            scene(),
            d,
            &[
                SCENE_CAMERA,
                LOW_SUN[0],
                LOW_SUN[1],
                LOW_SUN[2],
                LOW_SUN[3],
                "--lit",
                lit.to_str().unwrap(),
            ],
        );
        (
            std::fs::read(d.join("frame.png")).unwrap(),
            std::fs::read(lit).unwrap(),
        )
    };
    let (pa, la) = go(a.path());
    let (pb, lb) = go(b.path());
    assert!(pa == pb, "frames differ");
    assert!(la == lb, "lit fractions differ");
}

#[test]
fn a_real_dem_validates_every_method_at_a_low_sun() {
    if !gpu() {
        return;
    }
    let Some(dir) = shoemaker() else {
        return;
    };
    // Shoemaker's 1.3 km square of 5 m LOLA heights near 87°S from the default camera, with
    // the sun 5.7° high: every method against its CPU twin, DP and extrema against the
    // reference too.
    for m in ["dp", "uniform", "extrema", "extrema-soft", "fourier"] {
        let d = tmp();
        let v = frame(
            dir,
            d.path(),
            &[
                "--sun-lat=-3",
                "--sun-lon",
                "45",
                "--method",
                m,
                "--validate",
            ],
        );
        assert!(u(&v, "surface") > 160 * 120 / 3, "{v}");
        assert!(
            u(&v, "dark") > 0 && u(&v, "lit") > 0,
            "{m}: {}",
            v["pixels"]
        );
        let vs_ref = match m {
            "dp" | "extrema" => Some((0.05, 1.0)),
            "extrema-soft" => Some((0.01, 1.0)),
            _ => None,
        };
        check_validation(&v, &format!("Shoemaker, {m}"), vs_ref);
        if m == "extrema-soft" {
            check_penumbra(&v, "Shoemaker, extrema-soft");
        }
    }
}

#[test]
fn albedo_colours_the_terrain() {
    if !gpu() {
        return;
    }
    let d = tmp();
    // The whole globe from above 0°, 0° with the sun behind the eye: west red, east blue.
    let v = frame(
        crate::util::albedo_globe(),
        d.path(),
        &["--sun-lat", "0", "--sun-lon", "0", "--method", "extrema"],
    );
    assert!(u(&v, "surface") > 5000, "{v}");
    let (w, h, px) = read_png(&d.path().join("frame.png"));
    let row = h as usize / 2;
    let at = |c: usize| px[row * w as usize + c];
    let (west, east) = (at(w as usize / 2 - 20), at(w as usize / 2 + 20));
    assert!(west[0] > 2 * west[2] && west[0] > 80, "west {west:?}");
    assert!(east[2] > 2 * east[0] && east[2] > 80, "east {east:?}");
}
