//! The deflate encoder of every ZIP block Penumbra writes (height tiles, mip files, horizon
//! maps): it looks for repeats only where the block's layout puts them.
//!
//! OpenEXR's ZIP transform lays a block out as the even bytes of every line's channels, then the
//! odd bytes, delta-predicted (see `predict` in the parent module). In a max-pooled mip level a
//! value repeats over 2×2 texels and more, and a `min` texel often repeats a `max` texel a line
//! or two up and two texels aside: a hash-chain search (256 deep) over LDEM_4's and SRTM's
//! two-channel mip blocks finds 71 % and 91 % of the bytes it matches at the few distances
//! [`distances`] derives from the layout (the rest are mostly 3–5-byte matches that save
//! little). miniz_oxide and libdeflate hash every position to find them and spend most of
//! their time on f32 mantissa bytes that repeat nowhere. Here the candidate distances are
//! compared 64 positions at a time (SSE2, AVX2 or AVX-512BW, whichever the CPU has: the output
//! is the same bytes), the parse is greedy (the longest candidate match, else a literal), and
//! each block is Huffman-coded with length-limited codes built for it, or with the fixed codes,
//! or stored, whichever is shortest. The result is one ordinary zlib stream: the file stays
//! plain OpenEXR ZIP that every reader inflates.
//!
//! [`zlib_unless_weak`] (what f32 blocks get) parses a sixteenth of the block first and gives
//! up on a block that would not deflate below 90 % of its size: the caller stores it raw, as
//! OpenEXR stores a block deflate does not shrink. A quarter of LDEM_4's mip bytes are in such
//! blocks; storing them cost 2.7 % in size and saved 22 % of the encoder's time
//! (docs/benchmarks.md, "Weak blocks stored").

/// The round-trip check of the randomised test and the fuzz target (tools/fuzz).
#[path = "layout_check.rs"]
pub(super) mod check;
#[cfg(test)]
#[path = "layout_roundtrip.rs"]
mod roundtrip;

/// Length symbols' base lengths and extra bits (RFC 1951 §3.2.5), symbols 257–285.
const LEN_BASE: [u16; 29] = [
    3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131,
    163, 195, 227, 258,
];
const LEN_EXTRA: [u8; 29] = [
    0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0,
];
/// Distance symbols' base distances and extra bits, symbols 0–29.
const DIST_BASE: [u16; 30] = [
    1, 2, 3, 4, 5, 7, 9, 13, 17, 25, 33, 49, 65, 97, 129, 193, 257, 385, 513, 769, 1025, 1537,
    2049, 3073, 4097, 6145, 8193, 12289, 16385, 24577,
];
const DIST_EXTRA: [u8; 30] = [
    0, 0, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7, 8, 8, 9, 9, 10, 10, 11, 11, 12, 12, 13,
    13,
];
/// The order the code-length code's lengths are sent in (RFC 1951 §3.2.7).
const CL_ORDER: [usize; 19] = [
    16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15,
];
/// Extra bits of the code-length symbols (16: repeat 3–6, 17: 3–10 zeros, 18: 11–138 zeros).
const CL_EXTRA: [u8; 19] = [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, 3, 7];

const MIN_MATCH: usize = 3;
const MAX_MATCH: usize = 258;
const WINDOW: usize = 32 * 1024;
/// Literal/length symbols: 0–287 (286 and 287 are never used, but the fixed code's canonical
/// order counts them).
const NLIT: usize = 288;
const NDIST: usize = 30;
/// At most this many candidate distances.
const MAX_DISTANCES: usize = 16;

/// The distances tried at every position of a block of `lines` lines of `width` samples whose
/// channels take `bps` bytes per sample (in stored order). With `q` bytes per sample and half
/// (`bps / 2`), `s = q · width` bytes per channel and half-line, and `l` bytes per half-line:
/// runs (1) and repeated byte pairs (2), the previous line of the same channel (`l`); with two
/// or more channels of one type also the previous channel one and two lines up, two samples
/// either side (`l + s ± 2q`, `2l + s ± 2q`), where max-pooled `min` samples repeat `max`
/// samples (LDEM_4's mips).
///
/// Left out because they cost a comparison per 62 bytes and a test per match for almost
/// nothing (counted on LDEM_4's f32 mips, 6.5 million matches): runs (1) when every channel is
/// f32, where a repeated value is a repeated byte pair and pairs (2) find runs of four bytes
/// or more (0.5 % of the matches went to 1); and the previous channel of the same line (`s`),
/// 0.03 % of the matches. Without them the files came out 0.1 % smaller, with 8 % fewer
/// instructions in the encoder.
pub(super) fn distances(bps: &[usize], width: usize, lines: usize) -> Vec<usize> {
    let all_f32 = !bps.is_empty() && bps.iter().all(|&b| b == 4);
    let mut d = if all_f32 { vec![2] } else { vec![1, 2] };
    if !bps.is_empty() && bps.iter().all(|b| b % 2 == 0) {
        let line: usize = bps.iter().map(|b| b * width / 2).sum();
        if lines > 1 {
            d.push(line);
        }
        if bps.len() > 1 && bps.iter().all(|&b| b == bps[0]) {
            let q = bps[0] / 2;
            let s = q * width;
            if lines > 1 {
                d.extend([line + s - 2 * q, line + s + 2 * q]);
            }
            if lines > 2 {
                d.extend([2 * line + s - 2 * q, 2 * line + s + 2 * q]);
            }
        }
    }
    d.retain(|&x| (1..=WINDOW).contains(&x));
    d.sort_unstable();
    d.dedup();
    d.truncate(MAX_DISTANCES);
    d
}

/// The zlib stream of `data` (one block's predicted bytes), with matches at the distances
/// `dist` (ascending, 1–32768, at most [`MAX_DISTANCES`]) only.
pub(super) fn zlib(data: &[u8], dist: &[usize]) -> Vec<u8> {
    dispatch(data, dist, false).expect("a block is always compressed without the probe")
}

/// As [`zlib`], except that blocks of [`PROBE_MIN`] bytes or more are first parsed for a
/// sixteenth of their length, and a block whose sixteenth would not compress to
/// [`WEAK`] of its size is given up: `None`, to be stored as it is. The blocks that go on
/// are the same bytes as [`zlib`]'s (the parse continues where the probe stopped).
pub(super) fn zlib_unless_weak(data: &[u8], dist: &[usize]) -> Option<Vec<u8>> {
    dispatch(data, dist, true)
}

fn dispatch(data: &[u8], dist: &[usize], probe: bool) -> Option<Vec<u8>> {
    debug_assert!(dist.len() <= MAX_DISTANCES && dist.windows(2).all(|w| w[0] < w[1]));
    debug_assert!(dist.iter().all(|&d| (1..=WINDOW).contains(&d)));
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512bw,bmi2")]
        unsafe fn avx512(data: &[u8], dist: &[usize], probe: bool) -> Option<Vec<u8>> {
            zlib_with::<x86::Avx512>(data, dist, probe)
        }
        #[target_feature(enable = "avx2,bmi2")]
        unsafe fn avx2(data: &[u8], dist: &[usize], probe: bool) -> Option<Vec<u8>> {
            zlib_with::<x86::Avx2>(data, dist, probe)
        }
        use std::arch::is_x86_feature_detected as has;
        if has!("avx512bw") && has!("bmi2") {
            // SAFETY: the CPU has AVX-512BW and BMI2, checked just above.
            return unsafe { avx512(data, dist, probe) };
        }
        if has!("avx2") && has!("bmi2") {
            // SAFETY: the CPU has AVX2 and BMI2, checked just above.
            return unsafe { avx2(data, dist, probe) };
        }
        zlib_with::<x86::Sse2>(data, dist, probe)
    }
    #[cfg(not(target_arch = "x86_64"))]
    zlib_with::<Portable>(data, dist, probe)
}

