//! What a scene's bake makes: the tiles per level (the regions' tiles the sources resolve and
//! have data on), the products the renderer's methods read, and everything left out, each with
//! the rule that left it out, its bytes and its estimated CPU time.
//!
//! The plan is computed from the scene file and the sources' headers and pixels alone — no
//! tileset is read — so `penumbra plan` shows the cost before anything is paid, and
//! `penumbra bake SCENE` makes exactly the planned tiles (the tiling stage's `wanted` set).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use super::cost::{self, HorizonWork, WorkInputs};
use super::{Finest, RegionShape, RegionSpec, Scene, SourceKind, SunSpec, PRODUCTS};
use crate::body::Body;
use crate::cube;
use crate::dem::{self, mask, Dem};
use crate::dem::{body_for, BodyChoice};
use crate::error::{Error, Result};
use crate::layout::{Layout, TileId, MAX_LEVELS};
use crate::region;
use crate::tileset::Product;

/// A source as the plan uses it.
pub struct PlannedSource {
    /// The file, or the embedded terrain's label.
    pub label: String,
    pub dem: Dem,
    /// The embedded terrain's label and content hash (for the tiling run's identity).
    pub embedded: Option<crate::tiling::Embedded>,
    pub feather_px: f64,
    /// Ground size of its pixels (m).
    pub pixel_m: f64,
    /// The finest level it resolves (centre pixel no larger than its own) and the finest it
    /// may be oversampled to (the scene's `max_oversampling`).
    pub native_level: u8,
    pub max_level: u8,
    /// Tiles at levels `..= max_level` its footprint reaches (and their ancestors).
    pub reach: BTreeSet<TileId>,
    pub line: usize,
}

/// Why a tile or a product is not made.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Rule {
    /// The tile meets no region.
    OutsideRegions,
    /// The tile is in a region but finer than the region asks.
    FinerThanRegion,
    /// No source covering the tile resolves its level within `max_oversampling`.
    Oversampled,
    /// No interior pixel of the tile falls on any source's data.
    NoData,
    /// No listed method reads the product.
    NotRead,
    /// The tile's horizon provably never reaches the scene's lowest sun: recorded fully lit.
    SunNeverOccluded,
}

impl Rule {
    pub fn name(self) -> &'static str {
        match self {
            Rule::OutsideRegions => "outside-regions",
            Rule::FinerThanRegion => "finer-than-region",
            Rule::Oversampled => "oversampled",
            Rule::NoData => "no-data",
            Rule::NotRead => "not-read",
            Rule::SunNeverOccluded => "sun-never-occluded",
        }
    }
}

/// CPU rates the estimates use (core-nanoseconds), with where they come from.
///
/// Tiling and mipmaps cost a rate per stored pixel. The horizons (fast method) cost a sum of
/// four terms per azimuth, over the quantities [`super::cost::HorizonWork`] counts for each
/// tile: every interior pixel (degrees, the zero-distance slope, the Fourier sink's input),
/// every pixel with data (its exact near field and the exact search of the sweep's guesses),
/// every line sample the sweeps visit (the full-resolution context and the far rings: a tile's
/// context grows with the body's relief in pixels of its level, not with its pixel count), and
/// every pixel raised to a far ring.
#[derive(Clone, Debug, Serialize)]
pub struct Rates {
    /// Tiling, per stored height pixel (halo included), per source sampled.
    pub tile_ns_per_px: f64,
    /// Both mipmaps, per stored height pixel.
    pub mip_ns_per_px: f64,
    /// Horizons, per interior pixel and azimuth.
    pub horizon_ns_per_px_az: f64,
    /// Horizons, per interior pixel with data and azimuth.
    pub horizon_ns_per_data_px_az: f64,
    /// Horizons, per line sample swept (contexts and far rings) and azimuth.
    pub horizon_ns_per_sample_az: f64,
    /// Horizons, per interior pixel, far ring and azimuth.
    pub horizon_ns_per_ring_px_az: f64,
    /// Fourier encoding, per interior pixel and azimuth.
    pub fourier_ns_per_px_az: f64,
    pub source: &'static str,
}

impl Default for Rates {
    fn default() -> Self {
        Rates {
            tile_ns_per_px: 300.0,
            mip_ns_per_px: 100.0,
            horizon_ns_per_px_az: 20.0,
            horizon_ns_per_data_px_az: 400.0,
            horizon_ns_per_sample_az: 25.0,
            horizon_ns_per_ring_px_az: 43.0,
            fourier_ns_per_px_az: 6.0,
            source: "core-ns; horizons (fast method): each term's functions' share of a perf \
                     profile of a bake on this 2-core machine, 2026-12-05, over the quantities \
                     the plan counts: per line sample swept 18-37 (sweeps), per pixel with \
                     data 280-510 (near field, exact search: it varies with the terrain), per \
                     pixel raised to a far ring 43, per pixel 6-25; the rates are the middle \
                     of the ranges over the embedded, Shoemaker descent and equatorial scenes \
                     (docs/scenes.md, \"Plan against bake: CPU time\"); tiling and mipmaps \
                     from this machine's bakes",
        }
    }
}

impl Rates {
    /// Core-seconds of the horizons of `work` at `az` azimuths (fast method).
    pub fn horizon_core_s(&self, work: &HorizonWork, az: u64) -> f64 {
        (work.px * self.horizon_ns_per_px_az
            + work.data_px * self.horizon_ns_per_data_px_az
            + (work.context_samples + work.ring_samples) * self.horizon_ns_per_sample_az
            + work.ring_px * self.horizon_ns_per_ring_px_az)
            * az as f64
            * 1e-9
    }
}

/// Bytes on disk per byte before compression where no sample of tiles measures them
/// ([`sampled_tile_bytes`] does for heights and mipmaps when the plan has tiles): the larger of
/// those measured on the embedded scene's bake (smooth synthetic terrain: height 0.37, mip 0.25)
/// and the Shoemaker descent scene's (LDEM_4 tiles oversampled 2–4×, whose f32 mantissas are
/// noise to deflate: height 0.83, mip 0.79), 2026-12-05: an estimate from the safe side. The
/// Fourier pyramids are stored as they are (their size is exact).
const DISK_RATIO: [(Product, f64); 4] = [
    (Product::Height, 0.83),
    (Product::Mip, 0.79),
    // Raw horizon maps: not measured here (f16 maps of real terrain deflate little).
    (Product::Horizon, 0.9),
    (Product::Fourier, 1.0),
];

/// One product's part of the plan.
#[derive(Clone, Debug, Serialize)]
pub struct ProductPlan {
    pub product: &'static str,
    /// Whether the bake makes it, and why (the methods that read it, or "listed").
    pub made: bool,
    pub why: Vec<String>,
    /// Tiles per level it covers.
    pub tiles: BTreeMap<u8, u64>,
    /// Exact bytes before compression, and the estimate on disk.
    pub raw_bytes: u64,
    pub disk_bytes_est: u64,
    pub cpu_s_est: f64,
}

