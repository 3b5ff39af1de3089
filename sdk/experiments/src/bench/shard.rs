//! `human2nav bench --shard K/N` and `human2nav bench --merge DIR...` on a [`Bench`]: a shard
//! runs its slice of the runs and writes its folder ([`human2nav_sim::shard`]); a merge reads
//! the folders, sets the benchmark up again from what they recorded, checks that it is the
//! benchmark they ran, and writes the `results.csv`, report and figures of the whole run (the
//! figures that show runs re-run them, as one run does), gathering the shards' recordings when
//! they ran with `--record`.

use super::{Bench, BenchRequest};
use anyhow::{Context, bail};
use human2nav_sim::ResultRow;
use human2nav_sim::bench::{MethodTimes, RunId, run_ids};
use human2nav_sim::driver::{self, BenchOutcome, Merged};
use human2nav_sim::report::PlannerFailures;
use human2nav_sim::shard::{
    self, MANIFEST_FORMAT, ShardManifest, ShardSpec, fingerprint, merge_shards, settings_difference,
};
use indicatif::ProgressBar;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What a shard produced.
#[derive(Debug)]
pub struct ShardOutcome {
    /// The shard.
    pub spec: ShardSpec,
    /// Its rows, in job order.
    pub rows: Vec<ResultRow>,
    /// The runs of the whole benchmark.
    pub total_runs: usize,
    /// The files written (`results.csv`, `results-exact.csv`, `shard.json`).
    pub files: Vec<PathBuf>,
    /// Wall time of the shard's runs (s).
    pub wall_time: f64,
    /// Thread time per method.
    pub times: MethodTimes,
    /// `(method, robot, SR)` on the shard's empty-world runs, where SR < 1.
    pub empty_world_failures: Vec<(String, String, f64)>,
    /// Every (method, robot) with failed planner calls in the shard.
    pub planner_failures: Vec<PlannerFailures>,
}

impl ShardOutcome {
    /// True when no planner call failed and every empty-world run of the shard succeeded.
    pub fn passed(&self) -> bool {
        self.empty_world_failures.is_empty() && self.planner_failures.is_empty()
    }
}

/// A fingerprint of the files a method reads, so that shards run with a different planner
/// file or model are not merged: every string of its `config` table (and of a TOML file it
/// names, one level down) that names a file or folder under `base` (a folder: the files in it,
/// two levels deep). Names that are no file are skipped (the configuration itself is compared
/// as well). A plugin's library is left out: each machine of a cluster may build its own.
fn method_files(method: &human2nav_sim::config::MethodConfig, base: &Path) -> String {
    fn strings(value: &toml::Value, out: &mut Vec<String>) {
        match value {
            toml::Value::String(s) => out.push(s.clone()),
            toml::Value::Array(a) => a.iter().for_each(|v| strings(v, out)),
            toml::Value::Table(t) => t.values().for_each(|v| strings(v, out)),
            _ => {}
        }
    }
    fn add(path: &Path, depth: usize, seen: &mut BTreeMap<PathBuf, String>) {
        if seen.contains_key(path) {
            return;
        }
        if path.is_dir() && depth < 2 {
            let Ok(entries) = std::fs::read_dir(path) else {
                return;
            };
            let mut children: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
            children.sort();
            for c in children {
                add(&c, depth + 1, seen);
            }
        } else if let Ok(bytes) = std::fs::read(path) {
            seen.insert(path.to_path_buf(), fingerprint(&bytes));
        }
    }
    let mut seen = BTreeMap::new();
    let mut names = Vec::new();
    strings(&toml::Value::Table(method.config.clone()), &mut names);
    for name in names {
        let path = base.join(&name);
        if path.extension().is_some_and(|e| e == "toml") {
            let nested = std::fs::read_to_string(&path)
                .ok()
                .and_then(|t| t.parse::<toml::Table>().ok());
            if let Some(table) = nested {
                let mut inner = Vec::new();
                strings(&toml::Value::Table(table), &mut inner);
                for n in inner {
                    let p = base.join(n);
                    if p.exists() {
                        add(&p, 0, &mut seen);
                    }
                }
            }
        }
        if path.exists() {
            add(&path, 0, &mut seen);
        }
    }
    let listing: Vec<String> = seen
        .iter()
        .map(|(p, f)| {
            let shown = p.strip_prefix(base).unwrap_or(p);
            format!("{}: {f}", shown.display())
        })
        .collect();
    fingerprint(listing.join("\n"))
}

/// A JSON value that has been through its text form, as a value read from `shard.json` has:
/// compared with one read back, a value made in memory could differ in a float's last bit.
fn as_read_back(v: Value) -> Value {
    serde_json::from_str(&v.to_string()).unwrap_or(v)
}

