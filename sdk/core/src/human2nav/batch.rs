//! Planning for several planners at once ([`Human2Nav::plan_batch`]): the flow model's
//! sampling of every planner runs in lockstep, one batched network call per integration step
//! for all of them, and each planner then plans as it would alone, its network calls answered
//! from those batched velocities ([`Replay`]).
//!
//! The answers are looked up by exact input, flow time and condition, so a planner whose own
//! sampling asks for anything else (a deadline cut it differently, Algorithm 1's pull-backs)
//! gets it from its model as usual: batching changes where the velocities are computed, never
//! which ones a plan uses.

use super::settings::budget_deadline;
use super::{Human2Nav, Prepared};
use crate::flow::{CrowdGuidance, FlowCondition, FlowError, FlowModel, FlowQuery};
use crate::guidance::{euler_advance, flow_time};
use crate::planner::{Deadline, Observation, Plan, PlanError};

/// Flow velocities computed for a planner by a batched call, answered in place of its model.
#[derive(Debug, Default)]
pub(super) struct Replay {
    /// The conditions the answers were computed under: the call's, and with crowd guidance its
    /// copy without the crowd.
    conds: Vec<FlowCondition>,
    answers: Vec<Answer>,
}

#[derive(Debug)]
struct Answer {
    cond: usize,
    /// Bits of the flow time.
    t: u64,
    x: Vec<f64>,
    v: Vec<f64>,
}

impl Replay {
    /// Drops the answers (at the end of every planning call).
    pub(super) fn clear(&mut self) {
        self.conds.clear();
        self.answers.clear();
    }

    fn answer(&self, x: &[f64], t: f64, cond: &FlowCondition) -> Option<&[f64]> {
        let t = t.to_bits();
        self.answers
            .iter()
            .find(|a| a.t == t && a.x == x && self.conds[a.cond] == *cond)
            .map(|a| a.v.as_slice())
    }
}

/// A planner's model with its [`Replay`] in front.
pub(super) struct Replayed<'a, M> {
    model: &'a M,
    replay: &'a Replay,
}

impl<'a, M> Replayed<'a, M> {
    pub(super) fn new(model: &'a M, replay: &'a Replay) -> Self {
        Self { model, replay }
    }
}

impl<M: FlowModel> FlowModel for Replayed<'_, M> {
    fn horizon(&self) -> usize {
        self.model.horizon()
    }

    fn source_std(&self) -> [f64; 3] {
        self.model.source_std()
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        match self.replay.answer(x, t, cond) {
            Some(v) if v.len() == out.len() => {
                out.copy_from_slice(v);
                Ok(())
            }
            _ => self.model.velocity(x, t, cond, out),
        }
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        self.model.velocity_vjp(x, t, cond, cotangent, out, vjp)
    }

    fn velocity_batch(&self, queries: &[FlowQuery<'_>], out: &mut [f64]) -> Result<(), FlowError> {
        self.model.velocity_batch(queries, out)
    }

    fn network_id(&self) -> Option<usize> {
        self.model.network_id()
    }
}

/// One planner's rollout in the batched sampling.
struct Member {
    /// Index among the planners.
    planner: usize,
    x: Vec<f64>,
    /// The velocity of the current step (crowd guidance combined).
    v: Vec<f64>,
    next: Vec<f64>,
    w: Vec<f64>,
    zero: Vec<f64>,
    steps: usize,
    guidance: CrowdGuidance<()>,
    /// Still stepping in lockstep.
    active: bool,
}

impl<M: FlowModel> Human2Nav<M> {
    /// Plans for several planners at once, planner `i` on `observations[i]`: the flow model's
    /// sampling of all of them runs as one batch (one network call per integration step for
    /// every planner's `K` samples), then each plans on from its samples as [`Planner::plan`]
    /// does. Each plan is the one `planners[i].plan(&observations[i])` returns, bit for bit,
    /// with the same state carried to the next call (warm start, generator). Batching saves
    /// network calls, not arithmetic: on a CPU the native backend plans no faster this way
    /// (docs/experiments/2026-12-07-batch-planning.md); an accelerator, where a call costs
    /// more than its rows, is what it is for.
    ///
    /// Planners share a batch when their models run the same network
    /// ([`FlowModel::network_id`]: clones of one native model, e.g. one robot planner per
    /// robot or episode, all loaded from one model folder); a planner with a model of its own
    /// samples alone. Each planner's budget (`budget_ms`) starts with the call; a planner
    /// whose deadline passes drops out of the batch and its own sampling handles the cut. An
    /// invalid observation is an error for its planner alone. Algorithm 1, when enabled,
    /// runs per planner after the batched sampling.
    ///
    /// Fails only when the two slices differ in length.
    ///
    /// [`Planner::plan`]: crate::planner::Planner::plan
    pub fn plan_batch(
        planners: &mut [&mut Self],
        observations: &[Observation],
    ) -> Result<Vec<Result<Plan, PlanError>>, PlanError> {
        if planners.len() != observations.len() {
            return Err(PlanError::InvalidSettings(format!(
                "plan_batch: {} planners for {} observations",
                planners.len(),
                observations.len()
            )));
        }
        let deadlines: Vec<Deadline> = planners
            .iter()
            .map(|p| budget_deadline(p.settings.budget_ms).unwrap_or_else(|_| Deadline::never()))
            .collect();
        // As `plan_within` begins: the observation checked, the start warnings, the inputs.
        let started: Vec<Result<(Prepared, Vec<String>), PlanError>> = planners
            .iter_mut()
            .zip(observations)
            .map(|(p, obs)| {
                obs.validate()?;
                let warnings = p.start_warnings(obs);
                Ok((p.prepare(obs), warnings))
            })
            .collect();
        let prepared: Vec<Option<&Prepared>> = started
            .iter()
            .map(|s| s.as_ref().ok().map(|(p, _)| p))
            .collect();
        sample_batched(planners, &prepared, &deadlines);
        let mut results = Vec::with_capacity(started.len());
        for (i, s) in started.into_iter().enumerate() {
            results.push(s.map(|(prepared, warnings)| {
                let (p, obs) = (&mut planners[i], &observations[i]);
                let result = p.try_plan_prepared(obs, prepared, &deadlines[i]);
                p.conclude(obs, result, warnings)
            }));
        }
        Ok(results)
    }
}

