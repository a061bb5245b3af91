//! The Fourier stage: each tile's horizons → per-pixel truncated series → a coefficient
//! pyramid file. Runs from the stored raw maps (`penumbra fourier`) or inside the horizon stage
//! on each tile's maps as they are computed ([`Encoder`]), so that raw maps need never be
//! written.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::series::{max_coefficients, Scratch, Sigma, Transform};
use crate::format::fourier::{
    self as pyramid, group_list, tile_path, Encoding, Layout, Pyramid, Reduce, FLOOR, FORMAT,
    PATTERN,
};

use crate::error::{Error, Result};
use crate::format::height::HeightTile;
use crate::format::horizon::HorizonError;
use crate::format::KeyBasis;
use crate::layout::TileId;
use crate::manifest::{self, FourierProduct, HorizonLevelDistance, Tileset};
use crate::progress::Progress;
use crate::runner::{self, Cx, Finished, Order, Reads, Select, Stage, StageSpec, Unit};
use crate::tileset::{Product, Store};

/// What the user chose.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FourierOptions {
    /// Tile levels (None: every level that has horizons).
    pub levels: Option<Vec<u8>>,
    /// Coefficients kept per pixel (K), 1..=A/2+1; the most when `max_error_deg` is set.
    pub coefficients: usize,
    pub layout: Layout,
    pub encoding: Encoding,
    pub sigma: Sigma,
    /// How reduced groups are made from the pixels' coefficients (multires).
    pub reduce: Reduce,
    /// Choose K per tile: the fewest whose truncation error (99th percentile over the tile's
    /// pixels of the RMS over azimuths) is at most this many degrees.
    pub max_error_deg: Option<f64>,
    /// Mark tiles whose horizon never rises above this sun elevation minus the sun's radius
    /// as fully lit instead of storing them.
    pub min_sun_el_deg: Option<f64>,
    /// The body's distance from the Sun (AU), for the sun's apparent radius; None: the body
    /// preset's (`sun::sun_distance_au`).
    pub sun_distance_au: Option<f64>,
    /// Refuse a run whose files would exceed this many GiB.
    pub max_output_gib: f64,
}

impl Default for FourierOptions {
    fn default() -> Self {
        FourierOptions {
            levels: None,
            coefficients: 16,
            layout: Layout::Multires,
            encoding: Encoding::F16,
            sigma: Sigma::None,
            reduce: Reduce::Mean,
            max_error_deg: None,
            min_sun_el_deg: None,
            sun_distance_au: None,
            max_output_gib: runner::DEFAULT_MAX_OUTPUT_GIB,
        }
    }
}

/// Check options that do not depend on the tileset; `azimuths` is the horizons' A.
pub fn check_options(opts: &FourierOptions, azimuths: usize) -> Result<()> {
    runner::check_output_cap("max_output_gib", opts.max_output_gib)?;
    let most = max_coefficients(azimuths);
    if !(1..=most).contains(&opts.coefficients) {
        return Err(Error::param(
            "coefficients",
            format!(
                "{} is outside 1..={most} (A/2 + 1 for {azimuths} azimuths)",
                opts.coefficients
            ),
        ));
    }
    if let Some(e) = opts.max_error_deg {
        if !(e.is_finite() && e > 0.0 && e <= 90.0) {
            return Err(Error::param(
                "max_error_deg",
                format!("{e} is not an angle in (0, 90] degrees"),
            ));
        }
    }
    if let Some(e) = opts.min_sun_el_deg {
        if !(e.is_finite() && (-90.0..=90.0).contains(&e)) {
            return Err(Error::param(
                "min_sun_el",
                format!("{e} is not an elevation in −90..=90 degrees"),
            ));
        }
    }
    if opts.sun_distance_au.is_some() {
        sun_distance(opts.sun_distance_au, "")?;
    }
    Ok(())
}

