//! A scene's stages run as concurrent shard processes (`bake SCENE --stage S --shard I/N`, all N
//! spawned at once) and finished (`--finish`) give the bytes of one `bake SCENE`, for N = 1, 2,
//! 4, 7; and the faults: a shard killed mid-run is rerun to the same bytes, a finish with a
//! shard missing or a staged file damaged is refused (exit 2) naming the shard and commits
//! nothing, and of two finishes at once exactly one commits.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Output, Stdio};
use std::time::{Duration, Instant};

use crate::util::{copy_tree, indexes, penumbra_bin, snapshot};

/// The embedded terrain (512² px) in 32² tiles down to level 10, with mipmaps and level 10's
/// horizons (16 tiles, 16 azimuths) streamed into Fourier pyramids: a bake of about a second.
const SCENE: &str = "[scene]\nname = \"shards\"\nbody = \"moon\"\n\n[layout]\ntile_size = 32\n\n\
     [[source]]\nembedded = \"south-pole\"\nsize = 512\n\n\
     [[region]]\nname = \"all\"\nbody = true\nlevel = 10\n\n\
     [renderer]\nmethods = [\"dp\", \"fourier\"]\n\n[horizon]\nlevels = [10]\nazimuths = 16\n";

/// The sharded stages, in the order the graph runs them.
const STAGES: [&str; 2] = ["mip", "horizon"];

struct Scene {
    _tmp: tempfile::TempDir,
    root: PathBuf,
    file: PathBuf,
    /// `bake SCENE` in one process.
    whole: PathBuf,
    /// The scene tiled (`--stage tile`), nothing else.
    tiled: PathBuf,
}

fn scene() -> Scene {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().to_path_buf();
    let file = root.join("scene.toml");
    std::fs::write(&file, SCENE).unwrap();
    let (whole, tiled) = (root.join("whole"), root.join("tiled"));
    let s = Scene {
        _tmp: tmp,
        root,
        file,
        whole,
        tiled,
    };
    ok(&s.bake(&s.whole, &[]));
    ok(&s.bake(&s.tiled, &["--stage", "tile"]));
    s
}

impl Scene {
    fn cmd(&self, out: &Path, extra: &[&str]) -> std::process::Command {
        let mut c = penumbra_bin();
        c.arg("bake")
            .arg(&self.file)
            .arg("--out")
            .arg(out)
            .args(extra);
        c
    }

    fn bake(&self, out: &Path, extra: &[&str]) -> Output {
        self.cmd(out, extra).output().unwrap()
    }

    /// A copy of the tiled folder to run stages on.
    fn fresh(&self, name: &str) -> PathBuf {
        let d = self.root.join(name);
        copy_tree(&self.tiled, &d);
        d
    }

    fn spawn_shard(&self, out: &Path, stage: &str, i: usize, n: usize, extra: &[&str]) -> Child {
        let shard = format!("{i}/{n}");
        let mut args = vec!["--stage", stage, "--shard", &shard, "--json"];
        args.extend(extra);
        self.cmd(out, &args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    }

    /// Shards `which` of `n` of `stage`, spawned at once; each must succeed without committing.
    fn shards(&self, out: &Path, stage: &str, n: usize, which: &[usize]) {
        let children: Vec<(usize, Child)> = which
            .iter()
            .map(|&i| (i, self.spawn_shard(out, stage, i, n, &[])))
            .collect();
        for (i, c) in children {
            let o = c.wait_with_output().unwrap();
            let text = ok(&o);
            let v: serde_json::Value = serde_json::from_str(&text).unwrap();
            assert_eq!(v["partial"], true, "{stage} {i}/{n} committed: {v}");
            assert!(v["units_run"].as_u64().unwrap() > 0, "{stage} {i}/{n}: {v}");
        }
    }

    fn finish(&self, out: &Path, stage: &str) -> Output {
        self.bake(out, &["--stage", stage, "--finish", "--json"])
    }
}

fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "exit {:?}: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout.clone()).unwrap()
}

/// A refusal: exit 2, the message returned.
fn refused(o: &Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "not refused: {err}");
    err
}

/// The folder's product files and indexes (what a run must reproduce byte for byte), and its
/// manifest.
type State = (BTreeMap<String, Vec<u8>>, BTreeMap<String, Vec<u8>>);

