/*!
The window (winit 0.30): the same frame as the headless mode ([`Core::render`]) composited
onto the window's surface with the status line, and the keys and mouse that move the camera,
the sun and the method.

Keys: arrows turn the sun in azimuth (←/→) and elevation (↑/↓) *at the view's target*;
`M` cycles the method, `1`–`6` pick dp, uniform, extrema, fourier, extrema-soft, dp-jung; `H` toggles shadows; `F`
toggles orbit and fly; `W A S D` and `Q E` fly; `+`/`-` make the keys' steps larger or
smaller; `Esc` quits. Mouse: drag to orbit the target (or to look around when flying), wheel to
zoom. `--screenshot PNG --frames N` saves the N-th frame as the window shows it and exits.
With `--path` the window flies a camera path ([`crate::flight`]), one row per frame with the
tiles streamed, the keys live (the camera keys are overridden by the path), and closes at the
path's end (saving `--screenshot` then), printing the flight's report.

Vulkan first; where a surface cannot be made or no Vulkan adapter presents to it (a software
X server without DRI3), the instance is made again for OpenGL with the window system's
display handle.
*/

use std::path::Path;
use std::sync::Arc;

use anyhow::{anyhow, bail, Context as _, Result};
use penumbra::tileset::Store;
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop, OwnedDisplayHandle};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

use crate::camera::norm;
use crate::core::{level_range, Core};
use crate::flight::Flight;
use crate::gpu::Gpu;
use crate::options::{self, Options};
use crate::output;
use crate::overlay::Composite;
use crate::render::{FrameTime, Targets, COLOUR_FORMAT};
use crate::shadow::GpuMethod;

