//! The native half of the Python package `human2nav` (module `human2nav._human2nav`).
//!
//! It holds robot profiles, planners and the closed-loop runner, and speaks in plain Python
//! values (tuples, lists, dicts, JSON text); the pure-Python half (`python/human2nav`) turns
//! them into numpy arrays and dataclasses and checks array shapes. Planning and episodes
//! release the GIL. Errors: a bad argument (a non-finite number, an unknown configuration
//! key, a missing file) is `ValueError` (`FileNotFoundError` for a missing file); anything else
//! the SDK reports is `human2nav.Human2NavError`.

use human2nav_core::embodiment::Embodiment;
use human2nav_core::human2nav::budget_deadline;
use human2nav_core::obstacle::{Obstacle, OccupancyGrid};
use human2nav_core::robot::{PluginIsolation, ProfileError, RobotProfile};
use human2nav_core::{AgentState, Observation, Plan, PlanError, Planner, Pose2, Twist2};
use human2nav_flow::planner::{Backend, PlannerConfig, PlannerError, RobotPlanner, load_model};
use human2nav_orca_core::planner::{OrcaConfig, OrcaPlanner};
use human2nav_plugin::PluginHost;
use human2nav_sim::config::synthetic_episodes;
use human2nav_sim::crowd::{CrowdModel, SocialForce};
use human2nav_sim::episode::load_episode_file;
use human2nav_sim::metrics::EpisodeMetrics;
use human2nav_sim::plan_figure::select_episode;
use human2nav_sim::runner::{RobotSetup, SimConfig, run_episode_with};
use pyo3::create_exception;
use pyo3::exceptions::{PyFileNotFoundError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

create_exception!(
    _human2nav,
    Human2NavError,
    PyRuntimeError,
    "An error of the SDK that is not a bad argument: a model or plugin that does not load, a \
     planner that fails."
);

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

fn sdk_error(e: impl std::fmt::Display) -> PyErr {
    Human2NavError::new_err(e.to_string())
}

fn profile_error(e: ProfileError) -> PyErr {
    match &e {
        ProfileError::Read { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        _ => value_error(e),
    }
}

fn planner_error(e: PlannerError) -> PyErr {
    match e {
        PlannerError::Config { .. }
        | PlannerError::Setting { .. }
        | PlannerError::Profile { .. }
        | PlannerError::Plan(PlanError::InvalidSettings(_) | PlanError::InvalidObservation(_)) => {
            value_error(e)
        }
        other => sdk_error(other),
    }
}

fn plan_error(e: PlanError) -> PyErr {
    match e {
        PlanError::InvalidObservation(_) | PlanError::InvalidSettings(_) => value_error(e),
        other => sdk_error(other),
    }
}

/// A robot: its profile (`robot.toml` + URDF) and its embodiment (kinematics and tracking
/// controller).
#[pyclass(module = "human2nav._human2nav", name = "RobotProfile", frozen)]
struct PyRobot {
    profile: RobotProfile,
    embodiment: Arc<dyn Embodiment>,
}

impl PyRobot {
    /// The profile's plugins run in the Python process unless it writes
    /// `isolation = "process"` (no helper executable ships with the package; see
    /// `human2nav_plugin::process`).
    fn new(mut profile: RobotProfile) -> PyResult<Self> {
        profile.default_plugin_isolation(PluginIsolation::InProcess);
        let embodiment = PluginHost::new()
            .robot_embodiment(&mut profile)
            .map_err(sdk_error)?;
        Ok(Self {
            profile,
            embodiment: Arc::from(embodiment),
        })
    }

    fn setup(&self) -> RobotSetup {
        RobotSetup::from_profile(&self.profile, Arc::clone(&self.embodiment))
    }
}

#[pymethods]
impl PyRobot {
    /// Loads and validates `robot.toml` and the URDF it names.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Self::new(RobotProfile::load(&path).map_err(profile_error)?)
    }

    /// A profile held in memory: the TOML text, the URDF text (None: read the file the profile
    /// names, relative to `source`'s folder) and the path the profile goes by in errors.
    #[staticmethod]
    #[pyo3(signature = (robot_toml, urdf = None, source = "robot.toml"))]
    fn from_strings(robot_toml: &str, urdf: Option<&str>, source: &str) -> PyResult<Self> {
        let path = PathBuf::from(source);
        Self::new(RobotProfile::from_toml_str(robot_toml, &path, urdf).map_err(profile_error)?)
    }

    /// The robot's name.
    #[getter]
    fn name(&self) -> &str {
        &self.profile.name
    }

    /// The embodiment kind (`differential_drive`, `ackermann`, `omnidirectional`, `plugin`).
    #[getter]
    fn embodiment(&self) -> &'static str {
        self.profile.embodiment.kind_name()
    }

    /// Whether the robot can move sideways.
    #[getter]
    fn holonomic(&self) -> bool {
        self.embodiment.holonomic()
    }

    /// Radius of the disc about the reference point that covers the footprint, m.
    #[getter]
    fn footprint_radius(&self) -> f64 {
        self.profile.footprint_radius
    }

    /// The effective limits: `v_max`, `v_reverse_max` (m/s), `a_max` (m/s²), `omega_max`
    /// (rad/s), `kappa_max` (1/m or None), `lateral_speed_max` (m/s).
    #[getter]
    fn limits<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for entry in self.profile.limit_table() {
            d.set_item(entry.name, entry.value)?;
        }
        Ok(d)
    }

    /// Every limit as `(name, value, unit, where it came from)`.
    fn limit_table(&self) -> Vec<(String, Option<f64>, String, String)> {
        self.profile
            .limit_table()
            .into_iter()
            .map(|e| {
                (
                    e.name.to_owned(),
                    e.value,
                    e.unit.to_owned(),
                    e.source.to_string(),
                )
            })
            .collect()
    }

    fn __repr__(&self) -> String {
        format!(
            "RobotProfile(name={:?}, embodiment={:?}, footprint_radius={})",
            self.profile.name,
            self.profile.embodiment.kind_name(),
            self.profile.footprint_radius
        )
    }
}

