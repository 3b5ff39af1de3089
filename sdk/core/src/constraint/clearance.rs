//! The built-in clearance term: room between the robot's footprint and the people and static
//! obstacles of the planning scene, with a contact penalty.
//!
//! The batch's pose 0 is the robot's current pose (it cannot be planned away and is not
//! scored); pose `k ≥ 1` is waypoint `k − 1`, `k·dt` after the planning instant, and meets the
//! forecast's step `k − 1`. For one trajectory and one scene of the forecast:
//!
//! ```text
//! C = (1/len) Σ_j Σ_i ((margin − gap_ij)/margin)²   over the pairs with 0 ≤ gap_ij < margin
//! ```
//!
//! where `gap_ij` is the distance between the footprint at waypoint `j` and agent `i`'s disc
//! (or obstacle `i`), and `len` the number of waypoints scored. The first waypoint with an
//! overlap (`gap < 0`) ends the trajectory: it and every waypoint after it add
//! [`Clearance::collision`] instead, so a plan that runs through someone is no better than one
//! that stops in them, and a later contact costs less than an earlier one. With a goal in the
//! context ([`SceneContext::goal`]) the waypoints after the trajectory's arrival
//! ([`Clearance::arrival`]) are not scored (the run ends there); one that does not arrive is
//! also scored standing at its last pose for [`Clearance::hold`] more waypoints. With several
//! scenes the cost is their expectation.
//!
//! The gradient is that of the quadratic part, with the footprint's clearance differentiated
//! by central differences in `(x, y, θ)` (footprints and obstacles are unions of discs,
//! rectangles, segments and polygons; their distance is 1-Lipschitz and smooth almost
//! everywhere). The contact penalty is a step and has no gradient; at the waypoint of first
//! contact the penetrating pair keeps its quadratic gradient, which points out of the contact,
//! so that Algorithm 1 moves a sample out of someone rather than leaving it there.
//!
//! The selection of the Human2Nav planner scores its candidates with this term through Φ, and
//! Algorithm 1 descends it; one definition serves both.

use super::near::{Near, held};
use super::{ConstraintContext, ConstraintError, ConstraintTerm, SceneContext, TrajBatch};
use crate::forecast::Forecast;
use crate::obstacle;
use crate::robot::footprint::{self, FootprintShape};
use crate::se2::Pose2;

/// The name of the clearance term in Φ.
pub const CLEARANCE: &str = "clearance";

/// Step of the central differences of the footprint's clearance (m, and rad for θ).
const FD_STEP: f64 = 1e-6;

/// The clearance term (module docs). Built by the planner from its selection settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clearance {
    /// Gap (m) between footprint and an agent's disc or an obstacle below which the term
    /// rises; finite, > 0.
    pub margin: f64,
    /// What the waypoint of first contact and every later one add (≥ 0).
    pub collision: f64,
    /// Waypoints a trajectory that has not arrived is also scored standing at its last pose.
    pub hold: usize,
    /// With a goal in the context: the first waypoint within this distance of it (m) ends the
    /// trajectory. `None`: every waypoint is scored, and a trajectory has arrived only when
    /// its last waypoint is on the goal.
    pub arrival: Option<f64>,
}

impl Clearance {
    /// Checks the settings; the error names the field.
    pub fn validate(&self) -> Result<(), ConstraintError> {
        let fail = |message: String| ConstraintError::Failed {
            term: CLEARANCE.into(),
            message,
        };
        if !(self.margin.is_finite() && self.margin > 0.0) {
            return Err(fail(format!(
                "margin {} must be finite and > 0",
                self.margin
            )));
        }
        if !(self.collision.is_finite() && self.collision >= 0.0) {
            return Err(fail(format!(
                "collision {} must be finite and ≥ 0",
                self.collision
            )));
        }
        if let Some(a) = self.arrival
            && !(a.is_finite() && a >= 0.0)
        {
            return Err(fail(format!("arrival {a} must be finite and ≥ 0")));
        }
        Ok(())
    }

