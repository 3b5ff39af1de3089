//! PNG figures drawn with plotters: SR per scenario and method (paper Fig. 6), TFS and SR per
//! robot and method (Fig. 7), SR against crowd density, trajectory snapshots (Fig. 4) and the
//! data-scaling curve (Fig. 5).
//!
//! The charts are drawn to be printed: the y axis spans exactly 0–100 % (SR) or 0–1 (TFS),
//! both axes are described, the legend sits below the plotting area, and the fonts are read
//! at 100 % zoom. SR bars and points carry 95 % Wilson score intervals ([`sr_interval`]), TFS
//! bars ±1.96 standard errors of the mean of the per-episode TFS ([`tfs_interval`]).

use crate::bench::ResultRow;
use crate::episode::{Episode, ScenarioClass, ScenarioTitle};
use crate::error::SimError;
use crate::plan_figure::draw_bev_raster;
use crate::replay::CrowdReplay;
use crate::report::summarize;
use crate::runner::{EpisodeRun, PlanSample};
use crate::stats::{self, DENSITY_BINS, Z95};
use human2nav_core::bev::BevSpec;
use human2nav_core::obstacle::Obstacle;
use human2nav_core::robot::footprint::FootprintShape;
use human2nav_core::{AgentState, Pose2};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
/// A chart in metres on a bitmap.
type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Method colours, in method order (colour-blind-safe Tableau-like palette).
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

const FONT: &str = "sans-serif";
/// Font sizes (px) of the charts: title, axis descriptions, tick and group labels, legend.
const TITLE_PX: u32 = 30;
const DESC_PX: u32 = 26;
const TICK_PX: u32 = 22;
const LEGEND_PX: u32 = 24;
/// Chart size (px): one panel, and a chart of two panels side by side.
const CHART_SIZE: (u32, u32) = (1400, 820);
const TWO_PANEL_SIZE: (u32, u32) = (2000, 820);

fn draw_err(file: &Path) -> impl Fn(String) -> SimError + '_ {
    move |message| SimError::Figure {
        file: file.to_path_buf(),
        message,
    }
}

fn text_err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// A value and its interval, all in `[0, 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interval {
    /// The estimate.
    pub value: f64,
    /// Lower end of the interval.
    pub lo: f64,
    /// Upper end of the interval.
    pub hi: f64,
}

/// The SR of `rows` with its 95 % Wilson score interval (`None` without rows).
pub fn sr_interval<'a>(rows: impl IntoIterator<Item = &'a ResultRow>) -> Option<Interval> {
    let (k, n) = rows.into_iter().fold((0, 0), |(k, n), r| {
        (k + usize::from(r.metrics.success), n + 1)
    });
    let (lo, hi) = stats::wilson_interval(k, n, Z95)?;
    Some(Interval {
        value: k as f64 / n as f64,
        lo,
        hi,
    })
}

/// The mean TFS of `rows` ± 1.96 standard errors of the mean, clipped to `[0, 1]` (`None`
/// without rows).
pub fn tfs_interval<'a>(rows: impl IntoIterator<Item = &'a ResultRow>) -> Option<Interval> {
    let v: Vec<f64> = rows.into_iter().map(|r| r.metrics.tfs).collect();
    let (mean, half) = stats::mean_with_error(&v, Z95)?;
    Some(Interval {
        value: mean,
        lo: (mean - half).max(0.0),
        hi: (mean + half).min(1.0),
    })
}

/// What a legend entry shows next to its label.
#[derive(Clone, Copy, Debug)]
enum Mark {
    /// A filled box (a bar, a footprint).
    Bar(RGBColor),
    /// A line of the given width.
    Line(RGBColor, u32),
    /// A line through a dot (a curve with markers).
    LinePoint(RGBColor),
    /// A circle outline.
    Ring(RGBColor),
    /// A filled star.
    Star(RGBColor),
    /// A grey disc with history dots and a velocity arrow.
    Pedestrian,
}

/// Legend geometry (px): the mark's width, the gap between entries, a row's height.
const MARK_W: i32 = 46;
const ENTRY_GAP: i32 = 44;
const LEGEND_ROW: i32 = 40;

