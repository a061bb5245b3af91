//! One writer per tileset: an advisory lock on `.penumbra/lock`, held for the whole run and
//! released by the operating system when the process exits or is killed. The lock file names
//! the holder's pid so that a refused writer can say who holds it. The file itself is never
//! removed (removing a lock file lets two writers lock two different files).
//!
//! On Unix the writer lock is a POSIX record lock (`fcntl(F_SETLK)`), which belongs to the
//! process, not to the open file: a child spawned while it is held (a program that embeds the
//! library and runs other programs, or a test harness) does not inherit it. An flock(2) lock, as
//! `File::try_lock` takes, lives on in every copy of the descriptor: a child caught between
//! fork and exec kept a released tileset locked, and the next writer was refused. Record locks
//! go when the process closes any descriptor of the file, so this module is the only place that
//! opens it, once per lock held.
//!
//! Shard processes ([`ShardLock`]: concurrent runs of parts of one stage, possibly on several
//! hosts sharing the folder) take a *shared* record lock (`F_RDLCK`) on the same file: any
//! number of them hold it together, and the writer's exclusive lock (`F_WRLCK`) is refused while
//! one does, so nothing commits under a running shard and no shard starts under a writer. On
//! NFS the record locks are the server's (NFSv4 has them built in, NFSv3 needs the lock
//! daemons, `lockd`/`statd`, on both sides); a host that dies holding one keeps it until the
//! server's lease or the lock manager's recovery lets it go (NFSv4: one lease period, typically
//! 90 s), and a mount with `nolock` makes every lock local to its host, which no longer keeps
//! hosts apart.
//!
//! Readers take a shared lock on `.penumbra/commit.lock` for as long as they read; a writer
//! takes it exclusively only while it swaps finished products into place, so a reader sees the
//! tileset before or after a commit, never halfway.

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, Weak};

use crate::error::{Error, IoContext, Result};

/// Folder inside a tileset for its bookkeeping: locks, staging, indexes.
pub const STATE_DIR: &str = ".penumbra";
const LOCK: &str = "lock";
const COMMIT_LOCK: &str = "commit.lock";

/// The exclusive right to write one tileset; released when the last holder in this process
/// drops it.
#[derive(Debug)]
pub struct WriteLock {
    _file: Arc<File>,
}

/// A shard's hold on a tileset ([`ShardLock::acquire`]): shared with other shards, exclusive
/// of the writer; released when the last holder in this process drops it.
#[derive(Debug)]
pub struct ShardLock {
    _file: Arc<File>,
}

/// Writer and shard locks this process holds, by lock-file path, and whether each is the
/// writer's: a run that holds a tileset (`bake`, across its stages) lets its own stages take
/// the lock again. One entry per file: a record lock belongs to the process, so a second
/// descriptor would convert the first's lock and, closed, release it.
static HELD: Mutex<Vec<(PathBuf, Weak<File>, bool)>> = Mutex::new(Vec::new());

/// The lock file of the tileset in `dir` (its state folder made if missing) and the key it is
/// held under in [`HELD`].
fn lock_path(dir: &Path) -> Result<(PathBuf, PathBuf)> {
    let state = dir.join(STATE_DIR);
    std::fs::create_dir_all(&state).at(&state)?;
    let key = std::fs::canonicalize(&state).at(&state)?.join(LOCK);
    Ok((state.join(LOCK), key))
}

fn open_lock(path: &Path) -> Result<File> {
    OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .at(path)
}

impl WriteLock {
    /// Take the writer lock of the tileset in `dir` (creating `dir` and its state folder), or
    /// fail at once, naming the pid that holds it. Within one process the lock is shared by
    /// whoever takes it while it is held.
    pub fn acquire(dir: &Path) -> Result<WriteLock> {
        let (path, key) = lock_path(dir)?;
        let mut held = HELD.lock().unwrap_or_else(|e| e.into_inner());
        held.retain(|(_, w, _)| w.strong_count() > 0);
        if let Some((_, w, exclusive)) = held.iter().find(|(p, _, _)| *p == key) {
            if let (Some(f), true) = (w.upgrade(), *exclusive) {
                return Ok(WriteLock { _file: f });
            }
            return Err(Error::invalid(
                dir,
                "this process runs a shard of this tileset's stage: a writer cannot begin \
                 until it ends",
            ));
        }
        let mut f = open_lock(&path)?;
        match try_lock_process(&f, true) {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                if let Some(pid) = shard_holder(&f) {
                    return Err(Error::invalid(
                        dir,
                        format!(
                            "shards of a stage are running on this tileset (process {pid} \
                             among them): wait for them to end before a writer begins"
                        ),
                    ));
                }
                let mut holder = String::new();
                let _ = f.read_to_string(&mut holder);
                let holder = holder.trim();
                let who = if holder.is_empty() {
                    "another penumbra process".to_string()
                } else {
                    format!("penumbra process {holder}")
                };
                return Err(Error::invalid(
                    dir,
                    format!(
                        "{who} is writing this tileset: wait for it to finish, or choose another \
                         output folder"
                    ),
                ));
            }
            Err(TryLockError::Error(e)) => return Err(Error::io(&path, e)),
        }
        // Best effort: the pid is only for the message above.
        let _ = f.set_len(0);
        let _ = f.rewind();
        let _ = write!(f, "{}", std::process::id());
        let _ = f.flush();
        let f = Arc::new(f);
        held.push((key, Arc::downgrade(&f), true));
        Ok(WriteLock { _file: f })
    }
}

