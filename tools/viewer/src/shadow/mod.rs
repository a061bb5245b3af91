//! The GPU twins of the CPU shadow methods of `penumbra::shadow` and the per-tile GPU data they
//! read.
//!
//! Every tile gets one `@group(1)` bind group ([`TileShadow::bind_group`]) with its sun and
//! method in a uniform, its context raster (the heights a ray-marching method searches, on the
//! face's extended gnomonic plane, as `penumbra::shadow::shadow_context` makes it), the raster's
//! cell min/max pyramid (`penumbra::shadow::trace::Extrema`, its levels side by side in one
//! texture) and, for `fourier`, the tile's Fourier horizon pyramid expanded into each texel's
//! coefficients. The WGSL
//! ([`Shadows::wgsl`]) declares these bindings and `fn shadow_lit(p: vec2<i32>) -> f32`: the
//! lit fraction of the sun's disc at raster texel `p` (0 or 1 for the hard `extrema`), negative
//! over no data. The shader follows the CPU methods step by step (docs/shadow-methods.md):
//!
//! - `dp-jung`: Jung et al.'s Algorithm 1 (the at most three texels of a 2×2 block under the
//!   ray at each level, runs fixed or `auto`), the exact near field and the exact search of the
//!   chosen cell; `dp` the same, then, where a texel a descent passed over could still beat what
//!   the runs found, one exact search of those runs' stretch (the CPU's answer, found without
//!   its stack);
//! - `uniform`: equal steps out to where the ray leaves the terrain volume;
//! - `extrema`: Timokhin & Mikhaylyuk's min/max traversal (without a stack: a texel named by
//!   its level and index, `sh_search`);
//! - `extrema-soft`: the same traversal finding the exact horizon slope within the disc's band,
//!   with DP's disc occlusion (the CPU's most accurate soft method);
//! - `fourier`: the pyramid's coefficients at the texel centre (bilinear, clamp-to-edge, as
//!   `Pyramid::coefficients_at`, expanded when the tile is loaded) and a disc model of `penumbra::fourier::sun`: `constant` (the default; the series once, at the
//!   sun's azimuth), `segment` (twice, at the disc's rims), `slices` (8 times) or `exact` (256
//!   strips with bisection, for validation), as `penumbra shadow --method horizon` does.
//!
//! [`TileShadow::cpu_lit`] gives the CPU's answer at the same texel, and [`evaluate`] runs
//! `shadow_lit` in a compute shader at chosen texels, for validation.

use std::sync::{Arc, Mutex, OnceLock};

use anyhow::{bail, Context as _};
use bytemuck::Zeroable as _;
use penumbra::fourier::sun::{self, Frame, Model, Sun};
use penumbra::fourier::Pyramid;
use penumbra::horizon::{Context, Rect};
use penumbra::layout::TileId;
use penumbra::shadow::trace::{Extrema, Method, Work, MAX_DP_RUNS, MAX_STEPS};
use penumbra::shadow::{HorizonSource, Runs, ShadowMethod, Tracer};
use penumbra::tileset::Store;
use rayon::prelude::*;
use wgpu::util::DeviceExt;

use crate::gpu::Gpu;

/// The WGSL of the shadow methods: the `@group(1)` bindings and `shadow_lit`.
const WGSL: &str = include_str!("shadow.wgsl");

/// Most pyramid levels the uniform describes (a raster up to 32768 texels a side).
const MAX_LEVELS: usize = 16;
/// Most Fourier coefficients the shader reads.
const MAX_COEFFICIENTS: usize = 32;
/// What stands for −∞ and for no data in the textures (WGSL need not support infinities).
const NEG: f32 = -1.0e30;

/// A shadow method the GPU evaluates.
#[derive(Clone, Debug, PartialEq)]
pub enum GpuMethod {
    /// DP over the maximum mipmap with the exact refinement of the texels Jung's descent passed
    /// over (soft; the CPU's `dp`).
    Dp {
        /// How the runs are concatenated.
        runs: Runs,
    },
    /// Jung et al.'s DP as published: one texel per level (soft; the CPU's `dp-jung`).
    DpJung {
        /// How the runs are concatenated.
        runs: Runs,
    },
    /// Uniform stepping (soft).
    Uniform {
        /// Number of steps.
        steps: u32,
    },
    /// Timokhin & Mikhaylyuk's min/max traversal (hard).
    Extrema,
    /// The min/max traversal finding the exact horizon within the disc's band (soft).
    ExtremaSoft,
    /// The tile's Fourier horizon pyramid with a disc model (soft).
    Fourier {
        /// How the disc meets the horizon (`constant` by default: O(K) per pixel).
        model: Model,
    },
}

