//! The report's paired comparisons, density and composition tables, and the per-suite figures,
//! on synthetic result rows (no simulation); a trajectory snapshot in a crowd. Set
//! `HUMAN2NAV_FIGURE_DIR` to keep the PNGs and the report in that directory for inspection.

mod common;

use human2nav_core::Pose2;
use human2nav_core::bev::BevSpec;
use human2nav_sim::bench::{ResultRow, SuiteKind};
use human2nav_sim::episode::AgentTrack;
use human2nav_sim::episode::{Episode, ScenarioClass};
use human2nav_sim::figures::{self, sr_interval, tfs_interval};
use human2nav_sim::figures::{Snapshot, pedestrians_at};
use human2nav_sim::metrics::{EpisodeMetrics, HumanComparison, LimitCounts};
use human2nav_sim::report::{ReportContext, report_markdown};
use human2nav_sim::stats::{SuiteComposition, success_pairs};
use human2nav_sim::straight::{StraightConfig, StraightPlanner};
use human2nav_sim::{Contact, Outcome, SimConfig, run_episode};
use std::path::PathBuf;

const METHODS: [&str; 5] = ["human2nav", "human2nav-noguide", "orca", "sarl", "straight"];
const ROBOTS: [&str; 3] = ["diablo", "go2", "ackermann"];

/// A stable pseudo-random number in [0, 1) from a key.
fn unit(key: &str) -> f64 {
    let h = key.bytes().fold(0xCBF2_9CE4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
    });
    let mut z = h.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

fn metrics(outcome: Outcome, tfs: f64) -> EpisodeMetrics {
    EpisodeMetrics {
        outcome,
        success: outcome == Outcome::Success,
        collision: outcome == Outcome::Collision,
        timeout: outcome == Outcome::Timeout,
        tfs,
        tfs_plan: tfs,
        tfs_executed: 1.0,
        path_length: 5.5,
        time_to_goal: (outcome == Outcome::Success).then_some(8.0),
        duration: 8.0,
        budget: 12.5,
        min_clearance: Some(0.4),
        time_within_intimate: 0.1,
        time_within_personal: 1.5,
        mean_jerk: 2.0,
        plans: 40,
        fallbacks: 1,
        planner_errors: 0,
        contact: (outcome == Outcome::Collision).then_some(Contact {
            pedestrian: 1,
            robot_closing: 0.5,
            pedestrian_closing: 0.8,
            pedestrian_age: 3.0,
            pedestrian_speed: 0.8,
        }),
        obstacle_hit: None,
        executed_violations: LimitCounts {
            commands: 160,
            speed: 2,
            ..LimitCounts::default()
        },
        end_goal_distance: if outcome == Outcome::Success {
            0.2
        } else {
            3.0
        },
        end_goal_crowd: Some(1.0),
        human: None,
    }
}

fn episode(id: String, scenario: ScenarioClass, density: usize, distance: f64) -> Episode {
    Episode {
        id,
        scene: "synthetic".into(),
        source: "synthetic".into(),
        scenario,
        dt: 0.1,
        start: Pose2::new(0.0, 0.0, 0.0),
        goal: [distance, 0.0],
        time_budget: 12.5,
        agents: Vec::new(),
        density,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    }
}

/// A suite of 4 classes × `per_class` episodes, densities spread over 1..=45.
fn episodes(suite: &str, per_class: usize) -> Vec<Episode> {
    let mut out = Vec::new();
    for c in ScenarioClass::ALL {
        for k in 0..per_class {
            let id = format!("{suite}/{}/{k}", c.name());
            let density = 1 + (45.0 * unit(&format!("{id}/density")).powi(2)) as usize;
            let distance = 5.0 + unit(&format!("{id}/d"));
            out.push(episode(id, c, density, distance));
        }
    }
    out
}

