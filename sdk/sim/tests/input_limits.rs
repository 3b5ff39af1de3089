//! Hostile input to the benchmark and `plan --episode`: bounded budgets, counts and threads,
//! regular files only, and one episode reader for both (ARCHITECTURE.md, "Input limits").

#![allow(clippy::unwrap_used)]

mod common;

use human2nav_core::Limits;
use human2nav_sim::config::{BenchConfig, build_suites};
use human2nav_sim::driver::{BenchPlan, MAX_THREADS, run};
use human2nav_sim::episode::{Episode, EpisodeSuite, ScenarioClass};
use human2nav_sim::plan_figure::load_episodes;
use human2nav_sim::runner::MAX_BUDGET;
use human2nav_sim::{ProgressBar, SimConfig, SimError};
use std::path::{Path, PathBuf};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("h2n-sim-limits-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const BASE: &str = r#"
robots = ["robots/diablo/robot.toml"]
[[methods]]
name = "straight"
kind = "straight"
"#;

#[test]
fn huge_budgets_steps_and_counts_in_the_bench_config_name_the_setting() {
    for (i, (extra, needle)) in [
        ("[sim]\nbudget_margin = 1e9\n", "`sim.budget_margin`"),
        ("[sim]\nbudget_factor = 1e9\n", "`sim.budget_factor`"),
        ("[sim]\ndt = 1e-9\nreplan_hz = 1e8\n", "`sim.dt`"),
        ("[sim]\ndt = 0.0\n", "`sim.dt`"),
    ]
    .iter()
    .enumerate()
    {
        let dir = scratch(&format!("cfg{i}"));
        let path = dir.join("bench.toml");
        let body = format!("{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\n\n{extra}");
        std::fs::write(&path, body).unwrap();
        let e = BenchConfig::load(&path).unwrap_err().to_string();
        assert!(e.contains(needle), "{extra}: {e}");
    }
    let dir = scratch("per-class");
    let path = dir.join("bench.toml");
    std::fs::write(
        &path,
        format!(
            "{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\nper_class = 1000000000000\n"
        ),
    )
    .unwrap();
    let e = BenchConfig::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("suites[0].per_class") && e.contains("1..=10000"),
        "{e}"
    );
    assert!(SimConfig::default().validate().is_ok());
}

#[test]
fn threads_are_bounded_before_any_is_spawned() {
    let sim = SimConfig::default();
    let plan = BenchPlan {
        suites: &[],
        robots: &[],
        methods: &[],
        sim: &sim,
        seed: 1,
        quick: true,
        snapshot_method: None,
        command: String::new(),
        threads: Some(100_000),
        failures: 0,
        record: None,
    };
    let out = scratch("threads").join("out");
    let e = run(&plan, &out, &ProgressBar::hidden()).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("`bench.threads`"), "{msg}");
    assert!(
        msg.contains(&format!("more than the limit of {MAX_THREADS}")),
        "{msg}"
    );
    assert!(!out.exists(), "nothing is written before the check");
}

#[test]
fn a_run_budget_is_bounded_whatever_the_robot() {
    // A robot crawling at 1 µm/s towards a goal 5 m away: the budget rule asks for 190 years.
    let slow = Limits {
        v_max: 1e-6,
        v_reverse_max: 1e-6,
        a_max: 1.0,
        omega_max: 1.0,
        kappa_max: None,
        lateral_speed_max: 1e-6,
        coupled: None,
    };
    let ep = common::episode("far", ScenarioClass::CoFlow, 0.0, Vec::new());
    let budget = SimConfig::default().budget_for(&ep, &slow);
    assert_eq!(budget, MAX_BUDGET);
    let normal = common::robot("diablo");
    let b = SimConfig::default().budget_for(&ep, &normal.limits);
    assert!(b > 0.0 && b < 60.0, "{b}");
}

/// Writes `episodes` as a suite file (no header checks: the file is written as given).
fn write_suite(path: &Path, episodes: Vec<Episode>, version: u32) {
    let mut suite = EpisodeSuite::new("test", episodes);
    suite.version = version;
    std::fs::write(path, serde_json::to_string(&suite).unwrap()).unwrap();
}

fn good_episodes() -> Vec<Episode> {
    ScenarioClass::ALL
        .iter()
        .enumerate()
        .map(|(i, c)| {
            common::episode(
                &format!("e{i}"),
                *c,
                0.0,
                vec![common::standing(1, [2.5, 1.5], 40)],
            )
        })
        .collect()
}

