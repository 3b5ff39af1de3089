//! A grid of the robot's own motions: two-segment twist profiles rolled out from the current
//! velocity within the robot's limits. The benchmark's motion search (`sim::oracle`) ranks them
//! against a crowd's future; the Human2Nav planner offers them to its selection beside the flow
//! model's samples ([`crate::human2nav::Human2NavSettings::motions`]).
//!
//! For the first `switch` steps the twist ramps toward one target of the grid, then toward a
//! second one. The grid spans forward speeds from `-v_reverse_max` to `v_max` (`speed_levels`
//! values, standstill among them), turns from −1 to 1 as a fraction of the yaw rate the robot
//! can use at the speed it has (`ω_max`, and `κ_max·|v|` for a car; `turn_levels` values) and,
//! for an omnidirectional robot (lateral limit above a fifth of `v_max`), `lateral_levels`
//! sideways speeds. Speeds ramp at `a_max` as segment means: the first segment lies
//! `a_max·dt/2` from the current speed and the next ones `a_max·dt` apart, which is what the
//! tracking controller's feed-forward needs to stay within `a_max` across replanning
//! ([`crate::embodiment::plan_feedforward`]). A coupled limit scales the yaw rate, then the
//! speeds, back inside it. So every rolled-out motion is within the robot's limits (plan TFS 1
//! up to the TFS tolerance).

use crate::limits::Limits;
use crate::se2::{Pose2, Twist2};

/// One segment's target: forward speed, sideways speed and the turn as a fraction of the yaw
/// rate the robot can use at its speed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Target {
    /// Forward speed (m/s).
    pub vx: f64,
    /// Sideways speed (m/s; 0 for a robot that cannot move sideways).
    pub vy: f64,
    /// Yaw rate as a fraction in `[−1, 1]` of what the robot can use at its speed.
    pub turn: f64,
}

/// Sizes of the grid of targets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridLevels {
    /// Forward speed targets (at least 2).
    pub speed: usize,
    /// Turn targets (odd, so that straight is one).
    pub turn: usize,
    /// Sideways speed targets of an omnidirectional robot (odd).
    pub lateral: usize,
}

impl Default for GridLevels {
    fn default() -> Self {
        Self {
            speed: 7,
            turn: 7,
            lateral: 3,
        }
    }
}

/// `n` values from `lo` to `hi`, evenly spaced (`n = 1`: the midpoint).
fn levels(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if n <= 1 {
        return vec![0.5 * (lo + hi)];
    }
    (0..n)
        .map(|i| lo + (hi - lo) * i as f64 / (n - 1) as f64)
        .collect()
}

/// The motions of one robot (module docs).
#[derive(Clone, Debug)]
pub struct MotionGrid {
    limits: Limits,
    targets: Vec<Target>,
    holonomic: bool,
}

impl MotionGrid {
    /// The grid of `levels` for a robot with `limits`.
    pub fn new(limits: Limits, levels_: GridLevels) -> Self {
        let mut speeds = Vec::with_capacity(levels_.speed.max(2));
        let forward = if limits.v_reverse_max > 0.0 && levels_.speed >= 3 {
            speeds.push(-limits.v_reverse_max);
            levels_.speed - 2
        } else {
            levels_.speed.max(2) - 1
        };
        speeds.push(0.0);
        speeds.extend((1..=forward).map(|j| limits.v_max * j as f64 / forward as f64));
        let holonomic = limits.lateral_speed_max > 0.2 * limits.v_max;
        let laterals = if holonomic {
            levels(
                -limits.lateral_speed_max,
                limits.lateral_speed_max,
                levels_.lateral,
            )
        } else {
            vec![0.0]
        };
        let turns = levels(-1.0, 1.0, levels_.turn);
        let mut targets = Vec::with_capacity(speeds.len() * laterals.len() * turns.len());
        for &vx in &speeds {
            for &vy in &laterals {
                for &turn in &turns {
                    targets.push(Target { vx, vy, turn });
                }
            }
        }
        Self {
            limits,
            targets,
            holonomic,
        }
    }

