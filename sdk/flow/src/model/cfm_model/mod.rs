//! [`CfmModel`]: the trained network behind core's [`FlowModel`] trait, and its checkpoints.
//!
//! Metric poses `[K, T, 3]` go in, metric se(2) velocities come out (see
//! [`crate::config::Normalisation`] for the exact mapping). The condition encoding (BEV CNN and
//! goal MLP) is computed once per distinct [`FlowCondition`] and cached: a planning call that
//! integrates `N` steps and runs `M` guidance iterations with the same condition encodes it
//! once. The cache compares the whole condition for equality (a 3·32·32 raster compares in a
//! few microseconds), so there are no false hits.

use super::{CARD_FILE, MAX_WEIGHTS_BYTES, WEIGHTS_FILE, crowd_points, planning_condition};
use crate::card::{FORMAT_VERSION, ModelCard, SourceInfo};
use crate::config::{NetConfig, Normalisation};
use crate::error::CfmError;
use crate::io_map::{self, check_len};
use crate::net::{CondUnet1d, Film, store_kind};
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel, FlowQuery};
use human2nav_core::input::{fnv1a64, read_user_bytes};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use tch::{Device, Kind, Tensor, nn};

/// At most this many flow times keep their FiLM parameters cached per condition.
const FILM_CACHE: usize = 64;

struct CachedCondition {
    cond: FlowCondition,
    embedding: Tensor,
    /// The crowd points `[1, N, 5]` (`N = 0` without the crowd pathway).
    points: Tensor,
    /// FiLM parameters per flow time (keyed by the bits of `t`).
    films: Vec<(u64, Film)>,
}

impl CachedCondition {
    /// The FiLM parameters of flow time `t` under this condition (cached).
    fn film(&mut self, model: &CfmModel, t: f64) -> Film {
        let key = t.to_bits();
        if let Some((_, f)) = self.films.iter().find(|(k, _)| *k == key) {
            return f.shallow_clone();
        }
        let tt = Tensor::from_slice(&[t])
            .to_kind(model.kind())
            .to_device(model.device());
        let film = tch::no_grad(|| model.net.film(&tt, &self.embedding));
        if self.films.len() >= FILM_CACHE {
            self.films.remove(0);
        }
        self.films.push((key, film.shallow_clone()));
        film
    }
}

/// A conditional flow-matching model on SE(2): network, normalisation and model card.
pub struct CfmModel {
    vs: nn::VarStore,
    net: CondUnet1d,
    card: ModelCard,
    /// Multiplier from standardised network output to metric velocity, per component.
    out_scale: [f64; 3],
    cache: Mutex<Option<CachedCondition>>,
    /// [`FlowModel::velocity_batch`]'s encodings, one per query index (kept while the query at
    /// that index keeps its condition).
    batch_cache: Mutex<Vec<Option<CachedCondition>>>,
    /// [`FlowModel::network_id`]: set by [`Self::load`] from the weights file's checksum and
    /// the device, withdrawn (0) once the weights may have changed or been handed out.
    network: AtomicU64,
}

impl std::fmt::Debug for CfmModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CfmModel")
            .field("name", &self.card.name)
            .field("net", &self.card.net)
            .field("normalisation", &self.card.normalisation)
            .field("device", &self.vs.device())
            .finish_non_exhaustive()
    }
}

impl CfmModel {
    /// A freshly initialised model (weights from torch's RNG; seed it with
    /// `tch::manual_seed` for reproducibility).
    pub fn new(net: &NetConfig, norm: &Normalisation, device: Device) -> Result<Self, CfmError> {
        net.validate()?;
        norm.validate()?;
        let card = ModelCard {
            format_version: FORMAT_VERSION,
            name: "human2nav-cfm".into(),
            description: String::new(),
            weights: WEIGHTS_FILE.into(),
            net: net.clone(),
            normalisation: norm.clone(),
            source: SourceInfo {
                std: norm.source_std(),
                steps: 10,
            },
            ..ModelCard::default()
        };
        Ok(Self::from_card(card, device))
    }

