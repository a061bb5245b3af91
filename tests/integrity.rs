//! Damaged tilesets, generated: every product file of a small baked tileset (heights, albedo,
//! both mipmaps, face pyramids, raw horizon maps, Fourier pyramids) is in turn swapped with a
//! sibling of its product (as is, and with the index rewritten to the swapped bytes so that
//! only the file's identity can tell), re-encoded at another precision (encoding, bit depth)
//! with its identity kept and the index rewritten (so that only the manifest's labels can
//! tell), replaced by a FIFO, linked to /dev/zero and padded by a sparse 5 GiB; then
//! `penumbra verify` must flag exactly that file (exit 1) and a command that reads it must
//! exit 2 naming it and what is wrong, within 5 s and 100 MB of RSS. Each label of the manifest
//! that describes the files (precisions, channels, encoding, sigma, albedo bit depth and
//! channels) flipped to each other value is refused by every command that reads the product
//! and flagged by `verify`, with and without the run key basis that names it at once. A FIFO,
//! device or folder `tileset.json` does the same for every command. See issue 41.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

use penumbra::cube::{self, Face};
use penumbra::layout::TileId;
use penumbra::manifest::Tileset;

use crate::util::penumbra_bin;

/// Longest a damaged read may take, and the most memory it may hold.
const LIMIT: Duration = Duration::from_secs(5);
const MAX_RSS_KIB: u64 = 100 << 10;

