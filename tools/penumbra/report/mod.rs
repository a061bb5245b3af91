//! `penumbra report`: error against run time on the user's own terrain. On a deterministic
//! sample of a tileset's pixels (blocks of observers in tiles of one level, pixels stratified by
//! slope and by distance to the data's edge, as many blocks as the time budget allows), every
//! horizon method, every Fourier variant and classic map, and every shadow method is measured
//! against the exact reference at those pixels, at the scene's suns. The figures use the
//! benchmarks' own measures ([`crate::measure`]), so that on the shared DEMs they are the
//! benchmarks' figures up to sampling.
//!
//! [`render`] writes them as report.html (plots as inline SVG), report.md and report.json.

pub mod render;

use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use penumbra::error::{Error, Result};
use penumbra::fourier::stage::{Encoder, FourierOptions};
use penumbra::fourier::sun::{sun_distance_au, sun_radius_deg, Frame, Sun};
use penumbra::fourier::Pyramid;
use penumbra::horizon::{self, horizons_with, Context as HzContext, Method as HzMethod, Rect};
use penumbra::layout::TileId;
use penumbra::progress::Progress;
use penumbra::scene::{Scene, SunSpec};
use penumbra::shadow::smap::SMap;
use penumbra::shadow::trace::{Method as TraceMethod, Work};
use penumbra::shadow::Tracer;
use penumbra::tileset::Store;

use crate::measure::{
    self, interp, lit_exact, lookup_lit, Case, ErrStats, ErrSum, Horizon, ShadowWay, Variant,
};

/// Limits of the options (exit 2 outside them).
pub const BUDGET_S: std::ops::RangeInclusive<f64> = 5.0..=86_400.0;
pub const MAX_PER_PCT: std::ops::RangeInclusive<f64> = 0.001..=50.0;
pub const MAX_ERROR_DEG: std::ops::RangeInclusive<f64> = 0.0001..=10.0;
/// Azimuths of the report's horizon maps when the scene names none (a multiple of 4, ≥ 64 so
/// that K = 32 fits: K ≤ A/2 + 1).
pub const DEFAULT_AZIMUTHS: usize = 360;
/// Default sun elevations (degrees) and compass azimuths where no scene gives them: the
/// benchmarks' (docs/fourier-bench.md, docs/shadows.md).
pub const DEFAULT_SUN_EL: [f64; 3] = [1.0, 5.0, 15.0];
/// The shadow benchmark's elevations (docs/shadows.md), where no scene gives them: the
/// Fourier ones and a high sun.
pub const DEFAULT_SHADOW_SUN_EL: [f64; 4] = [1.0, 5.0, 15.0, 45.0];
pub const SUN_AZ: [f64; 8] = [17.0, 62.0, 107.0, 152.0, 197.0, 242.0, 287.0, 332.0];
/// Strata of the sample: three slope classes × near or far from the data's edge.
const EDGE_PX: usize = 16;
/// Side of the sub-block of each block the exact method is timed and measured on (pixels).
const EXACT_PX: usize = 24;
/// Most blocks a report samples.
pub const MAX_BLOCKS: usize = 64;
/// Part of the budget kept for writing the report (s).
const WRITE_RESERVE_S: f64 = 1.0;

/// What `penumbra report` was asked.
#[derive(Clone, Debug)]
pub struct Options {
    pub budget_s: f64,
    /// Pixel error rate (percent) the scene can afford.
    pub max_per_pct: f64,
    /// Horizon error (degrees, RMS) the scene can afford.
    pub max_error_deg: f64,
    /// Seed of the sample (another seed: an independent sample of the same strata).
    pub seed: u64,
    /// Tile level sampled (None: the scene's finest horizon level, else the finest level).
    pub level: Option<u8>,
    /// A fixed sample instead of the budget's: this many blocks of this side (one of
    /// [`block_sizes`]), the same pixels whatever the machine's speed.
    pub fixed: Option<(usize, usize)>,
}

