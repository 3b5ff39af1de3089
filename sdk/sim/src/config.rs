//! The benchmark configuration (TOML) and how suites are built from it.
//!
//! ```toml
//! seed = 7
//! robots = ["robots/diablo/robot.toml"]         # relative to the workspace root
//! snapshot_method = "orca"                      # method drawn in the Fig. 4 snapshots
//!
//! [sim]                                         # runner::SimConfig
//! dt = 0.05
//! replan_hz = 10.0
//!
//! [[methods]]
//! name = "orca"                                 # name in the report
//! kind = "plugin"                               # straight | oracle | plugin | ... (human2nav: the experiments crate)
//! library = "target/{profile}/human2nav_orca"   # plugin library (kind = "plugin")
//! plugin = "orca"                               # factory name in the library
//! config = { time_horizon = 5.0 }               # passed to the method, kind-specific
//! replan_hz = 5.0                               # optional: this method's replanning rate
//! deadline_ms = 1000                            # plugin only: deadline per planner call
//!                                               # (default 1000; 0: none; human2nav_plugin::deadline)
//! isolation = "process"                         # plugin only: process (default): the planner
//!                                               # runs in a helper process, restarted when it
//!                                               # aborts, segfaults or hangs
//!                                               # (human2nav_plugin::process); "in_process":
//!                                               # opt-in for speed, a crash ends the benchmark
//!
//! [[suites]]
//! name = "real"
//! kind = "real"                                 # real | synthetic | empty
//! episodes = "out/data/episodes.json"          # real only (`human2nav data episodes`)
//! per_class = 50                                # episodes per scenario class
//! quick_per_class = 3                           # with --quick
//! crowd = "replay"                              # replay (default) | reactive
//! social_force = { relaxation_time = 0.5 }      # reactive only: crowd::SocialForce overrides
//! methods = ["human2nav", "orca"]               # optional: only these methods run the suite
//! ```
//!
//! Relative paths are resolved against the workspace root (the nearest ancestor of the config
//! file with a `[workspace]` manifest), like the data configuration's. `base = "<file>"` starts
//! from another config: each top-level key the file sets replaces the base's.
//!
//! A `real` suite whose episode file is missing is an error naming the file, unless the caller
//! allows the synthetic fallback (the benchmark does when the datasets are absent): the suite then
//! becomes a `synthetic` suite of the same size, with a warning in its note. An `empty` suite
//! takes the episodes of the first other suite (or synthetic ones when there is none) and
//! removes every pedestrian.

mod methods;
mod robots;
mod suites;

pub use methods::builtin_method;
pub use robots::{load_robots, load_robots_with};
pub use suites::{build_suites, ensure_episode_files, synthetic_episodes, take_per_class};

use crate::bench::SuiteKind;
use crate::crowd::{CrowdModel, SocialForce};
use crate::error::SimError;
use crate::runner::SimConfig;
use human2nav_plugin::PluginIsolation;
use human2nav_plugin::deadline::deadline_from_ms;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Largest `per_class` / `quick_per_class` of a suite: the mined files hold 50 per class, and a
/// synthetic suite generates this many episodes per class up front.
pub const MAX_PER_CLASS: usize = 10_000;

/// One benchmarked method as configured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MethodConfig {
    /// Name in the report (unique).
    pub name: String,
    /// What to build (`straight`, `plugin`, `human2nav`, ...); resolved by the caller.
    pub kind: String,
    /// The plugin library of a `plugin` method, relative to the workspace root; `{profile}` and
    /// a missing `lib` prefix or extension are resolved by the plugin host.
    #[serde(default)]
    pub library: Option<PathBuf>,
    /// The planner factory's name in the library (default: the method's `name`).
    #[serde(default)]
    pub plugin: Option<String>,
    /// Kind-specific settings.
    #[serde(default)]
    pub config: toml::Table,
    /// This method's replanning rate (Hz) instead of `[sim] replan_hz`, under the same rule (a
    /// whole number of simulation steps per period).
    #[serde(default)]
    pub replan_hz: Option<f64>,
    /// Deadline of each planner call of a `plugin` method, in milliseconds (default
    /// [`human2nav_plugin::deadline::DEFAULT_DEADLINE`], 1000 ms; `0`: none). A call past it
    /// gets the stop-in-place plan, counts as a failed call, and the planner instance is dead
    /// for the rest of its episode (see [`human2nav_plugin::deadline`]).
    #[serde(default)]
    pub deadline_ms: Option<f64>,
    /// Where a `plugin` method's planner runs: in a helper process of its own (`None`, not
    /// written, is [`PluginIsolation::Process`]), restarted when it aborts, segfaults or hangs
    /// (a failed call gets the stop-in-place plan and counts as failed; see
    /// [`human2nav_plugin::process`]), or, opted into with `"in_process"`, in the host process.
    #[serde(default)]
    pub isolation: Option<PluginIsolation>,
}