    fn from_card(card: ModelCard, device: Device) -> Self {
        let vs = nn::VarStore::new(device);
        let net = CondUnet1d::new(&vs.root(), &card.net);
        let n = &card.normalisation;
        let s = n.position_scale;
        let out_scale = [
            s * n.velocity_std[0],
            s * n.velocity_std[1],
            n.velocity_std[2],
        ];
        Self {
            vs,
            net,
            card,
            out_scale,
            cache: Mutex::new(None),
            batch_cache: Mutex::new(Vec::new()),
            network: AtomicU64::new(0),
        }
    }

    /// Loads a model folder (`model.toml` + the weights it names) or a card file directly.
    ///
    /// The weights are checked against the card's architecture: every tensor name must be
    /// known, none may be missing, and every shape must match; a truncated or corrupt file
    /// fails with [`CfmError::Corrupt`].
    pub fn load(path: &Path, device: Device) -> Result<Self, CfmError> {
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
        let weights = dir.join(&card.weights);
        let bytes = read_user_bytes(&weights, "weights file", MAX_WEIGHTS_BYTES)
            .map_err(|e| CfmError::io(&weights, e))?;
        card.verify_weights(&weights, &bytes)?;
        let model = Self::from_card(card, device);
        model.load_weights(&weights, "")?;
        // The same file on the same device is the same network (never 0: that means none).
        let id = fnv1a64(format!("{device:?}").as_bytes()) ^ fnv1a64(&bytes);
        model.network.store(id.max(1), Ordering::Relaxed);
        Ok(model)
    }

    /// Copies the tensors named `prefix + name` in a safetensors file into this model's
    /// variables, validating names and shapes. With an empty prefix, tensors the model does
    /// not know are an error; with a prefix, only the prefixed tensors are considered.
    pub(crate) fn load_weights(&self, path: &Path, prefix: &str) -> Result<(), CfmError> {
        let tensors = read_safetensors(path)?;
        self.assign_from(path, prefix, &tensors)
    }

    pub(crate) fn assign_from(
        &self,
        path: &Path,
        prefix: &str,
        tensors: &BTreeMap<String, Tensor>,
    ) -> Result<(), CfmError> {
        let vars = self.vs.variables();
        if prefix.is_empty() {
            if let Some(name) = tensors.keys().find(|n| !vars.contains_key(n.as_str())) {
                return Err(CfmError::UnexpectedTensor {
                    path: path.into(),
                    name: name.clone(),
                });
            }
        }
        let _guard = tch::no_grad_guard();
        let mut names: Vec<&String> = vars.keys().collect();
        names.sort();
        for name in names {
            let key = format!("{prefix}{name}");
            let Some(src) = tensors.get(&key) else {
                return Err(CfmError::MissingTensor {
                    path: path.into(),
                    name: key,
                });
            };
            let mut dst = vars[name].shallow_clone();
            if src.size() != dst.size() {
                return Err(CfmError::TensorShape {
                    path: path.into(),
                    name: key,
                    expected: dst.size(),
                    found: src.size(),
                });
            }
            dst.f_copy_(&src.to_kind(dst.kind()).to_device(dst.device()))?;
        }
        self.invalidate_cache();
        Ok(())
    }

    /// Writes the weights (float32) and the card, with the weights' checksum, into `dir`
    /// (created if needed), and returns that checksum and the weights file's size.
    /// The written card is this model's card with `weights_fnv64` set; the weights are written
    /// in a fixed order, so the same weights always get the same checksum.
    pub fn save(&self, dir: &Path) -> Result<(String, u64), CfmError> {
        std::fs::create_dir_all(dir).map_err(|e| CfmError::io(dir, e))?;
        let weights = dir.join(&self.card.weights);
        write_safetensors(&weights, &self.named_tensors(""))?;
        record_metadata(&weights, &self.card.trained_on())?;
        let bytes = std::fs::read(&weights).map_err(|e| CfmError::io(&weights, e))?;
        let checksum = ModelCard::checksum(&bytes);
        let mut card = self.card.clone();
        card.weights_fnv64 = Some(checksum.clone());
        card.save(&dir.join(CARD_FILE))?;
        Ok((checksum, bytes.len() as u64))
    }

