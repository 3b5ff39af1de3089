//! One planning step as a picture in the style of the paper's Fig. 4, and the helpers that set
//! such a step up from a benchmark episode.
//!
//! # The step
//! [`observation_at`] places the robot at the episode's start pose (heading per
//! [`StartHeading`], as the simulator starts an episode), moving straight ahead at
//! [`StepOptions::ego_speed`], and observes the replayed crowd at [`StepOptions::time`]: every
//! pedestrian present within [`StepOptions::sensor_range`] of the robot, with up to
//! [`StepOptions::history_len`] recorded positions, through [`CrowdReplay::observe`].
//!
//! [`StartHeading`]: crate::runner::StartHeading
//! [`CrowdReplay::observe`]: crate::replay::CrowdReplay::observe
//!
//! # The picture ([`draw_plan_figure`])
//! World frame around the robot, 1 m grid:
//! * pedestrians: grey discs, their recent history as grey dots, a heading arrow (0.6 s of
//!   their velocity);
//! * the robot: red disc of its footprint radius with a black heading tick;
//! * start: green star; goal: blue star (the paper's convention);
//! * the `K` sampled candidates before guidance: thin light blue lines; after guidance: faint
//!   violet lines; the kept sample before guidance: dashed orange;
//! * the final plan: each segment green when the waypoint it reaches is feasible and red when
//!   not ([`human2nav_core::feasibility::feasibility_mask`]), waypoints as dots;
//! * top left, the planner's ego-frame BEV raster (forward is up): free cells light grey,
//!   occupied cells coloured by the direction of their velocity channels (hue, the wheel in the
//!   corner) with saturation growing with speed (a static pedestrian is dark grey), black
//!   arrows for the observed velocities, the robot as a red triangle;
//! * the title: robot, guidance on/off, TFS of the plan (and of the kept sample before
//!   guidance) and Φ before → after guidance.

mod bev_raster;
mod step;
#[cfg(test)]
mod tests;

pub(crate) use bev_raster::draw_bev_raster;
pub use step::{StepOptions, load_episodes, observation_at, select_episode, start_pose};

use crate::error::SimError;
use crate::figures::{disc, draw_obstacles, star};
use human2nav_core::bev::BevSpec;
use human2nav_core::feasibility;
use human2nav_core::forecast::Forecast;
use human2nav_core::{Limits, Observation, Plan, Pose2};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// What [`draw_plan_figure`] draws.
#[derive(Clone, Copy, Debug)]
pub struct PlanFigure<'a> {
    /// Robot name (title).
    pub robot: &'a str,
    /// A label of the scene, e.g. the episode id (title; may be empty).
    pub label: &'a str,
    /// Whether the planner ran with guidance (title).
    pub guidance: bool,
    /// The observation the plan was made from.
    pub observation: &'a Observation,
    /// The episode's start pose (green star); `None` draws it at the robot.
    pub start: Option<Pose2>,
    /// The plan with its diagnostics (candidates, guided candidates, Φ).
    pub plan: &'a Plan,
    /// The robot's limits (segment colours, TFS).
    pub limits: &'a Limits,
    /// Footprint radius of the robot (m).
    pub footprint_radius: f64,
    /// The planner's BEV raster spec (inset).
    pub bev: BevSpec,
    /// The forecast the planner's selection scored against, in the world frame (its
    /// predictor's; `None`: not drawn).
    pub forecast: Option<&'a Forecast>,
}

/// Numbers shown on a [`PlanFigure`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanFigureNumbers {
    /// TFS of the plan.
    pub tfs: f64,
    /// TFS of the kept sample before guidance (when the plan is a fresh guided sample).
    pub tfs_before: Option<f64>,
    /// Feasible waypoints / all waypoints of the plan.
    pub feasible: usize,
    /// Waypoints of the plan.
    pub waypoints: usize,
}

