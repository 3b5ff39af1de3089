//! The reference Human2Nav planner: flow-model sampling, feasibility guidance (Algorithm 1) and
//! candidate selection behind the [`Planner`] trait.
//!
//! One planning call:
//! 1. validates the [`Observation`] and builds the condition in the **ego frame** of the
//!    planning instant: the BEV raster of the other agents ([`crate::bev`]), the goal (clipped
//!    to [`Human2NavSettings::goal_clip`], the range of goals seen in training) and the ego's
//!    body velocity;
//! 2. draws `K` source samples `x0 = exp(ξ0)`, `ξ0 ~ N(0, diag(σ²))` with `σ` from
//!    [`FlowModel::source_std`], and integrates them in one batch ([`guidance::sample`]);
//! 3. shortlists the [`Human2NavSettings::guided_samples`] best samples by the selection score
//!    without its feasibility term (`0`: all of them go on); with Algorithm 1 on
//!    (`guidance.enabled`) runs it on them, continuing from their rollout
//!    ([`guidance::guide_subset`]); adds their slowed copies, the stop and goal candidates and
//!    the warm-start candidate as their settings allow; with the correction on
//!    (`projection.enabled`) applies the exact last-step correction ([`crate::projection`]) to
//!    all of these; then adds the robot's own motions (`motions`). Guiding a shortlist instead
//!    of all `K` samples divides the cost of the `M` iterations (a forward and a
//!    vector-Jacobian product through the network per integration step) by
//!    `K / guided_samples`; the paper variant of Algorithm 1
//!    ([`guidance::GuidanceVariant::Paper`]) guides all of them whatever `guided_samples` says;
//! 4. scores every candidate (and the previous plan, shifted to the current time: the warm
//!    start of receding-horizon use) and keeps the lowest score (see [`SelectionWeights`]);
//!    Φ is left out where the score without it already loses, which changes no choice
//!    (branch and bound, `selection.rs`);
//! 5. returns the plan in the world frame: the current pose followed by the `T` future poses at
//!    `dt` = [`Human2NavSettings::dt`].
//!
//! Every stage but sampling and selection has its own switch; [`crate::ablation::Arm`] names
//! the combinations the guidance ablation compares (`raw`: the `K` samples as they come).
//!
//! # Selection rule
//! `score = w_feas·(1 − TFS) + w_goal·d/d_0 + w_Φ·Φ + w_cons·D`, where TFS is the
//! trajectory feasibility score of the candidate ([`crate::feasibility`]), `d/d_0` the candidate's
//! closest approach to the (clipped) goal relative to the current distance (0 once within
//! [`SelectionWeights::arrival`]; [`Progress`] also offers the distance at its end and how
//! soon it could arrive; [`SelectionWeights::lookahead`] scores each candidate continued past
//! its end), `D` the mean distance (m) to the previous plan at the same times (0 without one),
//! and Φ the robot's cost ([`RobotModel::phi`], the paper's Eq. 9) of the candidate with the
//! robot's pose prepended: its built-in soft-limit terms, its plugin terms, and the built-in
//! clearance term ([`Clearance`], weight [`SelectionWeights::clearance`]): the mean over
//! waypoints of `max(0, margin − gap)²/margin²` with `gap` the distance between the robot's
//! footprint (its shapes at the waypoint's pose, [`RobotModel::footprint`]) and each agent's
//! disc, agents predicted at constant velocity (or by the planner's [`CrowdPredictor`], when
//! it has one: then the expectation over the scenes of its [`Forecast`]), and each static
//! obstacle of the observation ([`crate::obstacle`]: circles, polygons, segments and the
//! occupied cells of its grid), where the first waypoint with a predicted overlap and every
//! one after it count [`SelectionWeights::collision`] instead (a collision ends the plan: the
//! earlier, the worse), and the waypoints after the candidate's arrival are not checked. Φ
//! is the cost Algorithm 1 descends too: one definition steers samples and chooses among
//! candidates. A term that fails or answers a non-finite value stops the robot in place with
//! [`PlanInfo::error`] naming it.
//!
//! Besides the guided samples, the selection sees each of them at
//! [`Human2NavSettings::slowdown`] of its speed along the same path and a "stop" candidate, all
//! through the last-step correction: the model proposes where people walk, not when to wait
//! for one to pass, and in the benchmark's counter- and co-flows the robot otherwise drove into
//! pedestrians it had predicted. Within [`Human2NavSettings::goal_approach`] of the goal it
//! also sees "straight to the goal" ([`goal_approach`]): the model, trained on goals metres
//! away, walks past one that close, and the robot circled it until its time ran out. With
//! [`Human2NavSettings::motions`] it also sees that many of the robot's own motions
//! ([`crate::motions`]: backing off, sidestepping, turning away, waiting), which are within the
//! limits as they are and skip the correction: the model proposes ways forward among people,
//! rarely a way out of someone's path.
//!
//! # Planning under a deadline
//! [`Planner::plan_within`] (or [`Planner::plan`] with [`Human2NavSettings::budget_ms`] set)
//! is anytime: the stages run in order (sampling, Algorithm 1, the last-step correction) and
//! none starts a network call after the [`Deadline`], so a call returns at most one network
//! call (about 1–2 ms with the native backend) plus two small QPs past it. What was cut:
//! * sampling: the remaining integration steps continue at the last velocity (module docs of
//!   [`guidance`], "Deadlines"); with no step at all there are no samples;
//! * Algorithm 1: the last completed iteration is kept, or none runs if sampling was cut;
//! * the correction: only the stop and previous-plan candidates are corrected once the
//!   deadline has passed (a stop candidate is added if it is off), and an uncorrected
//!   candidate never wins over a corrected one, so the plan is feasible: the best corrected
//!   candidate or braking to a stop.
//!
//! [`PlanInfo::stages`] says how far each stage got and which one the deadline cut short.
//! Without the correction (`projection.enabled = false`) a call cut before its first
//! integration step keeps the previous plan or falls back to stopping in place.
//!
//! # Safe fallback
//! A planner never returns a non-finite number. If the flow model or guidance fails, or every
//! candidate is non-finite, the plan is "stop in place" ([`Plan::stop_in_place`]) with
//! `info.fallback = true` and the reason in `info.notes`. An invalid observation (a non-finite
//! input) is an error instead, because the caller must fix it.

