//! The planner's C API, `libhuman2nav_c`: the header is `sdk/capi/include/human2nav.h`,
//! generated from this file by cbindgen (a test keeps it in sync).
//!
//! A C or C++ program creates a Human2Nav planner from a robot profile (`robot.toml` and its
//! URDF, as files or as strings), a planner configuration (`planner.toml`) and a model folder;
//! plans from an observation, optionally under a time budget; reads the plan's poses and
//! diagnostics; turns the plan into a velocity command with the robot's tracking controller;
//! and frees what it created.
//!
//! # Conventions
//!
//! * **Errors.** Every function that can fail returns an [`h2n_status`]; on failure,
//!   [`h2n_last_error`] returns a message that names the argument, file or field. Outputs are
//!   written only on success. Nothing panics across the boundary: a panic inside the library
//!   becomes `H2N_STATUS_PANIC`, and the planner it happened in refuses every later call with
//!   `H2N_STATUS_POISONED` (free it and create a new one).
//! * **Arguments.** Null pointers, non-UTF-8 strings, non-finite numbers, negative budgets
//!   and unknown configuration keys are `H2N_STATUS_INVALID_ARGUMENT` or
//!   `H2N_STATUS_CONFIG`, never a crash. Strings are NUL-terminated UTF-8.
//! * **Threads.** A planner may move between threads but must be used by one thread at a time
//!   (it keeps the previous plan as a warm start and its QP solver between calls); create one
//!   planner per thread to plan in parallel. A plan is immutable and may be read from any
//!   thread. The last error is kept per thread.
//! * **Units and frames.** SI units; poses `(x, y, θ)` and pedestrian positions and
//!   velocities in one world-fixed frame (e.g. `odom`), the robot's velocity in its body
//!   frame, times in seconds on the caller's clock.
//! * **Ownership.** `h2n_planner_create*` and `h2n_planner_plan` hand out objects the caller
//!   frees with `h2n_planner_free` and `h2n_plan_free`; freeing NULL does nothing.
//!
//! # Building and installing
//!
//! `sdk/capi/install.sh --prefix DIR` builds this package alone (`cargo build --release -p
//! human2nav-capi`) and installs the library, the header, a pkg-config file (`human2nav`) and a
//! CMake package (`find_package(human2nav)`, target `human2nav::human2nav`) with the shipped
//! robots, planner settings and model under `DIR/share/human2nav`. Built this way the library
//! plans on the native backend and links no libtorch; the `torch` feature (`install.sh
//! --torch`) adds the `torch` backend and with it libtorch. `examples/cmake` builds the C and
//! C++ examples against an installed copy.

#![warn(missing_docs)]
#![allow(non_camel_case_types)]

use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::human2nav::{budget_deadline, pose_at};
use human2nav_core::robot::{PluginIsolation, RobotProfile};
use human2nav_core::{Plan, Pose2, Stage, Twist2};
use human2nav_flow::planner::{PlannerConfig, PlannerError, RobotPlanner, load_model};
use human2nav_plugin::PluginHost;
use std::ffi::{CStr, CString, c_char};
use std::path::{Path, PathBuf};

mod args;
mod failure;
mod observation;

use args::{finite, optional_str, planner_mut, required_out, required_ref, required_str};
use failure::{Failure, LAST_ERROR, guard};
use observation::observation;

/// Largest number of pedestrians one observation may carry.
pub const H2N_MAX_AGENTS: usize = 10_000;

/// What a call returned.
#[repr(i32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum h2n_status {
    /// Success; the outputs are written.
    Ok = 0,
    /// A null pointer, a non-UTF-8 string, a non-finite number, a count out of range.
    InvalidArgument = 1,
    /// A robot profile or planner configuration was rejected (unknown key, value out of range,
    /// file missing); the message names the file and field.
    Config = 2,
    /// The model folder could not be loaded (missing, wrong checksum, incompatible card).
    Model = 3,
    /// A plugin the robot profile names could not be loaded.
    Plugin = 4,
    /// The planner failed on an observation it accepted.
    Plan = 5,
    /// An output buffer is too small; the message says how large it must be.
    BufferTooSmall = 6,
    /// The library panicked; the planner involved is unusable.
    Panic = 7,
    /// The planner panicked in an earlier call and refuses to plan.
    Poisoned = 8,
}

