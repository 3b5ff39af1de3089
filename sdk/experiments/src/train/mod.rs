//! Training the conditional flow-matching model (`human2nav train`, and each fraction of the
//! scaling experiment): the `train.toml` settings, training on the tuple cache with checkpoints
//! and resume, export of the EMA weights with a model card and a loss curve, and the evaluation
//! on the held-out test scenes. Progress is drawn with indicatif and reported on stderr.

mod config;
mod eval;

pub use config::{
    DataSection, EvalSection, INTERACTION_CONTACT, MAX_INTERACTION_REPEAT, RunSection, TrainConfig,
};
pub use eval::{cache_windows, run_evaluation};

use anyhow::{Context, bail};
use human2nav_core::AgentState;
use human2nav_core::forecast::constant_velocity_path;
use human2nav_data::cache::TupleCache;
use human2nav_data::tuples::{CompactTuple, Split};
use human2nav_flow::card::{ComplexityInfo, TrainingInfo};
use human2nav_flow::eval::meets;
use human2nav_flow::model::CARD_FILE;
use human2nav_flow::net::{Complexity, parameter_count};
use human2nav_flow::tch;
use human2nav_flow::train::{Trainer, TrainingSample};
use human2nav_flow::{CfmModel, Normalisation};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

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
