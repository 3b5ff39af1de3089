//! `human2nav plugin inspect` end to end on the workspace-built libraries (run after
//! `cargo build --workspace`, as `sdk/dev.sh test` does): a plugin is described; a bad library
//! gives one line on stderr and a non-zero exit.

use std::path::PathBuf;
use std::process::{Command, Output};

/// `target/<profile>`, where cargo put this test's binary and the plugin libraries.
fn profile_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_human2nav"))
        .parent()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target/debug"))
}

fn inspect(library: &str) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_human2nav"))
        .args(["plugin", "inspect"])
        .arg(profile_dir().join(library))
        .output();
    match out {
        Ok(out) => out,
        Err(e) => panic!("cannot run human2nav: {e}"),
    }
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn a_plugin_is_described() {
    let out = inspect("human2nav_personal_space");
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(
        out.status.success(),
        "{stderr}\n(build the plugins first: cargo build --workspace)"
    );
    assert!(
        stdout.contains("plugin    personal_space 0.1.0"),
        "{stdout}"
    );
    let abi = human2nav_plugin::ABI_VERSION;
    assert!(
        stdout.contains(&format!("ABI       version {abi}")),
        "{stdout}"
    );
    assert!(stdout.contains("constraint  personal_space"), "{stdout}");
    let out = inspect("human2nav_skid_steer");
    assert!(
        text(&out.stdout).contains("embodiment  skid_steer"),
        "{}",
        text(&out.stdout)
    );
}

/// Every failure is one line starting with `error:` and a non-zero exit.
fn assert_one_line_error(out: &Output, needle: &str) {
    let stderr = text(&out.stderr);
    assert!(
        !out.status.success(),
        "expected a failure, got {}",
        text(&out.stdout)
    );
    assert_eq!(stderr.lines().count(), 1, "one line: {stderr}");
    assert!(stderr.starts_with("error: "), "{stderr}");
    assert!(stderr.contains(needle), "`{needle}` not in: {stderr}");
}

#[test]
fn bad_libraries_give_one_clear_line() {
    let abi = human2nav_plugin::ABI_VERSION;
    assert_one_line_error(
        &inspect("human2nav_fixture_wrong_abi"),
        &format!(
            "built for plugin ABI version {}, this host loads versions 1–{abi}",
            abi + 1
        ),
    );
    assert_one_line_error(
        &inspect("human2nav_fixture_no_entry"),
        "does not export `human2nav_plugin_entry`",
    );
    assert_one_line_error(&inspect("no_such_plugin"), "not found");
    // A file that is not a shared library at all (this test's own source).
    let out = Command::new(env!("CARGO_BIN_EXE_human2nav"))
        .args(["plugin", "inspect", file!()])
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .output();
    match out {
        Ok(out) => assert_one_line_error(&out, "cannot load"),
        Err(e) => panic!("cannot run human2nav: {e}"),
    }
}

#[test]
fn inspect_lists_its_checks_and_refuses_broken_tables() {
    let out = inspect("human2nav_personal_space");
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    for needle in [
        "checked   ",
        "ok    file: regular file of",
        "ok    entry table:",
        "ok    factory 0 (constraint `personal_space`): create set",
    ] {
        assert!(stdout.contains(needle), "`{needle}` missing:\n{stdout}");
    }
    // A library whose instance comes with a null required function: before, inspect called it
    // fine and a profile using it crashed the host.
    let out = inspect("human2nav_fixture_bad_tables");
    assert_one_line_error(
        &out,
        "the planner vtable of `null_plan` has a null `plan` (a required function)",
    );
    assert!(
        text(&out.stdout).contains("FAIL  constraint `short_vtable` instance"),
        "{}",
        text(&out.stdout)
    );
}

/// A library that aborts, or hangs, when it is loaded ends the inspecting child process, not
/// this command: one clear error line each, and an ordinary exit status.
#[test]
fn a_library_that_aborts_or_hangs_on_load_is_reported_not_fatal() {
    let out = inspect("human2nav_fixture_crash_on_load");
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("took the inspecting process down (signal SIGABRT)"),
        "{stderr}"
    );

    let out = Command::new(env!("CARGO_BIN_EXE_human2nav"))
        .args(["plugin", "inspect", "--timeout-s", "2"])
        .arg(profile_dir().join("human2nav_fixture_crash_on_load"))
        .env("H2N_FIXTURE_ON_LOAD", "sleep")
        .output()
        .expect("running human2nav");
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("did not finish within 2.0 s and its process was killed"),
        "{stderr}"
    );
}
