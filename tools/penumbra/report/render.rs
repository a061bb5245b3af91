//! A [`Report`] as files: report.html (self-contained: tables and plots as inline SVG drawn
//! by `plotters`), report.md (the same tables, the plots as SVG files beside it) and
//! report.json (everything, for scripts and for `plan`).

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;

use penumbra::error::{Error, Result};

use super::Report;

/// One plot: points (cost, error, label, on the Pareto front, highlighted).
struct Plot<'a> {
    file: &'a str,
    title: String,
    x: &'a str,
    y: &'a str,
    points: Vec<(f64, f64, String, bool, bool)>,
}

/// The range of positive finite values, widened to whole decades (a log axis).
fn decades(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = v
        .filter(|x| x.is_finite() && *x > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(l, h), x| (l.min(x), h.max(x)));
    if !lo.is_finite() {
        return (1e-3, 1.0);
    }
    let lo = 10f64.powf(lo.log10().floor());
    let hi = 10f64.powf(hi.log10().ceil()).max(lo * 10.0);
    (lo, hi)
}

fn draw(p: &Plot) -> std::result::Result<String, String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (760, 440)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        // Errors of 0 (a method against itself) sit at the axis' floor.
        let (x0, x1) = decades(p.points.iter().map(|q| q.0));
        let (y0, y1) = decades(p.points.iter().map(|q| q.1));
        let clamp = |y: f64| if y > 0.0 { y } else { y0 };
        let mut chart = ChartBuilder::on(&root)
            .caption(&p.title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(64)
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc(p.x)
            .y_desc(p.y)
            .x_label_formatter(&|v| format!("{v:.0e}"))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(|e| e.to_string())?;
        let mut front: Vec<(f64, f64)> = p
            .points
            .iter()
            .filter(|q| q.3)
            .map(|q| (q.0, clamp(q.1)))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(front, RED.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RED.stroke_width(2)));
        chart
            .draw_series(
                p.points
                    .iter()
                    .filter(|q| !q.4)
                    .map(|q| Circle::new((q.0, clamp(q.1)), 4, BLUE.mix(0.7).filled())),
            )
            .map_err(|e| e.to_string())?
            .label("measured")
            .legend(|(x, y)| Circle::new((x + 9, y), 4, BLUE.filled()));
        chart
            .draw_series(
                p.points
                    .iter()
                    .filter(|q| q.4)
                    .map(|q| TriangleMarker::new((q.0, clamp(q.1)), 7, GREEN.filled())),
            )
            .map_err(|e| e.to_string())?
            .label("recommended / default")
            .legend(|(x, y)| TriangleMarker::new((x + 9, y), 6, GREEN.filled()));
        // One label per spot: variants that tie (F4 in every layout) would print on top of
        // each other.
        let mut labelled: Vec<(f64, f64)> = Vec::new();
        let mut labels = Vec::new();
        for q in p.points.iter().filter(|q| q.3 || q.4) {
            let near = |&(x, y): &(f64, f64)| {
                (x / q.0).ln().abs() < 0.05 && (y / clamp(q.1)).ln().abs() < 0.05
            };
            if q.4 || !labelled.iter().any(near) {
                labelled.push((q.0, clamp(q.1)));
                labels.push(Text::new(
                    q.2.clone(),
                    (q.0, clamp(q.1)),
                    ("sans-serif", 11),
                ));
            }
        }
        chart.draw_series(labels).map_err(|e| e.to_string())?;
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(svg)
}

