//! Hostile-user regressions of the plugin host (issue #17): a truncated library, tables with
//! null slots and wrong sizes, absurd counts, broken plugin embodiments in robot profiles,
//! planner and constraint calls that never return, and a benchmark whose planner fails every
//! call. Each of these crashed, hung or silently passed before. Run after
//! `cargo build --workspace` (the fixture libraries).

use human2nav_core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use human2nav_core::robot::RobotProfile;
use human2nav_core::{Limits, Observation, PlanError, Planner, Pose2, Twist2};
use human2nav_integration_tests::{target_profile_dir, workspace_root};
use human2nav_plugin::resolve::resolve_library_path;
use human2nav_plugin::{
    CheckStatus, PluginError, PluginHost, PluginKind, PluginLibrary, inspect_library,
};
use human2nav_sim::config::{BenchConfig, build_suites, builtin_method, load_robots};
use human2nav_sim::driver::{self, BenchPlan};
use human2nav_sim::{MethodSpec, ProgressBar, SuiteKind, bench};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn lib(name: &str) -> PathBuf {
    let path = target_profile_dir().join(name);
    if let Err(e) = resolve_library_path(&path) {
        panic!(
            "{e}: build the workspace first (`cargo build --workspace`, as sdk/dev.sh test does)"
        );
    }
    path
}

/// A fresh directory under cargo's per-target scratch space (inside the workspace, so bench
/// configs written there resolve paths against the workspace root).
fn scratch(name: &str) -> PathBuf {
    let dir =
        Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("h2n-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch dir");
    dir
}

fn obs() -> Observation {
    Observation {
        time: 0.0,
        ego: Pose2::IDENTITY,
        ego_velocity: Twist2::ZERO,
        goal: [3.0, 0.0],
        agents: vec![],
        ..Default::default()
    }
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

fn evaluate(term: &dyn ConstraintTerm) -> Result<(), ConstraintError> {
    let l = limits();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &l,
        initial_velocity: Twist2::ZERO,
        agents: &[],
        scene: Default::default(),
    };
    let data = [0.0, 0.0, 0.0, 0.1, 0.0, 0.0];
    let (mut cost, mut grad) = ([0.0], [0.0; 6]);
    term.evaluate(
        TrajBatch::new(&data, 1, 2).expect("shape"),
        &ctx,
        &mut cost,
        &mut grad,
    )
}

// ------------------------------------------------------------------------------------------
// A truncated library

#[test]
fn a_truncated_library_is_refused_before_dlopen() {
    let dir = scratch("truncated");
    let source = resolve_library_path(&lib("human2nav_fixture_test_plugin")).expect("built");
    let bytes = std::fs::read(&source).expect("read the fixture");
    // Cut inside the loadable segments: `dlopen` of this file maps pages past its end and
    // touches them (SIGBUS, measured with a plain `dlopen` of the same cut).
    let inside_load = load_end(&bytes) / 2;
    for (name, len) in [
        ("half", bytes.len() / 2),
        ("inside_load", inside_load),
        ("one_byte_short", bytes.len() - 1),
        ("header_only", 40),
    ] {
        let copy = dir.join(format!(
            "libtruncated_{name}{}",
            std::env::consts::DLL_SUFFIX
        ));
        std::fs::write(&copy, &bytes[..len]).expect("write the copy");
        // Before, `dlopen` of the half file died with SIGBUS and took this process with it.
        let err = PluginLibrary::load(&copy).expect_err("a truncated library");
        let msg = err.to_string();
        assert!(matches!(err, PluginError::Open { .. }), "{msg}");
        assert!(msg.contains(&copy.display().to_string()), "{msg}");
        assert!(msg.contains("truncated"), "{msg}");
        assert!(msg.contains("refused before loading"), "{msg}");
        eprintln!("{name}: {msg}");
    }
    // The intact copy loads.
    let whole = dir.join(format!("libwhole{}", std::env::consts::DLL_SUFFIX));
    std::fs::write(&whole, &bytes).expect("write");
    PluginLibrary::load(&whole).expect("the intact copy loads");
    // A directory is not a library.
    let d = dir.join(format!("libdir{}", std::env::consts::DLL_SUFFIX));
    std::fs::create_dir_all(&d).expect("mkdir");
    assert!(PluginLibrary::load(&d).is_err());
    std::fs::remove_dir_all(&dir).expect("clean up");
}

