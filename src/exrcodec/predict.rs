//! OpenEXR's ZIP predictor and its inverse: the byte transform the codec applies before
//! deflating a block and undoes after inflating one.

/// OpenEXR's ZIP transform before deflate: even bytes then odd bytes, then each byte as the
/// difference to the previous one plus 128. Written as one pass over byte pairs (each output
/// byte from two input bytes), 16 pairs at a time with SSE2.
pub(crate) fn predict(packed: &[u8], out: &mut Vec<u8>) {
    let n = packed.len();
    out.clear();
    out.resize(n, 0);
    if n == 0 {
        return;
    }
    let half = n.div_ceil(2);
    let (a, b) = out.split_at_mut(half);
    let d = |x: u8, y: u8| x.wrapping_sub(y).wrapping_add(128);
    a[0] = packed[0];
    if let Some(&o) = packed.get(1) {
        // The first odd byte follows the last even one.
        b[0] = d(o, packed[2 * (half - 1)]);
    }
    // Pairs 1.. of the input against the pair before each.
    let pairs = n / 2;
    #[allow(unused_mut)]
    let mut done = 1;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // 16 pairs at a time: the byte differences of 32 bytes and the 32 before them by two,
        // plus 128 (the top bit flipped), split into even and odd bytes.
        while done + 16 <= pairs {
            // SAFETY: SSE2 is part of x86_64; the loads read packed[2·done − 2 .. 2·done + 32]
            // and the stores write a and b at done .. done + 16, all inside the slices (both
            // hold `pairs` elements at least).
            unsafe {
                let at = |k: usize| packed.as_ptr().add(k).cast::<__m128i>();
                let flip = _mm_set1_epi8(-128);
                let lo = _mm_xor_si128(
                    _mm_sub_epi8(
                        _mm_loadu_si128(at(2 * done)),
                        _mm_loadu_si128(at(2 * done - 2)),
                    ),
                    flip,
                );
                let hi = _mm_xor_si128(
                    _mm_sub_epi8(
                        _mm_loadu_si128(at(2 * done + 16)),
                        _mm_loadu_si128(at(2 * done + 14)),
                    ),
                    flip,
                );
                let mask = _mm_set1_epi16(0xff);
                let even = _mm_packus_epi16(_mm_and_si128(lo, mask), _mm_and_si128(hi, mask));
                let odd = _mm_packus_epi16(_mm_srli_epi16(lo, 8), _mm_srli_epi16(hi, 8));
                _mm_storeu_si128(a.as_mut_ptr().add(done).cast(), even);
                _mm_storeu_si128(b.as_mut_ptr().add(done).cast(), odd);
            }
            done += 16;
        }
    }
    for i in done..pairs {
        a[i] = d(packed[2 * i], packed[2 * i - 2]);
        b[i] = d(packed[2 * i + 1], packed[2 * i - 1]);
    }
    if n % 2 == 1 && n > 1 {
        a[half - 1] = d(packed[n - 1], packed[n - 3]);
    }
}

/// The inverse of [`predict`]: the running sum, then the even and odd halves interleaved.
pub(crate) fn unpredict(data: &mut [u8]) -> Vec<u8> {
    running_sum(data);
    let n = data.len();
    let half = n.div_ceil(2);
    let mut out = vec![0u8; n];
    let (a, b) = data.split_at(half);
    let pairs = n / 2;
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        while done + 16 <= pairs {
            // SAFETY: SSE2 is part of x86_64; the loads read a and b at done .. done + 16 and
            // the stores write out at 2·done .. 2·done + 32, all inside the slices (a and b
            // hold `pairs` elements at least, out 2·pairs).
            unsafe {
                let x = _mm_loadu_si128(a.as_ptr().add(done).cast::<__m128i>());
                let y = _mm_loadu_si128(b.as_ptr().add(done).cast::<__m128i>());
                let o = out.as_mut_ptr().add(2 * done);
                _mm_storeu_si128(o.cast(), _mm_unpacklo_epi8(x, y));
                _mm_storeu_si128(o.add(16).cast(), _mm_unpackhi_epi8(x, y));
            }
            done += 16;
        }
    }
    for i in done..pairs {
        out[2 * i] = a[i];
        out[2 * i + 1] = b[i];
    }
    if n % 2 == 1 {
        out[n - 1] = a[half - 1];
    }
    out
}

