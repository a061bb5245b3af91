//! Durable file operations: every file a tileset holds is written through [`write_atomic`]
//! (temp file in the same folder, fsync, rename, fsync of the folder), so neither a reader nor a
//! run killed at any moment sees half a file under its final name.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, IoContext, Result};

/// Marker in the names of temp files: `.{name}.tmp.{pid}`.
pub const TEMP_MARK: &str = ".tmp.";

/// Write `path` atomically and durably: the bytes go to a temp file in the same folder, which
/// is synced to disk and renamed over `path`; the folder is synced after the rename so that the
/// new name survives a crash too.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut std::fs::File) -> Result<()>,
) -> Result<()> {
    write_renamed(path, true, write)
}

/// Write one of a run's files into its staging folder atomically (temp file, rename) but
/// without an fsync of its own: the run's commit makes all staged files durable at once
/// ([`sync_staged`]), and a rerun resumes from staged files only within the boot of the system
/// that wrote them ([`boot_id`]). A killed process loses nothing the kernel already holds; only
/// a crash of the whole system can, and that changes the boot id. Where no boot id can be read,
/// each file is synced as [`write_atomic`] does. Two fsyncs per tile were half the wall time
/// of tiling LDEM_4 at 4 levels on a disk-backed folder (docs/benchmarks.md, "Tiling").
pub fn write_staged(
    path: &Path,
    write: impl FnOnce(&mut std::fs::File) -> Result<()>,
) -> Result<()> {
    if let Some(e) = injected_disk_full(path) {
        return Err(Error::io(path, e));
    }
    write_renamed(path, boot_id().is_none(), write)
}

/// Test hook for the failure paths of multi-stage runs (`tests/cli.rs`, disk full during
/// `bake`): with `PENUMBRA_TEST_DISK_FULL=<stage>` in the environment, every file staged below
/// `staging/<stage>/` fails as a full disk does (ENOSPC), before anything is written. Read once
/// per process; unset, it costs one comparison per staged file.
fn injected_disk_full(path: &Path) -> Option<std::io::Error> {
    static STAGE: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    let stage = STAGE.get_or_init(|| std::env::var("PENUMBRA_TEST_DISK_FULL").ok());
    let stage = stage.as_deref()?;
    let mut parts = path.components().map(|c| c.as_os_str());
    parts
        .any(|c| c == "staging")
        .then(|| parts.next())
        .flatten()
        .is_some_and(|s| s == stage)
        .then(|| std::io::Error::from_raw_os_error(28))
}

fn write_renamed(
    path: &Path,
    durable: bool,
    write: impl FnOnce(&mut std::fs::File) -> Result<()>,
) -> Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).at(dir)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}{TEMP_MARK}{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp).at(&tmp)?;
        write(&mut f)?;
        f.flush().at(&tmp)?;
        if durable {
            f.sync_all().at(&tmp)?;
        }
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path).at(path)?;
    if durable {
        sync_dir(dir)?;
    }
    Ok(())
}

/// This boot of the system (Linux: `/proc/sys/kernel/random/boot_id`), or None where there is
/// no such thing to read.
pub fn boot_id() -> Option<&'static str> {
    static ID: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    ID.get_or_init(|| {
        let bytes = read_capped(
            Path::new("/proc/sys/kernel/random/boot_id"),
            256,
            "a boot id",
        )
        .ok()?;
        let id = String::from_utf8(bytes).ok()?.trim().to_string();
        (!id.is_empty()).then_some(id)
    })
    .as_deref()
}

/// Make everything [`write_staged`] wrote below `root` durable: one `syncfs` of its file system
/// on Linux (every file at once; the data has mostly been written back by then), else an
/// fsync of each file; then each folder.
pub fn sync_staged(root: &Path) -> Result<()> {
    #[cfg(target_os = "linux")]
    let synced = {
        use std::os::fd::AsRawFd;
        let d = std::fs::File::open(root).at(root)?;
        // SAFETY: syncfs takes an open descriptor, which `d` holds for the call.
        unsafe { libc::syncfs(d.as_raw_fd()) == 0 }
    };
    #[cfg(not(target_os = "linux"))]
    let synced = false;
    if !synced {
        for (rel, _) in list_files(root)? {
            let p = root.join(rel);
            std::fs::File::open(&p).and_then(|f| f.sync_all()).at(&p)?;
        }
    }
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).at(&d)?.flatten() {
            if e.file_type().is_ok_and(|t| t.is_dir()) {
                stack.push(e.path());
            }
        }
        sync_dir(&d)?;
    }
    Ok(())
}

