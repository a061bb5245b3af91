//! `penumbra-bench codec`: size and speed of each EXR compression option on the tiles the
//! stages really write (issue 14). Tiles LDEM_4 (4 levels) and SRTM N19W156, builds their mips
//! and LDEM_4's level-1 horizon maps with the `penumbra` binary, then, on one thread, encodes
//! and decodes a sample of the files with the `exr` crate's own writer/reader (what Penumbra
//! used before), with src/exrcodec.rs at several miniz_oxide and libdeflate levels, with its own
//! layout-aware encoder and uncompressed, against a memcpy of the same raw bytes in the same
//! run. Every decode is checked bit for bit.

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use half::f16;
use penumbra::exrcodec::{self, Blocks, Channel, Samples, ZipLevel};
use penumbra::format::TileCompression;
use serde::Serialize;

use crate::common::{best_of, in_pool, penumbra_exe, tempfile_dir, LDEM4_BENCH_TILING};

/// One channel's stored samples, every level.
#[derive(Clone)]
enum Stored {
    F32(Vec<Vec<f32>>),
    F16(Vec<Vec<f16>>),
}

/// One file's content, as the stage stores it.
#[derive(Clone)]
struct Item {
    name: String,
    size: (usize, usize),
    mip: bool,
    channels: Vec<(String, Stored)>,
}

impl Item {
    fn raw_bytes(&self) -> usize {
        self.channels
            .iter()
            .map(|(_, s)| match s {
                Stored::F32(l) => l.iter().map(|v| v.len() * 4).sum::<usize>(),
                Stored::F16(l) => l.iter().map(|v| v.len() * 2).sum(),
            })
            .sum()
    }

    /// The raw sample bytes, for the memcpy baseline.
    fn raw(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.raw_bytes());
        for (_, s) in &self.channels {
            match s {
                Stored::F32(l) => l
                    .iter()
                    .flatten()
                    .for_each(|v| out.extend_from_slice(&v.to_le_bytes())),
                Stored::F16(l) => l
                    .iter()
                    .flatten()
                    .for_each(|v| out.extend_from_slice(&v.to_bits().to_le_bytes())),
            }
        }
        out
    }

    fn encode(&self, compression: TileCompression, level: ZipLevel) -> Result<Vec<u8>> {
        let channels: Vec<Channel> = self
            .channels
            .iter()
            .map(|(n, s)| Channel {
                name: n,
                levels: match s {
                    Stored::F32(l) => l
                        .iter()
                        .map(|v| Samples::F32(Cow::Borrowed(v.as_slice())))
                        .collect(),
                    Stored::F16(l) => l
                        .iter()
                        .map(|v| Samples::F16(Cow::Borrowed(v.as_slice())))
                        .collect(),
                },
            })
            .collect();
        let enc = exrcodec::Encoding {
            compression,
            level,
            blocks: if self.mip {
                Blocks::MipTiles(64)
            } else {
                Blocks::ScanLines
            },
        };
        exrcodec::encode(&self.name, self.size, &channels, &enc).map_err(anyhow::Error::msg)
    }

    /// What the `exr` crate's writer made of it (ZIP, level 4, one block after another).
    fn encode_exr_crate(&self) -> Result<Vec<u8>> {
        self.encode_exr_crate_with(true)
    }

    /// What the `exr` crate's writer made of it, ZIP or uncompressed.
    fn encode_exr_crate_with(&self, zip: bool) -> Result<Vec<u8>> {
        use exr::prelude::*;
        let list = self
            .channels
            .iter()
            .map(|(n, s)| {
                let levels: Vec<FlatSamples> = match s {
                    Stored::F32(l) => l.iter().map(|v| FlatSamples::F32(v.clone())).collect(),
                    Stored::F16(l) => l.iter().map(|v| FlatSamples::F16(v.clone())).collect(),
                };
                if self.mip {
                    AnyChannel::new(
                        n.as_str(),
                        Levels::Mip {
                            rounding_mode: exr::math::RoundingMode::Up,
                            level_data: levels,
                        },
                    )
                } else {
                    AnyChannel::new(
                        n.as_str(),
                        Levels::Singular(levels.into_iter().next().unwrap()),
                    )
                }
            })
            .collect();
        let encoding = match (self.mip, zip) {
            (true, _) => Encoding {
                compression: if zip {
                    Compression::ZIP16
                } else {
                    Compression::Uncompressed
                },
                blocks: Blocks::Tiles(Vec2(64, 64)),
                line_order: LineOrder::Increasing,
            },
            (false, true) => Encoding::SMALL_LOSSLESS,
            (false, false) => Encoding::UNCOMPRESSED,
        };
        let layer = Layer::new(
            self.size,
            LayerAttributes::named(self.name.as_str()),
            encoding,
            AnyChannels::sort(SmallVec::from_vec(list)),
        );
        let mut buf = std::io::Cursor::new(Vec::new());
        Image::from_layer(layer)
            .write()
            .non_parallel()
            .to_buffered(&mut buf)?;
        Ok(buf.into_inner())
    }

    /// Every channel's levels as f32 bits, sorted by channel name.
    fn bits(&self) -> Vec<Vec<u32>> {
        let mut c: Vec<_> = self.channels.iter().collect();
        c.sort_by(|a, b| a.0.cmp(&b.0));
        c.iter()
            .flat_map(|(_, s)| match s {
                Stored::F32(l) => l
                    .iter()
                    .map(|v| v.iter().map(|x| x.to_bits()).collect())
                    .collect::<Vec<_>>(),
                Stored::F16(l) => l
                    .iter()
                    .map(|v| v.iter().map(|x| x.to_f32().to_bits()).collect())
                    .collect(),
            })
            .collect()
    }
}

