//! Interaction-rich episodes end to end: the synthetic fallback, and the validation scenes of
//! the shipped config mined from the real data (skipped when the datasets are absent).

#![allow(clippy::unwrap_used)]

mod common;

use human2nav_data::config::DataConfig;
use human2nav_data::interaction::is_interactive;
use human2nav_data::pipeline::{self, Locations, NoProgress};
use human2nav_data::scenario::EpisodeSuite;
use human2nav_data::{DataError, Episode, ScenarioClass, Split};
use std::path::{Path, PathBuf};
use std::time::Instant;

fn config_file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/data.toml")
}

fn locations(tag: &str, data_root: PathBuf) -> Locations {
    let dir = common::scratch(tag);
    Locations {
        workspace: dir.clone(),
        data_root,
        cache_dir: dir.join("cache"),
        episodes: dir.join("episodes.json"),
    }
}

#[test]
fn synthetic_fallback_says_it_is_not_interaction_rich() {
    let mut cfg = DataConfig::load(&config_file()).unwrap();
    cfg.episodes.per_class = 3;
    let loc = locations(
        "interaction-synthetic",
        PathBuf::from("/nonexistent/h2n-data"),
    );
    let r = pipeline::build_interaction_episodes(&cfg, &loc, Split::Val, &NoProgress).unwrap();
    assert_eq!(r.split, Split::Val);
    assert!(
        r.suite.source.starts_with("synthetic"),
        "{}",
        r.suite.source
    );
    for c in ScenarioClass::ALL {
        assert_eq!(r.suite.counts[&c], 3, "{c}");
    }
    assert!(
        r.notes.iter().any(|n| n.contains("NOT interaction-rich")),
        "{:?}",
        r.notes
    );
    // The test fallback draws other crowds than the val one.
    let t = pipeline::build_interaction_episodes(&cfg, &loc, Split::Test, &NoProgress).unwrap();
    assert_ne!(t.suite.episodes, r.suite.episodes);
    // Train is not held out.
    let err =
        pipeline::build_interaction_episodes(&cfg, &loc, Split::Train, &NoProgress).unwrap_err();
    assert!(matches!(err, DataError::Option { .. }), "{err}");
    let p = pipeline::interaction_episodes_path(&cfg, &loc, Split::Val).unwrap();
    assert!(
        p.ends_with("out/data/episodes-interaction-val.json"),
        "{p:?}"
    );
    // An excluded file that is missing or not a suite is refused, naming the key and the
    // file, with or without the datasets.
    std::fs::create_dir_all(&loc.workspace).unwrap();
    std::fs::write(loc.workspace.join("not-a-suite.json"), "{\"episodes\": 3}").unwrap();
    for name in ["missing.json", "not-a-suite.json"] {
        let mut bad = cfg.clone();
        bad.interaction.exclude_episodes = vec![PathBuf::from(name)];
        let err =
            pipeline::build_interaction_episodes(&bad, &loc, Split::Val, &NoProgress).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("interaction.exclude_episodes") && msg.contains(name),
            "{msg}"
        );
    }
    // A readable one is not applied to synthetic episodes, and the notes say so.
    let earlier = loc.workspace.join("earlier.json");
    r.suite.save(&earlier).unwrap();
    let mut with = cfg.clone();
    with.interaction.exclude_episodes = vec![earlier];
    let again = pipeline::build_interaction_episodes(&with, &loc, Split::Val, &NoProgress).unwrap();
    assert_eq!(again.suite, r.suite);
    assert!(
        again.notes.iter().any(|n| n.contains("exclude_episodes")),
        "{:?}",
        again.notes
    );
}

/// The reference robot, written out again for the check: from rest at `accel` to `speed`
/// along start→goal, stopping there.
fn reference_at(e: &Episode, speed: f64, accel: f64, t: f64) -> [f64; 2] {
    let t_acc = speed / accel;
    let s = if t < t_acc {
        0.5 * accel * t * t
    } else {
        0.5 * accel * t_acc * t_acc + speed * (t - t_acc)
    };
    let d = e.goal_distance();
    let f = (s / d).min(1.0);
    [
        e.start.x + f * (e.goal[0] - e.start.x),
        e.start.y + f * (e.goal[1] - e.start.y),
    ]
}

/// Does the reference at `speed` start touching a pedestrian whose track is at least
/// `min_age` old then, at a 0.1 s step before (or when) it reaches the goal?
fn meets_someone(e: &Episode, speed: f64, radius: f64, accel: f64, min_age: f64) -> bool {
    let mut prev: Vec<bool> = vec![false; e.agents.len()];
    let mut k = 0usize;
    loop {
        let t = k as f64 * e.dt;
        let p = reference_at(e, speed, accel, t);
        for (j, a) in e.agents.iter().enumerate() {
            let here = k >= a.start_step && k - a.start_step < a.positions.len();
            let touching = here && {
                let q = a.positions[k - a.start_step];
                (q[0] - p[0]).hypot(q[1] - p[1]) < radius + a.radius
            };
            if touching && !prev[j] && (k - a.start_step) as f64 * e.dt >= min_age - 1e-9 {
                return true;
            }
            prev[j] = touching;
        }
        let at_goal = (p[0] - e.goal[0]).hypot(p[1] - e.goal[1]) < 1e-12;
        if at_goal || t > e.time_budget {
            return false;
        }
        k += 1;
    }
}

