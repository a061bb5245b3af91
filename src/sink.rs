//! Streams between stages. A stage whose per-tile output another stage consumes hands each
//! finished tile to a sink instead of (or as well as) writing it, and the graph
//! ([`crate::graph`]) composes the two: neither stage names the other. Today one stream
//! exists: horizon maps → the Fourier encoder (`horizon --fourier`, `bake`), so that the raw
//! maps need never be written.
//!
//! A sink is part of the producing stage's run: its products are written by that run, its
//! options enter that run's key, and its per-tile records are stored with the run's unit
//! records, so a resumed or sharded run finishes the sink's product exactly as a whole run
//! does.

use std::path::Path;

use crate::error::Result;
use crate::format::height::HeightTile;
use crate::format::horizon::{HorizonError, HorizonLevelDistance};
use crate::layout::TileId;
use crate::manifest::Tileset;
use crate::tileset::Product;

/// One finished tile of horizon maps.
pub struct HorizonTile<'a> {
    pub id: TileId,
    /// The run key of the horizon run (a streamed product's run key: its files' identity).
    pub run_key: &'a str,
    /// `A` planes of n² elevations (degrees), plane k at plane azimuth 360·k/A; empty when
    /// the tile was left out (`pruned`).
    pub planes: &'a [f32],
    /// The tile's heights (halo included).
    pub height: &'a HeightTile,
    /// Left out by the run's `lit_above_deg` (the horizon was not computed): the upper bound
    /// of its horizon elevation (degrees, below the threshold). The tile is fully lit for every
    /// sun whose lower limb is at or above the threshold.
    pub pruned: Option<f32>,
}

/// How the horizons a sink consumed were made (what a product built from them records).
#[derive(Clone, Debug)]
pub struct HorizonSource {
    pub levels: Vec<u8>,
    pub azimuths: usize,
    pub method: String,
    pub near_px: Option<f64>,
    /// The method's measured error against the reference (the sweep method).
    pub error: Option<HorizonError>,
    pub terrain_min_m: f64,
    pub terrain_max_m: f64,
    pub distances: Vec<HorizonLevelDistance>,
    /// What the run key of the run that made them hashes besides its inputs' (a streamed
    /// product's `run_key_basis`).
    pub basis: crate::format::KeyBasis,
    /// The threshold tiles were left out below (`HorizonOptions::lit_above_deg`).
    pub lit_above_deg: Option<f64>,
}

/// A consumer of horizon maps, set up by the graph.
pub trait HorizonSink: Sync {
    /// Its name (the key of its summary in the run's report).
    fn name(&self) -> &'static str;
    /// The products it writes.
    fn products(&self) -> &'static [Product];
    /// Version strings of its output (part of the run key).
    fn formats(&self) -> &'static [&'static str];
    /// Its options as fields of the run key's parameters: (name, JSON text).
    fn key_fields(&self) -> Vec<(&'static str, String)>;
    /// Check its options for horizons of `azimuths` samples.
    fn check(&self, azimuths: usize) -> Result<()>;
    /// Check it against the tileset and the run's `tiles`, and set up a run whose horizons
    /// are bounded below by `terrain_min_m` and which leaves out the tiles whose horizon never
    /// reaches `lit_above_deg` (handed over as [`HorizonTile::pruned`]).
    fn prepare(
        &self,
        ts: &Tileset,
        tiles: usize,
        azimuths: usize,
        terrain_min_m: f64,
        lit_above_deg: Option<f64>,
    ) -> Result<Box<dyn SinkRun>>;
}

/// A sink within one run.
pub trait SinkRun: Sync {
    /// Write what the sink makes of one tile below `out` (the run's staging root); a record
    /// for [`SinkRun::finish`], which must round-trip through JSON exactly.
    fn accept(&self, out: &Path, tile: HorizonTile) -> Result<serde_json::Value>;
    /// Every tile accepted (in plan order; `here`: accepted by this process): add the sink's
    /// products to `manifest`; a summary for the run's report.
    fn finish(
        &self,
        manifest: &mut Tileset,
        records: Vec<(TileId, serde_json::Value, bool)>,
        source: &HorizonSource,
        run_key: &str,
    ) -> Result<serde_json::Value>;
    /// The summary of a run that found the products of `ts` up to date.
    fn up_to_date(&self, ts: &Tileset) -> serde_json::Value;
}
