//! The one EXR codec behind every tile Penumbra writes and reads (height tiles, mip files,
//! horizon maps, lit-fraction maps).
//!
//! The `exr` crate still writes and parses the header and the offset table (so the files stay
//! plain single-part OpenEXR that any reader opens), but the pixel blocks are packed and
//! compressed here: OpenEXR's ZIP is "interleave the bytes, delta-predict, zlib", and `exr`'s
//! writer runs that through miniz_oxide at level 4, one block after another, which was 87% of the
//! mip stage. Here the same transform is deflated by this codec's own encoder, which looks for
//! repeats only at the distances where a block's layout puts them ([`layout`]), and all blocks
//! of a file are compressed in parallel; f32 blocks it probes as noise are stored raw. It was
//! measured fastest on every product at 1.003–1.057× the `exr` crate's size (see [`ZipLevel`]
//! and docs/benchmarks.md, "EXR codec" and "Weak blocks stored"). Height tiles
//! are the exception: miniz_oxide level 1 with the channels that are noise to deflate stored
//! ([`mixed`]), which decodes faster. libdeflate stays selectable for the codec bench that
//! compares them. miniz_oxide at level 4 also reproduces the `exr` crate's files
//! byte for byte, which the tests use to prove the transform is OpenEXR's. Reading inflates the
//! blocks in parallel with zune-inflate (the inflater `exr` itself uses), undoes the predictor
//! and the interleave, and converts to f32. Blocks in any other compression (RLE, PIZ, …
//! written by other tools) are decoded by `exr`'s own block decompressor, so every file the old
//! `exr`-based reader opened still opens.
//!
//! The stored samples are the same bits whatever the library or level: only the deflate stream
//! differs (and, for a given level, it is fixed by the library versions in Cargo.lock and, for
//! the codec's own encoder, by its code: the same bytes whatever vector instructions the CPU
//! has).
//! Output bytes do not depend on the thread count (blocks are compressed independently and
//! written in offset-table order).

use std::borrow::Cow;
use std::io::Cursor;

use exr::block::chunk::{Chunk, CompressedBlock, CompressedScanLineBlock, CompressedTileBlock};
use exr::block::UncompressedBlock;
use exr::compression::Compression;
use exr::math::{RoundingMode, Vec2};
use exr::meta::attribute::{
    AttributeValue, ChannelDescription, ChannelList, IntegerBounds, LevelMode, LineOrder,
    SampleType, TileDescription,
};
use exr::meta::header::{Header, ImageAttributes, LayerAttributes};
use exr::meta::{compute_level_count, compute_level_size, BlockDescription};
use exr::prelude::f16;
use rayon::prelude::*;

mod layout;
mod mixed;
pub(crate) mod predict;

use predict::{predict, unpredict};

/// Lossless compression of EXR tiles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TileCompression {
    /// ZIP over 16 scanlines (OpenEXR's predictor + deflate; 64² tiles for mip files): 1.5–3.5×
    /// smaller than raw on real DEMs. [`crate::exrcodec`](self) deflates at a low level with all
    /// blocks of a file in parallel, so it costs a few percent of a stage (PIZ was slower and
    /// no smaller).
    #[default]
    Zip,
    /// Uncompressed: fastest to write and to read.
    None,
}

impl std::str::FromStr for TileCompression {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "zip" => Ok(TileCompression::Zip),
            "none" => Ok(TileCompression::None),
            _ => Err(format!("unknown compression '{s}': use zip or none")),
        }
    }
}