/// Write a small file atomically.
pub fn write_atomic_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |f| f.write_all(bytes).at(path))
}

/// Flush a folder's entries (new names, renames, removals) to disk.
pub fn sync_dir(dir: &Path) -> Result<()> {
    #[cfg(unix)]
    {
        std::fs::File::open(dir)
            .and_then(|f| f.sync_all())
            .at(dir)?;
    }
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}

/// Read a small file, refusing one larger than `cap` bytes (a manifest linked to /dev/zero or a
/// multi-gigabyte file is not a manifest). The file must be a regular file: it is opened without
/// blocking, so a FIFO cannot hang the open, and refused (as are devices and folders) before a
/// byte is read. Reads at most `cap + 1` bytes whatever the file is.
pub fn read_capped(path: &Path, cap: u64, what: &str) -> Result<Vec<u8>> {
    let (f, _) = open_regular(path, what)?;
    let mut buf = Vec::new();
    f.take(cap + 1).read_to_end(&mut buf).at(path)?;
    if buf.len() as u64 > cap {
        return Err(Error::invalid(
            path,
            format!(
                "larger than {}: too large to be {what}; point at the folder made by penumbra",
                human_bytes(cap)
            ),
        ));
    }
    Ok(buf)
}

/// `n` bytes for a message: KiB, MiB or GiB when round enough.
fn human_bytes(n: u64) -> String {
    if n >= 1 << 30 && n % (1 << 30) == 0 {
        format!("{} GiB", n >> 30)
    } else if n >= 1 << 20 && n % (1 << 20) == 0 {
        format!("{} MiB", n >> 20)
    } else if n >= 1 << 10 && n % (1 << 10) == 0 {
        format!("{} KiB", n >> 10)
    } else {
        format!("{n} bytes")
    }
}

/// Open `path` for reading as a regular file and return it with its size. The open does not
/// block (`O_NONBLOCK`: a FIFO with no writer would otherwise hang it forever); a FIFO, a
/// device, a socket or a folder is refused naming the file and what it is. `what` says what
/// the file should have been.
pub fn open_regular(path: &Path, what: &str) -> Result<(std::fs::File, u64)> {
    let mut o = std::fs::OpenOptions::new();
    o.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.custom_flags(libc::O_NONBLOCK);
    }
    let f = o.open(path).at(path)?;
    let m = f.metadata().at(path)?;
    if !m.is_file() {
        return Err(Error::invalid(
            path,
            format!(
                "is {}, not a regular file: it cannot be {what}; replace it with the file                  penumbra wrote (or rerun the stage that makes it)",
                file_kind(&m)
            ),
        ));
    }
    Ok((f, m.len()))
}

/// What a non-regular file is, for messages.
fn file_kind(m: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = m.file_type();
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if m.is_dir() {
        "a folder"
    } else {
        "not a regular file"
    }
}

/// How large a file of a tileset may be before it is read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Expect {
    /// The size the tileset's index recorded for it: any other size is refused.
    Exactly(u64),
    /// A file the index does not know: at most this many bytes.
    AtMost(u64),
}

