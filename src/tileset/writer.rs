//! Writing a tileset: one writer at a time, a run's files staged beside the tileset, and a
//! commit that swaps them in. Until the commit the tileset is exactly as it was, so a run that
//! fails or is killed loses nothing; the commit itself is a short, written-down sequence of
//! renames that the next writer finishes if a kill interrupts it.
//!
//! Layout of the state folder `.penumbra/`:
//! - `lock`, `commit.lock`: see [`super::lock`];
//! - `staging/<stage>/`: a run in progress: `run.json` (its run key, so that a rerun with the
//!   same key resumes), the product folders as they will appear in the tileset, `units/<pid>.log`
//!   (the units each process finished) and `hashes/<pid>.log` (the size, stamp and blake3 of
//!   each file it wrote, hashed as it was written: [`fsio::write_staged`]), then `tileset.json`
//!   and `index/<product>.json` once the run is complete;
//! - `commit.json`: the plan of a commit under way (present only during one);
//! - `index/<product>.json`: every file of a committed product with its size and blake3
//!   ([`IndexEntry`]), so that an up-to-date check can verify that the files it vouches for are
//!   there, readers can bound a read by the recorded size and check what they read, and
//!   `penumbra verify` can check every file;
//! - `trash/`: folders replaced by a commit, removed right after it.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::fsio::{self, list_files, remove_tree, sync_dir, write_atomic_bytes};
use super::index::IndexEntry;
use super::lock::{CommitLock, ShardLock, WriteLock, STATE_DIR};
use super::Product;
use crate::error::{Error, IoContext, Result};
use crate::manifest::{Tileset, MANIFEST};

const RUN: &str = "run.json";
const PLAN: &str = "commit.json";

#[derive(Serialize, Deserialize)]
struct RunMarker {
    run_key: String,
    /// The boot of the system the run wrote its (unsynced, [`fsio::write_staged`]) files in: a
    /// rerun resumes from them only within the same boot.
    #[serde(default)]
    boot: Option<String>,
    /// Made by shards ([`ShardWriter`]), on any host: resumed by shards of the same key, whose
    /// records carry each file's blake3, and finished by [`Writer::open_staged`]; a whole run
    /// replaces it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    sharded: bool,
}

impl RunMarker {
    fn read(root: &Path) -> Option<RunMarker> {
        fsio::read_capped(&root.join(RUN), 1 << 16, "a run marker")
            .ok()
            .and_then(|b| serde_json::from_slice::<RunMarker>(&b).ok())
    }

    /// A marker of this run key written in this boot.
    fn resumable(&self, run_key: &str) -> bool {
        self.run_key == run_key && self.boot.as_deref() == fsio::boot_id()
    }
}

#[derive(Serialize, Deserialize)]
struct Plan {
    /// Staging folder (below `.penumbra/staging/`) whose contents move in.
    staging: String,
    /// Top-level folders that move from the staging folder into the tileset.
    moves: Vec<String>,
    /// Top-level folders of the tileset removed (stale products not rewritten).
    removes: Vec<String>,
    /// Products whose indexes are replaced (from the staging folder) or dropped.
    indexes: Vec<String>,
}

/// What follows a product's name in the name of its unit records in the index folder
/// (`.penumbra/index/<product>.units.json`, [`crate::runner`]).
pub const UNITS_SUFFIX: &str = ".units";

/// The unit records of `product`'s last committed run (`.penumbra/index/<product>.units.json`)
/// as stored, when there are any that read back within `cap` bytes.
pub fn read_unit_records(dir: &std::path::Path, product: Product, cap: u64) -> Option<Vec<u8>> {
    let p = records_path(dir, product);
    crate::fsio::read_capped(&p, cap, "a stage's unit records").ok()
}

/// Stage `bytes` as `product`'s unit records in the staging folder `root` (the commit moves
/// them in beside the product's index).
pub fn stage_unit_records(
    root: &std::path::Path,
    product: Product,
    bytes: &[u8],
) -> crate::error::Result<()> {
    use crate::error::IoContext;
    let index = root.join("index");
    std::fs::create_dir_all(&index).at(&index)?;
    crate::fsio::write_atomic_bytes(
        &index.join(format!("{}{}.json", product.name(), UNITS_SUFFIX)),
        bytes,
    )
}

fn records_path(dir: &std::path::Path, product: Product) -> std::path::PathBuf {
    super::index::index_path(dir, &format!("{}{}", product.name(), UNITS_SUFFIX))
}

/// The exclusive writer of one tileset folder.
pub struct Writer {
    dir: PathBuf,
    /// Set when this writer made the folder (or its state folder): a run that fails before
    /// its first commit removes what it made.
    created_dir: bool,
    created_state: bool,
    committed: bool,
    staging: Option<PathBuf>,
    _lock: WriteLock,
}

