//! The mip kernels: level sizes, directed f16 rounding, and the maximum and (min, max)
//! pyramids of a tile (separable 3×3 level 0, 2×2 reductions up; AVX where present, bit-identical
//! to the portable code) and of a face's tile grid. Texel and no-data conventions: [`super`].

use crate::error::{Error, Result};

pub use crate::format::mip::{f16_down, f16_up, level_sizes};

pub(super) const NEG_INF: f32 = f32::NEG_INFINITY;
pub(super) const POS_INF: f32 = f32::INFINITY;

/// Fold `v` into a NaN-free running maximum: a NaN `v` leaves `acc` (x86 `maxps v, acc`).
#[inline(always)]
pub(super) fn fmax(acc: f32, v: f32) -> f32 {
    if v > acc {
        v
    } else {
        acc
    }
}

#[inline(always)]
pub(super) fn fmin(acc: f32, v: f32) -> f32 {
    if v < acc {
        v
    } else {
        acc
    }
}

/// −∞ (an all-NaN footprint) back to NaN.
#[inline(always)]
pub(super) fn nan_if(v: f32, empty: f32) -> f32 {
    if v == empty {
        f32::NAN
    } else {
        v
    }
}

/// A maximum pyramid: `max[k]` is level k, `sizes[k]²` texels, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct MaxPyramid {
    pub sizes: Vec<usize>,
    pub max: Vec<Vec<f32>>,
}

/// A (min, max) pyramid: `min[k]`, `max[k]` are level k, `sizes[k]²` texels, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct MinMaxPyramid {
    pub sizes: Vec<usize>,
    pub min: Vec<Vec<f32>>,
    pub max: Vec<Vec<f32>>,
}

impl MaxPyramid {
    /// An allocated pyramid for `n`-texel tiles, for [`max_pyramid_into`].
    pub fn new(n: usize) -> MaxPyramid {
        let sizes = level_sizes(n);
        let max = sizes.iter().map(|&s| vec![0.0; s * s]).collect();
        MaxPyramid { sizes, max }
    }
}

impl MinMaxPyramid {
    /// An allocated pyramid for `n`-texel tiles, for [`minmax_pyramid_into`].
    pub fn new(n: usize) -> MinMaxPyramid {
        let sizes = level_sizes(n);
        let min = sizes.iter().map(|&s| vec![0.0; s * s]).collect();
        let max = sizes.iter().map(|&s| vec![0.0; s * s]).collect();
        MinMaxPyramid { sizes, min, max }
    }

    /// The whole-pyramid extrema (the 1×1 level).
    pub fn top(&self) -> (f32, f32) {
        (self.min.last().unwrap()[0], self.max.last().unwrap()[0])
    }
}

/// Interior size of a stored tile, after checking the buffer against it.
fn interior(height: &[f32], stored_size: usize, halo: usize) -> Result<usize> {
    if halo < 1 || stored_size <= 2 * halo {
        return Err(Error::usage(format!(
            "mipmaps need a halo of at least 1 pixel and a non-empty interior (stored size \
             {stored_size}, halo {halo})"
        )));
    }
    if height.len() != stored_size * stored_size {
        return Err(Error::usage(format!(
            "height buffer holds {} samples, not {stored_size}²",
            height.len()
        )));
    }
    Ok(stored_size - 2 * halo)
}

/// Whether the AVX kernels can run here (detected once; the results are bit-identical to the
/// portable code, so the output does not depend on it).
#[cfg(target_arch = "x86_64")]
#[inline]
fn avx() -> bool {
    std::arch::is_x86_feature_detected!("avx")
}

/// `out[i]` = NaN-ignoring max of `row[i..i+3]` (−∞ when all NaN).
#[inline]
fn hmax3(row: &[f32], out: &mut [f32]) {
    let n = out.len();
    let row = &row[..n + 2];
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if avx() {
        // SAFETY: AVX is present (checked above).
        done = unsafe { simd::h3::<true>(row, out) };
    }
    for i in done..n {
        out[i] = fmax(fmax(fmax(NEG_INF, row[i]), row[i + 1]), row[i + 2]);
    }
}

