//! What the benchmarks and `penumbra report` measure with: a case (a block of observers in a
//! context raster reaching as far as a horizon could see), pseudo-random pixels, the exact
//! lit fraction of a sun's disc over a horizon, and the error tallies of horizon maps (degrees,
//! pixel error rate) and of lit fractions (mean absolute error, pixel error rate). Shared so
//! that the report's figures on a user's terrain are the benchmarks' figures on the shared DEMs.

use std::f64::consts::TAU;

use serde::Serialize;

use penumbra::cube::{Face, Vec3};
use penumbra::format::fourier::file_bytes;
use penumbra::format::height::HeightTile;
use penumbra::fourier::stage::FourierOptions;
use penumbra::fourier::sun::{lit_fraction, Frame, Model, Sun};
use penumbra::fourier::{evaluate, Encoding, Layout, Pyramid, Reduce, Sigma};
use penumbra::horizon::{Context as HzContext, Rect};
use penumbra::shadow::trace::Method as TraceMethod;

/// Histogram of absolute errors for the 99th percentile: 1e-4° bins to 2°, then 0.01° to 92°.
const FINE_BINS: usize = 20_000;
const COARSE_BINS: usize = 9_000;

/// Mean radii (m) of the bodies the shared DEMs are of.
pub const EARTH_RADIUS_M: f64 = 6_371_008.8;
pub const MARS_RADIUS_M: f64 = 3_396_190.0;
pub const MOON_RADIUS_M: f64 = 1_737_400.0;

/// `n` distinct pseudo-random pixels of a `w` × `h` raster (fixed seed: the same every run).
pub fn random_pixels(w: usize, h: usize, n: usize) -> Vec<(usize, usize)> {
    let n = n.min(w * h);
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let i = (state % (w * h) as u64) as usize;
        if seen.insert(i) {
            out.push((i % w, i / w));
        }
    }
    out
}

pub fn body_radius(body: &str) -> f64 {
    match body {
        "moon" => MOON_RADIUS_M,
        "mars" => MARS_RADIUS_M,
        _ => EARTH_RADIUS_M,
    }
}

/// Horizon reach in plane pixels: an observer on the highest terrain sees down to the tangent
/// of the lowest sphere, and terrain beyond it can rise above that floor again.
pub fn reach_px(radius_m: f64, relief_m: f64, pixel_m: f64) -> usize {
    (2.0 * (2.0 * radius_m * relief_m.max(0.0)).sqrt() / pixel_m).ceil() as usize + 2
}

/// One case: a context raster and the block of observers in it.
pub struct Case {
    pub name: String,
    pub real: bool,
    pub body: &'static str,
    pub pixel_m: f64,
    pub ctx: HzContext,
    pub rect: Rect,
    /// Lowest terrain of the context (the encoder's floor).
    pub terrain_min_m: f64,
    /// Pixels (block coordinates) the stiff check must include.
    pub special: Vec<(usize, usize)>,
    /// Extra frames the stiff check must include (exact pole or corner), with the block pixel
    /// whose horizon they use.
    pub extra_frames: Vec<(Frame, (usize, usize))>,
    pub note: String,
}

impl Case {
    /// A case of a real terrain's block, with no stiff-case extras.
    pub fn real(
        name: String,
        body: &'static str,
        pixel_m: f64,
        ctx: HzContext,
        rect: Rect,
    ) -> Case {
        let terrain_min_m = ctx
            .heights
            .iter()
            .filter(|v| v.is_finite())
            .fold(f64::INFINITY, |m, &v| m.min(v as f64));
        Case {
            name,
            real: true,
            body,
            pixel_m,
            ctx,
            rect,
            terrain_min_m,
            special: Vec::new(),
            extra_frames: Vec::new(),
            note: String::new(),
        }
    }

    /// The block's heights as a height tile without halo (what the Fourier encoder reads for
    /// the floor and the no-data pixels).
    pub fn block_tile(&self) -> HeightTile {
        let n = self.rect.w;
        HeightTile {
            size: n,
            height: (0..n * n)
                .map(|p| {
                    self.ctx.heights[(self.rect.y0 + p / n) * self.ctx.width + self.rect.x0 + p % n]
                })
                .collect(),
            mask: vec![0; n * n],
        }
    }
}

