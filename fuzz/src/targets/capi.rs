//! The C API (`human2nav-capi`) through its Rust library: the `extern "C"` functions are called
//! as `unsafe` functions, with the arguments a C program could pass.
//!
//! * `capi_create`: `h2n_planner_create_from_strings` with a fuzzed robot profile and planner
//!   configuration (the input is the profile's text, then optionally [`SEPARATOR`] and the
//!   configuration's), the shipped URDF as text or read through the profile's `urdf` key, and
//!   now and then a NULL or missing argument. A planner that is created plans an ordinary
//!   observation.
//! * `capi_plan`: one planner created once per process from the shipped Diablo profile, the
//!   shipped `planner.toml` and the shipped model, and `h2n_planner_plan` with observations
//!   built from the input: any f64 (NaN, infinities, 1e300, subnormals, raw bits) in every
//!   number, agent and obstacle counts up to and past the caps, NULL arrays with a count,
//!   unknown obstacle kinds, polygons with too few, too many or NULL vertices, NULL arguments,
//!   and budgets that are 0, tiny, huge, negative or NaN. A plan that comes back is read with
//!   `h2n_plan_get_info`, `h2n_plan_poses` (buffers too small, exact, larger, NULL),
//!   `h2n_plan_pose_at` and `h2n_planner_command` with fuzzed arguments.
//!
//! Both assert what the header promises: a status comes back (a panic inside the library is
//! `H2N_STATUS_PANIC`, which the targets count as a failure), every successful output is
//! finite, a failure leaves `h2n_last_error()` non-empty and the output unwritten, and a bad
//! call never makes the planner refuse the next good one.

use super::observe::Draw;
use crate::{Scratch, Target};
use human2nav_c::{
    H2N_MAX_AGENTS, H2N_MAX_OBSTACLES, h2n_agent, h2n_last_error, h2n_observation, h2n_obstacle,
    h2n_plan, h2n_plan_free, h2n_plan_get_info, h2n_plan_info, h2n_plan_notes, h2n_plan_pose_at,
    h2n_plan_poses, h2n_planner, h2n_planner_command, h2n_planner_create,
    h2n_planner_create_from_strings, h2n_planner_free, h2n_planner_limits, h2n_planner_plan,
    h2n_planner_reset, h2n_pose, h2n_status, h2n_twist,
};
use human2nav_core::obstacle::MAX_POLYGON_VERTICES;
use std::ffi::{CStr, CString, c_char};
use std::sync::{Mutex, OnceLock};

const ROBOT_TOML: &str = include_str!("../../../robots/diablo/robot.toml");
const URDF: &str = include_str!("../../../robots/diablo/diablo.urdf");
const PLANNER_TOML: &str = include_str!("../../../sdk/configs/planner.toml");
const ROBOT_PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../robots/diablo/robot.toml");
const PLANNER_PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../sdk/configs/planner.toml");
const MODEL_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/human2nav-cfm");

/// Separates the robot profile from the planner configuration in a `capi_create` input.
pub const SEPARATOR: &str = "\n#== planner.toml ==\n";

pub(crate) fn targets() -> Vec<Target> {
    vec![
        Target {
            name: "capi_create",
            covers: "h2n_planner_create_from_strings (C API) with a fuzzed robot.toml and \
                     planner.toml as texts, the shipped URDF and model, NULL and missing \
                     arguments: a status, a message on failure, a planner that plans on success",
            seeds: || {
                vec![
                    format!("{ROBOT_TOML}{SEPARATOR}{PLANNER_TOML}").into_bytes(),
                    ROBOT_TOML.as_bytes().to_vec(),
                    format!("{ROBOT_TOML}{SEPARATOR}").into_bytes(),
                ]
            },
            exec: capi_create,
        },
        Target {
            name: "capi_plan",
            covers: "h2n_planner_plan (C API) on the shipped Diablo planner with observations \
                     of any f64 (NaN/inf/1e300/raw bits), counts past the caps, NULL arrays, bad \
                     obstacle kinds and vertex counts, hostile budgets; then h2n_plan_get_info, \
                     h2n_plan_poses with wrong buffer sizes, h2n_plan_pose_at and \
                     h2n_planner_command: finite outputs, a message on every failure, never \
                     poisoned",
            seeds: || {
                vec![
                    vec![0u8; 96],
                    (0u8..=255).collect(),
                    (0u8..=255).rev().cycle().take(700).collect(),
                ]
            },
            exec: capi_plan,
        },
    ]
}

