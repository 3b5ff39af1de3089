//! [`FlowPredictor`]: people predicted by sampling a goal-free flow model of walkers.

use super::{
    CrowdPredictor, Forecast, ForecastAgent, ForecastError, MAX_SCENES, constant_velocity_path,
};
use crate::bev::{self, BevAgent, BevSpec};
use crate::flow::{FlowCondition, FlowModel};
use crate::guidance::{self, GuidanceWorkspace};
use crate::planner::Observation;
use crate::se2::Pose2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

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
    ) -> Result<Vec<Vec<[f64; 2]>>, ForecastError> {
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
        .map_err(|source| ForecastError::Sampling {
            agent: a.id,
            source,
        })?;
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

    fn forecast(
        &mut self,
        obs: &Observation,
        horizon: usize,
        dt: f64,
    ) -> Result<Forecast, ForecastError> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forecast::tests::walker;

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
}
