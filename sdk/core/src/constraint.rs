//! Constraint terms: batched costs with analytic gradients, summed into Φ (paper Eq. 8-9).
//!
//! A [`ConstraintTerm`] evaluates a batch of trajectories and *adds* its cost per trajectory and
//! its gradient with respect to every pose into caller-owned buffers (the pattern of Nav2's MPPI
//! critics: one context struct, batched evaluation, no allocation on the hot path).
//!
//! The built-in soft-margin terms of Eq. 8 are [`BuiltinTerm`]s (see [`builtin`] for the exact
//! formulas); [`Phi`] is their weighted sum (Eq. 9) plus any plugin terms.

use crate::forecast::Forecast;
use crate::limits::Limits;
use crate::obstacle::Obstacle;
use crate::planner::AgentState;
use crate::robot::footprint::FootprintShape;
use crate::se2::Twist2;

/// A read-only view of `batch` trajectories of `horizon` poses, flat `[B, T, 3]` (`x, y, θ`).
#[derive(Clone, Copy, Debug)]
pub struct TrajBatch<'a> {
    /// The poses, trajectory after trajectory (`x, y` in m, `θ` in rad); `batch·horizon·3`
    /// values when built by [`TrajBatch::new`].
    pub data: &'a [f64],
    /// Number of trajectories `B`.
    pub batch: usize,
    /// Number of poses `T` per trajectory.
    pub horizon: usize,
}

impl<'a> TrajBatch<'a> {
    /// Checks that `data.len() == batch·horizon·3`.
    pub fn new(data: &'a [f64], batch: usize, horizon: usize) -> Result<Self, ConstraintError> {
        if data.len() != batch * horizon * 3 {
            return Err(ConstraintError::Shape(format!(
                "{} values cannot be {batch} trajectories × {horizon} poses × 3",
                data.len()
            )));
        }
        Ok(Self {
            data,
            batch,
            horizon,
        })
    }

    /// The poses of trajectory `b`, flat `[T, 3]`.
    pub fn trajectory(&self, b: usize) -> &'a [f64] {
        let n = self.horizon * 3;
        &self.data[b * n..(b + 1) * n]
    }
}

/// What a constraint term may look at besides the trajectories. All in the trajectories' frame.
#[derive(Clone, Copy, Debug)]
pub struct ConstraintContext<'a> {
    /// Time between consecutive poses (s).
    pub dt: f64,
    /// The robot's hard limits.
    pub limits: &'a Limits,
    /// The robot's body velocity at the first pose (used for the first acceleration).
    pub initial_velocity: Twist2,
    /// Other agents, in the same frame as the trajectories (for clearance-style terms).
    pub agents: &'a [AgentState],
    /// What the planner knows of the scene beyond the agents' current states (empty unless
    /// the caller fills it: `scene: Default::default()`).
    pub scene: SceneContext<'a>,
}

/// The planning scene as the Human2Nav planner hands it to Φ, in the trajectories' frame: where
/// the people are expected to go, the static obstacles, the robot's body and its goal. The
/// built-in [`Clearance`] term reads it; plugin terms see the agents of [`ConstraintContext`]
/// only (the plugin ABI carries no more).
#[derive(Clone, Copy, Debug, Default)]
pub struct SceneContext<'a> {
    /// The forecast of the agents over the trajectories' waypoints (`None`: constant velocity
    /// from [`ConstraintContext::agents`]).
    pub forecast: Option<&'a Forecast>,
    /// Static obstacles near the robot.
    pub obstacles: &'a [Obstacle],
    /// The robot's footprint, placed at each pose.
    pub footprint: &'a [FootprintShape],
    /// The goal the trajectories head for, if any.
    pub goal: Option<[f64; 2]>,
}

/// Why a constraint term could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum ConstraintError {
    /// A batch or buffer whose size does not match the others; the message gives the sizes.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// A term could not be evaluated (an unusable limit, a plugin that failed).
    #[error("constraint `{term}` failed: {message}")]
    Failed {
        /// Name of the term ([`ConstraintTerm::name`]).
        term: String,
        /// Why it failed, on one line.
        message: String,
    },
}

