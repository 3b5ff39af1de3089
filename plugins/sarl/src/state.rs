//! SARL's states and the rotation into the robot-centric frame (CrowdNav `MultiHumanRL.rotate`).
//!
//! The robot-centric frame has its origin at the robot, its x axis pointing at the goal and its
//! y axis 90° counter-clockwise from it. Each human contributes one *joint state* of
//! [`JOINT_DIM`] = 13 numbers, in CrowdNav's order:
//!
//! | index | name | meaning |
//! |---|---|---|
//! | 0 | `dg` | distance robot → goal (m) |
//! | 1 | `v_pref` | robot's preferred speed (m/s) |
//! | 2 | `theta` | robot heading relative to the goal direction (rad; 0 for a holonomic robot) |
//! | 3 | `radius` | robot radius (m) |
//! | 4, 5 | `vx`, `vy` | robot velocity in the rotated frame (m/s) |
//! | 6, 7 | `px1`, `py1` | human position relative to the robot, rotated (m) |
//! | 8, 9 | `vx1`, `vy1` | human velocity, rotated (m/s) |
//! | 10 | `radius1` | human radius (m) |
//! | 11 | `da` | distance robot ↔ human centres (m) |
//! | 12 | `radius_sum` | robot radius + human radius (m) |
//!
//! The first [`SELF_DIM`] = 6 numbers are the robot's own state (the same in every row).

/// Numbers per joint (robot, human) state.
pub const JOINT_DIM: usize = 13;
/// Numbers of the robot's own part of a joint state (its first entries).
pub const SELF_DIM: usize = 6;

/// The robot's full state (world frame, SI).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotState {
    pub px: f64,
    pub py: f64,
    pub vx: f64,
    pub vy: f64,
    pub radius: f64,
    pub gx: f64,
    pub gy: f64,
    pub v_pref: f64,
    /// Heading (rad). Ignored for the holonomic robot SARL is trained as.
    pub theta: f64,
}

/// What the robot observes of a human (world frame, SI).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HumanState {
    pub px: f64,
    pub py: f64,
    pub vx: f64,
    pub vy: f64,
    pub radius: f64,
}

impl RobotState {
    /// Distance from the robot's centre to its goal.
    pub fn goal_distance(&self) -> f64 {
        (self.gx - self.px).hypot(self.gy - self.py)
    }

    /// The state after moving with velocity `v` for `dt` (holonomic: the velocity becomes `v`).
    pub fn propagate(&self, v: [f64; 2], dt: f64) -> RobotState {
        RobotState {
            px: self.px + v[0] * dt,
            py: self.py + v[1] * dt,
            vx: v[0],
            vy: v[1],
            ..*self
        }
    }
}

impl HumanState {
    /// The state after `dt` at constant velocity (SARL's look-ahead model of a human).
    pub fn propagate(&self, dt: f64) -> HumanState {
        HumanState {
            px: self.px + self.vx * dt,
            py: self.py + self.vy * dt,
            ..*self
        }
    }
}

/// The joint state of `robot` and `human` in the robot-centric frame (see the module docs).
/// `holonomic` zeroes the relative heading, as CrowdNav does for holonomic robots.
pub fn rotate(robot: &RobotState, human: &HumanState, holonomic: bool) -> [f32; JOINT_DIM] {
    let dx = robot.gx - robot.px;
    let dy = robot.gy - robot.py;
    let rot = dy.atan2(dx);
    let (s, c) = rot.sin_cos();
    let dg = dx.hypot(dy);
    let vx = robot.vx * c + robot.vy * s;
    let vy = robot.vy * c - robot.vx * s;
    let theta = if holonomic { 0.0 } else { robot.theta - rot };
    let vx1 = human.vx * c + human.vy * s;
    let vy1 = human.vy * c - human.vx * s;
    let rx = human.px - robot.px;
    let ry = human.py - robot.py;
    let px1 = rx * c + ry * s;
    let py1 = ry * c - rx * s;
    let da = rx.hypot(ry);
    [
        dg,
        robot.v_pref,
        theta,
        robot.radius,
        vx,
        vy,
        px1,
        py1,
        vx1,
        vy1,
        human.radius,
        da,
        robot.radius + human.radius,
    ]
    .map(|v| v as f32)
}

/// Appends the joint states of `robot` with every human (one row each) to `out`.
pub fn push_joint_states(
    robot: &RobotState,
    humans: &[HumanState],
    holonomic: bool,
    out: &mut Vec<f32>,
) {
    for h in humans {
        out.extend_from_slice(&rotate(robot, h, holonomic));
    }
}
