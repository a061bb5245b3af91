/*!
The catalogue of stiff and extreme cases (`penumbra stress`, docs/stress.md): each case builds a
small terrain whose answer is known analytically (a geometric dip, the top of a cliff or a
spike, a lit fraction of ½, 0 or 1, a Fourier series that reproduces its samples) or by brute
force (a footprint's maximum, the same horizons computed over one rectangle), runs the library's
kernels on it and reports, per quantity, the error, the bound it must stay within and whether it
did. One catalogue, two front ends: the command prints it as a table or JSON, and the
integration tests run every case as its own test.

[`Size::Short`] is what CI and `cargo test` run (seconds); [`Size::Full`] uses the real sizes
(16384² tiles). [`Weaken`] is a test-only switch: a deliberately broken kernel, applied here
in the catalogue (never in the production kernels), that must make cases fail; it proves that
the bounds can fail.
*/

mod fourier;
mod geometry;
mod horizon;
mod shadow;
mod tiles;
mod types;

pub use self::geometry::set_sweep_device;
pub use self::types::{Case, Row, Size, Weaken};
use rayon::prelude::*;

/// The least bound (degrees) of a sweep row whose horizons a device computed in f32: the CPU
/// rows at float accuracy (1e-6° to 8e-6°) are its f64 geometry's; in f32 a slope carries a few
/// ulp of its places (measured on lavapipe: the cliff's top edge 2.0e-6°, the cone's apex along
/// the axes 4.4e-6°, the same pixel over two tiles 1.7e-5°).
pub const DEVICE_FLOOR_DEG: f64 = 3e-5;

/// Every case, in the order the table prints them.
pub fn catalogue() -> Vec<Case> {
    let mut v = Vec::new();
    v.extend(horizon::cases());
    v.extend(shadow::cases());
    v.extend(fourier::cases());
    v.extend(tiles::cases());
    v
}

/// Runs one case: its rows with the case's name and area filled in and `pass` decided.
pub fn run_case(case: &Case, size: Size, weaken: Weaken) -> Vec<Row> {
    let on_device = geometry::sweep_device_set();
    (case.run)(size, weaken)
        .into_iter()
        .map(|mut r| {
            r.case = case.name.to_string();
            r.area = case.area.to_string();
            // The sweep on a device (`--device gpu`) works in f32 throughout: its float-accuracy
            // rows are held to f32's accuracy over the same geometry, not the CPU's f64.
            if on_device && r.unit == "deg" && r.quantity.ends_with(" sweep") {
                r.bound = r.bound.max(DEVICE_FLOOR_DEG);
            }
            r.pass = r.error.is_finite() && r.error <= r.bound && r.nonfinite == 0;
            r
        })
        .collect()
}

/// The cases whose name contains `filter` (all with `None`).
pub fn select(filter: Option<&str>) -> Vec<Case> {
    catalogue()
        .into_iter()
        .filter(|c| filter.is_none_or(|f| c.name.contains(f)))
        .collect()
}

/// Runs `cases` in parallel; the rows come back in the cases' order whatever the thread count.
/// `done(case, rows)` is called as each case finishes (in any order), for progress.
pub fn run(
    cases: &[Case],
    size: Size,
    weaken: Weaken,
    done: &(dyn Fn(&Case, &[Row], f64) + Sync),
) -> Vec<Row> {
    cases
        .par_iter()
        .map(|c| {
            let t0 = std::time::Instant::now();
            let rows = run_case(c, size, weaken);
            done(c, &rows, t0.elapsed().as_secs_f64());
            rows
        })
        .collect::<Vec<_>>()
        .into_iter()
        .flatten()
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_weaken_names_parse() {
        let c = catalogue();
        let mut names: Vec<_> = c.iter().map(|c| c.name).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), c.len());
        for w in Weaken::ALL {
            assert_eq!(Weaken::parse(w.name()), Some(w));
        }
        assert_eq!(Weaken::parse("nonsense"), None);
    }

    #[test]
    fn a_row_fails_on_nan_or_above_its_bound() {
        let case = Case {
            name: "t",
            area: "t",
            about: "",
            run: |_, _| {
                vec![
                    Row::new("ok", "deg", 1.0, 1.0),
                    Row::new("over", "deg", 1.1, 1.0),
                    Row::of("nan", "deg", &[0.0, f64::NAN], 1.0),
                    Row::new("inf count", "deg", 0.0, 1.0).nonfinite(1),
                ]
            },
        };
        let rows = run_case(&case, Size::Short, Weaken::None);
        let pass: Vec<bool> = rows.iter().map(|r| r.pass).collect();
        assert_eq!(pass, [true, false, false, false]);
        assert_eq!(rows[2].nonfinite, 1);
    }
}
