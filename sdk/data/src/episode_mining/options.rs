//! The `[interaction]` options of `data.toml` ([`InteractionOptions`]) and their bounds.

use super::ReferenceRobot;
use crate::error::DataError;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Rules of the interaction-rich miner (module docs). The episode geometry comes from
/// [`MiningOptions`](crate::scenario::MiningOptions) (`[episodes]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InteractionOptions {
    /// Smallest time between the path's window start and the crowd start, seconds. Default 20.
    pub min_time_shift: f64,
    /// Crowd starts drawn per path direction. Default 32 (module docs, "Measured": with 8,
    /// co-flow and cross-flow fell short of 50 kept candidates).
    pub shifts_per_path: usize,
    /// Also drive each path from its goal back to its start. Default true.
    pub reverse: bool,
    /// Radius of the reference robot's disc, metres. Default 0.4.
    pub reference_radius: f64,
    /// Acceleration of the reference robot from rest, m/s². Default 1.0.
    pub reference_accel: f64,
    /// Nominal speeds of the reference robot, m/s; a candidate is interactive when the
    /// reference meets someone at every one of them. Default [1.0, 1.5, 2.0].
    pub reference_speeds: Vec<f64>,
    /// A pedestrian counts for the criterion only once its track has existed this long,
    /// seconds. Default 1.0.
    pub min_track_age: f64,
    /// Fewest relevant agents. Default 1.
    pub min_density: usize,
    /// Most relevant agents; unset: no cap. Default unset.
    pub max_density: Option<usize>,
    /// Seed of the crowd-start draws and of the selection shuffle. Default 11.
    pub seed: u64,
    /// Episode files (suites as `human2nav data episodes` writes them) whose episodes are never
    /// selected: with another `seed`, a fresh draw of the same scenes, disjoint from the
    /// suites named. Relative paths start at the workspace root. Default none.
    pub exclude_episodes: Vec<PathBuf>,
}

impl Default for InteractionOptions {
    fn default() -> Self {
        Self {
            min_time_shift: 20.0,
            shifts_per_path: 32,
            reverse: true,
            reference_radius: 0.4,
            reference_accel: 1.0,
            reference_speeds: vec![1.0, 1.5, 2.0],
            min_track_age: 1.0,
            min_density: 1,
            max_density: None,
            seed: 11,
            exclude_episodes: Vec::new(),
        }
    }
}

/// Largest `interaction.shifts_per_path` (the default is 32).
pub const MAX_SHIFTS_PER_PATH: usize = 10_000;

/// Most files in `interaction.exclude_episodes`.
pub const MAX_EXCLUDED_FILES: usize = 100;

impl InteractionOptions {
    /// Checks every option is usable; errors name the `interaction.<field>` key.
    pub fn validate(&self) -> Result<(), DataError> {
        let pos = crate::scenario::positive;
        pos(self.reference_radius, "interaction.reference_radius")?;
        pos(self.reference_accel, "interaction.reference_accel")?;
        // Upper and lower bounds keep every derived step count within the scene.
        use crate::input_limits::{MAX_TIME, count_at_most, option_in};
        option_in(
            self.reference_accel,
            0.01,
            100.0,
            "interaction.reference_accel",
        )?;
        option_in(
            self.min_time_shift,
            0.0,
            MAX_TIME,
            "interaction.min_time_shift",
        )?;
        option_in(
            self.min_track_age,
            0.0,
            MAX_TIME,
            "interaction.min_track_age",
        )?;
        count_at_most(
            self.shifts_per_path,
            MAX_SHIFTS_PER_PATH,
            "interaction.shifts_per_path",
        )?;
        if self.shifts_per_path == 0 {
            return Err(DataError::option(
                "interaction.shifts_per_path",
                "must be at least 1",
            ));
        }
        count_at_most(
            self.exclude_episodes.len(),
            MAX_EXCLUDED_FILES,
            "interaction.exclude_episodes",
        )?;
        if self.reference_speeds.is_empty() {
            return Err(DataError::option(
                "interaction.reference_speeds",
                "needs at least one speed",
            ));
        }
        if self
            .reference_speeds
            .iter()
            .any(|v| !(v.is_finite() && (0.01..=100.0).contains(v)))
        {
            return Err(DataError::option(
                "interaction.reference_speeds",
                format!(
                    "every speed must be in [0.01, 100] m/s (got {:?})",
                    self.reference_speeds
                ),
            ));
        }
        if let Some(max) = self.max_density
            && max < self.min_density
        {
            return Err(DataError::option(
                "interaction.max_density",
                format!("must not be below min_density ({})", self.min_density),
            ));
        }
        Ok(())
    }

    /// The slowest reference speed (the one the density probe drives at).
    pub fn slowest_speed(&self) -> f64 {
        self.reference_speeds
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
    }

    /// The reference robot at nominal speed `speed`.
    pub fn reference(&self, speed: f64) -> ReferenceRobot {
        ReferenceRobot {
            speed,
            accel: self.reference_accel,
            radius: self.reference_radius,
        }
    }
}