/// Rows of `methods` on `eps`: the success probability falls with density, by method.
fn rows(suite: &str, kind: SuiteKind, eps: &[Episode], methods: &[&str]) -> Vec<ResultRow> {
    let mut out = Vec::new();
    for robot in ROBOTS {
        for (mi, method) in methods.iter().enumerate() {
            for e in eps {
                let skill = [0.97, 0.9, 0.8, 0.6, 0.5][mi % 5];
                let p = skill * (1.0 - e.density as f64 / 70.0);
                let key = format!("{}/{robot}", e.id);
                let u = unit(&key) * 0.7 + unit(&format!("{key}/{method}")) * 0.3;
                let outcome = if u < p {
                    Outcome::Success
                } else if mi % 2 == 0 {
                    Outcome::Collision
                } else {
                    Outcome::Timeout
                };
                let tfs = (1.0 - 0.15 * mi as f64 * unit(&format!("{key}/{method}/tfs"))).max(0.0);
                out.push(ResultRow {
                    suite: suite.into(),
                    suite_kind: kind,
                    scenario: e.scenario,
                    episode: e.id.clone(),
                    scene: e.scene.clone(),
                    robot: robot.into(),
                    method: method.to_string(),
                    seed: 0,
                    agents: e.density,
                    density: e.density,
                    metrics: metrics(outcome, tfs),
                });
            }
        }
    }
    out
}

fn out_dir(name: &str) -> (PathBuf, bool) {
    match std::env::var_os("HUMAN2NAV_FIGURE_DIR") {
        Some(d) => (PathBuf::from(d), true),
        None => (
            std::env::temp_dir().join(format!("h2n-{name}-{}", std::process::id())),
            false,
        ),
    }
}

fn png_size(path: &std::path::Path) -> (u32, u32) {
    let b = std::fs::read(path).expect("the PNG is readable");
    assert!(b.starts_with(b"\x89PNG"), "{} is not a PNG", path.display());
    let at = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    (at(16), at(20))
}

