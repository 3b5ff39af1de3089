//! Tests of the interaction-rich miner.

use super::*;
use crate::resample::{Scene, Track};
use crate::scenario::{Episode, MiningOptions, ScenarioClass};
use crate::tuples::Split;
use std::collections::HashSet;

use crate::scenario::test_track as walker;

fn scene(tracks: Vec<Track>) -> Scene {
    Scene {
        name: "hand".into(),
        dataset: "test".into(),
        format: "test".into(),
        dt: 0.1,
        tracks,
        stats: crate::resample::ResampleStats::default(),
        dropped: Vec::new(),
    }
}

/// Global step of the crowd start at which the wall below crosses the path 3 s in.
const CROSS_AT: i64 = 600;

/// Track 0 (the path's pedestrian) walks +x at 1 m/s from the origin during the first 6 s:
/// one window, steps 0–50, from (0, 0) to (5, 0). A standing marker far away keeps the
/// recording 100 s long (steps 0–1000). A wall of eight walkers at x = 1.0, 1.5, …, 4.5
/// walks −y at 1 m/s from y = 6 (global step `CROSS_AT − 30`) and crosses y = 0 at
/// `CROSS_AT + 30`: with the crowd started at `CROSS_AT`, 3 s into the episode, when the
/// reference is at x = 2.5 (1 m/s), 3.4 (1.5 m/s) or 4.0 (2 m/s).
fn crossing_scene() -> Scene {
    let mut tracks = vec![
        walker(0, 0, [0.0, 0.0], [1.0, 0.0], 60),
        walker(1, 0, [50.0, 50.0], [0.0, 0.0], 1001),
    ];
    for i in 0..8 {
        let x = 1.0 + 0.5 * i as f64;
        tracks.push(walker(10 + i, CROSS_AT - 30, [x, 6.0], [0.0, -1.0], 120));
    }
    scene(tracks)
}

fn forward_path() -> EgoPath {
    EgoPath {
        track: 0,
        s0: 0,
        start: [0.0, 0.0],
        goal: [5.0, 0.0],
        reversed: false,
    }
}

fn attempt(s: &Scene, c0: i64, opts: &InteractionOptions) -> Result<Episode, InteractionReject> {
    try_interaction(
        s,
        &s.index(),
        &forward_path(),
        c0,
        &MiningOptions::default(),
        opts,
    )
}

#[test]
fn reference_kinematics() {
    let r = ReferenceRobot {
        speed: 1.5,
        accel: 1.0,
        radius: 0.4,
    };
    assert!((r.distance_at(1.0) - 0.5).abs() < 1e-12);
    assert!((r.distance_at(1.5) - 1.125).abs() < 1e-12);
    assert!((r.distance_at(2.5) - 2.625).abs() < 1e-12);
    let t = r.arrival_time(5.0);
    assert!((t - (1.5 + 3.875 / 1.5)).abs() < 1e-12);
    assert!((r.distance_at(t) - 5.0).abs() < 1e-12);
    assert!((r.arrival_time(0.5) - 1.0).abs() < 1e-12); // still accelerating
    assert_eq!(r.position([0.0, 0.0], [5.0, 0.0], 100.0), [5.0, 0.0]);
    let p = r.path([0.0, 0.0], [5.0, 0.0], 0.1);
    assert_eq!(p.len(), 42); // 0 … 4.1 s
    assert_eq!(p[0], [0.0, 0.0]);
    assert_eq!(*p.last().unwrap(), [5.0, 0.0]);
}

