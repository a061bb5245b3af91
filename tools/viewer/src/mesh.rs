/*!
A tile's drawable data, built on the CPU in f64 from its stored heights: a displaced grid of
`grid × grid` quads (vertices in f32 metres relative to the tile's centre, so that precision
does not depend on where on the body the tile lies), a skirt hanging from its edges that
closes the cracks where a neighbour is drawn at another level, and per-texel normals for the
fragment shader's Lambert term (with a flag for texels without data).

The grid's edges lie on the tile's edges (pixel coordinates −½ and n − ½), where heights are
interpolated from the halo, so neighbours at the same level meet without a gap. Every vertex
carries its fractional tile-pixel coordinates: the fragment shader rounds them to the nearest
interior texel, the texel whose shadow it shows.
*/

use bytemuck::{Pod, Zeroable};
use penumbra::cube::{dot, Vec3};
use penumbra::format::height::HeightTile;
use penumbra::layout::{Layout, TileId};

use crate::camera::{add, cross, norm, scale, sub};

/// One vertex: position relative to the tile's centre (m, body frame) and fractional tile
/// pixel coordinates (pixel centres at integers).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    pub pos: [f32; 3],
    pub ij: [f32; 2],
}

/// A tile ready for upload.
#[derive(Clone, Debug)]
pub struct TileMesh {
    pub tile: TileId,
    /// Interior pixels per side.
    pub n: usize,
    /// The tile's centre, body frame (m, f64): the origin of its vertices.
    pub centre: Vec3,
    /// `(grid + 1)²` surface vertices, then `4·grid + 4`… skirt vertices (see [`indices`]).
    pub vertices: Vec<Vertex>,
    /// Per texel of the interior and a one-texel border, `(n + 2)²` row-major (texel (i, j) at
    /// (i + 1, j + 1)): unit normal (body frame) and 1 where the texel has data, 0 where not.
    pub normals: Vec<[f32; 4]>,
    /// Lowest and highest interior height (m; NaN when the tile has no data).
    pub height_range: (f32, f32),
}

/// Quads per side of a tile's grid for tiles of `n` pixels.
pub fn grid_for(n: usize) -> usize {
    n.clamp(1, 64)
}