    /// Number of two-segment motions (pairs of targets).
    pub fn len(&self) -> usize {
        self.targets.len() * self.targets.len()
    }

    /// Whether the grid has no motion (never: standstill is always a target).
    pub fn is_empty(&self) -> bool {
        self.targets.is_empty()
    }

    /// The target pairs of `count` motions spread evenly over all of them (every one when
    /// `count` reaches [`Self::len`]): indices `i·s mod len` for a stride `s` coprime with the
    /// number of pairs, so that no two coincide.
    pub fn spread(&self, count: usize) -> impl Iterator<Item = (Target, Target)> + '_ {
        let m = self.targets.len();
        let pairs = m * m;
        let count = count.min(pairs);
        let stride = if count == pairs || count == 0 {
            1
        } else {
            let mut s = pairs / count;
            while gcd(s, pairs) != 1 {
                s += 1;
            }
            s
        };
        (0..count).map(move |i| {
            let p = (i * stride) % pairs;
            (self.targets[p / m], self.targets[p % m])
        })
    }

    /// The twist one step of `dt` moves `now` to on the way to `target` (module docs; `first`:
    /// the plan's first segment, half a ramp step from the current speed).
    pub fn step_twist(&self, now: Twist2, target: Target, dt: f64, first: bool) -> Twist2 {
        let l = &self.limits;
        let dv = l.a_max * dt * if first { 0.5 } else { 1.0 };
        let vx = now.vx + (target.vx - now.vx).clamp(-dv, dv);
        let vy = if self.holonomic {
            now.vy + (target.vy - now.vy).clamp(-dv, dv)
        } else {
            0.0
        };
        let omega_cap = match l.kappa_max {
            Some(k) => l.omega_max.min(k * vx.abs()),
            None => l.omega_max,
        };
        let mut twist = Twist2 {
            vx,
            vy,
            omega: target.turn * omega_cap,
        };
        if let Some(c) = l.coupled
            && c.value(twist.vx, twist.vy, twist.omega) > c.max
        {
            // The yaw rate gives way first, then the speeds.
            let linear = c.value(twist.vx, twist.vy, 0.0);
            if linear < c.max && c.omega > 0.0 {
                twist.omega = twist.omega.signum() * (c.max - linear) / c.omega;
            } else {
                twist.omega = 0.0;
                let s = if linear > 0.0 { c.max / linear } else { 0.0 };
                twist.vx *= s;
                twist.vy *= s;
            }
        }
        twist
    }

    /// Rolls out the motion toward `first` for `switch` steps, then toward `second`, from
    /// `start` with body velocity `v0`: `steps` poses at `dt, 2·dt, …` (the start itself not
    /// included) appended to `out`.
    #[allow(clippy::too_many_arguments)]
    pub fn rollout(
        &self,
        start: Pose2,
        v0: Twist2,
        (first, second): (Target, Target),
        switch: usize,
        dt: f64,
        steps: usize,
        out: &mut Vec<Pose2>,
    ) {
        out.reserve(steps);
        let mut state = Rollout::new(start, v0);
        for k in 1..=steps {
            let target = if k <= switch { first } else { second };
            out.push(state.step(self, target, dt, k == 1));
        }
    }

    /// [`Self::rollout`] of every pair of `pairs`, in order, each `steps` poses: the same poses
    /// to the bit, with the first `switch` steps rolled out once per first target and shared
    /// by the pairs that start with it (a whole grid has as many pairs per first target as it
    /// has targets).
    pub fn rollouts(
        &self,
        start: Pose2,
        v0: Twist2,
        pairs: impl IntoIterator<Item = (Target, Target)>,
        switch: usize,
        dt: f64,
        steps: usize,
    ) -> Vec<Vec<Pose2>> {
        let head = switch.min(steps);
        // Per first target seen so far: its first segment and the state at its end.
        let mut prefixes: Vec<(Target, Vec<Pose2>, Rollout)> = Vec::new();
        let mut out = Vec::new();
        for (first, second) in pairs {
            let key = [first.vx, first.vy, first.turn];
            let k = match prefixes
                .iter()
                .rposition(|(t, ..)| same_bits([t.vx, t.vy, t.turn], key))
            {
                Some(k) => k,
                None => {
                    let mut state = Rollout::new(start, v0);
                    let poses = (1..=head)
                        .map(|k| state.step(self, first, dt, k == 1))
                        .collect();
                    prefixes.push((first, poses, state));
                    prefixes.len() - 1
                }
            };
            let (_, prefix, state) = &prefixes[k];
            let mut state = *state;
            let mut poses = Vec::with_capacity(steps);
            poses.extend_from_slice(prefix);
            poses.extend((head + 1..=steps).map(|k| state.step(self, second, dt, k == 1)));
            out.push(poses);
        }
        out
    }
}

