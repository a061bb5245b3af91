//! The manifest against itself: the fields that describe one thing twice must agree, so that an
//! edit that passes every range check cannot silently change what readers compute (issue 41:
//! `{x}` and `{y}` exchanged in a path pattern, `layout.projection` changed, a run key of any
//! string, `min_m > max_m`). docs/tileset.md, "`tileset.json`".
//!
//! - The tiling run key is recomputed from what it hashes (the tool version, `source.files`,
//!   the albedo source, `parameters`) and compared with `run_key`.
//! - A mosaic's sources (`mosaic`) must be the ones `parameters.mosaic` names, the first of
//!   them `source`.
//! - `layout`, `resampling` and `body` must be the ones in `parameters` (which the run key
//!   covers).
//! - Every listed product's path pattern must be the one this penumbra writes.
//! - Every run key is a blake3 hash (64 lower-case hex digits).
//! - Numbers that describe the terrain are in range and ordered (min ≤ max).
//! - The mip, horizon and Fourier run keys are recomputed from their `run_key_basis` and their
//!   inputs' run keys, and their labels compared with the options their run was given
//!   ([`check_keys`], after the range checks).

use std::path::Path;

use crate::dem::limits::show;
use crate::error::{Error, Result};
use crate::format::mip::Precision;
use crate::format::{KeyBasis, TileCompression};
use crate::manifest::{
    FourierProduct, HorizonLevelDistance, HorizonProduct, MipProduct, MosaicSource, Tileset,
};

const FIX: &str = "the manifest is damaged: restore it, or rerun `penumbra tile`/`bake` into a \
                   fresh folder";

pub(crate) fn bad(path: &Path, field: &str, msg: String) -> Error {
    Error::invalid(path, format!("field `{field}`: {msg}; {FIX}"))
}

pub(crate) fn within(path: &Path, field: &str, v: f64, lo: f64, hi: f64) -> Result<()> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(bad(
            path,
            field,
            format!("{} is outside {}..={}", show(v), show(lo), show(hi)),
        ))
    }
}

pub use crate::format::run_key_of;