fn legend_font() -> FontDesc<'static> {
    (FONT, LEGEND_PX).into_font()
}

/// The entries of each legend row, with their widths, for a strip `width` px wide.
fn legend_rows(entries: &[(String, Mark)], width: i32) -> Vec<Vec<(usize, i32)>> {
    let font = legend_font();
    let mut rows: Vec<Vec<(usize, i32)>> = vec![Vec::new()];
    let mut used = 0;
    for (i, (text, _)) in entries.iter().enumerate() {
        let text_w = font
            .box_size(text)
            .map_or(text.chars().count() as i32 * LEGEND_PX as i32 / 2, |s| {
                s.0 as i32
            });
        let w = MARK_W + 10 + text_w;
        let row = rows.last_mut().expect("one row");
        if row.is_empty() {
            used = w;
        } else if used + ENTRY_GAP + w > width - 2 * ENTRY_GAP {
            rows.push(Vec::new());
            used = w;
        } else {
            used += ENTRY_GAP + w;
        }
        rows.last_mut().expect("one row").push((i, w));
    }
    rows
}

/// Height (px) of the legend strip of `entries` at `width` px.
fn legend_height(entries: &[(String, Mark)], width: u32) -> u32 {
    legend_rows(entries, width as i32).len() as u32 * LEGEND_ROW as u32 + 20
}

/// Splits `root` into the chart area and the legend strip below it.
fn split_legend<'a>(root: &Area<'a>, entries: &[(String, Mark)]) -> (Area<'a>, Area<'a>) {
    let (w, h) = root.dim_in_pixel();
    root.split_vertically(h.saturating_sub(legend_height(entries, w)))
}

fn draw_mark(area: &Area<'_>, mark: Mark, x: i32, y: i32) -> Result<(), String> {
    match mark {
        Mark::Bar(c) => area.draw(&Rectangle::new(
            [(x + 6, y - 11), (x + MARK_W - 6, y + 11)],
            c.filled(),
        )),
        Mark::Line(c, w) => area.draw(&PathElement::new(
            vec![(x, y), (x + MARK_W, y)],
            c.stroke_width(w),
        )),
        Mark::LinePoint(c) => {
            area.draw(&PathElement::new(
                vec![(x, y), (x + MARK_W, y)],
                c.stroke_width(3),
            ))
            .map_err(text_err)?;
            area.draw(&Circle::new((x + MARK_W / 2, y), 7, c.filled()))
        }
        Mark::Ring(c) => area.draw(&Circle::new((x + MARK_W / 2, y), 11, c.stroke_width(2))),
        Mark::Star(c) => area.draw(&Polygon::new(
            star([f64::from(x + MARK_W / 2), f64::from(y)], 13.0)
                .into_iter()
                .map(|(a, b)| (a.round() as i32, (2.0 * f64::from(y) - b).round() as i32))
                .collect::<Vec<_>>(),
            c.filled(),
        )),
        Mark::Pedestrian => {
            for k in 0..3 {
                area.draw(&Circle::new((x + 3 + 6 * k, y), 2, GREY.mix(0.6).filled()))
                    .map_err(text_err)?;
            }
            let c = (x + 26, y);
            area.draw(&Circle::new(c, 9, GREY.mix(0.6).filled()))
                .map_err(text_err)?;
            area.draw(&PathElement::new(
                vec![c, (x + MARK_W - 2, y)],
                ARROW_GREY.stroke_width(2),
            ))
        }
    }
    .map_err(text_err)
}

/// Draws the legend rows centred in `area`.
fn draw_legend(area: &Area<'_>, entries: &[(String, Mark)]) -> Result<(), String> {
    let (w, _) = area.dim_in_pixel();
    let font = legend_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    for (ri, row) in legend_rows(entries, w as i32).iter().enumerate() {
        let total: i32 = row.iter().map(|e| e.1).sum::<i32>() + ENTRY_GAP * (row.len() as i32 - 1);
        let mut x = (w as i32 - total) / 2;
        let y = 10 + ri as i32 * LEGEND_ROW + LEGEND_ROW / 2;
        for &(i, ew) in row {
            let (label, mark) = &entries[i];
            draw_mark(area, *mark, x, y)?;
            area.draw(&Text::new(
                label.clone(),
                (x + MARK_W + 10, y),
                font.clone(),
            ))
            .map_err(text_err)?;
            x += ew + ENTRY_GAP;
        }
    }
    Ok(())
}

