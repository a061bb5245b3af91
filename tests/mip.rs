//! Mipmaps: conservative bounds of the interpolated surface at every level, equality with a
//! naive sequential reference, the face pyramid across tiles, determinism, bad input, the CLI.

use std::path::Path;
use std::process::Output;

use penumbra::body::Body;
use penumbra::dem;
use penumbra::format::height::{self as tileio, HeightTile};
use penumbra::layout::TileId;
use penumbra::manifest::Tileset;
use penumbra::mip::{self, MipOptions, Precision};
use penumbra::progress::NoProgress;
use penumbra::tiling::{tile_dem, TileOptions};

use crate::util::{analytic, geographic_dem, global_dem, penumbra_bin, shared_data, snapshot, Rng};

fn same(a: f32, b: f32) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

/// The reference: for each texel of each level, the extreme over every stored sample of its
/// whole footprint — level-0 texels (x·2^k .. min((x+1)·2^k, n)−1) widened by one sample on
/// each side — plainly, one texel at a time.
fn reference(h: &[f32], s: usize, halo: usize) -> (Vec<usize>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let n = s - 2 * halo;
    let mut sizes = vec![n];
    while *sizes.last().unwrap() > 1 {
        let w = *sizes.last().unwrap();
        sizes.push(w.div_ceil(2));
    }
    let (mut lo, mut hi) = (Vec::new(), Vec::new());
    for (k, &w) in sizes.iter().enumerate() {
        let (mut l, mut u) = (vec![f32::NAN; w * w], vec![f32::NAN; w * w]);
        for y in 0..w {
            for x in 0..w {
                let (i0, i1) = (x << k, ((x + 1) << k).min(n) - 1);
                let (j0, j1) = (y << k, ((y + 1) << k).min(n) - 1);
                let (mut a, mut b) = (f32::NAN, f32::NAN);
                for j in j0 + halo - 1..=j1 + halo + 1 {
                    for i in i0 + halo - 1..=i1 + halo + 1 {
                        let v = h[j * s + i];
                        if v.is_nan() {
                            continue;
                        }
                        if a.is_nan() || v < a {
                            a = v;
                        }
                        if b.is_nan() || v > b {
                            b = v;
                        }
                    }
                }
                l[y * w + x] = a;
                u[y * w + x] = b;
            }
        }
        lo.push(l);
        hi.push(u);
    }
    (sizes, lo, hi)
}

/// Kernels = reference, max pyramid = max channel of the min/max pyramid.
fn check_exact(h: &[f32], s: usize, halo: usize, what: &str) {
    let mm = mip::minmax_pyramid(h, s, halo).unwrap();
    let mx = mip::max_pyramid(h, s, halo).unwrap();
    let (sizes, lo, hi) = reference(h, s, halo);
    assert_eq!(mm.sizes, sizes, "{what}");
    assert_eq!(mx.sizes, sizes, "{what}");
    for k in 0..sizes.len() {
        for t in 0..sizes[k] * sizes[k] {
            assert!(
                same(mm.min[k][t], lo[k][t]),
                "{what}: min level {k} texel {t}"
            );
            assert!(
                same(mm.max[k][t], hi[k][t]),
                "{what}: max level {k} texel {t}"
            );
            assert!(
                same(mx.max[k][t], hi[k][t]),
                "{what}: max-only level {k} texel {t}"
            );
        }
    }
}