/// One suite as configured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SuiteConfig {
    /// Name in the report (unique).
    pub name: String,
    /// Where the episodes come from: `real`, `synthetic`, `corridor` or `empty`.
    pub kind: SuiteKind,
    /// Episode file of a `real` suite (`EpisodeSuite` JSON), relative to the workspace root.
    #[serde(default)]
    pub episodes: Option<PathBuf>,
    /// Episodes per scenario class (1 to [`MAX_PER_CLASS`]). Default 50.
    #[serde(default = "default_per_class")]
    pub per_class: usize,
    /// Episodes per scenario class with `--quick` (1 to [`MAX_PER_CLASS`]). Default 3.
    #[serde(default = "default_quick_per_class")]
    pub quick_per_class: usize,
    /// Seed of the synthetic generator; default: the benchmark seed.
    #[serde(default)]
    pub seed: Option<u64>,
    /// How the pedestrians behave. Default `replay`.
    #[serde(default)]
    pub crowd: CrowdMode,
    /// Parameters of a `reactive` crowd (default [`SocialForce::default`]).
    #[serde(default)]
    pub social_force: Option<SocialForce>,
    /// Only these methods run the suite (default: every method).
    #[serde(default)]
    pub methods: Option<Vec<String>>,
}

/// How the pedestrians of a suite behave.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CrowdMode {
    /// Replayed exactly as recorded (the paper's protocol).
    #[default]
    Replay,
    /// Recorded paths with a social-force response to the robot ([`crate::crowd`]).
    Reactive,
}

impl SuiteConfig {
    /// The crowd model of this suite.
    pub fn crowd_model(&self) -> CrowdModel {
        match self.crowd {
            CrowdMode::Replay => CrowdModel::Replay,
            CrowdMode::Reactive => CrowdModel::Reactive(self.social_force.unwrap_or_default()),
        }
    }
}

fn default_per_class() -> usize {
    50
}

fn default_quick_per_class() -> usize {
    3
}

/// The whole benchmark configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BenchConfig {
    /// Master seed. Default 7.
    pub seed: u64,
    /// Robot profiles (`robot.toml`), relative to the workspace root.
    pub robots: Vec<PathBuf>,
    /// Simulation settings shared by every run (`[sim]`).
    pub sim: SimConfig,
    /// The methods benchmarked (`[[methods]]`), in report order.
    pub methods: Vec<MethodConfig>,
    /// The suites run (`[[suites]]`), in report order.
    pub suites: Vec<SuiteConfig>,
    /// Method drawn in the trajectory snapshots; default the first method that is not
    /// `straight`.
    pub snapshot_method: Option<String>,
    /// The directory relative paths are resolved against (the workspace root, else the config
    /// file's directory; not read from the file).
    #[serde(skip)]
    pub base_dir: PathBuf,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            seed: 7,
            robots: Vec::new(),
            sim: SimConfig::default(),
            methods: Vec::new(),
            suites: Vec::new(),
            snapshot_method: None,
            base_dir: PathBuf::from("."),
        }
    }
}

