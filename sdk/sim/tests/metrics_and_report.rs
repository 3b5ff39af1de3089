//! Metrics closed forms, the deterministic parallel runner, CSV, report and figures.

mod common;

use approx::assert_relative_eq;
use common::{episode, robot, robots, standing, walking};
use human2nav_core::embodiment::RobotState;
use human2nav_core::{Pose2, Twist2};
use human2nav_sim::bench::{MethodSpec, ResultRow, Suite, SuiteKind, episode_seed, run_bench};
use human2nav_sim::driver::{self, BenchOutcome, BenchPlan};
use human2nav_sim::episode::ScenarioClass;
use human2nav_sim::metrics::{EpisodeMetrics, mean_jerk, tfs_scores};
use human2nav_sim::report::{CSV_HEADER, results_csv};
use human2nav_sim::runner::{EpisodeRun, PlanSample};
use human2nav_sim::{Outcome, SimConfig};
use indicatif::ProgressBar;

#[test]
fn jerk_of_constant_velocity_from_rest() {
    // p_n = v·n·dt (N positions, N − 2 jerks): the only non-zero jerk is the start, (0 − v/dt)/dt.
    let (v, dt, n) = (1.2, 0.05, 11);
    let p: Vec<[f64; 2]> = (0..n).map(|k| [v * dt * k as f64, 0.0]).collect();
    assert_relative_eq!(
        mean_jerk(&p, dt),
        v / (dt * dt) / (n - 2) as f64,
        epsilon = 1e-9
    );
    // Constant acceleration from rest, p = ½·a·t²: v_n = a·dt·(n + ½), a_{−1} = a/2, then a;
    // the jerks are a/(2·dt) and zeros.
    let a = 0.8;
    let p: Vec<[f64; 2]> = (0..n)
        .map(|k| [0.0, 0.5 * a * (dt * k as f64).powi(2)])
        .collect();
    assert_relative_eq!(
        mean_jerk(&p, dt),
        a / (2.0 * dt) / (n - 2) as f64,
        epsilon = 1e-9
    );
    assert_eq!(mean_jerk(&p[..1], dt), 0.0);
}

fn run_with(
    states: Vec<RobotState>,
    raw: Vec<Twist2>,
    clearance: Vec<f64>,
    plans: Vec<PlanSample>,
) -> EpisodeRun {
    EpisodeRun {
        outcome: Outcome::Success,
        end_time: 0.05 * raw.len() as f64,
        budget: 10.0,
        dt: 0.05,
        commands: raw.clone(),
        raw_commands: raw,
        states,
        clearance,
        plans,
        planner_errors: vec![],
        contact: None,
        obstacle_hit: None,
        end_goal_distance: 0.0,
        end_goal_crowd: None,
        crowd: None,
    }
}

#[test]
fn tfs_pools_plan_waypoints_and_takes_the_minimum() {
    let r = robot("diablo");
    let l = r.limits;
    // Plan A: 4 poses at 1 m/s along x from rest... the first waypoint needs (1 − 0)/0.1 =
    // 10 m/s² > a_max: 2 of 3 waypoints feasible. Plan B: standing still, 3 of 3 feasible.
    let a: Vec<Pose2> = (0..4)
        .map(|k| Pose2::new(0.1 * k as f64, 0.0, 0.0))
        .collect();
    let b = vec![Pose2::new(0.0, 0.0, 0.0); 4];
    let plans = vec![
        PlanSample {
            t0: 0.0,
            dt: 0.1,
            poses: a,
            initial_velocity: Twist2::ZERO,
            fallback: false,
            candidates: Vec::new(),
        },
        PlanSample {
            t0: 0.1,
            dt: 0.1,
            poses: b,
            initial_velocity: Twist2::ZERO,
            fallback: true,
            candidates: Vec::new(),
        },
    ];
    // Commands: one beyond v_max out of four, accelerations small.
    let raw = vec![
        Twist2::new(0.0, 0.0, 0.0),
        Twist2::new(0.02, 0.0, 0.0),
        Twist2::new(0.04, 0.0, 9.0),
        Twist2::new(0.06, 0.0, 0.0),
    ];
    let states = vec![RobotState::default(); 5];
    let run = run_with(states, raw, vec![f64::INFINITY; 5], plans);
    let (p, e) = tfs_scores(&run, &l);
    assert_relative_eq!(p, 5.0 / 6.0, epsilon = 1e-12);
    assert_relative_eq!(e, 3.0 / 4.0, epsilon = 1e-12);
    let m = EpisodeMetrics::compute(&run, &l);
    assert_relative_eq!(m.tfs, 0.75, epsilon = 1e-12);
    // The one infeasible command breaks the yaw-rate limit (9 rad/s), and the curvature limit
    // when the robot has one.
    let v = m.executed_violations;
    assert_eq!((v.commands, v.yaw_rate), (4, 1));
    assert_eq!(v.speed + v.reverse + v.acceleration + v.lateral, 0);
    assert_eq!(v.curvature, usize::from(l.kappa_max.is_some()));
    assert_eq!(m.fallbacks, 1);
    assert_eq!(m.plans, 2);
    assert!(m.min_clearance.is_none());
}

