/*!
The command line in two steps (as ripgrep does): [`Args`] holds what the user typed (clap),
[`Options`] the checked and resolved values — the camera, the sun's sub-solar point, the
method, the frame size — with every bad value refused up front, naming the flag.
*/

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Parser;
use penumbra::fourier::sun::Model;
use penumbra::shadow::Runs;

use crate::shadow::GpuMethod;

/// `penumbra-view`: renders a baked tileset with the soft shadow of a GPU method, in a window
/// or headless, and checks the GPU against the CPU methods.
#[derive(Debug, Parser)]
#[command(
    name = "penumbra-view",
    version,
    about = "Render a Penumbra tileset with GPU soft shadows (window or headless) and validate \
             them against the CPU methods",
    after_help = "Keys (window): arrows = sun azimuth/elevation at the view's target, M = next \
                  method, 1-6 = dp/uniform/extrema/fourier/extrema-soft/dp-jung, H = shadows on/off, \
                  F = orbit/fly, \
                  WASD/QE = fly, drag = orbit or look, wheel = zoom, +/- = sun faster/slower, \
                  Esc = quit."
)]
pub struct Args {
    /// Tileset folder (made by `penumbra tile` or `penumbra bake`), or a package folder (made
    /// by `penumbra package`: its cube-face tileset is drawn).
    pub dir: PathBuf,
    /// Shadow method: dp, dp-jung (Jung et al.'s DP as published), uniform, extrema,
    /// extrema-soft or fourier (needs the Fourier pyramids).
    #[arg(long, default_value = "dp")]
    pub method: String,
    /// The disc model of `fourier`: constant (the series once per pixel, at the sun's azimuth),
    /// segment (at the disc's two rims), slices (8 strips) or exact (256 strips with
    /// bisection: the validation model).
    #[arg(long, default_value = "constant")]
    pub fourier_model: String,
    /// Steps of the uniform method.
    #[arg(long, default_value_t = 100)]
    pub steps: u32,
    /// DP levels per run (`auto`, or a list such as 5,5,5).
    #[arg(long, default_value = "auto")]
    pub dp_levels: String,
    // The brackets are the help text's (clap shows this comment), not links.
    #[allow(rustdoc::broken_intra_doc_links)]
    /// Camera: LAT,LON,ALT[,HEADING[,PITCH[,FOV]]] — eye latitude and longitude (degrees),
    /// height above the reference sphere (m), compass heading, pitch above the horizontal
    /// (−90 looks straight down) and vertical field of view (degrees). Default: above the
    /// tileset's finest coverage.
    #[arg(long, allow_hyphen_values = true)]
    pub camera: Option<String>,
    /// Sub-solar latitude (degrees); with --sun-lon. Default: a sun 5° high in the south-east
    /// of the view's target.
    #[arg(long, allow_hyphen_values = true)]
    pub sun_lat: Option<f64>,
    /// Sub-solar longitude (degrees, east positive, −180..360).
    #[arg(long, allow_hyphen_values = true)]
    pub sun_lon: Option<f64>,
    /// Distance to the Sun (AU): sets the disc's radius. Default: the body's.
    #[arg(long)]
    pub sun_distance_au: Option<f64>,
    /// Frame size WIDTHxHEIGHT in pixels (the window's initial size).
    #[arg(long, default_value = "512x384")]
    pub size: String,
    /// Draw this level only (default: levels chosen by screen-space error; with --method
    /// fourier, the finest level with Fourier pyramids).
    #[arg(long)]
    pub level: Option<u8>,
    /// Refine tiles until a texel spans at most this many screen pixels.
    #[arg(long, default_value_t = 1.0)]
    pub max_texel_px: f64,
    /// Most tiles per frame.
    #[arg(long, default_value_t = 96)]
    pub max_tiles: usize,
    /// Most context pixels the shadow search gathers around a tile.
    #[arg(long, default_value_t = penumbra::shadow::MAX_MARGIN_PX)]
    pub max_margin_px: u64,
    /// Render off-screen (no window) and write --out.
    #[arg(long)]
    pub headless: bool,
    /// Headless: the frame (PNG).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Headless: the per-pixel lit fraction (single-channel float EXR, NaN where no surface).
    #[arg(long)]
    pub lit: Option<PathBuf>,
    /// Headless: print the report as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Headless: evaluate the CPU method of the same name and the CPU reference at every
    /// texel the frame shows, and report the errors.
    #[arg(long)]
    pub validate: bool,
    /// With --validate: the difference image (PNG; default: beside --out, `-diff.png`).
    #[arg(long)]
    pub diff: Option<PathBuf>,
    /// Frames to render: headless, the number timed (default 3); with --screenshot, the frame
    /// after which the window is saved and closed (default 3).
    #[arg(long)]
    pub frames: Option<u32>,
    /// Window: save the window's frame (with its status line) to this PNG after --frames
    /// frames, and exit.
    #[arg(long)]
    pub screenshot: Option<PathBuf>,
    /// Lambert shading only, no shadows.
    #[arg(long)]
    pub no_shadows: bool,
    /// CPU threads for tile preparation and validation (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Flying a camera path (crate::flight).
    #[command(flatten)]
    pub flight: FlightArgs,
}

