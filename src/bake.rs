//! `bake`: run the stages a scene needs, in order, on one tileset.
//!
//! A [`Plan`] lists the stages to run; the stage graph ([`crate::graph`]) orders them by the
//! products each reads and writes, and each records its product in the manifest. Stages a
//! scene does not select are not run and leave nothing behind. Today: tiling, mipmaps, and
//! (when levels are asked for) horizons, streamed into Fourier pyramids unless told not to.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::body::Body;
use crate::dem::{self, Dem};
pub use crate::dem::{body_for, BodyChoice};
use crate::error::{Error, Result};
use crate::fourier::FourierOptions;
use crate::graph::{self, HorizonNode, Node, Ran};
use crate::horizon::{HorizonOptions, HorizonReport};
use crate::mip::{MipOptions, MipReport};
use crate::progress::Progress;
use crate::runner::{Pricing, Role, Select};
use crate::synthetic::{self, SyntheticSpec};
use crate::tileset::Product;
use crate::tiling::{self, Embedded, TileOptions, TileReport};

/// A stage of the pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Stage {
    /// Cut the DEM (and albedo) into cube-face tiles.
    Tile,
    /// Maximum and (min, max) mipmaps of the height tiles (needs `Tile` first).
    Mip,
    /// Raw horizon maps of the levels in [`HorizonOptions::levels`] (needs `Tile`; uses the
    /// mipmaps' global extrema when `Mip` ran).
    Horizon,
}

/// Where the terrain comes from.
pub enum Input<'a> {
    /// The embedded synthetic south-pole scene on the Moon.
    Embedded(SyntheticSpec),
    /// A DEM file and the body it belongs to as the caller chose it.
    Dem { path: PathBuf, body: BodyChoice },
    /// A DEM file read by the reader `format` names (`DemFormat::Gdal`: through GDAL).
    DemWith {
        path: PathBuf,
        body: BodyChoice,
        format: crate::dem::DemFormat,
    },
    /// A scene's planned tiles, cut from its sources' mosaic.
    Scene(&'a crate::scene::plan::Plan),
}

/// What to run.
pub struct Plan {
    pub stages: Vec<Stage>,
    pub tile: TileOptions,
    pub mip: MipOptions,
    pub horizon: HorizonOptions,
    /// Compress the horizons into Fourier pyramids as they are computed.
    pub fourier: Option<FourierOptions>,
    /// With `fourier`: write the raw maps too.
    pub keep_raw: bool,
    /// Horizons at this level, or the finest when the tileset has fewer (the embedded scene's
    /// default), instead of `horizon.levels`.
    pub horizon_level_at_most: Option<u8>,
    /// When a stage fails after earlier stages committed in a folder this bake created, keep
    /// the folder (a valid tileset of the committed stages) instead of removing it.
    pub keep_partial: bool,
}

impl Default for Plan {
    fn default() -> Self {
        Plan {
            stages: vec![Stage::Tile, Stage::Mip],
            tile: TileOptions::default(),
            mip: MipOptions::default(),
            horizon: HorizonOptions::default(),
            fourier: None,
            keep_raw: false,
            horizon_level_at_most: None,
            keep_partial: false,
        }
    }
}

#[derive(Debug, Serialize)]
pub struct BakeReport {
    pub out: PathBuf,
    /// Nothing changed since the last bake of this scene into `out` (its stamp,
    /// [`crate::scene::bake::unchanged`]): no stage ran.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub unchanged: bool,
    pub stages: Vec<Stage>,
    pub tile: Option<TileReport>,
    pub mip: Option<MipReport>,
    pub horizon: Option<HorizonReport>,
}

