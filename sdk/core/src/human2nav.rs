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
//! 5. returns the plan in the world frame: the current pose followed by the `T` future poses at
//!    `dt` = [`Human2NavSettings::dt`].
//!
//! Every stage but sampling and selection has its own switch; [`crate::ablation::Arm`] names
//! the combinations the guidance ablation compares (`raw`: the `K` samples as they come).
//!
//! # Selection rule
//! `score = w_feas·(1 − TFS) + w_goal·d/d_0 + w_Φ·Φ + w_cons·D`, where TFS is the
//! trajectory feasibility score of the candidate ([`crate::tfs`]), `d/d_0` the candidate's
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
    arrival,
};
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
use crate::tfs;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Default of [`SelectionWeights::collision`]: the score a predicted overlap between the
/// footprint and an agent's disc (or an obstacle) adds for it and each later waypoint.
pub const COLLISION_PENALTY: f64 = 10.0;

/// How the selection's goal term measures a candidate's progress ([`SelectionWeights::progress`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Progress {
    /// The distance left to the goal at the candidate's last waypoint. A candidate that
    /// passes the goal scores worse than one that stops short of it.
    End,
    /// The closest approach to the goal along the candidate (from the robot's current
    /// position on); a candidate that comes within [`SelectionWeights::arrival`] of the goal
    /// has arrived there: its goal term is 0 and the waypoints after its arrival are not
    /// checked for contact, since the run ends on arrival.
    #[default]
    Closest,
    /// How soon the robot could be at the goal following the candidate, in metres at `v_max`,
    /// over `d_0`: the way `v_max` covers by its arrival (as with [`Progress::Closest`]; the
    /// waypoints after it are not checked) or, without one, by its end plus the distance left
    /// there. Unlike the closest approach it ranks an arrival by how soon it comes, so a
    /// candidate that dawdles to the goal scores worse than one that drives there.
    Time,
}

/// Weights of the selection rule (see the module docs). All finite and ≥ 0.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SelectionWeights {
    /// Weight of `1 − TFS`. Default 0 (with the last-step correction every guided candidate is
    /// feasible; set it when running Algorithm 1 without the correction).
    pub feasibility: f64,
    /// Weight of the remaining goal distance ratio. Default 1.
    pub goal: f64,
    /// Weight of Φ, the robot's cost ([`RobotModel::phi`]: its built-in terms with the
    /// profile's `[cost]` weights, its plugin terms, and the clearance term), in the score.
    /// Default 1.
    pub phi: f64,
    /// Weight of the built-in clearance term ([`Clearance`]) in Φ. Default 2.
    pub clearance: f64,
    /// Weight of the distance to the previous plan (m). Default 0.1.
    pub consistency: f64,
    /// Gap (m) between footprint and agent disc below which clearance is penalised. Default 0.5.
    pub margin: f64,
    /// How the goal term measures progress. Default [`Progress::Closest`].
    pub progress: Progress,
    /// Distance to the goal (m) within which a waypoint counts as arrived with
    /// [`Progress::Closest`]. Default 0.3.
    pub arrival: f64,
    /// What the first waypoint with a predicted overlap, and every waypoint after it, adds to
    /// the clearance sum (a collision ends the plan, so an early contact costs more than a late
    /// one). Default [`COLLISION_PENALTY`].
    pub collision: f64,
    /// How long (s) a candidate that has not arrived is taken to stand at its last pose after
    /// it, checked for contact like its waypoints: a plan that ends in someone's path scores
    /// the contact the robot would meet once it stops there. 0 (the default): the plan alone.
    /// At most [`MAX_HOLD_S`].
    pub hold: f64,
    /// How long (s) every candidate is taken to go on after its last pose at the twist of its
    /// last step ([`continued`]), scored over those waypoints too: the goal term and the
    /// clearance term see that far ahead, while the plan sent stays the candidate. With the
    /// closest approach ([`Progress::Closest`]) a lookahead of seconds lets most candidates
    /// "arrive" and the robot stop making haste; [`Progress::Time`] keeps it. 0 (the default):
    /// the plan alone. At most [`MAX_HOLD_S`].
    pub lookahead: f64,
}

/// Largest [`SelectionWeights::hold`] and [`SelectionWeights::lookahead`] (s): longer than any
/// plan, and a typo beyond it.
pub const MAX_HOLD_S: f64 = 10.0;

impl Default for SelectionWeights {
    fn default() -> Self {
        Self {
            feasibility: 0.0,
            goal: 1.0,
            phi: 1.0,
            clearance: 2.0,
            consistency: 0.1,
            margin: 0.5,
            progress: Progress::Closest,
            arrival: 0.3,
            collision: COLLISION_PENALTY,
            hold: 0.0,
            lookahead: 0.0,
        }
    }
}

/// Largest number of sampled candidates `K` ([`Human2NavSettings::samples`]) and of guided
/// samples ([`Human2NavSettings::guided_samples`]): 64 times the `K = 16` the planner shipped
/// with until December 2026 (now 4). The network runs on the whole batch at every integration
/// step, so a planning call's network time grows linearly with `K` (about 5 ms at 16
/// unguided); beyond this it takes seconds, and a mistyped count should be
/// an error rather than an allocation of gigabytes.
pub const MAX_SAMPLES: usize = 1024;

