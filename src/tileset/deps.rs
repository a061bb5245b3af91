//! What a unit of a stage read, found while it runs: every product file it read (with the
//! blake3 its index recorded), every tile it asked for that the tileset does not hold, and the
//! values it computed from the tileset as a whole (a stage names and recomputes those). A
//! later run with the same run key reuses the unit's files when every one of its dependencies
//! still holds ([`crate::runner`]): an incremental bake redoes only the units whose inputs
//! changed, found from what they read rather than declared, so that a dependency a stage
//! does not declare cannot be missed.
//!
//! Recording is per unit: on the worker thread for a stage whose units run one per thread, or
//! tileset-wide for a stage that runs one unit at a time over the whole pool.

use std::cell::RefCell;
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use crate::layout::TileId;

/// One thing a unit's output depends on.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Dep {
    /// A file of `product` (path relative to the tileset) with the blake3 its index recorded;
    /// None: no such file was there.
    File {
        product: String,
        rel: String,
        blake3: Option<String>,
    },
    /// A tile asked for that the tileset's coverage does not hold.
    Absent { tile: TileId },
    /// A value computed from the tileset as a whole; the stage that recorded it recomputes it
    /// by its name ([`crate::runner::Stage::revalue`]).
    Value { name: String, value: String },
}

thread_local! {
    /// The dependencies of the unit running on this thread, when recorded per thread.
    static LOCAL: RefCell<Option<BTreeSet<Dep>>> = const { RefCell::new(None) };
}

/// A store's recorder of dependencies.
#[derive(Default)]
pub struct Recorder {
    /// Recording tileset-wide (one unit at a time).
    on: AtomicBool,
    set: Mutex<BTreeSet<Dep>>,
}

impl Recorder {
    /// Whether a dependency noted now would be kept.
    pub fn active(&self) -> bool {
        self.on.load(Ordering::Relaxed) || LOCAL.with(|l| l.borrow().is_some())
    }

    /// Keep `dep` for the unit running now (nothing when none records).
    pub fn note(&self, dep: Dep) {
        let local = LOCAL.with(|l| match l.borrow_mut().as_mut() {
            Some(s) => {
                s.insert(dep.clone());
                true
            }
            None => false,
        });
        if !local && self.on.load(Ordering::Relaxed) {
            self.set
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .insert(dep);
        }
    }

    /// Run `f` without recording what it reads (on this thread, and tileset-wide): for a
    /// read whose parts a unit records more finely itself.
    pub fn paused<T>(&self, f: impl FnOnce() -> T) -> T {
        let local = LOCAL.with(|l| l.borrow_mut().take());
        let on = self.on.swap(false, Ordering::Relaxed);
        let t = f();
        self.on.store(on, Ordering::Relaxed);
        LOCAL.with(|l| *l.borrow_mut() = local);
        t
    }

    /// Run `f`, a unit running on this thread alone, and return what it read.
    pub fn on_this_thread<T>(&self, f: impl FnOnce() -> T) -> (T, Vec<Dep>) {
        LOCAL.with(|l| *l.borrow_mut() = Some(BTreeSet::new()));
        let t = f();
        let deps = LOCAL.with(|l| l.borrow_mut().take()).unwrap_or_default();
        (t, deps.into_iter().collect())
    }

    /// Run `f`, a unit that may spread over the thread pool while no other unit runs, and
    /// return what it read.
    pub fn tileset_wide<T>(&self, f: impl FnOnce() -> T) -> (T, Vec<Dep>) {
        self.set.lock().unwrap_or_else(|e| e.into_inner()).clear();
        self.on.store(true, Ordering::Relaxed);
        let t = f();
        self.on.store(false, Ordering::Relaxed);
        let deps = std::mem::take(&mut *self.set.lock().unwrap_or_else(|e| e.into_inner()));
        (t, deps.into_iter().collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cube::Face;

    fn absent(x: u32) -> Dep {
        Dep::Absent {
            tile: TileId {
                level: 1,
                face: Face::ALL[0],
                x,
                y: 0,
            },
        }
    }

    /// What is noted inside a recording is returned once, sorted and without repeats; what is
    /// noted outside any recording is dropped.
    #[test]
    fn records_only_inside_a_unit() {
        let r = Recorder::default();
        r.note(absent(9));
        assert!(!r.active());
        let ((), d) = r.on_this_thread(|| {
            assert!(r.active());
            r.note(absent(2));
            r.note(absent(1));
            r.note(absent(2));
        });
        assert_eq!(d, vec![absent(1), absent(2)]);
        let ((), d) = r.tileset_wide(|| {
            use rayon::prelude::*;
            (0..8u32)
                .into_par_iter()
                .for_each(|x| r.note(absent(x % 3)));
        });
        assert_eq!(d, vec![absent(0), absent(1), absent(2)]);
        r.note(absent(7));
        let ((), d) = r.tileset_wide(|| ());
        assert!(d.is_empty());
    }
}
