//! The benchmark's quick mode end to end with the shipped configurations: ORCA loaded from its
//! built plugin library, the straight baseline, every robot of the workspace, the real held-out
//! suites (mined first when the datasets are present and a file is missing, else the synthetic
//! fallback), the reactive crowd, the synthetic suite, and the `human2nav bench --quick`
//! command itself. Run after
//! `cargo build --workspace` (as `sdk/dev.sh test` does), which builds the plugin and the CLI.

// Helpers outside #[test] functions unwrap too (clippy.toml only allows it inside tests).
#![allow(clippy::unwrap_used)]

use human2nav_integration_tests::{target_profile_dir, workspace_root};
use human2nav_plugin::PluginHost;
use human2nav_sim::config::{
    BenchConfig, build_suites, builtin_method, ensure_episode_files, load_robots,
};
use human2nav_sim::driver::{self, BenchOutcome, BenchPlan};
use human2nav_sim::report::CSV_HEADER;
use human2nav_sim::{MethodSpec, ProgressBar, RobotSetup, Suite, SuiteKind};
use std::path::{Path, PathBuf};
use std::sync::Arc;

fn scratch(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("h2n-{name}-{}", std::process::id()))
}

/// A shipped config in quick mode: its robots, the methods this crate can build (methods that
/// need libtorch are left out with a note) and its suites.
struct Quick {
    config: String,
    cfg: BenchConfig,
    robots: Vec<RobotSetup>,
    methods: Vec<MethodSpec>,
    suites: Vec<Suite>,
}

impl Quick {
    fn names(&self) -> Vec<String> {
        self.methods.iter().map(|m| m.name.clone()).collect()
    }

    /// One benchmark run into `out`.
    fn run(&self, out: &Path) -> BenchOutcome {
        let plan = BenchPlan {
            suites: &self.suites,
            robots: &self.robots,
            methods: &self.methods,
            sim: &self.cfg.sim,
            seed: self.cfg.seed,
            quick: true,
            snapshot_method: Some("orca"),
            command: format!("quick test of {}", self.config),
            threads: None,
            failures: 1,
            record: None,
        };
        let res = driver::run(&plan, out, &ProgressBar::hidden()).unwrap();
        let expected: usize = self
            .suites
            .iter()
            .map(|s| {
                s.episodes.len()
                    * self.robots.len()
                    * self.methods.iter().filter(|m| s.runs(&m.name)).count()
            })
            .sum();
        assert_eq!(res.rows.len(), expected);
        res
    }
}

fn quick(config: &str) -> Quick {
    let cfg = BenchConfig::load(&workspace_root().join(config)).unwrap();
    let robots = load_robots(&cfg).unwrap();
    let host = Arc::new(PluginHost::new());
    let mut methods: Vec<MethodSpec> = Vec::new();
    for m in &cfg.methods {
        match builtin_method(m, &cfg, &host) {
            Ok(Some(spec)) => methods.push(spec),
            Ok(None) => eprintln!(
                "{config}: method `{}` (kind `{}`) needs libtorch (human2nav-experiments); left out",
                m.name, m.kind
            ),
            Err(e) => panic!(
                "{e}: build the workspace first (`cargo build --workspace`, as sdk/dev.sh test does)"
            ),
        }
    }
    assert!(
        methods.iter().any(|m| m.name == "orca"),
        "{config} must benchmark ORCA"
    );
    let data = workspace_root().join("sdk/configs/data.toml");
    let fallback = ensure_episode_files(&cfg, &data, &|m| eprintln!("{m}")).unwrap();
    let suites = build_suites(&cfg, true, fallback.as_deref()).unwrap();
    Quick {
        config: config.to_string(),
        cfg,
        robots,
        methods,
        suites,
    }
}

fn check_outputs(res: &BenchOutcome, suites: &[Suite], methods: &[String]) {
    // The empty-world sanity suite: every method reaches SR = 1 on every robot.
    assert!(
        res.empty_world_failures.is_empty(),
        "empty-world failures: {:?}",
        res.empty_world_failures
    );
    for r in &res.rows {
        let m = &r.metrics;
        assert_eq!(
            u8::from(m.success) + u8::from(m.collision) + u8::from(m.timeout),
            1
        );
        assert!((0.0..=1.0).contains(&m.tfs) && m.tfs <= m.tfs_plan && m.tfs <= m.tfs_executed);
        assert!(m.duration <= m.budget + 1e-9 && m.path_length >= 0.0);
        assert!(m.time_within_intimate <= m.time_within_personal + 1e-12);
        assert_eq!(
            m.planner_errors, 0,
            "{} on {} in {}: planner errors",
            r.method, r.robot, r.episode
        );
        if let Some(c) = m.min_clearance {
            assert_eq!(
                c < 0.0 || m.obstacle_hit.is_some(),
                m.collision,
                "{}: clearance {c} vs collision {}",
                r.episode,
                m.collision
            );
        }
    }
    let csv = std::fs::read_to_string(&res.results_csv).unwrap();
    assert!(csv.starts_with(CSV_HEADER));
    assert_eq!(csv.lines().count(), res.rows.len() + 1);
    let report = std::fs::read_to_string(&res.report_md).unwrap();
    for m in methods {
        assert!(
            report.contains(&format!("| {m} |")),
            "report lacks method {m}"
        );
    }
    // Per suite with pedestrians: Fig. 6, 7 and the density figure, Fig. 4 when the snapshot
    // method succeeded somewhere on the first robot, and one failure figure per method that
    // failed in it (quick mode draws one failed run each).
    let names: Vec<String> = res
        .figures
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    for s in suites.iter().filter(|s| s.kind != SuiteKind::Empty) {
        for f in driver::suite_figure_files(&s.name) {
            assert!(names.contains(&f), "{f} missing: {names:?}");
        }
        for m in methods.iter().filter(|m| s.runs(m)) {
            let failed = res
                .rows
                .iter()
                .any(|r| r.suite == s.name && &r.method == m && !r.metrics.success);
            let file = driver::failure_file(&s.name, m, 1);
            assert_eq!(names.contains(&file), failed, "{file}: {names:?}");
        }
    }
    for f in &res.figures {
        let bytes = std::fs::read(f).unwrap();
        assert!(
            bytes.starts_with(b"\x89PNG"),
            "{} is not a PNG",
            f.display()
        );
    }
}

