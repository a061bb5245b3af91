//! `penumbra package`: a finished Celestia addon folder made from a tileset (docs/packaging.md,
//! "The package"), and optionally a ZIP archive of it.
//!
//! The folder holds the addon [`celestia::write_addon`] writes (the `.ssc` catalog, virtual
//! textures of the albedo and of the normal map, the [`MARKER`]), the tileset itself as the
//! addon's cube-face products in [`CUBEMAP_DIR`] (a copy that opens as the original,
//! [`copy_tileset`]: linked where it can be, checked file by file against the indexes), and a
//! [`README`] saying what is inside and how to install it.
//!
//! It is written into a temp folder beside the output (`.<name>.penumbra-partial.<pid>`) and
//! renamed into place only when complete, swapping out an earlier package atomically where the
//! system can (Linux `renameat2(RENAME_EXCHANGE)`); a run that fails or is killed leaves the
//! earlier package as it was, and the next run removes what a dead run left. The archive is
//! written after the folder, through a temp file, by [`archive::write_zip`].

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::celestia::{self, AddonOptions, Layer, SurfaceMode, MARKER, TEXTURES_DIR};
use crate::error::{Error, IoContext, Result};
use crate::format::{archive, vt};
use crate::fsio::{list_files, remove_tree, sync_dir, sync_staged};
use crate::manifest::{SourceInfo, Tileset, MANIFEST};
use crate::progress::Progress;
use crate::tileset::copy::{copy_tileset, CopyReport};
use crate::tileset::Store;

/// The folder of a package that holds the tileset: the addon's cube-face products.
pub const CUBEMAP_DIR: &str = "cubemap";

/// The package's README.
pub const README: &str = "README.txt";

/// Marks in the names of the temp folders a package is written into and an earlier package is
/// moved out to: `.<name>.penumbra-partial.<pid>`, `.<name>.penumbra-old.<pid>`.
const PARTIAL: &str = ".penumbra-partial.";
const OLD: &str = ".penumbra-old.";

/// What to package and how.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PackageOptions {
    /// The addon's choices (tile size, body, alternate surface's name).
    pub addon: AddonOptions,
    /// Also write a ZIP archive of the folder here (its parent must exist).
    pub zip: Option<PathBuf>,
    /// The command that made the package, as the README records it (the caller's words:
    /// the library does not know its command line); empty: not recorded.
    pub command: String,
}

/// One virtual-texture level and the cube level its pixels come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct VtLevel {
    pub vt_level: u8,
    pub cube_level: u8,
}

/// One virtual texture of the package.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct TextureReport {
    /// `albedo` or `normal`.
    pub layer: String,
    /// Its `.ctx`, relative to the package.
    pub ctx: String,
    pub tiles: u64,
    /// Bytes of its tiles.
    pub bytes: u64,
}

/// What [`package`] made.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PackageReport {
    /// The package folder.
    pub out: PathBuf,
    /// The tileset it was made from.
    pub tileset: PathBuf,
    /// The body and its parent as Celestia's catalogs name them.
    pub body: String,
    pub parent: String,
    /// `Modify` (the data covers the body) or `AltSurface`.
    pub mode: String,
    /// The alternate surface's name, for `AltSurface`.
    pub alt_surface: Option<String>,
    /// The catalog, relative to the package.
    pub catalog: String,
    pub vt_tile_size: u32,
    pub vt_levels: Vec<VtLevel>,
    pub textures: Vec<TextureReport>,
    /// The cube-face tileset in [`CUBEMAP_DIR`]: its product files (linked or copied, and
    /// checked).
    pub cubemap: CopyReport,
    /// Bytes of everything in [`CUBEMAP_DIR`] (product files, manifest and indexes).
    pub cubemap_bytes: u64,
    /// Every file of the package, and their bytes.
    pub files: u64,
    pub bytes: u64,
    /// Whether an earlier package at `out` was replaced.
    pub replaced: bool,
    /// The archive, when one was asked for.
    pub zip: Option<archive::ZipReport>,
}

/// The tileset a folder holds for a reader: the cube-face tileset of a package (a folder with
/// the [`MARKER`]), else the folder itself.
pub fn tileset_in(dir: &Path) -> PathBuf {
    if dir.join(MARKER).is_file() {
        dir.join(CUBEMAP_DIR)
    } else {
        dir.to_path_buf()
    }
}

/// The archive beside a package folder: `OUT.zip`.
pub fn default_zip_path(out: &Path) -> PathBuf {
    let mut name = out.file_name().unwrap_or_default().to_os_string();
    name.push(".zip");
    out.with_file_name(name)
}

