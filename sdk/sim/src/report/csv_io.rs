//! `results.csv` written (six decimals, or every number exact for the shards) and read back
//! into rows.

use crate::bench::{ResultRow, SuiteKind};
use crate::episode::ScenarioClass;
use crate::error::SimError;
use crate::metrics::{EpisodeMetrics, HumanComparison, LimitCounts};
use crate::runner::{Contact, Outcome};
use std::collections::HashMap;

/// The header of `results.csv`.
pub const CSV_HEADER: &str = "suite,suite_kind,scenario,episode,scene,robot,method,seed,agents,density,outcome,\
success,collision,timeout,tfs,tfs_plan,tfs_executed,path_length,time_to_goal,duration,budget,min_clearance,\
time_within_0_45,time_within_1_2,mean_jerk,plans,fallbacks,planner_errors,contact_robot_closing,\
contact_pedestrian_closing,contact_pedestrian_age,contact_pedestrian_speed,commands,exec_over_speed,exec_over_reverse,\
exec_over_acceleration,exec_over_yaw_rate,exec_over_curvature,exec_over_lateral,exec_over_coupled,\
end_goal_distance,end_goal_crowd,human_distance,human_length_ratio";

/// A number of `results.csv`: six decimals, empty when not finite.
pub(super) fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.6}")
    } else {
        String::new()
    }
}

/// An optional number of `results.csv`: empty when `None`.
#[cfg(test)]
pub(super) fn opt(v: Option<f64>) -> String {
    v.map(num).unwrap_or_default()
}

/// A number written so that reading it back gives the same `f64` (the shortest such form;
/// `NaN`, `inf` and `-inf` for the others): [`results_csv_exact`].
fn exact(v: f64) -> String {
    format!("{v:?}")
}

/// The fields of one `results.csv` line, in [`CSV_HEADER`]'s order, numbers written by `num`.
fn csv_record(r: &ResultRow, num: fn(f64) -> String) -> Vec<String> {
    let opt = |v: Option<f64>| v.map(num).unwrap_or_default();
    let m = &r.metrics;
    [
        r.suite.clone(),
        r.suite_kind.as_str().to_string(),
        r.scenario.name().to_string(),
        r.episode.clone(),
        r.scene.clone(),
        r.robot.clone(),
        r.method.clone(),
        r.seed.to_string(),
        r.agents.to_string(),
        r.density.to_string(),
        m.outcome.as_str().to_string(),
        u8::from(m.success).to_string(),
        u8::from(m.collision).to_string(),
        u8::from(m.timeout).to_string(),
        num(m.tfs),
        num(m.tfs_plan),
        num(m.tfs_executed),
        num(m.path_length),
        opt(m.time_to_goal),
        num(m.duration),
        num(m.budget),
        opt(m.min_clearance),
        num(m.time_within_intimate),
        num(m.time_within_personal),
        num(m.mean_jerk),
        m.plans.to_string(),
        m.fallbacks.to_string(),
        m.planner_errors.to_string(),
        opt(m.contact.map(|c| c.robot_closing)),
        opt(m.contact.map(|c| c.pedestrian_closing)),
        opt(m.contact.map(|c| c.pedestrian_age)),
        opt(m.contact.map(|c| c.pedestrian_speed)),
        m.executed_violations.commands.to_string(),
    ]
    .into_iter()
    .chain(
        m.executed_violations
            .per_limit()
            .iter()
            .map(|c| c.to_string()),
    )
    .chain([
        num(m.end_goal_distance),
        opt(m.end_goal_crowd),
        opt(m.human.map(|h| h.distance)),
        opt(m.human.map(|h| h.length_ratio)),
    ])
    .collect()
}

/// `results.csv` (header plus one line per row, `\n` line ends, six decimals). A field is
/// quoted only when it contains `,`, `"`, `\r` or `\n`, with its quotes doubled (the `csv`
/// crate's default writer).
pub fn results_csv(rows: &[ResultRow]) -> String {
    write_csv(rows, num)
}

/// `results.csv` with every number written exactly (the shortest decimal form that reads back
/// as the same `f64`, `NaN` and `inf` included) instead of with six decimals: what a shard of
/// `human2nav bench --shard` keeps besides its `results.csv`, so that the merged report is
/// computed from the very numbers one run would have had. [`parse_results_csv`] reads it back
/// into the same rows, except for what `results.csv` has no column for (see there).
pub fn results_csv_exact(rows: &[ResultRow]) -> String {
    write_csv(rows, exact)
}

