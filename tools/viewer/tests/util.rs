//! What the viewer's tests share: the tilesets they render (baked once per run under the
//! target folder and reused while complete), the GPU-adapter probe that skips or fails, and
//! running `penumbra-view`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use penumbra::bake::{self, BodyChoice, Input, Plan, Stage};
use penumbra::fourier::FourierOptions;
use penumbra::horizon::HorizonOptions;
use penumbra::mip::MipOptions;
use penumbra::progress::NoProgress;
use penumbra::synthetic::SyntheticSpec;
use penumbra::tiling::TileOptions;

/// Whether this is a CI run (`CI` set, and not empty, `0` or `false`).
pub fn ci() -> bool {
    std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false"))
}

/// Skip (print why, return false) or, under CI, fail.
pub fn skip(why: &str) -> bool {
    if ci() {
        panic!("{why}, and CI is set: CI must run this test (.ci/run installs what it needs)");
    }
    eprintln!("skipping: {why}");
    false
}

/// Whether a GPU adapter (any: lavapipe counts) is there; otherwise skip or fail.
pub fn gpu() -> bool {
    static PROBE: OnceLock<Result<String, String>> = OnceLock::new();
    let p = PROBE.get_or_init(|| {
        // Mesa in this process wants a runtime folder too (else it prints that it has none).
        if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
            std::env::set_var("XDG_RUNTIME_DIR", runtime_dir());
        }
        match penumbra_view::gpu::Gpu::headless() {
            Ok(g) => Ok(g.info.name.clone()),
            Err(e) => Err(e.to_string()),
        }
    });
    match p {
        Ok(_) => true,
        Err(e) => skip(&format!(
            "no GPU adapter ({e}); install Mesa's lavapipe (apt-get install mesa-vulkan-drivers)"
        )),
    }
}

/// The `penumbra-view` binary, with a private runtime folder (Mesa and the window system
/// want one; a shared /tmp is refused as "invalid").
pub fn view() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_penumbra-view"));
    c.env("XDG_RUNTIME_DIR", runtime_dir());
    c
}

/// A private runtime folder (mode 0700) under the target folder.
fn runtime_dir() -> &'static Path {
    static RUNTIME: OnceLock<PathBuf> = OnceLock::new();
    RUNTIME.get_or_init(|| {
        use std::os::unix::fs::PermissionsExt;
        let d = fixtures().join("runtime");
        std::fs::create_dir_all(&d).unwrap();
        std::fs::set_permissions(&d, std::fs::Permissions::from_mode(0o700)).unwrap();
        d
    })
}

/// Run `penumbra-view` with `args`.
pub fn run(args: &[&str]) -> Output {
    view().args(args).output().expect("penumbra-view runs")
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The JSON report of a successful run.
pub fn json(o: &Output) -> serde_json::Value {
    assert!(
        o.status.success(),
        "exit {:?}: {}",
        o.status.code(),
        stderr(o)
    );
    serde_json::from_slice(&o.stdout).expect("a JSON report")
}

/// Folder for the fixtures: kept under the target folder between runs.
fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR")).join("viewer-fixtures")
}

/// Whether every file of the tileset in `dir` is what the tileset says it is: a cached fixture
/// written by an older penumbra (whose files lack what this one checks) is rebuilt.
fn sound(dir: &Path) -> bool {
    penumbra::tileset::verify::verify(dir).is_ok_and(|r| r.clean())
}

/// Bake `input` into `dir` with `plan` unless a complete, sound tileset (one with `needs`'
/// product) is there already.
fn baked(dir: &Path, input: &Input, plan: &Plan, fourier: bool) -> PathBuf {
    if let Ok(ts) = penumbra::manifest::Tileset::load(dir) {
        if ts.products.mip.is_some() && (!fourier || ts.products.fourier.is_some()) && sound(dir) {
            return dir.to_path_buf();
        }
    }
    // Made again from nothing: a stale fixture's files would count as up to date.
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir.parent().unwrap()).unwrap();
    bake::bake(input, dir, plan, &NoProgress).expect("fixture bakes");
    dir.to_path_buf()
}

/// The embedded south-pole scene, 1024² px at 20 m: 64-px tiles, levels 0..=9 (106 m at the
/// finest), Fourier horizon pyramids (from 90 azimuths) at level 9.
pub fn scene() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let plan = Plan {
            stages: vec![Stage::Tile, Stage::Mip, Stage::Horizon],
            tile: TileOptions {
                tile_size: 64,
                levels: Some(10),
                ..TileOptions::default()
            },
            mip: MipOptions::default(),
            horizon: HorizonOptions {
                levels: Some(vec![9]),
                azimuths: 90,
                ..HorizonOptions::default()
            },
            fourier: Some(FourierOptions::default()),
            keep_raw: false,
            horizon_level_at_most: None,
            keep_partial: false,
        };
        let spec = SyntheticSpec {
            size: 1024,
            ..SyntheticSpec::default()
        };
        baked(
            &fixtures().join("scene-1024-64"),
            &Input::Embedded(spec),
            &plan,
            true,
        )
    })
}

