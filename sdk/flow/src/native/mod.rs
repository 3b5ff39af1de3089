//! [`NativeCfm`]: the trained flow model run by Rust kernels instead of libtorch.
//!
//! A planning call makes a few dozen network calls on batches of 4–16 trajectories of 32
//! poses. Through libtorch each call is some 150 small operators, and on tensors this small the
//! per-operator dispatch, allocation and oneDNN set-up cost more than the arithmetic. The native
//! path runs the same network (`net`: the same layers, read by name from the same
//! safetensors file) as a fixed sequence of batched kernels (`kernels`: one SGEMM per
//! convolution over the whole batch, group normalisation and the activation), with every buffer
//! reused from call to call. It computes the forward pass and the gradient of its input (the
//! vector-Jacobian product guidance needs); weight gradients, and so training, stay with tch.
//! It keeps its recent forward passes: a VJP at the input of one, or at some of its rows (the
//! shortlist of a rollout), pulls back through it instead of running it again.
//!
//! [`NativeCfm`] implements core's [`FlowModel`] exactly as `CfmModel` does (same features,
//! normalisation and output scaling), so a planner can use either; the agreement tests compare
//! the two. It runs on the CPU, one thread per model; a GPU runs `CfmModel`.

mod crowd;
mod kernels;
mod net;

use crate::card::ModelCard;
use crate::error::CfmError;
use crate::io_map::{self, batch_of, check_len};
#[cfg(feature = "torch")]
use crate::model::CfmModel;
use crate::model::{CARD_FILE, crowd_points, planning_condition};
use crate::net::Complexity;
use crowd::{CrowdScratch, CrowdTape};
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel, FlowQuery};
use human2nav_core::input::read_user_bytes;
use kernels::Film;
use net::{Net, Pool, Tape, WeightError, Weights};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// At most this many flow times keep their FiLM vector per condition.
const FILM_CACHE: usize = 64;

/// Forward passes kept for a later VJP at the same input (Algorithm 1's adjoint pass pulls
/// back through the very points its rollout just evaluated) or at some of its rows (Algorithm
/// 1 on a shortlist of the samples): the integration steps of two rollouts of `N = 5`, the
/// sampling's and the shortlist's. Each keeps about 50 KiB of activations per trajectory.
const KEPT_FORWARDS: usize = 10;

/// One forward pass with its input, output and tape.
#[derive(Debug, Default)]
struct Forward {
    /// Bits of the flow time.
    t: u64,
    x: Vec<f64>,
    batch: usize,
    tape: Tape,
    /// The crowd pathway's part of the pass (empty without one).
    crowd: CrowdTape,
    raw: Vec<f32>,
    /// Last use (for least-recently-used replacement).
    stamp: u64,
}

/// One condition's encoding: the condition embedding, the crowd points and the FiLM vectors of
/// recent flow times.
#[derive(Debug, Default)]
struct Encoded {
    cond: Option<FlowCondition>,
    embedding: Vec<f32>,
    /// The condition's crowd points ([`crowd_points`]; empty without the crowd pathway).
    points: Vec<f32>,
    /// FiLM vectors per flow time (keyed by the bits of `t`).
    films: Vec<(u64, Vec<f32>)>,
}

impl Encoded {
    /// Encodes `cond` unless it is the one encoded already; returns whether it changed.
    fn update(&mut self, model: &NativeCfm, cond: &FlowCondition) -> Result<bool, FlowError> {
        if self.cond.as_ref() == Some(cond) {
            return Ok(false);
        }
        let card = &model.card;
        let (bev, gv) = planning_condition(card, cond)?;
        self.embedding = model.net.encode_condition(&bev, &gv);
        let net = &card.net;
        self.points.clear();
        self.points.resize(net.crowd_len(), 0.0);
        if let Some(c) = &net.crowd {
            crowd_points(
                c,
                &card.normalisation,
                net.bev_cells,
                &cond.bev,
                &mut self.points,
            );
        }
        self.films.clear();
        self.cond = Some(cond.clone());
        Ok(true)
    }

    /// The index in `films` of flow time `t`'s FiLM vector (computed on first use).
    fn film(&mut self, net: &Net, t: f64) -> usize {
        let key = t.to_bits();
        if let Some(i) = self.films.iter().position(|(k, _)| *k == key) {
            return i;
        }
        if self.films.len() >= FILM_CACHE {
            self.films.remove(0);
        }
        let film = net.film(t, &self.embedding);
        self.films.push((key, film));
        self.films.len() - 1
    }
}