#[inline]
fn hminmax3(row: &[f32], lo: &mut [f32], hi: &mut [f32]) {
    let n = lo.len();
    let (row, hi) = (&row[..n + 2], &mut hi[..n]);
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if avx() {
        // SAFETY: AVX is present (checked above).
        done = unsafe { simd::h3_both(row, lo, hi) };
    }
    for i in done..n {
        lo[i] = fmin(fmin(fmin(POS_INF, row[i]), row[i + 1]), row[i + 2]);
        hi[i] = fmax(fmax(fmax(NEG_INF, row[i]), row[i + 1]), row[i + 2]);
    }
}

/// `out[i]` = extreme of NaN-free `a[i]`, `b[i]`, `c[i]` (the empty value ±∞ kept), and the
/// same with the empty value turned to NaN in `dst`. `out` is a cache-resident scratch row the
/// cascade reads next; `dst` is the level-0 output row, written with non-temporal stores when
/// `NT` (and AVX is present): in a large tile level 0 is most of the bytes written and is not
/// read again soon, so it bypasses the cache (no read-for-ownership). Call [`store_fence`]
/// after the last row.
#[inline]
fn v3_out<const MAX: bool, const NT: bool>(
    a: &[f32],
    b: &[f32],
    c: &[f32],
    out: &mut [f32],
    dst: &mut [f32],
) {
    let n = out.len();
    let (a, b, c, dst) = (&a[..n], &b[..n], &c[..n], &mut dst[..n]);
    let empty = if MAX { NEG_INF } else { POS_INF };
    let one = |i: usize| {
        if MAX {
            fmax(fmax(a[i], b[i]), c[i])
        } else {
            fmin(fmin(a[i], b[i]), c[i])
        }
    };
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if avx() {
        // Elements before `dst` reaches a cache-line boundary (it is 4-byte aligned as an f32):
        // the streamed part then covers whole lines only, and the partial lines at either end
        // are ordinary stores (a partly written non-temporal line is slow).
        let head = if NT {
            ((64 - dst.as_ptr() as usize % 64) % 64 / 4).min(n)
        } else {
            0
        };
        for i in 0..head {
            let v = one(i);
            out[i] = v;
            dst[i] = nan_if(v, empty);
        }
        // SAFETY: AVX is present (checked above) and, when `NT`, `dst[head..]` starts 64-byte
        // aligned.
        done = head
            + unsafe {
                simd::v3_stream::<MAX, NT>(
                    &a[head..],
                    &b[head..],
                    &c[head..],
                    &mut out[head..],
                    &mut dst[head..],
                )
            };
    }
    for i in done..n {
        let v = one(i);
        out[i] = v;
        dst[i] = nan_if(v, empty);
    }
}

/// Order the non-temporal stores of [`v3_out`] before whatever follows.
#[inline]
fn store_fence() {
    #[cfg(target_arch = "x86_64")]
    if avx() {
        // SAFETY: SSE is part of every x86_64 CPU.
        unsafe { std::arch::x86_64::_mm_sfence() };
    }
}

/// Scratch rows of every level: `pairs[k][r % 2]` holds row `r` of level `k` without NaN
/// (the empty value ±∞), cache-resident while the output rows are streamed out.
fn scratch_pairs(sizes: &[usize]) -> Vec<[Vec<f32>; 2]> {
    sizes
        .iter()
        .map(|&w| [vec![0.0; w], vec![0.0; w]])
        .collect()
}

/// Row `r` of level `k` is in `pairs[k][r % 2]` (and in `levels[k]`): when it completes a pair
/// of rows (or is the last row of an odd level), make the row of level k+1 they reduce to, in
/// `pairs[k + 1]` and `levels[k + 1]`, and so on up the pyramid.
fn cascade_raw<const MAX: bool, const NT: bool>(
    sizes: &[usize],
    levels: &mut [Vec<f32>],
    pairs: &mut [[Vec<f32>; 2]],
    k: usize,
    r: usize,
) {
    let (mut k, mut r) = (k, r);
    while k + 1 < levels.len() {
        let w = sizes[k];
        if r % 2 == 0 && r != w - 1 {
            return;
        }
        let y = r / 2;
        let w2 = sizes[k + 1];
        let (lo, hi) = pairs.split_at_mut(k + 1);
        let [r0, r1] = &lo[k];
        let r1 = if r % 2 == 1 { r1 } else { r0 };
        let out = &mut hi[0][y % 2];
        reduce_raw::<MAX>(r0, r1, out);
        emit::<MAX, NT>(out, &mut levels[k + 1][y * w2..(y + 1) * w2]);
        k += 1;
        r = y;
    }
}