/// The floor of the stored horizons (degrees) for an observer at height `h0` on a body of
/// `radius_m` whose lowest terrain is `terrain_min_m`: the elevation of the tangent to the
/// sphere of the lowest terrain. Below it lies the body, mapped or not.
pub fn floor_deg(radius_m: f64, terrain_min_m: f64, h0: f64) -> f64 {
    -((radius_m + terrain_min_m) / (radius_m + h0.max(terrain_min_m)))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// The body's distance from the Sun (AU): the one given (checked: 0.01..=10000), else the body
/// preset's; an error naming the option when neither is known.
pub fn sun_distance(distance_au: Option<f64>, body: &str) -> Result<f64> {
    if let Some(d) = distance_au {
        if !(d.is_finite() && (0.01..=1.0e4).contains(&d)) {
            return Err(Error::param(
                "sun_distance_au",
                format!("{d} is outside 0.01..=10000 AU"),
            ));
        }
        return Ok(d);
    }
    super::sun::sun_distance_au(body).ok_or_else(|| {
        Error::param(
            "sun_distance_au",
            format!(
                "is needed: the body '{body}' has no distance from the Sun on record; give it \
                 in AU"
            ),
        )
    })
}

/// Checks of the options against a tileset: a sun radius must be known for `min_sun_el_deg`
/// and for horizons left out below `lit_above_deg` (a pruned horizon run), and then a
/// `min_sun_el_deg` asked must not promise suns those tiles have no horizon for.
pub fn check_tileset(
    opts: &FourierOptions,
    ts: &Tileset,
    lit_above_deg: Option<f64>,
) -> Result<()> {
    if opts.min_sun_el_deg.is_some() || lit_above_deg.is_some() {
        let r = sun_radius_deg(opts.sun_distance_au, &ts.body.name)?;
        effective_min_sun_el(opts.min_sun_el_deg, lit_above_deg, r)
            .map_err(|m| Error::param("min_sun_el", m))?;
    }
    Ok(())
}

/// The `min_sun_el_deg` a Fourier product records (tiles marked fully lit are lit for every
/// sun whose centre is at or above it): the one asked; with horizons left out below
/// `lit_above_deg` (whose tiles are written fully lit), `lit_above_deg` plus the sun's radius
/// unless a higher one was asked. A lower one is refused: the tiles left out keep no horizon
/// for suns below the threshold.
pub fn effective_min_sun_el(
    asked: Option<f64>,
    lit_above_deg: Option<f64>,
    sun_radius_deg: f64,
) -> std::result::Result<Option<f64>, String> {
    match (asked, lit_above_deg) {
        (a, None) => Ok(a),
        (None, Some(t)) => Ok(Some(t + sun_radius_deg)),
        (Some(a), Some(t)) if a >= t + sun_radius_deg => Ok(Some(a)),
        (Some(a), Some(t)) => Err(format!(
            "{a}° is below the sun the horizons were computed for: tiles were left out whose \
             horizon never reaches {t}° (the lowest sun less its radius, {sun_radius_deg:.4}°), \
             so their pyramids are fully lit only for suns at or above {:.4}°; ask at least \
             that, or compute the horizons without leaving tiles out",
            t + sun_radius_deg
        )),
    }
}

/// The sun's apparent radius (degrees) seen from `body`: from the distance given, else the
/// body preset's; an error naming the option when neither is known.
pub fn sun_radius_deg(distance_au: Option<f64>, body: &str) -> Result<f64> {
    Ok(super::sun::sun_radius_deg(sun_distance(distance_au, body)?))
}

/// What one tile's compression found.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct TileStats {
    /// Coefficients kept (0 when fully lit).
    pub k: usize,
    pub fully_lit: bool,
    pub bytes: u64,
}

/// Compresses tiles' horizons with one set of options; shared by the stage and the horizon
/// stage's streaming (one FFT plan per size, scratch per thread).
pub struct Encoder {
    opts: FourierOptions,
    n: usize,
    a: usize,
    halo: usize,
    radius_m: f64,
    terrain_min_m: f64,
    /// For `min_sun_el_deg` (0 unless a distance is set; [`Encoder::new`] takes the body's).
    sun_radius_deg: f64,
    transform: Transform,
}

