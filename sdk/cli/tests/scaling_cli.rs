//! `human2nav scaling` end to end on a tiny self-contained setup: a synthetic tuple cache (built
//! with `human2nav data build` from a data config with `synthetic_only = true`), a tiny
//! network trained for a few steps on two fractions of the training scenes, one synthetic
//! episode per scenario class (the suite's episode file is absent) and one robot. Checks the
//! CSV, the report and the figure, then that a second run reuses the complete models and the
//! stored closed-loop rows, and a third without the stored rows measures the same SR.

#![allow(clippy::unwrap_used)] // test helpers; a failed fixture should panic

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn human2nav(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_human2nav"))
        .current_dir(workspace_root())
        .args(args)
        .output()
        .unwrap()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// TOML string literal of a path.
fn lit(p: &Path) -> String {
    format!("{:?}", p.display().to_string())
}

/// Writes the data, train, bench, planner and scaling configs into `dir`; returns the scaling
/// config's path.
fn write_configs(dir: &Path) -> PathBuf {
    let root = workspace_root().canonicalize().unwrap();
    let cache = dir.join("cache");
    std::fs::write(
        dir.join("data.toml"),
        format!(
            "[paths]\ncache_dir = {}\nepisodes = {}\n\
             [sources]\nsynthetic_only = true\nsynthetic_scenes = 10\nseed = 3\n\
             [bev]\ncells = 16\n\
             [tuples]\nhorizon = 8\n",
            lit(&cache),
            lit(&dir.join("episodes.json")),
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("train.toml"),
        format!(
            "[data]\ncache = {}\n\
             [net]\nhorizon = 8\nbev_cells = 16\ndown_dims = [8, 16]\nn_groups = 4\n\
             bev_channels = [4, 8, 8]\ntime_embed_dim = 8\nbev_embed_dim = 8\ngoal_embed_dim = 8\n\
             [train]\nbatch_size = 16\nsteps = 1000\nwarmup_steps = 1\n\
             [run]\nname = \"tiny\"\nthreads = 1\ndevice = \"cpu\"\nvalidate_every = 2\n\
             checkpoint_every = 2\nmax_minutes = 0.01\n",
            lit(&cache)
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("bench.toml"),
        format!(
            "seed = 5\nrobots = [{}]\n\
             [[methods]]\nname = \"straight\"\nkind = \"straight\"\n\
             [[suites]]\nname = \"real\"\nkind = \"real\"\nepisodes = {}\nper_class = 50\n\
             quick_per_class = 3\n\
             [[suites]]\nname = \"again\"\nkind = \"real\"\nepisodes = {}\nper_class = 50\n\
             quick_per_class = 3\n",
            lit(&root.join("robots/diablo/robot.toml")),
            lit(&dir.join("episodes.json")),
            lit(&dir.join("episodes.json")),
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("planner.toml"),
        "model = \"replaced\"\n[human2nav]\nsamples = 4\nguided_samples = 2\n\
         [human2nav.guidance]\nsteps_n = 3\niterations_m = 1\n",
    )
    .unwrap();
    let scaling = dir.join("scaling.toml");
    std::fs::write(
        &scaling,
        format!(
            "train = {}\nbench = {}\nplanner = {}\ndata = {}\n\
             fractions = [0.5, 1.0]\nsteps = 4\nper_class = 1\nrobots = [\"diablo\"]\nseed = 2\n",
            lit(&dir.join("train.toml")),
            lit(&dir.join("bench.toml")),
            lit(&dir.join("planner.toml")),
            lit(&dir.join("data.toml")),
        ),
    )
    .unwrap();
    scaling
}

/// The data rows of `scaling.csv` as field lists, with the header's column index of `name`.
fn csv_rows(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let csv = std::fs::read_to_string(path).unwrap();
    let mut lines = csv.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

/// `human2nav scaling --config <scaling> --out <out> --threads 1` with `extra` arguments.
fn run_scaling(scaling: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "scaling",
        "--config",
        scaling.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--threads",
        "1",
    ];
    args.extend_from_slice(extra);
    human2nav(&args)
}

fn column(header: &[String], name: &str) -> usize {
    header.iter().position(|h| h == name).unwrap()
}

#[test]
fn two_fractions_end_to_end_then_resumed() {
    let dir = std::env::temp_dir().join(format!("h2n-scaling-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let scaling = write_configs(&dir);

    let out = human2nav(&[
        "data",
        "build",
        "--config",
        dir.join("data.toml").to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));

    let out_dir = dir.join("out");
    let run = || run_scaling(&scaling, &out_dir, &[]);
    let out = run();
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stderr}");
    assert!(stdout.contains("2 fractions in"), "{stdout}");
    assert!(
        stderr.contains("frac-050: training 4 steps on 4 of 8"),
        "{stderr}"
    );
    assert!(
        stderr.contains("frac-100: training 4 steps on 8 of 8"),
        "{stderr}"
    );

    let (header, rows) = csv_rows(&out_dir.join("scaling.csv"));
    assert_eq!(rows.len(), 2, "one row per fraction");
    let hours_col = column(&header, "recorded_hours");
    let hours: Vec<f64> = rows.iter().map(|r| r[hours_col].parse().unwrap()).collect();
    // Fig. 5's x-axis: the recorded time of the chosen scenes, more for more scenes.
    assert!(hours[0] > 0.0 && hours[0] < hours[1], "{hours:?}");
    let (f, sr, n, scenes, steps, model) = (
        column(&header, "fraction"),
        column(&header, "sr"),
        column(&header, "episode_runs"),
        column(&header, "train_scenes"),
        column(&header, "steps"),
        column(&header, "model"),
    );
    for (row, (fraction, n_scenes)) in rows.iter().zip([(0.5, "4"), (1.0, "8")]) {
        assert_eq!(row.len(), header.len());
        assert_eq!(row[f].parse::<f64>().unwrap(), fraction);
        let v: f64 = row[sr].parse().unwrap();
        assert!((0.0..=1.0).contains(&v), "SR {v}");
        assert_eq!(row[n], "4", "one episode per class on one robot");
        assert_eq!(row[scenes], n_scenes);
        // run.max_minutes of the train config is ignored: every model gets its 4 steps.
        assert_eq!(row[steps], "4");
        assert_eq!(row[model], "trained");
    }
    let png = std::fs::metadata(out_dir.join("fig5_sr_vs_training_data.png")).unwrap();
    assert!(png.len() > 1000, "figure of {} bytes", png.len());
    let report = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    assert!(
        report.contains(&format!("| 50 % | {:.2} | 4 |", hours[0])),
        "{report}"
    );
    assert!(
        report.contains(&format!("| 100 % | {:.2} | 8 |", hours[1])),
        "{report}"
    );
    for frac in ["frac-050", "frac-100"] {
        assert!(
            out_dir
                .join("models")
                .join(frac)
                .join("model.toml")
                .is_file()
        );
        let results = std::fs::read_to_string(out_dir.join(frac).join("results.csv")).unwrap();
        assert_eq!(results.lines().count(), 5, "{results}");
    }

    let closed_loop = column(&header, "closed_loop");
    assert!(rows.iter().all(|r| r[closed_loop] == "measured"));

    // A second run reuses both models and their stored closed-loop rows.
    let out = run();
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("frac-050: model"), "{stderr}");
    assert!(!stderr.contains("training 4 steps"), "{stderr}");
    let (_, again) = csv_rows(&out_dir.join("scaling.csv"));
    for (a, b) in rows.iter().zip(&again) {
        assert_eq!(b[model], "reused");
        assert_eq!(b[closed_loop], "reused");
        assert_eq!(a[sr], b[sr]);
    }

    // Without the stored rows the episodes run again on the reused models, with the same
    // outcome (deterministic given the seeds).
    for frac in ["frac-050", "frac-100"] {
        std::fs::remove_file(out_dir.join(frac).join("closed_loop.toml")).unwrap();
    }
    let out = run();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let (_, third) = csv_rows(&out_dir.join("scaling.csv"));
    for (a, c) in rows.iter().zip(&third) {
        assert_eq!(c[model], "reused");
        assert_eq!(c[closed_loop], "measured");
        assert_eq!(a[sr], c[sr], "deterministic given the seeds");
    }

    // Another suite on the same models: `--suite` measures it, `--models` reuses the models
    // of the run above instead of training them again (the suite `again` has the same
    // episodes, so the success rates are the same).
    let again_dir = dir.join("out-again");
    let out = run_scaling(
        &scaling,
        &again_dir,
        &["--models", out_dir.to_str().unwrap(), "--suite", "again"],
    );
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("suite `again`"), "{stderr}");
    assert!(!stderr.contains("training 4 steps"), "{stderr}");
    assert!(!again_dir.join("models").exists());
    let (_, other_suite) = csv_rows(&again_dir.join("scaling.csv"));
    for (a, d) in rows.iter().zip(&other_suite) {
        assert_eq!(d[model], "reused");
        assert_eq!(d[closed_loop], "measured");
        assert_eq!(a[sr], d[sr]);
    }
    let out = run_scaling(&scaling, &again_dir, &["--suite", "nope"]);
    let stderr = text(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("`nope` is not a suite of") && stderr.contains("real, again"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
