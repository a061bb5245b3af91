//! A corpus of damaged DEMs, generated at test time from crops of the shared real DEMs and
//! written in every format Penumbra reads (PDS3, raw + sidecar, SRTM .hgt, GeoTIFF, EXR), each
//! with one damage: label and sidecar keys out of range or of the wrong type, NaN/inf/huge
//! samples, truncated or padded files, flipped bytes, bad names. Every case runs `penumbra
//! tile` into a copy of an existing valid tileset, and must either succeed with a valid
//! tileset or exit 2 naming the damaged file, without a panic and without touching the old
//! tileset. Never 101, a signal or a hang.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use penumbra::dem::Crs;
use penumbra::manifest::Tileset;

use crate::util::{copy_tree, geokeys, penumbra_bin, shared_data, Rng, LOLA_SOUTH_POLAR_KEYS};

/// Parallel `penumbra` runs (each with `--threads 1`).
const POOL: usize = 3;
/// A run that takes longer than this is killed and fails the test.
const RUN_LIMIT: Duration = Duration::from_secs(60);
/// Small tiles; each case adds `--levels`: 4 for the geographic crops (16° of the Moon or
/// Mars, 1° of Mars for Gale), 6 for the SRTM tile, 11 for the 320 m polar Shoemaker crop —
/// enough for every intact input to cover a few tiles, few enough that a damage stretching a
/// crop around the planet stays a few hundred tiles.
const TILE_ARGS: &[&str] = &["--threads", "1", "tile", "--tile-size", "64"];

// ------------------------------------------------------------------------------------------
// Files
// ------------------------------------------------------------------------------------------

/// A label or sidecar value: raw text, or a nested JSON object.
#[derive(Clone)]
enum Val {
    Text(String),
    Obj(Vec<(String, Val)>),
}

fn t(s: impl Into<String>) -> Val {
    Val::Text(s.into())
}

/// Keys in order, with values that may be nested one level (`bounds.north`).
#[derive(Clone, Default)]
struct Keys(Vec<(String, Val)>);

impl Keys {
    fn with(mut self, k: &str, v: Val) -> Keys {
        self.0.push((k.to_string(), v));
        self
    }

    fn set(&mut self, path: &str, v: Option<&str>) {
        let (head, rest) = match path.split_once('.') {
            Some((h, r)) => (h, Some(r)),
            None => (path, None),
        };
        let i = self
            .0
            .iter()
            .position(|(k, _)| k == head)
            .unwrap_or_else(|| panic!("no key {path}"));
        match (rest, v) {
            (None, None) => {
                self.0.remove(i);
            }
            (None, Some(v)) => self.0[i].1 = t(v),
            (Some(r), v) => {
                let Val::Obj(inner) = &mut self.0[i].1 else {
                    panic!("{head} is not an object")
                };
                let mut k = Keys(std::mem::take(inner));
                k.set(r, v);
                *inner = k.0;
            }
        }
    }

    fn json(&self) -> String {
        fn obj(items: &[(String, Val)]) -> String {
            let parts: Vec<String> = items
                .iter()
                .map(|(k, v)| match v {
                    Val::Text(s) => format!("\"{k}\": {s}"),
                    Val::Obj(o) => format!("\"{k}\": {}", obj(o)),
                })
                .collect();
            format!("{{{}}}", parts.join(", "))
        }
        obj(&self.0)
    }
}

/// A PDS3 label: top-level statements, the IMAGE object and the IMAGE_MAP_PROJECTION object.
#[derive(Clone)]
struct Label {
    top: Keys,
    image: Keys,
    proj: Keys,
}

impl Label {
    fn set(&mut self, key: &str, v: Option<&str>) {
        for k in [&mut self.top, &mut self.image, &mut self.proj] {
            if k.0.iter().any(|(n, _)| n == key) {
                k.set(key, v);
                return;
            }
        }
        panic!("no label key {key}");
    }

    fn keys(&self) -> Vec<String> {
        [&self.image, &self.proj]
            .iter()
            .flat_map(|k| k.0.iter().map(|(n, _)| n.clone()))
            .collect()
    }

    fn text(&self) -> String {
        let block = |k: &Keys| -> String {
            k.0.iter()
                .map(|(n, v)| match v {
                    Val::Text(s) => format!("  {n} = {s}\r\n"),
                    Val::Obj(_) => unreachable!(),
                })
                .collect()
        };
        format!(
            "PDS_VERSION_ID = PDS3\r\n{}OBJECT = IMAGE\r\n{}END_OBJECT = IMAGE\r\n\
             OBJECT = IMAGE_MAP_PROJECTION\r\n{}END_OBJECT = IMAGE_MAP_PROJECTION\r\nEND\r\n",
            block(&self.top),
            block(&self.image),
            block(&self.proj)
        )
    }
}

/// Samples of a crop, as the file stores them.
#[derive(Clone)]
enum Data {
    I16(Vec<i16>),
    U16(Vec<u16>),
    F32(Vec<f32>),
}

impl Data {
    fn len(&self) -> usize {
        match self {
            Data::I16(v) => v.len(),
            Data::U16(v) => v.len(),
            Data::F32(v) => v.len(),
        }
    }

    fn bytes(&self, big_endian: bool) -> Vec<u8> {
        match (self, big_endian) {
            (Data::I16(v), false) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            (Data::I16(v), true) => v.iter().flat_map(|x| x.to_be_bytes()).collect(),
            (Data::U16(v), false) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            (Data::U16(v), true) => v.iter().flat_map(|x| x.to_be_bytes()).collect(),
            (Data::F32(v), false) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            (Data::F32(v), true) => v.iter().flat_map(|x| x.to_be_bytes()).collect(),
        }
    }

    /// Heights in metres for formats that store floats.
    fn to_f32(&self, scale: f32, offset: f32) -> Vec<f32> {
        match self {
            Data::I16(v) => v.iter().map(|&x| x as f32 * scale + offset).collect(),
            Data::U16(v) => v.iter().map(|&x| x as f32 * scale + offset).collect(),
            Data::F32(v) => v.iter().map(|&x| x * scale + offset).collect(),
        }
    }
}