/// Every bilinear height sampled densely (9×9 points per level-0 footprint, its edges — which
/// reach into the halo for edge texels — included) lies within every level's texel above it.
fn check_bounds(tile: &HeightTile, halo: usize, lo: &[Vec<f32>], hi: &[Vec<f32>], what: &str) {
    let n = tile.size - 2 * halo;
    let sizes = mip::level_sizes(n);
    for j in 0..n {
        for i in 0..n {
            for b in 0..9 {
                for a in 0..9 {
                    let x = i as f64 - 0.5 + a as f64 / 8.0 + halo as f64;
                    let y = j as f64 - 0.5 + b as f64 / 8.0 + halo as f64;
                    let v = tile.bilinear(x, y);
                    if v.is_nan() {
                        continue;
                    }
                    for (k, &w) in sizes.iter().enumerate() {
                        let t = (j >> k) * w + (i >> k);
                        assert!(
                            lo[k][t] <= v && v <= hi[k][t],
                            "{what}: level {k} texel ({}, {}) [{}, {}] misses {v} at ({x}, {y})",
                            i >> k,
                            j >> k,
                            lo[k][t],
                            hi[k][t]
                        );
                    }
                }
            }
        }
    }
}

fn tile_of(h: Vec<f32>, s: usize) -> HeightTile {
    HeightTile {
        size: s,
        mask: vec![0; s * s],
        height: h,
    }
}

fn terrain(kind: &str, s: usize, rng: &mut Rng) -> Vec<f32> {
    let mut h = vec![0.0f32; s * s];
    for j in 0..s {
        for i in 0..s {
            let (x, y) = (i as f32 / s as f32, j as f32 / s as f32);
            h[j * s + i] = match kind {
                "constant" => 1234.5,
                "smooth" => 2000.0 * (7.0 * x).sin() * (5.0 * y).cos() + 30.0 * rng.unit_f32(),
                "noise" => 20000.0 * (rng.unit_f32() - 0.5),
                "spikes" => {
                    if rng.unit_f32() < 0.02 {
                        9000.0 * (rng.unit_f32() - 0.3)
                    } else {
                        -500.0 + 10.0 * rng.unit_f32()
                    }
                }
                "holes" => {
                    let hole = (x - 0.4).powi(2) + (y - 0.6).powi(2) < 0.05;
                    if hole || rng.unit_f32() < 0.1 {
                        f32::NAN
                    } else {
                        -8000.0 + 29000.0 * rng.unit_f32()
                    }
                }
                "all-nan" => f32::NAN,
                _ => unreachable!(),
            };
        }
    }
    h
}

#[test]
fn random_terrains_are_bounded_and_match_the_reference() {
    let mut rng = Rng(0x1234_5678_9ABC_DEF1);
    // (tile size, halo): powers of two, even non-powers (24, 10: odd levels 3 and 5), halo 1..3.
    for (n, halo) in [(8, 1), (16, 2), (24, 2), (10, 1), (64, 2), (30, 3)] {
        let s = n + 2 * halo;
        for kind in ["constant", "smooth", "noise", "spikes", "holes", "all-nan"] {
            let h = terrain(kind, s, &mut rng);
            let what = format!("{kind} {n}+2·{halo}");
            check_exact(&h, s, halo, &what);
            let mm = mip::minmax_pyramid(&h, s, halo).unwrap();
            check_bounds(&tile_of(h.clone(), s), halo, &mm.min, &mm.max, &what);
            match kind {
                "constant" => assert!(mm
                    .min
                    .iter()
                    .chain(&mm.max)
                    .all(|l| l.iter().all(|&v| v == 1234.5))),
                "all-nan" => assert!(mm
                    .min
                    .iter()
                    .chain(&mm.max)
                    .all(|l| l.iter().all(|v| v.is_nan()))),
                "holes" => {
                    // NaN never wins: where a footprint has data the texel has data.
                    let (_, lo, _) = reference(&h, s, halo);
                    assert!(lo[0].iter().zip(&mm.min[0]).all(|(r, m)| same(*r, *m)));
                    assert!(!mm.max.last().unwrap()[0].is_nan());
                }
                _ => {}
            }
        }
    }
}