/// Whether a window system is reachable from the environment (X11 or Wayland).
pub fn window_system_present() -> bool {
    ["DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}

/// Open the window and run until it is closed (or the screenshot is saved).
pub fn run(opts: Options) -> Result<()> {
    if let Some(s) = &opts.args.screenshot {
        output::check_parent(s, "--screenshot")?;
    }
    let store = crate::core::open_checked(&opts.args.dir, &opts.method)?;
    let flight = match opts.args.flight.path {
        Some(_) => Some(Flight::new(&opts, &store)?),
        None => None,
    };
    if !window_system_present() {
        bail!(
            "no window system: neither DISPLAY nor WAYLAND_DISPLAY is set. Run it in a desktop \
             session (or under Xvfb: `Xvfb :99 & DISPLAY=:99 penumbra-view …`), or render \
             without a window with --headless --out FRAME.png"
        );
    }
    let event_loop = EventLoop::new().map_err(|e| {
        anyhow!(
            "cannot connect to the window system ({e}); check DISPLAY/WAYLAND_DISPLAY, or use \
             --headless"
        )
    })?;
    let display = event_loop.owned_display_handle();
    let mut app = App {
        opts,
        store: Some(store),
        display,
        state: None,
        error: None,
        frames: 0,
        drag: None,
        cursor: None,
        step: 1.0,
        fly: false,
        note: None,
        flight,
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| anyhow!("the window's event loop failed: {e}"))?;
    if let Some(e) = app.error {
        return Err(e);
    }
    if let (Some(f), Some(st)) = (&app.flight, &app.state) {
        let size = (st.targets.width, st.targets.height);
        let report = f.report("window", &st.core, &app.opts, size);
        crate::flight::emit(&report, app.opts.args.json, true)?;
    }
    Ok(())
}

/// The window and what draws into it.
struct State {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    core: Core,
    targets: Targets,
    composite: Composite,
    last: Option<FrameTime>,
}

struct App {
    opts: Options,
    store: Option<Store>,
    display: OwnedDisplayHandle,
    state: Option<State>,
    error: Option<anyhow::Error>,
    frames: u32,
    /// The cursor position where the left button went down, while it is held.
    drag: Option<(f64, f64)>,
    cursor: Option<(f64, f64)>,
    /// Multiplier of the keys' steps.
    step: f64,
    fly: bool,
    /// A message shown in the status line until the next key.
    note: Option<String>,
    /// The camera path being flown (`--path`).
    flight: Option<Flight>,
}

/// Make the instance, the surface and the device, Vulkan first, then OpenGL.
fn connect(
    display: &OwnedDisplayHandle,
    window: &Arc<Window>,
) -> Result<(Gpu, wgpu::Surface<'static>)> {
    let mut errors = Vec::new();
    let forced = std::env::var("WGPU_BACKEND").ok();
    for backends in [wgpu::Backends::VULKAN, wgpu::Backends::GL] {
        let mut desc =
            wgpu::InstanceDescriptor::new_with_display_handle_from_env(Box::new(display.clone()));
        if forced.is_none() {
            desc.backends = backends;
        } else if backends == wgpu::Backends::GL {
            break; // WGPU_BACKEND chose already
        }
        let instance = wgpu::Instance::new(desc);
        let surface = match instance.create_surface(window.clone()) {
            Ok(s) => s,
            Err(e) => {
                errors.push(format!("{backends:?}: no surface ({e})"));
                continue;
            }
        };
        match Gpu::for_surface(instance, &surface) {
            Ok(g) => return Ok((g, surface)),
            Err(e) => errors.push(format!("{backends:?}: {e}")),
        }
    }
    Err(anyhow!(
        "no GPU adapter can draw into the window ({}); install a Vulkan or OpenGL driver \
         (Mesa's lavapipe: `apt-get install mesa-vulkan-drivers`), or use --headless",
        errors.join("; ")
    ))
}

/// The surface format: an sRGB RGBA8/BGRA8 one when offered.
fn pick_format(caps: &wgpu::SurfaceCapabilities) -> Result<wgpu::TextureFormat> {
    caps.formats
        .iter()
        .copied()
        .find(|f| f.is_srgb())
        .or_else(|| caps.formats.first().copied())
        .ok_or_else(|| anyhow!("the window's surface offers no format"))
}

impl App {
    fn start(&mut self, el: &ActiveEventLoop) -> Result<()> {
        let (w, h) = (self.opts.width, self.opts.height);
        let window = Arc::new(
            el.create_window(
                Window::default_attributes()
                    .with_title("penumbra-view")
                    .with_inner_size(PhysicalSize::new(w, h)),
            )
            .context("cannot open a window")?,
        );
        let (gpu, surface) = connect(&self.display, &window)?;
        let caps = surface.get_capabilities(&gpu.adapter);
        let format = pick_format(&caps)?;
        let size = window.inner_size();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            color_space: Default::default(),
            width: size.width.max(1),
            height: size.height.max(1),
            desired_maximum_frame_latency: 2,
            present_mode: wgpu::PresentMode::Fifo,
            alpha_mode: caps
                .alpha_modes
                .first()
                .copied()
                .unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: vec![],
        };
        surface.configure(&gpu.device, &config);
        let store = self.store.take().expect("started once");
        // Glyph pixels: 1:1 in a small window, doubled from 800 px across.
        let composite = Composite::new(&gpu, format, if config.width >= 800 { 2 } else { 1 })?;
        let mut core = Core::new(gpu, store, &self.opts)?;
        if let Some(f) = &mut self.flight {
            f.attach(&mut core, &self.opts);
        }
        let targets = Targets::new(&core.gpu, config.width, config.height);
        eprintln!(
            "penumbra-view: {} ({:?}) into a {}×{} window",
            core.gpu.info.name, core.gpu.info.backend, config.width, config.height
        );
        window.request_redraw();
        self.state = Some(State {
            window,
            surface,
            config,
            core,
            targets,
            composite,
            last: None,
        });
        Ok(())
    }

    fn fail(&mut self, el: &ActiveEventLoop, e: anyhow::Error) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        el.exit();
    }

    fn redraw(&mut self, el: &ActiveEventLoop) -> Result<()> {
        let Some(st) = self.state.as_mut() else {
            return Ok(());
        };
        if let Some(fl) = &mut self.flight {
            if !fl.begin(&mut st.core) {
                el.exit();
                return Ok(());
            }
        }
        let f = st.core.render(&st.targets)?;
        st.last = Some(f.time);
        let mut line = st.core.status_line(st.last.as_ref());
        if self.fly {
            line.push_str(" | fly");
        }
        if let Some(fl) = &self.flight {
            line.push_str(&fl.status(&st.core));
        }
        if let Some(n) = &self.note {
            line = format!("{line} | {n}");
        }
        st.composite.set_text(&st.core.gpu, &line);
        let frame = match st.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                st.surface.configure(&st.core.gpu.device, &st.config);
                st.window.request_redraw();
                return Ok(());
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                st.window.request_redraw();
                return Ok(());
            }
            other => bail!("the window's surface failed: {other:?}"),
        };
        let view = frame.texture.create_view(&Default::default());
        st.composite.draw(&st.core.gpu, &st.targets, &view);
        st.window.pre_present_notify();
        st.core.gpu.queue.present(frame);
        self.frames += 1;
        if let Some(fl) = &mut self.flight {
            fl.end(&st.core, &f.time);
            if fl.finished() {
                if let Some(path) = self.opts.args.screenshot.as_deref().map(output::in_folder) {
                    self.screenshot(&path)?;
                }
                el.exit();
            } else {
                st.window.request_redraw();
            }
            return Ok(());
        }
        if let Some(path) = self.opts.args.screenshot.as_deref().map(output::in_folder) {
            if self.frames >= self.opts.frames {
                self.screenshot(&path)?;
                el.exit();
                return Ok(());
            }
            if let Some(st) = &self.state {
                st.window.request_redraw();
            }
        }
        Ok(())
    }

    /// Save what the window shows (the composited frame with its status line).
    fn screenshot(&mut self, path: &Path) -> Result<()> {
        let st = self.state.as_mut().expect("running");
        let mut shot = Composite::new(&st.core.gpu, COLOUR_FORMAT, st.composite.scale)?;
        let mut line = st.core.status_line(st.last.as_ref());
        if let Some(fl) = &self.flight {
            line.push_str(&fl.status(&st.core));
        }
        if let Some(n) = &self.note {
            line = format!("{line} | {n}");
        }
        shot.set_text(&st.core.gpu, &line);
        let px = shot.capture(&st.core.gpu, &st.targets)?;
        output::write_rgba_as_png(path, st.targets.width, st.targets.height, &px)?;
        eprintln!(
            "penumbra-view: saved {} after {} frames ({})",
            path.display(),
            self.frames,
            line
        );
        Ok(())
    }

    fn key(&mut self, key: &Key) -> Result<bool> {
        let Some(st) = self.state.as_mut() else {
            return Ok(false);
        };
        let core = &mut st.core;
        self.note = None;
        let step = self.step;
        let r_mean = core.mean_radius();
        let alt = (norm(core.camera.eye) - r_mean).max(1.0);
        let sun_turn = |core: &mut Core, d_az: f64, d_el: f64| {
            let t = core.target();
            let (az, el) = core.sun_local();
            let mut s = core.scene.sun();
            s.set_local(t, az + d_az, (el + d_el).clamp(-89.0, 89.0));
            core.scene.set_sun(&core.gpu, s);
        };
        match key {
            Key::Named(NamedKey::Escape) => return Ok(true),
            Key::Named(NamedKey::ArrowLeft) => sun_turn(core, -5.0 * step, 0.0),
            Key::Named(NamedKey::ArrowRight) => sun_turn(core, 5.0 * step, 0.0),
            Key::Named(NamedKey::ArrowUp) => sun_turn(core, 0.0, 0.25 * step),
            Key::Named(NamedKey::ArrowDown) => sun_turn(core, 0.0, -0.25 * step),
            Key::Character(c) => match c.as_str() {
                "m" | "M" => {
                    let next = match core.scene.method() {
                        GpuMethod::Dp { .. } => "dp-jung",
                        GpuMethod::DpJung { .. } => "uniform",
                        GpuMethod::Uniform { .. } => "extrema",
                        GpuMethod::Extrema => "extrema-soft",
                        GpuMethod::ExtremaSoft => "fourier",
                        GpuMethod::Fourier { .. } => "dp",
                    };
                    self.note = self.switch(next).err().map(|e| format!("{e:#}"));
                }
                "1" | "2" | "3" | "4" | "5" | "6" => {
                    let name = [
                        "dp",
                        "uniform",
                        "extrema",
                        "fourier",
                        "extrema-soft",
                        "dp-jung",
                    ][c.parse::<usize>()? - 1];
                    self.note = self.switch(name).err().map(|e| format!("{e:#}"));
                }
                "h" | "H" => core.shadows_on = !core.shadows_on,
                "f" | "F" => self.fly = !self.fly,
                "+" | "=" => self.step = (self.step * 2.0).min(64.0),
                "-" | "_" => self.step = (self.step / 2.0).max(1.0 / 64.0),
                "w" | "W" => core.camera.fly(0.1 * alt * step, 0.0, 0.0),
                "s" | "S" => core.camera.fly(-0.1 * alt * step, 0.0, 0.0),
                "a" | "A" => core.camera.fly(0.0, -0.1 * alt * step, 0.0),
                "d" | "D" => core.camera.fly(0.0, 0.1 * alt * step, 0.0),
                "q" | "Q" => core.camera.fly(0.0, 0.0, -0.1 * alt * step),
                "e" | "E" => core.camera.fly(0.0, 0.0, 0.1 * alt * step),
                _ => return Ok(false),
            },
            _ => return Ok(false),
        }
        if let Some(st) = &self.state {
            st.window.request_redraw();
        }
        Ok(false)
    }

    /// Use the method `name` with the command line's steps and DP levels, when the tileset
    /// holds what it reads.
    fn switch(&mut self, name: &str) -> Result<()> {
        let m = options::method(name, &self.opts.args)?;
        let st = self.state.as_mut().expect("running");
        let core = &mut st.core;
        crate::core::check_method(&core.scene.store, &m)?;
        let (lo, hi) = level_range(&core.scene.store, &m, self.opts.args.level)?;
        core.lod.min_level = lo;
        core.lod.max_level = hi;
        core.scene.set_method(&core.gpu, m);
        Ok(())
    }

    fn mouse_move(&mut self, x: f64, y: f64) {
        self.cursor = Some((x, y));
        let (Some((x0, y0)), Some(st)) = (self.drag, self.state.as_mut()) else {
            return;
        };
        let (dx, dy) = (x - x0, y - y0);
        self.drag = Some((x, y));
        let core = &mut st.core;
        let deg_per_px = core.camera.fov_y_deg / st.config.height as f64;
        if self.fly {
            core.camera.heading_deg += dx * deg_per_px;
            core.camera.pitch_deg = (core.camera.pitch_deg - dy * deg_per_px).clamp(-90.0, 90.0);
        } else {
            let r = core.mean_radius();
            core.camera.orbit(r, -dx * 0.3, dy * 0.2);
        }
        st.window.request_redraw();
    }

    fn zoom(&mut self, lines: f64) {
        let Some(st) = self.state.as_mut() else {
            return;
        };
        let core = &mut st.core;
        let r = core.mean_radius();
        let texel = core
            .scene
            .store
            .manifest()
            .layout
            .centre_pixel_m(core.lod.max_level, core.scene.radius_m());
        core.camera.zoom(r, 0.85f64.powf(lines), 4.0 * texel);
        st.window.request_redraw();
    }

    fn resize(&mut self, size: PhysicalSize<u32>) {
        let Some(st) = self.state.as_mut() else {
            return;
        };
        if size.width == 0 || size.height == 0 {
            return;
        }
        st.config.width = size.width;
        st.config.height = size.height;
        st.surface.configure(&st.core.gpu.device, &st.config);
        st.targets = Targets::new(&st.core.gpu, size.width, size.height);
        st.window.request_redraw();
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.state.is_none() && self.error.is_none() {
            if let Err(e) = self.start(el) {
                self.fail(el, e);
            }
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => el.exit(),
            WindowEvent::Resized(size) => self.resize(size),
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw(el) {
                    self.fail(el, e);
                }
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                match self.key(&event.logical_key) {
                    Ok(true) => el.exit(),
                    Ok(false) => {}
                    Err(e) => self.fail(el, e),
                }
            }
            WindowEvent::CursorMoved { position, .. } => self.mouse_move(position.x, position.y),
            WindowEvent::MouseInput {
                state,
                button: MouseButton::Left,
                ..
            } => {
                self.drag = match state {
                    ElementState::Pressed => self.cursor,
                    ElementState::Released => None,
                };
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                self.zoom(lines);
            }
            _ => {}
        }
    }
}
