//! `penumbra package` (docs/packaging.md): the addon Celestia reads (every file its catalogs
//! and virtual textures name), the tileset inside it byte for byte as the source's, the README,
//! the archive (exactly the folder's files, the same bytes on every run and thread count); a
//! scene's bake packaged only when it is up to date; bad input exits 2 and writes nothing.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use penumbra::package::bundle::{tileset_in, CUBEMAP_DIR, README};
use penumbra::package::celestia::{check_addon, MARKER, TEXTURES_DIR, TEXTURE_KEYS};
use penumbra::package::ssc;

use crate::util::{copy_tree, indexes, penumbra_bin, snapshot};

/// Run `penumbra` with `args`.
fn run(args: &[&str]) -> std::process::Output {
    penumbra_bin().args(args).output().unwrap()
}

fn ok_json(args: &[&str]) -> serde_json::Value {
    let o = run(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The embedded terrain at 4 levels of 32² tiles (12 tiles), an 8-bit RGB albedo, mipmaps, raw
/// horizon maps and Fourier pyramids at level 3: every product a tileset can hold, in a few
/// seconds.
fn tileset(dir: &Path) {
    let png = dir.with_extension("albedo.png");
    image::RgbImage::from_fn(64, 32, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 8) as u8, 128])
    })
    .save(&png)
    .unwrap();
    ok_json(&[
        "bake",
        "--albedo",
        s(&png),
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--tile-size",
        "32",
        "--horizon-levels",
        "3",
        "--keep-raw",
        "--out",
        s(dir),
        "--json",
    ]);
}

/// Every file below `dir` (the bookkeeping folder included), by `/`-separated relative path.
fn all_files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p
                    .strip_prefix(dir)
                    .unwrap()
                    .to_string_lossy()
                    .replace('\\', "/");
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// The archive's entries in their order, with their bytes; every entry stored.
fn zip_entries(path: &Path) -> Vec<(String, Vec<u8>)> {
    let mut z = zip::ZipArchive::new(std::fs::File::open(path).unwrap()).unwrap();
    (0..z.len())
        .map(|i| {
            let mut f = z.by_index(i).unwrap();
            let name = f.name().unwrap().to_string();
            assert_eq!(f.compression(), zip::CompressionMethod::Stored, "{name}");
            let mut b = Vec::new();
            f.read_to_end(&mut b).unwrap();
            (name, b)
        })
        .collect()
}

/// What is next to `dir` in its folder besides `keep`: temp folders a run left.
fn leftovers(parent: &Path, keep: &[&str]) -> Vec<String> {
    std::fs::read_dir(parent)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !keep.contains(&n.as_str()))
        .collect()
}

