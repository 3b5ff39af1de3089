//! Every entry point of the C API refuses bad arguments with a status and a message naming
//! the argument, and writes nothing.

use human2nav_c::*;
use std::ffi::{CStr, CString, c_char};
use std::path::PathBuf;
use std::ptr::{null, null_mut};

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn c(path: PathBuf) -> CString {
    CString::new(path.to_string_lossy().into_owned()).expect("no NUL in the path")
}

fn last_error() -> String {
    // SAFETY: h2n_last_error returns a valid NUL-terminated string.
    unsafe { CStr::from_ptr(h2n_last_error()) }
        .to_string_lossy()
        .into_owned()
}

/// `status` is `expected` and the message contains `needle`.
fn refused(status: h2n_status, expected: h2n_status, needle: &str) {
    assert_eq!(status, expected, "{}", last_error());
    let message = last_error();
    assert!(message.contains(needle), "`{needle}` not in `{message}`");
}

fn robot() -> CString {
    c(workspace().join("robots/diablo/robot.toml"))
}

fn model() -> CString {
    c(workspace().join("models/human2nav-cfm"))
}

fn planner() -> *mut h2n_planner {
    let mut p = null_mut();
    // SAFETY: valid strings and out pointer.
    let status = unsafe { h2n_planner_create(robot().as_ptr(), null(), model().as_ptr(), &mut p) };
    assert_eq!(status, h2n_status::Ok, "{}", last_error());
    p
}

/// A change that makes an observation invalid.
type Spoil = Box<dyn Fn(&mut h2n_observation)>;

fn observation(agents: &[h2n_agent]) -> h2n_observation {
    h2n_observation {
        time: 0.0,
        ego: h2n_pose::default(),
        ego_velocity: h2n_twist::default(),
        goal_x: 4.0,
        goal_y: 0.0,
        agents: agents.as_ptr(),
        agent_count: agents.len(),
        obstacles: std::ptr::null(),
        obstacle_count: 0,
    }
}

#[test]
fn creating_a_planner_refuses_nulls_bad_files_and_unknown_keys() {
    let mut out = null_mut();
    let none: *const c_char = null();
    // SAFETY (whole test): every pointer is NULL or valid.
    unsafe {
        refused(
            h2n_planner_create(none, none, model().as_ptr(), &mut out),
            h2n_status::InvalidArgument,
            "robot_toml is NULL",
        );
        refused(
            h2n_planner_create(robot().as_ptr(), none, none, &mut out),
            h2n_status::InvalidArgument,
            "model_dir is NULL",
        );
        refused(
            h2n_planner_create(robot().as_ptr(), none, model().as_ptr(), null_mut()),
            h2n_status::InvalidArgument,
            "out is NULL",
        );
        let bad_utf8 = [0xffu8, 0xfe, 0];
        refused(
            h2n_planner_create(bad_utf8.as_ptr().cast(), none, model().as_ptr(), &mut out),
            h2n_status::InvalidArgument,
            "robot_toml is not UTF-8",
        );
        let missing = c(workspace().join("models/no-such-model"));
        refused(
            h2n_planner_create(robot().as_ptr(), none, missing.as_ptr(), &mut out),
            h2n_status::Model,
            "no-such-model",
        );
        let toml = std::fs::read_to_string(workspace().join("robots/diablo/robot.toml"))
            .expect("diablo profile");
        let urdf = std::fs::read_to_string(workspace().join("robots/diablo/diablo.urdf"))
            .expect("diablo URDF");
        let (toml, urdf) = (
            CString::new(toml).expect("text"),
            CString::new(urdf).expect("text"),
        );
        let unknown = CString::new("[human2nav]\nsamplez = 3\n").expect("text");
        refused(
            h2n_planner_create_from_strings(
                toml.as_ptr(),
                urdf.as_ptr(),
                unknown.as_ptr(),
                model().as_ptr(),
                none,
                &mut out,
            ),
            h2n_status::Config,
            "samplez",
        );
        let out_of_range = CString::new("[human2nav]\nbudget_ms = -1\n").expect("text");
        refused(
            h2n_planner_create_from_strings(
                toml.as_ptr(),
                urdf.as_ptr(),
                out_of_range.as_ptr(),
                model().as_ptr(),
                none,
                &mut out,
            ),
            h2n_status::Config,
            "budget_ms",
        );
        let broken_urdf = CString::new("<robot name='x'>").expect("text");
        refused(
            h2n_planner_create_from_strings(
                toml.as_ptr(),
                broken_urdf.as_ptr(),
                none,
                model().as_ptr(),
                none,
                &mut out,
            ),
            h2n_status::Config,
            "urdf",
        );
        assert!(out.is_null(), "nothing is written on failure");
        // The profile and URDF as texts give a working planner.
        let status = h2n_planner_create_from_strings(
            toml.as_ptr(),
            urdf.as_ptr(),
            none,
            model().as_ptr(),
            none,
            &mut out,
        );
        assert_eq!(status, h2n_status::Ok, "{}", last_error());
        h2n_planner_free(out);
        h2n_planner_free(null_mut());
    }
}