impl GpuMethod {
    /// A short name for logs and reports (`dp auto`, `uniform 100`, `extrema`, `fourier`).
    pub fn label(&self) -> String {
        match self {
            GpuMethod::Dp { runs } => format!("dp {runs}"),
            GpuMethod::DpJung { runs } => format!("dp-jung {runs}"),
            GpuMethod::Uniform { steps } => format!("uniform {steps}"),
            GpuMethod::Extrema => "extrema".into(),
            GpuMethod::ExtremaSoft => "extrema-soft".into(),
            GpuMethod::Fourier { model } => format!("fourier {model}"),
        }
    }

    /// Whether the method answers 0 or 1 only.
    pub fn is_hard(&self) -> bool {
        matches!(self, GpuMethod::Extrema)
    }

    /// The CPU method it twins (`penumbra shadow --method …`).
    pub fn cpu(&self) -> ShadowMethod {
        match self {
            GpuMethod::Dp { runs } => ShadowMethod::Trace(Method::Dp {
                runs: runs.clone(),
                dda: false,
            }),
            GpuMethod::DpJung { runs } => ShadowMethod::Trace(Method::JungDp {
                runs: runs.clone(),
                dda: false,
            }),
            GpuMethod::Uniform { steps } => ShadowMethod::Trace(Method::Uniform {
                steps: *steps as usize,
            }),
            GpuMethod::Extrema => ShadowMethod::Trace(Method::Extrema),
            GpuMethod::ExtremaSoft => ShadowMethod::Trace(Method::ExtremaSoft),
            GpuMethod::Fourier { model } => ShadowMethod::Horizon(HorizonSource::Fourier, *model),
        }
    }

    /// Whether the method searches the terrain (the context raster and its pyramid), rather
    /// than reading the Fourier pyramid.
    pub fn is_trace(&self) -> bool {
        !matches!(self, GpuMethod::Fourier { .. })
    }
}

/// `dp` (runs `auto`), `dp:5,5,5` (fixed runs), `dp-jung`, `dp-jung:5,5,5`, `uniform` (100
/// steps), `uniform:N`, `extrema`,
/// `extrema-soft`, `fourier` (the `constant` model), `fourier:MODEL` (`constant`, `segment`,
/// `slices`, `exact`).
impl std::str::FromStr for GpuMethod {
    type Err = String;
    fn from_str(s: &str) -> Result<GpuMethod, String> {
        let (name, arg) = match s.split_once(':') {
            Some((n, a)) => (n, Some(a)),
            None => (s, None),
        };
        match (name, arg) {
            ("dp", None) => Ok(GpuMethod::Dp { runs: Runs::Auto }),
            ("dp", Some(a)) => Ok(GpuMethod::Dp { runs: a.parse()? }),
            ("dp-jung", None) => Ok(GpuMethod::DpJung { runs: Runs::Auto }),
            ("dp-jung", Some(a)) => Ok(GpuMethod::DpJung { runs: a.parse()? }),
            ("uniform", None) => Ok(GpuMethod::Uniform { steps: 100 }),
            ("uniform", Some(a)) => match a.parse::<u32>() {
                Ok(n) if n >= 1 && n as usize <= MAX_STEPS => Ok(GpuMethod::Uniform { steps: n }),
                _ => Err(format!("'{a}': uniform steps must be 1..={MAX_STEPS}")),
            },
            ("extrema", None) => Ok(GpuMethod::Extrema),
            ("extrema-soft", None) => Ok(GpuMethod::ExtremaSoft),
            ("fourier", None) => Ok(GpuMethod::Fourier {
                model: Model::Constant,
            }),
            ("fourier", Some(a)) => Ok(GpuMethod::Fourier { model: a.parse()? }),
            _ => Err(format!(
                "unknown GPU shadow method '{s}' (dp, dp:5,5,5, dp-jung, dp-jung:5,5,5, uniform, uniform:N, extrema, \
                 extrema-soft, fourier, fourier:constant|segment|slices|exact)"
            )),
        }
    }
}

