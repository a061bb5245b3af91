//! The horizon stage's **sweep** method as a wgpu compute pass: `penumbra horizon --device gpu`,
//! `bake --device`, a scene's `[horizon] device` (docs/horizons.md, "On the GPU").
//!
//! The `penumbra` library prepares each tile's azimuth jobs ([`penumbra::horizon::device`]: the
//! lines, near-field steps and column tables the CPU sweep uses) and finishes the result (the
//! reference where a pixel found nothing); this crate runs the lines and pixels in three compute
//! passes (`sweep.wgsl`) a batch of azimuth jobs at a time, so that GPU memory is bounded by
//! the tile and its context, never by the number of tiles or azimuths ([`TileShape`]).
//! The Fourier DFT and the far rings stay on the CPU, after each tile's maps are read back.

use std::sync::Mutex;
use std::time::Duration;

use bytemuck::{Pod, Zeroable};
use penumbra::horizon::device::{DeviceChoice, SweepDevice, SweepJob, EDGE_SCAN_COLS, NEAR_COLS};
use penumbra::horizon::{Context, Rect};

/// Near-field steps per direction the shader has room for (the CPU makes ≤ 24 column, ≤ 24 row
/// and ≤ 8 mid-cell steps).
const MAX_STEPS: usize = 64;

/// GPU memory a batch of azimuth jobs may take (scratch lines, slots and results), unless
/// `PENUMBRA_GPU_MEMORY_MIB` says otherwise: a 512² tile with a 1150² context takes ≈ 37 MiB
/// per job, so 13 jobs (26 azimuths) go at once.
pub const DEFAULT_MEMORY_MIB: u64 = 512;

/// Why no GPU could be used.
#[derive(Debug)]
pub enum OpenError {
    /// `--device gpu` and no adapter at all.
    NoAdapter(String),
    /// The adapter refused a device or the shader.
    Device(String),
    /// A setting of the environment is out of range.
    Setting(String),
}

impl std::fmt::Display for OpenError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            OpenError::NoAdapter(why) => write!(
                f,
                "--device gpu: no GPU adapter ({why}); install a Vulkan driver for your GPU, or \
                 Mesa's software one, lavapipe (`apt-get install mesa-vulkan-drivers`), or run \
                 the sweep on the CPU with --device cpu"
            ),
            OpenError::Setting(why) => write!(f, "--device: {why}"),
            OpenError::Device(why) => write!(
                f,
                "--device gpu: {why}; update the driver, try another backend with \
                 WGPU_BACKEND=vulkan|gl, or run the sweep on the CPU with --device cpu"
            ),
        }
    }
}

impl std::error::Error for OpenError {}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    width: u32,
    height: u32,
    rx0: u32,
    ry0: u32,
    rw: u32,
    rh: u32,
    jobs: u32,
    max_lines: u32,
    ox: f32,
    oy: f32,
    face_px: f32,
    radius: f32,
    np_max: u32,
    row_threads: u32,
    seg: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuJob {
    xmajor: u32,
    look: i32,
    step: i32,
    dirs: u32,
    t: f32,
    m_lo: i32,
    m_hi: i32,
    pc: i32,
    rp0: i32,
    rp1: i32,
    rq0: i32,
    rq1: i32,
    du: f32,
    dv: f32,
    adp: f32,
    nsteps0: u32,
    nsteps1: u32,
    _pad0: u32,
    zero: [[ZeroTap; 2]; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ZeroTap {
    step: i32,
    weight: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuStep {
    k: f32,
    four: u32,
    _a: u32,
    _b: u32,
    dc: [i32; 4],
    dr: [i32; 4],
    w: [f32; 4],
}

/// Observer columns per invocation of the observers pass on a hardware GPU: more invocations
/// than lines alone give (a 512² tile has ≈ 1000 lines an azimuth), each with a short run.
const SEG_COLS: u32 = 16;

/// Bytes of one line sample in the scratch buffer: its place (x, y) and, per direction, its
/// predecessor in the hull chain and the hull's top after its column.
const SAMPLE_BYTES: u64 = 24;

/// Invocations per row of the pixel pass (workgroups of 256, at most 32768 per row).
const ROW_THREADS: u32 = 32768 * 256;

/// A GPU ready to run the sweep: its device, queue and the three pipelines.
pub struct GpuSweep {
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    hulls: wgpu::ComputePipeline,
    observers: wgpu::ComputePipeline,
    pixels: wgpu::ComputePipeline,
    /// Observer columns per invocation of the observers pass: 1 on a software adapter, whose
    /// loops stop after 65535 steps an invocation (Mesa's llvmpipe), else [`SEG_COLS`].
    seg: u32,
    layout: wgpu::BindGroupLayout,
    limits: wgpu::Limits,
    memory: u64,
    /// One tile at a time (the stage's tiles are sequential; this keeps a caller's threads
    /// from interleaving batches).
    busy: Mutex<()>,
}

impl std::fmt::Debug for GpuSweep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.describe())
    }
}

