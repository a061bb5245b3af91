/*!
Tiles made in the background: [`Loader`] runs threads that each take the most wanted tile
from a shared list, make it ([`TileMaker::make`]: read, mesh, context raster and min/max
pyramid, upload) and send it back. The frame loop ([`crate::scene::Scene`] when it streams)
replaces the list every frame with the tiles that frame lacks, coarsest first, so what the
camera has flown past is never made; it takes finished tiles without waiting
([`Loader::try_recv`]) or, for complete frames, waits ([`Loader::recv`]).

wgpu's device and queue are used from the loader threads: buffers and textures are made and
written there, and the writes reach the GPU with the frame loop's next submission, before the
draw that first uses the tile (a tile is handed over only when it is whole).
*/

use std::collections::{HashSet, VecDeque};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use anyhow::{anyhow, Result};
use penumbra::layout::TileId;

use crate::camera::SunPos;
use crate::maker::TileMaker;
use crate::render::GpuTile;
use crate::shadow::GpuMethod;

/// A tile a loader finished (or failed to make), with what it was made for.
pub struct Loaded {
    pub tile: TileId,
    pub result: Result<GpuTile>,
    /// Milliseconds the loader spent on it.
    pub ms: f64,
    /// The sun and method it was made for (the scene's may have moved on since).
    pub sun: SunPos,
    pub method: GpuMethod,
}

struct Queue {
    wanted: VecDeque<TileId>,
    busy: HashSet<TileId>,
    sun: SunPos,
    method: GpuMethod,
    stop: bool,
}

struct Shared {
    queue: Mutex<Queue>,
    cv: Condvar,
}

/// Background tile loaders (threads), stopped and joined when dropped.
pub struct Loader {
    shared: Arc<Shared>,
    done: Receiver<Loaded>,
    workers: Vec<JoinHandle<()>>,
}

impl Loader {
    /// Start `threads` loaders (at least one) making tiles with `maker`.
    pub fn new(maker: TileMaker, threads: usize, sun: SunPos, method: GpuMethod) -> Loader {
        let shared = Arc::new(Shared {
            queue: Mutex::new(Queue {
                wanted: VecDeque::new(),
                busy: HashSet::new(),
                sun,
                method,
                stop: false,
            }),
            cv: Condvar::new(),
        });
        let (tx, done) = mpsc::channel();
        let workers = (0..threads.max(1))
            .map(|k| {
                let (maker, shared, tx) = (maker.clone(), shared.clone(), tx.clone());
                std::thread::Builder::new()
                    .name(format!("tile-loader-{k}"))
                    .spawn(move || work(&maker, &shared, &tx))
                    .expect("a loader thread starts")
            })
            .collect();
        Loader {
            shared,
            done,
            workers,
        }
    }

    /// The tiles wanted now, most wanted first, and the sun and method to make them for; it
    /// replaces the earlier list (tiles being made carry on and are not asked again).
    pub fn want(&self, ids: &[TileId], sun: SunPos, method: &GpuMethod) {
        let mut guard = lock(&self.shared);
        let q = &mut *guard;
        q.wanted.clear();
        q.wanted
            .extend(ids.iter().copied().filter(|id| !q.busy.contains(id)));
        q.sun = sun;
        q.method = method.clone();
        drop(guard);
        self.shared.cv.notify_all();
    }

    /// A finished tile, if one is waiting.
    pub fn try_recv(&self) -> Option<Loaded> {
        self.done.try_recv().ok()
    }

    /// The next finished tile, waiting for it (an error if nothing is wanted or being made,
    /// which would wait for ever).
    pub fn recv(&self) -> Result<Loaded> {
        {
            // Under the lock: a loader sends its tile before it leaves `busy`, so with both
            // empty every finished tile is already in the channel.
            let q = lock(&self.shared);
            if let Ok(d) = self.done.try_recv() {
                return Ok(d);
            }
            if q.wanted.is_empty() && q.busy.is_empty() {
                return Err(anyhow!("waiting for a tile that no loader makes"));
            }
        }
        self.done
            .recv()
            .map_err(|_| anyhow!("the tile loaders stopped"))
    }
}

impl Drop for Loader {
    fn drop(&mut self) {
        lock(&self.shared).stop = true;
        self.shared.cv.notify_all();
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

fn lock(shared: &Shared) -> std::sync::MutexGuard<'_, Queue> {
    shared.queue.lock().unwrap_or_else(|e| e.into_inner())
}

/// A loader thread: take the most wanted tile, make it, send it; until stopped.
fn work(maker: &TileMaker, shared: &Shared, tx: &Sender<Loaded>) {
    loop {
        let (tile, sun, method) = {
            let mut q = lock(shared);
            loop {
                if q.stop {
                    return;
                }
                if let Some(id) = q.wanted.pop_front() {
                    q.busy.insert(id);
                    break (id, q.sun, q.method.clone());
                }
                q = shared.cv.wait(q).unwrap_or_else(|e| e.into_inner());
            }
        };
        let t0 = Instant::now();
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            maker.make(tile, &sun, &method)
        }))
        .unwrap_or_else(|_| Err(anyhow!("the loader panicked making tile {tile}")));
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        // Sent before it stops counting as busy, so that no frame asks for it in between.
        let sent = tx.send(Loaded {
            tile,
            result,
            ms,
            sun,
            method,
        });
        lock(shared).busy.remove(&tile);
        if sent.is_err() {
            return;
        }
    }
}
