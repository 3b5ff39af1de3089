//! `human2nav compare`: a method of one benchmark run against a method of another, paired run
//! by run ([`human2nav_sim::compare`]): the way a setting is judged against the shipped
//! planner on the same episodes.

use anyhow::{Context, bail};
use clap::Args;
use human2nav_sim::compare;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `human2nav compare`.
#[derive(Debug, Args)]
pub struct CompareArgs {
    /// The baseline: a `results.csv` of `human2nav bench` and a method in it, `FILE:METHOD`
    /// (`FILE` alone when it holds one method).
    baseline: String,
    /// The candidate, given the same way.
    candidate: String,
    /// Also write the table to this file (Markdown).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// A `FILE:METHOD` argument: the file, and the method (`None`: not given).
fn split(arg: &str) -> (PathBuf, Option<String>) {
    if Path::new(arg).is_file() {
        return (PathBuf::from(arg), None);
    }
    match arg.rsplit_once(':') {
        Some((file, method)) if !method.is_empty() => (PathBuf::from(file), Some(method.into())),
        _ => (PathBuf::from(arg), None),
    }
}

/// The outcomes of the method `arg` names, and a label for it.
fn side(arg: &str, role: &str) -> anyhow::Result<(compare::Outcomes, String)> {
    let (file, method) = split(arg);
    if !file.is_file() {
        bail!(
            "the {role} `{}` is not a file (give FILE:METHOD)",
            file.display()
        );
    }
    let results = compare::read_results(&file)?;
    let method = match (method, results.keys().next()) {
        (Some(m), _) => m,
        (None, Some(only)) if results.len() == 1 => only.clone(),
        (None, _) => bail!(
            "the {role} `{}` holds the methods {}: name one as FILE:METHOD",
            file.display(),
            results.keys().cloned().collect::<Vec<_>>().join(", ")
        ),
    };
    let outcomes = compare::method_outcomes(results, &method, &file)?;
    Ok((outcomes, format!("{}:{method}", file.display())))
}

/// Runs `human2nav compare`.
pub fn run(args: CompareArgs) -> anyhow::Result<ExitCode> {
    let (baseline, baseline_label) = side(&args.baseline, "baseline")?;
    let (candidate, candidate_label) = side(&args.candidate, "candidate")?;
    let Some(comparison) = compare::compare(&baseline, &candidate) else {
        bail!(
            "`{baseline_label}` and `{candidate_label}` share no run (same suite, scenario, \
             episode, robot and seed)"
        );
    };
    let table = compare::markdown(&comparison, &baseline_label, &candidate_label);
    print!("{table}");
    if let Some(out) = &args.out {
        std::fs::write(out, &table).with_context(|| format!("writing {}", out.display()))?;
        eprintln!("table: {}", out.display());
    }
    Ok(ExitCode::SUCCESS)
}
