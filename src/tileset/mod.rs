//! The tileset store: the one place that opens and validates `tileset.json`, knows where every
//! product's files live, reads them back checked (with a bounded cache shared by the stages
//! that read many tiles), and writes through one writer per tileset.
//!
//! - [`Product`]: the registry of products, the folders each owns and the products each is
//!   derived from; invalidation downstream of a changed product is derived from it.
//! - [`Store`]: the read API (`open` validates the manifest; typed, size-checked tile reads).
//! - [`writer::Writer`]: the writer lock, staging of a run's files beside the tileset, and the
//!   commit that swaps them in (crash-safe, rolled forward by the next writer).
//! - [`copy::copy_tileset`]: a copy that reads as the original (linked where it can be),
//!   checked against its indexes.
//! - [`crate::fsio`]: atomic, durable file writes; [`lock`]: the advisory locks; [`crate::manifest::validate`]: the
//!   manifest's limits.

pub mod cache;
pub mod copy;
pub mod deps;
pub mod index;
pub use crate::fsio;

pub mod lock;

pub mod verify;
pub mod writer;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::error::{Error, IoContext, Result};
use crate::format::{self, height::HeightTile};
use crate::layout::TileId;
use crate::manifest::{Tileset, MANIFEST};

pub use cache::TileCache;
pub use index::{Index, IndexEntry};
pub use lock::STATE_DIR;

/// The products a tileset can hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Product {
    /// Height tiles (`height/`), written by the tiling stage.
    Height,
    /// Albedo tiles (`albedo/`), written by the tiling stage beside the heights.
    Albedo,
    /// Maximum and (min, max) mipmaps of the height tiles.
    Mip,
    /// Raw horizon maps.
    Horizon,
    /// Fourier-compressed horizon pyramids (from the raw maps, or streamed from the horizon
    /// stage).
    Fourier,
    /// A product this registry does not list, defined where its stage is (a plug-in or a
    /// test): its manifest entry is `products.<name>` (with a `run_key`), and the store
    /// stamps it with the folders it owns and the products it reads, so that a later writer
    /// invalidates it as it does the products above (docs/architecture.md, "How to add a
    /// product format").
    Other(&'static ProductDef),
}

/// What the store needs to know of a product it does not list.
#[derive(Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ProductDef {
    /// Its name: the key of its manifest entry and of its index.
    pub name: &'static str,
    /// The top-level folders it owns (plain names).
    pub dirs: &'static [&'static str],
    /// The products it is computed from.
    pub reads: &'static [Product],
}

impl serde::Serialize for Product {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl Product {
    pub const ALL: [Product; 5] = [
        Product::Height,
        Product::Albedo,
        Product::Mip,
        Product::Horizon,
        Product::Fourier,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Product::Height => "height",
            Product::Albedo => "albedo",
            Product::Mip => "mip",
            Product::Horizon => "horizon",
            Product::Fourier => "fourier",
            Product::Other(d) => d.name,
        }
    }

    /// Top-level folders of the tileset that hold this product's files (and nothing else).
    pub fn dirs(self) -> &'static [&'static str] {
        match self {
            Product::Height => &["height"],
            Product::Albedo => &["albedo"],
            Product::Mip => &["maxmip", "minmax"],
            Product::Horizon => &["horizon"],
            Product::Fourier => &["fourier"],
            Product::Other(d) => d.dirs,
        }
    }

    /// Products this one is computed from: when one of them changes, this one is stale.
    pub fn reads(self) -> &'static [Product] {
        match self {
            Product::Height | Product::Albedo => &[],
            Product::Mip => &[Product::Height],
            // The horizon's search distance uses the mipmaps' global extrema when present.
            Product::Horizon => &[Product::Height, Product::Mip],
            // Streamed pyramids depend on what the horizons do; pyramids made from stored raw
            // maps on those maps. Either way a new horizon run makes them stale.
            Product::Fourier => &[Product::Height, Product::Mip, Product::Horizon],
            Product::Other(d) => d.reads,
        }
    }

    /// Every product derived, directly or not, from one of `changed` (not including them).
    pub fn downstream(changed: &[Product]) -> Vec<Product> {
        let mut out: Vec<Product> = Vec::new();
        loop {
            let before = out.len();
            for p in Product::ALL {
                if changed.contains(&p) || out.contains(&p) {
                    continue;
                }
                if p.reads()
                    .iter()
                    .any(|r| changed.contains(r) || out.contains(r))
                {
                    out.push(p);
                }
            }
            if out.len() == before {
                out.sort();
                return out;
            }
        }
    }

    /// The run key the manifest records for this product, if it holds it.
    pub fn recorded_key(self, ts: &Tileset) -> Option<&str> {
        match self {
            Product::Height => ts.products.height.as_ref().map(|_| ts.run_key.as_str()),
            Product::Albedo => ts.products.albedo.as_ref().map(|_| ts.run_key.as_str()),
            Product::Mip => ts.products.mip.as_ref().map(|m| m.run_key.as_str()),
            Product::Horizon => ts.products.horizon.as_ref().map(|h| h.run_key.as_str()),
            Product::Fourier => ts.products.fourier.as_ref().map(|f| f.run_key.as_str()),
            Product::Other(d) => ts
                .products
                .extra
                .get(d.name)
                .and_then(|e| e.get("run_key"))
                .and_then(|k| k.as_str()),
        }
    }

    /// Drop this product's entry from a manifest.
    pub fn clear(self, ts: &mut Tileset) {
        match self {
            Product::Height => ts.products.height = None,
            Product::Albedo => ts.products.albedo = None,
            Product::Mip => ts.products.mip = None,
            Product::Horizon => ts.products.horizon = None,
            Product::Fourier => ts.products.fourier = None,
            Product::Other(d) => {
                ts.products.extra.remove(d.name);
            }
        }
    }
}

