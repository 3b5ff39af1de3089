//! The task guides in `docs/guide/` keep working: their files are written out and used.
//!
//! A fenced block preceded by `<!-- guide file: PATH -->` is a file the reader writes, and one
//! preceded by `<!-- guide append: PATH -->` is appended to one; paths are relative to the
//! folder holding the SDK's checkout (`human2nav/...`) and the reader's plugin crates
//! (`keep_distance/...`). Each test writes a page's files into a scratch folder laid out that
//! way and uses them as the SDK would: robot profiles are loaded, benchmark configurations
//! parsed, `Cargo.toml`s read, the C plugin compiled and loaded through the host (when a C
//! compiler is present), and `human2nav robot check` compared with the output the guide shows
//! (when the CLI is built). The Rust blocks are doctests of `examples/custom_constraint`
//! (`cargo test -p human2nav-example-proximity-speed --doc`); a test here checks that every
//! page with Rust code is listed there.

// Helpers outside #[test] functions unwrap too (clippy.toml only allows it inside tests).
#![allow(clippy::unwrap_used)]

use human2nav_core::constraint::{ConstraintContext, ConstraintTerm, TrajBatch};
use human2nav_core::robot::{EmbodimentSpec, RobotProfile};
use human2nav_core::{Limits, Twist2};
use human2nav_integration_tests::{target_profile_dir, workspace_root};
use human2nav_plugin::PluginHost;
use human2nav_sim::config::BenchConfig;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The guide pages whose files this test writes, and the index that lists every page.
const PAGES: [&str; 7] = [
    "README.md",
    "add-a-robot.md",
    "constraint-plugin.md",
    "planner-plugin.md",
    "embodiment-plugin.md",
    "benchmark.md",
    "train-a-model.md",
];

/// The crate whose doctests are the guides' Rust blocks.
const DOCTEST_HOOK: &str = "examples/custom_constraint/src/lib.rs";

/// A fenced code block of a guide page.
#[derive(Debug)]
struct Block {
    /// The info string's first word (`rust,test_harness` counts as `rust`).
    lang: String,
    /// `file`, `append` or `output`, from the comment before the block.
    marker: Option<(String, String)>,
    text: String,
    line: usize,
}

fn page(name: &str) -> String {
    let path = workspace_root().join("docs/guide").join(name);
    fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The fenced blocks of a page, with the `<!-- guide KIND: VALUE -->` comment right above each.
fn blocks(text: &str) -> Vec<Block> {
    let mut out = Vec::new();
    let lines: Vec<&str> = text.lines().collect();
    let mut i = 0;
    while i < lines.len() {
        let Some(info) = lines[i].strip_prefix("```") else {
            i += 1;
            continue;
        };
        let lang = info.split([',', ' ']).next().unwrap_or("").to_string();
        let marker = i
            .checked_sub(1)
            .and_then(|j| lines[j].trim().strip_prefix("<!-- guide "))
            .and_then(|m| m.strip_suffix("-->"))
            .and_then(|m| m.split_once(':'))
            .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()));
        let start = i + 1;
        let end = (start..lines.len())
            .find(|&j| lines[j].starts_with("```"))
            .unwrap_or_else(|| panic!("the block at line {start} is not closed"));
        let mut body = lines[start..end].join("\n");
        body.push('\n');
        out.push(Block {
            lang,
            marker,
            text: body,
            line: start,
        });
        i = end + 1;
    }
    out
}

/// A scratch folder of its own for `name`.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("h2n-guide-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    dir
}

/// Writes (or appends) the files `page` marks into `dir`; returns how many blocks it wrote.
fn write_files(page_name: &str, dir: &Path) -> usize {
    let mut n = 0;
    for b in blocks(&page(page_name)) {
        let Some((kind, path)) = &b.marker else {
            continue;
        };
        if kind != "file" && kind != "append" {
            continue;
        }
        let dest = dir.join(path);
        fs::create_dir_all(dest.parent().unwrap()).unwrap();
        if kind == "file" {
            fs::write(&dest, &b.text).unwrap();
        } else {
            let mut text = fs::read_to_string(&dest)
                .unwrap_or_else(|e| panic!("{page_name}:{}: append to {path}: {e}", b.line));
            text.push('\n');
            text.push_str(&b.text);
            fs::write(&dest, text).unwrap();
        }
        n += 1;
    }
    n
}

