//! One tile's coefficient pyramid: groups of four coefficients, each at its own resolution
//! (`multires`: group g at n/2^g, the exact mean of the finer pixels' coefficients; `full`:
//! every group at n), 16-bit encoded, and its file (docs/fourier.md, "File"): a small header,
//! then the planes as a GPU uploads them (RGBA16F or RGBA16Snorm texels holding two
//! coefficients as re, im, re, im), then a blake3 checksum.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use half::f16;
use serde::{Deserialize, Serialize};

use super::horizon::{HorizonError, HorizonLevelDistance};
use super::Identity;
use crate::cube::Face;
use crate::error::{Error, IoContext, Result};
use crate::fsio::{read_capped, write_staged};
use crate::layout::TileId;

/// The most coefficients `a` real samples have: ⌊A/2⌋ + 1.
pub fn max_coefficients(a: usize) -> usize {
    a / 2 + 1
}

/// Taper of the kept coefficients.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sigma {
    /// The plain truncated series.
    #[default]
    None,
    /// Lanczos σ-factors sinc(k/K): trade sharpness for less Gibbs ringing at cliffs.
    Lanczos,
}

impl Sigma {
    pub fn name(self) -> &'static str {
        match self {
            Sigma::None => "none",
            Sigma::Lanczos => "lanczos",
        }
    }
}

impl std::str::FromStr for Sigma {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "none" => Ok(Sigma::None),
            "lanczos" => Ok(Sigma::Lanczos),
            _ => Err(format!("unknown sigma '{s}' (none, lanczos)")),
        }
    }
}

/// Coefficients per group (one mip level of the multires pyramid).
pub const GROUP: usize = 4;
/// Magic bytes that open a pyramid file.
pub const MAGIC: &[u8; 8] = b"PNBRFHM\0";
/// Version of the file layout. 2: the header holds the file's identity (level, face, y, x and
/// the run key, bytes 48..128).
pub const VERSION: u32 = 2;
/// Bytes of the fixed header, then 16 per group.
pub const HEADER_BYTES: usize = 128;
/// Where the identity sits in the header: level (u8), face (u8, in `Face::ALL` order), two
/// zero bytes, y (u32), x (u32), four zero bytes, then the run key in ASCII, zero-padded to 64
/// bytes. All zero: a file written without an identity.
const IDENTITY_AT: usize = 48;
const RUN_KEY_AT: usize = 64;
const RUN_KEY_BYTES: usize = 64;
/// The product name of the pyramids' identities.
pub const ID: &str = "fourier";
const GROUP_BYTES: usize = 16;
const CHECKSUM_BYTES: usize = 32;
/// Bytes of one texel of a group: four coefficients × (re, im) × 16 bits, in two RGBA planes.
const TEXEL_BYTES: usize = GROUP * 2 * 2;
/// Most groups a file may declare (K ≤ 4·MAX_GROUPS = 2052 ≥ 4096/2 + 1).
pub const MAX_GROUPS: usize = 513;
/// Header flag: every pixel of the tile is lit for suns at or above `min_sun_el`; no planes.
pub const FLAG_FULLY_LIT: u8 = 1;

/// Spatial layout of the groups.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// Every group at the tile's resolution.
    Full,
    /// Group g at ⌊n/2^g⌋ (at least 1): the mip chain of a 2-layer texture array.
    #[default]
    Multires,
}

impl Layout {
    pub fn name(self) -> &'static str {
        match self {
            Layout::Full => "full",
            Layout::Multires => "multires",
        }
    }

    /// Texels per side of group `g` for tiles of `n` pixels.
    pub fn resolution(self, n: usize, g: usize) -> usize {
        match self {
            Layout::Full => n,
            Layout::Multires => (n >> g.min(63)).max(1),
        }
    }

    fn code(self) -> u8 {
        match self {
            Layout::Full => 0,
            Layout::Multires => 1,
        }
    }
}

impl std::str::FromStr for Layout {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "full" => Ok(Layout::Full),
            "multires" => Ok(Layout::Multires),
            _ => Err(format!("unknown layout '{s}' (multires, full)")),
        }
    }
}

/// How each 16-bit value holds a coefficient.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// IEEE half floats (11-bit mantissa), as in the paper.
    #[default]
    F16,
    /// Signed normalised 16-bit integers times a per-tile, per-group scale.
    Snorm16,
}

