//! Suites built from the configuration: real episodes (mined when missing, or a synthetic
//! fallback), synthetic ones and the empty world.

use super::{BenchConfig, MAX_PER_CLASS, SuiteConfig};
use crate::bench::{Suite, SuiteKind};
use crate::crowd::CrowdModel;
use crate::episode::{Episode, ScenarioClass};
use crate::error::SimError;
use std::path::{Path, PathBuf};

/// The first `n` episodes of each class, in the classes' order and then file order.
pub fn take_per_class(episodes: &[Episode], n: usize) -> Vec<Episode> {
    let mut out = Vec::new();
    for c in ScenarioClass::ALL {
        out.extend(episodes.iter().filter(|e| e.scenario == c).take(n).cloned());
    }
    out
}

/// `n` synthetic episodes per class from the data crate's generator.
pub fn synthetic_episodes(n: usize, seed: u64) -> Result<Vec<Episode>, SimError> {
    let mut out = Vec::new();
    for c in ScenarioClass::ALL {
        out.extend(human2nav_data::synthetic::episodes(c, n, seed));
    }
    Ok(out)
}

/// Builds every configured suite. A `real` suite whose episode file is missing is an error
/// naming the file, unless `synthetic_fallback` gives the reason it may fall back to synthetic
/// episodes (the datasets are absent, say); the suite's note then starts with "Warning:".
pub fn build_suites(
    cfg: &BenchConfig,
    quick: bool,
    synthetic_fallback: Option<&str>,
) -> Result<Vec<Suite>, SimError> {
    let mut suites: Vec<Suite> = Vec::new();
    for (i, s) in cfg.suites.iter().enumerate() {
        let (field, n) = if quick {
            ("quick_per_class", s.quick_per_class)
        } else {
            ("per_class", s.per_class)
        };
        // Checked here too: callers may set the count after validation (a scaling run does).
        if n == 0 || n > MAX_PER_CLASS {
            return Err(SimError::setting(
                format!("suites[{i}]"),
                field,
                format!("episode counts must be in 1..={MAX_PER_CLASS}, got {n}"),
            ));
        }
        let seed = s.seed.unwrap_or(cfg.seed);
        let (kind, episodes, note) = match s.kind {
            SuiteKind::Real => real_suite(cfg, i, s, n, seed, synthetic_fallback)?,
            SuiteKind::Synthetic => (
                SuiteKind::Synthetic,
                synthetic_episodes(n, seed)?,
                format!(
                    "{n} episodes per class from the synthetic social-force generator, seed {seed}"
                ),
            ),
            SuiteKind::Corridor => (
                SuiteKind::Corridor,
                ScenarioClass::ALL
                    .iter()
                    .flat_map(|c| human2nav_data::corridor::episodes(*c, n, seed))
                    .collect(),
                format!(
                    "{n} corridor episodes per class (walls with doors, pillars; generated \
                     pedestrians on straight lanes), seed {seed}"
                ),
            ),
            SuiteKind::Empty => empty_suite(&suites, n, seed)?,
        };
        if episodes.is_empty() {
            return Err(SimError::Episodes {
                suite: s.name.clone(),
                message: "no episode selected".into(),
            });
        }
        let crowd = s.crowd_model();
        let note = match &crowd {
            CrowdModel::Replay => note,
            CrowdModel::Reactive(_) => format!(
                "{note}. Reactive crowd: recorded paths with a social-force response to the robot"
            ),
        };
        suites.push(Suite {
            note: Some(note),
            crowd,
            methods: s.methods.clone(),
            ..Suite::new(s.name.clone(), kind, episodes)
        });
    }
    Ok(suites)
}

/// The episodes of the `real` suite `suites[i]` (`s`), at most `n` per class, and its note;
/// synthetic ones (kind `synthetic`, a warning note) when its file is missing and
/// `synthetic_fallback` gives the reason.
fn real_suite(
    cfg: &BenchConfig,
    i: usize,
    s: &SuiteConfig,
    n: usize,
    seed: u64,
    synthetic_fallback: Option<&str>,
) -> Result<(SuiteKind, Vec<Episode>, String), SimError> {
    let file = cfg.resolve(s.episodes.as_deref().unwrap_or(Path::new("")));
    // Anything at the path is read (a directory or a FIFO is an error naming it);
    // only a missing file may fall back.
    if file.exists() {
        let loaded = crate::episode::load_episode_file(&file).map_err(|e| SimError::Episodes {
            suite: s.name.clone(),
            message: e.to_string(),
        })?;
        let episodes = take_per_class(&loaded.episodes, n);
        let short: Vec<String> = ScenarioClass::ALL
            .iter()
            .filter_map(|c| {
                let k = episodes.iter().filter(|e| e.scenario == *c).count();
                (k < n).then(|| format!("{} has {k}", c.name()))
            })
            .collect();
        let note = format!(
            "Held-out real episodes from `{}` ({}){}",
            file.display(),
            loaded.source,
            if short.is_empty() {
                String::new()
            } else {
                format!("; fewer than {n} per class: {}", short.join(", "))
            }
        );
        Ok((SuiteKind::Real, episodes, note))
    } else if let Some(reason) = synthetic_fallback {
        let note = format!(
            "Warning: the real episode file `{}` is absent ({reason}); this suite fell back \
                 to {n} synthetic episodes per class",
            file.display()
        );
        Ok((SuiteKind::Synthetic, synthetic_episodes(n, seed)?, note))
    } else {
        Err(SimError::setting(
            format!("suites[{i}]"),
            "episodes",
            format!(
                "suite `{}`: the episode file `{}` does not exist (`human2nav data \
                     episodes` writes the episode files its data config names)",
                s.name,
                file.display()
            ),
        ))
    }
}

