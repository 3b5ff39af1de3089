//! The report's paired comparisons, density and composition tables on synthetic result rows
//! (no simulation). Set `HUMAN2NAV_FIGURE_DIR` to keep the report in that directory for
//! inspection.

use human2nav_core::Pose2;
use human2nav_sim::bench::{ResultRow, SuiteKind};
use human2nav_sim::episode::{Episode, ScenarioClass};
use human2nav_sim::metrics::{EpisodeMetrics, LimitCounts};
use human2nav_sim::report::{ReportContext, report_markdown};
use human2nav_sim::stats::{SuiteComposition, success_pairs};
use human2nav_sim::{Contact, Outcome};
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
        }),
        executed_violations: LimitCounts {
            commands: 160,
            speed: 2,
            ..LimitCounts::default()
        },
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
        "| sarl | all | 0 | – |",
    ] {
        assert!(md.contains(needle), "report lacks `{needle}`:\n{md}");
    }
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

    let (dir, keep) = out_dir("report");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("report.md"), &md).unwrap();
    if !keep {
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
