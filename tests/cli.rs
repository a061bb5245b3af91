use std::path::Path;
use std::process::Output;

use crate::util::penumbra_bin;

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

/// Bad input: exit code 2, a message naming the file and the problem, and no output folder.
fn assert_refused(args: &[&str], out: &Path, needle: &str) {
    let o = run(args);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains(needle),
        "{args:?}: message {e:?} lacks {needle:?}"
    );
    assert!(!e.contains("panicked"), "{e}");
    assert!(!out.exists(), "{args:?} left {} behind", out.display());
}

/// `penumbra info DIR | head -1`: a reader that closes the pipe early is no error (exit 0, no
/// message), as with other Unix tools, for the table and for JSON.
#[test]
fn a_closed_pipe_is_not_an_error() {
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles");
    let o = out.to_str().unwrap();
    json(&run(&[
        "bake",
        "--out",
        o,
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--no-horizons",
        "--json",
    ]));
    for args in [
        vec!["info", o],
        vec!["info", o, "--json"],
        vec!["query", "height", o, "--lat", "-89.5", "--lon", "10"],
    ] {
        for _ in 0..5 {
            let mut child = penumbra_bin()
                .args(&args)
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap();
            // Close the reading end before the command writes anything.
            drop(child.stdout.take());
            let o = child.wait_with_output().unwrap();
            assert_eq!(o.status.code(), Some(0), "{args:?}: {}", stderr(&o));
            assert!(o.stderr.is_empty(), "{args:?}: {}", stderr(&o));
        }
    }
}

#[test]
fn bake_info_and_query_on_the_embedded_scene() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles");
    let o = out.to_str().unwrap();
    let r = json(&run(&[
        "bake",
        "--out",
        o,
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--no-horizons",
        "--json",
    ]));
    assert_eq!(r["tile"]["levels"], 4);
    assert!(r["tile"]["tiles_written"].as_u64().unwrap() >= 4);

    let info = json(&run(&["info", o, "--json"]));
    assert_eq!(info["body"]["radius_m"], 1_737_400.0);
    assert_eq!(info["layout"]["projection"], "gnomonic");
    let text = run(&["info", o]);
    assert!(String::from_utf8_lossy(&text.stdout).contains("level"));

    // The south pole is in the scene; heights are lunar-like.
    let q = json(&run(&[
        "query", "height", o, "--lat", "-89.95", "--lon", "260", "--json",
    ]));
    let h = q["height_m"].as_f64().unwrap();
    assert!(
        h.abs() < 5000.0 && q["face"] == "nz" && q["level"] == 3,
        "{q}"
    );
    // Longitudes 260 and −100 are the same; 0..360 accepted.
    let q2 = json(&run(&[
        "query", "height", o, "--lat", "-89.95", "--lon", "-100", "--json",
    ]));
    assert_eq!(q["height_m"], q2["height_m"]);
    // A second bake is a no-op.
    let r = json(&run(&[
        "bake",
        "--out",
        o,
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--no-horizons",
        "--json",
    ]));
    assert_eq!(r["tile"]["up_to_date"], true);

    // Outside the scene, and bad coordinates: exit 2 with a reason.
    let e = run(&["query", "height", o, "--lat", "10", "--lon", "10", "--json"]);
    assert_eq!(e.status.code(), Some(2));
    assert!(
        stderr(&e).contains("no height tile covers"),
        "{}",
        stderr(&e)
    );
    let e = run(&["query", "height", o, "--lat", "-95", "--lon", "10"]);
    assert_eq!(e.status.code(), Some(2));
    let e = run(&[
        "query", "height", o, "--lat", "-89.9", "--lon", "10", "--level", "9",
    ]);
    assert!(stderr(&e).contains("levels 0..=3"), "{}", stderr(&e));
}

