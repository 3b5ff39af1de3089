//! The plugin ABI end to end: the real `cdylib`s built by the workspace are loaded with the host
//! and used through their proxies. Run after `cargo build --workspace` (as `sdk/dev.sh test`
//! does); a missing library fails with a message saying so.

use approx::assert_relative_eq;
use human2nav_core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::{
    AgentState, ControllerGains, Limits, Observation, Plan, PlanError, PlanInfo, Planner, Pose2,
    Twist2,
};
use human2nav_integration_tests::target_profile_dir;
use human2nav_plugin::abi::{ABI_VERSION, layout};
use human2nav_plugin::resolve::resolve_library_path;
use human2nav_plugin::{PluginError, PluginHost, PluginKind, PluginLibrary, RobotContext};
use std::path::PathBuf;

/// A workspace-built plugin library, named without prefix or extension (the host adds them).
fn lib(name: &str) -> PathBuf {
    let path = target_profile_dir().join(name);
    if let Err(e) = resolve_library_path(&path) {
        panic!(
            "{e}: build the workspace first (`cargo build --workspace`, as sdk/dev.sh test does)"
        );
    }
    path
}

fn limits() -> Limits {
    Limits {
        v_max: 1.2,
        v_reverse_max: 0.4,
        a_max: 1.0,
        omega_max: 1.5,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    }
}

fn robot() -> RobotContext {
    RobotContext {
        limits: limits(),
        gains: ControllerGains {
            k_x: 1.5,
            k_y: 4.0,
            k_theta: 3.0,
            k_d: 0.2,
            lookahead: 0.05,
        },
        footprint_radius: 0.3,
    }
}

fn agents() -> Vec<AgentState> {
    vec![
        AgentState {
            id: 7,
            position: [1.2, 0.3],
            velocity: [-0.8, 0.1],
            radius: 0.25,
            history: vec![[1.4, 0.28], [1.3, 0.29]],
        },
        AgentState {
            id: 9,
            position: [0.4, -0.9],
            velocity: [0.0, 0.9],
            radius: 0.3,
            history: vec![],
        },
    ]
}

/// A deterministic batch of `b` trajectories of `t` poses passing near the agents.
fn batch(b: usize, t: usize) -> Vec<f64> {
    let mut data = Vec::with_capacity(b * t * 3);
    for i in 0..b {
        for k in 0..t {
            let s = k as f64 / t as f64;
            let bend = (i as f64 - b as f64 / 2.0) * 0.07;
            data.extend_from_slice(&[2.0 * s, bend * (3.0 * s).sin(), 0.1 * bend]);
        }
    }
    data
}

fn evaluate(term: &dyn ConstraintTerm, data: &[f64], b: usize, t: usize) -> (Vec<f64>, Vec<f64>) {
    let l = limits();
    let a = agents();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &l,
        initial_velocity: Twist2::ZERO,
        agents: &a,
        scene: Default::default(),
    };
    let mut cost = vec![0.0; b];
    let mut grad = vec![0.0; data.len()];
    term.evaluate(
        TrajBatch::new(data, b, t).expect("batch shape"),
        &ctx,
        &mut cost,
        &mut grad,
    )
    .expect("evaluation through the proxy");
    (cost, grad)
}

/// Central differences of the per-trajectory cost.
fn check_gradient(term: &dyn ConstraintTerm, data: &[f64], b: usize, t: usize) {
    let (_, grad) = evaluate(term, data, b, t);
    let h = 1e-6;
    for i in 0..data.len() {
        let mut p = data.to_vec();
        p[i] += h;
        let (cp, _) = evaluate(term, &p, b, t);
        p[i] -= 2.0 * h;
        let (cm, _) = evaluate(term, &p, b, t);
        let traj = i / (t * 3);
        let fd = (cp[traj] - cm[traj]) / (2.0 * h);
        assert!(
            (fd - grad[i]).abs() <= 1e-7 + 1e-5 * grad[i].abs(),
            "{}: d cost / d x[{i}]: finite difference {fd}, analytic {}",
            term.name(),
            grad[i]
        );
    }
}

