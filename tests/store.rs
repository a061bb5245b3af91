//! The tileset store and the stage runner through the CLI: one writer at a time, killed runs
//! that resume to the same bytes, retiles that leave no stale product behind, up-to-date
//! checks that look at the files, and a corpus of damaged manifests that must be refused
//! (exit 2, the file and field named) without touching the tileset.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::util::{copy_tree, indexes, penumbra_bin, snapshot, Rng};

fn run(args: &[&str]) -> Output {
    penumbra_bin().args(args).output().unwrap()
}

fn ok(args: &[&str]) {
    let o = run(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// A small tileset of the embedded scene with every product: tiles, mipmaps, raw horizon maps
/// and Fourier pyramids.
const BAKE: &[&str] = &[
    "bake",
    "--scene-size",
    "1024",
    "--levels",
    "4",
    "--tile-size",
    "32",
    "--horizon-levels",
    "3",
    "--keep-raw",
];

fn bake(out: &Path, extra: &[&str]) -> Command {
    let mut c = penumbra_bin();
    c.args(BAKE)
        .args(["--out", out.to_str().unwrap()])
        .args(extra);
    c
}

/// Paths of temp files and staging folders left anywhere below `dir`.
fn leftovers(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            if name.contains(".tmp.") || name == "staging" && has_entries(&p) || name == "trash" {
                out.push(p.clone());
            }
            if p.is_dir() {
                stack.push(p);
            }
        }
    }
    out
}

fn has_entries(p: &Path) -> bool {
    std::fs::read_dir(p).is_ok_and(|mut r| r.next().is_some())
}

