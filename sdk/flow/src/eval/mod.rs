//! Held-out evaluation of a flow model: best-of-K ADE/FDE against the true futures, the
//! constant-velocity baseline on the same windows, and how often trajectories come close to
//! other agents.
//!
//! * ADE: mean over the `T` waypoints of the Euclidean position error; FDE: error at the last
//!   waypoint. Best-of-K takes the minimum over the `K` sampled futures of each window
//!   (ADE and FDE minimised separately, the usual convention).
//! * Constant velocity: waypoint `j` (time `(j + 1)·dt`) at `(j + 1)·dt·v` with `v` the ego
//!   velocity of the condition (ego frame).
//! * The samples' mean: the `K` samples averaged waypoint by waypoint, scored as one point
//!   forecast. One sample of a model that does not know the goal is a worse guess than
//!   constant velocity; their mean may be a better one, and a point forecast is what a
//!   planner that must not wait for every possible turn would use.
//! * Early ADE: the ADE over the waypoints of the first [`EvalOptions::early`] seconds only,
//!   where a prediction's errors decide what a robot next to the walker does.
//! * Proximity: a trajectory "comes within `r`" of another agent when, at some waypoint `j`,
//!   its position is closer than `r` to that agent's position at the same time. Reported as the
//!   fraction of sampled trajectories (model) and of windows (ground truth) that do.

use crate::cfm::sample_source;
use crate::error::CfmError;
use crate::sampler::{integrate, sample};
use human2nav_core::bev::BevSpec;
use human2nav_core::constraint::{ConstraintContext, Phi};
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel};
use human2nav_core::forecast;
use human2nav_core::guidance::{self, GuidanceError, GuidanceSettings, GuidanceWorkspace};
use human2nav_core::se2::Pose2;
use human2nav_core::se2::Twist2;
use human2nav_core::{Limits, feasibility};
use human2nav_data::resample::Scene;
use human2nav_data::track::AgentClass;
use human2nav_data::tuples::{TrainingTuple, TupleOptions, scene_tuples};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeSet;

/// One held-out window.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalWindow {
    /// The model's condition (BEV, goal, ego velocity).
    pub cond: FlowCondition,
    /// The true future, `T` poses in the ego frame.
    pub future: Vec<Pose2>,
    /// Other agents' positions over the same `T` future steps, ego frame; `None` where an
    /// agent is not observed. Empty when unknown.
    pub others: Vec<Vec<Option<[f64; 2]>>>,
    /// The agents observed at the window's start walking on at their velocity then: `T`
    /// positions each, ego frame (what a planner predicts of them). Empty when unknown.
    pub others_cv: Vec<Vec<[f64; 2]>>,
}

impl EvalWindow {
    /// The window of a training tuple (its BEV, goal, velocity and future) with the other
    /// agents' future positions `others` and their constant-velocity futures `others_cv`.
    pub fn from_tuple(
        t: TrainingTuple,
        others: Vec<Vec<Option<[f64; 2]>>>,
        others_cv: Vec<Vec<[f64; 2]>>,
    ) -> Self {
        Self {
            cond: FlowCondition {
                bev: t.bev,
                goal: [t.goal[0] as f64, t.goal[1] as f64],
                velocity: [t.velocity[0] as f64, t.velocity[1] as f64],
            },
            future: t
                .future
                .iter()
                .map(|p| Pose2::new(p[0] as f64, p[1] as f64, p[2] as f64))
                .collect(),
            others,
            others_cv,
        }
    }
}

/// Options of [`evaluate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvalOptions {
    /// Samples per window `K`. Default 20.
    pub samples: usize,
    /// Euler steps `N`. Default 10.
    pub steps: usize,
    /// Waypoint spacing in seconds (for the constant-velocity baseline). Default 0.1.
    pub dt: f64,
    /// Proximity radius in metres. Default 0.3.
    pub radius: f64,
    /// Seed of the source samples.
    pub seed: u64,
    /// Seconds of the early ADEs (at least one waypoint). Default 1.
    pub early: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            samples: 20,
            steps: 10,
            dt: 0.1,
            radius: 0.3,
            seed: 0,
            early: 1.0,
        }
    }
}

