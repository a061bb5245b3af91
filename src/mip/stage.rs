//! The mip stage over a tileset (every tile's pyramids, the face pyramids, the manifest entry)
//! and the query of the texel containing a point. Specified in docs/mipmaps.md.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::kernels::{
    f16_down, f16_up, face_pyramid, fmax, fmin, minmax_pyramid_into, nan_if, MinMaxPyramid,
    NEG_INF, POS_INF,
};
use crate::cube::Face;
use crate::error::{Error, Result};
use crate::format::mip::{
    face_chunk_path, face_path, tile_paths, write_mip_exr, Precision, FACE_CHUNK_PATTERN,
    FACE_CHUNK_TILES, FACE_PATTERN, MAX_PATTERN, MINMAX_PATTERN, MIP_FORMAT, TEXEL_CONVENTION,
};
use crate::format::mip::{FACE_CHUNK_ID, FACE_ID, MAX_ID, MINMAX_ID};
use crate::format::{Identity, KeyBasis, TileCompression};
use crate::layout::TileId;
use crate::manifest::{self, MipLevelRange, MipProduct, Tileset};
use crate::progress::Progress;
use crate::runner::{self, Cx, Finished, Reads, Select, Stage, StageSpec, Unit};
use crate::tileset::{Product, Store};

// ---------------------------------------------------------------------------------------------
// Stage

/// What the user chose.
#[derive(Clone, Debug, Serialize)]
pub struct MipOptions {
    pub precision: Precision,
    pub compression: TileCompression,
    /// Tiles per side of a face-pyramid chunk, a power of two: [`FACE_CHUNK_TILES`]. Only tests
    /// lower it (to chunk the faces of a small tileset); not part of the run key.
    #[doc(hidden)]
    #[serde(skip)]
    pub face_chunk_tiles: u32,
    /// Refuse a run whose pyramids would exceed this many GiB before compression (changes no
    /// byte of the output, so not part of the run key).
    #[serde(skip)]
    pub max_output_gib: f64,
}

impl Default for MipOptions {
    fn default() -> Self {
        MipOptions {
            precision: Precision::default(),
            compression: TileCompression::default(),
            face_chunk_tiles: FACE_CHUNK_TILES,
            max_output_gib: runner::DEFAULT_MAX_OUTPUT_GIB,
        }
    }
}

/// Refuse a run whose tile pyramids (max, and min + max; 4/3 of the level-0 texels) would
/// exceed the output cap before compression.
fn check_output_size(opts: &MipOptions, ts: &Tileset) -> Result<()> {
    runner::check_output_cap("max_output_gib", opts.max_output_gib)?;
    let n = ts.layout.tile_size as f64;
    let bytes = match opts.precision {
        Precision::F32 => 4.0,
        Precision::F16 => 2.0,
    };
    let tiles: u64 = ts.coverage.iter().map(|c| c.tiles).sum();
    let gib = tiles as f64 * n * n * 4.0 / 3.0 * 3.0 * bytes / (1u64 << 30) as f64;
    if gib > opts.max_output_gib {
        return Err(Error::param(
            "max_output_gib",
            format!(
                "is {}, but the mipmaps of {tiles} tiles would write {gib:.3} GiB before \
                 compression: raise the cap",
                opts.max_output_gib
            ),
        ));
    }
    Ok(())
}

/// What a run did.
#[derive(Clone, Debug, Serialize)]
pub struct MipReport {
    pub out: PathBuf,
    pub tiles: u64,
    pub tiles_written: u64,
    pub tiles_kept: u64,
    pub face_pyramids: u64,
    /// Chunk files of the face pyramids of faces with more tiles per side than a chunk.
    pub face_chunks: u64,
    pub precision: Precision,
    pub global_min_m: f64,
    pub global_max_m: f64,
    /// Height samples read (halos included) × 4 bytes.
    pub input_bytes: u64,
    pub up_to_date: bool,
}

fn nan_to_none(v: f32) -> Option<f64> {
    (!v.is_nan()).then_some(v as f64)
}

/// The mip stage writes the max and (min, max) pyramids of the height tiles.
pub const STAGE: StageSpec = StageSpec {
    name: "mip",
    writes: Cow::Borrowed(&[Product::Mip]),
    reads: Cow::Borrowed(&[Product::Height]),
    format: Cow::Borrowed(&[MIP_FORMAT]),
};

