//! The GPU twins of the shadow methods against the CPU methods, texel by texel, on Mesa's
//! lavapipe (or whatever adapter there is): every texel of a tile, for each method and several
//! suns, on the embedded scene and on a real DEM. Without an adapter the tests skip with a
//! message, except under CI (`CI` set, not `false` or `0`), where they fail.

use std::path::{Path, PathBuf};

use penumbra::bake::{bake, Input, Plan};
use penumbra::fourier::sun::{sun_radius_deg, Frame, Model, Sun};
use penumbra::fourier::FourierOptions;
use penumbra::horizon::HorizonOptions;
use penumbra::layout::TileId;
use penumbra::manifest::Tileset;
use penumbra::progress::NoProgress;
use penumbra::shadow::Runs;
use penumbra::synthetic::SyntheticSpec;
use penumbra::tileset::Store;
use penumbra::tiling::TileOptions;
use penumbra_view::gpu::{Gpu, GpuError};
use penumbra_view::shadow::{evaluate, CpuTwin, GpuMethod, Shadows, TileShadow};

fn ci() -> bool {
    std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false"))
}

/// The device, or a skip (`None`, after a message) — a panic under CI.
fn adapter_or_skip(r: Result<Gpu, GpuError>, ci: bool) -> Option<Gpu> {
    match r {
        Ok(g) => {
            eprintln!("adapter: {}", g.describe());
            Some(g)
        }
        Err(e) if ci => panic!("no GPU adapter under CI ({e}): CI must run the GPU tests"),
        Err(e) => {
            eprintln!("skipping: {e}");
            None
        }
    }
}

fn gpu() -> Option<Gpu> {
    adapter_or_skip(Gpu::headless(), ci())
}

#[test]
fn no_adapter_skips_outside_ci() {
    let none = Err(GpuError::NoAdapter("test".into()));
    assert!(adapter_or_skip(none, false).is_none());
}

#[test]
#[should_panic(expected = "CI must run the GPU tests")]
fn no_adapter_fails_under_ci() {
    adapter_or_skip(Err(GpuError::NoAdapter("test".into())), true);
}

/// The real DEMs: `$PENUMBRA_SHARED_DATA`, else ../shared/data beside the repository; a skip
/// when absent, a panic under CI.
fn shared_data() -> Option<PathBuf> {
    let dir = match std::env::var_os("PENUMBRA_SHARED_DATA") {
        Some(p) => PathBuf::from(p),
        None => Path::new(env!("CARGO_MANIFEST_DIR"))
            .ancestors()
            .nth(2)
            .expect("tools/viewer lies two levels below the repository root")
            .join("../shared/data"),
    };
    if dir.is_dir() {
        Some(dir)
    } else if ci() {
        panic!("{}: real-DEM folder not found under CI", dir.display());
    } else {
        eprintln!(
            "skipping: {} not found (real-DEM checks need it)",
            dir.display()
        );
        None
    }
}

/// Bakes `input` into `out` with tiles of `tile_size` (heights and mipmaps, `levels` levels or
/// as many as the source resolution asks), and when `fourier` horizons with Fourier pyramids
/// (64 azimuths) at the coarsest level of at least 16 tiles; returns that level.
fn bake_small(input: Input, out: &Path, tile_size: u32, levels: Option<u8>, fourier: bool) -> u8 {
    let plan = Plan {
        tile: TileOptions {
            tile_size,
            levels,
            ..Default::default()
        },
        ..Plan::default()
    };
    let t0 = std::time::Instant::now();
    bake(&input, out, &plan, &NoProgress).unwrap();
    let ts = Tileset::load(out).unwrap();
    let tiles = ts.tile_set();
    let level = (0..ts.layout.levels)
        .find(|&l| tiles.iter().filter(|t| t.level == l).count() >= 16)
        .unwrap_or(ts.layout.levels - 1);
    if fourier {
        let opts = HorizonOptions {
            levels: Some(vec![level]),
            azimuths: 64,
            max_margin_px: 256,
            ..Default::default()
        };
        penumbra::graph::horizons(
            out,
            &opts,
            Some(&FourierOptions::default()),
            false,
            &penumbra::runner::Select::All,
            &NoProgress,
        )
        .unwrap();
    }
    eprintln!(
        "baked {} in {:.1} s (level {level})",
        out.display(),
        t0.elapsed().as_secs_f64()
    );
    level
}

/// Levels of the embedded scene's test tilesets: its finest, level 9, has 4×4 64-px tiles or
/// more (the levels the source's resolution asks for go finer, and take longer to bake).
const EMBEDDED_LEVELS: u8 = 10;

