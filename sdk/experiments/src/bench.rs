//! The closed-loop benchmark (suites × robots × methods) behind `human2nav bench`: a
//! [`BenchRequest`] (the command's options) is turned into a [`Bench`] (configuration loaded,
//! robots, methods and suites built, output folder locked), which runs and writes
//! `results.csv`, `report.md` and the figures.
//!
//! Method kinds: `straight` and `plugin` (ORCA ships as a plugin) are built by
//! [`human2nav_sim::config::builtin_method`]; `human2nav` (the reference planner with the
//! shipped flow model, see [`human2nav_method`]) is built here because it needs libtorch.
//!
//! Episodes: a `real` suite reads its episode file; when the file is missing but the datasets
//! are present (per [`BenchRequest::data_config`]), its episodes are mined first exactly as
//! `human2nav data episodes` does and written there. Without the datasets the suite falls back
//! to synthetic episodes, with a warning in the suite's note and in the report.

use anyhow::{Context, anyhow, bail};
use human2nav_core::ablation::Arm;
use human2nav_core::forecast::HistoryRidge;
use human2nav_core::human2nav::Human2NavSettings;
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use human2nav_core::lock::DirLock;
use human2nav_flow::planner::{
    PlannerConfig, PlannerModel, PredictionModel, RobotPlanner, load_model,
};
use human2nav_plugin::{PluginFailure, PluginHost};
use human2nav_sim::config::MethodConfig;
use human2nav_sim::config::{
    BenchConfig, build_suites, builtin_method, ensure_episode_files, load_robots_with,
};
use human2nav_sim::driver::{self, BenchOutcome, BenchPlan};
use human2nav_sim::foresight::ForesightSettings;
use human2nav_sim::shard::ShardSpec;
use human2nav_sim::{MethodSpec, RobotSetup, Suite};
use indicatif::ProgressBar;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod shard;
pub use shard::ShardOutcome;

/// The options of one benchmark run (those of `human2nav bench`).
#[derive(Clone, Debug, Default)]
pub struct BenchRequest {
    /// Benchmark configuration (TOML); relative paths inside it resolve against the workspace
    /// root.
    pub config: PathBuf,
    /// Output directory for results.csv, report.md and the figures; `None` is `out/bench`, or
    /// `out/bench-quick` when `quick`, under the configuration's workspace root.
    pub out: Option<PathBuf>,
    /// Run a few episodes per scenario class (each suite's `quick_per_class`).
    pub quick: bool,
    /// Overrides the configuration's seed.
    pub seed: Option<u64>,
    /// Worker threads for the episodes; `None` is one per core.
    pub threads: Option<usize>,
    /// Data configuration used to mine the held-out episodes when a real suite's file is
    /// missing and the datasets are present; a relative path that does not exist from the
    /// current directory is taken under the workspace root.
    pub data_config: PathBuf,
    /// Failed runs to draw per method; `None` is 4, or 1 when `quick`.
    pub failures: Option<usize>,
    /// Run only these methods of the configuration (all when empty).
    pub methods: Vec<String>,
    /// Run only these robots of the configuration (all when empty).
    pub robots: Vec<String>,
    /// Run only these suites of the configuration (all when empty).
    pub suites: Vec<String>,
    /// Also write every run as an MCAP file for Foxglove under `<out>/record/`
    /// (`<suite>/<robot>/<method>/<episode>.mcap`, [`human2nav_sim::record`]).
    pub record: bool,
    /// Run only this slice of the runs and keep it for `--merge` ([`human2nav_sim::shard`]);
    /// `None`: every run, with the report and figures.
    pub shard: Option<ShardSpec>,
}

impl BenchRequest {
    /// The command line written into the report: the options that shape its numbers
    /// (`out` and `threads` do not; nor does `shard`: merged shards write the report of the
    /// whole run).
    pub fn command(&self) -> String {
        let list = |flag: &str, names: &[String]| {
            if names.is_empty() {
                String::new()
            } else {
                format!(" --{flag} {}", names.join(","))
            }
        };
        format!(
            "human2nav bench --config {}{}{}{}{}{}{}",
            self.config.display(),
            if self.quick { " --quick" } else { "" },
            self.seed
                .map(|s| format!(" --seed {s}"))
                .unwrap_or_default(),
            list("methods", &self.methods),
            list("robots", &self.robots),
            list("suites", &self.suites),
            self.failures
                .map(|n| format!(" --failures {n}"))
                .unwrap_or_default()
        )
    }
}

