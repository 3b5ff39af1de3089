//! Cache, episodes, synthetic crowds and the end-to-end jobs.

#![allow(clippy::unwrap_used)]

mod common;

use approx::assert_relative_eq;
use human2nav_core::bev::BevSpec;
use human2nav_data::InteractionOptions;
use human2nav_data::cache::TupleCache;
use human2nav_data::config::DataConfig;
use human2nav_data::pipeline::{self, Locations, NoProgress};
use human2nav_data::scenario::{EpisodeSuite, MiningOptions};
use human2nav_data::synthetic;
use human2nav_data::tuples::TupleOptions;
use human2nav_data::{DataError, ScenarioClass, Split};
use std::path::{Path, PathBuf};

fn config_file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/data.toml")
}

fn synthetic_locations(tag: &str) -> (DataConfig, Locations) {
    let mut cfg = DataConfig::load(&config_file()).unwrap();
    cfg.sources.synthetic_scenes = 24;
    cfg.episodes.per_class = 6;
    let dir = common::scratch(tag);
    let loc = Locations {
        workspace: dir.clone(),
        data_root: dir.join("no-datasets-here"),
        cache_dir: dir.join("cache"),
        episodes: dir.join("episodes.json"),
    };
    (cfg, loc)
}

#[test]
fn shipped_config_parses_and_unknown_keys_are_rejected() {
    let cfg = DataConfig::load(&config_file()).unwrap();
    assert_eq!(cfg.bev, BevSpec::default());
    assert_eq!(cfg.tuples, TupleOptions::default());
    assert_eq!(cfg.episodes, MiningOptions::default());
    assert_eq!(cfg.interaction, InteractionOptions::default());
    assert_eq!(cfg.paths, human2nav_data::config::PathsConfig::default());
    assert!(cfg.split.test.contains(&"eth/eth".to_string()));
    let err = DataConfig::parse("[tuples]\nstrde = 3\n", Path::new("x.toml")).unwrap_err();
    assert!(
        matches!(err, DataError::Config { .. }) && err.to_string().contains("strde"),
        "{err}"
    );
    let err = DataConfig::parse("[interaction]\nshifts = 3\n", Path::new("x.toml")).unwrap_err();
    assert!(err.to_string().contains("shifts"), "{err}");
    let err = DataConfig::parse(
        "[interaction]\nreference_speeds = []\n",
        Path::new("x.toml"),
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("interaction.reference_speeds"),
        "{err}"
    );
    let cfg = DataConfig::parse("[interaction]\nmax_density = 30\n", Path::new("x.toml")).unwrap();
    assert_eq!(cfg.interaction.max_density, Some(30));
    let err = DataConfig::parse("[bev]\ncells = 0\n", Path::new("x.toml")).unwrap_err();
    assert!(err.to_string().contains("cells"), "{err}");
    let err = DataConfig::parse(
        "[split]\ntest = [\"a\"]\nval = [\"a\"]\n",
        Path::new("x.toml"),
    )
    .unwrap_err();
    assert!(err.to_string().contains("both"), "{err}");
}

#[test]
fn synthetic_tuples_are_deterministic_and_well_formed() {
    let a = synthetic::tuples(40, 3);
    let b = synthetic::tuples(40, 3);
    assert_eq!(a.len(), 40);
    assert_eq!(a, b);
    assert_ne!(a, synthetic::tuples(40, 4));
    let spec = BevSpec::default();
    for t in &a {
        assert_eq!(t.bev.len(), spec.len());
        assert_eq!(t.future.len(), 32);
        assert!(t.bev.iter().all(|v| v.is_finite()));
        // Occupancy is binary and velocities vanish off the discs.
        let n = spec.cells * spec.cells;
        for i in 0..n {
            let occ = t.bev[i];
            assert!(occ == 0.0 || occ == 1.0);
            if occ == 0.0 {
                assert_eq!(t.bev[n + i], 0.0);
                assert_eq!(t.bev[2 * n + i], 0.0);
            }
        }
        // The first future pose is one 0.1 s step ahead of a walker.
        let d = t.future[0][0].hypot(t.future[0][1]);
        assert!(d < 0.3, "first step {d} m");
    }
    assert!(
        a.iter().any(|t| t.bev.contains(&1.0)),
        "some raster shows a neighbour"
    );
}

