//! PDS3 image DEMs: a detached label (`X.LBL` beside `X.IMG`) or a label attached to the start
//! of the `.IMG`.
//!
//! # Label syntax read
//!
//! ODL statements `KEY = VALUE`, one per line or spread over several lines; values are bare
//! tokens (numbers, identifiers, dates, radix integers `16#FF7FFFFB#`) optionally followed by a
//! unit `<km>`, quoted strings `"…"` / `'…'` (which may span lines), sequences `(a, b)` and sets
//! `{a, b}`; `/* … */` comments; `OBJECT`/`END_OBJECT` and `GROUP`/`END_GROUP` nesting; `END`.
//! Keys are matched case-insensitively.
//!
//! # Data
//!
//! `^IMAGE` locates the samples: `"FILE.IMG"` (offset 0), `("FILE.IMG", n)` (1-based record
//! `n`, or byte `n` with `<BYTES>`), `n <BYTES>` (1-based byte in the labelled file), `n`
//! (1-based record in the labelled file). File names are matched case-insensitively in the
//! label's folder (labels often say `MEGT90N000CB.IMG` for `megt90n000cb.img`). The IMAGE object
//! gives `LINES`, `LINE_SAMPLES`, `SAMPLE_TYPE` + `SAMPLE_BITS`, `LINE_PREFIX_BYTES` /
//! `LINE_SUFFIX_BYTES`, `SCALING_FACTOR`, `OFFSET`, `UNIT` (metres or kilometres) and the void
//! value (`MISSING_CONSTANT`, `NULL` or `CORE_NULL`; a radix value gives the bit pattern of a
//! float sample). The samples are memory-mapped, never copied.
//!
//! Heights are `DN · SCALING_FACTOR + OFFSET`, except that an `OFFSET` larger than 100 km is the
//! radius of the reference sphere, not a height offset: LOLA LDEM labels say `OFFSET = 1737400`
//! and `HEIGHT = DN · SCALING_FACTOR`. Such an offset becomes the DEM's `datum_radius_m` and the
//! height offset is 0. Products without a radius offset (MOLA MEGDR: areoid heights) have no
//! datum radius.
//!
//! # Map projection (IMAGE_MAP_PROJECTION)
//!
//! **SIMPLE CYLINDRICAL / EQUIRECTANGULAR** → geographic degrees, `MAP_RESOLUTION` pixels per
//! degree (or derived from `MAP_SCALE` and `A_AXIS_RADIUS`); an EQUIRECTANGULAR
//! `CENTER_LATITUDE` φ₀ ≠ 0 widens the longitude spacing to `1/(res·cos φ₀)`. Placement:
//!
//! 1. When `MAXIMUM_LATITUDE`, `MINIMUM_LATITUDE`, `WESTERNMOST_LONGITUDE` and
//!    `EASTERNMOST_LONGITUDE` are all given and agree with `LINES`/`LINE_SAMPLES` (span × pixels
//!    per degree = count within 1e-6 relative), they are the outer pixel *edges*: the centre of
//!    pixel (0, 0) is (`MAXIMUM_LATITUDE − dy/2`, `WESTERNMOST_LONGITUDE + dx/2`).
//! 2. Otherwise the PDS standard applies: `LINE_PROJECTION_OFFSET` / `SAMPLE_PROJECTION_OFFSET`
//!    are the 1-based line/sample of the projection origin, so 0-based row `r` is at latitude
//!    `CENTER_LATITUDE − (r + 1 − LINE_PROJECTION_OFFSET)/res` and column `c` at longitude
//!    `CENTER_LONGITUDE + (c + 1 − SAMPLE_PROJECTION_OFFSET)/res`.
//!
//! Rule 1 exists because real products disagree on the offsets: LOLA LDEM_4 says 359.5/719.5
//! (0-based) and MOLA MEGDR says 360.5/720.5 (1-based, the standard), yet both are pixel-registered
//! global grids whose row 0 is centred at 89.875°N and column 0 at 0.125°E — which their edge
//! keywords state unambiguously. Only `POSITIVE_LONGITUDE_DIRECTION = "EAST"` is read.
//!
//! **POLAR STEREOGRAPHIC** → spherical polar stereographic, true scale at the pole (lat_ts =
//! ±90), pole from the sign of `CENTER_LATITUDE`, `lon0 = CENTER_LONGITUDE`, radius
//! `A_AXIS_RADIUS`, pixel size `MAP_SCALE` (km/pixel unless its unit says metres). Column `c`
//! is at `x = (c − SAMPLE_PROJECTION_OFFSET)·scale` and row `r` at
//! `y = (LINE_PROJECTION_OFFSET − r)·scale`: the 0-based convention of the LOLA polar products,
//! whose offsets `(N − 1)/2` put the pole at the centre of an N×N grid.
//!
//! Other projections are reported as unsupported.

use std::io::Read;
use std::path::{Path, PathBuf};

use crate::dem::limits;
use crate::dem::types::{
    check_dimensions, map_file, ByteOrder, Crs, DemParts, GeoRef, SampleType, Samples,
};
use crate::error::{Error, IoContext, Result};

/// Labels larger than this are refused (real ones are a few KiB).
const MAX_LABEL_BYTES: u64 = 4 << 20;
/// An `OFFSET` above this (metres) is a reference radius, not a height offset.
const RADIUS_OFFSET_M: f64 = 100_000.0;
const NOT_A_LABEL: &str = "not a PDS3 label (no PDS_VERSION_ID / OBJECT = IMAGE)";

