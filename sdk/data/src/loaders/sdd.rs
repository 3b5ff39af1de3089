//! Stanford Drone Dataset: raw `annotations.txt`, `estimated_scales.yaml` and the TrajNet
//! split files in metres.
//!
//! Raw rows are `track_id xmin ymin xmax ymax frame lost occluded generated "label"` with pixel
//! boxes at 30 fps. The position is the box centre times the video's meter-per-pixel scale.
//! `lost = 1` rows (outside the view) are dropped and counted; by default only `Pedestrian`
//! tracks are kept. Image axes point right and down; the loaders return `x = u·s`,
//! `y = −v·s` so the world frame is right-handed.

use crate::error::DataError;
use crate::homography::Homography;
use crate::input_limits::{self, MAX_COORDINATE};
use crate::text;
use crate::track::{AgentClass, RawScene, RawTrack, Sample, SourceTiming, group_rows};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// SDD video frame rate.
pub const FPS: f64 = 30.0;

/// Largest meter-per-pixel scale accepted from `estimated_scales.yaml` (the real ones are
/// 0.03–0.05): with box corners within [`MAX_COORDINATE`] pixels, every world position then
/// stays within [`MAX_COORDINATE`] metres ([`crate::input_limits`]).
pub const MAX_SCALE: f64 = 1.0;

/// Meter-per-pixel scales per video, from `estimated_scales.yaml`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SddScales {
    /// `scene_videoN` (`gates_2`) → (scale m/px, certainty).
    pub scales: BTreeMap<String, (f64, f64)>,
    path: std::path::PathBuf,
}

impl SddScales {
    /// Parses the two-level YAML (`scene:` / `videoN:` / `scale:` and `certainty:`) by hand.
    pub fn load(path: &Path) -> Result<Self, DataError> {
        let body = text::read(path)?;
        let mut scales = BTreeMap::new();
        let mut scene: Option<String> = None;
        let mut video: Option<String> = None;
        let mut cur: (Option<f64>, Option<f64>) = (None, None);
        let mut flush = |scene: &Option<String>,
                         video: &Option<String>,
                         cur: &mut (Option<f64>, Option<f64>)| {
            if let (Some(s), Some(v), Some(scale)) = (scene, video, cur.0) {
                let n = v.trim_start_matches("video");
                scales.insert(format!("{s}_{n}"), (scale, cur.1.unwrap_or(1.0)));
            }
            *cur = (None, None);
        };
        for (i, raw) in body.lines().enumerate() {
            let ln = i + 1;
            let line = raw.split('#').next().unwrap_or("");
            if line.trim().is_empty() {
                continue;
            }
            let indent = line.len() - line.trim_start().len();
            let (key, value) = line
                .trim()
                .split_once(':')
                .ok_or_else(|| DataError::parse(path, ln, "expected `key:` or `key: value`"))?;
            let value = value.trim();
            match (indent, value.is_empty()) {
                (0, true) => {
                    flush(&scene, &video, &mut cur);
                    scene = Some(key.to_string());
                    video = None;
                }
                (_, true) => {
                    flush(&scene, &video, &mut cur);
                    if scene.is_none() {
                        return Err(DataError::parse(
                            path,
                            ln,
                            format!("video `{key}` outside a scene"),
                        ));
                    }
                    video = Some(key.to_string());
                }
                (_, false) => {
                    let v = text::number(value, path, ln, key)?;
                    match key {
                        "scale" if v > 0.0 && v <= MAX_SCALE => cur.0 = Some(v),
                        "scale" => {
                            return Err(DataError::parse(
                                path,
                                ln,
                                format!("scale must be in (0, {MAX_SCALE}] m/px, got {v}"),
                            ));
                        }
                        "certainty" => cur.1 = Some(v),
                        _ => {
                            return Err(DataError::parse(path, ln, format!("unknown key `{key}`")));
                        }
                    }
                }
            }
        }
        flush(&scene, &video, &mut cur);
        Ok(Self {
            scales,
            path: path.to_path_buf(),
        })
    }

