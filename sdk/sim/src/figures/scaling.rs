//! The data-scaling curve (Fig. 5): SR against the hours of training data.

use super::{
    CHART_SIZE, DESC_PX, FONT, Mark, TICK_PX, colour, draw_err, draw_legend, faint, split_legend,
    text_err, titled,
};
use crate::bench::ResultRow;
use crate::episode::{ScenarioClass, ScenarioTitle};
use crate::error::SimError;
use crate::report::summarize;
use plotters::prelude::*;
use std::path::Path;

/// One point of the data-scaling curve (paper Fig. 5): the SR of a model trained on
/// training data of `hours`, for one scenario class or (`None`) over all classes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScalingPoint {
    /// Recorded human data the model was trained on (hours: the recorded time of its training
    /// scenes), the x-axis of Fig. 5 as in the paper.
    pub hours: f64,
    /// The scenario class, `None` for all classes together.
    pub scenario: Option<ScenarioClass>,
    /// Success rate.
    pub sr: f64,
    /// Standard error of `sr` (drawn as shading around the all-class curve).
    pub sr_se: f64,
}

/// The scaling points of one method on one suite from benchmark rows of several trainings,
/// each given as `(hours of recorded training data, rows)`: per class and over all classes.
pub fn scaling_points(
    runs: &[(f64, Vec<ResultRow>)],
    suite: &str,
    method: &str,
) -> Vec<ScalingPoint> {
    let mut out = Vec::new();
    for (hours, rows) in runs {
        let pick = |c: Option<ScenarioClass>| {
            summarize(rows.iter().filter(|r| {
                r.suite == suite && r.method == method && c.is_none_or(|c| r.scenario == c)
            }))
        };
        for c in ScenarioClass::ALL.into_iter().map(Some).chain([None]) {
            let s = pick(c);
            if s.n > 0 {
                out.push(ScalingPoint {
                    hours: *hours,
                    scenario: c,
                    sr: s.sr,
                    sr_se: s.sr_se,
                });
            }
        }
    }
    out
}

/// Fig. 5: SR against the share of training data, one faint line per scenario class and the
/// all-class curve in bold with ±1 standard error shading.
pub fn sr_vs_training_data(
    path: &Path,
    points: &[ScalingPoint],
    title: &str,
) -> Result<(), SimError> {
    let err = draw_err(path);
    let mut legend: Vec<(String, Mark)> = ScenarioClass::ALL
        .into_iter()
        .enumerate()
        .map(|(i, c)| (c.title().to_string(), Mark::Line(faint(colour(i), 0.55), 3)))
        .collect();
    legend.push(("all scenarios (±1 SE shaded)".into(), Mark::Line(BLACK, 5)));
    let root = BitMapBackend::new(path, CHART_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (plot, strip) = split_legend(&root, &legend);
    let most = points.iter().map(|p| p.hours).fold(0.0, f64::max);
    let x_max = if most > 0.0 { 1.05 * most } else { 1.0 };
    let draw = || -> Result<(), String> {
        let plot = titled(&plot, title)?;
        let mut chart = ChartBuilder::on(&plot)
            .margin(16)
            .margin_right(30)
            .x_label_area_size(TICK_PX + DESC_PX + 30)
            .y_label_area_size(3 * TICK_PX + DESC_PX)
            .build_cartesian_2d(0f64..x_max, 0f64..100f64)
            .map_err(text_err)?;
        chart
            .configure_mesh()
            .x_desc("recorded human data used for training (hours)")
            .y_desc("success rate (%)")
            .y_labels(6)
            .y_label_formatter(&|v| format!("{v:.0}"))
            .x_label_formatter(&|v| format!("{v:.1}"))
            .label_style((FONT, TICK_PX))
            .axis_desc_style((FONT, DESC_PX))
            .light_line_style(WHITE)
            .bold_line_style(RGBColor(225, 225, 225))
            .draw()
            .map_err(text_err)?;
        let curve = |c: Option<ScenarioClass>| {
            let mut v: Vec<ScalingPoint> =
                points.iter().filter(|p| p.scenario == c).copied().collect();
            v.sort_by(|a, b| a.hours.total_cmp(&b.hours));
            v
        };
        for (i, c) in ScenarioClass::ALL.into_iter().enumerate() {
            let v = curve(Some(c));
            chart
                .draw_series(std::iter::once(PathElement::new(
                    v.iter()
                        .map(|p| (p.hours, 100.0 * p.sr))
                        .collect::<Vec<_>>(),
                    faint(colour(i), 0.55).stroke_width(3),
                )))
                .map_err(text_err)?;
        }
        let all = curve(None);
        if !all.is_empty() {
            let mut band: Vec<(f64, f64)> = all
                .iter()
                .map(|p| (p.hours, 100.0 * (p.sr + p.sr_se).min(1.0)))
                .collect();
            band.extend(
                all.iter()
                    .rev()
                    .map(|p| (p.hours, 100.0 * (p.sr - p.sr_se).max(0.0))),
            );
            chart
                .draw_series(std::iter::once(Polygon::new(
                    band,
                    colour(0).mix(0.15).filled(),
                )))
                .map_err(text_err)?;
            chart
                .draw_series(std::iter::once(PathElement::new(
                    all.iter()
                        .map(|p| (p.hours, 100.0 * p.sr))
                        .collect::<Vec<_>>(),
                    BLACK.stroke_width(5),
                )))
                .map_err(text_err)?;
            chart
                .draw_series(
                    all.iter()
                        .map(|p| Circle::new((p.hours, 100.0 * p.sr), 6, BLACK.filled())),
                )
                .map_err(text_err)?;
        }
        Ok(())
    };
    draw().map_err(&err)?;
    draw_legend(&strip, &legend).map_err(&err)?;
    root.present().map_err(|e| err(e.to_string()))
}
