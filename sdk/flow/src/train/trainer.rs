//! The trainer of [the module](super) on libtorch: batches as tensors, the loss, AdamW with EMA
//! and resumable checkpoints.

use super::*;
use crate::cfm::{TimeSampler, geodesic_point};
use crate::model::{
    CfmModel, crowd_points, normalise_condition, read_safetensors, trajectory_features,
    write_safetensors,
};
use crate::net::CROWD_FEATURES;
use human2nav_core::bev::{BevSpec, overlay_agent};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use std::time::Instant;
use tch::{Device, Kind, Tensor};

/// Draws `[K, 4]` uniforms for the counterfactual walkers from a generator of their own, so
/// that the other draws of a batch are the same with or without them.
struct CounterfactualNoise<'a> {
    opts: &'a Counterfactual,
    rng: ChaCha8Rng,
}

impl<'a> CounterfactualNoise<'a> {
    fn new(opts: Option<&'a Counterfactual>, seed: u64, stream: u64) -> Option<Self> {
        opts.map(|opts| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_c0f7_ac7a_0001);
            rng.set_stream(stream);
            Self { opts, rng }
        })
    }
}

/// A training batch in tensor form: the network's inputs and the regression target of Eq. 3.
#[derive(Debug)]
pub struct Batch {
    /// `[B, 5, T]` features of the path point `x_t` ([`trajectory_features`]).
    pub x: Tensor,
    /// `[B]` flow times.
    pub t: Tensor,
    /// `[B, 3, H, W]` normalised BEV rasters.
    pub bev: Tensor,
    /// `[B, 4]` normalised goal and ego velocity.
    pub goal_vel: Tensor,
    /// `[B, N, 5]` crowd points of the (mirrored) rasters (`N = 0` without the crowd pathway).
    pub points: Tensor,
    /// `[B, 3, T]` standardised target velocities `ξ/σ`.
    pub target: Tensor,
    /// `[B, 3, T]` the path point `x_t` itself: normalised translations and heading.
    pub xt: Tensor,
    /// `[B, P, 5]` the people the clearance term keeps the endpoint from, read from the
    /// (mirrored, augmented) rasters as [`crowd_points`] reads them (`P = 0` without the term).
    pub people: Tensor,
}

/// Eq. 3's path noise: `σ` and its own generator, so that the source draws, flow times and
/// targets of a batch are the same with or without it.
struct PathNoise {
    sigma: f64,
    rng: ChaCha8Rng,
}

impl PathNoise {
    /// The noise of batch `stream` of a run seeded `seed` (`None` when `sigma` is 0).
    fn new(sigma: f64, seed: u64, stream: u64) -> Option<Self> {
        (sigma > 0.0).then(|| {
            // A seed of its own: the batch generator is seeded with `seed` itself.
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
            rng.set_stream(stream);
            Self { sigma, rng }
        })
    }
}

/// The random part of a batch (per-waypoint entries row-major; `x_0 = exp(ξ_0)`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BatchDraws {
    /// Per row: mirrored (y ↦ −y) or not.
    pub flip: Vec<bool>,
    /// Per row: the flow time.
    pub t: Vec<f64>,
    /// Per row and waypoint: the source twist `ξ_0`.
    pub source: Vec<Twist2>,
    /// Per row and waypoint: the path noise twist, scaled by `σ`; empty without path noise.
    pub path: Vec<Twist2>,
    /// Per row: the four uniforms of [`Counterfactual::person`]; empty without
    /// counterfactual walkers.
    pub counterfactual: Vec<[f64; 4]>,
}

/// The draws of a batch of `rows` rows from `rng` (and the path noise's own generator), in
/// the order the trainer has always taken them: per row the mirror flag (only when `mirror`),
/// the flow time, then the waypoints' source twists.
fn draw_batch<R: Rng + ?Sized>(
    rows: usize,
    t_len: usize,
    time: &TimeSampler,
    mirror: bool,
    path: Option<&mut PathNoise>,
    counterfactual: Option<&mut CounterfactualNoise<'_>>,
    rng: &mut R,
) -> BatchDraws {
    let mut path = path.filter(|p| p.sigma > 0.0);
    let mut d = BatchDraws::default();
    for _ in 0..rows {
        d.flip.push(mirror && rng.random_bool(0.5));
        d.t.push(time.sample(rng));
        for _ in 0..t_len {
            d.source.push(unit_normal_twist(rng));
            if let Some(p) = path.as_deref_mut() {
                d.path.push(unit_normal_twist(&mut p.rng).scale(p.sigma));
            }
        }
    }
    if let Some(c) = counterfactual {
        d.counterfactual = (0..rows)
            .map(|_| std::array::from_fn(|_| c.rng.random::<f64>()))
            .collect();
    }
    d
}