impl Encoding {
    pub fn name(self) -> &'static str {
        match self {
            Encoding::F16 => "f16",
            Encoding::Snorm16 => "snorm16",
        }
    }

    fn code(self) -> u8 {
        match self {
            Encoding::F16 => 0,
            Encoding::Snorm16 => 1,
        }
    }
}

impl std::str::FromStr for Encoding {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "f16" => Ok(Encoding::F16),
            "snorm16" => Ok(Encoding::Snorm16),
            _ => Err(format!("unknown encoding '{s}' (f16, snorm16)")),
        }
    }
}

/// How a reduced group's texels are made from the full-resolution coefficients.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Reduce {
    /// The mean of the finer pixels' coefficients (the coefficients of the averaged horizon).
    #[default]
    Mean,
    /// The texels whose bilinear interpolation at the pixel centres, as a GPU samples them, is
    /// closest to the pixels' coefficients in least squares (by Parseval: the smallest RMS
    /// horizon error over azimuths that texels at this resolution can give).
    Fit,
}

impl Reduce {
    pub fn name(self) -> &'static str {
        match self {
            Reduce::Mean => "mean",
            Reduce::Fit => "fit",
        }
    }
}

impl std::str::FromStr for Reduce {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "mean" => Ok(Reduce::Mean),
            "fit" => Ok(Reduce::Fit),
            _ => Err(format!("unknown reduction '{s}' (mean, fit)")),
        }
    }
}

/// Number of groups holding `k` coefficients.
pub fn groups(k: usize) -> usize {
    k.div_ceil(GROUP)
}

/// Bytes of a tile's file.
pub fn file_bytes(n: usize, k: usize, layout: Layout) -> usize {
    let g = groups(k);
    HEADER_BYTES
        + g * GROUP_BYTES
        + (0..g)
            .map(|i| layout.resolution(n, i).pow(2) * TEXEL_BYTES)
            .sum::<usize>()
        + CHECKSUM_BYTES
}

/// One group: `res`² texels of four coefficients, as decoded values.
#[derive(Clone, Debug, PartialEq)]
pub struct Group {
    pub res: usize,
    /// snorm16: value = q/32767 · scale; f16: 1.
    pub scale: f32,
    /// Texel (x, y), coefficient slot c (0..4) at `[(y·res + x)·4 + c]`, (re, im).
    pub coef: Vec<[f32; 2]>,
}

/// A tile's decoded pyramid.
#[derive(Clone, Debug, PartialEq)]
pub struct Pyramid {
    /// Pixels per tile side.
    pub n: usize,
    /// Azimuth samples the series came from.
    pub azimuths: usize,
    /// Coefficients kept (≤ 4 × groups; the last group's spare slots are zero).
    pub k: usize,
    pub layout: Layout,
    pub encoding: Encoding,
    pub sigma: Sigma,
    /// Highest horizon of any pixel of the tile (degrees), after the floor.
    pub max_horizon_deg: f32,
    /// Marked fully lit for suns at or above the manifest's `min_sun_el_deg`: no groups.
    pub fully_lit: bool,
    pub groups: Vec<Group>,
}

/// Round `v` as `enc` stores it with `scale`.
pub(crate) fn quantise(v: f32, enc: Encoding, scale: f32) -> f32 {
    match enc {
        Encoding::F16 => f16::from_f32(v).to_f32(),
        Encoding::Snorm16 => snorm_value(snorm_code(v, scale), scale),
    }
}

fn snorm_code(v: f32, scale: f32) -> i16 {
    ((v / scale) * 32767.0).round().clamp(-32767.0, 32767.0) as i16
}

fn snorm_value(q: i16, scale: f32) -> f32 {
    (q as f32 / 32767.0) * scale
}

impl Pyramid {
    /// A tile marked fully lit: no coefficients.
    pub fn fully_lit(
        n: usize,
        azimuths: usize,
        layout: Layout,
        encoding: Encoding,
        sigma: Sigma,
        max_horizon_deg: f32,
    ) -> Pyramid {
        Pyramid {
            n,
            azimuths,
            k: 0,
            layout,
            encoding,
            sigma,
            max_horizon_deg,
            fully_lit: true,
            groups: Vec::new(),
        }
    }

