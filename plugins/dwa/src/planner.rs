//! The dynamic window approach (Fox, Burgard & Thrun, 1997).
//!
//! Each call:
//!
//! 1. the dynamic window: the velocities `(v_x, ω)` (and `v_y` on an omnidirectional base)
//!    reachable from the current one within one `control_period` at the robot's acceleration
//!    limits, inside its speed limits, sampled on a grid (`ω = 0` added when the window holds
//!    it); an Ackermann base keeps `|ω| ≤ κ_max·|v_x|`;
//! 2. each sample is rolled out at constant velocity for `sim_time`, poses `plan_dt` apart;
//! 3. `dist`: the path length driven before the robot's disc, grown by `safety_margin`, first
//!    closes in on a pedestrian (walking on at constant velocity) or a static obstacle;
//!    `clearance_max` when that does not happen within `sim_time`. A sample is admissible when
//!    its rollout never overlaps anything it is not already overlapping and the robot can
//!    brake before that point: `|v| ≤ √(2·dist·a_max)`;
//! 4. the admissible sample maximising
//!    `G = heading_weight·heading + clearance_weight·dist/clearance_max +
//!    velocity_weight·v_x/vx_max` wins, `heading = 1 − |bearing of the goal|/π` from the pose
//!    Fox et al. predict: one `control_period` at the sample's velocity, then braking at
//!    `a_max` (measured at the end of the whole rollout instead, a sample that would pass the
//!    goal within `sim_time` scores as facing away, and the robot stops short of the goal).
//!    The plan is its rollout. Without an admissible sample the plan brakes at `a_max` along
//!    the current heading (marked as a fallback).

use crate::config::DwaConfig;
use crate::kinematics::{Bounds, MotionModel};
use crate::world::{StaticWorld, Walker, walker_clearance, walkers_near};
use human2nav_core::se2::wrap_angle;
use human2nav_core::{Limits, Observation, Plan, PlanError, PlanInfo, Planner, Pose2, Twist2};
use human2nav_plugin::{InitError, PluginInit};
use std::f64::consts::PI;

/// The planner's name in reports.
pub const NAME: &str = "dwa";

/// The DWA planner (name `dwa`).
#[derive(Clone, Debug)]
pub struct DwaPlanner {
    config: DwaConfig,
    bounds: Bounds,
    radius: f64,
}

/// One scored sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// The body velocity `[v_x, v_y, ω]` held over the rollout.
    pub velocity: [f64; 3],
    /// Heading term in `[0, 1]`.
    pub heading: f64,
    /// Path length before closing in on something (m), at most `clearance_max`.
    pub dist: f64,
    /// True when the sample may be chosen.
    pub admissible: bool,
    /// The objective `G`.
    pub score: f64,
}

struct Scene {
    ego: Pose2,
    goal: [f64; 2],
    walls: StaticWorld,
    walkers: Vec<Walker>,
}

/// `n` values evenly spread over `[lo, hi]` (one when they are equal or `n` is 1).
fn grid(lo: f64, hi: f64, n: usize) -> impl Iterator<Item = f64> {
    let n = if hi > lo { n.max(1) } else { 1 };
    (0..n).map(move |i| {
        if n == 1 {
            0.5 * (lo + hi)
        } else {
            lo + (hi - lo) * i as f64 / (n - 1) as f64
        }
    })
}

/// The window `[x − r, x + r] ∩ [lo, hi]`; when they do not meet, the reachable value
/// nearest to the limits.
fn window(x: f64, r: f64, lo: f64, hi: f64) -> (f64, f64) {
    let (a, b) = (lo.max(x - r), hi.min(x + r));
    if a <= b {
        (a, b)
    } else if x + r < lo {
        (x + r, x + r)
    } else {
        (x - r, x - r)
    }
}

impl DwaPlanner {
    /// A planner for a robot with `limits` and footprint radius (`None`: Nav2's MPPI defaults
    /// of the shared kinematics module), the configuration's own values taking precedence.
    pub fn new(config: DwaConfig, robot: Option<(&Limits, f64)>) -> Result<Self, InitError> {
        config.validate()?;
        let (bounds, radius) =
            config
                .overrides()
                .resolve(config.wz_accel_max, config.radius, robot)?;
        Ok(Self {
            config,
            bounds,
            radius,
        })
    }

