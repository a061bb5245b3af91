//! The reliability audit's "exit 0 with nonsense" DEMs (issue 41), made from the real DEMs in
//! ../shared/data in a temporary folder: each is refused by `penumbra tile` with exit 2, a
//! message naming the file and the key at fault, and no output folder — or, for heights beyond
//! the body's relief, tiles only with `--allow-relief`. Skipped without the data (failing under
//! CI, `util::shared_data`). docs/formats.md, "Relief of the body".

use std::path::{Path, PathBuf};

use crate::util::{penumbra_bin, shared_data, Rng};

/// `penumbra tile DEM --out OUT` on one thread, one level of 64-px tiles, plus `extra`.
fn tile(dem: &Path, out: &Path, extra: &[&str]) -> (i32, String) {
    let o = penumbra_bin()
        .args([
            "--threads",
            "1",
            "tile",
            "--tile-size",
            "64",
            "--levels",
            "1",
        ])
        .arg(dem)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Refused: exit 2, no output folder, and the message holds every one of `words`.
fn refused(dem: &Path, dir: &Path, extra: &[&str], words: &[&str]) -> String {
    let out = dir.join(format!(
        "out-{}",
        dem.file_name().unwrap().to_string_lossy()
    ));
    let (code, err) = tile(dem, &out, extra);
    assert_eq!(code, 2, "{}: {err}", dem.display());
    assert!(!out.exists(), "{}: left {}", dem.display(), out.display());
    for w in words {
        assert!(err.contains(w), "{}: '{w}' not in: {err}", dem.display());
    }
    err
}

/// A PDS3 LDEM_4 in `dir/name/`: the real label with `edit` applied and the real image
/// (linked, or `img` bytes when given).
fn ldem(data: &Path, dir: &Path, name: &str, edit: impl Fn(String) -> String) -> PathBuf {
    let d = dir.join(name);
    std::fs::create_dir_all(&d).unwrap();
    let label = std::fs::read_to_string(data.join("lola_ldem4/LDEM_4.LBL")).unwrap();
    let edited = edit(label.clone());
    assert_ne!(edited, label, "{name}: the edit changed nothing");
    std::fs::write(d.join("LDEM_4.LBL"), edited).unwrap();
    std::os::unix::fs::symlink(data.join("lola_ldem4/LDEM_4.IMG"), d.join("LDEM_4.IMG")).unwrap();
    d.join("LDEM_4.LBL")
}

/// The label's `KEY = value` line with another value.
fn set(label: String, key: &str, value: &str) -> String {
    let mut out = String::new();
    let mut done = false;
    for line in label.split_inclusive('\n') {
        let t = line.trim_start();
        if !done && t.starts_with(key) && t[key.len()..].trim_start().starts_with('=') {
            let indent = &line[..line.len() - t.len()];
            out.push_str(&format!("{indent}{key} = {value}\r\n"));
            done = true;
        } else {
            out.push_str(line);
        }
    }
    out
}

#[test]
fn nonsense_heights_need_allow_relief() {
    let Some(data) = shared_data() else { return };
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();

    // SCALING_FACTOR = 3 (the label says 0.5): lunar peaks of +63 km.
    let p = ldem(&data, dir, "scale3", |l| set(l, "SCALING_FACTOR", "3"));
    let e = refused(
        &p,
        dir,
        &[],
        &[
            "--allow-relief",
            "LDEM_4.IMG",
            "moon",
            "SCALING_FACTOR",
            "-19200..20800",
        ],
    );
    assert!(
        e.contains("highest is 63012 m") || e.contains("lowest"),
        "{e}"
    );
    // The user says the terrain is real: it tiles.
    let out = dir.join("scale3-allowed");
    let (code, err) = tile(&p, &out, &["--allow-relief", "-60000,70000"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.join("tileset.json").is_file());
    // An allowed range that still does not hold it: refused, naming the range allowed.
    refused(
        &p,
        dir,
        &["--allow-relief", "-60000,60000"],
        &["relief allowed"],
    );

    // SRTM of all 32767 (the largest int16): a 32.8 km Earth.
    let d = dir.join("srtm-max");
    std::fs::create_dir_all(&d).unwrap();
    let p = d.join("N19W156.hgt");
    std::fs::write(&p, [0x7Fu8, 0xFF].repeat(1201 * 1201)).unwrap();
    refused(
        &p,
        dir,
        &[],
        &["--allow-relief", "N19W156.hgt", "earth", "32767"],
    );

    // SRTM of random bytes (seeded): ±32.7 km.
    let d = dir.join("srtm-random");
    std::fs::create_dir_all(&d).unwrap();
    let p = d.join("N44W072.hgt");
    let mut rng = Rng(0x41_41);
    let bytes: Vec<u8> = (0..1201 * 1201 * 2)
        .map(|_| (rng.next() >> 56) as u8)
        .collect();
    std::fs::write(&p, bytes).unwrap();
    refused(&p, dir, &[], &["--allow-relief", "N44W072.hgt", "earth"]);

    // The real files pass as they are (their relief is within their bodies').
    for (f, body) in [
        ("srtm3/N19W156.hgt", "earth"),
        ("srtm3/N44W072.hgt", "earth"),
        ("lola_ldem4/LDEM_4.LBL", "moon"),
        ("mola_megt90n000cb/megt90n000cb.lbl", "mars"),
        ("mola_gale_128ppd_crop/gale-mola.json", "mars"),
        (
            "lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif",
            "moon",
        ),
    ] {
        let dem = penumbra::dem::open(&data.join(f), 64).unwrap();
        let body = penumbra::body::Body::preset(body).unwrap();
        dem.check_for_body(&body, None).unwrap();
    }
}

#[test]
fn contradictory_labels_are_refused_by_key() {
    let Some(data) = shared_data() else { return };
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();

    // LDEM_4 labelled Mars: its lunar datum would put the terrain 1659 km below Mars's sphere.
    let p = ldem(&data, dir, "mars", |l| set(l, "TARGET_NAME", "MARS"));
    refused(&p, dir, &[], &["TARGET_NAME = mars", "OFFSET", "1737400"]);
    // Also when the user names Mars, and when a radius forces Mars's.
    refused(&p, dir, &["--body", "mars"], &["TARGET_NAME = mars"]);

    // SCALING_FACTOR = "" is not "absent" (it read as 1: a Moon 2× too rough).
    let p = ldem(&data, dir, "empty-scale", |l| {
        set(l, "SCALING_FACTOR", "\"\"")
    });
    refused(&p, dir, &[], &["SCALING_FACTOR", "empty", "LDEM_4.LBL"]);
    let p = ldem(&data, dir, "empty-offset", |l| set(l, "OFFSET", "\"\""));
    refused(&p, dir, &[], &["OFFSET", "empty"]);

    // SCALING_FACTOR = -1 turns the terrain upside down.
    let p = ldem(&data, dir, "negative-scale", |l| {
        set(l, "SCALING_FACTOR", "-1")
    });
    refused(
        &p,
        dir,
        &[],
        &["SCALING_FACTOR = -1", "negative", "LDEM_4.LBL"],
    );

    // An IMG 240× longer than its label says (sparse: no disk used).
    let d = dir.join("long");
    std::fs::create_dir_all(&d).unwrap();
    std::fs::copy(data.join("lola_ldem4/LDEM_4.LBL"), d.join("LDEM_4.LBL")).unwrap();
    let img = d.join("LDEM_4.IMG");
    std::fs::copy(data.join("lola_ldem4/LDEM_4.IMG"), &img).unwrap();
    let f = std::fs::OpenOptions::new().write(true).open(&img).unwrap();
    f.set_len(240 * 1440 * 720 * 2).unwrap();
    drop(f);
    refused(
        &d.join("LDEM_4.LBL"),
        dir,
        &[],
        &["LDEM_4.IMG", "LINES = 720", "ends at byte 2073600"],
    );

    // A GeoTIFF whose pixel scale says 57:1 (Shoemaker's 5 m × 5 m made 285 m × 5 m).
    let shoe = data.join("lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif");
    let mut bytes = std::fs::read(&shoe).unwrap();
    let (at, le) = tiff_doubles(&bytes, 33550).expect("Shoemaker has a ModelPixelScale");
    let sx = f64_at(&bytes, at, le);
    put_f64(&mut bytes, at, le, sx * 57.0);
    let p = dir.join("shoemaker-57.tif");
    std::fs::write(&p, bytes).unwrap();
    refused(
        &p,
        dir,
        &["--body", "moon"],
        &["ModelPixelScale", "57.0 times", "shoemaker-57.tif"],
    );

    // A south polar sidecar whose true-scale latitude is +90 (the north's): the Gale crop's
    // samples placed on a 463 m polar grid.
    let gale = data.join("mola_gale_128ppd_crop");
    for (lat_ts, ok) in [(-90, true), (90, false), (71, false)] {
        let d = dir.join(format!("polar{lat_ts}"));
        std::fs::create_dir_all(&d).unwrap();
        std::os::unix::fs::symlink(gale.join("gale-mola.bin"), d.join("gale.bin")).unwrap();
        let sc = format!(
            r#"{{"size": 897, "format": "uint16-le", "elevationMin": -4648.0,
                "elevationMax": 2002.0, "target": "mars",
                "crs": {{"kind": "polar-stereographic", "north": false, "lon0_deg": 0,
                         "lat_ts_deg": {lat_ts}, "radius_m": 3396190}},
                "x0": -207424, "y0": 207424, "dx": 463, "dy": 463}}"#
        );
        std::fs::write(d.join("gale.json"), sc).unwrap();
        let p = d.join("gale.json");
        if ok {
            let (code, err) = tile(&p, &dir.join("polar-ok"), &[]);
            assert_eq!(code, 0, "{err}");
        } else {
            refused(
                &p,
                dir,
                &[],
                &["lat_ts_deg", "other hemisphere", "gale.json"],
            );
        }
    }
}