/// Where a run writes its files.
#[derive(Debug)]
pub struct Staging {
    /// Root under which the run writes product folders as they will appear in the tileset.
    pub root: PathBuf,
    /// True when an interrupted run with the same run key left files here to keep.
    pub resume: bool,
    /// Name (less `.log`) of this process's logs of unit records and file hashes: its pid, or
    /// a shard's `shard-<i>-of-<n>.<host>.<pid>`.
    pub log: String,
    /// While the run lasts, the files it stages have their hashes recorded for the commit.
    _hashes: fsio::StagedHashes,
}

impl Staging {
    /// Folder of the run's unit records (the runner's bookkeeping, not product files).
    const UNITS: &'static str = "units";
    /// Largest log of unit records read back.
    const MAX_LOG_BYTES: u64 = 1 << 30;

    /// The log this process appends its unit records to: one line per unit done,
    /// `name<TAB>record`, written after the unit's files (one `write` each, kept by the kernel
    /// through a kill like the staged files; a line cut short by a crash is not read back).
    /// One file per process, so that runs of the same key add to the staging folder without
    /// creating a file per unit.
    pub fn record_log(&self) -> Result<RecordLog> {
        let dir = self.root.join(Self::UNITS);
        std::fs::create_dir_all(&dir).at(&dir)?;
        let path = dir.join(format!("{}.log", self.log));
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .at(&path)?;
        Ok(RecordLog {
            path,
            file: std::sync::Mutex::new(file),
        })
    }

    /// Put the committed file `from` at `rel` below the staging root, as a hard link (a copy
    /// where the file system cannot link), with its blake3 recorded for the commit's index:
    /// a unit an earlier run made and whose inputs have not changed is kept, not redone.
    pub fn link(&self, from: &Path, rel: &str, hash: &blake3::Hash) -> Result<()> {
        let to = self.root.join(rel);
        if let Some(d) = to.parent() {
            std::fs::create_dir_all(d).at(d)?;
        }
        if std::fs::symlink_metadata(&to).is_ok() {
            std::fs::remove_file(&to).at(&to)?;
        }
        if std::fs::hard_link(from, &to).is_err() {
            fsio::write_staged(&to, |f| {
                let mut r = std::fs::File::open(from).at(from)?;
                std::io::copy(&mut r, f).at(from)?;
                Ok(())
            })?;
            return Ok(());
        }
        let stamp = fsio::FileStamp::of(&std::fs::symlink_metadata(&to).at(&to)?);
        self._hashes.record(rel, stamp, hash)
    }

    /// Every unit record runs of this key left here, by unit name (the last of a name wins),
    /// with the name of the log it was read from (less `.log`: which process, which shard).
    pub fn read_records(&self) -> Result<std::collections::HashMap<String, (Vec<u8>, String)>> {
        let mut out = std::collections::HashMap::new();
        for p in fsio::logs_in(&self.root.join(Self::UNITS)) {
            let log = p
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let bytes = fsio::read_capped(&p, Self::MAX_LOG_BYTES, "a log of unit records")?;
            // Whole lines only: the last may have been cut by a crash.
            for line in bytes.split_inclusive(|&b| b == b'\n') {
                let Some(line) = line.strip_suffix(b"\n") else {
                    break;
                };
                if let Some(tab) = line.iter().position(|&b| b == b'\t') {
                    let name = String::from_utf8_lossy(&line[..tab]).into_owned();
                    out.insert(name, (line[tab + 1..].to_vec(), log.clone()));
                }
            }
        }
        Ok(out)
    }
}

/// A process's log of unit records ([`Staging::record_log`]).
pub struct RecordLog {
    path: PathBuf,
    file: std::sync::Mutex<std::fs::File>,
}

impl RecordLog {
    /// Append the record of unit `name` (`record` holds no newline: compact JSON).
    pub fn append(&self, name: &str, record: &[u8]) -> Result<()> {
        debug_assert!(!name.contains(['\t', '\n']) && !record.contains(&b'\n'));
        let mut line = Vec::with_capacity(name.len() + record.len() + 2);
        line.extend_from_slice(name.as_bytes());
        line.push(b'\t');
        line.extend_from_slice(record);
        line.push(b'\n');
        let mut f = self.file.lock().unwrap_or_else(|e| e.into_inner());
        f.write_all(&line).at(&self.path)
    }
}

