//! `penumbra-bench fourier` (issue 10's acceptance table): the error of Fourier-compressed
//! horizon maps against their bytes and compression time, on blocks of the shared real DEMs
//! and on synthetic stiff cases, next to classic horizon maps of 8 and 12 samples.
//!
//! Per case the raw maps are the fast method's at `--azimuths` plane azimuths; every variant is
//! compared with those maps floored as the encoder floors them (`Encoder::floor_deg`), over the
//! valid pixels only.

use std::f64::consts::TAU;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use rayon::prelude::*;
use serde::Serialize;

use penumbra::cube::Face;
use penumbra::fourier::stage::{Encoder, FourierOptions};
use penumbra::fourier::sun::{lit_fraction, sun_distance_au, sun_radius_deg, Frame, Model, Sun};
use penumbra::fourier::Reduce;
use penumbra::fourier::{Encoding, Layout, Pyramid, Sigma};
use penumbra::horizon::{horizons_with, Context as HzContext, Method, Rect, DEFAULT_NEAR_PX};

use crate::cases::real_cases;
use crate::common::{random_pixels, MOON_RADIUS_M};
use penumbra_cli::measure::{interp, lit_exact, sun_dir, Case, ErrStats, Horizon, Variant};

/// Tile size the bytes and times are reported for.
const TILE: usize = 256;
/// Sun elevations of the PER and lit-fraction metrics (degrees).
const SUN_EL: [f64; 3] = [1.0, 5.0, 15.0];
/// Sun plane azimuths (degrees): 17° + 45°·m, between the classic maps' samples.
const SUN_AZ: [f64; 8] = [17.0, 62.0, 107.0, 152.0, 197.0, 242.0, 287.0, 332.0];
/// Sun elevations of the NaN / range check (degrees): below the horizon, on it, at the zenith.
const CHECK_EL: [f64; 6] = [-2.0, 0.0, 1.0, 5.0, 15.0, 90.0];

pub struct Args {
    pub data: PathBuf,
    pub block: usize,
    pub azimuths: usize,
    pub markdown: bool,
    pub json: bool,
    pub svg: PathBuf,
    pub quick: bool,
    pub lit_pixels: usize,
    /// Only the cases whose name contains this (case-insensitive).
    pub only: Option<String>,
}

#[derive(Serialize)]
struct CaseRow {
    case: String,
    real: bool,
    body: String,
    pixel_m: f64,
    context: String,
    block: usize,
    valid_px: usize,
    horizon_s: f64,
    horizon_ms_per_tile: f64,
    terrain_min_m: f64,
    note: String,
}

#[derive(Serialize, Clone)]
struct Row {
    case: String,
    real: bool,
    variant: String,
    bytes_per_tile: usize,
    compress_ms_per_tile: f64,
    /// Compression time ÷ the horizon stage's time on the same block (%).
    share_pct: f64,
    rms_deg: f64,
    p99_deg: f64,
    max_deg: f64,
    /// Pixel error rate at each of SUN_EL, and over all 24 sun positions.
    per: [f64; 3],
    per_all: f64,
    lit_mae: f64,
    /// Model::Constant on this variant against the exact truth (the paper's configuration).
    lit_mae_constant: Option<f64>,
    /// NaN lit fractions among the metric's samples (should be 0).
    lit_nan: usize,
}

#[derive(Serialize)]
struct Check {
    check: String,
    value: String,
    pass: bool,
}

/// Rolling terrain: a sum of plane waves of wavelengths 8..2048 px with slopes of ~10°,
/// fixed seed.
fn rolling(x: f64, y: f64, pixel_m: f64, waves: &[(f64, f64, f64, f64)]) -> f32 {
    waves
        .iter()
        .map(|&(l, ca, sa, p)| 0.03 * l * pixel_m * ((x * ca + y * sa) * TAU / l + p).sin())
        .sum::<f64>() as f32
}

fn waves() -> Vec<(f64, f64, f64, f64)> {
    let mut state = 0x853C_49E6_748F_EA9Bu64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..9)
        .map(|o| {
            let l = 2048.0 / 2f64.powi(o);
            let a = next() * TAU;
            (l, a.cos(), a.sin(), next() * TAU)
        })
        .collect()
}