/// A pose in the world frame: position (m) and heading (rad).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct h2n_pose {
    /// Position along the world x axis, m.
    pub x: f64,
    /// Position along the world y axis, m.
    pub y: f64,
    /// Heading, rad, counter-clockwise from the world x axis.
    pub theta: f64,
}

/// A body-frame velocity: forward and leftward speed (m/s) and yaw rate (rad/s).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct h2n_twist {
    /// Forward speed, m/s.
    pub vx: f64,
    /// Leftward speed, m/s (0 for robots that cannot move sideways).
    pub vy: f64,
    /// Yaw rate, rad/s, counter-clockwise.
    pub omega: f64,
}

/// A pedestrian (or any other moving disc) in the world frame.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct h2n_agent {
    /// Identity, stable across observations (a tracker's track id).
    pub id: u64,
    /// Position, m.
    pub x: f64,
    /// Position, m.
    pub y: f64,
    /// Velocity, m/s.
    pub vx: f64,
    /// Velocity, m/s.
    pub vy: f64,
    /// Radius of the disc used for collision checks, m (≥ 0).
    pub radius: f64,
}

/// Largest number of static obstacles one observation may carry.
pub const H2N_MAX_OBSTACLES: usize = 100_000;

/// The shape of a static obstacle.
#[repr(i32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum h2n_obstacle_kind {
    /// A disc: centre `(x0, y0)`, `radius`.
    Circle = 0,
    /// A line segment (a wall) from `(x0, y0)` to `(x1, y1)`.
    Segment = 1,
    /// A simple polygon: `vertex_count ≥ 3` points, `vertices` holding `x, y` pairs.
    Polygon = 2,
}

/// A static obstacle in the world frame (the fields its kind does not use are ignored).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct h2n_obstacle {
    /// Which shape it is: an `h2n_obstacle_kind` value (any other is refused).
    pub kind: i32,
    /// Circle centre or segment start, m.
    pub x0: f64,
    /// Circle centre or segment start, m.
    pub y0: f64,
    /// Segment end, m.
    pub x1: f64,
    /// Segment end, m.
    pub y1: f64,
    /// Circle radius, m (≥ 0).
    pub radius: f64,
    /// Polygon vertices as `2·vertex_count` numbers `x0, y0, x1, y1, …`.
    pub vertices: *const f64,
    /// Number of polygon vertices.
    pub vertex_count: usize,
}

/// Everything the planner uses at one planning instant.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct h2n_observation {
    /// Time of the observation, s (the plan's first pose is at this time).
    pub time: f64,
    /// The robot's pose, world frame.
    pub ego: h2n_pose,
    /// The robot's velocity, body frame.
    pub ego_velocity: h2n_twist,
    /// The goal position, world frame, m.
    pub goal_x: f64,
    /// The goal position, world frame, m.
    pub goal_y: f64,
    /// `agent_count` pedestrians (may be NULL when the count is 0).
    pub agents: *const h2n_agent,
    /// Number of pedestrians, at most `H2N_MAX_AGENTS`.
    pub agent_count: usize,
    /// `obstacle_count` static obstacles (may be NULL when the count is 0): walls, pillars.
    pub obstacles: *const h2n_obstacle,
    /// Number of obstacles, at most `H2N_MAX_OBSTACLES`.
    pub obstacle_count: usize,
}

/// The stage of a planning call a deadline cut short.
#[repr(i32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum h2n_stage {
    /// No stage was cut short: the call ran to completion.
    None = 0,
    /// Integrating the flow model (the rest continued at the last velocity).
    Sampling = 1,
    /// Algorithm 1's iterations (the last completed one was kept).
    Guidance = 2,
    /// The last-step correction (only the stop and previous-plan candidates were corrected).
    Correction = 3,
}

