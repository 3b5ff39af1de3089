//! The table of hostile cases (issue #17), executable: each case feeds one bad input to the
//! loader that reads it (robot profiles, configuration files, episodes and datasets, the model
//! folder, plugins, checkpoints after a `kill -9`, concurrent runs), a few through the
//! `human2nav` binary, and states the outcome it must have: an error whose text contains the
//! listed fragments (the file, field or line it names), or a documented bound. Cases already
//! pinned by a regression test elsewhere are listed with that test's name instead of running
//! twice; a test checks the named tests exist.
//!
//! `docs/hostile-inputs.md` is generated from this table: `BLESS=1 cargo test -p human2nav-cli
//! --test hostile_inputs` rewrites it, and the test fails while it is out of date. The "before"
//! column is the behaviour the issue or the history recorded, else "not recorded".
//!
//! Needs the plugin libraries built (`cargo build --workspace`, as `sdk/dev.sh test` does).

use human2nav_core::fileset;
use human2nav_core::guidance::GuidanceSettings;
use human2nav_core::lock::DirLock;
use human2nav_core::robot::RobotProfile;
use human2nav_core::{Observation, PlanError, Planner, Pose2};
use human2nav_data::cache::CACHE_VERSION;
use human2nav_data::homography::Homography;
use human2nav_data::loaders::{eth, sgan, ucy};
use human2nav_data::tuples::{CompactTuple, Split, TupleOptions, TupleStats};
use human2nav_data::{Manifest, SceneInfo, TupleCache};
use human2nav_flow::ModelCard;
use human2nav_flow::planner::{Backend, PlannerConfig, RobotPlanner, load_model};
use human2nav_plugin::resolve::resolve_library_path;
use human2nav_plugin::{PluginHost, PluginLibrary};
use serde_json::Value;
use std::error::Error;
use std::path::{Path, PathBuf};
use std::process::Command;

type Run = Box<dyn Fn(&Path) -> Result<(), String>>;

/// What a case must produce.
enum Expect {
    /// An error containing every fragment.
    Error(&'static [&'static str]),
    /// Success: within a documented bound, or accepted as it is (the text says which).
    Accepted(&'static str),
    /// Pinned by the test `file::name` (path from the workspace root); the text is its outcome.
    Covered(&'static str, &'static str),
}

struct Case {
    area: &'static str,
    case: &'static str,
    before: &'static str,
    expect: Expect,
    run: Option<Run>,
}

const NR: &str = "not recorded";

fn err(
    area: &'static str,
    case: &'static str,
    before: &'static str,
    fragments: &'static [&'static str],
    run: impl Fn(&Path) -> Result<(), String> + 'static,
) -> Case {
    Case {
        area,
        case,
        before,
        expect: Expect::Error(fragments),
        run: Some(Box::new(run)),
    }
}

fn accepted(
    area: &'static str,
    case: &'static str,
    before: &'static str,
    after: &'static str,
    run: impl Fn(&Path) -> Result<(), String> + 'static,
) -> Case {
    Case {
        area,
        case,
        before,
        expect: Expect::Accepted(after),
        run: Some(Box::new(run)),
    }
}

fn covered(
    area: &'static str,
    case: &'static str,
    before: &'static str,
    after: &'static str,
    test: &'static str,
) -> Case {
    Case {
        area,
        case,
        before,
        expect: Expect::Covered(after, test),
        run: None,
    }
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// An error and its sources, one line.
fn chain(e: &dyn Error) -> String {
    let mut s = e.to_string();
    let mut src = e.source();
    while let Some(c) = src {
        let t = c.to_string();
        if !s.contains(&t) {
            s.push_str(": ");
            s.push_str(&t);
        }
        src = c.source();
    }
    s
}

fn fail<T, E: Error>(r: Result<T, E>) -> Result<(), String> {
    r.map(|_| ()).map_err(|e| chain(&e))
}

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    if let Some(parent) = p.parent() {
        std::fs::create_dir_all(parent).expect("scratch folder");
    }
    std::fs::write(&p, bytes).expect("scratch file");
    p
}

fn fifo(path: &Path) {
    let status = Command::new("mkfifo").arg(path).status().expect("mkfifo");
    assert!(status.success(), "mkfifo {}", path.display());
}

/// Nested `depth` deep: `open` repeated, then `close` repeated.
fn nested(open: &str, close: &str, depth: usize) -> String {
    format!("{}{}", open.repeat(depth), close.repeat(depth))
}

// ---------------------------------------------------------------------------------------------
// Robot profiles: the shipped diablo with one edit.

const DIABLO: &str = include_str!("../../../robots/diablo/robot.toml");
const DIABLO_URDF: &str = include_str!("../../../robots/diablo/diablo.urdf");

fn robot_with(dir: &Path, toml: &str, urdf: Option<&str>) -> Result<(), String> {
    write(dir, "diablo.urdf", urdf.unwrap_or(DIABLO_URDF));
    let path = write(dir, "robot.toml", toml);
    fail(RobotProfile::load(&path))
}

/// Diablo with `from` replaced by `to` (which must occur).
fn robot_edit(from: &'static str, to: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        assert!(DIABLO.contains(from), "diablo's robot.toml has no `{from}`");
        robot_with(dir, &DIABLO.replacen(from, to, 1), None)
    }
}

/// Diablo with `from` replaced by `to` (which must occur) in its URDF.
fn urdf_edit(from: &'static str, to: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        assert!(DIABLO_URDF.contains(from), "diablo's URDF has no `{from}`");
        robot_with(dir, DIABLO, Some(&DIABLO_URDF.replacen(from, to, 1)))
    }
}

/// The cases of robot profiles: a table, one entry per case, hence longer than a function should be.
fn robot_cases() -> Vec<Case> {
    let a = "robot profiles";
    vec![
        err(
            a,
            "robot `name = \"../../x\"`",
            "`plan` without `--out` wrote outside `out/`",
            &["name", "file names"],
            robot_edit("name = \"diablo\"", "name = \"../../x\""),
        ),
        err(
            a,
            "`v_max = -1.0`",
            NR,
            &["v_max"],
            robot_edit("v_max = 1.5", "v_max = -1.0"),
        ),
        err(
            a,
            "`v_max = nan`",
            NR,
            &["v_max"],
            robot_edit("v_max = 1.5", "v_max = nan"),
        ),
        err(
            a,
            "`v_max = inf`",
            NR,
            &["v_max"],
            robot_edit("v_max = 1.5", "v_max = inf"),
        ),
        err(
            a,
            "`a_max = 0`",
            NR,
            &["a_max"],
            robot_edit("a_max = 1.0", "a_max = 0.0"),
        ),
        err(
            a,
            "`omega_max = -2`",
            NR,
            &["omega_max"],
            robot_edit("omega_max = 2.0", "omega_max = -2.0"),
        ),
        err(
            a,
            "`v_reverse_max = -0.5`",
            NR,
            &["v_reverse_max"],
            robot_edit("v_reverse_max = 0.5", "v_reverse_max = -0.5"),
        ),
        err(
            a,
            "`lateral_speed_max = -1`",
            NR,
            &["lateral_speed_max"],
            robot_edit("lateral_speed_max = 0.05", "lateral_speed_max = -1.0"),
        ),
        err(
            a,
            "`min_turning_radius = -1`",
            NR,
            &["min_turning_radius"],
            robot_edit("min_turning_radius = 0.0", "min_turning_radius = -1.0"),
        ),
        err(
            a,
            "misspelt key `v_maxx` in `[limits]`",
            NR,
            &["v_maxx"],
            robot_edit("v_max = 1.5", "v_maxx = 1.5"),
        ),
        err(
            a,
            "a key given twice",
            NR,
            &["robot.toml", "duplicate key"],
            robot_edit("v_max = 1.5", "v_max = 1.5\nv_max = 1.0"),
        ),
        err(
            a,
            "`v_max = \"fast\"` (wrong type)",
            NR,
            &["robot.toml", "v_max"],
            robot_edit("v_max = 1.5", "v_max = \"fast\""),
        ),
        err(
            a,
            "unknown embodiment kind",
            NR,
            &["hovercraft"],
            robot_edit("kind = \"differential_drive\"", "kind = \"hovercraft\""),
        ),
        err(
            a,
            "wheel joint not in the URDF",
            NR,
            &["nope_joint"],
            robot_edit("\"left_wheel_joint\"", "\"nope_joint\""),
        ),
        err(
            a,
            "base link not in the URDF",
            NR,
            &["nowhere"],
            robot_edit("base_link = \"base_link\"", "base_link = \"nowhere\""),
        ),
        err(
            a,
            "URDF file missing",
            NR,
            &["missing.urdf"],
            robot_edit("urdf = \"diablo.urdf\"", "urdf = \"missing.urdf\""),
        ),
        err(
            a,
            "URDF path names `/dev/zero`",
            "memory grew without bound",
            &["/dev/zero", "regular file"],
            robot_edit("urdf = \"diablo.urdf\"", "urdf = \"/dev/zero\""),
        ),
        err(
            a,
            "URDF path names a FIFO",
            "blocked forever",
            &["fifo.urdf", "FIFO"],
            |d| {
                fifo(&d.join("fifo.urdf"));
                robot_with(
                    d,
                    &DIABLO.replacen("urdf = \"diablo.urdf\"", "urdf = \"fifo.urdf\"", 1),
                    None,
                )
            },
        ),
        err(
            a,
            "URDF path names a directory",
            NR,
            &["regular file", "directory"],
            |d| {
                std::fs::create_dir_all(d.join("dir.urdf")).map_err(|e| e.to_string())?;
                robot_with(
                    d,
                    &DIABLO.replacen("urdf = \"diablo.urdf\"", "urdf = \"dir.urdf\"", 1),
                    None,
                )
            },
        ),
        err(
            a,
            "URDF nested 100 000 elements deep",
            "stack overflow (abort)",
            &["diablo.urdf", "64"],
            |d| {
                let deep = format!(
                    "<robot name=\"x\">{}</robot>",
                    nested("<a>", "</a>", 100_000)
                );
                robot_with(d, DIABLO, Some(&deep))
            },
        ),
        err(a, "URDF of 20 MB", NR, &["diablo.urdf", "16 MiB"], |d| {
            let big = format!("{DIABLO_URDF}<!--{}-->", "x".repeat(20_000_000));
            robot_with(d, DIABLO, Some(&big))
        }),
        err(a, "URDF that is not XML", NR, &["diablo.urdf"], |d| {
            robot_with(d, DIABLO, Some("this is not xml <<<"))
        }),
        err(a, "URDF that is empty", NR, &["diablo.urdf"], |d| {
            robot_with(d, DIABLO, Some(""))
        }),
        err(a, "robot.toml of 2 MB", NR, &["robot.toml", "1 MiB"], |d| {
            robot_with(d, &format!("{DIABLO}\n#{}", "x".repeat(2_000_000)), None)
        }),
        err(
            a,
            "robot.toml not UTF-8",
            NR,
            &["robot.toml", "UTF-8"],
            |d| {
                write(d, "diablo.urdf", DIABLO_URDF);
                let mut bytes = DIABLO.as_bytes().to_vec();
                bytes.extend_from_slice(b"\n# \xff\xfe\n");
                fail(RobotProfile::load(&write(d, "robot.toml", bytes)))
            },
        ),
        err(
            a,
            "robot.toml empty",
            NR,
            &["robot.toml", "missing field"],
            |d| robot_with(d, "", None),
        ),
        err(
            a,
            "robot.toml is a FIFO",
            NR,
            &["robot.toml", "FIFO"],
            |d| {
                let p = d.join("robot.toml");
                fifo(&p);
                fail(RobotProfile::load(&p))
            },
        ),
        err(a, "robot.toml missing", NR, &["robot.toml"], |d| {
            fail(RobotProfile::load(&d.join("robot.toml")))
        }),
        err(
            a,
            "array nested 10 000 deep in robot.toml",
            NR,
            &["robot.toml"],
            |d| {
                robot_with(
                    d,
                    &format!("{DIABLO}\nx = {}", nested("[", "]", 10_000)),
                    None,
                )
            },
        ),
        err(
            a,
            "controller gain `k_x = nan`",
            NR,
            &["k_x"],
            robot_edit("k_x = 1.5", "k_x = nan"),
        ),
        err(
            a,
            "controller gain `k_theta = -3`",
            NR,
            &["k_theta"],
            robot_edit("k_theta = 3.0", "k_theta = -3.0"),
        ),
        err(
            a,
            "guidance weight `lambda_v = -1`",
            NR,
            &["lambda_v"],
            robot_edit("lambda_v = 1.0", "lambda_v = -1.0"),
        ),
        err(
            a,
            "guidance `gamma = inf`",
            NR,
            &["gamma"],
            robot_edit("gamma = 10.0", "gamma = inf"),
        ),
        err(
            a,
            "guidance `delta = nan`",
            NR,
            &["delta"],
            robot_edit("delta = 0.05", "delta = nan"),
        ),
        err(a, "`[limits]` table missing", NR, &["limits"], |d| {
            let start = DIABLO.find("[limits]").expect("limits table");
            let end = DIABLO.find("[controller]").expect("controller table");
            robot_with(d, &format!("{}{}", &DIABLO[..start], &DIABLO[end..]), None)
        }),
        err(
            a,
            "`v_max = 1e-300`",
            "accepted: infinite costs (1/limit overflows)",
            &["limits.v_max", "1e-300"],
            robot_edit("v_max = 1.5", "v_max = 1e-300"),
        ),
        err(
            a,
            "`v_max = 1e300`",
            "accepted",
            &["limits.v_max", "1e300"],
            robot_edit("v_max = 1.5", "v_max = 1e300"),
        ),
        err(
            a,
            "controller gain `k_x = 1e300`",
            "accepted",
            &["controller.k_x", "1e3"],
            robot_edit("k_x = 1.5", "k_x = 1e300"),
        ),
        err(
            a,
            "guidance `gamma = 1e-300`",
            "accepted: Φ's softplus overflowed",
            &["cost.gamma", "1e-300"],
            robot_edit("gamma = 10.0", "gamma = 1e-300"),
        ),
        err(
            a,
            "the same wheel joint listed twice",
            "accepted: the wheel counted twice",
            &[
                "embodiment.wheel_joints[1]",
                "already embodiment.wheel_joints[0]",
            ],
            robot_edit(
                "\"right_wheel_joint\"",
                "\"left_wheel_joint\", \"right_wheel_joint\"",
            ),
        ),
        err(
            a,
            "two wheel joints at the same position",
            "accepted: a track of 0 m",
            &["embodiment.wheel_joints[1]", "sits where wheel_joints[0]"],
            urdf_edit("xyz=\"0 -0.24 0.09\"", "xyz=\"0 0.24 0.09\""),
        ),
        err(
            a,
            "URDF joints forming a cycle",
            "accepted",
            &["diablo.urdf", "cycle"],
            urdf_edit(
                "</robot>",
                "<joint name=\"loop\" type=\"fixed\"><parent link=\"left_wheel\"/>\
                 <child link=\"base_link\"/></joint></robot>",
            ),
        ),
        err(
            a,
            "URDF link defined twice",
            "accepted: the last one won",
            &["diablo.urdf", "link `left_wheel`", "defined twice"],
            urdf_edit("</robot>", "<link name=\"left_wheel\"/></robot>"),
        ),
        err(
            a,
            "URDF wheel `velocity = \"nan\"`",
            "accepted: the cap was dropped silently",
            &["joint `left_wheel_joint`", "velocity=\"NaN\""],
            urdf_edit("velocity=\"22.0\"", "velocity=\"nan\""),
        ),
        err(
            a,
            "URDF wheel `velocity = \"-22\"`",
            "accepted: the cap was dropped silently",
            &["joint `left_wheel_joint`", "velocity=\"-22\""],
            urdf_edit("velocity=\"22.0\"", "velocity=\"-22\""),
        ),
        covered(
            a,
            "plugin embodiment naming a missing library, a wrong factory or a bad config",
            "passed `robot check`",
            "`robot check` fails naming the library, factory or config key",
            "sdk/cli/tests/robot_check.rs::plugin_embodiments_are_resolved_and_a_broken_declaration_fails",
        ),
        covered(
            a,
            "plugin-embodiment robot (shipped `robots/tracked`) in `bench`",
            "`bench` refused every plugin-embodiment robot",
            "runs through its plugin embodiment",
            "tests/tests/plugins_hardening.rs::the_bench_runs_the_tracked_robot_through_its_plugin_embodiment",
        ),
        covered(
            a,
            "profile resolved with a broken plugin term or embodiment",
            NR,
            "error naming what is broken",
            "tests/tests/plugins_hardening.rs::a_robot_profile_resolves_fully_or_fails_naming_what_is_broken",
        ),
    ]
}

