//! Scene files: one TOML file says what a scene needs — the body, its elevation sources, the
//! regions to tile and how finely, the shadow methods its renderer uses (hence the products),
//! and the suns it will see. [`parse`] reads and checks one (every error names the line and the
//! key); [`plan`] turns it into the tiles and products to make, and what is left out and why.
//! docs/scenes.md documents the format with examples; [`EMBEDDED`] is the scene `penumbra bake`
//! bakes when given none.

pub mod bake;
pub mod cost;
pub mod plan;
pub mod shards;
pub mod slurm;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use toml::Spanned;

use crate::cube::Projection;
use crate::error::{Error, Result};
use crate::format::horizon::Method as HorizonMethod;
use crate::layout::MAX_LEVELS;
use crate::synthetic::SyntheticSpec;
use crate::tileset::Product;

/// The embedded scene: the synthetic south pole, whole, horizons of level 6 into Fourier
/// pyramids. `penumbra bake` with no scene bakes this.
pub const EMBEDDED: &str = include_str!("embedded.toml");
/// The name the embedded scene goes by in messages and manifests.
pub const EMBEDDED_NAME: &str = "embedded:south-pole.toml";

/// Largest scene file read (bytes).
pub const MAX_SCENE_BYTES: u64 = 1 << 20;
/// Most sources, regions and polygon vertices a scene may list.
pub const MAX_SOURCES: usize = 16;
pub const MAX_REGIONS: usize = 256;
pub const MAX_POLYGON_VERTICES: usize = 100_000;
/// Feather widths accepted (source pixels of the finer source).
pub const MAX_FEATHER_PX: f64 = 256.0;
/// How far a region's finest pixel may be below the finest source covering it: the ratio of
/// the source's pixel to the level's centre pixel. Beyond it a level only interpolates.
pub const DEFAULT_MAX_OVERSAMPLING: f64 = 4.0;