#[test]
fn personal_space_library_describes_itself() {
    let library = PluginLibrary::load(&lib("human2nav_personal_space")).unwrap();
    assert_eq!(library.name(), "personal_space");
    assert_eq!(library.version(), "0.1.0");
    assert_eq!(library.abi_version(), ABI_VERSION);
    let f = library.factories();
    assert_eq!(f.len(), 1);
    assert_eq!(
        (f[0].kind, f[0].name.as_str()),
        (PluginKind::Constraint, "personal_space")
    );
    // Loading again returns the same (never unloaded) library.
    let again = PluginLibrary::load(&lib("human2nav_personal_space")).unwrap();
    assert!(std::sync::Arc::ptr_eq(&library, &again));
}

#[test]
fn personal_space_through_the_boundary_matches_its_closed_form() {
    let host = PluginHost::new();
    let term = host
        .constraint(
            &lib("human2nav_personal_space"),
            "personal_space",
            "predict = false",
            Some(&robot()),
        )
        .unwrap();
    assert_eq!(term.name(), "personal_space");
    // One pose at the origin, agents frozen (predict = false): for each agent
    // d_safe = 0.3 + r + 0.5, z = γ·(1 − d/d_safe + δ), cost = Σ softplus(z)/γ.
    let (cost, grad) = evaluate(&term, &[0.0, 0.0, 0.0], 1, 1);
    let mut expected = 0.0;
    let mut g = [0.0, 0.0];
    for a in agents() {
        let d_safe = 0.3 + a.radius + 0.5;
        let (dx, dy) = (-a.position[0], -a.position[1]);
        let d = (dx * dx + dy * dy + 1e-12f64).sqrt();
        let z = 10.0 * (1.0 - d / d_safe + 0.05);
        expected += (1.0 + f64::exp(z)).ln() / 10.0;
        let sig = 1.0 / (1.0 + (-z).exp());
        g[0] -= sig * dx / (d * d_safe);
        g[1] -= sig * dy / (d * d_safe);
    }
    assert_relative_eq!(cost[0], expected, max_relative = 1e-12);
    assert_relative_eq!(grad[0], g[0], max_relative = 1e-12);
    assert_relative_eq!(grad[1], g[1], max_relative = 1e-12);
    assert_eq!(grad[2], 0.0);
}

#[test]
fn plugin_gradient_matches_finite_differences_through_the_boundary() {
    let host = PluginHost::new();
    let data = batch(4, 8);
    for library in ["human2nav_personal_space", "human2nav_c_personal_space"] {
        let name = if library.contains("_c_") {
            "personal_space_c"
        } else {
            "personal_space"
        };
        let term = host
            .constraint(&lib(library), name, "gamma = 6.0", Some(&robot()))
            .unwrap();
        let (cost, _) = evaluate(&term, &data, 4, 8);
        assert!(
            cost.iter().all(|c| *c > 1e-3),
            "the batch must pass near the agents: {cost:?}"
        );
        check_gradient(&term, &data, 4, 8);
    }
}

#[test]
fn the_custom_constraint_example_loads_and_its_gradient_holds() {
    let library = PluginLibrary::load(&lib("human2nav_proximity_speed")).unwrap();
    assert_eq!(library.name(), "proximity_speed");
    let term = PluginHost::new()
        .constraint(
            &lib("human2nav_proximity_speed"),
            "proximity_speed",
            "v_near = 0.4",
            None,
        )
        .unwrap();
    // Fast trajectories (about 2 m/s) near the agents cost something.
    let data = batch(3, 10);
    let (cost, _) = evaluate(&term, &data, 3, 10);
    assert!(cost.iter().all(|c| *c > 1e-3), "{cost:?}");
    check_gradient(&term, &data, 3, 10);
}

