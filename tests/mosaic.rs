//! Several DEMs tiled as one surface (`tiling::tile_sources`, issue 35): the finest source with
//! data wins, feathered into the coarser one with no cliff at the border (a synthetic pair with
//! a known answer, and LDEM_4 + the Shoemaker 5 m DEM), the mipmaps of the result, a wanted
//! tile set, the horizons across the seam, and sources of different bodies refused.

use std::collections::{BTreeSet, HashMap};
use std::path::Path;

use penumbra::body::Body;
use penumbra::cube::{self, Face};
use penumbra::dem::{self, mask, Dem};
use penumbra::layout::{Layout, TileId};
use penumbra::manifest::Tileset;
use penumbra::mip::{self, MipOptions};
use penumbra::progress::NoProgress;
use penumbra::tileset::Store;
use penumbra::tiling::{tile_dem, tile_sources, MosaicSource, TileOptions};

use crate::util::{analytic, geographic_dem, global_dem, shared_data, snapshot};

fn moon() -> Body {
    Body::preset("moon").unwrap()
}

fn tile_mosaic(
    sources: &[(&Dem, f64)],
    out: &Path,
    opts: &TileOptions,
    wanted: Option<&BTreeSet<TileId>>,
) -> penumbra::error::Result<penumbra::tiling::TileReport> {
    let s: Vec<MosaicSource> = sources
        .iter()
        .map(|&(dem, feather_px)| MosaicSource { dem, feather_px })
        .collect();
    tile_sources(&s, &moon(), out, opts, None, wanted, &NoProgress)
}

/// Every interior pixel of the level-`level` tiles of the tileset in `dir`, by face and global
/// face pixel: (height, mask).
fn face_pixels(dir: &Path, level: u8) -> HashMap<(Face, i64, i64), (f32, u8)> {
    let store = Store::open(dir).unwrap();
    let ts = store.manifest().clone();
    let (n, h) = (ts.layout.tile_size as i64, ts.layout.halo as usize);
    let mut out = HashMap::new();
    for id in ts.tile_set().into_iter().filter(|t| t.level == level) {
        let t = store.height(id).unwrap().unwrap();
        for j in 0..n {
            for i in 0..n {
                let k = (j as usize + h) * t.size + i as usize + h;
                out.insert(
                    (id.face, id.x as i64 * n + i, id.y as i64 * n + j),
                    (t.height[k], t.mask[k]),
                );
            }
        }
    }
    out
}

/// Latitude and longitude (degrees) of global face pixel (gx, gy) at `level`.
fn latlon(layout: &Layout, level: u8, face: Face, gx: i64, gy: i64) -> (f64, f64) {
    let (s, t) = layout.global_st(level, gx as f64, gy as f64);
    let (la, lo) = cube::dir_to_latlon(layout.st_to_dir(face, s, t));
    (la.to_degrees(), lo.to_degrees())
}

/// Global face pixel of (lat, lon) at `level`.
fn face_pixel(layout: &Layout, level: u8, lat: f64, lon: f64) -> (Face, i64, i64) {
    let d = cube::latlon_to_dir(lat.to_radians(), lon.to_radians());
    let l = layout.locate(level, d);
    let n = layout.tile_size as i64;
    (
        l.tile.face,
        l.tile.x as i64 * n + l.px.round() as i64,
        l.tile.y as i64 * n + l.py.round() as i64,
    )
}

const OFFSET_M: f64 = 500.0;

/// The coarse source: 6° × 6° of 0.05° pixels of the analytic surface raised by `OFFSET_M`.
fn coarse() -> Dem {
    geographic_dem((17.0, 13.0), (120, 120), 0.05, "coarse", |_, _, la, lo| {
        (analytic(la, lo) + OFFSET_M) as f32
    })
}

/// The fine source: the analytic surface itself, 1.6° × 1.6° of 0.01° pixels (303 m on the
/// Moon) inside the coarse one; its east border is at 20.8°E.
fn fine() -> Dem {
    geographic_dem((19.2, 10.8), (160, 160), 0.01, "fine", |_, _, la, lo| {
        analytic(la, lo) as f32
    })
}