/// Blocks shorter than this are never probed (the mip files' 64² tiles are 16 and 32 KiB at
/// f32; their small coarse levels are a few percent of the bytes).
pub(super) const PROBE_MIN: usize = 4096;
/// The probe's verdict: a block is weak when its first sixteenth's estimated deflate bits
/// exceed this share of its raw bits (numerator, denominator).
const WEAK: (usize, usize) = (9, 10);
/// The bits the probe counts for a literal and for a match. The predicted bytes of f32 mip
/// blocks are nearly uniform (order-0 entropy 7.6–7.8 bits per byte on LDEM_4's), so a literal
/// costs about 8 bits; a match, its length and distance codes with their extra bits.
const LITERAL_BITS: usize = 8;
const MATCH_BITS: usize = 13;

/// Whether a probe of `len` bytes that found `tokens` says the block is weak.
fn weak(tokens: &[Match], len: usize) -> bool {
    let covered: usize = tokens.iter().map(|t| usize::from(t.len)).sum();
    let bits = (len - covered) * LITERAL_BITS + tokens.len() * MATCH_BITS;
    bits * WEAK.1 > len * 8 * WEAK.0
}

/// Inputs longer than this are cut into several deflate blocks (it bounds the symbol counts
/// and the match list; mip tiles are 32 KiB at most).
const MAX_BLOCK: usize = 1 << 20;

/// [`zlib`] with the window comparisons of `C`; compiled once per instruction set, with
/// everything it calls inlined, so that all of it uses that set's instructions.
#[inline(always)]
fn zlib_with<C: Compare>(data: &[u8], dist: &[usize], probe: bool) -> Option<Vec<u8>> {
    let n = data.len();
    let mut w = BitWriter::with_capacity(n + 5 * n.div_ceil(65535) + 64);
    // CMF: deflate, 32 KiB window; FLG: fastest, no dictionary, check bits.
    w.bytes(&[0x78, 0x01]);
    let mut tokens = Vec::with_capacity(n.min(MAX_BLOCK) / 8);
    let mut counts = Counts::default();
    let mut s = 0;
    loop {
        let e = n.min(s + MAX_BLOCK);
        tokens.clear();
        counts.clear();
        let mut from = s;
        if probe && s == 0 && e == n && n >= PROBE_MIN {
            from = parse_with::<C>(data, s, s, s + n / 16, e, dist, &mut tokens, &mut counts);
            if weak(&tokens, from - s) {
                return None;
            }
        }
        parse_with::<C>(data, s, from, e, e, dist, &mut tokens, &mut counts);
        write_block(&mut w, data, s, e, dist, &tokens, &mut counts, e == n);
        if e == n {
            break;
        }
        s = e;
    }
    w.align();
    w.bytes(&simd_adler32::adler32(&data).to_be_bytes());
    Some(w.finish())
}

/// Symbol counts of one deflate block; literals are counted in four tables (a repeated byte
/// would otherwise wait on its own previous increment).
struct Counts {
    lit4: [[u32; 256]; 4],
    lit: [u32; NLIT],
    dist: [u32; NDIST],
}

impl Default for Counts {
    fn default() -> Self {
        Counts {
            lit4: [[0; 256]; 4],
            lit: [0; NLIT],
            dist: [0; NDIST],
        }
    }
}

impl Counts {
    fn clear(&mut self) {
        *self = Counts::default();
    }

    /// Count these bytes as literals.
    fn bytes(&mut self, bytes: &[u8]) {
        let mut q = bytes.chunks_exact(4);
        for c in &mut q {
            self.lit4[0][c[0] as usize] += 1;
            self.lit4[1][c[1] as usize] += 1;
            self.lit4[2][c[2] as usize] += 1;
            self.lit4[3][c[3] as usize] += 1;
        }
        for &b in q.remainder() {
            self.lit4[0][b as usize] += 1;
        }
    }

    /// Fold the literal tables into `lit`.
    fn merge(&mut self) {
        for b in 0..256 {
            self.lit[b] += self.lit4[0][b] + self.lit4[1][b] + self.lit4[2][b] + self.lit4[3][b];
        }
    }
}

/// A match: `len` bytes at `pos` (from the start of the deflate block) repeat the bytes
/// `dist[d]` before.
#[derive(Clone, Copy)]
struct Match {
    pos: u32,
    len: u16,
    d: u16,
}

/// Length symbol index (0–28) of each length 3–258.
const LEN_SYM: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut k = 0;
    while k < 29 {
        let hi = if k + 1 < 29 {
            LEN_BASE[k + 1] as usize
        } else {
            259
        };
        let mut l = LEN_BASE[k] as usize;
        while l < hi {
            t[l - 3] = k as u8;
            l += 1;
        }
        k += 1;
    }
    t
};

fn dist_symbol(d: usize) -> usize {
    DIST_BASE.partition_point(|&b| b as usize <= d) - 1
}

/// How many bytes from `i` (at most `max`) equal those `d` before.
#[inline(always)]
fn extend(data: &[u8], i: usize, d: usize, max: usize) -> usize {
    let mut l = 0;
    while l + 8 <= max {
        let a = u64::from_le_bytes(data[i + l..i + l + 8].try_into().unwrap());
        let b = u64::from_le_bytes(data[i - d + l..i - d + l + 8].try_into().unwrap());
        let x = a ^ b;
        if x != 0 {
            return l + (x.trailing_zeros() / 8) as usize;
        }
        l += 8;
    }
    while l < max && data[i + l] == data[i - d + l] {
        l += 1;
    }
    l
}

/// Compares 64 bytes with 64 others: bit k of the result set where byte k is equal. The
/// implementations give the same masks; the encoder is compiled once for each (see [`zlib`]).
trait Compare {
    /// # Safety
    /// The CPU must have the instructions the implementation uses.
    unsafe fn eq(x: &[u8; 64], y: &[u8; 64]) -> u64;
}

/// Byte by byte: any CPU.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
struct Portable;

