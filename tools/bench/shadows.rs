//! `penumbra-bench shadows` (issue 11): every shadow method's error against the exact
//! reference and its time per megapixel on 1 and 2 threads, on the embedded scene and a block
//! of each shared real DEM, for suns at 1°, 5°, 15° and 45° from 8 azimuths; DP against uniform
//! stepping at equal or lower error; the DP variants; the canonical DDA's streaks beside the
//! 3-texel rule; and a 1024² hard-shadow mask.
//!
//! The sun of each (elevation, azimuth) is one direction in the body frame, set at the block's
//! centre, so its local elevation varies across the block as it does over a tile.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Result};
use rayon::prelude::*;
use serde::Serialize;

use penumbra::fourier::stage::{Encoder, FourierOptions};
use penumbra::fourier::sun::{sun_radius_deg, Frame, Sun};
use penumbra::fourier::{evaluate, Pyramid};
use penumbra::horizon::{horizons_with, Method as HzMethod, DEFAULT_NEAR_PX};
use penumbra::shadow::smap::SMap;
use penumbra::shadow::trace::{Method, Runs, Work, PENUMBRA_BAND_DEG};
use penumbra::shadow::Tracer;

use crate::cases::real_cases;
use penumbra_cli::measure::{dem_case, lookup_lit, Baked as Lookup, Case, ErrSum, ShadowWay as Bm};

/// Sun elevations (degrees) and compass azimuths at the block's centre (degrees).
const SUN_EL: [f64; 4] = [1.0, 5.0, 15.0, 45.0];
const SUN_AZ: [f64; 8] = [17.0, 62.0, 107.0, 152.0, 197.0, 242.0, 287.0, 332.0];
/// Uniform step counts tried.
const STEPS: [usize; 6] = [25, 50, 100, 200, 400, 800];
/// The pictures' sun: compass azimuth and elevation at the block's centre (degrees).
const PICTURE_SUN: (f64, f64) = (107.0, 12.0);
/// Azimuths of the raw maps the horizon method looks up.
const AZIMUTHS: usize = 360;

pub struct Args {
    pub data: PathBuf,
    pub block: usize,
    pub mask: usize,
    pub markdown: bool,
    pub json: bool,
    pub svg: PathBuf,
    pub images: PathBuf,
    pub quick: bool,
    pub only: Option<String>,
}

fn methods(quick: bool) -> Vec<Bm> {
    let mut v = Vec::new();
    let steps: &[usize] = if quick { &[25, 100, 400] } else { &STEPS };
    for &s in steps {
        v.push(Bm::Trace(Method::Uniform { steps: s }));
    }
    for runs in ["5,5,5", "5,5,5,3", "auto"] {
        v.push(Bm::Trace(Method::Dp {
            runs: runs.parse().expect("runs"),
            dda: false,
        }));
    }
    for runs in ["5,5,5", "auto"] {
        v.push(Bm::Trace(Method::Dp {
            runs: runs.parse().expect("runs"),
            dda: true,
        }));
    }
    // Jung et al.'s DP as published (one texel per level, no refinement), for comparison.
    for dda in [false, true] {
        v.push(Bm::Trace(Method::JungDp {
            runs: Runs::Auto,
            dda,
        }));
    }
    v.push(Bm::Trace(Method::Extrema));
    v.push(Bm::Trace(Method::ExtremaSoft));
    v.push(Bm::SMap);
    v.push(Bm::Lookup(true));
    v.push(Bm::Lookup(false));
    v
}

/// The suns of a case: one body-frame direction per (elevation, azimuth), set at the block's
/// centre.
fn suns(case: &Case, radius_deg: f64) -> Vec<(f64, Sun)> {
    let c = centre_frame(case);
    SUN_EL
        .iter()
        .flat_map(|&e| {
            SUN_AZ.iter().map(move |&a| {
                (
                    e,
                    Sun {
                        dir: c.direction(a, e),
                        radius_deg,
                    },
                )
            })
        })
        .collect()
}

fn centre_frame(case: &Case) -> Frame {
    let (u, v) = case.ctx.uv(
        (case.rect.x0 + case.rect.w / 2) as f64,
        (case.rect.y0 + case.rect.h / 2) as f64,
    );
    Frame::at(case.ctx.face, u, v)
}

/// Baked horizons of a case's block for the lookup method.
struct Baked {
    raw: Vec<f32>,
    pyramid: Pyramid,
    floor_enc: Encoder,
    bake_s: f64,
    encode_s: f64,
}

