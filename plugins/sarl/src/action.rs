//! SARL's discrete holonomic action space (CrowdNav `build_action_space`).
//!
//! `speed_samples` speeds spaced exponentially, `v_k = (e^{k/K} − 1)/(e − 1) · v_pref` for
//! `k = 1..K` (so the fastest is exactly `v_pref` and slow speeds are dense), times
//! `rotation_samples` headings evenly spaced in `[0, 2π)`, plus the stop action first.
//! With CrowdNav's `K = 5` speeds and 16 headings that is 81 actions.

use std::f64::consts::{E, PI};

/// Speeds per heading (CrowdNav default).
pub const SPEED_SAMPLES: usize = 5;
/// Headings (CrowdNav default).
pub const ROTATION_SAMPLES: usize = 16;

/// The discrete actions as world-frame velocities `[vx, vy]`; `actions[0]` is stop.
#[derive(Clone, Debug, PartialEq)]
pub struct ActionSpace {
    /// The speeds `v_1 < … < v_K` (m/s).
    pub speeds: Vec<f64>,
    /// The headings (rad), `2π·j/R`.
    pub headings: Vec<f64>,
    /// Stop, then every (heading, speed) pair heading-major.
    pub actions: Vec<[f64; 2]>,
}

impl ActionSpace {
    /// The action space for a robot with preferred speed `v_pref`.
    pub fn holonomic(v_pref: f64, speed_samples: usize, rotation_samples: usize) -> Self {
        let speeds: Vec<f64> = (1..=speed_samples)
            .map(|k| ((k as f64 / speed_samples as f64).exp() - 1.0) / (E - 1.0) * v_pref)
            .collect();
        let headings: Vec<f64> = (0..rotation_samples)
            .map(|j| 2.0 * PI * j as f64 / rotation_samples as f64)
            .collect();
        let mut actions = Vec::with_capacity(1 + speeds.len() * headings.len());
        actions.push([0.0, 0.0]);
        for &h in &headings {
            let (s, c) = h.sin_cos();
            for &v in &speeds {
                actions.push([v * c, v * s]);
            }
        }
        Self {
            speeds,
            headings,
            actions,
        }
    }

    /// CrowdNav's 81 actions (5 speeds × 16 headings + stop) for `v_pref`.
    pub fn crowdnav(v_pref: f64) -> Self {
        Self::holonomic(v_pref, SPEED_SAMPLES, ROTATION_SAMPLES)
    }

    /// Number of actions.
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    /// Never true for a valid space (stop is always there).
    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }
}