impl Encoder {
    /// The pyramid of a tile whose horizons were left out (never rising above `bound_deg`,
    /// below the run's `lit_above_deg`): marked fully lit, no coefficients.
    pub fn encode_pruned(&self, bound_deg: f32) -> (Pyramid, TileStats) {
        let o = &self.opts;
        let p = Pyramid::fully_lit(self.n, self.a, o.layout, o.encoding, o.sigma, bound_deg);
        let bytes = p.file_bytes() as u64;
        (
            p,
            TileStats {
                k: 0,
                fully_lit: true,
                bytes,
            },
        )
    }
}

impl Encoder {
    /// An encoder for the tiles of `ts`; the sun radius for `min_sun_el_deg` is resolved by
    /// [`check_tileset`] before a run starts.
    pub fn new(opts: &FourierOptions, ts: &Tileset, a: usize, terrain_min_m: f64) -> Encoder {
        let mut e = Encoder::for_tiles(
            opts,
            ts.layout.tile_size as usize,
            ts.layout.halo as usize,
            a,
            ts.body.radius_m,
            terrain_min_m,
        );
        if opts.min_sun_el_deg.is_some() {
            e.sun_radius_deg = sun_radius_deg(opts.sun_distance_au, &ts.body.name).unwrap_or(0.0);
        }
        e
    }

    /// An encoder for tiles of `n` pixels with `halo` (height tiles of `(n + 2·halo)²`), `a`
    /// azimuths, on a body of `radius_m` whose lowest terrain is `terrain_min_m`.
    pub fn for_tiles(
        opts: &FourierOptions,
        n: usize,
        halo: usize,
        a: usize,
        radius_m: f64,
        terrain_min_m: f64,
    ) -> Encoder {
        Encoder {
            opts: opts.clone(),
            n,
            a,
            halo,
            radius_m,
            terrain_min_m,
            sun_radius_deg: opts.sun_distance_au.map_or(0.0, super::sun::sun_radius_deg),
            transform: Transform::new(a),
        }
    }

    /// The floor (degrees) of an observer at height `h0`: the tangent to the lowest sphere.
    pub fn floor_deg(&self, h0: f64) -> f64 {
        floor_deg(self.radius_m, self.terrain_min_m, h0)
    }

