//! What a planner expects the people around the robot to do: [`Forecast`]s, and the
//! [`CrowdPredictor`]s that make them.
//!
//! A forecast holds `scenes` possible futures of the crowd. In each, every agent has a
//! position at each of the plan's `horizon` waypoints (`dt` apart, the first `dt` after the
//! observation). An agent predicted one way only (at constant velocity, say) has one path,
//! shared by every scene. Scenes are equally likely unless the forecast carries weights
//! ([`Forecast::with_weights`]): a selection that scores a plan against each and takes the
//! weighted mean ([`crate::human2nav`]) scores its expected cost.
//!
//! [`Forecast::constant_velocity`] is the one-scene forecast every planner of the SDK used
//! before predictors existed. [`FlowPredictor`], a learned, multimodal predictor, samples a
//! goal-free flow model of people (trained with `train.goal = false`); it implements
//! [`CrowdPredictor`] and is handed to the planner like any other.

use crate::bev::{self, BevAgent, BevSpec};
use crate::flow::{FlowCondition, FlowModel};
use crate::guidance::{self, GuidanceWorkspace};
use crate::planner::{AgentState, Observation};
use crate::se2::Pose2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Largest number of scenes of a forecast: each one is a pass of the selection over every
/// candidate, so hundreds would be seconds a call.
pub const MAX_SCENES: usize = 64;

/// One agent's predicted paths.
#[derive(Clone, Debug, PartialEq)]
pub struct ForecastAgent {
    /// The agent's id, as observed.
    pub id: u64,
    /// Radius of its disc (m).
    pub radius: f64,
    /// One path (the same in every scene) or one per scene; each `horizon` positions `[x, y]`.
    pub paths: Vec<Vec<[f64; 2]>>,
}

/// Possible futures of the observed agents (module docs). Build one with
/// [`Forecast::constant_velocity`] or [`Forecast::new`].
#[derive(Clone, Debug, PartialEq)]
pub struct Forecast {
    horizon: usize,
    scenes: usize,
    agents: Vec<ForecastAgent>,
    /// Each scene's probability (summing to 1); `None`: equally likely.
    weights: Option<Vec<f64>>,
}

impl Forecast {
    /// A forecast of `scenes` scenes over `horizon` waypoints, checked: at least one scene (at
    /// most [`MAX_SCENES`]), every agent with one path or `scenes` of them, each of `horizon`
    /// finite positions, and a finite radius ≥ 0.
    pub fn new(horizon: usize, scenes: usize, agents: Vec<ForecastAgent>) -> Result<Self, String> {
        if !(1..=MAX_SCENES).contains(&scenes) {
            return Err(format!(
                "a forecast needs 1 to {MAX_SCENES} scenes, got {scenes}"
            ));
        }
        for a in &agents {
            if a.paths.len() != 1 && a.paths.len() != scenes {
                return Err(format!(
                    "agent {}: {} paths for {scenes} scenes (1 or {scenes} expected)",
                    a.id,
                    a.paths.len()
                ));
            }
            if let Some(p) = a.paths.iter().find(|p| p.len() != horizon) {
                return Err(format!(
                    "agent {}: a path of {} positions for a horizon of {horizon}",
                    a.id,
                    p.len()
                ));
            }
            let finite = a.paths.iter().flatten().flatten().all(|v| v.is_finite());
            if !(finite && a.radius.is_finite() && a.radius >= 0.0) {
                return Err(format!("agent {}: a non-finite position or radius", a.id));
            }
        }
        Ok(Self {
            horizon,
            scenes,
            agents,
            weights: None,
        })
    }

    /// The same forecast with scene `s` given probability `weights[s] / Σ weights`: one finite
    /// weight ≥ 0 per scene, not all 0.
    pub fn with_weights(self, weights: Vec<f64>) -> Result<Self, String> {
        if weights.len() != self.scenes {
            return Err(format!(
                "{} weights for {} scenes",
                weights.len(),
                self.scenes
            ));
        }
        if let Some(w) = weights.iter().find(|w| !(w.is_finite() && **w >= 0.0)) {
            return Err(format!("a scene weight of {w} (finite and ≥ 0 expected)"));
        }
        let sum: f64 = weights.iter().sum();
        if !(sum > 0.0 && sum.is_finite()) {
            return Err(format!(
                "the scene weights sum to {sum} (a positive, finite sum expected)"
            ));
        }
        Ok(Self {
            weights: Some(weights.iter().map(|w| w / sum).collect()),
            ..self
        })
    }

    /// Scene `scene`'s probability.
    pub fn weight(&self, scene: usize) -> f64 {
        self.weights
            .as_ref()
            .map_or(1.0 / self.scenes as f64, |w| w[scene])
    }

    /// The scenes' probabilities when they are not equally likely.
    pub(crate) fn weights(&self) -> Option<&[f64]> {
        self.weights.as_deref()
    }

    /// The expectation over the scenes of `f(scene)`: with equally likely scenes their sum
    /// divided by their number, otherwise the weighted sum.
    pub fn expectation(&self, f: impl FnMut(usize) -> f64) -> f64 {
        expectation(self.weights.as_deref(), self.scenes, f)
    }

    /// Every agent moving on at its observed velocity: one scene, positions at `dt, 2dt, …`
    /// after the observation, in the agents' frame.
    pub fn constant_velocity(agents: &[AgentState], horizon: usize, dt: f64) -> Self {
        Self {
            horizon,
            scenes: 1,
            agents: one_path_per_agent(agents, |a| constant_velocity_path(a, horizon, dt)),
            weights: None,
        }
    }

