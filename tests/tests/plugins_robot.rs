//! A robot the SDK does not know, from `robots/tracked/robot.toml`: its embodiment and one of its
//! constraint terms are plugins named by the profile; the host turns the profile into a runtime
//! robot used exactly like one with built-ins. Run after `cargo build --workspace`.

use approx::assert_relative_eq;
use human2nav_core::constraint::{ConstraintContext, PhiScratch, TrajBatch};
use human2nav_core::embodiment::RobotState;
use human2nav_core::robot::{EmbodimentSpec, RobotProfile};
use human2nav_core::{AgentState, Plan, PlanInfo, Pose2, Twist2};
use human2nav_integration_tests::{target_profile_dir, workspace_root};
use human2nav_plugin::resolve::{PROFILE_ENV, profile_dir_name};
use human2nav_plugin::{PluginError, PluginHost};

/// The tracked robot's profile. Its plugin paths say `target/{profile}`, which must name the
/// directory this test binary was built into.
fn profile() -> RobotProfile {
    let dir = target_profile_dir();
    let profile_name = dir.file_name().and_then(|n| n.to_str()).unwrap_or("debug");
    assert_eq!(
        profile_dir_name(),
        profile_name,
        "{{profile}} expands to {}, but the plugins were built into {} (set {PROFILE_ENV})",
        profile_dir_name(),
        dir.display()
    );
    RobotProfile::load(&workspace_root().join("robots/tracked/robot.toml"))
        .expect("robots/tracked/robot.toml loads")
}

#[test]
fn the_profile_names_its_plugins() {
    let p = profile();
    let EmbodimentSpec::Plugin(r) = &p.embodiment else {
        panic!("expected a plugin embodiment")
    };
    assert_eq!(r.plugin, "skid_steer");
    assert!(
        r.library.ends_with("target/{profile}/human2nav_skid_steer"),
        "{}",
        r.library.display()
    );
    assert_eq!(p.constraints.len(), 1);
    assert_eq!(
        (p.constraints[0].plugin.as_str(), p.constraints[0].weight),
        ("personal_space", 0.5)
    );
    // Footprint: half the diagonal of the 0.78 × 0.58 m collision box.
    assert_relative_eq!(
        p.footprint_radius,
        (0.39f64.powi(2) + 0.29f64.powi(2)).sqrt(),
        max_relative = 1e-9
    );
}

#[test]
fn the_tracked_robot_loads_and_drives_through_its_plugin_embodiment() {
    let host = PluginHost::new();
    let mut robot = host
        .load_robot(profile())
        .expect("the tracked robot's plugins load");
    assert_eq!(robot.embodiment.name(), "skid_steer");
    assert!(!robot.embodiment.holonomic());
    assert_eq!(robot.plugin_terms.len(), 1);
    assert_eq!(robot.plugin_terms[0].1.name(), "personal_space");

    // Closed loop in an empty world: follow a feasible arc (0.6 m/s, 0.4 rad/s: tracks at
    // 0.6 ∓ 0.4·0.345 m/s) from on the plan and at its speed, controller at 20 Hz.
    let twist = Twist2::new(0.6, 0.0, 0.4);
    let mut poses = vec![Pose2::IDENTITY];
    for _ in 0..60 {
        let last = poses[poses.len() - 1];
        poses.push(last.euler_step(twist, 0.1));
    }
    let plan = Plan {
        t0: 0.0,
        dt: 0.1,
        poses: poses.clone(),
        info: PlanInfo::default(),
    };
    let e = &robot.embodiment;
    let mut s = RobotState {
        pose: Pose2::IDENTITY,
        velocity: twist,
    };
    let dt = 0.05;
    let mut worst: f64 = 0.0;
    for i in 0..100 {
        let t = i as f64 * dt;
        let cmd = e.saturate(&s, e.track(&s, &plan, t), dt);
        s = e.step(&s, cmd, dt);
        let k = ((t + dt) / 0.1).round() as usize;
        if ((t + dt) / 0.1 - k as f64).abs() < 1e-9 {
            let r = poses[k];
            worst = worst.max(((s.pose.x - r.x).powi(2) + (s.pose.y - r.y).powi(2)).sqrt());
        }
    }
    assert!(worst < 0.01, "tracking error {worst} m");
    assert_relative_eq!(s.velocity.vx, 0.6, max_relative = 1e-3);

    // Φ for this robot: the built-in terms plus the plugin term, used like any other.
    let phi = robot.take_phi().expect("Φ builds");
    let names: Vec<_> = phi.terms().map(|(w, n)| (w, n.to_owned())).collect();
    assert!(
        names.contains(&(0.5, "personal_space".to_owned())),
        "{names:?}"
    );
    let data: Vec<f64> = poses[1..33].iter().flat_map(|p| p.to_array()).collect();
    let agent = AgentState {
        id: 1,
        position: [poses[20].x, poses[20].y + 0.4],
        velocity: [0.0, 0.0],
        radius: 0.3,
        history: vec![],
    };
    let limits = robot.profile.limits;
    let mut scratch = PhiScratch::default();
    let mut cost = |agents: &[AgentState]| {
        let ctx = ConstraintContext {
            dt: 0.1,
            limits: &limits,
            initial_velocity: twist,
            agents,
            scene: Default::default(),
        };
        let (mut c, mut g) = (vec![0.0], vec![0.0; data.len()]);
        phi.evaluate(
            TrajBatch::new(&data, 1, 32).expect("shape"),
            &ctx,
            &mut c,
            &mut g,
            &mut scratch,
        )
        .expect("Φ evaluates");
        c[0]
    };
    let alone = cost(&[]);
    let crowded = cost(&[agent]);
    assert!(
        crowded > alone + 1e-3,
        "a pedestrian on the path must raise Φ: {alone} → {crowded}"
    );
}

