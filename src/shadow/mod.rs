//! Shadows of a tileset for one sun: the lit fraction of the sun's disc at a point or over a
//! whole tile, and a shaded relief with those shadows, the picture a user looks at first. The
//! sun is fixed by its sub-solar point (a direction in the body frame, at infinity), so its
//! local elevation varies across a tile.
//!
//! One interface, several methods ([`ShadowMethod`]): the ray-marching methods of [`trace`]
//! (the exact `reference`, `uniform` stepping, Jung et al.'s `dp` over a maximum mipmap,
//! Timokhin & Mikhaylyuk's `extrema` traversal) search the terrain itself on the face's
//! extended gnomonic plane, across tile and face edges, as the horizon stage does; `smap`
//! (Sakalauskas' silhouette map, [`smap`]) prepares the same raster once for the sun's
//! direction and then answers each pixel from it; `horizon` looks the baked horizon products
//! up (raw maps or Fourier pyramids).

pub mod smap;
pub mod trace;

use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use crate::cube::{self, dot, Vec3};
use crate::error::{Error, Result};
use crate::fourier::sun::{self, Frame, Model, Sun};
use crate::horizon::stage::{
    check_layout, context_for, coverage_box, margin_for, reach_rad, terrain_range,
};
use crate::horizon::{Context, Rect};
use crate::layout::TileId;
use crate::tileset::Store;

pub use self::trace::{Runs, Tracer};

/// Where the horizon comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum HorizonSource {
    /// The stored raw maps, linearly interpolated in azimuth.
    Raw,
    /// The Fourier pyramids, sampled at each pixel centre as a GPU would.
    Fourier,
}

impl std::str::FromStr for HorizonSource {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "raw" => Ok(HorizonSource::Raw),
            "fourier" => Ok(HorizonSource::Fourier),
            _ => Err(format!("unknown horizon source '{s}' (raw, fourier)")),
        }
    }
}

/// How a shadow is found.
#[derive(Clone, Debug, PartialEq)]
pub enum ShadowMethod {
    /// Search the terrain along the sun's ray ([`trace`]).
    Trace(trace::Method),
    /// Sakalauskas' silhouette map for the sun's direction ([`smap`]; hard shadow), built once
    /// per tile (per point for a query) over the same context raster the tracer searches.
    SMap,
    /// Look the baked horizon up, with a disc model.
    Horizon(HorizonSource, Model),
}

impl ShadowMethod {
    pub fn label(&self) -> String {
        match self {
            ShadowMethod::Trace(m) => m.label(),
            ShadowMethod::SMap => "smap".into(),
            ShadowMethod::Horizon(HorizonSource::Raw, m) => format!("horizon raw {m}"),
            ShadowMethod::Horizon(HorizonSource::Fourier, m) => format!("horizon fourier {m}"),
        }
    }
}

/// The context raster a ray-marching method searches for `tile`: as far as terrain could hide
/// any part of a sun whose lowest point over the tile is `lowest_deg` above the horizontal
/// (and no farther than a horizon could see), capped at `cap_px`.
pub fn shadow_context(
    store: &Store,
    tile: TileId,
    lowest_deg: f64,
    cap_px: u64,
) -> Result<(Context, Rect)> {
    let ts = store.manifest();
    check_layout(store.dir(), ts)?;
    let (tmin, tmax) = terrain_range(ts).unwrap_or((0.0, 0.0));
    let r = ts.body.radius_m;
    // From the lowest observer, the line at the lowest elevation climbs above the highest
    // terrain after ψ = acos(r0·cos e / r_max) − e.
    let e = lowest_deg.clamp(-89.0, 89.0).to_radians();
    let c = ((r + tmin) * e.cos() / (r + tmax)).min(1.0);
    let sun_rad = (c.acos() - e).max(0.0);
    let rad = reach_rad(r, tmin, tmax, tmax).min(sun_rad);
    let reach = margin_for(ts, tile, rad, cap_px);
    let cover = coverage_box(ts, tile.level, tile.face);
    context_for(store, tile, reach.margin_px, cover)
}

