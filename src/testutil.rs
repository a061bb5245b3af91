//! Helpers shared by the library's unit tests.

/// A xorshift stream of uniform numbers in [0, 1), the same for the same seed (≠ 0).
pub(crate) fn rng(seed: u64) -> impl FnMut() -> f64 {
    let mut st = seed;
    move || {
        st ^= st << 13;
        st ^= st >> 7;
        st ^= st << 17;
        (st >> 11) as f64 / (1u64 << 53) as f64
    }
}