/// A benchmark ready to run: configuration loaded, robots, methods and suites built (episodes
/// mined when needed), output folder locked for as long as this value lives.
#[derive(Debug)]
pub struct Bench {
    request: BenchRequest,
    cfg: BenchConfig,
    out: PathBuf,
    host: Arc<PluginHost>,
    robots: Vec<RobotSetup>,
    methods: Vec<MethodSpec>,
    suites: Vec<Suite>,
    _lock: DirLock,
}

impl Bench {
    /// Loads `request.config`, locks the output folder and builds the selected robots,
    /// methods and suites. `log` receives what episode mining reports. Errors name the
    /// configuration, the option or the field at fault; an unknown name in a selection lists
    /// the known ones.
    pub fn prepare(request: &BenchRequest, log: &dyn Fn(String)) -> anyhow::Result<Bench> {
        let mut cfg = BenchConfig::load(&request.config)
            .with_context(|| format!("loading {}", request.config.display()))?;
        if let Some(seed) = request.seed {
            cfg.seed = seed;
        }
        let out = match (&request.out, request.shard) {
            (Some(p), _) => p.clone(),
            (None, shard) => {
                let dir = cfg.base_dir.join(if request.quick {
                    "out/bench-quick"
                } else {
                    "out/bench"
                });
                match shard {
                    Some(s) => dir.join(format!("shard-{}-of-{}", s.index, s.count)),
                    None => dir,
                }
            }
        };
        let lock = DirLock::acquire(&out, "human2nav bench")
            .with_context(|| format!("locking the output folder {}", out.display()))?;
        let host = Arc::new(PluginHost::new());
        let robots = select(
            load_robots_with(&cfg, &host)?,
            &request.robots,
            "robot",
            |r| &r.name,
        )?;
        let methods = build_methods(&cfg, &host, &request.methods)?;
        // Check the names before mining anything.
        select(cfg.suites.clone(), &request.suites, "suite", |s| &s.name)?;
        let data_config = if request.data_config.is_relative() && !request.data_config.exists() {
            cfg.base_dir.join(&request.data_config)
        } else {
            request.data_config.clone()
        };
        let fallback = ensure_real_episodes(&cfg, &data_config, log)?;
        let suites = select(
            build_suites(&cfg, request.quick, fallback.as_deref())?,
            &request.suites,
            "suite",
            |s| &s.name,
        )?;
        Ok(Bench {
            request: request.clone(),
            cfg,
            out,
            host,
            robots,
            methods,
            suites,
            _lock: lock,
        })
    }

    /// The suites that will run, with their episodes and notes.
    pub fn suites(&self) -> &[Suite] {
        &self.suites
    }

    /// The output folder.
    pub fn out(&self) -> &Path {
        &self.out
    }

    /// Runs every episode (advancing `progress`, whose length it sets) and writes the results,
    /// the report and the figures into the output folder.
    pub fn run(&self, progress: &ProgressBar) -> anyhow::Result<BenchOutcome> {
        Ok(driver::run(&self.plan(), &self.out, progress)?)
    }

    /// What the simulator's driver runs.
    fn plan(&self) -> BenchPlan<'_> {
        BenchPlan {
            suites: &self.suites,
            robots: &self.robots,
            methods: &self.methods,
            sim: &self.cfg.sim,
            seed: self.cfg.seed,
            quick: self.request.quick,
            snapshot_method: self.cfg.snapshot_method(),
            command: self.request.command(),
            threads: self.request.threads,
            failures: self
                .request
                .failures
                .unwrap_or(if self.request.quick { 1 } else { 4 }),
            record: self
                .request
                .record
                .then(|| self.out.join(human2nav_sim::shard::RECORD_DIR)),
        }
    }

    /// The plugin instances that failed so far (a panic or a refused call inside a plugin).
    pub fn plugin_failures(&self) -> Vec<PluginFailure> {
        self.host.failures()
    }
}