fn bake(case: &Case) -> Baked {
    let n = case.rect.w;
    let t0 = Instant::now();
    let raw = horizons_with(
        &case.ctx,
        case.rect,
        AZIMUTHS,
        HzMethod::Fast,
        DEFAULT_NEAR_PX,
    );
    let bake_s = t0.elapsed().as_secs_f64();
    let tile = case.block_tile();
    let enc = Encoder::for_tiles(
        &FourierOptions::default(),
        n,
        0,
        AZIMUTHS,
        case.ctx.radius_m,
        case.terrain_min_m,
    );
    let t1 = Instant::now();
    let (pyramid, _) = enc.encode(&raw, &tile);
    let encode_s = t1.elapsed().as_secs_f64();
    Baked {
        raw,
        pyramid,
        floor_enc: enc,
        bake_s,
        encode_s,
    }
}

/// Lit fractions of every (sun, block pixel), sun-major; texel/sample visits; for the SMap, the
/// share of its samples marked black (over all suns).
fn eval(
    tr: &Tracer,
    case: &Case,
    suns: &[(f64, Sun)],
    m: &Bm,
    baked: Option<&Baked>,
) -> (Vec<f32>, u64, Option<f64>) {
    let (n, rect) = (case.rect.w, case.rect);
    if let Bm::SMap = m {
        let mut lit = Vec::with_capacity(suns.len() * n * n);
        let (mut marked, mut samples) = (0.0, 0.0);
        for (_, sun) in suns {
            let map = SMap::build(&case.ctx, sun.dir, rect, case.terrain_min_m);
            let k = map.size().1 as f64;
            marked += map.marked_fraction() * k;
            samples += k;
            lit.extend(map.lit_region(&case.ctx));
        }
        return (lit, 0, Some(marked / samples.max(1.0)));
    }
    let rows: Vec<(Vec<f32>, u64)> = (0..suns.len() * n)
        .into_par_iter()
        .map(|k| {
            let (s, j) = (k / n, k % n);
            let sun = &suns[s].1;
            let mut out = vec![f32::NAN; n];
            let mut work = Work::default();
            let mut coef = Vec::new();
            for (i, o) in out.iter_mut().enumerate() {
                let (x, y) = (rect.x0 + i, rect.y0 + j);
                *o = match m {
                    Bm::Trace(t) => tr.lit(x, y, sun, t, &mut work) as f32,
                    Bm::SMap => unreachable!("answered above"),
                    Bm::Lookup(raw) => {
                        let b = baked.expect("baked");
                        let h0 = case.ctx.at(x as i64, y as i64);
                        if h0.is_nan() {
                            f32::NAN
                        } else {
                            let at = tr.sun_at(x, y, sun);
                            let floor = b.floor_enc.floor_deg(h0 as f64);
                            let from = if *raw {
                                Lookup::Raw(&b.raw, AZIMUTHS)
                            } else {
                                Lookup::Pyramid(&b.pyramid)
                            };
                            lookup_lit(&at.frame, sun, &from, i, j, n, floor, &mut coef) as f32
                        }
                    }
                };
            }
            (out, work.visits)
        })
        .collect();
    let mut lit = Vec::with_capacity(suns.len() * n * n);
    let mut visits = 0;
    for (r, v) in rows {
        lit.extend(r);
        visits += v;
    }
    (lit, visits, None)
}

/// Which (sun, block pixel) pairs are penumbral (sun-major, as [`eval`]'s lit fractions): the
/// sun's centre within [`PENUMBRA_BAND_DEG`] of the exact horizon in its azimuth.
fn penumbral(tr: &Tracer, case: &Case, suns: &[(f64, Sun)]) -> Vec<bool> {
    let (n, rect) = (case.rect.w, case.rect);
    (0..suns.len() * n * n)
        .into_par_iter()
        .map(|k| {
            let (s, p) = (k / (n * n), k % (n * n));
            let (x, y) = (rect.x0 + p % n, rect.y0 + p / n);
            tr.penumbral(x, y, &suns[s].1)
        })
        .collect()
}

fn timed<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<(T, f64)> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let t0 = Instant::now();
    let r = pool.install(f);
    Ok((r, t0.elapsed().as_secs_f64()))
}

#[derive(Serialize)]
struct Row {
    case: String,
    real: bool,
    method: String,
    hard: bool,
    /// Per sun elevation (SUN_EL order), then all.
    err: Vec<ErrSum>,
    all: ErrSum,
    /// Over the penumbral (pixel, sun) pairs only ([`PENUMBRA_BAND_DEG`]).
    penumbra: ErrSum,
    ms_per_mpx_1t: f64,
    ms_per_mpx_2t: f64,
    visits_per_px: f64,
    /// SMap: share of the samples marked black.
    marked: Option<f64>,
}

#[derive(Serialize)]
struct CaseInfo {
    case: String,
    context: String,
    block: usize,
    pixel_m: f64,
    reference_ms_per_mpx_2t: f64,
    horizon_bake_s: f64,
    fourier_encode_s: f64,
    /// (pixel, sun) pairs of the block with the sun's centre within [`PENUMBRA_BAND_DEG`] of the
    /// exact horizon, of all pairs over terrain.
    penumbral_pairs: u64,
    pairs: u64,
    note: String,
}