impl GpuSweep {
    /// The device `choice` asks for: None for the CPU (`cpu`, or `auto` where the only
    /// adapter is a software one or there is none); an error where `gpu` finds no adapter.
    pub fn open(choice: DeviceChoice) -> Result<Option<GpuSweep>, OpenError> {
        if choice == DeviceChoice::Cpu {
            return Ok(None);
        }
        let memory = memory_budget()? << 20;
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let options = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        };
        let adapter = match pollster::block_on(instance.request_adapter(&options)) {
            Ok(a) => a,
            Err(e) => {
                if choice == DeviceChoice::Auto {
                    return Ok(None);
                }
                // A software adapter only answers when asked for the fallback.
                let fallback = wgpu::RequestAdapterOptions {
                    force_fallback_adapter: true,
                    ..options
                };
                pollster::block_on(instance.request_adapter(&fallback))
                    .map_err(|e2| OpenError::NoAdapter(format!("{e}; {e2}")))?
            }
        };
        let info = adapter.get_info();
        if choice == DeviceChoice::Auto && info.device_type == wgpu::DeviceType::Cpu {
            return Ok(None);
        }
        let limits = adapter.limits();
        let desc = wgpu::DeviceDescriptor {
            label: Some("penumbra-gpu"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc)).map_err(|e| {
            OpenError::Device(format!(
                "{} ({:?}) refused a device: {e}",
                info.name, info.backend
            ))
        })?;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("sweep.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("sweep.wgsl").into()),
        });
        let storage = |binding: u32, read_only: bool| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("sweep"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                storage(1, true),
                storage(2, true),
                storage(3, true),
                storage(4, true),
                storage(5, false),
                storage(6, false),
                storage(7, false),
            ],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("sweep"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let constants = [
            ("NEAR_COLS", NEAR_COLS as f64),
            ("EDGE_SCAN", EDGE_SCAN_COLS),
            ("MAX_STEPS", MAX_STEPS as f64),
        ];
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pl),
                module: &module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    ..Default::default()
                },
                cache: None,
            })
        };
        let (hulls, observers, pixels) =
            (pipeline("hulls"), pipeline("observers"), pipeline("pixels"));
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(OpenError::Device(format!(
                "the sweep shader does not build on {}: {e}",
                info.name
            )));
        }
        let seg = if info.device_type == wgpu::DeviceType::Cpu {
            1
        } else {
            SEG_COLS
        };
        Ok(Some(GpuSweep {
            device,
            queue,
            info,
            hulls,
            observers,
            pixels,
            seg,
            layout,
            limits,
            memory,
            busy: Mutex::new(()),
        }))
    }

    /// One line naming the adapter: name, backend, device type, driver.
    pub fn describe(&self) -> String {
        let i = &self.info;
        let driver = if i.driver_info.is_empty() {
            i.driver.clone()
        } else {
            format!("{} {}", i.driver, i.driver_info)
        };
        format!(
            "{} ({:?}, {:?}, {})",
            i.name,
            i.backend,
            i.device_type,
            driver.trim()
        )
    }

    /// Whether the adapter is a software one (lavapipe).
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The memory budget a tile's batches are cut to (bytes).
    pub fn memory_budget(&self) -> u64 {
        self.memory
    }
}

/// `PENUMBRA_GPU_MEMORY_MIB` (16..=1048576), or [`DEFAULT_MEMORY_MIB`] where unset.
fn memory_budget() -> Result<u64, OpenError> {
    const VAR: &str = "PENUMBRA_GPU_MEMORY_MIB";
    let Ok(v) = std::env::var(VAR) else {
        return Ok(DEFAULT_MEMORY_MIB);
    };
    v.trim()
        .parse::<u64>()
        .ok()
        .filter(|m| (16..=1 << 20).contains(m))
        .ok_or_else(|| {
            OpenError::Setting(format!(
                "{VAR}={v:?} is not a GPU memory budget in MiB within 16..=1048576 (unset it for \
                 the default {DEFAULT_MEMORY_MIB})"
            ))
        })
}