#[test]
fn c_plugin_computes_what_its_rust_twin_computes() {
    let host = PluginHost::new();
    let c_lib = PluginLibrary::load(&lib("human2nav_c_personal_space")).unwrap();
    assert_eq!(c_lib.name(), "personal_space_c");
    assert_eq!(c_lib.factories()[0].kind, PluginKind::Constraint);
    let configs = [
        "",
        "personal_space = 0.8\ngamma = 4\n# comment\ndelta = 0.0",
        "predict = false",
    ];
    for config in configs {
        let c = host.constraint(
            &lib("human2nav_c_personal_space"),
            "personal_space_c",
            config,
            Some(&robot()),
        );
        let r = host.constraint(
            &lib("human2nav_personal_space"),
            "personal_space",
            config,
            Some(&robot()),
        );
        let (c, r) = (c.unwrap(), r.unwrap());
        // Both declare what lets the shipped planner's selection prune (`properties`).
        assert!(c.separable_nonnegative() && r.separable_nonnegative());
        let data = batch(6, 32);
        let (cc, gc) = evaluate(&c, &data, 6, 32);
        let (cr, gr) = evaluate(&r, &data, 6, 32);
        for (a, b) in cc.iter().zip(&cr) {
            assert_relative_eq!(a, b, max_relative = 1e-12);
        }
        for (a, b) in gc.iter().zip(&gr) {
            assert_relative_eq!(a, b, max_relative = 1e-10, epsilon = 1e-15);
        }
    }
    // The C plugin also rejects unknown fields, naming them.
    let err = host
        .constraint(
            &lib("human2nav_c_personal_space"),
            "personal_space_c",
            "gama = 3",
            None,
        )
        .unwrap_err();
    assert!(matches!(err, PluginError::Config { .. }), "{err}");
    assert!(err.to_string().contains("`gama`"), "{err}");
}

/// Sizes and offsets of every ABI struct as the C compiler saw `human2nav_plugin.h`.
#[test]
fn c_header_matches_the_rust_layout() {
    let path = resolve_library_path(&lib("human2nav_c_personal_space")).unwrap();
    // SAFETY: the library is the workspace's C plugin; `h2n_c_layout` has this signature.
    let c_values = unsafe {
        let library = libloading::Library::new(&path).unwrap();
        let f: libloading::Symbol<'_, unsafe extern "C" fn(*mut usize, usize) -> usize> =
            library.get(b"h2n_c_layout").unwrap();
        let n = f(std::ptr::null_mut(), 0);
        let mut out = vec![0usize; n];
        f(out.as_mut_ptr(), n);
        // Keep the library loaded (the host's rule: never unload).
        std::mem::forget(library);
        out
    };
    let mut rust_values = Vec::new();
    let mut names = Vec::new();
    for s in layout() {
        rust_values.push(s.size);
        names.push(format!("sizeof({})", s.name));
        for (f, o) in &s.fields {
            rust_values.push(*o);
            names.push(format!("offsetof({}, {f})", s.name));
        }
    }
    assert_eq!(
        c_values.len(),
        rust_values.len(),
        "the C layout table lists other fields"
    );
    for ((c, r), what) in c_values.iter().zip(&rust_values).zip(&names) {
        assert_eq!(c, r, "{what}: C {c}, Rust {r}");
    }
}

#[test]
fn constraint_proxy_is_usable_from_several_threads() {
    let host = PluginHost::new();
    let term = host
        .constraint(&lib("human2nav_personal_space"), "personal_space", "", None)
        .unwrap();
    let data = batch(8, 32);
    let reference = evaluate(&term, &data, 8, 32);
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..4)
            .map(|_| s.spawn(|| evaluate(&term, &data, 8, 32)))
            .collect();
        for h in handles {
            assert_eq!(h.join().unwrap(), reference);
        }
    });
}

#[test]
fn constraint_shape_errors_are_reported_not_crashed() {
    let host = PluginHost::new();
    let term = host
        .constraint(&lib("human2nav_personal_space"), "personal_space", "", None)
        .unwrap();
    let l = limits();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &l,
        initial_velocity: Twist2::ZERO,
        agents: &[],
        scene: Default::default(),
    };
    let data = batch(2, 4);
    let batch = TrajBatch {
        data: &data,
        batch: 2,
        horizon: 4,
    };
    let mut cost = vec![0.0; 3];
    let mut grad = vec![0.0; data.len()];
    let err = term
        .evaluate(batch, &ctx, &mut cost, &mut grad)
        .unwrap_err();
    assert!(matches!(err, ConstraintError::Shape(_)), "{err}");
}

