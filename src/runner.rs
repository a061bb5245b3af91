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

    /// The indices (into `units`) this selection takes.
    pub fn pick(&self, units: &[Unit]) -> Vec<usize> {
        match self {
            Select::All => (0..units.len()).collect(),
            Select::Shard { index, count } => {
                // Cut the cumulative cost into `count` equal spans; unit i belongs to the span
                // its cost midpoint falls in (the same cut whatever process computes it).
                let total: f64 = units.iter().map(|u| u.cost.max(0.0)).sum();
                let mut acc = 0.0;
                let mut out = Vec::new();
                for (i, u) in units.iter().enumerate() {
                    let c = u.cost.max(0.0);
                    let mid = acc + c / 2.0;
                    acc += c;
                    let span = if total > 0.0 {
                        ((mid / total * *count as f64) as usize).min(count - 1)
                    } else {
                        i * count / units.len().max(1)
                    };
                    if span == *index {
                        out.push(i);
                    }
                }
                out
            }
            Select::Keys(keys) => units
                .iter()
                .enumerate()
                .filter(|(_, u)| keys.contains(&u.key()))
                .map(|(i, _)| i)
                .collect(),
        }
    }
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
    let picked = select.pick(&units);
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
            let r: UnitRecord = serde_json::from_slice(staged.get(&record_name(u))?).ok()?;
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
    let mut records = UnitRecords {
        key: key.clone(),
        units: Default::default(),
    };
    let done: Vec<Finished<S::Done>> = units
        .into_iter()
        .zip(done)
        .map(|(unit, d)| {
            let (done, here, record) = d.expect("every unit done");
            records.units.insert(record_name(&unit), record);
            Finished { unit, done, here }
        })
        .collect();
    let (manifest, report) = stage.finish(&cx, done)?;
    // Beside the product's index in the staging folder; the commit moves it in with it.
    crate::tileset::writer::stage_unit_records(
        &out,
        primary,
        &serde_json::to_vec(&records).expect("unit records serialise"),
    )?;
    run.commit(manifest)?;
    Ok(Outcome::Done(report))
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