// ---------------------------------------------------------------------------------------------
// Configuration files.

const PLANNER: &str = include_str!("../../../sdk/configs/planner.toml");
const BENCH: &str = include_str!("../../../sdk/configs/bench.toml");
const DATA: &str = include_str!("../../../sdk/configs/data.toml");
const GUIDANCE: &str = include_str!("../../../sdk/configs/guidance.toml");
const SARL: &str = include_str!("../../../sdk/configs/sarl.toml");
const TRAIN: &str = include_str!("../../../sdk/configs/train.toml");

fn edit(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from), "the shipped file has no `{from}`");
    text.replacen(from, to, 1)
}

fn planner_edit(from: &'static str, to: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    planner_edits(vec![(from, to)])
}

/// The shipped planner file with several edits, each as [`edit`].
fn planner_edits(edits: Vec<(&'static str, &'static str)>) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let text = edits
            .iter()
            .fold(PLANNER.to_string(), |t, (from, to)| edit(&t, from, to));
        let p = write(dir, "planner.toml", text);
        fail(PlannerConfig::load(&p))
    }
}

fn bench_edit(from: &'static str, to: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let p = write(dir, "bench.toml", edit(BENCH, from, to));
        fail(human2nav_sim::config::BenchConfig::load(&p))
    }
}

fn data_edit(from: &'static str, to: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let p = write(dir, "data.toml", edit(DATA, from, to));
        fail(human2nav_data::config::DataConfig::load(&p))
    }
}

/// A `human2nav` method of the shipped bench.toml with `config = <config>`, built.
fn human2nav_method_with(dir: &Path, config: &str) -> Result<(), String> {
    let p = write(dir, "bench.toml", BENCH);
    let cfg = human2nav_sim::config::BenchConfig::load(&p).map_err(|e| chain(&e))?;
    let m: human2nav_sim::config::MethodConfig = toml::from_str(&format!(
        "name = \"h\"\nkind = \"human2nav\"\nconfig = {config}\n"
    ))
    .map_err(|e| chain(&e))?;
    human2nav_experiments::bench::human2nav_method(&m, &cfg)
        .map(|_| ())
        .map_err(|e| format!("{e:#}"))
}

fn sarl_edit(from: &'static str, to: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let p = write(dir, "sarl.toml", edit(SARL, from, to));
        fail(human2nav_sarl::train::TrainConfig::load(&p))
    }
}

