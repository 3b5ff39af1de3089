//! The report's tables of one suite: SR per scenario and per robot, TFS per robot, the other
//! metrics, SR against crowd density, and what each suite holds.

use super::{cell_sr, f2, opt2, pct, summarize};
use crate::bench::ResultRow;
use crate::episode::{ScenarioClass, ScenarioTitle};
use crate::stats::{self, DENSITY_BINS, SuiteComposition};
use std::fmt::Write as _;

/// SR per scenario class and method over all robots (Fig. 6).
pub(super) fn sr_per_scenario_table(md: &mut String, in_suite: &[&ResultRow], methods: &[String]) {
    let _ = writeln!(
        md,
        "### Success rate (%) per scenario and method, all robots (Fig. 6)\n"
    );
    let _ = write!(md, "| method |");
    for c in ScenarioClass::ALL {
        let _ = write!(md, " {} |", c.title());
    }
    let _ = writeln!(md, " all |\n|---|---|---|---|---|---|");
    for m in methods {
        let _ = write!(md, "| {m} |");
        for c in ScenarioClass::ALL {
            let s = summarize(
                in_suite
                    .iter()
                    .copied()
                    .filter(|r| &r.method == m && r.scenario == c),
            );
            let _ = write!(md, " {} |", cell_sr(&s));
        }
        let s = summarize(in_suite.iter().copied().filter(|r| &r.method == m));
        let _ = writeln!(md, " {} |", cell_sr(&s));
    }
}

/// SR per robot, scenario class and method.
pub(super) fn sr_per_robot_table(
    md: &mut String,
    in_suite: &[&ResultRow],
    robot_names: &[String],
    methods: &[String],
) {
    let _ = writeln!(
        md,
        "\n### Success rate (%) per robot, scenario and method\n"
    );
    let _ = write!(md, "| robot | method |");
    for c in ScenarioClass::ALL {
        let _ = write!(md, " {} |", c.title());
    }
    let _ = writeln!(md, "\n|---|---|---|---|---|---|");
    for robot in robot_names {
        for m in methods {
            let _ = write!(md, "| {robot} | {m} |");
            for c in ScenarioClass::ALL {
                let s = summarize(
                    in_suite
                        .iter()
                        .copied()
                        .filter(|r| &r.robot == robot && &r.method == m && r.scenario == c),
                );
                let _ = write!(md, " {} |", cell_sr(&s));
            }
            let _ = writeln!(md);
        }
    }
}

/// TFS (overall, plan, executed), SR and failed planner calls per robot and method (Fig. 7).
pub(super) fn tfs_table(
    md: &mut String,
    in_suite: &[&ResultRow],
    robot_names: &[String],
    methods: &[String],
) {
    let _ = writeln!(md, "\n### TFS and SR per robot and method (Fig. 7)\n");
    let _ = writeln!(
        md,
        "| robot | method | n | TFS | TFS plan | TFS executed | SR (%) | failed planner calls |\n\
         |---|---|---|---|---|---|---|---|"
    );
    for robot in robot_names {
        for m in methods {
            let s = summarize(
                in_suite
                    .iter()
                    .copied()
                    .filter(|r| &r.robot == robot && &r.method == m),
            );
            if s.n == 0 {
                let _ = writeln!(md, "| {robot} | {m} | 0 | – | – | – | – | – |");
                continue;
            }
            let failed = if s.failed_calls == 0 {
                "0".to_owned()
            } else {
                format!("**{} of {}**", s.failed_calls, s.planner_calls)
            };
            let _ = writeln!(
                md,
                "| {robot} | {m} | {} | {:.3} | {:.3} | {:.3} | {} | {failed} |",
                s.n,
                s.tfs,
                s.tfs_plan,
                s.tfs_executed,
                pct(s.sr)
            );
        }
    }
}

