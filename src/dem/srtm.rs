//! SRTM `.hgt` tiles: a square of big-endian int16 heights (metres above the EGM96 geoid),
//! 1201×1201 (3″) or 3601×3601 (1″), no header. The file name gives the south-west corner:
//! `N19W156.hgt` covers 19..20°N, 156..155°W. The grid is registered on its corners: the centre of
//! the first sample is exactly at (lat + 1, lon), the last at (lat, lon + 1), so neighbouring
//! tiles share their edge rows. Voids are −32768.

use std::path::Path;

use crate::dem::types::{map_file, ByteOrder, Crs, DemParts, GeoRef, SampleType, Samples};
use crate::error::{Error, IoContext, Result};

/// SRTM's void value.
pub const VOID: f64 = -32768.0;

/// South-west corner (lat, lon) in whole degrees from a name like `N19W156` or `s01e036`
/// (anything may follow the first seven characters: `N19W156.SRTMGL1.hgt`).
pub fn corner_from_name(name: &str) -> Option<(i32, i32)> {
    let b = name.as_bytes();
    if b.len() < 7 {
        return None;
    }
    let digits = |s: &[u8]| -> Option<i32> {
        s.iter()
            .all(u8::is_ascii_digit)
            .then(|| s.iter().fold(0, |a, &d| a * 10 + (d - b'0') as i32))
    };
    let lat = digits(&b[1..3])?;
    let lon = digits(&b[4..7])?;
    let lat = match b[0].to_ascii_uppercase() {
        b'N' if lat <= 89 => lat,
        b'S' if (1..=90).contains(&lat) => -lat,
        _ => return None,
    };
    let lon = match b[3].to_ascii_uppercase() {
        b'E' if lon <= 179 => lon,
        b'W' if (1..=180).contains(&lon) => -lon,
        _ => return None,
    };
    // The corner name must end there (not "N19W1567").
    if b.get(7).is_some_and(u8::is_ascii_digit) {
        return None;
    }
    Some((lat, lon))
}

pub fn read(path: &Path) -> Result<DemParts> {
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or_default();
    let Some((lat, lon)) = corner_from_name(name) else {
        return Err(Error::invalid(
            path,
            "an SRTM file name must start with its south-west corner, [NS]dd[EW]ddd, e.g. \
             N19W156.hgt (19°N 156°W) or S01E036.hgt; rename the file or use a raw file with a \
             JSON sidecar",
        ));
    };
    let len = std::fs::metadata(path).at(path)?.len();
    let n: usize = match len {
        2_884_802 => 1201,
        25_934_402 => 3601,
        _ => {
            return Err(Error::invalid(
                path,
                format!(
                    "file is {len} bytes: an SRTM .hgt is 1201×1201 (2884802 bytes, 3″) or \
                     3601×3601 (25934402 bytes, 1″) big-endian int16 samples"
                ),
            ))
        }
    };
    let d = 1.0 / (n - 1) as f64;
    let arc = if n == 1201 { 3 } else { 1 };
    Ok(DemParts {
        width: n,
        height: n,
        samples: Samples::Mapped {
            map: map_file(path)?,
            offset: 0,
            row_stride: n * 2,
            ty: SampleType::I16,
            order: ByteOrder::Big,
        },
        scale: 1.0,
        offset: 0.0,
        nodata: Some(VOID),
        georef: GeoRef {
            crs: Crs::Geographic,
            x0: lon as f64,
            y0: lat as f64 + 1.0,
            dx: d,
            dy: d,
        },
        datum_radius_m: None,
        target: Some("earth".into()),
        sources: vec![path.to_path_buf()],
        format: format!("SRTM .hgt {arc}″ ({n}×{n}) int16 big-endian, geographic"),
    })
}

#[cfg(test)]
mod tests {
    use super::corner_from_name;

    #[test]
    fn names() {
        assert_eq!(corner_from_name("N19W156.hgt"), Some((19, -156)));
        assert_eq!(corner_from_name("s01e036.hgt"), Some((-1, 36)));
        assert_eq!(corner_from_name("N44W072.SRTMGL1.hgt"), Some((44, -72)));
        assert_eq!(corner_from_name("X19W156.hgt"), None);
        assert_eq!(corner_from_name("N19W1567.hgt"), None);
        assert_eq!(corner_from_name("N95W156.hgt"), None);
        assert_eq!(corner_from_name("N1.hgt"), None);
    }
}
