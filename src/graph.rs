//! The stage graph: every stage declares the products it writes and reads
//! ([`crate::runner::StageSpec`]) and its units ([`crate::runner::Stage`]); the graph orders a
//! set of stages so that each runs after the stages making what it reads, runs them through
//! the runner (all their units, or a selection), and composes streams between stages
//! ([`crate::sink`]): "horizons → Fourier encoder" when raw maps are not kept, without either
//! stage naming the other.
//!
//! `bake` is a walk of this graph ([`walk`]); `horizon --fourier` is [`horizons`].

use std::path::Path;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::fourier::{FourierOptions, FourierReport, FourierSink, FourierStage};
use crate::horizon::{HorizonOptions, HorizonReport, HorizonStage};
use crate::mip::{MipOptions, MipReport, MipStage};
use crate::progress::Progress;
use crate::runner::{self, Outcome, Pricing, Role, Select, Stage};
use crate::sink::HorizonSink;
use crate::tileset::Product;
use crate::tiling::TileReport;

/// What one stage of a walk reported.
#[derive(Debug, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Ran {
    Tile(TileReport),
    Mip(MipReport),
    Horizon(HorizonReport),
    Fourier(FourierReport),
    /// A stage the graph does not list (its report as JSON).
    Other(serde_json::Value),
    /// Some of the stage's units ran; the stage has not committed.
    Partial {
        stage: &'static str,
        ran: usize,
        done: usize,
        total: usize,
    },
}

/// A stage as the graph sees it: what it writes and reads, and how to run (some of) it.
pub trait Node {
    fn name(&self) -> &'static str;
    fn writes(&self) -> Vec<Product>;
    fn reads(&self) -> Vec<Product>;
    fn run(&self, dir: &Path, select: &Select, progress: &dyn Progress) -> Result<Ran>;
    /// Run (some of) it in a [`Role`]: as a shard among others running at once, or as the
    /// finish of their run; `pricing` prices the units for the shard cut. A node that is not a
    /// runner stage runs whole, as the writer, only.
    fn run_as(
        &self,
        dir: &Path,
        select: &Select,
        role: Role,
        pricing: Option<Pricing>,
        progress: &dyn Progress,
    ) -> Result<Ran> {
        if role != Role::Writer || pricing.is_some() {
            return Err(Error::usage(format!(
                "the {} stage runs whole, in one process: it has no shards to run or finish",
                self.name()
            )));
        }
        self.run(dir, select, progress)
    }
}

/// A runner stage as a node, with how its report is told apart.
pub struct StageNode<S: Stage> {
    pub stage: S,
    pub report: fn(S::Report) -> Ran,
}

impl<S: Stage> Node for StageNode<S> {
    fn name(&self) -> &'static str {
        self.stage.spec().name
    }
    fn writes(&self) -> Vec<Product> {
        self.stage.spec().writes.to_vec()
    }
    fn reads(&self) -> Vec<Product> {
        self.stage.spec().reads.to_vec()
    }
    fn run(&self, dir: &Path, select: &Select, progress: &dyn Progress) -> Result<Ran> {
        let outcome = runner::execute(&self.stage, dir, select, progress)?;
        Ok(ran(self.name(), outcome, self.report))
    }
    fn run_as(
        &self,
        dir: &Path,
        select: &Select,
        role: Role,
        pricing: Option<Pricing>,
        progress: &dyn Progress,
    ) -> Result<Ran> {
        let outcome = runner::execute_as(&self.stage, dir, select, role, pricing, progress)?;
        Ok(ran(self.name(), outcome, self.report))
    }
}

/// What a run of `stage` did, as the graph tells reports apart.
fn ran<R>(stage: &'static str, outcome: Outcome<R>, report: impl FnOnce(R) -> Ran) -> Ran {
    match outcome {
        Outcome::Done(r) => report(r),
        Outcome::Partial { ran, done, total } => Ran::Partial {
            stage,
            ran,
            done,
            total,
        },
    }
}

/// The mip stage as a node.
pub fn mip(opts: MipOptions) -> StageNode<MipStage> {
    StageNode {
        stage: MipStage::new(opts),
        report: Ran::Mip,
    }
}