    /// The pyramid of one tile from its raw maps (`A` planes of n², degrees) and its height
    /// tile (for the floor and the no-data pixels).
    pub fn encode(&self, elev: &[f32], tile: &HeightTile) -> (Pyramid, TileStats) {
        let (n, a) = (self.n, self.a);
        assert_eq!(elev.len(), n * n * a);
        let h0: Vec<f32> = (0..n * n)
            .map(|p| tile.height[(p / n + self.halo) * tile.size + p % n + self.halo])
            .collect();
        let valid: Vec<bool> = (0..n * n)
            .map(|p| h0[p].is_finite() && elev[p].is_finite())
            .collect();
        let floor: Vec<f64> = h0.iter().map(|&h| self.floor_deg(h as f64)).collect();
        let value = |p: usize, s: usize| -> f64 {
            let v = elev[s * n * n + p] as f64;
            if v.is_finite() {
                v.max(floor[p])
            } else {
                0.0
            }
        };
        let max_h = (0..n * n)
            .filter(|&p| valid[p])
            .flat_map(|p| (0..a).map(move |s| (p, s)))
            .map(|(p, s)| value(p, s))
            .fold(f64::NEG_INFINITY, f64::max);
        let max_h = if max_h.is_finite() { max_h } else { -90.0 };
        let (layout, enc, sigma) = (self.opts.layout, self.opts.encoding, self.opts.sigma);
        if let Some(e) = self.opts.min_sun_el_deg {
            if max_h <= e - self.sun_radius_deg {
                let p = Pyramid::fully_lit(n, a, layout, enc, sigma, max_h as f32);
                let bytes = p.file_bytes() as u64;
                return (
                    p,
                    TileStats {
                        k: 0,
                        fully_lit: true,
                        bytes,
                    },
                );
            }
        }
        // With an error budget the whole spectrum is needed to measure each K's error.
        let k_max = self.opts.coefficients;
        let k_calc = if self.opts.max_error_deg.is_some() {
            max_coefficients(a)
        } else {
            k_max
        };
        let mut coef = vec![[0.0f32; 2]; n * n * k_calc];
        let tr = &self.transform;
        let untapered = if self.opts.max_error_deg.is_some() {
            Sigma::None
        } else {
            sigma
        };
        coef.par_chunks_mut(n * k_calc).enumerate().for_each_init(
            Scratch::default,
            |scratch, (j, row)| {
                tr.forward(
                    n,
                    |i, s| value(j * n + i, s),
                    k_calc,
                    untapered,
                    row,
                    scratch,
                )
            },
        );
        let k = match self.opts.max_error_deg {
            None => k_max,
            Some(budget) => {
                let k = choose_k(&coef, &valid, a, k_calc, k_max, budget);
                if sigma != Sigma::None {
                    for c in coef.chunks_mut(k_calc) {
                        for (j, v) in c.iter_mut().take(k).enumerate() {
                            let f = sigma.factor(j, k) as f32;
                            *v = [v[0] * f, v[1] * f];
                        }
                    }
                }
                k
            }
        };
        let p = Pyramid::build(
            n,
            a,
            &coef,
            k_calc,
            k,
            &valid,
            layout,
            enc,
            sigma,
            self.opts.reduce,
            max_h as f32,
        );
        let bytes = p.file_bytes() as u64;
        (
            p,
            TileStats {
                k,
                fully_lit: false,
                bytes,
            },
        )
    }
}

/// The fewest coefficients (≤ `k_max`) whose truncation error, the 99th percentile over the
/// valid pixels of each pixel's RMS over azimuths (Parseval on the full spectrum), is within
/// `budget` degrees.
fn choose_k(
    coef: &[[f32; 2]],
    valid: &[bool],
    a: usize,
    k_full: usize,
    k_max: usize,
    budget: f64,
) -> usize {
    let pixels: Vec<&[[f32; 2]]> = coef
        .chunks(k_full)
        .zip(valid)
        .filter(|(_, &v)| v)
        .map(|(c, _)| c)
        .collect();
    if pixels.is_empty() {
        return 1;
    }
    // Per pixel the tail energy for every K at once (suffix sums), then a percentile per K.
    let tails: Vec<Vec<f64>> = pixels
        .par_iter()
        .map(|c| {
            let mut t = vec![0.0; k_max + 1];
            let mut acc = Transform::tail_energy(c, a, k_max);
            t[k_max] = acc;
            for k in (1..k_max).rev() {
                acc += super::series::term_energy(c[k], k, a);
                t[k] = acc;
            }
            t
        })
        .collect();
    let mut e: Vec<f64> = Vec::with_capacity(tails.len());
    for k in 1..=k_max {
        e.clear();
        e.extend(tails.iter().map(|t| t[k]));
        let idx = ((e.len() as f64 * 0.99).ceil() as usize).clamp(1, e.len()) - 1;
        let (_, p99, _) = e.select_nth_unstable_by(idx, |x, y| x.total_cmp(y));
        if p99.sqrt() <= budget {
            return k;
        }
    }
    k_max
}

/// Key of a tile in `tile_coefficients`.
pub fn tile_key(id: TileId) -> String {
    pyramid::tile_key(id)
}

/// Collects per-tile results into the manifest's entry.
#[derive(Default)]
pub struct Tally {
    pub tiles: u64,
    pub fully_lit: u64,
    /// Bytes of the files written in this run (not those kept).
    pub bytes_written: u64,
    pub k: BTreeMap<String, usize>,
}

