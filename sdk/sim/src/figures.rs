//! PNG figures drawn with plotters: SR per scenario and method (paper Fig. 6), TFS and SR per
//! robot and method (Fig. 7) and one trajectory snapshot per scenario (Fig. 4).

use crate::bench::ResultRow;
use crate::episode::{Episode, ScenarioClass, ScenarioTitle};
use crate::error::SimError;
use crate::replay::CrowdReplay;
use crate::report::summarize;
use crate::runner::EpisodeRun;
use human2nav_core::Pose2;
use human2nav_core::robot::footprint::FootprintShape;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

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

fn draw_err(file: &Path) -> impl Fn(String) -> SimError + '_ {
    move |message| SimError::Figure {
        file: file.to_path_buf(),
        message,
    }
}

/// Height of one legend line in the units of a `[0, 1]` bar chart's y axis.
const LEGEND_ROOM_PER_SERIES: f64 = 0.075;

/// One grouped bar chart: `groups` along x, one bar per series in each group, values in `[0, 1]`.
fn grouped_bars(
    area: &Area<'_>,
    title: &str,
    y_desc: &str,
    groups: &[String],
    series: &[String],
    value: &dyn Fn(usize, usize) -> Option<f64>,
) -> Result<(), String> {
    let n = groups.len().max(1) as f64;
    // Room above 1 for the legend (one line per series), so that it never hides a bar.
    let top = 1.08 + LEGEND_ROOM_PER_SERIES * series.len() as f64;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(50)
        .build_cartesian_2d(0f64..n, 0f64..top)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .y_desc(y_desc)
        .y_label_formatter(&|v| {
            if *v <= 1.0 + 1e-9 {
                format!("{v:.1}")
            } else {
                String::new()
            }
        })
        .draw()
        .map_err(|e| e.to_string())?;
    let k = series.len().max(1) as f64;
    let width = 0.8 / k;
    for (si, name) in series.iter().enumerate() {
        let c = colour(si);
        let bars: Vec<Rectangle<(f64, f64)>> = (0..groups.len())
            .filter_map(|gi| {
                let v = value(gi, si)?;
                let x0 = gi as f64 + 0.1 + si as f64 * width;
                Some(Rectangle::new(
                    [(x0, 0.0), (x0 + width * 0.92, v)],
                    c.filled(),
                ))
            })
            .collect();
        chart
            .draw_series(bars)
            .map_err(|e| e.to_string())?
            .label(name.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.filled()));
    }
    for (gi, g) in groups.iter().enumerate() {
        // backend_coord is in whole-image pixels; the area draws relative to its own corner.
        let (px, py) = chart.backend_coord(&(gi as f64 + 0.5, 0.0));
        let (bx, by) = area.get_base_pixel();
        area.draw(&Text::new(
            g.clone(),
            (px - bx, py - by + 8),
            ("sans-serif", 16).into_font().color(&BLACK).pos(
                plotters::style::text_anchor::Pos::new(
                    plotters::style::text_anchor::HPos::Center,
                    plotters::style::text_anchor::VPos::Top,
                ),
            ),
        ))
        .map_err(|e| e.to_string())?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(|e| e.to_string())?;
    Ok(())
}