pub use crate::format::{face_chunk_file_path, face_file_path, tile_path};

/// A bookkeeping file of the tileset in `dir` (`.penumbra/<name>`, e.g. a scene's stamp) as
/// stored, when it is there and reads back within `cap` bytes.
pub fn read_state_file(dir: &Path, name: &str, cap: u64) -> Option<Vec<u8>> {
    fsio::read_capped(
        &dir.join(STATE_DIR).join(name),
        cap,
        "a tileset's bookkeeping file",
    )
    .ok()
}

/// The blake3 (hex) of the manifest of the tileset in `dir` as stored; None when there is
/// none readable.
pub fn manifest_hash(dir: &Path) -> Option<String> {
    let bytes = fsio::read_capped(
        &dir.join(MANIFEST),
        crate::manifest::MAX_MANIFEST_BYTES,
        "a tileset manifest",
    )
    .ok()?;
    Some(blake3::hash(&bytes).to_hex().to_string())
}

/// Default byte budget of a store's height-tile cache.
pub const DEFAULT_CACHE_BYTES: u64 = 1 << 30;

/// An open, validated tileset.
pub struct Store {
    dir: PathBuf,
    ts: Tileset,
    cache: TileCache,
    /// Each product's index, read on the first read of one of its files.
    indexes: std::sync::Mutex<std::collections::HashMap<&'static str, Option<Arc<Index>>>>,
    /// What the unit running now reads ([`deps`]).
    deps: deps::Recorder,
    _reader: Option<lock::CommitLock>,
}

impl Store {
    /// Open the tileset in `dir` for reading: waits while a writer commits, validates the
    /// manifest (exit-2 errors name the file and the field).
    pub fn open(dir: &Path) -> Result<Store> {
        let reader = lock::CommitLock::shared(dir)?;
        let mut s = Store::open_unlocked(dir)?;
        s._reader = Some(reader);
        Ok(s)
    }

