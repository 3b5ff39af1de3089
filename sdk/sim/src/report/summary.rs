//! Aggregates over groups of rows ([`Summary`]) and the failed planner calls of a benchmark,
//! with the report's warning about them.

use crate::bench::ResultRow;
use std::fmt::Write as _;

/// Aggregates over a group of rows.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Summary {
    /// Rows aggregated.
    pub n: usize,
    /// Success rate.
    pub sr: f64,
    /// Standard error of the success rate, `sqrt(SR·(1 − SR)/n)`.
    pub sr_se: f64,
    /// Share of runs ending in a collision.
    pub collision_rate: f64,
    /// Share of runs ending in a timeout.
    pub timeout_rate: f64,
    /// Mean TFS (`min(plan, executed)` per run).
    pub tfs: f64,
    /// Mean TFS of the plans.
    pub tfs_plan: f64,
    /// Mean TFS of the executed commands.
    pub tfs_executed: f64,
    /// Mean executed path length (m).
    pub path_length: f64,
    /// Mean over successful episodes.
    pub time_to_goal: Option<f64>,
    /// Mean over episodes with pedestrians.
    pub min_clearance: Option<f64>,
    /// Mean time closer than the intimate distance (s).
    pub time_within_intimate: f64,
    /// Mean time closer than the personal distance (s).
    pub time_within_personal: f64,
    /// Mean of the runs' mean jerk (m/s³).
    pub mean_jerk: f64,
    /// Fraction of plans that were fallbacks.
    pub fallback_rate: f64,
    /// Planner calls, and those that failed (see [`PlannerFailures`]).
    pub planner_calls: usize,
    /// Planner calls that failed.
    pub failed_calls: usize,
}

pub(super) fn mean(it: impl Iterator<Item = f64>) -> Option<f64> {
    let (s, n) = it.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| s / n as f64)
}

/// Summarises `rows` (an empty group gives `n = 0` and zeros).
pub fn summarize<'a>(rows: impl IntoIterator<Item = &'a ResultRow>) -> Summary {
    let rows: Vec<&ResultRow> = rows.into_iter().collect();
    let n = rows.len();
    if n == 0 {
        return Summary::default();
    }
    let rate =
        |f: &dyn Fn(&ResultRow) -> bool| rows.iter().filter(|r| f(r)).count() as f64 / n as f64;
    let avg = |f: &dyn Fn(&ResultRow) -> f64| mean(rows.iter().map(|r| f(r))).unwrap_or(0.0);
    let sr = rate(&|r| r.metrics.success);
    let plans: usize = rows.iter().map(|r| r.metrics.plans).sum();
    let fallbacks: usize = rows.iter().map(|r| r.metrics.fallbacks).sum();
    Summary {
        n,
        sr,
        sr_se: (sr * (1.0 - sr) / n as f64).sqrt(),
        collision_rate: rate(&|r| r.metrics.collision),
        timeout_rate: rate(&|r| r.metrics.timeout),
        tfs: avg(&|r| r.metrics.tfs),
        tfs_plan: avg(&|r| r.metrics.tfs_plan),
        tfs_executed: avg(&|r| r.metrics.tfs_executed),
        path_length: avg(&|r| r.metrics.path_length),
        time_to_goal: mean(rows.iter().filter_map(|r| r.metrics.time_to_goal)),
        min_clearance: mean(rows.iter().filter_map(|r| r.metrics.min_clearance)),
        time_within_intimate: avg(&|r| r.metrics.time_within_intimate),
        time_within_personal: avg(&|r| r.metrics.time_within_personal),
        mean_jerk: avg(&|r| r.metrics.mean_jerk),
        fallback_rate: if plans > 0 {
            fallbacks as f64 / plans as f64
        } else {
            0.0
        },
        planner_calls: plans,
        failed_calls: rows.iter().map(|r| r.metrics.planner_errors).sum(),
    }
}

/// Failed planner calls of one method on one robot, over every suite of a benchmark.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlannerFailures {
    /// The method.
    pub method: String,
    /// The robot.
    pub robot: String,
    /// Runs of this method on this robot.
    pub runs: usize,
    /// Planner calls in those runs.
    pub calls: usize,
    /// Calls that failed (error, panic, missed deadline, unusable plan): each was replaced by
    /// the simulator's stop-in-place plan (or the plugin host's, after a missed deadline).
    pub failed: usize,
    /// Runs in which every call failed: the robot only ever followed stop-in-place plans.
    pub runs_all_failed: usize,
}

/// Every (method, robot) with at least one failed planner call, in the order the rows first
/// name them.
pub fn planner_failures(rows: &[ResultRow]) -> Vec<PlannerFailures> {
    let mut out: Vec<PlannerFailures> = Vec::new();
    for r in rows {
        let i = match out
            .iter()
            .position(|f| f.method == r.method && f.robot == r.robot)
        {
            Some(i) => i,
            None => {
                out.push(PlannerFailures {
                    method: r.method.clone(),
                    robot: r.robot.clone(),
                    runs: 0,
                    calls: 0,
                    failed: 0,
                    runs_all_failed: 0,
                });
                out.len() - 1
            }
        };
        let m = &r.metrics;
        let f = &mut out[i];
        f.runs += 1;
        f.calls += m.plans;
        f.failed += m.planner_errors;
        if m.plans > 0 && m.planner_errors >= m.plans {
            f.runs_all_failed += 1;
        }
    }
    out.retain(|f| f.failed > 0);
    out
}

/// The report's warning about failed planner calls (empty when there were none).
pub(super) fn planner_failure_warning(md: &mut String, rows: &[ResultRow]) {
    let failures = planner_failures(rows);
    if failures.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "> **Warning: planner calls failed.** Each failed call (an error, a panic, a missed \
         deadline or an unusable plan) was replaced by a stop-in-place plan, so where calls \
         failed the numbers below measure that stand-in, not the method: a robot whose every \
         call failed never moved, and its TFS of 1.000 scores the stop plans. `human2nav bench` \
         exits with an error.\n>"
    );
    let _ = writeln!(
        md,
        "> | method | robot | runs | planner calls | failed calls | runs where every call failed |\n\
         > |---|---|---|---|---|---|"
    );
    for f in &failures {
        let share = if f.calls > 0 {
            100.0 * f.failed as f64 / f.calls as f64
        } else {
            0.0
        };
        let _ = writeln!(
            md,
            "> | {} | {} | {} | {} | **{} ({share:.1} %)** | {} |",
            f.method, f.robot, f.runs, f.calls, f.failed, f.runs_all_failed
        );
    }
    let _ = writeln!(md);
}
