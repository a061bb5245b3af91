//! Reader stub (being written).
use std::path::Path;
use crate::dem::DemParts;
use crate::error::{Error, Result};

pub fn read(path: &Path) -> Result<DemParts> {
    Err(Error::unsupported(path, "geotiff reader not written yet"))
}
