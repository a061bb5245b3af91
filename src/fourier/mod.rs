//! Fourier-compressed horizon maps (Fritsch et al. 2025): per pixel the truncated real DFT of
//! the horizon over the plane azimuths, stored as 16-bit coefficient pyramids, and the sun's
//! visibility reconstructed from them. Specified in docs/fourier.md.
//!
//! - [`series`]: the per-pixel DFT (rustfft), the taper, the series' evaluation;
//! - [`pyramid`]: one tile's groups of coefficients, their layout, encoding and file;
//! - [`sun`]: the lit fraction of the sun's disc from a horizon, by the paper's three models
//!   and an exact one;
//! - `stage`: the stage, from stored raw maps or streamed from the horizon stage.

pub mod pyramid;
pub mod series;
pub mod sun;

pub use self::series::{evaluate, max_coefficients, Sigma, Transform};
pub use crate::format::fourier::{Encoding, Layout, Pyramid, Reduce};
pub mod stage;
pub mod stream;

pub use self::stage::{build_fourier, Encoder, FourierOptions, FourierReport, FourierStage, STAGE};
pub use self::stream::{FourierSink, StreamedFourier};