    /// The plugin factory: the configuration (unknown keys refused, values checked, errors
    /// naming the key) and, with a robot context, the robot's limits and footprint radius
    /// unless the configuration sets them.
    pub fn from_init(init: &PluginInit<'_>) -> Result<Self, InitError> {
        let config: DwaConfig = init.config()?;
        let robot = init.robot().map(|r| (&r.limits, r.footprint_radius));
        Self::new(config, robot)
    }

    /// The settings.
    pub fn config(&self) -> &DwaConfig {
        &self.config
    }

    /// The motion model and velocity bounds in use.
    pub fn bounds(&self) -> &Bounds {
        &self.bounds
    }

    /// The robot radius in use (m).
    pub fn radius(&self) -> f64 {
        self.radius
    }

    fn steps(&self) -> usize {
        ((self.config.sim_time / self.config.plan_dt).ceil() as usize).max(1)
    }

    fn scene(&self, obs: &Observation) -> Scene {
        let b = &self.bounds;
        let speed = b.vx_max.max(-b.vx_min).hypot(b.vy_max);
        let horizon = self.steps() as f64 * self.config.plan_dt;
        let influence = self.radius + self.config.safety_margin;
        let ego = [obs.ego.x, obs.ego.y];
        Scene {
            ego: obs.ego,
            goal: obs.goal,
            walls: StaticWorld::new(
                &obs.obstacles,
                obs.occupancy.as_ref(),
                ego,
                speed * horizon + 1.0,
                influence,
            ),
            walkers: walkers_near(obs, speed, horizon, influence),
        }
    }

    /// The sampled velocities of the dynamic window around the body velocity `v`.
    pub fn window_samples(&self, v: Twist2) -> Vec<[f64; 3]> {
        let c = &self.config;
        let b = &self.bounds;
        let dv = b.ax_max * c.control_period;
        let (vx_lo, vx_hi) = window(v.vx, dv, b.vx_min.max(c.min_vel_x), b.vx_max);
        let (vy_lo, vy_hi) = if b.model == MotionModel::Omni {
            window(v.vy, dv, -b.vy_max, b.vy_max)
        } else {
            (0.0, 0.0)
        };
        let dw = b
            .wz_accel_max
            .map_or(f64::INFINITY, |a| a * c.control_period);
        let mut out = Vec::new();
        for vx in grid(vx_lo, vx_hi, c.vx_samples) {
            let wz_bound = match b.model {
                MotionModel::Ackermann { kappa_max } => b.wz_max.min(kappa_max * vx.abs()),
                _ => b.wz_max,
            };
            let (w_lo, w_hi) = window(v.omega, dw, -wz_bound, wz_bound);
            let vy_n = if b.model == MotionModel::Omni {
                c.vy_samples
            } else {
                1
            };
            for vy in grid(vy_lo, vy_hi, vy_n) {
                // The embodiments bound the change of (v_x, v_y) as a vector.
                if (vx - v.vx).hypot(vy - v.vy) > dv * (1.0 + 1e-9) + 1e-12 && vy != 0.0 {
                    continue;
                }
                let mut omegas: Vec<f64> = grid(w_lo, w_hi, c.vtheta_samples).collect();
                if w_lo < 0.0 && w_hi > 0.0 {
                    omegas.push(0.0);
                }
                for wz in omegas {
                    out.push(b.clip([vx, vy, wz]));
                }
            }
        }
        out
    }