/// How values in `[0, 1]` are shown on the y axis.
#[derive(Clone, Copy, Debug)]
enum Scale {
    /// 0–100 (%).
    Percent,
    /// 0–1.
    Unit,
}

impl Scale {
    fn factor(self) -> f64 {
        match self {
            Scale::Percent => 100.0,
            Scale::Unit => 1.0,
        }
    }

    fn label(self, v: f64) -> String {
        match self {
            Scale::Percent => format!("{v:.0}"),
            Scale::Unit => format!("{v:.1}"),
        }
    }
}

/// Draws `title` centred at the top of `area` and returns the area below it (plotters'
/// own caption leaves no room between the title and the top tick label).
fn titled<'a>(area: &Area<'a>, title: &str) -> Result<Area<'a>, String> {
    let (w, _) = area.dim_in_pixel();
    let (top, rest) = area.split_vertically(TITLE_PX + 30);
    top.draw(&Text::new(
        title.to_string(),
        (w as i32 / 2, 12),
        (FONT, TITLE_PX)
            .into_font()
            .color(&BLACK)
            .pos(Pos::new(HPos::Center, VPos::Top)),
    ))
    .map_err(text_err)?;
    Ok(rest)
}

/// The texts of a chart.
struct ChartText<'a> {
    title: &'a str,
    x_desc: &'a str,
    y_desc: &'a str,
}

/// Draws category labels (one or two lines) centred under `x = gi + 0.5` of `chart`.
fn category_labels(
    area: &Area<'_>,
    chart: &ChartContext<'_, BitMapBackend<'_>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    labels: &[(String, Option<String>)],
) -> Result<(), String> {
    let (bx, by) = area.get_base_pixel();
    for (gi, (label, second)) in labels.iter().enumerate() {
        // backend_coord is in whole-image pixels; the area draws relative to its own corner.
        let (px, py) = chart.backend_coord(&(gi as f64 + 0.5, 0.0));
        let style = |px_size: u32| {
            (FONT, px_size)
                .into_font()
                .color(&BLACK)
                .pos(Pos::new(HPos::Center, VPos::Top))
        };
        area.draw(&Text::new(
            label.clone(),
            (px - bx, py - by + 10),
            style(TICK_PX),
        ))
        .map_err(text_err)?;
        if let Some(second) = second {
            area.draw(&Text::new(
                second.clone(),
                (px - bx, py - by + 14 + TICK_PX as i32),
                style(TICK_PX - 4).color(&RGBColor(90, 90, 90)),
            ))
            .map_err(text_err)?;
        }
    }
    Ok(())
}

/// A vertical whisker from `lo` to `hi` at `x` with caps `cap` wide (chart units).
fn whisker(x: f64, lo: f64, hi: f64, cap: f64, style: ShapeStyle) -> [PathElement<(f64, f64)>; 3] {
    [
        PathElement::new(vec![(x, lo), (x, hi)], style),
        PathElement::new(vec![(x - cap, lo), (x + cap, lo)], style),
        PathElement::new(vec![(x - cap, hi), (x + cap, hi)], style),
    ]
}

