//! What a scaling run writes at the end: the figure, `scaling.csv` (one row per fraction) and
//! `report.md` (settings, SR per fraction, class and robot, models and wall times).

use super::{FractionResult, METHOD, ScalingOutcome, ScalingRequest, Setup};
use anyhow::Context;
use human2nav_data::tuples::Split;
use human2nav_sim::episode::{ScenarioClass, ScenarioTitle};
use human2nav_sim::figures::{scaling_points, sr_vs_training_data};
use human2nav_sim::report::summarize;
use human2nav_sim::{ResultRow, RobotSetup};
use std::fmt::Write as _;
use std::time::Instant;

impl Setup {
    /// Writes the figure, `scaling.csv` and `report.md`.
    pub(super) fn write_outputs(
        &self,
        request: &ScalingRequest,
        results: Vec<FractionResult>,
        started: Instant,
    ) -> anyhow::Result<ScalingOutcome> {
        let runs: Vec<(f64, Vec<ResultRow>)> = results
            .iter()
            .map(|r| (r.recorded_hours, r.rows.clone()))
            .collect();
        let points = scaling_points(&runs, &self.suite.name, METHOD);
        let png = self.out.join("fig5_sr_vs_training_data.png");
        sr_vs_training_data(
            &png,
            &points,
            &format!(
                "Human2Nav (guided): SR against training data, suite `{}`",
                self.suite.name
            ),
        )?;
        let csv = self.out.join("scaling.csv");
        std::fs::write(&csv, scaling_csv(&results))
            .with_context(|| format!("writing {}", csv.display()))?;
        let report = self.out.join("report.md");
        std::fs::write(
            &report,
            report_markdown(
                &results,
                &self.settings(request),
                &self.robots,
                request.quick,
                started.elapsed().as_secs_f64(),
            ),
        )
        .with_context(|| format!("writing {}", report.display()))?;
        Ok(ScalingOutcome {
            fractions: results,
            report,
            csv,
            figure: png,
            wall_time_s: started.elapsed().as_secs_f64(),
        })
    }

    /// The report's settings table.
    fn settings(&self, request: &ScalingRequest) -> Vec<(String, String)> {
        let tr = &self.train;
        let manifest = tr.cache.manifest();
        let (suite, bcfg) = (&self.suite, &self.bcfg);
        vec![
            ("command".to_string(), format!("`{}`", request.command())),
            ("train config".into(), format!("`{}`", tr.path.display())),
            (
                "tuple cache".into(),
                format!(
                    "`{}` ({} data, {} training scenes)",
                    tr.cache_dir.display(),
                    manifest.source,
                    manifest.scenes_in(Split::Train).len()
                ),
            ),
            (
                "training".into(),
                format!(
                    "{} steps of batch {} per model, seed {} (scene choice and training), {} torch thread(s), device {:?}",
                    tr.cfg.train.steps,
                    tr.cfg.train.batch_size,
                    tr.cfg.train.seed,
                    tr.cfg.run.threads,
                    tr.device
                ),
            ),
            (
                "bench config".into(),
                format!("`{}`", self.bench_path.display()),
            ),
            (
                "suite".into(),
                format!(
                    "`{}` ({}), {} episodes, up to {} per scenario class{}",
                    suite.name,
                    suite.kind.as_str(),
                    suite.episodes.len(),
                    self.per_class,
                    suite
                        .note
                        .as_ref()
                        .map(|n| format!(": {n}"))
                        .unwrap_or_default()
                ),
            ),
            (
                "robots".into(),
                self.robots
                    .iter()
                    .map(|r| format!("`{}`", r.name))
                    .collect::<Vec<_>>()
                    .join(", "),
            ),
            (
                "method".into(),
                format!(
                    "Human2Nav with guidance: `{}` with `model` replaced per fraction",
                    self.planner_path.display()
                ),
            ),
            (
                "episode seed".into(),
                format!(
                    "{} (the bench config's; identical draws for every fraction)",
                    bcfg.seed
                ),
            ),
            (
                "simulation".into(),
                format!(
                    "step {} s, replanning {} Hz, goal tolerance {} m, budget max(episode budget, {} × empty-world time + {} s)",
                    bcfg.sim.dt,
                    bcfg.sim.replan_hz,
                    bcfg.sim.goal_tolerance,
                    bcfg.sim.budget_factor,
                    bcfg.sim.budget_margin
                ),
            ),
        ]
    }
}