/// The numbers the figure reports for a plan (pure; used by [`draw_plan_figure`]).
pub fn plan_numbers(fig: &PlanFigure<'_>) -> PlanFigureNumbers {
    let v0 = fig.observation.ego_velocity;
    let plan = fig.plan;
    let mask = feasibility::feasibility_mask(&plan.poses, plan.dt, fig.limits, v0);
    let waypoints = mask.len().saturating_sub(1);
    let feasible = mask.iter().skip(1).filter(|f| **f).count();
    let tfs_before =
        before_guidance(fig).map(|poses| feasibility::tfs_plan(poses, plan.dt, fig.limits, v0));
    PlanFigureNumbers {
        tfs: feasibility::tfs_plan(&plan.poses, plan.dt, fig.limits, v0),
        tfs_before,
        feasible,
        waypoints,
    }
}

/// The kept sample before guidance, when guidance ran and the plan is a fresh sample.
fn before_guidance<'a>(fig: &PlanFigure<'a>) -> Option<&'a [Pose2]> {
    let info = &fig.plan.info;
    if !fig.guidance || info.phi_after.is_none() {
        return None;
    }
    info.selected
        .and_then(|i| info.candidates.get(i))
        .map(Vec::as_slice)
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
/// A chart in metres on a bitmap.
type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

const GREY: RGBColor = RGBColor(120, 120, 120);
const EGO_RED: RGBColor = RGBColor(214, 39, 40);
const FEASIBLE: RGBColor = RGBColor(30, 160, 60);
const INFEASIBLE: RGBColor = RGBColor(220, 30, 30);
const CANDIDATE: RGBColor = RGBColor(110, 160, 220);
const GUIDED: RGBColor = RGBColor(150, 90, 200);
const BEFORE: RGBColor = RGBColor(255, 140, 0);
const START: RGBColor = RGBColor(44, 160, 44);
const GOAL: RGBColor = RGBColor(31, 119, 180);

/// Image size in pixels.
const WIDTH: u32 = 1000;
const HEIGHT: u32 = 1060;

/// Draws the figure as a PNG at `path` (parent directories are created) and returns the
/// numbers it shows.
pub fn draw_plan_figure(path: &Path, fig: &PlanFigure<'_>) -> Result<PlanFigureNumbers, SimError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| SimError::io(dir, e))?;
    }
    let numbers = plan_numbers(fig);
    let err = |message: String| SimError::Figure {
        file: path.to_path_buf(),
        message,
    };
    let root = BitMapBackend::new(path, (WIDTH, HEIGHT)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    draw(&root, fig, &numbers).map_err(err)?;
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(numbers)
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".to_string(), |x| format!("{x:.digits$}"))
}

