//! Per-episode metrics computed from an [`EpisodeRun`].
//!
//! * **success / collision / timeout**: the [`Outcome`]; SR is the mean of `success`.
//! * **TFS** = `min(TFS_plan, TFS_executed)` (paper §IV, [`human2nav_core::feasibility`]): `TFS_plan` is
//!   the fraction of all planned waypoints of the episode (every plan, pooled) that satisfy the
//!   robot's limits, each plan checked from the robot's velocity when it was requested;
//!   `TFS_executed` is the fraction of the tracking controller's commands *before saturation*
//!   that are within the limits (so a planner whose plans demand the impossible is not rescued
//!   by the saturation). Both are 1 when there is nothing to score.
//! * **path length**: `Σ ‖p_{n+1} − p_n‖` of the executed positions.
//! * **time to goal**: the end time of a successful episode.
//! * **minimum clearance**: the smallest `‖p_robot − p_ped‖ − r_footprint − r_ped` over the
//!   episode (negative at a collision; absent when nobody was ever present). The centre distance
//!   is this plus both radii.
//! * **time within 0.45 m / 1.2 m**: time during which the clearance was below Hall's intimate
//!   (0.45 m) and personal (1.2 m) distances, each step counting `dt`.
//! * **mean jerk**: the mean norm of the third finite difference of the executed world
//!   positions, `‖a_{n+1} − a_n‖ / dt` with `a_n = (v_{n+1} − v_n)/dt`,
//!   `v_n = (p_{n+1} − p_n)/dt` and `v_{−1} = 0` (the robot starts at rest); 0 when the episode
//!   is too short for one value.
//! * **how human** (episodes with a recorded human, [`Episode::human_path`]: the pedestrian
//!   whose start and goal the robot took): the mean over time of the distance between the
//!   robot and that pedestrian at the same time since the start, each held at its last
//!   position once its path ends, over the longer of the two; and the ratio of the robot's
//!   path length to the pedestrian's ([`HumanComparison`]).

use crate::episode::Episode;
use crate::runner::{Contact, EpisodeRun, Outcome};
use human2nav_core::Limits;
use human2nav_core::feasibility;
use serde::{Deserialize, Serialize};

/// Hall's intimate distance (m).
pub const INTIMATE_DISTANCE: f64 = 0.45;
/// Hall's personal distance (m).
pub const PERSONAL_DISTANCE: f64 = 1.2;

/// The metrics of one episode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeMetrics {
    /// How the episode ended.
    pub outcome: Outcome,
    /// The goal was reached (outcome `success`).
    pub success: bool,
    /// The robot touched a pedestrian or an obstacle (outcome `collision`).
    pub collision: bool,
    /// The budget ran out (outcome `timeout`).
    pub timeout: bool,
    /// `min(tfs_plan, tfs_executed)`.
    pub tfs: f64,
    /// Trajectory feasibility score of the plans, against the robot's limits.
    pub tfs_plan: f64,
    /// Trajectory feasibility score of the executed commands (before saturation).
    pub tfs_executed: f64,
    /// Length of the executed path (m).
    pub path_length: f64,
    /// End time of a successful episode (s).
    pub time_to_goal: Option<f64>,
    /// Time simulated (s).
    pub duration: f64,
    /// The budget that applied (s).
    pub budget: f64,
    /// Smallest footprint-to-pedestrian clearance (m).
    pub min_clearance: Option<f64>,
    /// Time with clearance below [`INTIMATE_DISTANCE`] (s).
    pub time_within_intimate: f64,
    /// Time with clearance below [`PERSONAL_DISTANCE`] (s).
    pub time_within_personal: f64,
    /// Mean jerk norm of the executed path (m/s³).
    pub mean_jerk: f64,
    /// Number of planner calls.
    pub plans: usize,
    /// Plans that were stop-in-place fallbacks (the planner's own or the simulator's).
    pub fallbacks: usize,
    /// Planner errors, panics and rejected plans.
    pub planner_errors: usize,
    /// How the collision happened (collisions only).
    pub contact: Option<Contact>,
    /// Index of the episode's static obstacle the robot hit (collisions with one only).
    #[serde(default)]
    pub obstacle_hit: Option<usize>,
    /// Executed commands (before saturation) outside each limit: what pulls `tfs_executed`
    /// down.
    pub executed_violations: LimitCounts,
    /// The robot's distance to the goal at the end (m).
    #[serde(default)]
    pub end_goal_distance: f64,
    /// The gap between the goal and the nearest pedestrian's disc at the end (m; negative:
    /// the goal lies inside it; `None` with nobody present).
    #[serde(default)]
    pub end_goal_crowd: Option<f64>,
    /// The run against the recorded human of the episode (`None` without one).
    #[serde(default)]
    pub human: Option<HumanComparison>,
}