/// The lowest elevation (degrees) of the sun's lower limb over `tile`: the sun's elevation is
/// lowest on the tile's border, sampled at 64 points, less 0.05° for the gaps between them.
pub fn lowest_sun_deg(store: &Store, tile: TileId, sun: &Sun) -> f64 {
    let lay = store.manifest().layout;
    let n = lay.tile_size as i64;
    let mut lo = f64::INFINITY;
    for k in 0..64 {
        let e = k % 16 * n / 16;
        let (i, j) = match k / 16 {
            0 => (e, 0),
            1 => (n - 1, e),
            2 => (n - 1 - e, n - 1),
            _ => (0, n - 1 - e),
        };
        let (s, t) = lay.pixel_st(tile, i, j);
        let f = Frame::at(
            tile.face,
            lay.projection.s_to_u(s),
            lay.projection.s_to_u(t),
        );
        lo = lo.min(f.elevation_deg(sun.dir));
    }
    lo - sun.radius_deg - 0.05
}

/// One tile's shadows.
#[derive(Clone, Debug, Serialize)]
pub struct TileShadows {
    pub tile: TileId,
    pub n: usize,
    /// Lit fraction per interior pixel, row-major (NaN: no data).
    #[serde(skip)]
    pub lit: Vec<f32>,
    /// Lambertian shading of the terrain times the lit fraction, with 10 % ambient, in [0, 1]
    /// (NaN: no data).
    #[serde(skip)]
    pub relief: Vec<f32>,
    /// Sun elevation range over the tile's pixels (degrees) and its radius.
    pub sun_elevation_deg: [f64; 2],
    pub sun_radius_deg: f64,
    /// Pixels fully lit, fully shadowed, partly lit, without data.
    pub lit_pixels: u64,
    pub dark_pixels: u64,
    pub partial_pixels: u64,
    pub no_data_pixels: u64,
    /// For `smap`: the map's size and marks.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub smap: Option<SMapStats>,
}

/// What an SMap held and how long it took to build.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct SMapStats {
    /// Maps built (one per tile).
    pub maps: u64,
    pub beams: u64,
    pub samples: u64,
    /// Share of the samples marked black (the silhouette seen from the sun: prefix maxima of
    /// g along their beam), and of those that are local maxima (Sakalauskas' Eq. 1).
    pub marked_fraction: f64,
    pub silhouette_fraction: f64,
    /// Largest map held at once.
    pub bytes: u64,
    pub build_s: f64,
}

impl SMapStats {
    /// The statistics of one map built in `build_s` seconds.
    pub fn of(map: &smap::SMap, build_s: f64) -> SMapStats {
        let (beams, samples) = map.size();
        SMapStats {
            maps: 1,
            beams: beams as u64,
            samples: samples as u64,
            marked_fraction: map.marked_fraction(),
            silhouette_fraction: map.silhouette_fraction(),
            bytes: map.bytes() as u64,
            build_s,
        }
    }

    /// Both maps' statistics together (fractions weighted by samples).
    pub fn merge(self, o: SMapStats) -> SMapStats {
        let n = (self.samples + o.samples).max(1) as f64;
        let w = |a: f64, b: f64| (a * self.samples as f64 + b * o.samples as f64) / n;
        SMapStats {
            maps: self.maps + o.maps,
            beams: self.beams + o.beams,
            samples: self.samples + o.samples,
            marked_fraction: w(self.marked_fraction, o.marked_fraction),
            silhouette_fraction: w(self.silhouette_fraction, o.silhouette_fraction),
            bytes: self.bytes.max(o.bytes),
            build_s: self.build_s + o.build_s,
        }
    }
}

/// The sun's centre at one surface point, from the point's gnomonic (u, v) on a face: the
/// sine of its elevation and its plane azimuth, without building a [`Frame`] (a hard mask
/// needs only these; the same formulas as [`Frame::elevation_deg`] and
/// [`Frame::plane_azimuth`]).
#[derive(Clone, Copy, Debug)]
pub struct CentreAt {
    pub sin_el: f64,
    pub phi: f64,
}

