/*!
What the window and the headless mode share: the tileset and its GPU tiles, the camera, the
sun, the level-of-detail choice and one frame's rendering ([`Core::render`]). The window adds
input and presentation; the headless mode adds the files and the validation.
*/

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Result};
use penumbra::cube::{self, Vec3};
use penumbra::fourier::sun::Model;
use penumbra::layout::TileId;
use penumbra::shadow::{trace, HorizonSource, ShadowMethod};
use penumbra::tileset::Store;

use crate::camera::{norm, scale, Camera, SunPos};
use crate::gpu::Gpu;
use crate::lod::{LodParams, View};
use crate::options::Options;
use crate::render::{FrameParams, FrameTime, GpuTile, Renderer, Targets};
use crate::scene::Scene;
use crate::shadow::{GpuMethod, Shadows};

/// Azimuth and elevation (degrees) of the default sun at the view's target.
pub const DEFAULT_SUN_AZ_EL: (f64, f64) = (135.0, 5.0);

/// One rendered frame: which tiles, how long.
#[derive(Clone, Debug)]
pub struct FrameInfo {
    pub tiles: Vec<TileId>,
    pub time: FrameTime,
}

/// The viewer's state.
pub struct Core {
    pub gpu: Gpu,
    /// Shared with the tile loaders when tiles stream ([`crate::stream`]).
    pub shadows: Arc<Shadows>,
    pub renderer: Renderer,
    pub scene: Scene,
    pub camera: Camera,
    pub lod: LodParams,
    /// Show shadows (otherwise Lambert only).
    pub shadows_on: bool,
    /// The sun's distance (AU), for its radius.
    pub sun_distance_au: f64,
}

/// Open the tileset in `dir` (or, in a package `penumbra package` wrote, the cube-face tileset
/// it holds) and check that it holds what `method` reads: heights on a gnomonic cube for every
/// method, and Fourier pyramids for `fourier`.
pub fn open_checked(dir: &Path, method: &GpuMethod) -> Result<Store> {
    if !dir.is_dir() {
        bail!(
            "{}: no such folder; give a tileset made by `penumbra tile` or `penumbra bake`, or \
             a package made by `penumbra package`",
            dir.display()
        );
    }
    let store = Store::open(&penumbra::package::bundle::tileset_in(dir))?;
    check_method(&store, method)?;
    Ok(store)
}

/// Check that `store` holds what `method` reads: heights on a gnomonic cube for every
/// method, and Fourier pyramids for `fourier` (the library's check names what to run first).
pub fn check_method(store: &Store, method: &GpuMethod) -> Result<()> {
    let ts = store.manifest();
    if ts.products.height.is_none() {
        return Err(store
            .missing("tileset has no height tiles: make them with `penumbra tile`")
            .into());
    }
    let (check, level) = match method {
        GpuMethod::Fourier { .. } => (
            ShadowMethod::Horizon(HorizonSource::Fourier, Model::Constant),
            ts.products
                .fourier
                .as_ref()
                .and_then(|f| f.levels.iter().max().copied())
                .unwrap_or(0),
        ),
        _ => (ShadowMethod::Trace(trace::Method::Reference), 0),
    };
    penumbra::shadow::check_products(store, &check, level)?;
    Ok(())
}

/// The level range the method may draw: the Fourier pyramids' finest level for `fourier`
/// (they exist only where they were baked), `--level` when given, else every level.
pub fn level_range(store: &Store, method: &GpuMethod, level: Option<u8>) -> Result<(u8, u8)> {
    let ts = store.manifest();
    let levels = ts.layout.levels;
    if let Some(l) = level {
        if l >= levels {
            bail!(
                "--level {l}: {} has levels 0..{}",
                store.dir().display(),
                levels - 1
            );
        }
        if let (GpuMethod::Fourier { .. }, Some(f)) = (method, &ts.products.fourier) {
            if !f.levels.contains(&l) {
                bail!(
                    "--level {l} has no Fourier pyramids in {} (levels {:?}): pick one of \
                     those, or another method",
                    store.dir().display(),
                    f.levels
                );
            }
        }
        return Ok((l, l));
    }
    if let (GpuMethod::Fourier { .. }, Some(f)) = (method, &ts.products.fourier) {
        let l = f.levels.iter().max().copied().unwrap_or(levels - 1);
        return Ok((l, l));
    }
    Ok((0, levels - 1))
}

