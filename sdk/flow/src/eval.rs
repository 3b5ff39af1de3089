//! Held-out evaluation of a flow model: best-of-K ADE/FDE against the true futures, the
//! constant-velocity baseline on the same windows, and how often trajectories come close to
//! other agents.
//!
//! * ADE: mean over the `T` waypoints of the Euclidean position error; FDE: error at the last
//!   waypoint. Best-of-K takes the minimum over the `K` sampled futures of each window
//!   (ADE and FDE minimised separately, the usual convention).
//! * Constant velocity: waypoint `j` (time `(j + 1)·dt`) at `(j + 1)·dt·v` with `v` the ego
//!   velocity of the condition (ego frame).
//! * Proximity: a trajectory "comes within `r`" of another agent when, at some waypoint `j`,
//!   its position is closer than `r` to that agent's position at the same time. Reported as the
//!   fraction of sampled trajectories (model) and of windows (ground truth) that do.

use crate::sampler::sample;
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel};
use human2nav_core::se2::Pose2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// One held-out window.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalWindow {
    /// The model's condition (BEV, goal, ego velocity).
    pub cond: FlowCondition,
    /// The true future, `T` poses in the ego frame.
    pub future: Vec<Pose2>,
    /// Other agents' positions over the same `T` future steps, ego frame; `None` where an
    /// agent is not observed. Empty when unknown.
    pub others: Vec<Vec<Option<[f64; 2]>>>,
}

/// Options of [`evaluate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvalOptions {
    /// Samples per window `K`. Default 20.
    pub samples: usize,
    /// Euler steps `N`. Default 10.
    pub steps: usize,
    /// Waypoint spacing in seconds (for the constant-velocity baseline). Default 0.1.
    pub dt: f64,
    /// Proximity radius in metres. Default 0.3.
    pub radius: f64,
    /// Seed of the source samples.
    pub seed: u64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            samples: 20,
            steps: 10,
            dt: 0.1,
            radius: 0.3,
            seed: 0,
        }
    }
}

/// Aggregated metrics over all windows (means over windows).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EvalMetrics {
    pub windows: usize,
    pub min_ade: f64,
    pub min_fde: f64,
    pub mean_ade: f64,
    pub cv_ade: f64,
    pub cv_fde: f64,
    /// Fraction of sampled trajectories within `radius` of another agent.
    pub proximity_model: f64,
    /// Fraction of true futures within `radius` of another agent.
    pub proximity_truth: f64,
    /// Fraction of constant-velocity predictions within `radius` of another agent.
    pub proximity_cv: f64,
}

/// `(ADE, FDE)` of a predicted trajectory (flat `[T, 3]`) against the truth.
pub fn displacement_errors(pred: &[f64], truth: &[Pose2]) -> (f64, f64) {
    let mut sum = 0.0;
    let mut last = 0.0;
    for (p, q) in pred.chunks_exact(3).zip(truth) {
        last = ((p[0] - q.x).powi(2) + (p[1] - q.y).powi(2)).sqrt();
        sum += last;
    }
    (sum / truth.len().max(1) as f64, last)
}

/// The constant-velocity prediction of `horizon` waypoints, flat `[T, 3]` (heading along the
/// velocity, or 0 when standing).
pub fn constant_velocity(velocity: [f64; 2], horizon: usize, dt: f64) -> Vec<f64> {
    let heading = if velocity[0].hypot(velocity[1]) > 1e-6 {
        velocity[1].atan2(velocity[0])
    } else {
        0.0
    };
    (0..horizon)
        .flat_map(|j| {
            let s = (j + 1) as f64 * dt;
            [velocity[0] * s, velocity[1] * s, heading]
        })
        .collect()
}

/// Whether a trajectory (flat `[T, 3]`) comes within `radius` of any other agent.
pub fn comes_close(traj: &[f64], others: &[Vec<Option<[f64; 2]>>], radius: f64) -> bool {
    others.iter().any(|agent| {
        traj.chunks_exact(3).zip(agent).any(|(p, o)| match o {
            Some(o) => (p[0] - o[0]).hypot(p[1] - o[1]) < radius,
            None => false,
        })
    })
}