#[test]
fn a_one_pixel_spike_appears_at_every_level_above_it() {
    let (n, halo) = (32usize, 2usize);
    let s = n + 2 * halo;
    // Interior pixels, a halo sample next to the edge, and the corner of the halo ring.
    for (si, sj) in [
        (halo + 5, halo + 17),
        (halo, halo + n - 1),
        (halo - 1, halo + 3),
        (0, 0),
    ] {
        let mut h = vec![100.0f32; s * s];
        h[sj * s + si] = 5000.0;
        let mut low = h.clone();
        low[sj * s + si] = -5000.0;
        let mm = mip::minmax_pyramid(&h, s, halo).unwrap();
        let ml = mip::minmax_pyramid(&low, s, halo).unwrap();
        let sizes = mip::level_sizes(n);
        // Level-0 texels whose 3×3 samples include the spike.
        let mut hits = 0;
        for j in 0..n {
            for i in 0..n {
                let inside = (i + halo).abs_diff(si) <= 1 && (j + halo).abs_diff(sj) <= 1;
                if !inside {
                    continue;
                }
                hits += 1;
                for (k, &w) in sizes.iter().enumerate() {
                    let t = (j >> k) * w + (i >> k);
                    assert_eq!(mm.max[k][t], 5000.0, "spike at ({si},{sj}) level {k}");
                    assert_eq!(ml.min[k][t], -5000.0, "pit at ({si},{sj}) level {k}");
                }
            }
        }
        if (si, sj) == (0, 0) {
            // Outside every footprint (halo 2: only the halo ring next to the interior counts).
            assert_eq!(hits, 0);
            assert_eq!(mm.max.last().unwrap()[0], 100.0);
        } else {
            assert!(hits > 0);
            assert_eq!(mm.max.last().unwrap()[0], 5000.0);
        }
    }
}

#[test]
fn bad_buffers_are_refused() {
    assert!(mip::max_pyramid(&[0.0; 16], 4, 0).is_err());
    assert!(mip::max_pyramid(&[0.0; 15], 4, 1).is_err());
    assert!(mip::minmax_pyramid(&[0.0; 16], 4, 2).is_err());
}

#[test]
fn f16_bounds_still_bound_the_f32_values() {
    let mut rng = Rng(42);
    let mut xs: Vec<f32> = (0..200_000)
        .map(|_| (rng.unit_f32() - 0.3) * 30000.0 * rng.unit_f32().powi(3))
        .collect();
    xs.extend([
        0.0, -0.0, 1e-9, -1e-9, 65504.0, 65505.0, 65520.0, 1e6, -1e6, 21229.0, -8068.0,
    ]);
    for x in xs {
        let (u, d) = (mip::f16_up(x).to_f32(), mip::f16_down(x).to_f32());
        assert!(u >= x && d <= x, "{x}: down {d} up {u}");
        // Tight: the neighbour beyond the bound would not bound.
        if x.abs() <= 65504.0 {
            let next_down = half::f16::from_bits(mip::f16_up(x).to_bits().wrapping_sub(1));
            if u != x && u > 0.0 && x > 0.0 {
                assert!(next_down.to_f32() < x, "{x}: {u} not the smallest");
            }
        }
        // 16 m or finer up to 32 km (Mars −8..+21 km; Earth too).
        if x.abs() < 32768.0 {
            assert!(u - d <= 16.0, "{x}: {d}..{u}");
        }
    }
    assert!(mip::f16_up(f32::NAN).is_nan() && mip::f16_down(f32::NAN).is_nan());
}

fn small_tileset(dir: &Path) {
    let opts = TileOptions {
        tile_size: 32,
        halo: 2,
        levels: Some(3),
        ..Default::default()
    };
    let moon = Body::preset("moon").unwrap();
    tile_dem(&global_dem(360), &moon, dir, &opts, None, &NoProgress).unwrap();
}

fn copy_dir(from: &Path, to: &Path) {
    for (rel, bytes) in snapshot(from) {
        let p = to.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }
}