impl Writer {
    /// Become the writer of `dir` (made if missing): refuses at once if another process is;
    /// finishes a commit a killed writer left, and sweeps temp files of dead writers.
    pub fn begin(dir: &Path) -> Result<Writer> {
        let created_dir = !dir.exists();
        let created_state = !dir.join(STATE_DIR).exists();
        let lock = WriteLock::acquire(dir);
        let lock = match lock {
            Ok(l) => l,
            Err(e) => {
                if created_dir {
                    let _ = std::fs::remove_dir_all(dir);
                }
                return Err(e);
            }
        };
        let w = Writer {
            dir: dir.to_path_buf(),
            created_dir,
            created_state,
            committed: false,
            staging: None,
            _lock: lock,
        };
        let plan = w.state().join(PLAN);
        if plan.exists() {
            w.apply(&plan)?;
        }
        // Temp files of killed writers: beside the manifest and in staged runs.
        for e in std::fs::read_dir(&w.dir).at(&w.dir)?.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') && name.contains(fsio::TEMP_MARK) {
                let _ = std::fs::remove_file(e.path());
            }
        }
        fsio::sweep_temps(&w.state())?;
        remove_tree(&w.state().join("trash"))?;
        // Staging folders shards were making when killed ([`ShardWriter::stage`]).
        if let Ok(rd) = std::fs::read_dir(w.state().join("staging")) {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if name.starts_with('.') && name.contains(".new.") {
                    remove_tree(&e.path())?;
                }
            }
        }
        Ok(w)
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn state(&self) -> PathBuf {
        self.dir.join(STATE_DIR)
    }

    /// Write the bookkeeping file `.penumbra/<name>` (atomically; not a product file: a
    /// scene's stamp).
    pub fn write_state_file(&self, name: &str, bytes: &[u8]) -> Result<()> {
        write_atomic_bytes(&self.state().join(name), bytes)
    }

    /// True when every file the index of `product` lists is present with its size.
    pub fn verify(&self, product: Product) -> bool {
        verify_product(&self.dir, product)
    }

    /// Remove what a run of stage `name` with `run_key` left in staging once that run's
    /// output is committed (a kill between the commit's renames and its clean-up leaves the
    /// run marker behind). Staging of a run with another key is kept for its resume.
    pub fn discard_stage(&self, name: &str, run_key: &str) -> Result<()> {
        let root = self.state().join("staging").join(name);
        let same = RunMarker::read(&root).is_some_and(|m| m.run_key == run_key);
        if same {
            remove_tree(&root)?;
        }
        Ok(())
    }

    /// The staging folder of stage `name` for a run with `run_key`: kept (resume) when an
    /// interrupted run of the same key left it in this boot of the system, else made afresh
    /// (files are staged without an fsync each, so after a system crash none is trusted).
    pub fn stage(&mut self, name: &str, run_key: &str) -> Result<Staging> {
        let root = self.state().join("staging").join(name);
        let marker = root.join(RUN);
        let resume = RunMarker::read(&root).is_some_and(|m| m.resumable(run_key));
        if !resume {
            remove_tree(&root)?;
            std::fs::create_dir_all(&root).at(&root)?;
            let m = RunMarker {
                run_key: run_key.to_string(),
                boot: fsio::boot_id().map(str::to_string),
                sharded: false,
            };
            write_atomic_bytes(&marker, &serde_json::to_vec(&m).expect("marker serialises"))?;
        }
        // Leftovers of a completed-but-uncommitted run are rewritten by this one.
        let _ = std::fs::remove_file(root.join(MANIFEST));
        remove_tree(&root.join("index"))?;
        self.staging = Some(root.clone());
        let _hashes = fsio::StagedHashes::record_below(&root);
        Ok(Staging {
            root,
            resume,
            log: std::process::id().to_string(),
            _hashes,
        })
    }

    /// The staging folder shards of stage `name` made for a run with `run_key`, to check and
    /// commit (None: there is none). It stays when this writer ends without committing (a
    /// refused finish leaves the shards' work for a rerun). Refused when the folder holds a run
    /// of another key, or one not made by shards.
    pub fn open_staged(&mut self, name: &str, run_key: &str) -> Result<Option<Staging>> {
        let root = self.state().join("staging").join(name);
        if !root.exists() {
            return Ok(None);
        }
        match RunMarker::read(&root) {
            Some(m) if m.run_key == run_key && m.sharded => {}
            Some(m) if m.run_key == run_key => {
                return Err(Error::invalid(
                    &root,
                    format!(
                        "the {name} stage's staged run was made by one process, not by shards: \
                         run the stage whole to complete it"
                    ),
                ))
            }
            _ => {
                return Err(Error::invalid(
                    &root,
                    format!(
                        "the {name} stage's staged run is of another run key (other options, or \
                         other inputs) than this one: its shards were run for something else; \
                         run the stage whole, which replaces it, or remove this folder and run \
                         the shards again"
                    ),
                ))
            }
        }
        let _ = std::fs::remove_file(root.join(MANIFEST));
        remove_tree(&root.join("index"))?;
        let log = format!("finish.{}.{}", fsio::host_name(), std::process::id());
        let _hashes = fsio::StagedHashes::record_below_as(&root, &log);
        Ok(Some(Staging {
            root,
            resume: true,
            log,
            _hashes,
        }))
    }

    /// Leave the staged run as it is, uncommitted, for a later process with the same run key
    /// to complete and commit (a run of some of a stage's units: [`crate::runner::Select`]).
    pub fn leave_staged(&mut self) {
        self.staging = None;
    }

    /// Swap a completed run into the tileset: the product folders of `writes` found in the
    /// staging folder replace the tileset's; folders of `writes` the run did not make and, when
    /// the products `changed` (a new run key), of every product downstream of `writes` are
    /// removed, and so are their manifest entries; `manifest` becomes the tileset's manifest.
    pub fn commit(
        &mut self,
        staging: Staging,
        writes: &[Product],
        mut manifest: Tileset,
        changed: bool,
    ) -> Result<()> {
        // A product rebuilt with its old run key (files had gone missing) is what it was: what
        // was derived from it stays valid.
        let downstream = if changed {
            Product::downstream(writes)
        } else {
            Vec::new()
        };
        for p in &downstream {
            p.clear(&mut manifest);
        }
        // Products the registry does not list: stamp what this run writes with the folders it
        // owns and what it reads; remove those (in the tileset as committed, or carried over in
        // the new manifest) that read, directly or not, what this run rewrites.
        for &p in writes {
            if let Product::Other(d) = p {
                if let Some(serde_json::Value::Object(e)) = manifest.products.extra.get_mut(d.name)
                {
                    e.insert("dirs".into(), serde_json::json!(d.dirs));
                    let reads: Vec<&str> = d.reads.iter().map(|r| r.name()).collect();
                    e.insert("reads".into(), serde_json::json!(reads));
                }
            }
        }
        let unlisted_stale = if changed {
            let current = Tileset::load(&self.dir).ok();
            let mut changed_names: Vec<String> = writes
                .iter()
                .chain(&downstream)
                .map(|p| p.name().to_string())
                .collect();
            let mut entries: Vec<(String, serde_json::Value)> = manifest
                .products
                .extra
                .iter()
                .chain(current.iter().flat_map(|c| c.products.extra.iter()))
                .filter(|(n, _)| !writes.iter().any(|w| w.name() == n.as_str()))
                .map(|(n, v)| (n.clone(), v.clone()))
                .collect();
            let mut stale = Vec::new();
            while let Some(k) = entries.iter().position(|(_, v)| {
                unlisted_field(v, "reads")
                    .iter()
                    .any(|r| changed_names.contains(r))
            }) {
                let (name, v) = entries.remove(k);
                entries.retain(|(n, _)| *n != name);
                changed_names.push(name.clone());
                stale.push((name, unlisted_field(&v, "dirs")));
            }
            stale
        } else {
            Vec::new()
        };
        for (name, _) in &unlisted_stale {
            manifest.products.extra.remove(name);
        }
        let mut moves = Vec::new();
        let mut removes = Vec::new();
        let mut indexes = Vec::new();
        let index_dir = staging.root.join("index");
        std::fs::create_dir_all(&index_dir).at(&index_dir)?;
        let recorded = fsio::read_staged_hashes(&staging.root);
        for &p in writes {
            let mut files = Vec::new();
            for d in p.dirs() {
                if staging.root.join(d).is_dir() {
                    moves.push(d.to_string());
                    for (rel, len) in list_files(&staging.root.join(d))? {
                        files.push((format!("{d}/{rel}"), len));
                    }
                } else {
                    removes.push(d.to_string());
                }
            }
            let (files, _) = index_entries(&staging.root, files, &recorded)?;
            let json = serde_json::to_vec(&files).expect("index serialises");
            write_atomic_bytes(&index_dir.join(format!("{}.json", p.name())), &json)?;
            indexes.push(p.name().to_string());
            // The runner's unit records (staged beside the index, or dropped).
            indexes.push(format!("{}{UNITS_SUFFIX}", p.name()));
        }
        for p in &downstream {
            removes.extend(p.dirs().iter().map(|d| d.to_string()));
            indexes.push(p.name().to_string());
            indexes.push(format!("{}{UNITS_SUFFIX}", p.name()));
        }
        for (name, dirs) in unlisted_stale {
            removes.extend(dirs);
            indexes.push(name);
        }
        for d in &moves {
            fsio::sync_staged(&staging.root.join(d))?;
        }
        self.decide(&staging, &manifest, moves, removes, indexes)
    }

    /// Stage `manifest`, write the commit plan (`moves` from the staging folder, `removes`,
    /// `indexes` replaced or dropped) and carry it out: from the plan's write on the commit is
    /// decided, and a killed writer's successor finishes it.
    fn decide(
        &mut self,
        staging: &Staging,
        manifest: &Tileset,
        moves: Vec<String>,
        removes: Vec<String>,
        indexes: Vec<String>,
    ) -> Result<()> {
        let json = serde_json::to_string_pretty(manifest).expect("manifest serialises");
        write_atomic_bytes(&staging.root.join(MANIFEST), json.as_bytes())?;
        let plan = Plan {
            staging: staging
                .root
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            moves,
            removes,
            indexes,
        };
        let plan_path = self.state().join(PLAN);
        write_atomic_bytes(
            &plan_path,
            &serde_json::to_vec(&plan).expect("plan serialises"),
        )?;
        self.apply(&plan_path)?;
        self.committed = true;
        self.staging = None;
        Ok(())
    }

    /// Remove `products` from the tileset (their folders, indexes, unit records and manifest
    /// entries), nothing else: `manifest` is the tileset's manifest as it is. Crash-safe as a
    /// commit is (a kill is finished by the next writer).
    pub fn drop_products(&mut self, products: &[Product], mut manifest: Tileset) -> Result<()> {
        if products.is_empty() {
            return Ok(());
        }
        let staging = self.stage("drop", "drop")?;
        let mut removes = Vec::new();
        let mut indexes = Vec::new();
        for p in products {
            p.clear(&mut manifest);
            removes.extend(p.dirs().iter().map(|d| d.to_string()));
            indexes.push(p.name().to_string());
            indexes.push(format!("{}{UNITS_SUFFIX}", p.name()));
        }
        self.decide(&staging, &manifest, Vec::new(), removes, indexes)
    }

    /// Carry out a written commit plan; every step can be repeated after a kill.
    fn apply(&self, plan_path: &Path) -> Result<()> {
        let bytes = fsio::read_capped(plan_path, 1 << 20, "a commit plan")?;
        let plan: Plan = serde_json::from_slice(&bytes)
            .map_err(|e| Error::invalid(plan_path, format!("damaged commit plan ({e})")))?;
        let state = self.state();
        let staged = state.join("staging").join(&plan.staging);
        let trash = state.join("trash");
        let index = state.join("index");
        std::fs::create_dir_all(&trash).at(&trash)?;
        std::fs::create_dir_all(&index).at(&index)?;
        let _readers_out = CommitLock::exclusive(&self.dir)?;
        for p in &plan.indexes {
            let f = index.join(format!("{p}.json"));
            if f.exists() && !staged.join("index").join(format!("{p}.json")).exists() {
                std::fs::remove_file(&f).at(&f)?;
            }
        }
        let to_trash = |d: &str| -> Result<()> {
            let cur = self.dir.join(d);
            if cur.exists() {
                let t = trash.join(d);
                remove_tree(&t)?;
                std::fs::rename(&cur, &t).at(&cur)?;
            }
            Ok(())
        };
        for d in &plan.moves {
            let src = staged.join(d);
            if src.exists() {
                to_trash(d)?;
                let dst = self.dir.join(d);
                std::fs::rename(&src, &dst).at(&dst)?;
            }
        }
        for d in &plan.removes {
            to_trash(d)?;
        }
        for p in &plan.indexes {
            let src = staged.join("index").join(format!("{p}.json"));
            if src.exists() {
                let dst = index.join(format!("{p}.json"));
                std::fs::rename(&src, &dst).at(&dst)?;
            }
        }
        let m = staged.join(MANIFEST);
        if m.exists() {
            let dst = self.dir.join(MANIFEST);
            std::fs::rename(&m, &dst).at(&dst)?;
        }
        sync_dir(&self.dir)?;
        sync_dir(&index)?;
        std::fs::remove_file(plan_path).at(plan_path)?;
        sync_dir(&state)?;
        drop(_readers_out);
        remove_tree(&trash)?;
        remove_tree(&staged)?;
        Ok(())
    }
}