#[test]
fn clearance_times_and_path_length() {
    let l = robot("go2").limits;
    let states: Vec<RobotState> = (0..5)
        .map(|k| RobotState {
            pose: Pose2::new(0.3 * k as f64, 0.4 * k as f64, 0.0),
            velocity: Twist2::ZERO,
        })
        .collect();
    // Clearances per instant; the last (terminal) instant is not counted as time.
    let clearance = vec![2.0, 1.0, 0.3, 0.5, 0.1];
    let run = run_with(states, vec![Twist2::ZERO; 4], clearance, vec![]);
    let m = EpisodeMetrics::compute(&run, &l);
    assert_relative_eq!(m.path_length, 2.0, epsilon = 1e-12);
    assert_relative_eq!(m.time_within_intimate, 0.05, epsilon = 1e-12);
    assert_relative_eq!(m.time_within_personal, 0.15, epsilon = 1e-12);
    assert_relative_eq!(m.min_clearance.unwrap(), 0.1);
    assert_relative_eq!(m.time_to_goal.unwrap(), 0.2, epsilon = 1e-12);
}

#[test]
fn the_robot_is_compared_with_the_recorded_human_at_equal_times() {
    let l = robot("go2").limits;
    // The human walks 1 m/s along x for 2 s (positions every 0.1 s).
    let mut ep = episode("human", ScenarioClass::CoFlow, 0.0, vec![]);
    ep.dt = 0.1;
    ep.human_path = (0..=20).map(|k| [0.1 * k as f64, 0.0]).collect();
    let states = |positions: &[[f64; 2]]| -> Vec<RobotState> {
        positions
            .iter()
            .map(|p| RobotState {
                pose: Pose2::new(p[0], p[1], 0.0),
                velocity: Twist2::ZERO,
            })
            .collect()
    };
    let compare = |positions: Vec<[f64; 2]>| {
        let n = positions.len();
        let run = run_with(
            states(&positions),
            vec![Twist2::ZERO; n - 1],
            vec![],
            vec![],
        );
        EpisodeMetrics::compute(&run, &l)
            .against_human(&run, &ep)
            .human
            .expect("the episode has a human")
    };
    // Walking with them every 0.05 s: no distance, the same length.
    let same = compare((0..=40).map(|k| [0.05 * k as f64, 0.0]).collect());
    assert_relative_eq!(same.distance, 0.0, epsilon = 1e-12);
    assert_relative_eq!(same.length_ratio, 1.0, epsilon = 1e-12);
    // Half a metre to the side and twice as fast: at the end after 1 s, then held there while
    // the human catches up at 2 s. The mean of hypot(0.5, how far ahead) over the 41 instants.
    let fast: Vec<[f64; 2]> = (0..=20).map(|k| [(0.1 * k as f64).min(2.0), 0.5]).collect();
    let ahead = |t: f64| (2.0 * t).min(2.0) - t;
    let expected = (0..=40)
        .map(|n| {
            let t = 0.05 * n as f64;
            ahead(t).hypot(0.5)
        })
        .sum::<f64>()
        / 41.0;
    let fast = compare(fast);
    assert_relative_eq!(fast.distance, expected, epsilon = 1e-9);
    assert_relative_eq!(fast.length_ratio, 1.0, epsilon = 1e-12);
    // No recorded human: nothing to compare.
    ep.human_path.clear();
    let run = run_with(
        states(&[[0.0, 0.0], [0.1, 0.0]]),
        vec![Twist2::ZERO],
        vec![],
        vec![],
    );
    assert!(
        EpisodeMetrics::compute(&run, &l)
            .against_human(&run, &ep)
            .human
            .is_none()
    );
}

