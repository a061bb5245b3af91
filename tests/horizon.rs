//! Horizons: the fast sweep against the brute-force reference and against analytic answers.

use penumbra::cube::Face;
use penumbra::horizon::{self, Context, Method, Rect};

/// xorshift64*: deterministic and dependency-free.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Rough random terrain: a few octaves of value noise (bilinear between random lattices).
fn rough(w: usize, h: usize, amp: f64, seed: u64) -> Vec<f32> {
    let mut rng = Rng(seed | 1);
    let mut out = vec![0.0f64; w * h];
    let mut a = amp;
    let mut cell = 64usize;
    while cell >= 1 {
        let (gw, gh) = (w / cell + 2, h / cell + 2);
        let g: Vec<f64> = (0..gw * gh).map(|_| rng.unit() * 2.0 - 1.0).collect();
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f64 / cell as f64, y as f64 / cell as f64);
                let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
                let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
                let v = g[y0 * gw + x0] * (1.0 - tx) * (1.0 - ty)
                    + g[y0 * gw + x0 + 1] * tx * (1.0 - ty)
                    + g[(y0 + 1) * gw + x0] * (1.0 - tx) * ty
                    + g[(y0 + 1) * gw + x0 + 1] * tx * ty;
                out[y * w + x] += a * v;
            }
        }
        a *= 0.5;
        cell /= 2;
    }
    out.into_iter().map(|v| v as f32).collect()
}

/// A raster of `w × h` pixels of `pixel_m` metres centred on face `face` of a body of radius
/// `radius_m`, offset by `(dx, dy)` pixels from the face centre.
fn context(face: Face, radius_m: f64, pixel_m: f64, w: usize, h: usize, heights: Vec<f32>) -> Context {
    let s = (2.0 * radius_m / pixel_m).round();
    Context {
        face,
        face_pixels: s,
        origin: ((s as i64 - w as i64) / 2, (s as i64 - h as i64) / 2),
        width: w,
        height: h,
        heights,
        radius_m,
    }
}

fn stats(a: &[f32], b: &[f32]) -> (f64, f64, usize) {
    let (mut ss, mut mx, mut n) = (0.0f64, 0.0f64, 0usize);
    for (x, y) in a.iter().zip(b) {
        if x.is_nan() || y.is_nan() {
            continue;
        }
        let d = (*x as f64 - *y as f64).abs();
        ss += d * d;
        mx = mx.max(d);
        n += 1;
    }
    ((ss / n.max(1) as f64).sqrt(), mx, n)
}

#[test]
fn fast_matches_scan_and_reference_on_rough_terrain() {
    let (w, h) = (160, 160);
    let ctx = context(Face::Px, 1_737_400.0, 100.0, w, h, rough(w, h, 800.0, 7));
    let rect = Rect { x0: 50, y0: 50, w: 40, h: 40 };
    let a = 72;
    let fast = horizon::horizons(&ctx, rect, a, Method::Fast);
    let scan = horizon::horizons_scan(&ctx, rect, a);
    let reference = horizon::horizons(&ctx, rect, a, Method::Reference);
    let (rms_s, max_s, _) = stats(&fast, &scan);
    let (rms_r, max_r, n) = stats(&fast, &reference);
    eprintln!("fast vs scan: rms {rms_s:.2e} max {max_s:.2e}; fast vs reference: rms {rms_r:.4} max {max_r:.4} over {n}");
    assert!(max_s < 1e-4, "hull differs from a scan of the same samples: {max_s}");
    assert!(rms_r <= 0.05 && max_r <= 0.5, "rms {rms_r} max {max_r}");
}

#[test]
fn debug_per_azimuth() {
    let (w, h) = (160, 160);
    let ctx = context(Face::Px, 1_737_400.0, 100.0, w, h, rough(w, h, 800.0, 7));
    let rect = Rect { x0: 50, y0: 50, w: 40, h: 40 };
    let a = 8;
    let fast = horizon::horizons(&ctx, rect, a, Method::Fast);
    let scan = horizon::horizons_scan(&ctx, rect, a);
    let reference = horizon::horizons(&ctx, rect, a, Method::Reference);
    let p = rect.w * rect.h;
    for k in 0..a {
        let r = k * p..(k + 1) * p;
        let (r1, m1, _) = stats(&fast[r.clone()], &scan[r.clone()]);
        let (r2, m2, _) = stats(&scan[r.clone()], &reference[r.clone()]);
        eprintln!("k {k}: fast-scan rms {r1:.3} max {m1:.3}; scan-ref rms {r2:.3} max {m2:.3}; sample f {} s {} r {}", fast[r.start+820], scan[r.start+820], reference[r.start+820]);
    }
}

#[test]
fn debug_spike() {
    let (w, h) = (64, 64);
    let mut hs = vec![0.0f32; w * h];
    hs[30 * w + 40] = 1000.0;
    let ctx = context(Face::Px, 1_737_400.0, 100.0, w, h, hs);
    let rect = Rect { x0: 20, y0: 20, w: 10, h: 10 };
    let a = 8;
    let fast = horizon::horizons(&ctx, rect, a, Method::Fast);
    let scan = horizon::horizons_scan(&ctx, rect, a);
    let reference = horizon::horizons(&ctx, rect, a, Method::Reference);
    let p = rect.w * rect.h;
    for k in 0..a {
        for i in 0..p {
            let (f, s, r) = (fast[k * p + i], scan[k * p + i], reference[k * p + i]);
            if (f - r).abs() > 0.5 || (s - r).abs() > 0.5 {
                eprintln!("k {k} px ({}, {}) fast {f} scan {s} ref {r}", 20 + i % 10, 20 + i / 10);
            }
        }
    }
}

