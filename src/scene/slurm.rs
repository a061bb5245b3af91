//! `penumbra plan SCENE --slurm DIR --shards N`: a scene's bake as a chain of Slurm jobs
//! (docs/cluster.md, "Slurm"). Tiling runs whole as one job; each sharded stage is a job array
//! of N tasks (`bake SCENE --stage S --shard $SLURM_ARRAY_TASK_ID/N`) and its `--finish` job;
//! each job waits for the one before it (`--dependency=afterok`), in the stage graph's order.
//! `submit.sh` submits the chain. Every figure a script asks Slurm for comes from the plan's
//! estimates (named in a comment beside it) unless a flag overrides it.
//!
//! The files are a function of the plan and the options alone (the same scene and flags give
//! the same bytes), and the folder is written whole or not at all: a temp folder beside it,
//! renamed into place (exchanged with the previous plan penumbra wrote there; any other
//! existing folder is refused).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::plan::Plan;
use super::shards::ShardTable;
use crate::bake::Stage;
use crate::error::{Error, IoContext, Result};

/// The file in a plan's folder that marks it as penumbra's (its whole contents).
pub const MARKER: &str = ".penumbra-slurm";
const MARKER_TEXT: &str = "penumbra slurm plan, format 1: this folder is rewritten whole by \
                           `penumbra plan --slurm`; its logs/ are kept\n";

/// Most tasks of one array: Slurm's default `MaxArraySize` is 1001 (indexes 0..=1000).
pub const MAX_ARRAY: usize = 1000;

/// The core-seconds a task may take over the plan's estimate before Slurm stops it: the
/// model was within 1.25× of measured bakes on five scenes (docs/scenes.md, "Plan against
/// bake: CPU time"); 3× leaves room for slower cores, a shared node and threads that scale
/// below linear.
pub const TIME_SAFETY: f64 = 3.0;
/// Added to every time limit: starting, planning the scene (every task plans it as the
/// whole bake does) and pricing the units, reading the manifest.
pub const TIME_FLOOR_S: f64 = 600.0;
/// What a finish reads back per second (every staged file, hashed): a cautious rate for a
/// shared filesystem (blake3 hashes several GB/s per core).
pub const FINISH_READ_BYTES_PER_S: f64 = 100e6;
/// The slowest shard's estimate (core-seconds) one CPU should carry when no `--cpus-per-task`
/// is given: CPUs are added until it fits an hour, up to [`MAX_DEFAULT_CPUS`].
pub const CPU_TARGET_S: f64 = 3600.0;
/// The most CPUs per task chosen without `--cpus-per-task` (one node of a typical cluster).
pub const MAX_DEFAULT_CPUS: u32 = 32;
/// Memory: what every task holds whatever its work (the binary, the plan, the manifest).
const MEM_BASE: u64 = 64 << 20;
/// The most the sun rule's bound cache holds (`horizon/bound.rs`).
const BOUND_CACHE: u64 = 256 << 20;
/// Memory is asked for with this margin over the model, in steps of [`MEM_STEP`].
const MEM_SAFETY: f64 = 1.5;
const MEM_STEP: u64 = 64 << 20;

/// What `plan --slurm` writes and how the jobs run (the flags).
#[derive(Clone, Debug, Default)]
pub struct SlurmOptions {
    /// The plan's folder.
    pub dir: PathBuf,
    /// Tasks per sharded stage.
    pub shards: usize,
    /// The tileset the jobs bake into.
    pub out: PathBuf,
    /// The scene file (None: the embedded scene).
    pub scene_file: Option<PathBuf>,
    /// The `penumbra` the jobs run.
    pub penumbra: PathBuf,
    pub cpus_per_task: Option<u32>,
    /// Slurm's `--mem` syntax: a size in MiB or with a K, M, G or T suffix.
    pub mem: Option<String>,
    /// Slurm's `--time` syntax: M, M:S, H:M:S, D-H, D-H:M, D-H:M:S.
    pub time: Option<String>,
    pub partition: Option<String>,
    pub account: Option<String>,
}

