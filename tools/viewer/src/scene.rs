/*!
The tileset on the GPU: the tiles a frame draws, each with its mesh, normals, albedo and
shadow data, made on first use and kept while they are drawn.

A tile is read through the library's [`Store`] (heights and albedo, each checked against the
tileset's index, its identity and the manifest), meshed on the CPU ([`crate::mesh`]), and handed to the shadow module
([`Shadows::prepare_tile`]) for the selected method. Changing the sun updates every kept
tile's shadow uniforms; changing the method drops them (each method reads different data).

Tiles are made in the frame ([`Scene::tiles`] blocks until every tile of the frame is
ready) unless the scene streams ([`Scene::stream`]): then background loaders
([`crate::stream::Loader`]) make them, and a frame draws what is ready — a missing tile's
nearest ready ancestor stands in for it, or nothing is drawn there — and counts what it
lacked ([`FrameLoad`]).
*/

use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context as _, Result};
use penumbra::layout::TileId;
use penumbra::tileset::Store;

use crate::camera::SunPos;
use crate::gpu::Gpu;
use crate::lod::Quadtree;
use crate::maker::{make_tile, TileBinding, TileMaker};
use crate::render::{GpuTile, Renderer};
use crate::shadow::{GpuMethod, Shadows};
use crate::stream::{Loaded, Loader};

/// Tiles kept beyond those of the current frame (the least recently drawn go first).
pub const SPARE_TILES: usize = 64;

/// The tileset, what is on the GPU, and the sun and method the kept tiles were made for.
pub struct Scene {
    /// Shared with the tile loaders when tiles stream.
    pub store: Arc<Store>,
    pub quadtree: Quadtree,
    tiles: HashMap<TileId, GpuTile>,
    method: GpuMethod,
    sun: SunPos,
    /// The most context pixels the shadow module may gather around a tile.
    pub max_margin_px: u64,
    frame: u64,
    /// Seconds spent preparing tiles (reading, meshing, shadow data), all frames together
    /// (in the frame loop; streamed tiles count in [`Scene::loads`] instead).
    pub prepare_s: f64,
    /// The background loaders, when tiles stream, and whether a frame waits for its tiles.
    loader: Option<Loader>,
    wait_tiles: bool,
    /// What the last frame lacked and what arrived for it (streaming only).
    pub last_load: FrameLoad,
    /// Milliseconds each streamed tile took on its loader, in order of arrival.
    pub loads: Vec<f64>,
}

/// What a streamed frame chose, drew and lacked.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FrameLoad {
    /// Tiles the frame chose.
    pub chosen: usize,
    /// Tiles drawn (ready chosen tiles and stand-ins).
    pub drawn: usize,
    /// Chosen tiles not ready when the frame was drawn.
    pub missing: usize,
    /// Ready ancestors drawn in place of missing tiles.
    pub stand_ins: usize,
    /// Tiles that arrived from the loaders while this frame was being prepared.
    pub arrived: usize,
    /// Milliseconds the frame waited for the loaders (`wait_tiles` only).
    pub wait_ms: f64,
}

impl Scene {
    pub fn new(store: Store, method: GpuMethod, sun: SunPos, max_margin_px: u64) -> Scene {
        let quadtree = crate::lod::quadtree(store.manifest());
        Scene {
            store: Arc::new(store),
            quadtree,
            tiles: HashMap::new(),
            method,
            sun,
            max_margin_px,
            frame: 0,
            prepare_s: 0.0,
            loader: None,
            wait_tiles: false,
            last_load: FrameLoad::default(),
            loads: Vec::new(),
        }
    }

    /// What a loader needs to make this scene's tiles on `gpu` for `renderer`.
    pub fn maker(&self, gpu: &Gpu, renderer: &Renderer, shadows: &Arc<Shadows>) -> TileMaker {
        TileMaker {
            gpu: gpu.clone(),
            binding: TileBinding::of(renderer),
            shadows: shadows.clone(),
            store: self.store.clone(),
            max_margin_px: self.max_margin_px,
        }
    }