fn state(dir: &Path) -> State {
    (snapshot(dir), indexes(dir))
}

fn same_as_whole(s: &Scene, dir: &Path, what: &str) {
    crate::util::same_tileset(&s.whole, dir, what);
    let staging = dir.join(".penumbra").join("staging");
    let left: Vec<_> = std::fs::read_dir(&staging)
        .map(|r| r.flatten().map(|e| e.file_name()).collect())
        .unwrap_or_default();
    assert!(left.is_empty(), "{what}: staging left {left:?}");
}

/// The records `(unit, files)` of shard `i` of `n` of `stage`, from its unit logs.
fn shard_files(dir: &Path, stage: &str, i: usize, n: usize) -> Vec<(String, u64)> {
    let units = dir.join(".penumbra/staging").join(stage).join("units");
    let mut out = Vec::new();
    for e in std::fs::read_dir(&units).unwrap().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if !name.starts_with(&format!("shard-{i}-of-{n}.")) {
            continue;
        }
        for line in std::fs::read_to_string(e.path()).unwrap().lines() {
            let (_, rec) = line.split_once('\t').unwrap();
            let rec: serde_json::Value = serde_json::from_str(rec).unwrap();
            for f in rec["files"].as_array().unwrap() {
                out.push((f[0].as_str().unwrap().to_string(), f[1].as_u64().unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// Lines in shard `i` of `n`'s unit logs of `stage`.
fn logged_units(dir: &Path, stage: &str, i: usize, n: usize) -> usize {
    let units = dir.join(".penumbra/staging").join(stage).join("units");
    let Ok(rd) = std::fs::read_dir(units) else {
        return 0;
    };
    rd.flatten()
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .starts_with(&format!("shard-{i}-of-{n}."))
        })
        .map(|e| {
            std::fs::read(e.path())
                .unwrap_or_default()
                .iter()
                .filter(|&&b| b == b'\n')
                .count()
        })
        .sum()
}

#[test]
fn concurrent_shards_and_a_finish_give_the_bytes_of_one_bake() {
    let s = scene();
    for n in [1usize, 2, 4, 7] {
        let dir = s.fresh(&format!("n{n}"));
        for stage in STAGES {
            let all: Vec<usize> = (0..n).collect();
            s.shards(&dir, stage, n, &all);
            let v: serde_json::Value = serde_json::from_str(&ok(&s.finish(&dir, stage))).unwrap();
            assert_eq!(v["up_to_date"], false, "{stage} {n}: {v}");
        }
        same_as_whole(&s, &dir, &format!("{n} shards"));
        // A finish again, or a shard, of a committed stage: up to date, nothing to do.
        let v: serde_json::Value = serde_json::from_str(&ok(&s.finish(&dir, "horizon"))).unwrap();
        assert_eq!(v["up_to_date"], true, "{v}");
    }
    // The tiling stage runs whole: its shards are refused, and so is a stage the scene lacks.
    let dir = s.fresh("tile");
    let e = refused(&s.bake(&dir, &["--stage", "tile", "--shard", "0/2"]));
    assert!(e.contains("runs whole"), "{e}");
    let e = refused(&s.bake(&dir, &["--stage", "fourier", "--shard", "0/2"]));
    assert!(e.contains("stages are tile, mip, horizon"), "{e}");
}

#[test]
fn a_killed_shard_rerun_finishes_to_the_same_bytes() {
    let s = scene();
    let dir = s.fresh("killed");
    ok(&s.bake(&dir, &["--stage", "mip"]));
    // Shard 0 of 2 on one thread, killed once it has logged a unit; shard 1 runs through.
    let mut victim = s.spawn_shard(&dir, "horizon", 0, 2, &["--threads", "1"]);
    let other = s.spawn_shard(&dir, "horizon", 1, 2, &[]);
    let t0 = Instant::now();
    while logged_units(&dir, "horizon", 0, 2) == 0 {
        assert!(
            victim.try_wait().unwrap().is_none(),
            "shard 0/2 ended before it was killed"
        );
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "shard 0/2 logs nothing"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    victim.kill().unwrap();
    victim.wait().unwrap();
    let logged = logged_units(&dir, "horizon", 0, 2);
    ok(&other.wait_with_output().unwrap());
    assert!(logged < 8, "shard 0/2 had done all its 8 units: {logged}");
    // The finish names the shard that did not complete, and commits nothing.
    let before = state(&dir);
    let e = refused(&s.finish(&dir, "horizon"));
    assert!(e.contains("shard 0/2") && !e.contains("shard 1/2"), "{e}");
    assert_eq!(state(&dir), before, "a refused finish changed the tileset");
    s.shards(&dir, "horizon", 2, &[0]);
    ok(&s.finish(&dir, "horizon"));
    same_as_whole(&s, &dir, "a killed shard rerun");
}

#[test]
fn a_finish_with_a_shard_missing_or_damaged_names_it_and_commits_nothing() {
    let s = scene();
    let dir = s.fresh("faults");
    // No shard at all.
    let e = refused(&s.finish(&dir, "mip"));
    assert!(e.contains("no shard"), "{e}");
    let before = state(&dir);
    s.shards(&dir, "mip", 3, &[0, 2]);
    let e = refused(&s.finish(&dir, "mip"));
    assert!(e.contains("shard 1/3"), "{e}");
    assert!(!e.contains("shard 0/3") && !e.contains("shard 2/3"), "{e}");
    assert_eq!(state(&dir), before, "a refused finish changed the tileset");
    s.shards(&dir, "mip", 3, &[1]);
    // A byte flipped in a file of shard 2, another file of shard 0 cut short.
    let staged = dir.join(".penumbra/staging/mip");
    let (flip, _) = shard_files(&dir, "mip", 2, 3).pop().unwrap();
    let (cut, len) = shard_files(&dir, "mip", 0, 3).pop().unwrap();
    let mut bytes = std::fs::read(staged.join(&flip)).unwrap();
    let k = bytes.len() / 2;
    bytes[k] ^= 0x40;
    std::fs::write(staged.join(&flip), bytes).unwrap();
    std::fs::OpenOptions::new()
        .write(true)
        .open(staged.join(&cut))
        .unwrap()
        .set_len(len - 1)
        .unwrap();
    let e = refused(&s.finish(&dir, "mip"));
    assert!(e.contains("shard 2/3") && e.contains(&flip), "{e}");
    assert!(e.contains("shard 0/3") && e.contains(&cut), "{e}");
    assert!(!e.contains("shard 1/3"), "{e}");
    assert_eq!(state(&dir), before, "a refused finish changed the tileset");
    // Rerunning the shards named redoes what is damaged, and only that.
    for i in [0, 2] {
        let o = s
            .spawn_shard(&dir, "mip", i, 3, &[])
            .wait_with_output()
            .unwrap();
        let v: serde_json::Value = serde_json::from_str(&ok(&o)).unwrap();
        assert_eq!(v["units_run"], 1, "{i}/3: {v}");
    }
    ok(&s.finish(&dir, "mip"));
    s.shards(&dir, "horizon", 1, &[0]);
    ok(&s.finish(&dir, "horizon"));
    same_as_whole(&s, &dir, "shards rerun after a refused finish");
}

#[test]
fn of_two_finishes_at_once_one_commits() {
    let s = scene();
    let dir = s.fresh("two");
    s.shards(&dir, "mip", 2, &[0, 1]);
    // A reader holds the tileset: the finish that becomes the writer waits at its commit for
    // the reader to go, so the other is sure to find the writer there.
    let reader = penumbra::tileset::Store::open(&dir).unwrap();
    let spawn = || {
        s.cmd(&dir, &["--stage", "mip", "--finish", "--json"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let mut two = [spawn(), spawn()];
    let t0 = Instant::now();
    let first = loop {
        if let Some(k) = (0..2).find(|&k| two[k].try_wait().unwrap().is_some()) {
            break k;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "neither finish ended"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    let [a, b] = two;
    let (loser, winner) = if first == 0 { (a, b) } else { (b, a) };
    let e = refused(&loser.wait_with_output().unwrap());
    assert!(e.contains("is writing this tileset"), "{e}");
    drop(reader);
    ok(&winner.wait_with_output().unwrap());
    ok(&s.finish(&dir, "mip"));
    s.shards(&dir, "horizon", 1, &[0]);
    ok(&s.finish(&dir, "horizon"));
    same_as_whole(&s, &dir, "two finishes");
}
