//! The episode jobs: mining the paper-protocol and interaction-rich suites (or the synthetic
//! fallback) and writing the episode files of `human2nav data episodes`.

use super::{Locations, Progress, Source, discover, load_source};
use crate::config::DataConfig;
use crate::episode_mining::{
    InteractionReport, InteractionStats, mine_interaction_scene, select_interaction_suite,
    summarize,
};
use crate::error::DataError;
use crate::paths;
use crate::resample::resample;
use crate::scenario::{EpisodeSuite, MiningStats, ScenarioClass, mine_scene, select};
use crate::synthetic;
use crate::tuples::Split;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// What `build_episodes` did.
#[derive(Clone, Debug)]
pub struct EpisodeReport {
    /// The selected episodes.
    pub suite: EpisodeSuite,
    /// Why candidate windows were rejected, over all scenes.
    pub stats: MiningStats,
    /// What the user should know (missing datasets, the synthetic fallback, ...).
    pub notes: Vec<String>,
    /// Test scenes mined.
    pub scenes: Vec<String>,
}

/// Mines episodes from the test scenes (or generates synthetic ones) and selects up to
/// `episodes.per_class` per class.
pub fn build_episodes(
    cfg: &DataConfig,
    loc: &Locations,
    progress: &dyn Progress,
) -> Result<EpisodeReport, DataError> {
    let opts = &cfg.episodes;
    if !loc.datasets(cfg) {
        let episodes = synthetic_fallback(cfg, loc, opts.seed, progress)?;
        let note = format!(
            "{}: synthetic social-force episodes",
            loc.synthetic_reason(cfg)
        );
        return Ok(EpisodeReport {
            suite: EpisodeSuite::new("synthetic", episodes),
            stats: MiningStats::default(),
            notes: vec![note],
            scenes: Vec::new(),
        });
    }
    let (sources, notes) = discover(&loc.data_root, cfg);
    let sources: Vec<Source> = sources
        .into_iter()
        .filter(|s| cfg.split.of(&s.name) == Some(Split::Test))
        .collect();
    if sources.is_empty() {
        return Err(DataError::NoData(
            "no test scene found (see [split] test)".into(),
        ));
    }
    progress.stage("mine", sources.len() as u64);
    let mined = sources
        .par_iter()
        .map(|src| {
            let raw = load_source(src, cfg)?;
            let scene = resample(&raw, &cfg.resample);
            let mut stats = MiningStats::default();
            let eps = mine_scene(&scene, opts, &mut stats);
            progress.inc(1);
            Ok((eps, stats))
        })
        .collect::<Result<Vec<_>, DataError>>()?;
    let mut all = Vec::new();
    let mut stats = MiningStats::default();
    for (eps, st) in mined {
        all.extend(eps);
        stats.add(&st);
    }
    let names: Vec<String> = sources.iter().map(|s| s.name.clone()).collect();
    let episodes = select(all, opts.per_class, opts.seed);
    Ok(EpisodeReport {
        suite: EpisodeSuite::new(format!("real: {}", names.join(", ")), episodes),
        stats,
        notes,
        scenes: names,
    })
}

/// The interaction-rich suite file of a split (`paths.interaction_episodes` for test,
/// `paths.interaction_val_episodes` for val), resolved against the workspace.
pub fn interaction_episodes_path(
    cfg: &DataConfig,
    loc: &Locations,
    split: Split,
) -> Result<PathBuf, DataError> {
    let p = match split {
        Split::Test => &cfg.paths.interaction_episodes,
        Split::Val => &cfg.paths.interaction_val_episodes,
        Split::Train => return Err(not_held_out()),
    };
    Ok(paths::output_path(p, &loc.workspace))
}

fn not_held_out() -> DataError {
    DataError::option(
        "split",
        "interaction episodes are mined from the test or val scenes, not from train",
    )
}

