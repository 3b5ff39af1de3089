//! How human the robot moved: on episodes with a recorded human (the pedestrian whose start and
//! goal the robot took, [`crate::metrics::HumanComparison`]), each method's distance to that
//! pedestrian's path and path-length ratio, beside its time close to people and its jerk.
//!
//! The table compares methods on the same runs: per robot, the episodes every method of the
//! suite reached the goal on (a run that failed early is short and straight, and would look
//! more human than it is).

use crate::bench::ResultRow;
use std::collections::BTreeSet;
use std::fmt::Write as _;

/// Writes the section into `md` when some row of `in_suite` has a recorded human; nothing
/// otherwise.
pub(crate) fn human_likeness_table(
    md: &mut String,
    in_suite: &[&ResultRow],
    robots: &[String],
    methods: &[String],
) {
    if !in_suite.iter().any(|r| r.metrics.human.is_some()) {
        return;
    }
    let _ = writeln!(
        md,
        "\n### How human, per robot (the recorded pedestrian's path; runs every method \
         succeeded on)\n\n\
         Distance: mean over time of the robot's distance to the pedestrian at the same time \
         since the start; length ratio: the robot's path length over the pedestrian's (the \
         human: 0 m and 1).\n\n\
         | robot | method | n | distance to the human (m) | length ratio | time < 0.45 m (s) | \
         mean jerk (m/s³) |\n|---|---|---|---|---|---|---|"
    );
    for robot in robots {
        let of_robot: Vec<&ResultRow> = in_suite
            .iter()
            .copied()
            .filter(|r| &r.robot == robot && r.metrics.human.is_some())
            .collect();
        let common = common_successes(&of_robot, methods);
        for m in methods {
            let rows: Vec<&ResultRow> = of_robot
                .iter()
                .copied()
                .filter(|r| &r.method == m && common.contains(r.episode.as_str()))
                .collect();
            if rows.is_empty() {
                let _ = writeln!(md, "| {robot} | {m} | 0 | – | – | – | – |");
                continue;
            }
            let mean = |f: &dyn Fn(&ResultRow) -> f64| {
                rows.iter().map(|r| f(r)).sum::<f64>() / rows.len() as f64
            };
            let human = |r: &ResultRow| r.metrics.human.map_or(f64::NAN, |h| h.distance);
            let ratio = |r: &ResultRow| r.metrics.human.map_or(f64::NAN, |h| h.length_ratio);
            let _ = writeln!(
                md,
                "| {robot} | {m} | {} | {:.2} | {:.2} | {:.2} | {:.2} |",
                rows.len(),
                mean(&human),
                mean(&ratio),
                mean(&|r| r.metrics.time_within_intimate),
                mean(&|r| r.metrics.mean_jerk),
            );
        }
    }
}

/// The episodes of `rows` (one robot) that every method of `methods` ran and succeeded on.
fn common_successes<'a>(rows: &[&'a ResultRow], methods: &[String]) -> BTreeSet<&'a str> {
    let episodes: BTreeSet<&str> = rows.iter().map(|r| r.episode.as_str()).collect();
    episodes
        .into_iter()
        .filter(|e| {
            methods.iter().all(|m| {
                rows.iter()
                    .any(|r| &r.method == m && r.episode == *e && r.metrics.success)
            })
        })
        .collect()
}
