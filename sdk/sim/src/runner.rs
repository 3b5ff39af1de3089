//! The closed loop: pedestrians replayed, a planner called at a fixed rate, the plan followed by
//! the embodiment's tracking controller, commands saturated, the kinematic model stepped.
//!
//! Per simulation step `n` (time `t_n = n·dt`, default `dt` = 0.05 s):
//! 1. the crowd is where it is at `t_n`: replayed as recorded ([`crate::replay`]), or, in a
//!    reactive suite, recorded paths with a social-force response to the robot during the
//!    previous step ([`crate::crowd`]); the clearance to each pedestrian is the
//!    distance from the robot's footprint (the URDF base collision's xy projection: a box is a
//!    rectangle, a cylinder a disc; [`human2nav_core::robot::footprint`]) to the pedestrian's
//!    disc. Planners get the coarser disc about the robot's reference point that covers the
//!    footprint (`RobotSetup::footprint_radius`);
//! 2. a negative clearance is a **collision** (the episode ends); a robot within
//!    `goal_tolerance` of the goal is a **success**; reaching the time budget is a **timeout**;
//! 3. every `replan_every = round(1 / (replan_hz·dt))` steps (default 10 Hz, every 2nd step)
//!    the planner receives an [`Observation`] (pedestrians within `sensor_range`, with history)
//!    and returns a plan; a planner error, panic or non-finite plan is recorded and replaced by
//!    [`Plan::stop_in_place`]; a plan whose `info.error` is set (the substitute a plugin planner
//!    that missed its deadline gets) is followed and recorded as a failed call too;
//! 4. the tracking controller turns the current plan into a command at `t_n` (recorded before
//!    saturation: the TFS of execution is measured on what the planner asked for), the command
//!    is saturated to the robot's limits and the kinematic model advances by `dt`.
//!
//! Start, goal and budget: the robot starts at rest at the episode's start position, facing
//! its goal (default; the recorded heading belongs to a pedestrian, not to a robot, and an
//! Ackermann robot cannot turn in place). The budget is
//! `max(episode.time_budget, budget_factor·t_empty + budget_margin)` where `t_empty` is the
//! minimum time the robot needs in an empty scene (rest-to-cruise at `a_max`, then `v_max`, over
//! the start-goal distance minus the tolerance, plus turning toward the goal when the start
//! heading is the episode's), so every robot can reach the goal of every episode in an empty
//! world within its budget. The budget is at most [`MAX_BUDGET`] (an hour).

use crate::crowd::{Crowd, CrowdModel};
use crate::episode::Episode;
use crate::error::SimError;
use crate::replay::PedestrianSample;
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::obstacle::{self, footprint_clearance};
use human2nav_core::robot::RobotProfile;
use human2nav_core::robot::footprint::{self, FootprintShape};
use human2nav_core::{
    ControllerGains, Limits, Observation, Plan, PlanError, Planner, Pose2, Twist2,
};
use human2nav_plugin::PluginHost;
use serde::{Deserialize, Serialize};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;

/// How the robot's initial heading is chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StartHeading {
    /// Facing the goal (default).
    #[default]
    FaceGoal,
    /// The episode's recorded start heading.
    Episode,
}

/// Smallest simulation step (s): 1 kHz. Every state of a run is kept, so together with
/// [`MAX_BUDGET`] this bounds a run to 3.6 million steps.
pub const MIN_SIM_DT: f64 = 1e-3;

/// Largest simulation step (s).
pub const MAX_SIM_DT: f64 = 1.0;

/// Largest time budget of a run (s), whatever the episode and the budget rule say: an hour,
/// the bound on an episode's own `time_budget` ([`human2nav_data::scenario::MAX_TIME_BUDGET`])
/// and on `budget_margin`. The benchmark's budgets are 10–30 s.
pub const MAX_BUDGET: f64 = human2nav_data::scenario::MAX_TIME_BUDGET;

