//! Everything the CLI shows people: progress bars on stderr, tables and JSON on stdout.

use std::io::Write;
use std::path::Path;
use std::sync::Mutex;

use anyhow::Result;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use penumbra::bake::BakeReport;
use penumbra::fourier::FourierReport;
use penumbra::graph::Ran;
use penumbra::horizon::HorizonReport;
use penumbra::manifest::Tileset;
use penumbra::mip::MipReport;
use penumbra::query::HeightAnswer;
use penumbra::query::{HorizonAnswer, MipAnswer, ShadowAnswer};

/// indicatif bars on stderr; nothing when quiet or when stderr is not a terminal.
pub struct Bars {
    quiet: bool,
    bar: Mutex<Option<ProgressBar>>,
}

impl Bars {
    pub fn new(quiet: bool) -> Bars {
        Bars {
            quiet,
            bar: Mutex::new(None),
        }
    }
}

impl penumbra::progress::Progress for Bars {
    fn start(&self, label: &str, total: u64) {
        if self.quiet {
            return;
        }
        let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
        bar.set_style(
            ProgressStyle::with_template("{prefix:>10} [{bar:40}] {pos}/{len} {per_sec} eta {eta}")
                .expect("valid template")
                .progress_chars("=> "),
        );
        bar.set_prefix(label.to_string());
        *self.bar.lock().expect("progress lock") = Some(bar);
    }
    fn inc(&self, n: u64) {
        if let Some(b) = self.bar.lock().expect("progress lock").as_ref() {
            b.inc(n);
        }
    }
    fn finish(&self) {
        if let Some(b) = self.bar.lock().expect("progress lock").take() {
            b.finish_and_clear();
        }
    }
}

pub fn print_json<T: serde::Serialize>(v: &T) -> Result<()> {
    let mut out = std::io::stdout().lock();
    serde_json::to_writer_pretty(&mut out, v)?;
    writeln!(out)?;
    Ok(())
}

/// Peak resident set size of this process in MiB (Linux), for reports and benchmarks.
pub fn peak_rss_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

pub fn print_bake(r: &BakeReport, wall_s: f64, json: bool) -> Result<()> {
    if json {
        let mut v = serde_json::to_value(r)?;
        v["wall_s"] = serde_json::json!(wall_s);
        v["peak_rss_mib"] = serde_json::json!(peak_rss_mib());
        return print_json(&v);
    }
    let mut out = std::io::stdout().lock();
    if r.unchanged {
        writeln!(
            out,
            "{}: up to date (nothing changed since this scene's last bake here)",
            r.out.display()
        )?;
    }
    if let Some(t) = &r.tile {
        if t.up_to_date {
            writeln!(
                out,
                "{}: up to date ({} tiles)",
                t.out.display(),
                t.tiles_kept
            )?;
        } else {
            writeln!(
                out,
                "{}: {} levels, {} tiles written, {} kept from an earlier run, {} candidates",
                t.out.display(),
                t.levels,
                t.tiles_written,
                t.tiles_kept,
                t.candidates
            )?;
        }
    }
    if let Some(m) = &r.mip {
        write_mip_line(&mut out, m)?;
    }
    if let Some(h) = &r.horizon {
        write_horizon_line(&mut out, h)?;
    }
    writeln!(out, "{wall_s:.2} s")?;
    Ok(())
}

fn write_horizon_line(out: &mut impl Write, h: &HorizonReport) -> Result<()> {
    if h.up_to_date {
        writeln!(
            out,
            "{}: horizons up to date ({} tiles)",
            h.out.display(),
            h.tiles
        )?;
        return Ok(());
    }
    writeln!(
        out,
        "{}: horizons of {} tiles at levels {:?} ({} written, {} kept), {} azimuths, {} method",
        h.out.display(),
        h.tiles,
        h.levels,
        h.tiles_written,
        h.tiles_kept,
        h.azimuths,
        h.method.name()
    )?;
    let fourier = h
        .streamed
        .get("fourier")
        .and_then(|v| serde_json::from_value::<penumbra::fourier::StreamedFourier>(v.clone()).ok());
    if let Some(f) = &fourier {
        writeln!(
            out,
            "  Fourier pyramids: K = {} {} {} (sigma {}), {} written{}; {} per tile ({}), raw maps {}",
            f.coefficients,
            f.layout.name(),
            f.encoding.name(),
            f.sigma.name(),
            mib(f.bytes_written),
            if f.tiles_fully_lit > 0 {
                format!(", {} tiles fully lit", f.tiles_fully_lit)
            } else {
                String::new()
            },
            mib(f.bytes_per_tile),
            if h.horizon_s > 0.0 {
                format!(
                    "compression {:.1} % of the horizon time",
                    100.0 * h.compress_s / h.horizon_s
                )
            } else {
                "nothing compressed in this run".into()
            },
            if h.raw { "kept" } else { "not written (--keep-raw keeps them)" }
        )?;
    }
    for d in &h.distances {
        let capped = if d.tiles_capped > 0 {
            format!(", {} tiles capped by --max-margin-px", d.tiles_capped)
        } else {
            String::new()
        };
        writeln!(
            out,
            "  level {}: terrain can rise above the horizon up to {:.1} km away; margin searched up to {} px{capped}",
            d.level, d.needed_km, d.max_margin_px
        )?;
    }
    Ok(())
}

