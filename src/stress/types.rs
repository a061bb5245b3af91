//! The catalogue's types: the sizes, the weakened kernels, a row and a case.

use serde::Serialize;

/// How large the cases are.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Size {
    /// What CI and the tests run: the whole catalogue in seconds (the 16384² tile is 1024²).
    Short,
    /// The real sizes (a 16384² tile: about 1 GiB of heights).
    Full,
}

/// A deliberately weakened kernel (test-only): the cases that use the kernel run the weakened
/// variant instead, so that their bounds are seen to fail. Nothing in the production kernels
/// changes; the weakening is applied to their output here.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Weaken {
    /// The kernels as they are.
    #[default]
    None,
    /// A horizon kernel that starts its running maximum at the local horizontal (0°) instead of
    /// below it: every horizon under 0° (the dip of a spike, a small body) reads 0.
    HorizonFloorZero,
    /// A shadow kernel that takes the sun for a point (no penumbra): the lit fraction is 0 or 1.
    ShadowPointSun,
    /// A Fourier reconstruction that leaves out the last kept coefficient.
    FourierDropTerm,
}

impl Weaken {
    pub const ALL: [Weaken; 4] = [
        Weaken::None,
        Weaken::HorizonFloorZero,
        Weaken::ShadowPointSun,
        Weaken::FourierDropTerm,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Weaken::None => "none",
            Weaken::HorizonFloorZero => "horizon-floor-zero",
            Weaken::ShadowPointSun => "shadow-point-sun",
            Weaken::FourierDropTerm => "fourier-drop-term",
        }
    }

    /// The variant named `s`; `None` for an unknown name.
    pub fn parse(s: &str) -> Option<Weaken> {
        Weaken::ALL.into_iter().find(|w| w.name() == s)
    }
}

/// One quantity of one case.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub case: String,
    pub area: String,
    pub quantity: String,
    /// Unit of `error` and `bound` ("deg", "lit", "m", "ulp", "count", …).
    pub unit: String,
    /// Largest error over the case's samples (NaN when a sample was not finite).
    pub error: f64,
    pub bound: f64,
    /// Samples that came out NaN or infinite where a finite value was due.
    pub nonfinite: usize,
    /// error ≤ bound, error finite and no non-finite sample.
    pub pass: bool,
    /// What the answer is, or how the size differs from the full one.
    pub note: String,
}

impl Row {
    pub(crate) fn new(quantity: impl Into<String>, unit: &str, error: f64, bound: f64) -> Row {
        Row {
            case: String::new(),
            area: String::new(),
            quantity: quantity.into(),
            unit: unit.into(),
            error,
            bound,
            nonfinite: 0,
            pass: false,
            note: String::new(),
        }
    }

    /// The row of a set of errors: the largest (NaN if any is NaN) and the non-finite count.
    pub(crate) fn of(quantity: impl Into<String>, unit: &str, errors: &[f64], bound: f64) -> Row {
        let nonfinite = errors.iter().filter(|e| !e.is_finite()).count();
        let error = if nonfinite > 0 {
            f64::NAN
        } else {
            errors.iter().fold(0.0f64, |m, &e| m.max(e))
        };
        Row {
            nonfinite,
            ..Row::new(quantity, unit, error, bound)
        }
    }

    pub(crate) fn note(mut self, note: impl Into<String>) -> Row {
        self.note = note.into();
        self
    }

    pub(crate) fn nonfinite(mut self, n: usize) -> Row {
        self.nonfinite += n;
        self
    }
}

/// One case of the catalogue.
#[derive(Clone, Copy)]
pub struct Case {
    pub name: &'static str,
    /// horizon, shadow, fourier or tiles.
    pub area: &'static str,
    /// What the case is and its answer, in a line.
    pub about: &'static str,
    pub run: fn(Size, Weaken) -> Vec<Row>,
}
