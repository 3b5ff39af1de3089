//! One benchmark run end to end: suites × robots × methods in parallel, then `results.csv`,
//! the figures and `report.md` in the output directory.

use crate::bench::{
    MethodSpec, MethodTimes, ResultRow, Suite, SuiteKind, run_bench_shard, run_one,
};
use crate::episode::{Episode, ScenarioClass, ScenarioTitle};
use crate::error::SimError;
use crate::figures::{self, Snapshot};
use crate::report::{self, PlannerFailures, ReportContext, summarize};
use crate::runner::{RobotSetup, SimConfig};
use crate::shard::ShardSpec;
use crate::stats::SuiteComposition;
use human2nav_core::bev::BevSpec;
use indicatif::ProgressBar;
use std::collections::HashMap;
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything a run needs besides the suites.
#[derive(Debug)]
pub struct BenchPlan<'a> {
    /// The suites run.
    pub suites: &'a [Suite],
    /// The robots, each running every suite.
    pub robots: &'a [RobotSetup],
    /// The methods, each running the suites that name it (all by default).
    pub methods: &'a [MethodSpec],
    /// Simulation settings (a method may override the replanning rate).
    pub sim: &'a SimConfig,
    /// Master seed: every run's seed derives from it.
    pub seed: u64,
    /// Quick mode (a few episodes per class); noted in the report.
    pub quick: bool,
    /// Method drawn in the snapshots (default: the first).
    pub snapshot_method: Option<&'a str>,
    /// How the run was started, for the report.
    pub command: String,
    /// Worker threads (`None`: rayon's default, one per core; at most [`MAX_THREADS`]).
    pub threads: Option<usize>,
    /// Failed runs drawn per method (see `failure_figures`; 0: none).
    pub failures: usize,
    /// Write every run as an MCAP file under this folder ([`crate::record`]; `None`: none).
    pub record: Option<PathBuf>,
}

/// Largest number of worker threads of a run (`--threads`). Each thread has its own stack and
/// runs one episode at a time with its own planner; asking for 100 000 of them brought the
/// process down before any episode ran. 256 is far more than the cores of any machine the
/// benchmark runs on.
pub const MAX_THREADS: usize = 256;

/// What a run produced.
#[derive(Debug)]
pub struct BenchOutcome {
    /// One row per episode × robot × method.
    pub rows: Vec<ResultRow>,
    /// Path of the written `results.csv`.
    pub results_csv: PathBuf,
    /// Path of the written `report.md`.
    pub report_md: PathBuf,
    /// Paths of the written figures, in the report's order.
    pub figures: Vec<PathBuf>,
    /// `(method, robot, SR)` on the empty-world suites, where SR < 1.
    pub empty_world_failures: Vec<(String, String, f64)>,
    /// Every (method, robot) with failed planner calls (report.md lists them at the top).
    pub planner_failures: Vec<PlannerFailures>,
    /// Wall time of the episode runs and figures (s).
    pub wall_time: f64,
    /// Thread time per method.
    pub times: MethodTimes,
}

/// Runs the plan and writes every output into `out_dir` (created when missing).
pub fn run(
    plan: &BenchPlan<'_>,
    out_dir: &Path,
    progress: &ProgressBar,
) -> Result<BenchOutcome, SimError> {
    check_threads(plan)?;
    std::fs::create_dir_all(out_dir).map_err(|e| SimError::io(out_dir, e))?;
    let started = Instant::now();
    let (rows, times) = run_episodes(plan, None, progress)?;
    write_outputs(plan, rows, times, Merged::default(), out_dir, started)
}

/// Refuses more worker threads than [`MAX_THREADS`].
fn check_threads(plan: &BenchPlan<'_>) -> Result<(), SimError> {
    match plan.threads.filter(|&n| n > MAX_THREADS) {
        Some(n) => Err(SimError::setting(
            "bench",
            "threads",
            format!("{n} is more than the limit of {MAX_THREADS}"),
        )),
        None => Ok(()),
    }
}

/// The runs of one shard of the plan ([`crate::shard`]): its rows in job order and the thread
/// time per method. Writes nothing.
pub fn run_shard(
    plan: &BenchPlan<'_>,
    shard: ShardSpec,
    progress: &ProgressBar,
) -> Result<(Vec<ResultRow>, MethodTimes), SimError> {
    check_threads(plan)?;
    run_episodes(plan, Some(shard), progress)
}

/// What the shards a merge joins add to its report: their number and the wall time they took
/// together.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Merged {
    /// Shards merged (0: one run).
    pub shards: usize,
    /// The shards' wall times summed (s).
    pub wall_time: f64,
}

