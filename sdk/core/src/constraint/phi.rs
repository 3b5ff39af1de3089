//! Φ of Eq. 9: the weighted sum of constraint terms.

use super::builtin::{
    BuiltinKind, BuiltinTerm, Segments, SoftMargin, check_buffers, check_cost_buffer, check_dt,
};
use super::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use crate::limits::{GuidanceWeights, Limits};
use std::sync::Arc;

/// The feasibility cost `Φ(x) = Σ_j w_j·C_j(x)` (Eq. 9, extended by the lateral-speed and
/// reverse-speed terms and by any plugin terms).
///
/// Built with [`Phi::from_weights`] for the robot's built-in terms and extended with
/// [`Phi::push`]; a new constraint is one more `push`, nothing else changes. The terms are
/// shared, so [`Phi::without_limits`] is a second view of the same terms, not a copy.
#[derive(Default)]
pub struct Phi {
    terms: Vec<Weighted>,
}

/// One term of Φ with its weight; `builtin`: the robot's built-in limit term behind `term`
/// ([`Phi::from_weights`]) rather than a pushed one, which [`Phi::costs`] scores from the
/// segment values every built-in term shares.
struct Weighted {
    weight: f64,
    term: Arc<dyn ConstraintTerm>,
    builtin: Option<BuiltinTerm>,
}

/// Scratch buffers of [`Phi::evaluate`]; they grow to the largest batch seen and are reused, so
/// evaluation does not allocate once warm.
#[derive(Clone, Debug, Default)]
pub struct PhiScratch {
    cost: Vec<f64>,
    grad: Vec<f64>,
    segments: Segments,
}

impl std::fmt::Debug for Phi {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list()
            .entries(self.terms.iter().map(|t| (t.term.name(), t.weight)))
            .finish()
    }
}

impl Phi {
    /// An empty Φ (cost 0 everywhere).
    pub fn new() -> Self {
        Self::default()
    }

    /// The built-in terms weighted by `λ_v, λ_reverse, λ_a, λ_ω, λ_κ, λ_lateral, λ_coupled` with
    /// the soft margin `(γ, δ)` of `weights`. Terms of weight 0 are left out, and so are the
    /// curvature term when `limits.kappa_max` is `None` and the coupled term when
    /// `limits.coupled` is.
    pub fn from_weights(weights: &GuidanceWeights, limits: &Limits) -> Self {
        let margin = SoftMargin {
            gamma: weights.gamma,
            delta: weights.delta,
        };
        let mut phi = Self::new();
        for kind in BuiltinKind::ALL {
            let w = match kind {
                BuiltinKind::Speed => weights.lambda_v,
                BuiltinKind::Reverse => weights.lambda_reverse,
                BuiltinKind::Acceleration => weights.lambda_a,
                BuiltinKind::YawRate => weights.lambda_omega,
                BuiltinKind::Curvature if limits.kappa_max.is_none() => continue,
                BuiltinKind::Curvature => weights.lambda_kappa,
                BuiltinKind::Lateral => weights.lambda_lateral,
                BuiltinKind::Coupled if limits.coupled.is_none() => continue,
                BuiltinKind::Coupled => weights.lambda_coupled,
            };
            if w != 0.0 {
                let builtin = BuiltinTerm::new(kind, margin);
                phi.terms.push(Weighted {
                    weight: w,
                    term: Arc::new(builtin),
                    builtin: Some(builtin),
                });
            }
        }
        phi
    }

    /// Adds `weight · term`. The weight must be finite and non-negative.
    pub fn push(
        &mut self,
        weight: f64,
        term: Box<dyn ConstraintTerm>,
    ) -> Result<(), ConstraintError> {
        if !(weight.is_finite() && weight >= 0.0) {
            return Err(ConstraintError::Failed {
                term: term.name().to_owned(),
                message: format!("weight {weight} must be finite and non-negative"),
            });
        }
        self.terms.push(Weighted {
            weight,
            term: Arc::from(term),
            builtin: None,
        });
        Ok(())
    }

    /// The terms pushed onto Φ (plugin terms, the planner's clearance term) without the
    /// robot's built-in limit terms of [`Phi::from_weights`]: what Algorithm 1 descends when
    /// the last-step correction enforces the limits exactly. Shares the terms with `self`.
    pub fn without_limits(&self) -> Phi {
        Phi {
            terms: self
                .terms
                .iter()
                .filter(|t| t.builtin.is_none())
                .map(|t| Weighted {
                    weight: t.weight,
                    term: Arc::clone(&t.term),
                    builtin: None,
                })
                .collect(),
        }
    }

    /// Whether every term of Φ is [`ConstraintTerm::separable_nonnegative`] (the weights are
    /// never negative): then so is Φ, and Φ of a subset of a batch is Φ of those trajectories
    /// in the whole batch, to the bit.
    pub fn separable_nonnegative(&self) -> bool {
        self.terms
            .iter()
            .all(|t| t.weight == 0.0 || t.term.separable_nonnegative())
    }