/// Decode with the `exr` crate's reader as Penumbra did before (one thread, all levels).
fn decode_exr_crate(bytes: &[u8]) -> Result<Vec<Vec<u32>>> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .all_resolution_levels()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_buffered(std::io::Cursor::new(bytes))?;
    let mut out = Vec::new();
    for ch in &image.layer_data.channel_data.list {
        match &ch.sample_data {
            Levels::Singular(s) => out.push(s.values_as_f32().map(f32::to_bits).collect()),
            Levels::Mip { level_data, .. } => {
                for s in level_data {
                    out.push(s.values_as_f32().map(f32::to_bits).collect())
                }
            }
            Levels::Rip { .. } => bail!("rip map"),
        }
    }
    Ok(out)
}

fn decode_codec(bytes: &[u8]) -> Result<Vec<Vec<u32>>> {
    let d = exrcodec::decode(bytes, false).map_err(anyhow::Error::msg)?;
    Ok(d.channels
        .iter()
        .flat_map(|(_, _, l)| {
            l.iter()
                .map(|v| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>())
        })
        .collect())
}

#[derive(Serialize)]
struct Row {
    product: String,
    files: usize,
    raw_mb: f64,
    option: String,
    stored_mb: f64,
    ratio: f64,
    /// Stored size relative to the `exr` crate's ZIP of the same files (1.0 = same).
    vs_exr_zip: f64,
    encode_mb_s: f64,
    decode_mb_s: f64,
}

fn run_penumbra(args: &[&str], dir: &Path, quiet: bool) -> Result<()> {
    if !quiet {
        eprintln!("bench codec: penumbra {}", args.join(" "));
    }
    let status = Command::new(penumbra_exe()?)
        .arg("--quiet")
        .args(args)
        .arg(dir)
        .stdout(std::process::Stdio::null())
        .status()?;
    if !status.success() {
        bail!("penumbra {} failed", args.join(" "));
    }
    Ok(())
}

fn exr_files(dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
    for e in std::fs::read_dir(dir)? {
        let p = e?.path();
        if p.is_dir() {
            if !p.ends_with(".penumbra") {
                exr_files(&p, out)?;
            }
        } else if p.extension().is_some_and(|x| x == "exr") {
            out.push(p);
        }
    }
    Ok(())
}