    /// The variables as `(prefix + name, float32 CPU tensor)`, sorted by name.
    pub(crate) fn named_tensors(&self, prefix: &str) -> Vec<(String, Tensor)> {
        let mut v: Vec<(String, Tensor)> = self
            .vs
            .variables()
            .into_iter()
            .map(|(n, t)| {
                (
                    format!("{prefix}{n}"),
                    t.detach().to_kind(Kind::Float).to_device(Device::Cpu),
                )
            })
            .collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v
    }

    /// The model card (architecture, normalisation, provenance).
    pub fn card(&self) -> &ModelCard {
        &self.card
    }

    /// Mutable card, to record training provenance and metrics before [`Self::save`].
    /// Architecture and normalisation are fixed once the model exists; change them through a
    /// new model.
    pub fn card_mut(&mut self) -> &mut ModelCard {
        &mut self.card
    }

    /// The network.
    pub fn net(&self) -> &CondUnet1d {
        &self.net
    }

    /// The variables (for optimisers and EMA). Handing them out withdraws the model's
    /// [`FlowModel::network_id`]: whoever holds them may change the weights.
    pub fn var_store(&self) -> &nn::VarStore {
        self.network.store(0, Ordering::Relaxed);
        &self.vs
    }

    /// Device the weights live on.
    pub fn device(&self) -> Device {
        self.vs.device()
    }

    /// Floating-point kind of the weights.
    pub fn kind(&self) -> Kind {
        store_kind(&self.vs)
    }

    /// Converts the weights to float64 (for finite-difference tests of the autograd VJP).
    pub fn to_double(&mut self) {
        self.vs.double();
        self.invalidate_cache();
    }

    /// Drops the cached condition encoding (after the weights changed), and the model's
    /// [`FlowModel::network_id`].
    pub fn invalidate_cache(&self) {
        self.network.store(0, Ordering::Relaxed);
        if let Ok(mut c) = self.cache.lock() {
            *c = None;
        }
        if let Ok(mut c) = self.batch_cache.lock() {
            c.clear();
        }
    }

    /// Normalised condition tensors `([1, 3, H, W], [1, 4])` of one planning condition.
    pub fn condition_tensors(&self, cond: &FlowCondition) -> Result<(Tensor, Tensor), FlowError> {
        let cells = self.card.net.bev_cells;
        let (bev, gv) = planning_condition(&self.card, cond)?;
        let (kind, device) = (self.kind(), self.device());
        let c = cells as i64;
        let bev = Tensor::from_slice(&bev)
            .view([1, 3, c, c])
            .to_kind(kind)
            .to_device(device);
        let gv = Tensor::from_slice(&gv)
            .view([1, 4])
            .to_kind(kind)
            .to_device(device);
        Ok((bev, gv))
    }

    /// The static condition embedding `[1, ·]`, from the cache when `cond` is unchanged.
    pub fn condition_embedding(&self, cond: &FlowCondition) -> Result<Tensor, FlowError> {
        self.with_cached(cond, |c| Ok(c.embedding.shallow_clone()))
    }

    /// The crowd points `[1, N, 5]` of one condition ([`crowd_points`]; `N = 0` without the
    /// crowd pathway), in the model's kind.
    pub fn crowd_tensor(&self, cond: &FlowCondition) -> Tensor {
        let net = &self.card.net;
        let mut pts = vec![0f32; net.crowd_len()];
        if let Some(c) = &net.crowd {
            crowd_points(
                c,
                &self.card.normalisation,
                net.bev_cells,
                &cond.bev,
                &mut pts,
            );
        }
        Tensor::from_slice(&pts)
            .view([1, -1, crate::net::CROWD_FEATURES])
            .to_kind(self.kind())
            .to_device(self.device())
    }

    /// FiLM parameters and crowd points for `(t, cond)`, from the cache when both are
    /// unchanged.
    fn film(&self, cond: &FlowCondition, t: f64) -> Result<(Film, Tensor), FlowError> {
        self.with_cached(cond, |c| Ok((c.film(self, t), c.points.shallow_clone())))
    }