/// A stage's run: its report, or what a partial run (`--shard`) did.
pub fn print_ran(ran: &Ran, wall_s: f64, json: bool) -> Result<()> {
    match ran {
        // Tiling runs through `bake` (print_bake); a tiling report alone prints as JSON.
        Ran::Tile(r) => print_json(r),
        Ran::Other(v) => print_json(v),
        Ran::Mip(r) => print_mip(r, wall_s, json),
        Ran::Horizon(r) => print_horizon(r, wall_s, json),
        Ran::Fourier(r) => print_fourier(r, wall_s, json),
        Ran::Partial {
            stage,
            ran,
            done,
            total,
        } => {
            if json {
                return print_json(&serde_json::json!({
                    "stage": stage,
                    "partial": true,
                    "units_run": ran,
                    "units_done": done,
                    "units": total,
                    "wall_s": wall_s,
                }));
            }
            let mut out = std::io::stdout().lock();
            writeln!(
                out,
                "{stage}: {ran} units run, {done} of {total} done; the stage commits when a run \
                 with the same options completes the rest (shards of a scene's stage: when \
                 `bake SCENE --stage {stage} --finish` has checked them) ({wall_s:.2} s)"
            )?;
            Ok(())
        }
    }
}

pub fn print_horizon(r: &HorizonReport, wall_s: f64, json: bool) -> Result<()> {
    if json {
        let mut v = serde_json::to_value(r)?;
        v["wall_s"] = serde_json::json!(wall_s);
        v["peak_rss_mib"] = serde_json::json!(peak_rss_mib());
        return print_json(&v);
    }
    let mut out = std::io::stdout().lock();
    write_horizon_line(&mut out, r)?;
    if r.pixel_azimuths > 0 {
        writeln!(
            out,
            "{wall_s:.2} s, {:.1} M pixel·azimuths/s",
            r.pixel_azimuths as f64 / wall_s / 1e6
        )?;
    } else {
        writeln!(out, "{wall_s:.2} s")?;
    }
    Ok(())
}

fn mib(b: u64) -> String {
    format!("{:.2} MiB", b as f64 / (1u64 << 20) as f64)
}

pub fn print_fourier(r: &FourierReport, wall_s: f64, json: bool) -> Result<()> {
    if json {
        let mut v = serde_json::to_value(r)?;
        v["wall_s"] = serde_json::json!(wall_s);
        v["peak_rss_mib"] = serde_json::json!(peak_rss_mib());
        return print_json(&v);
    }
    let mut out = std::io::stdout().lock();
    if r.up_to_date {
        writeln!(
            out,
            "{}: Fourier pyramids up to date ({} tiles)",
            r.out.display(),
            r.tiles
        )?;
        return Ok(());
    }
    writeln!(
        out,
        "{}: Fourier pyramids of {} tiles at levels {:?} ({} written, {} kept{}), K = {} of {} \
         azimuths, {} {} (sigma {})",
        r.out.display(),
        r.tiles,
        r.levels,
        r.tiles_written,
        r.tiles_kept,
        if r.tiles_fully_lit > 0 {
            format!(", {} fully lit", r.tiles_fully_lit)
        } else {
            String::new()
        },
        r.coefficients,
        r.azimuths,
        r.layout.name(),
        r.encoding.name(),
        r.sigma.name()
    )?;
    writeln!(
        out,
        "  {} per tile against {} of raw f16 maps ({:.1}×); {} written; {wall_s:.2} s",
        mib(r.bytes_per_tile),
        mib(r.raw_bytes_per_tile),
        r.raw_bytes_per_tile as f64 / r.bytes_per_tile.max(1) as f64,
        mib(r.bytes_written)
    )?;
    Ok(())
}

/// A shadow report as JSON, with the images written and the wall time.
fn print_shadow_json(
    mut v: serde_json::Value,
    out: &Path,
    relief: Option<&Path>,
    wall_s: f64,
) -> Result<()> {
    v["out"] = serde_json::json!(out.display().to_string());
    v["relief"] = serde_json::json!(relief.map(|r| r.display().to_string()));
    v["wall_s"] = serde_json::json!(wall_s);
    print_json(&v)
}

