//! Stage 3, the selection: the shortlist for Algorithm 1, Φ and the clearance term on a batch
//! of candidates, the goal term and the score, and the best candidate.

use super::*;
use crate::planner::MAX_COORDINATE;

impl<M: FlowModel> Human2Nav<M> {
    /// The samples that go on past sampling (to Algorithm 1, the slowed copies and the
    /// correction): the [`Human2NavSettings::guided_samples`] best by the selection score
    /// without its feasibility term (guidance and the correction are what fix feasibility),
    /// all of them when that is 0 or at least `K`, or when the paper variant of Algorithm 1
    /// runs (the paper guides every sample). Indices in sample order.
    pub(super) fn shortlist(
        &self,
        samples: &[Vec<Pose2>],
        goal: [f64; 2],
        ctx: &ConstraintContext<'_>,
        v0: Twist2,
        previous: Option<&[Pose2]>,
    ) -> Result<Vec<usize>, StageError> {
        let g = self.settings.guided_samples;
        let paper = self.settings.guidance.enabled
            && self.settings.guidance.variant == GuidanceVariant::Paper;
        if paper || g == 0 || g >= samples.len() {
            return Ok((0..samples.len()).collect());
        }
        let samples = self.scored(samples);
        let phi = self.phi_costs(&samples, ctx)?;
        let mut scored: Vec<(f64, usize)> = samples
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let s = self.score(c, goal, phi[i], v0, previous, false);
                (if s.is_finite() { s } else { f64::INFINITY }, i)
            })
            .collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut keep: Vec<usize> = scored[..g].iter().map(|&(_, i)| i).collect();
        keep.sort_unstable();
        Ok(keep)
    }

    /// Φ's context for this call: the plan step, the limits, the robot's velocity, the
    /// ego-frame agents, and the scene the clearance term reads (the forecast, the nearby
    /// obstacles, the footprint and the clipped goal).
    pub(super) fn phi_context<'a>(
        &'a self,
        obs: &Observation,
        agents: &'a [AgentState],
        forecast: &'a Forecast,
        goal: [f64; 2],
    ) -> ConstraintContext<'a> {
        let scene = SceneContext {
            forecast: Some(forecast),
            obstacles: &self.obstacles,
            footprint: &self.robot.footprint,
            goal: Some(goal),
        };
        phi_context(self.settings.dt, &self.robot.limits, obs, agents, scene)
    }

    /// The selection's clearance term (the one in Φ).
    pub(super) fn clearance(&self) -> Clearance {
        selection_clearance(&self.settings)
    }

    /// Whether each ego-frame candidate keeps out of contact with the people and obstacles as
    /// forecast, by the selection's clearance term ([`Clearance::contact_free`]).
    pub(super) fn contact_free(
        &self,
        candidates: &[Vec<Pose2>],
        ctx: &ConstraintContext<'_>,
    ) -> Result<Vec<bool>, StageError> {
        let Some((data, poses)) = pose_batch(candidates)? else {
            return Ok(Vec::new());
        };
        let batch = TrajBatch::new(&data, candidates.len(), poses).map_err(StageError::Batch)?;
        self.clearance()
            .contact_free(batch, ctx)
            .map_err(StageError::Contact)
    }

    /// Φ of every ego-frame candidate (each with the robot's pose, the identity, prepended as
    /// pose 0), without gradients. A term that fails or answers a non-finite cost is an error
    /// naming it: the selection never scores without a term.
    pub(super) fn phi_costs<C: AsRef<[Pose2]>>(
        &self,
        candidates: &[C],
        ctx: &ConstraintContext<'_>,
    ) -> Result<Vec<f64>, StageError> {
        let Some((data, poses)) = pose_batch(candidates)? else {
            return Ok(Vec::new());
        };
        let batch = TrajBatch::new(&data, candidates.len(), poses).map_err(StageError::Batch)?;
        let mut cost = vec![0.0; candidates.len()];
        self.robot
            .phi
            .costs(batch, ctx, &mut cost, &mut PhiScratch::default())
            .map_err(StageError::Phi)?;
        Ok(cost)
    }

    /// [`SelectionWeights::hold`] in plan steps.
    pub(super) fn hold_steps(&self) -> usize {
        steps(self.settings.selection.hold, self.settings.dt)
    }

    /// [`SelectionWeights::lookahead`] in plan steps.
    pub(super) fn lookahead_steps(&self) -> usize {
        steps(self.settings.selection.lookahead, self.settings.dt)
    }

    /// The candidates as the selection scores them: each [`continued`] for the lookahead, or
    /// as they are without one.
    pub(super) fn scored<'a>(&self, candidates: &'a [Vec<Pose2>]) -> Cow<'a, [Vec<Pose2>]> {
        match self.lookahead_steps() {
            0 => Cow::Borrowed(candidates),
            ahead => Cow::Owned(candidates.iter().map(|c| continued(c, ahead)).collect()),
        }
    }

    /// The selection score of one ego-frame candidate (lower is better), given its Φ (the
    /// robot's constraint terms and the clearance term, [`Self::phi_costs`]); without
    /// `with_feasibility` the TFS term is left out.
    pub(super) fn score(
        &self,
        traj: &[Pose2],
        goal: [f64; 2],
        phi: f64,
        v0: Twist2,
        previous: Option<&[Pose2]>,
        with_feasibility: bool,
    ) -> f64 {
        self.score_without_phi(traj, goal, v0, previous, with_feasibility)
            .with_phi(phi)
    }

    /// [`Self::score`] but for its Φ term, which [`Unweighed::with_phi`] adds.
    fn score_without_phi(
        &self,
        traj: &[Pose2],
        goal: [f64; 2],
        v0: Twist2,
        previous: Option<&[Pose2]>,
        with_feasibility: bool,
    ) -> Unweighed {
        let w = &self.settings.selection;
        // TFS costs a pass over the plan; with a zero weight (the shipped selection) it is
        // not computed.
        let feas = if with_feasibility && w.feasibility > 0.0 {
            let mut with_start = Vec::with_capacity(traj.len() + 1);
            with_start.push(Pose2::IDENTITY);
            with_start.extend_from_slice(traj);
            feasibility::tfs_plan(&with_start, self.settings.dt, &self.robot.limits, v0)
        } else {
            1.0
        };
        let reach_per_step = self.robot.limits.v_max * self.settings.dt;
        let progress = goal_term(traj, goal, w, reach_per_step);
        let consistency = previous.map_or(0.0, |prev| {
            let n = prev.len().min(traj.len()).max(1);
            prev.iter()
                .zip(traj)
                .map(|(a, b)| (a.x - b.x).hypot(a.y - b.y))
                .sum::<f64>()
                / n as f64
        });

        Unweighed {
            before: w.feasibility * (1.0 - feas) + w.goal * progress,
            phi_weight: w.phi,
            after: w.consistency * consistency,
        }
    }

    /// The candidate [`select_best`] chooses by [`Self::score`] with Φ of every candidate
    /// ([`Self::phi_costs`]), found without Φ of most of them. The score without its Φ term
    /// is a lower bound of the score when Φ is never negative (a sum of non-negative terms,
    /// and rounding is monotone), so the candidates are taken in the order of that bound, Φ
    /// of a few at a time, until the next bound cannot beat the best score found (ties going
    /// to the lower index, as in `select_best`): branch and bound. Φ of a candidate does not
    /// depend on the others of its batch (the terms' [`ConstraintTerm::separable_nonnegative`]),
    /// so the choice is the same to the bit. With a term that does not declare it, with a
    /// candidate of non-finite or far-off poses, or of another length, every candidate is
    /// scored, so that the same errors arise; so they are when a Φ comes out negative (a term
    /// that broke its declaration).
    pub(super) fn select(
        &self,
        scored: &[Vec<Pose2>],
        corrected: &[bool],
        ctx: &ConstraintContext<'_>,
        goal: [f64; 2],
        v0: Twist2,
        previous: Option<&[Pose2]>,
    ) -> Result<Option<usize>, StageError> {
        let parts: Vec<Unweighed> = scored
            .iter()
            .map(|c| self.score_without_phi(c, goal, v0, previous, true))
            .collect();
        let sane = |c: &Vec<Pose2>| {
            c.len() == scored[0].len()
                && c.iter().all(|p| {
                    p.is_finite() && p.x.abs() <= MAX_COORDINATE && p.y.abs() <= MAX_COORDINATE
                })
        };
        let eligible = eligible(corrected);
        let mut order: Vec<(f64, usize)> = (0..scored.len())
            .filter(|&i| eligible(i))
            .map(|i| (parts[i].with_phi(0.0), i))
            .filter(|(bound, _)| bound.is_finite())
            .collect();
        let score_all = || -> Result<Option<usize>, StageError> {
            let phi = self.phi_costs(scored, ctx)?;
            Ok(select_best(scored, corrected, |i| {
                parts[i].with_phi(phi[i])
            }))
        };
        if order.is_empty() || !self.robot.phi.separable_nonnegative() || !scored.iter().all(sane) {
            return score_all();
        }
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let beats = |(s, i): (f64, usize), best: Option<(f64, usize)>| {
            best.is_none_or(|(bs, bi)| s < bs || (s == bs && i < bi))
        };
        let mut best: Option<(f64, usize)> = None;
        let mut rest = &order[..];
        while let Some(&first) = rest.first() {
            if !beats(first, best) {
                break;
            }
            let (next, after) = rest.split_at(rest.len().min(PRUNE_CHUNK));
            rest = after;
            // In candidate order: neighbours often share their first poses, which Φ's
            // built-in terms score once.
            let mut chunk: Vec<usize> = next
                .iter()
                .filter(|&&bound| beats(bound, best))
                .map(|&(_, i)| i)
                .collect();
            chunk.sort_unstable();
            let candidates: Vec<&[Pose2]> = chunk.iter().map(|&i| scored[i].as_slice()).collect();
            let phi = self.phi_costs(&candidates, ctx)?;
            if phi.iter().any(|&v| v < 0.0) {
                // A term broke its declaration (a plugin's, say): the bound does not hold.
                return score_all();
            }
            for (&i, phi) in chunk.iter().zip(phi) {
                let s = parts[i].with_phi(phi);
                if s.is_finite() && beats((s, i), best) {
                    best = Some((s, i));
                }
            }
        }
        Ok(best.map(|(_, i)| i))
    }
}