    /// Stream tiles from now on: `loader` makes them in the background; a frame draws what is
    /// ready (with stand-ins), or with `wait_tiles` waits until its tiles are ready.
    pub fn stream(&mut self, loader: Loader, wait_tiles: bool) {
        self.loader = Some(loader);
        self.wait_tiles = wait_tiles;
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
        if self.loader.is_some() {
            return self.streamed(gpu, ids);
        }
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
        self.let_go(ids.len());
        Ok(ids.iter().map(|id| &self.tiles[id]).collect())
    }

    /// Let go of the least recently drawn tiles beyond `in_use` + [`SPARE_TILES`].
    fn let_go(&mut self, in_use: usize) {
        if self.tiles.len() > in_use + SPARE_TILES {
            let mut by_age: Vec<(u64, TileId)> =
                self.tiles.values().map(|t| (t.last_used, t.tile)).collect();
            by_age.sort();
            let drop = self.tiles.len() - in_use - SPARE_TILES;
            for (_, id) in by_age.into_iter().take(drop) {
                self.tiles.remove(&id);
            }
        }
    }

    /// Keep a tile a loader finished, made to serve the current sun and method: one made
    /// for another method's data or a higher sun (its context reaches too short) is dropped
    /// and asked for again by the next frame that needs it.
    fn arrived(&mut self, gpu: &Gpu, done: Loaded) -> Result<bool> {
        let mut t = done
            .result
            .with_context(|| format!("preparing tile {} in the background", done.tile))?;
        self.loads.push(done.ms);
        let s = self.sun.sun();
        if !t.shadow.supports(&self.method) || !t.shadow.margin_ok(&self.store, &s) {
            return Ok(false);
        }
        if done.sun != self.sun || done.method != self.method {
            t.shadow.set_sun(gpu, &s, &self.method);
        }
        t.last_used = self.frame;
        self.tiles.insert(t.tile, t);
        Ok(true)
    }

    /// [`Scene::tiles`] when tiles stream. The chosen tiles not kept are asked of the loaders
    /// (coarser levels first; what earlier frames asked and no longer need is forgotten);
    /// with `wait_tiles` the frame waits for them, otherwise each missing tile's nearest kept
    /// ancestor is drawn in its place (once, and instead of the ready tiles below it, which
    /// it covers), or nothing where no ancestor is kept.
    fn streamed(&mut self, gpu: &Gpu, ids: &[TileId]) -> Result<Vec<&GpuTile>> {
        let loader = self.loader.take().expect("streaming");
        let r = self.streamed_with(gpu, &loader, ids);
        self.loader = Some(loader);
        r?;
        let draw = self.draw_list(ids);
        // Chosen tiles covered by a stand-in count as used too: kept for the next frames.
        for id in ids.iter().chain(&draw) {
            if let Some(t) = self.tiles.get_mut(id) {
                t.last_used = self.frame;
            }
        }
        self.let_go(ids.len() + self.last_load.stand_ins);
        Ok(draw.iter().map(|id| &self.tiles[id]).collect())
    }

    fn streamed_with(&mut self, gpu: &Gpu, loader: &Loader, ids: &[TileId]) -> Result<()> {
        let mut load = FrameLoad {
            chosen: ids.len(),
            ..FrameLoad::default()
        };
        while let Some(done) = loader.try_recv() {
            load.arrived += self.arrived(gpu, done)? as usize;
        }
        let missing = |tiles: &HashMap<TileId, GpuTile>| -> Vec<TileId> {
            let mut m: Vec<TileId> = ids
                .iter()
                .copied()
                .filter(|id| !tiles.contains_key(id))
                .collect();
            m.sort_by_key(|id| id.level);
            m
        };
        let mut want = missing(&self.tiles);
        loader.want(&want, self.sun, &self.method);
        if self.wait_tiles && !want.is_empty() {
            let t0 = Instant::now();
            while !want.is_empty() {
                let done = loader.recv()?;
                load.arrived += self.arrived(gpu, done)? as usize;
                want = missing(&self.tiles);
                // Asked again: a tile dropped on arrival (the sun moved) is made anew.
                loader.want(&want, self.sun, &self.method);
            }
            load.wait_ms = t0.elapsed().as_secs_f64() * 1e3;
        }
        load.missing = want.len();
        self.last_load = load;
        Ok(())
    }