use std::borrow::Cow;

use crate::bev::{self, BevSpec};
use crate::constraint::{
    Clearance, ConstraintContext, ConstraintError, Phi, PhiScratch, SceneContext, TrajBatch,
    arrival, closest_distance,
};
use crate::feasibility;
use crate::flow::{CrowdGuidance, FlowCondition, FlowModel};
use crate::forecast::{CrowdPredictor, Forecast};
use crate::guidance::{
    self, GuidanceError, GuidanceResult, GuidanceSettings, GuidanceVariant, GuidanceWorkspace,
};
use crate::limits::Limits;
use crate::motions::{GridLevels, MotionGrid};
use crate::obstacle::Obstacle;
use crate::planner::{
    AgentState, Deadline, Observation, Plan, PlanError, PlanInfo, Planner, Stage, StageProgress,
    Stages,
};
use crate::projection::{self, ProjectionSettings};
use crate::robot::footprint::{self, FootprintShape};
use crate::se2::{Pose2, Twist2};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

mod batch;
mod candidates;
mod inputs;
mod selection;
mod settings;
#[cfg(test)]
mod tests;

use batch::{Replay, Replayed};
use candidates::Source;
pub use candidates::{continued, goal_approach, time_scaled};
use selection::{phi_context, selection_clearance};
pub use settings::{
    COLLISION_PENALTY, GuidanceTerms, Human2NavSettings, MAX_BUDGET_MS, MAX_CROWD_WEIGHT,
    MAX_HOLD_S, MAX_MOTIONS, MAX_SAMPLES, MOTION_SWITCH_S, Progress, SelectionWeights,
    budget_deadline,
};