fn wait_with_timeout(mut child: Child, limit: Duration) -> Output {
    let t0 = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            return child.wait_with_output().unwrap();
        }
        if t0.elapsed() > limit {
            child.kill().unwrap();
            panic!("a run took longer than {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A deeper tileset of the embedded scene (about 200 tiles) so that each stage runs long
/// enough to be killed in the middle.
const DEEP: &[&str] = &[
    "bake",
    "--scene-size",
    "1024",
    "--levels",
    "11",
    "--tile-size",
    "32",
    "--no-horizons",
];

/// Ten `kill -9` at random moments of `cmd` (each on a fresh copy of `start`, or from nothing),
/// each followed by a rerun of `cmd` to completion: the result must equal an uninterrupted
/// run's bytes, `tileset.json` and the indexes included, with no temp file or staged run left.
pub(crate) fn kill_trials(
    label: &str,
    start: Option<&Path>,
    cmd: &dyn Fn(&Path) -> Command,
    seed: u64,
) {
    let tmp = tempfile::tempdir().unwrap();
    let fresh = |dir: &Path| {
        let _ = std::fs::remove_dir_all(dir);
        if let Some(s) = start {
            copy_tree(s, dir);
        }
    };
    let reference = tmp.path().join("reference");
    fresh(&reference);
    let t0 = Instant::now();
    let o = cmd(&reference).output().unwrap();
    assert!(
        o.status.success(),
        "{label}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let first = t0.elapsed();
    let want = snapshot(&reference);
    let want_index = indexes(&reference);
    let out = tmp.path().join("killed");
    // The shorter of two uninterrupted runs: the first one pays for cold caches, and a short
    // stage (f16 mips take well under a second) would otherwise end before most kills.
    fresh(&out);
    let t1 = Instant::now();
    assert!(cmd(&out).output().unwrap().status.success(), "{label}");
    let full = first.min(t1.elapsed());
    let mut rng = Rng(seed);
    let mut interrupted = 0;
    // Kill times spread over the first 10/11 of an uninterrupted run's time. Runs vary on a
    // loaded machine (a test run beside other tests): a kill that finds the run already ended
    // shrinks the span for the kills after it, so that they land inside the run again.
    let mut span = full;
    for k in 0..10 {
        fresh(&out);
        let at = span.mul_f64((k as f64 + rng.unit()) / 11.0);
        let mut child = cmd(&out)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(at);
        if child.try_wait().unwrap().is_none() {
            interrupted += 1;
        } else {
            span = span.mul_f64(0.7);
        }
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
        let o = wait_with_timeout(
            cmd(&out)
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap(),
            Duration::from_secs(600),
        );
        assert!(
            o.status.success(),
            "{label}: rerun after kill {k}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert_eq!(
            snapshot(&out),
            want,
            "{label}: rerun after a kill at {at:?} differs"
        );
        assert!(
            indexes(&out) == want_index,
            "{label}: the index after a kill at {at:?} differs"
        );
        assert!(leftovers(&out).is_empty(), "{label}: {:?}", leftovers(&out));
    }
    eprintln!("{label}: {interrupted} of 10 kills hit a running process ({full:?} a run)");
    assert!(
        interrupted >= 6,
        "{label}: only {interrupted} of 10 kills hit a running process"
    );
}

#[test]
fn killed_tiling_resumes_to_the_uninterrupted_bytes() {
    kill_trials(
        "bake (tile + mip)",
        None,
        &|out| {
            let mut c = penumbra_bin();
            c.args(DEEP).args(["--out", out.to_str().unwrap()]);
            c
        },
        0x9e37_79b9_7f4a_7c15,
    );
}

fn deep_tileset(dir: &Path) {
    ok(&[DEEP, &["--out", dir.to_str().unwrap()]].concat());
}

#[test]
fn killed_mip_resumes_to_the_uninterrupted_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let base = tmp.path().join("base");
    deep_tileset(&base);
    kill_trials(
        "mip",
        Some(&base),
        &|out| {
            let mut c = penumbra_bin();
            c.args(["mip", out.to_str().unwrap(), "--precision", "f16"]);
            c
        },
        0x2545_f491_4f6c_dd1d,
    );
}

#[test]
fn killed_horizon_resumes_to_the_uninterrupted_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let base = tmp.path().join("base");
    deep_tileset(&base);
    kill_trials(
        "horizon",
        Some(&base),
        &|out| {
            let mut c = penumbra_bin();
            c.args([
                "horizon",
                out.to_str().unwrap(),
                "--levels",
                "9",
                "--azimuths",
                "64",
            ]);
            c
        },
        0x1234_5678_9abc_def1,
    );
}

#[test]
fn killed_streamed_fourier_resumes_to_the_uninterrupted_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let base = tmp.path().join("base");
    deep_tileset(&base);
    // Both products at once, and a per-tile K that a resumed run reads back from kept files.
    kill_trials(
        "horizon --fourier",
        Some(&base),
        &|out| {
            let mut c = penumbra_bin();
            c.args([
                "horizon",
                out.to_str().unwrap(),
                "--levels",
                "9",
                "--azimuths",
                "64",
                "--fourier",
                "--keep-raw",
                "--max-error-deg",
                "0.5",
            ]);
            c
        },
        0x0f0e_0d0c_0b0a_0908,
    );
}

