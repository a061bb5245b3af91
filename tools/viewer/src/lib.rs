//! The `penumbra-view` viewer: draws a baked tileset as displaced cube-sphere tile meshes with
//! the soft shadow of a selectable method computed in the fragment shader, in a window
//! (winit) or headless, and validates the GPU's lit fractions against the CPU methods of
//! `penumbra::shadow` at the same surface points.
//!
//! Modules (to come):
//! - [`shadow`]: the GPU twins of the CPU shadow methods (WGSL beside the code) and the
//!   per-tile data they read (context raster, max and min pyramids, Fourier pyramid).

pub mod gpu;
pub mod shadow;
