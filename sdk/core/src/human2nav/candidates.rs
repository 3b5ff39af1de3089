//! The candidates besides the samples: slowed copies, braking, straight to the goal, the
//! previous plan, the robot's own motions, and the last-step correction that makes them feasible.

use super::*;

impl<M: FlowModel> Human2Nav<M> {
    /// The candidates besides the flow samples: the shortlist's slowed copies, the stop, the
    /// straight approach to a near goal and the previous plan, each as the settings allow.
    pub(super) fn push_extra_candidates(
        &self,
        shortlist: &[usize],
        goal: [f64; 2],
        horizon: usize,
        warm: Option<&Vec<Pose2>>,
        candidates: &mut Vec<Vec<Pose2>>,
        origin: &mut Vec<Source>,
    ) {
        let dt = self.settings.dt;
        if self.settings.slowdown < 1.0 {
            for (j, &i) in shortlist.iter().enumerate() {
                candidates.push(time_scaled(&candidates[j], self.settings.slowdown));
                origin.push(Source::Slowed(i));
            }
        }
        if self.settings.stop_candidate {
            candidates.push(vec![Pose2::IDENTITY; horizon]);
            origin.push(Source::Stop);
        }
        if goal[0].hypot(goal[1]) <= self.settings.goal_approach {
            let speed = 0.5 * self.robot.limits.v_max;
            candidates.push(goal_approach(goal, speed, dt, horizon));
            origin.push(Source::Goal);
        }
        if let Some(prev) = warm {
            candidates.push(prev.clone());
            origin.push(Source::Previous);
        }
    }

    /// [`Human2NavSettings::motions`] (or, for a car, [`Human2NavSettings::car_motions`]) of
    /// the robot's own motions from its velocity `v0`, ego frame, `horizon` poses each.
    pub(super) fn push_motions(
        &self,
        v0: Twist2,
        horizon: usize,
        candidates: &mut Vec<Vec<Pose2>>,
        origin: &mut Vec<Source>,
    ) {
        let dt = self.settings.dt;
        let switch = ((MOTION_SWITCH_S / dt).round() as usize).max(1);
        let count = motion_count(&self.settings, &self.robot.limits);
        let grid = &self.motion_grid;
        let motions = grid.rollouts(Pose2::IDENTITY, v0, grid.spread(count), switch, dt, horizon);
        origin.extend(std::iter::repeat_n(Source::Motion, motions.len()));
        candidates.extend(motions);
    }

    /// The last-step correction of every candidate, in order, returning which it made
    /// feasible. Once `deadline` has passed only the stop and the previous-plan candidates are
    /// corrected (the previous plan usually is feasible already, which costs no QP), and a stop
    /// candidate is added if there is none, so that a plan cut short is still a safe one.
    pub(super) fn correct(
        &mut self,
        candidates: &mut Vec<Vec<Pose2>>,
        origin: &mut Vec<Source>,
        v0: Twist2,
        deadline: &Deadline,
        stages: &mut Stages,
        notes: &mut Vec<String>,
    ) -> Vec<bool> {
        let mut corrected = Vec::with_capacity(candidates.len() + 1);
        let mut late = false;
        for j in 0.. {
            late = late || stages.cut_short.is_some() || deadline.passed();
            if j == candidates.len() {
                if !late || origin.contains(&Source::Stop) {
                    break;
                }
                candidates.push(vec![Pose2::IDENTITY; self.model.horizon()]);
                origin.push(Source::Stop);
            }
            if late && !matches!(origin[j], Source::Stop | Source::Previous) {
                corrected.push(false);
                continue;
            }
            stages.correction.done += 1;
            match projection::project_with(
                &candidates[j],
                self.settings.dt,
                &self.robot.limits,
                v0,
                &self.settings.projection,
                &mut self.projection,
            ) {
                Ok(p) => {
                    candidates[j] = p.poses;
                    corrected.push(true);
                }
                Err(e) => {
                    notes.push(format!("last-step correction skipped: {e}"));
                    corrected.push(false);
                }
            }
        }
        stages.correction.planned = candidates.len();
        if late {
            stages.cut_short.get_or_insert(Stage::Correction);
            if corrected.iter().filter(|&&c| c).count() < candidates.len() {
                notes.push(format!(
                    "deadline: {} of {} candidates corrected",
                    stages.correction.done,
                    candidates.len()
                ));
            }
        }
        corrected
    }

