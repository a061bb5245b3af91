//! `penumbra-bench integrity` (issue 41): what the files' identities, hashes and bounded reads
//! cost. On the LDEM_4 tileset of the mip benchmark (4 levels of 256² tiles) with its mipmaps
//! and raw horizon maps of one level: `penumbra verify` (every file hashed and its identity
//! read) against reading the same bytes plainly; and the read overhead of the checks on the
//! mip and horizon stages: every height tile read through the store (bounded open, the index's
//! size and blake3, the identity) against a plain `read` and decode of the same file, times
//! the reads each stage makes, as a share of that stage's wall time, all on one thread. The
//! index's hashes are timed the same way: what the stages now do (each file hashed from its
//! bytes in memory as it is written, its record appended to the staging folder's hash log, and
//! the commit's look-up of the records), replayed on the stages' files, and, for comparison,
//! what the commit did before the records (every file read back and hashed).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use serde::Serialize;

use penumbra::horizon::HorizonOptions;
use penumbra::manifest::Tileset;
use penumbra::mip::MipOptions;
use penumbra::progress::NoProgress;
use penumbra::tileset::Store;

use crate::common::{best_of, in_pool, tempfile_dir, tile_ldem4};

/// The horizon level and azimuths of the horizon stage measured (a short run: the smaller the
/// stage's time, the larger the checks' share).
const HORIZON_LEVEL: u8 = 2;
const HORIZON_AZIMUTHS: usize = 64;

#[derive(Serialize)]
struct Report {
    case: String,
    tiles: usize,
    files: u64,
    bytes: u64,
    /// `verify` (one thread, then all), and a plain read of every indexed file (one thread).
    verify_s_1t: f64,
    verify_s: f64,
    plain_read_s_1t: f64,
    /// Every height tile: read through the store (checked) and plainly (read + decode).
    heights_checked_s: f64,
    heights_plain_s: f64,
    /// The index's hashes of the files the mip and horizon stages wrote, as the stages make
    /// them: blake3 of each file's bytes in memory and its record as they are written, then
    /// the commit's look-up of the records.
    mip_hash_s: f64,
    horizon_hash_s: f64,
    /// Of which: blake3 of the bytes; the stamps and records as written; the commit's look-up.
    mip_hash_parts: HashCost,
    horizon_hash_parts: HashCost,
    /// The same hashes as the commit made them before the records: every file read back and
    /// hashed.
    mip_readback_hash_s: f64,
    horizon_readback_hash_s: f64,
    /// The stages, one thread.
    mip_stage_s: f64,
    horizon_stage_s: f64,
    horizon_tiles_read: usize,
    /// The checks' share of each stage.
    mip_read_overhead: f64,
    mip_hash_share: f64,
    mip_readback_hash_share: f64,
    horizon_read_overhead: f64,
    horizon_hash_share: f64,
    horizon_readback_hash_share: f64,
}