    /// Number of terms.
    pub fn len(&self) -> usize {
        self.terms.len()
    }

    /// True when Φ has no term.
    pub fn is_empty(&self) -> bool {
        self.terms.is_empty()
    }

    /// `(weight, name)` of every term, in evaluation order.
    pub fn terms(&self) -> impl Iterator<Item = (f64, &str)> + '_ {
        self.terms.iter().map(|t| (t.weight, t.term.name()))
    }

    /// Writes `Φ` of every trajectory into `cost` (length `B`) and `∇Φ` with respect to every
    /// pose into `grad` (the shape of `batch.data`). Both are overwritten, not added to.
    pub fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
        scratch: &mut PhiScratch,
    ) -> Result<(), ConstraintError> {
        check_buffers("phi", &batch, ctx, cost, grad)?;
        cost.fill(0.0);
        grad.fill(0.0);
        scratch.cost.resize(cost.len(), 0.0);
        scratch.grad.resize(grad.len(), 0.0);
        for Weighted {
            weight: w, term, ..
        } in &self.terms
        {
            if *w == 0.0 {
                continue;
            }
            scratch.cost.fill(0.0);
            scratch.grad.fill(0.0);
            term.evaluate(batch, ctx, &mut scratch.cost, &mut scratch.grad)?;
            check_finite(term.as_ref(), &scratch.cost, batch.batch, "cost")?;
            check_finite(term.as_ref(), &scratch.grad, batch.batch, "gradient")?;
            for (c, s) in cost.iter_mut().zip(&scratch.cost) {
                *c += w * s;
            }
            for (g, s) in grad.iter_mut().zip(&scratch.grad) {
                *g += w * s;
            }
        }
        Ok(())
    }

    /// Writes `Φ` of every trajectory into `cost` (length `B`, overwritten) without its
    /// gradient ([`ConstraintTerm::cost`]): how a planner's selection scores its candidates.
    /// A term that fails or returns a non-finite cost is an error naming the term.
    pub fn costs(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        scratch: &mut PhiScratch,
    ) -> Result<(), ConstraintError> {
        check_cost_buffer("phi", &batch, cost)?;
        cost.fill(0.0);
        scratch.cost.resize(cost.len(), 0.0);
        // The built-in terms read one set of segment values instead of each computing its own.
        if let Some(first) = self
            .terms
            .iter()
            .find(|t| t.builtin.is_some() && t.weight != 0.0)
        {
            check_dt(first.term.name(), ctx)?;
            scratch.segments.fill(&batch, ctx.dt);
        }
        for Weighted {
            weight: w,
            term,
            builtin,
            ..
        } in &self.terms
        {
            if *w == 0.0 {
                continue;
            }
            scratch.cost.fill(0.0);
            match builtin {
                Some(b) => b.add_costs(&mut scratch.segments, ctx, &mut scratch.cost)?,
                None => term.cost(batch, ctx, &mut scratch.cost)?,
            }
            check_finite(term.as_ref(), &scratch.cost, batch.batch, "cost")?;
            for (c, s) in cost.iter_mut().zip(&scratch.cost) {
                *c += w * s;
            }
        }
        Ok(())
    }

    /// Per-term costs for diagnostics: `out[j·B + b]` is the *unweighted* cost of term `j` on
    /// trajectory `b` (`out.len()` must be `len()·B`).
    pub fn term_costs(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        out: &mut [f64],
        scratch: &mut PhiScratch,
    ) -> Result<(), ConstraintError> {
        if out.len() != self.terms.len() * batch.batch {
            return Err(ConstraintError::Shape(format!(
                "`phi`: {} values cannot hold {} terms × {} trajectories",
                out.len(),
                self.terms.len(),
                batch.batch
            )));
        }
        scratch.grad.resize(batch.data.len(), 0.0);
        out.fill(0.0);
        for (j, Weighted { term, .. }) in self.terms.iter().enumerate() {
            let slot = &mut out[j * batch.batch..(j + 1) * batch.batch];
            term.evaluate(batch, ctx, slot, &mut scratch.grad)?;
        }
        Ok(())
    }
}

/// An error naming `term` when one of its `values` (a cost per trajectory, or a gradient of
/// `batch` trajectories) is not finite: Φ never passes such a value on, and never drops a term
/// in silence.
fn check_finite(
    term: &dyn ConstraintTerm,
    values: &[f64],
    batch: usize,
    what: &str,
) -> Result<(), ConstraintError> {
    let Some(i) = values.iter().position(|v| !v.is_finite()) else {
        return Ok(());
    };
    let per = (values.len() / batch.max(1)).max(1);
    Err(ConstraintError::Failed {
        term: term.name().to_owned(),
        message: format!(
            "returned a non-finite {what} ({}) for trajectory {} of {batch}",
            values[i],
            i / per
        ),
    })
}