/// What the planner needs to know about the robot.
#[derive(Debug)]
pub struct RobotModel {
    /// The robot's hard limits (TFS and selection).
    pub limits: Limits,
    /// The footprint the selection predicts contacts with, placed at each plan pose
    /// ([`RobotProfile::footprint_shapes`](crate::robot::RobotProfile::footprint_shapes));
    /// at least one shape.
    pub footprint: Vec<FootprintShape>,
    /// Φ: the profile's built-in terms plus any plugin terms.
    pub phi: Phi,
}

/// A starting velocity above this multiple of a limit is flagged in [`PlanInfo::warnings`]
/// (below it, tracking overshoot is ordinary).
pub const LIMIT_WARNING_FACTOR: f64 = 1.1;

/// The reference planner. Generic over the flow model so it runs with the libtorch network or
/// an analytic field alike.
pub struct Human2Nav<M> {
    name: String,
    model: M,
    robot: RobotModel,
    /// What Algorithm 1 descends: `robot.phi`, or its scene terms ([`GuidanceTerms`]).
    guidance_phi: Option<Phi>,
    bev: BevSpec,
    settings: Human2NavSettings,
    rng: ChaCha8Rng,
    workspace: GuidanceWorkspace,
    /// The last-step correction's QP solver, kept from call to call.
    projection: projection::ProjectionSolver,
    previous: Option<Plan>,
    raster: Vec<f32>,
    /// The static obstacles near the robot in the ego frame of the current call (explicit ones
    /// and occupied grid cells), for the selection.
    obstacles: Vec<Obstacle>,
    /// The robot's own motions offered to the selection ([`Human2NavSettings::motions`]).
    motion_grid: MotionGrid,
    /// [`footprint::reach`] of the robot's footprint.
    reach: f64,
    /// Where the selection expects people to go; `None`: constant velocity.
    predictor: Option<Box<dyn CrowdPredictor>>,
    /// The flow velocities [`Self::plan_batch`] computed for this planner's current call.
    replay: Replay,
}

impl<M> std::fmt::Debug for Human2Nav<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Human2Nav")
            .field("name", &self.name)
            .field("settings", &self.settings)
            .finish_non_exhaustive()
    }
}

impl<M: FlowModel> Human2Nav<M> {
    /// A planner named `human2nav`. The built-in clearance term ([`Clearance`], weighted by
    /// [`SelectionWeights::clearance`]) joins the robot's Φ.
    pub fn new(
        model: M,
        robot: RobotModel,
        bev: BevSpec,
        settings: Human2NavSettings,
    ) -> Result<Self, PlanError> {
        settings.validate()?;
        bev.validate()
            .map_err(|e| PlanError::InvalidSettings(format!("bev: {e}")))?;
        if robot.footprint.is_empty() {
            return Err(PlanError::InvalidSettings(
                "the robot model has no footprint shape".into(),
            ));
        }
        if model.horizon() == 0 {
            return Err(PlanError::InvalidSettings(
                "flow model has a horizon of 0 poses".into(),
            ));
        }
        let mut robot = robot;
        let sel = &settings.selection;
        let clearance = selection_clearance(&settings);
        clearance
            .validate()
            .and_then(|()| robot.phi.push(sel.clearance, Box::new(clearance)))
            .map_err(|e| PlanError::InvalidSettings(format!("human2nav.selection: {e}")))?;
        Ok(Self {
            name: "human2nav".to_string(),
            raster: vec![0.0; bev.len()],
            obstacles: Vec::new(),
            rng: ChaCha8Rng::seed_from_u64(settings.seed),
            motion_grid: MotionGrid::new(robot.limits, GridLevels::default()),
            reach: footprint::reach(&robot.footprint),
            model,
            guidance_phi: match settings.guidance_terms {
                GuidanceTerms::All => None,
                GuidanceTerms::Scene => Some(robot.phi.without_limits()),
            },
            robot,
            bev,
            settings,
            workspace: GuidanceWorkspace::new(),
            projection: projection::ProjectionSolver::default(),
            previous: None,
            predictor: None,
            replay: Replay::default(),
        })
    }