/// The square world window `(centre, half side)` showing the robot, the plan, the candidates
/// and the goal (when it is within 12 m).
fn view(fig: &PlanFigure<'_>) -> ([f64; 2], f64) {
    let obs = fig.observation;
    let mut pts: Vec<[f64; 2]> = vec![[obs.ego.x, obs.ego.y]];
    pts.extend(fig.plan.poses.iter().map(|p| [p.x, p.y]));
    for c in fig.plan.info.candidates.iter().chain(&fig.plan.info.guided) {
        pts.extend(c.iter().map(|p| [p.x, p.y]));
    }
    let near = |p: [f64; 2]| (p[0] - obs.ego.x).hypot(p[1] - obs.ego.y) <= 12.0;
    if near(obs.goal) {
        pts.push(obs.goal);
    }
    if let Some(s) = fig.start.filter(|s| near([s.x, s.y])) {
        pts.push([s.x, s.y]);
    }
    let pts: Vec<[f64; 2]> = pts
        .into_iter()
        .filter(|p| p[0].is_finite() && p[1].is_finite() && near(*p))
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (obs.ego.x, obs.ego.x, obs.ego.y, obs.ego.y);
    for p in &pts {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    let half = (0.5 * (x1 - x0).max(y1 - y0) + 1.5).max(4.0);
    let centre = [0.5 * (x0 + x1), 0.5 * (y0 + y1)];
    // The BEV inset covers about the top-left INSET_SHARE of the window. When content would
    // hide under it, widen the window and push the content to the bottom-right instead.
    let side = 2.0 * half;
    let covered = |p: &[f64; 2]| {
        p[0] < centre[0] - half + INSET_SHARE * side && p[1] > centre[1] + half - INSET_SHARE * side
    };
    let agents = obs.agents.iter().map(|a| a.position);
    if pts.iter().copied().chain(agents).any(|p| covered(&p)) {
        let wide = side / (1.0 - INSET_SHARE);
        let (right, bottom) = (centre[0] + half, centre[1] - half);
        return ([right - 0.5 * wide, bottom + 0.5 * wide], 0.5 * wide);
    }
    (centre, half)
}

/// Share of the plot window's width and height the BEV inset covers.
const INSET_SHARE: f64 = 0.3;

/// A polyline and a filled triangle.
type ArrowShape = (Vec<(f64, f64)>, Vec<(f64, f64)>);

/// An arrow from `from` to `to`: its shaft and its head (empty for a zero-length arrow).
fn arrow(from: (f64, f64), to: (f64, f64), head: f64) -> ArrowShape {
    let (dx, dy) = (to.0 - from.0, to.1 - from.1);
    let len = dx.hypot(dy);
    if len < 1e-9 {
        return (vec![from, to], Vec::new());
    }
    let (ux, uy) = (dx / len, dy / len);
    let h = head.min(0.5 * len);
    let base = (to.0 - ux * h, to.1 - uy * h);
    let w = 0.5 * h;
    let tri = vec![
        to,
        (base.0 - uy * w, base.1 + ux * w),
        (base.0 + uy * w, base.1 - ux * w),
    ];
    (vec![from, base], tri)
}

/// Draws the whole figure: titles, the scene with the samples and the plan, the legend and
/// the BEV inset.
fn draw(root: &Area<'_>, fig: &PlanFigure<'_>, numbers: &PlanFigureNumbers) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let obs = fig.observation;
    let (c, half) = view(fig);
    let (top, body) = root.split_vertically(64);
    draw_titles(&top, fig, numbers)?;

    let mut chart = ChartBuilder::on(&body)
        .margin(10)
        .margin_right(24)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d((c[0] - half)..(c[0] + half), (c[1] - half)..(c[1] + half))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .x_labels(12)
        .y_labels(12)
        .light_line_style(WHITE)
        .bold_line_style(RGBColor(222, 222, 222))
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|x| e(&x))?;
    let inside = |p: [f64; 2]| (p[0] - c[0]).abs() < half && (p[1] - c[1]).abs() < half;
    draw_obstacles(&mut chart, &obs.obstacles)?;

    draw_pedestrians(&mut chart, fig, &inside)?;
    if let Some(f) = fig.forecast {
        draw_forecast(&mut chart, f, &inside)?;
    }
    draw_samples(&mut chart, fig)?;
    draw_plan(&mut chart, fig)?;
    draw_robot_and_goal(&mut chart, fig, half, &inside)?;

    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.88))
        .border_style(RGBColor(160, 160, 160))
        .label_font(("sans-serif", 15))
        .margin(8)
        .draw()
        .map_err(|x| e(&x))?;

    // The BEV inset in the top-left corner of the plotting area.
    let (px, py) = chart.plotting_area().get_base_pixel();
    let (pw, ph) = chart.plotting_area().dim_in_pixel();
    let size = (INSET_SHARE * f64::from(pw.min(ph))) as u32 - 12;
    let inset = root
        .clone()
        .shrink((px + 6, py + 6), (size, size.saturating_sub(22) + 22));
    draw_bev_inset(&inset, fig).map_err(|x| e(&x))?;
    Ok(())
}