#[derive(Serialize)]
struct Mask {
    size: usize,
    context: String,
    method: String,
    sun_el: f64,
    seconds_2t: f64,
    seconds_1t: f64,
    lit_px: u64,
}

pub fn run(args: Args, quiet: bool) -> Result<()> {
    let block = if args.quick { 48 } else { args.block };
    if !(16..=1024).contains(&block) {
        bail!("--block must be 16..=1024");
    }
    let say = |m: String| {
        if !quiet {
            eprintln!("bench shadows: {m}");
        }
    };
    let t_all = Instant::now();
    let scene = penumbra::dem::Dem::new(
        penumbra::synthetic::generate(&penumbra::synthetic::SyntheticSpec::default()),
        64,
    )?;
    let mut cases = vec![dem_case(
        "embedded scene (Moon, 20 m)",
        &scene,
        "moon",
        block,
    )];
    let (real, notes) = real_cases(&args.data, block, &say)?;
    cases.extend(real);
    if let Some(o) = &args.only {
        let o = o.to_lowercase();
        cases.retain(|c| c.name.to_lowercase().contains(&o));
    }
    if std::env::var("CI").as_deref() == Ok("true") && !notes.is_empty() {
        bail!("shared DEMs missing under CI: {notes:?}");
    }
    let radius = sun_radius_deg(1.0);
    let ms = methods(args.quick);
    let mut rows = Vec::new();
    let mut infos = Vec::new();
    for case in &cases {
        let n = case.rect.w;
        let tr = Tracer::new(&case.ctx, case.terrain_min_m);
        let sv = suns(case, radius);
        let mpx = (sv.len() * n * n) as f64 / 1e6;
        say(format!(
            "{}: {n}² pixels × {} suns in a {}×{} context",
            case.name,
            sv.len(),
            case.ctx.width,
            case.ctx.height
        ));
        let ((reference, _, _), t_ref) = timed(2, || {
            eval(&tr, case, &sv, &Bm::Trace(Method::Reference), None)
        })?;
        say(format!("{}: reference {t_ref:.1} s", case.name));
        let pen = penumbral(&tr, case, &sv);
        let pairs = reference.iter().filter(|v| v.is_finite()).count() as u64;
        let pen_pairs = pen
            .iter()
            .zip(&reference)
            .filter(|(p, r)| **p && r.is_finite())
            .count() as u64;
        say(format!(
            "{}: {pen_pairs} of {pairs} (pixel, sun) pairs penumbral (within {PENUMBRA_BAND_DEG}° of the horizon)",
            case.name
        ));
        let baked = bake(case);
        say(format!(
            "{}: horizons {:.1} s, pyramid {:.2} s",
            case.name, baked.bake_s, baked.encode_s
        ));
        infos.push(CaseInfo {
            case: case.name.clone(),
            context: format!("{}×{}", case.ctx.width, case.ctx.height),
            block: n,
            pixel_m: case.pixel_m,
            reference_ms_per_mpx_2t: t_ref * 1e3 / mpx,
            horizon_bake_s: baked.bake_s,
            fourier_encode_s: baked.encode_s,
            penumbral_pairs: pen_pairs,
            pairs,
            note: case.note.clone(),
        });
        for m in &ms {
            let b = Some(&baked);
            let ((lit, visits, marked), t2) = timed(2, || eval(&tr, case, &sv, m, b))?;
            let (_, t1) = timed(1, || eval(&tr, case, &sv, m, b))?;
            let mut err = vec![ErrSum::default(); SUN_EL.len()];
            for (s, (el, _)) in sv.iter().enumerate() {
                let e = SUN_EL.iter().position(|x| x == el).expect("elevation");
                for p in 0..n * n {
                    err[e].add(lit[s * n * n + p], reference[s * n * n + p]);
                }
            }
            let mut all = ErrSum::default();
            for e in &err {
                all.merge(e);
            }
            let mut penumbra = ErrSum::default();
            for (k, _) in pen.iter().enumerate().filter(|(_, p)| **p) {
                penumbra.add(lit[k], reference[k]);
            }
            say(format!(
                "{}: {:<20} mean |err| {:.4}, PER {:.3} %; penumbra {:.4}, {:.2} %; {:.0} ms/Mpx on 2 threads",
                case.name,
                m.label(AZIMUTHS),
                all.mae(),
                all.per(),
                penumbra.mae(),
                penumbra.per(),
                t2 * 1e3 / mpx
            ));
            rows.push(Row {
                case: case.name.clone(),
                real: case.real && !case.name.starts_with("embedded"),
                method: m.label(AZIMUTHS),
                hard: m.hard(),
                err,
                all,
                penumbra,
                ms_per_mpx_1t: t1 * 1e3 / mpx,
                ms_per_mpx_2t: t2 * 1e3 / mpx,
                visits_per_px: visits as f64 / (sv.len() * n * n) as f64,
                marked,
            });
        }
    }
    // The 1024² hard mask on the embedded scene.
    let (mask, mask_bake_s) = mask_runs(&scene, args.mask, radius, &say)?;
    let images = if args.quick {
        Vec::new()
    } else {
        pictures(&scene, &args.images, radius, &say)?
    };
    let summary = summarise(&rows);
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "cases": infos, "rows": rows, "summary": summary, "mask": mask,
                "notes": notes, "wall_s": t_all.elapsed().as_secs_f64(),
            }))?
        );
    }
    std::fs::write(&args.svg, svg(&summary))?;
    let md = markdown(
        &infos,
        &rows,
        &summary,
        (&mask, mask_bake_s),
        &images,
        &notes,
        &args,
        t_all.elapsed().as_secs_f64(),
    );
    // Markdown unless only JSON was asked.
    if args.markdown || !args.json {
        print!("{md}");
    }
    Ok(())
}

