//! The formats layer: every product's file format and manifest entry, in one place below the
//! store (docs/architecture.md). Each module says what a product's files hold and how they are
//! named, writes them (staged, atomically) and reads them back checked; it knows no stage, no
//! runner and no tileset beyond the path patterns it is given. The store ([`crate::tileset`])
//! and the stages both use it.
//!
//! | module | product | files |
//! |---|---|---|
//! | [`height`] | height tiles | EXR: f32 `height` + f16 `mask`, halo included |
//! | [`albedo`] | albedo tiles | PNG, 8/16-bit, 1–4 channels |
//! | [`mip`] | max and (min, max) mipmaps | mip-mapped EXR per tile; face pyramids |
//! | [`horizon`] | raw horizon maps | EXR of `A` stacked planes, f16/f32 |
//! | [`fourier`] | Fourier horizon pyramids | `.fhm`: header, 16-bit groups, blake3 |
//! | [`lit`] | lit-fraction maps | grey PNG, f32 EXR |
//!
//! The EXR codec below them is [`crate::exrcodec`]; atomic writes are [`crate::fsio`].

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::cube::Face;
use crate::layout::TileId;

pub mod albedo;
pub mod archive;
pub mod fourier;
pub mod height;
pub mod horizon;
pub mod lit;
pub mod mip;
pub mod vt;

#[cfg(test)]
mod tests;

pub use crate::exrcodec::TileCompression;

/// The top-level folders the listed products own (`tileset::Product::dirs`); a product the
/// registry does not list may claim none of them.
pub const LISTED_DIRS: &[&str] = &["height", "albedo", "maxmip", "minmax", "horizon", "fourier"];

/// A source file a product was made from, as the manifest records it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SourceFile {
    pub path: String,
    pub bytes: u64,
    pub blake3: String,
}

/// Path of a tile's file below `root` from a product's path pattern (`{level}`, `{face}`,
/// `{x}`, `{y}`), e.g. `height/{level}/{face}/{y}/{x}.exr`.
pub fn tile_path(root: &Path, pattern: &str, id: TileId) -> PathBuf {
    root.join(
        pattern
            .replace("{level}", &id.level.to_string())
            .replace("{face}", id.face.name())
            .replace("{x}", &id.x.to_string())
            .replace("{y}", &id.y.to_string()),
    )
}

/// Path of a per-(level, face) file below `root` from a pattern with `{level}` and `{face}`.
pub fn face_file_path(root: &Path, pattern: &str, level: u8, face: Face) -> PathBuf {
    root.join(
        pattern
            .replace("{level}", &level.to_string())
            .replace("{face}", face.name()),
    )
}

/// Path of chunk (cx, cy) of a per-(level, face) file below `root` from a pattern with
/// `{level}`, `{face}`, `{cx}` and `{cy}`.
pub fn face_chunk_file_path(
    root: &Path,
    pattern: &str,
    level: u8,
    face: Face,
    cx: u32,
    cy: u32,
) -> PathBuf {
    root.join(
        pattern
            .replace("{level}", &level.to_string())
            .replace("{face}", face.name())
            .replace("{cx}", &cx.to_string())
            .replace("{cy}", &cy.to_string()),
    )
}

/// What a product file is: the product, the tile (or face-pyramid chunk) and the run that made
/// it, written into the file itself (an EXR header attribute, the `.fhm` header) and checked on
/// every read, so that a file moved, copied or swapped from elsewhere — another tile, another
/// level, another tileset — is refused instead of read as the file expected (docs/formats.md,
/// "File identity").
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Identity {
    /// The file's kind: `height`, `maxmip`, `minmax`, `minmax-face` (x = y = 0) or
    /// `minmax-face-chunk` (x, y: the chunk), `horizon`, `fourier`.
    pub product: String,
    pub level: u8,
    pub face: Face,
    pub y: u32,
    pub x: u32,
    /// The run key of the product's manifest entry (`run_key`; the tileset's for heights).
    pub run_key: String,
}

/// The version tag that opens an identity's text.
const IDENTITY_TAG: &str = "penumbra-identity-1";

