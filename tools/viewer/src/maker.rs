/*!
Making one tile for the GPU, in the frame loop or on a loader thread ([`crate::stream`]): read
its heights (and albedo) through the library's [`Store`], mesh them ([`crate::mesh`]), make its
shadow data ([`Shadows::prepare_tile`]) and upload it all.
*/

use std::sync::Arc;

use anyhow::{Context as _, Result};
use penumbra::layout::TileId;
use penumbra::tileset::Store;
use wgpu::util::DeviceExt;

use crate::camera::SunPos;
use crate::gpu::Gpu;
use crate::mesh;
use crate::render::{GpuTile, Renderer, TileUniform};
use crate::shadow::{GpuMethod, Shadows};

/// What a tile's `@group(2)` bind group needs from the renderer: handles, cheap to clone.
#[derive(Clone)]
pub struct TileBinding {
    pub layout: wgpu::BindGroupLayout,
    pub white: wgpu::TextureView,
    pub sampler: wgpu::Sampler,
}

impl TileBinding {
    pub fn of(renderer: &Renderer) -> TileBinding {
        TileBinding {
            layout: renderer.tile_layout.clone(),
            white: renderer.white.clone(),
            sampler: renderer.sampler.clone(),
        }
    }
}

/// Everything a tile is made from, owned (shared handles): a loader thread holds one.
#[derive(Clone)]
pub struct TileMaker {
    pub gpu: Gpu,
    pub binding: TileBinding,
    pub shadows: Arc<Shadows>,
    pub store: Arc<Store>,
    pub max_margin_px: u64,
}

impl TileMaker {
    /// Make tile `id` for `sun` and `method` (any thread).
    pub fn make(&self, id: TileId, sun: &SunPos, method: &GpuMethod) -> Result<GpuTile> {
        make_tile(
            &self.gpu,
            &self.binding,
            &self.shadows,
            &self.store,
            self.max_margin_px,
            id,
            sun,
            method,
        )
    }
}

/// Read tile `id`, mesh it, make its shadow data for `sun` and `method`, and upload it all.
#[allow(clippy::too_many_arguments)]
pub fn make_tile(
    gpu: &Gpu,
    binding: &TileBinding,
    shadows: &Shadows,
    store: &Store,
    max_margin_px: u64,
    id: TileId,
    sun: &SunPos,
    method: &GpuMethod,
) -> Result<GpuTile> {
    let ts = store.manifest();
    let lay = ts.layout;
    let heights = store
        .height(id)?
        .with_context(|| format!("the tileset has no tile {id}"))?;
    let m = mesh::build(&lay, ts.body.radius_m, id, &heights);
    let shadow = shadows.prepare_tile(gpu, store, id, &sun.sun(), method, max_margin_px)?;
    let device = &gpu.device;
    let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("tile vertices"),
        contents: bytemuck::cast_slice(&m.vertices),
        usage: wgpu::BufferUsages::VERTEX,
    });
    let uniform = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("tile"),
        size: std::mem::size_of::<TileUniform>() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let half: Vec<u16> = m
        .normals
        .iter()
        .flatten()
        .map(|&v| half::f16::from_f32(v).to_bits())
        .collect();
    let side = m.n as u32 + 2;
    let normals = gpu.texture_view(
        "normals",
        wgpu::TextureFormat::Rgba16Float,
        side,
        side,
        bytemuck::cast_slice(&half),
    );
    let albedo = albedo(store, id)?;
    let stored = lay.stored_size();
    let (albedo_view, albedo_params) = match albedo {
        Some(rgba) => (
            Some(gpu.texture_view(
                "albedo",
                wgpu::TextureFormat::Rgba8UnormSrgb,
                stored as u32,
                stored as u32,
                &rgba,
            )),
            [1.0, lay.halo as f32, stored as f32, 0.0],
        ),
        None => (None, [0.0, lay.halo as f32, stored as f32, 0.0]),
    };
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("tile"),
        layout: &binding.layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: uniform.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: wgpu::BindingResource::TextureView(&normals),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(
                    albedo_view.as_ref().unwrap_or(&binding.white),
                ),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::Sampler(&binding.sampler),
            },
        ],
    });
    Ok(GpuTile {
        tile: id,
        n: m.n,
        centre: m.centre,
        vertices,
        uniform,
        bind_group,
        albedo_params,
        shadow,
        last_used: 0,
    })
}

/// The albedo tile of `id` as RGBA8 (stored size, halo included), when the tileset has
/// albedo: read through the store, which checks it against the index, its identity and
/// the manifest (bit depth, channels, size).
fn albedo(store: &Store, id: TileId) -> Result<Option<Vec<u8>>> {
    let Some(tile) = store.albedo(id)? else {
        return Ok(None);
    };
    let img = tile
        .to_image()
        .context("the store returned an albedo tile of the wrong length")?;
    Ok(Some(img.to_rgba8().into_raw()))
}
