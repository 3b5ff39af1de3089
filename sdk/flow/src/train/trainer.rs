//! The trainer of [the module](super) on libtorch: batches as tensors, the loss, AdamW with EMA
//! and resumable checkpoints.

use super::*;
use crate::cfm::TimeSampler;
use crate::model::{CfmModel, read_safetensors, write_safetensors};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use std::time::Instant;
use tch::{Device, Kind, Tensor};

mod batch;
#[cfg(test)]
mod tests;

pub use batch::{Batch, BatchDraws, batch_from_draws};
use batch::{CounterfactualNoise, PathNoise, build_batch};

/// CFM loss (Eq. 3) of `model` on a batch: mean squared error of the standardised velocity,
/// plus the clearance term when `clearance` is given.
fn batch_loss(model: &CfmModel, b: &Batch, clearance: Option<&ClearanceLoss>) -> Tensor {
    let cond = model.net().encode_condition(&b.bev, &b.goal_vel);
    let pred = model.net().forward(&b.x, &b.t, &cond, &b.points);
    let mse = pred.mse_loss(&b.target, tch::Reduction::Mean);
    match clearance {
        Some(c) => mse + super::clearance_penalty(&pred, b, &model.card().normalisation, c),
        None => mse,
    }
}

/// Training state that is not part of [`CfmModel`]: saved as `state.toml` beside the tensors.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StateFile {
    step: u64,
    elapsed_s: f64,
    net: NetConfig,
    normalisation: Normalisation,
    options: TrainOptions,
    history: Vec<LossRecord>,
}

/// A training run: the trained weights, their EMA, the AdamW moments and the history.
pub struct Trainer<'a, S: TrainingSample> {
    model: CfmModel,
    ema: CfmModel,
    opts: TrainOptions,
    time: TimeSampler,
    train: &'a [S],
    val: &'a [S],
    names: Vec<String>,
    params: Vec<Tensor>,
    ema_params: Vec<Tensor>,
    adam_m: Vec<Tensor>,
    adam_v: Vec<Tensor>,
    step: u64,
    elapsed_s: f64,
    history: Vec<LossRecord>,
    order: Vec<usize>,
    order_epoch: Option<u64>,
    loss_sum: f64,
    loss_count: u64,
}

impl<S: TrainingSample> std::fmt::Debug for Trainer<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Trainer")
            .field("step", &self.step)
            .field("train", &self.train.len())
            .field("val", &self.val.len())
            .finish_non_exhaustive()
    }
}

/// Number of validation examples used at most (a fixed, seeded draw of noise).
pub const VAL_MAX: usize = 4096;

impl<'a, S: TrainingSample> Trainer<'a, S> {
    /// A fresh run: weights initialised from `opts.seed`.
    pub fn new(
        net: &NetConfig,
        norm: &Normalisation,
        opts: &TrainOptions,
        train: &'a [S],
        val: &'a [S],
        device: Device,
    ) -> Result<Self, CfmError> {
        opts.validate()?;
        net.validate()?;
        opts.check_batch_size(net)?;
        if train.is_empty() {
            return Err(CfmError::EmptyData { split: "train" });
        }
        check_examples(net, train)?;
        check_examples(net, val)?;
        tch::manual_seed(opts.seed as i64);
        let norm = &Normalisation {
            goal_conditioned: opts.goal,
            velocity_conditioned: opts.velocity,
            ..norm.clone()
        };
        let model = CfmModel::new(net, norm, device)?;
        let ema = CfmModel::new(net, norm, device)?;
        let mut names: Vec<String> = model.var_store().variables().into_keys().collect();
        names.sort();
        let vars = model.var_store().variables();
        let evars = ema.var_store().variables();
        let params: Vec<Tensor> = names.iter().map(|n| vars[n].shallow_clone()).collect();
        let ema_params: Vec<Tensor> = names.iter().map(|n| evars[n].shallow_clone()).collect();
        tch::no_grad(|| {
            for (e, p) in ema_params.iter().zip(&params) {
                e.shallow_clone().copy_(p);
            }
        });
        let adam_m = params.iter().map(Tensor::zeros_like).collect();
        let adam_v = params.iter().map(Tensor::zeros_like).collect();
        Ok(Self {
            model,
            ema,
            time: opts.time.sampler()?,
            opts: opts.clone(),
            train,
            val,
            names,
            params,
            ema_params,
            adam_m,
            adam_v,
            step: 0,
            elapsed_s: 0.0,
            history: Vec::new(),
            order: Vec::new(),
            order_epoch: None,
            loss_sum: 0.0,
            loss_count: 0,
        })
    }