#[test]
fn skid_steer_embodiment_through_the_boundary() {
    let host = PluginHost::new();
    let config = "track_width = 0.5\nskid_factor = 1.4\ntrack_speed_max = 1.0";
    let e = host
        .embodiment(&lib("human2nav_skid_steer"), "skid_steer", config, &robot())
        .unwrap();
    assert_eq!(e.name(), "skid_steer");
    assert!(!e.holonomic());
    // χB/2 = 0.35: the command (1, 0.3, 1) has tracks 0.65 and 1.35 m/s; the box scales both
    // by 1/1.35 (curvature kept) and v_y is dropped. From rest, dt = 10 s: no accel limit.
    let s = e.saturate(&RobotState::default(), Twist2::new(1.0, 0.3, 1.0), 10.0);
    assert_relative_eq!(s.vx, 1.0 / 1.35, max_relative = 1e-12);
    assert_relative_eq!(s.omega, 1.0 / 1.35, max_relative = 1e-12);
    assert_eq!(s.vy, 0.0);
    // a_max·dt = 0.1 m/s from rest.
    let s = e.saturate(&RobotState::default(), Twist2::new(1.0, 0.0, 0.0), 0.1);
    assert_relative_eq!(s.vx, 0.1, max_relative = 1e-12);
    // Half a circle of radius 1 in π s ends at (0, 2).
    let next = e.step(
        &RobotState::default(),
        Twist2::new(1.0, 0.0, 1.0),
        std::f64::consts::PI,
    );
    assert_relative_eq!(next.pose.x, 0.0, epsilon = 1e-12);
    assert_relative_eq!(next.pose.y, 2.0, epsilon = 1e-12);
    // Tracking a straight plan from on the plan: feed-forward 1 m/s, no correction.
    let poses = (0..32)
        .map(|k| Pose2::new(0.1 * k as f64, 0.0, 0.0))
        .collect();
    let plan = Plan {
        t0: 0.0,
        dt: 0.1,
        poses,
        info: PlanInfo::default(),
    };
    let on_plan = RobotState {
        pose: Pose2::IDENTITY,
        velocity: Twist2::new(1.0, 0.0, 0.0),
    };
    let cmd = e.track(&on_plan, &plan, 0.0);
    assert_relative_eq!(cmd.vx, 1.0, max_relative = 1e-9);
    assert_relative_eq!(cmd.omega, 0.0, epsilon = 1e-9);
    assert!(e.failure().is_none());
}

/// Static obstacles and an occupancy grid in the observation.
fn with_obstacles(obs: &Observation) -> Observation {
    use human2nav_core::obstacle::{Obstacle, OccupancyGrid};
    Observation {
        obstacles: vec![
            Obstacle::Circle {
                center: [2.0, 3.0],
                radius: 0.4,
            },
            Obstacle::Polygon {
                vertices: vec![[4.0, 0.0], [5.0, 0.0], [5.0, 1.0], [4.0, 1.0]],
            },
            Obstacle::Segment {
                a: [0.0, 2.0],
                b: [3.0, 2.0],
            },
        ],
        occupancy: Some(OccupancyGrid {
            origin: Pose2::new(-1.0, -1.0, 0.0),
            resolution: 0.5,
            width: 4,
            height: 3,
            data: vec![0; 12],
            occupied_threshold: 65,
        }),
        ..obs.clone()
    }
}

/// ABI version 2: a planner built with this SDK sees the observation's static obstacles and
/// occupancy grid, in process and in a helper process alike.
#[test]
fn a_version_2_planner_sees_obstacles_and_the_grid() {
    use human2nav_core::robot::PluginIsolation;
    let obs = with_obstacles(&Observation {
        goal: [1.0, 5.0],
        agents: agents(),
        ..Default::default()
    });
    let want = "call 1 agents 2 history 2 obstacles 3 vertices 4 grid cells 12";
    for isolation in [PluginIsolation::InProcess, PluginIsolation::Process] {
        let mut p = PluginHost::new()
            .planner_with_options(
                &lib("human2nav_fixture_test_plugin"),
                "straight",
                "",
                None,
                None,
                isolation,
            )
            .unwrap();
        assert_eq!(
            p.plan(&obs).unwrap().info.notes,
            vec![want.to_string()],
            "{isolation:?}"
        );
    }
}

