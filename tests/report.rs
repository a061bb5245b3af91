//! `penumbra report`: every method measured against the reference on a small tileset, the
//! recommendation checked on a second, independent sample of pixels, bad input refused with
//! exit 2 and nothing written, and report.html opened in a real headless browser (Debian's
//! chromium; required under CI, skipped with a message elsewhere when absent).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::util::penumbra_bin;

fn run(args: &[&str]) -> Output {
    penumbra_bin().args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn json(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", stderr(o));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// The embedded terrain at 1024 px in 128-px tiles (12 levels, the finest at 13 m/px), heights
/// and mipmaps only.
fn tileset(dir: &Path) -> String {
    let o = dir.join("tiles");
    let s = o.to_str().unwrap().to_string();
    let out = run(&[
        "bake",
        "--out",
        &s,
        "--scene-size",
        "1024",
        "--tile-size",
        "128",
        "--no-horizons",
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    s
}

fn report(tiles: &str, out: &Path, extra: &[&str]) -> serde_json::Value {
    report_with(tiles, out, extra, true)
}

fn report_with(tiles: &str, out: &Path, extra: &[&str], fixed: bool) -> serde_json::Value {
    let o = out.to_str().unwrap();
    // A fixed sample (three 32-px blocks), the same pixels however loaded the machine is.
    let mut args = vec![
        "report",
        tiles,
        "--out",
        o,
        "--json",
        "--quiet",
        "--blocks",
        "3",
        "--block-px",
        "32",
    ];
    if !fixed {
        args.truncate(6);
    }
    args.extend_from_slice(extra);
    json(&run(&args))
}

fn rows<'a>(r: &'a serde_json::Value, key: &str) -> &'a Vec<serde_json::Value> {
    r[key].as_array().unwrap_or_else(|| panic!("{key} missing"))
}

fn num(v: &serde_json::Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} missing in {v}"))
}

#[test]
fn report_measures_every_method_against_the_reference_and_writes_its_files() {
    let tmp = tempfile::tempdir().unwrap();
    let tiles = tileset(tmp.path());
    let out = tmp.path().join("rep");
    let r = report(&tiles, &out, &[]);
    for f in [
        "report.html",
        "report.md",
        "report.json",
        "report-horizons.svg",
        "report-fourier.svg",
        "report-shadows.svg",
    ] {
        assert!(out.join(f).is_file(), "{f} not written");
    }
    assert!(num(&r, "pixels") > 0.0);
    let hz = rows(&r, "horizons");
    let names: Vec<&str> = hz.iter().map(|h| h["method"].as_str().unwrap()).collect();
    assert_eq!(names, ["reference", "exact", "fast", "sweep"]);
    // The reference against itself is exact; the exact method within 1e-3° of it; the fast
    // method within its budget (on this smooth terrain it finds the reference's answers); the
    // sweep close but not equal (a report that compared a method with itself would show 0).
    assert_eq!(num(&hz[0], "rms_deg"), 0.0);
    assert!(num(&hz[1], "rms_deg") < 1e-3, "{}", hz[1]);
    assert!(num(&hz[2], "rms_deg") < 0.03, "{}", hz[2]);
    let sweep = num(&hz[3], "rms_deg");
    assert!(sweep > 0.0 && sweep < 0.1, "{}", hz[3]);
    for h in hz {
        assert!(num(h, "core_ns") > 0.0, "{h}");
        assert!(num(h, "samples") > 0.0, "{h}");
        // The strata partition the samples, and the worst one holds the maximum.
        let st = h["strata"].as_array().unwrap();
        assert_eq!(st.len(), 6);
        let total: f64 = st.iter().map(|x| num(x, "samples")).sum();
        assert_eq!(total, num(h, "samples"), "{h}");
        let worst = st.iter().map(|x| num(x, "max_deg")).fold(0.0, f64::max);
        assert_eq!(worst, num(h, "max_deg"), "{h}");
    }
    // 4 K × 2 encodings × (2 layouts × 2 tapers + fitted) + classic 8 and 12.
    let f = rows(&r, "fourier");
    assert_eq!(f.len(), 42);
    let per = |name: &str| {
        num(
            f.iter().find(|x| x["variant"] == name).expect(name),
            "per_pct",
        )
    };
    // More coefficients decide more shadows right; the full layout is at least as good as
    // the reduced one at the same K.
    assert!(per("F32 full f16 plain") <= per("F4 full f16 plain"));
    assert!(per("F16 full f16 plain") <= per("F16 multires f16 plain") + 1e-9);
    let s = rows(&r, "shadows");
    assert_eq!(s[0]["method"], "reference");
    assert_eq!(num(&s[0], "lit_mae"), 0.0);
    let mae = |name: &str| {
        num(
            s.iter().find(|x| x["method"] == name).expect(name),
            "lit_mae",
        )
    };
    // Uniform stepping converges with its step count; extrema-soft is the reference's twin.
    assert!(mae("uniform 800") < mae("uniform 25"));
    assert!(mae("extrema-soft") < 0.01, "{}", mae("extrema-soft"));
    assert!(hz.iter().any(|h| h["pareto"] == true));
    assert!(f.iter().any(|h| h["pareto"] == true));
    let recs = rows(&r, "recommendations");
    assert_eq!(recs.len(), 4);
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert_eq!(html.matches("<svg").count(), 3);
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("![") && md.contains("| variant |"));
    // Another budget without another sample: the measurements stay, the choices follow it.
    let again = tmp.path().join("again");
    let loose = json(&run(&[
        "report",
        "--from",
        out.join("report.json").to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
        "--max-per",
        "50",
        "--json",
        "--quiet",
    ]));
    assert_eq!(loose["fourier"], r["fourier"]);
    assert_eq!(num(&loose, "max_per_pct"), 50.0);
    let storage = rows(&loose, "recommendations")
        .iter()
        .find(|x| x["product"] == "horizon storage, any layout")
        .unwrap()["choice"]
        .clone();
    // At 50 % every variant qualifies: the smallest is a 4-coefficient pyramid or classic 8.
    let smallest = f
        .iter()
        .min_by_key(|x| x["bytes_per_tile"].as_u64().unwrap())
        .unwrap();
    assert_eq!(
        num(
            f.iter().find(|x| x["variant"] == storage).unwrap(),
            "bytes_per_tile"
        ),
        num(smallest, "bytes_per_tile")
    );
    assert!(again.join("report.html").is_file());
}

