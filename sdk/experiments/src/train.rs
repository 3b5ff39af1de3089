//! Training the conditional flow-matching model (`human2nav train`, and each fraction of the
//! scaling experiment): the `train.toml` settings, training on the tuple cache with checkpoints
//! and resume, export of the EMA weights with a model card and a loss curve, and the evaluation
//! on the held-out test scenes. Progress is drawn with indicatif and reported on stderr.

use anyhow::{Context, bail};
use human2nav_core::AgentState;
use human2nav_core::flow::CrowdGuidance;
use human2nav_core::forecast::constant_velocity_path;
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use human2nav_data::cache::TupleCache;
use human2nav_data::tuples::{CompactTuple, Split};
use human2nav_flow::card::{
    ComplexityInfo, CrowdProbeInfo, EarlyAde, EvaluationInfo, TrainingInfo,
};
use human2nav_flow::eval::{
    EvalOptions, EvalWindow, counterfactual_probe, crowd_probe, evaluate, meets,
};
use human2nav_flow::model::CARD_FILE;
use human2nav_flow::net::{Complexity, parameter_count};
use human2nav_flow::tch;
use human2nav_flow::train::{Counterfactual, TrainOptions, Trainer, TrainingSample};
use human2nav_flow::{CfmModel, NetConfig, Normalisation};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Where the data comes from.
#[derive(Clone, Debug, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DataSection {
    /// Tuple cache directory (from `human2nav data build`); relative paths start at the
    /// workspace root.
    pub cache: PathBuf,
    /// Fraction of the training scenes to use (seeded choice). Default 1.
    pub train_fraction: f64,
    /// How many times each *interacting* training window is used per epoch (1 to
    /// [`MAX_INTERACTION_REPEAT`]): a window where the walker, going on at its velocity, would
    /// come within [`INTERACTION_CONTACT`] of someone going on at theirs, where what the
    /// crowd does matters to where the walker goes. Default 1: every window once.
    pub interaction_repeat: usize,
}

/// Largest [`DataSection::interaction_repeat`].
pub const MAX_INTERACTION_REPEAT: usize = 100;

/// Distance between centres (m) at which two constant-velocity paths meet, for
/// [`DataSection::interaction_repeat`]: two pedestrian discs of 0.3 m touching.
pub const INTERACTION_CONTACT: f64 = 0.6;

impl Default for DataSection {
    fn default() -> Self {
        Self {
            cache: PathBuf::from("out/data/cache"),
            train_fraction: 1.0,
            interaction_repeat: 1,
        }
    }
}

/// Whether the walker of `t`, going on at its velocity, comes within `contact` of one of its
/// neighbours going on at theirs over its future's waypoints, `dt` apart.
pub fn interacting(t: &CompactTuple, dt: f64, contact: f64) -> bool {
    let walker = moving(
        [0.0, 0.0],
        [f64::from(t.velocity[0]), f64::from(t.velocity[1])],
    );
    let straight: Vec<f64> = constant_velocity_path(&walker, t.future.len(), dt)
        .into_iter()
        .flat_map(|[x, y]| [x, y, 0.0])
        .collect();
    meets(&straight, &neighbour_paths(t, dt), contact)
}

/// Someone at `position` with `velocity`, for a constant-velocity path.
fn moving(position: [f64; 2], velocity: [f64; 2]) -> AgentState {
    AgentState {
        id: 0,
        position,
        velocity,
        radius: 0.0,
        history: Vec::new(),
    }
}

/// The neighbours of `t` going on at their velocity, over its future's waypoints, `dt` apart.
fn neighbour_paths(t: &CompactTuple, dt: f64) -> Vec<Vec<[f64; 2]>> {
    t.agents
        .iter()
        .map(|a| {
            let agent = moving(
                [f64::from(a[0]), f64::from(a[1])],
                [f64::from(a[2]), f64::from(a[3])],
            );
            constant_velocity_path(&agent, t.future.len(), dt)
        })
        .collect()
}

/// Run bookkeeping.
#[derive(Clone, Debug, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunSection {
    /// Model name in the card.
    pub name: String,
    /// Checkpoints and logs. Default `out/train/<name>`.
    pub out_dir: Option<PathBuf>,
    /// Where the exported model goes. Default `models/<name>`.
    pub model_dir: Option<PathBuf>,
    /// Torch intra-op threads. Default 2.
    pub threads: usize,
    /// `auto` (CUDA when available), `cpu` or `cuda`.
    pub device: String,
    /// Steps between validation points. Default 250.
    pub validate_every: u64,
    /// Steps between checkpoints. Default 1000.
    pub checkpoint_every: u64,
    /// Stop (and checkpoint) after this many minutes of this invocation; 0 = no limit.
    pub max_minutes: f64,
}