/// The cases of configs: a table, one entry per case, hence longer than a function should be.
fn config_cases() -> Vec<Case> {
    let a = "configs";
    vec![
        err(
            a,
            "planner.toml `threads = 100000`",
            "stack overflow (abort)",
            &["threads", "256"],
            planner_edit("threads = 1 ", "threads = 100000 "),
        ),
        err(
            a,
            "planner.toml `threads = 0`",
            NR,
            &["threads"],
            planner_edit("threads = 1 ", "threads = 0 "),
        ),
        err(
            a,
            "planner.toml `backend = \"gpu\"`",
            NR,
            &["planner.toml", "gpu"],
            planner_edit("backend = \"native\"", "backend = \"gpu\""),
        ),
        err(
            a,
            "planner.toml `model = \"\"`",
            NR,
            &["model"],
            planner_edit("model = \"models/human2nav-cfm\"", "model = \"\""),
        ),
        err(
            a,
            "planner.toml `samples = 100000`",
            "ran without an upper bound",
            &["samples", "1024"],
            planner_edit("\nsamples = 4 ", "\nsamples = 100000 "),
        ),
        err(
            a,
            "planner.toml `samples = 0` with `motions = 0` (nothing to plan from)",
            NR,
            &["samples"],
            planner_edits(vec![
                ("\nsamples = 4 ", "\nsamples = 0 "),
                ("\nmotions = 500 ", "\nmotions = 0 "),
            ]),
        ),
        err(
            a,
            "planner.toml `samples = 0` with `motions_recovery = true`",
            NR,
            &["motions_recovery"],
            planner_edits(vec![
                ("\nsamples = 4 ", "\nsamples = 0 "),
                ("\nmotions_recovery = false", "\nmotions_recovery = true"),
            ]),
        ),
        err(
            a,
            "planner.toml `[prediction.flow] samples = 0`",
            NR,
            &["prediction.flow.samples"],
            planner_edit(
                "samples = 4                       # scenes",
                "samples = 0 # scenes",
            ),
        ),
        err(
            a,
            "planner.toml `constant_velocity_weight` without the constant-velocity scene",
            NR,
            &[
                "prediction.flow.constant_velocity_weight",
                "constant_velocity_scene",
            ],
            planner_edit(
                "# constant_velocity_weight = 0.5 ",
                "constant_velocity_weight = 0.5 ",
            ),
        ),
        err(
            a,
            "planner.toml `deviation_horizon = 0`",
            NR,
            &["prediction.flow.deviation_horizon", "> 0"],
            planner_edit("# deviation_horizon = 2.0 ", "deviation_horizon = 0.0 "),
        ),
        err(
            a,
            "planner.toml `[prediction.flow] robot_radius = -1`",
            NR,
            &["prediction.flow.robot_radius"],
            planner_edit("robot_radius = 0.4 ", "robot_radius = -1 "),
        ),
        err(
            a,
            "planner.toml `iterations_m = 1000000000`",
            "ran without an upper bound",
            &["iterations_m", "1000"],
            planner_edit("iterations_m = 3 ", "iterations_m = 1000000000 "),
        ),
        err(
            a,
            "planner.toml `steps_n = 0`",
            NR,
            &["steps_n"],
            planner_edit("steps_n = 5 ", "steps_n = 0 "),
        ),
        err(
            a,
            "planner.toml `dt = -0.1`",
            NR,
            &["dt"],
            planner_edit("dt = 0.1 ", "dt = -0.1 "),
        ),
        err(
            a,
            "planner.toml `goal_clip = nan`",
            NR,
            &["goal_clip"],
            planner_edit("goal_clip = 6.0", "goal_clip = nan"),
        ),
        err(
            a,
            "planner.toml `guided_samples = 5000`",
            NR,
            &["guided_samples", "1024"],
            planner_edit("guided_samples = 4 ", "guided_samples = 5000 "),
        ),
        err(
            a,
            "planner.toml projection `iterations = 1000`",
            NR,
            &["iterations", "100"],
            planner_edit("iterations = 1 ", "iterations = 1000 "),
        ),
        err(
            a,
            "planner.toml selection `margin = -1`",
            NR,
            &["margin"],
            planner_edit("margin = 0.5 ", "margin = -1.0 "),
        ),
        err(
            a,
            "planner.toml guidance `variant = \"magic\"`",
            NR,
            &["planner.toml", "magic"],
            planner_edit("variant = \"adaptive\"", "variant = \"magic\""),
        ),
        err(
            a,
            "planner.toml unknown key",
            NR,
            &["planner.toml", "sampels"],
            planner_edit("\nsamples = 4 ", "\nsampels = 4 "),
        ),
        err(
            a,
            "planner.toml is a FIFO",
            NR,
            &["planner.toml", "FIFO"],
            |d| {
                let p = d.join("planner.toml");
                fifo(&p);
                fail(PlannerConfig::load(&p))
            },
        ),
        err(
            a,
            "planner.toml of 5 MB",
            NR,
            &["planner.toml", "4 MiB"],
            |d| {
                let p = write(
                    d,
                    "planner.toml",
                    format!("{PLANNER}\n#{}", "x".repeat(5_000_000)),
                );
                fail(PlannerConfig::load(&p))
            },
        ),
        err(
            a,
            "bench.toml method named with a terminal escape (`or\\u001b[2Kca`)",
            "went raw into stdout, report.md and results.csv",
            &["methods[0]", "name", "control character"],
            bench_edit("name = \"orca\"", "name = \"or\\u001b[2Kca\""),
        ),
        err(
            a,
            "bench.toml suite named `../x`",
            NR,
            &["suites[0]", "name", "file names"],
            bench_edit("name = \"real\"", "name = \"../x\""),
        ),
        err(
            a,
            "bench.toml `[sim] dt = 0`",
            NR,
            &["dt"],
            bench_edit("dt = 0.05 ", "dt = 0.0 "),
        ),
        err(
            a,
            "bench.toml `budget_margin = 1e9`",
            "tried to allocate tens of GB and aborted",
            &["budget_margin", "3600"],
            bench_edit("budget_margin = 3.0 ", "budget_margin = 1e9 "),
        ),
        err(
            a,
            "bench.toml `budget_factor = 1000`",
            NR,
            &["budget_factor", "100"],
            bench_edit("budget_factor = 1.5 ", "budget_factor = 1000.0 "),
        ),
        err(
            a,
            "bench.toml `replan_hz = 0`",
            NR,
            &["replan_hz"],
            bench_edit("replan_hz = 10.0 ", "replan_hz = 0.0 "),
        ),
        err(
            a,
            "bench.toml `goal_tolerance = nan`",
            NR,
            &["goal_tolerance"],
            bench_edit("goal_tolerance = 0.3 ", "goal_tolerance = nan "),
        ),
        err(
            a,
            "bench.toml suite `per_class = 0`",
            NR,
            &["per_class"],
            bench_edit("per_class = 50", "per_class = 0"),
        ),
        err(
            a,
            "bench.toml suite `per_class = 1000000`",
            "generated that many episodes up front",
            &["per_class", "10000"],
            bench_edit("per_class = 50", "per_class = 1000000"),
        ),
        err(
            a,
            "bench.toml `start_heading = \"north\"`",
            NR,
            &["bench.toml", "north"],
            bench_edit("start_heading = \"face_goal\"", "start_heading = \"north\""),
        ),
        err(
            a,
            "bench.toml human2nav method `foresight_within` without `foresight`",
            NR,
            &["methods[h].config.foresight_within", "needs"],
            |d| human2nav_method_with(d, "{ foresight_within = 2.0 }"),
        ),
        err(
            a,
            "bench.toml human2nav method `foresight = 2`",
            NR,
            &["methods[h].config.foresight", "0 to 1"],
            |d| human2nav_method_with(d, "{ foresight = 2.0 }"),
        ),
        err(
            a,
            "bench.toml human2nav method `history_ridge` of the wrong shape",
            NR,
            &[
                "methods[h].config.history_ridge",
                "ridge.toml",
                "weights",
                "needs 6",
            ],
            |d| {
                let p = write(
                    d,
                    "ridge.toml",
                    "history = 1\nhorizon = 1\ndt = 0.1\nfitted_on = \"\"\nweights = [0.0]\n",
                );
                human2nav_method_with(d, &format!("{{ history_ridge = {:?} }}", p.display()))
            },
        ),
        err(
            a,
            "bench.toml listing the same robot twice",
            "every run of that robot counted twice, exit 0",
            &["robots[1]", "is already robots[0]"],
            |d| {
                let diablo = root().join("robots/diablo/robot.toml");
                let p = write(
                    d,
                    "bench.toml",
                    edit(
                        BENCH,
                        "    \"robots/go2/robot.toml\",",
                        &format!("    {:?},", diablo.display().to_string()),
                    )
                    .replace(
                        "    \"robots/diablo/robot.toml\",",
                        &format!("    {:?},", diablo.display().to_string()),
                    )
                    .replace("    \"robots/ackermann/robot.toml\",", ""),
                );
                let cfg = human2nav_sim::config::BenchConfig::load(&p).map_err(|e| chain(&e))?;
                fail(human2nav_sim::config::load_robots(&cfg))
            },
        ),
        err(
            a,
            "bench.toml `base` naming a missing file",
            NR,
            &["missing_base.toml"],
            |d| {
                let p = write(d, "bench.toml", "base = \"missing_base.toml\"\n");
                fail(human2nav_sim::config::BenchConfig::load(&p))
            },
        ),
        err(
            a,
            "bench.toml naming itself as `base`",
            NR,
            &["bench.toml", "base"],
            |d| {
                let p = write(
                    d,
                    "bench.toml",
                    format!("base = \"{}\"\n", d.join("bench.toml").display()),
                );
                fail(human2nav_sim::config::BenchConfig::load(&p))
            },
        ),
        err(
            a,
            "data.toml `synthetic_scenes = 1000000000`",
            NR,
            &["synthetic_scenes", "100000"],
            data_edit("synthetic_scenes = 400 ", "synthetic_scenes = 1000000000 "),
        ),
        err(
            a,
            "data.toml `reference_speed = 1e-300`",
            "infinite budgets, overflowing step arithmetic",
            &["reference_speed"],
            data_edit("reference_speed = 1.0 ", "reference_speed = 1e-300 "),
        ),
        err(
            a,
            "data.toml `max_goal_time = 1e9`",
            NR,
            &["max_goal_time", "86400"],
            data_edit("max_goal_time = 10.0 ", "max_goal_time = 1e9 "),
        ),
        err(
            a,
            "data.toml unknown table",
            NR,
            &["data.toml", "sorces"],
            data_edit("[sources]", "[sorces]"),
        ),
        err(
            a,
            "data.toml `exclude_episodes` names a missing file",
            NR,
            &["interaction.exclude_episodes", "gone.json"],
            |dir| {
                let p = write(
                    dir,
                    "data.toml",
                    edit(
                        DATA,
                        "exclude_episodes = [] ",
                        "exclude_episodes = [\"gone.json\"] ",
                    ),
                );
                let cfg = human2nav_data::config::DataConfig::load(&p).map_err(|e| chain(&e))?;
                let loc = human2nav_data::pipeline::Locations {
                    workspace: dir.to_path_buf(),
                    data_root: dir.join("no-datasets"),
                    cache_dir: dir.join("cache"),
                    episodes: dir.join("episodes.json"),
                };
                fail(human2nav_data::pipeline::build_interaction_episodes(
                    &cfg,
                    &loc,
                    Split::Val,
                    &human2nav_data::pipeline::NoProgress,
                ))
            },
        ),
        err(a, "guidance.toml unknown key", NR, &["iteration_m"], |_| {
            fail(GuidanceSettings::from_toml_str(&edit(
                GUIDANCE,
                "iterations_m",
                "iteration_m",
            )))
        }),
        err(
            a,
            "guidance.toml `steps_n = 100000`",
            NR,
            &["steps_n", "1000"],
            |_| {
                fail(GuidanceSettings::from_toml_str(&edit(
                    GUIDANCE,
                    "steps_n = 5",
                    "steps_n = 100000",
                )))
            },
        ),
        err(
            a,
            "sarl.toml `threads = 100000`",
            "accepted",
            &["threads", "1..=256"],
            sarl_edit("threads = 1 ", "threads = 100000 "),
        ),
        err(
            a,
            "sarl.toml `checkpoint_every = 0`",
            NR,
            &["checkpoint_every"],
            sarl_edit("checkpoint_every = ", "checkpoint_every = 0 #"),
        ),
        err(
            a,
            "sarl.toml unknown key",
            NR,
            &["sarl.toml", "episodez"],
            sarl_edit("[rl]", "[rl]\nepisodez = 3"),
        ),
        err(
            a,
            "sarl.toml `human_num = 40` (more than fit on the circle)",
            "accepted; placing the humans could search forever",
            &["env.human_num", "40 humans do not fit"],
            sarl_edit("human_num = 5", "human_num = 40"),
        ),
        err(
            a,
            "planner.toml `dt = 0.4` (the model was trained at 0.1 s)",
            "accepted: every sample replayed four times as fast",
            &["human2nav.dt", "0.4 s", "0.1 s apart"],
            |d| {
                let p = write(d, "planner.toml", edit(PLANNER, "dt = 0.1 ", "dt = 0.4 "));
                let cfg = PlannerConfig::load(&p).map_err(|e| chain(&e))?;
                fail(RobotPlanner::load(
                    &root().join("robots/diablo/robot.toml"),
                    &cfg.model_dir(&root()),
                    cfg.human2nav,
                ))
            },
        ),
        err(
            a,
            "train.toml `batch_size = 1000000000`",
            "12 GB of batch building before it was killed",
            &["train.batch_size", "largest batch"],
            |d| {
                let p = write(
                    d,
                    "train.toml",
                    edit(TRAIN, "batch_size = 128", "batch_size = 1000000000"),
                );
                let cfg = human2nav_experiments::train::TrainConfig::load(&p)
                    .map_err(|e| format!("{e:#}"))?;
                cfg.validate().map_err(|e| format!("{e:#}"))
            },
        ),
        err(
            a,
            "data.toml `data_root` naming a folder that does not exist (`data build`)",
            "a warning, then a synthetic cache and exit 0",
            &[
                "data.toml",
                "paths.data_root",
                "no/such/datsets",
                "does not exist",
            ],
            |d| {
                let p = write(d, "data.toml", "[paths]\ndata_root = \"no/such/datsets\"\n");
                cli(&["data", "build", "--config", &p.to_string_lossy()])
            },
        ),
        err(
            a,
            "`baseline eval-sarl --humans 40`",
            NR,
            &["40 humans", "env.human_num", "do not fit"],
            |_| cli(&["baseline", "eval-sarl", "--humans", "40", "--episodes", "1"]),
        ),
        err(
            a,
            "`baseline eval-sarl --model` a folder without a card",
            NR,
            &["loading the SARL model", "model.toml"],
            |d| {
                cli(&[
                    "baseline",
                    "eval-sarl",
                    "--model",
                    &d.to_string_lossy(),
                    "--episodes",
                    "1",
                ])
            },
        ),
    ]
}

// ---------------------------------------------------------------------------------------------
// Episodes and datasets.

/// One synthetic episode as a JSON value.
fn episode() -> Value {
    let mut eps = human2nav_sim::config::synthetic_episodes(1, 7).expect("synthetic episodes");
    eps.truncate(1);
    serde_json::to_value(&eps[0]).expect("episode JSON")
}

fn suite() -> Value {
    let eps = human2nav_sim::config::synthetic_episodes(1, 7).expect("synthetic episodes");
    serde_json::to_value(human2nav_data::EpisodeSuite::new("synthetic", eps)).expect("suite JSON")
}

fn load_episodes(dir: &Path, text: &str) -> Result<(), String> {
    let p = write(dir, "episodes.json", text);
    fail(human2nav_sim::episode::load_episode_file(&p))
}

fn episode_edit(f: fn(&mut Value)) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let mut e = episode();
        f(&mut e);
        load_episodes(dir, &e.to_string())
    }
}

