//! The sweep method on another device (a GPU, `penumbra-gpu`): what the library prepares for
//! it and finishes after it, so that the device computes the same thing as
//! [`super::linesweep`] and nothing of the method's geometry is written twice.
//!
//! The library has no GPU code (docs/horizons.md, "On the GPU"): a device is anything that
//! implements [`SweepDevice`]; the `penumbra` command makes one from `--device` and hands it
//! to the horizon stage through [`super::HorizonOptions::device`].

use std::fmt;
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::geometry::{plane_azimuth, Context, Rect};
use super::linesweep::{self, near_steps, zero_steps};
use super::sweep::Lines;
use crate::error::{Error, Result};

/// Columns next to each pixel that the sweep searches on the pixel's own ray (the lines'
/// hulls cover the rest): the CPU's [`linesweep::NEAR_COLS`].
pub const NEAR_COLS: i64 = linesweep::NEAR_COLS;

/// How near (columns) the raster's edge must be on a pixel's ray for the part of it that the
/// line on the exit side never saw to be scanned on the ray itself.
pub const EDGE_SCAN_COLS: f64 = linesweep::EDGE_SCAN_COLS;

/// Where the horizon stage's sweep runs, as a user chooses it (`--device`, a scene's
/// `[horizon] device`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeviceChoice {
    /// The CPU (every method).
    Cpu,
    /// A GPU, a software one (Mesa's lavapipe) included; an error where there is none.
    Gpu,
    /// A hardware GPU where one is present, else the CPU.
    #[default]
    Auto,
}

impl DeviceChoice {
    pub const NAMES: [&'static str; 3] = ["cpu", "gpu", "auto"];

    pub fn parse(s: &str) -> Option<DeviceChoice> {
        match s {
            "cpu" => Some(DeviceChoice::Cpu),
            "gpu" => Some(DeviceChoice::Gpu),
            "auto" => Some(DeviceChoice::Auto),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            DeviceChoice::Cpu => "cpu",
            DeviceChoice::Gpu => "gpu",
            DeviceChoice::Auto => "auto",
        }
    }
}

/// A device that runs the sweep method's far field and near field: given a tile's context
/// and the per-azimuth [`SweepJob`]s, the horizons of `rect` in `a` plane azimuths (layout as
/// [`super::horizons`]), −90 exactly where a pixel found nothing (the library then searches
/// those with the reference) and NaN where the observer has no data.
pub trait SweepDevice: Send + Sync + fmt::Debug {
    /// What the device is, for the run key and the reports: two devices with the same key give
    /// the same bytes (e.g. `gpu: NVIDIA H100 (Vulkan, driver 550.54)`).
    fn key(&self) -> String;

    /// The horizons (see the trait); an error says what the device refused.
    fn sweep(
        &self,
        ctx: &Context,
        rect: Rect,
        a: usize,
        jobs: &[SweepJob],
    ) -> std::result::Result<Vec<f32>, String>;
}

/// A shared device handle, as the stage options carry it.
pub type SharedDevice = Arc<dyn SweepDevice>;

/// One near-field step along every ray of a direction: `k` columns out, up to four taps
/// (column and row offsets from the observer in (p, q), weight); `four`: inside a cell (the
/// four taps' weighted sum, a no-data tap leaves the step out), else on a grid line (two taps,
/// a no-data tap left out).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearStep {
    pub k: f64,
    pub taps: [(i64, i64, f32); 4],
    pub four: bool,
}

