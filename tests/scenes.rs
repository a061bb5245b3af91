//! Scenes (docs/scenes.md): bad scene files exit 2 naming the line and the key and write
//! nothing; `plan` counts what `bake SCENE` writes; the embedded scene's plan.

use std::path::{Path, PathBuf};

use crate::util::{penumbra_bin, shared_data};

/// A small embedded-terrain scene (512² px at 20 m, 128-px tiles) with `extra` appended.
fn small_scene(extra: &str) -> String {
    format!(
        "[scene]\nname = \"small\"\nbody = \"moon\"\n\n[layout]\ntile_size = 128\n\n\
         [[source]]\nembedded = \"south-pole\"\nsize = 512\n{extra}"
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// `penumbra bake SCENE --out OUT` must exit 2 with a message holding every one of `want`, and
/// leave OUT absent.
fn refused(scene: &Path, want: &[&str]) {
    let out = scene.with_extension("out");
    let o = penumbra_bin()
        .args(["bake"])
        .arg(scene)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{}: {err}", scene.display());
    for w in want {
        assert!(
            err.contains(w),
            "{}: expected {w:?} in: {err}",
            scene.display()
        );
    }
    assert!(
        !out.exists(),
        "{}: bake wrote {}",
        scene.display(),
        out.display()
    );
    // `plan` refuses it the same way.
    let o = penumbra_bin().arg("plan").arg(scene).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "plan {}", scene.display());
}

const REGION: &str = "\n[[region]]\nname = \"all\"\nbody = true\n";
const RENDERER: &str = "\n[renderer]\nmethods = [\"dp\"]\n";

#[test]
fn bad_scene_files_exit_2_naming_line_and_key() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        (
            "unknown-key",
            small_scene(&format!("{REGION}levl = 3\n{RENDERER}")),
            vec!["line 15", "levl", "unknown field"],
        ),
        (
            "wrong-type",
            small_scene(&format!("{REGION}level = \"fine\"\n{RENDERER}")),
            vec!["line 15", "region[0].level"],
        ),
        (
            "missing-source",
            format!(
                "[scene]\nname = \"x\"\n[[source]]\npath = \"nowhere/dem.tif\"\n{REGION}{RENDERER}"
            ),
            vec!["line 4", "source[0].path", "nowhere/dem.tif"],
        ),
        (
            "sun-above-90",
            small_scene(&format!(
                "{REGION}{RENDERER}\n[sun]\nelevation_deg = [10.0, 95.0]\n"
            )),
            vec!["sun.elevation_deg", "95"],
        ),
        (
            "region-outside",
            small_scene(&format!(
                "\n[[region]]\nname = \"equator\"\ncap = {{ lat_deg = 0.0, lon_deg = 0.0, \
                 radius_m = 5000.0 }}\n{RENDERER}"
            )),
            vec!["line 12", "region[0]", "outside every source"],
        ),
        (
            "level-past-resolution",
            small_scene(&format!(
                "\n[[region]]\nname = \"all\"\nbody = true\nlevel = 16\n{RENDERER}"
            )),
            vec!["region[0].level", "finer than any source"],
        ),
        (
            "no-method",
            small_scene(REGION),
            vec!["renderer.methods", "names no shadow method"],
        ),
        (
            "two-shapes",
            small_scene(&format!(
                "{REGION}cap = {{ lat_deg = -90.0, lon_deg = 0.0, radius_m = 5.0 }}\n{RENDERER}"
            )),
            vec!["region[0]", "exactly one shape"],
        ),
        ("not-toml", "[scene\nname = ".into(), vec!["line 1"]),
    ];
    for (name, text, want) in &cases {
        let p = write(d, &format!("{name}.toml"), text);
        refused(&p, want);
    }
    // An empty camera path (the header alone).
    write(d, "empty.csv", "lat_deg,lon_deg,height_m\n");
    let p = write(
        d,
        "empty-path.toml",
        &small_scene(&format!(
            "\n[[region]]\nname = \"descent\"\npath = \"empty.csv\"\nlevel = 3\n{RENDERER}"
        )),
    );
    refused(&p, &["empty.csv", "descent"]);
    // A scene file that is not a file, or too big.
    refused(d, &["not a regular file"]);
    let big = write(d, "big.toml", &"#".repeat(2 << 20));
    refused(&big, &["bytes"]);
}