impl Bench {
    /// What must be the same in every shard of a merge and in the merge itself: the program's
    /// version, the configuration as loaded (its `base` files merged, the seed override
    /// applied), the options that change results or figures, and fingerprints of each suite's
    /// episodes, each robot's setup and the list of runs.
    pub fn shard_settings(&self) -> anyhow::Result<BTreeMap<String, Value>> {
        let r = &self.request;
        let mut episodes = serde_json::Map::new();
        for s in &self.suites {
            let text = serde_json::to_string(&s.episodes)?;
            episodes.insert(
                s.name.clone(),
                Value::from(format!(
                    "{} episodes, {}",
                    s.episodes.len(),
                    fingerprint(&text)
                )),
            );
        }
        let mut robots = serde_json::Map::new();
        for robot in &self.robots {
            let text = format!(
                "{} {:?} {:?} {:?} {:?}",
                robot.embodiment.name(),
                robot.footprint_radius,
                robot.footprint,
                robot.limits,
                robot.gains
            );
            robots.insert(robot.name.clone(), Value::from(fingerprint(&text)));
        }
        let runs: Vec<String> = run_ids(&self.suites, &self.robots, &self.methods)
            .iter()
            .map(|id| {
                format!(
                    "{}\u{1f}{}\u{1f}{}\u{1f}{}",
                    id.suite, id.robot, id.method, id.episode
                )
            })
            .collect();
        let method_files = self
            .cfg
            .methods
            .iter()
            .map(|m| {
                (
                    m.name.clone(),
                    Value::from(method_files(m, &self.cfg.base_dir)),
                )
            })
            .collect();
        let settings = [
            ("version", Value::from(env!("CARGO_PKG_VERSION"))),
            ("config", serde_json::to_value(&self.cfg)?),
            ("quick", Value::from(r.quick)),
            ("seed", serde_json::to_value(r.seed)?),
            ("methods", serde_json::to_value(&r.methods)?),
            ("robots", serde_json::to_value(&r.robots)?),
            ("suites", serde_json::to_value(&r.suites)?),
            ("failures", serde_json::to_value(r.failures)?),
            ("record", Value::from(r.record)),
            ("episodes", Value::Object(episodes)),
            ("robot_setups", Value::Object(robots)),
            ("method_files", Value::Object(method_files)),
            (
                "runs",
                Value::from(format!(
                    "{} runs, {}",
                    runs.len(),
                    fingerprint(runs.join("\n"))
                )),
            ),
        ];
        Ok(settings
            .into_iter()
            .map(|(k, v)| (k.to_string(), as_read_back(v)))
            .collect())
    }

    /// Runs the slice of `request.shard` (advancing `progress`, whose length it sets) and
    /// writes the shard folder: `results.csv` of its runs, `results-exact.csv` and `shard.json`.
    /// Errors when the request names no shard.
    pub fn run_shard(&self, progress: &ProgressBar) -> anyhow::Result<ShardOutcome> {
        let Some(spec) = self.request.shard else {
            bail!("run_shard: the request names no shard (--shard K/N)");
        };
        let settings = self.shard_settings()?;
        let total_runs = run_ids(&self.suites, &self.robots, &self.methods).len();
        let started = Instant::now();
        let plan = self.plan();
        let (rows, times) = driver::run_shard(&plan, spec, progress)?;
        let wall_time = started.elapsed().as_secs_f64();
        let context = [
            (
                "config_file",
                Value::from(self.request.config.display().to_string()),
            ),
            (
                "data_config",
                Value::from(self.request.data_config.display().to_string()),
            ),
        ];
        let manifest = ShardManifest {
            format: MANIFEST_FORMAT,
            shard: spec.to_string(),
            total_runs,
            runs: rows.len(),
            settings,
            context: context
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
            wall_time,
            method_times: times.per_method.clone(),
        };
        let files = shard::write_shard(&self.out, &manifest, &rows)?;
        let method_names: Vec<String> = self.methods.iter().map(|m| m.name.clone()).collect();
        let robot_names: Vec<String> = self.robots.iter().map(|r| r.name.clone()).collect();
        Ok(ShardOutcome {
            spec,
            empty_world_failures: driver::empty_world_failures(
                &plan,
                &rows,
                &method_names,
                &robot_names,
            ),
            planner_failures: human2nav_sim::report::planner_failures(&rows),
            rows,
            total_runs,
            files,
            wall_time,
            times,
        })
    }

