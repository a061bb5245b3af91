//! Which tiles to draw: the walk of `penumbra::lod` (screen-space error, frustum and horizon
//! culling), shared with the scene planner's camera paths (`penumbra::region::path_tiles`),
//! and the quadtree of a tileset's coverage.

pub use penumbra::lod::{Bounds, Chosen, LodParams, Quadtree, View};
use penumbra::manifest::Tileset;

/// The quadtree of `ts`'s coverage, bounded by its height product's lowest and highest
/// terrain (0, 0 without one).
pub fn quadtree(ts: &Tileset) -> Quadtree {
    let terrain_m = ts
        .products
        .height
        .as_ref()
        .map_or((0.0, 0.0), |h| (h.min_m, h.max_m));
    let terrain_m = if terrain_m.0.is_finite() && terrain_m.1.is_finite() {
        terrain_m
    } else {
        (0.0, 0.0)
    };
    Quadtree::from_layout(ts.layout, ts.body.radius_m, terrain_m, Some(ts.tile_set()))
}