#[test]
fn synthetic_episodes_have_the_requested_class_and_a_reachable_goal() {
    for class in ScenarioClass::ALL {
        let eps = synthetic::episodes(class, 5, 11);
        assert_eq!(eps.len(), 5, "{class}");
        assert_eq!(eps, synthetic::episodes(class, 5, 11));
        for e in &eps {
            assert_eq!(e.scenario, class);
            assert!((1..=15).contains(&e.density), "{}", e.density);
            assert_relative_eq!(e.dt, 0.1);
            let d = e.goal_distance();
            assert!((5.0..5.3).contains(&d), "goal distance {d}");
            // Empty world: 1 m/s in a straight line needs d seconds; the budget is 2.5 d.
            assert_relative_eq!(e.time_budget, 2.5 * d, epsilon = 1e-9);
            for a in &e.agents {
                assert!(a.start_step + a.positions.len() <= e.steps() + 1);
                assert!(a.positions.iter().flatten().all(|v| v.is_finite()));
            }
            // Nobody within 1 m of the start at step 0.
            for a in e.agents.iter().filter(|a| a.start_step == 0) {
                let p = a.positions[0];
                assert!((p[0] - e.start.x).hypot(p[1] - e.start.y) >= 1.0);
            }
        }
    }
}

#[test]
fn episode_suite_round_trips_and_rejects_bad_files() {
    let eps = synthetic::episodes(ScenarioClass::CrossFlow, 3, 5);
    let suite = EpisodeSuite::new("synthetic", eps);
    assert_eq!(suite.counts[&ScenarioClass::CrossFlow], 3);
    assert_eq!(suite.counts[&ScenarioClass::CoFlow], 0);
    let path = common::scratch("suite.json");
    suite.save(&path).unwrap();
    assert!(
        EpisodeSuite::load(&path).unwrap() == suite,
        "round trip changed the suite"
    );
    let body = std::fs::read_to_string(&path).unwrap();
    assert!(body.contains("\"cross_flow\""));
    std::fs::write(&path, body.replacen("\"version\":1", "\"version\":99", 1)).unwrap();
    assert!(
        EpisodeSuite::load(&path)
            .unwrap_err()
            .to_string()
            .contains("version")
    );
    let mut bad = suite.clone();
    bad.counts.insert(ScenarioClass::CoFlow, 7);
    bad.save(&path).unwrap();
    assert!(EpisodeSuite::load(&path).is_err());
}