fn stiff_cases(block: usize) -> Vec<Case> {
    let n = block;
    let margin = n / 4;
    let cw = n + 2 * margin;
    let rect = Rect {
        x0: margin,
        y0: margin,
        w: n,
        h: n,
    };
    let centred = |pixel_m: f64| {
        let s = (2.0 * MOON_RADIUS_M / pixel_m).round();
        (s, ((s as i64 - cw as i64) / 2, (s as i64 - cw as i64) / 2))
    };
    let grid = |f: &dyn Fn(f64, f64) -> f32| -> Vec<f32> {
        (0..cw * cw)
            .map(|p| f((p % cw) as f64, (p / cw) as f64))
            .collect()
    };
    let mk = |name: &str,
              pixel_m: f64,
              face: Face,
              s: f64,
              origin: (i64, i64),
              heights: Vec<f32>,
              special: Vec<(usize, usize)>,
              note: String| {
        let terrain_min_m = heights.iter().fold(f64::INFINITY, |m, &v| m.min(v as f64));
        Case {
            name: name.into(),
            real: false,
            body: "moon",
            pixel_m,
            ctx: HzContext {
                face,
                face_pixels: s,
                origin,
                width: cw,
                height: cw,
                heights,
                radius_m: MOON_RADIUS_M,
            },
            rect,
            terrain_min_m,
            special,
            extra_frames: Vec::new(),
            note,
        }
    };
    let mid = n / 2;
    let mut out = Vec::new();
    // Cliff: a 1 km step along x = centre, across the whole context.
    let (s, o) = centred(20.0);
    let edge = (margin + mid) as f64;
    out.push(mk(
        "cliff (1 km step)",
        20.0,
        Face::Px,
        s,
        o,
        grid(&|x, _| if x >= edge { 1000.0 } else { 0.0 }),
        (0..n)
            .step_by(8)
            .flat_map(|j| [(mid - 1, j), (mid, j)])
            .collect(),
        "a 1 km step across the block at its centre column, flat on both sides, 20 m/px".into(),
    ));
    // Spike: one pixel 2 km high on flat ground at the block's centre.
    let (s, o) = centred(50.0);
    let sp = ((margin + mid) as f64, (margin + mid) as f64);
    out.push(mk(
        "1-px spike (2 km)",
        50.0,
        Face::Px,
        s,
        o,
        grid(&|x, y| if (x, y) == sp { 2000.0 } else { 0.0 }),
        (mid - 1..=mid + 1)
            .flat_map(|j| (mid - 1..=mid + 1).map(move |i| (i, j)))
            .collect(),
        "flat ground with one 2 km pixel at the block's centre, 50 m/px".into(),
    ));
    // Crater: a bowl of radius R = 0.35·block, 1 km deep, with a 300 m rim decaying as (R/r)³.
    let (s, o) = centred(50.0);
    let c = (margin + mid) as f64;
    let rr = 0.35 * n as f64;
    out.push(mk(
        "crater rim",
        50.0,
        Face::Px,
        s,
        o,
        grid(&|x, y| {
            let r = (x - c).hypot(y - c) / rr;
            (if r < 1.0 {
                -1000.0 + 1300.0 * r * r
            } else {
                300.0 / (r * r * r)
            }) as f32
        }),
        vec![
            (mid, mid),
            (mid + (rr as usize), mid),
            (mid, mid - (rr as usize)),
        ],
        format!(
            "a bowl of radius {:.1} km, 1 km deep, with a 300 m rim (parabolic inside, (R/r)³ \
             outside), 50 m/px",
            rr * 50.0 / 1000.0
        ),
    ));
    let wv = waves();
    // Pole: face Pz (the north pole at its centre), rolling terrain, 100 m/px; the context's
    // origin is chosen so that a pixel centre lies exactly on the pole when S is odd.
    let pixel_m = 100.0;
    let mut s = (2.0 * MOON_RADIUS_M / pixel_m).round();
    if s as i64 % 2 == 0 {
        s += 1.0;
    }
    // Pixel (x, y) of the raster has u = −1 + 2(ox + x + ½)/S: u = 0 at ox + x = (S − 1)/2.
    let pole_global = (s as i64 - 1) / 2;
    let o = (
        pole_global - (margin + mid) as i64,
        pole_global - (margin + mid) as i64,
    );
    let mut pole = mk(
        "pole (Pz centre)",
        pixel_m,
        Face::Pz,
        s,
        o,
        grid(&|x, y| rolling(x, y, pixel_m, &wv)),
        vec![(mid, mid)],
        "rolling terrain (plane waves of 0.8–205 km) on face Pz with block pixel (n/2, n/2) \
         exactly on the north pole, 100 m/px"
            .into(),
    );
    pole.extra_frames
        .push((Frame::at(Face::Pz, 0.0, 0.0), (mid, mid)));
    out.push(pole);
    // Corner: face Px's extended plane with u = v = 1 (the cube corner) at the block's centre.
    let s = (2.0 * MOON_RADIUS_M / pixel_m).round();
    let si = s as i64;
    // u = 1 at ox + x + ½ = S; v = 1 at oy + y + ½ = 0: the corner lies on the pixel edges
    // between block pixels mid − 1 and mid.
    let o = (si - (margin + mid) as i64, -((margin + mid) as i64));
    let mut corner = mk(
        "cube corner (Px, u = v = 1)",
        pixel_m,
        Face::Px,
        s,
        o,
        grid(&|x, y| rolling(x, y, pixel_m, &wv)),
        (mid - 1..=mid)
            .flat_map(|j| (mid - 1..=mid).map(move |i| (i, j)))
            .collect(),
        "rolling terrain on face Px's extended plane, the block centred on the corner u = v = 1 \
         (a quarter of it on the face, the rest past its edges), 100 m/px"
            .into(),
    );
    corner
        .extra_frames
        .push((Frame::at(Face::Px, 1.0, 1.0), (mid, mid)));
    out.push(corner);
    out
}

/// Running error statistics.
#[derive(Clone)]
/// Everything computed once per case that every variant is measured against.
struct Truth {
    n: usize,
    a: usize,
    /// Pixel-major floored raw maps (n²·a).
    floored: Vec<f32>,
    valid: Vec<bool>,
    /// Per pixel, the 24 sun positions' truth shadow bits (bit e·8 + m).
    shadow: Vec<u32>,
    /// Lit-fraction pixels (block coordinates), their frames, and the exact lit fractions
    /// (24 per pixel).
    lit_px: Vec<(usize, usize)>,
    frames: Vec<Frame>,
    lit_truth: Vec<f64>,
    sun_radius: f64,
}

fn suns() -> Vec<(f64, f64)> {
    SUN_EL
        .iter()
        .flat_map(|&e| SUN_AZ.iter().map(move |&a| (a.to_radians(), e)))
        .collect()
}

fn frame_of(case: &Case, i: usize, j: usize) -> Frame {
    let (u, v) = case
        .ctx
        .uv((case.rect.x0 + i) as f64, (case.rect.y0 + j) as f64);
    Frame::at(case.ctx.face, u, v)
}

