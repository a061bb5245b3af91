//! The randomised round trip of the deflate encoder in [`super`]: the guard a compressor of
//! user data needs. Blocks of every kind of content the codec meets or could meet, of every
//! size from 0 bytes to past the largest block it writes, are compressed with the match
//! distances of the block layouts the codec uses (and with arbitrary distance sets), and each
//! stream is inflated by miniz_oxide, by zune-inflate and by libdeflate and compared with its
//! input byte for byte ([`super::check::round_trip`], which the fuzz target in tools/fuzz runs
//! too).
//!
//! Each kind of content is one test, of 100 375 blocks (73 MB; the runs 118 025, with a sweep
//! of 17 650 blocks over every candidate distance of the layouts):
//! - 100 000 ([`SMALL`]) of a size drawn log-uniformly from 1 to [`SMALL_MAX`] (4096) bytes:
//!   about 8 300 in each octave, ≈ 490 bytes on average;
//! - 135 ([`LARGE`]) in the octaves from 4 KiB to 4 MiB, 64 in the first, halving to 2 and 1
//!   in the last: past the largest block a tile set's products have ([`LARGEST`], a 16-line
//!   f32 horizon map of the largest tile size, 8192) into the lit-fraction maps of wide
//!   regions, which the encoder cuts into deflate blocks of [`MAX_BLOCK`];
//! - 240 of [`EDGE_SIZES`] (37 sizes around every boundary of the encoder and of deflate:
//!   the 64-byte windows, the longest match, a stored chunk, the window size, [`PROBE_MIN`],
//!   [`LARGEST`], [`MAX_BLOCK`]), 8 blocks each up to 128 KiB and 1 above.
//!
//! `cargo test` (the dev profile, opt-level 1) ran the seven in 47 s on two shared cores.
//! The predicted samples are synthetic tiles of the layouts the codec writes, so their sizes
//! follow the drawn ones only to a whole line. Every stream comes from [`super::zlib`]; from
//! [`super::zlib_unless_weak`] too where it probes (from [`PROBE_MIN`] bytes on; below, it is
//! `zlib` and is tried with the next checks only). One block in 32 and the edge blocks up to
//! 128 KiB also go through every instruction-set variant of the encoder this CPU has, with and
//! without the probe, which must write the same bytes.
//!
//! A failure names the seed, the kind, the block's index, its layout, distances and
//! generator's parameters. `PENUMBRA_DEFLATE_BLOCK=<index>` runs that block alone
//! (`cargo test -p penumbra --lib exrcodec::layout::roundtrip::<test>`);
//! `PENUMBRA_DEFLATE_SEED=<seed>` (decimal or 0x-hex) draws other blocks than the default
//! seed's, which CI runs.

use super::check::round_trip;
use super::{distances, MAX_BLOCK, MAX_DISTANCES, PROBE_MIN, WINDOW};
use rayon::prelude::*;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// The seed CI runs (`PENUMBRA_DEFLATE_SEED` chooses another).
const SEED: u64 = 0x5eed_def1_a7e5_0001;
/// Blocks per kind of a size drawn log-uniformly from 1 to `SMALL_MAX` bytes.
const SMALL: usize = 100_000;
const SMALL_MAX: usize = 4096;
/// Blocks per kind in each octave from `SMALL_MAX` (2¹²) up, of a size drawn log-uniformly in
/// it: fewer the larger, the last reaching past `2 · MAX_BLOCK` (three deflate blocks).
const LARGE: [usize; 10] = [64, 32, 16, 8, 4, 4, 2, 2, 2, 1];
/// The largest block among a tile set's products: 16 lines of a horizon map (one f32
/// channel) of the largest tile size, 8192 (the mip files' tiles are 32 KiB at most). Only
/// lit-fraction maps of wide regions have larger blocks, which the encoder cuts at
/// [`MAX_BLOCK`].
const LARGEST: usize = 16 * 8192 * 4;
/// Sizes around the encoder's and deflate's boundaries, each tried by every kind: the empty
/// block; the 64 bytes compared at once (62 positions a window); the longest match; the probe's
/// threshold and its sixteenth's window; the window size; a stored chunk; the largest block;
/// the deflate blocks a large input is cut into.
const EDGE_SIZES: [usize; 37] = [
    0,
    1,
    2,
    3,
    4,
    62,
    63,
    64,
    65,
    66,
    126,
    127,
    128,
    257,
    258,
    259,
    PROBE_MIN - 1,
    PROBE_MIN,
    PROBE_MIN + 1,
    16 * 64 * 16 - 1,
    16 * 64 * 16,
    32767,
    32768,
    32769,
    65534,
    65535,
    65536,
    65537,
    2 * 65535 + 1,
    LARGEST - 1,
    LARGEST,
    LARGEST + 1,
    MAX_BLOCK - 1,
    MAX_BLOCK,
    MAX_BLOCK + 1,
    MAX_BLOCK + 65535,
    2 * MAX_BLOCK + 1,
];
/// Blocks of each edge size per kind: fewer of the large ones.
fn edge_reps(size: usize) -> usize {
    if size <= 1 << 17 {
        8
    } else {
        1
    }
}