    /// The scale of video `gates_2`, or an error naming the video and the yaml file.
    pub fn scale(&self, video: &str) -> Result<f64, DataError> {
        self.scales
            .get(video)
            .map(|s| s.0)
            .ok_or_else(|| DataError::MissingScale {
                video: video.to_string(),
                path: self.path.clone(),
            })
    }
}

/// Options of the raw SDD loader.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SddRawOptions {
    /// Keep only `Pedestrian` tracks (default true).
    pub pedestrians_only: bool,
    /// Keep `occluded = 1` rows (default true: the box is still the annotator's best estimate).
    pub keep_occluded: bool,
}

impl Default for SddRawOptions {
    fn default() -> Self {
        Self {
            pedestrians_only: true,
            keep_occluded: true,
        }
    }
}

/// One row of a raw SDD annotation file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SddRow {
    /// The annotation's track id.
    pub track_id: u64,
    /// Box centre in pixels `(u, v)`.
    pub center_px: [f64; 2],
    /// Video frame (30 fps).
    pub frame: i64,
    /// The annotator marked the agent as out of view.
    pub lost: bool,
    /// The agent is occluded.
    pub occluded: bool,
    /// The box was interpolated by the annotation tool, not drawn.
    pub generated: bool,
    /// The agent's label.
    pub class: AgentClass,
}

/// Parses every row of a raw `annotations.txt`.
pub fn parse_raw(path: &Path) -> Result<Vec<SddRow>, DataError> {
    let body = text::read(path)?;
    let mut rows = Vec::with_capacity(body.len() / 40);
    for (i, line) in body.lines().enumerate() {
        let ln = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let toks = text::fields(line, 10, path, ln)?;
        if toks.len() != 10 {
            return Err(DataError::parse(
                path,
                ln,
                format!("expected 10 columns, found {}", toks.len()),
            ));
        }
        let id = text::integer(toks[0], path, ln, "track_id")?;
        let xmin = text::number(toks[1], path, ln, "xmin")?;
        let ymin = text::number(toks[2], path, ln, "ymin")?;
        let xmax = text::number(toks[3], path, ln, "xmax")?;
        let ymax = text::number(toks[4], path, ln, "ymax")?;
        let frame = text::integer(toks[5], path, ln, "frame")?;
        let flag = |k: usize, f: &str| -> Result<bool, DataError> {
            match toks[k] {
                "0" => Ok(false),
                "1" => Ok(true),
                t => Err(DataError::parse(
                    path,
                    ln,
                    format!("{f} must be 0 or 1, found `{t}`"),
                )),
            }
        };
        let class = AgentClass::from_sdd_label(toks[9])
            .ok_or_else(|| DataError::parse(path, ln, format!("unknown label {}", toks[9])))?;
        if id < 0 || frame < 0 {
            return Err(DataError::parse(path, ln, "negative track id or frame"));
        }
        input_limits::time(frame as f64 / FPS, path, ln)?;
        for (v, f) in [
            (xmin, "xmin"),
            (ymin, "ymin"),
            (xmax, "xmax"),
            (ymax, "ymax"),
        ] {
            if v.abs() > MAX_COORDINATE {
                return Err(DataError::parse(
                    path,
                    ln,
                    format!("{f} = {v:e} px is out of range (|{f}| ≤ {MAX_COORDINATE:e} px)"),
                ));
            }
        }
        rows.push(SddRow {
            track_id: id as u64,
            center_px: [0.5 * (xmin + xmax), 0.5 * (ymin + ymax)],
            frame,
            lost: flag(6, "lost")?,
            occluded: flag(7, "occluded")?,
            generated: flag(8, "generated")?,
            class,
        });
    }
    Ok(rows)
}

/// Pixel `(u, v)` to the right-handed world frame: `(u·s, −v·s)`.
pub fn pixel_to_world(scale: &Homography, px: [f64; 2]) -> [f64; 2] {
    let w = scale.image_to_world(px).unwrap_or([f64::NAN, f64::NAN]);
    [w[0], -w[1]]
}

