//! What a planning call starts from: the model's condition (BEV raster, goal, velocity), the
//! crowd's forecast, the obstacles near the robot, the source noise and warnings on the start.

use super::*;

impl<M: FlowModel> Human2Nav<M> {
    /// The forecast the selection scores against, in the ego frame: the predictor's, or
    /// constant velocity without one or when it fails (noted in `notes`).
    pub(super) fn forecast(
        &mut self,
        obs: &Observation,
        agents: &[AgentState],
        horizon: usize,
        notes: &mut Vec<String>,
    ) -> Forecast {
        let dt = self.settings.dt;
        if let Some(p) = self.predictor.as_mut() {
            match p.forecast(obs, horizon, dt) {
                Ok(f) if f.horizon() == horizon && f.agents().len() == obs.agents.len() => {
                    return f.in_frame(obs.ego);
                }
                Ok(f) => notes.push(format!(
                    "predictor {} forecast {} agents over {} waypoints for {} agents over {}; \
                     constant velocity used",
                    p.name(),
                    f.agents().len(),
                    f.horizon(),
                    obs.agents.len(),
                    horizon
                )),
                Err(e) => notes.push(format!(
                    "predictor {} failed ({e}); constant velocity used",
                    p.name()
                )),
            }
        }
        Forecast::constant_velocity(agents, horizon, dt)
    }

    /// Builds the ego-frame condition and the ego-frame agents for one observation.
    pub fn condition(&mut self, obs: &Observation) -> (FlowCondition, Vec<AgentState>) {
        bev::rasterize(self.bev, obs.ego, &obs.agents, &mut self.raster);
        let mut goal = obs.ego.inverse_act(obs.goal);
        let dist = goal[0].hypot(goal[1]);
        if dist > self.settings.goal_clip {
            let s = self.settings.goal_clip / dist;
            goal = [goal[0] * s, goal[1] * s];
        }
        let agents = obs
            .agents
            .iter()
            .map(|a| AgentState {
                position: obs.ego.inverse_act(a.position),
                velocity: obs.ego.inverse_rotate(a.velocity),
                history: a.history.iter().map(|p| obs.ego.inverse_act(*p)).collect(),
                ..a.clone()
            })
            .collect();
        let cond = FlowCondition {
            bev: self.raster.clone(),
            goal,
            velocity: [obs.ego_velocity.vx, obs.ego_velocity.vy],
        };
        (cond, agents)
    }

    pub(super) fn draw_source(&mut self, k: usize, t: usize) -> Vec<f64> {
        crate::flow::draw_source(self.model.source_std(), k, t, &mut self.rng)
    }

    /// What is wrong with the robot's own state in `obs` ([`PlanInfo::warnings`]): its
    /// footprint overlapping an obstacle or an occupied cell, or a velocity more than
    /// [`LIMIT_WARNING_FACTOR`] times a limit.
    pub(super) fn start_warnings(&self, obs: &Observation) -> Vec<String> {
        let mut warnings = Vec::new();
        let shapes = &self.robot.footprint;
        let here = [obs.ego.x, obs.ego.y];
        for (i, o) in obs.obstacles.iter().enumerate() {
            let c = crate::obstacle::footprint_clearance(shapes, obs.ego, o);
            if c < 0.0 {
                warnings.push(format!(
                    "the robot starts inside obstacles[{i}] (overlapping by {:.3} m)",
                    -c
                ));
            }
        }
        if let Some(grid) = &obs.occupancy {
            let cells = grid.obstacles_near(here, self.reach);
            if cells
                .iter()
                .any(|o| crate::obstacle::footprint_clearance(shapes, obs.ego, o) < 0.0)
            {
                warnings.push("the robot starts on an occupied cell of the occupancy grid".into());
            }
        }
        let l = &self.robot.limits;
        let v = obs.ego_velocity;
        for (what, value, limit) in [
            ("forward speed", v.vx, l.v_max),
            ("reverse speed", -v.vx, l.v_reverse_max),
            ("lateral speed", v.vy.abs(), l.lateral_speed_max),
            ("yaw rate", v.omega.abs(), l.omega_max),
        ] {
            if value > LIMIT_WARNING_FACTOR * limit {
                warnings.push(format!(
                    "the robot starts at a {what} of {value:.3}, beyond its limit of {limit:.3}"
                ));
            }
        }
        warnings
    }

    /// The observation's static obstacles that a plan of `horizon` poses could reach (within
    /// the distance covered at `v_max`, plus the footprint's reach and the selection margin),
    /// with the occupied cells of its grid there, in the ego frame.
    pub(super) fn nearby_obstacles(&self, obs: &Observation, horizon: usize) -> Vec<Obstacle> {
        let range = self.robot.limits.v_max * horizon as f64 * self.settings.dt
            + self.reach
            + self.settings.selection.margin;
        let here = [obs.ego.x, obs.ego.y];
        let grid = obs
            .occupancy
            .as_ref()
            .map(|g| g.obstacles_near(here, range))
            .unwrap_or_default();
        obs.obstacles
            .iter()
            .filter(|o| o.distance(here) <= range)
            .chain(&grid)
            .map(|o| o.in_frame(obs.ego))
            .collect()
    }
}