    /// The tiles to draw for the chosen `ids` ([`draw_list`] over the kept tiles), and the
    /// frame's counts of drawn tiles and stand-ins.
    fn draw_list(&mut self, ids: &[TileId]) -> Vec<TileId> {
        let (draw, stand_ins) = draw_list(ids, |id| self.tiles.contains_key(&id));
        self.last_load.stand_ins = stand_ins;
        self.last_load.drawn = draw.len();
        draw
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
        let mut t = make_tile(
            gpu,
            &TileBinding::of(renderer),
            shadows,
            &self.store,
            self.max_margin_px,
            id,
            &self.sun,
            &self.method,
        )?;
        t.last_used = self.frame;
        Ok(t)
    }
}

/// What a streamed frame draws for its chosen tiles `ids` when only those `ready` are on the
/// GPU: each missing tile's nearest ready ancestor stands in for it; a stand-in under another
/// stand-in is left out (the outer one covers it), and so are the ready chosen tiles under a
/// stand-in (drawing both would put two surfaces in one place). The ready chosen tiles, then
/// the stand-ins (sorted), and how many stand-ins.
pub fn draw_list(ids: &[TileId], ready: impl Fn(TileId) -> bool) -> (Vec<TileId>, usize) {
    let ancestors = |id: TileId| std::iter::successors(id.parent(), |p| p.parent());
    let stand: BTreeSet<TileId> = ids
        .iter()
        .filter(|id| !ready(**id))
        .filter_map(|id| ancestors(*id).find(|p| ready(*p)))
        .collect();
    let under = |id: TileId| ancestors(id).any(|p| stand.contains(&p));
    let outer: Vec<TileId> = stand.iter().copied().filter(|s| !under(*s)).collect();
    let mut draw: Vec<TileId> = ids
        .iter()
        .copied()
        .filter(|id| ready(*id) && !under(*id))
        .collect();
    draw.extend(outer.iter().copied());
    (draw, outer.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use penumbra::cube::Face;

    fn t(level: u8, x: u32, y: u32) -> TileId {
        TileId {
            level,
            face: Face::Nz,
            x,
            y,
        }
    }

    #[test]
    fn missing_tiles_are_drawn_by_their_nearest_ready_ancestor() {
        // Chosen: the four children of L2 (0,0) and one grandchild of L2 (1,0).
        let ids = [t(3, 0, 0), t(3, 1, 0), t(3, 0, 1), t(3, 1, 1), t(4, 4, 0)];
        // Everything ready: drawn as chosen, no stand-in.
        assert_eq!(draw_list(&ids, |_| true), (ids.to_vec(), 0));
        // Two children missing, their parent ready: the parent alone covers all four.
        let ready = [t(3, 0, 0), t(3, 1, 1), t(2, 0, 0), t(4, 4, 0), t(1, 0, 0)];
        let (draw, n) = draw_list(&ids, |id| ready.contains(&id));
        assert_eq!((draw, n), (vec![t(4, 4, 0), t(2, 0, 0)], 1));
        // The grandchild missing too: its nearest ready ancestor is L1 (0,0), which covers
        // L2 (0,0) as well, so L1 alone is drawn.
        let ready = [t(3, 0, 0), t(2, 0, 0), t(1, 0, 0)];
        let (draw, n) = draw_list(&ids, |id| ready.contains(&id));
        assert_eq!((draw, n), (vec![t(1, 0, 0)], 1));
        // Nothing ready above a missing tile: a gap there, the rest drawn.
        let ready = [t(3, 0, 0)];
        let (draw, n) = draw_list(&ids, |id| ready.contains(&id));
        assert_eq!((draw, n), (vec![t(3, 0, 0)], 0));
    }
}
