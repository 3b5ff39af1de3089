//! The error type of the flow crate.

use std::path::PathBuf;

/// Everything that can go wrong while building, training, saving or loading a flow model.
#[derive(Debug, thiserror::Error)]
pub enum CfmError {
    /// An option is out of range; `field` names it as it appears in the TOML.
    #[error("invalid option `{field}`: {reason}")]
    Option { field: &'static str, reason: String },

    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// A TOML file (model card, training state, config) could not be parsed.
    #[error("{path}: {message}")]
    Toml { path: PathBuf, message: String },

    /// A weights file is not a readable safetensors file.
    #[error("{path}: not a readable safetensors file: {message}")]
    Corrupt { path: PathBuf, message: String },

    /// A weights file lacks a tensor the architecture in the model card needs.
    #[error("{path}: missing tensor `{name}` (the model card's architecture expects it)")]
    MissingTensor { path: PathBuf, name: String },

    /// A weights file holds a tensor the architecture does not know.
    #[error("{path}: unexpected tensor `{name}` (not part of the model card's architecture)")]
    UnexpectedTensor { path: PathBuf, name: String },

    /// A tensor in a weights file has the wrong shape.
    #[error("{path}: tensor `{name}` has shape {found:?}, the architecture expects {expected:?}")]
    TensorShape {
        path: PathBuf,
        name: String,
        expected: Vec<i64>,
        found: Vec<i64>,
    },

    /// A training example does not match the model's input spec.
    #[error("training example {index}: {reason}")]
    Example { index: usize, reason: String },

    /// The data set is empty or too small for the requested operation.
    #[error("data set `{split}` is empty")]
    EmptyData { split: &'static str },

    /// Evaluation windows could not be rebuilt from a scene.
    #[error("evaluation windows of scene `{scene}`: {reason}")]
    EvalData { scene: String, reason: String },

    /// Training diverged.
    #[error("training loss became non-finite at step {step}")]
    Diverged { step: u64 },

    /// A libtorch call failed.
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),

    /// The weights file is not the one the model card was written with.
    #[error(
        "{path}: checksum {found} ({bytes} bytes) differs from the model card's weights_fnv64 = \
         {expected}: these are not the weights the card was written with"
    )]
    WeightsChecksum {
        path: PathBuf,
        found: String,
        expected: String,
        bytes: usize,
    },

    /// A training checkpoint is not a complete set.
    #[error("checkpoint {path}: {reason}")]
    Checkpoint { path: PathBuf, reason: String },

    /// Drawing a figure failed.
    #[error("plot {path}: {message}")]
    Plot { path: PathBuf, message: String },
}

impl CfmError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn option(field: &'static str, reason: impl Into<String>) -> Self {
        Self::Option {
            field,
            reason: reason.into(),
        }
    }
}