/// One azimuth (or a pair φ, φ + π that share the lines) of a tile's sweep: everything of the
/// method's geometry the device does not compute itself. The raster is read in (p, q) order:
/// p along the major axis of the look direction (x where `xmajor`), q along the other.
#[derive(Clone, Debug)]
pub struct SweepJob {
    /// The plane azimuth φ (radians).
    pub phi: f64,
    /// The output planes of φ and of φ + π (None: only φ).
    pub planes: [Option<usize>; 2],
    pub xmajor: bool,
    /// dq/dp of every ray and line.
    pub t: f64,
    /// φ's look direction along p (±1), and the sweep's step (−look).
    pub look: i64,
    pub step: i64,
    /// The observers in (p, q), half-open.
    pub rp: (i64, i64),
    pub rq: (i64, i64),
    /// The lines q = m + t·p (integer m) that bracket an observer.
    pub m_lo: i64,
    pub m_hi: i64,
    /// Per raster column p: t·p (moved onto a grid line within 1e-9 px) as its floor and the
    /// fraction above it, so that a device in f32 places every line and ray as the CPU does.
    pub col_floor: Vec<i32>,
    pub col_frac: Vec<f32>,
    /// The near-field steps of φ (0) and φ + π (1).
    pub steps: [Vec<NearStep>; 2],
    /// The zero-distance slope's neighbours of φ and φ + π: (step, weight) along p and along
    /// q, None where the direction has none there.
    pub zero: [[Option<(i64, f64)>; 2]; 2],
    /// |look direction's major component| (the ground distance per column is this times α).
    pub adp: f64,
    /// The gnomonic plane's (du, dv) for one column step along p (q moving t): with the
    /// pixel's (u, v, 1), the ray geometry tan γ_k = kα/(1 + kβ) follows.
    pub duv: (f64, f64),
}

/// The jobs of a tile: pairs (φ, φ + π) where `a` is even, else one azimuth each.
pub fn sweep_jobs(ctx: &Context, rect: Rect, a: usize) -> Vec<SweepJob> {
    let pairs = a % 2 == 0;
    let n = if pairs { a / 2 } else { a };
    (0..n)
        .map(|k| {
            let phi = plane_azimuth(k, a);
            let planes = [Some(k), pairs.then_some(k + a / 2)];
            job(ctx, rect, phi, planes)
        })
        .collect()
}

fn job(ctx: &Context, rect: Rect, phi: f64, planes: [Option<usize>; 2]) -> SweepJob {
    let lines = Lines::new(ctx, rect, phi);
    let np = if lines.xmajor { ctx.width } else { ctx.height };
    let (t, look) = (lines.t, -lines.step);
    let (col_floor, col_frac): (Vec<i32>, Vec<f32>) = (0..np)
        .map(|p| {
            let v = linesweep::grid(t * p as f64);
            let f = v.floor();
            (f as i32, (v - f) as f32)
        })
        .unzip();
    let to_steps = |s: i64| -> Vec<NearStep> {
        near_steps(t, s)
            .into_iter()
            .map(|(k, taps, four)| NearStep { k, taps, four })
            .collect()
    };
    let s = 2.0 / ctx.face_pixels;
    let (bx, by) = if lines.xmajor { (1.0, t) } else { (t, 1.0) };
    SweepJob {
        phi,
        planes,
        xmajor: lines.xmajor,
        t,
        look,
        step: lines.step,
        rp: (lines.rp0, lines.rp1),
        rq: (lines.rq0, lines.rq1),
        m_lo: lines.m_lo,
        m_hi: lines.m_hi,
        col_floor,
        col_frac,
        steps: [to_steps(look), to_steps(-look)],
        zero: [
            zero_steps(lines.xmajor, phi, 0),
            zero_steps(lines.xmajor, phi, 1),
        ],
        adp: lines.dp.abs(),
        duv: (s * bx, -s * by),
    }
}

/// The sweep method's horizons of `rect` over `ctx` in `a` plane azimuths, computed by
/// `device`: as [`super::horizons`] with [`super::Method::Sweep`] within the method's error
/// budget, not to the bit (docs/horizons.md, "On the GPU").
pub fn horizons_sweep_on(
    device: &dyn SweepDevice,
    ctx: &Context,
    rect: Rect,
    a: usize,
) -> Result<Vec<f32>> {
    let plane = rect.w * rect.h;
    assert!(rect.x0 + rect.w <= ctx.width && rect.y0 + rect.h <= ctx.height);
    if plane == 0 || a == 0 {
        return Ok(vec![0.0; plane * a]);
    }
    let jobs = sweep_jobs(ctx, rect, a);
    let mut out = device
        .sweep(ctx, rect, a, &jobs)
        .map_err(|why| Error::usage(format!("{}: {why}", device.key())))?;
    if out.len() != plane * a {
        return Err(Error::usage(format!(
            "{}: returned {} horizon samples for {plane} pixels × {a} azimuths",
            device.key(),
            out.len()
        )));
    }
    let hmax = ctx.max_height();
    out.par_chunks_mut(plane)
        .enumerate()
        .for_each(|(k, dst)| linesweep::fill_gaps(ctx, rect, hmax, plane_azimuth(k, a), dst));
    Ok(out)
}
