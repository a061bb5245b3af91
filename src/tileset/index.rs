//! A product's index (`.penumbra/index/<product>.json`): every file of the product as the
//! commit found it, with its size and blake3. The writer makes it ([`super::writer`]); readers
//! bound each read by the recorded size and check the recorded hash ([`super::Store`]);
//! `penumbra verify` checks every file against it ([`super::verify`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::lock::STATE_DIR;
use crate::error::{Error, Result};
use crate::fsio;

/// One file of a product's index: its path relative to the tileset (with `/`), its size in
/// bytes and the blake3 of its bytes (hex), stored as a JSON array `[path, bytes, blake3]`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct IndexEntry(pub String, pub u64, pub String);

/// A product's index as a reader uses it: each file's size and blake3, by relative path.
pub struct Index {
    /// The index file it was read from.
    pub path: PathBuf,
    pub files: std::collections::HashMap<String, (u64, [u8; 32])>,
}

/// Largest index read (some 10⁷ files; the manifest's own limits keep real ones far below).
pub const MAX_INDEX_BYTES: u64 = 4 << 30;

/// Path of the index of the product named `name` in the tileset at `dir`.
pub fn index_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(STATE_DIR)
        .join("index")
        .join(format!("{name}.json"))
}

impl Index {
    /// The index of the product named `name` in the tileset at `dir`, or None when it has none
    /// (a product never committed).
    pub fn load(dir: &Path, name: &str) -> Result<Option<Index>> {
        let path = index_path(dir, name);
        if std::fs::symlink_metadata(&path).is_err() {
            return Ok(None);
        }
        let bytes = fsio::read_capped(&path, MAX_INDEX_BYTES, "an index of a product's files")?;
        let damaged = |what: String| {
            Error::invalid(
                &path,
                format!("damaged index ({what}); rerun the stage that makes {name} to rebuild it"),
            )
        };
        let entries: Vec<IndexEntry> =
            serde_json::from_slice(&bytes).map_err(|e| damaged(e.to_string()))?;
        let mut files = std::collections::HashMap::with_capacity(entries.len());
        for IndexEntry(rel, len, hex) in entries {
            let hash = blake3::Hash::from_hex(&hex)
                .map_err(|_| damaged(format!("`{rel}` has no blake3 hash")))?;
            files.insert(rel, (len, *hash.as_bytes()));
        }
        Ok(Some(Index { path, files }))
    }
}
