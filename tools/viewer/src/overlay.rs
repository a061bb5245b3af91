/*!
The composite pass: the terrain pass's colour target onto the window's surface (or onto an
offscreen texture for `--screenshot`), with the status line — method, sun, frame time — in the
top-left corner ([`crate::font`]).
*/

use anyhow::{anyhow, Result};
use bytemuck::{Pod, Zeroable};

use crate::font;
use crate::gpu::Gpu;
use crate::render::{self, Targets};

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct OverlayUniform {
    size: [f32; 4],
}

/// The composite pipeline for one output format, and the current status line.
pub struct Composite {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    uniform: wgpu::Buffer,
    text: wgpu::Texture,
    text_size: (u32, u32),
    line: String,
    /// Font pixels per glyph pixel.
    pub scale: usize,
    format: wgpu::TextureFormat,
}

/// Widest status line (characters) the text texture holds.
const MAX_CHARS: usize = 160;

impl Composite {
    /// A composite pass that writes `format`.
    pub fn new(gpu: &Gpu, format: wgpu::TextureFormat, scale: usize) -> Result<Composite> {
        let device = &gpu.device;
        let tex = |binding, sample_type| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type,
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("composite"),
            entries: &[
                tex(0, wgpu::TextureSampleType::Float { filterable: false }),
                tex(1, wgpu::TextureSampleType::Float { filterable: false }),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("composite"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::include_wgsl!("shaders/composite.wgsl"));
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("composite"),
            layout: Some(&pl),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(format.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(anyhow!("the composite shader does not build: {e}"));
        }
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("overlay"),
            size: std::mem::size_of::<OverlayUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let scale = scale.max(1);
        let text_size = (
            ((MAX_CHARS + 1) * font::CELL_W * scale) as u32,
            ((font::CELL_H + 2) * scale) as u32,
        );
        let text = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("status line"),
            size: wgpu::Extent3d {
                width: text_size.0,
                height: text_size.1,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let c = Composite {
            pipeline,
            layout,
            uniform,
            text,
            text_size,
            line: String::new(),
            scale,
            format,
        };
        c.set_text_raw(gpu, "", false);
        Ok(c)
    }

    /// The format this pass writes.
    pub fn format(&self) -> wgpu::TextureFormat {
        self.format
    }

    /// Show `line` (cut to what fits) from the next pass on.
    pub fn set_text(&mut self, gpu: &Gpu, line: &str) {
        if line != self.line {
            self.line = line.to_string();
            self.set_text_raw(gpu, line, true);
        }
    }

    fn set_text_raw(&self, gpu: &Gpu, line: &str, show: bool) {
        let line: String = line.chars().take(MAX_CHARS).collect();
        let m = font::rasterise(&line, self.scale);
        let mut data = vec![0u8; (self.text_size.0 * self.text_size.1) as usize];
        for r in 0..m.height.min(self.text_size.1 as usize) {
            let w = m.width.min(self.text_size.0 as usize);
            let d = r * self.text_size.0 as usize;
            data[d..d + w].copy_from_slice(&m.data[r * m.width..r * m.width + w]);
        }
        gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &self.text,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            &data,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(self.text_size.0),
                rows_per_image: Some(self.text_size.1),
            },
            wgpu::Extent3d {
                width: self.text_size.0,
                height: self.text_size.1,
                depth_or_array_layers: 1,
            },
        );
        let u = OverlayUniform {
            size: [
                m.width as f32,
                m.height as f32,
                if show && !line.is_empty() { 1.0 } else { 0.0 },
                0.0,
            ],
        };
        gpu.queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&u));
    }

    /// Draw `targets`' colour with the status line into `view` (a texture of this pass's
    /// format and the targets' size) and submit.
    pub fn draw(&self, gpu: &Gpu, targets: &Targets, view: &wgpu::TextureView) {
        let text_view = self.text.create_view(&Default::default());
        let bg = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("composite"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(targets.colour_view()),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&text_view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: self.uniform.as_entire_binding(),
                },
            ],
        });
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("composite"),
            });
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("composite"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bg, &[]);
            pass.draw(0..3, 0..1);
        }
        gpu.queue.submit([enc.finish()]);
    }

    /// The composited frame as RGBA8 (this pass's format must be an RGBA8 one), for
    /// `--screenshot`.
    pub fn capture(&self, gpu: &Gpu, targets: &Targets) -> Result<Vec<u8>> {
        let tex = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("screenshot"),
            size: wgpu::Extent3d {
                width: targets.width,
                height: targets.height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: self.format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        self.draw(gpu, targets, &tex.create_view(&Default::default()));
        let mut px = render::read_texture(gpu, &tex, targets.width, targets.height, 4)?;
        if matches!(
            self.format,
            wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb
        ) {
            for p in px.chunks_exact_mut(4) {
                p.swap(0, 2);
            }
        }
        Ok(px)
    }
}