/// What the report recommends for a budget meets that budget on another sample of pixels
/// (another seed: other blocks, other pixels in them). The pyramids it measures are encoded
/// by the bake's own encoder, so the bake of the recommended K stores these same bytes.
#[test]
fn recommendation_holds_on_an_independent_sample() {
    let tmp = tempfile::tempdir().unwrap();
    let tiles = tileset(tmp.path());
    let budget = ["--max-per", "3", "--max-error-deg", "0.1"];
    let first = report(
        &tiles,
        &tmp.path().join("a"),
        &[&budget[..], &["--seed", "1"]].concat(),
    );
    let second = report(
        &tiles,
        &tmp.path().join("b"),
        &[&budget[..], &["--seed", "2"]].concat(),
    );
    let blocks = |r: &serde_json::Value| -> Vec<(String, u64, u64)> {
        rows(r, "blocks")
            .iter()
            .map(|b| {
                (
                    b["tile"].as_str().unwrap().to_string(),
                    b["x0"].as_u64().unwrap(),
                    b["y0"].as_u64().unwrap(),
                )
            })
            .collect()
    };
    assert_ne!(
        blocks(&first),
        blocks(&second),
        "the two samples are the same blocks"
    );
    let recs = rows(&first, "recommendations");
    let mut checked = 0;
    for rec in recs {
        let Some(choice) = rec["choice"].as_str() else {
            continue;
        };
        // Which rows of the second report the product's choice is in, by which key, and
        // the figure the budget bounds.
        let (table, key, figure, bound) = match rec["product"].as_str().unwrap() {
            "horizon method" => ("horizons", "method", "rms_deg", 0.1),
            "horizon storage" | "horizon storage, any layout" => {
                ("fourier", "variant", "per_pct", 3.0)
            }
            "shadow method" => ("shadows", "method", "per_pct", 3.0),
            p => panic!("unknown product {p}"),
        };
        let row = rows(&second, table)
            .iter()
            .find(|x| x[key] == choice)
            .unwrap_or_else(|| panic!("{choice} not in the second report's {table}"));
        assert!(
            num(row, figure) <= bound,
            "{choice} on the second sample: {row}"
        );
        checked += 1;
    }
    assert_eq!(
        checked, 4,
        "a budget this loose has a choice per product: {recs:?}"
    );
}

