//! The horizon stage: for every pixel of a tile, the elevation angle of the horizon in `A`
//! azimuths, geodesic and curvature-exact, seeing across tile and face edges as far as any
//! terrain of the body could rise above it. Specified in docs/horizons.md.
//!
//! [`core`] holds the two algorithms over a context raster on one face's extended gnomonic
//! plane (straight lines there are great circles): the brute-force reference march and the
//! per-azimuth upper-hull sweep. [`stage`] builds those rasters from a tileset, stores the raw
//! maps and answers point queries.

mod core;
mod near;
mod stage;

pub use self::core::{
    compass_azimuth_deg, horizons, horizons_reference_step, horizons_with, plane_azimuth, Context,
    Method, Rect,
};
pub use self::near::{DEFAULT_NEAR_PX, MAX_NEAR_PX};
pub use self::stage::{
    build_horizons, context_for, query, reach_rad, read_horizon_exr, terrain_range, tile_path,
    write_horizon_exr, HorizonAnswer, HorizonOptions, HorizonPrecision, HorizonReport, Reach,
    AZIMUTH_CONVENTION, PATTERN, STAGE,
};