/// Aggregated metrics over all windows (means over windows).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EvalMetrics {
    /// Windows evaluated.
    pub windows: usize,
    /// Best-of-K average displacement error (m).
    pub min_ade: f64,
    /// Best-of-K final displacement error (m).
    pub min_fde: f64,
    /// Average displacement error of all samples, not only the best (m).
    pub mean_ade: f64,
    /// Average displacement error of the constant-velocity baseline (m).
    pub cv_ade: f64,
    /// Final displacement error of the constant-velocity baseline (m).
    pub cv_fde: f64,
    /// Average displacement error of the samples' mean, one point forecast (m).
    pub centroid_ade: f64,
    /// Final displacement error of the samples' mean (m).
    pub centroid_fde: f64,
    /// Waypoints of the early ADEs below.
    pub early_steps: usize,
    /// Mean over samples of the ADE over the first `early_steps` waypoints (m).
    pub early_mean_ade: f64,
    /// The samples' mean's ADE over the first `early_steps` waypoints (m).
    pub early_centroid_ade: f64,
    /// Constant velocity's ADE over the first `early_steps` waypoints (m).
    pub early_cv_ade: f64,
    /// Fraction of sampled trajectories within `radius` of another agent.
    pub proximity_model: f64,
    /// Fraction of true futures within `radius` of another agent.
    pub proximity_truth: f64,
    /// Fraction of constant-velocity predictions within `radius` of another agent.
    pub proximity_cv: f64,
}

/// `(ADE, FDE)` of a predicted trajectory (flat `[T, 3]`) against the truth, over the
/// waypoints both have (a prefix of either scores that prefix).
pub fn displacement_errors(pred: &[f64], truth: &[Pose2]) -> (f64, f64) {
    let (mut sum, mut last, mut n) = (0.0, 0.0, 0usize);
    for (p, q) in pred.chunks_exact(3).zip(truth) {
        last = ((p[0] - q.x).powi(2) + (p[1] - q.y).powi(2)).sqrt();
        sum += last;
        n += 1;
    }
    (sum / n.max(1) as f64, last)
}

/// The constant-velocity prediction of `horizon` waypoints from the origin
/// ([`forecast::constant_velocity_positions`]), flat `[T, 3]` (heading along the velocity, or
/// 0 when standing).
pub fn constant_velocity(velocity: [f64; 2], horizon: usize, dt: f64) -> Vec<f64> {
    let heading = if velocity[0].hypot(velocity[1]) > 1e-6 {
        velocity[1].atan2(velocity[0])
    } else {
        0.0
    };
    forecast::constant_velocity_positions([0.0, 0.0], velocity, horizon, dt)
        .into_iter()
        .flat_map(|p| [p[0], p[1], heading])
        .collect()
}

/// Whether a trajectory (flat `[T, 3]`) comes within `radius` of any other agent.
pub fn comes_close(traj: &[f64], others: &[Vec<Option<[f64; 2]>>], radius: f64) -> bool {
    others.iter().any(|agent| {
        traj.chunks_exact(3).zip(agent).any(|(p, o)| match o {
            Some(o) => (p[0] - o[0]).hypot(p[1] - o[1]) < radius,
            None => false,
        })
    })
}