/// The commit indexes staged files from the hashes their writers recorded as they wrote them
/// (`hashes/<pid>.log` in the staging folder) and reads back only files without a usable
/// record. The mip stage in two shards: the first leaves a record of every file it staged;
/// its log then damaged as kills and accidents leave one (its last record never written, the
/// one before cut short, a file's only record replaced by one of another size, another's by
/// one of another inode, both with a wrong hash, garbage), the second shard's commit still
/// gives the bytes and the index of an uninterrupted run.
#[test]
fn the_commit_indexes_from_recorded_hashes_and_survives_damaged_records() {
    use penumbra::tileset::fsio;
    let tmp = tempfile::tempdir().unwrap();
    let (whole, parts) = (tmp.path().join("whole"), tmp.path().join("parts"));
    let w = whole.to_str().unwrap();
    ok(&[
        "bake",
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--tile-size",
        "32",
        "--no-horizons",
        "--out",
        w,
    ]);
    copy_tree(&whole, &parts);
    let p = parts.to_str().unwrap();
    ok(&["mip", w, "--precision", "f16"]);
    ok(&["mip", p, "--precision", "f16", "--shard", "0/2"]);

    let staging = parts
        .join(penumbra::tileset::STATE_DIR)
        .join("staging")
        .join("mip");
    let recorded = fsio::read_staged_hashes(&staging);
    let mut staged = 0;
    for d in ["maxmip", "minmax"] {
        for (rel, _) in fsio::list_files(&staging.join(d)).unwrap() {
            let rel = format!("{d}/{rel}");
            let f = staging.join(&rel);
            let stamp = fsio::FileStamp::of(&std::fs::symlink_metadata(&f).unwrap());
            let want = blake3::hash(&std::fs::read(&f).unwrap());
            assert_eq!(recorded.hash_of(&rel, stamp), Some(want), "{rel}");
            staged += 1;
        }
    }
    assert!(staged >= 10, "{staged} files staged");
    assert_eq!(recorded.len(), staged, "one record a file");

    let logs: Vec<PathBuf> = std::fs::read_dir(staging.join(fsio::HASH_LOGS))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(logs.len(), 1, "{logs:?}");
    let text = std::fs::read_to_string(&logs[0]).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let n = lines.len();
    let fields = |l: &str| l.split('\t').map(str::to_string).collect::<Vec<_>>();
    // The only records of the first two files: were either trusted, its hash would be wrong.
    let lie = blake3::hash(b"not the file").to_hex().to_string();
    let mut wrong_size = fields(lines[0]);
    wrong_size[1] = (wrong_size[1].parse::<u64>().unwrap() + 1).to_string();
    wrong_size[4] = lie.clone();
    let mut other_inode = fields(lines[1]);
    other_inode[2] = (other_inode[2].parse::<u64>().unwrap() + 1).to_string();
    other_inode[4] = lie;
    let mut damaged = vec![
        "garbage".to_string(),
        wrong_size.join("\t"),
        other_inode.join("\t"),
    ];
    damaged.extend(lines[2..n - 2].iter().map(|l| l.to_string()));
    let cut = lines[n - 2];
    let damaged = format!("{}\n{}", damaged.join("\n"), &cut[..cut.len() / 2]);
    std::fs::write(&logs[0], damaged).unwrap();

    ok(&["mip", p, "--precision", "f16", "--shard", "1/2"]);
    assert_eq!(snapshot(&whole), snapshot(&parts));
    assert!(
        indexes(&whole) == indexes(&parts),
        "the index differs from an uninterrupted run's"
    );
}

#[test]
fn an_up_to_date_stage_clears_what_a_kill_after_its_commit_left() {
    // A kill between a commit's renames and its clean-up leaves the committed run's marker in
    // staging; the next run of that stage finds its output up to date and clears it.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("t");
    let o = out.to_str().unwrap();
    ok(&[BAKE, &["--out", o]].concat());
    let ts = penumbra::manifest::Tileset::load(&out).unwrap();
    let key = ts.products.mip.unwrap().run_key;
    let stale = out.join(".penumbra/staging/mip");
    std::fs::create_dir_all(&stale).unwrap();
    std::fs::write(stale.join("run.json"), format!("{{\"run_key\":\"{key}\"}}")).unwrap();
    // A staged run of another key is an interrupted run to resume: it stays.
    let other = out.join(".penumbra/staging/fourier");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("run.json"), br#"{"run_key":"another"}"#).unwrap();
    let r = run(&["mip", o, "--json"]);
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(j["up_to_date"], true);
    assert!(!stale.exists(), "the committed run's staging is left");
    assert!(other.join("run.json").exists());
}