#[test]
fn synthetic_fallback_builds_a_cache_that_round_trips() {
    let (cfg, loc) = synthetic_locations("fallback");
    let report = pipeline::build_cache(&cfg, &loc, &NoProgress).unwrap();
    assert!(report.notes[0].contains("synthetic"));
    let cache = TupleCache::open(&loc.cache_dir).unwrap();
    let m = cache.manifest();
    assert_eq!(m.source, "synthetic");
    assert_eq!(m.horizon, 32);
    assert_eq!(m.scenes.len(), 24);
    for s in Split::ALL {
        assert!(m.counts[&s] > 0, "{s}");
        let compact = cache.load_compact(s).unwrap();
        assert_eq!(compact.len(), m.counts[&s]);
        assert!(
            compact
                .iter()
                .all(|t| m.scenes[t.scene as usize].split == s)
        );
        let dense = cache.load(s).unwrap();
        assert_eq!(dense.len(), compact.len());
        assert_eq!(dense[0], compact[0].to_tuple(&m.bev));
    }
    // Fractions of the training scenes: nested, at least one scene, deterministic.
    let all = cache.pick_scenes(Split::Train, 1.0, 9).unwrap();
    let half = cache.pick_scenes(Split::Train, 0.5, 9).unwrap();
    let tiny = cache.pick_scenes(Split::Train, 0.01, 9).unwrap();
    assert_eq!(all.len(), m.scenes_in(Split::Train).len());
    assert_eq!(tiny.len(), 1);
    assert!(half.iter().all(|s| all.contains(s)) && tiny.iter().all(|s| half.contains(s)));
    let part = cache.load_scenes(Split::Train, 0.5, 9).unwrap();
    assert!(part.iter().all(|t| half.contains(&t.scene)));
    assert!(cache.pick_scenes(Split::Train, 0.0, 9).is_err());
    // A truncated file names itself.
    let bin = loc.cache_dir.join("val.bin");
    let bytes = std::fs::read(&bin).unwrap();
    std::fs::write(&bin, &bytes[..bytes.len() - 3]).unwrap();
    let err = cache.load_compact(Split::Val).unwrap_err();
    assert!(err.to_string().contains("val.bin"), "{err}");
    assert!(err.to_string().contains("the manifest says"), "{err}");
    // A file from another build (same header, other length) is refused by the manifest's size.
    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0; 7]);
    std::fs::write(&bin, &longer).unwrap();
    let err = cache.load_compact(Split::Val).unwrap_err();
    assert!(err.to_string().contains("human2nav data build"), "{err}");
    // A build interrupted before its manifest leaves no manifest behind: the cache does not open.
    std::fs::remove_file(loc.cache_dir.join("manifest.json")).unwrap();
    assert!(TupleCache::open(&loc.cache_dir).is_err());
}

#[test]
fn cache_bytes_do_not_depend_on_the_thread_count() {
    let (cfg, loc) = synthetic_locations("threads");
    let build = |threads: usize, sub: &str| {
        let loc = Locations {
            cache_dir: loc.cache_dir.join(sub),
            ..loc.clone()
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| pipeline::build_cache(&cfg, &loc, &NoProgress).unwrap());
        Split::ALL.map(|s| std::fs::read(loc.cache_dir.join(format!("{}.bin", s.name()))).unwrap())
    };
    assert_eq!(build(1, "one"), build(2, "two"));
}

#[test]
fn synthetic_fallback_episodes() {
    let (cfg, loc) = synthetic_locations("episodes");
    let r = pipeline::build_episodes(&cfg, &loc, &NoProgress).unwrap();
    assert_eq!(r.suite.source, "synthetic");
    for c in ScenarioClass::ALL {
        assert_eq!(r.suite.counts[&c], 6, "{c}");
    }
}

#[test]
fn missing_data_without_fallback_is_an_error() {
    let (mut cfg, loc) = synthetic_locations("nofallback");
    cfg.sources.synthetic_fallback = false;
    let err = pipeline::build_cache(&cfg, &loc, &NoProgress).unwrap_err();
    assert!(matches!(err, DataError::NoData(_)), "{err}");
}

