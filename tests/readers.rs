//! DEM readers: synthetic files written to temp folders (good, damaged, truncated, absurd, not a
//! DEM at all) and the real products in ../shared/data when that folder is present.

use std::path::Path;

use penumbra::dem::{self, Crs, Dem, Resampling, DEFAULT_MAX_FILL_PX};
use penumbra::Error;

use crate::util::shared_data;

fn open(p: &Path) -> penumbra::Result<Dem> {
    dem::open(p, DEFAULT_MAX_FILL_PX)
}

#[derive(Debug, PartialEq)]
enum Kind {
    Invalid,
    Unsupported,
}

/// Open `p`, expect an error of `kind` whose message contains every one of `words`.
#[track_caller]
fn expect_err(p: &Path, kind: Kind, words: &[&str]) -> String {
    let e = match open(p) {
        Ok(d) => panic!("{} opened ({}) but should fail", p.display(), d.format()),
        Err(e) => e,
    };
    let msg = e.to_string();
    let got = match e {
        Error::Invalid { .. } => Kind::Invalid,
        Error::Unsupported { .. } => Kind::Unsupported,
        other => panic!("expected {kind:?}, got {other:?}"),
    };
    assert_eq!(got, kind, "{msg}");
    for w in words {
        assert!(msg.contains(w), "message lacks '{w}': {msg}");
    }
    msg
}