/// Run the plan's stages on the tileset in `out` as a walk of the stage graph: each stage
/// after the stages whose products it reads.
///
/// A stage that fails leaves the tileset as the stages before it committed it. When none had
/// committed, the error is the stage's own (and a folder this bake made is gone). When some
/// had, the error is [`Error::AfterCommit`], naming the failed stage, the committed ones and
/// what became of the folder: removed when this bake created it (unless
/// [`Plan::keep_partial`]), else kept, valid, with the committed stages' products.
pub fn bake(
    input: &Input<'_>,
    out: &Path,
    plan: &Plan,
    progress: &dyn Progress,
) -> Result<BakeReport> {
    // Options alone are checked before any file is read or folder made.
    if plan.stages.contains(&Stage::Tile) {
        plan.tile.validate()?;
    }
    // One writer for the whole bake: no other process can slip in between two stages. (A
    // folder this makes is removed again if the bake fails before its first commit.)
    let created = !out.exists();
    let _writer = crate::tileset::writer::Writer::begin(out)?;
    let tile = TileNode {
        input,
        opts: &plan.tile,
    };
    let mip = graph::mip(plan.mip.clone());
    let horizon = BakeHorizon {
        node: HorizonNode::new(plan.horizon.clone(), plan.fourier.clone(), plan.keep_raw)?,
        at_most: plan.horizon_level_at_most,
    };
    let nodes: Vec<&dyn Node> = plan
        .stages
        .iter()
        .map(|s| -> &dyn Node {
            match s {
                Stage::Tile => &tile,
                Stage::Mip => &mip,
                Stage::Horizon => &horizon,
            }
        })
        .collect();
    let mut report = BakeReport {
        out: out.to_path_buf(),
        unchanged: false,
        stages: plan.stages.clone(),
        tile: None,
        mip: None,
        horizon: None,
    };
    let mut committed: Vec<&'static str> = Vec::new();
    for i in graph::order(&nodes)? {
        let ran = match nodes[i].run(out, &Select::All, progress) {
            Ok(r) => r,
            Err(e) if committed.is_empty() => return Err(e),
            Err(e) => {
                return Err(after_commit(
                    out,
                    created,
                    plan.keep_partial,
                    nodes[i],
                    &committed,
                    e,
                ))
            }
        };
        committed.push(nodes[i].name());
        match ran {
            Ran::Tile(r) => report.tile = Some(r),
            Ran::Mip(r) => report.mip = Some(r),
            Ran::Horizon(r) => report.horizon = Some(r),
            Ran::Fourier(_) | Ran::Other(_) | Ran::Partial { .. } => {}
        }
    }
    Ok(report)
}