impl Default for RunSection {
    fn default() -> Self {
        Self {
            name: "human2nav-cfm".into(),
            out_dir: None,
            model_dir: None,
            threads: 2,
            device: "auto".into(),
            validate_every: 250,
            checkpoint_every: 1000,
            max_minutes: 0.0,
        }
    }
}

/// Held-out evaluation.
#[derive(Clone, Debug, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalSection {
    /// Sampled futures per window `K`. Default 20.
    pub samples: usize,
    /// Euler steps `N`. Default 10.
    pub steps: usize,
    /// Proximity radius, metres. Default 0.3.
    pub radius: f64,
    /// Distance between centres (m) at which a sample meets someone in the crowd-awareness
    /// probe ([`human2nav_flow::eval::CrowdProbe`]): two pedestrian discs of the raster's
    /// 0.3 m touching. Default 0.6.
    pub contact: f64,
    /// Crowd-guidance weights the probe runs ([`human2nav_core::flow::CrowdGuidance`]; 1:
    /// the model as it is). Default `[1]`.
    pub crowd_weights: Vec<f64>,
    /// Also run [`human2nav_flow::eval::counterfactual_probe`]: a standing person placed on
    /// each window's constant-velocity line where the recorded future avoided it, the samples
    /// with and without that person in the raster, once per crowd weight. Default
    /// false.
    pub counterfactual_probe: bool,
    /// Split whose windows are evaluated: `test` (the default, and what a model card
    /// reports), `val` (to study settings without looking at the test scenes) or `train`.
    pub split: Split,
    /// Windows evaluated at most (seeded subsample). Default 2000.
    pub max_windows: usize,
    /// Seed of the subsample and of the source noise. Default 0.
    pub seed: u64,
    /// Data config used to rebuild the test scenes for the other agents' true futures
    /// (proximity metric). When the datasets are unavailable, the neighbours stored in the
    /// cache are extrapolated at constant velocity instead (noted in the card).
    pub data_config: PathBuf,
}

impl Default for EvalSection {
    fn default() -> Self {
        Self {
            samples: 20,
            steps: 10,
            radius: 0.3,
            contact: 0.6,
            crowd_weights: vec![1.0],
            counterfactual_probe: false,
            split: Split::Test,
            max_windows: 2000,
            seed: 0,
            data_config: PathBuf::from("sdk/configs/data.toml"),
        }
    }
}

/// The whole `train.toml`; every section defaults to the values documented on its fields.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Where the data comes from.
    pub data: DataSection,
    /// The network.
    pub net: NetConfig,
    /// The optimisation.
    pub train: TrainOptions,
    /// Run bookkeeping.
    pub run: RunSection,
    /// Held-out evaluation.
    pub eval: EvalSection,
}

impl TrainConfig {
    /// Reads and parses a `train.toml` (not validated: callers apply their overrides, then
    /// call [`Self::validate`]).
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = read_user_file(path, "configuration", MAX_CONFIG_BYTES)
            .with_context(|| format!("reading {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))
    }

    /// Checks every section; the error names the offending field.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.net.validate()?;
        self.train.validate()?;
        self.train.check_batch_size(&self.net)?;
        if !(1..=MAX_INTERACTION_REPEAT).contains(&self.data.interaction_repeat) {
            bail!(
                "data.interaction_repeat: {} is not in 1..={MAX_INTERACTION_REPEAT}",
                self.data.interaction_repeat
            );
        }
        let f = self.data.train_fraction;
        if !(f > 0.0 && f <= 1.0) {
            bail!("data.train_fraction must lie in (0, 1], got {f}");
        }
        let max = human2nav_flow::planner::MAX_THREADS;
        if !(1..=max).contains(&self.run.threads) {
            bail!("run.threads: {} is not in 1..={max}", self.run.threads);
        }
        if self.run.validate_every == 0 || self.run.checkpoint_every == 0 {
            bail!("run.validate_every and run.checkpoint_every must be positive");
        }
        if !matches!(self.run.device.as_str(), "auto" | "cpu" | "cuda") {
            bail!(
                "run.device must be auto, cpu or cuda, got `{}`",
                self.run.device
            );
        }
        if self.run.max_minutes.is_nan() || self.run.max_minutes < 0.0 {
            bail!("run.max_minutes must be >= 0");
        }
        if self.eval.samples == 0
            || self.eval.steps == 0
            || self.eval.radius.is_nan()
            || self.eval.radius <= 0.0
            || !(self.eval.contact.is_finite() && self.eval.contact > 0.0)
        {
            bail!(
                "eval.samples, eval.steps, eval.radius and eval.contact must be positive and finite"
            );
        }
        if let Some(w) = self
            .eval
            .crowd_weights
            .iter()
            .find(|w| !(w.is_finite() && **w >= 0.0))
        {
            bail!("eval.crowd_weights: {w} must be finite and >= 0");
        }
        if self.eval.crowd_weights.len() > 16 {
            bail!("eval.crowd_weights: at most 16 weights (each is a pass over the windows)");
        }
        Ok(())
    }
}