/// End of the last `PT_LOAD` segment of a 64-bit little-endian ELF file (`p_offset + p_filesz`).
fn load_end(elf: &[u8]) -> usize {
    let u = |at: usize, n: usize| {
        elf[at..at + n]
            .iter()
            .rev()
            .fold(0usize, |v, &b| (v << 8) | usize::from(b))
    };
    assert_eq!(&elf[..6], b"\x7fELF\x02\x01", "a 64-bit LSB ELF file");
    let (phoff, phentsize, phnum) = (u(32, 8), u(54, 2), u(56, 2));
    (0..phnum)
        .map(|i| phoff + i * phentsize)
        .filter(|&ph| u(ph, 4) == 1)
        .map(|ph| u(ph + 8, 8) + u(ph + 32, 8))
        .max()
        .expect("a PT_LOAD segment")
}

// ------------------------------------------------------------------------------------------
// Null slots, wrong sizes, absurd lengths

#[test]
fn a_null_required_slot_is_an_error_naming_file_table_and_slot() {
    let host = PluginHost::new();
    let library = lib("human2nav_fixture_bad_tables");
    let err = host
        .planner(&library, "null_plan", "", None)
        .expect_err("null plan slot");
    let msg = err.to_string();
    assert!(
        matches!(err, PluginError::NullSlot { slot: "plan", .. }),
        "{msg}"
    );
    assert!(msg.contains("human2nav_fixture_bad_tables"), "{msg}");
    assert!(
        msg.ends_with("the planner vtable of `null_plan` has a null `plan` (a required function)"),
        "{msg}"
    );
    let robot = human2nav_plugin::RobotContext {
        limits: limits(),
        gains: Default::default(),
        footprint_radius: 0.3,
    };
    let err = host
        .embodiment(&library, "null_step", "", &robot)
        .expect_err("null step slot");
    assert!(
        err.to_string()
            .contains("the embodiment vtable of `null_step` has a null `step`"),
        "{err}"
    );
    // A coupled limit with a negative bound is refused, naming the slot and the field.
    let err = host
        .embodiment(&library, "bad_coupled", "", &robot)
        .expect_err("negative coupled bound");
    assert!(
        err.to_string()
            .contains("embodiment `bad_coupled`: coupled_limit: max = -1 must be finite and > 0"),
        "{err}"
    );
    // A table of the first version ends before `coupled_limit`: the host reads no further
    // (the bad slot that follows it in memory is never called) and the robot has no coupled
    // limit.
    let e = host
        .embodiment(&library, "first_version", "", &robot)
        .expect("a first-version embodiment table is accepted");
    assert_eq!(
        human2nav_core::embodiment::Embodiment::coupled_limit(&e),
        None
    );
    // A constraint whose `properties` fails is refused, naming the slot.
    let err = host
        .constraint(&library, "bad_properties", "", None)
        .expect_err("failing properties");
    assert!(
        err.to_string()
            .contains("constraint `bad_properties`: properties returned"),
        "{err}"
    );
    // Likewise a constraint table that ends before `properties`: no properties.
    let term = host
        .constraint(&library, "first_version_term", "", None)
        .expect("a first-version constraint table is accepted");
    assert!(!term.separable_nonnegative());
}

/// An embodiment that answers well, then NaN: every answer is checked, not the first only, and
/// a bad one halts the robot and names the call and the field instead of reaching a result.
#[test]
fn an_embodiment_that_goes_bad_later_is_halted_and_named() {
    use human2nav_core::embodiment::{Embodiment, RobotState};
    let host = PluginHost::new();
    let robot = human2nav_plugin::RobotContext {
        limits: limits(),
        gains: Default::default(),
        footprint_radius: 0.3,
    };
    let e = host
        .embodiment(&lib("human2nav_fixture_bad_tables"), "late_nan", "", &robot)
        .expect("a valid table");
    let cmd = Twist2::new(0.5, 0.0, 0.1);
    let mut state = RobotState::default();
    let mut halted_at = None;
    for k in 0..100 {
        let next = e.step(&state, e.saturate(&state, cmd, 0.05), 0.05);
        assert!(
            [next.pose.x, next.pose.y, next.pose.theta]
                .iter()
                .all(|v| v.is_finite()),
            "step {k}: {next:?}"
        );
        if next.velocity == Twist2::ZERO && next.pose == state.pose {
            halted_at.get_or_insert(k);
        }
        state = next;
    }
    assert_eq!(halted_at, Some(40), "halted at the first bad answer");
    assert_eq!(e.saturate(&state, cmd, 0.05), Twist2::ZERO);
    let failure = e.failure().expect("the embodiment is marked failed");
    assert!(
        failure.contains("embodiment `late_nan`: step answered x = NaN"),
        "{failure}"
    );
    assert!(
        host.failures().iter().any(|f| f.message == failure),
        "{:?}",
        host.failures()
    );
}

