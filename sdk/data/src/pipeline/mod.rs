//! End-to-end jobs: dataset discovery, the tuple cache build, episode mining (paper protocol
//! and interaction-rich) and the association evaluation. Scenes are processed in parallel
//! (rayon) and collected in name order, so the output is identical for any number of threads.

mod episodes;
mod sources;

pub use episodes::{
    EpisodeFile, EpisodeReport, WrittenEpisodes, build_episodes, build_interaction_episodes,
    interaction_episodes_path, write_episode_file,
};
pub use sources::{Source, SourceKind, UCY_SCENES, discover, load_source};

use crate::association::{AssociationReport, associate, evaluate, sdd_detections};
use crate::cache::{Manifest, SceneInfo, TupleCache};
use crate::config::DataConfig;
pub use crate::episode_mining::InteractionReport;
use crate::error::DataError;
use crate::loaders::sdd;
use crate::paths;
use crate::resample::{Scene, median, resample};
use crate::synthetic;
use crate::tuples::{CompactTuple, Split, TupleStats, scene_tuples};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Receives progress of long jobs (the CLI draws a bar).
pub trait Progress: Sync {
    /// A new stage with `total` units of work.
    fn stage(&self, name: &str, total: u64);
    /// `n` units done.
    fn inc(&self, n: u64);
}

/// Progress that goes nowhere.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn stage(&self, _: &str, _: u64) {}
    fn inc(&self, _: u64) {}
}

/// Resolved locations of a job.
#[derive(Clone, Debug, PartialEq)]
pub struct Locations {
    /// The workspace root relative paths are resolved against.
    pub workspace: PathBuf,
    /// Where the datasets are.
    pub data_root: PathBuf,
    /// Where the tuple cache is written.
    pub cache_dir: PathBuf,
    /// Where the paper protocol's episode file is written.
    pub episodes: PathBuf,
}

impl Locations {
    /// Resolves the config's paths; `config_path` locates the workspace root (its nearest
    /// ancestor with a `[workspace]` manifest, else the current directory).
    pub fn resolve(cfg: &DataConfig, config_path: &Path) -> Self {
        let workspace = config_path
            .parent()
            .and_then(paths::find_workspace_root)
            .or_else(|| {
                std::env::current_dir()
                    .ok()
                    .and_then(|d| paths::find_workspace_root(&d))
            })
            .unwrap_or_else(|| PathBuf::from("."));
        let data_root = paths::data_root(Some(&cfg.paths.data_root), &workspace);
        Self {
            cache_dir: paths::output_path(&cfg.paths.cache_dir, &workspace),
            episodes: paths::output_path(&cfg.paths.episodes, &workspace),
            data_root,
            workspace,
        }
    }

    /// [`Self::resolve`], refusing a dataset directory that was named and is not there: a
    /// `paths.data_root` or `$HUMAN2NAV_DATA` that does not exist is an error naming it and
    /// the path (a typo must not turn a build on real data into one on synthetic crowds).
    /// Only the default directory may be missing; the synthetic fallback then applies.
    pub fn resolve_checked(cfg: &DataConfig, config_path: &Path) -> Result<Self, DataError> {
        let loc = Self::resolve(cfg, config_path);
        if cfg.sources.synthetic_only || loc.data_root.is_dir() {
            return Ok(loc);
        }
        let (_, from) = paths::data_root_from(Some(&cfg.paths.data_root), &loc.workspace);
        let named = match from {
            paths::DataRootFrom::Config => "paths.data_root".to_string(),
            paths::DataRootFrom::Env => format!("${} (paths.data_root is unset)", paths::DATA_ENV),
            paths::DataRootFrom::Default => return Ok(loc),
        };
        Err(DataError::Config {
            path: config_path.to_path_buf(),
            message: format!(
                "{named}: the dataset directory {} does not exist (leave it unset for the \
                 synthetic fallback, or set [sources] synthetic_only = true)",
                loc.data_root.display()
            ),
        })
    }

    /// Whether the real datasets are read: the directory exists and `[sources]
    /// synthetic_only` is off.
    pub fn datasets(&self, cfg: &DataConfig) -> bool {
        !cfg.sources.synthetic_only && self.data_root.is_dir()
    }