/// The episodes of an `empty` suite: start, goal and budget of `n` episodes per class of the
/// first suite built with pedestrians (else of the synthetic generator), every pedestrian
/// removed; and its note.
fn empty_suite(
    suites: &[Suite],
    n: usize,
    seed: u64,
) -> Result<(SuiteKind, Vec<Episode>, String), SimError> {
    let source = suites.iter().find(|x| x.kind != SuiteKind::Empty);
    let (base, from) = match source {
        Some(src) => (
            take_per_class(&src.episodes, n),
            format!("suite `{}`", src.name),
        ),
        None => (
            synthetic_episodes(n, seed)?,
            "the synthetic generator".to_string(),
        ),
    };
    let episodes = base
        .into_iter()
        .map(|mut e| {
            e.agents.clear();
            e.density = 0;
            e.id = format!("{}-empty", e.id);
            e
        })
        .collect();
    let note = format!(
        "Start, goal and budget of {n} episodes per class of {from}, every pedestrian removed"
    );
    Ok((SuiteKind::Empty, episodes, note))
}

/// Makes sure the episode file of every `real` suite exists: one that is missing is mined and
/// written (with `human2nav data episodes`'s rules, per the data config `data_config`) when
/// the datasets are present; `log` hears what is mined. Returns why missing files may fall back
/// to synthetic episodes when the datasets are absent (for [`build_suites`]), else `None`. A
/// missing file the data config does not name is an error naming the suite's `episodes` key.
pub fn ensure_episode_files(
    cfg: &BenchConfig,
    data_config: &Path,
    log: &dyn Fn(String),
) -> Result<Option<String>, SimError> {
    use human2nav_data::config::DataConfig;
    use human2nav_data::pipeline::{self, EpisodeFile, Locations, NoProgress};
    let data_err = |message: String| SimError::Parse {
        path: data_config.to_path_buf(),
        message,
    };
    let dcfg = DataConfig::load(data_config).map_err(|e| data_err(e.to_string()))?;
    let loc = Locations::resolve(&dcfg, data_config);
    if dcfg.sources.synthetic_only {
        return Ok(Some(format!(
            "[sources] synthetic_only = true in {}",
            data_config.display()
        )));
    }
    if !loc.data_root.is_dir() {
        return Ok(Some(format!(
            "no datasets at {} (set ${} or paths.data_root in {})",
            loc.data_root.display(),
            human2nav_data::paths::DATA_ENV,
            data_config.display()
        )));
    }
    let mut files = Vec::new();
    for f in EpisodeFile::ALL {
        files.push((f, f.path(&dcfg, &loc).map_err(|e| data_err(e.to_string()))?));
    }
    let mut written: Vec<PathBuf> = Vec::new();
    for (i, s) in cfg.suites.iter().enumerate() {
        let Some(file) = s.episodes.as_deref().map(|p| cfg.resolve(p)) else {
            continue;
        };
        if s.kind != SuiteKind::Real || file.exists() || written.contains(&file) {
            continue;
        }
        let Some((kind, _)) = files.iter().find(|(_, p)| *p == file) else {
            let known: Vec<String> = files
                .iter()
                .map(|(f, p)| format!("{} = {}", f.key(), p.display()))
                .collect();
            return Err(SimError::setting(
                format!("suites[{i}]"),
                "episodes",
                format!(
                    "suite `{}`: `{}` does not exist, and the data config {} writes only {}",
                    s.name,
                    file.display(),
                    data_config.display(),
                    known.join(", ")
                ),
            ));
        };
        log(format!(
            "suite `{}`: mining its episodes ({}) from {} into {}",
            s.name,
            kind.key(),
            loc.data_root.display(),
            file.display()
        ));
        let out =
            pipeline::write_episode_file(*kind, &dcfg, &loc, None, &NoProgress).map_err(|e| {
                SimError::Episodes {
                    suite: s.name.clone(),
                    message: e.to_string(),
                }
            })?;
        for n in &out.notes {
            log(format!("  note: {n}"));
        }
        written.push(file);
    }
    Ok(None)
}