#[test]
fn a_wrong_table_size_is_an_error() {
    let err = PluginHost::new()
        .constraint(
            &lib("human2nav_fixture_bad_tables"),
            "short_vtable",
            "",
            None,
        )
        .expect_err("8-byte vtable");
    let msg = err.to_string();
    assert!(
        matches!(err, PluginError::TableSize { size: 8, .. }),
        "{msg}"
    );
    assert!(
        msg.contains("the constraint vtable of `short_vtable` declares 8 bytes (struct_size); this host needs at least 40"),
        "{msg}"
    );
}

#[test]
fn absurd_lengths_from_a_plugin_are_capped() {
    let host = PluginHost::new();
    let library = lib("human2nav_fixture_bad_tables");
    // A 2^40-pose plan: before, the host tried to allocate 24 TB and aborted.
    let mut p = host
        .planner_with_deadline(&library, "huge_plan", "", None, None)
        .expect("a valid vtable");
    let err = p.plan(&obs()).expect_err("too long");
    assert!(
        err.to_string().contains(
            "returned a plan of 1099511627776 poses, more than the 10000 this host accepts"
        ),
        "{err}"
    );
    // The same through the deadline worker.
    let mut p = host
        .planner(&library, "huge_plan", "", None)
        .expect("a valid vtable");
    assert!(p.plan(&obs()).is_err());
    // A 2^40-byte instance name.
    let err = host
        .constraint(&library, "huge_name", "", None)
        .expect_err("name too long");
    assert!(
        err.to_string()
            .contains("the instance name is 1099511627776 bytes long, the limit is 256"),
        "{err}"
    );
}

#[test]
fn inspect_reports_what_it_checked() {
    let report = inspect_library(&lib("human2nav_personal_space"));
    assert!(report.ok(), "{}", report.render());
    let text = report.render();
    for needle in [
        "plugin    personal_space 0.1.0",
        "ok    file: regular file of",
        "ELF 64-bit",
        "ok    ABI version: 2 (this host: 2)",
        "ok    entry table:",
        "ok    factory table: 1 factories (limit 256)",
        "ok    factory 0 (constraint `personal_space`): create set",
    ] {
        assert!(text.contains(needle), "`{needle}` missing:\n{text}");
    }
    // The instance check: created with an empty config, or left for later.
    assert!(
        report
            .checks
            .iter()
            .any(|c| c.item == "constraint `personal_space` instance"),
        "{text}"
    );

    let report = inspect_library(&lib("human2nav_fixture_bad_tables"));
    let text = report.render();
    assert!(!report.ok(), "{text}");
    let failed: Vec<&str> = report
        .checks
        .iter()
        .filter(|c| c.status == CheckStatus::Failed)
        .map(|c| c.item.as_str())
        .collect();
    assert_eq!(
        failed,
        vec![
            "planner `null_plan` instance",
            "constraint `short_vtable` instance",
            "embodiment `null_step` instance",
            "constraint `huge_name` instance",
            "embodiment `bad_coupled` instance",
            "constraint `bad_properties` instance",
        ],
        "{text}"
    );
    assert!(text.contains("has a null `plan`"), "{text}");
    assert!(text.contains("declares 8 bytes"), "{text}");
    assert!(text.contains("properties returned error"), "{text}");
    assert!(
        text.contains("ok    planner `huge_plan` instance: created with an empty config"),
        "{text}"
    );
    assert!(matches!(
        report.error,
        Some(PluginError::NullSlot { slot: "plan", .. })
    ));
    // A library that does not load: the failed check is the last one.
    let report = inspect_library(&lib("human2nav_fixture_wrong_abi"));
    assert!(!report.ok());
    assert!(
        report
            .checks
            .last()
            .is_some_and(|c| c.status == CheckStatus::Failed && c.item == "ABI version"),
        "{}",
        report.render()
    );
}