pub fn print_shadows(
    s: &penumbra::shadow::TileShadows,
    out: &Path,
    relief: Option<&Path>,
    wall_s: f64,
    json: bool,
) -> Result<()> {
    if json {
        return print_shadow_json(serde_json::to_value(s)?, out, relief, wall_s);
    }
    let mut o = std::io::stdout().lock();
    writeln!(
        o,
        "tile {}: sun elevation {:.2}°..{:.2}° (radius {:.4}°); {} lit, {} shadowed, {} partly lit, {} without data; {}{}; {wall_s:.2} s",
        s.tile,
        s.sun_elevation_deg[0],
        s.sun_elevation_deg[1],
        s.sun_radius_deg,
        s.lit_pixels,
        s.dark_pixels,
        s.partial_pixels,
        s.no_data_pixels,
        out.display(),
        relief.map(|r| format!(", {}", r.display())).unwrap_or_default()
    )?;
    Ok(())
}

pub fn print_region_shadows(
    s: &penumbra::shadow::RegionShadows,
    out: &Path,
    relief: Option<&Path>,
    wall_s: f64,
    json: bool,
) -> Result<()> {
    if json {
        return print_shadow_json(serde_json::to_value(s)?, out, relief, wall_s);
    }
    let mut o = std::io::stdout().lock();
    writeln!(
        o,
        "box {:?} at level {} ({}×{} px of {:.5}°, {} tiles, {}): sun elevation {:.2}°..{:.2}° (radius {:.4}°); {} lit, {} shadowed, {} partly lit, {} without data; {}{}; {wall_s:.2} s",
        s.bbox,
        s.level,
        s.width,
        s.height,
        s.step_deg,
        s.tiles.len(),
        s.method,
        s.sun_elevation_deg[0],
        s.sun_elevation_deg[1],
        s.sun_radius_deg,
        s.lit_pixels,
        s.dark_pixels,
        s.partial_pixels,
        s.no_data_pixels,
        out.display(),
        relief.map(|r| format!(", {}", r.display())).unwrap_or_default()
    )?;
    Ok(())
}

pub fn print_shadow_answer(a: &ShadowAnswer, json: bool) -> Result<()> {
    if json {
        return print_json(a);
    }
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "pixel centre {:.6}°, {:.6}° (level {}, face {}, tile {}/{}, pixel {},{}), height {:.1} m",
        a.lat_deg,
        a.lon_deg,
        a.level,
        a.face,
        a.tile[0],
        a.tile[1],
        a.pixel[0],
        a.pixel[1],
        a.height_m
    )?;
    writeln!(
        out,
        "sun at azimuth {:.3}°, elevation {:.3}° (radius {:.4}° at {} AU); horizon there {:.3}° ({} {}, {} model)",
        a.sun_azimuth_deg,
        a.sun_elevation_deg,
        a.sun_radius_deg,
        a.sun_distance_au,
        a.horizon_deg,
        a.source,
        a.horizon_method.map_or(a.method.as_str(), |m| m.name()),
        a.model.name()
    )?;
    writeln!(out, "lit fraction {:.6}", a.lit_fraction)?;
    Ok(())
}

pub fn print_horizon_answer(a: &HorizonAnswer, json: bool) -> Result<()> {
    if json {
        return print_json(a);
    }
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "pixel centre {:.6}°, {:.6}° (level {}, face {}, tile {}/{}, pixel {},{}), height {:.1} m, {} horizon ({}), {} azimuths",
        a.lat_deg, a.lon_deg, a.level, a.face, a.tile[0], a.tile[1], a.pixel[0], a.pixel[1],
        a.height_m, a.method.name(), a.source, a.azimuths
    )?;
    writeln!(out, "azimuth°  elevation°  (clockwise from north)")?;
    let step = (a.azimuths / 36).max(1);
    for k in (0..a.azimuths).step_by(step) {
        writeln!(out, "{:8.2}  {:10.3}", a.azimuth_deg[k], a.elevation_deg[k])?;
    }
    if step > 1 {
        writeln!(out, "(every {step}th of {}; --json prints all)", a.azimuths)?;
    }
    if let Some(e) = &a.error {
        writeln!(
            out,
            "{} method's error against the {} (measured by the run on {} pixel·azimuths): \
             RMS {:.4}°, p99 ≤ {:.3}°, max {:.3}° ({:.3}° above at most)",
            a.method.name(),
            e.against,
            e.samples,
            e.rms_deg,
            e.p99_deg,
            e.max_deg,
            e.max_above_deg
        )?;
    }
    Ok(())
}