/// Read a PDS3 DEM given its label (`.LBL`) or its image (`.IMG`, with an attached label or a
/// `.LBL` beside it).
pub fn read(path: &Path) -> Result<DemParts> {
    let ext = lower_ext(path);
    let (label_path, text) = if ext == "img" {
        let head = read_head(path)?;
        if looks_like_label(&head) {
            (path.to_path_buf(), head)
        } else {
            let Some(lbl) = find_partner(path, "lbl") else {
                return Err(Error::invalid(
                    path,
                    format!(
                        "no PDS3 label: the file has no attached label and there is no {} beside \
                         it (looked for the name in any letter case)",
                        with_ext_name(path, "LBL")
                    ),
                ));
            };
            let text = read_head(&lbl)?;
            (lbl, text)
        }
    } else {
        (path.to_path_buf(), read_head(path)?)
    };
    if !looks_like_label(&text) {
        return Err(Error::invalid(&label_path, NOT_A_LABEL));
    }
    let root = parse_label(&text).map_err(|m| Error::invalid(&label_path, m))?;
    interpret(&label_path, path, &root)
}

// ---------------------------------------------------------------------------------------------
// Label reading and parsing
// ---------------------------------------------------------------------------------------------

fn lower_ext(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default()
}

fn with_ext_name(path: &Path, ext: &str) -> String {
    path.with_extension(ext)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| ext.to_string())
}

/// The first `MAX_LABEL_BYTES` of a file as Latin-1 text.
fn read_head(path: &Path) -> Result<String> {
    let f = std::fs::File::open(path).at(path)?;
    let mut buf = Vec::new();
    f.take(MAX_LABEL_BYTES).read_to_end(&mut buf).at(path)?;
    Ok(buf.iter().map(|&b| b as char).collect())
}

/// Whether text starts like a PDS3 label: `PDS_VERSION_ID` as the first keyword (after blank
/// lines, comments or an SFDU header line).
fn looks_like_label(text: &str) -> bool {
    let head: String = text
        .chars()
        .take(1024)
        .collect::<String>()
        .to_ascii_uppercase();
    head.find("PDS_VERSION_ID").is_some_and(|i| {
        // Only printable text before the keyword.
        head[..i]
            .chars()
            .all(|c| c == '\n' || c == '\r' || c == '\t' || (' '..='~').contains(&c))
    })
}

/// Find `<stem>.<ext>` beside `path`, in any letter case.
fn find_partner(path: &Path, ext: &str) -> Option<PathBuf> {
    let stem = path.file_stem()?.to_str()?;
    let name = format!("{stem}.{ext}");
    find_case_insensitive(parent_dir(path), &name)
}

fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// `dir/name`, or the entry of `dir` whose name equals `name` ignoring ASCII case.
fn find_case_insensitive(dir: &Path, name: &str) -> Option<PathBuf> {
    let exact = dir.join(name);
    if exact.is_file() {
        return Some(exact);
    }
    // The name may carry folders ("DATA/X.IMG"): match only the last component loosely.
    let rel = Path::new(name);
    let (dir, leaf) = match (rel.parent(), rel.file_name()) {
        (Some(p), Some(f)) if !p.as_os_str().is_empty() => (dir.join(p), f.to_str()?.to_string()),
        _ => (dir.to_path_buf(), name.to_string()),
    };
    std::fs::read_dir(&dir)
        .ok()?
        .filter_map(|e| e.ok())
        .find(|e| {
            e.file_name()
                .to_str()
                .is_some_and(|n| n.eq_ignore_ascii_case(&leaf))
                && e.path().is_file()
        })
        .map(|e| e.path())
}

/// A label value.
#[derive(Clone, Debug, PartialEq)]
enum Value {
    Scalar {
        text: String,
        quoted: bool,
        unit: Option<String>,
    },
    List(Vec<Value>),
}

/// An OBJECT or GROUP (or the label's root) with its statements.
#[derive(Debug, Default)]
struct Node {
    name: String,
    attrs: Vec<(String, Value)>,
    children: Vec<Node>,
}

impl Node {
    fn get(&self, key: &str) -> Option<&Value> {
        self.attrs
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(key))
            .map(|(_, v)| v)
    }

    /// Depth-first search for a child object named `name` (this node included).
    fn find_object(&self, name: &str) -> Option<&Node> {
        if self.name.eq_ignore_ascii_case(name) {
            return Some(self);
        }
        self.children.iter().find_map(|c| c.find_object(name))
    }

    /// Depth-first search for the object holding `key`; returns it with the value.
    fn find_attr(&self, key: &str) -> Option<(&Node, &Value)> {
        if let Some(v) = self.get(key) {
            return Some((self, v));
        }
        self.children.iter().find_map(|c| c.find_attr(key))
    }
}

struct Lexer<'a> {
    s: &'a [u8],
    i: usize,
    line: usize,
}

impl<'a> Lexer<'a> {
    fn peek(&self) -> Option<u8> {
        self.s.get(self.i).copied()
    }

    fn bump(&mut self) -> Option<u8> {
        let c = self.peek()?;
        self.i += 1;
        if c == b'\n' {
            self.line += 1;
        }
        Some(c)
    }

    /// Skip whitespace and `/* */` comments.
    fn skip_blank(&mut self) -> std::result::Result<(), String> {
        loop {
            match self.peek() {
                Some(c) if c.is_ascii_whitespace() => {
                    self.bump();
                }
                Some(b'/') if self.s.get(self.i + 1) == Some(&b'*') => {
                    let start = self.line;
                    self.i += 2;
                    loop {
                        match self.bump() {
                            None => {
                                return Err(format!(
                                    "label line {start}: comment /* is never closed"
                                ))
                            }
                            Some(b'*') if self.peek() == Some(b'/') => {
                                self.i += 1;
                                break;
                            }
                            _ => {}
                        }
                    }
                }
                _ => return Ok(()),
            }
        }
    }

    fn keyword(&mut self) -> std::result::Result<String, String> {
        let start = self.i;
        while let Some(c) = self.peek() {
            if c.is_ascii_alphanumeric() || c == b'_' || c == b'^' || c == b':' {
                self.i += 1;
            } else {
                break;
            }
        }
        if start == self.i {
            let what = match self.peek() {
                Some(c) if (0x20..0x7f).contains(&c) => format!("'{}'", c as char),
                Some(c) => format!("byte 0x{c:02x}"),
                None => "end of file".into(),
            };
            return Err(format!(
                "label line {}: expected a KEYWORD = value statement, found {what}",
                self.line
            ));
        }
        Ok(String::from_utf8_lossy(&self.s[start..self.i]).into_owned())
    }