/// Mines interaction-rich episodes ([`crate::episode_mining`]) from the scenes of `split`
/// (`[split] test` or `val`) and selects up to `episodes.per_class` per class. Errors when no
/// scene of the split is found or a class yields no episode at all; fewer than `per_class`
/// in a class is a note. Without a dataset directory and with `sources.synthetic_fallback`,
/// the synthetic episodes of `build_episodes` (paper protocol), with a note saying so.
pub fn build_interaction_episodes(
    cfg: &DataConfig,
    loc: &Locations,
    split: Split,
    progress: &dyn Progress,
) -> Result<InteractionReport, DataError> {
    if split == Split::Train {
        return Err(not_held_out());
    }
    let geometry = &cfg.episodes;
    let opts = &cfg.interaction;
    // Read first, so that a bad file is refused whether or not the datasets are there.
    let excluded = excluded_episode_ids(&opts.exclude_episodes, &loc.workspace)?;
    if !loc.datasets(cfg) {
        let seed = match split {
            Split::Val => geometry.seed ^ 0x5641_4C00, // other crowds than the test fallback
            _ => geometry.seed,
        };
        let episodes = synthetic_fallback(cfg, loc, seed, progress)?;
        let note = format!(
            "{}: synthetic social-force episodes of the paper protocol, NOT \
             interaction-rich (no time shift, no interaction criterion)",
            loc.synthetic_reason(cfg)
        );
        let mut notes = vec![note];
        if !opts.exclude_episodes.is_empty() {
            notes.push(
                "interaction.exclude_episodes applies to mined episodes only; the synthetic \
                 ones are drawn as without it"
                    .into(),
            );
        }
        let suite = EpisodeSuite::new(format!("synthetic ({split})"), episodes);
        return Ok(InteractionReport {
            split,
            summary: summarize(&suite.episodes),
            suite,
            scenes: Vec::new(),
            stats: InteractionStats::default(),
            notes,
        });
    }
    let (sources, mut notes) = discover(&loc.data_root, cfg);
    let sources: Vec<Source> = sources
        .into_iter()
        .filter(|s| cfg.split.of(&s.name) == Some(split))
        .collect();
    let listed = match split {
        Split::Val => &cfg.split.val,
        _ => &cfg.split.test,
    };
    for name in listed {
        if !sources.iter().any(|s| &s.name == name) && !cfg.split.exclude.contains(name) {
            notes.push(format!(
                "{split} scene {name} not found under the data root"
            ));
        }
    }
    if sources.is_empty() {
        return Err(DataError::NoData(format!(
            "no {split} scene found under {} (see [split] {split})",
            loc.data_root.display()
        )));
    }
    progress.stage("mine interactions", sources.len() as u64);
    let mined = sources
        .par_iter()
        .map(|src| {
            let raw = load_source(src, cfg)?;
            let scene = resample(&raw, &cfg.resample);
            let mut stats = InteractionStats::default();
            let mut eps = mine_interaction_scene(&scene, geometry, opts, &mut stats);
            crate::episode_mining::withhold(&mut eps, &excluded, &mut stats);
            progress.inc(1);
            Ok((src.name.clone(), eps, stats))
        })
        .collect::<Result<Vec<_>, DataError>>()?;
    select_interaction_suite(split, mined, &cfg.episodes, &cfg.interaction, notes)
}

/// The ids of every episode in the files of `interaction.exclude_episodes` (relative paths
/// against `workspace`); an unreadable or malformed file is an error naming the key and the file.
fn excluded_episode_ids(
    files: &[PathBuf],
    workspace: &Path,
) -> Result<std::collections::HashSet<String>, DataError> {
    let mut ids = std::collections::HashSet::new();
    for f in files {
        let path = paths::output_path(f, workspace);
        let suite = EpisodeSuite::load(&path)
            .map_err(|e| DataError::option("interaction.exclude_episodes", format!("{e}")))?;
        ids.extend(suite.episodes.into_iter().map(|e| e.id));
    }
    Ok(ids)
}

