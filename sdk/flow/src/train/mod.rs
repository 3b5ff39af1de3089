//! Training: the CFM loss of Eq. 3 minimised with AdamW, warm-up + cosine learning rate,
//! gradient-norm clipping and an exponential moving average (EMA) of the weights.
//!
//! Everything random is derived from `(seed, step)` (batch order from `(seed, epoch)`, noise
//! and flow times from `(seed, step)`), so a run resumed from a checkpoint continues exactly
//! as the uninterrupted run would have. AdamW is implemented here on plain tensors so its
//! moments can be checkpointed with the weights.

use crate::cfm::{TimeDistribution, target_velocity};
use crate::config::{NetConfig, Normalisation};
use crate::error::CfmError;
use human2nav_core::bev::BevAgent;
use human2nav_core::fileset::{self, SetError};
use human2nav_core::se2::{Pose2, Twist2};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[cfg(feature = "torch")]
mod trainer;
#[cfg(feature = "torch")]
pub use trainer::{Batch, BatchDraws, Trainer, VAL_MAX, batch_from_draws, evaluate_loss};
#[cfg(feature = "torch")]
mod clearance;
#[cfg(feature = "torch")]
pub use clearance::clearance_penalty;

/// One training example as the trainer needs it. Implemented for the data crate's tuples and
/// for [`Example`].
pub trait TrainingSample {
    /// `[3, H, W]` raster.
    fn bev(&self) -> &[f32];
    /// Goal `[x, y]`, ego frame, metres.
    fn goal(&self) -> [f64; 2];
    /// Ego velocity `[v_x, v_y]`, ego frame, m/s.
    fn velocity(&self) -> [f64; 2];
    /// Number of future poses.
    fn future_len(&self) -> usize;
    /// Future pose `i` (`x, y, θ`), ego frame; the current (identity) pose is not included.
    fn future_pose(&self, i: usize) -> Pose2;
}

/// A self-contained training example (tests, synthetic data).
#[derive(Clone, Debug, PartialEq)]
pub struct Example {
    /// The `[3, H, W]` BEV raster.
    pub bev: Vec<f32>,
    /// Goal `[x, y]`, ego frame, metres.
    pub goal: [f64; 2],
    /// Ego velocity `[v_x, v_y]`, ego frame, m/s.
    pub velocity: [f64; 2],
    /// The future poses, ego frame, without the current (identity) pose.
    pub future: Vec<Pose2>,
}

impl TrainingSample for Example {
    fn bev(&self) -> &[f32] {
        &self.bev
    }
    fn goal(&self) -> [f64; 2] {
        self.goal
    }
    fn velocity(&self) -> [f64; 2] {
        self.velocity
    }
    fn future_len(&self) -> usize {
        self.future.len()
    }
    fn future_pose(&self, i: usize) -> Pose2 {
        self.future[i]
    }
}

impl TrainingSample for human2nav_data::tuples::TrainingTuple {
    fn bev(&self) -> &[f32] {
        &self.bev
    }
    fn goal(&self) -> [f64; 2] {
        [self.goal[0] as f64, self.goal[1] as f64]
    }
    fn velocity(&self) -> [f64; 2] {
        [self.velocity[0] as f64, self.velocity[1] as f64]
    }
    fn future_len(&self) -> usize {
        self.future.len()
    }
    fn future_pose(&self, i: usize) -> Pose2 {
        let p = self.future[i];
        Pose2::new(p[0] as f64, p[1] as f64, p[2] as f64)
    }
}

