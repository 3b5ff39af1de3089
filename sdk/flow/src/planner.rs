//! The reference planner with the trained flow model: a [`Human2Nav<PlannerModel>`] built from a
//! robot profile (`robot.toml` + URDF + plugin constraint terms) and a model folder
//! (`model.toml` card + weights), plus the two measurements the issue asks of it:
//!
//! * the guidance ablation (raw, Algorithm 1, QP, both) lives in
//!   [`human2nav_core::ablation`]; `human2nav plan --eval` runs it with this planner;
//! * [`measure_latency`] / [`LatencyStats`]: p50/p95 wall time of one planning call, and
//!   [`TimedModel`], which splits that time into flow-network calls and everything else.
//!
//! # Configuration
//! [`PlannerConfig`] is the TOML of `sdk/configs/planner.toml`: the model folder, the number of
//! libtorch threads and the [`Human2NavSettings`] table (`[human2nav]`, with
//! `[human2nav.guidance]` and `[human2nav.selection]`). Unknown keys are rejected.
//!
//! # The BEV raster
//! The planner must rasterise the crowd exactly as the training tuples were rasterised
//! ([`bev_spec`]): the number of cells is the network's input size (`net.bev_cells` of the
//! card) and the cell size comes from the card's training record.

use crate::card::ModelCard;
use crate::error::CfmError;
#[cfg(feature = "torch")]
use crate::model::CfmModel;
use crate::native::NativeCfm;
use human2nav_core::bev::BevSpec;
use human2nav_core::constraint::Phi;
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel};
use human2nav_core::forecast::{CrowdPredictor, FlowPredictor, FlowPredictorSettings};
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings, RobotModel};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use human2nav_core::robot::RobotProfile;
use human2nav_core::{Limits, Observation, PlanError, Planner};
use human2nav_plugin::PluginHost;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// The shipped model's folder, relative to the workspace root.
pub const DEFAULT_MODEL_DIR: &str = "models/human2nav-cfm";

/// Why a planner could not be built or measured.
#[derive(Debug, thiserror::Error)]
pub enum PlannerError {
    /// A planner configuration file could not be read or parsed.
    #[error("{path}: {message}")]
    Config {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
    /// A configuration value is out of range; `field` is its TOML path.
    #[error("invalid planner setting `{field}`: {message}")]
    Setting {
        /// The setting's TOML path.
        field: String,
        /// What went wrong, in one line.
        message: String,
    },
    /// The robot profile could not be loaded.
    #[error("robot profile {path}: {message}")]
    Profile {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
    /// A plugin constraint term of the profile could not be instantiated.
    #[error("robot profile {path}: plugin constraint: {message}")]
    Plugin {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
    /// The model folder could not be loaded.
    #[error("model {path}: {source}")]
    Model {
        /// The file or folder.
        path: PathBuf,
        /// Why the model could not be loaded.
        #[source]
        source: CfmError,
    },
    /// The planner rejected its settings or an observation.
    #[error(transparent)]
    Plan(#[from] PlanError),
}

/// Contents of `sdk/configs/planner.toml` (every key optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerConfig {
    /// Model folder (`model.toml` + weights); relative paths are resolved against the workspace
    /// root. Default [`DEFAULT_MODEL_DIR`].
    pub model: PathBuf,
    /// libtorch intra-op threads for planning with the `torch` backend. Default 1 (one core
    /// per robot; the latency targets are stated for one thread). The native backend always
    /// runs on the calling thread.
    pub threads: usize,
    /// What runs the network: `native` (Rust kernels on the CPU, the default) or `torch`
    /// (libtorch: the reference, and the way to a GPU).
    pub backend: Backend,
    /// The planner's settings (sampling, guidance, selection).
    pub human2nav: Human2NavSettings,
    /// Where the selection expects people to go (the `[prediction]` table). Without a model
    /// (the default): constant velocity.
    pub prediction: PredictionConfig,
}

/// The `[prediction]` table of a planner file: a goal-free flow model of people
/// ([`Normalisation::goal_conditioned`](crate::config::Normalisation::goal_conditioned) false,
/// `train.goal = false`) and how the [`FlowPredictor`] samples it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PredictionConfig {
    /// The predictor's model folder, resolved like [`PlannerConfig::model`]; `None` (the
    /// default): constant velocity. It runs on the planner's backend.
    pub model: Option<PathBuf>,
    /// How it is sampled (`[prediction.flow]`).
    pub flow: FlowPredictorSettings,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            model: PathBuf::from(DEFAULT_MODEL_DIR),
            threads: 1,
            backend: Backend::default(),
            human2nav: Human2NavSettings::default(),
            prediction: PredictionConfig::default(),
        }
    }
}

impl PlannerConfig {
    /// Checks every field; the error names the first offending one.
    pub fn validate(&self) -> Result<(), PlannerError> {
        if !(1..=MAX_THREADS).contains(&self.threads) {
            return Err(PlannerError::Setting {
                field: "threads".into(),
                message: format!("{} is not in 1..={MAX_THREADS}", self.threads),
            });
        }
        if self.model.as_os_str().is_empty() {
            return Err(PlannerError::Setting {
                field: "model".into(),
                message: "must name a model folder".into(),
            });
        }
        self.backend.check_available()?;
        self.human2nav.validate()?;
        // Checked with or without a model: a bad value is an error before it is used.
        self.prediction.flow.validate().map_err(|e| {
            let (key, message) = e.split_once(": ").unwrap_or(("", &e));
            PlannerError::Setting {
                field: format!("prediction.flow.{key}"),
                message: message.to_owned(),
            }
        })?;
        Ok(())
    }