/// Refuse what the mip stage cannot build from.
fn check_tileset(dir: &Path, ts: &Tileset) -> Result<()> {
    let manifest_path = dir.join(manifest::MANIFEST);
    if ts.products.height.is_none() {
        return Err(Error::invalid(
            &manifest_path,
            "tileset has no height product to build mipmaps from",
        ));
    }
    if ts.layout.halo < 1 {
        return Err(Error::unsupported(
            &manifest_path,
            "mipmaps need a halo of at least 1 pixel: retile with a halo of 1 or more",
        ));
    }
    Ok(())
}

/// Build every mip product of the tileset in `dir` and record them in its manifest.
pub fn build_mips(dir: &Path, opts: &MipOptions, progress: &dyn Progress) -> Result<MipReport> {
    runner::execute(&MipStage::new(opts.clone()), dir, &Select::All, progress)?.into_report("mip")
}

/// The mip stage as units: one per height tile (its max and (min, max) pyramids), then the
/// face pyramids of the tiles' extrema.
pub struct MipStage {
    pub opts: MipOptions,
}

impl MipStage {
    pub fn new(opts: MipOptions) -> MipStage {
        MipStage { opts }
    }

    /// What the run key hashes besides the height tiles' run key: the height pattern and the
    /// options as JSON.
    fn basis(&self, plan: &MipPlan) -> KeyBasis {
        runner::key_basis(
            &STAGE,
            vec![
                plan.height_path.clone(),
                serde_json::to_string(&self.opts).unwrap_or_default(),
            ],
        )
    }
}

/// What a mip run knows once the tileset is checked.
pub struct MipPlan {
    height_path: String,
    /// Tile size, stored size, halo.
    n: usize,
    s: usize,
    halo: usize,
}

/// A tile's extrema as its files hold them (bits: NaN when the tile is no data).
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct TileTop {
    lo: u32,
    hi: u32,
}

impl Stage for MipStage {
    type Plan = MipPlan;
    type Done = TileTop;
    type Scratch = MinMaxPyramid;
    type Report = MipReport;

    fn spec(&self) -> StageSpec {
        STAGE
    }

    fn check(&self) -> Result<()> {
        let chunk = self.opts.face_chunk_tiles;
        if !chunk.is_power_of_two() || chunk < 2 {
            return Err(Error::usage(format!(
                "face-pyramid chunks of {chunk} tiles per side: not a power of two of at least 2"
            )));
        }
        Ok(())
    }

    fn plan(&self, dir: &Path, ts: &Tileset) -> Result<MipPlan> {
        check_tileset(dir, ts)?;
        check_output_size(&self.opts, ts)?;
        let lay = ts.layout;
        Ok(MipPlan {
            height_path: ts.products.height.as_ref().expect("checked").path.clone(),
            n: lay.tile_size as usize,
            s: lay.stored_size(),
            halo: lay.halo as usize,
        })
    }

    fn key(&self, ts: &Tileset, plan: &MipPlan) -> String {
        self.basis(plan).key(&[&ts.run_key])
    }

    fn units(&self, ts: &Tileset, plan: &MipPlan) -> Result<Vec<Unit>> {
        Ok(ts
            .tile_set()
            .into_iter()
            .map(|id| {
                let reads = vec![Reads::Tile {
                    product: Product::Height,
                    tile: id,
                }];
                Unit::tile(id, reads, (plan.s * plan.s) as f64)
            })
            .collect())
    }

    fn scratch(&self, plan: &MipPlan) -> MinMaxPyramid {
        // One pyramid per worker, reused from tile to tile: fresh level buffers would cost a
        // page fault per 4 KiB written, more than computing the pyramid.
        MinMaxPyramid::new(plan.n)
    }

    fn run_unit(&self, cx: &Cx<MipPlan>, unit: &Unit, p: &mut MinMaxPyramid) -> Result<TileTop> {
        let (lo, hi) = mip_tile(cx.store, cx.out, unit.tile, cx.plan, &self.opts, p, cx.key)?;
        Ok(TileTop {
            lo: lo.to_bits(),
            hi: hi.to_bits(),
        })
    }

