//! Resampling raw tracks to the 0.1 s grid, with velocity and heading.
//!
//! Rules (all in [`ResampleOptions`]):
//! * A track is split where two consecutive samples are more than the source's `max_gap`
//!   apart (short gaps are bridged by the interpolant). Segments shorter than `min_duration`
//!   or with fewer than two samples are skipped and counted.
//! * Sources with jittery positions (SDD raw boxes at 30 fps) are first smoothed with a
//!   centred moving average over the source's `smooth_window`.
//! * Positions are interpolated at the absolute times `k·dt` (so all tracks of a scene share
//!   step indices) with a cubic Hermite spline whose knot tangents are the non-uniform
//!   Catmull-Rom slopes `(p[i+1] − p[i−1]) / (t[i+1] − t[i−1])`, one-sided at the ends. It
//!   passes through every sample and handles the irregular UCY control points.
//! * A track is cut where it jumps: where one step between its samples (before smoothing) is
//!   faster than [`TRACK_SPEED_LIMIT`], and again where one grid step is (the interpolant can
//!   overshoot). That is a tracking error, and no observation may carry such a speed; the
//!   samples inside a run of such steps are dropped, the pieces follow the `min_duration` rule.
//! * Velocity is the central difference of the resampled positions (one-sided at the ends).
//! * Heading θ is the direction of the displacement over ±`heading_window` steps. When that
//!   displacement corresponds to less than `heading_speed` (nearly stationary), the last
//!   valid heading is held; leading stationary samples take the first valid heading; a track
//!   that never moves gets θ = 0 and is reported by [`Track::is_stationary`].

use crate::error::DataError;
use crate::track::{AgentClass, RawScene, RawTrack, Sample};
use human2nav_core::Pose2;
use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Fastest grid step (m/s) a track keeps: 1 % under the bound every observation is checked
/// against ([`human2nav_core::planner::MAX_SPEED`]), so that the velocities a simulator
/// interpolates between grid positions stay under it through rounding. A faster step is cut.
pub const TRACK_SPEED_LIMIT: f64 = 0.99 * human2nav_core::planner::MAX_SPEED;

/// Whether moving from `a` to `b` in `dt` seconds is faster than [`TRACK_SPEED_LIMIT`] (a
/// jump, not a motion): the one rule of the raw samples, the grid and episode files.
pub fn is_jump(a: [f64; 2], b: [f64; 2], dt: f64) -> bool {
    (b[0] - a[0]).hypot(b[1] - a[1]) > TRACK_SPEED_LIMIT * dt
}

/// Options of [`resample`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ResampleOptions {
    /// Output time step, seconds (default 0.1, the paper's sampling interval).
    pub dt: f64,
    /// Segments shorter than this are skipped, seconds (default 1.0).
    pub min_duration: f64,
    /// Below this speed (m/s) the heading is held instead of taken from motion (default 0.2).
    pub heading_speed: f64,
    /// Half-width, in steps, of the displacement used for the heading (default 2, ±0.2 s; at
    /// most 1000).
    pub heading_window: usize,
}

impl Default for ResampleOptions {
    fn default() -> Self {
        Self {
            dt: 0.1,
            min_duration: 1.0,
            heading_speed: 0.2,
            heading_window: 2,
        }
    }
}

impl ResampleOptions {
    /// Checks every option is usable.
    pub fn validate(&self) -> Result<(), DataError> {
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(DataError::option(
                "resample.dt",
                "must be finite and positive",
            ));
        }
        if !(self.min_duration.is_finite() && self.min_duration >= 0.0) {
            return Err(DataError::option(
                "resample.min_duration",
                "must be finite and >= 0",
            ));
        }
        if !(self.heading_speed.is_finite() && self.heading_speed >= 0.0) {
            return Err(DataError::option(
                "resample.heading_speed",
                "must be finite and >= 0",
            ));
        }
        if self.heading_window == 0 {
            return Err(DataError::option(
                "resample.heading_window",
                "must be at least 1",
            ));
        }
        crate::input_limits::count_at_most(self.heading_window, 1000, "resample.heading_window")?;
        crate::input_limits::option_in(
            self.min_duration,
            0.0,
            crate::input_limits::MAX_TIME,
            "resample.min_duration",
        )?;
        Ok(())
    }
}

