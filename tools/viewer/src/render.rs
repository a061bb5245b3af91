/*!
The terrain pass: one pipeline that draws every chosen tile's mesh into three targets (the
shaded colour, the lit fraction (as f32 bits) and the id of the texel each pixel shows) over a reversed-Z
depth buffer, timed with GPU timestamp queries where the adapter has them; and the readback
of those targets. The window and the headless mode share all of it: the window only adds the
composite pass ([`crate::overlay`]) that puts the colour target on its surface.

Bind groups: @group(0) the frame (view-projection, sun), @group(1) the tile's shadow data
(the shadow module's layout), @group(2) the tile's uniform, normals and albedo.
*/

use std::time::{Duration, Instant};

use anyhow::{anyhow, Context as _, Result};
use bytemuck::{Pod, Zeroable};
use penumbra::cube::Vec3;
use penumbra::layout::TileId;
use wgpu::util::DeviceExt;

use crate::camera::sub;
use crate::gpu::Gpu;
use crate::mesh;
use crate::shadow::{Shadows, TileShadow};

/// The colour target's format: sRGB, so that shading is linear and the PNG is display-ready.
pub const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// The lit fraction of the texel each pixel shows, as the bits of an f32 (negative: no data in
/// the shadow raster). An integer target: OpenGL ES cannot render to R32Float without an
/// extension, every backend renders R32Uint.
pub const LIT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
/// Tile index + 1 (0: no surface) and the texel (i | j << 16).
pub const ID_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rg32Uint;
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Light that reaches shadowed terrain (fraction of full sun), so relief stays readable.
pub const AMBIENT: f32 = 0.015;

/// @group(0): the frame.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct FrameUniform {
    pub view_proj: [[f32; 4]; 4],
    pub sun_dir: [f32; 4],
    /// x: ambient, y: 1 to show shadows.
    pub params: [f32; 4],
}

/// @group(2) binding 0: one tile.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct TileUniform {
    /// Tile centre − eye (m).
    pub offset: [f32; 4],
    /// Tile index in the frame, n, shadow raster position of texel (0, 0).
    pub info: [i32; 4],
    /// 1 with albedo, halo, stored size.
    pub albedo: [f32; 4],
}

/// One tile ready to draw.
pub struct GpuTile {
    pub tile: TileId,
    /// Interior pixels per side.
    pub n: usize,
    /// Origin of the vertices, body frame (m).
    pub centre: Vec3,
    pub vertices: wgpu::Buffer,
    pub uniform: wgpu::Buffer,
    pub bind_group: wgpu::BindGroup,
    /// [`TileUniform::albedo`].
    pub albedo_params: [f32; 4],
    pub shadow: TileShadow,
    /// Frame counter when last drawn (the scene's, to let go of the least recently drawn).
    pub(crate) last_used: u64,
}

/// What a frame shows.
#[derive(Clone, Copy, Debug)]
pub struct FrameParams {
    pub eye: Vec3,
    pub view_proj: [[f32; 4]; 4],
    /// Unit direction to the sun's centre.
    pub sun_dir: Vec3,
    pub shadows: bool,
}

/// The render targets of one frame size.
pub struct Targets {
    pub width: u32,
    pub height: u32,
    pub colour: wgpu::Texture,
    pub lit: wgpu::Texture,
    pub id: wgpu::Texture,
    colour_view: wgpu::TextureView,
    lit_view: wgpu::TextureView,
    id_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
}

