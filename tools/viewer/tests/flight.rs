//! `--path`: a camera path flown headless (`--record`: one PNG per row and `report.json`) and
//! in the window under Xvfb, with tiles streamed; `--wait-tiles` frames are complete and the
//! same bytes on a rerun; bad path files exit 2 naming the line and write nothing.

use std::path::Path;

use serde_json::Value;

use crate::util::{gpu, json, run, scene, stderr, tmp, view};

/// A short descent towards the scene's pole, looking along the path except where a row says
/// (heading and pitch given on row 3, pitch only on row 5).
const PATH: &str = "lat_deg,lon_deg,height_m,heading_deg,pitch_deg
-89.80,30,9000,,
-89.82,30,8000,,
-89.84,30,7000,210,-50
-89.86,30,6000,,
-89.88,30,5000,,-70
-89.90,30,4000,,
";

fn write_path(dir: &Path, text: &str) -> String {
    let p = dir.join("path.csv");
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

/// Fly `path` headless over the scene, recording into `rec`, with `extra` flags; the report.
fn fly(path: &str, rec: &Path, extra: &[&str]) -> Value {
    let mut args = vec![
        scene().to_str().unwrap(),
        "--headless",
        "--path",
        path,
        "--record",
        rec.to_str().unwrap(),
        "--size",
        "96x72",
        "--sun-lat=-2.5",
        "--sun-lon",
        "75",
        "--json",
    ];
    args.extend_from_slice(extra);
    json(&run(&args))
}

fn n(v: &Value, k: &str) -> u64 {
    v[k].as_u64().unwrap_or_else(|| panic!("{k} in {v}"))
}

/// The report's counts agree with its frames. `waited`: the frames waited for their tiles, so
/// tiles were loaded (a streamed flight this short may end before its first tile arrives).
fn check_report(r: &Value, rows: u64, waited: bool) {
    assert_eq!(n(r, "rows"), rows);
    assert_eq!(n(r, "frames"), rows);
    if waited {
        assert!(n(r, "tiles_loaded") > 0, "{r}");
    }
    let fm = &r["frame_ms"];
    let (p50, p95, max) = (
        fm["p50"].as_f64().unwrap(),
        fm["p95"].as_f64().unwrap(),
        fm["max"].as_f64().unwrap(),
    );
    assert!(0.0 < p50 && p50 <= p95 && p95 <= max, "{fm}");
    if r["gpu_ms"].is_object() {
        assert!(r["outside_gpu_ms"]["max"].as_f64().unwrap() <= max, "{r}");
    }
    let frames = r["per_frame"].as_array().unwrap();
    assert_eq!(frames.len() as u64, rows);
    let mut waiting = 0;
    for (k, f) in frames.iter().enumerate() {
        assert_eq!(n(f, "index"), k as u64);
        // Line 1 is the header.
        assert_eq!(n(f, "line"), k as u64 + 2);
        assert!(n(f, "missing") <= n(f, "chosen"), "{f}");
        waiting += (n(f, "missing") > 0) as u64;
    }
    assert_eq!(n(r, "frames_waiting"), waiting);
}

#[test]
fn a_headless_flight_records_every_row_and_a_report() {
    if !gpu() {
        return;
    }
    let d = tmp();
    let path = write_path(d.path(), PATH);
    // Streaming: the first frame cannot have its tiles (nothing was asked before it).
    let rec = d.path().join("frames");
    let r = fly(&path, &rec, &[]);
    check_report(&r, 6, false);
    assert!(n(&r, "frames_waiting") >= 1, "{r}");
    assert!(n(&r["per_frame"][0], "missing") > 0);
    for k in 0..6 {
        assert!(rec.join(format!("frame_{k:05}.png")).is_file());
    }
    assert!(!rec.join("frame_00006.png").exists());
    let on_disk: Value =
        serde_json::from_slice(&std::fs::read(rec.join("report.json")).unwrap()).unwrap();
    assert_eq!(on_disk["frames"], r["frames"]);
    assert_eq!(on_disk["per_frame"][5]["file"], "frame_00005.png");
    // Row 3's view is its own.
    let cam = r["per_frame"][2]["camera"].as_str().unwrap();
    assert!(cam.contains(",210.000,-50.000,"), "{cam}");
    // A shorter flight into the same record replaces it whole: its frames and report, none of
    // the earlier flight's frames past its own.
    let short: String = PATH.lines().take(4).map(|l| format!("{l}\n")).collect();
    let short_path = d.path().join("short.csv");
    std::fs::write(&short_path, short).unwrap();
    let r3 = fly(short_path.to_str().unwrap(), &rec, &[]);
    check_report(&r3, 3, false);
    let mut names: Vec<String> = std::fs::read_dir(&rec)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "frame_00000.png",
            "frame_00001.png",
            "frame_00002.png",
            "report.json"
        ]
    );

    // Waiting for the tiles: complete frames, none drawn with a tile missing, the same
    // bytes on a rerun.
    let a = d.path().join("a");
    let b = d.path().join("b");
    let ra = fly(&path, &a, &["--wait-tiles", "--load-threads", "2"]);
    check_report(&ra, 6, true);
    assert_eq!(n(&ra, "frames_waiting"), 0, "{ra}");
    assert!(ra["per_frame"][0]["wait_ms"].as_f64().unwrap() > 0.0);
    fly(&path, &b, &["--wait-tiles"]);
    for k in 0..6 {
        let f = format!("frame_{k:05}.png");
        let (x, y) = (
            std::fs::read(a.join(&f)).unwrap(),
            std::fs::read(b.join(&f)).unwrap(),
        );
        assert!(x == y, "{f} differs between two --wait-tiles runs");
    }
    // The last complete frame shows terrain: many shades.
    let (_, _, px) = crate::util::read_png(&a.join("frame_00005.png"));
    let mut g: Vec<u8> = px.iter().map(|p| p[1]).collect();
    g.sort();
    g.dedup();
    assert!(g.len() > 20, "{} shades", g.len());
}