/// One job of the chain.
#[derive(Clone, Debug)]
pub struct Job {
    /// Its name in submit.sh's output: `tile`, `mip`, `mip-finish`, …
    pub name: String,
    /// Its script's file name in the plan's folder.
    pub file: String,
    pub script: String,
}

/// The files of a plan's folder (name, bytes, executable), in order; nothing written.
pub fn files(plan: &Plan, table: &ShardTable, o: &SlurmOptions) -> Result<Vec<(String, String)>> {
    let jobs = jobs(plan, table, o)?;
    let mut out: Vec<(String, String)> = jobs
        .iter()
        .map(|j| (j.file.clone(), j.script.clone()))
        .collect();
    out.push(("submit.sh".into(), submit_script(&jobs, o)?));
    out.push((MARKER.into(), MARKER_TEXT.into()));
    Ok(out)
}

/// Resources of one job and where each figure came from.
struct Resources {
    cpus: u32,
    cpus_why: String,
    mem_mib: u64,
    mem_why: String,
    time: String,
    time_why: String,
}

/// The chain's jobs in the order they run, after checking every option.
pub fn jobs(plan: &Plan, table: &ShardTable, o: &SlurmOptions) -> Result<Vec<Job>> {
    let n = o.shards;
    if n == 0 || n > MAX_ARRAY {
        return Err(Error::usage(format!(
            "--shards {n}: a Slurm plan needs 1..={MAX_ARRAY} tasks per stage (Slurm's default \
             MaxArraySize is 1001, indexes 0..=1000); give a count in that range"
        )));
    }
    for st in &table.stages {
        if n as u64 > st.units {
            return Err(Error::usage(format!(
                "--shards {n}: the {} stage has {} units, and every task must have one; give \
                 --shards {} or fewer",
                st.stage, st.units, st.units
            )));
        }
    }
    let mem_override = o.mem.as_deref().map(parse_mem).transpose()?;
    let time_override = o.time.as_deref().map(parse_time).transpose()?;
    for (flag, v) in [("--partition", &o.partition), ("--account", &o.account)] {
        if let Some(v) = v {
            if v.is_empty()
                || !v
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "_-.,".contains(c))
            {
                return Err(Error::usage(format!(
                    "{flag} '{v}': Slurm names are letters, digits and _ - . , only; give the \
                     name `sinfo` (partitions) or `sacctmgr show assoc` (accounts) lists"
                )));
            }
        }
    }
    if o.cpus_per_task == Some(0) {
        return Err(Error::usage(
            "--cpus-per-task 0: a task needs at least one CPU; give 1 or more",
        ));
    }
    let dir = absolute(&o.dir)?;
    let out = absolute(&o.out)?;
    // The tileset's folder is made by the first job, on the file system the nodes share: its
    // parent must be there already (a typo here would only show as the chain's first failure).
    if let Some(parent) = out.parent().filter(|p| !p.is_dir()) {
        return Err(Error::invalid(
            parent,
            format!(
                "--out {}: its parent folder does not exist; mkdir it on the file system the \
                 cluster's nodes share, or give another --out",
                out.display()
            ),
        ));
    }
    let logs = dir.join("logs");
    // The logs' path goes on `#SBATCH --output=` lines, which sbatch reads itself: no shell
    // quoting there, and % starts its file name patterns. The other paths are only in the
    // scripts' shell lines, quoted.
    let plain = dir.to_str().is_some_and(|s| {
        !s.chars()
            .any(|c| c.is_control() || c.is_whitespace() || "%\"'\\".contains(c))
    });
    if !plain {
        return Err(Error::invalid(
            &dir,
            "--slurm: Slurm's #SBATCH lines cannot carry this path (not UTF-8, or it holds a \
             space, % \" ' \\ or a control character); choose a plain one",
        ));
    }
    let penumbra = &o.penumbra;
    if !penumbra.is_absolute() || !penumbra.is_file() {
        return Err(Error::invalid(
            penumbra,
            "--penumbra: not an existing file given by an absolute path; give the absolute path \
             of the penumbra binary the cluster's nodes run",
        ));
    }
    let scene = match &o.scene_file {
        Some(f) => Some(std::fs::canonicalize(f).at(f)?),
        None => None,
    };
    let stages = super::bake::stage_plan(plan, &super::bake::BakeOptions::default()).stages;
    let header = |what: &str| {
        let mut s = String::new();
        let _ = writeln!(s, "#!/bin/bash");
        let _ = writeln!(s, "# {what}.");
        let _ = writeln!(
            s,
            "# Written by `penumbra plan --slurm` (penumbra {}; docs/cluster.md).",
            env!("CARGO_PKG_VERSION")
        );
        let _ = writeln!(
            s,
            "# Scene: {}",
            scene
                .as_ref()
                .map_or("the embedded scene".to_string(), |p| p
                    .display()
                    .to_string()),
        );
        let _ = writeln!(s, "# Tileset: {}", out.display());
        s
    };
    let command = |stage: &str, role: &str, cpus: u32| {
        let mut c = format!("{} --quiet --threads {cpus} bake", shell_quote(penumbra));
        if let Some(f) = &scene {
            let _ = write!(c, " {}", shell_quote(f));
        }
        let _ = write!(c, " --out {} --stage {stage}", shell_quote(&out));
        if !role.is_empty() {
            let _ = write!(c, " {role}");
        }
        c.push_str(" --json");
        c
    };
    let mut jobs = Vec::new();
    for st in &stages {
        let name = st.name();
        let sharded = table.stages.iter().find(|s| s.stage == name);
        let est = match sharded {
            Some(s) => s.shards.iter().map(|s| s.cpu_s_est).fold(0.0, f64::max),
            None => table.tile_cpu_s_est,
        };
        let est_why = match sharded {
            Some(s) => format!(
                "the slowest of the {n} shards in the plan's model: {est:.1} core-s \
                 (`penumbra plan SCENE --shards {n}`: {:.1} core-s for the stage, slowest/mean \
                 {:.3})",
                s.cpu_s_est, s.slowest_over_mean
            ),
            None => format!("the plan's estimate of tiling: {est:.1} core-s"),
        };
        let res = resources(plan, *st, est, &est_why, o, mem_override, &time_override);
        let index = jobs.len() + 1;
        match sharded {
            None => {
                let mut s = header(&format!("The {name} stage, whole, in one job"));
                sbatch_lines(
                    &mut s,
                    &format!("penumbra-{name}"),
                    &res,
                    o,
                    &logs,
                    name,
                    false,
                );
                body(&mut s, &command(name, "", res.cpus), false);
                jobs.push(Job {
                    name: name.into(),
                    file: format!("{index}-{name}.sbatch"),
                    script: s,
                });
            }
            Some(_) => {
                let mut s = header(&format!(
                    "The {name} stage as {n} shards, one array task each (task I runs \
                     `--shard I/{n}`)"
                ));
                let _ = writeln!(s, "#SBATCH --array=0-{}", n - 1);
                sbatch_lines(
                    &mut s,
                    &format!("penumbra-{name}"),
                    &res,
                    o,
                    &logs,
                    name,
                    true,
                );
                body(
                    &mut s,
                    &command(
                        name,
                        &format!("--shard \"${{SLURM_ARRAY_TASK_ID}}/{n}\""),
                        res.cpus,
                    ),
                    true,
                );
                jobs.push(Job {
                    name: name.into(),
                    file: format!("{index}-{name}.sbatch"),
                    script: s,
                });
                // The finish: reads back every file the shards staged, then the stage's own
                // finish (face pyramids, manifest) as a whole run does.
                let bytes: f64 = plan
                    .products
                    .iter()
                    .filter(|p| p.made && stage_of(p.product) == Some(*st))
                    .map(|p| p.disk_bytes_est as f64)
                    .sum();
                let est_s = bytes / FINISH_READ_BYTES_PER_S;
                let fin_why = format!(
                    "reading back the stage's files, {:.1} MB by the plan, at {:.0} MB/s: \
                     {est_s:.1} s",
                    bytes / 1e6,
                    FINISH_READ_BYTES_PER_S / 1e6
                );
                let fres = resources(plan, *st, est_s, &fin_why, o, mem_override, &time_override);
                let fname = format!("{name}-finish");
                let mut s = header(&format!(
                    "The {name} stage's finish: checks every shard's work and commits the stage \
                     once"
                ));
                sbatch_lines(
                    &mut s,
                    &format!("penumbra-{fname}"),
                    &fres,
                    o,
                    &logs,
                    &fname,
                    false,
                );
                body(&mut s, &command(name, "--finish", fres.cpus), false);
                jobs.push(Job {
                    name: fname.clone(),
                    file: format!("{}-{fname}.sbatch", index + 1),
                    script: s,
                });
            }
        }
    }
    // Last, a whole bake of the scene: it finds every stage up to date (each committed by its
    // job or its finish) and stamps the folder, so that a later `bake SCENE` answers
    // "unchanged" at once and `package SCENE` takes the folder as the scene's bake (sharded
    // runs leave the stamp to a whole bake).
    let res = resources(
        plan,
        Stage::Tile,
        0.0,
        "none beyond the start: every stage is up to date, so the bake plans the scene, checks \
         each stage's records and writes the stamp",
        o,
        mem_override,
        &time_override,
    );
    let mut s = header(
        "The bake's last job: a whole bake of the scene, which finds every stage up to date and \
         stamps the folder",
    );
    sbatch_lines(&mut s, "penumbra-stamp", &res, o, &logs, "stamp", false);
    let mut c = format!(
        "{} --quiet --threads {} bake",
        shell_quote(penumbra),
        res.cpus
    );
    if let Some(f) = &scene {
        let _ = write!(c, " {}", shell_quote(f));
    }
    let _ = write!(c, " --out {} --json", shell_quote(&out));
    body(&mut s, &c, false);
    jobs.push(Job {
        name: "stamp".into(),
        file: format!("{}-stamp.sbatch", jobs.len() + 1),
        script: s,
    });
    Ok(jobs)
}

