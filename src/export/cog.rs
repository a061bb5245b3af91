//! Writing a [`Raster`] as a Cloud-Optimized GeoTIFF with GDAL's own COG driver (the reference
//! writer): an in-memory (MEM) dataset with the samples, geotransform, CRS (WKT on the body's
//! sphere), no-data value and metadata, copied by the COG driver (DEFLATE with the float
//! predictor, 512² blocks — 256² below 2048 pixels a side —, overviews down to one block
//! averaged without no-data) into a temporary file beside the output, which is then renamed
//! over it: a failed write leaves no output and no temporary file.

use std::path::{Path, PathBuf};

use gdal::raster::{Buffer, RasterCreationOptions};
use gdal::{DriverManager, GeoTransform, Metadata};

use super::Raster;
use crate::error::{Error, Result};

/// What was written.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CogReport {
    pub path: PathBuf,
    pub bytes: u64,
    pub block_px: usize,
    /// The GDAL version that wrote it.
    pub gdal: String,
}

fn gdal_err(out: &Path, what: &str, e: gdal::errors::GdalError) -> Error {
    Error::invalid(out, format!("GDAL could not {what}: {e}"))
}

/// Write `r` to `out` as a COG (replacing a file there), atomically.
pub fn write(r: &Raster, out: &Path) -> Result<CogReport> {
    super::check_out(out)?;
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = out.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    let res = write_to(r, out, &tmp);
    if res.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    let block = res?;
    std::fs::rename(&tmp, out).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(out, e)
    })?;
    let bytes = std::fs::metadata(out).map_err(|e| Error::io(out, e))?.len();
    Ok(CogReport {
        path: out.to_path_buf(),
        bytes,
        block_px: block,
        gdal: gdal::version_info("RELEASE_NAME"),
    })
}

fn write_to(r: &Raster, out: &Path, tmp: &Path) -> Result<usize> {
    let e = |what: &'static str| move |err: gdal::errors::GdalError| gdal_err(out, what, err);
    let mem = DriverManager::get_driver_by_name("MEM").map_err(e("find its MEM driver"))?;
    let cog = DriverManager::get_driver_by_name("COG")
        .map_err(e("find its COG driver (GDAL 3.1 or later has it)"))?;
    let mut ds = mem
        .create_with_band_type::<f32, _>("", r.width, r.height, 1)
        .map_err(e("create an in-memory raster"))?;
    ds.set_geo_transform(&(r.geo_transform as GeoTransform))
        .map_err(e("set the geotransform"))?;
    ds.set_projection(&r.crs.wkt(&r.body, r.radius_m))
        .map_err(e("set the CRS"))?;
    let (what, unit) = r.product.description();
    let mut meta = vec![
        ("AREA_OR_POINT", "Area".to_string()),
        ("PENUMBRA_PRODUCT", r.product.name().to_string()),
        ("PENUMBRA_LEVEL", r.level.to_string()),
        ("PENUMBRA_BODY", r.body.clone()),
        ("PENUMBRA_RADIUS_M", r.radius_m.to_string()),
        ("PENUMBRA_VERSION", env!("CARGO_PKG_VERSION").to_string()),
    ];
    if let Some(s) = &r.sun {
        meta.push(("PENUMBRA_SUN_AZIMUTH_DEG", s.azimuth_deg.to_string()));
        meta.push(("PENUMBRA_SUN_ELEVATION_DEG", s.elevation_deg.to_string()));
        if let Some(rad) = r.sun_radius_deg {
            meta.push(("PENUMBRA_SUN_RADIUS_DEG", rad.to_string()));
        }
        meta.push((
            "PENUMBRA_SUN_MODEL",
            format!("{:?}", s.model).to_lowercase(),
        ));
    }
    if let Some(f) = &r.from {
        meta.push(("PENUMBRA_HORIZONS_FROM", f.clone()));
    }
    for (k, v) in &meta {
        ds.set_metadata_item(k, v, "")
            .map_err(e("set the metadata"))?;
    }
    {
        let mut band = ds.rasterband(1).map_err(e("open the band"))?;
        band.set_no_data_value(Some(Raster::NODATA as f64))
            .map_err(e("set the no-data value"))?;
        band.set_description(what).map_err(e("describe the band"))?;
        band.set_metadata_item("UNIT", unit, "")
            .map_err(e("set the band's unit"))?;
        let mut buf = Buffer::new((r.width, r.height), r.values.clone());
        band.write((0, 0), (r.width, r.height), &mut buf)
            .map_err(e("fill the in-memory raster"))?;
    }
    let block = if r.width.max(r.height) < 2048 {
        256
    } else {
        512
    };
    let opts = RasterCreationOptions::from_iter([
        "COMPRESS=DEFLATE".to_string(),
        "PREDICTOR=YES".to_string(),
        format!("BLOCKSIZE={block}"),
        "OVERVIEWS=AUTO".to_string(),
        "RESAMPLING=AVERAGE".to_string(),
        "BIGTIFF=IF_SAFER".to_string(),
    ]);
    let copy = ds
        .create_copy(&cog, tmp, &opts)
        .map_err(e("write the Cloud-Optimized GeoTIFF"))?;
    copy.close().map_err(e("finish the GeoTIFF"))?;
    Ok(block)
}