/// The evaluation windows of one scene, with the other agents' true future positions.
///
/// The windows are exactly the tuples [`scene_tuples`] builds for the scene (same BEV, goal,
/// velocity and future, so they match the cache's tuples); this function walks the ego tracks
/// in the same order to recover each window's ego track and step, checks that the recovered
/// future equals the tuple's, and adds every other agent's position in the ego frame at each
/// of the `T` future steps (`None` where the agent is not present).
pub fn scene_windows(
    scene: &Scene,
    scene_index: u16,
    spec: &BevSpec,
    opts: &TupleOptions,
) -> Result<Vec<EvalWindow>, CfmError> {
    let (tuples, _) = scene_tuples(scene, scene_index, spec, opts);
    let h = opts.horizon;
    let mut keys = Vec::with_capacity(tuples.len());
    for (e, ego) in scene.tracks.iter().enumerate() {
        if ego.class != AgentClass::Pedestrian || ego.len() < h + 1 {
            continue;
        }
        let mut k = 0;
        while k + h < ego.len() {
            let (p0, pe) = (ego.positions[k], ego.positions[k + h]);
            if (pe[0] - p0[0]).hypot(pe[1] - p0[1]) >= opts.min_future_displacement {
                keys.push((e, k));
            }
            k += opts.stride;
        }
    }
    let mismatch = |reason: String| CfmError::EvalData {
        scene: scene.name.clone(),
        reason,
    };
    if keys.len() != tuples.len() {
        return Err(mismatch(format!(
            "{} windows recovered, {} tuples built",
            keys.len(),
            tuples.len()
        )));
    }
    let index = scene.index();
    let mut out = Vec::with_capacity(tuples.len());
    for (&(e, k), tup) in keys.iter().zip(&tuples) {
        let ego = &scene.tracks[e];
        let pose = ego.pose(k);
        let last = pose.between(ego.pose(k + h));
        let f = tup.future[h - 1];
        if (last.x - f[0] as f64).abs() > 1e-4 || (last.y - f[1] as f64).abs() > 1e-4 {
            return Err(mismatch(format!(
                "window of track {} at step {k} does not match",
                ego.id
            )));
        }
        let step = ego.start + k as i64;
        let mut others_idx = BTreeSet::new();
        for j in 1..=h as i64 {
            others_idx.extend(
                index
                    .at(step + j)
                    .iter()
                    .map(|&i| i as usize)
                    .filter(|&i| i != e),
            );
        }
        let others = others_idx
            .into_iter()
            .map(|i| {
                let t = &scene.tracks[i];
                (1..=h as i64)
                    .map(|j| t.local(step + j).map(|l| pose.inverse_act(t.positions[l])))
                    .collect()
            })
            .collect();
        // Everyone seen now and a step before, walking on at that step's velocity.
        let others_cv = index
            .at(step)
            .iter()
            .map(|&i| i as usize)
            .filter(|&i| i != e)
            .filter_map(|i| {
                let t = &scene.tracks[i];
                let (now, before) = (t.local(step)?, t.local(step - 1)?);
                let (p, q) = (t.positions[now], t.positions[before]);
                let v = [(p[0] - q[0]) / scene.dt, (p[1] - q[1]) / scene.dt];
                Some(
                    forecast::constant_velocity_positions(p, v, h, scene.dt)
                        .into_iter()
                        .map(|q| pose.inverse_act(q))
                        .collect(),
                )
            })
            .collect();
        out.push(EvalWindow::from_tuple(
            tup.to_tuple(spec),
            others,
            others_cv,
        ));
    }
    Ok(out)
}

/// How much a model's samples react to the crowd in their input (the crowd-awareness probe):
/// the same source samples integrated with the window's BEV raster as observed and emptied.
/// Shares are over every sample of every window.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CrowdProbe {
    /// Windows probed.
    pub windows: usize,
    /// Distance between centres (m) below which a sample meets someone.
    pub contact: f64,
    /// Share of samples meeting someone on their recorded future, crowd observed.
    pub observed_recorded: f64,
    /// The same with the crowd hidden from the model.
    pub hidden_recorded: f64,
    /// Share of samples meeting someone walking on at constant velocity, crowd observed.
    pub observed_cv: f64,
    /// The same with the crowd hidden.
    pub hidden_cv: f64,
    /// The recorded human's own share at the same windows, against the recorded futures.
    pub human_recorded: f64,
    /// The recorded human's share against constant-velocity futures.
    pub human_cv: f64,
    /// Mean distance (m) between a sample and its twin drawn with the crowd hidden, over
    /// samples and waypoints.
    pub displacement: f64,
}

/// Whether a trajectory (flat `[T, 3]`) comes within `contact` of any of `paths` at the same
/// waypoint.
pub fn meets(traj: &[f64], paths: &[Vec<[f64; 2]>], contact: f64) -> bool {
    paths.iter().any(|path| {
        traj.chunks_exact(3)
            .zip(path)
            .any(|(p, o)| (p[0] - o[0]).hypot(p[1] - o[1]) < contact)
    })
}

