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

/// A DEM held in memory: `w × h` samples `f(column, row)` on `georef`.
pub(crate) fn synthetic_dem(
    w: usize,
    h: usize,
    georef: crate::dem::GeoRef,
    f: impl Fn(usize, usize) -> f32,
) -> crate::dem::Dem {
    use crate::dem::{Dem, DemParts, DEFAULT_MAX_FILL_PX};
    let mut v = Vec::with_capacity(w * h);
    for r in 0..h {
        for c in 0..w {
            v.push(f(c, r));
        }
    }
    Dem::new(
        DemParts::in_memory(georef, w, h, v, "test"),
        DEFAULT_MAX_FILL_PX,
    )
    .unwrap()
}

/// A pixel-registered geographic raster of the whole body, `w × h` pixels, columns from 0°E.
pub(crate) fn global_georef(w: usize, h: usize) -> crate::dem::GeoRef {
    let d = 360.0 / w as f64;
    crate::dem::GeoRef {
        crs: crate::dem::Crs::Geographic,
        x0: d / 2.0,
        y0: 90.0 - d / 2.0,
        dx: d,
        dy: 180.0 / h as f64,
    }
}