fn truth(case: &Case, enc: &Encoder, elev: &[f32], a: usize, lit_pixels: usize) -> Truth {
    let n = case.rect.w;
    let plane = n * n;
    let h0: Vec<f32> = (0..plane)
        .map(|p| case.ctx.heights[(case.rect.y0 + p / n) * case.ctx.width + case.rect.x0 + p % n])
        .collect();
    let mut floored = vec![0.0f32; plane * a];
    let valid: Vec<bool> = floored
        .par_chunks_mut(a)
        .enumerate()
        .map(|(p, row)| {
            let ok = h0[p].is_finite() && (0..a).all(|k| elev[k * plane + p].is_finite());
            if ok {
                let fl = enc.floor_deg(h0[p] as f64) as f32;
                for (k, r) in row.iter_mut().enumerate() {
                    *r = elev[k * plane + p].max(fl);
                }
            }
            ok
        })
        .collect();
    let sn = suns();
    let shadow: Vec<u32> = floored
        .par_chunks(a)
        .map(|row| {
            sn.iter().enumerate().fold(0u32, |b, (q, &(phi, e))| {
                b | (((interp(row, phi) > e) as u32) << q)
            })
        })
        .collect();
    let lit_px: Vec<(usize, usize)> = random_pixels(n, n, plane)
        .into_iter()
        .filter(|&(i, j)| valid[j * n + i])
        .take(lit_pixels)
        .collect();
    let frames: Vec<Frame> = lit_px.iter().map(|&(i, j)| frame_of(case, i, j)).collect();
    let sun_radius = sun_radius_deg(sun_distance_au(case.body).unwrap_or(1.0));
    let lit_truth: Vec<f64> = lit_px
        .par_iter()
        .zip(&frames)
        .flat_map_iter(|(&(i, j), f)| {
            let row = &floored[(j * n + i) * a..(j * n + i + 1) * a];
            let sn = &sn;
            sn.iter()
                .map(move |&(phi, e)| lit_exact(f, phi, e, sun_radius, &|t| interp(row, t)))
        })
        .collect();
    Truth {
        n,
        a,
        floored,
        valid,
        shadow,
        lit_px,
        frames,
        lit_truth,
        sun_radius,
    }
}

struct Measured {
    err: ErrStats,
    lit_mae: f64,
    lit_nan: usize,
    lit_mae_constant: Option<f64>,
}

fn measure(t: &Truth, hz: &Horizon, constant_too: bool) -> Measured {
    let (n, a) = (t.n, t.a);
    let kmax = 32usize;
    // cos/sin(k θ_m) tables, k-major, for the reconstruction at the raw maps' azimuths.
    let (cos_t, sin_t): (Vec<f32>, Vec<f32>) = (0..kmax * a)
        .map(|q| {
            let (k, m) = (q / a, q % a);
            let th = TAU * (k * m) as f64 / a as f64;
            (th.cos() as f32, th.sin() as f32)
        })
        .unzip();
    let sn = suns();
    let err = (0..n)
        .into_par_iter()
        .fold(
            || (ErrStats::new(SUN_EL.len()), Vec::new(), vec![0.0f32; a]),
            |(mut e, mut buf, mut rec), j| {
                for i in 0..n {
                    let p = j * n + i;
                    if !t.valid[p] {
                        continue;
                    }
                    hz.load(n, i, j, &mut buf);
                    match hz {
                        Horizon::Fourier(_) => {
                            rec.fill(0.0);
                            for (k, c) in buf.iter().enumerate() {
                                let (cr, ci) = (c[0] as f32, c[1] as f32);
                                let (cs, sn) =
                                    (&cos_t[k * a..(k + 1) * a], &sin_t[k * a..(k + 1) * a]);
                                for m in 0..a {
                                    rec[m] += cr * cs[m] - ci * sn[m];
                                }
                            }
                        }
                        Horizon::Classic(..) => {
                            for (m, r) in rec.iter_mut().enumerate() {
                                *r = hz.at(&buf, TAU * m as f64 / a as f64) as f32;
                            }
                        }
                    }
                    let row = &t.floored[p * a..(p + 1) * a];
                    for m in 0..a {
                        e.add(rec[m] as f64 - row[m] as f64);
                    }
                    let truth = t.shadow[p];
                    for (q, &(phi, el)) in sn.iter().enumerate() {
                        let sh = hz.at(&buf, phi) > el;
                        if sh != ((truth >> q) & 1 == 1) {
                            e.per_miss[q / SUN_AZ.len()] += 1;
                        }
                    }
                    e.per_n += 1;
                }
                (e, buf, rec)
            },
        )
        .map(|(e, _, _)| e)
        .reduce(|| ErrStats::new(SUN_EL.len()), ErrStats::merge);
    let models: &[Model] = if constant_too {
        &[Model::Exact, Model::Constant]
    } else {
        &[Model::Exact]
    };
    let per_model: Vec<(f64, usize)> = models
        .iter()
        .map(|&model| {
            t.lit_px
                .par_iter()
                .zip(&t.frames)
                .enumerate()
                .map(|(q, (&(i, j), f))| {
                    let mut buf = Vec::new();
                    hz.load(n, i, j, &mut buf);
                    let mut s = (0.0, 0usize);
                    for (r, &(phi, el)) in sn.iter().enumerate() {
                        let sun = Sun {
                            dir: sun_dir(f, phi, el),
                            radius_deg: t.sun_radius,
                        };
                        let l = if model == Model::Exact {
                            lit_exact(f, phi, el, t.sun_radius, &|th| hz.at(&buf, th))
                        } else {
                            lit_fraction(f, &sun, model, &|th| hz.at(&buf, th))
                        };
                        let tr = t.lit_truth[q * sn.len() + r];
                        if l.is_nan() || tr.is_nan() {
                            s.1 += 1;
                        } else {
                            s.0 += (l - tr).abs();
                        }
                    }
                    s
                })
                .reduce(|| (0.0, 0), |x, y| (x.0 + y.0, x.1 + y.1))
        })
        .collect();
    let samples = (t.lit_px.len() * sn.len()).max(1) as f64;
    Measured {
        err,
        lit_mae: per_model[0].0 / samples,
        lit_nan: per_model[0].1,
        lit_mae_constant: per_model.get(1).map(|m| m.0 / samples),
    }
}

/// Classic maps: floored raw samples at 2πm/N, rounded to f16, pixel-major.
fn classic(t: &Truth, m: usize) -> Vec<f32> {
    let a = t.a;
    t.floored
        .par_chunks(a)
        .flat_map_iter(|row| {
            (0..m)
                .map(move |q| half::f16::from_f64(interp(row, TAU * q as f64 / m as f64)).to_f32())
        })
        .collect()
}

