//! UCY (Crowds-by-Example) `annotation.vsp` splines.
//!
//! The file starts with the number of splines; each spline is a line with its number of
//! control points followed by that many lines `x y frame gaze_deg`, optionally followed by a
//! comment starting with ` - `. `x, y` are pixels of the 720×576 video with the origin at the
//! image centre; frames run at 25 fps; control points are sparse and irregular in time.
//! Anything after the declared splines (students03 lists line obstacles there) is ignored.
//!
//! World positions are `p_world = H·p_image` (paper Eq. 1) with the scene's `H.txt`, where the
//! image point depends on the matrix ([`VspConvention`]):
//! * the zara `H.txt` (shared by zara01/02/03) expects `(row, col)` pixels with the origin at
//!   the top-left corner, like the ETH files: `p_image = [288 − y, x + 360, 1]`. With this,
//!   vsp + H reproduces the authors' `zara01/obsmat.txt` exactly (checked in the tests);
//!   applying H to the centred `(x, y)` directly, as some loaders do, distorts the axes by
//!   23 % and 10 %.
//! * the students03 `H.txt` is a pure scale whose offsets are exactly half the image times the
//!   scale, i.e. it expects the centred `(x, y)` directly: `p_image = [x, y, 1]` (this is also
//!   what the sgan/Trajectron files contain). students01 and uni_examples have no H and, as in
//!   the OpenTraj loader, use the students03 one (see [`homography_dir`]).
//!
//! The splines are kept at their control points; the 0.1 s resampler interpolates them with
//! a cubic Hermite spline. Note that the students scenes are genuinely slow (median speed of
//! moving samples ≈ 0.7 m/s, also in the authors' metric `students03/obsmat.txt`).

use crate::error::DataError;
use crate::homography::Homography;
use crate::input_limits;
use crate::text;
use crate::track::{AgentClass, RawScene, Sample, SourceTiming, group_rows};
use std::path::{Path, PathBuf};

/// UCY video frame rate.
pub const FPS: f64 = 25.0;

/// The directory whose `H.txt` maps scene `scene`'s vsp coordinates to metres.
pub fn homography_dir(ucy_root: &Path, scene: &str) -> PathBuf {
    match scene {
        "students01" | "uni_examples" => ucy_root.join("students03"),
        _ => ucy_root.join(scene),
    }
}

/// How a scene's `H.txt` expects vsp coordinates (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VspConvention {
    /// `(row, col) = (288 − y, x + 360)`, origin top-left (zara).
    ImageRowCol,
    /// The centred vsp `(x, y)` as they are (students03 H).
    Centred,
}

impl VspConvention {
    /// The convention of the H used for UCY scene `scene`.
    pub fn of(scene: &str) -> Self {
        if scene.starts_with("zara") {
            Self::ImageRowCol
        } else {
            Self::Centred
        }
    }

    /// The image point `H` expects for a vsp point.
    pub fn image_point(self, x: f64, y: f64) -> [f64; 2] {
        match self {
            Self::ImageRowCol => [288.0 - y, x + 360.0],
            Self::Centred => [x, y],
        }
    }
}

/// Loads the homography for a UCY scene, naming the missing file if there is none.
pub fn load_homography(ucy_root: &Path, scene: &str) -> Result<Homography, DataError> {
    let path = homography_dir(ucy_root, scene).join("H.txt");
    if !path.is_file() {
        return Err(DataError::MissingHomography {
            scene: scene.to_string(),
            path,
        });
    }
    Homography::load(&path)
}

/// A control point of a vsp spline, in file units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlPoint {
    /// Horizontal image coordinate, file units.
    pub x: f64,
    /// Vertical image coordinate, file units.
    pub y: f64,
    /// Video frame.
    pub frame: i64,
    /// Gaze direction, degrees, as in the file.
    pub gaze_deg: f64,
    /// The 1-based line of the file it was read from.
    pub line: usize,
}

/// Largest number of splines, and of control points in one spline, a vsp file may declare
/// (the real ones have at most 434 splines of at most 59 points). A
/// count must also fit in the lines that follow it: every spline and control point takes one.
pub const MAX_VSP_COUNT: usize = 1_000_000;