/// One grouped bar chart: `groups` along x, one bar per series (colour) in each group, values
/// and whiskers from `value(group, series)`.
fn grouped_bars(
    area: &Area<'_>,
    text: &ChartText<'_>,
    scale: Scale,
    groups: &[String],
    series: &[RGBColor],
    value: &dyn Fn(usize, usize) -> Option<Interval>,
) -> Result<(), String> {
    let n = groups.len().max(1) as f64;
    let f = scale.factor();
    let area = &titled(area, text.title)?;
    let mut chart = ChartBuilder::on(area)
        .margin(16)
        .margin_right(30)
        .x_label_area_size(TICK_PX + DESC_PX + 36)
        .y_label_area_size(3 * TICK_PX + DESC_PX)
        .build_cartesian_2d(0f64..n, 0f64..f)
        .map_err(text_err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .y_labels(6)
        .y_label_formatter(&|v| scale.label(*v))
        .label_style((FONT, TICK_PX))
        .axis_desc_style((FONT, DESC_PX))
        .x_desc(text.x_desc)
        .y_desc(text.y_desc)
        .light_line_style(WHITE)
        .bold_line_style(RGBColor(225, 225, 225))
        .draw()
        .map_err(text_err)?;
    let k = series.len().max(1) as f64;
    let width = 0.8 / k;
    for (si, c) in series.iter().enumerate() {
        let cells: Vec<(f64, Interval)> = (0..groups.len())
            .filter_map(|gi| Some((gi as f64 + 0.1 + si as f64 * width, value(gi, si)?)))
            .collect();
        chart
            .draw_series(cells.iter().map(|(x0, v)| {
                Rectangle::new([(*x0, 0.0), (x0 + width * 0.9, f * v.value)], c.filled())
            }))
            .map_err(text_err)?;
        for (x0, v) in &cells {
            let xc = x0 + 0.45 * width;
            chart
                .draw_series(whisker(
                    xc,
                    f * v.lo,
                    f * v.hi,
                    (0.2 * width).min(0.04),
                    BLACK.stroke_width(2),
                ))
                .map_err(text_err)?;
        }
    }
    let labels: Vec<(String, Option<String>)> = groups.iter().map(|g| (g.clone(), None)).collect();
    category_labels(area, &chart, &labels)
}

/// The methods (index, name) that have rows in `rows`, in method order.
fn methods_present<'m>(rows: &[&ResultRow], methods: &'m [String]) -> Vec<(usize, &'m String)> {
    methods
        .iter()
        .enumerate()
        .filter(|(_, m)| rows.iter().any(|r| &r.method == *m))
        .collect()
}

fn method_legend(present: &[(usize, &String)], mark: fn(RGBColor) -> Mark) -> Vec<(String, Mark)> {
    present
        .iter()
        .map(|(i, m)| (m.to_string(), mark(colour(*i))))
        .collect()
}

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

/// One recorded episode to draw as a trajectory snapshot.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// The episode run.
    pub episode: Episode,
    /// What the run recorded (states, plans, outcome).
    pub run: EpisodeRun,
    /// Robot name, for the title.
    pub robot: String,
    /// Method name, for the title.
    pub method: String,
    /// The planners' covering disc (drawn as an outline, and the heading arrow's scale).
    pub footprint_radius: f64,
    /// The footprint collisions are checked with (drawn filled).
    pub footprint: Vec<FootprintShape>,
    /// The planner's BEV raster (the inset).
    pub bev: BevSpec,
    /// The planners observe pedestrians within this centre distance (m); the inset shows
    /// those.
    pub sensor_range: f64,
    /// Recorded positions per pedestrian the planners get (drawn as history dots).
    pub history_len: usize,
}

impl Snapshot {
    /// The instant drawn: when the robot was closest to a pedestrian, else mid-episode.
    pub fn time(&self) -> f64 {
        let best = self
            .run
            .clearance
            .iter()
            .enumerate()
            .filter(|(_, c)| c.is_finite())
            .min_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, _)| i as f64 * self.run.dt);
        best.unwrap_or(0.5 * self.run.end_time)
    }

    /// The plan the robot followed at `t`: the last one requested at or before it.
    pub fn plan_at(&self, t: f64) -> Option<&PlanSample> {
        self.run.plans.iter().rev().find(|p| p.t0 <= t + 1e-9)
    }

    /// The index of the recorded robot state at `t` (clamped to the run).
    pub fn state_index(&self, t: f64) -> usize {
        ((t / self.run.dt).round().max(0.0) as usize).min(self.run.states.len().saturating_sub(1))
    }
}

