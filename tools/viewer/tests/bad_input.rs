//! Bad input exits 2 with a message that says what is wrong and what to do, and writes no
//! frame: a missing folder, a tileset without the method's product, malformed flags, no
//! window system, no GPU adapter.

use crate::util::{run, scene, scene_without_horizons, stderr, tmp, view};

/// `args` exit 2, say `needle` on stderr, and leave no `frame.png` in `out`.
fn refused(args: &[&str], out: &std::path::Path, needle: &str) {
    let o = run(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
    assert!(e.contains(needle), "{args:?}: expected {needle:?} in: {e}");
    assert!(!e.contains("panicked"), "{args:?}: {e}");
    assert!(!out.join("frame.png").exists(), "{args:?} wrote a frame");
}

#[test]
fn bad_input_exits_2_and_writes_nothing() {
    let d = tmp();
    let out = d.path().join("frame.png");
    let o = out.to_str().unwrap();
    let bare = scene_without_horizons().to_str().unwrap();
    let full = scene().to_str().unwrap();
    let missing = d.path().join("nothing-here");
    let m = missing.to_str().unwrap();
    let h = |extra: &[&str], dir: &str| -> Vec<String> {
        let mut v: Vec<String> = [dir, "--headless", "--out", o, "--size", "64x48"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let cases: Vec<(Vec<String>, &str)> = vec![
        (h(&[], m), "no such folder"),
        // Fourier without pyramids: name what makes them.
        (
            h(&["--method", "fourier"], bare),
            "penumbra horizon --fourier",
        ),
        (h(&["--method", "smoke"], full), "unknown shadow method"),
        (h(&["--camera", "1,2"], full), "--camera"),
        (h(&["--camera=-91,0,100"], full), "--camera"),
        (h(&["--camera", "a,b,c"], full), "--camera"),
        (h(&["--sun-lat", "10"], full), "--sun-lon"),
        (h(&["--sun-lat", "95", "--sun-lon", "0"], full), "--sun-lat"),
        (h(&["--size", "0x10"], full), "--size"),
        (h(&["--steps", "0", "--method", "uniform"], full), "--steps"),
        (h(&["--dp-levels", "0,5"], full), "--dp-levels"),
        (
            h(&["--method", "fourier", "--fourier-model", "disc"], full),
            "--fourier-model",
        ),
        (h(&["--fourier-model", "Exact"], full), "--fourier-model"),
        (h(&["--level", "40"], full), "--level"),
        (
            h(
                &["--sun-distance-au", "0", "--sun-lat", "0", "--sun-lon", "0"],
                full,
            ),
            "sun-distance-au",
        ),
        (vec![full.into(), "--headless".into()], "--out"),
    ];
    for (args, needle) in &cases {
        let a: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
        refused(&a, d.path(), needle);
    }
    // A tileset folder that is not one.
    std::fs::create_dir_all(&missing).unwrap();
    refused(
        &h(&[], m).iter().map(|s| s.as_str()).collect::<Vec<_>>(),
        d.path(),
        "tileset",
    );
}

#[test]
fn no_window_system_exits_2() {
    let d = tmp();
    let o = view()
        .arg(scene())
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("WAYLAND_SOCKET")
        .output()
        .unwrap();
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(
        e.contains("no window system") && e.contains("--headless"),
        "{e}"
    );
    drop(d);
}

#[test]
fn no_gpu_adapter_exits_2_with_what_to_do() {
    let d = tmp();
    let out = d.path().join("frame.png");
    // Point the Vulkan loader at no driver and keep wgpu to Vulkan: no adapter at all.
    let o = view()
        .args([
            scene().to_str().unwrap(),
            "--headless",
            "--out",
            out.to_str().unwrap(),
        ])
        .env("WGPU_BACKEND", "vulkan")
        .env("VK_ICD_FILENAMES", d.path().join("none.json"))
        .env("VK_DRIVER_FILES", d.path().join("none.json"))
        .output()
        .unwrap();
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.to_lowercase().contains("adapter"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
    assert!(!out.exists());
}