/// Runs the sampling of every prepared planner with samples, grouped by network, in lockstep,
/// and leaves each planner's velocities in its [`Replay`].
fn sample_batched<M: FlowModel>(
    planners: &mut [&mut Human2Nav<M>],
    prepared: &[Option<&Prepared>],
    deadlines: &[Deadline],
) {
    let mut groups: Vec<(usize, Vec<usize>)> = Vec::new();
    for (i, p) in planners.iter().enumerate() {
        let samples = prepared[i].is_some_and(|p| !p.x0.is_empty());
        let Some(id) = p.model.network_id().filter(|_| samples) else {
            continue;
        };
        match groups.iter_mut().find(|(g, _)| *g == id) {
            Some((_, members)) => members.push(i),
            None => groups.push((id, vec![i])),
        }
    }
    for (_, members) in groups.into_iter().filter(|(_, m)| m.len() > 1) {
        sample_group(planners, prepared, deadlines, &members);
    }
}

/// [`sample_batched`] for planners whose models run one network (`members`, at least two).
fn sample_group<M: FlowModel>(
    planners: &mut [&mut Human2Nav<M>],
    prepared: &[Option<&Prepared>],
    deadlines: &[Deadline],
    members: &[usize],
) {
    let mut rollouts: Vec<Member> = Vec::new();
    for &i in members {
        let (Some(p), planner) = (prepared[i], &mut planners[i]) else {
            continue;
        };
        let weight = planner.settings.crowd_weight;
        planner.replay.clear();
        planner.replay.conds.push(p.cond.clone());
        if weight != 1.0 {
            planner
                .replay
                .conds
                .push(CrowdGuidance::<()>::empty(&p.cond));
        }
        rollouts.push(Member {
            planner: i,
            x: p.x0.clone(),
            v: vec![0.0; p.x0.len()],
            next: vec![0.0; p.x0.len()],
            w: vec![0.0; p.x0.len()],
            zero: vec![0.0; p.x0.len()],
            steps: planner.settings.guidance.steps_n,
            guidance: CrowdGuidance { model: (), weight },
            active: true,
        });
    }
    let Some(&first) = members.first() else {
        return;
    };
    let mut out = Vec::new();
    for step in 0.. {
        for r in &mut rollouts {
            r.active &= step < r.steps && !deadlines[r.planner].passed();
        }
        if !rollouts.iter().any(|r| r.active) {
            break;
        }
        // The queries of this step: each active planner's samples, and their crowd-free copy
        // under crowd guidance (condition 1 of its replay).
        let mut queries = Vec::new();
        let mut owners = Vec::new();
        for (m, r) in rollouts.iter().enumerate().filter(|(_, r)| r.active) {
            let t = flow_time(step, r.steps);
            for (c, cond) in planners[r.planner].replay.conds.iter().enumerate() {
                queries.push(FlowQuery { x: &r.x, t, cond });
                owners.push((m, c));
            }
        }
        out.clear();
        out.resize(queries.iter().map(|q| q.x.len()).sum(), 0.0);
        if planners[first]
            .model
            .velocity_batch(&queries, &mut out)
            .is_err()
        {
            // Each planner's own call reports the failure.
            return;
        }
        drop(queries);
        let mut at = 0;
        for &(m, c) in &owners {
            let r = &mut rollouts[m];
            let v = &out[at..at + r.x.len()];
            at += r.x.len();
            planners[r.planner].replay.answers.push(Answer {
                cond: c,
                t: flow_time(step, r.steps).to_bits(),
                x: r.x.clone(),
                v: v.to_vec(),
            });
            // The crowd-free velocity (condition 1) follows the conditional one.
            if c == 0 {
                r.v.copy_from_slice(v);
            } else {
                r.guidance.combine(&mut r.v, v);
            }
        }
        for r in rollouts.iter_mut().filter(|r| r.active) {
            if !r.v.iter().all(|a| a.is_finite()) {
                r.active = false;
                continue;
            }
            euler_advance(
                &r.x,
                &r.v,
                &r.zero,
                1.0 / r.steps as f64,
                &mut r.w,
                &mut r.next,
            );
            std::mem::swap(&mut r.x, &mut r.next);
            r.active &= r.x.iter().all(|a| a.is_finite());
        }
    }
}