    /// The same planner with its selection scoring candidates against `predictor`'s forecasts
    /// instead of constant velocity ([`crate::forecast`]; a forecast of several scenes is
    /// scored as the mean over them). A call whose forecast fails falls back to constant
    /// velocity and says so in its plan's notes. The forecast is made first in a call and is
    /// not cut short by a deadline: its cost comes on top of the stages a budget governs.
    pub fn with_predictor(mut self, predictor: Box<dyn CrowdPredictor>) -> Self {
        self.predictor = Some(predictor);
        self
    }

    /// The predictor in use, if any ([`Self::with_predictor`]).
    pub fn predictor(&self) -> Option<&dyn CrowdPredictor> {
        self.predictor.as_deref()
    }

    /// The settings in force.
    pub fn settings(&self) -> &Human2NavSettings {
        &self.settings
    }

    /// The flow model the planner samples from.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// Plans within `deadline`, returning the plan or the reason the flow stage failed (for
    /// [`Planner::plan_within`], which turns such failures into the stop-in-place fallback).
    fn try_plan(&mut self, obs: &Observation, deadline: &Deadline) -> Result<Plan, StageError> {
        let prepared = self.prepare(obs);
        self.try_plan_prepared(obs, prepared, deadline)
    }

    /// What a planning call computes before the flow model runs: the condition, the agents in
    /// the ego frame, the forecast, the obstacles near the robot (kept in `self.obstacles`), the
    /// source samples (drawn from the planner's generator) and the warm start.
    fn prepare(&mut self, obs: &Observation) -> Prepared {
        let horizon = self.model.horizon();
        let (cond, agents) = self.condition(obs);
        let mut notes = Vec::new();
        let ahead = self.lookahead_steps();
        let forecast = self.forecast(
            obs,
            &agents,
            horizon + ahead + self.hold_steps(),
            &mut notes,
        );
        self.obstacles = self.nearby_obstacles(obs, horizon + ahead);
        let x0 = self.draw_source(self.settings.samples, horizon);
        let warm = if self.settings.warm_start {
            self.shifted_previous(obs, horizon)
        } else {
            None
        };
        Prepared {
            cond,
            agents,
            notes,
            forecast,
            x0,
            warm,
        }
    }