/// `text` as C sees it: up to its first NUL.
fn c_string(text: &str) -> CString {
    let head = text.split('\0').next().unwrap_or_default();
    CString::new(head).unwrap_or_default()
}

fn last_error() -> String {
    // SAFETY: h2n_last_error returns a valid NUL-terminated string (never NULL).
    unsafe { CStr::from_ptr(h2n_last_error()) }
        .to_string_lossy()
        .into_owned()
}

/// Asserts a failed call left a message, and that no panic crossed into a status.
fn failed(call: &str, status: h2n_status) {
    let message = last_error();
    assert!(
        status != h2n_status::Panic && status != h2n_status::Poisoned,
        "{call} returned {status:?}: {message}"
    );
    assert!(
        !message.is_empty(),
        "{call} returned {status:?} with an empty h2n_last_error()"
    );
}

fn ptr(s: &Option<CString>) -> *const c_char {
    s.as_ref().map_or(std::ptr::null(), |c| c.as_ptr())
}

fn capi_create(_: &Scratch, input: &[u8]) {
    let text = String::from_utf8_lossy(input);
    let (robot, planner) = match text.split_once(SEPARATOR) {
        Some((r, p)) => (r, Some(p)),
        None => (&*text, None),
    };
    let choice = crate::fnv(input);
    let robot = (choice % 64 != 0).then(|| c_string(robot));
    let planner = planner.map(c_string);
    // The URDF as text, or (one in eight) read from the file the profile names.
    let urdf = (choice / 64 % 8 != 0).then(|| c_string(URDF));
    let source = match choice / 512 % 8 {
        0 => None,
        1 => Some(c_string("/nonexistent/robot.toml")),
        _ => Some(c_string(ROBOT_PATH)),
    };
    let model = match choice / 4096 % 16 {
        0 => None,
        1 => Some(c_string("/nonexistent/model")),
        _ => Some(c_string(MODEL_DIR)),
    };
    let null_out = choice / 65536 % 64 == 0;
    let mut out: *mut h2n_planner = std::ptr::null_mut();
    // SAFETY: every string is NULL or NUL-terminated and outlives the call; `out` is writable.
    let status = unsafe {
        h2n_planner_create_from_strings(
            ptr(&robot),
            ptr(&urdf),
            ptr(&planner),
            ptr(&model),
            ptr(&source),
            if null_out {
                std::ptr::null_mut()
            } else {
                &mut out
            },
        )
    };
    if status != h2n_status::Ok {
        failed("h2n_planner_create_from_strings", status);
        assert!(out.is_null(), "a failed create wrote its output");
        return;
    }
    assert!(
        !out.is_null(),
        "h2n_planner_create_from_strings: OK and a NULL planner"
    );
    // A planner that was created plans an ordinary observation (one in four: loading the
    // model is most of a case's time already).
    if choice / 4_194_304 % 4 == 0 {
        let agents = ordinary_agents();
        let obs = ordinary(&agents);
        // SAFETY: `out` is a live planner; `obs` and its agents outlive the call.
        let r = unsafe { plan_once(out, &obs, 0.0) };
        if let Err((status, message)) = r {
            // A fuzzed configuration may refuse observations (a budget it cannot meet is still
            // a plan); what it must not do is panic.
            assert!(
                status != h2n_status::Panic && !message.is_empty(),
                "a planner created from fuzzed texts failed to plan: {status:?} {message}"
            );
        }
    }
    // SAFETY: created above, freed once.
    unsafe { h2n_planner_free(out) };
}