    fn with_cached<R>(
        &self,
        cond: &FlowCondition,
        f: impl FnOnce(&mut CachedCondition) -> Result<R, FlowError>,
    ) -> Result<R, FlowError> {
        let mut cache = self
            .cache
            .lock()
            .map_err(|_| FlowError::Backend("condition cache poisoned".into()))?;
        f(self.encoded(&mut cache, cond)?)
    }

    /// The encoding of `cond` in `slot`, made there unless it holds `cond`'s already.
    fn encoded<'a>(
        &self,
        slot: &'a mut Option<CachedCondition>,
        cond: &FlowCondition,
    ) -> Result<&'a mut CachedCondition, FlowError> {
        if slot.as_ref().is_none_or(|c| c.cond != *cond) {
            let (bev, gv) = self.condition_tensors(cond)?;
            *slot = Some(CachedCondition {
                cond: cond.clone(),
                embedding: tch::no_grad(|| self.net.encode_condition(&bev, &gv)),
                points: self.crowd_tensor(cond),
                films: Vec::new(),
            });
        }
        slot.as_mut()
            .ok_or_else(|| FlowError::Backend("condition cache empty".into()))
    }

    /// The encodings of a batched call's `n` queries, one slot per query index (kept while the
    /// query at that index keeps its condition).
    fn batch_slots(
        &self,
        n: usize,
    ) -> Result<std::sync::MutexGuard<'_, Vec<Option<CachedCondition>>>, FlowError> {
        let mut cache = self
            .batch_cache
            .lock()
            .map_err(|_| FlowError::Backend("batch condition cache poisoned".into()))?;
        cache.resize_with(n, || None);
        Ok(cache)
    }

    /// [`FlowModel::velocity_batch`] as one forward pass over every group's rows: each row with
    /// its group's condition encoding (kept per query index while its condition is
    /// unchanged), flow time and crowd points.
    /// Agrees with one [`FlowModel::velocity`] per group to float rounding (libtorch's kernels
    /// differ with the batch size).
    pub fn batched_velocity(
        &self,
        queries: &[FlowQuery<'_>],
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        let total: usize = queries.iter().map(|q| q.x.len()).sum();
        check_len("out", out.len(), total)?;
        if let [q] = queries {
            return self.velocity(q.x, q.t, q.cond, out);
        }
        if queries.is_empty() {
            return Ok(());
        }
        let (kind, device) = (self.kind(), self.device());
        let mut cache = self.batch_slots(queries.len())?;
        let mut feats = Vec::with_capacity(queries.len());
        let (mut embeddings, mut points) = (Vec::new(), Vec::new());
        let (mut rows, mut times) = (Vec::new(), Vec::new());
        for (g, (q, slot)) in queries.iter().zip(cache.iter_mut()).enumerate() {
            let (f, k) = self.feature_tensor(q.x)?;
            feats.push(f);
            let c = self.encoded(slot, q.cond)?;
            embeddings.push(c.embedding.shallow_clone());
            points.push(c.points.shallow_clone());
            rows.extend(std::iter::repeat_n(g as i64, k));
            times.extend(std::iter::repeat_n(q.t, k));
        }
        drop(cache);
        let rows = Tensor::from_slice(&rows).to_device(device);
        let times = Tensor::from_slice(&times).to_kind(kind).to_device(device);
        let v = tch::no_grad(|| {
            let cond = Tensor::cat(&embeddings, 0).index_select(0, &rows);
            let points = Tensor::cat(&points, 0).index_select(0, &rows);
            self.net
                .forward(&Tensor::cat(&feats, 0), &times, &cond, &points)
        });
        self.write_velocity(&v, out)
    }

    /// Network features `[K, 5, T]` of metric poses (flat `[K, T, 3]`), in the model's kind:
    /// the same values as [`trajectory_features`](super::trajectory_features) of the normalised poses.
    pub fn feature_tensor(&self, x: &[f64]) -> Result<(Tensor, usize), FlowError> {
        let t = self.card.net.horizon;
        let k = io_map::batch_of(x.len(), t)?;
        let mut f = vec![0f64; k * 5 * t];
        let s = self.card.normalisation.position_scale;
        io_map::for_each_feature(x, t, s, |b, c, j, v| f[(b * 5 + c) * t + j] = v);
        let shape = [k as i64, 5, t as i64];
        Ok((tensor_of(&f, &shape, self.kind(), self.device()), k))
    }

    /// Writes `out[k, j, c] = net[k, c, j]·scale_c` (metric velocity from standardised output).
    fn write_velocity(&self, net_out: &Tensor, out: &mut [f64]) -> Result<(), FlowError> {
        let t = self.card.net.horizon;
        let raw = values_of(net_out, out.len())?;
        io_map::write_velocity(out, t, self.out_scale, |b, c, j| raw[(b * 3 + c) * t + j])
    }
}

