//! Hostile input: every file the data crate reads must be a regular file within its size cap,
//! and counts, coordinates and times are bounded when a file is read (ARCHITECTURE.md, "Input
//! limits"). Each case is an error naming the file (and line or field), never an abort.

#![allow(clippy::unwrap_used)]

mod common;

use human2nav_data::config::DataConfig;
use human2nav_data::limits::MAX_DATASET_FILE_BYTES;
use human2nav_data::loaders::{eth, sdd, sgan, ucy};
use human2nav_data::pipeline::{self, Locations, NoProgress};
use human2nav_data::scenario::EpisodeSuite;
use human2nav_data::{DataError, Homography, ScenarioClass, TupleCache, synthetic};
use std::path::Path;

fn message(e: DataError) -> String {
    e.to_string()
}

#[test]
fn ucy_counts_are_bounded_before_anything_is_allocated() {
    let p = common::scratch("huge_count.vsp");
    // Four billion splines announced by a two-line file: this allocated before reading them.
    std::fs::write(&p, "4000000000 - splines\n1\n").unwrap();
    let e = message(ucy::parse_vsp(&p).unwrap_err());
    assert!(e.contains("huge_count.vsp:1"), "{e}");
    assert!(e.contains("more than the limit of 1000000"), "{e}");

    std::fs::write(&p, "1 - splines\n900000 - points\n1 2 0 0\n").unwrap();
    let e = message(ucy::parse_vsp(&p).unwrap_err());
    assert!(e.contains("huge_count.vsp:2"), "{e}");
    assert!(
        e.contains("declares 900000 control points but only 1 non-empty lines follow"),
        "{e}"
    );

    std::fs::write(&p, "3 - splines\n1\n1 2 0 0\n").unwrap();
    let e = message(ucy::parse_vsp(&p).unwrap_err());
    assert!(e.contains("declares 3 splines but only 2"), "{e}");

    // A frame that jumps back within a spline: the walker would go back in time.
    std::fs::write(&p, "1 - splines\n3 - points\n1 2 10 0\n1 3 20 0\n1 4 5 0\n").unwrap();
    let e = message(ucy::parse_vsp(&p).unwrap_err());
    assert!(e.contains("huge_count.vsp:5"), "{e}");
    assert!(
        e.contains("frame 5 of spline 1 comes after frame 20"),
        "{e}"
    );

    // A count that is not a number at all.
    std::fs::write(&p, "99999999999999999999999 - splines\n").unwrap();
    let e = message(ucy::parse_vsp(&p).unwrap_err());
    assert!(e.contains("expected the number of splines"), "{e}");
}

#[test]
fn a_huge_coordinate_is_refused_when_read_with_file_and_line() {
    // sgan / TrajNet rows.
    let p = common::scratch("far.txt");
    std::fs::write(&p, "0 1 1.0 2.0\n10 1 1e300 2.0\n").unwrap();
    let e = sgan::load(&p, "far", "sgan").unwrap_err();
    assert!(matches!(e, DataError::Parse { line: 2, .. }), "{e}");
    let e = message(e);
    assert!(e.contains("far.txt:2"), "{e}");
    assert!(e.contains("world x = 1e300 m is out of range"), "{e}");
    let e = message(sdd::load_trajnet(&p, "far").unwrap_err());
    assert!(e.contains("far.txt:2") && e.contains("out of range"), "{e}");

    // ETH obsmat.
    let p = common::scratch("far_obsmat.txt");
    std::fs::write(
        &p,
        "0 1 1.0 0 2.0 0 0 0\n6 1 1.5 0 -2e7 0 0 0\n12 1 2.0 0 2.0 0 0 0\n",
    )
    .unwrap();
    let e = message(eth::load_obsmat(&p, "far").unwrap_err());
    assert!(e.contains("far_obsmat.txt:2"), "{e}");
    assert!(e.contains("world y = -2e7 m is out of range"), "{e}");

    // UCY: the pixel is fine, the homography sends it far away.
    let p = common::scratch("far.vsp");
    std::fs::write(&p, "1 - splines\n2 - points\n0.5 0.5 0 0\n3 4 10 0\n").unwrap();
    let h = Homography::scale(1e6).unwrap();
    let e = message(ucy::load_vsp(&p, &h, ucy::VspConvention::Centred, "far").unwrap_err());
    assert!(e.contains("far.vsp:4"), "{e}");
    assert!(e.contains("out of range"), "{e}");

    // SDD raw: box corners in pixels, and a scale that would blow them up.
    let p = common::scratch("far_annotations.txt");
    std::fs::write(
        &p,
        "0 1 2 3 4 5 0 0 0 \"Pedestrian\"\n0 1e300 2 3 4 6 0 0 0 \"Pedestrian\"\n",
    )
    .unwrap();
    let e = message(sdd::parse_raw(&p).unwrap_err());
    assert!(e.contains("far_annotations.txt:2"), "{e}");
    assert!(e.contains("xmin = 1e300 px is out of range"), "{e}");
    let y = common::scratch("far_scales.yaml");
    std::fs::write(&y, "gates:\n  video0:\n    scale: 1e300\n").unwrap();
    let e = message(sdd::SddScales::load(&y).unwrap_err());
    assert!(e.contains("far_scales.yaml:3"), "{e}");
    assert!(e.contains("scale must be in (0, 1] m/px"), "{e}");
}