#[test]
fn bad_paths_exit_2_naming_the_line_and_write_nothing() {
    let d = tmp();
    let rec = d.path().join("frames");
    let full = scene().to_str().unwrap();
    let cases = [
        ("", "empty"),
        ("# only a comment\n", "empty"),
        ("lat_deg,lon_deg,height_m\n", "no rows"),
        (
            "lat_deg,lon_deg,height_m\n-89.8,30,9000\n-89.8,x,9000\n",
            "line 3, column lon_deg",
        ),
        (
            "lat_deg,lon_deg,height_m\n-89.8,30,9000\n-89.8,30\n",
            "line 3: 2 fields",
        ),
        (
            "lat_deg,lon_deg,height_m\n-89.8,30,9000\n-89.8,30,9000\n-89.8,30,NaN\n",
            "line 4, column height_m",
        ),
        (
            "lat_deg,lon_deg,height_m\n-95,30,9000\n",
            "line 2, column lat_deg",
        ),
        (
            "lat_deg,lon_deg,height_m,pitch_deg\n-89.8,30,9000,-120\n",
            "line 2, column pitch_deg",
        ),
        // Inside the body: below the scene's lowest terrain.
        (
            "lat_deg,lon_deg,height_m\n-89.8,30,9000\n-89.8,30,-19000\n",
            "line 3: height_m -19000 m is below the tileset's lowest terrain",
        ),
    ];
    for (text, needle) in cases {
        let path = write_path(d.path(), text);
        let o = run(&[
            full,
            "--headless",
            "--path",
            &path,
            "--record",
            rec.to_str().unwrap(),
        ]);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{text:?}: {e}");
        assert!(e.contains(needle), "{text:?}: expected {needle:?} in: {e}");
        assert!(
            e.contains("path.csv"),
            "{text:?}: the file is not named: {e}"
        );
        assert!(!e.contains("panicked"), "{e}");
        assert!(!rec.exists(), "{text:?}: the record folder was made");
    }
    // The window refuses a bad path before it looks for a window system.
    let path = write_path(d.path(), "lat_deg,lon_deg,height_m\n-89.8,30,-19000\n");
    let o = view()
        .args([full, "--path", &path])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("line 2"), "{}", stderr(&o));
    // Flags that do not go together.
    let good = write_path(d.path(), PATH);
    for (args, needle) in [
        (
            vec![full, "--headless", "--out", "x.png", "--record", "r"],
            "--record goes with --path",
        ),
        (
            vec![full, "--headless", "--path", &good, "--out", "x.png"],
            "--out does not go with --path",
        ),
        (
            vec![full, "--headless", "--path", &good, "--frames", "2"],
            "--frames does not go",
        ),
        (
            vec![full, "--path", &good, "--record", "r"],
            "--record is for --headless",
        ),
        (
            vec![full, "--headless", "--path", &good, "--load-threads", "0"],
            "--load-threads",
        ),
    ] {
        let o = run(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        assert!(stderr(&o).contains(needle), "{args:?}: {}", stderr(&o));
    }
    assert!(!rec.exists());
    // A record folder holding someone else's files is refused, and they are left as they were.
    let theirs = d.path().join("theirs");
    std::fs::create_dir(&theirs).unwrap();
    std::fs::write(theirs.join("report.json"), "mine").unwrap();
    std::fs::write(theirs.join("notes.txt"), "mine").unwrap();
    let o = run(&[
        full,
        "--headless",
        "--path",
        &good,
        "--record",
        theirs.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("notes.txt") && stderr(&o).contains("not a flight's record"),
        "{}",
        stderr(&o)
    );
    assert_eq!(std::fs::read(theirs.join("report.json")).unwrap(), b"mine");
    assert_eq!(std::fs::read_dir(&theirs).unwrap().count(), 2);
}

#[test]
fn the_window_flies_the_path_and_reports() {
    if !gpu() {
        return;
    }
    let Some(x) = crate::window::xvfb() else {
        return;
    };
    let d = tmp();
    let path = write_path(d.path(), PATH);
    let shot = d.path().join("last.png");
    let o = view()
        .args([
            scene().to_str().unwrap(),
            "--path",
            &path,
            "--size",
            "128x96",
            "--sun-lat=-2.5",
            "--sun-lon",
            "75",
            "--json",
            "--screenshot",
            shot.to_str().unwrap(),
        ])
        .env("DISPLAY", &x.display)
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    let r = json(&o);
    assert_eq!(r["mode"], "window");
    check_report(&r, 6, false);
    assert!(shot.is_file(), "no screenshot at the path's end");
}

/// Press and release the key of `keysym` in the X server `display` (XTEST), with the
/// keyboard focus on the top-most window (no window manager gives it one: winit takes keys
/// only after a focus-in).
fn press(display: &str, keysym: u32) {
    use x11rb::connection::Connection as _;
    use x11rb::protocol::xproto::{self, ConnectionExt as _};
    use x11rb::protocol::xtest::ConnectionExt as _;
    let (conn, screen) = x11rb::connect(Some(display)).expect("the X server answers");
    let root = conn.setup().roots[screen].root;
    let (lo, hi) = (conn.setup().min_keycode, conn.setup().max_keycode);
    let map = conn
        .get_keyboard_mapping(lo, hi - lo + 1)
        .unwrap()
        .reply()
        .unwrap();
    let per = map.keysyms_per_keycode as usize;
    let code = map
        .keysyms
        .chunks(per)
        .position(|syms| syms.contains(&keysym))
        .map(|k| lo + k as u8)
        .expect("the key is on the keyboard map");
    let tree = conn.query_tree(root).unwrap().reply().unwrap();
    let window = *tree.children.last().expect("a window is open");
    conn.set_input_focus(xproto::InputFocus::PARENT, window, x11rb::CURRENT_TIME)
        .unwrap();
    // A round trip: the server has handled the requests before this returns.
    let sync = || {
        conn.flush().unwrap();
        conn.get_input_focus().unwrap().reply().unwrap();
    };
    sync();
    std::thread::sleep(std::time::Duration::from_millis(300));
    for kind in [xproto::KEY_PRESS_EVENT, xproto::KEY_RELEASE_EVENT] {
        conn.xtest_fake_input(kind, code, x11rb::CURRENT_TIME, root, 0, 0, 0)
            .unwrap();
        sync();
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
}

#[test]
fn the_window_takes_keys_while_it_flies_and_esc_ends_the_flight_with_a_report() {
    use std::io::{BufRead as _, BufReader};
    use std::process::Stdio;
    use std::time::{Duration, Instant};
    if !gpu() {
        return;
    }
    let Some(x) = crate::window::xvfb() else {
        return;
    };
    let d = tmp();
    // 3000 rows: far more than the second the test lets it fly.
    let mut text = String::from("lat_deg,lon_deg,height_m\n");
    let rows = 3000;
    for k in 0..rows {
        let f = k as f64 / rows as f64;
        text.push_str(&format!(
            "{},30,{}\n",
            -89.80 - 0.15 * f,
            9000.0 - 6000.0 * f
        ));
    }
    let path = write_path(d.path(), &text);
    let mut child = view()
        .args([
            scene().to_str().unwrap(),
            "--path",
            &path,
            "--size",
            "128x96",
            "--json",
        ])
        .env("DISPLAY", &x.display)
        .env_remove("WAYLAND_DISPLAY")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for the window to be up (its first line on stderr), let it fly, press Esc.
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    let t0 = Instant::now();
    let mut log = Vec::new();
    while !log.iter().any(|l: &String| l.contains("window")) {
        match rx.recv_timeout(Duration::from_secs(1)) {
            Ok(l) => log.push(l),
            Err(_) if t0.elapsed() > Duration::from_secs(60) => panic!("no window: {log:?}"),
            Err(_) => {}
        }
    }
    std::thread::sleep(Duration::from_secs(1));
    press(&x.display, 0xff1b); // XK_Escape
    let t1 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t1.elapsed() > Duration::from_secs(30) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the window did not close on Esc");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{:?}: {log:?}", o.status);
    let r: Value = serde_json::from_slice(&o.stdout).expect("the report");
    assert_eq!(n(&r, "rows"), rows);
    let frames = n(&r, "frames");
    assert!(frames >= 1 && frames < rows, "{frames} frames flown");
    assert_eq!(r["per_frame"].as_array().unwrap().len() as u64, frames);
}