/// The title (robot, guidance, TFS, Φ) and the subtitle (time, crowd, speed, feasible
/// waypoints, fallback) in the strip `top`.
fn draw_titles(
    top: &Area<'_>,
    fig: &PlanFigure<'_>,
    numbers: &PlanFigureNumbers,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let obs = fig.observation;
    let info = &fig.plan.info;
    let title = format!(
        "{} — guidance {} — TFS {:.2}{} — Φ {} → {}",
        fig.robot,
        if fig.guidance { "on" } else { "off" },
        numbers.tfs,
        numbers
            .tfs_before
            .map_or(String::new(), |t| format!(" (before guidance {t:.2})")),
        fmt_opt(info.phi_before, 3),
        fmt_opt(info.phi_after, 3),
    );
    top.draw(&Text::new(
        title,
        (WIDTH as i32 / 2, 8),
        ("sans-serif", 24)
            .into_font()
            .color(&BLACK)
            .pos(Pos::new(HPos::Center, VPos::Top)),
    ))
    .map_err(|x| e(&x))?;
    let sub = format!(
        "{}t = {:.1} s, {} pedestrians observed, robot speed {:.2} m/s; {} of {} waypoints feasible{}",
        if fig.label.is_empty() {
            String::new()
        } else {
            format!("{} — ", fig.label)
        },
        obs.time,
        obs.agents.len(),
        obs.ego_velocity.vx.hypot(obs.ego_velocity.vy),
        numbers.feasible,
        numbers.waypoints,
        if info.fallback {
            " — FALLBACK: stop in place"
        } else {
            ""
        },
    );
    top.draw(&Text::new(
        sub,
        (WIDTH as i32 / 2, 38),
        ("sans-serif", 16)
            .into_font()
            .color(&RGBColor(60, 60, 60))
            .pos(Pos::new(HPos::Center, VPos::Top)),
    ))
    .map_err(|x| e(&x))?;

    Ok(())
}

/// The observed pedestrians inside the view: history dots, disc, heading arrow; and their
/// legend entry.
fn draw_pedestrians(
    chart: &mut Chart<'_, '_>,
    fig: &PlanFigure<'_>,
    inside: &dyn Fn([f64; 2]) -> bool,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let obs = fig.observation;
    for a in &obs.agents {
        if !inside(a.position) {
            continue;
        }
        chart
            .draw_series(
                a.history
                    .iter()
                    .map(|q| Circle::new((q[0], q[1]), 3, GREY.mix(0.55).filled())),
            )
            .map_err(|x| e(&x))?;
        chart
            .draw_series(std::iter::once(Polygon::new(
                disc(a.position, a.radius),
                GREY.mix(0.65).filled(),
            )))
            .map_err(|x| e(&x))?;
        let from = (a.position[0], a.position[1]);
        let to = (from.0 + 0.6 * a.velocity[0], from.1 + 0.6 * a.velocity[1]);
        let (shaft, head) = arrow(from, to, 0.18);
        chart
            .draw_series(std::iter::once(PathElement::new(
                shaft,
                RGBColor(70, 70, 70).stroke_width(2),
            )))
            .map_err(|x| e(&x))?;
        if !head.is_empty() {
            chart
                .draw_series(std::iter::once(Polygon::new(
                    head,
                    RGBColor(70, 70, 70).filled(),
                )))
                .map_err(|x| e(&x))?;
        }
    }
    // Legend entry for pedestrians.
    chart
        .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
        .map_err(|x| e(&x))?
        .label("pedestrian (history dots, heading arrow)")
        .legend(|(x, y)| Circle::new((x + 8, y), 6, GREY.mix(0.65).filled()));

    Ok(())
}