/// The block of `page_name` marked `<!-- guide output: NAME -->`.
fn output_block(page_name: &str, name: &str) -> String {
    blocks(&page(page_name))
        .into_iter()
        .find(|b| b.marker == Some(("output".into(), name.into())))
        .unwrap_or_else(|| panic!("{page_name} has no output block `{name}`"))
        .text
}

/// The built `human2nav` binary, if the workspace was built.
fn cli() -> Option<PathBuf> {
    let exe = target_profile_dir().join(format!("human2nav{}", std::env::consts::EXE_SUFFIX));
    exe.is_file().then_some(exe)
}

/// A plugin crate's `Cargo.toml` from a guide: a `cdylib` (and `rlib`) named `lib_name`,
/// depending on the SDK's facade without its default features.
fn check_plugin_manifest(path: &Path, lib_name: &str) {
    let text = fs::read_to_string(path).unwrap();
    let manifest: toml::Table = text.parse().unwrap();
    let lib = manifest["lib"].as_table().unwrap();
    assert_eq!(lib["name"].as_str(), Some(lib_name), "{}", path.display());
    let types: Vec<_> = lib["crate-type"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(types, ["cdylib", "rlib"], "{}", path.display());
    let sdk = manifest["dependencies"]["human2nav"].as_table().unwrap();
    assert_eq!(sdk["default-features"].as_bool(), Some(false));
    // The crate sits beside the SDK's checkout, `human2nav/`.
    let sdk_path = Path::new(sdk["path"].as_str().unwrap());
    assert_eq!(sdk_path, Path::new("../human2nav/sdk/human2nav"));
    assert!(workspace_root().join("sdk/human2nav/Cargo.toml").is_file());
}

#[test]
fn the_index_lists_every_guide_page() {
    let index = page("README.md");
    let dir = workspace_root().join("docs/guide");
    for entry in fs::read_dir(&dir).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        if name.ends_with(".md") && name != "README.md" {
            assert!(
                index.contains(&format!("]({name})")),
                "docs/guide/README.md does not link {name}"
            );
        }
    }
    for name in PAGES {
        assert!(dir.join(name).is_file(), "docs/guide/{name} is missing");
    }
}

#[test]
fn every_block_names_its_language_and_rust_blocks_are_doctests() {
    let hook = fs::read_to_string(workspace_root().join(DOCTEST_HOOK)).unwrap();
    for name in PAGES {
        let all = blocks(&page(name));
        for b in &all {
            // A block without a language would be taken for Rust by rustdoc.
            assert!(
                !b.lang.is_empty(),
                "{name}:{}: a block without a language",
                b.line
            );
        }
        if all.iter().any(|b| b.lang == "rust") {
            let include = format!("include_str!(\"../../../docs/guide/{name}\")");
            assert!(
                hook.contains(&include),
                "{name} has Rust blocks but {DOCTEST_HOOK} does not include it as a doctest"
            );
        }
    }
}

#[test]
fn the_block_parser_reads_markers() {
    let text = "a\n<!-- guide file: x/y.toml -->\n```toml\nk = 1\n```\n```rust,test_harness\nfn f() {}\n```\n";
    let b = blocks(text);
    assert_eq!(b.len(), 2);
    assert_eq!(b[0].marker, Some(("file".into(), "x/y.toml".into())));
    assert_eq!(
        (b[0].lang.as_str(), b[0].text.as_str()),
        ("toml", "k = 1\n")
    );
    assert_eq!((b[1].lang.as_str(), b[1].marker.is_none()), ("rust", true));
}