impl BenchConfig {
    /// Reads, parses and validates a config file; relative paths resolve against the workspace
    /// root above it (else its own directory). A file may start from another one with
    /// `base = "<path>"` (relative to the workspace root): every top-level key it sets replaces
    /// the base's (so a validation config can take the robots, simulation settings and
    /// methods of the test config and name its own suites).
    pub fn load(path: &Path) -> Result<Self, SimError> {
        let dir = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        let base_dir = human2nav_data::paths::find_workspace_root(&dir).unwrap_or(dir);
        let table = Self::load_table(path, &base_dir, 0)?;
        let mut cfg: BenchConfig =
            table
                .try_into()
                .map_err(|e: toml::de::Error| SimError::Parse {
                    path: path.to_path_buf(),
                    message: e.to_string(),
                })?;
        cfg.base_dir = base_dir;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The file's table with its `base` chain merged in (at most 8 deep, no cycles).
    fn load_table(path: &Path, base_dir: &Path, depth: usize) -> Result<toml::Table, SimError> {
        let parse = |message: String| SimError::Parse {
            path: path.to_path_buf(),
            message,
        };
        if depth > 8 {
            return Err(parse("more than 8 nested `base` files (a cycle?)".into()));
        }
        let text = human2nav_core::input::read_user_file(
            path,
            "benchmark configuration",
            human2nav_core::input::MAX_CONFIG_BYTES,
        )
        .map_err(|e| SimError::io(path, e))?;
        let mut table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| parse(e.to_string()))?;
        let Some(base) = table.remove("base") else {
            return Ok(table);
        };
        let Some(base) = base.as_str() else {
            return Err(parse("`base` must be a path (a string)".into()));
        };
        let base_path = if Path::new(base).is_absolute() {
            PathBuf::from(base)
        } else {
            base_dir.join(base)
        };
        let mut merged = Self::load_table(&base_path, base_dir, depth + 1)
            .map_err(|e| parse(format!("base `{base}`: {e}")))?;
        merged.extend(table);
        Ok(merged)
    }

    /// Checks the simulation settings, that names are unique and that every `real` suite names
    /// its episode file.
    pub fn validate(&self) -> Result<(), SimError> {
        self.sim.validate()?;
        if self.robots.is_empty() {
            return Err(SimError::setting(
                "bench",
                "robots",
                "list at least one robot profile",
            ));
        }
        if self.methods.is_empty() {
            return Err(SimError::setting(
                "bench",
                "methods",
                "list at least one method",
            ));
        }
        if self.suites.is_empty() {
            return Err(SimError::setting(
                "bench",
                "suites",
                "list at least one suite",
            ));
        }
        for (i, m) in self.methods.iter().enumerate() {
            self.validate_method(i, m)?;
        }
        for (i, s) in self.suites.iter().enumerate() {
            self.validate_suite(i, s)?;
        }
        if let Some(m) = &self.snapshot_method {
            if !self.methods.iter().any(|x| &x.name == m) {
                return Err(SimError::setting(
                    "bench",
                    "snapshot_method",
                    format!("`{m}` is not a configured method"),
                ));
            }
        }
        Ok(())
    }

    /// Checks `methods[i]`: a unique name, its replanning rate, and the keys only a plugin
    /// method takes.
    fn validate_method(&self, i: usize, m: &MethodConfig) -> Result<(), SimError> {
        human2nav_core::input::check_name(&m.name)
            .map_err(|why| SimError::setting(format!("methods[{i}]"), "name", why))?;
        if self.methods[..i].iter().any(|o| o.name == m.name) {
            return Err(SimError::setting(
                format!("methods[{i}]"),
                "name",
                format!("`{}` is repeated", m.name),
            ));
        }
        self.sim
            .with_replan_hz(m.replan_hz)
            .validate()
            .map_err(|e| match e {
                SimError::Setting { message, .. } => {
                    SimError::setting(format!("methods[{}]", m.name), "replan_hz", message)
                }
                other => other,
            })?;
        if m.kind == "plugin" && m.library.is_none() {
            return Err(SimError::setting(
                format!("methods[{i}]"),
                "library",
                "a plugin method names its library",
            ));
        }
        if m.deadline_ms.is_some() && m.kind != "plugin" {
            return Err(SimError::setting(
                format!("methods[{i}]"),
                "deadline_ms",
                "only a plugin method has a deadline (built-in planners run in the host)",
            ));
        }
        deadline_from_ms(m.deadline_ms)
            .map_err(|e| SimError::setting(format!("methods[{i}]"), "deadline_ms", e))?;
        if m.isolation.is_some() && m.kind != "plugin" {
            return Err(SimError::setting(
                format!("methods[{i}]"),
                "isolation",
                "only a plugin method can run in its own process (built-in planners run in \
                 the host)",
            ));
        }
        Ok(())
    }

