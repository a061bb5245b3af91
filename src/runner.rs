//! The stage runner: what every stage that writes a tileset product has in common. A stage
//! declares a [`StageSpec`] (its name, the products it writes, the version strings of its
//! format and algorithm); the runner derives its run key, takes the tileset's writer lock,
//! answers "up to date" only when the manifest's key matches *and* every file the product's
//! index lists is on disk, resumes an interrupted run of the same key, and commits the result,
//! which invalidates every product downstream of the ones written (from
//! [`Product::reads`], without the stage naming them).
//!
//! A stage's own work: validate its inputs before calling [`start`] (a refused run touches
//! nothing), write its files below [`Run::out`] (keeping those a resumed run already made), and
//! hand its updated manifest to [`Run::commit`].

use std::borrow::Cow;
use std::path::Path;

use rayon::prelude::*;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::layout::TileId;
use crate::manifest::Tileset;
use crate::progress::Progress;
use crate::tileset::deps::Dep;
use crate::tileset::writer::{Staging, Writer};
use crate::tileset::{Product, Store};

/// What a stage declares (constant for most stages; composed for a stage with sinks).
#[derive(Clone, Debug)]
pub struct StageSpec {
    /// Name of the stage (its staging folder, progress label).
    pub name: &'static str,
    /// Products it writes; the first is the one whose run key decides "up to date".
    pub writes: Cow<'static, [Product]>,
    /// Products it reads (the graph runs their stages first).
    pub reads: Cow<'static, [Product]>,
    /// Version strings of its output format and algorithms: a change recomputes.
    pub format: Cow<'static, [&'static str]>,
}

/// The run key of a stage: the tool version, the stage's format, the run keys of the products
/// it reads and its parameters. Equal keys mean identical output.
pub fn run_key(spec: &StageSpec, inputs: &[&str], params: &[&[u8]]) -> String {
    crate::manifest::consistency::run_key_of(
        env!("CARGO_PKG_VERSION"),
        &spec.format,
        inputs,
        params,
    )
}

/// What a stage's run key hashes besides the run keys of its inputs, as text: this tool's
/// version, the stage's format strings and `params` (recorded in the product's manifest entry
/// as `run_key_basis`; `basis.key(inputs)` is [`run_key`] of the same parameters).
pub fn key_basis(spec: &StageSpec, params: Vec<String>) -> crate::format::KeyBasis {
    crate::format::KeyBasis {
        tool: env!("CARGO_PKG_VERSION").to_string(),
        format: spec.format.iter().map(|f| f.to_string()).collect(),
        params,
    }
}

/// A run under way.
pub struct Run {
    spec: StageSpec,
    writer: Writer,
    staging: Staging,
    /// The run key differs from the one the manifest records (not a repair of missing files).
    changed: bool,
}

/// What [`start`] found.
// Made once per run and matched at once: its size does not matter.
#[allow(clippy::large_enum_variant)]
pub enum Start {
    /// The tileset already holds this stage's output for this run key, every file present.
    UpToDate,
    Run(Run),
}

/// Begin a stage on the tileset in `dir` (made if missing). `current` gives the manifest as
/// the stage read it *under the writer lock* (None: no tileset yet).
pub fn start(
    writer: Writer,
    spec: StageSpec,
    key: &str,
    current: Option<&Tileset>,
) -> Result<Start> {
    start_units(writer, spec, key, current, true)
}

/// [`start`], where `units_current` says whether the product's units are those this run
/// would make (false: the same run key over another selection of tiles, or inputs changed
/// under some units; the run goes ahead, reusing what it can, and what was derived from the
/// product is not invalidated by the key).
pub fn start_units(
    writer: Writer,
    spec: StageSpec,
    key: &str,
    current: Option<&Tileset>,
    units_current: bool,
) -> Result<Start> {
    let primary = spec.writes[0];
    let changed = current.and_then(|ts| primary.recorded_key(ts)) != Some(key);
    if let Some(ts) = current {
        if units_current
            && primary.recorded_key(ts) == Some(key)
            && spec
                .writes
                .iter()
                .filter(|p| p.recorded_key(ts).is_some())
                .all(|&p| writer.verify(p))
        {
            writer.discard_stage(spec.name, key)?;
            return Ok(Start::UpToDate);
        }
    }
    let mut writer = writer;
    let staging = writer.stage(spec.name, key)?;
    Ok(Start::Run(Run {
        spec,
        writer,
        staging,
        changed,
    }))
}

impl Run {
    /// Root under which the run writes its product folders (`height/…`, `maxmip/…`).
    pub fn out(&self) -> &Path {
        &self.staging.root
    }

    /// True when an interrupted run of the same key left files to keep.
    pub fn resume(&self) -> bool {
        self.staging.resume
    }

    /// The tileset's folder.
    pub fn dir(&self) -> &Path {
        self.writer.dir()
    }

    /// Put the committed file `from` at `rel` in the run's staging folder, kept rather than
    /// made again ([`Staging::link`]).
    pub fn staging_link(&self, from: &Path, rel: &str, hash: &blake3::Hash) -> Result<()> {
        self.staging.link(from, rel, hash)
    }

    /// Leave the staged run uncommitted for a later run of the same key to complete.
    pub fn leave(mut self) {
        self.writer.leave_staged();
    }

    /// Swap the finished run in with `manifest` as the tileset's manifest.
    pub fn commit(self, manifest: Tileset) -> Result<()> {
        let Run {
            spec,
            mut writer,
            staging,
            changed,
        } = self;
        writer.commit(staging, &spec.writes, manifest, changed)
    }
}

/// Default cap on a stage's output before compression (tiling, mipmaps).
pub const DEFAULT_MAX_OUTPUT_GIB: f64 = 64.0;