fn write_mip_line(out: &mut impl Write, m: &MipReport) -> Result<()> {
    if m.up_to_date {
        writeln!(
            out,
            "{}: mipmaps up to date ({} tiles)",
            m.out.display(),
            m.tiles
        )?;
    } else {
        writeln!(
            out,
            "{}: mipmaps of {} tiles ({} written, {} kept), {} face pyramids, {:?}; heights {:.1} .. {:.1} m",
            m.out.display(),
            m.tiles,
            m.tiles_written,
            m.tiles_kept,
            m.face_pyramids,
            m.precision,
            m.global_min_m,
            m.global_max_m
        )?;
    }
    Ok(())
}

pub fn print_mip(r: &MipReport, wall_s: f64, json: bool) -> Result<()> {
    if json {
        let mut v = serde_json::to_value(r)?;
        v["wall_s"] = serde_json::json!(wall_s);
        v["peak_rss_mib"] = serde_json::json!(peak_rss_mib());
        return print_json(&v);
    }
    let mut out = std::io::stdout().lock();
    write_mip_line(&mut out, r)?;
    writeln!(out, "{wall_s:.2} s")?;
    Ok(())
}

pub fn print_mip_answer(a: &MipAnswer, json: bool) -> Result<()> {
    if json {
        return print_json(a);
    }
    let f = |v: Option<f64>| v.map_or("no data".to_string(), |v| format!("{v:.3} m"));
    writeln!(
        std::io::stdout().lock(),
        "min {} max {} at {}°, {}° (mip level {} of tile level {}: {} texel {},{} of {}², face {}, tile {}/{})",
        f(a.min_m),
        f(a.max_m),
        a.lat_deg,
        a.lon_deg,
        a.level,
        a.tile_level,
        a.scope,
        a.texel[0],
        a.texel[1],
        a.texels,
        a.face,
        a.tile[0],
        a.tile[1]
    )?;
    Ok(())
}

/// `penumbra verify`: per product what was checked, then one line per problem found.
pub fn print_verify(r: &penumbra::tileset::verify::VerifyReport, json: bool) -> Result<()> {
    if json {
        return print_json(r);
    }
    let mut o = std::io::stdout().lock();
    writeln!(
        o,
        "{:<10} {:>8} {:>12} {:>10} {:>8}",
        "product", "files", "bytes", "identities", "problems"
    )?;
    for (name, s) in &r.products {
        writeln!(
            o,
            "{:<10} {:>8} {:>12} {:>10} {:>8}",
            name, s.files, s.bytes, s.identities, s.problems
        )?;
    }
    writeln!(
        o,
        "{} files, {} bytes checked in {:.2} s: {}",
        r.files,
        r.bytes,
        r.seconds,
        if r.clean() {
            "every file is what the tileset says it is".to_string()
        } else {
            format!("{} problems", r.findings.len())
        }
    )?;
    if !r.clean() {
        writeln!(o)?;
        writeln!(o, "{:<12} {:<8} file: what is wrong", "problem", "product")?;
        for f in &r.findings {
            writeln!(
                o,
                "{:<12} {:<8} {}: {}",
                f.problem, f.product, f.path, f.detail
            )?;
        }
    }
    o.flush()?;
    Ok(())
}