/// A damage to the samples themselves (the file stays well formed).
#[derive(Clone, Copy, Debug)]
enum Values {
    /// Every sample the void value (NaN for floats).
    AllVoid,
    /// One sample at the type's largest value.
    SpikeMax,
    /// One sample at the type's smallest value.
    SpikeMin,
    /// Floats: one +inf, a row of NaN (voids to fill), everything 1e30, one f32::MAX.
    Inf,
    NanRow,
    Huge,
    /// Random samples of the type.
    Noise,
}

const VALUE_DAMAGES: &[Values] = &[
    Values::AllVoid,
    Values::SpikeMax,
    Values::SpikeMin,
    Values::Inf,
    Values::NanRow,
    Values::Huge,
    Values::Noise,
];

fn damage_values(d: &Data, how: Values, void: Option<f64>, w: usize, seed: u64) -> Option<Data> {
    let mut rng = Rng(seed | 1);
    let mid = d.len() / 2 + w / 2;
    Some(match (d.clone(), how) {
        (Data::I16(mut v), _) => {
            match how {
                Values::AllVoid => v.fill(void? as i16),
                Values::SpikeMax => v[mid] = i16::MAX,
                Values::SpikeMin => v[mid] = i16::MIN + 1,
                Values::Noise => v.iter_mut().for_each(|x| *x = rng.next() as i16),
                _ => return None,
            }
            Data::I16(v)
        }
        (Data::U16(mut v), _) => {
            match how {
                Values::AllVoid => v.fill(void? as u16),
                Values::SpikeMax => v[mid] = u16::MAX,
                Values::SpikeMin => v[mid] = 0,
                Values::Noise => v.iter_mut().for_each(|x| *x = rng.next() as u16),
                _ => return None,
            }
            Data::U16(v)
        }
        (Data::F32(mut v), _) => {
            match how {
                Values::AllVoid => v.fill(f32::NAN),
                Values::SpikeMax => v[mid] = f32::MAX,
                Values::SpikeMin => v[mid] = -f32::MAX,
                Values::Inf => v[mid] = f32::INFINITY,
                Values::NanRow => v[mid - mid % w..mid - mid % w + w].fill(f32::NAN),
                Values::Huge => v.fill(1e30),
                Values::Noise => v
                    .iter_mut()
                    .for_each(|x| *x = f32::from_bits(rng.next() as u32)),
            }
            Data::F32(v)
        }
    })
}

/// Byte-level damage to a whole file.
#[derive(Clone, Copy, Debug)]
enum Bytes {
    Empty,
    Half,
    MinusOne,
    PlusOne,
    Header(usize),
    Flip(u64),
    Zeros,
}

const BYTE_DAMAGES: &[Bytes] = &[
    Bytes::Empty,
    Bytes::Half,
    Bytes::MinusOne,
    Bytes::PlusOne,
    Bytes::Header(64),
    Bytes::Flip(1),
    Bytes::Flip(2),
    Bytes::Flip(3),
    Bytes::Zeros,
];

fn damage_bytes(b: &[u8], how: Bytes) -> Vec<u8> {
    match how {
        Bytes::Empty => Vec::new(),
        Bytes::Half => b[..b.len() / 2].to_vec(),
        Bytes::MinusOne => b[..b.len() - 1].to_vec(),
        Bytes::PlusOne => [b, &[0x5a]].concat(),
        Bytes::Header(n) => b[..n.min(b.len())].to_vec(),
        Bytes::Flip(seed) => {
            // Sixteen random bytes replaced, half of them in the first 512 (headers).
            let mut v = b.to_vec();
            let mut rng = Rng(seed * 0x9e37_79b9 + 7);
            for k in 0..16 {
                let span = if k % 2 == 0 {
                    v.len().min(512)
                } else {
                    v.len()
                };
                let i = (rng.next() % span as u64) as usize;
                v[i] = rng.next() as u8;
            }
            v
        }
        Bytes::Zeros => vec![0; b.len()],
    }
}

fn tiff(w: usize, h: usize, v: &[f32], tags: &TiffTags) -> Vec<u8> {
    use std::io::Cursor;
    use tiff::encoder::{colortype, TiffEncoder};
    use tiff::tags::Tag;
    let mut buf = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut buf).unwrap();
    let mut img = enc
        .new_image::<colortype::Gray32Float>(w as u32, h as u32)
        .unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelPixelScaleTag, &tags.scale[..])
        .unwrap();
    e.write_tag(Tag::ModelTiepointTag, &tags.tie[..]).unwrap();
    e.write_tag(Tag::GeoKeyDirectoryTag, &tags.keys[..])
        .unwrap();
    if !tags.doubles.is_empty() {
        e.write_tag(Tag::GeoDoubleParamsTag, &tags.doubles[..])
            .unwrap();
    }
    e.write_tag(Tag::GdalNodata, tags.nodata.as_str()).unwrap();
    img.rows_per_strip(8).unwrap();
    img.write_data(v).unwrap();
    buf.into_inner()
}

#[derive(Clone)]
struct TiffTags {
    scale: Vec<f64>,
    tie: Vec<f64>,
    keys: Vec<u16>,
    doubles: Vec<f64>,
    nodata: String,
}

fn exr(w: usize, h: usize, v: &[f32]) -> Vec<u8> {
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    let channels = SpecificChannels::build()
        .with_channel::<f32>("height")
        .with_pixel_fn(|p: Vec2<usize>| (v[p.y() * w + p.x()],));
    let mut out = std::io::Cursor::new(Vec::new());
    Image::from_channels((w, h), channels)
        .write()
        .to_buffered(&mut out)
        .unwrap();
    out.into_inner()
}

// ------------------------------------------------------------------------------------------
// The shared DEMs, cropped
// ------------------------------------------------------------------------------------------