/// Reduce rows `r0`, `r1` of a `w`-wide level into one row of ⌈w/2⌉ texels of the next
/// (pairs of columns; the last column alone when `w` is odd). NaN-ignoring; NaN when all four
/// are NaN.
#[inline]
fn reduce_row<const MAX: bool>(r0: &[f32], r1: &[f32], out: &mut [f32]) {
    let w = r0.len();
    let (r1, out) = (&r1[..w], &mut out[..w.div_ceil(2)]);
    let empty = if MAX { NEG_INF } else { POS_INF };
    let fold = |acc: f32, v: f32| if MAX { fmax(acc, v) } else { fmin(acc, v) };
    let pairs = w / 2;
    #[cfg(target_arch = "x86_64")]
    let done = simd::reduce_pairs::<MAX>(&r0[..2 * pairs], &r1[..2 * pairs], &mut out[..pairs]);
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    for x in done..pairs {
        let v = fold(
            fold(fold(fold(empty, r0[2 * x]), r0[2 * x + 1]), r1[2 * x]),
            r1[2 * x + 1],
        );
        out[x] = nan_if(v, empty);
    }
    if w % 2 == 1 {
        out[pairs] = nan_if(fold(fold(empty, r0[w - 1]), r1[w - 1]), empty);
    }
}

/// [`reduce_row`] of rows without NaN (the empty value ±∞ instead, also in `out`): no empty
/// value to fold in first. Same fold order as the SIMD code of [`reduce_row`]: each column of
/// the pair vertically, then the even column with the odd.
#[inline]
fn reduce_raw<const MAX: bool>(r0: &[f32], r1: &[f32], out: &mut [f32]) {
    let w = r0.len();
    let (r1, out) = (&r1[..w], &mut out[..w.div_ceil(2)]);
    let fold = |acc: f32, v: f32| if MAX { fmax(acc, v) } else { fmin(acc, v) };
    let pairs = w / 2;
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if avx() {
        // SAFETY: AVX is present (checked above).
        done = unsafe {
            simd::reduce_raw::<MAX>(&r0[..2 * pairs], &r1[..2 * pairs], &mut out[..pairs])
        };
    }
    for x in done..pairs {
        let even = fold(r0[2 * x], r1[2 * x]);
        let odd = fold(r0[2 * x + 1], r1[2 * x + 1]);
        out[x] = fold(even, odd);
    }
    if w % 2 == 1 {
        out[pairs] = fold(r0[w - 1], r1[w - 1]);
    }
}

/// `dst` = `raw` with the empty value (±∞) turned to NaN, written with non-temporal stores when
/// `NT` (see [`v3_out`]).
#[inline]
fn emit<const MAX: bool, const NT: bool>(raw: &[f32], dst: &mut [f32]) {
    let n = raw.len();
    let dst = &mut dst[..n];
    let empty = if MAX { NEG_INF } else { POS_INF };
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if avx() && n >= 32 {
        let head = if NT {
            (64 - dst.as_ptr() as usize % 64) % 64 / 4
        } else {
            0
        };
        for i in 0..head {
            dst[i] = nan_if(raw[i], empty);
        }
        // SAFETY: AVX is present (checked above) and, when `NT`, `dst[head..]` starts 64-byte
        // aligned.
        done = head + unsafe { simd::emit::<MAX, NT>(&raw[head..], &mut dst[head..]) };
    }
    for i in done..n {
        dst[i] = nan_if(raw[i], empty);
    }
}

#[cfg(target_arch = "x86_64")]
mod simd {
    //! SSE2 (part of every x86-64 CPU) for the 2×2 step: LLVM does not vectorize the
    //! de-interleaving of column pairs on its own. `maxps v, acc` returns `acc` when `v` is NaN,
    //! which is exactly the NaN-ignoring fold of the scalar code.
    use std::arch::x86_64::*;