/// NaN or out-of-range lit fractions of the paper's horizon on a stiff case: every model, suns
/// at CHECK_EL × SUN_AZ, on the lit pixels, the special pixels and the extra frames.
fn stiff_check(case: &Case, t: &Truth, p: &Pyramid) -> (usize, usize) {
    let n = t.n;
    let mut frames: Vec<(Frame, (usize, usize))> = t
        .lit_px
        .iter()
        .take(128)
        .chain(&case.special)
        .filter(|&&(i, j)| t.valid[j * n + i])
        .map(|&(i, j)| (frame_of(case, i, j), (i, j)))
        .collect();
    frames.extend(case.extra_frames.iter().cloned());
    let hz = Horizon::Fourier(p);
    frames
        .par_iter()
        .map(|(f, (i, j))| {
            let mut buf = Vec::new();
            hz.load(n, *i, *j, &mut buf);
            let mut bad = 0;
            let mut total = 0;
            for &el in &CHECK_EL {
                for &az in &SUN_AZ {
                    let sun = Sun {
                        dir: sun_dir(f, az.to_radians(), el),
                        radius_deg: t.sun_radius,
                    };
                    for model in Model::ALL {
                        let l = lit_fraction(f, &sun, model, &|th| hz.at(&buf, th));
                        total += 1;
                        if !(0.0..=1.0).contains(&l) {
                            bad += 1;
                        }
                    }
                }
            }
            (bad, total)
        })
        .reduce(|| (0, 0), |x, y| (x.0 + y.0, x.1 + y.1))
}