/// Files and the face pyramids of a built tileset against the reference and the surface.
fn check_tileset(dir: &Path, bounds: bool) {
    let ts = Tileset::load(dir).unwrap();
    let m = ts
        .products
        .mip
        .clone()
        .expect("mip product in the manifest");
    assert_eq!(m.products, ["max", "minmax"]);
    let (n, halo, s) = (
        ts.layout.tile_size as usize,
        ts.layout.halo as usize,
        ts.layout.stored_size(),
    );
    let (mut gmin, mut gmax) = (f32::INFINITY, f32::NEG_INFINITY);
    for id in ts.tile_set() {
        let hp = penumbra::tileset::tile_path(dir, "height/{level}/{face}/{y}/{x}.exr", id);
        let t = tileio::read_height_tile(&hp).unwrap();
        let (pmax, pmm) = mip::tile_paths(dir, id);
        let fmax = mip::read_mip_exr(&pmax).unwrap();
        let fmm = mip::read_mip_exr(&pmm).unwrap();
        let (sizes, lo, hi) = reference(&t.height, s, halo);
        assert_eq!(fmm.sizes, sizes);
        let what = format!("{id}");
        for (k, _) in sizes.iter().enumerate() {
            for (a, b) in fmm.channels["min"][k].iter().zip(&lo[k]) {
                assert!(same(*a, *b), "{what} min level {k}");
            }
            for (a, b) in fmm.channels["max"][k].iter().zip(&hi[k]) {
                assert!(same(*a, *b), "{what} max level {k}");
            }
            assert_eq!(
                fmax.channels["max"][k]
                    .iter()
                    .map(|v| v.to_bits())
                    .collect::<Vec<_>>(),
                fmm.channels["max"][k]
                    .iter()
                    .map(|v| v.to_bits())
                    .collect::<Vec<_>>()
            );
        }
        gmin = gmin.min(lo.last().unwrap()[0]);
        gmax = gmax.max(hi.last().unwrap()[0]);
        if bounds {
            check_bounds(&t, halo, &fmm.channels["min"], &fmm.channels["max"], &what);
        }
        // Face pyramid: every interpolated height of the tile (edges included, so points shared
        // with the neighbouring tiles) lies within every face texel above the tile.
        let fp = mip::read_mip_exr(&mip::face_path(dir, id.level, id.face)).unwrap();
        assert_eq!(fp.sizes[0], 1 << id.level);
        for (f, &w) in fp.sizes.iter().enumerate() {
            let k = (id.y as usize >> f) * w + (id.x as usize >> f);
            let (a, b) = (fp.channels["min"][f][k], fp.channels["max"][f][k]);
            assert!(
                a <= lo.last().unwrap()[0] && hi.last().unwrap()[0] <= b,
                "{what} face level {f}"
            );
            for q in 0..=16 * n {
                for (x, y) in [
                    (q as f64 / 16.0 - 0.5, -0.5),
                    (q as f64 / 16.0 - 0.5, n as f64 - 0.5),
                    (-0.5, q as f64 / 16.0 - 0.5),
                    (n as f64 - 0.5, q as f64 / 16.0 - 0.5),
                    (q as f64 / 16.0 - 0.5, q as f64 / 16.0 - 0.5),
                ] {
                    let v = t.bilinear(x + halo as f64, y + halo as f64);
                    assert!(
                        v.is_nan() || (a <= v && v <= b),
                        "{what} face level {f}: {v}"
                    );
                }
            }
        }
    }
    assert_eq!(m.global_min_m, gmin as f64);
    assert_eq!(m.global_max_m, gmax as f64);
}