/// A face's axes, for [`centre_at`].
#[derive(Clone, Copy, Debug)]
pub struct FaceAxes {
    n: Vec3,
    ua: Vec3,
    va: Vec3,
}

impl FaceAxes {
    pub fn new(face: cube::Face) -> FaceAxes {
        let (n, ua, va) = face.axes();
        FaceAxes { n, ua, va }
    }
}

/// See [`CentreAt`]; `s` is the unit sun direction.
#[inline]
pub fn centre_at(ax: &FaceAxes, u: f64, v: f64, s: Vec3) -> CentreAt {
    let p = [
        ax.n[0] + u * ax.ua[0] + v * ax.va[0],
        ax.n[1] + u * ax.ua[1] + v * ax.va[1],
        ax.n[2] + u * ax.ua[2] + v * ax.va[2],
    ];
    let inv = 1.0 / dot(p, p).sqrt();
    let up = [p[0] * inv, p[1] * inv, p[2] * inv];
    let (np, nt) = (dot(ax.n, up), dot(ax.n, s));
    let x = dot(ax.ua, s) * np - dot(ax.ua, up) * nt;
    let y = dot(ax.va, s) * np - dot(ax.va, up) * nt;
    let phi = y.atan2(x);
    CentreAt {
        sin_el: dot(s, up).clamp(-1.0, 1.0),
        phi: if phi < 0.0 {
            phi + std::f64::consts::TAU
        } else {
            phi
        },
    }
}

/// Whether the sun's centre is above a horizon of `horizon_deg` degrees (a hard shadow's
/// decision; the horizon already floored).
#[inline]
pub fn centre_above(c: &CentreAt, horizon_deg: f64) -> bool {
    c.sin_el > horizon_deg.to_radians().sin()
}

/// Largest context margin (pixels) the ray-marching methods search around a tile.
pub const MAX_MARGIN_PX: u64 = 4096;

/// Checks a sub-solar point (degrees).
pub fn check_subsolar(sun_lat: f64, sun_lon: f64) -> Result<()> {
    if !(sun_lat.is_finite() && (-90.0..=90.0).contains(&sun_lat)) {
        return Err(Error::param(
            "sun_lat",
            format!("{sun_lat} is outside −90..=90 degrees"),
        ));
    }
    if !(sun_lon.is_finite() && (-180.0..=360.0).contains(&sun_lon)) {
        return Err(Error::param(
            "sun_lon",
            format!("{sun_lon} is outside −180..=360 degrees"),
        ));
    }
    Ok(())
}

/// A tile the tileset records as fully lit for every sun high enough: left out of the horizon
/// computation (`products.horizon.pruned`, docs/horizons.md) or stored as a Fourier pyramid
/// marked fully lit (`products.fourier.min_sun_el_deg`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordedLit {
    /// The tile is fully lit for a sun whose lower limb is at or above this (degrees).
    pub lower_limb_deg: f64,
    /// An upper bound of the tile's horizon elevation (degrees).
    pub bound_deg: f64,
    /// `pruned` (the raw maps' list) or `fourier` (a pyramid marked fully lit).
    pub source: &'static str,
}

impl RecordedLit {
    /// Whether a sun at elevation `el_deg` (its centre) of radius `radius_deg` is above it.
    pub fn lights(&self, el_deg: f64, radius_deg: f64) -> bool {
        el_deg - radius_deg >= self.lower_limb_deg
    }

    /// The refusal for a sun whose lower limb reaches `low_deg`, below the threshold: the tile
    /// keeps no horizon for it.
    pub fn refuse(&self, tile: TileId, low_deg: f64) -> Error {
        Error::usage(format!(
            "tile {tile} is recorded fully lit for suns whose lower limb is at or above {:.4}° \
             (its horizon never rises above {:.4}°; {}), and keeps no horizon below that; the \
             sun here reaches down to {low_deg:.4}°, which is not a sun the tileset was made \
             for: use a ray-marching method, or recompute the horizons without leaving tiles out",
            self.lower_limb_deg,
            self.bound_deg,
            match self.source {
                "pruned" => "the horizon stage left it out",
                _ => "its Fourier pyramid is marked fully lit",
            }
        ))
    }
}

