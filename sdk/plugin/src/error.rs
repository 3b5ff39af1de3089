//! Errors of the plugin host. Every message is one line and names the library.

use std::fmt;
use std::path::PathBuf;

/// The kind of object a factory creates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PluginKind {
    /// A constraint term (`ConstraintTerm`).
    Constraint,
    /// An embodiment: kinematic model and tracking controller (`Embodiment`).
    Embodiment,
    /// A planner (`Planner`).
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
    NotFound {
        /// The library path as named.
        path: PathBuf,
        /// Every path looked at.
        tried: Vec<PathBuf>,
    },
    /// The path uses a `{placeholder}` the host does not know.
    #[error(
        "plugin library path {path}: unknown placeholder `{{{placeholder}}}` (only `{{profile}}` is supported)"
    )]
    Placeholder {
        /// The library path as named.
        path: PathBuf,
        /// The unknown placeholder's name.
        placeholder: String,
    },
    /// The OS loader refused the file (not a shared library, wrong architecture, ...).
    #[error("cannot load {path} as a shared library: {message}")]
    Open {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
    /// The library loads but does not export the entry symbol.
    #[error("{path} is not a human2nav plugin: it does not export `{symbol}`")]
    MissingEntry {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// The entry symbol the host looks for.
        symbol: &'static str,
    },
    /// The library was built against another ABI version.
    #[error(
        "{path} was built for plugin ABI version {found}, this host loads versions {}–{expected}; rebuild the plugin against this SDK",
        crate::abi::MIN_ABI_VERSION
    )]
    AbiMismatch {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// The version the plugin was built for.
        found: u32,
        /// The newest version this host speaks ([`crate::ABI_VERSION`]; it loads down to
        /// [`crate::abi::MIN_ABI_VERSION`]).
        expected: u32,
    },
    /// The entry table or a factory is malformed.
    #[error("{path} has a malformed plugin table: {message}")]
    Malformed {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
    /// No factory of that kind and name.
    #[error("{path} (plugin `{plugin}`) has no {kind} factory named `{name}`; it provides: {}", provided(.available))]
    UnknownFactory {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// The plugin's name.
        plugin: String,
        /// The kind of object asked for.
        kind: PluginKind,
        /// The factory's name.
        name: String,
        /// The factories of that kind the library provides.
        available: Vec<String>,
    },
    /// The factory rejected its TOML configuration.
    #[error("{path}: {kind} `{name}` rejected its config: {message}")]
    Config {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// The kind of object asked for.
        kind: PluginKind,
        /// The factory's name.
        name: String,
        /// What went wrong, in one line.
        message: String,
    },
    /// The factory failed (or panicked) while creating the instance.
    #[error("{path}: creating {kind} `{name}` failed ({status}): {message}")]
    Create {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// The kind of object asked for.
        kind: PluginKind,
        /// The factory's name.
        name: String,
        /// The status the factory returned (`H2N_*` name).
        status: &'static str,
        /// What went wrong, in one line.
        message: String,
    },
    /// A required function slot of a table is null.
    #[error("{path}: the {table} has a null `{slot}` (a required function)")]
    NullSlot {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// `factory table entry 1 (planner `orca`)`, `planner vtable of `orca``, ...
        table: String,
        /// The null slot.
        slot: &'static str,
    },
    /// A table's `struct_size` is smaller than this ABI's table or larger than the cap
    /// ([`crate::validate::MAX_TABLE_BYTES`]).
    #[error(
        "{path}: the {table} declares {size} bytes (struct_size); this host needs at least {min} and accepts at most {max}"
    )]
    TableSize {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// The table (`entry table`, `factory table entry 0`, a vtable).
        table: String,
        /// The `struct_size` the plugin declared.
        size: u32,
        /// This ABI's size of the table.
        min: usize,
        /// The cap ([`crate::validate::MAX_TABLE_BYTES`]).
        max: usize,
    },
    /// A count or size from the plugin is above the host's cap ([`crate::validate`]).
    #[error("{path}: {what} is {value}, more than this host accepts ({cap})")]
    Cap {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// What was counted or measured.
        what: String,
        /// The plugin's value.
        value: u64,
        /// The host's cap.
        cap: u64,
    },
    /// The instance was created but its first call failed (robot checks).
    #[error("{path}: {kind} `{name}` was created but its first call failed: {message}")]
    Probe {
        /// The library (as resolved, or as named when it was not found).
        path: PathBuf,
        /// The kind of object asked for.
        kind: PluginKind,
        /// The factory's name.
        name: String,
        /// What went wrong, in one line.
        message: String,
    },
    /// A plugin declared by a robot profile could not be used; `item` names the declaration
    /// (`[embodiment]`, `[[constraint]] 1`).
    #[error("robot profile {profile}, {item}: {error}")]
    Profile {
        /// The robot profile.
        profile: PathBuf,
        /// The declaration (`[embodiment]`, `[[constraint]] 1`).
        item: String,
        /// Why the plugin could not be used.
        error: Box<PluginError>,
    },
    /// The thread that runs an instance's calls under a deadline could not be started.
    #[error("{instance}: cannot start its worker thread: {message}")]
    Worker {
        /// The instance (plugin, factory and kind).
        instance: String,
        /// What went wrong, in one line.
        message: String,
    },
    /// An instance declared with `isolation = "process"` could not be started in its helper
    /// process (see [`crate::process`]).
    #[error("{instance} (in its own process): {message}")]
    Process {
        /// The instance (plugin, factory and kind).
        instance: String,
        /// What went wrong, in one line.
        message: String,
    },
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
