//! `human2nav bench --shard K/N` and `--merge`: two shards merged write the results.csv, the
//! figures and (but for its wall-time line) the report.md of one run, and bad specs, missing,
//! doubled and mismatched shards are refused with what is wrong.

#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A fresh folder holding a small benchmark (two robots, the built-in `straight` and `oracle`
/// methods, a synthetic suite with two episodes per class and an empty-world suite): 48 runs,
/// a few seconds.
fn small_bench(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("h2n-bench-shards-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let root = workspace_root().canonicalize().unwrap();
    let robot = |name: &str| {
        format!(
            "{:?}",
            root.join(format!("robots/{name}/robot.toml"))
                .display()
                .to_string()
        )
    };
    let config = format!(
        "seed = 11\nrobots = [{}, {}]\nsnapshot_method = \"oracle\"\n\n\
         [sim]\ndt = 0.05\nreplan_hz = 10.0\n\n\
         [[methods]]\nname = \"straight\"\nkind = \"straight\"\n\n\
         [[methods]]\nname = \"oracle\"\nkind = \"oracle\"\n\n\
         [[suites]]\nname = \"synthetic\"\nkind = \"synthetic\"\nper_class = 2\n\n\
         [[suites]]\nname = \"empty\"\nkind = \"empty\"\nper_class = 1\n",
        robot("diablo"),
        robot("go2")
    );
    std::fs::write(dir.join("bench.toml"), config).unwrap();
    dir
}

/// `human2nav bench` with `args` in `dir` (the data configuration given, since the small
/// benchmark's folder is outside the workspace).
fn bench(dir: &Path, args: &[&str]) -> Output {
    let data = workspace_root().join("sdk/configs/data.toml");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_human2nav"));
    cmd.current_dir(dir).arg("bench").args(args);
    if !args.contains(&"--merge") {
        cmd.arg("--data-config").arg(data);
    }
    cmd.output().unwrap()
}

fn ok(out: &Output) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{text}");
    text
}

fn refused(out: &Output) -> String {
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "{text}");
    text
}