/// `p` itself when absolute, else `p` under `root`.
fn resolve(root: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        root.join(p)
    }
}

/// The names of the cache's scenes of `split`, comma-separated.
fn scene_names(cache: &TupleCache, split: Split) -> String {
    let m = cache.manifest();
    let names: Vec<&str> = m
        .scenes_in(split)
        .iter()
        .map(|&i| m.scenes[i as usize].name.as_str())
        .collect();
    names.join(", ")
}

/// The tuples a run of `cfg` trains on (its share of the training scenes); an empty split is
/// an error naming the cache.
fn training_tuples(
    cfg: &TrainConfig,
    cache: &TupleCache,
) -> anyhow::Result<Vec<human2nav_data::tuples::TrainingTuple>> {
    let repeat = cfg.data.interaction_repeat;
    if repeat == 1 {
        let train_set = cache.load_scenes(Split::Train, cfg.data.train_fraction, cfg.train.seed)?;
        if train_set.is_empty() {
            bail!("the training split of {} is empty", cache.dir().display());
        }
        return Ok(train_set);
    }
    let keep = cache.pick_scenes(Split::Train, cfg.data.train_fraction, cfg.train.seed)?;
    let (spec, dt) = (cache.manifest().bev, cache.manifest().dt);
    let compact: Vec<CompactTuple> = cache
        .load_compact(Split::Train)?
        .into_iter()
        .filter(|t| keep.binary_search(&t.scene).is_ok())
        .collect();
    if compact.is_empty() {
        bail!("the training split of {} is empty", cache.dir().display());
    }
    let mut train_set = Vec::with_capacity(compact.len());
    let mut interactions = 0;
    for t in &compact {
        let copies = if interacting(t, dt, INTERACTION_CONTACT) {
            interactions += 1;
            repeat
        } else {
            1
        };
        let tuple = t.to_tuple(&spec);
        train_set.extend(std::iter::repeat_n(tuple, copies));
    }
    eprintln!(
        "{interactions} of {} training windows interact (a walker going on at its velocity \
         meets someone going on at theirs); each is used {repeat} times",
        compact.len()
    );
    Ok(train_set)
}

/// Trains (or resumes from `out_dir/checkpoint`) and exports the EMA model with its card.
pub fn train(
    cfg: &TrainConfig,
    cache: &TupleCache,
    out_dir: &Path,
    model_dir: &Path,
    device: tch::Device,
    fresh: bool,
) -> anyhow::Result<()> {
    let load_start = Instant::now();
    let train_set = training_tuples(cfg, cache)?;
    let val_set = cache.load(Split::Val)?;
    eprintln!(
        "loaded {} training and {} validation tuples in {:.1} s",
        train_set.len(),
        val_set.len(),
        load_start.elapsed().as_secs_f64()
    );
    if let Some(c) = &cfg.train.counterfactual {
        // A standing person, wherever one fits: the windows the augmentation can touch.
        let fits = train_set
            .iter()
            .filter(|t| {
                let future: Vec<_> = (0..t.future_len()).map(|j| t.future_pose(j)).collect();
                c.place(&future, t.velocity(), [0.5, 0.0, 0.0]).is_some()
            })
            .count();
        eprintln!(
            "counterfactual walkers: a standing person fits in {fits} of {} training windows \
             ({:.1} %); probability {} each time one is drawn",
            train_set.len(),
            100.0 * fits as f64 / train_set.len().max(1) as f64,
            c.probability
        );
    }

    let ckpt = out_dir.join("checkpoint");
    let resume_from = if fresh {
        None
    } else {
        human2nav_flow::train::find_checkpoint(&ckpt)?
    };
    let mut trainer = if let Some(set) = resume_from {
        eprintln!("resuming from {}", set.display());
        Trainer::resume(&set, &cfg.train, &train_set, &val_set, device)?
    } else {
        let norm = Normalisation::estimate(&train_set, cfg.train.seed)?;
        let trainer = Trainer::new(&cfg.net, &norm, &cfg.train, &train_set, &val_set, device)?;
        // The trainer's copy: `train.goal` and `train.velocity` decide what the network sees.
        eprintln!("normalisation: {:?}", trainer.model().card().normalisation);
        trainer
    };

    let capped = train_steps(cfg, &mut trainer, out_dir, &ckpt)?;
    if capped {
        if trainer.history().last().map(|r| r.step) != Some(trainer.step()) {
            trainer.record();
        }
        trainer.save_checkpoint(&ckpt)?;
        eprintln!(
            "stopped at step {} after run.max_minutes = {}; run again to resume",
            trainer.step(),
            cfg.run.max_minutes
        );
    }
    export(
        cfg,
        cache,
        &trainer,
        model_dir,
        train_set.len(),
        val_set.len(),
    )?;
    Ok(())
}