fn plots(r: &Report) -> Vec<Plot<'static>> {
    let rec = |product: &str| -> Option<String> {
        r.recommendations
            .iter()
            .find(|x| x.product == product)
            .and_then(|x| x.choice.clone())
    };
    // The reference is the truth (error 0 by definition): it is in the tables, not on a log
    // axis.
    let (hz, fs, sh) = (
        rec("horizon method"),
        // The scene's storage, or where none meets the budget, any layout's.
        rec("horizon storage").or_else(|| rec("horizon storage, any layout")),
        rec("shadow method"),
    );
    vec![
        Plot {
            file: "report-horizons.svg",
            title: format!(
                "Horizon methods: RMS error against cost ({} azimuths)",
                r.azimuths
            ),
            x: "core-ns per pixel·azimuth",
            y: "RMS error against the reference (degrees)",
            points: r
                .horizons
                .iter()
                .filter(|h| h.method != "reference")
                .map(|h| {
                    let hi = hz.as_deref() == Some(h.method.as_str());
                    (h.core_ns, h.rms_deg, h.method.clone(), h.pareto, hi)
                })
                .collect(),
        },
        Plot {
            file: "report-fourier.svg",
            title: "Horizon storage: pixel error rate against bytes per tile".into(),
            x: "bytes per tile",
            y: "pixel error rate at the scene's suns (%)",
            points: r
                .fourier
                .iter()
                .map(|f| {
                    let hi = fs.as_deref() == Some(f.variant.as_str());
                    (
                        f.bytes_per_tile as f64,
                        f.per_pct,
                        f.variant.clone(),
                        f.pareto,
                        hi,
                    )
                })
                .collect(),
        },
        Plot {
            file: "report-shadows.svg",
            title: "Shadow methods: lit-fraction error against time".into(),
            x: "core-ms per megapixel (per pixel and sun)",
            y: "lit-fraction mean absolute error",
            points: r
                .shadows
                .iter()
                .skip(1)
                .map(|s| {
                    let hi = sh.as_deref() == Some(s.method.as_str());
                    (s.ms_per_mpx, s.lit_mae, s.method.clone(), s.pareto, hi)
                })
                .collect(),
        },
    ]
}

