//! The stage graph: a stage run in shards by separate processes gives the bytes of one run,
//! whatever order the shards come in; bad selections are refused; and a toy stage defined in
//! this file alone (a product, its format, its units) runs through the graph and the store.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;

use penumbra::error::Result;
use penumbra::graph::{self, Node, Ran, StageNode};
use penumbra::layout::TileId;
use penumbra::manifest::Tileset;
use penumbra::progress::NoProgress;
use penumbra::runner::{self, Cx, Finished, Reads, Select, Stage, StageSpec, Unit};
use penumbra::tileset::{Product, ProductDef, Store};

use crate::util::{copy_tree, penumbra_bin, snapshot};

fn run(args: &[&str]) -> Output {
    penumbra_bin().args(args).output().unwrap()
}

fn ok(args: &[&str]) -> String {
    let o = run(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

/// Tiles and mipmaps of a small embedded scene (4 levels of 32² tiles).
fn base(dir: &Path) {
    bake(dir, 32);
}

fn bake(dir: &Path, tile_size: u32) {
    ok(&[
        "bake",
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--tile-size",
        &tile_size.to_string(),
        "--no-horizons",
        "--out",
        dir.to_str().unwrap(),
    ]);
}

fn json(s: &str) -> serde_json::Value {
    serde_json::from_str(s).unwrap()
}

/// Run `args` on `parts` as the given shards, one process each, and check that only the last
/// commits.
fn in_shards(parts: &Path, args: &[&str], shards: &[&str]) {
    let before = Tileset::load(parts).unwrap();
    for (i, s) in shards.iter().enumerate() {
        let mut a = args.to_vec();
        a.insert(1, parts.to_str().unwrap());
        a.extend(["--shard", s, "--json"]);
        let out = json(&ok(&a));
        let last = i + 1 == shards.len();
        if last {
            assert!(out.get("partial").is_none(), "{s}: {out}");
        } else {
            assert_eq!(out["partial"], true, "{s}: {out}");
            assert!(out["units_run"].as_u64().unwrap() > 0, "{s}: {out}");
            assert!(
                out["units_done"].as_u64().unwrap() < out["units"].as_u64().unwrap(),
                "{s}: {out}"
            );
            // Nothing is committed before the last shard.
            assert_eq!(Tileset::load(parts).unwrap(), before, "{s} committed");
        }
    }
}

#[test]
fn shards_in_separate_processes_give_the_bytes_of_one_run() {
    let d = tempfile::tempdir().unwrap();
    let (whole, parts) = (d.path().join("whole"), d.path().join("parts"));
    base(&whole);
    copy_tree(&whole, &parts);
    let w = whole.to_str().unwrap();

    // The mip stage again with other options (a new run key), in three shards out of order.
    ok(&["mip", w, "--precision", "f16"]);
    in_shards(
        &parts,
        &["mip", "--precision", "f16"],
        &["2/3", "0/3", "1/3"],
    );
    assert_eq!(snapshot(&whole), snapshot(&parts), "mip");

    // Horizons streamed into Fourier pyramids (the sink's records finish the product), in
    // two shards; then the Fourier stage from raw maps.
    let h = [
        "horizon",
        "--levels",
        "3",
        "--azimuths",
        "16",
        "--fourier",
        "--coefficients",
        "9",
        "--keep-raw",
    ];
    let mut a = h.to_vec();
    a.insert(1, w);
    ok(&a);
    in_shards(&parts, &h, &["1/2", "0/2"]);
    assert_eq!(snapshot(&whole), snapshot(&parts), "horizon --fourier");
    ok(&["fourier", w, "--coefficients", "5"]);
    in_shards(&parts, &["fourier", "--coefficients", "5"], &["0/2", "1/2"]);
    let (a, b) = (snapshot(&whole), snapshot(&parts));
    assert!(a.keys().any(|k| k.starts_with("fourier/")));
    assert_eq!(a, b, "fourier");

    // A shard of a run that is already up to date does nothing and says so.
    let out = json(&ok(&[
        "mip",
        w,
        "--precision",
        "f16",
        "--shard",
        "0/3",
        "--json",
    ]));
    assert_eq!(out["up_to_date"], true, "{out}");
}

#[test]
fn bad_shards_are_refused_and_write_nothing() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("t");
    base(&dir);
    let before = snapshot(&dir);
    let p = dir.to_str().unwrap();
    for bad in ["2/2", "1/0", "x/2", "3", "-1/2", "0/100001", ""] {
        let o = run(&["mip", p, "--precision", "f16", &format!("--shard={bad}")]);
        assert_eq!(o.status.code(), Some(2), "--shard {bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("shard"), "--shard {bad}: {err}");
        assert_eq!(snapshot(&dir), before, "--shard {bad} wrote");
    }
    // More shards than units: the empty ones are refused, the tileset untouched.
    let o = run(&["mip", p, "--precision", "f16", "--shard", "99999/100000"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("picks none"));
    assert_eq!(snapshot(&dir), before);
}

#[test]
fn shards_cover_every_unit_once_by_cost() {
    let t = |x| TileId {
        level: 3,
        face: penumbra::cube::Face::Px,
        x,
        y: 0,
    };
    let units: Vec<Unit> = (0..97)
        .map(|i| Unit::tile(t(i), Vec::new(), 1.0 + (i % 7) as f64 * 10.0))
        .collect();
    for n in [1usize, 2, 3, 8, 97, 200] {
        let mut seen = vec![0; units.len()];
        let mut costs = Vec::new();
        for k in 0..n {
            let picked = Select::Shard { index: k, count: n }.pick(&units);
            costs.push(picked.iter().map(|&i| units[i].cost).sum::<f64>());
            for i in picked {
                seen[i] += 1;
            }
        }
        assert!(seen.iter().all(|&c| c == 1), "{n} shards: {seen:?}");
        if n <= 8 {
            let total: f64 = costs.iter().sum();
            let most = costs.iter().cloned().fold(0.0, f64::max);
            // Balanced to within the largest unit.
            assert!(most <= total / n as f64 + 61.0, "{n}: {costs:?}");
        }
    }
    let keys = Select::Keys(vec![units[5].key(), units[50].key()]).pick(&units);
    assert_eq!(keys, vec![5, 50]);
}

/// Shards lie together: the 16 × 16 tiles of a face at level 4, of equal cost, in four shards
/// are its four quadrants (the Hilbert curve fills each before the next), and in 16 shards its
/// 4 × 4 blocks; the levels and faces follow one another, each whole.
#[test]
fn shards_are_compact_blocks_of_tiles() {
    use penumbra::cube::Face;
    let mut units = Vec::new();
    for face in [Face::Px, Face::Nz] {
        for y in 0..16 {
            for x in 0..16 {
                let t = TileId {
                    level: 4,
                    face,
                    x,
                    y,
                };
                units.push(Unit::tile(t, Vec::new(), 1.0));
            }
        }
    }
    for (n, side) in [(8usize, 8u32), (32, 4)] {
        let costs = vec![1.0; units.len()];
        let shard = Select::assign(&units, &costs, n);
        let mut blocks: BTreeMap<usize, std::collections::BTreeSet<(usize, u32, u32)>> =
            BTreeMap::new();
        for (u, &k) in units.iter().zip(&shard) {
            let t = u.tile;
            blocks
                .entry(k)
                .or_default()
                .insert((t.face as usize, t.x / side, t.y / side));
        }
        assert_eq!(blocks.len(), n, "{n} shards: {blocks:?}");
        for (k, b) in &blocks {
            assert_eq!(b.len(), 1, "{n} shards: shard {k} spans the blocks {b:?}");
        }
    }
}

// -------------------------------------------------------------------------------------------
// A toy stage: per height tile, a text file with the tile's interior mean height.

/// The toy product: one `toy/{level}/{face}/{y}/{x}.txt` per height tile, made from the heights.
static TOY: ProductDef = ProductDef {
    name: "toy",
    dirs: &["toy"],
    reads: &[Product::Height],
};

/// Its format: the mean as text with the tile it belongs to.
fn toy_path(root: &Path, id: TileId) -> std::path::PathBuf {
    penumbra::format::tile_path(root, "toy/{level}/{face}/{y}/{x}.txt", id)
}

fn toy_write(path: &Path, id: TileId, mean: f64) -> Result<()> {
    let text = format!(
        "{} {} {} {} {mean:.6}\n",
        id.level,
        id.face.name(),
        id.x,
        id.y
    );
    penumbra::fsio::write_staged(path, |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())
            .map_err(|e| penumbra::error::Error::io(path, e))
    })
}

fn toy_read(path: &Path) -> f64 {
    let s = std::fs::read_to_string(path).unwrap();
    s.split_whitespace().last().unwrap().parse().unwrap()
}

struct ToyStage {
    level: u8,
}

impl Stage for ToyStage {
    type Plan = (Tileset, Vec<TileId>);
    /// The mean as bits (an all-no-data tile's mean is NaN).
    type Done = u64;
    type Scratch = ();
    type Report = serde_json::Value;

    fn spec(&self) -> StageSpec {
        StageSpec {
            name: "toy",
            writes: std::borrow::Cow::Owned(vec![Product::Other(&TOY)]),
            reads: std::borrow::Cow::Borrowed(&[Product::Height]),
            format: std::borrow::Cow::Borrowed(&["toy-1"]),
        }
    }

    fn plan(&self, _dir: &Path, ts: &Tileset) -> Result<Self::Plan> {
        let tiles = ts
            .tile_set()
            .into_iter()
            .filter(|t| t.level == self.level)
            .collect();
        Ok((ts.clone(), tiles))
    }

    fn key(&self, ts: &Tileset, _plan: &Self::Plan) -> String {
        runner::run_key(&self.spec(), &[&ts.run_key], &[&[self.level]])
    }

    fn units(&self, _ts: &Tileset, plan: &Self::Plan) -> Result<Vec<Unit>> {
        Ok(plan
            .1
            .iter()
            .map(|&id| {
                let reads = vec![Reads::Tile {
                    product: Product::Height,
                    tile: id,
                }];
                Unit::tile(id, reads, 1.0)
            })
            .collect())
    }

    fn scratch(&self, _plan: &Self::Plan) {}

    fn run_unit(&self, cx: &Cx<Self::Plan>, unit: &Unit, _: &mut ()) -> Result<u64> {
        let t = cx.store.height(unit.tile)?.expect("listed");
        let v: Vec<f64> = t
            .height
            .iter()
            .filter(|h| h.is_finite())
            .map(|&h| h as f64)
            .collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        toy_write(&toy_path(cx.out, unit.tile), unit.tile, mean)?;
        Ok(mean.to_bits())
    }

    fn finish(
        &self,
        cx: &Cx<Self::Plan>,
        done: Vec<Finished<u64>>,
    ) -> Result<(Tileset, serde_json::Value)> {
        let means: BTreeMap<String, f64> = done
            .iter()
            .map(|f| (f.unit.key(), f64::from_bits(f.done)))
            .collect();
        let mut m = cx.plan.0.clone();
        let entry = serde_json::json!({
            "path": "toy/{level}/{face}/{y}/{x}.txt",
            "level": self.level,
            "tiles": done.len(),
            "run_key": cx.key,
        });
        m.products.extra.insert("toy".into(), entry.clone());
        Ok((
            m,
            serde_json::json!({"tiles": means.len(), "here": done.iter().filter(|f| f.here).count()}),
        ))
    }

    fn up_to_date(&self, _store: &Store, plan: &Self::Plan, _units: &[Unit]) -> serde_json::Value {
        serde_json::json!({"tiles": plan.1.len(), "up_to_date": true})
    }
}

#[test]
fn a_toy_stage_runs_through_the_graph_and_the_store() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("t");
    base(&dir);
    let toy = StageNode {
        stage: ToyStage { level: 2 },
        report: Ran::Other,
    };
    // Listed before the mip stage it does not depend on, after nothing: the walk keeps the
    // given order where no product orders it, and runs it first.
    let mip = graph::mip(penumbra::mip::MipOptions {
        precision: penumbra::mip::Precision::F16,
        ..Default::default()
    });
    assert_eq!(graph::order(&[&mip, &toy]).unwrap(), vec![0, 1]);
    // Part of it (two of its three shards), then the whole walk finishes it.
    let r = toy.run(&dir, &Select::Shard { index: 0, count: 3 }, &NoProgress);
    assert!(matches!(r, Ok(Ran::Partial { ran, .. }) if ran > 0));
    let r = toy.run(&dir, &Select::Shard { index: 2, count: 3 }, &NoProgress);
    assert!(matches!(r, Ok(Ran::Partial { .. })));
    let ran = graph::walk(&dir, &[&toy, &mip], &NoProgress).unwrap();
    let Ran::Other(v) = &ran[0] else {
        panic!("{ran:?}")
    };
    let n = Tileset::load(&dir)
        .unwrap()
        .tile_set()
        .iter()
        .filter(|t| t.level == 2)
        .count();
    assert!(n >= 3, "{n} tiles at level 2");
    assert_eq!(v["tiles"], n, "{v}");
    // The last run did only the shard left.
    let here = v["here"].as_u64().unwrap() as usize;
    assert!(here > 0 && here < n, "{v}");

    // Through the store: the manifest records it; every file is where its format says, with
    // the mean of its tile's heights.
    let store = Store::open(&dir).unwrap();
    let entry = &store.manifest().products.extra["toy"];
    assert_eq!(entry["tiles"], n);
    assert_eq!(
        entry["dirs"],
        serde_json::json!(["toy"]),
        "the store stamps what it owns"
    );
    assert_eq!(entry["reads"], serde_json::json!(["height"]));
    let key = entry["run_key"].as_str().unwrap().to_string();
    assert_eq!(
        Product::Other(&TOY).recorded_key(store.manifest()),
        Some(key.as_str())
    );
    for id in store
        .manifest()
        .tile_set()
        .into_iter()
        .filter(|t| t.level == 2)
    {
        let t = store.read_height(id).unwrap();
        let v: Vec<f64> = t
            .height
            .iter()
            .filter(|h| h.is_finite())
            .map(|&h| h as f64)
            .collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        assert!((toy_read(&toy_path(&dir, id)) - mean).abs() < 1e-5);
    }
    drop(store);

    // Up to date on a rerun; a new height product (a retile) makes it stale and removes it.
    let again = toy.run(&dir, &Select::All, &NoProgress).unwrap();
    assert!(
        matches!(&again, Ran::Other(v) if v["up_to_date"] == true),
        "{again:?}"
    );
    bake(&dir, 64);
    let ts = Tileset::load(&dir).unwrap();
    assert!(
        !ts.products.extra.contains_key("toy"),
        "stale toy entry kept"
    );
    assert!(!dir.join("toy").exists(), "stale toy files kept");
}

