//! The horizon of the pixel over a point: read from the stored raw maps, reconstructed from the
//! Fourier pyramids, or computed on demand; and the sun's visibility there.

use crate::format::horizon::HorizonError;
use std::path::Path;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::fourier::sun::{self, Frame, Model, Sun};
use crate::fourier::Pyramid;
use crate::horizon::stage::{
    check_layout, check_options, default_fine_margin_px, horizons_seeing_rings, interior_max,
    margin_for, reach_rad, terrain_range, tile_rasters, HorizonOptions,
};
use crate::horizon::{compass_azimuth_deg, plane_azimuth, Method, Rect};
use crate::layout::TileId;
use crate::manifest;
use crate::shadow::HorizonSource;
use crate::tileset::Store;

/// Where a queried horizon comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum HorizonFrom {
    /// Stored raw maps of the method and azimuths asked when there are, else computed.
    #[default]
    Auto,
    /// The stored raw maps (an error when there are none for this level).
    Raw,
    /// The Fourier pyramids, evaluated at the pixel centre.
    Fourier,
    /// Computed on demand by the reference method (exact search of every ray).
    Reference,
}

impl std::str::FromStr for HorizonFrom {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(HorizonFrom::Auto),
            "raw" => Ok(HorizonFrom::Raw),
            "fourier" => Ok(HorizonFrom::Fourier),
            "reference" => Ok(HorizonFrom::Reference),
            _ => Err(format!(
                "unknown horizon source '{s}' (auto, raw, fourier, reference)"
            )),
        }
    }
}

/// The horizon of the pixel that contains a point.
#[derive(Clone, Debug, Serialize)]
pub struct HorizonAnswer {
    /// The point asked for.
    pub query_lat_deg: f64,
    pub query_lon_deg: f64,
    /// Centre of the pixel whose horizon this is.
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub height_m: f64,
    pub level: u8,
    pub face: String,
    pub tile: [u32; 2],
    /// Interior pixel (column, row) of the tile.
    pub pixel: [u32; 2],
    pub method: Method,
    /// `stored` (read from the raw maps), `computed` (on demand) or `fourier` (reconstructed
    /// from the pyramids).
    pub source: String,
    pub azimuths: usize,
    /// Compass azimuth of each sample, degrees clockwise from local north, ascending.
    pub azimuth_deg: Vec<f64>,
    /// Horizon elevation above the local horizontal, degrees, for each azimuth.
    pub elevation_deg: Vec<f64>,
    /// The same samples' plane azimuths (the stored convention), degrees.
    pub plane_azimuth_deg: Vec<f64>,
    /// Context searched around the pixel's tile when computed (pixels; 0 otherwise).
    pub margin_px: u64,
    pub needed_margin_px: u64,
    /// The method's error against the reference as the run that stored these horizons
    /// measured it (the sweep method's error budget); absent for the other methods and for
    /// horizons computed on demand.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<HorizonError>,
}

/// A pixel's horizon as a function of plane azimuth.
pub(crate) enum Profile {
    /// `A` samples at plane azimuths 2πk/A, linearly interpolated between.
    Samples(Vec<f32>),
    /// The series' coefficients.
    Series(Vec<[f64; 2]>),
}

impl Profile {
    /// Elevation (degrees) at plane azimuth `phi` (radians).
    pub(crate) fn at(&self, phi: f64) -> f64 {
        match self {
            Profile::Samples(s) => crate::fourier::series::interpolate_samples(s, phi),
            Profile::Series(c) => crate::fourier::evaluate(c, phi),
        }
    }

    /// The lit fraction of `sun`'s disc above this horizon, seen from `frame` (what the shadow
    /// query answers, and what `export` writes per pixel).
    pub(crate) fn lit(&self, frame: &Frame, sun: &Sun, model: Model) -> f64 {
        sun::lit_fraction(frame, sun, model, &|p| self.at(p))
    }
}

/// Raw and computed horizons floored as the pyramids are: below the tangent to the sphere of
/// the lowest terrain lies the body, mapped or not (−90° means no mapped terrain). `height` is
/// the pixel's own height.
pub(crate) fn floor_samples(ts: &manifest::Tileset, height: f32, e: &mut [f32]) {
    if let Some((tmin, _)) = terrain_range(ts) {
        let floor = crate::fourier::stage::floor_deg(ts.body.radius_m, tmin, height as f64);
        for v in e.iter_mut() {
            *v = v.max(floor as f32);
        }
    }
}