#[test]
fn a_tileset_matches_the_reference_and_the_face_pyramids_bound_it() {
    let dir = tempfile::tempdir().unwrap();
    small_tileset(dir.path());
    let r = mip::build_mips(dir.path(), &MipOptions::default(), &NoProgress).unwrap();
    assert_eq!((r.tiles, r.tiles_written), (126, 126));
    assert_eq!(r.face_pyramids, 18);
    check_tileset(dir.path(), true);
    // A rerun is a no-op; older manifests without the key still load.
    let r = mip::build_mips(dir.path(), &MipOptions::default(), &NoProgress).unwrap();
    assert!(r.up_to_date);
    let mp = dir.path().join("tileset.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&mp).unwrap()).unwrap();
    v["products"].as_object_mut().unwrap().remove("mip");
    let old = dir.path().join("old");
    std::fs::create_dir(&old).unwrap();
    std::fs::write(old.join("tileset.json"), v.to_string()).unwrap();
    assert!(Tileset::load(&old).unwrap().products.mip.is_none());
}

#[test]
fn same_bytes_whatever_the_thread_count() {
    let base = tempfile::tempdir().unwrap();
    small_tileset(base.path());
    let mut snaps = Vec::new();
    for threads in [1, 2] {
        let d = tempfile::tempdir().unwrap();
        copy_dir(base.path(), d.path());
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| mip::build_mips(d.path(), &MipOptions::default(), &NoProgress).unwrap());
        snaps.push(snapshot(d.path()));
    }
    assert_eq!(snaps[0].len(), 126 * 3 + 3 * 6 + 1);
    assert_eq!(
        snaps[0].keys().collect::<Vec<_>>(),
        snaps[1].keys().collect::<Vec<_>>()
    );
    for (k, v) in &snaps[0] {
        assert!(v == &snaps[1][k], "{k} differs between 1 and 2 threads");
    }
}

#[test]
fn f16_files_bound_the_f32_files() {
    let a = tempfile::tempdir().unwrap();
    small_tileset(a.path());
    let b = tempfile::tempdir().unwrap();
    copy_dir(a.path(), b.path());
    mip::build_mips(a.path(), &MipOptions::default(), &NoProgress).unwrap();
    let opts = MipOptions {
        precision: Precision::F16,
        ..Default::default()
    };
    mip::build_mips(b.path(), &opts, &NoProgress).unwrap();
    let ts = Tileset::load(b.path()).unwrap();
    assert_eq!(ts.products.mip.as_ref().unwrap().precision, Precision::F16);
    for id in ts.tile_set().into_iter().filter(|t| t.level == 2).take(20) {
        let (_, p32) = mip::tile_paths(a.path(), id);
        let (_, p16) = mip::tile_paths(b.path(), id);
        let (f32_, f16_) = (
            mip::read_mip_exr(&p32).unwrap(),
            mip::read_mip_exr(&p16).unwrap(),
        );
        for k in 0..f32_.sizes.len() {
            for (x, h) in f32_.channels["max"][k].iter().zip(&f16_.channels["max"][k]) {
                assert!(same(*x, *h) || h >= x);
                assert!(h - x <= 16.0 || x.is_nan());
            }
            for (x, h) in f32_.channels["min"][k].iter().zip(&f16_.channels["min"][k]) {
                assert!(same(*x, *h) || h <= x);
            }
        }
    }
}

/// A regional tileset (lat −20..20, lon 20..70: two faces, partly covered) of 8-px tiles on
/// 5 levels: 16 tiles per face side at the finest.
fn regional_tileset(dir: &Path) {
    let opts = TileOptions {
        tile_size: 8,
        halo: 2,
        levels: Some(5),
        ..Default::default()
    };
    let moon = Body::preset("moon").unwrap();
    let dem = geographic_dem(
        (20.0, 20.0),
        (200, 160),
        0.25,
        "regional test raster",
        |_, _, lat, lon| analytic(lat, lon) as f32,
    );
    tile_dem(&dem, &moon, dir, &opts, None, &NoProgress).unwrap();
}