/// The crowd-awareness probe of `model` on `windows` ([`CrowdProbe`]): `opts.samples` source
/// samples per window (seeded by `opts.seed`), each integrated in `opts.steps` steps once with
/// the window's raster and once with an empty one; `progress` is called after each window.
pub fn crowd_probe<M: FlowModel + ?Sized>(
    model: &M,
    windows: &[EvalWindow],
    opts: &EvalOptions,
    contact: f64,
    mut progress: impl FnMut(usize),
) -> Result<CrowdProbe, FlowError> {
    let t = model.horizon();
    let mut probe = CrowdProbe {
        windows: windows.len(),
        contact,
        ..CrowdProbe::default()
    };
    if windows.is_empty() {
        return Ok(probe);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let count = |b: bool| f64::from(u8::from(b));
    for (w, win) in windows.iter().enumerate() {
        let x0 = sample_source(opts.samples, t, model.source_std(), &mut rng);
        let mut observed = x0.clone();
        integrate(model, &mut observed, &win.cond, opts.steps)?;
        let hidden_cond = FlowCondition {
            bev: vec![0.0; win.cond.bev.len()],
            ..win.cond.clone()
        };
        let mut hidden = x0;
        integrate(model, &mut hidden, &hidden_cond, opts.steps)?;
        for (o, h) in observed.chunks_exact(3 * t).zip(hidden.chunks_exact(3 * t)) {
            probe.observed_recorded += count(comes_close(o, &win.others, contact));
            probe.hidden_recorded += count(comes_close(h, &win.others, contact));
            probe.observed_cv += count(meets(o, &win.others_cv, contact));
            probe.hidden_cv += count(meets(h, &win.others_cv, contact));
            probe.displacement += mean_distance(o, h);
        }
        let truth: Vec<f64> = win.future.iter().flat_map(|p| p.to_array()).collect();
        probe.human_recorded += count(comes_close(&truth, &win.others, contact));
        probe.human_cv += count(meets(&truth, &win.others_cv, contact));
        progress(w + 1);
    }
    let samples = (windows.len() * opts.samples) as f64;
    for v in [
        &mut probe.observed_recorded,
        &mut probe.hidden_recorded,
        &mut probe.observed_cv,
        &mut probe.hidden_cv,
        &mut probe.displacement,
    ] {
        *v /= samples;
    }
    probe.human_recorded /= windows.len() as f64;
    probe.human_cv /= windows.len() as f64;
    Ok(probe)
}

/// What [`counterfactual_probe`] measured: over the windows where a standing person fits on
/// the walker's constant-velocity line clear of its recorded future
/// ([`crate::train::Counterfactual::person`]), the share of samples that come within
/// `contact` of that person with the person in the raster (`observed`) and without
/// (`hidden`, the window as recorded), and the mean distance between the two sample sets.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CounterfactualProbe {
    /// Windows where a person fitted (of those probed).
    pub windows: usize,
    /// Share of samples meeting the person, person in the raster.
    pub observed: f64,
    /// Share of samples meeting the person's place, person not in the raster.
    pub hidden: f64,
    /// Mean distance (m) between a sample with and without the person.
    pub displacement: f64,
}

/// Does the model avoid a person it sees on its way, whom the recorded human's future
/// avoided? On each window a standing person is placed as the counterfactual augmentation
/// would place one ([`crate::train::Counterfactual::place`]), and the same source samples are
/// integrated with and without that person in the window's raster (`spec`).
pub fn counterfactual_probe<M: FlowModel + ?Sized>(
    model: &M,
    windows: &[EvalWindow],
    opts: &EvalOptions,
    (person, spec): (&crate::train::Counterfactual, BevSpec),
    contact: f64,
    mut progress: impl FnMut(usize),
) -> Result<CounterfactualProbe, FlowError> {
    use rand::Rng;
    let t = model.horizon();
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x00c0_ffee);
    let mut probe = CounterfactualProbe::default();
    let (mut disc, mut samples) = (Vec::new(), 0usize);
    for (w, win) in windows.iter().enumerate() {
        progress(w + 1);
        let u: f64 = rng.random();
        let Some(a) = person.place(&win.future, win.cond.velocity, [u, 0.0, 0.0]) else {
            continue;
        };
        let mut seen = win.cond.clone();
        human2nav_core::bev::overlay_agent(spec, a, &mut seen.bev, &mut disc);
        let x0 = sample_source(opts.samples, t, model.source_std(), &mut rng);
        let mut observed = x0.clone();
        integrate(model, &mut observed, &seen, opts.steps)?;
        let mut hidden = x0;
        integrate(model, &mut hidden, &win.cond, opts.steps)?;
        let standing = [vec![a.position; t]];
        for (o, h) in observed.chunks_exact(3 * t).zip(hidden.chunks_exact(3 * t)) {
            probe.observed += f64::from(u8::from(meets(o, &standing, contact)));
            probe.hidden += f64::from(u8::from(meets(h, &standing, contact)));
            probe.displacement += mean_distance(o, h);
            samples += 1;
        }
        probe.windows += 1;
    }
    if samples > 0 {
        let n = samples as f64;
        probe.observed /= n;
        probe.hidden /= n;
        probe.displacement /= n;
    }
    Ok(probe)
}

/// The mean distance (m) between the waypoints of two paths (flat `[T, 3]`).
fn mean_distance(a: &[f64], b: &[f64]) -> f64 {
    let t = (a.len() / 3).max(1);
    a.chunks_exact(3)
        .zip(b.chunks_exact(3))
        .map(|(p, q)| (p[0] - q[0]).hypot(p[1] - q[1]))
        .sum::<f64>()
        / t as f64
}

