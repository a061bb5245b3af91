//! Raw rasters described by a JSON sidecar.
//!
//! The raw file `X.bin` (any extension: `.raw`, `.dat` …) holds `height` rows of `width`
//! samples, no padding, after `header_bytes`. Its sidecar is `X.bin.json` or `X.json`; opening
//! the sidecar itself also works (the data file is its `"data"` key, or `X.bin`/`X.raw`/`X.dat`).
//! The samples are memory-mapped.
//!
//! The sidecar schema is in [`super::sidecar`]; [`super::open`] sends a sidecar that describes
//! an EXR to [`super::exrdem`].

use std::path::Path;

use crate::dem::sidecar::{crs_name, data_for_sidecar, is_json, require_sidecar};
pub use crate::dem::sidecar::{sidecar_for, Bounds, Sidecar};
use crate::dem::types::{check_dimensions, map_file, ByteOrder, DemParts, SampleType, Samples};
use crate::error::{Error, IoContext, Result};

pub fn read(path: &Path) -> Result<DemParts> {
    let (data_path, sidecar_path) = if is_json(path) {
        let sc = Sidecar::load(path)?;
        let data = data_for_sidecar(path, &sc)?;
        (data, path.to_path_buf())
    } else {
        (path.to_path_buf(), require_sidecar(path, "a raw raster")?)
    };
    let sc = Sidecar::load(&sidecar_path)?;
    let (w, h) = sc.dimensions(&sidecar_path)?.ok_or_else(|| {
        Error::invalid(
            &sidecar_path,
            "the sidecar gives no raster size: add \"width\" and \"height\" (or \"size\" for a \
             square)",
        )
    })?;
    check_dimensions(&sidecar_path, w, h)?;
    let (st, order) = sc.encoding(&sidecar_path)?;
    let (scale, offset) = sc.scale_offset(&sidecar_path, Some(st))?;
    let georef = sc.georef(&sidecar_path, w, h)?;
    let header = sc.header_bytes.unwrap_or(0);
    let need = header as u128 + w as u128 * h as u128 * st.size() as u128;
    let len = std::fs::metadata(&data_path).at(&data_path)?.len();
    if (len as u128) < need {
        return Err(Error::invalid(
            &data_path,
            format!(
                "truncated: sidecar {} says {need} bytes ({w}×{h} {}{}), file has {len}",
                sidecar_path.display(),
                st.name(),
                if header > 0 {
                    format!(" after {header} header bytes")
                } else {
                    String::new()
                }
            ),
        ));
    }
    if (len as u128) > need {
        return Err(Error::invalid(
            &data_path,
            format!(
                "file has {len} bytes but sidecar {} describes {need} ({w}×{h} {}{}): check \
                 width/height and the sample type, or set header_bytes",
                sidecar_path.display(),
                st.name(),
                if header > 0 {
                    format!(" after {header} header bytes")
                } else {
                    String::new()
                }
            ),
        ));
    }
    let header = usize::try_from(header)
        .map_err(|_| Error::invalid(&sidecar_path, "header_bytes is too large"))?;
    let order_name = match order {
        ByteOrder::Little => "LE",
        ByteOrder::Big => "BE",
    };
    let format = format!(
        "raw {}{} + JSON sidecar, {}",
        st.name(),
        if st.size() > 1 {
            format!(" {order_name}")
        } else {
            String::new()
        },
        crs_name(&georef.crs)
    );
    let nodata = sc.nodata.map(|v| match st {
        SampleType::F32 => v as f32 as f64,
        _ => v,
    });
    Ok(DemParts {
        width: w as usize,
        height: h as usize,
        samples: Samples::Mapped {
            map: map_file(&data_path)?,
            offset: header,
            row_stride: w as usize * st.size(),
            ty: st,
            order,
        },
        scale,
        offset,
        nodata,
        georef,
        datum_radius_m: sc.datum_radius(&sidecar_path)?,
        target: sc.target.as_ref().map(|t| t.to_ascii_lowercase()),
        sources: vec![sidecar_path, data_path],
        format,
    })
}
