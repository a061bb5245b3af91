//! Reading `tileset.json` ([`Tileset::load`]) and its limits: every number in range and every path relative and inside the
//! tileset, checked when a tileset is opened so that no reader trusts a damaged manifest.
//! Each error names the manifest and the field.

use std::path::Path;

use super::consistency::{bad, within};
use crate::error::{Error, Result};
use crate::layout::MAX_LEVELS;
use crate::manifest::{
    Tileset, FORMAT, FORMAT_VERSION, MANIFEST, MAX_FEATHER_PX, MAX_MOSAIC_SOURCES,
};

impl Tileset {
    /// Read and validate the manifest of the tileset in `dir` (checked here).
    pub fn load(dir: &Path) -> Result<Tileset> {
        let path = dir.join(MANIFEST);
        if !path.exists() {
            return Err(Error::invalid(
                &path,
                "no tileset manifest here: point at a folder made by `penumbra tile` or `penumbra bake`",
            ));
        }
        let bytes = crate::fsio::read_capped(&path, MAX_MANIFEST_BYTES, "a tileset manifest")?;
        let de = &mut serde_json::Deserializer::from_slice(&bytes);
        let t: Tileset = serde_path_to_error::deserialize(de).map_err(|e| {
            let field = e.path().to_string();
            Error::invalid(
                &path,
                format!(
                    "manifest is not valid at field `{field}`: {}; restore it, or rerun \
                     `penumbra tile`/`bake` into a fresh folder",
                    e.inner()
                ),
            )
        })?;
        if t.format != FORMAT || t.format_version > FORMAT_VERSION {
            return Err(Error::unsupported(
                &path,
                format!(
                    "format {} v{} (this penumbra reads {FORMAT} up to v{FORMAT_VERSION})",
                    t.format, t.format_version
                ),
            ));
        }
        if t.format_version < FORMAT_VERSION {
            return Err(Error::unsupported(
                &path,
                format!(
                    "tileset format v{} was written by a penumbra whose files carry no identity \
                     or hash (v{FORMAT_VERSION} checks every file it reads against both); \
                     rebuild it: rerun `penumbra tile`/`bake` with the same DEM and options into \
                     a fresh folder, then the stages it had (`mip`, `horizon`, `fourier`)",
                    t.format_version
                ),
            ));
        }
        check(&t, &path)?;
        Ok(t)
    }
}

pub use crate::manifest::MAX_MANIFEST_BYTES;

fn finite(path: &Path, field: &str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(bad(path, field, format!("{v} is not a finite number")))
    }
}

/// A recorded horizon error budget: against the reference, degrees within 0..=180 (a
/// difference of two elevations), p99 and RMS no larger than the largest error, mean and
/// excess within ±max, samples no fewer than pixels.
fn horizon_error(path: &Path, field: &str, e: &crate::format::horizon::HorizonError) -> Result<()> {
    if e.against != "reference" {
        return Err(bad(
            path,
            &format!("{field}.against"),
            format!("'{}' is not reference", e.against),
        ));
    }
    within(path, &format!("{field}.max_deg"), e.max_deg, 0.0, 180.0)?;
    let m = e.max_deg * (1.0 + 1e-9);
    within(path, &format!("{field}.rms_deg"), e.rms_deg, 0.0, m)?;
    within(path, &format!("{field}.p99_deg"), e.p99_deg, 0.0, m)?;
    within(path, &format!("{field}.mean_deg"), e.mean_deg, -m, m)?;
    within(
        path,
        &format!("{field}.max_above_deg"),
        e.max_above_deg,
        0.0,
        m,
    )?;
    if e.samples > e.pixels.saturating_mul(4096) || e.pixels > e.samples.max(1) * 4096 {
        return Err(bad(
            path,
            &format!("{field}.samples"),
            format!(
                "{} samples cannot come from {} pixels of 4..=4096 azimuths",
                e.samples, e.pixels
            ),
        ));
    }
    Ok(())
}