/// Checks every example matches the architecture (raster size, horizon, finite values).
pub fn check_examples<S: TrainingSample>(net: &NetConfig, data: &[S]) -> Result<(), CfmError> {
    for (index, s) in data.iter().enumerate() {
        if s.bev().len() != net.bev_len() {
            return Err(CfmError::Example {
                index,
                reason: format!(
                    "BEV has {} values, expected {}",
                    s.bev().len(),
                    net.bev_len()
                ),
            });
        }
        if s.future_len() != net.horizon {
            return Err(CfmError::Example {
                index,
                reason: format!("{} future poses, expected {}", s.future_len(), net.horizon),
            });
        }
        let finite = s.goal().iter().chain(&s.velocity()).all(|v| v.is_finite())
            && (0..net.horizon).all(|i| s.future_pose(i).is_finite());
        if !finite {
            return Err(CfmError::Example {
                index,
                reason: "non-finite goal, velocity or pose".into(),
            });
        }
    }
    Ok(())
}

impl Normalisation {
    /// Estimates the normalisation from training data: RMS future distance, goal distance and
    /// ego speed, and the RMS of the target velocity per component over sampled source/data
    /// pairs (up to 4096 examples, seeded).
    pub fn estimate<S: TrainingSample>(data: &[S], seed: u64) -> Result<Self, CfmError> {
        if data.is_empty() {
            return Err(CfmError::EmptyData { split: "train" });
        }
        let (mut d2, mut n) = (0.0, 0usize);
        let (mut g2, mut v2) = (0.0, 0.0);
        for s in data {
            for i in 0..s.future_len() {
                let p = s.future_pose(i);
                d2 += p.x * p.x + p.y * p.y;
                n += 1;
            }
            let g = s.goal();
            let v = s.velocity();
            g2 += g[0] * g[0] + g[1] * g[1];
            v2 += v[0] * v[0] + v[1] * v[1];
        }
        let m = data.len() as f64;
        let position_scale = (d2 / n.max(1) as f64).sqrt().max(0.1);
        let goal_scale = (g2 / m).sqrt().max(0.1);
        let speed_scale = (v2 / m).sqrt().max(0.1);
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x05ee_d0f5_ca1e);
        let mut acc = [0.0; 3];
        let mut count = 0usize;
        let take = data.len().min(4096);
        let mut idx: Vec<usize> = (0..data.len()).collect();
        idx.shuffle(&mut rng);
        for &i in &idx[..take] {
            let s = &data[i];
            for j in 0..s.future_len() {
                let x1 = scaled(s.future_pose(j), position_scale);
                let x0 = Pose2::exp(unit_normal_twist(&mut rng));
                let xi = target_velocity(x0, x1).to_array();
                for c in 0..3 {
                    acc[c] += xi[c] * xi[c];
                }
                count += 1;
            }
        }
        let velocity_std = acc.map(|a| (a / count.max(1) as f64).sqrt().max(1e-3));
        let norm = Self {
            position_scale,
            velocity_std,
            goal_scale,
            speed_scale,
            goal_conditioned: true,
            velocity_conditioned: true,
        };
        norm.validate()?;
        Ok(norm)
    }
}

fn scaled(p: Pose2, s: f64) -> Pose2 {
    Pose2::new(p.x / s, p.y / s, p.theta)
}

fn unit_normal_twist<R: Rng + ?Sized>(rng: &mut R) -> Twist2 {
    let mut n = || -> f64 { StandardNormal.sample(rng) };
    Twist2::new(n(), n(), n())
}

