//! A scene's stages in shards: how `penumbra plan SCENE --shards N` and
//! `penumbra bake SCENE --stage S --shard I/N` cut a stage's units between N processes. The
//! runner cuts the cumulative cost of the units laid along a space-filling curve
//! ([`Select::assign`]); for the horizon stage, whose tiles cost very different amounts
//! (relief, data, far rings), the cost of each tile is the plan's model of it
//! ([`super::cost::tile_work`] priced by the plan's rates), computed by every shard alike.
//! The mip stage's units cost the same per tile, and tiling runs whole (it is not a runner
//! stage: its units are groups of tiles sampled from the sources together).

use std::collections::{BTreeSet, HashMap};

use rayon::prelude::*;
use serde::Serialize;

use super::cost::{self, WorkInputs};
use super::plan::Plan;
use crate::dem::Dem;
use crate::layout::TileId;
use crate::runner::{Select, Unit};

/// The plan's model of the horizon stage's core-seconds for each of `tiles` (in order).
pub fn horizon_costs(plan: &Plan, tiles: &[TileId]) -> Vec<f64> {
    let radius = plan.body.radius_m;
    let shifted: Vec<(&Dem, f64)> = plan
        .sources
        .iter()
        .map(|s| (&s.dem, s.dem.datum_radius_m().map_or(0.0, |r0| r0 - radius)))
        .collect();
    let defaults = crate::horizon::HorizonOptions::default();
    let inputs = WorkInputs {
        layout: &plan.layout,
        radius_m: radius,
        range: cost::terrain_range(&shifted).unwrap_or(plan.body.relief_m),
        sources: shifted,
        fine_margin_px: crate::horizon::default_fine_margin_px(plan.layout.tile_size),
        max_margin_px: defaults.max_margin_px,
        far_rings: plan.scene.horizon.method.sees_far_rings(),
    };
    let az = plan.scene.horizon.azimuths as u64;
    let n = f64::from(plan.layout.tile_size);
    // Streamed Fourier pyramids: the encoder's time, the same per tile.
    let encode = if plan.makes(crate::tileset::Product::Fourier) {
        n * n * az as f64 * plan.rates.fourier_ns_per_px_az * 1e-9
    } else {
        0.0
    };
    tiles
        .par_chunks(64)
        .flat_map_iter(|chunk| {
            let mut covers = HashMap::new();
            chunk
                .iter()
                .map(|&t| {
                    let w = cost::tile_work(&inputs, t, &plan.tiles, &mut covers);
                    plan.rates.horizon_core_s(&w, az) + encode
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

/// The pricing of a stage's units for its shard cut ([`crate::runner::Pricing`]): the plan's
/// model for the horizon stage; None (the units' own, equal, costs) for the others.
pub fn pricing(
    plan: &Plan,
    stage: crate::bake::Stage,
) -> Option<impl Fn(&[Unit]) -> Vec<f64> + Sync + '_> {
    (stage == crate::bake::Stage::Horizon).then_some(move |units: &[Unit]| {
        let tiles: Vec<TileId> = units.iter().map(|u| u.tile).collect();
        horizon_costs(plan, &tiles)
    })
}

/// One shard of one stage in the plan's model.
#[derive(Clone, Debug, Serialize)]
pub struct ShardCost {
    pub shard: usize,
    pub units: u64,
    /// Estimated core-seconds.
    pub cpu_s_est: f64,
}

/// A stage cut into shards in the plan's model.
#[derive(Clone, Debug, Serialize)]
pub struct StageShards {
    pub stage: &'static str,
    pub units: u64,
    pub cpu_s_est: f64,
    pub shards: Vec<ShardCost>,
    /// The costliest shard's estimate over the mean: 1 is a perfect balance; the whole run
    /// takes about this much longer than its work spread evenly.
    pub slowest_over_mean: f64,
}

/// `penumbra plan SCENE --shards N`: each sharded stage cut into N shards, and the share of
/// the estimated CPU time spent in tiling, which runs whole before them.
#[derive(Clone, Debug, Serialize)]
pub struct ShardTable {
    pub count: usize,
    pub stages: Vec<StageShards>,
    /// Tiling's estimated core-seconds, and its share of the bake's.
    pub tile_cpu_s_est: f64,
    pub tile_share: f64,
}

/// Cut the plan's sharded stages into `count` shards as the bake's shards will, by the plan's
/// units: one per planned tile (of the horizon levels for the horizon stage). The bake's units
/// are the tiles the tiling stage wrote (tiles the plan lists but finds no data on are not
/// units) and the sun rule's pruned tiles cost little there; the plan prices them all.
pub fn table(plan: &Plan, count: usize) -> ShardTable {
    let side = plan.layout.stored_size() as f64;
    let all: Vec<TileId> = plan.tiles.iter().copied().collect();
    let mut stages = Vec::new();
    if plan.makes(crate::tileset::Product::Mip) {
        let per = side * side * plan.rates.mip_ns_per_px * 1e-9;
        stages.push(cut("mip", &all, &vec![per; all.len()], count));
    }
    if plan.makes(crate::tileset::Product::Horizon) || plan.makes(crate::tileset::Product::Fourier)
    {
        let levels: BTreeSet<u8> = plan.horizon_levels.iter().copied().collect();
        let tiles: Vec<TileId> = all
            .iter()
            .copied()
            .filter(|t| levels.contains(&t.level))
            .collect();
        let costs = horizon_costs(plan, &tiles);
        stages.push(cut("horizon", &tiles, &costs, count));
    }
    let cpu = |name: &str| {
        plan.products
            .iter()
            .filter(|p| p.made && p.product == name)
            .map(|p| p.cpu_s_est)
            .sum::<f64>()
    };
    let tile_cpu_s_est = cpu("height") + cpu("albedo");
    let total: f64 = plan.products.iter().map(|p| p.cpu_s_est).sum();
    ShardTable {
        count,
        stages,
        tile_cpu_s_est,
        tile_share: if total > 0.0 {
            tile_cpu_s_est / total
        } else {
            0.0
        },
    }
}

fn cut(stage: &'static str, tiles: &[TileId], costs: &[f64], count: usize) -> StageShards {
    let units: Vec<Unit> = tiles
        .iter()
        .zip(costs)
        .map(|(&t, &c)| Unit::tile(t, Vec::new(), c))
        .collect();
    let shard = Select::assign(&units, costs, count);
    let mut shards: Vec<ShardCost> = (0..count)
        .map(|shard| ShardCost {
            shard,
            units: 0,
            cpu_s_est: 0.0,
        })
        .collect();
    for (i, &s) in shard.iter().enumerate() {
        shards[s].units += 1;
        shards[s].cpu_s_est += costs[i].max(0.0);
    }
    let total: f64 = shards.iter().map(|s| s.cpu_s_est).sum();
    let slowest = shards.iter().map(|s| s.cpu_s_est).fold(0.0, f64::max);
    let mean = total / count.max(1) as f64;
    StageShards {
        stage,
        units: tiles.len() as u64,
        cpu_s_est: total,
        shards,
        slowest_over_mean: if mean > 0.0 { slowest / mean } else { 1.0 },
    }
}