#[test]
fn a_second_writer_is_refused_at_once_and_the_first_wins() {
    let tmp = tempfile::tempdir().unwrap();
    let reference = tmp.path().join("reference");
    ok(&[BAKE, &["--out", reference.to_str().unwrap()]].concat());
    let out = tmp.path().join("shared");
    let first = bake(&out, &[])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Wait until the first run holds the lock (it reads its input first).
    let lock = out.join(".penumbra/lock");
    let t0 = Instant::now();
    while !std::fs::read_to_string(&lock).is_ok_and(|s| s.trim() == first.id().to_string()) {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the first writer never locked"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // Another writer with other parameters, into the same folder.
    let t1 = Instant::now();
    let second = bake(&out, &["--prefilter", "point"]).output().unwrap();
    let refused_in = t1.elapsed();
    let first = wait_with_timeout(first, Duration::from_secs(600));
    assert!(first.status.success());
    assert_eq!(second.status.code(), Some(2));
    let e = String::from_utf8_lossy(&second.stderr);
    assert!(e.contains(&format!("process {}", first_pid(&lock))), "{e}");
    assert!(
        refused_in < Duration::from_secs(30),
        "refused after {refused_in:?}"
    );
    assert_eq!(
        snapshot(&out),
        snapshot(&reference),
        "the tileset is the first run's"
    );
}

/// A program that embeds the library and spawns other programs while it writes (a test harness
/// is one): a child caught between fork and exec must not keep the tileset locked after the
/// writer lets go. With flock(2) the child's copy of the descriptor held the lock, and the
/// next writer was refused (a CI failure of `mip::a_corrupt_height_tile_is_an_error_naming_it`).
#[cfg(unix)]
#[test]
fn a_child_spawned_while_the_lock_is_held_does_not_keep_it() {
    use std::os::unix::process::CommandExt;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("tiles");
    ok(&[BAKE, &["--out", out.to_str().unwrap()]].concat());
    let writer = penumbra::tileset::writer::Writer::begin(&out).unwrap();
    // `spawn` returns once the child has exec'd, so it runs on another thread; the child
    // lingers before exec with every descriptor of this process.
    let child = std::thread::spawn(|| {
        let mut c = Command::new("true");
        // SAFETY: the hook only sleeps (nanosleep is async-signal-safe).
        unsafe {
            c.pre_exec(|| {
                std::thread::sleep(Duration::from_secs(3));
                Ok(())
            });
        }
        c.status().unwrap()
    });
    std::thread::sleep(Duration::from_millis(500));
    drop(writer);
    let t0 = Instant::now();
    let again = bake(&out, &[]).output().unwrap();
    let lingered = t0.elapsed() < Duration::from_millis(2500);
    assert!(child.join().unwrap().success());
    assert!(
        again.status.success(),
        "refused while the child lingered ({lingered}): {}",
        String::from_utf8_lossy(&again.stderr)
    );
}

fn first_pid(lock: &Path) -> String {
    std::fs::read_to_string(lock).unwrap().trim().to_string()
}

#[test]
fn retile_with_other_parameters_leaves_no_stale_product() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("t");
    ok(&[BAKE, &["--out", out.to_str().unwrap()]].concat());
    let before = snapshot(&out);
    assert!(before.keys().any(|k| k.starts_with("horizon/")));
    // Retile alone, with another prefilter: mipmaps and horizons of the old heights must go.
    let o = run(&[
        "bake",
        "--scene-size",
        "1024",
        "--levels",
        "4",
        "--tile-size",
        "32",
        "--prefilter",
        "point",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let after = snapshot(&out);
    assert!(
        !after.keys().any(|k| k.starts_with("horizon/")),
        "old horizon maps remain"
    );
    let old: serde_json::Value = serde_json::from_slice(&before["tileset.json"]).unwrap();
    let new: serde_json::Value = serde_json::from_slice(&after["tileset.json"]).unwrap();
    assert!(new["products"].get("horizon").is_none());
    assert_ne!(new["run_key"], old["run_key"]);
    // The mipmaps are the new heights' (bake rebuilt them), not the old ones kept.
    assert_ne!(
        new["products"]["mip"]["run_key"],
        old["products"]["mip"]["run_key"]
    );
    let index: Vec<(String, u64, String)> =
        serde_json::from_slice(&std::fs::read(out.join(".penumbra/index/mip.json")).unwrap())
            .unwrap();
    let on_disk: Vec<&String> = after
        .keys()
        .filter(|k| k.starts_with("maxmip/") || k.starts_with("minmax/"))
        .collect();
    assert_eq!(index.len(), on_disk.len(), "mip files beyond the new run's");
}

#[test]
fn up_to_date_only_when_the_files_are_there() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("t");
    let o = out.to_str().unwrap();
    ok(&[BAKE, &["--out", o]].concat());
    let want = snapshot(&out);
    let r = run(&["mip", o, "--json"]);
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(j["up_to_date"], true);
    // Products deleted or damaged behind the manifest's back are rebuilt, not vouched for.
    std::fs::remove_dir_all(out.join("maxmip")).unwrap();
    std::fs::remove_dir_all(out.join("minmax")).unwrap();
    let r = run(&["mip", o, "--json"]);
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(
        j["up_to_date"],
        false,
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let h = snapshot(&out)
        .into_keys()
        .find(|k| k.starts_with("horizon/"))
        .unwrap();
    std::fs::write(out.join(&h), b"truncated").unwrap();
    let r = run(&[
        "horizon",
        o,
        "--levels",
        "3",
        "--azimuths",
        "360",
        "--compression",
        "zip",
        // As the bake ran it: streamed pyramids and the raw maps.
        "--fourier",
        "--keep-raw",
        "--json",
    ]);
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(
        j["up_to_date"],
        false,
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    assert_eq!(snapshot(&out), want);
}

/// One damage to a manifest: the field path and a new value (None: remove the key).
fn damages() -> Vec<(String, Option<serde_json::Value>)> {
    use serde_json::json;
    let mut d: Vec<(String, Option<serde_json::Value>)> = Vec::new();
    let numbers = [
        "layout.tile_size",
        "layout.halo",
        "layout.levels",
        "body.radius_m",
        "coverage.0.tiles",
        "coverage.0.tiles_per_face",
        "coverage.0.level",
        "coverage.3.level",
        "products.height.min_m",
        "products.height.max_m",
        "products.horizon.azimuths",
        "products.horizon.near_px",
        "products.horizon.terrain_min_m",
        "products.mip.global_max_m",
        "products.fourier.coefficients",
        "products.fourier.azimuths",
        "products.fourier.bytes_per_tile",
        "products.fourier.terrain_max_m",
        "source.pixel_size_m",
        "format_version",
    ];
    let values = [
        json!(0),
        json!(-1),
        json!(1e300),
        json!(18446744073709551615u64),
        json!(4294967296u64),
        json!("12"),
        json!(null),
        json!([1]),
    ];
    for f in numbers {
        for v in &values {
            d.push((f.to_string(), Some(v.clone())));
        }
    }
    for f in [
        "products.height.path",
        "products.mip.max_path",
        "products.mip.minmax_path",
        "products.mip.face_path",
        "products.horizon.path",
        "products.fourier.path",
    ] {
        for v in [
            "../outside/{level}/{face}/{y}/{x}.exr",
            "/etc/{level}/{face}/{y}/{x}.exr",
            "height/{level}/{face}/{y}.exr",
            "",
            "height/{level}/{face}/{y}/{x}/{z}.exr",
            "horizon/../../{level}/{face}/{y}/{x}.exr",
        ] {
            d.push((f.to_string(), Some(json!(v))));
        }
        d.push((f.to_string(), None));
        d.push((f.to_string(), Some(json!(7))));
    }
    for f in [
        "products",
        "products.height",
        "layout",
        "coverage",
        "body",
        "run_key",
        "coverage.1.faces",
    ] {
        d.push((f.to_string(), None));
    }
    d.push(("coverage.2.faces.nz".into(), Some(json!([[0, 0, 99]]))));
    d.push(("coverage.2.faces.nz".into(), Some(json!([[99, 0, 0]]))));
    d.push(("coverage.2.faces.nz".into(), Some(json!([[0, 3, 1]]))));
    d.push(("coverage.2.faces.nz".into(), Some(json!("all"))));
    d.push(("layout.projection".into(), Some(json!("mercator"))));
    d.push(("products.horizon.precision".into(), Some(json!("f8"))));
    d.push(("products.horizon.method".into(), Some(json!("magic"))));
    d.push(("products.horizon.levels".into(), Some(json!([200]))));
    d.push(("products.mip.precision".into(), Some(json!("f64"))));
    d.push(("products.fourier.layout".into(), Some(json!("pyramid"))));
    d.push(("products.fourier.encoding".into(), Some(json!("f8"))));
    d.push(("products.fourier.sigma".into(), Some(json!("gauss"))));
    d.push(("products.fourier.source".into(), Some(json!("magic"))));
    d.push(("products.fourier.levels".into(), Some(json!([200]))));
    d.push(("products.fourier.groups".into(), Some(json!([]))));
    d.push(("products.fourier.max_error_deg".into(), Some(json!(-1))));
    // Chunked face pyramids: the pattern and the chunk size come together.
    d.push((
        "products.mip.face_chunk_path".into(),
        Some(json!("minmax/{level}/{face}/face/{cy}/{cx}.exr")),
    ));
    d.push(("products.mip.face_chunk_tiles".into(), Some(json!(1024))));
    d.push(("format".into(), Some(json!("something-else"))));
    d
}

fn set_path(v: &mut serde_json::Value, path: &str, new: Option<serde_json::Value>) {
    let parts: Vec<&str> = path.split('.').collect();
    let mut cur = v;
    for p in &parts[..parts.len() - 1] {
        cur = match p.parse::<usize>() {
            Ok(i) => &mut cur[i],
            Err(_) => &mut cur[*p],
        };
    }
    let last = parts[parts.len() - 1];
    match (new, last.parse::<usize>()) {
        (Some(n), Ok(i)) => cur[i] = n,
        (Some(n), Err(_)) => cur[last] = n,
        (None, _) => {
            if let Some(o) = cur.as_object_mut() {
                o.remove(last);
            }
        }
    }
}

#[test]
fn damaged_manifests_are_refused_and_left_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join("good");
    ok(&[BAKE, &["--out", good.to_str().unwrap()]].concat());
    let text = std::fs::read_to_string(good.join("tileset.json")).unwrap();
    let original: serde_json::Value = serde_json::from_str(&text).unwrap();

    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    for (path, value) in damages() {
        let mut v = original.clone();
        set_path(&mut v, &path, value.clone());
        cases.push((
            format!("{path} = {value:?}"),
            serde_json::to_vec_pretty(&v).unwrap(),
        ));
    }
    cases.push(("empty file".into(), Vec::new()));
    cases.push((
        "truncated".into(),
        text.as_bytes()[..text.len() / 2].to_vec(),
    ));
    cases.push(("not JSON".into(), b"\x00\xff garbage".to_vec()));
    cases.push(("a JSON array".into(), b"[]".to_vec()));
    let mut huge = text.clone().into_bytes();
    huge.extend(std::iter::repeat_n(b' ', 70 << 20));
    cases.push(("70 MiB of padding".into(), huge));
    assert!(cases.len() >= 100, "{} cases", cases.len());

    let mut refused = 0;
    let mut accepted = 0;
    let mut field_named = 0;
    let dir = tmp.path().join("case");
    for (i, (what, bytes)) in cases.iter().enumerate() {
        // Copy the good tileset and damage its manifest.
        let _ = std::fs::remove_dir_all(&dir);
        copy_tree(&good, &dir);
        std::fs::write(dir.join("tileset.json"), bytes).unwrap();
        let before = snapshot(&dir);
        let d = dir.to_str().unwrap();
        // Reading and writing commands, one per case in turn.
        let cmd: Vec<&str> = match i % 6 {
            5 => vec![
                "query", "shadow", d, "--lat", "-89.9", "--lon", "0", "--level", "3", "--sun-az",
                "10", "--sun-el", "3",
            ],
            0 => vec!["info", d, "--json"],
            1 => vec!["query", "height", d, "--lat", "-89.9", "--lon", "0"],
            2 => vec![
                "query", "mip", d, "--lat", "-89.9", "--lon", "0", "--level", "1",
            ],
            3 => vec!["mip", d],
            _ => vec!["horizon", d, "--levels", "3", "--azimuths", "8"],
        };
        let o = wait_with_timeout(
            penumbra_bin()
                .args(&cmd)
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap(),
            Duration::from_secs(120),
        );
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!e.contains("panicked"), "{what}: {cmd:?} panicked: {e}");
        match o.status.code() {
            Some(0) => accepted += 1,
            Some(2) => {
                refused += 1;
                assert!(e.contains("tileset.json"), "{what}: {cmd:?}: {e}");
                field_named += e.contains("field `") as usize;
                assert_eq!(
                    snapshot(&dir),
                    before,
                    "{what}: {cmd:?} altered the tileset"
                );
                assert!(
                    !dir.join(".penumbra/staging").exists()
                        || !has_entries(&dir.join(".penumbra/staging")),
                    "{what}: staging left behind"
                );
            }
            c => panic!("{what}: {cmd:?} exited {c:?}: {e}"),
        }
    }
    eprintln!(
        "damaged manifests: {} cases, {refused} refused ({field_named} naming the field), \
         {accepted} accepted",
        cases.len()
    );
    assert!(refused >= 90, "only {refused} of {} refused", cases.len());
    assert!(
        field_named >= 150,
        "only {field_named} refusals name the damaged field"
    );
}

#[test]
fn a_manifest_that_is_a_device_is_not_read_to_the_end() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("t");
    std::fs::create_dir(&d).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink("/dev/zero", d.join("tileset.json")).unwrap();
    #[cfg(unix)]
    {
        let o = run(&["info", d.to_str().unwrap()]);
        assert_eq!(o.status.code(), Some(2));
        // Refused as what it is before a byte is read (it used to be read up to the cap).
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("character device") && err.contains("tileset.json"),
            "{err}"
        );
    }
}