/// The block sides a fixed sample may take, for messages.
pub fn block_sizes() -> String {
    SIZES
        .iter()
        .map(|s| s.block.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The scene and tileset a report is about.
pub struct Input<'a> {
    pub store: &'a Store,
    pub tileset: PathBuf,
    pub scene: Option<&'a Scene>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    pub version: u32,
    pub tileset: String,
    pub scene: Option<String>,
    pub body: String,
    pub radius_m: f64,
    pub level: u8,
    pub tile_size: u32,
    pub azimuths: usize,
    /// Sun elevations of the horizon-storage figures and of the shadow figures (degrees).
    pub sun_elevations_deg: Vec<f64>,
    pub shadow_sun_elevations_deg: Vec<f64>,
    pub sun_azimuths_deg: Vec<f64>,
    pub sun_radius_deg: f64,
    pub max_per_pct: f64,
    pub max_error_deg: f64,
    pub budget_s: f64,
    pub elapsed_s: f64,
    pub threads: usize,
    pub seed: u64,
    pub blocks: Vec<BlockInfo>,
    pub pixels: usize,
    pub horizons: Vec<HorizonRow>,
    pub fourier: Vec<FourierRow>,
    pub shadows: Vec<ShadowRow>,
    pub recommendations: Vec<Recommendation>,
    pub notes: Vec<String>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BlockInfo {
    pub tile: String,
    /// Block origin within the tile and its side (pixels).
    pub x0: usize,
    pub y0: usize,
    pub size: usize,
    pub context: String,
    /// Sampled pixels per stratum: slope low/mid/high × far/near the data's edge.
    pub strata: [usize; 6],
    pub seconds: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct HorizonRow {
    pub method: String,
    pub samples: u64,
    pub rms_deg: f64,
    pub p99_deg: f64,
    pub max_deg: f64,
    /// Core-nanoseconds per pixel·azimuth (wall time × threads).
    pub core_ns: f64,
    /// Standard error of `rms_deg` from the spread between blocks (None: one block).
    pub se_rms_deg: Option<f64>,
    /// The same per stratum of the sample ([`STRATA`]).
    #[serde(default)]
    pub strata: Vec<StratumFigures>,
    pub pareto: bool,
    pub default: bool,
}

/// A horizon method's errors in one stratum of the sample.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StratumFigures {
    pub stratum: String,
    pub samples: u64,
    pub rms_deg: f64,
    pub max_deg: f64,
}

/// The sample's strata, in the order the sample lists them.
pub const STRATA: [&str; 6] = [
    "low slope, inland",
    "mid slope, inland",
    "steep, inland",
    "low slope, near an edge",
    "mid slope, near an edge",
    "steep, near an edge",
];

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FourierRow {
    pub variant: String,
    pub bytes_per_tile: usize,
    pub encode_ms_per_tile: f64,
    /// Against the raw map it compresses (the compression's own error).
    pub rms_deg: f64,
    pub p99_deg: f64,
    pub max_deg: f64,
    /// Against the reference (the horizon method's error and the compression's together).
    pub rms_ref_deg: f64,
    pub p99_ref_deg: f64,
    /// Lit-fraction mean absolute error (exact disc model) and pixel error rate (%) at the
    /// scene's suns, against the raw map's.
    pub lit_mae: f64,
    pub per_pct: f64,
    /// Standard errors of `per_pct` and `lit_mae` from the spread between blocks.
    pub se_per_pct: Option<f64>,
    pub se_lit_mae: Option<f64>,
    pub pareto: bool,
    pub paper: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ShadowRow {
    pub method: String,
    pub hard: bool,
    pub samples: u64,
    pub lit_mae: f64,
    pub lit_max: f64,
    pub per_pct: f64,
    /// Core-milliseconds (wall time × threads) per million (pixel, sun) answers: about one
    /// thread's milliseconds per megapixel, as docs/shadows.md reports them.
    pub ms_per_mpx: f64,
    /// Standard errors of `lit_mae` and `per_pct` from the spread between blocks.
    pub se_lit_mae: Option<f64>,
    pub se_per_pct: Option<f64>,
    pub pareto: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Recommendation {
    pub product: String,
    pub choice: Option<String>,
    pub why: String,
    /// The scene-file setting it amounts to (for `plan`), where there is one.
    pub setting: Option<String>,
}

/// Three elevations over a range of sun elevations (the lowest, where shadows are decided,
/// then a quarter of the way up, then the highest), kept within −5°..85° (near 90° the
/// azimuth no longer means anything).
fn elevations_over(lo: f64, hi: f64) -> Vec<f64> {
    let (lo, hi) = (lo.clamp(-5.0, 85.0), hi.clamp(-5.0, 85.0));
    let mut el = vec![lo, lo + (hi - lo) / 4.0, hi];
    el.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    el
}

/// The suns a report uses: elevations (degrees) and compass azimuths (degrees). A time span
/// is turned into the range of elevations the sun takes over `points` (latitude, longitude in
/// degrees: the sampled level's tile centres) during it.
fn suns_of(
    scene: Option<&Scene>,
    body: &str,
    points: &[(f64, f64)],
    notes: &mut Vec<String>,
) -> (Vec<f64>, Vec<f64>) {
    let az: Vec<f64> = SUN_AZ.to_vec();
    match scene.and_then(|s| s.sun.as_ref()) {
        Some(SunSpec::Range {
            elevation_deg: (lo, hi),
            azimuth_deg,
            ..
        }) => {
            let az = match azimuth_deg {
                Some((a0, a1)) => {
                    let span = (a1 - a0).rem_euclid(360.0);
                    let span = if span == 0.0 { 360.0 } else { span };
                    (0..8)
                        .map(|m| (a0 + span * (m as f64 + 0.5) / 8.0).rem_euclid(360.0))
                        .collect()
                }
                None => az,
            };
            (elevations_over(*lo, *hi), az)
        }
        Some(SunSpec::Span { start, end, .. }) => {
            let spec = penumbra::ephemeris::SunSpec::Span {
                body: body.to_string(),
                start_utc: start.clone(),
                end_utc: end.clone(),
            };
            match penumbra::ephemeris::elevation_range(&spec, points, None) {
                Ok((lo, hi)) => {
                    notes.push(format!(
                        "The scene's sun is a time span: over it the sun's elevation at the \
                         sampled level's {} tile centres ranges {lo:.2}° to {hi:.2}°; the \
                         report's suns are three elevations over that range at eight azimuths.",
                        points.len()
                    ));
                    (elevations_over(lo, hi), az)
                }
                Err(e) => {
                    notes.push(format!(
                        "The scene's sun span could not be evaluated ({e}): the report uses \
                         the benchmarks' suns (1°, 5° and 15° at eight azimuths)."
                    ));
                    (DEFAULT_SUN_EL.to_vec(), az)
                }
            }
        }
        None => (DEFAULT_SUN_EL.to_vec(), az),
    }
}

/// Deterministic 64-bit mix (splitmix64).
fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// The tiles of `level` in a deterministic order spread over the level (sorted by a hash of
/// the tile and the seed).
fn tile_order(store: &Store, level: u8, seed: u64) -> Vec<TileId> {
    let mut t: Vec<TileId> = store
        .manifest()
        .tile_set()
        .into_iter()
        .filter(|t| t.level == level)
        .collect();
    t.sort_by_key(|id| {
        mix(seed ^ mix(((id.face as u64) << 48) | ((id.x as u64) << 24) | id.y as u64))
    });
    t
}

/// The sample of one block: `want` pixels (block coordinates), allocated to the six strata in
/// proportion to their populations, at least a few from each non-empty one, drawn in a
/// seeded order. Pixels without data are not drawn.
fn stratified(
    ctx: &HzContext,
    rect: Rect,
    pixel_m: f64,
    want: usize,
    seed: u64,
) -> (Vec<(usize, usize)>, [usize; 6]) {
    let n = rect.w;
    let h = |x: i64, y: i64| ctx.at(x, y);
    let mut slope = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let (x, y) = ((rect.x0 + i) as i64, (rect.y0 + j) as i64);
            let (l, r, u, d) = (h(x - 1, y), h(x + 1, y), h(x, y - 1), h(x, y + 1));
            let s = if h(x, y).is_finite()
                && l.is_finite()
                && r.is_finite()
                && u.is_finite()
                && d.is_finite()
            {
                (((r - l) as f64).hypot((d - u) as f64) / (2.0 * pixel_m))
                    .atan()
                    .to_degrees()
            } else if h(x, y).is_finite() {
                f64::INFINITY
            } else {
                f64::NAN
            };
            slope.push(s);
        }
    }
    let mut sorted: Vec<f64> = slope.iter().copied().filter(|s| s.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let q = |f: f64| {
        sorted
            .get(((sorted.len() as f64 * f) as usize).min(sorted.len().saturating_sub(1)))
            .copied()
            .unwrap_or(0.0)
    };
    let (t1, t2) = (q(1.0 / 3.0), q(2.0 / 3.0));
    // Distance to the data's edge: to the context's border or the nearest void (Chebyshev,
    // capped at EDGE_PX).
    let near_edge = |i: usize, j: usize| -> bool {
        let (x, y) = (rect.x0 + i, rect.y0 + j);
        if x < EDGE_PX || y < EDGE_PX || x + EDGE_PX >= ctx.width || y + EDGE_PX >= ctx.height {
            return true;
        }
        let e = EDGE_PX as i64;
        for dy in (-e..=e).step_by(4) {
            for dx in (-e..=e).step_by(4) {
                if !h(x as i64 + dx, y as i64 + dy).is_finite() {
                    return true;
                }
            }
        }
        false
    };
    let mut strata: [Vec<(u64, usize, usize)>; 6] = Default::default();
    for j in 0..n {
        for i in 0..n {
            let s = slope[j * n + i];
            if s.is_nan() {
                continue;
            }
            let c = if s <= t1 {
                0
            } else if s <= t2 {
                1
            } else {
                2
            };
            let k = c + 3 * near_edge(i, j) as usize;
            strata[k].push((mix(seed ^ mix((j * n + i) as u64 + 1)), i, j));
        }
    }
    let total: usize = strata.iter().map(|s| s.len()).sum();
    let mut out = Vec::new();
    let mut counts = [0usize; 6];
    if total == 0 {
        return (out, counts);
    }
    let floor = (want / 24).max(1);
    for (k, s) in strata.iter_mut().enumerate() {
        if s.is_empty() {
            continue;
        }
        s.sort_unstable();
        let share = ((want as f64 * s.len() as f64 / total as f64).round() as usize).max(floor);
        for &(_, i, j) in s.iter().take(share) {
            out.push((i, j));
        }
        counts[k] = share.min(s.len());
    }
    (out, counts)
}

const HZ_METHODS: [HzMethod; 4] = [
    HzMethod::Reference,
    HzMethod::Exact,
    HzMethod::Fast,
    HzMethod::Sweep,
];

/// The shadow methods the report measures (the reference first: the truth).
fn shadow_methods() -> Vec<ShadowWay> {
    let mut v = vec![ShadowWay::Trace(TraceMethod::Reference)];
    for s in [25, 50, 100, 200, 400, 800] {
        v.push(ShadowWay::Trace(TraceMethod::Uniform { steps: s }));
    }
    for (runs, dda) in [("5,5,5", false), ("auto", false), ("auto", true)] {
        v.push(ShadowWay::Trace(TraceMethod::Dp {
            runs: runs.parse().expect("runs"),
            dda,
        }));
    }
    v.push(ShadowWay::Trace(TraceMethod::Extrema));
    v.push(ShadowWay::Trace(TraceMethod::ExtremaSoft));
    v.push(ShadowWay::SMap);
    v.push(ShadowWay::Lookup(true));
    v.push(ShadowWay::Lookup(false));
    v
}

/// Tallies over every block.
struct Tally {
    hz: Vec<(ErrStats, f64, f64)>,
    /// Per horizon method and stratum: samples, Σe², max |e|.
    hz_strata: Vec<[(u64, f64, f64); 6]>,
    fourier: Vec<FourierTally>,
    shadow: Vec<(ErrSum, f64, f64)>,
}

struct FourierTally {
    err: ErrStats,
    err_ref: ErrStats,
    lit_abs: f64,
    lit_n: u64,
    per_miss: u64,
    per_n: u64,
    encode_s: f64,
    encode_px: f64,
}

impl Tally {
    /// The additive sums the per-block figures come from, in a fixed order: per horizon
    /// method (n, Σe²); per variant (PER misses, PER n, Σ|lit error|, lit n); per shadow method
    /// (n, Σ|error|, wrong).
    fn sums(&self) -> Vec<f64> {
        let mut v = Vec::new();
        for (e, ..) in &self.hz {
            v.extend([e.n as f64, e.sum2]);
        }
        for f in &self.fourier {
            v.extend([f.per_miss as f64, f.per_n as f64, f.lit_abs, f.lit_n as f64]);
        }
        for (e, ..) in &self.shadow {
            v.extend([e.n as f64, e.abs_sum, e.wrong as f64]);
        }
        v
    }
}

/// One block's figures from the difference of two [`Tally::sums`]: per horizon method its
/// RMS; per variant its PER (%) and lit MAE; per shadow method its lit MAE and PER (%). NaN
/// where the block had no sample of it.
fn block_figures(d: &[f64], hz: usize, variants: usize, shadows: usize) -> Vec<f64> {
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
    let mut v = Vec::new();
    for m in 0..hz {
        v.push(ratio(d[2 * m + 1], d[2 * m]).sqrt());
    }
    let o = 2 * hz;
    for q in 0..variants {
        let x = &d[o + 4 * q..o + 4 * q + 4];
        v.push(100.0 * ratio(x[0], x[1]));
        v.push(ratio(x[2], x[3]));
    }
    let o = o + 4 * variants;
    for m in 0..shadows {
        let x = &d[o + 3 * m..o + 3 * m + 3];
        v.push(ratio(x[1], x[0]));
        v.push(100.0 * ratio(x[2], x[0]));
    }
    v
}

/// The standard error of the mean of each figure over the blocks (blocks as clusters: the
/// spread between blocks over √blocks); None with fewer than two blocks holding it.
fn standard_errors(per_block: &[Vec<f64>]) -> Vec<Option<f64>> {
    let k = per_block.first().map_or(0, |b| b.len());
    (0..k)
        .map(|i| {
            let x: Vec<f64> = per_block
                .iter()
                .map(|b| b[i])
                .filter(|v| v.is_finite())
                .collect();
            if x.len() < 2 {
                return None;
            }
            let n = x.len() as f64;
            let mean = x.iter().sum::<f64>() / n;
            let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
            Some((var / n).sqrt())
        })
        .collect()
}

/// Sizes of one block's work.
#[derive(Clone, Copy, Debug)]
struct Size {
    block: usize,
    pixels: usize,
    lit_pixels: usize,
}

/// The sizes a block may take, smallest first (the first block, which times the rest).
const SIZES: [Size; 6] = [
    Size {
        block: 24,
        pixels: 12,
        lit_pixels: 4,
    },
    Size {
        block: 32,
        pixels: 24,
        lit_pixels: 8,
    },
    Size {
        block: 64,
        pixels: 48,
        lit_pixels: 16,
    },
    Size {
        block: 96,
        pixels: 96,
        lit_pixels: 24,
    },
    Size {
        block: 128,
        pixels: 160,
        lit_pixels: 32,
    },
    Size {
        block: 192,
        pixels: 256,
        lit_pixels: 48,
    },
];

/// Make the report.
pub fn report(input: &Input, opts: &Options, progress: &dyn Progress) -> Result<Report> {
    let t_all = Instant::now();
    progress.start("report", opts.budget_s.ceil() as u64);
    let threads = rayon::current_num_threads();
    let ts = input.store.manifest();
    let levels = ts.layout.levels;
    let mut notes = Vec::new();
    let scene_level = input
        .scene
        .and_then(|s| s.horizon.levels.as_ref())
        .and_then(|l| l.iter().copied().max());
    let level = opts
        .level
        .or(scene_level)
        .unwrap_or(levels.saturating_sub(1));
    if level >= levels {
        return Err(Error::param(
            "level",
            format!("{level} is past the tileset's finest level {}", levels - 1),
        ));
    }
    let order = tile_order(input.store, level, opts.seed);
    if order.is_empty() {
        return Err(Error::invalid(
            &input.tileset,
            format!("no tiles at level {level}: give --level with a level the tileset has"),
        ));
    }
    let a = input
        .scene
        .map(|s| s.horizon.azimuths)
        .unwrap_or(DEFAULT_AZIMUTHS);
    let a = if a < 64 {
        notes.push(format!(
            "The scene's {a} azimuths are too few for K = 32 (K ≤ A/2 + 1): the report uses \
             {DEFAULT_AZIMUTHS}."
        ));
        DEFAULT_AZIMUTHS
    } else {
        a
    };
    let n = ts.layout.tile_size as i64;
    let points: Vec<(f64, f64)> = order
        .iter()
        .take(256)
        .map(|&id| {
            let (lat, lon) = penumbra::cube::dir_to_latlon(ts.layout.pixel_dir(id, n / 2, n / 2));
            (lat.to_degrees(), lon.to_degrees())
        })
        .collect();
    let (sun_el, sun_az) = suns_of(input.scene, &ts.body.name, &points, &mut notes);
    let shadow_el = if input.scene.and_then(|s| s.sun.as_ref()).is_some() {
        sun_el.clone()
    } else {
        DEFAULT_SHADOW_SUN_EL.to_vec()
    };
    let body = ts.body.name.clone();
    let radius_m = ts.body.radius_m;
    let sun_r = sun_radius_deg(sun_distance_au(&body).unwrap_or(1.0));
    let default_method = input.scene.map_or(HzMethod::Sweep, |s| s.horizon.method);
    let variants = Variant::all();
    let smethods = shadow_methods();
    let mut tally = Tally {
        hz: HZ_METHODS
            .iter()
            .map(|_| (ErrStats::new(1), 0.0, 0.0))
            .collect(),
        hz_strata: vec![[(0, 0.0, 0.0); 6]; HZ_METHODS.len()],
        fourier: variants
            .iter()
            .map(|_| FourierTally {
                err: ErrStats::new(1),
                err_ref: ErrStats::new(1),
                lit_abs: 0.0,
                lit_n: 0,
                per_miss: 0,
                per_n: 0,
                encode_s: 0.0,
                encode_px: 0.0,
            })
            .collect(),
        shadow: smethods
            .iter()
            .map(|_| (ErrSum::default(), 0.0, 0.0))
            .collect(),
    };
    let tile_size = ts.layout.tile_size as usize;
    let mut blocks = Vec::new();
    let mut per_block: Vec<Vec<f64>> = Vec::new();
    let mut pixels = 0usize;
    // The first block is small: its time sizes the rest so that about eight blocks fill the
    // budget (each at most an eighth of it: stopping before a block that would not fit leaves
    // at most that much unspent).
    let mut size_ix = 0usize;
    let mut per_unit: Option<f64> = None;
    let budget = opts.budget_s - WRITE_RESERVE_S;
    // Every tile once, then again with other blocks, until the budget is spent.
    let rounds = order
        .iter()
        .cycle()
        .take(order.len() * MAX_BLOCKS)
        .enumerate();
    if let Some((_, px)) = opts.fixed {
        size_ix = SIZES.iter().position(|s| s.block == px).ok_or_else(|| {
            Error::param("block_px", format!("{px} is not one of {}", block_sizes()))
        })?;
    }
    for (b_ix, &id) in rounds {
        let elapsed = t_all.elapsed().as_secs_f64();
        if let Some((count, _)) = opts.fixed {
            if blocks.len() >= count {
                break;
            }
        } else if let Some(u) = per_unit {
            // Choose the largest size whose predicted time fits an eighth of the budget, then
            // stop if even that does not fit what is left.
            let cost = |s: &Size| u * work_units(s, a, variants.len());
            size_ix = SIZES
                .iter()
                .rposition(|s| cost(s) <= budget / 8.0)
                .unwrap_or(0);
            if elapsed + cost(&SIZES[size_ix]) > budget {
                break;
            }
        }
        let size = SIZES[size_ix];
        let t_block = Instant::now();
        let before = tally.sums();
        let Some(info) = measure_block(
            input,
            id,
            size,
            a,
            (&sun_el, &shadow_el, &sun_az, sun_r),
            default_method,
            &variants,
            &smethods,
            opts.seed ^ b_ix as u64,
            &mut tally,
        )?
        else {
            continue;
        };
        let dt = t_block.elapsed().as_secs_f64();
        let d: Vec<f64> = tally
            .sums()
            .iter()
            .zip(&before)
            .map(|(a, b)| a - b)
            .collect();
        per_block.push(block_figures(
            &d,
            HZ_METHODS.len(),
            variants.len(),
            smethods.len(),
        ));
        pixels += info.strata.iter().sum::<usize>();
        progress.inc(dt.round() as u64);
        // Seconds per unit of work, from every block so far (the later ones weigh more).
        let u = dt / work_units(&size, a, variants.len());
        per_unit = Some(per_unit.map_or(u, |p| 0.5 * p + 0.5 * u));
        blocks.push(BlockInfo {
            seconds: dt,
            ..info
        });
        if blocks.len() >= MAX_BLOCKS {
            break;
        }
    }
    if blocks.is_empty() {
        return Err(Error::invalid(
            &input.tileset,
            format!("no tile of level {level} has data to sample"),
        ));
    }
    if blocks.len() < order.len() {
        notes.push(format!(
            "{} of level {level}'s {} tiles sampled within the budget.",
            blocks.len(),
            order.len()
        ));
    }
    progress.finish();
    let se = standard_errors(&per_block);
    let (nh, nv) = (HZ_METHODS.len(), variants.len());
    let mut hz_rows = horizon_rows(&tally, default_method);
    for (m, r) in hz_rows.iter_mut().enumerate() {
        r.se_rms_deg = se[m];
    }
    let mut f_rows = fourier_rows(&tally, &variants, tile_size);
    for (q, r) in f_rows.iter_mut().enumerate() {
        r.se_per_pct = se[nh + 2 * q];
        r.se_lit_mae = se[nh + 2 * q + 1];
    }
    let mut s_rows = shadow_rows(&tally, &smethods, a);
    for (m, r) in s_rows.iter_mut().enumerate() {
        r.se_lit_mae = se[nh + 2 * nv + 2 * m];
        r.se_per_pct = se[nh + 2 * nv + 2 * m + 1];
    }
    let mut r = Report {
        version: 1,
        tileset: input.tileset.display().to_string(),
        scene: input
            .scene
            .map(|s| format!("{} ({})", s.name, s.file.display())),
        body,
        radius_m,
        level,
        tile_size: tile_size as u32,
        azimuths: a,
        sun_elevations_deg: sun_el,
        shadow_sun_elevations_deg: shadow_el,
        sun_azimuths_deg: sun_az,
        sun_radius_deg: sun_r,
        max_per_pct: opts.max_per_pct,
        max_error_deg: opts.max_error_deg,
        budget_s: opts.budget_s,
        elapsed_s: 0.0,
        threads,
        seed: opts.seed,
        blocks,
        pixels,
        horizons: hz_rows,
        fourier: f_rows,
        shadows: s_rows,
        recommendations: Vec::new(),
        notes,
    };
    r.recommendations = recommend(&r);
    r.elapsed_s = t_all.elapsed().as_secs_f64();
    Ok(r)
}

/// Relative work of a block of `s` (arbitrary units: what scales with the block's pixels and
/// what with its sampled pixels), for sizing blocks from the first one's time.
fn work_units(s: &Size, a: usize, variants: usize) -> f64 {
    let block = (s.block * s.block * a) as f64 * (1.0 + 0.02 * variants as f64);
    let sampled = (s.pixels * a) as f64 * 60.0 + (s.lit_pixels * variants) as f64 * 2000.0;
    block + sampled
}

/// Sun elevations for the storage figures, for the shadow figures, compass azimuths (degrees),
/// and the sun's angular radius.
type SunSet<'a> = (&'a [f64], &'a [f64], &'a [f64], f64);

/// Measure one block of tile `id`; None when it has no data.
#[allow(clippy::too_many_arguments)]
fn measure_block(
    input: &Input,
    id: TileId,
    size: Size,
    a: usize,
    suns: SunSet,
    default_method: HzMethod,
    variants: &[Variant],
    smethods: &[ShadowWay],
    seed: u64,
    tally: &mut Tally,
) -> Result<Option<BlockInfo>> {
    let store = input.store;
    let (ctx, tile_rect) = horizon::report_context(store, id)?;
    let n = size.block.min(tile_rect.w);
    // The block: centred on a seeded pixel of the tile that has data (a tile may be mostly
    // empty where a regional DEM ends), kept inside the tile.
    let valid: Vec<usize> = (0..tile_rect.w * tile_rect.h)
        .filter(|&p| {
            ctx.heights
                [(tile_rect.y0 + p / tile_rect.w) * ctx.width + tile_rect.x0 + p % tile_rect.w]
                .is_finite()
        })
        .collect();
    if valid.is_empty() {
        return Ok(None);
    }
    let c = valid[(mix(seed ^ 0x5EED) % valid.len() as u64) as usize];
    let room = tile_rect.w - n;
    let (bx, by) = (
        (c % tile_rect.w).saturating_sub(n / 2).min(room),
        (c / tile_rect.w).saturating_sub(n / 2).min(room),
    );
    let rect = Rect {
        x0: tile_rect.x0 + bx,
        y0: tile_rect.y0 + by,
        w: n,
        h: n,
    };
    let (u, v) = ctx.uv((rect.x0 + n / 2) as f64, (rect.y0 + n / 2) as f64);
    let pixel_m = pixel_size_m(&ctx, rect);
    let (sample, strata) = stratified(&ctx, rect, pixel_m, size.pixels, seed);
    if sample.is_empty() {
        return Ok(None);
    }
    let case = Case::real(id.to_string(), "", pixel_m, ctx, rect);
    let threads = rayon::current_num_threads() as f64;
    let plane = n * n;
    // Horizons: the reference and the exact method at the sampled pixels (each pixel alone),
    // the fast and sweep methods over the whole block (their costs are per block).
    let mut maps: Vec<Vec<f32>> = Vec::new(); // per method: sample-major, a per pixel
    let mut block_maps: Vec<Option<Vec<f32>>> = Vec::new();
    for (m_ix, &m) in HZ_METHODS.iter().enumerate() {
        let t0 = Instant::now();
        let (vals, units, full) = match m {
            HzMethod::Exact => {
                // Over a contiguous sub-block: the method takes its first guesses from the row
                // and column neighbours' horizons, so a pixel alone would cost it several times
                // more. Its errors are those of the sampled pixels inside the sub-block.
                let e = n.min(EXACT_PX);
                // Around the first sampled pixel, so that it holds at least one.
                let (ex, ey) = (
                    sample[0].0.saturating_sub(e / 2).min(n - e),
                    sample[0].1.saturating_sub(e / 2).min(n - e),
                );
                let sub = Rect {
                    x0: rect.x0 + ex,
                    y0: rect.y0 + ey,
                    w: e,
                    h: e,
                };
                let full = horizons_with(&case.ctx, sub, a, m, horizon::DEFAULT_NEAR_PX);
                let v: Vec<f32> = sample
                    .iter()
                    .flat_map(|&(i, j)| {
                        let inside = (ex..ex + e).contains(&i) && (ey..ey + e).contains(&j);
                        let full = &full;
                        (0..a).map(move |k| {
                            if inside {
                                full[k * e * e + (j - ey) * e + i - ex]
                            } else {
                                f32::NAN
                            }
                        })
                    })
                    .collect();
                (v, (e * e * a) as f64, None)
            }
            HzMethod::Reference => {
                let v: Vec<f32> = sample
                    .iter()
                    .flat_map(|&(i, j)| {
                        let r1 = Rect {
                            x0: rect.x0 + i,
                            y0: rect.y0 + j,
                            w: 1,
                            h: 1,
                        };
                        horizons_with(&case.ctx, r1, a, m, horizon::DEFAULT_NEAR_PX)
                    })
                    .collect();
                (v, (sample.len() * a) as f64, None)
            }
            HzMethod::Fast | HzMethod::Sweep => {
                let full = horizons_with(&case.ctx, rect, a, m, horizon::DEFAULT_NEAR_PX);
                let v: Vec<f32> = sample
                    .iter()
                    .flat_map(|&(i, j)| (0..a).map(move |k| (k, j * n + i)))
                    .map(|(k, p)| full[k * plane + p])
                    .collect();
                (v, (plane * a) as f64, Some(full))
            }
        };
        let dt = t0.elapsed().as_secs_f64();
        tally.hz[m_ix].1 += dt * threads;
        tally.hz[m_ix].2 += units;
        maps.push(vals);
        block_maps.push(full);
    }
    let reference = &maps[0];
    // The sample lists its strata in order, `strata[k]` pixels each.
    let stratum_of: Vec<usize> = strata
        .iter()
        .enumerate()
        .flat_map(|(k, &c)| std::iter::repeat_n(k, c))
        .collect();
    for (m_ix, vals) in maps.iter().enumerate() {
        let e = &mut tally.hz[m_ix].0;
        let by = &mut tally.hz_strata[m_ix];
        for (q, (v, r)) in vals.iter().zip(reference).enumerate() {
            if v.is_finite() && r.is_finite() {
                let d = *v as f64 - *r as f64;
                e.add(d);
                let st = &mut by[stratum_of[q / a]];
                st.0 += 1;
                st.1 += d * d;
                st.2 = st.2.max(d.abs());
            }
        }
    }
    // The raw map the pyramids compress: the default method's over the block.
    let raw_ix = HZ_METHODS
        .iter()
        .position(|&m| m == default_method)
        .unwrap_or(3);
    let raw = block_maps[raw_ix]
        .take()
        .or_else(|| block_maps[3].take())
        .expect("sweep's block map");
    let (floor_enc, paper) = measure_fourier(
        &case,
        &raw,
        reference,
        &sample,
        size.lit_pixels,
        a,
        suns,
        variants,
        tally,
    );
    let baked = Baked {
        raw: &raw,
        floor_enc: &floor_enc,
        paper: &paper,
    };
    measure_shadows(&case, &baked, &sample, a, suns, (u, v), smethods, tally);
    Ok(Some(BlockInfo {
        tile: id.to_string(),
        x0: bx,
        y0: by,
        size: n,
        context: format!("{}×{}", case.ctx.width, case.ctx.height),
        strata,
        seconds: 0.0,
    }))
}

/// Metres per pixel at the block's centre (the gnomonic plane's scale there).
fn pixel_size_m(ctx: &HzContext, rect: Rect) -> f64 {
    let (cx, cy) = ((rect.x0 + rect.w / 2) as f64, (rect.y0 + rect.h / 2) as f64);
    let d0 = ctx.dir(cx, cy);
    let d1 = ctx.dir(cx + 1.0, cy);
    let dot = d0[0] * d1[0] + d0[1] * d1[1] + d0[2] * d1[2];
    dot.clamp(-1.0, 1.0).acos() * ctx.radius_m
}

/// A block's baked horizons for the lookup methods: the raw map, the encoder whose floor they
/// are clamped to, and the paper's pyramid (the default options, which that encoder has).
struct Baked<'a> {
    raw: &'a [f32],
    floor_enc: &'a Encoder,
    paper: &'a Pyramid,
}

/// Measure every storage variant on a block; the floor encoder (the default options) and the
/// paper's pyramid it made, for the shadow lookups.
#[allow(clippy::too_many_arguments)]
fn measure_fourier(
    case: &Case,
    raw: &[f32],
    reference: &[f32],
    sample: &[(usize, usize)],
    lit_pixels: usize,
    a: usize,
    (sun_el, _, _, sun_r): SunSet,
    variants: &[Variant],
    tally: &mut Tally,
) -> (Encoder, Pyramid) {
    let n = case.rect.w;
    let plane = n * n;
    let tile = case.block_tile();
    let floor_enc = Encoder::for_tiles(
        &FourierOptions::default(),
        n,
        0,
        a,
        case.ctx.radius_m,
        case.terrain_min_m,
    );
    // Floored raw and reference rows at the sampled pixels; which are valid.
    let mut raw_rows = vec![0.0f32; sample.len() * a];
    let mut ref_rows = vec![0.0f32; sample.len() * a];
    let mut valid = vec![false; sample.len()];
    for (q, &(i, j)) in sample.iter().enumerate() {
        let p = j * n + i;
        let h0 = tile.height[p];
        let ok = h0.is_finite()
            && (0..a).all(|k| raw[k * plane + p].is_finite() && reference[q * a + k].is_finite());
        valid[q] = ok;
        if ok {
            let fl = floor_enc.floor_deg(h0 as f64) as f32;
            for k in 0..a {
                raw_rows[q * a + k] = raw[k * plane + p].max(fl);
                ref_rows[q * a + k] = reference[q * a + k].max(fl);
            }
        }
    }
    // Suns as the Fourier bench sets them: plane azimuths between the classic maps' samples.
    let sn: Vec<(f64, f64)> = sun_el
        .iter()
        .flat_map(|&e| SUN_AZ.iter().map(move |&z| (z.to_radians(), e)))
        .collect();
    let frame = |i: usize, j: usize| {
        let (u, v) = case
            .ctx
            .uv((case.rect.x0 + i) as f64, (case.rect.y0 + j) as f64);
        Frame::at(case.ctx.face, u, v)
    };
    let lit_q: Vec<usize> = (0..sample.len())
        .filter(|&q| valid[q])
        .take(lit_pixels)
        .collect();
    let lit_truth: Vec<f64> = lit_q
        .par_iter()
        .flat_map_iter(|&q| {
            let f = frame(sample[q].0, sample[q].1);
            let row = &raw_rows[q * a..(q + 1) * a];
            let sn = &sn;
            sn.iter()
                .map(move |&(phi, e)| lit_exact(&f, phi, e, sun_r, &|t| interp(row, t)))
                .collect::<Vec<_>>()
        })
        .collect();
    let threads = rayon::current_num_threads() as f64;
    let mut paper = None;
    for (v_ix, &v) in variants.iter().enumerate() {
        let t0 = Instant::now();
        let (pyr, classic): (Option<Pyramid>, Option<(Vec<f32>, usize)>) = match v {
            Variant::Fourier { .. } => {
                let opts = v.options().expect("a Fourier variant");
                let enc = Encoder::for_tiles(&opts, n, 0, a, case.ctx.radius_m, case.terrain_min_m);
                let (p, _) = enc.encode(raw, &tile);
                std::hint::black_box(p.encode().len());
                (Some(p), None)
            }
            Variant::Classic(m) => {
                // What the encoder would store: every pixel's floored samples at 2πq/m in f16.
                let s: Vec<f32> = (0..plane)
                    .into_par_iter()
                    .flat_map_iter(|p| {
                        let fl = floor_enc.floor_deg(tile.height[p] as f64);
                        (0..m).map(move |q| {
                            let x = q as f64 * a as f64 / m as f64;
                            let k0 = x.floor() as usize % a;
                            let w = x - x.floor();
                            let v0 = (raw[k0 * plane + p] as f64).max(fl);
                            let v1 = (raw[((k0 + 1) % a) * plane + p] as f64).max(fl);
                            half::f16::from_f64(v0 + (v1 - v0) * w).to_f32()
                        })
                    })
                    .collect();
                (None, Some((s, m)))
            }
        };
        let enc_s = t0.elapsed().as_secs_f64();
        let hz = match (&pyr, &classic) {
            (Some(p), _) => Horizon::Fourier(p),
            (None, Some((s, m))) => Horizon::Classic(s, *m),
            _ => unreachable!("one of the two"),
        };
        let ft = &mut tally.fourier[v_ix];
        ft.encode_s += enc_s * threads;
        ft.encode_px += plane as f64;
        let mut buf = Vec::new();
        for (q, &(i, j)) in sample.iter().enumerate() {
            if !valid[q] {
                continue;
            }
            hz.load(n, i, j, &mut buf);
            for k in 0..a {
                let th = TAU * k as f64 / a as f64;
                let val = hz.at(&buf, th);
                ft.err.add(val - raw_rows[q * a + k] as f64);
                ft.err_ref.add(val - ref_rows[q * a + k] as f64);
            }
            let row = &raw_rows[q * a..(q + 1) * a];
            for &(phi, el) in &sn {
                let truth = interp(row, phi) > el;
                if (hz.at(&buf, phi) > el) != truth {
                    ft.per_miss += 1;
                }
                ft.per_n += 1;
            }
        }
        let lit: Vec<f64> = lit_q
            .par_iter()
            .flat_map_iter(|&q| {
                let (i, j) = sample[q];
                let f = frame(i, j);
                let mut buf = Vec::new();
                hz.load(n, i, j, &mut buf);
                let sn = &sn;
                sn.iter()
                    .map(|&(phi, e)| lit_exact(&f, phi, e, sun_r, &|t| hz.at(&buf, t)))
                    .collect::<Vec<_>>()
            })
            .collect();
        for (l, t) in lit.iter().zip(&lit_truth) {
            if l.is_finite() && t.is_finite() {
                ft.lit_abs += (l - t).abs();
                ft.lit_n += 1;
            }
        }
        if v.is_paper() {
            paper = pyr;
        }
    }
    (
        floor_enc,
        paper.expect("the paper's variant is among the variants"),
    )
}

#[allow(clippy::too_many_arguments)]
fn measure_shadows(
    case: &Case,
    baked: &Baked,
    sample: &[(usize, usize)],
    a: usize,
    (_, sun_el, sun_az, sun_r): SunSet,
    (u, v): (f64, f64),
    smethods: &[ShadowWay],
    tally: &mut Tally,
) {
    let n = case.rect.w;
    let plane = n * n;
    let rect = case.rect;
    let tr = Tracer::new(&case.ctx, case.terrain_min_m);
    let centre = Frame::at(case.ctx.face, u, v);
    let suns: Vec<Sun> = sun_el
        .iter()
        .flat_map(|&e| sun_az.iter().map(move |&z| (z, e)))
        .map(|(z, e)| Sun {
            dir: centre.direction(z, e),
            radius_deg: sun_r,
        })
        .collect();
    let threads = rayon::current_num_threads() as f64;
    let mut truth: Vec<f32> = Vec::new();
    for (m_ix, m) in smethods.iter().enumerate() {
        let t0 = Instant::now();
        let lit: Vec<f32> = match m {
            ShadowWay::SMap => suns
                .iter()
                .flat_map(|sun| {
                    let map = SMap::build(&case.ctx, sun.dir, rect, case.terrain_min_m);
                    let l = map.lit_region(&case.ctx);
                    sample
                        .iter()
                        .map(move |&(i, j)| l[j * n + i])
                        .collect::<Vec<_>>()
                })
                .collect(),
            _ => suns
                .par_iter()
                .flat_map_iter(|sun| {
                    let mut work = Work::default();
                    let mut coef = Vec::new();
                    sample
                        .iter()
                        .map(|&(i, j)| {
                            let (x, y) = (rect.x0 + i, rect.y0 + j);
                            match m {
                                ShadowWay::Trace(t) => tr.lit(x, y, sun, t, &mut work) as f32,
                                ShadowWay::Lookup(from_raw) => {
                                    let h0 = case.ctx.at(x as i64, y as i64);
                                    if h0.is_nan() {
                                        return f32::NAN;
                                    }
                                    let at = tr.sun_at(x, y, sun);
                                    let floor = baked.floor_enc.floor_deg(h0 as f64);
                                    let from = if *from_raw {
                                        measure::Baked::Raw(baked.raw, a)
                                    } else {
                                        measure::Baked::Pyramid(baked.paper)
                                    };
                                    lookup_lit(&at.frame, sun, &from, i, j, n, floor, &mut coef)
                                        as f32
                                }
                                ShadowWay::SMap => unreachable!("answered above"),
                            }
                        })
                        .collect::<Vec<_>>()
                })
                .collect(),
        };
        let dt = t0.elapsed().as_secs_f64();
        if m_ix == 0 {
            truth = lit.clone();
        }
        let t = &mut tally.shadow[m_ix];
        for (l, r) in lit.iter().zip(&truth) {
            t.0.add(*l, *r);
        }
        // SMap's cost is per block (it answers every pixel of it); the others' per answer.
        let answers = if matches!(m, ShadowWay::SMap) {
            (plane * suns.len()) as f64
        } else {
            lit.len() as f64
        };
        t.1 += dt * threads;
        t.2 += answers;
    }
}

fn horizon_rows(t: &Tally, default: HzMethod) -> Vec<HorizonRow> {
    let mut rows: Vec<HorizonRow> = HZ_METHODS
        .iter()
        .zip(&t.hz)
        .map(|(&m, (e, core_s, units))| HorizonRow {
            method: m.name().to_string(),
            samples: e.n,
            rms_deg: e.rms(),
            p99_deg: e.p99(),
            max_deg: e.max,
            core_ns: core_s / units.max(1.0) * 1e9,
            se_rms_deg: None,
            strata: STRATA
                .iter()
                .zip(&t.hz_strata[HZ_METHODS.iter().position(|&x| x == m).unwrap_or(0)])
                .map(|(name, &(n, sum2, max))| StratumFigures {
                    stratum: name.to_string(),
                    samples: n,
                    rms_deg: (sum2 / n.max(1) as f64).sqrt(),
                    max_deg: max,
                })
                .collect(),
            pareto: false,
            default: m == default,
        })
        .collect();
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| (r.core_ns, r.rms_deg)).collect();
    for (r, p) in rows.iter_mut().zip(pareto(&pts)) {
        r.pareto = p;
    }
    rows
}