/// The camera as given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraSpec {
    pub lat: f64,
    pub lon: f64,
    pub alt: f64,
    pub heading: f64,
    pub pitch: f64,
    pub fov: f64,
}

/// Checked options.
#[derive(Debug)]
pub struct Options {
    pub args: Args,
    pub method: GpuMethod,
    pub camera: Option<CameraSpec>,
    pub sun: Option<(f64, f64)>,
    pub width: u32,
    pub height: u32,
    pub frames: u32,
}

/// Largest frame side (pixels).
pub const MAX_SIDE: u32 = 8192;

/// The GPU method `name` with the uniform steps, DP runs and Fourier disc model of `args`.
pub fn method(name: &str, args: &Args) -> Result<GpuMethod> {
    let steps = args.steps;
    // Checked whatever the method: the window may switch to `fourier` later.
    let model = args
        .fourier_model
        .parse::<Model>()
        .map_err(|e| anyhow::anyhow!("--fourier-model {e}"))?;
    Ok(match name {
        "dp" | "dp-jung" => {
            let runs = args
                .dp_levels
                .parse::<Runs>()
                .map_err(|e| anyhow::anyhow!("--dp-levels {e}"))?;
            if name == "dp" {
                GpuMethod::Dp { runs }
            } else {
                GpuMethod::DpJung { runs }
            }
        }
        "uniform" => {
            if !(1..=100_000).contains(&steps) {
                bail!("--steps {steps} is outside 1..=100000");
            }
            GpuMethod::Uniform { steps }
        }
        "extrema" => GpuMethod::Extrema,
        "extrema-soft" => GpuMethod::ExtremaSoft,
        "fourier" => GpuMethod::Fourier { model },
        _ => bail!(
            "--method {name}: unknown shadow method; the viewer has dp, dp-jung, uniform, \
             extrema, extrema-soft and fourier"
        ),
    })
}

/// Parse `--camera LAT,LON,ALT[,HEADING[,PITCH[,FOV]]]`.
pub fn parse_camera(s: &str) -> Result<CameraSpec> {
    let bad = |why: &str| {
        anyhow::anyhow!(
            "--camera '{s}': {why}; give LAT,LON,ALT[,HEADING[,PITCH[,FOV]]] in degrees and \
             metres, e.g. -89.6,20,15000,200,-35"
        )
    };
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad("not a list of numbers"))?;
    if !(3..=6).contains(&v.len()) {
        return Err(bad(&format!("{} numbers", v.len())));
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(bad("a value is not a finite number"));
    }
    let c = CameraSpec {
        lat: v[0],
        lon: v[1],
        alt: v[2],
        heading: v.get(3).copied().unwrap_or(0.0),
        pitch: v.get(4).copied().unwrap_or(-90.0),
        fov: v.get(5).copied().unwrap_or(45.0),
    };
    if !(-90.0..=90.0).contains(&c.lat) {
        return Err(bad("latitude outside −90..=90"));
    }
    if !(-180.0..=360.0).contains(&c.lon) {
        return Err(bad("longitude outside −180..=360"));
    }
    if !(-90.0..=90.0).contains(&c.pitch) {
        return Err(bad("pitch outside −90..=90"));
    }
    let (lo, hi) = crate::camera::FOV_RANGE;
    if !(lo..=hi).contains(&c.fov) {
        return Err(bad(&format!("field of view outside {lo}..={hi}")));
    }
    Ok(c)
}