    /// The file's bytes, without an identity.
    pub fn encode(&self) -> Vec<u8> {
        self.encode_identified(None)
    }

    /// The file's bytes with `identity` in its header (what [`write`] stores). A run key
    /// longer than 64 bytes is cut (run keys are 64 hex digits).
    pub fn encode_identified(&self, identity: Option<&Identity>) -> Vec<u8> {
        let g = self.groups.len();
        let header = HEADER_BYTES + g * GROUP_BYTES;
        let payload: usize = self
            .groups
            .iter()
            .map(|gr| gr.res * gr.res * TEXEL_BYTES)
            .sum();
        let mut b = Vec::with_capacity(header + payload + CHECKSUM_BYTES);
        b.extend_from_slice(MAGIC);
        b.extend_from_slice(&VERSION.to_le_bytes());
        b.extend_from_slice(&(self.n as u32).to_le_bytes());
        b.extend_from_slice(&(self.azimuths as u32).to_le_bytes());
        b.extend_from_slice(&(self.k as u32).to_le_bytes());
        b.push(self.layout.code());
        b.push(self.encoding.code());
        b.push(match self.sigma {
            Sigma::None => 0,
            Sigma::Lanczos => 1,
        });
        b.push(if self.fully_lit { FLAG_FULLY_LIT } else { 0 });
        b.extend_from_slice(&(g as u32).to_le_bytes());
        b.extend_from_slice(&self.max_horizon_deg.to_le_bytes());
        b.extend_from_slice(&(header as u32).to_le_bytes());
        b.extend_from_slice(&(payload as u64).to_le_bytes());
        b.resize(HEADER_BYTES, 0);
        if let Some(id) = identity {
            b[IDENTITY_AT] = id.level;
            b[IDENTITY_AT + 1] = id.face.index() as u8;
            b[IDENTITY_AT + 4..IDENTITY_AT + 8].copy_from_slice(&id.y.to_le_bytes());
            b[IDENTITY_AT + 8..IDENTITY_AT + 12].copy_from_slice(&id.x.to_le_bytes());
            let key = id.run_key.as_bytes();
            let k = key.len().min(RUN_KEY_BYTES);
            b[RUN_KEY_AT..RUN_KEY_AT + k].copy_from_slice(&key[..k]);
        }
        for (i, gr) in self.groups.iter().enumerate() {
            b.extend_from_slice(&(gr.res as u32).to_le_bytes());
            b.extend_from_slice(&((i * GROUP) as u32).to_le_bytes());
            b.extend_from_slice(&gr.scale.to_le_bytes());
            b.extend_from_slice(&0u32.to_le_bytes());
        }
        for gr in &self.groups {
            for plane in 0..2 {
                for t in 0..gr.res * gr.res {
                    for c in 0..2 {
                        let v = gr.coef[t * GROUP + plane * 2 + c];
                        for x in v {
                            let bits: u16 = match self.encoding {
                                Encoding::F16 => f16::from_f32(x).to_bits(),
                                Encoding::Snorm16 => snorm_code(x, gr.scale) as u16,
                            };
                            b.extend_from_slice(&bits.to_le_bytes());
                        }
                    }
                }
            }
        }
        let h = blake3::hash(&b);
        b.extend_from_slice(h.as_bytes());
        b
    }

    /// Read a file's bytes back, checking everything against `expect` (tile size, azimuths)
    /// and the checksum; errors name `path`.
    pub fn decode(bytes: &[u8], path: &Path, n: usize, azimuths: usize) -> Result<Pyramid> {
        Self::decode_identified(bytes, path, n, azimuths).map(|(p, _)| p)
    }

    /// [`Pyramid::decode`] of a file that must be `expected` (its identity is checked).
    pub fn decode_as(
        bytes: &[u8],
        path: &Path,
        n: usize,
        azimuths: usize,
        expected: &Identity,
    ) -> Result<Pyramid> {
        let (p, found) = Self::decode_identified(bytes, path, n, azimuths)?;
        Identity::check(expected, found).map_err(|m| Error::invalid(path, m))?;
        Ok(p)
    }