/// Plans `obs` and checks the plan is finite; frees it. `Err`: the status and message.
///
/// # Safety
/// `planner` is a live planner.
unsafe fn plan_once(
    planner: *mut h2n_planner,
    obs: &h2n_observation,
    budget_ms: f64,
) -> Result<(), (h2n_status, String)> {
    let mut plan: *mut h2n_plan = std::ptr::null_mut();
    // SAFETY: the caller's planner; `obs` is a valid observation; `plan` is writable.
    let status = unsafe { h2n_planner_plan(planner, obs, budget_ms, &mut plan) };
    if status != h2n_status::Ok {
        return Err((status, last_error()));
    }
    // SAFETY: a plan just returned.
    let poses = unsafe { finite_plan(plan) };
    // SAFETY: freed once.
    unsafe { h2n_plan_free(plan) };
    assert!(poses > 0, "an OK plan has no poses");
    Ok(())
}

/// Reads a plan's info and poses and asserts they are finite; returns the pose count.
///
/// # Safety
/// `plan` is a live plan.
unsafe fn finite_plan(plan: *const h2n_plan) -> usize {
    assert!(!plan.is_null(), "h2n_planner_plan: OK and a NULL plan");
    let mut info = std::mem::MaybeUninit::<h2n_plan_info>::uninit();
    // SAFETY: a live plan, a writable info.
    let status = unsafe { h2n_plan_get_info(plan, info.as_mut_ptr()) };
    assert_eq!(
        status,
        h2n_status::Ok,
        "h2n_plan_get_info: {}",
        last_error()
    );
    // SAFETY: written on OK.
    let info = unsafe { info.assume_init() };
    assert!(
        info.t0.is_finite() && info.dt.is_finite() && info.dt > 0.0 && info.pose_count > 0,
        "an OK plan's info is not finite: {info:?}"
    );
    let mut poses = vec![h2n_pose::default(); info.pose_count];
    let mut written = 0usize;
    // SAFETY: `poses` holds `pose_count` poses.
    let status = unsafe { h2n_plan_poses(plan, poses.as_mut_ptr(), poses.len(), &mut written) };
    assert_eq!(status, h2n_status::Ok, "h2n_plan_poses: {}", last_error());
    assert_eq!(written, info.pose_count);
    assert!(
        poses
            .iter()
            .all(|p| p.x.is_finite() && p.y.is_finite() && p.theta.is_finite()),
        "an OK plan has a non-finite pose: {poses:?}"
    );
    // SAFETY: a live plan; the notes are a NUL-terminated string it owns.
    assert!(!unsafe { h2n_plan_notes(plan) }.is_null());
    info.pose_count
}

fn ordinary_agents() -> [h2n_agent; 2] {
    [
        h2n_agent {
            id: 1,
            x: 2.0,
            y: 0.6,
            vx: -0.8,
            vy: 0.0,
            radius: 0.3,
        },
        h2n_agent {
            id: 2,
            x: 3.5,
            y: -1.0,
            vx: 0.0,
            vy: 0.5,
            radius: 0.25,
        },
    ]
}

/// An ordinary observation: the robot at the origin, a goal 4 m ahead, two pedestrians.
fn ordinary(agents: &[h2n_agent]) -> h2n_observation {
    h2n_observation {
        time: 0.0,
        ego: h2n_pose::default(),
        ego_velocity: h2n_twist::default(),
        goal_x: 4.0,
        goal_y: 0.5,
        agents: agents.as_ptr(),
        agent_count: agents.len(),
        obstacles: std::ptr::null(),
        obstacle_count: 0,
    }
}

/// The planner `capi_plan` shares across cases.
struct Shared(*mut h2n_planner);

// SAFETY: a planner may move between threads (the header's threads rule); the mutex lets one
// thread use it at a time.
unsafe impl Send for Shared {}

fn create_shipped() -> *mut h2n_planner {
    let (robot, planner, model) = (
        c_string(ROBOT_PATH),
        c_string(PLANNER_PATH),
        c_string(MODEL_DIR),
    );
    let mut out = std::ptr::null_mut();
    // SAFETY: NUL-terminated strings that outlive the call, a writable output.
    let status =
        unsafe { h2n_planner_create(robot.as_ptr(), planner.as_ptr(), model.as_ptr(), &mut out) };
    assert_eq!(
        status,
        h2n_status::Ok,
        "the shipped planner does not load: {}",
        last_error()
    );
    out
}

fn shared() -> &'static Mutex<Shared> {
    static SHARED: OnceLock<Mutex<Shared>> = OnceLock::new();
    SHARED.get_or_init(|| Mutex::new(Shared(create_shipped())))
}

