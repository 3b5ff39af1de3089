//! A benchmark spread over machines: `human2nav bench --shard K/N` runs the K-th of N slices of
//! the runs and keeps them in a shard folder; `human2nav bench --merge DIR...` joins the N
//! folders into the rows one run would have had, from which the usual `results.csv`, report
//! and figures are written ([`crate::driver::write_outputs`]).
//!
//! The slices: the runs in job order ([`crate::bench::run_ids`]: suite, robot, method, episode)
//! are numbered from 0, and run `i` belongs to shard `i mod N + 1` (K counts from 1, as
//! `1/4` … `4/4`). Interleaving spreads every suite, robot and method over all shards, so the
//! shards take about the same time.
//!
//! A shard folder holds `results.csv` (its runs, as a full run writes them), the same rows
//! with every number exact (`results-exact.csv`, [`crate::report::results_csv_exact`]: the
//! merged report is computed from the numbers one run would have had, not from six-decimal
//! roundings) and `shard.json` ([`ShardManifest`]): the shard spec, the settings that must
//! agree between shards (the effective configuration, every option that changes results, a
//! fingerprint of the runs), what the merge needs to set the benchmark up again, and the
//! shard's timing.
//!
//! A shard run with `--record` also holds `record/`, the MCAP file of each of its runs
//! ([`crate::record::run_file`]); the merge gathers them into its own `record/` under the same
//! names, as one run with `--record` lays them out ([`gather_recordings`]). Shards that recorded
//! and shards that did not are not merged.

use crate::bench::ResultRow;
use crate::error::SimError;
use crate::report;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// The file of a shard folder that describes it.
pub const MANIFEST_FILE: &str = "shard.json";
/// The file of a shard folder with its rows, every number exact.
pub const EXACT_CSV_FILE: &str = "results-exact.csv";
/// The folder of a shard's (and a run's) recordings, under its output folder.
pub const RECORD_DIR: &str = "record";
/// The version of [`ShardManifest`]'s layout (2: its settings say whether the shard recorded
/// its runs).
pub const MANIFEST_FORMAT: u32 = 2;

/// A short fingerprint of `data` (text or a file's bytes) for [`ShardManifest::settings`]: its length and its 64-bit
/// FNV-1a hash (stable across platforms and releases), as `"<len> bytes, <hex>"`.
pub fn fingerprint(data: impl AsRef<[u8]>) -> String {
    let data = data.as_ref();
    let hash = human2nav_core::input::fnv1a64(data);
    format!("{} bytes, {hash:016x}", data.len())
}

/// `K/N`: the K-th (from 1) of N slices of a benchmark's runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ShardSpec {
    /// K, from 1 to `count`.
    pub index: usize,
    /// N, at least 1.
    pub count: usize,
}

impl ShardSpec {
    /// Whether run `i` (from 0, in job order) belongs to this shard: `i mod N == K − 1`.
    pub fn holds(&self, i: usize) -> bool {
        i % self.count == self.index - 1
    }

    /// How many of `total` runs this shard holds.
    pub fn runs_of(&self, total: usize) -> usize {
        (total + self.count - self.index) / self.count
    }
}

impl std::fmt::Display for ShardSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for ShardSpec {
    type Err = String;

    /// `K/N` with whole numbers `1 ≤ K ≤ N`; the error says what is wrong.
    fn from_str(s: &str) -> Result<Self, String> {
        let form = "a shard is K/N, the K-th of N slices with 1 ≤ K ≤ N (such as 2/8)";
        let Some((k, n)) = s.split_once('/') else {
            return Err(format!("`{s}`: {form}"));
        };
        let number = |t: &str, what: &str| {
            t.trim()
                .parse::<usize>()
                .map_err(|_| format!("`{s}`: {what} `{}` is not a whole number; {form}", t.trim()))
        };
        let (index, count) = (number(k, "K")?, number(n, "N")?);
        if count == 0 {
            return Err(format!("`{s}`: N must be at least 1; {form}"));
        }
        if index == 0 {
            return Err(format!(
                "`{s}`: K counts from 1 (1/{count} to {count}/{count})"
            ));
        }
        if index > count {
            return Err(format!(
                "`{s}`: K is larger than N (the shards are 1/{count} to {count}/{count})"
            ));
        }
        Ok(Self { index, count })
    }
}