/// Diagnostics of a plan.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct h2n_plan_info {
    /// Time of the first pose, s.
    pub t0: f64,
    /// Time between poses, s.
    pub dt: f64,
    /// Number of poses, the robot's current pose first.
    pub pose_count: usize,
    /// True when the planner fell back to stopping in place (the reason is in the notes).
    pub fallback: bool,
    /// Index of the flow-model sample the plan follows, or -1 (a kept previous plan, braking,
    /// the straight approach to a close goal).
    pub selected: i64,
    /// Integration steps of the flow model that ran, of `sampling_planned`.
    pub sampling_done: u32,
    /// Integration steps a full call runs (`N`).
    pub sampling_planned: u32,
    /// Algorithm 1 iterations completed, of `guidance_planned`.
    pub guidance_done: u32,
    /// Algorithm 1 iterations a full call runs at most (`M`; 0 with guidance off).
    pub guidance_planned: u32,
    /// Candidates the last-step correction ran on, of `correction_planned`.
    pub correction_done: u32,
    /// Candidates of the selection (0 when the correction is off).
    pub correction_planned: u32,
    /// The stage the deadline cut short.
    pub cut_short: h2n_stage,
}

/// The robot's hard limits as the planner uses them.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct h2n_limits {
    /// Forward speed limit, m/s.
    pub v_max: f64,
    /// Reverse speed limit, m/s (0: cannot reverse).
    pub v_reverse_max: f64,
    /// Acceleration limit, m/s².
    pub a_max: f64,
    /// Yaw-rate limit, rad/s.
    pub omega_max: f64,
    /// Curvature limit, 1/m (`INFINITY` when the robot has none).
    pub kappa_max: f64,
    /// Lateral speed limit, m/s.
    pub lateral_speed_max: f64,
}

/// A Human2Nav planner for one robot (opaque).
pub struct h2n_planner {
    robot: RobotPlanner,
    embodiment: Box<dyn Embodiment>,
    /// Set while a call runs; still set after a panic, which makes the planner unusable.
    busy: bool,
}

impl std::fmt::Debug for h2n_planner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("h2n_planner")
            .field("robot", &self.robot.profile.name)
            .finish_non_exhaustive()
    }
}

/// A plan (opaque, immutable).
#[derive(Debug)]
pub struct h2n_plan {
    plan: Plan,
    notes: CString,
}

// ---------------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------------

/// The message of the last failed call on this thread ("" before any). The pointer stays
/// valid until the next failed call on this thread.
#[unsafe(no_mangle)]
pub extern "C" fn h2n_last_error() -> *const c_char {
    LAST_ERROR.with(|slot| slot.borrow().as_ptr())
}

/// The library's version, e.g. "0.1.0" (a static string).
#[unsafe(no_mangle)]
pub extern "C" fn h2n_version() -> *const c_char {
    static VERSION: &CStr =
        match CStr::from_bytes_with_nul(concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes()) {
            Ok(v) => v,
            Err(_) => c"unknown",
        };
    VERSION.as_ptr()
}

// ---------------------------------------------------------------------------------------------
// Creating and freeing planners
// ---------------------------------------------------------------------------------------------

/// Builds the planner from a loaded profile, a configuration and a model folder. The
/// profile's plugins run in the calling program's process unless it writes
/// `isolation = "process"` (the program embedding this library is the host, and no helper
/// executable is installed with it; see `human2nav_plugin::process`).
fn build(
    mut profile: RobotProfile,
    config: PlannerConfig,
    model_dir: &str,
) -> Result<Box<h2n_planner>, Failure> {
    profile.default_plugin_isolation(PluginIsolation::InProcess);
    let embodiment = PluginHost::new()
        .robot_embodiment(&mut profile)
        .map_err(|e| Failure::new(h2n_status::Plugin, e.to_string()))?;
    #[cfg(feature = "torch")]
    if config.backend != human2nav_flow::planner::Backend::Native {
        human2nav_flow::tch::set_num_threads(i32::try_from(config.threads).unwrap_or(1));
    }
    let model = load_model(Path::new(model_dir), config.backend)?;
    // A predictor model the configuration names is loaded too, relative to the current
    // directory (the API has no workspace root).
    let robot = RobotPlanner::new(profile, model, config.human2nav)?
        .with_prediction(&config, Path::new("."))?;
    Ok(Box::new(h2n_planner {
        robot,
        embodiment,
        busy: false,
    }))
}