/// Tiles left out by one rule.
#[derive(Clone, Debug, Serialize)]
pub struct LeftOut {
    pub rule: Rule,
    pub what: String,
    /// Tiles per level.
    pub tiles: BTreeMap<u8, u64>,
    pub raw_bytes: u64,
    pub cpu_s_est: f64,
}

/// A scene's plan.
pub struct Plan {
    pub scene: Scene,
    pub body: Body,
    /// In priority order, highest first.
    pub sources: Vec<PlannedSource>,
    pub layout: Layout,
    /// Each region's finest level and tile count.
    pub regions: Vec<RegionReport>,
    /// The tiles to cut (closed under parent where their ancestors have data).
    pub tiles: BTreeSet<TileId>,
    /// The tiles are every tile the sources give at their own resolution (no region leaves
    /// any out): the tiling stage then needs no list of wanted tiles.
    pub whole: bool,
    /// The tiles the tiling stage tries (closed under parent): [`Plan::tiles`] and those of
    /// their ancestors without data, which it leaves unwritten.
    pub candidates: BTreeSet<TileId>,
    /// Levels that get horizons (or Fourier pyramids).
    pub horizon_levels: Vec<u8>,
    pub products: Vec<ProductPlan>,
    pub left_out: Vec<LeftOut>,
    /// The suns' lowest elevation (degrees, centre of the disc) over the scene's regions, and
    /// the sun's angular radius: horizons below `lowest − radius` cannot occlude any part.
    pub sun_lowest_deg: Option<f64>,
    pub sun_radius_deg: Option<f64>,
    /// Horizons are left out of tiles whose bound is below this (the lowest sun less its
    /// radius), when the scene gives its suns and prunes.
    pub lit_above_deg: Option<f64>,
    /// The tiles whose horizons are left out, when known (the plan was given a tileset holding
    /// this plan's heights and mipmaps); None: decided by the horizon stage after the mipmaps.
    pub pruned: Option<BTreeSet<TileId>>,
    pub rates: Rates,
    /// The horizon stage's work the estimate prices (per azimuth, over the horizon tiles).
    pub horizon_work: HorizonWork,
}

/// What `penumbra plan --json` prints.
#[derive(Serialize)]
pub struct PlanReport<'a> {
    pub scene: &'a str,
    pub file: String,
    pub body: &'a Body,
    pub layout: &'a Layout,
    pub sources: Vec<SourceReport>,
    pub regions: Vec<RegionReport>,
    pub stages: Vec<&'static str>,
    pub tiles: BTreeMap<u8, u64>,
    pub horizon_levels: &'a [u8],
    /// The Fourier pyramids' K, and the report it came from with `coefficients = "auto"`.
    pub fourier: &'a super::FourierSpec,
    pub products: &'a [ProductPlan],
    pub left_out: &'a [LeftOut],
    pub made: Totals,
    pub left_out_total: Totals,
    pub sun_lowest_deg: Option<f64>,
    pub sun_radius_deg: Option<f64>,
    pub lit_above_deg: Option<f64>,
    /// Horizon tiles left out by the sun rule: a count when known, null when the horizon stage
    /// decides after the mipmaps.
    pub pruned_tiles: Option<BTreeMap<u8, u64>>,
    pub rates: &'a Rates,
    pub horizon_work: &'a HorizonWork,
}

#[derive(Serialize)]
pub struct SourceReport {
    pub label: String,
    pub pixel_m: f64,
    pub native_level: u8,
    pub max_level: u8,
    pub feather_px: f64,
}

#[derive(Clone, Serialize)]
pub struct RegionReport {
    pub name: String,
    pub finest_level: u8,
    pub tiles: u64,
}

#[derive(Clone, Copy, Default, Serialize)]
pub struct Totals {
    pub tiles: u64,
    pub raw_bytes: u64,
    pub disk_bytes_est: u64,
    pub cpu_s_est: f64,
}