/// Read a product file of the tileset at `root` whole, bounded before the read starts: it must
/// be a regular file (see [`open_regular`]), a symbolic link on its way may point only inside
/// `root`, and its size must be the one `expect` says. Never reads more than that size, even
/// from a file that grows meanwhile.
pub fn read_product_file(root: &Path, path: &Path, expect: Expect, what: &str) -> Result<Vec<u8>> {
    check_inside(root, path)?;
    let (f, len) = open_regular(path, what)?;
    let limit = match expect {
        Expect::Exactly(n) if n != len => {
            return Err(Error::invalid(
                path,
                format!(
                    "is {len} bytes but the tileset's index recorded {n}: it is not the file                      penumbra wrote (padded, truncated or replaced); delete it and rerun the                      stage that makes it"
                ),
            ));
        }
        Expect::Exactly(n) => n,
        Expect::AtMost(cap) if len > cap => {
            return Err(Error::invalid(
                path,
                format!(
                    "is {len} bytes, more than the {} a file of {what} can be: it is not a                      file penumbra wrote; delete it and rerun the stage that makes it",
                    human_bytes(cap)
                ),
            ));
        }
        Expect::AtMost(_) => len,
    };
    let mut buf = Vec::with_capacity(usize::try_from(limit).unwrap_or(0));
    f.take(limit + 1).read_to_end(&mut buf).at(path)?;
    if buf.len() as u64 != len {
        return Err(Error::invalid(
            path,
            format!(
                "changed size while it was read ({len} bytes, then {}); is another program                  writing it?",
                buf.len()
            ),
        ));
    }
    Ok(buf)
}

/// Refuse a path below `root` that a symbolic link takes outside `root` (a tile linked to
/// /dev/zero or to another tileset's file). Links that stay inside the tileset are followed.
pub fn check_inside(root: &Path, path: &Path) -> Result<()> {
    // Only a path that is (or passes through) a link can leave the root: most reads are of
    // plain files, checked with one lstat of the file itself.
    let rel = match path.strip_prefix(root) {
        Ok(r) => r,
        Err(_) => return Ok(()),
    };
    let mut cur = root.to_path_buf();
    let mut linked = false;
    for c in rel.components() {
        cur.push(c);
        match std::fs::symlink_metadata(&cur) {
            Ok(m) if m.file_type().is_symlink() => {
                linked = true;
                break;
            }
            Ok(_) => {}
            Err(_) => break,
        }
    }
    if !linked {
        return Ok(());
    }
    let real_root = std::fs::canonicalize(root).at(root)?;
    let real = std::fs::canonicalize(path).at(path)?;
    if !real.starts_with(&real_root) {
        return Err(Error::invalid(
            path,
            format!(
                "is a symbolic link to {}, outside the tileset: a tileset's files are read only                  from inside it; replace the link with the file itself",
                real.display()
            ),
        ));
    }
    Ok(())
}

/// Remove the temp files ([`TEMP_MARK`]) of writers that are gone from `dir` and everything
/// below it; returns how many were removed. Only call with the tileset's writer lock held.
pub fn sweep_temps(dir: &Path) -> Result<u64> {
    let mut removed = 0;
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in rd.flatten() {
            let Ok(ty) = e.file_type() else { continue };
            let name = e.file_name();
            let name = name.to_string_lossy();
            if ty.is_dir() {
                stack.push(e.path());
            } else if name.starts_with('.') && name.contains(TEMP_MARK) {
                let p = e.path();
                std::fs::remove_file(&p).at(&p)?;
                removed += 1;
            }
        }
    }
    Ok(removed)
}

/// Every regular file below `root` (relative paths with `/`, sorted) and its size.
pub fn list_files(root: &Path) -> Result<Vec<(String, u64)>> {
    let mut out = Vec::new();
    let mut stack = vec![PathBuf::new()];
    while let Some(rel) = stack.pop() {
        let d = root.join(&rel);
        let rd = match std::fs::read_dir(&d) {
            Ok(rd) => rd,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(Error::io(&d, e)),
        };
        for e in rd {
            let e = e.at(&d)?;
            let ty = e.file_type().at(e.path())?;
            let r = rel.join(e.file_name());
            if ty.is_dir() {
                stack.push(r);
            } else if ty.is_file() {
                let len = e.metadata().at(e.path())?.len();
                out.push((r.to_string_lossy().replace('\\', "/"), len));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Remove a folder tree if it exists.
pub fn remove_tree(p: &Path) -> Result<()> {
    match std::fs::remove_dir_all(p) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(p, e)),
    }
}