    /// A one-scene forecast of `agents`: `path(a)` for each, checked as [`Forecast::new`]
    /// checks (a point forecast such as a predictor that makes one guess per person returns).
    pub fn one_path_each(
        agents: &[AgentState],
        horizon: usize,
        path: impl FnMut(&AgentState) -> Vec<[f64; 2]>,
    ) -> Result<Self, String> {
        Self::new(horizon, 1, one_path_per_agent(agents, path))
    }

    /// Waypoints per path.
    pub fn horizon(&self) -> usize {
        self.horizon
    }

    /// Number of scenes.
    pub fn scenes(&self) -> usize {
        self.scenes
    }

    /// The agents and their paths.
    pub fn agents(&self) -> &[ForecastAgent] {
        &self.agents
    }

    /// Agent `agent`'s position at waypoint `step` (0-based: `dt` after the observation) of
    /// scene `scene`.
    pub fn position(&self, agent: usize, scene: usize, step: usize) -> [f64; 2] {
        let paths = &self.agents[agent].paths;
        paths[if paths.len() == 1 { 0 } else { scene }][step]
    }

    /// The same forecast with every position `p` replaced by `frame.inverse_act(p)`: from the
    /// world frame into the frame whose pose in the world is `frame` (the robot's, say).
    pub fn in_frame(&self, frame: Pose2) -> Self {
        let agents = self
            .agents
            .iter()
            .map(|a| ForecastAgent {
                paths: a
                    .paths
                    .iter()
                    .map(|p| p.iter().map(|&q| frame.inverse_act(q)).collect())
                    .collect(),
                ..a.clone()
            })
            .collect();
        Self {
            agents,
            weights: self.weights.clone(),
            ..*self
        }
    }
}

/// The expectation of `f(scene)` over `scenes` scenes of probabilities `weights` (`None`:
/// equally likely, the mean).
pub(crate) fn expectation(
    weights: Option<&[f64]>,
    scenes: usize,
    mut f: impl FnMut(usize) -> f64,
) -> f64 {
    match weights {
        None => (0..scenes).map(&mut f).sum::<f64>() / scenes as f64,
        Some(w) => w.iter().enumerate().map(|(s, w)| w * f(s)).sum(),
    }
}

/// Each of `agents` with the one path `path` gives it.
fn one_path_per_agent(
    agents: &[AgentState],
    mut path: impl FnMut(&AgentState) -> Vec<[f64; 2]>,
) -> Vec<ForecastAgent> {
    agents
        .iter()
        .map(|a| ForecastAgent {
            id: a.id,
            radius: a.radius,
            paths: vec![path(a)],
        })
        .collect()
}

/// `horizon` positions of `agent` moving on at its velocity, `dt` apart from `dt` on.
pub fn constant_velocity_path(agent: &AgentState, horizon: usize, dt: f64) -> Vec<[f64; 2]> {
    (1..=horizon)
        .map(|j| agent.walked_on(j as f64 * dt))
        .collect()
}

/// The mean of equally long `paths`, position by position.
fn mean_path(paths: &[Vec<[f64; 2]>]) -> Vec<[f64; 2]> {
    let share = 1.0 / paths.len().max(1) as f64;
    let mut mean = vec![[0.0; 2]; paths.first().map_or(0, Vec::len)];
    for path in paths {
        for (m, p) in mean.iter_mut().zip(path) {
            m[0] += p[0] * share;
            m[1] += p[1] * share;
        }
    }
    mean
}

/// From waypoint `from` on (0-based), every path in `sampled` follows `cv` (the constant-
/// velocity path) at the offset it had at waypoint `from − 1`.
fn hold_departure(sampled: &mut [Vec<[f64; 2]>], cv: &[[f64; 2]], from: usize) {
    if from == 0 || from > cv.len() {
        return;
    }
    for path in sampled {
        let (p, c) = (path[from - 1], cv[from - 1]);
        let offset = [p[0] - c[0], p[1] - c[1]];
        for (q, c) in path.iter_mut().zip(cv).skip(from) {
            *q = [c[0] + offset[0], c[1] + offset[1]];
        }
    }
}

/// A source of [`Forecast`]s for a planner.
pub trait CrowdPredictor: Send {
    /// A short name for diagnostics (`constant-velocity`, `flow`, …).
    fn name(&self) -> &str;

    /// The forecast of `obs.agents` over `horizon` waypoints `dt` apart, in the world frame of
    /// `obs`, with every agent of the observation in it. An error makes the planner fall back
    /// to constant velocity for this call (and say so in its plan's notes).
    fn forecast(&mut self, obs: &Observation, horizon: usize, dt: f64) -> Result<Forecast, String>;
}

/// The forecast the planner makes without a predictor ([`Forecast::constant_velocity`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct ConstantVelocity;

impl CrowdPredictor for ConstantVelocity {
    fn name(&self) -> &str {
        "constant-velocity"
    }

    fn forecast(&mut self, obs: &Observation, horizon: usize, dt: f64) -> Result<Forecast, String> {
        Ok(Forecast::constant_velocity(&obs.agents, horizon, dt))
    }
}

