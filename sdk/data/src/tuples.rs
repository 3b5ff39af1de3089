//! Training tuples: the paper's (BEV raster, goal, trajectory), plus the ego's velocity.
//!
//! For an ego pedestrian at step `k`, in the ego frame at that step (origin at the ego,
//! `x` along its heading):
//! * `bev`: the [`human2nav_core::bev`] raster of every other agent present at `k`;
//! * `goal`: the ego's position `goal_horizon` (5 s) later, or at the end of its track if that
//!   comes first (never earlier than the end of the 3.2 s future);
//! * `velocity`: the ego's velocity at `k`;
//! * `future`: the poses at `k+1 … k+32` (3.2 s at 0.1 s) as `(x, y, θ)`, the current pose
//!   (the identity) excluded.
//!
//! Windows start every `stride` steps. A track shorter than `horizon + 1` samples yields no
//! tuple (counted), and windows whose ego moves less than `min_future_displacement` over the
//! horizon are skipped (counted): a standing person has no heading to learn from.
//!
//! Tuples are stored compactly ([`CompactTuple`]): the neighbours that can touch the raster,
//! in the ego frame, instead of the dense raster, which is drawn at load time with the same
//! [`rasterize_agents`] call the planner uses at inference (with the ego at the identity).

use crate::error::DataError;
use crate::resample::Scene;
use crate::scenario::{ClassifyOptions, ScenarioClass, classify};
use crate::track::AgentClass;
use human2nav_core::Pose2;
use human2nav_core::bev::{BevAgent, BevSpec, rasterize_agents};
use serde::{Deserialize, Serialize};

/// Number of future poses in a tuple (3.2 s at 0.1 s).
pub const HORIZON: usize = 32;

/// One training example of the flow model.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingTuple {
    /// `[3, H, W]` BEV raster (occupancy, v_x, v_y in the ego frame).
    pub bev: Vec<f32>,
    /// Goal in the ego frame, metres.
    pub goal: [f32; 2],
    /// The ego's current velocity in the ego frame, m/s.
    pub velocity: [f32; 2],
    /// The next [`HORIZON`] poses `(x, y, θ)` in the ego frame, at `t+0.1 … t+3.2` s.
    pub future: Vec<[f32; 3]>,
    /// Index into the manifest's scenes.
    pub scene: u16,
}

/// Train / validation / test.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Scenes the model is trained on.
    Train,
    /// Scenes for validation and for tuning planner settings.
    Val,
    /// Held-out scenes: the benchmark's.
    Test,
}

impl Split {
    /// The three splits in order.
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    /// The lowercase name used in file names, configs and reports.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }
}

impl std::fmt::Display for Split {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Largest number of future poses per tuple (`tuples.horizon`; the model uses 32).
pub const MAX_HORIZON: usize = 1000;

/// Options of the tuple builder (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TupleOptions {
    /// Future poses per tuple (1 to [`MAX_HORIZON`]). Default 32.
    pub horizon: usize,
    /// Steps between window starts along one track. Default 5 (0.5 s).
    pub stride: usize,
    /// Goal = ego position this long after `t`, seconds. Default 5.
    pub goal_horizon: f64,
    /// Windows whose ego moves less than this over the horizon are skipped, metres. Default 0.5.
    pub min_future_displacement: f64,
    /// Disc radius of a pedestrian in the raster, metres. Default 0.3.
    pub agent_radius: f64,
    /// Disc radius of other agent classes (bikers, carts, cars, buses), metres. Default 0.6.
    pub vehicle_radius: f64,
    /// Thresholds of the per-tuple scenario class (for statistics only).
    pub classify: ClassifyOptions,
}

impl Default for TupleOptions {
    fn default() -> Self {
        Self {
            horizon: HORIZON,
            stride: 5,
            goal_horizon: 5.0,
            min_future_displacement: 0.5,
            agent_radius: 0.3,
            vehicle_radius: 0.6,
            classify: ClassifyOptions::default(),
        }
    }
}