/// A small cache (two scenes, a few tuples), written by `TupleCache::write`.
fn cache(dir: &Path) -> PathBuf {
    let scene = |name: &str, split| SceneInfo {
        name: format!("eth/{name}"),
        dataset: "eth".into(),
        format: "eth".into(),
        split,
        duration: 12.0,
        tracks: 3,
        tuples: 2,
        median_speed: Some(1.2),
        skipped: Default::default(),
    };
    let tuple = |scene: u16, k: usize| CompactTuple {
        scene,
        class: None,
        goal: [3.0, 0.5 * k as f32],
        velocity: [1.0, 0.0],
        future: (1..=4).map(|i| [0.1 * i as f32, 0.0, 0.0]).collect(),
        agents: (0..k)
            .map(|a| [1.0 + a as f32, -0.5, 0.3, 0.0, 0.3])
            .collect(),
    };
    let manifest = Manifest {
        version: CACHE_VERSION,
        source: "real".into(),
        bev: Default::default(),
        horizon: 4,
        dt: 0.1,
        tuples: TupleOptions::default(),
        scenes: vec![scene("hotel", Split::Train), scene("univ", Split::Test)],
        counts: Default::default(),
        stats: TupleStats::default(),
        file_bytes: Default::default(),
    };
    let splits = [
        (Split::Train, vec![tuple(0, 0), tuple(0, 2)]),
        (Split::Val, Vec::new()),
        (Split::Test, vec![tuple(1, 3)]),
    ];
    let at = dir.join("cache");
    TupleCache::write(&at, manifest, &splits).expect("cache written");
    at
}

fn open_train(dir: &Path) -> Result<(), String> {
    let c = TupleCache::open(dir).map_err(|e| chain(&e))?;
    fail(c.load_compact(Split::Train))
}

fn manifest_edit(f: fn(&mut Value)) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let c = cache(dir);
        let p = c.join("manifest.json");
        let mut m: Value =
            serde_json::from_str(&std::fs::read_to_string(&p).map_err(|e| e.to_string())?)
                .map_err(|e| e.to_string())?;
        f(&mut m);
        write(&c, "manifest.json", m.to_string());
        open_train(&c)
    }
}

fn train_bin_edit(f: fn(&mut Vec<u8>)) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let c = cache(dir);
        let p = c.join("train.bin");
        let mut b = std::fs::read(&p).map_err(|e| e.to_string())?;
        f(&mut b);
        std::fs::write(&p, b).map_err(|e| e.to_string())?;
        // Sizes recorded by the build would catch every edit: drop them to reach the reader.
        let mp = c.join("manifest.json");
        let mut m: Value =
            serde_json::from_str(&std::fs::read_to_string(&mp).map_err(|e| e.to_string())?)
                .map_err(|e| e.to_string())?;
        m["file_bytes"] = Value::Object(Default::default());
        write(&c, "manifest.json", m.to_string());
        open_train(&c)
    }
}

const OBSMAT_ROW: &str =
    "7.8000000e+02 1.0000000e+00 8.4568443e+00 0.0 3.5880664e+00 1.6717144e+00 0.0 1.7629183e-01\n";

fn obsmat(dir: &Path, text: &str) -> Result<(), String> {
    fail(eth::load_obsmat(&write(dir, "obsmat.txt", text), "eth/eth"))
}

fn vsp(dir: &Path, text: &str) -> Result<(), String> {
    let p = write(dir, "annotation.vsp", text);
    let h = Homography::new([
        [-0.025956517, 0.0, 7.838868],
        [-0.0010953874, 0.02166433, 5.5660456],
        [0.0, 0.0, 1.0],
    ])
    .expect("zara homography");
    fail(ucy::load_vsp(
        &p,
        &h,
        ucy::VspConvention::ImageRowCol,
        "ucy/zara01",
    ))
}

/// The cases of data and episodes: a table, one entry per case, hence longer than a function should be.
fn data_cases() -> Vec<Case> {
    let a = "data and episodes";
    vec![
        err(
            a,
            "episode `dt = 0`",
            "`plan --episode` accepted it (`bench` refused)",
            &["dt"],
            episode_edit(|e| e["dt"] = 0.0.into()),
        ),
        err(
            a,
            "episode `dt = -0.1`",
            "`plan --episode` accepted it",
            &["dt"],
            episode_edit(|e| e["dt"] = (-0.1).into()),
        ),
        err(
            a,
            "episode `time_budget = 0`",
            "`plan --episode` accepted it",
            &["time_budget"],
            episode_edit(|e| e["time_budget"] = 0.0.into()),
        ),
        err(
            a,
            "episode `time_budget = -5`",
            "`plan --episode` accepted it",
            &["time_budget"],
            episode_edit(|e| e["time_budget"] = (-5.0).into()),
        ),
        err(
            a,
            "episode `time_budget = 1e9`",
            "tried to allocate tens of GB and aborted",
            &["time_budget", "3600"],
            episode_edit(|e| e["time_budget"] = 1e9.into()),
        ),
        err(
            a,
            "episode goal at 1e300 m",
            NR,
            &["goal"],
            episode_edit(|e| e["goal"] = serde_json::json!([1e300, 0.0])),
        ),
        err(
            a,
            "episode start at 1e300 m",
            NR,
            &["start"],
            episode_edit(|e| e["start"]["x"] = 1e300.into()),
        ),
        err(
            a,
            "episode with an unknown field",
            "accepted: unknown fields were ignored",
            &["episodes.json", "budgett"],
            episode_edit(|e| e["budgett"] = 1.0.into()),
        ),
        err(
            a,
            "episode missing `goal`",
            NR,
            &["episodes.json", "goal"],
            episode_edit(|e| {
                e.as_object_mut().map(|o| o.remove("goal"));
            }),
        ),
        err(
            a,
            "episode number out of range (`1e999`)",
            NR,
            &["episodes.json"],
            |d| {
                let text = episode().to_string();
                let at =
                    text.find("\"time_budget\":").expect("time_budget") + "\"time_budget\":".len();
                let end = at + text[at..].find([',', '}']).expect("value end");
                load_episodes(d, &format!("{}1e999{}", &text[..at], &text[end..]))
            },
        ),
        err(
            a,
            "suite `version = 999`",
            "`plan --episode` accepted it",
            &["version", "999"],
            |d| {
                let mut s = suite();
                s["version"] = 999.into();
                load_episodes(d, &s.to_string())
            },
        ),
        err(a, "episode file empty", NR, &["episodes.json"], |d| {
            load_episodes(d, "")
        }),
        err(
            a,
            "episode file nested 100 000 deep",
            NR,
            &["episodes.json", "recursion limit"],
            |d| load_episodes(d, &nested("[", "]", 100_000)),
        ),
        err(
            a,
            "episode file is a FIFO",
            NR,
            &["episodes.json", "FIFO"],
            |d| {
                let p = d.join("episodes.json");
                fifo(&p);
                fail(human2nav_sim::episode::load_episode_file(&p))
            },
        ),
        err(
            a,
            "episode file is `/dev/zero`",
            NR,
            &["/dev/zero", "regular file"],
            |_| {
                fail(human2nav_sim::episode::load_episode_file(Path::new(
                    "/dev/zero",
                )))
            },
        ),
        err(
            a,
            "ETH obsmat with a 1e300 coordinate",
            "the cache built, then `data stats` refused it",
            &["obsmat.txt"],
            |d| obsmat(d, &OBSMAT_ROW.replace("8.4568443e+00", "1e300")),
        ),
        err(a, "ETH obsmat with a NaN", NR, &["obsmat.txt"], |d| {
            obsmat(d, &OBSMAT_ROW.replace("8.4568443e+00", "nan"))
        }),
        err(
            a,
            "ETH obsmat with a word in a number column",
            NR,
            &["obsmat.txt:1", "pos_x", "not a number"],
            |d| obsmat(d, &OBSMAT_ROW.replace("8.4568443e+00", "eight")),
        ),
        err(
            a,
            "ETH obsmat with a short row",
            NR,
            &["obsmat.txt:1", "at least 8 columns"],
            |d| obsmat(d, "7.8e+02 1.0 8.4\n"),
        ),
        err(
            a,
            "UCY spline count 10^12",
            "tried to allocate hundreds of GB and aborted",
            &["annotation.vsp"],
            |d| {
                vsp(
                    d,
                    "1000000000000 - the number of splines\n3 - Num of control points\n",
                )
            },
        ),
        err(
            a,
            "UCY control-point count 10^12",
            "tried to allocate hundreds of GB and aborted",
            &["annotation.vsp"],
            |d| {
                vsp(
                    d,
                    "1 - the number of splines\n1000000000000 - Num of control points\n1.0 2.0 0 90.0 - (2D point, m_id)\n",
                )
            },
        ),
        err(
            a,
            "UCY file ending inside a spline",
            NR,
            &["annotation.vsp"],
            |d| {
                vsp(
                    d,
                    "2 - the number of splines\n3 - Num of control points\n279.0 -123.0 0 87.3\n",
                )
            },
        ),
        err(
            a,
            "UCY spline whose frame jumps backwards",
            "accepted: the walker went back in time",
            &["annotation.vsp:5", "comes after frame 20", "backwards"],
            |d| {
                vsp(
                    d,
                    "1 - the number of splines\n3 - Num of control points\n\
                     279.0 -123.0 10 87.3\n280.0 -123.0 20 87.3\n281.0 -123.0 5 87.3\n",
                )
            },
        ),
        err(
            a,
            "episode with one agent id twice",
            "accepted: one person in two places",
            &[
                "episodes.json",
                "agents[1].id",
                "already the id of agents[0]",
            ],
            episode_edit(|e| {
                if let Some(agents) = e["agents"].as_array_mut() {
                    let first = agents[0].clone();
                    agents.push(first);
                    let n = agents.len();
                    agents.swap(1, n - 1);
                }
            }),
        ),
        err(
            a,
            "episode agent with no positions",
            "accepted",
            &["episodes.json", "agents[0].positions", "no positions"],
            episode_edit(|e| e["agents"][0]["positions"] = serde_json::json!([])),
        ),
        err(
            a,
            "episode agent that jumps 50 m in one step",
            "`bench` failed the planner calls that observed it (a recorded SDD track did this)",
            &["episodes.json", "agents[0].positions[1]", "m/s"],
            episode_edit(|e| {
                let p = e["agents"][0]["positions"][0].clone();
                let (x, y) = (p[0].as_f64().unwrap_or(0.0), p[1].as_f64().unwrap_or(0.0));
                e["agents"][0]["positions"] = serde_json::json!([[x, y], [x + 50.0, y]]);
            }),
        ),
        err(
            a,
            "episode polygon that crosses itself",
            "accepted though the format says \"simple polygon\"",
            &["obstacles[0]", "not a simple polygon", "edge 0"],
            episode_edit(|e| {
                e["obstacles"] = serde_json::json!([{
                    "kind": "polygon",
                    "vertices": [[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]
                }])
            }),
        ),
        err(a, "homography that is singular", NR, &["H.txt"], |d| {
            fail(Homography::load(&write(
                d,
                "H.txt",
                "1 2 3\n2 4 6\n0 0 0\n",
            )))
        }),
        err(a, "homography with two rows", NR, &["H.txt"], |d| {
            fail(Homography::load(&write(d, "H.txt", "1 0 0\n0 1 0\n")))
        }),
        err(
            a,
            "sgan file with text in a column",
            NR,
            &["seq.txt:2", "ped_id"],
            |d| {
                fail(sgan::load(
                    &write(d, "seq.txt", "780\t1.0\t8.46\t3.59\n790\tone\t9.57\t3.79\n"),
                    "eth/eth",
                    "eth",
                ))
            },
        ),
        err(
            a,
            "tuple cache without `manifest.json` (interrupted build)",
            NR,
            &["manifest.json"],
            |d| {
                let c = cache(d);
                std::fs::remove_file(c.join("manifest.json")).map_err(|e| e.to_string())?;
                open_train(&c)
            },
        ),
        err(
            a,
            "tuple cache of another version",
            NR,
            &["manifest.json", "cache version 99"],
            manifest_edit(|m| m["version"] = 99.into()),
        ),
        err(
            a,
            "tuple cache `horizon = 0`",
            NR,
            &["manifest.json", "horizon 0"],
            manifest_edit(|m| m["horizon"] = 0.into()),
        ),
        err(
            a,
            "tuple cache split file of another build (size differs)",
            NR,
            &["train.bin", "the manifest says"],
            |d| {
                let c = cache(d);
                let p = c.join("train.bin");
                let mut b = std::fs::read(&p).map_err(|e| e.to_string())?;
                b.extend_from_slice(&[0; 8]);
                std::fs::write(&p, b).map_err(|e| e.to_string())?;
                open_train(&c)
            },
        ),
        err(
            a,
            "tuple cache header claiming 2^60 tuples",
            NR,
            &["train.bin"],
            train_bin_edit(|b| b[16..24].copy_from_slice(&(1u64 << 60).to_le_bytes())),
        ),
        err(
            a,
            "tuple cache with a NaN in a tuple",
            NR,
            &["train.bin", "non-finite value at byte"],
            train_bin_edit(|b| {
                let at = 24 + 8;
                b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
            }),
        ),
        err(
            a,
            "tuple cache file truncated",
            NR,
            &["train.bin", "truncated"],
            train_bin_edit(|b| b.truncate(b.len() - 3)),
        ),
        err(
            a,
            "tuple cache file with a wrong magic",
            NR,
            &["train.bin"],
            train_bin_edit(|b| b[..8].copy_from_slice(b"NOTCACHE")),
        ),
    ]
}

// ---------------------------------------------------------------------------------------------
// The model folder.

const CARD: &str = include_str!("../../../models/human2nav-cfm/model.toml");

/// A copy of the shipped model folder with the card edited by `card` and the weights by
/// `weights`, loaded by the native backend.
fn model_with(dir: &Path, card: &str, weights: Option<&[u8]>) -> Result<(), String> {
    let m = dir.join("model");
    write(&m, "model.toml", card);
    let shipped = root().join("models/human2nav-cfm/model.safetensors");
    match weights {
        Some(w) => {
            write(&m, "model.safetensors", w);
        }
        None => {
            std::fs::copy(&shipped, m.join("model.safetensors")).map_err(|e| e.to_string())?;
        }
    }
    fail(load_model(&m, Backend::Native))
}

fn card_edit(from: &'static str, to: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| model_with(dir, &edit(CARD, from, to), None)
}

/// The shipped card with `[table] key` set to `value`, whatever the trained value was:
/// retraining changes the numbers, not the cases.
fn card_set(
    table: &'static str,
    key: &'static str,
    value: toml::Value,
) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let mut card: toml::Table = CARD.parse().expect("the shipped card is TOML");
        let slot = card
            .get_mut(table)
            .and_then(toml::Value::as_table_mut)
            .and_then(|t| t.get_mut(key))
            .unwrap_or_else(|| panic!("the shipped card has no `{table}.{key}`"));
        *slot = value.clone();
        model_with(dir, &card.to_string(), None)
    }
}

