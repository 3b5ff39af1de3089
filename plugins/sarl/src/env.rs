//! The circle-crossing training environment (CrowdNav `CrowdSim`, `circle_crossing` mode) and
//! SARL's reward.
//!
//! * The robot starts at `(0, −R)` with goal `(0, R)`, `R` = [`EnvConfig::circle_radius`]
//!   (4 m). It is holonomic: an action is a world-frame velocity held for one time step.
//! * Each human starts on the circle at a uniform random angle, with uniform noise of
//!   ±`v_pref/2` added to both coordinates, and walks to the antipodal point; positions (and
//!   goals) closer than the two radii plus the discomfort distance to any earlier agent (or its
//!   goal) are redrawn.
//! * Humans are driven by ORCA (RVO2 semantics, from `human2nav-orca-core`: neighbour distance
//!   10 m, 10 neighbours, time horizon 5 s, radius + 0.01 m, preferred velocity = the goal
//!   vector clipped to unit length). By default the robot is **invisible** to them (CrowdNav's
//!   default, so the robot alone must avoid collisions); [`EnvConfig::robot_visible`] makes
//!   them avoid it too.
//! * An episode ends in a collision (the closest approach of the robot to a human during the
//!   step, both moving linearly, is below the sum of radii), success (the robot ends the step
//!   within its radius of the goal) or timeout (time ≥ [`EnvConfig::time_limit`]).
//!
//! The reward (CrowdNav): `+1` on reaching the goal, `−0.25` on a collision, and otherwise
//! `(d_min − 0.2)·0.5·Δt` when the closest gap `d_min` to a human is below the discomfort
//! distance 0.2 m, else 0. A timeout earns 0.

use crate::state::{HumanState, RobotState};
use human2nav_orca_core::lp::Vec2;
use human2nav_orca_core::orca::{Neighbor, OrcaParams, compute_new_velocity};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::error::SarlError;

/// Settings of the circle-crossing environment and of the reward. Defaults are CrowdNav's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnvConfig {
    /// Radius of the circle the agents start on (m). Default 4.
    pub circle_radius: f64,
    /// Number of humans. Default 5.
    pub human_num: usize,
    /// Human disc radius (m). Default 0.3.
    pub human_radius: f64,
    /// Human preferred (and largest) speed (m/s). Default 1.
    pub human_v_pref: f64,
    /// Robot disc radius (m). Default 0.3.
    pub robot_radius: f64,
    /// Robot preferred speed (m/s); the fastest action. Default 1.
    pub robot_v_pref: f64,
    /// Control and simulation step Δt (s). Default 0.25.
    pub time_step: f64,
    /// Episode time limit (s). Default 25.
    pub time_limit: f64,
    /// Whether the humans' ORCA sees the robot. Default false (CrowdNav's invisible robot).
    pub robot_visible: bool,
    /// Reward on reaching the goal. Default 1.
    pub success_reward: f64,
    /// Reward on a collision. Default −0.25.
    pub collision_penalty: f64,
    /// Gaps below this distance are penalised (m). Default 0.2.
    pub discomfort_dist: f64,
    /// Factor of the discomfort penalty `(d_min − discomfort_dist)·factor·Δt`. Default 0.5.
    pub discomfort_penalty_factor: f64,
}

impl Default for EnvConfig {
    fn default() -> Self {
        Self {
            circle_radius: 4.0,
            human_num: 5,
            human_radius: 0.3,
            human_v_pref: 1.0,
            robot_radius: 0.3,
            robot_v_pref: 1.0,
            time_step: 0.25,
            time_limit: 25.0,
            robot_visible: false,
            success_reward: 1.0,
            collision_penalty: -0.25,
            discomfort_dist: 0.2,
            discomfort_penalty_factor: 0.5,
        }
    }
}