    /// Reduces 4 output texels per step; returns how many outputs it wrote.
    #[inline]
    pub fn reduce_pairs<const MAX: bool>(r0: &[f32], r1: &[f32], out: &mut [f32]) -> usize {
        let steps = out.len() / 4;
        assert!(r0.len() >= steps * 8 && r1.len() >= steps * 8);
        // SAFETY: SSE2 is always present on x86_64; every load reads r0/r1[8k..8k+8] and every
        // store writes out[4k..4k+4] with k < steps, inside the slices (checked above).
        unsafe {
            let empty = _mm_set1_ps(if MAX {
                f32::NEG_INFINITY
            } else {
                f32::INFINITY
            });
            let nan = _mm_set1_ps(f32::NAN);
            let fold = |acc: __m128, v: __m128| {
                if MAX {
                    _mm_max_ps(v, acc)
                } else {
                    _mm_min_ps(v, acc)
                }
            };
            for k in 0..steps {
                let (p0, p1, q) = (
                    r0.as_ptr().add(8 * k),
                    r1.as_ptr().add(8 * k),
                    out.as_mut_ptr().add(4 * k),
                );
                let a = fold(fold(empty, _mm_loadu_ps(p0)), _mm_loadu_ps(p1));
                let b = fold(
                    fold(empty, _mm_loadu_ps(p0.add(4))),
                    _mm_loadu_ps(p1.add(4)),
                );
                let even = _mm_shuffle_ps::<0b10_00_10_00>(a, b);
                let odd = _mm_shuffle_ps::<0b11_01_11_01>(a, b);
                let m = fold(even, odd);
                let is_empty = _mm_cmpeq_ps(m, empty);
                let r = _mm_or_ps(_mm_andnot_ps(is_empty, m), _mm_and_ps(is_empty, nan));
                _mm_storeu_ps(q, r);
            }
        }
        steps * 4
    }

    // The AVX kernels below handle 8 outputs per step and return how many they wrote; the
    // caller finishes the tail with the portable code. `_mm256_max_ps(v, acc)` is `acc` when `v`
    // is NaN, like the scalar fold.

    #[inline]
    #[target_feature(enable = "avx")]
    unsafe fn fold8<const MAX: bool>(acc: __m256, v: __m256) -> __m256 {
        if MAX {
            _mm256_max_ps(v, acc)
        } else {
            _mm256_min_ps(v, acc)
        }
    }

    #[inline]
    #[target_feature(enable = "avx")]
    unsafe fn empty8<const MAX: bool>() -> __m256 {
        _mm256_set1_ps(if MAX {
            f32::NEG_INFINITY
        } else {
            f32::INFINITY
        })
    }

    /// [`super::reduce_raw`], 8 outputs per step.
    #[target_feature(enable = "avx")]
    pub unsafe fn reduce_raw<const MAX: bool>(r0: &[f32], r1: &[f32], out: &mut [f32]) -> usize {
        let steps = out.len() / 8;
        assert!(r0.len() >= steps * 16 && r1.len() >= steps * 16);
        let (p0, p1, q) = (r0.as_ptr(), r1.as_ptr(), out.as_mut_ptr());
        for k in 0..steps {
            let i = 16 * k;
            // a = columns i..i+8, b = i+8..i+16, each folded over the two rows.
            let a = fold8::<MAX>(_mm256_loadu_ps(p0.add(i)), _mm256_loadu_ps(p1.add(i)));
            let b = fold8::<MAX>(
                _mm256_loadu_ps(p0.add(i + 8)),
                _mm256_loadu_ps(p1.add(i + 8)),
            );
            // Lanes a0..a3 b0..b3 and a4..a7 b4..b7, so that the in-lane shuffles below give
            // the even and odd columns in order.
            let lo = _mm256_permute2f128_ps::<0x20>(a, b);
            let hi = _mm256_permute2f128_ps::<0x31>(a, b);
            let even = _mm256_shuffle_ps::<0b10_00_10_00>(lo, hi);
            let odd = _mm256_shuffle_ps::<0b11_01_11_01>(lo, hi);
            _mm256_storeu_ps(q.add(8 * k), fold8::<MAX>(even, odd));
        }
        steps * 8
    }

