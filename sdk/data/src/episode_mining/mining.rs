//! Mining one scene: the pedestrian windows and their paths, the crowd starts drawn for each,
//! the episode of one (path, crowd start) or why there is none, and the miner's counters.

use super::{InteractionOptions, is_interactive};
use crate::resample::{Scene, StepIndex};
use crate::scenario::{
    Episode, MiningOptions, ScenarioClass, classify, dist, export_agents, goal_index,
    relevant_agents, start_blocked,
};
use crate::track::AgentClass;
use human2nav_core::Pose2;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashSet};

/// One direction of a pedestrian's window: the robot's straight path.
#[derive(Clone, Debug, PartialEq)]
pub struct EgoPath {
    /// Index of the pedestrian's track in [`Scene::tracks`].
    pub track: usize,
    /// Global step at which the pedestrian started the window.
    pub s0: i64,
    /// The robot's start, world frame, metres.
    pub start: [f64; 2],
    /// The robot's goal, world frame, metres.
    pub goal: [f64; 2],
    /// True when the path runs from the window's goal back to its start.
    pub reversed: bool,
}

impl EgoPath {
    /// The robot's start pose: at `start`, facing the goal.
    pub fn start_pose(&self) -> Pose2 {
        let th = (self.goal[1] - self.start[1]).atan2(self.goal[0] - self.start[0]);
        Pose2::new(self.start[0], self.start[1], th)
    }
}

/// The non-overlapping windows of every pedestrian track of `scene` (module docs), as
/// `(track, first local index, goal local index)`: one track's next window starts where the
/// previous one reached its goal; where the goal is not reached in time, one second later.
pub fn ego_windows(scene: &Scene, geometry: &MiningOptions) -> Vec<(usize, usize, usize)> {
    let step = (1.0 / scene.dt).round().max(1.0) as usize;
    let mut out = Vec::new();
    for (e, t) in scene.tracks.iter().enumerate() {
        if t.class != AgentClass::Pedestrian {
            continue;
        }
        let mut i0 = 0usize;
        while i0 + 1 < t.len() {
            match goal_index(t, i0, scene.dt, geometry) {
                Some(ig) => {
                    out.push((e, i0, ig));
                    i0 = ig;
                }
                None => i0 += step,
            }
        }
    }
    out
}

/// The crowd starts allowed for a path whose window starts at global step `s0` and whose
/// budget lasts `steps`: on the 1 s grid around `s0`, at least `min_time_shift` away from it,
/// with `[c0, c0 + steps]` inside the recording. Ascending.
pub fn allowed_crowd_starts(
    scene: &Scene,
    s0: i64,
    steps: i64,
    opts: &InteractionOptions,
) -> Vec<i64> {
    let Some((first, last)) = scene.step_range() else {
        return Vec::new();
    };
    let grid = (1.0 / scene.dt).round().max(1.0) as i64;
    let min_shift = (opts.min_time_shift / scene.dt - 1e-9).ceil().max(0.0) as i64;
    let lo = (first - s0).div_euclid(grid) - 1;
    let hi = (last - steps - s0).div_euclid(grid) + 1;
    (lo..=hi)
        .map(|k| s0 + k * grid)
        .filter(|&c0| (c0 - s0).abs() >= min_shift && c0 >= first && c0 + steps <= last)
        .collect()
}

/// A 64-bit mix (splitmix64's finaliser).
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A stable hash of a scene name (FNV-1a).
fn name_hash(name: &str) -> u64 {
    name.bytes().fold(0xCBF2_9CE4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01B3)
    })
}

/// The crowd starts tried for `path`: up to `shifts_per_path` of the allowed ones, drawn
/// without replacement with an RNG seeded by the seed, the scene, the track, the window and
/// the direction. Draw order.
pub fn draw_crowd_starts(
    scene: &Scene,
    path: &EgoPath,
    steps: i64,
    opts: &InteractionOptions,
) -> Vec<i64> {
    let mut allowed = allowed_crowd_starts(scene, path.s0, steps, opts);
    let seed = mix(opts.seed
        ^ mix(name_hash(&scene.name)
            ^ mix(scene.tracks[path.track].id ^ mix(path.s0 as u64 ^ mix(path.reversed as u64)))));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = opts.shifts_per_path.min(allowed.len());
    let (picked, _) = allowed.partial_shuffle(&mut rng, n);
    picked.to_vec()
}