fn small_suite() -> Suite {
    let mut episodes = Vec::new();
    for (i, c) in ScenarioClass::ALL.into_iter().enumerate() {
        let agents = match c {
            ScenarioClass::CoFlow => vec![walking(1, [1.0, 0.5], [0.8, 0.0], 100)],
            ScenarioClass::CrossFlow => vec![walking(1, [2.5, -3.0], [0.0, 1.0], 100)],
            ScenarioClass::CounterFlow => vec![
                walking(1, [6.0, 0.0], [-1.0, 0.0], 100),
                standing(2, [3.0, 2.0], 100),
            ],
            ScenarioClass::MultidirectionFlow => {
                vec![
                    walking(1, [4.0, 3.0], [0.0, -1.0], 100),
                    walking(2, [0.0, 3.0], [1.0, -1.0], 100),
                ]
            }
        };
        episodes.push(episode(&format!("e{i}"), c, 0.0, agents));
    }
    Suite::new("hand", SuiteKind::Synthetic, episodes)
}

fn empty_suite() -> Suite {
    let mut s = small_suite();
    for e in &mut s.episodes {
        e.agents.clear();
        e.density = 0;
    }
    Suite::new("empty", SuiteKind::Empty, s.episodes)
}

#[test]
fn bench_is_deterministic_and_ordered() {
    let suites = [small_suite(), empty_suite()];
    let robots = robots();
    let methods = [MethodSpec::straight("straight", &toml::Table::new()).unwrap()];
    let sim = SimConfig::default();
    let a = run_bench(&suites, &robots, &methods, &sim, 7, &ProgressBar::hidden()).unwrap();
    let b = run_bench(&suites, &robots, &methods, &sim, 7, &ProgressBar::hidden()).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.len(), 2 * 3 * 4);
    // Job order: suite, robot, method, episode.
    assert_eq!(a[0].suite, "hand");
    assert_eq!(a[0].robot, "diablo");
    assert_eq!(a[3].scenario, ScenarioClass::MultidirectionFlow);
    assert_eq!(a[4].robot, "go2");
    // Empty world: the straight planner always succeeds.
    assert!(
        a.iter()
            .filter(|r| r.suite == "empty")
            .all(|r| r.metrics.success)
    );
    // Seeds depend on suite, episode and robot only.
    assert_eq!(a[0].seed, episode_seed(7, "hand", "e0", "diablo"));
    assert_ne!(
        episode_seed(7, "hand", "e0", "diablo"),
        episode_seed(7, "hand", "e0", "go2")
    );
    assert_ne!(
        episode_seed(7, "hand", "e0", "diablo"),
        episode_seed(8, "hand", "e0", "diablo")
    );

    let csv = results_csv(&a);
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines[0], CSV_HEADER);
    assert_eq!(lines.len(), a.len() + 1);
    let columns = CSV_HEADER.split(',').count();
    assert!(lines.iter().all(|l| l.split(',').count() == columns));
}