    /// Decode and return the identity the header holds (None: all zero).
    #[allow(clippy::type_complexity)]
    fn decode_identified(
        bytes: &[u8],
        path: &Path,
        n: usize,
        azimuths: usize,
    ) -> Result<(Pyramid, Option<std::result::Result<Identity, String>>)> {
        let bad = |msg: String| {
            Error::invalid(
                path,
                format!("{msg}; delete it and rerun `penumbra fourier` (or the horizon stage)"),
            )
        };
        if bytes.len() < HEADER_BYTES + CHECKSUM_BYTES || &bytes[..8] != MAGIC {
            return Err(bad(
                "not a Penumbra Fourier pyramid (bad magic or too short)".into(),
            ));
        }
        let (body, sum) = bytes.split_at(bytes.len() - CHECKSUM_BYTES);
        if blake3::hash(body).as_bytes() != sum {
            return Err(bad(
                "checksum mismatch: the file is damaged or truncated".into()
            ));
        }
        let u32_at = |o: usize| u32::from_le_bytes(body[o..o + 4].try_into().expect("4 bytes"));
        let f32_at = |o: usize| f32::from_le_bytes(body[o..o + 4].try_into().expect("4 bytes"));
        let version = u32_at(8);
        if version != VERSION {
            return Err(bad(format!(
                "format version {version} (this penumbra reads {VERSION})"
            )));
        }
        let (fn_, fa, k) = (
            u32_at(12) as usize,
            u32_at(16) as usize,
            u32_at(20) as usize,
        );
        if fn_ != n || fa != azimuths {
            return Err(bad(format!(
                "holds {fn_}-pixel tiles of {fa} azimuths, the manifest says {n} and {azimuths}"
            )));
        }
        let layout = match body[24] {
            0 => Layout::Full,
            1 => Layout::Multires,
            x => return Err(bad(format!("unknown layout code {x}"))),
        };
        let encoding = match body[25] {
            0 => Encoding::F16,
            1 => Encoding::Snorm16,
            x => return Err(bad(format!("unknown encoding code {x}"))),
        };
        let sigma = match body[26] {
            0 => Sigma::None,
            1 => Sigma::Lanczos,
            x => return Err(bad(format!("unknown sigma code {x}"))),
        };
        let flags = body[27];
        if flags & !FLAG_FULLY_LIT != 0 {
            return Err(bad(format!("unknown flags {flags:#x}")));
        }
        let fully_lit = flags & FLAG_FULLY_LIT != 0;
        let g = u32_at(28) as usize;
        let max_horizon_deg = f32_at(32);
        if !(-90.0..=90.0).contains(&max_horizon_deg) {
            return Err(bad(format!(
                "highest horizon {max_horizon_deg} is not an angle"
            )));
        }
        if g > MAX_GROUPS || (fully_lit && (g != 0 || k != 0)) || (!fully_lit && groups(k) != g) {
            return Err(bad(format!(
                "{g} groups do not hold {k} coefficients (at most {MAX_GROUPS} groups)"
            )));
        }
        if !fully_lit && (k == 0 || k > max_coefficients(azimuths)) {
            return Err(bad(format!(
                "{k} coefficients of {azimuths} azimuths (1..={})",
                max_coefficients(azimuths)
            )));
        }
        let header = u32_at(36) as usize;
        let payload = u64::from_le_bytes(body[40..48].try_into().expect("8 bytes")) as usize;
        if header != HEADER_BYTES + g * GROUP_BYTES {
            return Err(bad(format!("header length {header} for {g} groups")));
        }
        let want: usize = (0..g)
            .map(|i| layout.resolution(n, i).pow(2) * TEXEL_BYTES)
            .sum();
        if payload != want || body.len() != header + payload {
            return Err(bad(format!(
                "payload is {} bytes, {want} expected for {g} groups of {n}-pixel tiles ({})",
                body.len().saturating_sub(header),
                layout.name()
            )));
        }
        let mut out = Vec::with_capacity(g);
        let mut off = header;
        for i in 0..g {
            let o = HEADER_BYTES + i * GROUP_BYTES;
            let (res, first, scale) = (u32_at(o) as usize, u32_at(o + 4) as usize, f32_at(o + 8));
            if res != layout.resolution(n, i) || first != i * GROUP {
                return Err(bad(format!(
                    "group {i} is {res} texels from coefficient {first}, expected {} from {}",
                    layout.resolution(n, i),
                    i * GROUP
                )));
            }
            if !(scale.is_finite() && scale > 0.0 && scale <= 1e6) {
                return Err(bad(format!("group {i} has scale {scale}")));
            }
            let mut coef = vec![[0.0f32; 2]; res * res * GROUP];
            for plane in 0..2 {
                for t in 0..res * res {
                    for c in 0..2 {
                        let mut v = [0.0f32; 2];
                        for x in &mut v {
                            let bits = u16::from_le_bytes([body[off], body[off + 1]]);
                            off += 2;
                            *x = match encoding {
                                Encoding::F16 => f16::from_bits(bits).to_f32(),
                                Encoding::Snorm16 => snorm_value(bits as i16, scale),
                            };
                            if !x.is_finite() {
                                return Err(bad(format!("group {i} holds a non-finite value")));
                            }
                        }
                        coef[t * GROUP + plane * 2 + c] = v;
                    }
                }
            }
            out.push(Group { res, scale, coef });
        }
        let pyramid = Pyramid {
            n,
            azimuths,
            k,
            layout,
            encoding,
            sigma,
            max_horizon_deg,
            fully_lit,
            groups: out,
        };
        Ok((pyramid, identity_of(body)))
    }

