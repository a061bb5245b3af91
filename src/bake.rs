//! `bake`: run the stages a scene needs, in order, on one tileset.
//!
//! A [`Plan`] lists the stages to run; each stage reads the tileset the previous one left and
//! records its product in the manifest. Stages a scene does not select are not run and leave
//! nothing behind. Today: tiling, mipmaps, and (when levels are asked for) raw horizon maps;
//! Fourier pyramids join as they are built.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::body::Body;
use crate::dem::{self, Dem};
use crate::error::{Error, Result};
use crate::horizon::{self, HorizonOptions, HorizonReport};
use crate::mip::{self, MipOptions, MipReport};
use crate::progress::Progress;
use crate::scene::{self, SceneSpec};
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
pub enum Input {
    /// The embedded synthetic south-pole scene on the Moon.
    Embedded(SceneSpec),
    /// A DEM file and the body it belongs to as the caller chose it.
    Dem { path: PathBuf, body: BodyChoice },
}

/// The body to tile a DEM for, as the caller gave it: a preset name, a radius (which forces
/// that radius whatever the file says), both, or neither (the body the file names).
#[derive(Clone, Debug, Default)]
pub struct BodyChoice {
    pub name: Option<String>,
    pub radius_m: Option<f64>,
}

/// What to run.
pub struct Plan {
    pub stages: Vec<Stage>,
    pub tile: TileOptions,
    pub mip: MipOptions,
    pub horizon: HorizonOptions,
    /// Horizons at this level, or the finest when the tileset has fewer (the embedded scene's
    /// default), instead of `horizon.levels`.
    pub horizon_level_at_most: Option<u8>,
}

impl Default for Plan {
    fn default() -> Self {
        Plan {
            stages: vec![Stage::Tile, Stage::Mip],
            tile: TileOptions::default(),
            mip: MipOptions::default(),
            horizon: HorizonOptions::default(),
            horizon_level_at_most: None,
        }
    }
}

#[derive(Debug, Serialize)]
pub struct BakeReport {
    pub out: PathBuf,
    pub stages: Vec<Stage>,
    pub tile: Option<TileReport>,
    pub mip: Option<MipReport>,
    pub horizon: Option<HorizonReport>,
}

pub fn bake(input: &Input, out: &Path, plan: &Plan, progress: &dyn Progress) -> Result<BakeReport> {
    // One writer for the whole bake: no other process can slip in between two stages. (A
    // folder this makes is removed again if the bake fails before its first commit.)
    let _writer = crate::tileset::writer::Writer::begin(out)?;
    let mut report = BakeReport {
        out: out.to_path_buf(),
        stages: plan.stages.clone(),
        tile: None,
        mip: None,
        horizon: None,
    };
    for stage in &plan.stages {
        match stage {
            Stage::Tile => {
                let r = match input {
                    Input::Embedded(spec) => {
                        let parts = scene::generate(spec);
                        let hash = scene::content_hash(&parts);
                        let dem = Dem::new(parts, plan.tile.max_fill_px)?;
                        let body = Body::preset("moon")?;
                        let label = format!("south-pole-scene-{}px-{}m", spec.size, spec.pixel_m);
                        let emb = Embedded {
                            label,
                            blake3: hash,
                        };
                        tiling::tile_dem(&dem, &body, out, &plan.tile, Some(&emb), progress)?
                    }
                    Input::Dem { path, body } => {
                        let dem = dem::open(path, plan.tile.max_fill_px)?;
                        let body = body_for(&dem, body)?;
                        tiling::tile_dem(&dem, &body, out, &plan.tile, None, progress)?
                    }
                };
                report.tile = Some(r);
            }
            Stage::Mip => report.mip = Some(mip::build_mips(out, &plan.mip, progress)?),
            Stage::Horizon => {
                let mut opts = plan.horizon.clone();
                if let Some(l) = plan.horizon_level_at_most {
                    let levels = crate::manifest::Tileset::load(out)?.layout.levels;
                    opts.levels = Some(vec![l.min(levels - 1)]);
                }
                report.horizon = Some(horizon::build_horizons(out, &opts, progress)?)
            }
        }
    }
    Ok(report)
}

/// The body to tile `dem` for. A radius given by the caller is taken as it is (with the preset's
/// name when one is named too). A preset name alone is checked against the body the file names
/// (PDS3 TARGET_NAME): tiling Mars heights on the Moon is refused. Neither: the named body.
pub fn body_for(dem: &Dem, given: &BodyChoice) -> Result<Body> {
    let path = dem.sources().first().cloned().unwrap_or_default();
    if given.radius_m.is_some() {
        return Body::resolve(given.name.as_deref(), given.radius_m);
    }
    match (&given.name, dem.target()) {
        (Some(n), t) => {
            let b = Body::preset(n)?;
            match t {
                Some(t) if Body::preset(t).is_ok_and(|tb| tb.name != b.name) => {
                    Err(Error::usage(format!(
                        "{} is a DEM of {t} but the body {} was given: leave the body out, or give \
                         a radius to force one",
                        path.display(),
                        b.name
                    )))
                }
                _ => Ok(b),
            }
        }
        (None, Some(t)) => Body::preset(t).map_err(|_| {
            Error::usage(format!(
                "{} names the body '{t}', which has no preset: name a body or give a radius",
                path.display()
            ))
        }),
        (None, None) => Err(Error::usage(format!(
            "{} does not say which body it belongs to: name one (moon, mars, earth, …) or give a \
             radius",
            path.display()
        ))),
    }
}