impl Tally {
    /// A tile this run wrote.
    pub fn add(&mut self, id: TileId, s: TileStats) {
        self.bytes_written += s.bytes;
        self.count(id, s);
    }

    /// A tile an interrupted run wrote (its stats from [`kept`]).
    pub fn add_kept(&mut self, id: TileId, s: TileStats) {
        self.count(id, s);
    }

    fn count(&mut self, id: TileId, s: TileStats) {
        self.tiles += 1;
        if s.fully_lit {
            self.fully_lit += 1;
        }
        self.k.insert(tile_key(id), s.k);
    }
}

/// How the horizons a Fourier product compresses were made.
pub struct Source<'a> {
    pub kind: &'static str,
    pub method: &'a str,
    pub near_px: Option<f64>,
    pub error: Option<HorizonError>,
    pub terrain: (f64, f64),
    pub distances: Vec<HorizonLevelDistance>,
    /// The threshold the horizons left tiles out below, if any.
    pub lit_above_deg: Option<f64>,
}

/// The manifest entry of a finished run.
#[allow(clippy::too_many_arguments)]
pub fn product(
    ts: &Tileset,
    opts: &FourierOptions,
    levels: Vec<u8>,
    a: usize,
    tally: Tally,
    source: Source,
    run_key: String,
    run_key_basis: KeyBasis,
) -> FourierProduct {
    let n = ts.layout.tile_size as usize;
    let lit_above = source.lit_above_deg;
    let radius = (opts.min_sun_el_deg.is_some() || lit_above.is_some())
        .then(|| sun_radius_deg(opts.sun_distance_au, &ts.body.name).ok())
        .flatten();
    let min_sun_el =
        effective_min_sun_el(opts.min_sun_el_deg, lit_above, radius.unwrap_or(0.0)).unwrap_or(None);
    FourierProduct {
        path: PATTERN.into(),
        format: FORMAT.into(),
        levels,
        azimuths: a,
        azimuth: crate::format::horizon::AZIMUTH_CONVENTION.into(),
        coefficients: opts.coefficients,
        layout: opts.layout.name().into(),
        encoding: opts.encoding.name().into(),
        sigma: opts.sigma.name().into(),
        reduce: opts.reduce.name().into(),
        groups: group_list(n, opts.coefficients, opts.layout),
        bytes_per_tile: pyramid::file_bytes(n, opts.coefficients, opts.layout) as u64,
        floor: FLOOR.into(),
        max_error_deg: opts.max_error_deg,
        tile_coefficients: opts.max_error_deg.map(|_| tally.k),
        min_sun_el_deg: min_sun_el,
        sun_radius_deg: min_sun_el.and(radius),
        tiles_fully_lit: tally.fully_lit,
        source: source.kind.into(),
        horizon_method: source.method.into(),
        horizon_near_px: source.near_px,
        horizon_error: source.error,
        terrain_min_m: source.terrain.0,
        terrain_max_m: source.terrain.1,
        distances: source.distances,
        run_key,
        run_key_basis: Some(run_key_basis),
    }
}

/// Refuse a run whose pyramids would exceed the cap.
pub fn check_output_size(opts: &FourierOptions, tiles: usize, n: usize) -> Result<()> {
    let gib = tiles as f64 * pyramid::file_bytes(n, opts.coefficients, opts.layout) as f64
        / (1u64 << 30) as f64;
    if gib > opts.max_output_gib {
        return Err(Error::param(
            "max_output_gib",
            format!(
                "is {}, but the pyramids would take {gib:.3} GiB ({tiles} tiles): choose fewer \
                 levels or coefficients, or raise the cap",
                opts.max_output_gib
            ),
        ));
    }
    Ok(())
}

/// The stage from stored raw maps.
pub const STAGE: StageSpec = StageSpec {
    name: "fourier",
    writes: Cow::Borrowed(&[Product::Fourier]),
    reads: Cow::Borrowed(&[Product::Height, Product::Horizon]),
    format: Cow::Borrowed(&[FORMAT]),
};

