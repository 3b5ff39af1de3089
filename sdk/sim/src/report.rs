//! `results.csv` and `report.md`: one row per episode × method × robot, and the tables of the
//! paper's Fig. 6 (SR per scenario and method) and Fig. 7 (TFS and SR per robot and method),
//! what each suite holds, paired comparisons of every method with the reference method (exact
//! McNemar test, bootstrap interval of the SR difference), SR against crowd density, the other
//! metrics, how the collisions happened, and the empty-world sanity check.

mod csv_io;
mod failures;
mod paired;
mod summary;
mod tables;

pub use csv_io::{CSV_HEADER, parse_results_csv, results_csv, results_csv_exact};
pub use failures::{
    APPEARED_WITHIN, FAST_SPEED, Failure, GOAL_TAKEN_WITHIN, NEAR_GOAL, WALKED_INTO_BELOW,
};
pub use summary::{PlannerFailures, Summary, planner_failures, summarize};

use crate::bench::{ResultRow, SuiteKind};
use crate::stats::SuiteComposition;
use failures::{failure_table, violation_table};
use paired::paired_section;
use std::fmt::Write as _;
use summary::planner_failure_warning;
use tables::{
    composition_section, density_section, other_metrics_table, sr_per_robot_table,
    sr_per_scenario_table, tfs_table,
};

/// What the report says about the run besides the numbers.
#[derive(Clone, Debug, Default)]
pub struct ReportContext {
    /// The command line (or a description) that produced the report.
    pub command: String,
    /// The benchmark's master seed.
    pub seed: u64,
    /// Quick mode (a few episodes per class).
    pub quick: bool,
    /// Simulation settings, one `key = value` per line.
    pub sim: Vec<(String, String)>,
    /// One line per robot (name, embodiment, footprint, limits).
    pub robots: Vec<String>,
    /// Method names in order.
    pub methods: Vec<String>,
    /// Suites: (name, kind, episode count, optional note).
    pub suites: Vec<(String, SuiteKind, usize, Option<String>)>,
    /// Robot names in order.
    pub robot_names: Vec<String>,
    /// Figure files (relative to the report) with captions.
    pub figures: Vec<(String, String)>,
    /// Wall time of the run (s), if measured.
    pub wall_time: Option<f64>,
    /// `(method, runs, thread-seconds)`, if measured.
    pub method_times: Vec<(String, usize, f64)>,
    /// How many shards of `human2nav bench --shard` the rows were merged from (0 or 1: one
    /// run); the wall time is then their sum.
    pub shards: usize,
    /// The method every other is compared with in the paired tables (see
    /// [`ReportContext::reference`]); `None`: `human2nav` when it ran, else the first method.
    pub reference_method: Option<String>,
    /// What each suite holds (episodes per class, densities, goal distances), in suite order.
    pub composition: Vec<SuiteComposition>,
}

/// The reference method when [`ReportContext::reference_method`] names none that ran.
pub const DEFAULT_REFERENCE_METHOD: &str = "human2nav";

impl ReportContext {
    /// The reference method of the paired comparisons: [`ReportContext::reference_method`]
    /// when it is one of the methods, else [`DEFAULT_REFERENCE_METHOD`] when it is, else the
    /// first method (`None` without methods).
    pub fn reference(&self) -> Option<&str> {
        let ran = |name: &str| self.methods.iter().any(|m| m == name);
        self.reference_method
            .as_deref()
            .filter(|m| ran(m))
            .or_else(|| ran(DEFAULT_REFERENCE_METHOD).then_some(DEFAULT_REFERENCE_METHOD))
            .or_else(|| self.methods.first().map(String::as_str))
    }
}

/// A share as a percentage with one decimal.
pub(crate) fn pct(v: f64) -> String {
    format!("{:.1}", 100.0 * v)
}

fn f2(v: f64) -> String {
    format!("{v:.2}")
}

fn opt2(v: Option<f64>) -> String {
    v.map(f2).unwrap_or_else(|| "–".into())
}

