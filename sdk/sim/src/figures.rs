//! PNG figures drawn with plotters: SR per scenario and method (paper Fig. 6), TFS and SR per
//! robot and method (Fig. 7), SR against crowd density, trajectory snapshots (Fig. 4) and the
//! data-scaling curve (Fig. 5).
//!
//! The charts are drawn to be printed: the y axis spans exactly 0–100 % (SR) or 0–1 (TFS),
//! both axes are described, the legend sits below the plotting area, and the fonts are read
//! at 100 % zoom. SR bars and points carry 95 % Wilson score intervals ([`sr_interval`]), TFS
//! bars ±1.96 standard errors of the mean of the per-episode TFS ([`tfs_interval`]).

mod charts;
mod scaling;
mod shapes;
mod snapshots;

pub use charts::{sr_per_density, sr_per_scenario, tfs_sr_per_robot};
pub use scaling::{ScalingPoint, scaling_points, sr_vs_training_data};
pub(crate) use shapes::draw_obstacles;
pub use shapes::{OBSTACLE, disc, footprint_polygons, star};
pub use snapshots::{Snapshot, pedestrians_at, trajectory_snapshots};

use crate::bench::ResultRow;
use crate::error::SimError;
use crate::stats::{self, Z95};
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

const GREY: RGBColor = RGBColor(120, 120, 120);
const ARROW_GREY: RGBColor = RGBColor(70, 70, 70);
const ROBOT_RED: RGBColor = RGBColor(214, 39, 40);
const PLAN_ORANGE: RGBColor = RGBColor(255, 140, 0);
const START_GREEN: RGBColor = RGBColor(44, 160, 44);
const GOAL_BLUE: RGBColor = RGBColor(31, 119, 180);

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

/// `c` blended with white, `alpha` of `c` (an opaque colour for legend marks).
fn faint(c: RGBColor, alpha: f64) -> RGBColor {
    let m = |v: u8| (alpha * f64::from(v) + (1.0 - alpha) * 255.0).round() as u8;
    RGBColor(m(c.0), m(c.1), m(c.2))
}