/// Package the tileset in `tileset` as the Celestia addon folder `out` (new, an empty folder or
/// a package this function wrote, which is replaced), and its archive when `opts.zip` asks for
/// one. Everything that can be refused is refused before anything is written: an `out` that
/// holds something else, a missing parent, a folder that is no tileset or one without
/// heights, an archive path inside `out` or without its parent; a damaged tileset is refused
/// naming its file, and leaves nothing behind.
pub fn package(
    tileset: &Path,
    out: &Path,
    opts: &PackageOptions,
    progress: &dyn Progress,
) -> Result<PackageReport> {
    let name = plain_name(out)?;
    let parent = parent_of(out);
    check_out(out, &parent)?;
    if let Some(z) = &opts.zip {
        check_zip(z, out, &parent)?;
    }
    let store = Store::open(tileset)?;
    let ts = store.manifest();
    if ts.products.height.is_none() {
        return Err(store.missing(
            "the tileset has no height tiles: a package's normal map and cube faces are made \
             from them (make them with `penumbra tile` or `penumbra bake`)",
        ));
    }
    check_apart(tileset, out)?;
    sweep(&parent, &name)?;

    let tmp = parent.join(format!(".{name}{PARTIAL}{}", std::process::id()));
    remove_tree(&tmp)?;
    std::fs::create_dir(&tmp).at(&tmp)?;
    let made = (|| {
        let addon = celestia::write_addon(&store, &tmp, &opts.addon, progress)?;
        let cubemap = copy_tileset(&store, &tmp.join(CUBEMAP_DIR), progress)?;
        let mut report = describe(&store, &tmp, out, opts, &addon, cubemap)?;
        vt::write_text(&tmp.join(README), &readme(ts, &report, &opts.command))?;
        let files = list_files(&tmp)?;
        report.files = files.len() as u64;
        report.bytes = files.iter().map(|f| f.1).sum();
        // Durable before it takes the name (the copies and tiles are not synced one by one).
        sync_staged(&tmp)?;
        Ok(report)
    })();
    let mut report = match made {
        Ok(r) => r,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    report.replaced = replace(&tmp, out, &parent, &name)?;
    if let Some(z) = &opts.zip {
        report.zip = Some(archive::write_zip(out, &name, z, progress)?);
    }
    Ok(report)
}

/// The last component of `out`, a plain name.
fn plain_name(out: &Path) -> Result<String> {
    match out.file_name().and_then(|n| n.to_str()) {
        Some(n) if !n.is_empty() && n != "." && n != ".." => Ok(n.to_string()),
        _ => Err(Error::invalid(
            out,
            "is no folder name a package can take: name the package's folder (such as \
             penumbra-moon)",
        )),
    }
}

fn parent_of(p: &Path) -> PathBuf {
    match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// `out` is absent, an empty folder or a package, and its parent is a folder.
fn check_out(out: &Path, parent: &Path) -> Result<()> {
    if !parent.is_dir() {
        return Err(Error::invalid(
            parent,
            "is not a folder: the package's folder is made inside an existing folder; create it \
             first",
        ));
    }
    match std::fs::symlink_metadata(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(out, e)),
        Ok(m) if !m.is_dir() => Err(Error::invalid(
            out,
            "exists and is not a folder: choose a new folder for the package",
        )),
        Ok(_) => {
            let empty = std::fs::read_dir(out).at(out)?.next().is_none();
            if empty || out.join(MARKER).is_file() {
                Ok(())
            } else {
                Err(Error::usage(format!(
                    "{} is not empty and holds no package penumbra wrote (no {MARKER}): choose \
                     a new or empty folder",
                    out.display()
                )))
            }
        }
    }
}

/// The archive's path: its parent exists, it lies outside the package, and it is a new file
/// or an archive (never another file or a folder).
fn check_zip(z: &Path, out: &Path, parent: &Path) -> Result<()> {
    let inside = || {
        Error::invalid(
            z,
            format!(
                "lies inside the package {}: put the archive beside it",
                out.display()
            ),
        )
    };
    let (az, ao) = (
        std::path::absolute(z).at(z)?,
        std::path::absolute(out).at(out)?,
    );
    if az.starts_with(&ao) {
        return Err(inside());
    }
    let zparent = parent_of(z);
    if !zparent.is_dir() {
        return Err(Error::invalid(
            &zparent,
            format!(
                "is not a folder: the archive {} is written inside an existing folder; create \
                 it first",
                z.display()
            ),
        ));
    }
    let real_parent = std::fs::canonicalize(&zparent).at(&zparent)?;
    let real_out = std::fs::canonicalize(parent)
        .at(parent)?
        .join(out.file_name().unwrap_or_default());
    if real_parent.starts_with(&real_out) {
        return Err(inside());
    }
    match std::fs::symlink_metadata(z) {
        Err(_) => Ok(()),
        Ok(m) if m.is_file() => {
            let mut head = [0u8; 4];
            let n = std::io::Read::read(&mut std::fs::File::open(z).at(z)?, &mut head).at(z)?;
            if n == 4 && (head == *b"PK\x03\x04" || head == *b"PK\x05\x06") {
                Ok(())
            } else {
                Err(Error::invalid(
                    z,
                    "exists and is not a ZIP archive: the package's archive replaces only an \
                     archive; choose another name",
                ))
            }
        }
        Ok(_) => Err(Error::invalid(
            z,
            "exists and is not a file: name the archive's file (such as penumbra-moon.zip)",
        )),
    }
}

/// Neither the tileset nor the package lies inside the other (the copy would copy itself).
fn check_apart(tileset: &Path, out: &Path) -> Result<()> {
    let ts = std::fs::canonicalize(tileset).at(tileset)?;
    let parent = parent_of(out);
    let o = std::fs::canonicalize(&parent)
        .at(&parent)?
        .join(out.file_name().unwrap_or_default());
    if o.starts_with(&ts) || ts.starts_with(&o) {
        return Err(Error::invalid(
            out,
            format!(
                "and the tileset {} lie one inside the other: put the package beside the \
                 tileset",
                tileset.display()
            ),
        ));
    }
    Ok(())
}

/// Remove the temp folders of runs that are gone (their pid no longer lives) for the package
/// `name` in `parent`.
fn sweep(parent: &Path, name: &str) -> Result<()> {
    if !cfg!(target_os = "linux") {
        return Ok(());
    }
    let me = std::process::id();
    for e in std::fs::read_dir(parent).at(parent)?.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = n.strip_prefix(&format!(".{name}")) else {
            continue;
        };
        let pid = rest
            .strip_prefix(PARTIAL)
            .or_else(|| rest.strip_prefix(OLD))
            .and_then(|p| p.parse::<u32>().ok());
        if let Some(pid) = pid {
            if pid != me && !Path::new(&format!("/proc/{pid}")).exists() {
                remove_tree(&e.path())?;
            }
        }
    }
    Ok(())
}

