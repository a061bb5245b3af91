/*!
`--headless`: one frame rendered off-screen by the window's code path ([`Core::render`]),
written as a PNG (`--out`), the per-pixel lit fraction as float EXR (`--lit`), the timings of
`--frames` frames (and of as many frames without shadows, for the cost of the shadows), and with `--validate` the GPU against the CPU at the frame's texels
([`crate::validate`]). `--json` prints the report on stdout.
*/

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use serde::Serialize;

use crate::core::Core;
use crate::gpu::Gpu;
use crate::options::Options;
use crate::output;
use crate::render::{GpuTile, Readback, Targets};
use crate::validate::{self, Validation};

/// The adapter a frame was rendered on.
#[derive(Clone, Debug, Serialize)]
pub struct AdapterReport {
    pub name: String,
    pub backend: String,
    pub device_type: String,
    pub driver: String,
    /// Whether frame times come from GPU timestamp queries.
    pub timestamps: bool,
}

impl AdapterReport {
    pub fn of(gpu: &Gpu) -> AdapterReport {
        AdapterReport {
            name: gpu.info.name.clone(),
            backend: format!("{:?}", gpu.info.backend).to_lowercase(),
            device_type: format!("{:?}", gpu.info.device_type).to_lowercase(),
            driver: format!("{} {}", gpu.info.driver, gpu.info.driver_info)
                .trim()
                .to_string(),
            timestamps: gpu.timestamps,
        }
    }
}

/// Where the eye was.
#[derive(Clone, Debug, Serialize)]
pub struct CameraReport {
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: f64,
    pub heading_deg: f64,
    pub pitch_deg: f64,
    pub fov_deg: f64,
}

/// Where the sun was.
#[derive(Clone, Debug, Serialize)]
pub struct SunReport {
    /// Sub-solar point (degrees).
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub radius_deg: f64,
    pub distance_au: f64,
    /// Compass azimuth and elevation of the sun's centre at the view's target.
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
}

/// Pixels of the frame by what they show.
#[derive(Clone, Debug, Serialize)]
pub struct PixelReport {
    /// Showing terrain.
    pub surface: u64,
    /// Fully lit, fully shadowed, partly lit, terrain without shadow data.
    pub lit: u64,
    pub dark: u64,
    pub partial: u64,
    pub no_data: u64,
}

/// Frame times.
#[derive(Clone, Debug, Serialize)]
pub struct TimingReport {
    /// Per frame: the terrain pass on the GPU (ms; null without timestamps) and the wall time
    /// from encoding to completion (ms).
    pub gpu_ms: Vec<Option<f64>>,
    pub wall_ms: Vec<f64>,
    /// Medians.
    pub gpu_ms_median: Option<f64>,
    pub wall_ms_median: f64,
    /// Seconds spent preparing the tiles (read, mesh, shadow data) before the first frame.
    pub prepare_s: f64,
    /// With shadows on: the same frame with shadows off (`--no-shadows`), timed the same
    /// number of times just before (GPU ms per frame, null without timestamps; wall ms), their
    /// medians, and the cost of the shadows as Jung et al. and Fritsch et al. report it: the
    /// median frame time with shadows minus the median without (GPU time where timestamps
    /// exist, else wall time).
    pub no_shadows: Option<NoShadows>,
    pub shadow_overhead_ms: Option<f64>,
}

/// The frame without shadows.
#[derive(Clone, Debug, Serialize)]
pub struct NoShadows {
    pub gpu_ms: Vec<Option<f64>>,
    pub wall_ms: Vec<f64>,
    pub gpu_ms_median: Option<f64>,
    pub wall_ms_median: f64,
}

/// What [`time_frames`] measured: per frame GPU ms (None without timestamps) and wall ms, and
/// the drawn tiles of the last frame.
struct Timed {
    gpu_ms: Vec<Option<f64>>,
    wall_ms: Vec<f64>,
    tiles: Vec<penumbra::layout::TileId>,
}

/// Times `frames` renders after one untimed warm-up render (drivers such as lavapipe compile
/// a pipeline's shaders at its first draw).
fn time_frames(core: &mut Core, targets: &Targets, frames: u32) -> Result<Timed> {
    let mut t = Timed {
        gpu_ms: Vec::new(),
        wall_ms: Vec::new(),
        tiles: Vec::new(),
    };
    core.render(targets)?;
    for _ in 0..frames {
        let f = core.render(targets)?;
        t.gpu_ms.push(f.time.gpu_ms);
        t.wall_ms.push(f.time.wall_ms);
        t.tiles = f.tiles;
    }
    Ok(t)
}

