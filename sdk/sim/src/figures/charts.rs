//! The benchmark's charts of one suite: SR per scenario (Fig. 6), TFS and SR per robot
//! (Fig. 7) and SR against crowd density.

use super::{
    CHART_SIZE, ChartText, DESC_PX, FONT, Interval, Mark, Scale, TICK_PX, TWO_PANEL_SIZE,
    category_labels, colour, draw_err, draw_legend, grouped_bars, method_legend, methods_present,
    split_legend, sr_interval, text_err, tfs_interval, titled, whisker,
};
use crate::bench::ResultRow;
use crate::episode::{ScenarioClass, ScenarioTitle};
use crate::error::SimError;
use crate::stats::{self, DENSITY_BINS};
use plotters::prelude::*;
use std::path::Path;

/// Fig. 6: success rate per scenario class (x) and method (bars), over every robot of `suite`,
/// with 95 % Wilson intervals. Methods without rows in the suite are left out.
pub fn sr_per_scenario(
    path: &Path,
    rows: &[ResultRow],
    suite: &str,
    methods: &[String],
) -> Result<(), SimError> {
    let err = draw_err(path);
    let in_suite: Vec<&ResultRow> = rows.iter().filter(|r| r.suite == suite).collect();
    let present = methods_present(&in_suite, methods);
    let legend = method_legend(&present, Mark::Bar);
    let root = BitMapBackend::new(path, CHART_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (plot, strip) = split_legend(&root, &legend);
    let groups: Vec<String> = ScenarioClass::ALL
        .iter()
        .map(|c| c.title().to_string())
        .collect();
    let colours: Vec<RGBColor> = present.iter().map(|(i, _)| colour(*i)).collect();
    let value = |gi: usize, si: usize| {
        sr_interval(
            in_suite
                .iter()
                .copied()
                .filter(|r| r.scenario == ScenarioClass::ALL[gi] && &r.method == present[si].1),
        )
    };
    grouped_bars(
        &plot,
        &ChartText {
            title: &format!("Success rate per scenario — suite {suite}, all robots"),
            x_desc: "scenario class",
            y_desc: "success rate (%)",
        },
        Scale::Percent,
        &groups,
        &colours,
        &value,
    )
    .map_err(&err)?;
    draw_legend(&strip, &legend).map_err(&err)?;
    root.present().map_err(|e| err(e.to_string()))
}

/// Fig. 7: TFS (left, ±1.96 standard errors) and SR (right, 95 % Wilson intervals) per robot
/// (x) and method (bars) on `suite`. Methods without rows in the suite are left out.
pub fn tfs_sr_per_robot(
    path: &Path,
    rows: &[ResultRow],
    suite: &str,
    robots: &[String],
    methods: &[String],
) -> Result<(), SimError> {
    let err = draw_err(path);
    let in_suite: Vec<&ResultRow> = rows.iter().filter(|r| r.suite == suite).collect();
    let present = methods_present(&in_suite, methods);
    let legend = method_legend(&present, Mark::Bar);
    let root = BitMapBackend::new(path, TWO_PANEL_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (plot, strip) = split_legend(&root, &legend);
    let panels = plot.split_evenly((1, 2));
    let colours: Vec<RGBColor> = present.iter().map(|(i, _)| colour(*i)).collect();
    let present = &present;
    let in_suite = &in_suite;
    let pick = |gi: usize, si: usize| {
        in_suite
            .iter()
            .copied()
            .filter(move |r| r.robot == robots[gi] && &r.method == present[si].1)
    };
    let tfs = |gi: usize, si: usize| tfs_interval(pick(gi, si));
    let sr = |gi: usize, si: usize| sr_interval(pick(gi, si));
    grouped_bars(
        &panels[0],
        &ChartText {
            title: &format!("Trajectory feasibility score — suite {suite}"),
            x_desc: "robot",
            y_desc: "TFS (mean over episodes)",
        },
        Scale::Unit,
        robots,
        &colours,
        &tfs,
    )
    .map_err(&err)?;
    grouped_bars(
        &panels[1],
        &ChartText {
            title: &format!("Success rate — suite {suite}"),
            x_desc: "robot",
            y_desc: "success rate (%)",
        },
        Scale::Percent,
        robots,
        &colours,
        &sr,
    )
    .map_err(&err)?;
    draw_legend(&strip, &legend).map_err(&err)?;
    root.present().map_err(|e| err(e.to_string()))
}

/// SR against crowd density on `suite`, all robots and scenarios: the occupied
/// [`DENSITY_BINS`] along x (with their episode counts), one line per method through its SR in
/// each bin, 95 % Wilson intervals as whiskers (the methods' points are spread a little
/// sideways so that the whiskers do not hide each other). Methods without rows in the suite
/// are left out.
pub fn sr_per_density(
    path: &Path,
    rows: &[ResultRow],
    suite: &str,
    methods: &[String],
) -> Result<(), SimError> {
    let err = draw_err(path);
    let in_suite: Vec<&ResultRow> = rows.iter().filter(|r| r.suite == suite).collect();
    let present = methods_present(&in_suite, methods);
    let legend = method_legend(&present, Mark::LinePoint);
    let bins = stats::occupied_bins(in_suite.iter().map(|r| r.density));
    let root = BitMapBackend::new(path, CHART_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (plot, strip) = split_legend(&root, &legend);
    let draw = || -> Result<(), String> {
        let n = bins.len().max(1) as f64;
        let plot = titled(
            &plot,
            &format!("Success rate against crowd density — suite {suite}"),
        )?;
        let mut chart = ChartBuilder::on(&plot)
            .margin(16)
            .margin_right(30)
            .x_label_area_size(2 * TICK_PX + DESC_PX + 40)
            .y_label_area_size(3 * TICK_PX + DESC_PX)
            .build_cartesian_2d(0f64..n, 0f64..100f64)
            .map_err(text_err)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_labels(6)
            .y_label_formatter(&|v| format!("{v:.0}"))
            .label_style((FONT, TICK_PX))
            .axis_desc_style((FONT, DESC_PX))
            .x_desc("crowd density (relevant pedestrians per episode), all robots and scenarios")
            .y_desc("success rate (%)")
            .light_line_style(WHITE)
            .bold_line_style(RGBColor(225, 225, 225))
            .draw()
            .map_err(text_err)?;
        let k = present.len().max(1) as f64;
        let spread = (0.5 / k).min(0.08);
        for (si, (mi, m)) in present.iter().enumerate() {
            let c = colour(*mi);
            let dx = (si as f64 - 0.5 * (k - 1.0)) * spread;
            let points: Vec<(f64, Interval)> =
                bins.iter()
                    .enumerate()
                    .filter_map(|(gi, &b)| {
                        let v =
                            sr_interval(in_suite.iter().copied().filter(|r| {
                                &r.method == *m && DENSITY_BINS[b].contains(r.density)
                            }))?;
                        Some((gi as f64 + 0.5 + dx, v))
                    })
                    .collect();
            chart
                .draw_series(std::iter::once(PathElement::new(
                    points
                        .iter()
                        .map(|(x, v)| (*x, 100.0 * v.value))
                        .collect::<Vec<_>>(),
                    c.stroke_width(3),
                )))
                .map_err(text_err)?;
            for (x, v) in &points {
                chart
                    .draw_series(whisker(
                        *x,
                        100.0 * v.lo,
                        100.0 * v.hi,
                        0.35 * spread,
                        c.stroke_width(2),
                    ))
                    .map_err(text_err)?;
            }
            // The markers on the whole chart area, so that one at 100 % is not cut in half by
            // the plotting area.
            let (bx, by) = plot.get_base_pixel();
            for (x, v) in &points {
                let (px, py) = chart.backend_coord(&(*x, 100.0 * v.value));
                plot.draw(&Circle::new((px - bx, py - by), 7, c.filled()))
                    .map_err(text_err)?;
            }
        }
        let labels: Vec<(String, Option<String>)> = bins
            .iter()
            .map(|&b| {
                let mut ids: Vec<&str> = in_suite
                    .iter()
                    .filter(|r| DENSITY_BINS[b].contains(r.density))
                    .map(|r| r.episode.as_str())
                    .collect();
                ids.sort_unstable();
                ids.dedup();
                (
                    DENSITY_BINS[b].label(),
                    Some(format!("{} episodes", ids.len())),
                )
            })
            .collect();
        category_labels(&plot, &chart, &labels)
    };
    draw().map_err(&err)?;
    draw_legend(&strip, &legend).map_err(&err)?;
    root.present().map_err(|e| err(e.to_string()))
}
