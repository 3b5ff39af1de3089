//! The settings of Algorithm 1 (`[human2nav.guidance]` in `planner.toml`): the variant, the
//! paper variant's parameters, their limits and their validation.

use super::*;

/// Which form of Algorithm 1 runs (`variant` in the TOML table).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GuidanceVariant {
    /// The project's variant (the default): exact adjoint gradient `∂J/∂u_i`, optional
    /// preconditioning, per-sample adaptive step, samples below the tolerance frozen and an
    /// early stop; parameters [`GuidanceSettings::learning_rate`], [`GuidanceSettings::momentum`],
    /// [`GuidanceSettings::clip`], [`GuidanceSettings::tolerance`],
    /// [`GuidanceSettings::precondition`] and [`GuidanceSettings::adaptive_step`].
    #[default]
    Adaptive,
    /// Algorithm 1 as printed (module docs, "The paper variant"), with the parameters of
    /// [`GuidanceSettings::paper`]; the adaptive variant's parameters are ignored. A planner
    /// guides every sample with it.
    Paper,
}

impl GuidanceVariant {
    /// The name used in the TOML (`adaptive`, `paper`).
    pub fn name(self) -> &'static str {
        match self {
            GuidanceVariant::Adaptive => "adaptive",
            GuidanceVariant::Paper => "paper",
        }
    }
}

/// Parameters of the paper variant (the `paper` sub-table, every field optional).
///
/// Defaults: `learning_rate = 1e-4`, `momentum = 0.9`, `clip = 10.0`. The paper gives no
/// values: β = 0.9 is a choice (the common momentum default; a decay of 10 % of the control per
/// iteration), `clip` is the adaptive variant's, and γ is the best of a sweep on the analytic
/// fields of the tests (`paper_variant_step_sizes`: the violation cases on a constant field,
/// `N = 10`, `M = 8`; Φ falls to 0.24 of its value on average, while 5·10⁻⁴ and above raise
/// it). Not tuned on the trained model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PaperSettings {
    /// `γ` of line 12, `u_{t_i} ← β·u_{t_i} − γ·μ_{t_i}`: metres (radians) of control per unit
    /// of co-state. Finite, > 0.
    pub learning_rate: f64,
    /// `β` of line 12, in `(0, 1]`: with `β < 1` a control the co-state no longer asks for
    /// decays geometrically, the effort penalty of Eq. 7.
    pub momentum: f64,
    /// Largest Euclidean norm of a waypoint's 3-vector in `μ_T` (line 6) and in every `μ_{t_i}`
    /// (line 10). Finite, > 0.
    pub clip: f64,
}

impl Default for PaperSettings {
    fn default() -> Self {
        Self {
            learning_rate: 1e-4,
            momentum: 0.9,
            clip: 10.0,
        }
    }
}

/// Parameters of Algorithm 1 (TOML table, every field optional).
///
/// Defaults: Algorithm 1 as tuned for the shipped planner (`sdk/configs/planner.toml`, where the
/// measurements behind them are; the planner itself ships with `iterations_m = 0`, see
/// [`Human2NavSettings`](crate::human2nav::Human2NavSettings)): `variant = "adaptive"`, `enabled = true`,
/// `steps_n = 5`, `iterations_m = 3`,
/// `learning_rate = 0.1`, `momentum = 1.0`, `clip = 10.0`, `tolerance = 0.01`,
/// `precondition = false` (on the trained model every preconditioned update raised Φ),
/// `adaptive_step = true`, `last_step_iterations = 0`, `last_step_rate = 0.01`, and the
/// [`PaperSettings`] defaults. See the module docs for what
/// each does. The analytic tests of the preconditioned direction use `steps_n = 10`,
/// `iterations_m = 8`, `learning_rate = 0.03` (a unit-less step there: 1 would move each
/// violated twist component by about its own limit per iteration). `enabled`, `steps_n` and `iterations_m` apply to both
/// variants; `learning_rate` to `adaptive_step` to the adaptive variant only, `paper` to the
/// paper variant only.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidanceSettings {
    /// Which form of Algorithm 1 runs.
    pub variant: GuidanceVariant,
    /// Whether Algorithm 1 runs; when false, sampling is the plain rollout.
    pub enabled: bool,
    /// Number of Euler integration steps `N` (1 to [`MAX_STEPS_N`]).
    pub steps_n: usize,
    /// Number of optimisation iterations `M`: at most (adaptive) or exactly (paper); 0 disables
    /// guidance; at most [`MAX_ITERATIONS_M`].
    pub iterations_m: usize,
    /// Initial step size `γ` of the control update (Algorithm 1's γ; not the softplus sharpness
    /// γ of Eq. 8, which is [`GuidanceWeights::gamma`](crate::GuidanceWeights)). Finite, ≥ 0.
    pub learning_rate: f64,
    /// `β` of the control update, in `[0, 1]`.
    pub momentum: f64,
    /// Largest Euclidean norm of a waypoint's terminal gradient `∇Φ` (and, without
    /// preconditioning, of its co-states and control gradients); > 0, `inf` turns it off.
    pub clip: f64,
    /// A sample whose Φ is below this is left alone (finite, ≥ 0).
    pub tolerance: f64,
    /// Precondition the terminal co-state with `L·Lᵀ` (steepest descent in the waypoint
    /// increments, see the module docs).
    pub precondition: bool,
    /// Per-sample adaptive step: an update that raises a sample's Φ is undone and its step
    /// halved; an accepted one grows the step by half.
    pub adaptive_step: bool,
    /// The paper variant's `γ`, `β` and clip (validated whichever variant is selected).
    pub paper: PaperSettings,
    /// Adaptive variant: iterations of the control update on the last control `u_{N−1}` alone
    /// after the `M` full iterations (module docs, "Last-step iterations"). They call no
    /// network; 0 turns them off. At most [`MAX_LAST_STEP_ITERATIONS`].
    pub last_step_iterations: usize,
    /// Adam's step size in the last-step iterations: the largest move of a waypoint coordinate
    /// per iteration, in metres (radians for the heading); finite, > 0.
    pub last_step_rate: f64,
}