// ---------------------------------------------------------------------------------------------
// The file as written: serde types (unknown keys refused).

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    scene: Spanned<SceneTable>,
    #[serde(default)]
    layout: Option<Spanned<LayoutTable>>,
    #[serde(default)]
    source: Vec<Spanned<SourceTable>>,
    #[serde(default)]
    albedo: Option<Spanned<AlbedoTable>>,
    #[serde(default)]
    region: Vec<Spanned<RegionTable>>,
    #[serde(default)]
    renderer: Option<Spanned<RendererTable>>,
    #[serde(default)]
    sun: Option<Spanned<SunTable>>,
    #[serde(default)]
    horizon: Option<Spanned<HorizonTable>>,
    #[serde(default)]
    fourier: Option<Spanned<FourierTable>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneTable {
    name: Spanned<String>,
    body: Option<Spanned<String>>,
    radius_m: Option<Spanned<f64>>,
    max_oversampling: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LayoutTable {
    tile_size: Option<Spanned<u32>>,
    halo: Option<Spanned<u32>>,
    projection: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SourceTable {
    path: Option<Spanned<String>>,
    /// The reader of `path`: `"auto"` (the native reader the file name chooses) or `"gdal"`.
    format: Option<Spanned<String>>,
    /// `"south-pole"`: the embedded synthetic terrain.
    embedded: Option<Spanned<String>>,
    /// Pixels per side of the embedded terrain.
    size: Option<Spanned<usize>>,
    feather_px: Option<Spanned<f64>>,
    priority: Option<Spanned<i64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AlbedoTable {
    path: Spanned<String>,
    west_lon_deg: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RegionTable {
    name: Spanned<String>,
    body: Option<Spanned<bool>>,
    lat_deg: Option<Spanned<[f64; 2]>>,
    lon_deg: Option<Spanned<[f64; 2]>>,
    cap: Option<Spanned<CapTable>>,
    polygon: Option<Spanned<Vec<[f64; 2]>>>,
    path: Option<Spanned<String>>,
    frame_px: Option<Spanned<[u32; 2]>>,
    fov_deg: Option<Spanned<f64>>,
    texel_px: Option<Spanned<f64>>,
    level: Option<Spanned<i64>>,
    resolution_m: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CapTable {
    lat_deg: f64,
    lon_deg: f64,
    radius_m: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RendererTable {
    #[serde(default)]
    methods: Vec<Spanned<String>>,
    #[serde(default)]
    products: Vec<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SunTable {
    elevation_deg: Option<Spanned<[f64; 2]>>,
    azimuth_deg: Option<Spanned<[f64; 2]>>,
    start: Option<Spanned<String>>,
    end: Option<Spanned<String>>,
    distance_au: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct HorizonTable {
    levels: Option<Spanned<Vec<i64>>>,
    azimuths: Option<Spanned<usize>>,
    method: Option<Spanned<String>>,
    prune: Option<Spanned<bool>>,
    device: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FourierTable {
    coefficients: Option<Spanned<Coefficients>>,
    /// With `coefficients = "auto"`: the report whose recommendation gives K.
    report: Option<Spanned<String>>,
    keep_raw: Option<Spanned<bool>>,
}

/// `coefficients = 16`, or `coefficients = "auto"` (from a `penumbra report`).
#[derive(Deserialize)]
#[serde(untagged)]
enum Coefficients {
    K(usize),
    Word(String),
}

// ---------------------------------------------------------------------------------------------
// The scene as checked.

/// A checked scene.
#[derive(Clone, Debug, Serialize)]
pub struct Scene {
    /// The file it was read from ([`EMBEDDED_NAME`] for the embedded one); relative paths in it
    /// are relative to its folder.
    pub file: PathBuf,
    pub name: String,
    /// A body preset name (or the custom body's name with `radius_m`).
    pub body: Option<String>,
    pub radius_m: Option<f64>,
    pub max_oversampling: f64,
    pub tile_size: u32,
    pub halo: u32,
    pub projection: Projection,
    /// In the file's order (the plan orders them by priority).
    pub sources: Vec<SourceSpec>,
    pub albedo: Option<AlbedoSpec>,
    pub regions: Vec<RegionSpec>,
    pub methods: Vec<RenderMethod>,
    /// Products listed explicitly (beside those the methods read).
    pub products: Vec<Product>,
    pub sun: Option<SunSpec>,
    pub horizon: HorizonSpec,
    pub fourier: FourierSpec,
}

/// Where a source's heights come from.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SourceKind {
    /// A DEM file (resolved against the scene file's folder).
    File(PathBuf),
    /// The embedded synthetic south pole.
    Embedded(SyntheticSpec),
}

#[derive(Clone, Debug, Serialize)]
pub struct SourceSpec {
    pub kind: SourceKind,
    /// The reader of a file source (`format = "gdal"`: through GDAL).
    #[serde(skip_serializing_if = "crate::dem::DemFormat::is_auto")]
    pub format: crate::dem::DemFormat,
    /// Width of the seam where this source gives way to the next below it (its own pixels).
    pub feather_px: f64,
    /// Higher wins; None: by resolution (finer wins).
    pub priority: Option<i64>,
    /// Line of its `[[source]]` table.
    pub line: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct AlbedoSpec {
    pub path: PathBuf,
    pub west_lon_deg: f64,
    pub line: usize,
}

/// A part of the body a scene shows, and how finely.
#[derive(Clone, Debug, Serialize)]
pub struct RegionSpec {
    pub name: String,
    pub shape: RegionShape,
    pub finest: Finest,
    pub line: usize,
}

/// The geometry of a region.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RegionShape {
    /// The whole body (where sources have data).
    Body,
    /// A latitude/longitude box; longitudes may cross ±180° (`lon.0 > lon.1` wraps).
    Box { lat: (f64, f64), lon: (f64, f64) },
    /// Every point within `radius_m` (along the surface) of a centre.
    Cap {
        lat_deg: f64,
        lon_deg: f64,
        radius_m: f64,
    },
    /// A spherical polygon: vertices (lat, lon) in degrees joined by great circles.
    Polygon(Vec<(f64, f64)>),
    /// The tiles a viewer draws along a camera path (CSV `lat_deg,lon_deg,height_m`).
    Path {
        file: PathBuf,
        frame_px: (u32, u32),
        fov_deg: f64,
        texel_px: f64,
    },
}

/// How finely a region is tiled.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Finest {
    /// As finely as the finest source with data there resolves (neither key given).
    Source,
    Level(u8),
    /// The coarsest level whose face-centre pixel is at most this many metres.
    ResolutionM(f64),
}

/// A renderer's shadow method, for the products it reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum RenderMethod {
    Dp,
    DpDda,
    Uniform,
    Extrema,
    ExtremaSoft,
    Smap,
    Reference,
    /// Horizons from the Fourier pyramids.
    Fourier,
    /// Horizons from the raw maps.
    Horizon,
}

/// Every method's name as written in a scene, and the method.
pub const METHODS: &[(&str, RenderMethod)] = &[
    ("dp", RenderMethod::Dp),
    ("dp-dda", RenderMethod::DpDda),
    ("uniform", RenderMethod::Uniform),
    ("extrema", RenderMethod::Extrema),
    ("extrema-soft", RenderMethod::ExtremaSoft),
    ("smap", RenderMethod::Smap),
    ("reference", RenderMethod::Reference),
    ("fourier", RenderMethod::Fourier),
    ("horizon", RenderMethod::Horizon),
];

/// Every product's name as written in a scene.
pub const PRODUCTS: &[(&str, Product)] = &[
    ("height", Product::Height),
    ("albedo", Product::Albedo),
    ("mip", Product::Mip),
    ("horizon", Product::Horizon),
    ("fourier", Product::Fourier),
];

impl RenderMethod {
    pub fn name(self) -> &'static str {
        METHODS
            .iter()
            .find(|(_, m)| *m == self)
            .map(|(n, _)| *n)
            .unwrap_or("?")
    }

    /// The products the method reads, with why (for `plan`): every method reads the height
    /// tiles; DP walks the maximum mipmap (Jung et al. 2020) and the extrema traversal the
    /// (min, max) mipmap (Timokhin & Mikhaylyuk), both in the `mip` product; `fourier` reads
    /// the pyramids (Fritsch et al. 2025), `horizon` the raw maps; uniform stepping, SMap and the
    /// reference search the heights alone.
    pub fn reads(self) -> &'static [Product] {
        use RenderMethod::*;
        match self {
            Dp | DpDda | Extrema | ExtremaSoft => &[Product::Height, Product::Mip],
            Uniform | Smap | Reference => &[Product::Height],
            Fourier => &[Product::Height, Product::Fourier],
            Horizon => &[Product::Height, Product::Horizon],
        }
    }
}

/// The suns a scene will see.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SunSpec {
    /// Elevations (and optionally compass azimuths) of the sun's centre, degrees.
    Range {
        elevation_deg: (f64, f64),
        azimuth_deg: Option<(f64, f64)>,
        distance_au: Option<f64>,
        line: usize,
    },
    /// Every moment between two UTC instants (ISO 8601), with the body's rotation and orbit.
    Span {
        start: String,
        end: String,
        distance_au: Option<f64>,
        line: usize,
    },
}

#[derive(Clone, Debug, Serialize)]
pub struct HorizonSpec {
    /// Levels that get horizons; None: every level a region asks for.
    pub levels: Option<Vec<u8>>,
    pub azimuths: usize,
    pub method: HorizonMethod,
    /// Leave out the horizons of tiles that provably cannot shadow the scene's suns.
    pub prune: bool,
    /// Where the sweep runs (`penumbra bake SCENE`; `--device` overrides it).
    #[serde(skip_serializing_if = "is_auto")]
    pub device: crate::horizon::device::DeviceChoice,
}

fn is_auto(d: &crate::horizon::device::DeviceChoice) -> bool {
    *d == crate::horizon::device::DeviceChoice::Auto
}

#[derive(Clone, Debug, Serialize)]
pub struct FourierSpec {
    pub coefficients: usize,
    pub keep_raw: bool,
    /// Where K came from with `coefficients = "auto"`: the report read.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub auto_from: Option<PathBuf>,
    /// Why `coefficients = "auto"` found no K (no report yet, a damaged one, another
    /// scene's): `plan` and `bake` refuse the scene with it.
    #[serde(skip)]
    pub auto_error: Option<String>,
}

/// The report `coefficients = "auto"` reads when the scene names none: `penumbra report`'s
/// default output folder beside the scene file.
pub const DEFAULT_REPORT: &str = "report/report.json";
/// Largest report.json read (bytes).
pub const MAX_REPORT_BYTES: u64 = 64 << 20;

/// K from a `penumbra report`'s report.json: its recommendation for the horizon storage a
/// scene can bake (the K of the multires f16 pyramids), checked to be a report of scene
/// `name`. Errors say what is wrong with the file and what to do.
pub fn coefficients_from_report(path: &Path, name: &str) -> std::result::Result<usize, String> {
    let meta = std::fs::metadata(path).map_err(|e| {
        format!(
            "{}: {e}; run `penumbra report SCENE --tileset DIR --out {}` first",
            path.display(),
            path.parent()
                .map_or(".".into(), |p| p.display().to_string())
        )
    })?;
    if meta.len() > MAX_REPORT_BYTES {
        return Err(format!(
            "{}: larger than a report ({} bytes)",
            path.display(),
            meta.len()
        ));
    }
    let text = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let v: serde_json::Value = serde_json::from_slice(&text)
        .map_err(|e| format!("{}: not a report.json ({e})", path.display()))?;
    let of = v["scene"].as_str().unwrap_or("");
    if !(of == name || of.starts_with(&format!("{name} ("))) {
        return Err(format!(
            "{}: a report of {}, not of scene '{name}'; report this scene",
            path.display(),
            if of.is_empty() {
                "a tileset alone".to_string()
            } else {
                format!("'{of}'")
            }
        ));
    }
    let rec = v["recommendations"]
        .as_array()
        .and_then(|a| a.iter().find(|r| r["product"] == "horizon storage"))
        .ok_or_else(|| {
            format!(
                "{}: no horizon-storage recommendation in it",
                path.display()
            )
        })?;
    let Some(choice) = rec["choice"].as_str() else {
        return Err(format!(
            "{}: the report recommends no storage ({}); loosen --max-per or give coefficients",
            path.display(),
            rec["why"].as_str().unwrap_or("no reason given")
        ));
    };
    choice
        .strip_prefix('F')
        .and_then(|s| s.split(' ').next())
        .and_then(|k| k.parse::<usize>().ok())
        .filter(|&k| k >= 1)
        .ok_or_else(|| {
            format!(
                "{}: recommendation '{choice}' is not a Fourier variant",
                path.display()
            )
        })
}

// ---------------------------------------------------------------------------------------------
// Reading.

/// Read and check the scene file at `path`.
pub fn load(path: &Path) -> Result<Scene> {
    let meta = std::fs::metadata(path).map_err(|e| {
        Error::invalid(
            path,
            format!("cannot read the scene file ({e}): give the path of a scene's .toml file"),
        )
    })?;
    if !meta.is_file() {
        return Err(Error::invalid(
            path,
            "is not a regular file: give the path of a scene's .toml file",
        ));
    }
    if meta.len() > MAX_SCENE_BYTES {
        return Err(Error::invalid(
            path,
            format!(
                "is {} bytes, more than a scene file's {MAX_SCENE_BYTES}: is it a scene file?",
                meta.len()
            ),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8(bytes)
        .map_err(|_| Error::invalid(path, "is not UTF-8 text: a scene file is TOML"))?;
    parse(&text, path)
}

/// The embedded scene, checked.
pub fn embedded() -> Scene {
    parse(EMBEDDED, Path::new(EMBEDDED_NAME)).expect("the embedded scene is valid")
}

/// An error at byte `at` of `text` (the scene file `file`): "FILE: line N, KEY: MSG".
struct Here<'a> {
    file: &'a Path,
    text: &'a str,
}

impl Here<'_> {
    fn line(&self, at: usize) -> usize {
        self.text[..at.min(self.text.len())]
            .bytes()
            .filter(|&b| b == b'\n')
            .count()
            + 1
    }
    fn err<T>(&self, span: &Spanned<T>, key: &str, msg: impl std::fmt::Display) -> Error {
        self.at(span.span().start, key, msg)
    }
    fn at(&self, at: usize, key: &str, msg: impl std::fmt::Display) -> Error {
        Error::invalid(
            self.file,
            format!("line {}, key `{key}`: {msg}", self.line(at)),
        )
    }
}

/// Parse and check scene text; `file` names it in errors and anchors its relative paths.
pub fn parse(text: &str, file: &Path) -> Result<Scene> {
    let here = Here { file, text };
    let de = toml::Deserializer::parse(text).map_err(|e| toml_error(&here, &e, ""))?;
    let raw: File = serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        toml_error(&here, e.inner(), &path)
    })?;
    check(raw, &here)
}

fn toml_error(here: &Here, e: &toml::de::Error, path: &str) -> Error {
    let at = e.span().map_or(0, |s| s.start);
    // `Spanned` wraps each value in a private field the path would name.
    let path = path
        .replace("$__serde_spanned_private_value.", "")
        .replace(".$__serde_spanned_private_value", "")
        .replace("$__serde_spanned_private_value", "");
    let key = if path.is_empty() || path == "." {
        "(document)".to_string()
    } else {
        path
    };
    let msg = e.message().trim().to_string();
    let hint = if msg.starts_with("unknown field") {
        " (docs/scenes.md lists every key)"
    } else {
        ""
    };
    here.at(at, &key, format!("{msg}{hint}"))
}

/// Resolve `p` against the scene file's folder.
fn resolve(file: &Path, p: &str) -> PathBuf {
    let p = Path::new(p);
    if p.is_absolute() {
        return p.to_path_buf();
    }
    match file.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.join(p),
        _ => p.to_path_buf(),
    }
}

fn finite(here: &Here, s: &Spanned<f64>, key: &str, lo: f64, hi: f64) -> Result<f64> {
    let v = *s.get_ref();
    if !v.is_finite() || v < lo || v > hi {
        return Err(here.err(s, key, format!("{v} is outside {lo} ..= {hi}")));
    }
    Ok(v)
}

fn pair(here: &Here, s: &Spanned<[f64; 2]>, key: &str, lo: f64, hi: f64) -> Result<(f64, f64)> {
    let [a, b] = *s.get_ref();
    for v in [a, b] {
        if !v.is_finite() || v < lo || v > hi {
            return Err(here.err(s, key, format!("{v} is outside {lo} ..= {hi}")));
        }
    }
    Ok((a, b))
}

fn check(raw: File, here: &Here) -> Result<Scene> {
    let file = here.file;
    let sc = raw.scene.get_ref();
    let name = sc.name.get_ref().trim().to_string();
    if name.is_empty() || name.len() > 128 || name.chars().any(|c| c.is_control()) {
        return Err(here.err(
            &sc.name,
            "scene.name",
            "give a name of 1 to 128 printable characters",
        ));
    }
    let body = match &sc.body {
        Some(b) => {
            let n = b.get_ref().to_ascii_lowercase();
            if sc.radius_m.is_none() && crate::body::Body::preset(&n).is_err() {
                return Err(here.err(
                    b,
                    "scene.body",
                    format!(
                        "'{n}' is no preset ({}); give radius_m too for another body",
                        crate::body::Body::preset_names().join(", ")
                    ),
                ));
            }
            Some(n)
        }
        None => None,
    };
    let radius_m = match &sc.radius_m {
        Some(r) => Some(finite(here, r, "scene.radius_m", 1.0, 1.0e9)?),
        None => None,
    };
    let max_oversampling = match &sc.max_oversampling {
        Some(o) => finite(here, o, "scene.max_oversampling", 1.0, 64.0)?,
        None => DEFAULT_MAX_OVERSAMPLING,
    };

    let defaults = crate::tiling::TileOptions::default();
    let (mut tile_size, mut halo, mut projection) =
        (defaults.tile_size, defaults.halo, defaults.projection);
    if let Some(l) = &raw.layout {
        let l = l.get_ref();
        if let Some(t) = &l.tile_size {
            tile_size = *t.get_ref();
            if !(8..=8192).contains(&tile_size) || tile_size % 2 != 0 {
                return Err(here.err(
                    t,
                    "layout.tile_size",
                    format!("{tile_size} is not an even size from 8 to 8192"),
                ));
            }
        }
        if let Some(h) = &l.halo {
            halo = *h.get_ref();
            if halo < 1 || halo >= tile_size / 2 {
                return Err(here.err(
                    h,
                    "layout.halo",
                    format!("{halo} is outside 1 ..= {}", tile_size / 2 - 1),
                ));
            }
        }
        if let Some(p) = &l.projection {
            projection = p
                .get_ref()
                .parse()
                .map_err(|e: String| here.err(p, "layout.projection", e))?;
        }
    }

    if raw.source.is_empty() {
        return Err(here.err(
            &raw.scene,
            "source",
            "the scene lists no [[source]]: give at least one DEM (path = \"…\")",
        ));
    }
    if raw.source.len() > MAX_SOURCES {
        return Err(here.err(
            &raw.source[MAX_SOURCES],
            "source",
            format!("more than {MAX_SOURCES} sources"),
        ));
    }
    let mut sources = Vec::new();
    for (i, s) in raw.source.iter().enumerate() {
        let key = |k: &str| format!("source[{i}].{k}");
        let t = s.get_ref();
        let line = here.line(s.span().start);
        let kind = match (&t.path, &t.embedded) {
            (Some(p), None) => {
                if let Some(z) = &t.size {
                    return Err(here.err(z, &key("size"), "only an embedded source has a size"));
                }
                let path = resolve(file, p.get_ref());
                if !path.is_file() {
                    return Err(here.err(
                        p,
                        &key("path"),
                        format!(
                            "{} is not a readable file (paths are relative to the scene file's \
                             folder)",
                            path.display()
                        ),
                    ));
                }
                SourceKind::File(path)
            }
            (None, Some(e)) => {
                if e.get_ref() != "south-pole" {
                    return Err(here.err(
                        e,
                        &key("embedded"),
                        format!(
                            "'{}' is no embedded terrain: the one there is is \"south-pole\"",
                            e.get_ref()
                        ),
                    ));
                }
                let mut spec = SyntheticSpec::default();
                if let Some(z) = &t.size {
                    spec.size = *z.get_ref();
                    if !(256..=16384).contains(&spec.size) {
                        return Err(here.err(
                            z,
                            &key("size"),
                            format!("{} is outside 256 ..= 16384", spec.size),
                        ));
                    }
                }
                SourceKind::Embedded(spec)
            }
            _ => {
                return Err(here.err(
                    s,
                    &format!("source[{i}]"),
                    "give exactly one of path = \"DEM file\" or embedded = \"south-pole\"",
                ))
            }
        };
        let format = match &t.format {
            None => crate::dem::DemFormat::Auto,
            Some(f) => {
                if t.path.is_none() {
                    return Err(here.err(f, &key("format"), "only a file source has a format"));
                }
                let v: crate::dem::DemFormat = f
                    .get_ref()
                    .parse()
                    .map_err(|m: String| here.err(f, &key("format"), m))?;
                if v == crate::dem::DemFormat::Gdal && !crate::dem::DemFormat::gdal_available() {
                    return Err(here.err(
                        f,
                        &key("format"),
                        format!("\"gdal\" reads through GDAL: {}", crate::error::NO_GDAL),
                    ));
                }
                v
            }
        };
        let feather_px = match &t.feather_px {
            Some(f) => finite(here, f, &key("feather_px"), 0.0, MAX_FEATHER_PX)?,
            None => 4.0,
        };
        let priority = match &t.priority {
            Some(p) => {
                let v = *p.get_ref();
                if v.abs() > 1_000_000 {
                    return Err(here.err(p, &key("priority"), format!("{v} is outside ±1000000")));
                }
                Some(v)
            }
            None => None,
        };
        sources.push(SourceSpec {
            kind,
            format,
            feather_px,
            priority,
            line,
        });
    }

    let albedo = match &raw.albedo {
        Some(a) => {
            let t = a.get_ref();
            let path = resolve(file, t.path.get_ref());
            if !path.is_file() {
                return Err(here.err(
                    &t.path,
                    "albedo.path",
                    format!("{} is not a readable file", path.display()),
                ));
            }
            let west_lon_deg = match &t.west_lon_deg {
                Some(w) => finite(here, w, "albedo.west_lon_deg", -360.0, 360.0)?,
                None => -180.0,
            };
            Some(AlbedoSpec {
                path,
                west_lon_deg,
                line: here.line(a.span().start),
            })
        }
        None => None,
    };

    if raw.region.is_empty() {
        return Err(here.err(
            &raw.scene,
            "region",
            "the scene lists no [[region]]: give at least one (body = true for the whole body)",
        ));
    }
    if raw.region.len() > MAX_REGIONS {
        return Err(here.err(
            &raw.region[MAX_REGIONS],
            "region",
            format!("more than {MAX_REGIONS} regions"),
        ));
    }
    let mut regions = Vec::new();
    for (i, r) in raw.region.iter().enumerate() {
        regions.push(check_region(here, i, r)?);
    }
    for (i, r) in regions.iter().enumerate() {
        if let Some(j) = regions[..i].iter().position(|q| q.name == r.name) {
            return Err(here.err(
                &raw.region[i].get_ref().name,
                &format!("region[{i}].name"),
                format!(
                    "'{}' names region[{j}] too: give each region its own name",
                    r.name
                ),
            ));
        }
    }

    let (mut methods, mut products) = (Vec::new(), Vec::new());
    if let Some(rt) = &raw.renderer {
        let rt = rt.get_ref();
        for (i, m) in rt.methods.iter().enumerate() {
            let found = METHODS.iter().find(|(n, _)| *n == m.get_ref().as_str());
            match found {
                Some((_, meth)) if !methods.contains(meth) => methods.push(*meth),
                Some(_) => {}
                None => {
                    let names: Vec<&str> = METHODS.iter().map(|(n, _)| *n).collect();
                    return Err(here.err(
                        m,
                        &format!("renderer.methods[{i}]"),
                        format!("unknown method '{}' ({})", m.get_ref(), names.join(", ")),
                    ));
                }
            }
        }
        for (i, p) in rt.products.iter().enumerate() {
            match PRODUCTS.iter().find(|(n, _)| *n == p.get_ref().as_str()) {
                Some((_, prod)) if !products.contains(prod) => products.push(*prod),
                Some(_) => {}
                None => {
                    let names: Vec<&str> = PRODUCTS.iter().map(|(n, _)| *n).collect();
                    return Err(here.err(
                        p,
                        &format!("renderer.products[{i}]"),
                        format!("unknown product '{}' ({})", p.get_ref(), names.join(", ")),
                    ));
                }
            }
        }
    }
    if methods.is_empty() && products.is_empty() {
        return Err(here.err_at(
            raw.renderer
                .as_ref()
                .map_or(&raw.scene as &dyn SpanOf, |r| r as &dyn SpanOf),
            "renderer.methods",
            "the scene names no shadow method and no product: list the renderer's methods \
             (e.g. methods = [\"dp\", \"fourier\"]) or products",
        ));
    }
    if products.contains(&Product::Albedo) && albedo.is_none() {
        return Err(here.err(
            &raw.scene,
            "renderer.products",
            "lists albedo but the scene has no [albedo] source",
        ));
    }

    let sun = match &raw.sun {
        Some(s) => Some(check_sun(here, s)?),
        None => None,
    };

    // The horizon method by default: `sweep` where the scene keeps only the Fourier pyramids
    // (its error, ≤ 0.03° RMS, is a few per cent of the pyramids' own), `fast` where it keeps
    // raw maps too (their accuracy contract is the fast method's; docs/horizons.md).
    let reads =
        |p: Product| products.contains(&p) || methods.iter().any(|m| m.reads().contains(&p));
    let mut horizon = HorizonSpec {
        levels: None,
        azimuths: 360,
        method: if reads(Product::Fourier) && !reads(Product::Horizon) {
            HorizonMethod::Sweep
        } else {
            HorizonMethod::Fast
        },
        prune: true,
        device: Default::default(),
    };
    if let Some(h) = &raw.horizon {
        let h = h.get_ref();
        if let Some(l) = &h.levels {
            let mut v = Vec::new();
            for &x in l.get_ref() {
                if !(0..i64::from(MAX_LEVELS)).contains(&x) {
                    return Err(here.err(
                        l,
                        "horizon.levels",
                        format!("{x} is outside 0 ..= {}", MAX_LEVELS - 1),
                    ));
                }
                if !v.contains(&(x as u8)) {
                    v.push(x as u8);
                }
            }
            if v.is_empty() {
                return Err(here.err(
                    l,
                    "horizon.levels",
                    "is empty: leave it out for every level a region asks for",
                ));
            }
            v.sort_unstable();
            horizon.levels = Some(v);
        }
        if let Some(a) = &h.azimuths {
            horizon.azimuths = *a.get_ref();
            if !(4..=4096).contains(&horizon.azimuths) || horizon.azimuths % 4 != 0 {
                return Err(here.err(
                    a,
                    "horizon.azimuths",
                    format!("{} is not a multiple of 4 in 4 ..= 4096", horizon.azimuths),
                ));
            }
        }
        if let Some(m) = &h.method {
            horizon.method = m
                .get_ref()
                .parse()
                .map_err(|e: String| here.err(m, "horizon.method", e))?;
        }
        if let Some(p) = &h.prune {
            horizon.prune = *p.get_ref();
        }
        if let Some(d) = &h.device {
            use crate::horizon::device::DeviceChoice;
            horizon.device = DeviceChoice::parse(d.get_ref()).ok_or_else(|| {
                here.err(
                    d,
                    "horizon.device",
                    format!(
                        "\"{}\" is not one of {}",
                        d.get_ref(),
                        DeviceChoice::NAMES.join(", ")
                    ),
                )
            })?;
            if horizon.device == DeviceChoice::Gpu && horizon.method != HorizonMethod::Sweep {
                return Err(here.err(
                    d,
                    "horizon.device",
                    format!(
                        "\"gpu\" runs the sweep method only, and this scene's method is \"{}\": \
                         set method = \"sweep\" or device = \"cpu\"",
                        horizon.method.name()
                    ),
                ));
            }
        }
    }
    // The default K, or all the azimuths give when they are fewer.
    let mut fourier = FourierSpec {
        coefficients: crate::fourier::FourierOptions::default()
            .coefficients
            .min(horizon.azimuths / 2 + 1),
        keep_raw: false,
        auto_from: None,
        auto_error: None,
    };
    if let Some(f) = &raw.fourier {
        let f = f.get_ref();
        if let Some(k) = &f.coefficients {
            fourier.coefficients = match k.get_ref() {
                Coefficients::K(k) => *k,
                Coefficients::Word(w) if w == "auto" => {
                    let rel = f
                        .report
                        .as_ref()
                        .map_or(DEFAULT_REPORT, |r| r.get_ref().as_str());
                    let path = resolve(file, rel);
                    fourier.auto_from = Some(path.clone());
                    // Kept, not raised: `penumbra report` reads this scene to make the very
                    // report K comes from; `plan` and `bake` refuse it ([`plan::plan`]).
                    match coefficients_from_report(&path, &name) {
                        Ok(k) => k,
                        Err(e) => {
                            fourier.auto_error = Some(format!(
                                "line {}, key `fourier.coefficients`: {e}",
                                here.line(k.span().start)
                            ));
                            fourier.coefficients
                        }
                    }
                }
                Coefficients::Word(w) => {
                    return Err(here.err(
                        k,
                        "fourier.coefficients",
                        format!("'{w}': give a number of coefficients or \"auto\""),
                    ))
                }
            };
            if fourier.coefficients == 0 || fourier.coefficients > horizon.azimuths / 2 + 1 {
                return Err(here.err(
                    k,
                    "fourier.coefficients",
                    format!(
                        "{} is outside 1 ..= {} (half the azimuths, plus one)",
                        fourier.coefficients,
                        horizon.azimuths / 2 + 1
                    ),
                ));
            }
        }
        if let (Some(r), false) = (
            &f.report,
            matches!(
                f.coefficients.as_ref().map(|c| c.get_ref()),
                Some(Coefficients::Word(_))
            ),
        ) {
            return Err(here.err(
                r,
                "fourier.report",
                "is read only with coefficients = \"auto\"",
            ));
        }
        if let Some(k) = &f.keep_raw {
            fourier.keep_raw = *k.get_ref();
        }
    }

    Ok(Scene {
        file: file.to_path_buf(),
        name,
        body,
        radius_m,
        max_oversampling,
        tile_size,
        halo,
        projection,
        sources,
        albedo,
        regions,
        methods,
        products,
        sun,
        horizon,
        fourier,
    })
}

/// Anything with a span in the file (to point at a table when no key is at fault).
trait SpanOf {
    fn start(&self) -> usize;
}
impl<T> SpanOf for Spanned<T> {
    fn start(&self) -> usize {
        self.span().start
    }
}

impl Here<'_> {
    fn err_at(&self, s: &dyn SpanOf, key: &str, msg: impl std::fmt::Display) -> Error {
        self.at(s.start(), key, msg)
    }
}

