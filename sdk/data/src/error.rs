//! The data crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong between dataset files and training tuples or episodes.
///
/// Every variant names the file (and line or field) it is about.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A file could not be read or written.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system reported.
        #[source]
        source: std::io::Error,
    },
    /// A line of a dataset file could not be parsed.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with the line.
        message: String,
    },
    /// A number in a dataset file is NaN or infinite.
    #[error("{path}:{line}: {field} is not a finite number ({value})")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The column or field the number was read for.
        field: String,
        /// The text as found.
        value: String,
    },
    /// A scene that needs a homography (image to world, Eq. 1) has none.
    #[error("missing homography for scene `{scene}`: expected {path}")]
    MissingHomography {
        /// The scene (`dataset/scene`).
        scene: String,
        /// Where the homography was looked for.
        path: PathBuf,
    },
    /// A homography cannot be inverted.
    #[error("homography {path} is singular (|det| = {det:e})")]
    SingularHomography {
        /// The homography's file.
        path: PathBuf,
        /// Its determinant.
        det: f64,
    },
    /// A Stanford Drone Dataset video has no metres-per-pixel scale.
    #[error("missing meter-per-pixel scale for SDD video `{video}` in {path}")]
    MissingScale {
        /// The video (`scene/videoN`).
        video: String,
        /// The scale file that lacks it.
        path: PathBuf,
    },
    /// A configuration file is invalid.
    #[error("config {path}: {message}")]
    Config {
        /// The configuration file.
        path: PathBuf,
        /// What is wrong, naming the field.
        message: String,
    },
    /// An option given in code is out of range.
    #[error("invalid option `{field}`: {message}")]
    Option {
        /// The option's name.
        field: String,
        /// What is wrong with its value.
        message: String,
    },
    /// A tuple cache is missing, of another version or corrupt.
    #[error("cache {path}: {message}")]
    Cache {
        /// The cache folder or file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A JSON file (episodes, manifest) could not be parsed or written.
    #[error("{path}: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The parser's error, with line and column.
        #[source]
        source: serde_json::Error,
    },
    /// No dataset was found where the configuration points; the text says where was looked.
    #[error("no dataset found: {0}")]
    NoData(String),
    /// An episode file whose header is unusable (format version, per-class counts).
    #[error("{path}: {message}")]
    Episodes {
        /// The episode file.
        path: PathBuf,
        /// What is wrong with its header.
        message: String,
    },
    /// One episode of an episode file out of range ([`crate::Episode::validate`]).
    #[error("{path}: episode {index} (`{id}`): {field}: {message}")]
    Episode {
        /// The episode file.
        path: PathBuf,
        /// 0-based position in the file.
        index: usize,
        /// The episode's id.
        id: String,
        /// The offending field.
        field: String,
        /// What is wrong with its value.
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