/// The Fourier stage from stored raw maps as a node.
pub fn fourier(opts: FourierOptions) -> StageNode<FourierStage> {
    StageNode {
        stage: FourierStage { opts },
        report: Ran::Fourier,
    }
}

/// The horizon stage, streaming into the Fourier encoder when `fourier` is given (and then
/// writing raw maps only with `keep_raw`).
pub struct HorizonNode {
    pub opts: HorizonOptions,
    pub fourier: Option<FourierSink>,
    pub keep_raw: bool,
}

impl HorizonNode {
    pub fn new(
        opts: HorizonOptions,
        fourier: Option<FourierOptions>,
        keep_raw: bool,
    ) -> Result<HorizonNode> {
        if keep_raw && fourier.is_none() {
            return Err(Error::param(
                "keep_raw",
                "only means something with Fourier compression (--fourier): raw maps are what \
                 the horizon stage writes otherwise",
            ));
        }
        Ok(HorizonNode {
            opts,
            fourier: fourier.map(|opts| FourierSink { opts }),
            keep_raw,
        })
    }

    /// The horizon stage with its sinks composed.
    pub fn stage(&self) -> HorizonStage<'_> {
        HorizonStage {
            opts: self.opts.clone(),
            raw: self.fourier.is_none() || self.keep_raw,
            sinks: self.fourier.iter().map(|s| s as &dyn HorizonSink).collect(),
        }
    }
}

impl Node for HorizonNode {
    fn name(&self) -> &'static str {
        "horizon"
    }
    fn writes(&self) -> Vec<Product> {
        self.stage().spec().writes.to_vec()
    }
    fn reads(&self) -> Vec<Product> {
        self.stage().spec().reads.to_vec()
    }
    fn run(&self, dir: &Path, select: &Select, progress: &dyn Progress) -> Result<Ran> {
        let outcome = runner::execute(&self.stage(), dir, select, progress)?;
        Ok(ran(self.name(), outcome, Ran::Horizon))
    }
    fn run_as(
        &self,
        dir: &Path,
        select: &Select,
        role: Role,
        pricing: Option<Pricing>,
        progress: &dyn Progress,
    ) -> Result<Ran> {
        let outcome = runner::execute_as(&self.stage(), dir, select, role, pricing, progress)?;
        Ok(ran(self.name(), outcome, Ran::Horizon))
    }
}

/// Compute horizons (streamed into Fourier pyramids when `fourier` is given), all units or
/// the selected ones.
pub fn horizons(
    dir: &Path,
    opts: &HorizonOptions,
    fourier: Option<&FourierOptions>,
    keep_raw: bool,
    select: &Select,
    progress: &dyn Progress,
) -> Result<Ran> {
    HorizonNode::new(opts.clone(), fourier.cloned(), keep_raw)?.run(dir, select, progress)
}

/// The order a set of nodes runs in: each after every node that writes what it reads (the
/// given order among the rest). A node reading a product no node here writes reads what the
/// tileset holds.
pub fn order(nodes: &[&dyn Node]) -> Result<Vec<usize>> {
    let mut left: Vec<usize> = (0..nodes.len()).collect();
    let mut out = Vec::with_capacity(nodes.len());
    while !left.is_empty() {
        let ready = left.iter().position(|&i| {
            nodes[i].reads().iter().all(|r| {
                !left
                    .iter()
                    .any(|&j| j != i && nodes[j].writes().contains(r))
            })
        });
        match ready {
            Some(k) => out.push(left.remove(k)),
            None => {
                let names: Vec<&str> = left.iter().map(|&i| nodes[i].name()).collect();
                return Err(Error::usage(format!(
                    "the stages {names:?} read each other's products: no order runs them"
                )));
            }
        }
    }
    Ok(out)
}

/// Run every node on the tileset in `dir`, in [`order`]; their reports in that order.
pub fn walk(dir: &Path, nodes: &[&dyn Node], progress: &dyn Progress) -> Result<Vec<Ran>> {
    let mut out = Vec::with_capacity(nodes.len());
    for i in order(nodes)? {
        out.push(nodes[i].run(dir, &Select::All, progress)?);
    }
    Ok(out)
}