/// Across the fine source's east border, along a row of finest-level pixels at 10°N: deep
/// inside the mosaic is the fine source bit for bit, beyond it the coarse one bit for bit; in
/// between the fine source's share falls monotonically from 1 to 0, and no step between
/// adjacent pixels is larger than the terrain's own steps away from the seam plus 10 % of the
/// sources' 500 m offset. A hard seam (no feather) puts the whole offset in one step and fails
/// the same bound, so the check can fail.
#[test]
fn feathered_seam_has_no_cliff() {
    let (coarse, fine) = (coarse(), fine());
    let feather = 16.0;
    let base = TileOptions {
        tile_size: 256,
        ..Default::default()
    };
    let dirs: Vec<tempfile::TempDir> = (0..4).map(|_| tempfile::tempdir().unwrap()).collect();
    let r = tile_mosaic(
        &[(&fine, feather), (&coarse, 4.0)],
        dirs[0].path(),
        &base,
        None,
    )
    .unwrap();
    let opts = TileOptions {
        levels: Some(r.levels),
        ..base.clone()
    };
    tile_dem(&fine, &moon(), dirs[1].path(), &opts, None, &NoProgress).unwrap();
    tile_dem(&coarse, &moon(), dirs[2].path(), &opts, None, &NoProgress).unwrap();
    tile_mosaic(&[(&fine, 0.0), (&coarse, 4.0)], dirs[3].path(), &opts, None).unwrap();

    let ts = Tileset::load(dirs[0].path()).unwrap();
    assert_eq!(ts.mosaic.len(), 2);
    assert_eq!(ts.mosaic[0].feather_px, feather);
    assert_eq!(ts.parameters["mosaic"][1]["feather_px"], 4.0);
    let layout = ts.layout;
    let level = layout.levels - 1;
    // Levels follow the finest source.
    let finest_m = fine.pixel_size_m(moon().radius_m);
    assert!(layout.centre_pixel_m(level, moon().radius_m) <= finest_m);

    let [m, f, g, hard] = [0, 1, 2, 3].map(|k| face_pixels(dirs[k].path(), level));
    let (face, x0, gy) = face_pixel(&layout, level, 10.0, 20.2);
    let (face1, x1, _) = face_pixel(&layout, level, 10.0, 21.4);
    assert_eq!(face, face1);
    let border = 20.8;
    let feather_deg = feather * 0.01;
    let get = |t: &HashMap<(Face, i64, i64), (f32, u8)>, gx: i64| t[&(face, gx, gy)];
    let (mut share, mut steps_seam, mut steps_away, mut hard_seam) = (Vec::new(), 0f64, 0f64, 0f64);
    for gx in x0..x1 {
        let lon = latlon(&layout, level, face, gx, gy).1;
        let ((mv, mm), (fv, fm), (gv, _)) = (get(&m, gx), get(&f, gx), get(&g, gx));
        assert_ne!(mm, mask::NO_DATA);
        if lon < border - feather_deg - 0.02 {
            assert_eq!(
                mv.to_bits(),
                fv.to_bits(),
                "inside the fine source at {lon}°E"
            );
        }
        if fm == mask::NO_DATA {
            assert_eq!(
                mv.to_bits(),
                gv.to_bits(),
                "beyond the fine source at {lon}°E"
            );
        } else {
            // m = w·f + (1 − w)·g: the fine source's share.
            share.push(((mv - gv) as f64 / (fv - gv) as f64, lon));
        }
        let (nv, hv) = (
            get(&m, gx + 1).0,
            (get(&hard, gx + 1).0 - get(&hard, gx).0).abs(),
        );
        let step = (nv - mv).abs() as f64;
        if (lon - border).abs() < feather_deg + 0.05 {
            steps_seam = steps_seam.max(step);
            hard_seam = hard_seam.max(hv as f64);
        } else {
            steps_away = steps_away.max(step);
        }
    }
    assert!(
        share.len() > 50,
        "{} pixels on the fine source",
        share.len()
    );
    for w in share.windows(2) {
        assert!(
            (-1e-3..=1.0 + 1e-3).contains(&w[0].0) && w[1].0 <= w[0].0 + 1e-3,
            "the fine source's share rises outward: {:?} then {:?}",
            w[0],
            w[1]
        );
    }
    assert!(share.first().unwrap().0 == 1.0 && share.last().unwrap().0 < 0.05);
    eprintln!(
        "synthetic seam: largest step {steps_seam:.2} m in the seam, {steps_away:.2} m away, \
         {hard_seam:.1} m with a hard seam (offset {OFFSET_M} m)"
    );
    assert!(
        steps_seam <= steps_away + 0.1 * OFFSET_M,
        "a cliff at the seam: step {steps_seam} m, {steps_away} m away"
    );
    assert!(
        hard_seam > steps_away + 0.5 * OFFSET_M,
        "the hard seam should fail the bound: {hard_seam} m"
    );
}

/// [`analytic`] with hills: 600 m ridges about 30 km apart, whose horizons rise several degrees
/// (the analytic surface alone is flat to within 0.1° at 27 km).
fn hilly(lat: f64, lon: f64) -> f32 {
    let k = std::f64::consts::TAU;
    (analytic(lat, lon) + 600.0 * (k * lon / 0.9).sin() * (k * lat / 1.1).cos()) as f32
}