fn embedded() -> Input<'static> {
    Input::Embedded(SyntheticSpec {
        size: 1024,
        ..SyntheticSpec::default()
    })
}

/// The tile of `level` nearest the middle of its coverage.
fn middle_tile(store: &Store, level: u8) -> TileId {
    let tiles: Vec<TileId> = store
        .manifest()
        .tile_set()
        .into_iter()
        .filter(|t| t.level == level)
        .collect();
    let n = tiles.len() as f64;
    let (cx, cy) = (
        tiles.iter().map(|t| t.x as f64).sum::<f64>() / n,
        tiles.iter().map(|t| t.y as f64).sum::<f64>() / n,
    );
    *tiles
        .iter()
        .min_by(|a, b| {
            let d = |t: &TileId| (t.x as f64 - cx).powi(2) + (t.y as f64 - cy).powi(2);
            d(a).total_cmp(&d(b))
        })
        .unwrap()
}

/// A sun at local elevation `el` and compass azimuth `az` (degrees) over the tile's centre.
fn sun_over(store: &Store, tile: TileId, az: f64, el: f64) -> Sun {
    let lay = store.manifest().layout;
    let c = lay.tile_size as i64 / 2;
    let (s, t) = lay.pixel_st(tile, c, c);
    let f = Frame::at(
        tile.face,
        lay.projection.s_to_u(s),
        lay.projection.s_to_u(t),
    );
    Sun {
        dir: f.direction(az, el),
        radius_deg: sun_radius_deg(1.0),
    }
}

/// GPU-against-CPU numbers over texels both have data at.
#[derive(Default)]
struct Cmp {
    n: usize,
    abs: f64,
    decisions: usize,
    /// Texels with data on one side only.
    data_mismatch: usize,
    max: f64,
}

impl Cmp {
    fn add(&mut self, gpu: &[f32], cpu: &[f64]) {
        for (&g, &c) in gpu.iter().zip(cpu) {
            match (g >= 0.0, c.is_finite()) {
                (true, true) => {
                    let d = (g as f64 - c).abs();
                    self.n += 1;
                    self.abs += d;
                    self.max = self.max.max(d);
                    if (g > 0.5) != (c > 0.5) {
                        self.decisions += 1;
                    }
                }
                (false, false) => {}
                _ => self.data_mismatch += 1,
            }
        }
    }
    fn mean(&self) -> f64 {
        self.abs / self.n.max(1) as f64
    }
    fn per(&self) -> f64 {
        self.decisions as f64 / self.n.max(1) as f64
    }
}

/// Every texel of the tile's interior.
fn interior(t: &TileShadow) -> Vec<[i32; 2]> {
    let r = t.rect;
    (0..r.h)
        .flat_map(|j| (0..r.w).map(move |i| [(r.x0 + i) as i32, (r.y0 + j) as i32]))
        .collect()
}

const SUNS: [(f64, f64); 6] = [
    (1.0, 35.0),
    (1.0, 200.0),
    (5.0, 120.0),
    (5.0, 300.0),
    (15.0, 75.0),
    (45.0, 250.0),
];

