//! Errors of the plugin host. Every message is one line and names the library.

use std::fmt;
use std::path::PathBuf;

/// The kind of object a factory creates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PluginKind {
    Constraint,
    Embodiment,
    Planner,
    /// A kind this host does not know (from a newer plugin).
    Unknown(u32),
}

impl PluginKind {
    /// The ABI's `H2N_KIND_*` code.
    pub fn code(self) -> u32 {
        match self {
            Self::Constraint => crate::abi::H2N_KIND_CONSTRAINT,
            Self::Embodiment => crate::abi::H2N_KIND_EMBODIMENT,
            Self::Planner => crate::abi::H2N_KIND_PLANNER,
            Self::Unknown(c) => c,
        }
    }

    /// The kind of an ABI code.
    pub fn from_code(code: u32) -> Self {
        match code {
            crate::abi::H2N_KIND_CONSTRAINT => Self::Constraint,
            crate::abi::H2N_KIND_EMBODIMENT => Self::Embodiment,
            crate::abi::H2N_KIND_PLANNER => Self::Planner,
            c => Self::Unknown(c),
        }
    }
}

impl fmt::Display for PluginKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Constraint => f.write_str("constraint"),
            Self::Embodiment => f.write_str("embodiment"),
            Self::Planner => f.write_str("planner"),
            Self::Unknown(c) => write!(f, "unknown kind {c}"),
        }
    }
}

/// Why a plugin library or instance could not be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PluginError {
    /// No file at the path (nor with the OS's library extension or `lib` prefix added).
    #[error("plugin library {path} not found (tried {})", list(.tried))]
    NotFound { path: PathBuf, tried: Vec<PathBuf> },
    /// The path uses a `{placeholder}` the host does not know.
    #[error(
        "plugin library path {path}: unknown placeholder `{{{placeholder}}}` (only `{{profile}}` is supported)"
    )]
    Placeholder { path: PathBuf, placeholder: String },
    /// The OS loader refused the file (not a shared library, wrong architecture, ...).
    #[error("cannot load {path} as a shared library: {message}")]
    Open { path: PathBuf, message: String },
    /// The library loads but does not export the entry symbol.
    #[error("{path} is not a human2nav plugin: it does not export `{symbol}`")]
    MissingEntry { path: PathBuf, symbol: &'static str },
    /// The library was built against another ABI version.
    #[error(
        "{path} was built for plugin ABI version {found}, this host speaks version {expected}; rebuild the plugin against this SDK"
    )]
    AbiMismatch {
        path: PathBuf,
        found: u32,
        expected: u32,
    },
    /// The entry table or a factory is malformed.
    #[error("{path} has a malformed plugin table: {message}")]
    Malformed { path: PathBuf, message: String },
    /// No factory of that kind and name.
    #[error("{path} (plugin `{plugin}`) has no {kind} factory named `{name}`; it provides: {}", provided(.available))]
    UnknownFactory {
        path: PathBuf,
        plugin: String,
        kind: PluginKind,
        name: String,
        available: Vec<String>,
    },
    /// The factory rejected its TOML configuration.
    #[error("{path}: {kind} `{name}` rejected its config: {message}")]
    Config {
        path: PathBuf,
        kind: PluginKind,
        name: String,
        message: String,
    },
    /// The factory failed (or panicked) while creating the instance.
    #[error("{path}: creating {kind} `{name}` failed ({status}): {message}")]
    Create {
        path: PathBuf,
        kind: PluginKind,
        name: String,
        status: &'static str,
        message: String,
    },
    /// A required function slot of a table is null.
    #[error("{path}: the {table} has a null `{slot}` (a required function)")]
    NullSlot {
        path: PathBuf,
        /// `factory table entry 1 (planner `orca`)`, `planner vtable of `orca``, ...
        table: String,
        slot: &'static str,
    },
    /// A table's `struct_size` is smaller than this ABI's table or larger than the cap
    /// ([`crate::validate::MAX_TABLE_BYTES`]).
    #[error(
        "{path}: the {table} declares {size} bytes (struct_size); this host needs at least {min} and accepts at most {max}"
    )]
    TableSize {
        path: PathBuf,
        table: String,
        size: u32,
        min: usize,
        max: usize,
    },
    /// A count or size from the plugin is above the host's cap ([`crate::validate`]).
    #[error("{path}: {what} is {value}, more than this host accepts ({cap})")]
    Cap {
        path: PathBuf,
        what: String,
        value: u64,
        cap: u64,
    },
    /// The instance was created but its first call failed (robot checks).
    #[error("{path}: {kind} `{name}` was created but its first call failed: {message}")]
    Probe {
        path: PathBuf,
        kind: PluginKind,
        name: String,
        message: String,
    },
    /// A plugin declared by a robot profile could not be used; `item` names the declaration
    /// (`[embodiment]`, `[[constraint]] 1`).
    #[error("robot profile {profile}, {item}: {error}")]
    Profile {
        profile: PathBuf,
        item: String,
        error: Box<PluginError>,
    },
    /// The thread that runs an instance's calls under a deadline could not be started.
    #[error("{instance}: cannot start its worker thread: {message}")]
    Worker { instance: String, message: String },
    /// An instance declared with `isolation = "process"` could not be started in its helper
    /// process (see [`crate::process`]).
    #[error("{instance} (in its own process): {message}")]
    Process { instance: String, message: String },
}

fn provided(names: &[String]) -> String {
    if names.is_empty() {
        "nothing of that kind".to_owned()
    } else {
        names.join(", ")
    }
}

fn list(paths: &[PathBuf]) -> String {
    paths
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}