/// splitmix64: a seeded stream of 64-bit numbers, the same on every platform.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (n ≥ 1).
    fn below(&mut self, n: usize) -> usize {
        ((u128::from(self.next()) * n as u128) >> 64) as usize
    }

    /// Uniform in lo..=hi.
    fn range(&mut self, lo: usize, hi: usize) -> usize {
        lo + self.below(hi - lo + 1)
    }

    /// True with probability 1/n.
    fn one_in(&mut self, n: usize) -> bool {
        self.below(n) == 0
    }

    fn byte(&mut self) -> u8 {
        self.next() as u8
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// In lo..=hi (lo ≥ 1), log-uniformly: each octave as likely.
    fn log_uniform(&mut self, lo: usize, hi: usize) -> usize {
        let (a, b) = ((lo as f64).ln(), ((hi + 1) as f64).ln());
        ((a + self.unit() * (b - a)).exp() as usize).clamp(lo, hi)
    }

    fn pick<T: Copy>(&mut self, from: &[T]) -> T {
        from[self.below(from.len())]
    }

    fn fill(&mut self, out: &mut [u8]) {
        let mut c = out.chunks_exact_mut(8);
        for q in &mut c {
            q.copy_from_slice(&self.next().to_le_bytes());
        }
        let r = c.into_remainder();
        let x = self.next().to_le_bytes();
        r.copy_from_slice(&x[..r.len()]);
    }
}

/// What a block is made of; each kind is one test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// Random bytes from an alphabet of 1–256 values, uniform or skewed: Huffman-coded.
    Random,
    /// One byte repeated.
    Constant,
    /// Little-endian integers of 1, 2 or 4 bytes stepping by a stride, each repeated 1–4 times.
    Ramp,
    /// Runs repeating the bytes at the layout's candidate distances, with mutations.
    Runs,
    /// Uniform random bytes: stored.
    Incompressible,
    /// Synthetic f32/f16 tiles of the layouts the codec writes, predicted as OpenEXR's ZIP.
    Samples,
    /// Segments of all the above but samples.
    Mixed,
}