impl EnvConfig {
    /// Checks every field; names the first offending one.
    pub fn validate(&self) -> Result<(), SarlError> {
        let positive = [
            ("env.circle_radius", self.circle_radius),
            ("env.human_radius", self.human_radius),
            ("env.human_v_pref", self.human_v_pref),
            ("env.robot_radius", self.robot_radius),
            ("env.robot_v_pref", self.robot_v_pref),
            ("env.time_step", self.time_step),
            ("env.time_limit", self.time_limit),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(SarlError::config(
                    field,
                    format!("must be finite and > 0, got {v}"),
                ));
            }
        }
        if self.human_num == 0 {
            return Err(SarlError::config("env.human_num", "must be ≥ 1"));
        }
        // Each human starts near the circle at least 2·human_radius + discomfort_dist from
        // every start and goal placed before (goals are the opposite points): past what fits
        // on half the circle, the placement could search forever.
        let spacing = 2.0 * self.human_radius + self.discomfort_dist.max(0.0);
        let fit = (std::f64::consts::PI * self.circle_radius / spacing).floor();
        if self.human_num as f64 > fit {
            return Err(SarlError::config(
                "env.human_num",
                format!(
                    "{} humans do not fit on a circle of radius {} m at {spacing} m spacing (at most {fit})",
                    self.human_num, self.circle_radius
                ),
            ));
        }
        for (field, v) in [
            ("env.success_reward", self.success_reward),
            ("env.collision_penalty", self.collision_penalty),
            ("env.discomfort_dist", self.discomfort_dist),
            (
                "env.discomfort_penalty_factor",
                self.discomfort_penalty_factor,
            ),
        ] {
            if !v.is_finite() {
                return Err(SarlError::config(field, format!("must be finite, got {v}")));
            }
        }
        if self.discomfort_dist < 0.0 {
            return Err(SarlError::config("env.discomfort_dist", "must be ≥ 0"));
        }
        Ok(())
    }

    /// The reward settings alone.
    pub fn reward(&self) -> RewardConfig {
        RewardConfig {
            success_reward: self.success_reward,
            collision_penalty: self.collision_penalty,
            discomfort_dist: self.discomfort_dist,
            discomfort_penalty_factor: self.discomfort_penalty_factor,
        }
    }
}

/// The reward's constants (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RewardConfig {
    pub success_reward: f64,
    pub collision_penalty: f64,
    pub discomfort_dist: f64,
    pub discomfort_penalty_factor: f64,
}

impl Default for RewardConfig {
    fn default() -> Self {
        EnvConfig::default().reward()
    }
}

/// How an episode ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    Success,
    Collision,
    Timeout,
}

/// The reward of being in `robot` with the humans at `humans` after a step of `dt`, judged at
/// the end positions (SARL's look-ahead reward, CrowdNav `MultiHumanRL.compute_reward`).
/// Returns the reward and whether the state is terminal (collision or goal).
pub fn lookahead_reward(
    robot: &RobotState,
    humans: &[HumanState],
    dt: f64,
    r: &RewardConfig,
) -> (f64, bool) {
    let dmin = humans
        .iter()
        .map(|h| (h.px - robot.px).hypot(h.py - robot.py) - h.radius - robot.radius)
        .fold(f64::INFINITY, f64::min);
    step_reward(dmin, robot.goal_distance() < robot.radius, dt, r)
}

/// The reward for a step whose closest gap to a human was `dmin` (negative: collision) and
/// that did or did not end at the goal.
pub fn step_reward(dmin: f64, reached_goal: bool, dt: f64, r: &RewardConfig) -> (f64, bool) {
    if dmin < 0.0 {
        (r.collision_penalty, true)
    } else if reached_goal {
        (r.success_reward, true)
    } else if dmin < r.discomfort_dist {
        (
            (dmin - r.discomfort_dist) * r.discomfort_penalty_factor * dt,
            false,
        )
    } else {
        (0.0, false)
    }
}

/// Smallest distance from the origin to the segment `a → b`.
fn origin_to_segment(a: [f64; 2], b: [f64; 2]) -> f64 {
    let d = [b[0] - a[0], b[1] - a[1]];
    let len2 = d[0] * d[0] + d[1] * d[1];
    let t = if len2 > 0.0 {
        (-(a[0] * d[0] + a[1] * d[1]) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a[0] + t * d[0]).hypot(a[1] + t * d[1])
}

/// The result of one environment step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepResult {
    pub reward: f64,
    /// `Some` when the episode ended with this step.
    pub outcome: Option<Outcome>,
    /// Closest gap between the robot's and any human's disc during the step (m).
    pub dmin: f64,
}

/// A circle-crossing episode in progress.
#[derive(Clone, Debug)]
pub struct CircleCrossing {
    cfg: EnvConfig,
    robot: RobotState,
    humans: Vec<HumanState>,
    human_goals: Vec<[f64; 2]>,
    time: f64,
}