#[test]
fn bad_input_exits_2_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = out.to_str().unwrap();
    let missing = dir.path().join("nope.LBL");
    assert_refused(
        &[
            "tile",
            missing.to_str().unwrap(),
            "--body",
            "moon",
            "--out",
            o,
        ],
        &out,
        "nope.LBL",
    );
    let junk = dir.path().join("junk.xyz");
    std::fs::write(&junk, b"hello").unwrap();
    assert_refused(
        &["tile", junk.to_str().unwrap(), "--body", "moon", "--out", o],
        &out,
        "unknown DEM format",
    );
    let lbl = dir.path().join("garbage.LBL");
    std::fs::write(&lbl, [0u8, 159, 146, 150, 1, 2, 3, 255].repeat(100)).unwrap();
    assert_refused(
        &["tile", lbl.to_str().unwrap(), "--body", "moon", "--out", o],
        &out,
        "garbage.LBL",
    );
    assert_refused(
        &["bake", "--out", o, "--tile-size", "7"],
        &out,
        "--tile-size 7",
    );
    assert_refused(&["bake", "--out", o, "--halo", "0"], &out, "--halo 0");
    assert_refused(
        &["bake", "--out", o, "--body", "vulcan", "--dem", "x.hgt"],
        &out,
        "vulcan",
    );
    let e = run(&["info", dir.path().to_str().unwrap()]);
    assert_eq!(e.status.code(), Some(2));
    assert!(stderr(&e).contains("tileset.json"), "{}", stderr(&e));
}

/// A `bake` whose mip stage fails on a full disk after tiling committed (the failure injected
/// by `PENUMBRA_TEST_DISK_FULL`, `fsio::write_staged`): exit 2, a message naming the failed
/// stage, the committed one and what became of the folder. A folder the bake created is
/// removed, or kept with `--keep-partial`; an existing tileset is kept, valid, with the stages
/// that committed. Issue 41.
#[test]
fn bake_failing_after_a_commit_says_what_it_kept() {
    let dir = tempfile::tempdir().unwrap();
    let bake = |out: &Path, extra: &[&str], full: Option<&str>| {
        let mut c = penumbra_bin();
        c.args([
            "--threads",
            "1",
            "bake",
            "--scene-size",
            "1024",
            "--tile-size",
            "64",
        ])
        .args(["--levels", "3", "--no-horizons", "--out"])
        .arg(out)
        .args(extra);
        if let Some(stage) = full {
            c.env("PENUMBRA_TEST_DISK_FULL", stage);
        }
        let o = c.output().unwrap();
        (o.status.code(), stderr(&o))
    };
    let full = "No space left on device";

    // A folder the bake made: removed.
    let out = dir.path().join("new");
    let (code, e) = bake(&out, &[], Some("mip"));
    assert_eq!(code, Some(2), "{e}");
    for w in [
        "the mip stage failed after tile committed",
        "removed",
        "created",
        full,
    ] {
        assert!(e.contains(w), "'{w}' not in {e}");
    }
    assert!(!e.contains("panicked"), "{e}");
    assert!(!out.exists(), "{e}");

    // The same with --keep-partial: the tiles stay, a valid tileset without mipmaps.
    let (code, e) = bake(&out, &["--keep-partial"], Some("mip"));
    assert_eq!(code, Some(2), "{e}");
    assert!(e.contains("kept") && e.contains(full), "{e}");
    let info = json(&run(&["info", out.to_str().unwrap(), "--json"]));
    assert!(info.to_string().contains("height"), "{info}");
    assert!(!out.join("maxmip").exists() && !out.join(".penumbra/staging/mip").exists());
    // A rerun with room resumes: tiling is up to date, the mipmaps are made.
    let (code, e) = bake(&out, &[], None);
    assert_eq!(code, Some(0), "{e}");
    assert!(out.join("maxmip").is_dir());

    // An existing tileset: kept as the committed stages left it, whatever --keep-partial says.
    let before = crate::util::snapshot(&out);
    let (code, e) = bake(&out, &["--precision", "f16"], Some("mip"));
    assert_eq!(code, Some(2), "{e}");
    assert!(
        e.contains("kept") && e.contains("the mip stage failed"),
        "{e}"
    );
    assert!(out.join("tileset.json").is_file());
    let after = crate::util::snapshot(&out);
    let heights = |s: &std::collections::BTreeMap<String, Vec<u8>>| {
        s.iter()
            .filter(|(k, _)| k.starts_with("height/"))
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect::<Vec<_>>()
    };
    assert_eq!(heights(&before), heights(&after));
}