fn write_csv(rows: &[ResultRow], num: fn(f64) -> String) -> String {
    let mut w = csv::Writer::from_writer(Vec::with_capacity(256 * (rows.len() + 1)));
    // Only an I/O error (there is none: the writer is a Vec) or a record whose length differs
    // from the header's (there is none: `csv_record` has one field per header column, as the
    // tests check) can fail.
    const INFALLIBLE: &str = "results.csv records match the header and are written to memory";
    w.write_record(CSV_HEADER.split(',')).expect(INFALLIBLE);
    for r in rows {
        w.write_record(csv_record(r, num)).expect(INFALLIBLE);
    }
    let bytes = w.into_inner().expect(INFALLIBLE);
    String::from_utf8(bytes).expect("CSV made of UTF-8 fields is UTF-8")
}

/// Reads the rows of a `results.csv` ([`results_csv`] or [`results_csv_exact`]) back; `source`
/// names the file in errors. Columns are found by name, in any order; every column of
/// [`CSV_HEADER`] must be there and no other. An error names the line and the column: a
/// missing or unknown column, a field that is not a number, a count or a flag (0 or 1), an
/// unknown suite kind, scenario class or outcome, a line with too few or too many fields.
///
/// What reads back: `parse_results_csv(results_csv_exact(rows)) == rows` for every row;
/// `parse_results_csv(results_csv(rows)) == rows` when every number has at most six decimals
/// and is finite (an empty number field reads as `NaN`, an empty optional one as `None`).
/// Two things `results.csv` has no column for read back as their defaults: the id of the
/// pedestrian a collision was with (`contact.pedestrian`, 0) and the obstacle hit
/// (`obstacle_hit`, `None`); nothing in the report or the figures uses them. A collision's
/// contact is `Some` when any of its four `contact_*` fields is set.
pub fn parse_results_csv(text: &str, source: &str) -> Result<Vec<ResultRow>, SimError> {
    let error = |message: String| SimError::Parse {
        path: source.into(),
        message,
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .from_reader(text.as_bytes());
    let header = reader
        .headers()
        .map_err(|e| error(format!("its header: {e}")))?
        .clone();
    let known: Vec<&str> = CSV_HEADER.split(',').collect();
    let mut at: HashMap<&str, usize> = HashMap::new();
    for (i, name) in header.iter().enumerate() {
        if !known.contains(&name) {
            return Err(error(format!(
                "line 1: unknown column `{name}` (results.csv of this version has {})",
                known.len()
            )));
        }
        if at.insert(name, i).is_some() {
            return Err(error(format!("line 1: column `{name}` appears twice")));
        }
    }
    if let Some(missing) = known.iter().find(|k| !at.contains_key(*k)) {
        return Err(error(format!("line 1: no `{missing}` column")));
    }
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| error(e.to_string()))?;
        let line = record.position().map_or(0, |p| p.line());
        if record.len() != header.len() {
            return Err(error(format!(
                "line {line}: {} fields, the header has {}",
                record.len(),
                header.len()
            )));
        }
        let fields = Fields {
            record: &record,
            at: &at,
            line,
        };
        rows.push(fields.row().map_err(error)?);
    }
    Ok(rows)
}

/// One line of a `results.csv` being read: its fields by column name.
struct Fields<'a> {
    record: &'a csv::StringRecord,
    at: &'a HashMap<&'a str, usize>,
    line: u64,
}

