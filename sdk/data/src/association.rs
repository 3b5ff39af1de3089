//! Detection-to-track association with the Hungarian algorithm (paper §III-A: "Detections are
//! associated across frames using the Hungarian algorithm").
//!
//! # Tracker ([`associate`], options in [`TrackerOptions`])
//! Every live track predicts its position with constant velocity. The assignment problem of a
//! frame is `tracks × (detections + tracks)`: a real pair costs the distance between
//! prediction and detection (pairs farther than `gate` are forbidden), and each track has a
//! private "miss" column costing `gate`, so the optimum matches exactly the pairs that beat
//! leaving both unmatched. Unmatched detections start new tracks (birth); a track not matched
//! for longer than `max_missed` seconds ends (death), which also bridges short gaps such as
//! occlusions. Velocity is an exponential average (`velocity_gain`) of the displacement per
//! second between matches.
//!
//! # Evaluation ([`evaluate`])
//! Against annotated identities: an ID switch is counted whenever two consecutive detections
//! of one annotated identity carry different track ids; the fraction of correctly associated
//! detections is the IDF1-style `IDTP / detections`, where `IDTP` is the number of detections
//! shared by annotated identities and tracks under the one-to-one identity matching that
//! maximises it (solved with the same Hungarian routine).

use crate::error::DataError;
use crate::loaders::sdd::SddRow;
use crate::track::AgentClass;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Minimum-cost assignment: `cost` is `rows × cols` row-major. Returns each row's column.
/// When `rows ≤ cols` every row is assigned; otherwise `cols` rows are and the rest get
/// `None`. O(n²·m) (shortest augmenting paths with potentials).
//
// Hand-written on purpose, not `pathfinding::kuhn_munkres_min`: that solver needs integer-like
// weights (`Ord`, exact zero tests on slacks), so these f64 costs would have to be scaled and
// rounded to i64. The scale must leave room for sums of `rows` weights and is set by the
// largest cost, which in `associate` is a forbidden pair at 1e6·gate, so distances would only
// be resolved to about 1e6·gate·(rows + 1)/2⁶², and assignments whose totals differ by less
// than that would be decided by rounding, not by cost. Example (test
// `tracker_near_tie_is_decided_by_cost_next_to_forbidden_pairs`):
// 2 tracks × (2 detections + 2 miss columns) with costs [[0.5 + 4e-14, 0.5 + 6e-14, 1, 1e6],
// [0.5, 0.5 + 4e-14, 1e6, 1]]: this solver returns the optimum (1, 0) of total 1 + 6e-14; at
// the largest safe scale (2⁶²/(3·1e6) ≈ 1.5e12) every real pair rounds to the same weight and
// kuhn_munkres_min returns (0, 1), total 1 + 8e-14. (On this module's other tests the two
// solvers agree, ties included.)
pub fn hungarian(cost: &[f64], rows: usize, cols: usize) -> Vec<Option<usize>> {
    assert_eq!(
        cost.len(),
        rows * cols,
        "hungarian: cost has the wrong length"
    );
    if rows == 0 || cols == 0 {
        return vec![None; rows];
    }
    if rows > cols {
        let mut t = vec![0.0; rows * cols];
        for i in 0..rows {
            for j in 0..cols {
                t[j * rows + i] = cost[i * cols + j];
            }
        }
        let by_col = hungarian(&t, cols, rows);
        let mut out = vec![None; rows];
        for (j, r) in by_col.into_iter().enumerate() {
            if let Some(i) = r {
                out[i] = Some(j);
            }
        }
        return out;
    }
    let (n, m) = (rows, cols);
    // 1-based arrays as in the classic formulation; p[j] = row matched to column j.
    let mut u = vec![0.0f64; n + 1];
    let mut v = vec![0.0f64; m + 1];
    let mut p = vec![0usize; m + 1];
    let mut way = vec![0usize; m + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0usize;
        let mut minv = vec![f64::INFINITY; m + 1];
        let mut used = vec![false; m + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0usize;
            for j in 1..=m {
                if !used[j] {
                    let cur = cost[(i0 - 1) * m + (j - 1)] - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=m {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut out = vec![None; n];
    for j in 1..=m {
        if p[j] != 0 {
            out[p[j] - 1] = Some(j - 1);
        }
    }
    out
}

/// Options of the tracker (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerOptions {
    /// Largest prediction-to-detection distance that may be matched, metres. Default 1.0.
    pub gate: f64,
    /// A track unmatched for longer than this ends, seconds. Default 0.5.
    pub max_missed: f64,
    /// Weight of the newest displacement in the velocity average. Default 0.6.
    pub velocity_gain: f64,
    /// Evaluation on SDD: use every `frame_step`-th video frame (3 = 10 Hz). Default 3.
    pub frame_step: usize,
}

impl Default for TrackerOptions {
    fn default() -> Self {
        Self {
            gate: 1.0,
            max_missed: 0.5,
            velocity_gain: 0.6,
            frame_step: 3,
        }
    }
}

impl TrackerOptions {
    /// Checks every option is usable.
    pub fn validate(&self) -> Result<(), DataError> {
        if !(self.gate.is_finite() && self.gate > 0.0) {
            return Err(DataError::option(
                "association.gate",
                "must be finite and positive",
            ));
        }
        if !(self.max_missed.is_finite() && self.max_missed >= 0.0) {
            return Err(DataError::option(
                "association.max_missed",
                "must be finite and >= 0",
            ));
        }
        if !(self.velocity_gain > 0.0 && self.velocity_gain <= 1.0) {
            return Err(DataError::option(
                "association.velocity_gain",
                "must be in (0, 1]",
            ));
        }
        if self.frame_step == 0 {
            return Err(DataError::option(
                "association.frame_step",
                "must be at least 1",
            ));
        }
        crate::input_limits::count_at_most(self.frame_step, 1_000_000, "association.frame_step")?;
        crate::input_limits::option_in(
            self.max_missed,
            0.0,
            crate::input_limits::MAX_TIME,
            "association.max_missed",
        )?;
        Ok(())
    }
}

/// One frame of identity-free detections.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Seconds.
    pub time: f64,
    /// World positions, metres.
    pub detections: Vec<[f64; 2]>,
}

#[derive(Clone, Debug)]
struct Live {
    id: u64,
    p: [f64; 2],
    v: [f64; 2],
    t: f64,
    hits: usize,
}

/// Assigns a track id to every detection of every frame (frames in time order).
pub fn associate(frames: &[Frame], opts: &TrackerOptions) -> Vec<Vec<u64>> {
    let mut live: Vec<Live> = Vec::new();
    let mut next_id = 0u64;
    let mut out = Vec::with_capacity(frames.len());
    let big = 1e6 * opts.gate;
    for f in frames {
        live.retain(|l| f.time - l.t <= opts.max_missed + 1e-9);
        let (n, d) = (live.len(), f.detections.len());
        let cols = d + n;
        let mut cost = vec![big; n * cols];
        for (i, l) in live.iter().enumerate() {
            let dt = f.time - l.t;
            let pred = [l.p[0] + l.v[0] * dt, l.p[1] + l.v[1] * dt];
            for (j, z) in f.detections.iter().enumerate() {
                let c = (z[0] - pred[0]).hypot(z[1] - pred[1]);
                if c <= opts.gate {
                    cost[i * cols + j] = c;
                }
            }
            cost[i * cols + d + i] = opts.gate;
        }
        let assign = hungarian(&cost, n, cols);
        let mut ids = vec![u64::MAX; d];
        for (i, a) in assign.iter().enumerate() {
            if let Some(j) = *a
                && j < d
                && cost[i * cols + j] <= opts.gate
            {
                let l = &mut live[i];
                let z = f.detections[j];
                let dt = f.time - l.t;
                if dt > 0.0 {
                    let vn = [(z[0] - l.p[0]) / dt, (z[1] - l.p[1]) / dt];
                    let g = if l.hits == 1 { 1.0 } else { opts.velocity_gain };
                    l.v = [
                        g * vn[0] + (1.0 - g) * l.v[0],
                        g * vn[1] + (1.0 - g) * l.v[1],
                    ];
                }
                l.p = z;
                l.t = f.time;
                l.hits += 1;
                ids[j] = l.id;
            }
        }
        for (j, id) in ids.iter_mut().enumerate() {
            if *id == u64::MAX {
                *id = next_id;
                live.push(Live {
                    id: next_id,
                    p: f.detections[j],
                    v: [0.0, 0.0],
                    t: f.time,
                    hits: 1,
                });
                next_id += 1;
            }
        }
        out.push(ids);
    }
    out
}

/// Association quality against annotated identities (module docs).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AssociationReport {
    /// Frames with detections.
    pub frames: usize,
    /// Detections associated.
    pub detections: usize,
    /// Annotated identities among them.
    pub identities: usize,
    /// Tracks the tracker made.
    pub tracks: usize,
    /// Consecutive detections of one annotated identity given different track ids.
    pub id_switches: usize,
    /// IDTP / detections.
    pub correct_fraction: f64,
}

impl AssociationReport {
    /// Sums counts; the fraction is re-weighted by detections.
    pub fn add(&mut self, o: &AssociationReport) {
        let good = self.correct_fraction * self.detections as f64
            + o.correct_fraction * o.detections as f64;
        self.frames += o.frames;
        self.detections += o.detections;
        self.identities += o.identities;
        self.tracks += o.tracks;
        self.id_switches += o.id_switches;
        self.correct_fraction = if self.detections > 0 {
            good / self.detections as f64
        } else {
            0.0
        };
    }
}

/// Compares predicted track ids with annotated ids (same shapes: per frame, per detection).
pub fn evaluate(truth: &[Vec<u64>], predicted: &[Vec<u64>]) -> AssociationReport {
    let mut last: BTreeMap<u64, u64> = BTreeMap::new();
    let mut shared: BTreeMap<(u64, u64), usize> = BTreeMap::new();
    let mut switches = 0;
    let mut detections = 0;
    for (tf, pf) in truth.iter().zip(predicted) {
        for (&g, &p) in tf.iter().zip(pf) {
            detections += 1;
            if let Some(prev) = last.insert(g, p)
                && prev != p
            {
                switches += 1;
            }
            *shared.entry((g, p)).or_default() += 1;
        }
    }
    let gts: Vec<u64> = last.keys().copied().collect();
    let mut preds: Vec<u64> = shared.keys().map(|k| k.1).collect();
    preds.sort_unstable();
    preds.dedup();
    let (g, p) = (gts.len(), preds.len());
    let mut cost = vec![0.0; g * p];
    for (&(gi, pi), &n) in &shared {
        let (Ok(a), Ok(b)) = (gts.binary_search(&gi), preds.binary_search(&pi)) else {
            continue;
        };
        cost[a * p + b] = -(n as f64);
    }
    let idtp: f64 = hungarian(&cost, g, p)
        .iter()
        .enumerate()
        .filter_map(|(a, b)| b.map(|b| -cost[a * p + b]))
        .sum();
    AssociationReport {
        frames: truth.len(),
        detections,
        identities: g,
        tracks: p,
        id_switches: switches,
        correct_fraction: if detections > 0 {
            idtp / detections as f64
        } else {
            0.0
        },
    }
}

/// Identity-free detections from raw SDD rows: every `frame_step`-th frame, rows not `lost`
/// (pedestrians only if asked), box centres in metres (`x = u·s`, `y = −v·s`), shuffled per
/// frame with `seed` so the file's row order cannot leak identities. Returns the frames and
/// the annotated ids aligned with them.
pub fn sdd_detections(
    rows: &[SddRow],
    scale: f64,
    frame_step: usize,
    pedestrians_only: bool,
    seed: u64,
) -> (Vec<Frame>, Vec<Vec<u64>>) {
    let mut by_frame: BTreeMap<i64, Vec<(u64, [f64; 2])>> = BTreeMap::new();
    for r in rows {
        if r.lost || (pedestrians_only && r.class != AgentClass::Pedestrian) {
            continue;
        }
        if r.frame % frame_step.max(1) as i64 != 0 {
            continue;
        }
        by_frame.entry(r.frame).or_default().push((
            r.track_id,
            [r.center_px[0] * scale, -r.center_px[1] * scale],
        ));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut frames = Vec::with_capacity(by_frame.len());
    let mut truth = Vec::with_capacity(by_frame.len());
    for (f, mut dets) in by_frame {
        dets.sort_by_key(|d| d.0);
        dets.shuffle(&mut rng);
        truth.push(dets.iter().map(|d| d.0).collect());
        frames.push(Frame {
            time: f as f64 / crate::loaders::sdd::FPS,
            detections: dets.iter().map(|d| d.1).collect(),
        });
    }
    (frames, truth)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    fn brute(cost: &[f64], rows: usize, cols: usize) -> f64 {
        // Best over all injective maps of the smaller side into the larger one.
        fn rec(
            cost: &[f64],
            rows: usize,
            cols: usize,
            i: usize,
            used: &mut Vec<bool>,
            acc: f64,
            best: &mut f64,
        ) {
            if i == rows {
                *best = best.min(acc);
                return;
            }
            for j in 0..cols {
                if !used[j] {
                    used[j] = true;
                    rec(
                        cost,
                        rows,
                        cols,
                        i + 1,
                        used,
                        acc + cost[i * cols + j],
                        best,
                    );
                    used[j] = false;
                }
            }
        }
        let (c, r, k) = if rows <= cols {
            (cost.to_vec(), rows, cols)
        } else {
            let mut t = vec![0.0; rows * cols];
            for i in 0..rows {
                for j in 0..cols {
                    t[j * rows + i] = cost[i * cols + j];
                }
            }
            (t, cols, rows)
        };
        let mut best = f64::INFINITY;
        rec(&c, r, k, 0, &mut vec![false; k], 0.0, &mut best);
        best
    }

    #[test]
    fn hungarian_matches_brute_force_on_random_matrices() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
        for case in 0..500 {
            let rows = rng.random_range(1..=6);
            let cols = rng.random_range(1..=6);
            let cost: Vec<f64> = (0..rows * cols)
                .map(|_| {
                    if case % 3 == 0 {
                        rng.random_range(0..4) as f64
                    } else {
                        rng.random_range(-5.0..10.0)
                    }
                })
                .collect();
            let a = hungarian(&cost, rows, cols);
            let mut seen = vec![false; cols];
            let mut total = 0.0;
            for (i, c) in a.iter().enumerate() {
                if let Some(j) = *c {
                    assert!(!seen[j], "column {j} used twice");
                    seen[j] = true;
                    total += cost[i * cols + j];
                }
            }
            assert_eq!(a.iter().flatten().count(), rows.min(cols));
            let best = brute(&cost, rows, cols);
            assert!(
                (total - best).abs() < 1e-9,
                "case {case}: {rows}x{cols} hungarian {total} brute {best}"
            );
        }
    }

    #[test]
    fn hungarian_closed_form() {
        // The classic 3×3 example: optimum 1 + 2 + 2 = 5 on the anti-diagonal pattern.
        let c = [4.0, 1.0, 3.0, 2.0, 0.0, 5.0, 3.0, 2.0, 2.0];
        let a = hungarian(&c, 3, 3);
        assert_eq!(a, vec![Some(1), Some(0), Some(2)]);
        assert!(hungarian(&[], 0, 3).is_empty());
        assert_eq!(hungarian(&[], 2, 0), vec![None, None]);
    }

    #[test]
    fn tracker_near_tie_is_decided_by_cost_next_to_forbidden_pairs() {
        // Two tracks × (two detections + one miss column each); forbidden pairs cost 1e6. The
        // cross assignment is cheaper by 2e-14, which the solver must still see.
        let c = [
            0.5 + 4e-14,
            0.5 + 6e-14,
            1.0,
            1e6,
            0.5,
            0.5 + 4e-14,
            1e6,
            1.0,
        ];
        assert_eq!(hungarian(&c, 2, 4), vec![Some(1), Some(0)]);
    }

    fn walkers(n_frames: usize) -> (Vec<Frame>, Vec<Vec<u64>>) {
        // Two pedestrians crossing at right angles through the origin, plus one standing.
        let mut frames = Vec::new();
        let mut truth = Vec::new();
        for k in 0..n_frames {
            let t = k as f64 * 0.1;
            let a = [-3.0 + 1.3 * t, 0.05];
            let b = [0.0, -3.0 + 1.2 * t];
            let c = [2.0, 2.0];
            // Detection order rotates so it carries no identity.
            let mut dets = [(0u64, a), (1, b), (2, c)];
            dets.rotate_left(k % 3);
            truth.push(dets.iter().map(|d| d.0).collect());
            frames.push(Frame {
                time: t,
                detections: dets.iter().map(|d| d.1).collect(),
            });
        }
        (frames, truth)
    }

    #[test]
    fn crossing_walkers_keep_their_identities() {
        let (frames, truth) = walkers(50);
        let pred = associate(&frames, &TrackerOptions::default());
        let r = evaluate(&truth, &pred);
        assert_eq!(r.id_switches, 0);
        assert_eq!(r.tracks, 3);
        assert!((r.correct_fraction - 1.0).abs() < 1e-12);
    }

    #[test]
    fn short_gaps_are_bridged_and_long_ones_end_the_track() {
        let (mut frames, truth) = walkers(40);
        // Remove walker 0 for 3 frames (0.3 s < 0.5 s) and walker 1 for 8 frames (0.8 s).
        let mut truth2 = truth.clone();
        for k in 0..40 {
            let drop: Vec<u64> = match k {
                10..=12 => vec![0],
                20..=27 => vec![1],
                _ => vec![],
            };
            let keep: Vec<usize> = (0..truth[k].len())
                .filter(|&i| !drop.contains(&truth[k][i]))
                .collect();
            frames[k].detections = keep.iter().map(|&i| frames[k].detections[i]).collect();
            truth2[k] = keep.iter().map(|&i| truth[k][i]).collect();
        }
        let pred = associate(&frames, &TrackerOptions::default());
        let r = evaluate(&truth2, &pred);
        assert_eq!(r.tracks, 4, "walker 1 is re-born after its long gap");
        assert_eq!(r.id_switches, 1);
    }

    #[test]
    fn evaluation_closed_form() {
        // Identity 7 seen 4 times: tracks a, a, b, b → 1 switch, IDTP = 2 + 2 (b matched to 8).
        let truth = vec![vec![7, 8], vec![7], vec![7], vec![7]];
        let pred = vec![vec![0, 1], vec![0], vec![1], vec![1]];
        let r = evaluate(&truth, &pred);
        assert_eq!(r.id_switches, 1);
        assert_eq!(r.detections, 5);
        assert_eq!((r.identities, r.tracks), (2, 2));
        // Best matching: 7↔1 (2 shared) and 8↔0 (0) or 7↔0 (2) and 8↔1 (1) → IDTP 3.
        assert!((r.correct_fraction - 3.0 / 5.0).abs() < 1e-12);
    }
}