/// ORCA through the host sees a wall across its way (ABI version 2) and stops short of it
/// instead of driving through, as it did when the ABI carried no obstacles.
#[test]
fn orca_through_the_host_respects_a_wall() {
    use human2nav_core::obstacle::Obstacle;
    let mut orca = PluginHost::new()
        .planner(&lib("human2nav_orca"), "orca", "max_speed = 1.0", None)
        .unwrap();
    let open = Observation {
        ego: Pose2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        ego_velocity: Twist2::new(1.0, 0.0, 0.0),
        goal: [0.0, 6.0],
        ..Default::default()
    };
    let walled = Observation {
        obstacles: vec![Obstacle::Segment {
            a: [-5.0, 1.0],
            b: [5.0, 1.0],
        }],
        ..open.clone()
    };
    let mut end = |obs: &Observation| *orca.plan(obs).unwrap().poses.last().unwrap();
    assert!(
        end(&open).y > 3.0,
        "without the wall ORCA heads for the goal"
    );
    let stop = end(&walled);
    assert!(
        stop.y < 1.0 - 0.3,
        "ORCA's plan ends at {stop:?}, through the wall"
    );
}

/// A library built for ABI version 1 still loads and plans. It is given what version 1 knows,
/// and its plans say which obstacles it was not given.
#[test]
fn a_version_1_planner_still_loads_and_its_plans_say_what_it_missed() {
    let path = lib("human2nav_fixture_v1_planner");
    let library = PluginLibrary::load(&path).unwrap();
    assert_eq!(library.abi_version(), 1);
    let mut p = PluginHost::new()
        .planner(&path, "straight_v1", "", None)
        .unwrap();
    let obs = Observation {
        time: 2.0,
        goal: [3.0, 4.0],
        agents: agents(),
        ..Default::default()
    };
    let plan = p.plan(&obs).unwrap();
    assert_eq!((plan.poses.len(), plan.t0), (10, 2.0));
    assert_relative_eq!(plan.poses[9].x, 0.9 * 0.6, max_relative = 1e-12);
    assert!(plan.info.notes.is_empty(), "{:?}", plan.info.notes);
    let plan = p.plan(&with_obstacles(&obs)).unwrap();
    assert_relative_eq!(plan.poses[9].y, 0.9 * 0.8, max_relative = 1e-12);
    assert_eq!(
        plan.info.notes,
        vec![
            "plugin ABI version 1: 3 static obstacle(s) and the occupancy grid not passed to \
             the planner (version 2 carries them)"
                .to_string()
        ]
    );
}

#[test]
fn planner_plugin_round_trip() {
    let host = PluginHost::new();
    let mut p = host
        .planner(
            &lib("human2nav_fixture_test_plugin"),
            "straight",
            "speed = 0.5",
            None,
        )
        .unwrap();
    assert_eq!(p.name(), "straight");
    let obs = Observation {
        time: 3.0,
        ego: Pose2::new(1.0, 1.0, 0.0),
        ego_velocity: Twist2::ZERO,
        goal: [1.0, 5.0],
        agents: agents(),
        ..Default::default()
    };
    // 100 poses: longer than the host's first 64-pose buffer, so `last_plan` is exercised.
    let plan = p.plan(&obs).unwrap();
    assert_eq!(plan.poses.len(), 100);
    assert_eq!((plan.t0, plan.dt), (3.0, 0.1));
    assert_relative_eq!(
        plan.poses[99].y,
        1.0 + 0.5 * 0.1 * 99.0,
        max_relative = 1e-12
    );
    assert_relative_eq!(
        plan.poses[99].theta,
        std::f64::consts::FRAC_PI_2,
        max_relative = 1e-12
    );
    assert_eq!(
        plan.info.notes,
        vec!["call 1 agents 2 history 2".to_string()]
    );
    let plan = p.plan(&obs).unwrap();
    assert_eq!(
        plan.info.notes,
        vec!["call 2 agents 2 history 2".to_string()]
    );
    p.reset();
    assert_eq!(
        p.plan(&obs).unwrap().info.notes,
        vec!["call 1 agents 2 history 2".to_string()]
    );
    // A non-finite observation is refused before it crosses the boundary.
    let bad = Observation {
        time: f64::NAN,
        ..obs.clone()
    };
    assert!(matches!(
        p.plan(&bad),
        Err(PlanError::InvalidObservation(_))
    ));
    // An ordinary planner error is not fatal.
    let mut failing = host
        .planner(
            &lib("human2nav_fixture_test_plugin"),
            "straight",
            "fail = true",
            None,
        )
        .unwrap();
    let err = failing.plan(&obs).unwrap_err();
    assert!(
        matches!(&err, PlanError::Failed { message, .. } if message == "told to fail"),
        "{err}"
    );
    let err = failing.plan(&obs).unwrap_err();
    assert!(matches!(err, PlanError::Failed { .. }), "{err}");
}