/// `--allow-relief` itself: malformed or out-of-range values exit 2 naming the flag, before
/// anything is read or written.
#[test]
fn allow_relief_flag_is_checked() {
    let t = tempfile::tempdir().unwrap();
    let dem = t.path().join("none.hgt");
    for bad in [
        "abc", "1", "5,1", "1,1", "nan,1", "-inf,0", "0,1e12", "1,2,3", "",
    ] {
        let out = t.path().join("out");
        let (code, err) = tile(&dem, &out, &["--allow-relief", bad]);
        assert_eq!(code, 2, "{bad}: {err}");
        assert!(err.contains("--allow-relief"), "{bad}: {err}");
        assert!(!out.exists());
    }
}

/// The offset of tag `tag`'s DOUBLE values in a classic TIFF, and whether it is little-endian.
fn tiff_doubles(b: &[u8], tag: u16) -> Option<(usize, bool)> {
    let le = &b[..2] == b"II";
    let u16_at = |o: usize| {
        let a = [b[o], b[o + 1]];
        if le {
            u16::from_le_bytes(a)
        } else {
            u16::from_be_bytes(a)
        }
    };
    let u32_at = |o: usize| {
        let a = [b[o], b[o + 1], b[o + 2], b[o + 3]];
        if le {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        }
    };
    let ifd = u32_at(4) as usize;
    (0..u16_at(ifd) as usize)
        .map(|i| ifd + 2 + 12 * i)
        .find(|&e| u16_at(e) == tag && u16_at(e + 2) == 12)
        .map(|e| (u32_at(e + 8) as usize, le))
}

fn f64_at(b: &[u8], at: usize, le: bool) -> f64 {
    let a: [u8; 8] = b[at..at + 8].try_into().unwrap();
    if le {
        f64::from_le_bytes(a)
    } else {
        f64::from_be_bytes(a)
    }
}

fn put_f64(b: &mut [u8], at: usize, le: bool, v: f64) {
    let a = if le { v.to_le_bytes() } else { v.to_be_bytes() };
    b[at..at + 8].copy_from_slice(&a);
}