#[test]
fn bad_report_input_exits_2_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let tiles = tileset(tmp.path());
    let out = tmp.path().join("rep");
    let o = out.to_str().unwrap();
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, "[scene]\nname = \"x\"\nbody = \"moon\"\n").unwrap();
    let scene = scene.to_str().unwrap();
    let missing = tmp.path().join("nothing-here");
    let missing = missing.to_str().unwrap();
    for (args, needle) in [
        (vec!["report", &tiles, "--budget-s", "0"], "--budget-s"),
        (vec!["report", &tiles, "--budget-s", "nan"], "--budget-s"),
        (vec!["report", &tiles, "--max-per", "99"], "--max-per"),
        (
            vec!["report", &tiles, "--max-error-deg=-1"],
            "--max-error-deg",
        ),
        (vec!["report", &tiles, "--level", "19"], "--level"),
        (vec!["report", &tiles, "--blocks", "0"], "--blocks"),
        (
            vec!["report", &tiles, "--blocks", "2", "--block-px", "50"],
            "--block-px",
        ),
        (vec!["report", &tiles, "--block-px", "32"], "--blocks"),
        (
            vec!["report", &tiles, "--blocks", "2", "--budget-s", "9"],
            "--budget-s",
        ),
        (vec!["report", missing], "no such file"),
        (vec!["report", scene], "--tileset"),
        (
            vec!["report", &tiles, "--tileset", &tiles],
            "--tileset only with a scene",
        ),
        (vec!["report"], "--tileset"),
        (vec!["report", "--from", missing], "nothing-here"),
        (vec!["report", "--from", scene], "not a report.json"),
        (vec!["report", "--from", scene, &tiles], "--from"),
    ] {
        let mut a = args.clone();
        a.extend(["--out", o]);
        let r = run(&a);
        assert_eq!(r.status.code(), Some(2), "{args:?}: {}", stderr(&r));
        assert!(stderr(&r).contains(needle), "{args:?}: {}", stderr(&r));
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
}

/// Debian's chromium (or Chrome) if installed; under CI it must be.
fn browser() -> Option<PathBuf> {
    let found = ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .find_map(|b| {
            std::env::var_os("PATH").and_then(|p| {
                std::env::split_paths(&p)
                    .map(|d| d.join(b))
                    .find(|c| c.is_file())
            })
        });
    let ci = std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false"));
    if found.is_none() {
        if ci {
            panic!("no chromium on PATH, and CI is set: .ci/run installs Debian's chromium");
        }
        eprintln!("skipped: no chromium on PATH (apt-get install chromium)");
    }
    found
}

/// The page as the browser lays it out, and the console lines it printed.
fn open_headless(browser: &Path, page: &Path, profile: &Path) -> (String, Vec<String>) {
    let o = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--enable-logging=stderr",
            "--v=0",
            "--virtual-time-budget=5000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let console = stderr(&o)
        .lines()
        .filter(|l| l.contains(":CONSOLE"))
        .map(String::from)
        .collect();
    (String::from_utf8_lossy(&o.stdout).into_owned(), console)
}

#[test]
fn report_html_shows_its_plots_in_a_headless_browser() {
    let Some(browser) = browser() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let tiles = tileset(tmp.path());
    let out = tmp.path().join("rep");
    // This one with the budget's sample.
    report_with(&tiles, &out, &["--budget-s", "6"], false);
    let page = out.join("report.html");
    let (dom, console) = open_headless(&browser, &page, &tmp.path().join("profile"));
    assert!(console.is_empty(), "console: {console:?}");
    // The page's own check: every inline plot laid out with a size and with marks in it.
    assert!(dom.contains("data-plots=\"3/3\""), "plots not all shown");
    // The check can fail: a page whose plots lost their marks, and one with a script error.
    let html = std::fs::read_to_string(&page).unwrap();
    let broken = tmp.path().join("broken.html");
    let stripped = html
        .replace("<circle", "<g")
        .replace("<polygon", "<g")
        .replace("<polyline", "<g")
        .replace("<path", "<g")
        .replace("</script>", "undefined_call();</script>");
    std::fs::write(&broken, stripped).unwrap();
    let (dom, console) = open_headless(&browser, &broken, &tmp.path().join("profile2"));
    assert!(!dom.contains("data-plots=\"3/3\""));
    assert!(
        !console.is_empty(),
        "a script error reached no console line"
    );
}