    /// Whether each trajectory of `batch` keeps out of contact (a gap above zero) with every
    /// agent and obstacle over the waypoints this term scores, in every forecast scene with a
    /// weight: the cost of the same term with the smallest margin and a unit collision
    /// weight is zero exactly then.
    pub fn contact_free(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
    ) -> Result<Vec<bool>, ConstraintError> {
        let probe = Clearance {
            margin: f64::MIN_POSITIVE,
            collision: 1.0,
            ..*self
        };
        let mut cost = vec![0.0; batch.batch];
        probe.run(batch, ctx, &mut cost, None)?;
        Ok(cost.iter().map(|&c| c == 0.0).collect())
    }

    /// How many of `traj`'s waypoints are scored, and whether it arrives at `goal`.
    pub(crate) fn checked(&self, traj: &[Pose2], goal: Option<[f64; 2]>) -> (usize, bool) {
        let Some(goal) = goal else {
            return (traj.len(), false);
        };
        match self.arrival {
            Some(r) => arrival(traj, goal, r).map_or((traj.len(), false), |k| (k + 1, true)),
            None => (
                traj.len(),
                traj.last().is_some_and(|p| distance(p, goal) == 0.0),
            ),
        }
    }

    /// Cost into `cost` and, with `grad`, its gradient: the one body of
    /// [`ConstraintTerm::evaluate`] and [`ConstraintTerm::cost`].
    fn run(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        mut grad: Option<&mut [f64]>,
    ) -> Result<(), ConstraintError> {
        let scene = &ctx.scene;
        if scene.footprint.is_empty() {
            return Err(ConstraintError::Failed {
                term: CLEARANCE.into(),
                message: "the context gives no robot footprint (`scene.footprint`)".into(),
            });
        }
        if batch.horizon < 2 {
            return Ok(());
        }
        let waypoints: Vec<Vec<Pose2>> = (0..batch.batch)
            .map(|b| {
                batch.trajectory(b)[3..]
                    .chunks_exact(3)
                    .map(|p| Pose2::new(p[0], p[1], p[2]))
                    .collect()
            })
            .collect();
        let owned;
        let forecast = match scene.forecast {
            Some(f) => f,
            None => {
                owned =
                    Forecast::constant_velocity(ctx.agents, batch.horizon - 1 + self.hold, ctx.dt);
                &owned
            }
        };
        let reach = footprint::reach(scene.footprint);
        let near = Near::new(
            &waypoints,
            self.hold,
            forecast,
            scene.obstacles,
            reach,
            self.margin,
        );
        let pose_values = batch.horizon * 3;
        for (b, traj) in waypoints.iter().enumerate() {
            let (checked, arrived) = self.checked(traj, scene.goal);
            let hold = if arrived { 0 } else { self.hold };
            let len = traj.len() + if checked > 0 { hold } else { 0 };
            let one = Trajectory {
                checked: &traj[..checked],
                hold,
                len,
            };
            cost[b] += near
                .expectation(|s| self.scene_cost(&one, scene, &near, s, None) / len.max(1) as f64);
            if let Some(grad) = grad.as_deref_mut() {
                let g = &mut grad[b * pose_values..(b + 1) * pose_values];
                for s in 0..near.scenes() {
                    let scale = near.weight(s) / len.max(1) as f64;
                    self.scene_cost(&one, scene, &near, s, Some((g, scale)));
                }
            }
        }
        Ok(())
    }

