//! ETH (BIWI/EWAP) original annotations: `obsmat.txt` and `H.txt`.
//!
//! `obsmat.txt` has 8 columns `frame ped_id pos_x pos_z pos_y v_x v_z v_y` in metres and m/s;
//! `pos_z` is always 0, so x is column 3 and y column 5 (1-based). The annotation runs at
//! 2.5 fps (0.4 s, `info.txt`); the frame step is 6 for `seq_eth` (a 15 fps video) and 10 for
//! `seq_hotel` (25 fps). The loader measures the file's modal frame step and sets
//! `time = frame · 0.4 s / step`, so both sequences come out on their true 0.4 s grid.

use super::modal_step;
use crate::error::DataError;
use crate::homography::Homography;
use crate::input_limits;
use crate::text;
use crate::track::{AgentClass, RawScene, Sample, SourceTiming, group_rows};
use std::path::Path;

/// EWAP annotation interval, seconds (2.5 fps).
pub const ANNOTATION_DT: f64 = 0.4;

/// Loads an EWAP `obsmat.txt` as scene `name` (`eth/eth`, `eth/hotel`).
pub fn load_obsmat(path: &Path, name: &str) -> Result<RawScene, DataError> {
    let body = text::read(path)?;
    let mut rows = Vec::new();
    for (i, line) in body.lines().enumerate() {
        let ln = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let toks = text::fields(line, 8, path, ln)?;
        if toks.len() != 8 {
            return Err(DataError::parse(
                path,
                ln,
                format!("obsmat has 8 columns, found {}", toks.len()),
            ));
        }
        let frame = text::integer(toks[0], path, ln, "frame")?;
        let id = text::integer(toks[1], path, ln, "ped_id")?;
        let x = text::number(toks[2], path, ln, "pos_x")?;
        let y = text::number(toks[4], path, ln, "pos_y")?;
        for (k, f) in [(3, "pos_z"), (5, "v_x"), (6, "v_z"), (7, "v_y")] {
            text::number(toks[k], path, ln, f)?;
        }
        if id < 0 || frame < 0 {
            return Err(DataError::parse(
                path,
                ln,
                "negative frame or pedestrian id",
            ));
        }
        rows.push((
            id as u64,
            frame,
            input_limits::position([x, y], path, ln)?,
            ln,
        ));
    }
    if rows.is_empty() {
        return Err(DataError::NoData(format!(
            "{} holds no rows",
            path.display()
        )));
    }
    // Frame step from the per-pedestrian frame sequences.
    let mut frames: std::collections::BTreeMap<u64, Vec<i64>> = Default::default();
    for (id, f, _, _) in &rows {
        frames.entry(*id).or_default().push(*f);
    }
    for v in frames.values_mut() {
        v.sort_unstable();
    }
    let step = modal_step(frames.values().map(|v| v.as_slice())).ok_or_else(|| {
        DataError::parse(
            path,
            1,
            "cannot infer the frame step: no pedestrian has two rows",
        )
    })?;
    let frame_dt = ANNOTATION_DT / step as f64;
    let samples = rows
        .into_iter()
        .map(|(id, f, p, ln)| {
            let t = input_limits::time(f as f64 * frame_dt, path, ln)?;
            Ok((id, AgentClass::Pedestrian, Sample { t, p }))
        })
        .collect::<Result<_, DataError>>()?;
    let (tracks, dup) = group_rows(samples);
    let mut scene = RawScene {
        name: name.to_string(),
        dataset: "eth".into(),
        format: "ewap_obsmat".into(),
        timing: SourceTiming {
            nominal_dt: ANNOTATION_DT,
            max_gap: 2.5 * ANNOTATION_DT,
            smooth_window: 0.0,
        },
        tracks,
        dropped: Vec::new(),
    };
    scene.drop_count("duplicate_time", dup);
    Ok(scene)
}

/// Loads the `H.txt` of an ETH sequence directory (image `(row, col)` → world metres).
pub fn load_homography(seq_dir: &Path, scene: &str) -> Result<Homography, DataError> {
    let path = seq_dir.join("H.txt");
    if !path.is_file() {
        return Err(DataError::MissingHomography {
            scene: scene.to_string(),
            path,
        });
    }
    Homography::load(&path)
}