impl Compare for Portable {
    #[inline(always)]
    unsafe fn eq(x: &[u8; 64], y: &[u8; 64]) -> u64 {
        x.iter()
            .zip(y)
            .enumerate()
            .fold(0u64, |m, (k, (a, b))| m | (u64::from(a == b) << k))
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::Compare;
    use std::arch::x86_64::*;

    /// SSE2 (every x86_64 CPU): four 16-byte compares.
    pub(super) struct Sse2;
    /// AVX2: two 32-byte compares.
    pub(super) struct Avx2;
    /// AVX-512BW: one 64-byte compare into a mask register.
    pub(super) struct Avx512;

    impl Compare for Sse2 {
        #[inline(always)]
        unsafe fn eq(x: &[u8; 64], y: &[u8; 64]) -> u64 {
            let mut m = 0u64;
            for k in 0..4 {
                let a = _mm_loadu_si128(x.as_ptr().add(16 * k).cast::<__m128i>());
                let b = _mm_loadu_si128(y.as_ptr().add(16 * k).cast::<__m128i>());
                m |= u64::from(_mm_movemask_epi8(_mm_cmpeq_epi8(a, b)) as u16) << (16 * k);
            }
            m
        }
    }

    impl Compare for Avx2 {
        #[inline(always)]
        unsafe fn eq(x: &[u8; 64], y: &[u8; 64]) -> u64 {
            let half = |k: usize| {
                let a = _mm256_loadu_si256(x.as_ptr().add(32 * k).cast::<__m256i>());
                let b = _mm256_loadu_si256(y.as_ptr().add(32 * k).cast::<__m256i>());
                u64::from(_mm256_movemask_epi8(_mm256_cmpeq_epi8(a, b)) as u32)
            };
            half(0) | (half(1) << 32)
        }
    }

    impl Compare for Avx512 {
        #[inline(always)]
        unsafe fn eq(x: &[u8; 64], y: &[u8; 64]) -> u64 {
            let a = _mm512_loadu_si512(x.as_ptr().cast());
            let b = _mm512_loadu_si512(y.as_ptr().cast());
            _mm512_cmpeq_epi8_mask(a, b)
        }
    }
}

/// The longest match at `i` among `dist` (all ≤ `i`), at most `max` bytes: (length, index).
fn best_match(data: &[u8], i: usize, max: usize, dist: &[usize]) -> (usize, usize) {
    let mut best = (0, 0);
    for (k, &d) in dist.iter().enumerate() {
        let l = extend(data, i, d, max);
        if l > best.0 {
            best = (l, k);
        }
    }
    best
}

/// Greedy parse of `data[s..e]` (matches may reach back before `s`; token positions count
/// from `s`): at each position the longest match among `dist`, else a literal. It starts at
/// `from` and stops at the first window boundary at or past `until`, returning it; a parse
/// that stops at `until < e` and goes on from there with `until = e` finds what one parse
/// does. The counts are complete (and the end of block counted) only once `until = e`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn parse_with<C: Compare>(
    data: &[u8],
    s: usize,
    from: usize,
    until: usize,
    e: usize,
    dist: &[usize],
    out: &mut Vec<Match>,
    c: &mut Counts,
) -> usize {
    let mut dsym = [0u8; MAX_DISTANCES];
    for (k, &d) in dist.iter().enumerate() {
        dsym[k] = dist_symbol(d) as u8;
    }
    let push = |out: &mut Vec<Match>, c: &mut Counts, p: usize, (len, k): (usize, usize)| {
        out.push(Match {
            pos: (p - s) as u32,
            len: len as u16,
            d: k as u16,
        });
        c.lit[257 + LEN_SYM[len - MIN_MATCH] as usize] += 1;
        c.dist[dsym[k] as usize] += 1;
    };
    let mut i = from;
    // Windows of 62 positions (64 bytes compared, a match needs three), each compared with
    // every usable distance at once: bit j of eq[k] says whether byte ws + j repeats the byte
    // dist[k] before it.
    let mut eq = [0u64; MAX_DISTANCES];
    let far = dist.last().copied().unwrap_or(0);
    while i < until && e - i >= 64 {
        let nd = if i >= far {
            dist.len()
        } else {
            dist.partition_point(|&d| d <= i)
        };
        let ws = i;
        let wend = i + 62;
        let mut counted = wend;
        let x: &[u8; 64] = data[i..i + 64].try_into().unwrap();
        let mut any = 0u64;
        for k in 0..nd {
            let d = dist[k];
            let y: &[u8; 64] = data[i - d..i - d + 64].try_into().unwrap();
            // SAFETY: `zlib` picked C for this CPU.
            let m = unsafe { C::eq(x, y) };
            eq[k] = m;
            any |= m & (m >> 1) & (m >> 2);
        }
        any &= (1 << 62) - 1;
        while any != 0 {
            let j = any.trailing_zeros() as usize;
            let p = ws + j;
            let max = (e - p).min(MAX_MATCH);
            // The run of equal bytes from bit j of each mask (runs that reach the end of the
            // window go on past it); the longest, then the nearest distance, wins: the
            // largest run · 16 + (15 − k).
            let mut key = 0usize;
            for (k, &m) in eq[..nd].iter().enumerate() {
                let mut run = (!(m >> j)).trailing_zeros() as usize;
                if run == 64 - j && run < max {
                    run += extend(data, p + run, dist[k], max - run);
                }
                key = key.max((run << 4) | (15 - k));
            }
            let best = ((key >> 4).min(max), 15 - (key & 15));
            debug_assert!(best.0 >= MIN_MATCH);
            push(out, c, p, best);
            i = p + best.0;
            if i >= wend {
                // A match on past the window: its bytes are not literals.
                counted = p;
                break;
            }
            any &= !0u64 << (i - ws);
        }
        // The window's bytes up to a match that runs past it count as literals, those of
        // the matches inside it too: counting each literal run apart costs a mispredicted
        // loop exit per run, and the bytes of matches shorter than a window skew the counts
        // by about 0.1 % of the size.
        c.bytes(&data[ws..counted]);
        i = i.max(wend);
    }
    if until < e {
        return i;
    }
    // The last bytes one by one.
    while i < e {
        let usable = &dist[..dist.partition_point(|&d| d <= i)];
        let best = best_match(data, i, (e - i).min(MAX_MATCH), usable);
        if best.0 >= MIN_MATCH {
            push(out, c, i, best);
            i += best.0;
        } else {
            c.bytes(&data[i..i + 1]);
            i += 1;
        }
    }
    c.merge();
    c.lit[256] += 1;
    i
}

/// Huffman code lengths, at most `limit` bits, for the symbol counts `counts` (0 for unused
/// symbols, each below 2²³: a block is at most [`MAX_BLOCK`] bytes). At least two symbols
/// must be used; the code is then complete.
fn code_lengths(counts: &[u32], limit: usize, lens: &mut [u8]) {
    debug_assert!(counts.len() <= NLIT && (1..=15).contains(&limit));
    lens.iter_mut().for_each(|l| *l = 0);
    // Count · 512 + symbol of the used symbols, ascending.
    let mut keys = [0u32; NLIT];
    let mut m = 0;
    for (s, &c) in counts.iter().enumerate() {
        if c > 0 {
            keys[m] = (c << 9) | s as u32;
            m += 1;
        }
    }
    debug_assert!(m >= 2 && counts.iter().all(|&c| c < 1 << 23));
    let keys = &mut keys[..m];
    sort_keys(keys);
    let mut a = [0u32; NLIT];
    for (x, &k) in a.iter_mut().zip(keys.iter()) {
        *x = k >> 9;
    }
    minimum_redundancy(&mut a[..m]);
    // a[k] is now the optimal length of the k-th rarest symbol. Longer than the limit go to
    // the limit; then codes move down a level until the code is complete again (each step
    // frees one unit of the Kraft sum at the limit).
    let mut per_len = [0u32; 16];
    for &d in &a[..m] {
        per_len[(d as usize).min(limit)] += 1;
    }
    let mut total: u64 = (1..=limit)
        .map(|l| u64::from(per_len[l]) << (limit - l))
        .sum();
    while total > 1 << limit {
        per_len[limit] -= 1;
        for l in (1..limit).rev() {
            if per_len[l] != 0 {
                per_len[l] -= 1;
                per_len[l + 1] += 2;
                break;
            }
        }
        total -= 1;
    }
    // The rarest symbols get the longest codes.
    let mut k = 0;
    for l in (1..=limit).rev() {
        for _ in 0..per_len[l] {
            lens[(keys[k] & 511) as usize] = l as u8;
            k += 1;
        }
    }
}