/// How a run's path compares with the recorded human's (module docs, "how human").
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HumanComparison {
    /// Mean distance between the robot and the human at equal times (m).
    pub distance: f64,
    /// The robot's path length over the human's.
    pub length_ratio: f64,
}

impl HumanComparison {
    /// `run` against `episode`'s recorded human; `None` when the episode has no human path
    /// of two or more positions (or one of zero length), or the run no state.
    pub fn of(run: &EpisodeRun, episode: &Episode) -> Option<Self> {
        let human = &episode.human_path;
        let human_length = path_length(human);
        if human.len() < 2 || human_length <= 0.0 || run.states.is_empty() {
            return None;
        }
        let robot: Vec<[f64; 2]> = run.states.iter().map(|s| [s.pose.x, s.pose.y]).collect();
        // Both sampled at the run's step, each held at its end.
        let human_end = (human.len() - 1) as f64 * episode.dt;
        let steps = (robot.len() - 1).max((human_end / run.dt - 1e-9).ceil() as usize);
        let distance = (0..=steps)
            .map(|n| {
                let r = robot[n.min(robot.len() - 1)];
                let h = position_at(human, episode.dt, n as f64 * run.dt);
                (r[0] - h[0]).hypot(r[1] - h[1])
            })
            .sum::<f64>()
            / (steps + 1) as f64;
        Some(Self {
            distance,
            length_ratio: path_length(&robot) / human_length,
        })
    }
}

/// `Σ ‖p_{n+1} − p_n‖`.
fn path_length(positions: &[[f64; 2]]) -> f64 {
    positions
        .windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .sum()
}

/// The position of a path sampled every `dt` at time `t`, linearly interpolated and held at
/// its ends (`path` not empty).
fn position_at(path: &[[f64; 2]], dt: f64, t: f64) -> [f64; 2] {
    let u = (t / dt).max(0.0);
    let i = (u.floor() as usize).min(path.len() - 1);
    let Some(next) = path.get(i + 1) else {
        return path[i];
    };
    let f = u - i as f64;
    [
        path[i][0] + f * (next[0] - path[i][0]),
        path[i][1] + f * (next[1] - path[i][1]),
    ]
}

/// How many commands broke each limit (a command can break several), out of `commands`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LimitCounts {
    /// Commands checked.
    pub commands: usize,
    /// Commands whose forward speed exceeds `v_max`.
    pub speed: usize,
    /// Commands whose reverse speed exceeds `v_reverse_max`.
    pub reverse: usize,
    /// Commands whose longitudinal acceleration exceeds `a_max`.
    pub acceleration: usize,
    /// Commands whose yaw rate exceeds `omega_max`.
    pub yaw_rate: usize,
    /// Commands whose curvature exceeds `kappa_max`.
    pub curvature: usize,
    /// Commands whose body-frame lateral speed exceeds `lateral_speed_max`.
    pub lateral: usize,
    /// Commands over the embodiment's coupled limit (a tracked base's track speed).
    #[serde(default)]
    pub coupled: usize,
}