struct Sources {
    /// LDEM_4 rows 200.., columns 700.. (40°N..24°N, 175°E..191°E): int16 DN, 0.5 m.
    ldem: Data,
    /// MEGDR rows 400.., columns 240.. (10°S..26°S, 60°E..76°E): int16 metres.
    megdr: Data,
    /// Gale rows and columns 300..428: uint16 DN.
    gale: Data,
    /// Shoemaker centre 64×64: float32 metres, with the polar stereographic georeferencing.
    shoe: Data,
    shoe_x0: f64,
    shoe_y0: f64,
    shoe_d: f64,
    /// N19W156.hgt, whole.
    srtm: Vec<u8>,
}

const N: usize = 64;
const GALE_N: usize = 128;

fn crop_i16(bytes: &[u8], stride: usize, r0: usize, c0: usize, big: bool) -> Data {
    let mut v = Vec::with_capacity(N * N);
    for r in r0..r0 + N {
        for c in c0..c0 + N {
            let i = (r * stride + c) * 2;
            let b = [bytes[i], bytes[i + 1]];
            v.push(if big {
                i16::from_be_bytes(b)
            } else {
                i16::from_le_bytes(b)
            });
        }
    }
    Data::I16(v)
}

fn load(data: &Path) -> Sources {
    let ldem = std::fs::read(data.join("lola_ldem4/LDEM_4.IMG")).unwrap();
    let megdr = std::fs::read(data.join("mola_megt90n000cb/megt90n000cb.img")).unwrap();
    let gale = std::fs::read(data.join("mola_gale_128ppd_crop/gale-mola.bin")).unwrap();
    let mut g = Vec::with_capacity(GALE_N * GALE_N);
    for r in 300..300 + GALE_N {
        for c in 300..300 + GALE_N {
            let i = (r * 897 + c) * 2;
            g.push(u16::from_le_bytes([gale[i], gale[i + 1]]));
        }
    }
    let tif = data.join("lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif");
    let dem = penumbra::dem::open(&tif, 0).unwrap();
    let geo = dem.georef().clone();
    assert!(matches!(
        geo.crs,
        Crs::PolarStereographic { north: false, .. }
    ));
    let (r0, c0) = (96, 96);
    let mut s = Vec::with_capacity(N * N);
    for r in r0..r0 + N {
        for c in c0..c0 + N {
            s.push(dem.raw(c, r));
        }
    }
    Sources {
        ldem: crop_i16(&ldem, 1440, 200, 700, false),
        megdr: crop_i16(&megdr, 1440, 400, 240, true),
        gale: Data::U16(g),
        shoe: Data::F32(s),
        shoe_x0: geo.x0 + c0 as f64 * geo.dx,
        shoe_y0: geo.y0 - r0 as f64 * geo.dy,
        shoe_d: geo.dx,
        srtm: std::fs::read(data.join("srtm3/N19W156.hgt")).unwrap(),
    }
}

// ------------------------------------------------------------------------------------------
// Base inputs (valid) in each format
// ------------------------------------------------------------------------------------------

fn ldem_label() -> Label {
    Label {
        top: Keys::default()
            .with("RECORD_TYPE", t("FIXED_LENGTH"))
            .with("RECORD_BYTES", t((N * 2).to_string()))
            .with("^IMAGE", t("\"CROP.IMG\""))
            .with("TARGET_NAME", t("MOON")),
        image: Keys::default()
            .with("LINES", t(N.to_string()))
            .with("LINE_SAMPLES", t(N.to_string()))
            .with("SAMPLE_TYPE", t("LSB_INTEGER"))
            .with("SAMPLE_BITS", t("16"))
            .with("UNIT", t("METER"))
            .with("SCALING_FACTOR", t("0.5"))
            .with("OFFSET", t("1737400."))
            .with("MISSING_CONSTANT", t("-32768")),
        proj: Keys::default()
            .with("MAP_PROJECTION_TYPE", t("\"SIMPLE CYLINDRICAL\""))
            .with("MAP_RESOLUTION", t("4 <pix/deg>"))
            .with("A_AXIS_RADIUS", t("1737.4 <km>"))
            .with("POSITIVE_LONGITUDE_DIRECTION", t("\"EAST\""))
            .with("CENTER_LATITUDE", t("0 <deg>"))
            .with("CENTER_LONGITUDE", t("180 <deg>"))
            .with("MAP_SCALE", t("7580.84 <m/pix>"))
            .with("MAXIMUM_LATITUDE", t("40 <deg>"))
            .with("MINIMUM_LATITUDE", t("24 <deg>"))
            .with("WESTERNMOST_LONGITUDE", t("175 <deg>"))
            .with("EASTERNMOST_LONGITUDE", t("191 <deg>"))
            .with("LINE_PROJECTION_OFFSET", t("-160.5 <pix>"))
            .with("SAMPLE_PROJECTION_OFFSET", t("20.5 <pix>")),
    }
}

/// MEGDR-style: placed by the 1-based projection offsets only, MSB.
fn megdr_label() -> Label {
    Label {
        top: Keys::default()
            .with("RECORD_BYTES", t((N * 2).to_string()))
            .with("^IMAGE", t("\"CROP.IMG\""))
            .with("TARGET_NAME", t("MARS")),
        image: Keys::default()
            .with("LINES", t(N.to_string()))
            .with("LINE_SAMPLES", t(N.to_string()))
            .with("SAMPLE_TYPE", t("MSB_INTEGER"))
            .with("SAMPLE_BITS", t("16"))
            .with("UNIT", t("METER"))
            .with("SCALING_FACTOR", t("1.0"))
            .with("OFFSET", t("0.0")),
        proj: Keys::default()
            .with("MAP_PROJECTION_TYPE", t("\"SIMPLE CYLINDRICAL\""))
            .with("MAP_RESOLUTION", t("4 <PIXEL/DEGREE>"))
            .with("A_AXIS_RADIUS", t("3396.0 <KM>"))
            .with("CENTER_LATITUDE", t("0.0 <DEGREE>"))
            .with("CENTER_LONGITUDE", t("180.0 <DEGREE>"))
            .with("LINE_PROJECTION_OFFSET", t("-39.5"))
            .with("SAMPLE_PROJECTION_OFFSET", t("480.5")),
    }
}