/// The local frame at the centre of interior pixel (i, j) of `tile`, and a sun of angular
/// radius `radius_deg` at compass azimuth `sun_az` and elevation `sun_el` (degrees) there.
pub(crate) fn sun_at_pixel(
    lay: &crate::layout::Layout,
    tile: TileId,
    (i, j): (usize, usize),
    (sun_az, sun_el): (f64, f64),
    radius_deg: f64,
) -> (Frame, Sun) {
    let (s, t) = lay.pixel_st(tile, i as i64, j as i64);
    let (u, v) = (lay.projection.s_to_u(s), lay.projection.s_to_u(t));
    let frame = Frame::at(tile.face, u, v);
    let sun = Sun {
        dir: frame.direction(sun_az, sun_el),
        radius_deg,
    };
    (frame, sun)
}

/// The located pixel of a query.
struct Pixel {
    level: u8,
    tile: TileId,
    i: usize,
    j: usize,
    height: f32,
    /// Face coordinates (s, t) of its centre.
    st: (f64, f64),
}

fn locate_pixel(store: &Store, dir: &Path, lat: f64, lon: f64, level: Option<u8>) -> Result<Pixel> {
    super::check_latlon(lat, lon)?;
    let ts = store.manifest();
    check_layout(dir, ts)?;
    let level = super::pick_level(ts, level)?;
    let (tile, px, py) = super::locate(ts, lat, lon, level);
    if !ts.has_tile(tile) {
        return Err(Error::usage(format!(
            "no height tile covers {lat}°, {lon}° at level {level} (tile {tile}): the source DEM \
             does not reach there; `penumbra info {}` lists the coverage",
            dir.display()
        )));
    }
    let lay = ts.layout;
    let n = lay.tile_size as usize;
    let (i, j) = (
        (px.round().max(0.0) as usize).min(n - 1),
        (py.round().max(0.0) as usize).min(n - 1),
    );
    let t = store.height(tile)?.expect("covered");
    let h = lay.halo as usize;
    let height = t.height[(j + h) * t.size + i + h];
    if height.is_nan() {
        return Err(Error::usage(format!(
            "the pixel at {lat}°, {lon}° (level {level}, tile {tile}, pixel {i},{j}) has no data: \
             it has no horizon"
        )));
    }
    Ok(Pixel {
        level,
        tile,
        i,
        j,
        height,
        st: lay.pixel_st(tile, i as i64, j as i64),
    })
}

/// The pixel's horizon from `from`: its profile, source name, the samples' count and, when
/// computed, the context margins.
/// A pixel's profile, where it came from, the method, the margin searched and needed (px),
/// and the recorded error of the method.
type ProfileFound = (
    Profile,
    &'static str,
    Method,
    u64,
    u64,
    Option<HorizonError>,
);

