//! The `penumbra-view` viewer: draws a baked tileset as displaced cube-sphere tile meshes with
//! the soft shadow of a selectable method computed in the fragment shader, in a window
//! (winit) or headless, and validates the GPU's lit fractions against the CPU methods of
//! `penumbra::shadow` at the same surface points (docs/viewer.md).
//!
//! Modules:
//! - [`options`]: the command line, typed and then checked.
//! - [`camera`]: the eye (f64, body frame), orbit and fly moves, the reversed-Z projection,
//!   and the sun by its sub-solar point, moved in azimuth/elevation at the view's target.
//! - [`lod`]: which tiles to draw (screen-space error, frustum and horizon culling).
//! - [`mesh`]: a tile's displaced grid relative to its centre, skirts, per-texel normals.
//! - [`scene`]: the tiles on the GPU (mesh, normals, albedo, shadow data), made on first use
//!   ([`maker`]) or, when they stream, by background loaders ([`stream`]).
//! - [`render`]: the terrain pass, drawing [`render::GpuTile`]s (what the scene makes) into
//!   colour, lit-fraction and texel-id targets, GPU timestamps, readback.
//! - [`core`]: what the window and the headless mode share: one frame.
//! - [`headless`], [`validate`], [`output`]: off-screen frames, the GPU against the CPU,
//!   files.
//! - [`flight`]: `--path`, a camera path flown headless or in the window with streamed
//!   tiles, and its frame-time report.
//! - [`window`], [`overlay`], [`font`]: the winit window, its composite pass and status line.
//! - [`gpu`]: the device (headless or for a window's surface).
//! - [`shadow`]: the GPU twins of the CPU shadow methods (WGSL beside the code) and the
//!   per-tile data they read (context raster, max and min pyramids, Fourier pyramid).

pub mod camera;
pub mod core;
pub mod flight;
pub mod font;
pub mod gpu;
pub mod headless;
pub mod lod;
pub mod maker;
pub mod mesh;
pub mod options;
pub mod output;
pub mod overlay;
pub mod render;
pub mod scene;
pub mod shadow;
pub mod stream;
pub mod validate;
pub mod window;