/// The text of `report.md`: header and warnings, the setup, one section per suite with
/// pedestrians, the empty-world verdicts and the figures.
pub fn report_markdown(rows: &[ResultRow], ctx: &ReportContext) -> String {
    let mut md = String::new();
    report_header(&mut md, rows, ctx);
    setup_section(&mut md, ctx);
    for (suite, kind, _, _) in ctx.suites.iter().filter(|s| s.1 != SuiteKind::Empty) {
        let in_suite: Vec<&ResultRow> = rows.iter().filter(|r| &r.suite == suite).collect();
        suite_section(&mut md, &in_suite, suite, *kind, ctx);
    }
    for (suite, _, _, _) in ctx.suites.iter().filter(|s| s.1 == SuiteKind::Empty) {
        let in_suite: Vec<&ResultRow> = rows.iter().filter(|r| &r.suite == suite).collect();
        empty_suite_section(&mut md, &in_suite, suite, ctx);
    }
    if !ctx.figures.is_empty() {
        let _ = writeln!(md, "## Figures\n");
        for (file, caption) in &ctx.figures {
            let _ = writeln!(md, "![{caption}]({file})\n\n*{caption}*\n");
        }
    }
    md
}

/// The title, what produced the report, the suites' warnings, failed planner calls and the
/// wall time.
fn report_header(md: &mut String, rows: &[ResultRow], ctx: &ReportContext) {
    let _ = writeln!(md, "# Closed-loop crowd-navigation benchmark\n");
    let _ = writeln!(
        md,
        "Produced by `{}`{} with seed {}. One row per episode × method × robot is in \
         [`results.csv`](results.csv). SR = success rate (goal reached within the time budget \
         without collision); TFS = trajectory feasibility score, min(plan, executed).\n",
        ctx.command,
        if ctx.quick {
            " (quick mode: a few episodes per class)"
        } else {
            ""
        },
        ctx.seed
    );
    for (name, _, _, note) in &ctx.suites {
        if let Some(w) = note.as_deref().and_then(|n| n.strip_prefix("Warning:")) {
            let _ = writeln!(md, "> **Warning** (suite `{name}`):{w}\n");
        }
    }
    planner_failure_warning(md, rows);
    if let Some(w) = ctx.wall_time {
        let _ = write!(md, "Wall time: {w:.1} s for {} episode runs", rows.len());
        if ctx.shards > 1 {
            let _ = write!(md, ", summed over {} shards", ctx.shards);
        }
        let per: Vec<String> = ctx
            .method_times
            .iter()
            .filter(|(_, n, _)| *n > 0)
            .map(|(m, n, secs)| format!("{m} {:.2} s", secs / *n as f64))
            .collect();
        if !per.is_empty() {
            let _ = write!(md, " (thread time per run: {})", per.join(", "));
        }
        let _ = writeln!(md, ".\n");
    }
}

