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

use std::path::Path;

use crate::error::{Error, Result};
use crate::manifest::Tileset;
use crate::tileset::writer::{Staging, Writer};
use crate::tileset::Product;

/// What a stage declares.
#[derive(Clone, Copy, Debug)]
pub struct StageSpec {
    /// Name of the stage (its staging folder, progress label).
    pub name: &'static str,
    /// Products it writes; the first is the one whose run key decides "up to date".
    pub writes: &'static [Product],
    /// Version strings of its output format and algorithms: a change recomputes.
    pub format: &'static [&'static str],
}

/// The run key of a stage: the tool version, the stage's format, the run keys of the products
/// it reads and its parameters. Equal keys mean identical output.
pub fn run_key(spec: &StageSpec, inputs: &[&str], params: &[&[u8]]) -> String {
    let mut h = blake3::Hasher::new();
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    for f in spec.format {
        h.update(f.as_bytes());
    }
    for k in inputs {
        h.update(k.as_bytes());
    }
    for p in params {
        h.update(p);
    }
    h.finalize().to_hex().to_string()
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
    let primary = spec.writes[0];
    let changed = current.and_then(|ts| primary.recorded_key(ts)) != Some(key);
    if let Some(ts) = current {
        if primary.recorded_key(ts) == Some(key)
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

    /// Swap the finished run in with `manifest` as the tileset's manifest.
    pub fn commit(self, manifest: Tileset) -> Result<()> {
        let Run {
            spec,
            mut writer,
            staging,
            changed,
        } = self;
        writer.commit(staging, spec.writes, manifest, changed)
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
