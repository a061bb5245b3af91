//! The round-trip check of the deflate encoder in [`super`], shared by its randomised test
//! (layout_roundtrip.rs) and the fuzz target (tools/fuzz, through
//! [`crate::exrcodec::fuzz_deflate_round_trip`]). The encoder compresses user data (any
//! DEM's samples), so it must give every input back, whatever its bytes, to every inflater
//! that reads the files: here miniz_oxide (flate2's, the commonest in Rust), zune-inflate
//! (which the `exr` crate and this codec's reader use) and libdeflate (which OpenEXR's own
//! library inflates ZIP blocks with since 3.2).

use super::{zlib, zlib_unless_weak, zlib_with, Portable, MAX_BLOCK, PROBE_MIN};

/// Compress `data` with the match distances `dist` and check the stream; the stream's length,
/// or what is wrong with it. The stream must inflate to `data` with miniz_oxide (which must
/// consume it to its last byte: no garbage after the checksum), with zune-inflate and with
/// libdeflate (both checking the Adler-32), be no longer than storing `data` would be (the
/// encoder chooses the shortest of its three block types), and [`zlib_unless_weak`] must give
/// the same bytes or, for a block it may probe, none (below [`PROBE_MIN`] bytes, where it does
/// not probe, only with `every_isa`). With `every_isa`, each instruction set this CPU has must
/// also write the same bytes as the one [`zlib`] picked, with and without the probe.
pub(in crate::exrcodec) fn round_trip(
    data: &[u8],
    dist: &[usize],
    every_isa: bool,
) -> Result<usize, String> {
    let n = data.len();
    let z = zlib(data, dist);
    // Each deflate block (of MAX_BLOCK bytes at most) is no longer than stored, in 65535-byte
    // chunks of a 3-bit header, up to 7 bits of padding, LEN and NLEN (`write_block`); plus
    // the zlib header, the padding after the last block and the Adler-32.
    let chunks: usize = (0..n.div_ceil(MAX_BLOCK).max(1))
        .map(|b| (n - b * MAX_BLOCK).min(MAX_BLOCK).div_ceil(65535).max(1))
        .sum();
    let bound = 2 + (chunks * (3 + 7 + 32) + 8 * n).div_ceil(8) + 4;
    if z.len() > bound {
        return Err(format!(
            "the stream is {} bytes, more than the {bound} of storing {n}",
            z.len()
        ));
    }
    inflate_miniz(&z, data)?;
    inflate_zune(&z, data)?;
    inflate_libdeflate(&z, data)?;
    // Below PROBE_MIN the probe does not run and zlib_unless_weak is zlib: tried with
    // `every_isa` only.
    if n < PROBE_MIN && !every_isa {
        return Ok(z.len());
    }
    let p = zlib_unless_weak(data, dist);
    match &p {
        Some(p) if *p != z => {
            return Err(format!(
                "zlib_unless_weak wrote {} bytes that differ from zlib's {} (first at {})",
                p.len(),
                z.len(),
                first_difference(p, &z)
            ))
        }
        None if !(PROBE_MIN..=MAX_BLOCK).contains(&n) => {
            return Err(format!("zlib_unless_weak gave up on a block of {n} bytes"));
        }
        _ => {}
    }
    if every_isa {
        for (probe, want) in [(false, Some(z.clone())), (true, p)] {
            let mut got = vec![("portable", zlib_with::<Portable>(data, dist, probe))];
            #[cfg(target_arch = "x86_64")]
            {
                use super::x86;
                use std::arch::is_x86_feature_detected as has;
                got.push(("SSE2", zlib_with::<x86::Sse2>(data, dist, probe)));
                if has!("avx2") && has!("bmi2") {
                    got.push(("AVX2", zlib_with::<x86::Avx2>(data, dist, probe)));
                }
                if has!("avx512bw") && has!("bmi2") {
                    got.push(("AVX-512", zlib_with::<x86::Avx512>(data, dist, probe)));
                }
            }
            for (isa, g) in got {
                if g != want {
                    return Err(format!(
                        "the {isa} encoder (probe {probe}) wrote other bytes than the \
                         dispatched one: {:?} against {:?} bytes",
                        g.map(|v| v.len()),
                        want.as_ref().map(Vec::len)
                    ));
                }
            }
        }
    }
    Ok(z.len())
}

/// Inflate with miniz_oxide into a buffer of exactly `want.len()` bytes: the stream must end
/// (checksum verified) having filled it and consumed every byte of `z`.
fn inflate_miniz(z: &[u8], want: &[u8]) -> Result<(), String> {
    use miniz_oxide::inflate::core::{decompress, inflate_flags, DecompressorOxide};
    use miniz_oxide::inflate::TINFLStatus;
    let mut out = vec![0u8; want.len()];
    let mut r = DecompressorOxide::new();
    let flags = inflate_flags::TINFL_FLAG_PARSE_ZLIB_HEADER
        | inflate_flags::TINFL_FLAG_COMPUTE_ADLER32
        | inflate_flags::TINFL_FLAG_USING_NON_WRAPPING_OUTPUT_BUF;
    let (status, read, written) = decompress(&mut r, z, &mut out, 0, flags);
    if status != TINFLStatus::Done {
        return Err(format!(
            "miniz_oxide: {status:?} after {read} of {} stream bytes, {written} of {} bytes out \
             (first difference at {})",
            z.len(),
            want.len(),
            first_difference(&out[..written], &want[..written.min(want.len())])
        ));
    }
    if read != z.len() || written != want.len() || out != want {
        return Err(format!(
            "miniz_oxide read {read} of {} stream bytes and inflated {written} of {} bytes, \
             first difference at {}",
            z.len(),
            want.len(),
            first_difference(&out[..written], want)
        ));
    }
    Ok(())
}

/// Inflate with zune-inflate, confirming the Adler-32, and compare.
fn inflate_zune(z: &[u8], want: &[u8]) -> Result<(), String> {
    let options = zune_inflate::DeflateOptions::default()
        .set_confirm_checksum(true)
        .set_limit(want.len())
        .set_size_hint(want.len());
    let got = zune_inflate::DeflateDecoder::new_with_options(z, options)
        .decode_zlib()
        .map_err(|e| format!("zune-inflate: {:?}", e.error))?;
    if got != want {
        return Err(format!(
            "zune-inflate gave {} bytes for {}, first difference at {}",
            got.len(),
            want.len(),
            first_difference(&got, want)
        ));
    }
    Ok(())
}

/// Inflate with libdeflate into a buffer of exactly `want.len()` bytes (a stream that makes
/// more does not fit), checking the Adler-32, and compare.
fn inflate_libdeflate(z: &[u8], want: &[u8]) -> Result<(), String> {
    let mut out = vec![0u8; want.len()];
    let n = libdeflater::Decompressor::new()
        .zlib_decompress(z, &mut out)
        .map_err(|e| format!("libdeflate: {e:?}"))?;
    if out[..n] != *want {
        return Err(format!(
            "libdeflate gave {n} bytes for {}, first difference at {}",
            want.len(),
            first_difference(&out[..n], want)
        ));
    }
    Ok(())
}

/// The first index where `a` and `b` differ (the shorter length when one is a prefix).
fn first_difference(a: &[u8], b: &[u8]) -> usize {
    a.iter()
        .zip(b)
        .position(|(x, y)| x != y)
        .unwrap_or(a.len().min(b.len()))
}