/// Which deflate library, at which level, compresses the ZIP blocks. Both write plain zlib
/// streams that every OpenEXR reader inflates; only the size and the time differ. The table in
/// docs/benchmarks.md ("EXR codec") measured each on the shared DEMs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ZipLevel {
    /// libdeflate (C, through the `libdeflater` crate) at this level, 1–12: what f16 mip files
    /// were written with before [`ZipLevel::Layout`]; measured in the codec bench.
    Libdeflate(u8),
    /// miniz_oxide at this level, 0–10: the library the `exr` crate's writer uses, so the
    /// codec can reproduce that writer byte for byte ([`ZipLevel::EXR_CRATE`]).
    Miniz(u8),
    /// As `Miniz(level)`, except in blocks where a channel's predicted bytes are noise to
    /// deflate (order-0 entropy above [`mixed::NOISE_BITS`] bits per byte on a sample): there
    /// those channels are stored and the others run-length coded, in one plain zlib stream
    /// (src/exrcodec/mixed.rs). Blocks without noise get exactly `Miniz(level)`'s bytes. What
    /// height tiles are written with ([`ZipLevel::HEIGHT_TILE`]).
    StoreNoise(u8),
    /// This codec's own deflate (src/exrcodec/layout.rs): matches looked for only at the few
    /// distances where a block's layout puts repeats (the previous line of a channel, the
    /// other channel a line or two up, runs), compared 64 positions at a time, then one
    /// Huffman-coded deflate block per ZIP block. All-f32 blocks of 4 KiB or more whose first
    /// sixteenth would not deflate below 90 % are stored raw instead (the probe in
    /// src/exrcodec/layout.rs). What every file but height tiles is written with
    /// ([`ZipLevel::DEFAULT`]).
    Layout,
}

impl ZipLevel {
    /// What mip files (both precisions), horizon maps and lit-fraction maps are written with:
    /// [`ZipLevel::Layout`]. In the codec bench of 2026-12-03 09:0x UTC (one core, the shared
    /// DEMs) it was the fastest encoder on every product, 204–453 MB/s against 55–252 for
    /// miniz_oxide level 1 and 70–185 for libdeflate level 1, at 1.003–1.046× the `exr`
    /// crate's size (issue 14 allows 1.10×), smaller than miniz_oxide level 1 on all but
    /// LDEM_4's f32 heights (docs/benchmarks.md, "EXR codec"). Storing the f32 blocks that
    /// probe as noise made f32 mips 1.26–1.36× faster to write at 1.050–1.057× (same
    /// document, "Weak blocks stored").
    pub const DEFAULT: ZipLevel = ZipLevel::Layout;
    /// Height tiles (f32 height + f16 mask): miniz_oxide level 1, except where a block's heights
    /// are noise to deflate (LDEM_4 oversampled: ratio 1.00): there they are stored and the mask
    /// run-length coded. [`ZipLevel::Layout`] writes these 3–18 % faster at 0.98–0.99× the size, but
    /// its Huffman-coded noise decodes at 0.64–0.90× the speed of stored bytes (codec bench,
    /// 2026-12-03), and the horizon, mip and shadow stages read height tiles far more often than
    /// the tiling stage writes them: the whole mip stage on LDEM_4 took 5.2 s of CPU on
    /// Layout-written height tiles against 4.5–4.8 s on these.
    pub const HEIGHT_TILE: ZipLevel = ZipLevel::StoreNoise(1);
    /// What the `exr` crate's writer used, miniz_oxide at level 4 (and this codec reproduces its
    /// files byte for byte with it, which the tests check).
    pub const EXR_CRATE: ZipLevel = ZipLevel::Miniz(4);
}

/// How the pixels are cut into blocks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Blocks {
    /// Scanline blocks: 16 lines for ZIP, 1 line uncompressed (OpenEXR's ZIP and NONE).
    ScanLines,
    /// Square tiles of this side with all mip levels (rounding up), as the mip files store.
    MipTiles(usize),
}

/// How a file is encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Encoding {
    pub compression: TileCompression,
    pub level: ZipLevel,
    pub blocks: Blocks,
}

impl Encoding {
    pub fn scanlines(compression: TileCompression) -> Self {
        Encoding {
            compression,
            level: ZipLevel::DEFAULT,
            blocks: Blocks::ScanLines,
        }
    }
}

