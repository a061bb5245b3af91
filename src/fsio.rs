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
///
/// When `path` lies below a staging root that records hashes ([`StagedHashes`]), the bytes
/// are hashed (blake3) as `write` writes them, and once the file has its name the hash is
/// appended to that root's log with the file's size and stamp, so that the commit indexes the
/// file without reading it back ([`read_staged_hashes`]).
pub fn write_staged(
    path: &Path,
    write: impl FnOnce(&mut StagedFile<'_>) -> Result<()>,
) -> Result<()> {
    if let Some(e) = injected_disk_full(path) {
        return Err(Error::io(path, e));
    }
    let log = hash_log_for(path);
    let written = write_renamed(path, boot_id().is_none(), |f| {
        let mut staged = StagedFile {
            file: f,
            hasher: log.as_ref().map(|_| blake3::Hasher::new()),
        };
        write(&mut staged)?;
        match staged.hasher {
            Some(h) => {
                // The stamp of the file as written: the rename keeps its inode and mtime.
                let m = staged.file.metadata().at(path)?;
                Ok(Some((h.finalize(), FileStamp::of(&m))))
            }
            None => Ok(None),
        }
    })?;
    // Recorded only once the file has its name: a kill before this line leaves a file without
    // a record, which the commit hashes.
    if let (Some((log, rel)), Some((hash, stamp))) = (log, written) {
        log.append(&rel, stamp, &hash)?;
        captured(&rel, stamp.len, &hash);
    }
    Ok(())
}

/// A file [`write_staged`] wrote below a recording staging root: its path relative to the
/// root (`/` between names), size and blake3.
pub type Written = (String, u64, blake3::Hash);

thread_local! {
    static THREAD_WRITES: std::cell::RefCell<Option<Vec<Written>>> =
        const { std::cell::RefCell::new(None) };
}

/// The files written in [`capture_writes`] with `whole_process`.
static PROCESS_WRITES: std::sync::Mutex<Option<Vec<Written>>> = std::sync::Mutex::new(None);

fn captured(rel: &str, len: u64, hash: &blake3::Hash) {
    THREAD_WRITES.with(|c| {
        if let Some(v) = c.borrow_mut().as_mut() {
            v.push((rel.to_string(), len, *hash));
        }
    });
    let mut p = PROCESS_WRITES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(v) = p.as_mut() {
        v.push((rel.to_string(), len, *hash));
    }
}

/// Run `f` and return, with its result, every file [`write_staged`] wrote meanwhile below a
/// staging root that records hashes ([`StagedHashes`]): on this thread only, or, with
/// `whole_process`, on any thread (then one capture at a time: the caller runs nothing else
/// that writes). The files of one unit of a stage, for a shard's record of it.
pub fn capture_writes<T>(whole_process: bool, f: impl FnOnce() -> T) -> (T, Vec<Written>) {
    if whole_process {
        *PROCESS_WRITES.lock().unwrap_or_else(|e| e.into_inner()) = Some(Vec::new());
        let t = f();
        let w = PROCESS_WRITES
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        (t, w.unwrap_or_default())
    } else {
        // Nested: a thread waiting inside a unit's parallel work may run another unit (work
        // stealing); that unit captures its own files and the outer capture goes on after it.
        let outer = THREAD_WRITES.with(|c| c.borrow_mut().replace(Vec::new()));
        let t = f();
        let w = THREAD_WRITES.with(|c| std::mem::replace(&mut *c.borrow_mut(), outer));
        (t, w.unwrap_or_default())
    }
}

/// The file [`write_staged`] hands its writer: writes go to the temp file and, when the
/// staging root records hashes, into the file's blake3 as they are made. Only sequential
/// writes, so that the hash is the hash of the file.
pub struct StagedFile<'a> {
    file: &'a mut std::fs::File,
    hasher: Option<blake3::Hasher>,
}