impl Drop for Writer {
    /// A run that ends without committing (an error) leaves the tileset as it was: its staging
    /// folder goes, and so does the folder itself if this writer made it and never committed.
    fn drop(&mut self) {
        if self.committed {
            return;
        }
        if let Some(s) = self.staging.take() {
            let _ = std::fs::remove_dir_all(s);
        }
        // Only what this writer made, and only if nothing was ever committed there (a nested
        // writer of the same process may have committed while this one held the lock).
        if self.created_dir && !self.dir.join(MANIFEST).exists() {
            let _ = std::fs::remove_dir_all(&self.dir);
        } else if self.created_state && !self.state().join("index").exists() {
            let _ = std::fs::remove_dir_all(self.state());
        }
    }
}

/// True when every file the index of `product` lists in the tileset `dir` is present with its
/// size ([`Writer::verify`], for a reader that is not the writer: a shard).
pub fn verify_product(dir: &Path, product: Product) -> bool {
    let path = dir
        .join(STATE_DIR)
        .join("index")
        .join(format!("{}.json", product.name()));
    let Ok(bytes) = fsio::read_capped(&path, 1 << 30, "an index") else {
        return false;
    };
    let Ok(files) = serde_json::from_slice::<Vec<IndexEntry>>(&bytes) else {
        return false;
    };
    files.iter().all(|IndexEntry(rel, len, _)| {
        std::fs::metadata(dir.join(rel)).is_ok_and(|m| m.is_file() && m.len() == *len)
    })
}

