//! One ZIP block as a zlib stream that stores what deflate could not shrink.
//!
//! OpenEXR's ZIP transform lays a block out as the even bytes of every line's channels, then
//! the odd bytes, delta-predicted. Where a channel's samples are noise to deflate (the f32
//! heights of an oversampled bilinear tile: mantissa bytes that look random, measured ratio
//! 1.00 in docs/benchmarks.md, "EXR codec") the LZ77 search and the Huffman tables cost most of
//! a stage's write time and save nothing. Here each channel's stretch of the block is judged by
//! the order-0 entropy of a sample of its predicted bytes: noisy channels go into stored deflate
//! blocks (a copy), the others into fixed-Huffman blocks that code runs of a repeated byte as
//! distance-1 matches (a mask or a no-data stretch shrinks 50–100×). The result is one ordinary
//! zlib stream, so the file stays plain OpenEXR ZIP that every reader inflates; only the encoder
//! changed, and the samples are the same bits.

/// Bits per byte of order-0 entropy above which a channel's predicted bytes count as noise:
/// a Huffman code could save at most 1 − 7.75/8 ≈ 3 % of them, less than its tables and the
/// time cost (deflate found no repeats in such data either: ratio 1.00 on LDEM_4's heights).
pub(super) const NOISE_BITS: f64 = 7.75;

/// Every how many bytes one enters the entropy estimate (an 8th of a block is plenty for a
/// 256-bin histogram and keeps the estimate ≈ 8× cheaper than deflating).
const STRIDE: usize = 8;

/// Fewer sampled bytes than this in a channel and it is never judged noise (too few for a
/// 256-bin estimate; such blocks are tiny anyway).
const MIN_SAMPLES: u32 = 1024;

/// Each channel's stretch of one half of the block: `(start, len, channel)` in block order,
/// for `lines` lines of `width` samples whose channels take `bps` bytes per sample.
fn segments(
    bps: &[usize],
    width: usize,
    lines: usize,
) -> impl Iterator<Item = (usize, usize, usize)> + '_ {
    let line: usize = bps.iter().map(|b| b * width / 2).sum();
    let half = line * lines;
    (0..2).flat_map(move |side| {
        (0..lines).flat_map(move |l| {
            let mut off = side * half + l * line;
            bps.iter().enumerate().map(move |(c, b)| {
                let len = b * width / 2;
                let s = off;
                off += len;
                (s, len, c)
            })
        })
    })
}

/// The channels (bit c for channel c, at most 32) whose predicted bytes in this block look
/// like noise to deflate: order-0 entropy above [`NOISE_BITS`] on a sample, confirmed by
/// deflating an excerpt of the channel (`probe`: zlib size of its argument). The entropy alone
/// misses repeats, which deflate does find: max-pooled mip levels repeat each value over 2×2
/// and more, at an entropy that looks like noise but a deflate ratio of 1.2–3.
pub(super) fn noisy_channels(
    predicted: &[u8],
    bps: &[usize],
    width: usize,
    lines: usize,
    probe: impl Fn(&[u8]) -> usize,
) -> u32 {
    if bps.len() > 32 || bps.iter().any(|b| b % 2 != 0) {
        return 0;
    }
    let mut hist = vec![[0u32; 256]; bps.len()];
    for (s, len, c) in segments(bps, width, lines) {
        let h = &mut hist[c];
        for &v in predicted[s..s + len].iter().step_by(STRIDE) {
            h[v as usize] += 1;
        }
    }
    let mut noisy = 0;
    let mut excerpt = Vec::with_capacity(PROBE_BYTES);
    for (c, h) in hist.iter().enumerate() {
        let n: u32 = h.iter().sum();
        if n < MIN_SAMPLES {
            continue;
        }
        let nf = n as f64;
        let sum: f64 = h
            .iter()
            .filter(|&&k| k > 0)
            .map(|&k| k as f64 * (k as f64).log2())
            .sum();
        let bits = nf.log2() - sum / nf;
        if bits <= NOISE_BITS {
            continue;
        }
        // The channel's first stretches of the even half, line after line, as deflate would
        // meet them (with the other channels' stretches between them left out).
        excerpt.clear();
        for (s, len, _) in segments(bps, width, lines).filter(|&(_, _, k)| k == c) {
            let take = len.min(PROBE_BYTES - excerpt.len());
            excerpt.extend_from_slice(&predicted[s..s + take]);
            if excerpt.len() == PROBE_BYTES {
                break;
            }
        }
        if probe(&excerpt) as f64 >= PROBE_RATIO * excerpt.len() as f64 {
            noisy |= 1 << c;
        }
    }
    noisy
}

