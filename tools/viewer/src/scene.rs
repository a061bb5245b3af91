/*!
The tileset on the GPU: the tiles a frame draws, each with its mesh, normals, albedo and
shadow data, made on first use and kept while they are drawn.

A tile is read through the library's [`Store`] (heights and albedo, each checked against the
tileset's index, its identity and the manifest), meshed on the CPU ([`crate::mesh`]), and handed to the shadow module
([`Shadows::prepare_tile`]) for the selected method. Changing the sun updates every kept
tile's shadow uniforms; changing the method drops them (each method reads different data).
*/

use std::collections::HashMap;
use std::time::Instant;

use anyhow::{Context as _, Result};
use penumbra::layout::TileId;
use penumbra::tileset::Store;
use wgpu::util::DeviceExt;

use crate::camera::SunPos;
use crate::gpu::Gpu;
use crate::lod::Quadtree;
use crate::mesh;
use crate::render::{GpuTile, Renderer, TileUniform};
use crate::shadow::{GpuMethod, Shadows};

/// Tiles kept beyond those of the current frame (the least recently drawn go first).
pub const SPARE_TILES: usize = 64;

/// The tileset, what is on the GPU, and the sun and method the kept tiles were made for.
pub struct Scene {
    pub store: Store,
    pub quadtree: Quadtree,
    tiles: HashMap<TileId, GpuTile>,
    method: GpuMethod,
    sun: SunPos,
    /// The most context pixels the shadow module may gather around a tile.
    pub max_margin_px: u64,
    frame: u64,
    /// Seconds spent preparing tiles (reading, meshing, shadow data), all frames together.
    pub prepare_s: f64,
}

impl Scene {
    pub fn new(store: Store, method: GpuMethod, sun: SunPos, max_margin_px: u64) -> Scene {
        let quadtree = crate::lod::quadtree(store.manifest());
        Scene {
            store,
            quadtree,
            tiles: HashMap::new(),
            method,
            sun,
            max_margin_px,
            frame: 0,
            prepare_s: 0.0,
        }
    }

    pub fn method(&self) -> &GpuMethod {
        &self.method
    }

    pub fn sun(&self) -> SunPos {
        self.sun
    }

    /// Radius of the body (m).
    pub fn radius_m(&self) -> f64 {
        self.store.manifest().body.radius_m
    }

    /// Use another method: kept tiles whose data serves it switch at once (`dp`, `uniform`
    /// and `extrema` read the same data), the others are dropped and prepared again.
    pub fn set_method(&mut self, gpu: &Gpu, method: GpuMethod) {
        if method == self.method {
            return;
        }
        self.tiles.retain(|_, t| t.shadow.supports(&method));
        let s = self.sun.sun();
        for t in self.tiles.values() {
            t.shadow.set_sun(gpu, &s, &method);
        }
        self.method = method;
    }

    /// Move the sun: every kept tile's shadow follows; a tile whose context raster no longer
    /// reaches far enough for the new sun (a lower sun casts longer shadows) is dropped and
    /// prepared again when next drawn.
    pub fn set_sun(&mut self, gpu: &Gpu, sun: SunPos) {
        if sun == self.sun {
            return;
        }
        self.sun = sun;
        let s = sun.sun();
        let store = &self.store;
        self.tiles.retain(|_, t| t.shadow.margin_ok(store, &s));
        for t in self.tiles.values() {
            t.shadow.set_sun(gpu, &s, &self.method);
        }
    }

    /// The GPU tiles of `ids`, in that order, preparing those not kept yet; the least recently
    /// drawn tiles beyond [`SPARE_TILES`] are let go.
    pub fn tiles(
        &mut self,
        gpu: &Gpu,
        renderer: &Renderer,
        shadows: &Shadows,
        ids: &[TileId],
    ) -> Result<Vec<&GpuTile>> {
        self.frame += 1;
        for &id in ids {
            if !self.tiles.contains_key(&id) {
                let t0 = Instant::now();
                let t = self.prepare(gpu, renderer, shadows, id)?;
                self.prepare_s += t0.elapsed().as_secs_f64();
                self.tiles.insert(id, t);
            }
            if let Some(t) = self.tiles.get_mut(&id) {
                t.last_used = self.frame;
            }
        }
        if self.tiles.len() > ids.len() + SPARE_TILES {
            let mut by_age: Vec<(u64, TileId)> =
                self.tiles.values().map(|t| (t.last_used, t.tile)).collect();
            by_age.sort();
            let drop = self.tiles.len() - ids.len() - SPARE_TILES;
            for (_, id) in by_age.into_iter().take(drop) {
                self.tiles.remove(&id);
            }
        }
        Ok(ids.iter().map(|id| &self.tiles[id]).collect())
    }

    /// A kept tile.
    pub fn get(&self, id: TileId) -> Option<&GpuTile> {
        self.tiles.get(&id)
    }

    fn prepare(
        &self,
        gpu: &Gpu,
        renderer: &Renderer,
        shadows: &Shadows,
        id: TileId,
    ) -> Result<GpuTile> {
        let ts = self.store.manifest();
        let lay = ts.layout;
        let heights = self
            .store
            .height(id)?
            .with_context(|| format!("the tileset has no tile {id}"))?;
        let m = mesh::build(&lay, ts.body.radius_m, id, &heights);
        let shadow = shadows.prepare_tile(
            gpu,
            &self.store,
            id,
            &self.sun.sun(),
            &self.method,
            self.max_margin_px,
        )?;
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
        let albedo = self.albedo(id)?;
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
            layout: &renderer.tile_layout,
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
                        albedo_view.as_ref().unwrap_or(&renderer.white),
                    ),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::Sampler(&renderer.sampler),
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
            last_used: self.frame,
        })
    }

    /// The albedo tile of `id` as RGBA8 (stored size, halo included), when the tileset has
    /// albedo: read through the store, which checks it against the index, its identity and
    /// the manifest (bit depth, channels, size).
    fn albedo(&self, id: TileId) -> Result<Option<Vec<u8>>> {
        let Some(tile) = self.store.albedo(id)? else {
            return Ok(None);
        };
        let img = tile
            .to_image()
            .context("the store returned an albedo tile of the wrong length")?;
        Ok(Some(img.to_rgba8().into_raw()))
    }
}