/// Optimiser, schedule and bookkeeping options of a training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainOptions {
    /// Seed of weight initialisation, batch order, noise and flow times. Default 0.
    pub seed: u64,
    /// Examples per optimiser step. Default 256.
    pub batch_size: usize,
    /// Total optimiser steps (the cosine schedule ends here). Default 20 000.
    pub steps: u64,
    /// Peak learning rate. Default 1e-3.
    pub lr: f64,
    /// Final learning rate of the cosine decay. Default 1e-5.
    pub lr_min: f64,
    /// Linear warm-up steps. Default 500.
    pub warmup_steps: u64,
    /// AdamW `β1`. Default 0.9.
    pub beta1: f64,
    /// AdamW `β2`. Default 0.999.
    pub beta2: f64,
    /// AdamW `ε`. Default 1e-8.
    pub eps: f64,
    /// AdamW's decoupled weight decay. Default 1e-4.
    pub weight_decay: f64,
    /// Gradient clipping by global norm. Default 1.0.
    pub grad_clip: f64,
    /// EMA decay; the effective decay at step `k` is `min(ema_decay, (1 + k)/(10 + k))`.
    /// Default 0.999.
    pub ema_decay: f64,
    /// Flow-time distribution.
    pub time: TimeDistribution,
    /// Also train on the left-right mirror image of each example with probability 1/2
    /// (erases any side preference of walkers). Default false.
    pub mirror: bool,
    /// `σ` of Eq. 3's probability path `N(x0·exp(t·log(x0⁻¹x1)), σ)`: each `x_t` is moved by
    /// `exp(σ·ε)`, `ε ~ N(0, I)` in se(2), in the network's normalised units; the target stays
    /// the path's velocity `log(x0⁻¹x1)` (as in independent conditional flow matching). Default
    /// 0, the deterministic geodesic: no noise is drawn, so batches are exactly those of
    /// earlier versions.
    pub path_sigma: f64,
    /// Condition the model on the goal (the paper's planner). `false` trains a goal-free model
    /// ([`Normalisation::goal_conditioned`]): from a walker's velocity and the scene alone it
    /// generates where the walker goes, a multimodal predictor of people. Default true.
    pub goal: bool,
    /// Condition the model on the ego velocity. `false` trains a model that does not see it
    /// ([`Normalisation::velocity_conditioned`]). Default true.
    pub velocity: bool,
    /// Counterfactual walkers ([`Counterfactual`]); absent (the default): none, and batches
    /// are exactly those of earlier versions.
    pub counterfactual: Option<Counterfactual>,
    /// A clearance term added to Eq. 3's loss ([`ClearanceLoss`]); absent (the default): the
    /// loss is Eq. 3 alone, as in earlier versions.
    pub clearance: Option<ClearanceLoss>,
}

/// A clearance term in the training loss: an objective beyond imitation.
///
/// From each batch row the network's velocity gives the endpoint it predicts,
/// `x̂_1 = x_t·exp((1 − t)·v_θ)` (exact when `v_θ` is the target of Eq. 3). Every waypoint of
/// `x̂_1` that comes within `distance` of a person of the raster walking on at constant
/// velocity (an occupied cell centre moved by its velocity to the waypoint's time) adds
/// `weight·((distance − d)/distance)²` per occupied cell, averaged over waypoints and rows (each
/// row weighted by `t^time_power`).
/// The people are those the network is shown (counterfactual walkers included), so what it
/// gains by avoiding them it can only gain by looking.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClearanceLoss {
    /// Weight of the term against Eq. 3's mean squared error. Default 1.
    pub weight: f64,
    /// Contact distance (m) between a waypoint and a cell centre. Default 0.6 (the crowd
    /// probe's contact).
    pub distance: f64,
    /// Occupied raster cells read per row, nearest to the ego first. Default 40.
    pub points: usize,
    /// Edge of a raster cell (m): the cache's resolution. Default 0.3.
    pub cell: f64,
    /// Seconds between waypoints. Default 0.1.
    pub step: f64,
    /// Each row's term is weighted by its flow time to this power, `t^p`: above 0 the late
    /// predictions, which the samples end as, count more than the early ones, whose `x̂_1` is
    /// a mean of the futures still possible. Default 0 (every flow time alike).
    pub time_power: f64,
}

impl Default for ClearanceLoss {
    fn default() -> Self {
        Self {
            weight: 1.0,
            distance: 0.6,
            points: 40,
            cell: 0.3,
            step: 0.1,
            time_power: 0.0,
        }
    }
}