fn shipped_weights() -> Vec<u8> {
    std::fs::read(root().join("models/human2nav-cfm/model.safetensors")).expect("shipped weights")
}

/// The cases of the model folder: a table, one entry per case, hence longer than a function should be.
fn model_cases() -> Vec<Case> {
    let a = "model folder";
    vec![
        err(
            a,
            "card `n_groups = 0`",
            "division by zero (panic) in model loading",
            &["n_groups"],
            card_edit("n_groups = 8", "n_groups = 0"),
        ),
        err(
            a,
            "card `n_groups` not dividing the channels",
            NR,
            &["n_groups"],
            card_edit("n_groups = 8", "n_groups = 7"),
        ),
        err(
            a,
            "card `[bev] cells` not the network's `bev_cells`",
            "the `[bev]` table was ignored",
            &["model.toml", "[bev] cells = 16", "net.bev_cells = 32"],
            card_edit("\ncells = 32", "\ncells = 16"),
        ),
        err(
            a,
            "card `[bev] resolution = -0.3`",
            "the `[bev]` table was ignored",
            &["[bev]", "resolution"],
            card_edit("resolution = 0.3", "resolution = -0.3"),
        ),
        err(
            a,
            "card `bev_cells = 16` (and `[bev] cells = 16`) over weights trained at 32",
            "accepted: every tensor shape still fits, and the checksum covers the weights, not the card",
            &[
                "model.safetensors",
                "bev_cells = 32",
                "the model card says 16",
            ],
            |d| {
                model_with(
                    d,
                    &edit(
                        &edit(CARD, "bev_cells = 32", "bev_cells = 16"),
                        "\ncells = 32",
                        "\ncells = 16",
                    ),
                    None,
                )
            },
        ),
        err(
            a,
            "card `horizon = 0`",
            NR,
            &["horizon"],
            card_edit("horizon = 32", "horizon = 0"),
        ),
        err(
            a,
            "card `format_version = 2`",
            NR,
            &["model.toml", "format_version 2"],
            card_edit("format_version = 1", "format_version = 2"),
        ),
        err(
            a,
            "card with an unknown field",
            NR,
            &["model.toml", "weigths"],
            card_edit(
                "weights = \"model.safetensors\"",
                "weigths = \"model.safetensors\"",
            ),
        ),
        err(
            a,
            "card `activation = \"relu6\"`",
            NR,
            &["model.toml", "relu6"],
            card_edit("activation = \"silu\"", "activation = \"relu6\""),
        ),
        err(
            a,
            "card `position_scale = 0`",
            NR,
            &["position_scale"],
            card_set("normalisation", "position_scale", toml::Value::Float(0.0)),
        ),
        err(
            a,
            "card `velocity_std` with a NaN",
            NR,
            &["velocity_std"],
            card_set(
                "normalisation",
                "velocity_std",
                toml::Value::Array(vec![f64::NAN.into(), 1.0.into(), 1.0.into()]),
            ),
        ),
        err(
            a,
            "card `[source] std` with a NaN",
            "loaded silently",
            &["[source]", "std[1]"],
            card_set(
                "source",
                "std",
                toml::Value::Array(vec![1.0.into(), f64::NAN.into(), 1.0.into()]),
            ),
        ),
        err(
            a,
            "card `[source] steps = 0`",
            "loaded silently",
            &["[source]", "steps"],
            card_set("source", "steps", toml::Value::Integer(0)),
        ),
        err(a, "card missing", NR, &["model.toml"], |d| {
            std::fs::create_dir_all(d.join("model")).map_err(|e| e.to_string())?;
            fail(load_model(&d.join("model"), Backend::Native))
        }),
        err(a, "card is a FIFO", NR, &["model.toml", "FIFO"], |d| {
            let m = d.join("model");
            std::fs::create_dir_all(&m).map_err(|e| e.to_string())?;
            fifo(&m.join("model.toml"));
            fail(ModelCard::load(&m.join("model.toml")))
        }),
        err(
            a,
            "weights one byte changed",
            "the weights had no checksum",
            &["model.safetensors", "checksum"],
            |d| {
                let mut w = shipped_weights();
                let last = w.len() - 1;
                w[last] ^= 1;
                model_with(d, CARD, Some(&w))
            },
        ),
        err(a, "weights truncated", NR, &["model.safetensors"], |d| {
            let w = shipped_weights();
            model_with(d, CARD, Some(&w[..w.len() / 2]))
        }),
        err(a, "weights missing", NR, &["model.safetensors"], |d| {
            let m = d.join("model");
            write(&m, "model.toml", CARD);
            fail(load_model(&m, Backend::Native))
        }),
        err(
            a,
            "weights file of garbage without a checksum in the card",
            NR,
            &["model.safetensors"],
            |d| {
                let checksum = CARD
                    .lines()
                    .find(|l| l.starts_with("weights_fnv64 = "))
                    .expect("the shipped card has a weights checksum");
                let card = edit(CARD, &format!("{checksum}\n"), "");
                model_with(d, &card, Some(b"not safetensors at all"))
            },
        ),
        err(a, "weights a directory", NR, &["model.safetensors"], |d| {
            let m = d.join("model");
            write(&m, "model.toml", CARD);
            std::fs::create_dir_all(m.join("model.safetensors")).map_err(|e| e.to_string())?;
            fail(load_model(&m, Backend::Native))
        }),
        covered(
            a,
            "`plan` with a missing model folder",
            NR,
            "one clear error line naming the folder",
            "sdk/cli/tests/plan_cli.rs::a_missing_model_is_one_clear_error",
        ),
    ]
}

// ---------------------------------------------------------------------------------------------
// Plugins.

fn plugin_lib(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test binary");
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("target/<profile>")
        .to_path_buf();
    let p = dir.join(name);
    if let Err(e) = resolve_library_path(&p) {
        panic!("{e}: build the workspace first (`cargo build --workspace`)");
    }
    p
}

/// Diablo's profile in `dir` with its embodiment replaced by the fixture's `unicycle` with
/// `config`, and `extra` appended; nothing said about isolation or deadlines (the defaults).
fn fixture_robot(dir: &Path, config: &str, extra: &str) -> PathBuf {
    let lib = plugin_lib("human2nav_fixture_test_plugin");
    let builtin = "kind = \"differential_drive\"\nwheel_joints = [\"left_wheel_joint\", \"right_wheel_joint\"]";
    assert!(
        DIABLO.contains(builtin),
        "diablo's robot.toml has no `{builtin}`"
    );
    let toml = DIABLO.replacen(
        builtin,
        &format!(
            "kind = \"plugin\"\nlibrary = {:?}\nplugin = \"unicycle\"\nconfig = {config:?}",
            lib.display().to_string()
        ),
        1,
    );
    write(dir, "diablo.urdf", DIABLO_URDF);
    write(dir, "robot.toml", format!("{toml}\n{extra}"))
}

/// `human2nav robot check` on [`fixture_robot`].
fn robot_check_fixture(
    config: &'static str,
    extra: &'static str,
) -> impl Fn(&Path) -> Result<(), String> {
    move |dir| {
        let p = fixture_robot(dir, config, extra);
        cli(&["robot", "check", &p.to_string_lossy()])
    }
}

/// `human2nav bench` on one synthetic episode per class: `robot` (a path) and `methods`.
fn bench_fixture(dir: &Path, robot: &Path, methods: &str) -> Result<(), String> {
    let cfg = write(
        dir,
        "bench.toml",
        format!(
            "seed = 3\nrobots = [{:?}]\n{methods}\n[[suites]]\nname = \"synthetic\"\n\
             kind = \"synthetic\"\nper_class = 1\n",
            robot.display().to_string()
        ),
    );
    let out = dir.join("out");
    cli(&[
        "bench",
        "--config",
        &cfg.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
    ])
}

fn orca_with(config: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    move |_| fail(PluginHost::new().planner(&plugin_lib("human2nav_orca"), "orca", config, None))
}