/// Plan `scene`.
pub fn plan(scene: &Scene) -> Result<Plan> {
    let file = scene.file.clone();
    if let Some(e) = &scene.fourier.auto_error {
        return Err(Error::invalid(&file, e.clone()));
    }
    let line_err = |line: usize, key: &str, msg: String| {
        Error::invalid(&file, format!("line {line}, key `{key}`: {msg}"))
    };

    // Sources: opened (headers, and mapped pixels), of one body.
    let mut opened = Vec::new();
    for (i, s) in scene.sources.iter().enumerate() {
        let (dem, label, embedded) = match &s.kind {
            SourceKind::File(p) => {
                let d = dem::open_as(p, s.format, crate::dem::DEFAULT_MAX_FILL_PX)
                    .map_err(|e| line_err(s.line, &format!("source[{i}].path"), e.to_string()))?;
                (d, p.display().to_string(), None)
            }
            SourceKind::Embedded(spec) => {
                let parts = crate::synthetic::generate(spec);
                let hash = crate::synthetic::content_hash(&parts);
                let label = format!("south-pole-scene-{}px-{}m", spec.size, spec.pixel_m);
                let d = Dem::new(parts, crate::dem::DEFAULT_MAX_FILL_PX)?;
                (
                    d,
                    format!("embedded:{label}"),
                    Some(crate::tiling::Embedded {
                        label,
                        blake3: hash,
                    }),
                )
            }
        };
        opened.push((i, s, dem, label, embedded));
    }
    let choice = BodyChoice {
        name: scene.body.clone(),
        radius_m: scene.radius_m,
    };
    let mut body: Option<(Body, usize)> = None;
    for (i, s, dem, label, _) in &opened {
        let b = body_for(dem, &choice)
            .map_err(|e| line_err(s.line, &format!("source[{i}]"), e.to_string()))?;
        match &body {
            None => body = Some((b, *i)),
            Some((b0, j)) if b0.name != b.name || b0.radius_m != b.radius_m => {
                return Err(line_err(
                    s.line,
                    &format!("source[{i}]"),
                    format!(
                        "{label} is a DEM of {} but source[{j}] is of {}: a scene's sources \
                         belong to one body",
                        b.name, b0.name
                    ),
                ));
            }
            Some(_) => {}
        }
    }
    let body = body.expect("a scene has a source").0;
    let radius = body.radius_m;

    let probe = Layout {
        projection: scene.projection,
        tile_size: scene.tile_size,
        halo: scene.halo,
        levels: MAX_LEVELS,
    };
    let extra_levels = scene.max_oversampling.log2().floor() as u8;
    let mut sources: Vec<PlannedSource> = opened
        .into_iter()
        .map(|(_, s, dem, label, embedded)| {
            let pixel_m = dem.pixel_size_m(radius);
            let native_level =
                Layout::levels_for(scene.projection, scene.tile_size, radius, pixel_m) - 1;
            let max_level = (native_level + extra_levels).min(MAX_LEVELS - 1);
            let reach = crate::tiling::footprint_tiles(&dem, &probe, max_level, radius);
            PlannedSource {
                label,
                dem,
                embedded,
                feather_px: s.feather_px,
                pixel_m,
                native_level,
                max_level,
                reach,
                line: s.line,
            }
        })
        .collect();
    // Priority: the scene's, then finer first; ties keep the file's order.
    let prio: Vec<(i64, f64)> = scene
        .sources
        .iter()
        .zip(&sources)
        .map(|(s, p)| (s.priority.unwrap_or(0), p.pixel_m))
        .collect();
    let mut order: Vec<usize> = (0..sources.len()).collect();
    order.sort_by(|&a, &b| {
        prio[b]
            .0
            .cmp(&prio[a].0)
            .then(prio[a].1.total_cmp(&prio[b].1))
            .then(a.cmp(&b))
    });
    let mut taken: Vec<Option<PlannedSource>> = sources.drain(..).map(Some).collect();
    let sources: Vec<PlannedSource> = order
        .iter()
        .map(|&i| taken[i].take().expect("each once"))
        .collect();

    // Tiles: per region, every level up to its finest, where a source resolves the level.
    let native: BTreeSet<TileId> = sources
        .iter()
        .flat_map(|s| s.reach.iter().filter(move |t| t.level <= s.native_level))
        .copied()
        .collect();
    let mut wanted = BTreeSet::new();
    let mut finer_than_region = BTreeSet::new();
    let mut oversampled: BTreeMap<u8, u64> = BTreeMap::new();
    let mut region_reports = Vec::new();
    for (i, r) in scene.regions.iter().enumerate() {
        let (tiles, finest) = region_tiles(scene, r, i, &sources, &probe, radius)?;
        // Regions may overlap: the largest count per level.
        for (l, n) in &tiles.over {
            let e = oversampled.entry(*l).or_insert(0);
            *e = (*e).max(*n);
        }
        region_reports.push(RegionReport {
            name: r.name.clone(),
            finest_level: finest,
            tiles: tiles.keep.len() as u64,
        });
        wanted.extend(tiles.keep);
        finer_than_region.extend(tiles.finer);
    }
    // Close under parent among tiles that a source reaches (a tile's ancestors carry it at
    // coarser levels; they are in a region too, the region being the same area).
    let mut closed = wanted.clone();
    for t in &wanted {
        let mut c = t.parent();
        while let Some(p) = c {
            if !closed.insert(p) {
                break;
            }
            c = p.parent();
        }
    }
    let wanted = closed;

    // Which wanted tiles have data: the tiling stage writes only those.
    // The prefilter of a level depends on the level count: that of the wanted tiles (and
    // again if the finest of them have no data).
    let mut levels = wanted.iter().map(|t| t.level + 1).max().unwrap_or(1);
    let (present, no_data) = loop {
        let lay = Layout { levels, ..probe };
        let (p, n) = with_data(&sources, &lay, &wanted);
        let got = p.iter().map(|t| t.level + 1).max().unwrap_or(levels);
        if got == levels || p.is_empty() {
            break (p, n);
        }
        levels = got;
    };
    let levels = present.iter().map(|t| t.level + 1).max().ok_or_else(|| {
        Error::invalid(
            &file,
            "no tile of any region falls on a source's data: check the regions against the \
             sources' footprints",
        )
    })?;
    let layout = Layout { levels, ..probe };

    // Left out by region: what the sources alone would give (each at its own resolution),
    // less what the regions keep.
    let finer_than_region: BTreeSet<TileId> = finer_than_region
        .intersection(&native)
        .filter(|t| !present.contains(t))
        .copied()
        .collect();
    let outside: BTreeSet<TileId> = native
        .iter()
        .filter(|t| !present.contains(t) && !finer_than_region.contains(t) && !no_data.contains(t))
        .copied()
        .collect();

    // Products.
    let mut needed: BTreeMap<Product, Vec<String>> = BTreeMap::new();
    for m in &scene.methods {
        for p in m.reads() {
            needed
                .entry(*p)
                .or_default()
                .push(format!("read by {}", m.name()));
        }
    }
    for p in &scene.products {
        needed.entry(*p).or_default().push("listed".into());
    }
    needed
        .entry(Product::Height)
        .or_default()
        .push("every product is made from the heights".into());
    if scene.albedo.is_some() {
        needed
            .entry(Product::Albedo)
            .or_default()
            .push("the scene gives an albedo source".into());
    }
    let horizon_levels: Vec<u8> = match &scene.horizon.levels {
        Some(l) => {
            for &x in l {
                if x >= levels {
                    return Err(Error::invalid(
                        &file,
                        format!(
                            "key `horizon.levels`: level {x} is past the scene's finest level \
                             {}",
                            levels - 1
                        ),
                    ));
                }
            }
            l.clone()
        }
        None => (0..levels).collect(),
    };
    let horizon_tiles: BTreeSet<TileId> = present
        .iter()
        .filter(|t| horizon_levels.contains(&t.level))
        .copied()
        .collect();
    let (sun_lowest_deg, sun_radius_deg) = sun_limits(scene, &body, &horizon_tiles, &layout)?;
    let wants_horizons =
        needed.contains_key(&Product::Horizon) || needed.contains_key(&Product::Fourier);
    let lit_above_deg = match (sun_lowest_deg, sun_radius_deg) {
        (Some(lo), Some(r)) if scene.horizon.prune && wants_horizons => Some(lo - r),
        _ => None,
    };
    if scene.fourier.keep_raw && needed.contains_key(&Product::Fourier) {
        needed
            .entry(Product::Horizon)
            .or_default()
            .push("kept beside the Fourier pyramids (fourier.keep_raw)".into());
    }
    if lit_above_deg.is_some() {
        needed
            .entry(Product::Mip)
            .or_default()
            .push("read by the horizon prune bound".into());
    }

    let rates = Rates::default();
    // The horizon stage's work over the horizon tiles, counted as it lays out its rasters.
    let work = if wants_horizons {
        let shifted: Vec<(&Dem, f64)> = sources
            .iter()
            .map(|s| (&s.dem, s.dem.datum_radius_m().map_or(0.0, |r0| r0 - radius)))
            .collect();
        let defaults = crate::horizon::HorizonOptions::default();
        let inputs = WorkInputs {
            layout: &layout,
            radius_m: radius,
            range: cost::terrain_range(&shifted).unwrap_or(body.relief_m),
            sources: shifted,
            fine_margin_px: crate::horizon::default_fine_margin_px(layout.tile_size),
            max_margin_px: defaults.max_margin_px,
            far_rings: scene.horizon.method.sees_far_rings(),
        };
        cost::horizon_work(&inputs, &horizon_tiles, &present)
    } else {
        HorizonWork::default()
    };
    let side = layout.stored_size() as u64;
    let n = layout.tile_size as u64;
    let az = scene.horizon.azimuths as u64;
    let per_level = |set: &BTreeSet<TileId>, f: &dyn Fn(&TileId) -> bool| {
        let mut m = BTreeMap::new();
        for t in set.iter().filter(|t| f(t)) {
            *m.entry(t.level).or_insert(0u64) += 1;
        }
        m
    };
    let count = |m: &BTreeMap<u8, u64>| m.values().sum::<u64>();
    // Heights and mipmaps on disk: a sample of the tiles rendered and encoded as the bake
    // does, their mean size per tile; the measured ratios where there is no sample.
    let sampled = sampled_tile_bytes(&sources, &layout, &present);
    let disk = |p: Product, raw: u64, tiles: u64| {
        let per_tile = match (p, sampled) {
            (Product::Height, Some((h, _))) => Some(h),
            (Product::Mip, Some((_, m))) => Some(m),
            _ => None,
        };
        if let Some(b) = per_tile {
            return (tiles as f64 * b).round() as u64;
        }
        let r = DISK_RATIO
            .iter()
            .find(|(q, _)| *q == p)
            .map_or(1.0, |(_, r)| *r);
        (raw as f64 * r) as u64
    };
    let horizon_tile_s = if work.tiles > 0.0 {
        rates.horizon_core_s(&work, az) / work.tiles
    } else {
        let px = (n * n) as f64;
        let fine = crate::horizon::default_fine_margin_px(layout.tile_size) as i64;
        let nn = n as i64;
        let one = HorizonWork {
            tiles: 1.0,
            px,
            data_px: px,
            context_samples: cost::line_samples(
                (-fine, -fine, nn + fine, nn + fine),
                (0, 0, nn, nn),
            ),
            ..Default::default()
        };
        rates.horizon_core_s(&one, az)
    };
    // Raw bytes and core-seconds per tile of each product.
    let k = scene.fourier.coefficients as u64;
    let cost = |p: Product| -> (u64, f64) {
        match p {
            // f32 heights and a u8 mask per stored pixel.
            Product::Height => (
                side * side * 5,
                side as f64 * side as f64 * rates.tile_ns_per_px * 1e-9,
            ),
            Product::Albedo => (side * side * 3, 0.0),
            // The maximum (f32) and (min, max) (2 × f32) pyramids, 4/3 for their levels.
            Product::Mip => (
                side * side * 12 * 4 / 3,
                side as f64 * side as f64 * rates.mip_ns_per_px * 1e-9,
            ),
            // f16 per pixel and azimuth.
            // The mean of the horizon tiles' work (a tile of the same size with data in
            // every pixel and no far rings where there are none).
            Product::Horizon => (n * n * az * 2, horizon_tile_s),
            // The multires pyramid: 4/3 · K bytes per pixel (K f16 coefficients, reduced
            // groups), measured 21.27 B/px at K = 16 against 21.33.
            Product::Fourier => (
                n * n * k * 4 / 3,
                (n * n * az) as f64 * rates.fourier_ns_per_px_az * 1e-9,
            ),
            Product::Other(_) => (0, 0.0),
        }
    };
    let horizon_set = horizon_tiles;
    let mut products = Vec::new();
    let mut left_out = Vec::new();
    for p in [
        Product::Height,
        Product::Albedo,
        Product::Mip,
        Product::Horizon,
        Product::Fourier,
    ] {
        let set = match p {
            Product::Horizon | Product::Fourier => &horizon_set,
            _ => &present,
        };
        let tiles = per_level(set, &|_| true);
        let (raw1, cpu1) = cost(p);
        let mut cpu = count(&tiles) as f64 * cpu1;
        // Streamed Fourier pyramids pay the horizons too; raw maps kept beside them cost
        // their bytes only.
        if p == Product::Fourier {
            cpu += count(&tiles) as f64 * cost(Product::Horizon).1;
        }
        let raw = count(&tiles) * raw1;
        match needed.get(&p) {
            Some(why) => {
                let made = true;
                products.push(ProductPlan {
                    product: p.name(),
                    made,
                    why: why.clone(),
                    disk_bytes_est: disk(p, raw, count(&tiles)),
                    tiles,
                    raw_bytes: raw,
                    cpu_s_est: if p == Product::Horizon && needed.contains_key(&Product::Fourier) {
                        0.0
                    } else {
                        cpu
                    },
                });
            }
            None if p == Product::Albedo => {}
            None if p == Product::Horizon && wants_horizons => {
                // Streamed into the Fourier encoder, not stored.
                left_out.push(LeftOut {
                    rule: Rule::NotRead,
                    what: "raw horizon maps (streamed into the Fourier pyramids, not stored)"
                        .into(),
                    tiles,
                    raw_bytes: raw,
                    cpu_s_est: 0.0,
                });
            }
            None => left_out.push(LeftOut {
                rule: Rule::NotRead,
                what: format!("{} (no listed method reads it)", p.name()),
                tiles,
                raw_bytes: raw,
                cpu_s_est: cpu,
            }),
        }
    }
    // What a tile left out would have cost: its heights and every product made of it (the
    // horizons and pyramids at the horizon levels only).
    let made_products: Vec<Product> = products
        .iter()
        .filter(|p| p.made)
        .filter_map(|p| {
            PRODUCTS
                .iter()
                .find(|(n, _)| *n == p.product)
                .map(|(_, q)| *q)
        })
        .collect();
    let height_cost = |set: &BTreeSet<TileId>| {
        let (mut raw, mut cpu) = (0u64, 0.0f64);
        for t in set {
            for &p in &made_products {
                if matches!(p, Product::Horizon | Product::Fourier)
                    && !horizon_levels.contains(&t.level)
                {
                    continue;
                }
                let (r, c) = cost(p);
                raw += r;
                cpu += c + if p == Product::Fourier {
                    cost(Product::Horizon).1
                } else {
                    0.0
                };
            }
        }
        (raw, cpu)
    };
    for (rule, what, set) in [
        (
            Rule::OutsideRegions,
            "tiles the sources cover at their own resolution outside every region",
            &outside,
        ),
        (
            Rule::FinerThanRegion,
            "tiles in a region finer than its level",
            &finer_than_region,
        ),
        (
            Rule::NoData,
            "tiles of a region with no source data in their interior",
            &no_data,
        ),
    ] {
        if set.is_empty() {
            continue;
        }
        let (raw, cpu) = height_cost(set);
        left_out.push(LeftOut {
            rule,
            what: what.into(),
            tiles: per_level(set, &|_| true),
            raw_bytes: raw,
            cpu_s_est: cpu,
        });
    }

    let whole = outside.is_empty()
        && finer_than_region.is_empty()
        && present.iter().all(|t| native.contains(t));
    if !oversampled.is_empty() {
        // Per level: a tile's heights and products, times the count.
        let (mut raw, mut cpu) = (0u64, 0.0f64);
        for (&level, &n) in &oversampled {
            let one = TileId {
                level,
                face: cube::Face::Px,
                x: 0,
                y: 0,
            };
            let (r, c) = height_cost(&BTreeSet::from([one]));
            raw = raw.saturating_add(n.saturating_mul(r));
            cpu += n as f64 * c;
        }
        left_out.push(LeftOut {
            rule: Rule::Oversampled,
            what: "tiles of a region finer than any source there resolves within \
                   max_oversampling (counted from the sources' deepest tiles in it)"
                .into(),
            tiles: oversampled,
            raw_bytes: raw,
            cpu_s_est: cpu,
        });
    }
    Ok(Plan {
        scene: scene.clone(),
        body,
        sources,
        layout,
        regions: region_reports,
        whole,
        candidates: wanted
            .iter()
            .filter(|t| t.level < levels)
            .copied()
            .collect(),
        tiles: present,
        horizon_levels,
        products,
        left_out,
        sun_lowest_deg,
        sun_radius_deg,
        lit_above_deg,
        pruned: None,
        rates,
        horizon_work: work,
    })
}