/// The planner configuration from an optional file or text (`None`: the built-in defaults,
/// which are the shipped `planner.toml`'s).
fn config_from(text: Option<&str>, path: &Path) -> Result<PlannerConfig, Failure> {
    match text {
        Some(t) => Ok(PlannerConfig::from_toml_str(t, path)?),
        None => Ok(PlannerConfig::default()),
    }
}

/// Creates a planner from files: the robot profile `robot_toml` (its URDF is found relative to
/// it), the planner configuration `planner_toml` (NULL: the built-in defaults, equal to the
/// shipped `sdk/configs/planner.toml`) and the model folder `model_dir` (`model.toml` and its
/// weights; the configuration's `model` key is not used; a `[prediction]` model it names is
/// loaded, a relative path from the current directory). On success `*out` holds the planner.
///
/// # Safety
/// The strings are NULL or NUL-terminated; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_planner_create(
    robot_toml: *const c_char,
    planner_toml: *const c_char,
    model_dir: *const c_char,
    out: *mut *mut h2n_planner,
) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (robot, planner, model, out) = unsafe {
            (
                required_str(robot_toml, "robot_toml")?,
                optional_str(planner_toml, "planner_toml")?,
                required_str(model_dir, "model_dir")?,
                required_out(out, "out")?,
            )
        };
        let profile = RobotProfile::load(Path::new(robot))
            .map_err(|e| Failure::new(h2n_status::Config, e.to_string()))?;
        let config = match planner {
            Some(p) => PlannerConfig::load(Path::new(p))?,
            None => PlannerConfig::default(),
        };
        *out = Box::into_raw(build(profile, config, model)?);
        Ok(())
    })
}

/// Creates a planner from texts, for a robot description held in memory (a URDF read from a
/// parameter server, say): `robot_toml_text` is the profile's TOML, `urdf_text` the URDF its
/// `urdf` key would name (NULL: read the file that key names), `planner_toml_text` the planner
/// configuration (NULL: the built-in defaults). `source_name` is the path the profile goes by
/// in error messages, and relative paths in it (plugins, and the URDF when `urdf_text` is
/// NULL) are resolved against its folder; NULL: `robot.toml` in the current directory.
///
/// # Safety
/// The strings are NULL or NUL-terminated; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_planner_create_from_strings(
    robot_toml_text: *const c_char,
    urdf_text: *const c_char,
    planner_toml_text: *const c_char,
    model_dir: *const c_char,
    source_name: *const c_char,
    out: *mut *mut h2n_planner,
) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (robot, urdf, planner, model, source, out) = unsafe {
            (
                required_str(robot_toml_text, "robot_toml_text")?,
                optional_str(urdf_text, "urdf_text")?,
                optional_str(planner_toml_text, "planner_toml_text")?,
                required_str(model_dir, "model_dir")?,
                optional_str(source_name, "source_name")?,
                required_out(out, "out")?,
            )
        };
        let source = PathBuf::from(source.unwrap_or("robot.toml"));
        let profile = RobotProfile::from_toml_str(robot, &source, urdf)
            .map_err(|e| Failure::new(h2n_status::Config, e.to_string()))?;
        let config = config_from(planner, Path::new("planner_toml_text"))?;
        *out = Box::into_raw(build(profile, config, model)?);
        Ok(())
    })
}

/// Frees a planner (NULL: nothing happens).
///
/// # Safety
/// `planner` is NULL or from `h2n_planner_create*`, not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_planner_free(planner: *mut h2n_planner) {
    if !planner.is_null() {
        // SAFETY: created by Box::into_raw in h2n_planner_create*, freed once (contract).
        drop(unsafe { Box::from_raw(planner) });
    }
}

/// Forgets the previous plan (the warm start) and restarts the planner's noise from its seed:
/// call it at the start of a new navigation task.
///
/// # Safety
/// `planner` is NULL or a live planner.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_planner_reset(planner: *mut h2n_planner) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let p = unsafe { planner_mut(planner) }?;
        human2nav_core::Planner::reset(&mut p.robot.planner);
        Ok(())
    })
}