fn stage_of(product: &str) -> Option<Stage> {
    match product {
        "height" | "albedo" => Some(Stage::Tile),
        "mip" => Some(Stage::Mip),
        "horizon" | "fourier" => Some(Stage::Horizon),
        _ => None,
    }
}

#[allow(clippy::too_many_arguments)]
fn resources(
    plan: &Plan,
    stage: Stage,
    est_core_s: f64,
    est_why: &str,
    o: &SlurmOptions,
    mem_override: Option<u64>,
    time_override: &Option<u64>,
) -> Resources {
    let (cpus, cpus_why) = match o.cpus_per_task {
        Some(c) => (c, "--cpus-per-task".to_string()),
        None => {
            let c = ((est_core_s / CPU_TARGET_S).ceil() as u32).clamp(1, MAX_DEFAULT_CPUS);
            (
                c,
                format!(
                    "enough that the estimate below fits {CPU_TARGET_S:.0} s per CPU, at most \
                     {MAX_DEFAULT_CPUS}"
                ),
            )
        }
    };
    let (mem_bytes, mem_model) = memory(plan, stage, cpus);
    let (mem_mib, mem_why) = match mem_override {
        Some(m) => (m, "--mem".to_string()),
        None => {
            let asked =
                ((mem_bytes as f64 * MEM_SAFETY / MEM_STEP as f64).ceil() as u64 * MEM_STEP) >> 20;
            (
                asked,
                format!("{MEM_SAFETY}× the plan's model, {mem_model}; in steps of 64 MiB"),
            )
        }
    };
    let (time_s, time_why) = match time_override {
        Some(t) => (*t, "--time".to_string()),
        None => {
            let s = TIME_FLOOR_S + TIME_SAFETY * est_core_s / f64::from(cpus);
            let s = ((s / 60.0).ceil() * 60.0) as u64;
            (
                s,
                format!(
                    "{TIME_FLOOR_S:.0} s (start, planning) + {TIME_SAFETY}× the estimate on \
                     {cpus} CPU(s), in whole minutes; the estimate: {est_why}"
                ),
            )
        }
    };
    Resources {
        cpus,
        cpus_why,
        mem_mib,
        mem_why,
        time: format_time(time_s),
        time_why,
    }
}

