//! The storage precision of the mip pyramids: a leaf (serde and parsing only), so that the
//! manifest can name it without depending on the rest of the mip stage.

use serde::{Deserialize, Serialize};

/// Storage precision of the pyramids.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// f32: the extrema of the f32 heights, exactly.
    #[default]
    F32,
    /// f16: max rounded up and min rounded down to the next f16, so bounds stay bounds.
    F16,
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "f32" => Ok(Precision::F32),
            "f16" => Ok(Precision::F16),
            _ => Err(format!("unknown precision '{s}': use f32 or f16")),
        }
    }
}
