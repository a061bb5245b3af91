//! Tests of the `penumbra-view` viewer (headless on Mesa's lavapipe in CI).
//!
//! Frames need a GPU adapter: without one a test prints `skipping: …` and passes, except under
//! `CI=true`, where it fails (`.ci/run` installs lavapipe, so CI always has one).

// Fixtures (tilesets baked once per run), the adapter probe, and running the binary.
mod util;
// Headless frames: light and shadow where they belong, determinism, GPU against CPU.
mod headless;
// Bad input: exit 2 with a message that says what to do, nothing written.
mod bad_input;
// The window under Xvfb: a few frames and a screenshot; no window system: exit 2.
mod window;
// The GPU shadow methods against the CPU methods, texel by texel (the shadow module's own).
mod shadow_gpu;
// A package made by `penumbra package` draws as the tileset it was made from.
mod package;
// A camera path flown headless and in the window: frames, report, bad paths.
mod flight;