    /// A non-temporal store (64-byte aligned `p`) when `NT`, else an ordinary one.
    #[inline]
    #[target_feature(enable = "avx")]
    unsafe fn store<const NT: bool>(p: *mut f32, v: __m256) {
        if NT {
            _mm256_stream_ps(p, v)
        } else {
            _mm256_storeu_ps(p, v)
        }
    }

    /// [`super::emit`]: when `NT`, `dst` must be 64-byte aligned.
    #[target_feature(enable = "avx")]
    pub unsafe fn emit<const MAX: bool, const NT: bool>(raw: &[f32], dst: &mut [f32]) -> usize {
        let steps = raw.len().min(dst.len()) / 16 * 2;
        assert!(!NT || dst.as_ptr() as usize % 64 == 0);
        let (e, nan) = (empty8::<MAX>(), _mm256_set1_ps(f32::NAN));
        let (p, d) = (raw.as_ptr(), dst.as_mut_ptr());
        for k in 0..steps {
            let m = _mm256_loadu_ps(p.add(8 * k));
            let is_empty = _mm256_cmp_ps::<_CMP_EQ_OQ>(m, e);
            store::<NT>(d.add(8 * k), _mm256_blendv_ps(m, nan, is_empty));
        }
        steps * 8
    }

    /// `out[i]` = NaN-ignoring extreme of `row[i..i+3]`; `row.len() == out.len() + 2`.
    #[target_feature(enable = "avx")]
    pub unsafe fn h3<const MAX: bool>(row: &[f32], out: &mut [f32]) -> usize {
        let steps = out.len() / 8;
        assert!(row.len() >= steps * 8 + 2);
        let e = empty8::<MAX>();
        let (p, q) = (row.as_ptr(), out.as_mut_ptr());
        for k in 0..steps {
            let i = 8 * k;
            let a = fold8::<MAX>(e, _mm256_loadu_ps(p.add(i)));
            let a = fold8::<MAX>(a, _mm256_loadu_ps(p.add(i + 1)));
            let a = fold8::<MAX>(a, _mm256_loadu_ps(p.add(i + 2)));
            _mm256_storeu_ps(q.add(i), a);
        }
        steps * 8
    }

    /// [`h3`] for the minimum and the maximum from the same loads.
    #[target_feature(enable = "avx")]
    pub unsafe fn h3_both(row: &[f32], lo: &mut [f32], hi: &mut [f32]) -> usize {
        let steps = lo.len().min(hi.len()) / 8;
        assert!(row.len() >= steps * 8 + 2);
        let (el, eh) = (empty8::<false>(), empty8::<true>());
        let (p, ql, qh) = (row.as_ptr(), lo.as_mut_ptr(), hi.as_mut_ptr());
        for k in 0..steps {
            let i = 8 * k;
            let (x, y, z) = (
                _mm256_loadu_ps(p.add(i)),
                _mm256_loadu_ps(p.add(i + 1)),
                _mm256_loadu_ps(p.add(i + 2)),
            );
            let l = fold8::<false>(fold8::<false>(fold8::<false>(el, x), y), z);
            let h = fold8::<true>(fold8::<true>(fold8::<true>(eh, x), y), z);
            _mm256_storeu_ps(ql.add(i), l);
            _mm256_storeu_ps(qh.add(i), h);
        }
        steps * 8
    }