fn write(p: impl AsRef<Path>, bytes: impl AsRef<[u8]>) {
    std::fs::write(p, bytes).unwrap();
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

/// Minimum and maximum measured heights with their (lat, lon).
fn extremes(d: &Dem) -> ((f32, f64, f64), (f32, f64, f64)) {
    let (mut lo, mut hi) = ((f32::INFINITY, 0, 0), (f32::NEG_INFINITY, 0, 0));
    for r in 0..d.height() {
        for c in 0..d.width() {
            let v = d.raw(c, r);
            if v < lo.0 {
                lo = (v, c, r);
            }
            if v > hi.0 {
                hi = (v, c, r);
            }
        }
    }
    let (la, lo_) = d.to_latlon(lo.1 as f64, lo.2 as f64);
    let (ha, ho) = d.to_latlon(hi.1 as f64, hi.2 as f64);
    ((lo.0, la, lo_), (hi.0, ha, ho))
}

/// A PNG file's first bytes (signature, IHDR): a non-DEM input.
const PNG: &[u8] =
    b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\0\x10\0\0\0\x10\x08\x00\x00\x00\x00\x3a\x7e\x9b\x55";

// ------------------------------------------------------------------------------------------
// PDS3
// ------------------------------------------------------------------------------------------

const W: usize = 16;
const H: usize = 8;

fn pds_dn(c: usize, r: usize) -> i16 {
    (c as i16) * 10 - (r as i16) * 100
}

fn pds_img_le() -> Vec<u8> {
    let mut v = Vec::new();
    for r in 0..H {
        for c in 0..W {
            let dn = if (c, r) == (3, 3) {
                -32768
            } else {
                pds_dn(c, r)
            };
            v.extend(dn.to_le_bytes());
        }
    }
    v
}

fn pds_label(pointer: &str, extra_image: &str, projection: &str) -> String {
    format!(
        "PDS_VERSION_ID = \"PDS3\"\r\n\
         /* a synthetic LOLA-like product */\r\n\
         RECORD_TYPE = FIXED_LENGTH\r\n\
         RECORD_BYTES = {rb}\r\n\
         FILE_RECORDS = {H}\r\n\
         ^IMAGE = {pointer}\r\n\
         TARGET_NAME = MOON\r\n\
         DESCRIPTION = \"Two lines of text\r\n   with = signs and 'quotes' /* not a comment */\"\r\n\
         OBJECT = IMAGE\r\n\
           LINES = {H}\r\n\
           LINE_SAMPLES = {W}\r\n\
           {extra_image}\r\n\
           UNIT = METER\r\n\
           SCALING_FACTOR = 0.5\r\n\
           OFFSET = 1737400.\r\n\
           MISSING_CONSTANT = -32768\r\n\
         END_OBJECT = IMAGE\r\n\
         OBJECT = IMAGE_MAP_PROJECTION\r\n\
         {projection}\r\n\
         END_OBJECT = IMAGE_MAP_PROJECTION\r\n\
         END\r\n",
        rb = W * 2
    )
}

const INT16_LSB: &str = "SAMPLE_TYPE = LSB_INTEGER\r\n SAMPLE_BITS = 16";

/// Global 16×8 grid: 22.5°/px, edges given (LOLA-style 0-based offsets, which must be ignored).
const PROJ_EDGES: &str = " MAP_PROJECTION_TYPE = \"SIMPLE CYLINDRICAL\"\r\n\
    MAP_RESOLUTION = 0.0444444444444444444 <pix/deg>\r\n\
    A_AXIS_RADIUS = 1737.4 <km>\r\n\
    POSITIVE_LONGITUDE_DIRECTION = \"EAST\"\r\n\
    CENTER_LATITUDE = 0 <deg>\r\n CENTER_LONGITUDE = 180 <deg>\r\n\
    MAXIMUM_LATITUDE = 90 <deg>\r\n MINIMUM_LATITUDE = -90 <deg>\r\n\
    WESTERNMOST_LONGITUDE = 0 <deg>\r\n EASTERNMOST_LONGITUDE = 360 <deg>\r\n\
    LINE_PROJECTION_OFFSET = 3.5 <pix>\r\n SAMPLE_PROJECTION_OFFSET = 7.5 <pix>";

/// The same grid placed by the PDS-standard 1-based offsets only (MEGDR-style).
const PROJ_OFFSETS: &str = " MAP_PROJECTION_TYPE = \"SIMPLE CYLINDRICAL\"\r\n\
    MAP_RESOLUTION = 0.0444444444444444444 <PIXEL/DEGREE>\r\n\
    A_AXIS_RADIUS = 1737.4 <KM>\r\n\
    CENTER_LATITUDE = 0.0 <DEGREE>\r\n CENTER_LONGITUDE = 180.0 <DEGREE>\r\n\
    LINE_PROJECTION_OFFSET = 4.5\r\n SAMPLE_PROJECTION_OFFSET = 8.5";

fn check_pds_grid(d: &Dem) {
    let g = d.georef();
    assert_eq!(g.crs, Crs::Geographic);
    assert!(close(g.dx, 22.5, 1e-9) && close(g.dy, 22.5, 1e-9), "{g:?}");
    assert!(
        close(g.x0, 11.25, 1e-9) && close(g.y0, 78.75, 1e-9),
        "{g:?}"
    );
    assert_eq!(d.is_global(), (true, true));
}

#[test]
fn pds3_detached_label_lsb_int16() {
    let t = tempfile::tempdir().unwrap();
    // Label names the data in upper case; the file on disk is lower case.
    let lbl = t.path().join("LDEM_T.LBL");
    write(&lbl, pds_label("\"LDEM_T.IMG\"", INT16_LSB, PROJ_EDGES));
    write(t.path().join("ldem_t.img"), pds_img_le());
    let d = open(&lbl).unwrap();
    assert_eq!((d.width(), d.height()), (W, H));
    check_pds_grid(&d);
    assert_eq!(d.datum_radius_m(), Some(1_737_400.0));
    assert_eq!(d.target(), Some("moon"));
    assert_eq!(d.sources().len(), 2);
    assert_eq!(d.sources()[0], lbl);
    assert!(d.format().contains("PDS3 LSB int16"), "{}", d.format());
    for (c, r) in [(0, 0), (15, 7), (5, 2)] {
        assert_eq!(d.raw(c, r), pds_dn(c, r) as f32 * 0.5);
    }
    assert!(d.raw(3, 3).is_nan(), "MISSING_CONSTANT is a void");
    assert_eq!(d.void_counts(), (1, 0));
    // Geographic sampling: the centre of pixel (5, 2).
    let (v, _) = d.sample(78.75 - 2.0 * 22.5, 11.25 + 5.0 * 22.5, Resampling::Bilinear);
    assert!(close(v as f64, pds_dn(5, 2) as f64 * 0.5, 1e-3));

    // Opened through the image, the label is found beside it (any case).
    let d2 = open(&t.path().join("ldem_t.img")).unwrap();
    check_pds_grid(&d2);
    assert_eq!(d2.sources()[0], lbl);
}

#[test]
fn pds3_standard_offsets_match_edges() {
    let t = tempfile::tempdir().unwrap();
    let lbl = t.path().join("megt.lbl");
    // MSB variant of the same values, placed by the 1-based offsets only.
    let mut img = Vec::new();
    for r in 0..H {
        for c in 0..W {
            img.extend(pds_dn(c, r).to_be_bytes());
        }
    }
    let label = pds_label(
        "\"MEGT.IMG\"",
        "SAMPLE_TYPE = MSB_INTEGER\r\n SAMPLE_BITS = 16",
        PROJ_OFFSETS,
    )
    .replace("MISSING_CONSTANT = -32768", "")
    .replace("SCALING_FACTOR = 0.5", "")
    .replace("OFFSET = 1737400.", "");
    write(&lbl, label);
    write(t.path().join("megt.img"), &img);
    let d = open(&lbl).unwrap();
    check_pds_grid(&d);
    assert_eq!(d.datum_radius_m(), None);
    assert_eq!(d.raw(7, 5), pds_dn(7, 5) as f32);
    assert!(d.format().contains("MSB int16"), "{}", d.format());
}

#[test]
fn pds3_attached_label_records_and_bytes() {
    let t = tempfile::tempdir().unwrap();
    // Float32 big-endian, attached label padded to 4 records of 64 bytes, void as a bit pattern.
    let rb = W * 4;
    let make = |pointer: &str| {
        let label = pds_label(
            pointer,
            "SAMPLE_TYPE = IEEE_REAL\r\n SAMPLE_BITS = 32",
            PROJ_EDGES,
        )
        .replace(
            &format!("RECORD_BYTES = {}", W * 2),
            &format!("RECORD_BYTES = {rb}"),
        )
        .replace(
            "MISSING_CONSTANT = -32768",
            "MISSING_CONSTANT = 16#FF7FFFFB#",
        )
        .replace("OFFSET = 1737400.", "OFFSET = 10.0");
        let mut bytes = label.into_bytes();
        assert!(bytes.len() <= 20 * rb);
        bytes.resize(20 * rb, b' ');
        for r in 0..H {
            for c in 0..W {
                let v = if (c, r) == (1, 1) {
                    f32::from_bits(0xFF7F_FFFB)
                } else {
                    pds_dn(c, r) as f32 + 0.25
                };
                bytes.extend(v.to_be_bytes());
            }
        }
        bytes
    };
    for (name, pointer) in [
        ("a.img", "21"),
        ("b.img", format!("{} <BYTES>", 20 * rb + 1).as_str()),
    ] {
        let p = t.path().join(name);
        write(&p, make(pointer));
        let d = open(&p).unwrap();
        check_pds_grid(&d);
        assert_eq!(d.sources(), std::slice::from_ref(&p));
        // OFFSET 10 is a height offset (not a radius).
        assert_eq!(d.datum_radius_m(), None);
        assert_eq!(d.raw(4, 6), (pds_dn(4, 6) as f32 + 0.25) * 0.5 + 10.0);
        assert!(d.raw(1, 1).is_nan());
        assert_eq!(d.void_counts(), (1, 0));
    }
}

#[test]
fn pds3_line_prefix_and_polar_stereographic() {
    let t = tempfile::tempdir().unwrap();
    let n = 8usize;
    let proj = " MAP_PROJECTION_TYPE = \"POLAR STEREOGRAPHIC\"\r\n\
        A_AXIS_RADIUS = 1737.4 <KM>\r\n CENTER_LATITUDE = -90.0 <DEG>\r\n\
        CENTER_LONGITUDE = 0.0 <DEG>\r\n MAP_SCALE = 0.02 <KM/PIXEL>\r\n\
        LINE_PROJECTION_OFFSET = 3.5 <PIXEL>\r\n SAMPLE_PROJECTION_OFFSET = 3.5 <PIXEL>";
    let label = format!(
        "PDS_VERSION_ID = PDS3\nRECORD_BYTES = {}\n^IMAGE = (\"POLE.IMG\", 1)\n\
         OBJECT = IMAGE\n LINES = {n}\n LINE_SAMPLES = {n}\n SAMPLE_TYPE = PC_REAL\n\
         SAMPLE_BITS = 32\n LINE_PREFIX_BYTES = 4\n LINE_SUFFIX_BYTES = 2\nEND_OBJECT\n\
         OBJECT = IMAGE_MAP_PROJECTION\n{proj}\nEND_OBJECT = IMAGE_MAP_PROJECTION\nEND\n",
        4 + n * 4 + 2
    );
    let lbl = t.path().join("pole.lbl");
    write(&lbl, label);
    let mut img = Vec::new();
    for r in 0..n {
        img.extend([0xAA; 4]);
        for c in 0..n {
            img.extend(((r * 100 + c) as f32).to_le_bytes());
        }
        img.extend([0xBB; 2]);
    }
    write(t.path().join("POLE.IMG"), &img);
    let d = open(&lbl).unwrap();
    assert_eq!(d.raw(5, 6), 605.0);
    assert_eq!(d.raw(0, 0), 0.0);
    let g = d.georef();
    assert!(matches!(
        g.crs,
        Crs::PolarStereographic { north: false, lat_ts_deg, radius_m, .. }
            if lat_ts_deg == -90.0 && radius_m == 1_737_400.0
    ));
    assert_eq!((g.x0, g.y0, g.dx, g.dy), (-70.0, 70.0, 20.0, 20.0));
    // The pole is at the grid centre.
    let (lat, _) = d.to_latlon(3.5, 3.5);
    assert!(close(lat, -90.0, 1e-9));
    assert!(d.format().contains("polar stereographic"), "{}", d.format());
}

#[test]
fn pds3_damaged_inputs_fail_cleanly() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();
    let good = pds_label("\"X.IMG\"", INT16_LSB, PROJ_EDGES);

    // Truncated data.
    write(dir.join("trunc.lbl"), good.replace("X.IMG", "TRUNC.IMG"));
    write(dir.join("trunc.img"), &pds_img_le()[..100]);
    expect_err(
        &dir.join("trunc.lbl"),
        Kind::Invalid,
        &["truncated", "256 bytes", "file has 100"],
    );

    // Label says more lines than the file holds.
    write(
        dir.join("lines.lbl"),
        good.replace("X.IMG", "LINES.IMG")
            .replace(&format!("LINES = {H}"), "LINES = 9"),
    );
    write(dir.join("lines.img"), pds_img_le());
    expect_err(&dir.join("lines.lbl"), Kind::Invalid, &["truncated"]);

    // Unknown sample type is named.
    write(
        dir.join("vax.lbl"),
        good.replace("X.IMG", "LINES.IMG")
            .replace("LSB_INTEGER", "VAX_REAL"),
    );
    expect_err(&dir.join("vax.lbl"), Kind::Unsupported, &["VAX_REAL"]);

    // SAMPLE_BITS contradicting SAMPLE_TYPE.
    write(
        dir.join("bits.lbl"),
        good.replace("X.IMG", "LINES.IMG")
            .replace("LSB_INTEGER", "PC_REAL"),
    );
    expect_err(
        &dir.join("bits.lbl"),
        Kind::Invalid,
        &["SAMPLE_BITS = 16", "PC_REAL"],
    );

    // Absurd dimensions fail before anything is mapped.
    write(
        dir.join("huge.lbl"),
        good.replace("X.IMG", "LINES.IMG")
            .replace(&format!("LINES = {H}"), "LINES = 4000000000")
            .replace(&format!("LINE_SAMPLES = {W}"), "LINE_SAMPLES = 4000000000"),
    );
    expect_err(
        &dir.join("huge.lbl"),
        Kind::Invalid,
        &["4000000000×4000000000"],
    );

    // Garbage bytes named .LBL; a PNG named .IMG with no label; a text file.
    write(
        dir.join("garbage.lbl"),
        [0u8, 1, 2, 0xff, 0xfe, 7, 13, 10, 0, 0],
    );
    expect_err(
        &dir.join("garbage.lbl"),
        Kind::Invalid,
        &["not a PDS3 label"],
    );
    write(dir.join("picture.img"), PNG);
    expect_err(
        &dir.join("picture.img"),
        Kind::Invalid,
        &["no PDS3 label", "picture.LBL"],
    );
    write(dir.join("notes.lbl"), "Dear diary,\nthe Moon is grey.\n");
    expect_err(&dir.join("notes.lbl"), Kind::Invalid, &["not a PDS3 label"]);

    // Data file absent.
    write(dir.join("lonely.lbl"), good.replace("X.IMG", "NOWHERE.IMG"));
    expect_err(&dir.join("lonely.lbl"), Kind::Invalid, &["NOWHERE.IMG"]);

    // Unterminated string, reported with its line.
    write(
        dir.join("quote.lbl"),
        "PDS_VERSION_ID = PDS3\nA = \"never closed\n",
    );
    expect_err(&dir.join("quote.lbl"), Kind::Invalid, &["line 2"]);

    // West-positive longitudes and unknown projections are not read.
    write(
        dir.join("west.lbl"),
        good.replace("X.IMG", "LINES.IMG")
            .replace("\"EAST\"", "\"WEST\""),
    );
    expect_err(&dir.join("west.lbl"), Kind::Unsupported, &["WEST"]);
    write(
        dir.join("sinu.lbl"),
        good.replace("X.IMG", "LINES.IMG")
            .replace("SIMPLE CYLINDRICAL", "SINUSOIDAL"),
    );
    expect_err(&dir.join("sinu.lbl"), Kind::Unsupported, &["SINUSOIDAL"]);

    // No map projection at all.
    let unprojected = good
        .split("OBJECT = IMAGE_MAP_PROJECTION")
        .next()
        .unwrap()
        .to_string();
    write(
        dir.join("raw.lbl"),
        unprojected.replace("X.IMG", "LINES.IMG"),
    );
    expect_err(
        &dir.join("raw.lbl"),
        Kind::Unsupported,
        &["IMAGE_MAP_PROJECTION"],
    );
}

