//! The MPPI planner.
//!
//! Each call, for `iteration_count` rounds:
//!
//! 1. `batch_size` control sequences `v_i = clip(u + ε_i)`, `ε_i ~ N(0, diag(σ²))` per step,
//!    around the current optimum `u` (sample 0 is `u` itself, noise-free);
//! 2. each is rolled out through the motion model from the robot's pose and current velocity,
//!    the velocity following the controls within the acceleration limits;
//! 3. each rollout is scored by the critics (goal, prefer-forward, static obstacles,
//!    pedestrians at constant velocity) plus the control-cost term
//!    `γ·Σ_t Σ_c u_t,c·ε'_t,c / σ_c²` (`ε' = v − u`, the noise left after clipping);
//! 4. `u ← Σ_i w_i v_i` with `w_i ∝ exp(−(S_i − min S)/λ)`, clipped into the limits.
//!
//! The plan is the rollout of `u`: poses `model_dt` apart from the current pose. Between
//! calls `u` is shifted by the number of `model_dt` steps the observation time advanced (the
//! last control repeated), Nav2's warm start; `reset` clears it and re-seeds the noise.

use crate::config::MppiConfig;
use crate::kinematics::Bounds;
use crate::world::{StaticWorld, Walker, walker_clearance_below, walkers_near};
use human2nav_core::{Observation, Plan, PlanError, PlanInfo, Planner, Pose2, Twist2};
use human2nav_plugin::{InitError, PluginInit};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// The planner's name in reports.
pub const NAME: &str = "mppi";

/// The MPPI planner (name `mppi`).
#[derive(Clone, Debug)]
pub struct MppiPlanner {
    config: MppiConfig,
    bounds: Bounds,
    /// Noise standard deviations `[v_x, v_y, ω]`.
    std: [f64; 3],
    radius: f64,
    rng: ChaCha8Rng,
    /// The optimal control sequence `[v_x, v_y, ω]` per step, `time_steps` long.
    controls: Vec<[f64; 3]>,
    /// Observation time of the last call.
    last_time: Option<f64>,
    /// Scratch: the sampled sequences, `batch_size × time_steps`.
    samples: Vec<[f64; 3]>,
    costs: Vec<f64>,
}

/// The scene one call scores against.
struct Scene {
    ego: Pose2,
    velocity: [f64; 3],
    goal: [f64; 2],
    walls: StaticWorld,
    walkers: Vec<Walker>,
    /// Static repulsion is off (near the goal).
    near_goal: bool,
    /// Prefer-forward is off (near the goal).
    forward_off: bool,
}

impl MppiPlanner {
    /// A planner for a robot with `limits` (`None`: the defaults of
    /// [`crate::kinematics::default_limits`]) and footprint radius, the configuration's own
    /// values taking precedence.
    pub fn new(
        config: MppiConfig,
        robot: Option<(&human2nav_core::Limits, f64)>,
    ) -> Result<Self, InitError> {
        config.validate()?;
        let (bounds, radius) =
            config
                .overrides()
                .resolve(config.wz_accel_max, config.radius, robot)?;
        let std = config.noise_std(&bounds);
        Ok(Self {
            std,
            rng: ChaCha8Rng::seed_from_u64(config.seed),
            controls: vec![[0.0; 3]; config.time_steps],
            samples: Vec::new(),
            costs: Vec::new(),
            last_time: None,
            bounds,
            radius,
            config,
        })
    }

    /// The plugin factory: the configuration (unknown keys refused, values checked, errors
    /// naming the key) and, with a robot context, the robot's limits and footprint radius
    /// unless the configuration sets them.
    pub fn from_init(init: &PluginInit<'_>) -> Result<Self, InitError> {
        let config: MppiConfig = init.config()?;
        let robot = init.robot().map(|r| (&r.limits, r.footprint_radius));
        Self::new(config, robot)
    }

    /// The settings.
    pub fn config(&self) -> &MppiConfig {
        &self.config
    }

    /// The motion model and velocity bounds in use.
    pub fn bounds(&self) -> &Bounds {
        &self.bounds
    }

    /// The noise standard deviations `[v_x, v_y, ω]` in use.
    pub fn noise_std(&self) -> [f64; 3] {
        self.std
    }

    /// The robot radius in use (m).
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// The current optimal control sequence.
    pub fn controls(&self) -> &[[f64; 3]] {
        &self.controls
    }

    /// Advances the warm start to `time`: shifts the sequence by the whole `model_dt` steps
    /// elapsed (repeating the last control); a jump back in time or past the horizon starts
    /// from zero controls.
    fn shift_to(&mut self, time: f64) {
        let n = self.controls.len();
        let steps = match self.last_time {
            None => 0,
            Some(t0) => {
                let k = ((time - t0) / self.config.model_dt).round();
                if !(k.is_finite() && k >= 0.0) || k >= n as f64 {
                    self.controls.fill([0.0; 3]);
                    0
                } else {
                    k as usize
                }
            }
        };
        if steps > 0 {
            self.controls.rotate_left(steps);
            let last = self.controls[n - 1 - steps];
            for c in &mut self.controls[n - steps..] {
                *c = last;
            }
        }
        self.last_time = Some(time);
    }