/// Why [`try_interaction`] rejected a candidate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InteractionReject {
    /// The crowd window does not lie inside the recording.
    OutsideRecording,
    /// Someone is too close to the start during `start_window`.
    StartBlocked,
    /// The number of relevant agents is outside `[min_density, max_density]`.
    DensityOutOfRange,
    /// No relevant agent moves fast enough to vote on a class.
    Unclassified,
    /// The reference robot reached the goal without meeting anyone at some reference speed.
    NotInteractive(ScenarioClass),
}

/// The episode of `path` with the crowd of global steps `[c0, c0 + budget]`, or why there is
/// none (module docs).
pub fn try_interaction(
    scene: &Scene,
    index: &StepIndex,
    path: &EgoPath,
    c0: i64,
    geometry: &MiningOptions,
    opts: &InteractionOptions,
) -> Result<Episode, InteractionReject> {
    let dt = scene.dt;
    let distance = dist(path.start, path.goal);
    let budget = geometry.budget(distance);
    if budget.is_nan() || budget > crate::scenario::MAX_TIME_BUDGET {
        // No episode file could hold it (Episode::validate).
        return Err(InteractionReject::OutsideRecording);
    }
    let steps = (budget / dt - 1e-9).ceil() as i64;
    let (first, last) = scene
        .step_range()
        .ok_or(InteractionReject::OutsideRecording)?;
    if c0 < first || c0 + steps > last {
        return Err(InteractionReject::OutsideRecording);
    }
    if start_blocked(scene, index, None, c0, path.start, geometry) {
        return Err(InteractionReject::StartBlocked);
    }
    // The reference's positions up to its arrival, within the episode's steps.
    let reference = opts.reference(opts.slowest_speed());
    let arrival = (reference.arrival_time(distance) / dt - 1e-9)
        .ceil()
        .max(0.0);
    let last_k = arrival.min(steps.max(0) as f64) as i64;
    let probe = (0..=last_k).map(|k| {
        let p = reference.position(path.start, path.goal, k as f64 * dt);
        (c0 + k, p)
    });
    let relevant = relevant_agents(scene, index, probe, None, geometry.density_radius);
    let density = relevant.len();
    if density < opts.min_density || opts.max_density.is_some_and(|m| density > m) {
        return Err(InteractionReject::DensityOutOfRange);
    }
    let u = [path.goal[0] - path.start[0], path.goal[1] - path.start[1]];
    let class = classify(u, relevant.iter().map(|r| r.1), &geometry.classify)
        .ok_or(InteractionReject::Unclassified)?;
    let track = &scene.tracks[path.track];
    let id = format!(
        "{}/ped{}/t{:.1}{}/crowd{:.1}",
        scene.name,
        track.source_id,
        path.s0 as f64 * dt,
        if path.reversed { "/rev" } else { "" },
        c0 as f64 * dt
    );
    let episode = Episode {
        id,
        scene: scene.name.clone(),
        source: scene.dataset.clone(),
        scenario: class,
        dt,
        start: path.start_pose(),
        goal: path.goal,
        time_budget: budget,
        agents: export_agents(
            scene, index, None, c0, steps, path.start, path.goal, geometry,
        ),
        density,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    };
    if !is_interactive(&episode, opts) {
        return Err(InteractionReject::NotInteractive(class));
    }
    Ok(episode)
}

/// Counters of the interaction-rich miner: how many candidates were tried, why they were
/// rejected and how many passed, per class.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct InteractionStats {
    /// Pedestrian windows (each gives one path per direction).
    pub windows: usize,
    /// Path directions (windows × directions).
    pub paths: usize,
    /// Path directions without any allowed crowd window (too close to both ends of the
    /// recording); no candidate is tried for them.
    pub no_crowd_window: usize,
    /// Candidates (path direction × crowd start) tried.
    pub candidates: usize,
    /// Rejected: [`InteractionReject::OutsideRecording`].
    pub outside_recording: usize,
    /// Rejected: [`InteractionReject::StartBlocked`].
    pub start_blocked: usize,
    /// Rejected: [`InteractionReject::DensityOutOfRange`].
    pub density_out_of_range: usize,
    /// Rejected: [`InteractionReject::Unclassified`].
    pub unclassified: usize,
    /// Classified candidates on which the reference reached the goal without meeting anyone
    /// at some speed, per class.
    pub not_interactive: BTreeMap<ScenarioClass, usize>,
    /// Interactive candidates, per class (every crowd start counted).
    pub interactive: BTreeMap<ScenarioClass, usize>,
    /// Interactive candidates kept, at most one per (window, direction, class), and not
    /// withheld.
    pub kept: BTreeMap<ScenarioClass, usize>,
    /// Kept candidates withheld because a file of `interaction.exclude_episodes` lists them,
    /// per class.
    pub withheld: BTreeMap<ScenarioClass, usize>,
}

