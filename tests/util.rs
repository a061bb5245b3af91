use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use penumbra::dem::{Crs, Dem, DemParts, GeoRef};

/// The real DEMs every real-data test reads: `$PENUMBRA_SHARED_DATA` when set, else
/// `../shared/data` beside the repository root. When the folder is absent the test is skipped
/// (`None`, after a message), except under CI (`CI` set, and not `false` or `0`), where it
/// fails: a CI run must never pass by skipping the real-DEM checks.
pub fn shared_data() -> Option<PathBuf> {
    let dir = match std::env::var_os("PENUMBRA_SHARED_DATA") {
        Some(p) => PathBuf::from(p),
        // This test binary belongs to tools/penumbra; the repository root is two levels up.
        None => Path::new(env!("CARGO_MANIFEST_DIR"))
            .ancestors()
            .nth(2)
            .expect("tools/penumbra lies two levels below the repository root")
            .join("../shared/data"),
    };
    let ci = std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false"));
    found_or_skip(dir, ci)
}

/// `Some(dir)` when it is a folder; otherwise a skip (`None`), or a panic when `ci`.
fn found_or_skip(dir: PathBuf, ci: bool) -> Option<PathBuf> {
    if dir.is_dir() {
        Some(dir)
    } else if ci {
        panic!(
            "{}: real-DEM folder not found, and CI is set: CI must run the real-DEM tests \
             (put the data in ../shared/data beside the repository or set PENUMBRA_SHARED_DATA)",
            dir.display()
        );
    } else {
        eprintln!(
            "skipping: {} not found (real-DEM checks need it)",
            dir.display()
        );
        None
    }
}

#[test]
fn shared_data_missing_skips_outside_ci() {
    assert_eq!(
        found_or_skip(PathBuf::from("/nonexistent/shared/data"), false),
        None
    );
}

#[test]
#[should_panic(expected = "CI must run the real-DEM tests")]
fn shared_data_missing_fails_under_ci() {
    found_or_skip(PathBuf::from("/nonexistent/shared/data"), true);
}

/// A smooth analytic height field over the sphere (m), defined on directions so it has no
/// seams, poles or wrap of its own.
pub fn analytic(lat_deg: f64, lon_deg: f64) -> f64 {
    let d = penumbra::cube::latlon_to_dir(lat_deg.to_radians(), lon_deg.to_radians());
    1500.0 * (3.0 * d[0]).sin() * (2.0 * d[1]).cos() + 800.0 * (4.0 * d[2] + 0.3).sin()
        - 400.0 * d[0] * d[1]
}

/// A global geographic raster of [`analytic`], pixel-registered, `w × w/2` samples.
pub fn global_dem(w: usize) -> Dem {
    let h = w / 2;
    let d = 360.0 / w as f64;
    let georef = GeoRef {
        crs: Crs::Geographic,
        x0: -180.0 + d / 2.0,
        y0: 90.0 - d / 2.0,
        dx: d,
        dy: d,
    };
    let mut v = Vec::with_capacity(w * h);
    for r in 0..h {
        for c in 0..w {
            let lat = georef.y0 - r as f64 * d;
            let lon = georef.x0 + c as f64 * d;
            v.push(analytic(lat, lon) as f32);
        }
    }
    dem_from(georef, w, h, v, "analytic test raster")
}

/// A geographic raster of `w × h` pixels of `d` degrees whose outer edges are at
/// `lon_west` and `lat_north`, sample `f(column, row, lat, lon)` at each pixel centre.
pub fn geographic_dem(
    (lon_west, lat_north): (f64, f64),
    (w, h): (usize, usize),
    d: f64,
    label: &str,
    f: impl Fn(usize, usize, f64, f64) -> f32,
) -> Dem {
    let georef = GeoRef {
        crs: Crs::Geographic,
        x0: lon_west + d / 2.0,
        y0: lat_north - d / 2.0,
        dx: d,
        dy: d,
    };
    let mut v = Vec::with_capacity(w * h);
    for r in 0..h {
        for c in 0..w {
            v.push(f(c, r, georef.y0 - r as f64 * d, georef.x0 + c as f64 * d));
        }
    }
    dem_from(georef, w, h, v, label)
}

pub fn penumbra_bin() -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_penumbra"));
    c.arg("--quiet");
    c
}

/// A DEM over `values` (row-major, `w × h`, metres) placed by `georef`.
pub fn dem_from(georef: GeoRef, w: usize, h: usize, values: Vec<f32>, label: &str) -> Dem {
    Dem::new(DemParts::in_memory(georef, w, h, values, label), 64).unwrap()
}