/// Sort the keys of [`code_lengths`] (count · 512 + symbol, made in ascending symbol order,
/// so already in order within each count) ascending. Alphabets of more than 32 symbols go
/// through a stable radix sort on the count's bytes (a 32 KiB block's counts have two), for
/// the same order: in a perf profile of the encoder the sorts went from 3.1 % to 2.2 %.
fn sort_keys(keys: &mut [u32]) {
    let m = keys.len();
    if m <= 32 {
        keys.sort_unstable();
        return;
    }
    let top = keys.iter().map(|&k| k >> 9).max().unwrap_or(0);
    let mut tmp = [0u32; NLIT];
    let mut in_keys = true;
    let mut shift = 9;
    while shift < 32 && top >> (shift - 9) != 0 {
        let (src, dst): (&[u32], &mut [u32]) = if in_keys {
            (&*keys, &mut tmp[..m])
        } else {
            (&tmp[..m], &mut *keys)
        };
        let mut at = [0u16; 256];
        for &k in src {
            at[((k >> shift) & 255) as usize] += 1;
        }
        let mut sum = 0u16;
        for a in at.iter_mut() {
            (*a, sum) = (sum, sum + *a);
        }
        for &k in src {
            let d = ((k >> shift) & 255) as usize;
            dst[at[d] as usize] = k;
            at[d] += 1;
        }
        in_keys = !in_keys;
        shift += 8;
    }
    if !in_keys {
        keys.copy_from_slice(&tmp[..m]);
    }
}

/// Moffat and Katajainen's in-place computation of minimum-redundancy code lengths: `a` holds
/// the weights in ascending order (at least two) and gets the code lengths (the first, rarest
/// symbol the longest).
fn minimum_redundancy(a: &mut [u32]) {
    let n = a.len();
    // Phase 1: internal node weights, each leaf or node replaced by its parent's index.
    a[0] += a[1];
    let (mut root, mut leaf) = (0usize, 2usize);
    for next in 1..n - 1 {
        if leaf >= n || a[root] < a[leaf] {
            a[next] = a[root];
            a[root] = next as u32;
            root += 1;
        } else {
            a[next] = a[leaf];
            leaf += 1;
        }
        if leaf >= n || (root < next && a[root] < a[leaf]) {
            a[next] += a[root];
            a[root] = next as u32;
            root += 1;
        } else {
            a[next] += a[leaf];
            leaf += 1;
        }
    }
    // Phase 2: internal node depths.
    a[n - 2] = 0;
    for next in (0..n.saturating_sub(2)).rev() {
        a[next] = a[a[next] as usize] + 1;
    }
    // Phase 3: leaf depths, from the internal nodes at each depth.
    let (mut avail, mut used, mut depth) = (1u32, 0u32, 0u32);
    let (mut root, mut next) = (n as isize - 2, n as isize - 1);
    while avail > 0 {
        while root >= 0 && a[root as usize] == depth {
            used += 1;
            root -= 1;
        }
        while avail > used {
            a[next as usize] = depth;
            next -= 1;
            avail -= 1;
        }
        avail = 2 * used;
        depth += 1;
        used = 0;
    }
}

/// Canonical codes for these lengths, bit-reversed for deflate's LSB-first order (0 for unused
/// symbols). Symbols of one length get consecutive codes in symbol order; the symbols are
/// counted and given codes in four interleaved quarters, each starting per length where the
/// quarters before it end, so that a run of one length does not wait on a single counter.
fn codes(lens: &[u8], out: &mut [u16]) {
    let n = lens.len();
    let q = n.div_ceil(4);
    let mut count = [[0u16; 16]; 4];
    for i in 0..q {
        for (k, c) in count.iter_mut().enumerate() {
            if let Some(&l) = lens.get(k * q + i) {
                c[l as usize] += 1;
            }
        }
    }
    let mut next = [0u16; 16];
    let mut code = 0u16;
    for b in 1..16 {
        let below = if b > 1 {
            count.iter().map(|c| c[b - 1]).sum()
        } else {
            0
        };
        code = (code + below) << 1;
        next[b] = code;
    }
    let mut base = [next; 4];
    for k in 1..4 {
        for l in 1..16 {
            base[k][l] = base[k - 1][l] + count[k - 1][l];
        }
    }
    for i in 0..q {
        for (k, b) in base.iter_mut().enumerate() {
            let s = k * q + i;
            if let Some(&l) = lens.get(s) {
                let c = b[l as usize];
                b[l as usize] = c.wrapping_add(1);
                out[s] = if l > 0 {
                    c.reverse_bits() >> (16 - l)
                } else {
                    0
                };
            }
        }
    }
}

/// The code-length sequence of `lens` with runs as symbols 16, 17, 18: (symbol, extra value).
fn rle_lengths(lens: &[u8], out: &mut Vec<(u8, u8)>) {
    out.clear();
    let mut i = 0;
    while i < lens.len() {
        let l = lens[i];
        let mut run = lens[i..].iter().take_while(|&&x| x == l).count();
        i += run;
        if l == 0 {
            while run >= 11 {
                let r = run.min(138);
                out.push((18, (r - 11) as u8));
                run -= r;
            }
            if run >= 3 {
                out.push((17, (run - 3) as u8));
                run = 0;
            }
        } else {
            out.push((l, 0));
            run -= 1;
            while run >= 3 {
                let r = run.min(6);
                out.push((16, (r - 3) as u8));
                run -= r;
            }
        }
        for _ in 0..run {
            out.push((l, 0));
        }
    }
}

/// The fixed Huffman code's length of literal/length symbol `s` (RFC 1951 §3.2.6).
const fn fixed_len(s: usize) -> u8 {
    match s {
        0..=143 => 8,
        144..=255 => 9,
        256..=279 => 7,
        _ => 8,
    }
}

const FIXED_LIT: [u8; NLIT] = {
    let mut t = [0u8; NLIT];
    let mut s = 0;
    while s < NLIT {
        t[s] = fixed_len(s);
        s += 1;
    }
    t
};

/// Bits of the symbols and their extra bits with these code lengths (no block header).
fn body_bits(c: &Counts, lit: &[u8], dist: &[u8]) -> u64 {
    let mut bits = 0u64;
    for (s, &n) in c.lit.iter().enumerate() {
        let extra = match s.checked_sub(257) {
            Some(k) => u64::from(LEN_EXTRA.get(k).copied().unwrap_or(0)),
            None => 0,
        };
        bits += u64::from(n) * (u64::from(lit[s]) + extra);
    }
    for (s, &n) in c.dist.iter().enumerate() {
        bits += u64::from(n) * (u64::from(dist[s]) + u64::from(DIST_EXTRA[s]));
    }
    bits
}

/// Make a code complete by giving a second symbol a count when fewer than two are used (a
/// code of one symbol is incomplete, which some inflaters refuse; the spare is never sent).
fn at_least_two(counts: &mut [u32]) {
    for spare in 0..2 {
        if counts.iter().filter(|&&n| n > 0).count() < 2 && counts[spare] == 0 {
            counts[spare] = 1;
        }
    }
}

