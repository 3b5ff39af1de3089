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

use crate::planner::{AgentState, Observation};
use crate::se2::Pose2;

mod flow;
mod ridge;

pub use flow::{FlowPredictor, FlowPredictorSettings};
pub use ridge::HistoryRidge;

/// Largest number of scenes of a forecast: each one is a pass of the selection over every
/// candidate, so hundreds would be seconds a call.
pub const MAX_SCENES: usize = 64;

/// Why a [`Forecast`] could not be built or a [`CrowdPredictor`] could not make one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ForecastError {
    /// Too few or too many scenes.
    #[error("a forecast needs 1 to {MAX_SCENES} scenes, got {0}")]
    Scenes(usize),
    /// An agent has neither one path nor one per scene.
    #[error("agent {agent}: {paths} paths for {scenes} scenes (1 or {scenes} expected)")]
    Paths {
        /// The agent's id.
        agent: u64,
        /// Its paths.
        paths: usize,
        /// The forecast's scenes.
        scenes: usize,
    },
    /// A path whose length is not the horizon.
    #[error("agent {agent}: a path of {len} positions for a horizon of {horizon}")]
    PathLength {
        /// The agent's id.
        agent: u64,
        /// The path's positions.
        len: usize,
        /// The forecast's horizon.
        horizon: usize,
    },
    /// A position or radius that is not a finite number (a radius below 0 too).
    #[error("agent {0}: a non-finite position or radius")]
    NotFinite(u64),
    /// Not one weight per scene.
    #[error("{weights} weights for {scenes} scenes")]
    WeightCount {
        /// The weights given.
        weights: usize,
        /// The forecast's scenes.
        scenes: usize,
    },
    /// A scene weight that is negative or not finite.
    #[error("a scene weight of {0} (finite and ≥ 0 expected)")]
    Weight(f64),
    /// Scene weights that sum to 0 or overflow.
    #[error("the scene weights sum to {0} (a positive, finite sum expected)")]
    WeightSum(f64),
    /// A predictor fitted at another waypoint spacing than the plan's.
    #[error("the {predictor} was fitted at {fitted} s steps, the plan's are {plan} s")]
    Step {
        /// What was fitted, in words.
        predictor: &'static str,
        /// Its spacing, seconds.
        fitted: f64,
        /// The plan's, seconds.
        plan: f64,
    },
    /// Sampling a flow model for one agent failed.
    #[error("agent {agent}: {source}")]
    Sampling {
        /// The agent's id.
        agent: u64,
        /// Why.
        source: crate::guidance::GuidanceError,
    },
    /// A predictor's own reason (predictors written elsewhere: `"…".into()`).
    #[error("{0}")]
    Other(String),
}

impl From<String> for ForecastError {
    fn from(reason: String) -> Self {
        Self::Other(reason)
    }
}

impl From<&str> for ForecastError {
    fn from(reason: &str) -> Self {
        Self::Other(reason.to_owned())
    }
}

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
    pub fn new(
        horizon: usize,
        scenes: usize,
        agents: Vec<ForecastAgent>,
    ) -> Result<Self, ForecastError> {
        if !(1..=MAX_SCENES).contains(&scenes) {
            return Err(ForecastError::Scenes(scenes));
        }
        for a in &agents {
            if a.paths.len() != 1 && a.paths.len() != scenes {
                return Err(ForecastError::Paths {
                    agent: a.id,
                    paths: a.paths.len(),
                    scenes,
                });
            }
            if let Some(p) = a.paths.iter().find(|p| p.len() != horizon) {
                return Err(ForecastError::PathLength {
                    agent: a.id,
                    len: p.len(),
                    horizon,
                });
            }
            let finite = a.paths.iter().flatten().flatten().all(|v| v.is_finite());
            if !(finite && a.radius.is_finite() && a.radius >= 0.0) {
                return Err(ForecastError::NotFinite(a.id));
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
    pub fn with_weights(self, weights: Vec<f64>) -> Result<Self, ForecastError> {
        if weights.len() != self.scenes {
            return Err(ForecastError::WeightCount {
                weights: weights.len(),
                scenes: self.scenes,
            });
        }
        if let Some(&w) = weights.iter().find(|w| !(w.is_finite() && **w >= 0.0)) {
            return Err(ForecastError::Weight(w));
        }
        let sum: f64 = weights.iter().sum();
        if !(sum > 0.0 && sum.is_finite()) {
            return Err(ForecastError::WeightSum(sum));
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
    ) -> Result<Self, ForecastError> {
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

/// Where something at `position` moving at `velocity` is `t` later: `position + velocity·t`,
/// the one constant-velocity extrapolation of the SDK (the forecast, the evaluation baselines,
/// [`AgentState::walked_on`]).
#[inline]
pub fn walk_on(position: [f64; 2], velocity: [f64; 2], t: f64) -> [f64; 2] {
    [position[0] + velocity[0] * t, position[1] + velocity[1] * t]
}

/// `horizon` positions of something at `position` moving at `velocity`, `dt` apart from `dt`
/// on ([`walk_on`] at `dt, 2dt, …`).
pub fn constant_velocity_positions(
    position: [f64; 2],
    velocity: [f64; 2],
    horizon: usize,
    dt: f64,
) -> Vec<[f64; 2]> {
    (1..=horizon)
        .map(|j| walk_on(position, velocity, j as f64 * dt))
        .collect()
}

/// `horizon` positions of `agent` moving on at its velocity, `dt` apart from `dt` on.
pub fn constant_velocity_path(agent: &AgentState, horizon: usize, dt: f64) -> Vec<[f64; 2]> {
    constant_velocity_positions(agent.position, agent.velocity, horizon, dt)
}

/// A source of [`Forecast`]s for a planner.
pub trait CrowdPredictor: Send {
    /// A short name for diagnostics (`constant-velocity`, `flow`, …).
    fn name(&self) -> &str;

    /// The forecast of `obs.agents` over `horizon` waypoints `dt` apart, in the world frame of
    /// `obs`, with every agent of the observation in it. An error makes the planner fall back
    /// to constant velocity for this call (and say so in its plan's notes).
    fn forecast(
        &mut self,
        obs: &Observation,
        horizon: usize,
        dt: f64,
    ) -> Result<Forecast, ForecastError>;
}

/// The forecast the planner makes without a predictor ([`Forecast::constant_velocity`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct ConstantVelocity;

impl CrowdPredictor for ConstantVelocity {
    fn name(&self) -> &str {
        "constant-velocity"
    }

    fn forecast(
        &mut self,
        obs: &Observation,
        horizon: usize,
        dt: f64,
    ) -> Result<Forecast, ForecastError> {
        Ok(Forecast::constant_velocity(&obs.agents, horizon, dt))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(super) fn walker(id: u64, p: [f64; 2], v: [f64; 2]) -> AgentState {
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
            let e = f.clone().with_weights(weights).unwrap_err().to_string();
            assert!(e.starts_with(why), "{e}");
        }
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
        let e = Forecast::new(2, 3, vec![one(4, vec![path(2), path(2)])])
            .unwrap_err()
            .to_string();
        assert!(e.contains("agent 4") && e.contains("2 paths"), "{e}");
        let e = Forecast::new(2, 1, vec![one(5, vec![path(3)])])
            .unwrap_err()
            .to_string();
        assert!(e.contains("agent 5") && e.contains("3 positions"), "{e}");
        let e = Forecast::new(2, 1, vec![one(6, vec![vec![[f64::NAN, 0.0]; 2]])])
            .unwrap_err()
            .to_string();
        assert!(e.contains("agent 6"), "{e}");
    }
}