// ------------------------------------------------------------------------------------------
// SRTM
// ------------------------------------------------------------------------------------------

fn srtm_dn(c: usize, r: usize) -> i16 {
    ((c * 3 + r * 2) % 5000) as i16 - 100
}

#[test]
fn srtm_good_tile() {
    let t = tempfile::tempdir().unwrap();
    let p = t.path().join("S01E036.hgt");
    let n = 1201;
    let mut v = Vec::with_capacity(n * n * 2);
    for r in 0..n {
        for c in 0..n {
            let dn = if r == 600 && (10..13).contains(&c) {
                -32768
            } else {
                srtm_dn(c, r)
            };
            v.extend(dn.to_be_bytes());
        }
    }
    write(&p, &v);
    let d = open(&p).unwrap();
    assert_eq!((d.width(), d.height()), (n, n));
    let g = d.georef();
    assert_eq!((g.x0, g.y0), (36.0, 0.0));
    assert!(close(g.dx, 1.0 / 1200.0, 1e-15));
    assert_eq!(d.to_latlon(1200.0, 1200.0), (-1.0, 37.0));
    assert_eq!(d.raw(7, 9), srtm_dn(7, 9) as f32);
    assert_eq!(d.void_counts(), (3, 0));
    let (v, m) = d.value(11, 600);
    assert!(m && v.is_finite());
    // Exactly on a pixel centre.
    let (s, _) = d.sample(
        0.0 - 9.0 / 1200.0,
        36.0 + 7.0 / 1200.0,
        Resampling::Bilinear,
    );
    assert!(close(s as f64, srtm_dn(7, 9) as f64, 1e-3));
    assert!(d.format().contains("SRTM"));
}

#[test]
fn srtm_damaged_inputs_fail_cleanly() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();
    write(dir.join("N10E010.hgt"), vec![0u8; 1201 * 1200 * 2]);
    expect_err(
        &dir.join("N10E010.hgt"),
        Kind::Invalid,
        &["2882400 bytes", "1201×1201", "3601×3601"],
    );
    write(dir.join("tile.hgt"), vec![0u8; 1201 * 1201 * 2]);
    expect_err(&dir.join("tile.hgt"), Kind::Invalid, &["[NS]dd[EW]ddd"]);
    write(dir.join("N95W010.hgt"), vec![0u8; 1201 * 1201 * 2]);
    expect_err(&dir.join("N95W010.hgt"), Kind::Invalid, &["N19W156"]);
    write(dir.join("N10E011.hgt"), PNG);
    expect_err(&dir.join("N10E011.hgt"), Kind::Invalid, &["bytes"]);
    // All voids: nothing to tile.
    write(dir.join("N10E012.hgt"), [0x80u8, 0x00].repeat(1201 * 1201));
    expect_err(&dir.join("N10E012.hgt"), Kind::Invalid, &["void"]);
}

// ------------------------------------------------------------------------------------------
// GeoTIFF
// ------------------------------------------------------------------------------------------

mod tif {
    use std::io::Cursor;
    use tiff::encoder::{colortype, compression::DeflateLevel, Compression, TiffEncoder};
    use tiff::tags::Tag;

    pub struct Geo {
        pub scale: [f64; 3],
        pub tie: [f64; 6],
        pub keys: Vec<u16>,
        pub doubles: Vec<f64>,
        pub nodata: Option<&'static str>,
    }

    /// GeoKeyDirectory from (key, location, count, value) entries.
    pub use crate::util::geokeys as keys;

    pub fn geographic(x0: f64, y0: f64, d: f64, point: bool) -> Geo {
        Geo {
            scale: [d, d, 0.0],
            tie: [0.0, 0.0, 0.0, x0, y0, 0.0],
            keys: keys(&[
                (1024, 0, 1, 2),
                (1025, 0, 1, if point { 2 } else { 1 }),
                (2054, 0, 1, 9102),
            ]),
            doubles: vec![],
            nodata: Some("-9999"),
        }
    }

    /// The keys of the LOLA Shoemaker product: user-defined south polar stereographic on the
    /// 1737400 m sphere.
    pub fn south_polar(x0: f64, y0: f64, d: f64) -> Geo {
        Geo {
            scale: [d, d, 0.0],
            tie: [0.0, 0.0, 0.0, x0, y0, 0.0],
            keys: keys(crate::util::LOLA_SOUTH_POLAR_KEYS),
            doubles: vec![-90.0, 0.0, 1.0, 0.0, 0.0, 1737400.0, 1737400.0, 0.0],
            nodata: Some("nan"),
        }
    }