/// A layout the codec writes, or one it could: (bytes per sample of each channel, width,
/// lines) and a name.
fn draw_layout(rng: &mut Rng) -> (Vec<usize>, usize, usize, &'static str) {
    let side = |rng: &mut Rng, max: usize| {
        if rng.one_in(2) {
            max
        } else {
            rng.range(1, max)
        }
    };
    match rng.below(5) {
        0 | 1 => {
            // Mip tiles: max (and min), f32 or f16, 64² or the edge and coarse levels' less.
            let bps: &[usize] = rng.pick(&[&[4, 4][..], &[2, 2], &[4], &[2]]);
            (bps.to_vec(), side(rng, 64), side(rng, 64), "mip tile")
        }
        2 | 3 => {
            // Scanline blocks of 16 lines (fewer at the bottom): horizon maps (f32, f16),
            // lit-fraction maps (f32), height tiles (f32 height + f16 mask), up to the largest
            // tile size and past it (lit maps).
            let bps: &[usize] = rng.pick(&[&[4][..], &[2], &[4, 2]]);
            let w = rng.log_uniform(1, 1 << 15);
            (bps.to_vec(), w, side(rng, 16), "scanlines")
        }
        _ => {
            // Other channel lists (none: the encoder's default [1, 2]).
            let bps: &[usize] = rng.pick(&[
                &[][..],
                &[2, 2, 2],
                &[4, 4, 4],
                &[2, 4],
                &[4, 4, 2],
                &[2, 2, 2, 2],
                &[1],
                &[4, 4, 4, 4, 4, 4, 4, 4],
            ]);
            (bps.to_vec(), rng.range(1, 514), rng.range(1, 16), "other")
        }
    }
}

/// Any distance set the encoder accepts: ascending, 1 to [`WINDOW`], at most
/// [`MAX_DISTANCES`] (the layouts give at most 7).
fn any_distances(rng: &mut Rng) -> Vec<usize> {
    let k = rng.range(1, MAX_DISTANCES);
    let mut d: Vec<usize> = (0..k)
        .map(|_| match rng.below(4) {
            0 => rng.range(1, 4),
            1 => WINDOW - rng.below(3),
            _ => rng.log_uniform(1, WINDOW),
        })
        .collect();
    d.sort_unstable();
    d.dedup();
    d
}

/// Random bytes from an alphabet of `a` values.
fn random(rng: &mut Rng, n: usize) -> (Vec<u8>, String) {
    let a = rng.log_uniform(1, 256);
    let values: Vec<u8> = (0..a).map(|_| rng.byte()).collect();
    let skew = rng.below(3);
    let data = (0..n)
        .map(|_| {
            let k = match skew {
                0 => rng.below(a),
                1 => rng.below(a).min(rng.below(a)),
                _ => rng.below(a) * rng.below(a) / a,
            };
            values[k]
        })
        .collect();
    (data, format!("alphabet {a}, skew {skew}"))
}

fn constant(rng: &mut Rng, n: usize) -> (Vec<u8>, String) {
    let c = rng.byte();
    (vec![c; n], format!("byte {c}"))
}

fn ramp(rng: &mut Rng, n: usize) -> (Vec<u8>, String) {
    let width = rng.pick(&[1usize, 2, 4]);
    let step = match rng.below(4) {
        0 => rng.range(0, 8) as u32,
        1 => (rng.range(0, 8) as u32).wrapping_neg(),
        2 => rng.pick(&[256u32, 65536, 1 << 24, 0x0101_0101]),
        _ => rng.next() as u32,
    };
    let repeat = rng.range(1, 4);
    let mut v = rng.next() as u32;
    let mut data = Vec::with_capacity(n + 4 * repeat);
    while data.len() < n {
        for _ in 0..repeat {
            data.extend_from_slice(&v.to_le_bytes()[..width]);
        }
        v = v.wrapping_add(step);
    }
    data.truncate(n);
    (
        data,
        format!("{width}-byte steps of {step:#x}, each ×{repeat}"),
    )
}

/// Bytes repeating those `d` before, `d` from `dist` (or `focus`), in segments of up to 600
/// bytes with a share of mutated bytes and some random segments between.
fn runs(rng: &mut Rng, n: usize, dist: &[usize], focus: Option<usize>) -> (Vec<u8>, String) {
    let mutate = rng.pick(&[0usize, 3, 1000, 100, 10]);
    let literal = rng.pick(&[0usize, 2, 8, 32]);
    let mut data = Vec::with_capacity(n);
    while data.len() < n {
        let len = rng.log_uniform(1, 600).min(n - data.len());
        let d = focus.unwrap_or_else(|| rng.pick(dist));
        let fresh = literal != 0 && rng.one_in(literal);
        for _ in 0..len {
            let i = data.len();
            let b = if fresh || i < d || (mutate != 0 && rng.one_in(mutate)) {
                rng.byte()
            } else {
                data[i - d]
            };
            data.push(b);
        }
    }
    let at = focus.map_or("the layout's distances".into(), |d| format!("distance {d}"));
    let desc = format!("runs at {at}, 1 byte in {mutate} mutated, 1 segment in {literal} random");
    (data, desc)
}

