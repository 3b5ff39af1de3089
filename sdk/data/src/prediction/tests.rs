//! Tests of the predictor study: windows, predictors and scores on hand-made episodes.

use super::*;
use crate::scenario::{AgentTrack, Episode, ScenarioClass};

fn episode(scene: &str, tracks: Vec<Vec<[f64; 2]>>) -> Episode {
    Episode {
        id: format!("{scene}/e"),
        scene: scene.into(),
        source: "synthetic".into(),
        scenario: ScenarioClass::CoFlow,
        dt: 0.1,
        start: Pose2::new(0.0, 0.0, 0.0),
        goal: [5.0, 0.0],
        time_budget: 10.0,
        agents: tracks
            .into_iter()
            .enumerate()
            .map(|(i, positions)| AgentTrack {
                id: i as u64,
                start_step: 0,
                positions,
                radius: 0.3,
            })
            .collect(),
        density: 1,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    }
}

fn suite(episodes: Vec<Episode>) -> EpisodeSuite {
    EpisodeSuite::new("test", episodes)
}

/// A track along heading `theta` from `p0`, at speed `v0` per step changing by `a` per
/// step.
fn track(p0: [f64; 2], theta: f64, v0: f64, a: f64, n: usize) -> Vec<[f64; 2]> {
    let (c, s) = (theta.cos(), theta.sin());
    (0..n)
        .map(|k| {
            let k = k as f64;
            let d = v0 * k + 0.5 * a * k * k;
            [p0[0] + c * d, p0[1] + s * d]
        })
        .collect()
}

#[test]
fn constant_velocity_tracks_are_predicted_exactly_by_the_held_velocities() {
    let s = suite(vec![
        episode("a", vec![track([0.0, 0.0], 0.3, 0.12, 0.0, 60)]),
        episode("b", vec![track([5.0, 1.0], -2.0, 0.08, 0.0, 60)]),
    ]);
    let r = study(&s, PredictionOptions::default()).expect("study");
    for p in [
        Predictor::LastStep,
        Predictor::MeanVelocity(4),
        Predictor::MeanVelocity(8),
        Predictor::ConstantTurn(2),
        Predictor::ConstantTurn(4),
        // Alone in its episode, nobody pushes it off its velocity.
        Predictor::SocialForce,
    ] {
        assert!(r.overall[&p].ade < 1e-9, "{p}: {:?}", r.overall[&p]);
    }
    // Standing still is off by the distance walked: 0.12 m/step at the horizon's end.
    let st = r.per_scene["a"][&Predictor::Static];
    assert!((st.fde - 0.12 * 32.0).abs() < 1e-9, "{st:?}");
    // 60 positions, windows at 8, 13, 18, 23 (23 + 32 < 60 and 28 + 32 >= 60).
    assert_eq!(r.per_scene["a"][&Predictor::LastStep].windows, 4);
    assert_eq!(r.tracks, 2);
}

/// Walkers on circles (one turning left, one right) are foreseen exactly by the constant
/// turn, which the held velocity overshoots by metres.
#[test]
fn the_constant_turn_follows_a_walker_round_a_circle() {
    let circle = |centre: [f64; 2], radius: f64, turn: f64| -> Vec<[f64; 2]> {
        (0..60)
            .map(|k| {
                let a = turn * k as f64;
                [centre[0] + radius * a.cos(), centre[1] + radius * a.sin()]
            })
            .collect()
    };
    let s = suite(vec![
        episode("a", vec![circle([0.0, 0.0], 3.0, 0.04)]),
        episode("b", vec![circle([2.0, 1.0], 2.0, -0.05)]),
    ]);
    let r = study(&s, PredictionOptions::default()).expect("study");
    for n in [2, 4] {
        let e = r.overall[&Predictor::ConstantTurn(n)];
        assert!(e.fde < 1e-9, "{n}: {e:?}");
    }
    assert!(r.overall[&Predictor::LastStep].fde > 1.0);
}

/// Two walkers meeting head-on, 0.2 m off each other's line: the social force turns the
/// one predicted aside, away from the other, and slows it; someone 5 m behind it, walking
/// as fast, barely moves it.
#[test]
fn the_social_force_steps_a_walker_aside_from_one_coming_at_it() {
    let walking = |p: [f64; 2], v: [f64; 2]| Walker { p, v, radius: 0.3 };
    let window = |near: Vec<Walker>| Window {
        scene: 0,
        past: vec![[-0.13, 0.0], [0.0, 0.0]],
        future: Vec::new(),
        frame: Pose2::IDENTITY,
        radius: 0.3,
        near,
    };
    let alone = social_force(&window(Vec::new()), 30, 0.1);
    assert!((alone[29][0] - 3.9).abs() < 1e-9 && alone[29][1].abs() < 1e-12);
    let oncoming = walking([4.0, 0.2], [-0.13, 0.0]);
    let met = social_force(&window(vec![oncoming]), 30, 0.1);
    let aside = met.iter().map(|p| p[1]).fold(0.0f64, f64::min);
    assert!(
        aside < -0.2,
        "it should step to −y, away from the other: {aside}"
    );
    assert!(met[29][0] < alone[29][0] - 0.1, "{:?}", met[29]);
    let far = social_force(&window(vec![walking([-5.0, 0.0], [0.13, 0.0])]), 30, 0.1);
    assert!((far[29][0] - alone[29][0]).abs() < 1e-3, "{:?}", far[29]);
}

