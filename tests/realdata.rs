//! Real DEMs from ../shared/data, tiled and queried at landmarks. "Within the resampling error"
//! is made concrete per point: every interpolated value near a landmark lies within the range
//! of the source samples around it, so the tolerance is that range (the local relief over a few
//! source pixels), measured from the source in the same test.

use std::path::Path;

use penumbra::body::Body;
use penumbra::dem::{self, Dem};
use penumbra::manifest::Tileset;
use penumbra::progress::NoProgress;
use penumbra::query;
use penumbra::tiling::{tile_dem, TileOptions};

use crate::util::shared_data;

/// Range (max − min) of the source samples within `radius_m` (at least 2 source pixels) of
/// (lat, lon): every value a resampling at that scale can produce lies in it.
fn local_range(dem: &Dem, lat: f64, lon: f64, radius_m: f64, body_radius_m: f64) -> f64 {
    let (c, r) = dem.to_pixel(lat, lon);
    let k = (radius_m / dem.pixel_size_m(body_radius_m)).ceil().max(2.0) as i64;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for dr in -k..=k + 1 {
        for dc in -k..=k + 1 {
            let cc = (c.floor() as i64 + dc).clamp(0, dem.width() as i64 - 1) as usize;
            let rr = (r.floor() as i64 + dr).clamp(0, dem.height() as i64 - 1) as usize;
            let (v, _) = dem.value(cc, rr);
            lo = lo.min(v as f64);
            hi = hi.max(v as f64);
        }
    }
    hi - lo
}

fn tile(dem: &Dem, body: &str, out: &Path, tile_size: u32) -> Tileset {
    let opts = TileOptions {
        tile_size,
        ..Default::default()
    };
    let body = Body::preset(body).unwrap();
    tile_dem(dem, &body, out, &opts, None, &NoProgress).unwrap();
    Tileset::load(out).unwrap()
}

/// Query every level at a landmark and check it against the expected height.
/// The tolerance at each level is the source relief within two of that level's pixels.
fn check_landmark(dem: &Dem, out: &Path, levels: u8, lat: f64, lon: f64, expect: f64, what: &str) {
    for level in 0..levels {
        let a = query::height(out, lat, lon, Some(level)).unwrap();
        let tol = local_range(dem, lat, lon, 2.0 * a.level_pixel_m, a.radius_m) + 1.0;
        let err = (a.height_m - expect).abs();
        eprintln!(
            "{what}: level {level} ({:.0} m/px) {:.1} m, expected {expect} m, |err| {err:.1} m, tolerance {tol:.1} m",
            a.level_pixel_m, a.height_m
        );
        assert!(
            err <= tol,
            "{what} at level {level}: {} vs {expect} (tol {tol})",
            a.height_m
        );
    }
}

#[test]
fn ldem4_antoniadi_minimum_and_selenean_summit() {
    let Some(data) = shared_data() else { return };
    let dem = dem::open(&data.join("lola_ldem4/LDEM_4.LBL"), 64).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let ts = tile(&dem, "moon", dir.path(), 256);
    assert_eq!(
        ts.layout.levels, 2,
        "7.58 km source on 256-px tiles: 6.8 km and 3.4 km levels"
    );
    assert_eq!(
        ts.coverage.iter().map(|c| c.tiles).sum::<u64>(),
        6 + 24,
        "whole Moon"
    );
    check_landmark(
        &dem,
        dir.path(),
        2,
        -70.375,
        187.625,
        -8878.5,
        "Antoniadi minimum",
    );
    check_landmark(
        &dem,
        dir.path(),
        2,
        5.375,
        201.375,
        10504.0,
        "Selenean summit",
    );
    let h = ts.products.height.unwrap();
    assert!(
        h.min_m > -8879.0 && h.min_m < -8000.0,
        "tileset min {}",
        h.min_m
    );
    assert!(
        h.max_m < 10504.5 && h.max_m > 9800.0,
        "tileset max {}",
        h.max_m
    );
    // The source's datum is the 1737.4 km sphere: no shift for the Moon preset.
    assert_eq!(ts.source.height_shift_m, 0.0);
}

