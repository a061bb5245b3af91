//! `penumbra plan SCENE --slurm DIR --shards N` against a real Slurm: a single-node cluster
//! (munged, slurmctld, slurmd; a generated configuration in a temp folder, free ports, stopped
//! by their pid files) runs the plan's `submit.sh`, and the tileset the chain of jobs bakes is
//! byte for byte that of one `penumbra bake` — for a small embedded-terrain scene and for an
//! LDEM_4 scene with horizons, one of whose array tasks is requeued mid-run (a preemption):
//! Slurm reruns it, the shard resumes, the bytes are the same. Without Slurm the cluster tests
//! skip, except under CI, where they fail. Every bad flag exits 2 and writes nothing.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use crate::util::{penumbra_bin, shared_data, snapshot};

/// The embedded terrain (512² px) in 32² tiles down to level 10, with mipmaps and level 10's
/// horizons (16 tiles, 16 azimuths): tests/shards.rs's scene, a bake of about a second.
const SMALL: &str = "[scene]\nname = \"slurm\"\nbody = \"moon\"\n\n[layout]\ntile_size = 32\n\n\
     [[source]]\nembedded = \"south-pole\"\nsize = 512\n\n\
     [[region]]\nname = \"all\"\nbody = true\nlevel = 10\n\n\
     [renderer]\nmethods = [\"dp\", \"fourier\"]\n\n[horizon]\nlevels = [10]\nazimuths = 16\n";

fn ci() -> bool {
    std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false"))
}

/// No cluster: a skip with a message, or under CI a failure.
fn skip(why: &str) -> Option<Cluster> {
    if ci() {
        panic!("Slurm test cluster: {why}, and CI is set: CI must run the Slurm tests");
    }
    eprintln!("skipped: Slurm test cluster: {why} (apt-get install slurm-wlm munge)");
    None
}