/// What [`TileShadow::cpu_lit`] computes.
#[derive(Clone, Debug, PartialEq)]
pub enum CpuTwin {
    /// The CPU version of the same method (for `fourier`, the horizon lookup of
    /// `penumbra shadow --method horizon`).
    Same(GpuMethod),
    /// The exact `reference` method.
    Reference,
}

/// The uniform of `@group(1)` (`ShadowParams` in the WGSL).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    face_n: [f32; 4],
    face_u: [f32; 4],
    face_v: [f32; 4],
    sun: [f32; 4],
    raster: [i32; 4],
    geo: [f32; 4],
    method: [i32; 4],
    rect: [i32; 4],
    runs: [[i32; 4]; 4],
    levels: [[i32; 4]; MAX_LEVELS],
}

/// Per device: the layout of the shadow bind group (`@group(1)`) and what tiles share.
pub struct Shadows {
    layout: wgpu::BindGroupLayout,
    /// 1×1 textures bound where a tile has no data of that kind (no pyramid, no Fourier).
    empty_rg32: wgpu::TextureView,
    empty_rgba32: wgpu::TextureView,
    max_texture: u32,
    eval: OnceLock<(wgpu::ComputePipeline, wgpu::BindGroupLayout)>,
}

/// One tile's GPU shadow data.
pub struct TileShadow {
    /// The `@group(1)` bind group.
    pub bind_group: wgpu::BindGroup,
    /// The context raster the methods search.
    pub ctx: Arc<Context>,
    /// The tile's interior in the raster.
    pub rect: Rect,
    /// The tile.
    pub tile: TileId,
    /// The method the data was prepared for (`set_sun` may switch among `dp`, `uniform` and
    /// `extrema`, which read the same data).
    pub method: GpuMethod,
    uniform: wgpu::Buffer,
    base: Params,
    /// The sun elevation (degrees) the raster's margin was made for.
    lowest_deg: f64,
    /// The pyramid, lent to a [`Tracer`] for the CPU twins.
    extrema: Mutex<Option<Extrema>>,
    hmax: f64,
    /// Lowest terrain of the tileset (m), and that or the raster's lowest if lower.
    tmin_tileset: f64,
    tmin_trace: f64,
    fourier: Option<Pyramid>,
    layout: penumbra::layout::Layout,
}

fn empty_view(gpu: &Gpu, format: wgpu::TextureFormat, bytes: &[u8]) -> wgpu::TextureView {
    gpu.texture_view("shadow empty", format, 1, 1, bytes)
}

fn texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT | wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

/// A `format` texture of `w × h` texels from `data` (row-major, channels interleaved).
fn float_texture(
    gpu: &Gpu,
    label: &str,
    format: wgpu::TextureFormat,
    w: usize,
    h: usize,
    data: &[f32],
) -> wgpu::TextureView {
    gpu.texture_view(
        label,
        format,
        w as u32,
        h as u32,
        bytemuck::cast_slice(data),
    )
}

fn finite_or_neg(v: f32) -> f32 {
    if v.is_finite() {
        v
    } else {
        NEG
    }
}