#[test]
fn add_a_robot_the_profile_loads_and_robot_check_prints_what_the_guide_shows() {
    let dir = scratch("robot");
    assert_eq!(write_files("add-a-robot.md", &dir), 2);
    let sdk = dir.join("human2nav");
    let p = RobotProfile::load(&sdk.join("robots/trolley/robot.toml")).unwrap();
    assert_eq!(p.name, "trolley");
    assert!(matches!(p.embodiment, EmbodimentSpec::Builtin(_)));
    // The wheel joints cap the 1.2 m/s asked for: 20 rad/s × 0.05 m.
    assert!((p.limits.v_max - 1.0).abs() < 1e-9, "{}", p.limits.v_max);
    assert!((p.footprint_radius - 0.28).abs() < 1e-9);

    let Some(exe) = cli() else {
        eprintln!("skipping the robot check comparison: the human2nav CLI is not built");
        return;
    };
    let out = Command::new(exe)
        .current_dir(&sdk)
        .args(["robot", "check", "robots/trolley/robot.toml"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let shown = output_block("add-a-robot.md", "robot-check");
    let printed = String::from_utf8(out.stdout).unwrap();
    assert_eq!(
        printed.trim_end(),
        shown.trim_end(),
        "docs/guide/add-a-robot.md shows other output than `robot check` prints"
    );
    fs::remove_dir_all(&dir).ok();
}

#[test]
fn constraint_plugin_manifest_and_profile() {
    let dir = scratch("constraint");
    write_files("add-a-robot.md", &dir);
    assert_eq!(write_files("constraint-plugin.md", &dir), 5);
    check_plugin_manifest(
        &dir.join("keep_distance/Cargo.toml"),
        "human2nav_keep_distance",
    );
    let p = RobotProfile::load(&dir.join("human2nav/robots/trolley/robot.toml")).unwrap();
    let terms: Vec<_> = p
        .constraints
        .iter()
        .map(|c| (c.plugin.as_str(), c.weight))
        .collect();
    assert_eq!(terms, [("keep_distance", 2.0), ("speed_cap", 1.0)]);
    // The libraries, relative to the profile, are where the guide builds them.
    assert!(
        p.constraints[0]
            .library
            .ends_with("../../../keep_distance/target/release/human2nav_keep_distance")
    );
    assert!(
        p.constraints[1]
            .library
            .ends_with("../../../speed_cap/libspeed_cap.so")
    );
    fs::remove_dir_all(&dir).ok();
}

/// Compiles the guide's C plugin with the guide's flags; `None` without a C compiler.
fn build_c_plugin(dir: &Path) -> Option<PathBuf> {
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    if Command::new(&cc).arg("--version").output().is_err() {
        eprintln!("skipping the C plugin: no C compiler (`{cc}`)");
        return None;
    }
    let src = dir.join("speed_cap");
    let include = workspace_root().join("sdk/plugin/include");
    let status = Command::new(&cc)
        .current_dir(&src)
        .args([
            "-std=c11", "-Wall", "-Wextra", "-Werror", "-O2", "-shared", "-fPIC",
        ])
        .arg("-I")
        .arg(&include)
        .args(["speed_cap.c", "-o", "libspeed_cap.so", "-lm"])
        .status()
        .unwrap();
    assert!(status.success(), "the guide's C plugin does not compile");
    Some(src.join("libspeed_cap.so"))
}

#[test]
#[cfg(target_os = "linux")]
fn constraint_plugin_in_c_compiles_loads_and_costs_what_it_says() {
    let dir = scratch("c");
    write_files("add-a-robot.md", &dir);
    write_files("constraint-plugin.md", &dir);
    let Some(lib) = build_c_plugin(&dir) else {
        return;
    };
    let host = PluginHost::new();
    let library = host.load_library(&lib).unwrap();
    assert_eq!((library.name(), library.version()), ("speed_cap", "0.1.0"));
    assert!(
        host.constraint(&lib, "speed_cap", "v_max = 1", None)
            .is_err()
    );
    let term = host
        .constraint(&lib, "speed_cap", "v_cap = 0.6", None)
        .unwrap();
    assert!(term.separable_nonnegative(), "the `properties` slot");

    // Two trajectories of three poses 0.1 s apart: 1.0 m/s then 0.5 m/s, and 0.5 m/s only.
    let data = [
        0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.15, 0.0, 0.0, // b = 0
        0.0, 0.0, 0.0, 0.0, 0.05, 0.0, 0.0, 0.1, 0.0, // b = 1
    ];
    let limits = Limits {
        v_max: 1.0,
        v_reverse_max: 0.3,
        a_max: 0.8,
        omega_max: 2.0,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    };
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &limits,
        initial_velocity: Twist2::ZERO,
        agents: &[],
        scene: Default::default(),
    };
    let eval = |x: &[f64]| {
        let (mut cost, mut grad) = (vec![0.0; 2], vec![0.0; 18]);
        term.evaluate(TrajBatch::new(x, 2, 3).unwrap(), &ctx, &mut cost, &mut grad)
            .unwrap();
        (cost, grad)
    };
    let (cost, grad) = eval(&data);
    // (1.0 − 0.6)² over the 2 segments; nothing below the cap.
    assert!((cost[0] - 0.08).abs() < 1e-12, "{cost:?}");
    assert_eq!(cost[1], 0.0);
    for i in 0..9 {
        let h = 1e-7;
        let mut x = data;
        x[i] += h;
        let up = eval(&x).0[0];
        x[i] -= 2.0 * h;
        let down = eval(&x).0[0];
        let fd = (up - down) / (2.0 * h);
        assert!((fd - grad[i]).abs() < 1e-5, "x[{i}]: {fd} vs {}", grad[i]);
    }

    // The profile with the C term only: the host resolves its path and loads it for the robot.
    let robot = dir.join("human2nav/robots/trolley/robot.toml");
    let text = fs::read_to_string(&robot).unwrap();
    let start = text.rfind("[[constraint]]").unwrap();
    let end = text.find("[[constraint]]").unwrap();
    let only_c = format!("{}{}", &text[..end], &text[start..]);
    fs::write(&robot, only_c).unwrap();
    let loaded = host
        .load_robot(RobotProfile::load(&robot).unwrap())
        .unwrap();
    assert_eq!(loaded.plugin_terms.len(), 1);
    assert_eq!(loaded.plugin_terms[0].1.name(), "speed_cap");
    fs::remove_dir_all(&dir).ok();
}

#[test]
fn planner_plugin_manifest_and_bench_config() {
    let dir = scratch("planner");
    assert_eq!(write_files("planner-plugin.md", &dir), 3);
    check_plugin_manifest(&dir.join("stop_short/Cargo.toml"), "human2nav_stop_short");
    let cfg = BenchConfig::load(&dir.join("human2nav/bench-stop-short.toml")).unwrap();
    let methods: Vec<_> = cfg
        .methods
        .iter()
        .map(|m| (m.name.as_str(), m.kind.as_str()))
        .collect();
    assert_eq!(
        methods,
        [
            ("stop_short", "plugin"),
            ("orca", "plugin"),
            ("straight", "straight")
        ]
    );
    let m = &cfg.methods[0];
    assert_eq!(m.plugin.as_deref(), Some("stop_short"));
    assert_eq!(
        m.library.as_deref(),
        Some(Path::new(
            "../stop_short/target/release/human2nav_stop_short"
        ))
    );
    assert_eq!(m.config.get("margin").and_then(|v| v.as_float()), Some(0.3));
    // The robots it names are the SDK's own.
    for robot in &cfg.robots {
        RobotProfile::load(&workspace_root().join(robot)).unwrap();
    }
    let suites: Vec<_> = cfg.suites.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(suites, ["synthetic", "empty"]);
    fs::remove_dir_all(&dir).ok();
}

#[test]
fn embodiment_plugin_manifest_and_profile() {
    let dir = scratch("embodiment");
    write_files("add-a-robot.md", &dir);
    assert_eq!(write_files("embodiment-plugin.md", &dir), 3);
    check_plugin_manifest(&dir.join("unicycle/Cargo.toml"), "human2nav_unicycle");
    let p = RobotProfile::load(&dir.join("human2nav/robots/trolley_plugin/robot.toml")).unwrap();
    let EmbodimentSpec::Plugin(r) = &p.embodiment else {
        panic!("expected a plugin embodiment, got {:?}", p.embodiment)
    };
    assert_eq!(r.plugin, "unicycle");
    assert_eq!(r.config.trim(), "reverse = false");
    assert!(
        r.library
            .ends_with("../../../unicycle/target/release/human2nav_unicycle")
    );
    // The footprint still comes from the trolley's URDF.
    assert!((p.footprint_radius - 0.28).abs() < 1e-9);
    fs::remove_dir_all(&dir).ok();
}