#[derive(Clone, Debug, Serialize)]
pub struct FourierReport {
    pub out: PathBuf,
    pub levels: Vec<u8>,
    pub azimuths: usize,
    pub coefficients: usize,
    pub layout: Layout,
    pub encoding: Encoding,
    pub sigma: Sigma,
    pub tiles: u64,
    pub tiles_written: u64,
    pub tiles_kept: u64,
    pub tiles_fully_lit: u64,
    /// Bytes of the files written in this run.
    pub bytes_written: u64,
    /// Bytes a tile's raw maps take in f16 (A·n²·2), for comparison.
    pub raw_bytes_per_tile: u64,
    pub bytes_per_tile: u64,
    pub up_to_date: bool,
}

/// Compress the stored raw horizon maps of the levels asked into Fourier pyramids.
pub fn build_fourier(
    dir: &Path,
    opts: &FourierOptions,
    progress: &dyn Progress,
) -> Result<FourierReport> {
    runner::execute(
        &FourierStage { opts: opts.clone() },
        dir,
        &Select::All,
        progress,
    )?
    .into_report("fourier")
}

/// The Fourier stage from stored raw maps: one unit per tile of the levels asked.
pub struct FourierStage {
    pub opts: FourierOptions,
}

impl FourierStage {
    /// What the run key hashes besides the raw maps' run key: the options as JSON.
    fn basis(&self) -> KeyBasis {
        runner::key_basis(
            &STAGE,
            vec![serde_json::to_string(&self.opts).unwrap_or_default()],
        )
    }
}

/// What a run from raw maps knows once the tileset is checked.
pub struct FourierPlan {
    levels: Vec<u8>,
    tiles: Vec<TileId>,
    azimuths: usize,
    encoder: Encoder,
}

impl Stage for FourierStage {
    type Plan = FourierPlan;
    type Done = TileStats;
    type Scratch = ();
    type Report = FourierReport;

    fn spec(&self) -> StageSpec {
        STAGE
    }

    fn plan(&self, dir: &Path, ts: &Tileset) -> Result<FourierPlan> {
        let opts = &self.opts;
        let mpath = dir.join(manifest::MANIFEST);
        let h = ts.products.horizon.as_ref().ok_or_else(|| {
            Error::invalid(
                &mpath,
                "tileset has no raw horizon maps to compress: run `penumbra horizon` first, or \
                 `penumbra horizon --fourier` to compress them as they are computed",
            )
        })?;
        check_options(opts, h.azimuths)?;
        check_tileset(opts, ts, h.pruned.as_ref().map(|p| p.lit_above_deg))?;
        let levels = match &opts.levels {
            None => h.levels.clone(),
            Some(l) => {
                let mut l = l.clone();
                l.sort_unstable();
                l.dedup();
                if let Some(bad) = l.iter().find(|x| !h.levels.contains(x)) {
                    return Err(Error::usage(format!(
                        "level {bad} has no horizon maps in {} (levels {:?}): compute them \
                         first with `penumbra horizon --levels {bad}`",
                        dir.display(),
                        h.levels
                    )));
                }
                l
            }
        };
        let tiles: Vec<TileId> = ts
            .tile_set()
            .into_iter()
            .filter(|t| levels.contains(&t.level))
            .collect();
        check_output_size(opts, tiles.len(), ts.layout.tile_size as usize)?;
        Ok(FourierPlan {
            levels,
            tiles,
            azimuths: h.azimuths,
            encoder: Encoder::new(opts, ts, h.azimuths, h.terrain_min_m),
        })
    }

    fn key(&self, ts: &Tileset, _plan: &FourierPlan) -> String {
        let h = ts.products.horizon.as_ref().expect("checked");
        self.basis().key(&[&h.run_key])
    }