// ------------------------------------------------------------------------------------------
// Deadlines

#[test]
fn a_planner_that_never_returns_gets_the_safe_plan_and_is_dead_afterwards() {
    let host = PluginHost::new();
    let library = lib("human2nav_fixture_test_plugin");
    let deadline = Duration::from_millis(100);
    let mut p = host
        .planner_with_deadline(&library, "straight", "hang = true", None, Some(deadline))
        .expect("created");
    assert_eq!(p.deadline(), Some(deadline));
    let started = Instant::now();
    let plan = p.plan(&obs()).expect("the safe plan");
    let waited = started.elapsed();
    assert!(
        waited >= deadline && waited < Duration::from_secs(2),
        "{waited:?}"
    );
    assert!(plan.info.fallback);
    let why = plan.info.error.as_deref().expect("flagged as an error");
    assert!(
        why.contains("did not return from `plan` within its deadline of 100 ms"),
        "{why}"
    );
    // Stop in place at the ego pose.
    assert!(plan.poses.iter().all(|q| *q == Pose2::IDENTITY));
    assert!(p.is_poisoned());
    // Later calls fail at once (no new thread waits on the hung one).
    let started = Instant::now();
    let err = p.plan(&obs()).expect_err("dead");
    assert!(started.elapsed() < Duration::from_millis(50));
    assert!(matches!(err, PlanError::Unusable { .. }), "{err}");
    p.reset();
    assert!(matches!(p.plan(&obs()), Err(PlanError::Unusable { .. })));
    let failures = host.failures();
    assert_eq!(failures.len(), 1, "{failures:?}");
    assert!(failures[0].message.contains("deadline"), "{failures:?}");
    // Dropping the dead planner does not wait for the hung call.
    let started = Instant::now();
    drop(p);
    assert!(started.elapsed() < Duration::from_millis(50));
}

#[test]
fn a_late_answer_writes_only_into_memory_the_call_owns() {
    let host = PluginHost::new();
    let mut p = host
        .planner_with_deadline(
            &lib("human2nav_fixture_test_plugin"),
            "straight",
            "sleep_ms = 300",
            None,
            Some(Duration::from_millis(30)),
        )
        .expect("created");
    let plan = p.plan(&obs()).expect("the safe plan");
    assert!(plan.info.error.is_some());
    drop(p);
    // The plugin answers 270 ms later into the abandoned call's own buffers, then the worker
    // destroys the instance; nothing of this process is touched.
    std::thread::sleep(Duration::from_millis(500));
    let mut fresh = host
        .planner(&lib("human2nav_fixture_test_plugin"), "straight", "", None)
        .expect("created");
    assert_eq!(fresh.plan(&obs()).expect("plans").poses.len(), 100);
}

#[test]
fn deadlines_default_to_one_second_and_zero_means_none() {
    let host = PluginHost::new();
    let library = lib("human2nav_fixture_test_plugin");
    let p = host
        .planner(&library, "straight", "", None)
        .expect("created");
    assert_eq!(
        p.deadline(),
        Some(human2nav_plugin::deadline::DEFAULT_DEADLINE)
    );
    assert_eq!(
        human2nav_plugin::deadline::DEFAULT_DEADLINE,
        Duration::from_millis(1000)
    );
    let c = host
        .constraint(&library, "quadratic", "", None)
        .expect("created");
    assert_eq!(c.deadline(), Some(Duration::from_millis(1000)));
    let spec: human2nav_plugin::PluginSpec = toml_spec(&library, "straight", "0");
    let r = spec.resolve(Path::new("/config.toml"));
    let mut p = host.planner_ref(&r, None).expect("created");
    assert_eq!(p.deadline(), None);
    p.plan(&obs()).expect("plans on the caller's thread");
}