    fn finish(
        &self,
        cx: &Cx<MipPlan>,
        done: Vec<Finished<TileTop>>,
    ) -> Result<(Tileset, MipReport)> {
        let (opts, out, ts) = (&self.opts, cx.out, cx.store.manifest());
        let cx_key = cx.key;
        let lay = ts.layout;
        let manifest_path = cx.store.manifest_path();
        let tile_bytes = (cx.plan.s * cx.plan.s * 4) as u64;
        let mut tops = BTreeMap::new();
        let (mut written, mut kept) = (0u64, 0u64);
        for f in &done {
            if f.here {
                written += 1;
            } else {
                kept += 1;
            }
            tops.insert(
                f.unit.tile,
                (f32::from_bits(f.done.lo), f32::from_bits(f.done.hi)),
            );
        }

        // Face pyramids of whole-tile extrema, and per-level and global ranges. A face of at
        // most `chunk` tiles per side is one file; a larger one is cut into chunks of `chunk`²
        // tiles, built one at a time from the tiles present, and a file of the chunks' extrema
        // above them: nothing here grows with the number of tiles per side.
        let chunk = opts.face_chunk_tiles as usize;
        let mut ranges = Vec::new();
        let (mut face_pyramids, mut face_chunks) = (0u64, 0u64);
        let mut chunked = false;
        let (mut gmin, mut gmax) = (POS_INF, NEG_INF);
        for level in 0..lay.levels {
            let g = lay.tiles_per_side(level) as usize;
            let (mut lmin, mut lmax) = (POS_INF, NEG_INF);
            for face in Face::ALL {
                let on_face = tops.range(
                    TileId {
                        level,
                        face,
                        x: 0,
                        y: 0,
                    }..=TileId {
                        level,
                        face,
                        x: u32::MAX,
                        y: u32::MAX,
                    },
                );
                let top = if g <= chunk {
                    let mut lo = vec![f32::NAN; g * g];
                    let mut hi = vec![f32::NAN; g * g];
                    let mut any = false;
                    for (id, &(a, b)) in on_face {
                        let k = id.y as usize * g + id.x as usize;
                        lo[k] = a;
                        hi[k] = b;
                        any = true;
                    }
                    if !any {
                        continue;
                    }
                    write_face_pyramid(
                        &face_path(out, level, face),
                        &Identity::face(FACE_ID, level, face, 0, 0, cx_key),
                        g,
                        lo,
                        hi,
                        opts,
                    )?
                } else {
                    let mut chunks: BTreeMap<(usize, usize), Vec<ChunkTile>> = BTreeMap::new();
                    for (id, &(a, b)) in on_face {
                        let (x, y) = (id.x as usize, id.y as usize);
                        chunks.entry((y / chunk, x / chunk)).or_default().push((
                            (y % chunk) * chunk + x % chunk,
                            a,
                            b,
                        ));
                    }
                    if chunks.is_empty() {
                        continue;
                    }
                    let nc = g / chunk;
                    let mut clo = vec![f32::NAN; nc * nc];
                    let mut chi = vec![f32::NAN; nc * nc];
                    for ((cy, cx), list) in chunks {
                        let mut lo = vec![f32::NAN; chunk * chunk];
                        let mut hi = vec![f32::NAN; chunk * chunk];
                        for (k, a, b) in list {
                            lo[k] = a;
                            hi[k] = b;
                        }
                        let path = face_chunk_path(out, level, face, cx as u32, cy as u32);
                        let id = Identity::face(
                            FACE_CHUNK_ID,
                            level,
                            face,
                            cx as u32,
                            cy as u32,
                            cx_key,
                        );
                        let (a, b) = write_face_pyramid(&path, &id, chunk, lo, hi, opts)?;
                        clo[cy * nc + cx] = a;
                        chi[cy * nc + cx] = b;
                        face_chunks += 1;
                    }
                    chunked = true;
                    write_face_pyramid(
                        &face_path(out, level, face),
                        &Identity::face(FACE_ID, level, face, 0, 0, cx_key),
                        nc,
                        clo,
                        chi,
                        opts,
                    )?
                };
                lmin = fmin(lmin, top.0);
                lmax = fmax(lmax, top.1);
                face_pyramids += 1;
            }
            gmin = fmin(gmin, lmin);
            gmax = fmax(gmax, lmax);
            ranges.push(MipLevelRange {
                level,
                min_m: nan_to_none(nan_if(lmin, POS_INF)),
                max_m: nan_to_none(nan_if(lmax, NEG_INF)),
            });
        }
        if !(gmin.is_finite() && gmax.is_finite()) {
            return Err(Error::invalid(
                &manifest_path,
                "every height tile is no data: nothing to build mipmaps from",
            ));
        }
        let product = MipProduct {
            products: vec!["max".into(), "minmax".into()],
            max_path: MAX_PATTERN.into(),
            max_channels: vec!["max".into()],
            minmax_path: MINMAX_PATTERN.into(),
            minmax_channels: vec!["min".into(), "max".into()],
            face_path: FACE_PATTERN.into(),
            face_chunk_path: chunked.then(|| FACE_CHUNK_PATTERN.into()),
            face_chunk_tiles: chunked.then_some(chunk as u32),
            precision: opts.precision,
            face_precision: Precision::F32,
            level_rounding: "up".into(),
            texel: TEXEL_CONVENTION.into(),
            global_min_m: gmin as f64,
            global_max_m: gmax as f64,
            levels: ranges,
            run_key: cx.key.to_string(),
            run_key_basis: Some(self.basis(cx.plan)),
        };
        let (gmin, gmax) = (product.global_min_m, product.global_max_m);
        let mut manifest = ts.clone();
        manifest.products.mip = Some(product);
        let report = MipReport {
            out: cx.store.dir().to_path_buf(),
            tiles: done.len() as u64,
            tiles_written: written,
            tiles_kept: kept,
            face_pyramids,
            face_chunks,
            precision: opts.precision,
            global_min_m: gmin,
            global_max_m: gmax,
            input_bytes: written * tile_bytes,
            up_to_date: false,
        };
        Ok((manifest, report))
    }