/// A blake3 hash as `to_hex` writes it.
fn is_key(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

fn key(path: &Path, field: &str, s: &str) -> Result<()> {
    if is_key(s) {
        return Ok(());
    }
    let shown: String = s.chars().take(80).collect();
    Err(bad(
        path,
        field,
        format!("'{shown}' is not a run key (64 lower-case hex digits of a blake3 hash)"),
    ))
}

/// The run key of the tiling stage as `tiling::tile_dem` makes it, with the tool `version`.
pub fn tiling_key(ts: &Tileset, version: &str) -> String {
    let albedo = ts.products.albedo.as_ref().map(|a| &a.source);
    run_key_of(
        version,
        &[],
        &[],
        &[
            serde_json::to_string(&ts.source.files)
                .unwrap_or_default()
                .as_bytes(),
            serde_json::to_string(&albedo)
                .unwrap_or_default()
                .as_bytes(),
            ts.parameters.to_string().as_bytes(),
        ],
    )
}

/// What `parameters.mosaic` says (the run key covers it) for a mosaic's sources: each source's
/// files and feather, in priority order (`tiling::tile_sources`).
pub fn mosaic_parameters(sources: &[MosaicSource]) -> serde_json::Value {
    serde_json::Value::Array(
        sources
            .iter()
            .map(|m| serde_json::json!({ "files": m.source.files, "feather_px": m.feather_px }))
            .collect(),
    )
}

/// A mosaic's sources: the first is `source`, each in range, and together what `parameters`
/// (which the run key covers) says they are.
fn mosaic(ts: &Tileset, path: &Path) -> Result<()> {
    let r = ts.body.radius_m;
    let said = &ts.parameters["mosaic"];
    if ts.mosaic.is_empty() {
        if !said.is_null() {
            return Err(bad(
                path,
                "mosaic",
                "is absent but the tiles were made from a mosaic (parameters.mosaic)".into(),
            ));
        }
        return Ok(());
    }
    if ts.mosaic[0].source != ts.source {
        return Err(bad(
            path,
            "mosaic[0].source",
            "is not `source`: the first source of a mosaic is its primary".into(),
        ));
    }
    for (k, m) in ts.mosaic.iter().enumerate() {
        let s = &m.source;
        within(
            path,
            &format!("mosaic[{k}].source.pixel_size_m"),
            s.pixel_size_m,
            1e-3,
            2.0 * std::f64::consts::PI * r,
        )?;
        within(
            path,
            &format!("mosaic[{k}].source.height_shift_m"),
            s.height_shift_m,
            -r,
            r,
        )?;
        if let Some(d) = s.datum_radius_m {
            within(
                path,
                &format!("mosaic[{k}].source.datum_radius_m"),
                d,
                1.0,
                1e9,
            )?;
        }
    }
    if &mosaic_parameters(&ts.mosaic) != said {
        return Err(bad(
            path,
            "mosaic",
            "names other sources or feathers than the tiles were made from (parameters.mosaic)"
                .into(),
        ));
    }
    Ok(())
}

fn ordered(path: &Path, field: &str, lo: f64, hi: f64) -> Result<()> {
    if lo <= hi {
        return Ok(());
    }
    Err(bad(
        path,
        field,
        format!("the minimum {} is above the maximum {}", show(lo), show(hi)),
    ))
}

fn same_pattern(path: &Path, field: &str, p: &str, want: &str) -> Result<()> {
    if p == want {
        return Ok(());
    }
    Err(bad(
        path,
        field,
        format!(
            "path pattern '{p}' is not '{want}', the one the files were written with: a reader \
             would open other tiles' files (placeholders exchanged or moved)"
        ),
    ))
}

fn distances(path: &Path, field: &str, d: &[HorizonLevelDistance], ts: &Tileset) -> Result<()> {
    // Nothing on a sphere is farther than half its circumference.
    let half_km = std::f64::consts::PI * ts.body.radius_m / 1000.0;
    for (k, l) in d.iter().enumerate() {
        if l.level >= ts.layout.levels {
            return Err(bad(
                path,
                &format!("{field}[{k}].level"),
                format!("{} is not a level of this tileset", l.level),
            ));
        }
        within(
            path,
            &format!("{field}[{k}].needed_km"),
            l.needed_km,
            0.0,
            half_km,
        )?;
        within(
            path,
            &format!("{field}[{k}].max_margin_px"),
            l.max_margin_px as f64,
            0.0,
            (1u64 << 24) as f64,
        )?;
    }
    Ok(())
}

/// Check what the manifest says twice, and the terrain numbers' order; `path` is the
/// manifest's file (for messages).
pub fn check(ts: &Tileset, path: &Path) -> Result<()> {
    use crate::format::{albedo, fourier, height, horizon, mip};
    let r = ts.body.radius_m;
    ordered(
        path,
        "body.relief_m",
        ts.body.relief_m.0,
        ts.body.relief_m.1,
    )?;

    // Identity: every run key a hash; the tiling key recomputed.
    key(path, "run_key", &ts.run_key)?;
    let ours = env!("CARGO_PKG_VERSION");
    if tiling_key(ts, &ts.tool.version) != ts.run_key && tiling_key(ts, ours) != ts.run_key {
        return Err(bad(
            path,
            "run_key",
            "is not the hash of the tool version, source.files, the albedo source and \
             parameters it was made from: one of them was edited"
                .into(),
        ));
    }
    // What `parameters` says (and the run key covers) is what the other fields say.
    let params = &ts.parameters;
    let opts = &params["options"];
    let agree = |field: &str, have: serde_json::Value, said: &serde_json::Value| {
        if &have == said {
            Ok(())
        } else {
            Err(bad(
                path,
                field,
                format!("is {have} but the tiles were made with {said} (parameters)"),
            ))
        }
    };
    agree(
        "layout.projection",
        json(&ts.layout.projection),
        &opts["projection"],
    )?;
    agree(
        "layout.tile_size",
        json(&ts.layout.tile_size),
        &opts["tile_size"],
    )?;
    agree("layout.halo", json(&ts.layout.halo), &opts["halo"])?;
    agree("layout.levels", json(&ts.layout.levels), &params["levels"])?;
    agree("resampling", json(&ts.resampling), &opts["resampling"])?;
    agree("body", json(&ts.body), &params["body"])?;

    // Source.
    let src = &ts.source;
    within(
        path,
        "source.pixel_size_m",
        src.pixel_size_m,
        1e-3,
        2.0 * std::f64::consts::PI * r,
    )?;
    within(path, "source.height_shift_m", src.height_shift_m, -r, r)?;
    if let Some(d) = src.datum_radius_m {
        within(path, "source.datum_radius_m", d, 1.0, 1e9)?;
    }
    mosaic(ts, path)?;

    // Products: patterns, keys, terrain numbers.
    let p = &ts.products;
    if let Some(h) = &p.height {
        same_pattern(
            path,
            "products.height.path",
            &h.path,
            height::HEIGHT_PATTERN,
        )?;
        within(path, "products.height.min_m", h.min_m, -r, r)?;
        within(path, "products.height.max_m", h.max_m, -r, r)?;
        ordered(path, "products.height.min_m", h.min_m, h.max_m)?;
    }
    if let Some(a) = &p.albedo {
        same_pattern(
            path,
            "products.albedo.path",
            &a.path,
            albedo::ALBEDO_PATTERN,
        )?;
    }
    if let Some(m) = &p.mip {
        same_pattern(path, "products.mip.max_path", &m.max_path, mip::MAX_PATTERN)?;
        same_pattern(
            path,
            "products.mip.minmax_path",
            &m.minmax_path,
            mip::MINMAX_PATTERN,
        )?;
        same_pattern(
            path,
            "products.mip.face_path",
            &m.face_path,
            mip::FACE_PATTERN,
        )?;
        if let Some(c) = &m.face_chunk_path {
            same_pattern(
                path,
                "products.mip.face_chunk_path",
                c,
                mip::FACE_CHUNK_PATTERN,
            )?;
        }
        key(path, "products.mip.run_key", &m.run_key)?;
        within(path, "products.mip.global_min_m", m.global_min_m, -r, r)?;
        within(path, "products.mip.global_max_m", m.global_max_m, -r, r)?;
        ordered(
            path,
            "products.mip.global_min_m",
            m.global_min_m,
            m.global_max_m,
        )?;
        for (k, l) in m.levels.iter().enumerate() {
            let f = format!("products.mip.levels[{k}]");
            if let Some(v) = l.min_m {
                within(path, &format!("{f}.min_m"), v, -r, r)?;
            }
            if let Some(v) = l.max_m {
                within(path, &format!("{f}.max_m"), v, -r, r)?;
            }
            if let (Some(a), Some(b)) = (l.min_m, l.max_m) {
                ordered(path, &format!("{f}.min_m"), a, b)?;
            }
        }
    }
    if let Some(h) = &p.horizon {
        same_pattern(path, "products.horizon.path", &h.path, horizon::PATTERN)?;
        key(path, "products.horizon.run_key", &h.run_key)?;
        ordered(
            path,
            "products.horizon.terrain_min_m",
            h.terrain_min_m,
            h.terrain_max_m,
        )?;
        distances(path, "products.horizon.distances", &h.distances, ts)?;
    }
    if let Some(f) = &p.fourier {
        same_pattern(path, "products.fourier.path", &f.path, fourier::PATTERN)?;
        key(path, "products.fourier.run_key", &f.run_key)?;
        ordered(
            path,
            "products.fourier.terrain_min_m",
            f.terrain_min_m,
            f.terrain_max_m,
        )?;
        distances(path, "products.fourier.distances", &f.distances, ts)?;
    }
    Ok(())
}

/// A field as JSON, for comparison with `parameters`.
fn json<T: serde::Serialize>(v: &T) -> serde_json::Value {
    serde_json::to_value(v).unwrap_or(serde_json::Value::Null)
}

// ---------------------------------------------------------------------------------------------
// The stage products' run keys

/// The mip, horizon and Fourier entries' run keys recomputed from their `run_key_basis` (what
/// the stage hashed besides its inputs' run keys: the tool version, its format strings, its
/// parameters as text) and the run keys of the products they were made from, and their labels
/// (precision, azimuths, method, levels, encoding, …) compared with the options the run that
/// made the files was given. A mip entry written before the basis was recorded has its key
/// recomputed from its fields (the one option it does not record, the compression, tried
/// both ways); a horizon or Fourier entry without one is checked as a hash only (its files'
/// headers are still checked against its labels on every read). Runs after every range check
/// ([`crate::manifest::validate`]), so that a value out of range is named as such first.
pub fn check_keys(ts: &Tileset, path: &Path) -> Result<()> {
    let p = &ts.products;
    if let Some(m) = &p.mip {
        mip_key(ts, m, path)?;
    }
    if let Some(h) = &p.horizon {
        horizon_key(ts, h, path)?;
    }
    if let Some(f) = &p.fourier {
        fourier_key(ts, f, path)?;
    }
    Ok(())
}

/// The height pattern the stages hashed.
fn height_path<'a>(ts: &'a Tileset, path: &Path, field: &str) -> Result<&'a str> {
    ts.products
        .height
        .as_ref()
        .map(|h| h.path.as_str())
        .ok_or_else(|| {
            bad(
                path,
                field,
                "is made from the height tiles, but the manifest lists none (`products.height`)"
                    .into(),
            )
        })
}