/// A linear predictor of people from their recent positions: in the frame of the walker's
/// heading, its last `history` steps (and a constant) map linearly to how far its next
/// `horizon` positions depart from walking on at its last step. Fitted by ridge regression on
/// recorded tracks (`human2nav data predict --fit-on <data.toml> --export <file>`), saved as
/// TOML. An agent whose observation holds fewer than `history + 1` positions walks on at its
/// velocity; past `horizon` the last departure is held.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HistoryRidge {
    /// Steps of history the model reads (`history + 1` positions, the last the present).
    pub history: usize,
    /// Steps it predicts.
    pub horizon: usize,
    /// Seconds per step of the tracks it was fitted on; the planner's waypoints must match.
    pub dt: f64,
    /// What it was fitted on, in words.
    pub fitted_on: String,
    /// Row-major `(2·history + 1) × (2·horizon)`: row `f` holds feature `f`'s weight on each
    /// departure `(x, y)` of each predicted step, in the heading frame.
    pub weights: Vec<f64>,
}

impl HistoryRidge {
    /// Checks the shape and that every number is finite.
    pub fn validate(&self) -> Result<(), String> {
        if !(1..=1000).contains(&self.history) || !(1..=1000).contains(&self.horizon) {
            return Err(format!(
                "history and horizon must be 1 to 1000 steps, got {} and {}",
                self.history, self.horizon
            ));
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(format!("dt must be a time above 0 s, got {}", self.dt));
        }
        let want = (2 * self.history + 1) * 2 * self.horizon;
        if self.weights.len() != want {
            return Err(format!(
                "weights: {} numbers, the shape {} × {} needs {want}",
                self.weights.len(),
                2 * self.history + 1,
                2 * self.horizon
            ));
        }
        if let Some(i) = self.weights.iter().position(|w| !w.is_finite()) {
            return Err(format!("weights[{i}] is not a finite number"));
        }
        Ok(())
    }

    /// The walker's heading frame (a rotation) from its positions: the last step's direction,
    /// or the whole history's displacement when the last step is (nearly) zero, or the world's
    /// axes.
    pub fn heading(past: &[[f64; 2]]) -> Pose2 {
        let n = past.len();
        if n >= 2 {
            for d in [sub(past[n - 1], past[n - 2]), sub(past[n - 1], past[0])] {
                if d[0].hypot(d[1]) > 1e-4 {
                    return Pose2::new(0.0, 0.0, d[1].atan2(d[0]));
                }
            }
        }
        Pose2::IDENTITY
    }

    /// The features of `past` (positions, oldest first): each step's displacement in the
    /// heading `frame`, then 1.
    pub fn features(past: &[[f64; 2]], frame: Pose2) -> Vec<f64> {
        past.windows(2)
            .flat_map(|p| frame.inverse_rotate(sub(p[1], p[0])))
            .chain(std::iter::once(1.0))
            .collect()
    }

    /// `n` predicted positions after the last of `past` (`history + 1` positions, oldest
    /// first): the last step held, plus the model's departures turned out of the heading frame
    /// (the last one held past `horizon`). `None` when `past` has another length.
    pub fn predict(&self, past: &[[f64; 2]], n: usize) -> Option<Vec<[f64; 2]>> {
        if past.len() != self.history + 1 {
            return None;
        }
        let frame = Self::heading(past);
        let x = Self::features(past, frame);
        let outputs = 2 * self.horizon;
        let mut d = vec![0.0; outputs];
        for (xf, row) in x.iter().zip(self.weights.chunks_exact(outputs)) {
            for (d, w) in d.iter_mut().zip(row) {
                *d += xf * w;
            }
        }
        let now = past[self.history];
        let step = sub(now, past[self.history - 1]);
        Some(
            (0..n)
                .map(|i| {
                    let k = i.min(self.horizon - 1);
                    let dep = frame.rotate([d[2 * k], d[2 * k + 1]]);
                    let s = (i + 1) as f64;
                    [now[0] + step[0] * s + dep[0], now[1] + step[1] * s + dep[1]]
                })
                .collect(),
        )
    }
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

impl CrowdPredictor for HistoryRidge {
    fn name(&self) -> &str {
        "history-ridge"
    }