impl Shadows {
    /// The bind group layout and the shared resources for `gpu`.
    pub fn new(gpu: &Gpu) -> Shadows {
        let layout = gpu
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("shadow @group(1)"),
                entries: &[
                    wgpu::BindGroupLayoutEntry {
                        binding: 0,
                        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT
                            | wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: wgpu::BufferSize::new(
                                std::mem::size_of::<Params>() as u64
                            ),
                        },
                        count: None,
                    },
                    texture_entry(1),
                    texture_entry(2),
                    texture_entry(3),
                ],
            });
        let neg = NEG.to_le_bytes();
        Shadows {
            layout,
            empty_rg32: empty_view(gpu, wgpu::TextureFormat::Rg32Float, &[neg, neg].concat()),
            empty_rgba32: empty_view(gpu, wgpu::TextureFormat::Rgba32Float, &[0u8; 16]),
            max_texture: gpu.device.limits().max_texture_dimension_2d,
            eval: OnceLock::new(),
        }
    }

    /// The layout of `@group(1)` (the renderer's pipelines put it there).
    pub fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// WGSL declaring the `@group(1)` bindings and `fn shadow_lit(p: vec2<i32>) -> f32` (its
    /// own helpers are prefixed `sh_`/`SH_`).
    pub fn wgsl() -> &'static str {
        WGSL
    }

    /// The GPU data of `tile` for `method` and `sun`: its context raster as
    /// `penumbra::shadow::shadow_context` makes it for the sun's lowest elevation over the tile
    /// (capped at `max_margin_px`), the raster's min/max pyramid, and for `fourier` the tile's
    /// Fourier pyramid (an error naming what to run first when the tileset has none).
    pub fn prepare_tile(
        &self,
        gpu: &Gpu,
        store: &Store,
        tile: TileId,
        sun: &Sun,
        method: &GpuMethod,
        max_margin_px: u64,
    ) -> anyhow::Result<TileShadow> {
        let ts = store.manifest();
        if !ts.has_tile(tile) {
            bail!("{} has no tile {tile}", store.dir().display());
        }
        penumbra::shadow::check_products(store, &method.cpu(), tile.level)?;
        let lowest_deg = penumbra::shadow::lowest_sun_deg(store, tile, sun);
        let (ctx, rect, fourier) = if method.is_trace() {
            let (ctx, rect) =
                penumbra::shadow::shadow_context(store, tile, lowest_deg, max_margin_px)?;
            (ctx, rect, None)
        } else {
            let p = store.fourier(tile)?;
            if p.fully_lit {
                bail!(
                    "tile {tile} is stored as fully lit (no horizon kept): rebuild the pyramids \
                     without --min-sun-el to render it, or use a ray-marching method"
                );
            }
            if p.k > MAX_COEFFICIENTS {
                bail!(
                    "tile {tile}'s Fourier pyramid keeps {} coefficients; the GPU reads at most \
                     {MAX_COEFFICIENTS}: rebuild it with `penumbra fourier --coefficients 16`",
                    p.k
                );
            }
            // The lookup reads the tile's own pixels only.
            let (ctx, rect) = penumbra::horizon::context_for(store, tile, 0, None)?;
            (ctx, rect, Some(p))
        };
        let (w, h) = (ctx.width, ctx.height);
        let max_tex = self.max_texture as usize;
        if w > max_tex || h > max_tex {
            bail!(
                "tile {tile}'s context raster is {w}×{h} texels, beyond this GPU's {max_tex}: \
                 lower the margin (--max-margin)"
            );
        }
        let tmin_tileset = penumbra::horizon::terrain_range(ts).map_or(0.0, |t| t.0);
        let raster_min = ctx
            .heights
            .iter()
            .filter(|v| v.is_finite())
            .fold(f64::INFINITY, |m, &v| m.min(v as f64));
        let tmin_trace = tmin_tileset.min(raster_min);
        let hmax = ctx.max_height() as f64;

        let heights: Vec<f32> = ctx.heights.iter().map(|&v| finite_or_neg(v)).collect();
        let heights = float_texture(
            gpu,
            "shadow heights",
            wgpu::TextureFormat::R32Float,
            w,
            h,
            &heights,
        );

        let mut base = Params::zeroed();
        let (n, ua, va) = tile.face.axes();
        let v4 = |v: [f64; 3]| [v[0] as f32, v[1] as f32, v[2] as f32, 0.0];
        base.face_n = v4(n);
        base.face_u = v4(ua);
        base.face_v = v4(va);
        base.raster = [ctx.origin.0 as i32, ctx.origin.1 as i32, w as i32, h as i32];
        base.geo = [
            ctx.face_pixels as f32,
            ctx.radius_m as f32,
            0.0,
            finite_or_neg(hmax as f32),
        ];
        base.rect = [rect.x0 as i32, rect.y0 as i32, rect.w as i32, rect.h as i32];

        let mut extrema = None;
        let atlas = if method.is_trace() {
            let ex = Extrema::new(&ctx);
            if ex.len() > MAX_LEVELS {
                bail!("tile {tile}'s context raster has too many pyramid levels");
            }
            // Level 0 at the left, the others stacked to its right.
            let (w0, h0, _, _) = ex.level(0);
            let (w1, mut stack) = if ex.len() > 1 {
                (ex.level(1).0, 0)
            } else {
                (0, 0)
            };
            let mut offsets = vec![(0usize, 0usize)];
            for m in 1..ex.len() {
                offsets.push((w0, stack));
                stack += ex.level(m).1;
            }
            let (aw, ah) = (w0 + w1, h0.max(stack));
            if aw > max_tex || ah > max_tex {
                bail!(
                    "tile {tile}'s min/max pyramid needs a {aw}×{ah} texture, beyond this \
                     GPU's {max_tex}: lower the margin (--max-margin)"
                );
            }
            let mut data = vec![NEG; aw * ah * 2];
            for (m, &(ox, oy)) in offsets.iter().enumerate() {
                let (lw, lh, mx, mn) = ex.level(m);
                for y in 0..lh {
                    for x in 0..lw {
                        let o = ((oy + y) * aw + ox + x) * 2;
                        data[o] = finite_or_neg(mx[y * lw + x]);
                        data[o + 1] = finite_or_neg(mn[y * lw + x]);
                    }
                }
                base.levels[m] = [ox as i32, oy as i32, lw as i32, lh as i32];
            }
            base.method[2] = ex.len() as i32;
            extrema = Some(ex);
            float_texture(
                gpu,
                "shadow extrema",
                wgpu::TextureFormat::Rg32Float,
                aw,
                ah,
                &data,
            )
        } else {
            self.empty_rg32.clone()
        };
        let fourier_view = match &fourier {
            Some(p) => {
                // The pyramid expanded at load time into each texel's own coefficients (the
                // bilinear interpolation of every group at the texel centre, in f64 as the CPU
                // does, then f32): a fragment reads ⌈K/2⌉ texels instead of interpolating
                // 4 × ⌈K/2⌉, at K × 8 bytes per texel of GPU memory.
                let pairs = p.k.div_ceil(2);
                let (n, m) = (rect.w, rect.h);
                let aw = n * pairs;
                if aw > max_tex || m > max_tex {
                    bail!(
                        "tile {tile}'s Fourier coefficients ({aw}×{m} texels) do not fit a \
                         texture of this GPU (at most {max_tex}): use fewer coefficients"
                    );
                }
                let mut data = vec![0.0f32; aw * m * 4];
                data.par_chunks_mut(aw * 4)
                    .enumerate()
                    .for_each(|(j, row)| {
                        let mut coef = Vec::with_capacity(p.k);
                        for i in 0..n {
                            p.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, &mut coef);
                            for (c, v) in coef.iter().enumerate() {
                                row[(i * pairs) * 4 + 2 * c] = v[0] as f32;
                                row[(i * pairs) * 4 + 2 * c + 1] = v[1] as f32;
                            }
                        }
                    });
                base.method[3] = p.k as i32;
                float_texture(
                    gpu,
                    "shadow fourier",
                    wgpu::TextureFormat::Rgba32Float,
                    aw,
                    m,
                    &data,
                )
            }
            None => self.empty_rgba32.clone(),
        };

        let mut params = base;
        fill_sun(&mut params, sun, method, tmin_trace, tmin_tileset);
        let uniform = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("shadow params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            });
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shadow tile"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&heights),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&atlas),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&fourier_view),
                },
            ],
        });
        Ok(TileShadow {
            bind_group,
            ctx: Arc::new(ctx),
            rect,
            tile,
            method: method.clone(),
            uniform,
            base,
            lowest_deg,
            extrema: Mutex::new(extrema),
            hmax,
            tmin_tileset,
            tmin_trace,
            fourier,
            layout: ts.layout,
        })
    }
}