/// The shared real DEMs the benchmarks and the GPU sweep's tests take a block of: (label, path
/// under the shared data folder, body).
pub const REAL_DEMS: [(&str, &str, &str); 6] = [
    ("LDEM_4 (Moon)", "lola_ldem4/LDEM_4.LBL", "moon"),
    ("MEGDR (Mars)", "mola_megt90n000cb/megt90n000cb.lbl", "mars"),
    (
        "Gale (MOLA 463 m)",
        "mola_gale_128ppd_crop/gale-mola.bin",
        "mars",
    ),
    (
        "Shoemaker (LOLA 5 m)",
        "lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif",
        "moon",
    ),
    ("Hawaiʻi (SRTM3)", "srtm3/N19W156.hgt", "earth"),
    ("White Mts (SRTM3)", "srtm3/N44W072.hgt", "earth"),
];

/// A case from a DEM: a `block`² block of observers at the map's centre, in a context reaching
/// as far as a horizon could see, on a face plane whose pixels are the map's.
pub fn dem_case(label: &str, dem: &penumbra::dem::Dem, body: &'static str, block: usize) -> Case {
    let (w, h) = (dem.width(), dem.height());
    let radius_m = body_radius(body);
    let pixel_m = dem.pixel_size_m(radius_m);
    let b = block.min(w).min(h);
    let mut all = vec![0.0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            all[r * w + c] = dem.value(c, r).0;
        }
    }
    let (lo, hi) = all
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, u), &v| {
            (l.min(v), u.max(v))
        });
    let margin = reach_px(radius_m, (hi - lo) as f64, pixel_m);
    let (bx, by) = ((w - b) / 2, (h - b) / 2);
    let (cx0, cy0) = (bx.saturating_sub(margin), by.saturating_sub(margin));
    let (cx1, cy1) = ((bx + b + margin).min(w), (by + b + margin).min(h));
    let (cw, ch) = (cx1 - cx0, cy1 - cy0);
    let mut heights = Vec::with_capacity(cw * ch);
    for r in cy0..cy1 {
        heights.extend_from_slice(&all[r * w + cx0..r * w + cx1]);
    }
    let s = (2.0 * radius_m / pixel_m).round();
    let si = s as i64;
    let ctx = HzContext {
        face: Face::Px,
        face_pixels: s,
        origin: ((si - cw as i64) / 2, (si - ch as i64) / 2),
        width: cw,
        height: ch,
        heights,
        radius_m,
    };
    let rect = Rect {
        x0: bx - cx0,
        y0: by - cy0,
        w: b,
        h: b,
    };
    let note = if b < block {
        format!("the whole {w}×{h} map (smaller than the block)")
    } else {
        format!(
            "{b}² block at the map's centre (pixel {bx}, {by} of {w}×{h}), context \
             {cw}×{ch} (reach {margin} px)"
        )
    };
    Case {
        note,
        ..Case::real(label.into(), body, pixel_m, ctx, rect)
    }
}

/// Errors of horizon maps in degrees (RMS, 99th percentile, maximum) and the pixel error
/// rate of the shadow bits they decide, per group of suns (`per_miss[g]` of `per_n`).
#[derive(Clone)]
pub struct ErrStats {
    pub n: u64,
    pub sum2: f64,
    pub max: f64,
    pub hist: Vec<u32>,
    pub per_miss: Vec<u64>,
    pub per_n: u64,
}

impl ErrStats {
    pub fn new(groups: usize) -> ErrStats {
        ErrStats {
            n: 0,
            sum2: 0.0,
            max: 0.0,
            hist: vec![0; FINE_BINS + COARSE_BINS + 1],
            per_miss: vec![0; groups],
            per_n: 0,
        }
    }

    #[inline]
    pub fn add(&mut self, e: f64) {
        let a = e.abs();
        self.n += 1;
        self.sum2 += a * a;
        if a > self.max {
            self.max = a;
        }
        let bin = if a < 2.0 {
            (a * 1e4) as usize
        } else {
            (FINE_BINS + ((a - 2.0) * 100.0) as usize).min(FINE_BINS + COARSE_BINS)
        };
        self.hist[bin] += 1;
    }