/// How far one `capi_plan` input got (the bounded test checks both outcomes occur).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Reached {
    /// The status of `h2n_planner_plan`.
    pub status: Option<h2n_status>,
    /// The message of a failed call (its start).
    pub message: Option<String>,
}

fn capi_plan(_: &Scratch, input: &[u8]) {
    let _ = run_plan(input);
}

/// One extreme budget (ms).
fn hostile_budget(d: &mut Draw<'_>) -> f64 {
    match d.u8() % 10 {
        0 => f64::NAN,
        1 => f64::INFINITY,
        2 => f64::NEG_INFINITY,
        3 => -1.0,
        4 => 1e300,
        5 => f64::from_bits(1),
        6 => 1e9,
        7 => f64::MAX,
        8 => -0.0,
        _ => f64::from_bits(d.u64()),
    }
}

/// Feeds one input to `h2n_planner_plan` and the plan readers (module docs); panics on a
/// broken promise.
pub fn run_plan(input: &[u8]) -> Reached {
    let hostile = [0, 0, 64, 16, 4, 1][usize::from(input.first().copied().unwrap_or(0) % 6)];
    let mut d = Draw {
        b: input.get(1..).unwrap_or(&[]),
        i: 0,
        hostile,
    };
    let time = d.f64();
    let ego = h2n_pose {
        x: d.f64(),
        y: d.f64(),
        theta: d.f64(),
    };
    let ego_velocity = h2n_twist {
        vx: d.f64(),
        vy: d.f64(),
        omega: d.f64(),
    };
    let (goal_x, goal_y) = (d.f64(), d.f64());

    // Agents: an array of the count, or a NULL array with a count, or a count past the cap.
    let agent_mode = d.u8() % 16;
    let n = d.count(12, 300);
    let agents: Vec<h2n_agent> = (0..n)
        .map(|k| h2n_agent {
            id: if d.u8() % 8 == 0 { 7 } else { k as u64 },
            x: d.f64(),
            y: d.f64(),
            vx: d.f64(),
            vy: d.f64(),
            radius: if d.u8() % 16 == 0 {
                -0.3
            } else {
                d.f64().abs() / 16.0
            },
        })
        .collect();
    let (agents_ptr, agent_count) = match agent_mode {
        0 => (std::ptr::null(), n.max(1)),
        1 => (std::ptr::null(), H2N_MAX_AGENTS + 1 + usize::from(d.u16())),
        2 => (std::ptr::null(), usize::MAX),
        _ if n == 0 && d.u8() % 2 == 0 => (std::ptr::null(), 0),
        _ => (agents.as_ptr(), agents.len()),
    };

    // Obstacles of every kind (and some that are none), polygons with any vertex count.
    let obstacle_mode = d.u8() % 16;
    let mut vertex_buffers: Vec<Vec<f64>> = Vec::new();
    let m = d.count(3, 40);
    let obstacles: Vec<h2n_obstacle> = (0..m)
        .map(|_| {
            let kind = match d.u8() % 16 {
                0..=4 => 0,
                5..=8 => 1,
                9..=13 => 2,
                14 => [3, -1, i32::MAX, i32::MIN][usize::from(d.u8() % 4)],
                _ => d.u64() as i32,
            };
            let (vertices, vertex_count) = if kind == 2 {
                let count = match d.u8() % 8 {
                    0 => usize::from(d.u8() % 3),
                    1 => MAX_POLYGON_VERTICES + 1 + usize::from(d.u8()),
                    2 => 3 + usize::from(d.u16()) % (MAX_POLYGON_VERTICES - 2),
                    _ => 3 + usize::from(d.u8() % 6),
                };
                if d.u8() % 16 == 0 {
                    (std::ptr::null(), count)
                } else {
                    // A regular polygon (its numbers may be extremes), or any numbers.
                    let (cx, cy, r) = (d.f64(), d.f64(), 0.2 + d.f64().abs() / 8.0);
                    let raw = d.u8() % 8 == 0;
                    let xy: Vec<f64> = (0..count)
                        .flat_map(|k| {
                            let a = std::f64::consts::TAU * k as f64 / count as f64;
                            [cx + r * a.cos(), cy + r * a.sin()]
                        })
                        .map(|v| if raw { d.f64() } else { v })
                        .collect();
                    vertex_buffers.push(xy);
                    let xy = vertex_buffers.last().map_or(std::ptr::null(), Vec::as_ptr);
                    (xy, count)
                }
            } else {
                (std::ptr::null(), usize::from(d.u8()))
            };
            h2n_obstacle {
                kind,
                x0: d.f64(),
                y0: d.f64(),
                x1: d.f64(),
                y1: d.f64(),
                radius: d.f64(),
                vertices,
                vertex_count,
            }
        })
        .collect();
    let (obstacles_ptr, obstacle_count) = match obstacle_mode {
        0 => (std::ptr::null(), m.max(1)),
        1 => (
            std::ptr::null(),
            H2N_MAX_OBSTACLES + 1 + usize::from(d.u16()),
        ),
        2 => (std::ptr::null(), usize::MAX),
        _ if m == 0 => (std::ptr::null(), 0),
        _ => (obstacles.as_ptr(), obstacles.len()),
    };
    let obs = h2n_observation {
        time,
        ego,
        ego_velocity,
        goal_x,
        goal_y,
        agents: agents_ptr,
        agent_count,
        obstacles: obstacles_ptr,
        obstacle_count,
    };
    let budget_ms = match d.u8() % 8 {
        0..=3 => 0.0,
        4 => hostile_budget(&mut d),
        5 => d.f64(),
        6 => 1.0 + f64::from(d.u8() % 50),
        _ => 0.001,
    };
    let nulls = d.u8() % 32;

    let mut guard = shared().lock().unwrap_or_else(|p| p.into_inner());
    let planner = guard.0;
    if d.u8() % 32 == 0 {
        // SAFETY: a live planner.
        let status = unsafe { h2n_planner_reset(planner) };
        assert_eq!(
            status,
            h2n_status::Ok,
            "h2n_planner_reset: {}",
            last_error()
        );
    }
    let mut plan: *mut h2n_plan = std::ptr::null_mut();
    // SAFETY: the planner is live and used by this thread only (the mutex); `obs` and every
    // array it points to outlive the call, and each non-NULL array holds its count (a NULL
    // one, or a count past a cap, the library refuses before reading).
    let status = unsafe {
        h2n_planner_plan(
            if nulls == 0 {
                std::ptr::null_mut()
            } else {
                planner
            },
            if nulls == 1 { std::ptr::null() } else { &obs },
            budget_ms,
            if nulls == 2 {
                std::ptr::null_mut()
            } else {
                &mut plan
            },
        )
    };
    let mut reached = Reached {
        status: Some(status),
        message: None,
    };
    if status == h2n_status::Panic {
        // The planner is poisoned: replace it for the next case (the long run goes on), then
        // fail this one.
        let message = last_error();
        // SAFETY: the old planner is freed once and replaced.
        unsafe { h2n_planner_free(planner) };
        guard.0 = create_shipped();
        panic!("h2n_planner_plan panicked: {message}");
    }
    if status != h2n_status::Ok {
        failed("h2n_planner_plan", status);
        assert!(plan.is_null(), "a failed h2n_planner_plan wrote its output");
        reached.message = Some(last_error().chars().take(80).collect());
        // The refusal left the planner usable: an ordinary observation still plans.
        let ordinary_agents = ordinary_agents();
        // SAFETY: a live planner; the observation's agents outlive the call.
        let r = unsafe { plan_once(planner, &ordinary(&ordinary_agents), 0.0) };
        if let Err((status, message)) = r {
            panic!(
                "after a refused observation, an ordinary one fails: {status:?} {message} \
                 (refused with: {:?})",
                reached.message
            );
        }
        return reached;
    }

    // SAFETY: an OK plan.
    let n = unsafe { finite_plan(plan) };
    read_plan(&mut d, planner, plan, n);
    // SAFETY: freed once.
    unsafe { h2n_plan_free(plan) };
    reached
}