/// Face pyramids cut into chunks of 4 tiles per side (1024 in production) answer every texel
/// of every level exactly as the one-file pyramids, through `query::face_texel` and through
/// `query::mip` at every tile; the files are where the manifest says.
#[test]
fn chunked_face_pyramids_answer_as_the_dense_ones() {
    use penumbra::cube::Face;
    use penumbra::query;
    let a = tempfile::tempdir().unwrap();
    regional_tileset(a.path());
    let b = tempfile::tempdir().unwrap();
    copy_dir(a.path(), b.path());
    let (a, b) = (a.path(), b.path());
    mip::build_mips(a, &MipOptions::default(), &NoProgress).unwrap();
    let opts = MipOptions {
        face_chunk_tiles: 4,
        ..Default::default()
    };
    let rb = mip::build_mips(b, &opts, &NoProgress).unwrap();
    let (ta, tb) = (Tileset::load(a).unwrap(), Tileset::load(b).unwrap());
    let sb = penumbra::tileset::Store::open(b).unwrap();
    let (ma, mb) = (
        ta.products.mip.clone().unwrap(),
        tb.products.mip.clone().unwrap(),
    );
    // The dense tileset's manifest has no chunk keys at all (shallow manifests are unchanged).
    assert!(ma.face_chunk_path.is_none() && ma.face_chunk_tiles.is_none());
    let text = std::fs::read_to_string(a.join("tileset.json")).unwrap();
    assert!(!text.contains("face_chunk"));
    assert_eq!(mb.face_chunk_path.as_deref(), Some(mip::FACE_CHUNK_PATTERN));
    assert_eq!(mb.face_chunk_tiles, Some(4));
    assert_eq!(
        (ma.global_min_m, ma.global_max_m),
        (mb.global_min_m, mb.global_max_m)
    );
    assert_eq!(ma.levels, mb.levels);

    let mut chunk_files = 0;
    let mut compared = 0;
    for level in 0..ta.layout.levels {
        let g = ta.layout.tiles_per_side(level);
        for face in Face::ALL {
            let dense = mip::face_path(a, level, face);
            assert_eq!(dense.exists(), mip::face_path(b, level, face).exists());
            if !dense.exists() {
                continue;
            }
            let fp = mip::read_mip_exr(&dense).unwrap();
            let coarse = mip::read_mip_exr(&mip::face_path(b, level, face)).unwrap();
            assert_eq!(coarse.sizes[0] as u32, if g > 4 { g / 4 } else { g });
            for (fl, &w) in fp.sizes.iter().enumerate() {
                for y in 0..w {
                    for x in 0..w {
                        let (tx, ty) = ((x << fl) as u32, (y << fl) as u32);
                        let t = query::face_texel(&sb, level, face, fl as u32, tx, ty).unwrap();
                        let k = y * w + x;
                        let what = format!("L{level} {face} f{fl} ({x}, {y})");
                        assert_eq!(
                            t.min.to_bits(),
                            fp.channels["min"][fl][k].to_bits(),
                            "{what}"
                        );
                        assert_eq!(
                            t.max.to_bits(),
                            fp.channels["max"][fl][k].to_bits(),
                            "{what}"
                        );
                        assert_eq!(t.texels as usize, w, "{what}");
                        let in_chunk = g > 4 && fl < 2;
                        let name = t.file.file_name().unwrap().to_str().unwrap().to_string();
                        assert!(in_chunk || name == "face.exr", "{what}: {name}");
                        compared += 1;
                    }
                }
            }
            // One chunk file per chunk with a tile, 4² at level 0.
            if g > 4 {
                let mut chunks = std::collections::BTreeSet::new();
                for id in ta
                    .tile_set()
                    .iter()
                    .filter(|t| t.level == level && t.face == face)
                {
                    chunks.insert((id.x / 4, id.y / 4));
                }
                for cy in 0..g / 4 {
                    for cx in 0..g / 4 {
                        let p = mip::face_chunk_path(b, level, face, cx, cy);
                        assert_eq!(p.exists(), chunks.contains(&(cx, cy)), "{}", p.display());
                        if p.exists() {
                            assert_eq!(mip::read_mip_exr(&p).unwrap().sizes, [4, 2, 1]);
                            chunk_files += 1;
                        }
                    }
                }
                assert!(chunks.len() > 1 && chunks.len() < (g as usize / 4).pow(2));
            }
        }
    }
    assert_eq!(rb.face_chunks, chunk_files);
    assert!(
        chunk_files >= 4 && compared > 500,
        "{chunk_files} {compared}"
    );

    // `query mip` at a pixel of every tile, every face-pyramid level: the same answers.
    let n = ta.layout.tile_size as i64;
    let m = mip::level_sizes(n as usize).len() as u32;
    for id in ta.tile_set() {
        let (lat, lon) = penumbra::cube::dir_to_latlon(ta.layout.pixel_dir(id, n / 2, n / 2));
        let (lat, lon) = (lat.to_degrees(), lon.to_degrees());
        for level in m - 1..=m - 1 + id.level as u32 {
            let qa = query::mip(a, lat, lon, level, Some(id.level)).unwrap();
            let qb = query::mip(b, lat, lon, level, Some(id.level)).unwrap();
            let key = |q: &query::MipAnswer| {
                (q.min_m, q.max_m, q.texel, q.texels, q.scope.clone(), q.tile)
            };
            assert_eq!(key(&qa), key(&qb), "{id} level {level}");
        }
    }

    // A damaged chunk pattern or size is refused when the tileset is opened.
    let mp = b.join("tileset.json");
    let good: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&mp).unwrap()).unwrap();
    for (key, bad) in [
        (
            "face_chunk_path",
            serde_json::json!("height/{level}/{face}/{cy}/{cx}.exr"),
        ),
        (
            "face_chunk_path",
            serde_json::json!("minmax/{level}/{face}/{cx}.exr"),
        ),
        (
            "face_chunk_path",
            serde_json::json!("minmax/../{level}/{face}/{cy}/{cx}.exr"),
        ),
        ("face_chunk_tiles", serde_json::json!(3)),
        ("face_chunk_tiles", serde_json::json!(0)),
    ] {
        let mut v = good.clone();
        v["products"]["mip"][key] = bad.clone();
        std::fs::write(&mp, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
        let e = penumbra::tileset::Store::open(b).err();
        assert!(e.is_some(), "{key} = {bad} accepted");
    }
    std::fs::write(&mp, serde_json::to_vec_pretty(&good).unwrap()).unwrap();
    assert!(penumbra::tileset::Store::open(b).is_ok());
}