fn shoe_label(s: &Sources) -> Label {
    Label {
        top: Keys::default()
            .with("RECORD_BYTES", t((N * 4).to_string()))
            .with("^IMAGE", t("\"CROP.IMG\""))
            .with("TARGET_NAME", t("MOON")),
        image: Keys::default()
            .with("LINES", t(N.to_string()))
            .with("LINE_SAMPLES", t(N.to_string()))
            .with("SAMPLE_TYPE", t("PC_REAL"))
            .with("SAMPLE_BITS", t("32"))
            .with("SCALING_FACTOR", t("1"))
            .with("MISSING_CONSTANT", t("16#FF7FFFFB#")),
        proj: Keys::default()
            .with("MAP_PROJECTION_TYPE", t("\"POLAR STEREOGRAPHIC\""))
            .with("A_AXIS_RADIUS", t("1737.4 <km>"))
            .with("CENTER_LATITUDE", t("-90 <deg>"))
            .with("CENTER_LONGITUDE", t("0 <deg>"))
            .with("MAP_SCALE", t(format!("{} <m/pix>", s.shoe_d)))
            .with(
                "LINE_PROJECTION_OFFSET",
                t(format!("{}", s.shoe_y0 / s.shoe_d)),
            )
            .with(
                "SAMPLE_PROJECTION_OFFSET",
                t(format!("{}", -s.shoe_x0 / s.shoe_d)),
            ),
    }
}

fn gale_sidecar() -> Keys {
    let d = 1.0 / 128.0;
    let north = -1.8984375 - 300.0 * d;
    let west = 134.296875 + 300.0 * d;
    let span = GALE_N as f64 * d;
    Keys::default()
        .with("size", t(GALE_N.to_string()))
        .with("format", t("\"uint16-le\""))
        .with("elevationMin", t("-4648.0"))
        .with("elevationMax", t("2002.0"))
        .with(
            "bounds",
            Val::Obj(vec![
                ("north".into(), t(north.to_string())),
                ("south".into(), t((north - span).to_string())),
                ("west".into(), t(west.to_string())),
                ("east".into(), t((west + span).to_string())),
            ]),
        )
        .with("target", t("\"mars\""))
}

fn ldem_sidecar() -> Keys {
    Keys::default()
        .with("width", t(N.to_string()))
        .with("height", t(N.to_string()))
        .with("sample_type", t("\"i16\""))
        .with("byte_order", t("\"little\""))
        .with("header_bytes", t("0"))
        .with("scale", t("0.5"))
        .with("offset", t("0"))
        .with("nodata", t("-32768"))
        .with("x0", t("175.125"))
        .with("y0", t("39.875"))
        .with("dx", t("0.25"))
        .with("dy", t("0.25"))
        .with("datum_radius_m", t("1737400"))
        .with("target", t("\"moon\""))
}

fn polar_crs() -> Val {
    Val::Obj(vec![
        ("kind".into(), t("\"polar-stereographic\"")),
        ("north".into(), t("false")),
        ("lon0_deg".into(), t("0")),
        ("lat_ts_deg".into(), t("-90")),
        ("radius_m".into(), t("1737400")),
    ])
}

fn shoe_sidecar(s: &Sources, raw: bool) -> Keys {
    let mut k = Keys::default();
    if raw {
        k = k
            .with("width", t(N.to_string()))
            .with("height", t(N.to_string()))
            .with("format", t("\"float32-le\""));
    }
    k.with("crs", polar_crs())
        .with("x0", t(s.shoe_x0.to_string()))
        .with("y0", t(s.shoe_y0.to_string()))
        .with("dx", t(s.shoe_d.to_string()))
        .with("dy", t(s.shoe_d.to_string()))
        .with("nodata", t("-3.4028226550889045e38"))
        .with("datum_radius_m", t("1737400"))
        .with("target", t("\"moon\""))
}

fn megdr_exr_sidecar() -> Keys {
    Keys::default()
        .with(
            "bounds",
            Val::Obj(vec![
                ("north".into(), t("-10")),
                ("south".into(), t("-26")),
                ("west".into(), t("60")),
                ("east".into(), t("76")),
            ]),
        )
        .with("scale", t("1"))
        .with("offset", t("0"))
        .with("target", t("\"mars\""))
}

fn geo_keys() -> Vec<u16> {
    vec![1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2054, 0, 1, 9102]
}

fn polar_keys() -> Vec<u16> {
    geokeys(LOLA_SOUTH_POLAR_KEYS)
}

/// Indices into the polar GeoDoubleParams, by meaning.
const D_LAT0: usize = 0;
const D_LON0: usize = 1;
const D_K0: usize = 2;
const D_FE: usize = 3;
const D_A: usize = 5;

fn shoe_tags(s: &Sources) -> TiffTags {
    let d = s.shoe_d;
    TiffTags {
        scale: vec![d, d, 0.0],
        tie: vec![0.0, 0.0, 0.0, s.shoe_x0 - d / 2.0, s.shoe_y0 + d / 2.0, 0.0],
        keys: polar_keys(),
        doubles: vec![-90.0, 0.0, 1.0, 0.0, 0.0, 1737400.0, 1737400.0, 0.0],
        nodata: "-3.4028226550889045e38".into(),
    }
}

fn ldem_tags() -> TiffTags {
    TiffTags {
        scale: vec![0.25, 0.25, 0.0],
        tie: vec![0.0, 0.0, 0.0, 175.0, 40.0, 0.0],
        keys: geo_keys(),
        doubles: vec![],
        nodata: "-32768".into(),
    }
}

// ------------------------------------------------------------------------------------------
// Cases
// ------------------------------------------------------------------------------------------

