//! Builds the C and C++ examples against the C library and the checked-in header, runs them on
//! the shipped robot, configuration and model, and checks what they print.

use std::path::{Path, PathBuf};
use std::process::Command;

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The directory holding the `libhuman2nav_c.so` of this build: the test binary's own `deps/`
/// folder, where cargo builds the library's cdylib for the tests (`cargo build` copies it one
/// level up, `cargo test` does not).
fn library_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test binary path");
    let dir = exe.parent().expect("target/<profile>/deps").to_path_buf();
    let lib = dir.join(format!(
        "{}human2nav_c{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    ));
    assert!(lib.is_file(), "{} was not built", lib.display());
    dir
}

/// Compiles `source` with `compiler` (warnings are errors) into the test's scratch folder.
fn build(compiler: &str, std: &str, source: &str, name: &str) -> PathBuf {
    let lib = library_dir();
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let status = Command::new(compiler)
        .arg(format!("-std={std}"))
        .args(["-Wall", "-Wextra", "-Werror", "-pedantic"])
        .arg("-I")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("include"))
        .arg(workspace().join(source))
        .arg("-L")
        .arg(&lib)
        .arg("-lhuman2nav_c")
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .arg("-lm")
        .arg("-o")
        .arg(&out)
        .status()
        .unwrap_or_else(|e| panic!("running the compiler `{compiler}`: {e}"));
    assert!(status.success(), "{compiler} failed on {source}");
    out
}

/// Runs an example on the shipped diablo robot, planner configuration and model.
fn run(exe: &Path) -> (bool, String) {
    let ws = workspace();
    // As a user would run it: cargo's LD_LIBRARY_PATH for the tests names `target/<profile>`
    // first, which may hold an older copy of the library; the rpaths find the right one.
    let out = Command::new(exe)
        .env_remove("LD_LIBRARY_PATH")
        .arg(ws.join("robots/diablo/robot.toml"))
        .arg(ws.join("sdk/configs/planner.toml"))
        .arg(ws.join("models/human2nav-cfm"))
        .output()
        .expect("running the example");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

fn compiler(var: &str, default: &str) -> String {
    std::env::var(var).unwrap_or_else(|_| default.to_owned())
}

#[test]
fn the_c_example_plans_commands_and_refuses_bad_input() {
    let exe = build(&compiler("CC", "cc"), "c11", "examples/c/plan.c", "plan_c");
    let (ok, text) = run(&exe);
    println!("{text}");
    assert!(ok, "the C example failed:\n{text}");
    assert!(
        text.contains("plan: 33 poses 0.10 s apart; sampling 5/5 steps"),
        "{text}"
    );
    assert!(text.contains("plan within 5 ms:"), "{text}");
    for message in [
        "observation.goal is not finite",
        "observation.agents is NULL but agent_count is 2",
        "planner is NULL",
        "out holds 3 poses; the plan has 33",
        "observation.obstacles[0].kind 7 is not an h2n_obstacle_kind",
        "no/such/robot.toml",
    ] {
        assert!(text.contains(message), "missing `{message}` in:\n{text}");
    }
    assert!(text.trim_end().ends_with("ok"), "{text}");
}

#[test]
fn the_cpp_controller_reaches_the_end_of_its_path_past_two_pedestrians() {
    let exe = build(
        &compiler("CXX", "c++"),
        "c++17",
        "examples/cpp/nav2_style_controller.cpp",
        "nav2_style_controller",
    );
    let (ok, text) = run(&exe);
    println!("{text}");
    assert!(ok, "the C++ example failed:\n{text}");
    assert!(text.contains("reached the end of the path"), "{text}");
}