impl Targets {
    pub fn new(gpu: &Gpu, width: u32, height: u32) -> Targets {
        let make = |label, format, usage| {
            gpu.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let rw = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
        let colour = make(
            "colour",
            COLOUR_FORMAT,
            rw | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let lit = make("lit", LIT_FORMAT, rw);
        let id = make("id", ID_FORMAT, rw);
        let depth = make(
            "depth",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let v = |t: &wgpu::Texture| t.create_view(&wgpu::TextureViewDescriptor::default());
        Targets {
            width,
            height,
            colour_view: v(&colour),
            lit_view: v(&lit),
            id_view: v(&id),
            depth_view: v(&depth),
            colour,
            lit,
            id,
        }
    }

    /// A view of the colour target, for the composite pass.
    pub fn colour_view(&self) -> &wgpu::TextureView {
        &self.colour_view
    }
}

/// Timestamp queries around the terrain pass.
struct Timer {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    read: wgpu::Buffer,
    period_ns: f64,
}

/// How long a frame took.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameTime {
    /// The terrain pass on the GPU (timestamp queries), when the adapter has them.
    pub gpu_ms: Option<f64>,
    /// From encoding to the GPU's completion, on the CPU's clock.
    pub wall_ms: f64,
}

impl FrameTime {
    /// The GPU time when measured, else the wall time.
    pub fn best_ms(&self) -> f64 {
        self.gpu_ms.unwrap_or(self.wall_ms)
    }
}

/// The terrain pipeline and what every frame shares.
pub struct Renderer {
    pipeline: wgpu::RenderPipeline,
    frame_buf: wgpu::Buffer,
    frame_bg: wgpu::BindGroup,
    /// @group(2)'s layout, for the tiles' bind groups.
    pub tile_layout: wgpu::BindGroupLayout,
    /// Linear, clamped: the normals and the albedo.
    pub sampler: wgpu::Sampler,
    /// A 1×1 white texture standing in for albedo where the tileset has none.
    pub white: wgpu::TextureView,
    index_buf: wgpu::Buffer,
    index_count: u32,
    timer: Option<Timer>,
}

/// The terrain shader: ours, then the shadow module's (which declares @group(1) and
/// `shadow_lit`).
pub fn terrain_wgsl() -> String {
    format!(
        "{}\n// ---- shadow module ----\n{}",
        include_str!("shaders/terrain.wgsl"),
        Shadows::wgsl()
    )
}

impl Renderer {
    /// The pipeline for tiles of `tile_size` pixels.
    pub fn new(gpu: &Gpu, shadows: &Shadows, tile_size: usize) -> Result<Renderer> {
        let device = &gpu.device;
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let tex = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let tile_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("tile"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                tex(1),
                tex(2),
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("terrain"),
            bind_group_layouts: &[
                Some(&frame_layout),
                Some(shadows.layout()),
                Some(&tile_layout),
            ],
            immediate_size: 0,
        });
        let source = terrain_wgsl();
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("terrain.wgsl"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x2];
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("terrain"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: std::mem::size_of::<mesh::Vertex>() as u64,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &attrs,
                })],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[
                    Some(COLOUR_FORMAT.into()),
                    Some(LIT_FORMAT.into()),
                    Some(ID_FORMAT.into()),
                ],
            }),
            multiview_mask: None,
            cache: None,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(anyhow!("the terrain shader does not build: {e}"));
        }
        let frame_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame"),
            size: std::mem::size_of::<FrameUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let frame_bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame"),
            layout: &frame_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: frame_buf.as_entire_binding(),
            }],
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("linear clamp"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let white = device
            .create_texture_with_data(
                &gpu.queue,
                &wgpu::TextureDescriptor {
                    label: Some("no albedo"),
                    size: wgpu::Extent3d {
                        width: 1,
                        height: 1,
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format: wgpu::TextureFormat::Rgba8UnormSrgb,
                    usage: wgpu::TextureUsages::TEXTURE_BINDING,
                    view_formats: &[],
                },
                wgpu::util::TextureDataOrder::LayerMajor,
                &[255, 255, 255, 255],
            )
            .create_view(&Default::default());
        let indices = mesh::indices(mesh::grid_for(tile_size));
        let index_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("tile indices"),
            contents: bytemuck::cast_slice(&indices),
            usage: wgpu::BufferUsages::INDEX,
        });
        let timer = gpu.timestamps.then(|| Timer {
            set: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("terrain pass"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            }),
            resolve: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamps"),
                size: 16,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            read: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamps read"),
                size: 16,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            period_ns: gpu.queue.get_timestamp_period() as f64,
        });
        Ok(Renderer {
            pipeline,
            frame_buf,
            frame_bg,
            tile_layout,
            sampler,
            white,
            index_buf,
            index_count: indices.len() as u32,
            timer,
        })
    }

    /// Whether frame times come from GPU timestamps.
    pub fn has_timestamps(&self) -> bool {
        self.timer.is_some()
    }

    /// Draw `tiles` (tile index = position in the slice) into `targets`, wait for the GPU and
    /// return the frame's time.
    pub fn draw(
        &self,
        gpu: &Gpu,
        targets: &Targets,
        frame: &FrameParams,
        tiles: &[&GpuTile],
    ) -> Result<FrameTime> {
        let t0 = Instant::now();
        let s = frame.sun_dir;
        let fu = FrameUniform {
            view_proj: frame.view_proj,
            sun_dir: [s[0] as f32, s[1] as f32, s[2] as f32, 0.0],
            params: [AMBIENT, if frame.shadows { 1.0 } else { 0.0 }, 0.0, 0.0],
        };
        gpu.queue
            .write_buffer(&self.frame_buf, 0, bytemuck::bytes_of(&fu));
        for (k, t) in tiles.iter().enumerate() {
            let off = sub(t.centre, frame.eye);
            let tu = TileUniform {
                offset: [off[0] as f32, off[1] as f32, off[2] as f32, 0.0],
                info: [
                    k as i32,
                    t.n as i32,
                    t.shadow.rect.x0 as i32,
                    t.shadow.rect.y0 as i32,
                ],
                albedo: t.albedo_params,
            };
            gpu.queue
                .write_buffer(&t.uniform, 0, bytemuck::bytes_of(&tu));
        }
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("terrain"),
            });
        {
            let clear = |v: wgpu::Color| wgpu::Operations {
                load: wgpu::LoadOp::Clear(v),
                store: wgpu::StoreOp::Store,
            };
            let attach = |view, c| {
                Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: clear(c),
                })
            };
            let sky = wgpu::Color {
                r: 0.0,
                g: 0.0,
                b: 0.0,
                a: 1.0,
            };
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("terrain"),
                color_attachments: &[
                    attach(&targets.colour_view, sky),
                    attach(&targets.lit_view, wgpu::Color::TRANSPARENT),
                    attach(&targets.id_view, wgpu::Color::TRANSPARENT),
                ],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &targets.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: self
                    .timer
                    .as_ref()
                    .map(|t| wgpu::RenderPassTimestampWrites {
                        query_set: &t.set,
                        beginning_of_pass_write_index: Some(0),
                        end_of_pass_write_index: Some(1),
                    }),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.frame_bg, &[]);
            pass.set_index_buffer(self.index_buf.slice(..), wgpu::IndexFormat::Uint32);
            for t in tiles {
                pass.set_bind_group(1, &t.shadow.bind_group, &[]);
                pass.set_bind_group(2, &t.bind_group, &[]);
                pass.set_vertex_buffer(0, t.vertices.slice(..));
                pass.draw_indexed(0..self.index_count, 0, 0..1);
            }
        }
        if let Some(t) = &self.timer {
            enc.resolve_query_set(&t.set, 0..2, &t.resolve, 0);
            enc.copy_buffer_to_buffer(&t.resolve, 0, &t.read, 0, 16);
        }
        let idx = gpu.queue.submit([enc.finish()]);
        wait(gpu, Some(idx))?;
        let wall_ms = t0.elapsed().as_secs_f64() * 1e3;
        let gpu_ms = match &self.timer {
            Some(t) => {
                let bytes = map_read(gpu, &t.read, 16)?;
                let ts: [u64; 2] = bytemuck::pod_read_unaligned(&bytes);
                (ts[1] > ts[0]).then(|| (ts[1] - ts[0]) as f64 * t.period_ns / 1e6)
            }
            None => None,
        };
        Ok(FrameTime { gpu_ms, wall_ms })
    }
}