/// Writes `results.csv`, the figures (re-running the episodes they draw) and `report.md` of
/// every run of the plan, given as `rows` in job order, into `out_dir` (created when missing).
/// `started` is when the run began (the report's wall time counts from it); `merged` says what
/// shards the rows came from ([`Merged::default`] for one run).
pub fn write_outputs(
    plan: &BenchPlan<'_>,
    rows: Vec<ResultRow>,
    times: MethodTimes,
    merged: Merged,
    out_dir: &Path,
    started: Instant,
) -> Result<BenchOutcome, SimError> {
    check_threads(plan)?;
    std::fs::create_dir_all(out_dir).map_err(|e| SimError::io(out_dir, e))?;
    let results_csv = out_dir.join("results.csv");
    std::fs::write(&results_csv, report::results_csv(&rows))
        .map_err(|e| SimError::io(&results_csv, e))?;

    let method_names: Vec<String> = plan.methods.iter().map(|m| m.name.clone()).collect();
    let robot_names: Vec<String> = plan.robots.iter().map(|r| r.name.clone()).collect();
    let figure_list = draw_figures(plan, &rows, out_dir, &method_names, &robot_names)?;
    let figure_paths = figure_list
        .iter()
        .map(|(file, _)| out_dir.join(file))
        .collect();

    let wall_time = started.elapsed().as_secs_f64() + merged.wall_time;
    let ctx = ReportContext {
        command: plan.command.clone(),
        seed: plan.seed,
        quick: plan.quick,
        sim: sim_table(plan.sim, plan.methods, plan.suites),
        robots: plan.robots.iter().map(robot_line).collect(),
        methods: method_names.clone(),
        suites: plan
            .suites
            .iter()
            .map(|s| (s.name.clone(), s.kind, s.episodes.len(), s.note.clone()))
            .collect(),
        robot_names: robot_names.clone(),
        figures: figure_list,
        wall_time: Some(wall_time),
        method_times: times.per_method.clone(),
        reference_method: None,
        composition: plan
            .suites
            .iter()
            .map(|s| SuiteComposition::of(&s.name, &s.episodes))
            .collect(),
        shards: merged.shards,
    };
    let report_md = out_dir.join("report.md");
    std::fs::write(&report_md, report::report_markdown(&rows, &ctx))
        .map_err(|e| SimError::io(&report_md, e))?;

    let empty_world_failures = empty_world_failures(plan, &rows, &method_names, &robot_names);
    let planner_failures = report::planner_failures(&rows);
    Ok(BenchOutcome {
        rows,
        results_csv,
        report_md,
        figures: figure_paths,
        empty_world_failures,
        planner_failures,
        wall_time,
        times,
    })
}

/// Every episode run of the plan (of `shard` only, when given), on `plan.threads` workers
/// (rayon's default pool when `None`), with the thread time per method.
fn run_episodes(
    plan: &BenchPlan<'_>,
    shard: Option<ShardSpec>,
    progress: &ProgressBar,
) -> Result<(Vec<ResultRow>, MethodTimes), SimError> {
    in_pool(plan, || {
        run_bench_shard(
            plan.suites,
            plan.robots,
            plan.methods,
            plan.sim,
            plan.seed,
            shard,
            plan.record.as_deref(),
            progress,
        )
    })
}

/// `work` on `plan.threads` workers (rayon's default pool when `None`).
fn in_pool<T: Send>(
    plan: &BenchPlan<'_>,
    work: impl FnOnce() -> Result<T, SimError> + Send,
) -> Result<T, SimError> {
    match plan.threads {
        None => work(),
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build()
            .map_err(|e| SimError::setting("bench", "threads", e.to_string()))?
            .install(work),
    }
}

