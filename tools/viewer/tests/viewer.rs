//! Tests of the `penumbra-view` viewer (headless on Mesa's lavapipe in CI).
mod shadow_gpu;