/// The plan readers and the tracking controller with fuzzed arguments.
fn read_plan(d: &mut Draw<'_>, planner: *mut h2n_planner, plan: *mut h2n_plan, n: usize) {
    // Buffers too small, exact, larger, or NULL; `written` NULL now and then.
    let capacity = match d.u8() % 6 {
        0 => 0,
        1 => n - 1,
        2 => n + 1 + usize::from(d.u8()),
        3 => usize::MAX,
        _ => n,
    };
    let buffer_null = capacity == usize::MAX || d.u8() % 16 == 0;
    let mut buffer = vec![h2n_pose::default(); if buffer_null { 0 } else { capacity }];
    let out = if buffer_null {
        std::ptr::null_mut()
    } else {
        buffer.as_mut_ptr()
    };
    let written_null = d.u8() % 16 == 0;
    let mut written = usize::MAX;
    // SAFETY: `out` is NULL or holds `capacity` poses; `written` is NULL or writable.
    let status = unsafe {
        h2n_plan_poses(
            plan,
            out,
            capacity,
            if written_null {
                std::ptr::null_mut()
            } else {
                &mut written
            },
        )
    };
    let expected = if written_null {
        h2n_status::InvalidArgument
    } else if capacity < n {
        h2n_status::BufferTooSmall
    } else if buffer_null {
        h2n_status::InvalidArgument
    } else {
        h2n_status::Ok
    };
    assert_eq!(
        status,
        expected,
        "h2n_plan_poses with capacity {capacity} for {n} poses (out NULL {buffer_null}, \
         written NULL {written_null}): {}",
        last_error()
    );
    if status == h2n_status::Ok {
        assert_eq!(written, n);
    } else {
        failed("h2n_plan_poses", status);
        assert_eq!(
            written,
            usize::MAX,
            "a failed h2n_plan_poses wrote `written`"
        );
    }

    // The pose at any time.
    let t = d.f64();
    let mut pose = h2n_pose::default();
    // SAFETY: a live plan, a writable pose.
    let status = unsafe { h2n_plan_pose_at(plan, t, &mut pose) };
    if status == h2n_status::Ok {
        assert!(
            t.is_finite() && pose.x.is_finite() && pose.y.is_finite() && pose.theta.is_finite(),
            "h2n_plan_pose_at({t}) returned {pose:?}"
        );
    } else {
        failed("h2n_plan_pose_at", status);
    }

    // The command from any state.
    let state = h2n_pose {
        x: d.f64(),
        y: d.f64(),
        theta: d.f64(),
    };
    let velocity = h2n_twist {
        vx: d.f64(),
        vy: d.f64(),
        omega: d.f64(),
    };
    let control_dt = match d.u8() % 4 {
        0 => hostile_budget(d),
        1 => d.f64(),
        _ => 0.05,
    };
    let mut command = h2n_twist::default();
    // SAFETY: a live planner and plan, a writable twist.
    let status = unsafe {
        h2n_planner_command(
            planner,
            plan,
            d.f64(),
            state,
            velocity,
            control_dt,
            &mut command,
        )
    };
    if status == h2n_status::Ok {
        assert!(
            command.vx.is_finite() && command.vy.is_finite() && command.omega.is_finite(),
            "h2n_planner_command returned {command:?}"
        );
    } else {
        failed("h2n_planner_command", status);
    }

    // The limits, and the readers with NULL outputs.
    let mut limits = std::mem::MaybeUninit::uninit();
    // SAFETY: a live planner, a writable output.
    let status = unsafe { h2n_planner_limits(planner, limits.as_mut_ptr()) };
    assert_eq!(
        status,
        h2n_status::Ok,
        "h2n_planner_limits: {}",
        last_error()
    );
    if d.u8() % 8 == 0 {
        // SAFETY: NULL outputs are refused before anything is written.
        let statuses = unsafe {
            [
                h2n_plan_get_info(plan, std::ptr::null_mut()),
                h2n_plan_get_info(std::ptr::null(), std::ptr::null_mut()),
                h2n_plan_pose_at(plan, 0.0, std::ptr::null_mut()),
                h2n_planner_command(
                    planner,
                    std::ptr::null(),
                    0.0,
                    state,
                    velocity,
                    0.05,
                    &mut command,
                ),
            ]
        };
        for status in statuses {
            assert_eq!(status, h2n_status::InvalidArgument);
            failed("a reader with a NULL argument", status);
        }
    }
}