/// Compares every method's GPU twin with its CPU method at every texel of `tile`, for every
/// sun of [`SUNS`], and GPU `dp` with the CPU reference; asserts the acceptance bounds.
fn compare_scene(gpu: &Gpu, dir: &Path, tile: TileId, scene: &str) {
    let store = Store::open(dir).unwrap();
    let shadows = Shadows::new(gpu);
    let methods = [
        GpuMethod::Dp { runs: Runs::Auto },
        GpuMethod::Dp {
            runs: "5,5,5".parse().unwrap(),
        },
        GpuMethod::DpJung { runs: Runs::Auto },
        GpuMethod::Uniform { steps: 64 },
        GpuMethod::Extrema,
        GpuMethod::ExtremaSoft,
        GpuMethod::Fourier {
            model: Model::Constant,
        },
        GpuMethod::Fourier {
            model: Model::Segment,
        },
        GpuMethod::Fourier {
            model: Model::Slices,
        },
        GpuMethod::Fourier {
            model: Model::Exact,
        },
    ];
    let is_fourier = |m: &GpuMethod| matches!(m, GpuMethod::Fourier { .. });
    let mut totals: Vec<Cmp> = methods.iter().map(|_| Cmp::default()).collect();
    let mut vs_reference = Cmp::default();
    // GPU extrema-soft against the CPU reference, and each GPU O(K) Fourier model against the
    // CPU's exact disc model over the same coefficients.
    let mut soft_vs_reference = Cmp::default();
    let mut vs_exact: Vec<Cmp> = methods.iter().map(|_| Cmp::default()).collect();
    for &(el, az) in &SUNS {
        let sun = sun_over(&store, tile, az, el);
        // One preparation for the ray-marching methods (they share the data), one for Fourier.
        let trace = shadows
            .prepare_tile(gpu, &store, tile, &sun, &methods[0], 512)
            .unwrap();
        let fourier = shadows
            .prepare_tile(gpu, &store, tile, &sun, &methods[6], 512)
            .unwrap();
        let texels = interior(&trace);
        let mut exact_cpu = None;
        for (k, m) in methods.iter().enumerate() {
            let t = if is_fourier(m) { &fourier } else { &trace };
            assert!(t.margin_ok(&store, &sun));
            t.set_sun(gpu, &sun, m);
            let texels = if is_fourier(m) {
                interior(t)
            } else {
                texels.clone()
            };
            let t0 = std::time::Instant::now();
            let g = evaluate(gpu, &shadows, t, &texels).unwrap();
            let gpu_s = t0.elapsed().as_secs_f64();
            let c = t.cpu_lit_many(&texels, &sun, &CpuTwin::Same(m.clone()));
            let mut one = Cmp::default();
            one.add(&g, &c);
            eprintln!(
                "{scene} {tile} sun el {el:>4}° az {az:>5}°  {:<12} GPU vs CPU: mean {:.5} \
                 max {:.4} PER {:.3}% ({} texels, {} data mismatches, GPU {:.2} s)",
                m.label(),
                one.mean(),
                one.max,
                100.0 * one.per(),
                one.n,
                one.data_mismatch,
                gpu_s
            );
            assert_eq!(one.data_mismatch, 0, "{}: no-data texels differ", m.label());
            assert!(one.n > 0);
            totals[k].add(&g, &c);
            if is_fourier(m) {
                let exact = exact_cpu.get_or_insert_with(|| {
                    let model = Model::Exact;
                    t.cpu_lit_many(&texels, &sun, &CpuTwin::Same(GpuMethod::Fourier { model }))
                });
                vs_exact[k].add(&g, exact);
            }
            if *m == GpuMethod::ExtremaSoft {
                let r = t.cpu_lit_many(&texels, &sun, &CpuTwin::Reference);
                soft_vs_reference.add(&g, &r);
            }
            if k == 0 {
                let r = t.cpu_lit_many(&texels, &sun, &CpuTwin::Reference);
                let mut one = Cmp::default();
                one.add(&g, &r);
                eprintln!(
                    "{scene} {tile} sun el {el:>4}° az {az:>5}°  GPU dp auto vs CPU reference: \
                     mean {:.5} PER {:.3}%",
                    one.mean(),
                    100.0 * one.per()
                );
                vs_reference.add(&g, &r);
            }
        }
    }
    for (m, c) in methods.iter().zip(&totals) {
        eprintln!(
            "{scene}: {:<12} GPU vs CPU over all suns: mean {:.5} PER {:.3}% max {:.4} ({} texels)",
            m.label(),
            c.mean(),
            100.0 * c.per(),
            c.max,
            c.n
        );
        assert!(
            c.mean() <= 0.01,
            "{scene} {}: mean |GPU − CPU| {} > 0.01",
            m.label(),
            c.mean()
        );
        assert!(
            c.per() <= 0.005,
            "{scene} {}: PER {} > 0.5 %",
            m.label(),
            c.per()
        );
    }
    for (m, c) in methods.iter().zip(&vs_exact).filter(|(m, _)| is_fourier(m)) {
        eprintln!(
            "{scene}: GPU {:<16} vs CPU fourier exact over all suns: mean {:.5} PER {:.3}%",
            m.label(),
            c.mean(),
            100.0 * c.per()
        );
        assert!(
            c.mean() <= 0.005,
            "{scene} GPU {} vs the exact disc model: mean {} > 0.005",
            m.label(),
            c.mean()
        );
    }
    eprintln!(
        "{scene}: GPU extrema-soft vs CPU reference over all suns: mean {:.5} PER {:.3}%",
        soft_vs_reference.mean(),
        100.0 * soft_vs_reference.per()
    );
    assert!(
        soft_vs_reference.mean() <= 0.01,
        "{scene}: GPU extrema-soft vs the reference: mean {} > 0.01",
        soft_vs_reference.mean()
    );
    eprintln!(
        "{scene}: GPU dp auto vs CPU reference over all suns: mean {:.5} PER {:.3}%",
        vs_reference.mean(),
        100.0 * vs_reference.per()
    );
    assert!(
        vs_reference.mean() <= 0.05,
        "{scene}: GPU dp vs the reference: mean {}",
        vs_reference.mean()
    );
}