    fn scene(&self, obs: &Observation) -> Scene {
        let c = &self.config;
        let b = &self.bounds;
        let horizon = c.time_steps as f64 * c.model_dt;
        let speed = b.vx_max.max(-b.vx_min).hypot(b.vy_max);
        let ego = [obs.ego.x, obs.ego.y];
        let to_goal = (obs.goal[0] - ego[0]).hypot(obs.goal[1] - ego[1]);
        let influence = self.radius
            + c.inflation_radius
                .max(c.collision_margin_distance)
                .max(c.pedestrian_inflation_radius);
        let reach = speed * horizon + 1.0;
        Scene {
            ego: obs.ego,
            velocity: [
                obs.ego_velocity.vx,
                obs.ego_velocity.vy,
                obs.ego_velocity.omega,
            ],
            goal: obs.goal,
            walls: StaticWorld::new(
                &obs.obstacles,
                obs.occupancy.as_ref(),
                ego,
                reach,
                influence,
            ),
            walkers: walkers_near(obs, speed, horizon, influence),
            near_goal: to_goal < c.near_goal_distance,
            forward_off: to_goal < c.prefer_forward_threshold,
        }
    }

    /// Rolls `controls` out from the scene's state: the poses after each step (not the
    /// current one) and the velocities reached.
    fn rollout(
        &self,
        scene: &Scene,
        controls: &[[f64; 3]],
        mut each: impl FnMut(usize, Pose2, [f64; 3]),
    ) {
        let dt = self.config.model_dt;
        let mut pose = scene.ego;
        let mut v = scene.velocity;
        for (t, u) in controls.iter().enumerate() {
            v = self.bounds.step_velocity(v, *u, dt);
            pose = pose.euler_step(Twist2::new(v[0], v[1], v[2]), dt);
            each(t, pose, v);
        }
    }

    /// The critics' cost of the control sequence `controls` (clipped into the limits) from the
    /// state of `obs`, without the control-cost term, and whether its rollout touches an
    /// obstacle or a pedestrian.
    pub fn evaluate(&self, obs: &Observation, controls: &[[f64; 3]]) -> (f64, bool) {
        let clipped: Vec<[f64; 3]> = controls.iter().map(|u| self.bounds.clip(*u)).collect();
        self.score(&self.scene(obs), &clipped)
    }

    /// The critics' cost of one control sequence (without the control-cost term), and whether
    /// its rollout touches an obstacle or a pedestrian.
    fn score(&self, scene: &Scene, controls: &[[f64; 3]]) -> (f64, bool) {
        let c = &self.config;
        let dt = c.model_dt;
        let (mut goal, mut backward) = (0.0, 0.0);
        let (mut wall_critical, mut wall_repulsive) = (0.0, 0.0);
        let (mut ped_critical, mut ped_repulsive) = (0.0, 0.0);
        let mut collided = false;
        let check_walls = !scene.walls.is_empty();
        // The pedestrian critics act below the larger of their two distances.
        let acts = c
            .collision_margin_distance
            .max(c.pedestrian_inflation_radius);
        self.rollout(scene, controls, |t, pose, v| {
            let p = [pose.x, pose.y];
            goal += (p[0] - scene.goal[0]).hypot(p[1] - scene.goal[1]);
            backward += (-v[0]).max(0.0) * dt;
            if check_walls {
                let d = scene.walls.distance(p) - self.radius;
                if d < 0.0 {
                    collided = true;
                } else if d < c.collision_margin_distance {
                    wall_critical += c.collision_margin_distance - d;
                } else if d < c.inflation_radius && !scene.near_goal {
                    wall_repulsive += c.inflation_radius - d;
                }
            }
            if !scene.walkers.is_empty() {
                let t = (t + 1) as f64 * dt;
                let d = walker_clearance_below(&scene.walkers, p, t, self.radius, acts);
                if d < 0.0 {
                    collided = true;
                } else if d < c.collision_margin_distance {
                    ped_critical += c.collision_margin_distance - d;
                } else if d < c.pedestrian_inflation_radius {
                    ped_repulsive += c.pedestrian_inflation_radius - d;
                }
            }
        });
        let steps = controls.len().max(1) as f64;
        let mut cost = c.goal_weight * goal / steps;
        if !scene.forward_off {
            cost += c.prefer_forward_weight * backward;
        }
        cost += c.critical_weight * wall_critical + c.repulsion_weight * wall_repulsive / steps;
        cost += c.pedestrian_weight
            * (c.critical_weight * ped_critical + c.repulsion_weight * ped_repulsive / steps);
        if collided {
            cost += c.collision_cost;
        }
        (cost, collided)
    }