/// The forecast's paths of the pedestrians in view, one thin line per scene (a pedestrian
/// predicted one way has one) up to where it leaves the view, and their legend entry.
fn draw_forecast(
    chart: &mut Chart<'_, '_>,
    forecast: &Forecast,
    inside: &dyn Fn([f64; 2]) -> bool,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let colour = RGBColor(230, 140, 30);
    for a in forecast.agents() {
        for path in &a.paths {
            // Up to where it leaves the view (plotters would run it along the border).
            let shown: Vec<(f64, f64)> = path
                .iter()
                .take_while(|q| inside(**q))
                .map(|q| (q[0], q[1]))
                .collect();
            chart
                .draw_series(std::iter::once(PathElement::new(
                    shown,
                    colour.mix(0.7).stroke_width(1),
                )))
                .map_err(|x| e(&x))?;
        }
    }
    chart
        .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
        .map_err(|x| e(&x))?
        .label(format!(
            "predicted pedestrian paths ({} scene{})",
            forecast.scenes(),
            if forecast.scenes() == 1 { "" } else { "s" }
        ))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
    Ok(())
}

/// The flow samples before and after guidance, and the kept sample before guidance.
fn draw_samples(chart: &mut Chart<'_, '_>, fig: &PlanFigure<'_>) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let info = &fig.plan.info;
    let xy = |p: &[Pose2]| p.iter().map(|q| (q.x, q.y)).collect::<Vec<_>>();
    for (i, cand) in info.candidates.iter().enumerate() {
        let s = chart
            .draw_series(std::iter::once(PathElement::new(
                xy(cand),
                CANDIDATE.mix(0.55).stroke_width(1),
            )))
            .map_err(|x| e(&x))?;
        if i == 0 {
            s.label(format!("{} samples before guidance", info.candidates.len()))
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], CANDIDATE.stroke_width(2))
                });
        }
    }
    for (i, cand) in info.guided.iter().enumerate() {
        let s = chart
            .draw_series(std::iter::once(PathElement::new(
                xy(cand),
                GUIDED.mix(0.35).stroke_width(1),
            )))
            .map_err(|x| e(&x))?;
        if i == 0 {
            s.label("samples after guidance").legend(|(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], GUIDED.mix(0.6).stroke_width(2))
            });
        }
    }
    if let Some(before) = before_guidance(fig) {
        chart
            .draw_series(std::iter::once(DashedPathElement::new(
                xy(before),
                6,
                4,
                BEFORE.stroke_width(2),
            )))
            .map_err(|x| e(&x))?
            .label("kept sample before guidance")
            .legend(|(x, y)| {
                DashedPathElement::new(vec![(x, y), (x + 18, y)], 5, 3, BEFORE.stroke_width(2))
            });
    }

    Ok(())
}

/// The plan, segment by segment, coloured by feasibility; and its legend entries.
fn draw_plan(chart: &mut Chart<'_, '_>, fig: &PlanFigure<'_>) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let obs = fig.observation;
    let mask =
        feasibility::feasibility_mask(&fig.plan.poses, fig.plan.dt, fig.limits, obs.ego_velocity);
    let segs: Vec<(Vec<(f64, f64)>, bool)> = fig
        .plan
        .poses
        .windows(2)
        .zip(mask.iter().skip(1))
        .map(|(w, ok)| (vec![(w[0].x, w[0].y), (w[1].x, w[1].y)], *ok))
        .collect();
    for (seg, ok) in &segs {
        let col = if *ok { FEASIBLE } else { INFEASIBLE };
        chart
            .draw_series(std::iter::once(PathElement::new(
                seg.clone(),
                col.stroke_width(4),
            )))
            .map_err(|x| e(&x))?;
    }
    chart
        .draw_series(fig.plan.poses.iter().zip(&mask).skip(1).map(|(p, ok)| {
            let col = if *ok { FEASIBLE } else { INFEASIBLE };
            Circle::new((p.x, p.y), 3, col.filled())
        }))
        .map_err(|x| e(&x))?;
    chart
        .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
        .map_err(|x| e(&x))?
        .label("plan: feasible segment")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], FEASIBLE.stroke_width(4)));
    chart
        .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
        .map_err(|x| e(&x))?
        .label("plan: infeasible segment")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], INFEASIBLE.stroke_width(4)));

    Ok(())
}

