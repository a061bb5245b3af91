//! `tileset.json` consistency (issue 41, item 2): edits that pass the range checks but change
//! what readers compute — path placeholders exchanged, the projection changed, run keys of any
//! string, minima above maxima, numbers the docs call validated — are each refused naming the
//! field. One case per row of a table, on the manifest of a small baked tileset with every
//! product, through `Tileset::load` (what every command opens a tileset with) and, for a
//! sample, through the CLI. The mip, horizon and Fourier run keys are recomputed from their
//! `run_key_basis`: each product's key, its basis and each label the basis records (precision,
//! method, azimuths, levels, encoding, …) edited to every other value is refused by name, on
//! streamed and on raw Fourier pyramids.

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
        // A stage product's key: another hash, or its basis edited.
        (
            "products.mip.run_key",
            json!(OTHER_KEY),
            "products.mip.run_key",
        ),
        (
            "products.horizon.run_key",
            json!(OTHER_KEY),
            "products.horizon.run_key",
        ),
        (
            "products.fourier.run_key",
            json!(OTHER_KEY),
            "products.fourier.run_key",
        ),
        (
            "products.mip.run_key_basis.tool",
            json!("9.9.9"),
            "products.mip.run_key",
        ),
        (
            "products.mip.run_key_basis.params.1",
            json!("{\"precision\":\"f16\",\"compression\":\"zip\"}"),
            "products.mip.run_key",
        ),
        (
            "products.horizon.run_key_basis.params.3",
            json!("fine margin 7"),
            "products.horizon.run_key",
        ),
        (
            "products.horizon.run_key_basis.format.1",
            json!("3"),
            "products.horizon.run_key",
        ),
        (
            "products.fourier.run_key_basis.params.2",
            json!("0 1"),
            "products.fourier.run_key",
        ),
        // The layout's other fields (the levels: the coverage says how many there are).
        ("layout.levels", json!(3), "coverage"),
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

/// A valid run key that is not the one the fields hash.
const OTHER_KEY: &str = "0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef";

/// Every other value of each label a stage product's run key basis records (as in a manifest
/// whose Fourier pyramids were streamed, `raw` false, or made from raw maps), each with the
/// field the refusal must name.
fn label_rows(good: &Value, raw: bool) -> Vec<(String, Value, String)> {
    let get = |p: &str| {
        p.split('.').fold(good, |v, k| match k.parse::<usize>() {
            Ok(i) => &v[i],
            Err(_) => &v[k],
        })
    };
    let mut t: Vec<(String, Value, String)> = Vec::new();
    let mut every = |field: &str, values: &[Value], named: &str| {
        for v in values {
            if v != get(field) {
                t.push((field.to_string(), v.clone(), named.to_string()));
            }
        }
    };
    let methods = [
        json!("fast"),
        json!("sweep"),
        json!("exact"),
        json!("reference"),
    ];
    let f16_f32 = [json!("f16"), json!("f32")];
    every("products.mip.precision", &f16_f32, "products.mip.precision");
    every(
        "products.horizon.precision",
        &f16_f32,
        "products.horizon.precision",
    );
    every(
        "products.horizon.method",
        &methods,
        "products.horizon.method",
    );
    every(
        "products.horizon.near_px",
        &[json!(8.0), json!(null)],
        "products.horizon.near_px",
    );
    every(
        "products.horizon.azimuths",
        &[json!(72), json!(8)],
        "products.horizon.azimuths",
    );
    every(
        "products.horizon.levels",
        &[json!([2]), json!([0, 1, 2, 3])],
        "products.horizon.levels",
    );
    let tmax = get("products.horizon.terrain_max_m").as_f64().unwrap();
    every(
        "products.horizon.terrain_max_m",
        &[json!(tmax + 1.0)],
        "products.horizon.terrain_max_m",
    );
    for (field, values) in [
        ("encoding", vec![json!("f16"), json!("snorm16")]),
        ("sigma", vec![json!("none"), json!("lanczos")]),
        ("reduce", vec![json!("mean"), json!("fit")]),
        ("max_error_deg", vec![json!(0.5)]),
        ("min_sun_el_deg", vec![json!(3.0)]),
        ("levels", vec![json!([2])]),
        ("horizon_method", methods.to_vec()),
        ("horizon_near_px", vec![json!(8.0)]),
    ] {
        let f = format!("products.fourier.{field}");
        every(&f, &values, &f);
    }
    // The layout and K are also what `groups` and `bytes_per_tile` describe: the range checks
    // name those first.
    every(
        "products.fourier.layout",
        &[json!("multires"), json!("full")],
        "products.fourier.groups",
    );
    every(
        "products.fourier.coefficients",
        &[json!(3), json!(5)],
        "products.fourier.groups",
    );
    if raw {
        // What a Fourier entry made from raw maps copied from theirs.
        let tmin = get("products.fourier.terrain_min_m").as_f64().unwrap();
        every(
            "products.fourier.terrain_min_m",
            &[json!(tmin - 1.0)],
            "products.fourier.terrain_min_m",
        );
        every(
            "products.fourier.azimuths",
            &[json!(72)],
            "products.fourier.azimuths",
        );
    } else {
        every(
            "products.fourier.azimuths",
            &[json!(72)],
            "products.fourier.azimuths",
        );
    }
    t
}