    pub fn merge(mut self, o: ErrStats) -> ErrStats {
        self.n += o.n;
        self.sum2 += o.sum2;
        self.max = self.max.max(o.max);
        for (a, b) in self.hist.iter_mut().zip(&o.hist) {
            *a += b;
        }
        for (a, b) in self.per_miss.iter_mut().zip(&o.per_miss) {
            *a += b;
        }
        self.per_n += o.per_n;
        self
    }

    pub fn rms(&self) -> f64 {
        (self.sum2 / self.n.max(1) as f64).sqrt()
    }

    /// Upper edge of the bin holding the 99th percentile.
    pub fn p99(&self) -> f64 {
        let target = (self.n as f64 * 0.99).ceil() as u64;
        let mut acc = 0u64;
        for (b, &c) in self.hist.iter().enumerate() {
            acc += c as u64;
            if acc >= target {
                let edge = if b < FINE_BINS {
                    (b + 1) as f64 * 1e-4
                } else {
                    2.0 + (b - FINE_BINS + 1) as f64 * 0.01
                };
                return edge.min(self.max);
            }
        }
        self.max
    }
}

/// Unit direction at elevation `el_deg` whose plane azimuth is `phi` (radians).
pub fn sun_dir(f: &Frame, phi: f64, el_deg: f64) -> Vec3 {
    let (s, c) = phi.sin_cos();
    let w = [
        c * f.ua[0] + s * f.va[0],
        c * f.ua[1] + s * f.va[1],
        c * f.ua[2] + s * f.va[2],
    ];
    let wu = w[0] * f.up[0] + w[1] * f.up[1] + w[2] * f.up[2];
    let t = [
        w[0] - wu * f.up[0],
        w[1] - wu * f.up[1],
        w[2] - wu * f.up[2],
    ];
    let tn = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    let (se, ce) = el_deg.to_radians().sin_cos();
    [
        ce * t[0] / tn + se * f.up[0],
        ce * t[1] / tn + se * f.up[1],
        ce * t[2] / tn + se * f.up[2],
    ]
}

/// The lit fraction by `Model::Exact`, skipping the model where the answer is plain: when the
/// horizon over the disc's plane-azimuth span (its rim's extremes at 1.5 radii, sampled at 17
/// points and at every 1°, 30° and 45° node, where linear interpolations have their kinks) is
/// more than 0.05° clear of the disc's elevations el ± r, the disc is wholly lit (1) or wholly
/// hidden (0) — what Exact returns there up to rounding (~1e-16) — at a fraction of the cost.
pub fn lit_exact(f: &Frame, phi: f64, el: f64, r: f64, hor: &dyn Fn(f64) -> f64) -> f64 {
    let s = sun_dir(f, phi, el);
    let sun = Sun {
        dir: s,
        radius_deg: r,
    };
    if r > 0.0 && el.abs() < 80.0 && std::env::var_os("PENUMBRA_BENCH_EXACT_ALWAYS").is_none() {
        let cr = |a: Vec3, b: Vec3| -> Vec3 {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let nz = |a: Vec3| -> Vec3 {
            let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            [a[0] / l, a[1] / l, a[2] / l]
        };
        let e_h = nz(cr(s, f.up));
        let e_v = nz(cr(e_h, s));
        let t = (1.5 * r).to_radians().tan();
        let p0 = f.plane_azimuth(s);
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for (x, y) in [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)] {
            let d = [
                s[0] + t * (x * e_h[0] + y * e_v[0]),
                s[1] + t * (x * e_h[1] + y * e_v[1]),
                s[2] + t * (x * e_h[2] + y * e_v[2]),
            ];
            let dp = (f.plane_azimuth(d) - p0 + std::f64::consts::PI).rem_euclid(TAU)
                - std::f64::consts::PI;
            lo = lo.min(dp);
            hi = hi.max(dp);
        }
        let (mut hmin, mut hmax) = (f64::INFINITY, f64::NEG_INFINITY);
        let mut take = |th: f64| {
            let h = hor(th.rem_euclid(TAU));
            hmin = hmin.min(h);
            hmax = hmax.max(h);
        };
        for q in 0..=16 {
            take(p0 + lo + (hi - lo) * q as f64 / 16.0);
        }
        for step in [1.0f64, 30.0, 45.0] {
            let st = step.to_radians();
            let mut k = ((p0 + lo) / st).ceil();
            while k * st <= p0 + hi {
                take(k * st);
                k += 1.0;
            }
        }
        if hmax < el - r - 0.05 {
            return 1.0;
        }
        if hmin > el + r + 0.05 {
            return 0.0;
        }
    }
    lit_fraction(f, &sun, Model::Exact, hor)
}