/// The configured methods named in `only` (all when empty), each built by its kind.
fn build_methods(
    cfg: &BenchConfig,
    host: &Arc<PluginHost>,
    only: &[String],
) -> anyhow::Result<Vec<MethodSpec>> {
    let mut methods: Vec<MethodSpec> = Vec::new();
    let configured = select(cfg.methods.clone(), only, "method", |m| &m.name)?;
    for m in &configured {
        match builtin_method(m, cfg, host)? {
            Some(spec) => methods.push(spec),
            None if m.kind == "human2nav" => methods.push(human2nav_method(m, cfg)?),
            None => bail!(
                "method `{}`: unknown kind `{}` (this build knows `straight`, `oracle`, `plugin` and `human2nav`)",
                m.name,
                m.kind
            ),
        }
    }
    Ok(methods)
}

/// Keeps the items named in `only` (all when it is empty); an unknown name is an error that
/// lists the known ones.
fn select<T>(
    items: Vec<T>,
    only: &[String],
    what: &str,
    name: impl Fn(&T) -> &str,
) -> anyhow::Result<Vec<T>> {
    if only.is_empty() {
        return Ok(items);
    }
    let known: Vec<&str> = items.iter().map(&name).collect();
    if let Some(bad) = only.iter().find(|o| !known.contains(&o.as_str())) {
        bail!(
            "--{what}s: no {what} `{bad}` in the configuration (it has {})",
            known.join(", ")
        );
    }
    Ok(items
        .into_iter()
        .filter(|i| only.iter().any(|o| o == name(i)))
        .collect())
}

/// [`ensure_episode_files`]: mines the missing episode files of `cfg`'s real suites from the
/// datasets of `data_config`, telling `log` what it mines; returns the note of the synthetic
/// fallback when the datasets are absent.
pub fn ensure_real_episodes(
    cfg: &BenchConfig,
    data_config: &Path,
    log: &dyn Fn(String),
) -> anyhow::Result<Option<String>> {
    Ok(ensure_episode_files(cfg, data_config, log)?)
}

/// A predictor of people fitted by `human2nav data predict --fit-on … --export <path>`.
fn load_history_ridge(path: &Path) -> anyhow::Result<HistoryRidge> {
    let text = read_user_file(path, "history model", MAX_CONFIG_BYTES)
        .with_context(|| format!("reading {}", path.display()))?;
    let model: HistoryRidge =
        toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    model
        .validate()
        .map_err(|e| anyhow!("{}: {e}", path.display()))?;
    Ok(model)
}

/// The `foresight` keys of a `human2nav` method's `config` (`None` without `foresight`),
/// checked; `field` names a key in errors.
fn foresight_settings(
    m: &MethodConfig,
    field: &dyn Fn(&str) -> String,
) -> anyhow::Result<Option<ForesightSettings>> {
    let number = |key: &str| -> anyhow::Result<Option<f64>> {
        m.config
            .get(key)
            .map(|v| {
                v.as_float()
                    .or_else(|| v.as_integer().map(|i| i as f64))
                    .ok_or_else(|| anyhow!("{}: must be a number, got {v}", field(key)))
            })
            .transpose()
    };
    let Some(share) = number("foresight")? else {
        if let Some(key) = ["foresight_within", "foresight_until"]
            .into_iter()
            .find(|k| m.config.contains_key(*k))
        {
            bail!("{}: needs `foresight` (the share it limits)", field(key));
        }
        return Ok(None);
    };
    let unlimited = ForesightSettings::share(share);
    let settings = ForesightSettings {
        within: number("foresight_within")?.unwrap_or(unlimited.within),
        until: number("foresight_until")?.unwrap_or(unlimited.until),
        ..unlimited
    };
    // The message begins with the key it is about.
    settings
        .validate()
        .map_err(|e| anyhow!("methods[{}].config.{e}", m.name))?;
    Ok(Some(settings))
}