impl Identity {
    /// The identity of tile `id`'s file of `product` made by the run `run_key`.
    pub fn tile(product: &str, id: TileId, run_key: &str) -> Identity {
        Identity {
            product: product.to_string(),
            level: id.level,
            face: id.face,
            y: id.y,
            x: id.x,
            run_key: run_key.to_string(),
        }
    }

    /// The identity of a per-(level, face) file (`x`, `y`: its chunk, 0 for a whole face).
    pub fn face(product: &str, level: u8, face: Face, x: u32, y: u32, run_key: &str) -> Identity {
        Identity {
            product: product.to_string(),
            level,
            face,
            y,
            x,
            run_key: run_key.to_string(),
        }
    }

    /// The text stored in an EXR header: `penumbra-identity-1 product=height level=3 face=px
    /// y=1 x=2 run=<run key>`.
    pub fn text(&self) -> String {
        format!(
            "{IDENTITY_TAG} product={} level={} face={} y={} x={} run={}",
            self.product,
            self.level,
            self.face.name(),
            self.y,
            self.x,
            self.run_key
        )
    }

    /// Parse [`Identity::text`]; None for anything else.
    pub fn parse(text: &str) -> Option<Identity> {
        let mut it = text.split(' ');
        if it.next()? != IDENTITY_TAG {
            return None;
        }
        let mut field = |key: &str| -> Option<String> {
            it.next()?
                .strip_prefix(key)?
                .strip_prefix('=')
                .map(str::to_string)
        };
        let product = field("product")?;
        let level = field("level")?.parse().ok()?;
        let face = field("face")?;
        let face = *Face::ALL.iter().find(|f| f.name() == face)?;
        let y = field("y")?.parse().ok()?;
        let x = field("x")?.parse().ok()?;
        let run_key = field("run")?;
        if it.next().is_some() {
            return None;
        }
        Some(Identity {
            product,
            level,
            face,
            y,
            x,
            run_key,
        })
    }

    /// Compare what a file claims to be (`found`: its parsed identity, None when it has none,
    /// `Some(Err(text))` when it cannot be read) with what was expected where it was found;
    /// the error says both and what to do (without the path).
    pub fn check(
        expected: &Identity,
        found: Option<std::result::Result<Identity, String>>,
    ) -> std::result::Result<(), String> {
        match found {
            Some(Ok(f)) if f == *expected => Ok(()),
            Some(Ok(f)) => Err(format!(
                "claims to be {f} but {expected} was expected here: the file was moved, copied \
                 or swapped from elsewhere; {REBUILD}"
            )),
            Some(Err(t)) => Err(format!(
                "carries a damaged identity ({t:?}) where {expected} was expected; {REBUILD}"
            )),
            None => Err(format!(
                "carries no identity where {expected} was expected: it was written by a penumbra \
                 older than tileset format 2 (an albedo tile: older than its identity chunk), or \
                 by another program; {REBUILD}"
            )),
        }
    }
}

/// What to do about a file that is not what the tileset says it is.
const REBUILD: &str = "delete it and rerun the stage that makes it (`penumbra verify DIR` lists \
                       every such file)";

impl std::fmt::Display for Identity {
    /// `height 3/px/y1/x2 (run 1a2b3c4d5e6f)`: the run key shortened to 12 digits.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let key: String = self.run_key.chars().take(12).collect();
        write!(
            f,
            "{} {}/{}/y{}/x{} (run {key})",
            self.product,
            self.level,
            self.face.name(),
            self.y,
            self.x
        )
    }
}

/// A run key: blake3 of the tool `version`, a stage's `format` version strings, the run keys
/// of its `inputs` and its `params`, in that order (`runner::run_key` with this tool's version;
/// `manifest::consistency` recomputes a manifest's).
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