/// Check an output cap given in GiB: a positive number (NaN or a negative cap is refused, not
/// read as "no cap").
pub fn check_output_cap(param: &'static str, gib: f64) -> Result<()> {
    if gib.is_nan() || gib <= 0.0 {
        return Err(Error::param(
            param,
            format!("{gib} is not a size: give a positive number of GiB"),
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Stages as units of work

/// One unit of a stage's work: normally one output tile, with what it reads and what it costs.
/// Units are named by their output tile, stable across processes, so that a run can be split
/// between processes ([`Select`]) and finished by whichever completes the last unit.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Unit {
    /// The tile this unit writes (a unit writing several tiles is named by the first).
    pub tile: TileId,
    /// Every tile it writes (tiling writes a group of tiles sampled together).
    pub writes: Vec<TileId>,
    /// What it reads.
    pub reads: Vec<Reads>,
    /// Estimated cost, in the stage's own unit (pixels, pixel·azimuths): for balancing shards
    /// and for plans, not a promise.
    pub cost: f64,
}

impl Unit {
    /// A unit writing the one tile `tile`.
    pub fn tile(tile: TileId, reads: Vec<Reads>, cost: f64) -> Unit {
        Unit {
            tile,
            writes: vec![tile],
            reads,
            cost,
        }
    }

    /// The unit's name: `level/face/x/y` of its tile.
    pub fn key(&self) -> String {
        let t = self.tile;
        format!("{}/{}/{}/{}", t.level, t.face.name(), t.x, t.y)
    }
}

/// What a unit reads.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reads {
    /// One tile of a product.
    Tile { product: Product, tile: TileId },
    /// The tiles of a product's level within `margin_px` pixels of a tile (across face edges).
    Around {
        product: Product,
        tile: TileId,
        margin_px: u64,
    },
}

/// Which units a run executes.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Select {
    /// Every unit: the run commits.
    #[default]
    All,
    /// Shard `index` of `count` (0-based): a contiguous run of units of about a `count`th of
    /// the cost. The run commits when it completes the last units left.
    Shard { index: usize, count: usize },
    /// The units with these keys ([`Unit::key`]).
    Keys(Vec<String>),
}

impl Select {
    /// Parse `K/N` (shard K of N, 0-based).
    pub fn shard(s: &str) -> std::result::Result<Select, String> {
        let (k, n) = s
            .split_once('/')
            .ok_or_else(|| format!("'{s}' is not K/N (e.g. 0/4)"))?;
        let (k, n): (usize, usize) = (
            k.trim()
                .parse()
                .map_err(|_| format!("'{k}' is not a shard index"))?,
            n.trim()
                .parse()
                .map_err(|_| format!("'{n}' is not a shard count"))?,
        );
        if n == 0 || n > MAX_SHARDS || k >= n {
            return Err(format!(
                "shard {k}/{n}: the count must be 1..={MAX_SHARDS} and the index below it"
            ));
        }
        Ok(Select::Shard { index: k, count: n })
    }

    /// The indices (into `units`) this selection takes, a shard cut by the units' own costs.
    pub fn pick(&self, units: &[Unit]) -> Vec<usize> {
        let costs: Vec<f64> = units.iter().map(|u| u.cost).collect();
        self.pick_priced(units, &costs)
    }

    /// The indices (into `units`, in order) this selection takes, a shard cut by `costs` (one
    /// per unit).
    pub fn pick_priced(&self, units: &[Unit], costs: &[f64]) -> Vec<usize> {
        match self {
            Select::All => (0..units.len()).collect(),
            Select::Shard { index, count } => Select::assign(units, costs, *count)
                .into_iter()
                .enumerate()
                .filter(|&(_, s)| s == *index)
                .map(|(i, _)| i)
                .collect(),
            Select::Keys(keys) => units
                .iter()
                .enumerate()
                .filter(|(_, u)| keys.contains(&u.key()))
                .map(|(i, _)| i)
                .collect(),
        }
    }
}

impl Select {
    /// The shard (0-based, below `count`) of each unit: the units are laid along a
    /// space-filling curve — by level, then face, then the Hilbert curve over the face's
    /// tiles, so that a shard's tiles lie together and the context they read around them is
    /// shared — and the cumulative cost along it is cut into `count` equal spans; a unit
    /// belongs to the span its cost midpoint falls in. The same cut whatever process computes
    /// it (negative or NaN costs count as zero).
    pub fn assign(units: &[Unit], costs: &[f64], count: usize) -> Vec<usize> {
        let count = count.max(1);
        let cost = |i: usize| costs.get(i).copied().filter(|c| *c > 0.0).unwrap_or(0.0);
        let mut along: Vec<usize> = (0..units.len()).collect();
        along.sort_by_key(|&i| {
            let t = units[i].tile;
            (t.level, t.face, hilbert(t.x, t.y), i)
        });
        let total: f64 = along.iter().map(|&i| cost(i)).sum();
        let mut out = vec![0; units.len()];
        let mut acc = 0.0;
        for (k, &i) in along.iter().enumerate() {
            let c = cost(i);
            let mid = acc + c / 2.0;
            acc += c;
            out[i] = if total > 0.0 {
                ((mid / total * count as f64) as usize).min(count - 1)
            } else {
                k * count / units.len().max(1)
            };
        }
        out
    }
}

/// The position of tile column `x`, row `y` along the Hilbert curve over a 2³² × 2³² grid
/// (any level's tiles of a face lie in its corner square of 2^level, which the curve visits
/// whole before leaving it).
fn hilbert(x: u32, y: u32) -> u64 {
    const N: u64 = 1 << 32;
    let (mut x, mut y) = (u64::from(x), u64::from(y));
    let mut d = 0u64;
    let mut s = N / 2;
    while s > 0 {
        let rx = u64::from(x & s > 0);
        let ry = u64::from(y & s > 0);
        d += s * s * ((3 * rx) ^ ry);
        // Turn the quadrant so that the curve within it starts at its corner.
        if ry == 0 {
            if rx == 1 {
                x = N - 1 - x;
                y = N - 1 - y;
            }
            std::mem::swap(&mut x, &mut y);
        }
        s >>= 1;
    }
    d
}

/// Most shards a run can be split into.
pub const MAX_SHARDS: usize = 100_000;

/// How a stage's units run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Order {
    /// Spread over the thread pool (each unit single-threaded).
    Parallel,
    /// One after another in plan order, each using the whole pool (and the tile cache's
    /// locality from one unit to the next).
    Sequential,
}

