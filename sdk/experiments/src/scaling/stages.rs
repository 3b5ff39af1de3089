//! The two stages of each fraction, training its model and running its closed loop, each
//! skipped when a stamp shows its result was already produced with the same settings.

use super::{FractionResult, METHOD, Setup, fraction_name, say};
use crate::bench::human2nav_method;
use crate::train::{self, TrainConfig};
use anyhow::Context;
use human2nav_data::tuples::Split;
use human2nav_flow::card::ModelCard;
use human2nav_flow::model::{CARD_FILE, WEIGHTS_FILE};
use human2nav_flow::train::TrainOptions;
use human2nav_flow::{NetConfig, tch};
use human2nav_sim::config::{BenchConfig, MethodConfig};
use human2nav_sim::report::{results_csv, summarize};
use human2nav_sim::{ResultRow, RobotSetup, SimConfig, Suite, run_bench};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// File in a model folder recording the settings it was trained with.
const STAMP_FILE: &str = "scaling_stamp.toml";

/// File in a fraction's folder with its closed-loop rows and what they were measured with.
const CLOSED_LOOP_FILE: &str = "closed_loop.toml";

/// What a model folder was trained with; a folder whose stamp equals the current one is
/// complete and reused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Stamp {
    fraction: f64,
    /// The tuple cache trained on.
    cache: String,
    net: NetConfig,
    train: TrainOptions,
}

/// What a fraction's closed-loop rows were measured with; rows stored with an equal stamp are
/// reused instead of running the episodes again.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClosedLoopStamp {
    model: Stamp,
    /// The planner configuration with this fraction's model.
    planner: toml::Table,
    suite: String,
    /// Episode ids, in order.
    episodes: Vec<String>,
    /// Each robot's name, footprint and limits.
    robots: Vec<String>,
    sim: SimConfig,
    seed: u64,
}

/// Contents of [`CLOSED_LOOP_FILE`].
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClosedLoopFile {
    stamp: ClosedLoopStamp,
    rows: Vec<ResultRow>,
}

/// The stored rows of `path` when they were measured with `stamp`.
fn stored_rows(path: &Path, stamp: &ClosedLoopStamp) -> Option<Vec<ResultRow>> {
    let text = std::fs::read_to_string(path).ok()?;
    let file: ClosedLoopFile = toml::from_str(&text).ok()?;
    (file.stamp == *stamp).then_some(file.rows)
}

/// The parts of a training checkpoint's `state.toml` that decide whether it can be resumed.
#[derive(Debug, Deserialize)]
struct CheckpointHead {
    step: u64,
    net: NetConfig,
    options: TrainOptions,
}

/// Whether a checkpoint in `ckpt` must be discarded: it is ahead of the requested steps or
/// was trained with other settings (a resume would fail or export the wrong model).
fn stale_checkpoint(ckpt: &Path, net: &NetConfig, opts: &TrainOptions) -> Option<String> {
    let path = ckpt.join("state.toml");
    let text = std::fs::read_to_string(&path).ok()?;
    let head: CheckpointHead = match toml::from_str(&text) {
        Ok(h) => h,
        Err(e) => return Some(format!("{} is unreadable ({e})", path.display())),
    };
    let mut same = head.options.clone();
    same.steps = opts.steps;
    if head.step > opts.steps {
        Some(format!(
            "{} is at step {}, beyond the requested {}",
            path.display(),
            head.step,
            opts.steps
        ))
    } else if same != *opts || head.net != *net {
        Some(format!("{} has other settings", path.display()))
    } else {
        None
    }
}

/// A fraction's model after its training stage.
pub(super) struct TrainedModel {
    name: String,
    model_dir: PathBuf,
    scenes: Vec<String>,
    recorded_hours: f64,
    stamp: Stamp,
    /// The model folder was complete and reused.
    complete: bool,
    train_stage_s: f64,
    card: ModelCard,
}