/// Whether `tile` is recorded fully lit ([`RecordedLit`]) where `from` reads its horizon: the
/// raw maps' list of tiles left out, the Fourier pyramid's mark, or (None: a method that needs
/// no horizon) either.
pub fn recorded_lit(
    store: &Store,
    tile: TileId,
    from: Option<HorizonSource>,
) -> Result<Option<RecordedLit>> {
    let p = &store.manifest().products;
    if from != Some(HorizonSource::Fourier) {
        if let Some((t, b)) = p.horizon.as_ref().and_then(|h| h.pruned_tile(tile)) {
            return Ok(Some(RecordedLit {
                lower_limb_deg: t,
                bound_deg: b as f64,
                source: "pruned",
            }));
        }
    }
    if from != Some(HorizonSource::Raw) {
        if let Some(f) = p
            .fourier
            .as_ref()
            .filter(|f| f.levels.contains(&tile.level))
        {
            if let Some(m) = f.min_sun_el_deg {
                let pyr = store.fourier(tile)?;
                if pyr.fully_lit {
                    // Marked where the horizon is at most min_sun_el − the recorded radius.
                    return Ok(Some(RecordedLit {
                        lower_limb_deg: m - f.sun_radius_deg.unwrap_or(0.0),
                        bound_deg: pyr.max_horizon_deg as f64,
                        source: "fourier",
                    }));
                }
            }
        }
    }
    Ok(None)
}

/// The per-pixel lit fraction of one method over one tile.
enum Source<'a> {
    /// Fully lit for this sun ([`RecordedLit`]).
    Lit,
    Raw(Vec<f32>, usize),
    Fourier(crate::fourier::Pyramid),
    Trace(Tracer<'a>, Rect, &'a trace::Method),
    SMap(Box<smap::SMap>, &'a Context, Rect),
}

/// Checks that the tileset holds what `method` reads at `level`: an exit-2 error naming what
/// to run first otherwise.
pub fn check_products(store: &Store, method: &ShadowMethod, level: u8) -> Result<()> {
    let ts = store.manifest();
    let dir = store.dir();
    let (levels, name) = match method {
        ShadowMethod::Trace(_) | ShadowMethod::SMap => {
            check_layout(dir, ts)?;
            return Ok(());
        }
        ShadowMethod::Horizon(HorizonSource::Raw, _) => (
            ts.products.horizon.as_ref().map(|h| h.levels.clone()),
            "raw horizon maps (`penumbra horizon`, or `--keep-raw` with `--fourier`)",
        ),
        ShadowMethod::Horizon(HorizonSource::Fourier, _) => (
            ts.products.fourier.as_ref().map(|f| f.levels.clone()),
            "Fourier pyramids (`penumbra horizon --fourier` or `penumbra fourier`)",
        ),
    };
    match levels {
        None => Err(store.missing(&format!(
            "tileset has no {name}: make them first, or use a ray-marching method (--method dp)"
        ))),
        Some(l) if !l.contains(&level) => Err(Error::usage(format!(
            "level {level} has no {name} in {} (levels {l:?})",
            dir.display()
        ))),
        Some(_) => Ok(()),
    }
}