#[test]
fn the_ridge_model_learns_a_deceleration_the_held_velocity_misses() {
    // Every pedestrian slows by the same amount per step, in every scene and direction:
    // the departure from the last step's velocity is a linear function of the history (its
    // velocities fall linearly), which the ridge model fits from the other scenes.
    let mut episodes = Vec::new();
    for (i, scene) in ["a", "b", "c"].into_iter().enumerate() {
        let tracks = (0..6)
            .map(|j| {
                let theta = 0.7 * (i * 6 + j) as f64;
                track(
                    [i as f64, j as f64],
                    theta,
                    0.15 + 0.01 * j as f64,
                    -0.002,
                    60,
                )
            })
            .collect();
        episodes.push(episode(scene, tracks));
    }
    let r = study(
        &suite(episodes),
        PredictionOptions {
            ridge_lambda: 1e-9,
            ..PredictionOptions::default()
        },
    )
    .expect("study");
    let (cv, ridge) = (
        r.overall[&Predictor::LastStep],
        r.overall[&Predictor::Ridge],
    );
    assert!(cv.fde > 0.5, "the held velocity overshoots: {cv:?}");
    assert!(ridge.fde < 1e-3 * cv.fde, "ridge {ridge:?} against {cv:?}");
}

/// Fitted on other scenes in which everyone slows the same way, the trained ridge model
/// foresees the file's slowing walkers, which the held velocity overshoots; without
/// training scenes it is not reported.
#[test]
fn the_ridge_model_fitted_on_training_scenes_learns_their_deceleration() {
    use crate::resample::{ResampleStats, Track};
    use crate::track::AgentClass;
    let slowing = |i: usize, j: usize| {
        track(
            [i as f64, j as f64],
            0.9 * (i * 5 + j) as f64,
            0.15 + 0.01 * j as f64,
            -0.002,
            60,
        )
    };
    let training: Vec<Scene> = (0..2)
        .map(|i| Scene {
            name: format!("train/{i}"),
            dataset: "train".into(),
            format: "hand".into(),
            dt: 0.1,
            tracks: (0..5)
                .map(|j| {
                    let positions = slowing(i, j);
                    Track {
                        id: j as u64,
                        source_id: j as u64,
                        class: AgentClass::Pedestrian,
                        start: 0,
                        velocities: vec![[0.0; 2]; positions.len()],
                        headings: vec![0.0; positions.len()],
                        positions,
                    }
                })
                .collect(),
            stats: ResampleStats::default(),
            dropped: Vec::new(),
        })
        .collect();
    let file = suite(vec![
        episode("a", vec![slowing(7, 1)]),
        episode("b", vec![slowing(8, 2)]),
    ]);
    let o = PredictionOptions {
        ridge_lambda: 1e-9,
        ..PredictionOptions::default()
    };
    let r = study_with_training(&file, o, &training).expect("study");
    let (cv, trained) = (
        r.overall[&Predictor::LastStep],
        r.overall[&Predictor::RidgeTrained],
    );
    assert!(cv.fde > 0.5, "{cv:?}");
    assert!(trained.fde < 1e-3 * cv.fde, "{trained:?} against {cv:?}");
    let untrained = study(&file, o).expect("study");
    assert!(!untrained.overall.contains_key(&Predictor::RidgeTrained));
}

#[test]
fn the_same_track_in_two_episodes_counts_once() {
    let t = track([0.0, 0.0], 0.0, 0.1, 0.0, 50);
    let s = suite(vec![
        episode("a", vec![t.clone()]),
        episode("a", vec![t]),
        episode("b", vec![track([1.0, 0.0], 1.0, 0.1, 0.0, 50)]),
    ]);
    let r = study(&s, PredictionOptions::default()).expect("study");
    assert_eq!(r.tracks, 2);
    assert_eq!(r.per_scene["a"][&Predictor::LastStep].windows, 2);
}

#[test]
fn unusable_files_and_options_are_refused_by_name() {
    let short = suite(vec![
        episode("a", vec![track([0.0, 0.0], 0.0, 0.1, 0.0, 20)]),
        episode("b", vec![track([0.0, 0.0], 0.0, 0.1, 0.0, 20)]),
    ]);
    let e = study(&short, PredictionOptions::default()).expect_err("too short");
    assert!(e.to_string().contains("41 steps"), "{e}");
    let one = suite(vec![episode(
        "a",
        vec![track([0.0, 0.0], 0.0, 0.1, 0.0, 60)],
    )]);
    let e = study(&one, PredictionOptions::default()).expect_err("one scene");
    assert!(e.to_string().contains("leave-one-scene-out"), "{e}");
    for (o, field) in [
        (
            PredictionOptions {
                history: 0,
                ..PredictionOptions::default()
            },
            "history",
        ),
        (
            PredictionOptions {
                ridge_lambda: f64::NAN,
                ..PredictionOptions::default()
            },
            "ridge_lambda",
        ),
    ] {
        let e = study(&short, o).expect_err(field);
        assert!(e.to_string().contains(field), "{e}");
    }
}
