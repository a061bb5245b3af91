//! `tileset.json` consistency (issue 41, item 2): edits that pass the range checks but change
//! what readers compute — path placeholders exchanged, the projection changed, run keys of any
//! string, minima above maxima, numbers the docs call validated — are each refused naming the
//! field. One case per row of a table, on the manifest of a small baked tileset with every
//! product, through `Tileset::load` (what every command opens a tileset with) and, for a
//! sample, through the CLI.

use std::path::Path;

use serde_json::{json, Value};

use penumbra::manifest::Tileset;

use crate::util::penumbra_bin;

/// The embedded scene with tiles, mipmaps, raw horizon maps and Fourier pyramids.
fn baked(out: &Path) -> Value {
    let o = penumbra_bin()
        .args([
            "--threads",
            "2",
            "bake",
            "--scene-size",
            "1024",
            "--levels",
            "4",
        ])
        .args([
            "--tile-size",
            "32",
            "--horizon-levels",
            "3",
            "--keep-raw",
            "--out",
        ])
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap()
}

/// `v` with the value at the dotted `path` (numbers index arrays) replaced.
fn with(v: &Value, path: &str, new: Value) -> Value {
    let mut v = v.clone();
    let mut cur = &mut v;
    for p in path.split('.') {
        cur = match p.parse::<usize>() {
            Ok(i) => &mut cur[i],
            Err(_) => &mut cur[p],
        };
    }
    assert!(
        !cur.is_null(),
        "{path} is absent or null in the baked manifest"
    );
    *cur = new;
    v
}

/// Rows: the field edited, its new value, the field the refusal must name.
fn table(good: &Value) -> Vec<(&'static str, Value, &'static str)> {
    let g = |p: &str| {
        p.split('.')
            .fold(good, |v, k| match k.parse::<usize>() {
                Ok(i) => &v[i],
                Err(_) => &v[k],
            })
            .as_f64()
            .unwrap()
    };
    let mut t = vec![
        // Path patterns with placeholders exchanged or moved.
        (
            "products.height.path",
            json!("height/{level}/{face}/{x}/{y}.exr"),
            "products.height.path",
        ),
        (
            "products.mip.max_path",
            json!("maxmip/{level}/{face}/{x}/{y}.exr"),
            "products.mip.max_path",
        ),
        (
            "products.mip.minmax_path",
            json!("minmax/{face}/{level}/{y}/{x}.exr"),
            "products.mip.minmax_path",
        ),
        (
            "products.mip.face_path",
            json!("minmax/{face}/{level}/face.exr"),
            "products.mip.face_path",
        ),
        (
            "products.horizon.path",
            json!("horizon/{level}/{face}/{x}/{y}.exr"),
            "products.horizon.path",
        ),
        (
            "products.fourier.path",
            json!("fourier/{level}/{face}/{x}/{y}.fhm"),
            "products.fourier.path",
        ),
        // The layout against the parameters the tiles were made with.
        (
            "layout.projection",
            json!("equal-angle"),
            "layout.projection",
        ),
        ("layout.tile_size", json!(64), "layout.tile_size"),
        ("layout.halo", json!(3), "layout.halo"),
        ("resampling", json!("bicubic"), "resampling"),
        ("body.radius_m", json!(1737000.0), "body"),
        ("body.name", json!("mars"), "body"),
        ("body.relief_m", json!([5000.0, -5000.0]), "body.relief_m"),
        // Run keys: any string, another hash, or what they hash edited.
        ("run_key", json!("anything"), "run_key"),
        ("run_key", json!("0".repeat(64)), "run_key"),
        ("run_key", json!("A".repeat(64)), "run_key"),
        ("parameters.options.resampling", json!("bicubic"), "run_key"),
        (
            "parameters.options.projection",
            json!("equal-angle"),
            "run_key",
        ),
        ("source.files.0.blake3", json!("1".repeat(64)), "run_key"),
        ("products.mip.run_key", json!("x"), "products.mip.run_key"),
        (
            "products.horizon.run_key",
            json!(""),
            "products.horizon.run_key",
        ),
        (
            "products.fourier.run_key",
            json!("g".repeat(64)),
            "products.fourier.run_key",
        ),
        // Heights: ordered and within the body.
        (
            "products.height.min_m",
            json!(g("products.height.max_m") + 1.0),
            "products.height.min_m",
        ),
        (
            "products.mip.global_min_m",
            json!(g("products.mip.global_max_m") + 1.0),
            "products.mip.global_min_m",
        ),
        (
            "products.mip.levels.1.min_m",
            json!(1e300),
            "products.mip.levels[1].min_m",
        ),
        (
            "products.mip.levels.2.max_m",
            json!(-1e300),
            "products.mip.levels[2].max_m",
        ),
        (
            "products.mip.levels.3.min_m",
            json!(g("products.mip.levels.3.max_m") + 1.0),
            "products.mip.levels[3].min_m",
        ),
        (
            "products.horizon.terrain_min_m",
            json!(g("products.horizon.terrain_max_m") + 1.0),
            "products.horizon.terrain_min_m",
        ),
        (
            "products.fourier.terrain_min_m",
            json!(g("products.fourier.terrain_max_m") + 1.0),
            "products.fourier.terrain_min_m",
        ),
        // Horizon distances.
        (
            "products.horizon.distances.0.level",
            json!(9),
            "products.horizon.distances[0].level",
        ),
        (
            "products.horizon.distances.0.max_margin_px",
            json!(1u64 << 40),
            "products.horizon.distances[0].max_margin_px",
        ),
        (
            "products.fourier.distances.0.level",
            json!(9),
            "products.fourier.distances[0].level",
        ),
    ];
    // Numbers the docs call validated, each with every value of the audit.
    for v in [1e308, -1e308] {
        t.push((
            "products.mip.global_max_m",
            json!(v),
            "products.mip.global_max_m",
        ));
        t.push((
            "products.mip.global_min_m",
            json!(v),
            "products.mip.global_min_m",
        ));
        t.push(("products.height.max_m", json!(v), "products.height.max_m"));
    }
    for v in [0.0, -1.0, 1e300, 1e-9] {
        t.push(("source.pixel_size_m", json!(v), "source.pixel_size_m"));
    }
    for v in [1e308, -1.0, 1e5] {
        t.push((
            "products.horizon.distances.0.needed_km",
            json!(v),
            "products.horizon.distances[0].needed_km",
        ));
        t.push((
            "products.fourier.distances.0.needed_km",
            json!(v),
            "products.fourier.distances[0].needed_km",
        ));
    }
    for v in [1e300, -1e300] {
        t.push(("source.height_shift_m", json!(v), "source.height_shift_m"));
    }
    for v in [-1737400.0, 0.0, 1e300] {
        t.push(("source.datum_radius_m", json!(v), "source.datum_radius_m"));
    }
    t
}