/// The median of the GPU times when every frame has one.
fn gpu_median(v: &[Option<f64>]) -> Option<f64> {
    let t: Vec<f64> = v.iter().flatten().copied().collect();
    (t.len() == v.len() && !t.is_empty()).then(|| median(&t))
}

/// What `--headless --json` prints.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub tileset: PathBuf,
    pub out: PathBuf,
    pub lit: Option<PathBuf>,
    pub diff: Option<PathBuf>,
    pub width: u32,
    pub height: u32,
    pub method: String,
    pub shadows: bool,
    pub adapter: AdapterReport,
    pub camera: CameraReport,
    pub sun: SunReport,
    /// The tiles drawn (`L{level}/{face}/{y}/{x}`).
    pub tiles: Vec<String>,
    pub pixels: PixelReport,
    pub timings: TimingReport,
    pub validation: Option<Validation>,
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        f64::NAN
    } else if s.len() % 2 == 1 {
        s[s.len() / 2]
    } else {
        (s[s.len() / 2 - 1] + s[s.len() / 2]) / 2.0
    }
}

/// The difference image's default path: beside `out`, `-diff.png`.
fn default_diff(out: &std::path::Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "frame".into());
    out.with_file_name(format!("{stem}-diff.png"))
}

/// Run a headless render.
pub fn run(opts: &Options) -> Result<Report> {
    let a = &opts.args;
    let out = output::in_folder(a.out.as_deref().expect("checked by Options"));
    output::check_parent(&out, "--out")?;
    let lit = a.lit.as_deref().map(output::in_folder);
    if let Some(l) = &lit {
        output::check_parent(l, "--lit")?;
    }
    let diff = a.validate.then(|| {
        a.diff
            .as_deref()
            .map_or_else(|| default_diff(&out), output::in_folder)
    });
    if let Some(d) = &diff {
        output::check_parent(d, "--diff")?;
    }
    // The tileset first: a bad one is reported whether or not there is a GPU.
    let store = crate::core::open_checked(&a.dir, &opts.method)?;
    let gpu = Gpu::headless().map_err(|e| anyhow!("{e}"))?;
    let mut core = Core::new(gpu, store, opts)?;
    let targets = Targets::new(&core.gpu, opts.width, opts.height);
    let ids = core.choose(opts.width, opts.height);
    if ids.is_empty() {
        eprintln!(
            "penumbra-view: warning: no tile of {} is in view; the frame is empty",
            a.dir.display()
        );
    }
    core.prepare(&ids)?;
    let prepare_s = core.scene.prepare_s;
    // The frame without shadows first, so that the targets hold the frame with them after.
    let no_shadows = if core.shadows_on {
        core.shadows_on = false;
        let t = time_frames(&mut core, &targets, opts.frames)?;
        core.shadows_on = true;
        Some(NoShadows {
            gpu_ms_median: gpu_median(&t.gpu_ms),
            wall_ms_median: median(&t.wall_ms),
            gpu_ms: t.gpu_ms,
            wall_ms: t.wall_ms,
        })
    } else {
        None
    };
    let Timed {
        gpu_ms,
        wall_ms,
        tiles,
    } = time_frames(&mut core, &targets, opts.frames)?;
    let gpu_ms_median = gpu_median(&gpu_ms);
    let wall_ms_median = median(&wall_ms);
    let shadow_overhead_ms = no_shadows
        .as_ref()
        .map(|n| match (gpu_ms_median, n.gpu_ms_median) {
            (Some(a), Some(b)) => a - b,
            _ => wall_ms_median - n.wall_ms_median,
        });
    let rb = Readback::read(&core.gpu, &targets)?;
    output::write_rgba_as_png(&out, rb.width, rb.height, &rb.colour)?;
    if let Some(l) = &lit {
        penumbra::shadow::write_lit_exr(l, rb.width as usize, rb.height as usize, &rb.lit)?;
    }
    let validation = match &diff {
        Some(d) => {
            let gt: Vec<&GpuTile> = tiles
                .iter()
                .map(|id| core.scene.get(*id).expect("drawn tiles are kept"))
                .collect();
            let (v, cpu) = validate::validate(
                &rb,
                &gt,
                &core.scene.sun().sun(),
                core.scene.method(),
                &core.scene.store,
                core.scene.max_margin_px,
            )?;
            validate::write_diff_png(d, rb.width, rb.height, &rb.lit, &cpu.same)?;
            let dref = d.with_file_name(format!(
                "{}-reference.png",
                d.file_stem().unwrap_or_default().to_string_lossy()
            ));
            validate::write_diff_png(&dref, rb.width, rb.height, &rb.lit, &cpu.reference)?;
            Some(v)
        }
        None => None,
    };
    let r = core.scene.radius_m();
    let (lat, lon, alt) = core.camera.lat_lon_alt(r);
    let sun = core.scene.sun();
    let (az, el) = core.sun_local();
    let mut px = PixelReport {
        surface: 0,
        lit: 0,
        dark: 0,
        partial: 0,
        no_data: 0,
    };
    for (v, t) in rb.lit.iter().zip(&rb.texel) {
        if t.is_none() {
            continue;
        }
        px.surface += 1;
        match *v {
            v if v.is_nan() => px.no_data += 1,
            v if v >= 1.0 => px.lit += 1,
            v if v <= 0.0 => px.dark += 1,
            _ => px.partial += 1,
        }
    }
    Ok(Report {
        tileset: a.dir.clone(),
        out,
        lit,
        diff,
        width: rb.width,
        height: rb.height,
        method: core.scene.method().label(),
        shadows: core.shadows_on,
        adapter: AdapterReport::of(&core.gpu),
        camera: CameraReport {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
            heading_deg: core.camera.heading_deg,
            pitch_deg: core.camera.pitch_deg,
            fov_deg: core.camera.fov_y_deg,
        },
        sun: SunReport {
            lat_deg: sun.lat_deg,
            lon_deg: sun.lon_deg,
            radius_deg: sun.radius_deg,
            distance_au: core.sun_distance_au,
            azimuth_deg: az,
            elevation_deg: el,
        },
        tiles: tiles.iter().map(|t| t.to_string()).collect(),
        pixels: px,
        timings: TimingReport {
            gpu_ms_median,
            gpu_ms,
            wall_ms_median,
            wall_ms,
            prepare_s,
            no_shadows,
            shadow_overhead_ms,
        },
        validation,
    })
}