/// A tile as the GPU holds it: its context raster, its pixels and the most lines an azimuth
/// job sweeps (≤ tile width + height + 3).
#[derive(Clone, Copy, Debug)]
pub struct TileShape {
    pub width: u64,
    pub height: u64,
    pub plane: u64,
    pub max_lines: u64,
}

impl TileShape {
    /// The shape of a square `tile` with `margin` context pixels on each side.
    pub fn square(tile: u64, margin: u64) -> TileShape {
        let side = tile + 2 * margin;
        TileShape {
            width: side,
            height: side,
            plane: tile * tile,
            max_lines: 2 * tile + 3,
        }
    }

    fn heights_bytes(&self) -> u64 {
        self.width * self.height * 4
    }

    /// One job's (two azimuths') buffers: the lines' scratch, the far-field slots (two a pixel
    /// and direction), the results and their read-back copy, the job's small tables.
    pub fn per_job_bytes(&self) -> u64 {
        let np = self.width.max(self.height);
        self.max_lines * np * SAMPLE_BYTES
            + 2 * self.plane * 2 * 4
            + 2 * 2 * self.plane * 4
            + 2 * MAX_STEPS as u64 * 64
            + np * 8
            + 128
    }

    fn biggest_buffer(&self) -> u64 {
        let np = self.width.max(self.height);
        (self.max_lines * np * SAMPLE_BYTES)
            .max(2 * self.plane * 8)
            .max(self.heights_bytes())
    }

    /// Jobs per batch within `memory` bytes (at least one) and an adapter's largest binding
    /// `cap`; None where one job's largest buffer exceeds `cap`.
    pub fn batch(&self, memory: u64, cap: u64) -> Option<u64> {
        if self.biggest_buffer() > cap {
            return None;
        }
        let np = self.width.max(self.height);
        let by_budget = memory.saturating_sub(self.heights_bytes()) / self.per_job_bytes();
        let by_cap = (cap / (self.max_lines * np * SAMPLE_BYTES).max(1))
            .min(cap / (2 * self.plane * 8).max(1));
        Some(by_budget.min(by_cap).max(1))
    }

    /// The GPU memory the tile takes at the peak with `batch` jobs a batch: its heights and
    /// the batch's buffers. Depends on the tile and its context only, never on how many tiles,
    /// levels or azimuths a run has.
    pub fn peak_bytes(&self, batch: u64) -> u64 {
        self.heights_bytes() + batch * self.per_job_bytes()
    }
}

impl SweepDevice for GpuSweep {
    fn key(&self) -> String {
        format!("gpu: {}", self.describe())
    }

    fn sweep(
        &self,
        ctx: &Context,
        rect: Rect,
        a: usize,
        jobs: &[SweepJob],
    ) -> Result<Vec<f32>, String> {
        let _one = self.busy.lock().unwrap_or_else(|e| e.into_inner());
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let vscope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = self.run(ctx, rect, a, jobs);
        if let Some(e) = pollster::block_on(vscope.pop()) {
            return Err(format!("the GPU refused the sweep: {e}"));
        }
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(format!(
                "the GPU ran out of memory ({e}); lower PENUMBRA_GPU_MEMORY_MIB (now {}) or use \
                 --device cpu",
                self.memory >> 20
            ));
        }
        out
    }
}

impl GpuSweep {
    fn run(
        &self,
        ctx: &Context,
        rect: Rect,
        a: usize,
        jobs: &[SweepJob],
    ) -> Result<Vec<f32>, String> {
        let (dev, queue) = (&self.device, &self.queue);
        let plane = rect.w * rect.h;
        let np_max = ctx.width.max(ctx.height);
        let max_lines = jobs
            .iter()
            .map(|j| (j.m_hi - j.m_lo + 1).max(0) as u64)
            .max()
            .unwrap_or(0);
        let cap = self
            .limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size);
        let shape = TileShape {
            width: ctx.width as u64,
            height: ctx.height as u64,
            plane: plane as u64,
            max_lines,
        };
        let batch = shape.batch(self.memory, cap).ok_or_else(|| {
            format!(
                "a tile of {}×{} pixels with a {}×{} context needs {} MiB in one buffer, more \
                 than this adapter binds ({} MiB): use --device cpu or smaller tiles",
                rect.w,
                rect.h,
                ctx.width,
                ctx.height,
                shape.biggest_buffer() >> 20,
                cap >> 20
            )
        })?;
        let batch = batch.min(jobs.len() as u64).max(1) as usize;