#[test]
fn a_method_can_replan_at_its_own_rate() {
    let suites = [empty_suite()];
    let robots = robots();
    let plain = MethodSpec::straight("every_2nd", &toml::Table::new()).unwrap();
    let own = MethodSpec::straight("every_4th", &toml::Table::new())
        .unwrap()
        .with_replan_hz(Some(5.0));
    let sim = SimConfig::default();
    let rows = run_bench(
        &suites,
        &robots,
        &[plain, own],
        &sim,
        7,
        &ProgressBar::hidden(),
    )
    .unwrap();
    let of = |m: &str| -> Vec<&ResultRow> { rows.iter().filter(|r| r.method == m).collect() };
    for (a, b) in of("every_2nd").into_iter().zip(of("every_4th")) {
        assert!(a.metrics.success && b.metrics.success);
        // The planner is called at steps 0, k, 2k, ... before the step that reaches the goal.
        let calls = |r: &ResultRow, k: usize| {
            let steps = (r.metrics.duration / sim.dt).round() as usize;
            steps.div_ceil(k)
        };
        assert_eq!(a.metrics.plans, calls(a, 2), "{a:?}");
        assert_eq!(b.metrics.plans, calls(b, 4), "{b:?}");
    }
    // A rate that is not a whole number of steps fails before any episode runs.
    let bad = MethodSpec::straight("every_3rd", &toml::Table::new())
        .unwrap()
        .with_replan_hz(Some(7.0));
    let err = run_bench(&suites, &robots, &[bad], &sim, 7, &ProgressBar::hidden()).unwrap_err();
    assert!(err.to_string().contains("replan_hz"), "{err}");
}

#[test]
fn driver_writes_csv_report_and_figures() {
    // The empty suite leaves a third method out: it is neither run there nor judged.
    let mut empty = empty_suite();
    empty.methods = Some(vec!["straight".into(), "slow".into()]);
    let suites = [small_suite(), empty];
    let robots = [robot("diablo"), robot("ackermann")];
    let methods = [
        MethodSpec::straight("straight", &toml::Table::new()).unwrap(),
        MethodSpec::straight("slow", &toml::toml! { speed = 0.5 })
            .unwrap()
            .with_replan_hz(Some(5.0)),
        MethodSpec::straight("crawl", &toml::toml! { speed = 0.05 }).unwrap(),
    ];
    let sim = SimConfig::default();
    let plan = BenchPlan {
        suites: &suites,
        robots: &robots,
        methods: &methods,
        sim: &sim,
        seed: 3,
        quick: true,
        snapshot_method: Some("slow"),
        command: "test".into(),
        threads: Some(2),
        failures: 2,
        record: None,
    };
    // HUMAN2NAV_FIGURE_DIR keeps the outputs there for inspection.
    let keep = std::env::var_os("HUMAN2NAV_FIGURE_DIR")
        .map(|d| std::path::PathBuf::from(d).join("driver"));
    let out = keep.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("h2n-sim-driver-{}", std::process::id()))
    });
    let res = driver::run(&plan, &out, &ProgressBar::hidden()).unwrap();
    assert_eq!(res.rows.len(), 2 * 2 * 2 * 4 + 2 * 4);
    assert!(
        !res.rows
            .iter()
            .any(|r| r.suite == "empty" && r.method == "crawl")
    );
    assert!(
        res.empty_world_failures.is_empty(),
        "{:?}",
        res.empty_world_failures
    );
    let report = std::fs::read_to_string(&res.report_md).unwrap();
    let sanity = &report[report.find("Empty-world sanity").unwrap()..];
    assert!(!sanity[..sanity.find("\n## ").unwrap_or(sanity.len())].contains("| crawl |"));
    for needle in [
        "Fig. 6",
        "Fig. 7",
        "Empty-world sanity",
        "| straight | 100.0",
        "pass",
        "How the runs failed, per robot",
        "Executed commands outside each limit",
        "| replanning rate | 10 Hz (every 2 steps); slow: 5 Hz (every 4 steps) |",
    ] {
        assert!(
            report.contains(needle),
            "report lacks `{needle}`:\n{report}"
        );
    }
    // Every failure is classified, per robot and method.
    let hand: Vec<_> = res.rows.iter().filter(|r| r.suite == "hand").collect();
    check_collision_classes(&report, &hand);
    let slow_successes = check_figure_list(&res, &report, &hand);
    for needle in [
        "Paired comparison with `straight`",
        "Suite composition",
        "against crowd density",
    ] {
        assert!(report.contains(needle), "report lacks `{needle}`");
    }
    check_pngs(&res, &slow_successes);
    let csv = std::fs::read_to_string(&res.results_csv).unwrap();
    assert_eq!(csv.lines().count(), res.rows.len() + 1);
    if keep.is_none() {
        std::fs::remove_dir_all(&out).unwrap();
    }
}