    pub enum Data<'a> {
        F32(&'a [f32]),
        F64(&'a [f64]),
        I16(&'a [i16]),
        U16(&'a [u16]),
        Rgb(&'a [u8]),
    }

    pub fn encode(w: u32, h: u32, data: Data, comp: &str, geo: Option<&Geo>) -> Vec<u8> {
        let mut buf = Cursor::new(Vec::new());
        let compression = match comp {
            "lzw" => Compression::Lzw,
            "deflate" => Compression::Deflate(DeflateLevel::Balanced),
            "packbits" => Compression::Packbits,
            _ => Compression::Uncompressed,
        };
        let mut enc = TiffEncoder::new(&mut buf)
            .unwrap()
            .with_compression(compression);
        macro_rules! go {
            ($ct:ty, $d:expr) => {{
                let mut img = enc.new_image::<$ct>(w, h).unwrap();
                if let Some(g) = geo {
                    let e = img.encoder();
                    e.write_tag(Tag::ModelPixelScaleTag, &g.scale[..]).unwrap();
                    e.write_tag(Tag::ModelTiepointTag, &g.tie[..]).unwrap();
                    e.write_tag(Tag::GeoKeyDirectoryTag, &g.keys[..]).unwrap();
                    if !g.doubles.is_empty() {
                        e.write_tag(Tag::GeoDoubleParamsTag, &g.doubles[..])
                            .unwrap();
                    }
                    if let Some(n) = g.nodata {
                        e.write_tag(Tag::GdalNodata, n).unwrap();
                    }
                }
                img.rows_per_strip(3).unwrap();
                img.write_data($d).unwrap();
            }};
        }
        match data {
            Data::F32(d) => go!(colortype::Gray32Float, d),
            Data::F64(d) => go!(colortype::Gray64Float, d),
            Data::I16(d) => go!(colortype::GrayI16, d),
            Data::U16(d) => go!(colortype::Gray16, d),
            Data::Rgb(d) => go!(colortype::RGB8, d),
        }
        buf.into_inner()
    }

    /// A little-endian classic TIFF built by hand: `payload` at byte 8, then the IFD.
    /// Entries are (tag, type, count, value bytes).
    pub fn handmade(payload: &[u8], mut entries: Vec<(u16, u16, u32, Vec<u8>)>) -> Vec<u8> {
        entries.sort_by_key(|e| e.0);
        let mut out = b"II*\0\0\0\0\0".to_vec();
        out.extend(payload);
        let mut fields = Vec::new();
        for (tag, ty, count, data) in &entries {
            if data.len() > 4 {
                if out.len() % 2 == 1 {
                    out.push(0);
                }
                let off = out.len() as u32;
                out.extend(data);
                fields.push((*tag, *ty, *count, off.to_le_bytes().to_vec()));
            } else {
                let mut d = data.clone();
                d.resize(4, 0);
                fields.push((*tag, *ty, *count, d));
            }
        }
        if out.len() % 2 == 1 {
            out.push(0);
        }
        let ifd = out.len() as u32;
        out[4..8].copy_from_slice(&ifd.to_le_bytes());
        out.extend((fields.len() as u16).to_le_bytes());
        for (tag, ty, count, v) in fields {
            out.extend(tag.to_le_bytes());
            out.extend(ty.to_le_bytes());
            out.extend(count.to_le_bytes());
            out.extend(v);
        }
        out.extend(0u32.to_le_bytes());
        out
    }

    pub fn short(tag: u16, v: u16) -> (u16, u16, u32, Vec<u8>) {
        (tag, 3, 1, v.to_le_bytes().to_vec())
    }
    pub fn long(tag: u16, v: u32) -> (u16, u16, u32, Vec<u8>) {
        (tag, 4, 1, v.to_le_bytes().to_vec())
    }
    pub fn longs(tag: u16, v: &[u32]) -> (u16, u16, u32, Vec<u8>) {
        (
            tag,
            4,
            v.len() as u32,
            v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        )
    }
    pub fn shorts(tag: u16, v: &[u16]) -> (u16, u16, u32, Vec<u8>) {
        (
            tag,
            3,
            v.len() as u32,
            v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        )
    }
    pub fn doubles(tag: u16, v: &[f64]) -> (u16, u16, u32, Vec<u8>) {
        (
            tag,
            12,
            v.len() as u32,
            v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        )
    }
}

fn tif_val(c: usize, r: usize) -> f32 {
    (c as f32) * 1.5 - (r as f32) * 7.0 + 100.0
}

#[test]
fn geotiff_float32_geographic_area_and_point() {
    let t = tempfile::tempdir().unwrap();
    let (w, h) = (10usize, 7usize);
    let mut data: Vec<f32> = (0..w * h).map(|i| tif_val(i % w, i / w)).collect();
    data[2 * w + 4] = -9999.0;
    data[3 * w + 4] = f32::NAN;
    for (point, comp) in [(false, "none"), (true, "deflate"), (false, "lzw")] {
        let p = t.path().join(format!("g_{point}_{comp}.tif"));
        let geo = tif::geographic(130.0, -2.0, 0.5, point);
        write(
            &p,
            tif::encode(w as u32, h as u32, tif::Data::F32(&data), comp, Some(&geo)),
        );
        let d = open(&p).unwrap();
        let g = d.georef();
        assert_eq!(g.crs, Crs::Geographic);
        let (x0, y0) = if point {
            (130.0, -2.0)
        } else {
            (130.25, -2.25)
        };
        assert_eq!((g.x0, g.y0, g.dx, g.dy), (x0, y0, 0.5, 0.5), "{comp}");
        assert_eq!(d.raw(9, 6), tif_val(9, 6));
        assert!(d.raw(4, 2).is_nan() && d.raw(4, 3).is_nan());
        assert_eq!(d.void_counts(), (2, 0));
        assert!(d.format().contains("float32"), "{}", d.format());
    }
}

#[test]
fn geotiff_integer_and_f64_variants() {
    let t = tempfile::tempdir().unwrap();
    let (w, h) = (9usize, 8usize);
    let i16s: Vec<i16> = (0..w * h)
        .map(|i| tif_val(i % w, i / w) as i16 * 3)
        .collect();
    let u16s: Vec<u16> = (0..w * h).map(|i| (i * 37) as u16).collect();
    let f64s: Vec<f64> = (0..w * h)
        .map(|i| tif_val(i % w, i / w) as f64 + 0.125)
        .collect();
    let geo = tif::geographic(0.0, 10.0, 1.0, false);
    let cases: Vec<(&str, Vec<u8>, Vec<f32>)> = vec![
        (
            "i16_lzw",
            tif::encode(w as u32, h as u32, tif::Data::I16(&i16s), "lzw", Some(&geo)),
            i16s.iter().map(|&v| v as f32).collect(),
        ),
        (
            "u16_deflate",
            tif::encode(
                w as u32,
                h as u32,
                tif::Data::U16(&u16s),
                "deflate",
                Some(&geo),
            ),
            u16s.iter().map(|&v| v as f32).collect(),
        ),
        (
            "u16_packbits",
            tif::encode(
                w as u32,
                h as u32,
                tif::Data::U16(&u16s),
                "packbits",
                Some(&geo),
            ),
            u16s.iter().map(|&v| v as f32).collect(),
        ),
        (
            "f64",
            tif::encode(
                w as u32,
                h as u32,
                tif::Data::F64(&f64s),
                "none",
                Some(&geo),
            ),
            f64s.iter().map(|&v| v as f32).collect(),
        ),
    ];
    for (name, bytes, expect) in cases {
        let p = t.path().join(format!("{name}.tif"));
        write(&p, bytes);
        let d = open(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
        for r in 0..h {
            for c in 0..w {
                assert_eq!(d.raw(c, r), expect[r * w + c], "{name} ({c}, {r})");
            }
        }
    }
}

#[test]
fn geotiff_tiled_with_partial_tiles() {
    let t = tempfile::tempdir().unwrap();
    let (w, h, tw, th) = (20usize, 18usize, 16usize, 16usize);
    let (across, down) = (w.div_ceil(tw), h.div_ceil(th));
    let mut payload = Vec::new();
    let mut offsets = Vec::new();
    for ty in 0..down {
        for tx in 0..across {
            offsets.push(8 + payload.len() as u32);
            for y in 0..th {
                for x in 0..tw {
                    let (c, r) = (tx * tw + x, ty * th + y);
                    let v = if c < w && r < h {
                        (r * 100 + c) as i16
                    } else {
                        -1
                    };
                    payload.extend(v.to_le_bytes());
                }
            }
        }
    }
    let counts = vec![(tw * th * 2) as u32; offsets.len()];
    let geo = tif::keys(&[(1024, 0, 1, 2), (1025, 0, 1, 2)]);
    let bytes = tif::handmade(
        &payload,
        vec![
            tif::long(256, w as u32),
            tif::long(257, h as u32),
            tif::short(258, 16),
            tif::short(259, 1),
            tif::short(262, 1),
            tif::short(277, 1),
            tif::short(284, 1),
            tif::short(322, tw as u16),
            tif::short(323, th as u16),
            tif::longs(324, &offsets),
            tif::longs(325, &counts),
            tif::short(339, 2),
            tif::doubles(33550, &[0.25, 0.25, 0.0]),
            tif::doubles(33922, &[0.0, 0.0, 0.0, -10.0, 5.0, 0.0]),
            tif::shorts(34735, &geo),
        ],
    );
    let p = t.path().join("tiled.tif");
    write(&p, &bytes);
    let d = open(&p).unwrap();
    assert_eq!((d.width(), d.height()), (w, h));
    for r in 0..h {
        for c in 0..w {
            assert_eq!(d.raw(c, r), (r * 100 + c) as f32, "({c}, {r})");
        }
    }
    let g = d.georef();
    assert_eq!((g.x0, g.y0), (-10.0, 5.0)); // PixelIsPoint
    assert!(d.format().contains("tiled"), "{}", d.format());

    // Tile data cut short: an error, not a panic.
    write(t.path().join("cut.tif"), &bytes[..300]);
    assert!(open(&t.path().join("cut.tif")).is_err());
}

#[test]
fn geotiff_polar_stereographic_like_shoemaker() {
    let t = tempfile::tempdir().unwrap();
    let (w, h) = (16usize, 16usize);
    let data: Vec<f32> = (0..w * h).map(|i| i as f32).collect();
    let p = t.path().join("pole.tif");
    // The grid's centre corner lies on the pole.
    let geo = tif::south_polar(-40.0, 40.0, 5.0);
    write(
        &p,
        tif::encode(w as u32, h as u32, tif::Data::F32(&data), "lzw", Some(&geo)),
    );
    let d = open(&p).unwrap();
    let g = d.georef();
    assert_eq!(
        g.crs,
        Crs::PolarStereographic {
            north: false,
            lon0_deg: 0.0,
            lat_ts_deg: -90.0,
            radius_m: 1737400.0
        }
    );
    assert_eq!((g.x0, g.y0, g.dx, g.dy), (-37.5, 37.5, 5.0, 5.0));
    let (lat, _) = d.to_latlon(7.5, 7.5);
    assert!(close(lat, -90.0, 1e-9));
    assert!(d.format().contains("polar stereographic"), "{}", d.format());
}

#[test]
fn geotiff_damaged_inputs_fail_cleanly() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();
    let (w, h) = (8usize, 6usize);
    let data: Vec<f32> = (0..w * h).map(|i| i as f32).collect();

    // No georeferencing tags.
    write(
        dir.join("plain.tif"),
        tif::encode(w as u32, h as u32, tif::Data::F32(&data), "none", None),
    );
    expect_err(
        &dir.join("plain.tif"),
        Kind::Invalid,
        &["no georeferencing (ModelTiepoint/ModelPixelScale)"],
    );

    // Truncated data.
    let good = tif::encode(
        w as u32,
        h as u32,
        tif::Data::F32(&data),
        "none",
        Some(&tif::geographic(0.0, 0.0, 1.0, false)),
    );
    write(dir.join("short.tif"), &good[..good.len() / 2]);
    assert!(matches!(
        open(&dir.join("short.tif")),
        Err(Error::Invalid { .. } | Error::Unsupported { .. })
    ));

    // Garbage, PNG, text.
    write(
        dir.join("garbage.tif"),
        [0x49u8, 0x49, 0x2a, 0, 0xff, 0xff, 0xff, 0x7f, 1, 2, 3],
    );
    assert!(matches!(
        open(&dir.join("garbage.tif")),
        Err(Error::Invalid { .. })
    ));
    write(dir.join("picture.tif"), PNG);
    expect_err(&dir.join("picture.tif"), Kind::Invalid, &["not a TIFF"]);
    write(dir.join("text.tif"), "hello, I am not an image\n");
    expect_err(&dir.join("text.tif"), Kind::Invalid, &["not a TIFF"]);

    // RGB is not a DEM.
    let rgb = vec![7u8; w * h * 3];
    write(
        dir.join("rgb.tif"),
        tif::encode(
            w as u32,
            h as u32,
            tif::Data::Rgb(&rgb),
            "none",
            Some(&tif::geographic(0.0, 0.0, 1.0, false)),
        ),
    );
    expect_err(&dir.join("rgb.tif"), Kind::Unsupported, &["one band"]);

    // EPSG Earth projection.
    let mut epsg = tif::geographic(0.0, 0.0, 1.0, false);
    epsg.keys = tif::keys(&[(1024, 0, 1, 1), (3072, 0, 1, 3031)]);
    write(
        dir.join("epsg.tif"),
        tif::encode(
            w as u32,
            h as u32,
            tif::Data::F32(&data),
            "none",
            Some(&epsg),
        ),
    );
    expect_err(&dir.join("epsg.tif"), Kind::Unsupported, &["EPSG:3031"]);

    // Unsupported coordinate transformation (transverse Mercator = 1).
    let mut tm = tif::south_polar(0.0, 0.0, 1.0);
    tm.keys = tif::keys(&[(1024, 0, 1, 1), (2057, 34736, 1, 5), (3075, 0, 1, 1)]);
    write(
        dir.join("tm.tif"),
        tif::encode(w as u32, h as u32, tif::Data::F32(&data), "none", Some(&tm)),
    );
    expect_err(
        &dir.join("tm.tif"),
        Kind::Unsupported,
        &["ProjCoordTransGeoKey 1"],
    );

    // Damaged GeoKeyDirectory (claims more keys than it holds).
    let mut broken = tif::geographic(0.0, 0.0, 1.0, false);
    broken.keys = vec![1, 1, 0, 50, 1024, 0, 1, 2];
    write(
        dir.join("keys.tif"),
        tif::encode(
            w as u32,
            h as u32,
            tif::Data::F32(&data),
            "none",
            Some(&broken),
        ),
    );
    expect_err(&dir.join("keys.tif"), Kind::Invalid, &["GeoKeyDirectory"]);

    // Absurd dimensions: 4e9 × 4e9 declared by a tiny file.
    let huge = tif::handmade(
        &[0u8; 16],
        vec![
            tif::long(256, 4_000_000_000),
            tif::long(257, 4_000_000_000),
            tif::short(258, 32),
            tif::short(259, 1),
            tif::short(262, 1),
            tif::long(273, 8),
            tif::short(277, 1),
            tif::long(278, 1),
            tif::long(279, 16),
            tif::short(339, 3),
        ],
    );
    write(dir.join("huge.tif"), &huge);
    expect_err(&dir.join("huge.tif"), Kind::Invalid, &[]);
    // Large but under the hard limit: refused because the file cannot hold it.
    let big = tif::handmade(
        &[0u8; 16],
        vec![
            tif::long(256, 100_000),
            tif::long(257, 100_000),
            tif::short(258, 32),
            tif::short(259, 1),
            tif::short(262, 1),
            tif::long(273, 8),
            tif::short(277, 1),
            tif::long(278, 100_000),
            tif::long(279, 16),
            tif::short(339, 3),
        ],
    );
    write(dir.join("big.tif"), &big);
    expect_err(&dir.join("big.tif"), Kind::Invalid, &["100000×100000"]);
}

// ------------------------------------------------------------------------------------------
// Raw + JSON sidecar
// ------------------------------------------------------------------------------------------

#[test]
fn raw_int16_big_endian_with_penumbra_keys() {
    let t = tempfile::tempdir().unwrap();
    let (w, h) = (12usize, 5usize);
    let mut v = Vec::new();
    for r in 0..h {
        for c in 0..w {
            let dn: i16 = if (c, r) == (2, 2) {
                -999
            } else {
                (r * 100 + c) as i16
            };
            v.extend(dn.to_be_bytes());
        }
    }
    let p = t.path().join("dem.bin");
    write(&p, &v);
    write(
        t.path().join("dem.json"),
        r#"{"width": 12, "height": 5, "sample_type": "i16", "byte_order": "big",
            "scale": 2.0, "offset": -5, "nodata": -999, "crs": "geographic",
            "bounds": {"north": 10, "south": 5, "west": 170, "east": -178},
            "target": "Mercury", "_comment": "ignored"}"#,
    );
    let d = open(&p).unwrap();
    let g = d.georef();
    // East < west crosses the antimeridian: 170 .. 182 over 12 columns.
    assert_eq!((g.x0, g.y0, g.dx, g.dy), (170.5, 9.5, 1.0, 1.0));
    assert_eq!(d.raw(11, 4), (411 * 2 - 5) as f32);
    assert!(d.raw(2, 2).is_nan());
    assert_eq!(d.void_counts(), (1, 0));
    assert_eq!(d.target(), Some("mercury"));
    assert_eq!(d.sources()[0], t.path().join("dem.json"));
    assert!(d.format().contains("raw int16 BE"), "{}", d.format());
    // The sidecar can be opened too.
    let d2 = open(&t.path().join("dem.json")).unwrap();
    assert_eq!(d2.raw(11, 4), d.raw(11, 4));
}

#[test]
fn raw_gale_style_sidecar_and_projected_crs() {
    let t = tempfile::tempdir().unwrap();
    let n = 4usize;
    let q: Vec<u16> = vec![
        0, 65535, 32768, 100, 200, 300, 400, 500, 600, 700, 800, 900, 1000, 1100, 1200, 1300,
    ];
    let p = t.path().join("crop.raw");
    write(
        &p,
        q.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>(),
    );
    // <file>.json wins over <stem>.json.
    write(t.path().join("crop.json"), "{ not json at all");
    write(
        t.path().join("crop.raw.json"),
        r#"{"source": "test", "size": 4, "format": "uint16-le", "elevationMin": -4648.0,
            "elevationMax": 2002.0, "metresPerPixelLat": 463.0,
            "bounds": {"north": -1.0, "south": -2.0, "west": 134.0, "east": 135.0},
            "origin": {"name": "somewhere", "lat": -1.5}}"#,
    );
    let d = open(&p).unwrap();
    assert_eq!(d.raw(0, 0), -4648.0);
    assert_eq!(d.raw(1, 0), 2002.0);
    assert!(close(
        d.raw(2, 0) as f64,
        -4648.0 + 32768.0 * 6650.0 / 65535.0,
        1e-3
    ));
    assert_eq!(d.georef().x0, 134.125);
    let _ = n;

    // x0/y0/dx/dy with a polar stereographic CRS object.
    write(
        t.path().join("crop.raw.json"),
        r#"{"width": 4, "height": 4, "format": "u16-le",
        "crs": {"kind": "polar-stereographic", "north": true, "lon0_deg": 0, "lat_ts_deg": 90, "radius_m": 1737400},
        "x0": -15, "y0": 15, "dx": 10, "dy": 10}"#,
    );
    let d = open(&p).unwrap();
    assert!(matches!(
        d.georef().crs,
        Crs::PolarStereographic { north: true, .. }
    ));
    assert!(close(d.to_latlon(1.5, 1.5).0, 90.0, 1e-9));
}

#[test]
fn raw_damaged_inputs_fail_cleanly() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();
    let sc = r#"{"width": 4, "height": 3, "format": "int16-le", "bounds": {"north": 1, "south": 0, "west": 0, "east": 1}}"#;