/// An unlisted product's entry may claim only plain folders of its own: any other claim (a
/// listed product's folder, a path, the state folder, not a list) is refused when the manifest
/// is read (exit 2, the field named, nothing touched), because a later writer removes what it
/// claims.
#[test]
fn unlisted_products_claiming_other_folders_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("t");
    base(&dir);
    let p = dir.to_str().unwrap();
    let path = dir.join("tileset.json");
    let good = std::fs::read_to_string(&path).unwrap();
    let with = |entry: serde_json::Value| {
        let mut m: serde_json::Value = serde_json::from_str(&good).unwrap();
        m["products"]["toy"] = entry;
        std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    };
    // Accepted: a plain folder of its own, and a key without folders (read past).
    for ok_entry in [
        serde_json::json!({"run_key": "k", "dirs": ["toy"], "reads": ["height"]}),
        serde_json::json!({"anything": [1, 2]}),
        serde_json::json!(7),
    ] {
        with(ok_entry.clone());
        ok(&["info", p]);
    }
    for (bad, field) in [
        (serde_json::json!({"dirs": ["height"]}), "products.toy.dirs"),
        (serde_json::json!({"dirs": ["../x"]}), "products.toy.dirs"),
        (
            serde_json::json!({"dirs": [".penumbra"]}),
            "products.toy.dirs",
        ),
        (serde_json::json!({"dirs": ["a/b"]}), "products.toy.dirs"),
        (serde_json::json!({"dirs": "toy"}), "products.toy.dirs"),
        (serde_json::json!({"dirs": [7]}), "products.toy.dirs"),
        (
            serde_json::json!({"dirs": ["toy"], "reads": ["../h"]}),
            "products.toy.reads",
        ),
    ] {
        with(bad.clone());
        let before = snapshot(&dir);
        let o = run(&["info", p]);
        assert_eq!(o.status.code(), Some(2), "{bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(field), "{bad}: {err}");
        // A writer refuses too, and touches nothing.
        let o = run(&["mip", p, "--precision", "f16"]);
        assert_eq!(o.status.code(), Some(2), "{bad}");
        assert_eq!(snapshot(&dir), before, "{bad}");
    }
}