/// One additive term of the feasibility cost.
///
/// `evaluate` writes one cost per trajectory and its gradient with respect to every pose value.
/// A term that penalises the squared distance of each trajectory's last pose from the origin:
///
/// ```
/// use human2nav_core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
/// use human2nav_core::{Limits, Twist2};
///
/// struct EndNearOrigin;
///
/// impl ConstraintTerm for EndNearOrigin {
///     fn name(&self) -> &str {
///         "end_near_origin"
///     }
///
///     fn evaluate(
///         &self,
///         batch: TrajBatch<'_>,
///         _ctx: &ConstraintContext<'_>,
///         cost: &mut [f64],
///         grad: &mut [f64],
///     ) -> Result<(), ConstraintError> {
///         grad.fill(0.0);
///         let per = batch.horizon * 3;
///         for (b, c) in cost.iter_mut().enumerate() {
///             let last = (b + 1) * per - 3;
///             let (x, y) = (batch.data[last], batch.data[last + 1]);
///             *c = x * x + y * y;
///             grad[last] = 2.0 * x;
///             grad[last + 1] = 2.0 * y;
///         }
///         Ok(())
///     }
/// }
///
/// let poses = [0.0, 0.0, 0.0, 3.0, 4.0, 0.0]; // one trajectory of two poses
/// let limits = Limits {
///     v_max: 1.5,
///     v_reverse_max: 0.5,
///     a_max: 1.0,
///     omega_max: 2.0,
///     kappa_max: None,
///     lateral_speed_max: 0.0,
///     coupled: None,
/// };
/// let ctx = ConstraintContext {
///     dt: 0.1,
///     limits: &limits,
///     initial_velocity: Twist2::ZERO,
///     agents: &[],
///     scene: Default::default(),
/// };
/// let (mut cost, mut grad) = ([0.0], [0.0; 6]);
/// EndNearOrigin.evaluate(TrajBatch::new(&poses, 1, 2)?, &ctx, &mut cost, &mut grad)?;
/// assert_eq!(cost, [25.0]);
/// assert_eq!(grad[3..5], [6.0, 8.0]);
/// # Ok::<(), ConstraintError>(())
/// ```
///
/// Written as a plugin, the same term goes behind `human2nav_plugin::export_plugin!`.
pub trait ConstraintTerm: Send + Sync {
    /// A short, stable name (`speed`, `acceleration`, `clearance`, ...).
    fn name(&self) -> &str;

    /// Adds this term's cost of trajectory `b` into `cost[b]` and its gradient with respect to
    /// every pose into `grad` (flat `[B, T, 3]`, the shape of `batch.data`).
    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError>;

    /// Adds this term's cost of trajectory `b` into `cost[b]`, without the gradient: what a
    /// planner's selection needs to score hundreds of candidates. The default evaluates the
    /// gradient into a scratch buffer and drops it; a term whose gradient is expensive
    /// overrides it.
    fn cost(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
    ) -> Result<(), ConstraintError> {
        let mut grad = vec![0.0; batch.data.len()];
        self.evaluate(batch, ctx, cost, &mut grad)
    }

    /// Whether this term's cost of a trajectory is never negative, is finite for finite
    /// poses, and is the same to the bit whatever other trajectories share its batch: what
    /// lets a planner's selection leave the term out for candidates whose score already loses
    /// without it. The default, `false`, is always safe; a term that answers `true` must hold
    /// to all three.
    fn separable_nonnegative(&self) -> bool {
        false
    }
}

pub mod builtin;
mod clearance;
pub(crate) mod near;
mod phi;

pub use builtin::{BuiltinKind, BuiltinTerm, SMOOTH_ABS_EPS, SoftMargin, sigmoid, softplus};
pub(crate) use clearance::closest_distance;
pub use clearance::{CLEARANCE, Clearance, arrival};
pub use phi::{Phi, PhiScratch};

#[cfg(test)]
mod tests;
