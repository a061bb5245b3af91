//! Fourier-compressed horizon maps (Fritsch et al. 2025): per pixel the truncated real DFT of
//! the horizon over the plane azimuths, stored as 16-bit coefficient pyramids, and the sun's
//! visibility reconstructed from them. Specified in docs/fourier.md.

pub mod sun;