/// Parameter `i` of `field`'s basis, which must hold `count`, as a JSON object (the options the
/// run was given).
fn options(
    path: &Path,
    field: &str,
    b: &KeyBasis,
    count: usize,
    i: usize,
) -> Result<serde_json::Value> {
    if b.params.len() != count {
        return Err(bad(
            path,
            &format!("{field}.run_key_basis.params"),
            format!(
                "holds {} parameters, but the stage hashes {count}",
                b.params.len()
            ),
        ));
    }
    match serde_json::from_str::<serde_json::Value>(&b.params[i]) {
        Ok(v) if v.is_object() => Ok(v),
        _ => Err(bad(
            path,
            &format!("{field}.run_key_basis.params[{i}]"),
            "is not the stage's options as a JSON object".into(),
        )),
    }
}

/// A label against what the run that made the files was given (`by`: the basis).
fn agree(
    path: &Path,
    field: &str,
    label: serde_json::Value,
    given: &serde_json::Value,
    by: &str,
) -> Result<()> {
    if &label == given {
        return Ok(());
    }
    Err(bad(
        path,
        field,
        format!("is {label}, but the run that made the files was given {given} ({by})"),
    ))
}

/// A field against the one it was copied from (`from`).
fn twice(
    path: &Path,
    field: &str,
    have: serde_json::Value,
    other: serde_json::Value,
    from: &str,
) -> Result<()> {
    if have == other {
        return Ok(());
    }
    Err(bad(
        path,
        field,
        format!("is {have}, but `{from}`, which it was copied from, is {other}"),
    ))
}