/// A run of the CLI under the limits: its output, wall time and peak RSS (KiB, sampled from
/// /proc while it runs; the kernel's high-water mark, so a run that allocated is seen).
fn run_bounded(args: &[&str]) -> (Output, Duration, u64) {
    let t0 = Instant::now();
    let mut child = penumbra_bin()
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status_path = format!("/proc/{}/status", child.id());
    let mut peak = 0u64;
    loop {
        // (Only once the child runs penumbra: between fork and exec its status is a copy of
        // this test process's, whose peak can be anything the other tests in it allocated.)
        if let Ok(s) = std::fs::read_to_string(&status_path).map(|s| {
            let execd = s
                .lines()
                .find(|l| l.starts_with("Name:"))
                .is_some_and(|l| l.split_whitespace().nth(1) == Some("penumbra"));
            if execd {
                s
            } else {
                String::new()
            }
        }) {
            if let Some(kib) = s
                .lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse::<u64>().ok())
            {
                peak = peak.max(kib);
            }
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if t0.elapsed() > LIMIT * 2 {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let out = child.wait_with_output().unwrap();
    (out, t0.elapsed(), peak)
}

/// A command that must refuse `file` (relative path) with exit 2 naming it, `what` in the message.
fn refused(args: &[&str], file: &str, what: &[&str], case: &str) {
    let (o, t, rss) = run_bounded(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{case}: {args:?}: {err}");
    assert!(
        err.contains(file),
        "{case}: {args:?} does not name {file}: {err}"
    );
    assert!(
        what.iter().any(|w| err.contains(w)),
        "{case}: {args:?} does not say {what:?}: {err}"
    );
    assert!(t < LIMIT, "{case}: {args:?} took {t:?}");
    assert!(rss < MAX_RSS_KIB, "{case}: {args:?} peaked at {rss} KiB");
}

/// The tileset every case damages: the embedded scene at 4 levels of 32² tiles (12 tiles), with
/// an 8-bit RGB albedo, mipmaps, raw horizon maps and Fourier pyramids at level 3 (59 product
/// files).
fn base(dir: &Path) {
    let png = dir.with_extension("albedo.png");
    image::RgbImage::from_fn(64, 32, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 8) as u8, 128])
    })
    .save(&png)
    .unwrap();
    let o = penumbra_bin()
        .args([
            "bake",
            "--albedo",
            png.to_str().unwrap(),
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
            dir.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Every indexed file by product: (relative path, size).
fn indexed(dir: &Path) -> BTreeMap<String, Vec<(String, u64)>> {
    let mut out = BTreeMap::new();
    for p in ["height", "albedo", "mip", "horizon", "fourier"] {
        let ix: Vec<(String, u64, String)> = serde_json::from_slice(
            &std::fs::read(dir.join(format!(".penumbra/index/{p}.json"))).unwrap(),
        )
        .unwrap();
        out.insert(
            p.to_string(),
            ix.into_iter().map(|(r, l, _)| (r, l)).collect(),
        );
    }
    out
}

/// The file's kind (its identity's product name) from its path.
fn kind(rel: &str) -> &'static str {
    let parts: Vec<&str> = rel.split('/').collect();
    match parts[0] {
        "height" => "height",
        "albedo" => "albedo",
        "maxmip" => "maxmip",
        "minmax" if parts.len() == 4 && parts[3] == "face.exr" => "minmax-face",
        "minmax" if parts.get(3) == Some(&"face") => "minmax-face-chunk",
        "minmax" => "minmax",
        "horizon" => "horizon",
        "fourier" => "fourier",
        other => panic!("unexpected product folder {other}"),
    }
}

/// The tile of a per-tile file's path (`<dir>/<level>/<face>/<y>/<x>.<ext>`); for a face file
/// the tile (0, 0) of its level and face.
fn tile_of(rel: &str) -> TileId {
    let parts: Vec<&str> = rel.split('/').collect();
    let level = parts[1].parse().unwrap();
    let face = Face::ALL
        .iter()
        .copied()
        .find(|f| f.name() == parts[2])
        .unwrap();
    let (y, x) = if parts.len() == 5 {
        let x = parts[4].split('.').next().unwrap();
        (parts[3].parse().unwrap(), x.parse().unwrap())
    } else {
        (0, 0)
    };
    TileId { level, face, x, y }
}

/// Latitude and longitude (degrees) of a pixel with data: of tile `id`, or (a face file) of
/// any tile of its level and face, as near the tile's centre as there is one. The horizon
/// queries need a pixel with data (elsewhere they answer "no data" without reading a file).
fn point(dir: &Path, ts: &Tileset, id: TileId, face_file: bool) -> (f64, f64) {
    let tile = if face_file {
        *ts.tile_set()
            .iter()
            .find(|t| t.level == id.level && t.face == id.face)
            .unwrap()
    } else {
        id
    };
    let h = penumbra::format::height::read_height_tile(&penumbra::tileset::tile_path(
        dir,
        penumbra::manifest::HEIGHT_PATTERN,
        tile,
    ))
    .unwrap();
    let (n, halo) = (ts.layout.tile_size as i64, ts.layout.halo as i64);
    let s = h.size as i64;
    let (mut best, mut best_d) = ((n / 2, n / 2), i64::MAX);
    for j in 0..n {
        for i in 0..n {
            let k = ((j + halo) * s + i + halo) as usize;
            let d = (i - n / 2).pow(2) + (j - n / 2).pow(2);
            if h.mask[k] == 0 && d < best_d {
                (best, best_d) = ((i, j), d);
            }
        }
    }
    let (lat, lon) = cube::dir_to_latlon(ts.layout.pixel_dir(tile, best.0, best.1));
    (lat.to_degrees(), lon.to_degrees())
}

/// A command that reads `rel` (and what it says when it refuses it).
fn reader(dir: &str, ts: &Tileset, rel: &str) -> Vec<String> {
    let id = tile_of(rel);
    let (lat, lon) = point(Path::new(dir), ts, id, kind(rel) == "minmax-face");
    let (lat, lon) = (format!("{lat}"), format!("{lon}"));
    let level = id.level.to_string();
    let q = |what: &str| -> Vec<String> {
        ["query", what, dir, "--lat", &lat, "--lon", &lon]
            .iter()
            .map(|s| s.to_string())
            .collect()
    };
    let mut args = match kind(rel) {
        "height" => {
            let mut a = q("height");
            a.extend(["--level".into(), level]);
            a
        }
        // No command reads the maximum pyramids or the albedo (the viewer and shaders do,
        // through the store): the library's read is checked instead ([`library_read`]).
        "maxmip" | "albedo" => return Vec::new(),
        "minmax" => {
            let mut a = q("mip");
            a.extend(["--level".into(), "0".into(), "--tile-level".into(), level]);
            a
        }
        "minmax-face" => {
            // Past the tile's own pyramid: the face pyramid's level 0.
            let m = penumbra::mip::level_sizes(ts.layout.tile_size as usize).len();
            let mut a = q("mip");
            a.extend([
                "--level".into(),
                m.to_string(),
                "--tile-level".into(),
                level,
            ]);
            a
        }
        "horizon" => {
            let a = ts.products.horizon.as_ref().unwrap().azimuths.to_string();
            let mut v = q("horizon");
            v.extend([
                "--level".into(),
                level,
                "--from".into(),
                "raw".into(),
                "--azimuths".into(),
                a,
            ]);
            v
        }
        "fourier" => {
            let mut v = q("horizon");
            v.extend(["--level".into(), level, "--from".into(), "fourier".into()]);
            v
        }
        k => panic!("no reader for {k}"),
    };
    args.push("--json".into());
    args
}

/// Rewrite the index entry of `rel` to the size and blake3 of the bytes now there.
fn reindex(dir: &Path, product: &str, rel: &str) {
    let p = dir.join(format!(".penumbra/index/{product}.json"));
    let mut ix: Vec<(String, u64, String)> =
        serde_json::from_slice(&std::fs::read(&p).unwrap()).unwrap();
    let bytes = std::fs::read(dir.join(rel)).unwrap();
    for e in ix.iter_mut().filter(|e| e.0 == rel) {
        e.1 = bytes.len() as u64;
        e.2 = blake3::hash(&bytes).to_hex().to_string();
    }
    std::fs::write(&p, serde_json::to_vec(&ix).unwrap()).unwrap();
}

/// The file at `from` re-encoded at another precision (encoding, bit depth: what the manifest's
/// labels say of it) with its identity kept, written to `to`; the label that must name it.
fn relabel(from: &Path, to: &Path, kind: &str, ts: &Tileset) -> &'static str {
    use penumbra::exrcodec::{self, Channel, Encoding, Samples, TileCompression, ZipLevel};
    use penumbra::format::{self, Identity};
    use std::borrow::Cow;
    let bytes = std::fs::read(from).unwrap();
    let exr_id = || Identity::parse(&exrcodec::read_identity(&bytes).unwrap().unwrap()).unwrap();
    let n = ts.layout.tile_size as usize;
    let half = |v: &[f32]| -> Vec<exr::prelude::f16> {
        v.iter().map(|&x| exr::prelude::f16::from_f32(x)).collect()
    };
    let (out, label) = match kind {
        "height" => {
            let t = format::height::decode_height_tile(&bytes).unwrap();
            let mask: Vec<f32> = t.mask.iter().map(|&m| m as f32).collect();
            let out = exrcodec::encode_identified(
                "penumbra-height",
                Some(&exr_id().text()),
                (t.size, t.size),
                &[
                    Channel {
                        name: "height",
                        levels: vec![Samples::F16(Cow::Owned(half(&t.height)))],
                    },
                    Channel {
                        name: "mask",
                        levels: vec![Samples::F16(Cow::Owned(half(&mask)))],
                    },
                ],
                &Encoding::scanlines(TileCompression::Zip),
            )
            .unwrap();
            (out, "height tile format")
        }
        "maxmip" | "minmax" | "minmax-face" | "minmax-face-chunk" => {
            let f = format::mip::decode_mip_exr(&bytes).unwrap();
            let out = format::mip::encode_mip_exr_identified(
                f.sizes[0],
                f.channels.get("min").map(|v| v.as_slice()),
                &f.channels["max"],
                format::mip::Precision::F16,
                TileCompression::Zip,
                ZipLevel::DEFAULT,
                "relabelled",
                Some(&exr_id()),
            )
            .unwrap();
            let label = if kind.starts_with("minmax-face") {
                "products.mip.face_precision"
            } else {
                "products.mip.precision"
            };
            (out, label)
        }
        "horizon" => {
            let (a, e) = format::horizon::decode_horizon_exr(&bytes, n).unwrap();
            let out = format::horizon::encode_horizon_exr_identified(
                n,
                a,
                &e,
                format::horizon::HorizonPrecision::F32,
                TileCompression::Zip,
                ZipLevel::DEFAULT,
                Some(&exr_id()),
            )
            .unwrap();
            (out, "products.horizon.precision")
        }
        "fourier" => {
            let a = ts.products.fourier.as_ref().unwrap().azimuths;
            let mut p = format::fourier::Pyramid::decode(&bytes, from, n, a).unwrap();
            let id = format::fourier::read_identity(&bytes)
                .unwrap()
                .unwrap()
                .unwrap();
            p.encoding = format::fourier::Encoding::Snorm16;
            for g in &mut p.groups {
                g.scale = g.coef.iter().flatten().fold(1e-3f32, |m, v| m.max(v.abs()));
            }
            (p.encode_identified(Some(&id)), "products.fourier.encoding")
        }
        "albedo" => {
            let facts = format::albedo::read_header(&bytes).unwrap();
            let id = Identity::parse(facts.identity.as_deref().unwrap()).unwrap();
            let img = image::load_from_memory(&bytes).unwrap().into_rgb16();
            let tile = format::albedo::AlbedoTile {
                size: img.width() as usize,
                channels: 3,
                sixteen_bit: true,
                data: img.into_raw(),
            };
            let out = format::albedo::encode_albedo_tile(&tile, Some(&id)).unwrap();
            (out, "products.albedo.bit_depth")
        }
        k => panic!("no re-encoding for {k}"),
    };
    std::fs::write(to, out).unwrap();
    label
}