/// The embedded scene without horizons (heights and mipmaps only).
pub fn scene_without_horizons() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let plan = Plan {
            stages: vec![Stage::Tile, Stage::Mip],
            tile: TileOptions {
                tile_size: 64,
                levels: Some(8),
                ..TileOptions::default()
            },
            ..Plan::default()
        };
        let spec = SyntheticSpec {
            size: 1024,
            ..SyntheticSpec::default()
        };
        baked(
            &fixtures().join("scene-1024-64-bare"),
            &Input::Embedded(spec),
            &plan,
            false,
        )
    })
}

/// The real DEMs (`$PENUMBRA_SHARED_DATA`, else `../shared/data` beside the repository), or a
/// skip (a failure under CI).
pub fn shared_data() -> Option<PathBuf> {
    let dir = match std::env::var_os("PENUMBRA_SHARED_DATA") {
        Some(p) => PathBuf::from(p),
        None => Path::new(env!("CARGO_MANIFEST_DIR"))
            .ancestors()
            .nth(2)
            .expect("tools/viewer lies two levels below the repository root")
            .join("../shared/data"),
    };
    if dir.is_dir() {
        Some(dir)
    } else {
        skip(&format!(
            "{} not found (real-DEM checks need it)",
            dir.display()
        ));
        None
    }
}

/// LOLA's 5 m Shoemaker crater DEM at the lunar south pole (256² px): 64-px tiles, levels
/// 0..=13 (6.6 m at the finest), Fourier horizon pyramids (from 90 azimuths) at level 13.
pub fn shoemaker() -> Option<&'static Path> {
    static DIR: OnceLock<Option<PathBuf>> = OnceLock::new();
    DIR.get_or_init(|| {
        let data = shared_data()?;
        let dem = data.join("lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif");
        if !dem.is_file() {
            skip(&format!("{} not found", dem.display()));
            return None;
        }
        let plan = Plan {
            stages: vec![Stage::Tile, Stage::Mip, Stage::Horizon],
            tile: TileOptions {
                tile_size: 64,
                levels: Some(14),
                ..TileOptions::default()
            },
            mip: MipOptions::default(),
            horizon: HorizonOptions {
                levels: Some(vec![13]),
                azimuths: 90,
                ..HorizonOptions::default()
            },
            fourier: Some(FourierOptions::default()),
            keep_raw: false,
            horizon_level_at_most: None,
            keep_partial: false,
        };
        // The GeoTIFF names no body; its projection is on the 1737.4 km Moon.
        let input = Input::Dem {
            path: dem,
            body: BodyChoice {
                name: Some("moon".into()),
                radius_m: None,
            },
        };
        Some(baked(
            &fixtures().join("shoemaker-64"),
            &input,
            &plan,
            false,
        ))
    })
    .as_deref()
}

/// A fresh temporary folder.
pub fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// An RGB PNG's size and pixels.
pub fn read_png(p: &Path) -> (u32, u32, Vec<[u8; 3]>) {
    let img = image::ImageReader::open(p)
        .unwrap()
        .decode()
        .unwrap()
        .to_rgb8();
    let (w, h) = img.dimensions();
    (w, h, img.pixels().map(|p| p.0).collect())
}

/// A small global tileset (the Moon's radius, gentle analytic relief) with an albedo image
/// whose western hemisphere is red and eastern blue: 32-px tiles, levels 0..=1.
pub fn albedo_globe() -> &'static Path {
    use penumbra::dem::{Crs, Dem, DemParts, GeoRef};
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let root = fixtures().join("albedo-globe");
        let out = root.join("tiles");
        if penumbra::manifest::Tileset::load(&out).is_ok_and(|t| t.products.albedo.is_some())
            && sound(&out)
        {
            return out;
        }
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let png = root.join("albedo.png");
        let img = image::RgbImage::from_fn(64, 32, |x, _| {
            if x < 32 {
                image::Rgb([200, 40, 30])
            } else {
                image::Rgb([30, 60, 200])
            }
        });
        img.save(&png).unwrap();
        let (w, h) = (128usize, 64usize);
        let d = 360.0 / w as f64;
        let mut v = Vec::with_capacity(w * h);
        for r in 0..h {
            for c in 0..w {
                let (lat, lon) = (90.0 - (r as f64 + 0.5) * d, -180.0 + (c as f64 + 0.5) * d);
                v.push(
                    (2000.0 * (lat.to_radians() * 3.0).sin() * (lon.to_radians() * 2.0).cos())
                        as f32,
                );
            }
        }
        let georef = GeoRef {
            crs: Crs::Geographic,
            x0: -180.0 + d / 2.0,
            y0: 90.0 - d / 2.0,
            dx: d,
            dy: d,
        };
        let dem = Dem::new(DemParts::in_memory(georef, w, h, v, "analytic globe"), 64).unwrap();
        let body = penumbra::body::Body::preset("moon").unwrap();
        let opts = TileOptions {
            tile_size: 32,
            levels: Some(2),
            albedo: Some((png, -180.0)),
            ..TileOptions::default()
        };
        penumbra::tiling::tile_dem(&dem, &body, &out, &opts, None, &NoProgress).unwrap();
        penumbra::mip::build_mips(&out, &MipOptions::default(), &NoProgress).unwrap();
        out
    })
}