#[test]
fn planning_refuses_bad_observations_and_budgets() {
    let p = planner();
    let people = [h2n_agent {
        id: 3,
        x: 2.0,
        y: 0.5,
        vx: -0.5,
        vy: 0.0,
        radius: 0.3,
    }];
    let mut plan = null_mut();
    // SAFETY (whole test): every pointer is NULL or valid; `agents` arrays match their counts
    // unless the case is about that.
    unsafe {
        let obs = observation(&people);
        refused(
            h2n_planner_plan(null_mut(), &obs, 0.0, &mut plan),
            h2n_status::InvalidArgument,
            "planner is NULL",
        );
        refused(
            h2n_planner_plan(p, null(), 0.0, &mut plan),
            h2n_status::InvalidArgument,
            "obs is NULL",
        );
        refused(
            h2n_planner_plan(p, &obs, 0.0, null_mut()),
            h2n_status::InvalidArgument,
            "out is NULL",
        );
        for budget in [-1.0, f64::NAN, f64::INFINITY, 1e22, 6e4 + 1.0] {
            refused(
                h2n_planner_plan(p, &obs, budget, &mut plan),
                h2n_status::InvalidArgument,
                "budget_ms",
            );
        }
        let circle = h2n_obstacle {
            kind: h2n_obstacle_kind::Circle as i32,
            x0: 1.0,
            y0: 0.0,
            x1: 0.0,
            y1: 0.0,
            radius: -1.0,
            vertices: null(),
            vertex_count: 0,
        };
        let bad_circle: *const h2n_obstacle = &circle;
        let cases: [(&str, Spoil); 10] = [
            ("observation.time", Box::new(|o| o.time = f64::NAN)),
            (
                "ego pose is more than 1000000 m",
                Box::new(|o| o.ego.x = 1e300),
            ),
            (
                "ego velocity is faster than 30 m/s",
                Box::new(|o| o.ego_velocity.vx = 100.0),
            ),
            ("observation.ego", Box::new(|o| o.ego.theta = f64::INFINITY)),
            (
                "observation.ego_velocity",
                Box::new(|o| o.ego_velocity.vx = f64::NAN),
            ),
            ("observation.goal", Box::new(|o| o.goal_y = f64::NAN)),
            (
                "observation.agents is NULL",
                Box::new(|o| o.agents = null()),
            ),
            (
                "more than 10000",
                Box::new(|o| o.agent_count = H2N_MAX_AGENTS + 1),
            ),
            (
                "observation.obstacles is NULL but obstacle_count is 1",
                Box::new(|o| o.obstacle_count = 1),
            ),
            (
                "obstacles[0]: radius -1",
                Box::new(move |o| {
                    o.obstacles = bad_circle;
                    o.obstacle_count = 1;
                }),
            ),
        ];
        for (needle, spoil) in cases {
            let mut bad = observation(&people);
            spoil(&mut bad);
            refused(
                h2n_planner_plan(p, &bad, 0.0, &mut plan),
                h2n_status::InvalidArgument,
                needle,
            );
        }
        let mut nan_person = people;
        nan_person[0].vy = f64::NAN;
        refused(
            h2n_planner_plan(p, &observation(&nan_person), 0.0, &mut plan),
            h2n_status::InvalidArgument,
            "observation.agents[0] (id 3)",
        );
        let mut negative = people;
        negative[0].radius = -0.1;
        refused(
            h2n_planner_plan(p, &observation(&negative), 0.0, &mut plan),
            h2n_status::InvalidArgument,
            "negative",
        );
        assert!(plan.is_null(), "nothing is written on failure");
        h2n_planner_free(p);
    }
}