/// report.md without its wall-time line (one run's and a merge's differ there only).
fn report_without_wall_time(dir: &Path) -> String {
    std::fs::read_to_string(dir.join("report.md"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with("Wall time:"))
        .collect::<Vec<_>>()
        .join("\n")
}

fn files(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    names.sort();
    names
}

#[test]
fn two_shards_merged_write_what_one_run_writes() {
    let dir = small_bench("merge");
    let common = ["--config", "bench.toml", "--threads", "1"];
    ok(&bench(&dir, &[&common[..], &["--out", "one"]].concat()));
    // The shards given in the other order: the merge puts them in order.
    let s2 = ok(&bench(
        &dir,
        &[&common[..], &["--shard", "2/2", "--out", "s2"]].concat(),
    ));
    assert!(s2.contains("shard 2/2: 24 of 48 episode runs"), "{s2}");
    ok(&bench(
        &dir,
        &[&common[..], &["--shard", "1/2", "--out", "s1"]].concat(),
    ));
    assert_eq!(
        files(&dir.join("s1")),
        ["results-exact.csv", "results.csv", "shard.json"]
    );
    let merged = ok(&bench(
        &dir,
        &["--merge", "s2", "s1", "--out", "merged", "--threads", "1"],
    ));
    assert!(merged.contains("48 runs from 2 shards"), "{merged}");

    let one = std::fs::read(dir.join("one/results.csv")).unwrap();
    assert_eq!(one.iter().filter(|&&b| b == b'\n').count(), 49);
    assert!(
        one == std::fs::read(dir.join("merged/results.csv")).unwrap(),
        "results.csv of the merge differs from one run's"
    );
    // Every figure, the snapshots and failure pictures that re-run episodes included.
    let names = files(&dir.join("one"));
    assert_eq!(names, files(&dir.join("merged")));
    assert!(
        names.iter().any(|n| n.starts_with("fig4_snapshots")),
        "{names:?}"
    );
    assert!(
        names.iter().any(|n| n.starts_with("failures_")),
        "{names:?}"
    );
    for name in names.iter().filter(|n| n.ends_with(".png")) {
        assert!(
            std::fs::read(dir.join("one").join(name)).unwrap()
                == std::fs::read(dir.join("merged").join(name)).unwrap(),
            "{name} differs"
        );
    }
    assert_eq!(
        report_without_wall_time(&dir.join("one")),
        report_without_wall_time(&dir.join("merged"))
    );
    let report = std::fs::read_to_string(dir.join("merged/report.md")).unwrap();
    assert!(report.contains("for 48 episode runs, summed over 2 shards"));

    // Missing, doubled, not a shard.
    let e = refused(&bench(&dir, &["--merge", "s1", "--out", "m"]));
    assert!(e.contains("missing shard 2/2"), "{e}");
    let e = refused(&bench(&dir, &["--merge", "s1", "s1", "--out", "m"]));
    assert!(e.contains("shard 1/2 given twice: `s1` and `s1`"), "{e}");
    let e = refused(&bench(&dir, &["--merge", "s1", "one", "--out", "m"]));
    assert!(e.contains("`one` has no shard.json"), "{e}");
    // A shard of another seed, of another split, of another configuration.
    ok(&bench(
        &dir,
        &[
            &common[..],
            &["--shard", "2/2", "--seed", "5", "--out", "seed5"],
        ]
        .concat(),
    ));
    let e = refused(&bench(&dir, &["--merge", "s1", "seed5", "--out", "m"]));
    assert!(
        e.contains("shards of different benchmarks: `config.seed`: 11 against 5"),
        "{e}"
    );
    ok(&bench(
        &dir,
        &[&common[..], &["--shard", "2/3", "--out", "of3"]].concat(),
    ));
    let e = refused(&bench(&dir, &["--merge", "s1", "of3", "--out", "m"]));
    assert!(
        e.contains("`s1` is shard 1/2 and `of3` is shard 2/3"),
        "{e}"
    );
    let config = std::fs::read_to_string(dir.join("bench.toml")).unwrap();
    std::fs::write(dir.join("dt.toml"), config.replace("dt = 0.05", "dt = 0.1")).unwrap();
    let other = [
        "--config",
        "dt.toml",
        "--threads",
        "1",
        "--shard",
        "2/2",
        "--out",
        "dt",
    ];
    ok(&bench(&dir, &other));
    let e = refused(&bench(&dir, &["--merge", "s1", "dt", "--out", "m"]));
    assert!(e.contains("`config.sim.dt`: 0.05 against 0.1"), "{e}");
    // The configuration changed after the shards ran.
    std::fs::write(
        dir.join("bench.toml"),
        config.replace("per_class = 2", "per_class = 3"),
    )
    .unwrap();
    let e = refused(&bench(&dir, &["--merge", "s1", "s2", "--out", "m"]));
    assert!(
        e.contains("not the one the shards ran: `config.suites[0].per_class`: 2 against 3"),
        "{e}"
    );
    // A shard cut short.
    std::fs::write(dir.join("bench.toml"), &config).unwrap();
    let exact = std::fs::read_to_string(dir.join("s2/results-exact.csv")).unwrap();
    let cut: Vec<&str> = exact.lines().collect();
    std::fs::write(
        dir.join("s2/results-exact.csv"),
        cut[..cut.len() - 1].join("\n"),
    )
    .unwrap();
    let e = refused(&bench(&dir, &["--merge", "s1", "s2", "--out", "m"]));
    assert!(
        e.contains("23 rows, but shard.json says 24 of 48 runs"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_shard_specs_and_options_beside_merge_are_refused() {
    let dir = small_bench("specs");
    for (spec, why) in [
        ("3/2", "K is larger than N"),
        ("0/0", "N must be at least 1"),
        ("1/0", "N must be at least 1"),
        ("0/3", "K counts from 1"),
        ("x/2", "K `x` is not a whole number"),
        ("2", "a shard is K/N"),
    ] {
        let e = refused(&bench(&dir, &["--config", "bench.toml", "--shard", spec]));
        assert!(e.contains(why), "{spec}: {e}");
    }
    let e = refused(&bench(&dir, &["--merge", "a", "b", "--quick"]));
    assert!(e.contains("cannot be used with '--quick'"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The files under `dir`, relative to it, sorted.
fn tree(dir: &Path) -> Vec<PathBuf> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let path = e.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                out.push(path.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

#[test]
fn recorded_shards_merged_gather_the_recordings_one_run_writes() {
    let dir = small_bench("record");
    let common = [
        "--config",
        "bench.toml",
        "--threads",
        "1",
        "--robots",
        "diablo",
    ];
    let recorded = [&common[..], &["--record"]].concat();
    ok(&bench(&dir, &[&recorded[..], &["--out", "one"]].concat()));
    ok(&bench(
        &dir,
        &[&recorded[..], &["--shard", "1/2", "--out", "s1"]].concat(),
    ));
    ok(&bench(
        &dir,
        &[&recorded[..], &["--shard", "2/2", "--out", "s2"]].concat(),
    ));
    let merge = ["--merge", "s1", "s2", "--out", "merged", "--threads", "1"];
    let merged = ok(&bench(&dir, &merge));
    assert!(
        merged.contains("gathered the 24 recordings of the shards"),
        "{merged}"
    );

    // The recordings one run writes, under the same names, byte for byte.
    let one = tree(&dir.join("one/record"));
    assert_eq!(one.len(), 24, "{one:?}");
    assert!(
        one.iter()
            .all(|f| f.extension().is_some_and(|e| e == "mcap")),
        "{one:?}"
    );
    assert_eq!(one, tree(&dir.join("merged/record")));
    for f in &one {
        assert!(
            std::fs::read(dir.join("one/record").join(f)).unwrap()
                == std::fs::read(dir.join("merged/record").join(f)).unwrap(),
            "{} differs",
            f.display()
        );
    }
    assert!(
        std::fs::read(dir.join("one/results.csv")).unwrap()
            == std::fs::read(dir.join("merged/results.csv")).unwrap(),
        "results.csv of the merge differs from one run's"
    );
    assert_eq!(files(&dir.join("one")), files(&dir.join("merged")));
    // The shards keep theirs, and a second merge into the same folder replaces its files.
    let (s1, s2) = (tree(&dir.join("s1/record")), tree(&dir.join("s2/record")));
    assert_eq!((s1.len(), s2.len()), (12, 12));
    ok(&bench(&dir, &merge));
    assert_eq!(one, tree(&dir.join("merged/record")));

    // A shard that recorded with one that did not.
    ok(&bench(
        &dir,
        &[&common[..], &["--shard", "2/2", "--out", "plain"]].concat(),
    ));
    let e = refused(&bench(&dir, &["--merge", "s1", "plain", "--out", "m"]));
    assert!(
        e.contains("`s1` ran with --record and `plain` without: a merge gathers the recordings of every shard or of none"),
        "{e}"
    );
    // A recording missing from a shard.
    std::fs::remove_file(dir.join("s2/record").join(&s2[0])).unwrap();
    let e = refused(&bench(&dir, &["--merge", "s1", "s2", "--out", "m"]));
    assert!(
        e.contains("shard 2/2 (`s2`) ran with --record, but its recording")
            && e.contains("is missing"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