#[test]
fn abi_mismatch_is_refused_naming_both_versions() {
    let err = PluginLibrary::load(&lib("human2nav_fixture_wrong_abi")).unwrap_err();
    let PluginError::AbiMismatch {
        found, expected, ..
    } = &err
    else {
        panic!("{err}")
    };
    assert_eq!((*found, *expected), (ABI_VERSION + 1, ABI_VERSION));
    let msg = err.to_string();
    assert!(msg.contains("human2nav_fixture_wrong_abi"), "{msg}");
    assert!(
        msg.contains(&format!("version {}", ABI_VERSION + 1)),
        "{msg}"
    );
    assert!(msg.contains(&format!("versions 1–{ABI_VERSION}")), "{msg}");
}

#[test]
fn a_library_without_the_entry_symbol_is_not_a_plugin() {
    let err = PluginLibrary::load(&lib("human2nav_fixture_no_entry")).unwrap_err();
    assert!(matches!(err, PluginError::MissingEntry { .. }), "{err}");
    assert!(err.to_string().contains("human2nav_plugin_entry"), "{err}");
}

#[test]
fn a_file_that_is_not_a_library_is_refused() {
    let dir = std::env::temp_dir().join(format!("h2n-plugin-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fake = dir.join(format!("libfake{}", std::env::consts::DLL_SUFFIX));
    std::fs::write(&fake, "name = \"not a plugin\"\n").unwrap();
    let err = PluginLibrary::load(&dir.join("fake")).unwrap_err();
    assert!(matches!(err, PluginError::Open { .. }), "{err}");
    assert!(err.to_string().contains("libfake"), "{err}");
    assert!(!err.to_string().contains('\n'), "one line: {err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_missing_library_lists_the_paths_tried() {
    let err = PluginLibrary::load(&target_profile_dir().join("no_such_plugin")).unwrap_err();
    let PluginError::NotFound { tried, .. } = &err else {
        panic!("{err}")
    };
    assert!(tried.len() >= 2, "{tried:?}");
}

#[test]
fn unknown_factories_and_bad_configs_are_clear_errors() {
    let host = PluginHost::new();
    let err = host
        .constraint(&lib("human2nav_personal_space"), "clearance", "", None)
        .unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, PluginError::UnknownFactory { .. }), "{msg}");
    assert!(
        msg.contains("personal_space") && msg.contains("`clearance`"),
        "{msg}"
    );
    // Asking for the wrong kind is an unknown factory too.
    let err = host
        .planner(&lib("human2nav_personal_space"), "personal_space", "", None)
        .unwrap_err();
    assert!(
        matches!(
            err,
            PluginError::UnknownFactory {
                kind: PluginKind::Planner,
                ..
            }
        ),
        "{err}"
    );
    let err = host
        .constraint(
            &lib("human2nav_personal_space"),
            "personal_space",
            "gamma = 1\nsigma = 2",
            None,
        )
        .unwrap_err();
    assert!(matches!(err, PluginError::Config { .. }), "{err}");
    assert!(err.to_string().contains("`sigma`"), "{err}");
    let err = host
        .constraint(
            &lib("human2nav_personal_space"),
            "personal_space",
            "gamma = [",
            None,
        )
        .unwrap_err();
    assert!(err.to_string().contains("line 1"), "{err}");
    // An embodiment that needs the robot's limits says so.
    let err = host
        .embodiment(
            &lib("human2nav_skid_steer"),
            "skid_steer",
            "track_width = 0.5",
            &robot(),
        )
        .unwrap_err();
    assert!(err.to_string().contains("track_speed_max"), "{err}");
}

#[test]
fn a_panicking_constraint_is_marked_unusable_and_the_process_lives_on() {
    let host = PluginHost::new();
    let term = host
        .constraint(
            &lib("human2nav_fixture_test_plugin"),
            "quadratic",
            "panic = true",
            None,
        )
        .unwrap();
    let data = batch(2, 3);
    let l = limits();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &l,
        initial_velocity: Twist2::ZERO,
        agents: &[],
        scene: Default::default(),
    };
    let run = |term: &dyn ConstraintTerm| {
        let mut cost = vec![0.0; 2];
        let mut grad = vec![0.0; data.len()];
        term.evaluate(
            TrajBatch::new(&data, 2, 3).unwrap(),
            &ctx,
            &mut cost,
            &mut grad,
        )
    };
    let err = run(&term).unwrap_err().to_string();
    assert!(
        err.contains("panicked") && err.contains("quadratic was told to panic"),
        "{err}"
    );
    assert!(term.is_poisoned());
    let err = run(&term).unwrap_err().to_string();
    assert!(
        err.contains("unusable") && err.contains("quadratic was told to panic"),
        "{err}"
    );
    let failures = host.failures();
    assert_eq!(failures.len(), 1);
    assert!(failures[0].instance.contains("quadratic"), "{failures:?}");
    // Other instances of the same library are unaffected.
    let healthy = host
        .constraint(&lib("human2nav_fixture_test_plugin"), "quadratic", "", None)
        .unwrap();
    run(&healthy).unwrap();
    // An ordinary error does not poison.
    let failing = host
        .constraint(
            &lib("human2nav_fixture_test_plugin"),
            "quadratic",
            "fail = true",
            None,
        )
        .unwrap();
    assert!(
        run(&failing)
            .unwrap_err()
            .to_string()
            .contains("told to fail")
    );
    assert!(!failing.is_poisoned());
}

