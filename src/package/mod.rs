//! Packages made from a tileset for the tools people already run (docs/packaging.md):
//! [`celestia`], a Celestia addon (virtual textures of the albedo and of a normal map derived
//! from the heights, and the catalog that hands them to the body), read back with [`ssc`], a
//! reader of Celestia's catalog grammar; [`bundle`], `penumbra package`: that addon with the
//! tileset itself as its cube-face products, a README and an archive. Orchestration: reads the
//! tileset through [`crate::tileset::Store`] only and writes through [`crate::format::vt`],
//! [`crate::format::archive`] and [`crate::tileset::copy`].

pub mod bundle;
pub mod celestia;
pub mod ssc;
