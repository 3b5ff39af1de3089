//! The crate's error type.

use std::path::PathBuf;

/// Why a SARL operation failed. Variants name the file, the field or the tensor involved.
#[derive(Debug, thiserror::Error)]
pub enum SarlError {
    /// A setting is out of range.
    #[error("invalid SARL setting: `{field}` {message}")]
    Config { field: String, message: String },
    /// A TOML file or string does not parse (or has unknown fields).
    #[error("{path}: cannot parse TOML: {message}")]
    Parse { path: PathBuf, message: String },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A weights file is missing, unreadable or does not fit the architecture of its card.
    #[error("{path}: weights do not load: {message}")]
    Weights { path: PathBuf, message: String },
    /// A checkpoint is inconsistent with the configuration it is resumed under.
    #[error("{path}: cannot resume: {message}")]
    Resume { path: PathBuf, message: String },
    /// A checkpoint set could not be written or read (see `human2nav_core::fileset`).
    #[error(transparent)]
    Set(#[from] human2nav_core::fileset::SetError),
    /// A libtorch operation failed.
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
    /// Drawing a figure failed.
    #[error("{path}: cannot draw the figure: {message}")]
    Plot { path: PathBuf, message: String },
}

impl SarlError {
    /// An out-of-range setting.
    pub fn config(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Config {
            field: field.into(),
            message: message.into(),
        }
    }

    /// An I/O failure on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}