/// The plan's model of a task's memory (bytes) and how it was reckoned.
fn memory(plan: &Plan, stage: Stage, threads: u32) -> (u64, String) {
    let stored = plan.layout.stored_size() as u64;
    let tile_bytes = stored * stored * 5; // heights f32 + mip bytes, as the tile cache counts
    let tiles = plan.tiles.len() as u64;
    let cache = (tiles * tile_bytes).min(crate::tileset::DEFAULT_CACHE_BYTES);
    let t = u64::from(threads);
    match stage {
        Stage::Horizon => {
            let side = plan.layout.tile_size as u64;
            let margin = crate::horizon::default_fine_margin_px(plan.layout.tile_size);
            let ctx = side + 2 * margin;
            let az = plan.scene.horizon.azimuths as u64;
            // Per thread: the context raster (heights and a working copy, f32) and the tile's
            // maps in f32 with their pyramid buffers.
            let per = 2 * ctx * ctx * 4 + 2 * side * side * az * 4;
            // The sun rule's bounds: at most one per tile, smaller than the tile.
            let bound = cache.min(BOUND_CACHE);
            (
                MEM_BASE + cache + bound + t * per,
                format!(
                    "{} MiB base + {} MiB tile cache (the smaller of the scene's {tiles} tiles \
                     and 1 GiB) + {} MiB bound cache (at most the tile cache, at most 256 MiB) + \
                     {t} thread(s) × {} MiB (a {ctx}² px context twice, the {side}² px × {az} \
                     az maps twice, f32)",
                    MEM_BASE >> 20,
                    cache.div_ceil(1 << 20),
                    bound.div_ceil(1 << 20),
                    per.div_ceil(1 << 20)
                ),
            )
        }
        Stage::Mip => {
            let per = 4 * stored * stored * 4;
            (
                MEM_BASE + cache + t * per,
                format!(
                    "{} MiB base + {} MiB tile cache + {t} thread(s) × {} MiB (four {stored}² px \
                     f32 rasters)",
                    MEM_BASE >> 20,
                    cache.div_ceil(1 << 20),
                    per.div_ceil(1 << 20)
                ),
            )
        }
        _ => {
            let per = 4 * stored * stored * 4;
            (
                MEM_BASE + t * per,
                format!(
                    "{} MiB base + {t} thread(s) × {} MiB (four {stored}² px f32 rasters; the \
                     sources are memory-mapped)",
                    MEM_BASE >> 20,
                    per.div_ceil(1 << 20)
                ),
            )
        }
    }
}

