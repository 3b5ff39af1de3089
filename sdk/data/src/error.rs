//! The data crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong between dataset files and training tuples or episodes.
///
/// Every variant names the file (and line or field) it is about.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}:{line}: {field} is not a finite number ({value})")]
    NonFinite {
        path: PathBuf,
        line: usize,
        field: String,
        value: String,
    },
    #[error("missing homography for scene `{scene}`: expected {path}")]
    MissingHomography { scene: String, path: PathBuf },
    #[error("homography {path} is singular (|det| = {det:e})")]
    SingularHomography { path: PathBuf, det: f64 },
    #[error("missing meter-per-pixel scale for SDD video `{video}` in {path}")]
    MissingScale { video: String, path: PathBuf },
    #[error("config {path}: {message}")]
    Config { path: PathBuf, message: String },
    #[error("invalid option `{field}`: {message}")]
    Option { field: String, message: String },
    #[error("cache {path}: {message}")]
    Cache { path: PathBuf, message: String },
    #[error("{path}: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("no dataset found: {0}")]
    NoData(String),
    /// An episode file whose header is unusable (format version, per-class counts).
    #[error("{path}: {message}")]
    Episodes { path: PathBuf, message: String },
    /// One episode of an episode file out of range ([`crate::Episode::validate`]).
    #[error("{path}: episode {index} (`{id}`): {field}: {message}")]
    Episode {
        path: PathBuf,
        /// 0-based position in the file.
        index: usize,
        id: String,
        field: String,
        message: String,
    },
}

impl DataError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn parse(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.into(),
            line,
            message: message.into(),
        }
    }

    pub(crate) fn option(field: &str, message: impl Into<String>) -> Self {
        Self::Option {
            field: field.to_string(),
            message: message.into(),
        }
    }
}