impl ClearanceLoss {
    fn validate(&self) -> Result<(), CfmError> {
        for (field, v) in [
            ("train.clearance.weight", self.weight),
            ("train.clearance.distance", self.distance),
            ("train.clearance.cell", self.cell),
            ("train.clearance.step", self.step),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(CfmError::option(field, "must be finite and > 0"));
            }
        }
        if !(self.time_power.is_finite() && (0.0..=8.0).contains(&self.time_power)) {
            return Err(CfmError::option(
                "train.clearance.time_power",
                "must lie in [0, 8]",
            ));
        }
        if !(1..=4096).contains(&self.points) {
            return Err(CfmError::option(
                "train.clearance.points",
                "must lie in [1, 4096]",
            ));
        }
        Ok(())
    }

    /// The people of a raster as [`crate::model::crowd_points`] reads them.
    pub fn crowd(&self) -> crate::config::CrowdConfig {
        crate::config::CrowdConfig {
            points: self.points,
            cell: self.cell,
            step: self.step,
            ..Default::default()
        }
    }
}

/// Slowest walker (m/s) a counterfactual person is placed for.
pub const MIN_WALKER_SPEED: f64 = 0.3;

/// Counterfactual walkers: an augmentation that puts into a window's raster a person the
/// recorded walker's future avoided.
///
/// In a window where the walker did not go on at its velocity, a person is placed where the
/// straight continuation would have been at some waypoint, standing or walking at a random
/// velocity, but only where the walker's recorded future keeps `clearance` from that person's
/// constant-velocity path at every waypoint. The recorded future is untouched: the person is
/// one the human's own swerve or slowing would have avoided. The model sees more windows in
/// which the crowd, not the walker's velocity, tells where the walker goes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Counterfactual {
    /// Probability that a window gets a person, when one can be placed. Default 0.5.
    pub probability: f64,
    /// Least distance (m) between the recorded future and the placed person at every
    /// waypoint. Default 0.6 (two pedestrian discs of 0.3 m).
    pub clearance: f64,
    /// The person's disc radius (m). Default 0.3.
    pub radius: f64,
    /// Fastest the person walks (m/s); half of them stand. Default 1.3.
    pub max_speed: f64,
    /// Edge of a raster cell (m): the cache's resolution. Default 0.3.
    pub cell: f64,
    /// Seconds between waypoints. Default 0.1.
    pub step: f64,
}

impl Default for Counterfactual {
    fn default() -> Self {
        Self {
            probability: 0.5,
            clearance: 0.6,
            radius: 0.3,
            max_speed: 1.3,
            cell: 0.3,
            step: 0.1,
        }
    }
}