/// A product path pattern: relative, inside one of the product's folders, no `..`, only the
/// placeholders `placeholders` (each required), ending in `ext`.
fn pattern(
    path: &Path,
    field: &str,
    p: &str,
    dirs: &[&str],
    placeholders: &[&str],
    ext: &str,
) -> Result<()> {
    let fail = |m: &str| Err(bad(path, field, format!("path pattern '{p}' {m}")));
    if p.is_empty() || p.len() > 256 {
        return fail("is empty or longer than 256 characters");
    }
    if p.starts_with('/') || p.contains('\\') || p.contains(':') || p.contains('\0') {
        return fail("is not a relative path inside the tileset");
    }
    let parts: Vec<&str> = p.split('/').collect();
    if parts
        .iter()
        .any(|c| c.is_empty() || *c == "." || *c == "..")
    {
        return fail("has an empty, '.' or '..' component");
    }
    if !dirs.contains(&parts[0]) {
        return fail(&format!(
            "must lie in the product's folder ({})",
            dirs.join(" or ")
        ));
    }
    let mut rest = p.to_string();
    for ph in placeholders {
        if !rest.contains(ph) {
            return fail(&format!("lacks {ph}"));
        }
        rest = rest.replace(ph, "");
    }
    if rest.contains('{') || rest.contains('}') {
        return fail("has an unknown placeholder");
    }
    if !p.ends_with(ext) {
        return fail(&format!("does not end in {ext}"));
    }
    Ok(())
}

const TILE: &[&str] = &["{level}", "{face}", "{y}", "{x}"];

