//! The four scenario classes and the flow classification of a window by the relevant agents'
//! velocities ([`ClassifyOptions`]).

use crate::error::DataError;
use serde::{Deserialize, Serialize};

/// The four crowd scenarios of the paper (Figs. 4, 6, 8).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScenarioClass {
    /// The crowd moves with the robot (`|α| ≤ 45°`, module docs).
    CoFlow,
    /// The crowd crosses the robot's path.
    CrossFlow,
    /// The crowd comes toward the robot (`|α| ≥ 135°`).
    CounterFlow,
    /// No direction holds the dominant share of the votes.
    MultidirectionFlow,
}

impl ScenarioClass {
    /// All classes in a fixed order.
    pub const ALL: [ScenarioClass; 4] = [
        Self::CoFlow,
        Self::CrossFlow,
        Self::CounterFlow,
        Self::MultidirectionFlow,
    ];

    /// The snake_case name used in files and reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::CoFlow => "co_flow",
            Self::CrossFlow => "cross_flow",
            Self::CounterFlow => "counter_flow",
            Self::MultidirectionFlow => "multidirection_flow",
        }
    }

    /// Position in [`ScenarioClass::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Inverse of [`ScenarioClass::index`].
    pub fn from_index(i: usize) -> Option<Self> {
        Self::ALL.get(i).copied()
    }

    /// Parses a snake_case name.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == s)
    }
}

impl std::fmt::Display for ScenarioClass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Thresholds of the flow classification (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClassifyOptions {
    /// Agents slower than this (m/s) do not vote. Default 0.3.
    pub moving_speed: f64,
    /// `|α|` up to this many degrees is co-flow. Default 45.
    pub co_angle_deg: f64,
    /// `|α|` from this many degrees on is counter-flow. Default 135.
    pub counter_angle_deg: f64,
    /// Share of votes a flow needs to name the window. Default 0.7.
    pub dominant_share: f64,
}

impl Default for ClassifyOptions {
    fn default() -> Self {
        Self {
            moving_speed: 0.3,
            co_angle_deg: 45.0,
            counter_angle_deg: 135.0,
            dominant_share: 0.7,
        }
    }
}

impl ClassifyOptions {
    /// Checks the thresholds are consistent.
    pub fn validate(&self) -> Result<(), DataError> {
        if !(self.moving_speed.is_finite() && self.moving_speed >= 0.0) {
            return Err(DataError::option(
                "classify.moving_speed",
                "must be finite and >= 0",
            ));
        }
        if !(0.0 < self.co_angle_deg
            && self.co_angle_deg <= self.counter_angle_deg
            && self.counter_angle_deg < 180.0)
        {
            return Err(DataError::option(
                "classify.co_angle_deg",
                "need 0 < co_angle_deg <= counter_angle_deg < 180",
            ));
        }
        if !(self.dominant_share > 0.5 && self.dominant_share <= 1.0) {
            return Err(DataError::option(
                "classify.dominant_share",
                "must be in (0.5, 1]",
            ));
        }
        Ok(())
    }
}

/// The flow one agent votes for, or `None` when it is (nearly) standing.
pub fn flow_of(
    direction: [f64; 2],
    velocity: [f64; 2],
    opts: &ClassifyOptions,
) -> Option<ScenarioClass> {
    let speed = velocity[0].hypot(velocity[1]);
    let norm = direction[0].hypot(direction[1]);
    let moving = speed > opts.moving_speed && norm > 0.0;
    if !moving {
        return None;
    }
    let cos = (velocity[0] * direction[0] + velocity[1] * direction[1]) / (speed * norm);
    let alpha = cos.clamp(-1.0, 1.0).acos().to_degrees();
    Some(if alpha <= opts.co_angle_deg {
        ScenarioClass::CoFlow
    } else if alpha >= opts.counter_angle_deg {
        ScenarioClass::CounterFlow
    } else {
        ScenarioClass::CrossFlow
    })
}

/// Classifies a window from the reference direction and the relevant agents' velocities.
pub fn classify(
    direction: [f64; 2],
    velocities: impl IntoIterator<Item = [f64; 2]>,
    opts: &ClassifyOptions,
) -> Option<ScenarioClass> {
    let mut votes = [0usize; 3];
    for v in velocities {
        match flow_of(direction, v, opts) {
            Some(ScenarioClass::CoFlow) => votes[0] += 1,
            Some(ScenarioClass::CrossFlow) => votes[1] += 1,
            Some(ScenarioClass::CounterFlow) => votes[2] += 1,
            _ => {}
        }
    }
    let total: usize = votes.iter().sum();
    if total == 0 {
        return None;
    }
    let flows = [
        ScenarioClass::CoFlow,
        ScenarioClass::CrossFlow,
        ScenarioClass::CounterFlow,
    ];
    for (k, &n) in votes.iter().enumerate() {
        if n as f64 >= opts.dominant_share * total as f64 {
            return Some(flows[k]);
        }
    }
    Some(ScenarioClass::MultidirectionFlow)
}