/// A parameter the basis holds against the manifest field it must equal.
fn same_param(path: &Path, field: &str, param: &str, want: &str, of: &str) -> Result<()> {
    if param == want {
        return Ok(());
    }
    Err(bad(
        path,
        field,
        format!("is '{param}', but `{of}` is '{want}'"),
    ))
}

/// The key recomputed against the one recorded (checked before the labels: when it matches,
/// the basis is what the run hashed, and a label that disagrees with it is the field edited).
fn recomputed(path: &Path, field: &str, key: &str, want: &str, of: &str) -> Result<()> {
    if key == want {
        return Ok(());
    }
    Err(bad(
        path,
        &format!("{field}.run_key"),
        format!(
            "is not the hash of `{field}.run_key_basis` (the tool version, format and \
             parameters the stage hashed) and {of}: one of them was edited"
        ),
    ))
}

/// The levels a run computed when asked for `asked` (`null`: `all`), as the stages pick them
/// (sorted, each once); None when `asked` is not a list of levels.
fn levels_of(asked: &serde_json::Value, all: &[u8]) -> Option<Vec<u8>> {
    match asked {
        serde_json::Value::Null => Some(all.to_vec()),
        serde_json::Value::Array(a) => {
            let mut l: Vec<u8> = a
                .iter()
                .map(|v| v.as_u64().and_then(|x| u8::try_from(x).ok()))
                .collect::<Option<_>>()?;
            l.sort_unstable();
            l.dedup();
            Some(l)
        }
        _ => None,
    }
}

