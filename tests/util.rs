use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use penumbra::dem::{Crs, Dem, DemParts, GeoRef, Samples};

/// `../shared/data` beside the repository, or `None` (the caller prints a skip message).
pub fn shared_data() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipping: ../shared/data not found (real-DEM checks need it)");
        None
    }
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

pub fn penumbra_bin() -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_penumbra"));
    c.arg("--quiet");
    c
}

/// A DEM over `values` (row-major, `w × h`, metres) placed by `georef`.
pub fn dem_from(georef: GeoRef, w: usize, h: usize, values: Vec<f32>, label: &str) -> Dem {
    Dem::new(
        DemParts {
            width: w,
            height: h,
            samples: Samples::Owned(values),
            scale: 1.0,
            offset: 0.0,
            nodata: None,
            georef,
            datum_radius_m: None,
            target: None,
            sources: vec![],
            format: label.into(),
        },
        64,
    )
    .unwrap()
}

/// Every file below `dir` with its bytes, by relative path.
pub fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
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