#[test]
fn output_caps_refuse_nan_negative_and_oversized_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("t");
    let o = out.to_str().unwrap();
    // Before anything exists: the estimate refuses, nothing is made.
    for cap in ["NaN", "-1", "0", "0.00001"] {
        let r = run(&[BAKE, &["--out", o, "--max-output-gib", cap]].concat());
        assert_eq!(r.status.code(), Some(2), "cap {cap}");
        let e = String::from_utf8_lossy(&r.stderr);
        assert!(e.contains("--max-output-gib"), "cap {cap}: {e}");
        assert!(!out.exists(), "cap {cap} left the output folder behind");
    }
    ok(&[BAKE, &["--out", o]].concat());
    let want = snapshot(&out);
    for cmd in [
        vec!["mip", o, "--precision", "f16", "--max-output-gib"],
        vec!["horizon", o, "--levels", "2", "--max-output-gib"],
    ] {
        for cap in ["NaN", "-3", "0.0000001"] {
            let r = run(&[cmd.as_slice(), &[cap]].concat());
            assert_eq!(r.status.code(), Some(2), "{cmd:?} {cap}");
            let e = String::from_utf8_lossy(&r.stderr);
            assert!(e.contains("--max-output-gib"), "{cmd:?} {cap}: {e}");
            assert_eq!(snapshot(&out), want, "{cmd:?} {cap} changed the tileset");
        }
    }
}