impl Counterfactual {
    fn validate(&self) -> Result<(), CfmError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !(0.0..=1.0).contains(&self.probability) {
            return Err(CfmError::option(
                "train.counterfactual.probability",
                "must lie in [0, 1]",
            ));
        }
        for (field, v) in [
            ("train.counterfactual.clearance", self.clearance),
            ("train.counterfactual.radius", self.radius),
            ("train.counterfactual.cell", self.cell),
            ("train.counterfactual.step", self.step),
        ] {
            if !positive(v) {
                return Err(CfmError::option(field, "must be finite and > 0"));
            }
        }
        if !(self.max_speed.is_finite() && self.max_speed >= 0.0) {
            return Err(CfmError::option(
                "train.counterfactual.max_speed",
                "must be finite and ≥ 0",
            ));
        }
        Ok(())
    }

    /// The person to place in a window whose walker has velocity `velocity` and recorded
    /// future `future` (metres, ego frame), from four uniform draws `u`: `u[0]` against
    /// [`Self::probability`], the rest as in [`Self::place`]; `None` when the draw says no or
    /// no place keeps the clearance.
    pub fn person(&self, future: &[Pose2], velocity: [f64; 2], u: [f64; 4]) -> Option<BevAgent> {
        if u[0] >= self.probability {
            return None;
        }
        self.place(future, velocity, [u[1], u[2], u[3]])
    }

    /// Where a person fits whatever the probability: from the places that keep the clearance
    /// the one `u[0]` picks, standing when `u[1] < 0.5` (else walking at
    /// `max_speed·(2·u[1] − 1)`), heading `2π·u[2]`. `None` when no place fits, or when the
    /// walker is slower than [`MIN_WALKER_SPEED`] (it has no straight line to block).
    pub fn place(&self, future: &[Pose2], velocity: [f64; 2], u: [f64; 3]) -> Option<BevAgent> {
        if velocity[0].hypot(velocity[1]) < MIN_WALKER_SPEED {
            return None;
        }
        let speed = if u[1] >= 0.5 {
            self.max_speed * (2.0 * u[1] - 1.0)
        } else {
            0.0
        };
        let heading = std::f64::consts::TAU * u[2];
        let w = [speed * heading.cos(), speed * heading.sin()];
        let tau = |i: usize| (i + 1) as f64 * self.step;
        let clear = |j: usize| {
            let at = [velocity[0] * tau(j), velocity[1] * tau(j)];
            let start = [at[0] - w[0] * tau(j), at[1] - w[1] * tau(j)];
            let keeps = future.iter().enumerate().all(|(i, p)| {
                let q = [start[0] + w[0] * tau(i), start[1] + w[1] * tau(i)];
                (p.x - q[0]).hypot(p.y - q[1]) >= self.clearance
            });
            (keeps && start[0].hypot(start[1]) >= self.clearance).then_some(start)
        };
        // Waypoints from a quarter of the horizon on, where the walker has had time to react.
        let places: Vec<[f64; 2]> = (future.len() / 4..future.len()).filter_map(clear).collect();
        let last = places.len().checked_sub(1)?;
        let pick = places[((u[0] * places.len() as f64) as usize).min(last)];
        Some(BevAgent {
            position: pick,
            velocity: w,
            radius: self.radius,
        })
    }
}

impl Default for TrainOptions {
    fn default() -> Self {
        Self {
            seed: 0,
            batch_size: 256,
            steps: 20_000,
            lr: 1e-3,
            lr_min: 1e-5,
            warmup_steps: 500,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 1e-4,
            grad_clip: 1.0,
            ema_decay: 0.999,
            time: TimeDistribution::default(),
            mirror: false,
            path_sigma: 0.0,
            goal: true,
            velocity: true,
            counterfactual: None,
            clearance: None,
        }
    }
}

/// Memory a training run may plan for one batch (bytes): 16 GiB, the most a machine that
/// trains this model on its CPU can be expected to have free.
pub const MAX_BATCH_BYTES: u64 = 16 << 30;

/// A lower bound on the memory one example takes in a training step (bytes): its inputs (the
/// raster, the crowd points, goal and velocity, the noisy and target trajectories) and the
/// activations the backward pass keeps (one map per BEV encoder channel, the raster halving at
/// each of its three levels; one per U-Net channel and waypoint, four per level), in f32,
/// counted twice (values and gradients): about 346 KiB for the shipped network.
pub fn bytes_per_example(net: &NetConfig) -> u64 {
    // Saturating: a configuration is checked with this before anything else bounds its sizes.
    let n = |v: usize| v as u64;
    let cells = n(net.bev_cells);
    let crowd = net.crowd.as_ref().map_or(0, |c| {
        n(c.points).saturating_mul(n(crate::net::CROWD_FEATURES as usize))
    });
    let inputs = cells
        .saturating_mul(cells)
        .saturating_mul(3)
        .saturating_add(crowd)
        .saturating_add(4)
        .saturating_add(n(net.horizon).saturating_mul(6));
    let encoder = net
        .bev_channels
        .iter()
        .enumerate()
        .map(|(k, &c)| n(c).saturating_mul((cells >> k).saturating_pow(2)))
        .fold(0u64, u64::saturating_add);
    let unet = n(net.horizon).saturating_mul(4).saturating_mul(
        net.down_dims
            .iter()
            .map(|&d| n(d))
            .fold(0, u64::saturating_add),
    );
    inputs
        .saturating_add(encoder)
        .saturating_add(unet)
        .saturating_mul(8)
}