struct Case {
    name: String,
    /// Files written into the case's folder.
    files: Vec<(String, Vec<u8>)>,
    /// The file given to `penumbra tile`.
    input: String,
    /// The file a refusal must name.
    damaged: String,
    /// Extra arguments (`--body`).
    args: Vec<String>,
    expect: Expect,
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Expect {
    /// Exit 0 or 2, both fine.
    Either,
    /// The undamaged base: must tile.
    Tiles,
    /// One of the inputs issue #13 reported as tiled into nonsense: must be refused.
    Refused,
}

/// Values written into label keys.
const LABEL_VALUES: &[&str] = &["1e308", "1e-300", "0", "-1", "1000", "NaN"];
/// Values written into sidecar keys (JSON text, some of it invalid JSON or the wrong type).
const JSON_VALUES: &[&str] = &["1e308", "1e-300", "0", "-1", "1000", "\"abc\"", "1e400"];

fn pds3_files(label: &Label, img: Vec<u8>) -> Vec<(String, Vec<u8>)> {
    vec![
        ("CROP.LBL".into(), label.text().into_bytes()),
        ("CROP.IMG".into(), img),
    ]
}

fn raw_files(sc: &Keys, bin: Vec<u8>) -> Vec<(String, Vec<u8>)> {
    vec![
        ("crop.json".into(), sc.json().into_bytes()),
        ("crop.bin".into(), bin),
    ]
}

fn exr_files(sc: &Keys, file: Vec<u8>) -> Vec<(String, Vec<u8>)> {
    vec![
        ("crop.json".into(), sc.json().into_bytes()),
        ("crop.exr".into(), file),
    ]
}

fn case(
    name: String,
    files: Vec<(String, Vec<u8>)>,
    input: &str,
    damaged: &str,
    args: &[&str],
    expect: Expect,
) -> Case {
    Case {
        name,
        files,
        input: input.into(),
        damaged: damaged.into(),
        args: args.iter().map(|s| s.to_string()).collect(),
        expect,
    }
}

fn build_cases(s: &Sources) -> Vec<Case> {
    let mut cases = Vec::new();
    // Levels per crop: see TILE_ARGS.
    let geo: &[&str] = &["--levels", "4"];
    let polar: &[&str] = &["--levels", "11"];
    let ldem_f32 = s.ldem.to_f32(0.5, 0.0);
    let megdr_f32 = s.megdr.to_f32(1.0, 0.0);
    let shoe_f32 = s.shoe.to_f32(1.0, 0.0);

    // PDS3: three labels × each key × each value (and the key removed); the data damaged.
    let pds3 = [
        (
            "ldem-pds3",
            ldem_label(),
            s.ldem.bytes(false),
            Some(-32768.0),
            geo,
        ),
        ("megdr-pds3", megdr_label(), s.megdr.bytes(true), None, geo),
        ("shoe-pds3", shoe_label(s), s.shoe.bytes(false), None, polar),
    ];
    for (base, label, img, void, args) in pds3 {
        let (label, img) = (&label, &img);
        cases.push(case(
            format!("{base}/intact"),
            pds3_files(label, img.clone()),
            "CROP.LBL",
            "CROP.LBL",
            args,
            Expect::Tiles,
        ));
        for key in label.keys() {
            if matches!(
                key.as_str(),
                "MAP_PROJECTION_TYPE" | "POSITIVE_LONGITUDE_DIRECTION" | "UNIT"
            ) {
                continue;
            }
            for v in LABEL_VALUES.iter().map(|v| Some(*v)).chain([None]) {
                let mut l = label.clone();
                l.set(&key, v);
                cases.push(case(
                    format!("{base}/{key}={}", v.unwrap_or("(removed)")),
                    pds3_files(&l, img.clone()),
                    "CROP.LBL",
                    "CROP.LBL",
                    args,
                    Expect::Either,
                ));
            }
        }
        for b in BYTE_DAMAGES {
            cases.push(case(
                format!("{base}/IMG {b:?}"),
                pds3_files(label, damage_bytes(img, *b)),
                "CROP.LBL",
                "CROP.IMG",
                args,
                Expect::Either,
            ));
        }
        let data = match base {
            "ldem-pds3" => &s.ldem,
            "megdr-pds3" => &s.megdr,
            _ => &s.shoe,
        };
        for (i, how) in VALUE_DAMAGES.iter().enumerate() {
            let void = match data {
                Data::F32(_) => Some(f64::NAN),
                _ => void,
            };
            if let Some(d) = damage_values(data, *how, void, N, i as u64) {
                cases.push(case(
                    format!("{base}/samples {how:?}"),
                    pds3_files(label, d.bytes(base == "megdr-pds3")),
                    "CROP.LBL",
                    "CROP.IMG",
                    args,
                    Expect::Either,
                ));
            }
        }
        // The label damaged as a file.
        for b in [
            Bytes::Half,
            Bytes::Header(40),
            Bytes::Flip(4),
            Bytes::Flip(5),
        ] {
            let files = vec![
                (
                    "CROP.LBL".to_string(),
                    damage_bytes(label.text().as_bytes(), b),
                ),
                ("CROP.IMG".to_string(), img.clone()),
            ];
            cases.push(case(
                format!("{base}/LBL {b:?}"),
                files,
                "CROP.LBL",
                "CROP.LBL",
                args,
                Expect::Either,
            ));
        }
    }

    // Issue #13's reports, as they were given.
    let issue = |name: &str, key: &str, v: &str| {
        let mut l = ldem_label();
        l.set(key, Some(v));
        case(
            format!("issue/{name}"),
            pds3_files(&l, s.ldem.bytes(false)),
            "CROP.LBL",
            "CROP.LBL",
            geo,
            Expect::Refused,
        )
    };
    cases.push(issue("scaling 1e308", "SCALING_FACTOR", "1e308"));
    cases.push(issue("resolution 1e-300", "MAP_RESOLUTION", "1e-300"));
    cases.push(issue("max latitude 1000", "MAXIMUM_LATITUDE", "1000"));
    cases.push(issue("negative datum", "OFFSET", "-1737400"));
    for (name, key, v) in [
        ("sidecar datum 1e300", "datum_radius_m", "1e300"),
        ("sidecar dx 1e300", "dx", "1e300"),
        ("sidecar negative datum", "datum_radius_m", "-1737400"),
        ("raster 1e-12 deg tall", "dy", "1e-14"),
    ] {
        let mut sc = ldem_sidecar();
        sc.set(key, Some(v));
        cases.push(case(
            format!("issue/{name}"),
            raw_files(&sc, s.ldem.bytes(false)),
            "crop.bin",
            "crop.json",
            geo,
            Expect::Refused,
        ));
    }

    // Raw + sidecar: three sidecars × each key × each JSON value; the data damaged.
    let raws = [
        (
            "gale-raw",
            gale_sidecar(),
            &s.gale,
            s.gale.bytes(false),
            GALE_N,
            geo,
        ),
        (
            "ldem-raw",
            ldem_sidecar(),
            &s.ldem,
            s.ldem.bytes(false),
            N,
            geo,
        ),
        (
            "shoe-raw",
            shoe_sidecar(s, true),
            &s.shoe,
            s.shoe.bytes(false),
            N,
            polar,
        ),
    ];
    for (base, sc, data, bin, w, args) in raws {
        let (sc, bin, w) = (&sc, &bin, &w);
        cases.push(case(
            format!("{base}/intact"),
            raw_files(sc, bin.clone()),
            "crop.bin",
            "crop.json",
            args,
            Expect::Tiles,
        ));
        let mut keys: Vec<String> = Vec::new();
        for (k, v) in &sc.0 {
            match v {
                Val::Text(_) => keys.push(k.clone()),
                Val::Obj(o) => keys.extend(o.iter().map(|(i, _)| format!("{k}.{i}"))),
            }
        }
        for key in keys {
            if key == "target" || key == "crs.kind" {
                continue;
            }
            for v in JSON_VALUES.iter().map(|v| Some(*v)).chain([None]) {
                let mut d = sc.clone();
                d.set(&key, v);
                cases.push(case(
                    format!("{base}/{key}={}", v.unwrap_or("(removed)")),
                    raw_files(&d, bin.clone()),
                    "crop.bin",
                    "crop.json",
                    args,
                    Expect::Either,
                ));
            }
        }
        for b in BYTE_DAMAGES {
            cases.push(case(
                format!("{base}/bin {b:?}"),
                raw_files(sc, damage_bytes(bin, *b)),
                "crop.bin",
                "crop.bin",
                args,
                Expect::Either,
            ));
        }
        for (i, how) in VALUE_DAMAGES.iter().enumerate() {
            let void = match base {
                "ldem-raw" => Some(-32768.0),
                _ => Some(f64::NAN),
            };
            if let Some(d) = damage_values(data, *how, void, *w, 100 + i as u64) {
                cases.push(case(
                    format!("{base}/samples {how:?}"),
                    raw_files(sc, d.bytes(false)),
                    "crop.bin",
                    "crop.bin",
                    args,
                    Expect::Either,
                ));
            }
        }
        // The sidecar damaged as a file.
        for b in [Bytes::Half, Bytes::Empty, Bytes::Flip(6)] {
            let files = vec![
                (
                    "crop.json".to_string(),
                    damage_bytes(sc.json().as_bytes(), b),
                ),
                ("crop.bin".to_string(), bin.clone()),
            ];
            cases.push(case(
                format!("{base}/json {b:?}"),
                files,
                "crop.bin",
                "crop.json",
                args,
                Expect::Either,
            ));
        }
    }

    // SRTM: the whole N19W156 tile; bytes, samples and the name damaged.
    let hgt = |name: &str, bytes: Vec<u8>, expect: Expect| {
        case(
            format!("srtm/{name}"),
            vec![(name.to_string(), bytes)],
            name,
            name,
            &["--levels", "6"],
            expect,
        )
    };
    cases.push(hgt("N19W156.hgt", s.srtm.clone(), Expect::Tiles));
    for name in ["N95W156.hgt", "X19W156.hgt", "N19W181.hgt", "n19w156x.hgt"] {
        cases.push(hgt(name, s.srtm.clone(), Expect::Either));
    }
    for b in [
        Bytes::Empty,
        Bytes::Half,
        Bytes::MinusOne,
        Bytes::PlusOne,
        Bytes::Flip(7),
        Bytes::Zeros,
    ] {
        let mut c = hgt("N19W156.hgt", damage_bytes(&s.srtm, b), Expect::Either);
        c.name = format!("srtm/hgt {b:?}");
        cases.push(c);
    }
    let srtm_data = Data::I16(
        s.srtm
            .chunks_exact(2)
            .map(|b| i16::from_be_bytes([b[0], b[1]]))
            .collect(),
    );
    for (i, how) in VALUE_DAMAGES.iter().enumerate() {
        if let Some(d) = damage_values(&srtm_data, *how, Some(-32768.0), 1201, 200 + i as u64) {
            let mut c = hgt("N19W156.hgt", d.bytes(true), Expect::Either);
            c.name = format!("srtm/samples {how:?}");
            cases.push(c);
        }
    }

    // GeoTIFF: Shoemaker (polar) and LDEM (geographic) crops; tags, bytes and samples damaged.
    let tifs = [
        (
            "shoe-tif",
            shoe_tags(s),
            &shoe_f32,
            &["--body", "moon", "--levels", "11"][..],
        ),
        (
            "ldem-tif",
            ldem_tags(),
            &ldem_f32,
            &["--body", "moon", "--levels", "4"][..],
        ),
    ];
    for (base, tags, v, args) in tifs {
        let tags = &tags;
        let file = tiff(N, N, v, tags);
        cases.push(case(
            format!("{base}/intact"),
            vec![("crop.tif".into(), file.clone())],
            "crop.tif",
            "crop.tif",
            args,
            Expect::Tiles,
        ));
        let mut tag_damages: Vec<(String, TiffTags)> = Vec::new();
        for x in [0.0, -5.0, 1e300, 1e-300, f64::NAN, f64::INFINITY] {
            for axis in [0, 1] {
                let mut d = tags.clone();
                d.scale[axis] = x;
                tag_damages.push((format!("pixel scale[{axis}]={x:e}"), d));
            }
        }
        for x in [1e308, f64::NAN, -1e12, 1000.0, -1000.0] {
            for axis in [3, 4] {
                let mut d = tags.clone();
                d.tie[axis] = x;
                tag_damages.push((format!("tiepoint[{axis}]={x:e}"), d));
            }
        }
        if !tags.doubles.is_empty() {
            for (i, what) in [
                (D_A, "semi-major"),
                (D_LAT0, "origin latitude"),
                (D_LON0, "lon0"),
                (D_K0, "k0"),
                (D_FE, "false easting"),
            ] {
                for x in [0.0, -1737400.0, 1e300, f64::NAN, 1.7374, 45.0, 1000.0] {
                    let mut d = tags.clone();
                    d.doubles[i] = x;
                    tag_damages.push((format!("{what}={x:e}"), d));
                }
            }
        }
        for n in ["abc", "1e400", "inf", ""] {
            let mut d = tags.clone();
            d.nodata = n.into();
            tag_damages.push((format!("nodata={n:?}"), d));
        }
        for (name, d) in tag_damages {
            cases.push(case(
                format!("{base}/{name}"),
                vec![("crop.tif".into(), tiff(N, N, v, &d))],
                "crop.tif",
                "crop.tif",
                args,
                Expect::Either,
            ));
        }
        for b in BYTE_DAMAGES {
            cases.push(case(
                format!("{base}/bytes {b:?}"),
                vec![("crop.tif".into(), damage_bytes(&file, *b))],
                "crop.tif",
                "crop.tif",
                args,
                Expect::Either,
            ));
        }
        for (i, how) in VALUE_DAMAGES.iter().enumerate() {
            if let Some(Data::F32(d)) =
                damage_values(&Data::F32(v.to_vec()), *how, None, N, 300 + i as u64)
            {
                cases.push(case(
                    format!("{base}/samples {how:?}"),
                    vec![("crop.tif".into(), tiff(N, N, &d, tags))],
                    "crop.tif",
                    "crop.tif",
                    args,
                    Expect::Either,
                ));
            }
        }
    }

    // EXR + sidecar: MEGDR (geographic) and Shoemaker (polar); sidecar, bytes, samples.
    let exrs = [
        ("megdr-exr", megdr_exr_sidecar(), &megdr_f32, geo),
        ("shoe-exr", shoe_sidecar(s, false), &shoe_f32, polar),
    ];
    for (base, sc, v, args) in exrs {
        let sc = &sc;
        let file = exr(N, N, v);
        cases.push(case(
            format!("{base}/intact"),
            exr_files(sc, file.clone()),
            "crop.exr",
            "crop.json",
            args,
            Expect::Tiles,
        ));
        for key in [
            "scale",
            "offset",
            "datum_radius_m",
            "bounds.north",
            "dx",
            "crs.radius_m",
        ] {
            let present =
                sc.0.iter()
                    .any(|(k, _)| key.split('.').next() == Some(k.as_str()));
            if !present {
                continue;
            }
            for val in ["1e308", "0", "-1", "1e-300", "\"abc\""] {
                let mut d = sc.clone();
                d.set(key, Some(val));
                cases.push(case(
                    format!("{base}/{key}={val}"),
                    exr_files(&d, file.clone()),
                    "crop.exr",
                    "crop.json",
                    args,
                    Expect::Either,
                ));
            }
        }
        for b in [
            Bytes::Empty,
            Bytes::Half,
            Bytes::MinusOne,
            Bytes::Header(64),
            Bytes::Flip(8),
            Bytes::Flip(9),
            Bytes::Flip(10),
        ] {
            cases.push(case(
                format!("{base}/bytes {b:?}"),
                exr_files(sc, damage_bytes(&file, b)),
                "crop.exr",
                "crop.exr",
                args,
                Expect::Either,
            ));
        }
        for (i, how) in VALUE_DAMAGES.iter().enumerate() {
            if let Some(Data::F32(d)) =
                damage_values(&Data::F32(v.to_vec()), *how, None, N, 400 + i as u64)
            {
                cases.push(case(
                    format!("{base}/samples {how:?}"),
                    exr_files(sc, exr(N, N, &d)),
                    "crop.exr",
                    "crop.exr",
                    args,
                    Expect::Either,
                ));
            }
        }
    }
    cases
}

// ------------------------------------------------------------------------------------------
// Running
// ------------------------------------------------------------------------------------------

/// blake3 of every file below `dir`, by relative path.
fn hashes(dir: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(dir).unwrap().display().to_string();
            if rel == ".penumbra/lock" {
                // Holds the pid of the last writer that took the lock: not tileset content.
                continue;
            }
            if p.is_dir() {
                stack.push(p);
            } else {
                let h = blake3::hash(&std::fs::read(&p).unwrap())
                    .to_hex()
                    .to_string();
                out.insert(rel, h);
            }
        }
    }
    out
}

