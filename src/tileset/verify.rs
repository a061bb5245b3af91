//! `penumbra verify`: every file of a tileset against its product's index (present, a regular
//! file inside the tileset, the recorded size, the recorded blake3) and against its identity
//! (the product, tile and run it says it is, compared with what its path and the manifest say
//! it must be) and the manifest's labels (what its header says it holds: channels and sample
//! types, the Fourier encoding, layout, sigma and coefficients, the albedo bit depth and
//! channels), and every tile the coverage lists against the index. Nothing is written; each
//! file is read once, whole, bounded by its recorded size, files in parallel.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use super::index::Index;
use super::{fsio, Product, Store};
use crate::cube::Face;
use crate::error::Result;
use crate::format::{self, Identity};
use crate::layout::TileId;
use crate::manifest::Tileset;

/// One thing wrong with one file.
#[derive(Clone, Debug, Serialize, PartialEq, Eq, PartialOrd, Ord)]
pub struct Finding {
    /// The file, relative to the tileset (`/`-separated).
    pub path: String,
    /// The product whose index lists it (or whose coverage expects it).
    pub product: String,
    /// What kind of problem: `missing`, `not-a-file`, `outside-link`, `size`, `hash`,
    /// `identity`, `label`, `unreadable`, `unlisted`, `no-index`, `pruned` (the index lists
    /// horizon maps of a tile the manifest says the run left out).
    pub problem: String,
    /// What was found and what was expected, in words.
    pub detail: String,
}

/// Per product: what was checked.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ProductSummary {
    pub files: u64,
    pub bytes: u64,
    /// Files whose identity (and labels) were compared (all but unlisted products' files).
    pub identities: u64,
    pub problems: u64,
}

/// The result of [`verify`].
#[derive(Clone, Debug, Serialize)]
pub struct VerifyReport {
    pub dir: String,
    pub files: u64,
    pub bytes: u64,
    pub products: BTreeMap<String, ProductSummary>,
    pub findings: Vec<Finding>,
    pub seconds: f64,
}

impl VerifyReport {
    pub fn clean(&self) -> bool {
        self.findings.is_empty()
    }
}

/// A product's path patterns and the identity name of each.
fn patterns(ts: &Tileset, product: Product) -> Vec<(String, &'static str)> {
    let p = &ts.products;
    match product {
        Product::Height => p
            .height
            .iter()
            .map(|h| (h.path.clone(), format::height::ID))
            .collect(),
        Product::Mip => p
            .mip
            .iter()
            .flat_map(|m| {
                let mut v = vec![
                    (m.max_path.clone(), format::mip::MAX_ID),
                    (m.minmax_path.clone(), format::mip::MINMAX_ID),
                    (m.face_path.clone(), format::mip::FACE_ID),
                ];
                if let Some(c) = &m.face_chunk_path {
                    v.push((c.clone(), format::mip::FACE_CHUNK_ID));
                }
                v
            })
            .collect(),
        Product::Horizon => p
            .horizon
            .iter()
            .map(|h| (h.path.clone(), format::horizon::ID))
            .collect(),
        Product::Fourier => p
            .fourier
            .iter()
            .map(|f| (f.path.clone(), format::fourier::ID))
            .collect(),
        Product::Albedo => p
            .albedo
            .iter()
            .map(|a| (a.path.clone(), format::albedo::ID))
            .collect(),
        Product::Other(_) => Vec::new(),
    }
}

/// The placeholders of `pattern` read from `rel` (one placeholder per path segment at most, as
/// every product's patterns have), or None when `rel` does not follow it.
fn match_pattern(pattern: &str, rel: &str) -> Option<BTreeMap<String, String>> {
    let (ps, rs): (Vec<&str>, Vec<&str>) = (pattern.split('/').collect(), rel.split('/').collect());
    if ps.len() != rs.len() {
        return None;
    }
    let mut out = BTreeMap::new();
    for (p, r) in ps.iter().zip(&rs) {
        match (p.find('{'), p.find('}')) {
            (Some(a), Some(b)) if a < b => {
                let (pre, name, post) = (&p[..a], &p[a + 1..b], &p[b + 1..]);
                let v = r.strip_prefix(pre)?.strip_suffix(post)?;
                if v.is_empty() || v.contains('/') {
                    return None;
                }
                out.insert(name.to_string(), v.to_string());
            }
            _ if p == r => {}
            _ => return None,
        }
    }
    Some(out)
}