/// Fig. 6: success rate per scenario class (x) and method (bars), over every robot of `suite`.
pub fn sr_per_scenario(
    path: &Path,
    rows: &[ResultRow],
    suite: &str,
    methods: &[String],
) -> Result<(), SimError> {
    let err = draw_err(path);
    let root = BitMapBackend::new(path, (1000, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let groups: Vec<String> = ScenarioClass::ALL
        .iter()
        .map(|c| c.title().to_string())
        .collect();
    let value = |gi: usize, si: usize| {
        let s = summarize(rows.iter().filter(|r| {
            r.suite == suite && r.scenario == ScenarioClass::ALL[gi] && r.method == methods[si]
        }));
        (s.n > 0).then_some(s.sr)
    };
    grouped_bars(
        &root,
        &format!("Success rate per scenario ({suite})"),
        "SR",
        &groups,
        methods,
        &value,
    )
    .map_err(&err)?;
    root.present().map_err(|e| err(e.to_string()))
}

/// Fig. 7: TFS (left) and SR (right) per robot (x) and method (bars) on `suite`.
pub fn tfs_sr_per_robot(
    path: &Path,
    rows: &[ResultRow],
    suite: &str,
    robots: &[String],
    methods: &[String],
) -> Result<(), SimError> {
    let err = draw_err(path);
    let root = BitMapBackend::new(path, (1300, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let panels = root.split_evenly((1, 2));
    let pick = |gi: usize, si: usize| {
        let s = summarize(
            rows.iter()
                .filter(|r| r.suite == suite && r.robot == robots[gi] && r.method == methods[si]),
        );
        (s.n > 0).then_some(s)
    };
    let tfs = |gi: usize, si: usize| pick(gi, si).map(|s| s.tfs);
    let sr = |gi: usize, si: usize| pick(gi, si).map(|s| s.sr);
    grouped_bars(
        &panels[0],
        &format!("Trajectory feasibility score ({suite})"),
        "TFS",
        robots,
        methods,
        &tfs,
    )
    .map_err(&err)?;
    grouped_bars(
        &panels[1],
        &format!("Success rate ({suite})"),
        "SR",
        robots,
        methods,
        &sr,
    )
    .map_err(&err)?;
    root.present().map_err(|e| err(e.to_string()))
}

/// One recorded episode to draw as a trajectory snapshot.
#[derive(Clone, Debug)]
pub struct Snapshot {
    pub episode: Episode,
    pub run: EpisodeRun,
    pub robot: String,
    pub method: String,
    /// The planners' covering disc (drawn as an outline, and the heading arrow's scale).
    pub footprint_radius: f64,
    /// The footprint collisions are checked with (drawn filled).
    pub footprint: Vec<FootprintShape>,
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

fn draw_snapshot(area: &Area<'_>, snap: &Snapshot) -> Result<(), String> {
    let ep = &snap.episode;
    let run = &snap.run;
    let t = snap.time();
    let n_t = ((t / run.dt).round() as usize).min(run.states.len().saturating_sub(1));
    let replay = CrowdReplay::new(ep);
    let path: Vec<(f64, f64)> = run.states.iter().map(|s| (s.pose.x, s.pose.y)).collect();
    let plan: Option<&Vec<Pose2>> = run
        .plans
        .iter()
        .rev()
        .find(|p| p.t0 <= t + 1e-9)
        .map(|p| &p.poses);

    // View: start, goal, the robot path, padded; pedestrians outside are clipped.
    let mut xs: Vec<f64> = path
        .iter()
        .map(|p| p.0)
        .chain([ep.start.x, ep.goal[0]])
        .collect();
    let mut ys: Vec<f64> = path
        .iter()
        .map(|p| p.1)
        .chain([ep.start.y, ep.goal[1]])
        .collect();
    xs.sort_by(f64::total_cmp);
    ys.sort_by(f64::total_cmp);
    let (x0, x1) = (xs[0], xs[xs.len() - 1]);
    let (y0, y1) = (ys[0], ys[ys.len() - 1]);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let half = 0.5 * (x1 - x0).max(y1 - y0) + 2.5;
    let title = format!(
        "{} — {} on {} ({}, t = {:.1} s)",
        ep.scenario.title(),
        snap.method,
        snap.robot,
        run.outcome.as_str(),
        t
    );
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(28)
        .y_label_area_size(36)
        .build_cartesian_2d((cx - half)..(cx + half), (cy - half)..(cy + half))
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(|e| e.to_string())?;
    let inside = |p: &[f64; 2]| (p[0] - cx).abs() < half && (p[1] - cy).abs() < half;
    let grey = RGBColor(120, 120, 120);

    // Pedestrians: history dots, disc, heading arrow (0.6 s of velocity).
    for tr in &ep.agents {
        let Some(s) = replay.sample(tr, t) else {
            continue;
        };
        if !inside(&s.position) {
            continue;
        }
        let k = ((t / ep.dt - tr.start_step as f64).floor().max(0.0) as usize)
            .min(tr.positions.len() - 1);
        let from = k.saturating_sub(8);
        chart
            .draw_series(
                tr.positions[from..=k]
                    .iter()
                    .map(|q| Circle::new((q[0], q[1]), 2, grey.mix(0.5).filled())),
            )
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(std::iter::once(Polygon::new(
                disc(s.position, s.radius),
                grey.mix(0.6).filled(),
            )))
            .map_err(|e| e.to_string())?;
        let tip = (
            s.position[0] + 0.6 * s.velocity[0],
            s.position[1] + 0.6 * s.velocity[1],
        );
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(s.position[0], s.position[1]), tip],
                grey.stroke_width(2),
            )))
            .map_err(|e| e.to_string())?;
    }

    // Robot: whole path faint, path so far solid, footprint at t, plan at t.
    let red = RGBColor(214, 39, 40);
    chart
        .draw_series(std::iter::once(PathElement::new(
            path.clone(),
            red.mix(0.25).stroke_width(2),
        )))
        .map_err(|e| e.to_string())?;
    chart
        .draw_series(std::iter::once(PathElement::new(
            path[..=n_t].to_vec(),
            red.stroke_width(3),
        )))
        .map_err(|e| e.to_string())?;
    if let Some(plan) = plan {
        let orange = RGBColor(255, 140, 0);
        chart
            .draw_series(std::iter::once(PathElement::new(
                plan.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(),
                orange.stroke_width(3),
            )))
            .map_err(|e| e.to_string())?;
    }
    let pose = run.states[n_t].pose;
    chart
        .draw_series(
            footprint_polygons(&snap.footprint, pose)
                .into_iter()
                .map(|p| Polygon::new(p, red.mix(0.8).filled())),
        )
        .map_err(|e| e.to_string())?;
    let mut outline = disc([pose.x, pose.y], snap.footprint_radius);
    outline.push(outline[0]);
    chart
        .draw_series(std::iter::once(PathElement::new(
            outline,
            red.mix(0.5).stroke_width(1),
        )))
        .map_err(|e| e.to_string())?;
    let head = (
        pose.x + 1.5 * snap.footprint_radius * pose.theta.cos(),
        pose.y + 1.5 * snap.footprint_radius * pose.theta.sin(),
    );
    chart
        .draw_series(std::iter::once(PathElement::new(
            vec![(pose.x, pose.y), head],
            BLACK.stroke_width(2),
        )))
        .map_err(|e| e.to_string())?;

    // Start (green star) and goal (blue star), as in the paper.
    let r = 0.06 * half;
    chart
        .draw_series([
            Polygon::new(
                star([ep.start.x, ep.start.y], r),
                RGBColor(44, 160, 44).filled(),
            ),
            Polygon::new(star(ep.goal, r), RGBColor(31, 119, 180).filled()),
        ])
        .map_err(|e| e.to_string())?;
    Ok(())
}

/// Fig. 4: trajectory snapshots (one per scenario class there, failed runs elsewhere), in
/// panels of 600 × 600 px, two per row.
pub fn trajectory_snapshots(path: &Path, snapshots: &[Snapshot]) -> Result<(), SimError> {
    let err = draw_err(path);
    let cols = snapshots.len().clamp(1, 2);
    let rows = snapshots.len().div_ceil(2).max(1);
    let size = (600 * cols as u32, 600 * rows as u32);
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let panels = root.split_evenly((rows, cols));
    for (panel, snap) in panels.iter().zip(snapshots) {
        draw_snapshot(panel, snap).map_err(&err)?;
    }
    root.present().map_err(|e| err(e.to_string()))
}

/// One point of the data-scaling curve (paper Fig. 5): the SR of a model trained on
/// `fraction` of the training scenes, for one scenario class or (`None`) over all classes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScalingPoint {
    pub fraction: f64,
    pub scenario: Option<ScenarioClass>,
    pub sr: f64,
    /// Standard error of `sr` (drawn as shading around the all-class curve).
    pub sr_se: f64,
}