    // Missing sidecar: the expected path is named.
    write(dir.join("alone.bin"), [0u8; 24]);
    expect_err(
        &dir.join("alone.bin"),
        Kind::Invalid,
        &["no JSON sidecar", "alone.json"],
    );

    // Bad JSON: serde's message (with its position).
    write(dir.join("bad.bin"), [0u8; 24]);
    write(dir.join("bad.json"), r#"{"width": 4, "height": }"#);
    expect_err(
        &dir.join("bad.bin"),
        Kind::Invalid,
        &["JSON", "line 1 column"],
    );

    // Misspelt key.
    write(dir.join("typo.bin"), [0u8; 24]);
    write(
        dir.join("typo.json"),
        sc.replace("\"bounds\"", "\"nodta\": 0, \"bounds\""),
    );
    expect_err(&dir.join("typo.bin"), Kind::Invalid, &["nodta"]);

    // Truncated and oversized data.
    write(dir.join("short.bin"), [0u8; 20]);
    write(dir.join("short.json"), sc);
    expect_err(
        &dir.join("short.bin"),
        Kind::Invalid,
        &["truncated", "24 bytes", "file has 20"],
    );
    write(dir.join("long.bin"), [0u8; 30]);
    write(dir.join("long.json"), sc);
    expect_err(&dir.join("long.bin"), Kind::Invalid, &["30 bytes", "24"]);

    // Unknown sample type; missing byte order; missing georeferencing.
    write(dir.join("ty.bin"), [0u8; 24]);
    write(dir.join("ty.json"), sc.replace("int16-le", "complex64-le"));
    expect_err(&dir.join("ty.bin"), Kind::Unsupported, &["complex64"]);
    write(dir.join("bo.bin"), [0u8; 24]);
    write(dir.join("bo.json"), sc.replace("int16-le", "int16"));
    expect_err(&dir.join("bo.bin"), Kind::Invalid, &["byte order"]);
    write(dir.join("nogeo.bin"), [0u8; 24]);
    write(
        dir.join("nogeo.json"),
        r#"{"width": 4, "height": 3, "format": "int16-le"}"#,
    );
    expect_err(&dir.join("nogeo.bin"), Kind::Invalid, &["georeferencing"]);
    write(dir.join("flip.bin"), [0u8; 24]);
    write(
        dir.join("flip.json"),
        sc.replace("\"north\": 1", "\"north\": -1"),
    );
    expect_err(&dir.join("flip.bin"), Kind::Invalid, &["bounds"]);

    // Absurd dimensions fail before mapping.
    write(dir.join("huge.bin"), [0u8; 24]);
    write(
        dir.join("huge.json"),
        sc.replace(
            "\"width\": 4, \"height\": 3",
            "\"width\": 4000000000, \"height\": 4000000000",
        ),
    );
    expect_err(
        &dir.join("huge.bin"),
        Kind::Invalid,
        &["4000000000×4000000000"],
    );

    // A PNG with a sidecar that does not fit it; a text file as sidecar.
    write(dir.join("picture.bin"), PNG);
    write(dir.join("picture.json"), sc);
    expect_err(&dir.join("picture.bin"), Kind::Invalid, &["bytes"]);
    write(dir.join("prose.bin"), [0u8; 24]);
    write(dir.join("prose.json"), "Once upon a time");
    expect_err(&dir.join("prose.bin"), Kind::Invalid, &["JSON"]);

    // elevationMin/Max on a signed type.
    write(dir.join("em.bin"), [0u8; 24]);
    write(
        dir.join("em.json"),
        sc.replace(
            "\"bounds\"",
            "\"elevationMin\": 0, \"elevationMax\": 1, \"bounds\"",
        ),
    );
    expect_err(&dir.join("em.bin"), Kind::Invalid, &["unsigned"]);

    // A file with an unknown extension and no sidecar is not guessed at.
    write(dir.join("mystery.xyz"), [0u8; 24]);
    expect_err(
        &dir.join("mystery.xyz"),
        Kind::Unsupported,
        &["unknown DEM format"],
    );
}

/// Keys outside the plausibility limits (docs/formats.md) are refused by name where they are
/// parsed: the reports of issue #13 and their kin, in each reader that has such keys.
#[test]
fn implausible_keys_are_refused_by_name() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();
    write(dir.join("g.img"), pds_img_le());
    let good = pds_label("\"g.img\"", INT16_LSB, PROJ_EDGES);
    write(dir.join("good.lbl"), &good);
    open(&dir.join("good.lbl")).unwrap();
    for (name, from, to, words) in [
        (
            "scale",
            "SCALING_FACTOR = 0.5",
            "SCALING_FACTOR = 1e308",
            &["SCALING_FACTOR = 1e308"][..],
        ),
        (
            "tiny",
            "SCALING_FACTOR = 0.5",
            "SCALING_FACTOR = 1e-300",
            &["SCALING_FACTOR"][..],
        ),
        (
            "res",
            "MAP_RESOLUTION = 0.0444444444444444444",
            "MAP_RESOLUTION = 1e-300",
            &["MAP_RESOLUTION"],
        ),
        (
            "maxlat",
            "MAXIMUM_LATITUDE = 90",
            "MAXIMUM_LATITUDE = 1000",
            &["MAXIMUM_LATITUDE = 1000", "latitude"],
        ),
        (
            "west",
            "WESTERNMOST_LONGITUDE = 0",
            "WESTERNMOST_LONGITUDE = 1e30",
            &["WESTERNMOST_LONGITUDE", "longitude"],
        ),
        (
            "datum",
            "OFFSET = 1737400.",
            "OFFSET = -1737400.",
            &["OFFSET", "radius"],
        ),
        (
            "axis",
            "A_AXIS_RADIUS = 1737.4",
            "A_AXIS_RADIUS = 1e300",
            &["A_AXIS_RADIUS"],
        ),
        (
            "clat",
            "CENTER_LATITUDE = 0",
            "CENTER_LATITUDE = -95",
            &["CENTER_LATITUDE = -95"],
        ),
    ] {
        let text = good.replace(from, to);
        assert_ne!(text, good, "{name}: nothing replaced");
        let p = dir.join(format!("{name}.lbl"));
        write(&p, text);
        expect_err(&p, Kind::Invalid, words);
    }
    // Projection offsets that put rows beyond the pole (no edge keywords).
    let offsets = pds_label("\"g.img\"", INT16_LSB, PROJ_OFFSETS);
    write(
        dir.join("off.lbl"),
        offsets.replace(
            "LINE_PROJECTION_OFFSET = 4.5",
            "LINE_PROJECTION_OFFSET = 40",
        ),
    );
    expect_err(
        &dir.join("off.lbl"),
        Kind::Invalid,
        &["LINE/SAMPLE_PROJECTION_OFFSET", "latitude"],
    );