fn incompressible(rng: &mut Rng, n: usize) -> (Vec<u8>, String) {
    let mut data = vec![0u8; n];
    rng.fill(&mut data);
    (data, "uniform bytes".into())
}

/// A synthetic tile of about `target` bytes in a layout the codec writes (mip tiles, horizon
/// and lit-fraction maps, height tiles) as the encoder gets it: max-pooled heights with noise,
/// slopes, holes, the other channels repeating the first a line up and two samples aside,
/// packed line by line and channel by channel, predicted as OpenEXR's ZIP does. Its layout
/// (bytes per sample, width, lines), and a description.
fn samples(rng: &mut Rng, target: usize) -> (Vec<u8>, (Vec<usize>, usize, usize), String) {
    let mip = rng.one_in(2);
    let bps: Vec<usize> = if mip {
        rng.pick(&[&[4usize, 4][..], &[2, 2], &[4], &[2]]).to_vec()
    } else {
        rng.pick(&[&[4usize][..], &[2], &[4, 2]]).to_vec()
    };
    let per = bps.iter().sum::<usize>();
    let (mut lines, max_w) = if mip {
        ((target / per).isqrt().clamp(1, 64), 64)
    } else {
        ((target / per).clamp(1, 16), 1 << 20)
    };
    if rng.one_in(4) {
        lines = rng.range(1, lines);
    }
    let w = (target / (per * lines)).clamp(1, max_w);
    let pool = rng.below(3);
    let noise = rng.pick(&[0.0, 1e-4, 0.01, 1.0, 100.0, 1e6]);
    let (gx, gy) = (rng.unit() * 4.0 - 2.0, rng.unit() * 4.0 - 2.0);
    let base = rng.unit() * 4000.0 - 2000.0;
    let holes = rng.pick(&[0u64, 0, 97, 5]);
    let repeat = rng.one_in(2);
    let (x0, y0) = (rng.below(1 << 16), rng.below(1 << 16));
    let field = rng.next();
    let f = |x: usize, y: usize| {
        let (x, y) = ((x0 + x) >> pool, (y0 + y) >> pool);
        let mut h = Rng(field ^ (x as u64) << 32 ^ y as u64);
        let r = h.next();
        if holes != 0 && r % holes == 0 {
            return f32::NAN;
        }
        (base + gx * x as f64 + gy * y as f64 + noise * (h.unit() - 0.5)) as f32
    };
    let mut packed = Vec::with_capacity(per * w * lines);
    for y in 0..lines {
        for (k, &b) in bps.iter().enumerate() {
            for x in 0..w {
                let v = if repeat {
                    f(x + 2 * k, y + k)
                } else {
                    f(x, y) - 17.0 * k as f32
                };
                match b {
                    4 => packed.extend_from_slice(&v.to_bits().to_le_bytes()),
                    _ => packed.extend_from_slice(&half::f16::from_f32(v).to_bits().to_le_bytes()),
                }
            }
        }
    }
    let mut data = Vec::new();
    super::super::predict(&packed, &mut data);
    let desc = format!(
        "{} samples: pooled 2^{pool}, noise {noise}, slope ({gx:.3}, {gy:.3}), holes 1 in \
         {holes}, channels repeating: {repeat}",
        if mip { "mip" } else { "scanline" }
    );
    (data, (bps, w, lines), desc)
}