fn check_region(here: &Here, i: usize, r: &Spanned<RegionTable>) -> Result<RegionSpec> {
    let t = r.get_ref();
    let key = |k: &str| format!("region[{i}].{k}");
    let name = t.name.get_ref().trim().to_string();
    if name.is_empty() || name.len() > 128 || name.chars().any(|c| c.is_control()) {
        return Err(here.err(
            &t.name,
            &key("name"),
            "give a name of 1 to 128 printable characters",
        ));
    }
    let kinds = [
        t.body.as_ref().is_some_and(|b| *b.get_ref()),
        t.lat_deg.is_some() || t.lon_deg.is_some(),
        t.cap.is_some(),
        t.polygon.is_some(),
        t.path.is_some(),
    ];
    if kinds.iter().filter(|k| **k).count() != 1 {
        return Err(here.err(
            r,
            &format!("region[{i}]"),
            format!(
                "region '{name}' needs exactly one shape: body = true, lat_deg + lon_deg (a box), \
                 cap = {{ lat_deg, lon_deg, radius_m }}, polygon = [[lat, lon], …] or path = \
                 \"camera path CSV\""
            ),
        ));
    }
    let path_only = [
        (t.frame_px.as_ref().map(|s| s.span().start), "frame_px"),
        (t.fov_deg.as_ref().map(|s| s.span().start), "fov_deg"),
        (t.texel_px.as_ref().map(|s| s.span().start), "texel_px"),
    ];
    if t.path.is_none() {
        if let Some((Some(at), k)) = path_only.iter().find(|(s, _)| s.is_some()) {
            return Err(here.at(*at, &key(k), "only a camera path (path = …) takes it"));
        }
    }
    let shape = if kinds[0] {
        RegionShape::Body
    } else if kinds[1] {
        let (Some(la), Some(lo)) = (&t.lat_deg, &t.lon_deg) else {
            return Err(here.err(
                r,
                &format!("region[{i}]"),
                "a box needs both lat_deg = [south, north] and lon_deg = [west, east]",
            ));
        };
        let lat = pair(here, la, &key("lat_deg"), -90.0, 90.0)?;
        if lat.0 >= lat.1 {
            return Err(here.err(
                la,
                &key("lat_deg"),
                format!(
                    "[{}, {}] is not [south, north] with south < north",
                    lat.0, lat.1
                ),
            ));
        }
        let lon = pair(here, lo, &key("lon_deg"), -360.0, 360.0)?;
        if lon.0 == lon.1 {
            return Err(here.err(lo, &key("lon_deg"), "west and east are equal: an empty box"));
        }
        RegionShape::Box { lat, lon }
    } else if let Some(c) = &t.cap {
        let v = c.get_ref();
        let bad = |k: &str, x: f64, lo: f64, hi: f64| {
            (!x.is_finite() || x < lo || x > hi).then(|| {
                here.err(
                    c,
                    &key(&format!("cap.{k}")),
                    format!("{x} is outside {lo} ..= {hi}"),
                )
            })
        };
        if let Some(e) = bad("lat_deg", v.lat_deg, -90.0, 90.0)
            .or_else(|| bad("lon_deg", v.lon_deg, -360.0, 360.0))
            .or_else(|| bad("radius_m", v.radius_m, 1e-3, 1e10))
        {
            return Err(e);
        }
        RegionShape::Cap {
            lat_deg: v.lat_deg,
            lon_deg: v.lon_deg,
            radius_m: v.radius_m,
        }
    } else if let Some(p) = &t.polygon {
        let v = p.get_ref();
        if v.len() < 3 || v.len() > MAX_POLYGON_VERTICES {
            return Err(here.err(
                p,
                &key("polygon"),
                format!(
                    "has {} vertices: give 3 ..= {MAX_POLYGON_VERTICES} [lat, lon] pairs",
                    v.len()
                ),
            ));
        }
        for (k, [la, lo]) in v.iter().enumerate() {
            if !(la.is_finite() && lo.is_finite() && la.abs() <= 90.0 && lo.abs() <= 360.0) {
                return Err(here.err(
                    p,
                    &key(&format!("polygon[{k}]")),
                    format!("[{la}, {lo}] is not a latitude in ±90 and a longitude in ±360"),
                ));
            }
        }
        RegionShape::Polygon(v.iter().map(|[a, b]| (*a, *b)).collect())
    } else {
        let p = t.path.as_ref().expect("one shape");
        let file = resolve(here.file, p.get_ref());
        if !file.is_file() {
            return Err(here.err(
                p,
                &key("path"),
                format!(
                    "{} is not a readable file (paths are relative to the scene file's folder)",
                    file.display()
                ),
            ));
        }
        let frame_px = match &t.frame_px {
            Some(f) => {
                let [w, h] = *f.get_ref();
                if !(16..=16384).contains(&w) || !(16..=16384).contains(&h) {
                    return Err(here.err(
                        f,
                        &key("frame_px"),
                        format!("[{w}, {h}] is outside 16 ..= 16384 pixels a side"),
                    ));
                }
                (w, h)
            }
            None => (1920, 1080),
        };
        let fov_deg = match &t.fov_deg {
            Some(f) => finite(here, f, &key("fov_deg"), 1.0, 120.0)?,
            None => 60.0,
        };
        let texel_px = match &t.texel_px {
            Some(f) => finite(here, f, &key("texel_px"), 0.05, 64.0)?,
            None => 1.0,
        };
        RegionShape::Path {
            file,
            frame_px,
            fov_deg,
            texel_px,
        }
    };
    let finest = match (&t.level, &t.resolution_m) {
        (Some(l), None) => {
            let v = *l.get_ref();
            if !(0..i64::from(MAX_LEVELS)).contains(&v) {
                return Err(here.err(
                    l,
                    &key("level"),
                    format!("{v} is outside 0 ..= {}", MAX_LEVELS - 1),
                ));
            }
            Finest::Level(v as u8)
        }
        (None, Some(m)) => Finest::ResolutionM(finite(here, m, &key("resolution_m"), 1e-3, 1e7)?),
        (None, None) => Finest::Source,
        (Some(l), Some(_)) => {
            return Err(here.err(
                l,
                &key("level"),
                format!("region '{name}' gives both level and resolution_m: keep one"),
            ))
        }
    };
    Ok(RegionSpec {
        name,
        shape,
        finest,
        line: here.line(r.span().start),
    })
}