/// Largest `budget_factor` of the budget rule.
pub const MAX_BUDGET_FACTOR: f64 = 100.0;

/// Settings of the closed loop. All times in seconds, distances in metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Simulation step, in [[`MIN_SIM_DT`], [`MAX_SIM_DT`]]. Default 0.05.
    pub dt: f64,
    /// Replanning rate (Hz); `1 / (replan_hz·dt)` must be a whole number. Default 10.
    pub replan_hz: f64,
    /// Success radius around the goal. Default 0.3.
    pub goal_tolerance: f64,
    /// Pedestrians beyond this centre distance are not observed. Default 10.
    pub sensor_range: f64,
    /// Recorded positions per observed pedestrian (at the episode's step). Default 8.
    pub history_len: usize,
    /// Budget rule factor (see the module docs), in [1, [`MAX_BUDGET_FACTOR`]]. Default 1.5.
    pub budget_factor: f64,
    /// Budget rule margin (s), in [0, [`MAX_BUDGET`]]. Default 3.
    pub budget_margin: f64,
    /// Initial heading. Default `face_goal`.
    pub start_heading: StartHeading,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            dt: 0.05,
            replan_hz: 10.0,
            goal_tolerance: 0.3,
            sensor_range: 10.0,
            history_len: 8,
            budget_factor: 1.5,
            budget_margin: 3.0,
            start_heading: StartHeading::FaceGoal,
        }
    }
}

