//! Plausibility of a DEM against the body it is tiled for: the body the file names must agree
//! with the file's datum, and the heights must stay within the body's known relief (with a
//! margin, [`crate::body::RELIEF_MARGIN`]) unless the caller says the terrain really reaches
//! further. These catch what the body-independent limits ([`super::limits`]) cannot: a
//! tripled `SCALING_FACTOR` (+62 km lunar peaks), a lunar label renamed `TARGET_NAME = MARS`
//! (−1667 km on Mars), int16 garbage read as ±32.7 km of terrain. docs/formats.md, "Relief of
//! the body".

use super::limits::show;
use super::raster::{HeightAt, HeightExtremes};
use super::Dem;
use crate::body::Body;
use crate::error::{Error, Result};

/// A datum radius may differ from the radius of the body the file names by this fraction
/// (Earth's flattening is 0.34 %, Mars's 0.59 %; another body is tens of percent away).
pub const MAX_TARGET_DATUM_MISMATCH: f64 = 0.02;

/// The keys of a DEM's format that decide its heights and its body, for messages.
struct Keys {
    /// What turns samples into metres.
    scale: &'static str,
    /// Where the body is named.
    target: &'static str,
    /// Where the datum radius is given.
    datum: &'static str,
}

fn keys(format: &str) -> Keys {
    if format.starts_with("PDS3") {
        Keys {
            scale: "SCALING_FACTOR, OFFSET and UNIT",
            target: "TARGET_NAME",
            datum: "OFFSET (above 100 km: the datum radius)",
        }
    } else if format.starts_with("SRTM") {
        Keys {
            scale: "the samples themselves (SRTM samples are metres; a damaged or non-SRTM \
                    file?)",
            target: "the .hgt name (SRTM is Earth)",
            datum: "none",
        }
    } else if format.starts_with("GeoTIFF") {
        Keys {
            scale: "the samples themselves (GeoTIFF samples are read as metres)",
            target: "the body given",
            datum: "none",
        }
    } else {
        Keys {
            scale: "the sidecar's scale/offset (or elevationMin/elevationMax)",
            target: "the sidecar's target",
            datum: "the sidecar's datum_radius_m",
        }
    }
}

impl Dem {
    /// Everything [`Dem::check_plausible`] checks for a sphere of `body.radius_m`, and:
    ///
    /// * a datum radius (PDS3 `OFFSET` above 100 km, sidecar `datum_radius_m`) more than
    ///   [`MAX_TARGET_DATUM_MISMATCH`] away from the radius of the body the file names
    ///   (`TARGET_NAME`, `target`), when that body has a preset: the label contradicts itself;
    /// * measured heights above the body's sphere (the datum shift included) outside
    ///   `allow_relief_m` when given, else outside [`Body::relief_accepted_m`] (the body's known
    ///   relief widened by [`crate::body::RELIEF_MARGIN`]).
    ///
    /// The heights are those of the one pass [`Dem::check_plausible`] makes anyway. The relief
    /// refusal is an [`Error::Param`] on `allow_relief`, naming the source, the extreme found
    /// (height, pixel, DN), the body's range and the keys that scale the samples.
    pub fn check_for_body(&self, body: &Body, allow_relief_m: Option<(f64, f64)>) -> Result<()> {
        let first = self.sources().first().cloned().unwrap_or_default();
        let data = self.sources().last().cloned().unwrap_or_default();
        let keys = keys(self.format());
        if let (Some(t), Some(r0)) = (self.target(), self.datum_radius_m()) {
            if let Ok(named) = Body::preset(t) {
                let off = (r0 - named.radius_m).abs() / named.radius_m;
                if !(off.is_finite() && off <= MAX_TARGET_DATUM_MISMATCH) {
                    return Err(Error::invalid(
                        &first,
                        format!(
                            "{} = {} m contradicts {} = {t}: {t}'s sphere has radius {} m, {:.1} % \
                             away. The file names the wrong body or gives the wrong datum; fix \
                             the one that is wrong (see docs/formats.md, \"Relief of the body\")",
                            keys.datum,
                            show(r0),
                            keys.target,
                            show(named.radius_m),
                            100.0 * off
                        ),
                    ));
                }
            }
        }
        let ext = self.check_plausible(body.radius_m)?;
        if let Some((lo, hi)) = allow_relief_m {
            check_allowed(body, lo, hi)?;
        }
        let (lo, hi, whose) = match allow_relief_m {
            Some((lo, hi)) => (lo, hi, "the relief allowed".to_string()),
            None => {
                let (lo, hi) = body.relief_accepted_m();
                let (klo, khi) = body.relief_m;
                (
                    lo,
                    hi,
                    format!(
                        "{}'s known relief {}..{} m widened by half its span ({}..{} m)",
                        body.name,
                        show(klo),
                        show(khi),
                        show(lo),
                        show(hi)
                    ),
                )
            }
        };
        let out = |e: Option<HeightAt>, low: bool| {
            e.filter(|a| {
                if low {
                    a.height_m < lo
                } else {
                    a.height_m > hi
                }
            })
        };
        let HeightExtremes {
            lowest, highest, ..
        } = ext;
        let Some((a, low)) = out(lowest, true)
            .map(|a| (a, true))
            .or_else(|| out(highest, false).map(|a| (a, false)))
        else {
            return Ok(());
        };
        let (other, other_low) = if low {
            (highest, false)
        } else {
            (lowest, true)
        };
        let range = match other {
            Some(o) => {
                let (l, h) = if other_low {
                    (o.height_m, a.height_m)
                } else {
                    (a.height_m, o.height_m)
                };
                format!("{}..{} m", show(l), show(h))
            }
            None => format!("{} m", show(a.height_m)),
        };
        let shift = self.datum_radius_m().map_or(String::new(), |r0| {
            format!(", datum shift {} m", show(r0 - body.radius_m))
        });
        let name = if data.as_os_str().is_empty() {
            format!("the DEM ({})", self.format())
        } else {
            data.display().to_string()
        };
        let also = if first != data {
            format!(" in {}", first.display())
        } else {
            String::new()
        };
        Err(Error::param(
            "allow_relief",
            format!(
                "is needed for {}: its heights above {}'s sphere span {range}; the {} is {} m at \
                 column {}, row {} (DN {}{shift}), beyond {whose}. Check {}{also}, and that the \
                 DEM is of {} (radius {} m); if the terrain really reaches that far, allow the \
                 relief it covers (MIN,MAX in metres)",
                name,
                body.name,
                if low { "lowest" } else { "highest" },
                show(a.height_m),
                a.col,
                a.row,
                show(self.dn_at(a.col, a.row)),
                keys.scale,
                body.name,
                show(body.radius_m),
            ),
        ))
    }
}

