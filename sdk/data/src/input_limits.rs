//! Bounds on what the data crate reads, checked when a file is read so that bad input is an
//! error naming the file (and line) instead of an abort later on (ARCHITECTURE.md, "Input
//! limits").
//!
//! File sizes (every file is read through [`human2nav_core::input::read_user_file`]: a regular
//! file, at most the cap):
//!
//! | file | cap | largest real one |
//! |---|---|---|
//! | dataset text (`obsmat.txt`, `annotation.vsp`, `annotations.txt`, `H.txt`, TrajNet, sgan, `estimated_scales.yaml`) | [`MAX_DATASET_FILE_BYTES`] | 4.1 MB (SDD `gates/video2`) |
//! | episode file (`episodes*.json`) | [`MAX_EPISODE_FILE_BYTES`] | 6.8 MB |
//! | cache `manifest.json` | [`MAX_MANIFEST_BYTES`] | tens of KB |
//! | cache `<split>.bin` | [`MAX_CACHE_FILE_BYTES`] | 12 MB |
//! | `data.toml` | [`human2nav_core::input::MAX_CONFIG_BYTES`] | 6 KB |
//!
//! Values: every dataset position (after its homography or scale) lies within
//! [`MAX_COORDINATE`] metres of the origin and every time stamp within [`MAX_TIME`] seconds of
//! zero. The tuple cache stores `f32`: a finite `f64` such as `1e300` used to become `inf` there,
//! and `data stats` refused the cache it had just been written to; the scenes on the 0.1 s grid
//! span at most `2·MAX_TIME`, so no per-step index can grow beyond 1.7 million entries.

use crate::error::DataError;
use std::path::Path;

/// Cap of one dataset text file (256 MiB; the largest real one is 4.1 MB).
pub const MAX_DATASET_FILE_BYTES: u64 = 256 << 20;
/// Cap of an episode file (256 MiB; the shipped suites are under 7 MB for 200 episodes).
pub const MAX_EPISODE_FILE_BYTES: u64 = 256 << 20;
/// Cap of a tuple cache's `manifest.json` (64 MiB).
pub const MAX_MANIFEST_BYTES: u64 = 64 << 20;
/// Cap of one `<split>.bin` of the tuple cache (4 GiB, some 8 million tuples).
pub const MAX_CACHE_FILE_BYTES: u64 = 4 << 30;

/// Largest distance of a dataset position from its world origin (m): far beyond any recorded
/// scene (hundreds of metres), small enough that every difference, velocity and `f32` of the
/// cache stays finite.
pub const MAX_COORDINATE: f64 = 1e6;

/// Largest `|t|` of a dataset time stamp (s): one day. The recordings are minutes long; scenes
/// are resampled to 0.1 s steps over their whole span, so this bounds every per-step buffer.
pub const MAX_TIME: f64 = 86_400.0;

/// Checks a dataset position (world metres) against [`MAX_COORDINATE`]; `line` is the file's
/// 1-based line the position came from.
pub(crate) fn position(p: [f64; 2], path: &Path, line: usize) -> Result<[f64; 2], DataError> {
    for (v, axis) in p.iter().zip(["x", "y"]) {
        if !(v.is_finite() && v.abs() <= MAX_COORDINATE) {
            return Err(DataError::parse(
                path,
                line,
                format!("world {axis} = {v:e} m is out of range (|{axis}| ≤ {MAX_COORDINATE:e} m)"),
            ));
        }
    }
    Ok(p)
}

/// Checks a dataset time stamp (s) against [`MAX_TIME`].
pub(crate) fn time(t: f64, path: &Path, line: usize) -> Result<f64, DataError> {
    if !(t.is_finite() && t.abs() <= MAX_TIME) {
        return Err(DataError::parse(
            path,
            line,
            format!("time {t:e} s is out of range (|t| ≤ {MAX_TIME} s)"),
        ));
    }
    Ok(t)
}

/// `Ok` when `v` lies in `[lo, hi]`, else an error naming the option `key`.
pub(crate) fn option_in(v: f64, lo: f64, hi: f64, key: &str) -> Result<(), DataError> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(DataError::option(
            key,
            format!("must be in [{lo}, {hi}], got {v}"),
        ))
    }
}

/// `Ok` when the count `n` is at most `max`, else an error naming the option `key`.
pub(crate) fn count_at_most(n: usize, max: usize, key: &str) -> Result<(), DataError> {
    if n <= max {
        Ok(())
    } else {
        Err(DataError::option(
            key,
            format!("{n} is more than the limit of {max}"),
        ))
    }
}
