//! The product files through the EXR codec: every product's file holds the samples written,
//! bit for bit, and at deflate level 4 the `exr` crate's own bytes (which proves the transform
//! is OpenEXR's); damaged files are errors, not panics.

use crate::exrcodec::*;
use crate::format::height::{
    decode_height_tile, encode_height_tile, encode_height_tile_exr_crate, HeightTile,
};
use crate::format::horizon::{
    decode_horizon_exr, encode_horizon_exr, encode_horizon_exr_exr_crate, HorizonPrecision,
};
use crate::format::mip::{
    decode_mip_exr, encode_mip_exr, encode_mip_exr_exr_crate, level_sizes, Precision,
};

/// Terrain-like values with NaNs, negative zeros, infinities and extreme magnitudes.
fn values(n: usize, seed: u32) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let x = i as f32;
            match (i as u32 ^ seed) % 97 {
                0 => f32::NAN,
                1 => -0.0,
                2 => f32::INFINITY,
                3 => f32::MIN_POSITIVE / 3.0,
                4 => 65504.0 * 3.0,
                _ => (x * 0.013 + seed as f32).sin() * 1500.0 + (x * 0.0007).cos() * 30.0,
            }
        })
        .collect()
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn height_tiles_store_the_exr_crates_samples_and_its_bytes_at_level_4() {
    for n in [1usize, 15, 16, 17, 37, 260] {
        let tile = HeightTile {
            size: n,
            height: values(n * n, n as u32),
            mask: (0..n * n).map(|i| (i % 3) as u8).collect(),
        };
        for c in [TileCompression::Zip, TileCompression::None] {
            let old = encode_height_tile_exr_crate(&tile, c).unwrap();
            // Same transform, same deflate level: the very same file.
            assert_eq!(
                encode_height_tile(&tile, c, ZipLevel::EXR_CRATE).unwrap(),
                old
            );
            let new = encode_height_tile(&tile, c, ZipLevel::DEFAULT).unwrap();
            let (a, b) = (
                decode_height_tile(&old).unwrap(),
                decode_height_tile(&new).unwrap(),
            );
            assert_eq!(bits(&a.height), bits(&tile.height), "n = {n}");
            assert_eq!(bits(&b.height), bits(&tile.height), "n = {n}");
            assert_eq!((&a.mask, &b.mask), (&tile.mask, &tile.mask));
        }
    }
}