/// The static scene of one planning call, as the Python half sends it.
#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Scene {
    #[serde(default)]
    obstacles: Vec<Obstacle>,
    #[serde(default)]
    occupancy: Option<OccupancyGrid>,
}

/// A planner: Human2Nav or ORCA behind the SDK's `Planner` trait.
#[pyclass(module = "human2nav._human2nav", name = "Planner", frozen)]
struct PyPlanner {
    inner: Mutex<Box<dyn Planner>>,
    name: String,
}

impl PyPlanner {
    fn wrap(planner: Box<dyn Planner>) -> Self {
        let name = planner.name().to_owned();
        Self {
            inner: Mutex::new(planner),
            name,
        }
    }

    fn lock(&self) -> PyResult<std::sync::MutexGuard<'_, Box<dyn Planner>>> {
        self.inner
            .lock()
            .map_err(|_| sdk_error("the planner panicked in an earlier call; create a new one"))
    }
}

/// `(x, y, θ)` of each pose.
fn pose_list(poses: &[Pose2]) -> Vec<(f64, f64, f64)> {
    poses.iter().map(|p| (p.x, p.y, p.theta)).collect()
}

/// A plan as a dict of plain values (the Python half makes arrays of them).
fn plan_dict<'py>(py: Python<'py>, plan: &Plan) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("t0", plan.t0)?;
    d.set_item("dt", plan.dt)?;
    d.set_item("poses", pose_list(&plan.poses))?;
    let info = &plan.info;
    let candidates: Vec<_> = info.candidates.iter().map(|c| pose_list(c)).collect();
    let guided: Vec<_> = info.guided.iter().map(|c| pose_list(c)).collect();
    d.set_item("candidates", candidates)?;
    d.set_item("guided", guided)?;
    d.set_item("selected", info.selected)?;
    d.set_item("phi_before", info.phi_before)?;
    d.set_item("phi_after", info.phi_after)?;
    d.set_item("guidance_iterations", info.guidance_iterations)?;
    d.set_item("fallback", info.fallback)?;
    d.set_item("notes", info.notes.clone())?;
    d.set_item("warnings", info.warnings.clone())?;
    if let Some(s) = &info.stages {
        let stages = PyDict::new(py);
        for (name, p) in [
            ("sampling", s.sampling),
            ("guidance", s.guidance),
            ("correction", s.correction),
        ] {
            stages.set_item(name, (p.done, p.planned))?;
        }
        stages.set_item("cut_short", s.cut_short.map(|st| st.name()))?;
        d.set_item("stages", stages)?;
    } else {
        d.set_item("stages", py.None())?;
    }
    Ok(d)
}

