//! [`HistoryRidge`]: people predicted linearly from their recent positions.

use super::{CrowdPredictor, Forecast, ForecastError, constant_velocity_path};
use crate::planner::Observation;
use crate::se2::Pose2;
use serde::{Deserialize, Serialize};

/// A linear predictor of people from their recent positions: in the frame of the walker's
/// heading, its last `history` steps (and a constant) map linearly to how far its next
/// `horizon` positions depart from walking on at its last step. Fitted by ridge regression on
/// recorded tracks (`human2nav data predict --fit-on <data.toml> --export <file>`), saved as
/// TOML. An agent whose observation holds fewer than `history + 1` positions walks on at its
/// velocity; past `horizon` the last departure is held.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HistoryRidge {
    /// Steps of history the model reads (`history + 1` positions, the last the present).
    pub history: usize,
    /// Steps it predicts.
    pub horizon: usize,
    /// Seconds per step of the tracks it was fitted on; the planner's waypoints must match.
    pub dt: f64,
    /// What it was fitted on, in words.
    pub fitted_on: String,
    /// Row-major `(2·history + 1) × (2·horizon)`: row `f` holds feature `f`'s weight on each
    /// departure `(x, y)` of each predicted step, in the heading frame.
    pub weights: Vec<f64>,
}

impl HistoryRidge {
    /// Checks the shape and that every number is finite.
    pub fn validate(&self) -> Result<(), String> {
        if !(1..=1000).contains(&self.history) || !(1..=1000).contains(&self.horizon) {
            return Err(format!(
                "history and horizon must be 1 to 1000 steps, got {} and {}",
                self.history, self.horizon
            ));
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(format!("dt must be a time above 0 s, got {}", self.dt));
        }
        let want = (2 * self.history + 1) * 2 * self.horizon;
        if self.weights.len() != want {
            return Err(format!(
                "weights: {} numbers, the shape {} × {} needs {want}",
                self.weights.len(),
                2 * self.history + 1,
                2 * self.horizon
            ));
        }
        if let Some(i) = self.weights.iter().position(|w| !w.is_finite()) {
            return Err(format!("weights[{i}] is not a finite number"));
        }
        Ok(())
    }

    /// The walker's heading frame (a rotation) from its positions: the last step's direction,
    /// or the whole history's displacement when the last step is (nearly) zero, or the world's
    /// axes.
    pub fn heading(past: &[[f64; 2]]) -> Pose2 {
        let n = past.len();
        if n >= 2 {
            for d in [sub(past[n - 1], past[n - 2]), sub(past[n - 1], past[0])] {
                if d[0].hypot(d[1]) > 1e-4 {
                    return Pose2::new(0.0, 0.0, d[1].atan2(d[0]));
                }
            }
        }
        Pose2::IDENTITY
    }

    /// The features of `past` (positions, oldest first): each step's displacement in the
    /// heading `frame`, then 1.
    pub fn features(past: &[[f64; 2]], frame: Pose2) -> Vec<f64> {
        past.windows(2)
            .flat_map(|p| frame.inverse_rotate(sub(p[1], p[0])))
            .chain(std::iter::once(1.0))
            .collect()
    }

    /// `n` predicted positions after the last of `past` (`history + 1` positions, oldest
    /// first): the last step held, plus the model's departures turned out of the heading frame
    /// (the last one held past `horizon`). `None` when `past` has another length.
    pub fn predict(&self, past: &[[f64; 2]], n: usize) -> Option<Vec<[f64; 2]>> {
        if past.len() != self.history + 1 {
            return None;
        }
        let frame = Self::heading(past);
        let x = Self::features(past, frame);
        let outputs = 2 * self.horizon;
        let mut d = vec![0.0; outputs];
        for (xf, row) in x.iter().zip(self.weights.chunks_exact(outputs)) {
            for (d, w) in d.iter_mut().zip(row) {
                *d += xf * w;
            }
        }
        let now = past[self.history];
        let step = sub(now, past[self.history - 1]);
        Some(
            (0..n)
                .map(|i| {
                    let k = i.min(self.horizon - 1);
                    let dep = frame.rotate([d[2 * k], d[2 * k + 1]]);
                    let s = (i + 1) as f64;
                    [now[0] + step[0] * s + dep[0], now[1] + step[1] * s + dep[1]]
                })
                .collect(),
        )
    }
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

impl CrowdPredictor for HistoryRidge {
    fn name(&self) -> &str {
        "history-ridge"
    }

    fn forecast(
        &mut self,
        obs: &Observation,
        horizon: usize,
        dt: f64,
    ) -> Result<Forecast, ForecastError> {
        if (dt - self.dt).abs() > 1e-9 {
            return Err(ForecastError::Step {
                predictor: "history model",
                fitted: self.dt,
                plan: dt,
            });
        }
        Forecast::one_path_each(&obs.agents, horizon, |a| {
            let h = &a.history;
            let past = &h[h.len().saturating_sub(self.history + 1)..];
            self.predict(past, horizon)
                .filter(|p| p.iter().flatten().all(|v| v.is_finite()))
                .unwrap_or_else(|| constant_velocity_path(a, horizon, dt))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forecast::tests::walker;
    use crate::planner::AgentState;

    /// A history model whose only weight is on the constant feature: every walker departs to
    /// its left by 0.1 m per step from walking on at its last step, whichever way it walks; a
    /// walker with too short a history walks on at its velocity.
    #[test]
    fn the_history_model_departs_in_each_walkers_own_frame() {
        let (history, horizon) = (2, 4);
        let mut weights = vec![0.0; (2 * history + 1) * 2 * horizon];
        let constant = 2 * history;
        for k in 0..horizon {
            weights[constant * 2 * horizon + 2 * k + 1] = 0.1 * (k + 1) as f64;
        }
        let mut model = HistoryRidge {
            history,
            horizon,
            dt: 0.1,
            fitted_on: "by hand".into(),
            weights,
        };
        model.validate().unwrap();
        let with_history = |id, history: Vec<[f64; 2]>, v| AgentState {
            history,
            ..walker(id, [0.0, 0.0], v)
        };
        let obs = Observation {
            agents: vec![
                // Along +x: its left is +y.
                with_history(1, vec![[-0.2, 0.0], [-0.1, 0.0], [0.0, 0.0]], [1.0, 0.0]),
                // Along +y: its left is −x.
                with_history(2, vec![[0.0, -0.2], [0.0, -0.1], [0.0, 0.0]], [0.0, 1.0]),
                // One step of history only: constant velocity.
                with_history(3, vec![[0.0, -0.1], [0.0, 0.0]], [0.0, 1.0]),
            ],
            ..Observation::default()
        };
        let f = model.forecast(&obs, 6, 0.1).unwrap();
        let near = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]) < 1e-12;
        assert!(near(f.position(0, 0, 1), [0.2, 0.2]));
        assert!(near(f.position(1, 0, 1), [-0.2, 0.2]));
        // Past the model's four steps the last departure is held.
        assert!(near(f.position(0, 0, 5), [0.6, 0.4]));
        assert!(near(f.position(2, 0, 5), [0.0, 0.6]));
        assert!(model.forecast(&obs, 6, 0.05).is_err());
        model.weights.pop();
        assert!(model.validate().unwrap_err().starts_with("weights: "));
        model.weights.push(f64::NAN);
        assert!(model.validate().unwrap_err().contains("finite"));
    }
}