/// What the file at `rel` of `product` must say it is, from its path and the manifest; None
/// for files that carry no identity (unlisted products), `Err` (with what is wrong) for one
/// whose path follows no pattern.
fn expected_identity(
    ts: &Tileset,
    product: Product,
    rel: &str,
) -> Option<std::result::Result<Identity, String>> {
    let pats = patterns(ts, product);
    if pats.is_empty() {
        return None;
    }
    let key = product.recorded_key(ts).unwrap_or_default();
    for (pattern, name) in &pats {
        let Some(v) = match_pattern(pattern, rel) else {
            continue;
        };
        let num = |k: &str| v.get(k).and_then(|s| s.parse::<u32>().ok());
        let level = v.get("level").and_then(|s| s.parse::<u8>().ok());
        let face = v
            .get("face")
            .and_then(|f| Face::ALL.iter().copied().find(|x| x.name() == f));
        let (Some(level), Some(face)) = (level, face) else {
            continue;
        };
        let (x, y) = match (num("x"), num("y"), num("cx"), num("cy")) {
            (Some(x), Some(y), _, _) | (_, _, Some(x), Some(y)) => (x, y),
            _ if !pattern.contains("{x}") && !pattern.contains("{cx}") => (0, 0),
            _ => continue,
        };
        return Some(Ok(Identity::face(name, level, face, x, y, key)));
    }
    Some(Err(format!(
        "its path follows none of the manifest's patterns for {} ({})",
        product.name(),
        pats.iter()
            .map(|(p, _)| p.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    )))
}

/// Check one indexed file; its findings (none when it is sound).
fn check_file(
    store: &Store,
    product: Product,
    rel: &str,
    len: u64,
    hash: &[u8; 32],
) -> (Vec<Finding>, bool) {
    let dir = store.dir();
    let path = dir.join(rel);
    let finding = |problem: &str, detail: String| Finding {
        path: rel.to_string(),
        product: product.name().to_string(),
        problem: problem.to_string(),
        detail,
    };
    let what = format!("a file of {}", product.name());
    if let Err(e) = fsio::check_inside(dir, &path) {
        return (vec![finding("outside-link", error_detail(&e))], false);
    }
    let bytes = match fsio::read_product_file(dir, &path, fsio::Expect::Exactly(len), &what) {
        Ok(b) => b,
        Err(e) => {
            let kind = match &e {
                crate::error::Error::Io { source, .. }
                    if source.kind() == std::io::ErrorKind::NotFound =>
                {
                    "missing"
                }
                crate::error::Error::Invalid { msg, .. } if msg.contains("not a regular file") => {
                    "not-a-file"
                }
                crate::error::Error::Invalid { msg, .. } if msg.contains("index recorded") => {
                    "size"
                }
                _ => "unreadable",
            };
            return (vec![finding(kind, error_detail(&e))], false);
        }
    };
    let mut out = Vec::new();
    if blake3::hash(&bytes).as_bytes() != hash {
        out.push(finding(
            "hash",
            "its bytes differ from the blake3 the index recorded: damaged or replaced".into(),
        ));
    }
    let ts = store.manifest();
    let mut compared = false;
    match expected_identity(ts, product, rel) {
        None => {}
        Some(Err(msg)) => out.push(finding("identity", msg)),
        Some(Ok(expected)) => {
            compared = true;
            match header(ts, &expected, &bytes) {
                Err(e) => out.push(finding(
                    "unreadable",
                    format!("its header cannot be read ({e})"),
                )),
                Ok((found, labels)) => {
                    if let Err(msg) = Identity::check(&expected, found) {
                        out.push(finding("identity", msg));
                    } else if let Err(msg) = labels {
                        out.push(finding("label", msg));
                    }
                }
            }
        }
    }
    (out, compared)
}

type Found = Option<std::result::Result<Identity, String>>;

/// The identity a product file's header holds, and its header against the manifest's labels
/// (`Err`: what differs), read from the header alone; `Err` when the header cannot be read.
fn header(
    ts: &Tileset,
    expected: &Identity,
    bytes: &[u8],
) -> std::result::Result<(Found, std::result::Result<(), String>), String> {
    let p = &ts.products;
    let tile = TileId {
        level: expected.level,
        face: expected.face,
        x: expected.x,
        y: expected.y,
    };
    match expected.product.as_str() {
        format::fourier::ID => {
            let found = format::fourier::read_identity(bytes)?;
            let labels = format::fourier::read_labels(bytes)?;
            let check = p
                .fourier
                .as_ref()
                .map_or(Ok(()), |f| format::fourier::check_labels(&labels, f, tile));
            Ok((found, check))
        }
        format::albedo::ID => {
            let facts = format::albedo::read_header(bytes)?;
            let found = format::exr_identity(facts.identity.clone());
            let check = p
                .albedo
                .as_ref()
                .map_or(Ok(()), |a| format::albedo::check_labels(&facts, a));
            Ok((found, check))
        }
        name => {
            let h = crate::exrcodec::read_header(bytes)?;
            let found = format::exr_identity(h.identity);
            let channels = format::exr_channels(h.channels.iter().map(|(n, t)| (n, *t)));
            let labels = match (name, format::mip::MipKind::of_id(name)) {
                (format::height::ID, _) => p.height.as_ref().map(format::height::labels),
                (format::horizon::ID, _) => p.horizon.as_ref().map(format::horizon::labels),
                (_, Some(kind)) => p.mip.as_ref().map(|m| format::mip::labels(m, kind)),
                _ => None,
            };
            let check = labels.map_or(Ok(()), |l| format::check_channels(&channels, &l));
            Ok((found, check))
        }
    }
}

/// An error's message without the path it names (the report lists the path).
fn error_detail(e: &crate::error::Error) -> String {
    match e {
        crate::error::Error::Invalid { msg, .. } => msg.clone(),
        crate::error::Error::Unsupported { msg, .. } => format!("not supported: {msg}"),
        crate::error::Error::Io { source, .. } => source.to_string(),
        other => other.to_string(),
    }
}

/// The files the coverage says `product` must have (relative paths), for the products made
/// per tile.
fn expected_files(ts: &Tileset, product: Product) -> Vec<String> {
    let tiles = ts.tile_set();
    let rel = |pattern: &str, id: TileId| {
        format::tile_path(Path::new(""), pattern, id)
            .to_string_lossy()
            .replace('\\', "/")
    };
    let p = &ts.products;
    let mut out = Vec::new();
    match product {
        Product::Height => {
            if let Some(h) = &p.height {
                out.extend(tiles.iter().map(|&id| rel(&h.path, id)));
            }
        }
        Product::Mip => {
            if let Some(m) = &p.mip {
                for &id in &tiles {
                    out.push(rel(&m.max_path, id));
                    out.push(rel(&m.minmax_path, id));
                }
            }
        }
        Product::Horizon => {
            if let Some(h) = &p.horizon {
                // Tiles the run left out have no file.
                for &id in tiles
                    .iter()
                    .filter(|id| h.levels.contains(&id.level) && h.pruned_tile(**id).is_none())
                {
                    out.push(rel(&h.path, id));
                }
            }
        }
        Product::Fourier => {
            if let Some(f) = &p.fourier {
                for &id in tiles.iter().filter(|id| f.levels.contains(&id.level)) {
                    out.push(rel(&f.path, id));
                }
            }
        }
        Product::Albedo => {
            if let Some(a) = &p.albedo {
                out.extend(tiles.iter().map(|&id| rel(&a.path, id)));
            }
        }
        Product::Other(_) => {}
    }
    out
}

/// Verify every file of the tileset in `dir` (see the module's header). An error only when the
/// tileset cannot be opened at all (no manifest, a damaged one): every problem with a file is
/// a [`Finding`].
pub fn verify(dir: &Path) -> Result<VerifyReport> {
    let t0 = std::time::Instant::now();
    let store = Store::open(dir)?;
    let ts = store.manifest();
    let present: Vec<Product> = Product::ALL
        .into_iter()
        .filter(|&p| p.recorded_key(ts).is_some())
        .collect();
    let mut findings = Vec::new();
    let mut products = BTreeMap::new();
    for product in present {
        let mut sum = ProductSummary::default();
        let index: Option<std::sync::Arc<Index>> = match store.index(product) {
            Ok(ix) => ix,
            Err(e) => {
                findings.push(Finding {
                    path: format!(".penumbra/index/{}.json", product.name()),
                    product: product.name().into(),
                    problem: "no-index".into(),
                    detail: error_detail(&e),
                });
                sum.problems += 1;
                products.insert(product.name().to_string(), sum);
                continue;
            }
        };
        let Some(index) = index else {
            findings.push(Finding {
                path: format!(".penumbra/index/{}.json", product.name()),
                product: product.name().into(),
                problem: "no-index".into(),
                detail: "the manifest lists the product but its index is missing: its files \
                         cannot be checked; rerun the stage that makes it"
                    .into(),
            });
            sum.problems += 1;
            products.insert(product.name().to_string(), sum);
            continue;
        };
        let mut entries: Vec<(&String, &(u64, [u8; 32]))> = index.files.iter().collect();
        entries.sort();
        let results: Vec<(Vec<Finding>, bool)> = entries
            .par_iter()
            .map(|(rel, (len, hash))| check_file(&store, product, rel, *len, hash))
            .collect();
        for ((_, (len, _)), (f, compared)) in entries.iter().zip(results) {
            sum.files += 1;
            sum.bytes += len;
            sum.identities += compared as u64;
            sum.problems += f.len() as u64;
            findings.extend(f);
        }
        // Horizon maps of tiles the manifest lists as left out: the list or the index is wrong.
        if let (Product::Horizon, Some(h)) = (product, &ts.products.horizon) {
            if let Some(pr) = &h.pruned {
                for k in pr.tiles.keys() {
                    let Some(id) = format::horizon::parse_pruned_key(k) else {
                        continue;
                    };
                    let rel = format::tile_path(Path::new(""), &h.path, id)
                        .to_string_lossy()
                        .replace('\\', "/");
                    if index.files.contains_key(&rel) {
                        sum.problems += 1;
                        findings.push(Finding {
                            path: rel,
                            product: product.name().into(),
                            problem: "pruned".into(),
                            detail: format!(
                                "the manifest's `products.horizon.pruned` says the run left tile \
                                 {k} out (no maps), but {} lists its maps: the list or the \
                                 index was edited; rerun the horizon stage",
                                index.path.display()
                            ),
                        });
                    }
                }
            }
        }
        // Tiles the coverage lists that the index does not.
        for rel in expected_files(ts, product) {
            if !index.files.contains_key(&rel) {
                sum.problems += 1;
                findings.push(Finding {
                    path: rel,
                    product: product.name().into(),
                    problem: "unlisted".into(),
                    detail: format!(
                        "the coverage lists this tile but {} does not: the product is \
                         incomplete; rerun the stage that makes it",
                        index.path.display()
                    ),
                });
            }
        }
        products.insert(product.name().to_string(), sum);
    }
    findings.sort();
    let files = products.values().map(|s| s.files).sum();
    let bytes = products.values().map(|s| s.bytes).sum();
    Ok(VerifyReport {
        dir: dir.display().to_string(),
        files,
        bytes,
        products,
        findings,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_match_their_paths_only() {
        let v = match_pattern("height/{level}/{face}/{y}/{x}.exr", "height/3/px/1/2.exr").unwrap();
        assert_eq!(v["level"], "3");
        assert_eq!(v["face"], "px");
        assert_eq!((v["y"].as_str(), v["x"].as_str()), ("1", "2"));
        assert!(
            match_pattern("height/{level}/{face}/{y}/{x}.exr", "height/3/px/1/2.png").is_none()
        );
        assert!(match_pattern("height/{level}/{face}/{y}/{x}.exr", "height/3/px/2.exr").is_none());
        let f = match_pattern("minmax/{level}/{face}/face.exr", "minmax/2/nz/face.exr").unwrap();
        assert_eq!(f.len(), 2);
        assert!(match_pattern("minmax/{level}/{face}/face.exr", "minmax/2/nz/0/1.exr").is_none());
    }
}