    /// Bytes of this pyramid's file.
    pub fn file_bytes(&self) -> usize {
        if self.fully_lit {
            HEADER_BYTES + CHECKSUM_BYTES
        } else {
            file_bytes(self.n, self.k, self.layout)
        }
    }
}

/// What a pyramid file's header says it holds, which the manifest's labels describe.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeaderLabels {
    /// Coefficients kept (0 when fully lit).
    pub k: usize,
    pub layout: Layout,
    pub encoding: Encoding,
    pub sigma: Sigma,
    pub fully_lit: bool,
}

impl Pyramid {
    /// What its header says it holds.
    pub fn labels(&self) -> HeaderLabels {
        HeaderLabels {
            k: self.k,
            layout: self.layout,
            encoding: self.encoding,
            sigma: self.sigma,
            fully_lit: self.fully_lit,
        }
    }
}

/// The labels of a pyramid file's header, read from the header alone (verify checks the file's
/// hash against the index first).
pub fn read_labels(bytes: &[u8]) -> std::result::Result<HeaderLabels, String> {
    if bytes.len() < HEADER_BYTES + CHECKSUM_BYTES || &bytes[..8] != MAGIC {
        return Err("not a Penumbra Fourier pyramid (bad magic or too short)".into());
    }
    let k = u32::from_le_bytes(bytes[20..24].try_into().expect("4 bytes")) as usize;
    let layout = match bytes[24] {
        0 => Layout::Full,
        1 => Layout::Multires,
        x => return Err(format!("unknown layout code {x}")),
    };
    let encoding = match bytes[25] {
        0 => Encoding::F16,
        1 => Encoding::Snorm16,
        x => return Err(format!("unknown encoding code {x}")),
    };
    let sigma = match bytes[26] {
        0 => Sigma::None,
        1 => Sigma::Lanczos,
        x => return Err(format!("unknown sigma code {x}")),
    };
    Ok(HeaderLabels {
        k,
        layout,
        encoding,
        sigma,
        fully_lit: bytes[27] & FLAG_FULLY_LIT != 0,
    })
}

/// The key of tile `id` in the manifest's `tile_coefficients`: `level/face/x/y`.
pub fn tile_key(id: TileId) -> String {
    format!("{}/{}/{}/{}", id.level, id.face.name(), id.x, id.y)
}

/// What to do about a pyramid whose header is not what the manifest's labels say.
const RELABEL: &str = "the file was rewritten or the manifest edited after the stage made them: \
                       restore the manifest, or delete the file and rerun the stage that makes it \
                       (`penumbra verify DIR` lists every such file)";