/// Most tiles [`default_camera`] reads to find where the data lies.
const CAMERA_PROBE_TILES: usize = 16;

/// The default camera: looking 60° down at the middle of the data from the south-west, far
/// enough to see all of it; for a tileset that covers the body, the whole body from above
/// latitude 0°, longitude 0°. Where the data lies comes from an 8×8 sample of the pixels of
/// the finest level with at most 16 tiles (tiles extend past a small DEM's edges).
pub fn default_camera(store: &Store) -> Camera {
    let ts = store.manifest();
    let r = ts.body.radius_m;
    let q = crate::lod::quadtree(ts);
    let level = q
        .levels()
        .into_iter()
        .filter(|l| q.tiles_at(*l).len() <= CAMERA_PROBE_TILES)
        .max()
        .unwrap_or(0);
    let n = ts.layout.tile_size as usize;
    let halo = ts.layout.halo as usize;
    let mut dirs = Vec::new();
    for t in q.tiles_at(level) {
        let h = store.height(t).ok().flatten();
        for b in 0..8 {
            for a in 0..8 {
                let (i, j) = (a * (n - 1) / 7, b * (n - 1) / 7);
                let valid = h
                    .as_ref()
                    .is_none_or(|h| h.height[(j + halo) * h.size + i + halo].is_finite());
                if valid {
                    dirs.push(q.dir_at(t, i as f64, j as f64));
                }
            }
        }
    }
    let mut sum = [0.0; 3];
    for d in &dirs {
        sum = crate::camera::add(sum, *d);
    }
    let len = norm(sum);
    if dirs.is_empty() || len < 0.5 * dirs.len() as f64 {
        // Global (or nearly): the whole disc.
        return Camera::at(r, 0.0, 0.0, 2.2 * r, 0.0, -90.0, 45.0);
    }
    let centre: Vec3 = scale(sum, 1.0 / len);
    let spread = dirs
        .iter()
        .map(|d| cube::angle_between(*d, centre))
        .fold(0.0, f64::max);
    let (lo, hi) = q.terrain_m;
    let fov = 45.0f64;
    let ground = (spread * r).max(100.0);
    let range = 0.75 * ground / (fov / 2.0).to_radians().tan();
    let target = scale(centre, r + (lo + hi) / 2.0);
    let eye = crate::camera::add(
        target,
        scale(crate::camera::local_dir(centre, 225.0, 60.0), range),
    );
    let mut c = Camera {
        eye,
        heading_deg: 0.0,
        pitch_deg: -60.0,
        fov_y_deg: fov,
    };
    c.look_at(target);
    c
}

