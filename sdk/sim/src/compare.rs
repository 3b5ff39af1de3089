//! Two benchmark runs compared run by run: each method's outcomes read from a `results.csv`,
//! paired on the same (suite, scenario, episode, robot, seed), and the difference tested per
//! suite and robot, per suite and over everything with the exact McNemar test and the paired
//! bootstrap interval of [`crate::stats`] (`human2nav compare`).
//!
//! The report's own paired table compares the methods of one run; this compares a method of
//! one run with a method of another, as a setting is judged against the shipped planner on
//! the same episodes. Runs only one side has are counted and left out.

use crate::error::SimError;
use crate::report;
use crate::stats::PairedComparison;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt::Write as _;
use std::path::Path;

/// What identifies one run across two benchmark runs.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RunKey {
    /// The suite's name.
    pub suite: String,
    /// Its robot's name.
    pub robot: String,
    /// The scenario class.
    pub scenario: String,
    /// The episode's id.
    pub episode: String,
    /// The run's seed.
    pub seed: String,
}

/// The columns of `results.csv` this reads.
const COLUMNS: [&str; 7] = [
    "suite", "scenario", "episode", "robot", "method", "seed", "success",
];

/// Whether each run of one method succeeded.
pub type Outcomes = HashMap<RunKey, bool>;