/// The buffers of a batched call ([`FlowModel::velocity_batch`]): one encoding per query index
/// (kept while the query at that index keeps its condition), every row's FiLM vector and the
/// pass over all rows.
#[derive(Debug, Default)]
struct Batched {
    members: Vec<Encoded>,
    films: Vec<f32>,
    film_rows: Vec<usize>,
    feat: Vec<f32>,
    tape: Tape,
    crowd: CrowdTape,
    raw: Vec<f32>,
}

/// Per-condition caches and the reusable buffers of one model.
#[derive(Debug, Default)]
struct State {
    encoded: Encoded,
    /// Recent forward passes under this condition.
    forwards: Vec<Forward>,
    clock: u64,
    pool: Pool,
    crowd: CrowdScratch,
    feat: Vec<f32>,
    dfeat: Vec<f32>,
    cot: Vec<f32>,
    batched: Batched,
    /// Multiply-accumulates computed so far ([`NativeCfm::macs`]).
    macs: u64,
}

/// The flow model on Rust kernels; see the [module documentation](self).
#[derive(Debug)]
pub struct NativeCfm {
    card: ModelCard,
    net: Arc<Net>,
    out_scale: [f64; 3],
    /// Multiply-accumulates of the convolutions per trajectory ([`Complexity`]).
    conv_macs: u64,
    state: Mutex<State>,
}

/// A copy that shares the weights and starts with empty caches (one per planner: the weights
/// are read once, each planner keeps its own condition cache and forward passes).
impl Clone for NativeCfm {
    fn clone(&self) -> Self {
        Self {
            card: self.card.clone(),
            net: Arc::clone(&self.net),
            out_scale: self.out_scale,
            conv_macs: self.conv_macs,
            state: Mutex::new(State::default()),
        }
    }
}

impl NativeCfm {
    /// Loads a model folder (`model.toml` + the weights it names) or a card file directly,
    /// reading the weights without libtorch. Every tensor the card's architecture needs must be
    /// in the file with its size, and the file must hold no other tensor.
    pub fn load(path: &Path) -> Result<Self, CfmError> {
        let card_path = if path.is_dir() {
            path.join(CARD_FILE)
        } else {
            path.to_path_buf()
        };
        let card = ModelCard::load(&card_path)?;
        let dir = card_path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default();
        let weights_path = dir.join(&card.weights);
        let weights = read_weights(&weights_path, &card)?;
        Self::from_weights(card, weights, &weights_path)
    }

    /// The same network as a loaded (or trained) libtorch model, with its weights copied.
    #[cfg(feature = "torch")]
    pub fn from_model(model: &CfmModel) -> Result<Self, CfmError> {
        let mut weights = Weights::new();
        for (name, t) in model.named_tensors("") {
            let n = t.numel();
            let mut v = vec![0f32; n];
            t.f_copy_data(&mut v, n)?;
            weights.insert(name, v);
        }
        Self::from_weights(model.card().clone(), weights, Path::new("<in memory>"))
    }

    fn from_weights(card: ModelCard, mut weights: Weights, path: &Path) -> Result<Self, CfmError> {
        card.net.validate()?;
        card.normalisation.validate()?;
        let net = Net::load(&card.net, &mut weights).map_err(|e| weight_error(path, e))?;
        if let Some(name) = weights.keys().next() {
            return Err(CfmError::UnexpectedTensor {
                path: path.to_path_buf(),
                name: name.clone(),
            });
        }
        let n = &card.normalisation;
        let s = n.position_scale;
        let out_scale = [
            s * n.velocity_std[0],
            s * n.velocity_std[1],
            n.velocity_std[2],
        ];
        Ok(Self {
            conv_macs: Complexity::of(&card.net).conv_macs,
            card,
            net: Arc::new(net),
            out_scale,
            state: Mutex::new(State::default()),
        })
    }

    /// The model card (architecture, normalisation, provenance).
    pub fn card(&self) -> &ModelCard {
        &self.card
    }