impl Core {
    /// Set up everything for `opts` on `gpu`, with the tileset `store` (from
    /// [`open_checked`]).
    pub fn new(gpu: Gpu, store: Store, opts: &Options) -> Result<Core> {
        let (min_level, max_level) = level_range(&store, &opts.method, opts.args.level)?;
        let ts = store.manifest();
        let r = ts.body.radius_m;
        let dist =
            penumbra::fourier::stage::sun_distance(opts.args.sun_distance_au, &ts.body.name)?;
        let camera = match opts.camera {
            Some(c) => Camera::at(r, c.lat, c.lon, c.alt, c.heading, c.pitch, c.fov),
            None => default_camera(&store),
        };
        let mut sun = SunPos {
            lat_deg: 0.0,
            lon_deg: 0.0,
            radius_deg: penumbra::fourier::sun::sun_radius_deg(dist),
        };
        match opts.sun {
            Some((lat, lon)) => {
                sun.lat_deg = lat;
                sun.lon_deg = lon;
            }
            None => {
                let q = crate::lod::quadtree(ts);
                let mid = r + (q.terrain_m.0 + q.terrain_m.1) / 2.0;
                let (az, el) = DEFAULT_SUN_AZ_EL;
                sun.set_local(camera.target(mid), az, el);
            }
        }
        let shadows = Arc::new(Shadows::new(&gpu));
        let renderer = Renderer::new(&gpu, &shadows, ts.layout.tile_size as usize)?;
        let scene = Scene::new(store, opts.method.clone(), sun, opts.args.max_margin_px);
        Ok(Core {
            gpu,
            shadows,
            renderer,
            scene,
            camera,
            lod: LodParams {
                max_texel_px: opts.args.max_texel_px,
                max_tiles: opts.args.max_tiles,
                min_level,
                max_level,
            },
            shadows_on: !opts.args.no_shadows,
            sun_distance_au: dist,
        })
    }

    /// The radius of the terrain's mean sphere (m): where the camera's target lies.
    pub fn mean_radius(&self) -> f64 {
        let (lo, hi) = self.scene.quadtree.terrain_m;
        self.scene.radius_m() + (lo + hi) / 2.0
    }

    /// The view's target, body frame.
    pub fn target(&self) -> Vec3 {
        self.camera.target(self.mean_radius())
    }

    /// The sun's compass azimuth and elevation at the target (degrees).
    pub fn sun_local(&self) -> (f64, f64) {
        self.scene.sun().local(self.target())
    }

    /// The near plane for the current eye.
    pub fn near(&self) -> f64 {
        self.scene.quadtree.near_for(self.camera.eye)
    }

    /// The tiles the camera needs for a `width × height` frame.
    pub fn choose(&self, width: u32, height: u32) -> Vec<TileId> {
        let view = View {
            camera: self.camera,
            width,
            height,
            near: self.near(),
            all_directions: false,
        };
        self.scene
            .quadtree
            .select(&view, &self.lod)
            .into_iter()
            .map(|c| c.tile)
            .collect()
    }

    /// Prepare the tiles `ids` (reading, meshing, shadow data) without drawing.
    pub fn prepare(&mut self, ids: &[TileId]) -> Result<()> {
        self.scene
            .tiles(&self.gpu, &self.renderer, &self.shadows, ids)
            .map(|_| ())
    }

    /// Render one frame into `targets`.
    pub fn render(&mut self, targets: &Targets) -> Result<FrameInfo> {
        let ids = self.choose(targets.width, targets.height);
        let aspect = targets.width as f64 / targets.height as f64;
        let frame = FrameParams {
            eye: self.camera.eye,
            view_proj: crate::camera::view_proj(&self.camera, aspect, self.near()),
            sun_dir: self.scene.sun().sun().dir,
            shadows: self.shadows_on,
        };
        let tiles: Vec<&GpuTile> =
            self.scene
                .tiles(&self.gpu, &self.renderer, &self.shadows, &ids)?;
        let time = self.renderer.draw(&self.gpu, targets, &frame, &tiles)?;
        Ok(FrameInfo { tiles: ids, time })
    }

    /// The status line: method, sun at the target, frame time.
    pub fn status_line(&self, time: Option<&FrameTime>) -> String {
        let (az, el) = self.sun_local();
        let m = if self.shadows_on {
            self.scene.method().label()
        } else {
            "no shadows".into()
        };
        let t = match time {
            Some(FrameTime {
                gpu_ms: Some(g), ..
            }) => format!("gpu {g:.2} ms"),
            Some(t) => format!("frame {:.1} ms (no timestamps)", t.wall_ms),
            None => "-".into(),
        };
        format!("{m} | sun az {az:.1}° el {el:.2}° | {t}")
    }
}