fn profile(
    store: &Store,
    dir: &Path,
    px: &Pixel,
    from: HorizonFrom,
    opts: &HorizonOptions,
) -> Result<ProfileFound> {
    let ts = store.manifest();
    let n = ts.layout.tile_size as usize;
    let (i, j, level) = (px.i, px.j, px.level);
    if from == HorizonFrom::Fourier {
        let f = ts.products.fourier.as_ref().ok_or_else(|| {
            store.missing(
                "tileset has no Fourier pyramids: make them with `penumbra fourier` or \
                 `penumbra horizon --fourier`",
            )
        })?;
        if !f.levels.contains(&level) {
            return Err(Error::usage(format!(
                "level {level} has no Fourier pyramids in {} (levels {:?}); ask --level {}",
                dir.display(),
                f.levels,
                f.levels.last().copied().unwrap_or(0)
            )));
        }
        let p: Pyramid = store.fourier(px.tile)?;
        if p.fully_lit {
            return Err(Error::usage(format!(
                "tile {} is stored as fully lit (its horizon never rises above {:.3}°, below \
                 --min-sun-el {} minus the sun's radius): it keeps no horizon; rebuild the \
                 pyramids without --min-sun-el to query it",
                px.tile,
                p.max_horizon_deg,
                f.min_sun_el_deg.unwrap_or(f64::NAN)
            )));
        }
        let mut c = Vec::new();
        p.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, &mut c);
        let method = f.horizon_method.parse().unwrap_or(Method::Fast);
        let err = f.horizon_error.clone();
        return Ok((Profile::Series(c), "fourier", method, 0, 0, err));
    }
    let (method, azimuths) = match from {
        HorizonFrom::Reference => (Method::Reference, opts.azimuths),
        _ => (opts.method, opts.azimuths),
    };
    // Stored maps of the same method, azimuth count and (fast) near field.
    let near = (method == Method::Fast).then_some(opts.near_px);
    // A tile the run left out has none: computed on demand (`Raw` refuses, below).
    let stored = ts.products.horizon.as_ref().filter(|p| {
        p.azimuths == azimuths
            && p.method == method.name()
            && p.near_px == near
            && p.levels.contains(&level)
            && p.pruned_tile(px.tile).is_none()
    });
    let stored = match from {
        HorizonFrom::Raw => {
            let h = ts.products.horizon.as_ref().ok_or_else(|| {
                store.missing("tileset has no raw horizon maps: compute them with `penumbra horizon` (or `--keep-raw`)")
            })?;
            if !h.levels.contains(&level) {
                return Err(Error::usage(format!(
                    "level {level} has no raw horizon maps in {} (levels {:?})",
                    dir.display(),
                    h.levels
                )));
            }
            Some(h)
        }
        HorizonFrom::Reference => stored.filter(|h| h.method == "reference"),
        _ => stored,
    };
    if let Some(h) = stored {
        let planes = store.horizon(px.tile)?;
        let e: Vec<f32> = (0..h.azimuths)
            .map(|k| planes[k * n * n + j * n + i])
            .collect();
        let m = h.method.parse().unwrap_or(Method::Fast);
        return Ok((Profile::Samples(e), "stored", m, 0, 0, h.error.clone()));
    }
    let (tmin, tmax) = terrain_range(ts).ok_or_else(|| {
        Error::invalid(
            dir.join(manifest::MANIFEST),
            "tileset records no height range",
        )
    })?;
    let lay = ts.layout;
    let t = store.height(px.tile)?.expect("covered");
    let top = interior_max(&t, lay.halo as usize, n).unwrap_or(px.height);
    let rad = reach_rad(ts.body.radius_m, tmin, tmax, top as f64);
    let reach = margin_for(ts, px.tile, rad, opts.max_margin_px);
    let mut covers = std::collections::HashMap::new();
    let (ctx, rect, rings) = tile_rasters(
        store,
        px.tile,
        reach,
        method,
        opts.fine_margin_px
            .unwrap_or_else(|| default_fine_margin_px(lay.tile_size)),
        &mut covers,
    )?;
    let one = Rect {
        x0: rect.x0 + i,
        y0: rect.y0 + j,
        w: 1,
        h: 1,
    };
    let (samples, _) = horizons_seeing_rings(
        store,
        &ctx,
        one,
        &rings,
        azimuths,
        method,
        opts.near_px,
        None,
        None,
    )?;
    Ok((
        Profile::Samples(samples),
        "computed",
        method,
        reach.margin_px,
        reach.needed_px,
        None,
    ))
}

pub fn horizon(
    dir: &Path,
    lat: f64,
    lon: f64,
    level: Option<u8>,
    opts: &HorizonOptions,
    from: HorizonFrom,
) -> Result<HorizonAnswer> {
    check_options(opts)?;
    let store = Store::open(dir)?;
    let px = locate_pixel(&store, dir, lat, lon, level)?;
    let (prof, source, method, margin, needed, error) = profile(&store, dir, &px, from, opts)?;
    let ts = store.manifest();
    let lay = ts.layout;
    let (s, tt) = px.st;
    let d = lay.st_to_dir(px.tile.face, s, tt);
    let (plat, plon) = crate::cube::dir_to_latlon(d);
    let azimuths = match (&prof, ts.products.fourier.as_ref()) {
        (Profile::Samples(e), _) => e.len(),
        (Profile::Series(_), Some(f)) => f.azimuths,
        (Profile::Series(_), None) => opts.azimuths,
    };
    let (u, v) = (lay.projection.s_to_u(s), lay.projection.s_to_u(tt));
    let mut rows: Vec<(f64, f64, f64)> = (0..azimuths)
        .map(|k| {
            let phi = plane_azimuth(k, azimuths);
            let e = match &prof {
                Profile::Samples(e) => e[k] as f64,
                Profile::Series(_) => prof.at(phi),
            };
            (
                compass_azimuth_deg(px.tile.face, u, v, phi),
                e,
                phi.to_degrees(),
            )
        })
        .collect();
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(HorizonAnswer {
        query_lat_deg: lat,
        query_lon_deg: lon,
        lat_deg: plat.to_degrees(),
        lon_deg: plon.to_degrees(),
        height_m: px.height as f64,
        level: px.level,
        face: px.tile.face.name().into(),
        tile: [px.tile.x, px.tile.y],
        pixel: [px.i as u32, px.j as u32],
        method,
        source: source.into(),
        azimuths,
        azimuth_deg: rows.iter().map(|r| r.0).collect(),
        elevation_deg: rows.iter().map(|r| r.1).collect(),
        plane_azimuth_deg: rows.iter().map(|r| r.2).collect(),
        margin_px: margin,
        needed_margin_px: needed,
        error,
    })
}

