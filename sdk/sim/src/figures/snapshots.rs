//! Trajectory snapshots (Fig. 4): one recorded run per panel, with the crowd, the robot's path
//! and plan, and the planner's BEV as an inset.

use super::shapes::arrow_head;
use super::{
    ARROW_GREY, Area, Chart, FONT, GOAL_BLUE, GREY, Mark, PLAN_ORANGE, ROBOT_RED, START_GREEN,
    disc, draw_err, draw_legend, draw_obstacles, footprint_polygons, legend_height, star, text_err,
};
use crate::episode::{Episode, ScenarioTitle};
use crate::error::SimError;
use crate::plan_figure::draw_bev_raster;
use crate::replay::CrowdReplay;
use crate::runner::{EpisodeRun, PlanSample};
use human2nav_core::bev::BevSpec;
use human2nav_core::robot::footprint::FootprintShape;
use human2nav_core::{AgentState, Pose2};
use plotters::prelude::*;
use std::path::Path;

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