/// Decide the sun rule's tiles on `dir`, a tileset holding `plan`'s heights and mipmaps (a
/// bake of the plan's tiling and mip stages), with the horizon stage's own decision: the
/// horizon and Fourier tiles, bytes and time then count only the tiles that will be computed,
/// and the rule's tiles are listed as left out.
pub fn decide_pruning(plan: &mut Plan, dir: &Path) -> Result<()> {
    let Some(t) = plan.lit_above_deg else {
        return Ok(());
    };
    let store = crate::tileset::Store::open(dir)?;
    let opts = plan.horizon_options();
    let pruned: BTreeSet<TileId> = crate::horizon::prune_candidates_with(&store, &opts)?
        .into_iter()
        .map(|(id, _)| id)
        .collect();
    let mut tiles = BTreeMap::new();
    for id in &pruned {
        *tiles.entry(id.level).or_insert(0u64) += 1;
    }
    let n = pruned.len() as u64;
    let mut freed = (0u64, 0.0f64);
    for p in plan.products.iter_mut() {
        if p.product != "horizon" && p.product != "fourier" {
            continue;
        }
        let total: u64 = p.tiles.values().sum();
        if total == 0 {
            continue;
        }
        // Raw maps are not written for a left-out tile; its Fourier file is the small
        // fully-lit record.
        let keep = (total - n.min(total)) as f64 / total as f64;
        if p.product == "horizon" {
            for (l, c) in &tiles {
                if let Some(v) = p.tiles.get_mut(l) {
                    *v -= (*c).min(*v);
                }
            }
        }
        let cpu = p.cpu_s_est * (1.0 - keep);
        freed = (
            freed
                .0
                .max(p.raw_bytes - (p.raw_bytes as f64 * keep) as u64),
            freed.1 + cpu,
        );
        p.raw_bytes = (p.raw_bytes as f64 * keep) as u64;
        p.disk_bytes_est = (p.disk_bytes_est as f64 * keep) as u64;
        p.cpu_s_est *= keep;
    }
    plan.left_out.push(LeftOut {
        rule: Rule::SunNeverOccluded,
        what: format!(
            "horizons of tiles whose horizon stays below {t:.2}° (the lowest sun less its \
             radius): recorded fully lit"
        ),
        tiles,
        raw_bytes: freed.0,
        cpu_s_est: freed.1,
    });
    plan.pruned = Some(pruned);
    Ok(())
}