#[test]
fn quick_bench_with_the_shipped_config_is_sane_and_deterministic() {
    let (a_dir, b_dir) = (scratch("bench-a"), scratch("bench-b"));
    // The suites are built once: `cli_bench_quick_writes_the_report` may mine the real
    // episodes file while this test runs, which would change what a second `build_suites` reads.
    let q = quick("sdk/configs/bench.toml");
    let a = q.run(&a_dir);
    check_outputs(&a, &q.suites, &q.names());
    let real = q.suites.iter().any(|s| s.kind == SuiteKind::Real);
    eprintln!(
        "bench.toml quick: {} rows, real episodes: {real}",
        a.rows.len()
    );
    // Deterministic: a second run writes the same results.csv byte for byte.
    let b = q.run(&b_dir);
    let (ca, cb) = (
        std::fs::read(&a.results_csv).unwrap(),
        std::fs::read(&b.results_csv).unwrap(),
    );
    assert!(
        ca == cb,
        "results.csv differs between two runs with the same seed"
    );
    std::fs::remove_dir_all(&a_dir).unwrap();
    std::fs::remove_dir_all(&b_dir).unwrap();
}

#[test]
fn quick_bench_on_the_synthetic_suite() {
    let dir = scratch("bench-synthetic");
    let q = quick("sdk/configs/bench_synthetic.toml");
    let res = q.run(&dir);
    check_outputs(&res, &q.suites, &q.names());
    assert!(
        res.rows
            .iter()
            .any(|r| r.suite == "synthetic" && r.agents > 0)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The README's benchmark in quick mode through the CLI, with every shipped method (ORCA,
/// SARL, Human2Nav with and without guidance, straight): the command fails when a method
/// misses SR = 1 in the empty world.
#[test]
fn cli_bench_quick_writes_the_report() {
    let exe = target_profile_dir().join(format!("human2nav{}", std::env::consts::EXE_SUFFIX));
    if !exe.is_file() {
        eprintln!(
            "skipping cli_bench_quick_writes_the_report: {} not built (cargo build --workspace)",
            exe.display()
        );
        return;
    }
    let out = scratch("bench-cli");
    let status = std::process::Command::new(&exe)
        .current_dir(workspace_root())
        .args([
            "bench",
            "--config",
            "sdk/configs/bench.toml",
            "--quick",
            "--out",
        ])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success(), "human2nav bench --quick failed: {status}");
    let mut files = vec!["results.csv".to_string(), "report.md".to_string()];
    for suite in ["real", "interaction", "interaction-reactive"] {
        files.extend(driver::suite_figure_files(suite));
    }
    for f in files {
        assert!(out.join(&f).is_file(), "{f} missing");
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for s in ["real", "interaction", "interaction-reactive"] {
        assert!(
            report.contains(&format!("## Suite `{s}`")),
            "report lacks suite {s}"
        );
    }
    // The lock is gone after the run, and a folder another live run holds is refused before
    // anything is written.
    assert!(!out.join(human2nav_core::lock::LOCK_FILE).exists());
    let held = human2nav_core::lock::DirLock::acquire(&out, "a test").unwrap();
    let second = std::process::Command::new(&exe)
        .current_dir(workspace_root())
        .args([
            "bench",
            "--config",
            "sdk/configs/bench.toml",
            "--quick",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert!(!second.status.success());
    assert!(stderr.contains("is being written by process"), "{stderr}");
    drop(held);
    std::fs::remove_dir_all(&out).unwrap();
}

/// An unknown name in `--suites` fails before anything runs, naming it and the suites there are.
#[test]
fn cli_bench_rejects_an_unknown_suite() {
    let exe = target_profile_dir().join(format!("human2nav{}", std::env::consts::EXE_SUFFIX));
    if !exe.is_file() {
        eprintln!(
            "skipping cli_bench_rejects_an_unknown_suite: {} not built",
            exe.display()
        );
        return;
    }
    let out = std::process::Command::new(&exe)
        .current_dir(workspace_root())
        .args([
            "bench",
            "--config",
            "sdk/configs/bench.toml",
            "--suites",
            "real,intraction",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("intraction") && err.contains("interaction-reactive"),
        "{err}"
    );
}