/// One deflate block of `data[s..e]` parsed into `tokens`: dynamic Huffman codes, or the fixed
/// ones, or stored, whichever is smallest.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn write_block(
    w: &mut BitWriter,
    data: &[u8],
    s: usize,
    e: usize,
    dist: &[usize],
    tokens: &[Match],
    c: &mut Counts,
    last: bool,
) {
    at_least_two(&mut c.lit);
    at_least_two(&mut c.dist);
    let mut lit_len = [0u8; NLIT];
    let mut dist_len = [0u8; NDIST];
    code_lengths(&c.lit, 15, &mut lit_len);
    code_lengths(&c.dist, 15, &mut dist_len);
    let hlit = 257.max(NLIT - lit_len.iter().rev().take_while(|&&l| l == 0).count());
    let hdist = 1.max(NDIST - dist_len.iter().rev().take_while(|&&l| l == 0).count());
    let mut seq_lens = [0u8; NLIT + NDIST];
    seq_lens[..hlit].copy_from_slice(&lit_len[..hlit]);
    seq_lens[hlit..hlit + hdist].copy_from_slice(&dist_len[..hdist]);
    let mut seq = Vec::with_capacity(NLIT + NDIST);
    rle_lengths(&seq_lens[..hlit + hdist], &mut seq);
    let mut cl_counts = [0u32; 19];
    for &(sym, _) in &seq {
        cl_counts[sym as usize] += 1;
    }
    at_least_two(&mut cl_counts);
    let mut cl_len = [0u8; 19];
    code_lengths(&cl_counts, 7, &mut cl_len);
    let hclen = 4.max(
        19 - CL_ORDER
            .iter()
            .rev()
            .take_while(|&&s| cl_len[s] == 0)
            .count(),
    );
    let header_bits = 3
        + 5
        + 5
        + 4
        + 3 * hclen as u64
        + seq
            .iter()
            .map(|&(s, _)| u64::from(cl_len[s as usize] + CL_EXTRA[s as usize]))
            .sum::<u64>();
    let dynamic = header_bits + body_bits(c, &lit_len, &dist_len);
    let fixed = 3 + body_bits(c, &FIXED_LIT, &[5; NDIST]);
    // Stored: per 65535 bytes the header bits, padding to a byte (at most 7), LEN and NLEN.
    let n = e - s;
    let stored = (n.div_ceil(65535).max(1) * (3 + 7 + 32) + 8 * n) as u64;
    let bfinal = u64::from(last);
    // The counts overestimate the literals a little (see `parse`): the estimates are upper
    // bounds, and the block is stored when what was written turns out longer.
    let mark = w.mark();
    if fixed < dynamic {
        w.put(bfinal | 0b010, 3);
        lit_len = FIXED_LIT;
        dist_len = [5; NDIST];
    } else {
        w.put(bfinal | 0b100, 3);
        w.put((hlit - 257) as u64, 5);
        w.put((hdist - 1) as u64, 5);
        w.put((hclen - 4) as u64, 4);
        for &s in &CL_ORDER[..hclen] {
            w.put(u64::from(cl_len[s]), 3);
        }
        let mut cl_code = [0u16; 19];
        codes(&cl_len, &mut cl_code);
        for &(sym, extra) in &seq {
            let s = sym as usize;
            w.put(
                u64::from(cl_code[s]) | (u64::from(extra) << cl_len[s]),
                u32::from(cl_len[s] + CL_EXTRA[s]),
            );
        }
    }
    let mut lit_code = [0u16; NLIT];
    let mut dist_code = [0u16; NDIST];
    codes(&lit_len, &mut lit_code);
    codes(&dist_len, &mut dist_code);
    // Literal codes and lengths; each distance's code and extra bits in one.
    let lit = Literals {
        code: std::array::from_fn(|b| u64::from(lit_code[b])),
        len: std::array::from_fn(|b| lit_len[b]),
    };
    let mut dcode = [(0u64, 0u32); MAX_DISTANCES];
    for (k, &d) in dist.iter().enumerate() {
        let ds = dist_symbol(d);
        dcode[k] = (
            u64::from(dist_code[ds]) | (((d - DIST_BASE[ds] as usize) as u64) << dist_len[ds]),
            u32::from(dist_len[ds] + DIST_EXTRA[ds]),
        );
    }
    let mut lcode = [(0u64, 0u32); 29];
    for (k, l) in lcode.iter_mut().enumerate() {
        *l = (u64::from(lit_code[257 + k]), u32::from(lit_len[257 + k]));
    }
    let max_lit = lit_len[..256].iter().copied().max().unwrap_or(0);
    w.reserve_bits(dynamic.min(fixed));
    let end = (u64::from(lit_code[256]), u32::from(lit_len[256]));
    if max_lit <= 14 {
        emit::<4>(w, data, s, e, tokens, &lit, &lcode, &dcode, end);
    } else {
        emit::<3>(w, data, s, e, tokens, &lit, &lcode, &dcode, end);
    }
    if w.bits_since(mark) >= stored {
        w.rewind(mark);
        let chunks = n.div_ceil(65535).max(1);
        for k in 0..chunks {
            let chunk = &data[s + k * 65535..e.min(s + (k + 1) * 65535)];
            w.put(u64::from(last && k + 1 == chunks), 3);
            w.align();
            let len = chunk.len() as u16;
            w.bytes(&len.to_le_bytes());
            w.bytes(&(!len).to_le_bytes());
            w.bytes(chunk);
        }
    }
}

/// The literals and matches of `data[s..e]`, then the end-of-block code, with the writer's
/// state in registers; `N` literals go out per flush (N codes of the longest literal code
/// length must fit 56 bits). The writer must have room for the block (`reserve_bits`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn emit<const N: usize>(
    w: &mut BitWriter,
    data: &[u8],
    s: usize,
    e: usize,
    tokens: &[Match],
    lit: &Literals,
    lcode: &[(u64, u32); 29],
    dcode: &[(u64, u32); MAX_DISTANCES],
    end: (u64, u32),
) {
    let out = &mut w.out[..];
    let (mut pos, mut acc, mut n) = (w.pos, w.acc, w.n);
    macro_rules! flush {
        () => {
            out[pos..pos + 8].copy_from_slice(&acc.to_le_bytes());
            pos += (n >> 3) as usize;
            acc >>= n & 56;
            n &= 7;
        };
    }
    macro_rules! add {
        ($v:expr, $len:expr) => {
            acc |= $v << n;
            n += $len;
        };
    }
    let mut i = s;
    for t in tokens {
        let p = s + t.pos as usize;
        (pos, acc, n) = literals::<N>(out, data, i, p, lit, (pos, acc, n));
        let len = t.len as usize;
        let ls = LEN_SYM[len - MIN_MATCH] as usize;
        let (lc, ln) = lcode[ls];
        add!(
            lc | (((len - LEN_BASE[ls] as usize) as u64) << ln),
            ln + u32::from(LEN_EXTRA[ls])
        );
        let (dc, dn) = dcode[t.d as usize];
        add!(dc, dn);
        flush!();
        i = p + len;
    }
    (pos, acc, n) = literals::<N>(out, data, i, e, lit, (pos, acc, n));
    add!(end.0, end.1);
    flush!();
    (w.pos, w.acc, w.n) = (pos, acc, n);
}

/// The literals' codes (bit-reversed) and lengths.
struct Literals {
    code: [u64; 256],
    len: [u8; 256],
}

/// The codes of the literals `data[q..e]`, `N` per flush, into `out` at bit state (`p`, `a`,
/// `k`); the new state.
#[inline(always)]
fn literals<const N: usize>(
    out: &mut [u8],
    data: &[u8],
    q: usize,
    e: usize,
    lit: &Literals,
    (mut p, mut a, mut k): (usize, u64, u32),
) -> (usize, u64, u32) {
    let mut groups = data[q..e].chunks_exact(N);
    for g in &mut groups {
        // The N codes joined first, independently of the writer's state.
        let (mut v, mut l) = (0u64, 0u32);
        for &b in g {
            v |= lit.code[b as usize] << l;
            l += u32::from(lit.len[b as usize]);
        }
        a |= v << k;
        k += l;
        out[p..p + 8].copy_from_slice(&a.to_le_bytes());
        p += (k >> 3) as usize;
        a >>= k & 56;
        k &= 7;
    }
    let r = groups.remainder().len();
    let t = e - r;
    if let Some(tail) = data.get(t..t + N - 1) {
        // The last r < N without a branch on r: N − 1 codes, those from r on masked off.
        let (mut v, mut l) = (0u64, 0u32);
        for (j, &b) in tail.iter().enumerate() {
            let keep = 0u64.wrapping_sub(u64::from(j < r));
            v |= (lit.code[b as usize] & keep) << l;
            l += u32::from(lit.len[b as usize]) & keep as u32;
        }
        a |= v << k;
        k += l;
    } else {
        for &b in &data[t..e] {
            a |= lit.code[b as usize] << k;
            k += u32::from(lit.len[b as usize]);
        }
    }
    out[p..p + 8].copy_from_slice(&a.to_le_bytes());
    p += (k >> 3) as usize;
    a >>= k & 56;
    k &= 7;
    (p, a, k)
}

