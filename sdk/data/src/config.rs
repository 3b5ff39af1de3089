//! The `data.toml` configuration of `human2nav data build | episodes | associate` (and of the
//! interaction-rich episodes, `[interaction]`).
//!
//! Every section is optional and defaults to the values documented on its struct; unknown
//! keys are rejected. Relative paths are resolved against the workspace root.

use crate::association::TrackerOptions;
use crate::episode_mining::InteractionOptions;
use crate::error::DataError;
use crate::loaders::sdd::SddRawOptions;
use crate::resample::ResampleOptions;
use crate::scenario::MiningOptions;
use crate::tuples::{Split, TupleOptions};
use human2nav_core::bev::BevSpec;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Where to read and write.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PathsConfig {
    /// Dataset directory; empty: `$HUMAN2NAV_DATA`, else `<workspace>/../shared/data`.
    pub data_root: PathBuf,
    /// Tuple cache directory. Default `out/data/cache`.
    pub cache_dir: PathBuf,
    /// Episode suite file. Default `out/data/episodes.json`.
    pub episodes: PathBuf,
    /// Interaction-rich episodes of the test scenes ([`crate::episode_mining`]). Default
    /// `out/data/episodes-interaction.json`.
    pub interaction_episodes: PathBuf,
    /// Interaction-rich episodes of the validation scenes. Default
    /// `out/data/episodes-interaction-val.json`.
    pub interaction_val_episodes: PathBuf,
}

impl Default for PathsConfig {
    fn default() -> Self {
        Self {
            data_root: PathBuf::new(),
            cache_dir: PathBuf::from("out/data/cache"),
            episodes: PathBuf::from("out/data/episodes.json"),
            interaction_episodes: PathBuf::from("out/data/episodes-interaction.json"),
            interaction_val_episodes: PathBuf::from("out/data/episodes-interaction-val.json"),
        }
    }
}

/// Largest `sources.synthetic_scenes` (250 times the default of 400; each scene is a crowd of
/// a minute or so).
pub const MAX_SYNTHETIC_SCENES: usize = 100_000;

/// Which sources to read.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SourcesConfig {
    /// ETH/EWAP `obsmat.txt` (`eth/eth`, `eth/hotel`). Default true.
    pub eth: bool,
    /// UCY `annotation.vsp` + `H.txt` (`ucy/zara01` …; arxiepiskopi has no usable unit). Default true.
    pub ucy: bool,
    /// SDD raw annotations (`sdd/<scene>_<n>`, preferred where present). Default true.
    pub sdd_raw: bool,
    /// SDD TrajNet split in metres for the videos without raw annotations. Default true.
    pub sdd_trajnet: bool,
    /// The sgan/Trajectron benchmark files (`sgan/<file>`; they duplicate ETH/UCY). Default false.
    pub sgan: bool,
    /// Use synthetic social-force scenes when the default dataset directory (no
    /// `paths.data_root`, no `$HUMAN2NAV_DATA`) does not exist. Default true. A directory that
    /// was named and is missing is an error ([`crate::pipeline::Locations::resolve_checked`]).
    pub synthetic_fallback: bool,
    /// Use the synthetic scenes even where datasets exist (tests, a build without the data).
    /// Default false.
    pub synthetic_only: bool,
    /// Number of synthetic scenes for the fallback cache (at most [`MAX_SYNTHETIC_SCENES`]).
    /// Default 400.
    pub synthetic_scenes: usize,
    /// Seed of the synthetic fallback.
    pub seed: u64,
}

impl Default for SourcesConfig {
    fn default() -> Self {
        Self {
            eth: true,
            ucy: true,
            sdd_raw: true,
            sdd_trajnet: true,
            sgan: false,
            synthetic_fallback: true,
            synthetic_only: false,
            synthetic_scenes: 400,
            seed: 1,
        }
    }
}

/// Scene-level split: scenes named in `test` or `val` go there, every other scene to train.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SplitConfig {
    /// Held-out scenes (`dataset/scene`): the benchmark's.
    pub test: Vec<String>,
    /// Validation scenes (`dataset/scene`).
    pub val: Vec<String>,
    /// Scenes left out entirely.
    pub exclude: Vec<String>,
}

impl SplitConfig {
    /// The split of a scene, or `None` when it is excluded.
    pub fn of(&self, scene: &str) -> Option<Split> {
        if self.exclude.iter().any(|s| s == scene) {
            None
        } else if self.test.iter().any(|s| s == scene) {
            Some(Split::Test)
        } else if self.val.iter().any(|s| s == scene) {
            Some(Split::Val)
        } else {
            Some(Split::Train)
        }
    }
}

/// The whole configuration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DataConfig {
    /// Where the datasets are and where outputs go (`[paths]`).
    pub paths: PathsConfig,
    /// Which datasets to read (`[sources]`).
    pub sources: SourcesConfig,
    /// How Stanford Drone Dataset annotations are read (`[sdd]`).
    pub sdd: SddRawOptions,
    /// Which scenes train, validate and test (`[split]`).
    pub split: SplitConfig,
    /// The 0.1 s grid (`[resample]`).
    pub resample: ResampleOptions,
    /// The BEV raster of the tuples (`[bev]`).
    pub bev: BevSpec,
    /// How training tuples are made (`[tuples]`).
    pub tuples: TupleOptions,
    /// How benchmark episodes are mined (`[episodes]`).
    pub episodes: MiningOptions,
    /// Interaction-rich episodes; their geometry comes from `episodes`.
    pub interaction: InteractionOptions,
    /// The identity-free tracker (`[association]`).
    pub association: TrackerOptions,
}

impl DataConfig {
    /// Parses and validates a config file (a regular file of at most
    /// [`MAX_CONFIG_BYTES`](human2nav_core::input::MAX_CONFIG_BYTES)).
    pub fn load(path: &Path) -> Result<Self, DataError> {
        let body = human2nav_core::input::read_user_file(
            path,
            "data configuration",
            human2nav_core::input::MAX_CONFIG_BYTES,
        )
        .map_err(|e| DataError::io(path, e))?;
        Self::parse(&body, path)
    }

    /// Parses and validates config text (`path` only names it in errors).
    pub fn parse(body: &str, path: &Path) -> Result<Self, DataError> {
        let cfg: Self = toml::from_str(body).map_err(|e| DataError::Config {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate().map_err(|e| DataError::Config {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        Ok(cfg)
    }

    /// Checks every section.
    pub fn validate(&self) -> Result<(), DataError> {
        self.resample.validate()?;
        self.bev
            .validate()
            .map_err(|e| DataError::option("bev", e.to_string()))?;
        self.tuples.validate()?;
        self.episodes.validate()?;
        self.interaction.validate()?;
        self.association.validate()?;
        if self.sources.synthetic_scenes > MAX_SYNTHETIC_SCENES {
            return Err(DataError::option(
                "sources.synthetic_scenes",
                format!(
                    "{} is more than the limit of {MAX_SYNTHETIC_SCENES}",
                    self.sources.synthetic_scenes
                ),
            ));
        }
        if (self.resample.dt - 0.1).abs() > 1e-12 {
            return Err(DataError::option(
                "resample.dt",
                "the SDK's tuples and episodes use 0.1 s",
            ));
        }
        for name in &self.split.test {
            if self.split.val.contains(name) {
                return Err(DataError::option(
                    "split",
                    format!("scene `{name}` is in both test and val"),
                ));
            }
        }
        Ok(())
    }
}
