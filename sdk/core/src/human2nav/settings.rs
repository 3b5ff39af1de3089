//! The planner's settings (`[human2nav]` in `planner.toml`), the selection's weights and
//! their limits.

use super::*;

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