/// The samples of one channel at one level, in the type they are stored in.
#[derive(Clone, Debug)]
pub enum Samples<'a> {
    F32(Cow<'a, [f32]>),
    F16(Cow<'a, [f16]>),
}

impl Samples<'_> {
    fn len(&self) -> usize {
        match self {
            Samples::F32(v) => v.len(),
            Samples::F16(v) => v.len(),
        }
    }

    fn sample_type(&self) -> SampleType {
        match self {
            Samples::F32(_) => SampleType::F32,
            Samples::F16(_) => SampleType::F16,
        }
    }

    /// Append samples `start..start + n` as little-endian bytes.
    fn push_le(&self, start: usize, n: usize, out: &mut Vec<u8>) {
        match self {
            Samples::F32(v) => {
                for x in &v[start..start + n] {
                    out.extend_from_slice(&x.to_bits().to_le_bytes());
                }
            }
            Samples::F16(v) => {
                for x in &v[start..start + n] {
                    out.extend_from_slice(&x.to_bits().to_le_bytes());
                }
            }
        }
    }
}

/// One channel to write: its name and its levels (one level for scanline files, all mip levels,
/// largest first, for [`Blocks::MipTiles`]).
#[derive(Clone, Debug)]
pub struct Channel<'a> {
    pub name: &'a str,
    pub levels: Vec<Samples<'a>>,
}

/// The header a file of this size, channel list and encoding gets: the same attributes the
/// `exr` crate's `Image::from_layer(Layer::new(…, LayerAttributes::named(name), …))` wrote.
/// With `identity`, the layer also gets a text attribute [`IDENTITY_ATTRIBUTE`] holding it.
fn header(
    name: &str,
    identity: Option<&str>,
    size: (usize, usize),
    channels: ChannelList,
    enc: &Encoding,
) -> Header {
    let compression = match enc.compression {
        TileCompression::Zip => Compression::ZIP16,
        TileCompression::None => Compression::Uncompressed,
    };
    let blocks = match enc.blocks {
        Blocks::ScanLines => BlockDescription::ScanLines,
        Blocks::MipTiles(t) => BlockDescription::Tiles(TileDescription {
            tile_size: Vec2(t, t),
            level_mode: LevelMode::MipMap,
            rounding_mode: RoundingMode::Up,
        }),
    };
    let mut attributes = LayerAttributes::named(name);
    if let Some(id) = identity {
        attributes
            .other
            .insert(IDENTITY_ATTRIBUTE.into(), AttributeValue::Text(id.into()));
    }
    Header::new(name.into(), size, channels.list)
        .with_encoding(compression, blocks, LineOrder::Increasing)
        .with_attributes(attributes)
        .with_shared_attributes(ImageAttributes::new(IntegerBounds::from_dimensions(size)))
}

/// The text of an EXR file's [`IDENTITY_ATTRIBUTE`] (None: it has none), from its header
/// alone: no pixel is decoded.
pub fn read_identity(bytes: &[u8]) -> Result<Option<String>, String> {
    read_header(bytes).map(|h| h.identity)
}

/// What a product check needs of an EXR file's header: its identity and its channels.
#[derive(Clone, Debug)]
pub struct HeaderFacts {
    /// The text of the header's [`IDENTITY_ATTRIBUTE`] (None: it has none).
    pub identity: Option<String>,
    /// Each channel's name and stored sample type, in the file's order.
    pub channels: Vec<(String, SampleType)>,
}

/// The identity and the channels of an EXR file, from its header alone: no pixel is decoded.
pub fn read_header(bytes: &[u8]) -> Result<HeaderFacts, String> {
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| e.to_string())?;
    let header = meta
        .headers
        .first()
        .ok_or_else(|| "no image layer".to_string())?;
    Ok(HeaderFacts {
        identity: identity_of(header),
        channels: header
            .channels
            .list
            .iter()
            .map(|c| (c.name.to_string(), c.sample_type))
            .collect(),
    })
}

/// The text of a header's [`IDENTITY_ATTRIBUTE`] (an empty text when it is not text).
fn identity_of(header: &Header) -> Option<String> {
    match header
        .own_attributes
        .other
        .get(&exr::meta::attribute::Text::from(IDENTITY_ATTRIBUTE))
    {
        Some(AttributeValue::Text(t)) => Some(t.to_string()),
        Some(_) => Some(String::new()),
        None => None,
    }
}

