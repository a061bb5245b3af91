//! A bounded cache of decoded height tiles shared by every thread of a stage: tiles are loaded
//! once while they are in use and the least recently used go when the budget is exceeded.
//! What is cached never changes results, only how often a tile is read from disk.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use crate::error::Result;
use crate::format::height::HeightTile;
use crate::layout::TileId;

type Entry = (Option<Arc<HeightTile>>, u64);

pub struct TileCache {
    budget: u64,
    tile_bytes: u64,
    clock: AtomicU64,
    map: Mutex<HashMap<TileId, Entry>>,
}

impl TileCache {
    /// A cache of at most `budget` bytes of tiles `stored_size` pixels wide (at least 16 tiles,
    /// so that a stage's working set of neighbours always fits).
    pub fn new(budget: u64, stored_size: usize) -> TileCache {
        let tile_bytes = (stored_size * stored_size * 5) as u64;
        TileCache {
            budget: budget.max(16 * tile_bytes),
            tile_bytes,
            clock: AtomicU64::new(0),
            map: Mutex::new(HashMap::new()),
        }
    }

    /// The cached value of `id`, or `load()`'s, which is then cached.
    pub fn get_or_load(
        &self,
        id: TileId,
        load: impl FnOnce() -> Result<Option<HeightTile>>,
    ) -> Result<Option<Arc<HeightTile>>> {
        let now = self.clock.fetch_add(1, Ordering::Relaxed);
        if let Some(e) = self.map.lock().unwrap().get_mut(&id) {
            e.1 = now;
            return Ok(e.0.clone());
        }
        let t = load()?.map(Arc::new);
        let mut map = self.map.lock().unwrap();
        map.insert(id, (t.clone(), now));
        let held = map.values().filter(|e| e.0.is_some()).count() as u64;
        if held * self.tile_bytes > self.budget {
            // Drop the least recently used quarter of the budget at once.
            let keep = (self.budget * 3 / 4 / self.tile_bytes) as usize;
            let mut ages: Vec<(u64, TileId)> = map.iter().map(|(k, e)| (e.1, *k)).collect();
            ages.sort_unstable();
            let drop = ages.len().saturating_sub(keep);
            for (_, k) in ages.into_iter().take(drop) {
                map.remove(&k);
            }
        }
        Ok(t)
    }

    /// The cache's clock: every lookup advances it, and [`TileCache::keep_since`] drops what
    /// was last used before a reading of it.
    pub fn now(&self) -> u64 {
        self.clock.load(Ordering::Relaxed)
    }

    /// Drop every tile last used before clock reading `since`: a stage that walks its tiles in
    /// order keeps its working set (what the last few tiles read) instead of everything up to
    /// the budget, so that its memory does not grow with the number of tiles.
    pub fn keep_since(&self, since: u64) {
        self.map.lock().unwrap().retain(|_, e| e.1 >= since);
    }

    /// Drop every tile last used at or after clock reading `since`: what a stage read since
    /// then and will not need again soon.
    pub fn drop_since(&self, since: u64) {
        self.map.lock().unwrap().retain(|_, e| e.1 < since);
    }

    /// Tiles held now.
    pub fn len(&self) -> usize {
        self.map.lock().unwrap().len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cube::Face;

    #[test]
    fn stays_within_its_budget() {
        let c = TileCache::new(0, 8);
        let tile = || HeightTile {
            size: 8,
            height: vec![0.0; 64],
            mask: vec![0; 64],
        };
        for x in 0..100 {
            let id = TileId {
                level: 3,
                face: Face::Px,
                x,
                y: 0,
            };
            c.get_or_load(id, || Ok(Some(tile()))).unwrap();
            assert!(c.len() <= 16, "{} tiles held", c.len());
        }
        // Only what was used since a clock reading is kept.
        let c2 = TileCache::new(1 << 30, 8);
        let id = |x| TileId {
            level: 3,
            face: crate::cube::Face::Px,
            x,
            y: 0,
        };
        for x in 0..4 {
            c2.get_or_load(id(x), || Ok(None)).unwrap();
        }
        let mark = c2.now();
        c2.get_or_load(id(1), || Ok(None)).unwrap();
        c2.get_or_load(id(9), || Ok(None)).unwrap();
        c2.keep_since(mark);
        assert_eq!(c2.len(), 2);
        // What was used since a reading goes, the rest stays.
        let mark = c2.now();
        c2.get_or_load(id(5), || Ok(None)).unwrap();
        c2.get_or_load(id(9), || Ok(None)).unwrap();
        c2.drop_since(mark);
        assert_eq!(c2.len(), 1);
        c2.get_or_load(id(1), || panic!("id 1 was dropped"))
            .unwrap();
        // A cached tile is not loaded again.
        let id = TileId {
            level: 3,
            face: Face::Px,
            x: 99,
            y: 0,
        };
        let t = c.get_or_load(id, || panic!("loaded twice")).unwrap();
        assert!(t.is_some());
    }
}