/// A method's figures over the real DEMs together.
#[derive(Serialize, Clone)]
struct Summary {
    method: String,
    hard: bool,
    err: Vec<ErrSum>,
    all: ErrSum,
    /// Over the penumbral pairs of the real DEMs.
    penumbra: ErrSum,
    /// Worst single real DEM's mean |error| over elevations ≥ 1° and PER.
    worst_mae: f64,
    worst_per: f64,
    ms_per_mpx_1t: f64,
    ms_per_mpx_2t: f64,
    visits_per_px: f64,
    /// SMap: share of the samples marked black over the real DEMs.
    marked: Option<f64>,
}

fn summarise(rows: &[Row]) -> Vec<Summary> {
    let mut names: Vec<String> = Vec::new();
    for r in rows {
        if !names.contains(&r.method) {
            names.push(r.method.clone());
        }
    }
    names
        .iter()
        .map(|name| {
            let rs: Vec<&Row> = rows
                .iter()
                .filter(|r| &r.method == name && r.real)
                .collect();
            let mut err = vec![ErrSum::default(); SUN_EL.len()];
            let mut all = ErrSum::default();
            let mut penumbra = ErrSum::default();
            for r in &rs {
                for (a, b) in err.iter_mut().zip(&r.err) {
                    a.merge(b);
                }
                all.merge(&r.all);
                penumbra.merge(&r.penumbra);
            }
            let k = rs.len().max(1) as f64;
            Summary {
                method: name.clone(),
                hard: rs.first().is_some_and(|r| r.hard),
                err,
                all,
                penumbra,
                worst_mae: rs.iter().map(|r| r.all.mae()).fold(0.0, f64::max),
                worst_per: rs.iter().map(|r| r.all.per()).fold(0.0, f64::max),
                ms_per_mpx_1t: rs.iter().map(|r| r.ms_per_mpx_1t).sum::<f64>() / k,
                ms_per_mpx_2t: rs.iter().map(|r| r.ms_per_mpx_2t).sum::<f64>() / k,
                visits_per_px: rs.iter().map(|r| r.visits_per_px).sum::<f64>() / k,
                marked: rs
                    .first()
                    .and_then(|r| r.marked)
                    .map(|_| rs.iter().filter_map(|r| r.marked).sum::<f64>() / k),
            }
        })
        .collect()
}

/// Azimuths of the raw maps of the mask's horizon lookups (a lookup reads two samples
/// whatever their number, so a 1024² block's maps are made with few).
const MASK_AZIMUTHS: usize = 36;