    /// The constant-velocity rollout of `u` from `from`: the poses after each step.
    fn rollout(&self, from: Pose2, u: [f64; 3]) -> impl Iterator<Item = (usize, Pose2)> + '_ {
        let dt = self.config.plan_dt;
        let twist = Twist2::new(u[0], u[1], u[2]);
        (1..=self.steps()).scan(from, move |pose, k| {
            *pose = pose.euler_step(twist, dt);
            Some((k, *pose))
        })
    }

    fn clearance(&self, scene: &Scene, p: [f64; 2], t: f64) -> f64 {
        let walls = scene.walls.distance(p) - self.radius;
        walls.min(walker_clearance(&scene.walkers, p, t, self.radius))
    }

    /// Where Fox et al. measure the heading: the pose reached by driving `u` for one control
    /// period and then braking at `a_max` along the same arc. Braking from speed `s` covers the
    /// arc of driving `u` for `s / (2·a_max)`, so the pose is `u` held for
    /// `control_period + s / (2·a_max)`.
    fn predicted_pose(&self, from: Pose2, u: [f64; 3], speed: f64) -> Pose2 {
        let t = self.config.control_period + speed / (2.0 * self.bounds.ax_max);
        from.euler_step(Twist2::new(u[0], u[1], u[2]), t)
    }

    fn evaluate(&self, scene: &Scene, u: [f64; 3]) -> Candidate {
        let c = &self.config;
        let start = self.clearance(scene, [scene.ego.x, scene.ego.y], 0.0);
        let step_len = u[0].hypot(u[1]) * c.plan_dt;
        let mut contact: Option<f64> = None;
        let mut overlaps = false;
        for (k, pose) in self.rollout(scene.ego, u) {
            let d = self.clearance(scene, [pose.x, pose.y], k as f64 * c.plan_dt);
            // Only getting closer counts: a robot already inside the margin may leave it.
            let closing = d < start - 1e-9;
            if closing && d < c.safety_margin && contact.is_none() {
                contact = Some(k as f64 * step_len);
            }
            overlaps |= closing && d < 0.0;
        }
        let dist = contact.map_or(c.clearance_max, |s| s.min(c.clearance_max));
        let speed = u[0].hypot(u[1]);
        let at = self.predicted_pose(scene.ego, u, speed);
        let bearing = (scene.goal[1] - at.y).atan2(scene.goal[0] - at.x);
        let heading = 1.0 - wrap_angle(bearing - at.theta).abs() / PI;
        let brakes_in_time = contact.is_none() || speed <= (2.0 * dist * self.bounds.ax_max).sqrt();
        let velocity = (u[0] / self.bounds.vx_max).max(0.0);
        let score = c.heading_weight * heading
            + c.clearance_weight * dist / c.clearance_max
            + c.velocity_weight * velocity;
        Candidate {
            velocity: u,
            heading,
            dist,
            admissible: !overlaps && brakes_in_time,
            score,
        }
    }

    /// Every sample of the window for `obs`, scored.
    pub fn candidates(&self, obs: &Observation) -> Vec<Candidate> {
        let scene = self.scene(obs);
        self.window_samples(obs.ego_velocity)
            .into_iter()
            .map(|u| self.evaluate(&scene, u))
            .collect()
    }

    fn plan_of(&self, obs: &Observation, u: [f64; 3]) -> Plan {
        let mut poses = Vec::with_capacity(self.steps() + 1);
        poses.push(obs.ego);
        poses.extend(self.rollout(obs.ego, u).map(|(_, p)| p));
        Plan {
            t0: obs.time,
            dt: self.config.plan_dt,
            poses,
            info: PlanInfo::default(),
        }
    }

    /// Braking at `a_max` from the current velocity along the current heading.
    fn brake(&self, obs: &Observation) -> Plan {
        let dt = self.config.plan_dt;
        let mut v = [
            obs.ego_velocity.vx,
            obs.ego_velocity.vy,
            obs.ego_velocity.omega,
        ];
        let mut pose = obs.ego;
        let mut poses = vec![pose];
        for _ in 0..self.steps() {
            v = self.bounds.step_velocity(v, [0.0, 0.0, 0.0], dt);
            pose = pose.euler_step(Twist2::new(v[0], v[1], v[2]), dt);
            poses.push(pose);
        }
        let mut plan = Plan {
            t0: obs.time,
            dt,
            poses,
            info: PlanInfo::default(),
        };
        plan.info.fallback = true;
        plan.info
            .notes
            .push("dwa: no admissible velocity in the dynamic window; braking".into());
        plan
    }
}

impl Planner for DwaPlanner {
    fn name(&self) -> &str {
        NAME
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        obs.validate()?;
        let best = self
            .candidates(obs)
            .into_iter()
            .filter(|c| c.admissible && c.score.is_finite())
            .fold(None::<Candidate>, |best, c| match best {
                Some(b) if b.score >= c.score => Some(b),
                _ => Some(c),
            });
        let plan = match best {
            Some(c) => self.plan_of(obs, c.velocity),
            None => self.brake(obs),
        };
        if !plan.is_finite() {
            return Err(PlanError::Failed {
                planner: NAME.into(),
                message: "the chosen trajectory is not finite".into(),
            });
        }
        Ok(plan)
    }
}