/// Parse `--size WIDTHxHEIGHT`.
pub fn parse_size(s: &str) -> Result<(u32, u32)> {
    let bad = || {
        anyhow::anyhow!(
            "--size '{s}': give WIDTHxHEIGHT in pixels, e.g. 512x384, each 1..={MAX_SIDE}"
        )
    };
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: u32 = w.trim().parse().map_err(|_| bad())?;
    let h: u32 = h.trim().parse().map_err(|_| bad())?;
    if !(1..=MAX_SIDE).contains(&w) || !(1..=MAX_SIDE).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

/// The flight's flags (flattened into [`Args`]).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct FlightArgs {
    // The brackets are the help text's (clap shows this comment), not links.
    #[allow(rustdoc::broken_intra_doc_links)]
    /// Fly a camera path, one frame per row, tiles loaded in the background: a CSV whose
    /// header is lat_deg,lon_deg,height_m[,heading_deg,pitch_deg] (degrees, metres above
    /// the reference sphere). Headless with --record DIR (frames and report), or in the
    /// window.
    #[arg(long)]
    pub path: Option<PathBuf>,
    /// With --headless --path: write the frames (frame_00000.png …) and report.json into this
    /// folder: a new or empty one, or an earlier flight's record, which this one replaces
    /// (report.json is written last: a flight stopped by an error leaves none).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// With --path: draw a frame only when every tile it chose is ready (complete,
    /// reproducible frames; the wait is reported). Otherwise frames draw what is ready.
    #[arg(long)]
    pub wait_tiles: bool,
    /// With --path: background threads that prepare tiles.
    #[arg(long, default_value_t = 1)]
    pub load_threads: usize,
}

/// Most loader threads.
pub const MAX_LOAD_THREADS: usize = 64;

/// Refuse flag combinations the flight does not take (from [`Options::resolve`]).
pub fn check_flight(args: &Args) -> Result<()> {
    let f = &args.flight;
    if f.path.is_none() {
        for (set, flag) in [
            (f.record.is_some(), "--record"),
            (f.wait_tiles, "--wait-tiles"),
            (f.load_threads != 1, "--load-threads"),
        ] {
            if set {
                bail!("{flag} goes with --path FILE.csv (a camera path to fly)");
            }
        }
        return Ok(());
    }
    if !(1..=MAX_LOAD_THREADS).contains(&f.load_threads) {
        bail!(
            "--load-threads {} is outside 1..={MAX_LOAD_THREADS}",
            f.load_threads
        );
    }
    for (set, flag, why) in [
        (
            args.camera.is_some(),
            "--camera",
            "the path sets the camera",
        ),
        (
            args.frames.is_some(),
            "--frames",
            "a flight draws one frame per row of the path",
        ),
        (
            args.out.is_some(),
            "--out",
            "a headless flight writes its frames with --record DIR",
        ),
        (args.lit.is_some(), "--lit", "not recorded along a path"),
        (args.validate, "--validate", "validate single frames"),
    ] {
        if set {
            bail!("{flag} does not go with --path: {why}");
        }
    }
    if f.record.is_some() && !args.headless {
        bail!("--record is for --headless flights; the window flies the path on screen");
    }
    Ok(())
}