/// Wait until the GPU has finished `idx` (or everything), with a generous timeout so that a
/// hung driver is an error, not a hang.
pub fn wait(gpu: &Gpu, idx: Option<wgpu::SubmissionIndex>) -> Result<()> {
    gpu.device
        .poll(wgpu::PollType::Wait {
            submission_index: idx,
            timeout: Some(Duration::from_secs(600)),
        })
        .map(|_| ())
        .map_err(|e| anyhow!("waiting for the GPU: {e}"))
}

/// Map `buf` (MAP_READ) and copy its first `len` bytes out.
fn map_read(gpu: &Gpu, buf: &wgpu::Buffer, len: u64) -> Result<Vec<u8>> {
    let slice = buf.slice(0..len);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    wait(gpu, None)?;
    rx.recv()
        .context("the GPU dropped a buffer mapping")?
        .map_err(|e| anyhow!("mapping a readback buffer: {e}"))?;
    let out = slice
        .get_mapped_range()
        .map_err(|e| anyhow!("reading a mapped buffer: {e:?}"))?
        .to_vec();
    buf.unmap();
    Ok(out)
}

/// The pixels of a `width × height` texture of `bpp` bytes per pixel, rows packed.
pub fn read_texture(
    gpu: &Gpu,
    tex: &wgpu::Texture,
    width: u32,
    height: u32,
    bpp: u32,
) -> Result<Vec<u8>> {
    let row = width * bpp;
    let padded =
        row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let size = padded as u64 * height as u64;
    let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("readback"),
        });
    enc.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture: tex,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &buf,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded),
                rows_per_image: Some(height),
            },
        },
        wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
    );
    let idx = gpu.queue.submit([enc.finish()]);
    wait(gpu, Some(idx))?;
    let bytes = map_read(gpu, &buf, size)?;
    let mut out = Vec::with_capacity((row * height) as usize);
    for r in 0..height as usize {
        let s = r * padded as usize;
        out.extend_from_slice(&bytes[s..s + row as usize]);
    }
    Ok(out)
}