        // The heights, every NaN made the one no-data pattern the shader tests.
        let nodata = f32::from_bits(0x7fc0_0000);
        let heights: Vec<f32> = ctx
            .heights
            .iter()
            .map(|&h| if h.is_nan() { nodata } else { h })
            .collect();
        use wgpu::util::DeviceExt;
        let storage = |label: &str, bytes: &[u8]| {
            dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            })
        };
        let heights_buf = storage("heights", bytemuck::cast_slice(&heights));
        let empty = |label: &str, size: u64, usage: wgpu::BufferUsages| {
            dev.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16),
                usage,
                mapped_at_creation: false,
            })
        };
        let rw = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let scratch = empty(
            "scratch",
            batch as u64 * max_lines * np_max as u64 * SAMPLE_BYTES,
            rw,
        );
        let far = empty("far", batch as u64 * 2 * plane as u64 * 8, rw);
        let out_size = batch as u64 * 2 * plane as u64 * 4;
        let outb = empty("out", out_size, rw | wgpu::BufferUsages::COPY_SRC);
        let read = empty(
            "readback",
            out_size,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        let params_buf = empty(
            "params",
            std::mem::size_of::<Params>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let jobs_buf = empty(
            "jobs",
            (batch * std::mem::size_of::<GpuJob>()) as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        let steps_buf = empty(
            "steps",
            (batch * 2 * MAX_STEPS * std::mem::size_of::<GpuStep>()) as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        let cols_buf = empty(
            "cols",
            (batch * np_max * 8) as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        let bind = dev.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("sweep"),
            layout: &self.layout,
            entries: &[
                (0, &params_buf),
                (1, &heights_buf),
                (2, &jobs_buf),
                (3, &steps_buf),
                (4, &cols_buf),
                (5, &scratch),
                (6, &far),
                (7, &outb),
            ]
            .map(|(binding, b)| wgpu::BindGroupEntry {
                binding,
                resource: b.as_entire_binding(),
            }),
        });

        let mut result = vec![0.0f32; plane * a];
        for chunk in jobs.chunks(batch) {
            let mut gj = Vec::with_capacity(chunk.len());
            let mut gs = vec![GpuStep::zeroed(); chunk.len() * 2 * MAX_STEPS];
            let mut gc = vec![[0.0f32; 2]; chunk.len() * np_max];
            for (n, j) in chunk.iter().enumerate() {
                gj.push(gpu_job(j)?);
                for dir in 0..2 {
                    for (i, s) in j.steps[dir].iter().enumerate() {
                        gs[(n * 2 + dir) * MAX_STEPS + i] = GpuStep {
                            k: s.k as f32,
                            four: s.four as u32,
                            _a: 0,
                            _b: 0,
                            dc: s.taps.map(|t| t.0 as i32),
                            dr: s.taps.map(|t| t.1 as i32),
                            w: s.taps.map(|t| t.2),
                        };
                    }
                }
                for (p, (fl, fr)) in j.col_floor.iter().zip(&j.col_frac).enumerate() {
                    gc[n * np_max + p] = [*fl as f32, *fr];
                }
            }
            let params = Params {
                width: ctx.width as u32,
                height: ctx.height as u32,
                rx0: rect.x0 as u32,
                ry0: rect.y0 as u32,
                rw: rect.w as u32,
                rh: rect.h as u32,
                jobs: chunk.len() as u32,
                max_lines: max_lines as u32,
                ox: ctx.origin.0 as f32,
                oy: ctx.origin.1 as f32,
                face_px: ctx.face_pixels as f32,
                radius: ctx.radius_m as f32,
                np_max: np_max as u32,
                row_threads: ROW_THREADS,
                seg: self.seg,
            };
            queue.write_buffer(&params_buf, 0, bytemuck::bytes_of(&params));
            queue.write_buffer(&jobs_buf, 0, bytemuck::cast_slice(&gj));
            queue.write_buffer(&steps_buf, 0, bytemuck::cast_slice(&gs));
            queue.write_buffer(&cols_buf, 0, bytemuck::cast_slice(&gc));
            let mut enc = dev.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("sweep"),
            });
            enc.clear_buffer(&far, 0, None);
            let line_groups = (max_lines as u32).div_ceil(64);
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("hulls"),
                    timestamp_writes: None,
                });
                pass.set_bind_group(0, &bind, &[]);
                pass.set_pipeline(&self.hulls);
                pass.dispatch_workgroups(line_groups, chunk.len() as u32, 1);
            }
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("observers"),
                    timestamp_writes: None,
                });
                pass.set_bind_group(0, &bind, &[]);
                pass.set_pipeline(&self.observers);
                let cols = rect.w.max(rect.h) as u32;
                let segs = cols.div_ceil(self.seg);
                pass.dispatch_workgroups(line_groups, 2 * segs, chunk.len() as u32);
            }
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("pixels"),
                    timestamp_writes: None,
                });
                pass.set_bind_group(0, &bind, &[]);
                pass.set_pipeline(&self.pixels);
                let total = chunk.len() as u64 * 2 * plane as u64;
                let groups = total.div_ceil(256);
                let (x, y) = (groups.min(32768), groups.div_ceil(32768));
                pass.dispatch_workgroups(x as u32, y as u32, 1);
            }
            let bytes = (chunk.len() * 2 * plane * 4) as u64;
            enc.copy_buffer_to_buffer(&outb, 0, &read, 0, bytes);
            let idx = queue.submit([enc.finish()]);
            let slice = read.slice(0..bytes);
            let (tx, rx) = std::sync::mpsc::channel();
            slice.map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx.send(r);
            });
            dev.poll(wgpu::PollType::Wait {
                submission_index: Some(idx),
                timeout: Some(Duration::from_secs(600)),
            })
            .map_err(|e| format!("waiting for the GPU: {e}"))?;
            rx.recv()
                .map_err(|_| "the GPU dropped a buffer mapping".to_string())?
                .map_err(|e| format!("reading the horizons back: {e}"))?;
            {
                let view = slice
                    .get_mapped_range()
                    .map_err(|e| format!("reading the horizons back: {e:?}"))?;
                let got: &[f32] = bytemuck::cast_slice(&view);
                for (n, j) in chunk.iter().enumerate() {
                    for (dir, k) in j.planes.iter().enumerate() {
                        if let Some(k) = k {
                            let src = &got[(n * 2 + dir) * plane..][..plane];
                            result[k * plane..][..plane].copy_from_slice(src);
                        }
                    }
                }
            }
            read.unmap();
        }
        Ok(result)
    }
}

