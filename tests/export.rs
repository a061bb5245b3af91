//! `penumbra export` (Cloud-Optimized GeoTIFF through GDAL) and DEMs read through GDAL.
//!
//! With `--features gdal`: GDAL's own tools read the exported COGs back — `gdalinfo -json`
//! reports the CRS on the body's sphere, the geotransform of the report and the COG layout,
//! and `gdallocationinfo` at 20 seeded-random pixels (placed in the body's lon/lat by
//! `gdaltransform`, i.e. by PROJ, not by Penumbra) returns what `penumbra query` answers there.
//! Bad input exits 2 and writes nothing. Tiles cut from LDEM_4 through GDAL (its PDS driver, a
//! VRT mosaic of two GeoTIFF halves) equal the native reader's. Without the feature the command
//! exits 2 saying how to build it.

use std::path::Path;
use std::process::Output;

use crate::util::penumbra_bin;

fn run(args: &[&str]) -> Output {
    penumbra_bin().args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Files in `dir`, names only.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[cfg(not(feature = "gdal"))]
#[test]
fn without_gdal_export_exits_2_saying_how_to_build_it() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("h.tif");
    let o = run(&[
        "export",
        d.path().to_str().unwrap(),
        "--product",
        "height",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("this build has no GDAL: rebuild with `cargo build --features gdal`"),
        "{}",
        stderr(&o)
    );
    assert!(listing(d.path()).is_empty(), "{:?}", listing(d.path()));
    // And a DEM read through GDAL is refused the same way.
    let dem = d.path().join("x.vrt");
    std::fs::write(&dem, "<VRTDataset/>").unwrap();
    let o = run(&[
        "tile",
        dem.to_str().unwrap(),
        "--dem-format",
        "gdal",
        "--out",
        d.path().join("t").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--features gdal"), "{}", stderr(&o));
}

#[cfg(feature = "gdal")]
mod with_gdal {
    use super::*;
    use std::process::Command;

    fn json(o: &Output) -> serde_json::Value {
        assert!(o.status.success(), "{}", stderr(o));
        serde_json::from_slice(&o.stdout).unwrap()
    }

    fn tool(name: &str, args: &[&str], stdin: Option<&str>) -> String {
        use std::io::Write;
        let mut c = Command::new(name);
        c.args(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped());
        if stdin.is_some() {
            c.stdin(std::process::Stdio::piped());
        }
        let mut child = c
            .spawn()
            .unwrap_or_else(|e| panic!("{name} (gdal-bin) must be installed: {e}"));
        if let Some(s) = stdin {
            child.stdin.take().unwrap().write_all(s.as_bytes()).unwrap();
        }
        let o = child.wait_with_output().unwrap();
        assert!(o.status.success(), "{name} {args:?}: {}", stderr(&o));
        String::from_utf8(o.stdout).unwrap()
    }

    /// The embedded scene at 1024 px (20 km across the south pole), 32-px tiles, 12 levels
    /// (53 m/px at level 11), Fourier pyramids (and raw maps) at level 9 (212 m/px).
    fn baked(dir: &Path) -> String {
        let s = dir.join("tiles").to_str().unwrap().to_string();
        json(&run(&[
            "bake",
            "--out",
            &s,
            "--scene-size",
            "1024",
            "--levels",
            "12",
            "--tile-size",
            "32",
            "--horizon-levels",
            "9",
            "--keep-raw",
            "--json",
        ]));
        s
    }

    fn rng(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    const LONLAT: &str = "+proj=longlat +R=1737400 +no_defs +type=crs";

    /// How far a COG's value may be from the query's.
    #[derive(Clone, Copy)]
    enum Tol {
        /// The rounding of the query's value to the file's f32 (half an ulp; one ulp allowed).
        F32,
        /// An absolute bound.
        Abs(f64),
    }

    /// Export, then check the file with GDAL's tools against the report and the queries.
    fn check_export(
        tiles: &str,
        dir: &Path,
        name: &str,
        args: &[&str],
        query: &dyn Fn(f64, f64) -> f64,
        tol: Tol,
    ) {
        let out = dir.join(format!("{name}.tif"));
        let o = out.to_str().unwrap();
        let rep = json(&run(
            &[&["export", tiles, "--out", o, "--json"][..], args].concat()
        ));
        let r = &rep["raster"];
        let (w, h) = (
            r["width"].as_u64().unwrap() as usize,
            r["height"].as_u64().unwrap() as usize,
        );
        let gt: Vec<f64> = r["geo_transform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();

        // What GDAL says the file is.
        let info: serde_json::Value =
            serde_json::from_str(&tool("gdalinfo", &["-json", "-proj4", o], None)).unwrap();
        let cs = &info["coordinateSystem"];
        let wkt = cs["wkt"].as_str().unwrap();
        assert!(
            wkt.contains("1737400") && wkt.contains("Moon"),
            "{name}: {wkt}"
        );
        let proj4 = cs["proj4"].as_str().unwrap().trim().to_string();
        assert!(proj4.contains("+R=1737400"), "{name}: {proj4}");
        let g: Vec<f64> = info["geoTransform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        for k in 0..6 {
            assert!(
                (g[k] - gt[k]).abs() <= 1e-9 * gt[k].abs().max(1.0),
                "{name}: {g:?} {gt:?}"
            );
        }
        assert_eq!(info["size"], serde_json::json!([w, h]));
        assert_eq!(
            info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"], "COG",
            "{name}: {info}"
        );
        assert_eq!(
            info["metadata"]["IMAGE_STRUCTURE"]["COMPRESSION"],
            "DEFLATE"
        );
        let band = &info["bands"][0];
        assert_eq!(band["type"], "Float32");
        assert!(
            !band["noDataValue"].is_null(),
            "{name}: no nodata in {band}"
        );
        let overviews = band["overviews"].as_array().map_or(0, |v| v.len());
        if w.max(h) > 256 {
            assert!(overviews > 0, "{name}: {w}×{h} without overviews");
        }
        assert_eq!(
            info["metadata"][""]["PENUMBRA_PRODUCT"], rep["raster"]["product"],
            "{name}"
        );

        // 20 random pixels with data (found in GDAL's ASCII grid of the file): their centres
        // in the body's lon/lat by PROJ.
        // (To a file: on /vsistdout/ GDAL appends the .prj sidecar's WKT to the grid.)
        let asc = dir.join(format!("{name}.asc"));
        tool(
            "gdal_translate",
            &[
                "-q",
                "-of",
                "AAIGrid",
                "-co",
                "DECIMAL_PRECISION=2",
                o,
                asc.to_str().unwrap(),
            ],
            None,
        );
        let grid = std::fs::read_to_string(&asc).unwrap();
        let values: Vec<f64> = grid
            .lines()
            .filter(|l| {
                let key = l
                    .split_whitespace()
                    .next()
                    .unwrap_or("")
                    .to_ascii_lowercase();
                ![
                    "ncols",
                    "nrows",
                    "xllcorner",
                    "yllcorner",
                    "xllcenter",
                    "yllcenter",
                    "cellsize",
                    "dx",
                    "dy",
                    "nodata_value",
                ]
                .contains(&key.as_str())
            })
            .flat_map(|l| l.split_whitespace())
            .map(|t| t.parse().unwrap_or(f64::NAN))
            .collect();
        assert_eq!(
            values.len(),
            w * h,
            "{name}: the ASCII grid has {} values",
            values.len()
        );
        let mut data: Vec<usize> = (0..w * h).filter(|&k| !values[k].is_nan()).collect();
        assert!(data.len() >= 20, "{name}: {} pixels with data", data.len());
        // Lit fractions: the pixels on the shadows' edges (neither 0 nor 1), where a misplaced
        // pixel shows, when there are enough of them.
        let partial: Vec<usize> = data
            .iter()
            .copied()
            .filter(|&k| values[k] > 0.0 && values[k] < 1.0)
            .collect();
        if name == "lit" {
            assert!(
                partial.len() >= 20,
                "{name}: {} partly lit pixels",
                partial.len()
            );
            data = partial;
        }
        let mut rnd = rng(0x5EED ^ name.len() as u64);
        let mut picked = Vec::new();
        for _ in 0..20 {
            let k = data.swap_remove((rnd() * data.len() as f64) as usize % data.len());
            let (c, r) = (k % w, k / w);
            let v = tool(
                "gdallocationinfo",
                &["-valonly", o, &c.to_string(), &r.to_string()],
                None,
            );
            picked.push((c, r, v.trim().parse::<f64>().unwrap()));
        }
        let xy: String = picked
            .iter()
            .map(|&(c, r, _)| {
                format!(
                    "{:.6} {:.6}\n",
                    gt[0] + (c as f64 + 0.5) * gt[1],
                    gt[3] + (r as f64 + 0.5) * gt[5]
                )
            })
            .collect();
        let ll = tool(
            "gdaltransform",
            &["-output_xy", "-s_srs", &proj4, "-t_srs", LONLAT],
            Some(&xy),
        );
        let mut worst: f64 = 0.0;
        for (line, &(c, r, v)) in ll.lines().zip(&picked) {
            let p: Vec<&str> = line.split_whitespace().collect();
            let (lon, lat) = (p[0], p[1]);
            // The same pixel found from the body's lon/lat by GDAL.
            let at = tool(
                "gdallocationinfo",
                &["-valonly", "-l_srs", LONLAT, o, lon, lat],
                None,
            );
            assert_eq!(at.trim().parse::<f64>().unwrap(), v, "{name} at ({c}, {r})");
            let q = query(lat.parse().unwrap(), lon.parse().unwrap());
            let d = (q - v).abs();
            worst = worst.max(d);
            let tol = match tol {
                Tol::F32 => f32::EPSILON as f64 * q.abs().max(f32::MIN_POSITIVE as f64),
                Tol::Abs(t) => t,
            };
            assert!(
                d <= tol,
                "{name} pixel ({c}, {r}) at {lat}°, {lon}°: COG {v}, query {q}"
            );
        }
        let vs: Vec<f64> = picked.iter().map(|p| p.2).collect();
        eprintln!(
            "{name}: {w}×{h}, {proj4}; worst |COG − query| over 20 pixels {worst:.3e}; values \
             {:.4}..{:.4}",
            vs.iter().copied().fold(f64::INFINITY, f64::min),
            vs.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        );
    }

    #[test]
    fn cogs_hold_what_the_queries_answer() {
        let d = tempfile::tempdir().unwrap();
        let tiles = baked(d.path());
        let t = tiles.as_str();
        let q = |args: &[&str], key: &str, lat: f64, lon: f64| -> serde_json::Value {
            let (la, lo) = (lat.to_string(), lon.to_string());
            let v = json(&run(&[
                &args[..2],
                &[t, "--lat", &la, "--lon", &lo, "--json"],
                &args[2..],
            ]
            .concat()));
            v[key].clone()
        };
        // Heights at the finest level (default region and CRS: polar stereographic) and on a
        // face's gnomonic grid.
        check_export(
            t,
            d.path(),
            "height",
            &["--product", "height"],
            &|la, lo| {
                q(&["query", "height", "--level", "11"], "height_m", la, lo)
                    .as_f64()
                    .unwrap()
            },
            Tol::F32,
        );
        check_export(
            t,
            d.path(),
            "height-face",
            &["--product", "height", "--face", "nz", "--level", "5"],
            &|la, lo| {
                q(&["query", "height", "--level", "5"], "height_m", la, lo)
                    .as_f64()
                    .unwrap()
            },
            Tol::F32,
        );
        // Lit fractions for a low sun, and mean horizons, equirectangular by request.
        check_export(
            t,
            d.path(),
            "lit",
            &[
                "--product",
                "lit",
                "--sun-az",
                "135",
                "--sun-el",
                "1.5",
                "--level",
                "9",
            ],
            &|la, lo| {
                q(
                    &[
                        "query", "shadow", "--level", "9", "--sun-az", "135", "--sun-el", "1.5",
                    ],
                    "lit_fraction",
                    la,
                    lo,
                )
                .as_f64()
                .unwrap()
            },
            Tol::Abs(1e-6),
        );
        check_export(
            t,
            d.path(),
            "horizon-mean",
            // A narrow box (the whole polar cap in equirectangular is 51472×91 px).
            &[
                "--product",
                "horizon-mean",
                "--crs",
                "eqc",
                "--bbox",
                "-89.75,-89.7,10,25",
            ],
            &|la, lo| {
                let e = q(
                    &["query", "horizon", "--level", "9", "--from", "fourier"],
                    "elevation_deg",
                    la,
                    lo,
                );
                let e: Vec<f64> = e
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect();
                e.iter().sum::<f64>() / e.len() as f64
            },
            Tol::F32,
        );
    }

    #[test]
    fn bad_export_input_exits_2_and_writes_nothing() {
        let d = tempfile::tempdir().unwrap();
        let tiles = baked(d.path());
        let out_dir = d.path().join("out");
        std::fs::create_dir(&out_dir).unwrap();
        let out = out_dir.join("x.tif");
        let o = out.to_str().unwrap();
        let missing = d.path().join("no-such-folder/x.tif");
        let cases: Vec<(Vec<&str>, &str)> = vec![
            // A product the tileset lacks at that level.
            (
                vec!["--product", "horizon-mean", "--level", "2"],
                "--level 2 has no Fourier pyramids",
            ),
            (
                vec![
                    "--product",
                    "lit",
                    "--sun-az",
                    "1",
                    "--sun-el",
                    "2",
                    "--from",
                    "raw",
                    "--level",
                    "1",
                ],
                "--level 1 has no raw horizon maps",
            ),
            // A box outside the data.
            (
                vec!["--product", "height", "--bbox", "10,20,30,40"],
                "holds no data",
            ),
            (
                vec!["--product", "height", "--face", "px", "--level", "3"],
                "holds no data",
            ),
            // A format the build lacks, malformed or missing options.
            (
                vec!["--product", "height", "--format", "png"],
                "--format 'png'",
            ),
            (
                vec!["--product", "height", "--bbox", "1,2,3"],
                "--bbox '1,2,3' is not four numbers",
            ),
            (
                vec!["--product", "height", "--bbox", "-80,-90,0,10"],
                "--bbox latitudes",
            ),
            (
                vec!["--product", "height", "--face", "up"],
                "--face 'up' is no face",
            ),
            (vec!["--product", "lit"], "needs the sun"),
            (
                vec!["--product", "height", "--sun-az", "3", "--sun-el", "4"],
                "are for --product lit",
            ),
            (
                vec!["--product", "height", "--level", "12"],
                "--level 12 does not exist",
            ),
            (
                vec!["--product", "height", "--max-output-gib", "0.0000001"],
                "--max-output-gib",
            ),
            (vec!["--product", "shade"], "unknown product"),
        ];
        for (args, needle) in cases {
            let r = run(&[&["export", tiles.as_str(), "--out", o][..], &args].concat());
            assert_eq!(r.status.code(), Some(2), "{args:?}: {}", stderr(&r));
            assert!(stderr(&r).contains(needle), "{args:?}: {}", stderr(&r));
            assert!(
                listing(&out_dir).is_empty(),
                "{args:?} left {:?}",
                listing(&out_dir)
            );
        }
        // An --out whose folder is missing, or that is a folder.
        for (out, needle) in [
            (missing.to_str().unwrap(), "does not exist"),
            (out_dir.to_str().unwrap(), "is a folder"),
        ] {
            let r = run(&[
                "export",
                tiles.as_str(),
                "--product",
                "height",
                "--out",
                out,
            ]);
            assert_eq!(r.status.code(), Some(2), "{}", stderr(&r));
            assert!(stderr(&r).contains(needle), "{}", stderr(&r));
        }
        assert!(!missing.parent().unwrap().exists());
        // Not a tileset.
        let r = run(&[
            "export",
            out_dir.to_str().unwrap(),
            "--product",
            "height",
            "--out",
            o,
        ]);
        assert_eq!(r.status.code(), Some(2));
        assert!(listing(&out_dir).is_empty());
    }

    /// Height tiles of a tileset, decoded, by tile.
    fn heights(dir: &Path) -> std::collections::BTreeMap<String, Vec<f32>> {
        let store = penumbra::tileset::Store::open(dir).unwrap();
        penumbra::manifest::tiles_of(&store.manifest().coverage)
            .into_iter()
            .map(|t| (t.to_string(), store.read_height(t).unwrap().height))
            .collect()
    }

    fn tile(dem: &Path, out: &Path, extra: &[&str]) -> Output {
        run(&[
            &[
                "tile",
                dem.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                // Level 2: 512 px a face, 5.3 km/px at the centre, finer than LDEM_4's
                // 7.6 km: tiles sample between its pixels, across the antimeridian too.
                "--tile-size",
                "128",
                "--levels",
                "3",
            ][..],
            extra,
        ]
        .concat())
    }

    /// Largest |a − b| over tiles that must be the same set, NaN where both are.
    fn max_diff(a: &Path, b: &Path) -> f64 {
        let (a, b) = (heights(a), heights(b));
        assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
        let mut worst: f64 = 0.0;
        for (k, va) in &a {
            for (x, y) in va.iter().zip(&b[k]) {
                assert_eq!(x.is_nan(), y.is_nan(), "tile {k}");
                if !x.is_nan() {
                    worst = worst.max((x - y).abs() as f64);
                }
            }
        }
        worst
    }

    #[test]
    fn gdal_read_dems_tile_as_the_native_reader_does() {
        let Some(data) = crate::util::shared_data() else {
            return;
        };
        let lbl = data.join("lola_ldem4/LDEM_4.LBL");
        let d = tempfile::tempdir().unwrap();
        let native = d.path().join("native");
        let o = tile(&lbl, &native, &[]);
        assert!(o.status.success(), "{}", stderr(&o));
        // The same label through GDAL's PDS driver.
        let via = d.path().join("via-gdal");
        let o = tile(&lbl, &via, &["--dem-format", "gdal"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let pds = max_diff(&native, &via);
        // A VRT mosaic of two GeoTIFF halves made by gdal_translate.
        let (w, h) = (1440, 720);
        for (k, x0) in [(0, 0), (1, w / 2)] {
            let win = [
                x0.to_string(),
                "0".into(),
                (w / 2).to_string(),
                h.to_string(),
            ];
            let out = d.path().join(format!("half{k}.tif"));
            tool(
                "gdal_translate",
                &[
                    &["-q", "-srcwin"][..],
                    &win.iter().map(String::as_str).collect::<Vec<_>>(),
                    &[lbl.to_str().unwrap(), out.to_str().unwrap()],
                ]
                .concat(),
                None,
            );
        }
        let vrt = d.path().join("mosaic.vrt");
        tool(
            "gdalbuildvrt",
            &[
                "-q",
                vrt.to_str().unwrap(),
                d.path().join("half0.tif").to_str().unwrap(),
                d.path().join("half1.tif").to_str().unwrap(),
            ],
            None,
        );
        let mosaic = d.path().join("mosaic");
        let o = tile(&vrt, &mosaic, &[]); // .vrt: no native reader knows it, GDAL does.
        assert!(o.status.success(), "{}", stderr(&o));
        let vrt_diff = max_diff(&native, &mosaic);
        let m: serde_json::Value =
            serde_json::from_slice(&std::fs::read(mosaic.join("tileset.json")).unwrap()).unwrap();
        let srcs = m.to_string();
        assert!(
            srcs.contains("half0.tif") && srcs.contains("half1.tif"),
            "the VRT's sources are the manifest's: {srcs}"
        );
        eprintln!(
            "LDEM_4 through GDAL: PDS driver max |Δh| {pds:.3e} m, VRT mosaic {vrt_diff:.3e} m"
        );
        // Both read LDEM_4 as a global grid of 4 px/° (GDAL's PDS driver says equirectangular
        // metres with the label's rounded MAP_SCALE; read in degrees, its columns wrap across
        // the antimeridian as the native reader's do): the same samples, so the same tiles to
        // f32 rounding of the positions.
        assert!(pds <= 1e-3 && vrt_diff <= 1e-3, "{pds} {vrt_diff}");

        // A crop declared WGS 84 (Earth) is refused for the Moon.
        let earth = d.path().join("earth.tif");
        tool(
            "gdal_translate",
            &[
                "-q",
                "-srcwin",
                "0",
                "0",
                "64",
                "64",
                "-a_srs",
                "EPSG:4326",
                "-a_ullr",
                "0",
                "10",
                "16",
                "-6",
                lbl.to_str().unwrap(),
                earth.to_str().unwrap(),
            ],
            None,
        );
        let bad = d.path().join("bad");
        let o = tile(&earth, &bad, &["--dem-format", "gdal", "--body", "moon"]);
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        assert!(stderr(&o).contains("is a DEM of earth"), "{}", stderr(&o));
        assert!(!bad.exists());
        // Projected CRSs the reader does not model: on a flattened ellipsoid (UTM on WGS 84),
        // or a projection other than eqc / polar stere (Mercator on the Moon's sphere).
        for (k, srs, needle) in [
            (0, "+proj=utm +zone=33 +datum=WGS84", "flattened ellipsoid"),
            (1, "+proj=merc +R=1737400", "is none Penumbra reads"),
        ] {
            let f = d.path().join(format!("proj{k}.tif"));
            tool(
                "gdal_translate",
                &[
                    "-q",
                    "-srcwin",
                    "0",
                    "0",
                    "64",
                    "64",
                    "-a_srs",
                    srs,
                    "-a_ullr",
                    "0",
                    "640000",
                    "640000",
                    "0",
                    lbl.to_str().unwrap(),
                    f.to_str().unwrap(),
                ],
                None,
            );
            let o = tile(&f, &bad, &["--dem-format", "gdal"]);
            assert_eq!(o.status.code(), Some(2), "{srs}: {}", stderr(&o));
            assert!(stderr(&o).contains(needle), "{srs}: {}", stderr(&o));
            assert!(!bad.exists());
        }
        // A scene source read through GDAL.
        let scene = d.path().join("s.toml");
        std::fs::write(
            &scene,
            format!(
                "[scene]\nname = \"vrt\"\n[[source]]\npath = \"{}\"\nformat = \"gdal\"\n[[region]]\nname = \"all\"\nbody = true\n[renderer]\nmethods = [\"dp\"]\n",
                vrt.display()
            ),
        )
        .unwrap();
        // The plan opens it through GDAL: one source, LDEM_4's 4 px/° at the equator.
        let plan = json(&run(&["plan", scene.to_str().unwrap(), "--json"]));
        let srcs = plan["sources"].as_array().unwrap();
        assert_eq!(srcs.len(), 1, "{plan}");
        let px = srcs[0]["pixel_m"].as_f64().unwrap();
        let want = std::f64::consts::TAU * 1_737_400.0 / 1440.0;
        assert!((px - want).abs() < 0.01, "{px} m/px, want {want}");
    }
}