    /// [`Self::try_plan`] from its [`Self::prepare`]d inputs.
    ///
    /// A little over 120 lines: stage 2 fills half a dozen locals the selection and the plan's
    /// diagnostics read (candidates, their origin, Φ, the corrected flags, stages, notes);
    /// splitting it further would pass all of them back and forth.
    fn try_plan_prepared(
        &mut self,
        obs: &Observation,
        prepared: Prepared,
        deadline: &Deadline,
    ) -> Result<Plan, StageError> {
        let horizon = self.model.horizon();
        let k = self.settings.samples;
        let Prepared {
            cond,
            agents,
            mut notes,
            forecast,
            x0,
            warm,
        } = prepared;
        let goal = cond.goal;
        let previous_ego = warm.as_deref();
        let guidance = self.settings.guidance;
        let mut stages = Stages {
            sampling: StageProgress {
                done: 0,
                planned: guidance.steps_n,
            },
            ..Stages::default()
        };

        // Stage 1: the K samples of the flow model, without guidance (Φ for diagnostics).
        let first = if k == 0 {
            stages.sampling.planned = 0;
            None
        } else {
            self.sample_stage(
                obs,
                &cond,
                &x0,
                &agents,
                &forecast,
                deadline,
                &mut stages,
                &mut notes,
            )?
        };
        let unguided: Vec<Vec<Pose2>> = first
            .as_ref()
            .map(|f| (0..k).map(|i| f.unguided_poses(i)).collect())
            .unwrap_or_default();
        let phi_unguided: Vec<(f64, f64)> = first
            .as_ref()
            .map(|f| f.phi_before.iter().map(|&p| (p, p)).collect())
            .unwrap_or_default();

        // The samples that go on: the shortlist (all of them unless `guided_samples` says
        // fewer), guided by Algorithm 1 when it is on and time is left.
        let shortlist = if unguided.is_empty() {
            Vec::new()
        } else {
            let ctx = self.phi_context(obs, &agents, &forecast, goal);
            self.shortlist(&unguided, goal, &ctx, obs.ego_velocity, previous_ego)?
        };
        let mut candidates: Vec<Vec<Pose2>>;
        let phi: Vec<(f64, f64)>;
        let mut guidance_iterations = None;
        if guidance.enabled && !shortlist.is_empty() && stages.cut_short.is_none() {
            stages.guidance.planned = guidance.iterations_m;
            let guided = self.guide_stage(
                obs,
                &cond,
                &agents,
                &forecast,
                &shortlist,
                deadline,
                &mut stages,
                &mut notes,
            )?;
            guidance_iterations = Some(guided.iterations_run);
            candidates = (0..shortlist.len())
                .map(|j| guided.guided_poses(j))
                .collect();
            phi = guided
                .phi_before
                .iter()
                .copied()
                .zip(guided.phi_after.iter().copied())
                .collect();
        } else {
            candidates = shortlist.iter().map(|&i| unguided[i].clone()).collect();
            phi = shortlist.iter().map(|&i| phi_unguided[i]).collect();
        }
        let mut origin: Vec<Source> = shortlist.iter().map(|&i| Source::Sample(i)).collect();
        self.push_extra_candidates(
            &shortlist,
            goal,
            horizon,
            warm.as_ref(),
            &mut candidates,
            &mut origin,
        );
        // Which candidates the last-step correction made feasible (empty when it did not run).
        let mut corrected: Vec<bool> = Vec::new();
        if self.settings.projection.enabled {
            corrected = self.correct(
                &mut candidates,
                &mut origin,
                obs.ego_velocity,
                deadline,
                &mut stages,
                &mut notes,
            );
        }
        // The robot's own motions are within its limits as they are: no correction. Not
        // after the deadline: scoring them takes milliseconds. As a recovery, only when no
        // model candidate the selection may choose is free of predicted contact.
        let recover = || -> Result<bool, StageError> {
            if !self.settings.motions_recovery {
                return Ok(true);
            }
            let any_corrected = corrected.contains(&true);
            let model: Vec<Vec<Pose2>> = candidates
                .iter()
                .zip(&origin)
                .enumerate()
                .filter(|(i, (_, o))| {
                    o.sample().is_some() && (!any_corrected || corrected.get(*i) == Some(&true))
                })
                .map(|(_, (c, _))| c.clone())
                .collect();
            let ctx = self.phi_context(obs, &agents, &forecast, goal);
            let free = self.contact_free(&self.scored(&model), &ctx)?;
            Ok(!free.contains(&true))
        };
        if stages.cut_short.is_none() && !deadline.passed() && recover()? {
            self.push_motions(obs.ego_velocity, horizon, &mut candidates, &mut origin);
        }
        if !corrected.is_empty() {
            corrected.resize(candidates.len(), true);
        }

        // Stage 3: selection by the score with Φ (Φ only where it can change the choice).
        let scored = self.scored(&candidates);
        let ctx = self.phi_context(obs, &agents, &forecast, goal);
        let best = self.select(
            &scored,
            &corrected,
            &ctx,
            goal,
            obs.ego_velocity,
            previous_ego,
        )?;
        let Some(chosen) = best else {
            return Err(StageError::NoCandidate {
                deadline: candidates.is_empty(),
            });
        };
        Ok(self.assemble_plan(
            obs,
            Chosen {
                candidates: &candidates,
                origin: &origin,
                phi: &phi,
                index: chosen,
            },
            &unguided,
            guidance_iterations,
            notes,
            stages,
        ))
    }