    /// The multiply-accumulates this model has computed since it was made: per trajectory of
    /// a forward pass the convolutions and the crowd pathway's MLP at the points present; per
    /// trajectory of a VJP the convolutions' transposed products and, at the crowd pathway's
    /// picked pairs, its first layer again and both layers' transposed products. A kept pass
    /// reused counts nothing, nor do normalisation, activations, FiLM and the condition
    /// encoding (see [`Complexity`]). With the machine's SGEMM rate it gives the least time
    /// the arithmetic a call did can take.
    pub fn macs(&self) -> u64 {
        self.state.lock().map_or(0, |st| st.macs)
    }

    fn lock(&self) -> Result<std::sync::MutexGuard<'_, State>, FlowError> {
        self.state
            .lock()
            .map_err(|_| FlowError::Backend("native model state poisoned".into()))
    }

    /// Encodes `cond` (cached) and returns the index of the FiLM vector of `(cond, t)` in
    /// `st.encoded.films`; a new condition drops the kept forward passes.
    fn prepare(&self, st: &mut State, cond: &FlowCondition, t: f64) -> Result<usize, FlowError> {
        if st.encoded.update(self, cond)? {
            st.forwards.iter_mut().for_each(|f| f.x.clear());
        }
        Ok(st.encoded.film(&self.net, t))
    }

    /// The forward pass of poses `x` at flow time `t`: a kept one with exactly this input, or a
    /// new one in the least recently used slot. Returns the slot and the FiLM index.
    fn run_forward(
        &self,
        st: &mut State,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
    ) -> Result<(usize, usize), FlowError> {
        let h = self.card.net.horizon;
        let k = batch_of(x.len(), h)?;
        let fi = self.prepare(st, cond, t)?;
        st.clock += 1;
        let key = t.to_bits();
        if let Some(i) = st.forwards.iter().position(|f| f.t == key && f.x == x) {
            st.forwards[i].stamp = st.clock;
            return Ok((i, fi));
        }
        // Every row a row of a kept pass at this time (Algorithm 1 on a shortlist of a
        // rollout's samples): that pass's rows are what a new pass would compute.
        let per = 3 * h;
        let same = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(u, v)| u.to_bits() == v.to_bits());
        let subset = st.forwards.iter().enumerate().find_map(|(i, f)| {
            if f.t != key || f.batch <= k {
                return None;
            }
            let rows: Option<Vec<usize>> = x
                .chunks_exact(per)
                .map(|row| f.x.chunks_exact(per).position(|r| same(r, row)))
                .collect();
            rows.map(|rows| (i, rows))
        });
        let slot = if st.forwards.len() < KEPT_FORWARDS {
            st.forwards.push(Forward::default());
            st.forwards.len() - 1
        } else {
            (0..st.forwards.len())
                .filter(|&i| subset.as_ref().is_none_or(|(from, _)| *from != i))
                .min_by_key(|&i| st.forwards[i].stamp)
                .unwrap_or(0)
        };
        if let Some((from, rows)) = subset {
            let mut f = std::mem::take(&mut st.forwards[slot]);
            let src = &st.forwards[from];
            src.tape.gather(&rows, &mut f.tape);
            src.crowd.gather((src.batch, h), &rows, &mut f.crowd);
            net::gather_rows(&src.raw, src.batch, h, &rows, &mut f.raw);
            f.t = key;
            f.x.clear();
            f.x.extend_from_slice(x);
            f.batch = k;
            f.stamp = st.clock;
            st.forwards[slot] = f;
            return Ok((slot, fi));
        }
        write_features(x, h, self.card.normalisation.position_scale, &mut st.feat);
        let f = &mut st.forwards[slot];
        if let Some(c) = &self.net.crowd {
            let points = &st.encoded.points;
            st.macs += c.forward(&mut st.feat, (k, h), points, &mut f.crowd, &mut st.crowd);
        }
        st.macs += k as u64 * self.conv_macs;
        self.net.forward(
            &st.feat,
            k,
            Film::shared(&st.encoded.films[fi].1),
            &mut f.tape,
            &mut st.pool,
            &mut f.raw,
        );
        f.t = key;
        f.x.clear();
        f.x.extend_from_slice(x);
        f.batch = k;
        f.stamp = st.clock;
        Ok((slot, fi))
    }
}