    /// Open without the reader's lock: for a writer that holds the tileset's writer lock
    /// (nobody else can commit) and reads what earlier stages committed.
    pub fn open_unlocked(dir: &Path) -> Result<Store> {
        let ts = Tileset::load(dir)?;
        let cache = TileCache::new(DEFAULT_CACHE_BYTES, ts.layout.stored_size());
        Ok(Store {
            dir: dir.to_path_buf(),
            ts,
            cache,
            indexes: Default::default(),
            deps: Default::default(),
            _reader: None,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn manifest(&self) -> &Tileset {
        &self.ts
    }

    pub fn manifest_path(&self) -> PathBuf {
        self.dir.join(MANIFEST)
    }

    /// An error about the manifest that says what is missing and what to run.
    pub fn missing(&self, what: &str) -> Error {
        Error::invalid(self.manifest_path(), what.to_string())
    }

    /// Path of a height tile.
    pub fn height_path(&self, id: TileId) -> Result<PathBuf> {
        let h = self
            .ts
            .products
            .height
            .as_ref()
            .ok_or_else(|| self.missing("tileset has no height product"))?;
        Ok(tile_path(&self.dir, &h.path, id))
    }

    /// The index of `product`, read once (None: the product has none).
    pub fn index(&self, product: Product) -> Result<Option<Arc<Index>>> {
        let mut m = self.indexes.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(ix) = m.get(product.name()) {
            return Ok(ix.clone());
        }
        let ix = Index::load(&self.dir, product.name())?.map(Arc::new);
        m.insert(product.name(), ix.clone());
        Ok(ix)
    }

    /// The recorder of what the unit running now reads ([`deps`]).
    pub fn deps(&self) -> &deps::Recorder {
        &self.deps
    }

    /// Note, for the unit running now, that it read (or looked for) the file of `product` at
    /// `path`: with the blake3 its index records, None where there is none.
    pub fn note_file(&self, product: Product, path: &Path) {
        if !self.deps.active() {
            return;
        }
        let rel = path
            .strip_prefix(&self.dir)
            .map(|r| r.to_string_lossy().replace('\\', "/"))
            .unwrap_or_default();
        let blake3 = self.index(product).ok().flatten().and_then(|ix| {
            ix.files
                .get(&rel)
                .map(|(_, h)| blake3::Hash::from(*h).to_hex().to_string())
        });
        self.deps.note(deps::Dep::File {
            product: product.name().to_string(),
            rel,
            blake3,
        });
    }

    /// Whether the tileset holds tile `id`, noted for the unit running now when it does not
    /// (when it does, reading the tile notes its file).
    pub fn has_tile(&self, id: TileId) -> bool {
        let has = self.ts.has_tile(id);
        if !has && self.deps.active() {
            self.deps.note(deps::Dep::Absent { tile: id });
        }
        has
    }

    /// Whether `dep`, recorded by an earlier run, holds for this tileset (a value only its
    /// stage can recompute: None).
    pub fn dep_holds(&self, dep: &deps::Dep) -> Option<bool> {
        match dep {
            deps::Dep::File {
                product,
                rel,
                blake3,
            } => {
                let p = Product::ALL.iter().find(|p| p.name() == product)?;
                let now = match self.index(*p) {
                    Ok(Some(ix)) => ix
                        .files
                        .get(rel)
                        .map(|(_, h)| blake3::Hash::from(*h).to_hex().to_string()),
                    Ok(None) => None,
                    Err(_) => return Some(false),
                };
                Some(now == *blake3)
            }
            deps::Dep::Absent { tile } => Some(!self.ts.has_tile(*tile)),
            deps::Dep::Value { .. } => None,
        }
    }

    /// Read a file of `product` whole, bounded before the read starts: a regular file, inside
    /// the tileset, of the size its index recorded (or at most `cap` bytes when the product has
    /// no index), and then of the blake3 the index recorded. `what` names the file's kind.
    pub fn read_product_file(
        &self,
        product: Product,
        path: &Path,
        cap: u64,
        what: &str,
    ) -> Result<Vec<u8>> {
        self.note_file(product, path);
        let index = self.index(product)?;
        let rel = path
            .strip_prefix(&self.dir)
            .map(|r| r.to_string_lossy().replace('\\', "/"))
            .unwrap_or_default();
        let entry = match &index {
            Some(ix) => match ix.files.get(&rel) {
                Some(e) => Some(*e),
                None => {
                    // Absent altogether: the error the open gives (not found).
                    std::fs::symlink_metadata(path).at(path)?;
                    return Err(Error::invalid(
                        path,
                        format!(
                            "is not listed in the tileset's index {}: it is not a file the \
                             stage wrote; delete it (or rerun the stage that makes {})",
                            ix.path.display(),
                            product.name()
                        ),
                    ));
                }
            },
            None => None,
        };
        let expect = match entry {
            Some((len, _)) => fsio::Expect::Exactly(len),
            None => fsio::Expect::AtMost(cap),
        };
        let bytes = fsio::read_product_file(&self.dir, path, expect, what)?;
        if let Some((_, hash)) = entry {
            if blake3::hash(&bytes).as_bytes() != &hash {
                return Err(Error::invalid(
                    path,
                    format!(
                        "its bytes differ from the blake3 the tileset's index recorded: the \
                         file is damaged or was replaced; delete it and rerun the stage that \
                         makes {} (`penumbra verify DIR` checks every file)",
                        product.name()
                    ),
                ));
            }
        }
        Ok(bytes)
    }

    /// Read a height tile (uncached), checking it against the index (size, hash), its identity,
    /// its channels and its size against the manifest.
    pub fn read_height(&self, id: TileId) -> Result<HeightTile> {
        let p = self.height_path(id)?;
        let s = self.ts.layout.stored_size();
        let bytes = self.read_product_file(
            Product::Height,
            &p,
            format::height::max_file_bytes(s),
            "a height tile",
        )?;
        let expected = format::Identity::tile(format::height::ID, id, &self.ts.run_key);
        let labels = self
            .ts
            .products
            .height
            .as_ref()
            .map(format::height::labels)
            .unwrap_or_default();
        let t = format::height::decode_height_tile_as(&bytes, &expected, &labels)
            .map_err(|e| Error::invalid(&p, e))?;
        if t.size != s {
            return Err(Error::invalid(
                &p,
                format!("tile is {}² but the manifest says {s}²", t.size),
            ));
        }
        Ok(t)
    }

    /// The height tile `id` through the shared cache, or None where the tileset has none.
    pub fn height(&self, id: TileId) -> Result<Option<Arc<HeightTile>>> {
        if self.deps.active() {
            // Noted on every call: a tile another unit left in the cache is read here too.
            if self.has_tile(id) {
                self.note_file(Product::Height, &self.height_path(id)?);
            }
        }
        self.cache.get_or_load(id, || {
            if self.ts.has_tile(id) {
                self.read_height(id).map(Some)
            } else {
                Ok(None)
            }
        })
    }

    /// A tile's (min, max) mipmap, checked against the index, its identity, the manifest's
    /// channels and precision, and the tile size (`max`: the one-channel maximum pyramid
    /// instead).
    pub fn mip(&self, id: TileId, max: bool) -> Result<format::mip::MipFile> {
        let m =
            self.ts.products.mip.as_ref().ok_or_else(|| {
                self.missing("tileset has no mipmaps: build them with the mip stage")
            })?;
        let p = tile_path(
            &self.dir,
            if max { &m.max_path } else { &m.minmax_path },
            id,
        );
        let n = self.ts.layout.tile_size as usize;
        let bytes = self.read_product_file(
            Product::Mip,
            &p,
            format::mip::max_file_bytes(n, if max { 1 } else { 2 }),
            "a mipmap file",
        )?;
        let name = if max {
            format::mip::MAX_ID
        } else {
            format::mip::MINMAX_ID
        };
        let expected = format::Identity::tile(name, id, &m.run_key);
        let kind = if max {
            format::mip::MipKind::Max
        } else {
            format::mip::MipKind::MinMax
        };
        let labels = format::mip::labels(m, kind);
        let f = format::mip::decode_mip_exr_as(&bytes, &expected, &labels).map_err(|msg| {
            Error::invalid(&p, format!("{msg}; delete it and rerun `penumbra mip`"))
        })?;
        if f.sizes.first() != Some(&n) {
            return Err(Error::invalid(
                &p,
                format!("mipmap is {:?}² but tiles are {n}²", f.sizes.first()),
            ));
        }
        Ok(f)
    }

    /// The face pyramid file `path` of tile level `level` and `face` (`chunk`: the chunk
    /// (cx, cy) it is), checked against the index, its identity and the manifest's channels and
    /// `face_precision`.
    pub fn face_mip(
        &self,
        path: &Path,
        level: u8,
        face: crate::cube::Face,
        chunk: Option<(u32, u32)>,
    ) -> Result<format::mip::MipFile> {
        let m =
            self.ts.products.mip.as_ref().ok_or_else(|| {
                self.missing("tileset has no mipmaps: build them with the mip stage")
            })?;
        let (name, (x, y)) = match chunk {
            Some(c) => (format::mip::FACE_CHUNK_ID, c),
            None => (format::mip::FACE_ID, (0, 0)),
        };
        let side = match chunk {
            Some(_) => m.face_chunk_tiles.unwrap_or(1024) as usize,
            None => self.ts.layout.tiles_per_side(level) as usize,
        };
        let bytes = self.read_product_file(
            Product::Mip,
            path,
            format::mip::max_file_bytes(side, 2),
            "a face pyramid",
        )?;
        let expected = format::Identity::face(name, level, face, x, y, &m.run_key);
        let labels = format::mip::labels(m, format::mip::MipKind::Face);
        format::mip::decode_mip_exr_as(&bytes, &expected, &labels).map_err(|msg| {
            Error::invalid(path, format!("{msg}; delete it and rerun `penumbra mip`"))
        })
    }

    /// A tile's Fourier pyramid, checked against the index, its identity, the manifest (tile
    /// size, azimuths, encoding, layout, sigma, coefficients) and its checksum.
    pub fn fourier(&self, id: TileId) -> Result<format::fourier::Pyramid> {
        let f = self.ts.products.fourier.as_ref().ok_or_else(|| {
            self.missing(
                "tileset has no Fourier pyramids: make them with `penumbra fourier` or \
                 `penumbra horizon --fourier`",
            )
        })?;
        let p = tile_path(&self.dir, &f.path, id);
        let n = self.ts.layout.tile_size as usize;
        let bytes = self.read_product_file(
            Product::Fourier,
            &p,
            format::fourier::max_file_bytes(n, f.azimuths),
            "a Fourier pyramid",
        )?;
        let expected = format::Identity::tile(format::fourier::ID, id, &f.run_key);
        let pyramid = format::fourier::Pyramid::decode_as(&bytes, &p, n, f.azimuths, &expected)?;
        format::fourier::check_labels(&pyramid.labels(), f, id)
            .map_err(|m| Error::invalid(&p, m))?;
        Ok(pyramid)
    }

    /// A tile's raw horizon maps (`A` planes of n² elevations, degrees), checked against the
    /// index, its identity and the manifest's channel, precision and azimuth count.
    pub fn horizon(&self, id: TileId) -> Result<Vec<f32>> {
        let h = self.ts.products.horizon.as_ref().ok_or_else(|| {
            self.missing("tileset has no horizon maps: compute them with the horizon stage")
        })?;
        if let Some((t, b)) = h.pruned_tile(id) {
            return Err(Error::usage(format!(
                "tile {id} has no horizon maps: the run left it out, its horizon never rising \
                 above {b}° (below the {t}° it was given: a scene's lowest sun less the sun's \
                 radius); it is fully lit for suns whose lower limb is at or above {t}°"
            )));
        }
        let p = tile_path(&self.dir, &h.path, id);
        let n = self.ts.layout.tile_size as usize;
        let bytes = self.read_product_file(
            Product::Horizon,
            &p,
            format::horizon::max_file_bytes(n, h.azimuths),
            "a horizon map",
        )?;
        let expected = format::Identity::tile(format::horizon::ID, id, &h.run_key);
        let labels = format::horizon::labels(h);
        let (a, planes) = format::horizon::decode_horizon_exr_as(&bytes, n, &expected, &labels)
            .map_err(|msg| {
                Error::invalid(&p, format!("{msg}; delete it and rerun `penumbra horizon`"))
            })?;
        if a != h.azimuths {
            return Err(Error::invalid(
                &p,
                format!("holds {a} azimuths, the manifest says {}", h.azimuths),
            ));
        }
        Ok(planes)
    }

    /// A tile's albedo (halo included), checked against the index, its identity, the manifest's
    /// bit depth and channels and the tile size; None where the tileset has no albedo tile
    /// (no albedo product, or no data in the tile).
    pub fn albedo(&self, id: TileId) -> Result<Option<format::albedo::AlbedoTile>> {
        let Some(a) = self.ts.products.albedo.as_ref() else {
            return Ok(None);
        };
        if !self.ts.has_tile(id) {
            return Ok(None);
        }
        let p = tile_path(&self.dir, &a.path, id);
        let s = self.ts.layout.stored_size();
        let bytes = self.read_product_file(
            Product::Albedo,
            &p,
            format::albedo::max_file_bytes(s),
            "an albedo tile",
        )?;
        let expected = format::Identity::tile(format::albedo::ID, id, &self.ts.run_key);
        format::albedo::decode_albedo_tile_as(&bytes, &expected, a, s)
            .map(Some)
            .map_err(|m| Error::invalid(&p, m))
    }

    /// The shared height-tile cache (for stages that manage its budget).
    pub fn cache(&self) -> &TileCache {
        &self.cache
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The formats layer's list of product folders is the registry's.
    #[test]
    fn listed_dirs_are_the_registrys() {
        let dirs: Vec<&str> = Product::ALL
            .iter()
            .flat_map(|p| p.dirs().iter().copied())
            .collect();
        assert_eq!(dirs, crate::format::LISTED_DIRS);
    }
}
