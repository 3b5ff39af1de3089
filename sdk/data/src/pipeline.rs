//! End-to-end jobs: dataset discovery, the tuple cache build, episode mining (paper protocol
//! and interaction-rich) and the association evaluation. Scenes are processed in parallel
//! (rayon) and collected in name order, so the output is identical for any number of threads.

use crate::association::{AssociationReport, associate, evaluate, sdd_detections};
use crate::cache::{Manifest, SceneInfo, TupleCache};
use crate::config::DataConfig;
use crate::error::DataError;
pub use crate::interaction::InteractionReport;
use crate::interaction::{
    InteractionStats, mine_interaction_scene, select_interaction_suite, summarize,
};
use crate::loaders::{eth, sdd, sgan, ucy};
use crate::paths;
use crate::resample::{Scene, median, resample};
use crate::scenario::{EpisodeSuite, MiningStats, ScenarioClass, mine_scene, select};
use crate::synthetic;
use crate::track::RawScene;
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

/// How to read one source file.
#[derive(Clone, Debug, PartialEq)]
pub enum SourceKind {
    /// An ETH (EWAP) `obsmat.txt`: world coordinates at 2.5 fps.
    EwapObsmat {
        /// The file.
        path: PathBuf,
    },
    /// A UCY `.vsp` spline file in image coordinates.
    UcyVsp {
        /// The file.
        path: PathBuf,
        /// The UCY folder, where the scene's homography is looked up.
        ucy_root: PathBuf,
        /// The scene (`zara01`, ...).
        scene: String,
    },
    /// A Social-GAN benchmark file (`frame id x y`, world coordinates).
    Sgan {
        /// The file.
        path: PathBuf,
    },
    /// A Stanford Drone Dataset `annotations.txt` (pixel boxes at 30 fps).
    SddRaw {
        /// The file.
        path: PathBuf,
        /// The metres-per-pixel scale file.
        scales: PathBuf,
        /// The video (`scene/videoN`) whose scale applies.
        video: String,
    },
    /// A TrajNet conversion of SDD (world coordinates).
    SddTrajnet {
        /// The file.
        path: PathBuf,
    },
}

/// One scene to load.
#[derive(Clone, Debug, PartialEq)]
pub struct Source {
    /// `dataset/scene`.
    pub name: String,
    /// Its file and how to read it.
    pub kind: SourceKind,
}

/// UCY scenes with a usable homography (arxiepiskopi's unit is unknown).
pub const UCY_SCENES: [&str; 6] = [
    "zara01",
    "zara02",
    "zara03",
    "students01",
    "students03",
    "uni_examples",
];

fn sorted_dir(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .collect();
    v.sort();
    v
}

/// Lists the scenes of the enabled sources under `root`, sorted by name, with notes on
/// sources that were enabled but not found.
pub fn discover(root: &Path, cfg: &DataConfig) -> (Vec<Source>, Vec<String>) {
    let mut out = Vec::new();
    let mut notes = Vec::new();
    let s = &cfg.sources;
    if s.eth {
        for (seq, scene) in [("seq_eth", "eth"), ("seq_hotel", "hotel")] {
            let path = root
                .join("eth_ucy/opentraj_raw/ETH")
                .join(seq)
                .join("obsmat.txt");
            if path.is_file() {
                out.push(Source {
                    name: format!("eth/{scene}"),
                    kind: SourceKind::EwapObsmat { path },
                });
            } else {
                notes.push(format!("eth: {} not found", path.display()));
            }
        }
    }
    if s.ucy {
        let ucy_root = root.join("eth_ucy/opentraj_raw/UCY");
        for scene in UCY_SCENES {
            let path = ucy_root.join(scene).join("annotation.vsp");
            if path.is_file() {
                out.push(Source {
                    name: format!("ucy/{scene}"),
                    kind: SourceKind::UcyVsp {
                        path,
                        ucy_root: ucy_root.clone(),
                        scene: scene.to_string(),
                    },
                });
            } else {
                notes.push(format!("ucy: {} not found", path.display()));
            }
        }
    }
    let mut sdd_videos: Vec<String> = Vec::new();
    if s.sdd_raw {
        let base = root.join("sdd/opentraj_raw");
        let scales = base.join("estimated_scales.yaml");
        for scene_dir in sorted_dir(&base).into_iter().filter(|p| p.is_dir()) {
            for video_dir in sorted_dir(&scene_dir) {
                let path = video_dir.join("annotations.txt");
                if !path.is_file() {
                    continue;
                }
                let scene = scene_dir
                    .file_name()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let n = video_dir
                    .file_name()
                    .map(|s| s.to_string_lossy().trim_start_matches("video").to_string())
                    .unwrap_or_default();
                let video = format!("{scene}_{n}");
                sdd_videos.push(video.clone());
                out.push(Source {
                    name: format!("sdd/{video}"),
                    kind: SourceKind::SddRaw {
                        path,
                        scales: scales.clone(),
                        video,
                    },
                });
            }
        }
        if sdd_videos.is_empty() {
            notes.push(format!("sdd_raw: no annotations under {}", base.display()));
        }
    }
    if s.sdd_trajnet {
        let base = root.join("sdd/trajnet_split_socialvae");
        let mut found = false;
        for split in ["train", "test"] {
            for path in sorted_dir(&base.join(split)) {
                if path.extension().is_none_or(|e| e != "txt") {
                    continue;
                }
                found = true;
                let video = path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                if sdd_videos.contains(&video) {
                    continue; // the raw annotations of this video are used instead
                }
                out.push(Source {
                    name: format!("sdd/{video}"),
                    kind: SourceKind::SddTrajnet { path },
                });
            }
        }
        if !found {
            notes.push(format!("sdd_trajnet: no files under {}", base.display()));
        }
    }
    if s.sgan {
        let base = root.join("eth_ucy/trajectron_sgan_format/raw/all_data");
        for path in sorted_dir(&base) {
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            out.push(Source {
                name: format!("sgan/{stem}"),
                kind: SourceKind::Sgan { path },
            });
        }
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    (out, notes)
}

/// Loads one source as a raw scene.
pub fn load_source(src: &Source, cfg: &DataConfig) -> Result<RawScene, DataError> {
    match &src.kind {
        SourceKind::EwapObsmat { path } => eth::load_obsmat(path, &src.name),
        SourceKind::UcyVsp {
            path,
            ucy_root,
            scene,
        } => {
            let h = ucy::load_homography(ucy_root, scene)?;
            ucy::load_vsp(path, &h, ucy::VspConvention::of(scene), &src.name)
        }
        SourceKind::Sgan { path } => sgan::load(path, &src.name, "sgan"),
        SourceKind::SddRaw {
            path,
            scales,
            video,
        } => {
            let scale = sdd::SddScales::load(scales)?.scale(video)?;
            sdd::load_raw(path, scale, &src.name, &cfg.sdd)
        }
        SourceKind::SddTrajnet { path } => sdd::load_trajnet(path, &src.name),
    }
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

/// Mines interaction-rich episodes ([`crate::interaction`]) from the scenes of `split`
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
            crate::interaction::withhold(&mut eps, &excluded, &mut stats);
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