/// `[fourier] coefficients = "auto"`: `plan` takes K from the scene's report, refuses (exit 2,
/// naming the key) a missing, damaged or other scene's report.
#[test]
fn plan_takes_the_reports_storage_recommendation() {
    let tmp = tempfile::tempdir().unwrap();
    let tiles = tileset(tmp.path());
    let scene_text = |name: &str| {
        format!(
            "[scene]\nname = \"{name}\"\nbody = \"moon\"\n\n[layout]\ntile_size = 128\n\n\
             [[source]]\nembedded = \"south-pole\"\nsize = 1024\n\n[[region]]\nname = \"all\"\n\
             body = true\n\n[renderer]\nmethods = [\"fourier\"]\n\n[sun]\n\
             elevation_deg = [1.0, 15.0]\n\n[fourier]\ncoefficients = \"auto\"\n\
             report = \"rep/report.json\"\n"
        )
    };
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, scene_text("auto test")).unwrap();
    let sc = scene.to_str().unwrap();
    let refused = |needle: &str| {
        let o = run(&["plan", sc]);
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        assert!(
            stderr(&o).contains("fourier.coefficients"),
            "{}",
            stderr(&o)
        );
        assert!(stderr(&o).contains(needle), "{}", stderr(&o));
    };
    refused("penumbra report");
    let rep = tmp.path().join("rep");
    let r = json(&run(&[
        "report",
        sc,
        "--tileset",
        &tiles,
        "--out",
        rep.to_str().unwrap(),
        "--blocks",
        "2",
        "--block-px",
        "32",
        "--max-per",
        "5",
        "--json",
        "--quiet",
    ]));
    assert!(r["scene"].as_str().unwrap().starts_with("auto test ("));
    let choice = rows(&r, "recommendations")
        .iter()
        .find(|x| x["product"] == "horizon storage")
        .unwrap()["choice"]
        .as_str()
        .expect("a choice at PER ≤ 5 %")
        .to_string();
    assert!(choice.ends_with(" multires f16 plain"), "{choice}");
    let k: u64 = choice[1..].split(' ').next().unwrap().parse().unwrap();
    let plan = json(&run(&["plan", sc, "--json"]));
    assert_eq!(
        plan["fourier"]["coefficients"].as_u64(),
        Some(k),
        "{}",
        plan["fourier"]
    );
    assert!(plan["fourier"]["auto_from"]
        .as_str()
        .unwrap()
        .ends_with("report.json"));
    // A report of another scene, and a damaged one.
    let good = std::fs::read(rep.join("report.json")).unwrap();
    std::fs::write(&scene, scene_text("another scene")).unwrap();
    refused("not of scene 'another scene'");
    std::fs::write(&scene, scene_text("auto test")).unwrap();
    std::fs::write(rep.join("report.json"), &good[..good.len() / 2]).unwrap();
    refused("not a report.json");
    // `report` names a file only `coefficients = "auto"` reads.
    std::fs::write(
        &scene,
        scene_text("auto test").replace("coefficients = \"auto\"", "coefficients = 8"),
    )
    .unwrap();
    let o = run(&["plan", sc]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("fourier.report"), "{}", stderr(&o));
}

/// A scene whose sun is a time span: the report's suns are the elevations the sun takes over
/// the sampled tiles during it (a south-polar scene: low suns), not the benchmarks' defaults.
#[test]
fn a_time_span_sun_gives_the_spans_elevations() {
    let tmp = tempfile::tempdir().unwrap();
    let tiles = tileset(tmp.path());
    let scene = tmp.path().join("span.toml");
    std::fs::write(
        &scene,
        "[scene]\nname = \"span\"\nbody = \"moon\"\n\n[layout]\ntile_size = 128\n\n\
         [[source]]\nembedded = \"south-pole\"\nsize = 1024\n\n[[region]]\nname = \"all\"\n\
         body = true\n\n[renderer]\nmethods = [\"dp\"]\n\n[sun]\n\
         start = \"2027-01-01T00:00:00Z\"\nend = \"2027-02-01T00:00:00Z\"\n",
    )
    .unwrap();
    let r = json(&run(&[
        "report",
        scene.to_str().unwrap(),
        "--tileset",
        &tiles,
        "--out",
        tmp.path().join("rep").to_str().unwrap(),
        "--blocks",
        "1",
        "--block-px",
        "24",
        "--json",
        "--quiet",
    ]));
    let el: Vec<f64> = r["sun_elevations_deg"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    // Near the south pole the sun stays within ±(1.54° + the pole's distance) of the horizon.
    assert!(!el.is_empty() && el.iter().all(|e| e.abs() < 3.0), "{el:?}");
    assert_eq!(r["shadow_sun_elevations_deg"], r["sun_elevations_deg"]);
    let notes = r["notes"].to_string();
    assert!(notes.contains("time span"), "{notes}");
}