/// Every method's outcomes in the `results.csv` at `path`, by method name. Errors name the file
/// and, for a bad line, its number: a missing column, a `success` other than 0 or 1, or a run
/// a method lists twice.
pub fn read_results(path: &Path) -> Result<BTreeMap<String, Outcomes>, SimError> {
    let parse = |message: String| SimError::Parse {
        path: path.to_path_buf(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|source| SimError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut reader = csv::Reader::from_reader(file);
    let header = reader
        .headers()
        .map_err(|e| parse(format!("its header: {e}")))?
        .clone();
    let mut at = [0usize; COLUMNS.len()];
    for (slot, name) in at.iter_mut().zip(COLUMNS) {
        *slot = header.iter().position(|h| h == name).ok_or_else(|| {
            parse(format!(
                "no `{name}` column (a results.csv of `human2nav bench` has one)"
            ))
        })?;
    }
    let [suite, scenario, episode, robot, method, seed, success] = at;
    // Each method's runs: outcome and line.
    let mut runs: BTreeMap<String, HashMap<RunKey, (bool, u64)>> = BTreeMap::new();
    for record in reader.records() {
        let record = record.map_err(|e| parse(e.to_string()))?;
        let line = record.position().map_or(0, |p| p.line());
        let field = |i: usize| record.get(i).unwrap_or("");
        let ok = match field(success) {
            "1" => true,
            "0" => false,
            other => {
                return Err(parse(format!(
                    "line {line}: `success` is `{other}`, not 0 or 1"
                )));
            }
        };
        let key = RunKey {
            suite: field(suite).to_string(),
            robot: field(robot).to_string(),
            scenario: field(scenario).to_string(),
            episode: field(episode).to_string(),
            seed: field(seed).to_string(),
        };
        let of_method = runs.entry(field(method).to_string()).or_default();
        if let Some(&(_, first)) = of_method.get(&key) {
            return Err(parse(format!(
                "line {line}: method `{}` ran episode `{}` of suite `{}` on `{}` with seed {} \
                 already on line {first}",
                field(method),
                key.episode,
                key.suite,
                key.robot,
                key.seed
            )));
        }
        of_method.insert(key, (ok, line));
    }
    Ok(runs
        .into_iter()
        .map(|(m, of_method)| {
            (
                m,
                of_method.into_iter().map(|(k, (ok, _))| (k, ok)).collect(),
            )
        })
        .collect())
}

/// The outcomes of `method` among `results` (read from `path`), or an error naming the methods
/// the file holds.
pub fn method_outcomes(
    mut results: BTreeMap<String, Outcomes>,
    method: &str,
    path: &Path,
) -> Result<Outcomes, SimError> {
    results.remove(method).ok_or_else(|| {
        let held: Vec<String> = results.keys().map(|m| format!("`{m}`")).collect();
        SimError::Parse {
            path: path.to_path_buf(),
            message: format!(
                "no runs of method `{method}`; it holds {}",
                if held.is_empty() {
                    "no runs at all".to_string()
                } else {
                    held.join(", ")
                }
            ),
        }
    })
}

/// One group's comparison: the suite (`None`: all suites) and robot (`None`: all robots).
#[derive(Clone, Debug)]
pub struct GroupComparison {
    /// The suite, or `None` for all of them.
    pub suite: Option<String>,
    /// The robot, or `None` for all of them.
    pub robot: Option<String>,
    /// The paired statistics, the baseline as the reference.
    pub paired: PairedComparison,
}

/// Two runs compared (module docs).
#[derive(Clone, Debug)]
pub struct Comparison {
    /// Per suite and robot, then per suite, then over everything, suites and robots in order
    /// of name.
    pub groups: Vec<GroupComparison>,
    /// Runs the baseline has and the candidate does not.
    pub only_baseline: usize,
    /// Runs the candidate has and the baseline does not.
    pub only_candidate: usize,
}

/// The runs of `baseline` and `candidate` paired by [`RunKey`] and compared; `None` when they
/// share no run.
pub fn compare(baseline: &Outcomes, candidate: &Outcomes) -> Option<Comparison> {
    // In key order, so that the bootstrap sees the pairs in the same order every time.
    let mut shared: Vec<(&RunKey, bool, bool)> = baseline
        .iter()
        .filter_map(|(k, &b)| candidate.get(k).map(|&c| (k, b, c)))
        .collect();
    shared.sort();
    let group = |suite: Option<&str>, robot: Option<&str>| {
        let pairs: Vec<(bool, bool)> = shared
            .iter()
            .filter(|(k, ..)| {
                suite.is_none_or(|s| k.suite == s) && robot.is_none_or(|r| k.robot == r)
            })
            .map(|&(_, b, c)| (b, c))
            .collect();
        PairedComparison::of(&pairs).map(|paired| GroupComparison {
            suite: suite.map(str::to_string),
            robot: robot.map(str::to_string),
            paired,
        })
    };
    let total = group(None, None)?;
    let suites: BTreeSet<&str> = shared.iter().map(|(k, ..)| k.suite.as_str()).collect();
    let mut groups = Vec::new();
    for suite in suites {
        let robots: BTreeSet<&str> = shared
            .iter()
            .filter(|(k, ..)| k.suite == suite)
            .map(|(k, ..)| k.robot.as_str())
            .collect();
        groups.extend(
            robots
                .into_iter()
                .filter_map(|r| group(Some(suite), Some(r))),
        );
        groups.extend(group(Some(suite), None));
    }
    groups.push(total);
    let only = |a: &Outcomes, b: &Outcomes| a.keys().filter(|k| !b.contains_key(*k)).count();
    Some(Comparison {
        groups,
        only_baseline: only(baseline, candidate),
        only_candidate: only(candidate, baseline),
    })
}

/// `comparison` as a Markdown table, `baseline` and `candidate` naming the two sides.
pub fn markdown(comparison: &Comparison, baseline: &str, candidate: &str) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Paired runs: `{baseline}` (baseline) against `{candidate}`. b: runs only the baseline \
         solved, c: runs only the candidate solved; p: exact two-sided McNemar test; the \
         interval: 95 % paired bootstrap of the SR difference (candidate minus baseline).\n"
    );
    let _ = writeln!(
        out,
        "| suite | robot | n | SR baseline (%) | SR candidate (%) | ΔSR (pp) [95 % CI] | b | c | p |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|---|---|---|");
    for g in &comparison.groups {
        let p = &g.paired;
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {:+.1} [{:+.1}, {:+.1}] | {} | {} | {} |",
            g.suite.as_deref().unwrap_or("all"),
            g.robot.as_deref().unwrap_or("all"),
            p.n,
            report::pct(p.sr_reference),
            report::pct(p.sr_other),
            // Candidate minus baseline; `+ 0.0` writes a zero as +0.0, not -0.0.
            -100.0 * p.difference + 0.0,
            -100.0 * p.ci.1 + 0.0,
            -100.0 * p.ci.0 + 0.0,
            p.b,
            p.c,
            report::p_value(p.p_value),
        );
    }
    if comparison.only_baseline + comparison.only_candidate > 0 {
        let _ = writeln!(
            out,
            "\nLeft out, unpaired: {} runs only the baseline has, {} only the candidate has.",
            comparison.only_baseline, comparison.only_candidate
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write as _;

    /// The outcomes of `method` in the file at `path`, as `human2nav compare` reads them.
    fn read_outcomes(path: &Path, method: &str) -> Result<Outcomes, SimError> {
        method_outcomes(read_results(path)?, method, path)
    }

    fn key(suite: &str, robot: &str, episode: &str) -> RunKey {
        RunKey {
            suite: suite.into(),
            robot: robot.into(),
            scenario: "co_flow".into(),
            episode: episode.into(),
            seed: "7".into(),
        }
    }

    /// A file of `lines` under the temporary directory, removed when dropped.
    struct CsvFile(std::path::PathBuf);

    impl CsvFile {
        fn path(&self) -> &Path {
            &self.0
        }
    }

    impl Drop for CsvFile {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn csv_file(lines: &[&str]) -> CsvFile {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let path = std::env::temp_dir().join(format!(
            "h2n-compare-{}-{}.csv",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        let mut f = std::fs::File::create(&path).unwrap();
        for l in lines {
            writeln!(f, "{l}").unwrap();
        }
        CsvFile(path)
    }

    #[test]
    fn runs_are_paired_per_suite_and_robot_and_counted() {
        let mut a = HashMap::new();
        let mut b = HashMap::new();
        // Suite s, robot r: 4 shared runs, the baseline alone solves one, the candidate two.
        for (i, (x, y)) in [(true, true), (true, false), (false, true), (false, true)]
            .into_iter()
            .enumerate()
        {
            a.insert(key("s", "r", &i.to_string()), x);
            b.insert(key("s", "r", &i.to_string()), y);
        }
        // Robot q: one shared run; one run each side alone.
        a.insert(key("s", "q", "0"), true);
        b.insert(key("s", "q", "0"), true);
        a.insert(key("s", "q", "1"), true);
        b.insert(key("t", "q", "1"), false);
        let c = compare(&a, &b).unwrap();
        let names: Vec<(Option<&str>, Option<&str>)> = c
            .groups
            .iter()
            .map(|g| (g.suite.as_deref(), g.robot.as_deref()))
            .collect();
        assert_eq!(
            names,
            [
                (Some("s"), Some("q")),
                (Some("s"), Some("r")),
                (Some("s"), None),
                (None, None)
            ]
        );
        let r = &c.groups[1].paired;
        assert_eq!((r.n, r.b, r.c), (4, 1, 2));
        assert!((r.sr_reference - 0.5).abs() < 1e-12 && (r.sr_other - 0.75).abs() < 1e-12);
        let all = &c.groups[3].paired;
        assert_eq!((all.n, all.b, all.c), (5, 1, 2));
        assert_eq!((c.only_baseline, c.only_candidate), (1, 1));
        let md = markdown(&c, "A", "B");
        assert!(md.contains("| s | r | 4 | 50.0 | 75.0 | +25.0"), "{md}");
        assert!(md.contains("1 runs only the baseline has, 1 only the candidate has"));
        assert!(compare(&a, &HashMap::new()).is_none());
    }

    #[test]
    fn a_results_file_is_read_for_one_method_and_bad_lines_are_named() {
        let header = "suite,scenario,episode,robot,method,seed,outcome,success";
        let f = csv_file(&[
            header,
            "s,co_flow,e1,r,m,7,success,1",
            "s,co_flow,e1,r,n,7,collision,0",
            "s,co_flow,e2,r,m,7,timeout,0",
        ]);
        let m = read_outcomes(f.path(), "m").unwrap();
        assert_eq!(m.len(), 2);
        assert!(m[&key("s", "r", "e1")] && !m[&key("s", "r", "e2")]);
        assert!(read_results(f.path()).unwrap().keys().eq(["m", "n"]));
        let err = read_outcomes(f.path(), "x").unwrap_err().to_string();
        assert!(
            err.contains("no runs of method `x`; it holds `m`, `n`"),
            "{err}"
        );

        let f = csv_file(&[header, "s,co_flow,e1,r,m,7,success,yes"]);
        let err = read_outcomes(f.path(), "m").unwrap_err().to_string();
        assert!(err.contains("line 2: `success` is `yes`"), "{err}");
        let f = csv_file(&[
            header,
            "s,co_flow,e1,r,m,7,success,1",
            "s,co_flow,e1,r,m,7,success,1",
        ]);
        let err = read_outcomes(f.path(), "m").unwrap_err().to_string();
        assert!(err.contains("line 3") && err.contains("on line 2"), "{err}");
        let f = csv_file(&["suite,episode,robot,method,seed,success"]);
        let err = read_outcomes(f.path(), "m").unwrap_err().to_string();
        assert!(err.contains("no `scenario` column"), "{err}");
        let missing = Path::new("no/such/results.csv");
        let err = read_outcomes(missing, "m").unwrap_err().to_string();
        assert!(err.contains("no/such/results.csv"), "{err}");
    }
}