    /// Stage 1 of [`Self::try_plan`]: the flow model's samples from `x0` without guidance, or
    /// `None` when the deadline passed before sampling began; progress and deadline cuts go
    /// into `stages` and `notes`.
    fn sample_stage(
        &mut self,
        obs: &Observation,
        cond: &FlowCondition,
        x0: &[f64],
        agents: &[AgentState],
        forecast: &Forecast,
        deadline: &Deadline,
        stages: &mut Stages,
        notes: &mut Vec<String>,
    ) -> Result<Option<GuidanceResult>, StageError> {
        let guidance = self.settings.guidance;
        let scene = SceneContext {
            forecast: Some(forecast),
            obstacles: &self.obstacles,
            footprint: &self.robot.footprint,
            goal: Some(cond.goal),
        };
        let ctx = phi_context(self.settings.dt, &self.robot.limits, obs, agents, scene);
        let plain = GuidanceSettings {
            enabled: false,
            ..guidance
        };
        Ok(
            match guidance::sample_guided_until(
                &CrowdGuidance {
                    model: Replayed::new(&self.model, &self.replay),
                    weight: self.settings.crowd_weight,
                },
                cond,
                x0,
                &self.robot.phi,
                &ctx,
                &plain,
                &mut self.workspace,
                deadline,
            ) {
                Ok(first) => {
                    stages.sampling.done = first.steps_run;
                    if first.cut_short {
                        stages.cut_short = Some(Stage::Sampling);
                        notes.push(format!(
                            "deadline: sampling stopped after {} of {} integration steps",
                            first.steps_run, guidance.steps_n
                        ));
                    }
                    Some(first)
                }
                Err(GuidanceError::DeadlineBeforeSampling) => {
                    stages.cut_short = Some(Stage::Sampling);
                    notes.push("deadline: it passed before sampling began".into());
                    None
                }
                Err(e) => return Err(StageError::Sampling(e)),
            },
        )
    }

    /// Algorithm 1 of [`Self::try_plan`]'s stage 2 on the `shortlist` of samples; progress and
    /// deadline cuts go into `stages` and `notes`.
    fn guide_stage(
        &mut self,
        obs: &Observation,
        cond: &FlowCondition,
        agents: &[AgentState],
        forecast: &Forecast,
        shortlist: &[usize],
        deadline: &Deadline,
        stages: &mut Stages,
        notes: &mut Vec<String>,
    ) -> Result<GuidanceResult, StageError> {
        let guidance = self.settings.guidance;
        let scene = SceneContext {
            forecast: Some(forecast),
            obstacles: &self.obstacles,
            footprint: &self.robot.footprint,
            goal: Some(cond.goal),
        };
        let ctx = phi_context(self.settings.dt, &self.robot.limits, obs, agents, scene);
        let result = guidance::guide_subset_until(
            &CrowdGuidance {
                model: Replayed::new(&self.model, &self.replay),
                weight: self.settings.crowd_weight,
            },
            cond,
            shortlist,
            self.guidance_phi.as_ref().unwrap_or(&self.robot.phi),
            &ctx,
            &guidance,
            &mut self.workspace,
            deadline,
        )
        .map_err(StageError::Guidance)?;
        stages.guidance.done = result.iterations_run;
        if result.cut_short {
            stages.cut_short = Some(Stage::Guidance);
            notes.push(format!(
                "deadline: guidance stopped after {} iterations",
                result.iterations_run
            ));
        }
        Ok(result)
    }