/// Loads a raw SDD video as scene `name`, converting pixels to metres with `scale` (m/px).
pub fn load_raw(
    path: &Path,
    scale: f64,
    name: &str,
    opts: &SddRawOptions,
) -> Result<RawScene, DataError> {
    let h = (scale > 0.0 && scale <= MAX_SCALE)
        .then(|| Homography::scale(scale))
        .flatten()
        .ok_or_else(|| {
            DataError::option(
                "sdd scale",
                format!("{scale} is not a usable m/px scale (0 < scale ≤ {MAX_SCALE})"),
            )
        })?;
    let rows = parse_raw(path)?;
    let (mut lost, mut class, mut occluded) = (0, 0, 0);
    let mut kept = Vec::with_capacity(rows.len());
    for r in rows {
        if r.lost {
            lost += 1;
        } else if opts.pedestrians_only && r.class != AgentClass::Pedestrian {
            class += 1;
        } else if r.occluded && !opts.keep_occluded {
            occluded += 1;
        } else {
            let p = pixel_to_world(&h, r.center_px);
            kept.push((
                r.track_id,
                r.class,
                Sample {
                    t: r.frame as f64 / FPS,
                    p,
                },
            ));
        }
    }
    let (tracks, dup) = group_rows(kept);
    let mut scene = RawScene {
        name: name.to_string(),
        dataset: "sdd".into(),
        format: "sdd_raw".into(),
        // Box centres jitter by a pixel or two (≈ 4–8 cm): a 0.4 s moving average removes it
        // before velocities are differenced.
        timing: SourceTiming {
            nominal_dt: 1.0 / FPS,
            max_gap: 0.5,
            smooth_window: 0.4,
        },
        tracks,
        dropped: Vec::new(),
    };
    scene.drop_count("lost_rows", lost);
    scene.drop_count("non_pedestrian_rows", class);
    scene.drop_count("occluded_rows", occluded);
    scene.drop_count("duplicate_time", dup);
    Ok(scene)
}

/// The TrajNet files' step between rows of a chunk (12 frames at 30 fps).
pub const TRAJNET_STEP: f64 = 0.4;

/// How far (m) a chunk's first position may lie from where the chunk before it, continued one
/// step at its last velocity, puts the pedestrian, for the two to be joined. Over the 47 files,
/// the nearest chunk starting one step after another ends lies a median 0.06 m from that point
/// (90 % within 0.18 m, 99 % within 0.6 m); two different people both ending and starting on
/// the same frames within half a metre of it are rarer than that.
pub const CHUNK_JOIN_DISTANCE: f64 = 0.5;

/// Loads a TrajNet-split file (`frame id x y`, metres, image axes) as scene `name`.
///
/// Every id in these files is a 20-row chunk, not a pedestrian: a longer walk is cut into
/// chunks with new ids, each starting one step after the previous one ends. Read as separate
/// tracks, every pedestrian in view for more than 8 s would vanish for a step and reappear
/// with a new id, standing and without history, which a replayed crowd turns into people
/// materialising next to the robot. So chunks are joined back into walks ([`join_chunks`]); the
/// number joined is counted under `chunks_joined`.
pub fn load_trajnet(path: &Path, name: &str) -> Result<RawScene, DataError> {
    let body = text::read(path)?;
    let mut rows = Vec::new();
    for (i, line) in body.lines().enumerate() {
        let Some((frame, id, x, y)) = text::frame_id_xy(line, path, i + 1, "agent_id")? else {
            continue;
        };
        let sample = Sample {
            t: input_limits::time(frame as f64 / FPS, path, i + 1)?,
            p: input_limits::position([x, -y], path, i + 1)?,
        };
        rows.push((id, AgentClass::Pedestrian, sample));
    }
    if rows.is_empty() {
        return Err(DataError::NoData(format!(
            "{} holds no rows",
            path.display()
        )));
    }
    let (chunks, dup) = group_rows(rows);
    let (tracks, joined) = join_chunks(chunks, TRAJNET_STEP);
    let mut scene = RawScene {
        name: name.to_string(),
        dataset: "sdd".into(),
        format: "sdd_trajnet".into(),
        timing: SourceTiming {
            nominal_dt: TRAJNET_STEP,
            max_gap: 1.0,
            smooth_window: 0.0,
        },
        tracks,
        dropped: Vec::new(),
    };
    scene.drop_count("duplicate_time", dup);
    scene.drop_count("chunks_joined", joined);
    Ok(scene)
}