/// Check a parsed manifest; `path` is the manifest's file (for messages).
pub fn check(ts: &Tileset, path: &Path) -> Result<()> {
    let b = &ts.body;
    within(path, "body.radius_m", b.radius_m, 1.0, 1e9)?;
    within(
        path,
        "body.relief_m[0]",
        b.relief_m.0,
        -b.radius_m,
        b.radius_m,
    )?;
    within(
        path,
        "body.relief_m[1]",
        b.relief_m.1,
        -b.radius_m,
        b.radius_m,
    )?;

    let lay = &ts.layout;
    if !(8..=8192).contains(&lay.tile_size) || lay.tile_size % 2 != 0 {
        return Err(bad(
            path,
            "layout.tile_size",
            format!("{} is not an even size from 8 to 8192", lay.tile_size),
        ));
    }
    if lay.halo >= lay.tile_size / 2 {
        return Err(bad(
            path,
            "layout.halo",
            format!("{} is not below half the tile size", lay.halo),
        ));
    }
    if lay.levels == 0 || lay.levels > MAX_LEVELS {
        return Err(bad(
            path,
            "layout.levels",
            format!("{} is outside 1..={MAX_LEVELS}", lay.levels),
        ));
    }

    if ts.coverage.len() != lay.levels as usize {
        return Err(bad(
            path,
            "coverage",
            format!(
                "has {} levels but layout.levels is {}",
                ts.coverage.len(),
                lay.levels
            ),
        ));
    }
    for (i, lc) in ts.coverage.iter().enumerate() {
        let f = format!("coverage[{i}]");
        if lc.level as usize != i {
            return Err(bad(
                path,
                &format!("{f}.level"),
                format!("is {}, expected {i}", lc.level),
            ));
        }
        check_runs(path, &f, lc, lay)?;
    }
    // Tiles tried without data: levels in order, on the layout, none of them present.
    let mut last = None;
    for (i, lc) in ts.no_data.iter().enumerate() {
        let f = format!("no_data[{i}]");
        if lc.level >= lay.levels || last.is_some_and(|l| lc.level <= l) {
            return Err(bad(
                path,
                &format!("{f}.level"),
                format!(
                    "is {}: levels must rise and stay below layout.levels {}",
                    lc.level, lay.levels
                ),
            ));
        }
        last = Some(lc.level);
        check_runs(path, &f, lc, lay)?;
    }
    if !ts.no_data.is_empty() {
        if let Some(t) = ts.no_data_set().intersection(&ts.tile_set()).next() {
            return Err(bad(
                path,
                "no_data",
                format!("lists tile {t}, which the coverage holds: a tile has data or not"),
            ));
        }
    }

    let src = &ts.source;
    finite(path, "source.pixel_size_m", src.pixel_size_m)?;
    finite(path, "source.height_shift_m", src.height_shift_m)?;
    if ts.mosaic.len() == 1 || ts.mosaic.len() > MAX_MOSAIC_SOURCES {
        return Err(bad(
            path,
            "mosaic",
            format!(
                "lists {} sources: a mosaic has 2 ..= {MAX_MOSAIC_SOURCES} (one source is \
                 `source` alone, without `mosaic`)",
                ts.mosaic.len()
            ),
        ));
    }
    for (k, m) in ts.mosaic.iter().enumerate() {
        finite(
            path,
            &format!("mosaic[{k}].source.pixel_size_m"),
            m.source.pixel_size_m,
        )?;
        finite(
            path,
            &format!("mosaic[{k}].source.height_shift_m"),
            m.source.height_shift_m,
        )?;
        within(
            path,
            &format!("mosaic[{k}].feather_px"),
            m.feather_px,
            0.0,
            MAX_FEATHER_PX,
        )?;
    }
    // What the manifest says twice agrees, run keys are hashes, terrain numbers are ordered.
    super::consistency::check(ts, path)?;

    let p = &ts.products;
    if let Some(h) = &p.height {
        pattern(
            path,
            "products.height.path",
            &h.path,
            &["height"],
            TILE,
            ".exr",
        )?;
        within(
            path,
            "products.height.min_m",
            h.min_m,
            -b.radius_m,
            b.radius_m,
        )?;
        within(
            path,
            "products.height.max_m",
            h.max_m,
            -b.radius_m,
            b.radius_m,
        )?;
    }
    if let Some(a) = &p.albedo {
        pattern(
            path,
            "products.albedo.path",
            &a.path,
            &["albedo"],
            TILE,
            ".png",
        )?;
        if !matches!(a.bit_depth, 8 | 16) || !(1..=4).contains(&a.channels) {
            return Err(bad(
                path,
                "products.albedo",
                format!(
                    "bit depth {} with {} channels is not 8/16-bit with 1..=4 channels",
                    a.bit_depth, a.channels
                ),
            ));
        }
    }
    if let Some(m) = &p.mip {
        let dirs = &["maxmip", "minmax"];
        pattern(
            path,
            "products.mip.max_path",
            &m.max_path,
            dirs,
            TILE,
            ".exr",
        )?;
        pattern(
            path,
            "products.mip.minmax_path",
            &m.minmax_path,
            dirs,
            TILE,
            ".exr",
        )?;
        pattern(
            path,
            "products.mip.face_path",
            &m.face_path,
            dirs,
            &["{level}", "{face}"],
            ".exr",
        )?;
        match (&m.face_chunk_path, m.face_chunk_tiles) {
            (None, None) => {}
            (Some(p), Some(c)) => {
                pattern(
                    path,
                    "products.mip.face_chunk_path",
                    p,
                    &["minmax"],
                    &["{level}", "{face}", "{cy}", "{cx}"],
                    ".exr",
                )?;
                if !c.is_power_of_two() || !(2..=1 << 24).contains(&c) {
                    return Err(bad(
                        path,
                        "products.mip.face_chunk_tiles",
                        format!("{c} is not a power of two from 2 to 2^24"),
                    ));
                }
            }
            _ => {
                return Err(bad(
                    path,
                    "products.mip.face_chunk_path",
                    "face_chunk_path and face_chunk_tiles come together".into(),
                ))
            }
        }
        for (k, l) in m.levels.iter().enumerate() {
            if l.level >= lay.levels {
                return Err(bad(
                    path,
                    &format!("products.mip.levels[{k}].level"),
                    format!("{} is not a level of this tileset", l.level),
                ));
            }
        }
    }
    if let Some(h) = &p.horizon {
        pattern(
            path,
            "products.horizon.path",
            &h.path,
            &["horizon"],
            TILE,
            ".exr",
        )?;
        if !(4..=4096).contains(&h.azimuths) {
            return Err(bad(
                path,
                "products.horizon.azimuths",
                format!("{} is outside 4..=4096", h.azimuths),
            ));
        }
        if !matches!(h.precision.as_str(), "f16" | "f32") {
            return Err(bad(
                path,
                "products.horizon.precision",
                format!("'{}' is not f16 or f32", h.precision),
            ));
        }
        if h.method.parse::<crate::format::horizon::Method>().is_err() {
            return Err(bad(
                path,
                "products.horizon.method",
                format!("'{}' is not fast, sweep, exact or reference", h.method),
            ));
        }
        if let Some(n) = h.near_px {
            within(path, "products.horizon.near_px", n, 0.0, 1024.0)?;
        }
        if let Some(e) = &h.error {
            horizon_error(path, "products.horizon.error", e)?;
        }
        if let Some(&l) = h.levels.iter().find(|&&l| l >= lay.levels) {
            return Err(bad(
                path,
                "products.horizon.levels",
                format!("{l} is not a level of this tileset"),
            ));
        }
        within(
            path,
            "products.horizon.terrain_min_m",
            h.terrain_min_m,
            -b.radius_m,
            b.radius_m,
        )?;
        within(
            path,
            "products.horizon.terrain_max_m",
            h.terrain_max_m,
            -b.radius_m,
            b.radius_m,
        )?;
        if let Some(pr) = &h.pruned {
            pruned(path, ts, h, pr)?;
        }
    }
    if let Some(f) = &p.fourier {
        fourier(path, ts, f)?;
    }
    for (name, entry) in &p.extra {
        unlisted(path, name, entry)?;
    }
    // The stage products' run keys and labels against what their runs hashed, once every
    // value is known to be in range.
    super::consistency::check_keys(ts, path)
}