/// The sun's visibility at the pixel over a point.
#[derive(Clone, Debug, Serialize)]
pub struct ShadowAnswer {
    pub query_lat_deg: f64,
    pub query_lon_deg: f64,
    /// Centre of the pixel the answer is for.
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub height_m: f64,
    pub level: u8,
    pub face: String,
    pub tile: [u32; 2],
    pub pixel: [u32; 2],
    /// The sun's centre: compass azimuth (clockwise from local north) and elevation above the
    /// local horizontal of the sphere at the pixel, degrees; and its plane azimuth.
    pub sun_azimuth_deg: f64,
    pub sun_elevation_deg: f64,
    pub sun_plane_azimuth_deg: f64,
    /// The sun's apparent radius (degrees) and the distance it comes from (AU).
    pub sun_radius_deg: f64,
    pub sun_distance_au: f64,
    /// The horizon's elevation at the sun's azimuth, degrees, floored at the tangent to the
    /// sphere of the lowest terrain (as the pyramids store it: the body is there, mapped or
    /// not).
    pub horizon_deg: f64,
    /// Fraction of the sun's disc above the horizon, in [0, 1].
    pub lit_fraction: f64,
    pub model: Model,
    /// `stored`, `computed` or `fourier` (as for the horizon query), `traced` for the
    /// ray-marching methods or `smap`.
    pub source: String,
    /// The shadow method: `horizon` (a lookup in the horizon products), `reference`,
    /// `uniform N`, `dp RUNS`, `dp-dda RUNS`, `extrema`, `extrema-soft` or `smap`.
    pub method: String,
    /// For `horizon`: the method that computed the horizon (fast, exact or reference).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub horizon_method: Option<Method>,
    /// Context searched around the pixel's tile by a ray-marching method (pixels; 0 otherwise).
    pub margin_px: u64,
}