#[test]
fn reading_a_plan_refuses_nulls_small_buffers_and_bad_numbers() {
    let p = planner();
    let mut plan = null_mut();
    // SAFETY (whole test): every pointer is NULL or valid.
    unsafe {
        let status = h2n_planner_plan(p, &observation(&[]), 0.0, &mut plan);
        assert_eq!(status, h2n_status::Ok, "{}", last_error());
        let mut info = std::mem::MaybeUninit::<h2n_plan_info>::uninit();
        refused(
            h2n_plan_get_info(null(), info.as_mut_ptr()),
            h2n_status::InvalidArgument,
            "plan is NULL",
        );
        refused(
            h2n_plan_get_info(plan, null_mut()),
            h2n_status::InvalidArgument,
            "out is NULL",
        );
        assert_eq!(h2n_plan_get_info(plan, info.as_mut_ptr()), h2n_status::Ok);
        let info = info.assume_init();
        assert!(info.pose_count > 1 && !info.fallback);
        assert_eq!(info.cut_short, h2n_stage::None);

        let mut poses = vec![h2n_pose::default(); info.pose_count];
        let mut written = 0usize;
        refused(
            h2n_plan_poses(plan, poses.as_mut_ptr(), 2, &mut written),
            h2n_status::BufferTooSmall,
            "out holds 2 poses",
        );
        refused(
            h2n_plan_poses(plan, null_mut(), poses.len(), &mut written),
            h2n_status::InvalidArgument,
            "out is NULL",
        );
        refused(
            h2n_plan_poses(plan, poses.as_mut_ptr(), poses.len(), null_mut()),
            h2n_status::InvalidArgument,
            "written is NULL",
        );
        assert_eq!(written, 0);
        let status = h2n_plan_poses(plan, poses.as_mut_ptr(), poses.len(), &mut written);
        assert_eq!(status, h2n_status::Ok);
        assert_eq!(written, info.pose_count);
        assert!(
            poses
                .iter()
                .all(|q| q.x.is_finite() && q.y.is_finite() && q.theta.is_finite())
        );

        let mut pose = h2n_pose::default();
        refused(
            h2n_plan_pose_at(plan, f64::NAN, &mut pose),
            h2n_status::InvalidArgument,
            "t is not finite",
        );
        let mut cmd = h2n_twist::default();
        let here = h2n_pose::default();
        let still = h2n_twist::default();
        refused(
            h2n_planner_command(p, plan, 0.1, here, still, 0.0, &mut cmd),
            h2n_status::InvalidArgument,
            "control_dt",
        );
        refused(
            h2n_planner_command(null(), plan, 0.1, here, still, 0.1, &mut cmd),
            h2n_status::InvalidArgument,
            "planner is NULL",
        );
        let lost = h2n_pose {
            x: f64::NAN,
            ..here
        };
        refused(
            h2n_planner_command(p, plan, 0.1, lost, still, 0.1, &mut cmd),
            h2n_status::InvalidArgument,
            "pose is not finite",
        );
        assert_eq!(
            h2n_planner_command(p, plan, 0.1, here, still, 0.1, &mut cmd),
            h2n_status::Ok
        );
        assert!(cmd.vx.is_finite() && cmd.omega.is_finite());
        let mut limits = std::mem::MaybeUninit::<h2n_limits>::uninit();
        assert_eq!(h2n_planner_limits(p, limits.as_mut_ptr()), h2n_status::Ok);
        assert!(
            limits.assume_init().kappa_max.is_infinite(),
            "diablo has no curvature limit"
        );
        refused(
            h2n_planner_reset(null_mut()),
            h2n_status::InvalidArgument,
            "planner is NULL",
        );
        assert!(CStr::from_ptr(h2n_plan_notes(null())).to_bytes().is_empty());
        h2n_plan_free(plan);
        h2n_plan_free(null_mut());
        h2n_planner_free(p);
    }
}