    /// Checks `suites[i]`: a unique name, the episode file of a real suite, the episode
    /// counts, the social-force parameters and the methods it names.
    fn validate_suite(&self, i: usize, s: &SuiteConfig) -> Result<(), SimError> {
        let section = format!("suites[{i}]");
        human2nav_core::input::check_name(&s.name)
            .map_err(|why| SimError::setting(section.clone(), "name", why))?;
        if self.suites[..i].iter().any(|o| o.name == s.name) {
            return Err(SimError::setting(
                section,
                "name",
                format!("`{}` is repeated", s.name),
            ));
        }
        if s.kind == SuiteKind::Real && s.episodes.is_none() {
            return Err(SimError::setting(
                section,
                "episodes",
                "a real suite needs its episode file",
            ));
        }
        for (field, n) in [
            ("per_class", s.per_class),
            ("quick_per_class", s.quick_per_class),
        ] {
            if n == 0 || n > MAX_PER_CLASS {
                return Err(SimError::setting(
                    section,
                    field,
                    format!("episode counts must be in 1..={MAX_PER_CLASS}, got {n}"),
                ));
            }
        }
        match (&s.social_force, s.crowd) {
            (Some(_), CrowdMode::Replay) => {
                return Err(SimError::setting(
                    section,
                    "social_force",
                    "only a suite with crowd = \"reactive\" takes social-force parameters",
                ));
            }
            (Some(f), CrowdMode::Reactive) => {
                f.validate().map_err(|(field, message)| {
                    SimError::setting(format!("suites[{i}].social_force"), field, message)
                })?;
            }
            (None, _) => {}
        }
        if let Some(methods) = &s.methods {
            if methods.is_empty() {
                return Err(SimError::setting(
                    section,
                    "methods",
                    "list at least one method, or leave the key out for every method",
                ));
            }
            if let Some(bad) = methods
                .iter()
                .find(|m| !self.methods.iter().any(|x| &x.name == *m))
            {
                return Err(SimError::setting(
                    section,
                    "methods",
                    format!(
                        "`{bad}` is not a configured method (they are: {})",
                        self.methods
                            .iter()
                            .map(|m| m.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ));
            }
        }
        Ok(())
    }

    /// A path from the config resolved against [`BenchConfig::base_dir`].
    pub fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.base_dir.join(p)
        }
    }

    /// The method drawn in the snapshots.
    pub fn snapshot_method(&self) -> Option<&str> {
        self.snapshot_method
            .as_deref()
            .or_else(|| {
                self.methods
                    .iter()
                    .find(|m| m.kind != "straight")
                    .map(|m| m.name.as_str())
            })
            .or_else(|| self.methods.first().map(|m| m.name.as_str()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plugin_method_may_ask_for_its_own_process() {
        let m: MethodConfig = toml::from_str(
            "name = \"orca\"\nkind = \"plugin\"\nlibrary = \"x\"\nisolation = \"process\"",
        )
        .expect("parses");
        assert_eq!(m.isolation, Some(PluginIsolation::Process));
        // Not written: a helper process.
        let m: MethodConfig =
            toml::from_str("name = \"orca\"\nkind = \"plugin\"\nlibrary = \"x\"").expect("parses");
        assert_eq!(m.isolation, None);
        assert_eq!(m.isolation.unwrap_or_default(), PluginIsolation::Process);
        let m: MethodConfig = toml::from_str(
            "name = \"orca\"\nkind = \"plugin\"\nlibrary = \"x\"\nisolation = \"in_process\"",
        )
        .expect("parses");
        assert_eq!(m.isolation, Some(PluginIsolation::InProcess));
        assert!(
            toml::from_str::<MethodConfig>("name = \"a\"\nkind = \"plugin\"\nisolation = \"fork\"")
                .is_err()
        );
    }
}