impl TupleOptions {
    /// Checks every option is usable.
    pub fn validate(&self) -> Result<(), DataError> {
        if self.horizon == 0 || self.horizon > MAX_HORIZON {
            return Err(DataError::option(
                "tuples.horizon",
                format!("must be in 1..={MAX_HORIZON}"),
            ));
        }
        if self.stride == 0 {
            return Err(DataError::option("tuples.stride", "must be at least 1"));
        }
        for (v, f) in [
            (self.goal_horizon, "tuples.goal_horizon"),
            (self.agent_radius, "tuples.agent_radius"),
            (self.vehicle_radius, "tuples.vehicle_radius"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(DataError::option(f, "must be finite and positive"));
            }
        }
        crate::input_limits::option_in(
            self.goal_horizon,
            0.0,
            crate::input_limits::MAX_TIME,
            "tuples.goal_horizon",
        )?;
        if !(self.min_future_displacement.is_finite() && self.min_future_displacement >= 0.0) {
            return Err(DataError::option(
                "tuples.min_future_displacement",
                "must be finite and >= 0",
            ));
        }
        self.classify.validate()
    }

    /// Disc radius of an agent of `class`.
    pub fn radius(&self, class: AgentClass) -> f64 {
        match class {
            AgentClass::Pedestrian | AgentClass::Skater => self.agent_radius,
            _ => self.vehicle_radius,
        }
    }
}

/// A tuple with its neighbours stored sparsely (as in the cache).
#[derive(Clone, Debug, PartialEq)]
pub struct CompactTuple {
    /// Index into the manifest's scenes.
    pub scene: u16,
    /// Scenario class of the window from the agents in the raster (None: nobody moving).
    pub class: Option<ScenarioClass>,
    /// Goal in the ego frame, metres.
    pub goal: [f32; 2],
    /// The ego's current velocity in the ego frame, m/s.
    pub velocity: [f32; 2],
    /// The next [`HORIZON`] poses `(x, y, θ)` in the ego frame.
    pub future: Vec<[f32; 3]>,
    /// Neighbours in the ego frame: `[x, y, v_x, v_y, radius]`.
    pub agents: Vec<[f32; 5]>,
}

impl CompactTuple {
    /// Draws the BEV raster into `out` (`spec.len()` values).
    pub fn rasterize(&self, spec: &BevSpec, out: &mut [f32]) {
        let agents = self.agents.iter().map(|a| BevAgent {
            position: [a[0] as f64, a[1] as f64],
            velocity: [a[2] as f64, a[3] as f64],
            radius: a[4] as f64,
        });
        rasterize_agents(spec, Pose2::IDENTITY, agents, out);
    }

    /// The dense training tuple.
    pub fn to_tuple(&self, spec: &BevSpec) -> TrainingTuple {
        let mut bev = vec![0.0; spec.len()];
        self.rasterize(spec, &mut bev);
        TrainingTuple {
            bev,
            goal: self.goal,
            velocity: self.velocity,
            future: self.future.clone(),
            scene: self.scene,
        }
    }

    /// The ego's speed at `t`, m/s.
    pub fn speed(&self) -> f32 {
        self.velocity[0].hypot(self.velocity[1])
    }
}

/// Counters of what the tuple builder skipped.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TupleStats {
    /// Pedestrian tracks long enough to be an ego.
    pub ego_tracks: usize,
    /// Pedestrian tracks shorter than the horizon plus one step, skipped.
    pub too_short_tracks: usize,
    /// Tracks of other agent classes, never an ego.
    pub non_pedestrian_tracks: usize,
    /// Windows whose future moves less than `min_future_displacement`, skipped.
    pub stationary_windows: usize,
    /// Tuples made.
    pub tuples: usize,
}

impl TupleStats {
    /// Adds another scene's counters.
    pub fn add(&mut self, o: &TupleStats) {
        self.ego_tracks += o.ego_tracks;
        self.too_short_tracks += o.too_short_tracks;
        self.non_pedestrian_tracks += o.non_pedestrian_tracks;
        self.stationary_windows += o.stationary_windows;
        self.tuples += o.tuples;
    }
}