/// The library's read of `rel` (a file no command reads: the maximum pyramids, the albedo),
/// which must fail: its error.
fn library_read(dir: &Path, rel: &str) -> String {
    let store = penumbra::tileset::Store::open(dir).unwrap();
    let id = tile_of(rel);
    let r = match kind(rel) {
        "maxmip" => store.mip(id, true).map(|_| ()),
        "albedo" => store.albedo(id).map(|_| ()),
        k => panic!("{k} has a command that reads it"),
    };
    r.unwrap_err().to_string()
}

fn mkfifo(p: &Path) {
    let ok = std::process::Command::new("mkfifo")
        .arg(p)
        .status()
        .unwrap()
        .success();
    assert!(ok, "mkfifo {}", p.display());
}

/// The damages, each with what `verify` calls it and words the readers' messages use.
const DAMAGES: &[(&str, &[&str], &[&str])] = &[
    // A sibling's bytes: the index's size or hash tells (or, same size, its hash).
    ("swap", &["size", "hash"], &["index recorded"]),
    // A sibling's bytes and an index that agrees: only the identity tells.
    ("swap-reindexed", &["identity"], &["claims to be"]),
    // The file's samples at another precision (encoding, bit depth), its identity kept and
    // the index agreeing: only the manifest's labels can tell ([`relabel`] says which).
    ("relabelled", &["label"], &[]),
    ("fifo", &["not-a-file"], &["FIFO"]),
    ("dev-zero", &["outside-link"], &["outside the tileset"]),
    ("sparse-5gib", &["size"], &["index recorded"]),
];