#[test]
fn a_panicking_factory_is_a_create_error() {
    let err = PluginHost::new()
        .constraint(
            &lib("human2nav_fixture_test_plugin"),
            "panic_on_create",
            "",
            None,
        )
        .unwrap_err();
    assert!(
        matches!(
            err,
            PluginError::Create {
                status: "panic",
                ..
            }
        ),
        "{err}"
    );
    assert!(
        err.to_string().contains("this factory always panics"),
        "{err}"
    );
}

#[test]
fn a_panicking_embodiment_halts_the_robot_and_reports() {
    let host = PluginHost::new();
    let e = host
        .embodiment(
            &lib("human2nav_fixture_test_plugin"),
            "unicycle",
            "panic_on_step = true",
            &robot(),
        )
        .unwrap();
    let state = RobotState {
        pose: Pose2::new(1.0, 2.0, 0.5),
        velocity: Twist2::new(0.7, 0.0, 0.1),
    };
    assert_eq!(
        e.saturate(&state, Twist2::new(1.0, 1.0, 0.2), 0.1),
        Twist2::new(1.0, 0.0, 0.2)
    );
    let next = e.step(&state, Twist2::new(1.0, 0.0, 0.0), 0.1);
    assert_eq!(
        next,
        RobotState {
            pose: state.pose,
            velocity: Twist2::ZERO
        }
    );
    let failure = e.failure().expect("the panic is recorded");
    assert!(
        failure.contains("unicycle was told to panic in step"),
        "{failure}"
    );
    // From now on every call returns the safe value.
    assert_eq!(
        e.saturate(&state, Twist2::new(1.0, 0.0, 0.2), 0.1),
        Twist2::ZERO
    );
    assert_eq!(host.failures().len(), 1);
}

#[test]
fn a_panicking_planner_fails_then_is_unusable() {
    let host = PluginHost::new();
    let mut p = host
        .planner(
            &lib("human2nav_fixture_test_plugin"),
            "straight",
            "panic = true",
            None,
        )
        .unwrap();
    let obs = Observation {
        time: 0.0,
        ego: Pose2::IDENTITY,
        ego_velocity: Twist2::ZERO,
        goal: [3.0, 0.0],
        agents: vec![],
        ..Default::default()
    };
    let err = p.plan(&obs).unwrap_err();
    assert!(
        matches!(&err, PlanError::Failed { message, .. } if message.contains("straight was told to panic")),
        "{err}"
    );
    let err = p.plan(&obs).unwrap_err();
    assert!(matches!(err, PlanError::Unusable { .. }), "{err}");
    p.reset();
    assert!(matches!(p.plan(&obs), Err(PlanError::Unusable { .. })));
}