fn fourier_rows(t: &Tally, variants: &[Variant], tile: usize) -> Vec<FourierRow> {
    let mut rows: Vec<FourierRow> = variants
        .iter()
        .zip(&t.fourier)
        .map(|(v, f)| FourierRow {
            variant: v.name(),
            bytes_per_tile: v.bytes_per_tile(tile),
            encode_ms_per_tile: f.encode_s / f.encode_px.max(1.0) * (tile * tile) as f64 * 1e3,
            rms_deg: f.err.rms(),
            p99_deg: f.err.p99(),
            max_deg: f.err.max,
            rms_ref_deg: f.err_ref.rms(),
            p99_ref_deg: f.err_ref.p99(),
            lit_mae: f.lit_abs / f.lit_n.max(1) as f64,
            per_pct: 100.0 * f.per_miss as f64 / f.per_n.max(1) as f64,
            se_per_pct: None,
            se_lit_mae: None,
            pareto: false,
            paper: v.is_paper(),
        })
        .collect();
    let pts: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.bytes_per_tile as f64, r.per_pct))
        .collect();
    for (r, p) in rows.iter_mut().zip(pareto(&pts)) {
        r.pareto = p;
    }
    rows
}

fn shadow_rows(t: &Tally, smethods: &[ShadowWay], a: usize) -> Vec<ShadowRow> {
    let mut rows: Vec<ShadowRow> = smethods
        .iter()
        .zip(&t.shadow)
        .map(|(m, (e, core_s, answers))| ShadowRow {
            method: m.label(a),
            hard: m.hard(),
            samples: e.n,
            lit_mae: e.mae(),
            lit_max: e.max,
            per_pct: e.per(),
            ms_per_mpx: core_s / answers.max(1.0) * 1e9,
            se_lit_mae: None,
            se_per_pct: None,
            pareto: false,
        })
        .collect();
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| (r.ms_per_mpx, r.lit_mae)).collect();
    for (r, p) in rows.iter_mut().zip(pareto(&pts)) {
        r.pareto = p;
    }
    rows
}

