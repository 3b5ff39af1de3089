//! How well simple pedestrian predictors foresee the recorded crowds of an episode file: the
//! offline study behind `human2nav data predict`.
//!
//! Every planner of the benchmark sees a pedestrian as its present position and the velocity of
//! its last 0.1 s step (the simulator's causal observation), and Human2Nav's selection extends
//! that velocity over its 3.2 s plan. This module asks whether anything a planner could compute
//! from the same history predicts better. It cuts every recorded track of an episode file into
//! windows (a history of `history` steps, a future of `horizon` steps, one window every
//! `stride` steps) and scores, by average and final displacement error (ADE, FDE) and by ADE
//! over the first second:
//!
//! * [`Predictor::LastStep`]: the last step's velocity held (what the planners use);
//! * [`Predictor::MeanVelocity`]: the mean velocity over the last `n` steps, held;
//! * [`Predictor::Static`]: the present position held;
//! * [`Predictor::ConstantTurn`]: the last step's speed held, its direction turning on at the
//!   rate it turned over the last `n` steps (constant turn rate and velocity, the classical
//!   model of a walker in a turn);
//! * [`Predictor::SocialForce`]: the pedestrian and the people within 6 m of it walk on at
//!   their last steps' velocities while keeping clear of each other, by the social force model
//!   of Helbing & Molnár ([`human2nav_core::social_force`], with their parameters), each driven
//!   towards its last step's velocity and pushed off the others' discs. The one predictor here
//!   that sees the other people, as an interaction-aware predictor must;
//! * [`Predictor::Ridge`]: a linear model learned from data. In the frame of the pedestrian's
//!   heading, it maps the `history` step velocities (and a constant) to the future's departure
//!   from the last-step prediction, fitted by ridge regression. It is scored leave-one-scene-out:
//!   the windows of each scene are predicted by a model fitted on the other scenes' windows, so
//!   that no scene is scored by a model that has seen it;
//! * [`Predictor::RidgeTrained`]: the same model fitted on the windows of other scenes handed to
//!   [`study_with_training`] (the training split's, many more than the file's own), when given.
//!
//! The same pedestrian appears in many episodes of a file (the crowds of nearby episodes
//! overlap), so tracks are taken once per scene, identity and first position.

use crate::error::DataError;
use crate::resample::Scene;
use crate::scenario::EpisodeSuite;
use human2nav_core::forecast::{self, HistoryRidge};
use human2nav_core::se2::Pose2;
use human2nav_core::social_force::SocialForce;
use nalgebra::{DMatrix, DVector};
use std::collections::{BTreeMap, BTreeSet};

/// Options of the study.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PredictionOptions {
    /// Steps of history a window shows (at least 1; the ridge model's features are their
    /// velocities).
    pub history: usize,
    /// Steps predicted (32 at 0.1 s: the planner's 3.2 s).
    pub horizon: usize,
    /// Steps between the starts of two windows of a track (at least 1).
    pub stride: usize,
    /// Ridge regularisation `λ` of the learned model (added to `XᵀX`; `≥ 0`).
    pub ridge_lambda: f64,
}

impl Default for PredictionOptions {
    fn default() -> Self {
        Self {
            history: 8,
            horizon: 32,
            stride: 5,
            ridge_lambda: 1.0,
        }
    }
}

impl PredictionOptions {
    fn validate(&self) -> Result<(), DataError> {
        let bad = |field: &str, message: &str| {
            Err(DataError::Option {
                field: field.into(),
                message: message.into(),
            })
        };
        if !(1..=1000).contains(&self.history) {
            return bad("history", "must be 1 to 1000 steps");
        }
        if !(1..=1000).contains(&self.horizon) {
            return bad("horizon", "must be 1 to 1000 steps");
        }
        if !(1..=100_000).contains(&self.stride) {
            return bad("stride", "must be 1 to 100000 steps");
        }
        if !(self.ridge_lambda.is_finite() && self.ridge_lambda >= 0.0) {
            return bad("ridge_lambda", "must be a finite number >= 0");
        }
        Ok(())
    }
}