/// Largest [`Human2NavSettings::motions`]: each is scored against every agent at every
/// waypoint, and the grid has 2,401 (a car) to 21,609 (go2) pairs.
pub const MAX_MOTIONS: usize = 25_000;

/// Duration of a motion's first segment (s) ([`crate::motions`]).
pub const MOTION_SWITCH_S: f64 = 1.0;

/// Largest [`Human2NavSettings::crowd_weight`]: far past any weight that leaves samples a
/// model would draw; a typo beyond it.
pub const MAX_CROWD_WEIGHT: f64 = 100.0;

/// Largest [`Human2NavSettings::budget_ms`]: a minute is no planning budget but a typo.
pub const MAX_BUDGET_MS: f64 = 60_000.0;

/// The deadline of a planning call with a budget of `budget_ms` milliseconds from now (0: no
/// deadline). Every front end (the settings, the C API, Python) goes through this one check,
/// so a budget one refuses, all refuse, with the same message: it must be finite and lie in
/// 0 to [`MAX_BUDGET_MS`].
pub fn budget_deadline(budget_ms: f64) -> Result<Deadline, String> {
    if !(budget_ms.is_finite() && (0.0..=MAX_BUDGET_MS).contains(&budget_ms)) {
        return Err(format!(
            "budget_ms {budget_ms} must lie in 0 (no budget) to {MAX_BUDGET_MS}"
        ));
    }
    Ok(if budget_ms > 0.0 {
        Deadline::after(std::time::Duration::from_secs_f64(budget_ms / 1e3))
    } else {
        Deadline::never()
    })
}

/// Settings of the Human2Nav planner (TOML table; every field optional).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Human2NavSettings {
    /// Number of sampled candidates `K` (0 to [`MAX_SAMPLES`]). Default 4, as `planner.toml`
    /// ships (16 until December 2026; on the validation suites 4 succeed as often, and the
    /// network's work per call is a quarter). 0: the model is not called, and the robot's own
    /// motions ([`Self::motions`], which must then be offered) and the extra candidates are
    /// all there is: the arm that measures what the model adds.
    pub samples: usize,
    /// Time between plan poses (s); must match the model's training data. Default 0.1.
    pub dt: f64,
    /// Goals farther than this (m) are pulled in along the same bearing. Default 6.
    pub goal_clip: f64,
    /// Seed of the source noise; the planner is deterministic given the seed and the inputs.
    pub seed: u64,
    /// Classifier-free guidance on the crowd ([`CrowdGuidance`]): the model's field is drawn
    /// `w` times as far from its field with an empty raster as the crowd moves it (0 to
    /// [`MAX_CROWD_WEIGHT`]). 1 (the default): the model as it is; above 1, two network calls
    /// where one was.
    pub crowd_weight: f64,
    /// Keep the previous plan as a candidate (warm start). Default true.
    pub warm_start: bool,
    /// How many of the `K` samples Algorithm 1 runs on (0: all; at most [`MAX_SAMPLES`]).
    /// Default 4: the best by the selection score without its feasibility term. Ignored with the
    /// paper variant of Algorithm 1 (`guidance.variant = "paper"`), which guides all `K`, as
    /// the paper does.
    pub guided_samples: usize,
    /// Each guided candidate is also offered at this fraction of its speed along the same path
    /// (in `(0, 1]`; 1: no slowed copies). Default 0.5.
    pub slowdown: f64,
    /// Also offer "stop": brake to a standstill as hard as the limits allow. Default true.
    pub stop_candidate: bool,
    /// Within this distance (m) of the goal, also offer "straight to the goal": along the line
    /// to it at half of `v_max`, stopping there ([`goal_approach`]). The model's samples walk
    /// past a goal that close (it was trained on goals metres away). 0: never. Default 1.
    pub goal_approach: f64,
    /// Also offer this many of the robot's own motions ([`crate::motions`]: two-segment twist
    /// profiles within its limits, spread evenly over the grid) to the selection, beside the
    /// model's samples: backing off, sidestepping, turning away and waiting, which the model,
    /// trained on people walking to a goal, rarely proposes. 0: none (at most
    /// [`MAX_MOTIONS`]). Default 500 (`planner.toml` says which validation run chose it). A
    /// call whose deadline has passed offers none.
    pub motions: usize,
    /// For a robot with a turning circle (a car: `limits.kappa_max` set), this many motions
    /// instead of [`Self::motions`] (0: as many as `motions`; none when `motions` is 0; at
    /// most [`MAX_MOTIONS`]). A car cannot turn in place, and the manoeuvres it needs near
    /// people and near its goal are narrow: default 2401, every pair of its 7 × 7 grid
    /// (`planner.toml` says which validation run chose it).
    pub car_motions: usize,
    /// Offer the robot's own motions only as a recovery: when none of the model's candidates
    /// (its samples and their slowed copies) keeps out of contact with the people and
    /// obstacles as forecast ([`Clearance::contact_free`]), like a controller's recovery
    /// behaviour. Default false: the motions are always offered.
    pub motions_recovery: bool,
    /// Time budget of one [`Planner::plan`] call in milliseconds (0: none). The call then
    /// returns the best plan found within it (module docs, "Planning under a deadline").
    /// [`Planner::plan_within`] takes a deadline per call instead. Default 0.
    pub budget_ms: f64,
    /// Algorithm 1 (the paper's feasibility guidance) on the shortlisted samples:
    /// `guidance.enabled` switches it, and nothing else, on or off. Default: off, with
    /// [`GuidanceSettings::default`]'s tuned iterations when switched on (as `planner.toml`
    /// ships). The other stages have their own switches: `projection.enabled` (the
    /// correction), `slowdown`, `stop_candidate` and `goal_approach` (the extra candidates),
    /// `motions` (the robot's own motions); [`crate::ablation::Arm`] names the combinations.
    pub guidance: GuidanceSettings,
    /// Which terms of Φ Algorithm 1 descends ([`GuidanceTerms`]). Default `all`, as the paper.
    pub guidance_terms: GuidanceTerms,
    /// The exact last-step correction applied after Algorithm 1 ([`crate::projection`]).
    pub projection: ProjectionSettings,
    /// The weights of the selection rule (module docs, "Selection rule").
    pub selection: SelectionWeights,
}

