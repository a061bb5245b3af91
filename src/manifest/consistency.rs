//! The manifest against itself: the fields that describe one thing twice must agree, so that an
//! edit that passes every range check cannot silently change what readers compute (issue 41:
//! `{x}` and `{y}` exchanged in a path pattern, `layout.projection` changed, a run key of any
//! string, `min_m > max_m`). docs/tileset.md, "`tileset.json`".
//!
//! - The tiling run key is recomputed from what it hashes (the tool version, `source.files`,
//!   the albedo source, `parameters`) and compared with `run_key`.
//! - `layout`, `resampling` and `body` must be the ones in `parameters` (which the run key
//!   covers).
//! - Every listed product's path pattern must be the one this penumbra writes.
//! - Every run key is a blake3 hash (64 lower-case hex digits).
//! - Numbers that describe the terrain are in range and ordered (min ≤ max).

use std::path::Path;

use crate::dem::limits::show;
use crate::error::{Error, Result};
use crate::manifest::{HorizonLevelDistance, Tileset};

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

/// A run key: blake3 of the tool `version`, a stage's `format` version strings, the run keys
/// of its `inputs` and its `params`, in that order ([`crate::runner::run_key`] with this tool's
/// version; [`tiling_key`] recomputes a manifest's).
pub fn run_key_of(version: &str, format: &[&str], inputs: &[&str], params: &[&[u8]]) -> String {
    let mut h = blake3::Hasher::new();
    h.update(version.as_bytes());
    for f in format {
        h.update(f.as_bytes());
    }
    for k in inputs {
        h.update(k.as_bytes());
    }
    for p in params {
        h.update(p);
    }
    h.finalize().to_hex().to_string()
}

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
