//! What the benchmarks share: the scratch folder, the `penumbra` binary beside this one and
//! GNU time around a child process, best-of timing and thread pools, the pseudo-random pixels
//! and the bodies' radii. No benchmark module is imported here.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};

/// The `penumbra tile` options of the LDEM_4 tileset the mip and codec benchmarks measure
/// (510 tiles of 256² on 4 levels).
pub const LDEM4_BENCH_TILING: &[&str] = &["--body", "moon", "--tile-size", "256", "--levels", "4"];

/// Run `cmd` under GNU time; (wall seconds, peak RSS MiB).
pub(crate) fn timed(cmd: &mut Command, scratch: &Path) -> Result<(f64, f64)> {
    let tf = scratch.join("time.txt");
    let prog = cmd.get_program().to_owned();
    let args: Vec<_> = cmd.get_args().map(|a| a.to_owned()).collect();
    let t0 = std::time::Instant::now();
    let out = if Path::new("/usr/bin/time").exists() {
        Command::new("/usr/bin/time")
            .arg("-f")
            .arg("%e %M")
            .arg("-o")
            .arg(&tf)
            .arg(&prog)
            .args(&args)
            .output()?
    } else {
        cmd.output()?
    };
    let wall = t0.elapsed().as_secs_f64();
    if !out.status.success() {
        bail!(
            "{} failed: {}",
            prog.to_string_lossy(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let rss = std::fs::read_to_string(&tf)
        .ok()
        .and_then(|s| {
            s.split_whitespace()
                .nth(1)
                .and_then(|k| k.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |k| k / 1024.0);
    Ok((wall, rss))
}

/// The `penumbra` binary whose `tile` the benchmarks time in a child process: the one built
/// beside this executable (both in target/release/), so the figures are for this checkout's
/// build, not for whatever `penumbra` is installed.
pub(crate) fn penumbra_exe() -> Result<PathBuf> {
    let exe = std::env::current_exe()?
        .with_file_name(format!("penumbra{}", std::env::consts::EXE_SUFFIX));
    if !exe.is_file() {
        bail!(
            "{}: not found; build it beside penumbra-bench first: \
             cargo build --release --workspace",
            exe.display()
        );
    }
    Ok(exe)
}

/// Tile `dem` (LDEM_4's label) into `out` as the benchmarks' LDEM_4 tileset
/// ([`LDEM4_BENCH_TILING`]), by the `penumbra` binary.
pub(crate) fn tile_ldem4(dem: &Path, out: &Path) -> Result<()> {
    let status = Command::new(penumbra_exe()?)
        .args(["--quiet", "tile"])
        .arg(dem)
        .args(LDEM4_BENCH_TILING)
        .arg("--out")
        .arg(out)
        .stdout(std::process::Stdio::null())
        .status()?;
    if !status.success() {
        bail!("tiling LDEM_4 for the benchmark failed");
    }
    Ok(())
}

/// A bench's scratch folder (`penumbra-bench-<pid>` under `--work` or the system's temp
/// folder), removed when it goes out of scope, so that a bench that fails half-way leaves no
/// tilesets or rasters behind.
pub(crate) struct ScratchDir(PathBuf);

impl std::ops::Deref for ScratchDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for ScratchDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub(crate) fn tempfile_dir(work: Option<PathBuf>) -> Result<ScratchDir> {
    let base = work.unwrap_or_else(std::env::temp_dir);
    let p = base.join(format!("penumbra-bench-{}", std::process::id()));
    std::fs::create_dir_all(&p).with_context(|| format!("creating {}", p.display()))?;
    Ok(ScratchDir(p))
}

/// Best wall time of `reps` runs of `f`, in seconds.
pub(crate) fn best_of(reps: usize, mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    let mut best = f64::INFINITY;
    for _ in 0..reps {
        let t0 = std::time::Instant::now();
        f()?;
        best = best.min(t0.elapsed().as_secs_f64());
    }
    Ok(best)
}

pub(crate) fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    Ok(rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?
        .install(f))
}

pub(crate) use penumbra_cli::measure::{
    random_pixels, EARTH_RADIUS_M, MARS_RADIUS_M, MOON_RADIUS_M,
};

/// A little-endian float32, C-order, 2-D .npy file: (height, width, values).
pub(crate) fn read_npy_f32(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let bad = |what: &str| anyhow::anyhow!("{}: not a 2-D float32 .npy ({what})", path.display());
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("no .npy magic"));
    }
    let (hlen, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(bad(&format!("format version {v}"))),
    };
    let header = bytes
        .get(start..start + hlen)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| bad("truncated header"))?;
    let header: String = header.chars().filter(|c| !c.is_whitespace()).collect();
    if !header.contains("'descr':'<f4'") {
        return Err(bad("descr is not '<f4'"));
    }
    if header.contains("'fortran_order':True") {
        return Err(bad("Fortran order"));
    }
    let shape = header
        .split("'shape':(")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| bad("no shape"))?;
    let dims = shape
        .split(',')
        .filter(|d| !d.is_empty())
        .map(|d| d.parse::<usize>())
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|_| bad(&format!("shape ({shape})")))?;
    let &[h, w] = dims.as_slice() else {
        return Err(bad(&format!("shape ({shape}) is not 2-D")));
    };
    let data = &bytes[start + hlen..];
    if data.len() != h * w * 4 {
        return Err(bad(&format!(
            "{} data bytes for shape ({h}, {w})",
            data.len()
        )));
    }
    let v = data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((h, w, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scratch_folder_goes_with_its_guard() {
        let work = std::env::temp_dir().join(format!("scratch-guard-{}", std::process::id()));
        let dir = tempfile_dir(Some(work.clone())).unwrap();
        std::fs::write(dir.join("left.bin"), b"x").unwrap();
        let path = dir.to_path_buf();
        assert!(path.join("left.bin").is_file());
        drop(dir);
        assert!(!path.exists());
        std::fs::remove_dir(&work).unwrap();
    }
}
