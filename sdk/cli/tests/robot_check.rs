//! `human2nav robot check` end to end: the shipped robots pass, a broken copy fails with one
//! clear line naming the file and the field.

#![allow(clippy::unwrap_used)] // test helpers; a failed fixture should panic

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn robot_check(args: &[&Path]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_human2nav"))
        .arg("robot")
        .arg("check")
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn the_shipped_robots_pass() {
    let root = workspace_root();
    let profiles: Vec<PathBuf> = ["diablo", "go2", "ackermann"]
        .iter()
        .map(|r| root.join("robots").join(r).join("robot.toml"))
        .collect();
    let refs: Vec<&Path> = profiles.iter().map(PathBuf::as_path).collect();
    let out = robot_check(&refs);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stderr.is_empty(), "{stderr}");
    assert_eq!(stdout.lines().filter(|l| *l == "ok").count(), 3, "{stdout}");
    for needle in [
        "embodiment  differential_drive",
        "embodiment  omnidirectional",
        "embodiment  ackermann",
        "footprint   radius 0.3000 m",
        "footprint   radius 0.3828 m",
        "kappa_max",
        "lateral_speed_max",
        "URDF joint `rear_left_wheel_joint` velocity 9.09 rad/s",
        "robot.toml [limits] a_max",
        "lambda_v",
        "k_theta",
    ] {
        assert!(
            stdout.contains(needle),
            "`{needle}` missing from:\n{stdout}"
        );
    }
}

#[test]
fn a_broken_copy_fails_with_one_line() {
    let dir =
        std::env::temp_dir().join(format!("human2nav-cli-robot-check-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    let src = workspace_root().join("robots/diablo");
    for f in ["robot.toml", "diablo.urdf"] {
        fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let toml = dir.join("robot.toml");
    let text = fs::read_to_string(&toml).unwrap();
    fs::write(&toml, text.replace("omega_max = 2.0", "omega_max = -2.0")).unwrap();

    let good = workspace_root().join("robots/go2/robot.toml");
    let out = robot_check(&[good.as_path(), toml.as_path()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert_eq!(
        lines[0],
        format!(
            "error: {}: limits.omega_max: must be > 0, got -2",
            toml.display()
        )
    );
    // The good profile before it is still reported.
    assert!(String::from_utf8_lossy(&out.stdout).contains("robot       go2"));
    let _ = fs::remove_dir_all(&dir);
}

/// `target/<profile>`, where cargo put the binary and the plugin libraries.
fn profile_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_human2nav"))
        .parent()
        .map(PathBuf::from)
        .unwrap()
}

#[test]
fn plugin_embodiments_are_resolved_and_a_broken_declaration_fails() {
    let tracked = workspace_root().join("robots/tracked/robot.toml");
    let out = robot_check(&[tracked.as_path()]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}\n(build the plugins first: cargo build --workspace)",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("resolved    embodiment `skid_steer` from"),
        "{stdout}"
    );

    // A copy naming a factory the library does not have: the profile parses, so before this
    // passed `robot check`.
    let dir = std::env::temp_dir().join(format!(
        "human2nav-cli-robot-check-plugin-{}",
        std::process::id()
    ));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    let src = workspace_root().join("robots/tracked");
    fs::copy(src.join("tracked.urdf"), dir.join("tracked.urdf")).unwrap();
    let libs = profile_dir();
    let text = fs::read_to_string(src.join("robot.toml"))
        .unwrap()
        .replace(
            "../../target/{profile}/human2nav_skid_steer",
            &libs.join("human2nav_skid_steer").display().to_string(),
        )
        .replace(
            "../../target/{profile}/human2nav_personal_space",
            &libs.join("human2nav_personal_space").display().to_string(),
        )
        .replace("plugin = \"skid_steer\"", "plugin = \"skid_steering\"");
    let toml = dir.join("robot.toml");
    fs::write(&toml, text).unwrap();
    let out = robot_check(&[toml.as_path()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with(&format!(
            "error: robot profile {}, [embodiment]: ",
            toml.display()
        )),
        "{stderr}"
    );
    assert!(
        stderr.contains("has no embodiment factory named `skid_steering`; it provides: skid_steer"),
        "{stderr}"
    );
    let _ = fs::remove_dir_all(&dir);
}