/// Per-step wall times of `human2nav train --bench-steps`, milliseconds, one entry per timed
/// step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepBench {
    /// Whole steps (batch building included).
    pub step_ms: Vec<f64>,
    /// Batch indices and batch building.
    pub batch_ms: Vec<f64>,
    /// Forward pass and loss.
    pub forward_ms: Vec<f64>,
    /// Backward pass.
    pub backward_ms: Vec<f64>,
    /// Gradient clipping, AdamW and the EMA.
    pub update_ms: Vec<f64>,
}

/// Times `steps` training steps of a fresh run of `cfg` on the cache's training split (the
/// tuples `human2nav train` trains on, normalisation estimated the same way), after `warmup`
/// untimed steps: [`Trainer::train_step_timed`] at `train.batch_size` with the torch threads
/// already set by the caller, batch building included. Nothing is written (no checkpoint, no
/// model); a throughput measurement, comparable with `sdk/flow/reference/torch_train_step.py
/// --bench`.
pub fn bench_train_steps(
    cfg: &TrainConfig,
    cache: &TupleCache,
    device: tch::Device,
    steps: usize,
    warmup: usize,
) -> anyhow::Result<StepBench> {
    let load_start = Instant::now();
    let train_set = training_tuples(cfg, cache)?;
    eprintln!(
        "loaded {} training tuples in {:.1} s",
        train_set.len(),
        load_start.elapsed().as_secs_f64()
    );
    let norm = Normalisation::estimate(&train_set, cfg.train.seed)?;
    let no_val: &[human2nav_data::tuples::TrainingTuple] = &[];
    let mut trainer = Trainer::new(&cfg.net, &norm, &cfg.train, &train_set, no_val, device)?;
    for _ in 0..warmup {
        trainer.train_step()?;
    }
    let mut bench = StepBench::default();
    let ms = |s: f64| s * 1e3;
    for _ in 0..steps {
        let t = trainer.train_step_timed()?;
        bench.step_ms.push(ms(t.total_s()));
        bench.batch_ms.push(ms(t.batch_s));
        bench.forward_ms.push(ms(t.forward_s));
        bench.backward_ms.push(ms(t.backward_s));
        bench.update_ms.push(ms(t.update_s));
    }
    Ok(bench)
}

/// Steps `trainer` to its total under a progress bar, validating, checkpointing into `ckpt` and
/// redrawing `out_dir/loss_curve.png` at the configured intervals; returns whether
/// `run.max_minutes` stopped it early.
fn train_steps<S: human2nav_flow::train::TrainingSample>(
    cfg: &TrainConfig,
    trainer: &mut Trainer<'_, S>,
    out_dir: &Path,
    ckpt: &Path,
) -> anyhow::Result<bool> {
    let total = trainer.total_steps();
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{wide_bar}] {pos}/{len} steps  ETA {eta_precise}  {msg}",
        )?
        .progress_chars("=> "),
    );
    bar.set_position(trainer.step());
    let started = Instant::now();
    let cap =
        (cfg.run.max_minutes > 0.0).then(|| Duration::from_secs_f64(cfg.run.max_minutes * 60.0));
    let batch = cfg.train.batch_size as f64;
    let mut window_start = Instant::now();
    let mut window_steps = 0u64;
    let mut last_val = f64::NAN;
    let mut tick = Instant::now();
    let mut capped = false;
    while trainer.step() < total {
        trainer.train_step()?;
        let now = Instant::now();
        trainer.add_elapsed(now.duration_since(tick).as_secs_f64());
        tick = now;
        window_steps += 1;
        let step = trainer.step();
        bar.set_position(step);
        if step % 10 == 0 || step == total {
            let rate = window_steps as f64 * batch / window_start.elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!(
                "loss {:.4}  val {:.4}  {:.0} samples/s",
                trainer.running_loss(),
                last_val,
                rate
            ));
        }
        if step % cfg.run.validate_every == 0 || step == total {
            let rec = trainer.record();
            last_val = rec.val_loss;
            let line = format!(
                "step {:>6}  train {:.4}  val {:.4}  lr {:.2e}  {:.0} samples/s  {:.0} s",
                rec.step,
                rec.train_loss,
                rec.val_loss,
                rec.lr,
                window_steps as f64 * batch / window_start.elapsed().as_secs_f64().max(1e-9),
                rec.elapsed_s
            );
            // A hidden bar (no terminal, e.g. a log file) swallows println.
            if bar.is_hidden() {
                eprintln!("{line}")
            } else {
                bar.println(line)
            }
            window_start = Instant::now();
            window_steps = 0;
            tick = Instant::now();
        }
        if step % cfg.run.checkpoint_every == 0 || step == total {
            checkpoint(cfg, trainer, out_dir, ckpt)?;
            tick = Instant::now();
        }
        if cap.is_some_and(|c| started.elapsed() >= c) {
            capped = true;
            break;
        }
    }
    bar.finish();
    Ok(capped)
}