/// The pedestrians of `snap` present at `t`: position, velocity, radius and the last
/// [`Snapshot::history_len`] recorded positions, in the episode's track order. Every picture of
/// a snapshot (the discs, their history and arrows, the BEV inset) takes its pedestrians from
/// here: the episode's recording, or for a reactive run the crowd as it was simulated.
pub fn pedestrians_at(snap: &Snapshot, t: f64) -> Vec<AgentState> {
    let Some(states) = snap.run.crowd.as_ref() else {
        return CrowdReplay::new(&snap.episode).observe(
            t,
            [0.0, 0.0],
            f64::INFINITY,
            snap.history_len,
        );
    };
    // A reactive run recorded where everyone was at every step: history at the episode's
    // step, oldest first, ending at `t`.
    let n = snap.state_index(t).min(states.len().saturating_sub(1));
    let every = (snap.episode.dt / snap.run.dt).round().max(1.0) as usize;
    let Some(now) = states.get(n) else {
        return Vec::new();
    };
    now.iter()
        .map(|p| {
            let mut history: Vec<[f64; 2]> = (0..snap.history_len)
                .map_while(|k| n.checked_sub(k * every))
                .map_while(|m| states[m].iter().find(|q| q.id == p.id).map(|q| q.position))
                .collect();
            history.reverse();
            AgentState {
                id: p.id,
                position: p.position,
                velocity: p.velocity,
                radius: p.radius,
                history,
            }
        })
        .collect()
}

/// Colour of static obstacles in every picture.
pub const OBSTACLE: RGBColor = RGBColor(90, 90, 110);

/// Draws static obstacles on a chart: circles and polygons filled, segments as thick lines.
pub(crate) fn draw_obstacles<DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    obstacles: &[Obstacle],
) -> Result<(), String> {
    for o in obstacles {
        match o {
            Obstacle::Circle { center, radius } => chart
                .draw_series(std::iter::once(Polygon::new(
                    disc(*center, *radius),
                    OBSTACLE.mix(0.8).filled(),
                )))
                .map(|_| ()),
            Obstacle::Polygon { vertices } => chart
                .draw_series(std::iter::once(Polygon::new(
                    vertices.iter().map(|v| (v[0], v[1])).collect::<Vec<_>>(),
                    OBSTACLE.mix(0.8).filled(),
                )))
                .map(|_| ()),
            Obstacle::Segment { a, b } => chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(a[0], a[1]), (b[0], b[1])],
                    OBSTACLE.stroke_width(5),
                )))
                .map(|_| ()),
        }
        .map_err(text_err)?;
    }
    Ok(())
}

/// Polygon (24 vertices) of a disc of radius `r` around `c`.
pub fn disc(c: [f64; 2], r: f64) -> Vec<(f64, f64)> {
    (0..24)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / 24.0;
            (c[0] + r * a.cos(), c[1] + r * a.sin())
        })
        .collect()
}

/// The footprint's shapes placed at `pose`, as polygons in the world frame.
pub fn footprint_polygons(shapes: &[FootprintShape], pose: Pose2) -> Vec<Vec<(f64, f64)>> {
    let world = |p: [f64; 2]| {
        let q = pose.act(p);
        (q[0], q[1])
    };
    shapes
        .iter()
        .map(|s| match *s {
            FootprintShape::Disc { center, radius } => {
                let c = world(center);
                disc([c.0, c.1], radius)
            }
            FootprintShape::Rect { .. } => s.corners().into_iter().map(world).collect(),
        })
        .collect()
}

/// Polygon of a five-pointed star of outer radius `r` around `c`.
pub fn star(c: [f64; 2], r: f64) -> Vec<(f64, f64)> {
    (0..10)
        .map(|i| {
            let a = std::f64::consts::FRAC_PI_2 + std::f64::consts::PI * i as f64 / 5.0;
            let rr = if i % 2 == 0 { r } else { 0.4 * r };
            (c[0] + rr * a.cos(), c[1] + rr * a.sin())
        })
        .collect()
}