/// Run one stage of the plan, on its own, in a [`Role`]: whole as the writer (after the
/// stages it reads from have committed), as one shard of its units ([`Select::Shard`]) among
/// others running at the same time, or as the finish that checks and commits the shards'
/// work; `pricing` prices the units for the shard cut. The plan's other stages are the graph's
/// dependencies of this one: run before it, each whole or sharded and finished. Tiling runs
/// whole only.
#[allow(clippy::too_many_arguments)]
pub fn run_stage(
    input: &Input<'_>,
    out: &Path,
    plan: &Plan,
    stage: Stage,
    select: &Select,
    role: Role,
    pricing: Option<Pricing>,
    progress: &dyn Progress,
) -> Result<Ran> {
    if !plan.stages.contains(&stage) {
        return Err(Error::usage(format!(
            "the bake has no {} stage (its stages: {})",
            stage.name(),
            plan.stages
                .iter()
                .map(|s| s.name())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    match stage {
        Stage::Tile => {
            plan.tile.validate()?;
            TileNode {
                input,
                opts: &plan.tile,
            }
            .run_as(out, select, role, pricing, progress)
        }
        Stage::Mip => graph::mip(plan.mip.clone()).run_as(out, select, role, pricing, progress),
        Stage::Horizon => BakeHorizon {
            node: HorizonNode::new(plan.horizon.clone(), plan.fourier.clone(), plan.keep_raw)?,
            at_most: plan.horizon_level_at_most,
        }
        .run_as(out, select, role, pricing, progress),
    }
}

impl Stage {
    /// The stage's name, as the runner and the graph call it (`tile`, `mip`, `horizon`).
    pub fn name(self) -> &'static str {
        match self {
            Stage::Tile => tiling::STAGE.name,
            Stage::Mip => "mip",
            Stage::Horizon => "horizon",
        }
    }

    /// The stage called `name` ([`Stage::name`]).
    pub fn named(name: &str) -> Option<Stage> {
        [Stage::Tile, Stage::Mip, Stage::Horizon]
            .into_iter()
            .find(|s| s.name() == name)
    }
}

/// The error of stage `failed` after the stages `committed` had committed in `out`; removes
/// `out` when this bake `created` it and the caller did not ask to `keep_partial`.
fn after_commit(
    out: &Path,
    created: bool,
    keep_partial: bool,
    failed: &dyn Node,
    committed: &[&'static str],
    source: Error,
) -> Error {
    let done = committed.join(", ");
    let outcome =
        if created && !keep_partial {
            match crate::fsio::remove_tree(out) {
                Ok(()) => format!(
                    "removed {}, which this bake created (keep_partial keeps what the committed \
                 stages wrote)",
                    out.display()
                ),
                Err(e) => format!(
                    "could not remove {}, which this bake created ({e}): remove it by hand",
                    out.display()
                ),
            }
        } else {
            format!(
            "kept {}{} as {done} left it: a valid tileset, whose {} products (if any) are those \
             from before this bake; a rerun resumes from there",
            out.display(),
            if created { ", which this bake created," } else { "" },
            failed.name()
        )
        };
    Error::AfterCommit {
        stage: failed.name(),
        committed: done,
        outcome,
        source: Box::new(source),
    }
}

/// The tiling stage as a node of the graph: it makes the tileset from a DEM or the embedded
/// scene.
struct TileNode<'a> {
    input: &'a Input<'a>,
    opts: &'a TileOptions,
}

impl Node for TileNode<'_> {
    fn name(&self) -> &'static str {
        tiling::STAGE.name
    }
    fn writes(&self) -> Vec<Product> {
        tiling::STAGE.writes.to_vec()
    }
    fn reads(&self) -> Vec<Product> {
        Vec::new()
    }
    fn run(&self, out: &Path, select: &Select, progress: &dyn Progress) -> Result<Ran> {
        if *select != Select::All {
            return Err(Error::usage("the tiling stage runs whole"));
        }
        let r = match self.input {
            Input::Embedded(spec) => {
                let parts = synthetic::generate(spec);
                let hash = synthetic::content_hash(&parts);
                let dem = Dem::new(parts, self.opts.max_fill_px)?;
                let body = Body::preset("moon")?;
                let label = format!("south-pole-scene-{}px-{}m", spec.size, spec.pixel_m);
                let emb = Embedded {
                    label,
                    blake3: hash,
                };
                tiling::tile_dem(&dem, &body, out, self.opts, Some(&emb), progress)?
            }
            Input::Dem { path, body } => {
                let dem = dem::open(path, self.opts.max_fill_px)?;
                let body = body_for(&dem, body)?;
                tiling::tile_dem(&dem, &body, out, self.opts, None, progress)?
            }
            Input::DemWith { path, body, format } => {
                let dem = dem::open_as(path, *format, self.opts.max_fill_px)?;
                let body = body_for(&dem, body)?;
                tiling::tile_dem(&dem, &body, out, self.opts, None, progress)?
            }
            Input::Scene(plan) => {
                let sources: Vec<tiling::MosaicSource> = plan
                    .sources
                    .iter()
                    .map(|s| tiling::MosaicSource {
                        dem: &s.dem,
                        feather_px: s.feather_px,
                    })
                    .collect();
                let embedded = plan.sources.iter().find_map(|s| s.embedded.clone());
                tiling::tile_sources(
                    &sources,
                    &plan.body,
                    out,
                    self.opts,
                    embedded.as_ref(),
                    plan.wanted(),
                    progress,
                )?
            }
        };
        Ok(Ran::Tile(r))
    }
}

/// The horizon node of a bake, whose levels may depend on the tileset tiling makes (the
/// embedded scene's level, or the finest).
struct BakeHorizon {
    node: HorizonNode,
    at_most: Option<u8>,
}

impl Node for BakeHorizon {
    fn name(&self) -> &'static str {
        self.node.name()
    }
    fn writes(&self) -> Vec<Product> {
        self.node.writes()
    }
    fn reads(&self) -> Vec<Product> {
        self.node.reads()
    }
    fn run(&self, out: &Path, select: &Select, progress: &dyn Progress) -> Result<Ran> {
        self.run_as(out, select, Role::Writer, None, progress)
    }
    fn run_as(
        &self,
        out: &Path,
        select: &Select,
        role: Role,
        pricing: Option<Pricing>,
        progress: &dyn Progress,
    ) -> Result<Ran> {
        match self.at_most {
            None => self.node.run_as(out, select, role, pricing, progress),
            Some(l) => {
                let levels = crate::manifest::Tileset::load(out)?.layout.levels;
                let mut opts = self.node.opts.clone();
                opts.levels = Some(vec![l.min(levels - 1)]);
                let fourier = self.node.fourier.as_ref().map(|f| f.opts.clone());
                HorizonNode::new(opts, fourier, self.node.keep_raw)?
                    .run_as(out, select, role, pricing, progress)
            }
        }
    }
}