/// One agent on the regular grid: sample `i` is at time `(start + i)·dt`.
#[derive(Clone, Debug, PartialEq)]
pub struct Track {
    /// Unique within its scene (segments of one source track get distinct ids).
    pub id: u64,
    /// The identity in the source file.
    pub source_id: u64,
    /// What kind of agent it is.
    pub class: AgentClass,
    /// Global step index of the first sample.
    pub start: i64,
    /// World positions, metres, one per step.
    pub positions: Vec<[f64; 2]>,
    /// World velocities, m/s, one per step (finite differences).
    pub velocities: Vec<[f64; 2]>,
    /// Headings, radians, one per step (from motion, held while the agent stands).
    pub headings: Vec<f64>,
}

impl Track {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when the track holds no sample.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// One past the last global step.
    pub fn end(&self) -> i64 {
        self.start + self.len() as i64
    }

    /// The local index of global step `step`, if the track exists then.
    pub fn local(&self, step: i64) -> Option<usize> {
        (step >= self.start && step < self.end()).then(|| (step - self.start) as usize)
    }

    /// The pose `(x, y, θ)` at local index `i`.
    pub fn pose(&self, i: usize) -> Pose2 {
        Pose2::new(self.positions[i][0], self.positions[i][1], self.headings[i])
    }

    /// True when the heading never came from motion (θ is the fallback 0).
    pub fn is_stationary(&self, opts: &ResampleOptions) -> bool {
        headings(&self.positions, opts.dt, opts).1
    }
}

/// Counts of what resampling skipped.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ResampleStats {
    /// Tracks read from the loader.
    pub input_tracks: usize,
    /// Tracks on the grid (a split track counts once per segment).
    pub output_tracks: usize,
    /// Tracks without a sample, skipped.
    pub empty_tracks: usize,
    /// Segments too short for the grid (`min_duration`, or under two grid steps), skipped.
    pub short_segments: usize,
    /// Tracks split where a gap exceeded the source's `max_gap`.
    pub gap_splits: usize,
    /// Jumps (runs of grid steps faster than [`TRACK_SPEED_LIMIT`]) a track was cut at (a
    /// track cut twice counts twice).
    pub speed_splits: usize,
}

/// A scene on the regular grid.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Scene name, `dataset/scene`.
    pub name: String,
    /// Dataset name (`eth`, `ucy`, `sdd`, `synthetic`).
    pub dataset: String,
    /// Loader format the scene came from.
    pub format: String,
    /// Grid step, seconds.
    pub dt: f64,
    /// The agents on the grid.
    pub tracks: Vec<Track>,
    /// What resampling skipped.
    pub stats: ResampleStats,
    /// The loader's dropped-row counters, carried along for reports.
    pub dropped: Vec<(String, usize)>,
}

/// For every global step of a scene, the tracks present then.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepIndex {
    /// The first global step indexed.
    pub first: i64,
    /// Per step from `first`, the indices of the tracks present.
    pub active: Vec<Vec<u32>>,
}

impl StepIndex {
    /// Indices (into `Scene::tracks`) of the tracks present at global `step`.
    pub fn at(&self, step: i64) -> &[u32] {
        let k = step - self.first;
        if k < 0 {
            return &[];
        }
        self.active
            .get(k as usize)
            .map(Vec::as_slice)
            .unwrap_or(&[])
    }
}

impl Scene {
    /// `[first, last]` global steps covered by any track, or `None` for an empty scene.
    pub fn step_range(&self) -> Option<(i64, i64)> {
        let first = self.tracks.iter().map(|t| t.start).min()?;
        let last = self.tracks.iter().map(|t| t.end() - 1).max()?;
        Some((first, last))
    }

