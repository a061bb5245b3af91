//! Point queries against a tileset, one per product, all through the [`Store`]: which tile and
//! pixel a latitude/longitude falls in, and the stored products there.

mod height;
mod horizon;
mod locate;
mod mip;

pub use self::height::{height, HeightAnswer};
pub(crate) use self::horizon::{floor_samples, sun_at_pixel, Profile};
pub use self::horizon::{horizon, shadow, HorizonAnswer, HorizonFrom, ShadowAnswer};
pub use self::locate::{check_latlon, locate, pick_level};
pub use self::mip::{face_texel, mip, FaceTexel, MipAnswer};