#[test]
fn a_far_future_frame_is_refused_with_file_and_line() {
    let p = common::scratch("late.txt");
    // Frame 9e15 at 25 fps: a scene spanning 11 million years, resampled at 0.1 s.
    std::fs::write(&p, "0 1 1.0 2.0\n9000000000000000 1 1.0 2.0\n").unwrap();
    let e = message(sgan::load(&p, "late", "sgan").unwrap_err());
    assert!(e.contains("late.txt:2"), "{e}");
    assert!(e.contains("is out of range (|t| ≤ 86400 s)"), "{e}");
    let v = common::scratch("late.vsp");
    std::fs::write(&v, "1\n2\n1 2 0 0\n3 4 90000000 0\n").unwrap();
    let e = message(ucy::parse_vsp(&v).unwrap_err());
    assert!(
        e.contains("late.vsp:4") && e.contains("out of range"),
        "{e}"
    );
}

/// `data build` on a data root holding one ETH sequence with a 1e300 coordinate: refused while
/// reading, naming the file and the line (before, the cache was written with `inf` in it and
/// `data stats` refused it afterwards).
#[test]
fn data_build_refuses_a_dataset_with_a_huge_coordinate() {
    let dir = common::scratch("far-root");
    let seq = dir.join("data/eth_ucy/opentraj_raw/ETH/seq_eth");
    std::fs::create_dir_all(&seq).unwrap();
    let mut rows = String::new();
    for k in 0..40 {
        rows.push_str(&format!("{} 1 {:.2} 0 1.0 0 0 0\n", 6 * k, 0.5 * k as f64));
    }
    rows.push_str("240 1 1e300 0 1.0 0 0 0\n");
    std::fs::write(seq.join("obsmat.txt"), rows).unwrap();
    let mut cfg = DataConfig::default();
    cfg.sources.ucy = false;
    cfg.sources.sdd_raw = false;
    cfg.sources.sdd_trajnet = false;
    cfg.sources.synthetic_fallback = false;
    let loc = Locations {
        workspace: dir.clone(),
        data_root: dir.join("data"),
        cache_dir: dir.join("cache"),
        episodes: dir.join("episodes.json"),
    };
    let e = message(pipeline::build_cache(&cfg, &loc, &NoProgress).unwrap_err());
    assert!(e.contains("obsmat.txt:41"), "{e}");
    assert!(e.contains("out of range"), "{e}");
    assert!(!dir.join("cache/train.bin").exists());
}

#[cfg(unix)]
fn make_fifo(path: &Path) -> bool {
    let _ = std::fs::remove_file(path);
    matches!(
        std::process::Command::new("mkfifo").arg(path).status(),
        Ok(s) if s.success()
    )
}