impl SimConfig {
    /// Checks ranges and that the replanning period is a whole number of steps.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |field: &str, message: String| Err(SimError::setting("sim", field, message));
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !(self.dt.is_finite() && (MIN_SIM_DT..=MAX_SIM_DT).contains(&self.dt)) {
            return bad(
                "dt",
                format!("must be in [{MIN_SIM_DT}, {MAX_SIM_DT}] s, got {}", self.dt),
            );
        }
        if !positive(self.replan_hz) {
            return bad(
                "replan_hz",
                format!("must be finite and > 0, got {}", self.replan_hz),
            );
        }
        let ratio = 1.0 / (self.replan_hz * self.dt);
        if ratio < 1.0 - 1e-9 || (ratio - ratio.round()).abs() > 1e-6 {
            return bad(
                "replan_hz",
                format!(
                    "the period 1/{} s must be a whole number (≥ 1) of steps of {} s",
                    self.replan_hz, self.dt
                ),
            );
        }
        if !positive(self.goal_tolerance) {
            return bad(
                "goal_tolerance",
                format!("must be finite and > 0, got {}", self.goal_tolerance),
            );
        }
        if !positive(self.sensor_range) {
            return bad(
                "sensor_range",
                format!("must be finite and > 0, got {}", self.sensor_range),
            );
        }
        if !(self.budget_factor.is_finite()
            && (1.0..=MAX_BUDGET_FACTOR).contains(&self.budget_factor))
        {
            return bad(
                "budget_factor",
                format!(
                    "must be in [1, {MAX_BUDGET_FACTOR}], got {}",
                    self.budget_factor
                ),
            );
        }
        if !(self.budget_margin.is_finite() && (0.0..=MAX_BUDGET).contains(&self.budget_margin)) {
            return bad(
                "budget_margin",
                format!("must be in [0, {MAX_BUDGET}] s, got {}", self.budget_margin),
            );
        }
        Ok(())
    }

    /// These settings with another replanning rate (`None`: unchanged), for a method that
    /// replans at its own rate.
    pub fn with_replan_hz(&self, replan_hz: Option<f64>) -> SimConfig {
        SimConfig {
            replan_hz: replan_hz.unwrap_or(self.replan_hz),
            ..self.clone()
        }
    }

    /// Simulation steps between two planner calls.
    pub fn replan_every(&self) -> usize {
        (1.0 / (self.replan_hz * self.dt)).round().max(1.0) as usize
    }

    /// The robot's initial pose for `episode`.
    pub fn start_pose(&self, episode: &Episode) -> Pose2 {
        match self.start_heading {
            StartHeading::Episode => episode.start,
            StartHeading::FaceGoal => {
                let (dx, dy) = (
                    episode.goal[0] - episode.start.x,
                    episode.goal[1] - episode.start.y,
                );
                let theta = if dx.hypot(dy) > 0.0 {
                    dy.atan2(dx)
                } else {
                    episode.start.theta
                };
                Pose2::new(episode.start.x, episode.start.y, theta)
            }
        }
    }

    /// Minimum time the robot needs to reach the goal tolerance of `episode` in an empty scene:
    /// turning toward the goal (in place at `ω_max`, or along a minimum-radius arc at
    /// `min(ω_max, κ_max·v_max)` plus the `π·r_min / v_max` detour of a three-point turn when it
    /// cannot turn in place), then accelerating from rest at `a_max` to `v_max` over the
    /// remaining distance.
    pub fn empty_world_time(&self, episode: &Episode, limits: &Limits) -> f64 {
        let start = self.start_pose(episode);
        let (dx, dy) = (episode.goal[0] - start.x, episode.goal[1] - start.y);
        let dist = (dx.hypot(dy) - self.goal_tolerance).max(0.0);
        let heading_error = human2nav_core::se2::wrap_angle(dy.atan2(dx) - start.theta).abs();
        let turn = if heading_error < 1e-9 {
            0.0
        } else {
            match limits.kappa_max {
                None => heading_error / limits.omega_max,
                Some(k) => {
                    let rate = limits.omega_max.min(k * limits.v_max);
                    heading_error / rate + std::f64::consts::PI / (k * limits.v_max)
                }
            }
        };
        let (v, a) = (limits.v_max, limits.a_max);
        let ramp = v * v / (2.0 * a);
        let drive = if dist >= ramp {
            dist / v + v / (2.0 * a)
        } else {
            (2.0 * dist / a).sqrt()
        };
        turn + drive
    }

    /// The budget of `episode` for a robot with `limits` (see the module docs), at most
    /// [`MAX_BUDGET`] (a slow robot far from its goal could otherwise ask for years).
    pub fn budget_for(&self, episode: &Episode, limits: &Limits) -> f64 {
        let rule = self.budget_factor * self.empty_world_time(episode, limits) + self.budget_margin;
        let budget = if episode.time_budget.is_finite() {
            episode.time_budget.max(rule)
        } else {
            rule
        };
        // `min` keeps a NaN rule from reaching the step count as NaN.
        if budget.is_nan() {
            MAX_BUDGET
        } else {
            budget.min(MAX_BUDGET)
        }
    }
}

/// A robot as the simulator needs it: its name, footprint, limits and embodiment.
#[derive(Clone)]
pub struct RobotSetup {
    /// The robot's name (from its profile).
    pub name: String,
    /// Radius of the disc about the robot's reference point that covers its footprint (m):
    /// what planners are told to keep clear with.
    pub footprint_radius: f64,
    /// The footprint collisions are checked with (the URDF base collision's xy projection,
    /// base-link frame).
    pub footprint: Vec<FootprintShape>,
    /// The kinematic limits the planners respect and the TFS checks.
    pub limits: Limits,
    /// Gains of the tracking controller (passed on to plugin planners and embodiments).
    pub gains: ControllerGains,
    /// Tracks plans, saturates commands and steps the robot's state.
    pub embodiment: Arc<dyn Embodiment>,
}

impl RobotSetup {
    /// Loads a robot from its profile (`robot.toml` + URDF): a built-in embodiment, or a plugin
    /// embodiment created through a fresh [`PluginHost`] (see [`RobotSetup::load_with`]).
    pub fn load(path: &std::path::Path) -> Result<RobotSetup, SimError> {
        Self::load_with(path, &PluginHost::new())
    }