/// Saves the checkpoint into `ckpt` and, once a loss is finite, redraws the loss curve.
fn checkpoint<S: human2nav_flow::train::TrainingSample>(
    cfg: &TrainConfig,
    trainer: &Trainer<'_, S>,
    out_dir: &Path,
    ckpt: &Path,
) -> anyhow::Result<()> {
    trainer.save_checkpoint(ckpt)?;
    if trainer
        .history()
        .iter()
        .any(|r| r.val_loss.is_finite() || r.train_loss.is_finite())
    {
        let _ = human2nav_flow::plot::loss_curve(
            &out_dir.join("loss_curve.png"),
            trainer.history(),
            &format!("{}: conditional flow matching on SE(2)", cfg.run.name),
        );
    }
    Ok(())
}

/// Writes the exported model (EMA weights) and its card into `model_dir`.
fn export<S: human2nav_flow::train::TrainingSample>(
    cfg: &TrainConfig,
    cache: &TupleCache,
    trainer: &Trainer<'_, S>,
    model_dir: &Path,
    n_train: usize,
    n_val: usize,
) -> anyhow::Result<()> {
    let hist = trainer.history();
    let best_val = hist
        .iter()
        .map(|r| r.val_loss)
        .filter(|v| v.is_finite())
        .fold(f64::INFINITY, f64::min);
    let last = hist.last().copied();
    let steps = trainer.step();
    let wall = trainer.elapsed_s();
    let m = cache.manifest();
    let sources: std::collections::BTreeSet<&str> =
        m.scenes.iter().map(|s| s.dataset.as_str()).collect();
    let info = TrainingInfo {
        data: format!(
            "tuple cache `{}` ({} data: {}), BEV {}×{} cells of {} m, {} poses at {} s",
            cfg.data.cache.display(),
            m.source,
            sources.into_iter().collect::<Vec<_>>().join(", "),
            m.bev.cells,
            m.bev.cells,
            m.bev.resolution,
            m.horizon,
            m.dt
        ),
        split: format!(
            "by scene, as in the cache manifest; train fraction {}; train scenes: {}; val scenes: {}; test scenes: {}",
            cfg.data.train_fraction,
            scene_names(cache, Split::Train),
            scene_names(cache, Split::Val),
            scene_names(cache, Split::Test)
        ),
        train_tuples: n_train,
        val_tuples: n_val,
        steps,
        batch_size: cfg.train.batch_size,
        epochs: steps as f64 * cfg.train.batch_size as f64 / n_train.max(1) as f64,
        seed: cfg.train.seed,
        time_distribution: format!(
            "t = s·(1 − u), u ~ Beta({}, {}), s = {}",
            cfg.train.time.alpha, cfg.train.time.beta, cfg.train.time.s
        ),
        path_sigma: cfg.train.path_sigma,
        mirror: cfg.train.mirror,
        counterfactual: cfg.train.counterfactual.clone(),
        clearance: cfg.train.clearance.clone(),
        optimiser: cfg.train.describe_optimiser(),
        wall_time_s: wall,
        threads: cfg.run.threads,
        samples_per_s: steps as f64 * cfg.train.batch_size as f64 / wall.max(1e-9),
        final_val_loss: last.map(|r| r.val_loss).unwrap_or(f64::NAN),
        best_val_loss: best_val,
        final_train_loss: last.map(|r| r.train_loss).unwrap_or(f64::NAN),
    };
    // The EMA weights are what ships; copy them into a fresh model with the card filled in.
    let ema = trainer.ema_model();
    let tmp = model_dir.join(".export");
    ema.save(&tmp)?;
    let mut model = CfmModel::load(&tmp, tch::Device::Cpu)?;
    let _ = std::fs::remove_dir_all(&tmp);
    let card = model.card_mut();
    card.name = cfg.run.name.clone();
    card.description =
        "Conditional flow-matching model on SE(2) (Human2Nav §III-A): a 1-D temporal \
        U-Net with FiLM conditioning on an ego-centred BEV raster, the goal and the ego velocity, \
        predicting per-waypoint body velocities for 32 poses over 3.2 s. EMA weights."
            .into();
    card.training = Some(info);
    card.bev = Some(m.bev);
    card.source.steps = cfg.eval.steps;
    let cx = Complexity::of(&card.net);
    let params = parameter_count(model.var_store());
    let (checksum, bytes) = model.save(model_dir)?;
    model.card_mut().weights_fnv64 = Some(checksum);
    model.card_mut().complexity = Some(ComplexityInfo {
        parameters: params,
        unet_flops_per_trajectory: 2 * cx.unet_macs,
        condition_flops: 2 * cx.condition_macs,
        weights_bytes: bytes,
    });
    model.card().save(&model_dir.join(CARD_FILE))?;
    human2nav_flow::plot::loss_curve(
        &model_dir.join("loss_curve.png"),
        hist,
        &format!("{}: conditional flow matching on SE(2)", cfg.run.name),
    )?;
    eprintln!(
        "exported {} ({} parameters, {} bytes) to {}",
        cfg.run.name,
        params,
        bytes,
        model_dir.display()
    );
    Ok(())
}