#[test]
fn a_crowd_crossing_when_the_reference_passes_is_interactive() {
    let s = crossing_scene();
    let opts = InteractionOptions::default();
    let ep = attempt(&s, CROSS_AT, &opts).unwrap();
    assert_eq!(ep.scenario, ScenarioClass::CrossFlow);
    assert_eq!(ep.id, "hand/ped0/t0.0/crowd60.0");
    assert_eq!(ep.density, 8);
    for v in [1.0, 1.5, 2.0] {
        let c = reference_contact(&ep, v, &opts).unwrap();
        assert!(
            c.distance < 0.7 && (2.0..3.0).contains(&c.time),
            "{v}: {c:?}"
        );
    }
    // Only the wall is exported: the path's own pedestrian walked 60 s earlier and the
    // marker is 50 m away.
    assert_eq!(ep.agents.len(), 8);
    assert!(ep.agents.iter().all(|a| a.id >= 10));
    assert_eq!(ep.start.theta, 0.0);
    assert_eq!(ep.time_budget, 12.5);
}

#[test]
fn the_same_crowd_when_nobody_is_on_the_segment_is_not_interactive() {
    let s = crossing_scene();
    let opts = InteractionOptions::default();
    // Started 4 s earlier, the wall crosses the line 7 s in, after every reference has
    // arrived (5.5 s at 1 m/s); it still comes within 3 m of the path: a classified
    // cross-flow candidate that is not interactive.
    let r = attempt(&s, CROSS_AT - 40, &opts);
    assert_eq!(
        r,
        Err(InteractionReject::NotInteractive(ScenarioClass::CrossFlow))
    );
    // Started 6 s later, the wall has crossed already and nobody is relevant.
    let r = attempt(&s, CROSS_AT + 60, &opts);
    assert_eq!(r, Err(InteractionReject::DensityOutOfRange));
    // Crossing 4.8 s in: the 1 m/s reference (at x = 4.3) meets the wall, the faster ones
    // have reached the goal. Interactive at 1 m/s alone, not at every default speed.
    let slow = InteractionOptions {
        reference_speeds: vec![1.0],
        ..opts.clone()
    };
    let ep = attempt(&s, CROSS_AT - 18, &slow).unwrap();
    assert!(reference_contact(&ep, 1.0, &opts).is_some());
    assert!(reference_contact(&ep, 1.5, &opts).is_none());
    assert!(reference_contact(&ep, 2.0, &opts).is_none());
    assert_eq!(
        attempt(&s, CROSS_AT - 18, &opts),
        Err(InteractionReject::NotInteractive(ScenarioClass::CrossFlow))
    );
}

#[test]
fn a_track_that_begins_on_top_of_the_reference_does_not_count() {
    // Someone appears standing on the segment at x = 3, `appear` steps into the episode;
    // a walker 2 m beside the path, never touching the reference, gives the crowd a class.
    let with_appearing = |appear: i64| {
        scene(vec![
            walker(0, 0, [0.0, 0.0], [1.0, 0.0], 60),
            walker(1, 0, [50.0, 50.0], [0.0, 0.0], 1001),
            walker(2, CROSS_AT + appear, [3.0, 0.0], [0.0, 0.0], 200),
            walker(3, CROSS_AT, [-1.0, 2.0], [1.0, 0.0], 120),
        ])
    };
    let opts = |age: f64| InteractionOptions {
        reference_speeds: vec![1.0],
        min_track_age: age,
        ..InteractionOptions::default()
    };
    // The 1 m/s reference touches it at 2.8 s (x = 2.3) and stays in contact until 4.2 s;
    // appearing at 2.5 s it is 0.3 s old at the onset: an artefact, not counted (although
    // the contact lasts past its first second).
    let s = with_appearing(25);
    let r = attempt(&s, CROSS_AT, &opts(1.0));
    assert!(
        matches!(r, Err(InteractionReject::NotInteractive(_))),
        "{r:?}"
    );
    // Counting every track, the same candidate meets it at 2.8 s.
    let ep = attempt(&s, CROSS_AT, &opts(0.0)).unwrap();
    let c = reference_contact(&ep, 1.0, &opts(0.0)).unwrap();
    assert_eq!(c.agent, 2);
    assert!((c.time - 2.8).abs() < 0.051, "{c:?}");
    // Appearing 2 s earlier (3 m from the start: the start stays clear) it is 2.3 s old at
    // the onset and counts.
    let s = with_appearing(5);
    let ep = attempt(&s, CROSS_AT, &opts(1.0)).unwrap();
    assert_eq!(reference_contact(&ep, 1.0, &opts(1.0)).unwrap().agent, 2);
}