/// What a unit of a stage sees.
pub struct Cx<'a, P> {
    /// The tileset as committed, read through the store.
    pub store: &'a Store,
    /// The staging root the run writes its product folders under.
    pub out: &'a Path,
    /// The stage's plan of this run.
    pub plan: &'a P,
    /// The run key.
    pub key: &'a str,
    pub progress: &'a dyn Progress,
}

/// A unit's result as the finish sees it.
pub struct Finished<D> {
    pub unit: Unit,
    pub done: D,
    /// Whether this process computed it (else a run of the same key, an earlier shard or an
    /// interrupted run, did).
    pub here: bool,
}

/// A stage: what it writes and reads, its units, how to do one, and how to finish the run.
/// [`execute`] runs it with the staging, resume and commit every stage shares.
pub trait Stage: Sync {
    /// What a run knows once the tileset is checked (levels, ranges, encoders).
    type Plan: Sync;
    /// What one unit reports to the finish. It is stored beside the unit's files so that
    /// another process can finish the run: it must round-trip through JSON exactly (floats
    /// that may be NaN as bits).
    type Done: Serialize + DeserializeOwned + Send;
    /// What one worker keeps from unit to unit (buffers).
    type Scratch: Send;
    /// What a run reports.
    type Report;

    fn spec(&self) -> StageSpec;
    /// Check the options alone, before the tileset is even read.
    fn check(&self) -> Result<()> {
        Ok(())
    }
    /// Check the options and the tileset and plan the run; refuses before anything is
    /// written. Called on the manifest as read, and again under the writer lock.
    fn plan(&self, dir: &Path, ts: &Tileset) -> Result<Self::Plan>;
    /// The run key (from the inputs' run keys and every parameter that changes a byte).
    fn key(&self, ts: &Tileset, plan: &Self::Plan) -> String;
    /// The units, in the order a whole run executes them.
    fn units(&self, ts: &Tileset, plan: &Self::Plan) -> Result<Vec<Unit>>;
    fn order(&self) -> Order {
        Order::Parallel
    }
    fn scratch(&self, plan: &Self::Plan) -> Self::Scratch;
    /// Do one unit: write its files below `cx.out`.
    fn run_unit(
        &self,
        cx: &Cx<Self::Plan>,
        unit: &Unit,
        scratch: &mut Self::Scratch,
    ) -> Result<Self::Done>;
    /// Every unit done (in plan order): write what spans units (face pyramids) and return
    /// the manifest to commit and the report.
    fn finish(
        &self,
        cx: &Cx<Self::Plan>,
        done: Vec<Finished<Self::Done>>,
    ) -> Result<(Tileset, Self::Report)>;
    /// The report of a run that found its output up to date.
    fn up_to_date(&self, store: &Store, plan: &Self::Plan, units: &[Unit]) -> Self::Report;
    /// Recompute, on the tileset as it is now, a value one of this stage's units recorded as
    /// a dependency ([`Dep::Value`]) by its name; None: not a name this stage records (the
    /// unit is redone).
    fn revalue(&self, _store: &Store, _plan: &Self::Plan, _name: &str) -> Option<String> {
        None
    }
}

/// A unit's record: what it read and what it reported to the finish. Kept in the staging
/// folder's unit log while a run lasts (for a resume) and, once it commits, in
/// `.penumbra/index/<product>.units.json` with the run key (for the next run's reuse).
#[derive(Serialize, serde::Deserialize)]
struct UnitRecord {
    deps: Vec<Dep>,
    done: serde_json::Value,
    /// A shard's record ([`Role::Shard`]): every file the unit staged, with its size and
    /// blake3, for the finish to check; not kept once the run commits.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    files: Vec<FileRecord>,
    /// A shard's record of a unit kept from the last committed run rather than made.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    kept: bool,
}

/// A staged file of a unit: its path below the staging root, size and blake3 (hex).
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
struct FileRecord(String, u64, String);

impl FileRecord {
    fn of((rel, len, hash): &crate::fsio::Written) -> FileRecord {
        FileRecord(rel.clone(), *len, hash.to_hex().to_string())
    }

    /// Why the file is not what the record says, if it is not.
    fn problem(&self, root: &Path) -> Option<String> {
        let p = root.join(&self.0);
        let m = match std::fs::symlink_metadata(&p) {
            Ok(m) => m,
            Err(_) => return Some(format!("{} is missing", self.0)),
        };
        if !m.is_file() {
            return Some(format!("{} is not a regular file", self.0));
        }
        if m.len() != self.1 {
            return Some(format!(
                "{} has {} bytes, its record {}",
                self.0,
                m.len(),
                self.1
            ));
        }
        let mut h = blake3::Hasher::new();
        let read = std::fs::File::open(&p).and_then(|f| h.update_reader(f).map(|_| ()));
        if let Err(e) = read {
            return Some(format!("{} cannot be read ({e})", self.0));
        }
        (h.finalize().to_hex().as_str() != self.2).then(|| {
            format!(
                "{} does not hold the bytes its record's blake3 says",
                self.0
            )
        })
    }
}

