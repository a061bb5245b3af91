//! The sun a scene will see: the Sun's direction in a body's body-fixed frame at a moment, and a
//! conservative range of the sun's elevation over a region and a time span (docs/sun.md).
//!
//! # Frames and time
//! - Directions are unit vectors in the body-fixed frame of [`crate::cube::latlon_to_dir`]:
//!   x towards latitude 0°, longitude 0°, z towards the north pole (the IAU "north" pole, the
//!   one on the north side of the invariable plane), y = z × x (longitude +90°, east).
//!   Latitudes and longitudes are planetocentric, east-positive, in degrees.
//! - Time is TT seconds since J2000.0 (2000-01-01T12:00:00 TT). TDB − TT stays under 1.7 ms and
//!   is ignored (the formulas below take TDB). UTC strings are read by [`utc_to_tt_s`]:
//!   TT − UTC = 32.184 s + (TAI − UTC), with the leap seconds of IERS Bulletin C from
//!   1972-01-01 (10 s) to 2017-01-01 (37 s), so **TT − UTC = 69.184 s for every date after
//!   2017-01-01** (no leap second has been announced since; one more would move the Sun by
//!   0.004° in an Earth scene and by nothing measurable elsewhere). UTC before 1972 is refused.
//!
//! # Models (see [`BODIES`] for the table and its sources)
//! - Orientation: IAU WGCCRE 2015 (Archinal et al. 2018, Celest. Mech. Dyn. Astr. 130:22):
//!   pole right ascension/declination and prime meridian W with every periodic term the report
//!   gives for the Moon, Mars and Mercury. The Earth instead uses the IAU 1976 precession
//!   (Lieske et al. 1977) and the IAU 1982 Greenwich mean sidereal time (Aoki et al. 1982) with
//!   UT1 ≈ UTC, which the WGCCRE's own Earth expressions approximate (their W drifts with ΔT).
//! - Orbits: heliocentric mean elements of JPL's "Keplerian Elements for Approximate Positions
//!   of the Major Planets" (E. M. Standish), Table 2a (3000 BC – 3000 AD), with respect to the
//!   mean ecliptic and equinox of J2000, rotated to the equator by ε = 23.43928°. The Moon and
//!   the Earth use the Earth–Moon barycentre's orbit and their offset from it (the Moon's
//!   geocentric position from the main terms of Meeus, "Astronomical Algorithms", ch. 47): the
//!   offset moves the Sun by up to 0.145° seen from the Moon, 0.002° seen from the Earth.
//! - The direction is geometric (no light time, no aberration: both under 0.006°).

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use crate::cube::{dot, latlon_to_dir, Vec3};
use crate::error::{Error, Result};
use crate::fourier::sun::{sun_radius_deg, AU_KM};

/// Seconds in a Julian day.
const DAY_S: f64 = 86_400.0;
/// Days in a Julian century.
const CENTURY_D: f64 = 36_525.0;
/// TT − TAI (s), exact by definition.
pub const TT_MINUS_TAI_S: f64 = 32.184;
/// Obliquity of the J2000 ecliptic to the ICRF equator used by Standish's elements (degrees).
const OBLIQUITY_J2000_DEG: f64 = 23.43928;
/// Longest span a [`SunSpec::Span`] may cover (Julian years).
pub const MAX_SPAN_YEARS: f64 = 100.0;
/// Earliest UTC accepted (1972-01-01T00:00:00Z, when UTC became TAI minus whole leap seconds).
const FIRST_UTC_YEAR: i64 = 1972;
/// UTC is accepted up to (not including) 2201-01-01: the linear rates of the tables below are
/// fitted for centuries around 2000; Standish's Table 2a holds to 3000 AD.
const LAST_UTC_YEAR: i64 = 2200;

/// The outward error of [`SunPath::range_at`] from sampling alone: the range it returns contains
/// every elevation the model gives over the span, and exceeds the model's true extremes by at
/// most this much on each side (before the model's own accuracy, [`SunPath::accuracy_deg`], is
/// added). It is 2ρ + τ with ρ = 0.0225° (how far the Sun can stray from a piece's uniform path,
/// [`SunPath::new`]) and τ = 0.005° (the search's tolerance).
pub const ELEVATION_MARGIN_DEG: f64 = 0.05;
/// τ: the branch-and-bound search stops refining once no unexplored piece can beat the best
/// bound by more than this.
const SEARCH_TOL_DEG: f64 = 0.005;
/// ρ for the default step: half of the margin left after τ.
const RHO_DEG: f64 = (ELEVATION_MARGIN_DEG - SEARCH_TOL_DEG) / 2.0;
/// Safety factor on the rate bound D of [`SunPath::new`] (covers what the bound leaves out: the
/// slow drift of the orbital elements' rates, TDB − TT, the Moon's eccentric orbit about the
/// barycentre; the test `rate_bound_holds` measures the true rate well inside it).
const RATE_SAFETY: f64 = 1.1;

// ---------------------------------------------------------------------------------------------
// Time

/// Leap seconds: (year, month, TAI − UTC in s from the first day of that month), IERS
/// Bulletin C. The last one was introduced on 2017-01-01.
const LEAP_SECONDS: &[(i64, i64, f64)] = &[
    (1972, 1, 10.0),
    (1972, 7, 11.0),
    (1973, 1, 12.0),
    (1974, 1, 13.0),
    (1975, 1, 14.0),
    (1976, 1, 15.0),
    (1977, 1, 16.0),
    (1978, 1, 17.0),
    (1979, 1, 18.0),
    (1980, 1, 19.0),
    (1981, 7, 20.0),
    (1982, 7, 21.0),
    (1983, 7, 22.0),
    (1985, 7, 23.0),
    (1988, 1, 24.0),
    (1990, 1, 25.0),
    (1991, 1, 26.0),
    (1992, 7, 27.0),
    (1993, 7, 28.0),
    (1994, 7, 29.0),
    (1996, 1, 30.0),
    (1997, 7, 31.0),
    (1999, 1, 32.0),
    (2006, 1, 33.0),
    (2009, 1, 34.0),
    (2012, 7, 35.0),
    (2015, 7, 36.0),
    (2017, 1, 37.0),
];

/// Days from 2000-01-01 to the civil date (proleptic Gregorian; H. Hinnant's algorithm).
fn days_from_2000(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468 - 10_957
}

fn days_in_month(y: i64, m: i64) -> i64 {
    days_from_2000(if m == 12 { y + 1 } else { y }, m % 12 + 1, 1) - days_from_2000(y, m, 1)
}

/// TAI − UTC (s) on the UTC day `days` (days from 2000-01-01); 10 s before 1972.
fn tai_minus_utc_on_day(days: i64) -> f64 {
    LEAP_SECONDS
        .iter()
        .rev()
        .find(|&&(y, m, _)| days >= days_from_2000(y, m, 1))
        .map_or(10.0, |l| l.2)
}

/// TT − UTC (s) at TT seconds since J2000: 32.184 s plus the leap seconds in force (10 s
/// before 1972, where UTC was not yet tied to TAI by whole seconds; 37 s after 2017).
pub fn tt_minus_utc_s(t_tt: f64) -> f64 {
    let tai_utc = LEAP_SECONDS
        .iter()
        .rev()
        .find(|&&(y, m, dat)| {
            // The first TT instant of the month (its UTC label is midnight).
            let utc_label = (days_from_2000(y, m, 1) as f64) * DAY_S - DAY_S / 2.0;
            t_tt >= utc_label + TT_MINUS_TAI_S + dat
        })
        .map_or(10.0, |l| l.2);
    TT_MINUS_TAI_S + tai_utc
}

/// Reads a UTC time in ISO 8601 — `2027-03-01T00:00:00Z`, with optional fractional seconds,
/// `+00:00` in place of `Z`, or a bare date `2027-03-01` (midnight) — and returns TT seconds
/// since J2000.0 (2000-01-01T12:00:00 TT). `23:59:60` is accepted on the days that ended with a
/// leap second. Dates from 1972-01-01 to 2200-12-31.
pub fn utc_to_tt_s(text: &str) -> Result<f64> {
    parse_utc(text).map_err(|m| Error::usage(format!("UTC time '{text}': {m}")))
}

fn parse_utc(text: &str) -> std::result::Result<f64, String> {
    const FORM: &str = "write it as YYYY-MM-DDTHH:MM:SSZ, e.g. 2027-03-01T00:00:00Z";
    let s = text.trim();
    let (date, time) = match s.split_once(['T', 't']) {
        Some((d, t)) => (d, Some(t)),
        None => (s, None),
    };
    let num = |part: &str, what: &str| -> std::result::Result<i64, String> {
        if part.is_empty() || !part.bytes().all(|b| b.is_ascii_digit()) {
            return Err(format!("the {what} '{part}' is not a number; {FORM}"));
        }
        part.parse::<i64>()
            .map_err(|_| format!("the {what} '{part}' is not a number; {FORM}"))
    };
    let mut dp = date.split('-');
    let (Some(ys), Some(ms), Some(ds), None) = (dp.next(), dp.next(), dp.next(), dp.next()) else {
        return Err(format!("the date '{date}' is not YYYY-MM-DD; {FORM}"));
    };
    if ys.len() != 4 || ms.len() != 2 || ds.len() != 2 {
        return Err(format!("the date '{date}' is not YYYY-MM-DD; {FORM}"));
    }
    let (y, m, d) = (num(ys, "year")?, num(ms, "month")?, num(ds, "day")?);
    if !(1..=12).contains(&m) {
        return Err(format!("month {m} is not 01..12"));
    }
    if !(1..=days_in_month(y, m)).contains(&d) {
        return Err(format!("{y:04}-{m:02} has no day {d}"));
    }
    if !(FIRST_UTC_YEAR..=LAST_UTC_YEAR).contains(&y) {
        return Err(format!(
            "year {y} is outside {FIRST_UTC_YEAR}..={LAST_UTC_YEAR} (UTC is tied to TAI by leap \
             seconds from 1972; the rotation and orbit tables are fitted around 2000)"
        ));
    }
    let days = days_from_2000(y, m, d);
    let mut secs = 0.0;
    if let Some(t) = time {
        let clock = if let Some(c) = t.strip_suffix(['Z', 'z']) {
            c
        } else if let Some(c) = t.strip_suffix("+00:00") {
            c
        } else {
            return Err(format!(
                "the time '{t}' has no UTC designator: end it with Z (other offsets are not \
                 read); {FORM}"
            ));
        };
        let mut cp = clock.split(':');
        let (Some(hs), Some(mins)) = (cp.next(), cp.next()) else {
            return Err(format!("the time '{t}' is not HH:MM:SS; {FORM}"));
        };
        let ss = cp.next().unwrap_or("00");
        if cp.next().is_some() || hs.len() != 2 || mins.len() != 2 {
            return Err(format!("the time '{t}' is not HH:MM:SS; {FORM}"));
        }
        let (h, mi) = (num(hs, "hour")?, num(mins, "minute")?);
        let (whole, frac) = match ss.split_once('.') {
            Some((w, f)) => (w, Some(f)),
            None => (ss, None),
        };
        if whole.len() != 2 {
            return Err(format!("the seconds '{ss}' are not SS or SS.fff; {FORM}"));
        }
        let mut sec = num(whole, "second")? as f64;
        if let Some(f) = frac {
            sec += num(f, "fraction of a second")? as f64 / 10f64.powi(f.len().min(300) as i32);
        }
        if h > 23 || mi > 59 {
            return Err(format!("{h:02}:{mi:02} is not a time of day"));
        }
        let leap_day = tai_minus_utc_on_day(days + 1) > tai_minus_utc_on_day(days);
        let max_sec = if leap_day && h == 23 && mi == 59 {
            61.0
        } else {
            60.0
        };
        if sec >= max_sec {
            return Err(format!(
                "second {sec} is out of range (60 only in the leap second that ends a day)"
            ));
        }
        secs = (h * 3600 + mi * 60) as f64 + sec;
    }
    // The UTC label counted from 2000-01-01T12:00:00 plus TT − UTC of that day; a leap second
    // (23:59:60) keeps the day's own TAI − UTC, so it falls one second before the next midnight.
    let label = (days as f64) * DAY_S - DAY_S / 2.0 + secs;
    Ok(label + TT_MINUS_TAI_S + tai_minus_utc_on_day(days))
}