    /// The sum (before the division by `len`) of one trajectory's clearance in scene `s`;
    /// with `grad`, adds `scale` times the gradient of its quadratic part into the
    /// trajectory's `[T, 3]` gradient (pose 0, the current pose, gets none).
    fn scene_cost(
        &self,
        traj: &Trajectory<'_>,
        scene: &SceneContext<'_>,
        near: &Near,
        s: usize,
        mut grad: Option<(&mut [f64], f64)>,
    ) -> f64 {
        let margin = self.margin;
        let fp = scene.footprint;
        let mut sum = 0.0;
        for (j, p) in held(traj.checked, traj.hold).enumerate() {
            // The pose this waypoint is (a held waypoint is the last checked one).
            let pose_index = j.min(traj.checked.len() - 1) + 1;
            // The heading's sine and cosine, once per waypoint rather than per agent.
            let mut turn: Option<(f64, f64)> = None;
            let mut hit = false;
            let agents = near.agents(s, j).iter().filter_map(|a| {
                let (dx, dy) = (a.q[0] - p.x, a.q[1] - p.y);
                (dx * dx + dy * dy < a.far * a.far).then(|| {
                    let turn = *turn.get_or_insert_with(|| p.theta.sin_cos());
                    let gap = footprint::clearance_at_turned(fp, *p, turn, a.q, a.radius);
                    (gap, Gap::Agent(a.q, a.radius))
                })
            });
            let obstacles = near.obstacles(j).iter().filter_map(|&k| {
                let o = &scene.obstacles[k];
                near.obstacle_may_matter(o, p)
                    .then(|| (obstacle::footprint_clearance(fp, *p, o), Gap::Obstacle(k)))
            });
            for (gap, what) in agents.chain(obstacles) {
                if gap < margin
                    && let Some((g, scale)) = grad.as_mut()
                {
                    let d = what.gradient(fp, scene, *p);
                    let factor = *scale * -2.0 * (margin - gap) / (margin * margin);
                    for (slot, di) in g[pose_index * 3..pose_index * 3 + 3].iter_mut().zip(d) {
                        *slot += factor * di;
                    }
                }
                if gap < 0.0 {
                    hit = true;
                    break;
                } else if gap < margin {
                    sum += ((margin - gap) / margin).powi(2);
                }
            }
            if hit {
                sum += self.collision * (traj.len - j) as f64;
                break;
            }
        }
        sum
    }
}

/// The distance (m) from a pose to a point.
fn distance(p: &Pose2, q: [f64; 2]) -> f64 {
    (p.x - q[0]).hypot(p.y - q[1])
}

/// The index of the first waypoint of `traj` within `radius` of `goal`, where a run following
/// it ends: the rule the selection's goal term and this term's scored waypoints share.
pub fn arrival(traj: &[Pose2], goal: [f64; 2], radius: f64) -> Option<usize> {
    traj.iter().position(|p| within(p, goal, radius))
}

/// `distance(p, q) <= radius`, to the bit, with the square root left out wherever the squared
/// distance decides it (all but a thin shell around `radius`).
fn within(p: &Pose2, q: [f64; 2], radius: f64) -> bool {
    let (dx, dy) = (p.x - q[0], p.y - q[1]);
    let d2 = dx * dx + dy * dy;
    let (inner, outer) = (
        radius * (1.0 - obstacle::SHELL),
        radius * (1.0 + obstacle::SHELL),
    );
    if d2 < inner * inner {
        true
    } else if d2 > outer * outer {
        false
    } else {
        dx.hypot(dy) <= radius
    }
}

/// The smallest of `start` and the [`distance`]s from the poses of `traj` to `q`, to the bit
/// ([`obstacle::smallest_norm`]: few square roots).
pub(crate) fn closest_distance(traj: &[Pose2], q: [f64; 2], start: f64) -> f64 {
    obstacle::smallest_norm(traj.iter().map(|p| [p.x - q[0], p.y - q[1]]), start)
}

/// One trajectory as the term scores it: its scored waypoints, the hold after them and the
/// number of waypoints its cost is averaged over.
struct Trajectory<'a> {
    checked: &'a [Pose2],
    hold: usize,
    len: usize,
}

