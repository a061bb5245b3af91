//! Tile addressing on the cube: levels, tiles, pixels and the mapping between a tile pixel and
//! a direction on the body. Pixel (i, j) of a tile is its interior column i and row j
//! (0..tile_size); the halo extends them to −halo..tile_size+halo. Rows run from the face's
//! +V edge (top, north on equatorial faces) towards −V, columns from −U to +U.
//!
//! At level L a face is `tile_size · 2^L` pixels across and pixel centres sit at face
//! coordinates s = −1 + 2(gx + ½)/S, t = 1 − 2(gy + ½)/S for global pixel (gx, gy).
//! A halo pixel is the same formula continued past the tile (and past the face edge, where it
//! names a direction on the neighbouring face): halos are sampled from the source at their
//! own position, so a halo agrees with the neighbouring tile to within resampling error.

use serde::{Deserialize, Serialize};

use crate::cube::{self, Face, Projection, Vec3};

/// Address of one tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct TileId {
    pub level: u8,
    pub face: Face,
    pub x: u32,
    pub y: u32,
}

impl TileId {
    pub fn parent(self) -> Option<TileId> {
        (self.level > 0).then(|| TileId {
            level: self.level - 1,
            face: self.face,
            x: self.x / 2,
            y: self.y / 2,
        })
    }
}

impl std::fmt::Display for TileId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "L{}/{}/{}/{}", self.level, self.face, self.y, self.x)
    }
}

/// The tile grid shared by every product of a tileset.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Layout {
    pub projection: Projection,
    /// Interior pixels per tile side.
    pub tile_size: u32,
    /// Extra pixels on each side of the interior.
    pub halo: u32,
    /// Number of levels (0 = one tile per face … levels−1 = finest).
    pub levels: u8,
}

/// Where a direction falls at one level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Location {
    pub tile: TileId,
    /// Fractional interior pixel coordinates (pixel centres at integers).
    pub px: f64,
    pub py: f64,
}

pub const MAX_LEVELS: u8 = 24;

impl Layout {
    /// Pixels across a face at `level`.
    pub fn face_pixels(&self, level: u8) -> u64 {
        (self.tile_size as u64) << level
    }

    /// Tiles across a face at `level`.
    pub fn tiles_per_side(&self, level: u8) -> u32 {
        1u32 << level
    }

    /// Side of a stored tile (interior plus both halos).
    pub fn stored_size(&self) -> usize {
        (self.tile_size + 2 * self.halo) as usize
    }

    /// Face coordinates (s, t) of the centre of tile pixel (i, j); i, j may reach into the halo.
    #[inline]
    pub fn pixel_st(&self, tile: TileId, i: i64, j: i64) -> (f64, f64) {
        let s_px = self.face_pixels(tile.level) as f64;
        let gx = (tile.x as i64 * self.tile_size as i64 + i) as f64;
        let gy = (tile.y as i64 * self.tile_size as i64 + j) as f64;
        (
            -1.0 + 2.0 * (gx + 0.5) / s_px,
            1.0 - 2.0 * (gy + 0.5) / s_px,
        )
    }

    /// Face coordinates (s, t) of fractional *global* face pixel (gx, gy) at `level` (pixel
    /// centres at integers). Computing from the global position keeps every tile that sees a
    /// point, through its interior or its halo, on bit-identical coordinates.
    #[inline]
    pub fn global_st(&self, level: u8, gx: f64, gy: f64) -> (f64, f64) {
        let s_px = self.face_pixels(level) as f64;
        (
            -1.0 + 2.0 * (gx + 0.5) / s_px,
            1.0 - 2.0 * (gy + 0.5) / s_px,
        )
    }

    /// Global face pixel (column, row) of a tile's pixel (i, j); i, j may reach into the halo.
    #[inline]
    pub fn global_pixel(&self, tile: TileId, i: i64, j: i64) -> (i64, i64) {
        let n = self.tile_size as i64;
        (tile.x as i64 * n + i, tile.y as i64 * n + j)
    }

