//! `human2nav data ...`: build the tuple cache, inspect it, mine benchmark episodes and
//! evaluate detection-to-track association.

use anyhow::Context;
use clap::Subcommand;
use human2nav_data::cache::Manifest;
use human2nav_data::config::DataConfig;
use human2nav_data::pipeline::{self, Locations, Progress};
use human2nav_data::prediction::{self, PredictionOptions};
use human2nav_data::resample::median;
use human2nav_data::{EpisodeSuite, ScenarioClass, Split, TupleCache};
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Mutex;
use std::time::Instant;

#[derive(Debug, Subcommand)]
pub enum DataCommand {
    /// Build the training-tuple cache from the datasets (synthetic crowds if there are none).
    Build {
        /// Data config (e.g. sdk/configs/data.toml).
        #[arg(long)]
        config: PathBuf,
    },
    /// Counts per scene, split and scenario class, and speed statistics of a tuple cache.
    Stats {
        /// Cache directory (holding manifest.json).
        cache: PathBuf,
    },
    /// Mine the benchmark episodes: the paper protocol's from the test scenes
    /// (`paths.episodes`), and the interaction-rich ones from the test and the validation
    /// scenes (`paths.interaction_episodes`, `paths.interaction_val_episodes`, each with its
    /// mining report beside it as `<file>.md`).
    Episodes {
        /// Data config (e.g. sdk/configs/data.toml).
        #[arg(long)]
        config: PathBuf,
        /// Write the paper-protocol suite here instead of the config's `paths.episodes`
        /// (the interaction suites still go to their configured paths).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Associate identity-free SDD detections with the Hungarian tracker and score it
    /// against the annotated identities.
    Associate {
        /// Data config (e.g. sdk/configs/data.toml).
        #[arg(long)]
        config: PathBuf,
    },
    /// Score simple pedestrian predictors on the recorded crowds of an episode file: the
    /// last step's velocity held (what the benchmark's planners see), mean velocities, standing
    /// still, and a ridge model on the history fitted leave-one-scene-out (ADE / FDE over the
    /// horizon, ADE over the first second; overall and per scene, as Markdown).
    Predict {
        /// Episode file (e.g. out/data/episodes-interaction-val.json).
        #[arg(long)]
        episodes: PathBuf,
        /// Steps of history a prediction sees (1 to 1000).
        #[arg(long, default_value_t = 8)]
        history: usize,
        /// Steps predicted (1 to 1000; 32 = the planner's 3.2 s).
        #[arg(long, default_value_t = 32)]
        horizon: usize,
        /// Steps between two windows of a track (1 to 100000).
        #[arg(long, default_value_t = 5)]
        stride: usize,
        /// Ridge regularisation of the learned model (>= 0).
        #[arg(long, default_value_t = 1.0)]
        lambda: f64,
        /// Also fit the ridge model on the training scenes of this data config (e.g.
        /// sdk/configs/data.toml) and score it on the file's crowds; the file's scenes must
        /// not be among them.
        #[arg(long, value_name = "DATA_TOML")]
        fit_on: Option<PathBuf>,
        /// Write the model fitted with --fit-on here (TOML): a predictor of people for
        /// `human2nav bench` (a `human2nav` method's `history_ridge`).
        #[arg(long, value_name = "FILE", requires = "fit_on")]
        export: Option<PathBuf>,
    },
}

/// indicatif progress, one bar per stage.
struct Bars {
    bar: Mutex<Option<ProgressBar>>,
}

impl Bars {
    fn new() -> Self {
        Self {
            bar: Mutex::new(None),
        }
    }

    fn finish(&self) {
        if let Ok(mut b) = self.bar.lock()
            && let Some(b) = b.take()
        {
            b.finish();
        }
    }
}

impl Progress for Bars {
    fn stage(&self, name: &str, total: u64) {
        if let Ok(mut slot) = self.bar.lock() {
            if let Some(b) = slot.take() {
                b.finish();
            }
            let bar = ProgressBar::new(total);
            if let Ok(style) =
                ProgressStyle::with_template("{prefix:>10} [{bar:40}] {pos}/{len} {elapsed}")
            {
                bar.set_style(style.progress_chars("=> "));
            }
            bar.set_prefix(name.to_string());
            *slot = Some(bar);
        }
    }