#[test]
fn a_package_holds_the_addon_the_tileset_and_a_deterministic_archive() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let tiles = d.join("tiles");
    tileset(&tiles);
    let out = d.join("penumbra-moon");
    let zip = d.join("moon.zip");
    let zip_arg = format!("--zip={}", s(&zip));
    let pkg = |threads: &str| {
        ok_json(&[
            "--threads",
            threads,
            "package",
            s(&tiles),
            "--celestia",
            s(&out),
            &zip_arg,
            "--vt-tile-size",
            "64",
            "--json",
        ])
    };
    let r = pkg("2");
    assert_eq!(r["replaced"], false, "{r}");

    // The addon as Celestia reads it: the catalog, and every file it and its virtual textures
    // name.
    let check = check_addon(&out).unwrap();
    assert_eq!(check.catalogs.len(), 1);
    assert_eq!(check.virtual_textures.len(), 2, "albedo and normal map");
    let cat = std::fs::read_to_string(&check.catalogs[0]).unwrap();
    let items = ssc::parse_ssc(&cat).unwrap();
    let mut named = 0;
    for item in &items {
        assert_eq!(item.name, "Penumbra", "a partial tileset is an AltSurface");
        for key in TEXTURE_KEYS {
            let Some(name) = item.body.get_str(key) else {
                continue;
            };
            let ctx = out.join(TEXTURES_DIR).join(name);
            let v = ssc::parse_ctx(&std::fs::read_to_string(&ctx).unwrap()).unwrap();
            assert_eq!(v.tile_size, 64);
            let images = ctx.parent().unwrap().join(&v.image_directory);
            let level0 = std::fs::read_dir(images.join("level0")).unwrap().count();
            assert!(level0 > 0, "{}", images.display());
            named += 1;
        }
    }
    assert_eq!(named, 2, "{cat}");
    let tiles_json: u64 = r["textures"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["tiles"].as_u64().unwrap())
        .sum();
    assert_eq!(
        tiles_json,
        check.virtual_textures.iter().map(|v| v.1).sum::<u64>()
    );

    // The cube-face products: a tileset that opens, whose files are the source's, byte for byte.
    let cube = out.join(CUBEMAP_DIR);
    assert_eq!(tileset_in(&out), cube);
    assert_eq!(tileset_in(&tiles), tiles);
    penumbra::tileset::Store::open(&cube).unwrap();
    assert!(penumbra::tileset::verify::verify(&cube).unwrap().clean());
    let (a, b) = (snapshot(&tiles), snapshot(&cube));
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "the same files"
    );
    assert!(a == b, "the same bytes");
    assert_eq!(indexes(&tiles), indexes(&cube));
    let products: Vec<&str> = r["cubemap"]["products"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["product"].as_str().unwrap())
        .collect();
    assert_eq!(products, ["height", "albedo", "mip", "horizon", "fourier"]);
    assert_eq!(r["cubemap"]["verified"], r["cubemap"]["files"]);

    // The README says what is inside and how to install it.
    let readme = std::fs::read_to_string(out.join(README)).unwrap();
    for want in [
        "Moon",
        "extras",
        "Alternate Surfaces",
        "height",
        "albedo",
        "mip",
        "horizon",
        "fourier",
        "embedded",
        "penumbra package",
        CUBEMAP_DIR,
    ] {
        assert!(readme.contains(want), "README lacks {want:?}:\n{readme}");
    }
    assert!(out.join(MARKER).is_file());

    // The archive: exactly the folder's files under its name, in order, with their bytes.
    let entries = zip_entries(&zip);
    let files: Vec<(String, Vec<u8>)> = all_files(&out)
        .into_iter()
        .map(|(k, v)| (format!("penumbra-moon/{k}"), v))
        .collect();
    assert_eq!(
        entries.iter().map(|e| &e.0).collect::<Vec<_>>(),
        files.iter().map(|e| &e.0).collect::<Vec<_>>()
    );
    assert!(entries == files, "the archive's bytes are the folder's");
    assert_eq!(r["zip"]["entries"].as_u64(), Some(files.len() as u64));

    // Again, on one thread and on two: the earlier package is replaced, by the same bytes.
    let first = std::fs::read(&zip).unwrap();
    let folder = all_files(&out);
    for threads in ["1", "2"] {
        let again = pkg(threads);
        assert_eq!(again["replaced"], true);
        assert!(
            std::fs::read(&zip).unwrap() == first,
            "--threads {threads}: the archive differs"
        );
        assert!(
            all_files(&out) == folder,
            "--threads {threads}: the folder differs"
        );
    }
    assert_eq!(
        leftovers(
            d,
            &["tiles", "tiles.albedo.png", "penumbra-moon", "moon.zip"]
        ),
        Vec::<String>::new()
    );
}

/// A small embedded-terrain scene for the renderer's DP (tiles and mipmaps).
/// (128-px tiles, levels 0..11; the package's VT levels are capped: the embedded terrain lies
/// at the pole, where every VT level is a whole row of tiles.)
fn scene(dir: &Path, size: u32) -> PathBuf {
    let p = dir.join("small.toml");
    std::fs::write(
        &p,
        format!(
            "[scene]\nname = \"small\"\nbody = \"moon\"\n\n[layout]\ntile_size = 128\n\n\
             [[source]]\nembedded = \"south-pole\"\nsize = {size}\n\n[[region]]\nname = \
             \"all\"\nbody = true\n\n[renderer]\nmethods = [\"dp\"]\n"
        ),
    )
    .unwrap();
    p
}

/// Exit 2 with every one of `want` on stderr, and nothing at `out` (nor temp folders beside
/// it).
fn refused(args: &[&str], out: &Path, want: &[&str]) {
    let o = run(args);
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
    for w in want {
        assert!(e.contains(w), "{args:?}: expected {w:?} in: {e}");
    }
    assert!(!e.contains("panicked"), "{e}");
    assert!(!out.exists(), "{args:?} wrote {}", out.display());
    // An output whose folder is missing: that folder stays missing.
    let parent = out.parent().unwrap();
    if !parent.exists() {
        return;
    }
    let name = out.file_name().unwrap().to_string_lossy();
    let left: Vec<String> = leftovers(parent, &[])
        .into_iter()
        .filter(|n| n.contains(&*name))
        .collect();
    assert!(left.is_empty(), "{args:?} left {left:?}");
}

#[test]
fn a_scene_is_packaged_only_from_its_up_to_date_bake() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let sc = scene(d, 512);
    let baked = d.join("baked");
    let out = d.join("pkg");
    let args = [
        "package",
        s(&sc),
        "--tileset",
        s(&baked),
        "--celestia",
        s(&out),
        "--vt-tile-size",
        "64",
        "--vt-max-level",
        "3",
    ];
    // Never baked: say which bake to run.
    refused(
        &args,
        &out,
        &["penumbra bake", "small.toml", "--out", "baked"],
    );
    ok_json(&["bake", s(&sc), "--out", s(&baked), "--json"]);
    let r = ok_json(&[&args[..], &["--json"]].concat());
    assert_eq!(PathBuf::from(r["tileset"].as_str().unwrap()), baked);
    assert_eq!(snapshot(&out.join(CUBEMAP_DIR)), snapshot(&baked));
    // The scene changed since: its bake is stale, and the package is left as it was.
    let before = all_files(&out);
    scene(d, 1024);
    let o = run(&args);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("penumbra bake"));
    assert!(
        all_files(&out) == before,
        "a refused run changed the package"
    );
    // A tileset folder names its tileset itself.
    refused(
        &[
            "package",
            s(&baked),
            "--tileset",
            s(&baked),
            "--celestia",
            s(&d.join("p2")),
        ],
        &d.join("p2"),
        &["--tileset", "drop"],
    );
}