/// A predictor of the study (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Predictor {
    /// The last step's velocity, held.
    LastStep,
    /// The mean velocity over the last `n` steps, held.
    MeanVelocity(usize),
    /// The present position, held.
    Static,
    /// The last step's speed, turning at the rate of the last `n` steps.
    ConstantTurn(usize),
    /// The last step's velocity as the desired one, with the social force of the people near.
    SocialForce,
    /// The ridge model on the history's velocities, leave-one-scene-out.
    Ridge,
    /// The ridge model fitted on training scenes ([`study_with_training`]).
    RidgeTrained,
}

impl std::fmt::Display for Predictor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::LastStep => write!(f, "last-step velocity (the planners')"),
            Self::MeanVelocity(n) => write!(f, "mean velocity over {n} steps"),
            Self::Static => write!(f, "standing still"),
            Self::ConstantTurn(n) => write!(f, "last step turning at the rate of {n} steps"),
            Self::SocialForce => write!(f, "last step with the social force of the people near"),
            Self::Ridge => write!(f, "ridge on the history, leave-one-scene-out"),
            Self::RidgeTrained => write!(f, "ridge on the history, fitted on the training scenes"),
        }
    }
}

/// Errors of one predictor over a set of windows (metres).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Errors {
    /// Mean over windows of the mean displacement error over the horizon.
    pub ade: f64,
    /// Mean over windows of the displacement error at the horizon's end.
    pub fde: f64,
    /// Mean over windows of the mean displacement error over the first second.
    pub ade_1s: f64,
    /// Windows scored.
    pub windows: usize,
}

/// The study's result: errors per predictor, overall and per scene.
#[derive(Clone, Debug, PartialEq)]
pub struct PredictionReport {
    /// Options the study ran with.
    pub options: PredictionOptions,
    /// Distinct tracks found in the file.
    pub tracks: usize,
    /// Every predictor over all windows.
    pub overall: BTreeMap<Predictor, Errors>,
    /// Per scene (`dataset/scene`), every predictor over that scene's windows.
    pub per_scene: BTreeMap<String, BTreeMap<Predictor, Errors>>,
    /// The ridge model fitted on the training scenes, when there were any.
    pub trained: Option<HistoryRidge>,
}

/// One window: the history (`history + 1` positions, the last the present), the future, and
/// the pedestrian's heading frame ([`heading`]).
struct Window {
    scene: usize,
    past: Vec<[f64; 2]>,
    future: Vec<[f64; 2]>,
    frame: Pose2,
    /// The pedestrian's radius, then the others of its episode within [`NEAR`] of it now.
    radius: f64,
    near: Vec<Walker>,
}

/// How far from a pedestrian the others count for [`Predictor::SocialForce`] (m): the range
/// the planners predict people in.
const NEAR: f64 = 6.0;

/// A pedestrian as the social force model moves it: position, velocity (per step), radius.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Walker {
    p: [f64; 2],
    v: [f64; 2],
    radius: f64,
}

/// The windows of every distinct track of `suite`, and the scene names they index.
fn windows(suite: &EpisodeSuite, o: &PredictionOptions) -> (Vec<Window>, Vec<String>, usize) {
    let mut scenes: Vec<String> = Vec::new();
    let mut seen = BTreeSet::new();
    let mut out = Vec::new();
    for e in &suite.episodes {
        let scene = match scenes.iter().position(|s| *s == e.scene) {
            Some(i) => i,
            None => {
                scenes.push(e.scene.clone());
                scenes.len() - 1
            }
        };
        for (i, a) in e.agents.iter().enumerate() {
            let Some(first) = a.positions.first() else {
                continue;
            };
            if !seen.insert((scene, a.id, first[0].to_bits(), first[1].to_bits())) {
                continue;
            }
            let p = &a.positions;
            out.extend(cut(scene, p, a.radius, o, |k| {
                let step = a.start_step + k;
                e.agents
                    .iter()
                    .enumerate()
                    .filter(|&(j, _)| j != i)
                    .filter_map(|(_, b)| walker_at(b, step))
                    .filter(|w| (w.p[0] - p[k][0]).hypot(w.p[1] - p[k][1]) <= NEAR)
                    .collect()
            }));
        }
    }
    (out, scenes, seen.len())
}