    /// Why the synthetic scenes are used instead of the datasets.
    fn synthetic_reason(&self, cfg: &DataConfig) -> String {
        if cfg.sources.synthetic_only {
            "[sources] synthetic_only = true".to_string()
        } else {
            format!("no datasets at {}", self.data_root.display())
        }
    }
}

/// The scenes of a job: real ones when the dataset directory exists, else (if allowed) the
/// synthetic fallback. Second value: `"real"` or `"synthetic"`; third: notes for the user.
pub fn scenes(
    cfg: &DataConfig,
    loc: &Locations,
    progress: &dyn Progress,
) -> Result<(Vec<Scene>, String, Vec<String>), DataError> {
    if !loc.datasets(cfg) {
        if !cfg.sources.synthetic_fallback && !cfg.sources.synthetic_only {
            return Err(DataError::NoData(format!(
                "{} does not exist (set paths.data_root or ${})",
                loc.data_root.display(),
                paths::DATA_ENV
            )));
        }
        let n = cfg.sources.synthetic_scenes;
        progress.stage("synthetic", n as u64);
        let scenes: Vec<Scene> = (0..n)
            .into_par_iter()
            .map(|i| {
                let s = synthetic::scenes_range(i, 1, cfg.sources.seed);
                progress.inc(1);
                s
            })
            .flatten()
            .collect();
        let note = format!(
            "{}: using {} synthetic social-force scenes",
            loc.synthetic_reason(cfg),
            scenes.len()
        );
        return Ok((scenes, "synthetic".into(), vec![note]));
    }
    let (sources, notes) = discover(&loc.data_root, cfg);
    let sources: Vec<Source> = sources
        .into_iter()
        .filter(|s| cfg.split.of(&s.name).is_some())
        .collect();
    if sources.is_empty() {
        return Err(DataError::NoData(format!(
            "no enabled source found under {}",
            loc.data_root.display()
        )));
    }
    let names: Vec<&str> = sources.iter().map(|s| s.name.as_str()).collect();
    let unknown: Vec<&String> = cfg
        .split
        .test
        .iter()
        .chain(&cfg.split.val)
        .filter(|n| !names.contains(&n.as_str()))
        .collect();
    if !unknown.is_empty() {
        return Err(DataError::option(
            "split",
            format!("unknown scenes {unknown:?} (known: {names:?})"),
        ));
    }
    progress.stage("load", sources.len() as u64);
    let scenes = sources
        .par_iter()
        .map(|src| {
            let raw = load_source(src, cfg)?;
            let scene = resample(&raw, &cfg.resample);
            progress.inc(1);
            Ok(scene)
        })
        .collect::<Result<Vec<Scene>, DataError>>()?;
    Ok((scenes, "real".into(), notes))
}

/// Split of a scene: the config's for real scenes; synthetic scenes go 80/10/10 by index.
fn split_of(cfg: &DataConfig, scene: &Scene, index: usize) -> Option<Split> {
    if scene.dataset == "synthetic" {
        return Some(match index % 10 {
            0 => Split::Test,
            1 => Split::Val,
            _ => Split::Train,
        });
    }
    cfg.split.of(&scene.name)
}

/// What `build_cache` did.
#[derive(Clone, Debug)]
pub struct BuildReport {
    /// The cache written.
    pub cache: TupleCache,
    /// What the user should know (missing datasets, the synthetic fallback, ...).
    pub notes: Vec<String>,
    /// `(dataset, split) → tuples`.
    pub counts: BTreeMap<(String, Split), usize>,
}