/// Bytes of a noisy-looking channel deflated to confirm it is noise.
const PROBE_BYTES: usize = 4096;

/// A channel is stored when deflate leaves its excerpt at more than this share of its size.
const PROBE_RATIO: f64 = 0.97;

/// The zlib stream of `predicted` (one block after OpenEXR's predictor) with the channels in
/// `noisy` stored and the others run-length coded in fixed-Huffman blocks.
pub(super) fn zlib(
    predicted: &[u8],
    bps: &[usize],
    width: usize,
    lines: usize,
    noisy: u32,
) -> Vec<u8> {
    let mut w = Bits {
        out: Vec::with_capacity(predicted.len() + predicted.len() / 64 + 64),
        acc: 0,
        n: 0,
    };
    // CMF: deflate, 32 KiB window; FLG: fastest, no dictionary, check bits.
    w.out.extend_from_slice(&[0x78, 0x01]);
    // Consecutive stretches of the same kind go out as one run.
    let mut run: Option<(usize, usize, bool)> = None;
    for (s, len, c) in segments(bps, width, lines) {
        let store = noisy & (1 << c) != 0;
        match run {
            Some((rs, re, k)) if k == store && re == s => run = Some((rs, re + len, k)),
            _ => {
                if let Some((rs, re, k)) = run {
                    w.block(&predicted[rs..re], k);
                }
                run = Some((s, s + len, store));
            }
        }
    }
    if let Some((rs, re, k)) = run {
        w.block(&predicted[rs..re], k);
    }
    // The last block: empty, fixed Huffman, final.
    w.put(0b011, 3);
    w.put(0, 7);
    w.align();
    let adler = simd_adler32::adler32(&predicted);
    w.out.extend_from_slice(&adler.to_be_bytes());
    w.out
}

/// An LSB-first bit writer (deflate's order).
struct Bits {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

/// Length symbols' base lengths and extra bits (RFC 1951 §3.2.5), symbols 257–285.
const LEN_BASE: [u16; 29] = [
    3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131,
    163, 195, 227, 258,
];
const LEN_EXTRA: [u32; 29] = [
    0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0,
];

impl Bits {
    #[inline]
    fn put(&mut self, v: u64, len: u32) {
        self.acc |= v << self.n;
        self.n += len;
        while self.n >= 8 {
            self.out.push(self.acc as u8);
            self.acc >>= 8;
            self.n -= 8;
        }
    }

    fn align(&mut self) {
        if self.n > 0 {
            self.out.push(self.acc as u8);
            self.acc = 0;
            self.n = 0;
        }
    }

    /// A fixed-Huffman code (RFC 1951 §3.2.6), written most significant bit first.
    #[inline]
    fn symbol(&mut self, sym: u16) {
        let (code, len) = match sym {
            0..=143 => (0x30 + sym as u32, 8),
            144..=255 => (0x190 + (sym as u32 - 144), 9),
            256..=279 => (sym as u32 - 256, 7),
            _ => (0xC0 + (sym as u32 - 280), 8),
        };
        self.put(u64::from(code.reverse_bits() >> (32 - len)), len);
    }