fn sbatch_lines(
    s: &mut String,
    job: &str,
    r: &Resources,
    o: &SlurmOptions,
    logs: &Path,
    log: &str,
    array: bool,
) {
    let _ = writeln!(s, "#SBATCH --job-name={job}");
    let _ = writeln!(s, "#SBATCH --ntasks=1");
    let _ = writeln!(s, "#SBATCH --cpus-per-task={}", r.cpus);
    let _ = writeln!(s, "#SBATCH --mem={}M", r.mem_mib);
    let _ = writeln!(s, "#SBATCH --time={}", r.time);
    // Preempted or its node lost, the task is queued again and finishes its shard: a shard
    // rerun keeps what any run recorded and redoes the rest (docs/cluster.md).
    let _ = writeln!(s, "#SBATCH --requeue");
    let _ = writeln!(s, "#SBATCH --open-mode=append");
    // A job whose dependency failed is cancelled rather than left pending for ever.
    let _ = writeln!(s, "#SBATCH --kill-on-invalid-dep=yes");
    let pattern = if array { "%A_%a" } else { "%j" };
    let _ = writeln!(
        s,
        "#SBATCH --output={}",
        logs.join(format!("{log}-{pattern}.out")).display()
    );
    if let Some(p) = &o.partition {
        let _ = writeln!(s, "#SBATCH --partition={p}");
    }
    if let Some(a) = &o.account {
        let _ = writeln!(s, "#SBATCH --account={a}");
    }
    let _ = writeln!(s, "# --cpus-per-task: {}", r.cpus_why);
    let _ = writeln!(s, "# --mem: {}", r.mem_why);
    let _ = writeln!(s, "# --time: {}", r.time_why);
}