/// A tensor of the given kind and shape from `f64` values (built directly as `f32` for
/// float models).
fn tensor_of(v: &[f64], shape: &[i64], kind: Kind, device: Device) -> Tensor {
    let t = match kind {
        Kind::Double => Tensor::from_slice(v),
        Kind::Float => {
            let f: Vec<f32> = v.iter().map(|&x| x as f32).collect();
            Tensor::from_slice(&f)
        }
        _ => Tensor::from_slice(v).to_kind(kind),
    };
    t.view(shape).to_device(device)
}

/// The values of a tensor (any float kind) as `f64`, checking the count.
fn values_of(t: &Tensor, n: usize) -> Result<Vec<f64>, FlowError> {
    let t = t.detach().to_device(Device::Cpu).contiguous();
    if t.numel() != n {
        return Err(FlowError::Shape(format!(
            "network output has {} values, expected {n}",
            t.numel()
        )));
    }
    let backend = |e: tch::TchError| FlowError::Backend(e.to_string());
    match t.kind() {
        Kind::Float => {
            let mut v = vec![0f32; n];
            t.f_copy_data(&mut v, n).map_err(backend)?;
            Ok(v.into_iter().map(f64::from).collect())
        }
        Kind::Double => {
            let mut v = vec![0f64; n];
            t.f_copy_data(&mut v, n).map_err(backend)?;
            Ok(v)
        }
        _ => {
            let mut v = vec![0f64; n];
            t.to_kind(Kind::Double)
                .f_copy_data(&mut v, n)
                .map_err(backend)?;
            Ok(v)
        }
    }
}

impl FlowModel for CfmModel {
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
        let (feat, _) = self.feature_tensor(x)?;
        let (film, points) = self.film(cond, t)?;
        let v = tch::no_grad(|| self.net.forward_film(&feat, &film, &points));
        self.write_velocity(&v, out)
    }

    /// On a CUDA device, [`CfmModel::batched_velocity`]: one pass for all groups. On the CPU
    /// one pass per group (each query index keeping its condition's encoding, as
    /// [`FlowModel::velocity`] keeps the last one), which measured faster there
    /// (docs/experiments/2026-12-07-batch-planning.md).
    fn velocity_batch(&self, queries: &[FlowQuery<'_>], out: &mut [f64]) -> Result<(), FlowError> {
        if self.device() != Device::Cpu {
            return self.batched_velocity(queries, out);
        }
        let total: usize = queries.iter().map(|q| q.x.len()).sum();
        check_len("out", out.len(), total)?;
        let mut cache = self.batch_slots(queries.len())?;
        let mut rest = out;
        for (q, slot) in queries.iter().zip(cache.iter_mut()) {
            let (o, r) = rest.split_at_mut(q.x.len());
            let c = self.encoded(slot, q.cond)?;
            let film = c.film(self, q.t);
            let (feat, _) = self.feature_tensor(q.x)?;
            let v = tch::no_grad(|| self.net.forward_film(&feat, &film, &c.points));
            self.write_velocity(&v, o)?;
            rest = r;
        }
        Ok(())
    }

    fn network_id(&self) -> Option<usize> {
        match self.network.load(Ordering::Relaxed) {
            0 => None,
            id => Some(id as usize),
        }
    }

    /// The network runs in autograd mode on its input features; the pull-back through the
    /// features `(x/s, y/s, cos θ, sin θ)` and the output scaling is done here in closed form.
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
        let (feat, k) = self.feature_tensor(x)?;
        let (film, points) = self.film(cond, t)?;
        // Cotangent of the standardised output [K, 3, T].
        let mut cot = vec![0f64; x.len()];
        io_map::for_each_output_cotangent(cotangent, h, self.out_scale, |b, c, j, v| {
            cot[(b * 3 + c) * h + j] = v;
        });
        let cot = tensor_of(&cot, &[k as i64, 3, h as i64], self.kind(), self.device());
        let (v, grad) = tch::with_grad(|| -> Result<(Tensor, Tensor), FlowError> {
            let feat = feat.set_requires_grad(true);
            let v = self.net.forward_film(&feat, &film, &points);
            let s = (&v * &cot).sum(v.kind());
            let grads = Tensor::f_run_backward(&[&s], &[&feat], false, false)
                .map_err(|e| FlowError::Backend(e.to_string()))?;
            let g = grads
                .into_iter()
                .next()
                .ok_or_else(|| FlowError::Backend("autograd returned no gradient".into()))?;
            Ok((v, g))
        })?;
        self.write_velocity(&v, out)?;
        let g = values_of(&grad, k * 5 * h)?;
        let s = self.card.normalisation.position_scale;
        io_map::pull_back_features(x, h, s, |b, c, j| g[(b * 5 + c) * h + j], vjp)
    }
}