    fn units(&self, ts: &Tileset, plan: &FourierPlan) -> Result<Vec<Unit>> {
        let n = ts.layout.tile_size as usize;
        let h = ts.products.horizon.as_ref().expect("checked");
        Ok(plan
            .tiles
            .iter()
            .map(|&id| {
                let mut reads = vec![Reads::Tile {
                    product: Product::Height,
                    tile: id,
                }];
                // A tile the horizon run left out has no maps.
                if h.pruned_tile(id).is_none() {
                    reads.push(Reads::Tile {
                        product: Product::Horizon,
                        tile: id,
                    });
                }
                Unit::tile(id, reads, (n * n * plan.azimuths) as f64)
            })
            .collect())
    }

    fn order(&self) -> Order {
        // The encoder spreads a tile's pixels over the threads.
        Order::Sequential
    }

    fn scratch(&self, _plan: &FourierPlan) {}

    fn run_unit(&self, cx: &Cx<FourierPlan>, unit: &Unit, _: &mut ()) -> Result<TileStats> {
        let id = unit.tile;
        let h = cx
            .store
            .manifest()
            .products
            .horizon
            .as_ref()
            .expect("checked");
        let (p, stats) = match h.pruned_tile(id) {
            Some((_, bound)) => cx.plan.encoder.encode_pruned(bound),
            None => {
                let tile = cx.store.height(id)?.expect("listed tiles exist");
                let elev = cx.store.horizon(id)?;
                cx.plan.encoder.encode(&elev, &tile)
            }
        };
        let identity = crate::format::Identity::tile(pyramid::ID, id, cx.key);
        pyramid::write(&tile_path(cx.out, id), &p, &identity)?;
        Ok(stats)
    }

    fn finish(
        &self,
        cx: &Cx<FourierPlan>,
        done: Vec<Finished<TileStats>>,
    ) -> Result<(Tileset, FourierReport)> {
        let (opts, ts) = (&self.opts, cx.store.manifest());
        let h = ts.products.horizon.as_ref().expect("checked");
        let mut report = self.up_to_date(cx.store, cx.plan, &[]);
        report.up_to_date = false;
        report.tiles_kept = 0;
        let mut tally = Tally::default();
        for f in done {
            if f.here {
                tally.add(f.unit.tile, f.done);
                report.tiles_written += 1;
                report.bytes_written += f.done.bytes;
            } else {
                tally.add_kept(f.unit.tile, f.done);
                report.tiles_kept += 1;
            }
        }
        report.tiles_fully_lit = tally.fully_lit;
        let mut manifest = ts.clone();
        manifest.products.fourier = Some(product(
            ts,
            opts,
            cx.plan.levels.clone(),
            cx.plan.azimuths,
            tally,
            Source {
                kind: "raw",
                method: &h.method,
                near_px: h.near_px,
                error: h.error.clone(),
                terrain: (h.terrain_min_m, h.terrain_max_m),
                distances: h.distances.clone(),
                lit_above_deg: h.pruned.as_ref().map(|p| p.lit_above_deg),
            },
            cx.key.to_string(),
            self.basis(),
        ));
        Ok((manifest, report))
    }

    fn up_to_date(&self, store: &Store, plan: &FourierPlan, _units: &[Unit]) -> FourierReport {
        let (opts, n, a) = (
            &self.opts,
            store.manifest().layout.tile_size as usize,
            plan.azimuths,
        );
        let tiles = plan.tiles.len() as u64;
        FourierReport {
            out: store.dir().to_path_buf(),
            levels: plan.levels.clone(),
            azimuths: a,
            coefficients: opts.coefficients,
            layout: opts.layout,
            encoding: opts.encoding,
            sigma: opts.sigma,
            tiles,
            tiles_written: 0,
            tiles_kept: tiles,
            tiles_fully_lit: store
                .manifest()
                .products
                .fourier
                .as_ref()
                .map_or(0, |f| f.tiles_fully_lit),
            bytes_written: 0,
            raw_bytes_per_tile: (a * n * n * 2) as u64,
            bytes_per_tile: pyramid::file_bytes(n, opts.coefficients, opts.layout) as u64,
            up_to_date: true,
        }
    }
}