/// `base` with the keys of the table `over` in place of its own (tables merged key by key,
/// so `{ selection = { margin = 0.3 } }` changes one weight), validated as a whole.
fn override_settings(
    base: &Human2NavSettings,
    over: &toml::Value,
) -> anyhow::Result<Human2NavSettings> {
    fn merge(into: &mut toml::Value, over: &toml::Value) {
        match (into, over) {
            (toml::Value::Table(a), toml::Value::Table(b)) => {
                for (k, v) in b {
                    match a.get_mut(k) {
                        Some(slot) => merge(slot, v),
                        None => {
                            a.insert(k.clone(), v.clone());
                        }
                    }
                }
            }
            (slot, v) => *slot = v.clone(),
        }
    }
    if !over.is_table() {
        bail!("must be a table of planner settings, as in the planner file's [human2nav]");
    }
    let mut value = toml::Value::try_from(base)?;
    merge(&mut value, over);
    let settings: Human2NavSettings = value.try_into()?;
    settings.validate()?;
    Ok(settings)
}

/// A `human2nav` method: the reference planner with the model and settings of a planner
/// configuration. Its `config` table takes `planner` (the planner TOML, relative to the
/// workspace root; default `sdk/configs/planner.toml`), `model` (another model folder),
/// `human2nav` (a table of planner settings merged over the file's `[human2nav]`) and either `algorithm1` (bool: Algorithm 1
/// on or off, nothing else; the shipped planner runs none) or `arm` (one of the guidance
/// ablation's arms, `raw`, `alg1`, `qp` or `alg1+qp`, see [`human2nav_core::ablation::Arm`]),
/// and `foresight` (0 to 1, a
/// yardstick: the planner's forecast of people moved that share of the way from constant
/// velocity to the episode's recording, [`human2nav_sim::foresight`]; not with a planner file
/// that names a `[prediction]` model) with, optionally, `foresight_within` (m: only the people
/// that close to the robot get it) and `foresight_until` (s: the recording that far ahead,
/// constant velocity after it), or `history_ridge` (the path of a predictor of people fitted by
/// `human2nav data predict --fit-on … --export`, [`HistoryRidge`]). Each episode gets a fresh
/// planner (model loaded from disk, source noise seeded with the episode's seed) for the robot
/// of that episode, with the robot's Φ including its plugin constraint terms; libtorch runs one
/// thread per planner (the episodes already run in parallel).
pub fn human2nav_method(m: &MethodConfig, cfg: &BenchConfig) -> anyhow::Result<MethodSpec> {
    let field = |key: &str| format!("methods[{}].config.{key}", m.name);
    const KEYS: [&str; 9] = [
        "planner",
        "model",
        "human2nav",
        "algorithm1",
        "arm",
        "foresight",
        "foresight_within",
        "foresight_until",
        "history_ridge",
    ];
    if m.config.contains_key("guidance") {
        bail!(
            "{}: renamed in December 2026, when it stopped switching the correction and the \
             robot's motions too: `guidance = false` (the raw samples) is now `arm = \"raw\"`; \
             Algorithm 1 alone is `algorithm1 = true` or `false`",
            field("guidance")
        );
    }
    for key in m.config.keys() {
        if !KEYS.contains(&key.as_str()) {
            bail!(
                "{}: unknown key (expected one of {})",
                field(key),
                KEYS.map(|k| format!("`{k}`")).join(", ")
            );
        }
    }
    let foresight = foresight_settings(m, &field)?;
    let history_ridge = match m.config.get("history_ridge") {
        None => None,
        Some(v) => {
            let path = cfg
                .resolve(Path::new(v.as_str().ok_or_else(|| {
                    anyhow!("{}: must be a path", field("history_ridge"))
                })?));
            Some(load_history_ridge(&path).with_context(|| field("history_ridge"))?)
        }
    };
    if m.config.contains_key("algorithm1") && m.config.contains_key("arm") {
        bail!(
            "{}: give `algorithm1` or `arm`, not both (an arm says whether Algorithm 1 runs)",
            field("arm")
        );
    }
    let planner_toml = match m.config.get("planner") {
        Some(v) => cfg
            .resolve(Path::new(v.as_str().ok_or_else(|| {
                anyhow!("{}: must be a path", field("planner"))
            })?)),
        None => cfg.resolve(Path::new("sdk/configs/planner.toml")),
    };
    let mut planner_cfg = PlannerConfig::load(&planner_toml)?;
    if let Some(v) = m.config.get("model") {
        planner_cfg.model = PathBuf::from(
            v.as_str()
                .ok_or_else(|| anyhow!("{}: must be a path", field("model")))?,
        );
    }
    if let Some(v) = m.config.get("human2nav") {
        planner_cfg.human2nav = override_settings(&planner_cfg.human2nav, v)
            .with_context(|| format!("{} (over {})", field("human2nav"), planner_toml.display()))?;
    }
    if let Some(v) = m.config.get("algorithm1") {
        planner_cfg.human2nav.guidance.enabled = v
            .as_bool()
            .ok_or_else(|| anyhow!("{}: must be true or false", field("algorithm1")))?;
    }
    if let Some(v) = m.config.get("arm") {
        let arm: Arm = v
            .as_str()
            .ok_or_else(|| anyhow!("{}: must be a string", field("arm")))?
            .parse()
            .map_err(|e| anyhow!("{}: {e}", field("arm")))?;
        planner_cfg.human2nav = arm.settings(&planner_cfg.human2nav);
    }
    let model_dir = planner_cfg.model_dir(&cfg.base_dir);
    let backend = planner_cfg.backend;
    // Fail now, with the folder named, rather than once per episode; the native weights are
    // read this once and shared by every run's planner.
    let shared =
        match load_model(&model_dir, backend).with_context(|| format!("method `{}`", m.name))? {
            PlannerModel::Native(model) => Some(model),
            PlannerModel::Torch(_) => None,
        };
    let prediction = PredictionModel::load(&planner_cfg, &cfg.base_dir)
        .with_context(|| format!("method `{}`", m.name))?;
    // Each replaces the planner's forecast of people, so at most one may be given.
    let predictors: Vec<String> = [
        foresight.map(|_| format!("`{}`", field("foresight"))),
        history_ridge
            .as_ref()
            .map(|_| format!("`{}`", field("history_ridge"))),
        prediction.as_ref().map(|_| {
            format!(
                "the [prediction] model of the planner file {}",
                planner_toml.display()
            )
        }),
    ]
    .into_iter()
    .flatten()
    .collect();
    if predictors.len() > 1 {
        bail!(
            "methods[{}].config: give one predictor of people, not {}",
            m.name,
            predictors.join(" and ")
        );
    }
    human2nav_flow::tch::set_num_threads(1);

    let mut profiles = HashMap::new();
    for path in &cfg.robots {
        let path = cfg.resolve(path);
        let profile = human2nav_flow::planner::load_profile(&path)?;
        profiles.insert(profile.name.clone(), profile);
    }
    let settings = planner_cfg.human2nav;
    Ok(MethodSpec::new(m.name.clone(), move |ctx| {
        let profile = profiles
            .get(&ctx.robot.name)
            .cloned()
            .ok_or_else(|| format!("no robot profile named `{}`", ctx.robot.name))?;
        let model = match &shared {
            Some(native) => PlannerModel::Native(native.clone()),
            None => load_model(&model_dir, backend)?,
        };
        let mut planner = RobotPlanner::new(
            profile,
            model,
            Human2NavSettings {
                seed: ctx.seed,
                ..settings
            },
        )?;
        if let Some(p) = &prediction {
            planner = planner.with_predictor(p.predictor()?);
        }
        if let Some(model) = &history_ridge {
            planner = planner.with_predictor(Box::new(model.clone()));
        }
        if let Some(settings) = foresight {
            let f = human2nav_sim::foresight::Foresight::new(ctx.episode.clone(), settings)?;
            planner = planner.with_predictor(Box::new(f));
        }
        Ok(Box::new(planner.planner))
    })
    .with_replan_hz(m.replan_hz))
}
