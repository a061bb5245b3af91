//! A reader of Celestia's catalog grammar (`.ssc` solar-system catalogs and `.ctx` virtual
//! texture descriptions), written from Celestia's documentation and its reference
//! implementation (`src/celutil/tokenizer.cpp`, `src/celutil/parser.cpp`,
//! `src/celengine/solarsys.cpp`, `src/celengine/virtualtex.cpp`). It is what the tests of the
//! addon writers parse their output with; Celestia itself stays the judge of what it loads.
//!
//! Tokens: names (`[A-Za-z_][A-Za-z0-9_]*`), strings (`"…"` with the escapes `\"`, `\\`, `\n`
//! and `\uXXXX`), numbers (optional sign, digits, fraction, exponent), `{ } [ ] < > = |`, and
//! comments from `#` to the end of the line. Values: a number, a string, `true`/`false`, an
//! array `[ value… ]` or a group `{ Name [<units>] value … }`. A catalog is a sequence of
//! `[Add|Replace|Modify] [ItemType] "name" "parent" { … }`; a virtual texture is
//! `VirtualTexture { … }`.

use std::fmt;

/// One token of Celestia's grammar.
#[derive(Clone, Debug, PartialEq)]
pub enum Token {
    /// A bare word.
    Name(String),
    /// A quoted string, escapes resolved.
    Str(String),
    /// A number.
    Number(f64),
    /// `{`, `}`, `[`, `]`, `<`, `>`, `=` or `|`.
    Punct(char),
}

/// A value of the grammar.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    Number(f64),
    Str(String),
    Bool(bool),
    Array(Vec<Value>),
    /// A group's entries in file order: (key, units named in `<…>` after the key, value).
    Group(Vec<(String, Vec<String>, Value)>),
}

impl Value {
    /// The first entry `key` of a group.
    pub fn get(&self, key: &str) -> Option<&Value> {
        match self {
            Value::Group(e) => e.iter().find(|(k, _, _)| k == key).map(|(_, _, v)| v),
            _ => None,
        }
    }

    /// The string entry `key` of a group.
    pub fn get_str(&self, key: &str) -> Option<&str> {
        match self.get(key) {
            Some(Value::Str(s)) => Some(s),
            _ => None,
        }
    }

    /// The number entry `key` of a group.
    pub fn get_number(&self, key: &str) -> Option<f64> {
        match self.get(key) {
            Some(Value::Number(n)) => Some(*n),
            _ => None,
        }
    }
}

/// What went wrong, and where (1-based line).
#[derive(Clone, Debug, PartialEq)]
pub struct ParseError {
    pub line: usize,
    pub msg: String,
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}: {}", self.line, self.msg)
    }
}

impl std::error::Error for ParseError {}

fn err<T>(line: usize, msg: impl Into<String>) -> Result<T, ParseError> {
    Err(ParseError {
        line,
        msg: msg.into(),
    })
}