    fn quoted(&mut self, q: u8) -> std::result::Result<String, String> {
        let start_line = self.line;
        self.bump();
        let mut out = Vec::new();
        loop {
            match self.bump() {
                None => {
                    return Err(format!(
                        "label line {start_line}: string opened with {} is never closed",
                        q as char
                    ))
                }
                Some(c) if c == q => break,
                Some(c) => out.push(c),
            }
        }
        // Collapse the line breaks and indentation of multi-line strings.
        let s: String = out.iter().map(|&b| b as char).collect();
        Ok(s.split_whitespace().collect::<Vec<_>>().join(" "))
    }

    fn value(&mut self, depth: usize) -> std::result::Result<Value, String> {
        if depth > 16 {
            return Err(format!(
                "label line {}: values nested too deeply",
                self.line
            ));
        }
        self.skip_blank()?;
        match self.peek() {
            Some(q @ (b'"' | b'\'')) => {
                let text = self.quoted(q)?;
                let unit = self.unit()?;
                Ok(Value::Scalar {
                    text,
                    quoted: true,
                    unit,
                })
            }
            Some(open @ (b'(' | b'{')) => {
                let close = if open == b'(' { b')' } else { b'}' };
                let start = self.line;
                self.bump();
                let mut items = Vec::new();
                loop {
                    self.skip_blank()?;
                    match self.peek() {
                        None => {
                            return Err(format!(
                                "label line {start}: '{}' is never closed",
                                open as char
                            ))
                        }
                        Some(c) if c == close => {
                            self.bump();
                            break;
                        }
                        Some(b',') => {
                            self.bump();
                        }
                        Some(_) => items.push(self.value(depth + 1)?),
                    }
                }
                Ok(Value::List(items))
            }
            _ => {
                let start = self.i;
                while let Some(c) = self.peek() {
                    let stop = c.is_ascii_whitespace()
                        || b",(){}<>\"'=".contains(&c)
                        || (c == b'/' && self.s.get(self.i + 1) == Some(&b'*'));
                    if stop {
                        break;
                    }
                    self.i += 1;
                }
                if start == self.i {
                    return Err(format!("label line {}: a value is missing", self.line));
                }
                let text = String::from_utf8_lossy(&self.s[start..self.i]).into_owned();
                let unit = self.unit()?;
                Ok(Value::Scalar {
                    text,
                    quoted: false,
                    unit,
                })
            }
        }
    }

    /// An optional `<unit>` after a value, on the same line.
    fn unit(&mut self) -> std::result::Result<Option<String>, String> {
        let save = (self.i, self.line);
        while matches!(self.peek(), Some(b' ' | b'\t')) {
            self.i += 1;
        }
        if self.peek() != Some(b'<') {
            (self.i, self.line) = save;
            return Ok(None);
        }
        self.i += 1;
        let start = self.i;
        while let Some(c) = self.peek() {
            if c == b'>' {
                let u = String::from_utf8_lossy(&self.s[start..self.i])
                    .trim()
                    .to_string();
                self.i += 1;
                return Ok(Some(u));
            }
            if c == b'\n' {
                break;
            }
            self.i += 1;
        }
        Err(format!(
            "label line {}: unit '<' is never closed",
            self.line
        ))
    }
}

/// Parse label text into its object tree, stopping at `END`.
fn parse_label(text: &str) -> std::result::Result<Node, String> {
    // The text is Latin-1 (one char per byte), so this round-trips the bytes.
    let bytes: Vec<u8> = text.chars().map(|c| c as u32 as u8).collect();
    let mut lx = Lexer {
        s: &bytes,
        i: 0,
        line: 1,
    };
    let mut stack: Vec<Node> = vec![Node::default()];
    loop {
        lx.skip_blank()?;
        if lx.peek().is_none() {
            break; // a detached label may omit END
        }
        let line = lx.line;
        let key = lx.keyword()?;
        let upper = key.to_ascii_uppercase();
        if upper == "END" {
            break;
        }
        lx.skip_blank()?;
        let is_end_obj = upper == "END_OBJECT" || upper == "END_GROUP";
        let value = if lx.peek() == Some(b'=') {
            lx.bump();
            Some(lx.value(0)?)
        } else if is_end_obj {
            None
        } else {
            return Err(format!("label line {line}: expected '=' after {key}"));
        };
        if upper == "OBJECT" || upper == "GROUP" {
            let name = match value {
                Some(Value::Scalar { text, .. }) => text,
                _ => return Err(format!("label line {line}: {key} needs a name")),
            };
            if stack.len() > 64 {
                return Err(format!("label line {line}: objects nested too deeply"));
            }
            stack.push(Node {
                name,
                ..Node::default()
            });
        } else if is_end_obj {
            if stack.len() < 2 {
                return Err(format!(
                    "label line {line}: {key} without a matching OBJECT"
                ));
            }
            let node = stack.pop().expect("stack holds at least two nodes");
            stack
                .last_mut()
                .expect("stack holds the root")
                .children
                .push(node);
        } else {
            let value = value.expect("value parsed for a plain statement");
            stack
                .last_mut()
                .expect("stack holds the root")
                .attrs
                .push((key, value));
        }
    }
    // Close objects left open (lenient, as the PDS tools are).
    while stack.len() > 1 {
        let node = stack.pop().expect("stack holds at least two nodes");
        stack
            .last_mut()
            .expect("stack holds the root")
            .children
            .push(node);
    }
    Ok(stack.pop().expect("root"))
}

// ---------------------------------------------------------------------------------------------
// Value helpers
// ---------------------------------------------------------------------------------------------