/// A periodic row of samples at 2πm/len, linearly interpolated at `theta` (radians).
#[inline]
pub fn interp(row: &[f32], theta: f64) -> f64 {
    let a = row.len();
    let x = (theta / TAU).rem_euclid(1.0) * a as f64;
    let i = (x.floor() as usize).min(a - 1);
    let f = x - i as f64;
    row[i] as f64 * (1.0 - f) + row[(i + 1) % a] as f64 * f
}

/// Lit-fraction errors against a reference: mean absolute error and pixel error rate (lit
/// fraction on the other side of ½).
#[derive(Clone, Copy, Default, Serialize)]
pub struct ErrSum {
    pub n: u64,
    pub abs_sum: f64,
    pub max: f64,
    pub wrong: u64,
}

impl ErrSum {
    pub fn add(&mut self, v: f32, r: f32) {
        if !(v.is_finite() && r.is_finite()) {
            return;
        }
        let e = (v - r).abs() as f64;
        self.n += 1;
        self.abs_sum += e;
        self.max = self.max.max(e);
        if (v >= 0.5) != (r >= 0.5) {
            self.wrong += 1;
        }
    }
    pub fn merge(&mut self, o: &ErrSum) {
        self.n += o.n;
        self.abs_sum += o.abs_sum;
        self.max = self.max.max(o.max);
        self.wrong += o.wrong;
    }
    pub fn mae(&self) -> f64 {
        self.abs_sum / self.n.max(1) as f64
    }
    pub fn per(&self) -> f64 {
        100.0 * self.wrong as f64 / self.n.max(1) as f64
    }
}

/// A way to store horizons for lookup: a Fourier pyramid (Fritsch et al. 2025's variants and
/// ours), or a classic map of N f16 samples per pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Variant {
    Fourier {
        k: usize,
        encoding: Encoding,
        layout: Layout,
        sigma: Sigma,
        reduce: Reduce,
    },
    Classic(usize),
}

impl Variant {
    pub fn all() -> Vec<Variant> {
        let mut v = Vec::new();
        for k in [4, 8, 16, 32] {
            for encoding in [Encoding::F16, Encoding::Snorm16] {
                for layout in [Layout::Full, Layout::Multires] {
                    for sigma in [Sigma::None, Sigma::Lanczos] {
                        v.push(Variant::Fourier {
                            k,
                            encoding,
                            layout,
                            sigma,
                            reduce: Reduce::Mean,
                        });
                    }
                }
                // Beyond the paper: reduced groups fitted for bilinear sampling.
                v.push(Variant::Fourier {
                    k,
                    encoding,
                    layout: Layout::Multires,
                    sigma: Sigma::None,
                    reduce: Reduce::Fit,
                });
            }
        }
        v.push(Variant::Classic(8));
        v.push(Variant::Classic(12));
        v
    }

    pub fn name(self) -> String {
        match self {
            Variant::Fourier {
                k,
                encoding,
                layout,
                sigma,
                reduce,
            } => format!(
                "F{k} {} {} {}{}",
                layout.name(),
                encoding.name(),
                if sigma == Sigma::None {
                    "plain"
                } else {
                    "lanczos"
                },
                if reduce == Reduce::Fit { " fit" } else { "" }
            ),
            Variant::Classic(n) => format!("classic {n}"),
        }
    }

    /// The encoder's options of a Fourier variant (None: a classic map).
    pub fn options(self) -> Option<FourierOptions> {
        match self {
            Variant::Fourier {
                k,
                encoding,
                layout,
                sigma,
                reduce,
            } => Some(FourierOptions {
                coefficients: k,
                layout,
                encoding,
                sigma,
                reduce,
                ..Default::default()
            }),
            Variant::Classic(_) => None,
        }
    }

    /// The paper's configuration: 16 coefficients, multires, f16, untapered.
    pub fn is_paper(self) -> bool {
        self == Variant::Fourier {
            k: 16,
            encoding: Encoding::F16,
            layout: Layout::Multires,
            sigma: Sigma::None,
            reduce: Reduce::Mean,
        }
    }