fn which(cmd: &str) -> bool {
    std::env::var_os("PATH").is_some_and(|p| {
        std::env::split_paths(&p)
            .chain([PathBuf::from("/usr/sbin"), PathBuf::from("/sbin")])
            .any(|d| d.join(cmd).is_file())
    })
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("0.0.0.0:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A single-node Slurm cluster of this host's CPUs, all in one temp folder. Dropped, it cancels
/// its jobs and stops its daemons by their pid files (slurmd, slurmctld, munged).
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
}

impl Cluster {
    fn start() -> Option<Cluster> {
        for c in [
            "munged",
            "slurmctld",
            "slurmd",
            "sbatch",
            "squeue",
            "scontrol",
        ] {
            if !which(c) {
                return skip(&format!("{c} is not installed"));
            }
        }
        // A short path: munge's socket name must fit a sockaddr_un.
        let dir = tempfile::Builder::new()
            .prefix("pslurm")
            .tempdir_in("/tmp")
            .unwrap();
        let d = dir.path().to_path_buf();
        let key = d.join("munge.key");
        let mut bytes = vec![0u8; 1024];
        std::io::Read::read_exact(
            &mut std::fs::File::open("/dev/urandom").unwrap(),
            &mut bytes,
        )
        .unwrap();
        std::fs::write(&key, &bytes).unwrap();
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o400)).unwrap();
        }
        let c = Cluster {
            conf: d.join("slurm.conf"),
            dir,
        };
        let p = |n: &str| d.join(n).display().to_string();
        let o = Command::new("munged")
            .arg(format!("--key-file={}", p("munge.key")))
            .arg(format!("--socket={}", p("munge.sock")))
            .arg(format!("--pid-file={}", p("munged.pid")))
            .arg(format!("--log-file={}", p("munged.log")))
            .arg(format!("--seed-file={}", p("munged.seed")))
            .arg("-f")
            .output();
        if !o.as_ref().is_ok_and(|o| o.status.success()) {
            return skip(&format!("munged did not start: {o:?}"));
        }
        let host = String::from_utf8(Command::new("hostname").arg("-s").output().unwrap().stdout)
            .unwrap()
            .trim()
            .to_string();
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mem_mib = std::fs::read_to_string("/proc/meminfo")
            .ok()
            .and_then(|m| {
                m.lines()
                    .find(|l| l.starts_with("MemTotal:"))
                    .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
            })
            .map_or(4096, |kib| kib / 1024);
        let (ctld, slurmd) = (free_port(), free_port());
        std::fs::create_dir(d.join("state")).unwrap();
        std::fs::create_dir(d.join("spool")).unwrap();
        // cred_expire: a requeued job waits cred_expire + 1 s before it may start again (120 s
        // by default).
        let conf = format!(
            "ClusterName=penumbratest\nSlurmctldHost={host}\nSlurmUser=root\nSlurmdUser=root\n\
             AuthType=auth/munge\nAuthInfo=socket={sock},cred_expire=5\nCredType=cred/munge\n\
             StateSaveLocation={state}\nSlurmdSpoolDir={spool}\n\
             SlurmctldPidFile={ctldpid}\nSlurmdPidFile={slurmdpid}\n\
             SlurmctldLogFile={ctldlog}\nSlurmdLogFile={slurmdlog}\n\
             SlurmctldPort={ctld}\nSlurmdPort={slurmd}\n\
             ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\n\
             SelectType=select/cons_tres\nSelectTypeParameters=CR_Core\nReturnToService=2\n\
             AccountingStorageType=accounting_storage/none\nJobAcctGatherType=jobacct_gather/none\n\
             MinJobAge=600\n\
             NodeName={host} CPUs={cpus} RealMemory={mem_mib} State=UNKNOWN\n\
             PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP\n",
            sock = p("munge.sock"),
            state = p("state"),
            spool = p("spool"),
            ctldpid = p("slurmctld.pid"),
            slurmdpid = p("slurmd.pid"),
            ctldlog = p("slurmctld.log"),
            slurmdlog = p("slurmd.log"),
        );
        std::fs::write(&c.conf, conf).unwrap();
        for daemon in ["slurmctld", "slurmd"] {
            let o = c.cmd(daemon).arg("-f").arg(&c.conf).output();
            if !o.as_ref().is_ok_and(|o| o.status.success()) {
                return skip(&format!("{daemon} did not start: {o:?}{}", c.logs()));
            }
        }
        let t0 = Instant::now();
        loop {
            let o = c.cmd("sinfo").args(["-h", "-o", "%T"]).output().unwrap();
            let state = String::from_utf8_lossy(&o.stdout).trim().to_string();
            if o.status.success() && state == "idle" {
                break;
            }
            if t0.elapsed() > Duration::from_secs(30) {
                return skip(&format!(
                    "the node is not idle after 30 s (sinfo: {state:?}){}",
                    c.logs()
                ));
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        eprintln!(
            "Slurm test cluster up in {:.1} s ({cpus} CPUs, ports {ctld}, {slurmd})",
            t0.elapsed().as_secs_f64()
        );
        Some(c)
    }

    /// A Slurm command (client or daemon) on this cluster.
    fn cmd(&self, name: &str) -> Command {
        let mut c = Command::new(name);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn logs(&self) -> String {
        let mut s = String::new();
        for f in ["munged.log", "slurmctld.log", "slurmd.log"] {
            let t = std::fs::read_to_string(self.dir.path().join(f)).unwrap_or_default();
            let tail: Vec<&str> = t.lines().rev().take(15).collect();
            s += &format!("\n--- {f} (last lines)\n");
            for l in tail.iter().rev() {
                s += l;
                s.push('\n');
            }
        }
        s
    }

    /// Job states (`%i %T`) of `ids` still queued or running.
    fn queued(&self, ids: &[String]) -> Vec<String> {
        let o = self
            .cmd("squeue")
            .args(["-h", "-o", "%i %T", "-j", &ids.join(",")])
            .output()
            .unwrap();
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .map(str::to_string)
            .collect()
    }

    /// Every `JobState=` of job `id` (an array: of each of its tasks).
    fn states(&self, id: &str) -> Vec<String> {
        let o = self
            .cmd("scontrol")
            .args(["show", "job", id])
            .output()
            .unwrap();
        String::from_utf8_lossy(&o.stdout)
            .split_whitespace()
            .filter_map(|w| w.strip_prefix("JobState="))
            .map(str::to_string)
            .collect()
    }

    /// Wait for the chain `ids` to leave the queue, then require each job COMPLETED.
    fn wait(&self, ids: &[String], plan: &Path, timeout: Duration) {
        let t0 = Instant::now();
        while !self.queued(ids).is_empty() {
            assert!(
                t0.elapsed() < timeout,
                "the chain still runs after {timeout:?}: {:?}{}{}",
                self.queued(ids),
                job_logs(plan),
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(250));
        }
        for id in ids {
            let st = self.states(id);
            assert!(
                !st.is_empty() && st.iter().all(|s| s == "COMPLETED"),
                "job {id}: {st:?}{}{}",
                job_logs(plan),
                self.logs()
            );
        }
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // Our jobs first (this cluster's only), then the daemons by their pid files.
        let _ = self.cmd("scancel").arg("--user=root").output();
        for pidfile in ["slurmd.pid", "slurmctld.pid", "munged.pid"] {
            let Some(pid) = std::fs::read_to_string(self.dir.path().join(pidfile))
                .ok()
                .and_then(|s| s.trim().parse::<u32>().ok())
            else {
                continue;
            };
            let _ = Command::new("kill").arg(pid.to_string()).output();
            let proc = PathBuf::from(format!("/proc/{pid}"));
            let t0 = Instant::now();
            while proc.exists() && t0.elapsed() < Duration::from_secs(10) {
                std::thread::sleep(Duration::from_millis(50));
            }
            if proc.exists() {
                let _ = Command::new("kill").args(["-9", &pid.to_string()]).output();
            }
        }
    }
}

/// The plan folder's job logs, for a failure's message.
fn job_logs(plan: &Path) -> String {
    let mut s = String::new();
    if let Ok(rd) = std::fs::read_dir(plan.join("logs")) {
        let mut files: Vec<PathBuf> = rd.flatten().map(|e| e.path()).collect();
        files.sort();
        for f in files {
            s += &format!(
                "\n--- {}\n{}",
                f.display(),
                std::fs::read_to_string(&f).unwrap_or_default()
            );
        }
    }
    s
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

fn plan(scene: &Path, dir: &Path, out: &Path, extra: &[&str]) -> Output {
    penumbra_bin()
        .arg("plan")
        .arg(scene)
        .arg("--slurm")
        .arg(dir)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// `submit.sh`: the chain's (name, job id) in order.
fn submit(c: &Cluster, dir: &Path) -> Vec<(String, String)> {
    let text = ok(&c.cmd("bash").arg(dir.join("submit.sh")).output().unwrap());
    text.lines()
        .map(|l| {
            let (name, id) = l.split_once(' ').unwrap();
            (name.to_string(), id.to_string())
        })
        .collect()
}

fn bake_whole(scene: &Path, out: &Path) {
    ok(&penumbra_bin()
        .arg("bake")
        .arg(scene)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap());
}

#[test]
fn slurm_chain_bakes_the_bytes_of_one_bake() {
    let Some(c) = Cluster::start() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, SMALL).unwrap();
    let whole = tmp.path().join("whole");
    bake_whole(&scene, &whole);
    let (dir, out) = (tmp.path().join("plan"), tmp.path().join("tiles"));
    ok(&plan(&scene, &dir, &out, &["--shards", "3"]));
    let t0 = Instant::now();
    let jobs = submit(&c, &dir);
    let names: Vec<&str> = jobs.iter().map(|j| j.0.as_str()).collect();
    assert_eq!(
        names,
        [
            "tile",
            "mip",
            "mip-finish",
            "horizon",
            "horizon-finish",
            "stamp"
        ]
    );
    let ids: Vec<String> = jobs.iter().map(|j| j.1.clone()).collect();
    c.wait(&ids, &dir, Duration::from_secs(120));
    eprintln!(
        "chain of 6 jobs (3 tasks per array) in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    crate::util::same_tileset(&whole, &out, "slurm, 3 tasks");
    // The last job stamped the folder: a whole bake of the scene finds nothing to do.
    let again = ok(&penumbra_bin()
        .arg("bake")
        .arg(&scene)
        .arg("--out")
        .arg(&out)
        .arg("--json")
        .output()
        .unwrap());
    let r: serde_json::Value = serde_json::from_str(&again).unwrap();
    assert_eq!(r["unchanged"], true, "{again}");
    let stamp = std::fs::read_to_string(dir.join(format!("logs/stamp-{}.out", ids[5]))).unwrap();
    assert!(stamp.contains("== end"), "{stamp}");
    // ... and ran nothing: every stage of its report was up to date.
    let report = &stamp[stamp.find('{').unwrap()..=stamp.rfind('}').unwrap()];
    let r: serde_json::Value = serde_json::from_str(report).unwrap();
    for st in ["tile", "mip", "horizon"] {
        assert_eq!(r[st]["up_to_date"], true, "{st}: {stamp}");
        assert_eq!(r[st]["tiles_written"], 0, "{st}: {stamp}");
    }
    // Every array task logged its start and its shard's report.
    for (stage, id) in [("mip", &ids[1]), ("horizon", &ids[3])] {
        for i in 0..3 {
            let log =
                std::fs::read_to_string(dir.join(format!("logs/{stage}-{id}_{i}.out"))).unwrap();
            assert!(
                log.contains("== start") && log.contains("\"partial\": true"),
                "{log}"
            );
        }
    }
}

/// An LDEM_4 scene with horizons: docs/scenes/equatorial.toml's 60° box at 4 px/° in 64² tiles
/// (64 tiles at levels 0–3, each with horizons), 32 azimuths: about 8 core-s in the test build.
fn ldem_scene(data: &Path) -> String {
    format!(
        "[scene]\nname = \"slurm-ldem\"\nbody = \"moon\"\n\n[layout]\ntile_size = 64\n\n\
         [[source]]\npath = \"{}\"\n\n\
         [[region]]\nname = \"box\"\nlat_deg = [-30.0, 30.0]\nlon_deg = [-10.0, 50.0]\n\n\
         [renderer]\nmethods = [\"dp\", \"fourier\"]\n\n[horizon]\nazimuths = 32\n",
        data.join("lola_ldem4/LDEM_4.LBL").display()
    )
}

#[test]
fn slurm_requeued_task_resumes_its_shard() {
    let Some(data) = shared_data() else { return };
    let Some(c) = Cluster::start() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("ldem.toml");
    std::fs::write(&scene, ldem_scene(&data)).unwrap();
    let whole = tmp.path().join("whole");
    let t0 = Instant::now();
    bake_whole(&scene, &whole);
    eprintln!("one bake: {:.1} s", t0.elapsed().as_secs_f64());
    let (dir, out) = (tmp.path().join("plan"), tmp.path().join("tiles"));
    let n = 2;
    let table: serde_json::Value = serde_json::from_str(&ok(&penumbra_bin()
        .arg("plan")
        .arg(&scene)
        .args(["--shards", &n.to_string(), "--json"])
        .output()
        .unwrap()))
    .unwrap();
    let horizon = table["shards"]["stages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["stage"] == "horizon")
        .unwrap()
        .clone();
    let shard1_units = horizon["shards"][1]["units"].as_u64().unwrap();
    ok(&plan(&scene, &dir, &out, &["--shards", &n.to_string()]));
    let t0 = Instant::now();
    let jobs = submit(&c, &dir);
    let ids: Vec<String> = jobs.iter().map(|j| j.1.clone()).collect();
    let hid = &jobs.iter().find(|j| j.0 == "horizon").unwrap().1;
    // Task 1 of the horizon array, once it has recorded a unit: requeued as a preemption would.
    let units = out.join(".penumbra/staging/horizon/units");
    let task = format!("{hid}_1");
    loop {
        assert!(
            t0.elapsed() < Duration::from_secs(180),
            "horizon task 1 never ran with a unit recorded{}{}",
            job_logs(&dir),
            c.logs()
        );
        let recorded = std::fs::read_dir(&units).is_ok_and(|rd| {
            rd.flatten().any(|e| {
                e.file_name()
                    .to_string_lossy()
                    .starts_with(&format!("shard-1-of-{n}."))
                    && e.metadata().is_ok_and(|m| m.len() > 0)
            })
        });
        if recorded
            && c.queued(std::slice::from_ref(&task))
                .iter()
                .any(|l| l.ends_with("RUNNING"))
        {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let o = c.cmd("scontrol").args(["requeue", &task]).output().unwrap();
    ok(&o);
    eprintln!("requeued {task} at {:.1} s", t0.elapsed().as_secs_f64());
    c.wait(&ids, &dir, Duration::from_secs(300));
    eprintln!("chain in {:.1} s", t0.elapsed().as_secs_f64());
    crate::util::same_tileset(&whole, &out, "slurm, a task requeued");
    // The task ran twice into one log (--open-mode=append): its second run did what the
    // first had not recorded, no more.
    let log = std::fs::read_to_string(dir.join(format!("logs/horizon-{task}.out"))).unwrap();
    assert_eq!(log.matches("== start").count(), 2, "{log}");
    assert!(log.contains("restart 1"), "{log}");
    let reports: Vec<serde_json::Value> = log
        .split("\n{")
        .skip(1)
        .filter_map(|j| {
            let end = j.find("\n}")?;
            serde_json::from_str(&format!("{{{}", &j[..end + 2])).ok()
        })
        .collect();
    assert_eq!(reports.len(), 1, "one report, the rerun's: {log}");
    let rerun = reports[0]["units_run"].as_u64().unwrap();
    assert!(
        rerun < shard1_units,
        "the rerun ran {rerun} of the shard's {shard1_units} units: it did not resume\n{log}"
    );
}

/// A plan of the small scene, for the flag checks (no cluster).
struct Flags {
    tmp: tempfile::TempDir,
    scene: PathBuf,
}

fn flags() -> Flags {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, SMALL).unwrap();
    Flags { tmp, scene }
}

impl Flags {
    fn run(&self, dir: &Path, extra: &[&str]) -> Output {
        plan(&self.scene, dir, &self.tmp.path().join("tiles"), extra)
    }
}

fn refused(o: &Output, words: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "not refused: {err}");
    for w in words {
        assert!(err.contains(w), "{w:?} not in: {err}");
    }
}

#[test]
fn slurm_plan_scripts() {
    let f = flags();
    let dir = f.tmp.path().join("plan");
    ok(&f.run(&dir, &["--shards", "4"]));
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            ".penumbra-slurm",
            "1-tile.sbatch",
            "2-mip.sbatch",
            "3-mip-finish.sbatch",
            "4-horizon.sbatch",
            "5-horizon-finish.sbatch",
            "6-stamp.sbatch",
            "logs",
            "submit.sh"
        ]
    );
    let read = |n: &str| std::fs::read_to_string(dir.join(n)).unwrap();
    let h = read("4-horizon.sbatch");
    let scene = std::fs::canonicalize(&f.scene).unwrap();
    let tiles = f.tmp.path().join("tiles");
    for want in [
        "#SBATCH --array=0-3\n".to_string(),
        "#SBATCH --requeue\n".into(),
        "#SBATCH --open-mode=append\n".into(),
        "#SBATCH --cpus-per-task=1\n".into(),
        format!(
            "#SBATCH --output={}/logs/horizon-%A_%a.out\n",
            dir.display()
        ),
        format!(
            "'{}' --quiet --threads 1 bake '{}' --out '{}' --stage horizon --shard \
             \"${{SLURM_ARRAY_TASK_ID}}/4\" --json\n",
            std::fs::canonicalize(env!("CARGO_BIN_EXE_penumbra"))
                .unwrap()
                .display(),
            scene.display(),
            tiles.display()
        ),
        "# --time: 600 s (start, planning) + 3× the estimate".into(),
        "# --mem: 1.5× the plan's model".into(),
    ] {
        assert!(h.contains(&want), "{want:?} not in:\n{h}");
    }
    assert!(read("5-horizon-finish.sbatch").contains("--stage horizon --finish --json\n"));
    assert!(read("1-tile.sbatch").contains("--stage tile --json\n"));
    let submit = read("submit.sh");
    assert!(
        submit.contains("sbatch --parsable ${prev:+--dependency=afterok:$prev}"),
        "{submit}"
    );
    // Deterministic: the same scene and flags give the same bytes; a rerun replaces the plan
    // it wrote (other flags, other bytes) and keeps its logs.
    let before = snapshot(&dir);
    std::fs::write(dir.join("logs/kept.out"), "a job's log").unwrap();
    ok(&f.run(&dir, &["--shards", "4"]));
    let mut again = snapshot(&dir);
    assert_eq!(
        again.remove("logs/kept.out").as_deref(),
        Some(&b"a job's log"[..])
    );
    assert_eq!(before, again);
    ok(&f.run(
        &dir,
        &[
            "--shards",
            "2",
            "--time",
            "1:00:00",
            "--mem",
            "2G",
            "--cpus-per-task",
            "2",
        ],
    ));
    let h = read("4-horizon.sbatch");
    for want in [
        "#SBATCH --array=0-1\n",
        "#SBATCH --time=01:00:00\n",
        "#SBATCH --mem=2048M\n",
        "#SBATCH --cpus-per-task=2\n",
        "--threads 2 ",
        "# --time: --time\n",
    ] {
        assert!(h.contains(want), "{want:?} not in:\n{h}");
    }
    assert!(dir.join("logs/kept.out").is_file());
    // No temp folder left beside it.
    let left: Vec<_> = std::fs::read_dir(f.tmp.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .filter(|n| n.to_string_lossy().starts_with('.'))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    // The embedded scene: no scene argument in the jobs' commands.
    let emb = f.tmp.path().join("embedded");
    ok(&penumbra_bin()
        .arg("plan")
        .arg("--slurm")
        .arg(&emb)
        .args(["--shards", "2"])
        .output()
        .unwrap());
    let t = std::fs::read_to_string(emb.join("1-tile.sbatch")).unwrap();
    assert!(t.contains("--threads 1 bake --out '"), "{t}");
    assert!(t.contains("the embedded scene"), "{t}");
}

#[test]
fn slurm_bad_flags_exit_2_and_write_nothing() {
    let f = flags();
    let root = f.tmp.path();
    let dir = root.join("plan");
    let cases: &[(&[&str], &[&str])] = &[
        (&["--shards", "0"], &["--shards", "0"]),
        (
            &["--shards", "17"],
            &["horizon stage has 16 units", "--shards 16 or fewer"],
        ),
        (&["--shards", "1001"], &["1..=1000", "MaxArraySize"]),
        (
            &["--shards", "2", "--time", "1h"],
            &["--time '1h'", "1:30:00"],
        ),
        (&["--shards", "2", "--time", "0"], &["--time '0'", "zero"]),
        (
            &["--shards", "2", "--time", "1:2:3:4"],
            &["--time '1:2:3:4'"],
        ),
        (&["--shards", "2", "--mem", "4X"], &["--mem '4X'", "4G"]),
        (&["--shards", "2", "--mem", "0"], &["--mem '0'", "zero"]),
        (&["--shards", "2", "--mem", "1.5G"], &["--mem '1.5G'"]),
        (
            &["--shards", "2", "--cpus-per-task", "0"],
            &["--cpus-per-task 0"],
        ),
        (
            &["--shards", "2", "--partition", "a b"],
            &["--partition 'a b'"],
        ),
        (
            &["--shards", "2", "--account", "x;rm"],
            &["--account 'x;rm'"],
        ),
        (
            &["--shards", "2", "--penumbra", "relative/penumbra"],
            &["--penumbra", "absolute"],
        ),
        (
            &["--shards", "2", "--penumbra", "/nonexistent/penumbra"],
            &["/nonexistent/penumbra"],
        ),
    ];
    for (extra, words) in cases {
        let o = f.run(&dir, extra);
        refused(&o, words);
        assert!(!dir.exists(), "{extra:?} wrote {}", dir.display());
    }
    // --slurm without --shards.
    let o = penumbra_bin()
        .arg("plan")
        .arg(&f.scene)
        .arg("--slurm")
        .arg(&dir)
        .output()
        .unwrap();
    refused(&o, &["--shards"]);
    assert!(!dir.exists());
    // A tileset folder whose parent is missing.
    let o = plan(&f.scene, &dir, &root.join("gone/tiles"), &["--shards", "2"]);
    refused(&o, &["gone", "--out", "does not exist"]);
    assert!(!dir.exists() && !root.join("gone").exists());
    // A folder whose parent is missing; a path sbatch cannot carry.
    let deep = root.join("no/such/plan");
    refused(
        &f.run(&deep, &["--shards", "2"]),
        &["no/such", "does not exist", "mkdir"],
    );
    assert!(!root.join("no").exists());
    let pct = root.join("plan%j");
    refused(&f.run(&pct, &["--shards", "2"]), &["plan%j", "#SBATCH"]);
    assert!(!pct.exists());
    // A folder that is not a plan penumbra wrote, or a file: refused, left as it was.
    let theirs = root.join("theirs");
    std::fs::create_dir(&theirs).unwrap();
    std::fs::write(theirs.join("job.sh"), "mine").unwrap();
    refused(
        &f.run(&theirs, &["--shards", "2"]),
        &["theirs", "not a Slurm plan penumbra wrote"],
    );
    assert_eq!(snapshot(&theirs).len(), 1);
    std::fs::write(theirs.join(".penumbra-slurm"), "forged").unwrap();
    refused(
        &f.run(&theirs, &["--shards", "2"]),
        &["not a Slurm plan penumbra wrote"],
    );
    let file = root.join("file");
    std::fs::write(&file, "x").unwrap();
    refused(&f.run(&file, &["--shards", "2"]), &["not a folder"]);
    assert_eq!(std::fs::read(&file).unwrap(), b"x");
    // A bad flag against a plan penumbra wrote leaves that plan as it was.
    ok(&f.run(&dir, &["--shards", "2"]));
    let before = snapshot(&dir);
    refused(
        &f.run(&dir, &["--shards", "2", "--mem", "lots"]),
        &["--mem 'lots'"],
    );
    assert_eq!(before, snapshot(&dir));
}