pub fn print_info(dir: &Path, json: bool) -> Result<()> {
    let ts = Tileset::load(dir)?;
    if json {
        return print_json(&ts);
    }
    let mut o = std::io::stdout().lock();
    let l = &ts.layout;
    writeln!(o, "tileset      {}", dir.display())?;
    writeln!(o, "made by      {} {}", ts.tool.name, ts.tool.version)?;
    writeln!(
        o,
        "body         {} (radius {} m; {})",
        ts.body.name, ts.body.radius_m, ts.body.reference
    )?;
    writeln!(
        o,
        "layout       {} cube, {} px tiles + {} px halo, {} levels, {:?} resampling",
        l.projection.name(),
        l.tile_size,
        l.halo,
        l.levels,
        ts.resampling
    )?;
    writeln!(
        o,
        "source       {} ({}×{}, {:.1} m/px)",
        ts.source.format, ts.source.width, ts.source.height, ts.source.pixel_size_m
    )?;
    for f in &ts.source.files {
        writeln!(
            o,
            "             {} ({} bytes, blake3 {}…)",
            f.path,
            f.bytes,
            &f.blake3[..16.min(f.blake3.len())]
        )?;
    }
    writeln!(
        o,
        "voids        {} in the source, {} left as no data; height shift {:+} m",
        ts.source.voids, ts.source.voids_unfilled, ts.source.height_shift_m
    )?;
    if let Some(h) = &ts.products.height {
        writeln!(
            o,
            "height       {:.1} .. {:.1} m; {} filled px, {} no-data px; {}",
            h.min_m, h.max_m, h.filled_pixels, h.no_data_pixels, h.path
        )?;
    }
    if let Some(m) = &ts.products.mip {
        writeln!(
            o,
            "mipmaps      {} ({:?}) {:.1} .. {:.1} m; {}, {}, {}",
            m.products.join("+"),
            m.precision,
            m.global_min_m,
            m.global_max_m,
            m.max_path,
            m.minmax_path,
            m.face_path
        )?;
    }
    if let Some(h) = &ts.products.horizon {
        writeln!(
            o,
            "horizons     levels {:?}, {} azimuths, {} method, {}; {}",
            h.levels, h.azimuths, h.method, h.precision, h.path
        )?;
    }
    if let Some(f) = &ts.products.fourier {
        writeln!(
            o,
            "fourier      levels {:?}, K = {} of {} azimuths, {} {} (sigma {}), {} per tile, {} fully lit tiles, from {} horizons; {}",
            f.levels,
            f.coefficients,
            f.azimuths,
            f.layout,
            f.encoding,
            f.sigma,
            mib(f.bytes_per_tile),
            f.tiles_fully_lit,
            f.source,
            f.path
        )?;
    }
    if let Some(a) = &ts.products.albedo {
        writeln!(
            o,
            "albedo       {}-bit, {} channels from {}; {}",
            a.bit_depth, a.channels, a.source.path, a.path
        )?;
    }
    writeln!(o)?;
    writeln!(
        o,
        "{:>5} {:>12} {:>10} {:>8}  faces",
        "level", "m/px centre", "tiles", "of"
    )?;
    for c in &ts.coverage {
        let faces: Vec<String> = c
            .faces
            .iter()
            .map(|(f, runs)| {
                let n: u32 = runs.iter().map(|r| r[2] - r[1] + 1).sum();
                format!("{f}:{n}")
            })
            .collect();
        writeln!(
            o,
            "{:>5} {:>12.1} {:>10} {:>8}  {}",
            c.level,
            l.centre_pixel_m(c.level, ts.body.radius_m),
            c.tiles,
            6 * c.tiles_per_face,
            faces.join(" ")
        )?;
    }
    Ok(())
}

pub fn print_height(a: &HeightAnswer, json: bool) -> Result<()> {
    if json {
        return print_json(a);
    }
    let mask = ["measured", "filled void", "no data"][a.mask.min(2) as usize];
    writeln!(
        std::io::stdout().lock(),
        "{:.3} m at {}°, {}° (level {}, face {}, tile {}/{}, pixel {:.2},{:.2}; {mask})",
        a.height_m,
        a.lat_deg,
        a.lon_deg,
        a.level,
        a.face,
        a.tile[0],
        a.tile[1],
        a.pixel[0],
        a.pixel[1]
    )?;
    Ok(())
}

/// Tiles per level as `L:count` pairs.
fn per_level(m: &std::collections::BTreeMap<u8, u64>) -> String {
    m.iter()
        .map(|(l, n)| format!("{l}:{n}"))
        .collect::<Vec<_>>()
        .join(" ")
}

fn mb(bytes: u64) -> String {
    format!("{:.1}", bytes as f64 / 1.0e6)
}