/// An LSB-first bit writer (deflate's order): a 64-bit accumulator written out 8 bytes at a
/// time, advancing by the whole bytes in it. Between two flushes at most 56 bits may be added.
struct BitWriter {
    out: Vec<u8>,
    pos: usize,
    acc: u64,
    n: u32,
}

impl BitWriter {
    fn with_capacity(n: usize) -> Self {
        BitWriter {
            out: vec![0; n + 16],
            pos: 0,
            acc: 0,
            n: 0,
        }
    }

    #[inline(always)]
    fn add(&mut self, v: u64, len: u32) {
        self.acc |= v << self.n;
        self.n += len;
    }

    #[inline(always)]
    fn flush(&mut self) {
        if self.pos + 8 > self.out.len() {
            self.out.resize(2 * self.out.len() + 16, 0);
        }
        self.out[self.pos..self.pos + 8].copy_from_slice(&self.acc.to_le_bytes());
        let bytes = self.n >> 3;
        self.pos += bytes as usize;
        self.acc >>= bytes * 8;
        self.n &= 7;
    }

    #[inline(always)]
    fn put(&mut self, v: u64, len: u32) {
        self.add(v, len);
        self.flush();
    }

    /// The writer's state, to come back to.
    fn mark(&self) -> (usize, u64, u32) {
        (self.pos, self.acc, self.n)
    }

    /// Bits written since `mark`.
    fn bits_since(&self, mark: (usize, u64, u32)) -> u64 {
        (self.pos as u64 * 8 + u64::from(self.n)) - (mark.0 as u64 * 8 + u64::from(mark.2))
    }

    /// Forget what was written since `mark`.
    fn rewind(&mut self, mark: (usize, u64, u32)) {
        (self.pos, self.acc, self.n) = mark;
    }

    /// Make room for `bits` more bits (and the 8-byte writes past them).
    fn reserve_bits(&mut self, bits: u64) {
        let need = self.pos + (bits / 8) as usize + 32;
        if need > self.out.len() {
            self.out.resize(need, 0);
        }
    }

    /// Pad to a byte boundary with zero bits.
    fn align(&mut self) {
        self.flush();
        if self.n > 0 {
            self.pos += 1;
            self.acc = 0;
            self.n = 0;
        }
    }

    /// Append bytes; the writer must be byte-aligned.
    fn bytes(&mut self, b: &[u8]) {
        debug_assert_eq!(self.n, 0);
        if self.pos + b.len() + 8 > self.out.len() {
            self.out.resize(self.pos + b.len() + self.out.len() + 16, 0);
        }
        self.out[self.pos..self.pos + b.len()].copy_from_slice(b);
        self.pos += b.len();
    }