/// Joins chunks of one walk: chunk `b` continues chunk `a` when it starts `step` seconds after
/// `a` ends, at most [`CHUNK_JOIN_DISTANCE`] from `a`'s last position continued one step at
/// `a`'s last velocity. Candidate pairs are taken nearest first, each chunk continuing at most
/// one and continued by at most one, so the result does not depend on the order of the ids. A
/// walk keeps the id of its first chunk. Returns the tracks, sorted by id, and how many chunks
/// were joined to a predecessor.
pub fn join_chunks(chunks: Vec<RawTrack>, step: f64) -> (Vec<RawTrack>, usize) {
    const TIME_EPS: f64 = 1e-6;
    let ends: Vec<Option<(f64, [f64; 2])>> = chunks
        .iter()
        .map(|c| {
            let last = c.samples.last()?;
            let next = match c.samples.len() {
                n if n >= 2 => {
                    let prev = c.samples[n - 2];
                    let k = step / (last.t - prev.t).max(TIME_EPS);
                    [
                        last.p[0] + (last.p[0] - prev.p[0]) * k,
                        last.p[1] + (last.p[1] - prev.p[1]) * k,
                    ]
                }
                _ => last.p,
            };
            Some((last.t + step, next))
        })
        .collect();
    // Chunks by start time (in steps), to find those starting when another one ends.
    let key = |t: f64| (t / step).round() as i64;
    let mut starting: BTreeMap<i64, Vec<usize>> = BTreeMap::new();
    for (j, c) in chunks.iter().enumerate() {
        if let Some(first) = c.samples.first() {
            starting.entry(key(first.t)).or_default().push(j);
        }
    }
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (i, end) in ends.iter().enumerate() {
        let Some((t, next)) = *end else { continue };
        for &j in starting.get(&key(t)).into_iter().flatten() {
            let first = chunks[j].samples[0];
            if j == i || (first.t - t).abs() > TIME_EPS {
                continue;
            }
            let d = (first.p[0] - next[0]).hypot(first.p[1] - next[1]);
            if d <= CHUNK_JOIN_DISTANCE {
                pairs.push((d, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| {
        a.0.total_cmp(&b.0)
            .then(chunks[a.1].id.cmp(&chunks[b.1].id))
            .then(chunks[a.2].id.cmp(&chunks[b.2].id))
    });
    let mut next: Vec<Option<usize>> = vec![None; chunks.len()];
    let mut continues = vec![false; chunks.len()];
    for &(_, i, j) in &pairs {
        if next[i].is_none() && !continues[j] {
            next[i] = Some(j);
            continues[j] = true;
        }
    }
    let joined = continues.iter().filter(|&&c| c).count();
    // Each walk from its first chunk; a successor starts after its predecessor ends, so the
    // chains are acyclic.
    let mut slots: Vec<Option<RawTrack>> = chunks.into_iter().map(Some).collect();
    let mut walks = Vec::with_capacity(slots.len() - joined);
    for first in 0..slots.len() {
        if continues[first] {
            continue;
        }
        let Some(mut walk) = slots[first].take() else {
            continue;
        };
        let mut at = next[first];
        while let Some(j) = at {
            if let Some(chunk) = slots[j].take() {
                walk.samples.extend(chunk.samples);
            }
            at = next[j];
        }
        walks.push(walk);
    }
    walks.sort_by_key(|w| w.id);
    (walks, joined)
}