/// Replace a file by other bytes of the same size (as a writer would: a new file renamed over
/// it, so a package's link to the old file keeps the old bytes).
fn replace_flipped(p: &Path) {
    let mut b = std::fs::read(p).unwrap();
    let i = b.len() - 1;
    b[i] ^= 0x55;
    let t = p.with_extension("tmp-test");
    std::fs::write(&t, &b).unwrap();
    std::fs::rename(&t, p).unwrap();
}

#[test]
fn bad_input_exits_2_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let tiles = d.join("tiles");
    tileset(&tiles);
    let out = d.join("pkg");
    let pkg = |src: &Path, out: &Path, extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = ["package", s(src), "--celestia", s(out)]
            .iter()
            .map(|x| x.to_string())
            .collect();
        v.extend(extra.iter().map(|x| x.to_string()));
        v
    };
    let refuse = |args: Vec<String>, out: &Path, want: &[&str]| {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        refused(&a, out, want);
    };

    // An output folder that holds something else: refused, and left as it was.
    let other = d.join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "mine").unwrap();
    let o = run(&pkg(&tiles, &other, &[])
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("not empty"));
    assert_eq!(leftovers(&other, &[]), vec!["notes.txt".to_string()]);

    // A folder that is no tileset; an input that does not exist.
    let empty = d.join("empty");
    std::fs::create_dir(&empty).unwrap();
    refuse(pkg(&empty, &out, &[]), &out, &["tileset.json"]);
    refuse(pkg(&d.join("nowhere"), &out, &[]), &out, &["nowhere"]);

    // A tileset with no heights (nor the products made from them).
    let bare = d.join("bare");
    copy_tree(&tiles, &bare);
    let m = bare.join("tileset.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&m).unwrap()).unwrap();
    for p in ["height", "mip", "horizon", "fourier"] {
        v["products"][p] = serde_json::Value::Null;
    }
    std::fs::write(&m, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
    refuse(pkg(&bare, &out, &[]), &out, &["no height tiles"]);

    // An archive whose folder is missing; an archive inside the package.
    let nodir = d.join("no-such-dir").join("a.zip");
    refuse(
        pkg(&tiles, &out, &[&format!("--zip={}", s(&nodir))]),
        &out,
        &["no-such-dir", "not a folder"],
    );
    assert!(!nodir.parent().unwrap().exists());
    refuse(
        pkg(&tiles, &out, &[&format!("--zip={}", s(&out.join("a.zip")))]),
        &out,
        &["inside the package"],
    );
    // An output whose folder is missing.
    let deep = d.join("missing").join("pkg");
    refuse(pkg(&tiles, &deep, &[]), &deep, &["missing", "not a folder"]);

    // A damaged tileset: a product file truncated, named in the error.
    let damaged = d.join("damaged");
    copy_tree(&tiles, &damaged);
    let fhm = std::fs::read_dir(damaged.join("fourier/3/nz"))
        .unwrap()
        .flat_map(|e| std::fs::read_dir(e.unwrap().path()).unwrap())
        .map(|e| e.unwrap().path())
        .min()
        .unwrap();
    let f = std::fs::OpenOptions::new().write(true).open(&fhm).unwrap();
    let len = f.metadata().unwrap().len();
    f.set_len(len / 2).unwrap();
    drop(f);
    let rel = fhm
        .strip_prefix(&damaged)
        .unwrap()
        .to_string_lossy()
        .into_owned();
    refuse(pkg(&damaged, &out, &["--zip"]), &out, &[&rel, "bytes"]);
    assert!(!d.join("pkg.zip").exists());

    // A package made, then its tileset damaged (a mipmap's bytes replaced, its size kept): the
    // rerun names the file and leaves the package as it was.
    let good = d.join("good");
    copy_tree(&tiles, &good);
    let ok = d.join("ok");
    let args = pkg(&good, &ok, &["--json"]);
    ok_json(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let before = all_files(&ok);
    let mip = good.join("maxmip/3/nz/3/3.exr");
    assert!(mip.is_file(), "{}", mip.display());
    replace_flipped(&mip);
    let o = run(&pkg(&good, &ok, &[])
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(
        e.contains("maxmip/3/nz/3/3.exr") && e.contains("blake3"),
        "{e}"
    );
    assert!(
        all_files(&ok) == before,
        "a refused run changed the package"
    );
    let left: Vec<String> = leftovers(d, &[])
        .into_iter()
        .filter(|n| n.contains("penumbra-partial") || n.contains("penumbra-old"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}