impl LimitCounts {
    /// The names of the limits, in the order of [`LimitCounts::per_limit`].
    pub const NAMES: [&'static str; feasibility::LIMIT_COUNT] = feasibility::Violations::NAMES;

    /// Counts the violations of each limit.
    pub fn of(violations: &[feasibility::Violations]) -> Self {
        Self::from_per_limit(violations.len(), feasibility::Violations::count(violations))
    }

    /// The counts of `commands` commands, one per limit in [`Self::NAMES`]' order (the
    /// inverse of [`Self::per_limit`]).
    pub fn from_per_limit(commands: usize, per_limit: [usize; feasibility::LIMIT_COUNT]) -> Self {
        let [
            speed,
            reverse,
            acceleration,
            yaw_rate,
            curvature,
            lateral,
            coupled,
        ] = per_limit;
        Self {
            commands,
            speed,
            reverse,
            acceleration,
            yaw_rate,
            curvature,
            lateral,
            coupled,
        }
    }

    /// The counts in the order of [`LimitCounts::NAMES`].
    pub fn per_limit(&self) -> [usize; feasibility::LIMIT_COUNT] {
        [
            self.speed,
            self.reverse,
            self.acceleration,
            self.yaw_rate,
            self.curvature,
            self.lateral,
            self.coupled,
        ]
    }
}

impl EpisodeMetrics {
    /// Computes every metric of `run` for a robot with `limits`; the comparison with the
    /// recorded human needs the episode ([`Self::against_human`]).
    pub fn compute(run: &EpisodeRun, limits: &Limits) -> Self {
        let positions: Vec<[f64; 2]> = run.states.iter().map(|s| [s.pose.x, s.pose.y]).collect();
        let path_length = path_length(&positions);
        let steps = run.clearance.len().saturating_sub(1);
        let within =
            |thr: f64| run.clearance[..steps].iter().filter(|&&c| c < thr).count() as f64 * run.dt;
        let min_clearance = run.clearance.iter().copied().fold(f64::INFINITY, f64::min);
        let (tfs_plan, tfs_executed) = tfs_scores(run, limits);
        EpisodeMetrics {
            outcome: run.outcome,
            success: run.outcome == Outcome::Success,
            collision: run.outcome == Outcome::Collision,
            timeout: run.outcome == Outcome::Timeout,
            tfs: feasibility::tfs_min(tfs_plan, tfs_executed),
            tfs_plan,
            tfs_executed,
            path_length,
            time_to_goal: (run.outcome == Outcome::Success).then_some(run.end_time),
            duration: run.end_time,
            budget: run.budget,
            min_clearance: min_clearance.is_finite().then_some(min_clearance),
            time_within_intimate: within(INTIMATE_DISTANCE),
            time_within_personal: within(PERSONAL_DISTANCE),
            mean_jerk: mean_jerk(&positions, run.dt),
            plans: run.plans.len(),
            fallbacks: run.plans.iter().filter(|p| p.fallback).count(),
            planner_errors: run.planner_errors.len(),
            contact: run.contact,
            obstacle_hit: run.obstacle_hit,
            executed_violations: LimitCounts::of(&feasibility::command_violations(
                &run.raw_commands,
                run.dt,
                limits,
            )),
            end_goal_distance: run.end_goal_distance,
            end_goal_crowd: run.end_goal_crowd,
            human: None,
        }
    }

    /// These metrics with the comparison of `run` with `episode`'s recorded human.
    pub fn against_human(self, run: &EpisodeRun, episode: &Episode) -> Self {
        Self {
            human: HumanComparison::of(run, episode),
            ..self
        }
    }
}

/// `(TFS_plan, TFS_executed)` of a run (see the module docs).
pub fn tfs_scores(run: &EpisodeRun, limits: &Limits) -> (f64, f64) {
    let (mut feasible, mut total) = (0usize, 0usize);
    for p in &run.plans {
        let v = feasibility::plan_violations(&p.poses, p.dt, limits, p.initial_velocity);
        feasible += v.iter().filter(|x| x.feasible()).count();
        total += v.len();
    }
    let plan = if total == 0 {
        1.0
    } else {
        feasible as f64 / total as f64
    };
    (
        plan,
        feasibility::tfs_executed(&run.raw_commands, run.dt, limits),
    )
}

/// Mean jerk norm of positions sampled every `dt`, starting at rest (see the module docs).
pub fn mean_jerk(positions: &[[f64; 2]], dt: f64) -> f64 {
    if positions.len() < 2 || dt.is_nan() || dt <= 0.0 {
        return 0.0;
    }
    let mut v = vec![[0.0, 0.0]];
    v.extend(
        positions
            .windows(2)
            .map(|w| [(w[1][0] - w[0][0]) / dt, (w[1][1] - w[0][1]) / dt]),
    );
    let a: Vec<[f64; 2]> = v
        .windows(2)
        .map(|w| [(w[1][0] - w[0][0]) / dt, (w[1][1] - w[0][1]) / dt])
        .collect();
    let jerks: Vec<f64> = a
        .windows(2)
        .map(|w| ((w[1][0] - w[0][0]) / dt).hypot((w[1][1] - w[0][1]) / dt))
        .collect();
    if jerks.is_empty() {
        0.0
    } else {
        jerks.iter().sum::<f64>() / jerks.len() as f64
    }
}