/// `shard.json`: what a shard is, what it ran with and how long it took.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardManifest {
    /// [`MANIFEST_FORMAT`] of the program that wrote it.
    pub format: u32,
    /// The shard, `K/N`.
    pub shard: String,
    /// The runs of the whole benchmark.
    pub total_runs: usize,
    /// The runs of this shard (its rows).
    pub runs: usize,
    /// Everything that must be the same in every shard of a merge, by name: the effective
    /// configuration, the options that change results, a fingerprint of the runs.
    pub settings: BTreeMap<String, Value>,
    /// What the merge needs besides (taken from the first shard): the configuration file as it
    /// was named, say.
    pub context: BTreeMap<String, Value>,
    /// Wall time of the shard's runs (s).
    pub wall_time: f64,
    /// `(method, runs, thread-seconds)` of the shard.
    pub method_times: Vec<(String, usize, f64)>,
}

impl ShardManifest {
    /// The shard spec of [`ShardManifest::shard`].
    pub fn spec(&self) -> Result<ShardSpec, String> {
        self.shard.parse()
    }

    /// Whether the shard recorded its runs (`bench --record`; the setting `record`).
    pub fn recorded(&self) -> bool {
        self.settings
            .get("record")
            .and_then(Value::as_bool)
            .unwrap_or(false)
    }
}

/// Writes a shard folder: `results.csv`, [`EXACT_CSV_FILE`] and [`MANIFEST_FILE`] (created when
/// missing). Returns the paths written.
pub fn write_shard(
    dir: &Path,
    manifest: &ShardManifest,
    rows: &[ResultRow],
) -> Result<Vec<PathBuf>, SimError> {
    std::fs::create_dir_all(dir).map_err(|e| SimError::io(dir, e))?;
    let json = serde_json::to_string_pretty(manifest).map_err(|e| SimError::Parse {
        path: dir.join(MANIFEST_FILE),
        message: e.to_string(),
    })?;
    let files = [
        (dir.join("results.csv"), report::results_csv(rows)),
        (dir.join(EXACT_CSV_FILE), report::results_csv_exact(rows)),
        (dir.join(MANIFEST_FILE), json + "\n"),
    ];
    for (path, text) in &files {
        std::fs::write(path, text).map_err(|e| SimError::io(path, e))?;
    }
    Ok(files.into_iter().map(|(p, _)| p).collect())
}

/// A shard folder read back.
#[derive(Clone, Debug)]
pub struct Shard {
    /// The folder.
    pub dir: PathBuf,
    /// Its `shard.json`.
    pub manifest: ShardManifest,
    /// Its spec.
    pub spec: ShardSpec,
    /// Its rows in job order.
    pub rows: Vec<ResultRow>,
}

/// Reads a shard folder; errors name the file and what is wrong with it.
pub fn read_shard(dir: &Path) -> Result<Shard, SimError> {
    let path = dir.join(MANIFEST_FILE);
    if !path.is_file() {
        return Err(SimError::Shards(format!(
            "`{}` has no {MANIFEST_FILE}: not the output folder of `human2nav bench --shard K/N`",
            dir.display()
        )));
    }
    let parse = |path: &Path, message: String| SimError::Parse {
        path: path.to_path_buf(),
        message,
    };
    let text = human2nav_core::input::read_user_file(
        &path,
        "shard manifest",
        human2nav_core::input::MAX_CONFIG_BYTES,
    )
    .map_err(|e| SimError::io(&path, e))?;
    let manifest: ShardManifest =
        serde_json::from_str(&text).map_err(|e| parse(&path, e.to_string()))?;
    if manifest.format != MANIFEST_FORMAT {
        return Err(parse(
            &path,
            format!(
                "`format` is {}; this program reads shards of format {MANIFEST_FORMAT} (run every \
                 shard and the merge with the same version)",
                manifest.format
            ),
        ));
    }
    let spec = manifest
        .spec()
        .map_err(|e| parse(&path, format!("`shard`: {e}")))?;
    let csv = dir.join(EXACT_CSV_FILE);
    let text = std::fs::read_to_string(&csv).map_err(|e| SimError::io(&csv, e))?;
    let rows = report::parse_results_csv(&text, &csv.display().to_string())?;
    if rows.len() != manifest.runs || manifest.runs != spec.runs_of(manifest.total_runs) {
        return Err(parse(
            &csv,
            format!(
                "{} rows, but {MANIFEST_FILE} says {} of {} runs, and shard {spec} of them has {} \
                 (an interrupted or edited shard: run it again)",
                rows.len(),
                manifest.runs,
                manifest.total_runs,
                spec.runs_of(manifest.total_runs)
            ),
        ));
    }
    Ok(Shard {
        dir: dir.to_path_buf(),
        manifest,
        spec,
        rows,
    })
}