impl Fields<'_> {
    fn text(&self, column: &str) -> &str {
        // Every column of CSV_HEADER is in `at` (checked on the header) and every record has
        // the header's length (checked per line); a name outside CSV_HEADER is a bug here.
        self.at
            .get(column)
            .and_then(|&i| self.record.get(i))
            .unwrap_or_else(|| panic!("results.csv reader asks for `{column}`, not a column"))
    }

    fn bad(&self, column: &str, what: &str) -> String {
        format!(
            "line {}, column `{column}`: `{}` is not {what}",
            self.line,
            self.text(column)
        )
    }

    fn string(&self, column: &str) -> String {
        self.text(column).to_string()
    }

    fn number(&self, column: &str) -> Result<f64, String> {
        match self.text(column) {
            "" => Ok(f64::NAN),
            t => t.parse().map_err(|_| self.bad(column, "a number")),
        }
    }

    fn optional(&self, column: &str) -> Result<Option<f64>, String> {
        match self.text(column) {
            "" => Ok(None),
            _ => self.number(column).map(Some),
        }
    }

    fn count<T: std::str::FromStr>(&self, column: &str) -> Result<T, String> {
        self.text(column)
            .parse()
            .map_err(|_| self.bad(column, "a whole number"))
    }

    fn flag(&self, column: &str) -> Result<bool, String> {
        match self.text(column) {
            "0" => Ok(false),
            "1" => Ok(true),
            _ => Err(self.bad(column, "0 or 1")),
        }
    }

    fn named<T: Copy>(
        &self,
        column: &str,
        all: &[T],
        name: impl Fn(T) -> &'static str,
    ) -> Result<T, String> {
        let t = self.text(column);
        all.iter().copied().find(|&v| name(v) == t).ok_or_else(|| {
            let names: Vec<&str> = all.iter().map(|&v| name(v)).collect();
            self.bad(column, &format!("one of {}", names.join(", ")))
        })
    }

    /// The row of this line: one field per column of [`CSV_HEADER`], as [`csv_record`]
    /// writes them.
    fn row(&self) -> Result<ResultRow, String> {
        let contact = [
            "contact_robot_closing",
            "contact_pedestrian_closing",
            "contact_pedestrian_age",
            "contact_pedestrian_speed",
        ];
        let contact = if contact.iter().all(|c| self.text(c).is_empty()) {
            None
        } else {
            Some(Contact {
                pedestrian: 0,
                robot_closing: self.number(contact[0])?,
                pedestrian_closing: self.number(contact[1])?,
                pedestrian_age: self.number(contact[2])?,
                pedestrian_speed: self.number(contact[3])?,
            })
        };
        let mut per_limit = [0usize; LimitCounts::NAMES.len()];
        for (slot, name) in per_limit.iter_mut().zip(LimitCounts::NAMES) {
            *slot = self.count(&format!("exec_over_{name}"))?;
        }
        let executed_violations = LimitCounts::from_per_limit(self.count("commands")?, per_limit);
        let outcomes = [Outcome::Success, Outcome::Collision, Outcome::Timeout];
        let kinds = [
            SuiteKind::Real,
            SuiteKind::Synthetic,
            SuiteKind::Empty,
            SuiteKind::Corridor,
        ];
        Ok(ResultRow {
            suite: self.string("suite"),
            suite_kind: self.named("suite_kind", &kinds, SuiteKind::as_str)?,
            scenario: self.named("scenario", &ScenarioClass::ALL, ScenarioClass::name)?,
            episode: self.string("episode"),
            scene: self.string("scene"),
            robot: self.string("robot"),
            method: self.string("method"),
            seed: self.count("seed")?,
            agents: self.count("agents")?,
            density: self.count("density")?,
            metrics: EpisodeMetrics {
                outcome: self.named("outcome", &outcomes, Outcome::as_str)?,
                success: self.flag("success")?,
                collision: self.flag("collision")?,
                timeout: self.flag("timeout")?,
                tfs: self.number("tfs")?,
                tfs_plan: self.number("tfs_plan")?,
                tfs_executed: self.number("tfs_executed")?,
                path_length: self.number("path_length")?,
                time_to_goal: self.optional("time_to_goal")?,
                duration: self.number("duration")?,
                budget: self.number("budget")?,
                min_clearance: self.optional("min_clearance")?,
                time_within_intimate: self.number("time_within_0_45")?,
                time_within_personal: self.number("time_within_1_2")?,
                mean_jerk: self.number("mean_jerk")?,
                plans: self.count("plans")?,
                fallbacks: self.count("fallbacks")?,
                planner_errors: self.count("planner_errors")?,
                contact,
                obstacle_hit: None,
                executed_violations,
                end_goal_distance: self.number("end_goal_distance")?,
                end_goal_crowd: self.optional("end_goal_crowd")?,
                human: match (
                    self.optional("human_distance")?,
                    self.optional("human_length_ratio")?,
                ) {
                    (None, None) => None,
                    (Some(distance), Some(length_ratio)) => Some(HumanComparison {
                        distance,
                        length_ratio,
                    }),
                    _ => {
                        return Err(format!(
                            "line {}: `human_distance` and `human_length_ratio` are both \
                             set or both empty",
                            self.line
                        ));
                    }
                },
            },
        })
    }
}
