//! The Fourier encoder as a sink of the horizon stage ([`crate::sink`]): each tile's horizons
//! compressed into its pyramid as the horizon stage finishes it, so that raw maps need not be
//! written (`horizon --fourier`, `bake`). The graph ([`crate::graph`]) composes it.

use std::path::Path;

use serde::Serialize;

use super::stage::{
    check_options, check_output_size, check_tileset, product, Encoder, FourierOptions, Source,
    Tally, TileStats,
};
use crate::error::Result;
use crate::format::fourier::{self as pyramid, tile_path, Encoding, Layout, FORMAT};
use crate::layout::TileId;
use crate::manifest::Tileset;
use crate::sink::{HorizonSink, HorizonSource, HorizonTile, SinkRun};
use crate::tileset::Product;

use super::series::Sigma;

/// What the streamed compression made (the horizon run's report, under `fourier`).
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct StreamedFourier {
    pub coefficients: usize,
    pub layout: Layout,
    pub encoding: Encoding,
    pub sigma: Sigma,
    pub tiles_fully_lit: u64,
    pub bytes_written: u64,
    pub bytes_per_tile: u64,
}

/// Compress horizons into pyramids with these options as they are computed.
pub struct FourierSink {
    pub opts: FourierOptions,
}

impl HorizonSink for FourierSink {
    fn name(&self) -> &'static str {
        "fourier"
    }

    fn products(&self) -> &'static [Product] {
        &[Product::Fourier]
    }

    fn formats(&self) -> &'static [&'static str] {
        &[FORMAT]
    }

    fn key_fields(&self) -> Vec<(&'static str, String)> {
        vec![(
            "fourier",
            serde_json::to_string(&self.opts).unwrap_or_default(),
        )]
    }

    fn check(&self, azimuths: usize) -> Result<()> {
        check_options(&self.opts, azimuths)
    }

    fn prepare(
        &self,
        ts: &Tileset,
        tiles: usize,
        azimuths: usize,
        terrain_min_m: f64,
        lit_above_deg: Option<f64>,
    ) -> Result<Box<dyn SinkRun>> {
        check_tileset(&self.opts, ts, lit_above_deg)?;
        check_output_size(&self.opts, tiles, ts.layout.tile_size as usize)?;
        Ok(Box::new(FourierRun {
            opts: self.opts.clone(),
            encoder: Encoder::new(&self.opts, ts, azimuths, terrain_min_m),
            n: ts.layout.tile_size as usize,
        }))
    }
}

struct FourierRun {
    opts: FourierOptions,
    encoder: Encoder,
    n: usize,
}

impl FourierRun {
    fn summary(&self, fully_lit: u64, bytes_written: u64) -> serde_json::Value {
        let f = &self.opts;
        serde_json::to_value(StreamedFourier {
            coefficients: f.coefficients,
            layout: f.layout,
            encoding: f.encoding,
            sigma: f.sigma,
            tiles_fully_lit: fully_lit,
            bytes_written,
            bytes_per_tile: pyramid::file_bytes(self.n, f.coefficients, f.layout) as u64,
        })
        .expect("the summary serialises")
    }
}

impl SinkRun for FourierRun {
    fn accept(&self, out: &Path, tile: HorizonTile) -> Result<serde_json::Value> {
        let (p, stats) = match tile.pruned {
            Some(bound) => self.encoder.encode_pruned(bound),
            None => self.encoder.encode(tile.planes, tile.height),
        };
        let identity = crate::format::Identity::tile(pyramid::ID, tile.id, tile.run_key);
        pyramid::write(&tile_path(out, tile.id), &p, &identity)?;
        Ok(serde_json::to_value(stats).expect("stats serialise"))
    }

    fn finish(
        &self,
        manifest: &mut Tileset,
        records: Vec<(TileId, serde_json::Value, bool)>,
        source: &HorizonSource,
        run_key: &str,
    ) -> Result<serde_json::Value> {
        let mut tally = Tally::default();
        for (id, v, here) in records {
            let stats: TileStats = serde_json::from_value(v).map_err(|e| {
                crate::error::Error::usage(format!("a unit record of tile {id:?} is damaged: {e}"))
            })?;
            if here {
                tally.add(id, stats);
            } else {
                tally.add_kept(id, stats);
            }
        }
        let (lit, bytes) = (tally.fully_lit, tally.bytes_written);
        let entry = product(
            manifest,
            &self.opts,
            source.levels.clone(),
            source.azimuths,
            tally,
            Source {
                kind: "streamed",
                method: &source.method,
                near_px: source.near_px,
                error: source.error.clone(),
                terrain: (source.terrain_min_m, source.terrain_max_m),
                distances: source.distances.clone(),
                lit_above_deg: source.lit_above_deg,
            },
            run_key.to_string(),
            source.basis.clone(),
        );
        manifest.products.fourier = Some(entry);
        Ok(self.summary(lit, bytes))
    }

    fn up_to_date(&self, ts: &Tileset) -> serde_json::Value {
        let lit = ts
            .products
            .fourier
            .as_ref()
            .map_or(0, |f| f.tiles_fully_lit);
        self.summary(lit, 0)
    }
}