    fn forecast(&mut self, obs: &Observation, horizon: usize, dt: f64) -> Result<Forecast, String> {
        if (dt - self.dt).abs() > 1e-9 {
            return Err(format!(
                "the history model was fitted at {} s steps, the plan's are {dt} s",
                self.dt
            ));
        }
        Forecast::one_path_each(&obs.agents, horizon, |a| {
            let h = &a.history;
            let past = &h[h.len().saturating_sub(self.history + 1)..];
            self.predict(past, horizon)
                .filter(|p| p.iter().flatten().all(|v| v.is_finite()))
                .unwrap_or_else(|| constant_velocity_path(a, horizon, dt))
        })
    }
}

/// Settings of a [`FlowPredictor`] (the `[prediction]` table of a planner file).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FlowPredictorSettings {
    /// Scenes of the forecast: futures sampled per predicted agent (1 to [`MAX_SCENES`]).
    /// Default 4.
    pub samples: usize,
    /// Euler steps of each sample's integration (1 to 100). Default 5, as the planner's.
    pub steps_n: usize,
    /// Only agents within this distance (m) of the robot are predicted by the model; the
    /// others move on at constant velocity. Default 6.
    pub range: f64,
    /// At most this many agents, the nearest, are predicted by the model per call (each is a
    /// batch of `samples` through the network). Default 8.
    pub max_agents: usize,
    /// Agents slower than this (m/s) stay at constant velocity: the model was trained on
    /// people who walk (windows in which the walker moves less than 0.5 m were left out), and
    /// a standing person has no heading to predict from. Default 0.3.
    pub min_speed: f64,
    /// Agents faster than this (m/s) stay at constant velocity too: cyclists and skaters, or
    /// a track that jumps, are outside what the model saw (walkers, 90 % of them under 1.7
    /// m/s), and its samples for them scatter over metres. Default 2.5.
    pub max_speed: f64,
    /// Replace each agent's samples by their mean, position by position: one scene, a point
    /// forecast. One sample of a goal-free model is a worse guess than constant velocity, the
    /// mean of several a better one (on the validation windows, 16 samples of 5 steps: ADE
    /// 0.489 m over 3.2 s against constant velocity's 0.572). Default false: each sample is
    /// a scene.
    pub mean_of_samples: bool,
    /// Add the constant-velocity forecast as one more scene. Default false.
    pub constant_velocity_scene: bool,
    /// The constant-velocity scene's probability (0 to 1; needs `constant_velocity_scene`),
    /// the model's scenes sharing the rest equally. Unset (the default): every scene equally
    /// likely, `1 / (samples + 1)` each.
    pub constant_velocity_weight: Option<f64>,
    /// How long (s) the model's samples may depart from constant velocity: after this time
    /// each sampled path moves on at the agent's observed velocity, keeping the departure it
    /// had reached (so the scenes stop spreading). Unset (the default): the samples over the
    /// whole plan.
    pub deviation_horizon: Option<f64>,
    /// Draw the robot into each walker's raster, as a disc of `robot_radius` moving at its
    /// velocity: the walkers are predicted as people who see the robot and make way for it,
    /// as they make way for each other in the training data. Off, the robot is not in the
    /// raster, as in training, and the walkers are predicted as if it were not there (as a
    /// replayed crowd behaves). Default false.
    pub see_robot: bool,
    /// Radius (m) of the robot's disc in the rasters with `see_robot`. Default 0.4.
    pub robot_radius: f64,
    /// Seed of the source noise (mixed with the call's time and the agent's id, so that a
    /// forecast depends on its observation only). Default 0.
    pub seed: u64,
}

impl Default for FlowPredictorSettings {
    fn default() -> Self {
        Self {
            samples: 4,
            steps_n: 5,
            range: 6.0,
            max_agents: 8,
            min_speed: 0.3,
            max_speed: 2.5,
            mean_of_samples: false,
            constant_velocity_scene: false,
            constant_velocity_weight: None,
            deviation_horizon: None,
            see_robot: false,
            robot_radius: 0.4,
            seed: 0,
        }
    }
}

impl FlowPredictorSettings {
    /// Checks every field; the error is `<key>: <why>` for the first offending one.
    pub fn validate(&self) -> Result<(), String> {
        let scenes = self.samples + usize::from(self.constant_velocity_scene);
        if self.samples == 0 || scenes > MAX_SCENES {
            return Err(format!(
                "samples: must be 1 to {} (with the constant-velocity scene, {} \
                 scenes in all), got {}",
                MAX_SCENES - usize::from(self.constant_velocity_scene),
                MAX_SCENES,
                self.samples
            ));
        }
        if !(1..=100).contains(&self.steps_n) {
            return Err(format!("steps_n: must be 1 to 100, got {}", self.steps_n));
        }
        if !(self.range.is_finite() && self.range >= 0.0) {
            return Err("range: must be finite and ≥ 0".into());
        }
        if self.max_agents > 1000 {
            return Err(format!(
                "max_agents: must be at most 1000, got {}",
                self.max_agents
            ));
        }
        if !(self.min_speed.is_finite() && self.min_speed >= 0.0) {
            return Err("min_speed: must be finite and ≥ 0".into());
        }
        if !(self.max_speed.is_finite() && self.max_speed >= self.min_speed) {
            return Err("max_speed: must be finite and ≥ min_speed".into());
        }
        if !(self.robot_radius.is_finite() && self.robot_radius >= 0.0) {
            return Err("robot_radius: must be finite and ≥ 0".into());
        }
        if let Some(h) = self.deviation_horizon {
            if !(h.is_finite() && h > 0.0) {
                return Err(format!(
                    "deviation_horizon: must be finite and > 0 (s), got {h}"
                ));
            }
        }
        if let Some(w) = self.constant_velocity_weight {
            if !self.constant_velocity_scene {
                return Err(
                    "constant_velocity_weight: needs constant_velocity_scene = true".into(),
                );
            }
            if !(0.0..=1.0).contains(&w) {
                return Err(format!("constant_velocity_weight: must be 0 to 1, got {w}"));
            }
        }
        Ok(())
    }
}

/// A learned, multimodal predictor of people: a flow model trained on people walking, without
/// their goals (the flow crate's goal-free model), samples where each agent near the robot
/// goes, from the agent's own pose and velocity and the other agents around it (its BEV
/// raster, drawn as in training; the robot is in it only with
/// [`FlowPredictorSettings::see_robot`]). Scene `s` of the forecast is every such agent's
/// sample `s` (held parallel to constant velocity after
/// [`FlowPredictorSettings::deviation_horizon`]), or the one scene of their means with
/// [`FlowPredictorSettings::mean_of_samples`], then the constant-velocity scene with
/// [`FlowPredictorSettings::constant_velocity_scene`], of probability
/// [`FlowPredictorSettings::constant_velocity_weight`]; the other agents move on at constant
/// velocity. The model's poses are taken to be the forecast's `dt` apart (the planner's, which
/// must match the training data's 0.1 s); past its horizon the last pose is held.
pub struct FlowPredictor<M> {
    model: M,
    bev: BevSpec,
    settings: FlowPredictorSettings,
    raster: Vec<f32>,
    workspace: GuidanceWorkspace,
}