pub fn run(args: Args, quiet: bool) -> Result<()> {
    let a = args.azimuths;
    if a < 64 {
        bail!("--azimuths must be at least 64 (32 coefficients need A/2 + 1 ≥ 32)");
    }
    let block = if args.quick { 64 } else { args.block };
    if block < 16 {
        bail!("--block must be at least 16");
    }
    let lit_pixels = if args.quick {
        args.lit_pixels.min(64)
    } else {
        args.lit_pixels
    };
    let say = |m: String| {
        if !quiet {
            eprintln!("bench fourier: {m}");
        }
    };
    let t_all = Instant::now();
    let (mut cases, mut notes) = real_cases(&args.data, block, &say)?;
    cases.extend(stiff_cases(block));
    if let Some(o) = &args.only {
        let o = o.to_lowercase();
        cases.retain(|c| c.name.to_lowercase().contains(&o));
    }
    let variants = Variant::all();
    let threads = rayon::current_num_threads();
    let mut case_rows = Vec::new();
    let mut rows: Vec<Row> = Vec::new();
    let mut checks: Vec<Check> = Vec::new();
    let mut stiff_bad = Vec::new();
    for case in &cases {
        let n = case.rect.w;
        say(format!(
            "{}: horizons of {n}² observers in a {}×{} context, {a} azimuths",
            case.name, case.ctx.width, case.ctx.height
        ));
        let t0 = Instant::now();
        let elev = horizons_with(&case.ctx, case.rect, a, Method::Fast, DEFAULT_NEAR_PX);
        let t_h = t0.elapsed().as_secs_f64();
        let per_tile = (TILE * TILE) as f64 / (n * n) as f64;
        let tile = case.block_tile();
        let floor_enc = Encoder::for_tiles(
            &FourierOptions::default(),
            n,
            0,
            a,
            case.ctx.radius_m,
            case.terrain_min_m,
        );
        let t = truth(case, &floor_enc, &elev, a, lit_pixels);
        let valid_px = t.valid.iter().filter(|&&v| v).count();
        case_rows.push(CaseRow {
            case: case.name.clone(),
            real: case.real,
            body: case.body.into(),
            pixel_m: case.pixel_m,
            context: format!("{}×{}", case.ctx.width, case.ctx.height),
            block: n,
            valid_px,
            horizon_s: t_h,
            horizon_ms_per_tile: t_h * per_tile * 1e3,
            terrain_min_m: case.terrain_min_m,
            note: case.note.clone(),
        });
        say(format!(
            "{}: horizons {t_h:.2} s; {} variants",
            case.name,
            variants.len()
        ));
        let (mut t_enc, mut t_meas) = (0.0, 0.0);
        for &v in &variants {
            let tv = Instant::now();
            let (t_c, m) = match v {
                Variant::Fourier { .. } => {
                    let opts = v.options().expect("a Fourier variant");
                    let enc =
                        Encoder::for_tiles(&opts, n, 0, a, case.ctx.radius_m, case.terrain_min_m);
                    let mut best = f64::INFINITY;
                    let mut pyr = None;
                    for _ in 0..3 {
                        let t0 = Instant::now();
                        let (p, _) = enc.encode(&elev, &tile);
                        let file = p.encode();
                        let dt = t0.elapsed().as_secs_f64();
                        std::hint::black_box(file.len());
                        best = best.min(dt);
                        pyr = Some(p);
                    }
                    let pyr = pyr.expect("three runs");
                    t_enc += tv.elapsed().as_secs_f64();
                    let m = measure(&t, &Horizon::Fourier(&pyr), v.is_paper());
                    if v.is_paper() && !case.real {
                        stiff_bad.push((case.name.clone(), stiff_check(case, &t, &pyr)));
                    }
                    (best, m)
                }
                Variant::Classic(nc) => {
                    let mut best = f64::INFINITY;
                    let mut s = Vec::new();
                    for _ in 0..3 {
                        let t0 = Instant::now();
                        s = classic(&t, nc);
                        best = best.min(t0.elapsed().as_secs_f64());
                    }
                    (best, measure(&t, &Horizon::Classic(&s, nc), false))
                }
            };
            t_meas += tv.elapsed().as_secs_f64();
            let per_n = m.err.per_n.max(1) as f64 * SUN_AZ.len() as f64;
            rows.push(Row {
                case: case.name.clone(),
                real: case.real,
                variant: v.name(),
                bytes_per_tile: v.bytes_per_tile(TILE),
                compress_ms_per_tile: t_c * per_tile * 1e3,
                share_pct: 100.0 * t_c / t_h,
                rms_deg: m.err.rms(),
                p99_deg: m.err.p99(),
                max_deg: m.err.max,
                per: [
                    m.err.per_miss[0] as f64 / per_n,
                    m.err.per_miss[1] as f64 / per_n,
                    m.err.per_miss[2] as f64 / per_n,
                ],
                per_all: m.err.per_miss.iter().sum::<u64>() as f64 / (3.0 * per_n),
                lit_mae: m.lit_mae,
                lit_mae_constant: m.lit_mae_constant,
                lit_nan: m.lit_nan,
            });
        }
        say(format!(
            "{}: done (encoding {t_enc:.0} s, measuring {:.0} s; {:.0} s since the start)",
            case.name,
            t_meas - t_enc,
            t_all.elapsed().as_secs_f64()
        ));
    }

    // Goal checks.
    let paper = Variant::Fourier {
        k: 16,
        encoding: Encoding::F16,
        layout: Layout::Multires,
        sigma: Sigma::None,
        reduce: Reduce::Mean,
    }
    .name();
    let find = |c: &str, v: &str| rows.iter().find(|r| r.case == c && r.variant == v);
    for c in cases.iter().filter(|c| c.real) {
        if let (Some(f), Some(cl)) = (find(&c.name, &paper), find(&c.name, "classic 12")) {
            checks.push(Check {
                check: format!("{paper} PER ≤ classic 12 PER, {}", c.name),
                value: format!(
                    "{:.3} % vs {:.3} % (1°/5°/15°: {:.3}/{:.3}/{:.3} % vs {:.3}/{:.3}/{:.3} %)",
                    100.0 * f.per_all,
                    100.0 * cl.per_all,
                    100.0 * f.per[0],
                    100.0 * f.per[1],
                    100.0 * f.per[2],
                    100.0 * cl.per[0],
                    100.0 * cl.per[1],
                    100.0 * cl.per[2]
                ),
                pass: f.per_all <= cl.per_all,
            });
        }
    }
    for c in &cases {
        if let Some(f) = find(&c.name, &paper) {
            let worst = rows
                .iter()
                .filter(|r| r.case == c.name && r.variant.starts_with('F'))
                .max_by(|x, y| x.share_pct.total_cmp(&y.share_pct))
                .expect("variants");
            checks.push(Check {
                check: format!(
                    "compression time share ≤ 10 % of the horizon time, {}",
                    c.name
                ),
                value: format!(
                    "{paper}: {:.2} % (worst variant {}: {:.2} %)",
                    f.share_pct, worst.variant, worst.share_pct
                ),
                pass: f.share_pct <= 10.0,
            });
        }
    }
    let (bad, total) = stiff_bad
        .iter()
        .fold((0, 0), |x, (_, (b, t))| (x.0 + b, x.1 + t));
    let metric_nan: usize = rows.iter().map(|r| r.lit_nan).sum();
    checks.push(Check {
        check: "NaN or out-of-range lit fractions: count".into(),
        value: format!(
            "{bad} of {total} ({paper} horizon, all four models, suns at {CHECK_EL:?}° × 8 \
             azimuths, on every stiff case: {}); NaN in the metrics' samples: {metric_nan}",
            stiff_bad
                .iter()
                .map(|(c, (b, t))| format!("{c} {b}/{t}"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        pass: bad == 0 && metric_nan == 0,
    });

    let wall = t_all.elapsed().as_secs_f64();
    notes.push(format!(
        "Real DEMs: each map's grid laid on face +X's gnomonic plane at its own pixel size (as \
         `bench horizon`), the {block}² block at the map's centre (the place every DEM has; no \
         per-DEM hand-picking), the context the block plus the horizon's reach 2·√(2R·relief) \
         clipped to the map. Raw maps: fast method, {a} azimuths, near field {DEFAULT_NEAR_PX} px; \
         horizon time = that call on all {threads} threads."
    ));
    notes.push(format!(
        "Errors against the raw maps floored as the encoder floors them (max(raw, \
         Encoder::floor_deg(h₀))), at the {a} azimuths, over the valid pixels; Fourier variants \
         through Pyramid::coefficients_at at the pixel centre (bilinear per group, as a GPU); \
         classic N = floored raw maps linearly interpolated at 360°·m/N, rounded to f16, \
         linearly interpolated back. p99 from a histogram (1e-4° bins below 2°)."
    ));
    notes.push(format!(
        "PER: sun elevations {SUN_EL:?}° × plane azimuths {SUN_AZ:?}°, shadowed when the horizon \
         at the sun azimuth > its elevation; truth = the floored raw map linearly interpolated. \
         Lit MAE: Model::Exact on the variant vs Model::Exact on the interpolated raw map, {lit_pixels} \
         fixed pseudo-random valid pixels per case × the same 24 suns, sun radius from \
         sun_radius_deg(sun_distance_au(body)); the constant column is Model::Constant on {paper}."
    ));
    notes.push(format!(
        "Bytes per {TILE}² tile from pyramid::file_bytes({TILE}, K, layout) (header and checksum \
         included); classic N·2 bytes per pixel. Compression time = best of 3 of Encoder::encode + \
         Pyramid::encode (classic: sampling + f16 rounding), on all {threads} threads, scaled to \
         {TILE}² pixels; share = compression ÷ horizon time of the same block."
    ));
    notes.push(format!("Whole run: {wall:.0} s on {threads} threads."));

    // Averages over the real DEMs.
    let real_names: Vec<&str> = cases
        .iter()
        .filter(|c| c.real)
        .map(|c| c.name.as_str())
        .collect();
    let summary: Vec<Row> = variants
        .iter()
        .map(|v| {
            let rs: Vec<&Row> = rows
                .iter()
                .filter(|r| r.real && r.variant == v.name())
                .collect();
            let k = rs.len().max(1) as f64;
            let mean = |f: &dyn Fn(&Row) -> f64| rs.iter().map(|r| f(r)).sum::<f64>() / k;
            Row {
                case: "mean of real DEMs".into(),
                real: true,
                variant: v.name(),
                bytes_per_tile: v.bytes_per_tile(TILE),
                compress_ms_per_tile: mean(&|r| r.compress_ms_per_tile),
                share_pct: mean(&|r| r.share_pct),
                rms_deg: mean(&|r| r.rms_deg),
                p99_deg: mean(&|r| r.p99_deg),
                max_deg: rs.iter().map(|r| r.max_deg).fold(0.0, f64::max),
                per: [
                    mean(&|r| r.per[0]),
                    mean(&|r| r.per[1]),
                    mean(&|r| r.per[2]),
                ],
                per_all: mean(&|r| r.per_all),
                lit_mae: mean(&|r| r.lit_mae),
                lit_mae_constant: if v.is_paper() {
                    Some(mean(&|r| r.lit_mae_constant.unwrap_or(f64::NAN)))
                } else {
                    None
                },
                lit_nan: rs.iter().map(|r| r.lit_nan).sum(),
            }
        })
        .collect();
    if !real_names.is_empty() {
        std::fs::write(&args.svg, svg(&summary, &real_names))?;
        notes.push(format!("Figure written to {}.", args.svg.display()));
    }

    if args.json {
        return penumbra_cli::output::print_json(&serde_json::json!({
            "azimuths": a,
            "block": block,
            "threads": threads,
            "wall_s": wall,
            "cases": case_rows,
            "summary_real": summary,
            "rows": rows,
            "checks": checks,
            "notes": notes,
        }));
    }
    print_tables(
        &case_rows,
        &summary,
        &rows,
        &checks,
        &notes,
        &paper,
        args.markdown,
    );
    Ok(())
}

fn print_tables(
    cases: &[CaseRow],
    summary: &[Row],
    rows: &[Row],
    checks: &[Check],
    notes: &[String],
    paper: &str,
    md: bool,
) {
    if md {
        println!("### Cases\n");
        println!("| case | body | m/px | context | block | valid px | horizon s | horizon ms per 256² | lowest terrain m | what |");
        println!("|---|---|---:|---|---:|---:|---:|---:|---:|---|");
    }
    for c in cases {
        if md {
            println!(
                "| {} | {} | {:.1} | {} | {} | {} | {:.2} | {:.0} | {:.0} | {} |",
                c.case,
                c.body,
                c.pixel_m,
                c.context,
                c.block,
                c.valid_px,
                c.horizon_s,
                c.horizon_ms_per_tile,
                c.terrain_min_m,
                c.note
            );
        } else {
            println!(
                "{:<28} {:<6} {:>8.1} m/px  context {:>10}  block {:>4}  valid {:>6}  horizons {:>7.2} s  ({:.0} ms per 256²)",
                c.case, c.body, c.pixel_m, c.context, c.block, c.valid_px, c.horizon_s, c.horizon_ms_per_tile
            );
        }
    }
    println!();
    if md {
        println!("### Goal checks\n");
    }
    for c in checks {
        println!(
            "{}{}: {} — {}",
            if md { "- " } else { "" },
            c.check,
            c.value,
            if c.pass { "**pass**" } else { "**FAIL**" }
        );
    }
    println!();
    let header = |title: &str| {
        if md {
            println!("### {title}\n");
            println!("| case | variant | bytes per 256² | compress ms per 256² | share of horizon time | RMS ° | p99 ° | max ° | PER 1° | PER 5° | PER 15° | PER all | lit MAE (exact) | lit MAE (constant) |");
            println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        } else {
            println!("{title}");
        }
    };
    let line = |r: &Row| {
        let bold = r.variant == paper || r.variant.starts_with("classic");
        let name = if md && bold {
            format!("**{}**", r.variant)
        } else {
            r.variant.clone()
        };
        let cst = r
            .lit_mae_constant
            .map_or("–".to_string(), |v| format!("{v:.5}"));
        if md {
            println!(
                "| {} | {} | {} | {:.1} | {:.2} % | {:.4} | {:.4} | {:.3} | {:.3} % | {:.3} % | {:.3} % | {:.3} % | {:.5} | {} |",
                r.case,
                name,
                r.bytes_per_tile,
                r.compress_ms_per_tile,
                r.share_pct,
                r.rms_deg,
                r.p99_deg,
                r.max_deg,
                100.0 * r.per[0],
                100.0 * r.per[1],
                100.0 * r.per[2],
                100.0 * r.per_all,
                r.lit_mae,
                cst
            );
        } else {
            println!(
                "{:<28} {:<28} {:>9} B {:>8.1} ms {:>6.2} %  RMS {:.4}°  p99 {:.4}°  max {:.3}°  PER {:.3}/{:.3}/{:.3} all {:.3} %  lit MAE {:.5} ({cst})",
                r.case,
                name,
                r.bytes_per_tile,
                r.compress_ms_per_tile,
                r.share_pct,
                r.rms_deg,
                r.p99_deg,
                r.max_deg,
                100.0 * r.per[0],
                100.0 * r.per[1],
                100.0 * r.per[2],
                100.0 * r.per_all,
                r.lit_mae,
            );
        }
    };
    if cases.iter().any(|c| c.real) {
        header("Every variant, averaged over the real DEMs (max: the largest)");
        summary.iter().for_each(line);
        println!();
    }
    header(&format!("{paper} against the classic maps, per case"));
    for r in rows
        .iter()
        .filter(|r| r.variant == paper || r.variant.starts_with("classic"))
    {
        line(r);
    }
    println!();
    if md {
        println!("<details><summary>Every case × every variant</summary>\n");
    }
    header("Every case × every variant");
    rows.iter().for_each(line);
    if md {
        println!("\n</details>");
    }
    println!();
    for n in notes {
        println!("{}{n}", if md { "- " } else { "" });
    }
}

/// The x value of a row in one panel.
type XOf = Box<dyn Fn(&Row) -> f64>;

/// Two panels by hand: RMS error (log) against bytes per tile (log) and against compression
/// time per tile (log), one marker per variant (means over the real DEMs).
fn svg(summary: &[Row], dems: &[&str]) -> String {
    let (pw, ph) = (420.0, 320.0);
    let (ml, mr, mt, mb) = (70.0, 20.0, 40.0, 50.0);
    let width = 2.0 * (ml + pw + mr);
    let legend_h = 110.0;
    let height = mt + ph + mb + legend_h;
    let mut s = String::new();
    s += &format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width}\" height=\"{height}\" \
         viewBox=\"0 0 {width} {height}\" font-family=\"sans-serif\" font-size=\"12\">\n\
         <rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n"
    );
    let ys: Vec<f64> = summary
        .iter()
        .map(|r| r.rms_deg)
        .filter(|v| *v > 0.0)
        .collect();
    let (ylo, yhi) = log_range(&ys);
    let colour = |r: &Row| -> &'static str {
        match r.variant.split(' ').next().unwrap_or("") {
            "F4" => "#1b9e77",
            "F8" => "#d95f02",
            "F16" => "#7570b3",
            "F32" => "#e7298a",
            _ => "#000000",
        }
    };
    let panels: [(&str, XOf); 2] = [
        (
            "bytes per 256² tile",
            Box::new(|r: &Row| r.bytes_per_tile as f64),
        ),
        (
            "compression time per 256² tile (ms)",
            Box::new(|r: &Row| r.compress_ms_per_tile),
        ),
    ];
    for (pi, (xlabel, xf)) in panels.iter().enumerate() {
        let x0 = pi as f64 * (ml + pw + mr) + ml;
        let xs: Vec<f64> = summary.iter().map(xf).filter(|v| *v > 0.0).collect();
        let (xlo, xhi) = log_range(&xs);
        let px = |v: f64| x0 + (v.log10() - xlo) / (xhi - xlo) * pw;
        let py = |v: f64| mt + ph - (v.log10() - ylo) / (yhi - ylo) * ph;
        s += &format!(
            "<rect x=\"{x0}\" y=\"{mt}\" width=\"{pw}\" height=\"{ph}\" fill=\"none\" stroke=\"#333\"/>\n"
        );
        for (lo, hi, f, horiz) in [
            (xlo, xhi, &px as &dyn Fn(f64) -> f64, false),
            (ylo, yhi, &py, true),
        ] {
            let mut e = lo.floor() as i32;
            while (e as f64) <= hi.ceil() {
                for m in 1..10 {
                    let v = m as f64 * 10f64.powi(e);
                    let lv = v.log10();
                    if lv < lo - 1e-9 || lv > hi + 1e-9 {
                        continue;
                    }
                    let c = f(v);
                    let major = m == 1;
                    let stroke = if major { "#bbb" } else { "#eee" };
                    if horiz {
                        s += &format!("<line x1=\"{x0}\" x2=\"{}\" y1=\"{c:.1}\" y2=\"{c:.1}\" stroke=\"{stroke}\"/>\n", x0 + pw);
                        if major || (hi - lo) < 1.5 && (m == 2 || m == 5) {
                            s += &format!(
                                "<text x=\"{}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>\n",
                                x0 - 4.0,
                                c + 4.0,
                                tick(v)
                            );
                        }
                    } else {
                        s += &format!("<line x1=\"{c:.1}\" x2=\"{c:.1}\" y1=\"{mt}\" y2=\"{}\" stroke=\"{stroke}\"/>\n", mt + ph);
                        if major || (hi - lo) < 1.5 && (m == 2 || m == 5) {
                            s += &format!(
                                "<text x=\"{c:.1}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n",
                                mt + ph + 16.0,
                                tick(v)
                            );
                        }
                    }
                }
                e += 1;
            }
        }
        s += &format!(
            "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{xlabel} (log)</text>\n",
            x0 + pw / 2.0,
            mt + ph + 36.0
        );
        s += &format!(
            "<text transform=\"translate({},{}) rotate(-90)\" text-anchor=\"middle\">RMS horizon error, degrees (log)</text>\n",
            x0 - 52.0,
            mt + ph / 2.0
        );
        for r in summary {
            let (x, y) = (xf(r), r.rms_deg);
            if x <= 0.0 || y <= 0.0 {
                continue;
            }
            s += &marker(r, px(x), py(y), colour(r));
        }
    }
    s += &format!(
        "<text x=\"{}\" y=\"22\" text-anchor=\"middle\" font-size=\"14\">Fourier-compressed horizon \
         maps: error against size and compression time (means over {} real DEMs)</text>\n",
        width / 2.0,
        dems.len()
    );
    // Legend.
    let ly = mt + ph + mb + 10.0;
    let mut lx = ml;
    for (name, c) in [
        ("K = 4", "#1b9e77"),
        ("K = 8", "#d95f02"),
        ("K = 16", "#7570b3"),
        ("K = 32", "#e7298a"),
    ] {
        s += &format!("<rect x=\"{lx}\" y=\"{}\" width=\"12\" height=\"12\" fill=\"{c}\"/><text x=\"{}\" y=\"{}\">{name}</text>\n", ly, lx + 16.0, ly + 11.0);
        lx += 80.0;
    }
    let mut lx = ml;
    let ly2 = ly + 24.0;
    for (layout, enc, label) in [
        ("full", "f16", "full f16"),
        ("full", "snorm16", "full snorm16"),
        ("multires", "f16", "multires f16"),
        ("multires", "snorm16", "multires snorm16"),
    ] {
        let fake = Row {
            case: String::new(),
            real: true,
            variant: format!("F16 {layout} {enc} plain"),
            bytes_per_tile: 0,
            compress_ms_per_tile: 0.0,
            share_pct: 0.0,
            rms_deg: 0.0,
            p99_deg: 0.0,
            max_deg: 0.0,
            per: [0.0; 3],
            per_all: 0.0,
            lit_mae: 0.0,
            lit_mae_constant: None,
            lit_nan: 0,
        };
        s += &marker(&fake, lx + 6.0, ly2 + 6.0, "#555");
        s += &format!(
            "<text x=\"{}\" y=\"{}\">{label}</text>\n",
            lx + 16.0,
            ly2 + 11.0
        );
        lx += 130.0;
    }
    let ly3 = ly2 + 24.0;
    s += &format!(
        "<text x=\"{ml}\" y=\"{}\">filled: plain; hollow: Lanczos σ taper; dot: --reduce fit</text>\n",
        ly3 + 11.0
    );
    let classic_row = |n: usize| Row {
        case: String::new(),
        real: true,
        variant: format!("classic {n}"),
        bytes_per_tile: 0,
        compress_ms_per_tile: 0.0,
        share_pct: 0.0,
        rms_deg: 0.0,
        p99_deg: 0.0,
        max_deg: 0.0,
        per: [0.0; 3],
        per_all: 0.0,
        lit_mae: 0.0,
        lit_mae_constant: None,
        lit_nan: 0,
    };
    let legend_cross = marker(&classic_row(8), ml + 420.0, ly3 + 6.0, "#000");
    s += legend_cross.split("<text").next().unwrap_or("");
    s += "\n";
    s += &format!(
        "<text x=\"{}\" y=\"{}\">classic 8 / 12 samples (f16, labelled)</text>\n",
        ml + 434.0,
        ly3 + 11.0
    );
    let ly4 = ly3 + 24.0;
    s += &format!(
        "<text x=\"{ml}\" y=\"{}\" fill=\"#555\">DEMs: {}</text>\n",
        ly4 + 11.0,
        dems.join(", ")
    );
    s += "</svg>\n";
    s
}