    /// Parses and validates the TOML text of a planner configuration; `path` is only used in
    /// error messages.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self, PlannerError> {
        let cfg: Self = toml::from_str(text).map_err(|e| PlannerError::Config {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads, parses and validates a planner configuration file.
    pub fn load(path: &Path) -> Result<Self, PlannerError> {
        let text =
            read_user_file(path, "planner configuration", MAX_CONFIG_BYTES).map_err(|e| {
                PlannerError::Config {
                    path: path.to_path_buf(),
                    message: e.to_string(),
                }
            })?;
        Self::from_toml_str(&text, path)
    }

    /// The model folder, resolved against `workspace` when relative.
    pub fn model_dir(&self, workspace: &Path) -> PathBuf {
        resolve(&self.model, workspace)
    }
}

fn resolve(path: &Path, workspace: &Path) -> PathBuf {
    if path.is_absolute() {
        path.to_path_buf()
    } else {
        workspace.join(path)
    }
}

/// A loaded prediction model ([`PredictionConfig`]), from which every planner gets a
/// [`FlowPredictor`] of its own (the native weights are shared, libtorch's loaded again, so
/// that this can be shared between threads).
#[derive(Debug)]
pub struct PredictionModel {
    /// The native weights; `None` on the libtorch backend.
    native: Option<Box<NativeCfm>>,
    dir: PathBuf,
    backend: Backend,
    bev: BevSpec,
    settings: FlowPredictorSettings,
}

impl PredictionModel {
    /// The prediction model `cfg` names, loaded on `cfg.backend` (relative paths from
    /// `workspace`), or `None` when it names none. A goal-conditioned model is refused: it
    /// would predict every walker as heading for its own position.
    pub fn load(cfg: &PlannerConfig, workspace: &Path) -> Result<Option<Self>, PlannerError> {
        let Some(path) = &cfg.prediction.model else {
            return Ok(None);
        };
        let dir = resolve(path, workspace);
        let model = load_model(&dir, cfg.backend)?;
        if model.card().normalisation.goal_conditioned {
            return Err(PlannerError::Setting {
                field: "prediction.model".into(),
                message: format!(
                    "{} is conditioned on goals; a predictor of people needs a goal-free \
                     model (trained with train.goal = false)",
                    dir.display()
                ),
            });
        }
        let (bev, _) = bev_spec(model.card());
        Ok(Some(Self {
            native: match model {
                PlannerModel::Native(m) => Some(m),
                #[cfg(feature = "torch")]
                PlannerModel::Torch(_) => None,
            },
            dir,
            backend: cfg.backend,
            bev,
            settings: cfg.prediction.flow,
        }))
    }

    /// A predictor of its own for one planner.
    pub fn predictor(&self) -> Result<Box<dyn CrowdPredictor>, PlannerError> {
        let model = match &self.native {
            Some(m) => PlannerModel::Native(m.clone()),
            None => load_model(&self.dir, self.backend)?,
        };
        let p = FlowPredictor::new(model, self.bev, self.settings).map_err(|message| {
            PlannerError::Setting {
                field: "prediction".into(),
                message,
            }
        })?;
        Ok(Box::new(p))
    }
}

/// What runs a planner's network (`backend` in `planner.toml`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// [`NativeCfm`]: Rust kernels on the CPU, no per-operator dispatch.
    #[default]
    Native,
    /// `CfmModel`: libtorch, the reference implementation (CPU or GPU). Only in builds with
    /// the `torch` feature ([`Backend::check_available`]).
    Torch,
}

fn torch_missing() -> PlannerError {
    PlannerError::Setting {
        field: "backend".into(),
        message: TORCH_MISSING.into(),
    }
}

/// Why a build without libtorch cannot run the `torch` backend, and how to get one that can.
pub const TORCH_MISSING: &str = "this build of human2nav has no libtorch: the torch backend \
    needs the `torch` cargo feature (Rust: human2nav-flow/torch or human2nav/torch; C library: \
    sdk/capi/install.sh --torch; Python: sdk/dev.sh python, or pip install with \
    MATURIN_PEP517_ARGS=\"--features torch\"). The native backend runs the same weights without it";

/// The network behind a planner: the same trained weights run natively or by libtorch.
#[derive(Debug)]
pub enum PlannerModel {
    /// Rust kernels.
    Native(Box<NativeCfm>),
    /// libtorch.
    #[cfg(feature = "torch")]
    Torch(Box<CfmModel>),
}

impl Backend {
    /// The name `planner.toml` and `--backend` use.
    pub fn name(self) -> &'static str {
        match self {
            Self::Native => "native",
            Self::Torch => "torch",
        }
    }

    /// Whether this build can run the backend: the `torch` backend needs the `torch` feature;
    /// without it, an error on the `backend` setting that says how to get it
    /// ([`TORCH_MISSING`]).
    pub fn check_available(self) -> Result<(), PlannerError> {
        if self == Self::Torch && !cfg!(feature = "torch") {
            return Err(torch_missing());
        }
        Ok(())
    }
}