/// The tokens of `src`, each with its line.
pub fn tokenize(src: &str) -> Result<Vec<(Token, usize)>, ParseError> {
    let c: Vec<char> = src.chars().collect();
    let (mut i, mut line, mut out) = (0usize, 1usize, Vec::new());
    while i < c.len() {
        let ch = c[i];
        if ch == '\n' {
            line += 1;
            i += 1;
        } else if ch.is_whitespace() {
            i += 1;
        } else if ch == '#' {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if ch.is_ascii_alphabetic() || ch == '_' {
            let s = i;
            while i < c.len() && (c[i].is_ascii_alphanumeric() || c[i] == '_') {
                i += 1;
            }
            out.push((Token::Name(c[s..i].iter().collect()), line));
        } else if ch.is_ascii_digit()
            || ((ch == '-' || ch == '+' || ch == '.')
                && c.get(i + 1)
                    .is_some_and(|d| d.is_ascii_digit() || *d == '.'))
        {
            let s = i;
            if ch == '-' || ch == '+' {
                i += 1;
            }
            while i < c.len() && c[i].is_ascii_digit() {
                i += 1;
            }
            if i < c.len() && c[i] == '.' {
                i += 1;
                while i < c.len() && c[i].is_ascii_digit() {
                    i += 1;
                }
            }
            if i < c.len() && (c[i] == 'e' || c[i] == 'E') {
                let mut j = i + 1;
                if j < c.len() && (c[j] == '+' || c[j] == '-') {
                    j += 1;
                }
                if j < c.len() && c[j].is_ascii_digit() {
                    i = j;
                    while i < c.len() && c[i].is_ascii_digit() {
                        i += 1;
                    }
                } else {
                    return err(line, "a number's exponent has no digits");
                }
            }
            let text: String = c[s..i].iter().collect();
            match text.parse::<f64>() {
                Ok(v) if v.is_finite() => out.push((Token::Number(v), line)),
                _ => return err(line, format!("'{text}' is not a number")),
            }
            if i < c.len() && (c[i].is_ascii_alphabetic() || c[i] == '_') {
                return err(
                    line,
                    format!("'{text}{}' is neither a number nor a name", c[i]),
                );
            }
        } else if ch == '"' {
            let start_line = line;
            let mut s = String::new();
            i += 1;
            loop {
                match c.get(i) {
                    None => return err(start_line, "a string is not closed (missing '\"')"),
                    Some('"') => {
                        i += 1;
                        break;
                    }
                    // Strings may span lines (CR LF and CR read as LF), as in Celestia.
                    Some('\r') => {
                        s.push('\n');
                        line += 1;
                        i += if c.get(i + 1) == Some(&'\n') { 2 } else { 1 };
                    }
                    Some('\n') => {
                        s.push('\n');
                        line += 1;
                        i += 1;
                    }
                    Some('\\') => {
                        match c.get(i + 1) {
                            Some('"') => s.push('"'),
                            Some('\\') => s.push('\\'),
                            Some('n') => s.push('\n'),
                            Some('u') => {
                                let hex: String = c.iter().skip(i + 2).take(4).collect();
                                let cp = u32::from_str_radix(&hex, 16)
                                    .ok()
                                    .filter(|_| hex.len() == 4)
                                    .and_then(char::from_u32);
                                match cp {
                                    Some(v) => s.push(v),
                                    None => {
                                        return err(line, format!("bad unicode escape '\\u{hex}'"))
                                    }
                                }
                                i += 4;
                            }
                            Some(o) => {
                                return err(
                                    line,
                                    format!(
                                        "unknown escape '\\{o}' in a string (use \\\", \\\\, \\n \
                                         or \\uXXXX)"
                                    ),
                                )
                            }
                            None => return err(line, "a string is not closed (missing '\"')"),
                        }
                        i += 2;
                    }
                    Some(&o) => {
                        s.push(o);
                        i += 1;
                    }
                }
            }
            out.push((Token::Str(s), line));
        } else if "{}[]<>=|".contains(ch) {
            out.push((Token::Punct(ch), line));
            i += 1;
        } else {
            return err(line, format!("unexpected character '{ch}'"));
        }
    }
    Ok(out)
}

struct Cursor {
    toks: Vec<(Token, usize)>,
    at: usize,
    last_line: usize,
}

impl Cursor {
    fn peek(&self) -> Option<&Token> {
        self.toks.get(self.at).map(|(t, _)| t)
    }
    fn line(&self) -> usize {
        self.toks.get(self.at).map_or(self.last_line, |(_, l)| *l)
    }
    fn next(&mut self) -> Option<Token> {
        let t = self.toks.get(self.at).map(|(t, _)| t.clone());
        if t.is_some() {
            self.at += 1;
        }
        t
    }

    fn value(&mut self) -> Result<Value, ParseError> {
        let line = self.line();
        match self.next() {
            Some(Token::Number(v)) => Ok(Value::Number(v)),
            Some(Token::Str(s)) => Ok(Value::Str(s)),
            Some(Token::Name(n)) if n == "true" => Ok(Value::Bool(true)),
            Some(Token::Name(n)) if n == "false" => Ok(Value::Bool(false)),
            Some(Token::Name(n)) => err(
                line,
                format!("'{n}' is not a value (quote strings; booleans are true or false)"),
            ),
            Some(Token::Punct('[')) => {
                let mut v = Vec::new();
                loop {
                    match self.peek() {
                        Some(Token::Punct(']')) => {
                            self.next();
                            return Ok(Value::Array(v));
                        }
                        None => return err(line, "an array '[' is not closed (missing ']')"),
                        _ => v.push(self.value()?),
                    }
                }
            }
            Some(Token::Punct('{')) => {
                let mut e = Vec::new();
                loop {
                    let kline = self.line();
                    match self.next() {
                        Some(Token::Punct('}')) => return Ok(Value::Group(e)),
                        None => return err(line, "a group '{' is not closed (missing '}')"),
                        Some(Token::Name(k)) => {
                            let mut units = Vec::new();
                            if self.peek() == Some(&Token::Punct('<')) {
                                self.next();
                                loop {
                                    match self.next() {
                                        Some(Token::Punct('>')) => break,
                                        Some(Token::Name(u)) => units.push(u),
                                        _ => {
                                            return err(
                                                kline,
                                                format!("bad units after '{k}': expected <name>"),
                                            )
                                        }
                                    }
                                }
                            }
                            if self.peek().is_none() || self.peek() == Some(&Token::Punct('}')) {
                                return err(kline, format!("'{k}' has no value"));
                            }
                            let v = self.value()?;
                            e.push((k, units, v));
                        }
                        Some(t) => {
                            return err(
                                kline,
                                format!("expected a key name in a group, found {}", show(&t)),
                            )
                        }
                    }
                }
            }
            Some(t) => err(line, format!("expected a value, found {}", show(&t))),
            None => err(line, "expected a value, found the end of the file"),
        }
    }
}

fn show(t: &Token) -> String {
    match t {
        Token::Name(n) => format!("the name '{n}'"),
        Token::Str(s) => format!("the string \"{s}\""),
        Token::Number(v) => format!("the number {v}"),
        Token::Punct(c) => format!("'{c}'"),
    }
}

fn cursor(src: &str) -> Result<Cursor, ParseError> {
    let toks = tokenize(src)?;
    let last_line = toks.last().map_or(1, |(_, l)| *l);
    Ok(Cursor {
        toks,
        at: 0,
        last_line,
    })
}

/// What a catalog item does when an item of its name exists (`solarsys.cpp`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Disposition {
    Add,
    Replace,
    Modify,
}