/// Which points (cost, error) no other point beats in both (lower is better in both).
pub fn pareto(pts: &[(f64, f64)]) -> Vec<bool> {
    pts.iter()
        .map(|&(c, e)| {
            c.is_finite()
                && e.is_finite()
                && !pts.iter().any(|&(c2, e2)| {
                    c2.is_finite() && e2.is_finite() && c2 <= c && e2 <= e && (c2 < c || e2 < e)
                })
        })
        .collect()
}

/// A figure's upper bound at about 97.5 % confidence: two standard errors above it (the
/// figure itself with one block). A recommendation meets the budget with its bound, so that
/// it holds on another sample of the same terrain.
fn upper(v: f64, se: Option<f64>) -> f64 {
    v + 2.0 * se.unwrap_or(0.0)
}

/// The cheapest choice per product whose figure meets the budget with two standard errors to
/// spare.
fn recommend(r: &Report) -> Vec<Recommendation> {
    let mut out = Vec::new();
    // Horizon method: the lowest cost whose RMS against the reference is within the budget.
    let hz = r
        .horizons
        .iter()
        .filter(|h| upper(h.rms_deg, h.se_rms_deg) <= r.max_error_deg)
        .min_by(|x, y| x.core_ns.total_cmp(&y.core_ns));
    out.push(Recommendation {
        product: "horizon method".into(),
        choice: hz.map(|h| h.method.clone()),
        why: match hz {
            Some(h) => format!(
                "fastest with RMS ≤ {} ° against the reference: {:.4}° at {:.0} core-ns per \
                 pixel·azimuth",
                r.max_error_deg, h.rms_deg, h.core_ns
            ),
            None => format!("no method is within {}° RMS", r.max_error_deg),
        },
        setting: hz.map(|h| format!("[horizon] method = \"{}\"", h.method)),
    });
    // Storage: the fewest bytes whose pixel error rate at the scene's suns is within budget
    // (the shadows it decides), among the variants a bake makes from a scene (the K of the
    // default multires f16 layout) and, beside it, among all; ties by encode time.
    let pick = |scene_only: bool| {
        r.fourier
            .iter()
            .filter(|f| !scene_only || f.variant.ends_with(" multires f16 plain"))
            .filter(|f| upper(f.per_pct, f.se_per_pct) <= r.max_per_pct)
            .min_by(|x, y| {
                x.bytes_per_tile
                    .cmp(&y.bytes_per_tile)
                    .then(x.encode_ms_per_tile.total_cmp(&y.encode_ms_per_tile))
            })
    };
    let why = |f: Option<&FourierRow>| match f {
        Some(f) => format!(
            "smallest with PER ≤ {} %: PER {:.3} %, lit MAE {:.4}, RMS {:.4}° against the raw \
             map ({:.4}° against the reference), {} bytes per tile",
            r.max_per_pct, f.per_pct, f.lit_mae, f.rms_deg, f.rms_ref_deg, f.bytes_per_tile
        ),
        None => format!("no variant is within PER {} %", r.max_per_pct),
    };
    let f = pick(true);
    out.push(Recommendation {
        product: "horizon storage".into(),
        choice: f.map(|f| f.variant.clone()),
        why: why(f),
        setting: f.map(|f| format!("[fourier] coefficients = {}", coefficients_of(&f.variant))),
    });
    let any = pick(false);
    out.push(Recommendation {
        product: "horizon storage, any layout".into(),
        choice: any.map(|f| f.variant.clone()),
        why: why(any),
        setting: None,
    });
    // Shadows: the fastest with PER within budget (the reference excluded: it is the truth).
    let s = r
        .shadows
        .iter()
        .skip(1)
        .filter(|s| upper(s.per_pct, s.se_per_pct) <= r.max_per_pct)
        .min_by(|x, y| x.ms_per_mpx.total_cmp(&y.ms_per_mpx));
    out.push(Recommendation {
        product: "shadow method".into(),
        choice: s.map(|s| s.method.clone()),
        why: match s {
            Some(s) => format!(
                "fastest with PER ≤ {} %: PER {:.3} %, lit MAE {:.4}, {:.0} core-ms per megapixel",
                r.max_per_pct, s.per_pct, s.lit_mae, s.ms_per_mpx
            ),
            None => format!("no method is within PER {} %", r.max_per_pct),
        },
        setting: None,
    });
    out
}

