//! The ETH/UCY benchmark files of sgan / Trajectron++ (`frame ped_id x y`, metres).
//!
//! Frame numbers are video frames sampled every 10 frames. For UCY and `biwi_hotel` that is
//! 25 fps, so one row step is 0.4 s. `biwi_eth*` files keep the ETH video's frame numbers,
//! which run at 15 fps (EWAP's 0.4 s is 6 frames there), so one row step is 10/15 ≈ 0.667 s;
//! read as 0.4 s the walking speeds would come out 5/3 too fast (median ≈ 2.45 m/s). The
//! loader applies the right frame rate from the file name.

use crate::error::DataError;
use crate::input_limits;
use crate::text;
use crate::track::{AgentClass, RawScene, Sample, SourceTiming, group_rows};
use std::path::Path;

/// Video frame rate of a benchmark file: 15 fps for `biwi_eth*`, else 25 fps.
pub fn frame_rate(path: &Path) -> f64 {
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    if stem.starts_with("biwi_eth") {
        15.0
    } else {
        25.0
    }
}

/// Loads one benchmark file as scene `name`.
pub fn load(path: &Path, name: &str, dataset: &str) -> Result<RawScene, DataError> {
    let body = text::read(path)?;
    let fps = frame_rate(path);
    let mut rows = Vec::new();
    for (i, line) in body.lines().enumerate() {
        let Some((frame, id, x, y)) = text::frame_id_xy(line, path, i + 1, "ped_id")? else {
            continue;
        };
        let sample = Sample {
            t: input_limits::time(frame as f64 / fps, path, i + 1)?,
            p: input_limits::position([x, y], path, i + 1)?,
        };
        rows.push((id, AgentClass::Pedestrian, sample));
    }
    if rows.is_empty() {
        return Err(DataError::NoData(format!(
            "{} holds no rows",
            path.display()
        )));
    }
    let (tracks, dup) = group_rows(rows);
    let step = 10.0 / fps;
    let mut scene = RawScene {
        name: name.to_string(),
        dataset: dataset.to_string(),
        format: "sgan".into(),
        timing: SourceTiming {
            nominal_dt: step,
            max_gap: 2.5 * step,
            smooth_window: 0.0,
        },
        tracks,
        dropped: Vec::new(),
    };
    scene.drop_count("duplicate_time", dup);
    Ok(scene)
}