fn body(s: &mut String, command: &str, array: bool) {
    let _ = writeln!(s, "set -euo pipefail");
    let task = if array {
        " task ${SLURM_ARRAY_TASK_ID}"
    } else {
        ""
    };
    let _ = writeln!(
        s,
        "echo \"== start job ${{SLURM_JOB_ID}}{task} on $(hostname) at $(date +%s.%N), restart \
         ${{SLURM_RESTART_COUNT:-0}}\""
    );
    let _ = writeln!(s, "{command}");
    let _ = writeln!(s, "echo \"== end at $(date +%s.%N)\"");
}

fn submit_script(jobs: &[Job], o: &SlurmOptions) -> Result<String> {
    let dir = absolute(&o.dir)?;
    let mut s = String::new();
    let _ = writeln!(s, "#!/bin/bash");
    let _ = writeln!(
        s,
        "# Submits the bake as a chain of Slurm jobs, each starting once the one before it has \
         succeeded (afterok), and prints each job's name and id (written by `penumbra plan \
         --slurm`; docs/cluster.md)."
    );
    let _ = writeln!(s, "set -euo pipefail");
    let _ = writeln!(s, "dir={}", shell_quote(&dir));
    let _ = writeln!(s, "mkdir -p \"$dir/logs\"");
    let _ = writeln!(s, "prev=");
    for j in jobs {
        let _ = writeln!(
            s,
            "id=$(sbatch --parsable ${{prev:+--dependency=afterok:$prev}} \"$dir\"/{})",
            shell_quote(Path::new(&j.file))
        );
        let _ = writeln!(s, "prev=${{id%%;*}}");
        let _ = writeln!(s, "echo \"{} $prev\"", j.name);
    }
    Ok(s)
}

/// `--mem`: MiB from Slurm's syntax (a count of MiB, or K, M, G, T units of 1024).
pub fn parse_mem(s: &str) -> Result<u64> {
    let bad = || {
        Error::usage(format!(
            "--mem '{s}': not a size in Slurm's syntax; give a whole number with an optional \
             unit K, M (the default), G or T, e.g. 4G or 1500M"
        ))
    };
    let t = s.trim();
    let (num, unit) = match t.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() => (&t[..i], c.to_ascii_uppercase()),
        _ => (t, 'M'),
    };
    if num.is_empty() || !num.bytes().all(|b| b.is_ascii_digit()) || num.len() > 12 {
        return Err(bad());
    }
    let v: u64 = num.parse().map_err(|_| bad())?;
    let mib = match unit {
        'K' => v.div_ceil(1024),
        'M' => v,
        'G' => v * 1024,
        'T' => v * 1024 * 1024,
        _ => return Err(bad()),
    };
    if mib == 0 {
        return Err(Error::usage(format!(
            "--mem '{s}': zero memory (Slurm reads --mem=0 as a whole node's); give a size, \
             e.g. 4G"
        )));
    }
    Ok(mib)
}