/// The simulation settings, the robots, the methods, the suites and their composition.
fn setup_section(md: &mut String, ctx: &ReportContext) {
    let _ = writeln!(md, "## Setup\n");
    let _ = writeln!(md, "| setting | value |\n|---|---|");
    for (k, v) in &ctx.sim {
        let _ = writeln!(md, "| {k} | {v} |");
    }
    let _ = writeln!(md, "\nRobots:\n");
    for r in &ctx.robots {
        let _ = writeln!(md, "- {r}");
    }
    let _ = writeln!(md, "\nMethods: {}.\n\nSuites:\n", ctx.methods.join(", "));
    for (name, kind, n, note) in &ctx.suites {
        let _ = write!(md, "- `{name}` ({}): {n} episodes", kind.as_str());
        if let Some(note) = note {
            let _ = write!(md, ". {note}");
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md);
    composition_section(md, &ctx.composition);
}

/// One suite with pedestrians: SR per scenario (Fig. 6) and per robot, TFS and SR per robot
/// (Fig. 7), the paired tests, SR against density, the other metrics, how collisions happened
/// and the feasibility violations.
fn suite_section(
    md: &mut String,
    in_suite: &[&ResultRow],
    suite: &str,
    kind: SuiteKind,
    ctx: &ReportContext,
) {
    // The methods that ran this suite (a suite may name its own).
    let methods: Vec<String> = ctx
        .methods
        .iter()
        .filter(|m| in_suite.iter().any(|r| &r.method == *m))
        .cloned()
        .collect();
    let _ = writeln!(md, "## Suite `{suite}` ({})\n", kind.as_str());
    sr_per_scenario_table(md, in_suite, &methods);
    sr_per_robot_table(md, in_suite, &ctx.robot_names, &methods);
    tfs_table(md, in_suite, &ctx.robot_names, &methods);
    paired_section(md, in_suite, ctx, &methods);
    density_section(md, in_suite, &methods);
    other_metrics_table(md, in_suite, &methods);
    crate::human_likeness::human_likeness_table(md, in_suite, &ctx.robot_names, &methods);
    failure_table(md, in_suite, &ctx.robot_names, &methods);
    violation_table(md, in_suite, &ctx.robot_names, &methods);
    let _ = writeln!(md);
}

/// The verdict table of an empty-world suite: SR per method and robot, pass only at 100 %.
fn empty_suite_section(md: &mut String, in_suite: &[&ResultRow], suite: &str, ctx: &ReportContext) {
    let _ = writeln!(md, "## Empty-world sanity suite `{suite}`\n");
    let _ = writeln!(
        md,
        "Every working method must reach SR = 100 % on every robot (the methods the suite's \
         `methods` list leaves out are not run here).\n"
    );
    let _ = write!(md, "| method |");
    for robot in &ctx.robot_names {
        let _ = write!(md, " {robot} |");
    }
    let _ = write!(md, " verdict |\n|---|");
    for _ in &ctx.robot_names {
        let _ = write!(md, "---|");
    }
    let _ = writeln!(md, "---|");
    for m in &ctx.methods {
        // A method the suite's `methods` list leaves out is not held to the check.
        if !in_suite.iter().any(|r| &r.method == m) {
            continue;
        }
        let _ = write!(md, "| {m} |");
        let mut all_pass = true;
        for robot in &ctx.robot_names {
            let s = summarize(
                in_suite
                    .iter()
                    .copied()
                    .filter(|r| &r.robot == robot && &r.method == m),
            );
            all_pass &= s.n > 0 && s.sr == 1.0;
            let _ = write!(md, " {} |", cell_sr(&s));
        }
        let _ = writeln!(md, " {} |", if all_pass { "pass" } else { "FAIL" });
    }
    let _ = writeln!(md);
}

fn cell_sr(s: &Summary) -> String {
    if s.n == 0 {
        "–".into()
    } else {
        format!("{} ± {} (n={})", pct(s.sr), pct(s.sr_se), s.n)
    }
}

/// A p-value to three decimals, `< 0.001` below that.
pub(crate) fn p_value(p: f64) -> String {
    if p < 0.001 {
        "< 0.001".into()
    } else {
        format!("{p:.3}")
    }
}

#[cfg(test)]
mod tests {
    use super::csv_io::{num, opt};
    use super::*;
    use crate::episode::ScenarioClass;
    use crate::metrics::{EpisodeMetrics, HumanComparison, LimitCounts};
    use crate::runner::{Contact, Outcome};

    /// `results_csv` as it was written by hand before it used the `csv` crate (verbatim): the
    /// reference the crate's bytes are compared with.
    fn hand_written_results_csv(rows: &[ResultRow]) -> String {
        fn csv_field(s: &str) -> String {
            if s.contains([',', '"', '\n', '\r']) {
                format!("\"{}\"", s.replace('"', "\"\""))
            } else {
                s.to_string()
            }
        }
        let mut out = String::with_capacity(256 * (rows.len() + 1));
        out.push_str(CSV_HEADER);
        out.push('\n');
        for r in rows {
            let m = &r.metrics;
            let fields = [
                csv_field(&r.suite),
                r.suite_kind.as_str().to_string(),
                r.scenario.name().to_string(),
                csv_field(&r.episode),
                csv_field(&r.scene),
                csv_field(&r.robot),
                csv_field(&r.method),
                r.seed.to_string(),
                r.agents.to_string(),
                r.density.to_string(),
                m.outcome.as_str().to_string(),
                u8::from(m.success).to_string(),
                u8::from(m.collision).to_string(),
                u8::from(m.timeout).to_string(),
                num(m.tfs),
                num(m.tfs_plan),
                num(m.tfs_executed),
                num(m.path_length),
                opt(m.time_to_goal),
                num(m.duration),
                num(m.budget),
                opt(m.min_clearance),
                num(m.time_within_intimate),
                num(m.time_within_personal),
                num(m.mean_jerk),
                m.plans.to_string(),
                m.fallbacks.to_string(),
                m.planner_errors.to_string(),
                opt(m.contact.map(|c| c.robot_closing)),
                opt(m.contact.map(|c| c.pedestrian_closing)),
                opt(m.contact.map(|c| c.pedestrian_age)),
                opt(m.contact.map(|c| c.pedestrian_speed)),
                m.executed_violations.commands.to_string(),
            ]
            .into_iter()
            .chain(
                m.executed_violations
                    .per_limit()
                    .iter()
                    .map(|c| c.to_string()),
            )
            .chain([
                num(m.end_goal_distance),
                opt(m.end_goal_crowd),
                opt(m.human.map(|h| h.distance)),
                opt(m.human.map(|h| h.length_ratio)),
            ])
            .collect::<Vec<String>>();
            out.push_str(&fields.join(","));
            out.push('\n');
        }
        out
    }

    fn row(text: &str, outcome: Outcome, k: u32) -> ResultRow {
        let x = f64::from(k);
        ResultRow {
            suite: format!("suite {text}"),
            suite_kind: [SuiteKind::Real, SuiteKind::Synthetic, SuiteKind::Empty][k as usize % 3],
            scenario: ScenarioClass::ALL[k as usize % 4],
            episode: text.to_string(),
            scene: format!("{text}{text}"),
            robot: if k % 2 == 0 {
                String::new()
            } else {
                "go2".into()
            },
            method: format!("m,{k}"),
            seed: u64::MAX - u64::from(k),
            agents: k as usize,
            density: 2 * k as usize,
            metrics: EpisodeMetrics {
                outcome,
                success: outcome == Outcome::Success,
                collision: outcome == Outcome::Collision,
                timeout: outcome == Outcome::Timeout,
                tfs: 1.0 / (x + 3.0),
                tfs_plan: [f64::NAN, 0.0, -0.0, 1e-7][k as usize % 4],
                tfs_executed: [f64::INFINITY, 1.0, 0.1 + 0.2, -1e300][k as usize % 4],
                path_length: 12.345_678_9 * x,
                time_to_goal: (outcome == Outcome::Success).then_some(9.5 + x),
                duration: 20.0,
                budget: 30.000_000_5,
                min_clearance: (k % 3 != 0).then_some(0.25 * x - 0.5),
                time_within_intimate: 0.05 * x,
                time_within_personal: 0.1 * x,
                mean_jerk: 1e6 / (x + 1.0),
                plans: 100 + k as usize,
                fallbacks: k as usize,
                planner_errors: (k % 2) as usize,
                contact: (outcome == Outcome::Collision).then_some(Contact {
                    pedestrian: 7,
                    robot_closing: 0.4,
                    pedestrian_closing: -0.2,
                    pedestrian_age: f64::NAN,
                    pedestrian_speed: 1.25,
                }),
                obstacle_hit: None,
                executed_violations: LimitCounts {
                    commands: 400,
                    speed: k as usize,
                    reverse: 0,
                    acceleration: 3,
                    yaw_rate: 4,
                    curvature: 5,
                    lateral: 6,
                    coupled: 0,
                },
                end_goal_distance: [0.25, f64::NAN, 3.5][k as usize % 3],
                end_goal_crowd: (k % 2 == 0).then_some(-0.125 * x),
                human: (k % 3 == 1).then_some(HumanComparison {
                    distance: 0.375 * x,
                    length_ratio: 1.0 + 0.0625 * x,
                }),
            },
        }
    }

    #[test]
    fn each_failure_falls_in_the_first_class_that_applies() {
        let failed = |outcome, contact: Option<Contact>, distance: f64, crowd: Option<f64>| {
            let mut m = row("e", outcome, 1).metrics;
            m.contact = contact;
            m.obstacle_hit = None;
            m.end_goal_distance = distance;
            m.end_goal_crowd = crowd;
            Failure::of(&m)
        };
        // Closing speeds along the line between the centres; the pedestrian's speed is its
        // closing speed unless given.
        let moving = |age: f64, pedestrian: f64, robot: f64, speed: f64| {
            Some(Contact {
                pedestrian: 1,
                robot_closing: robot,
                pedestrian_closing: pedestrian,
                pedestrian_age: age,
                pedestrian_speed: speed,
            })
        };
        let contact = |age: f64, pedestrian: f64, robot: f64| {
            moving(age, pedestrian, robot, pedestrian.abs())
        };
        let c = Outcome::Collision;
        // A fast pedestrian whose track has just begun appeared; a robot standing still hit
        // by a cyclist was hit by someone fast.
        assert_eq!(
            failed(c, contact(0.5, 4.0, 0.0), 9.0, None),
            Some(Failure::Appeared)
        );
        assert_eq!(
            failed(c, contact(3.0, 4.0, 0.0), 9.0, None),
            Some(Failure::Fast)
        );
        // A cyclist at 6 m/s that overtakes the robot and clips it closes slowly along the
        // line between the centres (here it is already moving away) but is still fast.
        assert_eq!(
            failed(c, moving(3.0, -0.5, 0.3, 6.0), 9.0, None),
            Some(Failure::Fast)
        );
        assert_eq!(
            failed(c, contact(3.0, 1.2, 0.05), 9.0, None),
            Some(Failure::WalkedInto)
        );
        assert_eq!(
            failed(c, contact(3.0, 1.2, 0.5), 9.0, None),
            Some(Failure::DroveIn)
        );
        assert_eq!(failed(c, None, 9.0, None), Some(Failure::Obstacle));
        let t = Outcome::Timeout;
        assert_eq!(failed(t, None, 1.0, Some(0.2)), Some(Failure::GoalTaken));
        assert_eq!(failed(t, None, 5.0, Some(-0.1)), Some(Failure::GoalTaken));
        assert_eq!(failed(t, None, 1.0, Some(0.8)), Some(Failure::NearGoal));
        assert_eq!(failed(t, None, 1.0, None), Some(Failure::NearGoal));
        assert_eq!(failed(t, None, 3.0, Some(0.8)), Some(Failure::Timeout));
        assert_eq!(failed(Outcome::Success, None, 0.1, Some(0.0)), None);
    }

    #[test]
    fn the_csv_crate_writes_the_bytes_of_the_hand_written_writer() {
        let texts = [
            "e0",
            "",
            "a,b",
            "say \"hi\"",
            "\"",
            "\"\"",
            ",",
            "line\nbreak",
            "carriage\rreturn",
            "crlf\r\n",
            " padded ",
            "tab\there",
            "semi;colon",
            "#hash",
            "'single'",
            "ünïcødé → ✓",
            "=1+2",
            "trailing,",
            "\"quoted, with comma\"",
        ];
        let outcomes = [Outcome::Success, Outcome::Collision, Outcome::Timeout];
        let rows: Vec<ResultRow> = texts
            .iter()
            .enumerate()
            .map(|(k, t)| row(t, outcomes[k % 3], k as u32))
            .collect();
        assert_eq!(results_csv(&rows), hand_written_results_csv(&rows));
        assert_eq!(results_csv(&[]), hand_written_results_csv(&[]));
        assert_eq!(
            results_csv(&rows[..1]),
            hand_written_results_csv(&rows[..1])
        );
    }

    /// Rows as the reader gives them back: what `results.csv` has no column for at its
    /// default (the contact's pedestrian id, the obstacle hit).
    fn as_read(mut rows: Vec<ResultRow>) -> Vec<ResultRow> {
        for r in &mut rows {
            if let Some(c) = &mut r.metrics.contact {
                c.pedestrian = 0;
            }
            r.metrics.obstacle_hit = None;
        }
        rows
    }

    fn sample_rows() -> Vec<ResultRow> {
        let outcomes = [Outcome::Success, Outcome::Collision, Outcome::Timeout];
        (0..12)
            .map(|k| row(&format!("ep \"{k}\"\n"), outcomes[k as usize % 3], k))
            .collect()
    }

    #[test]
    fn the_exact_csv_reads_back_into_the_same_rows() {
        let rows = as_read(sample_rows());
        let text = results_csv_exact(&rows);
        let back = parse_results_csv(&text, "test").unwrap();
        // NaN is not equal to itself: compare the exact text (one spelling per f64, -0.0 and
        // NaN included), then the rows without NaN directly.
        assert_eq!(results_csv_exact(&back), text);
        assert_eq!(back.len(), rows.len());
        let finite = |r: &&ResultRow| {
            let m = &r.metrics;
            [m.tfs_plan, m.tfs_executed, m.end_goal_distance]
                .iter()
                .all(|v| !v.is_nan())
                && m.contact.is_none_or(|c| !c.pedestrian_age.is_nan())
        };
        let compared: Vec<_> = rows.iter().zip(&back).filter(|(r, _)| finite(r)).collect();
        assert!(compared.len() >= 3, "some rows without NaN are compared");
        for (r, b) in compared {
            assert_eq!(r, b);
        }
        // 0.1 + 0.2 and -1e300 are not six-decimal numbers: they came back exactly.
        assert_eq!(back[2].metrics.tfs_executed, 0.1 + 0.2);
        assert_eq!(back[3].metrics.tfs_executed, -1e300);
        assert!(back[2].metrics.tfs_plan.is_sign_negative());
    }

    #[test]
    fn six_decimal_rows_read_back_equal_and_any_rows_write_back_the_same_bytes() {
        // Rows whose numbers have six decimals at most and are finite read back equal.
        let rows: Vec<ResultRow> = as_read(sample_rows())
            .into_iter()
            .map(|mut r| {
                let m = &mut r.metrics;
                let six = |v: &mut f64| {
                    *v = if v.is_finite() {
                        (*v * 1e6).round() / 1e6
                    } else {
                        0.5
                    }
                };
                for v in [
                    &mut m.tfs,
                    &mut m.tfs_plan,
                    &mut m.tfs_executed,
                    &mut m.path_length,
                    &mut m.duration,
                    &mut m.budget,
                    &mut m.time_within_intimate,
                    &mut m.time_within_personal,
                    &mut m.mean_jerk,
                    &mut m.end_goal_distance,
                ] {
                    six(v);
                }
                for v in [
                    &mut m.time_to_goal,
                    &mut m.min_clearance,
                    &mut m.end_goal_crowd,
                ] {
                    v.iter_mut().for_each(six);
                }
                if let Some(c) = &mut m.contact {
                    for v in [
                        &mut c.robot_closing,
                        &mut c.pedestrian_closing,
                        &mut c.pedestrian_age,
                        &mut c.pedestrian_speed,
                    ] {
                        six(v);
                    }
                }
                r
            })
            .collect();
        let text = results_csv(&rows);
        assert_eq!(parse_results_csv(&text, "test").unwrap(), rows);
        // Any rows: what is read back from results.csv writes the same bytes again (what
        // `bench --merge` relies on when it is given plain results.csv files).
        let text = results_csv(&sample_rows());
        let back = parse_results_csv(&text, "test").unwrap();
        assert_eq!(results_csv(&back), text);
    }

    #[test]
    fn a_bad_results_csv_is_refused_naming_the_line_and_the_column() {
        let outcomes = [Outcome::Success, Outcome::Collision, Outcome::Timeout];
        let rows: Vec<ResultRow> = (0..3).map(|k| row("e", outcomes[k as usize], k)).collect();
        let text = results_csv(&rows);
        let err = |text: &str| {
            parse_results_csv(text, "shard/results.csv")
                .unwrap_err()
                .to_string()
        };
        let e = err(&text.replacen(",12.345679,", ",12.3x,", 1));
        assert!(
            e.contains("shard/results.csv")
                && e.contains("line 3")
                && e.contains("`path_length`")
                && e.contains("`12.3x` is not a number"),
            "{e}"
        );
        let e = err(&text.replacen(",success,", ",outcome2,", 1));
        assert!(e.contains("unknown column `outcome2`"), "{e}");
        let e = err(&text.replacen(",collision,0,1,0,", ",collision,0,1,", 1));
        let fewer = format!("{} fields", CSV_HEADER.split(',').count() - 1);
        assert!(e.contains("line 3") && e.contains(&fewer), "{e}");
        let header_only = format!("{}\n", CSV_HEADER.replacen(",mean_jerk", "", 1));
        assert!(err(&header_only).contains("no `mean_jerk` column"));
        let e = err(&text.replacen(",collision,0,1,0,", ",collision,2,1,0,", 1));
        assert!(e.contains("`success`") && e.contains("not 0 or 1"), "{e}");
        let e = err(&text.replacen(",timeout,0,0,1,", ",stuck,0,0,1,", 1));
        assert!(
            e.contains("`outcome`") && e.contains("one of success"),
            "{e}"
        );
    }
}
