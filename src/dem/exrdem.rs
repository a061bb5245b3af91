//! OpenEXR DEMs: one float channel of heights (f32 or f16; u32 is converted), georeferenced by
//! a JSON sidecar `X.exr.json` or `X.json` with the schema of [`crate::dem::sidecar`] (crs, bounds
//! or x0/y0/dx/dy, optional scale/offset/nodata; no sample encoding keys).
//!
//! The channel is the one named `height`, else `Y`, `R` or `Z` (in that order, names compared
//! ignoring case), else the only channel. The first layer (part) of the file is read, at its
//! largest resolution level; samples are decoded straight into one `f32` buffer.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use exr::prelude::{self as x, ReadChannels, ReadLayers, ReadSpecificChannel};

use crate::dem::sidecar::{crs_name, require_sidecar, Sidecar};
use crate::dem::types::{check_dimensions, damaged_or_io, DemParts, Samples};
use crate::error::{Error, IoContext, Result};

/// Decoded samples may be at most this many times the file size (guards allocations driven by
/// a forged header; real compression ratios of height data are far lower).
const MAX_EXPANSION: u64 = 4096;

fn exr_error(path: &Path, e: x::Error) -> Error {
    match e {
        x::Error::NotSupported(m) => Error::unsupported(path, format!("EXR feature: {m}")),
        x::Error::Invalid(m) => Error::invalid(path, format!("not a readable EXR file: {m}")),
        x::Error::Io(io) => damaged_or_io(path, io, "EXR"),
        x::Error::Aborted => Error::invalid(path, "EXR reading was aborted"),
    }
}

pub fn read(path: &Path) -> Result<DemParts> {
    let sidecar_path = require_sidecar(path, "an EXR DEM")?;
    let sc = Sidecar::load(&sidecar_path)?;
    if sc.has_encoding() || sc.elevation_min.is_some() || sc.elevation_max.is_some() {
        return Err(Error::invalid(
            &sidecar_path,
            "an EXR carries its own sample type: remove format / sample_type / byte_order / \
             header_bytes / elevationMin / elevationMax from its sidecar (scale and offset are \
             allowed)",
        ));
    }
    let file_len = std::fs::metadata(path).at(path)?.len();

    let meta = catch_unwind(AssertUnwindSafe(|| {
        x::MetaData::read_from_file(path, false)
    }))
    .map_err(|_| Error::invalid(path, "the EXR header is damaged (the decoder gave up)"))?
    .map_err(|e| exr_error(path, e))?;
    let Some(header) = meta.headers.iter().find(|h| !h.deep) else {
        return Err(Error::unsupported(
            path,
            "the EXR holds only deep data; a DEM needs a flat float channel",
        ));
    };
    let names: Vec<String> = header
        .channels
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    let pick = ["height", "y", "r", "z"]
        .iter()
        .find_map(|want| names.iter().position(|n| n.eq_ignore_ascii_case(want)))
        .or((names.len() == 1).then_some(0));
    let Some(ci) = pick else {
        return Err(Error::invalid(
            path,
            format!(
                "EXR has channels [{}]: name the height channel \"height\" (or Y, R, Z), or \
                 keep only one channel",
                names.join(", ")
            ),
        ));
    };
    let channel = &header.channels.list[ci];
    if channel.sampling != x::Vec2(1, 1) {
        return Err(Error::unsupported(
            path,
            format!("EXR channel {} is subsampled", names[ci]),
        ));
    }
    let (w, h) = (header.layer_size.width(), header.layer_size.height());
    check_dimensions(path, w as u64, h as u64)?;
    if let Some((sw, sh)) = sc.dimensions(&sidecar_path)? {
        if (sw, sh) != (w as u64, h as u64) {
            return Err(Error::invalid(
                &sidecar_path,
                format!("sidecar says {sw}×{sh}, the EXR image is {w}×{h}"),
            ));
        }
    }
    let n = (w as u64) * (h as u64);
    if n * 2 > file_len.saturating_mul(MAX_EXPANSION) {
        return Err(Error::invalid(
            path,
            format!("EXR header claims {w}×{h} samples, impossible for a {file_len}-byte file"),
        ));
    }
    let georef = sc.georef(&sidecar_path, w as u64, h as u64)?;
    let (scale, offset) = sc.scale_offset(&sidecar_path, None)?;
    let datum_radius_m = sc.datum_radius(&sidecar_path)?;
    let sample_name = format!("{:?}", channel.sample_type).to_lowercase();
    let name = names[ci].clone();

    let mut values: Vec<f32> = Vec::new();
    values
        .try_reserve_exact(w * h)
        .map_err(|_| Error::invalid(path, format!("cannot allocate {w}×{h} samples")))?;
    let buffer = std::cell::Cell::new(values);
    let decoded = catch_unwind(AssertUnwindSafe(|| {
        x::read()
            .no_deep_data()
            .largest_resolution_level()
            .specific_channels()
            .required(name.as_str())
            .collect_pixels(
                |size: x::Vec2<usize>, _: &(x::ChannelDescription,)| {
                    let mut v = buffer.take();
                    v.resize(size.width() * size.height(), f32::NAN);
                    (v, size.width())
                },
                |store: &mut (Vec<f32>, usize), pos: x::Vec2<usize>, (v,): (f32,)| {
                    let i = pos.y() * store.1 + pos.x();
                    if let Some(s) = store.0.get_mut(i) {
                        *s = v;
                    }
                },
            )
            .first_valid_layer()
            .all_attributes()
            .from_file(path)
    }))
    .map_err(|_| Error::invalid(path, "the EXR data is damaged (the decoder gave up)"))?
    .map_err(|e| exr_error(path, e))?;
    let (samples, sw) = decoded.layer_data.channel_data.pixels;
    if sw != w || samples.len() != w * h {
        return Err(Error::invalid(
            path,
            format!("decoded {} samples, {w}×{h} expected", samples.len()),
        ));
    }
    let format = format!(
        "OpenEXR {sample_name} channel \"{name}\" + JSON sidecar, {}",
        crs_name(&georef.crs)
    );
    Ok(DemParts {
        width: w,
        height: h,
        samples: Samples::Owned(samples),
        scale,
        offset,
        nodata: sc.nodata.map(|v| v as f32 as f64),
        georef,
        datum_radius_m,
        target: sc.target.as_ref().map(|t| t.to_ascii_lowercase()),
        sources: vec![sidecar_path, path.to_path_buf()],
        format,
    })
}