/// The first place where two settings maps differ, as `key: <a> against <b>` (`key.sub` inside
/// a table, `key[3]` inside a list); `None` when they agree.
pub fn settings_difference(
    a: &BTreeMap<String, Value>,
    b: &BTreeMap<String, Value>,
) -> Option<String> {
    let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
    keys.sort();
    keys.dedup();
    keys.into_iter()
        .find_map(|k| value_difference(k, a.get(k), b.get(k)))
}

fn value_difference(at: &str, a: Option<&Value>, b: Option<&Value>) -> Option<String> {
    let show = |v: Option<&Value>| match v {
        None => "(absent)".to_string(),
        Some(v) => {
            let s = v.to_string();
            if s.chars().count() > 80 {
                format!("{}…", s.chars().take(80).collect::<String>())
            } else {
                s
            }
        }
    };
    match (a, b) {
        (Some(Value::Object(x)), Some(Value::Object(y))) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter()
                .find_map(|k| value_difference(&format!("{at}.{k}"), x.get(k), y.get(k)))
        }
        (Some(Value::Array(x)), Some(Value::Array(y))) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(i, (p, q))| value_difference(&format!("{at}[{i}]"), Some(p), Some(q))),
        _ if a == b => None,
        _ => Some(format!("`{at}`: {} against {}", show(a), show(b))),
    }
}

/// The shards of one benchmark joined: their rows in job order.
#[derive(Clone, Debug)]
pub struct MergedShards {
    /// Every run's row, in job order, as one run would have them.
    pub rows: Vec<ResultRow>,
    /// The shards, in order 1/N to N/N.
    pub shards: Vec<Shard>,
}

impl MergedShards {
    /// The settings every shard agrees on.
    pub fn settings(&self) -> &BTreeMap<String, Value> {
        &self.shards[0].manifest.settings
    }

    /// The first shard's context ([`ShardManifest::context`]).
    pub fn context(&self) -> &BTreeMap<String, Value> {
        &self.shards[0].manifest.context
    }

    /// The shards' wall times summed (s).
    pub fn wall_time(&self) -> f64 {
        self.shards.iter().map(|s| s.manifest.wall_time).sum()
    }

    /// The shards' `(method, runs, thread-seconds)` summed, in the first shard's method order.
    pub fn method_times(&self) -> Vec<(String, usize, f64)> {
        let mut times = self.shards[0].manifest.method_times.clone();
        for shard in &self.shards[1..] {
            for (m, runs, secs) in &shard.manifest.method_times {
                match times.iter_mut().find(|(n, ..)| n == m) {
                    Some(t) => {
                        t.1 += runs;
                        t.2 += secs;
                    }
                    None => times.push((m.clone(), *runs, *secs)),
                }
            }
        }
        times
    }
}