    /// `out[i]` = extreme of NaN-free `a[i]`, `b[i]`, `c[i]`, and the same with the empty value
    /// turned to NaN written to `dst` ([`store`]; when `NT`, `dst` must be 64-byte aligned).
    #[target_feature(enable = "avx")]
    pub unsafe fn v3_stream<const MAX: bool, const NT: bool>(
        a: &[f32],
        b: &[f32],
        c: &[f32],
        out: &mut [f32],
        dst: &mut [f32],
    ) -> usize {
        // Whole 64-byte lines only.
        let steps = out.len().min(dst.len()) / 16 * 2;
        assert!(a.len() >= steps * 8 && b.len() >= steps * 8 && c.len() >= steps * 8);
        assert!(!NT || dst.as_ptr() as usize % 64 == 0);
        let (e, nan) = (empty8::<MAX>(), _mm256_set1_ps(f32::NAN));
        let (q, d) = (out.as_mut_ptr(), dst.as_mut_ptr());
        for k in 0..steps {
            let i = 8 * k;
            let m = fold8::<MAX>(
                fold8::<MAX>(
                    _mm256_loadu_ps(a.as_ptr().add(i)),
                    _mm256_loadu_ps(b.as_ptr().add(i)),
                ),
                _mm256_loadu_ps(c.as_ptr().add(i)),
            );
            let is_empty = _mm256_cmp_ps::<_CMP_EQ_OQ>(m, e);
            let r = _mm256_blendv_ps(m, nan, is_empty);
            _mm256_storeu_ps(q.add(i), m);
            store::<NT>(d.add(i), r);
        }
        steps * 8
    }
}

/// Row `r` of level `k` has just been written: when it completes a pair of rows (or is the
/// last row of an odd level), write the row of level k+1 they make, and so on up the pyramid,
/// while the rows are still in cache.
fn cascade<const MAX: bool>(sizes: &[usize], levels: &mut [Vec<f32>], k: usize, r: usize) {
    let (mut k, mut r) = (k, r);
    while k + 1 < levels.len() {
        let w = sizes[k];
        if r % 2 == 0 && r != w - 1 {
            return;
        }
        let y = r / 2;
        let (lo, hi) = levels.split_at_mut(k + 1);
        let src = &lo[k];
        let r0 = &src[2 * y * w..][..w];
        let r1 = &src[(2 * y + 1).min(w - 1) * w..][..w];
        let w2 = sizes[k + 1];
        reduce_row::<MAX>(r0, r1, &mut hi[0][y * w2..(y + 1) * w2]);
        k += 1;
        r = y;
    }
}

/// Level 0 of the max pyramid (separable 3×3 max, streaming stored rows through a ring of
/// three horizontal results so the input is read once), cascading each finished row pair up.
fn max_levels<const NT: bool>(
    h: &[f32],
    s: usize,
    halo: usize,
    sizes: &[usize],
    out: &mut [Vec<f32>],
) {
    let n = sizes[0];
    let row = |r: usize| &h[r * s + halo - 1..r * s + halo + n + 1];
    let mut ring = [vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]];
    let mut pairs = scratch_pairs(sizes);
    hmax3(row(halo - 1), &mut ring[0]);
    hmax3(row(halo), &mut ring[1]);
    for j in 0..n {
        hmax3(row(j + halo + 1), &mut ring[(j + 2) % 3]);
        v3_out::<true, NT>(
            &ring[j % 3],
            &ring[(j + 1) % 3],
            &ring[(j + 2) % 3],
            &mut pairs[0][j % 2],
            &mut out[0][j * n..(j + 1) * n],
        );
        cascade_raw::<true, NT>(sizes, out, &mut pairs, 0, j);
    }
    store_fence();
}

fn minmax_levels<const NT: bool>(
    h: &[f32],
    s: usize,
    halo: usize,
    sizes: &[usize],
    lo: &mut [Vec<f32>],
    hi: &mut [Vec<f32>],
) {
    let n = sizes[0];
    let row = |r: usize| &h[r * s + halo - 1..r * s + halo + n + 1];
    let mut rl = [vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]];
    let mut rh = [vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]];
    {
        let ([l0, l1, _], [h0, h1, _]) = (&mut rl, &mut rh);
        hminmax3(row(halo - 1), l0, h0);
        hminmax3(row(halo), l1, h1);
    }
    let mut pl = scratch_pairs(sizes);
    let mut ph = scratch_pairs(sizes);
    for j in 0..n {
        let k = (j + 2) % 3;
        hminmax3(row(j + halo + 1), &mut rl[k], &mut rh[k]);
        v3_out::<false, NT>(
            &rl[j % 3],
            &rl[(j + 1) % 3],
            &rl[k],
            &mut pl[0][j % 2],
            &mut lo[0][j * n..(j + 1) * n],
        );
        v3_out::<true, NT>(
            &rh[j % 3],
            &rh[(j + 1) % 3],
            &rh[k],
            &mut ph[0][j % 2],
            &mut hi[0][j * n..(j + 1) * n],
        );
        cascade_raw::<false, NT>(sizes, lo, &mut pl, 0, j);
        cascade_raw::<true, NT>(sizes, hi, &mut ph, 0, j);
    }
    store_fence();
}