    /// Loads a robot from its profile, creating a plugin embodiment through `host` (whose
    /// [`PluginHost::failures`] then lists it if it fails during a run). Every plugin the
    /// profile declares is resolved first ([`PluginHost::resolve_robot`]: library loaded and
    /// checked, factory found, instance created with its config, one cheap call), so a broken
    /// declaration fails here, naming the profile, and not in the middle of a benchmark. A
    /// plugin embodiment is one instance shared by every run of the robot (instances accept
    /// concurrent calls); if it fails, the robot stands still for the rest of the benchmark and
    /// the host lists the failure.
    pub fn load_with(path: &std::path::Path, host: &PluginHost) -> Result<RobotSetup, SimError> {
        let fail = |message: String| SimError::Robot {
            path: path.to_path_buf(),
            message,
        };
        let mut profile = RobotProfile::load(path).map_err(|e| fail(e.to_string()))?;
        host.resolve_robot(&profile)
            .map_err(|e| fail(e.to_string()))?;
        let embodiment = host
            .robot_embodiment(&mut profile)
            .map_err(|e| fail(e.to_string()))?;
        Ok(Self::from_profile(&profile, Arc::from(embodiment)))
    }

    /// A robot from a loaded profile and its embodiment.
    pub fn from_profile(profile: &RobotProfile, embodiment: Arc<dyn Embodiment>) -> RobotSetup {
        RobotSetup {
            name: profile.name.clone(),
            footprint_radius: profile.footprint_radius,
            footprint: profile.footprint_shapes.clone(),
            limits: profile.limits,
            gains: profile.controller,
            embodiment,
        }
    }
}

impl std::fmt::Debug for RobotSetup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotSetup")
            .field("name", &self.name)
            .field("footprint_radius", &self.footprint_radius)
            .field("footprint", &self.footprint)
            .field("limits", &self.limits)
            .field("embodiment", &self.embodiment.name())
            .finish()
    }
}

/// How an episode ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// The robot came within the goal tolerance before the budget ran out.
    Success,
    /// The robot's footprint touched a pedestrian or a static obstacle.
    Collision,
    /// The budget ran out first.
    Timeout,
}

impl Outcome {
    /// The outcome's name in `results.csv` and the report.
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Success => "success",
            Outcome::Collision => "collision",
            Outcome::Timeout => "timeout",
        }
    }
}

/// One plan the planner returned, with the robot velocity it started from.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanSample {
    /// Time the plan starts at (s).
    pub t0: f64,
    /// Time between its poses (s).
    pub dt: f64,
    /// The planned poses, world frame.
    pub poses: Vec<Pose2>,
    /// The robot's body velocity when the plan was requested.
    pub initial_velocity: Twist2,
    /// True when the plan is the simulator's or the planner's stop-in-place fallback.
    pub fallback: bool,
    /// The trajectories the planner chose among, world frame (after guidance when it ran;
    /// empty for planners that report none): what a recording draws.
    pub candidates: Vec<Vec<Pose2>>,
}