/// The windows of `eval.split` with the other agents' true futures: the split's scenes are
/// rebuilt from the datasets with the data config and the cache's tuple options, and must
/// reproduce the cache's tuples of that split exactly (same count).
fn true_future_windows(
    cfg: &TrainConfig,
    cache: &TupleCache,
    root: &Path,
) -> anyhow::Result<Vec<EvalWindow>> {
    use human2nav_data::config::DataConfig;
    use human2nav_data::pipeline::{Locations, discover, load_source};
    use human2nav_data::resample::resample;
    let path = resolve(root, &cfg.eval.data_config);
    let dcfg = DataConfig::load(&path)?;
    let loc = Locations::resolve(&dcfg, &path);
    if !loc.data_root.is_dir() {
        bail!("datasets not found at {}", loc.data_root.display());
    }
    let m = cache.manifest();
    let (sources, _) = discover(&loc.data_root, &dcfg);
    let split = cfg.eval.split;
    let mut windows = Vec::new();
    for i in m.scenes_in(split) {
        let name = &m.scenes[i as usize].name;
        let src = sources.iter().find(|s| &s.name == name).with_context(|| {
            format!(
                "{} scene {name} not found under {}",
                split.name(),
                loc.data_root.display()
            )
        })?;
        let scene = resample(&load_source(src, &dcfg)?, &dcfg.resample);
        windows.extend(human2nav_flow::eval::scene_windows(
            &scene, i, &m.bev, &m.tuples,
        )?);
    }
    let expected = m.counts.get(&split).copied().unwrap_or(0);
    if windows.len() != expected {
        bail!(
            "rebuilt {} {} windows, the cache has {expected}",
            windows.len(),
            split.name()
        );
    }
    human2nav_flow::eval::subsample(&mut windows, cfg.eval.max_windows, cfg.eval.seed);
    Ok(windows)
}

/// The windows of `eval.split` from the cache alone, see [`cache_windows`].
fn split_windows(cfg: &TrainConfig, cache: &TupleCache) -> anyhow::Result<Vec<EvalWindow>> {
    cache_windows(cache, cfg.eval.split, cfg.eval.max_windows, cfg.eval.seed)
}

/// At most `max` windows of `split` (seeded subsample) from the cache alone: the cache stores
/// the other agents only at the planning instant, so their future positions are extrapolated
/// at constant velocity.
pub fn cache_windows(
    cache: &TupleCache,
    split: Split,
    max: usize,
    seed: u64,
) -> anyhow::Result<Vec<EvalWindow>> {
    let mut compact: Vec<CompactTuple> = cache.load_compact(split)?;
    human2nav_flow::eval::subsample(&mut compact, max, seed);
    let spec = cache.manifest().bev;
    let dt = cache.manifest().dt;
    Ok(compact
        .iter()
        .map(|c| {
            let t = c.to_tuple(&spec);
            let others_cv = neighbour_paths(c, dt);
            let others = others_cv
                .iter()
                .map(|path| path.iter().copied().map(Some).collect())
                .collect();
            EvalWindow::from_tuple(t, others, others_cv)
        })
        .collect())
}