/// Parses the splines of an `annotation.vsp` file (file units, no homography). Counts are
/// bounded by [`MAX_VSP_COUNT`] and by the lines left in the file, frames by
/// [`crate::input_limits::MAX_TIME`]; within a spline frames never decrease.
pub fn parse_vsp(path: &Path) -> Result<Vec<Vec<ControlPoint>>, DataError> {
    let body = text::read(path)?;
    let lines: Vec<(usize, &str)> = body
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .collect();
    // A declared count, checked against the bound and the `left` lines that remain.
    let count = |l: &str, ln: usize, what: &str, left: usize| -> Result<usize, DataError> {
        let tok = l.split_whitespace().next().unwrap_or("");
        let n = tok.parse::<usize>().map_err(|_| {
            DataError::parse(
                path,
                ln,
                format!("expected the number of {what}, found `{tok}`"),
            )
        })?;
        if n > MAX_VSP_COUNT {
            return Err(DataError::parse(
                path,
                ln,
                format!("{n} {what} is more than the limit of {MAX_VSP_COUNT}"),
            ));
        }
        if n > left {
            return Err(DataError::parse(
                path,
                ln,
                format!("declares {n} {what} but only {left} non-empty lines follow"),
            ));
        }
        Ok(n)
    };
    let mut lines = lines.iter().copied();
    let (i0, first) = lines
        .next()
        .ok_or_else(|| DataError::parse(path, 1, "empty file"))?;
    let n_splines = count(first, i0 + 1, "splines", lines.len())?;
    let mut splines = Vec::with_capacity(n_splines);
    for s in 0..n_splines {
        let (i, l) = lines.next().ok_or_else(|| {
            DataError::parse(
                path,
                i0 + 1,
                format!("file ends before spline {} of {n_splines}", s + 1),
            )
        })?;
        let k = count(l, i + 1, "control points", lines.len())?;
        let mut pts = Vec::with_capacity(k);
        for _ in 0..k {
            let (j, l) = lines.next().ok_or_else(|| {
                DataError::parse(path, i + 1, format!("file ends inside spline {}", s + 1))
            })?;
            let ln = j + 1;
            let toks = text::fields(l, 4, path, ln)?;
            if toks.len() > 4 && toks[4] != "-" {
                return Err(DataError::parse(
                    path,
                    ln,
                    "a control point is `x y frame gaze` optionally followed by ` - comment`",
                ));
            }
            let frame = text::integer(toks[2], path, ln, "frame")?;
            input_limits::time(frame as f64 / FPS, path, ln)?;
            // A spline is a path through time: a frame before the previous one would make the
            // walker jump back (the real files never do; their frames only increase).
            if let Some(prev) = pts.last().map(|p: &ControlPoint| p.frame)
                && frame < prev
            {
                return Err(DataError::parse(
                    path,
                    ln,
                    format!(
                        "frame {frame} of spline {} comes after frame {prev}: a spline's frames \
                         must not go backwards",
                        s + 1
                    ),
                ));
            }
            pts.push(ControlPoint {
                x: text::number(toks[0], path, ln, "x")?,
                y: text::number(toks[1], path, ln, "y")?,
                frame,
                gaze_deg: text::number(toks[3], path, ln, "gaze")?,
                line: ln,
            });
        }
        splines.push(pts);
    }
    Ok(splines)
}

/// Loads a UCY scene's splines and maps them to metres with `h` (Eq. 1) under `convention`.
/// The pedestrian id is the spline index + 1 (as in the benchmark files).
pub fn load_vsp(
    path: &Path,
    h: &Homography,
    convention: VspConvention,
    name: &str,
) -> Result<RawScene, DataError> {
    let splines = parse_vsp(path)?;
    let mut rows = Vec::new();
    let mut spacing = Vec::new();
    let mut horizon = 0;
    for (i, pts) in splines.iter().enumerate() {
        for w in pts.windows(2) {
            if w[1].frame > w[0].frame {
                spacing.push((w[1].frame - w[0].frame) as f64 / FPS);
            }
        }
        for cp in pts {
            match h.image_to_world(convention.image_point(cp.x, cp.y)) {
                Some(p) => rows.push((
                    i as u64 + 1,
                    AgentClass::Pedestrian,
                    Sample {
                        t: cp.frame as f64 / FPS,
                        p: input_limits::position(p, path, cp.line)?,
                    },
                )),
                None => horizon += 1,
            }
        }
    }
    spacing.sort_by(f64::total_cmp);
    let nominal = spacing.get(spacing.len() / 2).copied().unwrap_or(0.4);
    let (tracks, dup) = group_rows(rows);
    let mut scene = RawScene {
        name: name.to_string(),
        dataset: "ucy".into(),
        format: "ucy_vsp".into(),
        // Control points are sparse by design: never split a spline at a "gap".
        timing: SourceTiming {
            nominal_dt: nominal,
            max_gap: f64::INFINITY,
            smooth_window: 0.0,
        },
        tracks,
        dropped: Vec::new(),
    };
    scene.drop_count("duplicate_time", dup);
    scene.drop_count("on_horizon", horizon);
    Ok(scene)
}