/// One item of a `.ssc` catalog.
#[derive(Clone, Debug, PartialEq)]
pub struct Item {
    pub disposition: Disposition,
    /// `Body` when the file names none.
    pub item_type: String,
    /// The name list (names separated by `:`).
    pub name: String,
    pub parent: String,
    /// The item's group (a [`Value::Group`]).
    pub body: Value,
    pub line: usize,
}

/// Parse a `.ssc` catalog.
pub fn parse_ssc(src: &str) -> Result<Vec<Item>, ParseError> {
    let mut c = cursor(src)?;
    let mut items = Vec::new();
    while c.peek().is_some() {
        let line = c.line();
        let mut disposition = Disposition::Add;
        if let Some(Token::Name(n)) = c.peek() {
            let d = match n.as_str() {
                "Add" => Some(Disposition::Add),
                "Replace" => Some(Disposition::Replace),
                "Modify" => Some(Disposition::Modify),
                _ => None,
            };
            if let Some(d) = d {
                disposition = d;
                c.next();
            }
        }
        let mut item_type = "Body".to_string();
        if let Some(Token::Name(n)) = c.peek() {
            item_type = n.clone();
            c.next();
        }
        let name_line = c.line();
        let name = match c.next() {
            Some(Token::Str(s)) => s,
            Some(t) => {
                return err(
                    name_line,
                    format!("object name expected (a quoted string), found {}", show(&t)),
                )
            }
            None => return err(line, "object name expected, found the end of the file"),
        };
        let parent_line = c.line();
        let parent = match c.next() {
            Some(Token::Str(s)) => s,
            Some(t) => {
                return err(
                    parent_line,
                    format!(
                        "parent name expected after \"{name}\" (a quoted string such as \
                         \"Sol/Earth\"), found {}",
                        show(&t)
                    ),
                )
            }
            None => {
                return err(
                    parent_line,
                    format!("parent name expected after \"{name}\""),
                )
            }
        };
        if c.peek() != Some(&Token::Punct('{')) {
            return err(
                c.line(),
                format!("'{{' expected after \"{name}\" \"{parent}\""),
            );
        }
        let body = c.value()?;
        items.push(Item {
            disposition,
            item_type,
            name,
            parent,
            body,
            line,
        });
    }
    Ok(items)
}