impl Write for StagedFile<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.file.write(buf)?;
        if let Some(h) = &mut self.hasher {
            h.update(&buf[..n]);
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
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

fn write_renamed<T>(
    path: &Path,
    durable: bool,
    write: impl FnOnce(&mut std::fs::File) -> Result<T>,
) -> Result<T> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).at(dir)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}{TEMP_MARK}{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp).at(&tmp)?;
        let t = write(&mut f)?;
        f.flush().at(&tmp)?;
        if durable {
            f.sync_all().at(&tmp)?;
        }
        Ok(t)
    })();
    let t = match result {
        Ok(t) => t,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    std::fs::rename(&tmp, path).at(path)?;
    if durable {
        sync_dir(dir)?;
    }
    Ok(t)
}

/// A file's size and where it lives on disk (inode, modification time in nanoseconds): what a
/// staged file's hash record is held against at the commit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FileStamp {
    pub len: u64,
    /// 0 where the system has no inode numbers.
    pub ino: u64,
    pub mtime_ns: i128,
}

impl FileStamp {
    pub fn of(m: &std::fs::Metadata) -> FileStamp {
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            FileStamp {
                len: m.len(),
                ino: m.ino(),
                mtime_ns: i128::from(m.mtime()) * 1_000_000_000 + i128::from(m.mtime_nsec()),
            }
        }
        #[cfg(not(unix))]
        {
            let mtime_ns = m
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map_or(0, |d| d.as_nanos() as i128);
            FileStamp {
                len: m.len(),
                ino: 0,
                mtime_ns,
            }
        }
    }
}

/// Folder of a staging root's hash logs: `hashes/<pid>.log`, one per process (a shard's:
/// [`StagedHashes::record_below_as`]), a line per file
/// [`write_staged`] wrote there: `path<TAB>bytes<TAB>inode<TAB>mtime_ns<TAB>blake3 hex`.
pub const HASH_LOGS: &str = "hashes";
/// Largest hash log read back (a line is about 150 bytes).
const MAX_HASH_LOG_BYTES: u64 = 1 << 30;

/// One staging root's hash log, opened at its first record.
#[derive(Debug)]
struct HashLog {
    root: PathBuf,
    /// The log's file name less `.log`.
    name: String,
    file: std::sync::Mutex<Option<std::fs::File>>,
}

/// The staging roots whose staged files have their hashes recorded, latest last.
static HASH_LOGS_OPEN: std::sync::Mutex<Vec<std::sync::Arc<HashLog>>> =
    std::sync::Mutex::new(Vec::new());

fn hash_logs_open() -> std::sync::MutexGuard<'static, Vec<std::sync::Arc<HashLog>>> {
    HASH_LOGS_OPEN.lock().unwrap_or_else(|e| e.into_inner())
}

/// While alive, every file [`write_staged`] writes below `root` has its blake3, size and stamp
/// appended to this process's hash log there (`root/hashes/<pid>.log`). The tileset's writer
/// holds one for the staging folder of the run under way ([`crate::tileset::writer`]); a later
/// registration of the same root takes over from an earlier one.
#[derive(Debug)]
pub struct StagedHashes(std::sync::Arc<HashLog>);

impl StagedHashes {
    pub fn record_below(root: &Path) -> StagedHashes {
        StagedHashes::record_below_as(root, &std::process::id().to_string())
    }

    /// [`StagedHashes::record_below`] into the log `root/hashes/<name>.log` (a shard's, named
    /// so that processes on several hosts sharing the folder cannot collide).
    pub fn record_below_as(root: &Path, name: &str) -> StagedHashes {
        let log = std::sync::Arc::new(HashLog {
            root: root.to_path_buf(),
            name: name.to_string(),
            file: std::sync::Mutex::new(None),
        });
        hash_logs_open().push(log.clone());
        StagedHashes(log)
    }

    /// Record the hash of the file at `rel` (below the root, `/` between names) with its
    /// stamp, as [`write_staged`] does once a file it wrote has its name: for a file written
    /// below the root by other means (`penumbra-bench integrity` replays a stage's records
    /// with it). A path that cannot be written into a log line is not recorded.
    pub fn record(&self, rel: &str, stamp: FileStamp, hash: &blake3::Hash) -> Result<()> {
        self.0.append(rel, stamp, hash)
    }
}

impl Drop for StagedHashes {
    fn drop(&mut self) {
        hash_logs_open().retain(|l| !std::sync::Arc::ptr_eq(l, &self.0));
    }
}