/// One of several processes (on one host or several sharing the folder) that each run some
/// units of one stage at the same time ([`crate::runner::Role::Shard`]): it holds the tileset's
/// shard lock ([`ShardLock`]), so no writer begins (nor commits) while it runs, and stages its
/// files in the stage's one staging folder, which the first shard makes; it never commits nor
/// removes anything.
pub struct ShardWriter {
    dir: PathBuf,
    _lock: ShardLock,
}

impl ShardWriter {
    /// Hold the tileset in `dir` as a shard: refused at once while a writer holds it, or when a
    /// commit a killed writer left is pending (a writer finishes it).
    pub fn begin(dir: &Path) -> Result<ShardWriter> {
        let lock = ShardLock::acquire(dir)?;
        let plan = dir.join(STATE_DIR).join(PLAN);
        if plan.exists() {
            return Err(Error::invalid(
                &plan,
                "a commit of this tileset was interrupted: a writer (a stage run whole, or the \
                 finish of a sharded run) completes it first; run the shards after it",
            ));
        }
        Ok(ShardWriter {
            dir: dir.to_path_buf(),
            _lock: lock,
        })
    }

    /// The staging folder of stage `name` for a run with `run_key`, for the shard whose logs
    /// are called `log`: made if missing, at once and whole (a folder with its run marker,
    /// renamed into place: of shards starting together one makes it and the others find it),
    /// kept when shards of the same key made it. Refused when it holds a run of another key
    /// or of one process: that run's finish (or a run of the stage whole, which replaces it)
    /// comes first.
    pub fn stage(&self, name: &str, run_key: &str, log: &str) -> Result<Staging> {
        let staging = self.dir.join(STATE_DIR).join("staging");
        let root = staging.join(name);
        if !root.exists() {
            std::fs::create_dir_all(&staging).at(&staging)?;
            let fresh = staging.join(format!(".{name}.new.{log}"));
            remove_tree(&fresh)?;
            std::fs::create_dir_all(&fresh).at(&fresh)?;
            let m = RunMarker {
                run_key: run_key.to_string(),
                boot: None,
                sharded: true,
            };
            write_atomic_bytes(
                &fresh.join(RUN),
                &serde_json::to_vec(&m).expect("marker serialises"),
            )?;
            // A folder renamed onto one that exists, not empty, is refused: another shard's
            // stands.
            if std::fs::rename(&fresh, &root).is_err() {
                remove_tree(&fresh)?;
            } else {
                sync_dir(&staging)?;
            }
        }
        let (resume, pending) = match RunMarker::read(&root) {
            Some(m) if m.run_key == run_key && m.sharded => (true, None),
            Some(m) if m.run_key == run_key => (false, Some("a run of this stage by one process")),
            Some(_) => (
                false,
                Some("shards or a run of this stage with another run key"),
            ),
            None => (
                false,
                Some("a run of this stage that did not get to write its marker"),
            ),
        };
        if let Some(what) = pending {
            return Err(Error::invalid(
                &root,
                format!(
                    "{what} left this staging folder: finish that run (or run the {name} stage \
                     whole, which replaces it) before running shards of this one"
                ),
            ));
        }
        let _hashes = fsio::StagedHashes::record_below_as(&root, log);
        Ok(Staging {
            root,
            resume,
            log: log.to_string(),
            _hashes,
        })
    }
}