#[test]
fn every_damaged_product_file_is_refused_by_its_readers_and_flagged_by_verify() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ts");
    base(&dir);
    let ds = dir.to_str().unwrap();
    // Clean first.
    let (o, _, _) = run_bounded(&["verify", ds, "--json"]);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let ts = Tileset::load(&dir).unwrap();
    let files = indexed(&dir);
    let index_backup: BTreeMap<String, Vec<u8>> = files
        .keys()
        .map(|p| {
            let f = dir.join(format!(".penumbra/index/{p}.json"));
            (p.clone(), std::fs::read(f).unwrap())
        })
        .collect();
    let mut cases = 0;
    let mut kinds_seen = std::collections::BTreeSet::new();
    for (product, list) in &files {
        for (rel, _) in list {
            let k = kind(rel);
            kinds_seen.insert(k);
            // A sibling of the same kind: the next file of that kind (by path), preferring
            // one of the same size (the audit's case: a valid file the size check cannot tell).
            let same_kind: Vec<&(String, u64)> = list
                .iter()
                .filter(|(r, _)| kind(r) == k && r != rel)
                .collect();
            let own_len = list.iter().find(|(r, _)| r == rel).unwrap().1;
            let sibling = same_kind
                .iter()
                .find(|(_, l)| *l == own_len)
                .or(same_kind.first())
                .map(|(r, _)| r.clone());
            let path = dir.join(rel);
            let saved = dir.join(".saved");
            // Chosen before any damage (it reads the height tile to find a pixel with data).
            let args = reader(ds, &ts, rel);
            for &(damage, flags, words) in DAMAGES {
                let mut words: Vec<&str> = words.to_vec();
                if damage.starts_with("swap") && sibling.is_none() {
                    continue;
                }
                std::fs::rename(&path, &saved).unwrap();
                match damage {
                    "swap" | "swap-reindexed" => {
                        std::fs::copy(dir.join(sibling.as_ref().unwrap()), &path).unwrap();
                        if damage == "swap-reindexed" {
                            reindex(&dir, product, rel);
                        }
                    }
                    "relabelled" => {
                        words.push(relabel(&saved, &path, k, &ts));
                        reindex(&dir, product, rel);
                    }
                    "fifo" => mkfifo(&path),
                    "dev-zero" => std::os::unix::fs::symlink("/dev/zero", &path).unwrap(),
                    "sparse-5gib" => {
                        std::fs::copy(&saved, &path).unwrap();
                        let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
                        f.set_len(own_len + (5 << 30)).unwrap();
                    }
                    _ => unreachable!(),
                }
                let case = format!("{rel} {damage}");
                // verify flags this file, and only it.
                let (o, t, rss) = run_bounded(&["verify", ds, "--json"]);
                assert_eq!(o.status.code(), Some(1), "{case}: verify");
                assert!(
                    t < LIMIT && rss < MAX_RSS_KIB,
                    "{case}: verify {t:?} {rss} KiB"
                );
                let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
                let found = r["findings"].as_array().unwrap();
                assert!(
                    !found.is_empty() && found.iter().all(|f| f["path"] == rel.as_str()),
                    "{case}: {found:?}"
                );
                assert!(
                    found
                        .iter()
                        .any(|f| flags.contains(&f["problem"].as_str().unwrap())),
                    "{case}: {found:?}"
                );
                // A command that reads it refuses it.
                if args.is_empty() {
                    let t0 = Instant::now();
                    let e = library_read(&dir, rel);
                    assert!(
                        e.contains(rel.as_str()) && words.iter().any(|w| e.contains(w)),
                        "{case}: {e}"
                    );
                    assert!(t0.elapsed() < LIMIT, "{case}: {:?}", t0.elapsed());
                } else {
                    let args: Vec<&str> = args.iter().map(String::as_str).collect();
                    refused(&args, rel, &words, &case);
                }
                // Restore.
                std::fs::remove_file(&path).unwrap();
                std::fs::rename(&saved, &path).unwrap();
                if damage == "swap-reindexed" || damage == "relabelled" {
                    let f = dir.join(format!(".penumbra/index/{product}.json"));
                    std::fs::write(f, &index_backup[product]).unwrap();
                }
                cases += 1;
            }
        }
    }
    for k in [
        "height",
        "albedo",
        "maxmip",
        "minmax",
        "minmax-face",
        "horizon",
        "fourier",
    ] {
        assert!(kinds_seen.contains(k), "no {k} file was damaged");
    }
    assert!(cases > 100, "only {cases} cases");
    // Restored: clean again.
    let (o, _, _) = run_bounded(&["verify", ds]);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
}