#[test]
fn crowd_starts_keep_min_time_shift_and_the_recording() {
    let s = crossing_scene(); // steps 0..=1000
    let opts = InteractionOptions::default();
    let steps = 125;
    let all = allowed_crowd_starts(&s, 300, steps, &opts);
    for &c0 in &all {
        assert!((c0 - 300).abs() >= 200, "{c0}");
        assert_eq!((c0 - 300).rem_euclid(10), 0, "{c0}");
        assert!(c0 >= 0 && c0 + steps <= 1000, "{c0}");
    }
    // Before: 0, 10, …, 100; after: 500, …, 870.
    assert_eq!(all.first(), Some(&0));
    assert!(all.contains(&100) && !all.contains(&110));
    assert!(all.contains(&500) && !all.contains(&490));
    assert_eq!(all.last(), Some(&870));
    assert_eq!(all.len(), 11 + 38);
    // A smaller shift lets closer crowd windows in.
    let near = InteractionOptions {
        min_time_shift: 5.0,
        ..opts.clone()
    };
    assert!(allowed_crowd_starts(&s, 300, steps, &near).contains(&250));
    // A window in the middle of a 30 s recording has no crowd 20 s away.
    let short = scene(vec![walker(1, 0, [0.0, 0.0], [0.0, 0.0], 301)]);
    assert!(allowed_crowd_starts(&short, 100, steps, &opts).is_empty());
    // The drawn starts are allowed, distinct and at most shifts_per_path.
    let path = EgoPath {
        s0: 300,
        ..forward_path()
    };
    let drawn = draw_crowd_starts(&s, &path, steps, &opts);
    assert_eq!(drawn.len(), opts.shifts_per_path);
    let mut d = drawn.clone();
    d.sort_unstable();
    d.dedup();
    assert_eq!(d.len(), opts.shifts_per_path);
    assert!(drawn.iter().all(|c| all.contains(c)));
    // Mining every allowed start: no episode of the path replays a crowd within 20 s of
    // its window (which starts at 0 s).
    let every = InteractionOptions {
        shifts_per_path: 1000,
        ..opts.clone()
    };
    let eps = mine_interaction_scene(
        &s,
        &MiningOptions::default(),
        &every,
        &mut Default::default(),
    );
    let crowd_times: Vec<f64> = eps
        .iter()
        .filter(|e| e.id.starts_with("hand/ped0/"))
        .map(|e| e.id.rsplit("/crowd").next().unwrap().parse().unwrap())
        .collect();
    assert!(!crowd_times.is_empty());
    assert!(crowd_times.iter().all(|&t| t >= 20.0), "{crowd_times:?}");
}