    /// Resumes a run saved with [`Self::save_state`]. The architecture and normalisation come
    /// from the state; `opts.steps` may extend the schedule, other options must match.
    pub fn resume(
        dir: &Path,
        opts: &TrainOptions,
        train: &'a [S],
        val: &'a [S],
        device: Device,
    ) -> Result<Self, CfmError> {
        let state_path = dir.join("state.toml");
        let text = read_user_file(&state_path, "training state", MAX_CONFIG_BYTES)
            .map_err(|e| CfmError::io(&state_path, e))?;
        let state: StateFile = toml::from_str(&text).map_err(|e| CfmError::Toml {
            path: state_path.clone(),
            message: e.to_string(),
        })?;
        let mut same = state.options.clone();
        same.steps = opts.steps;
        if same != *opts {
            return Err(CfmError::option(
                "train",
                format!(
                    "options differ from the checkpoint in {} (only `steps` may change on resume)",
                    state_path.display()
                ),
            ));
        }
        let mut tr = Self::new(&state.net, &state.normalisation, opts, train, val, device)?;
        let tensors_path = dir.join("state.safetensors");
        let tensors = read_safetensors(&tensors_path)?;
        tr.model.assign_from(&tensors_path, "param.", &tensors)?;
        tr.ema.assign_from(&tensors_path, "ema.", &tensors)?;
        let _guard = tch::no_grad_guard();
        for (i, name) in tr.names.iter().enumerate() {
            for (prefix, dst) in [("adam_m.", &tr.adam_m[i]), ("adam_v.", &tr.adam_v[i])] {
                let key = format!("{prefix}{name}");
                let src = tensors.get(&key).ok_or_else(|| CfmError::MissingTensor {
                    path: tensors_path.clone(),
                    name: key.clone(),
                })?;
                if src.size() != dst.size() {
                    return Err(CfmError::TensorShape {
                        path: tensors_path.clone(),
                        name: key,
                        expected: dst.size(),
                        found: src.size(),
                    });
                }
                dst.shallow_clone()
                    .copy_(&src.to_kind(dst.kind()).to_device(dst.device()));
            }
        }
        tr.step = state.step;
        tr.elapsed_s = state.elapsed_s;
        tr.history = state.history;
        Ok(tr)
    }

    /// Writes a checkpoint to `ckpt` as one set (see [`find_checkpoint`]): the files go into
    /// `<ckpt>.partial`, the manifest (sizes and checksums) last, then the folder replaces
    /// `ckpt` by two renames (the previous set is kept as `<ckpt>.old` between them). A crash at
    /// any point leaves a complete set behind: the new one, the old one or `<ckpt>.old`.
    pub fn save_checkpoint(&self, ckpt: &Path) -> Result<(), CfmError> {
        fileset::commit(ckpt, &CHECKPOINT_FILES, self.step, |dir| {
            self.save_state(dir)
        })
    }