/// This machine's single-thread SGEMM rate through the native path's kernel, GFLOP/s: the
/// median of `repeats` products of two `n × n` matrices. With the network's operation count it
/// gives the lower bound on a call's time that `human2nav plan --bench` compares against.
pub fn sgemm_gflops(n: usize, repeats: usize) -> f64 {
    let a: Vec<f32> = (0..n * n).map(|i| ((i % 17) as f32 - 8.0) * 0.01).collect();
    let b: Vec<f32> = (0..n * n).map(|i| ((i % 13) as f32 - 6.0) * 0.01).collect();
    let mut c = vec![0f32; n * n];
    kernels::sgemm(n, n, n, &a, n, 1, &b, n, 1, &mut c, false);
    let mut secs: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let start = std::time::Instant::now();
            kernels::sgemm(n, n, n, &a, n, 1, &b, n, 1, &mut c, false);
            start.elapsed().as_secs_f64()
        })
        .collect();
    std::hint::black_box(&c);
    secs.sort_by(f64::total_cmp);
    2.0 * (n * n * n) as f64 / secs[secs.len() / 2] / 1e9
}

/// Network features `[5, K, T]` of metric poses (flat `[K, T, 3]`).
fn write_features(x: &[f64], h: usize, position_scale: f64, out: &mut Vec<f32>) {
    let k = x.len() / (3 * h);
    out.clear();
    out.resize(5 * k * h, 0.0);
    io_map::for_each_feature(x, h, position_scale, |b, c, j, v| {
        out[(c * k + b) * h + j] = v as f32;
    });
}

/// Metric velocities of rows `first..` (as many as `out` holds) of the raw output
/// `[3, rows, T]`.
fn velocity_of(
    raw: &[f32],
    (rows, first): (usize, usize),
    h: usize,
    scale: [f64; 3],
    out: &mut [f64],
) -> Result<(), FlowError> {
    io_map::write_velocity(out, h, scale, |b, c, j| {
        f64::from(raw[(c * rows + first + b) * h + j])
    })
}

impl FlowModel for NativeCfm {
    fn horizon(&self) -> usize {
        self.card.net.horizon
    }

    fn source_std(&self) -> [f64; 3] {
        self.card.normalisation.source_std()
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        check_len("out", out.len(), x.len())?;
        let mut st = self.lock()?;
        let (slot, _) = self.run_forward(&mut st, x, t, cond)?;
        let f = &st.forwards[slot];
        velocity_of(
            &f.raw,
            (f.batch, 0),
            self.card.net.horizon,
            self.out_scale,
            out,
        )
    }