/// A `PluginSpec` as a config file would give it.
fn toml_spec(library: &Path, plugin: &str, deadline_ms: &str) -> human2nav_plugin::PluginSpec {
    toml::from_str(&format!(
        "library = {:?}\nplugin = {plugin:?}\ndeadline_ms = {deadline_ms}",
        library.display().to_string()
    ))
    .expect("spec")
}

#[test]
fn a_constraint_that_never_returns_fails_and_is_dead_afterwards() {
    let host = PluginHost::new();
    let term = host
        .constraint_with_deadline(
            &lib("human2nav_fixture_test_plugin"),
            "quadratic",
            "hang = true",
            None,
            Some(Duration::from_millis(100)),
        )
        .expect("created");
    let started = Instant::now();
    let err = evaluate(&term).expect_err("timed out");
    assert!(started.elapsed() < Duration::from_secs(2));
    assert!(
        err.to_string()
            .contains("did not return from `evaluate` within its deadline of 100 ms"),
        "{err}"
    );
    assert!(term.is_poisoned());
    let started = Instant::now();
    let err = evaluate(&term).expect_err("dead");
    assert!(started.elapsed() < Duration::from_millis(50));
    assert!(err.to_string().contains("unusable"), "{err}");
    // A healthy term with a deadline gives the numbers it gives without one.
    let with = host
        .constraint(&lib("human2nav_personal_space"), "personal_space", "", None)
        .expect("created");
    let without = host
        .constraint_with_deadline(
            &lib("human2nav_personal_space"),
            "personal_space",
            "",
            None,
            None,
        )
        .expect("created");
    let l = limits();
    let agents = vec![human2nav_core::AgentState {
        id: 1,
        position: [0.5, 0.2],
        velocity: [0.0, 0.0],
        radius: 0.3,
        history: vec![[0.6, 0.2], [0.55, 0.2]],
    }];
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &l,
        initial_velocity: Twist2::ZERO,
        agents: &agents,
        scene: Default::default(),
    };
    let data: Vec<f64> = (0..12).map(|k| 0.05 * k as f64).collect();
    let run = |t: &dyn ConstraintTerm| {
        let (mut c, mut g) = (vec![0.5; 2], vec![0.25; 12]);
        t.evaluate(
            TrajBatch::new(&data, 2, 2).expect("shape"),
            &ctx,
            &mut c,
            &mut g,
        )
        .expect("evaluates");
        (c, g)
    };
    assert_eq!(run(&with), run(&without));
}

// ------------------------------------------------------------------------------------------
// Robot profiles with plugin embodiments

/// A copy of `robots/tracked` in a scratch directory with `robot.toml` edited by `edit`.
fn tracked_copy(name: &str, edit: impl Fn(String) -> String) -> PathBuf {
    let dir = scratch(name);
    let src = workspace_root().join("robots/tracked");
    std::fs::copy(src.join("tracked.urdf"), dir.join("tracked.urdf")).expect("copy urdf");
    let toml = std::fs::read_to_string(src.join("robot.toml")).expect("read profile");
    let libs = target_profile_dir();
    let toml = toml
        .replace(
            "../../target/{profile}/human2nav_skid_steer",
            &libs.join("human2nav_skid_steer").display().to_string(),
        )
        .replace(
            "../../target/{profile}/human2nav_personal_space",
            &libs.join("human2nav_personal_space").display().to_string(),
        );
    std::fs::write(dir.join("robot.toml"), edit(toml)).expect("write profile");
    dir.join("robot.toml")
}

