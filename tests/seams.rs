use std::collections::HashMap;

use penumbra::body::Body;
use penumbra::cube::{self, Face, Projection};
use penumbra::format::height::{self as tileio, HeightTile};
use penumbra::layout::{Layout, TileId};
use penumbra::manifest::Tileset;
use penumbra::progress::NoProgress;
use penumbra::tiling::{tile_dem, TileOptions};

use crate::util::{analytic, global_dem};

struct Tiles {
    dir: tempfile::TempDir,
    ts: Tileset,
    cache: HashMap<TileId, HeightTile>,
}

impl Tiles {
    fn new(projection: Projection) -> Tiles {
        let dem = global_dem(1440);
        let dir = tempfile::tempdir().unwrap();
        let opts = TileOptions {
            tile_size: 64,
            halo: 2,
            projection,
            levels: Some(3),
            ..Default::default()
        };
        let body = Body::preset("moon").unwrap();
        tile_dem(&dem, &body, dir.path(), &opts, None, &NoProgress).unwrap();
        let ts = Tileset::load(dir.path()).unwrap();
        Tiles {
            dir,
            ts,
            cache: HashMap::new(),
        }
    }

    fn layout(&self) -> Layout {
        self.ts.layout
    }

    fn tile(&mut self, id: TileId) -> &HeightTile {
        let root = self.dir.path().to_path_buf();
        self.cache.entry(id).or_insert_with(|| {
            let p = penumbra::tileset::tile_path(&root, penumbra::manifest::HEIGHT_PATTERN, id);
            tileio::read_height_tile(&p).unwrap()
        })
    }

    /// Height at direction `d` read from `face`'s tiles (the halo when `d` lies past its edge).
    fn height_on(&mut self, level: u8, face: Face, d: cube::Vec3) -> f64 {
        let (u, v) = cube::dir_to_uv_on(face, d).unwrap();
        let lay = self.layout();
        let loc = lay.locate_on(level, face, u, v);
        let h = lay.halo as f64;
        assert!(loc.px >= -h && loc.px <= lay.tile_size as f64 - 1.0 + h);
        self.tile(loc.tile).bilinear(loc.px + h, loc.py + h) as f64
    }
}

#[test]
fn halos_equal_the_neighbours_interior_on_a_face() {
    let mut t = Tiles::new(Projection::Gnomonic);
    let lay = t.layout();
    let (n, h) = (lay.tile_size as usize, lay.halo as usize);
    let side = lay.stored_size();
    for face in Face::ALL {
        let a = t
            .tile(TileId {
                level: 2,
                face,
                x: 1,
                y: 2,
            })
            .clone();
        let b = t
            .tile(TileId {
                level: 2,
                face,
                x: 2,
                y: 2,
            })
            .clone();
        // a's right halo columns are b's first interior columns, bit for bit.
        for row in 0..side {
            for k in 0..h {
                let ha = a.height[row * side + h + n + k];
                let hb = b.height[row * side + h + k];
                assert_eq!(ha.to_bits(), hb.to_bits(), "{face} row {row} col {k}");
            }
        }
    }
}

#[test]
fn all_twelve_face_edges_agree_within_resampling_error() {
    for projection in [Projection::Gnomonic, Projection::EqualAngle] {
        let mut t = Tiles::new(projection);
        // Level 2 is point-sampled, level 1 box-filtered (2×2 samples per pixel).
        for level in [1u8, 2] {
            // Resampling error inside faces, against the analytic surface, sets the tolerance.
            let mut interior_err: f64 = 0.0;
            for face in Face::ALL {
                for k in 0..200 {
                    let (u, v) = (
                        ((k * 37) % 199) as f64 / 100.0 - 0.99,
                        ((k * 61) % 197) as f64 / 99.0 - 0.99,
                    );
                    let d = cube::face_uv_to_dir(face, projection.s_to_u(u), projection.s_to_u(v));
                    let (la, lo) = cube::dir_to_latlon(d);
                    let e = (t.height_on(level, face, d)
                        - analytic(la.to_degrees(), lo.to_degrees()))
                    .abs();
                    interior_err = interior_err.max(e);
                }
            }
            let mut edges = std::collections::BTreeSet::new();
            let mut worst: f64 = 0.0;
            let px = 2.0 / t.layout().face_pixels(level) as f64;
            for a in Face::ALL {
                for k in 0..=64 {
                    let along = -1.0 + 2.0 * k as f64 / 64.0;
                    for (su, sv) in [(1.0, along), (-1.0, along), (along, 1.0), (along, -1.0)] {
                        // On the edge and half a pixel to either side of it.
                        for off in [-0.5 * px, 0.0, 0.5 * px] {
                            let (su2, sv2) = if su.abs() == 1.0 {
                                (su + su * off, sv)
                            } else {
                                (su, sv + sv * off)
                            };
                            let d = cube::face_uv_to_dir(
                                a,
                                projection.s_to_u(su2),
                                projection.s_to_u(sv2),
                            );
                            for b in Face::ALL {
                                if b == a {
                                    continue;
                                }
                                let Some((ub, vb)) = cube::dir_to_uv_on(b, d) else {
                                    continue;
                                };
                                if ub.abs() > 1.0 + 1e-3 || vb.abs() > 1.0 + 1e-3 {
                                    continue;
                                }
                                if along.abs() < 0.999 {
                                    edges.insert((a.min(b), a.max(b)));
                                }
                                let diff =
                                    (t.height_on(level, a, d) - t.height_on(level, b, d)).abs();
                                worst = worst.max(diff);
                            }
                        }
                    }
                }
            }
            assert_eq!(edges.len(), 12, "every cube edge was visited");
            eprintln!(
            "{projection:?} level {level}: worst seam difference {worst:.3} m, interior resampling error {interior_err:.3} m"
        );
            // Relief is ±3 km; resampling at these levels is good to tens of metres.
            assert!(interior_err < 50.0, "interior error {interior_err}");
            assert!(
                worst <= 2.0 * interior_err + 1e-3,
                "seam {worst} vs interior {interior_err}"
            );
        }
    }
}