/// The index entries of the files (`rel`, size) staged below `root`, and how many of them
/// were read back and hashed. A file's blake3 is the one [`fsio::write_staged`] recorded as it
/// wrote the file when a record's size, inode and mtime are the file's on disk now; any other
/// file (no record: written by a process killed between its rename and its record, by an older
/// version, or not through `write_staged`; a record of an earlier version of the file, whose
/// stamp no longer matches) is read and hashed, in parallel, as every file was before the
/// records. Either way the entry holds the blake3 of the file's bytes, so the index is the same.
///
/// Trusting a matching record is safe because only this tool writes a staging folder, under the
/// tileset's writer lock, and always through a temp file renamed into place: a rewrite is a new
/// inode (made while the old one still exists) with a new record, so a record whose stamp
/// matches is of the bytes now there. A record that does not match is ignored, never an error.
/// Were the file changed in place behind the tool's back keeping its size, inode and mtime, the
/// index would keep the hash of what the tool wrote, and the store's reads and `verify` would
/// refuse the changed file, as they refuse one changed after the commit.
pub fn index_entries(
    root: &Path,
    files: Vec<(String, u64)>,
    recorded: &fsio::StagedHashRecords,
) -> Result<(Vec<IndexEntry>, usize)> {
    use rayon::prelude::*;
    let entries: Vec<(IndexEntry, bool)> = files
        .into_par_iter()
        .map(|(rel, len)| {
            let p = root.join(&rel);
            if !recorded.is_empty() {
                let stamp = fsio::FileStamp::of(&std::fs::symlink_metadata(&p).at(&p)?);
                if stamp.len == len {
                    if let Some(h) = recorded.hash_of(&rel, stamp) {
                        return Ok((IndexEntry(rel, len, h.to_hex().to_string()), false));
                    }
                }
            }
            let f = std::fs::File::open(&p).at(&p)?;
            let mut h = blake3::Hasher::new();
            h.update_reader(f).at(&p)?;
            Ok((
                IndexEntry(rel, len, h.finalize().to_hex().to_string()),
                true,
            ))
        })
        .collect::<Result<_>>()?;
    let hashed = entries.iter().filter(|(_, h)| *h).count();
    Ok((entries.into_iter().map(|(e, _)| e).collect(), hashed))
}