fn is_placeholder(text: &str) -> bool {
    matches!(
        text.trim().to_ascii_uppercase().as_str(),
        "N/A" | "UNK" | "NULL" | "NONE" | ""
    )
}

/// A radix integer `16#FF7F#`, `2#0101#`, `8#17#` (optionally signed).
fn parse_radix(text: &str) -> Option<(bool, u64)> {
    let t = text.trim();
    let (neg, t) = match t.strip_prefix('-') {
        Some(r) => (true, r),
        None => (false, t.strip_prefix('+').unwrap_or(t)),
    };
    let mut parts = t.split('#');
    let base: u32 = parts.next()?.parse().ok()?;
    let digits = parts.next()?;
    if parts.next() != Some("") || parts.next().is_some() || !(2..=16).contains(&base) {
        return None;
    }
    u64::from_str_radix(digits, base).ok().map(|v| (neg, v))
}

struct Ctx<'a> {
    path: &'a Path,
}

impl Ctx<'_> {
    fn invalid(&self, msg: impl Into<String>) -> Error {
        Error::invalid(self.path, msg)
    }

    fn scalar<'v>(&self, key: &str, v: &'v Value) -> Result<(&'v str, Option<&'v str>)> {
        match v {
            Value::Scalar { text, unit, .. } => Ok((text.as_str(), unit.as_deref())),
            Value::List(_) => {
                Err(self.invalid(format!("{key} is a list, a single value was expected")))
            }
        }
    }

    /// A number, `None` when absent or a placeholder such as 'N/A'.
    fn num(&self, node: &Node, key: &str) -> Result<Option<(f64, Option<String>)>> {
        let Some(v) = node.get(key) else {
            return Ok(None);
        };
        let (text, unit) = self.scalar(key, v)?;
        if is_placeholder(text) {
            return Ok(None);
        }
        let x = if let Some((neg, r)) = parse_radix(text) {
            if neg {
                -(r as f64)
            } else {
                r as f64
            }
        } else {
            text.trim()
                .parse::<f64>()
                .map_err(|_| self.invalid(format!("{key} = {text} is not a number")))?
        };
        if !x.is_finite() {
            return Err(self.invalid(format!("{key} = {text} is not a finite number")));
        }
        Ok(Some((x, unit.map(str::to_string))))
    }

    fn req_num(&self, node: &Node, key: &str, what: &str) -> Result<(f64, Option<String>)> {
        self.num(node, key)?.ok_or_else(|| {
            self.invalid(format!(
                "{key} is missing from the {} object: {what}",
                if node.name.is_empty() {
                    "label's top-level"
                } else {
                    &node.name
                }
            ))
        })
    }

    /// A non-negative integer (such as a count or a byte size).
    fn count(&self, node: &Node, key: &str) -> Result<Option<u64>> {
        match self.num(node, key)? {
            None => Ok(None),
            Some((x, _)) => {
                if x < 0.0 || x.fract() != 0.0 || x > 9.0e15 {
                    Err(self.invalid(format!(
                        "{key} = {} is not a non-negative integer",
                        crate::dem::limits::show(x)
                    )))
                } else {
                    Ok(Some(x as u64))
                }
            }
        }
    }

    fn text(&self, node: &Node, key: &str) -> Result<Option<String>> {
        match node.get(key) {
            None => Ok(None),
            Some(v) => {
                let (t, _) = self.scalar(key, v)?;
                Ok((!is_placeholder(t)).then(|| t.trim().to_string()))
            }
        }
    }
}

/// Metres per unit of a length unit (`km`, `m`, `KM/PIXEL`, `METERS/PIXEL` …); `default` when
/// there is no unit.
fn length_factor(unit: Option<&str>, default: f64) -> Option<f64> {
    let Some(u) = unit else {
        return Some(default);
    };
    let u = u
        .split('/')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    match u.as_str() {
        "km" | "kilometer" | "kilometers" | "kilometre" | "kilometres" => Some(1000.0),
        "m" | "meter" | "meters" | "metre" | "metres" => Some(1.0),
        _ => None,
    }
}

// ---------------------------------------------------------------------------------------------
// Interpretation
// ---------------------------------------------------------------------------------------------

/// Where the samples start.
struct Pointer {
    file: Option<String>,
    /// 1-based position and whether it counts bytes (else records).
    at: Option<(u64, bool)>,
}

fn parse_pointer(c: &Ctx, v: &Value) -> Result<Pointer> {
    let pos = |v: &Value| -> Result<(u64, bool)> {
        let (text, unit) = c.scalar("^IMAGE", v)?;
        let n: f64 = text
            .trim()
            .parse()
            .map_err(|_| c.invalid(format!("^IMAGE position '{text}' is not a number")))?;
        if n < 1.0 || n.fract() != 0.0 || n > 9.0e15 {
            return Err(c.invalid(format!(
                "^IMAGE position {text} is not a 1-based record or byte number"
            )));
        }
        let bytes = unit.is_some_and(|u| u.eq_ignore_ascii_case("bytes"));
        Ok((n as u64, bytes))
    };
    match v {
        Value::Scalar { text, quoted, .. } => {
            if !quoted && text.trim().starts_with(|ch: char| ch.is_ascii_digit()) {
                Ok(Pointer {
                    file: None,
                    at: Some(pos(v)?),
                })
            } else {
                Ok(Pointer {
                    file: Some(text.clone()),
                    at: None,
                })
            }
        }
        Value::List(items) => match items.as_slice() {
            [Value::Scalar { text, .. }] => Ok(Pointer {
                file: Some(text.clone()),
                at: None,
            }),
            [Value::Scalar { text, .. }, p] => Ok(Pointer {
                file: Some(text.clone()),
                at: Some(pos(p)?),
            }),
            _ => {
                Err(c
                    .invalid("^IMAGE must be \"FILE\", (\"FILE\", record), record or byte <BYTES>"))
            }
        },
    }
}

