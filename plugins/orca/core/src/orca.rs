//! One ORCA step for one agent, with the semantics of the RVO2 library (`Agent::computeNeighbors`
//! and `Agent::computeNewVelocity`; the static obstacles' lines are in [`crate::obstacle`]).
//!
//! For each neighbour `B` of agent `A` the velocity obstacle `VO^τ_{A|B}` is the truncated cone
//! of relative velocities that lead to a collision within the time horizon `τ`. With
//! `u` the smallest change of the current relative velocity that leaves the cone, the ORCA
//! half-plane is `{v : (v − (v_A + ½u))·n ≥ 0}` with `n` the outward normal at the closest
//! boundary point: each agent takes half of the responsibility for avoiding the collision.
//! When the agents already overlap, the cone is replaced by the cut-off disc of the simulation
//! time step so that they separate within one step. The new velocity is the one closest to the
//! preferred velocity inside every half-plane and the `max_speed` disc ([`crate::lp::solve`]).

use crate::lp::{self, Line, Vec2};

/// Another agent as ORCA sees it: position and velocity in the world frame, and its radius.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbor {
    pub position: Vec2,
    pub velocity: Vec2,
    pub radius: f64,
}

/// The parameters of one ORCA agent (RVO2's per-agent settings plus the simulation time step).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrcaParams {
    /// Neighbours further than this (centre to centre, m) are ignored.
    pub neighbor_dist: f64,
    /// At most this many (the closest) neighbours are considered.
    pub max_neighbors: usize,
    /// Time horizon `τ` of the velocity obstacles (s).
    pub time_horizon: f64,
    /// Time step used for the cut-off disc when agents already overlap (s).
    pub time_step: f64,
    /// The agent's own radius (m).
    pub radius: f64,
    /// The largest speed the agent may choose (m/s).
    pub max_speed: f64,
}

/// The indices of the neighbours RVO2 would consider: closer than `neighbor_dist` (strictly),
/// the `max_neighbors` closest, ordered by increasing distance (ties keep input order).
pub fn select_neighbors(
    position: Vec2,
    others: &[Neighbor],
    neighbor_dist: f64,
    max_neighbors: usize,
) -> Vec<usize> {
    let range_sq = neighbor_dist * neighbor_dist;
    let mut found: Vec<(f64, usize)> = others
        .iter()
        .enumerate()
        .map(|(i, o)| ((o.position - position).norm_sq(), i))
        .filter(|(d, _)| *d < range_sq)
        .collect();
    found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    found.truncate(max_neighbors);
    found.into_iter().map(|(_, i)| i).collect()
}

/// The ORCA half-plane that agent (`position`, `velocity`, `radius`) gets from `other`.
///
/// `time_horizon` is `τ`, `time_step` the cut-off used when the two discs already overlap.
pub fn orca_line(
    position: Vec2,
    velocity: Vec2,
    radius: f64,
    other: &Neighbor,
    time_horizon: f64,
    time_step: f64,
) -> Line {
    orca_line_inv(
        position,
        velocity,
        radius,
        other,
        1.0 / time_horizon,
        1.0 / time_step,
    )
}