/// Draws the figures of every suite with pedestrians (Fig. 6, Fig. 7 and SR against density,
/// then the snapshots and the failure pictures) into `out_dir`; returns each file's name and
/// caption, in the report's order.
fn draw_figures(
    plan: &BenchPlan<'_>,
    rows: &[ResultRow],
    out_dir: &Path,
    method_names: &[String],
    robot_names: &[String],
) -> Result<Vec<(String, String)>, SimError> {
    let mut figure_list: Vec<(String, String)> = Vec::new();
    for suite in plan.suites.iter().filter(|s| s.kind != SuiteKind::Empty) {
        let [f6, f7, fd] = suite_figure_files(&suite.name);
        figures::sr_per_scenario(&out_dir.join(&f6), rows, &suite.name, method_names)?;
        figure_list.push((
            f6,
            format!(
                "Fig. 6: success rate per scenario and method, suite `{}`, all robots; whiskers: \
                 95 % Wilson score intervals",
                suite.name
            ),
        ));
        figures::tfs_sr_per_robot(
            &out_dir.join(&f7),
            rows,
            &suite.name,
            robot_names,
            method_names,
        )?;
        figure_list.push((
            f7,
            format!(
                "Fig. 7: TFS (left; whiskers: ±1.96 standard errors of the mean of the per-episode \
                 TFS) and SR (right; whiskers: 95 % Wilson score intervals) per robot and method, \
                 suite `{}`",
                suite.name
            ),
        ));
        figures::sr_per_density(&out_dir.join(&fd), rows, &suite.name, method_names)?;
        figure_list.push((
            fd,
            format!(
                "SR against crowd density (relevant pedestrians per episode), suite `{}`, all \
                 robots and scenarios; whiskers: 95 % Wilson score intervals; under each bin the \
                 number of episodes in it",
                suite.name
            ),
        ));
    }
    for suite in plan.suites.iter().filter(|s| s.kind != SuiteKind::Empty) {
        if let Some((snaps, caption)) = representative_snapshots(plan, suite, rows)? {
            let f4 = fig4_file(&suite.name);
            figures::trajectory_snapshots(&out_dir.join(&f4), &snaps)?;
            figure_list.push((f4, caption));
        }
        figure_list.extend(failure_figures(plan, rows, suite, out_dir)?);
    }
    Ok(figure_list)
}

/// The report's line for a robot: embodiment, collision footprint, planners' disc and limits.
fn robot_line(r: &RobotSetup) -> String {
    let l = &r.limits;
    format!(
        "`{}` ({}): collides as {}; planners' disc r {:.2} m; v_max {:.2} m/s, a_max {:.2} m/s², ω_max {:.2} rad/s, {}",
        r.name,
        r.embodiment.name(),
        r.footprint
            .iter()
            .map(|s| s.to_string())
            .collect::<Vec<_>>()
            .join(" + "),
        r.footprint_radius,
        l.v_max,
        l.a_max,
        l.omega_max,
        match l.kappa_max {
            Some(k) => format!("min turning radius {:.2} m", 1.0 / k),
            None => "turns in place".into(),
        }
    )
}

/// `(method, robot, SR)` of every pair that missed SR = 1 on an empty-world suite.
pub fn empty_world_failures(
    plan: &BenchPlan<'_>,
    rows: &[ResultRow],
    method_names: &[String],
    robot_names: &[String],
) -> Vec<(String, String, f64)> {
    let mut failures = Vec::new();
    for s in plan.suites.iter().filter(|s| s.kind == SuiteKind::Empty) {
        for m in method_names {
            for r in robot_names {
                let sum = summarize(
                    rows.iter()
                        .filter(|x| x.suite == s.name && &x.method == m && &x.robot == r),
                );
                if sum.n > 0 && sum.sr < 1.0 {
                    failures.push((m.clone(), r.clone(), sum.sr));
                }
            }
        }
    }
    failures
}

impl BenchOutcome {
    /// True when a planner call failed in any run ([`BenchOutcome::planner_failures`]); the
    /// CLI then exits with an error.
    pub fn has_failed_planner_calls(&self) -> bool {
        !self.planner_failures.is_empty()
    }

    /// True when the benchmark is usable: no failed planner call and SR = 1 on every
    /// empty-world suite.
    pub fn passed(&self) -> bool {
        self.empty_world_failures.is_empty() && self.planner_failures.is_empty()
    }
}

/// The settings table of the report.
fn sim_table(sim: &SimConfig, methods: &[MethodSpec], suites: &[Suite]) -> Vec<(String, String)> {
    let radii = suites
        .iter()
        .flat_map(|s| &s.episodes)
        .flat_map(|e| &e.agents)
        .map(|a| a.radius);
    let (lo, hi) = radii.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
        (lo.min(r), hi.max(r))
    });
    let pedestrian_radius = if lo > hi {
        "no pedestrians".to_string()
    } else if (hi - lo).abs() < 1e-12 {
        format!("{lo} m (from the episodes)")
    } else {
        format!("{lo}–{hi} m (from the episodes)")
    };
    vec![
        ("simulation step".into(), format!("{} s", sim.dt)),
        ("replanning rate".into(), replanning_rates(sim, methods)),
        ("goal tolerance".into(), format!("{} m", sim.goal_tolerance)),
        ("sensor range".into(), format!("{} m", sim.sensor_range)),
        (
            "pedestrian history".into(),
            format!("{} positions", sim.history_len),
        ),
        (
            "time budget".into(),
            format!(
                "max(episode budget, {} × empty-world minimum time + {} s)",
                sim.budget_factor, sim.budget_margin
            ),
        ),
        ("start heading".into(), format!("{:?}", sim.start_heading)),
        ("pedestrian disc radius".into(), pedestrian_radius),
        (
            "collision".into(),
            "the robot's footprint (its URDF base collision seen from above; frame: base link) \
             overlaps a pedestrian disc, checked every step"
                .into(),
        ),
    ]
}

