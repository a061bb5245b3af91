//! The fast method's far rings: terrain beyond the full-resolution context, seen through the
//! tileset's coarser levels (docs/horizons.md, "Far rings").
//!
//! A tile's full-resolution context reaches `fine_margin_px` pixels around it. Beyond that,
//! ring k holds level L−k's heights (2^k pixels of the tile's level per ring pixel) in a window
//! of the same number of ring pixels around the tile's footprint, with what a finer raster
//! already holds blanked out (no data). A far ring's terrain is at least its inner distance
//! away, where a ring pixel of 2^k pixels subtends no more than a full-resolution pixel at
//! 1/2^k of that distance: the rings give every pixel the same angular resolution as the
//! near context gives its edge, and hold time to the tile size and the ring count instead of
//! the square of the reach. Rings are read and used one at a time
//! ([`super::method::FarHorizons`]), so memory holds one of them whatever their count.
//!
//! Per azimuth each ring runs the same sweep as the full-resolution raster over its own
//! observers (the footprint's ring pixels, at the coarse level's heights); each tile pixel then
//! searches its own ray exactly on the ring's surface around the winner of the ring observer it
//! lies in, unless that winner, lifted by the observer's height difference over the ring's
//! inner distance, is hopelessly below what the pixel already has.

use super::geometry::{Azimuth, Context, PixelGeo, Ray, Rect};

/// One ring of coarser terrain around a tile.
#[derive(Clone, Debug)]
pub struct FarRing {
    /// Level L−k's heights around the tile's footprint on the tile's face plane; a pit
    /// ([`FarRing::PIT_M`]) where a finer raster holds the terrain.
    pub ctx: Context,
    /// The tile's footprint in `ctx`: the ring's observers.
    pub rect: Rect,
    /// The observers' heights (level L−k's, row-major over `rect`; `ctx` has none there).
    pub observers: Vec<f32>,
    /// Pixels of the tile's level per ring pixel (2^k).
    pub factor: u32,
    /// Least distance from the tile to the ring's terrain, in pixels of the tile's level.
    pub inner_px: f64,
    /// The lowest terrain in the ring (m): a point found below it lies on the slope down to a
    /// pit, not on terrain.
    pub lowest_m: f32,
}

impl FarRing {
    /// Height (m) of the pit that fills a ring where a finer raster holds the terrain.
    pub const PIT_M: f32 = -1.0e6;

    /// The ring of `factor` (2^k) tile pixels per ring pixel over `ctx`, level L−k's heights
    /// in a window whose origin is `ctx.origin` (ring pixels), around the tile's footprint
    /// `foot` (x0, y0, x1, y1, ring pixels, end exclusive), inside the previous (finer) window
    /// `prev` (pixels of level L−k+1): its observers taken, what `prev` holds and the no-data
    /// filled with the pit; None when no terrain is left.
    pub fn new(
        mut ctx: Context,
        foot: (i64, i64, i64, i64),
        prev: (i64, i64, i64, i64),
        factor: u32,
    ) -> Option<FarRing> {
        let win = (
            ctx.origin.0,
            ctx.origin.1,
            ctx.origin.0 + ctx.width as i64,
            ctx.origin.1 + ctx.height as i64,
        );
        let rect = Rect {
            x0: (foot.0 - win.0) as usize,
            y0: (foot.1 - win.1) as usize,
            w: (foot.2 - foot.0) as usize,
            h: (foot.3 - foot.1) as usize,
        };
        let mut observers = Vec::with_capacity(rect.w * rect.h);
        for j in 0..rect.h {
            let row = (rect.y0 + j) * ctx.width + rect.x0;
            observers.extend_from_slice(&ctx.heights[row..row + rect.w]);
        }
        // Blank what the previous (finer) window holds: the ring pixels all of whose 2×2
        // finer pixels lie in it, with a pit far below any terrain rather than no data (the
        // bilinear surface renormalises over no-data corners, which would carry the boundary
        // pixels' heights up to a ring pixel towards the tile: closer terrain, a horizon too
        // high; next to a pit the surface falls away instead).
        let inner = (
            prev.0.div_euclid(2) + prev.0.rem_euclid(2),
            prev.1.div_euclid(2) + prev.1.rem_euclid(2),
            prev.2.div_euclid(2),
            prev.3.div_euclid(2),
        );
        for gy in inner.1.max(win.1)..inner.3.min(win.3) {
            let row = (gy - win.1) as usize * ctx.width;
            let (a, b) = (inner.0.max(win.0), inner.2.min(win.2));
            if a < b {
                ctx.heights[row + (a - win.0) as usize..row + (b - win.0) as usize]
                    .fill(FarRing::PIT_M);
            }
        }
        // The same pit where the level has no data: renormalising there would carry the
        // data's edge outwards by a whole ring pixel (a horizon too high where the terrain
        // falls away towards the edge).
        for h in &mut ctx.heights {
            if h.is_nan() {
                *h = FarRing::PIT_M;
            }
        }
        // Least distance from the footprint to the ring's terrain (the gap between pixel
        // edges along the farther axis, a lower bound of the plane distance), in pixels of the
        // tile's level; None: the ring holds no terrain.
        let mut gap: Option<i64> = None;
        let mut lowest = f32::INFINITY;
        for (r, row) in ctx.heights.chunks_exact(ctx.width).enumerate() {
            let gy = win.1 + r as i64;
            let dy = (foot.1 - gy - 1).max(gy - foot.3).max(0);
            for (c, h) in row.iter().enumerate() {
                if *h > FarRing::PIT_M {
                    lowest = lowest.min(*h);
                    let gx = win.0 + c as i64;
                    let d = (foot.0 - gx - 1).max(gx - foot.2).max(0).max(dy);
                    gap = Some(gap.map_or(d, |g| g.min(d)));
                }
            }
        }
        let gap = gap?;
        Some(FarRing {
            ctx,
            rect,
            observers,
            factor,
            inner_px: ((gap * factor as i64) as f64).max(1.0),
            lowest_m: lowest,
        })
    }