#[test]
fn sources_of_different_bodies_are_refused() {
    let Some(data) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let text = format!(
        "[scene]\nname = \"mixed\"\n\n[[source]]\npath = \"{}\"\n\n[[source]]\npath = \"{}\"\n\
         {REGION}level = 0\n{RENDERER}",
        data.join("lola_ldem4/LDEM_4.LBL").display(),
        data.join("mola_megt90n000cb/megt90n000cb.lbl").display()
    );
    let p = write(tmp.path(), "mixed.toml", &text);
    refused(&p, &["source[1]", "mars", "moon"]);
}

#[test]
fn embedded_scene_plan() {
    let o = penumbra_bin().args(["plan", "--json"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        v["stages"],
        serde_json::json!(["tile", "mip", "horizon → fourier"])
    );
    assert_eq!(v["horizon_levels"], serde_json::json!([6]));
    assert_eq!(v["layout"]["levels"], 10);
    let products: Vec<&str> = v["products"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["made"] == true)
        .map(|p| p["product"].as_str().unwrap())
        .collect();
    assert_eq!(products, ["height", "mip", "fourier"]);
}

/// Every tile file a bake wrote, per product folder and level.
fn written(out: &Path, product: &str) -> std::collections::BTreeMap<u8, u64> {
    let mut m = std::collections::BTreeMap::new();
    let root = out.join(product);
    if !root.is_dir() {
        return m;
    }
    for e in walk(&root) {
        let rel = e.strip_prefix(&root).unwrap();
        let level: u8 = rel
            .components()
            .next()
            .and_then(|c| c.as_os_str().to_str())
            .and_then(|s| {
                s.trim_start_matches(|c: char| !c.is_ascii_digit())
                    .parse()
                    .ok()
            })
            .unwrap_or(255);
        *m.entry(level).or_insert(0) += 1;
    }
    m
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

#[test]
fn plan_counts_what_bake_writes() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = write(
        tmp.path(),
        "s.toml",
        &small_scene(
            "\n[[region]]\nname = \"all\"\nbody = true\n\n[renderer]\nmethods = [\"dp\", \
             \"fourier\"]\n\n[horizon]\nlevels = [3]\nazimuths = 16\n",
        ),
    );
    let o = penumbra_bin()
        .args(["plan", "--json"])
        .arg(&scene)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plan: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let out = tmp.path().join("t");
    let o = penumbra_bin()
        .arg("bake")
        .arg(&scene)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for p in plan["products"].as_array().unwrap() {
        let name = p["product"].as_str().unwrap();
        let planned: std::collections::BTreeMap<u8, u64> =
            serde_json::from_value(p["tiles"].clone()).unwrap();
        let folder = match name {
            "mip" => "maxmip",
            other => other,
        };
        assert_eq!(
            written(&out, folder),
            if p["made"] == true {
                planned
            } else {
                Default::default()
            },
            "{name}: planned per level vs files written"
        );
    }
}

/// The equatorial scene of docs/scenes/ (LDEM_4, a 60° box, suns at 30–60°) baked with the sun
/// rule and without it: every pixel of every horizon tile (the pruned ones and the others)
/// lit the same by every method the scene lists, at suns within the scene's range.
#[test]
fn pruned_scene_renders_the_full_scenes_lit_fractions() {
    use penumbra::fourier::sun::Model;
    use penumbra::shadow::trace::Method as T;
    use penumbra::shadow::{HorizonSource, Runs, ShadowMethod};
    let Some(data) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let text = std::fs::read_to_string(repo.join("docs/scenes/equatorial.toml"))
        .unwrap()
        .replace(
            "../../../shared/data",
            data.to_str().expect("a UTF-8 path to the shared data"),
        );
    // 32 azimuths rather than the scene's 360: what is left out depends on the tiles' bounds,
    // not on the azimuths, and both bakes cost a ninth.
    let pruned_scene = write(
        tmp.path(),
        "pruned.toml",
        &format!("{text}\n[horizon]\nazimuths = 32\n"),
    );
    let full_scene = write(
        tmp.path(),
        "full.toml",
        &format!("{text}\n[horizon]\nazimuths = 32\nprune = false\n"),
    );
    let bake = |scene: &Path, out: &Path| {
        let o = penumbra_bin()
            .arg("bake")
            .arg(scene)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let (pruned, full) = (tmp.path().join("pruned"), tmp.path().join("full"));
    bake(&pruned_scene, &pruned);
    bake(&full_scene, &full);
    let ts = penumbra::manifest::Tileset::load(&pruned).unwrap();
    // The pyramids were streamed: the left-out tiles are the fully lit ones.
    let left_out = ts.products.fourier.as_ref().unwrap().tiles_fully_lit;
    assert!(
        left_out > 0,
        "the 30° sun leaves some of LDEM_4's horizons out"
    );
    let methods = [
        ShadowMethod::Trace(T::Dp {
            runs: Runs::Auto,
            dda: false,
        }),
        ShadowMethod::Trace(T::Extrema),
        ShadowMethod::Horizon(HorizonSource::Fourier, Model::Exact),
    ];
    let horizon_levels: Vec<u8> = ts.tile_set().iter().map(|t| t.level).collect();
    let mut compared = 0usize;
    for t in ts.tile_set() {
        if !horizon_levels.contains(&t.level) || t.level < 2 {
            continue;
        }
        // A sun east of the tile whose elevation over the tile's outline (where it is
        // extreme: the subsolar point is off the tile) stays within 30.5–59.5°.
        let lay = ts.layout;
        let n = lay.tile_size as i64;
        let (lat, lon) = penumbra::cube::dir_to_latlon(lay.pixel_dir(t, n / 2, n / 2));
        let (lat, lon) = (lat.to_degrees(), lon.to_degrees());
        let phi = lat.to_radians();
        let outline: Vec<_> = (0..n)
            .flat_map(|k| [(k, 0), (k, n - 1), (0, k), (n - 1, k)])
            .map(|(i, j)| lay.pixel_dir(t, i, j))
            .collect();
        let sun_lon = (300..=520)
            .map(|d| {
                let c =
                    ((d as f64 / 10.0).to_radians().cos() - phi.sin().powi(2)) / phi.cos().powi(2);
                lon + c.clamp(-1.0, 1.0).acos().to_degrees()
            })
            .find(|&sl| {
                let s = penumbra::cube::latlon_to_dir(lat.to_radians(), sl.to_radians());
                outline.iter().all(|d| {
                    let el = 90.0 - penumbra::cube::angle_between(*d, s).to_degrees();
                    (30.5..=59.5).contains(&el)
                })
            })
            .unwrap_or_else(|| panic!("tile {t}: no sun keeps it within 30–60°"));
        for m in &methods {
            let a = penumbra::shadow::tile_shadows(&pruned, t, lat, sun_lon, None, m).unwrap();
            assert!(
                a.sun_elevation_deg[0] >= 30.0 && a.sun_elevation_deg[1] <= 60.0,
                "tile {t}: the sun's elevations {:?} leave the scene's 30–60°",
                a.sun_elevation_deg
            );
            let b = penumbra::shadow::tile_shadows(&full, t, lat, sun_lon, None, m).unwrap();
            let same = a
                .lit
                .iter()
                .zip(&b.lit)
                .all(|(x, y)| x.to_bits() == y.to_bits() || (x - y).abs() <= 1e-6);
            assert!(same, "tile {t}, {}: pruned and full sets differ", m.label());
            compared += a.lit.len();
        }
    }
    assert!(compared > 0);
    eprintln!(
        "{left_out} of the scene's horizon tiles left out; {compared} lit fractions compared"
    );
}

/// Ten `kill -9` at random moments of a scene's bake (a wanted set from a cap region finer than
/// the body's, the mosaic path, mipmaps, horizons streamed into pyramids with the sun rule),
/// each rerun to completion: the bytes of an uninterrupted bake.
#[test]
fn killed_scene_bake_resumes_to_the_uninterrupted_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = write(
        tmp.path(),
        "k.toml",
        "[scene]\nname = \"killed\"\nbody = \"moon\"\n\n[layout]\ntile_size = 32\n\n\
         [[source]]\nembedded = \"south-pole\"\nsize = 1024\n\n\
         [[region]]\nname = \"all\"\nbody = true\nlevel = 8\n\n\
         [[region]]\nname = \"crater\"\ncap = { lat_deg = -89.8, lon_deg = 0.0, radius_m = 4000.0 }\n\n\
         [renderer]\nmethods = [\"dp\", \"fourier\"]\n\n[sun]\nelevation_deg = [8.0, 20.0]\n\n\
         [horizon]\nlevels = [8]\nazimuths = 16\n",
    );
    crate::store::kill_trials(
        "bake SCENE",
        None,
        &|out| {
            let mut c = penumbra_bin();
            c.arg("bake").arg(&scene).arg("--out").arg(out);
            c
        },
        0x5ce4_e5ca_1e00_0035,
    );
}

/// Every file below `dir`'s product folders (not `.penumbra/`), by path relative to `dir`, with
/// its inode (a file rewritten is a new inode: writes are temp file + rename) and its bytes.
fn files_of(dir: &Path) -> std::collections::BTreeMap<String, (u64, Vec<u8>)> {
    use std::os::unix::fs::MetadataExt;
    let mut m = std::collections::BTreeMap::new();
    for p in walk(dir) {
        let rel = p
            .strip_prefix(dir)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        if rel.starts_with(".penumbra/") {
            continue;
        }
        let ino = std::fs::metadata(&p).unwrap().ino();
        m.insert(rel, (ino, std::fs::read(&p).unwrap()));
    }
    m
}

/// The tiles (`level/face/y/x`) of the per-tile files of `folder` among `rels`.
fn tiles_in<'a>(
    rels: impl Iterator<Item = &'a String>,
    folder: &str,
) -> std::collections::BTreeSet<String> {
    rels.filter_map(|r| {
        let rest = r.strip_prefix(folder)?.strip_prefix('/')?;
        let parts: Vec<&str> = rest.split('/').collect();
        let [l, f, y, x] = parts[..] else { return None };
        let x = x.split_once('.')?.0;
        x.parse::<u32>().ok()?;
        Some(format!("{l}/{f}/{y}/{x}"))
    })
    .collect()
}