#[test]
fn mip_files_store_the_exr_crates_samples_and_its_bytes_at_level_4() {
    for size in [1usize, 63, 64, 65, 130, 260] {
        let sizes = level_sizes(size);
        let max: Vec<Vec<f32>> = sizes.iter().map(|&s| values(s * s, s as u32)).collect();
        let min: Vec<Vec<f32>> = sizes.iter().map(|&s| values(s * s, 7 + s as u32)).collect();
        for precision in [Precision::F32, Precision::F16] {
            for c in [TileCompression::Zip, TileCompression::None] {
                for m in [None, Some(min.as_slice())] {
                    let old = encode_mip_exr_exr_crate(size, m, &max, precision, c, "t").unwrap();
                    let same =
                        encode_mip_exr(size, m, &max, precision, c, ZipLevel::EXR_CRATE, "t");
                    assert_eq!(same.unwrap(), old, "{size} {precision:?} {c:?}");
                    let new = encode_mip_exr(size, m, &max, precision, c, ZipLevel::DEFAULT, "t")
                        .unwrap();
                    let (a, b) = (decode_mip_exr(&old).unwrap(), decode_mip_exr(&new).unwrap());
                    assert_eq!(a.sizes, sizes);
                    assert_eq!(b.sizes, sizes);
                    for name in ["max", "min"] {
                        let (x, y) = (a.channels.get(name), b.channels.get(name));
                        assert_eq!(x.is_some(), name == "max" || m.is_some());
                        let (Some(x), Some(y)) = (x, y) else { continue };
                        for (lx, ly) in x.iter().zip(y) {
                            assert_eq!(bits(lx), bits(ly));
                        }
                        if precision == Precision::F32 {
                            let want = if name == "max" { &max } else { &min };
                            for (lx, lw) in x.iter().zip(want) {
                                assert_eq!(bits(lx), bits(lw));
                            }
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn horizon_files_store_the_exr_crates_samples_and_its_bytes_at_level_4() {
    for (n, a) in [(16usize, 1usize), (33, 3), (64, 8)] {
        let e: Vec<f32> = values(n * n * a, a as u32)
            .iter()
            .map(|v| v.clamp(-90.0, 90.0))
            .collect();
        for p in [HorizonPrecision::F16, HorizonPrecision::F32] {
            for c in [TileCompression::Zip, TileCompression::None] {
                let old = encode_horizon_exr_exr_crate(n, a, &e, p, c).unwrap();
                let same = encode_horizon_exr(n, a, &e, p, c, ZipLevel::EXR_CRATE).unwrap();
                assert_eq!(same, old);
                let new = encode_horizon_exr(n, a, &e, p, c, ZipLevel::DEFAULT).unwrap();
                let (x, y) = (
                    decode_horizon_exr(&old, n).unwrap(),
                    decode_horizon_exr(&new, n).unwrap(),
                );
                assert_eq!(x.0, a);
                assert_eq!(y.0, a);
                assert_eq!(bits(&x.1), bits(&y.1));
            }
        }
    }
}

/// Heights that are noise to deflate (random mantissas, as LDEM_4's oversampled tiles)
/// are stored and the mask run-length coded: the samples come back bit for bit, the file
/// is about the heights' raw size (the mask all but vanishes), and heights deflate can
/// shrink get exactly the plain level-1 file.
#[test]
fn height_tiles_store_noisy_heights_and_keep_the_samples() {
    let mut rnd = crate::testutil::rng(11);
    for n in [16usize, 100, 260, 516] {
        let tile = HeightTile {
            size: n,
            height: (0..n * n)
                .map(|i| 1000.0 + (i % n) as f32 * 0.37 + rnd() as f32)
                .collect(),
            mask: (0..n * n).map(|i| u8::from(i % n > n / 2)).collect(),
        };
        let z = encode_height_tile(&tile, TileCompression::Zip, ZipLevel::StoreNoise(1)).unwrap();
        let back = decode_height_tile(&z).unwrap();
        assert_eq!(bits(&back.height), bits(&tile.height), "n = {n}");
        assert_eq!(back.mask, tile.mask);
        let raw_heights = 4 * n * n;
        if n >= 100 {
            assert!(
                z.len() < raw_heights + raw_heights / 20,
                "n = {n}: {} bytes for {raw_heights} of heights",
                z.len()
            );
        }
        // Whole metres, as SRTM's: the low mantissa bytes are zeros, deflate wins.
        let whole = HeightTile {
            height: values(n * n, 5).iter().map(|v| v.round()).collect(),
            ..tile
        };
        let plain = encode_height_tile(&whole, TileCompression::Zip, ZipLevel::Miniz(1));
        assert!(
            encode_height_tile(&whole, TileCompression::Zip, ZipLevel::StoreNoise(1)) == plain,
            "n = {n}: compressible heights were not deflated as before"
        );
    }
}

/// f32 mip blocks whose predicted bytes are noise to deflate (random low mantissa bits, as
/// LDEM_4's) are stored as they are, although deflate would shave a few percent off them:
/// the samples come back bit for bit, and the file is the size of the uncompressed one.
/// Blocks with repeats (whole metres, a plateau) are still deflated.
#[test]
fn mip_files_store_noisy_f32_blocks_and_keep_the_samples() {
    let mut rnd = crate::testutil::rng(13);
    let size = 260;
    let sizes = level_sizes(size);
    let mut noise =
        |s: usize| -> Vec<f32> { (0..s * s).map(|_| 1000.0 + 0.5 * rnd() as f32).collect() };
    let max: Vec<Vec<f32>> = sizes.iter().map(|&s| noise(s)).collect();
    let min: Vec<Vec<f32>> = sizes.iter().map(|&s| noise(s)).collect();
    let file = |min: &[Vec<f32>], max: &[Vec<f32>], c| {
        encode_mip_exr(
            size,
            Some(min),
            max,
            Precision::F32,
            c,
            ZipLevel::DEFAULT,
            "t",
        )
        .unwrap()
    };
    let z = file(&min, &max, TileCompression::Zip);
    let raw = file(&min, &max, TileCompression::None);
    let back = decode_mip_exr(&z).unwrap();
    for (name, want) in [("max", &max), ("min", &min)] {
        for (l, w) in back.channels[name].iter().zip(want.iter()) {
            assert_eq!(bits(l), bits(w), "{name}");
        }
    }
    // The 64² tiles are stored; only the coarse levels' small blocks (under PROBE_MIN)
    // are deflated, by a little.
    assert!(
        z.len() + raw.len() / 100 > raw.len(),
        "{} bytes against {} uncompressed: noise was deflated",
        z.len(),
        raw.len()
    );
    // Deflate does shrink such blocks a little: the probe, not the size check, stored them.
    let packed: Vec<u8> = max[0][..64 * 64]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let mut predicted = Vec::new();
    crate::exrcodec::predict::predict(&packed, &mut predicted);
    let deflated = layout_zlib(&predicted, &[4], 64, 64).len();
    assert!(
        deflated < packed.len(),
        "{deflated} of {} bytes",
        packed.len()
    );
    let whole: Vec<Vec<f32>> = max
        .iter()
        .map(|l| l.iter().map(|v| v.round()).collect())
        .collect();
    let z = file(&whole, &whole, TileCompression::Zip);
    assert!(
        z.len() < raw.len() / 4,
        "{} of {} bytes",
        z.len(),
        raw.len()
    );
}

#[test]
fn output_does_not_depend_on_the_thread_count() {
    let tile = HeightTile {
        size: 260,
        height: values(260 * 260, 3),
        mask: vec![1; 260 * 260],
    };
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let four = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    for level in [
        ZipLevel::DEFAULT,
        ZipLevel::StoreNoise(1),
        ZipLevel::Miniz(1),
    ] {
        let enc = || encode_height_tile(&tile, TileCompression::Zip, level).unwrap();
        assert_eq!(one.install(enc), four.install(enc));
    }
}

#[test]
fn damaged_blocks_are_errors_not_panics() {
    let tile = HeightTile {
        size: 64,
        height: values(64 * 64, 1),
        mask: vec![0; 64 * 64],
    };
    let good = encode_height_tile(&tile, TileCompression::Zip, ZipLevel::DEFAULT).unwrap();
    // Flip bytes across the whole file, one at a time at a stride, and truncate: every
    // variant either decodes or is an error (never a panic).
    for i in (0..good.len()).step_by(7) {
        let mut bad = good.clone();
        bad[i] ^= 0x5a;
        let _ = decode_height_tile(&bad);
    }
    for len in (0..good.len()).step_by(13) {
        assert!(
            decode_height_tile(&good[..len]).is_err(),
            "truncated to {len}"
        );
    }
}

mod header_limits {
    use crate::exrcodec::*;
    use crate::format::height::{decode_height_tile, encode_height_tile, HeightTile};

    /// A header that claims a huge image is refused before anything that size is allocated:
    /// the blocks actually present must cover the claimed image first.
    #[test]
    fn a_header_claiming_a_huge_image_is_refused_cheaply() {
        let tile = HeightTile {
            size: 32,
            height: vec![1.0; 32 * 32],
            mask: vec![0; 32 * 32],
        };
        let good = encode_height_tile(&tile, TileCompression::Zip, ZipLevel::DEFAULT).unwrap();
        let key = b"dataWindow\0box2i\0";
        let at = good.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        let mut bad = good.clone();
        // xMax, yMax of the data window: 60000 × 60000 pixels (≈ 29 GB as f32 + f32).
        bad[at + 8..at + 12].copy_from_slice(&59_999i32.to_le_bytes());
        bad[at + 12..at + 16].copy_from_slice(&59_999i32.to_le_bytes());
        assert!(decode_height_tile(&bad).is_err());
    }
}

/// A mip file written with the codec's own encoder decodes, with this codec and with the `exr`
/// crate, to the samples written, bit for bit.
mod mip_layout {
    /// A mip file written with this encoder decodes, with this codec and with the `exr`
    /// crate, to the samples written, bit for bit.
    #[test]
    fn mip_files_decode_to_their_samples() {
        use crate::format::mip::{decode_mip_exr, encode_mip_exr, Precision};
        use crate::format::TileCompression;
        use crate::mip::minmax_pyramid;
        use exr::prelude::*;
        for n in [1usize, 64, 130] {
            let s = n + 4;
            let height: Vec<f32> = (0..s * s)
                .map(|i| ((i % s) as f32 * 0.37).sin() * 500.0 + (i / s) as f32 * 0.01)
                .collect();
            let p = minmax_pyramid(&height, s, 2).unwrap();
            let bytes = encode_mip_exr(
                n,
                Some(&p.min),
                &p.max,
                Precision::F32,
                TileCompression::Zip,
                crate::exrcodec::ZipLevel::Layout,
                "t",
            )
            .unwrap();
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let ours = decode_mip_exr(&bytes).unwrap();
            assert_eq!(ours.sizes, p.sizes);
            for (name, want) in [("max", &p.max), ("min", &p.min)] {
                for (got, want) in ours.channels[name].iter().zip(want) {
                    assert_eq!(bits(got), bits(want), "{n} {name}");
                }
            }
            let image = read()
                .no_deep_data()
                .all_resolution_levels()
                .all_channels()
                .first_valid_layer()
                .all_attributes()
                .from_buffered(std::io::Cursor::new(&bytes))
                .unwrap();
            for ch in &image.layer_data.channel_data.list {
                let want = if ch.name.to_string() == "max" {
                    &p.max
                } else {
                    &p.min
                };
                let Levels::Mip { level_data, .. } = &ch.sample_data else {
                    panic!("not mip-mapped");
                };
                assert_eq!(level_data.len(), want.len());
                for (got, want) in level_data.iter().zip(want) {
                    let got: Vec<u32> = got.values_as_f32().map(f32::to_bits).collect();
                    assert_eq!(got, bits(want), "{n} {} (exr crate)", ch.name);
                }
            }
        }
    }
}

/// A mip, horizon or height file's header is compared with the manifest's labels: the sample
/// type, the channel names; the error names the label and what the file holds.
#[test]
fn exr_headers_are_checked_against_the_labels() {
    use crate::format::{check_channels, exr_channels, ChannelLabel, Identity};
    let n = 16;
    let sizes = level_sizes(n);
    let levels: Vec<Vec<f32>> = sizes.iter().map(|&s| values(s * s, 5)).collect();
    let id = Identity::tile(
        crate::format::mip::MAX_ID,
        crate::layout::TileId {
            level: 1,
            face: crate::cube::Face::Px,
            x: 0,
            y: 1,
        },
        &"a".repeat(64),
    );
    let bytes = crate::format::mip::encode_mip_exr_identified(
        n,
        None,
        &levels,
        Precision::F16,
        TileCompression::Zip,
        ZipLevel::DEFAULT,
        "t",
        Some(&id),
    )
    .unwrap();
    let h = read_header(&bytes).unwrap();
    let found = exr_channels(h.channels.iter().map(|(n, t)| (n, *t)));
    assert_eq!(found, vec![("max".to_string(), "f16")]);
    let label = |sample: &str| {
        vec![ChannelLabel::of(
            "max",
            sample,
            "products.mip.max_channels",
            "products.mip.precision",
        )]
    };
    check_channels(&found, &label("f16")).unwrap();
    let e = check_channels(&found, &label("f32")).unwrap_err();
    assert!(
        e.contains("holds channel `max` as f16 samples")
            && e.contains("`products.mip.precision` says f32"),
        "{e}"
    );
    // Decoding through the store's path says the same.
    let e = crate::format::mip::decode_mip_exr_as(&bytes, &id, &label("f32")).unwrap_err();
    assert!(e.contains("products.mip.precision"), "{e}");
    crate::format::mip::decode_mip_exr_as(&bytes, &id, &label("f16")).unwrap();
    // A channel the label does not list, one it lists that the file lacks.
    let two = vec![
        ChannelLabel::of(
            "min",
            "f16",
            "products.mip.minmax_channels",
            "products.mip.precision",
        ),
        ChannelLabel::of(
            "max",
            "f16",
            "products.mip.minmax_channels",
            "products.mip.precision",
        ),
    ];
    let e = check_channels(&found, &two).unwrap_err();
    assert!(
        e.contains("holds no channel `min`") && e.contains("minmax_channels"),
        "{e}"
    );
    let e =
        check_channels(&[("max".into(), "f16"), ("x".into(), "f32")], &label("f16")).unwrap_err();
    assert!(e.contains("holds channel `x` (f32)"), "{e}");
}

/// Albedo tiles carry their identity in a `tEXt` chunk right after the image header: the rest
/// of the file is the bytes written without it, the image decodes to the same pixels, and the
/// header is checked against the identity and the manifest's labels.
#[test]
fn albedo_tiles_carry_their_identity_in_a_text_chunk() {
    use crate::format::albedo::{
        check_labels, decode_albedo_tile_as, encode_albedo_tile, read_header, AlbedoProduct,
        AlbedoTile, ID,
    };
    use crate::format::{Identity, SourceFile};
    let size = 13;
    for (channels, sixteen_bit) in [(1, false), (3, false), (4, true), (2, true)] {
        let tile = AlbedoTile {
            size,
            channels,
            sixteen_bit,
            data: (0..size * size * channels)
                .map(|i| (i * 7919 % if sixteen_bit { 65536 } else { 256 }) as u16)
                .collect(),
        };
        let id = Identity::tile(
            ID,
            crate::layout::TileId {
                level: 2,
                face: crate::cube::Face::Nz,
                x: 3,
                y: 1,
            },
            &"0123456789abcdef".repeat(4),
        );
        let plain = encode_albedo_tile(&tile, None).unwrap();
        let with = encode_albedo_tile(&tile, Some(&id)).unwrap();
        // Only the chunk was added, after IHDR (8 + 25 bytes).
        let extra = with.len() - plain.len();
        assert_eq!(&with[..33], &plain[..33]);
        assert_eq!(&with[33 + extra..], &plain[33..]);
        assert_eq!(&with[37..41], b"tEXt");
        let facts = read_header(&with).unwrap();
        assert_eq!(facts.identity.as_deref(), Some(id.text().as_str()));
        let bit_depth = if sixteen_bit { 16 } else { 8 };
        assert_eq!(
            (facts.bit_depth, facts.channels as usize),
            (bit_depth, channels)
        );
        assert_eq!(read_header(&plain).unwrap().identity, None);
        let product = AlbedoProduct {
            path: crate::format::albedo::ALBEDO_PATTERN.into(),
            source: SourceFile {
                path: "a.png".into(),
                bytes: 1,
                blake3: "0".repeat(64),
            },
            bit_depth,
            channels: channels as u8,
            west_lon_deg: -180.0,
        };
        // The image crate (which checks every CRC) reads the same pixels back.
        let back = decode_albedo_tile_as(&with, &id, &product, size).unwrap();
        assert_eq!(back, tile);
        // Another tile's identity, no identity, another label, another size: refused.
        let other = Identity { x: 4, ..id.clone() };
        let e = decode_albedo_tile_as(&with, &other, &product, size).unwrap_err();
        assert!(e.contains("claims to be albedo 2/nz/y1/x3"), "{e}");
        let e = decode_albedo_tile_as(&plain, &id, &product, size).unwrap_err();
        assert!(e.contains("carries no identity"), "{e}");
        let flipped = AlbedoProduct {
            bit_depth: 24 - bit_depth,
            ..product.clone()
        };
        let e = check_labels(&facts, &flipped).unwrap_err();
        assert!(
            e.contains(&format!("holds {bit_depth}-bit samples"))
                && e.contains("`products.albedo.bit_depth` says"),
            "{e}"
        );
        let e = decode_albedo_tile_as(&with, &id, &product, size + 2).unwrap_err();
        assert!(e.contains("albedo tile is 13×13"), "{e}");
        // A damaged chunk is refused by its CRC.
        let mut bad = with.clone();
        bad[50] ^= 1;
        assert!(read_header(&bad).unwrap_err().contains("CRC"));
    }
}

/// A Fourier pyramid's labels read from its header alone are those it was written with.
#[test]
fn fourier_headers_are_checked_against_the_labels() {
    use crate::format::fourier::{read_labels, Encoding, Layout, Pyramid, Sigma};
    let p = Pyramid::fully_lit(8, 16, Layout::Multires, Encoding::F16, Sigma::None, 1.0);
    let bytes = p.encode();
    let l = read_labels(&bytes).unwrap();
    assert_eq!(l, p.labels());
    assert!(l.fully_lit && l.k == 0);
    assert!(read_labels(&bytes[..40]).is_err());
}
