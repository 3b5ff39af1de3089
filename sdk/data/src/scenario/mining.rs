//! Mining the paper-protocol episodes of a scene ([`MiningOptions`]): the geometry shared with
//! the interaction-rich miner (relevant agents, the start rule, goals, exported crowds) and
//! the reasons a window is rejected.

use super::{AgentTrack, ClassifyOptions, Episode, MAX_TIME_BUDGET, ScenarioClass, classify};
use crate::error::DataError;
use crate::resample::{Scene, StepIndex, Track};
use crate::track::AgentClass;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Rules for mining episodes (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MiningOptions {
    /// Straight-line start→goal distance, metres. Default 5.
    pub goal_distance: f64,
    /// The ego must reach the goal distance within this time, seconds. Default 10.
    pub max_goal_time: f64,
    /// Budget = `budget_factor · distance / reference_speed`. Default 2.5.
    pub budget_factor: f64,
    /// Robot reference speed for the budget, m/s. Default 1.0.
    pub reference_speed: f64,
    /// Radius around the ego that makes an agent relevant, metres. Default 3.
    pub density_radius: f64,
    /// Exported agents come within this distance of the start→goal segment, metres. Default 10.
    pub export_radius: f64,
    /// No agent may come closer than this to the start during `start_window`, metres.
    /// Default 1.5.
    pub min_start_clearance: f64,
    /// How long after the start `min_start_clearance` holds, seconds (0: the first step only).
    /// Default 1.5.
    pub start_window: f64,
    /// Fewest relevant agents an episode may have (module docs, "Density").
    pub min_density: usize,
    /// Most relevant agents an episode may have.
    pub max_density: usize,
    /// Episodes per class to select. Default 50.
    pub per_class: usize,
    /// Radius of every replayed agent, metres. Default 0.3.
    pub agent_radius: f64,
    /// Seed of the selection shuffle.
    pub seed: u64,
    /// How the crowd's class is decided.
    pub classify: ClassifyOptions,
}

impl Default for MiningOptions {
    fn default() -> Self {
        Self {
            goal_distance: 5.0,
            max_goal_time: 10.0,
            budget_factor: 2.5,
            reference_speed: 1.0,
            density_radius: 3.0,
            export_radius: 10.0,
            min_start_clearance: 1.5,
            start_window: 1.5,
            min_density: 1,
            max_density: 15,
            per_class: 50,
            agent_radius: 0.3,
            seed: 7,
            classify: ClassifyOptions::default(),
        }
    }
}

/// `Ok` when `v` is finite and positive, else an error naming the option `key`.
pub(crate) fn positive(v: f64, key: &str) -> Result<(), DataError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(DataError::option(key, "must be finite and positive"))
    }
}

impl MiningOptions {
    /// Checks every option is usable.
    pub fn validate(&self) -> Result<(), DataError> {
        let pos = positive;
        pos(self.goal_distance, "episodes.goal_distance")?;
        pos(self.max_goal_time, "episodes.max_goal_time")?;
        pos(self.reference_speed, "episodes.reference_speed")?;
        pos(self.density_radius, "episodes.density_radius")?;
        pos(self.export_radius, "episodes.export_radius")?;
        pos(self.agent_radius, "episodes.agent_radius")?;
        if !(self.budget_factor.is_finite() && self.budget_factor >= 1.0) {
            return Err(DataError::option("episodes.budget_factor", "must be >= 1"));
        }
        // Upper bounds: a mined episode's budget must stay within MAX_TIME_BUDGET and every
        // step count derived from these within the scene.
        use crate::input_limits::{MAX_COORDINATE, MAX_TIME, option_in};
        option_in(self.budget_factor, 1.0, 100.0, "episodes.budget_factor")?;
        option_in(
            self.reference_speed,
            0.01,
            100.0,
            "episodes.reference_speed",
        )?;
        option_in(
            self.goal_distance,
            0.0,
            MAX_COORDINATE,
            "episodes.goal_distance",
        )?;
        option_in(self.max_goal_time, 0.0, MAX_TIME, "episodes.max_goal_time")?;
        option_in(self.start_window, 0.0, MAX_TIME, "episodes.start_window")?;
        for (v, f) in [
            (self.min_start_clearance, "episodes.min_start_clearance"),
            (self.start_window, "episodes.start_window"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(DataError::option(f, "must be finite and >= 0"));
            }
        }
        if self.min_density > self.max_density {
            return Err(DataError::option(
                "episodes.min_density",
                "must not exceed max_density",
            ));
        }
        self.classify.validate()
    }

    /// The time budget for a start→goal distance, seconds.
    pub fn budget(&self, distance: f64) -> f64 {
        self.budget_factor * distance / self.reference_speed
    }
}

/// Counters of why candidate windows were rejected.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MiningStats {
    /// Candidate windows examined.
    pub windows: usize,
    /// Rejected: [`Reject::GoalNotReached`].
    pub goal_not_reached: usize,
    /// Rejected: [`Reject::OutsideRecording`].
    pub outside_recording: usize,
    /// Rejected: [`Reject::StartBlocked`].
    pub start_blocked: usize,
    /// Rejected: [`Reject::DensityOutOfRange`].
    pub density_out_of_range: usize,
    /// Rejected: [`Reject::Unclassified`].
    pub unclassified: usize,
    /// Accepted windows per class, before the per-class selection.
    pub candidates: BTreeMap<ScenarioClass, usize>,
}

