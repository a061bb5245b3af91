//! Several DEMs as one surface, per sample (issue 35): the highest-priority source with data
//! wins, blended into the sources below it over a feathered zone of `feather_px` of its own
//! pixels, measured inward from the edge of its data — its raster's border and the voids it
//! leaves unfilled. The weight is a smoothstep of distance / feather: 1 from `feather_px` inward
//! (exactly that source's value), 0 at the edge (exactly the value below), so the surface has
//! no cliff where a fine source ends. Pure: the tiler hands each source's samples of one row
//! and their source positions; this composes them.

use std::collections::HashMap;

use crate::dem::{mask, Dem};

/// One source of a mosaic as the tiler samples it.
pub(crate) struct Layer<'a> {
    pub dem: &'a Dem,
    pub feather_px: f64,
    /// Added to this source's heights to refer them to the primary source's datum (0 for the
    /// primary; the primary's own shift to the body's sphere is applied afterwards, as for one
    /// source).
    pub shift: f64,
    /// Distance (pixels, centre to centre) from each measured pixel within `feather_px + 1` of
    /// an unfilled void to the nearest one, keyed by `row · width + col`; voids hold 0.
    /// `None` when the source leaves no void unfilled or is the lowest (nothing to blend into).
    voids: Option<HashMap<u64, f32>>,
    w: f64,
    h: f64,
    wrap: (bool, bool),
}