/// Build the mesh of `tile` from its stored heights.
pub fn build(layout: &Layout, radius_m: f64, tile: TileId, h: &HeightTile) -> TileMesh {
    let n = layout.tile_size as usize;
    let halo = layout.halo as f64;
    let g = grid_for(n);
    // Interior height range.
    let hl = layout.halo as usize;
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for j in 0..n {
        for i in 0..n {
            let v = h.height[(j + hl) * h.size + i + hl];
            if v.is_finite() {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
    }
    let (lo, hi) = if lo <= hi {
        (lo, hi)
    } else {
        (f32::NAN, f32::NAN)
    };
    let fill = if lo.is_finite() { lo } else { 0.0 };
    let dir = |i: f64, j: f64| -> Vec3 {
        let (s, t) = layout.global_st(
            tile.level,
            tile.x as f64 * n as f64 + i,
            tile.y as f64 * n as f64 + j,
        );
        layout.st_to_dir(tile.face, s, t)
    };
    let mid = if lo.is_finite() {
        (lo as f64 + hi as f64) / 2.0
    } else {
        0.0
    };
    let centre = scale(
        dir(n as f64 / 2.0 - 0.5, n as f64 / 2.0 - 0.5),
        radius_m + mid,
    );
    let step = n as f64 / g as f64;
    let mut vertices = Vec::with_capacity((g + 1) * (g + 1) + 4 * (g + 1));
    let mut top = Vec::with_capacity((g + 1) * (g + 1));
    for b in 0..=g {
        for a in 0..=g {
            let (i, j) = (a as f64 * step - 0.5, b as f64 * step - 0.5);
            let hv = h.bilinear(i + halo, j + halo);
            let hv = if hv.is_finite() { hv } else { fill };
            let p = scale(dir(i, j), radius_m + hv as f64);
            top.push((p, [i as f32, j as f32]));
            let rel = sub(p, centre);
            vertices.push(Vertex {
                pos: [rel[0] as f32, rel[1] as f32, rel[2] as f32],
                ij: [i as f32, j as f32],
            });
        }
    }
    // Skirt: the edge vertices again, lowered along the vertical by a few texels' worth of
    // the grid's error (and no more than the tile's relief plus a texel).
    let texel = layout.centre_pixel_m(tile.level, radius_m);
    let relief = if lo.is_finite() {
        (hi - lo) as f64
    } else {
        0.0
    };
    let depth = (4.0 * texel * step).min(relief + texel).max(texel);
    for k in skirt_ring(g) {
        let (p, ij) = top[k];
        let d = scale(p, -depth / norm(p));
        let rel = sub(add(p, d), centre);
        vertices.push(Vertex {
            pos: [rel[0] as f32, rel[1] as f32, rel[2] as f32],
            ij,
        });
    }
    let normals = texel_normals(layout, radius_m, h, &dir);
    TileMesh {
        tile,
        n,
        centre,
        vertices,
        normals,
        height_range: (lo, hi),
    }
}

/// Indices into the `(g + 1)²` grid of the edge vertices, once round the tile (top row left
/// to right, right column down, bottom row right to left, left column up), closed.
fn skirt_ring(g: usize) -> Vec<usize> {
    let w = g + 1;
    let mut v = Vec::with_capacity(4 * g + 1);
    v.extend(0..g); // top row
    v.extend((0..g).map(|b| b * w + g)); // right column
    v.extend((0..g).map(|a| g * w + (g - a))); // bottom row
    v.extend((0..g).map(|b| (g - b) * w)); // left column
    v.push(0);
    v
}

/// The triangle list of a tile with `g` quads per side: the grid, then the skirt.
/// (Triangles face outwards, counter-clockwise seen from above; the pipeline does not cull.)
pub fn indices(g: usize) -> Vec<u32> {
    let w = (g + 1) as u32;
    let mut idx = Vec::with_capacity(6 * g * g + 6 * 4 * g);
    for b in 0..g as u32 {
        for a in 0..g as u32 {
            let k = b * w + a;
            idx.extend([k, k + w, k + 1, k + 1, k + w, k + w + 1]);
        }
    }
    let ring = skirt_ring(g);
    let base = w * w;
    for s in 0..ring.len() - 1 {
        let (t0, t1) = (ring[s] as u32, ring[s + 1] as u32);
        let (b0, b1) = (base + s as u32, base + s as u32 + 1);
        idx.extend([t0, t1, b0, b0, t1, b1]);
    }
    idx
}

/// Per texel of the interior and a one-texel border around it (`(n + 2)²`, row-major, texel
/// (i, j) at (i + 1, j + 1)) the outward unit normal from the central differences of the pixel
/// positions (the halo gives the edge texels their outer neighbours), as the CPU's shaded
/// relief computes it; one-sided where a neighbour is missing, radial where both are;
/// [0, 0, 0, 0] where the texel has no data. The border lets the shader interpolate normals
/// across a tile's edge as its neighbour does (no shading seam between tiles).
fn texel_normals(
    layout: &Layout,
    radius_m: f64,
    h: &HeightTile,
    dir: &dyn Fn(f64, f64) -> Vec3,
) -> Vec<[f32; 4]> {
    let n = layout.tile_size as i64;
    let halo = layout.halo as i64;
    let size = h.size as i64;
    let pos = |i: i64, j: i64| -> Option<Vec3> {
        let (x, y) = (i + halo, j + halo);
        if !(0..size).contains(&x) || !(0..size).contains(&y) {
            return None;
        }
        let v = h.height[(y * size + x) as usize];
        v.is_finite()
            .then(|| scale(dir(i as f64, j as f64), radius_m + v as f64))
    };
    let side = (n + 2) as usize;
    let mut out = vec![[0.0f32; 4]; side * side];
    for j in -1..=n {
        for i in -1..=n {
            let Some(p) = pos(i, j) else { continue };
            let e = pos(i + 1, j).unwrap_or(p);
            let w = pos(i - 1, j).unwrap_or(p);
            let nn = pos(i, j - 1).unwrap_or(p);
            let s = pos(i, j + 1).unwrap_or(p);
            let c = cross(sub(e, w), sub(nn, s));
            let c = if dot(c, p) < 0.0 { scale(c, -1.0) } else { c };
            let l = norm(c);
            let nrm = if l > 0.0 {
                scale(c, 1.0 / l)
            } else {
                scale(p, 1.0 / norm(p))
            };
            out[(j + 1) as usize * side + (i + 1) as usize] =
                [nrm[0] as f32, nrm[1] as f32, nrm[2] as f32, 1.0];
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use penumbra::cube::{Face, Projection};

    fn flat(size: usize, v: f32) -> HeightTile {
        HeightTile {
            size,
            height: vec![v; size * size],
            mask: vec![0; size * size],
        }
    }

    #[test]
    fn neighbours_share_their_edge_vertices() {
        let lay = Layout {
            projection: Projection::Gnomonic,
            tile_size: 16,
            halo: 2,
            levels: 3,
        };
        let r = 1000.0;
        let h = flat(20, 5.0);
        let a = TileId {
            level: 2,
            face: Face::Px,
            x: 1,
            y: 1,
        };
        let b = TileId { x: 2, ..a };
        let (ma, mb) = (build(&lay, r, a, &h), build(&lay, r, b, &h));
        let g = grid_for(16);
        let w = g + 1;
        for row in 0..=g {
            let va = ma.vertices[row * w + g].pos;
            let vb = mb.vertices[row * w].pos;
            let pa = add(ma.centre, [va[0] as f64, va[1] as f64, va[2] as f64]);
            let pb = add(mb.centre, [vb[0] as f64, vb[1] as f64, vb[2] as f64]);
            assert!(norm(sub(pa, pb)) < 1e-3, "row {row}");
        }
        // Flat terrain: every normal is radial, every texel has data (border included).
        for (k, nv) in ma.normals.iter().enumerate() {
            let (i, j) = ((k % 18) as f64 - 1.0, (k / 18) as f64 - 1.0);
            let (s, t) = lay.global_st(2, 16.0 + i, 16.0 + j);
            let d = lay.st_to_dir(Face::Px, s, t);
            let c = nv[0] as f64 * d[0] + nv[1] as f64 * d[1] + nv[2] as f64 * d[2];
            assert!(c > 0.9999 && nv[3] == 1.0, "{k}: {nv:?}");
        }
    }

    #[test]
    fn indices_stay_in_range_and_skirts_hang_below() {
        for g in [1, 4, 64] {
            let idx = indices(g);
            let nv = (g + 1) * (g + 1) + skirt_ring(g).len();
            assert!(idx.iter().all(|&k| (k as usize) < nv));
            assert_eq!(idx.len() % 3, 0);
        }
        let lay = Layout {
            projection: Projection::Gnomonic,
            tile_size: 8,
            halo: 1,
            levels: 1,
        };
        let mut h = flat(10, 100.0);
        h.height[0] = f32::NAN;
        let t = TileId {
            level: 0,
            face: Face::Nz,
            x: 0,
            y: 0,
        };
        let m = build(&lay, 1000.0, t, &h);
        let w = grid_for(8) + 1;
        let surf = m.vertices[0].pos;
        let skirt = m.vertices[w * w].pos;
        let r = |p: [f32; 3]| norm(add(m.centre, [p[0] as f64, p[1] as f64, p[2] as f64]));
        assert!(r(skirt) < r(surf));
        assert_eq!(m.height_range, (100.0, 100.0));
    }
}