/// The head of an arrow from `from` to `to` (a triangle `len` long), empty for a zero-length
/// arrow.
fn arrow_head(from: (f64, f64), to: (f64, f64), len: f64) -> Vec<(f64, f64)> {
    let (dx, dy) = (to.0 - from.0, to.1 - from.1);
    let d = dx.hypot(dy);
    if d < 1e-9 {
        return Vec::new();
    }
    let h = len.min(0.6 * d);
    let (ux, uy) = (dx / d, dy / d);
    let base = (to.0 - ux * h, to.1 - uy * h);
    let w = 0.5 * h;
    vec![
        to,
        (base.0 - uy * w, base.1 + ux * w),
        (base.0 + uy * w, base.1 - ux * w),
    ]
}

const GREY: RGBColor = RGBColor(120, 120, 120);
const ARROW_GREY: RGBColor = RGBColor(70, 70, 70);
const ROBOT_RED: RGBColor = RGBColor(214, 39, 40);
const PLAN_ORANGE: RGBColor = RGBColor(255, 140, 0);
const START_GREEN: RGBColor = RGBColor(44, 160, 44);
const GOAL_BLUE: RGBColor = RGBColor(31, 119, 180);

/// Side of one snapshot panel (px).
const PANEL: u32 = 800;
/// Share of the plot window's width and height the BEV inset covers (top-left corner).
const INSET_SHARE: f64 = 0.3;

/// The square world window `(centre, half side)` of a snapshot: start, goal and the robot's
/// path, padded; widened (content to the bottom right) when some of that would lie under the
/// BEV inset.
fn snapshot_view(snap: &Snapshot, plan: Option<&PlanSample>) -> ([f64; 2], f64) {
    let ep = &snap.episode;
    let mut pts: Vec<[f64; 2]> = snap
        .run
        .states
        .iter()
        .map(|s| [s.pose.x, s.pose.y])
        .chain([[ep.start.x, ep.start.y], ep.goal])
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (pts[0][0], pts[0][0], pts[0][1], pts[0][1]);
    for p in &pts {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    let centre = [0.5 * (x0 + x1), 0.5 * (y0 + y1)];
    let half = 0.5 * (x1 - x0).max(y1 - y0) + 2.5;
    pts.extend(
        plan.into_iter()
            .flat_map(|p| p.poses.iter().map(|q| [q.x, q.y])),
    );
    let side = 2.0 * half;
    let covered = |p: &[f64; 2]| {
        p[0] < centre[0] - half + INSET_SHARE * side && p[1] > centre[1] + half - INSET_SHARE * side
    };
    if pts.iter().any(covered) {
        let wide = side / (1.0 - INSET_SHARE);
        let (right, bottom) = (centre[0] + half, centre[1] - half);
        return ([right - 0.5 * wide, bottom + 0.5 * wide], 0.5 * wide);
    }
    (centre, half)
}

/// One snapshot panel: the crowd, the robot with its path and plan, start and goal, and the
/// planner's BEV as an inset.
fn draw_snapshot(area: &Area<'_>, snap: &Snapshot) -> Result<(), String> {
    let ep = &snap.episode;
    let run = &snap.run;
    let t = snap.time();
    let n_t = snap.state_index(t);
    let path: Vec<(f64, f64)> = run.states.iter().map(|s| (s.pose.x, s.pose.y)).collect();
    let plan = snap.plan_at(t);
    let (c, half) = snapshot_view(snap, plan);
    let title = format!(
        "{}: {} on {} ({}), t = {:.1} s",
        ep.scenario.title(),
        snap.method,
        snap.robot,
        run.outcome.as_str(),
        t
    );
    let mut chart = ChartBuilder::on(area)
        .caption(title, (FONT, 24))
        .margin(10)
        .margin_right(20)
        .x_label_area_size(58)
        .y_label_area_size(72)
        .build_cartesian_2d((c[0] - half)..(c[0] + half), (c[1] - half)..(c[1] + half))
        .map_err(text_err)?;
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .label_style((FONT, 19))
        .axis_desc_style((FONT, 21))
        .light_line_style(WHITE)
        .bold_line_style(RGBColor(230, 230, 230))
        .draw()
        .map_err(text_err)?;
    let err = text_err;
    draw_obstacles(&mut chart, &ep.obstacles)?;

    draw_pedestrians(&mut chart, snap, t, c, half)?;
    let pose = draw_robot(&mut chart, snap, &path, n_t, plan)?;
    // Start (green star) and goal (blue star), as in the paper.
    let r = 0.05 * half;
    chart
        .draw_series([
            Polygon::new(star([ep.start.x, ep.start.y], r), START_GREEN.filled()),
            Polygon::new(star(ep.goal, r), GOAL_BLUE.filled()),
        ])
        .map_err(err)?;

    draw_bev_inset(area, &chart, snap, plan, t, pose)
}

/// The pedestrians at `t` inside the view (centre `c`, half side `half`): history dots, disc
/// and velocity arrow (0.6 s of velocity).
fn draw_pedestrians(
    chart: &mut Chart<'_, '_>,
    snap: &Snapshot,
    t: f64,
    c: [f64; 2],
    half: f64,
) -> Result<(), String> {
    let inside = |p: &[f64; 2]| (p[0] - c[0]).abs() < half && (p[1] - c[1]).abs() < half;
    let err = text_err;
    for a in pedestrians_at(snap, t) {
        if !inside(&a.position) {
            continue;
        }
        chart
            .draw_series(
                a.history
                    .iter()
                    .map(|q| Circle::new((q[0], q[1]), 3, GREY.mix(0.5).filled())),
            )
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(Polygon::new(
                disc(a.position, a.radius),
                GREY.mix(0.6).filled(),
            )))
            .map_err(err)?;
        let from = (a.position[0], a.position[1]);
        let tip = (from.0 + 0.6 * a.velocity[0], from.1 + 0.6 * a.velocity[1]);
        let head = arrow_head(from, tip, 0.025 * half);
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![from, tip],
                ARROW_GREY.stroke_width(2),
            )))
            .map_err(err)?;
        if !head.is_empty() {
            chart
                .draw_series(std::iter::once(Polygon::new(head, ARROW_GREY.filled())))
                .map_err(err)?;
        }
    }

    Ok(())
}