/// The windows of one track's `positions` (module docs); `near(k)`: the people near it at its
/// step `k`.
fn cut<'a>(
    scene: usize,
    positions: &'a [[f64; 2]],
    radius: f64,
    o: &'a PredictionOptions,
    mut near: impl FnMut(usize) -> Vec<Walker> + 'a,
) -> impl Iterator<Item = Window> + 'a {
    (o.history..positions.len().saturating_sub(o.horizon))
        .step_by(o.stride)
        .map(move |k| {
            let past = &positions[k - o.history..=k];
            Window {
                scene,
                past: past.to_vec(),
                future: positions[k + 1..=k + o.horizon].to_vec(),
                frame: HistoryRidge::heading(past),
                radius,
                near: near(k),
            }
        })
}

/// Agent `b` at episode step `step` with its last step's velocity, if it is there and was
/// there a step before.
fn walker_at(b: &crate::scenario::AgentTrack, step: usize) -> Option<Walker> {
    let k = step.checked_sub(b.start_step)?;
    let (now, before) = (*b.positions.get(k)?, *b.positions.get(k.checked_sub(1)?)?);
    Some(Walker {
        p: now,
        v: sub(now, before),
        radius: b.radius,
    })
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

/// Position after `i + 1` steps of velocity `v` (per step) from `p`.
fn held(p: [f64; 2], v: [f64; 2], i: usize) -> [f64; 2] {
    forecast::walk_on(p, v, (i + 1) as f64)
}

/// The constant-turn prediction of a window (`horizon` positions): the last step's length,
/// its direction turning by the mean turn per step of the last `n` steps (the angle from the
/// step `n` steps before the last one to the last one, over `n`). Steps shorter than 1 mm have
/// no direction: then no turn.
fn constant_turn(w: &Window, n: usize, horizon: usize) -> Vec<[f64; 2]> {
    let m = w.past.len();
    let last = sub(w.past[m - 1], w.past[m - 2]);
    let n = n.min(m - 2);
    let before = sub(w.past[m - 1 - n], w.past[m - 2 - n]);
    let speed = last[0].hypot(last[1]);
    let turn = if n == 0 || speed < 1e-3 || before[0].hypot(before[1]) < 1e-3 {
        0.0
    } else {
        let a = last[1].atan2(last[0]) - before[1].atan2(before[0]);
        a.sin().atan2(a.cos()) / n as f64
    };
    let mut heading = last[1].atan2(last[0]);
    let mut p = w.past[m - 1];
    (0..horizon)
        .map(|_| {
            heading += turn;
            p = [p[0] + speed * heading.cos(), p[1] + speed * heading.sin()];
            p
        })
        .collect()
}

/// The social force prediction of a window (module docs): the pedestrian (walker 0) and the
/// people near it moved together, `horizon` steps of `dt`, each driven towards its last
/// step's velocity and pushed off the others; the pedestrian's positions.
fn social_force(w: &Window, horizon: usize, dt: f64) -> Vec<[f64; 2]> {
    let force = SocialForce::default();
    let m = w.past.len();
    let now = w.past[m - 1];
    // Velocities in m/s from here on.
    let per_s = |v: [f64; 2]| [v[0] / dt, v[1] / dt];
    let mut walkers: Vec<Walker> = std::iter::once(Walker {
        p: now,
        v: per_s(sub(now, w.past[m - 2])),
        radius: w.radius,
    })
    .chain(w.near.iter().map(|n| Walker {
        v: per_s(n.v),
        ..*n
    }))
    .collect();
    let desired: Vec<[f64; 2]> = walkers.iter().map(|a| a.v).collect();
    let cap: Vec<f64> = desired
        .iter()
        .map(|v| force.speed_cap(v[0].hypot(v[1])))
        .collect();
    let mut out = Vec::with_capacity(horizon);
    let mut pushes = vec![[0.0; 2]; walkers.len()];
    for _ in 0..horizon {
        for (a, push) in walkers.iter().zip(pushes.iter_mut()) {
            *push = [0.0; 2];
            for b in &walkers {
                let d = sub(a.p, b.p);
                let centres = d[0].hypot(d[1]);
                if centres < 1e-9 {
                    continue; // the walker itself, or someone exactly on it
                }
                let n = [d[0] / centres, d[1] / centres];
                let f = force.push(centres - a.radius - b.radius, a.radius, a.v, n);
                push[0] += f[0];
                push[1] += f[1];
            }
        }
        for (((a, push), desired), cap) in walkers.iter_mut().zip(&pushes).zip(&desired).zip(&cap) {
            (a.p, a.v) = force.step(a.p, a.v, *desired, *push, *cap, dt);
        }
        out.push(walkers[0].p);
    }
    out
}

/// The ridge model's features of a window ([`HistoryRidge::features`]).
fn features(w: &Window) -> DVector<f64> {
    DVector::from_vec(HistoryRidge::features(&w.past, w.frame))
}

/// The last-step prediction of a window.
fn last_step(w: &Window, horizon: usize) -> Vec<[f64; 2]> {
    let n = w.past.len();
    let v = sub(w.past[n - 1], w.past[n - 2]);
    (0..horizon).map(|i| held(w.past[n - 1], v, i)).collect()
}

/// The ridge model's targets of a window: the future's departure from the last-step
/// prediction `cv`, in the heading frame.
fn targets(w: &Window, cv: &[[f64; 2]]) -> DVector<f64> {
    let d = cv
        .iter()
        .zip(&w.future)
        .map(|(p, f)| w.frame.inverse_rotate(sub(*f, *p)));
    DVector::from_iterator(2 * cv.len(), d.flatten())
}

/// The sums `XᵀX` and `XᵀY` of the ridge model over a set of windows.
struct Normal {
    xtx: DMatrix<f64>,
    xty: DMatrix<f64>,
}

impl Normal {
    fn new(n: usize, m: usize) -> Self {
        Self {
            xtx: DMatrix::zeros(n, n),
            xty: DMatrix::zeros(n, m),
        }
    }

    fn add(&mut self, x: &DVector<f64>, y: &DVector<f64>) {
        self.xtx.ger(1.0, x, x, 1.0);
        self.xty.ger(1.0, x, y, 1.0);
    }

    /// The ridge solution `(XᵀX + λ·I)⁻¹·XᵀY` (features × targets), `None` when the system
    /// is not positive definite.
    fn solve(&self, lambda: f64) -> Option<DMatrix<f64>> {
        let n = self.xtx.nrows();
        let a = &self.xtx + DMatrix::identity(n, n) * lambda;
        Some(a.cholesky()?.solve(&self.xty))
    }
}

/// The fitted weights (features × 2·horizon) as the planners' predictor.
fn model(
    weights: &DMatrix<f64>,
    o: &PredictionOptions,
    dt: f64,
    fitted_on: String,
) -> HistoryRidge {
    HistoryRidge {
        history: o.history,
        horizon: o.horizon,
        dt,
        fitted_on,
        weights: weights.transpose().as_slice().to_vec(),
    }
}

/// A ridge model's prediction of a window (its history is the model's length).
fn ridged(model: &HistoryRidge, w: &Window, horizon: usize) -> Vec<[f64; 2]> {
    model
        .predict(&w.past, horizon)
        .expect("windows hold the model's history")
}

/// Adds one window's errors (ADE, FDE, ADE over the first `first` steps) to a running sum.
fn score(sum: &mut Errors, prediction: &[[f64; 2]], future: &[[f64; 2]], first: usize) {
    let e: Vec<f64> = prediction
        .iter()
        .zip(future)
        .map(|(p, f)| (p[0] - f[0]).hypot(p[1] - f[1]))
        .collect();
    let first = first.clamp(1, e.len());
    sum.ade += e.iter().sum::<f64>() / e.len() as f64;
    sum.fde += e[e.len() - 1];
    sum.ade_1s += e[..first].iter().sum::<f64>() / first as f64;
    sum.windows += 1;
}

/// Runs the study on `suite` (tracks at `dt`, from its episodes).
///
/// # Errors
/// [`DataError::Option`] for options out of range, and when the file yields no window (tracks
/// shorter than `history + horizon + 1` steps) or the ridge model cannot be fitted (fewer than
/// two scenes, or a scene whose complement has too few windows to determine it).
pub fn study(suite: &EpisodeSuite, o: PredictionOptions) -> Result<PredictionReport, DataError> {
    study_with_training(suite, o, &[])
}

/// [`study`], with [`Predictor::RidgeTrained`] fitted on the tracks of `training` (scenes of
/// other splits, every agent class) when it is not empty.
///
/// # Errors
/// Those of [`study`], and when the training scenes yield too few windows to fit the model.
pub fn study_with_training(
    suite: &EpisodeSuite,
    o: PredictionOptions,
    training: &[Scene],
) -> Result<PredictionReport, DataError> {
    o.validate()?;
    let (windows, scenes, tracks) = windows(suite, &o);
    let fail = |message: String| DataError::Option {
        field: "episodes".into(),
        message,
    };
    if windows.is_empty() {
        return Err(fail(format!(
            "no track is {} steps long (history {} + horizon {} + 1)",
            o.history + o.horizon + 1,
            o.history,
            o.horizon
        )));
    }
    if scenes.len() < 2 {
        return Err(fail(format!(
            "the ridge model is scored leave-one-scene-out and the file has {} scene",
            scenes.len()
        )));
    }
    let dt = suite.episodes.first().map_or(0.1, |e| e.dt);
    let first = ((1.0 / dt).round() as usize).max(1);
    let (nf, m) = (o.history * 2 + 1, o.horizon * 2);
    // Leave-one-scene-out: each scene's model is fitted on the sums of the other scenes.
    let mut own: Vec<Normal> = (0..scenes.len()).map(|_| Normal::new(nf, m)).collect();
    for w in &windows {
        own[w.scene].add(&features(w), &targets(w, &last_step(w, o.horizon)));
    }
    let mut weights = Vec::with_capacity(scenes.len());
    for (s, name) in scenes.iter().enumerate() {
        let mut rest = Normal::new(nf, m);
        for (_, other) in own.iter().enumerate().filter(|&(t, _)| t != s) {
            rest.xtx += &other.xtx;
            rest.xty += &other.xty;
        }
        let w = rest.solve(o.ridge_lambda).ok_or_else(|| {
            fail(format!(
                "the ridge model without scene `{name}` is undetermined (raise ridge_lambda)"
            ))
        })?;
        weights.push(model(&w, &o, dt, format!("the file's scenes but `{name}`")));
    }
    let trained = if training.is_empty() {
        None
    } else {
        let mut normal = Normal::new(nf, m);
        for (t, scene) in training.iter().enumerate() {
            for track in &scene.tracks {
                for w in cut(t, &track.positions, 0.0, &o, |_| Vec::new()) {
                    normal.add(&features(&w), &targets(&w, &last_step(&w, o.horizon)));
                }
            }
        }
        let w = normal.solve(o.ridge_lambda).ok_or_else(|| {
            fail(
                "the ridge model of the training scenes is undetermined (raise ridge_lambda)"
                    .into(),
            )
        })?;
        let names: Vec<&str> = training.iter().map(|s| s.name.as_str()).collect();
        Some(model(
            &w,
            &o,
            dt,
            format!("{} scenes: {}", names.len(), names.join(", ")),
        ))
    };
    let mut predictors = vec![
        Predictor::LastStep,
        Predictor::MeanVelocity(4.min(o.history)),
        Predictor::MeanVelocity(o.history),
        Predictor::Static,
        Predictor::ConstantTurn(2.min(o.history - 1)),
        Predictor::ConstantTurn(4.min(o.history - 1)),
        Predictor::SocialForce,
        Predictor::Ridge,
    ];
    if trained.is_some() {
        predictors.push(Predictor::RidgeTrained);
    }
    predictors.retain(|p| !matches!(p, Predictor::ConstantTurn(0)));
    predictors.dedup();
    let mut overall: BTreeMap<Predictor, Errors> = BTreeMap::new();
    let mut per_scene: BTreeMap<String, BTreeMap<Predictor, Errors>> = BTreeMap::new();
    for w in &windows {
        let n = w.past.len();
        let now = w.past[n - 1];
        let cv = last_step(w, o.horizon);
        for &p in &predictors {
            let prediction = match p {
                Predictor::LastStep => cv.clone(),
                Predictor::MeanVelocity(k) => {
                    let d = sub(now, w.past[n - 1 - k]);
                    let v = [d[0] / k as f64, d[1] / k as f64];
                    (0..o.horizon).map(|i| held(now, v, i)).collect()
                }
                Predictor::Static => vec![now; o.horizon],
                Predictor::ConstantTurn(k) => constant_turn(w, k, o.horizon),
                Predictor::SocialForce => social_force(w, o.horizon, dt),
                Predictor::Ridge => ridged(&weights[w.scene], w, o.horizon),
                Predictor::RidgeTrained => match &trained {
                    Some(t) => ridged(t, w, o.horizon),
                    None => continue,
                },
            };
            score(overall.entry(p).or_default(), &prediction, &w.future, first);
            let scene = per_scene.entry(scenes[w.scene].clone()).or_default();
            score(scene.entry(p).or_default(), &prediction, &w.future, first);
        }
    }
    for e in overall
        .values_mut()
        .chain(per_scene.values_mut().flat_map(|m| m.values_mut()))
    {
        let n = e.windows.max(1) as f64;
        e.ade /= n;
        e.fde /= n;
        e.ade_1s /= n;
    }
    Ok(PredictionReport {
        options: o,
        tracks,
        overall,
        per_scene,
        trained,
    })
}

impl PredictionReport {
    /// The report as Markdown: one table overall, one per scene.
    pub fn markdown(&self) -> String {
        let o = &self.options;
        let windows = self.overall.values().next().map_or(0, |e| e.windows);
        let mut s = format!(
            "{} distinct tracks, {windows} windows ({} steps of history, {} predicted, one \
             window every {} steps; ridge λ = {}).\n\n",
            self.tracks, o.history, o.horizon, o.stride, o.ridge_lambda
        );
        let table = |s: &mut String, rows: &BTreeMap<Predictor, Errors>| {
            s.push_str("| predictor | ADE (m) | FDE (m) | ADE first 1 s (m) | windows |\n");
            s.push_str("|---|---|---|---|---|\n");
            for (p, e) in rows {
                s.push_str(&format!(
                    "| {p} | {:.3} | {:.3} | {:.3} | {} |\n",
                    e.ade, e.fde, e.ade_1s, e.windows
                ));
            }
        };
        s.push_str("All scenes:\n\n");
        table(&mut s, &self.overall);
        for (scene, rows) in &self.per_scene {
            s.push_str(&format!("\n`{scene}`:\n\n"));
            table(&mut s, rows);
        }
        s
    }
}

#[cfg(test)]
mod tests;