    /// The groups run as one batch: each row gets its group's FiLM vector and crowd
    /// features, every layer one matrix product over all rows. The values equal one
    /// [`FlowModel::velocity`] per group bit for bit (each row's arithmetic is the same). Kept
    /// forward passes are neither used nor made: guidance pulls back through single calls.
    fn velocity_batch(&self, queries: &[FlowQuery<'_>], out: &mut [f64]) -> Result<(), FlowError> {
        let total: usize = queries.iter().map(|q| q.x.len()).sum();
        check_len("out", out.len(), total)?;
        match queries {
            [] => return Ok(()),
            [q] => return self.velocity(q.x, q.t, q.cond, out),
            _ => {}
        }
        let h = self.card.net.horizon;
        let scale = self.card.normalisation.position_scale;
        let mut guard = self.lock()?;
        let st = &mut *guard;
        let b = &mut st.batched;
        b.members.resize_with(queries.len(), Encoded::default);
        b.films.clear();
        b.film_rows.clear();
        let mut rows = 0;
        for (q, m) in queries.iter().zip(&mut b.members) {
            let k = batch_of(q.x.len(), h)?;
            m.update(self, q.cond)?;
            let fi = m.film(&self.net, q.t);
            b.film_rows.extend(std::iter::repeat_n(b.films.len(), k));
            b.films.extend_from_slice(&m.films[fi].1);
            rows += k;
        }
        // Each group's features `[C, k, T]` (the crowd pathway's under its own points) go to
        // its rows of `[C, rows, T]`.
        let mut first = 0;
        for (q, m) in queries.iter().zip(&b.members) {
            let k = q.x.len() / (3 * h);
            write_features(q.x, h, scale, &mut st.feat);
            if let Some(c) = &self.net.crowd {
                st.macs += c.forward(&mut st.feat, (k, h), &m.points, &mut b.crowd, &mut st.crowd);
            }
            let channels = st.feat.len() / (k * h);
            b.feat.resize(channels * rows * h, 0.0);
            for (c, group) in st.feat.chunks_exact(k * h).enumerate() {
                let at = (c * rows + first) * h;
                b.feat[at..at + k * h].copy_from_slice(group);
            }
            first += k;
        }
        st.macs += rows as u64 * self.conv_macs;
        let film = Film::per_row(&b.films, &b.film_rows);
        let (tape, pool) = (&mut b.tape, &mut st.pool);
        self.net
            .forward(&b.feat, rows, film, tape, pool, &mut b.raw);
        let mut first = 0;
        let mut rest = out;
        for q in queries {
            let (o, r) = rest.split_at_mut(q.x.len());
            velocity_of(&b.raw, (rows, first), h, self.out_scale, o)?;
            first += q.x.len() / (3 * h);
            rest = r;
        }
        Ok(())
    }

    /// Clones share their weights ([`Clone`]), and so their network.
    fn network_id(&self) -> Option<usize> {
        Some(Arc::as_ptr(&self.net) as usize)
    }

    /// The backward pass of the network input runs on the activations of the forward pass at
    /// `(x, t)`, reused when [`FlowModel::velocity`] was just called there; the pull-back
    /// through the features and the output scaling are the closed forms `CfmModel` uses.
    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        check_len("out", out.len(), x.len())?;
        check_len("vjp", vjp.len(), x.len())?;
        check_len("cotangent", cotangent.len(), x.len())?;
        let h = self.card.net.horizon;
        let mut st = self.lock()?;
        let (slot, fi) = self.run_forward(&mut st, x, t, cond)?;
        let State {
            encoded,
            forwards,
            dfeat,
            cot,
            pool,
            crowd: scratch,
            macs,
            ..
        } = &mut *st;
        let Forward {
            batch: k,
            tape,
            crowd,
            raw,
            ..
        } = &mut forwards[slot];
        let k = *k;
        velocity_of(raw, (k, 0), h, self.out_scale, out)?;
        cot.clear();
        cot.resize(3 * k * h, 0.0);
        io_map::for_each_output_cotangent(cotangent, h, self.out_scale, |b, c, j, v| {
            cot[(c * k + b) * h + j] = v as f32;
        });
        let film = Film::shared(&encoded.films[fi].1);
        self.net.backward(cot, film, tape, pool, dfeat);
        *macs += k as u64 * self.conv_macs;
        if let Some(c) = &self.net.crowd {
            *macs += c.backward(dfeat, (k, h), &encoded.points, crowd, scratch);
        }
        let s = self.card.normalisation.position_scale;
        io_map::pull_back_features(
            x,
            h,
            s,
            |b, c, j| f64::from(dfeat[(c * k + b) * h + j]),
            vjp,
        )
    }
}

fn weight_error(path: &Path, e: WeightError) -> CfmError {
    match e.found {
        None => CfmError::MissingTensor {
            path: path.to_path_buf(),
            name: e.name,
        },
        Some(found) => CfmError::TensorShape {
            path: path.to_path_buf(),
            name: e.name,
            expected: vec![e.expected as i64],
            found: vec![found as i64],
        },
    }
}

/// Reads every tensor of a safetensors file as flat `f32` (stored as F32 or F64).
fn read_weights(path: &Path, card: &ModelCard) -> Result<Weights, CfmError> {
    let corrupt = |message: String| CfmError::Corrupt {
        path: PathBuf::from(path),
        message,
    };
    let bytes = read_user_bytes(path, "weights file", crate::model::MAX_WEIGHTS_BYTES)
        .map_err(|e| CfmError::io(path, e))?;
    card.verify_weights(path, &bytes)?;
    let st = safetensors::SafeTensors::deserialize(&bytes).map_err(|e| corrupt(e.to_string()))?;
    let mut out = Weights::new();
    for (name, view) in st.tensors() {
        let data = view.data();
        use safetensors::Dtype;
        let values: Vec<f32> = match view.dtype() {
            Dtype::F32 => data
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
            Dtype::F64 => data
                .chunks_exact(8)
                .map(|b| {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(b);
                    f64::from_le_bytes(a) as f32
                })
                .collect(),
            other => {
                return Err(corrupt(format!(
                    "tensor `{name}` has dtype {other:?}; the native path reads F32 and F64"
                )));
            }
        };
        if values.iter().any(|v| !v.is_finite()) {
            return Err(corrupt(format!("tensor `{name}` holds a non-finite value")));
        }
        out.insert(name, values);
    }
    Ok(out)
}

#[cfg(all(test, feature = "torch"))]
mod tests;