/// The unit records a committed run left: its run key and each unit's record, by unit name.
#[derive(Serialize, serde::Deserialize)]
struct UnitRecords {
    key: String,
    units: std::collections::BTreeMap<String, UnitRecord>,
}

/// A unit done here: its report to the finish and its record.
type UnitResult<D> = Result<(D, UnitRecord)>;

/// Largest unit-records file read (a record is a few hundred bytes; 10⁶ units).
const MAX_UNIT_RECORDS_BYTES: u64 = 1 << 30;

/// The unit records of `product`'s last committed run, when there are any and they read back
/// (a damaged file only costs the reuse).
fn load_unit_records(dir: &Path, product: Product) -> Option<UnitRecords> {
    let bytes = crate::tileset::writer::read_unit_records(dir, product, MAX_UNIT_RECORDS_BYTES)?;
    serde_json::from_slice(&bytes).ok()
}

/// Whether every dependency a unit recorded holds for the tileset as it is now.
fn deps_hold<S: Stage>(stage: &S, store: &Store, plan: &S::Plan, deps: &[Dep]) -> bool {
    deps.iter().all(|d| match store.dep_holds(d) {
        Some(h) => h,
        None => match d {
            Dep::Value { name, value } => stage.revalue(store, plan, name).as_ref() == Some(value),
            _ => false,
        },
    })
}

/// A committed file a reused unit keeps: its path relative to the tileset, size and blake3
/// as indexed.
type Kept = (String, u64, blake3::Hash);

/// The committed files of each tile of the products `writes` (per-tile files only, at
/// `<dir>/<level>/<face>/<y>/<x>.<ext>`), from their indexes: what a reused unit keeps.
fn tile_files(
    store: &Store,
    writes: &[Product],
) -> Result<std::collections::HashMap<TileId, Vec<Kept>>> {
    let mut out: std::collections::HashMap<TileId, Vec<Kept>> = Default::default();
    for &p in writes {
        let Some(ix) = store.index(p)? else { continue };
        for (rel, (len, h)) in &ix.files {
            let parts: Vec<&str> = rel.split('/').collect();
            let [d, level, face, y, file] = parts[..] else {
                continue;
            };
            if !p.dirs().contains(&d) {
                continue;
            }
            let Some((x, _ext)) = file.split_once('.') else {
                continue;
            };
            let (Ok(level), Ok(y), Ok(x)) = (level.parse(), y.parse(), x.parse()) else {
                continue;
            };
            let Some(face) = crate::cube::Face::ALL.iter().find(|f| f.name() == face) else {
                continue;
            };
            out.entry(TileId {
                level,
                face: *face,
                x,
                y,
            })
            .or_default()
            .push((rel.clone(), *len, blake3::Hash::from(*h)));
        }
    }
    Ok(out)
}

/// What [`execute`] did.
pub enum Outcome<R> {
    /// The run committed (or was up to date).
    Done(R),
    /// The selected units are done and staged; others are left for another run of the
    /// same key.
    Partial {
        ran: usize,
        done: usize,
        total: usize,
    },
}

/// The name of a unit's record: `level-face-x-y`.
fn record_name(unit: &Unit) -> String {
    let t = unit.tile;
    format!("{}-{}-{}-{}", t.level, t.face.name(), t.x, t.y)
}

/// Run `stage` on the tileset in `dir`: the units `select` picks that an interrupted or
/// partial run of the same key has not already done, then, when every unit is done, the
/// stage's finish and the commit.
pub fn execute<S: Stage>(
    stage: &S,
    dir: &Path,
    select: &Select,
    progress: &dyn Progress,
) -> Result<Outcome<S::Report>> {
    execute_as(stage, dir, select, Role::Writer, None, progress)
}

/// How a process takes part in a stage's run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Role {
    /// The tileset's one writer: runs the selected units (those earlier runs of the key have
    /// not done) and, when every unit is done, the finish and the commit.
    #[default]
    Writer,
    /// One of several processes that run shards of the units at the same time, on one host or
    /// several sharing the folder ([`Select::Shard`]). It holds the tileset's shard lock (no
    /// writer begins or commits while it runs), stages its units with a record of each file
    /// they wrote (size, blake3) in logs named after the shard, host and process, and never
    /// commits, even when it did the last unit: [`Role::Finish`] does.
    Shard,
    /// After the shards: as the writer, checks that every unit is recorded, still holds, and
    /// that every file each record lists is there with its size and blake3; then the stage's
    /// finish and the commit, as a whole run makes them. Runs no unit: a unit missing or a
    /// file damaged refuses the run, naming the shard to run again, and commits nothing.
    Finish,
}

/// Unit costs a caller prices itself (a scene's plan, from its model of the stage's work):
/// given the stage's units, the cost of each, in order. They replace the units' own estimates
/// in a [`Select::Shard`] selection; all shards of a run and its finish must price alike.
pub type Pricing<'a> = &'a (dyn Fn(&[Unit]) -> Vec<f64> + Sync);

/// The costs a selection cuts by: `pricing`'s, or the units' own.
fn priced(units: &[Unit], pricing: Option<Pricing>) -> Vec<f64> {
    match pricing {
        Some(p) => {
            let c = p(units);
            assert_eq!(c.len(), units.len(), "a pricing prices every unit");
            c
        }
        None => units.iter().map(|u| u.cost).collect(),
    }
}