    /// Unit direction of face coordinates (s, t).
    #[inline]
    pub fn st_to_dir(&self, face: Face, s: f64, t: f64) -> Vec3 {
        cube::face_uv_to_dir(face, self.projection.s_to_u(s), self.projection.s_to_u(t))
    }

    /// Unit direction of tile pixel (i, j).
    #[inline]
    pub fn pixel_dir(&self, tile: TileId, i: i64, j: i64) -> Vec3 {
        let (s, t) = self.pixel_st(tile, i, j);
        self.st_to_dir(tile.face, s, t)
    }

    /// The tile and fractional pixel that contain direction `d` at `level`.
    pub fn locate(&self, level: u8, d: Vec3) -> Location {
        let (face, u, v) = cube::dir_to_face_uv(d);
        self.locate_on(level, face, u, v)
    }

    /// As [`Layout::locate`] for gnomonic plane coordinates (u, v) on a given face; (u, v) may lie
    /// slightly outside the face, the tile index is clamped and the pixel reaches into the halo.
    pub fn locate_on(&self, level: u8, face: Face, u: f64, v: f64) -> Location {
        let (s, t) = (self.projection.u_to_s(u), self.projection.u_to_s(v));
        let n = self.face_pixels(level) as f64;
        let gx = (s + 1.0) / 2.0 * n - 0.5;
        let gy = (1.0 - t) / 2.0 * n - 0.5;
        let per = self.tiles_per_side(level) as f64;
        let ts = self.tile_size as f64;
        let tx = ((gx + 0.5) / ts).floor().clamp(0.0, per - 1.0);
        let ty = ((gy + 0.5) / ts).floor().clamp(0.0, per - 1.0);
        Location {
            tile: TileId {
                level,
                face,
                x: tx as u32,
                y: ty as u32,
            },
            px: gx - tx * ts,
            py: gy - ty * ts,
        }
    }

    /// Ground size in metres of a pixel at the centre of a face at `level` (the largest pixel
    /// on the face for both projections).
    pub fn centre_pixel_m(&self, level: u8, radius_m: f64) -> f64 {
        let span = match self.projection {
            Projection::Gnomonic => 2.0,
            Projection::EqualAngle => std::f64::consts::FRAC_PI_2,
        };
        span * radius_m / self.face_pixels(level) as f64
    }

    /// Levels needed so that the finest level's largest pixel is no larger than `source_px_m`.
    pub fn levels_for(
        projection: Projection,
        tile_size: u32,
        radius_m: f64,
        source_px_m: f64,
    ) -> u8 {
        let probe = Layout {
            projection,
            tile_size,
            halo: 0,
            levels: 1,
        };
        let mut l = 0u8;
        while l + 1 < MAX_LEVELS && probe.centre_pixel_m(l, radius_m) > source_px_m * 1.0001 {
            l += 1;
        }
        l + 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locate_inverts_pixel_dir() {
        for projection in [Projection::Gnomonic, Projection::EqualAngle] {
            let lay = Layout {
                projection,
                tile_size: 64,
                halo: 2,
                levels: 4,
            };
            for face in Face::ALL {
                for (x, y, i, j) in [(0, 0, 0, 0), (3, 5, 63, 10), (7, 7, 31, 63)] {
                    let t = TileId {
                        level: 3,
                        face,
                        x,
                        y,
                    };
                    let loc = lay.locate(3, lay.pixel_dir(t, i, j));
                    assert_eq!(loc.tile, t);
                    assert!((loc.px - i as f64).abs() < 1e-9 && (loc.py - j as f64).abs() < 1e-9);
                }
            }
        }
    }

    #[test]
    fn level_count_matches_resolution() {
        // LDEM_4: 7580 m/px on the Moon; 512-px tiles: face is 6787 m/px at level 0.
        assert_eq!(
            Layout::levels_for(Projection::Gnomonic, 512, 1_737_400.0, 7580.84),
            1
        );
        // 20 m/px: level 8 is 26.5 m, level 9 is 13.3 m.
        assert_eq!(
            Layout::levels_for(Projection::Gnomonic, 512, 1_737_400.0, 20.0),
            10
        );
    }
}