/// Collision and timeout rates, path, time, clearance, proxemics, jerk and fallback plans per
/// method over all robots.
pub(super) fn other_metrics_table(md: &mut String, in_suite: &[&ResultRow], methods: &[String]) {
    let _ = writeln!(
        md,
        "\n### Other metrics per method, all robots (means over episodes)\n"
    );
    let _ = writeln!(
        md,
        "| method | n | collision (%) | timeout (%) | path length (m) | time to goal (s) | \
         min clearance (m) | time < 0.45 m (s) | time < 1.2 m (s) | mean jerk (m/s³) | fallback plans (%) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|"
    );
    for m in methods {
        let s = summarize(in_suite.iter().copied().filter(|r| &r.method == m));
        if s.n == 0 {
            let _ = writeln!(md, "| {m} | 0 |{}", " – |".repeat(10));
            continue;
        }
        let _ = writeln!(
            md,
            "| {m} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            s.n,
            pct(s.collision_rate),
            pct(s.timeout_rate),
            f2(s.path_length),
            opt2(s.time_to_goal),
            opt2(s.min_clearance),
            f2(s.time_within_intimate),
            f2(s.time_within_personal),
            f2(s.mean_jerk),
            pct(s.fallback_rate)
        );
    }
}

/// SR per crowd-density bin (rows) and method (columns), all robots and scenarios.
pub(super) fn density_section(md: &mut String, rows: &[&ResultRow], methods: &[String]) {
    let bins = stats::occupied_bins(rows.iter().map(|r| r.density));
    if bins.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "\n### Success rate (%) against crowd density, all robots and scenarios\n\n\
         Density is the episode's `density`: its number of relevant pedestrians as the suite \
         counts them (for the paper protocol's episodes, the pedestrians that come within 3 m \
         of the recorded pedestrian the robot replaces; for the interaction-rich ones, within \
         3 m of the straight-driving reference robot). Cells: SR ± 1 standard error \
         (n = runs).\n"
    );
    let _ = write!(md, "| density |");
    for m in methods {
        let _ = write!(md, " {m} |");
    }
    let _ = writeln!(md, "\n|---|{}", "---|".repeat(methods.len()));
    for b in bins {
        let _ = write!(md, "| {} |", DENSITY_BINS[b].label());
        for m in methods {
            let s = summarize(
                rows.iter()
                    .copied()
                    .filter(|r| &r.method == m && DENSITY_BINS[b].contains(r.density)),
            );
            let _ = write!(md, " {} |", cell_sr(&s));
        }
        let _ = writeln!(md);
    }
}

/// Per suite: episodes per class, their density histogram and goal distances.
pub(super) fn composition_section(md: &mut String, composition: &[SuiteComposition]) {
    if composition.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "## Suite composition\n\n\
         Episodes per scenario class, how many fall in each crowd-density bin (relevant \
         pedestrians, see the density tables) and the straight-line start-to-goal distance.\n"
    );
    for s in composition {
        let bins: Vec<usize> = (0..DENSITY_BINS.len())
            .filter(|&b| s.classes.iter().any(|c| c.density_histogram[b] > 0))
            .collect();
        let _ = writeln!(md, "`{}`:\n", s.suite);
        let _ = write!(md, "| scenario | episodes |");
        for &b in &bins {
            let _ = write!(md, " density {} |", DENSITY_BINS[b].label());
        }
        let _ = writeln!(
            md,
            " goal distance min / median / max (m) |\n|---|---|{}---|",
            "---|".repeat(bins.len())
        );
        for c in &s.classes {
            let name = c.class.map_or("all", |c| c.title());
            let _ = write!(md, "| {name} | {} |", c.episodes);
            for &b in &bins {
                let _ = write!(md, " {} |", c.density_histogram[b]);
            }
            let goal = c.goal_distance.map_or("–".to_string(), |(lo, m, hi)| {
                format!("{lo:.2} / {m:.2} / {hi:.2}")
            });
            let _ = writeln!(md, " {goal} |");
        }
        let _ = writeln!(md);
    }
}