impl Options {
    /// Check `args`.
    pub fn resolve(args: Args) -> Result<Options> {
        let method = method(&args.method, &args)?;
        let camera = args.camera.as_deref().map(parse_camera).transpose()?;
        let sun = match (args.sun_lat, args.sun_lon) {
            (Some(lat), Some(lon)) => {
                penumbra::shadow::check_subsolar(lat, lon)?;
                Some((lat, lon))
            }
            (None, None) => None,
            _ => bail!("--sun-lat and --sun-lon go together: give both, or neither"),
        };
        let (width, height) = parse_size(&args.size)?;
        if !(args.max_texel_px.is_finite() && args.max_texel_px > 0.0) {
            bail!(
                "--max-texel-px {} must be a positive number",
                args.max_texel_px
            );
        }
        if args.max_tiles == 0 || args.max_tiles > 4096 {
            bail!("--max-tiles {} is outside 1..=4096", args.max_tiles);
        }
        if args.max_margin_px == 0 || args.max_margin_px > penumbra::shadow::MAX_MARGIN_PX {
            bail!(
                "--max-margin-px {} is outside 1..={}",
                args.max_margin_px,
                penumbra::shadow::MAX_MARGIN_PX
            );
        }
        if args.headless {
            if args.out.is_none() && args.flight.path.is_none() {
                bail!("--headless needs --out FRAME.png (or --path PATH.csv to fly a path)");
            }
            if args.screenshot.is_some() {
                bail!("--screenshot is for the window; headless frames go to --out");
            }
        } else {
            for (set, flag) in [
                (args.out.is_some(), "--out"),
                (args.lit.is_some(), "--lit"),
                (args.validate, "--validate"),
                (args.diff.is_some(), "--diff"),
                (args.json && args.flight.path.is_none(), "--json"),
            ] {
                if set {
                    bail!("{flag} is for --headless renders");
                }
            }
        }
        if args.diff.is_some() && !args.validate {
            bail!("--diff needs --validate");
        }
        check_flight(&args)?;
        let frames = args.frames.unwrap_or(3);
        if !(1..=10_000).contains(&frames) {
            bail!("--frames {frames} is outside 1..=10000");
        }
        Ok(Options {
            args,
            method,
            camera,
            sun,
            width,
            height,
            frames,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_strings() {
        let c = parse_camera("-89.5,10,2000").unwrap();
        assert_eq!(
            (c.lat, c.lon, c.alt, c.pitch, c.fov),
            (-89.5, 10.0, 2000.0, -90.0, 45.0)
        );
        let c = parse_camera("1, 2, 3, 4, -5, 60").unwrap();
        assert_eq!((c.heading, c.pitch, c.fov), (4.0, -5.0, 60.0));
        for bad in [
            "",
            "1,2",
            "1,2,x",
            "91,0,1",
            "0,0,1,0,-91",
            "0,0,1,0,0,0",
            "0,0,NaN",
            "1,2,3,4,5,6,7",
        ] {
            assert!(parse_camera(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn sizes_and_methods() {
        assert_eq!(parse_size("256x128").unwrap(), (256, 128));
        for bad in ["256", "0x10", "10x99999", "axb"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
        let args = |extra: &[&str]| {
            let mut v = vec!["penumbra-view", "tiles"];
            v.extend_from_slice(extra);
            Args::try_parse_from(v).unwrap()
        };
        assert!(matches!(
            method("uniform", &args(&["--steps", "7"])).unwrap(),
            GpuMethod::Uniform { steps: 7 }
        ));
        assert_eq!(
            method("fourier", &args(&[])).unwrap(),
            GpuMethod::Fourier {
                model: Model::Constant
            }
        );
        assert_eq!(
            method("fourier", &args(&["--fourier-model", "exact"])).unwrap(),
            GpuMethod::Fourier {
                model: Model::Exact
            }
        );
        assert_eq!(
            method("extrema-soft", &args(&[])).unwrap(),
            GpuMethod::ExtremaSoft
        );
        assert!(method("smoke", &args(&[])).is_err());
        assert!(method("dp", &args(&["--dp-levels", "0,5"])).is_err());
        assert!(method("uniform", &args(&["--steps", "0"])).is_err());
        assert!(method("fourier", &args(&["--fourier-model", "disc"])).is_err());
    }
}