/// The scaling points of one method on one suite from benchmark rows of several trainings,
/// each given as `(fraction of the training scenes, rows)`: per class and over all classes.
pub fn scaling_points(
    runs: &[(f64, Vec<ResultRow>)],
    suite: &str,
    method: &str,
) -> Vec<ScalingPoint> {
    let mut out = Vec::new();
    for (fraction, rows) in runs {
        let pick = |c: Option<ScenarioClass>| {
            summarize(rows.iter().filter(|r| {
                r.suite == suite && r.method == method && c.is_none_or(|c| r.scenario == c)
            }))
        };
        for c in ScenarioClass::ALL.into_iter().map(Some).chain([None]) {
            let s = pick(c);
            if s.n > 0 {
                out.push(ScalingPoint {
                    fraction: *fraction,
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
    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let draw = || -> Result<(), String> {
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(0f64..105f64, 0f64..1.05)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("training data (% of the training scenes)")
            .y_desc("SR")
            .draw()
            .map_err(|e| e.to_string())?;
        let curve = |c: Option<ScenarioClass>| {
            let mut v: Vec<ScalingPoint> =
                points.iter().filter(|p| p.scenario == c).copied().collect();
            v.sort_by(|a, b| a.fraction.total_cmp(&b.fraction));
            v
        };
        for (i, c) in ScenarioClass::ALL.into_iter().enumerate() {
            let v = curve(Some(c));
            let col = colour(i);
            chart
                .draw_series(std::iter::once(PathElement::new(
                    v.iter()
                        .map(|p| (100.0 * p.fraction, p.sr))
                        .collect::<Vec<_>>(),
                    col.mix(0.45).stroke_width(2),
                )))
                .map_err(|e| e.to_string())?
                .label(c.title())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], col.mix(0.45).stroke_width(2))
                });
        }
        let all = curve(None);
        if !all.is_empty() {
            let mut band: Vec<(f64, f64)> = all
                .iter()
                .map(|p| (100.0 * p.fraction, (p.sr + p.sr_se).min(1.0)))
                .collect();
            band.extend(
                all.iter()
                    .rev()
                    .map(|p| (100.0 * p.fraction, (p.sr - p.sr_se).max(0.0))),
            );
            let blue = RGBColor(31, 119, 180);
            chart
                .draw_series(std::iter::once(Polygon::new(band, blue.mix(0.15).filled())))
                .map_err(|e| e.to_string())?;
            chart
                .draw_series(std::iter::once(PathElement::new(
                    all.iter()
                        .map(|p| (100.0 * p.fraction, p.sr))
                        .collect::<Vec<_>>(),
                    BLACK.stroke_width(4),
                )))
                .map_err(|e| e.to_string())?
                .label("all scenarios")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], BLACK.stroke_width(4))
                });
            chart
                .draw_series(
                    all.iter()
                        .map(|p| Circle::new((100.0 * p.fraction, p.sr), 4, BLACK.filled())),
                )
                .map_err(|e| e.to_string())?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|e| e.to_string())?;
        Ok(())
    };
    draw().map_err(&err)?;
    root.present().map_err(|e| err(e.to_string()))
}