/// [`hilly`] as a coarse (0.05°) source over 6° × 6°, raised by `raise` m, and a fine (0.01°)
/// one over 1.6° × 1.6° inside it, with the borders of [`coarse`] and [`fine`].
fn hilly_pair(raise: f64) -> (Dem, Dem) {
    (
        geographic_dem((17.0, 13.0), (120, 120), 0.05, "coarse", |_, _, la, lo| {
            hilly(la, lo) + raise as f32
        }),
        geographic_dem((19.2, 10.8), (160, 160), 0.01, "fine", |_, _, la, lo| {
            hilly(la, lo)
        }),
    )
}

/// Tile `id`'s context (`margin` pixels around it, as the horizon stage reads it from the
/// tileset in `dir`) and its horizons at `a` azimuths (fast method, no far rings).
fn tile_horizons(dir: &Path, id: TileId, margin: u64, a: usize) -> (Vec<f32>, Vec<f32>) {
    let store = Store::open(dir).unwrap();
    let (ctx, rect) = penumbra::horizon::context_for(&store, id, margin, None).unwrap();
    let h = penumbra::horizon::horizons_far(&ctx, rect, a, penumbra::horizon::DEFAULT_NEAR_PX, &[]);
    (ctx.heights, h)
}

/// The horizon stage sees one surface across a mosaic's seam: a fine source feathered into a
/// coarse one of the same hilly terrain ([`hilly_pair`]), on the finest tile across the fine
/// source's east border. Against the horizons of one source of that terrain at the fine
/// resolution everywhere, the mosaic's are nowhere farther off than the coarse source's alone
/// (plus 0.01°); and in the seam band (the feather and 0.05° beyond) no step between adjacent
/// pixels' horizons is larger than the steps either source's own surface has there, plus the
/// slope the feather's blend can add (twice the rasters' height difference over the feather's
/// width). The same border as a hard seam over the coarse source raised by 500 m fails the
/// step bound, so the check can fail. With `PENUMBRA_HORIZON_SEAM_PNG` set, writes the horizon
/// elevation looking along the face's +x over the tile (the one source, the feathered mosaic,
/// the hard seam).
#[test]
fn horizons_see_one_surface_across_the_seam() {
    let ((coarse, fine), (raised, _)) = (hilly_pair(0.0), hilly_pair(OFFSET_M));
    // The same terrain at the fine resolution over the coarse source's whole footprint.
    let whole = geographic_dem((17.0, 13.0), (600, 600), 0.01, "whole", |_, _, la, lo| {
        hilly(la, lo)
    });
    let feather = 16.0;
    let base = TileOptions {
        tile_size: 128,
        ..Default::default()
    };
    let dirs: Vec<tempfile::TempDir> = (0..4).map(|_| tempfile::tempdir().unwrap()).collect();
    let r = tile_mosaic(
        &[(&fine, feather), (&coarse, 4.0)],
        dirs[0].path(),
        &base,
        None,
    )
    .unwrap();
    let opts = TileOptions {
        levels: Some(r.levels),
        ..base.clone()
    };
    tile_dem(&whole, &moon(), dirs[1].path(), &opts, None, &NoProgress).unwrap();
    tile_mosaic(&[(&fine, 0.0), (&raised, 4.0)], dirs[2].path(), &opts, None).unwrap();
    tile_dem(&coarse, &moon(), dirs[3].path(), &opts, None, &NoProgress).unwrap();
    let layout = Tileset::load(dirs[0].path()).unwrap().layout;
    let level = layout.levels - 1;
    let px_m = layout.centre_pixel_m(level, moon().radius_m);
    let id = layout
        .locate(
            level,
            cube::latlon_to_dir(10f64.to_radians(), 20.8f64.to_radians()),
        )
        .tile;
    let (a, margin, n) = (16, 128, layout.tile_size as usize);
    let [(hm_ctx, hm), (h1_ctx, h1), (_, hh), (_, hc)] =
        [0, 1, 2, 3].map(|k| tile_horizons(dirs[k].path(), id, margin, a));
    for h in [&hm, &h1, &hh, &hc] {
        assert!(h.iter().all(|v| v.is_finite()), "every pixel has data");
    }
    // The rasters' own height difference over the context, and the slope the feather's blend
    // of it can add.
    let dh = hm_ctx
        .iter()
        .zip(&h1_ctx)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .map(|(x, y)| (x - y).abs() as f64)
        .fold(0.0, f64::max);
    let feather_m = feather * 0.01f64.to_radians() * moon().radius_m;
    let blend = (2.0 * dh / feather_m).atan().to_degrees();
    // Distance (degrees) of each pixel from the fine source's border (lat 9.2..10.8°N, lon
    // 19.2..20.8°E), and the seam band: the feather and 0.05° beyond.
    let border = |i: usize, j: usize| {
        let (gx, gy) = (
            id.x as i64 * n as i64 + i as i64,
            id.y as i64 * n as i64 + j as i64,
        );
        let (la, lo) = latlon(&layout, level, id.face, gx, gy);
        let dx = (lo - 19.2).abs().min((lo - 20.8).abs());
        let dy = (la - 9.2).abs().min((la - 10.8).abs());
        match ((19.2..=20.8).contains(&lo), (9.2..=10.8).contains(&la)) {
            (true, true) => dx.min(dy),
            (true, false) => dy,
            (false, true) => dx,
            (false, false) => dx.hypot(dy),
        }
    };
    let band = feather * 0.01 + 0.05;
    let (mut diff, mut diff_c) = (0f64, 0f64);
    // Largest steps in the seam band: the mosaic, the one source, the coarse source, the hard
    // seam; and the mosaic's away from the band.
    let (mut seam, mut seam1, mut seam_c, mut hard, mut away) = (0f64, 0f64, 0f64, 0f64, 0f64);
    let mut in_band = 0;
    for j in 0..n {
        for i in 0..n - 1 {
            let near = border(i, j) < band || border(i + 1, j) < band;
            in_band += usize::from(near);
            for k in 0..a {
                let at = |h: &[f32], i: usize| h[k * n * n + j * n + i] as f64;
                let step = |h: &[f32]| (at(h, i + 1) - at(h, i)).abs();
                diff = diff.max((at(&hm, i) - at(&h1, i)).abs());
                diff_c = diff_c.max((at(&hc, i) - at(&h1, i)).abs());
                if near {
                    seam = seam.max(step(&hm));
                    seam1 = seam1.max(step(&h1));
                    seam_c = seam_c.max(step(&hc));
                    hard = hard.max(step(&hh));
                } else {
                    away = away.max(step(&hm));
                }
            }
        }
    }
    eprintln!(
        "horizons across the seam (tile {id}, {px_m:.0} m pixels, heights differ by {dh:.1} m): \
         {diff:.3}° from the one source's at most ({diff_c:.3}° for the coarse source alone); \
         largest step in the seam band ({in_band} pixel pairs) {seam:.3}°, the one source's \
         {seam1:.3}°, the coarse source's {seam_c:.3}°, {away:.3}° away from it, {hard:.2}° \
         with a hard 500 m seam (blend allowance {blend:.3}°)"
    );
    assert!(in_band > 500, "{in_band} pixel pairs in the seam band");
    assert!(
        diff <= diff_c + 0.01,
        "the mosaic's horizons are {diff}° off, the coarse source's {diff_c}°"
    );
    let bound = seam1.max(seam_c) + blend;
    assert!(
        seam <= bound,
        "a step in the horizons at the seam: {seam}° against the sources' {seam1}°, {seam_c}°"
    );
    assert!(
        hard > bound + 1.0,
        "the hard seam should fail the step bound: {hard}°"
    );

    if let Some(png) = std::env::var_os("PENUMBRA_HORIZON_SEAM_PNG") {
        // Azimuth 0 looks along the face's +x, across the border; grey from the lowest to the
        // highest of the one source's and the mosaic's maps (the hard seam's cliff saturates).
        let maps = [&h1, &hm, &hh].map(|h| &h[..n * n]);
        let (lo, hi) = maps[..2]
            .iter()
            .flat_map(|m| m.iter())
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        let gap = 4;
        let mut img =
            image::GrayImage::from_pixel((3 * n + 2 * gap) as u32, n as u32, image::Luma([255]));
        for (p, m) in maps.iter().enumerate() {
            for y in 0..n {
                for x in 0..n {
                    let v = ((m[y * n + x] - lo) / (hi - lo) * 255.0).clamp(0.0, 255.0) as u8;
                    img.put_pixel((p * (n + gap) + x) as u32, y as u32, image::Luma([v]));
                }
            }
        }
        let img = image::imageops::resize(
            &img,
            img.width() * 2,
            img.height() * 2,
            image::imageops::FilterType::Nearest,
        );
        img.save(Path::new(&png)).unwrap();
        eprintln!(
            "wrote {} (tile {id}, horizon elevation {lo:.2}°..{hi:.2}° looking along +x)",
            Path::new(&png).display()
        );
    }
}

