//! The horizon stage: for every pixel of a tile, the elevation angle of the horizon in `A`
//! azimuths, geodesic and curvature-exact, seeing across tile and face edges as far as any
//! terrain of the body could rise above it. Specified in docs/horizons.md.
//!
//! `geometry` holds the context raster on one face's extended gnomonic plane (straight lines
//! there are great circles) and the exact search along an observer's ray; `method` runs one of
//! the two algorithms over it: the brute-force `reference` march, or the fast method (exact
//! `near` field, per-azimuth upper-hull `sweep` beyond). `stage` builds those rasters from
//! a tileset and stores the raw maps (the point query is `crate::query::horizon`).

pub mod bound;
mod budget;
pub mod device;
mod far;
mod geometry;
mod linesweep;
mod method;
mod near;
mod pyramid;
mod reference;
pub(crate) mod stage;
mod sweep;

pub use self::far::FarRing;
pub use self::geometry::{compass_azimuth_deg, plane_azimuth, Context, Rect};
pub(crate) use self::geometry::{Axis, Ray};
pub use self::method::{
    horizons, horizons_far, horizons_reference_step, horizons_with, FarHorizons, Method,
};
pub use self::near::{DEFAULT_NEAR_PX, MAX_NEAR_PX};
pub use self::stage::{
    build_horizons, context_for, default_fine_margin_px, prune_candidates, prune_candidates_with,
    reach_rad, report_context, terrain_range, tile_bounds, HorizonOptions, HorizonReport,
    HorizonStage, Reach, FINE_MARGIN_PX, STAGE,
};
pub use crate::format::horizon::{
    read_horizon_exr, tile_path, write_horizon_exr, HorizonPrecision, AZIMUTH_CONVENTION, PATTERN,
};