/// Largest report.json read back (bytes).
pub const MAX_REPORT_BYTES: u64 = 64 << 20;

/// A report.json read back (`penumbra report --from`). Errors: unreadable, too large, or not
/// a report of this version.
pub fn read(path: &Path) -> Result<Report> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.len() > MAX_REPORT_BYTES {
        return Err(Error::invalid(
            path,
            format!("{} bytes: larger than any report.json", meta.len()),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let r: Report = serde_json::from_slice(&bytes).map_err(|e| {
        Error::invalid(
            path,
            format!("not a report.json of this penumbra ({e}): run `penumbra report` again"),
        )
    })?;
    if r.version != 1 {
        return Err(Error::invalid(
            path,
            format!("report version {} (this penumbra writes 1)", r.version),
        ));
    }
    Ok(r)
}

/// The recommendations of `r` for another error budget (the measurements stay).
pub fn rebudget(r: &mut Report, max_per_pct: f64, max_error_deg: f64) {
    r.max_per_pct = max_per_pct;
    r.max_error_deg = max_error_deg;
    r.recommendations = recommend(r);
}

/// K of a Fourier variant's name ("F16 multires f16 plain" → 16).
pub fn coefficients_of(variant: &str) -> usize {
    variant
        .strip_prefix('F')
        .and_then(|s| s.split(' ').next())
        .and_then(|k| k.parse().ok())
        .unwrap_or(0)
}

/// Where the report's files go.
pub fn files(out: &Path) -> [PathBuf; 3] {
    ["report.html", "report.md", "report.json"].map(|f| out.join(f))
}