#[test]
fn a_corrupt_height_tile_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    small_tileset(dir.path());
    let id = TileId {
        level: 1,
        face: penumbra::cube::Face::ALL[2],
        x: 1,
        y: 0,
    };
    let p = penumbra::tileset::tile_path(dir.path(), "height/{level}/{face}/{y}/{x}.exr", id);
    std::fs::write(&p, b"\x76\x2f\x31\x01 truncated").unwrap();
    let e = mip::build_mips(dir.path(), &MipOptions::default(), &NoProgress)
        .unwrap_err()
        .to_string();
    assert!(e.contains(&p.display().to_string()), "{e}");
    let o = penumbra_bin()
        .args(["mip", dir.path().to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("0/1.exr") && !err.contains("panicked"),
        "{err}"
    );
    assert!(Tileset::load(dir.path()).unwrap().products.mip.is_none());
}

#[test]
fn real_tiles_match_the_reference() {
    let Some(data) = shared_data() else {
        return;
    };
    let lbl = data.join("lola_ldem4/LDEM_4.LBL");
    let dem = dem::open(&lbl, dem::DEFAULT_MAX_FILL_PX).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let opts = TileOptions {
        tile_size: 64,
        halo: 2,
        levels: Some(2),
        ..Default::default()
    };
    tile_dem(
        &dem,
        &Body::preset("moon").unwrap(),
        dir.path(),
        &opts,
        None,
        &NoProgress,
    )
    .unwrap();
    mip::build_mips(dir.path(), &MipOptions::default(), &NoProgress).unwrap();
    check_tileset(dir.path(), true);
    let m = Tileset::load(dir.path()).unwrap().products.mip.unwrap();
    // LDEM_4 spans about −9.1 km (Antoniadi) .. +10.8 km (Selenean summit); 64-px tiles on
    // 2 levels are coarser than the source and box-filtered.
    assert!(m.global_min_m < -7000.0 && m.global_max_m > 9000.0, "{m:?}");
}

