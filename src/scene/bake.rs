//! `penumbra bake SCENE`: make exactly what a scene's [`Plan`] lists, as one walk of the stage
//! graph ([`crate::bake::bake`]): the planned tiles cut from the sources' mosaic, then the
//! products the renderer's methods read.

use std::path::Path;

use crate::bake::{self, BakeReport, Input, Stage};
use crate::error::Result;
use crate::fourier::FourierOptions;
use crate::mip::MipOptions;
use crate::progress::Progress;
use crate::tileset::Product;
use crate::tiling::TileOptions;

use super::plan::Plan;

/// How a scene's bake runs (not what it makes: that is the plan).
#[derive(Clone, Debug, Default)]
pub struct BakeOptions {
    /// When a later stage fails in a folder this bake created, keep what the earlier stages
    /// committed.
    pub keep_partial: bool,
    /// Keep only the plan's tiles in the tileset: tiles that earlier bakes of other scenes
    /// (same sources and layout) added are removed. False: a bake adds what its plan lists
    /// and leaves what is there.
    pub prune: bool,
}

/// The stage options a plan's bake runs with: the tiling options of its layout and sources,
/// and the scene's horizon and Fourier settings.
pub fn stage_plan(plan: &Plan, how: &BakeOptions) -> bake::Plan {
    let sc = &plan.scene;
    let derived = plan
        .sources
        .iter()
        .map(|s| s.native_level + 1)
        .max()
        .unwrap_or(1);
    let tile = TileOptions {
        tile_size: sc.tile_size,
        halo: sc.halo,
        projection: sc.projection,
        // The levels the sources give unless the regions ask for others (the embedded scene's
        // run is then the `tile` command's, byte for byte).
        levels: (plan.layout.levels != derived).then_some(plan.layout.levels),
        albedo: sc.albedo.as_ref().map(|a| (a.path.clone(), a.west_lon_deg)),
        prune: how.prune,
        ..TileOptions::default()
    };
    let mut stages = vec![Stage::Tile];
    if plan.makes(Product::Mip) {
        stages.push(Stage::Mip);
    }
    let fourier = plan.makes(Product::Fourier);
    let raw = plan.makes(Product::Horizon);
    if fourier || raw {
        stages.push(Stage::Horizon);
    }
    let mut horizon = plan.horizon_options();
    if plan.wanted().is_some() {
        // Some tiles of the sources only: the horizons assume the sources' whole range, so
        // that tiles another bake adds leave the horizons already made valid.
        horizon.terrain_range_m = sources_range_m(plan);
    }
    bake::Plan {
        stages,
        tile,
        mip: MipOptions::default(),
        horizon,
        fourier: fourier.then(|| FourierOptions {
            coefficients: sc.fourier.coefficients,
            ..FourierOptions::default()
        }),
        keep_raw: fourier && raw,
        horizon_level_at_most: None,
        keep_partial: how.keep_partial,
    }
}

/// The lowest and highest heights of the plan's sources (metres above the body's sphere,
/// datum shifts included), read from every sample; None when they hold none (the tiling stage
/// refuses that before the horizons run).
fn sources_range_m(plan: &Plan) -> Option<(f64, f64)> {
    let mut range: Option<(f64, f64)> = None;
    for s in &plan.sources {
        let e = s.dem.check_plausible(plan.body.radius_m).ok()?;
        let (Some(lo), Some(hi)) = (e.lowest, e.highest) else {
            continue;
        };
        let (lo, hi) = (lo.height_m, hi.height_m);
        range = Some(match range {
            Some((a, b)) => (a.min(lo), b.max(hi)),
            None => (lo, hi),
        });
    }
    range
}

/// Bake `plan` into the tileset folder `out`.
pub fn bake_scene(
    plan: &Plan,
    out: &Path,
    how: &BakeOptions,
    progress: &dyn Progress,
) -> Result<BakeReport> {
    let stages = stage_plan(plan, how);
    bake::bake(&Input::Scene(plan), out, &stages, progress)
}