#[cfg(unix)]
#[test]
fn dataset_episode_config_and_cache_files_must_be_regular_files() {
    if Path::new("/dev/zero").exists() {
        let e = message(sgan::load(Path::new("/dev/zero"), "zero", "sgan").unwrap_err());
        assert!(e.contains("/dev/zero"), "{e}");
        assert!(
            e.contains("dataset file: expected a regular file, found a character device"),
            "{e}"
        );
    }
    let fifo = common::scratch("pipe");
    if !make_fifo(&fifo) {
        eprintln!("skipping the FIFO cases: mkfifo is not available");
        return;
    }
    let name = fifo.display().to_string();
    for e in [
        message(ucy::parse_vsp(&fifo).unwrap_err()),
        message(EpisodeSuite::load(&fifo).unwrap_err()),
        message(EpisodeSuite::load_any(&fifo).unwrap_err()),
        message(DataConfig::load(&fifo).unwrap_err()),
        message(Homography::load(&fifo).unwrap_err()),
    ] {
        assert!(e.contains(&name), "{e}");
        assert!(e.contains("a FIFO"), "{e}");
    }
    // A directory where the cache's manifest should be.
    let cache = common::scratch("cache-with-dir");
    std::fs::create_dir_all(cache.join("manifest.json")).unwrap();
    let e = message(TupleCache::open(&cache).unwrap_err());
    assert!(
        e.contains("manifest.json") && e.contains("a directory"),
        "{e}"
    );
}

#[test]
fn oversized_files_are_refused_with_the_cap() {
    let p = common::scratch("huge_obsmat.txt");
    let f = std::fs::File::create(&p).unwrap();
    f.set_len(MAX_DATASET_FILE_BYTES + 1).unwrap();
    let e = message(eth::load_obsmat(&p, "huge").unwrap_err());
    assert!(e.contains("huge_obsmat.txt"), "{e}");
    assert!(
        e.contains("dataset file: the file (268435457 bytes) is larger than the limit of 256 MiB"),
        "{e}"
    );
    let _ = std::fs::remove_file(&p);
}

#[test]
fn a_cache_header_announcing_more_tuples_than_it_holds_is_refused() {
    // A real (synthetic) cache whose test split's header count is rewritten, with the manifest
    // agreeing: the count must fit in the file before anything is allocated for it.
    let mut cfg = DataConfig::default();
    cfg.sources.synthetic_scenes = 12;
    let dir = common::scratch("huge-count-cache");
    let loc = Locations {
        workspace: dir.clone(),
        data_root: dir.join("no-datasets-here"),
        cache_dir: dir.join("cache"),
        episodes: dir.join("episodes.json"),
    };
    let report = pipeline::build_cache(&cfg, &loc, &NoProgress).unwrap();
    let bin = loc.cache_dir.join("test.bin");
    let mut bytes = std::fs::read(&bin).unwrap();
    let huge: u64 = 1 << 40;
    bytes[16..24].copy_from_slice(&huge.to_le_bytes());
    std::fs::write(&bin, bytes).unwrap();
    let mpath = loc.cache_dir.join("manifest.json");
    let mut manifest = report.cache.manifest().clone();
    manifest
        .counts
        .insert(human2nav_data::Split::Test, huge as usize);
    std::fs::write(&mpath, serde_json::to_string(&manifest).unwrap()).unwrap();
    let cache = TupleCache::open(&loc.cache_dir).unwrap();
    let e = message(cache.load_compact(human2nav_data::Split::Test).unwrap_err());
    assert!(e.contains("test.bin"), "{e}");
    assert!(
        e.contains("announces 1099511627776 tuples, the file has room for at most"),
        "{e}"
    );
}

#[test]
fn episode_files_are_checked_field_by_field() {
    let episodes = synthetic::episodes(ScenarioClass::CrossFlow, 3, 5);
    let path = common::scratch("checked.json");
    type Edit = fn(&mut human2nav_data::Episode);
    let cases: [(&str, Edit); 6] = [
        ("dt", |e| e.dt = -0.1),
        ("time_budget", |e| e.time_budget = 1e9),
        ("time_budget", |e| e.time_budget = 0.0),
        ("goal", |e| e.goal[0] = 1e300),
        ("agents[0].positions[1]", |e| {
            e.agents[0].positions[1][1] = -1e300
        }),
        ("agents[0].start_step", |e| {
            e.agents[0].start_step = usize::MAX
        }),
    ];
    for (field, edit) in cases {
        let mut eps = episodes.clone();
        edit(&mut eps[1]);
        let id = eps[1].id.clone();
        EpisodeSuite::new("synthetic", eps).save(&path).unwrap();
        for e in [
            EpisodeSuite::load(&path).unwrap_err(),
            EpisodeSuite::load_any(&path).unwrap_err(),
        ] {
            let e = message(e);
            assert!(e.contains("checked.json"), "{e}");
            assert!(e.contains(&format!("episode 1 (`{id}`): {field}:")), "{e}");
        }
    }
    // A single episode (the form `plan --episode` also reads) gets the same checks.
    let mut one = episodes[0].clone();
    one.time_budget = -1.0;
    std::fs::write(&path, serde_json::to_string(&one).unwrap()).unwrap();
    let e = message(EpisodeSuite::load_any(&path).unwrap_err());
    assert!(e.contains("episode 0") && e.contains("time_budget"), "{e}");
    // The file format version.
    let mut suite = EpisodeSuite::new("synthetic", episodes);
    suite.version = 999;
    suite.save(&path).unwrap();
    let e = message(EpisodeSuite::load_any(&path).unwrap_err());
    assert!(e.contains("version: episode format version 999"), "{e}");
}