impl Plan {
    /// The stages the bake runs, in order.
    pub fn stages(&self) -> Vec<&'static str> {
        let made = |name: &str| self.products.iter().any(|p| p.product == name);
        let mut s = vec!["tile"];
        if made("mip") {
            s.push("mip");
        }
        if made("horizon") || made("fourier") {
            s.push(if made("fourier") {
                "horizon → fourier"
            } else {
                "horizon"
            });
        }
        s
    }

    /// The tiles the tiling stage is to try, or None for all it finds ([`Plan::whole`]).
    pub fn wanted(&self) -> Option<&BTreeSet<TileId>> {
        (!self.whole).then_some(&self.candidates)
    }

    /// The horizon stage's options: the plan's levels, the scene's azimuths and method, the
    /// sun threshold.
    pub fn horizon_options(&self) -> crate::horizon::HorizonOptions {
        let sc = &self.scene;
        crate::horizon::HorizonOptions {
            levels: Some(self.horizon_levels.clone()),
            azimuths: sc.horizon.azimuths,
            method: sc.horizon.method,
            lit_above_deg: self.lit_above_deg,
            ..Default::default()
        }
    }

    /// Whether the bake makes `p`.
    pub fn makes(&self, p: Product) -> bool {
        self.products
            .iter()
            .any(|q| q.product == p.name() && q.made)
    }

    pub fn report(&self) -> PlanReport<'_> {
        let made = Totals {
            tiles: self.tiles.len() as u64,
            raw_bytes: self
                .products
                .iter()
                .filter(|p| p.made)
                .map(|p| p.raw_bytes)
                .sum(),
            disk_bytes_est: self
                .products
                .iter()
                .filter(|p| p.made)
                .map(|p| p.disk_bytes_est)
                .sum(),
            cpu_s_est: self.products.iter().map(|p| p.cpu_s_est).sum(),
        };
        let left = Totals {
            tiles: self
                .left_out
                .iter()
                .filter(|l| l.rule != Rule::NotRead)
                .map(|l| l.tiles.values().sum::<u64>())
                .sum(),
            raw_bytes: self.left_out.iter().map(|l| l.raw_bytes).sum(),
            disk_bytes_est: 0,
            cpu_s_est: self.left_out.iter().map(|l| l.cpu_s_est).sum(),
        };
        let mut tiles = BTreeMap::new();
        for t in &self.tiles {
            *tiles.entry(t.level).or_insert(0) += 1;
        }
        PlanReport {
            scene: &self.scene.name,
            file: self.scene.file.display().to_string(),
            body: &self.body,
            layout: &self.layout,
            sources: self
                .sources
                .iter()
                .map(|s| SourceReport {
                    label: s.label.clone(),
                    pixel_m: s.pixel_m,
                    native_level: s.native_level,
                    max_level: s.max_level,
                    feather_px: s.feather_px,
                })
                .collect(),
            regions: self.regions.clone(),
            stages: self.stages(),
            tiles,
            horizon_levels: &self.horizon_levels,
            fourier: &self.scene.fourier,
            products: &self.products,
            left_out: &self.left_out,
            made,
            left_out_total: left,
            sun_lowest_deg: self.sun_lowest_deg,
            sun_radius_deg: self.sun_radius_deg,
            lit_above_deg: self.lit_above_deg,
            pruned_tiles: self.pruned.as_ref().map(|p| {
                let mut m = BTreeMap::new();
                for t in p {
                    *m.entry(t.level).or_insert(0) += 1;
                }
                m
            }),
            rates: &self.rates,
            horizon_work: &self.horizon_work,
        }
    }
}