/// The tiles a horizon run left out: a threshold that is an elevation, and each key a tile of
/// the entry's levels in the coverage whose bound is an elevation below the threshold (a tile
/// whose bound is not could not have been left out: a reader would call it lit for suns its
/// horizon may hide).
fn pruned(
    path: &Path,
    ts: &Tileset,
    h: &crate::manifest::HorizonProduct,
    pr: &crate::format::horizon::HorizonPruned,
) -> Result<()> {
    let t = pr.lit_above_deg;
    within(
        path,
        "products.horizon.pruned.lit_above_deg",
        t,
        -90.0,
        90.0,
    )?;
    let field = "products.horizon.pruned.tiles";
    for (k, &b) in &pr.tiles {
        let id = crate::format::horizon::parse_pruned_key(k);
        if !id.is_some_and(|id| h.levels.contains(&id.level) && ts.has_tile(id)) {
            return Err(bad(
                path,
                field,
                format!(
                    "'{k}' is not a tile (level/face/x/y) of the horizon's levels {:?} in the \
                     coverage",
                    h.levels
                ),
            ));
        }
        if !(b.is_finite() && b >= -90.0 && (b as f64) < t) {
            return Err(bad(
                path,
                field,
                format!(
                    "tile {k}'s horizon bound {b}° is not an elevation below lit_above_deg \
                     {t}°: such a tile is not left out"
                ),
            ));
        }
    }
    Ok(())
}

/// Most products the registry does not list, and most names in one's `dirs` or `reads`.
const MAX_UNLISTED: usize = 64;