impl InteractionStats {
    /// Adds another scene's counters.
    pub fn add(&mut self, o: &Self) {
        self.windows += o.windows;
        self.paths += o.paths;
        self.no_crowd_window += o.no_crowd_window;
        self.candidates += o.candidates;
        self.outside_recording += o.outside_recording;
        self.start_blocked += o.start_blocked;
        self.density_out_of_range += o.density_out_of_range;
        self.unclassified += o.unclassified;
        for (mine, theirs) in [
            (&mut self.not_interactive, &o.not_interactive),
            (&mut self.interactive, &o.interactive),
            (&mut self.kept, &o.kept),
            (&mut self.withheld, &o.withheld),
        ] {
            for (c, n) in theirs {
                *mine.entry(*c).or_default() += n;
            }
        }
    }

    /// Kept candidates of `class`.
    pub fn kept_of(&self, class: ScenarioClass) -> usize {
        self.kept.get(&class).copied().unwrap_or(0)
    }

    /// Classified candidates of `class` (interactive or not).
    pub fn classified_of(&self, class: ScenarioClass) -> usize {
        self.interactive.get(&class).copied().unwrap_or(0)
            + self.not_interactive.get(&class).copied().unwrap_or(0)
    }
}

/// Removes from one scene's kept candidates those whose id is in `ids` (the episodes of the
/// files in `interaction.exclude_episodes`), moving them from `stats.kept` to `stats.withheld`.
pub fn withhold(
    candidates: &mut Vec<Episode>,
    ids: &HashSet<String>,
    stats: &mut InteractionStats,
) {
    candidates.retain(|e| {
        let keep = !ids.contains(&e.id);
        if !keep {
            *stats.withheld.entry(e.scenario).or_default() += 1;
            if let Some(n) = stats.kept.get_mut(&e.scenario) {
                *n = n.saturating_sub(1);
            }
        }
        keep
    });
}

/// All kept interactive candidates of one scene (before per-class selection), in window order.
pub fn mine_interaction_scene(
    scene: &Scene,
    geometry: &MiningOptions,
    opts: &InteractionOptions,
    stats: &mut InteractionStats,
) -> Vec<Episode> {
    let index = scene.index();
    let mut out = Vec::new();
    for (e, i0, ig) in ego_windows(scene, geometry) {
        stats.windows += 1;
        let t = &scene.tracks[e];
        let (a, b) = (t.positions[i0], t.positions[ig]);
        let s0 = t.start + i0 as i64;
        let directions: &[bool] = if opts.reverse {
            &[false, true]
        } else {
            &[false]
        };
        for &reversed in directions {
            stats.paths += 1;
            let (start, goal) = if reversed { (b, a) } else { (a, b) };
            let path = EgoPath {
                track: e,
                s0,
                start,
                goal,
                reversed,
            };
            let steps = (geometry.budget(dist(start, goal)) / scene.dt - 1e-9).ceil() as i64;
            let starts = draw_crowd_starts(scene, &path, steps, opts);
            if starts.is_empty() {
                stats.no_crowd_window += 1;
            }
            let mut seen: Vec<ScenarioClass> = Vec::new();
            for c0 in starts {
                stats.candidates += 1;
                match try_interaction(scene, &index, &path, c0, geometry, opts) {
                    Ok(ep) => {
                        *stats.interactive.entry(ep.scenario).or_default() += 1;
                        if !seen.contains(&ep.scenario) {
                            seen.push(ep.scenario);
                            *stats.kept.entry(ep.scenario).or_default() += 1;
                            out.push(ep);
                        }
                    }
                    Err(InteractionReject::OutsideRecording) => stats.outside_recording += 1,
                    Err(InteractionReject::StartBlocked) => stats.start_blocked += 1,
                    Err(InteractionReject::DensityOutOfRange) => stats.density_out_of_range += 1,
                    Err(InteractionReject::Unclassified) => stats.unclassified += 1,
                    Err(InteractionReject::NotInteractive(c)) => {
                        *stats.not_interactive.entry(c).or_default() += 1
                    }
                }
            }
        }
    }
    out
}