/// The hash log recording files written at `path`, and the path relative to its root (`/`
/// between names, as [`list_files`] gives it); None when nothing records there or the path
/// cannot be written into a log line (then the commit hashes the file).
fn hash_log_for(path: &Path) -> Option<(std::sync::Arc<HashLog>, String)> {
    let log = {
        let logs = hash_logs_open();
        logs.iter()
            .rev()
            .find(|l| path.starts_with(&l.root))?
            .clone()
    };
    let mut rel = String::new();
    for c in path.strip_prefix(&log.root).ok()?.components() {
        let std::path::Component::Normal(name) = c else {
            return None;
        };
        if !rel.is_empty() {
            rel.push('/');
        }
        rel.push_str(name.to_str()?);
    }
    recordable(&rel).then_some((log, rel))
}

/// A relative path a hash log line can hold.
fn recordable(rel: &str) -> bool {
    !rel.is_empty() && !rel.contains(['\t', '\n'])
}

impl HashLog {
    fn path(&self) -> PathBuf {
        self.root.join(HASH_LOGS).join(format!("{}.log", self.name))
    }

    /// Append the record of the file at `rel`: one `write` of a whole line, kept by the kernel
    /// through a kill like the file itself.
    fn append(&self, rel: &str, stamp: FileStamp, hash: &blake3::Hash) -> Result<()> {
        if !recordable(rel) {
            return Ok(());
        }
        let line = format!(
            "{rel}\t{}\t{}\t{}\t{}\n",
            stamp.len,
            stamp.ino,
            stamp.mtime_ns,
            hash.to_hex()
        );
        let path = self.path();
        let mut f = self.file.lock().unwrap_or_else(|e| e.into_inner());
        if f.is_none() {
            *f = Some(open_hash_log(&path)?);
        }
        let f = f.as_mut().expect("opened above");
        f.write_all(line.as_bytes()).at(&path)
    }
}

/// Open a hash log for appending. A log of an earlier process with the same pid may end in a
/// line a kill cut short: it is ended first, so that it stays a line of its own (and is not read
/// back, its hash being the last field and of fixed length) instead of running into this one's.
fn open_hash_log(path: &Path) -> Result<std::fs::File> {
    use std::io::{Seek, SeekFrom};
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).at(dir)?;
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .read(true)
        .open(path)
        .at(path)?;
    if f.metadata().at(path)?.len() > 0 {
        let mut last = [0u8];
        f.seek(SeekFrom::End(-1)).at(path)?;
        f.read_exact(&mut last).at(path)?;
        if last[0] != b'\n' {
            f.write_all(b"\n").at(path)?;
        }
    }
    Ok(f)
}

/// The hashes [`write_staged`] recorded below a staging root, by file.
#[derive(Debug, Default)]
pub struct StagedHashRecords(std::collections::HashMap<String, Vec<(FileStamp, blake3::Hash)>>);

impl StagedHashRecords {
    /// The recorded blake3 of the file at `rel` (relative to the root) if a record's size and
    /// stamp are the file's as it is now (`stamp`) and no other such record disagrees; None
    /// otherwise (no record, the file rewritten or replaced since, a conflict): then the
    /// caller hashes the file.
    pub fn hash_of(&self, rel: &str, stamp: FileStamp) -> Option<blake3::Hash> {
        let mut found = None;
        for (s, h) in self.0.get(rel)? {
            if *s == stamp {
                match found {
                    None => found = Some(*h),
                    Some(f) if f != *h => return None,
                    Some(_) => {}
                }
            }
        }
        found
    }

    /// How many records were read.
    pub fn len(&self) -> usize {
        self.0.values().map(Vec::len).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// The `*.log` files of `dir` (one per process that appended to it), in name order; none
/// when it cannot be listed.
pub fn logs_in(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut logs: Vec<PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "log"))
        .collect();
    logs.sort();
    logs
}