impl std::fmt::Display for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Backend {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        [Self::Native, Self::Torch]
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| format!("unknown backend `{s}` (expected native or torch)"))
    }
}

impl PlannerModel {
    /// Another planner's handle on the same weights, with caches of its own: free for the
    /// native backend (the weights are shared), `None` for libtorch (load it again).
    pub fn try_share(&self) -> Option<Self> {
        match self {
            Self::Native(m) => Some(Self::Native(m.clone())),
            #[cfg(feature = "torch")]
            Self::Torch(_) => None,
        }
    }

    /// The model card.
    pub fn card(&self) -> &ModelCard {
        match self {
            Self::Native(m) => m.card(),
            #[cfg(feature = "torch")]
            Self::Torch(m) => m.card(),
        }
    }

    /// The model behind either backend.
    fn flow(&self) -> &dyn FlowModel {
        match self {
            Self::Native(m) => m.as_ref(),
            #[cfg(feature = "torch")]
            Self::Torch(m) => m.as_ref(),
        }
    }
}

#[cfg(feature = "torch")]
impl From<CfmModel> for PlannerModel {
    fn from(m: CfmModel) -> Self {
        Self::Torch(Box::new(m))
    }
}

impl From<NativeCfm> for PlannerModel {
    fn from(m: NativeCfm) -> Self {
        Self::Native(Box::new(m))
    }
}

impl FlowModel for PlannerModel {
    fn horizon(&self) -> usize {
        self.flow().horizon()
    }

    fn source_std(&self) -> [f64; 3] {
        self.flow().source_std()
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        self.flow().velocity(x, t, cond, out)
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        self.flow().velocity_vjp(x, t, cond, cotangent, out, vjp)
    }
}

/// Where a planner's BEV raster came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BevOrigin {
    /// The model card's `[bev]` table (written by `human2nav train`; its cells are checked
    /// against the network's input size when the card is loaded).
    Card,
    /// A card without `[bev]` (written before the table existed): the cell size is read from
    /// its training record.
    Record,
    /// Neither (an untrained model): the data pipeline's default cell size.
    Default,
}

/// The BEV raster the model was trained on: the card's `[bev]` table; for older cards the
/// network's input size `card.net.bev_cells` with the cell size of the training record
/// ("... cells of 0.3 m ..."), or the data pipeline's default when there is none.
pub fn bev_spec(card: &ModelCard) -> (BevSpec, BevOrigin) {
    if let Some(bev) = card.bev {
        return (bev, BevOrigin::Card);
    }
    let cells = card.net.bev_cells;
    let from_record = card
        .training
        .as_ref()
        .and_then(|t| resolution_from_record(&t.data));
    match from_record {
        Some(resolution) => (BevSpec { cells, resolution }, BevOrigin::Record),
        None => (
            BevSpec {
                cells,
                ..BevSpec::default()
            },
            BevOrigin::Default,
        ),
    }
}

/// The number after `marker` in a training record, if it is a positive finite number.
fn number_after(data: &str, marker: &str) -> Option<f64> {
    let (_, rest) = data.split_once(marker)?;
    let number: String = rest
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.' || *c == 'e' || *c == '-')
        .collect();
    number
        .parse::<f64>()
        .ok()
        .filter(|r| r.is_finite() && *r > 0.0)
}

/// The number after `cells of` in a training record, if it is a positive finite length.
fn resolution_from_record(data: &str) -> Option<f64> {
    number_after(data, "cells of ")
}

/// Spacing (s) of the poses of every tuple the data pipeline writes: `data.toml` refuses any
/// other `resample.dt`, so every model is trained at it.
pub const TRAINING_DT: f64 = 0.1;

/// The spacing (s) of the poses a model was trained on: the training record's "... poses at
/// 0.1 s", else [`TRAINING_DT`].
pub fn trained_dt(card: &ModelCard) -> f64 {
    card.training
        .as_ref()
        .and_then(|t| number_after(&t.data, "poses at "))
        .unwrap_or(TRAINING_DT)
}

/// Refuses a planner `dt` other than the one the model was trained on: the network's
/// velocities are per training step, so poses spaced at another `dt` would replay the learnt
/// motion faster or slower than the people it learnt from (`human2nav.dt = 0.4` made every
/// sample four times as fast).
pub fn check_dt(card: &ModelCard, settings: &Human2NavSettings) -> Result<(), PlannerError> {
    let trained = trained_dt(card);
    if (settings.dt - trained).abs() > 1e-9 {
        return Err(PlannerError::Setting {
            field: "human2nav.dt".into(),
            message: format!(
                "{} s, but the model `{}` was trained on poses {trained} s apart; set \
                 human2nav.dt = {trained}",
                settings.dt, card.name
            ),
        });
    }
    Ok(())
}

/// Φ of a robot: the profile's built-in soft-margin terms (Eq. 8-9, weighted by its
/// `[cost]` table) plus every `[[constraint]]` plugin term it names.
pub fn robot_phi(profile: &RobotProfile) -> Result<Phi, PlannerError> {
    PluginHost::new()
        .phi(profile)
        .map_err(|e| PlannerError::Plugin {
            path: profile.source.clone(),
            message: e.to_string(),
        })
}