// ---------------------------------------------------------------------------------------------
// The table

/// An orbital element and its rate per Julian century (TDB).
type Element = (f64, f64);

/// Heliocentric mean elements with respect to the mean ecliptic and equinox of J2000: semi-major
/// axis a (AU), eccentricity e, inclination I, mean longitude L, longitude of perihelion ϖ,
/// longitude of the ascending node Ω (degrees), each with its rate per century.
#[derive(Clone, Copy, Debug)]
pub struct Orbit {
    pub a_au: Element,
    pub e: Element,
    pub i_deg: Element,
    pub l_deg: Element,
    pub peri_deg: Element,
    pub node_deg: Element,
}

/// A periodic term `amp · sin(arg0 + rate·d)` (or cos, for the pole's declination), degrees,
/// d in days since J2000.
#[derive(Clone, Copy, Debug)]
pub struct Term {
    pub amp_deg: f64,
    pub arg0_deg: f64,
    pub rate_deg_per_day: f64,
}

const fn term(amp_deg: f64, arg0_deg: f64, rate_deg_per_day: f64) -> Term {
    Term {
        amp_deg,
        arg0_deg,
        rate_deg_per_day,
    }
}

/// A term whose argument rate is given per Julian century (Mars's).
const fn term_cy(amp_deg: f64, arg0_deg: f64, rate_deg_per_century: f64) -> Term {
    term(amp_deg, arg0_deg, rate_deg_per_century / CENTURY_D)
}

/// How a body turns.
#[derive(Clone, Copy, Debug)]
pub enum Spin {
    /// IAU WGCCRE: α0 = ra.0 + ra.1·T + Σ A sin θ, δ0 = dec.0 + dec.1·T + Σ A cos θ,
    /// W = w.0 + w.1·d + w_quad·d² + Σ A sin θ (T in centuries, d in days since J2000, degrees).
    Iau {
        ra: Element,
        dec: Element,
        w: (f64, f64),
        w_quad: f64,
        ra_terms: &'static [Term],
        dec_terms: &'static [Term],
        w_terms: &'static [Term],
    },
    /// The Earth: IAU 1976 precession of the mean pole and IAU 1982 mean sidereal time of UT1
    /// (taken as UTC, within 0.9 s; nutation, ≤ 0.005°, is left out).
    Earth,
}

/// What the body's centre is offset by from the orbit's point (the Earth–Moon barycentre).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Offset {
    None,
    /// The Moon: + its geocentric position · 1/(1 + μ).
    Moon,
    /// The Earth: − the Moon's geocentric position · μ/(1 + μ).
    Earth,
}

/// One row of the table.
#[derive(Clone, Copy, Debug)]
pub struct BodyEphemeris {
    /// The `crate::body` preset name.
    pub name: &'static str,
    pub orbit: Orbit,
    pub spin: Spin,
    pub offset: Offset,
    /// An upper bound of the angle between the body's north pole and its orbit's normal
    /// (its obliquity to its orbit; for the Moon, to the barycentre's orbit) over 1972–2200,
    /// used to bound how fast the Sun drifts from uniform motion ([`SunPath::new`]); the test
    /// `obliquity_bounds_hold` checks it.
    pub obliquity_max_deg: f64,
    /// Accuracy of the Sun's direction from this model (degrees, an upper estimate): the orbit's
    /// error from Standish's table (Table 2a, 3000 BC – 3000 AD: right ascension errors 20″
    /// Mercury, 40″ Venus and the barycentre, 100″ Mars) plus the orientation's.
    pub accuracy_deg: f64,
    /// Where the numbers come from.
    pub source: &'static str,
}

const MOON_E: [(f64, f64); 13] = [
    (125.045, -0.0529921),
    (250.089, -0.1059842),
    (260.008, 13.0120009),
    (176.625, 13.3407154),
    (357.529, 0.9856003),
    (311.589, 26.4057084),
    (134.963, 13.0649930),
    (276.617, 0.3287146),
    (34.226, 1.7484877),
    (15.134, -0.1589763),
    (119.743, 0.0036096),
    (239.961, 0.1643573),
    (25.053, 12.9590088),
];

const fn moon(i: usize, amp: f64) -> Term {
    term(amp, MOON_E[i - 1].0, MOON_E[i - 1].1)
}

const MOON_RA: &[Term] = &[
    moon(1, -3.8787),
    moon(2, -0.1204),
    moon(3, 0.0700),
    moon(4, -0.0172),
    moon(6, 0.0072),
    moon(10, -0.0052),
    moon(13, 0.0043),
];
const MOON_DEC: &[Term] = &[
    moon(1, 1.5419),
    moon(2, 0.0239),
    moon(3, -0.0278),
    moon(4, 0.0068),
    moon(6, -0.0029),
    moon(7, 0.0009),
    moon(10, 0.0008),
    moon(13, -0.0009),
];
const MOON_W: &[Term] = &[
    moon(1, 3.5610),
    moon(2, 0.1208),
    moon(3, -0.0642),
    moon(4, 0.0158),
    moon(5, 0.0252),
    moon(6, -0.0066),
    moon(7, -0.0047),
    moon(8, -0.0046),
    moon(9, 0.0028),
    moon(10, 0.0052),
    moon(11, 0.0040),
    moon(12, 0.0019),
    moon(13, -0.0044),
];
const MARS_RA: &[Term] = &[
    term_cy(0.000068, 198.991226, 19139.4819985),
    term_cy(0.000238, 226.292679, 38280.8511281),
    term_cy(0.000052, 249.663391, 57420.7251593),
    term_cy(0.000009, 266.183510, 76560.6367950),
    term_cy(0.419057, 79.398797, 0.5042615),
];
const MARS_DEC: &[Term] = &[
    term_cy(0.000051, 122.433576, 19139.9407476),
    term_cy(0.000141, 43.058401, 38280.8753272),
    term_cy(0.000031, 57.663379, 57420.7517205),
    term_cy(0.000005, 79.476401, 76560.6495004),
    term_cy(1.591274, 166.325722, 0.5042615),
];
const MARS_W: &[Term] = &[
    term_cy(0.000145, 129.071773, 19140.0328244),
    term_cy(0.000157, 36.352167, 38281.0473591),
    term_cy(0.000040, 56.668646, 57420.9295360),
    term_cy(0.000001, 67.364003, 76560.2552215),
    term_cy(0.000001, 104.792680, 95700.4387578),
    term_cy(0.584542, 95.391654, 0.5042615),
];
const MERCURY_W: &[Term] = &[
    term(0.01067257, 174.7910857, 4.092335),
    term(-0.00112309, 349.5821714, 8.184670),
    term(-0.00011040, 164.3732571, 12.277005),
    term(-0.00002539, 339.1643429, 16.369340),
    term(-0.00000571, 153.9554286, 20.461675),
];

/// Standish, Table 2a: the Earth–Moon barycentre.
const EMB_ORBIT: Orbit = Orbit {
    a_au: (1.00000018, -0.00000003),
    e: (0.01673163, -0.00003661),
    i_deg: (-0.00054346, -0.01337178),
    l_deg: (100.46691572, 35999.37306329),
    peri_deg: (102.93005885, 0.31795260),
    node_deg: (-5.11260389, -0.24123856),
};