/// Put the complete folder `tmp` at `out`; whether an earlier package was replaced.
fn replace(tmp: &Path, out: &Path, parent: &Path, name: &str) -> Result<bool> {
    if std::fs::symlink_metadata(out).is_err() {
        std::fs::rename(tmp, out).at(out)?;
        sync_dir(parent)?;
        return Ok(false);
    }
    // Checked again: another process may have written there since the first check.
    check_out(out, parent)?;
    // Where the system cannot swap at once (or the swap fails), two renames instead.
    if !matches!(crate::fsio::exchange_paths(tmp, out), Ok(true)) {
        let old = parent.join(format!(".{name}{OLD}{}", std::process::id()));
        std::fs::rename(out, &old).at(out)?;
        std::fs::rename(tmp, out).at(out)?;
        sync_dir(parent)?;
        remove_tree(&old)?;
        return Ok(true);
    }
    sync_dir(parent)?;
    // `tmp` now holds the earlier package.
    remove_tree(tmp)?;
    Ok(true)
}

/// The report of the package written into `tmp` (to be renamed to `out`).
fn describe(
    store: &Store,
    tmp: &Path,
    out: &Path,
    opts: &PackageOptions,
    addon: &celestia::AddonReport,
    cubemap: CopyReport,
) -> Result<PackageReport> {
    let ts = store.manifest();
    let (body, parent) = match &opts.addon.body {
        Some(b) => b.clone(),
        None => celestia::celestia_body(&ts.body.name)
            .map(|(b, p)| (b.to_string(), p.to_string()))
            .unwrap_or_default(),
    };
    let rel = |p: &Path| {
        p.strip_prefix(tmp)
            .unwrap_or(p)
            .to_string_lossy()
            .replace('\\', "/")
    };
    let bytes_below = |d: &Path| -> Result<u64> { Ok(list_files(d)?.iter().map(|f| f.1).sum()) };
    let mut textures = Vec::new();
    for (layer, tiles) in &addon.tiles {
        let dir = tmp.join(TEXTURES_DIR).join(layer.name());
        textures.push(TextureReport {
            layer: match layer {
                Layer::Albedo => "albedo",
                Layer::Normal => "normal",
            }
            .into(),
            ctx: rel(&tmp.join(TEXTURES_DIR).join(format!("{}.ctx", layer.name()))),
            tiles: *tiles,
            bytes: bytes_below(&dir)?,
        });
    }
    let (mode, alt_surface) = match &addon.mode {
        SurfaceMode::Modify => ("Modify".to_string(), None),
        SurfaceMode::AltSurface(n) => ("AltSurface".to_string(), Some(n.clone())),
    };
    Ok(PackageReport {
        out: out.to_path_buf(),
        tileset: store.dir().to_path_buf(),
        body,
        parent,
        mode,
        alt_surface,
        catalog: rel(&addon.catalog),
        vt_tile_size: opts.addon.vt_tile_size,
        vt_levels: addon
            .levels
            .iter()
            .map(|l| VtLevel {
                vt_level: l.vt_level,
                cube_level: l.cube_level,
            })
            .collect(),
        textures,
        cubemap_bytes: bytes_below(&tmp.join(CUBEMAP_DIR))?,
        cubemap,
        files: 0,
        bytes: 0,
        replaced: false,
        zip: None,
    })
}