fn check_sun(here: &Here, s: &Spanned<SunTable>) -> Result<SunSpec> {
    let t = s.get_ref();
    let line = here.line(s.span().start);
    let distance_au = match &t.distance_au {
        Some(d) => Some(finite(here, d, "sun.distance_au", 0.01, 1000.0)?),
        None => None,
    };
    match (&t.elevation_deg, &t.start, &t.end) {
        (Some(e), None, None) => {
            let el = pair(here, e, "sun.elevation_deg", -90.0, 90.0)?;
            if el.0 > el.1 {
                return Err(here.err(
                    e,
                    "sun.elevation_deg",
                    format!("[{}, {}] is not [lowest, highest]", el.0, el.1),
                ));
            }
            let azimuth_deg = match &t.azimuth_deg {
                Some(a) => Some(pair(here, a, "sun.azimuth_deg", 0.0, 360.0)?),
                None => None,
            };
            Ok(SunSpec::Range {
                elevation_deg: el,
                azimuth_deg,
                distance_au,
                line,
            })
        }
        (None, Some(a), Some(b)) => {
            if let Some(az) = &t.azimuth_deg {
                return Err(here.err(
                    az,
                    "sun.azimuth_deg",
                    "goes with elevation_deg; a time span gives the azimuths itself",
                ));
            }
            Ok(SunSpec::Span {
                start: a.get_ref().clone(),
                end: b.get_ref().clone(),
                distance_au,
                line,
            })
        }
        _ => Err(here.err(
            s,
            "sun",
            "give either elevation_deg = [lowest, highest] (degrees) or start and end (UTC, \
             e.g. \"2027-01-01T00:00:00Z\")",
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> String {
        match parse(text, Path::new("s.toml")) {
            Ok(_) => panic!("accepted:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    const HEAD: &str =
        "[scene]\nname = \"t\"\nbody = \"moon\"\n\n[[source]]\nembedded = \"south-pole\"\n";

    #[test]
    fn embedded_scene_parses() {
        let s = embedded();
        assert_eq!(s.sources.len(), 1);
        assert_eq!(s.horizon.levels, Some(vec![6]));
        assert_eq!(
            s.methods,
            vec![
                RenderMethod::Dp,
                RenderMethod::Extrema,
                RenderMethod::Fourier
            ]
        );
        assert!(matches!(s.regions[0].shape, RegionShape::Body));
        assert_eq!(s.regions[0].finest, Finest::Source);
    }

    #[test]
    fn errors_name_line_and_key() {
        let body = "\n[[region]]\nname = \"a\"\nbody = true\n\n[renderer]\nmethods = [\"dp\"]\n";
        // Unknown key, on line 8.
        let e = err(&format!(
            "{HEAD}{}",
            body.replace("body = true", "body = true\nlevl = 3")
        ));
        assert!(e.contains("line 11") && e.contains("`levl`"), "{e}");
        // Wrong type.
        let e = err(&format!(
            "{HEAD}{}",
            body.replace("body = true", "body = true\nlevel = \"x\"")
        ));
        assert!(
            e.contains("line 11") && e.contains("`region[0].level`"),
            "{e}"
        );
        // A device that is none of the three, and the GPU for a method it does not run.
        let e = err(&format!("{HEAD}{body}\n[horizon]\ndevice = \"tpu\"\n"));
        assert!(
            e.contains("line 16") && e.contains("`horizon.device`") && e.contains("cpu, gpu, auto"),
            "{e}"
        );
        let e = err(&format!(
            "{HEAD}{body}\n[horizon]\nmethod = \"fast\"\ndevice = \"gpu\"\n"
        ));
        assert!(
            e.contains("`horizon.device`") && e.contains("sweep method only"),
            "{e}"
        );
        let ok = parse(
            &format!("{HEAD}{body}\n[horizon]\nmethod = \"sweep\"\ndevice = \"gpu\"\n"),
            Path::new("s.toml"),
        )
        .expect("the GPU runs the sweep");
        assert_eq!(ok.horizon.device, crate::horizon::device::DeviceChoice::Gpu);
        // Sun above 90°.
        let e = err(&format!(
            "{HEAD}{body}\n[sun]\nelevation_deg = [10.0, 95.0]\n"
        ));
        assert!(e.contains("sun.elevation_deg") && e.contains("95"), "{e}");
        // Missing source file.
        let e = err(&format!(
            "[scene]\nname = \"t\"\n[[source]]\npath = \"/nonexistent/x.tif\"\n{body}"
        ));
        assert!(e.contains("line 4") && e.contains("source[0].path"), "{e}");
        // No shape, two shapes.
        let e = err(&format!("{HEAD}{}", body.replace("body = true\n", "")));
        assert!(e.contains("exactly one shape"), "{e}");
        let e = err(&format!(
            "{HEAD}{}",
            body.replace(
                "body = true",
                "body = true\ncap = { lat_deg = 0.0, lon_deg = 0.0, radius_m = 5.0 }"
            )
        ));
        assert!(e.contains("exactly one shape"), "{e}");
        // Unknown method.
        let e = err(&format!("{HEAD}{}", body.replace("\"dp\"", "\"dpp\"")));
        assert!(
            e.contains("renderer.methods[0]") && e.contains("dpp"),
            "{e}"
        );
        // Not TOML at all.
        let e = err("[scene\nname=");
        assert!(e.contains("line 1"), "{e}");
    }
}