impl Setup {
    /// Trains the model of `fraction` into `models/<name>`, unless that folder is complete
    /// with an equal stamp; a stale checkpoint is discarded first.
    pub(super) fn train_stage(
        &self,
        fraction: f64,
        multi: &MultiProgress,
        stages: &ProgressBar,
    ) -> anyhow::Result<TrainedModel> {
        let tr = &self.train;
        let manifest = tr.cache.manifest();
        let name = fraction_name(fraction);
        let model_dir = self.models.join("models").join(&name);
        let run_dir = self.models.join("train").join(&name);
        let picked = tr
            .cache
            .pick_scenes(Split::Train, fraction, tr.cfg.train.seed)?;
        let scenes: Vec<String> = picked
            .iter()
            .map(|&i| manifest.scenes[i as usize].name.clone())
            .collect();
        let recorded_hours = picked
            .iter()
            .map(|&i| manifest.scenes[i as usize].duration)
            .sum::<f64>()
            / 3600.0;

        stages.set_message(format!("training {name} ({} scenes)", scenes.len()));
        let stamp = Stamp {
            fraction,
            cache: tr.cache_dir.display().to_string(),
            net: tr.cfg.net.clone(),
            train: tr.cfg.train.clone(),
        };
        let stamp_path = model_dir.join(STAMP_FILE);
        let complete = model_dir.join(CARD_FILE).is_file()
            && model_dir.join(WEIGHTS_FILE).is_file()
            && std::fs::read_to_string(&stamp_path)
                .ok()
                .and_then(|t| toml::from_str::<Stamp>(&t).ok())
                .is_some_and(|s| s == stamp);
        let t0 = Instant::now();
        if complete {
            say(
                multi,
                format!("{name}: model {} is complete, reused", model_dir.display()),
            );
        } else {
            let ckpt = run_dir.join("checkpoint");
            let stale = stale_checkpoint(&ckpt, &tr.cfg.net, &tr.cfg.train);
            if let Some(why) = &stale {
                say(multi, format!("{name}: training afresh: {why}"));
            }
            let _ = std::fs::remove_file(&stamp_path);
            let _ = std::fs::remove_file(self.out.join(&name).join(CLOSED_LOOP_FILE));
            let fcfg = self.fraction_train_config(fraction, &name);
            say(
                multi,
                format!(
                    "{name}: training {} steps on {} of {} training scenes into {}",
                    fcfg.train.steps,
                    scenes.len(),
                    manifest.scenes_in(Split::Train).len(),
                    model_dir.display()
                ),
            );
            tch::set_num_threads(fcfg.run.threads as i32);
            multi
                .suspend(|| {
                    train::train(
                        &fcfg,
                        &tr.cache,
                        &run_dir,
                        &model_dir,
                        tr.device,
                        stale.is_some(),
                    )
                })
                .with_context(|| format!("training {name}"))?;
            let stamp_text = toml::to_string(&stamp).context("serialising the stamp")?;
            std::fs::write(&stamp_path, stamp_text)
                .with_context(|| format!("writing {}", stamp_path.display()))?;
        }
        let train_stage_s = t0.elapsed().as_secs_f64();
        let card = ModelCard::load(&model_dir.join(CARD_FILE))?;
        Ok(TrainedModel {
            name,
            model_dir,
            scenes,
            recorded_hours,
            stamp,
            complete,
            train_stage_s,
            card,
        })
    }

    /// The train config (with the scaling overrides of [`train_settings`](super::setup)) for
    /// the fraction `name`: its share of the training scenes and its own run name.
    fn fraction_train_config(&self, fraction: f64, name: &str) -> TrainConfig {
        let mut fcfg = self.train.cfg.clone();
        fcfg.data.train_fraction = fraction;
        fcfg.run.name = format!("{}-{name}", self.train.cfg.run.name);
        fcfg
    }

