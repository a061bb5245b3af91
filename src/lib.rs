//! Penumbra: prepares planetary terrain for fast, accurate shadows.
//!
//! The library never parses arguments, prints or exits; the `penumbra` binary in `tools/` does.
//! Stages: [`dem`] readers → [`tiling`] into cube-face tiles ([`cube`], [`layout`]) described by a
//! [`manifest::Tileset`]; later stages (mipmaps, horizons, Fourier pyramids) consume a tileset
//! and add their products to its manifest. [`bake`] chains the stages a scene needs.

pub mod albedo;
pub mod bake;
pub mod body;
pub mod camera;
pub mod cube;
pub mod dem;
pub mod ephemeris;
pub mod error;
pub mod export;
pub mod exrcodec;
pub mod format;
pub mod fourier;
pub mod fsio;
pub mod graph;
pub mod horizon;
pub mod layout;
pub mod lod;
pub mod manifest;
pub mod mip;
pub mod package;
pub mod progress;
pub mod query;
pub mod region;
pub mod runner;
pub mod scene;
pub mod shadow;
pub mod sink;
pub mod stress;
pub mod synthetic;
pub mod tileset;
pub mod tiling;

#[cfg(test)]
mod testutil;

pub use error::{Error, Result};