/// Times of a hard-shadow mask of `size`² pixels of the embedded scene for one sun per
/// elevation: extrema, the SMap (its build for the sun included), and lookups in raw horizon
/// maps and in Fourier pyramids (their bake timed apart), on 1 and 2 threads.
fn mask_runs(
    scene: &penumbra::dem::Dem,
    size: usize,
    radius: f64,
    say: &dyn Fn(String),
) -> Result<(Vec<Mask>, f64)> {
    use penumbra::shadow::{centre_above, centre_at, FaceAxes};
    let case = dem_case("mask", scene, "moon", size);
    let n = case.rect.w;
    let tr = Tracer::new(&case.ctx, case.terrain_min_m);
    let c = centre_frame(&case);
    let t0 = Instant::now();
    let raw = horizons_with(
        &case.ctx,
        case.rect,
        MASK_AZIMUTHS,
        HzMethod::Fast,
        DEFAULT_NEAR_PX,
    );
    let tile = case.block_tile();
    let enc = Encoder::for_tiles(
        &FourierOptions::default(),
        n,
        0,
        MASK_AZIMUTHS,
        case.ctx.radius_m,
        case.terrain_min_m,
    );
    let (pyr, _) = enc.encode(&raw, &tile);
    let bake_s = t0.elapsed().as_secs_f64();
    say(format!(
        "mask {n}²: {MASK_AZIMUTHS}-azimuth horizons and pyramid {bake_s:.1} s"
    ));
    let ax = FaceAxes::new(case.ctx.face);
    let mut out = Vec::new();
    for &el in &SUN_EL {
        let sun = Sun {
            dir: c.direction(SUN_AZ[0], el),
            radius_deg: radius,
        };
        for which in ["extrema", "smap", "horizon raw", "horizon fourier F16"] {
            let run = || -> u64 {
                if which == "smap" {
                    let map = SMap::build(&case.ctx, sun.dir, case.rect, case.terrain_min_m);
                    return map
                        .lit_region(&case.ctx)
                        .iter()
                        .filter(|&&v| v > 0.5)
                        .count() as u64;
                }
                (0..n)
                    .into_par_iter()
                    .map(|j| {
                        let mut w = Work::default();
                        let mut coef = Vec::with_capacity(16);
                        let mut lit = 0u64;
                        for i in 0..n {
                            let (x, y) = (case.rect.x0 + i, case.rect.y0 + j);
                            let on = if which == "extrema" {
                                tr.lit(x, y, &sun, &Method::Extrema, &mut w) > 0.5
                            } else {
                                let h0 = case.ctx.at(x as i64, y as i64);
                                if h0.is_nan() {
                                    continue;
                                }
                                let (u, v) = case.ctx.uv(x as f64, y as f64);
                                let at = centre_at(&ax, u, v, sun.dir);
                                let floor = enc.floor_deg(h0 as f64);
                                let h = if which == "horizon raw" {
                                    let f = at.phi / std::f64::consts::TAU * MASK_AZIMUTHS as f64;
                                    let k0 = (f as usize) % MASK_AZIMUTHS;
                                    let wt = f - f.floor();
                                    let p = j * n + i;
                                    let a = raw[k0 * n * n + p] as f64;
                                    let b = raw[((k0 + 1) % MASK_AZIMUTHS) * n * n + p] as f64;
                                    a + (b - a) * wt
                                } else {
                                    pyr.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, &mut coef);
                                    evaluate(&coef, at.phi)
                                };
                                centre_above(&at, h.max(floor))
                            };
                            lit += on as u64;
                        }
                        lit
                    })
                    .sum()
            };
            let (lit, t2) = timed(2, run)?;
            let (_, t1) = timed(1, run)?;
            say(format!(
                "mask {n}² at {el}°, {which}: {t2:.3} s on 2 threads, {t1:.3} s on 1"
            ));
            out.push(Mask {
                size: n,
                context: format!("{}×{}", case.ctx.width, case.ctx.height),
                method: which.into(),
                sun_el: el,
                seconds_2t: t2,
                seconds_1t: t1,
                lit_px: lit,
            });
        }
    }
    Ok((out, bake_s))
}

/// Pictures of one sun over a 256² block of the embedded scene: the reference, DP, the
/// canonical DDA, uniform stepping, extrema, extrema-soft and the SMap, and the DP's, DDA's and
/// extrema-soft's errors (×4).
fn pictures(
    scene: &penumbra::dem::Dem,
    dir: &Path,
    radius: f64,
    say: &dyn Fn(String),
) -> Result<Vec<(String, String)>> {
    std::fs::create_dir_all(dir)?;
    let case = dem_case("pictures", scene, "moon", 256);
    let n = case.rect.w;
    let tr = Tracer::new(&case.ctx, case.terrain_min_m);
    let c = centre_frame(&case);
    let sun = Sun {
        dir: c.direction(PICTURE_SUN.0, PICTURE_SUN.1),
        radius_deg: radius,
    };
    let sv = vec![(PICTURE_SUN.1, sun)];
    let render = |m: &Bm| eval(&tr, &case, &sv, m, None).0;
    let reference = render(&Bm::Trace(Method::Reference));
    let shown = [
        ("reference", Bm::Trace(Method::Reference)),
        (
            "dp",
            Bm::Trace(Method::Dp {
                runs: Runs::Auto,
                dda: false,
            }),
        ),
        (
            "dp-dda",
            Bm::Trace(Method::Dp {
                runs: Runs::Auto,
                dda: true,
            }),
        ),
        ("uniform-100", Bm::Trace(Method::Uniform { steps: 100 })),
        ("extrema", Bm::Trace(Method::Extrema)),
        ("extrema-soft", Bm::Trace(Method::ExtremaSoft)),
        ("smap", Bm::SMap),
    ];
    let mut out = Vec::new();
    for (name, m) in shown {
        let lit = if name == "reference" {
            reference.clone()
        } else {
            render(&m)
        };
        let p = dir.join(format!("shadows-{name}.png"));
        penumbra::shadow::write_grey_png(&p, n, n, &lit)?;
        out.push((name.to_string(), p.display().to_string()));
        if name == "dp" || name == "dp-dda" || name == "extrema-soft" {
            let e: Vec<f32> = lit
                .iter()
                .zip(&reference)
                .map(|(a, b)| ((a - b).abs() * 4.0).min(1.0))
                .collect();
            let p = dir.join(format!("shadows-{name}-error.png"));
            penumbra::shadow::write_grey_png(&p, n, n, &e)?;
            out.push((format!("{name} |error| ×4"), p.display().to_string()));
        }
    }
    say(format!("pictures in {}", dir.display()));
    Ok(out)
}