/// The sun's and the method's part of the uniform.
fn fill_sun(p: &mut Params, sun: &Sun, method: &GpuMethod, tmin_trace: f64, tmin_tileset: f64) {
    let d = sun.dir;
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let r = if sun.radius_deg > 0.0 {
        sun.radius_deg.min(60.0)
    } else {
        0.0
    };
    p.sun = [
        (d[0] / l) as f32,
        (d[1] / l) as f32,
        (d[2] / l) as f32,
        r as f32,
    ];
    p.geo[2] = if method.is_trace() {
        tmin_trace
    } else {
        tmin_tileset
    } as f32;
    p.runs = [[0; 4]; 4];
    let mut dp_runs = |runs: &Runs| match runs {
        Runs::Auto => 0,
        Runs::Fixed(v) => {
            for (k, &n) in v.iter().take(MAX_DP_RUNS).enumerate() {
                p.runs[k / 4][k % 4] = n as i32;
            }
            v.len().min(MAX_DP_RUNS) as i32
        }
    };
    let (id, arg) = match method {
        GpuMethod::Dp { runs } => (0, dp_runs(runs)),
        GpuMethod::DpJung { runs } => (5, dp_runs(runs)),
        GpuMethod::Uniform { steps } => (1, (*steps as usize).min(MAX_STEPS) as i32),
        GpuMethod::Extrema => (2, 0),
        GpuMethod::Fourier { model } => (
            3,
            match model {
                Model::Constant => 0,
                Model::Segment => 1,
                Model::Slices => 2,
                Model::Exact => 3,
            },
        ),
        GpuMethod::ExtremaSoft => (4, 0),
    };
    p.method[0] = id;
    p.method[1] = arg;
}