/// Every failure of the `hand` suite is classified: for each robot and method, the report's
/// eight failure classes add up to its failed runs, the five collision classes to its
/// collisions, and every collision with a pedestrian has its contact recorded.
fn check_collision_classes(report: &str, hand: &[&ResultRow]) {
    let section = &report[report
        .find("How the runs failed, per robot")
        .expect("report has a failures section")..];
    let mut robots: Vec<&str> = hand.iter().map(|r| r.robot.as_str()).collect();
    robots.dedup();
    let mut failures_seen = 0;
    for robot in robots {
        for m in ["straight", "slow"] {
            let runs: Vec<_> = hand
                .iter()
                .filter(|r| r.robot == robot && r.method == m)
                .collect();
            let collisions = runs.iter().filter(|r| r.metrics.collision).count();
            let failed = runs.iter().filter(|r| !r.metrics.success).count();
            failures_seen += failed;
            assert!(
                runs.iter()
                    .filter(|r| r.metrics.collision && r.metrics.obstacle_hit.is_none())
                    .all(|r| r.metrics.contact.is_some())
            );
            let head = format!("| {robot} | {m} | {} | {failed} |", runs.len());
            let line = section
                .lines()
                .find(|l| l.starts_with(&head))
                .unwrap_or_else(|| panic!("no row `{head}`:\n{report}"));
            let counts: Vec<usize> = line
                .split('|')
                .skip(5)
                .take(8)
                .map(|c| c.trim().parse::<usize>().unwrap_or(usize::MAX))
                .collect();
            assert_eq!(counts[..5].iter().sum::<usize>(), collisions, "{line}");
            assert_eq!(counts.iter().sum::<usize>(), failed, "{line}");
        }
    }
    assert!(failures_seen > 0, "the hand suite has failures to classify");
}

/// The figures of the run and the report's references to them; returns the scenario classes
/// where `slow` succeeded on diablo (the Fig. 4 panels).
fn check_figure_list(res: &BenchOutcome, report: &str, hand: &[&ResultRow]) -> Vec<ScenarioClass> {
    // Fig. 6, 7 and the density figure of the one non-empty suite, Fig. 4 (`slow` succeeded
    // on diablo in some class), and one failure figure per method that failed somewhere in
    // the suite.
    let failing = ["straight", "slow", "crawl"]
        .iter()
        .filter(|m| hand.iter().any(|r| &r.method == *m && !r.metrics.success))
        .count();
    assert!(failing > 0, "the hand suite should make a method fail");
    let names: Vec<String> = res
        .figures
        .iter()
        .map(|f| {
            f.file_name()
                .expect("figure path has a file name")
                .to_string_lossy()
                .into_owned()
        })
        .collect();
    assert_eq!(res.figures.len(), 4 + failing, "{names:?}");
    for f in [
        "fig6_sr_per_scenario_hand.png",
        "fig7_tfs_sr_per_robot_hand.png",
        "fig_sr_density_hand.png",
        "fig4_snapshots_hand.png",
    ] {
        assert!(names.iter().any(|n| n == f), "{f} missing: {names:?}");
        assert!(report.contains(f), "report lacks {f}");
    }
    assert!(
        report.contains("failures_hand_straight_1.png")
            || report.contains("failures_hand_slow_1.png")
    );
    // Fig. 4 shows successful runs only: a class where `slow` failed on diablo is left out.
    let slow_successes: Vec<ScenarioClass> = hand
        .iter()
        .filter(|r| r.method == "slow" && r.robot == "diablo" && r.metrics.success)
        .map(|r| r.scenario)
        .collect();
    for c in ScenarioClass::ALL {
        let panel = format!("{} `", human2nav_sim::episode::ScenarioTitle::title(c));
        let fig4 = report
            .lines()
            .find(|l| l.starts_with("*Fig. 4"))
            .expect("report has a Fig. 4 caption");
        assert_eq!(fig4.contains(&panel), slow_successes.contains(&c), "{fig4}");
    }
    slow_successes
}