/// For a DP variant, the cheapest uniform stepping at equal or lower mean error, and the time
/// ratio (2 threads).
fn versus_uniform(s: &[Summary], dp: &Summary) -> Option<(String, f64)> {
    s.iter()
        .filter(|u| u.method.starts_with("uniform") && u.all.mae() <= dp.all.mae())
        .min_by(|a, b| a.ms_per_mpx_2t.total_cmp(&b.ms_per_mpx_2t))
        .map(|u| (u.method.clone(), u.ms_per_mpx_2t / dp.ms_per_mpx_2t))
}

#[allow(clippy::too_many_arguments)]
fn markdown(
    infos: &[CaseInfo],
    rows: &[Row],
    summary: &[Summary],
    (mask, mask_bake_s): (&[Mask], f64),
    images: &[(String, String)],
    notes: &[String],
    args: &Args,
    wall: f64,
) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(o, "# Shadow methods side by side (CPU)\n");
    let _ = writeln!(
        o,
        "Written by `penumbra-bench shadows --markdown` ({:.0} s, {} threads available; block {}², \
         suns at {:?}° × {} azimuths, sun radius {:.4}° at 1 AU). Errors are against the \
         `reference` (exact search of the bilinear surface in 7 azimuths across the disc, exact \
         disc model); PER is the share of pixels whose lit/unlit decision at 0.5 differs from \
         the reference's. Times are per megapixel of (pixel, sun) evaluations.\n",
        wall,
        rayon::current_num_threads(),
        args.block,
        SUN_EL,
        SUN_AZ.len(),
        sun_radius_deg(1.0)
    );
    let _ = writeln!(o, "## Cases\n");
    let _ = writeln!(o, "| case | context | m/px | reference ms/Mpx (2 thr) | 360-az horizons of the block (s) | F16 encode (s) | penumbral pairs | block |");
    let _ = writeln!(o, "|---|---|---:|---:|---:|---:|---:|---|");
    for c in infos {
        let _ = writeln!(
            o,
            "| {} | {} | {:.1} | {:.0} | {:.1} | {:.2} | {} of {} | {} |",
            c.case,
            c.context,
            c.pixel_m,
            c.reference_ms_per_mpx_2t,
            c.horizon_bake_s,
            c.fourier_encode_s,
            c.penumbral_pairs,
            c.pairs,
            c.note
        );
    }
    for n in notes {
        let _ = writeln!(o, "\n{n}");
    }
    let _ = writeln!(o, "\n## All methods over the real DEMs\n");
    let _ = write!(o, "| method | mean abs error |");
    for e in SUN_EL {
        let _ = write!(o, " {e}° |");
    }
    let _ = writeln!(
        o,
        " PER | worst DEM mean | worst DEM PER | max | ms/Mpx 1 thr | ms/Mpx 2 thr | visits/px |"
    );
    let _ = write!(o, "|---|---:|");
    for _ in SUN_EL {
        let _ = write!(o, "---:|");
    }
    let _ = writeln!(o, "---:|---:|---:|---:|---:|---:|---:|");
    for s in summary {
        let _ = write!(o, "| {} | {:.4} |", s.method, s.all.mae());
        for e in &s.err {
            let _ = write!(o, " {:.4} |", e.mae());
        }
        let _ = writeln!(
            o,
            " {:.3} % | {:.4} | {:.3} % | {:.3} | {:.0} | {:.0} | {:.1} |",
            s.all.per(),
            s.worst_mae,
            s.worst_per,
            s.all.max,
            s.ms_per_mpx_1t,
            s.ms_per_mpx_2t,
            s.visits_per_px
        );
    }
    for s in summary {
        if let Some(f) = s.marked {
            let _ = writeln!(
                o,
                "\n`{}` marks {:.2} % of its samples black (the silhouette seen from the sun: the \
                 samples standing above every sample sunward of them on their beam), averaged over \
                 the real DEMs and suns; its time includes building the map for each sun.",
                s.method,
                100.0 * f
            );
        }
    }
    let real_pen: u64 = summary.first().map_or(0, |s| s.penumbra.n);
    let _ = writeln!(o, "\n## In the penumbra, over the real DEMs\n");
    let _ = writeln!(
        o,
        "The same runs restricted to the (pixel, sun) pairs where the sun's centre lies within \
         {PENUMBRA_BAND_DEG}° of the exact horizon in its azimuth ({real_pen} pairs over the real DEMs; \
         per case in the tables above and below): where shadows are decided, which the \
         all-pixel means dilute with pixels far from any shadow edge.\n"
    );
    let _ = writeln!(
        o,
        "| method | penumbra mean abs error | penumbra PER | penumbra max | all-pixel mean | all-pixel PER | ms/Mpx 2 thr |"
    );
    let _ = writeln!(o, "|---|---:|---:|---:|---:|---:|---:|");
    for s in summary {
        let _ = writeln!(
            o,
            "| {} | {:.4} | {:.2} % | {:.3} | {:.4} | {:.3} % | {:.0} |",
            s.method,
            s.penumbra.mae(),
            s.penumbra.per(),
            s.penumbra.max,
            s.all.mae(),
            s.all.per(),
            s.ms_per_mpx_2t
        );
    }
    let _ = writeln!(o, "\n![error against time](shadows-error.svg)\n");
    let _ = writeln!(
        o,
        "## DP against uniform stepping at equal or lower error\n"
    );
    let _ = writeln!(o, "| DP variant | mean abs error | ms/Mpx (2 thr) | cheapest uniform at ≤ that error | its ms/Mpx | DP faster by |");
    let _ = writeln!(o, "|---|---:|---:|---|---:|---:|");
    for d in summary.iter().filter(|s| s.method.starts_with("dp")) {
        match versus_uniform(summary, d) {
            Some((u, r)) => {
                let um = summary.iter().find(|s| s.method == u).expect("uniform");
                let _ = writeln!(
                    o,
                    "| {} | {:.4} | {:.0} | {} ({:.4}) | {:.0} | {:.2}× |",
                    d.method,
                    d.all.mae(),
                    d.ms_per_mpx_2t,
                    u,
                    um.all.mae(),
                    um.ms_per_mpx_2t,
                    r
                );
            }
            None => {
                let _ = writeln!(
                    o,
                    "| {} | {:.4} | {:.0} | none of {:?} steps reaches it | | > {:.2}× |",
                    d.method,
                    d.all.mae(),
                    d.ms_per_mpx_2t,
                    STEPS,
                    summary
                        .iter()
                        .filter(|s| s.method.starts_with("uniform"))
                        .map(|s| s.ms_per_mpx_2t)
                        .fold(0.0, f64::max)
                        / d.ms_per_mpx_2t
                );
            }
        }
    }
    let _ = writeln!(o, "\n## Per case\n");
    let _ = writeln!(
        o,
        "| case | method | mean abs error | PER | max | penumbra mean | penumbra PER | ms/Mpx 2 thr |"
    );
    let _ = writeln!(o, "|---|---|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            o,
            "| {} | {} | {:.4} | {:.3} % | {:.3} | {:.4} | {:.2} % | {:.0} |",
            r.case,
            r.method,
            r.all.mae(),
            r.all.per(),
            r.all.max,
            r.penumbra.mae(),
            r.penumbra.per(),
            r.ms_per_mpx_2t
        );
    }
    let _ = writeln!(o, "\n## A hard-shadow mask of the embedded scene\n");
    let _ = writeln!(
        o,
        "One sun per elevation (azimuth {}° at the block's centre). The lookups read horizons \
         baked beforehand ({MASK_AZIMUTHS}-azimuth raw maps and their F16 pyramid, {:.1} s for \
         the block; a lookup reads the same number of values whatever the azimuth count); \
         extrema searches the terrain itself; the SMap's time includes building it for the sun.\n",
        SUN_AZ[0], mask_bake_s
    );
    let _ = writeln!(
        o,
        "| size | context | method | sun elevation | 2 threads (s) | 1 thread (s) | lit px |"
    );
    let _ = writeln!(o, "|---:|---|---|---:|---:|---:|---:|");
    for m in mask {
        let _ = writeln!(
            o,
            "| {}² | {} | {} | {}° | {:.3} | {:.3} | {} |",
            m.size, m.context, m.method, m.sun_el, m.seconds_2t, m.seconds_1t, m.lit_px
        );
    }
    let mae_of = |m: &str| {
        summary
            .iter()
            .find(|s| s.method == m)
            .map_or(f64::NAN, |s| s.all.mae())
    };
    if !images.is_empty() {
        let _ = writeln!(
            o,
            "\n## Pictures: one sun at {}° (azimuth {}°) over 256² of the embedded scene\n",
            PICTURE_SUN.1, PICTURE_SUN.0
        );
        let _ = writeln!(o, "Errors are |method − reference| ×4 (white: 0.25 or more). Jung et al. show streaks from a canonical DDA that samples two points per level and so misses texels the ray cuts at a corner (their Fig. 5), and visit every texel under the ray instead (the 3-texel rule, `dp`). With exact per-texel bounds, Jung et al.'s DP still keeps one texel per level and errs along the shadow's edge, where a texel beside the ray holds a higher maximum than the one the ray crosses: over the real DEMs `dp-dda-jung auto`'s mean error is {:.4} and `dp-jung auto`'s {:.4} (tables above). `dp` and `dp-dda` (shown) refine the texels their descent passed over ({:.4} and {:.4}), and `extrema-soft` searches every texel that could matter.\n", mae_of("dp-dda-jung auto"), mae_of("dp-jung auto"), mae_of("dp auto"), mae_of("dp-dda auto"));
        for (name, p) in images {
            let file = Path::new(p)
                .file_name()
                .map(|f| f.to_string_lossy().to_string())
                .unwrap_or_default();
            let _ = writeln!(o, "- {name}: ![{name}](images/{file})");
        }
    }
    o
}