/// Run `cmd` with stdout/stderr to files in `dir`; `None` when it ran past [`RUN_LIMIT`]
/// (it is killed).
fn run_limited(mut cmd: Command, dir: &Path) -> Option<(std::process::ExitStatus, String)> {
    let err_path = dir.join("stderr.txt");
    cmd.stdout(Stdio::from(
        std::fs::File::create(dir.join("stdout.txt")).unwrap(),
    ))
    .stderr(Stdio::from(std::fs::File::create(&err_path).unwrap()));
    let mut child = cmd.spawn().unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > RUN_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let err = String::from_utf8_lossy(&std::fs::read(&err_path).unwrap()).into_owned();
    Some((status, err))
}

#[derive(Default)]
struct Tally {
    ok: usize,
    refused: usize,
    failures: Vec<String>,
    /// Wall time per case.
    times: Vec<(Duration, String)>,
}

fn run_case(
    c: &Case,
    dir: &Path,
    base: &Path,
    base_hashes: &BTreeMap<String, String>,
) -> Result<bool, String> {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("case.txt"), &c.name).unwrap();
    for (name, bytes) in &c.files {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
    let out = dir.join("out");
    copy_tree(base, &out);
    let mut cmd = penumbra_bin();
    cmd.args(TILE_ARGS)
        .arg(dir.join(&c.input))
        .arg("--out")
        .arg(&out)
        .args(&c.args);
    let Some((status, err)) = run_limited(cmd, dir) else {
        return Err(format!("ran past {RUN_LIMIT:?}: killed"));
    };
    if err.contains("panicked") {
        return Err(format!("panicked: {err}"));
    }
    match status.code() {
        Some(0) => {
            if c.expect == Expect::Refused {
                return Err("tiled, but issue #13 reported it as nonsense".into());
            }
            let mut info = penumbra_bin();
            info.args(["info", "--json"]).arg(&out);
            let Some((st, ierr)) = run_limited(info, dir) else {
                return Err("info ran past the limit".into());
            };
            if !st.success() {
                return Err(format!("tiled, but `penumbra info` failed: {ierr}"));
            }
            let json: serde_json::Value =
                serde_json::from_slice(&std::fs::read(dir.join("stdout.txt")).unwrap())
                    .map_err(|e| format!("info --json is not JSON: {e}"))?;
            let ts = Tileset::load(&out).map_err(|e| format!("manifest: {e}"))?;
            let r = ts.body.radius_m;
            let h = ts.products.height.as_ref().ok_or("no height product")?;
            if !(h.min_m.is_finite()
                && h.max_m.is_finite()
                && h.min_m.abs() <= r
                && h.max_m.abs() <= r)
            {
                return Err(format!(
                    "tiled heights {}..{} m on a {r} m body",
                    h.min_m, h.max_m
                ));
            }
            if ts.coverage.iter().map(|c| c.tiles).sum::<u64>() == 0 || json["coverage"].is_null() {
                return Err("tileset covers nothing".into());
            }
            let staging = out.join(penumbra::tileset::STATE_DIR).join("staging");
            if std::fs::read_dir(&staging).is_ok_and(|mut d| d.next().is_some()) {
                return Err("a staged run was left".into());
            }
            Ok(true)
        }
        Some(2) => {
            if c.expect == Expect::Tiles {
                return Err(format!("the undamaged input was refused: {err}"));
            }
            if !err.contains(&c.damaged) {
                return Err(format!("message does not name {}: {err}", c.damaged));
            }
            if hashes(&out) != *base_hashes {
                return Err(format!(
                    "refused ({}) but the old tileset changed",
                    err.trim()
                ));
            }
            Ok(false)
        }
        other => Err(format!("exit {other:?} (status {status}): {err}")),
    }
}