/// A frame's targets read back.
#[derive(Clone, Debug)]
pub struct Readback {
    pub width: u32,
    pub height: u32,
    /// RGBA8, sRGB-encoded, row-major.
    pub colour: Vec<u8>,
    /// Lit fraction per pixel (NaN: no surface, or no data in the shadow raster).
    pub lit: Vec<f32>,
    /// Per pixel the tile index and texel (i, j) it shows, or None.
    pub texel: Vec<Option<(u32, u32, u32)>>,
}

impl Readback {
    /// Read `targets` back.
    pub fn read(gpu: &Gpu, targets: &Targets) -> Result<Readback> {
        let (w, h) = (targets.width, targets.height);
        let colour = read_texture(gpu, &targets.colour, w, h, 4)?;
        let lit_raw = read_texture(gpu, &targets.lit, w, h, 4)?;
        let id_raw = read_texture(gpu, &targets.id, w, h, 8)?;
        let ids: Vec<[u32; 2]> = id_raw
            .chunks_exact(8)
            .map(bytemuck::pod_read_unaligned)
            .collect();
        let texel: Vec<Option<(u32, u32, u32)>> = ids
            .iter()
            .map(|&[t, ij]| (t > 0).then(|| (t - 1, ij & 0xffff, ij >> 16)))
            .collect();
        let lit = lit_raw
            .chunks_exact(4)
            .zip(&texel)
            .map(|(b, t)| {
                let v = f32::from_bits(bytemuck::pod_read_unaligned(b));
                if t.is_some() && v >= 0.0 {
                    v
                } else {
                    f32::NAN
                }
            })
            .collect();
        Ok(Readback {
            width: w,
            height: h,
            colour,
            lit,
            texel,
        })
    }
}