/// A figure with its standard error, where there is one.
fn pm(v: f64, se: Option<f64>, digits: usize) -> String {
    match se {
        Some(e) => format!("{v:.digits$} ± {e:.digits$}"),
        None => format!("{v:.digits$}"),
    }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// Tables as (caption, header, rows).
type Table = (String, Vec<&'static str>, Vec<Vec<String>>);

fn tables(r: &Report) -> Vec<Table> {
    let mark = |p: bool| if p { "●".to_string() } else { String::new() };
    vec![
        (
            format!(
                "Horizon methods against the reference at the sampled pixels ({} azimuths)",
                r.azimuths
            ),
            vec![
                "method",
                "samples",
                "RMS °",
                "p99 °",
                "max °",
                "core-ns/px·az",
                "Pareto",
            ],
            r.horizons
                .iter()
                .map(|h| {
                    vec![
                        format!("{}{}", h.method, if h.default { " (default)" } else { "" }),
                        h.samples.to_string(),
                        pm(h.rms_deg, h.se_rms_deg, 4),
                        format!("{:.3}", h.p99_deg),
                        format!("{:.2}", h.max_deg),
                        format!("{:.0}", h.core_ns),
                        mark(h.pareto),
                    ]
                })
                .collect(),
        ),
        (
            "Horizon storage: Fourier pyramids and classic maps (error against the raw map they \
             store, and against the reference)"
                .into(),
            vec![
                "variant",
                "bytes/tile",
                "encode ms/tile",
                "RMS °",
                "p99 °",
                "max °",
                "RMS vs ref °",
                "lit MAE",
                "PER %",
                "Pareto",
            ],
            r.fourier
                .iter()
                .map(|f| {
                    vec![
                        format!("{}{}", f.variant, if f.paper { " (paper)" } else { "" }),
                        f.bytes_per_tile.to_string(),
                        format!("{:.1}", f.encode_ms_per_tile),
                        format!("{:.4}", f.rms_deg),
                        format!("{:.3}", f.p99_deg),
                        format!("{:.2}", f.max_deg),
                        format!("{:.4}", f.rms_ref_deg),
                        pm(f.lit_mae, f.se_lit_mae, 5),
                        pm(f.per_pct, f.se_per_pct, 3),
                        mark(f.pareto),
                    ]
                })
                .collect(),
        ),
        (
            "Shadow methods against the reference at the sampled pixels and the scene's suns"
                .into(),
            vec![
                "method",
                "answers",
                "lit MAE",
                "max",
                "PER %",
                "core-ms/Mpx",
                "Pareto",
            ],
            r.shadows
                .iter()
                .map(|s| {
                    vec![
                        format!("{}{}", s.method, if s.hard { " (hard)" } else { "" }),
                        s.samples.to_string(),
                        pm(s.lit_mae, s.se_lit_mae, 5),
                        format!("{:.3}", s.lit_max),
                        pm(s.per_pct, s.se_per_pct, 3),
                        format!("{:.0}", s.ms_per_mpx),
                        mark(s.pareto),
                    ]
                })
                .collect(),
        ),
    ]
}

/// The horizon methods' errors per stratum of the sample (where the worst ones are).
fn strata_table(r: &Report) -> Table {
    let names: Vec<&str> = r.horizons.iter().map(|h| h.method.as_str()).collect();
    let mut head = vec!["stratum"];
    head.extend(std::iter::repeat_n("RMS ° / max °", names.len()));
    let n = r.horizons.first().map_or(0, |h| h.strata.len());
    let rows = (0..n)
        .map(|k| {
            let mut row = vec![format!(
                "{} ({} px·az)",
                r.horizons[0].strata[k].stratum, r.horizons[0].strata[k].samples
            )];
            for h in &r.horizons {
                let st = &h.strata[k];
                row.push(if st.samples == 0 {
                    "–".into()
                } else {
                    format!("{:.4} / {:.2}", st.rms_deg, st.max_deg)
                });
            }
            row
        })
        .collect();
    (
        format!(
            "Horizon methods by stratum of the sample (columns: {})",
            names.join(", ")
        ),
        head,
        rows,
    )
}

fn summary_lines(r: &Report) -> Vec<String> {
    let mut v = vec![
        format!("Tileset: {}", r.tileset),
        format!(
            "Scene: {}",
            r.scene.as_deref().unwrap_or("none (the tileset alone)")
        ),
        format!(
            "Body: {} (radius {} m); level {} of {}-px tiles; {} azimuths",
            r.body, r.radius_m, r.level, r.tile_size, r.azimuths
        ),
        format!(
            "Suns: elevations {:?}° (storage) and {:?}° (shadows) at compass azimuths {:?}°; \
             the sun's radius {:.3}°",
            r.sun_elevations_deg, r.shadow_sun_elevations_deg, r.sun_azimuths_deg, r.sun_radius_deg
        ),
        format!(
            "Sample: {} pixels in {} blocks (seed {}), stratified by slope and by distance to \
             the data's edge",
            r.pixels,
            r.blocks.len(),
            r.seed
        ),
        format!(
            "Time: {:.1} s of a {:.0}-s budget on {} threads",
            r.elapsed_s, r.budget_s, r.threads
        ),
        format!(
            "Error budget: PER ≤ {} %, horizon RMS ≤ {}°",
            r.max_per_pct, r.max_error_deg
        ),
        "Figures ± one standard error of the mean over the blocks (their spread over √blocks)."
            .into(),
    ];
    v.extend(r.notes.iter().cloned());
    v
}

/// A table as HTML, its caption above.
fn html_table(h: &mut String, (cap, head, rows): &Table) {
    let _ = writeln!(h, "<table><caption>{}</caption><tr>", esc(cap));
    for c in head {
        let _ = write!(h, "<th>{}</th>", esc(c));
    }
    *h += "</tr>\n";
    for row in rows {
        *h += "<tr>";
        for c in row {
            let _ = write!(h, "<td>{}</td>", esc(c));
        }
        *h += "</tr>\n";
    }
    *h += "</table>\n";
}

/// A table as Markdown, its caption as the line before it.
fn md_table(m: &mut String, (cap, head, rows): &Table) {
    let _ = writeln!(m, "{cap}:\n\n| {} |", head.join(" | "));
    let _ = writeln!(m, "|---|{}", "---:|".repeat(head.len() - 1));
    for row in rows {
        let _ = writeln!(m, "| {} |", row.join(" | "));
    }
}

fn html(r: &Report, svgs: &[(Plot, String)]) -> String {
    let mut h = String::new();
    h += "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n";
    let _ = writeln!(h, "<title>penumbra report: {}</title>", esc(&r.tileset));
    h += "<style>body{font-family:sans-serif;max-width:70em;margin:1em auto;padding:0 1em}\
          table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #bbb;\
          padding:2px 6px;text-align:right}td:first-child,th:first-child{text-align:left}\
          caption{text-align:left;font-weight:bold;padding:4px 0}figure{margin:1em 0}\
          .rec{background:#eef7ee;padding:0.5em 1em;border-left:4px solid #393}</style>\n";
    h += "</head><body>\n<h1>penumbra report</h1>\n<ul>\n";
    for l in summary_lines(r) {
        let _ = writeln!(h, "<li>{}</li>", esc(&l));
    }
    h += "</ul>\n<h2>Recommendations</h2>\n<div class=\"rec\"><ul>\n";
    for x in &r.recommendations {
        let _ = writeln!(
            h,
            "<li><b>{}</b>: {} — {}{}</li>",
            esc(&x.product),
            esc(x.choice.as_deref().unwrap_or("none")),
            esc(&x.why),
            x.setting
                .as_ref()
                .map(|s| format!(" (<code>{}</code>)", esc(s)))
                .unwrap_or_default()
        );
    }
    h += "</ul></div>\n";
    for ((p, svg), t) in svgs.iter().zip(tables(r)) {
        let _ = writeln!(h, "<h2>{}</h2>\n<figure>{}</figure>", esc(&p.title), svg);
        html_table(&mut h, &t);
    }
    h += "<h2>By stratum</h2>\n";
    html_table(&mut h, &strata_table(r));
    // Checked by the headless-browser test: every plot laid out with a size.
    h += "<script>window.addEventListener('load',function(){var s=document.querySelectorAll(\
          'figure svg'),n=0;for(var i=0;i<s.length;i++){var b=s[i].getBBox();if(b.width>0&&\
          b.height>0&&s[i].querySelectorAll('circle,polygon,polyline,path').length>0)n++;}\
          document.body.setAttribute('data-plots',n+'/'+s.length);});</script>\n";
    h += "</body></html>\n";
    h
}

fn markdown(r: &Report, svgs: &[(Plot, String)]) -> String {
    let mut m = String::from("# penumbra report\n\n");
    for l in summary_lines(r) {
        let _ = writeln!(m, "- {l}");
    }
    m += "\n## Recommendations\n\n";
    for x in &r.recommendations {
        let _ = writeln!(
            m,
            "- **{}**: {} — {}{}",
            x.product,
            x.choice.as_deref().unwrap_or("none"),
            x.why,
            x.setting
                .as_ref()
                .map(|s| format!(" (`{s}`)"))
                .unwrap_or_default()
        );
    }
    for ((p, _), t) in svgs.iter().zip(tables(r)) {
        let _ = writeln!(m, "\n## {}\n\n![{}]({})\n", p.title, p.title, p.file);
        md_table(&mut m, &t);
    }
    m += "\n## By stratum\n\n";
    md_table(&mut m, &strata_table(r));
    m
}

/// Write the report into `out` (created): report.html, report.md with its three SVG plots,
/// report.json. Each file is written atomically.
pub fn write(r: &Report, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let mut svgs = Vec::new();
    for p in plots(r) {
        let svg = draw(&p).map_err(|e| Error::invalid(out, format!("drawing {}: {e}", p.file)))?;
        svgs.push((p, svg));
    }
    for (p, svg) in &svgs {
        penumbra::fsio::write_atomic_bytes(&out.join(p.file), svg.as_bytes())?;
    }
    penumbra::fsio::write_atomic_bytes(&out.join("report.md"), markdown(r, &svgs).as_bytes())?;
    let json = serde_json::to_vec_pretty(r).expect("reports serialise");
    penumbra::fsio::write_atomic_bytes(&out.join("report.json"), &json)?;
    penumbra::fsio::write_atomic_bytes(&out.join("report.html"), html(r, &svgs).as_bytes())?;
    Ok(())
}