struct RegionTiles {
    /// Tiles to make.
    keep: BTreeSet<TileId>,
    /// Tiles of the region finer than it asks (at levels a source resolves).
    finer: BTreeSet<TileId>,
    /// Per level, tiles of the region at its levels that no source resolves within the limit
    /// (counted, not listed: a whole-body region at a fine level has millions). Exact for one
    /// source; with several, the largest of the sources' counts.
    over: BTreeMap<u8, u64>,
}

/// A region's tiles, and its finest level.
fn region_tiles(
    scene: &Scene,
    r: &RegionSpec,
    i: usize,
    sources: &[PlannedSource],
    probe: &Layout,
    radius: f64,
) -> Result<(RegionTiles, u8)> {
    let err = |key: &str, msg: String| {
        Error::invalid(
            &scene.file,
            format!("line {}, key `region[{i}].{key}`: {msg}", r.line),
        )
    };
    let top = sources.iter().map(|s| s.max_level).max().unwrap_or(0);
    let native_top = sources.iter().map(|s| s.native_level).max().unwrap_or(0);
    let finest = match r.finest {
        Finest::Level(l) => l,
        Finest::ResolutionM(m) => {
            let mut l = 0u8;
            while l + 1 < MAX_LEVELS && probe.centre_pixel_m(l, radius) > m * 1.0001 {
                l += 1;
            }
            l
        }
        Finest::Source => native_top,
    };
    // A source resolves a level natively for `Finest::Source`, within the oversampling limit
    // otherwise.
    let limit = |s: &PlannedSource| match r.finest {
        Finest::Source => s.native_level,
        _ => s.max_level,
    };
    // The region's tiles at each level (a camera path's come from the LOD rule, all levels at
    // once); None: the whole body.
    let path_tiles: Option<BTreeSet<TileId>> = match &r.shape {
        RegionShape::Path {
            file,
            frame_px,
            fov_deg,
            texel_px,
        } => {
            let pts = region::read_path_csv(file).map_err(|e| {
                Error::invalid(
                    &scene.file,
                    format!(
                        "line {}, key `region[{i}].path`: the camera path of region '{}': {e}",
                        r.line, r.name
                    ),
                )
            })?;
            let lay = Layout {
                levels: finest + 1,
                ..*probe
            };
            let relief = crate::body::Body::preset(&scene_body_name(scene))
                .map(|b| b.relief_m)
                .unwrap_or((-10_000.0, 10_000.0));
            let view = region::PathView {
                frame: *frame_px,
                fov_deg: *fov_deg,
                max_texel_px: *texel_px,
                max_level: finest,
            };
            Some(region::path_tiles(&pts, &lay, radius, relief, &view, None)?)
        }
        _ => None,
    };
    let in_shape = |level: u8| -> Result<Option<BTreeSet<TileId>>> {
        Ok(match (&r.shape, &path_tiles) {
            (RegionShape::Body, _) => None,
            (_, Some(all)) => Some(all.iter().filter(|t| t.level == level).copied().collect()),
            (other, None) => Some(
                region::tiles_touching(&shape_of(other), probe, radius, level)
                    .map_err(|e| err("name", e.to_string()))?,
            ),
        })
    };
    let mut keep = BTreeSet::new();
    let mut over = BTreeMap::new();
    let mut finer = BTreeSet::new();
    // Per source, its tiles at its deepest level inside the region (the frontier whose
    // descendants it would oversample).
    let mut frontier: Vec<u64> = vec![0; sources.len()];
    for level in 0..=finest.max(top) {
        let shape = in_shape(level)?;
        let meets = |t: &TileId| shape.as_ref().is_none_or(|s| s.contains(t));
        let reached: BTreeSet<TileId> = sources
            .iter()
            .flat_map(|s| s.reach.range(level_range(level)))
            .filter(|t| meets(t))
            .copied()
            .collect();
        for (k, s) in sources.iter().enumerate() {
            if level == s.max_level {
                frontier[k] = s
                    .reach
                    .range(level_range(level))
                    .filter(|t| meets(t))
                    .count() as u64;
            }
        }
        if level > finest {
            finer.extend(reached);
            continue;
        }
        let mut kept = 0u64;
        for t in reached {
            if sources
                .iter()
                .any(|s| t.level <= limit(s) && s.reach.contains(&t))
            {
                keep.insert(t);
                kept += 1;
            }
        }
        // Tiles of the region below a source's resolution limit: counted where the region's
        // tiles are listed, else (the whole body) the frontier's descendants.
        if let Some(set) = &shape {
            let n = set
                .iter()
                .filter(|t| {
                    !keep.contains(t)
                        && sources
                            .iter()
                            .any(|s| t.level > limit(s) && ancestor_in(&s.reach, **t))
                })
                .count() as u64;
            if n > 0 {
                over.insert(level, n);
            }
            continue;
        }
        let beyond = sources
            .iter()
            .zip(&frontier)
            .filter(|(s, _)| level > limit(s))
            .map(|(s, f)| f.saturating_mul(1u64 << (2 * u32::from(level - limit(s)).min(31))))
            .max()
            .unwrap_or(0);
        if beyond > kept {
            over.insert(level, beyond - kept);
        }
    }
    if keep.is_empty() && over.is_empty() && finer.is_empty() {
        return Err(err(
            "name",
            format!(
                "region '{}' is outside every source: no tile of it meets a source's footprint",
                r.name
            ),
        ));
    }
    if !keep.iter().any(|t| t.level == finest) {
        // The finest level a source resolves within the region (not the finest any source
        // resolves anywhere).
        let top = keep.iter().map(|t| t.level).max().unwrap_or(0);
        if let Finest::Level(_) | Finest::ResolutionM(_) = r.finest {
            return Err(err(
                match r.finest {
                    Finest::Level(_) => "level",
                    _ => "resolution_m",
                },
                format!(
                    "level {finest} is finer than any source covering region '{}' resolves: \
                     the finest there is level {top} with max_oversampling {} \
                     (scene.max_oversampling raises it, up to 64)",
                    r.name, scene.max_oversampling
                ),
            ));
        }
    }
    Ok((RegionTiles { keep, finer, over }, finest))
}

