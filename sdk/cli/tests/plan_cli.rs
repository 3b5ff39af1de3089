//! `human2nav plan` end to end with a small freshly initialised model (the shipped model is not
//! needed): one step is planned and drawn, `--eval` prints a row per robot, `--bench` a row per
//! mode, and a missing model is one clear error.

#![allow(clippy::unwrap_used)] // test helpers; a failed fixture should panic

use human2nav_flow::{CfmModel, NetConfig, Normalisation};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A small model in a fresh temporary folder (one per test, so tests may run in parallel).
fn model_dir(tag: &str) -> PathBuf {
    human2nav_flow::tch::manual_seed(5);
    let net = NetConfig {
        horizon: 8,
        bev_cells: 16,
        down_dims: vec![8, 16],
        n_groups: 4,
        bev_channels: [4, 8, 8],
        time_embed_dim: 8,
        bev_embed_dim: 8,
        goal_embed_dim: 8,
        ..NetConfig::default()
    };
    let norm = Normalisation {
        position_scale: 1.5,
        velocity_std: [0.8, 0.3, 0.5],
        goal_scale: 4.0,
        speed_scale: 1.0,
        goal_conditioned: true,
        velocity_conditioned: true,
    };
    let dir = std::env::temp_dir().join(format!("h2n-plan-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let model = CfmModel::new(&net, &norm, human2nav_flow::tch::Device::Cpu).unwrap();
    model.save(&dir.join("model")).unwrap();
    dir
}

fn plan(args: &[&str], model: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_human2nav"))
        .current_dir(workspace_root())
        .arg("plan")
        .arg("--model")
        .arg(model)
        .args(["--samples", "4", "--threads", "1"])
        .args(args)
        .output()
        .unwrap()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn one_step_is_planned_printed_and_drawn() {
    let dir = model_dir("one");
    let png = dir.join("plan.png");
    let out = plan(
        &[
            "--robot",
            "robots/diablo/robot.toml",
            "--index",
            "1",
            "--guidance",
            "--out",
            png.to_str().unwrap(),
        ],
        &dir.join("model"),
    );
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stderr}");
    assert!(stdout.contains("robot diablo"), "{stdout}");
    assert!(
        stdout.contains("plan: 9 poses at 0.1 s, guidance on"),
        "{stdout}"
    );
    assert!(stdout.contains("TFS "), "{stdout}");
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);

    let out = plan(
        &[
            "--robot",
            "robots/ackermann/robot.toml",
            "--arm",
            "raw",
            "--time",
            "1.0",
            "--out",
            png.to_str().unwrap(),
        ],
        &dir.join("model"),
    );
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(stdout.contains("guidance off"), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn eval_and_bench_print_their_tables() {
    let dir = model_dir("eval");
    let model = dir.join("model");
    let out = plan(
        &[
            "--eval",
            "--windows",
            "2",
            "--robot",
            "robots/diablo/robot.toml",
            "--robot",
            "robots/go2/robot.toml",
        ],
        &model,
    );
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // Four arms per robot, each on both windows, and the QP arms always feasible.
    for robot in ["diablo", "go2"] {
        for arm in [
            "raw samples",
            "Algorithm 1 only",
            "QP only",
            "Algorithm 1 + QP",
        ] {
            assert!(
                stdout.contains(&format!("| {robot} | {arm} | 2 |")),
                "{stdout}"
            );
        }
        for arm in ["QP only", "Algorithm 1 + QP"] {
            assert!(
                stdout.contains(&format!("| {robot} | {arm} | 2 | 1.000 | 1.00 |")),
                "{stdout}"
            );
        }
    }
    assert!(
        stdout.contains("| robot | arm | speed | reverse | acceleration |"),
        "{stdout}"
    );

    let out = plan(
        &["--bench", "3", "--robot", "robots/go2/robot.toml"],
        &model,
    );
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // Both backends, each with its network operations and its ratio to the measured limit.
    assert!(stdout.contains("single-thread SGEMM 512³"), "{stdout}");
    // The configured planner, then one row per arm that changes the cost.
    for row in [
        "| configured | torch | 3 |",
        "| configured | native | 3 |",
        "| raw | torch | 3 |",
        "| raw | native | 3 |",
        "| qp | torch | 3 |",
        "| qp | native | 3 |",
        "| alg1+qp | torch | 3 |",
        "| alg1+qp | native | 3 |",
    ] {
        assert!(stdout.contains(row), "{row} missing in {stdout}");
    }
    assert!(stdout.contains("p50 / limit"), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_model_is_one_clear_error() {
    let out = plan(
        &["--robot", "robots/diablo/robot.toml"],
        Path::new("no/such/model"),
    );
    let stderr = text(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("no model at no/such/model"), "{stderr}");
}