impl CircleCrossing {
    /// A new episode drawn with `rng` (see the module docs for the layout).
    pub fn new<R: Rng>(cfg: &EnvConfig, rng: &mut R) -> Self {
        let r = cfg.circle_radius;
        let robot = RobotState {
            px: 0.0,
            py: -r,
            vx: 0.0,
            vy: 0.0,
            radius: cfg.robot_radius,
            gx: 0.0,
            gy: r,
            v_pref: cfg.robot_v_pref,
            theta: std::f64::consts::FRAC_PI_2,
        };
        // (position, goal, radius) of every placed agent.
        let mut placed: Vec<([f64; 2], [f64; 2], f64)> =
            vec![([robot.px, robot.py], [robot.gx, robot.gy], robot.radius)];
        let mut humans = Vec::with_capacity(cfg.human_num);
        let mut human_goals = Vec::with_capacity(cfg.human_num);
        for _ in 0..cfg.human_num {
            let p = loop {
                let angle = rng.random::<f64>() * 2.0 * std::f64::consts::PI;
                let nx = (rng.random::<f64>() - 0.5) * cfg.human_v_pref;
                let ny = (rng.random::<f64>() - 0.5) * cfg.human_v_pref;
                let p = [r * angle.cos() + nx, r * angle.sin() + ny];
                let clear = placed.iter().all(|(q, g, rad)| {
                    let min = cfg.human_radius + rad + cfg.discomfort_dist;
                    (p[0] - q[0]).hypot(p[1] - q[1]) >= min
                        && (-p[0] - g[0]).hypot(-p[1] - g[1]) >= min
                });
                if clear {
                    break p;
                }
            };
            placed.push((p, [-p[0], -p[1]], cfg.human_radius));
            humans.push(HumanState {
                px: p[0],
                py: p[1],
                vx: 0.0,
                vy: 0.0,
                radius: cfg.human_radius,
            });
            human_goals.push([-p[0], -p[1]]);
        }
        Self {
            cfg: cfg.clone(),
            robot,
            humans,
            human_goals,
            time: 0.0,
        }
    }

    /// The robot's state.
    pub fn robot(&self) -> &RobotState {
        &self.robot
    }

    /// The humans as the robot observes them.
    pub fn humans(&self) -> &[HumanState] {
        &self.humans
    }

    /// Elapsed time (s).
    pub fn time(&self) -> f64 {
        self.time
    }

    /// The settings.
    pub fn config(&self) -> &EnvConfig {
        &self.cfg
    }

    /// ORCA's velocity for an agent at `position` with `velocity`, heading to `goal`, among
    /// `others`, with disc `radius` (ORCA adds 0.01 m, as CrowdNav does) plus `safety_space`.
    pub fn orca_velocity(
        &self,
        position: [f64; 2],
        velocity: [f64; 2],
        goal: [f64; 2],
        radius: f64,
        safety_space: f64,
        max_speed: f64,
        others: &[Neighbor],
    ) -> [f64; 2] {
        let p = Vec2::from_array(position);
        let to_goal = Vec2::from_array(goal) - p;
        let d = to_goal.norm();
        let pref = if d > 1.0 {
            to_goal * (1.0 / d)
        } else {
            to_goal
        };
        let params = OrcaParams {
            neighbor_dist: 10.0,
            max_neighbors: 10,
            time_horizon: 5.0,
            time_step: self.cfg.time_step,
            radius: radius + 0.01 + safety_space,
            max_speed,
        };
        compute_new_velocity(p, Vec2::from_array(velocity), pref, others, &params).to_array()
    }

    fn neighbors(&self, skip_human: Option<usize>, with_robot: bool) -> Vec<Neighbor> {
        let mut out: Vec<Neighbor> = self
            .humans
            .iter()
            .enumerate()
            .filter(|(i, _)| Some(*i) != skip_human)
            .map(|(_, h)| Neighbor {
                position: Vec2::new(h.px, h.py),
                velocity: Vec2::new(h.vx, h.vy),
                radius: h.radius + 0.01,
            })
            .collect();
        if with_robot {
            out.push(Neighbor {
                position: Vec2::new(self.robot.px, self.robot.py),
                velocity: Vec2::new(self.robot.vx, self.robot.vy),
                radius: self.robot.radius + 0.01,
            });
        }
        out
    }

    /// The ORCA velocity of the robot itself (the demonstrator of imitation learning), with
    /// `safety_space` added to its radius; it sees every human.
    pub fn robot_orca_velocity(&self, safety_space: f64) -> [f64; 2] {
        let r = &self.robot;
        self.orca_velocity(
            [r.px, r.py],
            [r.vx, r.vy],
            [r.gx, r.gy],
            r.radius,
            safety_space,
            r.v_pref,
            &self.neighbors(None, false),
        )
    }