/// Reads every tensor of a safetensors file, mapping failures to [`CfmError`].
pub(crate) fn read_safetensors(path: &Path) -> Result<BTreeMap<String, Tensor>, CfmError> {
    // libtorch reads the file itself: check first that it is a regular file of sane size (a
    // FIFO would block, a device would never end).
    let meta = std::fs::metadata(path).map_err(|e| CfmError::io(path, e))?;
    if !meta.is_file() || meta.len() > MAX_WEIGHTS_BYTES {
        let why = if meta.is_file() {
            format!(
                "{} bytes, more than the limit of {MAX_WEIGHTS_BYTES}",
                meta.len()
            )
        } else {
            "not a regular file".to_string()
        };
        return Err(CfmError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::InvalidInput, why),
        ));
    }
    let list = Tensor::read_safetensors(path).map_err(|e| CfmError::Corrupt {
        path: PathBuf::from(path),
        message: e.to_string(),
    })?;
    Ok(list.into_iter().collect())
}

/// Writes named tensors to a safetensors file (atomically: temporary file, then rename).
pub(crate) fn write_safetensors(path: &Path, tensors: &[(String, Tensor)]) -> Result<(), CfmError> {
    let tmp = path.with_extension("safetensors.tmp");
    Tensor::write_safetensors(tensors, &tmp).map_err(|e| CfmError::Corrupt {
        path: tmp.clone(),
        message: e.to_string(),
    })?;
    std::fs::rename(&tmp, path).map_err(|e| CfmError::io(path, e))
}

/// Rewrites the safetensors file at `path` with `settings` as its header metadata (the tensors
/// unchanged; atomically: temporary file, then rename). See [`ModelCard::trained_on`].
fn record_metadata(path: &Path, settings: &[(&'static str, String)]) -> Result<(), CfmError> {
    let corrupt = |e: safetensors::SafeTensorError| CfmError::Corrupt {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let bytes = std::fs::read(path).map_err(|e| CfmError::io(path, e))?;
    let file = safetensors::SafeTensors::deserialize(&bytes).map_err(corrupt)?;
    let metadata = settings
        .iter()
        .map(|(k, v)| ((*k).to_string(), v.clone()))
        .collect();
    let tmp = path.with_extension("safetensors.tmp");
    safetensors::serialize_to_file(file.tensors(), Some(metadata), &tmp).map_err(corrupt)?;
    std::fs::rename(&tmp, path).map_err(|e| CfmError::io(path, e))
}

#[cfg(test)]
mod tests;