/// Largest number of Euler integration steps `N` ([`GuidanceSettings::steps_n`]). The planner
/// uses 5 (the default); each step costs a network call per iteration, so 1000 already
/// makes one planning call take minutes. A bound keeps a mistyped value an error instead of a
/// hang.
pub const MAX_STEPS_N: usize = 1000;

/// Largest number of guidance iterations `M` ([`GuidanceSettings::iterations_m`]); Algorithm 1
/// as tuned uses 3 (the default), the shipped planner 0. Each iteration costs `2N` network calls
/// (see [`MAX_STEPS_N`]).
pub const MAX_ITERATIONS_M: usize = 1000;

/// Largest number of last-step iterations ([`GuidanceSettings::last_step_iterations`]). One
/// costs one evaluation of Φ on the batch (no network call).
pub const MAX_LAST_STEP_ITERATIONS: usize = 10_000;

/// Factor applied to a sample's step size after an accepted update.
pub const STEP_GROW: f64 = 1.5;

/// Factor applied to a sample's step size after a rejected update.
pub const STEP_SHRINK: f64 = 0.5;

impl Default for GuidanceSettings {
    fn default() -> Self {
        Self {
            variant: GuidanceVariant::default(),
            enabled: true,
            steps_n: 5,
            iterations_m: 3,
            learning_rate: 0.1,
            momentum: 1.0,
            clip: 10.0,
            tolerance: 1e-2,
            precondition: false,
            adaptive_step: true,
            paper: PaperSettings::default(),
            last_step_iterations: 0,
            last_step_rate: 0.01,
        }
    }
}

impl GuidanceSettings {
    /// Checks every field; the error names the first offending one.
    pub fn validate(&self) -> Result<(), GuidanceError> {
        let bad = |field: &'static str, message: String| {
            Err(GuidanceError::InvalidSettings { field, message })
        };
        if self.steps_n == 0 {
            return bad("steps_n", "must be at least 1".into());
        }
        if self.steps_n > MAX_STEPS_N {
            return bad(
                "steps_n",
                format!("{} is more than the limit of {MAX_STEPS_N}", self.steps_n),
            );
        }
        if self.iterations_m > MAX_ITERATIONS_M {
            return bad(
                "iterations_m",
                format!(
                    "{} is more than the limit of {MAX_ITERATIONS_M}",
                    self.iterations_m
                ),
            );
        }
        if !(self.learning_rate.is_finite() && self.learning_rate >= 0.0) {
            return bad(
                "learning_rate",
                format!("{} must be finite and ≥ 0", self.learning_rate),
            );
        }
        if !(0.0..=1.0).contains(&self.momentum) {
            return bad("momentum", format!("{} must lie in [0, 1]", self.momentum));
        }
        if self.clip.is_nan() || self.clip <= 0.0 {
            return bad(
                "clip",
                format!("{} must be positive (inf disables clipping)", self.clip),
            );
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return bad(
                "tolerance",
                format!("{} must be finite and ≥ 0", self.tolerance),
            );
        }
        if self.last_step_iterations > MAX_LAST_STEP_ITERATIONS {
            return bad(
                "last_step_iterations",
                format!(
                    "{} is more than the limit of {MAX_LAST_STEP_ITERATIONS}",
                    self.last_step_iterations
                ),
            );
        }
        if !(self.last_step_rate.is_finite() && self.last_step_rate > 0.0) {
            return bad(
                "last_step_rate",
                format!("{} must be finite and > 0", self.last_step_rate),
            );
        }
        let p = &self.paper;
        if !(p.learning_rate.is_finite() && p.learning_rate > 0.0) {
            return bad(
                "paper.learning_rate",
                format!("{} must be finite and > 0", p.learning_rate),
            );
        }
        if !(p.momentum > 0.0 && p.momentum <= 1.0) {
            return bad(
                "paper.momentum",
                format!("{} must lie in (0, 1]", p.momentum),
            );
        }
        if !(p.clip.is_finite() && p.clip > 0.0) {
            return bad("paper.clip", format!("{} must be finite and > 0", p.clip));
        }
        Ok(())
    }

    /// Parses and validates a TOML table such as `steps_n = 10\nlearning_rate = 40.0`.
    pub fn from_toml_str(text: &str) -> Result<Self, GuidanceError> {
        let s: Self = toml::from_str(text).map_err(|e| GuidanceError::Parse(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }
}