    fn up_to_date(&self, store: &Store, _plan: &MipPlan, units: &[Unit]) -> MipReport {
        let m = store.manifest().products.mip.as_ref().expect("up to date");
        MipReport {
            out: store.dir().to_path_buf(),
            tiles: units.len() as u64,
            tiles_written: 0,
            tiles_kept: units.len() as u64,
            face_pyramids: 0,
            face_chunks: 0,
            precision: self.opts.precision,
            global_min_m: m.global_min_m,
            global_max_m: m.global_max_m,
            input_bytes: 0,
            up_to_date: true,
        }
    }
}

/// A tile of a face-pyramid chunk: (index in the chunk's grid, min, max); chunks are keyed by
/// (cy, cx).
type ChunkTile = (usize, f32, f32);

/// Reduce a `g`² grid of whole-tile (min, max) to its pyramid and write it (always f32);
/// the pyramid's 1×1 (min, max).
fn write_face_pyramid(
    path: &Path,
    identity: &Identity,
    g: usize,
    lo: Vec<f32>,
    hi: Vec<f32>,
    opts: &MipOptions,
) -> Result<(f32, f32)> {
    let p = face_pyramid(g, lo, hi);
    write_mip_exr(
        path,
        g,
        Some(&p.min),
        &p.max,
        Precision::F32,
        opts.compression,
        "penumbra-face-minmax",
        Some(identity),
    )?;
    Ok(p.top())
}

/// One tile: its files, and its (1×1 min, 1×1 max) as the files hold them.
fn mip_tile(
    store: &Store,
    out: &Path,
    id: TileId,
    plan: &MipPlan,
    opts: &MipOptions,
    p: &mut MinMaxPyramid,
    key: &str,
) -> Result<(f32, f32)> {
    let (n, s, halo) = (plan.n, plan.s, plan.halo);
    let (pmax, pmm) = tile_paths(out, id);
    let t = store.read_height(id)?;
    minmax_pyramid_into(&t.height, s, halo, p)?;
    write_mip_exr(
        &pmax,
        n,
        None,
        &p.max,
        opts.precision,
        opts.compression,
        "penumbra-maxmip",
        Some(&Identity::tile(MAX_ID, id, key)),
    )?;
    write_mip_exr(
        &pmm,
        n,
        Some(&p.min),
        &p.max,
        opts.precision,
        opts.compression,
        "penumbra-minmax",
        Some(&Identity::tile(MINMAX_ID, id, key)),
    )?;
    let (lo, hi) = p.top();
    // f16 files hold rounded bounds: the face pyramid uses the same rounded values.
    Ok(match opts.precision {
        Precision::F32 => (lo, hi),
        Precision::F16 => (f16_down(lo).to_f32(), f16_up(hi).to_f32()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mip entry written before `run_key_basis` was recorded is checked against the options
    /// text `manifest::consistency` rebuilds: the one this stage hashes.
    #[test]
    fn the_legacy_key_check_hashes_the_stages_options() {
        for precision in [Precision::F32, Precision::F16] {
            for compression in [TileCompression::Zip, TileCompression::None] {
                let opts = MipOptions {
                    precision,
                    compression,
                    ..MipOptions::default()
                };
                assert_eq!(
                    serde_json::to_string(&opts).unwrap(),
                    crate::manifest::consistency::legacy_mip_options(precision, compression)
                );
            }
        }
    }
}