/// Every file below `dir` with its bytes, by relative path.
pub fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.file_name()
                .is_some_and(|n| n == penumbra::tileset::STATE_DIR)
            {
                // The writer's bookkeeping (lock with its pid, indexes), not output.
                continue;
            }
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().display().to_string();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// The tileset's indexes (`.penumbra/index/<product>.json`) with their bytes, by product file:
/// the writer's bookkeeping that [`snapshot`] leaves out, but whose bytes a resumed or sharded
/// run must reproduce too.
pub fn indexes(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let d = dir.join(penumbra::tileset::STATE_DIR).join("index");
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(&d).unwrap() {
        let p = e.unwrap().path();
        // Unit records (what each unit read, for the next run's reuse) also hold each unit's
        // timings: bookkeeping, not an index of the output.
        if p.to_string_lossy().ends_with(".units.json") {
            continue;
        }
        out.insert(
            p.file_name().unwrap().to_string_lossy().into_owned(),
            std::fs::read(&p).unwrap(),
        );
    }
    out
}

/// A GeoTIFF GeoKeyDirectory (version 1.1.0) from (key, location, count, value) entries.
pub fn geokeys(entries: &[(u16, u16, u16, u16)]) -> Vec<u16> {
    let mut v = vec![1, 1, 0, entries.len() as u16];
    for e in entries {
        v.extend([e.0, e.1, e.2, e.3]);
    }
    v
}

/// The GeoKeys of the LOLA Shoemaker product: user-defined south polar stereographic on the
/// 1737400 m sphere (doubles and ASCII params referenced by location 34736/34737).
pub const LOLA_SOUTH_POLAR_KEYS: &[(u16, u16, u16, u16)] = &[
    (1024, 0, 1, 1),
    (1025, 0, 1, 1),
    (2048, 0, 1, 32767),
    (2054, 0, 1, 9102),
    (2056, 0, 1, 32767),
    (2057, 34736, 1, 5),
    (2058, 34736, 1, 6),
    (3072, 0, 1, 32767),
    (3074, 0, 1, 32767),
    (3075, 0, 1, 15),
    (3076, 0, 1, 9001),
    (3081, 34736, 1, 0),
    (3082, 34736, 1, 3),
    (3083, 34736, 1, 4),
    (3092, 34736, 1, 2),
    (3095, 34736, 1, 1),
];

/// Copy a folder tree.
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let t = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &t);
        } else {
            std::fs::copy(e.path(), t).unwrap();
        }
    }
}

/// xorshift64*: deterministic and dependency-free.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [0, 1), 53 bits.
    pub fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [0, 1), 24 bits.
    pub fn unit_f32(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Rough random terrain, `w × h` row-major: octaves of value noise (bilinear between random
/// lattices) from `cells.0`-px cells down to `cells.1`, amplitude `amp` halving per octave,
/// plus white noise of ±`white` metres.
pub fn rough(
    w: usize,
    h: usize,
    amp: f64,
    cells: (usize, usize),
    white: f64,
    seed: u64,
) -> Vec<f32> {
    let mut rng = Rng(seed | 1);
    let mut out = vec![0.0f64; w * h];
    let mut a = amp;
    let mut cell = cells.0;
    while cell >= cells.1.max(1) {
        let (gw, gh) = (w / cell + 2, h / cell + 2);
        let g: Vec<f64> = (0..gw * gh).map(|_| rng.unit() * 2.0 - 1.0).collect();
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f64 / cell as f64, y as f64 / cell as f64);
                let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
                let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
                let v = g[y0 * gw + x0] * (1.0 - tx) * (1.0 - ty)
                    + g[y0 * gw + x0 + 1] * tx * (1.0 - ty)
                    + g[(y0 + 1) * gw + x0] * (1.0 - tx) * ty
                    + g[(y0 + 1) * gw + x0 + 1] * tx * ty;
                out[y * w + x] += a * v;
            }
        }
        a *= 0.5;
        cell /= 2;
    }
    if white > 0.0 {
        for v in out.iter_mut() {
            *v += white * (rng.unit() * 2.0 - 1.0);
        }
    }
    out.into_iter().map(|v| v as f32).collect()
}

/// (rms, max, count) of |a − b| over the entries where both are numbers.
pub fn diff_stats(a: &[f32], b: &[f32]) -> (f64, f64, usize) {
    assert_eq!(a.len(), b.len());
    let (mut ss, mut mx, mut n) = (0.0f64, 0.0f64, 0usize);
    for (x, y) in a.iter().zip(b) {
        if x.is_nan() || y.is_nan() {
            continue;
        }
        let d = (*x as f64 - *y as f64).abs();
        ss += d * d;
        mx = mx.max(d);
        n += 1;
    }
    ((ss / n.max(1) as f64).sqrt(), mx, n)
}

/// Assert that tileset `got` holds `want`'s product files byte for byte and the same indexes
/// (`what` names the run in the failure).
pub fn same_tileset(want: &Path, got: &Path, what: &str) {
    let (w, g) = (
        (snapshot(want), indexes(want)),
        (snapshot(got), indexes(got)),
    );
    assert_eq!(
        w.0.keys().collect::<Vec<_>>(),
        g.0.keys().collect::<Vec<_>>(),
        "{what}: other files than one bake's"
    );
    for (k, v) in &w.0 {
        assert!(g.0[k] == *v, "{what}: {k} differs from one bake's");
    }
    assert_eq!(w.1, g.1, "{what}: indexes differ from one bake's");
}