/// Whole-tileset readers (the stages) refuse a damaged height tile too: `mip` with other
/// options, `horizon` and `fourier` read every tile.
#[test]
fn stages_refuse_a_swapped_height_tile() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ts");
    base(&dir);
    let ds = dir.to_str().unwrap();
    let files = indexed(&dir);
    let heights: Vec<&String> = files["height"]
        .iter()
        .map(|(r, _)| r)
        .filter(|r| r.starts_with("height/3/"))
        .collect();
    let (a, b) = (heights[0], heights[1]);
    // Same-size swap with a matching index: only the identity can tell.
    std::fs::copy(dir.join(b), dir.join(a)).unwrap();
    reindex(&dir, "height", a);
    for args in [
        vec!["mip", ds, "--precision", "f16"],
        vec!["horizon", ds, "--levels", "3", "--azimuths", "8"],
        vec!["fourier", ds, "--coefficients", "3"],
    ] {
        refused(&args, a, &["claims to be height"], "stage");
    }
}

/// A `tileset.json` that is a FIFO, a device or a folder: every command exits 2 at once naming
/// it (a FIFO used to hang `open` forever).
#[test]
fn a_manifest_that_is_not_a_file_is_refused_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ts");
    base(&dir);
    let ds = dir.to_str().unwrap();
    let m = dir.join("tileset.json");
    let saved = dir.join(".saved.json");
    std::fs::rename(&m, &saved).unwrap();
    for (damage, words) in [
        ("fifo", "FIFO"),
        ("dev-zero", "character device"),
        ("folder", "folder"),
    ] {
        match damage {
            "fifo" => mkfifo(&m),
            "dev-zero" => std::os::unix::fs::symlink("/dev/zero", &m).unwrap(),
            _ => std::fs::create_dir(&m).unwrap(),
        }
        for args in [
            vec!["info", ds],
            vec!["verify", ds],
            vec!["query", "height", ds, "--lat", "0", "--lon", "0"],
            vec!["mip", ds],
        ] {
            refused(&args, "tileset.json", &[words], damage);
        }
        if m.is_dir() {
            std::fs::remove_dir(&m).unwrap();
        } else {
            std::fs::remove_file(&m).unwrap();
        }
    }
    std::fs::rename(&saved, &m).unwrap();
    let (o, _, _) = run_bounded(&["verify", ds]);
    assert_eq!(o.status.code(), Some(0));
}

