//! Conditional flow matching on SE(2) with libtorch (paper §III-A, Eq. 2–5).
//!
//! * [`net`]: the conditional 1-D temporal U-Net (FiLM on BEV, goal/velocity and time).
//! * [`cfm`]: the objective: source `exp(ξ0)`, geodesic interpolation, the target velocity,
//!   the Beta distribution of flow time.
//! * [`model`]: [`CfmModel`], which implements core's [`human2nav_core::FlowModel`]
//!   (velocity and autograd vector-Jacobian product) and loads/saves checkpoints.
//! * [`native`]: [`NativeCfm`], the same network's forward pass and input gradient on Rust
//!   kernels (no per-operator dispatch): what the planner runs on the CPU.
//! * [`sampler`]: the `N`-step Lie-group Euler integrator (Eq. 5).
//! * [`train`]: AdamW with warm-up and cosine decay, EMA weights, gradient clipping,
//!   resumable training state.
//! * [`eval`]: best-of-K ADE/FDE, the constant-velocity baseline and the proximity rate.
//! * [`card`]: the TOML model card shipped with the weights.
//! * [`planner`]: the reference planner with this model, built from a robot profile and a model
//!   folder; guided-vs-unguided comparison and planning latency.
//!
//! Source distribution: the model works in normalised coordinates (translations divided by
//! `s`, see [`config::Normalisation`]) where `ξ0 ~ N(0, I)` as in the paper; in metric units
//! that is `N(0, diag(s², s², 1))`, which [`CfmModel`] reports through
//! [`human2nav_core::FlowModel::source_std`] and the model card records. Samplers draw it
//! with [`cfm::sample_source`] (or their own generator with that std).

#![warn(missing_docs)]
// The docs link the libtorch types (`CfmModel`, `CondUnet1d`, the trainer), which exist with the
// `torch` feature only: a build without it documents the rest and leaves those links unchecked
// (a workspace build turns `torch` on and checks every link).
#![cfg_attr(not(feature = "torch"), allow(rustdoc::broken_intra_doc_links))]

pub mod card;
pub mod cfm;
pub mod config;
pub mod error;
pub mod eval;
mod io_map;
pub mod model;
pub mod native;
pub mod net;
pub mod perf;
pub mod planner;
pub mod plot;
pub mod sampler;
pub mod train;

pub use card::ModelCard;
pub use config::{Activation, NetConfig, Normalisation};
pub use error::CfmError;
#[cfg(feature = "torch")]
pub use model::CfmModel;
pub use native::NativeCfm;
/// The libtorch bindings the `torch` feature builds on (for thread count and device selection).
#[cfg(feature = "torch")]
pub use tch;