/// The bodies whose Sun this module computes. Rotation: IAU WGCCRE 2015 (Archinal et al. 2018,
/// Celest. Mech. Dyn. Astr. 130:22, Table 2 and 3; as in NAIF's pck00011.tpc). Orbits:
/// Standish, "Keplerian Elements for Approximate Positions of the Major Planets", JPL SSD,
/// Table 2a (valid 3000 BC – 3000 AD).
pub const BODIES: &[BodyEphemeris] = &[
    BodyEphemeris {
        name: "moon",
        orbit: EMB_ORBIT,
        spin: Spin::Iau {
            ra: (269.9949, 0.0031),
            dec: (66.5392, 0.0130),
            w: (38.3213, 13.17635815),
            w_quad: -1.4e-12,
            ra_terms: MOON_RA,
            dec_terms: MOON_DEC,
            w_terms: MOON_W,
        },
        offset: Offset::Moon,
        obliquity_max_deg: 1.75,
        // The IAU series follows the mean-Earth/polar-axis frame to about 150 m (WGCCRE; under
        // 300 m from 1550 to 2000 against DE430, J. Irwin on NAIF's list, 2015): 0.01°; the
        // barycentre's orbit 40″ = 0.011°; the Moon's offset model ~0.001°.
        accuracy_deg: 0.025,
        source: "IAU WGCCRE 2015 full lunar series (E1–E13, mean-Earth/polar-axis); Standish \
                 Table 2a Earth–Moon barycentre; Meeus ch. 47 geocentric Moon",
    },
    BodyEphemeris {
        name: "earth",
        orbit: EMB_ORBIT,
        spin: Spin::Earth,
        offset: Offset::Earth,
        obliquity_max_deg: 23.5,
        // Orbit 40″ (0.011°); nutation ≤ 17″ in longitude (0.005°); UT1 − UTC ≤ 0.9 s
        // (0.004°); a future leap second 0.004° each.
        accuracy_deg: 0.03,
        source: "IAU 1976 precession (Lieske et al. 1977), IAU 1982 GMST (Aoki et al. 1982), \
                 UT1 ≈ UTC; Standish Table 2a Earth–Moon barycentre; Meeus ch. 47 Moon",
    },
    BodyEphemeris {
        name: "mars",
        orbit: Orbit {
            a_au: (1.52371243, 0.00000097),
            e: (0.09336511, 0.00009149),
            i_deg: (1.85181869, -0.00724757),
            l_deg: (-4.56813164, 19140.29934243),
            peri_deg: (-23.91744784, 0.45223625),
            node_deg: (49.71320984, -0.26852431),
        },
        spin: Spin::Iau {
            ra: (317.269202, -0.10927547),
            dec: (54.432516, -0.05827105),
            w: (176.049863, 350.891982443297),
            w_quad: 0.0,
            ra_terms: MARS_RA,
            dec_terms: MARS_DEC,
            w_terms: MARS_W,
        },
        offset: Offset::None,
        obliquity_max_deg: 25.5,
        // Orbit 100″ in right ascension (0.028°); the pole and W (Kuchynka et al. 2014) far
        // better.
        accuracy_deg: 0.035,
        source: "IAU WGCCRE 2015 (Kuchynka et al. 2014 pole and prime meridian with all \
                 periodic terms); Standish Table 2a Mars",
    },
    BodyEphemeris {
        name: "mercury",
        orbit: Orbit {
            a_au: (0.38709843, 0.0),
            e: (0.20563661, 0.00002123),
            i_deg: (7.00559432, -0.00590158),
            l_deg: (252.25166724, 149472.67486623),
            peri_deg: (77.45771895, 0.15940013),
            node_deg: (48.33961819, -0.12214182),
        },
        spin: Spin::Iau {
            ra: (281.0103, -0.0328),
            dec: (61.4155, -0.0049),
            w: (329.5988, 6.1385108),
            w_quad: 0.0,
            ra_terms: &[],
            dec_terms: &[],
            w_terms: MERCURY_W,
        },
        offset: Offset::None,
        obliquity_max_deg: 0.1,
        // Orbit 20″ (0.006°); pole and W (Margot 2009, 2012) to ~0.005°.
        accuracy_deg: 0.02,
        source: "IAU WGCCRE 2015 (Margot pole, 3:2 resonance, 88-day libration terms); \
                 Standish Table 2a Mercury",
    },
    BodyEphemeris {
        name: "venus",
        orbit: Orbit {
            a_au: (0.72332102, -0.00000026),
            e: (0.00676399, -0.00005107),
            i_deg: (3.39777545, 0.00043494),
            l_deg: (181.97970850, 58517.81560260),
            peri_deg: (131.76755713, 0.05679648),
            node_deg: (76.67261496, -0.27274174),
        },
        spin: Spin::Iau {
            ra: (272.76, 0.0),
            dec: (67.16, 0.0),
            w: (160.20, -1.4813688),
            w_quad: 0.0,
            ra_terms: &[],
            dec_terms: &[],
            w_terms: &[],
        },
        offset: Offset::None,
        obliquity_max_deg: 2.8,
        // Orbit 40″ (0.011°); the rotation period 243.0185 d is known to ~1e-4 d, which moves
        // W by under 0.01° per decade from the Magellan epoch.
        accuracy_deg: 0.03,
        source: "IAU WGCCRE 2015 (retrograde: W decreases); Standish Table 2a Venus",
    },
];

/// The names [`sun_direction`] and [`SunSpec::Span`] accept.
pub fn body_names() -> Vec<&'static str> {
    BODIES.iter().map(|b| b.name).collect()
}

/// The table's row for `name` (case-insensitive).
pub fn body_ephemeris(name: &str) -> Result<&'static BodyEphemeris> {
    let lower = name.to_ascii_lowercase();
    BODIES.iter().find(|b| b.name == lower).ok_or_else(|| {
        Error::usage(format!(
            "no ephemeris for body '{name}': the sun's motion is known for {}",
            body_names().join(", ")
        ))
    })
}

// ---------------------------------------------------------------------------------------------
// Geometry

const D2R: f64 = PI / 180.0;

#[inline]
fn sind(x: f64) -> f64 {
    (x * D2R).sin()
}

#[inline]
fn cosd(x: f64) -> f64 {
    (x * D2R).cos()
}

/// Frame rotation about x by `a` degrees (the vector's coordinates in the rotated frame).
#[inline]
fn rot1(a: f64, v: Vec3) -> Vec3 {
    let (s, c) = (a * D2R).sin_cos();
    [v[0], c * v[1] + s * v[2], -s * v[1] + c * v[2]]
}

/// Frame rotation about z by `a` degrees.
#[inline]
fn rot3(a: f64, v: Vec3) -> Vec3 {
    let (s, c) = (a * D2R).sin_cos();
    [c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2]]
}

#[inline]
fn norm(v: Vec3) -> f64 {
    dot(v, v).sqrt()
}

#[inline]
fn wrap180(a: f64) -> f64 {
    let w = (a + 180.0).rem_euclid(360.0) - 180.0;
    if w <= -180.0 {
        w + 360.0
    } else {
        w
    }
}

/// J2000 ecliptic → ICRF (J2000 mean equator).
#[inline]
fn ecliptic_to_equator(v: Vec3) -> Vec3 {
    rot1(-OBLIQUITY_J2000_DEG, v)
}

/// Heliocentric position (AU, J2000 ecliptic) from Standish's mean elements at T centuries.
fn kepler_position(o: &Orbit, t_cy: f64) -> Vec3 {
    let el = |x: Element| x.0 + x.1 * t_cy;
    let (a, e, i, l, peri, node) = (
        el(o.a_au),
        el(o.e),
        el(o.i_deg),
        el(o.l_deg),
        el(o.peri_deg),
        el(o.node_deg),
    );
    let w = peri - node;
    let m = wrap180(l - peri) * D2R;
    let mut ea = m + e * m.sin();
    for _ in 0..30 {
        let d = (ea - e * ea.sin() - m) / (1.0 - e * ea.cos());
        ea -= d;
        if d.abs() < 1e-15 {
            break;
        }
    }
    let xp = a * (ea.cos() - e);
    let yp = a * (1.0 - e * e).sqrt() * ea.sin();
    let (sw, cw) = (w * D2R).sin_cos();
    let (sn, cn) = (node * D2R).sin_cos();
    let (si, ci) = (i * D2R).sin_cos();
    [
        (cw * cn - sw * sn * ci) * xp + (-sw * cn - cw * sn * ci) * yp,
        (cw * sn + sw * cn * ci) * xp + (-sw * sn + cw * cn * ci) * yp,
        sw * si * xp + cw * si * yp,
    ]
}

/// The Moon's geocentric position (AU, J2000 ecliptic), from the largest terms of Meeus,
/// "Astronomical Algorithms" (2nd ed.), ch. 47 (about 0.05° in longitude and 0.01° in latitude,
/// 300 km in distance): enough, as the Moon's offset from the barycentre is under 0.003 AU.
fn moon_geocentric(t_cy: f64) -> Vec3 {
    let t = t_cy;
    let lp = 218.3164477 + 481267.88123421 * t;
    let d = 297.8501921 + 445267.1114034 * t;
    let m = 357.5291092 + 35999.0502909 * t;
    let mp = 134.9633964 + 477198.8675055 * t;
    let f = 93.2720950 + 483202.0175233 * t;
    let e = 1.0 - 0.002516 * t;
    // (D, M, M', coefficient of Σl in 1e-6 deg, of Σr in 1e-3 km)
    const LR: [(f64, f64, f64, f64, f64); 12] = [
        (0.0, 0.0, 1.0, 6_288_774.0, -20_905_355.0),
        (2.0, 0.0, -1.0, 1_274_027.0, -3_699_111.0),
        (2.0, 0.0, 0.0, 658_314.0, -2_955_968.0),
        (0.0, 0.0, 2.0, 213_618.0, -569_925.0),
        (0.0, 1.0, 0.0, -185_116.0, 48_888.0),
        (2.0, 0.0, -2.0, 58_793.0, 246_158.0),
        (2.0, -1.0, -1.0, 57_066.0, -152_138.0),
        (2.0, 0.0, 1.0, 53_322.0, -170_733.0),
        (2.0, -1.0, 0.0, 45_758.0, -204_586.0),
        (0.0, 1.0, -1.0, -40_923.0, -129_620.0),
        (1.0, 0.0, 0.0, -34_720.0, 108_743.0),
        (0.0, 1.0, 1.0, -30_383.0, 104_755.0),
    ];
    let mut sl = -114_332.0 * sind(2.0 * f); // the 2F term of Σl
    let mut sr = 0.0;
    for &(cd, cm, cmp, kl, kr) in &LR {
        let arg = cd * d + cm * m + cmp * mp;
        let ef = if cm != 0.0 { e } else { 1.0 };
        sl += kl * ef * sind(arg);
        sr += kr * ef * cosd(arg);
    }
    // (D, M', F, coefficient of Σb in 1e-6 deg)
    const B: [(f64, f64, f64, f64); 8] = [
        (0.0, 0.0, 1.0, 5_128_122.0),
        (0.0, 1.0, 1.0, 280_602.0),
        (0.0, 1.0, -1.0, 277_693.0),
        (2.0, 0.0, -1.0, 173_237.0),
        (2.0, -1.0, 1.0, 55_413.0),
        (2.0, -1.0, -1.0, 46_271.0),
        (2.0, 0.0, 1.0, 32_573.0),
        (0.0, 2.0, 1.0, 17_198.0),
    ];
    let sb: f64 = B
        .iter()
        .map(|&(cd, cmp, cf, k)| k * sind(cd * d + cmp * mp + cf * f))
        .sum();
    // Ecliptic of date → J2000 ecliptic: remove the general precession in longitude.
    let lon = lp + sl * 1e-6 - 1.396_971_3 * t;
    let lat = sb * 1e-6;
    let r_au = (385_000.56 + sr * 1e-3) / AU_KM;
    let (sl, cl) = (lon * D2R).sin_cos();
    let (sb, cb) = (lat * D2R).sin_cos();
    [r_au * cb * cl, r_au * cb * sl, r_au * sb]
}

/// Moon/Earth mass ratio (DE430).
const MOON_EARTH_MASS_RATIO: f64 = 0.012_300_037_1;

/// The body centre's heliocentric position (AU, ICRF).
fn heliocentric(b: &BodyEphemeris, t_tt: f64) -> Vec3 {
    let t_cy = t_tt / DAY_S / CENTURY_D;
    let mut p = kepler_position(&b.orbit, t_cy);
    let k = match b.offset {
        Offset::None => 0.0,
        Offset::Moon => 1.0 / (1.0 + MOON_EARTH_MASS_RATIO),
        Offset::Earth => -MOON_EARTH_MASS_RATIO / (1.0 + MOON_EARTH_MASS_RATIO),
    };
    if k != 0.0 {
        let g = moon_geocentric(t_cy);
        for i in 0..3 {
            p[i] += k * g[i];
        }
    }
    ecliptic_to_equator(p)
}

