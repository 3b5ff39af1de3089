//! The network behind a planner: the [`Backend`] that runs it, the [`PlannerModel`] loaded for
//! it, and the [`PredictionModel`] of people a planner may score against.

use super::config::resolve;
use super::{PlannerConfig, PlannerError, bev_spec};
use crate::card::ModelCard;
#[cfg(feature = "torch")]
use crate::model::CfmModel;
use crate::native::NativeCfm;
use human2nav_core::bev::BevSpec;
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel, FlowQuery};
use human2nav_core::forecast::{CrowdPredictor, FlowPredictor, FlowPredictorSettings};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A loaded prediction model ([`PredictionConfig`]), from which every planner gets a
/// [`FlowPredictor`] of its own (the native weights are shared, libtorch's loaded again, so
/// that this can be shared between threads).
///
/// [`PredictionConfig`]: super::PredictionConfig
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
    /// `CfmModel`: libtorch on the CPU, the reference implementation. Only in builds with the
    /// `torch` feature ([`Backend::check_available`]).
    Torch,
    /// `CfmModel`: libtorch on the first CUDA device. Only in builds with the `torch` feature
    /// whose libtorch has CUDA; loading fails naming the setting when no device is present.
    Cuda,
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
            Self::Cuda => "cuda",
        }
    }

    /// Whether this build can run the backend: the `torch` backend needs the `torch` feature;
    /// without it, an error on the `backend` setting that says how to get it
    /// ([`TORCH_MISSING`]).
    pub fn check_available(self) -> Result<(), PlannerError> {
        if self != Self::Native && !cfg!(feature = "torch") {
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
        [Self::Native, Self::Torch, Self::Cuda]
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| format!("unknown backend `{s}` (expected native, torch or cuda)"))
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

    /// The backend that runs it.
    pub fn backend(&self) -> Backend {
        match self {
            Self::Native(_) => Backend::Native,
            #[cfg(feature = "torch")]
            Self::Torch(m) if m.device() == tch::Device::Cpu => Backend::Torch,
            #[cfg(feature = "torch")]
            Self::Torch(_) => Backend::Cuda,
        }
    }

    /// The multiply-accumulates the network has computed so far, where the backend counts
    /// them ([`NativeCfm::macs`]; `None` for libtorch).
    pub fn macs(&self) -> Option<u64> {
        match self {
            Self::Native(m) => Some(m.macs()),
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

    fn velocity_batch(&self, queries: &[FlowQuery<'_>], out: &mut [f64]) -> Result<(), FlowError> {
        self.flow().velocity_batch(queries, out)
    }

    fn network_id(&self) -> Option<usize> {
        self.flow().network_id()
    }
}

/// Loads a model folder for `backend` (libtorch on the CPU), naming the folder in the error;
/// the `torch` backend in a build without libtorch is an error on `backend`
/// ([`Backend::check_available`]).
pub fn load_model(dir: &Path, backend: Backend) -> Result<PlannerModel, PlannerError> {
    let model = match backend {
        Backend::Native => NativeCfm::load(dir).map(PlannerModel::from),
        #[cfg(feature = "torch")]
        Backend::Torch => CfmModel::load(dir, tch::Device::Cpu).map(PlannerModel::from),
        #[cfg(feature = "torch")]
        Backend::Cuda => {
            if !tch::Cuda::is_available() {
                return Err(PlannerError::Setting {
                    field: "backend".into(),
                    message: "`cuda`: libtorch sees no CUDA device here (use `native` or \
                              `torch` on this machine)"
                        .into(),
                });
            }
            CfmModel::load(dir, tch::Device::Cuda(0)).map(PlannerModel::from)
        }
        #[cfg(not(feature = "torch"))]
        Backend::Torch | Backend::Cuda => return Err(torch_missing()),
    };
    model.map_err(|source| PlannerError::Model {
        path: dir.to_path_buf(),
        source,
    })
}