/// Evaluates `model` on the windows of `eval.split`, the test split unless set (with the other
/// agents' true futures when the datasets are present, see `eval.data_config`, else
/// extrapolated from the cache), and returns the card's evaluation record; `root` resolves
/// `eval.data_config`.
pub fn run_evaluation(
    cfg: &TrainConfig,
    cache: &TupleCache,
    model: &CfmModel,
    root: &Path,
) -> anyhow::Result<EvaluationInfo> {
    let (windows, neighbours) = match true_future_windows(cfg, cache, root) {
        Ok(w) => (
            w,
            "other agents' true future positions, from the split's scenes rebuilt with the data \
             config (windows identical to the cache's tuples)",
        ),
        Err(e) => {
            eprintln!(
                "note: true neighbour futures unavailable ({e:#}); extrapolating the cache's"
            );
            (
                split_windows(cfg, cache)?,
                "other agents' future positions extrapolated at constant velocity from their \
                 state at the planning instant (the tuple cache stores neighbours only then)",
            )
        }
    };
    if windows.is_empty() {
        bail!(
            "the {} split of {} is empty",
            cfg.eval.split,
            cache.dir().display()
        );
    }
    let opts = EvalOptions {
        samples: cfg.eval.samples,
        steps: cfg.eval.steps,
        dt: cache.manifest().dt,
        radius: cfg.eval.radius,
        seed: cfg.eval.seed,
        ..EvalOptions::default()
    };
    let bar = ProgressBar::new(windows.len() as u64);
    bar.set_style(ProgressStyle::with_template(
        "evaluating [{wide_bar}] {pos}/{len} windows  ETA {eta}",
    )?);
    let m = evaluate(model, &windows, &opts, |i| bar.set_position(i as u64))?;
    bar.finish_and_clear();
    let mut probes = Vec::with_capacity(cfg.eval.crowd_weights.len());
    for &weight in &cfg.eval.crowd_weights {
        let bar = ProgressBar::new(windows.len() as u64);
        bar.set_style(ProgressStyle::with_template(&format!(
            "probing the crowd's effect, w = {weight} [{{wide_bar}}] {{pos}}/{{len}} windows  ETA {{eta}}"
        ))?);
        let guided = CrowdGuidance::new(model, weight)?;
        let probe = crowd_probe(&guided, &windows, &opts, cfg.eval.contact, |i| {
            bar.set_position(i as u64)
        })?;
        bar.finish_and_clear();
        probes.push((weight, probe));
    }
    if cfg.eval.counterfactual_probe {
        let person = Counterfactual {
            step: cache.manifest().dt,
            ..cfg.train.counterfactual.clone().unwrap_or_default()
        };
        let placing = (&person, cache.manifest().bev);
        for &weight in &cfg.eval.crowd_weights {
            let bar = ProgressBar::new(windows.len() as u64);
            bar.set_style(ProgressStyle::with_template(&format!(
                "probing a counterfactual person, w = {weight} [{{wide_bar}}] {{pos}}/{{len}} windows  ETA {{eta}}"
            ))?);
            let guided = CrowdGuidance::new(model, weight)?;
            let p =
                counterfactual_probe(&guided, &windows, &opts, placing, cfg.eval.contact, |i| {
                    bar.set_position(i as u64)
                })?;
            bar.finish_and_clear();
            eprintln!(
                "{}: counterfactual probe, w = {weight} (a standing person on the straight line, \
                 clear of the recorded future; {} of {} windows): samples meeting the person \
                 {:.3} seen / {:.3} unseen; {:.3} m apart",
                cfg.eval.split,
                p.windows,
                windows.len(),
                p.observed,
                p.hidden,
                p.displacement
            );
        }
    }
    let info = EvaluationInfo {
        protocol: format!(
            "{} windows drawn (seed {}) from the {} split ({}); {} samples per window, {} Euler steps; \
             best-of-{} ADE/FDE against the true 3.2 s future; constant velocity = ego velocity held",
            m.windows,
            cfg.eval.seed,
            cfg.eval.split,
            scene_names(cache, cfg.eval.split),
            opts.samples,
            opts.steps,
            opts.samples
        ),
        windows: m.windows,
        samples_per_window: opts.samples,
        steps: opts.steps,
        min_ade: m.min_ade,
        min_fde: m.min_fde,
        mean_ade: m.mean_ade,
        cv_ade: m.cv_ade,
        cv_fde: m.cv_fde,
        ade_improvement: 1.0 - m.min_ade / m.cv_ade,
        centroid_ade: Some(m.centroid_ade),
        early_ade: Some(EarlyAde {
            seconds: m.early_steps as f64 * opts.dt,
            mean: m.early_mean_ade,
            centroid: m.early_centroid_ade,
            constant_velocity: m.early_cv_ade,
        }),
        proximity_radius: opts.radius,
        proximity_model: m.proximity_model,
        proximity_truth: m.proximity_truth,
        proximity_note: format!(
            "{neighbours}; constant-velocity ego prediction within the radius: {:.4}",
            m.proximity_cv
        ),
        crowd_probe: probes
            .iter()
            .map(|&(weight, p)| CrowdProbeInfo::of(p, weight))
            .collect(),
    };
    eprintln!(
        "{}: best-of-{} ADE {:.3} m FDE {:.3} m | constant velocity ADE {:.3} m FDE {:.3} m | ADE {:.1} % lower | \
         within {} m of another agent: model {:.3}, truth {:.3}, cv {:.3}",
        cfg.eval.split,
        opts.samples,
        m.min_ade,
        m.min_fde,
        m.cv_ade,
        m.cv_fde,
        100.0 * info.ade_improvement,
        opts.radius,
        m.proximity_model,
        m.proximity_truth,
        m.proximity_cv
    );
    eprintln!(
        "{}: one sample ADE {:.3} m | the samples' mean ADE {:.3} m FDE {:.3} m | first {:.1} s: \
         one sample {:.3} m, the samples' mean {:.3} m, constant velocity {:.3} m",
        cfg.eval.split,
        m.mean_ade,
        m.centroid_ade,
        m.centroid_fde,
        m.early_steps as f64 * opts.dt,
        m.early_mean_ade,
        m.early_centroid_ade,
        m.early_cv_ade
    );
    for (weight, probe) in &probes {
        eprintln!(
            "{}: crowd probe, crowd guidance w = {weight} (the same samples with the crowd in the \
             raster and with it emptied; meeting = centres within {} m): recorded futures {:.3} \
             observed / {:.3} hidden (the human {:.3}); constant velocity {:.3} / {:.3} (the \
             human {:.3}); samples {:.3} m apart",
            cfg.eval.split,
            probe.contact,
            probe.observed_recorded,
            probe.hidden_recorded,
            probe.human_recorded,
            probe.observed_cv,
            probe.hidden_cv,
            probe.human_cv,
            probe.displacement
        );
    }
    Ok(info)
}

