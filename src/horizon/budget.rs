//! The sweep method's error budget (docs/horizons.md, "Error budget"): on a fixed sample of
//! pixels of every tile it computes, the horizon stage also runs the reference and tallies the
//! difference; the run's manifest records the RMS, mean, 99th percentile and largest error.
//! The tallies travel in the unit records (floats as bits) and are summed in unit order, so
//! the figures do not depend on the thread count or on a resumed run.

use serde::{Deserialize, Serialize};

use super::geometry::{Context, Rect};
use super::method::{horizons, Method};
use crate::format::horizon::HorizonError;
use crate::layout::TileId;

/// Pixels of each tile checked against the reference, at every azimuth.
pub(crate) const CHECK_PIXELS: usize = 16;

/// Histogram bins of |error| per decade.
const PER_DECADE: f64 = 16.0;
/// The lowest bin edge (degrees): everything below falls into bin 0.
const FLOOR_DEG: f64 = 1e-4;
/// Bins: one below the floor, 7 decades (to 1000°), one above.
const BINS: usize = 7 * 16 + 2;

/// One tile's (or a run's) differences against the reference.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub(crate) struct Tally {
    pixels: u64,
    samples: u64,
    /// Sum and sum of squares of the signed differences, and the largest |difference| and
    /// difference above the reference, as f64 bits.
    sum: u64,
    sum_sq: u64,
    max: u64,
    max_above: u64,
    /// (bin, count) of |difference|, bins with samples only.
    hist: Vec<(u16, u64)>,
}

fn bin(d: f64) -> usize {
    if d < FLOOR_DEG {
        0
    } else {
        (((d / FLOOR_DEG).log10() * PER_DECADE).floor() as usize + 1).min(BINS - 1)
    }
}

/// The upper edge of bin `b` (degrees).
fn edge(b: usize) -> f64 {
    FLOOR_DEG * 10f64.powf(b as f64 / PER_DECADE)
}

impl Tally {
    /// The differences between `got` (a tile's planes, `a` of `n`×`n`, as the stage holds
    /// them) and the reference at [`CHECK_PIXELS`] pixels of tile `id` chosen by a fixed
    /// hash of its name, the observers at `rect` of `ctx`.
    pub(crate) fn measure(ctx: &Context, rect: Rect, id: TileId, a: usize, got: &[f32]) -> Tally {
        let n = rect.w;
        let plane = rect.w * rect.h;
        let mut state = 0x9E37_79B9_7F4A_7C15u64
            ^ (u64::from(id.level) << 56)
            ^ ((id.face.index() as u64) << 48)
            ^ (u64::from(id.y) << 24)
            ^ u64::from(id.x);
        let mut t = Tally::default();
        let (mut sum, mut sum_sq, mut max, mut max_above) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        let mut hist = vec![0u64; BINS];
        for _ in 0..CHECK_PIXELS.min(plane) {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let o = (state % plane as u64) as usize;
            let (i, j) = (o % n, o / n);
            let one = Rect {
                x0: rect.x0 + i,
                y0: rect.y0 + j,
                w: 1,
                h: 1,
            };
            let want = horizons(ctx, one, a, Method::Reference);
            t.pixels += 1;
            for (k, w) in want.iter().enumerate() {
                let g = got[k * plane + o];
                if !(g.is_finite() && w.is_finite()) {
                    continue;
                }
                let d = f64::from(g) - f64::from(*w);
                t.samples += 1;
                sum += d;
                sum_sq += d * d;
                max = max.max(d.abs());
                max_above = max_above.max(d);
                hist[bin(d.abs())] += 1;
            }
        }
        t.sum = sum.to_bits();
        t.sum_sq = sum_sq.to_bits();
        t.max = max.to_bits();
        t.max_above = max_above.to_bits();
        t.hist = hist
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(b, c)| (b as u16, *c))
            .collect();
        t
    }

    /// `other` added (in the caller's order: sums of floats depend on it).
    pub(crate) fn add(&mut self, other: &Tally) {
        let f = f64::from_bits;
        self.pixels += other.pixels;
        self.samples += other.samples;
        self.sum = (f(self.sum) + f(other.sum)).to_bits();
        self.sum_sq = (f(self.sum_sq) + f(other.sum_sq)).to_bits();
        self.max = f(self.max).max(f(other.max)).to_bits();
        self.max_above = f(self.max_above).max(f(other.max_above)).to_bits();
        let mut hist = vec![0u64; BINS];
        for &(b, c) in self.hist.iter().chain(&other.hist) {
            if let Some(h) = hist.get_mut(b as usize) {
                *h += c;
            }
        }
        self.hist = hist
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(b, c)| (b as u16, *c))
            .collect();
    }

    /// The manifest's figures (None when nothing was compared).
    pub(crate) fn error(&self) -> Option<HorizonError> {
        if self.samples == 0 {
            return None;
        }
        let n = self.samples as f64;
        let f = f64::from_bits;
        // The bin holding the sample of rank ⌈0.99·n⌉, reported at its upper edge.
        let rank = (0.99 * n).ceil() as u64;
        let mut seen = 0;
        let mut p99 = f(self.max);
        for &(b, c) in &self.hist {
            seen += c;
            if seen >= rank {
                p99 = edge(b as usize).min(f(self.max));
                break;
            }
        }
        Some(HorizonError {
            against: Method::Reference.name().into(),
            pixels: self.pixels,
            samples: self.samples,
            rms_deg: (f(self.sum_sq) / n).sqrt(),
            mean_deg: f(self.sum) / n,
            p99_deg: p99,
            max_deg: f(self.max),
            max_above_deg: f(self.max_above),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bins' edges hold what they say, the percentile is an upper bound within one bin,
    /// and tallies add up to the tally of everything.
    #[test]
    fn percentile_is_a_close_upper_bound() {
        for d in [1e-5, 1e-4, 3.3e-3, 0.05, 0.3, 1.49, 12.0, 400.0] {
            let b = bin(d);
            assert!(
                d < edge(b) || b == BINS - 1,
                "{d} in bin {b} below {}",
                edge(b)
            );
            assert!(
                b == 0 || d >= edge(b - 1),
                "{d} in bin {b} above {}",
                edge(b - 1)
            );
        }
        let mut t = Tally::default();
        let mut hist = vec![0u64; BINS];
        let mut all: Vec<f64> = (0..1000).map(|i| 0.001 * (i as f64 + 0.5)).collect();
        for &d in &all {
            hist[bin(d)] += 1;
        }
        let part = |lo: usize, hi: usize| {
            let mut h = vec![0u64; BINS];
            for &d in &all[lo..hi] {
                h[bin(d)] += 1;
            }
            Tally {
                pixels: 1,
                samples: (hi - lo) as u64,
                sum: all[lo..hi].iter().sum::<f64>().to_bits(),
                sum_sq: all[lo..hi].iter().map(|d| d * d).sum::<f64>().to_bits(),
                max: all[hi - 1].to_bits(),
                max_above: all[hi - 1].to_bits(),
                hist: h
                    .iter()
                    .enumerate()
                    .filter(|(_, c)| **c > 0)
                    .map(|(b, c)| (b as u16, *c))
                    .collect(),
            }
        };
        t.add(&part(0, 400));
        t.add(&part(400, 1000));
        let e = t.error().unwrap();
        all.sort_by(f64::total_cmp);
        let p99 = all[989];
        assert!(e.p99_deg >= p99 && e.p99_deg <= p99 * 10f64.powf(1.0 / 16.0) * 1.0001);
        assert_eq!(e.samples, 1000);
        assert!((e.max_deg - 0.9995).abs() < 1e-12);
    }
}
