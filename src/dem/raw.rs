//! Reader stub (being written).
use crate::dem::DemParts;
use crate::error::{Error, Result};
use std::path::Path;

pub fn read(path: &Path) -> Result<DemParts> {
    Err(Error::unsupported(path, "raw reader not written yet"))
}

/// The JSON sidecar of a raw raster, if there is one.
pub fn sidecar_for(path: &Path) -> Option<std::path::PathBuf> {
    let a = path.with_extension("json");
    a.exists().then_some(a)
}