/// A job as the shader reads it (its output planes in the batch are 2n and 2n + 1).
fn gpu_job(j: &SweepJob) -> Result<GpuJob, String> {
    for s in &j.steps {
        if s.len() > MAX_STEPS {
            return Err(format!(
                "{} near-field steps, more than the shader's {MAX_STEPS}",
                s.len()
            ));
        }
    }
    let zt = |z: Option<(i64, f64)>| match z {
        Some((s, w)) => ZeroTap {
            step: s as i32,
            weight: w as f32,
        },
        None => ZeroTap {
            step: 0,
            weight: 0.0,
        },
    };
    Ok(GpuJob {
        xmajor: j.xmajor as u32,
        look: j.look as i32,
        step: j.step as i32,
        dirs: if j.planes[1].is_some() { 2 } else { 1 },
        t: j.t as f32,
        m_lo: j.m_lo as i32,
        m_hi: j.m_hi as i32,
        pc: ((j.rp.0 + j.rp.1) / 2) as i32,
        rp0: j.rp.0 as i32,
        rp1: j.rp.1 as i32,
        rq0: j.rq.0 as i32,
        rq1: j.rq.1 as i32,
        du: j.duv.0 as f32,
        dv: j.duv.1 as f32,
        adp: j.adp as f32,
        nsteps0: j.steps[0].len() as u32,
        nsteps1: j.steps[1].len() as u32,
        _pad0: 0,
        zero: [
            [zt(j.zero[0][0]), zt(j.zero[0][1])],
            [zt(j.zero[1][0]), zt(j.zero[1][1])],
        ],
    })
}