    /// The previous plan re-expressed in the current ego frame at the current time, `T` future
    /// poses (holding the last pose past its end), or `None` without a usable previous plan.
    pub(super) fn shifted_previous(&self, obs: &Observation, horizon: usize) -> Option<Vec<Pose2>> {
        let prev = self.previous.as_ref()?;
        if prev.poses.len() < 2 || (prev.dt - self.settings.dt).abs() > 1e-9 {
            return None;
        }
        let inv = obs.ego.inverse();
        let out: Vec<Pose2> = (1..=horizon)
            .map(|j| inv.compose(pose_at(prev, obs.time + j as f64 * self.settings.dt)))
            .collect();
        out.iter().all(|p| p.is_finite()).then_some(out)
    }
}

/// How many of its own motions a robot with `limits` is offered:
/// [`Human2NavSettings::car_motions`] for a car (unless 0), [`Human2NavSettings::motions`]
/// otherwise, none when `motions` is 0.
pub(super) fn motion_count(settings: &Human2NavSettings, limits: &Limits) -> usize {
    match (settings.motions, limits.kappa_max) {
        (0, _) => 0,
        (_, Some(_)) if settings.car_motions > 0 => settings.car_motions,
        (m, _) => m,
    }
}

/// Where a candidate of the selection came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Source {
    /// A sample of the flow model (guided when guidance is on), by sample index.
    Sample(usize),
    /// That sample's guided path at [`Human2NavSettings::slowdown`] of its speed.
    Slowed(usize),
    /// Braking to a standstill.
    Stop,
    /// Straight to a nearby goal ([`goal_approach`]).
    Goal,
    /// The previous plan, shifted to now (the warm start).
    Previous,
    /// One of the robot's own motions ([`Human2NavSettings::motions`]).
    Motion,
}

impl Source {
    /// The model sample whose path the candidate follows.
    pub(super) fn sample(self) -> Option<usize> {
        match self {
            Source::Sample(i) | Source::Slowed(i) => Some(i),
            Source::Stop | Source::Goal | Source::Previous | Source::Motion => None,
        }
    }
}

/// An ego-frame trajectory (poses at `dt, 2·dt, …` after the identity at time 0) followed at
/// `scale` times its speed along the same path: pose `j` is the original's pose at time
/// `scale·(j + 1)·dt`, interpolated along the geodesic between the poses around it. The path
/// and its curvature are kept; speeds scale by `scale` and accelerations by `scale²` (bar
/// the first step from the current velocity, which the last-step correction takes care of).
pub fn time_scaled(traj: &[Pose2], scale: f64) -> Vec<Pose2> {
    (1..=traj.len())
        .map(|j| {
            let s = scale * j as f64; // in units of dt; the identity sits at 0
            let i = s.floor() as usize;
            let f = s - i as f64;
            let at = |k: usize| {
                if k == 0 {
                    Pose2::IDENTITY
                } else {
                    traj[(k - 1).min(traj.len() - 1)]
                }
            };
            if i >= traj.len() {
                at(traj.len())
            } else {
                at(i).interpolate(at(i + 1), f)
            }
        })
        .collect()
}

/// `traj` (ego frame, starting after the robot's pose, the identity) followed by `steps` more
/// poses at the twist of its last step ([`SelectionWeights::lookahead`]): where the robot would
/// be if it went on as the plan ends. A plan that ends at rest stays there; a robot's own
/// motion ([`crate::motions`]) whose last segment has reached its twist is rolled out longer.
pub fn continued(traj: &[Pose2], steps: usize) -> Vec<Pose2> {
    let mut out = Vec::with_capacity(traj.len() + steps);
    out.extend_from_slice(traj);
    if let Some(&last) = traj.last() {
        let before = traj
            .len()
            .checked_sub(2)
            .map_or(Pose2::IDENTITY, |i| traj[i]);
        let step = before.inverse().compose(last);
        let mut p = last;
        for _ in 0..steps {
            p = p.compose(step);
            out.push(p);
        }
    }
    out
}

/// "Straight to the goal" in the ego frame: `T` poses at `dt` along the line from the robot to
/// `goal`, facing it, at `speed` until the goal and resting there. Not feasible as it stands
/// (it turns to face the goal at once and starts at `speed`); the last-step correction makes
/// it so.
pub fn goal_approach(goal: [f64; 2], speed: f64, dt: f64, horizon: usize) -> Vec<Pose2> {
    let d = goal[0].hypot(goal[1]);
    let heading = goal[1].atan2(goal[0]);
    (1..=horizon)
        .map(|j| {
            let f = if d > 0.0 {
                (speed * j as f64 * dt / d).min(1.0)
            } else {
                1.0
            };
            Pose2::new(f * goal[0], f * goal[1], heading)
        })
        .collect()
}