/// The robot's hard limits.
///
/// # Safety
/// `planner` is NULL or a live planner; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_planner_limits(
    planner: *const h2n_planner,
    out: *mut h2n_limits,
) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (p, out) = unsafe { (required_ref(planner, "planner")?, required_out(out, "out")?) };
        let l = p.robot.limits();
        *out = h2n_limits {
            v_max: l.v_max,
            v_reverse_max: l.v_reverse_max,
            a_max: l.a_max,
            omega_max: l.omega_max,
            kappa_max: l.kappa_max.unwrap_or(f64::INFINITY),
            lateral_speed_max: l.lateral_speed_max,
        };
        Ok(())
    })
}

// ---------------------------------------------------------------------------------------------
// Planning
// ---------------------------------------------------------------------------------------------

/// Plans from `obs`. `budget_ms > 0` bounds the call: it returns the best plan found by then,
/// never starting a network call after it, and always a feasible one (braking at worst; see
/// `h2n_plan_info.cut_short`); `budget_ms = 0` uses the configuration's `budget_ms` (none by
/// default). On success `*out` holds the plan, to be freed with `h2n_plan_free`.
///
/// # Safety
/// `planner` is NULL or a live planner used by no other thread now; `obs` is NULL or a valid
/// observation (its `agents` array holds `agent_count` elements); `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_planner_plan(
    planner: *mut h2n_planner,
    obs: *const h2n_observation,
    budget_ms: f64,
    out: *mut *mut h2n_plan,
) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (p, obs, out) = unsafe {
            (
                planner_mut(planner)?,
                required_ref(obs, "obs")?,
                required_out(out, "out")?,
            )
        };
        // 0: the configuration's budget; otherwise the same bounds as every front end.
        let deadline = budget_deadline(budget_ms).map_err(Failure::invalid)?;
        // SAFETY: the caller's contract on `agents`.
        let observation = unsafe { observation(obs) }?;
        let planner = &mut p.robot.planner;
        p.busy = true;
        let result = if budget_ms > 0.0 {
            human2nav_core::Planner::plan_within(planner, &observation, &deadline)
        } else {
            human2nav_core::Planner::plan(planner, &observation)
        };
        p.busy = false;
        let plan = result.map_err(|e| Failure::from(PlannerError::Plan(e)))?;
        let notes = plan.info.notes.join("; ").replace('\0', " ");
        let notes = CString::new(notes).unwrap_or_default();
        *out = Box::into_raw(Box::new(h2n_plan { plan, notes }));
        Ok(())
    })
}

/// Frees a plan (NULL: nothing happens).
///
/// # Safety
/// `plan` is NULL or from `h2n_planner_plan`, not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_plan_free(plan: *mut h2n_plan) {
    if !plan.is_null() {
        // SAFETY: created by Box::into_raw in h2n_planner_plan, freed once (contract).
        drop(unsafe { Box::from_raw(plan) });
    }
}

/// The plan's diagnostics.
///
/// # Safety
/// `plan` is NULL or a live plan; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_plan_get_info(
    plan: *const h2n_plan,
    out: *mut h2n_plan_info,
) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (p, out) = unsafe { (required_ref(plan, "plan")?, required_out(out, "out")?) };
        let plan = &p.plan;
        let stages = plan.info.stages.unwrap_or_default();
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        *out = h2n_plan_info {
            t0: plan.t0,
            dt: plan.dt,
            pose_count: plan.poses.len(),
            fallback: plan.info.fallback,
            selected: plan
                .info
                .selected
                .and_then(|i| i64::try_from(i).ok())
                .unwrap_or(-1),
            sampling_done: count(stages.sampling.done),
            sampling_planned: count(stages.sampling.planned),
            guidance_done: count(stages.guidance.done),
            guidance_planned: count(stages.guidance.planned),
            correction_done: count(stages.correction.done),
            correction_planned: count(stages.correction.planned),
            cut_short: match stages.cut_short {
                None => h2n_stage::None,
                Some(Stage::Sampling) => h2n_stage::Sampling,
                Some(Stage::Guidance) => h2n_stage::Guidance,
                Some(Stage::Correction) => h2n_stage::Correction,
            },
        };
        Ok(())
    })
}

/// The planner's notes on the plan, `"; "`-separated ("" when none): why it fell back, what a
/// deadline cut, which candidate won. The pointer lives as long as the plan.
///
/// # Safety
/// `plan` is NULL or a live plan.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_plan_notes(plan: *const h2n_plan) -> *const c_char {
    // SAFETY: the caller's contract.
    match unsafe { plan.as_ref() } {
        Some(p) => p.notes.as_ptr(),
        None => c"".as_ptr(),
    }
}