/// Shadows of `tile` for a sun over (sun_lat, sun_lon) (degrees) by `method`.
pub fn tile_shadows(
    dir: &Path,
    tile: TileId,
    sun_lat: f64,
    sun_lon: f64,
    sun_distance_au: Option<f64>,
    method: &ShadowMethod,
) -> Result<TileShadows> {
    check_subsolar(sun_lat, sun_lon)?;
    let store = Store::open(dir)?;
    let ts = store.manifest();
    if !ts.has_tile(tile) {
        return Err(Error::usage(format!(
            "{} has no tile {tile}: `penumbra info {}` lists the coverage",
            dir.display(),
            dir.display()
        )));
    }
    let dist = crate::fourier::stage::sun_distance(sun_distance_au, &ts.body.name)?;
    check_products(&store, method, tile.level)?;
    let lay = ts.layout;
    let n = lay.tile_size as usize;
    let r = ts.body.radius_m;
    let tmin = terrain_range(ts).map_or(0.0, |t| t.0);
    let s_dir = cube::latlon_to_dir(sun_lat.to_radians(), sun_lon.to_radians());
    let radius_deg = sun::sun_radius_deg(dist);
    let sun = Sun {
        dir: s_dir,
        radius_deg,
    };
    let ctx_rect;
    let mut smap_stats = None;
    let heights = store.height(tile)?.expect("covered");
    let halo = lay.halo as usize;
    // A tile recorded fully lit: lit wherever the sun's lower limb clears the threshold; a
    // horizon lookup has nothing to answer below it.
    let recorded = recorded_lit(
        &store,
        tile,
        match method {
            ShadowMethod::Horizon(src, _) => Some(*src),
            _ => None,
        },
    )?;
    let all_lit = match recorded {
        Some(rec) => {
            let mut low = f64::INFINITY;
            for j in 0..n {
                for i in 0..n {
                    if heights.height[(j + halo) * heights.size + i + halo].is_nan() {
                        continue;
                    }
                    let (s, t) = lay.pixel_st(tile, i as i64, j as i64);
                    let (u, v) = (lay.projection.s_to_u(s), lay.projection.s_to_u(t));
                    low = low.min(Frame::at(tile.face, u, v).elevation_deg(s_dir) - radius_deg);
                }
            }
            let lit = low >= rec.lower_limb_deg;
            if !lit && matches!(method, ShadowMethod::Horizon(..)) {
                return Err(rec.refuse(tile, low));
            }
            lit
        }
        None => false,
    };
    let source = match method {
        _ if all_lit => Source::Lit,
        ShadowMethod::Horizon(HorizonSource::Raw, _) => {
            let e = store.horizon(tile)?;
            let a = e.len() / (n * n);
            Source::Raw(e, a)
        }
        ShadowMethod::Horizon(HorizonSource::Fourier, _) => {
            let p = store.fourier(tile)?;
            if p.fully_lit {
                // Marked without a threshold in the manifest (refused when it is read).
                return Err(Error::usage(format!(
                    "tile {tile} is stored as fully lit (no horizon kept): rebuild the pyramids \
                     without a minimum sun elevation to render it, or use a ray-marching method"
                )));
            }
            Source::Fourier(p)
        }
        ShadowMethod::Trace(m) => {
            let low = lowest_sun_deg(&store, tile, &sun);
            ctx_rect = shadow_context(&store, tile, low, MAX_MARGIN_PX)?;
            Source::Trace(Tracer::new(&ctx_rect.0, tmin), ctx_rect.1, m)
        }
        ShadowMethod::SMap => {
            let low = lowest_sun_deg(&store, tile, &sun);
            ctx_rect = shadow_context(&store, tile, low, MAX_MARGIN_PX)?;
            let t0 = std::time::Instant::now();
            let map = smap::SMap::build(&ctx_rect.0, s_dir, ctx_rect.1, tmin);
            smap_stats = Some(SMapStats::of(&map, t0.elapsed().as_secs_f64()));
            Source::SMap(Box::new(map), &ctx_rect.0, ctx_rect.1)
        }
    };
    let model = match method {
        ShadowMethod::Horizon(_, m) => *m,
        ShadowMethod::Trace(_) | ShadowMethod::SMap => Model::Exact,
    };
    // Position of a stored pixel (halo included) in metres, body frame.
    let size = heights.size as i64;
    let pos = |i: i64, j: i64| -> Option<Vec3> {
        let (x, y) = (i + halo as i64, j + halo as i64);
        if !(0..size).contains(&x) || !(0..size).contains(&y) {
            return None;
        }
        let h = heights.height[y as usize * heights.size + x as usize];
        if !h.is_finite() {
            return None;
        }
        let d = lay.pixel_dir(tile, i, j);
        let k = r + h as f64;
        Some([d[0] * k, d[1] * k, d[2] * k])
    };
    let source = &source;
    let rows: Vec<(Vec<f32>, Vec<f32>, [f64; 2])> = (0..n)
        .into_par_iter()
        .map(|j| {
            let mut lit = vec![f32::NAN; n];
            let mut relief = vec![f32::NAN; n];
            let mut el_range = [f64::INFINITY, f64::NEG_INFINITY];
            let mut coef = Vec::new();
            let mut work = trace::Work::default();
            let mut samples = match source {
                Source::Raw(_, a) => vec![0.0f32; *a],
                _ => Vec::new(),
            };
            for i in 0..n {
                let Some(p) = pos(i as i64, j as i64) else {
                    continue;
                };
                let (s, t) = lay.pixel_st(tile, i as i64, j as i64);
                let (u, v) = (lay.projection.s_to_u(s), lay.projection.s_to_u(t));
                let frame = Frame::at(tile.face, u, v);
                let h0 = heights.height[(j + halo) * heights.size + i + halo] as f64;
                let floor = crate::fourier::stage::floor_deg(r, tmin, h0);
                let el = frame.elevation_deg(s_dir);
                el_range[0] = el_range[0].min(el);
                el_range[1] = el_range[1].max(el);
                let f = match source {
                    _ if recorded.is_some_and(|r| r.lights(el, radius_deg)) => 1.0,
                    Source::Lit => 1.0,
                    Source::Fourier(pyr) => {
                        pyr.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, &mut coef);
                        let c = &coef;
                        sun::lit_fraction(&frame, &sun, model, &|phi| {
                            crate::fourier::evaluate(c, phi).max(floor)
                        })
                    }
                    Source::Raw(e, _) => {
                        for (k, v) in samples.iter_mut().enumerate() {
                            *v = e[k * n * n + j * n + i].max(floor as f32);
                        }
                        let sm = &samples;
                        sun::lit_fraction(&frame, &sun, model, &|phi| {
                            crate::fourier::series::interpolate_samples(sm, phi)
                        })
                    }
                    Source::Trace(tr, rect, m) => {
                        tr.lit(rect.x0 + i, rect.y0 + j, &sun, m, &mut work)
                    }
                    Source::SMap(map, ctx, rect) => map.lit(ctx, rect.x0 + i, rect.y0 + j),
                };
                lit[i] = f as f32;
                // Lambert from the central differences of the pixel positions (halo: one
                // pixel beyond the tile's edge is there).
                let shade = match (
                    pos(i as i64 + 1, j as i64),
                    pos(i as i64 - 1, j as i64),
                    pos(i as i64, j as i64 - 1),
                    pos(i as i64, j as i64 + 1),
                ) {
                    (Some(e), Some(w), Some(nn), Some(ss)) => {
                        let a3 = [e[0] - w[0], e[1] - w[1], e[2] - w[2]];
                        let b3 = [nn[0] - ss[0], nn[1] - ss[1], nn[2] - ss[2]];
                        let mut nrm = [
                            a3[1] * b3[2] - a3[2] * b3[1],
                            a3[2] * b3[0] - a3[0] * b3[2],
                            a3[0] * b3[1] - a3[1] * b3[0],
                        ];
                        if dot(nrm, p) < 0.0 {
                            nrm = [-nrm[0], -nrm[1], -nrm[2]];
                        }
                        let l = dot(nrm, nrm).sqrt();
                        if l > 0.0 {
                            (dot(nrm, s_dir) / l).max(0.0)
                        } else {
                            0.0
                        }
                    }
                    _ => dot(frame.up, s_dir).max(0.0),
                };
                relief[i] = (0.1 + 0.9 * shade * f) as f32;
            }
            (lit, relief, el_range)
        })
        .collect();
    let mut out = TileShadows {
        tile,
        n,
        lit: Vec::with_capacity(n * n),
        relief: Vec::with_capacity(n * n),
        sun_elevation_deg: [f64::INFINITY, f64::NEG_INFINITY],
        sun_radius_deg: radius_deg,
        lit_pixels: 0,
        dark_pixels: 0,
        partial_pixels: 0,
        no_data_pixels: 0,
        smap: smap_stats,
    };
    for (l, rl, e) in rows {
        out.sun_elevation_deg[0] = out.sun_elevation_deg[0].min(e[0]);
        out.sun_elevation_deg[1] = out.sun_elevation_deg[1].max(e[1]);
        out.lit.extend(l);
        out.relief.extend(rl);
    }
    [
        out.lit_pixels,
        out.dark_pixels,
        out.partial_pixels,
        out.no_data_pixels,
    ] = classify(&out.lit);
    Ok(out)
}