impl TileShadow {
    /// Whether this tile's data serves `method` (`dp`, `uniform`, `extrema` and `extrema-soft`
    /// read the same data; `fourier`, whatever its model, reads the Fourier pyramid).
    pub fn supports(&self, method: &GpuMethod) -> bool {
        method.is_trace() == self.method.is_trace()
    }

    /// Sets the sun and the method (a uniform write, no upload). A method the tile was not
    /// prepared for ([`TileShadow::supports`]) reads as no data (negative) until the tile is
    /// prepared for it.
    pub fn set_sun(&self, gpu: &Gpu, sun: &Sun, method: &GpuMethod) {
        let mut p = self.base;
        fill_sun(&mut p, sun, method, self.tmin_trace, self.tmin_tileset);
        if !self.supports(method) {
            p.method[0] = -1;
        }
        gpu.queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&p));
    }

    /// Whether the context raster reaches far enough for `sun` (its lowest elevation over the
    /// tile no lower than the one the raster was made for); otherwise prepare the tile again.
    pub fn margin_ok(&self, store: &Store, sun: &Sun) -> bool {
        !self.method.is_trace()
            || penumbra::shadow::lowest_sun_deg(store, self.tile, sun) >= self.lowest_deg
    }

    /// The CPU's lit fraction at raster texel (x, y) (NaN over no data): the same method (for
    /// `fourier` the horizon lookup of `penumbra shadow --method horizon`, only inside the
    /// tile) or the exact reference.
    pub fn cpu_lit(&self, x: usize, y: usize, sun: &Sun, method: CpuTwin) -> f64 {
        self.cpu_lit_many(&[[x as i32, y as i32]], sun, &method)[0]
    }

    /// [`TileShadow::cpu_lit`] at many texels, in parallel.
    pub fn cpu_lit_many(&self, texels: &[[i32; 2]], sun: &Sun, method: &CpuTwin) -> Vec<f64> {
        // A ray-marching method, or the Fourier lookup with its disc model.
        let trace = match method {
            CpuTwin::Reference => Ok(Method::Reference),
            CpuTwin::Same(m) => match m.cpu() {
                ShadowMethod::Trace(t) => Ok(t),
                ShadowMethod::Horizon(_, model) => Err(model),
                ShadowMethod::SMap => unreachable!("no GPU method's twin is the SMap"),
            },
        };
        match trace {
            Ok(m) => self.with_tracer(|tracer| {
                texels
                    .par_iter()
                    .map(|p| {
                        if !self.inside(p) {
                            return f64::NAN;
                        }
                        let mut work = Work::default();
                        tracer.lit(p[0] as usize, p[1] as usize, sun, &m, &mut work)
                    })
                    .collect()
            }),
            Err(model) => texels
                .par_iter()
                .map(|p| self.cpu_fourier(p[0] as i64, p[1] as i64, sun, model))
                .collect(),
        }
    }

    /// Whether the sun's centre is within ±3° of the terrain's own exact horizon in its azimuth
    /// at each texel (where shadows are decided: the penumbra metric of `penumbra-bench
    /// shadows`, by the same [`Tracer::penumbral`]). False over no data and outside the raster.
    pub fn cpu_penumbral_many(&self, texels: &[[i32; 2]], sun: &Sun) -> Vec<bool> {
        self.with_tracer(|tracer| {
            texels
                .par_iter()
                .map(|p| {
                    if !self.inside(p) {
                        return false;
                    }
                    tracer.penumbral(p[0] as usize, p[1] as usize, sun)
                })
                .collect()
        })
    }

    /// The exact reference's lit fraction and the penumbral band ([`Self::cpu_penumbral_many`])
    /// at `texels` of this tile's raster. A `fourier` tile's raster is the tile alone, whose
    /// horizon stops at the tile's edge; for it both come from a context raster made as the
    /// ray-marching methods' (`shadow_context` for the sun, within `max_margin_px`), at the
    /// same texels of the tile.
    pub fn cpu_reference_and_band(
        &self,
        store: &Store,
        texels: &[[i32; 2]],
        sun: &Sun,
        max_margin_px: u64,
    ) -> anyhow::Result<(Vec<f64>, Vec<bool>)> {
        if self.method.is_trace() {
            return Ok((
                self.cpu_lit_many(texels, sun, &CpuTwin::Reference),
                self.cpu_penumbral_many(texels, sun),
            ));
        }
        let lowest = penumbra::shadow::lowest_sun_deg(store, self.tile, sun);
        let (ctx, rect) =
            penumbra::shadow::shadow_context(store, self.tile, lowest, max_margin_px)?;
        let tracer = Tracer::new(&ctx, self.tmin_tileset);
        let (dx, dy) = (
            rect.x0 as i64 - self.rect.x0 as i64,
            rect.y0 as i64 - self.rect.y0 as i64,
        );
        let at = |p: &[i32; 2]| {
            let (x, y) = (p[0] as i64 + dx, p[1] as i64 + dy);
            (x >= 0 && y >= 0 && (x as usize) < ctx.width && (y as usize) < ctx.height)
                .then_some((x as usize, y as usize))
        };
        Ok(texels
            .par_iter()
            .map(|p| match at(p) {
                Some((x, y)) => {
                    let lit = tracer.lit(x, y, sun, &Method::Reference, &mut Work::default());
                    (lit, tracer.penumbral(x, y, sun))
                }
                None => (f64::NAN, false),
            })
            .unzip())
    }

    /// Whether raster texel `p` lies inside the context raster.
    fn inside(&self, p: &[i32; 2]) -> bool {
        p[0] >= 0
            && p[1] >= 0
            && (p[0] as usize) < self.ctx.width
            && (p[1] as usize) < self.ctx.height
    }

    /// Runs `f` with a [`Tracer`] over the tile's context raster, lending it the min/max
    /// pyramid kept between calls (made on first use).
    fn with_tracer<R>(&self, f: impl FnOnce(&Tracer) -> R) -> R {
        let mut slot = self.extrema.lock().unwrap_or_else(|e| e.into_inner());
        let pyramid = slot.take().unwrap_or_else(|| Extrema::new(&self.ctx));
        let tracer = Tracer {
            ctx: &self.ctx,
            pyramid,
            hmax: self.hmax,
            terrain_min_m: self.tmin_trace,
        };
        let out = f(&tracer);
        *slot = Some(tracer.pyramid);
        out
    }

    /// The Fourier lookup of `penumbra::shadow::tile_shadows` at raster texel (x, y), with the
    /// disc model `model`.
    fn cpu_fourier(&self, x: i64, y: i64, sun: &Sun, model: Model) -> f64 {
        let Some(pyr) = &self.fourier else {
            return f64::NAN;
        };
        let (i, j) = (x - self.rect.x0 as i64, y - self.rect.y0 as i64);
        if i < 0 || j < 0 || i >= self.rect.w as i64 || j >= self.rect.h as i64 {
            return f64::NAN;
        }
        let h0 = self.ctx.at(x, y) as f64;
        if !h0.is_finite() {
            return f64::NAN;
        }
        let lay = self.layout;
        let (s, t) = lay.pixel_st(self.tile, i, j);
        let (u, v) = (lay.projection.s_to_u(s), lay.projection.s_to_u(t));
        let frame = Frame::at(self.tile.face, u, v);
        let floor = penumbra::fourier::stage::floor_deg(self.ctx.radius_m, self.tmin_tileset, h0);
        let mut coef = Vec::new();
        pyr.coefficients_at(i as f64 + 0.5, j as f64 + 0.5, &mut coef);
        sun::lit_fraction(&frame, sun, model, &|phi| {
            penumbra::fourier::evaluate(&coef, phi).max(floor)
        })
    }
}