/// Every `step`-th element so that at most `max` remain (deterministic, spread over the set).
fn spread<T: Clone>(v: &[T], max: usize) -> Vec<T> {
    if v.len() <= max {
        return v.to_vec();
    }
    (0..max).map(|i| v[i * v.len() / max].clone()).collect()
}

/// A file's content (every level), and whether it is ZIP-compressed.
fn load_item(p: &Path) -> Result<(Item, bool)> {
    let bytes = std::fs::read(p)?;
    let d = exrcodec::decode(&bytes, false)
        .map_err(anyhow::Error::msg)
        .with_context(|| p.display().to_string())?;
    let channels = d
        .channels
        .iter()
        .map(|(n, t, l)| {
            let s = match t {
                exr::meta::attribute::SampleType::F16 => Stored::F16(
                    l.iter()
                        .map(|v| v.iter().map(|&x| f16::from_f32(x)).collect())
                        .collect(),
                ),
                _ => Stored::F32(l.clone()),
            };
            (n.clone(), s)
        })
        .collect();
    let item = Item {
        name: d.layer_name.clone().unwrap_or_default(),
        size: d.size(),
        mip: d.mip_mapped,
        channels,
    };
    Ok((
        item,
        d.compression != exr::compression::Compression::Uncompressed,
    ))
}

/// Rewrite every EXR under `from` into the same place under `to` as the `exr` crate's writer
/// (what Penumbra used before src/exrcodec.rs) would have written the same samples, and copy
/// the other files. Hashing the result against tools/golden/hashes.txt proves that a codec
/// change kept every stored sample (the codec at level 4 writes exactly the exr crate's bytes).
pub fn run_exr_crate_rewrite(from: &Path, to: &Path) -> Result<()> {
    let mut stack = vec![from.to_path_buf()];
    let mut n = 0;
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d)? {
            let p = e?.path();
            let rel = p.strip_prefix(from)?;
            let q = to.join(rel);
            if p.is_dir() {
                std::fs::create_dir_all(&q)?;
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "exr") {
                let (item, zip) = load_item(&p)?;
                std::fs::write(&q, item.encode_exr_crate_with(zip)?)?;
                n += 1;
            } else {
                std::fs::copy(&p, &q)?;
            }
        }
    }
    eprintln!("rewrote {n} EXR files with the exr crate's writer");
    Ok(())
}

/// The products of one DEM: height tiles, f32 mip files, horizon maps (each a list of items).
fn load_products(dir: &Path, max: usize) -> Result<Vec<(&'static str, Vec<Item>)>> {
    let mut files = Vec::new();
    exr_files(dir, &mut files)?;
    files.sort();
    let (mut height, mut mip, mut horizon) = (Vec::new(), Vec::new(), Vec::new());
    for p in files {
        let (item, _) = load_item(&p)?;
        let names: Vec<&str> = item.channels.iter().map(|(n, _)| n.as_str()).collect();
        match names.as_slice() {
            ["height", "mask"] => height.push(item),
            ["max"] | ["max", "min"] if item.mip => mip.push(item),
            ["elevation"] => horizon.push(item),
            _ => {}
        }
    }
    Ok(vec![
        ("height tile (height f32 + mask f16)", spread(&height, max)),
        (
            "mip file (max [+ min] f32, 64² tiles, all levels)",
            spread(&mip, max),
        ),
        ("horizon map (elevation f16)", spread(&horizon, max)),
    ])
}