#[test]
fn a_profile_naming_a_missing_plugin_fails_with_the_library_path() {
    let dir = std::env::temp_dir().join(format!("h2n-robot-plugin-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let src = workspace_root().join("robots/tracked");
    std::fs::copy(src.join("tracked.urdf"), dir.join("tracked.urdf")).expect("copy urdf");
    let toml = std::fs::read_to_string(src.join("robot.toml")).expect("read profile");
    let broken = toml.replace(
        "../../target/{profile}/human2nav_skid_steer",
        "plugins/nowhere",
    );
    std::fs::write(dir.join("robot.toml"), broken).expect("write profile");
    let p = RobotProfile::load(&dir.join("robot.toml")).expect("the profile itself is valid");
    let err = PluginHost::new()
        .load_robot(p)
        .expect_err("the plugin is missing");
    assert!(matches!(err, PluginError::NotFound { .. }), "{err}");
    assert!(err.to_string().contains("plugins/nowhere"), "{err}");
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn the_add_robot_example_profile_loads() {
    let mut p = RobotProfile::load(&workspace_root().join("examples/add_robot/cart/robot.toml"))
        .expect("examples/add_robot/cart/robot.toml loads");
    assert_eq!(p.name, "cart");
    // The README's claim: the URDF wheels cap v_max at 15 rad/s × 0.08 m.
    assert_relative_eq!(p.limits.v_max, 1.2, max_relative = 1e-12);
    assert_relative_eq!(
        p.footprint_radius,
        (0.3f64.powi(2) + 0.225f64.powi(2)).sqrt(),
        max_relative = 1e-9
    );
    let e = PluginHost::new()
        .robot_embodiment(&mut p)
        .expect("built-in embodiment");
    assert_eq!(e.name(), "differential_drive");
    assert_eq!(p.limits.coupled, None);
}

/// The example: at v = 1.2 m/s, ω = 1.2 rad/s each of the tracked base's box limits
/// holds, but the outer track needs 1.2 + 0.345·1.2 = 1.61 m/s of its 1.4. The embodiment
/// declares the track limit, loading the robot adds it to the profile, and TFS, Φ and the
/// planner's last-step correction all see it.
#[test]
fn the_track_speed_limit_reaches_tfs_phi_and_the_correction() {
    use human2nav_core::projection::{ProjectionSettings, project};
    use human2nav_core::tfs::tfs_plan;
    let host = PluginHost::new();
    let mut p = profile();
    assert_eq!(
        p.limits.coupled, None,
        "RobotProfile::load alone knows no plugin"
    );
    let boxed = p.limits;
    host.robot_embodiment(&mut p).expect("skid_steer loads");
    let c = p
        .limits
        .coupled
        .expect("the embodiment declares its track limit");
    assert_relative_eq!(c.omega, 0.5 * 1.5 * 0.46, max_relative = 1e-12);
    assert_eq!((c.v, c.lateral, c.max), (1.0, 0.0, 1.4));

    let twist = Twist2::new(1.2, 0.0, 1.2);
    let mut arc = vec![Pose2::IDENTITY];
    for _ in 0..32 {
        let last = arc[arc.len() - 1];
        arc.push(last.euler_step(twist, 0.1));
    }
    assert_eq!(
        tfs_plan(&arc, 0.1, &boxed, twist),
        1.0,
        "the box limits pass it"
    );
    assert_eq!(
        tfs_plan(&arc, 0.1, &p.limits, twist),
        0.0,
        "the tracks do not"
    );

    let phi_of = |limits: &human2nav_core::Limits| {
        let phi = human2nav_core::constraint::Phi::from_weights(&p.guidance, limits);
        let data: Vec<f64> = arc.iter().flat_map(|q| q.to_array()).collect();
        let ctx = ConstraintContext {
            dt: 0.1,
            limits,
            initial_velocity: twist,
            agents: &[],
            scene: Default::default(),
        };
        let mut cost = [0.0];
        let mut grad = vec![0.0; data.len()];
        phi.evaluate(
            TrajBatch::new(&data, 1, arc.len()).unwrap(),
            &ctx,
            &mut cost,
            &mut grad,
            &mut PhiScratch::default(),
        )
        .unwrap();
        cost[0]
    };
    assert!(
        phi_of(&p.limits) > phi_of(&boxed) + 0.1,
        "Φ penalises the outer track"
    );

    let out = project(
        &arc[1..],
        0.1,
        &p.limits,
        twist,
        &ProjectionSettings::default(),
    )
    .expect("a plan within the track limit exists");
    let mut corrected = vec![Pose2::IDENTITY];
    corrected.extend(out.poses);
    assert_eq!(tfs_plan(&corrected, 0.1, &p.limits, twist), 1.0);
}