    /// Advances one step with the robot moving at velocity `action` (world frame).
    pub fn step(&mut self, action: [f64; 2]) -> StepResult {
        let dt = self.cfg.time_step;
        let human_actions: Vec<[f64; 2]> = (0..self.humans.len())
            .map(|i| {
                let h = &self.humans[i];
                self.orca_velocity(
                    [h.px, h.py],
                    [h.vx, h.vy],
                    self.human_goals[i],
                    h.radius,
                    0.0,
                    self.cfg.human_v_pref,
                    &self.neighbors(Some(i), self.cfg.robot_visible),
                )
            })
            .collect();
        // Closest approach during the step: human relative to robot, both moving linearly.
        let mut dmin = f64::INFINITY;
        for (h, a) in self.humans.iter().zip(&human_actions) {
            let start = [h.px - self.robot.px, h.py - self.robot.py];
            let end = [
                start[0] + (a[0] - action[0]) * dt,
                start[1] + (a[1] - action[1]) * dt,
            ];
            dmin = dmin.min(origin_to_segment(start, end) - h.radius - self.robot.radius);
        }
        let next_robot = self.robot.propagate(action, dt);
        let reached = next_robot.goal_distance() < next_robot.radius;
        self.time += dt;
        let (mut reward, terminal) = step_reward(dmin, reached, dt, &self.cfg.reward());
        let outcome = if self.time >= self.cfg.time_limit - 1e-9 && !terminal {
            reward = 0.0;
            Some(Outcome::Timeout)
        } else if terminal {
            Some(if dmin < 0.0 {
                Outcome::Collision
            } else {
                Outcome::Success
            })
        } else {
            None
        };
        self.robot = next_robot;
        for (h, a) in self.humans.iter_mut().zip(&human_actions) {
            h.px += a[0] * dt;
            h.py += a[1] * dt;
            h.vx = a[0];
            h.vy = a[1];
        }
        StepResult {
            reward,
            outcome,
            dmin,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn segment_distance_closed_forms() {
        // The segment (−1, 1) → (1, 1) passes 1 m from the origin at its midpoint.
        assert_relative_eq!(
            origin_to_segment([-1.0, 1.0], [1.0, 1.0]),
            1.0,
            epsilon = 1e-12
        );
        // The segment (3, 4) → (6, 8) is closest at its start: 5 m.
        assert_relative_eq!(
            origin_to_segment([3.0, 4.0], [6.0, 8.0]),
            5.0,
            epsilon = 1e-12
        );
        assert_relative_eq!(
            origin_to_segment([3.0, 4.0], [3.0, 4.0]),
            5.0,
            epsilon = 1e-12
        );
    }

    #[test]
    fn reward_cases() {
        let r = RewardConfig::default();
        assert_eq!(step_reward(-0.01, true, 0.25, &r), (-0.25, true));
        assert_eq!(step_reward(0.5, true, 0.25, &r), (1.0, true));
        let (rew, done) = step_reward(0.1, false, 0.25, &r);
        assert_relative_eq!(rew, (0.1 - 0.2) * 0.5 * 0.25, epsilon = 1e-15);
        assert!(!done);
        assert_eq!(step_reward(0.3, false, 0.25, &r), (0.0, false));
    }

    #[test]
    fn layout_is_clear_and_symmetric() {
        let cfg = EnvConfig::default();
        for seed in 0..20 {
            let env = CircleCrossing::new(&cfg, &mut ChaCha8Rng::seed_from_u64(seed));
            assert_eq!(env.humans().len(), 5);
            for (i, h) in env.humans().iter().enumerate() {
                assert_eq!(env.human_goals[i], [-h.px, -h.py]);
                let d = (h.px - env.robot().px).hypot(h.py - env.robot().py);
                assert!(d >= 0.3 + 0.3 + 0.2, "human {i} too close: {d}");
            }
        }
    }

    #[test]
    fn an_empty_path_reaches_the_goal_in_time() {
        // No human in the way (one human far off the robot's line): drive straight at 1 m/s.
        let cfg = EnvConfig {
            human_num: 1,
            ..EnvConfig::default()
        };
        let mut env = CircleCrossing::new(&cfg, &mut ChaCha8Rng::seed_from_u64(3));
        env.humans[0] = HumanState {
            px: 100.0,
            py: 0.0,
            vx: 0.0,
            vy: 0.0,
            radius: 0.3,
        };
        env.human_goals[0] = [100.0, 0.0];
        let mut steps = 0;
        let outcome = loop {
            steps += 1;
            let s = env.step([0.0, 1.0]);
            if let Some(o) = s.outcome {
                assert_eq!(s.reward, if o == Outcome::Success { 1.0 } else { 0.0 });
                break o;
            }
        };
        assert_eq!(outcome, Outcome::Success);
        // 8 m at 1 m/s, success within 0.3 m: after 7.75 s = 31 steps.
        assert_eq!(steps, 31);
    }
}