/// A product split into its parts and precisions, as the table reports them.
fn variants(name: &str, items: &[Item]) -> Vec<(String, Vec<Item>)> {
    let one = |keep: &str| -> Vec<Item> {
        items
            .iter()
            .map(|i| Item {
                channels: i
                    .channels
                    .iter()
                    .filter(|(n, _)| n == keep)
                    .cloned()
                    .collect(),
                ..i.clone()
            })
            .collect()
    };
    let mut out = vec![(name.to_string(), items.to_vec())];
    if name.starts_with("height tile") {
        out.push(("height channel alone (f32)".into(), one("height")));
        out.push(("mask channel alone (f16)".into(), one("mask")));
    }
    if name.starts_with("mip file") {
        // What `penumbra mip --precision f16` stores: max rounded up, min rounded down.
        let f16s = items
            .iter()
            .map(|i| Item {
                channels: i
                    .channels
                    .iter()
                    .map(|(n, s)| {
                        let Stored::F32(l) = s else {
                            return (n.clone(), s.clone());
                        };
                        let conv = |v: f32| {
                            if n == "max" {
                                penumbra::mip::f16_up(v)
                            } else {
                                penumbra::mip::f16_down(v)
                            }
                        };
                        (
                            n.clone(),
                            Stored::F16(
                                l.iter()
                                    .map(|v| v.iter().map(|&x| conv(x)).collect())
                                    .collect(),
                            ),
                        )
                    })
                    .collect(),
                ..i.clone()
            })
            .collect();
        out.push(("mip file (max [+ min] f16, `--precision f16`)".into(), f16s));
    }
    out
}