/// `d[i] = d[i − 1] + d[i] − 128` from the second byte on, in place (mod 256).
fn running_sum(data: &mut [u8]) {
    let Some((first, rest)) = data.split_first_mut() else {
        return;
    };
    let mut prev = *first;
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // 16 bytes at a time: their prefix sums in four shifted adds, plus the last sum so far.
        // SAFETY (whole block): SSE2 is part of x86_64; every load and store is at
        // rest[done .. done + 16] with done + 16 <= rest.len().
        unsafe {
            let minus = _mm_set1_epi8(-128);
            let mut carry = _mm_set1_epi8(prev as i8);
            while done + 16 <= rest.len() {
                let p = rest.as_mut_ptr().add(done).cast::<__m128i>();
                let mut x = _mm_sub_epi8(_mm_loadu_si128(p), minus);
                x = _mm_add_epi8(x, _mm_slli_si128(x, 1));
                x = _mm_add_epi8(x, _mm_slli_si128(x, 2));
                x = _mm_add_epi8(x, _mm_slli_si128(x, 4));
                x = _mm_add_epi8(x, _mm_slli_si128(x, 8));
                x = _mm_add_epi8(x, carry);
                _mm_storeu_si128(p, x);
                // The last byte in every lane: its word shifted into place, then spread.
                let last = _mm_srli_epi16(_mm_shufflehi_epi16(x, 0xff), 8);
                let last = _mm_unpackhi_epi64(last, last);
                carry = _mm_or_si128(last, _mm_slli_epi16(last, 8));
                done += 16;
            }
            if done > 0 {
                prev = rest[done - 1];
            }
        }
    }
    for v in &mut rest[done..] {
        prev = v.wrapping_add(prev).wrapping_sub(128);
        *v = prev;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn running_sum_matches_the_byte_by_byte_definition() {
        let mut rnd = crate::testutil::rng(11);
        for n in (0usize..70).chain([255, 256, 257, 4096, 4099]) {
            let data: Vec<u8> = (0..n).map(|_| (rnd() * 256.0) as u8).collect();
            let mut want = data.clone();
            for i in 1..n {
                want[i] = want[i].wrapping_add(want[i - 1]).wrapping_sub(128);
            }
            let mut got = data.clone();
            running_sum(&mut got);
            assert_eq!(got, want, "n = {n}");
        }
    }

    #[test]
    fn predictor_round_trips_odd_and_even_lengths() {
        for n in [0usize, 1, 2, 3, 17, 31, 32, 33, 64, 1001, 4097] {
            let data: Vec<u8> = (0..n).map(|i| (i * 37 % 251) as u8).collect();
            let mut p = Vec::new();
            predict(&data, &mut p);
            assert_eq!(unpredict(&mut p), data, "n = {n}");
        }
    }

    /// The one-pass predictor gives the bytes of OpenEXR's definition done in two steps
    /// (split even and odd bytes, then the running difference).
    #[test]
    fn predictor_matches_the_two_step_definition() {
        let mut rnd = crate::testutil::rng(3);
        for n in (0usize..70).chain([255, 256, 257, 4096, 4097]) {
            let data: Vec<u8> = (0..n).map(|_| (rnd() * 256.0) as u8).collect();
            let mut want: Vec<u8> = data.iter().step_by(2).copied().collect();
            want.extend(data.iter().skip(1).step_by(2));
            for i in (1..n).rev() {
                want[i] = want[i].wrapping_sub(want[i - 1]).wrapping_add(128);
            }
            let mut got = Vec::new();
            predict(&data, &mut got);
            assert_eq!(got, want, "n = {n}");
        }
    }
}