impl Default for Human2NavSettings {
    fn default() -> Self {
        Self {
            samples: 4,
            dt: 0.1,
            goal_clip: 6.0,
            seed: 0,
            crowd_weight: 1.0,
            warm_start: true,
            guided_samples: 4,
            slowdown: 0.5,
            stop_candidate: true,
            goal_approach: 1.0,
            motions: 500,
            car_motions: 2401,
            motions_recovery: false,
            budget_ms: 0.0,
            // Algorithm 1 is off in the shipped planner: on the validation suite the correction
            // alone succeeded more often (ARCHITECTURE.md, "The guidance ablation"). Switched
            // on, it runs its tuned iterations.
            guidance: GuidanceSettings {
                enabled: false,
                ..GuidanceSettings::default()
            },
            guidance_terms: GuidanceTerms::All,
            projection: ProjectionSettings::default(),
            selection: SelectionWeights::default(),
        }
    }
}

/// Which terms of Φ Algorithm 1 descends ([`Human2NavSettings::guidance_terms`]). The
/// selection scores every candidate with the whole Φ either way.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GuidanceTerms {
    /// Every term: the robot's limit terms, its plugin terms and the clearance term (the
    /// paper's Φ).
    #[default]
    All,
    /// Every term but the robot's built-in limit terms ([`Phi::without_limits`]): the clearance
    /// term and the plugin terms, the ones that read the scene. The last-step correction
    /// (`projection.enabled`) then enforces the limits exactly; without it nothing does (the
    /// guidance ablation's "Algorithm 1 only" arm measures that). The limit terms'
    /// gradients are far larger than the clearance term's, so with `all` the iterations go
    /// to the limits and leave the samples' contacts as they were (experiment log,
    /// 2026-12-06, "Algorithm 1 on the scene's terms").
    Scene,
}