/// Everything recorded while running one episode.
#[derive(Clone, Debug)]
pub struct EpisodeRun {
    /// How the episode ended.
    pub outcome: Outcome,
    /// Time at which the episode ended (s).
    pub end_time: f64,
    /// The budget that applied (s).
    pub budget: f64,
    /// Simulation step (s).
    pub dt: f64,
    /// Robot states at `t_n = n·dt`, `n = 0 … N` (the last at `end_time`).
    pub states: Vec<RobotState>,
    /// Tracking-controller commands before saturation, one per step (`N` values).
    pub raw_commands: Vec<Twist2>,
    /// Saturated (executed) commands, one per step.
    pub commands: Vec<Twist2>,
    /// Smallest clearance to any pedestrian at each `t_n` (`+∞` with nobody present),
    /// `N + 1` values.
    pub clearance: Vec<f64>,
    /// Every plan, in order.
    pub plans: Vec<PlanSample>,
    /// Planner failures (errors, panics, non-finite plans, substitute plans), in order, as
    /// messages.
    pub planner_errors: Vec<String>,
    /// How the collision happened, when there was one with a pedestrian.
    pub contact: Option<Contact>,
    /// Index in the episode's `obstacles` of the static obstacle the robot hit, when the
    /// collision was with one.
    pub obstacle_hit: Option<usize>,
    /// The robot's distance to the goal when the run ended (m).
    pub end_goal_distance: f64,
    /// The gap between the goal and the nearest pedestrian's disc when the run ended (m;
    /// negative: the goal lies inside someone's disc; `None` with nobody present): whether a
    /// run that timed out had someone standing at its goal.
    pub end_goal_crowd: Option<f64>,
    /// The simulated pedestrians at each `t_n` (`N + 1` lists) when the crowd was reactive;
    /// `None` for a replayed crowd, whose pedestrians are the episode's recording.
    pub crowd: Option<Vec<Vec<PedestrianSample>>>,
}

/// The first overlap of an episode that ended in a collision: who moved into whom. The replay
/// is non-reactive, so a pedestrian can walk into a robot that stands still, or a track can
/// begin on top of the robot (a person the dataset's tracker first saw there).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Contact {
    /// The pedestrian's id.
    pub pedestrian: u64,
    /// The robot's velocity toward the pedestrian at contact (m/s; negative: moving away).
    pub robot_closing: f64,
    /// The pedestrian's velocity toward the robot at contact (m/s; negative: moving away).
    pub pedestrian_closing: f64,
    /// How long the pedestrian's track had existed at contact (s).
    pub pedestrian_age: f64,
    /// The pedestrian's speed at contact (m/s), whatever its direction: a cyclist passing the
    /// robot closes slowly along the line between the centres but is still a cyclist.
    pub pedestrian_speed: f64,
}

impl Contact {
    /// The contact between the robot in `state` and pedestrian `id` of the crowd now.
    fn at(crowd: &Crowd<'_>, state: &RobotState, id: u64) -> Option<Self> {
        let ped = *crowd.get(id)?;
        let age = crowd.age(id)?;
        let (dx, dy) = (
            ped.position[0] - state.pose.x,
            ped.position[1] - state.pose.y,
        );
        let d = dx.hypot(dy);
        // Coincident centres: no direction, count every motion as closing.
        let (nx, ny) = if d > 1e-12 {
            (dx / d, dy / d)
        } else {
            (0.0, 0.0)
        };
        let (c, s) = (state.pose.theta.cos(), state.pose.theta.sin());
        let v = state.velocity;
        let (vx, vy) = (c * v.vx - s * v.vy, s * v.vx + c * v.vy);
        Some(Self {
            pedestrian: id,
            robot_closing: vx * nx + vy * ny,
            pedestrian_closing: -(ped.velocity[0] * nx + ped.velocity[1] * ny),
            pedestrian_age: age,
            pedestrian_speed: ped.velocity[0].hypot(ped.velocity[1]),
        })
    }
}

/// Runs one episode closed loop with the recorded crowd replayed as it walked.
pub fn run_episode(
    episode: &Episode,
    robot: &RobotSetup,
    planner: &mut dyn Planner,
    cfg: &SimConfig,
) -> EpisodeRun {
    run_episode_with(episode, robot, planner, cfg, &CrowdModel::Replay)
}

