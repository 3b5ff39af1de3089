//! The report's paired comparisons of every method with the reference method (exact McNemar
//! test, bootstrap interval of the SR difference).

use super::{ReportContext, p_value, pct};
use crate::bench::ResultRow;
use crate::episode::{ScenarioClass, ScenarioTitle};
use crate::stats::{self, BOOTSTRAP_RESAMPLES, PairedComparison};
use std::fmt::Write as _;

/// `Δ [lo, hi]` in percentage points.
fn difference_cell(d: &PairedComparison) -> String {
    format!(
        "{:+.1} [{:+.1}, {:+.1}]",
        100.0 * d.difference,
        100.0 * d.ci.0,
        100.0 * d.ci.1
    )
}

fn paired_row(md: &mut String, lead: &str, pairs: &[(bool, bool)]) {
    match PairedComparison::of(pairs) {
        Some(d) => {
            let _ = writeln!(
                md,
                "| {lead} | {} | {} | {} | {} | {} | {} | {} |",
                d.n,
                pct(d.sr_reference),
                pct(d.sr_other),
                difference_cell(&d),
                d.b,
                d.c,
                p_value(d.p_value)
            );
        }
        None => {
            let _ = writeln!(md, "| {lead} | 0 | – | – | – | – | – | – |");
        }
    }
}

/// Every method against the reference on the same (episode, robot) pairs: pooled over the
/// robots per class and overall, then per robot.
pub(super) fn paired_section(
    md: &mut String,
    rows: &[&ResultRow],
    ctx: &ReportContext,
    methods: &[String],
) {
    let Some(reference) = ctx.reference() else {
        return;
    };
    let _ = writeln!(
        md,
        "\n### Paired comparison with `{reference}` (exact McNemar test, 95 % bootstrap interval)\n"
    );
    let others: Vec<&String> = methods.iter().filter(|m| *m != reference).collect();
    if others.is_empty() {
        let _ = writeln!(md, "Only `{reference}` ran: nothing to compare.");
        return;
    }
    if !rows.iter().any(|r| r.method == reference) {
        let _ = writeln!(
            md,
            "`{reference}` has no runs in this suite: no paired comparison."
        );
        return;
    }
    let _ = writeln!(
        md,
        "A pair is one (episode, robot) that both `{reference}` and the other method ran; the \
         runs of a pair face the same crowd, so the methods are compared on the pairs where they \
         differ. n = pairs; b = pairs only `{reference}` succeeded on; c = pairs only the other \
         method succeeded on; ΔSR = SR(`{reference}`) − SR(method) = (b − c)/n in percentage \
         points (positive: `{reference}` did better), with the 95 % percentile interval of \
         {BOOTSTRAP_RESAMPLES} paired bootstrap resamples of the pairs (fixed seed). p is the \
         exact two-sided McNemar test: under equal success probabilities each of the b + c \
         discordant pairs goes either way with probability 1/2, p = min(1, 2·P(X ≤ min(b, c))) \
         for X ~ Binomial(b + c, 1/2), and p = 1 when b + c = 0. A small p with b > c says \
         `{reference}` succeeds where the method fails more often than the reverse. The tests \
         are not corrected for multiple comparisons.\n"
    );
    let header = format!(
        "| n | SR `{reference}` (%) | SR method (%) | ΔSR (pp) [95 % CI] | b | c | McNemar p |"
    );
    let _ = writeln!(
        md,
        "Pooled over the robots:\n\n| method | scenario {header}\n|---|---|---|---|---|---|---|---|---|"
    );
    for m in &others {
        for c in ScenarioClass::ALL.into_iter().map(Some).chain([None]) {
            let pairs = stats::success_pairs(
                rows.iter()
                    .copied()
                    .filter(|r| c.is_none_or(|c| r.scenario == c)),
                reference,
                m,
            );
            let name = c.map_or("all", |c| c.title());
            paired_row(md, &format!("{m} | {name}"), &pairs);
        }
    }
    let _ = writeln!(
        md,
        "\nPer robot, all scenarios:\n\n| robot | method {header}\n|---|---|---|---|---|---|---|---|---|"
    );
    for robot in &ctx.robot_names {
        for m in &others {
            let pairs = stats::success_pairs(
                rows.iter().copied().filter(|r| &r.robot == robot),
                reference,
                m,
            );
            paired_row(md, &format!("{robot} | {m}"), &pairs);
        }
    }
}
