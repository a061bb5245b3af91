use std::collections::BTreeSet;

use penumbra::body::Body;
use penumbra::cube::{self, Face};
use penumbra::dem::{Dem, Resampling};
use penumbra::format::height as tileio;
use penumbra::layout::TileId;
use penumbra::manifest::{self, Tileset};
use penumbra::progress::NoProgress;
use penumbra::tiling::{tile_dem, TileOptions};

use crate::util::{analytic, copy_tree, geographic_dem, global_dem, snapshot};

fn small_opts() -> TileOptions {
    TileOptions {
        tile_size: 32,
        halo: 2,
        levels: Some(3),
        ..Default::default()
    }
}

fn moon() -> Body {
    Body::preset("moon").unwrap()
}

fn tile_with_threads(dem: &Dem, opts: &TileOptions, threads: usize) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| tile_dem(dem, &moon(), dir.path(), opts, None, &NoProgress).unwrap());
    dir
}

#[test]
fn same_bytes_whatever_the_thread_count() {
    let dem = global_dem(720);
    let a = tile_with_threads(&dem, &small_opts(), 1);
    let b = tile_with_threads(&dem, &small_opts(), 3);
    let (sa, sb) = (snapshot(a.path()), snapshot(b.path()));
    assert_eq!(sa.len(), 6 * (1 + 4 + 16) + 1, "126 tiles and the manifest");
    assert_eq!(sa.keys().collect::<Vec<_>>(), sb.keys().collect::<Vec<_>>());
    for (k, v) in &sa {
        assert!(v == &sb[k], "{k} differs between 1 and 3 threads");
    }
}

#[test]
fn reruns_resume_and_stale_tiles_go() {
    let dem = global_dem(360);
    let dir = tempfile::tempdir().unwrap();
    let opts = small_opts();
    let r1 = tile_dem(&dem, &moon(), dir.path(), &opts, None, &NoProgress).unwrap();
    assert_eq!(r1.tiles_written, 126);
    let before = snapshot(dir.path());

    // Unchanged inputs: nothing to do.
    let r2 = tile_dem(&dem, &moon(), dir.path(), &opts, None, &NoProgress).unwrap();
    assert!(r2.up_to_date);

    // An interrupted run (its staging folder holds all tiles but one, no manifest yet)
    // resumes: it keeps what the run wrote and gives the same bytes.
    let again = tempfile::tempdir().unwrap();
    let ts = Tileset::load(dir.path()).unwrap();
    let staged = again.path().join(".penumbra/staging/tile");
    std::fs::create_dir_all(&staged).unwrap();
    copy_tree(&dir.path().join("height"), &staged.join("height"));
    std::fs::write(
        staged.join("run.json"),
        // Staged files are trusted within the boot that wrote them (fsio::write_staged).
        serde_json::json!({ "run_key": ts.run_key, "boot": penumbra::tileset::fsio::boot_id() })
            .to_string(),
    )
    .unwrap();
    std::fs::remove_file(staged.join("height/2/px/1/3.exr")).unwrap();
    let r3 = tile_dem(&dem, &moon(), again.path(), &opts, None, &NoProgress).unwrap();
    assert_eq!((r3.tiles_written, r3.tiles_kept), (1, 125));
    assert_eq!(
        snapshot(again.path()),
        before,
        "a resumed run gives the same bytes"
    );
    assert!(!staged.exists(), "the staging folder goes with the commit");

    // Other parameters: the old tiles are stale and removed.
    let opts2 = TileOptions {
        levels: Some(2),
        ..small_opts()
    };
    let r4 = tile_dem(&dem, &moon(), dir.path(), &opts2, None, &NoProgress).unwrap();
    assert_eq!(r4.tiles_written, 30);
    assert!(!dir.path().join("height/2").exists());
}