impl Human2NavSettings {
    /// Checks every field; the error names the first offending one.
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |field: &str, why: &str| {
            Err(PlanError::InvalidSettings(format!(
                "human2nav.{field}: {why}"
            )))
        };
        if self.samples == 0 && self.motions == 0 {
            return bad(
                "samples",
                "0 (no model samples) needs the robot's own motions (motions > 0)",
            );
        }
        if self.samples == 0 && self.motions_recovery {
            return bad(
                "motions_recovery",
                "with samples = 0 there are no model candidates to recover from",
            );
        }
        if self.samples > MAX_SAMPLES {
            return bad(
                "samples",
                &format!("{} is more than the limit of {MAX_SAMPLES}", self.samples),
            );
        }
        if self.guided_samples > MAX_SAMPLES {
            return bad(
                "guided_samples",
                &format!(
                    "{} is more than the limit of {MAX_SAMPLES}",
                    self.guided_samples
                ),
            );
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return bad("dt", "must be finite and > 0");
        }
        if !(self.crowd_weight.is_finite() && (0.0..=MAX_CROWD_WEIGHT).contains(&self.crowd_weight))
        {
            return bad(
                "crowd_weight",
                &format!(
                    "must lie in 0 to {MAX_CROWD_WEIGHT}, got {}",
                    self.crowd_weight
                ),
            );
        }
        if !(self.goal_clip.is_finite() && self.goal_clip > 0.0) {
            return bad("goal_clip", "must be finite and > 0");
        }
        if !(self.slowdown > 0.0 && self.slowdown <= 1.0) {
            return bad("slowdown", "must be in (0, 1]");
        }
        if !(self.goal_approach.is_finite() && self.goal_approach >= 0.0) {
            return bad("goal_approach", "must be finite and ≥ 0");
        }
        if self.motions > MAX_MOTIONS {
            return bad(
                "motions",
                &format!("must be at most {MAX_MOTIONS}, got {}", self.motions),
            );
        }
        if self.car_motions > MAX_MOTIONS {
            return bad(
                "car_motions",
                &format!("must be at most {MAX_MOTIONS}, got {}", self.car_motions),
            );
        }
        if let Err(why) = budget_deadline(self.budget_ms) {
            return bad("budget_ms", &why);
        }
        let s = &self.selection;
        for (name, v) in [
            ("selection.feasibility", s.feasibility),
            ("selection.goal", s.goal),
            ("selection.phi", s.phi),
            ("selection.clearance", s.clearance),
            ("selection.consistency", s.consistency),
            ("selection.arrival", s.arrival),
            ("selection.collision", s.collision),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(name, "must be finite and ≥ 0");
            }
        }
        if !(s.margin.is_finite() && s.margin > 0.0) {
            return bad("selection.margin", "must be finite and > 0");
        }
        for (name, v) in [
            ("selection.hold", s.hold),
            ("selection.lookahead", s.lookahead),
        ] {
            if !(v.is_finite() && (0.0..=MAX_HOLD_S).contains(&v)) {
                return bad(name, &format!("must lie in 0 to {MAX_HOLD_S} s, got {v}"));
            }
        }
        self.projection
            .validate()
            .map_err(|e| PlanError::InvalidSettings(format!("human2nav.projection: {e}")))?;
        self.guidance
            .validate()
            .map_err(|e| PlanError::InvalidSettings(format!("human2nav.guidance: {e}")))
    }
}

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

    /// The forecast the selection scores against, in the ego frame: the predictor's, or
    /// constant velocity without one or when it fails (noted in `notes`).
    fn forecast(
        &mut self,
        obs: &Observation,
        agents: &[AgentState],
        horizon: usize,
        notes: &mut Vec<String>,
    ) -> Forecast {
        let dt = self.settings.dt;
        if let Some(p) = self.predictor.as_mut() {
            match p.forecast(obs, horizon, dt) {
                Ok(f) if f.horizon() == horizon && f.agents().len() == obs.agents.len() => {
                    return f.in_frame(obs.ego);
                }
                Ok(f) => notes.push(format!(
                    "predictor {} forecast {} agents over {} waypoints for {} agents over {}; \
                     constant velocity used",
                    p.name(),
                    f.agents().len(),
                    f.horizon(),
                    obs.agents.len(),
                    horizon
                )),
                Err(e) => notes.push(format!(
                    "predictor {} failed ({e}); constant velocity used",
                    p.name()
                )),
            }
        }
        Forecast::constant_velocity(agents, horizon, dt)
    }

    /// The settings in force.
    pub fn settings(&self) -> &Human2NavSettings {
        &self.settings
    }

    /// The flow model the planner samples from.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// Builds the ego-frame condition and the ego-frame agents for one observation.
    pub fn condition(&mut self, obs: &Observation) -> (FlowCondition, Vec<AgentState>) {
        bev::rasterize(self.bev, obs.ego, &obs.agents, &mut self.raster);
        let mut goal = obs.ego.inverse_act(obs.goal);
        let dist = goal[0].hypot(goal[1]);
        if dist > self.settings.goal_clip {
            let s = self.settings.goal_clip / dist;
            goal = [goal[0] * s, goal[1] * s];
        }
        let agents = obs
            .agents
            .iter()
            .map(|a| AgentState {
                position: obs.ego.inverse_act(a.position),
                velocity: obs.ego.inverse_rotate(a.velocity),
                history: a.history.iter().map(|p| obs.ego.inverse_act(*p)).collect(),
                ..a.clone()
            })
            .collect();
        let cond = FlowCondition {
            bev: self.raster.clone(),
            goal,
            velocity: [obs.ego_velocity.vx, obs.ego_velocity.vy],
        };
        (cond, agents)
    }

    fn draw_source(&mut self, k: usize, t: usize) -> Vec<f64> {
        crate::flow::draw_source(self.model.source_std(), k, t, &mut self.rng)
    }

    /// Plans within `deadline`, returning the plan or the reason the flow stage failed (for
    /// [`Planner::plan_within`], which turns such failures into the stop-in-place fallback).
    ///
    /// A little over 120 lines: stage 2 fills half a dozen locals the selection and the plan's
    /// diagnostics read (candidates, their origin, Φ, the corrected flags, stages, notes);
    /// splitting it further would pass all of them back and forth.
    fn try_plan(&mut self, obs: &Observation, deadline: &Deadline) -> Result<Plan, StageError> {
        let horizon = self.model.horizon();
        let k = self.settings.samples;
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
        let x0 = self.draw_source(k, horizon);
        let goal = cond.goal;
        let warm = if self.settings.warm_start {
            self.shifted_previous(obs, horizon)
        } else {
            None
        };
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

        // Stage 3: selection, every candidate scored with Φ.
        let scored = self.scored(&candidates);
        let ctx = self.phi_context(obs, &agents, &forecast, goal);
        let phi_cost = self.phi_costs(&scored, &ctx)?;
        let best = select_best(&scored, &corrected, |i| {
            self.score(
                &scored[i],
                goal,
                phi_cost[i],
                obs.ego_velocity,
                previous_ego,
                true,
            )
        });
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
                    model: &self.model,
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
                model: &self.model,
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

    /// The candidates besides the flow samples: the shortlist's slowed copies, the stop, the
    /// straight approach to a near goal and the previous plan, each as the settings allow.
    fn push_extra_candidates(
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
    fn push_motions(
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

    /// What is wrong with the robot's own state in `obs` ([`PlanInfo::warnings`]): its
    /// footprint overlapping an obstacle or an occupied cell, or a velocity more than
    /// [`LIMIT_WARNING_FACTOR`] times a limit.
    fn start_warnings(&self, obs: &Observation) -> Vec<String> {
        let mut warnings = Vec::new();
        let shapes = &self.robot.footprint;
        let here = [obs.ego.x, obs.ego.y];
        for (i, o) in obs.obstacles.iter().enumerate() {
            let c = crate::obstacle::footprint_clearance(shapes, obs.ego, o);
            if c < 0.0 {
                warnings.push(format!(
                    "the robot starts inside obstacles[{i}] (overlapping by {:.3} m)",
                    -c
                ));
            }
        }
        if let Some(grid) = &obs.occupancy {
            let cells = grid.obstacles_near(here, self.reach);
            if cells
                .iter()
                .any(|o| crate::obstacle::footprint_clearance(shapes, obs.ego, o) < 0.0)
            {
                warnings.push("the robot starts on an occupied cell of the occupancy grid".into());
            }
        }
        let l = &self.robot.limits;
        let v = obs.ego_velocity;
        for (what, value, limit) in [
            ("forward speed", v.vx, l.v_max),
            ("reverse speed", -v.vx, l.v_reverse_max),
            ("lateral speed", v.vy.abs(), l.lateral_speed_max),
            ("yaw rate", v.omega.abs(), l.omega_max),
        ] {
            if value > LIMIT_WARNING_FACTOR * limit {
                warnings.push(format!(
                    "the robot starts at a {what} of {value:.3}, beyond its limit of {limit:.3}"
                ));
            }
        }
        warnings
    }

    /// The observation's static obstacles that a plan of `horizon` poses could reach (within
    /// the distance covered at `v_max`, plus the footprint's reach and the selection margin),
    /// with the occupied cells of its grid there, in the ego frame.
    fn nearby_obstacles(&self, obs: &Observation, horizon: usize) -> Vec<Obstacle> {
        let range = self.robot.limits.v_max * horizon as f64 * self.settings.dt
            + self.reach
            + self.settings.selection.margin;
        let here = [obs.ego.x, obs.ego.y];
        let grid = obs
            .occupancy
            .as_ref()
            .map(|g| g.obstacles_near(here, range))
            .unwrap_or_default();
        obs.obstacles
            .iter()
            .filter(|o| o.distance(here) <= range)
            .chain(&grid)
            .map(|o| o.in_frame(obs.ego))
            .collect()
    }

    /// The last-step correction of every candidate, in order, returning which it made
    /// feasible. Once `deadline` has passed only the stop and the previous-plan candidates are
    /// corrected (the previous plan usually is feasible already, which costs no QP), and a stop
    /// candidate is added if there is none, so that a plan cut short is still a safe one.
    fn correct(
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

    /// The samples that go on past sampling (to Algorithm 1, the slowed copies and the
    /// correction): the [`Human2NavSettings::guided_samples`] best by the selection score
    /// without its feasibility term (guidance and the correction are what fix feasibility),
    /// all of them when that is 0 or at least `K`, or when the paper variant of Algorithm 1
    /// runs (the paper guides every sample). Indices in sample order.
    fn shortlist(
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
    fn phi_context<'a>(
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
    fn clearance(&self) -> Clearance {
        selection_clearance(&self.settings)
    }

    /// Whether each ego-frame candidate keeps out of contact with the people and obstacles as
    /// forecast, by the selection's clearance term ([`Clearance::contact_free`]).
    fn contact_free(
        &self,
        candidates: &[Vec<Pose2>],
        ctx: &ConstraintContext<'_>,
    ) -> Result<Vec<bool>, StageError> {
        let Some((data, poses)) = pose_batch(candidates)? else {
            return Ok(Vec::new());
        };
        let batch = TrajBatch::new(&data, candidates.len(), poses)
            .map_err(StageError::Batch)?;
        self.clearance()
            .contact_free(batch, ctx)
            .map_err(StageError::Contact)
    }

    /// Φ of every ego-frame candidate (each with the robot's pose, the identity, prepended as
    /// pose 0), without gradients. A term that fails or answers a non-finite cost is an error
    /// naming it: the selection never scores without a term.
    fn phi_costs(
        &self,
        candidates: &[Vec<Pose2>],
        ctx: &ConstraintContext<'_>,
    ) -> Result<Vec<f64>, StageError> {
        let Some((data, poses)) = pose_batch(candidates)? else {
            return Ok(Vec::new());
        };
        let batch = TrajBatch::new(&data, candidates.len(), poses)
            .map_err(StageError::Batch)?;
        let mut cost = vec![0.0; candidates.len()];
        self.robot
            .phi
            .costs(batch, ctx, &mut cost, &mut PhiScratch::default())
            .map_err(StageError::Phi)?;
        Ok(cost)
    }

    /// [`SelectionWeights::hold`] in plan steps.
    fn hold_steps(&self) -> usize {
        steps(self.settings.selection.hold, self.settings.dt)
    }

    /// [`SelectionWeights::lookahead`] in plan steps.
    fn lookahead_steps(&self) -> usize {
        steps(self.settings.selection.lookahead, self.settings.dt)
    }

    /// The candidates as the selection scores them: each [`continued`] for the lookahead, or
    /// as they are without one.
    fn scored<'a>(&self, candidates: &'a [Vec<Pose2>]) -> Cow<'a, [Vec<Pose2>]> {
        match self.lookahead_steps() {
            0 => Cow::Borrowed(candidates),
            ahead => Cow::Owned(candidates.iter().map(|c| continued(c, ahead)).collect()),
        }
    }

    /// The previous plan re-expressed in the current ego frame at the current time, `T` future
    /// poses (holding the last pose past its end), or `None` without a usable previous plan.
    fn shifted_previous(&self, obs: &Observation, horizon: usize) -> Option<Vec<Pose2>> {
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

    /// The selection score of one ego-frame candidate (lower is better), given its Φ (the
    /// robot's constraint terms and the clearance term, [`Self::phi_costs`]); without
    /// `with_feasibility` the TFS term is left out.
    fn score(
        &self,
        traj: &[Pose2],
        goal: [f64; 2],
        phi: f64,
        v0: Twist2,
        previous: Option<&[Pose2]>,
        with_feasibility: bool,
    ) -> f64 {
        let w = &self.settings.selection;
        // TFS costs a pass over the plan; with a zero weight (the shipped selection) it is
        // not computed.
        let feas = if with_feasibility && w.feasibility > 0.0 {
            let mut with_start = Vec::with_capacity(traj.len() + 1);
            with_start.push(Pose2::IDENTITY);
            with_start.extend_from_slice(traj);
            tfs::tfs_plan(&with_start, self.settings.dt, &self.robot.limits, v0)
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

        w.feasibility * (1.0 - feas) + w.goal * progress + w.phi * phi + w.consistency * consistency
    }
}

/// A duration in whole plan steps of `dt`.
fn steps(seconds: f64, dt: f64) -> usize {
    (seconds / dt).round() as usize
}

/// How many of its own motions a robot with `limits` is offered:
/// [`Human2NavSettings::car_motions`] for a car (unless 0), [`Human2NavSettings::motions`]
/// otherwise, none when `motions` is 0.
fn motion_count(settings: &Human2NavSettings, limits: &Limits) -> usize {
    match (settings.motions, limits.kappa_max) {
        (0, _) => 0,
        (_, Some(_)) if settings.car_motions > 0 => settings.car_motions,
        (m, _) => m,
    }
}

/// The selection's goal term of the ego-frame candidate `traj`: `d/d_0` (module docs), or
/// how soon it could arrive with [`Progress::Time`]; `reach_per_step` is the way `v_max`
/// covers in one plan step. Which of its waypoints the clearance term scores (those up to its
/// arrival) is the term's own business ([`Clearance::arrival`]).
fn goal_term(traj: &[Pose2], goal: [f64; 2], w: &SelectionWeights, reach_per_step: f64) -> f64 {
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
        _ => traj.iter().map(distance).fold(d0, f64::min) / d0,
    }
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

/// Where a candidate of the selection came from.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Source {
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
    fn sample(self) -> Option<usize> {
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

/// "Straight to the goal" in the ego frame: `T` poses at `dt` along the line from the robot to
/// The candidate with the lowest finite `score` among those whose poses are all finite. When
/// the last-step correction ran (`corrected` holds one flag per candidate), a candidate it
/// failed on is eligible only if it failed on every one: an uncorrected plan never wins over a
/// corrected one, whatever the weight of the score's feasibility term.
fn select_best(
    candidates: &[Vec<Pose2>],
    corrected: &[bool],
    mut score: impl FnMut(usize) -> f64,
) -> Option<usize> {
    let any_corrected = corrected.contains(&true);
    let mut best: Option<(usize, f64)> = None;
    for (i, c) in candidates.iter().enumerate() {
        let eligible = !any_corrected || corrected.get(i).copied().unwrap_or(false);
        if !eligible || !c.iter().all(|p| p.is_finite()) {
            continue;
        }
        let s = score(i);
        if s.is_finite() && best.is_none_or(|(_, b)| s < b) {
            best = Some((i, s));
        }
    }
    best.map(|(i, _)| i)
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
        let mut plan = match self.try_plan(obs, deadline) {
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
        Ok(plan)
    }
}

/// Φ's context at a planning instant: the plan step, the robot's limits, its velocity, the
/// nearby pedestrians and the scene (a free function so that it borrows fields, not the whole
/// planner).
/// Ego-frame candidates as one flat batch of poses, each with the robot's pose (the identity)
/// prepended as pose 0, and the poses per trajectory; `None` without candidates. Candidates
/// of different lengths cannot be scored together (an error).
fn pose_batch(candidates: &[Vec<Pose2>]) -> Result<Option<(Vec<f64>, usize)>, StageError> {
    let Some(first) = candidates.first() else {
        return Ok(None);
    };
    let poses = first.len() + 1;
    let mut data = Vec::with_capacity(candidates.len() * poses * 3);
    for c in candidates {
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
fn selection_clearance(settings: &Human2NavSettings) -> Clearance {
    let sel = &settings.selection;
    Clearance {
        margin: sel.margin,
        collision: sel.collision,
        hold: steps(sel.hold, settings.dt),
        arrival: (sel.progress != Progress::End).then_some(sel.arrival),
    }
}

fn phi_context<'a>(
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
#[cfg(test)]
mod tests {
    use super::*;

    /// A candidate's goal term, and how many of its waypoints the clearance term scores.
    fn progress_checked(
        (traj, goal, w, reach): (&[Pose2], [f64; 2], &SelectionWeights, f64),
    ) -> (f64, usize) {
        let clearance = Clearance {
            margin: w.margin,
            collision: w.collision,
            hold: 0,
            arrival: (w.progress != Progress::End).then_some(w.arrival),
        };
        (
            goal_term(traj, goal, w, reach),
            clearance.checked(traj, Some(goal)).0,
        )
    }

    fn line(speed: f64) -> Vec<Pose2> {
        (1..=4)
            .map(|k| Pose2::new(0.1 * speed * k as f64, 0.0, 0.0))
            .collect()
    }

    #[test]
    fn an_uncorrected_candidate_never_wins_over_a_corrected_one() {
        // Candidate 0 scores best but the correction failed on it.
        let candidates = vec![line(1.0), line(2.0), line(3.0)];
        let score = |i: usize| candidates[i][0].x;
        assert_eq!(
            select_best(&candidates, &[false, true, true], &score),
            Some(1)
        );
        // Without the correction, or when it failed on all, the score alone decides.
        assert_eq!(select_best(&candidates, &[], &score), Some(0));
        assert_eq!(
            select_best(&candidates, &[false, false, false], &score),
            Some(0)
        );
    }

    #[test]
    fn the_goal_term_measures_the_end_or_the_closest_approach() {
        // 0.1 m apart along x, from 0.4 m to 4.0 m: the goal at (2, 0.5) is passed.
        let traj: Vec<Pose2> = (4..=40)
            .map(|k| Pose2::new(0.1 * k as f64, 0.0, 0.0))
            .collect();
        let goal = [2.0, 0.5];
        let d0 = 2.0f64.hypot(0.5);
        let end = SelectionWeights {
            progress: Progress::End,
            ..SelectionWeights::default()
        };
        // The end at (4, 0) is as far from the goal as the start.
        let (p, checked) = progress_checked((&traj, goal, &end, 0.1));
        assert!((p - 1.0).abs() < 1e-12, "{p}");
        assert_eq!(checked, traj.len());
        // The closest approach is 0.5 m, at (2, 0): not within 0.3 m, so not arrived.
        let closest = SelectionWeights {
            progress: Progress::Closest,
            ..end
        };
        let (p, checked) = progress_checked((&traj, goal, &closest, 0.1));
        assert!((p - 0.5 / d0).abs() < 1e-12, "{p}");
        assert_eq!(checked, traj.len());
        // Within 0.6 m it arrives at (1.7, 0), the 14th waypoint, and is checked up to there.
        let (p, checked) = progress_checked((
            &traj,
            goal,
            &SelectionWeights {
                arrival: 0.6,
                ..closest
            },
            0.1,
        ));
        assert_eq!(p, 0.0);
        assert_eq!(checked, 14);
        assert!((traj[13].x - 1.7).abs() < 1e-12);
        // A candidate leading away: its closest approach is where the robot stands.
        let away: Vec<Pose2> = traj.iter().map(|p| Pose2::new(-p.x, 0.0, 0.0)).collect();
        assert_eq!(goal_term(&away, goal, &closest, 0.1), 1.0);
        assert_eq!(progress_checked((&[], goal, &closest, 0.1)), (1.0, 0));
    }

    #[test]
    fn a_candidate_goes_on_at_the_twist_of_its_last_step() {
        // An arc: 0.1 m and 0.05 rad a step from the robot's pose.
        let step = Pose2::new(0.1, 0.0, 0.05);
        let mut arc = vec![step];
        for _ in 1..5 {
            arc.push(arc[arc.len() - 1].compose(step));
        }
        let long = continued(&arc[..3], 2);
        assert_eq!(long.len(), 5);
        for (a, b) in long.iter().zip(&arc) {
            assert!(
                (a.x - b.x).abs() < 1e-12 && (a.y - b.y).abs() < 1e-12,
                "{a:?} {b:?}"
            );
            assert!((a.theta - b.theta).abs() < 1e-12);
        }
        // One pose: its step is from the robot's pose (the identity).
        let one = continued(&arc[..1], 4);
        assert!((one[4].x - arc[4].x).abs() < 1e-12 && (one[4].y - arc[4].y).abs() < 1e-12);
        // At rest it stays; nothing to continue from is nothing.
        let rest = continued(&[Pose2::new(1.0, 2.0, 0.3); 2], 3);
        assert!(rest.iter().all(|p| *p == Pose2::new(1.0, 2.0, 0.3)));
        assert!(continued(&[], 3).is_empty());
        assert_eq!(continued(&arc, 0), arc);
    }

    #[test]
    fn the_time_goal_term_ranks_an_arrival_by_how_soon_it_comes() {
        // v_max·dt = 0.1 m a step; the goal 2 m ahead.
        let goal = [2.0, 0.0];
        let w = SelectionWeights {
            progress: Progress::Time,
            ..SelectionWeights::default()
        };
        let at = |speed: f64, n: usize| -> Vec<Pose2> {
            (1..=n)
                .map(|k| Pose2::new(0.1 * speed * k as f64, 0.0, 0.0))
                .collect()
        };
        // At full speed it arrives (within 0.3 m) on the 17th waypoint: 1.7 m covered.
        let (fast, checked) = progress_checked((&at(1.0, 40), goal, &w, 0.1));
        assert_eq!(checked, 17);
        assert!((fast - 1.7 / 2.0).abs() < 1e-12, "{fast}");
        // At half speed it arrives on the 34th: twice as late, and it ranks worse.
        let (slow, checked) = progress_checked((&at(0.5, 40), goal, &w, 0.1));
        assert_eq!(checked, 34);
        assert!((slow - 3.4 / 2.0).abs() < 1e-12, "{slow}");
        // Closest approach calls both arrived alike.
        let closest = SelectionWeights::default();
        assert_eq!(goal_term(&at(1.0, 40), goal, &closest, 0.1), 0.0);
        assert_eq!(goal_term(&at(0.5, 40), goal, &closest, 0.1), 0.0);
        // Not arriving: the way covered by its end plus the distance left there. Standing
        // still for as long ranks behind it, and backing away behind that.
        let (short, checked) = progress_checked((&at(0.5, 10), goal, &w, 0.1));
        assert_eq!(checked, 10);
        assert!((short - (1.0 + 1.5) / 2.0).abs() < 1e-12, "{short}");
        let rest = goal_term(&[Pose2::IDENTITY; 10], goal, &w, 0.1);
        assert!((rest - 3.0 / 2.0).abs() < 1e-12, "{rest}");
        let away = goal_term(&at(-0.5, 10), goal, &w, 0.1);
        assert!((away - 3.5 / 2.0).abs() < 1e-12, "{away}");
        assert!(fast < short && short < rest && rest < away);
        // Over as many waypoints a late arrival still beats standing still.
        let rest_40 = goal_term(&[Pose2::IDENTITY; 40], goal, &w, 0.1);
        assert!((rest_40 - 6.0 / 2.0).abs() < 1e-12, "{rest_40}");
        assert!(slow < rest_40);
        assert_eq!(progress_checked((&[], goal, &w, 0.1)), (1.0, 0));
    }

    #[test]
    fn a_car_is_offered_its_own_count_of_motions() {
        let walker = Limits {
            v_max: 1.2,
            v_reverse_max: 0.3,
            a_max: 1.0,
            omega_max: 1.5,
            kappa_max: None,
            lateral_speed_max: 0.05,
            coupled: None,
        };
        let car = Limits {
            kappa_max: Some(1.0 / 1.6),
            ..walker
        };
        let count = |motions, car_motions, limits: &Limits| {
            let s = Human2NavSettings {
                motions,
                car_motions,
                ..Human2NavSettings::default()
            };
            motion_count(&s, limits)
        };
        assert_eq!(count(500, 2401, &walker), 500);
        assert_eq!(count(500, 2401, &car), 2401);
        assert_eq!(count(500, 0, &car), 500, "0: as many as motions");
        assert_eq!(count(0, 2401, &car), 0, "motions = 0: none");
        // The shipped defaults: every pair of the car's 7 × 7 grid.
        let d = Human2NavSettings::default();
        let grid = MotionGrid::new(car, GridLevels::default());
        assert_eq!(motion_count(&d, &car), grid.len());
    }

    #[test]
    fn selection_skips_non_finite_candidates_and_scores() {
        let mut bad = line(1.0);
        bad[2].y = f64::NAN;
        let candidates = vec![bad, line(2.0), line(3.0)];
        assert_eq!(
            select_best(&candidates, &[], |i| candidates[i][0].x),
            Some(1)
        );
        let nan_for_second = |i: usize| {
            let c = &candidates[i];
            if c[0].x > 0.15 && c[0].x < 0.25 {
                f64::NAN
            } else {
                c[0].x
            }
        };
        assert_eq!(select_best(&candidates, &[], nan_for_second), Some(2));
        assert_eq!(
            select_best(&candidates[..1], &[], |i| candidates[i][0].x),
            None
        );
    }
}