/// The largest `train.batch_size` for `net` ([`MAX_BATCH_BYTES`] over [`bytes_per_example`]).
pub fn max_batch_size(net: &NetConfig) -> usize {
    usize::try_from(MAX_BATCH_BYTES / bytes_per_example(net).max(1)).unwrap_or(usize::MAX)
}

impl TrainOptions {
    /// Checks `batch_size` against [`max_batch_size`] of `net`: a batch of 10⁹ examples grew
    /// to 12 GB of batch building before it was killed.
    pub fn check_batch_size(&self, net: &NetConfig) -> Result<(), CfmError> {
        let max = max_batch_size(net);
        if self.batch_size > max {
            return Err(CfmError::option(
                "train.batch_size",
                format!(
                    "{} examples need at least {:.1} GiB ({} KiB each for this [net]); the \
                     largest batch is {max} ({} GiB)",
                    self.batch_size,
                    self.batch_size as f64 * bytes_per_example(net) as f64 / (1u64 << 30) as f64,
                    bytes_per_example(net) / 1024,
                    MAX_BATCH_BYTES >> 30
                ),
            ));
        }
        Ok(())
    }

    /// Checks every option is in range.
    pub fn validate(&self) -> Result<(), CfmError> {
        if self.batch_size == 0 {
            return Err(CfmError::option("train.batch_size", "must be positive"));
        }
        if self.steps == 0 {
            return Err(CfmError::option("train.steps", "must be positive"));
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            return Err(CfmError::option("train.lr", "must be finite and > 0"));
        }
        if !(self.lr_min >= 0.0 && self.lr_min <= self.lr) {
            return Err(CfmError::option("train.lr_min", "must lie in [0, lr]"));
        }
        for (f, v) in [
            ("train.beta1", self.beta1),
            ("train.beta2", self.beta2),
            ("train.ema_decay", self.ema_decay),
        ] {
            if !(0.0..1.0).contains(&v) {
                return Err(CfmError::option(f, "must lie in [0, 1)"));
            }
        }
        if self.eps.is_nan() || self.eps <= 0.0 {
            return Err(CfmError::option("train.eps", "must be > 0"));
        }
        if self.weight_decay.is_nan() || self.weight_decay < 0.0 {
            return Err(CfmError::option("train.weight_decay", "must be >= 0"));
        }
        if self.grad_clip.is_nan() || self.grad_clip <= 0.0 {
            return Err(CfmError::option("train.grad_clip", "must be > 0"));
        }
        if !(self.path_sigma.is_finite() && (0.0..=1.0).contains(&self.path_sigma)) {
            return Err(CfmError::option(
                "train.path_sigma",
                format!("{} must lie in [0, 1] (normalised units)", self.path_sigma),
            ));
        }
        if let Some(c) = &self.counterfactual {
            c.validate()?;
        }
        if let Some(c) = &self.clearance {
            c.validate()?;
        }
        self.time.validate()
    }

    /// Learning rate at `step` (0-based): linear warm-up, then cosine decay to `lr_min`.
    pub fn lr_at(&self, step: u64) -> f64 {
        if step < self.warmup_steps {
            return self.lr * (step + 1) as f64 / self.warmup_steps as f64;
        }
        let span = self.steps.saturating_sub(self.warmup_steps).max(1) as f64;
        let p = ((step - self.warmup_steps) as f64 / span).min(1.0);
        self.lr_min + 0.5 * (self.lr - self.lr_min) * (1.0 + (std::f64::consts::PI * p).cos())
    }