/// The robot: whole path faint, path so far (up to state `n_t`) solid, the plan at the
/// snapshot's time, and its footprint and heading at state `n_t`, whose pose it returns.
fn draw_robot(
    chart: &mut Chart<'_, '_>,
    snap: &Snapshot,
    path: &[(f64, f64)],
    n_t: usize,
    plan: Option<&PlanSample>,
) -> Result<Pose2, String> {
    let run = &snap.run;
    let err = text_err;
    chart
        .draw_series(std::iter::once(PathElement::new(
            path.to_vec(),
            ROBOT_RED.mix(0.25).stroke_width(2),
        )))
        .map_err(err)?;
    chart
        .draw_series(std::iter::once(PathElement::new(
            path[..=n_t].to_vec(),
            ROBOT_RED.stroke_width(3),
        )))
        .map_err(err)?;
    if let Some(plan) = plan {
        chart
            .draw_series(std::iter::once(PathElement::new(
                plan.poses.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(),
                PLAN_ORANGE.stroke_width(4),
            )))
            .map_err(err)?;
    }
    let pose = run.states[n_t].pose;
    chart
        .draw_series(
            footprint_polygons(&snap.footprint, pose)
                .into_iter()
                .map(|p| Polygon::new(p, ROBOT_RED.mix(0.8).filled())),
        )
        .map_err(err)?;
    let mut outline = disc([pose.x, pose.y], snap.footprint_radius);
    outline.push(outline[0]);
    chart
        .draw_series(std::iter::once(PathElement::new(
            outline,
            ROBOT_RED.mix(0.6).stroke_width(2),
        )))
        .map_err(err)?;
    let head = (
        pose.x + 1.5 * snap.footprint_radius * pose.theta.cos(),
        pose.y + 1.5 * snap.footprint_radius * pose.theta.sin(),
    );
    chart
        .draw_series(std::iter::once(PathElement::new(
            vec![(pose.x, pose.y), head],
            BLACK.stroke_width(2),
        )))
        .map_err(err)?;

    Ok(pose)
}