/// [`execute`] in a given [`Role`], with the shard selection's costs from `pricing` when given.
pub fn execute_as<S: Stage>(
    stage: &S,
    dir: &Path,
    select: &Select,
    role: Role,
    pricing: Option<Pricing>,
    progress: &dyn Progress,
) -> Result<Outcome<S::Report>> {
    match role {
        Role::Writer => execute_writer(stage, dir, select, pricing, progress),
        Role::Shard => execute_shard(stage, dir, select, pricing, progress),
        Role::Finish => execute_finish(stage, dir, select, pricing),
    }
}

fn execute_writer<S: Stage>(
    stage: &S,
    dir: &Path,
    select: &Select,
    pricing: Option<Pricing>,
    progress: &dyn Progress,
) -> Result<Outcome<S::Report>> {
    let spec = stage.spec();
    // Everything that can refuse the run is checked before the tileset's folder is touched.
    stage.check()?;
    stage.plan(dir, &Tileset::load(dir)?)?;
    let writer = Writer::begin(dir)?;
    let store = Store::open_unlocked(dir)?;
    let ts = store.manifest();
    let plan = stage.plan(dir, ts)?;
    let key = stage.key(ts, &plan);
    let units = stage.units(ts, &plan)?;
    let picked = select.pick_priced(&units, &priced(&units, pricing));
    if *select != Select::All && picked.is_empty() {
        return Err(Error::usage(format!(
            "the selection picks none of the {} units of the {} stage",
            units.len(),
            spec.name
        )));
    }
    // What the last committed run of this key made and read: a unit whose every input is
    // as it was then is kept, not redone.
    let primary = spec.writes[0];
    let previous = load_unit_records(dir, primary);
    let prev = previous.as_ref().filter(|r| r.key == key);
    let holds = |r: &UnitRecord| deps_hold(stage, &store, &plan, &r.deps);
    let reusable: Vec<Option<&UnitRecord>> = units
        .iter()
        .map(|u| {
            prev.and_then(|p| p.units.get(&record_name(u)))
                .filter(|r| holds(r))
        })
        .collect();
    let units_current = match prev {
        // No records (a tileset made before them, or another key): the key decides.
        None => true,
        Some(p) => p.units.len() == units.len() && reusable.iter().all(Option::is_some),
    };
    let run = match start_units(writer, spec.clone(), &key, Some(ts), units_current)? {
        Start::UpToDate => return Ok(Outcome::Done(stage.up_to_date(&store, &plan, &units))),
        Start::Run(run) => run,
    };
    let out = run.out().to_path_buf();
    // Units an earlier run of this key finished (its records are written after its files),
    // when what they read is still what the tileset holds.
    let staged = if run.resume() {
        run.staging.read_records()?
    } else {
        Default::default()
    };
    let decode =
        |r: &UnitRecord| -> Option<S::Done> { serde_json::from_value(r.done.clone()).ok() };
    let mut done: Vec<Option<(S::Done, bool, UnitRecord)>> = units
        .iter()
        .map(|u| {
            let r: UnitRecord = serde_json::from_slice(&staged.get(&record_name(u))?.0).ok()?;
            if !holds(&r) {
                return None;
            }
            decode(&r).map(|d| (d, false, r))
        })
        .collect();
    let log = run.staging.record_log()?;
    // Units a committed run made: their files linked into the staging folder, their records
    // logged as if done here (a kill after this keeps them).
    if reusable.iter().any(Option::is_some) {
        let files = tile_files(&store, &spec.writes)?;
        for (i, u) in units.iter().enumerate() {
            let Some(r) = reusable[i] else { continue };
            if done[i].is_some() {
                continue;
            }
            let Some(d) = decode(r) else { continue };
            // A file gone or of another size than indexed (damaged) is not kept: the unit is
            // redone.
            let linked = u.writes.iter().all(|t| {
                files.get(t).into_iter().flatten().all(|(rel, len, h)| {
                    let from = dir.join(rel);
                    std::fs::metadata(&from).is_ok_and(|m| m.is_file() && m.len() == *len)
                        && run.staging.link(&from, rel, h).is_ok()
                })
            });
            if !linked {
                continue;
            }
            let record = UnitRecord {
                deps: r.deps.clone(),
                done: r.done.clone(),
                files: Vec::new(),
                kept: false,
            };
            log.append(
                &record_name(u),
                &serde_json::to_vec(&record).expect("unit records serialise"),
            )?;
            done[i] = Some((d, false, record));
        }
    }
    let todo: Vec<usize> = picked
        .iter()
        .copied()
        .filter(|&i| done[i].is_none())
        .collect();
    let cx = Cx {
        store: &store,
        out: &out,
        plan: &plan,
        key: &key,
        progress,
    };
    let order = stage.order();
    let one = |i: usize, scratch: &mut S::Scratch| -> UnitResult<S::Done> {
        let unit = || stage.run_unit(&cx, &units[i], scratch);
        let (d, deps) = match order {
            Order::Parallel => store.deps().on_this_thread(unit),
            Order::Sequential => store.deps().tileset_wide(unit),
        };
        let d = d?;
        let record = UnitRecord {
            deps,
            done: serde_json::to_value(&d).expect("unit records serialise"),
            files: Vec::new(),
            kept: false,
        };
        let bytes = serde_json::to_vec(&record).expect("unit records serialise");
        log.append(&record_name(&units[i]), &bytes)?;
        progress.inc(1);
        Ok((d, record))
    };
    progress.start(spec.name, todo.len() as u64);
    let results: Vec<(usize, UnitResult<S::Done>)> = match order {
        Order::Parallel => todo
            .par_iter()
            .map_init(|| stage.scratch(&plan), |s, &i| (i, one(i, s)))
            .collect(),
        Order::Sequential => {
            let mut s = stage.scratch(&plan);
            let mut r = Vec::with_capacity(todo.len());
            for &i in &todo {
                let x = one(i, &mut s);
                let failed = x.is_err();
                r.push((i, x));
                if failed {
                    break;
                }
            }
            r
        }
    };
    progress.finish();
    let ran = results.len();
    for (i, r) in results {
        let (d, record) = r?;
        done[i] = Some((d, true, record));
    }
    let finished = done.iter().filter(|d| d.is_some()).count();
    if finished < units.len() {
        run.leave();
        return Ok(Outcome::Partial {
            ran,
            done: finished,
            total: units.len(),
        });
    }
    let done = done
        .into_iter()
        .map(|d| d.expect("every unit done"))
        .collect();
    finish_and_commit(stage, &cx, run, units, done, key.clone())
}

