//! The horizon stage: for every pixel of a tile, the elevation angle of the horizon in `A`
//! azimuths, geodesic and curvature-exact, seeing across tile and face edges as far as any
//! terrain of the body could rise above it. Specified in docs/horizons.md.

mod core;

pub use self::core::{
    compass_azimuth_deg, horizons, horizons_reference_step, horizons_scan, plane_azimuth, Context,
    Method, Rect,
};
