/*!
`--path FILE`: fly a camera path (docs/viewer.md, "Flight"), one frame per row, with the tiles
streamed by background loaders ([`crate::stream`]) so that the frame loop never waits for a
tile unless asked to (`--wait-tiles`). Headless (`--headless --path F [--record DIR]`) the
frames go to `DIR/frame_00000.png` … (each written atomically) and the report to
`DIR/report.json`; in the window ([`crate::window`]) the path is flown one row per frame while
the keys and the mouse stay live, and the window closes at the end of the path. Either way the
report ([`FlightReport`]) gives the frame-time percentiles, the frames that drew with a tile
missing, and the tiles loaded; `--json` prints it on stdout, otherwise a table is printed
(stdout headless, stderr for the window).

The path is the library's camera-path CSV ([`penumbra::region::read_path_poses`]): the
header `lat_deg,lon_deg,height_m`, optionally `heading_deg` and `pitch_deg` (other columns are
ignored). Where a row gives no heading or pitch the camera looks along the path: towards the
next row's position that differs from its own (the last row keeps the direction from the row
before), straight down where the path never moves. A row whose height is below the tileset's
lowest terrain would put the eye inside the body: refused, naming the line, before anything is
rendered or written.
*/

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Context as _, Result};
use penumbra::region::PathPose;
use penumbra::tileset::Store;
use serde::Serialize;

use crate::camera::{add, norm, sub, Camera};
use crate::core::Core;
use crate::gpu::Gpu;
use crate::headless::AdapterReport;
use crate::options::Options;
use crate::output;
use crate::render::{FrameTime, Targets};
use crate::scene::FrameLoad;
use crate::stream::Loader;

/// Field of view of a flight's camera (degrees): the viewer's default.
pub const FLIGHT_FOV_DEG: f64 = 45.0;

/// The camera path of `path`, checked against the tileset in `store`: each row's camera,
/// with the row's line. Errors (exit 2) name the file and the line.
pub fn load_path(path: &Path, store: &Store) -> Result<Vec<(usize, Camera)>> {
    let poses = penumbra::region::read_path_poses(path).with_context(|| {
        format!(
            "--path {}: not a camera path to fly; give a CSV whose header is \
             lat_deg,lon_deg,height_m[,heading_deg,pitch_deg] with one row per frame (what \
             is wrong, and where, follows)",
            path.display()
        )
    })?;
    let ts = store.manifest();
    let r = ts.body.radius_m;
    let (lo, _) = crate::lod::quadtree(ts).terrain_m;
    for p in &poses {
        if p.point.height_m < lo {
            bail!(
                "--path {}: line {}: height_m {} m is below the tileset's lowest terrain \
                 ({lo:.1} m above the {} m reference sphere of {}): the camera would be inside \
                 the body; raise the point above {lo:.1} m",
                path.display(),
                p.line,
                p.point.height_m,
                r,
                ts.body.name
            );
        }
    }
    Ok(poses
        .iter()
        .map(|p| p.line)
        .zip(cameras(&poses, r, FLIGHT_FOV_DEG))
        .collect())
}

/// The cameras of a path's rows on a body of radius `radius_m`: the row's heading and pitch
/// where given, otherwise looking along the path (see the module's documentation).
pub fn cameras(poses: &[PathPose], radius_m: f64, fov_deg: f64) -> Vec<Camera> {
    let at = |p: &PathPose| {
        Camera::at(
            radius_m,
            p.point.lat_deg,
            p.point.lon_deg,
            p.point.height_m,
            0.0,
            -90.0,
            fov_deg,
        )
    };
    let eyes: Vec<Camera> = poses.iter().map(at).collect();
    // Closer than this, two rows are one position (m).
    const SAME_M: f64 = 1e-3;
    (0..poses.len())
        .map(|k| {
            let mut c = eyes[k];
            let ahead = eyes[k + 1..]
                .iter()
                .map(|e| sub(e.eye, c.eye))
                .find(|d| norm(*d) > SAME_M);
            let behind = || {
                eyes[..k]
                    .iter()
                    .rev()
                    .map(|e| sub(c.eye, e.eye))
                    .find(|d| norm(*d) > SAME_M)
            };
            if let Some(d) = ahead.or_else(behind) {
                c.look_at(add(c.eye, d));
            }
            if let Some(h) = poses[k].heading_deg {
                c.heading_deg = h;
            }
            if let Some(p) = poses[k].pitch_deg {
                c.pitch_deg = p;
            }
            c
        })
        .collect()
}