/// A `levels` label against the levels the run computed.
fn levels(
    path: &Path,
    field: &str,
    label: &[u8],
    asked: &serde_json::Value,
    all: &[u8],
    by: &str,
) -> Result<()> {
    if levels_of(asked, all).as_deref() == Some(label) {
        return Ok(());
    }
    Err(bad(
        path,
        field,
        format!(
            "is {label:?}, but the run that made the files was asked for levels {asked} ({by})"
        ),
    ))
}

/// Options the mip stage hashed, as its options serialise (`mip::MipOptions`; a test there
/// keeps the two alike): for mip entries written before `run_key_basis` was recorded.
#[derive(serde::Serialize)]
struct MipKeyOptions {
    precision: Precision,
    compression: TileCompression,
}

/// The options text the mip stage hashed for `precision` and `compression`, as a mip entry
/// without `run_key_basis` is checked against.
pub(crate) fn legacy_mip_options(precision: Precision, compression: TileCompression) -> String {
    serde_json::to_string(&MipKeyOptions {
        precision,
        compression,
    })
    .unwrap_or_default()
}

fn mip_key(ts: &Tileset, m: &MipProduct, path: &Path) -> Result<()> {
    let f = "products.mip";
    let height = height_path(ts, path, f)?;
    let Some(b) = &m.run_key_basis else {
        return legacy_mip_key(ts, m, height, path);
    };
    // The key first: when it is the basis's, the basis is what the run hashed, and a label
    // that disagrees with it is the field edited.
    recomputed(
        path,
        f,
        &m.run_key,
        &b.key(&[&ts.run_key]),
        "the height tiles' run key",
    )?;
    let by = "`products.mip.run_key_basis`";
    let opts = options(path, f, b, 2, 1)?;
    same_param(
        path,
        "products.mip.run_key_basis.params[0]",
        &b.params[0],
        height,
        "products.height.path",
    )?;
    agree(
        path,
        "products.mip.precision",
        json(&m.precision),
        &opts["precision"],
        by,
    )
}

/// A mip entry without `run_key_basis`: its key recomputed from the tool version recorded (or
/// ours), the height tiles' run key and pattern and its `precision`, with either compression.
fn legacy_mip_key(ts: &Tileset, m: &MipProduct, height: &str, path: &Path) -> Result<()> {
    use crate::format::mip::MIP_FORMAT;
    let ours = env!("CARGO_PKG_VERSION");
    let made_with = |precision: Precision| {
        [ts.tool.version.as_str(), ours].iter().any(|v| {
            [TileCompression::Zip, TileCompression::None]
                .into_iter()
                .any(|compression| {
                    let opts = legacy_mip_options(precision, compression);
                    run_key_of(
                        v,
                        &[MIP_FORMAT],
                        &[&ts.run_key],
                        &[height.as_bytes(), opts.as_bytes()],
                    ) == m.run_key
                })
        })
    };
    if made_with(m.precision) {
        return Ok(());
    }
    if let Some(p) = [Precision::F32, Precision::F16]
        .into_iter()
        .find(|&p| p != m.precision && made_with(p))
    {
        return Err(bad(
            path,
            "products.mip.precision",
            format!(
                "is {}, but the run key is that of {} mipmaps",
                m.precision.name(),
                p.name()
            ),
        ));
    }
    Err(bad(
        path,
        "products.mip.run_key",
        "is not the hash of the tool version, the mip format, the height tiles' run key and \
         pattern and the mip options of any run (this entry records no `run_key_basis`): one of \
         them was edited"
            .into(),
    ))
}

