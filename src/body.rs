//! Reference bodies. Heights everywhere in Penumbra are metres above the body's reference sphere
//! (`radius_m`); absolute positions are f64 metres in the body-fixed frame.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// A spherical reference body.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Body {
    /// Lower-case preset name, or "custom".
    pub name: String,
    /// Radius of the reference sphere in metres.
    pub radius_m: f64,
    /// Where the radius comes from.
    pub reference: String,
    /// Lowest and highest terrain relative to the sphere (m), a loose bound used to size
    /// search distances before the data has been read.
    pub relief_m: (f64, f64),
}

struct Preset {
    name: &'static str,
    radius_m: f64,
    reference: &'static str,
    relief_m: (f64, f64),
}

/// Radii are the mean/reference radii of the IAU WGCCRE 2015 report (Archinal et al. 2018,
/// Celest. Mech. Dyn. Astr. 130:22) unless noted; the Moon and Mars values are the reference
/// spheres of the LOLA and MOLA gridded products (LDEM OFFSET, MEGDR A_AXIS_RADIUS family).
const PRESETS: &[Preset] = &[
    Preset {
        name: "moon",
        radius_m: 1_737_400.0,
        reference: "IAU 2015 mean radius; LOLA LDEM reference sphere (OFFSET = 1737400 m)",
        relief_m: (-9_200.0, 10_800.0),
    },
    Preset {
        name: "mars",
        radius_m: 3_396_190.0,
        reference: "IAU 2015 equatorial radius 3396.19 km (MOLA MEGDR heights are areoid-relative)",
        relief_m: (-8_300.0, 21_300.0),
    },
    Preset {
        name: "earth",
        radius_m: 6_371_008.8,
        reference: "IUGG mean radius R1 = 6371.0088 km (SRTM heights are geoid-relative)",
        relief_m: (-11_000.0, 8_900.0),
    },
    Preset {
        name: "mercury",
        radius_m: 2_439_400.0,
        reference: "IAU 2015 mean radius 2439.4 km",
        relief_m: (-5_400.0, 4_600.0),
    },
    Preset {
        name: "venus",
        radius_m: 6_051_800.0,
        reference: "IAU 2015 mean radius 6051.8 km",
        relief_m: (-2_900.0, 11_100.0),
    },
    Preset {
        name: "pluto",
        radius_m: 1_188_300.0,
        reference: "New Horizons (Nimmo et al. 2017) 1188.3 km, IAU 2015",
        relief_m: (-4_000.0, 6_000.0),
    },
    Preset {
        name: "ceres",
        radius_m: 469_700.0,
        reference: "IAU 2015 mean radius 469.7 km",
        relief_m: (-7_300.0, 9_500.0),
    },
    Preset {
        name: "vesta",
        radius_m: 262_700.0,
        reference: "Dawn mean radius 262.7 km (Russell et al. 2012); far from spherical",
        relief_m: (-22_000.0, 22_000.0),
    },
];

/// Margin added on each side of a body's known relief ([`Body::relief_m`]) before a DEM's
/// heights are refused as implausible, as a fraction of the relief's span (bottom to top): half
/// the span, so that the Moon's −9.2..10.8 km accepts −19.2..20.8 km, Mars's −8.3..21.3 km
/// accepts −23.1..36.1 km and Earth's −11..8.9 km accepts −20.95..18.85 km. Wide enough for heights
/// given on another reference (Mars's poles lie 20 km below its equatorial sphere) and far below
/// the audit's nonsense (+62 km lunar peaks from a tripled scale, ±32.7 km from int16 garbage,
/// −1667 km from a lunar datum on Mars). docs/formats.md, "Relief of the body".
pub const RELIEF_MARGIN: f64 = 0.5;

impl Body {
    /// The heights (m above the sphere) a DEM of this body may reach without being asked for:
    /// [`Body::relief_m`] widened by [`RELIEF_MARGIN`] of its span on each side.
    pub fn relief_accepted_m(&self) -> (f64, f64) {
        let (lo, hi) = self.relief_m;
        let m = RELIEF_MARGIN * (hi - lo).abs();
        (lo - m, hi + m)
    }

    /// Names accepted by [`Body::preset`].
    pub fn preset_names() -> Vec<&'static str> {
        PRESETS.iter().map(|p| p.name).collect()
    }

    /// A preset by (case-insensitive) name.
    pub fn preset(name: &str) -> Result<Body> {
        let lower = name.to_ascii_lowercase();
        PRESETS
            .iter()
            .find(|p| p.name == lower)
            .map(|p| Body {
                name: p.name.to_string(),
                radius_m: p.radius_m,
                reference: p.reference.to_string(),
                relief_m: p.relief_m,
            })
            .ok_or_else(|| {
                Error::usage(format!(
                    "unknown body '{name}': use one of {} or give a radius",
                    Self::preset_names().join(", ")
                ))
            })
    }

    /// A body with a caller-given radius (metres). Relief is bounded at ±10% of the radius.
    pub fn custom(name: &str, radius_m: f64) -> Result<Body> {
        if !(radius_m.is_finite() && (1.0..=1.0e9).contains(&radius_m)) {
            return Err(Error::usage(format!(
                "radius {radius_m} m is not a body radius: give 1 m .. 1e9 m"
            )));
        }
        Ok(Body {
            name: name.to_ascii_lowercase(),
            radius_m,
            reference: "given by the user".into(),
            relief_m: (-0.1 * radius_m, 0.1 * radius_m),
        })
    }

    /// Preset `name` with its radius replaced when `radius_m` is given; a bare radius with no
    /// known name makes a custom body.
    pub fn resolve(name: Option<&str>, radius_m: Option<f64>) -> Result<Body> {
        match (name, radius_m) {
            (Some(n), None) => Body::preset(n),
            (Some(n), Some(r)) => match Body::preset(n) {
                Ok(mut b) => {
                    Body::custom(n, r)?;
                    b.radius_m = r;
                    b.reference = format!("radius given by the user (preset {n})");
                    Ok(b)
                }
                Err(_) => Body::custom(n, r),
            },
            (None, Some(r)) => Body::custom("custom", r),
            (None, None) => Err(Error::usage(
                "no body given: name one (moon, mars, earth, …) or give a radius",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_and_custom() {
        assert_eq!(Body::preset("Moon").unwrap().radius_m, 1_737_400.0);
        assert_eq!(Body::preset("pluto").unwrap().radius_m, 1_188_300.0);
        assert!(Body::preset("vulcan").is_err());
        assert_eq!(
            Body::resolve(None, Some(10_000.0)).unwrap().radius_m,
            10_000.0
        );
        assert_eq!(
            Body::resolve(Some("mars"), Some(3_396_000.0))
                .unwrap()
                .radius_m,
            3_396_000.0
        );
        assert!(Body::custom("x", -1.0).is_err());
        assert!(Body::resolve(None, None).is_err());
    }

    /// The accepted ranges quoted in the docs (docs/formats.md, "Relief of the body").
    #[test]
    fn accepted_relief() {
        let r = |n: &str| Body::preset(n).unwrap().relief_accepted_m();
        assert_eq!(r("moon"), (-19_200.0, 20_800.0));
        assert_eq!(r("mars"), (-23_100.0, 36_100.0));
        assert_eq!(r("earth"), (-20_950.0, 18_850.0));
        // A custom body: ±10 % of the radius, widened to ±20 %.
        let c = Body::custom("x", 10_000.0).unwrap().relief_accepted_m();
        assert_eq!(c, (-2_000.0, 2_000.0));
    }
}