impl<'a> Layer<'a> {
    /// A layer for `dem`; `lowest` skips the void distances (the lowest source blends into
    /// nothing).
    pub fn new(dem: &'a Dem, feather_px: f64, shift: f64, lowest: bool) -> Layer<'a> {
        let voids = (!lowest && feather_px > 0.0 && dem.void_counts().1 > 0)
            .then(|| void_distances(dem, feather_px));
        Layer {
            dem,
            feather_px,
            shift,
            voids,
            w: dem.width() as f64,
            h: dem.height() as f64,
            wrap: dem.is_global(),
        }
    }

    /// Weight of this source at source position (col, row) where it has data: smoothstep of the
    /// distance to the edge of its data over the feather, 1 beyond it.
    #[inline]
    pub fn weight(&self, col: f64, row: f64) -> f64 {
        if self.feather_px <= 0.0 {
            return 1.0;
        }
        let mut d = f64::INFINITY;
        if !self.wrap.0 {
            d = d.min(col + 0.5).min(self.w - 0.5 - col);
        }
        if !self.wrap.1 {
            d = d.min(row + 0.5).min(self.h - 0.5 - row);
        }
        if let Some(v) = &self.voids {
            d = d.min(self.void_distance(v, col, row));
        }
        smoothstep(d / self.feather_px)
    }

    /// The void distance field at (col, row), bilinear between pixel centres (pixels farther
    /// than the feather from every void count as `feather_px + 1`).
    fn void_distance(&self, v: &HashMap<u64, f32>, col: f64, row: f64) -> f64 {
        let far = self.feather_px + 1.0;
        let (c0, r0) = (col.floor(), row.floor());
        let (fc, fr) = (col - c0, row - r0);
        let (wi, hi) = (self.w as i64, self.h as i64);
        let at = |c: i64, r: i64| -> f64 {
            let (c, r) = (c.clamp(0, wi - 1), r.clamp(0, hi - 1));
            v.get(&((r * wi + c) as u64)).map_or(far, |&d| d as f64)
        };
        let (c0, r0) = (c0 as i64, r0 as i64);
        let top = at(c0, r0) * (1.0 - fc) + at(c0 + 1, r0) * fc;
        let bottom = at(c0, r0 + 1) * (1.0 - fc) + at(c0 + 1, r0 + 1) * fc;
        top * (1.0 - fr) + bottom * fr
    }
}

/// 3t² − 2t³ of t clamped to 0..1: 0 and 1 with zero slope at both ends.
#[inline]
pub(crate) fn smoothstep(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Distances from measured pixels near the voids `dem` leaves unfilled to the nearest of them
/// (see [`Layer`]): from every void with a pixel of data among its 8 neighbours (the nearest
/// void to a pixel of data is always one of those), the pixels within `feather_px + 1`.
fn void_distances(dem: &Dem, feather_px: f64) -> HashMap<u64, f32> {
    let (w, h) = (dem.width() as i64, dem.height() as i64);
    let void = |c: i64, r: i64| dem.value(c as usize, r as usize).0.is_nan();
    let reach = feather_px.ceil() as i64 + 1;
    let mut out: HashMap<u64, f32> = HashMap::new();
    for r in 0..h {
        for c in 0..w {
            if !void(c, r) {
                continue;
            }
            out.insert((r * w + c) as u64, 0.0);
            let edge = (-1..=1).any(|dr: i64| {
                (-1..=1).any(|dc: i64| {
                    let (cc, rr) = (c + dc, r + dr);
                    cc >= 0 && rr >= 0 && cc < w && rr < h && !void(cc, rr)
                })
            });
            if !edge {
                continue;
            }
            for rr in (r - reach).max(0)..=(r + reach).min(h - 1) {
                for cc in (c - reach).max(0)..=(c + reach).min(w - 1) {
                    let d = (((cc - c) * (cc - c) + (rr - r) * (rr - r)) as f64).sqrt() as f32;
                    if d as f64 > feather_px + 1.0 {
                        continue;
                    }
                    let e = out.entry((rr * w + cc) as u64).or_insert(f32::INFINITY);
                    *e = e.min(d);
                }
            }
        }
    }
    out
}

/// One row's samples of every layer sampled so far: height, mask and weight per pixel.
#[derive(Default)]
pub(crate) struct LayerRow {
    pub height: Vec<f32>,
    pub mask: Vec<u8>,
    pub weight: Vec<f64>,
}

impl LayerRow {
    /// Room for `n` pixels.
    pub fn resize(&mut self, n: usize) {
        self.height.resize(n, 0.0);
        self.mask.resize(n, 0);
        self.weight.resize(n, 0.0);
    }

    /// Weights of `layer` at `coords` where it has data.
    pub fn weigh(&mut self, layer: &Layer, coords: &[(f64, f64)]) {
        for ((w, &m), &(c, r)) in self.weight.iter_mut().zip(&self.mask).zip(coords) {
            *w = if m == mask::NO_DATA {
                0.0
            } else {
                layer.weight(c, r)
            };
        }
    }
}

/// Whether pixel `p` of `row` is settled by its layer: data at full weight, so that no layer
/// below it matters.
#[inline]
pub(crate) fn settles(row: &LayerRow, p: usize) -> bool {
    row.mask[p] != mask::NO_DATA && row.weight[p] >= 1.0
}

/// Compose pixel `p` from `rows` (the layers sampled for it, highest priority first; the last
/// is where it settled or the lowest sampled): from the bottom up, each layer with data blended
/// over what is below by its weight. Heights as the layers give them plus each layer's shift;
/// NaN with [`mask::NO_DATA`] where no layer has data.
#[inline]
pub(crate) fn compose(layers: &[Layer], rows: &[LayerRow], p: usize) -> (f32, u8) {
    let mut acc: Option<(f64, u8)> = None;
    for (layer, row) in layers.iter().zip(rows).rev() {
        let m = row.mask[p];
        if m == mask::NO_DATA {
            continue;
        }
        let v = row.height[p] as f64 + layer.shift;
        let w = row.weight[p];
        acc = Some(match acc {
            None => (v, m),
            Some((a, am)) => {
                let mk = if w >= 1.0 {
                    m
                } else if w <= 0.0 {
                    am
                } else if m == mask::FILLED || am == mask::FILLED {
                    mask::FILLED
                } else {
                    mask::MEASURED
                };
                // w = 1: exactly this layer (0 · a adds +0); w = 0: exactly the one below.
                (w * v + (1.0 - w) * a, mk)
            }
        });
    }
    match acc {
        Some((v, m)) => (v as f32, m),
        None => (f32::NAN, mask::NO_DATA),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dem::{Crs, DemParts, GeoRef};

    fn dem(w: usize, h: usize, heights: Vec<f32>) -> Dem {
        let g = GeoRef {
            crs: Crs::Geographic,
            x0: 0.0,
            y0: 0.0,
            dx: 0.01,
            dy: 0.01,
        };
        Dem::new(DemParts::in_memory(g, w, h, heights, "test"), 0).unwrap()
    }

    /// The weight is 0 at the raster's edge, 1 from the feather inward, monotonic between, and
    /// 0 at an unfilled void's centre.
    #[test]
    fn weight_is_zero_at_the_edge_of_data_and_one_inside() {
        let (w, h) = (40, 30);
        let mut v = vec![1.0f32; w * h];
        v[15 * w + 20] = f32::NAN;
        let d = dem(w, h, v);
        let l = Layer::new(&d, 4.0, 0.0, false);
        assert_eq!(l.weight(-0.5, 10.0), 0.0);
        assert_eq!(l.weight(3.5, 10.0), 1.0);
        assert_eq!(l.weight(20.0, 15.0), 0.0);
        assert_eq!(l.weight(10.0, 10.0), 1.0);
        let mut last = -1.0;
        for k in 0..=40 {
            let c = -0.5 + k as f64 * 0.1;
            let wt = l.weight(c, 10.0);
            assert!(wt >= last, "weight falls at column {c}");
            last = wt;
        }
        // Around the void: rising away from it, 1 beyond the feather.
        assert!(l.weight(21.0, 15.0) > 0.0 && l.weight(21.0, 15.0) < l.weight(22.0, 15.0));
        assert_eq!(l.weight(26.0, 15.0), 1.0);
        // The lowest layer ignores voids; no feather, full weight.
        assert_eq!(Layer::new(&d, 4.0, 0.0, true).weight(20.0, 15.0), 1.0);
        assert_eq!(Layer::new(&d, 0.0, 0.0, false).weight(-0.5, 0.0), 1.0);
    }

    /// Composition: a settled layer's value exactly, a zero weight the value below exactly,
    /// a blend between, no data only where no layer has data, and the shift applied.
    #[test]
    fn compose_blends_from_the_bottom_up() {
        let d = dem(4, 4, vec![0.0; 16]);
        let layers = [
            Layer::new(&d, 4.0, 0.0, false),
            Layer::new(&d, 4.0, 10.0, true),
        ];
        let row = |h: f32, m: u8, w: f64| LayerRow {
            height: vec![h],
            mask: vec![m],
            weight: vec![w],
        };
        let c = |a: LayerRow, b: LayerRow| compose(&layers, &[a, b], 0);
        assert_eq!(c(row(5.0, 0, 1.0), row(7.0, 0, 1.0)), (5.0, mask::MEASURED));
        assert_eq!(c(row(5.0, 0, 0.0), row(7.0, 1, 1.0)), (17.0, mask::FILLED));
        assert_eq!(
            c(row(5.0, 0, 0.25), row(7.0, 0, 1.0)),
            (14.0, mask::MEASURED)
        );
        assert_eq!(
            c(row(f32::NAN, mask::NO_DATA, 0.0), row(7.0, 0, 1.0)),
            (17.0, 0)
        );
        let (h, m) = c(
            row(f32::NAN, mask::NO_DATA, 0.0),
            row(f32::NAN, mask::NO_DATA, 0.0),
        );
        assert!(h.is_nan() && m == mask::NO_DATA);
        // Nothing below: the layer's own value whatever its weight.
        assert_eq!(
            c(row(5.0, 0, 0.5), row(f32::NAN, mask::NO_DATA, 0.0)),
            (5.0, 0)
        );
    }
}