/// Segments of the kinds above (but samples), each of a log-uniform share of what is left.
fn mixed(rng: &mut Rng, n: usize, dist: &[usize]) -> (Vec<u8>, String) {
    let mut data = Vec::with_capacity(n);
    let mut parts = Vec::new();
    while data.len() < n {
        let len = rng.log_uniform(1, n - data.len());
        let kind = rng.below(5);
        let (mut seg, _) = match kind {
            0 => random(rng, len),
            1 => constant(rng, len),
            2 => ramp(rng, len),
            3 => {
                // Runs that go on from the bytes before.
                let (start, mutate) = (data.len(), rng.pick(&[0usize, 3, 100]));
                for i in start..start + len {
                    let d = rng.pick(dist);
                    let b = if i < d || (mutate != 0 && rng.one_in(mutate)) {
                        rng.byte()
                    } else {
                        data[i - d]
                    };
                    data.push(b);
                }
                (Vec::new(), String::new())
            }
            _ => incompressible(rng, len),
        };
        data.append(&mut seg);
        if parts.len() < 8 {
            parts.push(format!(
                "{}×{len}",
                ["random", "constant", "ramp", "runs", "noise"][kind]
            ));
        }
    }
    (data, format!("segments {}", parts.join(" ")))
}

/// Layouts whose every candidate distance the runs try, one block a distance: every width
/// to 514 of each channel list, the widths of the larger tiles and the widths whose line
/// distance is around the window's size.
fn sweep() -> Vec<(Vec<usize>, usize, usize)> {
    let mut out = Vec::new();
    let lists: [&[usize]; 7] = [
        &[4],
        &[2],
        &[4, 4],
        &[2, 2],
        &[2, 2, 2],
        &[4, 2],
        &[4, 4, 4],
    ];
    for bps in lists {
        let wide = [1024, 2048, 4096, 8192, 10922, 16383, 16384, 32767, 32768];
        for w in (1..=514).chain(wide) {
            for d in distances(bps, w, 3) {
                out.push((bps.to_vec(), w, d));
            }
        }
    }
    out
}

/// The size (or sweep entry) of each block of a kind, in index order.
enum Plan {
    /// One of [`EDGE_SIZES`].
    Edge(usize),
    Size(usize),
    Sweep(Vec<usize>, usize, usize),
}

fn plan(kind: Kind, seed: u64) -> Vec<Plan> {
    let mut rng = Rng(seed ^ 0x91a7);
    let mut p = Vec::new();
    for s in EDGE_SIZES {
        p.extend((0..edge_reps(s)).map(|_| Plan::Edge(s)));
    }
    for (k, &count) in LARGE.iter().enumerate() {
        let lo = SMALL_MAX << k;
        p.extend((0..count).map(|_| Plan::Size(rng.log_uniform(lo, 2 * lo - 1))));
    }
    p.extend((0..SMALL).map(|_| Plan::Size(rng.log_uniform(1, SMALL_MAX))));
    if kind == Kind::Runs {
        p.extend(sweep().into_iter().map(|(b, w, d)| Plan::Sweep(b, w, d)));
    }
    p
}

