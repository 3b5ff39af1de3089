//! The error type of the flow crate.

use std::path::PathBuf;

/// Everything that can go wrong while building, training, saving or loading a flow model.
#[derive(Debug, thiserror::Error)]
pub enum CfmError {
    /// An option is out of range; `field` names it as it appears in the TOML.
    #[error("invalid option `{field}`: {reason}")]
    Option {
        /// The option's TOML key.
        field: &'static str,
        /// What is wrong with its value.
        reason: String,
    },

    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system reported.
        #[source]
        source: std::io::Error,
    },

    /// A TOML file (model card, training state, config) could not be parsed.
    #[error("{path}: {message}")]
    Toml {
        /// The file.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },

    /// A weights file is not a readable safetensors file.
    #[error("{path}: not a readable safetensors file: {message}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },

    /// A weights file lacks a tensor the architecture in the model card needs.
    #[error("{path}: missing tensor `{name}` (the model card's architecture expects it)")]
    MissingTensor {
        /// The file.
        path: PathBuf,
        /// The tensor's name.
        name: String,
    },

    /// A weights file holds a tensor the architecture does not know.
    #[error("{path}: unexpected tensor `{name}` (not part of the model card's architecture)")]
    UnexpectedTensor {
        /// The file.
        path: PathBuf,
        /// The tensor's name.
        name: String,
    },

    /// A tensor in a weights file has the wrong shape.
    #[error("{path}: tensor `{name}` has shape {found:?}, the architecture expects {expected:?}")]
    TensorShape {
        /// The file.
        path: PathBuf,
        /// The tensor's name.
        name: String,
        /// The shape the architecture needs.
        expected: Vec<i64>,
        /// The shape in the file.
        found: Vec<i64>,
    },

    /// A training example does not match the model's input spec.
    #[error("training example {index}: {reason}")]
    Example {
        /// 0-based position of the example.
        index: usize,
        /// What does not match.
        reason: String,
    },

    /// The data set is empty or too small for the requested operation.
    #[error("data set `{split}` is empty")]
    EmptyData {
        /// The split (`train`, `val`).
        split: &'static str,
    },

    /// Evaluation windows could not be rebuilt from a scene.
    #[error("evaluation windows of scene `{scene}`: {reason}")]
    EvalData {
        /// The scene (`dataset/scene`).
        scene: String,
        /// What went wrong.
        reason: String,
    },

    /// Training diverged.
    #[error("training loss became non-finite at step {step}")]
    Diverged {
        /// The optimiser step at which the loss became NaN or infinite.
        step: u64,
    },

    /// A libtorch call failed.
    #[cfg(feature = "torch")]
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),

    /// The weights file is not the one the model card was written with.
    #[error(
        "{path}: checksum {found} ({bytes} bytes) differs from the model card's weights_fnv64 = \
         {expected}: these are not the weights the card was written with"
    )]
    WeightsChecksum {
        /// The file.
        path: PathBuf,
        /// The file's FNV-1a 64 checksum.
        found: String,
        /// The model card's `weights_fnv64`.
        expected: String,
        /// The file's size.
        bytes: usize,
    },

    /// The weights file records a training setting (its safetensors metadata) that the model
    /// card contradicts.
    #[error(
        "{path}: the weights were trained with {setting}: the card does not describe these weights"
    )]
    WeightsTrainedOn {
        /// The weights file.
        path: PathBuf,
        /// The setting with both values: `bev_cells = 32, the model card says 16`.
        setting: String,
    },

    /// A training checkpoint is not a complete set.
    #[error("checkpoint {path}: {reason}")]
    Checkpoint {
        /// The file.
        path: PathBuf,
        /// What is missing or inconsistent.
        reason: String,
    },

    /// Drawing a figure failed.
    #[error("plot {path}: {message}")]
    Plot {
        /// The file.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
}

impl From<human2nav_core::fileset::SetError> for CfmError {
    fn from(e: human2nav_core::fileset::SetError) -> Self {
        use human2nav_core::fileset::SetError;
        match e {
            SetError::Io { path, source } => Self::Io { path, source },
            SetError::Manifest { path, message } => Self::Toml { path, message },
            SetError::Incomplete { path, reason } => Self::Checkpoint { path, reason },
        }
    }
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