    fn finish(mut self) -> Vec<u8> {
        debug_assert_eq!(self.n, 0);
        self.out.truncate(self.pos);
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inflate(z: &[u8]) -> Vec<u8> {
        miniz_oxide::inflate::decompress_to_vec_zlib(z).expect("a valid zlib stream")
    }

    /// Compress, check that miniz_oxide and zune-inflate both give the input back, and return
    /// the stream's length.
    fn round_trip(data: &[u8], dist: &[usize], what: &str) -> usize {
        let z = zlib(data, dist);
        assert_eq!(inflate(&z), data, "{what}: {} bytes", data.len());
        let options = zune_inflate::DeflateOptions::default()
            .set_limit(data.len())
            .set_size_hint(data.len());
        let zune = zune_inflate::DeflateDecoder::new_with_options(&z, options)
            .decode_zlib()
            .unwrap_or_else(|e| panic!("{what}: zune-inflate: {e:?}"));
        assert_eq!(zune, data, "{what}: {} bytes (zune-inflate)", data.len());
        z.len()
    }

    const LENGTHS: [usize; 15] = [
        0, 1, 2, 3, 4, 63, 64, 65, 257, 258, 259, 65535, 65536, 65537, 70000,
    ];

    /// Random bytes, zeros, runs, periodic data and a mix, of lengths around every boundary
    /// (a window, the longest match, a stored block), with several distance sets.
    #[test]
    fn streams_inflate_to_their_input() {
        let mut rnd = crate::testutil::rng(5);
        for n in LENGTHS {
            let random: Vec<u8> = (0..n).map(|_| (rnd() * 256.0) as u8).collect();
            let cases: [(&str, Vec<u8>); 5] = [
                ("random", random.clone()),
                ("zeros", vec![0; n]),
                ("runs", (0..n).map(|i| ((i / 300) % 7) as u8).collect()),
                (
                    "periodic",
                    (0..n)
                        .map(|i| ((i % 64) * 3) as u8 ^ (i / 5000) as u8)
                        .collect(),
                ),
                (
                    "mixed",
                    (0..n)
                        .map(|i| if (i / 500) % 2 == 0 { random[i] } else { 128 })
                        .collect(),
                ),
            ];
            for (what, data) in &cases {
                for dist in [
                    &[1usize][..],
                    &[1, 2, 64],
                    &[2, 3, 100, 256, 380, 388, 32768],
                ] {
                    round_trip(data, dist, &format!("{what} {dist:?}"));
                }
            }
        }
        // Every distance set mip blocks get.
        let data: Vec<u8> = (0..40_000).map(|i| ((i / 7) % 5 + (i % 3)) as u8).collect();
        for bps in [&[4usize][..], &[4, 4], &[2, 2], &[2], &[4, 2], &[2, 4, 4]] {
            for (w, h) in [(64, 64), (1, 1), (3, 2), (32, 64), (2048, 16)] {
                round_trip(&data, &distances(bps, w, h), &format!("{bps:?} {w}×{h}"));
            }
        }
    }

    /// Byte k of `x` and `y` equal where the bit says, for each comparison this CPU runs.
    #[test]
    fn every_comparison_gives_the_same_masks() {
        let mut rnd = crate::testutil::rng(17);
        for _ in 0..200 {
            let x: [u8; 64] = std::array::from_fn(|_| (rnd() * 4.0) as u8);
            let y: [u8; 64] = std::array::from_fn(|_| (rnd() * 4.0) as u8);
            let want = (0..64).fold(0u64, |m, k| m | (u64::from(x[k] == y[k]) << k));
            // SAFETY: the portable comparison runs anywhere.
            assert_eq!(unsafe { Portable::eq(&x, &y) }, want);
            #[cfg(target_arch = "x86_64")]
            {
                use std::arch::is_x86_feature_detected as has;
                // SAFETY: SSE2 is part of x86_64; the others are checked.
                assert_eq!(unsafe { x86::Sse2::eq(&x, &y) }, want);
                if has!("avx2") {
                    assert_eq!(unsafe { x86::Avx2::eq(&x, &y) }, want);
                }
                if has!("avx512bw") {
                    assert_eq!(unsafe { x86::Avx512::eq(&x, &y) }, want);
                }
            }
        }
    }

    /// The probe gives up on noise and on nothing else: random bytes are left to be stored;
    /// every block it lets through gets exactly the bytes [`zlib`] writes (the parse goes on
    /// where the probe stopped); a block it gives up on would not have deflated to less than
    /// 80 % of its size; and blocks under [`PROBE_MIN`] bytes are never probed.
    #[test]
    fn the_probe_stores_noise_and_keeps_the_bytes_of_the_rest() {
        let mut rnd = crate::testutil::rng(17);
        let noise: Vec<u8> = (0..32768).map(|_| (rnd() * 256.0) as u8).collect();
        let dist = distances(&[4, 4], 64, 64);
        assert!(zlib_unless_weak(&noise, &dist).is_none());
        let small = &noise[..PROBE_MIN - 1];
        assert_eq!(zlib_unless_weak(small, &dist), Some(zlib(small, &dist)));
        // Repeats only after the probed sixteenth: the probe is fooled, and says so.
        let mut late = noise.clone();
        late[noise.len() / 8..].fill(7);
        assert!(zlib_unless_weak(&late, &dist).is_none());
        // Repeats in the first sixteenth, noise after it: deflated, as `zlib` would.
        let mut early = noise.clone();
        early[..noise.len() / 16].fill(7);
        assert_eq!(zlib_unless_weak(&early, &dist), Some(zlib(&early, &dist)));
        let (mut kept, mut stored) = (0, 0);
        for n in [130, 260] {
            for block in mip_blocks(n) {
                let z = zlib(&block, &dist);
                match zlib_unless_weak(&block, &dist) {
                    Some(p) => {
                        assert_eq!(p, z);
                        kept += 1;
                    }
                    None => {
                        assert!(block.len() >= PROBE_MIN);
                        assert!(
                            z.len() * 5 > block.len() * 4,
                            "a block that deflates to {} of {} bytes was given up",
                            z.len(),
                            block.len()
                        );
                        stored += 1;
                    }
                }
            }
        }
        assert!(kept > 0 && stored > 0, "{kept} kept, {stored} stored");
    }

    /// The radix sort of the Huffman keys gives a comparison sort's order, for alphabets of
    /// every size and counts of one to three bytes.
    #[test]
    fn keys_sort_as_a_comparison_sort_does() {
        let mut rnd = crate::testutil::rng(29);
        for m in [2usize, 19, 30, 32, 33, 100, 257, 288] {
            for top in [3u32, 200, 255, 256, 40_000, 65_535, 65_536, (1 << 23) - 1] {
                let mut keys: Vec<u32> = (0..m)
                    .map(|s| ((((rnd() * f64::from(top)) as u32).max(1)) << 9) | s as u32)
                    .collect();
                let mut want = keys.clone();
                want.sort_unstable();
                sort_keys(&mut keys);
                assert_eq!(keys, want, "{m} symbols, counts up to {top}");
            }
        }
    }

    /// The quartered canonical codes are RFC 1951's: symbols in order, each length's codes
    /// consecutive from where the shorter ones end (§3.2.2's algorithm, here bit by bit).
    #[test]
    fn codes_are_the_canonical_ones() {
        let mut rnd = crate::testutil::rng(31);
        for n in [19usize, 30, 288] {
            for _ in 0..50 {
                let mut counts: Vec<u32> =
                    (0..n).map(|_| (rnd() * rnd() * 5000.0) as u32).collect();
                at_least_two(&mut counts);
                let mut lens = vec![0u8; n];
                code_lengths(&counts, if n == 19 { 7 } else { 15 }, &mut lens);
                let mut got = vec![0u16; n];
                codes(&lens, &mut got);
                let mut bl_count = [0u16; 16];
                for &l in &lens {
                    bl_count[l as usize] += 1;
                }
                bl_count[0] = 0;
                let (mut code, mut next) = (0u16, [0u16; 16]);
                for b in 1..16 {
                    code = (code + bl_count[b - 1]) << 1;
                    next[b] = code;
                }
                for (s, &l) in lens.iter().enumerate() {
                    if l == 0 {
                        assert_eq!(got[s], 0);
                        continue;
                    }
                    let c = next[l as usize];
                    next[l as usize] += 1;
                    let reversed = (0..l).fold(0u16, |r, b| (r << 1) | ((c >> b) & 1));
                    assert_eq!(got[s], reversed, "symbol {s} of {n}, length {l}");
                }
            }
        }
    }

    /// The bytes written do not depend on the instruction set the CPU offers.
    #[test]
    fn output_does_not_depend_on_the_instruction_set() {
        let (bps, w, h) = ([4usize, 4], 64, 64);
        let block = mip_blocks(130).swap_remove(0);
        let dist = distances(&bps, w, h);
        for probe in [false, true] {
            let want = zlib_with::<Portable>(&block, &dist, probe);
            assert_eq!(dispatch(&block, &dist, probe), want);
            #[cfg(target_arch = "x86_64")]
            {
                assert_eq!(zlib_with::<x86::Sse2>(&block, &dist, probe), want);
                if std::arch::is_x86_feature_detected!("avx2") {
                    assert_eq!(zlib_with::<x86::Avx2>(&block, &dist, probe), want);
                }
                if std::arch::is_x86_feature_detected!("avx512bw") {
                    assert_eq!(zlib_with::<x86::Avx512>(&block, &dist, probe), want);
                }
            }
        }
    }

    /// A (min, max) pyramid as the mip files hold one (level 0: the 3×3 extremes around each
    /// interior pixel, NaN left out; then 2×2 reductions, sizes rounding up), written here
    /// so that the codec's tests need no stage.
    struct Levels {
        sizes: Vec<usize>,
        min: Vec<Vec<f32>>,
        max: Vec<Vec<f32>>,
    }

    fn minmax_levels(height: &[f32], s: usize, halo: usize) -> Levels {
        let n = s - 2 * halo;
        let (mut lo, mut hi) = (vec![f32::NAN; n * n], vec![f32::NAN; n * n]);
        for j in 0..n {
            for i in 0..n {
                for (dy, dx) in (0..3).flat_map(|y| (0..3).map(move |x| (y, x))) {
                    let v = height[(j + halo + dy - 1) * s + i + halo + dx - 1];
                    lo[j * n + i] = lo[j * n + i].min(v);
                    hi[j * n + i] = hi[j * n + i].max(v);
                }
            }
        }
        let mut p = Levels {
            sizes: vec![n],
            min: vec![lo],
            max: vec![hi],
        };
        while *p.sizes.last().unwrap() > 1 {
            let m = *p.sizes.last().unwrap();
            let h = m.div_ceil(2);
            let (mut lo, mut hi) = (vec![f32::NAN; h * h], vec![f32::NAN; h * h]);
            for j in 0..m {
                for i in 0..m {
                    let k = (j / 2) * h + i / 2;
                    lo[k] = lo[k].min(p.min.last().unwrap()[j * m + i]);
                    hi[k] = hi[k].max(p.max.last().unwrap()[j * m + i]);
                }
            }
            p.sizes.push(h);
            p.min.push(lo);
            p.max.push(hi);
        }
        p
    }

    /// Predicted bytes of the 64² blocks (both channels, every level) of a (min, max) pyramid
    /// of an analytic height field with noise and a hole, as the mip files lay them out.
    fn mip_blocks(n: usize) -> Vec<Vec<u8>> {
        let s = n + 4;
        let mut rnd = crate::testutil::rng(23);
        let height: Vec<f32> = (0..s * s)
            .map(|i| {
                let (x, y) = ((i % s) as f32, (i / s) as f32);
                if (x - 40.0).hypot(y - 50.0) < 6.0 {
                    f32::NAN
                } else {
                    1000.0 + 300.0 * (x * 0.05).sin() * (y * 0.031).cos() + rnd() as f32
                }
            })
            .collect();
        let p = minmax_levels(&height, s, 2);
        let mut out = Vec::new();
        for (l, &size) in p.sizes.iter().enumerate() {
            for by in (0..size).step_by(64) {
                for bx in (0..size).step_by(64) {
                    let (w, h) = ((size - bx).min(64), (size - by).min(64));
                    let mut packed = Vec::new();
                    for y in by..by + h {
                        for level in [&p.max[l], &p.min[l]] {
                            for v in &level[y * size + bx..y * size + bx + w] {
                                packed.extend_from_slice(&v.to_le_bytes());
                            }
                        }
                    }
                    let mut predicted = Vec::new();
                    crate::exrcodec::predict::predict(&packed, &mut predicted);
                    out.push(predicted);
                }
            }
        }
        out
    }

    /// Real predicted mip bytes go through and come back, and deflate finds their repeats.
    #[test]
    fn mip_blocks_inflate_to_their_input() {
        let blocks = mip_blocks(130);
        let raw: usize = blocks.iter().map(Vec::len).sum();
        let mut total = 0;
        for b in &blocks {
            let w = (b.len() / 8).isqrt().clamp(1, 64);
            total += round_trip(b, &distances(&[4, 4], w, b.len() / 8 / w), "mip block");
        }
        assert!(total < raw, "{total} bytes for {raw}");
    }

    /// A smooth ramp's predicted bytes shrink to a fraction: the blocks are not stored.
    #[test]
    fn smooth_data_is_not_stored() {
        let (w, h) = (64usize, 64usize);
        let mut packed = Vec::new();
        for y in 0..h {
            for x in 0..w {
                // Whole metres, as SRTM's heights, each repeated over 2×2 as max-pooling does.
                let v = 1000.0f32 + (x / 2) as f32 * 3.0 + (y / 2) as f32 * 7.0;
                packed.extend_from_slice(&v.to_le_bytes());
            }
        }
        let mut predicted = Vec::new();
        crate::exrcodec::predict::predict(&packed, &mut predicted);
        // 3865 bytes of 16384 (miniz_oxide level 4: 894; stored: 16395).
        let z = round_trip(&predicted, &distances(&[4], w, h), "ramp");
        assert!(
            z * 10 < predicted.len() * 3,
            "{z} bytes for {} (≥ 30 %)",
            predicted.len()
        );
    }

    fn kraft(lens: &[u8], limit: u32) -> u64 {
        lens.iter()
            .filter(|&&l| l > 0)
            .map(|&l| 1u64 << (limit - u32::from(l)))
            .sum()
    }

    /// Skewed counts (powers of two, Fibonacci numbers) make Huffman codes as deep as the
    /// alphabet: the lengths are cut to the limit and the code stays complete, the commoner
    /// symbol never the longer code.
    #[test]
    fn code_lengths_are_limited_and_complete() {
        let fib = |n: usize| {
            let mut v = vec![1u32, 1];
            while v.len() < n {
                v.push(v[v.len() - 1] + v[v.len() - 2]);
            }
            v
        };
        // Powers of two: Huffman's code as deep as the alphabet, with no ties.
        for (n, limit) in [(23usize, 15usize), (19, 7), (9, 7)] {
            let counts: Vec<u32> = (0..n).map(|k| 1 << k).collect();
            let mut lens = vec![0u8; n];
            code_lengths(&counts, limit, &mut lens);
            assert_eq!(*lens.iter().max().unwrap() as usize, limit, "{n}");
            assert_eq!(kraft(&lens, limit as u32), 1 << limit, "{n}: not complete");
        }
        for (n, limit) in [(30usize, 15usize), (19, 7), (286, 15), (2, 15), (3, 7)] {
            // Counts below 2²³ in all (what a block of at most MAX_BLOCK bytes gives).
            let mut counts = fib(n.min(30));
            counts.resize(n, 1);
            let mut lens = vec![0u8; n];
            code_lengths(&counts, limit, &mut lens);
            assert!(lens.iter().all(|&l| (1..=limit as u8).contains(&l)), "{n}");
            assert_eq!(kraft(&lens, limit as u32), 1 << limit, "{n}: not complete");
            for i in 0..n {
                for j in 0..n {
                    if counts[i] > counts[j] {
                        assert!(lens[i] <= lens[j], "{n}: {i} vs {j}");
                    }
                }
            }
        }
        // Unused symbols get no code.
        let mut lens = [9u8; 5];
        code_lengths(&[0, 5, 0, 1, 0], 15, &mut lens);
        assert_eq!(lens, [0, 1, 0, 1, 0]);
    }

    /// Literal frequencies in powers of two (each symbol as common as all rarer ones
    /// together, plus one), in random order: Huffman's code would be 20 deep, the literal code
    /// is cut to 15 bits and the stream still inflates.
    #[test]
    fn skewed_literals_use_the_longest_codes() {
        let mut rnd = crate::testutil::rng(31);
        let mut data: Vec<u8> = (0..20u32)
            .flat_map(|s| std::iter::repeat_n(s as u8 * 11, 1 << s))
            .collect();
        for i in (1..data.len()).rev() {
            data.swap(i, (rnd() * (i + 1) as f64) as usize);
        }
        let mut lit = [0u32; NLIT];
        for &b in &data {
            lit[b as usize] += 1;
        }
        lit[256] = 1;
        let mut sorted: Vec<u32> = lit.iter().copied().filter(|&c| c > 0).collect();
        sorted.sort_unstable();
        minimum_redundancy(&mut sorted);
        assert_eq!(sorted[0], 20, "{sorted:?}");
        let mut lens = [0u8; NLIT];
        code_lengths(&lit, 15, &mut lens);
        assert_eq!(lens.iter().max(), Some(&15));
        assert_eq!(kraft(&lens, 15), 1 << 15);
        round_trip(&data, &[1, 2], "skewed literals");
    }

    /// The code-length sequence uses repeats (16) and both zero runs (17, 18), and expands
    /// back to the lengths; streams whose headers need all three inflate.
    #[test]
    fn code_length_runs_are_coded_and_inflate() {
        let mut lens = vec![8u8; 20];
        lens.extend([0; 5]);
        lens.extend([7; 3]);
        lens.extend([0; 140]);
        lens.extend([0, 0, 5, 5, 6]);
        let mut seq = Vec::new();
        rle_lengths(&lens, &mut seq);
        for sym in [16, 17, 18] {
            assert!(
                seq.iter().any(|&(s, _)| s == sym),
                "no symbol {sym}: {seq:?}"
            );
        }
        let mut back = Vec::new();
        for &(s, x) in &seq {
            match s {
                16 => {
                    let last = *back.last().unwrap();
                    back.extend(std::iter::repeat_n(last, 3 + x as usize));
                }
                17 => back.extend(std::iter::repeat_n(0, 3 + x as usize)),
                18 => back.extend(std::iter::repeat_n(0, 11 + x as usize)),
                l => back.push(l),
            }
        }
        assert_eq!(back, lens);
        // Literals 0–39 equally often (a run of equal lengths), then 45, 52 and 200–255:
        // zero runs of 5, 6 and 147 between them.
        let mut rnd = crate::testutil::rng(41);
        let values: Vec<u8> = (0..40).chain([45, 52]).chain(200..=255).collect();
        let data: Vec<u8> = (0..50_000)
            .map(|_| values[(rnd() * values.len() as f64) as usize])
            .collect();
        round_trip(&data, &[1, 2, 256], "runs of code lengths");
    }
}
