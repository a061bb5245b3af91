//! A copy of a tileset that opens and reads as the original: its manifest, every product's
//! index (`.penumbra/index/<product>.json`) and every file those indexes list, byte for byte,
//! hard-linked where the file system allows it (a writer never changes a product file in place:
//! it writes a new file and renames it, so a link stays the bytes the index recorded) and
//! copied otherwise. The copy is then checked file by file against its indexes by
//! [`super::verify`] (present, regular, the recorded size and blake3, the identity each file
//! holds), so a damaged source is never passed on. Bookkeeping that only a writer needs (locks,
//! staging, unit records, a scene's stamp) is not copied: the copy is a finished tileset a
//! reader opens, and a writer may extend it like any other.
//!
//! `penumbra package` puts such a copy inside an addon ([`crate::package`]).

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use super::index::{index_path, Index};
use super::{verify, Product, Store};
use crate::error::{Error, IoContext, Result};
use crate::manifest::MANIFEST;
use crate::progress::Progress;

/// What [`copy_tileset`] copied of one product.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ProductCopy {
    /// The product's name (its index's name).
    pub product: String,
    /// Files its index lists, and their bytes.
    pub files: u64,
    pub bytes: u64,
}

/// What [`copy_tileset`] made.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct CopyReport {
    /// Per product, in the registry's order (products defined outside it last, by name).
    pub products: Vec<ProductCopy>,
    /// Product files, and their bytes.
    pub files: u64,
    pub bytes: u64,
    /// Of those, how many were hard-linked and how many copied.
    pub linked: u64,
    pub copied: u64,
    /// Files the check read back against the indexes (every product file the registry knows;
    /// products defined outside it are checked for their size only).
    pub verified: u64,
}

/// How many of a check's findings an error lists.
const LISTED_FINDINGS: usize = 5;

/// Copy the tileset `store` holds open into the new folder `to` (it must not exist; its parent
/// must), then check the copy with [`verify::verify`]. An error names the source's file that is
/// missing, damaged or not a regular file; a failed copy leaves `to` removed.
pub fn copy_tileset(store: &Store, to: &Path, progress: &dyn Progress) -> Result<CopyReport> {
    if std::fs::symlink_metadata(to).is_ok() {
        return Err(Error::invalid(
            to,
            "exists already: a tileset is copied into a new folder",
        ));
    }
    std::fs::create_dir(to).at(to)?;
    let r = copy_into(store, to, progress);
    if r.is_err() {
        let _ = std::fs::remove_dir_all(to);
    }
    r
}

fn copy_into(store: &Store, to: &Path, progress: &dyn Progress) -> Result<CopyReport> {
    let src = store.dir();
    let ts = store.manifest();
    // The registry's products, then those defined outside it (by their manifest key).
    let mut names: Vec<(String, bool)> = Product::ALL
        .into_iter()
        .filter(|p| p.recorded_key(ts).is_some())
        .map(|p| (p.name().to_string(), true))
        .collect();
    names.extend(ts.products.extra.keys().map(|k| (k.clone(), false)));
    let mut lists = Vec::new();
    for (name, known) in &names {
        let ix = Index::load(src, name)?.ok_or_else(|| {
            Error::invalid(
                index_path(src, name),
                format!(
                    "is missing, but the manifest lists the product {name}: its files cannot be \
                     checked; rerun the stage that makes {name}"
                ),
            )
        })?;
        let mut files: Vec<(String, u64)> = ix
            .files
            .iter()
            .map(|(rel, (len, _))| (rel.clone(), *len))
            .collect();
        files.sort();
        lists.push((name.clone(), *known, files));
    }
    let total: u64 = lists.iter().map(|l| l.2.len() as u64).sum();
    progress.start("cubemap", total);
    let mut report = CopyReport::default();
    for (name, _, files) in &lists {
        let done: Vec<bool> = files
            .par_iter()
            .map(|(rel, len)| {
                let linked = place(src, to, rel, *len)?;
                progress.inc(1);
                Ok(linked)
            })
            .collect::<Result<_>>()?;
        let bytes: u64 = files.iter().map(|f| f.1).sum();
        report.linked += done.iter().filter(|l| **l).count() as u64;
        report.copied += done.iter().filter(|l| !**l).count() as u64;
        report.files += files.len() as u64;
        report.bytes += bytes;
        report.products.push(ProductCopy {
            product: name.clone(),
            files: files.len() as u64,
            bytes,
        });
        let ix = index_path(src, name);
        let rel = ix
            .strip_prefix(src)
            .expect("an index lies inside its tileset");
        copy_file(&ix, &to.join(rel))?;
    }
    progress.finish();
    copy_file(&src.join(MANIFEST), &to.join(MANIFEST))?;
    // Every file of the registry's products against the copied indexes, as a reader will read
    // them.
    let check = verify::verify(to)?;
    if !check.clean() {
        let f = &check.findings[0];
        let more = check.findings.len() - 1;
        let others: Vec<String> = check.findings[1..]
            .iter()
            .take(LISTED_FINDINGS - 1)
            .map(|f| format!("{} ({})", src.join(&f.path).display(), f.problem))
            .collect();
        return Err(Error::invalid(
            src.join(&f.path),
            format!(
                "{}: {}{}; the tileset is damaged: `penumbra verify {}` lists every file, and \
                 rerunning the stage that makes {} replaces it",
                f.problem,
                f.detail,
                match more {
                    0 => String::new(),
                    _ => format!(
                        " (and {more} more problem{}: {}{})",
                        if more == 1 { "" } else { "s" },
                        others.join(", "),
                        if more > others.len() { ", …" } else { "" }
                    ),
                },
                src.display(),
                f.product
            ),
        ));
    }
    report.verified = check.files;
    Ok(report)
}

/// Hard-link (or, across file systems or where links are refused, copy) the product file `rel`
/// of `src` into `to`; whether it was linked. The source must be a regular file of the size
/// the index recorded (the hash is checked on the copy).
fn place(src: &Path, to: &Path, rel: &str, len: u64) -> Result<bool> {
    let from = src.join(rel);
    let m = std::fs::symlink_metadata(&from).at(&from)?;
    if !m.file_type().is_file() {
        return Err(Error::invalid(
            &from,
            "is not a regular file (a link or a folder): a tileset's files are regular files; \
             replace it with the file itself or rerun the stage that makes it",
        ));
    }
    if m.len() != len {
        return Err(Error::invalid(
            &from,
            format!(
                "holds {} bytes, but the tileset's index recorded {len}: the file is damaged \
                 (truncated or replaced); rerun the stage that makes it",
                m.len()
            ),
        ));
    }
    let dest = to.join(rel);
    let parent: PathBuf = dest.parent().map(Path::to_path_buf).unwrap_or_default();
    std::fs::create_dir_all(&parent).at(&parent)?;
    if std::fs::hard_link(&from, &dest).is_ok() {
        return Ok(true);
    }
    copy_file(&from, &dest)?;
    Ok(false)
}

/// Copy one file, making its folder.
fn copy_file(from: &Path, to: &Path) -> Result<()> {
    if let Some(p) = to.parent() {
        std::fs::create_dir_all(p).at(p)?;
    }
    std::fs::copy(from, to).at(from)?;
    Ok(())
}