/// `--time`: seconds from Slurm's syntax: M, M:S, H:M:S, D-H, D-H:M, D-H:M:S.
pub fn parse_time(s: &str) -> Result<u64> {
    let bad = || {
        Error::usage(format!(
            "--time '{s}': not a time limit in Slurm's syntax; give minutes, M:S, H:M:S, D-H, \
             D-H:M or D-H:M:S, e.g. 90 or 1:30:00 or 2-00:00:00"
        ))
    };
    let num = |p: &str| -> Result<u64> {
        if p.is_empty() || p.len() > 9 || !p.bytes().all(|b| b.is_ascii_digit()) {
            return Err(bad());
        }
        p.parse().map_err(|_| bad())
    };
    let t = s.trim();
    let secs = match t.split_once('-') {
        Some((d, rest)) => {
            let d = num(d)?;
            let parts: Vec<&str> = rest.split(':').collect();
            let hms = match parts.as_slice() {
                [h] => num(h)? * 3600,
                [h, m] => num(h)? * 3600 + num(m)? * 60,
                [h, m, sec] => num(h)? * 3600 + num(m)? * 60 + num(sec)?,
                _ => return Err(bad()),
            };
            d * 86400 + hms
        }
        None => {
            let parts: Vec<&str> = t.split(':').collect();
            match parts.as_slice() {
                [m] => num(m)? * 60,
                [m, sec] => num(m)? * 60 + num(sec)?,
                [h, m, sec] => num(h)? * 3600 + num(m)? * 60 + num(sec)?,
                _ => return Err(bad()),
            }
        }
    };
    if secs == 0 {
        return Err(Error::usage(format!(
            "--time '{s}': a zero time limit (Slurm reads 0 as no limit, which clusters often \
             refuse); give a limit, e.g. 1:00:00"
        )));
    }
    Ok(secs)
}

/// Seconds as Slurm's D-HH:MM:SS (HH:MM:SS under a day).
pub fn format_time(s: u64) -> String {
    let (d, h, m, sec) = (s / 86400, s / 3600 % 24, s / 60 % 60, s % 60);
    if d > 0 {
        format!("{d}-{h:02}:{m:02}:{sec:02}")
    } else {
        format!("{h:02}:{m:02}:{sec:02}")
    }
}

/// A path as one word of a POSIX shell: in single quotes, a quote inside written `'\''`.
pub fn shell_quote(p: &Path) -> String {
    let s = p.to_string_lossy();
    format!("'{}'", s.replace('\'', "'\\''"))
}

fn absolute(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).at(p)
}

/// Check, before anything is planned, that `dir` can take a plan: its parent exists, and it is
/// absent or a plan penumbra wrote.
pub fn check_dir(dir: &Path) -> Result<()> {
    let abs = absolute(dir)?;
    let parent = abs.parent().unwrap_or(Path::new("/"));
    if !parent.is_dir() {
        return Err(Error::invalid(
            &abs,
            format!(
                "--slurm: its parent folder {} does not exist; create it (mkdir -p) or give \
                 another folder",
                parent.display()
            ),
        ));
    }
    match std::fs::symlink_metadata(&abs) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(&abs, e)),
        Ok(m) if !m.is_dir() => Err(Error::invalid(
            &abs,
            "--slurm: exists and is not a folder; give a new folder (it is created) or one a \
             previous `plan --slurm` wrote",
        )),
        Ok(_) => {
            // A small regular file holding exactly the mark (not a product file: read here).
            let marker = abs.join(MARKER);
            let ours = std::fs::symlink_metadata(&marker)
                .is_ok_and(|m| m.is_file() && m.len() == MARKER_TEXT.len() as u64)
                && std::fs::read(&marker).is_ok_and(|b| b == MARKER_TEXT.as_bytes());
            if ours {
                Ok(())
            } else {
                Err(Error::invalid(
                    &abs,
                    format!(
                        "--slurm: the folder exists and is not a Slurm plan penumbra wrote (no \
                         {MARKER} of its own); give a new folder, or remove this one if it is \
                         yours to remove"
                    ),
                ))
            }
        }
    }
}