/// The range of tile ids at `level` in a set ordered as [`TileId`]'s `Ord` (level first).
fn level_range(level: u8) -> std::ops::RangeInclusive<TileId> {
    let lo = TileId {
        level,
        face: cube::Face::ALL[0],
        x: 0,
        y: 0,
    };
    let hi = TileId {
        level,
        face: cube::Face::ALL[5],
        x: u32::MAX,
        y: u32::MAX,
    };
    lo..=hi
}

fn ancestor_in(set: &BTreeSet<TileId>, t: TileId) -> bool {
    let mut c = t.parent();
    while let Some(p) = c {
        if set.contains(&p) {
            return true;
        }
        c = p.parent();
    }
    false
}

fn scene_body_name(scene: &Scene) -> String {
    scene.body.clone().unwrap_or_else(|| "moon".into())
}

/// The region module's shape of a scene region (not a camera path).
fn shape_of(s: &RegionShape) -> region::Shape {
    match s {
        RegionShape::Body => region::Shape::Body,
        RegionShape::Box { lat, lon } => region::Shape::LatLonBox {
            lat: *lat,
            lon: *lon,
        },
        RegionShape::Cap {
            lat_deg,
            lon_deg,
            radius_m,
        } => region::Shape::Cap {
            lat_deg: *lat_deg,
            lon_deg: *lon_deg,
            radius_m: *radius_m,
        },
        RegionShape::Polygon(v) => region::Shape::Polygon {
            vertices: v.clone(),
        },
        RegionShape::Path { .. } => unreachable!("camera paths are walked by the LOD rule"),
    }
}

/// Most tiles [`sampled_tile_bytes`] renders and encodes.
const SAMPLE_TILES: usize = 8;

/// The mean bytes on disk of a height tile and of a tile's two mipmap files (maximum, and
/// minimum and maximum), measured on up to [`SAMPLE_TILES`] of `tiles` evenly spread over
/// them (coarse to fine), each rendered from the first source with data there as the tiling
/// stage renders it and encoded as the stages write it (default compression and precision).
/// None for no tiles.
fn sampled_tile_bytes(
    sources: &[PlannedSource],
    layout: &Layout,
    tiles: &BTreeSet<TileId>,
) -> Option<(f64, f64)> {
    use crate::format::{height, mip as mipfmt, Identity};
    if tiles.is_empty() {
        return None;
    }
    let all: Vec<TileId> = tiles.iter().copied().collect();
    let step = all.len().div_ceil(SAMPLE_TILES).max(1);
    let picked: Vec<TileId> = all.iter().copied().step_by(step).collect();
    let (h, n, s) = (
        layout.halo as usize,
        layout.tile_size as usize,
        layout.stored_size(),
    );
    let key = "0".repeat(64);
    let mip = crate::mip::MipOptions::default();
    let sizes: Vec<(f64, f64)> = picked
        .par_iter()
        .filter_map(|&id| {
            let tile = sources.iter().find_map(|src| {
                let t = crate::tiling::render_height_tile(
                    &src.dem,
                    layout,
                    id,
                    dem::Resampling::Bilinear,
                    crate::tiling::Prefilter::Box,
                    0.0,
                );
                (h..h + n)
                    .any(|j| {
                        t.mask[j * s + h..j * s + h + n]
                            .iter()
                            .any(|&m| m != mask::NO_DATA)
                    })
                    .then_some(t)
            })?;
            let hb = height::encode_height_tile_stored(
                &tile,
                crate::format::TileCompression::Zip,
                Some(&Identity::tile(height::ID, id, &key)),
            )
            .ok()?;
            let p = crate::mip::minmax_pyramid(&tile.height, s, h).ok()?;
            let mut mb = 0usize;
            for (min, name, what) in [
                (None, "penumbra-maxmip", mipfmt::MAX_ID),
                (Some(&p.min[..]), "penumbra-minmax", mipfmt::MINMAX_ID),
            ] {
                mb += mipfmt::encode_mip_exr_stored(
                    n,
                    min,
                    &p.max,
                    mip.precision,
                    mip.compression,
                    name,
                    Some(&Identity::tile(what, id, &key)),
                )
                .ok()?
                .len();
            }
            Some((hb.len() as f64, mb as f64))
        })
        .collect();
    if sizes.is_empty() {
        return None;
    }
    let k = sizes.len() as f64;
    Some((
        sizes.iter().map(|x| x.0).sum::<f64>() / k,
        sizes.iter().map(|x| x.1).sum::<f64>() / k,
    ))
}

/// Split `wanted` into the tiles with data in their interior on some source (the tiling stage
/// writes only those) and the rest. A tile is checked on its interior pixel centres every
/// `STRIDE` pixels and on every pixel of its interior's outline: data that reaches a tile
/// crosses its outline unless it lies wholly inside, where the grid finds it unless it spans
/// fewer than `STRIDE` pixels.
fn with_data(
    sources: &[PlannedSource],
    probe: &Layout,
    wanted: &BTreeSet<TileId>,
) -> (BTreeSet<TileId>, BTreeSet<TileId>) {
    const STRIDE: i64 = 8;
    let n = probe.tile_size as i64;
    let ids: Vec<TileId> = wanted.iter().copied().collect();
    let has: Vec<bool> = ids
        .par_iter()
        .map(|&id| {
            let srcs: Vec<&PlannedSource> = sources
                .iter()
                .filter(|s| s.reach.contains(&id) || ancestor_in(&s.reach, id))
                .collect();
            if crate::tiling::box_samples(probe, id.level, crate::tiling::Prefilter::Box) > 1 {
                // A prefiltered level: a pixel has data when any of its box's samples does;
                // render the tile as the tiling stage does.
                let (h, n) = (probe.halo as usize, probe.tile_size as usize);
                return srcs.iter().any(|s| {
                    let t = crate::tiling::render_height_tile(
                        &s.dem,
                        probe,
                        id,
                        crate::dem::Resampling::Bilinear,
                        crate::tiling::Prefilter::Box,
                        0.0,
                    );
                    (h..h + n).any(|j| {
                        t.mask[j * t.size + h..j * t.size + h + n]
                            .iter()
                            .any(|&m| m != mask::NO_DATA)
                    })
                });
            }
            let hit = |i: i64, j: i64| {
                let d = probe.pixel_dir(id, i, j);
                srcs.iter().any(|s| {
                    s.dem.sample_dir(d, crate::dem::Resampling::Bilinear).1 != mask::NO_DATA
                })
            };
            (0..n)
                .step_by(STRIDE as usize)
                .any(|j| (0..n).step_by(STRIDE as usize).any(|i| hit(i, j)))
                || (0..n).any(|k| hit(k, 0) || hit(k, n - 1) || hit(0, k) || hit(n - 1, k))
        })
        .collect();
    let mut yes = BTreeSet::new();
    let mut no = BTreeSet::new();
    for (id, h) in ids.into_iter().zip(has) {
        if h {
            yes.insert(id);
        } else {
            no.insert(id);
        }
    }
    (yes, no)
}