/// Runs one episode closed loop with the crowd behaving as `model` says
/// ([`crate::crowd`]).
pub fn run_episode_with(
    episode: &Episode,
    robot: &RobotSetup,
    planner: &mut dyn Planner,
    cfg: &SimConfig,
    model: &CrowdModel,
) -> EpisodeRun {
    let mut crowd = Crowd::new(episode, model);
    let dt = cfg.dt;
    let budget = cfg.budget_for(episode, &robot.limits);
    // The last step checked is the last one at or before the budget (so duration ≤ budget).
    let max_steps = (budget / dt + 1e-9).floor().max(0.0) as usize;
    // Reserved up front for a typical run only: a step outside [MIN_SIM_DT, MAX_SIM_DT] (a
    // settings struct that skipped `validate`) must not turn into one huge allocation.
    let reserve = max_steps.min(1 << 14);
    let replan_every = cfg.replan_every();
    let emb = robot.embodiment.as_ref();

    let mut state = RobotState {
        pose: cfg.start_pose(episode),
        velocity: Twist2::ZERO,
    };
    let mut run = EpisodeRun {
        outcome: Outcome::Timeout,
        end_time: 0.0,
        budget,
        dt,
        states: vec![state],
        raw_commands: Vec::with_capacity(reserve),
        commands: Vec::with_capacity(reserve),
        clearance: Vec::with_capacity(reserve + 1),
        plans: Vec::new(),
        planner_errors: Vec::new(),
        contact: None,
        obstacle_hit: None,
        end_goal_distance: 0.0,
        end_goal_crowd: None,
        crowd: crowd.is_reactive().then(|| Vec::with_capacity(reserve + 1)),
    };
    planner.reset();
    let mut plan: Option<Plan> = None;

    for n in 0..=max_steps {
        let t = n as f64 * dt;
        run.end_time = t;
        // 1-2: clearance, collision, goal, budget.
        if let Some(outcome) = check_end(
            episode,
            robot,
            cfg,
            &crowd,
            &state,
            n == max_steps,
            &mut run,
        ) {
            run.outcome = outcome;
            break;
        }
        // 3: replanning.
        if n % replan_every == 0 || plan.is_none() {
            plan = Some(replan(
                planner,
                episode,
                cfg,
                &crowd,
                &state,
                t,
                plan.as_ref(),
                &mut run,
            ));
        }
        // 4: track, saturate, step.
        let Some(current) = plan.as_ref() else { break };
        let raw = emb.track(&state, current, t);
        let cmd = emb.saturate(&state, raw, dt);
        // The crowd moves over the step with the robot where it was at its start.
        crowd.advance((n + 1) as f64 * dt, &robot.footprint, state.pose);
        state = emb.step(&state, cmd, dt);
        run.raw_commands.push(raw);
        run.commands.push(cmd);
        run.states.push(state);
    }
    let goal = episode.goal;
    run.end_goal_distance = distance_to(goal, state.pose);
    run.end_goal_crowd = crowd
        .present()
        .iter()
        .map(|p| (p.position[0] - goal[0]).hypot(p.position[1] - goal[1]) - p.radius)
        .reduce(f64::min);
    run
}

/// Steps 1-2 of a simulation step: records the crowd (when reactive) and the clearance, and
/// returns the outcome that ends the run here, if any: a collision with a pedestrian (its
/// contact recorded) or an obstacle (its index recorded), the goal reached, or the budget
/// spent (`last`).
fn check_end(
    episode: &Episode,
    robot: &RobotSetup,
    cfg: &SimConfig,
    crowd: &Crowd<'_>,
    state: &RobotState,
    last: bool,
    run: &mut EpisodeRun,
) -> Option<Outcome> {
    if let Some(states) = run.crowd.as_mut() {
        states.push(crowd.present().to_vec());
    }
    let (clearance, nearest) = nearest_clearance(crowd.present(), state.pose, &robot.footprint);
    run.clearance.push(clearance);
    if clearance < 0.0 {
        run.contact = nearest.and_then(|id| Contact::at(crowd, state, id));
        return Some(Outcome::Collision);
    }
    if let Some(i) = episode
        .obstacles
        .iter()
        .position(|o| footprint_clearance(&robot.footprint, state.pose, o) < 0.0)
    {
        run.obstacle_hit = Some(i);
        return Some(Outcome::Collision);
    }
    if distance_to(episode.goal, state.pose) <= cfg.goal_tolerance {
        return Some(Outcome::Success);
    }
    last.then_some(Outcome::Timeout)
}