#[test]
fn the_reversed_direction_starts_at_the_windows_goal() {
    let s = crossing_scene();
    let geometry = MiningOptions::default();
    let opts = InteractionOptions {
        shifts_per_path: 1000, // every allowed crowd start, so the crossing one is tried
        ..InteractionOptions::default()
    };
    let mut stats = InteractionStats::default();
    let eps = mine_interaction_scene(&s, &geometry, &opts, &mut stats);
    let windows = ego_windows(&s, &geometry);
    let (e, i0, ig) = windows[0];
    assert_eq!((e, i0), (0, 0));
    assert_eq!(stats.windows, windows.len());
    assert_eq!(stats.paths, 2 * windows.len());
    let (a, b) = (s.tracks[0].positions[i0], s.tracks[0].positions[ig]);
    let ped0: Vec<&Episode> = eps
        .iter()
        .filter(|e| e.id.starts_with("hand/ped0/"))
        .collect();
    let rev: Vec<&&Episode> = ped0.iter().filter(|e| e.id.contains("/rev/")).collect();
    assert!(!rev.is_empty(), "{stats:?}");
    // (Which crowd start a direction keeps is the first interactive one in draw order.)
    for ep in &rev {
        assert_eq!([ep.start.x, ep.start.y], b);
        assert_eq!(ep.goal, a);
        // Facing −x, towards the goal.
        assert!((ep.start.theta.abs() - std::f64::consts::PI).abs() < 1e-12);
    }
    assert!(ped0.iter().any(|e| !e.id.contains("/rev/")));
    assert!(eps.iter().all(|e| is_interactive(e, &opts)));
    // At most one per (window, direction, class).
    let mut keys: Vec<(String, ScenarioClass)> = eps
        .iter()
        .map(|e| {
            (
                e.id.rsplit_once("/crowd").unwrap().0.to_string(),
                e.scenario,
            )
        })
        .collect();
    let n = keys.len();
    keys.sort();
    keys.dedup();
    assert_eq!(keys.len(), n);
    assert_eq!(stats.kept.values().sum::<usize>(), eps.len());
    assert!(stats.interactive.values().sum::<usize>() >= eps.len());
}

#[test]
fn mining_is_deterministic() {
    let s = crossing_scene();
    let geometry = MiningOptions::default();
    let opts = InteractionOptions {
        shifts_per_path: 20,
        ..InteractionOptions::default()
    };
    let run = || {
        let mut st = InteractionStats::default();
        let e = mine_interaction_scene(&s, &geometry, &opts, &mut st);
        (e, st)
    };
    let (a, sa) = run();
    let (b, sb) = run();
    assert!(sa.candidates > 0);
    assert_eq!(a, b);
    assert_eq!(sa, sb);
    // Another seed draws other crowd starts.
    let other = InteractionOptions {
        seed: 12,
        ..opts.clone()
    };
    let path = forward_path();
    assert_ne!(
        draw_crowd_starts(&s, &path, 125, &opts),
        draw_crowd_starts(&s, &path, 125, &other)
    );
}

#[test]
fn options_validation_names_the_key() {
    assert!(InteractionOptions::default().validate().is_ok());
    let cases: [(InteractionOptions, &str); 7] = [
        (
            InteractionOptions {
                reference_speeds: vec![],
                ..Default::default()
            },
            "interaction.reference_speeds",
        ),
        (
            InteractionOptions {
                reference_speeds: vec![1.0, -1.0],
                ..Default::default()
            },
            "interaction.reference_speeds",
        ),
        (
            InteractionOptions {
                shifts_per_path: 0,
                ..Default::default()
            },
            "interaction.shifts_per_path",
        ),
        (
            InteractionOptions {
                min_time_shift: f64::NAN,
                ..Default::default()
            },
            "interaction.min_time_shift",
        ),
        (
            InteractionOptions {
                reference_radius: 0.0,
                ..Default::default()
            },
            "interaction.reference_radius",
        ),
        (
            InteractionOptions {
                reference_accel: f64::INFINITY,
                ..Default::default()
            },
            "interaction.reference_accel",
        ),
        (
            InteractionOptions {
                min_density: 5,
                max_density: Some(4),
                ..Default::default()
            },
            "interaction.max_density",
        ),
    ];
    for (o, key) in cases {
        let err = o.validate().unwrap_err();
        assert!(err.to_string().contains(key), "{err}");
    }
}