/// Old tilesets (format v1: files without identity, indexes without hashes) are refused with
/// what to rerun; a tile of the current format read without its index still has its identity
/// checked, and a file the index does not list is refused.
#[test]
fn format_1_tilesets_are_refused_with_what_to_rerun() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ts");
    base(&dir);
    let m = dir.join("tileset.json");
    let text = std::fs::read_to_string(&m).unwrap();
    std::fs::write(
        &m,
        text.replace("\"format_version\": 2", "\"format_version\": 1"),
    )
    .unwrap();
    let (o, _, _) = run_bounded(&["info", dir.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("tileset.json") && err.contains("rebuild it"),
        "{err}"
    );
}

/// Each label of the manifest that describes the files (sample types, channel names, the
/// Fourier encoding and sigma, the albedo bit depth and channels) flipped to each other value,
/// with the stage products' run key basis recorded and without it (as a penumbra that did not
/// record it wrote the manifest): every command that reads the product exits 2, naming either
/// the manifest and the field (the basis or the run key name it when the tileset is opened) or
/// the product file and the label (only its header can tell), within the limits; `verify`
/// refuses the tileset naming the field, or flags the product's files with `label` problems
/// naming it.
#[test]
fn every_label_flipped_is_refused_by_its_readers_and_flagged_by_verify() {
    use serde_json::{json, Value};
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ts");
    base(&dir);
    let ds = dir.to_str().unwrap();
    let ts = Tileset::load(&dir).unwrap();
    let m = dir.join("tileset.json");
    let good_bytes = std::fs::read(&m).unwrap();
    let good: Value = serde_json::from_slice(&good_bytes).unwrap();
    let files = indexed(&dir);
    // A file of each kind, and the command (or library read) that reads it.
    let file_of = |k: &str| -> String {
        files
            .values()
            .flatten()
            .map(|(r, _)| r.clone())
            .find(|r| kind(r) == k)
            .unwrap_or_else(|| panic!("no {k} file"))
    };
    // (label, the values it is flipped to, the kinds of file it describes)
    let rows: Vec<(&str, Vec<Value>, &[&str])> = vec![
        (
            "products.height.channels",
            vec![json!(["height"]), json!(["height", "mask", "slope"])],
            &["height"],
        ),
        ("products.mip.precision", vec![json!("f16")], &["minmax"]),
        (
            "products.mip.face_precision",
            vec![json!("f16")],
            &["minmax-face"],
        ),
        (
            "products.mip.max_channels",
            vec![json!(["min"])],
            &["maxmip"],
        ),
        (
            "products.mip.minmax_channels",
            vec![json!(["max"]), json!(["min", "max", "mean"])],
            &["minmax", "minmax-face"],
        ),
        (
            "products.horizon.precision",
            vec![json!("f32")],
            &["horizon"],
        ),
        (
            "products.horizon.channel",
            vec![json!("height")],
            &["horizon"],
        ),
        (
            "products.fourier.encoding",
            vec![json!("snorm16")],
            &["fourier"],
        ),
        (
            "products.fourier.sigma",
            vec![json!("lanczos")],
            &["fourier"],
        ),
        ("products.albedo.bit_depth", vec![json!(16)], &["albedo"]),
        (
            "products.albedo.channels",
            vec![json!(1), json!(2), json!(4)],
            &["albedo"],
        ),
    ];
    let mut cases = 0;
    let (mut at_open, mut at_file) = (0, 0);
    for with_basis in [true, false] {
        for (field, values, kinds) in &rows {
            for value in values {
                let mut v = good.clone();
                let parts: Vec<&str> = field.split('.').collect();
                let mut cur = &mut v;
                for p in &parts[..parts.len() - 1] {
                    cur = &mut cur[*p];
                }
                assert_ne!(cur[parts[parts.len() - 1]], *value, "{field}");
                cur[parts[parts.len() - 1]] = value.clone();
                if !with_basis {
                    for p in ["mip", "horizon", "fourier"] {
                        v["products"][p]
                            .as_object_mut()
                            .unwrap()
                            .remove("run_key_basis");
                    }
                }
                std::fs::write(&m, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
                let case = format!("{field} = {value} (basis: {with_basis})");
                let named = format!("field `{field}`");
                // Every reader of each kind of file the label describes.
                for k in kinds.iter() {
                    let rel = file_of(k);
                    let args = reader(ds, &ts, &rel);
                    let (err, code) = if args.is_empty() {
                        let t0 = Instant::now();
                        let e = match penumbra::tileset::Store::open(&dir) {
                            Ok(_) => library_read(&dir, &rel),
                            Err(e) => e.to_string(),
                        };
                        assert!(t0.elapsed() < LIMIT, "{case}: {:?}", t0.elapsed());
                        (e, Some(2))
                    } else {
                        let args: Vec<&str> = args.iter().map(String::as_str).collect();
                        let (o, t, rss) = run_bounded(&args);
                        assert!(t < LIMIT && rss < MAX_RSS_KIB, "{case}: {t:?} {rss} KiB");
                        (
                            String::from_utf8_lossy(&o.stderr).into_owned(),
                            o.status.code(),
                        )
                    };
                    assert_eq!(code, Some(2), "{case}: {k}: {err}");
                    if err.contains("tileset.json") && err.contains(&named) {
                        at_open += 1;
                    } else {
                        assert!(
                            err.contains(&rel) && err.contains(&format!("`{field}`")),
                            "{case}: {k} {rel}: names neither the field nor the file and the \
                             label: {err}"
                        );
                        at_file += 1;
                    }
                }
                // verify: refused naming the field, or the files flagged naming the label.
                let (o, t, rss) = run_bounded(&["verify", ds, "--json"]);
                assert!(
                    t < LIMIT && rss < MAX_RSS_KIB,
                    "{case}: verify {t:?} {rss} KiB"
                );
                let err = String::from_utf8_lossy(&o.stderr);
                match o.status.code() {
                    Some(2) => assert!(
                        err.contains("tileset.json") && err.contains(&named),
                        "{case}: verify: {err}"
                    ),
                    Some(1) => {
                        let r: Value = serde_json::from_slice(&o.stdout).unwrap();
                        let found = r["findings"].as_array().unwrap();
                        assert!(
                            !found.is_empty()
                                && found.iter().all(|f| f["problem"] == "label"
                                    && f["detail"]
                                        .as_str()
                                        .unwrap()
                                        .contains(&format!("`{field}`"))
                                    && kinds.contains(&kind(f["path"].as_str().unwrap()))),
                            "{case}: verify: {found:?}"
                        );
                    }
                    c => panic!("{case}: verify exited {c:?}: {err}"),
                }
                cases += 1;
            }
        }
    }
    std::fs::write(&m, &good_bytes).unwrap();
    let (o, _, _) = run_bounded(&["verify", ds]);
    assert_eq!(o.status.code(), Some(0));
    eprintln!("labels flipped: {cases} cases, {at_open} refused at open, {at_file} by a file");
    assert!(at_open > 0 && at_file > 0);
}
