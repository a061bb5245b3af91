//! The stress catalogue (`penumbra::stress`, docs/stress.md), one catalogue with two front
//! ends: every case as its own test at the short size, a check that no case goes untested, the
//! weakened kernels making cases fail, and `penumbra stress` through the CLI (exit 0 with every
//! row passing, 1 naming a failing case under `--weaken`, 2 on bad flags).

use penumbra::stress::{self, Row, Size, Weaken};

use crate::util::penumbra_bin;

/// The rows of the case named `name`, run at the short size with the kernels as they are.
fn run(name: &str) -> Vec<Row> {
    let case = stress::catalogue()
        .into_iter()
        .find(|c| c.name == name)
        .unwrap_or_else(|| panic!("no case {name} in the catalogue"));
    stress::run_case(&case, Size::Short, Weaken::None)
}

fn show(rows: &[Row]) -> String {
    rows.iter()
        .map(|r| {
            format!(
                "  {} / {}: error {:e} {} bound {:e} nonfinite {} {}",
                r.case,
                r.quantity,
                r.error,
                r.unit,
                r.bound,
                r.nonfinite,
                if r.pass { "ok" } else { "FAIL" }
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// One `#[test]` per catalogue case, and the list of the names they cover.
macro_rules! cases {
    ($($test:ident => $name:literal,)*) => {
        $(
            #[test]
            fn $test() {
                let rows = run($name);
                eprintln!("{}", show(&rows));
                assert!(!rows.is_empty(), "{}: no rows", $name);
                assert!(rows.iter().all(|r| r.pass), "{} fails:\n{}", $name, show(&rows));
            }
        )*
        const TESTED: &[&str] = &[$($name),*];
    };
}

cases! {
    flat_sphere => "flat-sphere",
    spike_1px => "spike-1px",
    vertical_cliff => "vertical-cliff",
    axes_diagonals => "axes-diagonals",
    cube_corner => "cube-corner",
    north_pole => "north-pole",
    ten_km_body => "ten-km-body",
    jupiter_sphere => "jupiter-sphere",
    mars_relief_f16 => "mars-relief-f16",
    voids_nan => "voids-nan",
    constant_tile => "constant-tile",
    tile_seam => "tile-seam",
    face_seam => "face-seam",
    sun_at_0 => "sun-at-0",
    sun_below_0 => "sun-below-0",
    sun_at_90 => "sun-at-90",
    grazing_texel_edges => "grazing-texel-edges",
    shadow_axes_diagonals => "shadow-axes-diagonals",
    shadow_small_and_huge_bodies => "shadow-small-and-huge-bodies",
    shadow_voids => "shadow-voids",
    k_1 => "k-1",
    k_a_half_plus_1 => "k-a-half-plus-1",
    f16_limits => "f16-limits",
    level_seams => "level-seams",
    tile_16384 => "tile-16384",
}

/// A case added to the catalogue without a test here fails this (and one removed, too).
#[test]
fn every_case_has_a_test() {
    let names: Vec<&str> = stress::catalogue().iter().map(|c| c.name).collect();
    assert_eq!(
        names, TESTED,
        "tests/stress.rs: add a line to `cases!` for each new case, in catalogue order"
    );
}

/// Each weakened kernel makes some case of its area fail (so the bounds can fail), and the
/// weakening stays within its area: the other areas still pass.
#[test]
fn weakened_kernels_fail_their_cases() {
    for (w, area) in [
        (Weaken::HorizonFloorZero, "horizon"),
        (Weaken::ShadowPointSun, "shadow"),
        (Weaken::FourierDropTerm, "fourier"),
    ] {
        let cases: Vec<_> = stress::catalogue()
            .into_iter()
            .filter(|c| c.area == area)
            .collect();
        let rows = stress::run(&cases, Size::Short, w, &|_, _, _| {});
        let failed: Vec<&str> = rows
            .iter()
            .filter(|r| !r.pass)
            .map(|r| r.case.as_str())
            .collect();
        eprintln!("{}: {} rows fail in {failed:?}", w.name(), failed.len());
        assert!(!failed.is_empty(), "{}: no {area} case fails", w.name());
    }
}

#[test]
fn cli_short_catalogue_passes_in_json() {
    let out = penumbra_bin().args(["stress", "--json"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "stderr: {stderr}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["passed"], true);
    assert_eq!(v["size"], "short");
    let rows = v["rows"].as_array().unwrap();
    let cases: std::collections::BTreeSet<&str> =
        rows.iter().map(|r| r["case"].as_str().unwrap()).collect();
    assert_eq!(cases.len(), stress::catalogue().len());
    for r in rows {
        assert_eq!(r["pass"], true, "{r}");
        assert!(r["error"].as_f64().unwrap() <= r["bound"].as_f64().unwrap());
    }
    // Rows in catalogue order.
    let order: Vec<&str> = rows.iter().map(|r| r["case"].as_str().unwrap()).collect();
    let mut dedup = order.clone();
    dedup.dedup();
    assert_eq!(dedup, TESTED);
}

#[test]
fn cli_weakened_kernel_exits_1_naming_the_case() {
    let out = penumbra_bin()
        .args([
            "stress",
            "--only",
            "spike",
            "--weaken",
            "horizon-floor-zero",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(stdout.contains("FAIL"), "{stdout}");
    assert!(
        stderr.contains("spike-1px / spike dip reference"),
        "{stderr}"
    );
}

#[test]
fn cli_bad_flags_exit_2() {
    for (args, says) in [
        (
            &["stress", "--weaken", "gentle"][..],
            "--weaken 'gentle' is no weakened kernel",
        ),
        (
            &["stress", "--only", "no-such-case"][..],
            "--only 'no-such-case' matches no case",
        ),
    ] {
        let out = penumbra_bin().args(args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
        assert!(out.stdout.is_empty(), "{args:?}: wrote to stdout");
    }
}