#[test]
fn a_robot_profile_resolves_fully_or_fails_naming_what_is_broken() {
    let host = PluginHost::new();
    let ok = RobotProfile::load(&tracked_copy("resolve-ok", |t| t)).expect("profile");
    let r = host.resolve_robot(&ok).expect("the tracked robot resolves");
    assert!(
        r.embodiment
            .as_deref()
            .is_some_and(|l| l.starts_with("embodiment `skid_steer` from")),
        "{r:?}"
    );
    assert_eq!(r.constraints.len(), 1);

    type Edit = Box<dyn Fn(String) -> String>;
    let cases: [(&str, Edit, &str); 4] = [
        (
            "missing-library",
            Box::new(|t: String| t.replacen("human2nav_skid_steer", "human2nav_no_such_plugin", 1)),
            "not found",
        ),
        (
            "wrong-factory",
            Box::new(|t: String| {
                t.replace("plugin = \"skid_steer\"", "plugin = \"skid_steering\"")
            }),
            "has no embodiment factory named `skid_steering`; it provides: skid_steer",
        ),
        (
            "bad-config",
            Box::new(|t: String| t.replace("skid_factor = 1.5", "skid_factr = 1.5")),
            "rejected its config",
        ),
        (
            "not-an-embodiment",
            Box::new(|t: String| {
                t.replacen(
                    "human2nav_skid_steer\"\nplugin = \"skid_steer\"",
                    "human2nav_personal_space\"\nplugin = \"personal_space\"",
                    1,
                )
            }),
            "has no embodiment factory named `personal_space`",
        ),
    ];
    for (name, edit, needle) in cases {
        let path = tracked_copy(name, edit);
        // The profile itself parses: before, `robot check` stopped here and said "ok".
        let profile = RobotProfile::load(&path).expect("the profile parses");
        let err = host.resolve_robot(&profile).expect_err(name);
        let msg = err.to_string();
        assert!(
            msg.starts_with(&format!("robot profile {}, [embodiment]: ", path.display())),
            "{name}: {msg}"
        );
        assert!(msg.contains(needle), "{name}: {msg}");
        // The benchmark refuses it the same way, before any episode.
        let err = human2nav_sim::RobotSetup::load(&path).expect_err(name);
        assert!(err.to_string().contains(needle), "{name}: {err}");
    }
    // A constraint deadline out of range is a profile error.
    let path = tracked_copy("bad-deadline", |t| {
        t.replace("weight = 0.5", "weight = 0.5\ndeadline_ms = -3")
    });
    let err = RobotProfile::load(&path).expect_err("negative deadline");
    assert!(
        err.to_string().contains("constraint[0].deadline_ms"),
        "{err}"
    );
    let path = tracked_copy("ok-deadline", |t| {
        t.replace("weight = 0.5", "weight = 0.5\ndeadline_ms = 250")
    });
    let profile = RobotProfile::load(&path).expect("valid deadline");
    assert_eq!(profile.constraints[0].deadline_ms, Some(250.0));
    let robot = host.load_robot(profile).expect("loads");
    assert_eq!(robot.plugin_terms.len(), 1);
}

// ------------------------------------------------------------------------------------------
// The benchmark

/// A bench config in a scratch directory inside the workspace (so relative paths resolve
/// against the workspace root).
fn bench_config(name: &str, robots: &[&str], methods: &str) -> (BenchConfig, PathBuf) {
    let dir = scratch(name);
    let robots: Vec<String> = robots.iter().map(|r| format!("{r:?}")).collect();
    let text = format!(
        "seed = 3\nrobots = [{}]\n{methods}\n\
         [[suites]]\nname = \"synthetic\"\nkind = \"synthetic\"\nper_class = 1\n\n\
         [[suites]]\nname = \"empty\"\nkind = \"empty\"\nper_class = 1\n",
        robots.join(", ")
    );
    let path = dir.join("bench.toml");
    std::fs::write(&path, text).expect("write config");
    (BenchConfig::load(&path).expect("config"), dir)
}

fn methods(cfg: &BenchConfig) -> Vec<MethodSpec> {
    let host = Arc::new(PluginHost::new());
    cfg.methods
        .iter()
        .map(|m| {
            builtin_method(m, cfg, &host)
                .expect("method")
                .expect("a built-in kind")
        })
        .collect()
}