/// Pixels fully lit, fully shadowed, partly lit and without data (NaN) of a lit-fraction image.
pub fn classify(lit: &[f32]) -> [u64; 4] {
    let mut c = [0u64; 4];
    for &v in lit {
        let k = match v {
            v if v.is_nan() => 3,
            v if v >= 1.0 => 0,
            v if v <= 0.0 => 1,
            _ => 2,
        };
        c[k] += 1;
    }
    c
}

/// Write a `w`×`h` lit-fraction image as PNG, and optionally the shaded relief as PNG and the
/// lit fraction as float EXR, each atomically.
pub fn write_images(
    w: usize,
    h: usize,
    lit: &[f32],
    relief: &[f32],
    out: &Path,
    relief_out: Option<&Path>,
    exr_out: Option<&Path>,
) -> Result<()> {
    write_grey_png(out, w, h, lit)?;
    if let Some(r) = relief_out {
        write_grey_png(r, w, h, relief)?;
    }
    if let Some(e) = exr_out {
        write_lit_exr(e, w, h, lit)?;
    }
    Ok(())
}

pub use crate::format::lit::{write_grey_png, write_lit_exr, NO_DATA_RGB};

/// Most output pixels and tiles of a region.
pub const MAX_REGION_PX: usize = 8192 * 8192;
pub const MAX_REGION_TILES: usize = 64;