/// The cases of plugins: a table, one entry per case, hence longer than a function should be.
fn plugin_cases() -> Vec<Case> {
    let a = "plugins";
    vec![
        err(
            a,
            "library path that does not exist",
            NR,
            &["nowhere.so"],
            |d| fail(PluginLibrary::load(&d.join("nowhere.so"))),
        ),
        err(a, "library that is a text file", NR, &["fake.so"], |d| {
            fail(PluginLibrary::load(&write(
                d,
                "fake.so",
                "just text, not a library",
            )))
        }),
        err(a, "library that is empty", NR, &["empty.so"], |d| {
            fail(PluginLibrary::load(&write(d, "empty.so", "")))
        }),
        err(
            a,
            "library that is a FIFO",
            NR,
            &["pipe.so", "not found"],
            |d| {
                let p = d.join("pipe.so");
                fifo(&p);
                fail(PluginLibrary::load(&p))
            },
        ),
        err(
            a,
            "factory name not in the library",
            NR,
            &["no_such_factory"],
            |_| {
                fail(PluginHost::new().planner(
                    &plugin_lib("human2nav_orca"),
                    "no_such_factory",
                    "",
                    None,
                ))
            },
        ),
        err(
            a,
            "ORCA config with an unknown key",
            NR,
            &["time_horizn"],
            orca_with("time_horizn = 5.0"),
        ),
        err(
            a,
            "ORCA config `time_horizon = -1`",
            NR,
            &["time_horizon"],
            orca_with("time_horizon = -1.0"),
        ),
        err(
            a,
            "ORCA config `max_neighbors = \"ten\"`",
            NR,
            &["orca", "line 1 column 17", "expected usize"],
            orca_with("max_neighbors = \"ten\""),
        ),
        err(
            a,
            "ORCA config that is not TOML",
            NR,
            &["orca"],
            orca_with("= = ="),
        ),
        err(
            a,
            "personal_space config with an unknown key",
            NR,
            &["persnal"],
            |_| {
                fail(PluginHost::new().constraint(
                    &plugin_lib("human2nav_personal_space"),
                    "personal_space",
                    "persnal = 1.0",
                    None,
                ))
            },
        ),
        err(
            a,
            "observation with a NaN pose sent to a plugin planner",
            NR,
            &["ego"],
            |_| {
                let mut p = PluginHost::new()
                    .planner(&plugin_lib("human2nav_orca"), "orca", "", None)
                    .map_err(|e| chain(&e))?;
                let obs = Observation {
                    ego: Pose2::new(f64::NAN, 0.0, 0.0),
                    goal: [3.0, 0.0],
                    ..Default::default()
                };
                match p.plan(&obs) {
                    Err(e @ PlanError::InvalidObservation(_)) => Err(chain(&e)),
                    other => Err(format!("expected an invalid observation, got {other:?}")),
                }
            },
        ),
        covered(
            a,
            "embodiment plugin answering NaN after 40 good steps",
            "passed `robot check`; the bench exited 0 with NaN in report.md",
            "every answer checked: the robot halts and the failure names the call and the field",
            "tests/tests/plugins_hardening.rs::an_embodiment_that_goes_bad_later_is_halted_and_named",
        ),
        covered(
            a,
            "truncated `.so`",
            "SIGBUS inside dlopen killed the host",
            "refused before dlopen, naming the file",
            "tests/tests/plugins_hardening.rs::a_truncated_library_is_refused_before_dlopen",
        ),
        covered(
            a,
            "null function pointer in a vtable",
            "segfault in the host; `plugin inspect` called it",
            "error naming file, table and slot",
            "tests/tests/plugins_hardening.rs::a_null_required_slot_is_an_error_naming_file_table_and_slot",
        ),
        covered(
            a,
            "wrong table size",
            NR,
            "error naming the table and both sizes",
            "tests/tests/plugins_hardening.rs::a_wrong_table_size_is_an_error",
        ),
        covered(
            a,
            "factory count 2^40 and other absurd lengths",
            "tried to allocate and aborted",
            "refused against the caps",
            "tests/tests/plugins_hardening.rs::absurd_lengths_from_a_plugin_are_capped",
        ),
        covered(
            a,
            "`plugin inspect` on a broken library",
            "called null pointers",
            "lists every check and refuses the broken tables",
            "sdk/cli/tests/plugin_inspect.rs::inspect_lists_its_checks_and_refuses_broken_tables",
        ),
        covered(
            a,
            "`plugin inspect` on a library that aborts or hangs in its entry function",
            "took `plugin inspect` down with it (no isolation)",
            "checked in a process of its own: one error line naming the signal or the timeout",
            "sdk/cli/tests/plugin_inspect.rs::a_library_that_aborts_or_hangs_on_load_is_reported_not_fatal",
        ),
        covered(
            a,
            "planner call that never returns",
            "hung the host",
            "safe plan after the deadline, said so; the planner is dead afterwards",
            "tests/tests/plugins_hardening.rs::a_planner_that_never_returns_gets_the_safe_plan_and_is_dead_afterwards",
        ),
        covered(
            a,
            "constraint call that never returns",
            "hung the host",
            "error after the deadline; the term is dead afterwards",
            "tests/tests/plugins_hardening.rs::a_constraint_that_never_returns_fails_and_is_dead_afterwards",
        ),
        covered(
            a,
            "planner that fails every call in `bench`",
            "exit 0 and TFS 1.000 for a robot that never moved",
            "non-zero exit, loud warning on stderr and in report.md",
            "tests/tests/plugins_hardening.rs::a_planner_that_fails_every_call_is_reported_loudly_and_fails_the_bench",
        ),
        covered(
            a,
            "planner plugin that aborts (process host)",
            "killed the host (inherent in-process)",
            "helper restarted, clear error, host lives on",
            "sdk/plugin/tests/process.rs::the_host_survives_a_planner_that_aborts_and_the_next_call_works",
        ),
        covered(
            a,
            "planner plugin that segfaults (process host)",
            "killed the host",
            "helper restarted, clear error, host lives on",
            "sdk/plugin/tests/process.rs::the_host_survives_a_planner_that_segfaults_and_the_next_call_works",
        ),
        covered(
            a,
            "planner plugin that hangs (process host)",
            "hung the host",
            "helper killed and restarted, host lives on",
            "sdk/plugin/tests/process.rs::the_host_survives_a_planner_that_hangs_and_the_next_call_works",
        ),
        covered(
            a,
            "constraint plugin that segfaults or aborts (process host)",
            "killed the host",
            "helper restarted, host lives on",
            "sdk/plugin/tests/process.rs::the_host_survives_a_constraint_that_segfaults_or_aborts",
        ),
        err(
            a,
            "embodiment plugin that sleeps in `saturate`, default settings, `robot check`",
            "hung `robot check` (embodiments had no deadline)",
            &[
                "[embodiment]",
                "embodiment `unicycle`",
                "did not answer `saturate` within 1000 ms (killed)",
            ],
            robot_check_fixture("sleep_ms = 3600000\nonly_call = \"saturate\"", ""),
        ),
        err(
            a,
            "embodiment plugin that aborts in `step`, default settings, `robot check`",
            "killed `robot check` (embodiments ran in process)",
            &[
                "[embodiment]",
                "embodiment `unicycle`",
                "died during `step`: signal SIGABRT",
            ],
            robot_check_fixture("abort = true\nonly_call = \"step\"", ""),
        ),
        err(
            a,
            "constraint plugin that aborts in `evaluate`, default settings, `robot check`",
            "killed `robot check` (in process by default)",
            &[
                "[[constraint]] 0",
                "constraint `quadratic`",
                "died during `evaluate`: signal SIGABRT",
            ],
            |d| {
                let lib = plugin_lib("human2nav_fixture_test_plugin");
                let extra = format!(
                    "[[constraint]]\nlibrary = {:?}\nplugin = \"quadratic\"\nconfig = \"abort = true\"\n",
                    lib.display().to_string()
                );
                let p = fixture_robot(d, "", &extra);
                cli(&["robot", "check", &p.to_string_lossy()])
            },
        ),
        err(
            a,
            "embodiment plugin that sleeps in `track`, default settings, `bench`",
            "hung `bench` (embodiments had no deadline)",
            &[
                "[embodiment]",
                "embodiment `unicycle`",
                "did not answer `track` within 1000 ms (killed)",
            ],
            |d| {
                let robot = fixture_robot(d, "sleep_ms = 3600000\nonly_call = \"track\"", "");
                bench_fixture(
                    d,
                    &robot,
                    "[[methods]]\nname = \"straight\"\nkind = \"straight\"\n",
                )
            },
        ),
        err(
            a,
            "planner plugin that aborts in `plan`, default settings, `bench`",
            "killed `bench` (in process by default)",
            &[
                "planner `straight`",
                "died during `plan`: signal SIGABRT",
                "the instance is marked dead",
            ],
            |d| {
                let lib = plugin_lib("human2nav_fixture_test_plugin");
                bench_fixture(
                    d,
                    &root().join("robots/diablo/robot.toml"),
                    &format!(
                        "[[methods]]\nname = \"aborts\"\nkind = \"plugin\"\nlibrary = {:?}\n\
                         plugin = \"straight\"\nconfig = {{ abort = true }}\n",
                        lib.display().to_string()
                    ),
                )
            },
        ),
        covered(
            a,
            "embodiment plugin that hangs, aborts, segfaults or panics (process host) or sleeps (in process)",
            "hung or killed the host",
            "the robot is halted; the failure names the plugin and the call; no restart",
            "sdk/plugin/tests/embodiment.rs::the_host_survives_an_embodiment_that_aborts_or_segfaults",
        ),
        covered(
            a,
            "random tables, buffers and observations through the host",
            NR,
            "error or finite result (fuzz targets `plugin_entry`, `plugin_vtable`, `plugin_observation`)",
            "fuzz/tests/bounded.rs::run",
        ),
    ]
}

// ---------------------------------------------------------------------------------------------
// kill -9 and resume; concurrent runs.

const SARL_FILES: [&str; 5] = [
    "model.safetensors",
    "target.safetensors",
    "momentum.safetensors",
    "memory.safetensors",
    "progress.toml",
];

fn sarl_resume(out: &Path) -> Result<(), String> {
    let cfg = human2nav_sarl::train::TrainConfig::default();
    match human2nav_sarl::train::Trainer::resume(cfg, out.to_path_buf()) {
        Ok(Some(_)) => Ok(()),
        Ok(None) => Err("no checkpoint: would start afresh".into()),
        Err(e) => Err(chain(&e)),
    }
}

fn flow_checkpoint(files: &[(&str, &str)], manifest: bool) -> impl Fn(&Path) -> Result<(), String> {
    let files: Vec<(String, String)> = files
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    move |dir| {
        let ck = dir.join("checkpoint");
        for (name, body) in &files {
            write(&ck, name, body);
        }
        if manifest {
            fileset::write_manifest(&ck, &["state.safetensors", "state.toml"], 10)
                .map_err(|e| chain(&e))?;
        }
        match human2nav_flow::train::find_checkpoint(&ck) {
            Ok(Some(p)) => Err(format!("would resume from {}", p.display())),
            Ok(None) => Err("would start at step 0".into()),
            Err(e) => Err(chain(&e)),
        }
    }
}

fn cli(args: &[&str]) -> Result<(), String> {
    let out = Command::new(env!("CARGO_BIN_EXE_human2nav"))
        .args(args)
        .current_dir(root())
        .output()
        .map_err(|e| e.to_string())?;
    if out.status.success() {
        Ok(())
    } else {
        Err(String::from_utf8_lossy(&out.stderr).into_owned())
    }
}