/// Reads the shard folders `dirs` and joins them: refused, naming the folders, when one is not
/// a shard, when they are slices of different splits or benchmarks (naming the first setting
/// that differs), when a shard is given twice or one is missing (naming which).
pub fn merge_shards(dirs: &[PathBuf]) -> Result<MergedShards, SimError> {
    if dirs.is_empty() {
        return Err(SimError::Shards(
            "--merge needs the shard folders to join".into(),
        ));
    }
    let shards = dirs
        .iter()
        .map(|d| read_shard(d))
        .collect::<Result<Vec<_>, _>>()?;
    let first = &shards[0];
    for s in &shards[1..] {
        if s.spec.count != first.spec.count {
            return Err(SimError::Shards(format!(
                "`{}` is shard {} and `{}` is shard {}: slices of different splits",
                first.dir.display(),
                first.spec,
                s.dir.display(),
                s.spec
            )));
        }
        if s.manifest.recorded() != first.manifest.recorded() {
            let (with, without) = if first.manifest.recorded() {
                (first, s)
            } else {
                (s, first)
            };
            return Err(SimError::Shards(format!(
                "`{}` ran with --record and `{}` without: a merge gathers the recordings of \
                 every shard or of none (run shard {} again with --record, or shard {} without)",
                with.dir.display(),
                without.dir.display(),
                without.spec,
                with.spec
            )));
        }
        if let Some(diff) = settings_difference(&first.manifest.settings, &s.manifest.settings) {
            return Err(SimError::Shards(format!(
                "shards of different benchmarks: {diff} (`{}` against `{}`)",
                first.dir.display(),
                s.dir.display()
            )));
        }
        if s.manifest.total_runs != first.manifest.total_runs {
            return Err(SimError::Shards(format!(
                "shards of different benchmarks: `total_runs`: {} against {} (`{}` against `{}`)",
                first.manifest.total_runs,
                s.manifest.total_runs,
                first.dir.display(),
                s.dir.display()
            )));
        }
    }
    let count = first.spec.count;
    let mut by_index: Vec<Option<Shard>> = vec![None; count];
    for s in shards {
        let slot = &mut by_index[s.spec.index - 1];
        if let Some(other) = slot {
            return Err(SimError::Shards(format!(
                "shard {} given twice: `{}` and `{}`",
                s.spec,
                other.dir.display(),
                s.dir.display()
            )));
        }
        *slot = Some(s);
    }
    let missing: Vec<String> = by_index
        .iter()
        .enumerate()
        .filter(|(_, s)| s.is_none())
        .map(|(k, _)| format!("{}/{count}", k + 1))
        .collect();
    if !missing.is_empty() {
        return Err(SimError::Shards(format!(
            "missing shard{} {} (a merge needs all {count})",
            if missing.len() > 1 { "s" } else { "" },
            missing.join(", ")
        )));
    }
    let shards: Vec<Shard> = by_index.into_iter().flatten().collect();
    let total = shards[0].manifest.total_runs;
    let mut rows = Vec::with_capacity(total);
    let mut next = vec![0usize; count];
    for i in 0..total {
        let k = i % count;
        rows.push(shards[k].rows[next[k]].clone());
        next[k] += 1;
    }
    Ok(MergedShards { rows, shards })
}