/// Sample type and byte order from SAMPLE_TYPE and SAMPLE_BITS.
fn sample_kind(c: &Ctx, ty: &str, bits: u64) -> Result<(SampleType, ByteOrder, &'static str)> {
    enum K {
        Signed,
        Unsigned,
        Real,
    }
    use ByteOrder::{Big, Little};
    let t = ty.trim().to_ascii_uppercase().replace(' ', "_");
    let (kind, order) = match t.as_str() {
        "LSB_INTEGER" | "PC_INTEGER" | "VAX_INTEGER" => (K::Signed, Little),
        "MSB_INTEGER" | "SUN_INTEGER" | "MAC_INTEGER" | "INTEGER" => (K::Signed, Big),
        "LSB_UNSIGNED_INTEGER" | "PC_UNSIGNED_INTEGER" | "VAX_UNSIGNED_INTEGER" => {
            (K::Unsigned, Little)
        }
        "MSB_UNSIGNED_INTEGER"
        | "SUN_UNSIGNED_INTEGER"
        | "MAC_UNSIGNED_INTEGER"
        | "UNSIGNED_INTEGER" => (K::Unsigned, Big),
        "IEEE_REAL" | "SUN_REAL" | "MAC_REAL" | "REAL" | "FLOAT" | "MSB_REAL" => (K::Real, Big),
        "PC_REAL" | "LSB_REAL" => (K::Real, Little),
        _ => {
            return Err(Error::unsupported(
                c.path,
                format!(
                    "SAMPLE_TYPE = {ty}: Penumbra reads LSB/MSB (PC/MAC/SUN) signed and unsigned \
                     integers and IEEE_REAL/PC_REAL floats"
                ),
            ))
        }
    };
    let st = match (kind, bits) {
        (K::Unsigned, 8) => SampleType::U8,
        (K::Signed, 16) => SampleType::I16,
        (K::Unsigned, 16) => SampleType::U16,
        (K::Signed, 32) => SampleType::I32,
        (K::Unsigned, 32) => SampleType::U32,
        (K::Real, 32) => SampleType::F32,
        (K::Real, 64) => SampleType::F64,
        (K::Signed, 8) => {
            return Err(Error::unsupported(
                c.path,
                format!("SAMPLE_TYPE = {ty} with SAMPLE_BITS = 8 (signed bytes) is not read"),
            ))
        }
        (K::Real, b) => {
            return Err(c.invalid(format!(
                "SAMPLE_BITS = {b} does not match SAMPLE_TYPE = {ty} (32 or 64 bits)"
            )))
        }
        (_, b) => {
            return Err(c.invalid(format!(
                "SAMPLE_BITS = {b} does not match SAMPLE_TYPE = {ty} (8, 16 or 32 bits)"
            )))
        }
    };
    Ok((st, order, st.name()))
}

/// The void value as the raw DN the sampler compares against.
fn nodata_value(c: &Ctx, image: &Node, st: SampleType) -> Result<Option<f64>> {
    for key in ["MISSING_CONSTANT", "NULL", "CORE_NULL", "MISSING"] {
        let Some(v) = image.get(key) else { continue };
        let (text, _) = c.scalar(key, v)?;
        if is_placeholder(text) {
            continue;
        }
        if let Some((neg, bits)) = parse_radix(text) {
            let x = match st {
                SampleType::F32 if !neg => f32::from_bits(bits as u32) as f64,
                SampleType::F64 if !neg => f64::from_bits(bits),
                SampleType::I16 if !neg && bits <= 0xffff => bits as u16 as i16 as f64,
                SampleType::I32 if !neg && bits <= 0xffff_ffff => bits as u32 as i32 as f64,
                _ if neg => -(bits as f64),
                _ => bits as f64,
            };
            return Ok((!x.is_nan()).then_some(x));
        }
        let Some((x, _)) = c.num(image, key)? else {
            continue;
        };
        let x = match st {
            SampleType::F32 => x as f32 as f64,
            _ => x,
        };
        return Ok(Some(x));
    }
    Ok(None)
}