#[test]
fn data_config_counts_and_times_are_bounded() {
    for (key, edit) in [
        (
            "sources.synthetic_scenes",
            (|c: &mut DataConfig| c.sources.synthetic_scenes = usize::MAX) as fn(&mut DataConfig),
        ),
        ("episodes.max_goal_time", |c| {
            c.episodes.max_goal_time = 1e300
        }),
        ("episodes.reference_speed", |c| {
            c.episodes.reference_speed = 1e-300
        }),
        ("episodes.budget_factor", |c| c.episodes.budget_factor = 1e9),
        ("interaction.reference_accel", |c| {
            c.interaction.reference_accel = 1e-300
        }),
        ("interaction.shifts_per_path", |c| {
            c.interaction.shifts_per_path = 1 << 40
        }),
        ("resample.heading_window", |c| {
            c.resample.heading_window = usize::MAX
        }),
        ("tuples.goal_horizon", |c| c.tuples.goal_horizon = 1e300),
        ("association.max_missed", |c| {
            c.association.max_missed = 1e300
        }),
    ] {
        let mut cfg = DataConfig::default();
        edit(&mut cfg);
        let e = message(cfg.validate().unwrap_err());
        assert!(e.contains(key), "{key}: {e}");
    }
    assert!(DataConfig::default().validate().is_ok());
}

/// A dataset folder that was named and is missing is an error naming the field and the path;
/// with `synthetic_only` the datasets are not looked for at all.
#[test]
fn a_named_dataset_folder_that_is_missing_is_an_error() {
    let dir = common::scratch("named-root");
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("data.toml");
    std::fs::write(&config, "[paths]\ndata_root = \"no/such/datsets\"\n").unwrap();
    let cfg = DataConfig::load(&config).unwrap();
    let e = message(Locations::resolve_checked(&cfg, &config).unwrap_err());
    assert!(
        e.contains("data.toml")
            && e.contains("paths.data_root")
            && e.contains("no/such/datsets")
            && e.contains("does not exist"),
        "{e}"
    );
    let mut only = cfg.clone();
    only.sources.synthetic_only = true;
    let loc = Locations::resolve_checked(&only, &config).unwrap();
    assert!(!loc.datasets(&only));
}

/// Two builds of one cache folder: the second is refused before it reads anything, naming the
/// folder and the build that holds it, and the first build's cache opens.
#[test]
fn a_second_build_of_one_cache_is_refused_while_the_first_runs() {
    let mut cfg = DataConfig::default();
    cfg.sources.synthetic_only = true;
    cfg.sources.synthetic_scenes = 4;
    let dir = common::scratch("locked-cache");
    let loc = Locations {
        workspace: dir.clone(),
        data_root: dir.join("no-datasets-here"),
        cache_dir: dir.join("cache"),
        episodes: dir.join("episodes.json"),
    };
    let held = human2nav_core::lock::DirLock::acquire(&loc.cache_dir, "the first build").unwrap();
    let e = message(pipeline::build_cache(&cfg, &loc, &NoProgress).unwrap_err());
    assert!(
        e.contains("cache") && e.contains(".human2nav.lock") && e.contains("the first build"),
        "{e}"
    );
    drop(held);
    let report = pipeline::build_cache(&cfg, &loc, &NoProgress).unwrap();
    assert!(TupleCache::open(report.cache.dir()).is_ok());
    assert!(!loc.cache_dir.join(".human2nav.lock").exists());
}