fn marker(r: &Row, x: f64, y: f64, c: &str) -> String {
    if let Some(n) = r.variant.strip_prefix("classic ") {
        let d = 6.0;
        return format!(
            "<path d=\"M{} {} L{} {} M{} {} L{} {}\" stroke=\"{c}\" stroke-width=\"2.5\"/>\
             <text x=\"{}\" y=\"{}\" font-size=\"11\">classic {n}</text>\n",
            x - d,
            y - d,
            x + d,
            y + d,
            x - d,
            y + d,
            x + d,
            y - d,
            x + 8.0,
            y - 6.0
        );
    }
    // Fitted reduction: the layout's marker with a black dot in it.
    if let Some(base) = r.variant.strip_suffix(" fit") {
        let plain = Row {
            variant: base.to_string(),
            ..r.clone()
        };
        return marker(&plain, x, y, c)
            + &format!(
                "<circle cx=\"{x:.1}\" cy=\"{:.1}\" r=\"1.8\" fill=\"#000\"/>\n",
                y + 0.5
            );
    }
    let hollow = r.variant.ends_with("lanczos");
    let fill = if hollow { "white" } else { c };
    let style =
        format!("fill=\"{fill}\" stroke=\"{c}\" stroke-width=\"1.5\" fill-opacity=\"0.85\"");
    let multires = r.variant.contains("multires");
    let snorm = r.variant.contains("snorm16");
    match (multires, snorm) {
        (false, false) => format!("<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"5\" {style}/>\n"),
        (false, true) => format!(
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"9\" height=\"9\" {style}/>\n",
            x - 4.5,
            y - 4.5
        ),
        (true, false) => format!(
            "<path d=\"M{:.1} {:.1} L{:.1} {:.1} L{:.1} {:.1} Z\" {style}/>\n",
            x,
            y - 6.0,
            x + 5.5,
            y + 4.0,
            x - 5.5,
            y + 4.0
        ),
        (true, true) => format!(
            "<path d=\"M{:.1} {:.1} L{:.1} {:.1} L{:.1} {:.1} L{:.1} {:.1} Z\" {style}/>\n",
            x,
            y - 6.0,
            x + 6.0,
            y,
            x,
            y + 6.0,
            x - 6.0,
            y
        ),
    }
}

