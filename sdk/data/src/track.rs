//! Raw tracks as the loaders produce them: timestamped world positions in metres, possibly
//! irregular in time, one list per agent.

use serde::{Deserialize, Serialize};

/// What kind of agent a track is (SDD labels; ETH/UCY hold pedestrians only).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AgentClass {
    /// A person on foot (every ETH/UCY agent).
    Pedestrian,
    /// A cyclist.
    Biker,
    /// A skateboarder.
    Skater,
    /// A golf cart or similar small vehicle.
    Cart,
    /// A car.
    Car,
    /// A bus.
    Bus,
}

impl AgentClass {
    /// Parses an SDD label (`Pedestrian`, `Biker`, ...), with or without quotes.
    pub fn from_sdd_label(label: &str) -> Option<Self> {
        match label.trim_matches('"') {
            "Pedestrian" => Some(Self::Pedestrian),
            "Biker" => Some(Self::Biker),
            "Skater" => Some(Self::Skater),
            "Cart" => Some(Self::Cart),
            "Car" => Some(Self::Car),
            "Bus" => Some(Self::Bus),
            _ => None,
        }
    }
}

/// One timestamped observation of an agent: time in seconds, world position in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Time, seconds.
    pub t: f64,
    /// World position `[x, y]`, metres.
    pub p: [f64; 2],
}

/// All observations of one agent, sorted by time, as read from a file.
#[derive(Clone, Debug, PartialEq)]
pub struct RawTrack {
    /// The identity in the source file (SDD track id, ETH/UCY pedestrian id, the id of a TrajNet
    /// walk's first chunk).
    pub id: u64,
    /// What kind of agent it is.
    pub class: AgentClass,
    /// The observations, sorted by time.
    pub samples: Vec<Sample>,
}

/// How a source's samples are to be turned into a 0.1 s grid (set by each loader).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SourceTiming {
    /// Nominal spacing of the source samples, seconds (0.4 for the 2.5 fps files, 1/30 for SDD
    /// raw; for UCY splines the median control-point spacing).
    pub nominal_dt: f64,
    /// A gap between consecutive samples longer than this splits the track (seconds).
    pub max_gap: f64,
    /// Width of the centred moving-average window applied before resampling (seconds, 0 = none).
    pub smooth_window: f64,
}

/// The tracks of one recording (a scene or video) in one world frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RawScene {
    /// Scene name, `dataset/scene` (`eth/eth`, `ucy/zara01`, `sdd/gates_2`).
    pub name: String,
    /// Dataset name (`eth`, `ucy`, `sdd`, `synthetic`).
    pub dataset: String,
    /// Loader format (`ewap_obsmat`, `ucy_vsp`, `sgan`, `sdd_raw`, `sdd_trajnet`, `social_force`).
    pub format: String,
    /// How the source's samples are turned into the 0.1 s grid.
    pub timing: SourceTiming,
    /// One track per agent.
    pub tracks: Vec<RawTrack>,
    /// Rows or tracks the loader dropped, with the reason (`lost`, `class`, `duplicate`, ...).
    pub dropped: Vec<(String, usize)>,
}

impl RawScene {
    /// Adds `n` to the dropped counter named `why`.
    pub fn drop_count(&mut self, why: &str, n: usize) {
        if n == 0 {
            return;
        }
        match self.dropped.iter_mut().find(|(w, _)| w == why) {
            Some((_, c)) => *c += n,
            None => self.dropped.push((why.to_string(), n)),
        }
    }

    /// Number of samples over all tracks.
    pub fn sample_count(&self) -> usize {
        self.tracks.iter().map(|t| t.samples.len()).sum()
    }
}

/// Groups `(id, sample)` rows into tracks sorted by id, each sorted by time; rows repeating a
/// time already present in the same track are dropped and counted (returned second).
pub(crate) fn group_rows(rows: Vec<(u64, AgentClass, Sample)>) -> (Vec<RawTrack>, usize) {
    use std::collections::BTreeMap;
    let mut by_id: BTreeMap<u64, RawTrack> = BTreeMap::new();
    for (id, class, s) in rows {
        by_id
            .entry(id)
            .or_insert_with(|| RawTrack {
                id,
                class,
                samples: Vec::new(),
            })
            .samples
            .push(s);
    }
    let mut dup = 0;
    let tracks = by_id
        .into_values()
        .map(|mut t| {
            t.samples.sort_by(|a, b| a.t.total_cmp(&b.t));
            let before = t.samples.len();
            t.samples.dedup_by(|b, a| (b.t - a.t).abs() < 1e-9);
            dup += before - t.samples.len();
            t
        })
        .collect();
    (tracks, dup)
}