/// `scaling.csv`: one row per fraction (SR overall and per scenario class, over every robot).
fn scaling_csv(results: &[FractionResult]) -> String {
    let mut out = String::from(
        "fraction,train_scenes,recorded_hours,train_tuples,steps,final_val_loss,episode_runs,sr,sr_se,\
         sr_co_flow,sr_cross_flow,sr_counter_flow,sr_multidirection_flow,tfs,collision_rate,\
         timeout_rate,model,closed_loop,training_time_s,train_stage_s,bench_stage_s\n",
    );
    for r in results {
        let s = summarize(&r.rows);
        let class_sr: Vec<String> = ScenarioClass::ALL
            .iter()
            .map(|&c| {
                let cs = summarize(r.rows.iter().filter(|x| x.scenario == c));
                if cs.n > 0 {
                    format!("{:.6}", cs.sr)
                } else {
                    String::new()
                }
            })
            .collect();
        let _ = writeln!(
            out,
            "{},{},{:.4},{},{},{:.6},{},{:.6},{:.6},{},{:.6},{:.6},{:.6},{},{},{:.1},{:.1},{:.1}",
            r.fraction,
            r.scenes.len(),
            r.recorded_hours,
            r.train_tuples,
            r.steps,
            r.final_val_loss,
            s.n,
            s.sr,
            s.sr_se,
            class_sr.join(","),
            s.tfs,
            s.collision_rate,
            s.timeout_rate,
            if r.trained { "trained" } else { "reused" },
            if r.measured { "measured" } else { "reused" },
            r.training_time_s,
            r.train_stage_s,
            r.bench_stage_s
        );
    }
    out
}

/// A share as a percentage with one decimal.
fn pct(v: f64) -> String {
    format!("{:.1}", 100.0 * v)
}

/// `report.md`: settings, the SR table per fraction (overall with its standard error, per
/// scenario class, per robot), the training record and the wall time of every stage.
fn report_markdown(
    results: &[FractionResult],
    settings: &[(String, String)],
    robots: &[RobotSetup],
    quick: bool,
    wall_s: f64,
) -> String {
    let mut md = String::new();
    report_intro(&mut md, settings, quick, wall_s);
    sr_table(&mut md, results);
    if robots.len() > 1 {
        robot_table(&mut md, results, robots);
    }
    models_table(&mut md, results);
    md
}

/// The report's title, what it measures, its wall time and the settings table.
fn report_intro(md: &mut String, settings: &[(String, String)], quick: bool, wall_s: f64) {
    let _ = writeln!(
        md,
        "# Success rate against the amount of human training data (paper Fig. 5)\n"
    );
    let _ = writeln!(
        md,
        "The flow model is retrained on each share of the training scenes (a seeded choice; the \
         smaller subsets are contained in the larger ones) and Human2Nav with guidance runs closed \
         loop on the same episodes. SR = success rate (goal reached within the time budget without \
         collision), in %; ± is the standard error sqrt(SR(1 − SR)/n).{}\n",
        if quick {
            " **Quick mode**: short trainings and a few episodes per class; the numbers only show \
             that the pipeline works."
        } else {
            ""
        }
    );
    let _ = writeln!(
        md,
        "Total wall time: {wall_s:.1} s. Figure: [fig5_sr_vs_training_data.png](fig5_sr_vs_training_data.png); \
         one row per fraction in [scaling.csv](scaling.csv); per-episode rows in `frac-<pct>/results.csv`.\n"
    );
    let _ = writeln!(md, "## Settings\n\n| setting | value |\n|---|---|");
    for (k, v) in settings {
        let _ = writeln!(md, "| {k} | {} |", v.replace('|', "\\|"));
    }
}