/// ICRF → body-fixed at TT seconds `t_tt`.
fn to_body_fixed(b: &BodyEphemeris, t_tt: f64, v: Vec3) -> Vec3 {
    let d = t_tt / DAY_S;
    let t_cy = d / CENTURY_D;
    match b.spin {
        Spin::Iau {
            ra,
            dec,
            w,
            w_quad,
            ra_terms,
            dec_terms,
            w_terms,
        } => {
            let arg = |x: &Term| (x.arg0_deg + x.rate_deg_per_day * d) * D2R;
            let a0 = ra.0
                + ra.1 * t_cy
                + ra_terms
                    .iter()
                    .map(|x| x.amp_deg * arg(x).sin())
                    .sum::<f64>();
            let d0 = dec.0
                + dec.1 * t_cy
                + dec_terms
                    .iter()
                    .map(|x| x.amp_deg * arg(x).cos())
                    .sum::<f64>();
            let wd = w.0
                + w.1 * d
                + w_quad * d * d
                + w_terms
                    .iter()
                    .map(|x| x.amp_deg * arg(x).sin())
                    .sum::<f64>();
            rot3(wd.rem_euclid(360.0), rot1(90.0 - d0, rot3(90.0 + a0, v)))
        }
        Spin::Earth => {
            // IAU 1976 precession angles (Lieske et al. 1977), arcseconds.
            let t = t_cy;
            let zeta = (2306.2181 * t + 0.30188 * t * t + 0.017998 * t * t * t) / 3600.0;
            let z = (2306.2181 * t + 1.09468 * t * t + 0.018203 * t * t * t) / 3600.0;
            let theta = (2004.3109 * t - 0.42665 * t * t - 0.041833 * t * t * t) / 3600.0;
            // GMST of UT1 ≈ UTC (IAU 1982; Meeus 12.4), days from J2000.0 UT1.
            let du = (t_tt - tt_minus_utc_s(t_tt)) / DAY_S;
            let tu = du / CENTURY_D;
            let gmst = 280.46061837 + 360.98564736629 * du + 0.000387933 * tu * tu
                - tu * tu * tu / 38_710_000.0;
            // Pole at α0 = −ζ, δ0 = 90° − θ; the node of the mean equator of date on the J2000
            // equator lies at 90° + z from the mean equinox of date, so W = GMST − 90° − z.
            rot3(
                (gmst - 90.0 - z).rem_euclid(360.0),
                rot1(theta, rot3(90.0 - zeta, v)),
            )
        }
    }
}

/// The Sun seen from the body's centre: unit direction (body-fixed) and distance (AU).
fn sun_seen(b: &BodyEphemeris, t_tt: f64) -> (Vec3, f64) {
    let p = heliocentric(b, t_tt);
    let r = norm(p);
    let s = to_body_fixed(b, t_tt, [-p[0] / r, -p[1] / r, -p[2] / r]);
    let n = norm(s);
    ([s[0] / n, s[1] / n, s[2] / n], r)
}

/// Unit vector from the centre of `body` (a name of [`body_names`]) to the Sun's centre, in the
/// body-fixed frame (x to longitude 0, z to the north pole, as [`crate::cube::latlon_to_dir`]),
/// at `t_tt_s_since_j2000` (TT seconds since 2000-01-01T12:00:00 TT; [`utc_to_tt_s`] reads UTC).
/// Geometric, from the models of the module's documentation.
pub fn sun_direction(body: &str, t_tt_s_since_j2000: f64) -> Result<[f64; 3]> {
    let b = body_ephemeris(body)?;
    if !t_tt_s_since_j2000.is_finite() {
        return Err(Error::usage(format!(
            "time {t_tt_s_since_j2000} s is not a time: give TT seconds since J2000"
        )));
    }
    Ok(sun_seen(b, t_tt_s_since_j2000).0)
}

/// The sub-solar point (latitude, longitude in (−180°, 180°], degrees) of a Sun direction.
pub fn subsolar_latlon_deg(dir_to_sun: [f64; 3]) -> (f64, f64) {
    let (lat, lon) = crate::cube::dir_to_latlon(dir_to_sun);
    (lat.to_degrees(), lon.to_degrees())
}

/// Geometric elevation (degrees) of the centre of the Sun's disc above the horizontal plane of
/// the sphere point (`lat_deg`, `lon_deg`), for a unit body-fixed direction to the Sun: the
/// complement of the angle between the Sun and the local vertical, from −90° to 90°.
pub fn sun_elevation_deg(dir_to_sun: [f64; 3], lat_deg: f64, lon_deg: f64) -> f64 {
    let up = latlon_to_dir(lat_deg.to_radians(), lon_deg.to_radians());
    dot(up, dir_to_sun).clamp(-1.0, 1.0).asin().to_degrees()
}

/// The largest angular radius (degrees) the Sun's disc reaches seen from `body`: at the
/// perihelion distance a(1 − e) of its orbit (less the Moon's or Earth's offset from the
/// barycentre), with [`crate::fourier::sun::sun_radius_deg`]. For a scene given as an elevation
/// range, where the dates are unknown.
pub fn sun_radius_bound_deg(body: &str) -> Result<f64> {
    Ok(sun_radius_deg(perihelion_au(body_ephemeris(body)?)))
}

/// The least distance (AU) from the Sun to the body's centre over ±3 centuries: a(1 − e) with
/// the elements' rates, less the Moon's (≤ 0.0027 AU) or the Earth's offset from the barycentre.
fn perihelion_au(b: &BodyEphemeris) -> f64 {
    let o = &b.orbit;
    let a = o.a_au.0 - 3.0 * o.a_au.1.abs();
    let e = o.e.0 + 3.0 * o.e.1.abs();
    let offset = if b.offset == Offset::None {
        0.0
    } else {
        0.0028
    };
    a * (1.0 - e) - offset
}

// ---------------------------------------------------------------------------------------------
// The scene's sun

/// The sun a scene sees: given as a range of elevations (and optionally azimuths), or as a time
/// span on a body whose Sun this module computes. Serialised externally tagged in snake case:
/// `{"range": {"elevation_deg": [0, 10], "azimuth_deg": [350, 10]}}` or
/// `{"span": {"body": "moon", "start_utc": "2027-01-01T00:00:00Z", "end_utc": "2028-01-01T00:00:00Z"}}`
/// (in TOML: a `[sun.range]` or `[sun.span]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum SunSpec {
    /// Every sun of the scene has its centre's elevation in `elevation_deg` (min, max; within
    /// [−90, 90]) and, if given, its compass azimuth (degrees clockwise from north, each in
    /// [0, 360]) in `azimuth_deg` (from, to), clockwise from the first to the second: (350, 10)
    /// is the 20° around north.
    Range {
        elevation_deg: (f64, f64),
        #[serde(default, skip_serializing_if = "Option::is_none")]
        azimuth_deg: Option<(f64, f64)>,
    },
    /// Every moment from `start_utc` to `end_utc` (ISO 8601 UTC, [`utc_to_tt_s`]) on `body`.
    Span {
        body: String,
        start_utc: String,
        end_utc: String,
    },
}

impl SunSpec {
    /// Checks the spec: elevations within [−90, 90] with min ≤ max, azimuths within [0, 360],
    /// a known body, readable UTC times with the end after the start and at most
    /// [`MAX_SPAN_YEARS`] later. The error names the field.
    pub fn validate(&self) -> Result<()> {
        match self {
            SunSpec::Range {
                elevation_deg: (lo, hi),
                azimuth_deg,
            } => {
                for v in [lo, hi] {
                    if !(v.is_finite() && (-90.0..=90.0).contains(v)) {
                        return Err(Error::param(
                            "elevation_deg",
                            format!("[{lo}, {hi}]: {v} is not an elevation; give degrees within [-90, 90]"),
                        ));
                    }
                }
                if lo > hi {
                    return Err(Error::param(
                        "elevation_deg",
                        format!("[{lo}, {hi}]: the minimum is above the maximum; give [min, max]"),
                    ));
                }
                if let Some((a, b)) = azimuth_deg {
                    for v in [a, b] {
                        if !(v.is_finite() && (0.0..=360.0).contains(v)) {
                            return Err(Error::param(
                                "azimuth_deg",
                                format!(
                                    "[{a}, {b}]: {v} is not a compass azimuth; give degrees within \
                                     [0, 360] (a range may wrap through north: [350, 10])"
                                ),
                            ));
                        }
                    }
                }
                Ok(())
            }
            SunSpec::Span { .. } => self.span_tt().map(|_| ()),
        }
    }

    /// For a span: its body's table row and TT seconds of its start and end, checked.
    fn span_tt(&self) -> Result<Option<(&'static BodyEphemeris, f64, f64)>> {
        let SunSpec::Span {
            body,
            start_utc,
            end_utc,
        } = self
        else {
            return Ok(None);
        };
        let b = body_ephemeris(body).map_err(|_| {
            Error::param(
                "body",
                format!(
                    "'{body}' has no ephemeris here: the sun's motion is known for {}",
                    body_names().join(", ")
                ),
            )
        })?;
        let t0 = parse_utc(start_utc)
            .map_err(|m| Error::param("start_utc", format!("'{start_utc}': {m}")))?;
        let t1 =
            parse_utc(end_utc).map_err(|m| Error::param("end_utc", format!("'{end_utc}': {m}")))?;
        if t1 <= t0 {
            return Err(Error::param(
                "end_utc",
                format!("'{end_utc}' is not after start_utc '{start_utc}'"),
            ));
        }
        let years = (t1 - t0) / DAY_S / 365.25;
        if years > MAX_SPAN_YEARS {
            return Err(Error::param(
                "end_utc",
                format!(
                    "'{end_utc}' is {years:.1} years after start_utc '{start_utc}': a span covers \
                     at most {MAX_SPAN_YEARS} years"
                ),
            ));
        }
        Ok(Some((b, t0, t1)))
    }
}