impl MiningStats {
    /// Adds another scene's counters.
    pub fn add(&mut self, o: &Self) {
        self.windows += o.windows;
        self.goal_not_reached += o.goal_not_reached;
        self.outside_recording += o.outside_recording;
        self.start_blocked += o.start_blocked;
        self.density_out_of_range += o.density_out_of_range;
        self.unclassified += o.unclassified;
        for (c, n) in &o.candidates {
            *self.candidates.entry(*c).or_default() += n;
        }
    }
}

pub(crate) fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

pub(crate) fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1]];
    let l2 = ab[0] * ab[0] + ab[1] * ab[1];
    let t = if l2 > 0.0 {
        (((p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1]) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    dist(p, [a[0] + t * ab[0], a[1] + t * ab[1]])
}

/// The agents that come within `radius` of a probe moving through the scene (the ego
/// pedestrian here, the reference robot in [`crate::episode_mining`]): at each `(global step,
/// probe position)`, every track present then except `exclude`. Returns (track index, mean
/// velocity over the steps it was in range), sorted by track index.
pub(crate) fn relevant_agents(
    scene: &Scene,
    index: &StepIndex,
    probe: impl IntoIterator<Item = (i64, [f64; 2])>,
    exclude: Option<usize>,
    radius: f64,
) -> Vec<(usize, [f64; 2])> {
    let mut acc: BTreeMap<usize, ([f64; 2], usize)> = BTreeMap::new();
    for (s, pe) in probe {
        for &j in index.at(s) {
            let j = j as usize;
            if Some(j) == exclude {
                continue;
            }
            let t = &scene.tracks[j];
            let Some(k) = t.local(s) else { continue };
            if dist(t.positions[k], pe) <= radius {
                let e = acc.entry(j).or_insert(([0.0, 0.0], 0));
                e.0[0] += t.velocities[k][0];
                e.0[1] += t.velocities[k][1];
                e.1 += 1;
            }
        }
    }
    acc.into_iter()
        .map(|(j, (v, n))| (j, [v[0] / n as f64, v[1] / n as f64]))
        .collect()
}

/// True when a track other than `exclude` comes within `min_start_clearance` of `start`
/// during the `start_window` after global step `s0` (module docs).
pub(crate) fn start_blocked(
    scene: &Scene,
    index: &StepIndex,
    exclude: Option<usize>,
    s0: i64,
    start: [f64; 2],
    opts: &MiningOptions,
) -> bool {
    let window = (opts.start_window / scene.dt + 1e-9).floor() as i64;
    (s0..=s0 + window).any(|step| {
        index.at(step).iter().any(|&j| {
            let j = j as usize;
            Some(j) != exclude
                && scene.tracks[j].local(step).is_some_and(|k| {
                    dist(scene.tracks[j].positions[k], start) < opts.min_start_clearance
                })
        })
    })
}

/// The local index at which track `t`, starting at local index `i0`, is first
/// `goal_distance` from its position there in a straight line, if within `max_goal_time`.
pub(crate) fn goal_index(t: &Track, i0: usize, dt: f64, opts: &MiningOptions) -> Option<usize> {
    let max_goal_steps = (opts.max_goal_time / dt).round() as usize;
    let p0 = t.positions[i0];
    (i0 + 1..t.len().min(i0 + max_goal_steps + 1))
        .find(|&i| dist(t.positions[i], p0) >= opts.goal_distance)
}

/// Why [`try_episode`] rejected a window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reject {
    /// The ego never gets `goal_distance` from its start within `max_goal_time`.
    GoalNotReached,
    /// The episode's time budget reaches past the end of the recording.
    OutsideRecording,
    /// Someone is too close to the start during `start_window`.
    StartBlocked,
    /// The number of relevant agents is outside `[min_density, max_density]`.
    DensityOutOfRange,
    /// No relevant agent moves fast enough to vote on a class.
    Unclassified,
}