impl ShardLock {
    /// Take a shard's shared lock on the tileset in `dir`, or fail at once when a writer holds
    /// the tileset. Within one process the lock is shared by whoever takes it while it (or the
    /// writer lock, which includes it) is held.
    pub fn acquire(dir: &Path) -> Result<ShardLock> {
        let (path, key) = lock_path(dir)?;
        let mut held = HELD.lock().unwrap_or_else(|e| e.into_inner());
        held.retain(|(_, w, _)| w.strong_count() > 0);
        if let Some(f) = held
            .iter()
            .find(|(p, _, _)| *p == key)
            .and_then(|(_, w, _)| w.upgrade())
        {
            return Ok(ShardLock { _file: f });
        }
        let mut f = open_lock(&path)?;
        match try_lock_process(&f, false) {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = f.read_to_string(&mut holder);
                let holder = holder.trim();
                return Err(Error::invalid(
                    dir,
                    format!(
                        "a writer (penumbra process {}) holds this tileset: a shard starts once \
                         it has ended",
                        if holder.is_empty() { "?" } else { holder }
                    ),
                ));
            }
            Err(TryLockError::Error(e)) => return Err(Error::io(&path, e)),
        }
        let f = Arc::new(f);
        held.push((key, Arc::downgrade(&f), false));
        Ok(ShardLock { _file: f })
    }
}

/// The pid of a process holding a shared (shard) lock on `f` that keeps this one's exclusive
/// lock out, if the system says (`F_GETLK`; over NFS the pid may be another host's).
#[cfg(unix)]
fn shard_holder(f: &File) -> Option<i64> {
    use std::os::fd::AsRawFd;
    // SAFETY: an all-zero `flock` is a valid value of the plain C struct.
    let mut fl: libc::flock = unsafe { std::mem::zeroed() };
    fl.l_type = libc::F_WRLCK as _;
    fl.l_whence = libc::SEEK_SET as _;
    // SAFETY: `f` is open for the call and `fl` a valid flock it fills in.
    let r = unsafe { libc::fcntl(f.as_raw_fd(), libc::F_GETLK, &mut fl) };
    (r == 0 && i32::from(fl.l_type) == libc::F_RDLCK).then_some(i64::from(fl.l_pid))
}

#[cfg(not(unix))]
fn shard_holder(_f: &File) -> Option<i64> {
    None
}

/// Take an exclusive (or, not `exclusive`, a shared) lock on the whole of `f` for this process,
/// or fail at once.
#[cfg(unix)]
fn try_lock_process(f: &File, exclusive: bool) -> std::result::Result<(), TryLockError> {
    use std::os::fd::AsRawFd;
    // SAFETY: an all-zero `flock` is a valid value of the plain C struct; the fields that
    // matter are set below.
    let mut fl: libc::flock = unsafe { std::mem::zeroed() };
    fl.l_type = if exclusive {
        libc::F_WRLCK as _
    } else {
        libc::F_RDLCK as _
    };
    fl.l_whence = libc::SEEK_SET as _;
    fl.l_start = 0;
    // l_len 0: to the end of the file, however long it grows.
    fl.l_len = 0;
    // SAFETY: `f` is an open descriptor for the duration of the call and `fl` a valid flock.
    let r = unsafe { libc::fcntl(f.as_raw_fd(), libc::F_SETLK, &fl) };
    if r == 0 {
        return Ok(());
    }
    let e = std::io::Error::last_os_error();
    match e.raw_os_error() {
        Some(libc::EACCES) | Some(libc::EAGAIN) => Err(TryLockError::WouldBlock),
        _ => Err(TryLockError::Error(e)),
    }
}

#[cfg(not(unix))]
fn try_lock_process(f: &File, exclusive: bool) -> std::result::Result<(), TryLockError> {
    if exclusive {
        f.try_lock()
    } else {
        f.try_lock_shared()
    }
}

/// Shared (reader) or exclusive (committing writer) hold on the commit lock.
#[derive(Debug)]
pub struct CommitLock {
    _file: Option<File>,
}

impl CommitLock {
    /// A reader's hold: waits while a writer commits. A tileset without a state folder (made
    /// by an older penumbra, or on read-only media) has no writer to wait for.
    pub fn shared(dir: &Path) -> Result<CommitLock> {
        let path = dir.join(STATE_DIR).join(COMMIT_LOCK);
        let f = match File::open(&path) {
            Ok(f) => f,
            Err(_) => return Ok(CommitLock { _file: None }),
        };
        f.lock_shared().at(&path)?;
        Ok(CommitLock { _file: Some(f) })
    }

    /// A committing writer's hold: waits for readers to finish.
    pub fn exclusive(dir: &Path) -> Result<CommitLock> {
        let state = dir.join(STATE_DIR);
        std::fs::create_dir_all(&state).at(&state)?;
        let path = state.join(COMMIT_LOCK);
        let f = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .at(&path)?;
        f.lock().at(&path)?;
        Ok(CommitLock { _file: Some(f) })
    }
}