/// `penumbra plan`: the stage graph, per product and level the tiles to make, what is left out
/// by which rule, bytes and estimated CPU time.
pub fn print_plan(plan: &penumbra::scene::plan::Plan, wall_s: f64, json: bool) -> Result<()> {
    let r = plan.report();
    if json {
        let mut v = serde_json::to_value(&r)?;
        v["plan_wall_s"] = serde_json::json!(wall_s);
        return print_json(&v);
    }
    let mut out = std::io::stdout().lock();
    let lay = r.layout;
    writeln!(
        out,
        "scene \"{}\" ({}) on {} (R = {} m)",
        r.scene, r.file, r.body.name, r.body.radius_m
    )?;
    writeln!(
        out,
        "layout: {} levels of {}² tiles, halo {}, {}",
        lay.levels,
        lay.tile_size,
        lay.halo,
        lay.projection.name()
    )?;
    writeln!(out, "sources, highest priority first:")?;
    for s in &r.sources {
        writeln!(
            out,
            "  {}: {:.2} m/px, resolves level {} (oversampled up to {}), feather {} px",
            s.label, s.pixel_m, s.native_level, s.max_level, s.feather_px
        )?;
    }
    for g in &r.regions {
        writeln!(
            out,
            "region \"{}\": finest level {}, {} tiles",
            g.name, g.finest_level, g.tiles
        )?;
    }
    writeln!(out, "stages: {}", r.stages.join(" → "))?;
    if !r.horizon_levels.is_empty() && r.stages.len() > 2 {
        writeln!(out, "horizon levels: {:?}", r.horizon_levels)?;
    }
    if let Some(from) = &r.fourier.auto_from {
        writeln!(
            out,
            "fourier: K = {} (auto: the storage {} recommends)",
            r.fourier.coefficients,
            from.display()
        )?;
    }
    if let (Some(lo), Some(rad)) = (r.sun_lowest_deg, r.sun_radius_deg) {
        writeln!(
            out,
            "lowest sun {lo:.2}°, radius {rad:.3}°: horizons below {:.2}° cannot occlude it",
            lo - rad
        )?;
    }
    writeln!(
        out,
        "\n{:<8} {:>5} {:>7} {:>10} {:>12} {:>10}  tiles per level; why",
        "product", "made", "tiles", "raw MB", "disk MB est", "CPU s est"
    )?;
    for p in r.products {
        writeln!(
            out,
            "{:<8} {:>5} {:>7} {:>10} {:>12} {:>10.1}  {}; {}",
            p.product,
            if p.made { "yes" } else { "no" },
            p.tiles.values().sum::<u64>(),
            mb(p.raw_bytes),
            mb(p.disk_bytes_est),
            p.cpu_s_est,
            per_level(&p.tiles),
            p.why.join(", ")
        )?;
    }
    if !r.left_out.is_empty() {
        writeln!(
            out,
            "\nleft out:\n{:<20} {:>7} {:>10} {:>10}  tiles per level; what",
            "rule", "tiles", "raw MB", "CPU s est"
        )?;
        for l in r.left_out {
            writeln!(
                out,
                "{:<20} {:>7} {:>10} {:>10.1}  {}; {}",
                l.rule.name(),
                l.tiles.values().sum::<u64>(),
                mb(l.raw_bytes),
                l.cpu_s_est,
                per_level(&l.tiles),
                l.what
            )?;
        }
    }
    writeln!(
        out,
        "\nmade: {} tiles, {} MB raw (≈ {} MB on disk), ≈ {:.1} CPU s; left out: {} tiles, {} MB \
         raw, ≈ {:.1} CPU s",
        r.made.tiles,
        mb(r.made.raw_bytes),
        mb(r.made.disk_bytes_est),
        r.made.cpu_s_est,
        r.left_out_total.tiles,
        mb(r.left_out_total.raw_bytes),
        r.left_out_total.cpu_s_est
    )?;
    writeln!(out, "rates: {}", r.rates.source)?;
    writeln!(out, "planned in {wall_s:.2} s")?;
    Ok(())
}

/// `penumbra plan SCENE --shards N`: the plan, then each sharded stage cut into N shards (JSON:
/// the plan's object with `shards` added).
pub fn print_plan_shards(
    plan: &penumbra::scene::plan::Plan,
    table: &penumbra::scene::shards::ShardTable,
    wall_s: f64,
    json: bool,
) -> Result<()> {
    if json {
        let mut v = serde_json::to_value(plan.report())?;
        v["plan_wall_s"] = serde_json::json!(wall_s);
        v["shards"] = serde_json::to_value(table)?;
        return print_json(&v);
    }
    print_plan(plan, wall_s, false)?;
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "in {} shards (tiling runs whole first: {:.1} core-s estimated, {:.1} % of the bake):",
        table.count,
        table.tile_cpu_s_est,
        100.0 * table.tile_share
    )?;
    for st in &table.stages {
        writeln!(
            out,
            "  {}: {} units, {:.1} core-s estimated; slowest shard / mean = {:.3}",
            st.stage, st.units, st.cpu_s_est, st.slowest_over_mean
        )?;
        writeln!(
            out,
            "    {:>6} {:>8} {:>12}",
            "shard", "units", "core-s est"
        )?;
        for s in &st.shards {
            writeln!(
                out,
                "    {:>6} {:>8} {:>12.2}",
                format!("{}/{}", s.shard, table.count),
                s.units,
                s.cpu_s_est
            )?;
        }
    }
    Ok(())
}

/// The report of `penumbra export`: the raster written and where.
pub fn print_export(
    r: &penumbra::export::Raster,
    path: &Path,
    bytes: u64,
    gdal: &str,
    wall_s: f64,
    json: bool,
) -> Result<()> {
    if json {
        return print_json(&serde_json::json!({
            "raster": r,
            "path": path,
            "bytes": bytes,
            "gdal": gdal,
            "wall_s": wall_s,
        }));
    }
    let mut o = std::io::stdout().lock();
    let g = &r.geo_transform;
    writeln!(
        o,
        "{}: {} of level {}, {}×{} px of {:.3} m, {}",
        path.display(),
        r.product.name(),
        r.level,
        r.width,
        r.height,
        g[1],
        r.crs.proj4(r.radius_m)
    )?;
    writeln!(
        o,
        "  {} px with data ({:.4} .. {:.4}), {} no data{}; {} MB, GDAL {gdal}, {:.2} s",
        r.data_pixels,
        r.min,
        r.max,
        r.nodata_pixels,
        if r.unknown_pixels > 0 {
            format!(
                " ({} in tiles that keep no horizon for this sun)",
                r.unknown_pixels
            )
        } else {
            String::new()
        },
        mb(bytes),
        wall_s
    )?;
    Ok(())
}