/// The report for people (without `--json`).
pub fn print_text(r: &Report) {
    println!(
        "frame      {} ({}×{}, {} tiles)",
        r.out.display(),
        r.width,
        r.height,
        r.tiles.len()
    );
    println!(
        "adapter    {} ({}, {})",
        r.adapter.name, r.adapter.backend, r.adapter.device_type
    );
    println!(
        "method     {}{}",
        r.method,
        if r.shadows { "" } else { " (shadows off)" }
    );
    println!(
        "sun        sub-solar {:.3}°, {:.3}°; at the target az {:.1}° el {:.2}° (radius {:.4}°)",
        r.sun.lat_deg, r.sun.lon_deg, r.sun.azimuth_deg, r.sun.elevation_deg, r.sun.radius_deg
    );
    println!(
        "pixels     {} terrain: {} lit, {} dark, {} partly lit, {} without data",
        r.pixels.surface, r.pixels.lit, r.pixels.dark, r.pixels.partial, r.pixels.no_data
    );
    match r.timings.gpu_ms_median {
        Some(g) => println!(
            "time       gpu {g:.3} ms (median of {}), wall {:.2} ms, tiles prepared in {:.2} s",
            r.timings.gpu_ms.len(),
            r.timings.wall_ms_median,
            r.timings.prepare_s
        ),
        None => println!(
            "time       wall {:.2} ms (median of {}; no GPU timestamps), tiles prepared in {:.2} s",
            r.timings.wall_ms_median,
            r.timings.wall_ms.len(),
            r.timings.prepare_s
        ),
    }
    if let (Some(o), Some(n)) = (r.timings.shadow_overhead_ms, &r.timings.no_shadows) {
        let (base, clock) = match n.gpu_ms_median {
            Some(g) => (g, "gpu"),
            None => (n.wall_ms_median, "wall"),
        };
        println!("shadows    cost {o:.3} ms per frame ({clock}; {base:.3} ms without shadows)");
    }
    if let Some(v) = &r.validation {
        println!(
            "validation {} texels on the CPU in {:.2} s",
            v.texels, v.cpu_s
        );
        for e in [&v.same, &v.reference, &v.cpu_same_vs_reference]
            .into_iter()
            .chain(&v.exact_model)
        {
            println!(
                "  vs {:<22} mean abs {:.5}  max {:.4}  PER {:.3} %  ({} px, {} data mismatches)",
                e.against, e.mean_abs, e.max_abs, e.per_percent, e.pixels, e.data_mismatch
            );
        }
        let p = &v.penumbra;
        println!(
            "  penumbra ({} px on {} texels with the sun within ±3° of their horizon):",
            p.pixels, p.texels
        );
        for e in [&p.same, &p.reference] {
            println!(
                "    vs {:<20} mean abs {:.5}  max {:.4}  PER {:.3} %",
                e.against, e.mean_abs, e.max_abs, e.per_percent
            );
        }
        if let Some(d) = &r.diff {
            println!("  difference image {}", d.display());
        }
    }
}