    /// One line describing the optimiser, for the model card.
    pub fn describe_optimiser(&self) -> String {
        format!(
            "AdamW (beta1 {}, beta2 {}, eps {:e}, weight decay {:e}), lr {:e} with {} warm-up \
             steps then cosine to {:e}, gradient clipping at global norm {}, EMA decay {}",
            self.beta1,
            self.beta2,
            self.eps,
            self.weight_decay,
            self.lr,
            self.warmup_steps,
            self.lr_min,
            self.grad_clip,
            self.ema_decay
        )
    }
}

/// One point of the loss history.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LossRecord {
    /// Optimiser steps done.
    pub step: u64,
    /// Mean training loss since the previous record.
    pub train_loss: f64,
    /// Validation loss of the EMA weights (NaN when no validation data).
    pub val_loss: f64,
    /// Learning rate at this step.
    pub lr: f64,
    /// Training seconds so far (across resumes).
    pub elapsed_s: f64,
}

/// One training step and where its wall time went ([`Trainer::train_step_timed`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepTimes {
    /// The batch loss (before the update).
    pub loss: f64,
    /// Seconds to draw the batch indices and build the batch: flow times, source noise,
    /// geodesic points and targets, trajectory features, the BEV stack and the normalised
    /// conditions, as tensors.
    pub batch_s: f64,
    /// Seconds of the forward pass and the loss (condition encoding, FiLM, U-Net, MSE).
    pub forward_s: f64,
    /// Seconds of the backward pass.
    pub backward_s: f64,
    /// Seconds of the update: gradient-norm clipping, AdamW and the EMA.
    pub update_s: f64,
}

impl StepTimes {
    /// Seconds of the whole step.
    pub fn total_s(&self) -> f64 {
        self.batch_s + self.forward_s + self.backward_s + self.update_s
    }
}

/// Files of a checkpoint, all listed in its manifest.
const CHECKPOINT_FILES: [&str; 2] = ["state.safetensors", "state.toml"];
/// The manifest of a checkpoint, written after every other file.
pub use human2nav_core::fileset::MANIFEST_FILE;

/// The complete checkpoint set to resume from at `ckpt`, if any ([`fileset::find_complete`]):
///
/// * `ckpt` with a manifest that matches its files: that set;
/// * otherwise `<ckpt>.old` with a matching manifest (a save was interrupted between its two
///   renames): that set;
/// * no `ckpt` folder (or an empty one): `None`, a fresh start;
/// * anything else (a file missing, sizes or checksums that disagree, both files without a
///   manifest, a `ckpt` that is a file or a loop of links): an error naming the folder and
///   what is wrong. Training never restarts from step 0 on its own.
pub fn find_checkpoint(ckpt: &Path) -> Result<Option<PathBuf>, CfmError> {
    fileset::find_complete(ckpt, &CHECKPOINT_FILES).map_err(|e| match e {
        SetError::Incomplete { path, reason } => CfmError::Checkpoint {
            path,
            reason: format!(
                "{reason}; the set is incomplete (restore it, or start over with --fresh)"
            ),
        },
        other => other.into(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_batch_beyond_the_memory_bound_is_refused_naming_the_field() {
        let net = NetConfig::default();
        assert_eq!(bytes_per_example(&net), 353_824);
        let max = max_batch_size(&net);
        assert!(max > 10_000, "{max}");
        let at = |batch_size| TrainOptions {
            batch_size,
            ..TrainOptions::default()
        };
        assert!(at(128).check_batch_size(&net).is_ok());
        assert!(at(max).check_batch_size(&net).is_ok());
        let err = at(1_000_000_000)
            .check_batch_size(&net)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("train.batch_size") && err.contains(&format!("largest batch is {max}")),
            "{err}"
        );
        // Sizes no validation has bounded yet saturate instead of overflowing.
        let huge = NetConfig {
            bev_cells: usize::MAX,
            ..NetConfig::default()
        };
        assert_eq!(bytes_per_example(&huge), u64::MAX);
        assert!(at(1).check_batch_size(&huge).is_err());
    }
}