/// Bytes in words: `812 B`, `4.2 kB`, `17.3 MB`, `2.41 GB`.
fn size(b: u64) -> String {
    let f = b as f64;
    match b {
        0..=999 => format!("{b} B"),
        1000..=999_999 => format!("{:.1} kB", f / 1e3),
        1_000_000..=999_999_999 => format!("{:.1} MB", f / 1e6),
        _ => format!("{:.2} GB", f / 1e9),
    }
}

/// What each product's files are, for the README.
fn product_words(name: &str) -> &'static str {
    match name {
        "height" => "height tiles: EXR, f32 `height` (m above the body's sphere) + f16 `mask`, halo included",
        "albedo" => "albedo tiles: PNG, in the same cube layout",
        "mip" => "maximum and (min, max) mipmaps of the heights: EXR per tile (maxmip/, minmax/), face pyramids",
        "horizon" => "raw horizon maps: EXR, the horizon's elevation in every azimuth per pixel",
        "fourier" => "Fourier horizon pyramids: .fhm, 16-bit truncated-Fourier coefficients a GPU uploads as they are",
        _ => "a product defined outside penumbra's registry",
    }
}

/// A source of the tileset's heights, in one line.
fn source_line(s: &SourceInfo) -> String {
    let files: Vec<String> = s
        .files
        .iter()
        .map(|f| {
            format!(
                "{} ({}, blake3 {})",
                f.path,
                size(f.bytes),
                f.blake3.get(..16).unwrap_or(&f.blake3)
            )
        })
        .collect();
    format!(
        "{}: {} × {} px, {} m/px, format {}",
        files.join(" + "),
        s.width,
        s.height,
        fmt_m(s.pixel_size_m),
        s.format
    )
}

fn fmt_m(m: f64) -> String {
    if m >= 100.0 {
        format!("{m:.0}")
    } else {
        format!("{m:.2}")
    }
}