/// Every figure is a PNG of the expected size: Fig. 4 with one 800 px panel per class where
/// `slow` succeeded (two per row, a legend strip below), a failure figure with one or two.
fn check_pngs(res: &BenchOutcome, slow_successes: &[ScenarioClass]) {
    for f in &res.figures {
        let bytes = std::fs::read(f).expect("figure is readable");
        assert!(
            bytes.len() > 1000 && bytes.starts_with(b"\x89PNG"),
            "{} is not a PNG",
            f.display()
        );
        // Panels of 800 px, two per row, and a legend strip below them: a failure figure has
        // two panels (failures: 2) or one.
        let size = |at: usize| {
            u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
        };
        let name = f
            .file_name()
            .expect("figure path has a file name")
            .to_string_lossy();
        if name.starts_with("fig4") {
            let panels = slow_successes
                .iter()
                .collect::<std::collections::HashSet<_>>()
                .len();
            assert_eq!(size(16), if panels > 1 { 1600 } else { 800 }, "{name}");
            let rows = panels.div_ceil(2) as u32;
            assert!(
                (800 * rows + 40..800 * rows + 200).contains(&size(20)),
                "{name}"
            );
        } else if name.starts_with("failures_") {
            assert!(size(16) == 800 || size(16) == 1600, "{name}");
            assert!((840..1000).contains(&size(20)), "{name}");
        }
    }
}

#[test]
fn data_scaling_points_and_figure() {
    use human2nav_sim::figures::{scaling_points, sr_vs_training_data};
    use human2nav_sim::report::summarize;
    let suites = [small_suite()];
    let robots = [robot("go2")];
    let sim = SimConfig::default();
    // Three "trainings" (on 0.4, 2 and 4 hours of data) stand in as three speeds of the
    // straight baseline.
    let runs: Vec<(f64, Vec<_>)> = [(0.4, 0.3), (2.0, 0.8), (4.0, 1.5)]
        .into_iter()
        .map(|(hours, speed)| {
            let table: toml::Table = toml::from_str(&format!("speed = {speed}")).unwrap();
            let methods = [MethodSpec::straight("m", &table).unwrap()];
            let rows =
                run_bench(&suites, &robots, &methods, &sim, 1, &ProgressBar::hidden()).unwrap();
            (hours, rows)
        })
        .collect();
    let points = scaling_points(&runs, "hand", "m");
    assert_eq!(points.len(), 3 * 5);
    for p in &points {
        let rows = &runs.iter().find(|(h, _)| *h == p.hours).unwrap().1;
        let s = summarize(
            rows.iter()
                .filter(|r| p.scenario.is_none_or(|c| r.scenario == c)),
        );
        assert_relative_eq!(p.sr, s.sr);
        assert_relative_eq!(p.sr_se, s.sr_se);
    }
    assert!(scaling_points(&runs, "hand", "other").is_empty());
    let keep = std::env::var_os("HUMAN2NAV_FIGURE_DIR").map(std::path::PathBuf::from);
    let out = match &keep {
        Some(d) => d.join("fig5_sr_vs_training_data.png"),
        None => std::env::temp_dir().join(format!("h2n-fig5-{}.png", std::process::id())),
    };
    sr_vs_training_data(&out, &points, "SR vs training data").unwrap();
    assert!(std::fs::read(&out).unwrap().starts_with(b"\x89PNG"));
    if keep.is_none() {
        std::fs::remove_file(&out).unwrap();
    }
}
