//! The benchmark episode as the simulator sees it: the data crate's types, re-exported.
//!
//! This is the single place where the simulator touches the data crate's episode types; every
//! other module of the crate goes through these names.

pub use human2nav_data::{AgentTrack, Episode, EpisodeSuite, ScenarioClass};

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