fn bake_scene(scene: &Path, out: &Path, extra: &[&str]) -> f64 {
    let t0 = std::time::Instant::now();
    let o = penumbra_bin()
        .arg("bake")
        .arg(scene)
        .arg("--out")
        .arg(out)
        .args(extra)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    t0.elapsed().as_secs_f64()
}

/// Adding a region to a baked scene cuts only the region's new tiles and redoes only the
/// mipmaps and horizons whose inputs they change, counted file by file (a kept file keeps its
/// inode), and the result is byte for byte the bake of the new scene from nothing (the sun
/// rule on: the horizon bounds' reads are dependencies too). A bake of a scene that lists
/// fewer tiles keeps the others; `--prune` removes them.
#[test]
fn adding_a_region_redoes_only_what_it_changes() {
    let tmp = tempfile::tempdir().unwrap();
    let base = "[scene]\nname = \"grow\"\nbody = \"moon\"\n\n[layout]\ntile_size = 32\n\n\
         [[source]]\nembedded = \"south-pole\"\nsize = 1024\n\n\
         [[region]]\nname = \"all\"\nbody = true\nlevel = 9\n\n\
         [[region]]\nname = \"crater\"\ncap = { lat_deg = -89.85, lon_deg = -45.0, radius_m = 2000.0 }\nlevel = 10\n\n\
         [renderer]\nmethods = [\"dp\", \"fourier\"]\n\n[sun]\nelevation_deg = [8.0, 20.0]\n\n\
         [horizon]\nlevels = [9, 10]\nazimuths = 16\n";
    let rim = "\n[[region]]\nname = \"rim\"\ncap = { lat_deg = -89.65, lon_deg = 135.0, radius_m = 2000.0 }\nlevel = 10\n";
    let a = write(tmp.path(), "a.toml", base);
    let b = write(tmp.path(), "b.toml", &format!("{base}{rim}"));
    let (inc, clean) = (tmp.path().join("inc"), tmp.path().join("clean"));

    bake_scene(&a, &inc, &[]);
    let before = files_of(&inc);
    bake_scene(&b, &inc, &[]);
    let after = files_of(&inc);
    bake_scene(&b, &clean, &[]);
    let fresh = files_of(&clean);

    // The incremental result is the clean bake's, file for file and byte for byte.
    assert_eq!(
        after.keys().collect::<Vec<_>>(),
        fresh.keys().collect::<Vec<_>>(),
        "incremental and clean bakes hold different files"
    );
    for (rel, (_, bytes)) in &after {
        assert!(
            fresh[rel].1 == *bytes,
            "{rel} differs from the clean bake's"
        );
    }

    // What was rewritten (a new inode) or added.
    let rewritten: Vec<&String> = after
        .iter()
        .filter(|(rel, (ino, _))| before.get(*rel).is_none_or(|(i, _)| i != ino))
        .map(|(rel, _)| rel)
        .collect();
    let new_tiles: std::collections::BTreeSet<String> = tiles_in(after.keys(), "height")
        .difference(&tiles_in(before.keys(), "height"))
        .cloned()
        .collect();
    assert!(!new_tiles.is_empty(), "the rim region added no tile");
    assert!(
        new_tiles.iter().all(|t| t.starts_with("10/")),
        "the rim's parents are the overview's: {new_tiles:?}"
    );
    for folder in ["height", "maxmip", "minmax"] {
        assert_eq!(
            tiles_in(rewritten.iter().copied(), folder),
            new_tiles,
            "{folder}: tiles rewritten are not exactly the new ones"
        );
    }
    // Horizons (streamed into Fourier pyramids): every new tile's; at level 10 also those of
    // the crater's tiles whose context the rim's tiles enter (here all of them: the fine
    // context reaches 1024 pixels, farther than the scene is wide); at level 9, which gained
    // no tile, none.
    let fourier_all = tiles_in(after.keys(), "fourier");
    let fourier_new = tiles_in(rewritten.iter().copied(), "fourier");
    assert!(
        new_tiles.is_subset(&fourier_new),
        "a new tile has no new pyramid"
    );
    let level9: Vec<&String> = fourier_all.iter().filter(|t| t.starts_with("9/")).collect();
    assert!(!level9.is_empty());
    assert!(
        fourier_new.iter().all(|t| t.starts_with("10/")),
        "level 9 gained no tile, yet pyramids of it were redone: {fourier_new:?}"
    );
    let kept = fourier_all.len() - fourier_new.len();
    eprintln!(
        "adding a region: {} new tiles; rewritten {} height, {} maxmip, {} fourier of {} \
         (kept {kept}); {} files rewritten of {}",
        new_tiles.len(),
        tiles_in(rewritten.iter().copied(), "height").len(),
        tiles_in(rewritten.iter().copied(), "maxmip").len(),
        fourier_new.len(),
        fourier_all.len(),
        rewritten.len(),
        after.len()
    );

    // A bake with nothing changed rewrites nothing.
    bake_scene(&b, &inc, &[]);
    let again = files_of(&inc);
    assert!(
        again.iter().all(|(rel, (ino, _))| after[rel].0 == *ino) && again.len() == after.len(),
        "a bake with nothing changed rewrote files"
    );

    // Baking the smaller scene again keeps the rim's tiles (another scene's); --prune makes
    // the tileset exactly the smaller scene's bake.
    bake_scene(&a, &inc, &[]);
    assert_eq!(
        files_of(&inc).len(),
        after.len(),
        "the rim's tiles were removed"
    );
    bake_scene(&a, &inc, &["--prune"]);
    let pruned = files_of(&inc);
    let only_a = tmp.path().join("only-a");
    bake_scene(&a, &only_a, &[]);
    let only_a = files_of(&only_a);
    assert_eq!(
        pruned.keys().collect::<Vec<_>>(),
        only_a.keys().collect::<Vec<_>>(),
        "--prune left other files than a bake of the scene alone"
    );
    for (rel, (_, bytes)) in &pruned {
        assert!(only_a[rel].1 == *bytes, "{rel} differs after --prune");
    }

    // A scene whose methods read the heights only keeps the other scene's products, unless
    // pruned: then the folder is its own clean bake.
    let heights = write(
        tmp.path(),
        "h.toml",
        &base.replace("methods = [\"dp\", \"fourier\"]", "methods = [\"uniform\"]"),
    );
    bake_scene(&heights, &inc, &[]);
    assert_eq!(
        files_of(&inc).len(),
        pruned.len(),
        "another scene's products went"
    );
    bake_scene(&heights, &inc, &["--prune"]);
    let only_h = tmp.path().join("only-h");
    bake_scene(&heights, &only_h, &[]);
    let (got, want) = (files_of(&inc), files_of(&only_h));
    assert_eq!(
        got.keys().collect::<Vec<_>>(),
        want.keys().collect::<Vec<_>>(),
        "--prune kept products the scene does not make"
    );
    for (rel, (_, bytes)) in &got {
        assert!(
            want[rel].1 == *bytes,
            "{rel} differs after pruning products"
        );
    }
}