/// Every unit done (`done`, in the units' order: report, whether made here, record): the
/// stage's finish, the unit records staged beside the product's index (without the files a
/// shard listed), and the commit.
fn finish_and_commit<S: Stage>(
    stage: &S,
    cx: &Cx<S::Plan>,
    run: Run,
    units: Vec<Unit>,
    done: Vec<(S::Done, bool, UnitRecord)>,
    key: String,
) -> Result<Outcome<S::Report>> {
    let mut records = UnitRecords {
        key,
        units: Default::default(),
    };
    let done: Vec<Finished<S::Done>> = units
        .into_iter()
        .zip(done)
        .map(|(unit, (done, here, mut record))| {
            record.files.clear();
            record.kept = false;
            records.units.insert(record_name(&unit), record);
            Finished { unit, done, here }
        })
        .collect();
    let (manifest, report) = stage.finish(cx, done)?;
    // Beside the product's index in the staging folder; the commit moves it in with it.
    crate::tileset::writer::stage_unit_records(
        cx.out,
        run.spec.writes[0],
        &serde_json::to_vec(&records).expect("unit records serialise"),
    )?;
    run.commit(manifest)?;
    Ok(Outcome::Done(report))
}

/// Whether the stage's output for `key` is up to date: recorded with this key, its units the
/// ones recorded (`units_current`), every file of its products' indexes there with its size.
fn up_to_date(dir: &Path, spec: &StageSpec, key: &str, ts: &Tileset, units_current: bool) -> bool {
    let primary = spec.writes[0];
    units_current
        && primary.recorded_key(ts) == Some(key)
        && spec
            .writes
            .iter()
            .filter(|p| p.recorded_key(ts).is_some())
            .all(|&p| crate::tileset::writer::verify_product(dir, p))
}

/// What a stage's run knows before it runs a unit: its plan, key, units, and which units the
/// last committed run of the key made with dependencies that still hold.
struct Prepared<'s, S: Stage> {
    plan: S::Plan,
    key: String,
    units: Vec<Unit>,
    previous: Option<UnitRecords>,
    stage: &'s S,
}

impl<'s, S: Stage> Prepared<'s, S> {
    fn new(stage: &'s S, dir: &Path, store: &Store) -> Result<Self> {
        let ts = store.manifest();
        let plan = stage.plan(dir, ts)?;
        let key = stage.key(ts, &plan);
        let units = stage.units(ts, &plan)?;
        let previous = load_unit_records(dir, stage.spec().writes[0]).filter(|r| r.key == key);
        Ok(Prepared {
            plan,
            key,
            units,
            previous,
            stage,
        })
    }

    fn holds(&self, store: &Store, r: &UnitRecord) -> bool {
        deps_hold(self.stage, store, &self.plan, &r.deps)
    }

    /// Per unit, its record in the last committed run of this key when its dependencies hold.
    fn reusable(&self, store: &Store) -> Vec<Option<&UnitRecord>> {
        self.units
            .iter()
            .map(|u| {
                self.previous
                    .as_ref()
                    .and_then(|p| p.units.get(&record_name(u)))
                    .filter(|r| self.holds(store, r))
            })
            .collect()
    }

    /// Whether the units are those the last committed run recorded, all still holding.
    fn units_current(&self, reusable: &[Option<&UnitRecord>]) -> bool {
        match &self.previous {
            None => true,
            Some(p) => p.units.len() == self.units.len() && reusable.iter().all(Option::is_some),
        }
    }
}

/// The name of a shard's logs: `shard-<index>-of-<count>.<host>.<pid>`.
fn shard_log(index: usize, count: usize) -> String {
    format!(
        "shard-{index}-of-{count}.{}.{}",
        crate::fsio::host_name(),
        std::process::id()
    )
}

/// The shard (index, count) whose log is called `log`, if a shard's.
fn shard_of_log(log: &str) -> Option<(usize, usize)> {
    let rest = log.strip_prefix("shard-")?;
    let (i, rest) = rest.split_once("-of-")?;
    let n = rest.split('.').next()?;
    Some((i.parse().ok()?, n.parse().ok()?))
}