    // Sidecars.
    write(dir.join("r.bin"), [0u8; 24]);
    let base = r#"{"width": 4, "height": 3, "format": "int16-le", "x0": 10, "y0": 20, "dx": 0.25, "dy": 0.25"#;
    write(dir.join("r.json"), format!("{base}}}"));
    open(&dir.join("r.bin")).unwrap();
    for (extra, words) in [
        (
            r#", "datum_radius_m": 1e300"#,
            &["datum_radius_m = 1e300"][..],
        ),
        (
            r#", "datum_radius_m": -1737400"#,
            &["datum_radius_m", "radius"][..],
        ),
        (r#", "scale": 1e308"#, &["scale = 1e308"][..]),
        (r#", "offset": -1e12"#, &["offset"][..]),
    ] {
        write(dir.join("r.json"), format!("{base}{extra}}}"));
        expect_err(&dir.join("r.bin"), Kind::Invalid, words);
    }
    for (from, to, words) in [
        (r#""dx": 0.25"#, r#""dx": 1e300"#, &["dx = 1e300"][..]),
        (r#""dy": 0.25"#, r#""dy": 1e-14"#, &["dy = 1e-14"][..]),
        (r#""y0": 20"#, r#""y0": 95"#, &["y0 = 95", "latitude"][..]),
        (
            r#""x0": 10"#,
            r#""x0": -400"#,
            &["x0 = -400", "longitude"][..],
        ),
        (
            r#""dy": 0.25"#,
            r#""dy": 60"#,
            &["x0, y0, dx, dy", "row 2"][..],
        ),
    ] {
        write(dir.join("r.json"), format!("{base}}}").replace(from, to));
        expect_err(&dir.join("r.bin"), Kind::Invalid, words);
    }
    let polar = r#"{"width": 4, "height": 3, "format": "int16-le", "crs": {"kind": "polar-stereographic", "north": false, "lon0_deg": 0, "lat_ts_deg": -90, "radius_m": 1737400}, "x0": 0, "y0": 0, "dx": 20, "dy": 20}"#;
    write(dir.join("r.json"), polar);
    open(&dir.join("r.bin")).unwrap();
    for (from, to, word) in [
        ("\"radius_m\": 1737400", "\"radius_m\": 0.5", "radius_m"),
        ("\"lon0_deg\": 0", "\"lon0_deg\": 1000", "lon0_deg"),
        ("\"dx\": 20", "\"dx\": 1e-6", "dx"),
        ("\"x0\": 0", "\"x0\": 1e9", "150°"),
    ] {
        write(dir.join("r.json"), polar.replace(from, to));
        expect_err(&dir.join("r.bin"), Kind::Invalid, &[word]);
    }

    // GeoTIFF: pixel scale, radius and angles of the Shoemaker-like keys.
    let v: Vec<f32> = (0..16).map(|i| i as f32).collect();
    let mut g = tif::south_polar(-20.0, 20.0, 10.0);
    g.doubles[5] = -1737400.0;
    write(
        dir.join("a.tif"),
        tif::encode(4, 4, tif::Data::F32(&v), "none", Some(&g)),
    );
    expect_err(
        &dir.join("a.tif"),
        Kind::Invalid,
        &["GeogSemiMajorAxisGeoKey"],
    );
    let mut g = tif::south_polar(-20.0, 20.0, 10.0);
    g.doubles[1] = 900.0;
    write(
        dir.join("b.tif"),
        tif::encode(4, 4, tif::Data::F32(&v), "none", Some(&g)),
    );
    expect_err(&dir.join("b.tif"), Kind::Invalid, &["3095", "longitude"]);
    let g = tif::geographic(10.0, 20.0, 1e-14, false);
    write(
        dir.join("c.tif"),
        tif::encode(4, 4, tif::Data::F32(&v), "none", Some(&g)),
    );
    expect_err(
        &dir.join("c.tif"),
        Kind::Invalid,
        &["ModelPixelScale", "pixel spacing"],
    );
    let g = tif::geographic(10.0, 2000.0, 1.0, false);
    write(
        dir.join("d.tif"),
        tif::encode(4, 4, tif::Data::F32(&v), "none", Some(&g)),
    );
    expect_err(
        &dir.join("d.tif"),
        Kind::Invalid,
        &["ModelTiepoint", "latitude"],
    );
}

/// What only the body can tell: heights beyond its radius, a datum far from it, pixels below
/// a millimetre or above its circumference.
#[test]
fn implausible_for_the_body() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();
    let sc = |extra: &str| {
        format!(
            r#"{{"width": 4, "height": 3, "format": "float32-le", "x0": 10, "y0": 20, "dx": 0.25, "dy": 0.25{extra}}}"#
        )
    };
    let samples = |spike: f32| -> Vec<u8> {
        (0..12)
            .flat_map(|i| if i == 7 { spike } else { i as f32 }.to_le_bytes())
            .collect()
    };
    write(dir.join("h.bin"), samples(5.0));
    write(dir.join("h.json"), sc(""));
    let d = open(&dir.join("h.bin")).unwrap();
    d.check_plausible(1_737_400.0).unwrap();
    // Small bodies: a 0.25° pixel is 4.4 mm on a 1 m sphere, heights of 11 m are not.
    assert!(d.check_plausible(1.0).is_err());
    // A pixel of 0.25° is more than 1 mm only on spheres above 0.23 m, less than a turn always.
    assert!(d.check_plausible(0.2).is_err());

    // A sample of 3e38 m (an undeclared void value): named by column and row, data file first.
    write(dir.join("h.bin"), samples(3.0e38));
    let d = open(&dir.join("h.bin")).unwrap();
    let e = d.check_plausible(1_737_400.0).unwrap_err().to_string();
    assert!(
        e.contains("h.bin") && e.contains("column 3, row 1") && e.contains("h.json"),
        "{e}"
    );
    // The same as a void is fine.
    write(dir.join("h.json"), sc(r#", "nodata": 3e38"#));
    open(&dir.join("h.bin"))
        .unwrap()
        .check_plausible(1_737_400.0)
        .unwrap();

    // Datum radius more than 50 % off the body, and a shift pushing heights below the centre.
    write(dir.join("h.bin"), samples(5.0));
    write(dir.join("h.json"), sc(r#", "datum_radius_m": 1737400"#));
    let d = open(&dir.join("h.bin")).unwrap();
    d.check_plausible(1_737_400.0).unwrap();
    d.check_plausible(3_396_190.0).unwrap(); // 49 % off: allowed, heights −1.66e6 m
    let e = d.check_plausible(6_371_008.8).unwrap_err().to_string();
    assert!(e.contains("datum radius") && e.contains("h.json"), "{e}");
    assert!(d.check_plausible(1_000_000.0).is_err());
}

// ------------------------------------------------------------------------------------------
// EXR
// ------------------------------------------------------------------------------------------

fn write_exr_f32(p: &Path, name: &str, w: usize, h: usize, f: impl Fn(usize, usize) -> f32 + Sync) {
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    let channels = SpecificChannels::build()
        .with_channel::<f32>(name)
        .with_pixel_fn(|pos: Vec2<usize>| (f(pos.x(), pos.y()),));
    Image::from_channels((w, h), channels)
        .write()
        .to_file(p)
        .unwrap();
}

const EXR_SIDECAR: &str =
    r#"{"crs": "geographic", "x0": 10.5, "y0": 20.5, "dx": 1, "dy": 1, "scale": 2, "offset": 1}"#;

#[test]
fn exr_float_channels() {
    let t = tempfile::tempdir().unwrap();
    let (w, h) = (13usize, 9usize);
    let p = t.path().join("h.exr");
    write_exr_f32(&p, "height", w, h, |c, r| {
        if (c, r) == (5, 5) {
            f32::NAN
        } else {
            (r * 100 + c) as f32
        }
    });
    write(t.path().join("h.exr.json"), EXR_SIDECAR);
    let d = open(&p).unwrap();
    assert_eq!((d.width(), d.height()), (w, h));
    assert_eq!(d.raw(12, 8), (812 * 2 + 1) as f32);
    assert!(d.raw(5, 5).is_nan());
    assert_eq!(d.void_counts(), (1, 0));
    let g = d.georef();
    assert_eq!((g.x0, g.y0, g.dx, g.dy), (10.5, 20.5, 1.0, 1.0));
    assert_eq!(d.sources()[0], t.path().join("h.exr.json"));
    assert!(d.format().contains("OpenEXR"), "{}", d.format());

    // f16 channel named Y, sidecar X.json.
    use exr::prelude::{f16, Image, SpecificChannels, Vec2, WritableImage};
    let p = t.path().join("y16.exr");
    let channels = SpecificChannels::build()
        .with_channel::<f16>("Y")
        .with_pixel_fn(|pos: Vec2<usize>| (f16::from_f32((pos.x() + pos.y()) as f32 * 0.5),));
    Image::from_channels((w, h), channels)
        .write()
        .to_file(&p)
        .unwrap();
    write(
        t.path().join("y16.json"),
        r#"{"bounds": {"north": 9, "south": 0, "west": 0, "east": 13}}"#,
    );
    let d = open(&p).unwrap();
    assert_eq!(d.raw(4, 6), 5.0);
    assert_eq!(d.georef().x0, 0.5);
}

#[test]
fn exr_damaged_inputs_fail_cleanly() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path();
    let (w, h) = (8usize, 8usize);

    // Missing sidecar: named.
    write_exr_f32(&dir.join("alone.exr"), "height", w, h, |c, _| c as f32);
    expect_err(
        &dir.join("alone.exr"),
        Kind::Invalid,
        &["no JSON sidecar", "alone.json"],
    );

    // Two channels, neither a known height name.
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    let p = dir.join("two.exr");
    let channels = SpecificChannels::build()
        .with_channel::<f32>("A")
        .with_channel::<f32>("B")
        .with_pixel_fn(|_: Vec2<usize>| (1.0f32, 2.0f32));
    Image::from_channels((w, h), channels)
        .write()
        .to_file(&p)
        .unwrap();
    write(dir.join("two.json"), EXR_SIDECAR);
    expect_err(&p, Kind::Invalid, &["A, B"]);

    // Truncated file.
    write_exr_f32(&dir.join("full.exr"), "height", 64, 64, |c, r| {
        (c * r) as f32
    });
    let bytes = std::fs::read(dir.join("full.exr")).unwrap();
    write(dir.join("cut.exr"), &bytes[..bytes.len() / 2]);
    write(dir.join("cut.json"), EXR_SIDECAR);
    assert!(matches!(
        open(&dir.join("cut.exr")),
        Err(Error::Invalid { .. } | Error::Unsupported { .. })
    ));

    // Garbage, PNG and text named .exr.
    for (name, bytes) in [
        (
            "g.exr",
            &[0x76u8, 0x2f, 0x31, 0x01, 2, 0, 0, 0, 0xff, 0xff][..],
        ),
        ("p.exr", PNG),
        ("t.exr", b"not an exr"),
    ] {
        let p = dir.join(name);
        write(&p, bytes);
        write(p.with_extension("json"), EXR_SIDECAR);
        assert!(
            matches!(
                open(&p),
                Err(Error::Invalid { .. } | Error::Unsupported { .. })
            ),
            "{name}"
        );
    }

    // Raw encoding keys make no sense for an EXR.
    write_exr_f32(&dir.join("enc.exr"), "height", w, h, |c, _| c as f32);
    write(
        dir.join("enc.json"),
        r#"{"format": "int16-le", "x0": 0, "y0": 0, "dx": 1, "dy": 1}"#,
    );
    expect_err(&dir.join("enc.exr"), Kind::Invalid, &["format"]);

    // Dimensions in the sidecar must match.
    write_exr_f32(&dir.join("dims.exr"), "height", w, h, |c, _| c as f32);
    write(
        dir.join("dims.json"),
        r#"{"width": 9, "height": 8, "x0": 0, "y0": 0, "dx": 1, "dy": 1}"#,
    );
    expect_err(&dir.join("dims.exr"), Kind::Invalid, &["9×8"]);
}

// ------------------------------------------------------------------------------------------
// Real data (../shared/data)
// ------------------------------------------------------------------------------------------

#[test]
fn real_lola_ldem4() {
    let Some(data) = shared_data() else { return };
    for name in ["LDEM_4.LBL", "LDEM_4.IMG"] {
        let d = open(&data.join("lola_ldem4").join(name)).unwrap();
        assert_eq!((d.width(), d.height()), (1440, 720));
        let g = d.georef();
        assert!(
            close(g.x0, 0.125, 1e-12) && close(g.y0, 89.875, 1e-12),
            "{g:?}"
        );
        assert_eq!(d.datum_radius_m(), Some(1_737_400.0));
        assert_eq!(d.target(), Some("moon"));
        assert_eq!(d.is_global(), (true, true));
        let ((lo, lo_lat, lo_lon), (hi, hi_lat, hi_lon)) = extremes(&d);
        eprintln!(
            "LDEM_4 min {lo} m at {lo_lat}, {lo_lon}; max {hi} m at {hi_lat}, {hi_lon}; {}",
            d.format()
        );
        // The label says MINIMUM = -17758, but the one deepest sample in the IMG is -17757.
        assert_eq!(lo, -17757.0 * 0.5);
        assert_eq!(hi, 21008.0 * 0.5);
        assert!(close(lo_lat, -70.4, 0.5) && close(lo_lon, 187.6, 0.5));
        assert!(close(hi_lat, 5.4, 0.5) && close(hi_lon, 201.4, 0.5));
        // The pixels nearest the landmarks hold the extremes.
        for (lat, lon, want) in [(-70.4, 187.6, -8878.5), (5.4, 201.4, 10504.0)] {
            let (c, r) = d.to_pixel(lat, lon);
            let (v, filled) = d.value(c.round() as usize, r.round() as usize);
            assert!(
                !filled && close(v as f64, want, 1e-3),
                "{v} at {lat}, {lon}"
            );
        }
        // Bilinear at the pixel centre reproduces the sample; 0.1 px away the pit is shallower.
        let (v, _) = d.sample(-70.375, 187.625, Resampling::Bilinear);
        assert!(close(v as f64, -8878.5, 1e-3), "{v}");
        let (v, _) = d.sample(-70.4, 187.6, Resampling::Bilinear);
        assert!(close(v as f64, -8878.0, 300.0), "{v}");
    }
}

#[test]
fn real_mola_megdr() {
    let Some(data) = shared_data() else { return };
    let d = open(&data.join("mola_megt90n000cb/megt90n000cb.lbl")).unwrap();
    let g = d.georef();
    assert!(
        close(g.x0, 0.125, 1e-12) && close(g.y0, 89.875, 1e-12),
        "{g:?}"
    );
    assert_eq!(d.datum_radius_m(), None);
    assert_eq!(d.target(), Some("mars"));
    let ((lo, lo_lat, lo_lon), (hi, hi_lat, hi_lon)) = extremes(&d);
    eprintln!(
        "MEGDR min {lo} m at {lo_lat}, {lo_lon}; max {hi} m at {hi_lat}, {hi_lon}; {}",
        d.format()
    );
    // The label's DESCRIPTION gives the data set's extremes, and the grid holds both.
    assert_eq!((lo, hi), (-8068.0, 21134.0));
    // Highest bin: the south rim of the Olympus Mons caldera (summit caldera ≈ 18.4°N 226.0°E;
    // in this grid the caldera floor is the ~18 000 m hollow around 18.1°N 226.7°E).
    assert!(close(hi_lat, 17.375, 1e-9) && close(hi_lon, 226.875, 1e-9));
    assert!(close(hi_lat, 18.4, 1.5) && close(hi_lon, 226.0, 1.5));
    // Deepest bin: the north-west floor of Hellas (32.9°S 62.1°E), 11° from the basin's centre
    // (42.5°S 70.5°E), which is itself deep.
    assert!(close(lo_lat, -32.875, 1e-9) && close(lo_lon, 62.125, 1e-9));
    let (centre, _) = d.sample(-42.5, 70.5, Resampling::Bilinear);
    eprintln!("MEGDR Hellas centre {centre} m");
    assert!(centre < -5_000.0, "{centre}");
    // Opening the image finds the label.
    let d2 = open(&data.join("mola_megt90n000cb/megt90n000cb.img")).unwrap();
    assert_eq!(d2.raw(100, 100), d.raw(100, 100));
}

#[test]
fn real_srtm_hawaii() {
    let Some(data) = shared_data() else { return };
    let d = open(&data.join("srtm3/N19W156.hgt")).unwrap();
    assert_eq!(d.void_counts(), (94, 0));
    let (_, (hi, hi_lat, hi_lon)) = extremes(&d);
    eprintln!("N19W156 max {hi} m at {hi_lat}, {hi_lon}");
    assert_eq!(hi, 4205.0);
    assert!(close(hi_lat, 19.82, 0.01) && close(hi_lon, -155.47, 0.01));
    let d = open(&data.join("srtm3/N44W072.hgt")).unwrap();
    let (_, (hi, hi_lat, hi_lon)) = extremes(&d);
    eprintln!(
        "N44W072 max {hi} m at {hi_lat}, {hi_lon}; voids {:?}",
        d.void_counts()
    );
    // Mount Washington, 44.27°N 71.30°W, 1917 m.
    assert!(close(hi_lat, 44.27, 0.02) && close(hi_lon, -71.30, 0.02));
}

#[test]
fn real_lola_shoemaker_geotiff() {
    let Some(data) = shared_data() else { return };
    let d = open(&data.join("lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif")).unwrap();
    assert_eq!((d.width(), d.height()), (256, 256));
    let (lat, lon) = d.to_latlon(128.0, 128.0);
    let ((lo, ..), (hi, ..)) = extremes(&d);
    eprintln!(
        "Shoemaker centre {lat}, {lon}; heights {lo} .. {hi}; voids {:?}; {}",
        d.void_counts(),
        d.format()
    );
    assert!(close(lat, -87.2, 0.1), "{lat}");
    assert!(matches!(
        d.georef().crs,
        Crs::PolarStereographic { north: false, radius_m, .. } if radius_m == 1_737_400.0
    ));
    assert!(lo > -6_000.0 && hi < 3_000.0 && hi > lo);
}

#[test]
fn real_mola_gale_raw() {
    let Some(data) = shared_data() else { return };
    let d = open(&data.join("mola_gale_128ppd_crop/gale-mola.bin")).unwrap();
    assert_eq!((d.width(), d.height()), (897, 897));
    let (v, m) = d.sample(-4.5895, 137.4417, Resampling::Bilinear);
    let ((lo, ..), (hi, hi_lat, hi_lon)) = extremes(&d);
    eprintln!(
        "Gale Bradbury {v} m; range {lo} .. {hi}; peak at {hi_lat}, {hi_lon}; {}",
        d.format()
    );
    assert_eq!(m, dem::mask::MEASURED);
    assert!((-4510.0..=-4502.0).contains(&v), "{v}");
    assert!(close(lo as f64, -4648.0, 1.0) && close(hi as f64, 2002.0, 1.0));
}