/// Compare what tile `id`'s pyramid holds (`found`, from its header) with the manifest entry's
/// labels: `encoding`, `layout`, `sigma`, and the coefficients it keeps (`coefficients`, or the
/// tile's `tile_coefficients`; none when fully lit, which needs `min_sun_el_deg`). The error
/// names the label and says what the file holds (without the path).
pub fn check_labels(
    found: &HeaderLabels,
    f: &FourierProduct,
    id: TileId,
) -> std::result::Result<(), String> {
    let differs = |field: &str, holds: &str, says: &str| {
        Err(format!(
            "holds {holds}, but the manifest's `products.fourier.{field}` says {says}; {RELABEL}"
        ))
    };
    if found.encoding.name() != f.encoding {
        let holds = format!("{}-encoded coefficients", found.encoding.name());
        return differs("encoding", &holds, &f.encoding);
    }
    if found.layout.name() != f.layout {
        let holds = format!("groups in the {} layout", found.layout.name());
        return differs("layout", &holds, &f.layout);
    }
    if found.sigma.name() != f.sigma {
        let holds = format!("coefficients tapered with sigma {}", found.sigma.name());
        return differs("sigma", &holds, &f.sigma);
    }
    if found.fully_lit && f.min_sun_el_deg.is_none() {
        return Err(format!(
            "is marked fully lit (no coefficients), but the manifest's \
             `products.fourier.min_sun_el_deg` is absent: no tile was marked; {RELABEL}"
        ));
    }
    let (want, field) = match &f.tile_coefficients {
        Some(m) => match m.get(&tile_key(id)) {
            Some(&k) => (k, "tile_coefficients"),
            None => {
                return Err(format!(
                    "is not listed in the manifest's `products.fourier.tile_coefficients` \
                     (tile {}); {RELABEL}",
                    tile_key(id)
                ))
            }
        },
        None if found.fully_lit => (0, "coefficients"),
        None => (f.coefficients, "coefficients"),
    };
    if found.k != want {
        let holds = format!("{} coefficients per pixel", found.k);
        return differs(field, &holds, &want.to_string());
    }
    Ok(())
}

/// The identity in a pyramid file's header, read from the header alone (verify checks the
/// file's hash against the index first): None when it has none, `Err` when the file is too
/// short to hold one or not a pyramid file.
pub fn read_identity(
    bytes: &[u8],
) -> std::result::Result<Option<std::result::Result<Identity, String>>, String> {
    if bytes.len() < HEADER_BYTES + CHECKSUM_BYTES || &bytes[..8] != MAGIC {
        return Err("not a Penumbra Fourier pyramid (bad magic or too short)".into());
    }
    Ok(identity_of(bytes))
}

/// The identity a file's header holds (the checksum has been verified): None when the field
/// is all zero, `Err` (its bytes, for the message) when it is not one.
fn identity_of(body: &[u8]) -> Option<std::result::Result<Identity, String>> {
    let f = &body[IDENTITY_AT..HEADER_BYTES];
    if f.iter().all(|&b| b == 0) {
        return None;
    }
    let u32_at = |o: usize| u32::from_le_bytes(body[o..o + 4].try_into().expect("4 bytes"));
    let key = &body[RUN_KEY_AT..RUN_KEY_AT + RUN_KEY_BYTES];
    let key_len = key.iter().position(|&b| b == 0).unwrap_or(RUN_KEY_BYTES);
    let face = Face::ALL.get(body[IDENTITY_AT + 1] as usize).copied();
    match (face, std::str::from_utf8(&key[..key_len])) {
        (Some(face), Ok(key)) if key.bytes().all(|b| b.is_ascii_graphic()) => Some(Ok(Identity {
            product: ID.to_string(),
            level: body[IDENTITY_AT],
            face,
            y: u32_at(IDENTITY_AT + 4),
            x: u32_at(IDENTITY_AT + 8),
            run_key: key.to_string(),
        })),
        _ => Some(Err(format!("header bytes 48..128 = {:02x?}", f))),
    }
}

pub const PATTERN: &str = "fourier/{level}/{face}/{y}/{x}.fhm";
/// Name and version of the pyramid files (part of the run key). 2: the header holds the
/// file's identity.
pub const FORMAT: &str = "penumbra-fourier-2";
pub const FLOOR: &str = "horizons below the tangent to the sphere of the lowest terrain \
     (radius + terrain_min_m) are raised to it, −90° (no terrain) included";

/// Path of a tile's pyramid below `dir`.
pub fn tile_path(dir: &Path, id: TileId) -> PathBuf {
    super::tile_path(dir, PATTERN, id)
}

/// Write a pyramid's file with its identity (staged: made durable by the run's commit); its
/// size in bytes.
pub fn write(path: &Path, p: &Pyramid, identity: &Identity) -> Result<u64> {
    let bytes = p.encode_identified(Some(identity));
    write_staged(path, |f| f.write_all(&bytes).at(path))?;
    Ok(bytes.len() as u64)
}

