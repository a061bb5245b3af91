use penumbra::cube::{self, Face, Projection};
use penumbra::layout::Layout;

/// Latitudes and longitudes that include the poles, the face edges (±45° meridians from each
/// face centre, the ±35.26° corner latitudes) and a dense grid.
fn grid() -> Vec<(f64, f64)> {
    let corner = (1.0f64 / 2.0f64.sqrt()).atan().to_degrees(); // 35.264°
    let mut lats: Vec<f64> = (-900..=900).step_by(7).map(|i| i as f64 / 10.0).collect();
    lats.extend([
        -90.0,
        90.0,
        corner,
        -corner,
        45.0,
        -45.0,
        89.999_999_9,
        -89.999_999_9,
    ]);
    let mut lons: Vec<f64> = (-1800..=3600)
        .step_by(11)
        .map(|i| i as f64 / 10.0)
        .collect();
    lons.extend([
        -180.0, -135.0, -45.0, 45.0, 135.0, 180.0, 225.0, 315.0, 360.0,
    ]);
    let mut v = Vec::new();
    for &la in &lats {
        for &lo in &lons {
            v.push((la, lo));
        }
    }
    v
}

#[test]
fn latlon_face_uv_round_trip_within_1e12_rad() {
    let mut worst: f64 = 0.0;
    let mut n = 0;
    for projection in [Projection::Gnomonic, Projection::EqualAngle] {
        for (la, lo) in grid() {
            let d = cube::latlon_to_dir(la.to_radians(), lo.to_radians());
            let (face, u, v) = cube::dir_to_face_uv(d);
            assert!(u.abs() <= 1.0 && v.abs() <= 1.0);
            let (s, t) = (projection.u_to_s(u), projection.u_to_s(v));
            let back = cube::face_uv_to_dir(face, projection.s_to_u(s), projection.s_to_u(t));
            let (la2, lo2) = cube::dir_to_latlon(back);
            let d2 = cube::latlon_to_dir(la2, lo2);
            let err = cube::angle_between(d, d2);
            worst = worst.max(err);
            n += 1;
            // Latitude directly, longitude away from the poles (where it is undefined).
            assert!((la2 - la.to_radians()).abs() < 1e-12, "{la} {lo}");
            if la.abs() < 89.9 {
                let dl = (lo2 - lo.to_radians()).rem_euclid(std::f64::consts::TAU);
                let dl = dl.min(std::f64::consts::TAU - dl);
                assert!(dl < 1e-12, "{la} {lo}");
            }
        }
    }
    eprintln!("worst lat/lon → face → lat/lon round trip: {worst:e} rad over {n} points");
    assert!(
        worst < 1e-12,
        "worst round-trip error {worst:e} rad over {n} points"
    );
}

#[test]
fn face_edges_and_corners_agree_between_faces() {
    // A direction on an edge projects to ±1 on both faces that share it.
    for face in Face::ALL {
        for k in 0..=20 {
            let a = -1.0 + k as f64 / 10.0;
            for (u, v) in [(1.0, a), (-1.0, a), (a, 1.0), (a, -1.0)] {
                let d = cube::face_uv_to_dir(face, u, v);
                let mut on = 0;
                for other in Face::ALL {
                    if let Some((uu, vv)) = cube::dir_to_uv_on(other, d) {
                        if uu.abs() <= 1.0 + 1e-12 && vv.abs() <= 1.0 + 1e-12 {
                            on += 1;
                            let back = cube::face_uv_to_dir(other, uu, vv);
                            assert!(cube::angle_between(d, back) < 1e-15);
                        }
                    }
                }
                let corner = u.abs() == 1.0 && v.abs() == 1.0;
                assert_eq!(on, if corner { 3 } else { 2 }, "{face} {u} {v}");
            }
        }
    }
}

#[test]
fn tile_pixels_round_trip_through_locate() {
    for projection in [Projection::Gnomonic, Projection::EqualAngle] {
        let lay = Layout {
            projection,
            tile_size: 256,
            halo: 2,
            levels: 8,
        };
        for (la, lo) in grid().into_iter().step_by(13) {
            let d = cube::latlon_to_dir(la.to_radians(), lo.to_radians());
            for level in [0u8, 3, 7] {
                let loc = lay.locate(level, d);
                // Rebuild the direction from the fractional pixel.
                let n = lay.face_pixels(level) as f64;
                let gx = loc.tile.x as f64 * 256.0 + loc.px;
                let gy = loc.tile.y as f64 * 256.0 + loc.py;
                let s = -1.0 + 2.0 * (gx + 0.5) / n;
                let t = 1.0 - 2.0 * (gy + 0.5) / n;
                let back = lay.st_to_dir(loc.tile.face, s, t);
                assert!(cube::angle_between(d, back) < 1e-12, "{la} {lo} L{level}");
                assert!((-0.5..=255.5).contains(&loc.px) && (-0.5..=255.5).contains(&loc.py));
            }
        }
    }
}