/// What a stage product's run key hashes besides the run keys of the products it was made from,
/// exactly as the stage hashed it: the tool version that ran the stage, the stage's format and
/// algorithm version strings, and its parameters (the height pattern, its options as JSON, …),
/// each as text. Recorded in the product's manifest entry (`run_key_basis`) so that a reader
/// recomputes the key and compares the entry's labels (precision, method, encoding, …) with the
/// options the files were really made with (docs/tileset.md, "`tileset.json`").
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct KeyBasis {
    /// The version of the penumbra that ran the stage.
    pub tool: String,
    /// The stage's format and algorithm version strings.
    pub format: Vec<String>,
    /// Its parameters, in the order hashed.
    pub params: Vec<String>,
}

impl KeyBasis {
    /// The run key of a run on this basis whose inputs have the run keys `inputs`.
    pub fn key(&self, inputs: &[&str]) -> String {
        let format: Vec<&str> = self.format.iter().map(String::as_str).collect();
        let params: Vec<&[u8]> = self.params.iter().map(|p| p.as_bytes()).collect();
        run_key_of(&self.tool, &format, inputs, &params)
    }
}

/// What the manifest says one channel of an EXR product file holds, and what says so: checked
/// against the file's header on every read and by `penumbra verify` ([`check_channels`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelLabel {
    pub name: String,
    /// Its sample type: `f16` or `f32`.
    pub sample: String,
    /// What lists the channel, e.g. "the manifest's `products.mip.max_channels`".
    pub names_by: String,
    /// What gives its sample type, e.g. "the manifest's `products.mip.precision`".
    pub sample_by: String,
}

impl ChannelLabel {
    /// A channel whose name the manifest field `names` lists and whose sample type the field
    /// `sample_field` gives.
    pub fn of(name: &str, sample: &str, names: &str, sample_field: &str) -> ChannelLabel {
        ChannelLabel {
            name: name.to_string(),
            sample: sample.to_string(),
            names_by: format!("the manifest's `{names}`"),
            sample_by: format!("the manifest's `{sample_field}`"),
        }
    }
}

/// What to do about a file whose contents are not what the manifest's labels say.
const RELABEL: &str = "the file was rewritten or the manifest edited after the stage made them: \
                       restore the manifest, or delete the file and rerun the stage that makes it \
                       (`penumbra verify DIR` lists every such file)";

/// Compare the channels an EXR file holds (`found`: name and sample type, as its header says)
/// with the manifest's labels (`want`); the error names the label and says what the file holds
/// (without the path).
pub fn check_channels(
    found: &[(String, &str)],
    want: &[ChannelLabel],
) -> std::result::Result<(), String> {
    let holds = || {
        found
            .iter()
            .map(|(n, t)| format!("`{n}` ({t})"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    for w in want {
        match found.iter().find(|(n, _)| *n == w.name) {
            None => {
                return Err(format!(
                    "holds no channel `{}`, which {} lists (it holds {}); {RELABEL}",
                    w.name,
                    w.names_by,
                    holds()
                ))
            }
            Some((_, t)) if *t != w.sample => {
                return Err(format!(
                    "holds channel `{}` as {t} samples, but {} says {}; {RELABEL}",
                    w.name, w.sample_by, w.sample
                ))
            }
            Some(_) => {}
        }
    }
    if let Some((n, t)) = found
        .iter()
        .find(|(n, _)| want.iter().all(|w| w.name != *n))
    {
        let by = want.first().map_or("the manifest", |w| w.names_by.as_str());
        return Err(format!(
            "holds channel `{n}` ({t}), which {by} does not list; {RELABEL}"
        ));
    }
    Ok(())
}

/// The channels of a decoded or parsed EXR header as [`check_channels`] takes them.
pub(crate) fn exr_channels<'a, I>(channels: I) -> Vec<(String, &'static str)>
where
    I: IntoIterator<Item = (&'a String, exr::meta::attribute::SampleType)>,
{
    channels
        .into_iter()
        .map(|(n, t)| (n.clone(), crate::exrcodec::sample_name(t)))
        .collect()
}

/// Parse an EXR file's identity attribute text for [`Identity::check`].
pub(crate) fn exr_identity(text: Option<String>) -> Option<std::result::Result<Identity, String>> {
    text.map(|t| Identity::parse(&t).ok_or(t))
}