/// The manifest with every stage product's `run_key_basis` removed (as a penumbra that did not
/// record it wrote it).
fn without_basis(v: &Value) -> Value {
    let mut v = v.clone();
    for p in ["mip", "horizon", "fourier"] {
        if let Some(o) = v["products"][p].as_object_mut() {
            o.remove("run_key_basis");
        }
    }
    v
}

/// Write `v` as `dir`'s manifest and load it: None when accepted, else the error.
fn load_with(dir: &Path, v: &Value) -> Option<String> {
    std::fs::write(
        dir.join("tileset.json"),
        serde_json::to_vec_pretty(v).unwrap(),
    )
    .unwrap();
    Tileset::load(dir).err().map(|e| e.to_string())
}

#[test]
fn every_stage_label_and_run_key_is_checked_against_its_basis() {
    let tmp = tempfile::tempdir().unwrap();
    let good_dir = tmp.path().join("good");
    let good = baked(&good_dir);
    // The same tileset with its pyramids remade from the raw maps.
    let raw_dir = tmp.path().join("raw");
    crate::util::copy_tree(&good_dir, &raw_dir);
    let o = penumbra_bin()
        .args(["fourier", raw_dir.to_str().unwrap(), "--coefficients", "9"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let raw: Value =
        serde_json::from_slice(&std::fs::read(raw_dir.join("tileset.json")).unwrap()).unwrap();
    assert_eq!(raw["products"]["fourier"]["source"], "raw");
    assert_eq!(good["products"]["fourier"]["source"], "streamed");

    let dir = tmp.path().join("case");
    std::fs::create_dir_all(&dir).unwrap();
    let mut failures = Vec::new();
    let mut rows = 0;
    for (name, manifest, is_raw) in [("streamed", &good, false), ("raw", &raw, true)] {
        for p in ["mip", "horizon", "fourier"] {
            assert!(
                manifest["products"][p]["run_key_basis"].is_object(),
                "{name}: products.{p} records no run_key_basis"
            );
        }
        // As written, and as written before the basis was recorded: accepted.
        for v in [manifest.clone(), without_basis(manifest)] {
            if let Some(e) = load_with(&dir, &v) {
                failures.push(format!("{name}: the manifest as written is refused: {e}"));
            }
        }
        for (field, value, named) in label_rows(manifest, is_raw) {
            rows += 1;
            // Set, or added where the baked manifest leaves it out (`max_error_deg`, …).
            let mut v = manifest.clone();
            let (parent, last) = field.rsplit_once('.').unwrap();
            parent.split('.').fold(&mut v, |v, k| &mut v[k])[last] = value.clone();
            match load_with(&dir, &v) {
                None => failures.push(format!("{name}: {field} = {value}: accepted")),
                Some(e) if !e.contains(&format!("field `{named}`")) => failures.push(format!(
                    "{name}: {field} = {value}: does not name `{named}`: {e}"
                )),
                Some(_) => {}
            }
        }
    }
    // Without a basis, the mip key is recomputed from its fields (the compression either
    // way): its precision flipped is still named.
    let v = with(
        &without_basis(&good),
        "products.mip.precision",
        json!("f16"),
    );
    match load_with(&dir, &v) {
        Some(e) if e.contains("field `products.mip.precision`") => {}
        other => failures.push(format!("no basis: mip precision flipped: {other:?}")),
    }
    let v = with(
        &without_basis(&good),
        "products.mip.run_key",
        json!(OTHER_KEY),
    );
    match load_with(&dir, &v) {
        Some(e) if e.contains("field `products.mip.run_key`") => {}
        other => failures.push(format!("no basis: mip run key: {other:?}")),
    }
    assert!(rows > 40, "only {rows} rows");
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
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
        ("layout.tile_size", json!(64), "layout.tile_size"),
        ("layout.halo", json!(3), "layout.halo"),
        ("layout.levels", json!(3), "coverage"),
        (
            "products.mip.global_max_m",
            json!(1e308),
            "products.mip.global_max_m",
        ),
        (
            "products.horizon.precision",
            json!("f32"),
            "products.horizon.precision",
        ),
        (
            "products.fourier.encoding",
            json!("snorm16"),
            "products.fourier.encoding",
        ),
        (
            "products.mip.run_key",
            json!(OTHER_KEY),
            "products.mip.run_key",
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
        // Every command that reads the tileset (each product's query, a stage, verify).
        let q = |what: &'static str, extra: &[&'static str]| {
            let mut v = vec!["query", what, d, "--lat", "-89.9", "--lon", "0"];
            v.extend_from_slice(extra);
            v
        };
        for cmd in [
            q("height", &[]),
            q("mip", &["--level", "1"]),
            q("horizon", &["--level", "3", "--from", "raw"]),
            q("horizon", &["--level", "3", "--from", "fourier"]),
            vec!["mip", d],
            vec!["verify", d],
            vec!["info", d],
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

/// A scene bake's tiles tried without data (`no_data`, absent from a whole bake's manifest):
/// off the layout's levels, miscounted, or tiles the coverage holds are refused by name.
#[test]
fn no_data_tiles_are_validated() {
    let tmp = tempfile::tempdir().unwrap();
    let good_dir = tmp.path().join("good");
    let good = baked(&good_dir);
    let dir = tmp.path().join("case");
    std::fs::create_dir_all(&dir).unwrap();
    let per = good["coverage"][1]["tiles_per_face"].clone();
    let cases = [
        (
            json!([{"level": 99, "tiles": 1, "tiles_per_face": 1, "faces": {"px": [[0, 0, 0]]}}]),
            "no_data[0].level",
        ),
        (
            json!([{"level": 1, "tiles": 2, "tiles_per_face": per, "faces": {"px": [[0, 0, 0]]}}]),
            "no_data[0].tiles",
        ),
        (json!([good["coverage"][1].clone()]), "no_data"),
    ];
    for (value, named) in cases {
        let mut v = good.clone();
        v["no_data"] = value.clone();
        std::fs::write(
            dir.join("tileset.json"),
            serde_json::to_vec_pretty(&v).unwrap(),
        )
        .unwrap();
        let e = Tileset::load(&dir).expect_err(&format!("no_data = {value}: accepted"));
        assert!(
            e.to_string().contains(&format!("field `{named}`")),
            "no_data = {value}: does not name `{named}`: {e}"
        );
    }
}