/// The lit fraction of the sun's disc at the pixel over (lat, lon) for a sun at compass
/// azimuth `sun_az` and elevation `sun_el` (degrees).
#[allow(clippy::too_many_arguments)]
pub fn shadow(
    dir: &Path,
    lat: f64,
    lon: f64,
    level: Option<u8>,
    sun_az: f64,
    sun_el: f64,
    sun_distance_au: Option<f64>,
    model: Model,
    from: HorizonFrom,
    opts: &HorizonOptions,
    search: Option<&crate::shadow::ShadowMethod>,
) -> Result<ShadowAnswer> {
    use crate::shadow::ShadowMethod;
    if !(sun_az.is_finite() && (-360.0..=720.0).contains(&sun_az)) {
        return Err(Error::param(
            "sun_az",
            format!("{sun_az} is not an azimuth in degrees (−360..720)"),
        ));
    }
    if !(sun_el.is_finite() && (-90.0..=90.0).contains(&sun_el)) {
        return Err(Error::param(
            "sun_el",
            format!("{sun_el} is not an elevation in −90..=90 degrees"),
        ));
    }
    if sun_distance_au.is_some() {
        crate::fourier::stage::sun_distance(sun_distance_au, "")?;
    }
    check_options(opts)?;
    let store = Store::open(dir)?;
    let ts = store.manifest();
    let dist = crate::fourier::stage::sun_distance(sun_distance_au, &ts.body.name)?;
    let px = locate_pixel(&store, dir, lat, lon, level)?;
    let (s, t) = px.st;
    let lay = ts.layout;
    let (frame, sun) = sun_at_pixel(
        &lay,
        px.tile,
        (px.i, px.j),
        (sun_az, sun_el),
        sun::sun_radius_deg(dist),
    );
    let phi = frame.plane_azimuth(sun.dir);
    let d = lay.st_to_dir(px.tile.face, s, t);
    let (plat, plon) = crate::cube::dir_to_latlon(d);
    let answer = |horizon_deg: f64,
                  lit_fraction: f64,
                  source: &str,
                  method: Option<Method>,
                  margin_px: u64| ShadowAnswer {
        query_lat_deg: lat,
        query_lon_deg: lon,
        lat_deg: plat.to_degrees(),
        lon_deg: plon.to_degrees(),
        height_m: px.height as f64,
        level: px.level,
        face: px.tile.face.name().into(),
        tile: [px.tile.x, px.tile.y],
        pixel: [px.i as u32, px.j as u32],
        sun_azimuth_deg: sun_az.rem_euclid(360.0),
        sun_elevation_deg: sun_el,
        sun_plane_azimuth_deg: phi.to_degrees(),
        sun_radius_deg: sun.radius_deg,
        sun_distance_au: dist,
        horizon_deg,
        lit_fraction,
        model,
        source: source.into(),
        method: match search {
            Some(m @ (ShadowMethod::Trace(_) | ShadowMethod::SMap)) => m.label(),
            _ => "horizon".into(),
        },
        horizon_method: method,
        margin_px,
    };
    if let Some(m @ (ShadowMethod::Trace(_) | ShadowMethod::SMap)) = search {
        crate::horizon::stage::check_layout(dir, ts)?;
        let low = sun_el - sun.radius_deg - 0.05;
        let (ctx, rect) = crate::shadow::shadow_context(&store, px.tile, low, opts.max_margin_px)?;
        let margin = (rect.x0.max(rect.y0)) as u64;
        let tmin = terrain_range(ts).map_or(0.0, |t| t.0);
        // A tile recorded fully lit is lit for every sun that clears its threshold.
        if let Some(rec) = crate::shadow::recorded_lit(&store, px.tile, None)? {
            if rec.lights(sun_el, sun.radius_deg) {
                let src = format!("{} (tile recorded fully lit)", m.label());
                return Ok(answer(rec.bound_deg, 1.0, &src, None, margin));
            }
        }
        let (x, y) = (rect.x0 + px.i, rect.y0 + px.j);
        if let ShadowMethod::Trace(m) = m {
            let tracer = crate::shadow::Tracer::new(&ctx, tmin);
            let mut work = crate::shadow::trace::Work::default();
            let t = tracer.trace(x, y, &sun, m, &mut work);
            return Ok(answer(t.horizon_deg, t.lit, "traced", None, margin));
        }
        // The map of this one pixel: every beam it needs, from the raster's sunward edge.
        let one = crate::horizon::Rect {
            x0: x,
            y0: y,
            w: 1,
            h: 1,
        };
        let map = crate::shadow::smap::SMap::build(&ctx, sun.dir, one, tmin);
        return Ok(answer(f64::NAN, map.lit(&ctx, x, y), "smap", None, margin));
    }
    // A tile stored as fully lit (a Fourier pyramid marked so, or left out of the raw maps)
    // answers for suns whose lower limb clears its threshold without a horizon; read from the
    // raw maps, a lower sun is refused (the Fourier pyramid refuses it when it is read; `Auto`
    // computes the horizon on demand).
    let (recorded_from, label) = match from {
        HorizonFrom::Fourier => (
            Some(HorizonSource::Fourier),
            "fourier (tile stored fully lit)",
        ),
        HorizonFrom::Raw | HorizonFrom::Auto => (
            Some(HorizonSource::Raw),
            "stored (tile left out: fully lit)",
        ),
        HorizonFrom::Reference => (None, ""),
    };
    if let Some(src) = recorded_from {
        let level_has = match src {
            HorizonSource::Fourier => ts.products.fourier.as_ref().map(|f| &f.levels),
            HorizonSource::Raw => ts.products.horizon.as_ref().map(|h| &h.levels),
        }
        .is_some_and(|l| l.contains(&px.level));
        if level_has {
            if let Some(rec) = crate::shadow::recorded_lit(&store, px.tile, Some(src))? {
                let method = match src {
                    HorizonSource::Fourier => {
                        ts.products.fourier.as_ref().map(|f| &f.horizon_method)
                    }
                    HorizonSource::Raw => ts.products.horizon.as_ref().map(|h| &h.method),
                }
                .and_then(|m| m.parse().ok());
                if rec.lights(sun_el, sun.radius_deg) {
                    return Ok(answer(rec.bound_deg, 1.0, label, method, 0));
                }
                if from == HorizonFrom::Raw {
                    return Err(rec.refuse(px.tile, sun_el - sun.radius_deg));
                }
            }
        }
    }
    let (mut prof, source, method, _, _, _) = profile(&store, dir, &px, from, opts)?;
    if let Profile::Samples(e) = &mut prof {
        floor_samples(ts, px.height, e);
    }
    let lit = prof.lit(&frame, &sun, model);
    Ok(answer(prof.at(phi), lit, source, Some(method), 0))
}