/// Make block `i` of a kind and check its round trip: (its length, the stream's), or the
/// failure with what reproduces it.
fn check_block(kind: Kind, seed: u64, i: usize, plan: &Plan) -> Result<(usize, usize), String> {
    let mut rng = Rng(seed ^ (kind as u64) << 56 ^ (i as u64).wrapping_mul(0x2545_f491_4f6c_dd1d));
    let mut layout;
    let mut dist;
    let (data, desc) = match plan {
        Plan::Sweep(bps, w, d) => {
            layout = format!("{bps:?} {w}×3 (sweep)");
            dist = distances(bps, *w, 3);
            let n = d + rng.log_uniform(3, 2048);
            runs(&mut rng, n, &dist, Some(*d))
        }
        &Plan::Edge(n) | &Plan::Size(n) => {
            let (bps, w, lines, name) = draw_layout(&mut rng);
            layout = format!("{name} {bps:?} {w}×{lines}");
            dist = distances(&bps, w, lines);
            if rng.one_in(if kind == Kind::Runs { 8 } else { 32 }) {
                layout = "any distances".into();
                dist = any_distances(&mut rng);
            }
            match kind {
                Kind::Random => random(&mut rng, n),
                Kind::Constant => constant(&mut rng, n),
                Kind::Ramp => ramp(&mut rng, n),
                Kind::Runs => runs(&mut rng, n, &dist, None),
                Kind::Incompressible => incompressible(&mut rng, n),
                Kind::Mixed => mixed(&mut rng, n, &dist),
                Kind::Samples => {
                    let (data, (bps, w, lines), desc) = samples(&mut rng, n.max(1));
                    layout = format!("{bps:?} {w}×{lines}");
                    dist = distances(&bps, w, lines);
                    (data, desc)
                }
            }
        }
    };
    let every_isa = i % 32 == 0 || matches!(plan, Plan::Edge(n) if *n <= 1 << 17);
    let result = catch_unwind(AssertUnwindSafe(|| round_trip(&data, &dist, every_isa)))
        .unwrap_or_else(|panic| {
            let msg = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            Err(format!("panicked: {msg}"))
        });
    result.map(|z| (data.len(), z)).map_err(|e| {
        format!(
            "seed {seed:#x}, {kind:?} block {i}: {} bytes, layout {layout}, distances {dist:?}, \
             {desc}: {e}\n(that block alone: PENUMBRA_DEFLATE_SEED={seed:#x} \
             PENUMBRA_DEFLATE_BLOCK={i} cargo test -p penumbra --lib exrcodec::layout::roundtrip)",
            data.len()
        )
    })
}

fn env_number(name: &str) -> Option<u64> {
    let s = std::env::var(name).ok()?;
    let s = s.trim();
    let v = match s.strip_prefix("0x") {
        Some(hex) => u64::from_str_radix(hex, 16),
        None => s.parse(),
    };
    Some(v.unwrap_or_else(|_| panic!("{name}={s} is not a number")))
}

/// Check every block of a kind (in parallel), failing on the first one (by index) that does
/// not come back.
fn run(kind: Kind) {
    let seed = env_number("PENUMBRA_DEFLATE_SEED").unwrap_or(SEED);
    let only = env_number("PENUMBRA_DEFLATE_BLOCK").map(|i| i as usize);
    let plan = plan(kind, seed);
    assert!(plan.len() >= SMALL, "{} blocks", plan.len());
    let start = std::time::Instant::now();
    let results: Vec<Result<(usize, usize), String>> = (0..plan.len())
        .into_par_iter()
        .filter(|&i| only.is_none_or(|o| o == i))
        .map(|i| check_block(kind, seed, i, &plan[i]))
        .collect();
    let (mut raw, mut packed, mut blocks) = (0usize, 0usize, 0usize);
    for r in &results {
        match r {
            Ok((n, z)) => {
                raw += n;
                packed += z;
                blocks += 1;
            }
            Err(e) => panic!("{e}"),
        }
    }
    eprintln!(
        "{kind:?}: {blocks} blocks, {:.1} MB to {:.1} MB, {:.1} s (seed {seed:#x})",
        raw as f64 / 1e6,
        packed as f64 / 1e6,
        start.elapsed().as_secs_f64()
    );
}

#[test]
fn random_bytes_round_trip() {
    run(Kind::Random);
}

#[test]
fn constant_bytes_round_trip() {
    run(Kind::Constant);
}

#[test]
fn ramps_round_trip() {
    run(Kind::Ramp);
}

#[test]
fn runs_at_every_candidate_distance_round_trip() {
    run(Kind::Runs);
}

#[test]
fn incompressible_bytes_round_trip() {
    run(Kind::Incompressible);
}

#[test]
fn predicted_samples_round_trip() {
    run(Kind::Samples);
}

#[test]
fn mixed_blocks_round_trip() {
    run(Kind::Mixed);
}