/// Copies the plan's poses (world frame, `info.dt` apart, the robot's pose at `info.t0`
/// first) into `out`, which holds `capacity` poses; `*written` gets the number copied. A
/// `capacity` below `info.pose_count` is `H2N_STATUS_BUFFER_TOO_SMALL` and copies nothing.
///
/// # Safety
/// `plan` is NULL or a live plan; `out` is NULL or holds `capacity` writable poses;
/// `written` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_plan_poses(
    plan: *const h2n_plan,
    out: *mut h2n_pose,
    capacity: usize,
    written: *mut usize,
) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (p, written) = unsafe {
            (
                required_ref(plan, "plan")?,
                required_out(written, "written")?,
            )
        };
        let poses = &p.plan.poses;
        if capacity < poses.len() {
            return Err(Failure::new(
                h2n_status::BufferTooSmall,
                format!(
                    "out holds {capacity} poses; the plan has {} (h2n_plan_info.pose_count)",
                    poses.len()
                ),
            ));
        }
        if out.is_null() {
            return Err(Failure::invalid("out is NULL"));
        }
        // SAFETY: non-null and at least `capacity ≥ poses.len()` writable poses (contract).
        let dst = unsafe { std::slice::from_raw_parts_mut(out, poses.len()) };
        for (d, s) in dst.iter_mut().zip(poses) {
            *d = h2n_pose {
                x: s.x,
                y: s.y,
                theta: s.theta,
            };
        }
        *written = poses.len();
        Ok(())
    })
}

/// The plan's pose at time `t` (s, the observation's clock), interpolated along the plan and
/// held at its ends.
///
/// # Safety
/// `plan` is NULL or a live plan; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_plan_pose_at(
    plan: *const h2n_plan,
    t: f64,
    out: *mut h2n_pose,
) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (p, out) = unsafe { (required_ref(plan, "plan")?, required_out(out, "out")?) };
        finite("t", &[t])?;
        let q = pose_at(&p.plan, t);
        *out = h2n_pose {
            x: q.x,
            y: q.y,
            theta: q.theta,
        };
        Ok(())
    })
}

/// The velocity command that follows `plan` at time `t` from the robot's current `pose`
/// (world frame) and `velocity` (body frame): the robot profile's tracking controller,
/// saturated to what the robot can do within one control period `control_dt` (s). This is
/// what a controller sends to the base (a `geometry_msgs/Twist`).
///
/// # Safety
/// `planner` is NULL or a live planner; `plan` is NULL or a live plan; `out` is NULL or
/// writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn h2n_planner_command(
    planner: *const h2n_planner,
    plan: *const h2n_plan,
    t: f64,
    pose: h2n_pose,
    velocity: h2n_twist,
    control_dt: f64,
    out: *mut h2n_twist,
) -> h2n_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (p, plan, out) = unsafe {
            (
                required_ref(planner, "planner")?,
                required_ref(plan, "plan")?,
                required_out(out, "out")?,
            )
        };
        finite("t", &[t])?;
        finite("pose", &[pose.x, pose.y, pose.theta])?;
        finite("velocity", &[velocity.vx, velocity.vy, velocity.omega])?;
        if !(control_dt.is_finite() && control_dt > 0.0) {
            return Err(Failure::invalid(format!(
                "control_dt {control_dt} must be finite and > 0"
            )));
        }
        let state = RobotState {
            pose: Pose2::new(pose.x, pose.y, pose.theta),
            velocity: Twist2::new(velocity.vx, velocity.vy, velocity.omega),
        };
        let raw = p.embodiment.track(&state, &plan.plan, t);
        let cmd = p.embodiment.saturate(&state, raw, control_dt);
        if !cmd.is_finite() {
            return Err(Failure::new(
                h2n_status::Plan,
                "the tracking controller produced a non-finite command",
            ));
        }
        *out = h2n_twist {
            vx: cmd.vx,
            vy: cmd.vy,
            omega: cmd.omega,
        };
        Ok(())
    })
}