/// The robot's footprint and heading, the start (when inside the view) and the goal (or,
/// off the view, a dashed arrow pointing to it).
fn draw_robot_and_goal(
    chart: &mut Chart<'_, '_>,
    fig: &PlanFigure<'_>,
    half: f64,
    inside: &dyn Fn([f64; 2]) -> bool,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let obs = fig.observation;
    let ego = obs.ego;
    chart
        .draw_series(std::iter::once(Polygon::new(
            disc([ego.x, ego.y], fig.footprint_radius),
            EGO_RED.mix(0.85).filled(),
        )))
        .map_err(|x| e(&x))?
        .label("robot (footprint)")
        .legend(|(x, y)| Circle::new((x + 8, y), 6, EGO_RED.filled()));
    let head = (
        ego.x + 1.6 * fig.footprint_radius * ego.theta.cos(),
        ego.y + 1.6 * fig.footprint_radius * ego.theta.sin(),
    );
    chart
        .draw_series(std::iter::once(PathElement::new(
            vec![(ego.x, ego.y), head],
            BLACK.stroke_width(2),
        )))
        .map_err(|x| e(&x))?;
    let r = 0.045 * half;
    let start = fig.start.unwrap_or(ego);
    if inside([start.x, start.y]) {
        chart
            .draw_series(std::iter::once(Polygon::new(
                star([start.x, start.y], r),
                START.filled(),
            )))
            .map_err(|x| e(&x))?
            .label("start")
            .legend(|(x, y)| Polygon::new(star_px(x + 8, y), START.filled()));
    }
    if inside(obs.goal) {
        chart
            .draw_series(std::iter::once(Polygon::new(
                star(obs.goal, r),
                GOAL.filled(),
            )))
            .map_err(|x| e(&x))?
            .label("goal")
            .legend(|(x, y)| Polygon::new(star_px(x + 8, y), GOAL.filled()));
    } else {
        // Goal off the window: an arrow at the robot pointing to it.
        let (dx, dy) = (obs.goal[0] - ego.x, obs.goal[1] - ego.y);
        let d = dx.hypot(dy).max(1e-9);
        let to = (ego.x + 0.8 * half * dx / d, ego.y + 0.8 * half * dy / d);
        let (shaft, tip) = arrow((ego.x, ego.y), to, 0.3);
        chart
            .draw_series(std::iter::once(DashedPathElement::new(
                shaft,
                8,
                6,
                GOAL.stroke_width(2),
            )))
            .map_err(|x| e(&x))?
            .label(format!("direction to the goal ({d:.1} m away)"))
            .legend(|(x, y)| {
                DashedPathElement::new(vec![(x, y), (x + 18, y)], 5, 3, GOAL.stroke_width(2))
            });
        chart
            .draw_series(std::iter::once(Polygon::new(tip, GOAL.filled())))
            .map_err(|x| e(&x))?;
    }

    Ok(())
}

/// A star polygon in pixel coordinates (legend marker).
fn star_px(x: i32, y: i32) -> Vec<(i32, i32)> {
    star([x as f64, y as f64], 8.0)
        .into_iter()
        .map(|(a, b)| (a.round() as i32, (2.0 * y as f64 - b).round() as i32))
        .collect()
}

fn draw_bev_inset<'b>(
    area: &Area<'b>,
    fig: &PlanFigure<'_>,
) -> Result<(), DrawingAreaErrorKind<<BitMapBackend<'b> as DrawingBackend>::ErrorType>> {
    let spec = fig.bev;
    let n = spec.cells;
    let label = format!(
        "BEV input {n}×{n} × {:.2} m (ego frame, forward up)",
        spec.resolution
    );
    let obs = fig.observation;
    draw_bev_raster(area, spec, obs.ego, &obs.agents, &label, 13)
}
