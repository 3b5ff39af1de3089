//! The simulator crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong in the simulator, the benchmark and the report.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A setting is out of range; `section` names the table (`sim`, `straight`, `suites[1]`...).
    #[error("invalid setting `{section}.{field}`: {message}")]
    Setting {
        section: String,
        field: String,
        message: String,
    },
    #[error("cannot parse `{path}`: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("cannot read or write `{path}`: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("robot profile `{path}`: {message}")]
    Robot { path: PathBuf, message: String },
    #[error("episodes of suite `{suite}`: {message}")]
    Episodes { suite: String, message: String },
    #[error(
        "method `{method}` could not build a planner for episode `{episode}` on robot `{robot}`: {message}"
    )]
    Method {
        method: String,
        robot: String,
        episode: String,
        message: String,
    },
    #[error("cannot draw `{file}`: {message}")]
    Figure { file: PathBuf, message: String },
    #[error("nothing to run: {0}")]
    Empty(String),
}

impl SimError {
    /// A [`SimError::Setting`].
    pub fn setting(
        section: impl Into<String>,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        SimError::Setting {
            section: section.into(),
            field: field.into(),
            message: message.into(),
        }
    }

    /// A [`SimError::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SimError::Io {
            path: path.into(),
            source,
        }
    }
}