/// One source through `tile_sources` is `tile_dem`: the same files, bytes and manifest,
/// whatever its feather.
#[test]
fn one_source_is_tile_dem() {
    let dem = global_dem(720);
    let opts = TileOptions {
        tile_size: 32,
        levels: Some(3),
        ..Default::default()
    };
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    tile_dem(&dem, &moon(), a.path(), &opts, None, &NoProgress).unwrap();
    tile_mosaic(&[(&dem, 9.0)], b.path(), &opts, None).unwrap();
    assert_eq!(snapshot(a.path()), snapshot(b.path()));
    assert!(Tileset::load(b.path()).unwrap().mosaic.is_empty());
}

/// A wanted set: only its tiles are cut (the same files as a whole run) and listed; a set
/// not closed under parent, or off the layout, is refused before anything is written.
#[test]
fn wanted_tiles_only() {
    let dem = global_dem(720);
    let opts = TileOptions {
        tile_size: 32,
        levels: Some(3),
        ..Default::default()
    };
    let t = |level, x, y| TileId {
        level,
        face: Face::Px,
        x,
        y,
    };
    let wanted: BTreeSet<TileId> = [t(0, 0, 0), t(1, 0, 0), t(1, 1, 0), t(2, 1, 1), t(2, 2, 0)]
        .into_iter()
        .collect();
    let (whole, part) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    tile_dem(&dem, &moon(), whole.path(), &opts, None, &NoProgress).unwrap();
    let r = tile_mosaic(&[(&dem, 4.0)], part.path(), &opts, Some(&wanted)).unwrap();
    assert_eq!(r.tiles_written, wanted.len() as u64);
    let ts = Tileset::load(part.path()).unwrap();
    assert_eq!(ts.tile_set(), wanted);
    let files: Vec<String> = snapshot(part.path())
        .into_keys()
        .filter(|k| k.starts_with("height/"))
        .collect();
    assert_eq!(files.len(), wanted.len(), "{files:?}");
    let (sw, sp) = (
        Store::open(whole.path()).unwrap(),
        Store::open(part.path()).unwrap(),
    );
    for id in &wanted {
        let (a, b) = (
            sw.height(*id).unwrap().unwrap(),
            sp.height(*id).unwrap().unwrap(),
        );
        assert_eq!(a.height, b.height, "{id}");
    }
    // The wanted set is not part of the run's identity: a tile's bytes do not depend on which
    // others are cut, so the files are the whole run's, byte for byte (identity included).
    assert_eq!(
        Tileset::load(whole.path()).unwrap().run_key,
        ts.run_key,
        "the wanted set changed the run key"
    );
    let whole_files = snapshot(whole.path());
    for (k, v) in snapshot(part.path()) {
        if k.starts_with("height/") {
            assert!(whole_files[&k] == v, "{k} differs from the whole run's");
        }
    }
    // Again: up to date.
    assert!(
        tile_mosaic(&[(&dem, 4.0)], part.path(), &opts, Some(&wanted))
            .unwrap()
            .up_to_date
    );

    let bad = tempfile::tempdir().unwrap();
    let out = bad.path().join("ts");
    let orphan: BTreeSet<TileId> = [t(0, 0, 0), t(2, 1, 1)].into_iter().collect();
    let e = tile_mosaic(&[(&dem, 4.0)], &out, &opts, Some(&orphan)).unwrap_err();
    assert!(
        e.to_string().contains("wanted") && e.to_string().contains("parent"),
        "{e}"
    );
    let deep: BTreeSet<TileId> = [t(0, 0, 0), t(1, 0, 0), t(2, 0, 0), t(3, 0, 0)]
        .into_iter()
        .collect();
    let e = tile_mosaic(&[(&dem, 4.0)], &out, &opts, Some(&deep)).unwrap_err();
    assert!(e.to_string().contains("not on this tileset's grid"), "{e}");
    assert!(!out.exists());
}