/// Builds the batch of examples `idx` with noise from `rng`: features of `x_t`, flow times,
/// normalised conditions and standardised targets `ξ/σ`.
fn build_batch<S: TrainingSample, R: Rng + ?Sized>(
    data: &[S],
    idx: &[usize],
    net: &NetConfig,
    norm: &Normalisation,
    time: &TimeSampler,
    mirror: bool,
    path: Option<&mut PathNoise>,
    counterfactual: Option<&mut CounterfactualNoise<'_>>,
    clearance: Option<&ClearanceLoss>,
    rng: &mut R,
    device: Device,
) -> Batch {
    let opts = counterfactual.as_ref().map(|c| c.opts);
    let draws = draw_batch(
        idx.len(),
        net.horizon,
        time,
        mirror,
        path,
        counterfactual,
        rng,
    );
    batch_from_draws(data, idx, net, norm, &draws, opts, clearance, device)
}

/// The batch of examples `idx` given its random part: the recipe of the trainer's batches
/// (the SE(2) geodesic point and target of Eq. 3, trajectory features, mirrored and
/// normalised conditions, counterfactual walkers when `counterfactual` is given, the people of
/// the clearance term when `clearance` is given), public so that a reference implementation can
/// be checked against it on the same draws.
#[allow(clippy::too_many_arguments)]
pub fn batch_from_draws<S: TrainingSample>(
    data: &[S],
    idx: &[usize],
    net: &NetConfig,
    norm: &Normalisation,
    draws: &BatchDraws,
    counterfactual: Option<&Counterfactual>,
    clearance: Option<&ClearanceLoss>,
    device: Device,
) -> Batch {
    let b = idx.len();
    let t_len = net.horizon;
    let bev_len = net.bev_len();
    let cells = net.bev_cells;
    let mut x = vec![0f32; b * 5 * t_len];
    let mut target = vec![0f32; b * 3 * t_len];
    let mut ts = vec![0f32; b];
    let mut bev = vec![0f32; b * bev_len];
    let mut gv = vec![0f32; b * 4];
    let crowd_len = net.crowd_len();
    let mut points = vec![0f32; b * crowd_len];
    let people_cfg = clearance.map(ClearanceLoss::crowd);
    let people_len = people_cfg.as_ref().map_or(0, |c| c.points * 5);
    let mut people = vec![0f32; b * people_len];
    let mut xt_all = vec![0f32; b * 3 * t_len];
    let mut poses = vec![0f64; t_len * 3];
    let mut flipped = vec![0f32; bev_len];
    let (mut stamped, mut disc) = (vec![0f32; bev_len], vec![0f32; bev_len]);
    let s = norm.position_scale;
    for (row, &i) in idx.iter().enumerate() {
        let ex = &data[i];
        let flip = draws.flip[row];
        let t = draws.t[row];
        ts[row] = t as f32;
        let tgt = &mut target[row * 3 * t_len..(row + 1) * 3 * t_len];
        for j in 0..t_len {
            let mut p1 = scaled(ex.future_pose(j), s);
            if flip {
                p1 = Pose2::new(p1.x, -p1.y, -p1.theta);
            }
            let k = row * t_len + j;
            let x0 = Pose2::exp(draws.source[k]);
            let xi = target_velocity(x0, p1);
            let mut xt = geodesic_point(x0, xi, t);
            if let Some(&noise) = draws.path.get(k) {
                xt = xt.compose(Pose2::exp(noise));
            }
            poses[3 * j..3 * j + 3].copy_from_slice(&xt.to_array());
            for (c, v) in xt.to_array().into_iter().enumerate() {
                xt_all[(row * 3 + c) * t_len + j] = v as f32;
            }
            let xi = xi.to_array();
            for c in 0..3 {
                tgt[c * t_len + j] = (xi[c] / norm.velocity_std[c]) as f32;
            }
        }
        trajectory_features(&poses, &mut x[row * 5 * t_len..(row + 1) * 5 * t_len]);
        let (mut goal, mut vel) = (ex.goal(), ex.velocity());
        let src: &[f32] = if flip {
            // Mirror y: columns reverse (column 0 is the far left), v_y flips sign.
            let plane = cells * cells;
            for c in 0..3 {
                let sign = if c == 2 { -1.0 } else { 1.0 };
                for r in 0..cells {
                    for q in 0..cells {
                        flipped[c * plane + r * cells + q] =
                            sign * ex.bev()[c * plane + r * cells + (cells - 1 - q)];
                    }
                }
            }
            goal[1] = -goal[1];
            vel[1] = -vel[1];
            &flipped
        } else {
            ex.bev()
        };
        let person = counterfactual
            .zip(draws.counterfactual.get(row))
            .and_then(|(c, &u)| {
                let future: Vec<Pose2> = (0..t_len)
                    .map(|j| {
                        let p = ex.future_pose(j);
                        if flip {
                            Pose2::new(p.x, -p.y, -p.theta)
                        } else {
                            p
                        }
                    })
                    .collect();
                c.person(&future, vel, u).map(|a| (c.cell, a))
            });
        let src: &[f32] = match person {
            Some((cell, a)) => {
                stamped.copy_from_slice(src);
                let spec = BevSpec {
                    cells,
                    resolution: cell,
                };
                overlay_agent(spec, a, &mut stamped, &mut disc);
                &stamped
            }
            None => src,
        };
        normalise_condition(
            norm,
            src,
            goal,
            vel,
            &mut bev[row * bev_len..(row + 1) * bev_len],
            &mut gv[row * 4..row * 4 + 4],
        );
        if let Some(c) = &net.crowd {
            let out = &mut points[row * crowd_len..(row + 1) * crowd_len];
            crowd_points(c, norm, cells, src, out);
        }
        if let Some(c) = &people_cfg {
            let out = &mut people[row * people_len..(row + 1) * people_len];
            crowd_points(c, norm, cells, src, out);
        }
    }
    let (bi, ti, ci) = (b as i64, t_len as i64, cells as i64);
    Batch {
        x: Tensor::from_slice(&x).view([bi, 5, ti]).to_device(device),
        t: Tensor::from_slice(&ts).to_device(device),
        bev: Tensor::from_slice(&bev)
            .view([bi, 3, ci, ci])
            .to_device(device),
        goal_vel: Tensor::from_slice(&gv).view([bi, 4]).to_device(device),
        points: Tensor::from_slice(&points)
            .view([bi, -1, CROWD_FEATURES])
            .to_device(device),
        target: Tensor::from_slice(&target)
            .view([bi, 3, ti])
            .to_device(device),
        xt: Tensor::from_slice(&xt_all)
            .view([bi, 3, ti])
            .to_device(device),
        people: Tensor::from_slice(&people)
            .view([bi, -1, CROWD_FEATURES])
            .to_device(device),
    }
}

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
#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// libtorch's generator is global and `Trainer::new` seeds it: tests that train must not
    /// interleave, or their weights depend on each other's draws.
    static TRAINING: std::sync::Mutex<()> = std::sync::Mutex::new(());

    fn tiny_net() -> NetConfig {
        NetConfig {
            horizon: 8,
            bev_cells: 8,
            down_dims: vec![8, 16],
            n_groups: 4,
            bev_channels: [4, 8, 8],
            time_embed_dim: 8,
            bev_embed_dim: 8,
            goal_embed_dim: 8,
            ..NetConfig::default()
        }
    }

    fn data(n: usize) -> Vec<Example> {
        (0..n)
            .map(|i| {
                let turn = 0.05 * (i as f64 - n as f64 / 2.0);
                let mut p = Pose2::IDENTITY;
                let future = (0..8)
                    .map(|_| {
                        p = p.euler_step(Twist2::new(1.2, 0.0, turn * 10.0), 0.1);
                        p
                    })
                    .collect();
                let mut bev = vec![0.0; 3 * 64];
                bev[i % 64] = 1.0;
                Example {
                    bev,
                    goal: [5.0, 10.0 * turn],
                    velocity: [1.2, 0.0],
                    future,
                }
            })
            .collect()
    }

    #[test]
    fn learning_rate_schedule() {
        let o = TrainOptions {
            steps: 1000,
            warmup_steps: 100,
            lr: 1e-3,
            lr_min: 1e-5,
            ..TrainOptions::default()
        };
        assert_relative_eq!(o.lr_at(0), 1e-5, epsilon = 1e-12);
        assert_relative_eq!(o.lr_at(99), 1e-3, epsilon = 1e-12);
        assert_relative_eq!(o.lr_at(100), 1e-3, epsilon = 1e-12);
        // Half-way through the cosine: the mean of lr and lr_min.
        assert_relative_eq!(o.lr_at(550), 0.5 * (1e-3 + 1e-5), epsilon = 1e-12);
        assert_relative_eq!(o.lr_at(1000), 1e-5, epsilon = 1e-12);
        assert_relative_eq!(o.lr_at(5000), 1e-5, epsilon = 1e-12);
    }

    #[test]
    fn normalisation_estimate_matches_closed_forms() {
        let d = data(10);
        let n = Normalisation::estimate(&d, 0).unwrap();
        assert_relative_eq!(n.speed_scale, 1.2, epsilon = 1e-12);
        let g2: f64 = d
            .iter()
            .map(|e| e.goal[0].powi(2) + e.goal[1].powi(2))
            .sum::<f64>()
            / 10.0;
        assert_relative_eq!(n.goal_scale, g2.sqrt(), epsilon = 1e-12);
        assert!(Normalisation::estimate::<Example>(&[], 0).is_err());
    }

    /// Three steps, a checkpoint, a resume and three more steps give the same weights as six
    /// uninterrupted steps (batch order and noise derive from (seed, step); AdamW moments and
    /// EMA are checkpointed).
    /// Eq. 3's path noise moves the network's input `x_t` and nothing else; `σ = 0` draws no
    /// noise, so batches are those of the deterministic path.
    #[test]
    fn path_noise_moves_the_input_not_the_target() {
        let d = data(6);
        let net = tiny_net();
        let norm = Normalisation::estimate(&d, 0).unwrap();
        let time = TimeDistribution::default().sampler().unwrap();
        let idx = [0, 3, 5];
        let batch = |sigma: f64| {
            let mut rng = ChaCha8Rng::seed_from_u64(4);
            let mut path = PathNoise::new(sigma, 4, 0);
            build_batch(
                &d,
                &idx,
                &net,
                &norm,
                &time,
                false,
                path.as_mut(),
                None,
                None,
                &mut rng,
                Device::Cpu,
            )
        };
        let same = |a: &Tensor, b: &Tensor| (a - b).abs().max().double_value(&[]) == 0.0;
        let (plain, again, noisy) = (batch(0.0), batch(0.0), batch(0.2));
        assert!(same(&plain.x, &again.x));
        assert!(same(&plain.target, &noisy.target));
        assert!(same(&plain.t, &noisy.t));
        assert!(!same(&plain.x, &noisy.x));
        for bad in [-0.1, 1.5, f64::NAN] {
            let opts = TrainOptions {
                path_sigma: bad,
                ..TrainOptions::default()
            };
            assert!(opts.validate().is_err(), "{bad}");
        }
    }

    /// A checkpoint is a set: a missing or altered file is an error naming it, never a silent
    /// restart; a save interrupted between its renames resumes from the previous set.
    #[test]
    fn incomplete_checkpoints_are_detected() {
        let _serial = TRAINING.lock().unwrap_or_else(|e| e.into_inner());
        let d = data(8);
        let net = tiny_net();
        let norm = Normalisation::estimate(&d, 0).unwrap();
        let opts = TrainOptions {
            batch_size: 4,
            steps: 4,
            warmup_steps: 1,
            ..TrainOptions::default()
        };
        let root = std::env::temp_dir().join(format!("h2n-flow-ckpt-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let ckpt = root.join("checkpoint");
        let mut tr = Trainer::new(&net, &norm, &opts, &d, &d[..2], Device::Cpu).unwrap();
        tr.train_step().unwrap();
        tr.save_checkpoint(&ckpt).unwrap();
        tr.train_step().unwrap();
        tr.save_checkpoint(&ckpt).unwrap();
        assert!(
            !fileset::sibling(&ckpt, "old").exists()
                && !fileset::sibling(&ckpt, "partial").exists()
        );
        let err = |dir: &Path| find_checkpoint(dir).unwrap_err().to_string();

        // A truncated tensor file.
        let tensors = ckpt.join("state.safetensors");
        let bytes = std::fs::read(&tensors).unwrap();
        std::fs::write(&tensors, &bytes[..bytes.len() / 2]).unwrap();
        let e = err(&ckpt);
        assert!(
            e.contains("state.safetensors has") && e.contains("--fresh"),
            "{e}"
        );
        std::fs::write(&tensors, &bytes).unwrap();
        assert_eq!(find_checkpoint(&ckpt).unwrap(), Some(ckpt.clone()));

        // state.toml gone (before, training restarted at step 0 without a word).
        let state = std::fs::read(ckpt.join("state.toml")).unwrap();
        std::fs::remove_file(ckpt.join("state.toml")).unwrap();
        assert!(err(&ckpt).contains("state.toml is missing"));
        std::fs::remove_file(ckpt.join(MANIFEST_FILE)).unwrap();
        assert!(err(&ckpt).contains("state.toml is missing"));
        // Both files without a manifest: nothing checks them, so no resume (and no restart).
        std::fs::write(ckpt.join("state.toml"), &state).unwrap();
        let e = err(&ckpt);
        assert!(
            e.contains("manifest.toml is missing") && e.contains("--fresh"),
            "{e}"
        );

        // Interrupted between the two renames: only `<ckpt>.old` is complete.
        fileset::write_manifest(&ckpt, &CHECKPOINT_FILES, tr.step()).unwrap();
        let old = fileset::sibling(&ckpt, "old");
        std::fs::rename(&ckpt, &old).unwrap();
        std::fs::create_dir_all(&ckpt).unwrap();
        std::fs::write(ckpt.join("state.toml"), "half").unwrap();
        assert_eq!(find_checkpoint(&ckpt).unwrap(), Some(old.clone()));
        let resumed = Trainer::resume(&old, &opts, &d, &d[..2], Device::Cpu).unwrap();
        assert_eq!(resumed.step(), 2);
        // The next save cleans up.
        resumed.save_checkpoint(&ckpt).unwrap();
        assert!(!old.exists());
        assert_eq!(find_checkpoint(&ckpt).unwrap(), Some(ckpt.clone()));
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn resume_continues_exactly() {
        let _serial = TRAINING.lock().unwrap_or_else(|e| e.into_inner());
        let d = data(12);
        let net = tiny_net();
        let norm = Normalisation::estimate(&d, 0).unwrap();
        let opts = TrainOptions {
            batch_size: 5,
            steps: 6,
            warmup_steps: 2,
            ..TrainOptions::default()
        };
        let mut straight = Trainer::new(&net, &norm, &opts, &d, &d[..4], Device::Cpu).unwrap();
        for _ in 0..6 {
            straight.train_step().unwrap();
        }
        let dir = std::env::temp_dir().join(format!("h2n-flow-resume-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut first = Trainer::new(&net, &norm, &opts, &d, &d[..4], Device::Cpu).unwrap();
        for _ in 0..3 {
            first.train_step().unwrap();
        }
        first.record();
        assert_eq!(find_checkpoint(&dir).unwrap(), None);
        first.save_checkpoint(&dir).unwrap();
        assert_eq!(find_checkpoint(&dir).unwrap(), Some(dir.clone()));
        let mut resumed = Trainer::resume(&dir, &opts, &d, &d[..4], Device::Cpu).unwrap();
        assert_eq!(resumed.step(), 3);
        assert_eq!(resumed.history().len(), 1);
        for _ in 0..3 {
            resumed.train_step().unwrap();
        }
        for (prefix, a, b) in [
            (
                "param",
                straight.model().named_tensors(""),
                resumed.model().named_tensors(""),
            ),
            (
                "ema",
                straight.ema_model().named_tensors(""),
                resumed.ema_model().named_tensors(""),
            ),
        ] {
            for ((na, ta), (nb, tb)) in a.iter().zip(&b) {
                assert_eq!(na, nb);
                let diff = (ta - tb).abs().max().double_value(&[]);
                assert!(diff < 1e-6, "{prefix} {na} differs by {diff}");
            }
        }
        // Options other than `steps` must match the checkpoint.
        let other = TrainOptions {
            lr: 5e-4,
            ..opts.clone()
        };
        assert!(matches!(
            Trainer::resume(&dir, &other, &d, &d[..4], Device::Cpu),
            Err(CfmError::Option { field: "train", .. })
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A walker going straight at its velocity gets no counterfactual person (its future
    /// would meet them); one that stopped gets a person where it would have been, clear of
    /// its recorded future at every waypoint; the person appears in the batch's raster.
    #[test]
    fn counterfactual_people_are_clear_of_the_recorded_future() {
        let c = Counterfactual::default();
        let straight: Vec<Pose2> = (1..=32)
            .map(|i| Pose2::new(0.12 * i as f64, 0.0, 0.0))
            .collect();
        for u1 in [0.0, 0.5, 0.99] {
            assert_eq!(c.person(&straight, [1.2, 0.0], [0.1, u1, 0.2, 0.0]), None);
        }
        // It stopped after 1 m.
        let stopped: Vec<Pose2> = (1..=32)
            .map(|i| Pose2::new((0.12 * i as f64).min(1.0), 0.0, 0.0))
            .collect();
        assert_eq!(
            c.person(&stopped, [1.2, 0.0], [0.9, 0.5, 0.2, 0.0]),
            None,
            "u0 ≥ p"
        );
        for u in [
            [0.1, 0.0, 0.2, 0.0],
            [0.1, 0.99, 0.2, 0.0],
            [0.3, 0.5, 0.9, 0.6],
        ] {
            let a = c
                .person(&stopped, [1.2, 0.0], u)
                .expect("a place ahead of the stop");
            for (i, p) in stopped.iter().enumerate() {
                let t = (i + 1) as f64 * c.step;
                let q = [
                    a.position[0] + a.velocity[0] * t,
                    a.position[1] + a.velocity[1] * t,
                ];
                assert!((p.x - q[0]).hypot(p.y - q[1]) >= c.clearance - 1e-12);
            }
        }
        // In a batch: the row's raster gains the person's disc.
        let ex = Example {
            bev: vec![0.0; 3 * 16 * 16],
            goal: [5.0, 0.0],
            velocity: [1.2, 0.0],
            future: stopped,
        };
        let net = NetConfig {
            horizon: 32,
            bev_cells: 16,
            ..tiny_net()
        };
        let norm = Normalisation::default();
        let draws = BatchDraws {
            flip: vec![false],
            t: vec![0.5],
            source: vec![Twist2::new(0.0, 0.0, 0.0); 32],
            path: Vec::new(),
            counterfactual: vec![[0.1, 0.5, 0.2, 0.0]],
        };
        let data = [ex];
        let occupied = |b: &Batch| b.bev.narrow(1, 0, 1).sum(Kind::Float).double_value(&[]);
        let with = batch_from_draws(
            &data,
            &[0],
            &net,
            &norm,
            &draws,
            Some(&c),
            None,
            Device::Cpu,
        );
        let without = batch_from_draws(&data, &[0], &net, &norm, &draws, None, None, Device::Cpu);
        assert_eq!(occupied(&without), 0.0);
        assert!(occupied(&with) >= 1.0);
        assert_eq!(
            (with.target - without.target).abs().max().double_value(&[]),
            0.0,
            "the recorded future is the target either way"
        );
    }

    #[test]
    fn rejects_mismatched_examples() {
        let mut d = data(3);
        d[1].future.pop();
        let err = check_examples(&tiny_net(), &d).unwrap_err();
        assert!(matches!(err, CfmError::Example { index: 1, .. }), "{err}");
    }
}