fn interpret(label_path: &Path, given: &Path, root: &Node) -> Result<DemParts> {
    let c = Ctx { path: label_path };
    let Some(image) = root.find_object("IMAGE") else {
        let msg = if root.get("PDS_VERSION_ID").is_some() {
            "the PDS3 label has no OBJECT = IMAGE: Penumbra reads image DEMs (not tables, \
             spectral cubes or documents)"
        } else {
            NOT_A_LABEL
        };
        return Err(c.invalid(msg));
    };

    // Where the data is.
    let Some((ptr_node, ptr_val)) = root.find_attr("^IMAGE") else {
        return Err(c.invalid("the label has no ^IMAGE pointer: cannot find the samples"));
    };
    let ptr = parse_pointer(&c, ptr_val)?;
    let data_path = match &ptr.file {
        None => label_path.to_path_buf(),
        Some(name) => {
            let dir = parent_dir(label_path);
            match find_case_insensitive(dir, name) {
                Some(p) => p,
                None if lower_ext(given) == "img" && given != label_path => given.to_path_buf(),
                None => match find_partner(label_path, "img") {
                    Some(p) => p,
                    None => {
                        return Err(c.invalid(format!(
                            "^IMAGE names the data file \"{name}\", which is not in {} (looked \
                             for the name in any letter case): put the .IMG beside its label",
                            dir.display()
                        )))
                    }
                },
            }
        }
    };
    let record_bytes = match c.count(ptr_node, "RECORD_BYTES")? {
        Some(r) => Some(r),
        None => c.count(root, "RECORD_BYTES")?,
    };
    let data_offset: u64 = match ptr.at {
        None => 0,
        Some((n, true)) => n - 1,
        Some((n, false)) => {
            let rb = record_bytes.ok_or_else(|| {
                c.invalid("^IMAGE counts records but the label has no RECORD_BYTES")
            })?;
            (n - 1).checked_mul(rb).ok_or_else(|| {
                c.invalid(format!("^IMAGE record {n} × RECORD_BYTES {rb} overflows"))
            })?
        }
    };

    // Raster layout.
    let what = "a DEM image needs LINES, LINE_SAMPLES, SAMPLE_TYPE and SAMPLE_BITS";
    let lines = c
        .count(image, "LINES")?
        .ok_or_else(|| c.invalid(format!("IMAGE has no LINES: {what}")))?;
    let samples = c
        .count(image, "LINE_SAMPLES")?
        .ok_or_else(|| c.invalid(format!("IMAGE has no LINE_SAMPLES: {what}")))?;
    check_dimensions(label_path, samples, lines)?;
    if let Some(b) = c.count(image, "BANDS")? {
        if b > 1 {
            return Err(Error::unsupported(
                label_path,
                format!("IMAGE has {b} BANDS: a DEM is a single band"),
            ));
        }
    }
    let sample_type = c
        .text(image, "SAMPLE_TYPE")?
        .ok_or_else(|| c.invalid(format!("IMAGE has no SAMPLE_TYPE: {what}")))?;
    let bits = c
        .count(image, "SAMPLE_BITS")?
        .ok_or_else(|| c.invalid(format!("IMAGE has no SAMPLE_BITS: {what}")))?;
    let (st, order, type_name) = sample_kind(&c, &sample_type, bits)?;
    let prefix = c.count(image, "LINE_PREFIX_BYTES")?.unwrap_or(0);
    let suffix = c.count(image, "LINE_SUFFIX_BYTES")?.unwrap_or(0);
    if prefix > 1 << 30 || suffix > 1 << 30 {
        return Err(c.invalid("LINE_PREFIX_BYTES / LINE_SUFFIX_BYTES are absurdly large"));
    }
    let row_bytes = samples * st.size() as u64; // ≤ 2^24 · 8
    let stride = prefix + row_bytes + suffix;
    // Bytes the samples span: up to the end of the last line's samples.
    let need = (data_offset as u128)
        + (prefix as u128)
        + (stride as u128) * (lines as u128 - 1)
        + row_bytes as u128;
    let file_len = std::fs::metadata(&data_path).at(&data_path)?.len();
    if need > file_len as u128 {
        return Err(Error::invalid(
            &data_path,
            format!(
                "truncated: label {} says {need} bytes ({lines} lines × {stride} bytes from byte \
                 {data_offset}), file has {file_len}: the download may be incomplete",
                label_path.display()
            ),
        ));
    }

    // Trailing bytes: a file may carry other objects after the image, but not more than the
    // image itself (a file 240 times its label's size is another file, or the label is wrong).
    let image_bytes = need - data_offset as u128;
    if file_len as u128 > need + image_bytes.max(1 << 20) {
        return Err(Error::invalid(
            &data_path,
            format!(
                "the file is {file_len} bytes but label {} says the image ends at byte {need} \
                 (^IMAGE, LINES = {lines}, LINE_SAMPLES = {samples}, SAMPLE_BITS = {bits}): more \
                 than the image's size again beyond it. The label's sizes or ^IMAGE are wrong, \
                 or the label belongs to another file",
                label_path.display()
            ),
        ));
    }

    // Values. A key present with an empty value is refused (it is not "absent").
    for key in ["SCALING_FACTOR", "OFFSET"] {
        if let Some(v) = image.get(key) {
            if c.scalar(key, v)?.0.trim().is_empty() {
                return Err(c.invalid(format!(
                    "{key} = \"\" is empty: give its value, or remove the key for the default \
                     ({})",
                    if key == "OFFSET" { "0" } else { "1" }
                )));
            }
        }
    }
    let unit_factor = match c.text(image, "UNIT")? {
        None => 1.0,
        Some(u) => match length_factor(Some(&u), 1.0) {
            Some(f) => f,
            None => {
                return Err(Error::unsupported(
                    label_path,
                    format!("IMAGE UNIT = {u}: heights must be in metres or kilometres"),
                ))
            }
        },
    };
    let scale = c.num(image, "SCALING_FACTOR")?.map_or(1.0, |v| v.0) * unit_factor;
    let mut offset = match c.num(image, "OFFSET")? {
        None => 0.0,
        Some((x, unit)) => x * length_factor(unit.as_deref(), unit_factor).unwrap_or(unit_factor),
    };
    let mut datum_radius_m = None;
    if offset.abs() > RADIUS_OFFSET_M {
        limits::radius(
            label_path,
            "OFFSET (above 100 km: the reference sphere's radius)",
            offset,
        )?;
        datum_radius_m = Some(offset);
        offset = 0.0;
    }
    limits::scale_offset(
        label_path,
        ("SCALING_FACTOR", scale),
        ("OFFSET", offset),
        Some(st),
    )?;
    let nodata = nodata_value(&c, image, st)?;
    let target = c.text(root, "TARGET_NAME")?.map(|t| t.to_ascii_lowercase());

    // Georeferencing.
    let Some(proj) = root.find_object("IMAGE_MAP_PROJECTION") else {
        return Err(Error::unsupported(
            label_path,
            "the label has no IMAGE_MAP_PROJECTION object: the image is not map-projected, so \
             it cannot be placed on the body",
        ));
    };
    let (georef, proj_desc) = georef(&c, proj, samples, lines)?;

    let order_name = match order {
        ByteOrder::Little => "LSB",
        ByteOrder::Big => "MSB",
    };
    let format = format!("PDS3 {order_name} {type_name}, {proj_desc}");

    let to_usize = |x: u64| {
        usize::try_from(x)
            .map_err(|_| c.invalid("the raster does not fit in this machine's memory"))
    };
    let map = map_file(&data_path)?;
    let mut sources = vec![label_path.to_path_buf()];
    if data_path != label_path {
        sources.push(data_path.clone());
    }
    Ok(DemParts {
        width: to_usize(samples)?,
        height: to_usize(lines)?,
        samples: Samples::Mapped {
            map,
            offset: to_usize(data_offset + prefix)?,
            row_stride: to_usize(stride)?,
            ty: st,
            order,
        },
        scale,
        offset,
        nodata,
        georef,
        datum_radius_m,
        target,
        sources,
        format,
    })
}