/// Write the plan's folder whole: a temp folder beside it, renamed into place (exchanged
/// with the previous plan, whose logs/ move into the new one).
pub fn write(dir: &Path, files: &[(String, String)]) -> Result<()> {
    check_dir(dir)?;
    let abs = absolute(dir)?;
    let parent = abs.parent().unwrap_or(Path::new("/")).to_path_buf();
    let name = abs
        .file_name()
        .ok_or_else(|| Error::invalid(&abs, "--slurm: names no folder; give a folder's path"))?
        .to_string_lossy()
        .into_owned();
    let tmp = parent.join(format!(
        ".{name}{}{}",
        crate::fsio::TEMP_MARK,
        std::process::id()
    ));
    crate::fsio::remove_tree(&tmp)?;
    let result = (|| -> Result<()> {
        std::fs::create_dir(&tmp).at(&tmp)?;
        // The scripts are not product files: written here, synced, and made visible all at
        // once by the folder's rename.
        for (f, text) in files {
            let p = tmp.join(f);
            std::fs::File::create(&p)
                .and_then(|mut w| {
                    std::io::Write::write_all(&mut w, text.as_bytes())?;
                    w.sync_all()
                })
                .at(&p)?;
            #[cfg(unix)]
            if f.ends_with(".sh") || f.ends_with(".sbatch") {
                use std::os::unix::fs::PermissionsExt;
                std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).at(&p)?;
            }
        }
        let old_logs = abs.join("logs");
        if old_logs.is_dir() {
            std::fs::rename(&old_logs, tmp.join("logs")).at(&old_logs)?;
        } else {
            std::fs::create_dir(tmp.join("logs")).at(&tmp)?;
        }
        if abs.exists() {
            exchange(&tmp, &abs)?;
        } else {
            std::fs::rename(&tmp, &abs).at(&abs)?;
        }
        crate::fsio::sync_dir(&parent)
    })();
    // After an exchange the temp name holds the previous plan; after a failure, the new one,
    // which may hold the previous plan's logs: they go back first.
    if result.is_err() && !abs.join("logs").exists() && abs.is_dir() {
        let _ = std::fs::rename(tmp.join("logs"), abs.join("logs"));
    }
    let _ = crate::fsio::remove_tree(&tmp);
    result
}

/// Swap two paths at once ([`crate::fsio::exchange_paths`]); elsewhere two renames.
fn exchange(a: &Path, b: &Path) -> Result<()> {
    if crate::fsio::exchange_paths(a, b).map_err(|e| Error::io(b, e))? {
        return Ok(());
    }
    // No atomic exchange here: the previous plan aside, then the new one into place.
    let aside = a.with_extension("old");
    std::fs::rename(b, &aside).at(b)?;
    std::fs::rename(a, b).at(b)?;
    std::fs::rename(&aside, a).at(a)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slurm_syntaxes() {
        assert_eq!(parse_mem("4G").unwrap(), 4096);
        assert_eq!(parse_mem("1500").unwrap(), 1500);
        assert_eq!(parse_mem("1500m").unwrap(), 1500);
        assert_eq!(parse_mem("1025K").unwrap(), 2);
        for bad in ["", "G", "4X", "-1", "1.5G", "0", "4 G"] {
            assert!(parse_mem(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_time("90").unwrap(), 5400);
        assert_eq!(parse_time("1:30").unwrap(), 90);
        assert_eq!(parse_time("1:30:00").unwrap(), 5400);
        assert_eq!(parse_time("2-0").unwrap(), 172_800);
        assert_eq!(parse_time("1-2:3").unwrap(), 86400 + 7200 + 180);
        assert_eq!(parse_time("1-2:3:4").unwrap(), 86400 + 7200 + 184);
        for bad in ["", "1h", "1:2:3:4", "-1", "a-1", "0", "1--2", "1-2:3:4:5"] {
            assert!(parse_time(bad).is_err(), "{bad}");
        }
        assert_eq!(format_time(5400), "01:30:00");
        assert_eq!(format_time(90_061), "1-01:01:01");
        assert_eq!(shell_quote(Path::new("/a b/it's")), "'/a b/it'\\''s'");
    }
}