    /// Total time covered by the scene, seconds.
    pub fn duration(&self) -> f64 {
        self.step_range()
            .map(|(a, b)| (b - a) as f64 * self.dt)
            .unwrap_or(0.0)
    }

    /// Builds the per-step index of present tracks.
    pub fn index(&self) -> StepIndex {
        let Some((first, last)) = self.step_range() else {
            return StepIndex::default();
        };
        let mut active = vec![Vec::new(); (last - first + 1) as usize];
        for (i, t) in self.tracks.iter().enumerate() {
            for s in t.start..t.end() {
                active[(s - first) as usize].push(i as u32);
            }
        }
        StepIndex { first, active }
    }

    /// Speeds (m/s) of every sample moving faster than `min_speed`.
    pub fn speeds(&self, min_speed: f64) -> Vec<f64> {
        self.tracks
            .iter()
            .flat_map(|t| t.velocities.iter().map(|v| v[0].hypot(v[1])))
            .filter(|&s| s > min_speed)
            .collect()
    }
}

/// The median of a list (`None` when empty).
pub fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// Resamples every track of a raw scene to the regular grid.
pub fn resample(raw: &RawScene, opts: &ResampleOptions) -> Scene {
    let mut stats = ResampleStats {
        input_tracks: raw.tracks.len(),
        ..Default::default()
    };
    let mut tracks = Vec::new();
    for rt in &raw.tracks {
        resample_track(rt, raw, opts, &mut stats, &mut tracks);
    }
    stats.output_tracks = tracks.len();
    Scene {
        name: raw.name.clone(),
        dataset: raw.dataset.clone(),
        format: raw.format.clone(),
        dt: opts.dt,
        tracks,
        stats,
        dropped: raw.dropped.clone(),
    }
}

fn resample_track(
    rt: &RawTrack,
    raw: &RawScene,
    opts: &ResampleOptions,
    stats: &mut ResampleStats,
    out: &mut Vec<Track>,
) {
    if rt.samples.is_empty() {
        stats.empty_tracks += 1;
        return;
    }
    // Split at gaps.
    let mut segments: Vec<&[Sample]> = Vec::new();
    let mut begin = 0;
    for i in 1..rt.samples.len() {
        if rt.samples[i].t - rt.samples[i - 1].t > raw.timing.max_gap {
            segments.push(&rt.samples[begin..i]);
            begin = i;
            stats.gap_splits += 1;
        }
    }
    segments.push(&rt.samples[begin..]);
    // Cut at jumps, before smoothing (which would spread a jump over its window).
    let too_fast = |a: &Sample, b: &Sample| is_jump(a.p, b.p, b.t - a.t);
    let mut pieces = Vec::new();
    for seg in segments {
        let (ranges, jumps) = cut_at_jumps(seg, too_fast);
        stats.speed_splits += jumps;
        pieces.extend(ranges.into_iter().map(|r| &seg[r]));
    }
    for seg in pieces {
        let duration = seg[seg.len() - 1].t - seg[0].t;
        if seg.len() < 2 || duration < opts.min_duration {
            stats.short_segments += 1;
            continue;
        }
        let smoothed;
        let seg = if raw.timing.smooth_window > 0.0 {
            smoothed = moving_average(seg, raw.timing.smooth_window);
            &smoothed[..]
        } else {
            seg
        };
        let k0 = (seg[0].t / opts.dt - 1e-6).ceil() as i64;
        let k1 = (seg[seg.len() - 1].t / opts.dt + 1e-6).floor() as i64;
        if k1 - k0 < 1 {
            stats.short_segments += 1;
            continue;
        }
        let times: Vec<f64> = (k0..=k1).map(|k| k as f64 * opts.dt).collect();
        let positions = hermite(seg, &times);
        if positions.iter().flatten().any(|v| !v.is_finite()) {
            stats.short_segments += 1;
            continue;
        }
        // The interpolant can overshoot its samples' speeds (up to twice): cut again on the
        // grid, so that no grid step is faster than the limit. A piece of a track cut here is
        // kept when it spans `min_duration` on the grid.
        let (ranges, jumps) = cut_at_jumps(&positions, |a, b| is_jump(*a, *b, opts.dt));
        stats.speed_splits += jumps;
        for r in ranges {
            let piece = &positions[r.clone()];
            if jumps > 0
                && (piece.len() < 2 || (piece.len() - 1) as f64 * opts.dt < opts.min_duration)
            {
                stats.short_segments += 1;
                continue;
            }
            out.push(Track {
                id: out.len() as u64,
                source_id: rt.id,
                class: rt.class,
                start: k0 + r.start as i64,
                positions: piece.to_vec(),
                velocities: central_difference(piece, opts.dt),
                headings: headings(piece, opts.dt, opts).0,
            });
        }
    }
}