fn execute_shard<S: Stage>(
    stage: &S,
    dir: &Path,
    select: &Select,
    pricing: Option<Pricing>,
    progress: &dyn Progress,
) -> Result<Outcome<S::Report>> {
    let spec = stage.spec();
    let Select::Shard { index, count } = *select else {
        return Err(Error::usage(format!(
            "a shard of the {} stage runs one shard of its units: give its index and count",
            spec.name
        )));
    };
    stage.check()?;
    stage.plan(dir, &Tileset::load(dir)?)?;
    let shard = crate::tileset::writer::ShardWriter::begin(dir)?;
    let store = Store::open_unlocked(dir)?;
    let ts = store.manifest();
    let pre = Prepared::new(stage, dir, &store)?;
    let units = &pre.units;
    let costs = priced(units, pricing);
    let picked = select.pick_priced(units, &costs);
    if picked.is_empty() {
        return Err(Error::usage(format!(
            "the selection picks none of the {} units of the {} stage",
            units.len(),
            spec.name
        )));
    }
    let reusable = pre.reusable(&store);
    if up_to_date(dir, &spec, &pre.key, ts, pre.units_current(&reusable)) {
        return Ok(Outcome::Done(stage.up_to_date(&store, &pre.plan, units)));
    }
    let staging = shard.stage(spec.name, &pre.key, &shard_log(index, count))?;
    let staged = staging.read_records()?;
    let record_of = |i: usize| -> Option<UnitRecord> {
        let r: UnitRecord = serde_json::from_slice(&staged.get(&record_name(&units[i]))?.0).ok()?;
        (pre.holds(&store, &r) && serde_json::from_value::<S::Done>(r.done.clone()).is_ok())
            .then_some(r)
    };
    // Units already recorded (by any shard); those of this shard are checked file by file (a
    // crash of a host can leave a recorded file short), and redone when they do not hold.
    let recorded: Vec<bool> = (0..units.len())
        .into_par_iter()
        .map(|i| {
            let Some(r) = record_of(i) else {
                return false;
            };
            !picked.contains(&i) || r.files.iter().all(|f| f.problem(&staging.root).is_none())
        })
        .collect();
    let log = staging.record_log()?;
    let mut todo = Vec::new();
    if reusable.iter().any(Option::is_some) {
        let files = tile_files(&store, &spec.writes)?;
        for &i in &picked {
            if recorded[i] {
                continue;
            }
            let (Some(r), u) = (reusable[i], &units[i]) else {
                todo.push(i);
                continue;
            };
            // A unit of the committed run: its files linked in, listed in its record.
            let mut listed = Vec::new();
            let linked = u.writes.iter().all(|t| {
                files.get(t).into_iter().flatten().all(|(rel, len, h)| {
                    let from = dir.join(rel);
                    let ok = std::fs::metadata(&from).is_ok_and(|m| m.is_file() && m.len() == *len)
                        && staging.link(&from, rel, h).is_ok();
                    listed.push(FileRecord(rel.clone(), *len, h.to_hex().to_string()));
                    ok
                })
            });
            if !linked {
                todo.push(i);
                continue;
            }
            let record = UnitRecord {
                deps: r.deps.clone(),
                done: r.done.clone(),
                files: listed,
                kept: true,
            };
            log.append(
                &record_name(u),
                &serde_json::to_vec(&record).expect("unit records serialise"),
            )?;
        }
    } else {
        todo = picked.iter().copied().filter(|&i| !recorded[i]).collect();
    }
    let out = staging.root.clone();
    let cx = Cx {
        store: &store,
        out: &out,
        plan: &pre.plan,
        key: &pre.key,
        progress,
    };
    let order = stage.order();
    let one = |i: usize, scratch: &mut S::Scratch| -> Result<()> {
        let unit = || stage.run_unit(&cx, &units[i], scratch);
        let ((d, deps), written) = match order {
            Order::Parallel => {
                crate::fsio::capture_writes(false, || store.deps().on_this_thread(unit))
            }
            Order::Sequential => {
                crate::fsio::capture_writes(true, || store.deps().tileset_wide(unit))
            }
        };
        let record = UnitRecord {
            deps,
            done: serde_json::to_value(d?).expect("unit records serialise"),
            files: written.iter().map(FileRecord::of).collect(),
            kept: false,
        };
        let bytes = serde_json::to_vec(&record).expect("unit records serialise");
        log.append(&record_name(&units[i]), &bytes)?;
        progress.inc(1);
        Ok(())
    };
    progress.start(spec.name, todo.len() as u64);
    let results: Vec<Result<()>> = match order {
        Order::Parallel => todo
            .par_iter()
            .map_init(|| stage.scratch(&pre.plan), |s, &i| one(i, s))
            .collect(),
        Order::Sequential => {
            let mut s = stage.scratch(&pre.plan);
            let mut r = Vec::with_capacity(todo.len());
            for &i in &todo {
                let x = one(i, &mut s);
                let failed = x.is_err();
                r.push(x);
                if failed {
                    break;
                }
            }
            r
        }
    };
    progress.finish();
    let ran = results.len();
    results.into_iter().collect::<Result<Vec<()>>>()?;
    let done = staging.read_records()?.len().min(units.len());
    Ok(Outcome::Partial {
        ran,
        done,
        total: units.len(),
    })
}

/// Most examples a refused finish names per shard.
const EXAMPLES: usize = 4;