/// A plain name: a folder of the tileset's top level or a product's name.
fn plain_name(s: &str) -> bool {
    (1..=64).contains(&s.len())
        && s.bytes()
            .next()
            .is_some_and(|b| b.is_ascii_lowercase() || b.is_ascii_digit())
        && s.bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

/// A product the registry does not list: whatever it holds, but the folders it claims (which
/// a later writer removes when it is stale) must be plain top-level names that no listed
/// product owns, and what it reads plain names.
fn unlisted(path: &Path, name: &str, entry: &serde_json::Value) -> Result<()> {
    let field = format!("products.{name}");
    // Keys this penumbra does not know are read past, unless they claim folders.
    let Some(obj) = entry.as_object().filter(|o| o.contains_key("dirs")) else {
        return Ok(());
    };
    if !plain_name(name) {
        return Err(bad(
            path,
            "products",
            format!("'{name}' is not a product name"),
        ));
    }
    let listed = crate::format::LISTED_DIRS;
    for key in ["dirs", "reads"] {
        let Some(v) = obj.get(key) else { continue };
        let names = v
            .as_array()
            .filter(|a| a.len() <= MAX_UNLISTED)
            .ok_or_else(|| {
                bad(
                    path,
                    &format!("{field}.{key}"),
                    format!("not a list of at most {MAX_UNLISTED} names"),
                )
            })?;
        for n in names {
            let ok = n
                .as_str()
                .is_some_and(|n| plain_name(n) && (key == "reads" || !listed.contains(&n)));
            if !ok {
                return Err(bad(
                    path,
                    &format!("{field}.{key}"),
                    format!("{n} is not a plain name of its own"),
                ));
            }
        }
    }
    Ok(())
}

fn fourier(path: &Path, ts: &Tileset, f: &crate::manifest::FourierProduct) -> Result<()> {
    use crate::format::fourier::{self as pyramid, group_list, Encoding, Layout, Reduce, Sigma};
    let (lay, b) = (&ts.layout, &ts.body);
    pattern(
        path,
        "products.fourier.path",
        &f.path,
        &["fourier"],
        TILE,
        ".fhm",
    )?;
    if !(4..=4096).contains(&f.azimuths) {
        return Err(bad(
            path,
            "products.fourier.azimuths",
            format!("{} is outside 4..=4096", f.azimuths),
        ));
    }
    let most = pyramid::max_coefficients(f.azimuths);
    if !(1..=most).contains(&f.coefficients) {
        return Err(bad(
            path,
            "products.fourier.coefficients",
            format!("{} is outside 1..={most}", f.coefficients),
        ));
    }
    let layout: Layout = f
        .layout
        .parse()
        .map_err(|e: String| bad(path, "products.fourier.layout", e))?;
    f.encoding
        .parse::<Encoding>()
        .map_err(|e| bad(path, "products.fourier.encoding", e))?;
    f.sigma
        .parse::<Sigma>()
        .map_err(|e| bad(path, "products.fourier.sigma", e))?;
    f.reduce
        .parse::<Reduce>()
        .map_err(|e| bad(path, "products.fourier.reduce", e))?;
    if let Some(&l) = f.levels.iter().find(|&&l| l >= lay.levels) {
        return Err(bad(
            path,
            "products.fourier.levels",
            format!("{l} is not a level of this tileset"),
        ));
    }
    let n = lay.tile_size as usize;
    if f.groups != group_list(n, f.coefficients, layout) {
        return Err(bad(
            path,
            "products.fourier.groups",
            format!(
                "do not describe {} coefficients of {n}-pixel tiles ({})",
                f.coefficients, f.layout
            ),
        ));
    }
    let bytes = pyramid::file_bytes(n, f.coefficients, layout) as u64;
    if f.bytes_per_tile != bytes {
        return Err(bad(
            path,
            "products.fourier.bytes_per_tile",
            format!("{} is not {bytes}", f.bytes_per_tile),
        ));
    }
    if let Some(e) = f.max_error_deg {
        within(path, "products.fourier.max_error_deg", e, 1e-9, 90.0)?;
    }
    if let Some(e) = f.min_sun_el_deg {
        within(path, "products.fourier.min_sun_el_deg", e, -90.0, 90.0)?;
    }
    if let Some(r) = f.sun_radius_deg {
        within(path, "products.fourier.sun_radius_deg", r, 0.0, 45.0)?;
    }
    if let Some(m) = &f.tile_coefficients {
        if let Some((t, k)) = m.iter().find(|(_, &k)| k > f.coefficients) {
            return Err(bad(
                path,
                "products.fourier.tile_coefficients",
                format!(
                    "tile {t} keeps {k} coefficients, more than {}",
                    f.coefficients
                ),
            ));
        }
    }
    if !matches!(f.source.as_str(), "raw" | "streamed") {
        return Err(bad(
            path,
            "products.fourier.source",
            format!("'{}' is not raw or streamed", f.source),
        ));
    }
    if f.horizon_method
        .parse::<crate::format::horizon::Method>()
        .is_err()
    {
        return Err(bad(
            path,
            "products.fourier.horizon_method",
            format!(
                "'{}' is not fast, sweep, exact or reference",
                f.horizon_method
            ),
        ));
    }
    if let Some(n) = f.horizon_near_px {
        within(path, "products.fourier.horizon_near_px", n, 0.0, 1024.0)?;
    }
    if let Some(e) = &f.horizon_error {
        horizon_error(path, "products.fourier.horizon_error", e)?;
    }
    within(
        path,
        "products.fourier.terrain_min_m",
        f.terrain_min_m,
        -b.radius_m,
        b.radius_m,
    )?;
    within(
        path,
        "products.fourier.terrain_max_m",
        f.terrain_max_m,
        -b.radius_m,
        b.radius_m,
    )?;
    Ok(())
}

/// One level's row runs (`field`: where they are in the manifest): on the layout, counted right.
fn check_runs(
    path: &Path,
    f: &str,
    lc: &crate::manifest::LevelCoverage,
    lay: &crate::layout::Layout,
) -> Result<()> {
    let per = lay.tiles_per_side(lc.level) as u64;
    if lc.tiles_per_face != per * per {
        return Err(bad(
            path,
            &format!("{f}.tiles_per_face"),
            format!("is {}, expected {}", lc.tiles_per_face, per * per),
        ));
    }
    let mut count = 0u64;
    for (face, runs) in &lc.faces {
        for (k, r) in runs.iter().enumerate() {
            let [y, x0, x1] = *r;
            if (y as u64) >= per || (x1 as u64) >= per || x0 > x1 {
                return Err(bad(
                    path,
                    &format!("{f}.faces.{face}[{k}]"),
                    format!("run {r:?} is not [y, x_first, x_last] within 0..{per}"),
                ));
            }
            count += (x1 - x0 + 1) as u64;
        }
    }
    if count != lc.tiles {
        return Err(bad(
            path,
            &format!("{f}.tiles"),
            format!("is {} but its runs hold {count} tiles", lc.tiles),
        ));
    }
    Ok(())
}