/// `penumbra package`: what the addon holds, per part, with files and bytes; the archive.
pub fn print_package(
    r: &penumbra::package::bundle::PackageReport,
    wall_s: f64,
    json: bool,
) -> Result<()> {
    if json {
        let mut v = serde_json::to_value(r)?;
        v["wall_s"] = serde_json::json!(wall_s);
        v["peak_rss_mib"] = serde_json::json!(peak_rss_mib());
        return print_json(&v);
    }
    let mut o = std::io::stdout().lock();
    let surface = match &r.alt_surface {
        Some(n) => format!("AltSurface \"{n}\" of \"{}/{}\"", r.parent, r.body),
        None => format!("Modify \"{}\" \"{}\"", r.body, r.parent),
    };
    writeln!(
        o,
        "{}: Celestia addon of {} ({surface}){}",
        r.out.display(),
        r.tileset.display(),
        if r.replaced {
            ", replacing the earlier package"
        } else {
            ""
        }
    )?;
    writeln!(o, "{:<34} {:>8} {:>12}  what", "part", "files", "MB")?;
    for t in &r.textures {
        writeln!(
            o,
            "{:<34} {:>8} {:>12}  {} tiles of {} px",
            t.ctx,
            t.tiles,
            mb(t.bytes),
            t.layer,
            r.vt_tile_size
        )?;
    }
    for p in &r.cubemap.products {
        writeln!(
            o,
            "{:<34} {:>8} {:>12}  cube-face product",
            format!("cubemap/ {}", p.product),
            p.files,
            mb(p.bytes)
        )?;
    }
    writeln!(
        o,
        "{:<34} {:>8} {:>12}  {} linked, {} copied, {} checked against the indexes",
        "cubemap/ (all)",
        r.cubemap.files,
        mb(r.cubemap_bytes),
        r.cubemap.linked,
        r.cubemap.copied,
        r.cubemap.verified
    )?;
    writeln!(
        o,
        "{:<34} {:>8} {:>12}  catalog {}, README, marker",
        "package",
        r.files,
        mb(r.bytes),
        r.catalog
    )?;
    let levels: Vec<String> = r
        .vt_levels
        .iter()
        .map(|l| format!("{}<-{}", l.vt_level, l.cube_level))
        .collect();
    writeln!(o, "virtual-texture levels (VT<-cube): {}", levels.join(" "))?;
    if let Some(z) = &r.zip {
        writeln!(
            o,
            "{}: {} entries, {} MB",
            z.path.display(),
            z.entries,
            mb(z.bytes)
        )?;
    }
    writeln!(o, "{wall_s:.2} s")?;
    Ok(())
}

/// What `plan --slurm` wrote: its jobs in order and how to submit them.
pub fn print_slurm(
    dir: &std::path::Path,
    jobs: &[penumbra::scene::slurm::Job],
    table: &penumbra::scene::shards::ShardTable,
    wall_s: f64,
    json: bool,
) -> Result<()> {
    let dir = std::path::absolute(dir)?;
    let submit = dir.join("submit.sh");
    if json {
        return print_json(&serde_json::json!({
            "dir": dir,
            "submit": submit,
            "shards": table.count,
            "jobs": jobs.iter().map(|j| serde_json::json!({"name": j.name, "script": dir.join(&j.file)})).collect::<Vec<_>>(),
            "stages": table,
            "plan_wall_s": wall_s,
        }));
    }
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "wrote a chain of {} Slurm jobs to {} ({wall_s:.2} s):",
        jobs.len(),
        dir.display()
    )?;
    for j in jobs {
        writeln!(out, "  {:<16} {}", j.name, j.file)?;
    }
    writeln!(out, "submit with: {}", submit.display())?;
    Ok(())
}