/// The cases of kill -9 and resume: a table, one entry per case, hence longer than a function should be.
fn resume_cases() -> Vec<Case> {
    let a = "kill -9 and resume";
    let c = "concurrent runs";
    vec![
        err(
            a,
            "flow checkpoint without `state.toml`",
            "training restarted at step 0 without a word",
            &["checkpoint", "state.toml is missing", "--fresh"],
            flow_checkpoint(&[("state.safetensors", "x")], false),
        ),
        err(
            a,
            "flow checkpoint with `state.safetensors` altered after its manifest",
            NR,
            &["state.safetensors has", "the manifest says"],
            |d| {
                let ck = d.join("checkpoint");
                write(&ck, "state.safetensors", "x");
                write(&ck, "state.toml", "step = 1");
                fileset::write_manifest(&ck, &["state.safetensors", "state.toml"], 1)
                    .map_err(|e| chain(&e))?;
                write(&ck, "state.safetensors", "changed");
                match human2nav_flow::train::find_checkpoint(&ck) {
                    Err(e) => Err(chain(&e)),
                    Ok(p) => Err(format!("accepted: {p:?}")),
                }
            },
        ),
        err(
            a,
            "flow checkpoint folder with stray files only",
            NR,
            &["checkpoint", "none of state.safetensors, state.toml"],
            flow_checkpoint(&[("notes.txt", "x")], false),
        ),
        accepted(
            a,
            "flow checkpoint killed between its two renames",
            NR,
            "resumes from `checkpoint.old/`, the last complete set",
            |d| {
                let old = d.join("checkpoint.old");
                write(&old, "state.safetensors", "x");
                write(&old, "state.toml", "step = 1");
                fileset::write_manifest(&old, &["state.safetensors", "state.toml"], 1)
                    .map_err(|e| chain(&e))?;
                write(&d.join("checkpoint"), "state.toml", "half");
                match human2nav_flow::train::find_checkpoint(&d.join("checkpoint")) {
                    Ok(Some(p)) if p == old => Ok(()),
                    other => Err(format!("{other:?}")),
                }
            },
        ),
        err(
            a,
            "flow checkpoint with both files and no manifest",
            "resumed without any check",
            &["manifest.toml is missing", "--fresh"],
            flow_checkpoint(
                &[("state.safetensors", "x"), ("state.toml", "step = 1")],
                false,
            ),
        ),
        err(
            a,
            "flow checkpoint path that is a file",
            "training restarted from step 0",
            &["checkpoint", "not a folder"],
            |d| {
                let ck = write(d, "checkpoint", "x");
                fail(human2nav_flow::train::find_checkpoint(&ck))
            },
        ),
        err(
            a,
            "flow checkpoint path that is a loop of symbolic links",
            "training restarted from step 0",
            &["checkpoint", "symbolic links"],
            |d| {
                let (a, b) = (d.join("checkpoint"), d.join("other"));
                std::os::unix::fs::symlink(&b, &a).map_err(|e| e.to_string())?;
                std::os::unix::fs::symlink(&a, &b).map_err(|e| e.to_string())?;
                fail(human2nav_flow::train::find_checkpoint(&a))
            },
        ),
        err(
            a,
            "SARL checkpoint without `progress.toml`",
            "resumed as \"no checkpoint\": a silent restart at episode 0",
            &["progress.toml is missing", "without --resume"],
            |d| {
                for f in &SARL_FILES[..4] {
                    write(&d.join("checkpoint"), f, "x");
                }
                sarl_resume(d)
            },
        ),
        err(
            a,
            "SARL checkpoint with a file altered after its manifest",
            NR,
            &["memory.safetensors has", "the manifest says"],
            |d| {
                let ck = d.join("checkpoint");
                for f in SARL_FILES {
                    write(&ck, f, "x");
                }
                fileset::write_manifest(&ck, &SARL_FILES, 3).map_err(|e| chain(&e))?;
                write(&ck, "memory.safetensors", "changed");
                sarl_resume(d)
            },
        ),
        err(
            a,
            "SARL checkpoint manifest that does not parse",
            NR,
            &["manifest.toml", "not a set manifest"],
            |d| {
                let ck = d.join("checkpoint");
                for f in SARL_FILES {
                    write(&ck, f, "x");
                }
                write(&ck, "manifest.toml", "step = \"ten\"");
                sarl_resume(d)
            },
        ),
        err(
            a,
            "`baseline train-sarl --resume` on a partial checkpoint",
            "started afresh silently",
            &["progress.toml is missing"],
            |d| {
                let out = d.join("run");
                for f in &SARL_FILES[..4] {
                    write(&out.join("checkpoint"), f, "x");
                }
                cli(&[
                    "baseline",
                    "train-sarl",
                    "--config",
                    "sdk/configs/sarl.toml",
                    "--resume",
                    "--out",
                    &out.to_string_lossy(),
                ])
            },
        ),
        covered(
            a,
            "SARL killed between the renames of a save",
            NR,
            "resumes from `checkpoint.old/`",
            "plugins/sarl/src/train/tests.rs::checkpoints_are_sets_with_a_manifest",
        ),
        covered(
            a,
            "SARL checkpoint truncated file, run end to end",
            NR,
            "refused naming the file",
            "plugins/sarl/src/train/tests.rs::a_partial_checkpoint_is_refused_naming_the_file",
        ),
        covered(
            a,
            "flow trainer: every partial set in turn",
            NR,
            "resume from the complete set or an error naming the file",
            "sdk/flow/src/train/trainer.rs::tests",
        ),
        covered(
            a,
            "lock left by a run that was killed",
            NR,
            "taken over with a note",
            "sdk/core/src/lock.rs::a_lock_whose_owner_is_gone_is_taken_over",
        ),
        covered(
            a,
            "scaling run interrupted, then resumed",
            NR,
            "continues where it stopped",
            "sdk/cli/tests/scaling_cli.rs::two_fractions_end_to_end_then_resumed",
        ),
        err(
            c,
            "two writers on one folder",
            "both exited 0 and left a corrupt PNG",
            &["out", ".human2nav.lock", "first writer"],
            |d| {
                let out = d.join("out");
                let _first = DirLock::acquire(&out, "first writer").map_err(|e| e.to_string())?;
                DirLock::acquire(&out, "second writer")
                    .map(|_| ())
                    .map_err(|e| e.to_string())
            },
        ),
        err(
            c,
            "`bench --out` on a folder another run writes",
            "both exited 0 and left a corrupt PNG",
            &["locking", "hostile test"],
            |d| {
                let out = d.join("bench-out");
                let _held = DirLock::acquire(&out, "hostile test").map_err(|e| e.to_string())?;
                cli(&["bench", "--quick", "--out", &out.to_string_lossy()])
            },
        ),
        err(
            c,
            "`data build` on a cache another build writes",
            "both exited 0; 4 of 6 tries left a corrupt cache",
            &["cache", ".human2nav.lock", "hostile test"],
            |d| {
                let cache = d.join("cache");
                let p = write(
                    d,
                    "data.toml",
                    format!(
                        "[paths]\ncache_dir = {:?}\n[sources]\nsynthetic_only = true\n\
                         synthetic_scenes = 2\n",
                        cache.display().to_string()
                    ),
                );
                let _held = DirLock::acquire(&cache, "hostile test").map_err(|e| e.to_string())?;
                cli(&["data", "build", "--config", &p.to_string_lossy()])
            },
        ),
        err(
            c,
            "`baseline train-sarl` on a run folder another run writes",
            NR,
            &["locking the run directory", "hostile test"],
            |d| {
                let out = d.join("sarl-out");
                let _held = DirLock::acquire(&out, "hostile test").map_err(|e| e.to_string())?;
                cli(&[
                    "baseline",
                    "train-sarl",
                    "--config",
                    "sdk/configs/sarl.toml",
                    "--out",
                    &out.to_string_lossy(),
                ])
            },
        ),
    ]
}

/// A planner for diablo with the shipped model and settings, and an observation of it at rest
/// at the origin, 4 m from its goal.
fn diablo_planner() -> Result<(RobotPlanner, Observation), String> {
    let cfg =
        PlannerConfig::load(&root().join("sdk/configs/planner.toml")).map_err(|e| chain(&e))?;
    let rp = RobotPlanner::load(
        &root().join("robots/diablo/robot.toml"),
        &cfg.model_dir(&root()),
        cfg.human2nav,
    )
    .map_err(|e| chain(&e))?;
    let obs = Observation {
        goal: [4.0, 0.0],
        ..Observation::default()
    };
    Ok((rp, obs))
}

/// Plans for diablo at `obs` edited by `f`; `Ok` when the plan is finite and its warnings
/// name `warning`, the warnings or the error otherwise.
fn flagged(f: fn(&mut Observation), warning: &'static str) -> impl Fn(&Path) -> Result<(), String> {
    move |_| {
        let (mut rp, mut obs) = diablo_planner()?;
        f(&mut obs);
        let plan = rp.planner.plan(&obs).map_err(|e| chain(&e))?;
        if plan.is_finite() && plan.info.warnings.iter().any(|w| w.contains(warning)) {
            Ok(())
        } else {
            Err(format!("warnings {:?}", plan.info.warnings))
        }
    }
}

/// The cases of one planning call: the robot's own state, and `plan --time`.
fn planner_call_cases() -> Vec<Case> {
    let a = "planner calls";
    vec![
        err(
            a,
            "robot at 100 m/s",
            "a normal plan, no warning",
            &["ego velocity is faster than 30 m/s"],
            |_| {
                let (mut rp, mut obs) = diablo_planner()?;
                obs.ego_velocity = human2nav_core::Twist2::new(100.0, 0.0, 0.0);
                fail(rp.planner.plan(&obs))
            },
        ),
        accepted(
            a,
            "robot at 5 m/s (its `v_max` is 1.5)",
            "a normal plan, no warning",
            "planned, flagged in `PlanInfo::warnings` (`forward speed of 5.000`)",
            flagged(
                |o| o.ego_velocity = human2nav_core::Twist2::new(5.0, 0.0, 0.0),
                "forward speed of 5.000",
            ),
        ),
        accepted(
            a,
            "robot starting inside an obstacle",
            "a normal plan, no warning",
            "planned, flagged in `PlanInfo::warnings` (`inside obstacles[0]`)",
            flagged(
                |o| {
                    o.obstacles = vec![human2nav_core::obstacle::Obstacle::Circle {
                        center: [0.1, 0.0],
                        radius: 0.5,
                    }]
                },
                "inside obstacles[0]",
            ),
        ),
        err(
            a,
            "`plan --time 999` (past the episode's end)",
            "a plan among nobody",
            &["--time 999", "past the end of episode", "which lasts"],
            |_| {
                cli(&[
                    "plan",
                    "--time",
                    "999",
                    "--robot",
                    "robots/diablo/robot.toml",
                ])
            },
        ),
        covered(
            "plugins",
            "plugin error whose claimed length runs past its text (1,009 NUL bytes)",
            "the NUL bytes printed",
            "the message ends at its first NUL, control characters dropped",
            "sdk/plugin/src/host/tests.rs::a_claimed_error_length_is_not_trusted_past_the_text",
        ),
        covered(
            a,
            "C API `budget_ms` of 1e22, NaN, infinite or negative",
            "1e22: a panic adding the budget to an instant; the planner stayed poisoned",
            "`H2N_INVALID_ARGUMENT` naming `budget_ms`, as the CLI's cap",
            "sdk/capi/tests/bad_input.rs::planning_refuses_bad_observations_and_budgets",
        ),
        covered(
            a,
            "C API ego pose at 1e300 m",
            "a plan there",
            "`H2N_INVALID_ARGUMENT`: `ego pose is more than 1000000 m`, the episodes' bound",
            "sdk/capi/tests/bad_input.rs::planning_refuses_bad_observations_and_budgets",
        ),
        covered(
            a,
            "Python `budget_ms` of 1e22 or NaN; ego at 1e300 m",
            "1e22: a `PanicException` that `except Exception` does not catch",
            "`ValueError` naming `budget_ms` / `ego pose is more than`, the C API's text",
            "sdk/python/tests/test_human2nav.py::test_bad_input_is_a_clear_error",
        ),
    ]
}

fn catalogue() -> Vec<Case> {
    let mut all = robot_cases();
    all.extend(config_cases());
    all.extend(data_cases());
    all.extend(planner_call_cases());
    all.extend(model_cases());
    all.extend(plugin_cases());
    all.extend(resume_cases());
    all.extend(compare_cases());
    all.extend(shard_and_bag_cases());
    all
}