/// The pieces of `items` left by cutting at jumps (`jump(a, b)`: the step from `a` to `b` is
/// not a possible motion) and the number of jumps. A run of consecutive jump steps is one
/// jump, and the items inside it are dropped; each piece of a non-empty list has an item.
fn cut_at_jumps<T>(items: &[T], jump: impl Fn(&T, &T) -> bool) -> (Vec<Range<usize>>, usize) {
    let mut pieces = Vec::new();
    let mut jumps = 0;
    let mut begin = 0;
    let mut in_jump = false;
    for i in 1..items.len() {
        if !jump(&items[i - 1], &items[i]) {
            in_jump = false;
            continue;
        }
        if !in_jump {
            pieces.push(begin..i);
            jumps += 1;
            in_jump = true;
        }
        begin = i;
    }
    pieces.push(begin..items.len());
    (pieces, jumps)
}

/// Centred moving average over samples within ±`window/2` seconds.
pub fn moving_average(s: &[Sample], window: f64) -> Vec<Sample> {
    let half = 0.5 * window;
    let (mut lo, mut hi) = (0usize, 0usize);
    let mut sum = [0.0f64; 2];
    let mut out = Vec::with_capacity(s.len());
    for i in 0..s.len() {
        while hi < s.len() && s[hi].t <= s[i].t + half + 1e-9 {
            sum[0] += s[hi].p[0];
            sum[1] += s[hi].p[1];
            hi += 1;
        }
        while s[lo].t < s[i].t - half - 1e-9 {
            sum[0] -= s[lo].p[0];
            sum[1] -= s[lo].p[1];
            lo += 1;
        }
        let n = (hi - lo) as f64;
        out.push(Sample {
            t: s[i].t,
            p: [sum[0] / n, sum[1] / n],
        });
    }
    out
}

/// Cubic Hermite interpolation through the samples at the (sorted, in-range) `times`.
pub fn hermite(s: &[Sample], times: &[f64]) -> Vec<[f64; 2]> {
    let n = s.len();
    let slope = |i: usize| -> [f64; 2] {
        let (a, b) = if i == 0 {
            (0, 1)
        } else if i == n - 1 {
            (n - 2, n - 1)
        } else {
            (i - 1, i + 1)
        };
        let dt = s[b].t - s[a].t;
        [(s[b].p[0] - s[a].p[0]) / dt, (s[b].p[1] - s[a].p[1]) / dt]
    };
    let mut out = Vec::with_capacity(times.len());
    let mut j = 0;
    for &t in times {
        while j + 2 < n && s[j + 1].t < t {
            j += 1;
        }
        let (a, b) = (&s[j], &s[j + 1]);
        let h = b.t - a.t;
        let u = ((t - a.t) / h).clamp(0.0, 1.0);
        let (u2, u3) = (u * u, u * u * u);
        let h00 = 2.0 * u3 - 3.0 * u2 + 1.0;
        let h10 = u3 - 2.0 * u2 + u;
        let h01 = -2.0 * u3 + 3.0 * u2;
        let h11 = u3 - u2;
        let (ma, mb) = (slope(j), slope(j + 1));
        out.push([
            h00 * a.p[0] + h10 * h * ma[0] + h01 * b.p[0] + h11 * h * mb[0],
            h00 * a.p[1] + h10 * h * ma[1] + h01 * b.p[1] + h11 * h * mb[1],
        ]);
    }
    out
}