#[test]
fn real_cache_keeps_test_scenes_out_of_training() {
    let Some(root) = common::data("real_cache_keeps_test_scenes_out_of_training") else {
        return;
    };
    let mut cfg = DataConfig::load(&config_file()).unwrap();
    cfg.tuples.stride = 20; // fewer tuples: this checks structure, not volume
    let dir = common::scratch("real");
    let loc = Locations {
        workspace: dir.clone(),
        data_root: root,
        cache_dir: dir.join("cache"),
        episodes: dir.join("e.json"),
    };
    let report = pipeline::build_cache(&cfg, &loc, &NoProgress).unwrap();
    let m = report.cache.manifest();
    assert_eq!(m.source, "real");
    for s in &m.scenes {
        let expected = cfg.split.of(&s.name).unwrap();
        assert_eq!(s.split, expected, "{}", s.name);
    }
    let names: Vec<&str> = m.scenes.iter().map(|s| s.name.as_str()).collect();
    for n in [
        "eth/eth",
        "eth/hotel",
        "ucy/zara01",
        "ucy/students03",
        "sdd/gates_2",
        "sdd/bookstore_0",
    ] {
        assert!(names.contains(&n), "{n} missing");
    }
    // SDD videos with raw annotations come from the raw files, the rest from TrajNet.
    let fmt = |n: &str| {
        m.scenes
            .iter()
            .find(|s| s.name == n)
            .unwrap()
            .format
            .clone()
    };
    assert_eq!(fmt("sdd/gates_2"), "sdd_raw");
    assert_eq!(fmt("sdd/bookstore_0"), "sdd_trajnet");
    let train = report.cache.load_compact(Split::Train).unwrap();
    let test_idx = m.scenes_in(Split::Test);
    assert!(!test_idx.is_empty());
    assert!(train.iter().all(|t| !test_idx.contains(&t.scene)));
    // Per dataset, the tuples' walking speed is plausible.
    for ds in ["eth", "ucy", "sdd"] {
        let v: Vec<f64> = train
            .iter()
            .filter(|t| m.scenes[t.scene as usize].dataset == ds && t.speed() > 0.2)
            .map(|t| t.speed() as f64)
            .collect();
        if v.is_empty() {
            continue;
        }
        let med = human2nav_data::resample::median(v).unwrap();
        assert!((0.8..=1.8).contains(&med), "{ds}: {med}");
    }
}

#[test]
fn real_episodes_from_held_out_scenes() {
    let Some(root) = common::data("real_episodes_from_held_out_scenes") else {
        return;
    };
    let cfg = DataConfig::load(&config_file()).unwrap();
    let dir = common::scratch("real-episodes");
    let loc = Locations {
        workspace: dir.clone(),
        data_root: root,
        cache_dir: dir.join("cache"),
        episodes: dir.join("e.json"),
    };
    let r = pipeline::build_episodes(&cfg, &loc, &NoProgress).unwrap();
    for c in ScenarioClass::ALL {
        eprintln!(
            "{c}: {} episodes ({} candidates)",
            r.suite.counts[&c],
            r.stats.candidates.get(&c).copied().unwrap_or(0)
        );
        assert!(r.suite.counts[&c] > 0, "{c}");
    }
    for e in &r.suite.episodes {
        assert_eq!(cfg.split.of(&e.scene), Some(Split::Test), "{}", e.scene);
        assert!((1..=15).contains(&e.density));
        assert!(
            (5.0..6.0).contains(&e.goal_distance()),
            "{}",
            e.goal_distance()
        );
        assert!(e.agents.iter().all(|a| !a.positions.is_empty()));
    }
    let densities: Vec<usize> = r.suite.episodes.iter().map(|e| e.density).collect();
    assert_eq!(densities.iter().min(), Some(&1));
    assert!(densities.iter().max().copied().unwrap_or(0) >= 10);
}

#[test]
fn hungarian_tracker_on_sdd_without_identities() {
    let Some(root) = common::data("hungarian_tracker_on_sdd_without_identities") else {
        return;
    };
    let cfg = DataConfig::load(&config_file()).unwrap();
    let dir = common::scratch("assoc");
    let loc = Locations {
        workspace: dir.clone(),
        data_root: root,
        cache_dir: dir.join("c"),
        episodes: dir.join("e.json"),
    };
    let per_video = pipeline::evaluate_association(&cfg, &loc, &NoProgress).unwrap();
    assert_eq!(per_video.len(), 19);
    let mut total = human2nav_data::association::AssociationReport::default();
    for (_, r) in &per_video {
        total.add(r);
    }
    eprintln!(
        "SDD association at 10 Hz: {} detections, {} identities, {} tracks, {} ID switches, {:.1}% correct",
        total.detections,
        total.identities,
        total.tracks,
        total.id_switches,
        100.0 * total.correct_fraction
    );
    assert!(total.correct_fraction > 0.9, "{}", total.correct_fraction);
    assert!(
        total.id_switches < total.identities,
        "{} switches",
        total.id_switches
    );
}