/// The 50th and 95th percentiles (nearest rank), the largest and the mean of a series.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Percentiles {
    pub p50: f64,
    pub p95: f64,
    pub max: f64,
    pub mean: f64,
}

impl Percentiles {
    /// Of `v`; `None` when it is empty.
    pub fn of(v: &[f64]) -> Option<Percentiles> {
        if v.is_empty() {
            return None;
        }
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        let rank = |p: f64| s[((p * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
        Some(Percentiles {
            p50: rank(0.50),
            p95: rank(0.95),
            max: s[s.len() - 1],
            mean: s.iter().sum::<f64>() / s.len() as f64,
        })
    }
}

/// One frame of a flight.
#[derive(Clone, Debug, Serialize)]
pub struct FrameRecord {
    /// Row of the path (from 0) and its line in the file.
    pub index: usize,
    pub line: usize,
    /// The frame's file name in the record folder.
    pub file: Option<String>,
    /// The camera: `--camera` of the same view (LAT,LON,ALT,HEADING,PITCH,FOV).
    pub camera: String,
    /// Wall time of the frame (ms): choosing and taking the tiles, drawing, waiting for the
    /// GPU (and, in the window, compositing and presenting); not the PNG's encoding.
    pub frame_ms: f64,
    /// The terrain pass on the GPU (timestamp queries), when the adapter has them.
    pub gpu_ms: Option<f64>,
    /// Tiles chosen, drawn, missing, stand-ins, arrived, and the wait for them (the report
    /// lists them beside the fields above).
    #[serde(flatten)]
    pub load: FrameLoad,
}

/// What a flight reports.
#[derive(Clone, Debug, Serialize)]
pub struct FlightReport {
    /// `headless` or `window`.
    pub mode: String,
    pub tileset: PathBuf,
    pub path: PathBuf,
    pub record: Option<PathBuf>,
    /// Rows of the path, and frames drawn (fewer when the window was closed early).
    pub rows: usize,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub method: String,
    pub adapter: AdapterReport,
    pub wait_tiles: bool,
    pub load_threads: usize,
    /// Wall time per frame (ms), and the terrain pass's GPU time where timestamps exist.
    pub frame_ms: Option<Percentiles>,
    pub gpu_ms: Option<Percentiles>,
    /// Frame time outside the terrain pass (frame − GPU, ms; where timestamps exist): what
    /// the frame loop spent on anything but drawing, a tile's load when a frame waits for it.
    pub outside_gpu_ms: Option<Percentiles>,
    /// Frames drawn with a chosen tile not ready (a coarser stand-in or a gap in its place).
    pub frames_waiting: usize,
    /// Chosen tiles missing, summed over the frames; stand-ins drawn, likewise.
    pub tiles_missing: usize,
    pub stand_ins: usize,
    /// Tiles the loaders made, and the time each took on its loader (ms).
    pub tiles_loaded: usize,
    pub load_ms: Option<Percentiles>,
    /// Total time frames waited for tiles (`--wait-tiles`; s).
    pub wait_s: f64,
    /// Wall time of the whole flight (s), PNG writing included.
    pub total_s: f64,
    pub per_frame: Vec<FrameRecord>,
}

/// A flight in progress: the cameras, the frames so far.
pub struct Flight {
    pub cameras: Vec<(usize, Camera)>,
    pub frames: Vec<FrameRecord>,
    started: Instant,
    frame_t0: Option<Instant>,
}

impl Flight {
    /// The flight of `opts`' path over `store` (the path is checked: exit 2 on bad rows).
    pub fn new(opts: &Options, store: &Store) -> Result<Flight> {
        let path = opts
            .args
            .flight
            .path
            .as_deref()
            .expect("a flight has --path");
        Ok(Flight {
            cameras: load_path(path, store)?,
            frames: Vec::new(),
            started: Instant::now(),
            frame_t0: None,
        })
    }

    /// Make `core` stream its tiles.
    pub fn attach(&mut self, core: &mut Core, opts: &Options) {
        let maker = core.scene.maker(&core.gpu, &core.renderer, &core.shadows);
        let loader = Loader::new(
            maker,
            opts.args.flight.load_threads,
            core.scene.sun(),
            core.scene.method().clone(),
        );
        core.scene.stream(loader, opts.args.flight.wait_tiles);
        self.started = Instant::now();
    }

    /// Whether every row has been flown.
    pub fn finished(&self) -> bool {
        self.frames.len() >= self.cameras.len()
    }

    /// Put the camera at the next row and start the frame's clock; false when the path is
    /// flown.
    pub fn begin(&mut self, core: &mut Core) -> bool {
        let Some((_, cam)) = self.cameras.get(self.frames.len()) else {
            return false;
        };
        core.camera = *cam;
        self.frame_t0 = Some(Instant::now());
        true
    }

    /// For the window's status line: the row being drawn (or the last drawn) and the tiles
    /// it lacks.
    pub fn status(&self, core: &Core) -> String {
        let l = core.scene.last_load;
        // Rows drawn, and the one being drawn.
        let row = self.frames.len() + self.frame_t0.is_some() as usize;
        let mut s = format!(" | row {row}/{}", self.cameras.len());
        if l.missing > 0 {
            s.push_str(&format!(", {} tiles loading", l.missing));
        }
        s
    }

    /// The frame begun last is drawn (`time` from the renderer); `file` where it was written.
    pub fn end(&mut self, core: &Core, time: &FrameTime) -> &mut FrameRecord {
        let t0 = self.frame_t0.take().expect("a frame was begun");
        let frame_ms = t0.elapsed().as_secs_f64() * 1e3;
        let index = self.frames.len();
        let c = &core.camera;
        let (lat, lon, alt) = c.lat_lon_alt(core.scene.radius_m());
        self.frames.push(FrameRecord {
            index,
            line: self.cameras[index].0,
            file: None,
            camera: format!(
                "{lat:.6},{lon:.6},{alt:.1},{:.3},{:.3},{:.1}",
                c.heading_deg, c.pitch_deg, c.fov_y_deg
            ),
            frame_ms,
            gpu_ms: time.gpu_ms,
            load: core.scene.last_load,
        });
        self.frames.last_mut().expect("just pushed")
    }

    /// The report so far.
    pub fn report(
        &self,
        mode: &str,
        core: &Core,
        opts: &Options,
        size: (u32, u32),
    ) -> FlightReport {
        let fr = &self.frames;
        let frame_ms: Vec<f64> = fr.iter().map(|f| f.frame_ms).collect();
        let gpu: Vec<f64> = fr.iter().filter_map(|f| f.gpu_ms).collect();
        let outside: Vec<f64> = fr
            .iter()
            .filter_map(|f| f.gpu_ms.map(|g| (f.frame_ms - g).max(0.0)))
            .collect();
        FlightReport {
            mode: mode.into(),
            tileset: opts.args.dir.clone(),
            path: opts.args.flight.path.clone().unwrap_or_default(),
            record: opts.args.flight.record.clone(),
            rows: self.cameras.len(),
            frames: fr.len(),
            width: size.0,
            height: size.1,
            method: core.scene.method().label(),
            adapter: AdapterReport::of(&core.gpu),
            wait_tiles: opts.args.flight.wait_tiles,
            load_threads: opts.args.flight.load_threads,
            frame_ms: Percentiles::of(&frame_ms),
            gpu_ms: (gpu.len() == fr.len())
                .then(|| Percentiles::of(&gpu))
                .flatten(),
            outside_gpu_ms: (outside.len() == fr.len())
                .then(|| Percentiles::of(&outside))
                .flatten(),
            frames_waiting: fr.iter().filter(|f| f.load.missing > 0).count(),
            tiles_missing: fr.iter().map(|f| f.load.missing).sum(),
            stand_ins: fr.iter().map(|f| f.load.stand_ins).sum(),
            tiles_loaded: core.scene.loads.len(),
            load_ms: Percentiles::of(&core.scene.loads),
            wait_s: fr.iter().map(|f| f.load.wait_ms).sum::<f64>() / 1e3,
            total_s: self.started.elapsed().as_secs_f64(),
            per_frame: fr.clone(),
        }
    }
}

/// The folder of `--record`, checked before anything is rendered: a new name whose parent
/// folder exists (it is made before the first frame is written), an empty folder, or the
/// record of an earlier flight (its frames and report, which this one replaces). A folder
/// holding anything else is refused: the flight would write over a user's `report.json` or mix
/// its frames with other files.
fn record_dir(dir: &Path) -> Result<PathBuf> {
    let dir = output::in_folder(dir);
    if dir.exists() && !dir.is_dir() {
        bail!(
            "--record {}: not a folder; give a folder for the frames",
            dir.display()
        );
    }
    if !dir.exists() {
        output::check_parent(&dir, "--record")?;
        return Ok(dir);
    }
    let entries = std::fs::read_dir(&dir)
        .with_context(|| format!("--record {}: cannot list the folder", dir.display()))?;
    for e in entries {
        let name = e
            .with_context(|| format!("--record {}: cannot list the folder", dir.display()))?
            .file_name();
        let name = name.to_string_lossy();
        let ours = name == "report.json"
            || frame_index(&name).is_some()
            || name.contains(penumbra::fsio::TEMP_MARK);
        if !ours {
            bail!(
                "--record {}: the folder holds {name}, which is not a flight's record (frames \
                 frame_NNNNN.png and report.json); give a new or empty folder",
                dir.display()
            );
        }
    }
    Ok(dir)
}

/// The frame file of row `k`.
pub fn frame_name(k: usize) -> String {
    format!("frame_{k:05}.png")
}

/// The row of a frame file's name ([`frame_name`]'s inverse).
fn frame_index(name: &str) -> Option<usize> {
    let digits = name.strip_prefix("frame_")?.strip_suffix(".png")?;
    (digits.len() >= 5 && digits.bytes().all(|b| b.is_ascii_digit()))
        .then(|| digits.parse().ok())
        .flatten()
}

/// An earlier record's frames past this flight's `frames`, removed once this one is written so
/// that the folder holds one flight (only names [`record_dir`] let through are there).
fn remove_stale_frames(dir: &Path, frames: usize) -> Result<()> {
    for e in std::fs::read_dir(dir)? {
        let e = e?;
        if frame_index(&e.file_name().to_string_lossy()).is_some_and(|k| k >= frames) {
            std::fs::remove_file(e.path()).with_context(|| {
                format!(
                    "--record: cannot remove the earlier frame {}",
                    e.path().display()
                )
            })?;
        }
    }
    Ok(())
}

/// Fly the path headless: every row a frame (written to `--record` when given), and the
/// report (also `report.json` in the record folder).
pub fn run_headless(opts: &Options) -> Result<FlightReport> {
    let a = &opts.args;
    let store = crate::core::open_checked(&a.dir, &opts.method)?;
    let mut flight = Flight::new(opts, &store)?;
    let record = a.flight.record.as_deref().map(record_dir).transpose()?;
    let gpu = Gpu::headless().map_err(|e| anyhow!("{e}"))?;
    let mut core = Core::new(gpu, store, opts)?;
    let targets = Targets::new(&core.gpu, opts.width, opts.height);
    flight.attach(&mut core, opts);
    if let Some(d) = &record {
        if d.exists() {
            // An earlier record's report goes first: until this flight's is written, the
            // folder has none, which says the record is not whole.
            let old = d.join("report.json");
            if old.exists() {
                std::fs::remove_file(&old).with_context(|| {
                    format!("--record: cannot remove the earlier {}", old.display())
                })?;
            }
        } else {
            std::fs::create_dir(d)
                .with_context(|| format!("--record {}: cannot make the folder", d.display()))?;
        }
    }
    while flight.begin(&mut core) {
        let f = core.render(&targets)?;
        let rec = flight.end(&core, &f.time);
        if let Some(dir) = &record {
            let name = frame_name(rec.index);
            let px = crate::render::read_texture(
                &core.gpu,
                &targets.colour,
                targets.width,
                targets.height,
                4,
            )?;
            output::write_rgba_as_png(&dir.join(&name), targets.width, targets.height, &px)?;
            rec.file = Some(name);
        }
    }
    let report = flight.report("headless", &core, opts, (opts.width, opts.height));
    if let Some(dir) = &record {
        remove_stale_frames(dir, report.frames)?;
        let json = serde_json::to_vec_pretty(&report)?;
        penumbra::fsio::write_atomic_bytes(&dir.join("report.json"), &json)?;
    }
    Ok(report)
}

fn fmt_p(p: &Option<Percentiles>) -> String {
    match p {
        Some(p) => format!(
            "{:>9.1} {:>9.1} {:>9.1} {:>9.1}",
            p.p50, p.p95, p.max, p.mean
        ),
        None => format!("{:>9} {:>9} {:>9} {:>9}", "-", "-", "-", "-"),
    }
}

/// The report as a table for people.
pub fn table(r: &FlightReport) -> String {
    let mut s = String::new();
    let mut line = |l: String| {
        s.push_str(&l);
        s.push('\n');
    };
    line(format!(
        "flight     {} over {} ({} mode, {} of {} rows, {}×{}, {})",
        r.path.display(),
        r.tileset.display(),
        r.mode,
        r.frames,
        r.rows,
        r.width,
        r.height,
        r.method
    ));
    line(format!(
        "adapter    {} ({}, {})",
        r.adapter.name, r.adapter.backend, r.adapter.device_type
    ));
    line(format!(
        "tiles      {} loaded by {} thread(s){}; {} of {} frames drew with a tile missing \
         ({} tile-frames missing, {} stand-ins)",
        r.tiles_loaded,
        r.load_threads,
        if r.wait_tiles {
            format!(", frames waited for them {:.2} s in all", r.wait_s)
        } else {
            String::new()
        },
        r.frames_waiting,
        r.frames,
        r.tiles_missing,
        r.stand_ins
    ));
    line(format!(
        "{:<22} {:>9} {:>9} {:>9} {:>9}",
        "ms", "p50", "p95", "max", "mean"
    ));
    line(format!("{:<22} {}", "frame (wall)", fmt_p(&r.frame_ms)));
    line(format!("{:<22} {}", "terrain pass (GPU)", fmt_p(&r.gpu_ms)));
    line(format!(
        "{:<22} {}",
        "frame outside the GPU",
        fmt_p(&r.outside_gpu_ms)
    ));
    line(format!(
        "{:<22} {}",
        "tile load (loader)",
        fmt_p(&r.load_ms)
    ));
    if let Some(d) = &r.record {
        line(format!(
            "frames     {}/frame_NNNNN.png, report.json",
            d.display()
        ));
    }
    line(format!("total      {:.2} s", r.total_s));
    s
}

/// Print the report: JSON on stdout with `json`, otherwise the table (on stderr with
/// `to_stderr`, as the window does).
pub fn emit(r: &FlightReport, json: bool, to_stderr: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(r)?);
    } else if to_stderr {
        eprint!("{}", table(r));
    } else {
        print!("{}", table(r));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use penumbra::region::PathPoint;

    fn pose(lat: f64, lon: f64, h: f64) -> PathPose {
        PathPose {
            point: PathPoint {
                lat_deg: lat,
                lon_deg: lon,
                height_m: h,
            },
            heading_deg: None,
            pitch_deg: None,
            line: 0,
        }
    }

    #[test]
    fn percentiles_by_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        let p = Percentiles::of(&v).unwrap();
        assert_eq!((p.p50, p.p95, p.max, p.mean), (50.0, 95.0, 100.0, 50.5));
        assert_eq!(Percentiles::of(&[3.0]).unwrap().p95, 3.0);
        assert!(Percentiles::of(&[]).is_none());
    }

    #[test]
    fn cameras_look_along_the_path_unless_told() {
        let r = 1_737_400.0;
        // Northwards and down, then a repeated last row, then one that gives its view.
        let mut p = vec![
            pose(-10.0, 0.0, 2000.0),
            pose(-9.99, 0.0, 1000.0),
            pose(-9.99, 0.0, 1000.0),
        ];
        let mut told = pose(-9.98, 0.0, 900.0);
        told.heading_deg = Some(90.0);
        told.pitch_deg = Some(-10.0);
        p.push(told);
        let c = cameras(&p, r, 45.0);
        // 303 m north (0.01° of the Moon) and 1000 m down: 73.1° below the horizon, heading
        // north.
        assert!(c[0].heading_deg.abs() < 1e-6 || (c[0].heading_deg - 360.0).abs() < 1e-6);
        let want = (1000.0f64 / (r * 0.01f64.to_radians())).atan().to_degrees();
        assert!(
            (c[0].pitch_deg + want).abs() < 0.1,
            "{} {want}",
            c[0].pitch_deg
        );
        // The repeated row looks towards the next distinct position.
        assert!((c[2].pitch_deg - c[1].pitch_deg).abs() < 1e-9);
        assert_eq!((c[3].heading_deg, c[3].pitch_deg), (90.0, -10.0));
        // A path that never moves looks straight down.
        let still = cameras(&[pose(0.0, 0.0, 10.0), pose(0.0, 0.0, 10.0)], r, 45.0);
        assert!(still.iter().all(|c| c.pitch_deg == -90.0));
    }
}