/// Whether two targets or twists are the same to the bit (so that sharing a rollout or an
/// increment between them changes nothing).
fn same_bits(a: [f64; 3], b: [f64; 3]) -> bool {
    a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// A rollout under way: the pose and twist reached, and the last Euler increment
/// `exp(dt·twist)` with its twist. Once the twist has ramped to its target it stays the same
/// from step to step, and the increment is reused instead of recomputed (the same value: the
/// pose is `pose·exp(dt·twist)` as in [`Pose2::euler_step`]).
#[derive(Clone, Copy, Debug)]
struct Rollout {
    pose: Pose2,
    twist: Twist2,
    increment: Option<(Twist2, Pose2)>,
}

impl Rollout {
    fn new(pose: Pose2, twist: Twist2) -> Self {
        Self {
            pose,
            twist,
            increment: None,
        }
    }

    /// One step of `dt` toward `target` ([`MotionGrid::step_twist`]); the new pose.
    fn step(&mut self, grid: &MotionGrid, target: Target, dt: f64, first: bool) -> Pose2 {
        self.twist = grid.step_twist(self.twist, target, dt, first);
        let twist = self.twist;
        let increment = match self.increment {
            Some((t, inc)) if same_bits(t.to_array(), twist.to_array()) => inc,
            _ => {
                let inc = Pose2::exp(twist.scale(dt));
                self.increment = Some((twist, inc));
                inc
            }
        };
        self.pose = self.pose.compose(increment);
        self.pose
    }
}

fn gcd(mut a: usize, mut b: usize) -> usize {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::feasibility::tfs_plan;

    fn car() -> Limits {
        Limits {
            v_max: 1.5,
            v_reverse_max: 0.5,
            a_max: 1.0,
            omega_max: 1.0,
            kappa_max: Some(1.0 / 1.6),
            lateral_speed_max: 0.05,
            coupled: None,
        }
    }

    #[test]
    fn every_motion_is_within_the_limits_from_any_start_speed() {
        let omni = Limits {
            v_max: 2.0,
            v_reverse_max: 0.5,
            a_max: 1.5,
            omega_max: 1.8,
            kappa_max: None,
            lateral_speed_max: 1.0,
            coupled: None,
        };
        for limits in [car(), omni] {
            let grid = MotionGrid::new(limits, GridLevels::default());
            for v0 in [
                Twist2::ZERO,
                Twist2::new(1.2, 0.0, 0.3),
                Twist2::new(-0.3, 0.0, 0.0),
            ] {
                for pair in grid.spread(500) {
                    let mut plan = vec![Pose2::IDENTITY];
                    grid.rollout(Pose2::IDENTITY, v0, pair, 10, 0.1, 32, &mut plan);
                    assert_eq!(plan.len(), 33);
                    let tfs = tfs_plan(&plan, 0.1, &limits, v0);
                    assert!(tfs >= 0.999, "{pair:?} from {v0:?}: TFS {tfs}");
                }
            }
        }
    }

    /// A rollout step by step with [`Pose2::euler_step`]: what `rollout` and `rollouts`
    /// must give to the bit.
    fn reference(
        grid: &MotionGrid,
        v0: Twist2,
        (a, b): (Target, Target),
        switch: usize,
    ) -> Vec<Pose2> {
        let (mut pose, mut twist) = (Pose2::new(1.0, -2.0, 0.7), v0);
        (1..=32)
            .map(|k| {
                twist = grid.step_twist(twist, if k <= switch { a } else { b }, 0.1, k == 1);
                pose = pose.euler_step(twist, 0.1);
                pose
            })
            .collect()
    }

    #[test]
    fn shared_first_segments_and_reused_increments_change_no_bit() {
        let bits = |plan: &[Pose2]| -> Vec<[u64; 3]> {
            plan.iter()
                .map(|p| [p.x.to_bits(), p.y.to_bits(), p.theta.to_bits()])
                .collect()
        };
        let grid = MotionGrid::new(car(), GridLevels::default());
        let start = Pose2::new(1.0, -2.0, 0.7);
        for v0 in [Twist2::ZERO, Twist2::new(1.2, 0.0, 0.3)] {
            for switch in [0, 10, 40] {
                for count in [500, grid.len()] {
                    let all = grid.rollouts(start, v0, grid.spread(count), switch, 0.1, 32);
                    assert_eq!(all.len(), count);
                    for (pair, plan) in grid.spread(count).zip(&all) {
                        let want = bits(&reference(&grid, v0, pair, switch));
                        assert_eq!(bits(plan), want, "{pair:?} from {v0:?}, switch {switch}");
                        let mut one = Vec::new();
                        grid.rollout(start, v0, pair, switch, 0.1, 32, &mut one);
                        assert_eq!(bits(&one), want);
                    }
                }
            }
        }
    }

    #[test]
    fn the_grid_holds_standstill_reverse_and_both_turns() {
        let grid = MotionGrid::new(car(), GridLevels::default());
        let t = &grid.targets;
        assert_eq!(t.len(), 7 * 7);
        assert!(t.iter().any(|x| x.vx == 0.0 && x.turn == 0.0));
        assert!(t.iter().any(|x| x.vx == -0.5));
        assert!(t.iter().any(|x| x.vx == 1.5 && x.turn == -1.0));
        assert!(
            t.iter().all(|x| x.vy == 0.0),
            "a car does not move sideways"
        );
        // Every pair once when all are asked for; an even spread otherwise, without repeats.
        assert_eq!(grid.spread(usize::MAX).count(), grid.len());
        let some: Vec<_> = grid.spread(300).collect();
        assert_eq!(some.len(), 300);
        for (i, a) in some.iter().enumerate() {
            assert!(!some[i + 1..].contains(a), "pair {i} repeats");
        }
    }

    #[test]
    fn a_coupled_limit_gives_way_in_the_yaw_rate_first() {
        let limits = Limits {
            v_max: 1.4,
            v_reverse_max: 0.0,
            a_max: 1.0,
            omega_max: 2.0,
            kappa_max: None,
            lateral_speed_max: 0.05,
            coupled: Some(crate::limits::CoupledLimit {
                v: 1.0,
                lateral: 0.0,
                omega: 0.4,
                max: 1.4,
            }),
        };
        let grid = MotionGrid::new(limits, GridLevels::default());
        let full = Target {
            vx: 1.4,
            vy: 0.0,
            turn: 1.0,
        };
        let tw = grid.step_twist(Twist2::new(1.0, 0.0, 0.0), full, 0.1, false);
        assert!((tw.vx - 1.1).abs() < 1e-12, "the speed ramps as usual");
        assert!(
            (tw.vx + 0.4 * tw.omega - 1.4).abs() < 1e-12,
            "ω takes what is left"
        );
    }
}