#[test]
fn density_bins_and_summary() {
    let mut h = DensityHistogram::default();
    for d in [0, 1, 2, 3, 5, 6, 10, 11, 20, 21, 40, 41, 90] {
        h.add(d);
    }
    assert_eq!(h.bins, [3, 2, 2, 2, 2, 2]);
    assert_eq!(h.max, 90);
    let s = crossing_scene();
    let ep = attempt(&s, CROSS_AT, &InteractionOptions::default()).unwrap();
    let sum = summarize(&[ep.clone(), ep]);
    assert_eq!(sum.per_class[&ScenarioClass::CrossFlow], 2);
    assert_eq!(sum.per_class[&ScenarioClass::CoFlow], 0);
    assert_eq!(sum.density_per_class[&ScenarioClass::CrossFlow].bins[2], 2);
    assert_eq!(sum.goal_distance, [5.0; 4]);
    assert!(sum.to_string().contains("cross_flow"));
}

/// The crossing scene mined with 1000 crowd starts per path: the geometry, the options, the
/// kept candidates and the counters.
fn mined_crossing() -> (
    MiningOptions,
    InteractionOptions,
    Vec<Episode>,
    InteractionStats,
) {
    let geometry = MiningOptions::default();
    let opts = InteractionOptions {
        shifts_per_path: 1000,
        ..InteractionOptions::default()
    };
    let mut st = InteractionStats::default();
    let eps = mine_interaction_scene(&crossing_scene(), &geometry, &opts, &mut st);
    (geometry, opts, eps, st)
}

#[test]
fn a_class_without_any_interactive_episode_is_an_error() {
    let s = crossing_scene();
    let (geometry, opts, eps, st) = mined_crossing();
    assert!(eps.iter().any(|e| e.scenario == ScenarioClass::CrossFlow));
    let mined = vec![("hand".to_string(), eps, st)];
    // Only cross-flow crowds in this scene: co-flow (the first class) has none.
    let err =
        select_interaction_suite(Split::Val, mined.clone(), &geometry, &opts, vec![]).unwrap_err();
    let msg = err.to_string();
    for part in [
        "interaction.reference_speeds",
        "val split",
        "co_flow",
        "min_time_shift",
        "shifts_per_path",
    ] {
        assert!(msg.contains(part), "{part}: {msg}");
    }
    // Nothing at all passes when the reference must be met by tracks older than the
    // recording: still an error, now counting the classified candidates.
    let strict = InteractionOptions {
        min_track_age: 1000.0,
        ..opts.clone()
    };
    let mut st = InteractionStats::default();
    let eps = mine_interaction_scene(&s, &geometry, &strict, &mut st);
    assert!(eps.is_empty());
    assert_eq!(st.kept_of(ScenarioClass::CrossFlow), 0);
    assert!(st.classified_of(ScenarioClass::CrossFlow) > 0);
    let err = select_interaction_suite(
        Split::Test,
        vec![("hand".to_string(), eps, st)],
        &geometry,
        &strict,
        vec![],
    )
    .unwrap_err();
    assert!(err.to_string().contains("test split"), "{err}");
}

#[test]
fn withheld_episodes_leave_the_kept_candidates_and_are_counted() {
    let (_, _, mut eps, mut st) = mined_crossing();
    let before = eps.clone();
    let kept = st.kept_of(ScenarioClass::CrossFlow);
    assert!(
        kept >= 1 && before.len() == kept,
        "{kept} of {}",
        before.len()
    );
    // An id no candidate has changes nothing.
    let mut unchanged = eps.clone();
    let mut st2 = st.clone();
    withhold(
        &mut unchanged,
        &HashSet::from(["elsewhere".to_string()]),
        &mut st2,
    );
    assert_eq!(unchanged, before);
    assert_eq!(st2, st);
    // The first candidate's id withholds exactly it.
    let gone = before[0].clone();
    withhold(&mut eps, &HashSet::from([gone.id.clone()]), &mut st);
    assert_eq!(eps, before[1..]);
    assert_eq!(st.kept_of(gone.scenario), kept - 1);
    assert_eq!(st.withheld.get(&gone.scenario), Some(&1));
    // Summed over scenes, the withheld counts add up like the others.
    let mut total = InteractionStats::default();
    total.add(&st);
    total.add(&st);
    assert_eq!(total.withheld.get(&gone.scenario), Some(&2));
}
