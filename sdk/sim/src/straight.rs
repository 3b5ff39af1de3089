//! `straight`: a sanity baseline that drives straight at the goal, ignoring everybody.
//!
//! The plan starts at the current pose; the following poses lie on the segment to the goal with
//! heading along it, at a speed that ramps (exactly, `s = v0·t + a·t²/2`) from the robot's current
//! forward speed to `speed` at `accel`, and stops at the goal. It reaches every goal of an empty world and collides whenever
//! somebody is in the way, which is exactly what an empty-world sanity suite and a lower bound
//! need.

use crate::error::SimError;
use human2nav_core::{Observation, Plan, PlanError, PlanInfo, Planner, Pose2};
use serde::{Deserialize, Serialize};

/// Settings of the straight-line planner.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StraightConfig {
    /// Cruise speed (m/s). Default 1.0; the benchmark sets the robot's `v_max`.
    pub speed: f64,
    /// Acceleration of the speed ramp (m/s²). Default 1.0; the benchmark sets 80 % of the
    /// robot's `a_max` (see [`crate::bench::STRAIGHT_ACCEL_SHARE`]).
    pub accel: f64,
    /// Spacing of the plan's poses (s). Default 0.1.
    pub plan_dt: f64,
    /// Number of poses including `poses[0]` (2 to [`MAX_HORIZON`]). Default 32.
    pub horizon: usize,
}

/// Largest `horizon` of the straight-line planner: every planning call allocates the plan.
pub const MAX_HORIZON: usize = 10_000;

impl Default for StraightConfig {
    fn default() -> Self {
        Self {
            speed: 1.0,
            accel: 1.0,
            plan_dt: 0.1,
            horizon: 32,
        }
    }
}

impl StraightConfig {
    /// Checks every field; the error names the offending one.
    pub fn validate(&self) -> Result<(), SimError> {
        for (field, v) in [
            ("speed", self.speed),
            ("accel", self.accel),
            ("plan_dt", self.plan_dt),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SimError::setting(
                    "straight",
                    field,
                    format!("must be finite and > 0, got {v}"),
                ));
            }
        }
        if !(2..=MAX_HORIZON).contains(&self.horizon) {
            return Err(SimError::setting(
                "straight",
                "horizon",
                format!("must be in 2..={MAX_HORIZON}, got {}", self.horizon),
            ));
        }
        Ok(())
    }
}

/// The straight-line planner (name `straight`).
#[derive(Clone, Debug)]
pub struct StraightPlanner {
    cfg: StraightConfig,
}

impl StraightPlanner {
    /// A straight-line planner with `cfg`, checked first.
    pub fn new(cfg: StraightConfig) -> Result<Self, SimError> {
        cfg.validate()?;
        Ok(Self { cfg })
    }
}

impl Planner for StraightPlanner {
    fn name(&self) -> &str {
        "straight"
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        obs.validate()?;
        let c = &self.cfg;
        let (dx, dy) = (obs.goal[0] - obs.ego.x, obs.goal[1] - obs.ego.y);
        let dist = dx.hypot(dy);
        let (ux, uy, heading) = if dist > 1e-9 {
            (dx / dist, dy / dist, dy.atan2(dx))
        } else {
            (0.0, 0.0, obs.ego.theta)
        };
        let mut poses = Vec::with_capacity(c.horizon);
        poses.push(obs.ego);
        // Exact arc length of the ramp: s(t) = v0·t + a·t²/2 until the cruise speed is reached
        // (at t_c = (speed − v0)/a), then cruise; never past the goal.
        let v0 = obs.ego_velocity.vx.clamp(0.0, c.speed);
        let t_c = (c.speed - v0) / c.accel;
        let arc = |t: f64| {
            if t <= t_c {
                v0 * t + 0.5 * c.accel * t * t
            } else {
                v0 * t_c + 0.5 * c.accel * t_c * t_c + c.speed * (t - t_c)
            }
        };
        for k in 1..c.horizon {
            let s = arc(k as f64 * c.plan_dt).min(dist);
            poses.push(Pose2::new(obs.ego.x + s * ux, obs.ego.y + s * uy, heading));
        }
        Ok(Plan {
            t0: obs.time,
            dt: c.plan_dt,
            poses,
            info: PlanInfo::default(),
        })
    }
}