/// The simulation's replanning rate, then the methods that replan at another one.
fn replanning_rates(sim: &SimConfig, methods: &[MethodSpec]) -> String {
    let rate = |s: &SimConfig| format!("{} Hz (every {} steps)", s.replan_hz, s.replan_every());
    let mut text = rate(sim);
    let mut others: Vec<(String, Vec<&str>)> = Vec::new();
    for m in methods {
        let own = m.sim_config(sim);
        if own.replan_every() == sim.replan_every() {
            continue;
        }
        let r = rate(&own);
        match others.iter_mut().find(|(o, _)| *o == r) {
            Some((_, names)) => names.push(&m.name),
            None => others.push((r, vec![&m.name])),
        }
    }
    for (r, names) in others {
        text.push_str(&format!("; {}: {r}", names.join(", ")));
    }
    text
}

/// Up to `plan.failures` failed runs (collision or timeout) of each method on `suite`, drawn
/// four to a figure at their closest approach: [`failure_file`]. The failures shown
/// first are those the most other methods succeeded on (same episode and robot), which are the
/// ones that tell a method's weaknesses from a hard episode. Runs are deterministic, so each is
/// simply run again. Returns each figure's file name and caption.
fn failure_figures(
    plan: &BenchPlan<'_>,
    rows: &[ResultRow],
    suite: &Suite,
    out_dir: &Path,
) -> Result<Vec<(String, String)>, SimError> {
    let mut figures = Vec::new();
    if plan.failures == 0 {
        return Ok(figures);
    }
    let in_suite: Vec<&ResultRow> = rows.iter().filter(|r| r.suite == suite.name).collect();
    // Successes per (episode, robot) over all methods: a failed run's own method adds none.
    let mut successes: HashMap<(&str, &str), usize> = HashMap::new();
    for r in in_suite.iter().filter(|r| r.metrics.success) {
        *successes.entry((&r.episode, &r.robot)).or_default() += 1;
    }
    for method in plan.methods.iter().filter(|m| suite.runs(&m.name)) {
        let mut failed: Vec<(usize, &ResultRow)> = in_suite
            .iter()
            .filter(|r| r.method == method.name && !r.metrics.success)
            .map(|r| {
                let others = successes
                    .get(&(r.episode.as_str(), r.robot.as_str()))
                    .copied()
                    .unwrap_or(0);
                (others, *r)
            })
            .collect();
        // Stable: among equals, the suite's episode order.
        failed.sort_by_key(|f| std::cmp::Reverse(f.0));
        failed.truncate(plan.failures);
        let mut snaps = Vec::new();
        let mut names = Vec::new();
        for (others, row) in &failed {
            let (Some(episode), Some(robot)) = (
                suite.episodes.iter().find(|e| e.id == row.episode),
                plan.robots.iter().find(|r| r.name == row.robot),
            ) else {
                continue;
            };
            let snap = rerun(plan, suite, episode, robot, method)?;
            names.push(format!(
                "`{}` on {} ({}; {others} other method(s) succeeded)",
                episode.id,
                robot.name,
                snap.run.outcome.as_str()
            ));
            snaps.push(snap);
        }
        for (k, (chunk, names)) in snaps.chunks(4).zip(names.chunks(4)).enumerate() {
            let file = failure_file(&suite.name, &method.name, k + 1);
            figures::trajectory_snapshots(&out_dir.join(&file), chunk)?;
            figures.push((
                file,
                format!(
                    "failed runs of `{}` on suite `{}` at their closest approach, panels left to \
                     right, top to bottom: {}",
                    method.name,
                    suite.name,
                    names.join("; ")
                ),
            ));
        }
    }
    Ok(figures)
}