    /// Joins the shard folders `dirs` into the output of one run: `results.csv` (byte for byte
    /// what one run writes), `report.md` (the same but for its wall-time line, which sums the
    /// shards') and the figures, in `out` (default: the output folder one run of the shards'
    /// options uses) with `threads` workers for the figures' runs. The benchmark is set up
    /// again from the configuration file the shards name (`config`, when given, instead) and
    /// must be the one they ran: a difference is named. `log` hears what the set-up says.
    pub fn merge(
        dirs: &[PathBuf],
        config: Option<&Path>,
        out: Option<PathBuf>,
        threads: Option<usize>,
        log: &dyn Fn(String),
    ) -> anyhow::Result<BenchOutcome> {
        let merged = merge_shards(dirs)?;
        let settings = merged.settings();
        let context = merged.context();
        let text = |map: &BTreeMap<String, Value>, key: &str| -> anyhow::Result<String> {
            map.get(key)
                .and_then(Value::as_str)
                .map(str::to_string)
                .with_context(|| {
                    format!(
                        "{}: no `{key}` text in shard.json",
                        merged.shards[0].dir.display()
                    )
                })
        };
        let json = |key: &str| settings.get(key).cloned().unwrap_or(Value::Null);
        let field = |key: &str| {
            format!(
                "{}/shard.json: `settings.{key}`",
                merged.shards[0].dir.display()
            )
        };
        let request = BenchRequest {
            config: match config {
                Some(c) => c.to_path_buf(),
                None => PathBuf::from(text(context, "config_file")?),
            },
            out,
            quick: serde_json::from_value(json("quick")).with_context(|| field("quick"))?,
            seed: serde_json::from_value(json("seed")).with_context(|| field("seed"))?,
            threads,
            data_config: PathBuf::from(text(context, "data_config")?),
            failures: serde_json::from_value(json("failures"))
                .with_context(|| field("failures"))?,
            methods: serde_json::from_value(json("methods")).with_context(|| field("methods"))?,
            robots: serde_json::from_value(json("robots")).with_context(|| field("robots"))?,
            suites: serde_json::from_value(json("suites")).with_context(|| field("suites"))?,
            shard: None,
            record: merged.shards[0].manifest.recorded(),
        };
        let bench = Bench::prepare(&request, log)?;
        if let Some(diff) = settings_difference(settings, &bench.shard_settings()?) {
            bail!(
                "the benchmark set up from {} is not the one the shards ran: {diff} (the shards' \
                 value first; did the configuration, an episode file or a robot profile change \
                 since?)",
                request.config.display()
            );
        }
        let ids = run_ids(&bench.suites, &bench.robots, &bench.methods);
        for (i, (id, row)) in ids.iter().zip(&merged.rows).enumerate() {
            if *id != RunId::of(row) {
                bail!(
                    "run {i} should be {id} but shard {}/{} holds {} (`{}`)",
                    i % merged.shards.len() + 1,
                    merged.shards.len(),
                    RunId::of(row),
                    merged.shards[i % merged.shards.len()].dir.display()
                );
            }
        }
        log(format!(
            "{} runs from {} shards; writing results.csv, the figures (re-running the runs they \
             draw) and report.md into {}",
            merged.rows.len(),
            merged.shards.len(),
            bench.out.display()
        ));
        let recordings = shard::gather_recordings(&merged, &bench.out.join(shard::RECORD_DIR))?;
        if recordings > 0 {
            log(format!(
                "gathered the {recordings} recordings of the shards into {}",
                bench.out.join(shard::RECORD_DIR).display()
            ));
        }
        let times = MethodTimes {
            per_method: merged.method_times(),
        };
        let info = Merged {
            shards: merged.shards.len(),
            wall_time: merged.wall_time(),
        };
        Ok(driver::write_outputs(
            &bench.plan(),
            merged.rows,
            times,
            info,
            &bench.out,
            Instant::now(),
        )?)
    }
}

#[cfg(test)]
mod tests {
    use super::method_files;
    use human2nav_sim::config::MethodConfig;

    #[test]
    fn the_files_a_method_names_are_fingerprinted_one_level_down() {
        let dir = std::env::temp_dir().join(format!("h2n-method-files-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("models/m")).expect("a temporary folder");
        let write = |path: &str, text: &str| std::fs::write(dir.join(path), text).expect("written");
        write(
            "planner.toml",
            "model = \"models/m\"\n[human2nav]\nsamples = 4\n",
        );
        write("models/m/model.toml", "horizon = 32\n");
        write("models/m/weights.bin", "0123");
        let method: MethodConfig = toml::from_str(
            "name = \"h\"\nkind = \"human2nav\"\n\
             config = { planner = \"planner.toml\", note = \"not a file\" }\n",
        )
        .expect("a method");
        let before = method_files(&method, &dir);
        assert_eq!(before, method_files(&method, &dir), "deterministic");
        // The model's weights, named only inside the planner file, count.
        write("models/m/weights.bin", "0124");
        let weights = method_files(&method, &dir);
        assert_ne!(weights, before);
        // So does the planner file itself.
        write(
            "planner.toml",
            "model = \"models/m\"\n[human2nav]\nsamples = 8\n",
        );
        assert_ne!(method_files(&method, &dir), weights);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