/// What a horizon entry, or a streamed Fourier entry, says of the horizons, and the fields
/// that say it.
struct HorizonLabels<'a> {
    field: &'a str,
    azimuths: usize,
    method: (&'a str, &'a str),
    near_px: (&'a str, Option<f64>),
    levels: &'a [u8],
    terrain: (f64, f64),
    /// The raw maps' precision (a raw horizon entry only).
    precision: Option<&'a str>,
    /// The threshold the raw maps' entry says tiles were left out below (a raw horizon entry
    /// only).
    lit_above: Option<Option<f64>>,
}

/// The horizon stage's basis (the height pattern, its options, "tmin tmax", "fine margin N")
/// against the entry's labels; its options.
fn horizon_run(
    ts: &Tileset,
    path: &Path,
    b: &KeyBasis,
    l: &HorizonLabels,
) -> Result<serde_json::Value> {
    let f = l.field;
    let by = format!("`{f}.run_key_basis`");
    let opts = options(path, f, b, 4, 1)?;
    same_param(
        path,
        &format!("{f}.run_key_basis.params[0]"),
        &b.params[0],
        height_path(ts, path, f)?,
        "products.height.path",
    )?;
    let terrain: Vec<f64> = b.params[2]
        .split(' ')
        .map(|x| x.parse().unwrap_or(f64::NAN))
        .collect();
    for (k, name) in ["terrain_min_m", "terrain_max_m"].into_iter().enumerate() {
        let have = [l.terrain.0, l.terrain.1][k];
        if terrain.len() != 2 || terrain[k] != have {
            return Err(bad(
                path,
                &format!("{f}.{name}"),
                format!(
                    "is {}, but the run that made the files bounded its search by the terrain \
                     '{}' ({by})",
                    show(have),
                    b.params[2]
                ),
            ));
        }
    }
    agree(
        path,
        &format!("{f}.azimuths"),
        json(&l.azimuths),
        &opts["azimuths"],
        &by,
    )?;
    agree(
        path,
        &format!("{f}.{}", l.method.0),
        json(&l.method.1),
        &opts["method"],
        &by,
    )?;
    // The near field is recorded for the fast method only.
    let near = if opts["method"] == "fast" {
        opts["near_px"].clone()
    } else {
        serde_json::Value::Null
    };
    agree(
        path,
        &format!("{f}.{}", l.near_px.0),
        json(&l.near_px.1),
        &near,
        &by,
    )?;
    let all: Vec<u8> = (0..ts.layout.levels).collect();
    levels(
        path,
        &format!("{f}.levels"),
        l.levels,
        &opts["levels"],
        &all,
        &by,
    )?;
    if let Some(p) = l.precision {
        agree(
            path,
            &format!("{f}.precision"),
            json(&p),
            &opts["precision"],
            &by,
        )?;
    }
    if let Some(t) = l.lit_above {
        agree(
            path,
            &format!("{f}.pruned.lit_above_deg"),
            json(&t),
            &opts["lit_above_deg"],
            &by,
        )?;
    }
    Ok(opts)
}

fn horizon_key(ts: &Tileset, h: &HorizonProduct, path: &Path) -> Result<()> {
    let Some(b) = &h.run_key_basis else {
        return Ok(());
    };
    let l = HorizonLabels {
        field: "products.horizon",
        azimuths: h.azimuths,
        method: ("method", &h.method),
        near_px: ("near_px", h.near_px),
        levels: &h.levels,
        terrain: (h.terrain_min_m, h.terrain_max_m),
        precision: Some(&h.precision),
        lit_above: Some(h.pruned.as_ref().map(|p| p.lit_above_deg)),
    };
    recomputed(
        path,
        "products.horizon",
        &h.run_key,
        &b.key(&[&ts.run_key]),
        "the height tiles' run key",
    )?;
    horizon_run(ts, path, b, &l).map(|_| ())
}