#[pymethods]
impl PyPlanner {
    /// The Human2Nav planner for `robot` with the model folder `model_dir`. `config` is a
    /// `planner.toml` (None: the built-in defaults, equal to the shipped configuration; a
    /// `[prediction]` model it names is loaded, a relative path from the current directory);
    /// the keyword arguments override it.
    #[staticmethod]
    #[pyo3(signature = (robot, model_dir, config = None, guidance = None, seed = None, samples = None, backend = None))]
    fn human2nav(
        robot: &PyRobot,
        model_dir: PathBuf,
        config: Option<PathBuf>,
        guidance: Option<bool>,
        seed: Option<u64>,
        samples: Option<usize>,
        backend: Option<&str>,
    ) -> PyResult<Self> {
        let mut cfg = match &config {
            Some(path) => PlannerConfig::load(path).map_err(planner_error)?,
            None => PlannerConfig::default(),
        };
        if let Some(g) = guidance {
            cfg.human2nav.guidance.enabled = g;
        }
        if let Some(s) = seed {
            cfg.human2nav.seed = s;
        }
        if let Some(k) = samples {
            cfg.human2nav.samples = k;
        }
        if let Some(b) = backend {
            cfg.backend = b.parse::<Backend>().map_err(value_error)?;
        }
        cfg.validate().map_err(planner_error)?;
        #[cfg(feature = "torch")]
        if cfg.backend != Backend::Native {
            human2nav_flow::tch::set_num_threads(i32::try_from(cfg.threads).unwrap_or(1));
        }
        let model = load_model(&model_dir, cfg.backend).map_err(planner_error)?;
        let rp = RobotPlanner::new(robot.profile.clone(), model, cfg.human2nav)
            .and_then(|rp| rp.with_prediction(&cfg, Path::new(".")))
            .map_err(planner_error)?;
        Ok(Self::wrap(Box::new(rp.planner)))
    }

    /// ORCA (RVO2 semantics) for `robot`: `config` is the TOML text of its settings (None: the
    /// defaults); the robot's footprint radius and `v_max` fill `radius` and `max_speed` unless
    /// the text sets them.
    #[staticmethod]
    #[pyo3(signature = (robot, config = None))]
    fn orca(robot: &PyRobot, config: Option<&str>) -> PyResult<Self> {
        let text = config.unwrap_or("");
        let table: toml::Table = text.parse().map_err(value_error)?;
        let mut cfg = OrcaConfig::from_toml_str(text).map_err(value_error)?;
        if !table.contains_key("radius") {
            cfg.radius = robot.profile.footprint_radius;
        }
        if !table.contains_key("max_speed") {
            cfg.max_speed = robot.profile.limits.v_max;
        }
        let planner = OrcaPlanner::new(cfg).map_err(value_error)?;
        Ok(Self::wrap(Box::new(planner)))
    }