/// Keeps a seeded random subset of at most `n` items (order shuffled).
pub fn subsample<T>(items: &mut Vec<T>, n: usize, seed: u64) {
    use rand::seq::SliceRandom;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    items.shuffle(&mut rng);
    items.truncate(n);
}

/// Evaluates `model` on `windows`; `progress` is called after each window.
pub fn evaluate<M: FlowModel + ?Sized>(
    model: &M,
    windows: &[EvalWindow],
    opts: &EvalOptions,
    mut progress: impl FnMut(usize),
) -> Result<EvalMetrics, FlowError> {
    let t = model.horizon();
    let mut m = EvalMetrics {
        windows: windows.len(),
        ..EvalMetrics::default()
    };
    if windows.is_empty() {
        return Ok(m);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let mut close_samples = 0usize;
    let early = ((opts.early / opts.dt).round() as usize).clamp(1, t);
    m.early_steps = early;
    for (w, win) in windows.iter().enumerate() {
        if win.future.len() != t {
            return Err(FlowError::Shape(format!(
                "window {w}: {} future poses, model horizon {t}",
                win.future.len()
            )));
        }
        let x = sample(model, &win.cond, opts.samples, opts.steps, &mut rng)?;
        let (mut best_ade, mut best_fde, mut mean_ade) = (f64::INFINITY, f64::INFINITY, 0.0);
        let mut centroid = vec![0.0; 3 * t];
        let share = 1.0 / opts.samples as f64;
        for traj in x.chunks_exact(3 * t) {
            let (ade, fde) = displacement_errors(traj, &win.future);
            best_ade = best_ade.min(ade);
            best_fde = best_fde.min(fde);
            mean_ade += ade * share;
            m.early_mean_ade += displacement_errors(&traj[..3 * early], &win.future).0 * share;
            for (c, p) in centroid.chunks_exact_mut(3).zip(traj.chunks_exact(3)) {
                c[0] += p[0] * share;
                c[1] += p[1] * share;
            }
            if comes_close(traj, &win.others, opts.radius) {
                close_samples += 1;
            }
        }
        let (centroid_ade, centroid_fde) = displacement_errors(&centroid, &win.future);
        let cv = constant_velocity(win.cond.velocity, t, opts.dt);
        let (cv_ade, cv_fde) = displacement_errors(&cv, &win.future);
        let truth: Vec<f64> = win.future.iter().flat_map(|p| p.to_array()).collect();
        m.min_ade += best_ade;
        m.min_fde += best_fde;
        m.mean_ade += mean_ade;
        m.cv_ade += cv_ade;
        m.cv_fde += cv_fde;
        m.centroid_ade += centroid_ade;
        m.centroid_fde += centroid_fde;
        m.early_centroid_ade += displacement_errors(&centroid[..3 * early], &win.future).0;
        m.early_cv_ade += displacement_errors(&cv[..3 * early], &win.future).0;
        m.proximity_truth += f64::from(u8::from(comes_close(&truth, &win.others, opts.radius)));
        m.proximity_cv += f64::from(u8::from(comes_close(&cv, &win.others, opts.radius)));
        progress(w + 1);
    }
    let n = windows.len() as f64;
    m.min_ade /= n;
    m.min_fde /= n;
    m.mean_ade /= n;
    m.cv_ade /= n;
    m.cv_fde /= n;
    m.centroid_ade /= n;
    m.centroid_fde /= n;
    m.early_mean_ade /= n;
    m.early_centroid_ade /= n;
    m.early_cv_ade /= n;
    m.proximity_truth /= n;
    m.proximity_cv /= n;
    m.proximity_model = close_samples as f64 / (n * opts.samples as f64);
    Ok(m)
}

/// Algorithm 1 on recorded human windows, every sample guided: how feasible the raw and the
/// guided samples are for one robot, and how far guidance moves them from the human data.
/// Means over windows of means over the `K` samples of each.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GuidedWindowMetrics {
    /// Windows evaluated.
    pub windows: usize,
    /// TFS of the recorded futures themselves (pose 0 the ego at the window's velocity).
    pub tfs_human: f64,
    /// TFS of the samples before guidance.
    pub tfs_raw: f64,
    /// TFS of the samples after guidance.
    pub tfs_guided: f64,
    /// Mean over samples of the ADE to the recorded future before guidance (m).
    pub ade_raw: f64,
    /// Mean over samples of the ADE to the recorded future after guidance (m).
    pub ade_guided: f64,
    /// Best-of-K ADE before guidance (m).
    pub min_ade_raw: f64,
    /// Best-of-K ADE after guidance (m).
    pub min_ade_guided: f64,
    /// Mean distance (m) between each guided sample and the same sample before guidance.
    pub displacement: f64,
    /// Φ (the robot's soft constraint cost, Eq. 9) of the samples before guidance.
    pub phi_raw: f64,
    /// Φ of the samples after guidance.
    pub phi_guided: f64,
    /// Algorithm 1 iterations run per window (mean).
    pub iterations: f64,
}