/// An allowed relief `lo..hi` (metres above the body's sphere): finite, `lo < hi`, within ±
/// the body's radius.
pub fn check_allowed(body: &Body, lo: f64, hi: f64) -> Result<()> {
    let r = body.radius_m;
    if !(lo.is_finite() && hi.is_finite() && lo < hi && lo >= -r && hi <= r) {
        return Err(Error::param(
            "allow_relief",
            format!(
                "{},{} is not a relief: give MIN,MAX in metres above the body's sphere, finite, \
                 MIN < MAX, within ± the body's radius ({} m)",
                show(lo),
                show(hi),
                show(r)
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{global_georef as global, synthetic_dem as synthetic};

    /// The extremes, with ties to the first sample in the file, and the relief refused or
    /// allowed around them.
    #[test]
    fn extremes_and_relief() {
        let (w, h) = (64, 32);
        // 30 km peaks at (5, 3) and again at (40, 20); a −25 km pit at (7, 30) and (8, 30).
        let dem = synthetic(w, h, global(w, h), |c, r| match (c, r) {
            (5, 3) | (40, 20) => 30_000.0,
            (7, 30) | (8, 30) => -25_000.0,
            (1, 1) => f32::NAN,
            _ => (c as f32) - (r as f32),
        });
        let e = dem.height_extremes(0.0);
        let at = |a: Option<HeightAt>| a.map(|a| (a.height_m, a.col, a.row));
        assert_eq!(at(e.highest), Some((30_000.0, 5, 3)));
        assert_eq!(at(e.lowest), Some((-25_000.0, 7, 30)));
        assert_eq!(at(e.farthest), Some((30_000.0, 5, 3)));
        // The same answer on one thread (rows are reduced in no fixed order on many).
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        assert_eq!(one.install(|| dem.height_extremes(0.0)), e);

        let moon = Body::preset("moon").unwrap();
        let err = dem.check_for_body(&moon, None).unwrap_err().to_string();
        assert!(
            err.contains("allow_relief") && err.contains("-25000"),
            "{err}"
        );
        dem.check_for_body(&moon, Some((-26_000.0, 31_000.0)))
            .unwrap();
        assert!(dem
            .check_for_body(&moon, Some((-20_000.0, 31_000.0)))
            .is_err());
        // Ranges that are no relief.
        for (lo, hi) in [(1.0, 0.0), (f64::NAN, 1.0), (-2e6, 0.0)] {
            assert!(dem.check_for_body(&moon, Some((lo, hi))).is_err());
        }
        // Vesta (−44..44 km accepted) takes this terrain as it is.
        dem.check_for_body(&Body::preset("vesta").unwrap(), None)
            .unwrap();
    }
}