/// `penumbra report`'s summary: where the files are, the sample, the recommendations, and
/// each product's Pareto front (the whole report: report.md / report.json).
pub fn print_report(r: &crate::report::Report, out: &Path, json: bool) -> Result<()> {
    if json {
        return print_json(r);
    }
    let mut o = std::io::stdout().lock();
    writeln!(
        o,
        "report of {} (level {}, {} azimuths): {} pixels in {} blocks, {:.1} s of a {:.0}-s budget",
        r.tileset,
        r.level,
        r.azimuths,
        r.pixels,
        r.blocks.len(),
        r.elapsed_s,
        r.budget_s
    )?;
    writeln!(
        o,
        "written: {}",
        crate::report::files(out)
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    writeln!(o, "\n{:<16} {:<34} why", "product", "recommended")?;
    for x in &r.recommendations {
        writeln!(
            o,
            "{:<16} {:<34} {}",
            x.product,
            x.choice.as_deref().unwrap_or("none"),
            x.why
        )?;
    }
    writeln!(
        o,
        "\n{:<34} {:>9} {:>8} {:>8} {:>12}",
        "horizon method", "RMS °", "p99 °", "max °", "core-ns/px·az"
    )?;
    for h in &r.horizons {
        writeln!(
            o,
            "{:<34} {:>9.4} {:>8.3} {:>8.2} {:>12.0}{}",
            h.method,
            h.rms_deg,
            h.p99_deg,
            h.max_deg,
            h.core_ns,
            if h.pareto { "  ● Pareto" } else { "" }
        )?;
    }
    writeln!(
        o,
        "\n{:<34} {:>9} {:>8} {:>9} {:>10}",
        "storage (Pareto front)", "bytes", "PER %", "lit MAE", "RMS vs ref"
    )?;
    for f in r.fourier.iter().filter(|f| f.pareto) {
        writeln!(
            o,
            "{:<34} {:>9} {:>8.3} {:>9.5} {:>10.4}",
            f.variant, f.bytes_per_tile, f.per_pct, f.lit_mae, f.rms_ref_deg
        )?;
    }
    writeln!(
        o,
        "\n{:<34} {:>9} {:>8} {:>12}",
        "shadow method", "lit MAE", "PER %", "core-ms/Mpx"
    )?;
    for s in &r.shadows {
        writeln!(
            o,
            "{:<34} {:>9.5} {:>8.3} {:>12.0}{}",
            s.method,
            s.lit_mae,
            s.per_pct,
            s.ms_per_mpx,
            if s.pareto { "  ● Pareto" } else { "" }
        )?;
    }
    for n in &r.notes {
        writeln!(o, "note: {n}")?;
    }
    Ok(())
}

/// The stress catalogue's rows: a table (case, quantity, error, bound, pass) and the failing
/// rows named on stderr, or JSON (`size`, `weaken`, `wall_s`, `passed`, `rows`).
pub fn print_stress(
    rows: &[penumbra::stress::Row],
    size: penumbra::stress::Size,
    weaken: penumbra::stress::Weaken,
    device: Option<&str>,
    wall_s: f64,
    json: bool,
) -> Result<()> {
    let failed: Vec<_> = rows.iter().filter(|r| !r.pass).collect();
    if json {
        return print_json(&serde_json::json!({
            "size": size,
            "weaken": weaken,
            "sweep_device": device.unwrap_or("cpu"),
            "wall_s": wall_s,
            "passed": failed.is_empty(),
            "rows": rows,
        }));
    }
    let mut o = std::io::stdout().lock();
    writeln!(
        o,
        "{:<28} {:<44} {:>10} {:>10} {:<5} {:<4}",
        "case", "quantity", "error", "bound", "unit", "pass"
    )?;
    for r in rows {
        let pass = if r.pass { "ok" } else { "FAIL" };
        let nonfinite = if r.nonfinite > 0 {
            format!(" ({} NaN/Inf)", r.nonfinite)
        } else {
            String::new()
        };
        writeln!(
            o,
            "{:<28} {:<44} {:>10} {:>10} {:<5} {pass}{nonfinite}",
            r.case,
            r.quantity,
            sci(r.error),
            sci(r.bound),
            r.unit
        )?;
    }
    writeln!(
        o,
        "{} rows, {} failed, {wall_s:.2} s ({}{})",
        rows.len(),
        failed.len(),
        match size {
            penumbra::stress::Size::Short => "short sizes",
            penumbra::stress::Size::Full => "full sizes",
        },
        device
            .map(|d| format!("; sweep on {d}"))
            .unwrap_or_default()
    )?;
    o.flush()?;
    for r in &failed {
        eprintln!(
            "penumbra: stress: {} / {}: error {} {} exceeds its bound {}{}",
            r.case,
            r.quantity,
            sci(r.error),
            r.unit,
            sci(r.bound),
            if r.nonfinite > 0 {
                format!(", {} NaN/Inf", r.nonfinite)
            } else {
                String::new()
            }
        );
    }
    Ok(())
}

/// A number in 3 significant digits, scientific ("1.23e-4"), 0 as "0".
fn sci(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else {
        format!("{v:.2e}")
    }
}