#[test]
fn debug_gale() {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mola_gale_128ppd_crop/gale-mola.bin");
    let d = penumbra::dem::open(&p, 64).unwrap();
    let n = d.width();
    let mut hs = vec![0.0f32; n * n];
    for r in 0..n { for c in 0..n { hs[r * n + c] = d.value(c, r).0; } }
    let ctx = context(Face::Px, 3_396_190.0, 463.0, n, n, hs);
    let rect = Rect { x0: 380, y0: 320, w: 40, h: 40 };
    let a = 72;
    let fast = horizon::horizons(&ctx, rect, a, Method::Fast);
    let r2 = horizon::horizons(&ctx, rect, a, Method::Reference);
    let r8 = horizon::horizons_reference_step(&ctx, rect, a, 0.125);
    eprintln!("fast-ref2 {:?}", stats(&fast, &r2));
    eprintln!("fast-ref8 {:?}", stats(&fast, &r8));
    eprintln!("ref2-ref8 {:?}", stats(&r2, &r8));
    let (w, h) = (160, 160);
    let ctx = context(Face::Px, 1_737_400.0, 100.0, w, h, rough(w, h, 800.0, 7));
    let rect = Rect { x0: 50, y0: 50, w: 40, h: 40 };
    let fast = horizon::horizons(&ctx, rect, a, Method::Fast);
    let r2 = horizon::horizons(&ctx, rect, a, Method::Reference);
    let r8 = horizon::horizons_reference_step(&ctx, rect, a, 0.125);
    eprintln!("rough fast-ref2 {:?}", stats(&fast, &r2));
    eprintln!("rough fast-ref8 {:?}", stats(&fast, &r8));
    eprintln!("rough ref2-ref8 {:?}", stats(&r2, &r8));
}

#[test]
fn debug_worst() {
    let (w, h) = (160, 160);
    let ctx = context(Face::Px, 1_737_400.0, 100.0, w, h, rough(w, h, 800.0, 7));
    let rect = Rect { x0: 50, y0: 50, w: 40, h: 40 };
    let a = 72;
    let fast = horizon::horizons(&ctx, rect, a, Method::Fast);
    let r2 = horizon::horizons(&ctx, rect, a, Method::Reference);
    let r8 = horizon::horizons_reference_step(&ctx, rect, a, 0.02);
    let mut v: Vec<(f32, usize)> = fast.iter().zip(&r8).enumerate().map(|(i, (f, r))| ((f - r).abs(), i)).collect();
    v.sort_by(|a, b| b.0.partial_cmp(&a.0).unwrap());
    let p = rect.w * rect.h;
    for &(d, i) in v.iter().take(12) {
        eprintln!("d {d:.3} k {} px ({}, {}) fast {} r2 {} r50 {}", i / p, 50 + (i % p) % 40, 50 + (i % p) / 40, fast[i], r2[i], r8[i]);
    }
    eprintln!("fast-r50 {:?} r2-r50 {:?}", stats(&fast, &r8), stats(&r2, &r8));
}

fn read_npy_f32(path: &std::path::Path) -> (usize, usize, Vec<f32>) {
    let b = std::fs::read(path).unwrap();
    let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
    let header = std::str::from_utf8(&b[10..10 + hl]).unwrap();
    let shape = header.split("'shape': (").nth(1).unwrap().split(')').next().unwrap();
    let dims: Vec<usize> = shape.split(',').filter(|s| !s.trim().is_empty()).map(|s| s.trim().parse().unwrap()).collect();
    let data = b[10 + hl..].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    (dims[1], dims[0], data)
}

#[test]
#[ignore]
fn debug_speed() {
    let (w, h, hs) = read_npy_f32(std::path::Path::new("/work/peers/data/dem1024.npy"));
    let ctx = context(Face::Px, 6_371_008.8, 30.0, w, h, hs);
    let rect = Rect { x0: 0, y0: 0, w, h };
    let a: usize = std::env::var("HZ_A").ok().and_then(|v| v.parse().ok()).unwrap_or(36);
    let t = std::time::Instant::now();
    let fast = horizon::horizons(&ctx, rect, a, Method::Fast);
    let el = t.elapsed().as_secs_f64();
    eprintln!("fast {w}x{h}x{a}: {el:.2} s, {:.1} ns per pixel-azimuth (wall)", el * 1e9 / (w * h * a) as f64);
    let sub = Rect { x0: 500, y0: 500, w: 16, h: 16 };
    let t = std::time::Instant::now();
    let r = horizon::horizons_reference_step(&ctx, sub, a, 0.25);
    let el2 = t.elapsed().as_secs_f64();
    eprintln!("reference 16x16x{a}: {el2:.2} s, {:.1} ns per pixel-azimuth", el2 * 1e9 / (256 * a) as f64);
    let mut f2 = Vec::new();
    for k in 0..a { for j in 0..16 { for i in 0..16 { f2.push(fast[k * w * h + (500 + j) * w + 500 + i]); } } }
    eprintln!("fast vs ref4 on the block: {:?}", stats(&f2, &r));
}