/// What `bench` says about an episode file: the error of its `real` suite, or `None`.
fn bench_error(dir: &Path, file: &str) -> Option<String> {
    let path = dir.join("bench.toml");
    std::fs::write(
        &path,
        format!(
            "{BASE}\n[[suites]]\nname = \"real\"\nkind = \"real\"\nepisodes = \"{file}\"\nper_class = 5\n"
        ),
    )
    .unwrap();
    let cfg = BenchConfig::load(&path).unwrap();
    build_suites(&cfg, false, None).err().map(|e| e.to_string())
}

/// `plan --episode` and `bench` accept exactly the same episode files: each bad file below is
/// refused by both, with the file, the episode's index and id and the field named.
#[test]
fn plan_and_bench_read_episode_files_alike() {
    let dir = scratch("episodes");
    let file = dir.join("episodes.json");
    write_suite(&file, good_episodes(), 1);
    assert!(bench_error(&dir, "episodes.json").is_none());
    assert_eq!(load_episodes(&file).unwrap().len(), 4);

    type Edit = fn(&mut Episode);
    let cases: [(&str, Edit); 5] = [
        ("dt", |e| e.dt = 0.0),
        ("dt", |e| e.dt = -0.1),
        ("time_budget", |e| e.time_budget = 1e9),
        ("time_budget", |e| e.time_budget = -1.0),
        ("start", |e| e.start.x = 1e300),
    ];
    for (field, edit) in cases {
        let mut eps = good_episodes();
        edit(&mut eps[2]);
        write_suite(&file, eps, 1);
        let needle = format!("episode 2 (`e2`): {field}:");
        let plan = load_episodes(&file).unwrap_err();
        assert!(matches!(plan, SimError::Parse { .. }), "{plan}");
        let bench = bench_error(&dir, "episodes.json").expect("bench accepted it");
        for e in [plan.to_string(), bench] {
            assert!(e.contains("episodes.json"), "{e}");
            assert!(e.contains(&needle), "{e}");
        }
    }
    // The file format version.
    write_suite(&file, good_episodes(), 999);
    let plan = load_episodes(&file).unwrap_err().to_string();
    let bench = bench_error(&dir, "episodes.json").expect("bench accepted version 999");
    for e in [plan, bench] {
        assert!(e.contains("version: episode format version 999"), "{e}");
    }
    // A single episode, the other form `plan --episode` reads: the same rule.
    let mut one = good_episodes().remove(0);
    one.dt = -1.0;
    std::fs::write(&file, serde_json::to_string(&one).unwrap()).unwrap();
    assert!(
        load_episodes(&file)
            .unwrap_err()
            .to_string()
            .contains("episode 0 (`e0`): dt:")
    );
    assert!(
        bench_error(&dir, "episodes.json")
            .unwrap()
            .contains("episode 0 (`e0`): dt:")
    );
}

#[cfg(unix)]
#[test]
fn configs_and_episode_files_must_be_regular_files() {
    let dir = scratch("fifo");
    let fifo = dir.join("bench.toml");
    let made = matches!(
        std::process::Command::new("mkfifo").arg(&fifo).status(),
        Ok(s) if s.success()
    );
    if !made {
        eprintln!("skipping: mkfifo is not available");
        return;
    }
    let e = BenchConfig::load(&fifo).unwrap_err().to_string();
    assert!(e.contains("bench.toml") && e.contains("a FIFO"), "{e}");
    let e = load_episodes(&fifo).unwrap_err().to_string();
    assert!(e.contains("bench.toml") && e.contains("a FIFO"), "{e}");
    // A suite's episode file that is a FIFO or a directory: an error naming it, not a
    // fallback to synthetic episodes and no blocking read.
    std::fs::remove_file(&fifo).unwrap();
    let pipe = dir.join("pipe.json");
    assert!(
        std::process::Command::new("mkfifo")
            .arg(&pipe)
            .status()
            .unwrap()
            .success()
    );
    let e = bench_error(&dir, "pipe.json").unwrap();
    assert!(e.contains("pipe.json") && e.contains("a FIFO"), "{e}");
    std::fs::create_dir_all(dir.join("episodes.json")).unwrap();
    let e = bench_error(&dir, "episodes.json").unwrap();
    assert!(
        e.contains("episodes.json") && e.contains("a directory"),
        "{e}"
    );
}