#[test]
fn gpu_methods_match_the_cpu_on_the_embedded_scene() {
    let Some(gpu) = gpu() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles");
    let level = bake_small(embedded(), &out, 64, Some(EMBEDDED_LEVELS), true);
    let store = Store::open(&out).unwrap();
    let tile = middle_tile(&store, level);
    drop(store);
    compare_scene(&gpu, &out, tile, "embedded");
}

#[test]
fn gpu_methods_match_the_cpu_on_a_real_dem() {
    let Some(data) = shared_data() else { return };
    let Some(gpu) = gpu() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles");
    let input = Input::Dem {
        path: data.join("lola_shoemaker_1k/Shoemaker_final_adj_5mpp_surf_1k.tif"),
        body: penumbra::bake::BodyChoice {
            name: Some("moon".into()),
            radius_m: None,
        },
    };
    let level = bake_small(input, &out, 64, None, true);
    let store = Store::open(&out).unwrap();
    let tile = middle_tile(&store, level);
    drop(store);
    compare_scene(&gpu, &out, tile, "Shoemaker (LOLA)");
}

#[test]
fn fourier_without_pyramids_says_what_to_run() {
    let Some(gpu) = gpu() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles");
    let level = bake_small(embedded(), &out, 64, Some(EMBEDDED_LEVELS), false);
    let store = Store::open(&out).unwrap();
    let tile = middle_tile(&store, level);
    let sun = sun_over(&store, tile, 90.0, 10.0);
    let shadows = Shadows::new(&gpu);
    let fourier = GpuMethod::Fourier {
        model: Model::Constant,
    };
    let err = match shadows.prepare_tile(&gpu, &store, tile, &sun, &fourier, 256) {
        Ok(_) => panic!("a tileset without Fourier pyramids was accepted"),
        Err(e) => format!("{e:#}"),
    };
    eprintln!("{err}");
    assert!(
        err.contains("penumbra horizon --fourier"),
        "the error should say what to run: {err}"
    );
    // The ray-marching methods need no product beyond the heights.
    let t = shadows
        .prepare_tile(&gpu, &store, tile, &sun, &GpuMethod::Extrema, 256)
        .unwrap();
    let g = evaluate(&gpu, &shadows, &t, &interior(&t)).unwrap();
    assert!(g.iter().all(|&v| v == 0.0 || v == 1.0 || v < 0.0));
}

/// `shadow_lit` in a fragment shader with the bind group at `@group(1)` (the renderer's
/// situation): one fragment per texel of the tile's interior, into an R32Float target (R16Float
/// where that is not renderable).
fn render_lit(gpu: &Gpu, shadows: &Shadows, t: &TileShadow) -> Vec<f32> {
    let (w, h) = (t.rect.w as u32, t.rect.h as u32);
    let src = format!(
        "{}\n{}",
        Shadows::wgsl(),
        r#"
@vertex fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    return vec4<f32>(f32(i32(i & 1u) * 4 - 1), f32(i32(i >> 1u) * 4 - 1), 0.0, 1.0);
}
@fragment fn fs(@builtin(position) q: vec4<f32>) -> @location(0) vec4<f32> {
    return vec4<f32>(shadow_lit(vec2<i32>(q.xy) + shadow_params.rect.xy), 0.0, 0.0, 1.0);
}
"#
    );
    let dev = &gpu.device;
    let module = dev.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("shadow fragment test"),
        source: wgpu::ShaderSource::Wgsl(src.into()),
    });
    let layout = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: None,
        bind_group_layouts: &[None, Some(shadows.layout())],
        immediate_size: 0,
    });
    // R32Float where it is renderable (Vulkan), else half floats (GL).
    let renderable = |f| {
        gpu.adapter
            .get_texture_format_features(f)
            .allowed_usages
            .contains(wgpu::TextureUsages::RENDER_ATTACHMENT)
    };
    let format = if renderable(wgpu::TextureFormat::R32Float) {
        wgpu::TextureFormat::R32Float
    } else {
        wgpu::TextureFormat::R16Float
    };
    let texel = format.block_copy_size(None).unwrap();
    let row = (w * texel).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let pipeline = dev.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: None,
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: None,
        multisample: wgpu::MultisampleState::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs"),
            compilation_options: Default::default(),
            targets: &[Some(format.into())],
        }),
        multiview_mask: None,
        cache: None,
    });
    let size = wgpu::Extent3d {
        width: w,
        height: h,
        depth_or_array_layers: 1,
    };
    let target = dev.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    });
    let view = target.create_view(&Default::default());
    let readback = dev.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: (row * h) as u64,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = dev.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: None,
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(1, &t.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }
    enc.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture: &target,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &readback,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: Some(h),
            },
        },
        size,
    );
    gpu.queue.submit([enc.finish()]);
    readback.map_async(wgpu::MapMode::Read, .., |r| r.unwrap());
    dev.poll(wgpu::PollType::Wait {
        submission_index: None,
        timeout: None,
    })
    .unwrap();
    let bytes = readback.get_mapped_range(..).unwrap();
    bytes
        .chunks_exact(row as usize)
        .flat_map(|r| r[..(w * texel) as usize].chunks_exact(texel as usize))
        .map(|b| match b.len() {
            4 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            _ => half::f16::from_le_bytes([b[0], b[1]]).to_f32(),
        })
        .collect()
}

