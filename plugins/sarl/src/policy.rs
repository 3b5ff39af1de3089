//! SARL's one-step look-ahead action selection (CrowdNav `MultiHumanRL.predict`).
//!
//! For every action `a` of the [`ActionSpace`]: the robot is propagated by `Δt` with velocity
//! `a`, every human by `Δt` at its observed (constant) velocity; the action's value is
//! `R(s, a) + γ^{Δt·v_pref} · V(s')` with `R` the look-ahead reward
//! ([`lookahead_reward`]) and `V` the value network on the propagated joint states. All
//! actions are evaluated in one batched forward pass; the argmax wins (the first on ties).
//!
//! With no human at all the network has nothing to attend to (it was trained with five), and
//! the value of a state is known in closed form instead: the discounted success reward after
//! the time the robot needs to cover the remaining distance at `v_pref`,
//! `V₀(s) = γ̄^{max(0, d_g − r)/(Δt·v_pref)}·R_goal` ([`empty_world_value`]). [`select_action`]
//! then uses `V₀` in place of the network, which picks the action that closes on the goal
//! fastest. Because `V₀` depends on the goal distance alone, the maximiser of `R + γ̄·V₀` over
//! *all* velocities `|v| ≤ v_pref` is also known: straight at the goal at
//! `min(v_pref, d_g/Δt)` ([`empty_world_velocity`]); the planner uses it, so a robot alone is
//! not steered along the nearest of 16 headings (a car-like robot would circle a goal it
//! cannot turn into).

use crate::action::ActionSpace;
use crate::env::{RewardConfig, lookahead_reward};
use crate::error::SarlError;
use crate::net::SarlNet;
use crate::state::{HumanState, JOINT_DIM, RobotState, push_joint_states};

/// The look-ahead's constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LookAhead {
    /// Discount per unit of `Δt·v_pref` (CrowdNav 0.9).
    pub gamma: f64,
    /// Look-ahead step Δt (s).
    pub time_step: f64,
    /// The reward's constants.
    pub reward: RewardConfig,
}

impl LookAhead {
    /// The discount of one step, `γ^{Δt·v_pref}`.
    pub fn gamma_bar(&self, v_pref: f64) -> f64 {
        self.gamma.powf(self.time_step * v_pref)
    }
}

/// What [`select_action`] decided.
#[derive(Clone, Debug, PartialEq)]
pub struct Decision {
    /// Index into the action space.
    pub index: usize,
    /// The chosen velocity (world frame, m/s).
    pub velocity: [f64; 2],
    /// `R + γ̄·V` of every action.
    pub action_values: Vec<f64>,
}

/// The closed-form value of a state without humans (see the module docs).
pub fn empty_world_value(robot: &RobotState, la: &LookAhead) -> f64 {
    let steps = (robot.goal_distance() - robot.radius).max(0.0) / (la.time_step * robot.v_pref);
    la.gamma_bar(robot.v_pref).powf(steps) * la.reward.success_reward
}

/// The best velocity of any magnitude up to `v_pref` without humans (see the module docs).
pub fn empty_world_velocity(robot: &RobotState, la: &LookAhead) -> [f64; 2] {
    let dx = robot.gx - robot.px;
    let dy = robot.gy - robot.py;
    let d = dx.hypot(dy);
    if d <= 0.0 {
        return [0.0, 0.0];
    }
    let speed = robot.v_pref.min(d / la.time_step);
    [dx / d * speed, dy / d * speed]
}

/// The value of every action and the best one (see the module docs; with no humans the
/// closed-form empty-world value replaces the network).
pub fn select_action(
    net: &SarlNet,
    actions: &ActionSpace,
    robot: &RobotState,
    humans: &[HumanState],
    la: &LookAhead,
) -> Result<Decision, SarlError> {
    let dt = la.time_step;
    let next_humans: Vec<HumanState> = humans.iter().map(|h| h.propagate(dt)).collect();
    let n = humans.len();
    let mut flat = Vec::with_capacity(actions.len() * n * JOINT_DIM);
    let mut rewards = Vec::with_capacity(actions.len());
    for &a in &actions.actions {
        let next = robot.propagate(a, dt);
        rewards.push(lookahead_reward(&next, &next_humans, dt, &la.reward).0);
        push_joint_states(&next, &next_humans, true, &mut flat);
    }
    let values: Vec<f32> = if n == 0 {
        actions
            .actions
            .iter()
            .map(|&a| empty_world_value(&robot.propagate(a, dt), la) as f32)
            .collect()
    } else {
        net.values(&flat, actions.len(), n)?
    };
    let g = la.gamma_bar(robot.v_pref);
    let action_values: Vec<f64> = rewards
        .iter()
        .zip(&values)
        .map(|(r, v)| r + g * f64::from(*v))
        .collect();
    let mut index = 0;
    for (i, v) in action_values.iter().enumerate() {
        if *v > action_values[index] {
            index = i;
        }
    }
    Ok(Decision {
        index,
        velocity: actions.actions[index],
        action_values,
    })
}