/// The libtorch device of `run.device`: `cpu`, `cuda` (an error without CUDA), else CUDA when
/// available.
pub fn device_of(name: &str) -> anyhow::Result<tch::Device> {
    Ok(match name {
        "cpu" => tch::Device::Cpu,
        "cuda" => {
            if !tch::Cuda::is_available() {
                bail!("run.device = \"cuda\" but CUDA is not available");
            }
            tch::Device::Cuda(0)
        }
        _ => tch::Device::cuda_if_available(),
    })
}

/// Opens the tuple cache at `cache_dir` and checks that its horizon and raster size match the
/// network of `cfg` (read from `config_path`, named in the error).
pub fn open_cache(
    cache_dir: &Path,
    cfg: &TrainConfig,
    config_path: &Path,
) -> anyhow::Result<TupleCache> {
    let cache = TupleCache::open(cache_dir).with_context(|| {
        format!(
            "opening the tuple cache {} (build it with `human2nav data build`)",
            cache_dir.display()
        )
    })?;
    let manifest = cache.manifest();
    if manifest.horizon != cfg.net.horizon || manifest.bev.cells != cfg.net.bev_cells {
        bail!(
            "the cache {} has horizon {} and {}×{} rasters; {} has net.horizon = {} and net.bev_cells = {}",
            cache_dir.display(),
            manifest.horizon,
            manifest.bev.cells,
            manifest.bev.cells,
            config_path.display(),
            cfg.net.horizon,
            cfg.net.bev_cells
        );
    }
    let cells = [
        ("net.crowd.cell", cfg.net.crowd.as_ref().map(|c| c.cell)),
        (
            "train.counterfactual.cell",
            cfg.train.counterfactual.as_ref().map(|c| c.cell),
        ),
    ];
    for (field, cell) in cells {
        if let Some(cell) = cell
            && (cell - manifest.bev.resolution).abs() > 1e-9
        {
            bail!(
                "{}: {field} = {cell} but the cache {} has cells of {} m",
                config_path.display(),
                cache_dir.display(),
                manifest.bev.resolution
            );
        }
    }
    Ok(cache)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A walker at 1 m/s along x, with `agents` (`[x, y, v_x, v_y, radius]`, ego frame).
    fn window(agents: Vec<[f32; 5]>) -> CompactTuple {
        CompactTuple {
            scene: 0,
            class: None,
            goal: [5.0, 0.0],
            velocity: [1.0, 0.0],
            future: vec![[0.0; 3]; 32],
            agents,
        }
    }

    #[test]
    fn a_window_interacts_when_the_straight_walk_meets_someone() {
        // Someone coming the other way on the same line: they meet after 1.5 s.
        assert!(interacting(
            &window(vec![[3.0, 0.0, -1.0, 0.0, 0.3]]),
            0.1,
            0.6
        ));
        // The same person 1 m to the side passes at 1 m: no meeting at 0.6 m.
        assert!(!interacting(
            &window(vec![[3.0, 1.0, -1.0, 0.0, 0.3]]),
            0.1,
            0.6
        ));
        // Someone standing 4 m ahead is reached only after the 3.2 s horizon.
        assert!(!interacting(
            &window(vec![[4.0, 0.0, 0.0, 0.0, 0.3]]),
            0.1,
            0.6
        ));
        assert!(!interacting(&window(vec![]), 0.1, 0.6));
    }
}