/// How many candidates [`Human2Nav::select`] scores with Φ at a time.
const PRUNE_CHUNK: usize = 32;

/// A selection score but for its Φ term: `before + phi_weight·Φ + after`, added in the order
/// [`Human2Nav::score`] adds them.
#[derive(Clone, Copy, Debug)]
struct Unweighed {
    before: f64,
    phi_weight: f64,
    after: f64,
}

impl Unweighed {
    /// The score with Φ `phi`.
    fn with_phi(self, phi: f64) -> f64 {
        self.before + self.phi_weight * phi + self.after
    }
}

/// A duration in whole plan steps of `dt`.
pub(super) fn steps(seconds: f64, dt: f64) -> usize {
    (seconds / dt).round() as usize
}

/// The selection's goal term of the ego-frame candidate `traj`: `d/d_0` (module docs), or
/// how soon it could arrive with [`Progress::Time`]; `reach_per_step` is the way `v_max`
/// covers in one plan step. Which of its waypoints the clearance term scores (those up to its
/// arrival) is the term's own business ([`Clearance::arrival`]).
pub(super) fn goal_term(
    traj: &[Pose2],
    goal: [f64; 2],
    w: &SelectionWeights,
    reach_per_step: f64,
) -> f64 {
    let d0 = goal[0].hypot(goal[1]).max(1e-3);
    let distance = |p: &Pose2| (p.x - goal[0]).hypot(p.y - goal[1]);
    if w.progress == Progress::End {
        return traj.last().map_or(d0, distance) / d0;
    }
    // The first waypoint within `arrival` ends the candidate.
    if let Some(k) = arrival(traj, goal, w.arrival) {
        return match w.progress {
            Progress::Time => (k + 1) as f64 * reach_per_step / d0,
            _ => 0.0,
        };
    }
    match w.progress {
        Progress::Time => {
            (traj.len() as f64 * reach_per_step + traj.last().map_or(d0, distance)) / d0
        }
        _ => closest_distance(traj, goal, d0) / d0,
    }
}