pub fn run(
    data: &std::path::Path,
    work: Option<PathBuf>,
    reps: usize,
    markdown: bool,
    json: bool,
    quiet: bool,
) -> Result<()> {
    let src = data.join("lola_ldem4/LDEM_4.LBL");
    if !src.exists() {
        bail!(
            "{} not found: the integrity benchmark needs LDEM_4",
            src.display()
        );
    }
    let tmp = tempfile_dir(work)?;
    let out = tmp.join("ldem4");
    let say = |m: &str| {
        if !quiet {
            eprintln!("bench integrity: {m}");
        }
    };
    say("tiling LDEM_4 (--tile-size 256 --levels 4)");
    tile_ldem4(&src, &out)?;
    say("mip stage, one thread");
    let t0 = std::time::Instant::now();
    in_pool(1, || {
        penumbra::mip::build_mips(&out, &MipOptions::default(), &NoProgress)
    })??;
    let mip_stage_s = t0.elapsed().as_secs_f64();
    say("horizon stage, one thread");
    let hopts = HorizonOptions {
        levels: Some(vec![HORIZON_LEVEL]),
        azimuths: HORIZON_AZIMUTHS,
        ..Default::default()
    };
    let t0 = std::time::Instant::now();
    in_pool(1, || {
        penumbra::horizon::build_horizons(&out, &hopts, &NoProgress)
    })??;
    let horizon_stage_s = t0.elapsed().as_secs_f64();

    let ts = Tileset::load(&out)?;
    let ids: Vec<_> = ts.tile_set().into_iter().collect();
    let pattern = ts
        .products
        .height
        .as_ref()
        .context("no heights")?
        .path
        .clone();
    // The horizon stage reads the tiles of its level and, for the far field, coarser ones:
    // counted as every tile of the levels up to it (each read once: the cache holds them).
    let horizon_tiles_read = ids.iter().filter(|i| i.level <= HORIZON_LEVEL).count();

    say("reading every height tile, checked and plain");
    let heights_checked_s = in_pool(1, || {
        best_of(reps, || {
            let store = Store::open(&out)?;
            for &id in &ids {
                std::hint::black_box(store.read_height(id)?);
            }
            Ok(())
        })
    })??;
    let heights_plain_s = in_pool(1, || {
        best_of(reps, || {
            for &id in &ids {
                let p = penumbra::tileset::tile_path(&out, &pattern, id);
                let bytes = std::fs::read(&p)?;
                std::hint::black_box(
                    penumbra::format::height::decode_height_tile(&bytes)
                        .map_err(anyhow::Error::msg)?,
                );
            }
            Ok(())
        })
    })??;

    say("verify, and a plain read of the same files");
    let verify_s_1t = in_pool(1, || {
        best_of(reps, || {
            let r = penumbra::tileset::verify::verify(&out)?;
            if !r.clean() {
                bail!("verify found problems on a fresh tileset: {:?}", r.findings);
            }
            Ok(())
        })
    })??;
    let verify_s = best_of(reps, || {
        penumbra::tileset::verify::verify(&out)?;
        Ok(())
    })?;
    let r = penumbra::tileset::verify::verify(&out)?;
    let files_of = |product: &str| -> Result<Vec<PathBuf>> {
        let ix: Vec<(String, u64, String)> = serde_json::from_slice(&std::fs::read(
            out.join(format!(".penumbra/index/{product}.json")),
        )?)?;
        Ok(ix.into_iter().map(|(r, _, _)| out.join(r)).collect())
    };
    let (hf, mf, zf) = (files_of("height")?, files_of("mip")?, files_of("horizon")?);
    let plain_read_s_1t = best_of(reps, || {
        for p in hf.iter().chain(&mf).chain(&zf) {
            std::hint::black_box(std::fs::read(p)?);
        }
        Ok(())
    })?;
    let hash_all = |files: &[PathBuf]| {
        best_of(reps, || {
            for p in files {
                std::hint::black_box(blake3::hash(&std::fs::read(p)?));
            }
            Ok(())
        })
    };
    // Before the records, the commit read every file back to hash it: read + hash, one thread.
    let mip_readback_hash_s = hash_all(&mf)?;
    let horizon_readback_hash_s = hash_all(&zf)?;
    // Now `write_staged` hashes each file's bytes as it writes them and records the hash, and
    // the commit looks the records up: replayed on the stages' files, one thread.
    let replay = tmp.join("hash-records");
    let mip_hash_parts = in_pool(1, || recorded_hashes(&out, "mip", &replay, reps))??;
    let horizon_hash_parts = in_pool(1, || recorded_hashes(&out, "horizon", &replay, reps))??;
    let (mip_hash_s, horizon_hash_s) = (mip_hash_parts.total(), horizon_hash_parts.total());

    let per_tile = (heights_checked_s - heights_plain_s) / ids.len() as f64;
    let rep = Report {
        case: format!(
            "LDEM_4, {} tiles of 256² on 4 levels; mip (f32, zip); horizon level {HORIZON_LEVEL}, \
             {HORIZON_AZIMUTHS} azimuths, fast",
            ids.len()
        ),
        tiles: ids.len(),
        files: r.files,
        bytes: r.bytes,
        verify_s_1t,
        verify_s,
        plain_read_s_1t,
        heights_checked_s,
        heights_plain_s,
        mip_hash_s,
        horizon_hash_s,
        mip_hash_parts,
        horizon_hash_parts,
        mip_readback_hash_s,
        horizon_readback_hash_s,
        mip_stage_s,
        horizon_stage_s,
        horizon_tiles_read,
        mip_read_overhead: per_tile * ids.len() as f64 / mip_stage_s,
        mip_hash_share: mip_hash_s / mip_stage_s,
        mip_readback_hash_share: mip_readback_hash_s / mip_stage_s,
        horizon_read_overhead: per_tile * horizon_tiles_read as f64 / horizon_stage_s,
        horizon_hash_share: horizon_hash_s / horizon_stage_s,
        horizon_readback_hash_share: horizon_readback_hash_s / horizon_stage_s,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&rep)?);
        return Ok(());
    }
    let pct = |x: f64| format!("{:.2} %", 100.0 * x);
    let mb = rep.bytes as f64 / 1e6;
    if markdown {
        println!("{}\n", rep.case);
        println!("| measurement | value |");
        println!("|---|---|");
        println!(
            "| `verify`: {} files, {mb:.1} MB, 1 thread | {:.3} s ({:.0} MB/s; a plain read of the same files {:.3} s: {:.2}×) |",
            rep.files,
            rep.verify_s_1t,
            mb / rep.verify_s_1t,
            rep.plain_read_s_1t,
            rep.verify_s_1t / rep.plain_read_s_1t
        );
        println!("| `verify`, all threads | {:.3} s |", rep.verify_s);
        println!(
            "| {} height tiles read checked / plain (1 thread) | {:.3} s / {:.3} s ({:+.1} µs a tile) |",
            rep.tiles,
            rep.heights_checked_s,
            rep.heights_plain_s,
            per_tile * 1e6
        );
        println!(
            "| mip stage (1 thread) {:.2} s: reads' checks / files' hashes (read back at the commit, as before) | {} / {} ({}) |",
            rep.mip_stage_s,
            pct(rep.mip_read_overhead),
            pct(rep.mip_hash_share),
            pct(rep.mip_readback_hash_share)
        );
        println!(
            "| horizon stage (1 thread) {:.2} s, {} tile reads: reads' checks / files' hashes (read back at the commit, as before) | {} / {} ({}) |",
            rep.horizon_stage_s,
            rep.horizon_tiles_read,
            pct(rep.horizon_read_overhead),
            pct(rep.horizon_hash_share),
            pct(rep.horizon_readback_hash_share)
        );
        let p = &rep.mip_hash_parts;
        println!(
            "| mip files' hashes (1 thread): blake3 as written / stamps and records / commit's look-up (read back at the commit, as before) | {:.3} s / {:.3} s / {:.3} s ({:.3} s) |",
            p.blake3_s, p.record_s, p.commit_s, rep.mip_readback_hash_s
        );
    } else {
        println!("{}", rep.case);
        println!(
            "verify: {} files, {mb:.1} MB in {:.3} s on 1 thread ({:.3} s on all); plain read {:.3} s",
            rep.files, rep.verify_s_1t, rep.verify_s, rep.plain_read_s_1t
        );
        println!(
            "height reads: checked {:.3} s, plain {:.3} s ({:+.1} µs a tile)",
            rep.heights_checked_s,
            rep.heights_plain_s,
            per_tile * 1e6
        );
        println!(
            "mip stage {:.2} s: read checks {}, files' hashes {} (read back at the commit: {})",
            rep.mip_stage_s,
            pct(rep.mip_read_overhead),
            pct(rep.mip_hash_share),
            pct(rep.mip_readback_hash_share)
        );
        println!(
            "horizon stage {:.2} s: read checks {}, files' hashes {} (read back at the commit: {})",
            rep.horizon_stage_s,
            pct(rep.horizon_read_overhead),
            pct(rep.horizon_hash_share),
            pct(rep.horizon_readback_hash_share)
        );
        let p = &rep.mip_hash_parts;
        println!(
            "mip files' hashes: blake3 {:.3} s, stamps and records {:.3} s, commit's look-up {:.3} s (read back: {:.3} s)",
            p.blake3_s, p.record_s, p.commit_s, rep.mip_readback_hash_s
        );
    }
    Ok(())
}