/// The compute harness of [`evaluate`]: `shadow_lit` at a list of texels.
const EVAL_WGSL: &str = r#"
@group(0) @binding(0) var<storage, read> eval_in: array<vec2<i32>>;
@group(0) @binding(1) var<storage, read_write> eval_out: array<f32>;

@compute @workgroup_size(64)
fn eval_main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x + id.y * 65535u * 64u;
    if i >= arrayLength(&eval_out) {
        return;
    }
    eval_out[i] = shadow_lit(eval_in[i]);
}
"#;

fn eval_pipeline<'a>(
    gpu: &Gpu,
    shadows: &'a Shadows,
) -> &'a (wgpu::ComputePipeline, wgpu::BindGroupLayout) {
    shadows.eval.get_or_init(|| {
        let src = format!("{}\n{}", Shadows::wgsl(), EVAL_WGSL);
        let module = gpu
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("shadow eval"),
                source: wgpu::ShaderSource::Wgsl(src.into()),
            });
        let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let io = gpu
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("shadow eval io"),
                entries: &[storage(0, true), storage(1, false)],
            });
        let layout = gpu
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("shadow eval"),
                bind_group_layouts: &[Some(&io), Some(&shadows.layout)],
                immediate_size: 0,
            });
        let pipeline = gpu
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("shadow eval"),
                layout: Some(&layout),
                module: &module,
                entry_point: Some("eval_main"),
                compilation_options: Default::default(),
                cache: None,
            });
        (pipeline, io)
    })
}