/// The range of sun elevations (degrees; min, max) a scene sees over a region: for
/// [`SunSpec::Range`] its elevations as given (the points do not matter); for
/// [`SunSpec::Span`] a conservative bound over every point of `points` (latitude, longitude in
/// degrees: the region's sample points) and every moment of the span ([`SunPath::range_over`]),
/// with pieces of `step_s` seconds (None: chosen from the body's motion so that the range is
/// within [`ELEVATION_MARGIN_DEG`] of the model's, [`SunPath::new`]).
pub fn elevation_range(
    spec: &SunSpec,
    points: &[(f64, f64)],
    step_s: Option<f64>,
) -> Result<(f64, f64)> {
    spec.validate()?;
    match spec {
        SunSpec::Range { elevation_deg, .. } => Ok(*elevation_deg),
        SunSpec::Span { .. } => {
            let (b, t0, t1) = spec.span_tt()?.expect("a span");
            SunPath::build(b, t0, t1, step_s)?.range_over(points)
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The Sun over a span

/// A piece of the span: the Sun at the piece's middle (latitude and unwrapped longitude of the
/// sub-solar point, degrees).
#[derive(Clone, Copy, Debug)]
struct Leaf {
    lon: f64,
    /// Sine and cosine of the latitude.
    sin: f64,
    cos: f64,
}

/// A group of pieces: a latitude band and a longitude arc (unwrapped) that hold every Sun
/// direction of its pieces.
#[derive(Clone, Copy, Debug)]
struct Band {
    lat_lo: f64,
    lat_hi: f64,
    lon_lo: f64,
    lon_hi: f64,
}

/// A [`Band`] as the search reads it: the band's edges as (cos, sin) and the arc's centre and
/// half-width (≥ 180: the whole circle).
#[derive(Clone, Copy, Debug)]
struct Node {
    band: Band,
    lo: (f64, f64),
    hi: (f64, f64),
    centre: f64,
    half: f64,
}

impl Node {
    fn new(band: Band) -> Node {
        let (lo, hi) = (band.lat_lo.max(-90.0), band.lat_hi.min(90.0));
        let (sl, cl) = (lo * D2R).sin_cos();
        let (sh, ch) = (hi * D2R).sin_cos();
        let width = band.lon_hi - band.lon_lo;
        Node {
            band,
            lo: (cl, sl),
            hi: (ch, sh),
            centre: 0.5 * (band.lon_lo + band.lon_hi),
            half: if width >= 360.0 { 180.0 } else { 0.5 * width },
        }
    }
}

/// Children per node.
const FAN: usize = 8;

/// The Sun's sub-solar path over a time span on one body, cut into pieces for fast, conservative
/// elevation ranges at any point.
///
/// # The bound
/// Let ω be the sub-solar point's mean westward rate (the body's spin rate less its orbital
/// mean motion: 360°/solar day) and q(t) the Sun's direction turned back by ω·t about the pole.
/// q moves slowly: its rate is at most D = |ν̇ − n|max + 2n·sin(ε/2) + (the pole's and
/// prime meridian's periodic rates) + (the Moon's or Earth's motion about the barycentre),
/// times 1.1 — n the mean motion, ν̇ the true anomaly's rate (n(1 ± e)²/(1 − e²)^{3/2}), ε the
/// body's obliquity to its orbit ([`BodyEphemeris::obliquity_max_deg`]). So over a piece of
/// length H centred on t_m the Sun stays within ρ = D·H/2 of the *uniform path*: latitude fixed
/// at the sub-solar latitude of t_m, longitude sweeping λ_m ± ω·H/2. The elevation at a point
/// along a uniform path is exact in closed form (its extremes are where the longitude arc comes
/// nearest to and farthest from the point's meridian), and the true elevation is within ρ of it.
/// H is chosen so that ρ = 0.0225° (the Earth keeps 0.0042° of it for the one-second steps of
/// UT1 ≈ UTC at leap seconds).
///
/// Pieces are grouped FAN at a time into a tree of latitude bands × longitude arcs holding their
/// paths widened by ρ; a point's extremes are found by best-first branch and bound: a group is
/// opened only if its bound could beat the best piece by more than τ = 0.005°. The result
/// contains the model's true range and exceeds it by at most 2ρ + τ = [`ELEVATION_MARGIN_DEG`]
/// per side; [`SunPath::range_at`] then widens it by the model's accuracy.
#[derive(Clone, Debug)]
pub struct SunPath {
    body: &'static str,
    t0: f64,
    t1: f64,
    leaves: Vec<Leaf>,
    /// Half-width of each piece's longitude arc (degrees).
    half_arc: f64,
    /// ρ (degrees).
    rho: f64,
    /// The tree, bottom level first (level 0 groups the leaves).
    levels: Vec<Vec<Node>>,
    accuracy: f64,
    radius: (f64, f64),
}

/// The per-body rates of [`SunPath`]'s bound (degrees per day): (ω, D).
fn path_rates(b: &BodyEphemeris) -> (f64, f64) {
    let o = &b.orbit;
    let n = o.l_deg.1 / CENTURY_D;
    let e = o.e.0 + 3.0 * o.e.1.abs();
    let nu_dev = n * ((1.0 + e).powi(2) / (1.0 - e * e).powf(1.5) - 1.0);
    let tilt = 2.0 * n * (b.obliquity_max_deg / 2.0 * D2R).sin();
    let elements = (o.i_deg.1.abs() + o.peri_deg.1.abs() + o.node_deg.1.abs()) / CENTURY_D;
    let offset = match b.offset {
        // The Moon's speed about the barycentre, ≤ 1.1 km/s, over ≥ 0.98 AU.
        Offset::Moon => 0.05,
        Offset::Earth => 0.001,
        Offset::None => 0.0,
    };
    let (spin, frame) = match b.spin {
        Spin::Iau {
            ra,
            dec,
            w,
            w_quad,
            ra_terms,
            dec_terms,
            w_terms,
        } => {
            let periodic: f64 = ra_terms
                .iter()
                .chain(dec_terms)
                .chain(w_terms)
                .map(|x| (x.amp_deg * x.rate_deg_per_day * D2R).abs())
                .sum();
            // |2·w_quad·d| over ±300 years.
            let quad = 2.0 * w_quad.abs() * 3.0 * CENTURY_D * 100.0;
            (
                w.1,
                periodic + (ra.1.abs() + dec.1.abs()) / CENTURY_D + quad,
            )
        }
        // GMST's rate; the precession angles' rates (ζ + z + θ ≈ 1.84°/century).
        Spin::Earth => (360.98564736629, 2.0 / CENTURY_D),
    };
    let omega = spin - n;
    (
        omega,
        RATE_SAFETY * (nu_dev + tilt + elements + offset + frame),
    )
}

/// ρ set aside for the Earth's one-second steps of UT1 ≈ UTC at leap seconds (degrees).
fn step_allowance(b: &BodyEphemeris) -> f64 {
    match b.spin {
        Spin::Earth => 360.985_647_4 / DAY_S * 1.0,
        Spin::Iau { .. } => 0.0,
    }
}

impl SunPath {
    /// The Sun over TT seconds `t0_tt`..`t1_tt` on `body`, in pieces of `step_s` seconds (None:
    /// the longest for which ρ = 0.0225°; see the type's documentation). Errors on an unknown
    /// body, a span that is empty, inverted or over [`MAX_SPAN_YEARS`], or a step that is not
    /// positive.
    pub fn new(body: &str, t0_tt: f64, t1_tt: f64, step_s: Option<f64>) -> Result<SunPath> {
        let b = body_ephemeris(body)?;
        if !(t0_tt.is_finite() && t1_tt.is_finite() && t1_tt > t0_tt) {
            return Err(Error::usage(format!(
                "the span {t0_tt} s .. {t1_tt} s is not a time span: the end must follow the start"
            )));
        }
        if (t1_tt - t0_tt) / DAY_S / 365.25 > MAX_SPAN_YEARS {
            return Err(Error::usage(format!(
                "the span {t0_tt} s .. {t1_tt} s is longer than {MAX_SPAN_YEARS} years"
            )));
        }
        SunPath::build(b, t0_tt, t1_tt, step_s)
    }

    /// [`SunPath::new`] from a [`SunSpec::Span`] (validated); None for a range.
    pub fn from_spec(spec: &SunSpec, step_s: Option<f64>) -> Result<Option<SunPath>> {
        spec.validate()?;
        match spec.span_tt()? {
            Some((b, t0, t1)) => SunPath::build(b, t0, t1, step_s).map(Some),
            None => Ok(None),
        }
    }

    fn build(b: &'static BodyEphemeris, t0: f64, t1: f64, step_s: Option<f64>) -> Result<SunPath> {
        let (omega, d_rate) = path_rates(b);
        let allowance = step_allowance(b);
        let span = t1 - t0;
        let h_max = match step_s {
            None => 2.0 * (RHO_DEG - allowance) / d_rate * DAY_S,
            Some(s) if s.is_finite() && s >= 1.0 => s,
            Some(s) => {
                return Err(Error::param(
                    "step_s",
                    format!("{s} is not a time step: give seconds ≥ 1 (or none to choose it)"),
                ))
            }
        };
        let count = (span / h_max).ceil().max(1.0);
        if count > 10_000_000.0 {
            return Err(Error::param(
                "step_s",
                format!("{h_max} s cuts the span into {count} pieces: give a longer step"),
            ));
        }
        let count = count as usize;
        let h = span / count as f64;
        let h_days = h / DAY_S;
        let rho = d_rate * h_days / 2.0 + allowance;
        let half_arc = (omega.abs() * h_days / 2.0).min(180.0);
        let mut leaves = Vec::with_capacity(count);
        let mut lats = Vec::with_capacity(count);
        let (mut r_min, mut r_max) = (f64::INFINITY, 0.0f64);
        let mut prev: Option<f64> = None;
        for k in 0..count {
            let t = t0 + (k as f64 + 0.5) * h;
            let (s, r) = sun_seen(b, t);
            r_min = r_min.min(r);
            r_max = r_max.max(r);
            let (lat, lon) = subsolar_latlon_deg(s);
            let lon = match prev {
                None => lon,
                Some(p) => {
                    let expect = p - omega * h_days;
                    expect + wrap180(lon - expect)
                }
            };
            prev = Some(lon);
            let (sin, cos) = (lat * D2R).sin_cos();
            lats.push(lat);
            leaves.push(Leaf { lon, sin, cos });
        }
        // The distance moves at most a·e·n (AU/day, n in radians) between piece centres.
        let o = &b.orbit;
        let dr = o.a_au.0 * (o.e.0 + 0.01) * (o.l_deg.1 / CENTURY_D * D2R) * h_days / 2.0
            + if b.offset == Offset::None {
                0.0
            } else {
                1e-5 * h_days
            };
        let radius = (
            sun_radius_deg(r_max + dr),
            sun_radius_deg((r_min - dr).max(perihelion_au(b))),
        );

        // The tree: level 0 groups FAN leaves.
        let mut levels: Vec<Vec<Node>> = Vec::new();
        let base: Vec<Node> = leaves
            .chunks(FAN)
            .zip(lats.chunks(FAN))
            .map(|(c, lc)| {
                let mut n = Band {
                    lat_lo: f64::INFINITY,
                    lat_hi: f64::NEG_INFINITY,
                    lon_lo: f64::INFINITY,
                    lon_hi: f64::NEG_INFINITY,
                };
                let mut lat_abs = 0.0f64;
                for (l, &lat) in c.iter().zip(lc) {
                    n.lat_lo = n.lat_lo.min(lat - rho);
                    n.lat_hi = n.lat_hi.max(lat + rho);
                    n.lon_lo = n.lon_lo.min(l.lon - half_arc);
                    n.lon_hi = n.lon_hi.max(l.lon + half_arc);
                    lat_abs = lat_abs.max(lat.abs());
                }
                // A cap of radius ρ around a point at latitude δ spans asin(sin ρ / cos δ) of
                // longitude either side, or all of it when it holds a pole.
                let (sr, cd) = ((rho * D2R).sin(), ((lat_abs + rho).min(90.0) * D2R).cos());
                let ext = if cd > sr {
                    (sr / cd).asin().to_degrees()
                } else {
                    360.0
                };
                n.lon_lo -= ext;
                n.lon_hi += ext;
                Node::new(n)
            })
            .collect();
        levels.push(base);
        while levels.last().expect("a level").len() > 1 {
            let up: Vec<Node> = levels
                .last()
                .expect("a level")
                .chunks(FAN)
                .map(|c| {
                    let fold = |f: fn(&Band) -> f64, init: f64, g: fn(f64, f64) -> f64| {
                        c.iter().map(|n| f(&n.band)).fold(init, g)
                    };
                    Node::new(Band {
                        lat_lo: fold(|b| b.lat_lo, f64::INFINITY, f64::min),
                        lat_hi: fold(|b| b.lat_hi, f64::NEG_INFINITY, f64::max),
                        lon_lo: fold(|b| b.lon_lo, f64::INFINITY, f64::min),
                        lon_hi: fold(|b| b.lon_hi, f64::NEG_INFINITY, f64::max),
                    })
                })
                .collect();
            levels.push(up);
        }
        Ok(SunPath {
            body: b.name,
            t0,
            t1,
            leaves,
            half_arc,
            rho,
            levels,
            accuracy: b.accuracy_deg,
            radius,
        })
    }

    /// The body's name.
    pub fn body(&self) -> &'static str {
        self.body
    }

    /// The span (TT seconds since J2000).
    pub fn span_tt(&self) -> (f64, f64) {
        (self.t0, self.t1)
    }

    /// How many pieces the span was cut into.
    pub fn pieces(&self) -> usize {
        self.leaves.len()
    }

    /// The outward sampling error bound of [`SunPath::range_at`] per side, 2ρ + τ (degrees):
    /// [`ELEVATION_MARGIN_DEG`] for the default step.
    pub fn margin_deg(&self) -> f64 {
        2.0 * self.rho + SEARCH_TOL_DEG
    }

    /// The model's accuracy that [`SunPath::range_at`] adds on each side (degrees,
    /// [`BodyEphemeris::accuracy_deg`]).
    pub fn accuracy_deg(&self) -> f64 {
        self.accuracy
    }

    /// The Sun's angular radius over the span (degrees; smallest, largest), from its distance
    /// with [`crate::fourier::sun::sun_radius_deg`].
    pub fn sun_radius_deg(&self) -> (f64, f64) {
        self.radius
    }

    /// The range (min, max; degrees) of the sun's centre's elevation at the sphere point
    /// (`lat_deg`, `lon_deg`) over the span, conservative: it holds every elevation of the
    /// model, widened by the model's accuracy, and exceeds the model's extremes by at most
    /// [`SunPath::margin_deg`] + [`SunPath::accuracy_deg`] per side. Clamped to [−90, 90].
    pub fn range_at(&self, lat_deg: f64, lon_deg: f64) -> (f64, f64) {
        let (sp, cp) = (lat_deg * D2R).sin_cos();
        let p = Point {
            sp,
            cp,
            lon: lon_deg,
        };
        let hi = self.search(&p, true);
        let lo = -self.search(&p, false);
        (
            (lo - self.accuracy).clamp(-90.0, 90.0),
            (hi + self.accuracy).clamp(-90.0, 90.0),
        )
    }

    /// [`SunPath::range_at`] over every point (latitude, longitude in degrees): the lowest low
    /// and the highest high. Errors on no points or a latitude outside [−90, 90].
    pub fn range_over(&self, points: &[(f64, f64)]) -> Result<(f64, f64)> {
        if points.is_empty() {
            return Err(Error::param(
                "points",
                "is empty: give the region's sample points (latitude, longitude in degrees)",
            ));
        }
        let mut out = (f64::INFINITY, f64::NEG_INFINITY);
        for &(lat, lon) in points {
            if !(lat.is_finite() && lon.is_finite() && (-90.0..=90.0).contains(&lat)) {
                return Err(Error::param(
                    "points",
                    format!("({lat}, {lon}) is not a latitude/longitude in degrees"),
                ));
            }
            let (lo, hi) = self.range_at(lat, lon);
            out = (out.0.min(lo), out.1.max(hi));
        }
        Ok(out)
    }

    /// Best-first branch and bound for the highest elevation (`upper`) or the negated lowest.
    fn search(&self, p: &Point, upper: bool) -> f64 {
        let mut heap = BinaryHeap::new();
        let top = self.levels.len() - 1;
        for (i, n) in self.levels[top].iter().enumerate() {
            heap.push(Entry {
                key: node_bound(p, n, upper),
                level: top,
                index: i,
            });
        }
        let mut best = f64::NEG_INFINITY;
        while let Some(e) = heap.pop() {
            if e.key <= best + SEARCH_TOL_DEG {
                // Nothing left can exceed e.key: report it if it beats the best piece.
                return best.max(e.key);
            }
            let from = e.index * FAN;
            if e.level == 0 {
                let to = (from + FAN).min(self.leaves.len());
                for l in &self.leaves[from..to] {
                    best = best.max(leaf_bound(p, l, self.half_arc, upper) + self.rho);
                }
            } else {
                let below = &self.levels[e.level - 1];
                let to = (from + FAN).min(below.len());
                for (i, n) in below[from..to].iter().enumerate() {
                    heap.push(Entry {
                        key: node_bound(p, n, upper),
                        level: e.level - 1,
                        index: from + i,
                    });
                }
            }
        }
        best
    }
}

/// A query point: sine and cosine of its latitude, its longitude (degrees).
struct Point {
    sp: f64,
    cp: f64,
    lon: f64,
}

#[derive(Debug)]
struct Entry {
    key: f64,
    level: usize,
    index: usize,
}

impl PartialEq for Entry {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        self.key
            .total_cmp(&o.key)
            .then(o.level.cmp(&self.level))
            .then(o.index.cmp(&self.index))
    }
}

/// Nearest and farthest longitude offsets (degrees, in [0, 180]) from `lon` to the arc
/// centred on `centre` of half-width `half` (≥ 180: the whole circle).
#[inline]
fn arc_offsets(lon: f64, centre: f64, half: f64) -> (f64, f64) {
    if half >= 180.0 {
        return (0.0, 180.0);
    }
    let d = wrap180(lon - centre).abs();
    ((d - half).max(0.0), (d + half).min(180.0))
}

#[inline]
fn asind(x: f64) -> f64 {
    x.clamp(-1.0, 1.0).asin().to_degrees()
}

/// The highest elevation (`upper`) or the negated lowest (degrees) along a piece's uniform
/// path: the Sun at the arc's nearest or farthest longitude offset.
#[inline]
fn leaf_bound(p: &Point, l: &Leaf, half_arc: f64, upper: bool) -> f64 {
    let (near, far) = arc_offsets(p.lon, l.lon, half_arc);
    let dl = if upper { near } else { far };
    let s = p.sp * l.sin + p.cp * l.cos * (dl * D2R).cos();
    if upper {
        asind(s)
    } else {
        -asind(s)
    }
}

/// The highest elevation (`upper`) or the negated lowest (degrees) of a Sun anywhere in a
/// node's latitude band × longitude arc. For any latitude δ the elevation is highest at the
/// arc's nearest longitude offset Δ and lowest at its farthest; for a fixed Δ,
/// sin e = sin φ sin δ + cos φ cos δ cos Δ = v·(cos δ, sin δ) with v = (cos φ cos Δ, sin φ):
/// over the band it is largest at |v| when v's direction lies in the band (and smallest at −|v|
/// when −v's does), and otherwise at an edge of the band.
#[inline]
fn node_bound(p: &Point, n: &Node, upper: bool) -> f64 {
    let (near, far) = arc_offsets(p.lon, n.centre, n.half);
    let dl = if upper { near } else { far };
    let v = (p.cp * (dl * D2R).cos(), p.sp);
    let at = |e: (f64, f64)| v.0 * e.0 + v.1 * e.1;
    // v's direction lies in the band [lo, hi] (narrower than 180°) when it is counter-clockwise
    // of lo and clockwise of hi.
    let inside =
        |w: (f64, f64)| n.lo.0 * w.1 - n.lo.1 * w.0 >= 0.0 && w.0 * n.hi.1 - w.1 * n.hi.0 >= 0.0;
    if upper {
        let s = if inside(v) {
            (v.0 * v.0 + v.1 * v.1).sqrt()
        } else {
            at(n.lo).max(at(n.hi))
        };
        asind(s)
    } else {
        let s = if inside((-v.0, -v.1)) {
            -(v.0 * v.0 + v.1 * v.1).sqrt()
        } else {
            at(n.lo).min(at(n.hi))
        };
        -asind(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tt(s: &str) -> f64 {
        utc_to_tt_s(s).unwrap()
    }

    fn subsolar(body: &str, t: f64) -> (f64, f64) {
        subsolar_latlon_deg(sun_direction(body, t).unwrap())
    }

    /// Angle (degrees) between a body's north pole and its orbit's normal at `t`.
    fn obliquity(b: &BodyEphemeris, t: f64) -> f64 {
        let t_cy = t / DAY_S / CENTURY_D;
        let o = &b.orbit;
        let (i, node) = (
            o.i_deg.0 + o.i_deg.1 * t_cy,
            o.node_deg.0 + o.node_deg.1 * t_cy,
        );
        let h = [sind(i) * sind(node), -sind(i) * cosd(node), cosd(i)];
        let hb = to_body_fixed(b, t, ecliptic_to_equator(h));
        hb[2].clamp(-1.0, 1.0).acos().to_degrees()
    }

    /// The Sun direction turned back by the mean solar rate (the q of [`SunPath`]).
    fn q(b: &BodyEphemeris, omega: f64, t: f64) -> Vec3 {
        let s = sun_seen(b, t).0;
        rot3(-omega * t / DAY_S, s)
    }

    fn angle_deg(a: Vec3, b: Vec3) -> f64 {
        crate::cube::angle_between(a, b).to_degrees()
    }

    /// Deterministic pseudo-random numbers in [0, 1).
    fn rng(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn utc_reads_known_instants() {
        // J2000.0 (12:00 TT) was 11:58:55.816 UTC: TT − UTC = 32.184 + 32 s in 2000.
        assert!(tt("2000-01-01T11:58:55.816Z").abs() < 1e-6);
        // 2027-03-01T00:00:00Z is Unix time 1_803_859_200; J2000.0 UTC-label 946_728_000.
        let label = 1_803_859_200.0 - 946_728_000.0;
        assert!((tt("2027-03-01T00:00:00Z") - (label + 69.184)).abs() < 1e-6);
        assert_eq!(tt("2027-03-01"), tt("2027-03-01T00:00:00Z"));
        assert_eq!(tt("2027-03-01T00:00:00+00:00"), tt("2027-03-01T00:00:00Z"));
        assert_eq!(tt("2027-03-01T00:00Z"), tt("2027-03-01T00:00:00Z"));
        assert!((tt("2027-03-01T00:00:01.25Z") - tt("2027-03-01T00:00:00Z") - 1.25).abs() < 1e-9);
        // The leap second at the end of 2016.
        assert_eq!(tt("2016-12-31T23:59:59Z") + 1.0, tt("2016-12-31T23:59:60Z"));
        assert_eq!(tt("2016-12-31T23:59:60Z") + 1.0, tt("2017-01-01T00:00:00Z"));
        // The first leap second, at the end of 1972-06-30: that minute had 61 seconds.
        assert_eq!(tt("1972-07-01") - tt("1972-06-30T23:59:00Z"), 61.0);
        assert_eq!(tt("1972-06-01") - tt("1972-05-31T23:59:00Z"), 60.0);
        // TT − UTC back from TT.
        for (s, want) in [
            ("1980-06-01T00:00:00Z", 32.184 + 19.0),
            ("2016-12-31T23:59:59Z", 32.184 + 36.0),
            ("2017-01-01T00:00:00Z", 69.184),
            ("2150-01-01T00:00:00Z", 69.184),
        ] {
            assert_eq!(tt_minus_utc_s(tt(s)), want, "{s}");
        }
        for bad in [
            "2027-03-01T00:00:00",
            "2027-03-01T00:00:00+01:00",
            "2027-13-01T00:00:00Z",
            "2027-02-29T00:00:00Z",
            "2027-03-01T24:00:00Z",
            "2027-03-01T23:59:60Z",
            "27-03-01",
            "2027/03/01",
            "1969-07-20T20:17:00Z",
            "2201-01-01",
            "soon",
        ] {
            let e = utc_to_tt_s(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn earth_seasons_and_equation_of_time() {
        // June solstice 2026-06-21 08:24 UTC: the sub-solar latitude is the obliquity of date.
        let (lat, _) = subsolar("earth", tt("2026-06-21T08:24:00Z"));
        assert!((lat - 23.436).abs() < 0.05, "{lat}");
        // March equinox 2026-03-20 14:46 UTC.
        let (lat, _) = subsolar("earth", tt("2026-03-20T14:46:00Z"));
        assert!(lat.abs() < 0.05, "{lat}");
        // Meeus, Astronomical Algorithms, example 28.b: on 1992-10-13 0h TD the equation of time
        // is +13m42.7s, so at that instant (UT = TD − 59.184 s) the Sun stands over
        // 180° + 59.184 s·15″/s − 3.4279° = 176.8187° east.
        let (_, lon) = subsolar("earth", tt("1992-10-13T00:00:00Z") - 59.184);
        assert!(wrap180(lon - 176.8187).abs() < 0.02, "{lon}");
        // Every day at 12:00 UTC the Sun is within the equation of time (≤ 16.5 min = 4.125°)
        // of the Greenwich meridian, and both signs occur over a year.
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for day in 0..365 {
            let (_, lon) = subsolar("earth", tt("2026-01-01T12:00:00Z") + day as f64 * DAY_S);
            assert!(lon.abs() < 4.125, "day {day}: {lon}");
            lo = lo.min(lon);
            hi = hi.max(lon);
        }
        // Mid-February the Sun crosses Greenwich 14.2 min after 12:00 UTC (at noon it is still
        // 3.5° east), early November 16.4 min before (4.1° west at noon).
        assert!(lo < -3.9 && hi > 3.4, "{lo} {hi}");
    }

    #[test]
    fn moon_mars_mercury_venus_known_answers() {
        let t0 = tt("2026-01-01");
        // The Moon's equator is 1.54° from the ecliptic (Cassini's laws), nodding by the
        // physical libration (±0.03°); seen from the Moon rather than the barycentre the Sun
        // moves by another ±0.013° in latitude. Over 2026–2028 the sub-solar latitude reaches
        // 1.54° and stays under 1.6° (1.586° at most).
        let mut mx = 0.0f64;
        for k in 0..(3 * 365 * 12) {
            mx = mx.max(subsolar("moon", t0 + k as f64 * 7200.0).0.abs());
        }
        assert!((1.54..1.6).contains(&mx), "{mx}");
        // So at the south pole the Sun stays within ±1.6° over a year, and the conservative
        // range within ±1.6° plus its margin and the model's accuracy.
        let path = SunPath::new("moon", t0, t0 + 365.25 * DAY_S, None).unwrap();
        let (lo, hi) = path.range_at(-90.0, 0.0);
        let slack = path.margin_deg() + path.accuracy_deg();
        assert!(lo > -1.6 - slack && hi < 1.6 + slack, "{lo} {hi}");
        assert!(lo < -1.5 && hi > 1.5, "{lo} {hi}");
        for k in 0..365 {
            let e = sun_elevation_deg(
                sun_direction("moon", t0 + k as f64 * DAY_S).unwrap(),
                -90.0,
                0.0,
            );
            assert!(e.abs() < 1.6 && (lo..=hi).contains(&e), "{e}");
        }
        // Mars: obliquity 25.19°, reached at both solstices of a Mars year (686.98 days).
        let (mut lo, mut hi) = (90.0f64, -90.0f64);
        for k in 0..(687 * 8) {
            let (lat, _) = subsolar("mars", t0 + k as f64 * 10_800.0);
            lo = lo.min(lat);
            hi = hi.max(lat);
        }
        assert!(
            (hi - 25.19).abs() < 0.05 && (lo + 25.19).abs() < 0.05,
            "{lo} {hi}"
        );
        // Mercury's 3:2 resonance: 1.5 turns per orbit, so a solar day is two orbits (175.94
        // days); measured over three solar days, a whole number of orbits.
        let solar_day = |body: &str, span_d: f64, step_d: f64| {
            let (mut prev, mut total) = (subsolar(body, t0).1, 0.0);
            let n = (span_d / step_d).round() as usize;
            for k in 1..=n {
                let lon = subsolar(body, t0 + k as f64 * step_d * DAY_S).1;
                total += wrap180(lon - prev);
                prev = lon;
            }
            360.0 * span_d / total
        };
        let day = solar_day("mercury", 6.0 * 87.9691, 0.25);
        assert!((day + 175.94).abs() < 0.1, "{day}");
        // The hot poles: at perihelion the Sun stands over longitude 0° or 180°.
        let b = body_ephemeris("mercury").unwrap();
        let mut t = t0;
        let (mut best_r, mut best_t) = (f64::INFINITY, t0);
        while t < t0 + 88.0 * DAY_S {
            let r = sun_seen(b, t).1;
            if r < best_r {
                (best_r, best_t) = (r, t);
            }
            t += 600.0;
        }
        let lon = subsolar("mercury", best_t).1;
        assert!(wrap180(2.0 * lon).abs() < 2.0, "{lon}");
        // Venus turns backwards: the Sun moves east, a solar day of 116.75 days.
        let day = solar_day("venus", 2.0 * 224.701, 0.5);
        assert!((day - 116.75).abs() < 0.05, "{day}");
        // Solar days of the Earth, the Moon and Mars.
        assert!((solar_day("earth", 365.0, 0.01) + 1.0).abs() < 1e-4);
        let moon = solar_day("moon", 29.530589 * 12.0, 0.1);
        assert!((moon + 29.53).abs() < 0.01, "{moon}");
        let mars = solar_day("mars", 686.98, 0.01);
        assert!((mars + 1.0275).abs() < 0.001, "{mars}");
    }

    #[test]
    fn elevation_is_geometric() {
        let s = latlon_to_dir(0.3, -1.1);
        let (lat, lon) = subsolar_latlon_deg(s);
        assert!((sun_elevation_deg(s, lat, lon) - 90.0).abs() < 1e-9);
        assert!((sun_elevation_deg(s, -lat, lon + 180.0) + 90.0).abs() < 1e-9);
        assert!(sun_elevation_deg(s, lat - 90.0, lon).abs() < 1e-9);
        assert!((sun_elevation_deg(s, lat + 30.0, lon) - 60.0).abs() < 1e-9);
    }

    #[test]
    fn obliquity_bounds_hold() {
        // The table's obliquity bounds hold over every date UTC may be given for.
        for b in BODIES {
            let (t0, t1) = (tt("1972-01-01"), tt("2200-12-31"));
            let mut t = t0;
            let mut mx = 0.0f64;
            while t < t1 {
                mx = mx.max(obliquity(b, t));
                t += 1.37 * DAY_S;
            }
            assert!(mx < b.obliquity_max_deg, "{}: {mx}", b.name);
            assert!(
                mx > 0.6 * b.obliquity_max_deg || b.name == "mercury",
                "{}: {mx} is loose",
                b.name
            );
        }
    }

    #[test]
    fn rate_bound_holds() {
        // The bound D of SunPath, without its safety factor, exceeds the rate at which the Sun
        // drifts from uniform motion, measured over a year in one-minute steps.
        for b in BODIES {
            let (omega, d) = path_rates(b);
            let raw = d / RATE_SAFETY;
            let t0 = tt("2026-01-01");
            let dt = 60.0;
            let mut prev = q(b, omega, t0);
            let mut mx = 0.0f64;
            for k in 1..(366 * 1440) {
                let cur = q(b, omega, t0 + k as f64 * dt);
                mx = mx.max(angle_deg(prev, cur) / (dt / DAY_S));
                prev = cur;
            }
            assert!(mx < raw, "{}: {mx} °/day, bound {raw}", b.name);
            assert!(
                mx > 0.3 * raw,
                "{}: {mx} °/day, bound {raw} is loose",
                b.name
            );
        }
    }

    /// Brute force: the elevations at `points` every `dt` seconds over the span.
    fn brute(body: &str, t0: f64, t1: f64, dt: f64, points: &[(f64, f64)]) -> Vec<(f64, f64)> {
        let b = body_ephemeris(body).unwrap();
        let ups: Vec<Vec3> = points
            .iter()
            .map(|&(la, lo)| latlon_to_dir(la.to_radians(), lo.to_radians()))
            .collect();
        let mut out = vec![(f64::INFINITY, f64::NEG_INFINITY); points.len()];
        let n = ((t1 - t0) / dt).ceil() as usize;
        for k in 0..=n {
            let s = sun_seen(b, (t0 + k as f64 * dt).min(t1)).0;
            for (o, &u) in out.iter_mut().zip(&ups) {
                let e = asind(dot(u, s));
                *o = (o.0.min(e), o.1.max(e));
            }
        }
        out
    }

    #[test]
    fn ranges_hold_brute_force_and_are_tight() {
        // (body, start, length in days, brute-force step in seconds)
        let cases = [
            ("moon", "2027-01-01", 40.0, 300.0),
            ("earth", "2026-06-01", 3.0, 10.0),
            ("earth", "2026-12-20T03:00:00Z", 0.2, 2.0),
            ("mars", "2030-05-01", 4.0, 15.0),
            ("mercury", "2026-01-01", 200.0, 600.0),
            ("venus", "2026-01-01", 130.0, 1200.0),
        ];
        let mut rnd = rng(11);
        let mut points = vec![
            (90.0, 0.0),
            (-90.0, 0.0),
            (0.0, 0.0),
            (-89.5, 45.0),
            (1.0, 179.9),
        ];
        for _ in 0..25 {
            points.push((
                (2.0 * rnd() - 1.0).asin().to_degrees(),
                360.0 * rnd() - 180.0,
            ));
        }
        for (body, start, days, dt) in cases {
            let t0 = tt(start);
            let t1 = t0 + days * DAY_S;
            let path = SunPath::new(body, t0, t1, None).unwrap();
            let b = body_ephemeris(body).unwrap();
            let (omega, d) = path_rates(b);
            // The brute force's own sampling error: the Sun moves at most |ω| + D.
            let fine = (omega.abs() + d) * dt / DAY_S / 2.0;
            let slack = path.margin_deg() + path.accuracy_deg() + fine + 1e-9;
            assert!(path.margin_deg() <= ELEVATION_MARGIN_DEG + 1e-12);
            let truth = brute(body, t0, t1, dt, &points);
            for (&(la, lo), &(bmin, bmax)) in points.iter().zip(&truth) {
                let (rmin, rmax) = path.range_at(la, lo);
                let at = format!("{body} {start} +{days} d at ({la}, {lo})");
                // Conservative: every sampled elevation lies inside, with the accuracy to spare.
                let acc = path.accuracy_deg();
                assert!(
                    rmin <= (bmin - acc).max(-90.0) + 1e-9,
                    "{at}: min {rmin} vs {bmin}"
                );
                assert!(
                    rmax >= (bmax + acc).min(90.0) - 1e-9,
                    "{at}: max {rmax} vs {bmax}"
                );
                // And tight.
                assert!(rmin >= bmin - slack, "{at}: min {rmin} vs {bmin}");
                assert!(rmax <= bmax + slack, "{at}: max {rmax} vs {bmax}");
            }
        }
    }

    #[test]
    fn full_rotations_follow_the_declination_rule() {
        // Over whole solar days the Sun culminates over every meridian: the highest elevation is
        // 90° − min|φ − δ| and the lowest min|φ + δ| − 90° over the sub-solar latitudes δ the
        // span reaches (sampled hourly here), up to how far δ moves in half a day (≤ 0.21° on
        // the Earth) between the culmination over a given meridian and the δ nearest φ.
        let t0 = tt("2026-01-01");
        let t1 = t0 + 365.25 * DAY_S;
        let path = SunPath::new("earth", t0, t1, None).unwrap();
        let decs: Vec<f64> = (0..(365 * 24))
            .map(|k| subsolar("earth", t0 + k as f64 * 3600.0).0)
            .collect();
        let (acc, margin) = (path.accuracy_deg(), path.margin_deg());
        for lat in [
            -90.0, -66.0, -40.0, -23.0, -10.0, 0.0, 12.5, 23.44, 50.0, 70.0, 89.0,
        ] {
            let near = decs
                .iter()
                .map(|d| (lat - d).abs())
                .fold(f64::INFINITY, f64::min);
            let far = decs
                .iter()
                .map(|d| (lat + d).abs())
                .fold(f64::INFINITY, f64::min);
            let (want_hi, want_lo) = (90.0 - near, far - 90.0);
            for lon in [-170.0, 0.0, 33.0] {
                let (lo, hi) = path.range_at(lat, lon);
                let at = format!("({lat}, {lon}): {lo}..{hi} vs {want_lo}..{want_hi}");
                assert!(hi <= (want_hi + acc + margin + 0.01).min(90.0), "{at}");
                assert!(hi >= (want_hi + acc - 0.22).min(90.0), "{at}");
                assert!(lo >= (want_lo - acc - margin - 0.01).max(-90.0), "{at}");
                assert!(lo <= (want_lo - acc + 0.22).max(-90.0), "{at}");
            }
        }
    }

    #[test]
    fn sun_radius_over_span() {
        let t0 = tt("2026-01-01");
        let path = SunPath::new("mercury", t0, t0 + 100.0 * DAY_S, None).unwrap();
        let (lo, hi) = path.sun_radius_deg();
        // Perihelion 0.3075 AU, aphelion 0.4667 AU.
        assert!(
            (hi - 0.8666).abs() < 0.002 && (lo - 0.571).abs() < 0.002,
            "{lo} {hi}"
        );
        assert!(hi <= sun_radius_bound_deg("mercury").unwrap());
        let moon = SunPath::new("moon", t0, t0 + 365.25 * DAY_S, None).unwrap();
        let (lo, hi) = moon.sun_radius_deg();
        assert!(
            lo < 0.2630 && hi > 0.2710 && hi <= sun_radius_bound_deg("moon").unwrap(),
            "{lo} {hi}"
        );
    }

    #[test]
    fn specs_validate_and_name_the_field() {
        let span = |b: &str, s: &str, e: &str| SunSpec::Span {
            body: b.into(),
            start_utc: s.into(),
            end_utc: e.into(),
        };
        let range = |e: (f64, f64), a: Option<(f64, f64)>| SunSpec::Range {
            elevation_deg: e,
            azimuth_deg: a,
        };
        let ok = [
            span("moon", "2027-01-01T00:00:00Z", "2028-01-01T00:00:00Z"),
            span("Mars", "2030-01-01", "2031-06-01"),
            range((-2.0, 10.0), None),
            range((5.0, 5.0), Some((350.0, 10.0))),
            range((-90.0, 90.0), Some((0.0, 360.0))),
        ];
        for s in &ok {
            s.validate().unwrap();
        }
        let bad = [
            (range((-91.0, 10.0), None), "elevation_deg"),
            (range((0.0, f64::NAN), None), "elevation_deg"),
            (range((10.0, 5.0), None), "elevation_deg"),
            (range((0.0, 5.0), Some((-1.0, 10.0))), "azimuth_deg"),
            (range((0.0, 5.0), Some((10.0, 361.0))), "azimuth_deg"),
            (span("pluto", "2027-01-01", "2028-01-01"), "body"),
            (
                span("moon", "2027-01-01T00:00:00", "2028-01-01"),
                "start_utc",
            ),
            (span("moon", "1960-01-01", "2028-01-01"), "start_utc"),
            (span("moon", "2027-01-01", "2027-02-30"), "end_utc"),
            (span("moon", "2027-01-01", "2026-12-31"), "end_utc"),
            (span("moon", "2027-01-01", "2027-01-01"), "end_utc"),
            (span("moon", "2000-01-01", "2100-01-02"), "end_utc"),
        ];
        for (s, field) in &bad {
            let e = s.validate().unwrap_err().to_string();
            assert!(e.starts_with(field), "{s:?}: {e}");
            assert!(elevation_range(s, &[(0.0, 0.0)], None).is_err());
        }
        let e = span("pluto", "2027-01-01", "2028-01-01")
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("moon, earth, mars, mercury, venus"), "{e}");
        let e = sun_direction("ceres", 0.0).unwrap_err().to_string();
        assert!(e.contains("ceres") && e.contains("moon"), "{e}");
        // Serde: externally tagged, snake case, unknown fields refused.
        let s: SunSpec = serde_json::from_str(
            r#"{"span": {"body": "moon", "start_utc": "2027-01-01T00:00:00Z", "end_utc": "2028-01-01T00:00:00Z"}}"#,
        )
        .unwrap();
        assert_eq!(
            s,
            span("moon", "2027-01-01T00:00:00Z", "2028-01-01T00:00:00Z")
        );
        let r: SunSpec = serde_json::from_str(r#"{"range": {"elevation_deg": [0, 10]}}"#).unwrap();
        assert_eq!(r, range((0.0, 10.0), None));
        for s in ok {
            let back: SunSpec = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
            assert_eq!(back, s);
        }
        assert!(serde_json::from_str::<SunSpec>(
            r#"{"range": {"elevation_deg": [0, 10], "elev": 1}}"#
        )
        .is_err());
        // A range is its own answer; a span needs points.
        assert_eq!(
            elevation_range(&range((-2.0, 10.0), None), &[], None).unwrap(),
            (-2.0, 10.0)
        );
        let s = span("moon", "2027-01-01", "2027-02-01");
        assert!(elevation_range(&s, &[], None)
            .unwrap_err()
            .to_string()
            .starts_with("points"));
        assert!(elevation_range(&s, &[(91.0, 0.0)], None)
            .unwrap_err()
            .to_string()
            .starts_with("points"));
        assert!(elevation_range(&s, &[(0.0, 0.0)], Some(0.0))
            .unwrap_err()
            .to_string()
            .starts_with("step_s"));
        // A coarser step widens the margin but stays conservative.
        let fine = elevation_range(&s, &[(10.0, 20.0)], None).unwrap();
        let coarse = elevation_range(&s, &[(10.0, 20.0)], Some(3.0 * DAY_S)).unwrap();
        assert!(
            coarse.0 <= fine.0 && coarse.1 >= fine.1,
            "{fine:?} {coarse:?}"
        );
    }

    #[test]
    fn ten_thousand_points_a_lunar_year() {
        // The planner's load: 10⁴ sample points over a year on the Moon (12 lunar days).
        let t0 = tt("2027-01-01");
        let start = std::time::Instant::now();
        let path = SunPath::new("moon", t0, t0 + 365.25 * DAY_S, None).unwrap();
        let built = start.elapsed();
        let mut rnd = rng(5);
        let points: Vec<(f64, f64)> = (0..10_000)
            .map(|_| {
                (
                    (2.0 * rnd() - 1.0).asin().to_degrees(),
                    360.0 * rnd() - 180.0,
                )
            })
            .collect();
        let start = std::time::Instant::now();
        let (lo, hi) = path.range_over(&points).unwrap();
        let ranged = start.elapsed();
        eprintln!(
            "moon, 1 year: {} pieces built in {built:?}; 10^4 points in {ranged:?}; range {lo:.3}..{hi:.3}",
            path.pieces()
        );
        assert!(lo < -89.0 && hi > 89.0);
        // A polar region: the Sun stays low.
        let polar: Vec<(f64, f64)> = (0..10_000)
            .map(|_| (-88.0 - 2.0 * rnd(), 360.0 * rnd()))
            .collect();
        let start = std::time::Instant::now();
        let (lo, hi) = path.range_over(&polar).unwrap();
        eprintln!(
            "polar cap: 10^4 points in {:?}; range {lo:.3}..{hi:.3}",
            start.elapsed()
        );
        assert!(lo > -3.7 && hi < 3.7 && hi > 3.4, "{lo} {hi}");
    }
}