/// Central differences (one-sided at the ends) of positions `dt` apart.
pub fn central_difference(p: &[[f64; 2]], dt: f64) -> Vec<[f64; 2]> {
    let n = p.len();
    (0..n)
        .map(|i| {
            if n < 2 {
                return [0.0, 0.0];
            }
            let a = i.saturating_sub(1);
            let b = (i + 1).min(n - 1);
            let span = (b - a) as f64 * dt;
            [(p[b][0] - p[a][0]) / span, (p[b][1] - p[a][1]) / span]
        })
        .collect()
}

/// Headings from motion with the hold rule of the module docs; second value: never moved.
pub fn headings(p: &[[f64; 2]], dt: f64, opts: &ResampleOptions) -> (Vec<f64>, bool) {
    let n = p.len();
    let w = opts.heading_window;
    let raw: Vec<Option<f64>> = (0..n)
        .map(|i| {
            let a = i.saturating_sub(w);
            let b = (i + w).min(n.saturating_sub(1));
            if b <= a {
                return None;
            }
            let d = [p[b][0] - p[a][0], p[b][1] - p[a][1]];
            let speed = d[0].hypot(d[1]) / ((b - a) as f64 * dt);
            (speed >= opts.heading_speed && speed > 0.0).then(|| d[1].atan2(d[0]))
        })
        .collect();
    let first = raw.iter().flatten().next().copied();
    let mut last = first.unwrap_or(0.0);
    let out = raw
        .into_iter()
        .map(|h| {
            if let Some(h) = h {
                last = h;
            }
            last
        })
        .collect();
    (out, first.is_none())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::SourceTiming;
    use approx::assert_relative_eq;

    fn scene(samples: Vec<Sample>, timing: SourceTiming) -> RawScene {
        RawScene {
            name: "t/t".into(),
            dataset: "t".into(),
            format: "test".into(),
            timing,
            tracks: vec![RawTrack {
                id: 9,
                class: AgentClass::Pedestrian,
                samples,
            }],
            dropped: Vec::new(),
        }
    }

    const TIMING: SourceTiming = SourceTiming {
        nominal_dt: 0.4,
        max_gap: 1.0,
        smooth_window: 0.0,
    };

    #[test]
    fn hermite_reproduces_quadratics_on_uniform_knots_and_lines_on_any_knots() {
        // Catmull-Rom slopes are exact for quadratics on uniform knots (interior intervals).
        let s: Vec<Sample> = (0..6)
            .map(|i| {
                let t = 0.4 * i as f64;
                Sample {
                    t,
                    p: [t * t, 3.0 - 2.0 * t],
                }
            })
            .collect();
        let out = hermite(&s, &[0.5, 1.0, 1.3]);
        for (o, t) in out.iter().zip([0.5, 1.0, 1.3]) {
            assert_relative_eq!(o[0], t * t, epsilon = 1e-12);
            assert_relative_eq!(o[1], 3.0 - 2.0 * t, epsilon = 1e-12);
        }
        // Irregular knots, linear motion: exact everywhere.
        let s: Vec<Sample> = [0.0, 0.3, 1.7, 2.0, 4.1]
            .iter()
            .map(|&t| Sample {
                t,
                p: [1.2 * t, -0.4 * t],
            })
            .collect();
        for (o, t) in hermite(&s, &[0.1, 1.0, 3.3, 4.1])
            .iter()
            .zip([0.1, 1.0, 3.3, 4.1])
        {
            assert_relative_eq!(o[0], 1.2 * t, epsilon = 1e-12);
            assert_relative_eq!(o[1], -0.4 * t, epsilon = 1e-12);
        }
    }

    #[test]
    fn straight_walk_gives_constant_velocity_and_heading() {
        let s: Vec<Sample> = (0..11)
            .map(|i| {
                let t = 0.4 * i as f64 + 0.05;
                Sample {
                    t,
                    p: [1.0 + 0.8 * t, 2.0 + 0.6 * t],
                }
            })
            .collect();
        let sc = resample(&scene(s, TIMING), &ResampleOptions::default());
        assert_eq!(sc.tracks.len(), 1);
        let t = &sc.tracks[0];
        assert_eq!(t.start, 1); // first grid time 0.1 s ≥ 0.05 s
        assert_eq!(t.end(), 41); // last 4.05 s → step 40
        for (v, h) in t.velocities.iter().zip(&t.headings) {
            assert_relative_eq!(v[0], 0.8, epsilon = 1e-9);
            assert_relative_eq!(v[1], 0.6, epsilon = 1e-9);
            assert_relative_eq!(*h, 0.6f64.atan2(0.8), epsilon = 1e-9);
        }
        assert_relative_eq!(t.positions[0][0], 1.0 + 0.08, epsilon = 1e-12);
    }

    #[test]
    fn gaps_split_and_short_segments_are_counted() {
        let mut s: Vec<Sample> = (0..5)
            .map(|i| Sample {
                t: 0.4 * i as f64,
                p: [0.4 * i as f64, 0.0],
            })
            .collect();
        s.extend((0..2).map(|i| Sample {
            t: 5.0 + 0.4 * i as f64,
            p: [5.0, 0.0],
        }));
        let sc = resample(&scene(s, TIMING), &ResampleOptions::default());
        assert_eq!(sc.stats.gap_splits, 1);
        assert_eq!(sc.stats.short_segments, 1);
        assert_eq!(sc.tracks.len(), 1);
        let empty = RawScene {
            tracks: vec![RawTrack {
                id: 1,
                class: AgentClass::Pedestrian,
                samples: vec![],
            }],
            ..scene(vec![], TIMING)
        };
        let sc = resample(&empty, &ResampleOptions::default());
        assert_eq!(sc.stats.empty_tracks, 1);
        assert!(sc.tracks.is_empty());
    }

    #[test]
    fn a_jump_faster_than_any_walker_cuts_the_track() {
        // 1 m/s along x for 3 s, a 20 m jump in one 0.4 s step (50 m/s), 3 s more; then a
        // second jump and a piece too short to keep.
        let walk = |t0: f64, x0: f64, n: usize| {
            (0..n).map(move |i| Sample {
                t: t0 + 0.4 * i as f64,
                p: [x0 + 0.4 * i as f64, 0.0],
            })
        };
        let s: Vec<Sample> = walk(0.0, 0.0, 8)
            .chain(walk(3.2, 23.2, 8))
            .chain(walk(6.4, 60.0, 2))
            .collect();
        let sc = resample(&scene(s, TIMING), &ResampleOptions::default());
        assert_eq!(sc.stats.gap_splits, 0);
        assert_eq!(sc.stats.speed_splits, 2);
        assert_eq!(sc.stats.short_segments, 1, "the 0.4 s piece is skipped");
        assert_eq!(sc.tracks.len(), 2);
        for t in &sc.tracks {
            for w in t.positions.windows(2) {
                let step = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
                assert!(step <= TRACK_SPEED_LIMIT * 0.1, "{step} m in a step");
            }
            for v in &t.velocities {
                assert!(v[0].hypot(v[1]) < 2.0, "{v:?}");
            }
            assert_eq!(t.positions.len(), t.velocities.len());
            assert_eq!(t.positions.len(), t.headings.len());
        }
        // The pieces keep their place on the grid: the first ends before the jump, the
        // second starts after it.
        let (a, b) = (&sc.tracks[0], &sc.tracks[1]);
        assert_eq!(a.start, 0);
        assert!(
            a.end() <= b.start && b.start <= 33,
            "{} {}",
            a.end(),
            b.start
        );
        assert!((b.positions[0][0] - (23.2 + 0.1 * b.start as f64 - 3.2)).abs() < 0.5);
        // Samples under the limit whose interpolant overshoots it (a 29 m/s out-and-back in
        // 0.8 s, between two walks): cut on the grid.
        let s: Vec<Sample> = walk(0.0, 0.0, 8)
            .chain([(3.2, 14.4), (3.6, 3.6)].map(|(t, x)| Sample { t, p: [x, 0.0] }))
            .chain(walk(4.0, 4.0, 8))
            .collect();
        let sc = resample(&scene(s, TIMING), &ResampleOptions::default());
        assert!(sc.stats.speed_splits >= 1);
        assert!(!sc.tracks.is_empty());
        for t in &sc.tracks {
            for w in t.positions.windows(2) {
                let step = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
                assert!(step <= TRACK_SPEED_LIMIT * 0.1, "{step} m in a step");
            }
        }
        // The cuts as such: a run of jump steps is one jump, the items inside it dropped.
        let jump = |a: &f64, b: &f64| (b - a).abs() > 5.0;
        let (pieces, jumps) = cut_at_jumps(&[0.0, 1.0, 10.0, 20.0, 21.0, 30.0], jump);
        assert_eq!((pieces, jumps), (vec![0..2, 3..5, 5..6], 2));
        let one_piece = |items: &[f64]| {
            let (pieces, jumps) = cut_at_jumps(items, jump);
            (pieces.len(), pieces[0].clone(), jumps)
        };
        assert_eq!(one_piece(&[0.0, 1.0]), (1, 0..2, 0));
        assert_eq!(one_piece(&[]), (1, 0..0, 0));
        // A walk at 2 m/s is not cut.
        let s: Vec<Sample> = (0..20)
            .map(|i| Sample {
                t: 0.4 * i as f64,
                p: [0.8 * i as f64, 0.0],
            })
            .collect();
        let sc = resample(&scene(s, TIMING), &ResampleOptions::default());
        assert_eq!((sc.stats.speed_splits, sc.tracks.len()), (0, 1));
    }

    #[test]
    fn heading_is_held_while_standing() {
        // Walk +x for 2 s, stand 2 s, walk +y for 2 s.
        let mut p = Vec::new();
        for i in 0..=20 {
            p.push([0.1 * i as f64, 0.0]);
        }
        for _ in 0..20 {
            p.push([2.0, 0.0]);
        }
        for i in 1..=20 {
            p.push([2.0, 0.1 * i as f64]);
        }
        let opts = ResampleOptions::default();
        let (h, never) = headings(&p, 0.1, &opts);
        assert!(!never);
        assert_relative_eq!(h[5], 0.0, epsilon = 1e-12);
        assert_relative_eq!(h[30], 0.0, epsilon = 1e-12); // standing: held
        assert_relative_eq!(h[55], std::f64::consts::FRAC_PI_2, epsilon = 1e-12);
        let (h, never) = headings(&[[1.0, 1.0]; 10], 0.1, &opts);
        assert!(never && h.iter().all(|&x| x == 0.0));
    }

    #[test]
    fn moving_average_removes_alternating_jitter() {
        let s: Vec<Sample> = (0..60)
            .map(|i| {
                let t = i as f64 / 30.0;
                Sample {
                    t,
                    p: [t + if i % 2 == 0 { 0.04 } else { -0.04 }, 0.0],
                }
            })
            .collect();
        let m = moving_average(&s, 0.4);
        // Window of 13 samples (odd): residual jitter 0.04/13, trend preserved in the middle.
        for q in &m[10..50] {
            assert!((q.p[0] - q.t).abs() <= 0.04 / 13.0 + 1e-12);
        }
    }
}