fn svg(summary: &[Summary]) -> String {
    use std::fmt::Write;
    let (w, h, l, b, t, r) = (720.0, 440.0, 70.0, 50.0, 20.0, 200.0);
    let pts: Vec<(f64, f64, &Summary)> = summary
        .iter()
        .filter(|s| s.all.n > 0)
        .map(|s| (s.ms_per_mpx_2t.max(1e-3), s.all.mae().max(1e-5), s))
        .collect();
    if pts.is_empty() {
        return format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}"><text x="20" y="40">no cases measured</text></svg>
"#
        );
    }
    let lr = |v: &mut dyn Iterator<Item = f64>| {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for x in v {
            lo = lo.min(x.log10());
            hi = hi.max(x.log10());
        }
        (lo.floor(), hi.ceil().max(lo.floor() + 1.0))
    };
    let (x0, x1) = lr(&mut pts.iter().map(|p| p.0));
    let (y0, y1) = lr(&mut pts.iter().map(|p| p.1));
    let px = |x: f64| l + (x.log10() - x0) / (x1 - x0) * (w - l - r);
    let py = |y: f64| h - b - (y.log10() - y0) / (y1 - y0) * (h - b - t);
    let mut o = String::new();
    let _ = writeln!(
        o,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><rect width="100%" height="100%" fill="white"/>"#
    );
    let _ = writeln!(
        o,
        r#"<rect x="{l}" y="{t}" width="{}" height="{}" fill="none" stroke="black"/>"#,
        w - l - r,
        h - b - t
    );
    let mut e = x0;
    while e <= x1 {
        let x = px(10f64.powf(e));
        let _ = writeln!(
            o,
            r##"<line x1="{x}" y1="{t}" x2="{x}" y2="{}" stroke="#ddd"/><text x="{x}" y="{}" text-anchor="middle">{}</text>"##,
            h - b,
            h - b + 16.0,
            10f64.powf(e)
        );
        e += 1.0;
    }
    let mut e = y0;
    while e <= y1 {
        let y = py(10f64.powf(e));
        let _ = writeln!(
            o,
            r##"<line x1="{l}" y1="{y}" x2="{}" y2="{y}" stroke="#ddd"/><text x="{}" y="{}" text-anchor="end">{}</text>"##,
            w - r,
            l - 6.0,
            y + 4.0,
            10f64.powf(e)
        );
        e += 1.0;
    }
    let _ = writeln!(
        o,
        r#"<text x="{}" y="{}" text-anchor="middle">ms per megapixel, 2 threads (log)</text>"#,
        (l + w - r) / 2.0,
        h - 12.0
    );
    let _ = writeln!(
        o,
        r#"<text x="16" y="{}" transform="rotate(-90 16 {})" text-anchor="middle">mean |lit error| vs reference (log)</text>"#,
        (t + h - b) / 2.0,
        (t + h - b) / 2.0
    );
    for (k, (x, y, s)) in pts.iter().enumerate() {
        let c = if s.method.starts_with("uniform") {
            "#888"
        } else if s.method.starts_with("dp-dda") {
            "#d62728"
        } else if s.method.starts_with("dp") {
            "#1f77b4"
        } else if s.method.starts_with("horizon") {
            "#2ca02c"
        } else {
            "#9467bd"
        };
        let (cx, cy) = (px(*x), py(*y));
        let _ = writeln!(o, r#"<circle cx="{cx:.1}" cy="{cy:.1}" r="4" fill="{c}"/>"#);
        let ly = t + 14.0 * (k as f64 + 1.0);
        let _ = writeln!(
            o,
            r#"<circle cx="{}" cy="{}" r="4" fill="{c}"/><text x="{}" y="{}">{}</text>"#,
            w - r + 12.0,
            ly - 4.0,
            w - r + 20.0,
            ly,
            s.method
        );
    }
    o.push_str("</svg>\n");
    o
}