/// What the planner needs to know about a robot, from its profile and its Φ.
pub fn robot_model(profile: &RobotProfile, phi: Phi) -> RobotModel {
    RobotModel {
        limits: profile.limits,
        footprint: profile.footprint_shapes.clone(),
        phi,
    }
}

/// Loads a robot profile, naming the file in the error, with its limits completed by its
/// embodiment (a plugin embodiment's coupled limit, see [`PluginHost::robot_embodiment`]).
pub fn load_profile(path: &Path) -> Result<RobotProfile, PlannerError> {
    let mut profile = RobotProfile::load(path).map_err(|e| PlannerError::Profile {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    PluginHost::new()
        .robot_embodiment(&mut profile)
        .map_err(|e| PlannerError::Plugin {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    Ok(profile)
}

/// Loads a model folder for `backend` (libtorch on the CPU), naming the folder in the error;
/// the `torch` backend in a build without libtorch is an error on `backend`
/// ([`Backend::check_available`]).
pub fn load_model(dir: &Path, backend: Backend) -> Result<PlannerModel, PlannerError> {
    let model = match backend {
        Backend::Native => NativeCfm::load(dir).map(PlannerModel::from),
        #[cfg(feature = "torch")]
        Backend::Torch => CfmModel::load(dir, tch::Device::Cpu).map(PlannerModel::from),
        #[cfg(not(feature = "torch"))]
        Backend::Torch => return Err(torch_missing()),
    };
    model.map_err(|source| PlannerError::Model {
        path: dir.to_path_buf(),
        source,
    })
}

/// Largest `threads` accepted (libtorch intra-op threads; a planner is meant to use one).
pub const MAX_THREADS: usize = 256;

/// A Human2Nav planner for one robot, with what it was built from.
#[derive(Debug)]
pub struct RobotPlanner {
    /// The robot.
    pub profile: RobotProfile,
    /// The BEV raster the planner rasterises (the model's training raster).
    pub bev: BevSpec,
    /// Where `bev`'s cell size came from.
    pub bev_origin: BevOrigin,
    /// The planner.
    pub planner: Human2Nav<PlannerModel>,
}

impl RobotPlanner {
    /// A planner for `profile` with an already loaded `model`: Φ from the profile (built-in and
    /// plugin terms), the BEV raster from the model card.
    pub fn new(
        profile: RobotProfile,
        model: impl Into<PlannerModel>,
        settings: Human2NavSettings,
    ) -> Result<Self, PlannerError> {
        let model = model.into();
        check_dt(model.card(), &settings)?;
        let phi = robot_phi(&profile)?;
        let (bev, bev_origin) = bev_spec(model.card());
        let planner = Human2Nav::new(model, robot_model(&profile, phi), bev, settings)?;
        Ok(Self {
            profile,
            bev,
            bev_origin,
            planner,
        })
    }

    /// Loads the robot profile at `robot_toml` and the model folder `model_dir` (run by the
    /// native backend), and builds the planner.
    ///
    /// ```
    /// use human2nav_core::{Observation, Planner};
    /// use human2nav_flow::planner::{PlannerConfig, RobotPlanner};
    ///
    /// let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    /// let config = PlannerConfig::load(&root.join("sdk/configs/planner.toml"))?;
    /// let robot = root.join("robots/diablo/robot.toml");
    /// let mut diablo = RobotPlanner::load(&robot, &config.model_dir(&root), config.human2nav)?;
    /// // The robot at rest at the origin, its goal 4 m ahead, nobody around.
    /// let obs = Observation { goal: [4.0, 0.0], ..Observation::default() };
    /// let plan = diablo.planner.plan(&obs)?;
    /// assert!(plan.poses.len() > 1 && plan.poses.last().is_some_and(|p| p.x > 0.0));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn load(
        robot_toml: &Path,
        model_dir: &Path,
        settings: Human2NavSettings,
    ) -> Result<Self, PlannerError> {
        Self::load_with(robot_toml, model_dir, Backend::Native, settings)
    }

    /// [`Self::load`] with the backend chosen.
    pub fn load_with(
        robot_toml: &Path,
        model_dir: &Path,
        backend: Backend,
        settings: Human2NavSettings,
    ) -> Result<Self, PlannerError> {
        let profile = load_profile(robot_toml)?;
        let model = load_model(model_dir, backend)?;
        Self::new(profile, model, settings)
    }

    /// The robot's hard limits.
    pub fn limits(&self) -> &Limits {
        &self.profile.limits
    }

    /// The same planner with the prediction `cfg` names ([`PredictionConfig`]; unchanged when
    /// it names no model), relative paths from `workspace`.
    pub fn with_prediction(
        self,
        cfg: &PlannerConfig,
        workspace: &Path,
    ) -> Result<Self, PlannerError> {
        Ok(match PredictionModel::load(cfg, workspace)? {
            Some(m) => self.with_predictor(m.predictor()?),
            None => self,
        })
    }

    /// The same planner with its selection scoring against `predictor`'s forecasts
    /// ([`Human2Nav::with_predictor`]).
    pub fn with_predictor(self, predictor: Box<dyn CrowdPredictor>) -> Self {
        Self {
            planner: self.planner.with_predictor(predictor),
            ..self
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Latency
// ---------------------------------------------------------------------------------------------

/// Percentiles of planning-call wall times, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct LatencyStats {
    /// Timed calls.
    pub calls: usize,
    /// Median wall time (ms).
    pub p50_ms: f64,
    /// 95th percentile wall time (ms).
    pub p95_ms: f64,
    /// Mean wall time (ms).
    pub mean_ms: f64,
    /// Slowest call (ms).
    pub max_ms: f64,
}

impl LatencyStats {
    /// Statistics of a set of durations in milliseconds (nearest-rank percentiles: the value
    /// at index `ceil(q·n) − 1` of the sorted list).
    pub fn of(ms: &[f64]) -> Self {
        let mut v: Vec<f64> = ms.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Self {
                calls: 0,
                p50_ms: f64::NAN,
                p95_ms: f64::NAN,
                mean_ms: f64::NAN,
                max_ms: f64::NAN,
            };
        }
        v.sort_by(f64::total_cmp);
        let rank = |q: f64| {
            let i = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
            v[i]
        };
        Self {
            calls: v.len(),
            p50_ms: rank(0.5),
            p95_ms: rank(0.95),
            mean_ms: v.iter().sum::<f64>() / v.len() as f64,
            max_ms: v[v.len() - 1],
        }
    }
}

/// Wall time of `repeats` planning calls cycling through `observations` (after `warmup`
/// untimed calls). The planner is reset before every call, so each call is a cold single step
/// (no warm start; a new observation also misses the model's condition cache, as in closed
/// loop). `on_call` runs after every timed call (for a progress bar).
pub fn measure_latency<P: Planner + ?Sized>(
    planner: &mut P,
    observations: &[Observation],
    warmup: usize,
    repeats: usize,
    mut on_call: impl FnMut(),
) -> Result<LatencyStats, PlanError> {
    if observations.is_empty() {
        return Ok(LatencyStats::of(&[]));
    }
    for obs in observations.iter().cycle().take(warmup) {
        planner.reset();
        planner.plan(obs)?;
    }
    let mut ms = Vec::with_capacity(repeats);
    for obs in observations.iter().cycle().take(repeats) {
        planner.reset();
        let start = Instant::now();
        let plan = planner.plan(obs)?;
        ms.push(start.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(plan);
        on_call();
    }
    Ok(LatencyStats::of(&ms))
}

/// Calls and wall time spent inside a flow model, accumulated by [`TimedModel`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FlowCallStats {
    /// Calls of [`FlowModel::velocity`].
    pub velocity_calls: u64,
    /// Total time inside [`FlowModel::velocity`] (s).
    pub velocity_s: f64,
    /// Calls of [`FlowModel::velocity_vjp`].
    pub vjp_calls: u64,
    /// Total time inside [`FlowModel::velocity_vjp`] (s).
    pub vjp_s: f64,
    /// Trajectories passed through the network by velocity calls.
    pub velocity_rows: u64,
    /// Trajectories passed through the network by VJP calls.
    pub vjp_rows: u64,
}

impl FlowCallStats {
    /// The counts accumulated since `earlier`.
    pub fn since(&self, earlier: &Self) -> Self {
        Self {
            velocity_calls: self.velocity_calls - earlier.velocity_calls,
            velocity_s: self.velocity_s - earlier.velocity_s,
            vjp_calls: self.vjp_calls - earlier.vjp_calls,
            vjp_s: self.vjp_s - earlier.vjp_s,
            velocity_rows: self.velocity_rows - earlier.velocity_rows,
            vjp_rows: self.vjp_rows - earlier.vjp_rows,
        }
    }

    /// Floating-point operations of the network's convolutions and linear layers in these calls
    /// (2 per multiply-accumulate): `unet` per trajectory forward, twice that for a VJP (the
    /// forward pass and the gradient of its input, which is the transposed products, no weight
    /// gradients). The condition encoding and FiLM layers are not included (see
    /// [`crate::net::Complexity`]: under 1 % of a planning call).
    pub fn network_flops(&self, unet_macs_per_trajectory: u64) -> f64 {
        let f = 2.0 * unet_macs_per_trajectory as f64;
        self.velocity_rows as f64 * f + self.vjp_rows as f64 * 2.0 * f
    }
}

/// A flow model that times every call of the model it wraps (a profiler for the planner:
/// the planning time minus the time recorded here is sampling arithmetic, Φ, the adjoint
/// pass, selection and rasterisation). The counters are shared through [`Self::stats`], so they
/// can be read while a planner owns the model.
#[derive(Debug)]
pub struct TimedModel<M> {
    inner: M,
    stats: Arc<Mutex<FlowCallStats>>,
}

impl<M> TimedModel<M> {
    /// Wraps `inner` with zeroed counters.
    pub fn new(inner: M) -> Self {
        Self {
            inner,
            stats: Arc::new(Mutex::new(FlowCallStats::default())),
        }
    }

    /// A handle on the counters.
    pub fn stats(&self) -> Arc<Mutex<FlowCallStats>> {
        Arc::clone(&self.stats)
    }

    fn record(&self, vjp: bool, rows: u64, seconds: f64) {
        if let Ok(mut s) = self.stats.lock() {
            if vjp {
                s.vjp_calls += 1;
                s.vjp_s += seconds;
                s.vjp_rows += rows;
            } else {
                s.velocity_calls += 1;
                s.velocity_s += seconds;
                s.velocity_rows += rows;
            }
        }
    }
}

impl<M: FlowModel> FlowModel for TimedModel<M> {
    fn horizon(&self) -> usize {
        self.inner.horizon()
    }

    fn source_std(&self) -> [f64; 3] {
        self.inner.source_std()
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        let start = Instant::now();
        let r = self.inner.velocity(x, t, cond, out);
        let rows = (x.len() / (3 * self.inner.horizon()).max(1)) as u64;
        self.record(false, rows, start.elapsed().as_secs_f64());
        r
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        let start = Instant::now();
        let r = self.inner.velocity_vjp(x, t, cond, cotangent, out, vjp);
        let rows = (x.len() / (3 * self.inner.horizon()).max(1)) as u64;
        self.record(true, rows, start.elapsed().as_secs_f64());
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::card::TrainingInfo;
    use approx::assert_relative_eq;
    #[cfg(feature = "torch")]
    use human2nav_core::Pose2;
    #[cfg(feature = "torch")]
    use human2nav_core::ablation::{Arm, ablation_step};

    #[test]
    fn a_planner_dt_other_than_the_training_one_is_refused() {
        let mut card = ModelCard::default();
        let at = |dt| Human2NavSettings {
            dt,
            ..Human2NavSettings::default()
        };
        assert_relative_eq!(trained_dt(&card), TRAINING_DT);
        assert!(check_dt(&card, &at(0.1)).is_ok());
        let err = check_dt(&card, &at(0.4)).unwrap_err().to_string();
        assert!(
            err.contains("human2nav.dt") && err.contains("0.4 s") && err.contains("0.1 s apart"),
            "{err}"
        );
        card.training = Some(TrainingInfo {
            data: "tuple cache, BEV 32×32 cells of 0.3 m, 32 poses at 0.2 s".into(),
            ..TrainingInfo::default()
        });
        assert_relative_eq!(trained_dt(&card), 0.2);
        assert!(check_dt(&card, &at(0.2)).is_ok());
    }

    #[test]
    fn bev_raster_comes_from_the_card_table_or_the_training_record() {
        let mut card = ModelCard::default();
        card.net.bev_cells = 24;
        let (spec, origin) = bev_spec(&card);
        assert_eq!(origin, BevOrigin::Default);
        assert_eq!(spec.cells, 24);
        assert_relative_eq!(spec.resolution, BevSpec::default().resolution);

        card.training = Some(TrainingInfo {
            data: "tuple cache `out/data/cache` (real data: eth, sdd), BEV 24×24 cells of 0.25 m, \
                   32 poses at 0.1 s"
                .into(),
            ..TrainingInfo::default()
        });
        let (spec, origin) = bev_spec(&card);
        assert_eq!(origin, BevOrigin::Record);
        assert_eq!(spec.cells, 24);
        assert_relative_eq!(spec.resolution, 0.25, epsilon = 1e-15);

        // The card's [bev] table wins over the record.
        card.bev = Some(BevSpec {
            cells: 24,
            resolution: 0.4,
        });
        assert_eq!(bev_spec(&card), (card.bev.unwrap(), BevOrigin::Card));

        // A record without a usable length falls back to the default.
        for data in ["BEV cells of x m", "cells of -1 m", "no raster here"] {
            assert_eq!(resolution_from_record(data), None, "{data}");
        }
    }

    #[test]
    fn config_defaults_round_trip_and_reject_unknown_keys() {
        let path = Path::new("planner.toml");
        let cfg = PlannerConfig::from_toml_str("", path).unwrap();
        assert_eq!(cfg, PlannerConfig::default());
        let cfg = PlannerConfig::from_toml_str(
            "threads = 2\n[human2nav]\nsamples = 8\n[human2nav.guidance]\niterations_m = 3\n",
            path,
        )
        .unwrap();
        assert_eq!(cfg.threads, 2);
        assert_eq!(cfg.human2nav.samples, 8);
        assert_eq!(cfg.human2nav.guidance.iterations_m, 3);
        let err = PlannerConfig::from_toml_str("[human2nav]\nsamplez = 8\n", path).unwrap_err();
        assert!(err.to_string().contains("samplez"), "{err}");
        for bad in ["threads = 0\n", "threads = 100000\n"] {
            let err = PlannerConfig::from_toml_str(bad, path).unwrap_err();
            assert!(matches!(err, PlannerError::Setting { ref field, .. } if field == "threads"));
        }
        let err = PlannerConfig::from_toml_str("[human2nav]\nsamples = 0\nmotions = 0\n", path)
            .unwrap_err();
        assert!(err.to_string().contains("samples"), "{err}");
        assert_eq!(
            cfg.model_dir(Path::new("/ws")),
            Path::new("/ws").join(DEFAULT_MODEL_DIR)
        );
    }

    #[test]
    fn latency_percentiles_are_nearest_rank() {
        let ms: Vec<f64> = (1..=20).map(f64::from).collect();
        let s = LatencyStats::of(&ms);
        assert_eq!(s.calls, 20);
        assert_relative_eq!(s.p50_ms, 10.0);
        assert_relative_eq!(s.p95_ms, 19.0);
        assert_relative_eq!(s.mean_ms, 10.5);
        assert_relative_eq!(s.max_ms, 20.0);
        let one = LatencyStats::of(&[3.0]);
        assert_relative_eq!(one.p50_ms, 3.0);
        assert_relative_eq!(one.p95_ms, 3.0);
        assert!(LatencyStats::of(&[]).p50_ms.is_nan());
    }

    fn workspace() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    /// A small freshly initialised model saved to a temporary folder.
    #[cfg(feature = "torch")]
    fn small_model_dir(tag: &str) -> PathBuf {
        small_model_dir_with(tag, true)
    }

    /// A small untrained model folder; `goal_conditioned: false` makes it a predictor's.
    #[cfg(feature = "torch")]
    fn small_model_dir_with(tag: &str, goal_conditioned: bool) -> PathBuf {
        use crate::config::{NetConfig, Normalisation};
        tch::manual_seed(11);
        let net = NetConfig {
            horizon: 16,
            bev_cells: 16,
            down_dims: vec![8, 16],
            n_groups: 4,
            bev_channels: [4, 8, 8],
            time_embed_dim: 8,
            bev_embed_dim: 8,
            goal_embed_dim: 8,
            ..NetConfig::default()
        };
        let norm = Normalisation {
            position_scale: 1.5,
            velocity_std: [0.8, 0.3, 0.5],
            goal_scale: 4.0,
            speed_scale: 1.0,
            goal_conditioned,
            velocity_conditioned: true,
        };
        let dir = std::env::temp_dir().join(format!("h2n-planner-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        CfmModel::new(&net, &norm, tch::Device::Cpu)
            .unwrap()
            .save(&dir)
            .unwrap();
        dir
    }

    #[cfg(feature = "torch")]
    fn observation() -> Observation {
        Observation {
            time: 1.5,
            ego: Pose2::new(2.0, -1.0, 0.4),
            ego_velocity: human2nav_core::Twist2::new(0.6, 0.0, 0.0),
            goal: [7.0, 1.0],
            agents: vec![human2nav_core::AgentState {
                id: 3,
                position: [3.5, -0.2],
                velocity: [-0.8, 0.1],
                radius: 0.3,
                history: vec![[3.7, -0.25], [3.6, -0.22]],
            }],
            ..Default::default()
        }
    }

    /// Profile + model folder → planner; guidance never raises Φ of the kept sample, the plan
    /// starts at the robot, and guided and unguided planners with one seed share their samples.
    #[test]
    #[cfg(feature = "torch")]
    fn planner_from_profile_and_model_folder() {
        let dir = small_model_dir("e2e");
        let robot = workspace().join("robots/diablo/robot.toml");
        // Algorithm 1's iterations on (the shipped planner runs none), so that its plumbing
        // and call counts are exercised; only the samples on offer (no slowed copies, stop or
        // goal candidates), so that the plan is a guided sample whatever Φ makes of braking.
        let settings = Arm::Both.settings(&Human2NavSettings {
            samples: 6,
            slowdown: 1.0,
            stop_candidate: false,
            goal_approach: 0.0,
            ..Human2NavSettings::default()
        });
        assert!(settings.guidance.iterations_m > 0);
        let mut guided = RobotPlanner::load(&robot, &dir, settings).unwrap();
        assert_eq!(guided.profile.name, "diablo");
        assert_eq!(guided.bev.cells, 16);
        assert_eq!(guided.bev_origin, BevOrigin::Default);
        let off = Arm::Raw.settings(&settings);
        let mut unguided = RobotPlanner::load(&robot, &dir, off).unwrap();
        assert_eq!(unguided.planner.name(), "human2nav");

        let obs = observation();
        let limits = *guided.limits();
        let plan = guided.planner.plan(&obs).unwrap();
        assert!(plan.is_finite());
        assert!(!plan.info.fallback, "{:?}", plan.info.notes);
        assert_eq!(plan.poses.len(), 17);
        assert_eq!(plan.poses[0], obs.ego);
        let (before, after) = (plan.info.phi_before.unwrap(), plan.info.phi_after.unwrap());
        assert!(after <= before + 1e-12, "Φ {before} → {after}");

        let m = settings.guidance.iterations_m;
        assert!(
            plan.info.guidance_iterations.is_some_and(|i| i <= m),
            "{:?}",
            plan.info
        );
        // Both planners drew the same source samples: identical pre-guidance candidates, and
        // the ablation's arms plan from them.
        guided.planner.reset();
        unguided.planner.reset();
        let g = guided.planner.plan(&obs).unwrap();
        let u = unguided.planner.plan(&obs).unwrap();
        assert_eq!(g.info.candidates, u.info.candidates);
        let footprint = guided.profile.footprint_shapes.clone();
        let mut arms: [(Arm, &mut dyn Planner); 2] = [
            (Arm::Raw, &mut unguided.planner),
            (Arm::Both, &mut guided.planner),
        ];
        let steps = ablation_step(&mut arms, &obs, &limits, &footprint).unwrap();
        assert!(steps[0].contact_samples.is_some());
        assert_eq!(steps[0].displacement, 0.0);
        assert_eq!(steps[0].iterations, None);
        assert!((0.0..=1.0).contains(&steps[1].tfs));
        assert_eq!(steps[1].phi_after, plan.info.phi_after);

        // The timing wrapper counts the calls Algorithm 1 documents: N for the first rollout,
        // then N per iteration forward and N − 1 VJPs backward.
        let model = load_model(&dir, Backend::Native).unwrap();
        let timed = TimedModel::new(model);
        let stats = timed.stats();
        let (bev, _) = bev_spec(timed.inner.card());
        let mut p = Human2Nav::new(
            timed,
            robot_model(&guided.profile, robot_phi(&guided.profile).unwrap()),
            bev,
            settings,
        )
        .unwrap();
        let lat = measure_latency(&mut p, std::slice::from_ref(&obs), 0, 1, || ()).unwrap();
        assert_eq!(lat.calls, 1);
        let s = *stats.lock().unwrap();
        let n = settings.guidance.steps_n as u64;
        assert!(s.velocity_calls >= n && s.velocity_calls % n == 0, "{s:?}");
        let iterations = s.velocity_calls / n - 1;
        assert_eq!(s.vjp_calls, iterations * (n - 1), "{s:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    #[cfg(feature = "torch")]
    fn a_prediction_model_is_goal_free_and_predicts_for_the_planner() {
        let ws = Path::new("/ws");
        let with_model = |dir: &Path| PlannerConfig {
            prediction: PredictionConfig {
                model: Some(dir.to_path_buf()),
                flow: FlowPredictorSettings::default(),
            },
            ..PlannerConfig::default()
        };
        // No [prediction] model: nothing is loaded.
        assert!(
            PredictionModel::load(&PlannerConfig::default(), ws)
                .unwrap()
                .is_none()
        );
        // A missing folder is named with the workspace it was resolved against.
        let err = PredictionModel::load(&with_model(Path::new("no/such/predictor")), ws)
            .unwrap_err()
            .to_string();
        assert!(err.contains("/ws/no/such/predictor"), "{err}");
        // A planner's model (conditioned on goals) is refused by field.
        let planner_dir = small_model_dir_with("pred-goal", true);
        let err = PredictionModel::load(&with_model(&planner_dir), ws).unwrap_err();
        assert!(
            matches!(err, PlannerError::Setting { ref field, ref message }
                if field == "prediction.model" && message.contains("goal-free")),
            "{err}"
        );
        // A goal-free one predicts: the planner's plan is made against its forecast.
        let dir = small_model_dir_with("pred-free", false);
        let robot = workspace().join("robots/diablo/robot.toml");
        let rp = RobotPlanner::load(&robot, &planner_dir, Human2NavSettings::default())
            .unwrap()
            .with_prediction(&with_model(&dir), ws)
            .unwrap();
        let mut planner = rp.planner;
        assert_eq!(planner.predictor().map(|p| p.name()), Some("flow"));
        let plan = planner.plan(&observation()).unwrap();
        assert!(plan.is_finite() && !plan.info.fallback, "{:?}", plan.info);
        assert!(
            !plan.info.notes.iter().any(|n| n.contains("predictor")),
            "{:?}",
            plan.info.notes
        );
        // The table's keys are checked by name.
        let path = Path::new("planner.toml");
        let err = PlannerConfig::from_toml_str("[prediction]\nmodle = \"m\"\n", path).unwrap_err();
        assert!(err.to_string().contains("modle"), "{err}");
        let err = PlannerConfig::from_toml_str(
            "[prediction]\nmodel = \"m\"\n[prediction.flow]\nsamples = 0\n",
            path,
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("`prediction.flow.samples`"),
            "{err}"
        );
        let _ = std::fs::remove_dir_all(&dir);
        let _ = std::fs::remove_dir_all(&planner_dir);
    }

    #[test]
    fn missing_model_and_profile_are_named() {
        let backends: &[Backend] = if cfg!(feature = "torch") {
            &[Backend::Native, Backend::Torch]
        } else {
            &[Backend::Native]
        };
        for &backend in backends {
            let err = load_model(Path::new("no/such/model"), backend).unwrap_err();
            assert!(err.to_string().contains("no/such/model"), "{err}");
        }
        let err = load_profile(Path::new("no/such/robot.toml")).unwrap_err();
        assert!(matches!(err, PlannerError::Profile { .. }), "{err}");
    }

    /// Without the `torch` feature, asking for the torch backend (in the file or when loading)
    /// is an error on `backend` that says how to get a build with it.
    #[test]
    #[cfg(not(feature = "torch"))]
    fn the_torch_backend_without_libtorch_says_how_to_get_it() {
        let err =
            PlannerConfig::from_toml_str("backend = \"torch\"\n", Path::new("p.toml")).unwrap_err();
        assert!(
            matches!(err, PlannerError::Setting { ref field, ref message }
                if field == "backend" && message.contains("--features torch")),
            "{err}"
        );
        let err =
            load_model(&workspace().join("models/human2nav-cfm"), Backend::Torch).unwrap_err();
        assert!(err.to_string().contains("`torch` cargo feature"), "{err}");
        assert!(load_model(&workspace().join("models/human2nav-cfm"), Backend::Native).is_ok());
    }
}
