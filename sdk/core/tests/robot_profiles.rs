//! Robot profiles: the three shipped robots load with the documented URDF-derived values, and
//! every kind of broken input is a clear error naming the file and the field.

#![allow(clippy::unwrap_used)] // test helpers; a failed fixture should panic

use approx::assert_relative_eq;
use human2nav_core::embodiment::EmbodimentKind;
use human2nav_core::robot::footprint::FootprintShape;
use human2nav_core::robot::{EmbodimentSpec, Origin, PluginIsolation, ProfileError, RobotProfile};
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

fn robots_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../robots")
}

fn load(name: &str) -> RobotProfile {
    let path = robots_dir().join(name).join("robot.toml");
    match RobotProfile::load(&path) {
        Ok(p) => p,
        Err(e) => panic!("{name}: {e}"),
    }
}

/// A fresh directory under the system temp dir holding a copy of `robots/<robot>/`.
fn scratch_copy(robot: &str) -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!(
        "human2nav-robot-test-{}-{}-{robot}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    for entry in fs::read_dir(robots_dir().join(robot)).unwrap() {
        let entry = entry.unwrap();
        fs::copy(entry.path(), dir.join(entry.file_name())).unwrap();
    }
    dir
}

/// Loads a copy of `robot` whose robot.toml went through `edit`.
fn load_edited(
    robot: &str,
    edit: impl Fn(&str) -> String,
) -> (PathBuf, Result<RobotProfile, ProfileError>) {
    let dir = scratch_copy(robot);
    let toml = dir.join("robot.toml");
    let text = fs::read_to_string(&toml).unwrap();
    let edited = edit(&text);
    assert_ne!(edited, text, "the edit changed nothing");
    fs::write(&toml, edited).unwrap();
    let result = RobotProfile::load(&toml);
    (toml, result)
}

