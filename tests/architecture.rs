//! The layering rules of docs/architecture.md, checked on the source itself:
//!
//! - **No import circle between files** of any crate in the workspace (the library, the CLI,
//!   the benchmarks, the viewer, the GPU sweep, this test binary). An edge `a.rs → b.rs` is any path in `a.rs`
//!   (a `use` or an inline `crate::…`/`super::…`/`self::…`/child-module path, test modules
//!   included) that names an item defined in `b.rs`; a path through a re-export (`pub use`) is
//!   followed to the file that defines the item, and the re-export itself is an edge of the
//!   file that makes it. Declaring a child module (`mod x;`) is not an edge.
//! - **Product files are read and written in the formats layer and the store only**: no file of
//!   the library outside `src/format/`, `src/tileset/` and the codecs below them names the EXR
//!   codec, the PNG encoder or the atomic-write helpers.
//!
//! The scanner is a small Rust lexer (comments, strings, raw strings, chars and lifetimes) and
//! a `use`-tree parser: enough for this code base, which uses no macros that expand to paths
//! and one `#[path]` attribute form.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    Str(String),
    Punct(char),
    PathSep,
}

/// Tokens of a Rust source, without comments; string literals keep their text.
fn lex(src: &str) -> Vec<Tok> {
    let b: Vec<char> = src.chars().collect();
    let (mut i, mut out) = (0, Vec::new());
    while i < b.len() {
        let c = b[i];
        if c == '/' && b.get(i + 1) == Some(&'/') {
            while i < b.len() && b[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && b.get(i + 1) == Some(&'*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == '/' && b.get(i + 1) == Some(&'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == '*' && b.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if c == 'r' && matches!(b.get(i + 1), Some('#') | Some('"')) && {
            // Raw string r"…", r#"…"#.
            let mut j = i + 1;
            while b.get(j) == Some(&'#') {
                j += 1;
            }
            b.get(j) == Some(&'"')
        } {
            let mut j = i + 1;
            let mut hashes = 0;
            while b[j] == '#' {
                hashes += 1;
                j += 1;
            }
            j += 1;
            let start = j;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == '"' && (0..hashes).all(|k| b.get(j + 1 + k) == Some(&'#')) {
                    break;
                }
                j += 1;
            }
            out.push(Tok::Str(b[start..j.min(b.len())].iter().collect()));
            i = j + 1 + hashes;
        } else if c == '"' {
            let mut j = i + 1;
            let mut s = String::new();
            while j < b.len() && b[j] != '"' {
                if b[j] == '\\' {
                    j += 1;
                }
                if j < b.len() {
                    s.push(b[j]);
                }
                j += 1;
            }
            out.push(Tok::Str(s));
            i = j + 1;
        } else if c == '\'' {
            // A char literal ('x', '\n', '\u{..}') or a lifetime ('a).
            if b.get(i + 1) == Some(&'\\') {
                let mut j = i + 2;
                while j < b.len() && b[j] != '\'' {
                    j += 1;
                }
                i = j + 1;
            } else if b.get(i + 2) == Some(&'\'') {
                i += 3;
            } else {
                i += 1;
                while i < b.len() && (b[i].is_alphanumeric() || b[i] == '_') {
                    i += 1;
                }
            }
        } else if c.is_alphabetic() || c == '_' {
            let start = i;
            while i < b.len() && (b[i].is_alphanumeric() || b[i] == '_') {
                i += 1;
            }
            let w: String = b[start..i].iter().collect();
            // Byte strings and raw byte strings: b"…", br"…" are lexed as their string.
            if (w == "b" || w == "br") && matches!(b.get(i), Some('"') | Some('#')) {
                if w == "br" {
                    // Leave i at '#'/'"' and let the raw-string branch see an 'r'.
                    i -= 1;
                }
                continue;
            }
            out.push(Tok::Ident(w));
        } else if c.is_ascii_digit() {
            while i < b.len() && (b[i].is_alphanumeric() || b[i] == '_' || b[i] == '.') {
                if b[i] == '.' && !b.get(i + 1).is_some_and(|d| d.is_ascii_digit()) {
                    break;
                }
                i += 1;
            }
        } else if c == ':' && b.get(i + 1) == Some(&':') {
            out.push(Tok::PathSep);
            i += 2;
        } else {
            if !c.is_whitespace() {
                out.push(Tok::Punct(c));
            }
            i += 1;
        }
    }
    out
}

/// A module path inside a crate (`["horizon", "stage"]`).
type ModPath = Vec<String>;

/// What one file says.
#[derive(Default)]
struct FileFacts {
    /// Child modules declared with `mod x;` (name, file).
    children: Vec<(String, PathBuf)>,
    /// Paths this file uses, each with the module it is written in (inline modules included).
    uses: Vec<(ModPath, Vec<String>)>,
    /// `pub use` re-exports at file level: name → absolute path.
    reexports: HashMap<String, (ModPath, Vec<String>)>,
    /// `pub use path::*` at file level.
    globs: Vec<(ModPath, Vec<String>)>,
    /// Names of items defined in the file.
    defines: BTreeSet<String>,
}

/// Parse a use tree starting at `toks[*i]`; appends every full path (a trailing `*` is kept as
/// a segment).
fn use_tree(toks: &[Tok], i: &mut usize, prefix: &[String], out: &mut Vec<Vec<String>>) {
    let mut path = prefix.to_vec();
    loop {
        match toks.get(*i) {
            Some(Tok::Ident(w)) => {
                path.push(w.clone());
                *i += 1;
                if toks.get(*i) == Some(&Tok::Ident("as".into())) {
                    *i += 2;
                }
            }
            Some(Tok::Punct('*')) => {
                path.push("*".into());
                *i += 1;
            }
            Some(Tok::Punct('{')) => {
                *i += 1;
                loop {
                    match toks.get(*i) {
                        Some(Tok::Punct('}')) => {
                            *i += 1;
                            return;
                        }
                        Some(Tok::Punct(',')) => *i += 1,
                        None => return,
                        _ => use_tree(toks, i, &path, out),
                    }
                }
            }
            _ => {
                if path.len() > prefix.len() {
                    out.push(path);
                }
                return;
            }
        }
        if toks.get(*i) == Some(&Tok::PathSep) {
            *i += 1;
        } else {
            out.push(path);
            return;
        }
    }
}

/// The `#[path = "…"]` among the attributes of the `mod` item at `toks[i]` (past its
/// visibility and any other attributes).
fn path_attribute(toks: &[Tok], i: usize) -> Option<String> {
    let mut j = i;
    while j > 0
        && match &toks[j - 1] {
            Tok::Ident(w) => matches!(w.as_str(), "pub" | "crate" | "super" | "self" | "in"),
            Tok::Punct(c) => matches!(c, '(' | ')'),
            _ => false,
        }
    {
        j -= 1;
    }
    let mut found = None;
    while j >= 2 && toks[j - 1] == Tok::Punct(']') {
        // Back to the attribute's `#[`.
        let mut k = j - 1;
        let mut depth = 0i32;
        loop {
            match toks[k] {
                Tok::Punct(']') => depth += 1,
                Tok::Punct('[') => {
                    depth -= 1;
                    if depth == 0 {
                        break;
                    }
                }
                _ => {}
            }
            if k == 0 {
                return found;
            }
            k -= 1;
        }
        if let [Tok::Ident(p), Tok::Punct('='), Tok::Str(s)] = &toks[k + 1..j - 1] {
            if p == "path" {
                found = Some(s.clone());
            }
        }
        if k == 0 || toks[k - 1] != Tok::Punct('#') {
            return found;
        }
        j = k - 1;
    }
    found
}

fn scan(path: &Path, module: &ModPath) -> FileFacts {
    let src = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let toks = lex(&src);
    let dir = path.parent().unwrap();
    let is_root_like = matches!(
        path.file_name().and_then(|n| n.to_str()),
        Some("mod.rs" | "lib.rs" | "main.rs" | "tests.rs")
    );
    // Where `mod x;` of this file looks for x.rs.
    let child_dir = if is_root_like {
        dir.to_path_buf()
    } else {
        dir.join(path.file_stem().unwrap())
    };
    let mut f = FileFacts::default();
    // Inline modules: (module path, brace depth at which it closes).
    let mut inline: Vec<(ModPath, usize)> = Vec::new();
    let mut depth = 0usize;
    let mut i = 0;
    let current = |inline: &Vec<(ModPath, usize)>| -> ModPath {
        inline.last().map_or(module.clone(), |m| m.0.clone())
    };
    while i < toks.len() {
        match &toks[i] {
            Tok::Punct('{') => {
                depth += 1;
                i += 1;
            }
            Tok::Punct('}') => {
                if inline.last().is_some_and(|m| m.1 == depth) {
                    inline.pop();
                }
                depth = depth.saturating_sub(1);
                i += 1;
            }
            Tok::Ident(w) if w == "mod" => {
                let Some(Tok::Ident(name)) = toks.get(i + 1) else {
                    i += 1;
                    continue;
                };
                match toks.get(i + 2) {
                    Some(Tok::Punct(';')) => {
                        let attr = path_attribute(&toks, i);
                        let file = match attr {
                            Some(s) => dir.join(s),
                            None if child_dir.join(format!("{name}.rs")).exists() => {
                                child_dir.join(format!("{name}.rs"))
                            }
                            None => child_dir.join(name).join("mod.rs"),
                        };
                        if inline.is_empty() {
                            f.children.push((name.clone(), file));
                        }
                        i += 3;
                    }
                    Some(Tok::Punct('{')) => {
                        let mut m = current(&inline);
                        m.push(name.clone());
                        depth += 1;
                        inline.push((m, depth));
                        i += 3;
                    }
                    _ => i += 1,
                }
            }
            Tok::Ident(w) if w == "use" => {
                let public = i >= 1
                    && (toks[i - 1] == Tok::Ident("pub".into())
                        || (i >= 4 && toks[i - 4] == Tok::Ident("pub".into()))
                        || (i >= 6 && toks[i - 6] == Tok::Ident("pub".into())));
                i += 1;
                let mut paths = Vec::new();
                use_tree(&toks, &mut i, &[], &mut paths);
                let here = current(&inline);
                for p in paths {
                    if public && inline.is_empty() {
                        if p.last().map(String::as_str) == Some("*") {
                            f.globs.push((here.clone(), p[..p.len() - 1].to_vec()));
                        } else if let Some(name) = p.last() {
                            f.reexports.insert(name.clone(), (here.clone(), p.clone()));
                        }
                    }
                    f.uses.push((here.clone(), p));
                }
            }
            Tok::Ident(w)
                if matches!(
                    w.as_str(),
                    "fn" | "struct" | "enum" | "const" | "static" | "type" | "trait" | "union"
                ) =>
            {
                if let Some(Tok::Ident(name)) = toks.get(i + 1) {
                    if inline.is_empty() {
                        f.defines.insert(name.clone());
                    }
                }
                i += 1;
            }
            Tok::Ident(w) if toks.get(i + 1) == Some(&Tok::PathSep) => {
                // An inline path a::b::c (not preceded by `::`, and not the module of a
                // `pub(in a::b)` visibility).
                if i > 0 && (toks[i - 1] == Tok::PathSep || toks[i - 1] == Tok::Ident("in".into()))
                {
                    i += 1;
                    continue;
                }
                let mut p = vec![w.clone()];
                let mut j = i + 1;
                while toks.get(j) == Some(&Tok::PathSep) {
                    match toks.get(j + 1) {
                        Some(Tok::Ident(s)) => {
                            p.push(s.clone());
                            j += 2;
                        }
                        _ => break,
                    }
                }
                f.uses.push((current(&inline), p));
                i = j;
            }
            _ => i += 1,
        }
    }
    f
}

/// A crate's files by module path.
struct Crate {
    files: BTreeMap<ModPath, PathBuf>,
    facts: BTreeMap<ModPath, FileFacts>,
}

fn load_crate(root: &Path) -> Crate {
    let mut c = Crate {
        files: BTreeMap::new(),
        facts: BTreeMap::new(),
    };
    let mut todo = vec![(Vec::new(), root.to_path_buf())];
    while let Some((m, p)) = todo.pop() {
        let facts = scan(&p, &m);
        for (name, file) in &facts.children {
            let mut cm = m.clone();
            cm.push(name.clone());
            todo.push((cm, file.clone()));
        }
        c.files.insert(m.clone(), p);
        c.facts.insert(m, facts);
    }
    c
}

impl Crate {
    /// The file that defines what `path` (written in module `at`) names, following re-exports.
    fn resolve(&self, at: &ModPath, path: &[String], hops: usize) -> Option<ModPath> {
        let (mut base, rest): (ModPath, &[String]) = match path.first().map(String::as_str) {
            Some("crate") => (Vec::new(), &path[1..]),
            Some("self") => (at.clone(), &path[1..]),
            Some("super") => {
                let mut b = at.clone();
                let mut k = 0;
                while path.get(k).map(String::as_str) == Some("super") {
                    b.pop();
                    k += 1;
                }
                (b, &path[k..])
            }
            Some(first) => {
                // A child module of the module it is written in (or of an enclosing file).
                let mut m = at.clone();
                m.push(first.to_string());
                if !self.files.contains_key(&m) {
                    return None;
                }
                (at.clone(), path)
            }
            None => return None,
        };
        // The file module containing `base` (inline modules live in their file).
        while !self.files.contains_key(&base) {
            base.pop();
        }
        let mut file = base.clone();
        let mut k = 0;
        while k < rest.len() {
            let mut next = file.clone();
            next.push(rest[k].clone());
            if self.files.contains_key(&next) {
                file = next;
                k += 1;
            } else {
                break;
            }
        }
        if hops < 16 {
            if let Some(name) = rest.get(k) {
                let facts = &self.facts[&file];
                if !facts.defines.contains(name) {
                    if let Some((from, target)) = facts.reexports.get(name) {
                        let mut t = target.clone();
                        t.extend_from_slice(&rest[k + 1..]);
                        if let Some(r) = self.resolve(from, &t, hops + 1) {
                            return Some(r);
                        }
                    }
                    for (from, glob) in &facts.globs {
                        let mut t = glob.clone();
                        t.extend_from_slice(&rest[k..]);
                        if let Some(r) = self.resolve(from, &t, hops + 1) {
                            if r != file && self.facts[&r].defines.contains(name) {
                                return Some(r);
                            }
                        }
                    }
                }
            }
        }
        Some(file)
    }

    fn edges(&self) -> BTreeMap<ModPath, BTreeSet<ModPath>> {
        let mut e: BTreeMap<ModPath, BTreeSet<ModPath>> = BTreeMap::new();
        for (m, facts) in &self.facts {
            let set = e.entry(m.clone()).or_default();
            for (at, p) in &facts.uses {
                if let Some(t) = self.resolve(at, p, 0) {
                    if &t != m {
                        set.insert(t);
                    }
                }
            }
        }
        e
    }
}

/// Strongly connected components of more than one file (Tarjan).
fn cycles(e: &BTreeMap<ModPath, BTreeSet<ModPath>>) -> Vec<Vec<ModPath>> {
    struct S<'a> {
        e: &'a BTreeMap<ModPath, BTreeSet<ModPath>>,
        idx: HashMap<&'a ModPath, usize>,
        low: HashMap<&'a ModPath, usize>,
        stack: Vec<&'a ModPath>,
        on: BTreeSet<&'a ModPath>,
        out: Vec<Vec<ModPath>>,
    }
    fn visit<'a>(s: &mut S<'a>, v: &'a ModPath) {
        let n = s.idx.len();
        s.idx.insert(v, n);
        s.low.insert(v, n);
        s.stack.push(v);
        s.on.insert(v);
        for w in s.e.get(v).into_iter().flatten() {
            if !s.idx.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.on.contains(w) {
                let iw = s.idx[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.idx[v] {
            let mut comp = Vec::new();
            loop {
                let w = s.stack.pop().unwrap();
                s.on.remove(w);
                comp.push(w.clone());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                s.out.push(comp);
            }
        }
    }
    let mut s = S {
        e,
        idx: HashMap::new(),
        low: HashMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in e.keys() {
        if !s.idx.contains_key(v) {
            visit(&mut s, v);
        }
    }
    s.out
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The crate roots of the workspace.
const ROOTS: &[&str] = &[
    "src/lib.rs",
    "tools/penumbra/lib.rs",
    "tools/penumbra/main.rs",
    "tools/bench/main.rs",
    "tools/viewer/src/lib.rs",
    "tools/viewer/src/main.rs",
    "tools/gpu/src/lib.rs",
    "tools/gpu/tests/gpu.rs",
    "tests/tests.rs",
];

fn describe(c: &Crate, comp: &[ModPath], e: &BTreeMap<ModPath, BTreeSet<ModPath>>) -> String {
    let name = |m: &ModPath| {
        c.files[m]
            .strip_prefix(repo())
            .unwrap_or(&c.files[m])
            .display()
            .to_string()
    };
    let mut s = String::new();
    for a in comp {
        for b in &e[a] {
            if comp.contains(b) {
                s += &format!("    {} -> {}\n", name(a), name(b));
            }
        }
    }
    s
}

#[test]
fn no_file_level_import_cycle() {
    let mut report = String::new();
    let mut files = 0;
    for root in ROOTS {
        let c = load_crate(&repo().join(root));
        files += c.files.len();
        let e = c.edges();
        for comp in cycles(&e) {
            report += &format!("cycle in the crate of {root}:\n{}", describe(&c, &comp, &e));
        }
    }
    assert!(
        files > 100,
        "found only {files} files: is the scanner broken?"
    );
    assert!(report.is_empty(), "{report}");
}

#[test]
fn the_checker_sees_a_cycle() {
    // A crate of three files in which a.rs and b.rs use each other through a re-export.
    let d = tempfile::tempdir().unwrap();
    let w = |p: &str, s: &str| std::fs::write(d.path().join(p), s).unwrap();
    w("lib.rs", "mod a;\nmod b;\npub use b::Thing;\n");
    w(
        "a.rs",
        "use crate::Thing; // through lib.rs's re-export\npub fn f() {}\n",
    );
    w("b.rs", "pub struct Thing;\nfn g() { crate::a::f() }\n");
    let c = load_crate(&d.path().join("lib.rs"));
    let e = c.edges();
    let found = cycles(&e);
    assert_eq!(found.len(), 1, "{e:?}");
    assert_eq!(found[0].len(), 2);
    // The same without b's call back: no cycle (lib.rs → b.rs by its re-export only).
    w(
        "b.rs",
        "pub struct Thing;\n/* crate::a::f() */ const S: &str = \"crate::a::f\";\n",
    );
    let c = load_crate(&d.path().join("lib.rs"));
    assert!(cycles(&c.edges()).is_empty());
    // A module behind `#[path]` (after other attributes and a visibility), whose item is
    // visible `pub(in crate::b)`: no edge from the visibility, one from its use of a.rs.
    w(
        "b.rs",
        "pub struct Thing;\n#[cfg(all())]\n#[path = \"b_impl.rs\"]\npub(crate) mod imp;\n",
    );
    w("b_impl.rs", "pub(in crate::b) fn h() { crate::a::f() }\n");
    let c = load_crate(&d.path().join("lib.rs"));
    assert!(c
        .files
        .contains_key(&vec!["b".to_string(), "imp".to_string()]));
    let e = c.edges();
    assert!(cycles(&e).is_empty(), "{e:?}");
    assert!(e[&vec!["b".to_string(), "imp".to_string()]].contains(&vec!["a".to_string()]));
}

/// What names product-file I/O: the EXR codec, the PNG encoder, the staged/atomic writers and
/// capped reads.
const IO_NAMES: &[&str] = &[
    "exrcodec",
    "image",
    "write_staged",
    "write_atomic",
    "write_atomic_bytes",
    "read_capped",
    "read_product_file",
    "open_regular",
];

#[test]
fn product_files_are_read_and_written_by_the_formats_layer_and_the_store_only() {
    let c = load_crate(&repo().join("src/lib.rs"));
    // Where product I/O may live, and the leaves it is built from (the codecs, the atomic
    // writes); the DEM readers, the manifest and the camera paths of `region` read their own
    // inputs, not products.
    let allowed = |m: &ModPath| {
        matches!(
            m.first().map(String::as_str),
            Some(
                "format"
                    | "tileset"
                    | "exrcodec"
                    | "fsio"
                    | "dem"
                    | "manifest"
                    | "albedo"
                    | "region"
            )
        )
    };
    let mut bad = Vec::new();
    for (m, facts) in &c.facts {
        if allowed(m) || m.is_empty() {
            continue;
        }
        for (_, p) in &facts.uses {
            if p.iter().any(|s| IO_NAMES.contains(&s.as_str())) {
                bad.push(format!("{}: {}", c.files[m].display(), p.join("::")));
            }
        }
    }
    assert!(
        bad.is_empty(),
        "product I/O outside the formats layer and the store:\n{}",
        bad.join("\n")
    );
}