    /// Where the pixels of `rect` in the full-resolution raster `fine` fall in this ring: per
    /// column (ring x, observer column) and per row (ring y, observer row).
    pub(super) fn map(&self, fine: &Context, rect: Rect) -> RingMap {
        let f = self.factor as i64;
        let ff = self.factor as f64;
        let axis = |origin: i64, start: usize, len: usize, ring_origin: i64, r0: usize| {
            (0..len)
                .map(|i| {
                    let g = origin + (start + i) as i64;
                    let pos = (g as f64 + 0.5) / ff - 0.5 - ring_origin as f64;
                    let cell = (g.div_euclid(f) - ring_origin) as usize - r0;
                    (pos, cell)
                })
                .collect::<Vec<_>>()
        };
        RingMap {
            cols: axis(
                fine.origin.0,
                rect.x0,
                rect.w,
                self.ctx.origin.0,
                self.rect.x0,
            ),
            rows: axis(
                fine.origin.1,
                rect.y0,
                rect.h,
                self.ctx.origin.1,
                self.rect.y0,
            ),
        }
    }
}

/// A full-resolution observer's place in a ring (see [`FarRing::map`]).
pub(super) struct RingMap {
    cols: Vec<(f64, usize)>,
    rows: Vec<(f64, usize)>,
}

/// Half-width (ring pixels) of the window searched exactly on a pixel's own ray around the
/// distance of its ring observer's winner: the pixel lies up to ½ ring pixel beside that
/// observer in each axis.
const FAR_WINDOW: f64 = 1.25;

/// How far (slope) below a pixel's best so far a ring observer's winner, lifted to the pixel
/// (see [`FarPass::raise`]), may lie and still be searched on the pixel's own ray.
const FAR_SKIP: f64 = 0.002;

/// One ring's sweep at one azimuth, ready for the tile's pixels.
pub(super) struct FarPass<'a> {
    pub(super) ring: &'a FarRing,
    pub(super) map: &'a RingMap,
    pub(super) az: Azimuth,
    /// The ring observers' best slopes and their distances (ring pixels).
    pub(super) acc: &'a [f64],
    pub(super) acc_s: &'a [f64],
}

impl FarPass<'_> {
    /// The best slope above `t` of this ring's terrain on the own ray of the pixel at column
    /// `i`, row `j` of the tile (height `h0`, geometry `g`, `ground` metres per pixel of the
    /// tile's level along the ray), or `t`.
    #[inline]
    pub(super) fn raise(
        &self,
        i: usize,
        j: usize,
        h0: f64,
        g: &PixelGeo,
        ground: f64,
        t: f64,
    ) -> f64 {
        let (xr, ci) = self.map.cols[i];
        let (yr, cj) = self.map.rows[j];
        let c = cj * self.ring.rect.w + ci;
        let best = self.acc[c];
        // −∞: the ring observer saw nothing; NaN: it has no data.
        if best.is_nan() || best == f64::NEG_INFINITY {
            return t;
        }
        // Seen from the pixel instead of the ring observer, far terrain rises by about the
        // height difference over its distance, and by what moving up to ¾ ring pixel along
        // the ray changes a slope at that distance (∂slope/∂d ≈ (|slope| + d/R)/d; d/R stays
        // below the reach's 0.2 rad even on the Moon).
        let inner = self.ring.inner_px;
        let lift = (self.ring.observers[c] as f64 - h0).max(0.0) / (inner * ground)
            + 0.75 * self.ring.factor as f64 / inner * (best.abs() + 0.2);
        if best + lift < t - FAR_SKIP {
            return t;
        }
        let ray = Ray::from_point(&self.ring.ctx, xr, yr, h0, g, &self.az);
        let (xc, yc) = (
            (self.ring.rect.x0 + ci) as f64,
            (self.ring.rect.y0 + cj) as f64,
        );
        let s = self.acc_s[c] + (xc - xr) * ray.cx + (yc - yr) * ray.cy;
        let from = (s - FAR_WINDOW).max(0.5);
        if from >= s + FAR_WINDOW {
            return t;
        }
        let (best, at) = ray.max_over(&self.ring.ctx, from, s + FAR_WINDOW, t);
        if best > t {
            let h = self.ring.ctx.bilinear64(xr + at * ray.cx, yr + at * ray.cy);
            if h >= self.ring.lowest_m as f64 {
                return best;
            }
        }
        t
    }
}