    /// One sample–score–update round. Returns the smallest sample cost and whether every
    /// sample collides.
    fn iterate(&mut self, scene: &Scene) -> (f64, bool) {
        let c = &self.config;
        let (n, t_len) = (c.batch_size, c.time_steps);
        let std = self.std;
        let inv_var = std.map(|s| if s > 0.0 { 1.0 / (s * s) } else { 0.0 });
        let mut samples = std::mem::take(&mut self.samples);
        let mut costs = std::mem::take(&mut self.costs);
        samples.resize(n * t_len, [0.0; 3]);
        costs.resize(n, 0.0);
        let mut all_collide = true;
        for i in 0..n {
            let seq = &mut samples[i * t_len..(i + 1) * t_len];
            let mut control_cost = 0.0;
            for (t, s) in seq.iter_mut().enumerate() {
                let u = self.controls[t];
                let mut noisy = u;
                if i > 0 {
                    for k in 0..3 {
                        if std[k] > 0.0 {
                            let e: f64 = StandardNormal.sample(&mut self.rng);
                            noisy[k] += std[k] * e;
                        }
                    }
                }
                *s = self.bounds.clip(noisy);
                for k in 0..3 {
                    control_cost += u[k] * (s[k] - u[k]) * inv_var[k];
                }
            }
            let (cost, collided) = self.score(scene, seq);
            all_collide &= collided;
            costs[i] = cost + c.gamma * control_cost;
        }
        let min = costs.iter().copied().fold(f64::INFINITY, f64::min);
        let inv_t = 1.0 / c.temperature;
        let mut total = 0.0;
        for cost in costs.iter_mut() {
            let w = (-(*cost - min) * inv_t).exp();
            *cost = if w.is_finite() { w } else { 0.0 };
            total += *cost;
        }
        if total > 0.0 && total.is_finite() {
            for t in 0..t_len {
                let mut acc = [0.0; 3];
                for i in 0..n {
                    let w = costs[i];
                    if w > 0.0 {
                        let s = samples[i * t_len + t];
                        for k in 0..3 {
                            acc[k] += w * s[k];
                        }
                    }
                }
                self.controls[t] = self.bounds.clip(acc.map(|a| a / total));
            }
        }
        self.samples = samples;
        self.costs = costs;
        (min, all_collide)
    }

    /// The plan of a control sequence: the current pose, then one pose per control.
    fn plan_of(&self, scene: &Scene, obs: &Observation, controls: &[[f64; 3]]) -> Plan {
        let mut poses = Vec::with_capacity(controls.len() + 1);
        poses.push(scene.ego);
        self.rollout(scene, controls, |_, pose, _| poses.push(pose));
        Plan {
            t0: obs.time,
            dt: self.config.model_dt,
            poses,
            info: PlanInfo::default(),
        }
    }

    /// The optimised plan for `obs`, without the finiteness check of [`Planner::plan`].
    fn optimise(&mut self, obs: &Observation) -> Plan {
        self.shift_to(obs.time);
        let scene = self.scene(obs);
        let mut all_collide = false;
        for _ in 0..self.config.iteration_count {
            all_collide = self.iterate(&scene).1;
        }
        if all_collide {
            // Nav2's soft reset: start once more from zero controls.
            self.controls.fill([0.0; 3]);
            for _ in 0..self.config.iteration_count {
                all_collide = self.iterate(&scene).1;
            }
        }
        let controls = self.controls.clone();
        let (_, collides) = self.score(&scene, &controls);
        if all_collide && collides {
            // Every sample touches someone or something: brake along the current heading.
            let brake = vec![[0.0; 3]; controls.len()];
            let mut plan = self.plan_of(&scene, obs, &brake);
            plan.info.fallback = true;
            plan.info.notes.push(
                "mppi: every sampled trajectory collides (also after a reset); braking".into(),
            );
            return plan;
        }
        self.plan_of(&scene, obs, &controls)
    }
}

impl Planner for MppiPlanner {
    fn name(&self) -> &str {
        NAME
    }

    fn reset(&mut self) {
        self.controls.fill([0.0; 3]);
        self.last_time = None;
        self.rng = ChaCha8Rng::seed_from_u64(self.config.seed);
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        obs.validate()?;
        let plan = self.optimise(obs);
        let finite_controls = self.controls.iter().flatten().all(|v| v.is_finite());
        if !plan.is_finite() || !finite_controls {
            self.reset();
            return Err(PlanError::Failed {
                planner: NAME.into(),
                message: "the optimised trajectory is not finite; the warm start was reset".into(),
            });
        }
        Ok(plan)
    }
}