fn fmt_num(x: f64) -> String {
    let s = format!("{x:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

fn georef(c: &Ctx, proj: &Node, samples: u64, lines: u64) -> Result<(GeoRef, String)> {
    let ptype = c
        .text(proj, "MAP_PROJECTION_TYPE")?
        .ok_or_else(|| c.invalid("IMAGE_MAP_PROJECTION has no MAP_PROJECTION_TYPE"))?;
    let norm = ptype
        .to_ascii_uppercase()
        .split(|ch: char| ch == '_' || ch.is_whitespace())
        .filter(|s| !s.is_empty())
        .collect::<Vec<_>>()
        .join(" ");
    let radius_m = match c.num(proj, "A_AXIS_RADIUS")? {
        None => None,
        Some((r, unit)) => {
            let f = length_factor(unit.as_deref(), 1000.0).ok_or_else(|| {
                c.invalid(format!(
                    "A_AXIS_RADIUS unit <{}> is not a length",
                    unit.unwrap_or_default()
                ))
            })?;
            Some(limits::radius(c.path, "A_AXIS_RADIUS", r * f)?)
        }
    };
    let map_scale_m = match c.num(proj, "MAP_SCALE")? {
        None => None,
        Some((s, unit)) => {
            let f = length_factor(unit.as_deref(), 1000.0).ok_or_else(|| {
                c.invalid(format!(
                    "MAP_SCALE unit <{}> is not a length per pixel",
                    unit.unwrap_or_default()
                ))
            })?;
            if s <= 0.0 {
                return Err(c.invalid(format!(
                    "MAP_SCALE = {} is not a positive pixel size",
                    limits::show(s)
                )));
            }
            Some(limits::pixel_m(c.path, "MAP_SCALE", s * f, radius_m)?)
        }
    };
    // Angles, wherever they are used below.
    let center_lat = match c.num(proj, "CENTER_LATITUDE")? {
        Some((v, _)) => Some(limits::latitude(c.path, "CENTER_LATITUDE", v)?),
        None => None,
    };
    let center_lon = match c.num(proj, "CENTER_LONGITUDE")? {
        Some((v, _)) => Some(limits::longitude(c.path, "CENTER_LONGITUDE", v)?),
        None => None,
    };
    if let Some(dir) = c.text(proj, "POSITIVE_LONGITUDE_DIRECTION")? {
        if !dir.eq_ignore_ascii_case("EAST") {
            return Err(Error::unsupported(
                c.path,
                format!(
                    "POSITIVE_LONGITUDE_DIRECTION = {dir}: only east-positive longitudes are \
                     read; convert the product to east longitudes"
                ),
            ));
        }
    }
    let (w, h) = (samples as f64, lines as f64);
    match norm.as_str() {
        "SIMPLE CYLINDRICAL" | "EQUIRECTANGULAR" | "EQUIDISTANT" => {
            let lat_ts = if norm == "EQUIRECTANGULAR" {
                center_lat.unwrap_or(0.0)
            } else {
                0.0
            };
            if lat_ts.abs() >= 89.0 {
                return Err(c.invalid(format!(
                    "EQUIRECTANGULAR CENTER_LATITUDE = {lat_ts} leaves no usable longitude scale"
                )));
            }
            let res = match c.num(proj, "MAP_RESOLUTION")? {
                Some((r, _)) => r,
                None => match (map_scale_m, radius_m) {
                    (Some(s), Some(r)) if s > 0.0 => r * std::f64::consts::PI / 180.0 / s,
                    _ => {
                        return Err(c.invalid(
                            "IMAGE_MAP_PROJECTION has no MAP_RESOLUTION (pixels per degree), \
                             nor MAP_SCALE with A_AXIS_RADIUS",
                        ))
                    }
                },
            };
            if !(res > 0.0 && res.is_finite()) {
                return Err(c.invalid(format!(
                    "MAP_RESOLUTION = {} is not a positive number of pixels per degree",
                    limits::show(res)
                )));
            }
            limits::pixel_deg(c.path, "1 / MAP_RESOLUTION (the pixel spacing)", 1.0 / res)?;
            let dy = 1.0 / res;
            let dx = dy / lat_ts.to_radians().cos();
            let angle = |key: &str, lat: bool| -> Result<Option<(f64, Option<String>)>> {
                match c.num(proj, key)? {
                    None => Ok(None),
                    Some((v, u)) => {
                        if lat {
                            limits::latitude(c.path, key, v)?;
                        } else {
                            limits::longitude(c.path, key, v)?;
                        }
                        Ok(Some((v, u)))
                    }
                }
            };
            let edges = (
                angle("MAXIMUM_LATITUDE", true)?,
                angle("MINIMUM_LATITUDE", true)?,
                angle("WESTERNMOST_LONGITUDE", false)?,
                angle("EASTERNMOST_LONGITUDE", false)?,
            );
            let from_edges = match edges {
                (Some((n, _)), Some((s, _)), Some((we, _)), Some((ea, _))) => {
                    let mut span_lon = ea - we;
                    if span_lon <= 0.0 {
                        span_lon += 360.0;
                    }
                    let ok = |span: f64, d: f64, count: f64| {
                        (span / d - count).abs() <= 1e-6 * count.max(1.0)
                    };
                    (n > s && ok(n - s, dy, h) && ok(span_lon, dx, w))
                        .then_some((we + dx / 2.0, n - dy / 2.0))
                }
                _ => None,
            };
            let (x0, y0, placed_by) = match from_edges {
                Some((x0, y0)) => (
                    x0,
                    y0,
                    "MAXIMUM/MINIMUM_LATITUDE and WESTERNMOST/EASTERNMOST_LONGITUDE",
                ),
                None => {
                    if lat_ts != 0.0 {
                        return Err(Error::unsupported(
                            c.path,
                            "EQUIRECTANGULAR with CENTER_LATITUDE ≠ 0 is read only when \
                             MAXIMUM/MINIMUM_LATITUDE and WESTERNMOST/EASTERNMOST_LONGITUDE \
                             give the grid edges",
                        ));
                    }
                    let need = "without consistent MAXIMUM/MINIMUM_LATITUDE and \
                                WESTERNMOST/EASTERNMOST_LONGITUDE the projection offsets \
                                place the grid";
                    let lpo = c.req_num(proj, "LINE_PROJECTION_OFFSET", need)?.0;
                    let spo = c.req_num(proj, "SAMPLE_PROJECTION_OFFSET", need)?.0;
                    let clat = center_lat.unwrap_or(0.0);
                    let clon = center_lon.unwrap_or(0.0);
                    (
                        clon + (1.0 - spo) * dx,
                        clat - (1.0 - lpo) * dy,
                        "LINE/SAMPLE_PROJECTION_OFFSET, CENTER_LATITUDE/LONGITUDE and \
                         MAP_RESOLUTION",
                    )
                }
            };
            let desc = if lat_ts == 0.0 {
                format!("simple cylindrical {} px/deg", fmt_num(res))
            } else {
                format!(
                    "equirectangular {} px/deg, true scale at {}°",
                    fmt_num(res),
                    fmt_num(lat_ts)
                )
            };
            let g = GeoRef {
                crs: Crs::Geographic,
                x0,
                y0,
                dx,
                dy,
            };
            limits::check_georef(c.path, &g, samples as usize, lines as usize, placed_by)?;
            Ok((g, desc))
        }
        "POLAR STEREOGRAPHIC" | "POLARSTEREOGRAPHIC" => {
            let what = "a polar stereographic grid needs CENTER_LATITUDE, MAP_SCALE, \
                        A_AXIS_RADIUS and the LINE/SAMPLE_PROJECTION_OFFSET";
            let clat = center_lat.ok_or_else(|| {
                c.invalid(format!(
                    "CENTER_LATITUDE is missing from the {} object: {what}",
                    proj.name
                ))
            })?;
            if (clat.abs() - 90.0).abs() > 1e-9 {
                return Err(Error::unsupported(
                    c.path,
                    format!("POLAR STEREOGRAPHIC with CENTER_LATITUDE = {clat} (not ±90)"),
                ));
            }
            let north = clat > 0.0;
            let lon0 = center_lon.unwrap_or(0.0);
            let scale =
                map_scale_m.ok_or_else(|| c.invalid(format!("MAP_SCALE is missing: {what}")))?;
            let radius =
                radius_m.ok_or_else(|| c.invalid(format!("A_AXIS_RADIUS is missing: {what}")))?;
            if !(scale > 0.0 && radius > 0.0) {
                return Err(c.invalid("MAP_SCALE and A_AXIS_RADIUS must be positive"));
            }
            let lpo = c.req_num(proj, "LINE_PROJECTION_OFFSET", what)?.0;
            let spo = c.req_num(proj, "SAMPLE_PROJECTION_OFFSET", what)?.0;
            let desc = format!(
                "polar stereographic ({} pole) {} m/px",
                if north { "north" } else { "south" },
                fmt_num(scale)
            );
            let g = GeoRef {
                crs: Crs::PolarStereographic {
                    north,
                    lon0_deg: lon0,
                    lat_ts_deg: if north { 90.0 } else { -90.0 },
                    radius_m: radius,
                },
                x0: -spo * scale,
                y0: lpo * scale,
                dx: scale,
                dy: scale,
            };
            let placed_by = "MAP_SCALE and LINE/SAMPLE_PROJECTION_OFFSET";
            limits::check_georef(c.path, &g, samples as usize, lines as usize, placed_by)?;
            Ok((g, desc))
        }
        _ => Err(Error::unsupported(
            c.path,
            format!(
                "MAP_PROJECTION_TYPE = {ptype}: Penumbra reads SIMPLE CYLINDRICAL, \
                 EQUIRECTANGULAR and POLAR STEREOGRAPHIC PDS3 products"
            ),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_odl_forms() {
        let text = "PDS_VERSION_ID = PDS3\n/* comment = x */\nA = \"multi\n  line\" \n\
                    B = ( \"F.IMG\", 3 <BYTES> )\nC = {X, 'Y z'}\nOBJECT = IMAGE\n  D = 4 <pix/deg>\n\
                    E = 16#FF7FFFFB#\nEND_OBJECT = IMAGE\nEND\ngarbage \u{1}\u{2}";
        let root = parse_label(text).unwrap();
        assert_eq!(
            root.get("A"),
            Some(&Value::Scalar {
                text: "multi line".into(),
                quoted: true,
                unit: None
            })
        );
        let img = root.find_object("image").unwrap();
        match img.get("D").unwrap() {
            Value::Scalar { text, unit, .. } => {
                assert_eq!(text, "4");
                assert_eq!(unit.as_deref(), Some("pix/deg"));
            }
            _ => panic!(),
        }
        assert_eq!(parse_radix("16#FF7FFFFB#"), Some((false, 0xFF7F_FFFB)));
        match root.get("B").unwrap() {
            Value::List(v) => assert_eq!(v.len(), 2),
            _ => panic!(),
        }
    }

    #[test]
    fn parse_errors_name_lines() {
        let e = parse_label("PDS_VERSION_ID = PDS3\nA = \"open\n").unwrap_err();
        assert!(e.contains("line 2"), "{e}");
        let e = parse_label("PDS_VERSION_ID = PDS3\nEND_OBJECT = IMAGE\n").unwrap_err();
        assert!(e.contains("line 2"), "{e}");
        assert!(parse_label("A B C").is_err());
    }
}