/// Evaluates `shadow_lit` at raster texels of one tile in a compute shader (the tile's sun and
/// method as last set).
pub fn evaluate(
    gpu: &Gpu,
    shadows: &Shadows,
    tile: &TileShadow,
    texels: &[[i32; 2]],
) -> anyhow::Result<Vec<f32>> {
    if texels.is_empty() {
        return Ok(Vec::new());
    }
    let (pipeline, io) = eval_pipeline(gpu, shadows);
    let dev = &gpu.device;
    let n = texels.len();
    let input = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("shadow eval in"),
        contents: bytemuck::cast_slice(texels),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let bytes = (n * 4) as u64;
    let output = dev.create_buffer(&wgpu::BufferDescriptor {
        label: Some("shadow eval out"),
        size: bytes,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let readback = dev.create_buffer(&wgpu::BufferDescriptor {
        label: Some("shadow eval readback"),
        size: bytes,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bind = dev.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("shadow eval io"),
        layout: io,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: input.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: output.as_entire_binding(),
            },
        ],
    });
    let mut enc = dev.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("shadow eval"),
    });
    {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("shadow eval"),
            timestamp_writes: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.set_bind_group(1, &tile.bind_group, &[]);
        let groups = n.div_ceil(64);
        let (gx, gy) = (groups.min(65535), groups.div_ceil(65535));
        pass.dispatch_workgroups(gx as u32, gy as u32, 1);
    }
    enc.copy_buffer_to_buffer(&output, 0, &readback, 0, bytes);
    let idx = gpu.queue.submit([enc.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    readback.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    dev.poll(wgpu::PollType::Wait {
        submission_index: Some(idx),
        timeout: None,
    })
    .context("waiting for the GPU")?;
    rx.recv()
        .context("the GPU's answer never came")?
        .context("mapping the GPU's answer")?;
    let out = {
        let view = readback
            .get_mapped_range(..)
            .map_err(|e| anyhow::anyhow!("reading the GPU's answer: {e:?}"))?;
        bytemuck::cast_slice::<u8, f32>(&view).to_vec()
    };
    readback.unmap();
    Ok(out)
}