#[test]
fn damaged_inputs_tile_or_exit_2_and_never_touch_the_old_tileset() {
    let Some(data) = shared_data() else { return };
    let t0 = Instant::now();
    let src = load(&data);
    let cases = build_cases(&src);
    assert!(cases.len() >= 300, "only {} cases", cases.len());
    // PENUMBRA_CORPUS_ONLY=text runs only the cases whose name contains it (for debugging).
    let only = std::env::var("PENUMBRA_CORPUS_ONLY").unwrap_or_default();
    let cases: Vec<Case> = cases
        .into_iter()
        .filter(|c| c.name.contains(&only))
        .collect();
    let tmp = tempfile::tempdir().unwrap();

    // The pre-existing tileset: the intact LDEM crop.
    let base = tmp.path().join("base");
    let seed = tmp.path().join("seed");
    std::fs::create_dir_all(&seed).unwrap();
    for (name, bytes) in pds3_files(&ldem_label(), src.ldem.bytes(false)) {
        std::fs::write(seed.join(name), bytes).unwrap();
    }
    let o = penumbra_bin()
        .args(TILE_ARGS)
        .args(["--levels", "4"])
        .arg(seed.join("CROP.LBL"))
        .arg("--out")
        .arg(&base)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let base_hashes = hashes(&base);
    assert!(base_hashes.len() > 2, "{base_hashes:?}");

    let next = AtomicUsize::new(0);
    let tally = Mutex::new(Tally::default());
    std::thread::scope(|sc| {
        for _ in 0..POOL {
            sc.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(c) = cases.get(i) else { break };
                let dir = tmp.path().join(format!("case{i:04}"));
                let t1 = Instant::now();
                let r = run_case(c, &dir, &base, &base_hashes);
                let mut t = tally.lock().unwrap();
                t.times.push((t1.elapsed(), c.name.clone()));
                match r {
                    Ok(true) => t.ok += 1,
                    Ok(false) => t.refused += 1,
                    Err(e) => t
                        .failures
                        .push(format!("{} [{}]: {e}", c.name, dir.display())),
                }
                drop(t);
                if std::env::var_os("PENUMBRA_KEEP_CORPUS").is_none() {
                    let _ = std::fs::remove_dir_all(&dir);
                }
            });
        }
    });
    let t = tally.into_inner().unwrap();
    eprintln!(
        "corpus: {} cases, {} tiled (exit 0), {} refused (exit 2), {} failed, in {:.1} s",
        cases.len(),
        t.ok,
        t.refused,
        t.failures.len(),
        t0.elapsed().as_secs_f64()
    );
    let mut times = t.times.clone();
    times.sort();
    for (d, name) in times.iter().rev().take(5) {
        eprintln!("slowest: {name} {:.2} s", d.as_secs_f64());
    }
    if std::env::var_os("PENUMBRA_KEEP_CORPUS").is_some() {
        let _ = tmp.keep();
    }
    assert!(
        t.failures.is_empty(),
        "{} of {} cases failed:\n{}",
        t.failures.len(),
        cases.len(),
        t.failures.join("\n")
    );
}