/// Reduce level 0 of `levels` up to 1×1.
fn reduce_levels<const MAX: bool>(sizes: &[usize], levels: &mut [Vec<f32>]) {
    for k in 0..levels.len() - 1 {
        for r in 0..sizes[k] {
            cascade::<MAX>(&sizes[..k + 2], &mut levels[..k + 2], k, r);
        }
    }
}

/// Whether an `n`-texel tile's pyramid is written with non-temporal stores: only when its
/// level 0 (4·n² bytes a channel) is well beyond the per-core caches, so that caching it would
/// only evict the input; a small tile's pyramid stays cached for the EXR encode that follows.
fn streams(n: usize) -> bool {
    n >= 1024
}

fn check_out(sizes: &[usize], levels: &[Vec<f32>], n: usize) -> Result<()> {
    if sizes != level_sizes(n).as_slice()
        || levels.len() != sizes.len()
        || levels.iter().zip(sizes).any(|(l, &s)| l.len() != s * s)
    {
        return Err(Error::usage(format!(
            "pyramid buffers do not fit a {n}-texel tile"
        )));
    }
    Ok(())
}

/// The maximum pyramid of one stored height tile (`stored_size²` samples, halo included).
pub fn max_pyramid(height: &[f32], stored_size: usize, halo: usize) -> Result<MaxPyramid> {
    let n = interior(height, stored_size, halo)?;
    let mut p = MaxPyramid::new(n);
    max_pyramid_into(height, stored_size, halo, &mut p)?;
    Ok(p)
}

/// As [`max_pyramid`], into buffers from [`MaxPyramid::new`] (no allocation of the levels).
pub fn max_pyramid_into(
    height: &[f32],
    stored_size: usize,
    halo: usize,
    out: &mut MaxPyramid,
) -> Result<()> {
    let n = interior(height, stored_size, halo)?;
    check_out(&out.sizes, &out.max, n)?;
    if streams(n) {
        max_levels::<true>(height, stored_size, halo, &out.sizes, &mut out.max);
    } else {
        max_levels::<false>(height, stored_size, halo, &out.sizes, &mut out.max);
    }
    Ok(())
}

/// The (min, max) pyramid of one stored height tile (`stored_size²` samples, halo included).
pub fn minmax_pyramid(height: &[f32], stored_size: usize, halo: usize) -> Result<MinMaxPyramid> {
    let n = interior(height, stored_size, halo)?;
    let mut p = MinMaxPyramid::new(n);
    minmax_pyramid_into(height, stored_size, halo, &mut p)?;
    Ok(p)
}

/// As [`minmax_pyramid`], into buffers from [`MinMaxPyramid::new`].
pub fn minmax_pyramid_into(
    height: &[f32],
    stored_size: usize,
    halo: usize,
    out: &mut MinMaxPyramid,
) -> Result<()> {
    let n = interior(height, stored_size, halo)?;
    check_out(&out.sizes, &out.min, n)?;
    check_out(&out.sizes, &out.max, n)?;
    let (sizes, lo, hi) = (&out.sizes, &mut out.min, &mut out.max);
    if streams(n) {
        minmax_levels::<true>(height, stored_size, halo, sizes, lo, hi);
    } else {
        minmax_levels::<false>(height, stored_size, halo, sizes, lo, hi);
    }
    Ok(())
}