/// Shadows over a latitude/longitude box, resampled (nearest pixel) onto an equirectangular
/// grid at the level's pixel size.
#[derive(Clone, Debug, Serialize)]
pub struct RegionShadows {
    /// [lat0, lat1, lon0, lon1], degrees.
    pub bbox: [f64; 4],
    pub level: u8,
    pub width: usize,
    pub height: usize,
    /// Grid step, degrees (rows from lat1 down, columns from lon0 east).
    pub step_deg: f64,
    pub method: String,
    #[serde(skip)]
    pub lit: Vec<f32>,
    #[serde(skip)]
    pub relief: Vec<f32>,
    pub tiles: Vec<String>,
    pub sun_elevation_deg: [f64; 2],
    pub sun_radius_deg: f64,
    pub lit_pixels: u64,
    pub dark_pixels: u64,
    pub partial_pixels: u64,
    pub no_data_pixels: u64,
    /// For `smap`: the maps' sizes and marks over all tiles.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub smap: Option<SMapStats>,
}

/// Checks a box [lat0, lat1, lon0, lon1] (degrees).
pub fn check_bbox(b: [f64; 4]) -> Result<()> {
    let [lat0, lat1, lon0, lon1] = b;
    let bad = |what: String| Err(Error::param("bbox", what));
    if b.iter().any(|v| !v.is_finite()) {
        return bad(format!("{b:?} holds a value that is not a number"));
    }
    if !(-90.0..=90.0).contains(&lat0) || !(-90.0..=90.0).contains(&lat1) || lat0 >= lat1 {
        return bad(format!(
            "latitudes {lat0}..{lat1}: give LAT0 < LAT1 within −90..=90"
        ));
    }
    if !(-180.0..=360.0).contains(&lon0)
        || !(-180.0..=360.0).contains(&lon1)
        || lon0 >= lon1
        || lon1 - lon0 > 360.0
    {
        return bad(format!(
            "longitudes {lon0}..{lon1}: give LON0 < LON1 within −180..=360, at most 360 apart"
        ));
    }
    Ok(())
}