/// A `.ctx` virtual texture description, with the rules `virtualtex.cpp` applies.
#[derive(Clone, Debug, PartialEq)]
pub struct VirtualTexture {
    pub image_directory: String,
    pub base_split: u32,
    pub tile_size: u32,
    /// `dds` when the file names none.
    pub tile_type: String,
    /// `tx_` when the file names none.
    pub tile_prefix: String,
}

/// Parse a `.ctx` file: `VirtualTexture { ImageDirectory "…" BaseSplit n TileSize n
/// [TileType "…"] [TilePrefix "…"] }`, checked as Celestia checks it.
pub fn parse_ctx(src: &str) -> Result<VirtualTexture, ParseError> {
    let mut c = cursor(src)?;
    let line = c.line();
    match c.next() {
        Some(Token::Name(n)) if n == "VirtualTexture" => {}
        Some(t) => {
            return err(
                line,
                format!(
                    "a virtual texture starts with VirtualTexture, not {}",
                    show(&t)
                ),
            )
        }
        None => {
            return err(
                line,
                "empty file: a virtual texture starts with VirtualTexture",
            )
        }
    }
    if c.peek() != Some(&Token::Punct('{')) {
        return err(c.line(), "'{' expected after VirtualTexture");
    }
    let g = c.value()?;
    if let Some(t) = c.peek() {
        return err(
            c.line(),
            format!("{} after the virtual texture's group", show(t)),
        );
    }
    let image_directory = g
        .get_str("ImageDirectory")
        .ok_or_else(|| ParseError {
            line,
            msg: "ImageDirectory (a string) is missing".into(),
        })?
        .to_string();
    let base_split = match g.get_number("BaseSplit") {
        Some(b) if b >= 0.0 && b == b.floor() && b <= 17.0 => b as u32,
        Some(b) => return err(line, format!("BaseSplit {b} must be a whole number 0..17")),
        None => return err(line, "BaseSplit (a number) is missing"),
    };
    let tile_size = match g.get_number("TileSize") {
        Some(t)
            if t == t.floor()
                && (64.0..=f64::from(i32::MAX >> (base_split + 1))).contains(&t)
                && (t as u64).is_power_of_two() =>
        {
            t as u32
        }
        Some(t) => {
            return err(
                line,
                format!("TileSize {t} must be a power of two, at least 64"),
            )
        }
        None => return err(line, "TileSize (a number) is missing"),
    };
    Ok(VirtualTexture {
        image_directory,
        base_split,
        tile_size,
        tile_type: g.get_str("TileType").unwrap_or("dds").to_string(),
        tile_prefix: g.get_str("TilePrefix").unwrap_or("tx_").to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_hand_written_catalog() {
        let src = r#"
# A comment, then a body changed in place.
Modify "Moon:Earth I" "Sol/Earth"
{
    Texture "moon.ctx"   # trailing comment
    NormalMap "moon-normal.ctx"
    Radius <km> 1737.53
    Color [ 0.5 .5 -1e-3 ]
    Clickable true
    Note "a \"quoted\" word\u00e9
on two lines"
}
AltSurface "limb" "Sol/Earth/Moon" { Texture "x.png" }
"A" "Sol" { }
"#;
        let items = parse_ssc(src).unwrap();
        assert_eq!(items.len(), 3);
        let m = &items[0];
        assert_eq!(m.disposition, Disposition::Modify);
        assert_eq!(m.item_type, "Body");
        assert_eq!(
            (m.name.as_str(), m.parent.as_str()),
            ("Moon:Earth I", "Sol/Earth")
        );
        assert_eq!(m.line, 3);
        assert_eq!(m.body.get_str("Texture"), Some("moon.ctx"));
        assert_eq!(m.body.get_number("Radius"), Some(1737.53));
        assert_eq!(
            m.body.get("Color"),
            Some(&Value::Array(vec![
                Value::Number(0.5),
                Value::Number(0.5),
                Value::Number(-1e-3)
            ]))
        );
        assert_eq!(m.body.get("Clickable"), Some(&Value::Bool(true)));
        assert_eq!(
            m.body.get_str("Note"),
            Some("a \"quoted\" wordé\non two lines")
        );
        if let Value::Group(e) = &m.body {
            assert_eq!(e[2].1, vec!["km".to_string()]);
        }
        assert_eq!(
            (items[1].item_type.as_str(), items[1].line),
            ("AltSurface", 13)
        );
        assert_eq!(items[1].disposition, Disposition::Add);
        assert_eq!(items[2].item_type, "Body");
    }

    #[test]
    fn refuses_bad_input_with_the_line_and_what_is_wrong() {
        let bad = [
            (
                "Modify \"Moon\" \"Sol/Earth\" {\n Texture \"a.ctx\"\n",
                1,
                "not closed",
            ),
            ("Modify \"Moon\"\n{ }", 2, "parent name expected"),
            // A bare name is read as the item type (as Celestia does): "Sol" is then the name.
            (
                "Modify Moon \"Sol\" { }",
                1,
                "parent name expected after \"Sol\"",
            ),
            ("Modify Body Moon \"Sol\" { }", 1, "object name expected"),
            ("\"Moon\" \"Sol\" {\n Texture moon }", 2, "not a value"),
            (
                "\"Moon\" \"Sol\" {\n Texture moon.png }",
                2,
                "unexpected character",
            ),
            (
                "\"Moon\" \"Sol\" { Texture \"a }\n\n",
                1,
                "string is not closed",
            ),
            ("\"Moon\" \"Sol\" { 12 \"x\" }", 1, "expected a key name"),
            ("\"Moon\" \"Sol\" { Radius }", 1, "has no value"),
            ("\"Moon\" \"Sol\" { Radius 1.5e }", 1, "exponent"),
            (
                "\"Moon\" \"Sol\" { Radius 12km }",
                1,
                "neither a number nor a name",
            ),
            (
                "\"Moon\" \"Sol\" { Texture \"a\\qb\" }",
                1,
                "unknown escape",
            ),
            ("\"Moon\" \"Sol\" Texture", 1, "'{' expected"),
            ("\"Moon\" \"Sol\" { Radius 1 } @", 1, "unexpected character"),
        ];
        for (src, line, what) in bad {
            let e = parse_ssc(src).expect_err(src);
            assert_eq!(e.line, line, "{src}: {e}");
            assert!(e.msg.contains(what), "{src}: {e}");
        }
    }

    #[test]
    fn reads_and_checks_virtual_textures() {
        let vt = parse_ctx(
            "VirtualTexture\n{\n ImageDirectory \"moon\"\n BaseSplit 0\n TileSize 512\n \
             TileType \"png\"\n}\n",
        )
        .unwrap();
        assert_eq!(
            vt,
            VirtualTexture {
                image_directory: "moon".into(),
                base_split: 0,
                tile_size: 512,
                tile_type: "png".into(),
                tile_prefix: "tx_".into(),
            }
        );
        let defaults =
            parse_ctx("VirtualTexture { ImageDirectory \"d\" BaseSplit 1 TileSize 64 }").unwrap();
        assert_eq!(
            (defaults.tile_type.as_str(), defaults.tile_prefix.as_str()),
            ("dds", "tx_")
        );
        for (src, what) in [
            ("Texture { }", "starts with VirtualTexture"),
            ("", "empty file"),
            (
                "VirtualTexture { BaseSplit 0 TileSize 512 }",
                "ImageDirectory",
            ),
            (
                "VirtualTexture { ImageDirectory \"d\" TileSize 512 }",
                "BaseSplit",
            ),
            (
                "VirtualTexture { ImageDirectory \"d\" BaseSplit 0.5 TileSize 512 }",
                "BaseSplit",
            ),
            (
                "VirtualTexture { ImageDirectory \"d\" BaseSplit 0 TileSize 500 }",
                "power of two",
            ),
            (
                "VirtualTexture { ImageDirectory \"d\" BaseSplit 0 TileSize 32 }",
                "power of two",
            ),
            (
                "VirtualTexture { ImageDirectory \"d\" BaseSplit 0 }",
                "TileSize",
            ),
            (
                "VirtualTexture { ImageDirectory \"d\" BaseSplit 0 TileSize 64 } x",
                "after",
            ),
        ] {
            let e = parse_ctx(src).expect_err(src);
            assert!(e.msg.contains(what), "{src}: {e}");
        }
    }
}