/// A sample type as the manifest's labels name it: `f16`, `f32` or `u32`.
pub fn sample_name(t: SampleType) -> &'static str {
    match t {
        SampleType::F16 => "f16",
        SampleType::F32 => "f32",
        SampleType::U32 => "u32",
    }
}

/// Name of the text attribute that holds a file's identity (`crate::format::Identity`): which
/// product, tile and run it belongs to.
pub const IDENTITY_ATTRIBUTE: &str = "penumbraIdentity";

/// The pixel size of each level of a header (one for scanline and single-level tiled files).
fn level_sizes(h: &Header) -> Result<Vec<(usize, usize)>, String> {
    let (w, ht) = (h.layer_size.width(), h.layer_size.height());
    match h.blocks {
        BlockDescription::ScanLines => Ok(vec![(w, ht)]),
        BlockDescription::Tiles(t) => match t.level_mode {
            LevelMode::Singular => Ok(vec![(w, ht)]),
            LevelMode::MipMap => {
                let n = compute_level_count(t.rounding_mode, w.max(ht));
                Ok((0..n)
                    .map(|l| {
                        (
                            compute_level_size(t.rounding_mode, w, l),
                            compute_level_size(t.rounding_mode, ht, l),
                        )
                    })
                    .collect())
            }
            LevelMode::RipMap => Err("rip-mapped, not mip-mapped".into()),
        },
    }
}

/// zlib-compress with the library and level asked for.
fn deflate(data: &[u8], level: ZipLevel) -> Vec<u8> {
    match level {
        ZipLevel::Libdeflate(l) => deflate_libdeflate(data, l),
        ZipLevel::Miniz(l) | ZipLevel::StoreNoise(l) => deflate_miniz(data, l),
        // Without a block layout: runs and repeated byte pairs only.
        ZipLevel::Layout => layout::zlib(data, &[1, 2]),
    }
}

/// zlib-compress with libdeflate, reusing one compressor per thread and level (allocating one
/// costs more than compressing a small block at the fast levels).
fn deflate_libdeflate(data: &[u8], level: u8) -> Vec<u8> {
    use libdeflater::{CompressionLvl, Compressor};
    use std::cell::RefCell;
    const LEVELS: usize = 13;
    thread_local! {
        static COMPRESSORS: RefCell<[Option<Compressor>; LEVELS]> =
            const { RefCell::new([const { None }; LEVELS]) };
    }
    let lvl = CompressionLvl::new(level.into())
        .unwrap_or_else(|_| panic!("libdeflate level {level} is not in 1–12"));
    COMPRESSORS.with(|c| {
        let mut slots = c.borrow_mut();
        let comp = slots[usize::from(level)].get_or_insert_with(|| Compressor::new(lvl));
        let mut out = vec![0u8; comp.zlib_compress_bound(data.len())];
        let n = comp
            .zlib_compress(data, &mut out)
            .expect("libdeflate's bound holds the whole stream");
        out.truncate(n);
        out
    })
}

/// zlib-compress with miniz_oxide, reusing one compressor per thread (a fresh one zeroes
/// ≈ 300 KB of tables, a noticeable cost for 25–30 KB blocks).
fn deflate_miniz(data: &[u8], level: u8) -> Vec<u8> {
    use miniz_oxide::deflate::core::{
        compress, create_comp_flags_from_zip_params, CompressorOxide, TDEFLFlush, TDEFLStatus,
    };
    use std::cell::RefCell;
    thread_local! {
        static COMPRESSOR: RefCell<Option<Box<CompressorOxide>>> = const { RefCell::new(None) };
    }
    let flags = create_comp_flags_from_zip_params(level.into(), 1, 0);
    COMPRESSOR.with(|c| {
        let mut slot = c.borrow_mut();
        let comp = slot.get_or_insert_with(|| Box::new(CompressorOxide::new(flags)));
        comp.reset();
        comp.set_format_and_level(miniz_oxide::DataFormat::Zlib, level);
        let mut out = vec![0u8; (data.len() / 2).max(64)];
        let mut input = data;
        let mut pos = 0;
        loop {
            let (status, used, written) =
                compress(comp, input, &mut out[pos..], TDEFLFlush::Finish);
            pos += written;
            match status {
                TDEFLStatus::Done => {
                    out.truncate(pos);
                    return out;
                }
                TDEFLStatus::Okay => {
                    input = &input[used..];
                    if out.len() - pos < 64 {
                        out.resize(out.len() * 2, 0);
                    }
                }
                _ => unreachable!("miniz_oxide failed on in-memory input"),
            }
        }
    })
}

