//! `human2nav baseline eval-sarl` on the shipped SARL model: the table it prints, and that in
//! its training regime the model does what its card says.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The table rows of `eval-sarl`'s output, split into cells.
fn rows(stdout: &str) -> Vec<Vec<String>> {
    stdout
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| robot"))
        .map(|l| {
            l.trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect()
}

fn percent(cell: &str) -> f64 {
    cell.trim_end_matches(" %")
        .parse()
        .unwrap_or_else(|e| panic!("not a percentage: {cell:?} ({e})"))
}

#[test]
fn eval_sarl_prints_one_row_per_setting_and_the_trained_regime_matches_the_card() {
    let table = std::env::temp_dir().join(format!("h2n-eval-sarl-{}.md", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_human2nav"))
        .args([
            "baseline",
            "eval-sarl",
            "--robot",
            "robots/go2/robot.toml",
            "--humans",
            "5",
            "--visible",
            "--episodes",
            "50",
            "--out",
        ])
        .arg(&table)
        .current_dir(root())
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows = rows(&stdout);
    // (trained, go2) × (humans unseeing, seeing).
    assert_eq!(rows.len(), 4, "{stdout}");
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row.len(), 9, "{row:?}");
        assert_eq!(row[0], if i < 2 { "trained" } else { "go2" });
        assert_eq!(row[3], "5");
        assert_eq!(row[4], if i % 2 == 0 { "no" } else { "yes" });
        let outcomes: f64 = row[5..8].iter().map(|c| percent(c)).sum();
        assert!((outcomes - 100.0).abs() < 0.2, "{row:?}");
    }
    // The trained robot among 5 humans that do not see it is the card's held-out evaluation
    // (99.4 % of 500 episodes; the first 50 of the same stream here, so at most 3 failures).
    assert_eq!(&rows[0][1..3], ["0.30", "1.00"]);
    assert!(percent(&rows[0][5]) >= 94.0, "{:?}", rows[0]);
    // go2 enters with the benchmark's radius and speed: its footprint disc and v_max.
    assert_eq!(&rows[2][1..3], ["0.38", "2.00"]);
    let written = std::fs::read_to_string(&table).expect("the table file");
    let _ = std::fs::remove_file(&table);
    assert_eq!(written.lines().count(), 2 + 4);
}
