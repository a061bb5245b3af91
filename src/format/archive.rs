//! A ZIP archive of a folder, for handing an addon on as one file (docs/packaging.md, "The
//! archive"): every regular file below the folder, under one top folder named in the archive,
//! in sorted order, each **stored** (the PNG and EXR tiles that are nearly all of its bytes are
//! compressed already; the text files are a few kilobytes), with a fixed time (1980-01-01
//! 00:00, the format's earliest) and mode 0644, so that the same folder gives the same bytes on
//! every run and thread count. Written through [`crate::fsio::write_atomic`]: a temp file
//! beside it, synced and renamed, so no reader sees half an archive. Entries and the archive
//! go to zip64 where they need it (the zip crate's rule).

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;
use zip::write::SimpleFileOptions;
use zip::{CompressionMethod, DateTime, ZipWriter};

use crate::error::{Error, IoContext, Result};
use crate::fsio::{list_files, write_atomic};
use crate::progress::Progress;

/// What [`write_zip`] wrote.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct ZipReport {
    /// The archive.
    pub path: PathBuf,
    /// Files it holds.
    pub entries: u64,
    /// Bytes of the files it holds, and of the archive.
    pub content_bytes: u64,
    pub bytes: u64,
}

/// Write every regular file below `dir` into the ZIP archive `path` as `top/<relative path>`
/// (see the module's header); an archive already at `path` is replaced.
pub fn write_zip(dir: &Path, top: &str, path: &Path, progress: &dyn Progress) -> Result<ZipReport> {
    if top.is_empty() || top.contains(['/', '\\']) {
        return Err(Error::invalid(
            path,
            format!("the archive's top folder '{top}' must be one plain name"),
        ));
    }
    // A bare file name lies in the working folder (the atomic writer wants a folder to name).
    let at = match path.parent() {
        Some(p) if p.as_os_str().is_empty() => Path::new(".").join(path),
        _ => path.to_path_buf(),
    };
    let files = list_files(dir)?;
    progress.start("zip", files.len() as u64);
    let mut content = 0u64;
    write_atomic(&at, |f| {
        let bad =
            |e: zip::result::ZipError| Error::invalid(path, format!("writing the archive: {e}"));
        let mut z = ZipWriter::new(f);
        for (rel, len) in &files {
            let opts = SimpleFileOptions::DEFAULT
                .compression_method(CompressionMethod::Stored)
                .last_modified_time(DateTime::DEFAULT)
                .unix_permissions(0o644)
                .large_file(*len >= u64::from(u32::MAX));
            z.start_file(format!("{top}/{rel}"), opts).map_err(bad)?;
            let p = dir.join(rel);
            let mut r = std::fs::File::open(&p).at(&p)?;
            let n = std::io::copy(&mut r, &mut z).at(&p)?;
            if n != *len {
                return Err(Error::invalid(
                    &p,
                    format!("changed while it was archived ({len} bytes listed, {n} read)"),
                ));
            }
            content += n;
            progress.inc(1);
        }
        z.finish().map_err(bad)?.flush().at(path)
    })?;
    progress.finish();
    let bytes = std::fs::metadata(&at).at(path)?.len();
    Ok(ZipReport {
        path: path.to_path_buf(),
        entries: files.len() as u64,
        content_bytes: content,
        bytes,
    })
}