fn json(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn cli_mip_and_query_mip() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles");
    let o = out.to_str().unwrap();
    let run = |args: &[&str]| penumbra_bin().args(args).output().unwrap();
    let r = json(&run(&[
        "bake",
        "--out",
        o,
        "--scene-size",
        "1024",
        "--levels",
        "3",
        "--no-horizons",
        "--json",
    ]));
    assert_eq!(r["stages"], serde_json::json!(["tile", "mip"]));
    assert_eq!(r["mip"]["up_to_date"], false);
    let r = json(&run(&["mip", o, "--json"]));
    assert_eq!(r["up_to_date"], true);

    // The texel bounds the height there, at every level, and widens going up.
    let h = json(&run(&[
        "query", "height", o, "--lat", "-89.95", "--lon", "260", "--json",
    ]))["height_m"]
        .as_f64()
        .unwrap();
    let mut prev = (f64::INFINITY, f64::NEG_INFINITY);
    for k in 0..=11 {
        let q = json(&run(&[
            "query",
            "mip",
            o,
            "--lat",
            "-89.95",
            "--lon",
            "260",
            "--level",
            &k.to_string(),
            "--json",
        ]));
        let (lo, hi) = (q["min_m"].as_f64().unwrap(), q["max_m"].as_f64().unwrap());
        assert!(lo <= h && h <= hi, "level {k}: {q}");
        assert!(
            lo <= prev.0 && hi >= prev.1,
            "level {k} narrower than {}",
            k - 1
        );
        assert_eq!(q["scope"], if k <= 9 { "tile" } else { "face" });
        prev = (lo, hi);
    }
    let ts = Tileset::load(&out).unwrap();
    assert_eq!(
        prev,
        (
            ts.products.mip.as_ref().unwrap().global_min_m,
            ts.products.mip.as_ref().unwrap().global_max_m
        )
    );
    let q = json(&run(&[
        "query",
        "mip",
        o,
        "--lat",
        "-89.95",
        "--lon",
        "260",
        "--level",
        "2",
        "--tile-level",
        "0",
        "--json",
    ]));
    assert_eq!(
        (q["tile_level"].as_u64(), q["texels"].as_u64()),
        (Some(0), Some(128))
    );

    // Coverage gaps: the face pyramid is NaN where tiles are absent.
    let fp = mip::read_mip_exr(&mip::face_path(&out, 2, penumbra::cube::Face::ALL[5])).unwrap();
    let present = ts.tile_set().iter().filter(|t| t.level == 2).count();
    assert_eq!(
        fp.channels["max"][0].iter().filter(|v| !v.is_nan()).count(),
        present
    );
    assert!(present < 16);

    // Bad requests: exit 2 with a reason.
    let e = run(&[
        "query", "mip", o, "--lat", "-89.95", "--lon", "260", "--level", "12",
    ]);
    assert_eq!(e.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&e.stderr).contains("0..=11"));
    let e = run(&[
        "query", "mip", o, "--lat", "10", "--lon", "10", "--level", "0",
    ]);
    assert_eq!(e.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&e.stderr).contains("no height tile covers"));

    // f16 on request: a rerun, and the bounds widen.
    let r = json(&run(&["mip", o, "--precision", "f16", "--json"]));
    assert_eq!(
        (r["up_to_date"].as_bool(), r["precision"].as_str()),
        (Some(false), Some("f16"))
    );
    let q = json(&run(&[
        "query", "mip", o, "--lat", "-89.95", "--lon", "260", "--level", "11", "--json",
    ]));
    assert!(q["min_m"].as_f64().unwrap() <= prev.0 && q["max_m"].as_f64().unwrap() >= prev.1);
}
