//! Fuzz target `deflate`: the ZIP blocks' deflate encoder (src/exrcodec/layout.rs) must give
//! back any block, in any block layout, to the inflaters the codec's files meet
//! (`penumbra::exrcodec::fuzz_deflate_round_trip` panics otherwise). See ../README.md.
//!
//! The input is 4 bytes of layout, then the block:
//! - byte 0: bits 0–3 choose the channel list (bytes per sample of each channel), bit 7 says
//!   how the rest makes the block: 0, the bytes themselves; 1, a program that copies runs from
//!   the layout's candidate distances, so that short inputs make long, repetitive blocks;
//! - bytes 1–2: the width less one (little-endian, 1–65536 samples);
//! - byte 3: the lines less one, modulo 64 (1–64).
#![no_main]

use libfuzzer_sys::fuzz_target;

/// Channel lists: those the codec writes (mip tiles, horizon, lit-fraction and height maps),
/// none (the encoder's default distances), and others.
const CHANNELS: [&[usize]; 16] = [
    &[4, 4],
    &[2, 2],
    &[4],
    &[2],
    &[4, 2],
    &[],
    &[2, 2, 2],
    &[4, 4, 4],
    &[2, 4],
    &[1],
    &[4, 4, 2],
    &[2, 2, 2, 2],
    &[6],
    &[8, 8],
    &[4, 4, 4, 4, 4, 4, 4, 4],
    &[1, 3],
];

/// Blocks a program makes stop growing here: past the encoder's deflate blocks of 1 MiB.
const MAX_LEN: usize = (1 << 20) + 70_000;

fuzz_target!(|input: &[u8]| {
    let Some((head, rest)) = input.split_first_chunk::<4>() else {
        return;
    };
    let bps = CHANNELS[usize::from(head[0] & 15)];
    let width = usize::from(u16::from_le_bytes([head[1], head[2]])) + 1;
    let lines = usize::from(head[3] % 64) + 1;
    if head[0] & 0x80 == 0 {
        penumbra::exrcodec::fuzz_deflate_round_trip(rest, bps, width, lines);
    } else {
        let block = run(rest, &candidates(bps, width));
        penumbra::exrcodec::fuzz_deflate_round_trip(&block, bps, width, lines);
    }
});

/// Distances where the layout puts repeats, as the encoder derives them (a copy that only
/// steers the blocks programs make: the encoder computes its own).
fn candidates(bps: &[usize], width: usize) -> Vec<usize> {
    let w = width as i64;
    let line: i64 = bps.iter().map(|&b| b as i64 * w / 2).sum();
    let q = bps.first().map_or(1, |&b| (b as i64 / 2).max(1));
    let s = q * w;
    let mut d = vec![1, 2, 3, 4, s, line];
    d.extend([line + s - 2 * q, line + s + 2 * q]);
    d.extend([2 * line + s - 2 * q, 2 * line + s + 2 * q]);
    d.retain(|&x| (1..=32768).contains(&x));
    d.into_iter().map(|x| x as usize).collect()
}

/// The block a program makes. Each op byte `o`:
/// - below 0x40: the next `o + 1` bytes as they are;
/// - 0x40–0xbf: a run of `(next + 1) · ((o >> 3 & 15) + 1)` bytes repeating those at
///   candidate distance `o & 7` back, each byte flipped with a chance given by the byte after
///   (0: never);
/// - 0xc0 and up: the next byte `64 · (o & 63 + 1)` times.
fn run(mut prog: &[u8], cand: &[usize]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    while let Some((&o, rest)) = prog.split_first() {
        prog = rest;
        if out.len() >= MAX_LEN {
            break;
        }
        match o {
            0..=0x3f => {
                let n = (usize::from(o) + 1).min(prog.len());
                out.extend_from_slice(&prog[..n]);
                prog = &prog[n..];
            }
            0x40..=0xbf => {
                let [len, flip, ..] = *prog else { break };
                prog = &prog[2..];
                let d = cand[usize::from(o & 7) % cand.len()];
                let n = (usize::from(len) + 1) * (usize::from(o >> 3 & 15) + 1);
                for _ in 0..n {
                    let i = out.len();
                    let mut b = if i >= d { out[i - d] } else { 0x80 };
                    if flip != 0 {
                        state ^= state << 13;
                        state ^= state >> 7;
                        state ^= state << 17;
                        if (state as u8) < flip / 16 {
                            b ^= (state >> 8) as u8 | 1;
                        }
                    }
                    out.push(b);
                }
            }
            _ => {
                let Some((&b, rest)) = prog.split_first() else {
                    break;
                };
                prog = rest;
                out.resize(out.len() + 64 * (usize::from(o & 63) + 1), b);
            }
        }
    }
    out.truncate(MAX_LEN);
    out
}