/// `…/t<s0>[/rev]/crowd<c0>` → (s0, c0) in seconds.
fn window_and_crowd_times(id: &str) -> (f64, f64) {
    let (head, crowd) = id.rsplit_once("/crowd").unwrap();
    let head = head.strip_suffix("/rev").unwrap_or(head);
    let (_, t) = head.rsplit_once("/t").unwrap();
    (t.parse().unwrap(), crowd.parse().unwrap())
}

#[test]
fn real_validation_scenes_yield_interactive_episodes_of_every_class() {
    let Some(root) =
        common::data("real_validation_scenes_yield_interactive_episodes_of_every_class")
    else {
        return;
    };
    // All five validation scenes of the shipped config (about 2 s in release, well under a
    // minute in the test profile).
    let cfg = DataConfig::load(&config_file()).unwrap();
    let opts = &cfg.interaction;
    let geometry = &cfg.episodes;
    let loc = locations("interaction-real", root);
    let t0 = Instant::now();
    let r = pipeline::build_interaction_episodes(&cfg, &loc, Split::Val, &NoProgress).unwrap();
    eprintln!(
        "mined {} val scenes in {:.1} s: {} candidates tried",
        r.scenes.len(),
        t0.elapsed().as_secs_f64(),
        r.stats.candidates
    );
    eprintln!("{}", r.summary);
    assert_eq!(r.scenes.len(), cfg.split.val.len());
    for c in ScenarioClass::ALL {
        assert_eq!(r.suite.counts[&c], geometry.per_class, "{c}: {:?}", r.notes);
        assert!(r.stats.kept_of(c) >= geometry.per_class, "{c}");
    }
    let mut ids: Vec<&str> = r.suite.episodes.iter().map(|e| e.id.as_str()).collect();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids.len(), r.suite.episodes.len(), "ids are unique");
    let window = (geometry.start_window / 0.1 + 1e-9).floor() as usize;
    for e in &r.suite.episodes {
        assert_eq!(cfg.split.of(&e.scene), Some(Split::Val), "{}", e.id);
        assert!(e.density >= opts.min_density, "{}", e.id);
        assert!(e.goal_distance() >= geometry.goal_distance, "{}", e.id);
        assert!((e.time_budget - geometry.budget(e.goal_distance())).abs() < 1e-9);
        let heading = (e.goal[1] - e.start.y).atan2(e.goal[0] - e.start.x);
        assert!((e.start.theta - heading).abs() < 1e-9, "{}", e.id);
        let (s0, c0) = window_and_crowd_times(&e.id);
        assert!((c0 - s0).abs() >= opts.min_time_shift - 1e-6, "{}", e.id);
        // The start is clear of the replayed crowd during the start window.
        for a in &e.agents {
            for (i, q) in a.positions.iter().enumerate() {
                if a.start_step + i <= window {
                    let d = (q[0] - e.start.x).hypot(q[1] - e.start.y);
                    assert!(d >= geometry.min_start_clearance, "{}: {d}", e.id);
                }
            }
        }
        // The interaction criterion, re-checked here at every default speed.
        for &v in &[1.0, 1.5, 2.0] {
            assert!(
                meets_someone(e, v, 0.4, 1.0, 1.0),
                "{} at {v} m/s meets nobody",
                e.id
            );
        }
        assert!(is_interactive(e, opts), "{}", e.id);
    }
    // The suite file round-trips.
    let path = pipeline::interaction_episodes_path(&cfg, &loc, Split::Val).unwrap();
    r.suite.save(&path).unwrap();
    assert_eq!(EpisodeSuite::load(&path).unwrap(), r.suite);

    // A fresh draw: the same mining with that file excluded (a relative path, against the
    // workspace) selects a full suite sharing no episode with it, and the report counts the
    // withheld candidates.
    let mut fresh_cfg = cfg.clone();
    fresh_cfg.interaction.exclude_episodes =
        vec![path.strip_prefix(&loc.workspace).unwrap().into()];
    let fresh =
        pipeline::build_interaction_episodes(&fresh_cfg, &loc, Split::Val, &NoProgress).unwrap();
    for c in ScenarioClass::ALL {
        assert_eq!(
            fresh.suite.counts[&c], geometry.per_class,
            "{c}: {:?}",
            fresh.notes
        );
        // Same seed, same candidates: exactly the first suite's episodes are withheld.
        assert_eq!(fresh.stats.withheld[&c], geometry.per_class, "{c}");
        assert_eq!(
            fresh.stats.kept_of(c) + geometry.per_class,
            r.stats.kept_of(c),
            "{c}"
        );
    }
    assert!(
        fresh
            .suite
            .episodes
            .iter()
            .all(|e| !ids.contains(&e.id.as_str())),
        "the fresh draw repeats an episode"
    );
    let md = fresh.markdown(&fresh_cfg.interaction);
    assert!(
        md.contains(&format!(
            "Withheld: {} kept candidates",
            4 * geometry.per_class
        )),
        "{md}"
    );
}
