//! Penumbra: prepares planetary terrain for fast, accurate shadows.
//!
//! The library never parses arguments, prints or exits; the `penumbra` binary in `tools/` does.
//! Stages: [`dem`] readers → [`tiling`] into cube-face tiles ([`cube`]) → later mipmaps,
//! horizons and Fourier pyramids, each a function over a [`manifest::Tileset`].

pub mod body;
pub mod cube;
pub mod dem;
pub mod error;

pub use error::{Error, Result};