    fn inc(&self, n: u64) {
        if let Ok(slot) = self.bar.lock()
            && let Some(b) = slot.as_ref()
        {
            b.inc(n);
        }
    }
}

fn load_config(path: &Path) -> anyhow::Result<(DataConfig, Locations)> {
    let cfg = DataConfig::load(path).with_context(|| format!("loading {}", path.display()))?;
    // A dataset folder that was named and is missing is an error; only the default one may
    // be missing, and then the synthetic fallback says so here.
    let loc = Locations::resolve_checked(&cfg, path)?;
    if !loc.datasets(&cfg) && cfg.sources.synthetic_fallback && !cfg.sources.synthetic_only {
        eprintln!(
            "warning: no datasets at {} (paths.data_root in {}, else ${}, else ../shared/data \
             beside the workspace); falling back to synthetic crowds",
            loc.data_root.display(),
            path.display(),
            human2nav_data::paths::DATA_ENV
        );
    }
    Ok((cfg, loc))
}

pub fn run(cmd: DataCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        DataCommand::Build { config } => build(&config),
        DataCommand::Stats { cache } => stats(&cache),
        DataCommand::Episodes { config, out } => episodes(&config, out),
        DataCommand::Associate { config } => associate(&config),
        DataCommand::Predict {
            episodes,
            history,
            horizon,
            stride,
            lambda,
            fit_on,
            export,
        } => predict(
            &episodes,
            PredictionOptions {
                history,
                horizon,
                stride,
                ridge_lambda: lambda,
            },
            fit_on.as_deref(),
            export.as_deref(),
        ),
    }
}

