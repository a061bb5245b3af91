//! The window under Xvfb: `--screenshot PNG --frames 3` opens the window, renders three
//! frames, saves what the window shows (terrain and the status line) and exits 0; and the X
//! server's own screenshot (ImageMagick's `import`) of a running viewer shows the frame it
//! presented. Without Xvfb or `import` the tests skip (fail under CI, where `.ci/run` installs
//! them).

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::util::{gpu, read_png, scene, skip, stderr, tmp, view};

/// An Xvfb server, killed when dropped.
pub struct Xvfb {
    child: Child,
    pub display: String,
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start Xvfb on a free display number, or None (after a skip message) when it is missing.
pub fn xvfb() -> Option<Xvfb> {
    if Command::new("Xvfb")
        .arg("-help")
        .stderr(Stdio::null())
        .stdout(Stdio::null())
        .status()
        .is_err()
    {
        skip("Xvfb not found (apt-get install xvfb)");
        return None;
    }
    let base = 90 + (std::process::id() % 400);
    for n in base..base + 20 {
        if Path::new(&format!("/tmp/.X11-unix/X{n}")).exists()
            || Path::new(&format!("/tmp/.X{n}-lock")).exists()
        {
            continue;
        }
        let child = Command::new("Xvfb")
            .args([
                &format!(":{n}"),
                "-screen",
                "0",
                "640x480x24",
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .ok()?;
        let x = Xvfb {
            child,
            display: format!(":{n}"),
        };
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(10) {
            if Path::new(&format!("/tmp/.X11-unix/X{n}")).exists() {
                return Some(x);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    panic!("Xvfb did not start");
}

#[test]
fn the_window_renders_frames_and_saves_a_screenshot() {
    if !gpu() {
        return;
    }
    let Some(x) = xvfb() else {
        return;
    };
    let d = tmp();
    let shot = d.path().join("window.png");
    let o = view()
        .args([
            scene().to_str().unwrap(),
            "--size",
            "256x192",
            "--camera=-89.8,30,9000,210,-60,50",
            "--sun-lat=-2.5",
            "--sun-lon",
            "75",
            "--screenshot",
            shot.to_str().unwrap(),
            "--frames",
            "3",
        ])
        .env("DISPLAY", &x.display)
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    let e = stderr(&o);
    assert!(o.status.success(), "exit {:?}: {e}", o.status.code());
    assert!(e.contains("after 3 frames"), "{e}");
    let (w, h, px) = read_png(&shot);
    assert_eq!((w, h), (256, 192));
    // The status line: its pale yellow text in the top-left band.
    let text = px[..w as usize * 12]
        .iter()
        .filter(|p| p[0] > 230 && p[1] > 220 && p[2] < 220 && p[2] + 25 < p[0])
        .count();
    assert!(text > 50, "no status line ({text} text pixels)");
    // Terrain below it: many shades.
    let mut g: Vec<u8> = px[w as usize * 24..].iter().map(|p| p[1]).collect();
    g.sort();
    g.dedup();
    assert!(g.len() > 30, "{} shades", g.len());
}

#[test]
fn the_x_server_shows_the_presented_frame() {
    if !gpu() {
        return;
    }
    if Command::new("import")
        .arg("-version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_err()
    {
        skip("ImageMagick's import not found (apt-get install imagemagick)");
        return;
    }
    let Some(x) = xvfb() else {
        return;
    };
    let d = tmp();
    let root = d.path().join("root.png");
    let mut viewer = view()
        .args([
            scene().to_str().unwrap(),
            "--size",
            "200x150",
            "--camera=-89.8,30,9000,210,-60,50",
            "--sun-lat=-8",
            "--sun-lon",
            "75",
        ])
        .env("DISPLAY", &x.display)
        .env_remove("WAYLAND_DISPLAY")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Screenshots of the whole screen until the window's area shows terrain (no window
    // manager: the window sits at the top-left corner).
    let t0 = Instant::now();
    let mut shades = 0;
    while t0.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(500));
        if let Ok(Some(_)) = viewer.try_wait() {
            break;
        }
        let ok = Command::new("import")
            .args([
                "-display",
                &x.display,
                "-window",
                "root",
                root.to_str().unwrap(),
            ])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if !ok {
            continue;
        }
        let (w, _, px) = read_png(&root);
        let mut g: Vec<u8> = (40..150)
            .flat_map(|r| (0..200).map(move |c| (r, c)))
            .map(|(r, c)| px[r * w as usize + c][1])
            .collect();
        g.sort();
        g.dedup();
        shades = g.len();
        if shades > 30 {
            break;
        }
    }
    let running = matches!(viewer.try_wait(), Ok(None));
    let _ = viewer.kill();
    let out = viewer.wait_with_output().unwrap();
    assert!(
        running,
        "the viewer exited: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        shades > 30,
        "the X screen shows {shades} shades in the window's area"
    );
}