/// Loads, resamples and converts every scene, and writes the tuple cache, holding the cache
/// folder's [`DirLock`](human2nav_core::lock::DirLock) throughout (a second build of the same
/// folder is an error naming the folder and the build that holds it).
pub fn build_cache(
    cfg: &DataConfig,
    loc: &Locations,
    progress: &dyn Progress,
) -> Result<BuildReport, DataError> {
    // One build per cache folder: two builds interleaving their split files and manifests
    // left a cache that did not open. The second is refused before it reads anything.
    let _lock = human2nav_core::lock::DirLock::acquire(&loc.cache_dir, "human2nav data build")
        .map_err(|e| DataError::io(&loc.cache_dir, e))?;
    let (scenes, source, notes) = scenes(cfg, loc, progress)?;
    if scenes.len() > u16::MAX as usize {
        return Err(DataError::option("sources", "more than 65535 scenes"));
    }
    progress.stage("tuples", scenes.len() as u64);
    let built: Vec<(Vec<CompactTuple>, TupleStats)> = scenes
        .par_iter()
        .enumerate()
        .map(|(i, s)| {
            let r = scene_tuples(s, i as u16, &cfg.bev, &cfg.tuples);
            progress.inc(1);
            r
        })
        .collect();
    let mut infos = Vec::with_capacity(scenes.len());
    let mut splits: Vec<(Split, Vec<CompactTuple>)> =
        Split::ALL.iter().map(|s| (*s, Vec::new())).collect();
    let mut stats = TupleStats::default();
    let mut counts = BTreeMap::new();
    for (i, (scene, (tuples, st))) in scenes.iter().zip(built).enumerate() {
        let Some(split) = split_of(cfg, scene, i) else {
            continue;
        };
        stats.add(&st);
        let mut skipped: BTreeMap<String, usize> = scene.dropped.iter().cloned().collect();
        for (k, v) in [
            ("empty_tracks", scene.stats.empty_tracks),
            ("short_segments", scene.stats.short_segments),
            ("gap_splits", scene.stats.gap_splits),
            ("speed_splits", scene.stats.speed_splits),
            ("too_short_tracks", st.too_short_tracks),
            ("stationary_windows", st.stationary_windows),
        ] {
            if v > 0 {
                skipped.insert(k.to_string(), v);
            }
        }
        infos.push(SceneInfo {
            name: scene.name.clone(),
            dataset: scene.dataset.clone(),
            format: scene.format.clone(),
            split,
            duration: scene.duration(),
            tracks: scene.tracks.len(),
            tuples: tuples.len(),
            median_speed: median(scene.speeds(0.2)),
            skipped,
        });
        *counts.entry((scene.dataset.clone(), split)).or_default() += tuples.len();
        // Scene indices must point into `infos`, which skips excluded scenes.
        let idx = (infos.len() - 1) as u16;
        let target = &mut splits[split as usize].1;
        target.extend(tuples.into_iter().map(|mut t| {
            t.scene = idx;
            t
        }));
    }
    let manifest = Manifest {
        version: crate::cache::CACHE_VERSION,
        source,
        bev: cfg.bev,
        horizon: cfg.tuples.horizon,
        dt: cfg.resample.dt,
        tuples: cfg.tuples.clone(),
        scenes: infos,
        counts: BTreeMap::new(),
        stats,
        file_bytes: BTreeMap::new(),
    };
    let cache = TupleCache::write(&loc.cache_dir, manifest, &splits)?;
    Ok(BuildReport {
        cache,
        notes,
        counts,
    })
}

/// Association quality per SDD raw video (identities removed, pedestrians only by default).
pub fn evaluate_association(
    cfg: &DataConfig,
    loc: &Locations,
    progress: &dyn Progress,
) -> Result<Vec<(String, AssociationReport)>, DataError> {
    let mut only_raw = cfg.clone();
    only_raw.sources = crate::config::SourcesConfig {
        eth: false,
        ucy: false,
        sdd_raw: true,
        sdd_trajnet: false,
        sgan: false,
        ..cfg.sources.clone()
    };
    let (sources, _) = discover(&loc.data_root, &only_raw);
    if sources.is_empty() {
        return Err(DataError::NoData(format!(
            "no SDD raw annotations under {}",
            loc.data_root.display()
        )));
    }
    progress.stage("associate", sources.len() as u64);
    sources
        .par_iter()
        .map(|src| {
            let SourceKind::SddRaw {
                path,
                scales,
                video,
            } = &src.kind
            else {
                return Err(DataError::NoData(format!(
                    "{} is not an SDD raw video",
                    src.name
                )));
            };
            let scale = sdd::SddScales::load(scales)?.scale(video)?;
            let rows = sdd::parse_raw(path)?;
            let (frames, truth) = sdd_detections(
                &rows,
                scale,
                cfg.association.frame_step,
                cfg.sdd.pedestrians_only,
                cfg.sources.seed,
            );
            let pred = associate(&frames, &cfg.association);
            progress.inc(1);
            Ok((src.name.clone(), evaluate(&truth, &pred)))
        })
        .collect()
}