    /// The plan a call returns from what [`Self::try_plan`] gave: the plan if finite, else
    /// stopping in place with the reason; the start `warnings` added, the plan kept for the
    /// warm start and the batched velocities of [`Self::plan_batch`] dropped.
    fn conclude(
        &mut self,
        obs: &Observation,
        result: Result<Plan, StageError>,
        warnings: Vec<String>,
    ) -> Plan {
        let mut plan = match result {
            Ok(plan) if plan.is_finite() => plan,
            Ok(_) => Plan::stop_in_place(
                obs,
                self.settings.dt,
                self.model.horizon() + 1,
                "the selected plan was not finite",
            ),
            Err(failure) => {
                let why = failure.to_string();
                let mut plan =
                    Plan::stop_in_place(obs, self.settings.dt, self.model.horizon() + 1, &why);
                // A term of Φ that fails is a broken extension, not the planner's own
                // fallback: callers count the call as failed (the benchmark records it).
                plan.info.error = failure.is_term().then_some(why);
                plan
            }
        };
        plan.info.warnings = warnings;
        self.previous = (!plan.info.fallback).then(|| plan.clone());
        self.replay.clear();
        plan
    }

    /// The plan of the chosen candidate in the world frame, with its diagnostics: the samples
    /// before and after guidance, Φ of the kept sample and the notes.
    fn assemble_plan(
        &self,
        obs: &Observation,
        chosen: Chosen<'_>,
        unguided: &[Vec<Pose2>],
        guidance_iterations: Option<usize>,
        mut notes: Vec<String>,
        stages: Stages,
    ) -> Plan {
        let Chosen {
            candidates,
            origin,
            phi,
            index: chosen,
        } = chosen;
        let dt = self.settings.dt;
        let to_world = |traj: &[Pose2]| -> Vec<Pose2> {
            std::iter::once(obs.ego)
                .chain(traj.iter().map(|p| obs.ego.compose(*p)))
                .collect()
        };
        // Φ before and after Algorithm 1 of the sample whose path is kept (`phi` is in the
        // order of the first candidates: the shortlist).
        let sample_pos = |i: usize| {
            origin
                .iter()
                .position(|o| *o == Source::Sample(i))
                .and_then(|j| phi.get(j))
        };
        let (phi_before, phi_after) = match origin[chosen].sample().and_then(sample_pos) {
            Some(&(b, a)) => (Some(b), Some(a)),
            None => (None, None),
        };
        match origin[chosen] {
            Source::Sample(_) => {}
            Source::Slowed(i) => notes.push(format!(
                "sample {i} at {} % of its speed",
                100.0 * self.settings.slowdown
            )),
            Source::Stop => notes.push("braking to a stop".into()),
            Source::Goal => notes.push("straight to the goal".into()),
            Source::Previous => notes.push("kept the previous plan".into()),
            Source::Motion => notes.push("one of the robot's own motions".into()),
        }
        let guided: Vec<Vec<Pose2>> = if guidance_iterations.is_some() {
            candidates
                .iter()
                .zip(origin)
                .filter(|(_, o)| matches!(o, Source::Sample(_)))
                .map(|(c, _)| to_world(c))
                .collect()
        } else {
            Vec::new()
        };
        let info = PlanInfo {
            candidates: unguided.iter().map(|c| to_world(c)).collect(),
            guided,
            selected: origin[chosen].sample(),
            phi_before,
            phi_after,
            guidance_iterations,
            fallback: false,
            notes,
            error: None,
            stages: Some(stages),
            warnings: Vec::new(),
        };
        Plan {
            t0: obs.time,
            dt,
            poses: to_world(&candidates[chosen]),
            info,
        }
    }
}

/// The inputs of a planning call up to the flow model ([`Human2Nav::prepare`]).
struct Prepared {
    cond: FlowCondition,
    agents: Vec<AgentState>,
    notes: Vec<String>,
    forecast: Forecast,
    /// The `K` source samples, flat `[K, T, 3]`.
    x0: Vec<f64>,
    /// The previous plan shifted to now, in the ego frame (with `warm_start`).
    warm: Option<Vec<Pose2>>,
}