/// The cases of `bench --shard`/`--merge` and of ROS 2 bags (`human2nav replay`).
fn shard_and_bag_cases() -> Vec<Case> {
    let s = "bench shards";
    let b = "ROS 2 bags";
    let robot = "robots/diablo/robot.toml";
    let shards = "sdk/cli/tests/bench_shards.rs::two_shards_merged_write_what_one_run_writes";
    vec![
        err(
            s,
            "`bench --shard 3/2`",
            NR,
            &["`3/2`", "K is larger than N"],
            |_| cli(&["bench", "--shard", "3/2"]),
        ),
        err(
            s,
            "`bench --shard 0/0`",
            NR,
            &["`0/0`", "N must be at least 1"],
            |_| cli(&["bench", "--shard", "0/0"]),
        ),
        err(
            s,
            "`bench --shard x/4`",
            NR,
            &["`x` is not a whole number"],
            |_| cli(&["bench", "--shard", "x/4"]),
        ),
        err(
            s,
            "`bench --merge` of a folder that is no shard",
            NR,
            &["has no shard.json"],
            |dir| cli(&["bench", "--merge", &dir.to_string_lossy()]),
        ),
        covered(
            s,
            "a shard missing from the merge",
            NR,
            "refused naming it (`missing shard 2/2`)",
            shards,
        ),
        covered(
            s,
            "a shard given twice",
            NR,
            "refused naming both folders",
            shards,
        ),
        covered(
            s,
            "shards of different splits (`1/2` with `2/3`)",
            NR,
            "refused naming both",
            shards,
        ),
        covered(
            s,
            "shards of different seeds or configurations",
            NR,
            "refused naming the first differing key (`config.sim.dt`: 0.05 against 0.1)",
            shards,
        ),
        covered(
            s,
            "the configuration changed between the shards and the merge",
            NR,
            "refused naming the key that changed",
            shards,
        ),
        covered(
            s,
            "a shard cut short (a row missing)",
            NR,
            "refused: rows against shard.json's count",
            shards,
        ),
        covered(
            s,
            "a malformed results.csv line (a number, a flag, a column)",
            NR,
            "refused naming the line and the column",
            "sdk/sim/src/report.rs::a_bad_results_csv_is_refused_naming_the_line_and_the_column",
        ),
        err(
            b,
            "`replay` of a file that is not MCAP",
            NR,
            &["x.mcap", "is not an MCAP file"],
            move |dir| {
                let bag = dir.join("x.mcap");
                std::fs::write(&bag, "not a bag").map_err(|e| e.to_string())?;
                cli(&["replay", &bag.to_string_lossy(), "--robot", robot])
            },
        ),
        err(
            b,
            "`replay` of a folder without an .mcap file",
            NR,
            &["holds no .mcap file"],
            move |dir| cli(&["replay", &dir.to_string_lossy(), "--robot", robot]),
        ),
        err(b, "`replay --rate 0`", NR, &["--rate 0"], move |dir| {
            cli(&[
                "replay",
                &dir.to_string_lossy(),
                "--robot",
                robot,
                "--rate",
                "0",
            ])
        }),
        covered(
            b,
            "a bag without the odometry or goal topic",
            NR,
            "refused naming the topic",
            "sdk/python/tests/test_replay.py::test_a_bag_without_the_goal_topic_is_refused_naming_it",
        ),
        covered(
            b,
            "a definition without a needed field, or with another type for it",
            NR,
            "refused naming the topic and the field (definition mismatch)",
            "sdk/python/tests/test_replay.py::test_a_definition_that_does_not_match_is_refused_naming_the_topic",
        ),
        covered(
            b,
            "header stamps going backwards; a truncated message; a file cut short",
            NR,
            "refused naming the topic and the message's index (the last read for a cut file)",
            "sdk/python/tests/test_replay.py::test_timestamps_going_backwards_and_truncated_messages_name_the_topic_and_index",
        ),
        covered(
            b,
            "a message shorter than its definition",
            NR,
            "refused naming the field and the byte where it stopped",
            "sdk/sim/src/rosbag/cdr.rs::a_written_message_decodes_with_alignment_and_a_truncated_one_says_where",
        ),
        covered(
            b,
            "a topic carrying another message type",
            NR,
            "refused naming the topic, its type and the expected one",
            "sdk/sim/src/rosbag.rs::written_paths_and_twists_read_back_with_their_definitions",
        ),
    ]
}

/// A `results.csv` of `lines` (after the columns `human2nav compare` reads) in `dir`, named
/// `name`; its path as an argument.
fn results_file(dir: &Path, name: &str, lines: &[&str]) -> Result<String, String> {
    let path = dir.join(name);
    let mut text = String::from("suite,scenario,episode,robot,method,seed,success\n");
    for l in lines {
        text.push_str(l);
        text.push('\n');
    }
    std::fs::write(&path, text).map_err(|e| e.to_string())?;
    Ok(path.to_string_lossy().into_owned())
}

/// The cases of `human2nav compare`, run through the binary.
fn compare_cases() -> Vec<Case> {
    let a = "compare";
    let summaries = "summary commands";
    let robot = "robots/diablo/robot.toml";
    vec![
        err(
            summaries,
            "`plan --eval --windows 0`",
            "a table of NaN, exit 0",
            &["--windows 0", "at least one window"],
            move |_| cli(&["plan", "--eval", "--windows", "0", "--robot", robot]),
        ),
        err(
            summaries,
            "`plan --bench 0`",
            "a table of NaN, exit 0",
            &["--bench 0", "at least one timed call"],
            move |_| cli(&["plan", "--bench", "0", "--robot", robot]),
        ),
        err(
            a,
            "a `success` that is not 0 or 1",
            NR,
            &["a.csv", "line 2", "not 0 or 1"],
            |dir| {
                let base = results_file(dir, "a.csv", &["s,co_flow,e1,r,m,7,yes"])?;
                let cand = results_file(dir, "b.csv", &["s,co_flow,e1,r,m,7,1"])?;
                cli(&["compare", &format!("{base}:m"), &cand])
            },
        ),
        err(
            a,
            "a run listed twice",
            NR,
            &["a.csv", "line 3", "already on line 2"],
            |dir| {
                let run = "s,co_flow,e1,r,m,7,1";
                let base = results_file(dir, "a.csv", &[run, run])?;
                cli(&["compare", &base, &base])
            },
        ),
        err(
            a,
            "a file of two methods, none named",
            NR,
            &["a.csv", "holds the methods m, n", "FILE:METHOD"],
            |dir| {
                let base = results_file(
                    dir,
                    "a.csv",
                    &["s,co_flow,e1,r,m,7,1", "s,co_flow,e1,r,n,7,0"],
                )?;
                cli(&["compare", &base, &base])
            },
        ),
        err(
            a,
            "a method the file does not hold",
            NR,
            &["a.csv", "no runs of method", "it holds"],
            |dir| {
                let base = results_file(dir, "a.csv", &["s,co_flow,e1,r,m,7,1"])?;
                cli(&["compare", &format!("{base}:x"), &base])
            },
        ),
        err(
            a,
            "two runs with no run in common",
            NR,
            &["share no run"],
            |dir| {
                let base = results_file(dir, "a.csv", &["s,co_flow,e1,r,m,7,1"])?;
                let cand = results_file(dir, "b.csv", &["s,co_flow,e2,r,m,7,1"])?;
                cli(&["compare", &base, &cand])
            },
        ),
        err(
            a,
            "a file without the `success` column",
            NR,
            &["a.csv", "success", "column"],
            |dir| {
                let path = dir.join("a.csv");
                std::fs::write(
                    &path,
                    "suite,scenario,episode,robot,method,seed\ns,c,e,r,m,7\n",
                )
                .map_err(|e| e.to_string())?;
                let arg = format!("{}:m", path.to_string_lossy());
                cli(&["compare", &arg, &arg])
            },
        ),
    ]
}

// ---------------------------------------------------------------------------------------------

fn after(e: &Expect) -> String {
    match e {
        Expect::Error(f) => format!(
            "error naming {}",
            f.iter()
                .map(|s| format!("`{s}`"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        Expect::Accepted(t) => (*t).to_string(),
        Expect::Covered(t, test) => format!("{t} (`{test}`)"),
    }
}

fn cell(s: &str) -> String {
    s.replace('|', "\\|")
}

fn render(cases: &[Case]) -> String {
    let mut areas: Vec<&str> = Vec::new();
    for c in cases {
        if !areas.contains(&c.area) {
            areas.push(c.area);
        }
    }
    let mut s = String::from(
        "# Hostile inputs: the table of cases\n\n\
         Generated from `sdk/cli/tests/hostile_inputs.rs`, which runs every case (regenerate with \
         `BLESS=1 cargo test -p human2nav-cli --test hostile_inputs`). \"After\" is what the test \
         checks: an error whose text contains the fragments shown (the file, field or line it \
         names), a documented bound, or the regression test that pins the case. \"Before\" is the \
         behaviour issues #17 and #51 or the history recorded; \"not recorded\" where neither did.\n\n\
         | area | cases | run here | pinned elsewhere |\n|---|---|---|---|\n",
    );
    for a in &areas {
        let n = cases.iter().filter(|c| c.area == *a).count();
        let here = cases
            .iter()
            .filter(|c| c.area == *a && c.run.is_some())
            .count();
        s.push_str(&format!("| {a} | {n} | {here} | {} |\n", n - here));
    }
    let here = cases.iter().filter(|c| c.run.is_some()).count();
    s.push_str(&format!(
        "| total | {} | {here} | {} |\n\n| area | case | before | after |\n|---|---|---|---|\n",
        cases.len(),
        cases.len() - here
    ));
    for c in cases {
        s.push_str(&format!(
            "| {} | {} | {} | {} |\n",
            c.area,
            cell(c.case),
            cell(c.before),
            cell(&after(&c.expect))
        ));
    }
    s
}

#[test]
fn every_case_has_its_outcome() {
    let base = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("hostile-inputs-{}", std::process::id()));
    let mut wrong = Vec::new();
    for (i, c) in catalogue().iter().enumerate() {
        let Some(run) = &c.run else { continue };
        let dir = base.join(format!("case-{i}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("case folder");
        let got = run(&dir);
        let ok = match (&c.expect, &got) {
            (Expect::Error(frags), Err(msg)) => frags.iter().all(|f| msg.contains(f)),
            (Expect::Accepted(_), Ok(())) => true,
            _ => false,
        };
        if !ok {
            wrong.push(format!(
                "[{}] {}: expected {}, got {:?}",
                c.area,
                c.case,
                after(&c.expect),
                got
            ));
        }
    }
    let _ = std::fs::remove_dir_all(&base);
    assert!(
        wrong.is_empty(),
        "{} cases:\n{}",
        wrong.len(),
        wrong.join("\n")
    );
}

#[test]
fn pinned_cases_name_tests_that_exist() {
    for c in catalogue() {
        let Expect::Covered(_, test) = c.expect else {
            continue;
        };
        let (file, name) = test.split_once("::").expect("file::test");
        let text = std::fs::read_to_string(root().join(file))
            .unwrap_or_else(|e| panic!("{test}: cannot read {file}: {e}"));
        let found = if name == "tests" {
            text.contains("mod tests")
        } else {
            // A Rust test, or a Python one (pytest).
            text.contains(&format!("fn {name}(")) || text.contains(&format!("def {name}("))
        };
        assert!(found, "{test}: no such test");
    }
}

#[test]
fn the_markdown_table_is_in_sync() {
    let path = root().join("docs/hostile-inputs.md");
    let want = render(&catalogue());
    if std::env::var_os("BLESS").is_some() {
        std::fs::create_dir_all(root().join("docs")).expect("docs folder");
        std::fs::write(&path, &want).expect("write the table");
        return;
    }
    let have = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        have == want,
        "{} is out of date: regenerate it with BLESS=1 cargo test -p human2nav-cli --test \
         hostile_inputs",
        path.display()
    );
}

#[test]
fn the_catalogue_is_broad() {
    let cases = catalogue();
    assert!(cases.len() >= 100, "{} cases", cases.len());
    for area in [
        "robot profiles",
        "configs",
        "data and episodes",
        "model folder",
        "plugins",
        "kill -9 and resume",
        "concurrent runs",
    ] {
        assert!(cases.iter().any(|c| c.area == area), "no case for {area}");
    }
}