/// Sources of different bodies (the Mars MEGDR and the Moon's LDEM_4) are refused, naming
/// both files, before anything is written; so is a feather that is not a width.
#[test]
fn sources_of_different_bodies_are_refused() {
    let Some(data) = shared_data() else { return };
    let ldem = data.join("lola_ldem4/LDEM_4.LBL");
    let megdr = data.join("mola_megt90n000cb/megt90n000cb.lbl");
    let (a, b) = (
        dem::open(&ldem, 64).unwrap(),
        dem::open(&megdr, 64).unwrap(),
    );
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ts");
    let e = tile_mosaic(&[(&a, 4.0), (&b, 4.0)], &out, &Default::default(), None).unwrap_err();
    let msg = e.to_string();
    assert!(
        matches!(e, penumbra::error::Error::Usage(_))
            && msg.contains("LDEM_4.LBL")
            && msg.contains("megt90n000cb.lbl")
            && msg.contains("same body"),
        "{msg}"
    );
    let e = tile_mosaic(&[(&a, f64::NAN)], &out, &Default::default(), None).unwrap_err();
    assert!(e.to_string().contains("feather_px"), "{e}");
    assert!(!out.exists());
}

/// Hillshade of a height tile's interior (`px_m` metres per pixel), light from the north-west
/// 35° up; grey levels.
fn hillshade(h: &[f32], size: usize, halo: usize, px_m: f64) -> Vec<u8> {
    let n = size - 2 * halo;
    let at = |i: usize, j: usize| h[(j + halo) * size + i + halo] as f64;
    let (az, el) = (315f64.to_radians(), 35f64.to_radians());
    let l = [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()];
    let mut out = vec![0u8; n * n];
    for j in 0..n {
        for i in 0..n {
            let (i0, i1) = (i.saturating_sub(1), (i + 1).min(n - 1));
            let (j0, j1) = (j.saturating_sub(1), (j + 1).min(n - 1));
            let dx = (at(i1, j) - at(i0, j)) / ((i1 - i0) as f64 * px_m);
            // Rows grow southward on the picture: north is up.
            let dy = (at(i, j0) - at(i, j1)) / ((j1 - j0) as f64 * px_m);
            let nz = 1.0 / (1.0 + dx * dx + dy * dy).sqrt();
            let s = (-dx * l[0] - dy * l[1] + l[2]) * nz;
            out[j * n + i] = if s.is_finite() {
                (s.clamp(0.0, 1.0) * 255.0) as u8
            } else {
                0
            };
        }
    }
    out
}