/// What a gap is measured to.
#[derive(Clone, Copy)]
enum Gap {
    /// An agent's disc: centre and radius.
    Agent([f64; 2], f64),
    /// The context's obstacle of this index.
    Obstacle(usize),
}

impl Gap {
    /// The gap between the footprint at `pose` and this.
    fn at(self, fp: &[FootprintShape], scene: &SceneContext<'_>, pose: Pose2) -> f64 {
        match self {
            Gap::Agent(q, r) => {
                footprint::clearance_at_turned(fp, pose, pose.theta.sin_cos(), q, r)
            }
            Gap::Obstacle(k) => obstacle::footprint_clearance(fp, pose, &scene.obstacles[k]),
        }
    }

    /// `∂gap/∂(x, y, θ)` at `pose` by central differences.
    fn gradient(self, fp: &[FootprintShape], scene: &SceneContext<'_>, pose: Pose2) -> [f64; 3] {
        let mut d = [0.0; 3];
        for (axis, slot) in d.iter_mut().enumerate() {
            let moved = |h: f64| {
                let mut q = pose;
                match axis {
                    0 => q.x += h,
                    1 => q.y += h,
                    _ => q.theta += h,
                }
                self.at(fp, scene, q)
            };
            *slot = (moved(FD_STEP) - moved(-FD_STEP)) / (2.0 * FD_STEP);
        }
        d
    }
}

impl ConstraintTerm for Clearance {
    fn name(&self) -> &str {
        CLEARANCE
    }

