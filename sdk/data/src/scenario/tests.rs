//! Tests of the scenario classification, the paper-protocol miner and the selection.

use super::mining::segment_distance;
use super::*;
use crate::resample::{Scene, Track};
use human2nav_core::Pose2;

#[test]
fn flows_follow_the_angle_thresholds() {
    let o = ClassifyOptions::default();
    let u = [2.0, 0.0];
    assert_eq!(flow_of(u, [1.0, 0.9], &o), Some(ScenarioClass::CoFlow)); // 42°
    assert_eq!(flow_of(u, [1.0, 1.1], &o), Some(ScenarioClass::CrossFlow)); // 47.7°
    assert_eq!(flow_of(u, [0.0, -1.0], &o), Some(ScenarioClass::CrossFlow));
    assert_eq!(
        flow_of(u, [-1.0, 0.9], &o),
        Some(ScenarioClass::CounterFlow)
    );
    assert_eq!(flow_of(u, [0.1, 0.1], &o), None); // 0.14 m/s: standing
}

#[test]
fn majority_and_mixture_rules() {
    let o = ClassifyOptions::default();
    let u = [0.0, 1.0];
    let co = [0.0, 1.2];
    let cross = [1.2, 0.0];
    let counter = [0.0, -1.2];
    assert_eq!(
        classify(u, [co, co, co, cross], &o),
        Some(ScenarioClass::CoFlow)
    ); // 75 %
    assert_eq!(
        classify(u, [co, co, cross], &o),
        Some(ScenarioClass::MultidirectionFlow)
    ); // 67 %
    assert_eq!(
        classify(u, [counter, [0.0, 0.0]], &o),
        Some(ScenarioClass::CounterFlow)
    );
    assert_eq!(
        classify(u, [cross, [-1.0, 0.1]], &o),
        Some(ScenarioClass::CrossFlow)
    );
    assert_eq!(classify(u, [[0.0, 0.1]], &o), None);
    assert_eq!(
        classify(u, [co, counter, cross], &o),
        Some(ScenarioClass::MultidirectionFlow)
    );
}

#[test]
fn class_names_round_trip() {
    for c in ScenarioClass::ALL {
        assert_eq!(ScenarioClass::parse(c.name()), Some(c));
        assert_eq!(ScenarioClass::from_index(c.index()), Some(c));
        let json = serde_json::to_string(&c).unwrap();
        assert_eq!(json, format!("\"{}\"", c.name()));
    }
}

/// A straight track from `from` at `velocity` (m/s), 0.1 s steps, from global step 0.
fn straight_track(id: u64, from: [f64; 2], velocity: [f64; 2], steps: usize) -> Track {
    test_track(id, 0, from, velocity, steps)
}

/// The ego walks +x at 1 m/s from the origin; one other pedestrian walks −y at `speed`
/// from `(x, y)`.
fn crossing_scene(other_from: [f64; 2], speed: f64) -> Scene {
    Scene {
        name: "hand".into(),
        dataset: "test".into(),
        format: "test".into(),
        dt: 0.1,
        tracks: vec![
            straight_track(0, [0.0, 0.0], [1.0, 0.0], 200),
            straight_track(1, other_from, [0.0, -speed], 200),
        ],
        stats: crate::resample::ResampleStats::default(),
        dropped: Vec::new(),
    }
}

#[test]
fn a_pedestrian_reaching_the_start_within_the_window_blocks_it() {
    let opts = MiningOptions::default();
    assert_eq!((opts.min_start_clearance, opts.start_window), (1.5, 1.5));
    // 3 m away at the start, but 3 − 1.2·1.5 = 1.2 m < 1.5 m from it at 1.5 s.
    let scene = crossing_scene([0.0, 3.0], 1.2);
    let r = try_episode(&scene, &scene.index(), 0, 0, &opts);
    assert!(matches!(r, Err(Reject::StartBlocked)), "{r:?}");
    // The same with the first step only checked: kept.
    let first_step = MiningOptions {
        start_window: 0.0,
        ..opts.clone()
    };
    assert!(try_episode(&scene, &scene.index(), 0, 0, &first_step).is_ok());
    // Crossing the ego's path 2 m ahead: never within 1.5 m of the start point.
    let scene = crossing_scene([2.0, 4.0], 1.0);
    let (ep, _) = try_episode(&scene, &scene.index(), 0, 0, &opts).unwrap();
    assert_eq!(ep.scenario, ScenarioClass::CrossFlow);
    assert_eq!(ep.agents.len(), 1);
}