#[test]
fn coverage_matches_brute_force_for_a_regional_dem() {
    // 20° × 10° at 0.1°, straddling faces +X and +Y (lon 30..50).
    let dem = geographic_dem(
        (30.0, 20.0),
        (200, 100),
        0.1,
        "regional",
        |_, _, lat, lon| analytic(lat, lon) as f32,
    );
    let dir = tempfile::tempdir().unwrap();
    let opts = TileOptions {
        tile_size: 32,
        halo: 2,
        levels: None,
        ..Default::default()
    };
    let r = tile_dem(&dem, &moon(), dir.path(), &opts, None, &NoProgress).unwrap();
    assert_eq!(
        r.levels, 7,
        "3 km source pixels need level 6 (2.7 km) on 32-px tiles"
    );
    let ts = Tileset::load(dir.path()).unwrap();
    let lay = ts.layout;
    let present = ts.tile_set();
    let finest = lay.levels - 1;
    // Brute force: a finest-level tile is covered when any interior pixel centre is on the DEM.
    let mut expect = BTreeSet::new();
    for face in Face::ALL {
        let per = lay.tiles_per_side(finest);
        for y in 0..per {
            for x in 0..per {
                let id = TileId {
                    level: finest,
                    face,
                    x,
                    y,
                };
                // Cheap reject: the tile centre more than 30° from the region centre.
                let c = lay.pixel_dir(id, 16, 16);
                let rc = cube::latlon_to_dir(15f64.to_radians(), 40f64.to_radians());
                if cube::angle_between(c, rc) > 30f64.to_radians() {
                    continue;
                }
                'px: for j in 0..32 {
                    for i in 0..32 {
                        let (la, lo) = cube::dir_to_latlon(lay.pixel_dir(id, i, j));
                        let (col, row) = dem.to_pixel(la.to_degrees(), lo.to_degrees());
                        if dem.covers(col, row) {
                            expect.insert(id);
                            break 'px;
                        }
                    }
                }
            }
        }
    }
    let got: BTreeSet<TileId> = present
        .iter()
        .filter(|t| t.level == finest)
        .copied()
        .collect();
    assert!(!expect.is_empty());
    assert_eq!(got, expect);
    let faces: BTreeSet<Face> = got.iter().map(|t| t.face).collect();
    assert_eq!(faces, [Face::Px, Face::Py].into_iter().collect());
    // Every coarser tile present is the parent of a finer one.
    for t in &present {
        if t.level < finest {
            assert!(present
                .iter()
                .any(|c| c.level == t.level + 1 && c.parent() == Some(*t)));
        }
    }
    // Pixels off the DEM inside a partial tile are NaN with mask 2, never zero.
    let ts_h = ts.products.height.unwrap();
    assert!(ts_h.no_data_pixels > 0);
    let some = got.iter().next().unwrap();
    let t = tileio::read_height_tile(&penumbra::tileset::tile_path(
        dir.path(),
        manifest::HEIGHT_PATTERN,
        *some,
    ))
    .unwrap();
    for (hgt, m) in t.height.iter().zip(&t.mask) {
        assert_eq!(hgt.is_nan(), *m == penumbra::dem::mask::NO_DATA);
    }
}

#[test]
fn bicubic_beats_bilinear_on_a_smooth_surface() {
    let dem = global_dem(360);
    let mut errs = Vec::new();
    for method in [Resampling::Bilinear, Resampling::Bicubic] {
        let mut worst: f64 = 0.0;
        for k in 0..5000 {
            let la = -80.0 + 160.0 * ((k * 7919) % 5003) as f64 / 5003.0;
            let lo = 360.0 * ((k * 104_729) % 4999) as f64 / 4999.0;
            let (h, _) = dem.sample(la, lo, method);
            worst = worst.max((h as f64 - analytic(la, lo)).abs());
        }
        errs.push(worst);
    }
    assert!(
        errs[1] < 0.5 * errs[0],
        "bicubic {} vs bilinear {}",
        errs[1],
        errs[0]
    );
}

#[test]
fn albedo_tiles_follow_the_height_layout() {
    let dir = tempfile::tempdir().unwrap();
    // 16-bit grey, value = longitude index; left edge at −180°.
    let (w, h) = (720u32, 360u32);
    let img = image::ImageBuffer::from_fn(w, h, |x, _| image::Luma([(x * 90) as u16]));
    let png = dir.path().join("albedo.png");
    img.save(&png).unwrap();
    let out = dir.path().join("ts");
    let opts = TileOptions {
        albedo: Some((png.clone(), -180.0)),
        ..small_opts()
    };
    tile_dem(&global_dem(360), &moon(), &out, &opts, None, &NoProgress).unwrap();
    let ts = Tileset::load(&out).unwrap();
    let a = ts.products.albedo.as_ref().unwrap();
    assert_eq!((a.bit_depth, a.channels), (16, 1));
    // Pixel (10, 20) of tile L1/px/0/1: compare with the column its longitude falls in.
    let id = TileId {
        level: 1,
        face: Face::Px,
        x: 0,
        y: 1,
    };
    let p = penumbra::tileset::tile_path(&out, manifest::ALBEDO_PATTERN, id);
    let img = image::open(&p).unwrap().into_luma16();
    assert_eq!(img.width() as usize, ts.layout.stored_size());
    let (_, lo) = cube::dir_to_latlon(ts.layout.pixel_dir(id, 10, 20));
    let col = (lo.to_degrees() + 180.0) / 360.0 * w as f64 - 0.5;
    let got = img.get_pixel(12, 22)[0] as f64;
    assert!((got - col * 90.0).abs() <= 1.0, "{got} vs {}", col * 90.0);
}