/// The candidate with the lowest finite `score` among those whose poses are all finite. When
/// the last-step correction ran (`corrected` holds one flag per candidate), a candidate it
/// failed on is eligible only if it failed on every one: an uncorrected plan never wins over a
/// corrected one, whatever the weight of the score's feasibility term.
pub(super) fn select_best(
    candidates: &[Vec<Pose2>],
    corrected: &[bool],
    mut score: impl FnMut(usize) -> f64,
) -> Option<usize> {
    let eligible = eligible(corrected);
    let mut best: Option<(usize, f64)> = None;
    for (i, c) in candidates.iter().enumerate() {
        if !eligible(i) || !c.iter().all(|p| p.is_finite()) {
            continue;
        }
        let s = score(i);
        if s.is_finite() && best.is_none_or(|(_, b)| s < b) {
            best = Some((i, s));
        }
    }
    best.map(|(i, _)| i)
}

/// Whether candidate `i` may be chosen given the correction's flags ([`select_best`]).
fn eligible(corrected: &[bool]) -> impl Fn(usize) -> bool + '_ {
    let any_corrected = corrected.contains(&true);
    move |i| !any_corrected || corrected.get(i).copied().unwrap_or(false)
}

/// Ego-frame candidates as one flat batch of poses, each with the robot's pose (the identity)
/// prepended as pose 0, and the poses per trajectory; `None` without candidates. Candidates
/// of different lengths cannot be scored together (an error).
pub(super) fn pose_batch<C: AsRef<[Pose2]>>(
    candidates: &[C],
) -> Result<Option<(Vec<f64>, usize)>, StageError> {
    let Some(first) = candidates.first().map(C::as_ref) else {
        return Ok(None);
    };
    let poses = first.len() + 1;
    let mut data = Vec::with_capacity(candidates.len() * poses * 3);
    for c in candidates.iter().map(C::as_ref) {
        if c.len() + 1 != poses {
            return Err(StageError::Lengths {
                first: first.len(),
                other: c.len(),
            });
        }
        data.extend_from_slice(&[0.0; 3]);
        data.extend(c.iter().flat_map(|p| p.to_array()));
    }
    Ok(Some((data, poses)))
}

/// The clearance term the selection weights (`selection.clearance`) from its settings.
pub(super) fn selection_clearance(settings: &Human2NavSettings) -> Clearance {
    let sel = &settings.selection;
    Clearance {
        margin: sel.margin,
        collision: sel.collision,
        hold: steps(sel.hold, settings.dt),
        arrival: (sel.progress != Progress::End).then_some(sel.arrival),
    }
}

/// Φ's context at a planning instant: the plan step, the robot's limits, its velocity, the
/// nearby pedestrians and the scene (a free function so that it borrows fields, not the whole
/// planner).
pub(super) fn phi_context<'a>(
    dt: f64,
    limits: &'a Limits,
    obs: &Observation,
    agents: &'a [AgentState],
    scene: SceneContext<'a>,
) -> ConstraintContext<'a> {
    ConstraintContext {
        dt,
        limits,
        initial_velocity: obs.ego_velocity,
        agents,
        scene,
    }
}