/// The coarse pyramid of one face at one tile level: level 0 is the `g × g` grid of each
/// tile's 1×1 (min, max) (NaN where a tile is absent), reduced 2×2 up to 1×1.
pub fn face_pyramid(g: usize, min: Vec<f32>, max: Vec<f32>) -> MinMaxPyramid {
    assert_eq!(min.len(), g * g);
    assert_eq!(max.len(), g * g);
    let sizes = level_sizes(g);
    let mut lo = vec![min];
    let mut hi = vec![max];
    for &s in &sizes[1..] {
        lo.push(vec![0.0; s * s]);
        hi.push(vec![0.0; s * s]);
    }
    reduce_levels::<false>(&sizes, &mut lo);
    reduce_levels::<true>(&sizes, &mut hi);
    MinMaxPyramid {
        sizes,
        min: lo,
        max: hi,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_halve_rounding_up() {
        assert_eq!(level_sizes(8), vec![8, 4, 2, 1]);
        assert_eq!(level_sizes(24), vec![24, 12, 6, 3, 2, 1]);
        assert_eq!(level_sizes(1), vec![1]);
    }

    #[test]
    fn f16_rounding_is_directed() {
        for x in [
            0.1f32, -0.1, 1e-8, -1e-8, 21229.3, -8068.7, 65519.0, 70000.0, -70000.0,
        ] {
            assert!(f16_up(x).to_f32() >= x, "{x}");
            assert!(f16_down(x).to_f32() <= x, "{x}");
        }
        assert!(f16_up(f32::NAN).is_nan() && f16_down(f32::NAN).is_nan());
        assert_eq!(f16_up(2.0).to_f32(), 2.0);
    }

    /// Naive 3×3 + 2×2 reference, at sizes and alignments where the SIMD heads and tails and
    /// the streamed level 0 all run.
    #[test]
    fn kernels_match_a_naive_reference() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut rnd = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        // 1030 and 1024: the streamed (non-temporal) path, see `streams`.
        for (n, halo) in [
            (256usize, 2usize),
            (131, 1),
            (200, 3),
            (37, 2),
            (1030, 2),
            (1024, 1),
        ] {
            let s = n + 2 * halo;
            let h: Vec<f32> = (0..s * s)
                .map(|_| {
                    let r = rnd();
                    if r % 7 == 0 {
                        f32::NAN
                    } else {
                        (r >> 40) as f32 / 1000.0 - 5000.0
                    }
                })
                .collect();
            let sizes = level_sizes(n);
            let (mut lo, mut hi) = (vec![vec![0.0f32; n * n]], vec![vec![0.0f32; n * n]]);
            for j in 0..n {
                for i in 0..n {
                    let (mut a, mut b) = (POS_INF, NEG_INF);
                    for dj in 0..3 {
                        for di in 0..3 {
                            let v = h[(j + halo + dj - 1) * s + i + halo + di - 1];
                            a = fmin(a, v);
                            b = fmax(b, v);
                        }
                    }
                    lo[0][j * n + i] = nan_if(a, POS_INF);
                    hi[0][j * n + i] = nan_if(b, NEG_INF);
                }
            }
            for k in 1..sizes.len() {
                let (w, w2) = (sizes[k - 1], sizes[k]);
                let (mut l, mut m) = (vec![0.0f32; w2 * w2], vec![0.0f32; w2 * w2]);
                for y in 0..w2 {
                    for xx in 0..w2 {
                        let (mut a, mut b) = (POS_INF, NEG_INF);
                        for yy in [2 * y, (2 * y + 1).min(w - 1)] {
                            for x2 in [2 * xx, (2 * xx + 1).min(w - 1)] {
                                a = fmin(a, lo[k - 1][yy * w + x2]);
                                b = fmax(b, hi[k - 1][yy * w + x2]);
                            }
                        }
                        l[y * w2 + xx] = nan_if(a, POS_INF);
                        m[y * w2 + xx] = nan_if(b, NEG_INF);
                    }
                }
                lo.push(l);
                hi.push(m);
            }
            let same = |a: &[Vec<f32>], b: &[Vec<f32>]| {
                a.iter()
                    .flatten()
                    .zip(b.iter().flatten())
                    .all(|(p, q)| p.to_bits() == q.to_bits() || (p.is_nan() && q.is_nan()))
            };
            let mm = minmax_pyramid(&h, s, halo).unwrap();
            let mx = max_pyramid(&h, s, halo).unwrap();
            assert!(
                same(&mm.min, &lo) && same(&mm.max, &hi),
                "minmax {n}+2·{halo}"
            );
            assert!(same(&mx.max, &hi), "max {n}+2·{halo}");
        }
    }
}