/// Keeps a seeded random subset of at most `n` items (order shuffled).
pub fn subsample<T>(items: &mut Vec<T>, n: usize, seed: u64) {
    use rand::seq::SliceRandom;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    items.shuffle(&mut rng);
    items.truncate(n);
}

/// Evaluates `model` on `windows`; `progress` is called after each window.
pub fn evaluate<M: FlowModel + ?Sized>(
    model: &M,
    windows: &[EvalWindow],
    opts: &EvalOptions,
    mut progress: impl FnMut(usize),
) -> Result<EvalMetrics, FlowError> {
    let t = model.horizon();
    let mut m = EvalMetrics {
        windows: windows.len(),
        ..EvalMetrics::default()
    };
    if windows.is_empty() {
        return Ok(m);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let mut close_samples = 0usize;
    for (w, win) in windows.iter().enumerate() {
        if win.future.len() != t {
            return Err(FlowError::Shape(format!(
                "window {w}: {} future poses, model horizon {t}",
                win.future.len()
            )));
        }
        let x = sample(model, &win.cond, opts.samples, opts.steps, &mut rng)?;
        let (mut best_ade, mut best_fde, mut mean_ade) = (f64::INFINITY, f64::INFINITY, 0.0);
        for traj in x.chunks_exact(3 * t) {
            let (ade, fde) = displacement_errors(traj, &win.future);
            best_ade = best_ade.min(ade);
            best_fde = best_fde.min(fde);
            mean_ade += ade / opts.samples as f64;
            if comes_close(traj, &win.others, opts.radius) {
                close_samples += 1;
            }
        }
        let cv = constant_velocity(win.cond.velocity, t, opts.dt);
        let (cv_ade, cv_fde) = displacement_errors(&cv, &win.future);
        let truth: Vec<f64> = win.future.iter().flat_map(|p| p.to_array()).collect();
        m.min_ade += best_ade;
        m.min_fde += best_fde;
        m.mean_ade += mean_ade;
        m.cv_ade += cv_ade;
        m.cv_fde += cv_fde;
        m.proximity_truth += f64::from(u8::from(comes_close(&truth, &win.others, opts.radius)));
        m.proximity_cv += f64::from(u8::from(comes_close(&cv, &win.others, opts.radius)));
        progress(w + 1);
    }
    let n = windows.len() as f64;
    m.min_ade /= n;
    m.min_fde /= n;
    m.mean_ade /= n;
    m.cv_ade /= n;
    m.cv_fde /= n;
    m.proximity_truth /= n;
    m.proximity_cv /= n;
    m.proximity_model = close_samples as f64 / (n * opts.samples as f64);
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn errors_of_a_shifted_line() {
        let truth: Vec<Pose2> = (1..=4).map(|j| Pose2::new(j as f64, 0.0, 0.0)).collect();
        let pred: Vec<f64> = (1..=4).flat_map(|j| [j as f64, 0.5, 0.0]).collect();
        let (ade, fde) = displacement_errors(&pred, &truth);
        assert_relative_eq!(ade, 0.5, epsilon = 1e-12);
        assert_relative_eq!(fde, 0.5, epsilon = 1e-12);
    }

    #[test]
    fn constant_velocity_is_linear_in_time() {
        let cv = constant_velocity([1.0, -0.5], 3, 0.1);
        assert_relative_eq!(cv[6], 0.3, epsilon = 1e-12);
        assert_relative_eq!(cv[7], -0.15, epsilon = 1e-12);
        assert_relative_eq!(cv[8], (-0.5f64).atan2(1.0), epsilon = 1e-12);
    }

    #[test]
    fn proximity_uses_same_time_positions() {
        let traj = vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        // At step 0 the agent is far; at step 1 it sits 0.2 m away.
        let near = vec![vec![Some([5.0, 0.0]), Some([1.0, 0.2])]];
        assert!(comes_close(&traj, &near, 0.3));
        // The same positions at swapped times are not a close approach.
        let swapped = vec![vec![Some([1.0, 0.2]), Some([5.0, 0.0])]];
        assert!(!comes_close(&traj, &swapped, 0.3));
        let unobserved = vec![vec![None, None]];
        assert!(!comes_close(&traj, &unobserved, 0.3));
    }
}
