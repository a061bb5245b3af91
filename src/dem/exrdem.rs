//! Reader stub (being written).
use crate::dem::DemParts;
use crate::error::{Error, Result};
use std::path::Path;

pub fn read(path: &Path) -> Result<DemParts> {
    Err(Error::unsupported(path, "exrdem reader not written yet"))
}