/// Runs [`guidance::sample_guided`] with `settings` on `samples` draws per window (seeded) and
/// measures raw and guided samples against the recorded futures; the robot at each window
/// moves at the recorded ego velocity. `progress` is called after each window.
pub fn guided_windows<M: FlowModel + ?Sized>(
    model: &M,
    windows: &[EvalWindow],
    phi: &Phi,
    limits: &Limits,
    settings: &GuidanceSettings,
    opts: &EvalOptions,
    mut progress: impl FnMut(usize),
) -> Result<GuidedWindowMetrics, GuidanceError> {
    let t = model.horizon();
    let mut m = GuidedWindowMetrics {
        windows: windows.len(),
        ..GuidedWindowMetrics::default()
    };
    if windows.is_empty() {
        return Ok(m);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let mut ws = GuidanceWorkspace::new();
    let mut scratch = Vec::new();
    let k = opts.samples as f64;
    for (w, win) in windows.iter().enumerate() {
        if win.future.len() != t {
            return Err(GuidanceError::Shape(format!(
                "window {w}: {} future poses, model horizon {t}",
                win.future.len()
            )));
        }
        let v0 = Twist2::new(win.cond.velocity[0], win.cond.velocity[1], 0.0);
        let ctx = ConstraintContext {
            dt: opts.dt,
            limits,
            initial_velocity: v0,
            agents: &[],
            scene: Default::default(),
        };
        let x0 = sample_source(opts.samples, t, model.source_std(), &mut rng);
        let r = guidance::sample_guided(model, &win.cond, &x0, phi, &ctx, settings, &mut ws)?;
        let mut tfs = |traj: &[f64]| {
            let poses: Vec<f64> = Pose2::IDENTITY
                .to_array()
                .into_iter()
                .chain(traj.iter().copied())
                .collect();
            feasibility::tfs_plan_flat(&poses, opts.dt, limits, v0, &mut scratch)
        };
        let truth: Vec<f64> = win.future.iter().flat_map(|p| p.to_array()).collect();
        m.tfs_human += tfs(&truth);
        let (mut best_raw, mut best_guided) = (f64::INFINITY, f64::INFINITY);
        for (raw, guided) in r
            .unguided
            .chunks_exact(3 * t)
            .zip(r.guided.chunks_exact(3 * t))
        {
            let (ade_raw, _) = displacement_errors(raw, &win.future);
            let (ade_guided, _) = displacement_errors(guided, &win.future);
            best_raw = best_raw.min(ade_raw);
            best_guided = best_guided.min(ade_guided);
            m.ade_raw += ade_raw / k;
            m.ade_guided += ade_guided / k;
            m.tfs_raw += tfs(raw) / k;
            m.tfs_guided += tfs(guided) / k;
            let gap: f64 = raw
                .chunks_exact(3)
                .zip(guided.chunks_exact(3))
                .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
                .sum();
            m.displacement += gap / (t as f64 * k);
        }
        m.min_ade_raw += best_raw;
        m.min_ade_guided += best_guided;
        m.phi_raw += r.phi_before.iter().sum::<f64>() / k;
        m.phi_guided += r.phi_after.iter().sum::<f64>() / k;
        m.iterations += r.iterations_run as f64;
        progress(w + 1);
    }
    let n = windows.len() as f64;
    for v in [
        &mut m.tfs_human,
        &mut m.tfs_raw,
        &mut m.tfs_guided,
        &mut m.ade_raw,
        &mut m.ade_guided,
        &mut m.min_ade_raw,
        &mut m.min_ade_guided,
        &mut m.displacement,
        &mut m.phi_raw,
        &mut m.phi_guided,
        &mut m.iterations,
    ] {
        *v /= n;
    }
    Ok(m)
}

#[cfg(test)]
mod tests;