/// With the box prefilter, a pixel `d ≤ 2` levels above the finest is the mean of the
/// `2^d × 2^d` finest-level pixels it covers, leaving out those without data, and is marked
/// filled when any of them is. Checked bit for bit against the finest tiles written, on a
/// regional DEM (so tiles are partly off the data) with a filled void.
#[test]
fn box_levels_are_means_of_the_finest_pixels_they_cover() {
    // 8° × 6° at 0.05°, near lon 44 (face +Y's edge with +X).
    let dem = geographic_dem(
        (40.0, 12.0),
        (160, 120),
        0.05,
        "regional with a void",
        |c, r, lat, lon| {
            let void = (50..53).contains(&r) && (70..74).contains(&c);
            if void {
                f32::NAN
            } else {
                analytic(lat, lon) as f32
            }
        },
    );
    let dir = tempfile::tempdir().unwrap();
    let opts = TileOptions {
        tile_size: 32,
        halo: 2,
        levels: Some(8),
        ..Default::default()
    };
    tile_dem(&dem, &moon(), dir.path(), &opts, None, &NoProgress).unwrap();
    let ts = Tileset::load(dir.path()).unwrap();
    let lay = ts.layout;
    let finest = lay.levels - 1;
    let read = |id: TileId| {
        let p = penumbra::tileset::tile_path(dir.path(), manifest::HEIGHT_PATTERN, id);
        p.exists().then(|| tileio::read_height_tile(&p).unwrap())
    };
    use penumbra::dem::mask;
    let (mut checked, mut partial, mut filled) = (0usize, 0usize, 0usize);
    for id in ts.tile_set() {
        let depth = finest - id.level;
        if depth == 0 || depth > 2 {
            continue;
        }
        let k = 1i64 << depth;
        let coarse = read(id).unwrap();
        let side = coarse.size;
        let mut fine_tiles = std::collections::BTreeMap::new();
        for j in 0..32i64 {
            for i in 0..32i64 {
                let (gx, gy) = lay.global_pixel(id, i, j);
                let (mut sum, mut n, mut any_filled, mut any_void) = (0f64, 0u32, false, false);
                for b in 0..k {
                    for a in 0..k {
                        let (fx, fy) = (gx * k + a, gy * k + b);
                        let fid = TileId {
                            level: finest,
                            face: id.face,
                            x: (fx / 32) as u32,
                            y: (fy / 32) as u32,
                        };
                        let t = fine_tiles.entry(fid).or_insert_with(|| read(fid));
                        let Some(t) = t else {
                            any_void = true;
                            continue;
                        };
                        let at = ((fy % 32 + 2) as usize) * t.size + (fx % 32 + 2) as usize;
                        if t.mask[at] == mask::NO_DATA {
                            any_void = true;
                            continue;
                        }
                        sum += t.height[at] as f64;
                        n += 1;
                        any_filled |= t.mask[at] == mask::FILLED;
                    }
                }
                let at = (j as usize + 2) * side + i as usize + 2;
                let (hgt, m) = (coarse.height[at], coarse.mask[at]);
                if n == 0 {
                    assert_eq!(m, mask::NO_DATA, "{id:?} ({i}, {j})");
                    assert!(hgt.is_nan());
                    continue;
                }
                let expect = (sum / n as f64) as f32;
                assert_eq!(hgt.to_bits(), expect.to_bits(), "{id:?} ({i}, {j})");
                let want = if any_filled {
                    mask::FILLED
                } else {
                    mask::MEASURED
                };
                assert_eq!(m, want, "{id:?} ({i}, {j})");
                checked += 1;
                partial += any_void as usize;
                filled += any_filled as usize;
            }
        }
    }
    assert!(checked > 1000, "only {checked} pixels checked");
    assert!(partial > 0, "no pixel averaged over the edge of the data");
    assert!(filled > 0, "no pixel averaged over the filled void");
}