#[test]
fn the_fragment_shader_draws_what_the_compute_harness_finds() {
    let Some(gpu) = gpu() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles");
    let level = bake_small(embedded(), &out, 64, Some(EMBEDDED_LEVELS), false);
    let store = Store::open(&out).unwrap();
    let tile = middle_tile(&store, level);
    let shadows = Shadows::new(&gpu);
    let sun = sun_over(&store, tile, 140.0, 3.0);
    let t = shadows
        .prepare_tile(
            &gpu,
            &store,
            tile,
            &sun,
            &GpuMethod::Dp { runs: Runs::Auto },
            256,
        )
        .unwrap();
    for m in [GpuMethod::Dp { runs: Runs::Auto }, GpuMethod::Extrema] {
        t.set_sun(&gpu, &sun, &m);
        let drawn = render_lit(&gpu, &shadows, &t);
        let found = evaluate(&gpu, &shadows, &t, &interior(&t)).unwrap();
        let mut c = Cmp::default();
        c.add(
            &drawn,
            &found
                .iter()
                .map(|&v| if v < 0.0 { f64::NAN } else { v as f64 })
                .collect::<Vec<_>>(),
        );
        eprintln!(
            "{}: fragment vs compute: mean {:.2e} max {:.2e} over {} texels, {} with data on one side",
            m.label(),
            c.mean(),
            c.max,
            c.n,
            c.data_mismatch
        );
        // Exact through R32Float; R16Float rounds to 2⁻¹¹.
        assert!(c.n > 0 && c.data_mismatch == 0 && c.mean() <= 1e-3 && c.per() <= 0.001);
    }
}

#[test]
fn method_names_parse() {
    assert_eq!(
        "dp".parse::<GpuMethod>().unwrap(),
        GpuMethod::Dp { runs: Runs::Auto }
    );
    assert_eq!("dp:5,5,5".parse::<GpuMethod>().unwrap().label(), "dp 5,5,5");
    assert_eq!(
        "uniform".parse::<GpuMethod>().unwrap(),
        GpuMethod::Uniform { steps: 100 }
    );
    assert_eq!("extrema".parse::<GpuMethod>().unwrap(), GpuMethod::Extrema);
    assert_eq!(
        "fourier".parse::<GpuMethod>().unwrap(),
        GpuMethod::Fourier {
            model: Model::Constant
        }
    );
    assert_eq!(
        "fourier:exact".parse::<GpuMethod>().unwrap().label(),
        "fourier exact"
    );
    assert_eq!(
        "extrema-soft".parse::<GpuMethod>().unwrap(),
        GpuMethod::ExtremaSoft
    );
    assert!("fourier:disc".parse::<GpuMethod>().is_err());
    assert_eq!(
        "dp-jung:5,5,5".parse::<GpuMethod>().unwrap().label(),
        "dp-jung 5,5,5"
    );
    assert!("smap".parse::<GpuMethod>().is_err());
    assert!("uniform:0".parse::<GpuMethod>().is_err());
}

#[test]
fn the_wgsl_compiles_and_declares_shadow_lit() {
    assert!(Shadows::wgsl().contains("fn shadow_lit(p: vec2<i32>) -> f32"));
    let Some(gpu) = gpu() else { return };
    let shadows = Shadows::new(&gpu);
    // A module using the group-1 layout: the renderer's situation.
    let src = format!(
        "{}\n@fragment fn fs(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> \
         {{ return vec4<f32>(shadow_lit(vec2<i32>(p.xy))); }}",
        Shadows::wgsl()
    );
    let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let _m = gpu
        .device
        .create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shadow test"),
            source: wgpu::ShaderSource::Wgsl(src.into()),
        });
    let err = pollster::block_on(scope.pop());
    assert!(err.is_none(), "{err:?}");
    let _ = shadows.layout();
}