/// The candidates of a planning call, where each came from, the Φ before and after
/// Algorithm 1 of the first ones, and the index of the one selected.
struct Chosen<'a> {
    candidates: &'a [Vec<Pose2>],
    origin: &'a [Source],
    phi: &'a [(f64, f64)],
    index: usize,
}

/// Why a planning call stopped in place instead of planning: the stage that failed. A
/// failure of a term of Φ (`is_term`) is a broken extension, which callers count as
/// a failed call; the others are the planner's own fallback.
#[derive(Debug)]
enum StageError {
    /// Stage 1: sampling the flow model.
    Sampling(GuidanceError),
    /// Stage 2: Algorithm 1 on the shortlist.
    Guidance(GuidanceError),
    /// Scoring the candidates with Φ (a term failed or answered a non-finite cost).
    Phi(ConstraintError),
    /// The recovery's test of the model's candidates for predicted contact.
    Contact(ConstraintError),
    /// Candidates of different lengths cannot be scored together.
    Lengths { first: usize, other: usize },
    /// The candidates did not make one batch of poses.
    Batch(ConstraintError),
    /// Nothing to choose from: the deadline passed before sampling began and there was no
    /// previous plan (`deadline`), or every candidate was non-finite.
    NoCandidate { deadline: bool },
}

impl StageError {
    /// Whether a term of Φ failed (in sampling, Algorithm 1 or the selection).
    fn is_term(&self) -> bool {
        match self {
            Self::Sampling(e) | Self::Guidance(e) => matches!(e, GuidanceError::Constraint(_)),
            Self::Phi(_) => true,
            Self::Contact(_) | Self::Lengths { .. } | Self::Batch(_) | Self::NoCandidate { .. } => {
                false
            }
        }
    }
}

impl std::fmt::Display for StageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Sampling(e) => write!(f, "sampling failed: {e}"),
            Self::Guidance(e) => write!(f, "guidance failed: {e}"),
            Self::Phi(e) => write!(f, "scoring the candidates with Φ: {e}"),
            Self::Contact(e) | Self::Batch(e) => write!(f, "{e}"),
            Self::Lengths { first, other } => write!(
                f,
                "candidates of {first} and {other} poses cannot be scored together"
            ),
            Self::NoCandidate { deadline: true } => f.write_str(
                "the deadline passed before sampling began, and there was no previous plan",
            ),
            Self::NoCandidate { deadline: false } => {
                f.write_str("every candidate trajectory was non-finite")
            }
        }
    }
}

/// The plan's pose at absolute time `t` (geodesic interpolation between waypoints, held at the
/// ends).
pub fn pose_at(plan: &Plan, t: f64) -> Pose2 {
    let n = plan.poses.len();
    if n == 0 {
        return Pose2::IDENTITY;
    }
    let s = ((t - plan.t0) / plan.dt).max(0.0);
    let i = s.floor() as usize;
    if i + 1 >= n {
        return plan.poses[n - 1];
    }
    plan.poses[i].interpolate(plan.poses[i + 1], s - i as f64)
}

impl<M: FlowModel + Send> Planner for Human2Nav<M> {
    fn name(&self) -> &str {
        &self.name
    }

    fn reset(&mut self) {
        self.previous = None;
        self.rng = ChaCha8Rng::seed_from_u64(self.settings.seed);
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        // Validated with the settings, so never refused here.
        let deadline =
            budget_deadline(self.settings.budget_ms).unwrap_or_else(|_| Deadline::never());
        self.plan_within(obs, &deadline)
    }

    fn plan_within(&mut self, obs: &Observation, deadline: &Deadline) -> Result<Plan, PlanError> {
        obs.validate()?;
        let warnings = self.start_warnings(obs);
        let result = self.try_plan(obs, deadline);
        Ok(self.conclude(obs, result, warnings))
    }
}