/// The episode of ego track `ego` starting at its local index `i0` (module docs), or why
/// there is none. On success the second value is the ego's local index at the goal.
pub fn try_episode(
    scene: &Scene,
    index: &StepIndex,
    ego: usize,
    i0: usize,
    opts: &MiningOptions,
) -> Result<(Episode, usize), Reject> {
    let t = &scene.tracks[ego];
    let dt = scene.dt;
    let last = scene.step_range().map(|r| r.1).unwrap_or(i64::MIN);
    let p0 = t.positions[i0];
    let ig = goal_index(t, i0, dt, opts).ok_or(Reject::GoalNotReached)?;
    let s0 = t.start + i0 as i64;
    let sg = t.start + ig as i64;
    let goal = t.positions[ig];
    let distance = dist(goal, p0);
    let budget = opts.budget(distance);
    if budget.is_nan() || budget > MAX_TIME_BUDGET {
        // No episode file could hold it (Episode::validate).
        return Err(Reject::OutsideRecording);
    }
    let steps = (budget / dt - 1e-9).ceil() as i64;
    if s0 + steps > last {
        return Err(Reject::OutsideRecording);
    }
    if start_blocked(scene, index, Some(ego), s0, p0, opts) {
        return Err(Reject::StartBlocked);
    }
    let ego_path = (s0..=sg).filter_map(|s| t.local(s).map(|i| (s, t.positions[i])));
    let relevant = relevant_agents(scene, index, ego_path, Some(ego), opts.density_radius);
    let density = relevant.len();
    if density < opts.min_density || density > opts.max_density {
        return Err(Reject::DensityOutOfRange);
    }
    let u = [goal[0] - p0[0], goal[1] - p0[1]];
    let class =
        classify(u, relevant.iter().map(|r| r.1), &opts.classify).ok_or(Reject::Unclassified)?;
    let agents = export_agents(scene, index, Some(ego), s0, steps, p0, goal, opts);
    let episode = Episode {
        id: format!("{}/ped{}/t{:.1}", scene.name, t.source_id, s0 as f64 * dt),
        scene: scene.name.clone(),
        source: scene.dataset.clone(),
        scenario: class,
        dt,
        start: t.pose(i0),
        goal,
        time_budget: budget,
        agents,
        density,
        obstacles: Vec::new(),
        human_path: t.positions[i0..=ig].to_vec(),
    };
    Ok((episode, ig))
}

/// All candidate episodes of one scene (before per-class selection). One ego's windows
/// never overlap: the next window starts where the previous one reached its goal.
pub fn mine_scene(scene: &Scene, opts: &MiningOptions, stats: &mut MiningStats) -> Vec<Episode> {
    let index = scene.index();
    let mut out = Vec::new();
    for (e, ego) in scene.tracks.iter().enumerate() {
        if ego.class != AgentClass::Pedestrian {
            continue;
        }
        let mut i0 = 0usize;
        while i0 + 1 < ego.len() {
            stats.windows += 1;
            match try_episode(scene, &index, e, i0, opts) {
                Ok((ep, ig)) => {
                    *stats.candidates.entry(ep.scenario).or_default() += 1;
                    out.push(ep);
                    i0 = ig;
                }
                Err(why) => {
                    match why {
                        Reject::GoalNotReached => stats.goal_not_reached += 1,
                        Reject::OutsideRecording => stats.outside_recording += 1,
                        Reject::StartBlocked => stats.start_blocked += 1,
                        Reject::DensityOutOfRange => stats.density_out_of_range += 1,
                        Reject::Unclassified => stats.unclassified += 1,
                    }
                    // Retry one second later.
                    i0 += (1.0 / scene.dt).round().max(1.0) as usize;
                }
            }
        }
    }
    out
}

/// The replayed crowd of an episode whose step 0 is global step `s0`: every track present
/// during `[s0, s0 + steps]` (except `exclude`) that comes within `export_radius` of the
/// segment `a`–`b` then, clipped to that window, in track order.
pub(crate) fn export_agents(
    scene: &Scene,
    index: &StepIndex,
    exclude: Option<usize>,
    s0: i64,
    steps: i64,
    a: [f64; 2],
    b: [f64; 2],
    opts: &MiningOptions,
) -> Vec<AgentTrack> {
    let mut ids: Vec<usize> = Vec::new();
    for s in s0..=s0 + steps {
        for &j in index.at(s) {
            let j = j as usize;
            if Some(j) == exclude || ids.contains(&j) {
                continue;
            }
            let t: &Track = &scene.tracks[j];
            if let Some(k) = t.local(s)
                && segment_distance(t.positions[k], a, b) <= opts.export_radius
            {
                ids.push(j);
            }
        }
    }
    ids.sort_unstable();
    ids.into_iter()
        .map(|j| {
            let t = &scene.tracks[j];
            let from = t.start.max(s0);
            let to = t.end().min(s0 + steps + 1);
            AgentTrack {
                id: t.id,
                start_step: (from - s0) as usize,
                positions: (from..to)
                    .filter_map(|s| t.local(s).map(|k| t.positions[k]))
                    .collect(),
                radius: opts.agent_radius,
            }
        })
        .collect()
}

/// A straight pedestrian track from `from` at `velocity` (m/s), 0.1 s steps, from global step
/// `start` (for the tests of the miners).
#[cfg(test)]
pub(crate) fn test_track(
    id: u64,
    start: i64,
    from: [f64; 2],
    velocity: [f64; 2],
    steps: usize,
) -> Track {
    let positions: Vec<[f64; 2]> = (0..steps)
        .map(|k| {
            let t = 0.1 * k as f64;
            [from[0] + velocity[0] * t, from[1] + velocity[1] * t]
        })
        .collect();
    Track {
        id,
        source_id: id,
        class: AgentClass::Pedestrian,
        start,
        velocities: vec![velocity; steps],
        headings: vec![velocity[1].atan2(velocity[0]); steps],
        positions,
    }
}