fn predict(
    path: &Path,
    options: PredictionOptions,
    fit_on: Option<&Path>,
    export: Option<&Path>,
) -> anyhow::Result<ExitCode> {
    let suite = EpisodeSuite::load(path).with_context(|| format!("loading {}", path.display()))?;
    let training = match fit_on {
        None => Vec::new(),
        Some(config) => {
            let (cfg, loc) = load_config(config)?;
            let (scenes, _, notes) = pipeline::scenes(&cfg, &loc, &Bars::new())?;
            for note in notes {
                eprintln!("note: {note}");
            }
            let training: Vec<_> = scenes
                .into_iter()
                .filter(|s| cfg.split.of(&s.name) == Some(Split::Train))
                .collect();
            if let Some(e) = suite
                .episodes
                .iter()
                .find(|e| training.iter().any(|s| s.name == e.scene))
            {
                anyhow::bail!(
                    "{}: scene `{}` of episode {} is in the training split of {}; the model \
                     fitted on that split would be scored on its own data",
                    path.display(),
                    e.scene,
                    e.id,
                    config.display()
                );
            }
            eprintln!(
                "fitting the ridge model on {} training scenes of {}",
                training.len(),
                config.display()
            );
            training
        }
    };
    let report = prediction::study_with_training(&suite, options, &training)
        .with_context(|| format!("predicting the crowds of {}", path.display()))?;
    println!("{}: {}\n", path.display(), suite.source);
    print!("{}", report.markdown());
    if let (Some(out), Some(model)) = (export, &report.trained) {
        let text = toml::to_string(model).context("writing the model as TOML")?;
        std::fs::write(out, text).with_context(|| format!("writing {}", out.display()))?;
        println!(
            "\nthe model fitted on the training scenes: {}",
            out.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn build(config: &Path) -> anyhow::Result<ExitCode> {
    let (cfg, loc) = load_config(config)?;
    println!("datasets: {}", loc.data_root.display());
    let t0 = Instant::now();
    let bars = Bars::new();
    let report = pipeline::build_cache(&cfg, &loc, &bars)?;
    bars.finish();
    let secs = t0.elapsed().as_secs_f64();
    for n in &report.notes {
        println!("note: {n}");
    }
    let m = report.cache.manifest();
    println!("\ntuples per dataset and split:");
    println!(
        "{:<12} {:>9} {:>9} {:>9}",
        "dataset", "train", "val", "test"
    );
    let datasets: Vec<&String> = {
        let mut d: Vec<&String> = report.counts.keys().map(|k| &k.0).collect();
        d.dedup();
        d
    };
    for d in datasets {
        let c = |s: Split| report.counts.get(&(d.clone(), s)).copied().unwrap_or(0);
        println!(
            "{:<12} {:>9} {:>9} {:>9}",
            d,
            c(Split::Train),
            c(Split::Val),
            c(Split::Test)
        );
    }
    let c = |s: Split| m.counts.get(&s).copied().unwrap_or(0);
    println!(
        "{:<12} {:>9} {:>9} {:>9}",
        "total",
        c(Split::Train),
        c(Split::Val),
        c(Split::Test)
    );
    let st = &m.stats;
    println!(
        "\nskipped: {} tracks too short for a {}-step future, {} stationary windows{}",
        st.too_short_tracks,
        m.horizon,
        st.stationary_windows,
        if st.non_pedestrian_tracks > 0 {
            format!(", {} non-pedestrian egos", st.non_pedestrian_tracks)
        } else {
            String::new()
        }
    );
    let mut skipped: BTreeMap<&str, usize> = BTreeMap::new();
    for s in &m.scenes {
        for (k, v) in &s.skipped {
            *skipped.entry(k.as_str()).or_default() += v;
        }
    }
    println!("skipped per reason (all scenes): {skipped:?}");
    println!(
        "\ncache {} ({} scenes, {:.1} MB) written in {secs:.1} s",
        report.cache.dir().display(),
        m.scenes.len(),
        report.cache.size_bytes() as f64 / 1e6
    );
    Ok(ExitCode::SUCCESS)
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// `human2nav data stats`: the cache's header, then its tuples per split, per scenario class
/// and per scene.
fn stats(dir: &Path) -> anyhow::Result<ExitCode> {
    let cache =
        TupleCache::open(dir).with_context(|| format!("opening cache {}", dir.display()))?;
    let m = cache.manifest();
    println!(
        "cache {} (version {}, source {}): BEV {}x{} at {} m, horizon {} x {} s, {:.1} MB",
        dir.display(),
        m.version,
        m.source,
        m.bev.cells,
        m.bev.cells,
        m.bev.resolution,
        m.horizon,
        m.dt,
        cache.size_bytes() as f64 / 1e6
    );
    let (class_rows, per_scene_class) = print_splits(&cache)?;
    print_classes(&class_rows);
    print_scenes(m, &per_scene_class);
    Ok(ExitCode::SUCCESS)
}

/// Tuples per scenario class of each split (co, cross, counter, multidirection, none).
type ClassRows = Vec<(Split, [usize; 5])>;

/// Prints the per-split table (tuples, scenes, hours, speeds, goal distance, neighbours);
/// returns the class counts per split and per scene.
fn print_splits(cache: &TupleCache) -> anyhow::Result<(ClassRows, BTreeMap<u16, [usize; 5]>)> {
    let m = cache.manifest();
    let mut per_scene_class: BTreeMap<u16, [usize; 5]> = BTreeMap::new();
    println!("\nper split:");
    println!(
        "{:<6} {:>8} {:>7} {:>8} | speed now m/s p10/p50/p90 | future mean speed p50 | goal dist p50 | neighbours mean",
        "split", "tuples", "scenes", "hours"
    );
    let mut class_rows = Vec::new();
    for split in Split::ALL {
        let tuples = cache.load_compact(split)?;
        let mut speed: Vec<f64> = tuples.iter().map(|t| t.speed() as f64).collect();
        let fut: Vec<f64> = tuples
            .iter()
            .filter_map(|t| {
                t.future
                    .last()
                    .map(|p| (p[0].hypot(p[1]) as f64) / (m.horizon as f64 * m.dt))
            })
            .collect();
        let goal: Vec<f64> = tuples
            .iter()
            .map(|t| t.goal[0].hypot(t.goal[1]) as f64)
            .collect();
        let neigh = if tuples.is_empty() {
            0.0
        } else {
            tuples.iter().map(|t| t.agents.len()).sum::<usize>() as f64 / tuples.len() as f64
        };
        let scenes = m.scenes_in(split);
        let hours: f64 = scenes
            .iter()
            .map(|&i| m.scenes[i as usize].duration)
            .sum::<f64>()
            / 3600.0;
        println!(
            "{:<6} {:>8} {:>7} {:>8.2} | {:>5.2} / {:>5.2} / {:>5.2}          | {:>5.2}                 | {:>5.2} m       | {:>5.2}",
            split.name(),
            tuples.len(),
            scenes.len(),
            hours,
            quantile(&mut speed, 0.1),
            quantile(&mut speed, 0.5),
            quantile(&mut speed, 0.9),
            median(fut).unwrap_or(f64::NAN),
            median(goal).unwrap_or(f64::NAN),
            neigh
        );
        let cc = TupleCache::class_counts(&tuples);
        let mut tot = [0usize; 5];
        for (s, c) in cc {
            for k in 0..5 {
                tot[k] += c[k];
            }
            per_scene_class.insert(s, c);
        }
        class_rows.push((split, tot));
    }
    Ok((class_rows, per_scene_class))
}

/// Prints the tuples per scenario class of each split.
fn print_classes(class_rows: &ClassRows) {
    println!("\nper scenario class (from the agents in each tuple's raster):");
    println!(
        "{:<6} {:>9} {:>11} {:>13} {:>20} {:>9}",
        "split", "co_flow", "cross_flow", "counter_flow", "multidirection_flow", "none"
    );
    for (split, t) in class_rows {
        println!(
            "{:<6} {:>9} {:>11} {:>13} {:>20} {:>9}",
            split.name(),
            t[0],
            t[1],
            t[2],
            t[3],
            t[4]
        );
    }
}

/// Prints one line per scene: its split, format, duration, tracks, tuples, median speed and
/// tuples per scenario class.
fn print_scenes(m: &Manifest, per_scene_class: &BTreeMap<u16, [usize; 5]>) {
    println!("\nper scene:");
    println!(
        "{:<22} {:<6} {:<12} {:>8} {:>7} {:>8} {:>7} | {:>6} {:>6} {:>7} {:>6} {:>6}",
        "scene",
        "split",
        "format",
        "dur s",
        "tracks",
        "tuples",
        "v50",
        "co",
        "cross",
        "counter",
        "multi",
        "none"
    );
    for (i, s) in m.scenes.iter().enumerate() {
        let c = per_scene_class
            .get(&(i as u16))
            .copied()
            .unwrap_or_default();
        println!(
            "{:<22} {:<6} {:<12} {:>8.0} {:>7} {:>8} {:>7.2} | {:>6} {:>6} {:>7} {:>6} {:>6}",
            s.name,
            s.split.name(),
            s.format,
            s.duration,
            s.tracks,
            s.tuples,
            s.median_speed.unwrap_or(f64::NAN),
            c[0],
            c[1],
            c[2],
            c[3],
            c[4]
        );
    }
}

fn episodes(config: &Path, out: Option<PathBuf>) -> anyhow::Result<ExitCode> {
    let (cfg, loc) = load_config(config)?;
    let t0 = Instant::now();
    let bars = Bars::new();
    let report = pipeline::build_episodes(&cfg, &loc, &bars)?;
    bars.finish();
    for n in &report.notes {
        println!("note: {n}");
    }
    let path = out.unwrap_or(loc.episodes.clone());
    report.suite.save(&path)?;
    if !report.scenes.is_empty() {
        println!("test scenes: {}", report.scenes.join(", "));
        let s = &report.stats;
        println!(
            "windows {}: goal not reached {}, outside recording {}, start blocked {}, density out of range {}, unclassified {}",
            s.windows,
            s.goal_not_reached,
            s.outside_recording,
            s.start_blocked,
            s.density_out_of_range,
            s.unclassified
        );
    }
    println!(
        "\n{:<20} {:>10} {:>9} {:>9}  densities (min / median / max)",
        "class", "candidates", "selected", "wanted"
    );
    for c in ScenarioClass::ALL {
        let sel: Vec<f64> = report
            .suite
            .episodes
            .iter()
            .filter(|e| e.scenario == c)
            .map(|e| e.density as f64)
            .collect();
        let n = sel.len();
        let (lo, hi) = sel
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &d| {
                (a.min(d), b.max(d))
            });
        println!(
            "{:<20} {:>10} {:>9} {:>9}  {} / {} / {}",
            c.name(),
            report
                .stats
                .candidates
                .get(&c)
                .map(|n| n.to_string())
                .unwrap_or_else(|| "-".into()),
            n,
            cfg.episodes.per_class,
            if n > 0 { lo.to_string() } else { "-".into() },
            median(sel)
                .map(|m| m.to_string())
                .unwrap_or_else(|| "-".into()),
            if n > 0 { hi.to_string() } else { "-".into() },
        );
    }
    println!(
        "\n{} episodes written to {} in {:.1} s",
        report.suite.episodes.len(),
        path.display(),
        t0.elapsed().as_secs_f64()
    );
    for file in [Split::Test, Split::Val].map(pipeline::EpisodeFile::Interaction) {
        let t0 = Instant::now();
        let written = pipeline::write_episode_file(file, &cfg, &loc, None, &bars)?;
        bars.finish();
        if let Some((_, md)) = &written.report {
            println!("\n{md}");
        }
        for n in &written.notes {
            println!("note: {n}");
        }
        println!(
            "{} episodes written to {} in {:.1} s{}",
            written.episodes,
            written.path.display(),
            t0.elapsed().as_secs_f64(),
            written
                .report
                .as_ref()
                .map(|(p, _)| format!(" (report: {})", p.display()))
                .unwrap_or_default()
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn associate(config: &Path) -> anyhow::Result<ExitCode> {
    let (cfg, loc) = load_config(config)?;
    let bars = Bars::new();
    let per_video = pipeline::evaluate_association(&cfg, &loc, &bars)?;
    bars.finish();
    let a = &cfg.association;
    println!(
        "Hungarian tracker on SDD raw detections without identities ({}), every {} frame(s) ({:.1} Hz), gate {} m, max missed {} s",
        if cfg.sdd.pedestrians_only {
            "pedestrians"
        } else {
            "all classes"
        },
        a.frame_step,
        30.0 / a.frame_step as f64,
        a.gate,
        a.max_missed
    );
    println!(
        "{:<22} {:>7} {:>10} {:>10} {:>7} {:>11} {:>9}",
        "video", "frames", "detections", "identities", "tracks", "id switches", "correct"
    );
    let mut total = human2nav_data::association::AssociationReport::default();
    for (name, r) in &per_video {
        println!(
            "{:<22} {:>7} {:>10} {:>10} {:>7} {:>11} {:>8.1}%",
            name,
            r.frames,
            r.detections,
            r.identities,
            r.tracks,
            r.id_switches,
            100.0 * r.correct_fraction
        );
        total.add(r);
    }
    println!(
        "{:<22} {:>7} {:>10} {:>10} {:>7} {:>11} {:>8.1}%",
        "total",
        total.frames,
        total.detections,
        total.identities,
        total.tracks,
        total.id_switches,
        100.0 * total.correct_fraction
    );
    Ok(ExitCode::SUCCESS)
}