#[test]
fn megdr_olympus_mons_and_hellas() {
    let Some(data) = shared_data() else { return };
    let dem = dem::open(&data.join("mola_megt90n000cb/megt90n000cb.lbl"), 64).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let ts = tile(&dem, "mars", dir.path(), 512);
    let n = ts.layout.levels;
    check_landmark(
        &dem,
        dir.path(),
        n,
        17.375,
        226.875,
        21134.0,
        "Olympus Mons",
    );
    check_landmark(&dem, dir.path(), n, -32.875, 62.125, -8068.0, "Hellas");
}

#[test]
fn srtm_mauna_kea_with_voids_filled() {
    let Some(data) = shared_data() else { return };
    let dem = dem::open(&data.join("srtm3/N19W156.hgt"), 64).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let ts = tile(&dem, "earth", dir.path(), 512);
    assert_eq!(
        ts.layout.levels, 10,
        "3″ ≈ 92.7 m needs level 9 (48.6 m) on 512-px tiles"
    );
    assert_eq!((ts.source.voids, ts.source.voids_unfilled), (94, 0));
    let h = ts.products.height.as_ref().unwrap();
    assert!(
        h.filled_pixels > 0,
        "void-filled pixels are marked in the mask"
    );
    let finest = ts.layout.levels - 1;
    check_landmark(
        &dem,
        dir.path(),
        ts.layout.levels,
        19.823333,
        -155.469167,
        4205.0,
        "Mauna Kea",
    );
    // Outside the 1°×1° tile there is nothing.
    assert!(query::height(dir.path(), 21.5, -155.5, Some(finest)).is_err());
    // No void reads as zero: every interior height on the island's tiles is finite or NaN+mask 2.
    assert!(
        h.min_m > -100.0,
        "tileset min {} (SRTM voids would read −32768)",
        h.min_m
    );
}

#[test]
fn shoemaker_polar_stereographic_is_georeferenced() {
    let Some(data) = shared_data() else { return };
    let dem = dem::open(
        &data.join("lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif"),
        64,
    )
    .unwrap();
    let (lat, lon) = dem.to_latlon(127.5, 127.5);
    eprintln!("Shoemaker centre: {lat:.4}°, {lon:.4}°");
    assert!((lat + 87.2).abs() < 0.1, "centre latitude {lat}");
    let dir = tempfile::tempdir().unwrap();
    let ts = tile(&dem, "moon", dir.path(), 256);
    let finest = ts.layout.levels - 1;
    let a = query::height(dir.path(), lat, lon, Some(finest)).unwrap();
    assert_eq!(a.face, "nz");
    let (src, _) = dem.sample(lat, lon, dem::Resampling::Bilinear);
    let tol = local_range(&dem, lat, lon, 2.0 * a.level_pixel_m, a.radius_m) + 0.01;
    assert!(
        (a.height_m - src as f64).abs() <= tol,
        "{} vs source {src}",
        a.height_m
    );
}

#[test]
fn gale_raw_sidecar_bradbury_landing() {
    let Some(data) = shared_data() else { return };
    let dem = dem::open(&data.join("mola_gale_128ppd_crop/gale-mola.bin"), 64).unwrap();
    let (lat, lon) = (-4.5895, 137.4417);
    let (h, _) = dem.sample(lat, lon, dem::Resampling::Bilinear);
    assert!(
        (-4520.0..=-4490.0).contains(&h),
        "Bradbury Landing reads {h} m"
    );
    let dir = tempfile::tempdir().unwrap();
    let ts = tile(&dem, "mars", dir.path(), 256);
    check_landmark(
        &dem,
        dir.path(),
        ts.layout.levels,
        lat,
        lon,
        h as f64,
        "Bradbury Landing",
    );
}