/// LDEM_4 (7.5 km) under the Shoemaker 5 m DEM at the finest level whose pixel is about 5 m,
/// over the tiles around Shoemaker (a wanted set): at every pixel where both have data the
/// mosaic lies between the two sources (it differs from each by no more than they differ
/// there), beyond Shoemaker it is LDEM_4 bit for bit, and along every transect across
/// Shoemaker's border no step of the mosaic exceeds the sources' own steps plus 40 % of their
/// difference (a 4-pixel feather), where a hard seam puts the whole difference in one step.
/// The mipmaps of the mosaic bound its heights across the seam, and the coarser levels are the
/// box means of the finest one: later stages see one surface. With `PENUMBRA_MOSAIC_PNG` set,
/// writes a picture of the seam there (hillshade of one tile: a hard seam, the default feather,
/// a 32-pixel feather).
#[test]
fn ldem4_under_shoemaker_has_no_seam() {
    let Some(data) = shared_data() else { return };
    let ldem = dem::open(&data.join("lola_ldem4/LDEM_4.LBL"), 64).unwrap();
    let shoe = dem::open(
        &data.join("lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif"),
        64,
    )
    .unwrap();
    let body = moon();
    let levels = 12;
    let opts = TileOptions {
        tile_size: 256,
        levels: Some(levels),
        ..Default::default()
    };
    let layout = Layout {
        projection: opts.projection,
        tile_size: opts.tile_size,
        halo: opts.halo,
        levels,
    };
    let level = levels - 1;
    let px_m = layout.centre_pixel_m(level, body.radius_m);
    assert!((4.0..7.0).contains(&px_m), "{px_m} m");
    // The wanted set: the finest tiles over Shoemaker and 64 of its pixels around, and their
    // ancestors.
    let (w, h) = (shoe.width() as i64, shoe.height() as i64);
    let mut wanted = BTreeSet::new();
    for r in (-64..h + 64).step_by(8) {
        for c in (-64..w + 64).step_by(8) {
            let (la, lo) = shoe.to_latlon(c as f64, r as f64);
            let d = cube::latlon_to_dir(la.to_radians(), lo.to_radians());
            let mut t = Some(layout.locate(level, d).tile);
            while let Some(id) = t {
                wanted.insert(id);
                t = id.parent();
            }
        }
    }
    let feather = penumbra::tiling::DEFAULT_FEATHER_PX;
    let dirs: Vec<tempfile::TempDir> = (0..5).map(|_| tempfile::tempdir().unwrap()).collect();
    let t0 = std::time::Instant::now();
    let r = tile_mosaic(
        &[(&shoe, feather), (&ldem, 4.0)],
        dirs[0].path(),
        &opts,
        Some(&wanted),
    )
    .unwrap();
    let t_mosaic = t0.elapsed();
    let t0 = std::time::Instant::now();
    tile_mosaic(&[(&ldem, 4.0)], dirs[1].path(), &opts, Some(&wanted)).unwrap();
    let t_ldem = t0.elapsed();
    tile_mosaic(&[(&shoe, 4.0)], dirs[2].path(), &opts, Some(&wanted)).unwrap();
    tile_mosaic(
        &[(&shoe, 0.0), (&ldem, 4.0)],
        dirs[3].path(),
        &opts,
        Some(&wanted),
    )
    .unwrap();
    tile_mosaic(
        &[(&shoe, 32.0), (&ldem, 4.0)],
        dirs[4].path(),
        &opts,
        Some(&wanted),
    )
    .unwrap();
    eprintln!(
        "LDEM_4 + Shoemaker: {} tiles in {:.3} s; LDEM_4 alone {:.3} s on the same tiles",
        r.tiles_written,
        t_mosaic.as_secs_f64(),
        t_ldem.as_secs_f64()
    );
    let [m, g, f, hard] = [0, 1, 2, 3].map(|k| face_pixels(dirs[k].path(), level));

    // Per pixel: between the sources; LDEM_4 where Shoemaker has no data.
    let (mut both, mut equal_fine, mut worst_diff) = (0usize, 0usize, 0f64);
    for (k, &(mv, mm)) in &m {
        let (gv, _) = g[k];
        let (fv, fm) = f.get(k).copied().unwrap_or((f32::NAN, mask::NO_DATA));
        assert_ne!(mm, mask::NO_DATA, "{k:?}");
        if fm == mask::NO_DATA {
            assert_eq!(mv.to_bits(), gv.to_bits(), "beyond Shoemaker at {k:?}");
            continue;
        }
        both += 1;
        equal_fine += usize::from(mv == fv);
        let (lo, hi) = (fv.min(gv) as f64, fv.max(gv) as f64);
        let slack = 1e-4 * (hi - lo) + 1e-3;
        worst_diff = worst_diff.max(hi - lo);
        assert!(
            (lo - slack..=hi + slack).contains(&(mv as f64)),
            "at {k:?} the mosaic {mv} m is not between Shoemaker {fv} m and LDEM_4 {gv} m"
        );
    }
    let on_fine = f.values().filter(|v| v.1 != mask::NO_DATA).count();
    eprintln!(
        "Shoemaker: {on_fine} pixels with data alone, {both} in the mosaic's tiles, {equal_fine} of \
         them exactly Shoemaker; voids {:?}",
        shoe.void_counts()
    );
    assert!(
        both > 30_000 && equal_fine * 10 > both * 8,
        "{both} {equal_fine}"
    );

    // Transects across the border: from each pixel on Shoemaker whose neighbour (along a face
    // axis) is off it, 3 × feather pixels inward to 4 outward.
    let (mut transects, mut worst_ratio, mut worst_hard) = (0usize, 0f64, 0f64);
    let (mut d_max, mut d_sum) = (0f64, 0f64);
    let on = |k: &(Face, i64, i64)| f.get(k).is_some_and(|v| v.1 != mask::NO_DATA);
    let shoe_px_m = shoe.pixel_size_m(body.radius_m);
    let reach = (feather * shoe_px_m / px_m).ceil() as i64;
    // The steepest share of the difference one output pixel can carry: smoothstep's largest
    // slope (1.5) over the feather in output pixels, and 5 % for the sources' own curvature.
    let slope = (1.05 * 1.5 * px_m / (feather * shoe_px_m)).min(1.0);
    for (&(face, gx, gy), _) in f.iter().filter(|(k, _)| on(k)) {
        for (dx, dy) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
            if on(&(face, gx + dx, gy + dy)) || !m.contains_key(&(face, gx + dx, gy + dy)) {
                continue;
            }
            let pts: Vec<(Face, i64, i64)> = (-3 * reach..=4)
                .map(|s| (face, gx + s * dx, gy + s * dy))
                .collect();
            if !pts.iter().all(|p| m.contains_key(p)) {
                continue;
            }
            let (mut step_m, mut step_src, mut step_hard, mut diff) = (0f64, 0f64, 0f64, 0f64);
            for p in pts.windows(2) {
                let d = |t: &HashMap<_, (f32, u8)>| (t[&p[1]].0 - t[&p[0]].0).abs() as f64;
                step_m = step_m.max(d(&m));
                step_hard = step_hard.max(d(&hard));
                step_src = step_src.max(d(&g));
                if on(&p[0]) && on(&p[1]) {
                    step_src = step_src.max(d(&f));
                }
            }
            for p in pts.iter().filter(|p| on(p)) {
                diff = diff.max((f[p].0 - g[p].0).abs() as f64);
            }
            transects += 1;
            d_max = d_max.max(diff);
            d_sum += diff;
            assert!(
                step_m <= step_src + slope * diff + 1e-3,
                "a cliff across Shoemaker's border at {face:?} {gx} {gy}: step {step_m} m, the \
                 sources' own steps {step_src} m, their difference {diff} m"
            );
            if diff > 1.0 {
                worst_ratio = worst_ratio.max((step_m - step_src) / diff);
                worst_hard = worst_hard.max((step_hard - step_src) / diff);
            }
        }
    }
    assert!(transects > 500, "{transects} transects");
    eprintln!(
        "Shoemaker's border: {transects} transects; sources differ by {:.1} m on average, {d_max:.1} \
         m at most ({worst_diff:.1} m over the whole overlap); the mosaic's largest step beyond \
         the sources' own is {:.0} % of their difference there ({:.0} % with a hard seam)",
        d_sum / transects as f64,
        100.0 * worst_ratio,
        100.0 * worst_hard
    );

    // The mipmaps see one surface: the max pyramid bounds the mosaic's heights across the
    // seam, and each coarser level is the box mean of the finest.
    mip::build_mips(dirs[0].path(), &MipOptions::default(), &NoProgress).unwrap();
    let store = Store::open(dirs[0].path()).unwrap();
    let (n, halo) = (layout.tile_size as usize, layout.halo as usize);
    let s = layout.stored_size();
    let mut texels = 0usize;
    for id in store.manifest().tile_set() {
        if id.level != level {
            continue;
        }
        let t = store.height(id).unwrap().unwrap();
        let mf = store.mip(id, true).unwrap();
        let max = &mf.channels["max"];
        for (k, lv) in max.iter().enumerate() {
            let side = mf.sizes[k];
            for y in 0..side {
                for x in 0..side {
                    let (i0, i1) = (x << k, ((x + 1) << k).min(n) - 1);
                    let (j0, j1) = (y << k, ((y + 1) << k).min(n) - 1);
                    let mut top = f32::NAN;
                    for j in j0 + halo..=j1 + halo {
                        for i in i0 + halo..=i1 + halo {
                            let v = t.height[j * s + i];
                            if !v.is_nan() && (top.is_nan() || v > top) {
                                top = v;
                            }
                        }
                    }
                    if top.is_nan() {
                        continue;
                    }
                    texels += 1;
                    assert!(
                        lv[y * side + x] >= top,
                        "{id} mip level {k} ({x}, {y}): max {} below the height {top}",
                        lv[y * side + x]
                    );
                }
            }
        }
    }
    assert!(texels > 0);
    let coarser = face_pixels(dirs[0].path(), level - 1);
    let mut checked = 0usize;
    for (&(face, gx, gy), &(v, mk)) in &coarser {
        let kids: Vec<f32> = [(0, 0), (1, 0), (0, 1), (1, 1)]
            .iter()
            .filter_map(|&(a, b)| m.get(&(face, 2 * gx + a, 2 * gy + b)))
            .filter(|c| c.1 != mask::NO_DATA)
            .map(|c| c.0)
            .collect();
        if kids.len() < 4 || mk == mask::NO_DATA {
            continue;
        }
        let mean = kids.iter().map(|&k| k as f64).sum::<f64>() / 4.0;
        assert!((v as f64 - mean).abs() <= 1e-3, "{gx} {gy}: {v} vs {mean}");
        checked += 1;
    }
    assert!(checked > 10_000, "{checked}");

    if let Some(png) = std::env::var_os("PENUMBRA_MOSAIC_PNG") {
        // The finest tile holding the middle of Shoemaker's east border.
        let (la, lo) = shoe.to_latlon(w as f64 - 0.5, h as f64 / 2.0);
        let id = layout
            .locate(level, cube::latlon_to_dir(la.to_radians(), lo.to_radians()))
            .tile;
        // Left to right: a hard seam, the default feather, a 32-pixel feather.
        let shades: Vec<Vec<u8>> = [3, 0, 4]
            .iter()
            .map(|&k| {
                let t = Store::open(dirs[k].path())
                    .unwrap()
                    .height(id)
                    .unwrap()
                    .unwrap();
                hillshade(&t.height, s, halo, px_m)
            })
            .collect();
        let gap = 6;
        let mut img =
            image::GrayImage::from_pixel((3 * n + 2 * gap) as u32, n as u32, image::Luma([255]));
        for (p, sh) in shades.iter().enumerate() {
            for y in 0..n {
                for x in 0..n {
                    img.put_pixel(
                        (p * (n + gap) + x) as u32,
                        y as u32,
                        image::Luma([sh[y * n + x]]),
                    );
                }
            }
        }
        let img = image::imageops::resize(
            &img,
            img.width() * 2,
            img.height() * 2,
            image::imageops::FilterType::Nearest,
        );
        img.save(Path::new(&png)).unwrap();
        eprintln!("wrote {} (tile {id})", Path::new(&png).display());
    }
}