/// [`orca_line`] given `1/time_horizon` and `1/time_step` (the same divisions, done once per
/// agent by callers that build many lines).
#[inline]
pub(crate) fn orca_line_inv(
    position: Vec2,
    velocity: Vec2,
    radius: f64,
    other: &Neighbor,
    inv_tau: f64,
    inv_dt: f64,
) -> Line {
    let rel_pos = other.position - position;
    let rel_vel = velocity - other.velocity;
    let dist_sq = rel_pos.norm_sq();
    let r = radius + other.radius;
    let r_sq = r * r;

    let (direction, u) = if dist_sq > r_sq {
        // No collision yet. `w` runs from the cut-off centre rel_pos/τ to the relative velocity.
        let w = rel_vel - rel_pos * inv_tau;
        let w_len_sq = w.norm_sq();
        let dot1 = w.dot(rel_pos);
        if dot1 < 0.0 && dot1 * dot1 > r_sq * w_len_sq {
            // Closest boundary point is on the cut-off circle.
            let w_len = w_len_sq.sqrt();
            let unit_w = w * (1.0 / w_len);
            (
                Vec2::new(unit_w.y, -unit_w.x),
                unit_w * (r * inv_tau - w_len),
            )
        } else {
            // Closest boundary point is on one of the legs of the cone: the left one when
            // `w` lies left of `rel_pos`, else the right one (also the tie when `w` points
            // straight at the other agent). The right leg is the left one's formula with
            // `−leg` for `leg`; choosing that sign by arithmetic instead of a branch gives the
            // same bits (IEEE rounding is symmetric in sign) without a mispredicted jump on
            // what is a coin flip in a crowd.
            let leg = (dist_sq - r_sq).sqrt();
            let sleg = if rel_pos.det(w) > 0.0 { leg } else { -leg };
            let direction = Vec2::new(
                rel_pos.x * sleg - rel_pos.y * r,
                rel_pos.x * r + rel_pos.y * sleg,
            ) * (1.0 / dist_sq);
            let dot2 = rel_vel.dot(direction);
            (direction, direction * dot2 - rel_vel)
        }
    } else {
        // Already overlapping: leave the cut-off disc of the time step.
        let w = rel_vel - rel_pos * inv_dt;
        let w_len = w.norm();
        // RVO2 divides by |w| unguarded; when it vanishes, push straight away from the other.
        let unit_w = if w_len > 0.0 {
            w * (1.0 / w_len)
        } else if dist_sq > 0.0 {
            -rel_pos.normalized()
        } else {
            Vec2::new(1.0, 0.0)
        };
        (
            Vec2::new(unit_w.y, -unit_w.x),
            unit_w * (r * inv_dt - w_len),
        )
    };
    Line {
        point: velocity + u * 0.5,
        direction,
    }
}

/// One ORCA velocity: the velocity closest to `pref_velocity` that is permitted by the ORCA
/// half-planes of the selected neighbours (RVO2 `computeNeighbors` + `computeNewVelocity`).
pub fn compute_new_velocity(
    position: Vec2,
    velocity: Vec2,
    pref_velocity: Vec2,
    others: &[Neighbor],
    params: &OrcaParams,
) -> Vec2 {
    let lines = orca_lines(position, velocity, others, params);
    lp::solve(&lines, params.max_speed, pref_velocity)
}

/// [`compute_new_velocity`] with static obstacles, as RVO2: the obstacles' lines
/// (`time_horizon_obst`, full responsibility) come first and are never relaxed, then the
/// neighbours' lines.
pub fn compute_new_velocity_with_obstacles(
    position: Vec2,
    velocity: Vec2,
    pref_velocity: Vec2,
    others: &[Neighbor],
    obstacles: &crate::obstacle::Obstacles,
    time_horizon_obst: f64,
    params: &OrcaParams,
) -> Vec2 {
    if obstacles.is_empty() {
        return compute_new_velocity(position, velocity, pref_velocity, others, params);
    }
    let mut lines = obstacles.lines(
        position,
        velocity,
        params.radius,
        time_horizon_obst,
        params.max_speed,
    );
    let fixed = lines.len();
    lines.extend(orca_lines(position, velocity, others, params));
    lp::solve_fixed(&lines, fixed, params.max_speed, pref_velocity)
}

/// The ORCA half-planes of the selected neighbours, closest neighbour first.
pub fn orca_lines(
    position: Vec2,
    velocity: Vec2,
    others: &[Neighbor],
    params: &OrcaParams,
) -> Vec<Line> {
    select_neighbors(position, others, params.neighbor_dist, params.max_neighbors)
        .into_iter()
        .map(|i| {
            orca_line(
                position,
                velocity,
                params.radius,
                &others[i],
                params.time_horizon,
                params.time_step,
            )
        })
        .collect()
}