/// The distance from the robot's reference point at `pose` to `point` (m).
fn distance_to(point: [f64; 2], pose: Pose2) -> f64 {
    (point[0] - pose.x).hypot(point[1] - pose.y)
}

/// Step 3 of a simulation step: the planner's plan for what the robot senses at `t`, or the
/// fallback when the call fails, returns an unusable plan or panics (the reason recorded in
/// `run`); the plan is sampled into `run.plans`.
fn replan(
    planner: &mut dyn Planner,
    episode: &Episode,
    cfg: &SimConfig,
    crowd: &Crowd<'_>,
    state: &RobotState,
    t: f64,
    previous: Option<&Plan>,
    run: &mut EpisodeRun,
) -> Plan {
    let obs = Observation {
        time: t,
        ego: state.pose,
        ego_velocity: state.velocity,
        goal: episode.goal,
        agents: crowd.observe(
            [state.pose.x, state.pose.y],
            cfg.sensor_range,
            cfg.history_len,
        ),
        obstacles: obstacle::within(
            &episode.obstacles,
            [state.pose.x, state.pose.y],
            cfg.sensor_range,
        ),
        ..Default::default()
    };
    let horizon = previous.map_or(32, |p| p.poses.len());
    let result = catch_unwind(AssertUnwindSafe(|| planner.plan(&obs)));
    let new_plan = match result {
        Ok(Ok(p)) if p.is_finite() && !p.poses.is_empty() && p.dt > 0.0 => {
            // A substitute plan (a plugin planner that missed its deadline) is a
            // failed call.
            if let Some(e) = &p.info.error {
                run.planner_errors.push(e.clone());
            }
            p
        }
        Ok(Ok(_)) => fallback(
            &obs,
            horizon,
            run,
            "planner returned an empty or non-finite plan".into(),
        ),
        Ok(Err(e)) => fallback(&obs, horizon, run, plan_error_message(&e)),
        Err(panic) => fallback(
            &obs,
            horizon,
            run,
            format!("planner panicked: {}", panic_message(&panic)),
        ),
    };
    run.plans.push(PlanSample {
        t0: new_plan.t0,
        dt: new_plan.dt,
        poses: new_plan.poses.clone(),
        initial_velocity: state.velocity,
        fallback: new_plan.info.fallback,
        candidates: if new_plan.info.guided.is_empty() {
            new_plan.info.candidates.clone()
        } else {
            new_plan.info.guided.clone()
        },
    });
    new_plan
}

/// The stop-in-place plan that replaces a failed planner call; `why` is recorded in `run`.
fn fallback(obs: &Observation, horizon: usize, run: &mut EpisodeRun, why: String) -> Plan {
    run.planner_errors.push(why.clone());
    Plan::stop_in_place(obs, human2nav_core::trajectory::DEFAULT_DT, horizon, why)
}

fn plan_error_message(e: &PlanError) -> String {
    e.to_string()
}

fn panic_message(p: &Box<dyn std::any::Any + Send>) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic payload".to_string()
    }
}

/// The smallest clearance between the robot's footprint at `pose` and any of `pedestrians`'
/// discs (`+∞` when there is nobody), and that pedestrian's id.
pub fn nearest_clearance(
    pedestrians: &[PedestrianSample],
    pose: Pose2,
    footprint: &[FootprintShape],
) -> (f64, Option<u64>) {
    let mut best = (f64::INFINITY, None);
    for s in pedestrians {
        let c = footprint::clearance_at(footprint, pose, s.position, s.radius);
        if c < best.0 {
            best = (c, Some(s.id));
        }
    }
    best
}
