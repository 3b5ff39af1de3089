//! The simulator crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong in the simulator, the benchmark and the report.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A setting is out of range; `section` names the table (`sim`, `straight`, `suites[1]`...).
    #[error("invalid setting `{section}.{field}`: {message}")]
    Setting {
        /// The table.
        section: String,
        /// The key in it.
        field: String,
        /// What is wrong with the value.
        message: String,
    },
    /// A file could not be parsed.
    #[error("cannot parse `{path}`: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's complaint.
        message: String,
    },
    /// A file could not be read or written.
    #[error("cannot read or write `{path}`: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// A robot profile could not be loaded or set up.
    #[error("robot profile `{path}`: {message}")]
    Robot {
        /// The profile (`robot.toml`).
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A suite's episodes could not be obtained (unreadable file, none selected, ...).
    #[error("episodes of suite `{suite}`: {message}")]
    Episodes {
        /// The suite.
        suite: String,
        /// What went wrong.
        message: String,
    },
    /// A method's factory failed to build a planner.
    #[error(
        "method `{method}` could not build a planner for episode `{episode}` on robot `{robot}`: {message}"
    )]
    Method {
        /// The method.
        method: String,
        /// The robot the planner was for.
        robot: String,
        /// The episode the planner was for.
        episode: String,
        /// The factory's error.
        message: String,
    },
    /// A figure could not be drawn or written.
    #[error("cannot draw `{file}`: {message}")]
    Figure {
        /// The figure's file.
        file: PathBuf,
        /// The drawing backend's error.
        message: String,
    },
    /// An MCAP recording could not be written.
    #[error("cannot write the recording `{path}`: {message}")]
    Record {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// Shards of `human2nav bench --shard` that cannot be merged; the message names the
    /// folders and what is wrong.
    #[error("cannot merge the shards: {0}")]
    Shards(String),
    /// The benchmark has nothing to run; the message says why.
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
