//! The benchmark episode as the simulator sees it: the data crate's types, re-exported.
//!
//! This is the single place where the simulator touches the data crate's episode types; every
//! other module of the crate goes through these names.

pub use human2nav_data::{AgentTrack, Episode, EpisodeSuite, ScenarioClass};

use crate::error::SimError;
use human2nav_data::DataError;
use std::path::Path;

/// Reads an episode file, a suite (`human2nav data episodes`) or a single [`Episode`] as JSON:
/// the one reader of the benchmark's `real` suites and of `plan --episode`, so both accept
/// exactly the same files. Every episode goes through [`Episode::validate`] (bounds in
/// ARCHITECTURE.md, "Input limits"); the error names the file, the episode's index and id, and
/// the field.
pub fn load_episode_file(path: &Path) -> Result<EpisodeSuite, SimError> {
    EpisodeSuite::load_any(path).map_err(|e| match e {
        DataError::Io { path, source } => SimError::Io { path, source },
        DataError::Json { path, source } => SimError::Parse {
            path,
            message: source.to_string(),
        },
        DataError::Episode {
            path,
            index,
            id,
            field,
            message,
        } => SimError::Parse {
            path,
            message: format!("episode {index} (`{id}`): {field}: {message}"),
        },
        DataError::Episodes { path, message } => SimError::Parse { path, message },
        other => SimError::Parse {
            path: path.to_path_buf(),
            message: other.to_string(),
        },
    })
}

/// Display names of the scenario classes, as the paper writes them.
pub trait ScenarioTitle {
    /// `Co-Flow`, `Cross-Flow`, `Counter-Flow`, `Multidirection-Flow`.
    fn title(self) -> &'static str;
}

impl ScenarioTitle for ScenarioClass {
    fn title(self) -> &'static str {
        match self {
            ScenarioClass::CoFlow => "Co-Flow",
            ScenarioClass::CrossFlow => "Cross-Flow",
            ScenarioClass::CounterFlow => "Counter-Flow",
            ScenarioClass::MultidirectionFlow => "Multidirection-Flow",
        }
    }
}