fn execute_finish<S: Stage>(
    stage: &S,
    dir: &Path,
    select: &Select,
    pricing: Option<Pricing>,
) -> Result<Outcome<S::Report>> {
    let spec = stage.spec();
    if *select != Select::All {
        return Err(Error::usage(format!(
            "the finish of the {} stage's shards takes every unit, not a selection",
            spec.name
        )));
    }
    stage.check()?;
    stage.plan(dir, &Tileset::load(dir)?)?;
    let mut writer = Writer::begin(dir)?;
    let store = Store::open_unlocked(dir)?;
    let ts = store.manifest();
    let mut pre = Prepared::new(stage, dir, &store)?;
    let reusable = pre.reusable(&store);
    if up_to_date(dir, &spec, &pre.key, ts, pre.units_current(&reusable)) {
        writer.discard_stage(spec.name, &pre.key)?;
        return Ok(Outcome::Done(
            stage.up_to_date(&store, &pre.plan, &pre.units),
        ));
    }
    let changed = spec.writes[0].recorded_key(ts) != Some(pre.key.as_str());
    let Some(staging) = writer.open_staged(spec.name, &pre.key)? else {
        return Err(Error::usage(format!(
            "no shard of the {} stage has run for this run key (the tileset as it is, these \
             options): run its shards, then finish",
            spec.name
        )));
    };
    let units = std::mem::take(&mut pre.units);
    let staged = staging.read_records()?;
    // Every count of shards that ran, to name the shard a missing unit belongs to.
    let counts: std::collections::BTreeSet<usize> = staged
        .values()
        .filter_map(|(_, log)| shard_of_log(log).map(|(_, n)| n))
        .collect();
    let shard_label = |log: &str| match shard_of_log(log) {
        Some((i, n)) => format!("shard {i}/{n}"),
        None => format!("the run that logged as {log}"),
    };
    // Per shard, what is wrong: (units not recorded, problems of recorded units).
    let mut wrong: std::collections::BTreeMap<String, (Vec<String>, Vec<String>)> =
        Default::default();
    let mut done = Vec::with_capacity(units.len());
    let mut missing = Vec::new();
    for (i, u) in units.iter().enumerate() {
        let found = staged.get(&record_name(u)).and_then(|(bytes, log)| {
            let r: UnitRecord = serde_json::from_slice(bytes).ok()?;
            let d: S::Done = serde_json::from_value(r.done.clone()).ok()?;
            Some((d, r, log.clone()))
        });
        match found {
            Some((d, r, log)) => {
                if !pre.holds(&store, &r) {
                    wrong
                        .entry(shard_label(&log))
                        .or_default()
                        .1
                        .push(format!("unit {} read what has changed since", u.key()));
                }
                done.push(Some((d, r, log)));
            }
            None => {
                missing.push(i);
                done.push(None);
            }
        }
    }
    if !missing.is_empty() {
        let costs = priced(&units, pricing);
        if counts.is_empty() {
            wrong.entry("no shard".into()).or_default().0 =
                missing.iter().map(|&i| units[i].key()).collect();
        }
        for &n in &counts {
            let shard = Select::assign(&units, &costs, n);
            for &i in &missing {
                wrong
                    .entry(format!("shard {}/{n}", shard[i]))
                    .or_default()
                    .0
                    .push(units[i].key());
            }
        }
    }
    // Every file of every recorded unit, read back against its record.
    let files: Vec<(&FileRecord, &str)> = done
        .iter()
        .flatten()
        .flat_map(|(_, r, log)| r.files.iter().map(move |f| (f, log.as_str())))
        .collect();
    let damaged: Vec<(String, String)> = files
        .par_iter()
        .filter_map(|(f, log)| f.problem(&staging.root).map(|p| (shard_label(log), p)))
        .collect();
    for (shard, p) in damaged {
        wrong.entry(shard).or_default().1.push(p);
    }
    if !wrong.is_empty() {
        let mut parts = Vec::new();
        for (shard, (miss, bad)) in &wrong {
            let mut say = Vec::new();
            if !miss.is_empty() {
                say.push(format!(
                    "{} of its units not recorded ({}{})",
                    miss.len(),
                    miss[..miss.len().min(EXAMPLES)].join(", "),
                    if miss.len() > EXAMPLES { ", …" } else { "" }
                ));
            }
            if !bad.is_empty() {
                say.push(format!(
                    "{}{}",
                    bad[..bad.len().min(EXAMPLES)].join("; "),
                    if bad.len() > EXAMPLES {
                        format!("; and {} more", bad.len() - EXAMPLES)
                    } else {
                        String::new()
                    }
                ));
            }
            parts.push(format!("{shard}: {}", say.join("; ")));
        }
        return Err(Error::invalid(
            &staging.root,
            format!(
                "the {} stage's shards are not complete, so nothing was committed: {}. Run \
                 each shard named again (it redoes what is missing or damaged), then finish",
                spec.name,
                parts.join(". ")
            ),
        ));
    }
    // What the units listed is what commits: anything else in the product folders (a
    // finish's leftovers, a stray file) goes.
    let listed: std::collections::HashSet<&str> = files.iter().map(|(f, _)| f.0.as_str()).collect();
    for p in spec.writes.iter() {
        for d in p.dirs() {
            for (rel, _) in crate::fsio::list_files(&staging.root.join(d))? {
                let rel = format!("{d}/{rel}");
                if !listed.contains(rel.as_str()) {
                    let f = staging.root.join(&rel);
                    std::fs::remove_file(&f).map_err(|e| Error::io(&f, e))?;
                }
            }
        }
    }
    let out = staging.root.clone();
    let cx = Cx {
        store: &store,
        out: &out,
        plan: &pre.plan,
        key: &pre.key,
        progress: &crate::progress::NoProgress,
    };
    let done: Vec<(S::Done, bool, UnitRecord)> = done
        .into_iter()
        .map(|d| {
            let (d, r, _) = d.expect("every unit recorded");
            let here = !r.kept;
            (d, here, r)
        })
        .collect();
    let run = Run {
        spec,
        writer,
        staging,
        changed,
    };
    finish_and_commit(stage, &cx, run, units, done, pre.key.clone())
}

impl<R> Outcome<R> {
    /// The report of a run that had to commit (a whole run); an error for a partial one.
    pub fn into_report(self, stage: &str) -> Result<R> {
        match self {
            Outcome::Done(r) => Ok(r),
            Outcome::Partial { done, total, .. } => Err(Error::usage(format!(
                "the {stage} stage ran {done} of its {total} units and did not commit"
            ))),
        }
    }
}