#[test]
fn the_bench_runs_the_tracked_robot_through_its_plugin_embodiment() {
    let orca = lib("human2nav_orca");
    let (cfg, dir) = bench_config(
        "bench-tracked",
        &["robots/tracked/robot.toml", "robots/diablo/robot.toml"],
        &format!(
            "[[methods]]\nname = \"straight\"\nkind = \"straight\"\n\n\
             [[methods]]\nname = \"orca\"\nkind = \"plugin\"\nlibrary = {:?}\n",
            orca.display().to_string()
        ),
    );
    // Before, this failed: "the embodiment is a plugin; load it through the plugin host".
    let robots = load_robots(&cfg).expect("the tracked robot loads for the bench");
    assert_eq!(robots[0].name, "tracked");
    assert_eq!(robots[0].embodiment.name(), "skid_steer");
    let suites = build_suites(&cfg, false, None).expect("suites");
    let rows = bench::run_bench(
        &suites,
        &robots,
        &methods(&cfg),
        &cfg.sim,
        cfg.seed,
        &ProgressBar::hidden(),
    )
    .expect("runs");
    let tracked: Vec<_> = rows.iter().filter(|r| r.robot == "tracked").collect();
    assert_eq!(tracked.len(), 2 * 2 * 4);
    for r in &tracked {
        assert_eq!(r.metrics.planner_errors, 0, "{} {}", r.method, r.episode);
        assert!(
            r.metrics.path_length > 0.5,
            "{} {}: did not move",
            r.method,
            r.episode
        );
    }
    // In the empty world both methods bring the tracked robot to its goal.
    for r in tracked.iter().filter(|r| r.suite_kind == SuiteKind::Empty) {
        assert!(
            r.metrics.success,
            "{} {}: {:?}",
            r.method, r.episode, r.metrics.outcome
        );
    }
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn a_planner_that_fails_every_call_is_reported_loudly_and_fails_the_bench() {
    let fixture = lib("human2nav_fixture_test_plugin");
    let (cfg, dir) = bench_config(
        "bench-failing",
        &["robots/diablo/robot.toml"],
        &format!(
            "[[methods]]\nname = \"straight\"\nkind = \"straight\"\n\n\
             [[methods]]\nname = \"broken\"\nkind = \"plugin\"\nlibrary = {lib:?}\nplugin = \"straight\"\nconfig = {{ fail = true }}\n\n\
             [[methods]]\nname = \"hung\"\nkind = \"plugin\"\nlibrary = {lib:?}\nplugin = \"straight\"\nconfig = {{ hang = true }}\ndeadline_ms = 20\n",
            lib = fixture.display().to_string()
        ),
    );
    let robots = load_robots(&cfg).expect("robots");
    let suites = build_suites(&cfg, false, None).expect("suites");
    let methods = methods(&cfg);
    let plan = BenchPlan {
        suites: &suites,
        robots: &robots,
        methods: &methods,
        sim: &cfg.sim,
        seed: cfg.seed,
        quick: true,
        snapshot_method: Some("straight"),
        command: "failing planner test".into(),
        threads: Some(2),
        failures: 0,
        record: None,
    };
    let out = driver::run(&plan, &dir.join("out"), &ProgressBar::hidden()).expect("runs");
    assert!(!out.passed());
    assert!(out.has_failed_planner_calls());
    let names: Vec<&str> = out
        .planner_failures
        .iter()
        .map(|f| f.method.as_str())
        .collect();
    assert_eq!(names, vec!["broken", "hung"]);
    for f in &out.planner_failures {
        assert_eq!(f.runs, 8, "{f:?}");
        assert_eq!(f.failed, f.calls, "{f:?}");
        assert_eq!(f.runs_all_failed, f.runs, "{f:?}");
    }
    let report = std::fs::read_to_string(&out.report_md).expect("report");
    assert!(
        report.contains("> **Warning: planner calls failed.**"),
        "{report}"
    );
    let broken = &out.planner_failures[0];
    assert!(
        report.contains(&format!(
            "> | broken | diablo | 8 | {} | **{} (100.0 %)** | 8 |",
            broken.calls, broken.failed
        )),
        "{report}"
    );
    // The TFS table no longer shows a robot that never moved as simply feasible: its last
    // column counts the failed calls.
    let row = report
        .lines()
        .find(|l| l.starts_with("| diablo | broken | 4 |") && l.split('|').count() == 10)
        .unwrap_or_else(|| panic!("no TFS row for `broken`:\n{report}"));
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let failed = cells[8].trim_matches('*');
    let (a, b) = failed.split_once(" of ").unwrap_or_else(|| panic!("{row}"));
    assert_eq!(a, b, "{row}");
    assert!(cells[8].starts_with("**"), "{row}");
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn plugin_kinds_are_named_in_unknown_factory_errors_of_the_bad_tables_fixture() {
    let err = PluginHost::new()
        .planner(&lib("human2nav_fixture_bad_tables"), "nope", "", None)
        .expect_err("unknown");
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
    assert!(err.to_string().contains("null_plan, huge_plan"), "{err}");
}