#[test]
fn report_has_paired_density_and_composition_tables() {
    let interaction = episodes("interaction", 50);
    let real = episodes("real", 8);
    let empty: Vec<Episode> = episodes("empty", 2)
        .into_iter()
        .map(|mut e| {
            e.density = 0;
            e
        })
        .collect();
    let mut all = rows("interaction", SuiteKind::Synthetic, &interaction, &METHODS);
    // `sarl` did not run on `real`.
    all.extend(rows(
        "real",
        SuiteKind::Real,
        &real,
        &["human2nav", "human2nav-noguide", "orca", "straight"],
    ));
    all.extend(rows("empty", SuiteKind::Empty, &empty, &METHODS));
    let methods: Vec<String> = METHODS.iter().map(|m| m.to_string()).collect();
    let ctx = ReportContext {
        command: "synthetic".into(),
        methods: methods.clone(),
        robot_names: ROBOTS.iter().map(|r| r.to_string()).collect(),
        suites: vec![
            (
                "interaction".into(),
                SuiteKind::Synthetic,
                interaction.len(),
                None,
            ),
            ("real".into(), SuiteKind::Real, real.len(), None),
            ("empty".into(), SuiteKind::Empty, empty.len(), None),
        ],
        composition: vec![
            SuiteComposition::of("interaction", &interaction),
            SuiteComposition::of("real", &real),
            SuiteComposition::of("empty", &empty),
        ],
        ..ReportContext::default()
    };
    assert_eq!(ctx.reference(), Some("human2nav"));
    let md = report_markdown(&all, &ctx);
    for needle in [
        "## Suite composition",
        "| density 0 |",
        "goal distance min / median / max (m)",
        "### Paired comparison with `human2nav` (exact McNemar test, 95 % bootstrap interval)",
        "A pair is one (episode, robot)",
        "### Success rate (%) against crowd density",
        "| 41+ |",
    ] {
        assert!(md.contains(needle), "report lacks `{needle}`:\n{md}");
    }
    // `sarl` did not run `real`: that suite's tables leave it out; `interaction` lists it.
    let section = |name: &str| {
        let from = md.find(&format!("## Suite `{name}`")).unwrap();
        let rest = &md[from + 1..];
        &md[from..from + 1 + rest.find("\n## ").unwrap_or(rest.len())]
    };
    assert!(!section("real").contains("| sarl |"), "{}", section("real"));
    assert!(section("interaction").contains("| sarl | all |"));
    // The pooled `orca` row of `interaction` agrees with the pairs computed directly.
    let in_suite: Vec<&ResultRow> = all.iter().filter(|r| r.suite == "interaction").collect();
    let pairs = success_pairs(in_suite.iter().copied(), "human2nav", "orca");
    assert_eq!(pairs.len(), 600);
    let b = pairs.iter().filter(|p| p.0 && !p.1).count();
    let c = pairs.iter().filter(|p| !p.0 && p.1).count();
    let section = &md[md.find("## Suite `interaction`").unwrap()..];
    let line = section
        .lines()
        .find(|l| l.starts_with("| orca | all | 600 |"))
        .unwrap_or_else(|| panic!("no pooled orca row:\n{section}"));
    let cells: Vec<&str> = line.split('|').map(str::trim).collect();
    assert_eq!(cells[7].parse::<usize>().unwrap(), b, "{line}");
    assert_eq!(cells[8].parse::<usize>().unwrap(), c, "{line}");
    // The report is deterministic.
    assert_eq!(md, report_markdown(&all, &ctx));
    // Another reference, and one that did not run (falls back to `human2nav`).
    let orca = ReportContext {
        reference_method: Some("orca".into()),
        ..ctx.clone()
    };
    assert!(report_markdown(&all, &orca).contains("### Paired comparison with `orca`"));
    let absent = ReportContext {
        reference_method: Some("nope".into()),
        ..ctx.clone()
    };
    assert_eq!(absent.reference(), Some("human2nav"));
    let baselines = ReportContext {
        methods: vec!["orca".into(), "straight".into()],
        ..ctx.clone()
    };
    assert_eq!(baselines.reference(), Some("orca"));

    let (dir, keep) = out_dir("report-figures");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("report.md"), &md).unwrap();
    for suite in ["interaction", "real"] {
        let f6 = dir.join(format!("fig6_sr_per_scenario_{suite}.png"));
        figures::sr_per_scenario(&f6, &all, suite, &methods).unwrap();
        let f7 = dir.join(format!("fig7_tfs_sr_per_robot_{suite}.png"));
        figures::tfs_sr_per_robot(&f7, &all, suite, &ctx.robot_names, &methods).unwrap();
        let fd = dir.join(format!("fig_sr_density_{suite}.png"));
        figures::sr_per_density(&fd, &all, suite, &methods).unwrap();
        assert_eq!(png_size(&f6), (1400, 820));
        assert_eq!(png_size(&f7), (2000, 820));
        assert_eq!(png_size(&fd), (1400, 820));
    }
    if !keep {
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[test]
fn the_how_human_table_compares_methods_on_the_runs_all_succeeded_on() {
    let real = episodes("real", 2);
    let methods = ["human2nav", "orca"];
    let mut all = rows("real", SuiteKind::Real, &real, &methods);
    let ctx = ReportContext {
        command: "synthetic".into(),
        methods: methods.iter().map(|m| m.to_string()).collect(),
        robot_names: ROBOTS.iter().map(|r| r.to_string()).collect(),
        suites: vec![("real".into(), SuiteKind::Real, real.len(), None)],
        ..ReportContext::default()
    };
    // No recorded human in the rows: no table.
    let title = "### How human, per robot";
    assert!(!report_markdown(&all, &ctx).contains(title));
    // `human2nav` 0.5 m from the human and 1.1 times their length, `orca` 1.5 m and 1.3; a run
    // `orca` failed leaves the episode out for both.
    for r in &mut all {
        let (distance, length_ratio) = if r.method == "human2nav" {
            (0.5, 1.1)
        } else {
            (1.5, 1.3)
        };
        r.metrics.human = Some(HumanComparison {
            distance,
            length_ratio,
        });
    }
    let common = |robot: &str| {
        real.iter()
            .filter(|e| {
                methods.iter().all(|m| {
                    all.iter().any(|r| {
                        r.robot == robot && r.episode == e.id && &r.method == m && r.metrics.success
                    })
                })
            })
            .count()
    };
    let md = report_markdown(&all, &ctx);
    let section = &md[md.find(title).expect("the table")..];
    for robot in ROBOTS {
        let n = common(robot);
        assert!(n > 0 && n < real.len(), "{robot}: {n} common successes");
        for (method, cells) in [("human2nav", "0.50 | 1.10"), ("orca", "1.50 | 1.30")] {
            let row = format!("| {robot} | {method} | {n} | {cells} | 0.10 | 2.00 |");
            assert!(section.contains(&row), "no `{row}` in\n{section}");
        }
    }
}

#[test]
fn intervals_of_rows() {
    let eps = episodes("s", 5);
    let all = rows("s", SuiteKind::Synthetic, &eps, &["m"]);
    let iv = sr_interval(&all).unwrap();
    let k = all.iter().filter(|r| r.metrics.success).count();
    assert_eq!(iv.value, k as f64 / all.len() as f64);
    assert!(iv.lo <= iv.value && iv.value <= iv.hi && iv.hi <= 1.0);
    let t = tfs_interval(&all).unwrap();
    assert!(0.0 <= t.lo && t.lo <= t.value && t.value <= t.hi && t.hi <= 1.0);
    assert!(sr_interval(std::iter::empty()).is_none());
    assert!(tfs_interval(std::iter::empty()).is_none());
}

/// A crowd crossing, meeting and following the robot's straight line from (0, 0) to (5, 0).
fn crowd() -> Vec<AgentTrack> {
    let mut agents = Vec::new();
    for k in 0..14u64 {
        let f = k as f64;
        let (p0, v) = match k % 4 {
            0 => ([1.0 + 0.7 * f, -3.0 - 0.3 * f], [0.1, 1.1]),
            1 => ([7.0 + 0.4 * f, 1.5 - 0.25 * f], [-1.2, 0.0]),
            2 => ([-1.0 + 0.5 * f, 2.0], [0.9, -0.2]),
            _ => ([2.0 + 0.3 * f, 3.5], [0.0, 0.0]),
        };
        agents.push(AgentTrack {
            id: k,
            start_step: 0,
            positions: (0..200)
                .map(|s| [p0[0] + v[0] * 0.1 * s as f64, p0[1] + v[1] * 0.1 * s as f64])
                .collect(),
            radius: 0.3,
        });
    }
    agents
}

#[test]
fn snapshot_in_a_crowd() {
    let sim = SimConfig::default();
    let mut panels = Vec::new();
    for (i, name) in ["diablo", "ackermann"].into_iter().enumerate() {
        let robot = common::robot(name);
        let ep = common::episode(
            &format!("crowd/{i}"),
            ScenarioClass::CrossFlow,
            0.0,
            crowd(),
        );
        let mut planner = StraightPlanner::new(StraightConfig {
            speed: 0.6 + 0.4 * i as f64,
            ..StraightConfig::default()
        })
        .unwrap();
        let run = run_episode(&ep, &robot, &mut planner, &sim);
        panels.push(Snapshot {
            episode: ep,
            run,
            robot: robot.name.clone(),
            method: "straight".into(),
            footprint_radius: robot.footprint_radius,
            footprint: robot.footprint.clone(),
            bev: BevSpec::default(),
            sensor_range: sim.sensor_range,
            history_len: sim.history_len,
        });
    }
    // The pedestrians of a snapshot: every one present, with its recent history.
    let peds = pedestrians_at(&panels[0], 1.0);
    assert_eq!(peds.len(), 14);
    assert!(peds.iter().all(|a| a.history.len() == sim.history_len));
    let walker = &peds[1];
    assert!(
        (walker.position[0] - (7.4 - 1.2)).abs() < 1e-9,
        "{walker:?}"
    );
    assert!((walker.velocity[0] + 1.2).abs() < 1e-9, "{walker:?}");

    let (dir, keep) = out_dir("snapshot");
    std::fs::create_dir_all(&dir).unwrap();
    let png = dir.join("snapshot_crowd.png");
    figures::trajectory_snapshots(&png, &panels).unwrap();
    let (w, h) = png_size(&png);
    assert_eq!(w, 1600);
    assert!((840..1000).contains(&h), "{h}");
    if !keep {
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