/// Gathers the recordings of merged shards that ran with `--record` into `into` (the merge's
/// `record/` folder): each run's file, at [`crate::record::run_file`] under each shard's
/// [`RECORD_DIR`], to the same name under `into`, hard-linked where the shard lies on the same
/// file system and copied otherwise (the shards keep theirs). Every file is checked to be there
/// before one is gathered; a missing one is named with its shard. Returns how many were
/// gathered (0 for shards that did not record).
pub fn gather_recordings(merged: &MergedShards, into: &Path) -> Result<usize, SimError> {
    let mut files = Vec::new();
    for shard in merged.shards.iter().filter(|s| s.manifest.recorded()) {
        for row in &shard.rows {
            let name = crate::record::run_file(row);
            let from = shard.dir.join(RECORD_DIR).join(&name);
            if !from.is_file() {
                return Err(SimError::Shards(format!(
                    "shard {} (`{}`) ran with --record, but its recording `{}` of run {} / {} \
                     / {} / {} is missing (an interrupted shard or a moved file: run the shard \
                     again)",
                    shard.spec,
                    shard.dir.display(),
                    from.display(),
                    row.suite,
                    row.robot,
                    row.method,
                    row.episode
                )));
            }
            files.push((from, into.join(name)));
        }
    }
    for (from, to) in &files {
        if let Some(dir) = to.parent() {
            std::fs::create_dir_all(dir).map_err(|e| SimError::io(dir, e))?;
        }
        if to.exists() {
            // The merge written into a shard's own folder: the file is already in place.
            if from.canonicalize().ok() == to.canonicalize().ok() {
                continue;
            }
            std::fs::remove_file(to).map_err(|e| SimError::io(to, e))?;
        }
        if std::fs::hard_link(from, to).is_err() {
            std::fs::copy(from, to).map_err(|e| SimError::io(to, e))?;
        }
    }
    Ok(files.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_and_bad_ones_say_why() {
        let ok = |s: &str| s.parse::<ShardSpec>().map_err(|e| e.to_string());
        assert_eq!(ok("2/8"), Ok(ShardSpec { index: 2, count: 8 }));
        assert_eq!(ok("1/1"), Ok(ShardSpec { index: 1, count: 1 }));
        let err = |s: &str| s.parse::<ShardSpec>().unwrap_err();
        assert!(err("3/2").contains("K is larger than N"), "{}", err("3/2"));
        assert!(
            err("0/0").contains("N must be at least 1"),
            "{}",
            err("0/0")
        );
        assert!(
            err("1/0").contains("N must be at least 1"),
            "{}",
            err("1/0")
        );
        assert!(err("0/4").contains("K counts from 1"), "{}", err("0/4"));
        assert!(err("a/4").contains("K `a` is not a whole number"));
        assert!(err("1/-4").contains("N `-4` is not a whole number"));
        assert!(err("3").contains("a shard is K/N"));
        assert!(err("").contains("a shard is K/N"));
    }

    #[test]
    fn every_run_is_in_exactly_one_shard_and_runs_of_counts_them() {
        for count in 1..7 {
            for total in 0..20 {
                let mut seen = vec![0; total];
                for index in 1..=count {
                    let spec = ShardSpec { index, count };
                    let held: Vec<usize> = (0..total).filter(|&i| spec.holds(i)).collect();
                    assert_eq!(held.len(), spec.runs_of(total), "{spec} of {total}");
                    for i in held {
                        seen[i] += 1;
                    }
                }
                assert!(seen.iter().all(|&n| n == 1), "{count} shards of {total}");
            }
        }
    }

    #[test]
    fn the_first_differing_setting_is_named_with_its_path() {
        let map =
            |v: Value| -> BTreeMap<String, Value> { serde_json::from_value(v).expect("an object") };
        let a = map(serde_json::json!({
            "seed": 7, "config": {"sim": {"dt": 0.05, "replan_hz": 10.0}, "robots": ["a", "b"]}
        }));
        assert_eq!(settings_difference(&a, &a.clone()), None);
        let mut b = a.clone();
        b.insert("seed".into(), Value::from(8));
        assert_eq!(
            settings_difference(&a, &b).as_deref(),
            Some("`seed`: 7 against 8")
        );
        let b = map(serde_json::json!({
            "seed": 7, "config": {"sim": {"dt": 0.1, "replan_hz": 10.0}, "robots": ["a", "b"]}
        }));
        assert_eq!(
            settings_difference(&a, &b).as_deref(),
            Some("`config.sim.dt`: 0.05 against 0.1")
        );
        let b = map(serde_json::json!({
            "seed": 7, "config": {"sim": {"dt": 0.05, "replan_hz": 10.0}, "robots": ["a", "c"]}
        }));
        assert_eq!(
            settings_difference(&a, &b).as_deref(),
            Some("`config.robots[1]`: \"b\" against \"c\"")
        );
        let mut b = a.clone();
        b.remove("seed");
        assert_eq!(
            settings_difference(&a, &b).as_deref(),
            Some("`seed`: 7 against (absent)")
        );
    }
}