/// Read and check a tile's pyramid of `n`² pixels and `azimuths` samples (no larger than the
/// largest such file may be); the pyramid and its file's size.
pub fn read(path: &Path, n: usize, azimuths: usize) -> Result<(Pyramid, u64)> {
    let bytes = read_capped(path, max_file_bytes(n, azimuths), "a Fourier pyramid")?;
    Ok((
        Pyramid::decode(&bytes, path, n, azimuths)?,
        bytes.len() as u64,
    ))
}

/// The largest pyramid file of `n`-pixel tiles of `azimuths` samples (every coefficient, every
/// group at full resolution): a file the index does not know is refused above it.
pub fn max_file_bytes(n: usize, azimuths: usize) -> u64 {
    file_bytes(n, max_coefficients(azimuths), Layout::Full) as u64
}

/// The groups of a pyramid holding `k` coefficients, for the manifest.
pub fn group_list(n: usize, k: usize, layout: Layout) -> Vec<FourierGroup> {
    (0..groups(k))
        .map(|g| FourierGroup {
            first: g * GROUP,
            count: (k - g * GROUP).min(GROUP),
            resolution: layout.resolution(n, g),
        })
        .collect()
}

/// One group of a Fourier pyramid: coefficients `first..first + count` at `resolution`² texels.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FourierGroup {
    pub first: usize,
    pub count: usize,
    pub resolution: usize,
}

/// Fourier-compressed horizon pyramids: per height tile one file of coefficient groups.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FourierProduct {
    /// Path pattern, one file per height tile of the levels listed.
    pub path: String,
    /// File format name and version (docs/fourier.md).
    pub format: String,
    /// Tile levels that have pyramids.
    pub levels: Vec<u8>,
    /// Azimuth samples the series come from (A); the series' variable is the plane azimuth.
    pub azimuths: usize,
    /// The azimuth convention in one line (the raw maps').
    pub azimuth: String,
    /// Coefficients kept per pixel (K; the most any tile keeps when `max_error_deg` is set).
    pub coefficients: usize,
    /// `multires` or `full`.
    pub layout: String,
    /// `f16` or `snorm16`.
    pub encoding: String,
    /// `none` or `lanczos`.
    pub sigma: String,
    /// How reduced groups were made: `mean` or `fit` (docs/fourier.md).
    pub reduce: String,
    /// The groups of a tile holding `coefficients`.
    pub groups: Vec<FourierGroup>,
    /// Bytes of a tile's file holding `coefficients`.
    pub bytes_per_tile: u64,
    /// What the stored series approximate: the raw horizon floored at the tangent to the sphere
    /// of the lowest terrain (a body does not end where its DEM does).
    pub floor: String,
    /// Error budget that chose K per tile (degrees, 99th percentile of per-pixel RMS), if any,
    /// and then each tile's K (`level/face/x/y` → K).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_error_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tile_coefficients: Option<BTreeMap<String, usize>>,
    /// Tiles marked fully lit for suns whose centre is at or above `min_sun_el_deg` (their
    /// horizon never rises above `min_sun_el_deg − sun_radius_deg`): no coefficients stored.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_sun_el_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sun_radius_deg: Option<f64>,
    pub tiles_fully_lit: u64,
    /// `raw` (from the stored horizon maps) or `streamed` (compressed as the horizon stage
    /// computed them).
    pub source: String,
    /// How the horizons were computed: `fast`, `exact` or `reference`, the fast method's near
    /// field, the terrain range bounding the search, and the per-level distances.
    pub horizon_method: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub horizon_near_px: Option<f64>,
    /// The horizon method's measured error against the reference (the sweep method).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub horizon_error: Option<HorizonError>,
    pub terrain_min_m: f64,
    pub terrain_max_m: f64,
    pub distances: Vec<HorizonLevelDistance>,
    /// Hash of the tool version, the inputs' run keys and the options.
    pub run_key: String,
    /// What `run_key` hashes besides the run keys of the products it was made from (the tool
    /// version, the stage's format strings, its parameters as text), so that a reader
    /// recomputes it; absent in tilesets written before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_key_basis: Option<super::KeyBasis>,
}