    /// One run of the block: stored, or run-length coded (matches stay within the run).
    fn block(&mut self, data: &[u8], store: bool) {
        if store {
            for chunk in data.chunks(u16::MAX as usize) {
                self.put(0b000, 3);
                self.align();
                let len = chunk.len() as u16;
                self.out.extend_from_slice(&len.to_le_bytes());
                self.out.extend_from_slice(&(!len).to_le_bytes());
                self.out.extend_from_slice(chunk);
            }
            return;
        }
        // BFINAL 0, BTYPE 01 (fixed Huffman).
        self.put(0b010, 3);
        let mut i = 0;
        while i < data.len() {
            if i > 0 {
                let prev = data[i - 1];
                let max = (data.len() - i).min(258);
                let mut r = 0;
                while r < max && data[i + r] == prev {
                    r += 1;
                }
                if r >= 3 {
                    let k = LEN_BASE.partition_point(|&b| b as usize <= r) - 1;
                    self.symbol(257 + k as u16);
                    if LEN_EXTRA[k] > 0 {
                        self.put((r - LEN_BASE[k] as usize) as u64, LEN_EXTRA[k]);
                    }
                    // Distance 1: distance code 0, five bits, none extra.
                    self.put(0, 5);
                    i += r;
                    continue;
                }
            }
            self.symbol(u16::from(data[i]));
            i += 1;
        }
        self.symbol(256);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inflate(z: &[u8], n: usize) -> Vec<u8> {
        let options = zune_inflate::DeflateOptions::default()
            .set_limit(n)
            .set_size_hint(n);
        zune_inflate::DeflateDecoder::new_with_options(z, options)
            .decode_zlib()
            .unwrap()
    }

    /// Every mix of stored and run-length coded channels inflates to the bytes given, with
    /// zune-inflate and with miniz_oxide (two independent inflaters), for runs of every length
    /// deflate codes differently and for stored stretches longer than one stored block.
    #[test]
    fn mixed_streams_inflate_to_their_input() {
        let mut rnd = crate::testutil::rng(0x51ED_270B_A5E1_1C3Du64);
        for (width, lines, bps) in [
            (1usize, 1usize, vec![4usize, 2]),
            (7, 3, vec![4, 2]),
            (512, 16, vec![4, 2]),
            (64, 64, vec![4, 4]),
            (40_000, 2, vec![4]),
            (300, 5, vec![2, 4, 2]),
        ] {
            let n: usize = bps.iter().sum::<usize>() * width * lines;
            let mut data = vec![0u8; n];
            for (s, len, c) in segments(&bps, width, lines) {
                for (k, v) in data[s..s + len].iter_mut().enumerate() {
                    // Channel 0 noise; the others runs of every length up to past 258.
                    *v = if c == 0 {
                        (rnd() * 256.0) as u8
                    } else {
                        ((k / (1 + (k % 300))) % 3) as u8 + 127
                    };
                }
            }
            for noisy in 0..(1u32 << bps.len()) {
                let z = zlib(&data, &bps, width, lines, noisy);
                assert_eq!(
                    inflate(&z, n),
                    data,
                    "{width}×{lines} {bps:?} noisy {noisy:b}"
                );
                let m = miniz_oxide::inflate::decompress_to_vec_zlib(&z).unwrap();
                assert_eq!(m, data);
            }
        }
    }

    fn probe(b: &[u8]) -> usize {
        miniz_oxide::deflate::compress_to_vec_zlib(b, 1).len()
    }

    /// Random bytes are noise, a run-heavy mask is not, and neither are noise-like values
    /// repeated as max-pooling repeats them; each channel is judged apart.
    #[test]
    fn noise_is_told_from_structure_per_channel() {
        let mut rnd = crate::testutil::rng(7);
        let (width, lines, bps) = (512, 16, [4usize, 2]);
        let n = 6 * width * lines;
        let mut data = vec![128u8; n];
        for (s, len, c) in segments(&bps, width, lines) {
            if c == 0 {
                for v in &mut data[s..s + len] {
                    *v = (rnd() * 256.0) as u8;
                }
            }
        }
        assert_eq!(noisy_channels(&data, &bps, width, lines, probe), 0b01);
        // A smooth ramp in channel 0 (few distinct deltas) is not noise.
        for (s, len, c) in segments(&bps, width, lines) {
            if c == 0 {
                for (k, v) in data[s..s + len].iter_mut().enumerate() {
                    *v = 127 + (k % 3) as u8;
                }
            }
        }
        assert_eq!(noisy_channels(&data, &bps, width, lines, probe), 0);
        // Random byte pairs, each repeated four times along the line: order-0 entropy of
        // noise, but deflate codes the repeats as matches.
        for (s, len, c) in segments(&bps, width, lines) {
            if c == 0 {
                let mut k = 0;
                while k + 8 <= len {
                    let (a, b) = ((rnd() * 256.0) as u8, (rnd() * 256.0) as u8);
                    data[s + k..s + k + 8].copy_from_slice(&[a, b, a, b, a, b, a, b]);
                    k += 8;
                }
            }
        }
        assert_eq!(noisy_channels(&data, &bps, width, lines, probe), 0);
    }
}