/// For the fuzz target (tools/fuzz) and tests only, not an API: compress `data` with the ZIP
/// blocks' own deflate encoder (src/exrcodec/layout.rs) at the match distances of a block of
/// `lines` lines of `width` samples whose channels take `bps` bytes each (in stored order),
/// and panic, saying what differs, unless miniz_oxide, zune-inflate and libdeflate all inflate
/// the stream to `data`, the stream is no longer than storing `data`, the probed variant keeps
/// the same bytes, and every instruction set this CPU has writes them too. `bps` holds at most
/// 16 channels of 1 to 16 bytes, `width` and `lines` are 1 to 2²⁰ (wider than any block the
/// codec writes).
#[doc(hidden)]
pub fn fuzz_deflate_round_trip(data: &[u8], bps: &[usize], width: usize, lines: usize) {
    assert!(
        bps.len() <= 16
            && bps.iter().all(|b| (1..=16).contains(b))
            && (1..=1 << 20).contains(&width)
            && (1..=1 << 20).contains(&lines),
        "not a block layout: {bps:?} {width}×{lines}"
    );
    let dist = layout::distances(bps, width, lines);
    if let Err(e) = layout::check::round_trip(data, &dist, true) {
        panic!(
            "{} bytes, layout {bps:?} {width}×{lines}, distances {dist:?}: {e}",
            data.len()
        );
    }
}