/// Staged files are not synced one by one (the commit syncs them all), so a run's staging
/// folder is trusted for a resume only within the boot of the system that wrote it: a marker
/// from another boot (a system crash may have lost unsynced files) starts the stage afresh.
#[test]
fn staging_from_another_boot_is_not_resumed() {
    use penumbra::tileset::writer::Writer;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("tiles");
    let mut writer = Writer::begin(&out).unwrap();
    let first = writer.stage("tile", "key-1").unwrap();
    assert!(!first.resume);
    let kept = first.root.join("height/0/px/0/0.exr");
    std::fs::create_dir_all(kept.parent().unwrap()).unwrap();
    std::fs::write(&kept, b"staged").unwrap();
    // As a kill leaves it: no clean-up of the staging folder.
    std::mem::forget(writer);
    // Same key, same boot: resumed, the staged file kept.
    let mut writer = Writer::begin(&out).unwrap();
    let again = writer.stage("tile", "key-1").unwrap();
    if penumbra::tileset::fsio::boot_id().is_some() {
        assert!(again.resume, "same boot, same key: resume");
        assert!(kept.exists());
    }
    std::mem::forget(writer);
    // The marker claims another boot: nothing staged is trusted.
    let marker = again.root.join("run.json");
    let text = std::fs::read_to_string(&marker).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["run_key"], "key-1");
    std::fs::write(
        &marker,
        serde_json::json!({"run_key": "key-1", "boot": "another-boot"}).to_string(),
    )
    .unwrap();
    let mut writer = Writer::begin(&out).unwrap();
    let fresh = writer.stage("tile", "key-1").unwrap();
    assert!(
        !fresh.resume,
        "a staging folder from another boot was resumed"
    );
    assert!(!kept.exists(), "files staged in another boot were kept");
}