impl<M> std::fmt::Debug for FlowPredictor<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FlowPredictor")
            .field("bev", &self.bev)
            .field("settings", &self.settings)
            .finish_non_exhaustive()
    }
}

impl<M: FlowModel> FlowPredictor<M> {
    /// A predictor sampling `model` (its rasters drawn with `bev`, the model's own spec).
    pub fn new(model: M, bev: BevSpec, settings: FlowPredictorSettings) -> Result<Self, String> {
        settings.validate()?;
        bev.validate().map_err(|e| format!("bev: {e}"))?;
        if model.horizon() == 0 {
            return Err("the prediction model has a horizon of 0 poses".into());
        }
        Ok(Self {
            raster: vec![0.0; bev.len()],
            model,
            bev,
            settings,
            workspace: GuidanceWorkspace::new(),
        })
    }

    /// The settings in force.
    pub fn settings(&self) -> &FlowPredictorSettings {
        &self.settings
    }

    /// The indices of the agents the model predicts: walking (between `min_speed` and
    /// `max_speed`), within range, the nearest first, at most `max_agents`.
    fn chosen(&self, obs: &Observation) -> Vec<usize> {
        let s = &self.settings;
        let mut near: Vec<(f64, usize)> = obs
            .agents
            .iter()
            .enumerate()
            .filter_map(|(i, a)| {
                let d = (a.position[0] - obs.ego.x).hypot(a.position[1] - obs.ego.y);
                let speed = a.velocity[0].hypot(a.velocity[1]);
                let walking = speed >= s.min_speed && speed <= s.max_speed && speed > 0.0;
                (d <= s.range && walking).then_some((d, i))
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        near.truncate(s.max_agents);
        near.into_iter().map(|(_, i)| i).collect()
    }

    /// `samples` paths of agent `i` of `obs` (world frame, `horizon` positions each).
    fn sample_agent(
        &mut self,
        obs: &Observation,
        i: usize,
        horizon: usize,
    ) -> Result<Vec<Vec<[f64; 2]>>, String> {
        let a = &obs.agents[i];
        let speed = a.velocity[0].hypot(a.velocity[1]);
        let pose = Pose2::new(
            a.position[0],
            a.position[1],
            a.velocity[1].atan2(a.velocity[0]),
        );
        // The others as the rasterizer takes them (no copies of their histories), then the
        // robot when the walkers are to see it.
        let others = obs
            .agents
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, b)| BevAgent::from(b));
        let v = obs.ego_velocity;
        let robot = self.settings.see_robot.then(|| BevAgent {
            position: [obs.ego.x, obs.ego.y],
            velocity: obs.ego.rotate([v.vx, v.vy]),
            radius: self.settings.robot_radius,
        });
        bev::rasterize_agents(self.bev, pose, others.chain(robot), &mut self.raster);
        let cond = FlowCondition {
            bev: self.raster.clone(),
            goal: [0.0, 0.0],
            velocity: [speed, 0.0],
        };
        let k = self.settings.samples;
        let t = self.model.horizon();
        // The source noise depends on the observation only: its time, the agent and the seed.
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.settings.seed ^ obs.time.to_bits() ^ a.id.wrapping_mul(0x9e37_79b9_7f4a_7c15),
        );
        let x0 = crate::flow::draw_source(self.model.source_std(), k, t, &mut rng);
        let out = guidance::sample(
            &self.model,
            &cond,
            &x0,
            self.settings.steps_n,
            &mut self.workspace,
        )
        .map_err(|e| format!("agent {}: {e}", a.id))?;
        Ok(out
            .chunks_exact(t * 3)
            .map(|traj| {
                (0..horizon)
                    .map(|j| {
                        // Past the model's horizon the last pose is held.
                        let q = &traj[3 * j.min(t - 1)..];
                        pose.act([q[0], q[1]])
                    })
                    .collect()
            })
            .collect())
    }
}

impl<M: FlowModel + Send> CrowdPredictor for FlowPredictor<M> {
    fn name(&self) -> &str {
        "flow"
    }