/// Encode a single-part EXR file in memory. `size` is the largest level's (width, height);
/// channels may come in any order (they are stored sorted by name, as OpenEXR requires).
pub fn encode(
    name: &str,
    size: (usize, usize),
    channels: &[Channel<'_>],
    enc: &Encoding,
) -> Result<Vec<u8>, String> {
    encode_identified(name, None, size, channels, enc)
}

/// [`encode`] with the file's identity in the header (attribute [`IDENTITY_ATTRIBUTE`]).
pub fn encode_identified(
    name: &str,
    identity: Option<&str>,
    size: (usize, usize),
    channels: &[Channel<'_>],
    enc: &Encoding,
) -> Result<Vec<u8>, String> {
    let mut channels: Vec<&Channel> = channels.iter().collect();
    channels.sort_by(|a, b| a.name.cmp(b.name));
    let list = ChannelList::new(
        channels
            .iter()
            .map(|c| {
                let t = c
                    .levels
                    .first()
                    .map_or(SampleType::F32, Samples::sample_type);
                ChannelDescription::named(c.name, t)
            })
            .collect(),
    );
    let header = header(name, identity, size, list, enc);
    let sizes = level_sizes(&header)?;
    for c in &channels {
        if c.levels.len() != sizes.len()
            || c.levels
                .iter()
                .zip(&sizes)
                .any(|(s, &(w, h))| s.len() != w * h)
            || c.levels
                .iter()
                .any(|s| s.sample_type() != c.levels[0].sample_type())
        {
            return Err(format!(
                "channel '{}' does not hold {} level(s) of a {}×{} image",
                c.name,
                sizes.len(),
                size.0,
                size.1
            ));
        }
    }
    let blocks: Vec<_> = header.blocks_increasing_y_order().collect();
    let zip = enc.compression == TileCompression::Zip;
    // Bytes per sample of each channel, in stored order, per level.
    let bps: Vec<Vec<usize>> = (0..sizes.len())
        .map(|l| {
            channels
                .iter()
                .map(|c| match c.levels[l] {
                    Samples::F32(_) => 4,
                    Samples::F16(_) => 2,
                })
                .collect()
        })
        .collect();
    let chunks: Vec<Result<Chunk, String>> = blocks
        .par_iter()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(packed, predicted), tile| {
                let b = header
                    .get_absolute_block_pixel_coordinates(tile.location)
                    .map_err(|e| e.to_string())?;
                let (x0, y0) = (b.position.x() as usize, b.position.y() as usize);
                let (w, h) = (b.size.width(), b.size.height());
                let level = tile.location.level_index.x();
                let lw = sizes[level].0;
                packed.clear();
                for y in y0..y0 + h {
                    for c in &channels {
                        c.levels[level].push_le(y * lw + x0, w, packed);
                    }
                }
                let bytes = if zip {
                    predict(packed, predicted);
                    let noisy = match enc.level {
                        ZipLevel::StoreNoise(_) => {
                            mixed::noisy_channels(predicted, &bps[level], w, h, |b| {
                                deflate(b, enc.level).len()
                            })
                        }
                        _ => 0,
                    };
                    // None: store the block raw without deflating it.
                    let z = if noisy != 0 {
                        Some(mixed::zlib(predicted, &bps[level], w, h, noisy))
                    } else if enc.level == ZipLevel::Layout {
                        let bps = &bps[level];
                        let dd = layout::distances(bps, w, h);
                        if bps.iter().all(|&b| b == 4) {
                            // f32 blocks whose predicted bytes probe as noise to deflate.
                            layout::zlib_unless_weak(predicted, &dd)
                        } else {
                            Some(layout::zlib(predicted, &dd))
                        }
                    } else {
                        Some(deflate(predicted, enc.level))
                    };
                    // OpenEXR stores a block raw when deflate does not make it smaller (a
                    // reader tells by its length).
                    match z {
                        Some(z) if z.len() < packed.len() => z,
                        _ => packed.clone(),
                    }
                } else {
                    packed.clone()
                };
                Ok(Chunk {
                    layer_index: 0,
                    compressed_block: match enc.blocks {
                        Blocks::ScanLines => CompressedBlock::ScanLine(CompressedScanLineBlock {
                            y_coordinate: y0 as i32,
                            compressed_pixels_le: bytes,
                        }),
                        Blocks::MipTiles(_) => CompressedBlock::Tile(CompressedTileBlock {
                            coordinates: tile.location,
                            compressed_pixels_le: bytes,
                        }),
                    },
                })
            },
        )
        .collect();
    let chunks: Vec<Chunk> = chunks.into_iter().collect::<Result<_, _>>()?;
    let total: usize = chunks.iter().map(chunk_len).sum();
    let mut buf = Cursor::new(Vec::with_capacity(total + 1024 + 8 * chunks.len()));
    exr::block::write(
        &mut buf,
        exr::prelude::SmallVec::from_vec(vec![header]),
        true,
        |_meta, writer| {
            use exr::block::writer::ChunksWriter;
            for (i, chunk) in chunks.into_iter().enumerate() {
                writer.write_chunk(i, chunk)?;
            }
            Ok(())
        },
    )
    .map_err(|e| e.to_string())?;
    Ok(buf.into_inner())
}

fn chunk_len(c: &Chunk) -> usize {
    match &c.compressed_block {
        CompressedBlock::ScanLine(b) => b.compressed_pixels_le.len() + 8,
        CompressedBlock::Tile(b) => b.compressed_pixels_le.len() + 20,
        _ => 0,
    }
}

/// A decoded file: every channel's levels (largest first) converted to f32.
#[derive(Clone, Debug)]
pub struct Decoded {
    /// The layer name stored in the header, if any.
    pub layer_name: Option<String>,
    /// The text of the header's [`IDENTITY_ATTRIBUTE`], if it has one.
    pub identity: Option<String>,
    /// The file's compression.
    pub compression: Compression,
    /// Whether the file is tiled with mip levels (even when it has a single one, 1×1).
    pub mip_mapped: bool,
    /// (width, height) of each level, largest first.
    pub level_sizes: Vec<(usize, usize)>,
    /// Channel name, stored sample type, levels.
    pub channels: Vec<(String, SampleType, Vec<Vec<f32>>)>,
}

impl Decoded {
    pub fn size(&self) -> (usize, usize) {
        self.level_sizes[0]
    }

    /// The levels of a channel.
    pub fn channel(&self, name: &str) -> Option<&Vec<Vec<f32>>> {
        self.channels
            .iter()
            .find(|(n, _, _)| n == name)
            .map(|(_, _, l)| l)
    }

    /// Take a channel's levels out.
    pub fn take(&mut self, name: &str) -> Option<Vec<Vec<f32>>> {
        let i = self.channels.iter().position(|(n, _, _)| n == name)?;
        Some(self.channels.swap_remove(i).2)
    }
}

/// One decoded block: its level, pixel rectangle and native little-endian bytes.
struct Block {
    level: usize,
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    bytes: Vec<u8>,
}

/// Decode the first layer of a flat EXR file in memory (all levels, or only the largest).
pub fn decode(bytes: &[u8], largest_only: bool) -> Result<Decoded, String> {
    let reader = exr::block::read(Cursor::new(bytes), false).map_err(|e| e.to_string())?;
    let meta = reader.meta_data().clone();
    let header = meta
        .headers
        .first()
        .ok_or_else(|| "no image layer".to_string())?;
    if meta.headers.len() != 1 {
        return Err(format!(
            "{} layers; a single-layer file expected",
            meta.headers.len()
        ));
    }
    if header.deep {
        return Err("deep data, not a flat image".into());
    }
    if header
        .channels
        .list
        .iter()
        .any(|c| c.sampling != Vec2(1, 1))
    {
        return Err("subsampled channels are not supported".into());
    }
    let sizes = level_sizes(header)?;
    let keep_levels = if largest_only { 1 } else { sizes.len() };
    let chunks: Vec<Chunk> = reader
        .all_chunks(false)
        .map_err(|e| e.to_string())?
        .collect::<Result<_, _>>()
        .map_err(|e| e.to_string())?;
    let bpp = header.channels.bytes_per_pixel;
    let compression = header.compression;
    let blocks: Vec<Result<Option<Block>, String>> = chunks
        .into_par_iter()
        .map(|chunk| {
            let tile = header
                .get_block_data_indices(&chunk.compressed_block)
                .map_err(|e| e.to_string())?;
            let level = tile.level_index.x();
            if tile.level_index.y() != level || level >= sizes.len() {
                return Err(format!(
                    "block at level {:?} outside the image",
                    tile.level_index
                ));
            }
            if level >= keep_levels {
                return Ok(None);
            }
            let b = header
                .get_absolute_block_pixel_coordinates(tile)
                .map_err(|e| e.to_string())?;
            let (x0, y0) = (b.position.x(), b.position.y());
            let (w, h) = (b.size.width(), b.size.height());
            if x0 < 0 || y0 < 0 {
                return Err("block at a negative position".into());
            }
            let (x0, y0) = (x0 as usize, y0 as usize);
            let (lw, lh) = sizes[level];
            if x0 + w > lw || y0 + h > lh {
                return Err("block outside the image".into());
            }
            let expected = w * h * bpp;
            let bytes = match (compression, chunk.compressed_block) {
                (
                    Compression::ZIP1 | Compression::ZIP16 | Compression::Uncompressed,
                    CompressedBlock::ScanLine(CompressedScanLineBlock {
                        compressed_pixels_le: data,
                        ..
                    })
                    | CompressedBlock::Tile(CompressedTileBlock {
                        compressed_pixels_le: data,
                        ..
                    }),
                ) => {
                    if data.len() == expected {
                        data
                    } else if compression == Compression::Uncompressed {
                        return Err(format!(
                            "uncompressed block of {} bytes, {expected} expected",
                            data.len()
                        ));
                    } else {
                        let options = zune_inflate::DeflateOptions::default()
                            .set_limit(expected)
                            .set_size_hint(expected);
                        let mut inflated =
                            zune_inflate::DeflateDecoder::new_with_options(&data, options)
                                .decode_zlib()
                                .map_err(|e| format!("damaged ZIP block ({e:?})"))?;
                        if inflated.len() != expected {
                            return Err(format!(
                                "ZIP block inflates to {} bytes, {expected} expected",
                                inflated.len()
                            ));
                        }
                        unpredict(&mut inflated)
                    }
                }
                (_, block) => {
                    let chunk = Chunk {
                        layer_index: 0,
                        compressed_block: block,
                    };
                    let u = UncompressedBlock::decompress_chunk(chunk, &meta, false)
                        .map_err(|e| e.to_string())?;
                    if u.data.len() != expected {
                        return Err("block decodes to the wrong size".into());
                    }
                    // exr returns native-endian samples; store them little-endian like the rest.
                    if cfg!(target_endian = "big") {
                        return Err("big-endian hosts are not supported".into());
                    }
                    u.data
                }
            };
            Ok(Some(Block {
                level,
                x0,
                y0,
                w,
                h,
                bytes,
            }))
        })
        .collect();

    // The blocks present must cover the image exactly before the image is allocated: a
    // header's claimed size alone never decides how much memory a damaged file takes.
    let mut covered = vec![0usize; keep_levels];
    let mut seen = std::collections::HashSet::new();
    let mut present = Vec::with_capacity(blocks.len());
    for b in blocks {
        let Some(b) = b? else { continue };
        if !seen.insert((b.level, b.x0, b.y0)) {
            return Err("a block is stored twice".into());
        }
        covered[b.level] += b.w * b.h;
        present.push(b);
    }
    for (l, &c) in covered.iter().enumerate() {
        let (w, h) = sizes[l];
        if c != w * h {
            return Err(format!("level {l} is missing blocks"));
        }
    }
    let blocks = present;
    let types: Vec<SampleType> = header.channels.list.iter().map(|c| c.sample_type).collect();
    let mut out: Vec<Vec<Vec<f32>>> = types
        .iter()
        .map(|_| {
            sizes[..keep_levels]
                .iter()
                .map(|&(w, h)| vec![0.0f32; w * h])
                .collect()
        })
        .collect();
    for b in &blocks {
        let lw = sizes[b.level].0;
        let mut off = 0;
        for y in b.y0..b.y0 + b.h {
            for (c, t) in types.iter().enumerate() {
                let dst = &mut out[c][b.level][y * lw + b.x0..y * lw + b.x0 + b.w];
                match t {
                    SampleType::F32 => {
                        for (d, s) in dst.iter_mut().zip(b.bytes[off..].chunks_exact(4)) {
                            *d = f32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                        }
                        off += 4 * b.w;
                    }
                    SampleType::F16 => {
                        for (d, s) in dst.iter_mut().zip(b.bytes[off..].chunks_exact(2)) {
                            *d = f16::from_bits(u16::from_le_bytes([s[0], s[1]])).to_f32();
                        }
                        off += 2 * b.w;
                    }
                    SampleType::U32 => {
                        for (d, s) in dst.iter_mut().zip(b.bytes[off..].chunks_exact(4)) {
                            *d = u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as f32;
                        }
                        off += 4 * b.w;
                    }
                }
            }
        }
    }
    let channels = header
        .channels
        .list
        .iter()
        .zip(types)
        .zip(out)
        .map(|((c, t), levels)| (c.name.to_string(), t, levels))
        .collect();
    let identity = identity_of(header);
    Ok(Decoded {
        identity,
        layer_name: header
            .own_attributes
            .layer_name
            .as_ref()
            .map(|n| n.to_string()),
        compression,
        mip_mapped: matches!(
            header.blocks,
            BlockDescription::Tiles(TileDescription {
                level_mode: LevelMode::MipMap,
                ..
            })
        ),
        level_sizes: sizes[..keep_levels].to_vec(),
        channels,
    })
}

/// The codec's own deflate of a predicted block laid out as `width` × `lines` samples of
/// `bps` bytes per channel (for the formats' tests).
#[cfg(test)]
pub(crate) fn layout_zlib(predicted: &[u8], bps: &[usize], width: usize, lines: usize) -> Vec<u8> {
    layout::zlib(predicted, &layout::distances(bps, width, lines))
}
