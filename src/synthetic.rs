//! The embedded default scene: a deterministic synthetic terrain like the lunar south pole —
//! fractal relief plus a power-law population of craters with raised rims and a large
//! Shackleton-like crater near the pole — on the 1737.4 km Moon, south polar stereographic.
//! No file is read, so `penumbra bake` works on a fresh machine.

use rayon::prelude::*;
use serde::Serialize;

use crate::dem::{Crs, DemParts, GeoRef, Samples};

/// Parameters of the synthetic scene; the defaults are what `penumbra bake` uses.
#[derive(Clone, Debug, Serialize)]
pub struct SyntheticSpec {
    /// Pixels per side.
    pub size: usize,
    /// Ground pixel size at the pole (m).
    pub pixel_m: f64,
    pub seed: u64,
    /// Number of craters besides the big one.
    pub craters: usize,
}

impl Default for SyntheticSpec {
    fn default() -> Self {
        SyntheticSpec {
            size: 2048,
            pixel_m: 20.0,
            seed: 0x005e_ed0f_5a0d,
            craters: 400,
        }
    }
}

pub const MOON_RADIUS_M: f64 = 1_737_400.0;

fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

fn unit(state: &mut u64) -> f64 {
    (splitmix(state) >> 11) as f64 / (1u64 << 53) as f64
}

fn lattice(seed: u64, ix: i64, iy: i64) -> f64 {
    let mut s =
        seed ^ (ix as u64).wrapping_mul(0x9e37_79b9) ^ (iy as u64).wrapping_mul(0x85eb_ca6b) << 1;
    unit(&mut s) * 2.0 - 1.0
}

/// Smooth value noise in [−1, 1] with a quintic fade.
fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (u, v) = (fade(fx), fade(fy));
    let (ix, iy) = (x0 as i64, y0 as i64);
    let a = lattice(seed, ix, iy);
    let b = lattice(seed, ix + 1, iy);
    let c = lattice(seed, ix, iy + 1);
    let d = lattice(seed, ix + 1, iy + 1);
    (a + (b - a) * u) + ((c + (d - c) * u) - (a + (b - a) * u)) * v
}

struct Crater {
    x: f64,
    y: f64,
    r: f64,
    depth: f64,
    rim: f64,
}

impl Crater {
    /// Height change at distance `d` from the centre: a parabolic bowl inside, a rim that
    /// decays as (r/d)^3 outside (continuous at d = r).
    fn profile(&self, d: f64) -> f64 {
        let q = d / self.r;
        if q < 1.0 {
            self.rim + (self.depth + self.rim) * (q * q - 1.0)
        } else {
            self.rim / (q * q * q)
        }
    }
}

/// Generate the scene as DEM parts (heights in metres above the 1737.4 km sphere).
pub fn generate(spec: &SyntheticSpec) -> DemParts {
    let n = spec.size;
    let px = spec.pixel_m;
    let extent = n as f64 * px;
    let mut st = spec.seed;
    let mut craters = vec![Crater {
        // Shackleton-like: 15 km across, 3 km deep, just off the pole.
        x: 0.06 * extent,
        y: -0.04 * extent,
        r: 7_500.0_f64.min(0.18 * extent),
        depth: 3_000.0_f64.min(0.1 * extent),
        rim: 250.0,
    }];
    for _ in 0..spec.craters {
        // Power-law sizes: N(>D) ∝ D^-2, radii 30 m .. 3 km.
        let u = unit(&mut st);
        let r = (30.0 / (1.0 - u * (1.0 - (30.0f64 / 3000.0).powi(2))).sqrt()).min(0.08 * extent);
        let x = (unit(&mut st) - 0.5) * extent;
        let y = (unit(&mut st) - 0.5) * extent;
        let depth = 0.4 * r * (0.8 + 0.4 * unit(&mut st));
        craters.push(Crater {
            x,
            y,
            r,
            depth,
            rim: 0.08 * r,
        });
    }
    let seed = spec.seed;
    let rows: Vec<Vec<f32>> = (0..n)
        .into_par_iter()
        .map(|row| {
            let y = (n as f64 / 2.0 - 0.5 - row as f64) * px;
            (0..n)
                .map(|col| {
                    let x = (col as f64 - n as f64 / 2.0 + 0.5) * px;
                    // fBm: 6 km base wavelength, H = 0.8, 9 octaves down to ~25 m.
                    let (mut amp, mut wl, mut h) = (600.0, 6_000.0, 0.0);
                    for o in 0..9u64 {
                        h += amp * value_noise(seed.wrapping_add(o * 7919), x / wl, y / wl);
                        amp *= 0.5f64.powf(0.8);
                        wl *= 0.5;
                    }
                    // A massif beside the big crater, like Malapert or Leibnitz β.
                    let (mx, my) = (x + 0.28 * extent, y - 0.22 * extent);
                    h += 1_800.0 * (-(mx * mx + my * my) / (0.22 * extent).powi(2)).exp();
                    for c in &craters {
                        let (dx, dy) = (x - c.x, y - c.y);
                        if dx.abs() > 4.0 * c.r || dy.abs() > 4.0 * c.r {
                            continue;
                        }
                        h += c.profile((dx * dx + dy * dy).sqrt());
                    }
                    h as f32
                })
                .collect()
        })
        .collect();
    let data: Vec<f32> = rows.into_iter().flatten().collect();
    let half = (n as f64 - 1.0) / 2.0 * px;
    DemParts {
        width: n,
        height: n,
        samples: Samples::Owned(data),
        scale: 1.0,
        offset: 0.0,
        nodata: None,
        georef: GeoRef {
            crs: Crs::PolarStereographic {
                north: false,
                lon0_deg: 0.0,
                lat_ts_deg: -90.0,
                radius_m: MOON_RADIUS_M,
            },
            x0: -half,
            y0: half,
            dx: px,
            dy: px,
        },
        datum_radius_m: Some(MOON_RADIUS_M),
        target: Some("moon".into()),
        sources: vec![],
        format: format!("embedded synthetic south-pole scene {n}×{n} at {px} m/px"),
    }
}

/// Content hash of the generated heights, for the manifest and run key.
pub fn content_hash(parts: &DemParts) -> String {
    let mut h = blake3::Hasher::new();
    if let Samples::Owned(v) = &parts.samples {
        for x in v {
            h.update(&x.to_le_bytes());
        }
    }
    h.finalize().to_hex().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_lunar_like() {
        let spec = SyntheticSpec {
            size: 256,
            pixel_m: 80.0,
            ..Default::default()
        };
        let a = generate(&spec);
        let b = generate(&spec);
        assert_eq!(content_hash(&a), content_hash(&b));
        let Samples::Owned(v) = &a.samples else {
            unreachable!()
        };
        let (lo, hi) = v
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), &x| (l.min(x), h.max(x)));
        assert!(
            lo < -1000.0 && hi > 500.0 && hi - lo < 10_000.0,
            "{lo} {hi}"
        );
    }
}