    fn forecast(&mut self, obs: &Observation, horizon: usize, dt: f64) -> Result<Forecast, String> {
        let chosen = self.chosen(obs);
        let mut paths: Vec<Vec<Vec<[f64; 2]>>> = obs
            .agents
            .iter()
            .map(|a| vec![constant_velocity_path(a, horizon, dt)])
            .collect();
        let k = if self.settings.mean_of_samples {
            1
        } else {
            self.settings.samples
        };
        let cv_scene = self.settings.constant_velocity_scene;
        // Waypoints within the deviation horizon (at least the first).
        let held_from = self
            .settings
            .deviation_horizon
            .map(|h| ((h / dt).round() as usize).clamp(1, horizon.max(1)));
        for &i in &chosen {
            let mut sampled = self.sample_agent(obs, i, horizon)?;
            if self.settings.mean_of_samples {
                sampled = vec![mean_path(&sampled)];
            }
            if let Some(from) = held_from {
                hold_departure(&mut sampled, &paths[i][0], from);
            }
            if cv_scene {
                sampled.push(paths[i][0].clone());
            }
            paths[i] = sampled;
        }
        let agents = obs
            .agents
            .iter()
            .zip(paths)
            .map(|(a, paths)| ForecastAgent {
                id: a.id,
                radius: a.radius,
                paths,
            })
            .collect();
        if chosen.is_empty() {
            return Forecast::new(horizon, 1, agents);
        }
        let forecast = Forecast::new(horizon, k + usize::from(cv_scene), agents)?;
        // `validate` allows a weight only with the constant-velocity scene.
        match self.settings.constant_velocity_weight {
            Some(w) => {
                let mut weights = vec![(1.0 - w) / k as f64; k];
                weights.push(w);
                forecast.with_weights(weights)
            }
            _ => Ok(forecast),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walker(id: u64, p: [f64; 2], v: [f64; 2]) -> AgentState {
        AgentState {
            id,
            position: p,
            velocity: v,
            radius: 0.3,
            history: Vec::new(),
        }
    }

    #[test]
    fn constant_velocity_moves_each_agent_on_from_the_first_step() {
        let f = Forecast::constant_velocity(&[walker(7, [1.0, 2.0], [0.5, -1.0])], 3, 0.1);
        assert_eq!((f.horizon(), f.scenes()), (3, 1));
        let p = f.position(0, 0, 2);
        assert!((p[0] - 1.15).abs() < 1e-12 && (p[1] - 1.7).abs() < 1e-12);
    }

    #[test]
    fn a_shared_path_serves_every_scene_and_frames_change_positions() {
        let agents = vec![
            ForecastAgent {
                id: 1,
                radius: 0.3,
                paths: vec![vec![[1.0, 0.0]; 2]],
            },
            ForecastAgent {
                id: 2,
                radius: 0.3,
                paths: vec![vec![[0.0, 1.0]; 2], vec![[0.0, 2.0]; 2]],
            },
        ];
        let f = Forecast::new(2, 2, agents).expect("valid");
        assert_eq!(f.position(0, 1, 1), [1.0, 0.0]);
        assert_eq!(f.position(1, 1, 0), [0.0, 2.0]);
        // In the frame of a robot at (1, 0) facing +y, (1, 0) is its origin and (0, 2) is 2 m
        // ahead and 1 m to the left.
        let g = f.in_frame(Pose2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2));
        let near = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]) < 1e-12;
        assert!(near(g.position(0, 0, 0), [0.0, 0.0]));
        assert!(near(g.position(1, 1, 0), [2.0, 1.0]));
    }

    /// A "model" whose every sample veers left: 0.1 m forward and 0.05 m left per step, in the
    /// walker's frame.
    fn veering_left(horizon: usize) -> crate::guidance::analytic::GeodesicTarget {
        let target = (1..=horizon)
            .flat_map(|k| [0.1 * k as f64, 0.05 * k as f64, 0.0])
            .collect();
        crate::guidance::analytic::GeodesicTarget { target }
    }

    #[test]
    fn the_flow_predictor_samples_near_walkers_in_their_own_frame() {
        let settings = FlowPredictorSettings {
            samples: 3,
            range: 5.0,
            max_agents: 1,
            ..FlowPredictorSettings::default()
        };
        let mut p = FlowPredictor::new(veering_left(8), BevSpec::default(), settings).unwrap();
        let obs = Observation {
            agents: vec![
                // Walking along +y: its left is −x.
                walker(1, [1.0, 0.0], [0.0, 1.0]),
                // Nearer, but standing: constant velocity.
                walker(2, [0.5, 0.0], [0.1, 0.0]),
                // Moving but beyond max_agents (farther than agent 1).
                walker(3, [2.0, 0.0], [1.0, 0.0]),
                // Out of range.
                walker(4, [9.0, 0.0], [1.0, 0.0]),
                // Near, but as fast as a cyclist: constant velocity.
                walker(5, [0.2, 0.0], [6.0, 0.0]),
            ],
            ..Observation::default()
        };
        let f = p.forecast(&obs, 10, 0.1).unwrap();
        assert_eq!((f.scenes(), f.horizon()), (3, 10));
        let paths: Vec<usize> = f.agents().iter().map(|a| a.paths.len()).collect();
        assert_eq!(paths, [3, 1, 1, 1, 1]);
        for s in 0..3 {
            // Step 4 (0.5 s): 0.5 m ahead (+y) and 0.25 m to its left (−x); past the model's 8
            // poses the last one is held.
            let q = f.position(0, s, 4);
            assert!(
                (q[0] - 0.75).abs() < 1e-3 && (q[1] - 0.5).abs() < 1e-3,
                "{q:?}"
            );
            let q = f.position(0, s, 9);
            assert!(
                (q[0] - 0.6).abs() < 1e-3 && (q[1] - 0.8).abs() < 1e-3,
                "{q:?}"
            );
        }
        assert_eq!(f.position(2, 1, 0), [2.1, 0.0]);
        // The same observation gives the same forecast; with the constant-velocity scene there
        // is one more scene, agent 1 on its straight line in it.
        assert_eq!(p.forecast(&obs, 10, 0.1).unwrap(), f);
        let settings = FlowPredictorSettings {
            constant_velocity_scene: true,
            ..settings
        };
        let mut p = FlowPredictor::new(veering_left(8), BevSpec::default(), settings).unwrap();
        let g = p.forecast(&obs, 10, 0.1).unwrap();
        assert_eq!(g.scenes(), 4);
        let q = g.position(0, 3, 4);
        assert!(
            (q[0] - 1.0).abs() < 1e-12 && (q[1] - 0.5).abs() < 1e-12,
            "{q:?}"
        );
        assert_eq!(g.weight(3), 0.25);
        // Weighted: the constant-velocity scene 0.4, the model's three 0.2 each; same paths.
        let weighted = FlowPredictorSettings {
            constant_velocity_weight: Some(0.4),
            ..settings
        };
        let mut p = FlowPredictor::new(veering_left(8), BevSpec::default(), weighted).unwrap();
        let h = p.forecast(&obs, 10, 0.1).unwrap();
        assert_eq!(h.agents(), g.agents());
        let w: Vec<f64> = (0..4).map(|s| h.weight(s)).collect();
        assert!(
            w.iter()
                .zip([0.2, 0.2, 0.2, 0.4])
                .all(|(a, b)| (a - b).abs() < 1e-12),
            "{w:?}"
        );
        // With a deviation horizon of 0.3 s the samples depart from the straight line for
        // three waypoints, then keep that departure: the same paths up to the third waypoint,
        // parallel to the straight line after it.
        let held = FlowPredictorSettings {
            deviation_horizon: Some(0.3),
            ..settings
        };
        let mut p = FlowPredictor::new(veering_left(8), BevSpec::default(), held).unwrap();
        let e = p.forecast(&obs, 10, 0.1).unwrap();
        for s in 0..3 {
            for j in 0..3 {
                assert_eq!(e.position(0, s, j), g.position(0, s, j));
            }
            let gap = |j: usize| {
                let (q, c) = (e.position(0, s, j), g.position(0, 3, j));
                [q[0] - c[0], q[1] - c[1]]
            };
            assert!(gap(2)[0].abs() > 0.05, "{:?}", gap(2));
            for j in 3..10 {
                let d = gap(j);
                assert!((d[0] - gap(2)[0]).abs() < 1e-12 && (d[1] - gap(2)[1]).abs() < 1e-12);
            }
        }
    }

    /// With `mean_of_samples` the samples of a model that leaves them scattered (a field of
    /// zero: each sample is where its source noise put it) are averaged into one scene, the
    /// mean of the very samples the scenes would have been.
    #[test]
    fn the_mean_of_samples_is_one_scene_of_their_average() {
        let model = || crate::guidance::analytic::ConstantField {
            twists: vec![0.0; 3 * 8],
        };
        let settings = FlowPredictorSettings {
            samples: 5,
            ..FlowPredictorSettings::default()
        };
        let obs = Observation {
            agents: vec![walker(1, [1.0, 0.0], [0.0, 1.0])],
            ..Observation::default()
        };
        let scattered = FlowPredictor::new(model(), BevSpec::default(), settings)
            .unwrap()
            .forecast(&obs, 8, 0.1)
            .unwrap();
        assert_eq!(scattered.scenes(), 5);
        let averaged = FlowPredictorSettings {
            mean_of_samples: true,
            constant_velocity_scene: true,
            constant_velocity_weight: Some(0.3),
            ..settings
        };
        let mean = FlowPredictor::new(model(), BevSpec::default(), averaged)
            .unwrap()
            .forecast(&obs, 8, 0.1)
            .unwrap();
        assert_eq!(mean.scenes(), 2);
        assert_eq!((mean.weight(0), mean.weight(1)), (0.7, 0.3));
        for j in 0..8 {
            let expect = (0..5).fold([0.0; 2], |acc, s| {
                let q = scattered.position(0, s, j);
                [acc[0] + q[0] / 5.0, acc[1] + q[1] / 5.0]
            });
            let q = mean.position(0, 0, j);
            assert!(
                (q[0] - expect[0]).abs() < 1e-12 && (q[1] - expect[1]).abs() < 1e-12,
                "{q:?} against {expect:?}"
            );
            // The second scene is the walker at constant velocity.
            let c = mean.position(0, 1, j);
            assert!((c[0] - 1.0).abs() < 1e-12 && (c[1] - 0.1 * (j + 1) as f64).abs() < 1e-12);
        }
        let spread = (0..5)
            .map(|s| scattered.position(0, s, 3)[0])
            .fold(0.0f64, |m, x| m.max((x - 1.0).abs()));
        assert!(spread > 0.1, "the samples should scatter: {spread}");
    }

    /// A history model whose only weight is on the constant feature: every walker departs to
    /// its left by 0.1 m per step from walking on at its last step, whichever way it walks; a
    /// walker with too short a history walks on at its velocity.
    #[test]
    fn the_history_model_departs_in_each_walkers_own_frame() {
        let (history, horizon) = (2, 4);
        let mut weights = vec![0.0; (2 * history + 1) * 2 * horizon];
        let constant = 2 * history;
        for k in 0..horizon {
            weights[constant * 2 * horizon + 2 * k + 1] = 0.1 * (k + 1) as f64;
        }
        let mut model = HistoryRidge {
            history,
            horizon,
            dt: 0.1,
            fitted_on: "by hand".into(),
            weights,
        };
        model.validate().unwrap();
        let with_history = |id, history: Vec<[f64; 2]>, v| AgentState {
            history,
            ..walker(id, [0.0, 0.0], v)
        };
        let obs = Observation {
            agents: vec![
                // Along +x: its left is +y.
                with_history(1, vec![[-0.2, 0.0], [-0.1, 0.0], [0.0, 0.0]], [1.0, 0.0]),
                // Along +y: its left is −x.
                with_history(2, vec![[0.0, -0.2], [0.0, -0.1], [0.0, 0.0]], [0.0, 1.0]),
                // One step of history only: constant velocity.
                with_history(3, vec![[0.0, -0.1], [0.0, 0.0]], [0.0, 1.0]),
            ],
            ..Observation::default()
        };
        let f = model.forecast(&obs, 6, 0.1).unwrap();
        let near = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]) < 1e-12;
        assert!(near(f.position(0, 0, 1), [0.2, 0.2]));
        assert!(near(f.position(1, 0, 1), [-0.2, 0.2]));
        // Past the model's four steps the last departure is held.
        assert!(near(f.position(0, 0, 5), [0.6, 0.4]));
        assert!(near(f.position(2, 0, 5), [0.0, 0.6]));
        assert!(model.forecast(&obs, 6, 0.05).is_err());
        model.weights.pop();
        assert!(model.validate().unwrap_err().starts_with("weights: "));
        model.weights.push(f64::NAN);
        assert!(model.validate().unwrap_err().contains("finite"));
    }

    #[test]
    fn the_expectation_weighs_each_scene_by_its_probability() {
        let agent = ForecastAgent {
            id: 1,
            radius: 0.3,
            paths: vec![vec![[0.0, 0.0]; 2]; 3],
        };
        let f = Forecast::new(2, 3, vec![agent]).unwrap();
        let cost = |s: usize| [1.0, 2.0, 6.0][s];
        assert_eq!(f.expectation(cost), 3.0);
        let w = f.clone().with_weights(vec![2.0, 1.0, 1.0]).unwrap();
        assert_eq!((w.weight(0), w.weight(2)), (0.5, 0.25));
        assert!((w.expectation(cost) - 2.5).abs() < 1e-12);
        // Weights survive a change of frame.
        let moved = w.in_frame(Pose2::new(1.0, 2.0, 0.3));
        assert_eq!(moved.weight(0), 0.5);
        for (weights, why) in [
            (vec![1.0, 1.0], "2 weights for 3 scenes"),
            (vec![1.0, -1.0, 1.0], "a scene weight of -1"),
            (vec![f64::NAN, 1.0, 1.0], "a scene weight of NaN"),
            (vec![0.0; 3], "the scene weights sum to 0"),
            (vec![f64::MAX; 3], "the scene weights sum to inf"),
        ] {
            let e = f.clone().with_weights(weights).unwrap_err();
            assert!(e.starts_with(why), "{e}");
        }
    }

    #[test]
    fn flow_predictor_settings_name_the_bad_field() {
        let bad = |s: FlowPredictorSettings| s.validate().unwrap_err();
        let d = FlowPredictorSettings::default();
        assert!(bad(FlowPredictorSettings { samples: 0, ..d }).starts_with("samples: "));
        assert!(bad(FlowPredictorSettings { steps_n: 0, ..d }).starts_with("steps_n: "));
        let e = bad(FlowPredictorSettings {
            range: f64::NAN,
            ..d
        });
        assert!(e.starts_with("range: "), "{e}");
        let e = bad(FlowPredictorSettings {
            min_speed: -1.0,
            ..d
        });
        assert!(e.starts_with("min_speed: "), "{e}");
        let e = bad(FlowPredictorSettings {
            max_speed: 0.1,
            ..d
        });
        assert!(e.starts_with("max_speed: "), "{e}");
        for h in [0.0, -1.0, f64::INFINITY] {
            let e = bad(FlowPredictorSettings {
                deviation_horizon: Some(h),
                ..d
            });
            assert!(e.starts_with("deviation_horizon: "), "{e}");
        }
        for (scene, weight) in [(false, 0.5), (true, 1.5), (true, f64::NAN)] {
            let e = bad(FlowPredictorSettings {
                constant_velocity_scene: scene,
                constant_velocity_weight: Some(weight),
                ..d
            });
            assert!(e.starts_with("constant_velocity_weight: "), "{e}");
        }
        assert!(toml::from_str::<FlowPredictorSettings>("sample = 3").is_err());
    }

    #[test]
    fn malformed_forecasts_are_refused_with_the_agent_named() {
        let path = |n: usize| vec![[0.0, 0.0]; n];
        let one = |id: u64, paths: Vec<Vec<[f64; 2]>>| ForecastAgent {
            id,
            radius: 0.3,
            paths,
        };
        assert!(Forecast::new(2, 0, Vec::new()).is_err());
        assert!(Forecast::new(2, MAX_SCENES + 1, Vec::new()).is_err());
        let e = Forecast::new(2, 3, vec![one(4, vec![path(2), path(2)])]).unwrap_err();
        assert!(e.contains("agent 4") && e.contains("2 paths"), "{e}");
        let e = Forecast::new(2, 1, vec![one(5, vec![path(3)])]).unwrap_err();
        assert!(e.contains("agent 5") && e.contains("3 positions"), "{e}");
        let e = Forecast::new(2, 1, vec![one(6, vec![vec![[f64::NAN, 0.0]; 2]])]).unwrap_err();
        assert!(e.contains("agent 6"), "{e}");
    }
}