    /// The planner's name (`human2nav`, `orca`).
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }

    /// Forgets the previous plan (a new navigation task).
    fn reset(&self) -> PyResult<()> {
        self.lock()?.reset();
        Ok(())
    }

    /// Plans from one observation (world frame; the robot's velocity in its body frame).
    /// `agents` holds `(id, x, y, vx, vy, radius)` per pedestrian; `budget_ms > 0` bounds the
    /// call (anytime planning; ignored by ORCA); `scene` is the JSON text of the static scene,
    /// `{"obstacles": [...], "occupancy": {...}}` in the serde form of core's `Obstacle` and
    /// `OccupancyGrid` (ORCA ignores it).
    #[pyo3(signature = (time, ego, ego_velocity, goal, agents, budget_ms = 0.0, scene = None))]
    fn plan<'py>(
        &self,
        py: Python<'py>,
        time: f64,
        ego: (f64, f64, f64),
        ego_velocity: (f64, f64, f64),
        goal: (f64, f64),
        agents: Vec<(u64, f64, f64, f64, f64, f64)>,
        budget_ms: f64,
        scene: Option<&str>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let scene: Scene = match scene {
            Some(text) => serde_json::from_str(text)
                .map_err(|e| value_error(format!("obstacles or occupancy: {e}")))?,
            None => Scene::default(),
        };
        let deadline = budget_deadline(budget_ms).map_err(value_error)?;
        let obs = Observation {
            time,
            ego: Pose2::new(ego.0, ego.1, ego.2),
            ego_velocity: Twist2::new(ego_velocity.0, ego_velocity.1, ego_velocity.2),
            goal: [goal.0, goal.1],
            agents: agents
                .into_iter()
                .map(|(id, x, y, vx, vy, radius)| AgentState {
                    id,
                    position: [x, y],
                    velocity: [vx, vy],
                    radius,
                    history: Vec::new(),
                })
                .collect(),
            obstacles: scene.obstacles,
            occupancy: scene.occupancy,
            ..Default::default()
        };
        let result = py.detach(|| {
            let mut planner = self.lock()?;
            let plan = if budget_ms > 0.0 {
                planner.plan_within(&obs, &deadline)
            } else {
                planner.plan(&obs)
            };
            plan.map_err(plan_error)
        })?;
        plan_dict(py, &result)
    }
}

/// Runs one benchmark episode closed loop: the episode `index` (or `episode_id`) of an episode
/// file (`human2nav data episodes`; None: the embedded synthetic episodes, one per scenario
/// class), with the crowd replayed (`"replay"`) or reacting to the robot (`"reactive"`).
/// Returns `(episode_id, metrics as JSON, states, commands, clearance)`: states are
/// `(x, y, θ, vx, vy, ω)` every simulation step, commands the executed `(vx, vy, ω)`.
#[pyfunction]
#[pyo3(signature = (planner, robot, episodes = None, index = 0, episode_id = None, crowd = "replay", replan_hz = 10.0))]
#[allow(clippy::type_complexity)]
fn run_episode(
    py: Python<'_>,
    planner: &PyPlanner,
    robot: &PyRobot,
    episodes: Option<PathBuf>,
    index: usize,
    episode_id: Option<&str>,
    crowd: &str,
    replan_hz: f64,
) -> PyResult<(
    String,
    String,
    Vec<(f64, f64, f64, f64, f64, f64)>,
    Vec<(f64, f64, f64)>,
    Vec<f64>,
)> {
    let list = match &episodes {
        Some(path) => load_episode_file(path).map_err(value_error)?.episodes,
        None => synthetic_episodes(1, 1).map_err(value_error)?,
    };
    let episode = select_episode(&list, index, episode_id).map_err(value_error)?;
    let model = match crowd {
        "replay" => CrowdModel::Replay,
        "reactive" => CrowdModel::Reactive(SocialForce::default()),
        other => {
            return Err(value_error(format!(
                "crowd `{other}`: expected \"replay\" or \"reactive\""
            )));
        }
    };
    if !(replan_hz.is_finite() && replan_hz > 0.0) {
        return Err(value_error(format!("replan_hz {replan_hz} must be > 0")));
    }
    let cfg = SimConfig::default().with_replan_hz(Some(replan_hz));
    cfg.validate().map_err(value_error)?;
    let setup = robot.setup();
    let run = py.detach(|| {
        let mut p = planner.lock()?;
        p.reset();
        Ok::<_, PyErr>(run_episode_with(episode, &setup, p.as_mut(), &cfg, &model))
    })?;
    let metrics = EpisodeMetrics::compute(&run, &robot.profile.limits);
    let metrics = serde_json::to_string(&metrics).map_err(sdk_error)?;
    let states = run
        .states
        .iter()
        .map(|s| {
            let (p, v) = (s.pose, s.velocity);
            (p.x, p.y, p.theta, v.vx, v.vy, v.omega)
        })
        .collect();
    let commands = run.commands.iter().map(|c| (c.vx, c.vy, c.omega)).collect();
    Ok((episode.id.clone(), metrics, states, commands, run.clearance))
}

/// The SDK's version.
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

#[pymodule]
fn _human2nav(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyRobot>()?;
    m.add_class::<PyPlanner>()?;
    m.add_function(wrap_pyfunction!(run_episode, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    m.add("Human2NavError", m.py().get_type::<Human2NavError>())?;
    Ok(())
}