#[allow(clippy::too_many_arguments)]
pub fn run_codec(
    data: &Path,
    work: Option<PathBuf>,
    reps: usize,
    max_files: usize,
    levels: &[u8],
    libdeflate_levels: &[u8],
    markdown: bool,
    json: bool,
    quiet: bool,
) -> Result<()> {
    let ldem = data.join("lola_ldem4/LDEM_4.LBL");
    let srtm = data.join("srtm3/N19W156.hgt");
    if !ldem.exists() || !srtm.exists() {
        bail!(
            "{}: the shared DEMs (lola_ldem4, srtm3) are needed; give --data",
            data.display()
        );
    }
    let tmp = tempfile_dir(work)?;
    let mut dems = Vec::new();
    let l = tmp.join("ldem4");
    let ls = ldem.to_string_lossy().into_owned();
    let ss = srtm.to_string_lossy().into_owned();
    let args: Vec<&str> = ["tile", ls.as_str()]
        .into_iter()
        .chain(LDEM4_BENCH_TILING.iter().copied())
        .chain(["--out"])
        .collect();
    run_penumbra(&args, &l, quiet)?;
    run_penumbra(&["mip"], &l, quiet)?;
    run_penumbra(&["horizon", "--levels", "1", "--azimuths", "16"], &l, quiet)?;
    dems.push(("LDEM_4 (256² tiles, 4 levels)", l));
    let s = tmp.join("srtm");
    run_penumbra(&["tile", &ss, "--body", "earth", "--out"], &s, quiet)?;
    run_penumbra(&["mip"], &s, quiet)?;
    dems.push(("SRTM N19W156", s));

    let mut rows = Vec::new();
    let mut memcpy_mb_s = 0.0f64;
    for (dem, dir) in &dems {
        for (product, items) in load_products(dir, max_files)? {
            if items.is_empty() {
                continue;
            }
            for (what, items) in variants(product, &items) {
                let name = format!("{dem}: {what}");
                if !quiet {
                    eprintln!("bench codec: {name}");
                }
                let raw: usize = items.iter().map(Item::raw_bytes).sum();
                let raw_mb = raw as f64 / 1e6;
                let want: Vec<Vec<Vec<u32>>> = items.iter().map(Item::bits).collect();
                // memcpy of the same raw bytes, one core.
                let raws: Vec<Vec<u8>> = items.iter().map(Item::raw).collect();
                let mut dst = vec![0u8; raws.iter().map(Vec::len).max().unwrap_or(0)];
                let t_copy = best_of(reps * 5, || {
                    for r in &raws {
                        dst[..r.len()].copy_from_slice(std::hint::black_box(r));
                        std::hint::black_box(&dst);
                    }
                    Ok(())
                })?;
                memcpy_mb_s = memcpy_mb_s.max(raw_mb / t_copy);
                let mut opts: Vec<(String, Option<(TileCompression, ZipLevel)>)> =
                    vec![("exr crate ZIP (level 4, before)".into(), None)];
                for &lv in levels {
                    opts.push((
                        format!("codec ZIP miniz_oxide level {lv}"),
                        Some((TileCompression::Zip, ZipLevel::Miniz(lv))),
                    ));
                }
                opts.push((
                    "codec ZIP miniz_oxide level 1, noisy channels stored (height tiles)".into(),
                    Some((TileCompression::Zip, ZipLevel::HEIGHT_TILE)),
                ));
                opts.push((
                    "codec ZIP layout-aware encoder (default but height tiles)".into(),
                    Some((TileCompression::Zip, ZipLevel::Layout)),
                ));
                for &lv in libdeflate_levels {
                    opts.push((
                        format!("codec ZIP libdeflate level {lv}"),
                        Some((TileCompression::Zip, ZipLevel::Libdeflate(lv))),
                    ));
                }
                opts.push((
                    "codec uncompressed".into(),
                    Some((TileCompression::None, ZipLevel::DEFAULT)),
                ));
                let mut exr_size = 0usize;
                for (label, opt) in opts {
                    let encode_all = || -> Result<Vec<Vec<u8>>> {
                        items
                            .iter()
                            .map(|i| match opt {
                                None => i.encode_exr_crate(),
                                Some((c, lv)) => i.encode(c, lv),
                            })
                            .collect()
                    };
                    let files = in_pool(1, encode_all)??;
                    let t_enc = in_pool(1, || {
                        best_of(reps, || {
                            std::hint::black_box(encode_all()?);
                            Ok(())
                        })
                    })??;
                    let decode_all = |check: bool| -> Result<()> {
                        for (f, w) in files.iter().zip(&want) {
                            let got = match opt {
                                None => decode_exr_crate(f)?,
                                Some(_) => decode_codec(f)?,
                            };
                            if check && &got != w {
                                bail!("{name}, {label}: decoded samples differ from the input");
                            }
                        }
                        Ok(())
                    };
                    in_pool(1, || decode_all(true))??;
                    let t_dec = in_pool(1, || best_of(reps, || decode_all(false)))??;
                    let stored: usize = files.iter().map(Vec::len).sum();
                    if opt.is_none() {
                        exr_size = stored;
                    }
                    rows.push(Row {
                        product: name.clone(),
                        files: items.len(),
                        raw_mb,
                        option: label,
                        stored_mb: stored as f64 / 1e6,
                        ratio: raw as f64 / stored as f64,
                        vs_exr_zip: stored as f64 / exr_size as f64,
                        encode_mb_s: raw_mb / t_enc,
                        decode_mb_s: raw_mb / t_dec,
                    });
                }
            }
        }
    }
    let _ = std::fs::remove_dir_all(&tmp);

    if json {
        return penumbra_cli::output::print_json(&serde_json::json!({
            "memcpy_mb_s": memcpy_mb_s,
            "rows": rows,
        }));
    }
    if markdown {
        println!(
            "| product | files | raw MB | option | stored MB | ratio | size ÷ exr ZIP | encode MB/s | decode MB/s |"
        );
        println!("|---|---:|---:|---|---:|---:|---:|---:|---:|");
    }
    for r in &rows {
        if markdown {
            println!(
                "| {} | {} | {:.1} | {} | {:.2} | {:.2} | {:.3} | {:.0} | {:.0} |",
                r.product,
                r.files,
                r.raw_mb,
                r.option,
                r.stored_mb,
                r.ratio,
                r.vs_exr_zip,
                r.encode_mb_s,
                r.decode_mb_s
            );
        } else {
            println!(
                "{:<70} {:<32} {:>8.2} MB  ×{:<5.2} {:>6.3} of exr  enc {:>6.0} MB/s  dec {:>6.0} MB/s",
                r.product, r.option, r.stored_mb, r.ratio, r.vs_exr_zip, r.encode_mb_s, r.decode_mb_s
            );
        }
    }
    println!();
    println!(
        "One thread; MB = raw sample bytes (what the file holds uncompressed); best of {reps} \
         runs; at most {max_files} files per product, spread over the set; memcpy of the same \
         raw bytes on one core in the same run: {memcpy_mb_s:.0} MB/s. Every decode was \
         checked bit for bit against the samples written."
    );
    Ok(())
}
