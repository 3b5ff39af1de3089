//! The benchmark configuration: parsing, validation and suite building with its fallbacks.

use human2nav_sim::SuiteKind;
use human2nav_sim::config::{BenchConfig, build_suites, ensure_episode_files, take_per_class};
use human2nav_sim::episode::ScenarioClass;
use std::path::{Path, PathBuf};

/// Writes `body` to a config file in a fresh scratch directory outside any workspace.
fn write_config(name: &str, body: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("h2n-sim-config-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch dir");
    let path = dir.join("bench.toml");
    std::fs::write(&path, body).expect("write config");
    path
}

const BASE: &str = r#"
robots = ["robots/diablo/robot.toml"]
[[methods]]
name = "straight"
kind = "straight"
"#;

#[test]
fn defaults_and_relative_paths() {
    let body = format!(
        "{BASE}\n[[suites]]\nname = \"real\"\nkind = \"real\"\nepisodes = \"missing/episodes.json\"\n"
    );
    let path = write_config("defaults", &body);
    let cfg = BenchConfig::load(&path).unwrap();
    assert_eq!(cfg.seed, 7);
    assert_eq!(cfg.suites[0].per_class, 50);
    assert_eq!(cfg.suites[0].quick_per_class, 3);
    assert_eq!(cfg.sim, human2nav_sim::SimConfig::default());
    // Outside a workspace, paths resolve against the config's directory.
    let dir = path.parent().unwrap();
    assert_eq!(cfg.base_dir, dir);
    assert_eq!(cfg.resolve(Path::new("a/b")), dir.join("a/b"));
    assert_eq!(cfg.resolve(Path::new("/abs")), PathBuf::from("/abs"));
    assert_eq!(cfg.snapshot_method(), Some("straight"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn validation_names_the_offending_setting() {
    let cases = [
        (BASE.to_string(), "suites"),
        (
            format!(
                "{BASE}\n[[methods]]\nname = \"straight\"\nkind = \"straight\"\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\n"
            ),
            "methods[1].name",
        ),
        (
            format!(
                "{BASE}\n[[methods]]\nname = \"orca\"\nkind = \"plugin\"\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\n"
            ),
            "library",
        ),
        (
            format!("{BASE}\n[[suites]]\nname = \"r\"\nkind = \"real\"\n"),
            "episodes",
        ),
        (
            format!("{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\nper_class = 0\n"),
            "per_class",
        ),
        (
            format!(
                "{BASE}\nsnapshot_method = \"nope\"\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\n"
            ),
            "snapshot_method",
        ),
        (
            format!(
                "{BASE}\n[sim]\nreplan_hz = 3.0\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\n"
            ),
            "replan_hz",
        ),
        (
            format!("{BASE}replan_hz = 3.0\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\n"),
            "methods[straight].replan_hz",
        ),
        (format!("{BASE}\ncolour = \"red\"\n"), "colour"),
        (
            format!(
                "{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\nmethods = [\"orca\"]\n"
            ),
            "suites[0].methods",
        ),
        (
            format!("{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\nmethods = []\n"),
            "suites[0].methods",
        ),
        (
            format!(
                "{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\nsocial_force = {{ range = 0.3 }}\n"
            ),
            "suites[0].social_force",
        ),
        (
            format!(
                "{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\ncrowd = \"reactive\"\nsocial_force = {{ range = -1.0 }}\n"
            ),
            "suites[0].social_force.range",
        ),
        (
            format!(
                "{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\ncrowd = \"panicking\"\n"
            ),
            "crowd",
        ),
    ];
    for (i, (body, needle)) in cases.iter().enumerate() {
        let path = write_config(&format!("invalid{i}"), body);
        let err = BenchConfig::load(&path).unwrap_err().to_string();
        assert!(
            err.contains(needle),
            "case {i}: `{err}` does not name `{needle}`"
        );
        std::fs::remove_dir_all(path.parent().unwrap()).unwrap();
    }
}

#[test]
fn missing_real_file_is_an_error_unless_the_fallback_is_allowed() {
    let body = format!(
        "{BASE}\n[[suites]]\nname = \"real\"\nkind = \"real\"\nepisodes = \"missing/episodes.json\"\n"
    );
    let path = write_config("missing", &body);
    let cfg = BenchConfig::load(&path).unwrap();
    let err = build_suites(&cfg, true, None).unwrap_err().to_string();
    assert!(
        err.contains("suites[0]")
            && err.contains("episodes")
            && err.contains("missing/episodes.json"),
        "{err}"
    );
    std::fs::remove_dir_all(path.parent().unwrap()).unwrap();
}

#[test]
fn missing_real_file_falls_back_to_synthetic_and_empty_strips_the_crowd() {
    let body = format!(
        "{BASE}\n[[suites]]\nname = \"real\"\nkind = \"real\"\nepisodes = \"missing/episodes.json\"\n\
         quick_per_class = 2\n[[suites]]\nname = \"empty\"\nkind = \"empty\"\nquick_per_class = 1\n"
    );
    let path = write_config("fallback", &body);
    let cfg = BenchConfig::load(&path).unwrap();
    let suites = build_suites(&cfg, true, Some("no datasets")).unwrap();
    assert_eq!(suites.len(), 2);
    let real = &suites[0];
    assert_eq!(real.kind, SuiteKind::Synthetic);
    let note = real.note.as_deref().unwrap_or("");
    assert!(
        note.starts_with("Warning:") && note.contains("fell back") && note.contains("no datasets"),
        "{:?}",
        real.note
    );
    assert_eq!(real.episodes.len(), 8);
    for c in ScenarioClass::ALL {
        assert_eq!(real.episodes.iter().filter(|e| e.scenario == c).count(), 2);
    }
    let empty = &suites[1];
    assert_eq!(empty.kind, SuiteKind::Empty);
    assert_eq!(empty.episodes.len(), 4);
    for e in &empty.episodes {
        assert!(e.agents.is_empty());
        let src = real
            .episodes
            .iter()
            .find(|r| format!("{}-empty", r.id) == e.id)
            .unwrap();
        assert_eq!(
            (src.start, src.goal, src.time_budget),
            (e.start, e.goal, e.time_budget)
        );
    }
    // Deterministic: the same config builds the same suites.
    let again = build_suites(&cfg, true, Some("no datasets")).unwrap();
    assert_eq!(again[0].episodes, real.episodes);
    std::fs::remove_dir_all(path.parent().unwrap()).unwrap();
}

#[test]
fn take_per_class_keeps_file_order_within_each_class() {
    let path = write_config(
        "take",
        &format!("{BASE}\n[[suites]]\nname = \"s\"\nkind = \"synthetic\"\n"),
    );
    let cfg = BenchConfig::load(&path).unwrap();
    let mut episodes = build_suites(&cfg, true, None).unwrap().remove(0).episodes;
    episodes.reverse();
    let picked = take_per_class(&episodes, 1);
    assert_eq!(picked.len(), 4);
    for (p, c) in picked.iter().zip(ScenarioClass::ALL) {
        assert_eq!(p.scenario, c);
        assert_eq!(p.id, episodes.iter().find(|e| e.scenario == c).unwrap().id);
    }
    std::fs::remove_dir_all(path.parent().unwrap()).unwrap();
}

#[test]
fn a_config_can_start_from_a_base_file() {
    let base = write_config(
        "base",
        &format!("seed = 11\n{BASE}[[suites]]\nname = \"test\"\nkind = \"synthetic\"\n"),
    );
    let dir = base.parent().unwrap();
    let child = dir.join("val.toml");
    std::fs::write(
        &child,
        format!(
            "base = \"{}\"\n[[suites]]\nname = \"val\"\nkind = \"synthetic\"\nper_class = 2\n",
            base.display()
        ),
    )
    .unwrap();
    let cfg = BenchConfig::load(&child).unwrap();
    assert_eq!(cfg.seed, 11);
    assert_eq!(cfg.methods[0].name, "straight");
    let names: Vec<&str> = cfg.suites.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["val"]);
    // A cycle is an error naming the chain, not a stack overflow.
    std::fs::write(&child, format!("base = \"{}\"\n", child.display())).unwrap();
    let err = BenchConfig::load(&child).unwrap_err().to_string();
    assert!(err.contains("base") && err.contains("8"), "{err}");
    std::fs::write(&child, "base = 3\n").unwrap();
    let err = BenchConfig::load(&child).unwrap_err().to_string();
    assert!(err.contains("`base` must be a path"), "{err}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// The workspace's data directory as the tests find it (`$HUMAN2NAV_DATA`, else
/// `../shared/data` beside the workspace).
fn data_root() -> Option<PathBuf> {
    let root = human2nav_data::paths::data_root(
        None,
        &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.."),
    );
    root.is_dir().then_some(root)
}

#[test]
fn missing_datasets_are_a_visible_fallback_and_an_unknown_missing_file_is_an_error() {
    let dir = write_config("ensure", "").parent().unwrap().to_path_buf();
    let bench = dir.join("bench.toml");
    std::fs::write(
        &bench,
        format!(
            "{BASE}\n[[suites]]\nname = \"typo\"\nkind = \"real\"\nepisodes = \"out/episodes-interation.json\"\n"
        ),
    )
    .unwrap();
    let cfg = BenchConfig::load(&bench).unwrap();
    // A misspelled data root: the fallback is allowed, and says why.
    let data = dir.join("data.toml");
    std::fs::write(&data, "[paths]\ndata_root = \"no/such/datsets\"\n").unwrap();
    let why = ensure_episode_files(&cfg, &data, &|_| {}).unwrap().unwrap();
    assert!(
        why.contains("no/such/datsets") && why.contains("data_root"),
        "{why}"
    );
    let suites = build_suites(&cfg, true, Some(&why)).unwrap();
    assert!(suites[0].note.as_deref().unwrap().starts_with("Warning:"));
    // With the datasets present, a missing file the data config does not write is an error.
    if let Some(root) = data_root() {
        std::fs::write(
            &data,
            format!("[paths]\ndata_root = \"{}\"\n", root.display()),
        )
        .unwrap();
        let err = ensure_episode_files(&cfg, &data, &|_| {})
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("suites[0].episodes") && err.contains("episodes-interation.json"),
            "{err}"
        );
    } else {
        eprintln!("skipping the datasets-present half: no datasets found");
    }
    std::fs::remove_dir_all(dir).unwrap();
}