    pub fn bytes_per_tile(self, tile: usize) -> usize {
        match self {
            Variant::Fourier { k, layout, .. } => file_bytes(tile, k, layout),
            Variant::Classic(n) => n * 2 * tile * tile,
        }
    }
}

/// A variant's horizon at one pixel: Fourier coefficients or classic samples.
pub enum Horizon<'a> {
    Fourier(&'a Pyramid),
    Classic(&'a [f32], usize),
}

impl Horizon<'_> {
    /// Fills `buf` with what pixel (i, j) needs (coefficients as [re, im], or the samples).
    pub fn load(&self, n: usize, i: usize, j: usize, buf: &mut Vec<[f64; 2]>) {
        match self {
            Horizon::Fourier(p) => p.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, buf),
            Horizon::Classic(s, m) => {
                buf.clear();
                let p = j * n + i;
                buf.extend(s[p * m..(p + 1) * m].iter().map(|&v| [v as f64, 0.0]));
            }
        }
    }

    pub fn at(&self, buf: &[[f64; 2]], theta: f64) -> f64 {
        match self {
            Horizon::Fourier(_) => evaluate(buf, theta),
            Horizon::Classic(..) => {
                let m = buf.len();
                let x = (theta / TAU).rem_euclid(1.0) * m as f64;
                let i = (x.floor() as usize).min(m - 1);
                let f = x - i as f64;
                buf[i][0] * (1.0 - f) + buf[(i + 1) % m][0] * f
            }
        }
    }
}

/// Baked horizons a renderer looks a pixel's horizon up in: the raw maps (`a` planes of n²
/// elevations, linear between azimuths) or a Fourier pyramid.
pub enum Baked<'a> {
    Raw(&'a [f32], usize),
    Pyramid(&'a Pyramid),
}

/// The lit fraction of `sun` at block pixel (i, j) of an `n`² block, its horizon looked up in
/// `baked` and clamped to the pixel's floor `floor_deg`, with the constant-altitude disc model
/// (Jung et al.'s and Fritsch et al.'s cheapest). `coef` is scratch for the pyramid.
#[allow(clippy::too_many_arguments)]
pub fn lookup_lit(
    frame: &Frame,
    sun: &Sun,
    baked: &Baked,
    i: usize,
    j: usize,
    n: usize,
    floor_deg: f64,
    coef: &mut Vec<[f64; 2]>,
) -> f64 {
    match *baked {
        Baked::Raw(raw, a) => {
            let (plane, p) = (n * n, j * n + i);
            lit_fraction(frame, sun, Model::Constant, &|phi| {
                let f = phi / TAU * a as f64;
                let k0 = (f as usize) % a;
                let w = f - f.floor();
                let lo = (raw[k0 * plane + p] as f64).max(floor_deg);
                let hi = (raw[((k0 + 1) % a) * plane + p] as f64).max(floor_deg);
                lo + (hi - lo) * w
            })
        }
        Baked::Pyramid(p) => {
            p.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, coef);
            let c = &*coef;
            lit_fraction(frame, sun, Model::Constant, &|phi| {
                evaluate(c, phi).max(floor_deg)
            })
        }
    }
}

/// A shadow method as the benchmarks and the report run it: a ray-marching method of the
/// tracer, Sakalauskas' SMap (built once per sun over a block), or a lookup in baked horizons,
/// the raw maps (true) or the paper's Fourier pyramid (false), with the constant-altitude disc.
#[derive(Clone, Debug)]
pub enum ShadowWay {
    Trace(TraceMethod),
    SMap,
    Lookup(bool),
}

impl ShadowWay {
    /// Its name in tables (`a`: the raw maps' azimuths).
    pub fn label(&self, a: usize) -> String {
        match self {
            ShadowWay::Trace(m) => m.label(),
            ShadowWay::SMap => "smap".into(),
            ShadowWay::Lookup(true) => format!("horizon raw {a}, constant"),
            ShadowWay::Lookup(false) => "horizon fourier F16, constant".into(),
        }
    }

    /// Whether it answers 0 or 1 only.
    pub fn hard(&self) -> bool {
        matches!(self, ShadowWay::SMap) || matches!(self, ShadowWay::Trace(m) if m.is_hard())
    }
}