/// log10 range covering the values with a little room.
fn log_range(v: &[f64]) -> (f64, f64) {
    let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let (l, h) = (lo.log10(), hi.log10());
    let pad = ((h - l) * 0.08).max(0.1);
    (l - pad, h + pad)
}

fn tick(v: f64) -> String {
    if v >= 1e6 {
        format!("{}M", v / 1e6)
    } else if v >= 1e3 {
        format!("{}k", v / 1e3)
    } else if v >= 1.0 {
        format!("{v}")
    } else {
        let s = format!("{v:.6}");
        s.trim_end_matches('0').to_string()
    }
}

/// What a product built from one horizon map scores against a truth map.
pub(crate) struct ProductError {
    pub(crate) rms_deg: f64,
    pub(crate) lit_mae: f64,
    /// Shadow-bit mismatches over every sun (fraction, not per cent).
    pub(crate) per_all: f64,
}

/// The product a user keeps, the paper's configuration (Fourier-16 multires f16, untapered),
/// built from each of `elevs` (plane-major raw maps of `case`'s block, `a` azimuths) and
/// measured against the truth built from `truth_elev`: the same suns, pixels and lit-fraction
/// pixels as `penumbra-bench fourier`.
pub(crate) fn paper_product_errors(
    case: &Case,
    truth_elev: &[f32],
    elevs: &[&[f32]],
    a: usize,
    lit_pixels: usize,
) -> Vec<ProductError> {
    let n = case.rect.w;
    let tile = case.block_tile();
    let opts = FourierOptions {
        coefficients: 16,
        layout: Layout::Multires,
        encoding: Encoding::F16,
        sigma: Sigma::None,
        reduce: Reduce::Mean,
        ..Default::default()
    };
    let enc = Encoder::for_tiles(&opts, n, 0, a, case.ctx.radius_m, case.terrain_min_m);
    let t = truth(case, &enc, truth_elev, a, lit_pixels);
    elevs
        .iter()
        .map(|elev| {
            let (p, _) = enc.encode(elev, &tile);
            let m = measure(&t, &Horizon::Fourier(&p), false);
            let per_n =
                m.err.per_miss.len() as f64 * (m.err.per_n.max(1) * SUN_AZ.len() as u64) as f64;
            ProductError {
                rms_deg: m.err.rms(),
                lit_mae: m.lit_mae,
                per_all: m.err.per_miss.iter().sum::<u64>() as f64 / per_n,
            }
        })
        .collect()
}