fn fourier_key(ts: &Tileset, f: &FourierProduct, path: &Path) -> Result<()> {
    let Some(b) = &f.run_key_basis else {
        return Ok(());
    };
    let field = "products.fourier";
    let by = "`products.fourier.run_key_basis`";
    let (opts, lit_above) = if f.source == "raw" {
        let h = ts.products.horizon.as_ref().ok_or_else(|| {
            bad(
                path,
                "products.fourier.source",
                "says the pyramids were made from stored raw horizon maps, but the manifest \
                 lists none (`products.horizon`)"
                    .into(),
            )
        })?;
        recomputed(
            path,
            field,
            &f.run_key,
            &b.key(&[&h.run_key]),
            "the raw horizon maps' run key",
        )?;
        // What the entry copied from the raw maps' entry.
        for (name, have, other, from) in [
            ("azimuths", json(&f.azimuths), json(&h.azimuths), "azimuths"),
            (
                "horizon_method",
                json(&f.horizon_method),
                json(&h.method),
                "method",
            ),
            (
                "horizon_near_px",
                json(&f.horizon_near_px),
                json(&h.near_px),
                "near_px",
            ),
            (
                "horizon_error",
                json(&f.horizon_error),
                json(&h.error),
                "error",
            ),
            (
                "terrain_min_m",
                json(&f.terrain_min_m),
                json(&h.terrain_min_m),
                "terrain_min_m",
            ),
            (
                "terrain_max_m",
                json(&f.terrain_max_m),
                json(&h.terrain_max_m),
                "terrain_max_m",
            ),
            (
                "distances",
                json(&f.distances),
                json(&h.distances),
                "distances",
            ),
        ] {
            twice(
                path,
                &format!("{field}.{name}"),
                have,
                other,
                &format!("products.horizon.{from}"),
            )?;
        }
        let opts = options(path, field, b, 1, 0)?;
        levels(
            path,
            "products.fourier.levels",
            &f.levels,
            &opts["levels"],
            &h.levels,
            by,
        )?;
        (opts, h.pruned.as_ref().map(|p| p.lit_above_deg))
    } else {
        recomputed(
            path,
            field,
            &f.run_key,
            &b.key(&[&ts.run_key]),
            "the height tiles' run key",
        )?;
        let l = HorizonLabels {
            field,
            azimuths: f.azimuths,
            method: ("horizon_method", &f.horizon_method),
            near_px: ("horizon_near_px", f.horizon_near_px),
            levels: &f.levels,
            terrain: (f.terrain_min_m, f.terrain_max_m),
            precision: None,
            lit_above: None,
        };
        let hopts = horizon_run(ts, path, b, &l)?;
        let opts = hopts
            .get("fourier")
            .filter(|o| o.is_object())
            .cloned()
            .ok_or_else(|| {
                bad(
                    path,
                    "products.fourier.source",
                    "says the pyramids were streamed from the horizon stage, but the options \
                     it was given hold none (`run_key_basis`)"
                        .into(),
                )
            })?;
        (opts, hopts["lit_above_deg"].as_f64())
    };
    for (name, label) in [
        ("coefficients", json(&f.coefficients)),
        ("layout", json(&f.layout)),
        ("encoding", json(&f.encoding)),
        ("sigma", json(&f.sigma)),
        ("reduce", json(&f.reduce)),
        ("max_error_deg", json(&f.max_error_deg)),
    ] {
        agree(path, &format!("{field}.{name}"), label, &opts[name], by)?;
    }
    // The threshold the pyramids marked fully lit: the one asked, or, with horizons left out,
    // the threshold plus the sun's radius (`fourier::stage::effective_min_sun_el`).
    let asked = opts["min_sun_el_deg"].as_f64();
    let want = crate::fourier::stage::effective_min_sun_el(
        asked,
        lit_above,
        f.sun_radius_deg.unwrap_or(0.0),
    )
    .map_err(|m| bad(path, &format!("{field}.min_sun_el_deg"), m))?;
    agree(
        path,
        &format!("{field}.min_sun_el_deg"),
        json(&f.min_sun_el_deg),
        &json(&want),
        by,
    )
}