#[test]
fn every_validated_field_is_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let good_dir = tmp.path().join("good");
    let good = baked(&good_dir);
    // The manifest as written passes (its run key recomputes).
    Tileset::load(&good_dir).unwrap();

    let dir = tmp.path().join("case");
    std::fs::create_dir_all(&dir).unwrap();
    let rows = table(&good);
    let mut failures = Vec::new();
    for (field, value, named) in &rows {
        let v = with(&good, field, value.clone());
        std::fs::write(
            dir.join("tileset.json"),
            serde_json::to_vec_pretty(&v).unwrap(),
        )
        .unwrap();
        match Tileset::load(&dir) {
            Ok(_) => failures.push(format!("{field} = {value}: accepted")),
            Err(e) => {
                let e = e.to_string();
                if !e.contains(&format!("field `{named}`")) || !e.contains("tileset.json") {
                    failures.push(format!("{field} = {value}: does not name `{named}`: {e}"));
                }
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} rows:\n{}",
        failures.len(),
        rows.len(),
        failures.join("\n")
    );

    // Through the commands: exit 2 naming the field, the tileset untouched.
    for (k, (field, value, named)) in [
        (
            "products.height.path",
            json!("height/{level}/{face}/{x}/{y}.exr"),
            "products.height.path",
        ),
        (
            "layout.projection",
            json!("equal-angle"),
            "layout.projection",
        ),
        (
            "products.mip.global_max_m",
            json!(1e308),
            "products.mip.global_max_m",
        ),
    ]
    .into_iter()
    .enumerate()
    {
        let case = tmp.path().join(format!("cli{k}"));
        crate::util::copy_tree(&good_dir, &case);
        let v = with(&good, field, value);
        std::fs::write(
            case.join("tileset.json"),
            serde_json::to_vec_pretty(&v).unwrap(),
        )
        .unwrap();
        let before = crate::util::snapshot(&case);
        let d = case.to_str().unwrap();
        for cmd in [
            vec!["query", "height", d, "--lat", "-89.9", "--lon", "0"],
            vec!["mip", d],
        ] {
            let o = penumbra_bin().args(&cmd).output().unwrap();
            let e = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{field}: {cmd:?}: {e}");
            assert!(
                e.contains(&format!("field `{named}`")),
                "{field}: {cmd:?}: {e}"
            );
        }
        assert_eq!(
            crate::util::snapshot(&case),
            before,
            "{field}: the tileset changed"
        );
    }
}