/// Builds every tuple of one scene (see the module docs), in track then time order.
pub fn scene_tuples(
    scene: &Scene,
    scene_index: u16,
    spec: &BevSpec,
    opts: &TupleOptions,
) -> (Vec<CompactTuple>, TupleStats) {
    let mut stats = TupleStats::default();
    let mut out = Vec::new();
    let index = scene.index();
    let goal_steps = (opts.goal_horizon / scene.dt)
        .round()
        .max(opts.horizon as f64) as usize;
    for (e, ego) in scene.tracks.iter().enumerate() {
        if ego.class != AgentClass::Pedestrian {
            stats.non_pedestrian_tracks += 1;
            continue;
        }
        if ego.len() < opts.horizon + 1 {
            stats.too_short_tracks += 1;
            continue;
        }
        stats.ego_tracks += 1;
        let mut k = 0;
        while k + opts.horizon < ego.len() {
            let p0 = ego.positions[k];
            let pe = ego.positions[k + opts.horizon];
            if (pe[0] - p0[0]).hypot(pe[1] - p0[1]) < opts.min_future_displacement {
                stats.stationary_windows += 1;
                k += opts.stride;
                continue;
            }
            let pose = ego.pose(k);
            let g = ego.positions[(k + goal_steps).min(ego.len() - 1)];
            let goal = pose.inverse_act(g);
            let v = pose.inverse_rotate(ego.velocities[k]);
            let future = (1..=opts.horizon)
                .map(|j| {
                    let q = pose.between(ego.pose(k + j));
                    [q.x as f32, q.y as f32, q.theta as f32]
                })
                .collect();
            let step = ego.start + k as i64;
            let mut agents = Vec::new();
            for &j in index.at(step) {
                let j = j as usize;
                if j == e {
                    continue;
                }
                let t = &scene.tracks[j];
                let Some(i) = t.local(step) else { continue };
                let r = opts.radius(t.class);
                let p = pose.inverse_act(t.positions[i]);
                if !spec.touches(p, r.max(spec.resolution)) {
                    continue;
                }
                let w = pose.inverse_rotate(t.velocities[i]);
                agents.push([p[0] as f32, p[1] as f32, w[0] as f32, w[1] as f32, r as f32]);
            }
            let class = classify(
                goal,
                agents.iter().map(|a| [a[2] as f64, a[3] as f64]),
                &opts.classify,
            );
            out.push(CompactTuple {
                scene: scene_index,
                class,
                goal: [goal[0] as f32, goal[1] as f32],
                velocity: [v[0] as f32, v[1] as f32],
                future,
                agents,
            });
            k += opts.stride;
        }
    }
    stats.tuples = out.len();
    (out, stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::resample::{ResampleStats, Track, central_difference, headings};
    use approx::assert_relative_eq;

    fn track(id: u64, start: i64, positions: Vec<[f64; 2]>) -> Track {
        let opts = crate::resample::ResampleOptions::default();
        let velocities = central_difference(&positions, 0.1);
        let (headings, _) = headings(&positions, 0.1, &opts);
        Track {
            id,
            source_id: id,
            class: AgentClass::Pedestrian,
            start,
            positions,
            velocities,
            headings,
        }
    }

    fn scene(tracks: Vec<Track>) -> Scene {
        Scene {
            name: "t/t".into(),
            dataset: "t".into(),
            format: "test".into(),
            dt: 0.1,
            tracks,
            stats: ResampleStats::default(),
            dropped: Vec::new(),
        }
    }

    #[test]
    fn straight_walker_gives_closed_form_tuples() {
        // Ego walks along world +y at 1.2 m/s for 10 s; a neighbour starts 2 m ahead of it and
        // drifts along −x at 0.5 m/s while keeping pace.
        let ego: Vec<[f64; 2]> = (0..100).map(|k| [1.0, 0.12 * k as f64]).collect();
        let other: Vec<[f64; 2]> = (0..100)
            .map(|k| [1.0 - 0.05 * k as f64, 2.0 + 0.12 * k as f64])
            .collect();
        let sc = scene(vec![track(0, 0, ego), track(1, 0, other)]);
        let opts = TupleOptions::default();
        let spec = BevSpec::default();
        let (tuples, stats) = scene_tuples(&sc, 3, &spec, &opts);
        // Ego: windows k = 0, 5, …, 65 (k + 32 < 100) → 14; the neighbour is an ego too.
        assert_eq!(stats.ego_tracks, 2);
        assert_eq!(tuples.len(), 28);
        let t = &tuples[2]; // ego 0 at k = 10
        assert_eq!(t.scene, 3);
        // Ego frame: x along world +y. Goal 5 s ahead = 6 m.
        assert_relative_eq!(t.goal[0], 6.0, epsilon = 1e-5);
        assert_relative_eq!(t.goal[1], 0.0, epsilon = 1e-5);
        assert_relative_eq!(t.velocity[0], 1.2, epsilon = 1e-5);
        assert_relative_eq!(t.velocity[1], 0.0, epsilon = 1e-5);
        assert_eq!(t.future.len(), 32);
        for (j, p) in t.future.iter().enumerate() {
            assert_relative_eq!(p[0], 0.12 * (j + 1) as f32, epsilon = 1e-5);
            assert_relative_eq!(p[1], 0.0, epsilon = 1e-5);
            assert_relative_eq!(p[2], 0.0, epsilon = 1e-5);
        }
        // Neighbour at world (1 − 0.5, 2 + 1.2) vs ego (1, 1.2): ego frame (2, 0.5); velocity
        // world (−0.5, 1.2) → ego frame (1.2, 0.5).
        assert_eq!(t.agents.len(), 1);
        let a = t.agents[0];
        assert_relative_eq!(a[0], 2.0, epsilon = 1e-5);
        assert_relative_eq!(a[1], 0.5, epsilon = 1e-5);
        assert_relative_eq!(a[2], 1.2, epsilon = 1e-5);
        assert_relative_eq!(a[3], 0.5, epsilon = 1e-5);
        assert_relative_eq!(a[4], 0.3, epsilon = 1e-7);
        assert_eq!(t.class, Some(ScenarioClass::CoFlow));
        // The dense raster has the neighbour's disc at (2, 0.5) with its ego-frame velocity.
        let dense = t.to_tuple(&spec);
        let (r, c) = spec.cell_of([2.0, 0.5]).unwrap();
        assert_eq!(dense.bev[spec.index(0, r, c)], 1.0);
        assert_relative_eq!(dense.bev[spec.index(1, r, c)], 1.2, epsilon = 1e-5);
        assert_relative_eq!(dense.bev[spec.index(2, r, c)], 0.5, epsilon = 1e-5);
        // Goal near the end of the track: clipped to the last sample.
        let last = tuples.iter().filter(|t| t.scene == 3).nth(13).unwrap();
        assert_relative_eq!(last.goal[0], 0.12 * (99 - 65) as f32, epsilon = 1e-4);
    }

    #[test]
    fn standing_and_short_tracks_are_skipped_and_counted() {
        let stand: Vec<[f64; 2]> = vec![[0.0, 0.0]; 60];
        let short: Vec<[f64; 2]> = (0..20).map(|k| [0.1 * k as f64, 0.0]).collect();
        let sc = scene(vec![track(0, 0, stand), track(1, 0, short)]);
        let (tuples, stats) = scene_tuples(&sc, 0, &BevSpec::default(), &TupleOptions::default());
        assert!(tuples.is_empty());
        assert_eq!(stats.too_short_tracks, 1);
        assert_eq!(stats.stationary_windows, 6); // k = 0, 5, …, 25
    }

    #[test]
    fn options_validate() {
        assert!(TupleOptions::default().validate().is_ok());
        assert!(
            TupleOptions {
                stride: 0,
                ..Default::default()
            }
            .validate()
            .is_err()
        );
        assert!(
            TupleOptions {
                agent_radius: f64::NAN,
                ..Default::default()
            }
            .validate()
            .is_err()
        );
    }
}