    /// Squares and contact penalties, per trajectory (the broad phase over the batch leaves
    /// out only what adds nothing).
    fn separable_nonnegative(&self) -> bool {
        true
    }

    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        super::builtin::check_buffers(CLEARANCE, &batch, ctx, cost, grad)?;
        self.run(batch, ctx, cost, Some(grad))
    }

    fn cost(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
    ) -> Result<(), ConstraintError> {
        super::builtin::check_cost_buffer(CLEARANCE, &batch, cost)?;
        self.run(batch, ctx, cost, None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::constraint::{Phi, PhiScratch};
    use crate::limits::Limits;
    use crate::planner::AgentState;
    use crate::se2::Twist2;

    const LIMITS: Limits = Limits {
        v_max: 1.0,
        v_reverse_max: 0.3,
        a_max: 1.0,
        omega_max: 1.0,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    };

    const TERM: Clearance = Clearance {
        margin: 0.5,
        collision: 10.0,
        hold: 0,
        arrival: Some(0.3),
    };

    fn disc(radius: f64) -> Vec<FootprintShape> {
        vec![FootprintShape::Disc {
            center: [0.0, 0.0],
            radius,
        }]
    }

    fn standing(x: f64, y: f64) -> AgentState {
        AgentState {
            id: 1,
            position: [x, y],
            velocity: [0.0, 0.0],
            radius: 0.2,
            history: vec![],
        }
    }

    /// Poses 0..=n along +x at `step` a pose, offset sideways by `y` (pose 0 at the origin).
    fn line(n: usize, step: f64, y: f64) -> Vec<f64> {
        (0..=n)
            .flat_map(|k| {
                let off = if k == 0 { 0.0 } else { y };
                [k as f64 * step, off, 0.0]
            })
            .collect()
    }

    fn context<'a>(
        agents: &'a [AgentState],
        footprint: &'a [FootprintShape],
        goal: Option<[f64; 2]>,
    ) -> ConstraintContext<'a> {
        ConstraintContext {
            dt: 0.1,
            limits: &LIMITS,
            initial_velocity: Twist2::new(0.0, 0.0, 0.0),
            agents,
            scene: SceneContext {
                footprint,
                goal,
                ..SceneContext::default()
            },
        }
    }

    fn cost_of(term: &Clearance, data: &[f64], ctx: &ConstraintContext<'_>) -> f64 {
        let batch = TrajBatch::new(data, 1, data.len() / 3).unwrap();
        let mut cost = [0.0];
        term.cost(batch, ctx, &mut cost).unwrap();
        cost[0]
    }

    #[test]
    fn the_cost_is_the_mean_squared_intrusion_into_the_margin() {
        // A robot disc of 0.3 m passing 0.7 m beside a standing agent of 0.2 m: gap 0.2 m at
        // the closest waypoint, inside the 0.5 m margin.
        let agents = [standing(1.0, 0.7)];
        let fp = disc(0.3);
        let ctx = context(&agents, &fp, None);
        let data = line(20, 0.1, 0.0);
        let mut expected = 0.0;
        for k in 1..=20 {
            let gap = (k as f64 * 0.1 - 1.0).hypot(0.7) - 0.5;
            if gap < 0.5 {
                expected += ((0.5 - gap) / 0.5f64).powi(2);
            }
        }
        expected /= 20.0;
        let c = cost_of(&TERM, &data, &ctx);
        assert!((c - expected).abs() < 1e-12, "{c} vs {expected}");
        assert!(c > 0.0);
    }

    #[test]
    fn a_contact_costs_the_penalty_for_it_and_every_later_waypoint() {
        let agents = [standing(1.0, 0.0)];
        let fp = disc(0.3);
        let ctx = context(&agents, &fp, None);
        let data = line(20, 0.1, 0.0);
        // First overlap: the gap |x − 1| − 0.5 < 0 first at x = 0.6, waypoint 6 (index 5).
        let before: f64 = (1..=5)
            .map(|k| {
                let gap = (1.0 - k as f64 * 0.1) - 0.5;
                if gap < 0.5 {
                    ((0.5 - gap) / 0.5f64).powi(2)
                } else {
                    0.0
                }
            })
            .sum();
        let expected = (before + 10.0 * (20 - 5) as f64) / 20.0;
        let c = cost_of(&TERM, &data, &ctx);
        assert!((c - expected).abs() < 1e-9, "{c} vs {expected}");
    }

    #[test]
    fn waypoints_after_the_arrival_are_not_scored() {
        // The agent stands just past the goal: a run that ends on arrival never meets it.
        let agents = [standing(1.3, 0.0)];
        let fp = disc(0.3);
        let data = line(20, 0.1, 0.0);
        let far = cost_of(&TERM, &data, &context(&agents, &fp, None));
        let arrived = cost_of(&TERM, &data, &context(&agents, &fp, Some([0.5, 0.0])));
        assert!(far > 1.0, "without a goal it runs into the agent: {far}");
        // Arrived at waypoint 2 (x = 0.2, within 0.3 m of the goal): gaps 0.6 and 0.5 m.
        assert_eq!(arrived, 0.0);
        let every = Clearance {
            arrival: None,
            ..TERM
        };
        assert_eq!(
            cost_of(&every, &data, &context(&agents, &fp, Some([0.5, 0.0]))),
            far
        );
    }

    #[test]
    fn the_gradient_is_the_derivative_of_the_cost_away_from_contact() {
        let agents = [standing(1.0, 0.6), standing(1.6, -0.7)];
        let fp = vec![FootprintShape::Rect {
            center: [0.1, 0.0],
            half: [0.35, 0.25],
            yaw: 0.0,
        }];
        let ctx = context(&agents, &fp, None);
        // A gently curving path, so that heading matters for the rectangle.
        let data: Vec<f64> = (0..=20)
            .flat_map(|k| {
                let x = k as f64 * 0.1;
                [x, 0.05 * x * x, 0.1 * x]
            })
            .collect();
        let batch = TrajBatch::new(&data, 1, 21).unwrap();
        let (mut cost, mut grad) = ([0.0], vec![0.0; data.len()]);
        TERM.evaluate(batch, &ctx, &mut cost, &mut grad).unwrap();
        assert!(cost[0] > 0.0);
        assert!(grad[..3].iter().all(|g| *g == 0.0), "pose 0 is the robot's");
        let h = 1e-6;
        for i in 3..data.len() {
            let mut up = data.clone();
            up[i] += h;
            let mut down = data.clone();
            down[i] -= h;
            let fd = (cost_of(&TERM, &up, &ctx) - cost_of(&TERM, &down, &ctx)) / (2.0 * h);
            assert!(
                (fd - grad[i]).abs() < 1e-5 * (1.0 + fd.abs()),
                "coordinate {i}: analytic {} vs finite difference {fd}",
                grad[i]
            );
        }
    }

    #[test]
    fn costs_without_gradients_match_the_full_evaluation() {
        let agents = [standing(1.0, 0.4)];
        let fp = disc(0.3);
        let ctx = context(&agents, &fp, Some([3.0, 0.0]));
        let mut phi = Phi::from_weights(&crate::GuidanceWeights::default(), &LIMITS);
        phi.push(2.0, Box::new(TERM)).unwrap();
        let data: Vec<f64> = [0.0, 0.3, -0.3]
            .iter()
            .flat_map(|&y| line(20, 0.12, y))
            .collect();
        let batch = TrajBatch::new(&data, 3, 21).unwrap();
        let mut scratch = PhiScratch::default();
        let (mut full, mut grad) = (vec![0.0; 3], vec![0.0; data.len()]);
        phi.evaluate(batch, &ctx, &mut full, &mut grad, &mut scratch)
            .unwrap();
        let mut costs = vec![0.0; 3];
        phi.costs(batch, &ctx, &mut costs, &mut scratch).unwrap();
        for (a, b) in full.iter().zip(&costs) {
            assert!((a - b).abs() < 1e-12, "{full:?} vs {costs:?}");
        }
        // The path through the agent costs most.
        assert!(costs[1] > costs[0] && costs[0] > costs[2], "{costs:?}");
    }

    #[test]
    fn without_a_footprint_the_term_is_an_error_not_a_zero() {
        let agents = [standing(1.0, 0.0)];
        let ctx = context(&agents, &[], None);
        let data = line(5, 0.1, 0.0);
        let batch = TrajBatch::new(&data, 1, 6).unwrap();
        let err = TERM.cost(batch, &ctx, &mut [0.0]).unwrap_err().to_string();
        assert!(
            err.contains("clearance") && err.contains("footprint"),
            "{err}"
        );
    }

    proptest::proptest! {
        /// `arrival` and `closest_distance` leave out square roots: they answer what the
        /// distances themselves answer, to the bit, on and around the radius, with poses on
        /// the goal, far off, equally far, tiny and not finite.
        #[test]
        fn squared_shortcuts_answer_as_the_distances(
            xs in proptest::collection::vec((-3.0..3.0f64, -3.0..3.0f64, 0usize..6), 1..12),
            radius in 0.0..2.0f64,
            start in 0.0..5.0f64,
        ) {
            let goal = [0.4, -0.7];
            let traj: Vec<Pose2> = xs
                .iter()
                .map(|&(x, y, kind)| match kind {
                    // Exactly on the radius along an axis, on the goal, tiny, not finite.
                    0 => Pose2::new(goal[0] + radius, goal[1], 0.0),
                    1 => Pose2::new(goal[0], goal[1], 0.0),
                    2 => Pose2::new(goal[0] + x * 1e-170, goal[1] + y * 1e-170, 0.0),
                    3 => Pose2::new(f64::NAN, y, 0.0),
                    _ => Pose2::new(x, y, 0.0),
                })
                .collect();
            let naive_arrival = traj.iter().position(|p| distance(p, goal) <= radius);
            proptest::prop_assert_eq!(arrival(&traj, goal, radius), naive_arrival);
            let naive = traj.iter().map(|p| distance(p, goal)).fold(start, f64::min);
            proptest::prop_assert_eq!(
                closest_distance(&traj, goal, start).to_bits(),
                naive.to_bits()
            );
        }
    }
}