/// Every record the processes that wrote below `root` left in its hash logs. Whole, well-formed
/// lines only: a line a kill cut short, or any line that is not exactly a path, three numbers
/// and a 64-digit hash, is skipped; a log that cannot be read is skipped whole. A file left
/// without a record is hashed by the commit, so skipping is always safe.
pub fn read_staged_hashes(root: &Path) -> StagedHashRecords {
    let mut out = StagedHashRecords::default();
    for p in logs_in(&root.join(HASH_LOGS)) {
        if let Ok(bytes) = read_capped(&p, MAX_HASH_LOG_BYTES, "a log of file hashes") {
            add_hash_log(&mut out, &bytes);
        }
    }
    out
}

/// The records of one hash log's bytes (see [`read_staged_hashes`]).
pub fn read_staged_hashes_from(log: &[u8]) -> StagedHashRecords {
    let mut out = StagedHashRecords::default();
    add_hash_log(&mut out, log);
    out
}

fn add_hash_log(out: &mut StagedHashRecords, bytes: &[u8]) {
    for line in bytes.split_inclusive(|&b| b == b'\n') {
        let Some(line) = line.strip_suffix(b"\n") else {
            break;
        };
        if let Some((rel, stamp, hash)) = parse_hash_record(line) {
            out.0.entry(rel).or_default().push((stamp, hash));
        }
    }
}

fn parse_hash_record(line: &[u8]) -> Option<(String, FileStamp, blake3::Hash)> {
    let line = std::str::from_utf8(line).ok()?;
    let mut f = line.split('\t');
    let (rel, len, ino, mtime, hash) = (f.next()?, f.next()?, f.next()?, f.next()?, f.next()?);
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if f.next().is_some()
        || rel.is_empty()
        || !digits(len)
        || !digits(ino)
        || !(digits(mtime) || mtime.strip_prefix('-').is_some_and(digits))
        || hash.len() != 64
        || !hash.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
    {
        return None;
    }
    let stamp = FileStamp {
        len: len.parse().ok()?,
        ino: ino.parse().ok()?,
        mtime_ns: mtime.parse().ok()?,
    };
    Some((rel.to_string(), stamp, blake3::Hash::from_hex(hash).ok()?))
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

/// This host's name as a file name can hold it (letters, digits, `-`, `_`; anything else
/// becomes `_`), or `host` where the system gives none: what tells apart the logs of processes
/// on several hosts that share a folder (a pid alone is unique on one host only).
pub fn host_name() -> String {
    #[cfg(unix)]
    let raw = {
        let mut buf = [0u8; 256];
        // SAFETY: `buf` is valid for writes of its length for the call.
        let r = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) };
        if r == 0 {
            let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
            String::from_utf8_lossy(&buf[..end]).into_owned()
        } else {
            String::new()
        }
    };
    #[cfg(not(unix))]
    let raw = std::env::var("COMPUTERNAME").unwrap_or_default();
    let name: String = raw
        .chars()
        .take(64)
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if name.is_empty() {
        "host".to_string()
    } else {
        name
    }
}

/// Swap the names of `a` and `b` at once (Linux `renameat2` with `RENAME_EXCHANGE`): Ok(true)
/// when swapped, Ok(false) where the system or file system cannot (then nothing moved), Err on
/// any other failure.
pub fn exchange_paths(a: &Path, b: &Path) -> std::io::Result<bool> {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::ffi::OsStrExt;
        let c = |p: &Path| {
            std::ffi::CString::new(p.as_os_str().as_bytes()).map_err(|_| {
                std::io::Error::new(std::io::ErrorKind::InvalidInput, "a NUL in the path")
            })
        };
        let (ca, cb) = (c(a)?, c(b)?);
        // SAFETY: two NUL-terminated paths that live across the call, relative to the working
        // folder.
        let r = unsafe {
            libc::renameat2(
                libc::AT_FDCWD,
                ca.as_ptr(),
                libc::AT_FDCWD,
                cb.as_ptr(),
                libc::RENAME_EXCHANGE,
            )
        };
        if r == 0 {
            return Ok(true);
        }
        let e = std::io::Error::last_os_error();
        if matches!(e.raw_os_error(), Some(libc::EINVAL) | Some(libc::ENOSYS)) {
            return Ok(false);
        }
        Err(e)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (a, b);
        Ok(false)
    }
}