/// The README's text.
fn readme(ts: &Tileset, r: &PackageReport, command: &str) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let name = r
        .out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let title = format!("{name}: a Celestia addon of {} made by penumbra", r.body);
    let _ = writeln!(s, "{title}\n{}\n", "=".repeat(title.chars().count()));
    let _ = writeln!(
        s,
        "Made by {} {} from a tileset of {} (radius {} m; run key {}).",
        ts.tool.name,
        env!("CARGO_PKG_VERSION"),
        ts.body.name,
        ts.body.radius_m,
        ts.run_key
    );
    if !command.is_empty() {
        let _ = writeln!(s, "Command:\n\n    {command}\n");
    } else {
        s.push('\n');
    }
    match &r.alt_surface {
        None => {
            let _ = writeln!(
                s,
                "The data covers the whole body: the catalog modifies \"{}\" (\"{}\"), replacing \
                 its surface texture and normal map.\n",
                r.body, r.parent
            );
        }
        Some(n) => {
            let _ = writeln!(
                s,
                "The data covers part of the body: the catalog adds an alternate surface \"{n}\" \
                 to \"{}/{}\" and leaves the stock surface the default.\n",
                r.parent, r.body
            );
        }
    }
    let _ = writeln!(s, "Install\n-------\n");
    let _ = writeln!(
        s,
        "1. Copy this folder ({name}/) into Celestia's `extras` folder (or unzip its archive \
         there), e.g. /usr/share/celestia/extras, ~/.celestia/extras or \
         C:\\Program Files\\Celestia\\extras. Celestia 1.6 and 1.7 read the catalogs there at \
         start-up."
    );
    match &r.alt_surface {
        None => {
            let _ = writeln!(
                s,
                "2. Start Celestia and go to {} (H, then G, or Enter and its name): it wears \
                 these textures.",
                r.body
            );
        }
        Some(n) => {
            let _ = writeln!(
                s,
                "2. Start Celestia, select {} and choose the surface in the right-click menu: \
                 Alternate Surfaces > {n} (Normal brings the stock surface back).",
                r.body
            );
        }
    }
    let _ = writeln!(
        s,
        "3. To uninstall, delete the folder. Render a normal map needs Celestia's OpenGL 2.0 \
         (GLSL) render path, its default.\n"
    );
    let _ = writeln!(s, "What is inside\n--------------\n");
    let _ = writeln!(
        s,
        "{:<44} the catalog ({} \"{}\")",
        r.catalog, r.mode, r.body
    );
    let vt = |t: &TextureReport| {
        format!(
            "{} tiles of {} px, {}",
            t.tiles,
            r.vt_tile_size,
            size(t.bytes)
        )
    };
    for t in &r.textures {
        let what = match t.layer.as_str() {
            "albedo" => "virtual texture of the albedo",
            _ => "virtual texture of the normal map derived from the heights",
        };
        let dir = t.ctx.trim_end_matches(".ctx");
        let _ = writeln!(s, "{:<44} {what}", t.ctx);
        let _ = writeln!(
            s,
            "{:<44} its tiles: {}",
            format!("{dir}/levelL/tx_X_Y.png"),
            vt(t)
        );
    }
    let levels: Vec<String> = r
        .vt_levels
        .iter()
        .map(|l| format!("{} <- cube level {}", l.vt_level, l.cube_level))
        .collect();
    let _ = writeln!(
        s,
        "{:<44} virtual-texture levels (2^(L+1) x 2^L tiles of 180/2^L degrees, column 0 at \
         180 W, row 0 at the north pole): {}",
        "",
        levels.join(", ")
    );
    let _ = writeln!(
        s,
        "{:<44} the cube-face products: a penumbra tileset ({}), which penumbra info, verify, \
         query and penumbra-view open as it is (penumbra-view opens this folder)",
        format!("{CUBEMAP_DIR}/"),
        size(r.cubemap_bytes)
    );
    let _ = writeln!(
        s,
        "{:<44} its manifest: body, cube layout, coverage, every product's parameters",
        format!("{CUBEMAP_DIR}/{MANIFEST}")
    );
    let _ = writeln!(
        s,
        "{:<44} each product's files with their size and blake3",
        format!("{CUBEMAP_DIR}/.penumbra/index/")
    );
    for p in &r.cubemap.products {
        let _ = writeln!(
            s,
            "{:<44} {} files, {}: {}",
            format!("{CUBEMAP_DIR}/ {}", p.product),
            p.files,
            size(p.bytes),
            product_words(&p.product)
        );
    }
    let _ = writeln!(
        s,
        "{:<44} marks this folder as a package penumbra wrote (a new package replaces it)",
        MARKER
    );
    let _ = writeln!(s, "{:<44} this file\n", README);
    let l = &ts.layout;
    let _ = writeln!(s, "The tileset\n-----------\n");
    let _ = writeln!(
        s,
        "Cube layout: {:?} projection, {}-px tiles (+{} px halo), levels 0..{}.",
        l.projection,
        l.tile_size,
        l.halo,
        l.levels.saturating_sub(1)
    );
    let _ = writeln!(s, "Coverage (tiles per level, share of the body):");
    for c in ts.coverage.iter().filter(|c| c.tiles > 0) {
        let _ = writeln!(
            s,
            "  level {:>2}: {:>7} tiles, {:.4} % of the body, {} m/px at a face centre",
            c.level,
            c.tiles,
            100.0 * c.tiles as f64 / (6 * c.tiles_per_face) as f64,
            fmt_m(celestia::cube_pixel_rad(l, c.level) * ts.body.radius_m)
        );
    }
    let _ = writeln!(s, "Sources of the heights (highest priority first):");
    if ts.mosaic.is_empty() {
        let _ = writeln!(s, "  {}", source_line(&ts.source));
    } else {
        for m in &ts.mosaic {
            let _ = writeln!(s, "  {}", source_line(&m.source));
        }
    }
    let _ = writeln!(
        s,
        "\nThe formats and this layout: docs/packaging.md, docs/formats.md and docs/tileset.md \
         of penumbra."
    );
    s
}