/// Replaces the first line starting with `key` (after trimming) by `line`.
fn set_line(text: &str, key: &str, line: &str) -> String {
    let mut done = false;
    text.lines()
        .map(|l| {
            if !done && l.trim_start().starts_with(key) {
                done = true;
                line.to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn expect_invalid(
    result: Result<RobotProfile, ProfileError>,
    file: &Path,
    field: &str,
    needle: &str,
) {
    match result {
        Err(e @ ProfileError::Invalid { .. }) => {
            assert_eq!(e.file(), file, "{e}");
            assert_eq!(e.field(), field, "{e}");
            let text = e.to_string();
            assert!(text.contains(needle), "`{text}` lacks `{needle}`");
            assert!(text.contains(&file.display().to_string()), "{text}");
            assert!(!text.contains('\n'), "multi-line message: {text}");
        }
        other => panic!("expected an Invalid error on {field}, got {other:?}"),
    }
}

#[test]
fn diablo_profile() {
    let p = load("diablo");
    assert_eq!(p.name, "diablo");
    assert_eq!(
        p.embodiment,
        EmbodimentSpec::Builtin(EmbodimentKind::DifferentialDrive)
    );
    assert_eq!(p.base_link, "base_link");
    // Upright cylinder of radius 0.30 m at the origin.
    assert_relative_eq!(p.footprint_radius, 0.30, epsilon = 1e-12);
    assert_eq!(p.footprint_source.origin, Origin::Urdf);
    assert_eq!(
        p.footprint_shapes,
        [FootprintShape::Disc {
            center: [0.0, 0.0],
            radius: 0.30
        }]
    );
    // Wheels: radius 0.09 m, 22 rad/s, centres at y = ±0.24 m.
    assert_eq!(p.wheel_joints.len(), 2);
    assert_relative_eq!(p.wheel_joints[0].radius, 0.09, epsilon = 1e-12);
    assert_eq!(p.wheel_joints[0].velocity_limit, Some(22.0));
    assert_relative_eq!(p.track_width.unwrap(), 0.48, epsilon = 1e-12);
    // The URDF caps (1.98 m/s, 2·1.98/0.48 = 8.25 rad/s) are above robot.toml's: not binding.
    assert_relative_eq!(p.limits.v_max, 1.5);
    assert_eq!(p.limit_sources.v_max.origin, Origin::Profile);
    assert!(
        p.limit_sources.v_max.detail.contains("1.98"),
        "{}",
        p.limit_sources.v_max
    );
    assert_relative_eq!(p.limits.omega_max, 2.0);
    assert!(
        p.limit_sources.omega_max.detail.contains("8.25"),
        "{}",
        p.limit_sources.omega_max
    );
    assert_eq!(p.limits.kappa_max, None);
    assert_relative_eq!(p.limits.lateral_speed_max, 0.05);
    assert_eq!(p.controller_source, Origin::Profile);
    assert!(p.constraints.is_empty());
    assert_eq!(
        p.builtin_embodiment()
            .map(|e| e.name().to_string())
            .as_deref(),
        Some("differential_drive")
    );
}

#[test]
fn go2_profile() {
    let p = load("go2");
    assert_eq!(
        p.embodiment,
        EmbodimentSpec::Builtin(EmbodimentKind::Omnidirectional)
    );
    // Axis-aligned 0.70 × 0.31 m box at the origin: the half diagonal.
    assert_relative_eq!(p.footprint_radius, 0.35f64.hypot(0.155), epsilon = 1e-12);
    assert_eq!(
        p.footprint_shapes,
        [FootprintShape::Rect {
            center: [0.0, 0.0],
            half: [0.35, 0.155],
            yaw: 0.0
        }]
    );
    assert_relative_eq!(p.limits.v_max, 2.0);
    assert_relative_eq!(p.limits.lateral_speed_max, 0.6);
    assert_eq!(p.limits.kappa_max, None);
    assert!(p.wheel_joints.is_empty());
    let e = p.builtin_embodiment().unwrap();
    assert!(e.holonomic());
}

#[test]
fn ackermann_profile() {
    let p = load("ackermann");
    assert_eq!(
        p.embodiment,
        EmbodimentSpec::Builtin(EmbodimentKind::Ackermann)
    );
    // Box 0.98 × 0.745 m centred 0.325 m ahead of the rear axle: farthest corner.
    assert_relative_eq!(
        p.footprint_radius,
        (0.325f64 + 0.49).hypot(0.3725),
        epsilon = 1e-12
    );
    // The simulator checks the box itself; the disc covers it exactly.
    let [shape] = p.footprint_shapes[..] else {
        panic!("{:?}", p.footprint_shapes)
    };
    let FootprintShape::Rect { center, half, yaw } = shape else {
        panic!("{shape:?}")
    };
    assert_relative_eq!(center[0], 0.325, epsilon = 1e-12);
    assert_relative_eq!(center[1], 0.0, epsilon = 1e-12);
    assert_relative_eq!(half[0], 0.49, epsilon = 1e-12);
    assert_relative_eq!(half[1], 0.3725, epsilon = 1e-12);
    assert_eq!(yaw, 0.0);
    assert_relative_eq!(shape.reach(), p.footprint_radius, epsilon = 1e-12);
    // Wheel cap 9.09 rad/s × 0.165 m = 1.49985 m/s binds below robot.toml's 1.8 m/s.
    assert_relative_eq!(p.limits.v_max, 9.09 * 0.165, epsilon = 1e-12);
    assert_eq!(p.limit_sources.v_max.origin, Origin::Urdf);
    assert!(
        p.limit_sources.v_max.detail.contains("rear_"),
        "{}",
        p.limit_sources.v_max
    );
    // v_reverse_max (0.8) is below the cap: robot.toml's value.
    assert_relative_eq!(p.limits.v_reverse_max, 0.8);
    // Wheelbase 0.65 m, δ_max 0.386 rad: r_min = 0.65 / tan 0.386 ≈ 1.60 m > 1.5 m asked for.
    assert_relative_eq!(p.wheelbase.unwrap(), 0.65, epsilon = 1e-12);
    let r_min = 0.65 / 0.386f64.tan();
    assert_relative_eq!(p.min_turning_radius, r_min, epsilon = 1e-12);
    assert_relative_eq!(p.limits.kappa_max.unwrap(), 1.0 / r_min, epsilon = 1e-12);
    assert_eq!(p.limit_sources.kappa_max.origin, Origin::Urdf);
    assert!((1.55..1.65).contains(&r_min));
}

#[test]
fn the_three_robots_are_infeasible_for_humans_in_different_ways() {
    let (d, g, a) = (load("diablo"), load("go2"), load("ackermann"));
    // A 1.2 m/s sideways step: only the quadruped moves sideways at all, and not that fast.
    assert!(d.limits.lateral_speed_max < 0.1 && a.limits.lateral_speed_max < 0.1);
    assert!(g.limits.lateral_speed_max < 1.2);
    // A 1.8 m/s walk: too fast for the wheeled robots, fine for the quadruped.
    assert!(d.limits.v_max < 1.8 && a.limits.v_max < 1.8 && g.limits.v_max >= 1.8);
    // A 1 m radius turn: only the car cannot.
    assert!(a.limits.kappa_max.unwrap() < 1.0);
    assert!(d.limits.kappa_max.is_none() && g.limits.kappa_max.is_none());
}

#[test]
fn plugin_references_resolve_relative_to_the_profile() {
    let (toml, result) = load_edited("diablo", |t| {
        let t = t.replace(
            "[embodiment]\nkind = \"differential_drive\"\nwheel_joints = [\"left_wheel_joint\", \"right_wheel_joint\"]",
            "[embodiment]\nkind = \"plugin\"\nlibrary = \"../plugins/skid\"\nplugin = \"skid_steer\"\nconfig = \"\"\"\ntrack = 0.5\n\"\"\"\nwheel_joints = [\"left_wheel_joint\", \"right_wheel_joint\"]",
        );
        format!(
            "{t}\n[[constraint]]\nlibrary = \"libclear\"\nplugin = \"clearance\"\nweight = 2.5\nconfig = \"\"\"\nmargin = 0.3\n[inner]\nx = 1\n\"\"\"\n\n[[constraint]]\nlibrary = \"/opt/abs/lib\"\nplugin = \"smooth\"\n"
        )
    });
    let p = result.unwrap();
    let dir = toml.parent().unwrap();
    match &p.embodiment {
        EmbodimentSpec::Plugin(r) => {
            assert_eq!(r.library, dir.join("../plugins/skid"));
            assert_eq!(r.plugin, "skid_steer");
            assert_eq!(r.config, "track = 0.5\n");
            assert_eq!(r.declared_in, toml);
        }
        other => panic!("{other:?}"),
    }
    assert!(p.builtin_embodiment().is_none());
    assert_eq!(p.constraints.len(), 2);
    assert_eq!(p.constraints[0].library, dir.join("libclear"));
    assert_eq!(p.constraints[0].weight, 2.5);
    assert_eq!(p.constraints[0].config, "margin = 0.3\n[inner]\nx = 1\n");
    assert_eq!(p.constraints[1].library, PathBuf::from("/opt/abs/lib"));
    assert_eq!(p.constraints[1].weight, 1.0);
    assert_eq!(p.constraints[1].config, "");
}

#[test]
fn plugin_isolation_defaults_to_a_helper_process_unless_written_or_chosen_by_the_embedder() {
    let (_, result) = load_edited("diablo", |t| {
        let t = t.replace(
            "[embodiment]\nkind = \"differential_drive\"\nwheel_joints = [\"left_wheel_joint\", \"right_wheel_joint\"]",
            "[embodiment]\nkind = \"plugin\"\nlibrary = \"skid\"\nplugin = \"skid_steer\"\ndeadline_ms = 50\nwheel_joints = [\"left_wheel_joint\", \"right_wheel_joint\"]",
        );
        format!(
            "{t}\n[[constraint]]\nlibrary = \"a\"\nplugin = \"a\"\n\n[[constraint]]\nlibrary = \"b\"\nplugin = \"b\"\nisolation = \"in_process\"\n"
        )
    });
    let mut p = result.unwrap();
    let EmbodimentSpec::Plugin(e) = &p.embodiment else {
        panic!("{:?}", p.embodiment)
    };
    assert_eq!((e.deadline_ms, e.isolation), (Some(50.0), None));
    assert_eq!(PluginIsolation::default(), PluginIsolation::Process);
    assert_eq!(p.constraints[0].isolation, None);
    assert_eq!(p.constraints[1].isolation, Some(PluginIsolation::InProcess));
    // What the C API and Python do: the unwritten ones run in the embedding process, the
    // written one stays as written.
    p.default_plugin_isolation(PluginIsolation::InProcess);
    let EmbodimentSpec::Plugin(e) = &p.embodiment else {
        unreachable!()
    };
    assert_eq!(e.isolation, Some(PluginIsolation::InProcess));
    assert_eq!(p.constraints[0].isolation, Some(PluginIsolation::InProcess));
    let mut p2 = p.clone();
    p2.constraints[1].isolation = Some(PluginIsolation::Process);
    p2.default_plugin_isolation(PluginIsolation::InProcess);
    assert_eq!(p2.constraints[1].isolation, Some(PluginIsolation::Process));
}

#[test]
fn malformed_toml_names_line_and_column() {
    let (toml, result) = load_edited("diablo", |t| set_line(t, "a_max", "a_max = = 1.0"));
    match result {
        Err(e @ ProfileError::Parse { .. }) => {
            assert_eq!(e.file(), toml);
            assert_eq!(e.field(), "limits.a_max", "{e}");
            let ProfileError::Parse { line, column, .. } = &e else {
                unreachable!()
            };
            let expected_line = fs::read_to_string(&toml)
                .unwrap()
                .lines()
                .position(|l| l.starts_with("a_max = ="))
                .unwrap()
                + 1;
            assert_eq!(*line, expected_line, "{e}");
            assert!(*column > 1, "{e}");
            assert!(!e.to_string().contains('\n'), "{e}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn syntax_error_found_on_the_next_line_names_the_key_before_it() {
    // An unterminated array is only detected at the next key; the culprit is `a_max`.
    let (_, result) = load_edited("go2", |t| set_line(t, "a_max", "a_max = [1.0"));
    match result {
        Err(e @ ProfileError::Parse { .. }) => assert_eq!(e.field(), "limits.a_max", "{e}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn unknown_fields_are_rejected_with_their_name() {
    let (toml, result) = load_edited("diablo", |t| {
        set_line(t, "a_max", "a_max = 1.0\nbrake_max = 3.0")
    });
    match result {
        Err(e @ ProfileError::Parse { .. }) => {
            assert_eq!(e.file(), toml);
            assert_eq!(e.field(), "limits.brake_max", "{e}");
            assert!(e.to_string().contains("unknown field"), "{e}");
        }
        other => panic!("{other:?}"),
    }
    let (_, result) = load_edited("diablo", |t| format!("colour = \"red\"\n{t}"));
    match result {
        Err(e @ ProfileError::Parse { .. }) => assert_eq!(e.field(), "colour", "{e}"),
        other => panic!("{other:?}"),
    }
    let (_, result) = load_edited("diablo", |t| set_line(t, "k_d", "k_d = 0.2\nk_i = 0.1"));
    match result {
        Err(e @ ProfileError::Parse { .. }) => assert_eq!(e.field(), "controller.k_i", "{e}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn missing_and_mistyped_fields() {
    let (_, result) = load_edited("go2", |t| set_line(t, "omega_max", ""));
    match result {
        Err(e @ ProfileError::Parse { .. }) => {
            assert_eq!(e.field(), "limits.omega_max", "{e}");
            assert!(e.to_string().contains("missing field"), "{e}");
        }
        other => panic!("{other:?}"),
    }
    let (_, result) = load_edited("go2", |t| set_line(t, "v_max", "v_max = \"fast\""));
    match result {
        Err(e @ ProfileError::Parse { .. }) => assert_eq!(e.field(), "limits.v_max", "{e}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn negative_zero_and_non_finite_limits() {
    for (line, field, needle) in [
        ("v_max = -1.0", "limits.v_max", "> 0"),
        ("v_max = 0.0", "limits.v_max", "> 0"),
        ("v_max = inf", "limits.v_max", "finite"),
        ("v_max = nan", "limits.v_max", "finite"),
    ] {
        let (toml, result) = load_edited("diablo", |t| set_line(t, "v_max", line));
        expect_invalid(result, &toml, field, needle);
    }
    let (toml, result) = load_edited("go2", |t| set_line(t, "a_max", "a_max = -0.5"));
    expect_invalid(result, &toml, "limits.a_max", "-0.5");
    let (toml, result) = load_edited("go2", |t| {
        set_line(t, "min_turning_radius", "min_turning_radius = -1")
    });
    expect_invalid(result, &toml, "limits.min_turning_radius", ">= 0");
    let (toml, result) = load_edited("go2", |t| {
        set_line(t, "lateral_speed_max", "lateral_speed_max = 0")
    });
    expect_invalid(result, &toml, "limits.lateral_speed_max", "> 0");
    let (toml, result) = load_edited("go2", |t| set_line(t, "gamma", "gamma = -inf"));
    expect_invalid(result, &toml, "cost.gamma", "finite");
    let (toml, result) = load_edited("go2", |t| set_line(t, "delta", "delta = 1.5"));
    expect_invalid(result, &toml, "cost.delta", "< 1");
    let (toml, result) = load_edited("go2", |t| set_line(t, "lookahead", "lookahead = 0"));
    expect_invalid(result, &toml, "controller.lookahead", "> 0");
    let (toml, result) = load_edited("go2", |t| format!("{t}\n[footprint]\nradius = -0.2\n"));
    expect_invalid(result, &toml, "footprint.radius", "> 0");
    let (toml, result) = load_edited("go2", |t| {
        format!("{t}\n[[constraint]]\nlibrary = \"x\"\nplugin = \"y\"\nweight = nan\n")
    });
    expect_invalid(result, &toml, "constraint[0].weight", "finite");
    let (toml, result) = load_edited("go2", |t| {
        format!("{t}\n[[constraint]]\nlibrary = \"x\"\nplugin = \"y\"\nweight = -1\n")
    });
    expect_invalid(result, &toml, "constraint[0].weight", "plugin `y`");
}

#[test]
fn unknown_embodiment() {
    let (toml, result) = load_edited("go2", |t| set_line(t, "kind", "kind = \"hovercraft\""));
    expect_invalid(
        result,
        &toml,
        "embodiment.kind",
        "unknown embodiment `hovercraft`",
    );
}

#[test]
fn embodiment_section_consistency() {
    let (toml, result) = load_edited("go2", |t| set_line(t, "kind", "kind = \"plugin\""));
    expect_invalid(result, &toml, "embodiment.library", "required");
    let (toml, result) = load_edited("go2", |t| {
        set_line(t, "kind", "kind = \"omnidirectional\"\nplugin = \"x\"")
    });
    expect_invalid(result, &toml, "embodiment.plugin", "only allowed");
    for (line, field) in [
        ("isolation = \"process\"", "embodiment.isolation"),
        ("deadline_ms = 10", "embodiment.deadline_ms"),
    ] {
        let (toml, result) = load_edited("go2", |t| {
            set_line(t, "kind", &format!("kind = \"omnidirectional\"\n{line}"))
        });
        expect_invalid(result, &toml, field, "only allowed");
    }
    let (toml, result) = load_edited("go2", |t| {
        set_line(
            t,
            "kind",
            "kind = \"plugin\"\nlibrary = \"x\"\nplugin = \"y\"\ndeadline_ms = -1",
        )
    });
    expect_invalid(result, &toml, "embodiment.deadline_ms", ">= 0");
    let (toml, result) = load_edited("diablo", |t| {
        set_line(
            t,
            "wheel_joints",
            "wheel_joints = [\"left_wheel_joint\"]\nsteering_joints = [\"x\"]",
        )
    });
    expect_invalid(result, &toml, "embodiment.steering_joints", "ackermann");
    let (toml, result) = load_edited("diablo", |t| {
        set_line(
            t,
            "wheel_joints",
            "wheel_joints = [\"left_wheel_joint\", \"middle_wheel_joint\"]",
        )
    });
    expect_invalid(
        result,
        &toml,
        "embodiment.wheel_joints[1]",
        "middle_wheel_joint",
    );
    // An Ackermann robot with neither a turning radius nor steering joints.
    let (toml, result) = load_edited("ackermann", |t| {
        let t = set_line(t, "steering_joints", "");
        set_line(&t, "min_turning_radius", "min_turning_radius = 0.0")
    });
    expect_invalid(
        result,
        &toml,
        "limits.min_turning_radius",
        "cannot turn in place",
    );
}

#[test]
fn missing_or_unparsable_urdf() {
    let (toml, result) = load_edited("diablo", |t| set_line(t, "urdf", "urdf = \"nowhere.urdf\""));
    match result {
        Err(e @ ProfileError::UrdfLoad { .. }) => {
            assert_eq!(e.file(), toml);
            assert_eq!(e.field(), "urdf");
            assert!(e.to_string().contains("nowhere.urdf"), "{e}");
            assert!(!e.to_string().contains('\n'), "{e}");
        }
        other => panic!("{other:?}"),
    }
    let dir = scratch_copy("diablo");
    fs::write(
        dir.join("diablo.urdf"),
        "<robot name=\"x\"><link name=\"a\"></robot>",
    )
    .unwrap();
    let toml = dir.join("robot.toml");
    match RobotProfile::load(&toml) {
        Err(e @ ProfileError::UrdfLoad { .. }) => {
            assert_eq!(e.file(), toml);
            assert!(e.to_string().contains("diablo.urdf"), "{e}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn missing_profile_file() {
    let path = std::env::temp_dir().join("human2nav-no-such-dir/robot.toml");
    match RobotProfile::load(&path) {
        Err(e @ ProfileError::Read { .. }) => {
            assert_eq!(e.file(), path);
            assert!(e.to_string().contains("robot.toml"), "{e}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn mesh_collision_needs_a_footprint_override() {
    let dir = scratch_copy("diablo");
    let urdf = dir.join("diablo.urdf");
    let text = fs::read_to_string(&urdf).unwrap();
    let meshed = text.replacen(
        "<cylinder radius=\"0.30\" length=\"0.50\"/>",
        "<mesh filename=\"package://diablo/meshes/base.stl\"/>",
        1,
    );
    assert_ne!(meshed, text);
    fs::write(&urdf, meshed).unwrap();
    let toml = dir.join("robot.toml");
    match RobotProfile::load(&toml) {
        Err(e @ ProfileError::UrdfContent { .. }) => {
            assert_eq!(e.file(), urdf);
            assert!(e.field().contains("base_link"), "{e}");
            assert!(e.to_string().contains("[footprint] radius"), "{e}");
        }
        other => panic!("{other:?}"),
    }
    let profile_text = fs::read_to_string(&toml).unwrap();
    fs::write(
        &toml,
        format!("{profile_text}\n[footprint]\nradius = 0.33\n"),
    )
    .unwrap();
    let p = RobotProfile::load(&toml).unwrap();
    assert_relative_eq!(p.footprint_radius, 0.33);
    assert_eq!(p.footprint_source.origin, Origin::Profile);
    assert!(
        p.footprint_source.detail.contains("no analytic extent"),
        "{}",
        p.footprint_source
    );
}

#[test]
fn footprint_override_applies_to_any_geometry() {
    let (_, result) = load_edited("go2", |t| format!("{t}\n[footprint]\nradius = 0.45\n"));
    let p = result.unwrap();
    assert_relative_eq!(p.footprint_radius, 0.45);
    // The override is what collisions are checked with too.
    assert_eq!(
        p.footprint_shapes,
        [FootprintShape::Disc {
            center: [0.0, 0.0],
            radius: 0.45
        }]
    );
    assert!(
        p.footprint_source.detail.contains("0.3828"),
        "{}",
        p.footprint_source
    );
}

#[test]
fn urdf_caps_bind_when_the_profile_asks_for_more() {
    // Ask Diablo for 3 m/s and 10 rad/s: the wheel limits (1.98 m/s, 8.25 rad/s) win.
    let (_, result) = load_edited("diablo", |t| {
        let t = set_line(t, "v_max", "v_max = 3.0");
        set_line(&t, "omega_max", "omega_max = 10.0")
    });
    let p = result.unwrap();
    assert_relative_eq!(p.limits.v_max, 22.0 * 0.09, epsilon = 1e-12);
    assert_relative_eq!(
        p.limits.omega_max,
        2.0 * 22.0 * 0.09 / 0.48,
        epsilon = 1e-12
    );
    assert_eq!(p.limit_sources.v_max.origin, Origin::Urdf);
    assert_eq!(p.limit_sources.omega_max.origin, Origin::Urdf);
    assert!(
        p.limit_sources.v_max.detail.contains("left_wheel_joint"),
        "{}",
        p.limit_sources.v_max
    );
}

#[test]
fn defaults_apply_when_sections_are_absent() {
    let (_, result) = load_edited("go2", |t| {
        let cut = t.find("[controller]").unwrap();
        t[..cut].to_string()
    });
    let p = result.unwrap();
    assert_eq!(p.controller, Default::default());
    assert_eq!(p.guidance, Default::default());
    assert_eq!(p.controller_source, Origin::Default);
    assert_eq!(p.guidance.gamma, 10.0);
}

/// A FIFO at `path` (`mkfifo`); false when it cannot be made (no `mkfifo` on this system).
#[cfg(unix)]
fn make_fifo(path: &Path) -> bool {
    let _ = fs::remove_file(path);
    matches!(
        std::process::Command::new("mkfifo").arg(path).status(),
        Ok(s) if s.success()
    )
}

#[test]
fn deeply_nested_urdf_is_an_error_not_a_stack_overflow() {
    use human2nav_core::robot::MAX_URDF_DEPTH;
    let dir = scratch_copy("diablo");
    let urdf = dir.join("diablo.urdf");
    let text = fs::read_to_string(&urdf).unwrap();
    // 100 000 nested elements inside the robot: the XML parser recursed once per level.
    let n = 100_000;
    let nested = format!("{}{}", "<a>".repeat(n), "</a>".repeat(n));
    let deep = text.replacen("</robot>", &format!("{nested}</robot>"), 1);
    fs::write(&urdf, deep).unwrap();
    match RobotProfile::load(&dir.join("robot.toml")) {
        Err(e @ ProfileError::UrdfLoad { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("diablo.urdf"), "{msg}");
            assert!(
                msg.contains(&format!("nested more than {MAX_URDF_DEPTH} deep")),
                "{msg}"
            );
        }
        other => panic!("{other:?}"),
    }
    // Nesting up to the limit is left to the parser (here: an unknown element it ignores).
    let ok = format!(
        "{}{}",
        "<a>".repeat(MAX_URDF_DEPTH - 1),
        "</a>".repeat(MAX_URDF_DEPTH - 1)
    );
    fs::write(
        &urdf,
        text.replacen("</robot>", &format!("{ok}</robot>"), 1),
    )
    .unwrap();
    assert!(RobotProfile::load(&dir.join("robot.toml")).is_ok());
}

#[cfg(unix)]
#[test]
fn urdf_naming_a_device_or_fifo_is_refused_without_reading_it() {
    if Path::new("/dev/zero").exists() {
        let (_, result) = load_edited("diablo", |t| set_line(t, "urdf", "urdf = \"/dev/zero\""));
        match result {
            Err(e @ ProfileError::UrdfLoad { .. }) => {
                let msg = e.to_string();
                assert!(msg.contains("/dev/zero"), "{msg}");
                assert!(msg.contains("URDF: expected a regular file"), "{msg}");
                assert!(msg.contains("character device"), "{msg}");
            }
            other => panic!("{other:?}"),
        }
    } else {
        eprintln!("skipping the /dev/zero case: no /dev/zero");
    }
    let dir = scratch_copy("diablo");
    if !make_fifo(&dir.join("pipe.urdf")) {
        eprintln!("skipping the FIFO case: mkfifo is not available");
        return;
    }
    let toml = dir.join("robot.toml");
    let text = fs::read_to_string(&toml).unwrap();
    fs::write(&toml, set_line(&text, "urdf", "urdf = \"pipe.urdf\"")).unwrap();
    match RobotProfile::load(&toml) {
        Err(e @ ProfileError::UrdfLoad { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("pipe.urdf"), "{msg}");
            assert!(msg.contains("a FIFO"), "{msg}");
        }
        other => panic!("{other:?}"),
    }
    // The profile itself as a FIFO, and as a directory.
    let fifo = dir.join("fifo.toml");
    assert!(make_fifo(&fifo));
    match RobotProfile::load(&fifo) {
        Err(e @ ProfileError::Read { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("fifo.toml") && msg.contains("a FIFO"), "{msg}");
        }
        other => panic!("{other:?}"),
    }
    match RobotProfile::load(&dir) {
        Err(e @ ProfileError::Read { .. }) => {
            assert!(e.to_string().contains("a directory"), "{e}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn oversized_profile_and_urdf_are_refused_with_the_cap() {
    use human2nav_core::input::{MAX_PROFILE_BYTES, MAX_URDF_BYTES};
    let dir = scratch_copy("diablo");
    let toml = dir.join("robot.toml");
    let text = fs::read_to_string(&toml).unwrap();
    let padding = "#".repeat(MAX_PROFILE_BYTES as usize);
    fs::write(&toml, format!("{text}\n{padding}\n")).unwrap();
    match RobotProfile::load(&toml) {
        Err(e @ ProfileError::Read { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("robot.toml"), "{msg}");
            assert!(msg.contains("robot profile: the file"), "{msg}");
            assert!(msg.contains("larger than the limit of 1 MiB"), "{msg}");
        }
        other => panic!("{other:?}"),
    }
    fs::write(&toml, &text).unwrap();
    let urdf = dir.join("diablo.urdf");
    let file = fs::File::create(&urdf).unwrap();
    file.set_len(MAX_URDF_BYTES + 1).unwrap();
    match RobotProfile::load(&toml) {
        Err(e @ ProfileError::UrdfLoad { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("diablo.urdf"), "{msg}");
            assert!(msg.contains("URDF: the file (16777217 bytes)"), "{msg}");
            assert!(msg.contains("larger than the limit of 16 MiB"), "{msg}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_profile_and_urdf_given_as_text_load_like_the_files() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../robots/diablo");
    let path = dir.join("robot.toml");
    let from_files = RobotProfile::load(&path).unwrap();
    let toml = std::fs::read_to_string(&path).unwrap();
    let urdf = std::fs::read_to_string(&from_files.urdf).unwrap();
    // The URDF text is used, not the file its key names: the profile may live anywhere.
    let elsewhere = std::path::Path::new("/nonexistent/param_server/robot.toml");
    let from_text = RobotProfile::from_toml_str(&toml, elsewhere, Some(&urdf)).unwrap();
    assert_eq!(from_text.limits, from_files.limits);
    assert_eq!(from_text.footprint_shapes, from_files.footprint_shapes);
    assert_eq!(from_text.source, elsewhere);
    // Without the URDF text, the file is looked for next to the named profile.
    let err = RobotProfile::from_toml_str(&toml, elsewhere, None).unwrap_err();
    assert!(err.to_string().contains("urdf"), "{err}");
    // A broken URDF text is an error naming the profile and the URDF.
    let err = RobotProfile::from_toml_str(&toml, elsewhere, Some("<robot")).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("robot.toml") && text.contains("urdf"),
        "{text}"
    );
}

#[test]
fn limits_gains_and_weights_outside_their_ranges_are_refused() {
    for (key, line, field) in [
        ("v_max", "v_max = 1e-300", "limits.v_max"),
        ("v_max", "v_max = 1e300", "limits.v_max"),
        ("a_max", "a_max = 1e-300", "limits.a_max"),
        ("omega_max", "omega_max = 1e300", "limits.omega_max"),
        (
            "min_turning_radius",
            "min_turning_radius = 1e-300",
            "limits.min_turning_radius",
        ),
        ("k_x", "k_x = 1e300", "controller.k_x"),
        ("k_theta", "k_theta = 1e-300", "controller.k_theta"),
        ("lookahead", "lookahead = 1e300", "controller.lookahead"),
        ("lambda_v", "lambda_v = 1e300", "cost.lambda_v"),
        ("gamma", "gamma = 1e-300", "cost.gamma"),
    ] {
        let (toml, result) = load_edited("diablo", |t| set_line(t, key, line));
        expect_invalid(result, &toml, field, "in [");
    }
    // 0 stays allowed where it switches a term off.
    let (_, result) = load_edited("diablo", |t| set_line(t, "k_d", "k_d = 0.0"));
    assert_eq!(result.unwrap().controller.k_d, 0.0);
}

/// Diablo's URDF with `from` replaced by `to` (which must occur), loaded with its robot.toml
/// edited by `toml`.
fn diablo_urdf_edit(
    from: &str,
    to: &str,
    toml: impl Fn(&str) -> String,
) -> (PathBuf, Result<RobotProfile, ProfileError>) {
    let dir = scratch_copy("diablo");
    let urdf = dir.join("diablo.urdf");
    let text = fs::read_to_string(&urdf).unwrap();
    assert!(text.contains(from), "diablo.urdf has no `{from}`");
    fs::write(&urdf, text.replacen(from, to, 1)).unwrap();
    let path = dir.join("robot.toml");
    let t = fs::read_to_string(&path).unwrap();
    fs::write(&path, toml(&t)).unwrap();
    (urdf, RobotProfile::load(&path))
}

fn expect_urdf_content(result: Result<RobotProfile, ProfileError>, element: &str, needle: &str) {
    match result {
        Err(e @ ProfileError::UrdfContent { .. }) => {
            assert_eq!(e.field(), element, "{e}");
            assert!(e.to_string().contains(needle), "`{e}` lacks `{needle}`");
        }
        other => panic!("expected a URDF content error on {element}, got {other:?}"),
    }
}

#[test]
fn wheel_joints_listed_twice_or_in_one_place_are_refused() {
    let (toml, result) = load_edited("diablo", |t| {
        t.replace(
            "\"right_wheel_joint\"",
            "\"left_wheel_joint\", \"right_wheel_joint\"",
        )
    });
    expect_invalid(
        result,
        &toml,
        "embodiment.wheel_joints[1]",
        "already embodiment.wheel_joints[0]",
    );
    // The right wheel moved onto the left one.
    let (_, result) = diablo_urdf_edit("xyz=\"0 -0.24 0.09\"", "xyz=\"0 0.24 0.09\"", |t| {
        t.to_string()
    });
    match result {
        Err(e) => {
            assert_eq!(e.field(), "embodiment.wheel_joints[1]", "{e}");
            assert!(e.to_string().contains("sits where wheel_joints[0]"), "{e}");
        }
        Ok(_) => panic!("two wheels in one place were accepted"),
    }
}

#[test]
fn a_urdf_that_is_not_a_tree_is_refused() {
    // A second link of the same name.
    let (_, r) = diablo_urdf_edit("</robot>", "<link name=\"left_wheel\"/></robot>", |t| {
        t.to_string()
    });
    expect_urdf_content(r, "link `left_wheel`", "defined twice");
    // A joint making the base link a child of its own wheel: a cycle.
    let (_, r) = diablo_urdf_edit(
        "</robot>",
        "<joint name=\"loop\" type=\"fixed\"><parent link=\"left_wheel\"/>\
         <child link=\"base_link\"/></joint></robot>",
        |t| t.to_string(),
    );
    expect_urdf_content(r, "link `base_link`", "cycle");
    // A link with two parents.
    let (_, r) = diablo_urdf_edit(
        "</robot>",
        "<joint name=\"again\" type=\"fixed\"><parent link=\"base_link\"/>\
         <child link=\"left_wheel\"/></joint></robot>",
        |t| t.to_string(),
    );
    expect_urdf_content(
        r,
        "joint `again`",
        "already the child of joint `left_wheel_joint`",
    );
    // A joint naming a link that does not exist.
    let (_, r) = diablo_urdf_edit(
        "</robot>",
        "<joint name=\"dangling\" type=\"fixed\"><parent link=\"base_link\"/>\
         <child link=\"ghost\"/></joint></robot>",
        |t| t.to_string(),
    );
    expect_urdf_content(r, "joint `dangling`", "`ghost` is not defined");
}

#[test]
fn wheel_speeds_that_are_nan_or_negative_are_refused() {
    for bad in ["nan", "-22.0", "inf"] {
        let (_, r) = diablo_urdf_edit("velocity=\"22.0\"", &format!("velocity=\"{bad}\""), |t| {
            t.to_string()
        });
        expect_urdf_content(r, "joint `left_wheel_joint`", "<limit velocity=");
    }
    // A limit so low that the cap leaves no speed.
    let (_, r) = diablo_urdf_edit("velocity=\"22.0\"", "velocity=\"1e-9\"", |t| t.to_string());
    match r {
        Err(e) => assert!(e.to_string().contains("caps it at"), "{e}"),
        Ok(_) => panic!("a wheel cap of 1e-10 m/s was accepted"),
    }
}