/// Runs one episode again (runs are deterministic) and keeps it for drawing.
fn rerun(
    plan: &BenchPlan<'_>,
    suite: &Suite,
    episode: &Episode,
    robot: &RobotSetup,
    method: &MethodSpec,
) -> Result<Snapshot, SimError> {
    let (run, _) = run_one(suite, episode, robot, method, plan.sim, plan.seed)?;
    Ok(Snapshot {
        episode: episode.clone(),
        run,
        robot: robot.name.clone(),
        method: method.name.clone(),
        footprint_radius: robot.footprint_radius,
        footprint: robot.footprint.clone(),
        bev: BevSpec::default(),
        sensor_range: plan.sim.sensor_range,
        history_len: plan.sim.history_len,
    })
}

/// `name` with every character that is not ASCII alphanumeric, `-` or `_` replaced by `_`.
fn file_safe(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// The file of a suite's Fig. 4: `fig4_snapshots_<suite>.png` (the suite name made file-safe
/// as in [`suite_figure_files`]).
pub fn fig4_file(suite: &str) -> String {
    format!("fig4_snapshots_{}.png", file_safe(suite))
}

/// The file of the `k`-th (from 1) failure figure of `method` on `suite`:
/// `failures_<suite>_<method>_<k>.png`.
pub fn failure_file(suite: &str, method: &str, k: usize) -> String {
    format!(
        "failures_{}_{}_{k}.png",
        file_safe(suite),
        file_safe(method)
    )
}

/// The files of Fig. 6, Fig. 7 and the SR-against-density figure of a suite:
/// `fig6_sr_per_scenario_<suite>.png`, `fig7_tfs_sr_per_robot_<suite>.png`,
/// `fig_sr_density_<suite>.png` (the suite name with every character other than ASCII
/// letters, digits, `-` and `_` replaced by `_`).
pub fn suite_figure_files(suite: &str) -> [String; 3] {
    let s = file_safe(suite);
    [
        format!("fig6_sr_per_scenario_{s}.png"),
        format!("fig7_tfs_sr_per_robot_{s}.png"),
        format!("fig_sr_density_{s}.png"),
    ]
}

/// Fig. 4: for each scenario class, the first episode of `suite` (in suite order) on which the
/// snapshot method succeeded on the first robot, run again and kept for drawing; with the
/// figure's caption. A class without such a success has no panel (the caption says so);
/// `None` when no class has one.
fn representative_snapshots(
    plan: &BenchPlan<'_>,
    suite: &Suite,
    rows: &[ResultRow],
) -> Result<Option<(Vec<Snapshot>, String)>, SimError> {
    let Some(robot) = plan.robots.first() else {
        return Ok(None);
    };
    let method = plan
        .snapshot_method
        .and_then(|name| plan.methods.iter().find(|m| m.name == name))
        .or_else(|| plan.methods.first());
    let Some(method) = method else {
        return Ok(None);
    };
    let succeeded: HashSet<&str> = rows
        .iter()
        .filter(|r| {
            r.suite == suite.name
                && r.robot == robot.name
                && r.method == method.name
                && r.metrics.success
        })
        .map(|r| r.episode.as_str())
        .collect();
    let mut snaps = Vec::new();
    let mut ids = Vec::new();
    let mut missing = Vec::new();
    for c in ScenarioClass::ALL {
        match suite
            .episodes
            .iter()
            .find(|e| e.scenario == c && succeeded.contains(e.id.as_str()))
        {
            Some(ep) => {
                snaps.push(rerun(plan, suite, ep, robot, method)?);
                ids.push(format!("{} `{}`", c.title(), ep.id));
            }
            None => missing.push(c.title()),
        }
    }
    if snaps.is_empty() {
        return Ok(None);
    }
    let bev = BevSpec::default();
    let mut caption = format!(
        "Fig. 4: suite `{}`, `{}` on {}: for each scenario class the first episode of the suite \
         on which it succeeded ({}), at the moment of closest approach to a pedestrian. \
         Pedestrians grey with their last positions and 0.6 s velocity arrows; robot red (path \
         so far solid, the rest faint; footprint filled, the planners' covering disc outlined, \
         heading black); the plan it was following orange; start green star, goal blue star. \
         Inset: the robot-centred BEV raster ({n} × {n} cells of {res:.2} m, forward up) the \
         drawn plan was made from; occupied cells coloured by the direction of the pedestrian's \
         velocity (hue wheel in its corner) and its speed (saturation; dark grey: standing), \
         black arrows 0.6 s of velocity",
        suite.name,
        method.name,
        robot.name,
        ids.join(", "),
        n = bev.cells,
        res = bev.resolution,
    );
    if !missing.is_empty() {
        caption.push_str(&format!(
            ". No successful run, so no panel, for: {}",
            missing.join(", ")
        ));
    }
    Ok(Some((snaps, caption)))
}