    /// Writes weights, EMA weights, AdamW moments (`state.safetensors`) and the step, options
    /// and history (`state.toml`) into `dir` (no manifest: use [`Self::save_checkpoint`] for a
    /// checkpoint that is detected as complete or not).
    pub fn save_state(&self, dir: &Path) -> Result<(), CfmError> {
        std::fs::create_dir_all(dir).map_err(|e| CfmError::io(dir, e))?;
        let mut tensors = self.model.named_tensors("param.");
        tensors.extend(self.ema.named_tensors("ema."));
        for (i, n) in self.names.iter().enumerate() {
            tensors.push((
                format!("adam_m.{n}"),
                self.adam_m[i].detach().to_device(Device::Cpu),
            ));
            tensors.push((
                format!("adam_v.{n}"),
                self.adam_v[i].detach().to_device(Device::Cpu),
            ));
        }
        write_safetensors(&dir.join("state.safetensors"), &tensors)?;
        let state = StateFile {
            step: self.step,
            elapsed_s: self.elapsed_s,
            net: self.model.card().net.clone(),
            normalisation: self.model.card().normalisation.clone(),
            options: self.opts.clone(),
            history: self.history.clone(),
        };
        let path = dir.join("state.toml");
        let text = toml::to_string_pretty(&state).map_err(|e| CfmError::Toml {
            path: path.clone(),
            message: e.to_string(),
        })?;
        let tmp = dir.join("state.toml.tmp");
        std::fs::write(&tmp, text).map_err(|e| CfmError::io(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| CfmError::io(&path, e))
    }

    /// Optimiser steps done.
    pub fn step(&self) -> u64 {
        self.step
    }

    /// Total steps of the schedule.
    pub fn total_steps(&self) -> u64 {
        self.opts.steps
    }

    /// The loss history recorded by [`Self::record`].
    pub fn history(&self) -> &[LossRecord] {
        &self.history
    }

    /// Seconds of training so far, across resumes.
    pub fn elapsed_s(&self) -> f64 {
        self.elapsed_s
    }

    /// Adds wall time spent outside [`Self::train_step`] bookkeeping (set by the driver).
    pub fn add_elapsed(&mut self, seconds: f64) {
        self.elapsed_s += seconds;
    }

    /// The EMA model (what gets shipped).
    pub fn ema_model(&self) -> &CfmModel {
        &self.ema
    }

    /// Consumes the trainer, returning the EMA model.
    pub fn into_ema_model(self) -> CfmModel {
        self.ema
    }

    /// The raw (non-averaged) model.
    pub fn model(&self) -> &CfmModel {
        &self.model
    }

    /// Indices of the examples of step `step`: a per-epoch permutation seeded by
    /// `(seed, epoch)`, walked in order across epoch boundaries.
    fn batch_indices(&mut self, step: u64) -> Vec<usize> {
        let n = self.train.len() as u64;
        let b = self.opts.batch_size as u64;
        let mut out = Vec::with_capacity(b as usize);
        for pos in step * b..(step + 1) * b {
            let epoch = pos / n;
            if self.order_epoch != Some(epoch) {
                let mut rng = ChaCha8Rng::seed_from_u64(self.opts.seed);
                rng.set_stream(0x0de0_0000 + epoch);
                self.order = (0..self.train.len()).collect();
                self.order.shuffle(&mut rng);
                self.order_epoch = Some(epoch);
            }
            out.push(self.order[(pos % n) as usize]);
        }
        out
    }

    /// One optimiser step; returns the batch loss (before the update).
    pub fn train_step(&mut self) -> Result<f64, CfmError> {
        self.train_step_timed().map(|t| t.loss)
    }

    /// [`Self::train_step`], also returning the wall time of its phases (for throughput
    /// measurements such as `human2nav train --bench-steps`).
    pub fn train_step_timed(&mut self) -> Result<StepTimes, CfmError> {
        let start = Instant::now();
        let step = self.step;
        let idx = self.batch_indices(step);
        let mut rng = ChaCha8Rng::seed_from_u64(self.opts.seed);
        rng.set_stream(step);
        let card = self.model.card();
        let batch = build_batch(
            self.train,
            &idx,
            &card.net,
            &card.normalisation,
            &self.time,
            self.opts.mirror,
            PathNoise::new(self.opts.path_sigma, self.opts.seed, step).as_mut(),
            CounterfactualNoise::new(self.opts.counterfactual.as_ref(), self.opts.seed, step)
                .as_mut(),
            self.opts.clearance.as_ref(),
            &mut rng,
            self.model.device(),
        );
        let built = Instant::now();
        for p in &mut self.params {
            p.zero_grad();
        }
        let loss = batch_loss(&self.model, &batch, self.opts.clearance.as_ref());
        let loss_value = loss.double_value(&[]);
        if !loss_value.is_finite() {
            return Err(CfmError::Diverged { step });
        }
        let forward = Instant::now();
        loss.backward();
        let backward = Instant::now();
        self.apply_adamw(step);
        self.step += 1;
        self.loss_sum += loss_value;
        self.loss_count += 1;
        self.model.invalidate_cache();
        self.ema.invalidate_cache();
        let end = Instant::now();
        Ok(StepTimes {
            loss: loss_value,
            batch_s: built.duration_since(start).as_secs_f64(),
            forward_s: forward.duration_since(built).as_secs_f64(),
            backward_s: backward.duration_since(forward).as_secs_f64(),
            update_s: end.duration_since(backward).as_secs_f64(),
        })
    }

    fn apply_adamw(&mut self, step: u64) {
        let o = &self.opts;
        let lr = o.lr_at(step);
        let _guard = tch::no_grad_guard();
        let grads: Vec<Tensor> = self.params.iter().map(Tensor::grad).collect();
        let sq: f64 = grads
            .iter()
            .filter(|g| g.defined())
            .map(|g| g.square().sum(Kind::Double).double_value(&[]))
            .sum();
        let norm = sq.sqrt();
        let clip = if norm > o.grad_clip {
            o.grad_clip / (norm + 1e-6)
        } else {
            1.0
        };
        let k = (step + 1) as f64;
        let bc1 = 1.0 - o.beta1.powf(k);
        let bc2 = 1.0 - o.beta2.powf(k);
        let decay = o.ema_decay.min((1.0 + step as f64) / (10.0 + step as f64));
        for i in 0..self.params.len() {
            let g = &grads[i];
            let mut p = self.params[i].shallow_clone();
            if g.defined() {
                let g = g * clip;
                let mut m = self.adam_m[i].shallow_clone();
                let mut v = self.adam_v[i].shallow_clone();
                m.copy_(&(&m * o.beta1 + &g * (1.0 - o.beta1)));
                v.copy_(&(&v * o.beta2 + g.square() * (1.0 - o.beta2)));
                let update = (&m / bc1) / ((&v / bc2).sqrt() + o.eps);
                let decayed = &p * (1.0 - lr * o.weight_decay);
                p.copy_(&(decayed - update * lr));
            }
            let mut e = self.ema_params[i].shallow_clone();
            e.copy_(&(&e * decay + &p * (1.0 - decay)));
        }
    }

    /// Validation loss (Eq. 3) of the EMA weights on up to [`VAL_MAX`] validation examples,
    /// with noise and flow times from a fixed seed (so successive values are comparable).
    /// `None` when there is no validation data.
    pub fn validate(&self) -> Option<f64> {
        if self.val.is_empty() {
            return None;
        }
        let n = self.val.len().min(VAL_MAX);
        let mut rng = ChaCha8Rng::seed_from_u64(self.opts.seed ^ 0x0007_a11d);
        let mut path = PathNoise::new(self.opts.path_sigma, self.opts.seed, u64::MAX);
        let card = self.ema.card();
        let (mut sum, mut count) = (0.0, 0usize);
        let bs = self.opts.batch_size.max(64);
        let _guard = tch::no_grad_guard();
        for start in (0..n).step_by(bs) {
            let idx: Vec<usize> = (start..(start + bs).min(n)).collect();
            let batch = build_batch(
                self.val,
                &idx,
                &card.net,
                &card.normalisation,
                &self.time,
                false,
                path.as_mut(),
                None,
                None,
                &mut rng,
                self.ema.device(),
            );
            sum += batch_loss(&self.ema, &batch, None).double_value(&[]) * idx.len() as f64;
            count += idx.len();
        }
        Some(sum / count as f64)
    }

    /// Records a history point: the mean training loss since the previous record and the
    /// validation loss now. Returns it.
    pub fn record(&mut self) -> LossRecord {
        let train_loss = if self.loss_count > 0 {
            self.loss_sum / self.loss_count as f64
        } else {
            f64::NAN
        };
        let rec = LossRecord {
            step: self.step,
            train_loss,
            val_loss: self.validate().unwrap_or(f64::NAN),
            lr: self.opts.lr_at(self.step.saturating_sub(1)),
            elapsed_s: self.elapsed_s,
        };
        self.loss_sum = 0.0;
        self.loss_count = 0;
        self.history.push(rec);
        rec
    }

    /// Mean training loss since the last [`Self::record`] (NaN before the first step).
    pub fn running_loss(&self) -> f64 {
        if self.loss_count > 0 {
            self.loss_sum / self.loss_count as f64
        } else {
            f64::NAN
        }
    }
}

/// Per-batch CFM loss of a model on `data` with a fixed seed (for tests and reports), on the
/// deterministic geodesic path (`σ = 0`).
pub fn evaluate_loss<S: TrainingSample>(
    model: &CfmModel,
    data: &[S],
    time: &TimeDistribution,
    seed: u64,
) -> Result<f64, CfmError> {
    if data.is_empty() {
        return Err(CfmError::EmptyData {
            split: "evaluation",
        });
    }
    let sampler = time.sampler()?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let card = model.card();
    let _guard = tch::no_grad_guard();
    let (mut sum, mut count) = (0.0, 0usize);
    for start in (0..data.len()).step_by(256) {
        let idx: Vec<usize> = (start..(start + 256).min(data.len())).collect();
        let b = build_batch(
            data,
            &idx,
            &card.net,
            &card.normalisation,
            &sampler,
            false,
            None,
            None,
            None,
            &mut rng,
            model.device(),
        );
        sum += batch_loss(model, &b, None).double_value(&[]) * idx.len() as f64;
        count += idx.len();
    }
    Ok(sum / count as f64)
}