/// Shadows of the box `bbox` = [lat0, lat1, lon0, lon1] (degrees) at `level`: every covered
/// tile it touches by [`tile_shadows`], resampled onto a latitude/longitude grid.
pub fn region_shadows(
    dir: &Path,
    level: u8,
    bbox: [f64; 4],
    sun_lat: f64,
    sun_lon: f64,
    sun_distance_au: Option<f64>,
    method: &ShadowMethod,
) -> Result<RegionShadows> {
    check_bbox(bbox)?;
    check_subsolar(sun_lat, sun_lon)?;
    let store = Store::open(dir)?;
    let ts = store.manifest();
    let lay = ts.layout;
    if level >= lay.levels {
        return Err(Error::usage(format!(
            "{} has levels 0..{}; --level {level} is not one",
            dir.display(),
            lay.levels
        )));
    }
    let [lat0, lat1, lon0, lon1] = bbox;
    let step = (lay.centre_pixel_m(level, ts.body.radius_m) / ts.body.radius_m).to_degrees();
    let (w, h) = (
        ((lon1 - lon0) / step).ceil().max(1.0),
        ((lat1 - lat0) / step).ceil().max(1.0),
    );
    if w * h > MAX_REGION_PX as f64 {
        return Err(Error::usage(format!(
            "the box is {w}×{h} pixels at level {level} (at most {MAX_REGION_PX}): ask a \
             coarser --level or a smaller --bbox"
        )));
    }
    let (w, h) = (w as usize, h as usize);
    // Where each output pixel comes from.
    let src: Vec<Option<(TileId, u32, u32)>> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let (r, c) = (p / w, p % w);
            let lat = lat1 - (r as f64 + 0.5) * step;
            let lon = lon0 + (c as f64 + 0.5) * step;
            let d = cube::latlon_to_dir(lat.to_radians(), lon.to_radians());
            let loc = lay.locate(level, d);
            let n = lay.tile_size as f64;
            ts.has_tile(loc.tile).then(|| {
                (
                    loc.tile,
                    loc.px.round().clamp(0.0, n - 1.0) as u32,
                    loc.py.round().clamp(0.0, n - 1.0) as u32,
                )
            })
        })
        .collect();
    let mut tiles: Vec<TileId> = src.iter().flatten().map(|s| s.0).collect();
    tiles.sort();
    tiles.dedup();
    if tiles.is_empty() {
        return Err(Error::usage(format!(
            "no tile of level {level} covers the box {bbox:?}: `penumbra info {}` lists the \
             coverage",
            dir.display()
        )));
    }
    if tiles.len() > MAX_REGION_TILES {
        return Err(Error::usage(format!(
            "the box touches {} tiles of level {level} (at most {MAX_REGION_TILES}): ask a \
             coarser --level or a smaller --bbox",
            tiles.len()
        )));
    }
    check_products(&store, method, level)?;
    drop(store);
    let mut out = RegionShadows {
        bbox,
        level,
        width: w,
        height: h,
        step_deg: step,
        method: method.label(),
        lit: vec![f32::NAN; w * h],
        relief: vec![f32::NAN; w * h],
        tiles: tiles.iter().map(|t| t.to_string()).collect(),
        sun_elevation_deg: [f64::INFINITY, f64::NEG_INFINITY],
        sun_radius_deg: 0.0,
        lit_pixels: 0,
        dark_pixels: 0,
        partial_pixels: 0,
        no_data_pixels: 0,
        smap: None,
    };
    for t in &tiles {
        let sh = tile_shadows(dir, *t, sun_lat, sun_lon, sun_distance_au, method)?;
        out.smap = match (out.smap, sh.smap) {
            (Some(a), Some(b)) => Some(a.merge(b)),
            (a, b) => a.or(b),
        };
        out.sun_radius_deg = sh.sun_radius_deg;
        out.sun_elevation_deg[0] = out.sun_elevation_deg[0].min(sh.sun_elevation_deg[0]);
        out.sun_elevation_deg[1] = out.sun_elevation_deg[1].max(sh.sun_elevation_deg[1]);
        for (p, s) in src.iter().enumerate() {
            if let Some((tt, i, j)) = s {
                if tt == t {
                    let k = *j as usize * sh.n + *i as usize;
                    out.lit[p] = sh.lit[k];
                    out.relief[p] = sh.relief[k];
                }
            }
        }
    }
    [
        out.lit_pixels,
        out.dark_pixels,
        out.partial_pixels,
        out.no_data_pixels,
    ] = classify(&out.lit);
    Ok(out)
}