#[test]
fn an_episode_with_one_id_twice_or_an_empty_track_is_refused() {
    let track = |id: u64, positions: Vec<[f64; 2]>| AgentTrack {
        id,
        start_step: 0,
        positions,
        radius: 0.3,
    };
    let mut ep = Episode {
        id: "e".into(),
        scene: "s".into(),
        source: "test".into(),
        scenario: ScenarioClass::CoFlow,
        dt: 0.1,
        start: Pose2::new(0.0, 0.0, 0.0),
        goal: [5.0, 0.0],
        time_budget: 12.5,
        agents: vec![track(3, vec![[1.0, 1.0]]), track(4, vec![[2.0, 1.0]])],
        density: 2,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    };
    assert_eq!(ep.validate(), Ok(()));
    ep.agents[1].id = 3;
    let (field, why) = ep.validate().unwrap_err();
    assert_eq!(field, "agents[1].id");
    assert!(why.contains("already the id of agents[0]"), "{why}");
    ep.agents[1] = track(4, Vec::new());
    let (field, why) = ep.validate().unwrap_err();
    assert_eq!(field, "agents[1].positions");
    assert!(why.contains("no positions"), "{why}");
    // 2.9 m in a 0.1 s step is 29 m/s, under the limit; 3 m is 30 m/s, over it.
    ep.agents[1] = track(4, vec![[2.0, 1.0], [4.9, 1.0], [7.9, 1.0]]);
    let (field, why) = ep.validate().unwrap_err();
    assert_eq!(field, "agents[1].positions[2]");
    assert!(
        why.contains("agent 4 moves 3.00 m in one 0.1 s step"),
        "{why}"
    );
    ep.agents[1].positions.pop();
    assert_eq!(ep.validate(), Ok(()));
}

#[test]
fn selection_across_scenes_spreads_each_density_over_the_scenes() {
    let ep = |scene: &str, k: usize, density: usize| Episode {
        id: format!("{scene}/{k}"),
        scene: scene.into(),
        source: "test".into(),
        scenario: ScenarioClass::CoFlow,
        dt: 0.1,
        start: Pose2::new(0.0, 0.0, 0.0),
        goal: [5.0, 0.0],
        time_budget: 12.5,
        agents: Vec::new(),
        density,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    };
    // Scene a: 40 candidates at density 1 and 2 at density 9; scene b: 4 at density 1.
    let mut all: Vec<Episode> = (0..40).map(|k| ep("a", k, 1)).collect();
    all.extend((40..42).map(|k| ep("a", k, 9)));
    all.extend((0..4).map(|k| ep("b", k, 1)));
    let picked = select_across_scenes(all.clone(), 8, 3);
    assert_eq!(picked.len(), 8);
    // Density 9 gets its two, density 1 its six, shared between the scenes.
    assert_eq!(picked.iter().filter(|e| e.density == 9).count(), 2);
    assert_eq!(picked.iter().filter(|e| e.scene == "b").count(), 4);
    assert_eq!(select_across_scenes(all.clone(), 8, 3), picked);
    // `select` on the same candidates draws density 1 from the 44 regardless of scene.
    assert_eq!(
        select(all, 8, 3).iter().filter(|e| e.density == 9).count(),
        2
    );
}

#[test]
fn segment_distance_closed_forms() {
    assert!((segment_distance([1.0, 2.0], [0.0, 0.0], [4.0, 0.0]) - 2.0).abs() < 1e-12);
    assert!((segment_distance([-3.0, 4.0], [0.0, 0.0], [4.0, 0.0]) - 5.0).abs() < 1e-12);
}