    /// Writes the fraction's planner config, runs its closed loop (unless the stored rows
    /// were measured with equal settings) and writes its `results.csv`.
    pub(super) fn closed_loop_stage(
        &self,
        fraction: f64,
        model: TrainedModel,
        multi: &MultiProgress,
        stages: &ProgressBar,
    ) -> anyhow::Result<FractionResult> {
        let name = &model.name;
        stages.set_message(format!(
            "closed loop {name} ({} episode runs)",
            self.suite.episodes.len() * self.robots.len()
        ));
        let t1 = Instant::now();
        let planner_dir = self.out.join(name);
        std::fs::create_dir_all(&planner_dir)
            .with_context(|| format!("creating {}", planner_dir.display()))?;
        let (fraction_planner, table) = self.write_planner(&planner_dir, fraction, &model)?;
        let cl_stamp = ClosedLoopStamp {
            model: model.stamp.clone(),
            planner: table,
            suite: self.suite.name.clone(),
            episodes: self.suite.episodes.iter().map(|e| e.id.clone()).collect(),
            robots: self
                .robots
                .iter()
                .map(|r| {
                    format!(
                        "{} (footprint {} m, {:?})",
                        r.name, r.footprint_radius, r.limits
                    )
                })
                .collect(),
            sim: self
                .bcfg
                .sim
                .with_replan_hz(human2nav_replan_hz(&self.bcfg)),
            seed: self.bcfg.seed,
        };
        let cl_path = planner_dir.join(CLOSED_LOOP_FILE);
        let (rows, measured) = match stored_rows(&cl_path, &cl_stamp) {
            Some(rows) => {
                say(
                    multi,
                    format!(
                        "{name}: closed-loop results in {} match these settings, reused",
                        cl_path.display()
                    ),
                );
                (rows, false)
            }
            None => {
                let rows = closed_loop(
                    &fraction_planner,
                    &self.bcfg,
                    &self.suite,
                    &self.robots,
                    multi,
                )?;
                let file = ClosedLoopFile {
                    stamp: cl_stamp,
                    rows,
                };
                let text = toml::to_string(&file).context("serialising the closed-loop rows")?;
                std::fs::write(&cl_path, text)
                    .with_context(|| format!("writing {}", cl_path.display()))?;
                (file.rows, true)
            }
        };
        let csv = planner_dir.join("results.csv");
        std::fs::write(&csv, results_csv(&rows))
            .with_context(|| format!("writing {}", csv.display()))?;
        let bench_stage_s = t1.elapsed().as_secs_f64();
        let s = summarize(&rows);
        say(
            multi,
            format!(
                "{name}: SR {:.3} ± {:.3} over {} episode runs ({:.0} s training stage, {:.0} s closed loop)",
                s.sr, s.sr_se, s.n, model.train_stage_s, bench_stage_s
            ),
        );
        let info = model.card.training.as_ref();
        Ok(FractionResult {
            fraction,
            train_tuples: info.map(|i| i.train_tuples).unwrap_or(0),
            steps: info.map(|i| i.steps).unwrap_or(0),
            final_val_loss: info.map(|i| i.final_val_loss).unwrap_or(f64::NAN),
            training_time_s: info.map(|i| i.wall_time_s).unwrap_or(f64::NAN),
            name: model.name,
            scenes: model.scenes,
            recorded_hours: model.recorded_hours,
            trained: !model.complete,
            measured,
            train_stage_s: model.train_stage_s,
            bench_stage_s,
            rows,
        })
    }

    /// Writes `planner_dir/planner.toml`: the planner config with the fraction's model;
    /// returns its path and table.
    fn write_planner(
        &self,
        planner_dir: &Path,
        fraction: f64,
        model: &TrainedModel,
    ) -> anyhow::Result<(PathBuf, toml::Table)> {
        let mut table = self.planner_table.clone();
        table.insert(
            "model".into(),
            toml::Value::String(model.model_dir.display().to_string()),
        );
        let fraction_planner = planner_dir.join("planner.toml");
        std::fs::write(
            &fraction_planner,
            format!(
                "# {} with the model trained on {:.0} % of the training scenes.\n{}",
                self.planner_path.display(),
                100.0 * fraction,
                toml::to_string(&table).context("serialising the planner config")?
            ),
        )
        .with_context(|| format!("writing {}", fraction_planner.display()))?;
        Ok((fraction_planner, table))
    }
}

/// The replanning rate of the bench config's first `human2nav` method (the guided one), which
/// the scaling runs share.
fn human2nav_replan_hz(bcfg: &BenchConfig) -> Option<f64> {
    bcfg.methods
        .iter()
        .find(|m| m.kind == "human2nav")
        .and_then(|m| m.replan_hz)
}

/// Runs Human2Nav with guidance (the planner config at `planner`) on every episode of `suite`
/// for every robot, in parallel; rows in job order.
fn closed_loop(
    planner: &Path,
    bcfg: &BenchConfig,
    suite: &Suite,
    robots: &[RobotSetup],
    multi: &MultiProgress,
) -> anyhow::Result<Vec<ResultRow>> {
    let mut method_table = toml::Table::new();
    method_table.insert(
        "planner".into(),
        toml::Value::String(planner.display().to_string()),
    );
    let method = human2nav_method(
        &MethodConfig {
            name: METHOD.into(),
            kind: "human2nav".into(),
            library: None,
            plugin: None,
            config: method_table,
            replan_hz: human2nav_replan_hz(bcfg),
            deadline_ms: None,
            isolation: Default::default(),
        },
        bcfg,
    )?;
    let bar = multi.add(ProgressBar::new(0));
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} episode runs  ETA {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let rows = run_bench(
        std::slice::from_ref(suite),
        robots,
        std::slice::from_ref(&method),
        &bcfg.sim,
        bcfg.seed,
        &bar,
    );
    bar.finish_and_clear();
    multi.remove(&bar);
    Ok(rows?)
}