/// The BEV inset, top left of the plotting area: the raster the plan drawn (else the state at
/// `t`, at `pose`) was made from.
fn draw_bev_inset(
    area: &Area<'_>,
    chart: &Chart<'_, '_>,
    snap: &Snapshot,
    plan: Option<&PlanSample>,
    t: f64,
    pose: Pose2,
) -> Result<(), String> {
    let run = &snap.run;
    let err = text_err;
    let (t_obs, ego) = match plan {
        Some(p) => (p.t0, run.states[snap.state_index(p.t0)].pose),
        None => (t, pose),
    };
    let seen: Vec<AgentState> = pedestrians_at(snap, t_obs)
        .into_iter()
        .filter(|a| (a.position[0] - ego.x).hypot(a.position[1] - ego.y) <= snap.sensor_range)
        .collect();
    let (px, py) = chart.plotting_area().get_base_pixel();
    let (bx, by) = area.get_base_pixel();
    let (pw, ph) = chart.plotting_area().dim_in_pixel();
    let label_px = 17;
    // The raster's side: label and raster together fill the INSET_SHARE corner.
    let size = ((INSET_SHARE * f64::from(pw.min(ph))) as u32).saturating_sub(label_px + 17);
    // A square raster under its label line.
    let inset = area
        .clone()
        .shrink((px - bx + 4, py - by + 4), (size, size + label_px + 9));
    draw_bev_raster(
        &inset,
        snap.bev,
        ego,
        &seen,
        &format!("planner's BEV, t = {t_obs:.1} s"),
        label_px,
    )
    .map_err(err)?;
    Ok(())
}

/// The legend of the snapshot figures.
fn snapshot_legend(snapshots: &[Snapshot]) -> Vec<(String, Mark)> {
    let history = snapshots
        .first()
        .map_or(0.0, |s| s.history_len as f64 * s.episode.dt);
    vec![
        (
            format!("pedestrian (last {history:.1} s, 0.6 s of velocity)"),
            Mark::Pedestrian,
        ),
        (
            "robot path (faint: after t)".into(),
            Mark::Line(ROBOT_RED, 3),
        ),
        ("plan at t".into(), Mark::Line(PLAN_ORANGE, 4)),
        ("robot footprint".into(), Mark::Bar(ROBOT_RED)),
        ("planners' disc".into(), Mark::Ring(ROBOT_RED)),
        ("start".into(), Mark::Star(START_GREEN)),
        ("goal".into(), Mark::Star(GOAL_BLUE)),
    ]
}

/// Fig. 4: trajectory snapshots (one per scenario class there, failed runs elsewhere), in
/// panels of 800 × 800 px, two per row, with a BEV inset in each and a shared legend below.
pub fn trajectory_snapshots(path: &Path, snapshots: &[Snapshot]) -> Result<(), SimError> {
    let err = draw_err(path);
    let cols = snapshots.len().clamp(1, 2);
    let rows = snapshots.len().div_ceil(2).max(1);
    let legend = snapshot_legend(snapshots);
    let width = PANEL * cols as u32;
    let panels_h = PANEL * rows as u32;
    let size = (width, panels_h + legend_height(&legend, width));
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (top, strip) = root.split_vertically(panels_h);
    let panels = top.split_evenly((rows, cols));
    for (panel, snap) in panels.iter().zip(snapshots) {
        draw_snapshot(panel, snap).map_err(&err)?;
    }
    draw_legend(&strip, &legend).map_err(&err)?;
    root.present().map_err(|e| err(e.to_string()))
}

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

/// `c` blended with white, `alpha` of `c` (an opaque colour for legend marks).
fn faint(c: RGBColor, alpha: f64) -> RGBColor {
    let m = |v: u8| (alpha * f64::from(v) + (1.0 - alpha) * 255.0).round() as u8;
    RGBColor(m(c.0), m(c.1), m(c.2))
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