/// What the index's hashes of `product`'s files cost the stage that writes them, best of
/// `reps`: for each file, its bytes (read beforehand, not timed: the writer has them in memory)
/// hashed as `write_staged` hashes them, its stamp taken and its record appended to a hash log
/// in `scratch`; then the commit's side: the log read back and every file's record looked up
/// against the file on disk (`writer::index_entries`). The index this yields must be the
/// product's own, with no file read back.
fn recorded_hashes(
    out: &std::path::Path,
    product: &str,
    scratch: &std::path::Path,
    reps: usize,
) -> Result<HashCost> {
    use penumbra::tileset::{fsio, writer, IndexEntry};
    let index: Vec<IndexEntry> = serde_json::from_slice(&std::fs::read(
        out.join(format!(".penumbra/index/{product}.json")),
    )?)?;
    let mut best: Option<HashCost> = None;
    for _ in 0..reps {
        let _ = std::fs::remove_dir_all(scratch);
        let records = fsio::StagedHashes::record_below(scratch);
        let (mut hashing, mut recording) = (Duration::ZERO, Duration::ZERO);
        for IndexEntry(rel, _, _) in &index {
            let p = out.join(rel);
            let bytes = std::fs::read(&p)?;
            let t0 = Instant::now();
            let mut h = blake3::Hasher::new();
            h.update(&bytes);
            let hash = h.finalize();
            let t1 = Instant::now();
            let stamp = fsio::FileStamp::of(&std::fs::metadata(&p)?);
            records.record(rel, stamp, &hash)?;
            let t2 = Instant::now();
            hashing += t1 - t0;
            recording += t2 - t1;
            std::hint::black_box(bytes);
        }
        let t0 = Instant::now();
        let recorded = fsio::read_staged_hashes(scratch);
        let files = index.iter().map(|e| (e.0.clone(), e.1)).collect();
        let (entries, hashed) = writer::index_entries(out, files, &recorded)?;
        let commit = t0.elapsed();
        if hashed != 0 || entries != index {
            bail!("the records of {product}'s files did not give its index ({hashed} read back)");
        }
        let cost = HashCost {
            blake3_s: hashing.as_secs_f64(),
            record_s: recording.as_secs_f64(),
            commit_s: commit.as_secs_f64(),
        };
        if best.as_ref().is_none_or(|b| cost.total() < b.total()) {
            best = Some(cost);
        }
    }
    let _ = std::fs::remove_dir_all(scratch);
    best.context("no repetition")
}

/// What the index's hashes of a product's files cost, in seconds (see [`recorded_hashes`]).
#[derive(Clone, Copy, Serialize)]
struct HashCost {
    /// blake3 of every file's bytes in memory.
    blake3_s: f64,
    /// Each file's stamp taken and its record appended to the log.
    record_s: f64,
    /// The commit's side: the log read back, every file's stamp and record looked up.
    commit_s: f64,
}

impl HashCost {
    fn total(&self) -> f64 {
        self.blake3_s + self.record_s + self.commit_s
    }
}
