//! `penumbra bake SCENE`: make exactly what a scene's [`Plan`] lists, as one walk of the stage
//! graph ([`crate::bake::bake`]): the planned tiles cut from the sources' mosaic, then the
//! products the renderer's methods read.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::bake::{self, BakeReport, Input, Stage};
use crate::error::{Error, Result};
use crate::fourier::FourierOptions;
use crate::fsio;
use crate::manifest::MANIFEST;
use crate::mip::MipOptions;
use crate::progress::Progress;
use crate::tileset::writer::Writer;
use crate::tileset::Product;
use crate::tiling::TileOptions;

use super::plan::Plan;
use super::Scene;

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
    /// Where the horizon stage's sweep runs (None: the CPU): a device the front end made from
    /// the scene's `[horizon] device` or `--device`.
    pub device: Option<crate::horizon::device::SharedDevice>,
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
    horizon.device = how.device.clone();
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

/// Run one stage of `plan`'s bake into `out` on its own ([`bake::run_stage`]): whole (the
/// writer), one shard of its units among others running at the same time, or the finish that
/// checks the shards' work and commits it once. Shards cut the horizon stage's units by the
/// plan's model of each tile's cost ([`super::shards::pricing`]), as `penumbra plan --shards`
/// shows them. The stages it reads from must have committed (each run whole, or sharded and
/// finished); the folder's stamp is left to a whole bake of the scene.
pub fn bake_stage(
    plan: &Plan,
    out: &Path,
    stage: &str,
    select: &crate::runner::Select,
    role: crate::runner::Role,
    device: Option<crate::horizon::device::SharedDevice>,
    progress: &dyn Progress,
) -> Result<crate::graph::Ran> {
    let how = BakeOptions {
        device,
        ..BakeOptions::default()
    };
    let stages = stage_plan(plan, &how);
    let Some(st) = Stage::named(stage).filter(|s| stages.stages.contains(s)) else {
        let names: Vec<&str> = stages.stages.iter().map(|s| s.name()).collect();
        return Err(Error::param(
            "stage",
            format!(
                "'{stage}' is not a stage of this scene's bake: its stages are {}",
                names.join(", ")
            ),
        ));
    };
    let sharded = role != crate::runner::Role::Writer
        || matches!(select, crate::runner::Select::Shard { .. });
    let price = super::shards::pricing(plan, st).filter(|_| sharded);
    let pricing = price
        .as_ref()
        .map(|p| p as &(dyn Fn(&[crate::runner::Unit]) -> Vec<f64> + Sync));
    bake::run_stage(
        &Input::Scene(plan),
        out,
        &stages,
        st,
        select,
        role,
        pricing,
        progress,
    )
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

/// Bake `plan` into the tileset folder `out`, then stamp the folder with what the bake was
/// made from ([`unchanged`]).
pub fn bake_scene(
    plan: &Plan,
    out: &Path,
    how: &BakeOptions,
    progress: &dyn Progress,
) -> Result<BakeReport> {
    let stages = stage_plan(plan, how);
    let report = bake::bake(&Input::Scene(plan), out, &stages, progress)?;
    let mut files: Vec<PathBuf> = plan
        .sources
        .iter()
        .flat_map(|s| s.dem.sources().iter().cloned())
        .collect();
    files.extend(plan.scene.albedo.iter().map(|a| a.path.clone()));
    let mut writer = Writer::begin(out)?;
    if how.prune {
        // Exactly the plan: products an earlier bake of another scene made go too.
        let ts = crate::manifest::Tileset::load(out)?;
        let extra: Vec<Product> = [Product::Mip, Product::Horizon, Product::Fourier]
            .into_iter()
            .filter(|p| p.recorded_key(&ts).is_some() && !plan.makes(*p))
            .collect();
        writer.drop_products(&extra, ts)?;
    }
    let stamp = Stamp::now(&plan.scene, how, out, &files)?;
    writer.write_state_file(
        STAMP,
        &serde_json::to_vec(&stamp).expect("stamps serialise"),
    )?;
    Ok(report)
}

/// What a scene's last bake into a folder was made from: the scene (every setting, paths
/// resolved) and this tool's version, the manifest it left, and each file it read with its
/// size and modification time. A bake of the same scene finding the same stamp has nothing to
/// do, as make and cargo decide from the files' times; touch a source to have it checked.
#[derive(Debug, PartialEq, Serialize, Deserialize)]
struct Stamp {
    scene: String,
    manifest: String,
    files: Vec<(PathBuf, u64, i128)>,
}

/// A folder's stamp, in its bookkeeping folder.
const STAMP: &str = "scene-stamp.json";

impl Stamp {
    fn now(scene: &Scene, how: &BakeOptions, out: &Path, files: &[PathBuf]) -> Result<Stamp> {
        let mut h = blake3::Hasher::new();
        h.update(env!("CARGO_PKG_VERSION").as_bytes());
        h.update(&serde_json::to_vec(scene).expect("scenes serialise"));
        // (Not the device: a folder baked on a GPU is up to date for the same scene on the CPU,
        // its maps being within the sweep's budget of the CPU's; the horizon stage's run key
        // has the device, so a bake that does run the stage redoes it on the device asked.)
        h.update(&[u8::from(how.prune)]);
        let manifest = crate::tileset::manifest_hash(out).ok_or_else(|| {
            Error::invalid(out.join(MANIFEST), "the bake left no readable manifest")
        })?;
        let mut stamped = Vec::new();
        for f in files {
            let m = std::fs::metadata(f).map_err(|e| Error::io(f, e))?;
            let t = fsio::FileStamp::of(&m);
            stamped.push((f.clone(), t.len, t.mtime_ns));
        }
        Ok(Stamp {
            scene: h.finalize().to_hex().to_string(),
            manifest,
            files: stamped,
        })
    }
}

/// The report of a bake of `scene` into `out` that has nothing to do: the folder's stamp is
/// the one the last bake of this scene left, the manifest is as it left it, every source it
/// read has the size and time it had, and every file the products' indexes list is there
/// with its size. None: plan and bake (the stages then decide what is up to date).
pub fn unchanged(scene: &Scene, out: &Path, how: &BakeOptions) -> Result<Option<BakeReport>> {
    let Some(bytes) = crate::tileset::read_state_file(out, STAMP, 64 << 20) else {
        return Ok(None);
    };
    let Ok(old) = serde_json::from_slice::<Stamp>(&bytes) else {
        return Ok(None);
    };
    let files: Vec<PathBuf> = old.files.iter().map(|f| f.0.clone()).collect();
    match Stamp::now(scene, how, out, &files) {
        Ok(now) if now == old => {}
        _ => return Ok(None),
    }
    let Ok(ts) = crate::manifest::Tileset::load(out) else {
        return Ok(None);
    };
    for p in Product::ALL {
        if p.recorded_key(&ts).is_none() {
            continue;
        }
        let Ok(Some(ix)) = crate::tileset::Index::load(out, p.name()) else {
            return Ok(None);
        };
        let all_there = ix.files.iter().all(|(rel, (len, _))| {
            std::fs::metadata(out.join(rel)).is_ok_and(|m| m.is_file() && m.len() == *len)
        });
        if !all_there {
            return Ok(None);
        }
    }
    Ok(Some(BakeReport {
        out: out.to_path_buf(),
        unchanged: true,
        stages: Vec::new(),
        tile: None,
        mip: None,
        horizon: None,
    }))
}