/// Without a dataset directory: synthetic episodes of the paper protocol (`episodes.per_class`
/// per class), or the error saying the directory is missing when `sources.synthetic_fallback`
/// is off.
fn synthetic_fallback(
    cfg: &DataConfig,
    loc: &Locations,
    seed: u64,
    progress: &dyn Progress,
) -> Result<Vec<crate::scenario::Episode>, DataError> {
    if !cfg.sources.synthetic_fallback && !cfg.sources.synthetic_only {
        return Err(DataError::NoData(format!(
            "{} does not exist",
            loc.data_root.display()
        )));
    }
    let opts = &cfg.episodes;
    progress.stage("synthetic episodes", 4);
    Ok(ScenarioClass::ALL
        .par_iter()
        .map(|&c| {
            let e = synthetic::episodes_with(c, opts.per_class, seed, opts);
            progress.inc(1);
            e
        })
        .flatten()
        .collect())
}

/// The episode files `human2nav data episodes` writes, each named by a key of `[paths]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EpisodeFile {
    /// The paper protocol's held-out test episodes (`paths.episodes`).
    Real,
    /// Interaction-rich episodes of the test or val scenes (`paths.interaction_episodes`,
    /// `paths.interaction_val_episodes`).
    Interaction(Split),
}

impl EpisodeFile {
    /// Every file, in the order `data episodes` writes them.
    pub const ALL: [EpisodeFile; 3] = [
        EpisodeFile::Real,
        EpisodeFile::Interaction(Split::Test),
        EpisodeFile::Interaction(Split::Val),
    ];

    /// The `[paths]` key that names the file.
    pub fn key(self) -> &'static str {
        match self {
            EpisodeFile::Real => "paths.episodes",
            EpisodeFile::Interaction(Split::Val) => "paths.interaction_val_episodes",
            EpisodeFile::Interaction(_) => "paths.interaction_episodes",
        }
    }

    /// Where the file goes.
    pub fn path(self, cfg: &DataConfig, loc: &Locations) -> Result<PathBuf, DataError> {
        match self {
            EpisodeFile::Real => Ok(loc.episodes.clone()),
            EpisodeFile::Interaction(split) => interaction_episodes_path(cfg, loc, split),
        }
    }
}

/// What [`write_episode_file`] wrote.
#[derive(Clone, Debug)]
pub struct WrittenEpisodes {
    /// The episode file.
    pub path: PathBuf,
    /// Episodes in it.
    pub episodes: usize,
    /// The mining report beside it (`<file>.md`, interaction files only) and its text.
    pub report: Option<(PathBuf, String)>,
    /// What the user should know (missing datasets, the synthetic fallback, ...).
    pub notes: Vec<String>,
}

/// Mines the episodes of `file` and writes them to `out` (default: the file's path); an
/// interaction file gets its mining report ([`InteractionReport::markdown`]) beside it as
/// `<file>.md`.
pub fn write_episode_file(
    file: EpisodeFile,
    cfg: &DataConfig,
    loc: &Locations,
    out: Option<&Path>,
    progress: &dyn Progress,
) -> Result<WrittenEpisodes, DataError> {
    let path = match out {
        Some(p) => p.to_path_buf(),
        None => file.path(cfg, loc)?,
    };
    let (suite, notes, report) = match file {
        EpisodeFile::Real => {
            let r = build_episodes(cfg, loc, progress)?;
            (r.suite, r.notes, None)
        }
        EpisodeFile::Interaction(split) => {
            let r = build_interaction_episodes(cfg, loc, split, progress)?;
            let md = r.markdown(&cfg.interaction);
            (r.suite, r.notes, Some(md))
        }
    };
    suite.save(&path)?;
    let report = match report {
        Some(md) => {
            let mut p = path.as_os_str().to_owned();
            p.push(".md");
            let p = PathBuf::from(p);
            std::fs::write(&p, &md).map_err(|e| DataError::io(&p, e))?;
            Some((p, md))
        }
        None => None,
    };
    Ok(WrittenEpisodes {
        path,
        episodes: suite.episodes.len(),
        report,
        notes,
    })
}