/// The lowest sun elevation the scene sees over its tiles (degrees, disc centre) and the sun's
/// angular radius (its largest), when the scene says which suns it sees. For a time span: the
/// lowest elevation over the span at 16 points along each edge of every tile, less the tile's
/// angular radius. For one sun, elevation is asin(up · s), smallest over a tile on its outline
/// unless the anti-solar point lies inside, where it is −90° and the outline is within the
/// tile's radius of it; the sampled outline points are within the radius too, so the result
/// is a lower bound.
fn sun_limits(
    scene: &Scene,
    body: &Body,
    tiles: &BTreeSet<TileId>,
    layout: &Layout,
) -> Result<(Option<f64>, Option<f64>)> {
    let radius_for = |d: Option<f64>| -> Result<Option<f64>> {
        Ok(match d {
            Some(au) => Some(crate::fourier::sun::sun_radius_deg(au)),
            None => match crate::ephemeris::sun_radius_bound_deg(&body.name) {
                Ok(r) => Some(r),
                Err(_) => crate::fourier::sun::sun_distance_au(&body.name)
                    .map(crate::fourier::sun::sun_radius_deg),
            },
        })
    };
    match &scene.sun {
        None => Ok((None, None)),
        Some(SunSpec::Range {
            elevation_deg,
            distance_au,
            ..
        }) => Ok((Some(elevation_deg.0), radius_for(*distance_au)?)),
        Some(SunSpec::Span {
            start,
            end,
            distance_au,
            line,
        }) => {
            let err =
                |e: Error| Error::invalid(&scene.file, format!("line {line}, key `sun`: {e}"));
            let spec = crate::ephemeris::SunSpec::Span {
                body: body.name.clone(),
                start_utc: start.clone(),
                end_utc: end.clone(),
            };
            let path = crate::ephemeris::SunPath::from_spec(&spec, None)
                .map_err(err)?
                .expect("a span");
            const PER_EDGE: i64 = 16;
            let n = layout.tile_size as i64;
            let mut lowest = f64::INFINITY;
            for &id in tiles {
                // The tile's angular radius: its corners' largest angle from its centre.
                let c = layout.pixel_dir(id, n / 2, n / 2);
                let rad = [(0, 0), (n - 1, 0), (0, n - 1), (n - 1, n - 1)]
                    .iter()
                    .map(|&(i, j)| cube::angle_between(c, layout.pixel_dir(id, i, j)))
                    .fold(0.0f64, f64::max)
                    .to_degrees();
                for k in 0..=PER_EDGE {
                    let e = k * (n - 1) / PER_EDGE;
                    for (i, j) in [(e, 0), (e, n - 1), (0, e), (n - 1, e)] {
                        let (la, lo) = cube::dir_to_latlon(layout.pixel_dir(id, i, j));
                        let (lo_el, _) = path.range_at(la.to_degrees(), lo.to_degrees());
                        lowest = lowest.min(lo_el - rad);
                    }
                }
            }
            let r = match distance_au {
                Some(au) => Some(crate::fourier::sun::sun_radius_deg(*au)),
                None => Some(path.sun_radius_deg().1),
            };
            Ok((lowest.is_finite().then_some(lowest.max(-90.0)), r))
        }
    }
}

/// Read and plan the scene file at `path`.
pub fn plan_file(path: &Path) -> Result<Plan> {
    plan(&super::load(path)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::cost::terrain_range;

    /// A scene of the embedded terrain (512² px at 20 m around the south pole, which lies at
    /// the corner of four tiles of every level) with horizons at `level`.
    fn small_plan(level: u8) -> Plan {
        let text = format!(
            "[scene]\nname = \"t\"\nbody = \"moon\"\n\n[layout]\ntile_size = 128\n\n\
             [[source]]\nembedded = \"south-pole\"\nsize = 512\n\n[[region]]\nname = \"all\"\n\
             body = true\n\n[renderer]\nmethods = [\"dp\", \"fourier\"]\n\n[horizon]\n\
             levels = [{level}]\nazimuths = 16\n"
        );
        let scene = crate::scene::parse(&text, Path::new("t.toml")).unwrap();
        plan(&scene).unwrap()
    }

    #[test]
    fn data_pixels_are_the_sources_footprint() {
        // Level 9's centre pixel is 53 m: the 10.24 km terrain covers about 193² pixels of the
        // four tiles around the pole.
        let plan = small_plan(9);
        let w = plan.horizon_work;
        let side = 512.0 * 20.0 / plan.layout.centre_pixel_m(9, plan.body.radius_m);
        assert_eq!(w.tiles, 4.0);
        assert_eq!(w.px, 4.0 * 128.0 * 128.0);
        assert!(
            (w.data_px / (side * side) - 1.0).abs() < 0.1,
            "{} data pixels against {}",
            w.data_px,
            side * side
        );
        assert!(w.context_samples > 0.0);
    }

    #[test]
    fn far_rings_count_only_where_they_hold_terrain() {
        let plan = small_plan(9);
        let shifted: Vec<(&Dem, f64)> = plan.sources.iter().map(|s| (&s.dem, 0.0)).collect();
        let tiles: BTreeSet<TileId> = plan
            .tiles
            .iter()
            .filter(|t| t.level == 9)
            .copied()
            .collect();
        let inputs = |fine_margin_px| WorkInputs {
            layout: &plan.layout,
            radius_m: plan.body.radius_m,
            sources: shifted.clone(),
            range: terrain_range(&shifted).unwrap(),
            fine_margin_px,
            max_margin_px: 4096,
            far_rings: true,
        };
        // The default margin holds the whole terrain: rings are planned but hold none.
        let wide = cost::horizon_work(&inputs(1024), &tiles, &plan.tiles);
        assert_eq!((wide.ring_px, wide.ring_samples), (0.0, 0.0));
        // A 16-px margin leaves most of it to the rings: each tile is raised to at least one.
        let narrow = cost::horizon_work(&inputs(16), &tiles, &plan.tiles);
        assert!(narrow.ring_px >= narrow.px, "{narrow:?}");
        assert!(narrow.ring_samples > 0.0);
        assert!(narrow.context_samples < wide.context_samples);
        // Without far rings the narrow margin is not applied.
        let none = cost::horizon_work(
            &WorkInputs {
                far_rings: false,
                ..inputs(16)
            },
            &tiles,
            &plan.tiles,
        );
        assert_eq!(none.ring_px, 0.0);
        assert_eq!(none.context_samples, wide.context_samples);
    }
}