/// SR per fraction: overall with its standard error, per scenario class, TFS and the failure
/// rates.
fn sr_table(md: &mut String, results: &[FractionResult]) {
    let _ = writeln!(md, "\n## SR per fraction of the training scenes\n");
    let mut header =
        String::from("| training data | recorded hours | scenes | tuples | n | SR (%) |");
    let mut rule = String::from("|---|---|---|---|---|---|");
    for c in ScenarioClass::ALL {
        let _ = write!(header, " {} (%) |", c.title());
        rule.push_str("---|");
    }
    header.push_str(" TFS | collision (%) | timeout (%) |");
    rule.push_str("---|---|---|");
    let _ = writeln!(md, "{header}\n{rule}");
    for r in results {
        let s = summarize(&r.rows);
        let mut line = format!(
            "| {:.0} % | {:.2} | {} | {} | {} | {} ± {} |",
            100.0 * r.fraction,
            r.recorded_hours,
            r.scenes.len(),
            r.train_tuples,
            s.n,
            pct(s.sr),
            pct(s.sr_se)
        );
        for c in ScenarioClass::ALL {
            let cs = summarize(r.rows.iter().filter(|x| x.scenario == c));
            if cs.n > 0 {
                let _ = write!(line, " {} |", pct(cs.sr));
            } else {
                line.push_str(" – |");
            }
        }
        let _ = write!(
            line,
            " {:.3} | {} | {} |",
            s.tfs,
            pct(s.collision_rate),
            pct(s.timeout_rate)
        );
        let _ = writeln!(md, "{line}");
    }
}

/// SR per fraction and robot, with standard errors.
fn robot_table(md: &mut String, results: &[FractionResult], robots: &[RobotSetup]) {
    let _ = writeln!(md, "\n## SR per robot (%)\n");
    let mut header = String::from("| training data |");
    let mut rule = String::from("|---|");
    for r in robots {
        let _ = write!(header, " {} |", r.name);
        rule.push_str("---|");
    }
    let _ = writeln!(md, "{header}\n{rule}");
    for r in results {
        let mut line = format!("| {:.0} % |", 100.0 * r.fraction);
        for robot in robots {
            let s = summarize(r.rows.iter().filter(|x| x.robot == robot.name));
            let _ = write!(line, " {} ± {} |", pct(s.sr), pct(s.sr_se));
        }
        let _ = writeln!(md, "{line}");
    }
}

/// Each fraction's model, its training record and the wall time of both stages, then the
/// training scenes per fraction.
fn models_table(md: &mut String, results: &[FractionResult]) {
    let _ = writeln!(md, "\n## Models and wall time per stage\n");
    let _ = writeln!(
        md,
        "| training data | model | steps | final val loss | training time (card, s) | training stage (s) | closed-loop stage (s) |\n\
         |---|---|---|---|---|---|---|"
    );
    for r in results {
        let _ = writeln!(
            md,
            "| {:.0} % | `models/{}` ({}) | {} | {:.4} | {:.1} | {:.1} | {:.1}{} |",
            100.0 * r.fraction,
            r.name,
            if r.trained {
                "trained now"
            } else {
                "complete, reused"
            },
            r.steps,
            r.final_val_loss,
            r.training_time_s,
            r.train_stage_s,
            r.bench_stage_s,
            if r.measured {
                ""
            } else {
                " (stored rows reused)"
            }
        );
    }
    let _ = writeln!(md, "\nTraining scenes per fraction:\n");
    for r in results {
        let _ = writeln!(
            md,
            "- {:.0} % ({} scenes): {}",
            100.0 * r.fraction,
            r.scenes.len(),
            r.scenes.join(", ")
        );
    }
}