/// A list of plain names in an unlisted product's manifest entry (`dirs`, `reads`); the
/// manifest's validation has checked them.
fn unlisted_field(entry: &serde_json::Value, field: &str) -> Vec<String> {
    entry
        .get(field)
        .and_then(|v| v.as_array())
        .map(|a| {
            a.iter()
                .filter_map(|x| x.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod record_tests {
    use super::*;

    /// Records from several processes' logs are read back by name; a line a crash cut short
    /// is not; a later record of the same unit wins.
    #[test]
    fn unit_records_survive_in_whole_lines_only() {
        let d = tempfile::tempdir().unwrap();
        let s = Staging {
            root: d.path().to_path_buf(),
            resume: true,
            log: std::process::id().to_string(),
            _hashes: fsio::StagedHashes::record_below(d.path()),
        };
        assert!(s.read_records().unwrap().is_empty());
        let log = s.record_log().unwrap();
        log.append("3-px-0-1", b"{\"a\":1}").unwrap();
        log.append("3-px-0-2", b"[1,2]").unwrap();
        // Another process's log: one whole line, then one cut short.
        let other = d.path().join("units").join("1.log");
        std::fs::write(&other, b"3-px-0-2\t[3]\n3-px-0-3\t{\"cut").unwrap();
        let r = s.read_records().unwrap();
        assert_eq!(r.len(), 2, "{r:?}");
        assert_eq!(r["3-px-0-1"].0, b"{\"a\":1}");
        assert!(r["3-px-0-2"].0 == b"[1,2]" || r["3-px-0-2"].0 == b"[3]");
        assert_eq!(r["3-px-0-1"].1, std::process::id().to_string());
        assert!(!r.contains_key("3-px-0-3"));
    }
}

#[cfg(test)]
mod hash_record_tests {
    use super::*;

    fn staged(root: &Path, rel: &str, bytes: &[u8]) {
        let p = root.join(rel);
        fsio::write_staged(&p, |f| f.write_all(bytes).at(&p)).unwrap();
    }

    /// Every file's index entry as the commit made it before the records: read back and hashed.
    fn read_back(root: &Path, files: &[(String, u64)]) -> Vec<IndexEntry> {
        files
            .iter()
            .map(|(rel, len)| {
                let h = blake3::hash(&std::fs::read(root.join(rel)).unwrap());
                IndexEntry(rel.clone(), *len, h.to_hex().to_string())
            })
            .collect()
    }

    fn log_of_this_process(root: &Path) -> PathBuf {
        root.join(fsio::HASH_LOGS)
            .join(format!("{}.log", std::process::id()))
    }

    /// Files staged through `write_staged` are indexed from their records without a read; a
    /// file without a usable record (the process killed between the rename and the record, a
    /// record cut short, a file rewritten or resized since its record) is read and hashed, and
    /// the index is the same either way.
    #[test]
    fn the_commit_uses_records_that_match_and_hashes_the_rest() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path().join("staging").join("mip");
        let hashes = fsio::StagedHashes::record_below(&root);
        let names: Vec<String> = (0..8).map(|i| format!("maxmip/0/px/0/{i}.exr")).collect();
        for (i, n) in names.iter().enumerate() {
            staged(&root, n, &vec![i as u8; 1000 + 37 * i]);
        }
        let files = || {
            list_files(&root.join("maxmip"))
                .unwrap()
                .into_iter()
                .map(|(r, l)| (format!("maxmip/{r}"), l))
                .collect::<Vec<_>>()
        };
        let recorded = fsio::read_staged_hashes(&root);
        assert_eq!(recorded.len(), 8);
        let (entries, hashed) = index_entries(&root, files(), &recorded).unwrap();
        assert_eq!(hashed, 0, "every file had its record");
        assert_eq!(entries, read_back(&root, &files()));

        let log = log_of_this_process(&root);
        let text = std::fs::read_to_string(&log).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 8);
        // 7: killed between its rename and its record (the line never written); 6: its line cut
        // short by the kill (every prefix of it is refused, not only this one).
        for cut in 0..lines[6].len() {
            assert!(
                fsio::read_staged_hashes_from(format!("{}\n", &lines[6][..cut]).as_bytes())
                    .is_empty(),
                "a line cut at {cut} was read"
            );
        }
        let mut kept = lines[..6].join("\n");
        kept.push('\n');
        kept.push_str(&lines[6][..lines[6].len() - 5]);
        std::fs::write(&log, &kept).unwrap();
        // 0: rewritten since by something else, same size (a new inode: the record's stamp no
        // longer matches); 1: grown since (its size no longer matches).
        let p0 = root.join(&names[0]);
        let tmp = root.join("maxmip/0/px/0/.0.exr.tmp.1");
        std::fs::write(&tmp, vec![9u8; 1000]).unwrap();
        std::fs::rename(&tmp, &p0).unwrap();
        std::fs::OpenOptions::new()
            .append(true)
            .open(root.join(&names[1]))
            .unwrap()
            .write_all(b"padding")
            .unwrap();
        // 2: a record from another process whose size is wrong, one with a malformed hash,
        // garbage: all ignored.
        let other = root.join(fsio::HASH_LOGS).join("1.log");
        let l2: Vec<&str> = lines[2].split('\t').collect();
        std::fs::write(
            &other,
            format!(
                "{}\t5\t{}\t{}\t{}\n{}\t{}\t{}\t{}\tXYZ\nnot a record\n\n",
                l2[0], l2[2], l2[3], l2[4], l2[0], l2[1], l2[2], l2[3]
            ),
        )
        .unwrap();
        let recorded = fsio::read_staged_hashes(&root);
        assert_eq!(
            recorded.len(),
            6 + 1,
            "the six whole lines and the sized one"
        );
        let (entries, hashed) = index_entries(&root, files(), &recorded).unwrap();
        assert_eq!(entries, read_back(&root, &files()));
        assert_eq!(hashed, 4, "files 0, 1, 6 and 7 read back");
        drop(hashes);
    }

    /// Two records of a file that both match its stamp but disagree (which a run of this tool
    /// cannot leave) are not trusted: the file is hashed. A single record that matches the
    /// file's size, inode and mtime is trusted as it is (why that is safe: `index_entries`).
    #[test]
    fn conflicting_records_are_not_trusted_and_a_matching_one_is() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path().to_path_buf();
        let _hashes = fsio::StagedHashes::record_below(&root);
        staged(&root, "minmax/1/nz/0/0.exr", b"the bytes written");
        let files = list_files(&root.join("minmax"))
            .unwrap()
            .into_iter()
            .map(|(r, l)| (format!("minmax/{r}"), l))
            .collect::<Vec<_>>();
        let line = std::fs::read_to_string(log_of_this_process(&root)).unwrap();
        let (head, _) = line.trim_end().rsplit_once('\t').unwrap();
        let lie = format!("{head}\t{}\n", blake3::hash(b"other bytes").to_hex());
        let other = root.join(fsio::HASH_LOGS).join("1.log");
        std::fs::write(&other, &lie).unwrap();
        let (entries, hashed) =
            index_entries(&root, files.clone(), &fsio::read_staged_hashes(&root)).unwrap();
        assert_eq!((hashed, &entries), (1, &read_back(&root, &files)));
        // The lying record alone matches the file's stamp: it is what the index says.
        std::fs::remove_file(log_of_this_process(&root)).unwrap();
        let (entries, hashed) =
            index_entries(&root, files.clone(), &fsio::read_staged_hashes(&root)).unwrap();
        assert_eq!(hashed, 0);
        assert_eq!(
            entries[0].2,
            blake3::hash(b"other bytes").to_hex().to_string()
        );
    }

    /// A process whose pid a killed one had appends to that one's log: a line the kill cut
    /// short is ended first, so the new records read back whole.
    #[test]
    fn a_log_reused_by_pid_ends_the_cut_line_first() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path().to_path_buf();
        let log = log_of_this_process(&root);
        std::fs::create_dir_all(log.parent().unwrap()).unwrap();
        std::fs::write(&log, b"height/0/px/0/0.exr\t12").unwrap();
        let _hashes = fsio::StagedHashes::record_below(&root);
        staged(&root, "height/0/px/0/1.exr", b"tile");
        let recorded = fsio::read_staged_hashes(&root);
        assert_eq!(recorded.len(), 1);
        let stamp =
            fsio::FileStamp::of(&std::fs::metadata(root.join("height/0/px/0/1.exr")).unwrap());
        assert_eq!(
            recorded.hash_of("height/0/px/0/1.exr", stamp),
            Some(blake3::hash(b"tile"))
        );
    }

    /// Nothing is recorded outside a registered root, nor after its registration ends.
    #[test]
    fn only_registered_roots_record() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path().join("a");
        staged(&root, "x/1.bin", b"1");
        let h = fsio::StagedHashes::record_below(&root);
        staged(&d.path().join("b"), "x/2.bin", b"2");
        staged(&root, "x/3.bin", b"3");
        drop(h);
        staged(&root, "x/4.bin", b"4");
        let r = fsio::read_staged_hashes(&root);
        assert_eq!(r.len(), 1);
        assert!(!d.path().join("b").join(fsio::HASH_LOGS).exists());
    }
}
