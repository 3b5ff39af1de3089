//! The planner's BEV raster drawn as a picture: occupied cells coloured by the direction of
//! their velocity, velocity arrows, the robot and the hue wheel.

use super::{Area, EGO_RED, arrow};
use human2nav_core::bev::{self, BevSpec};
use human2nav_core::{AgentState, Pose2};
use plotters::prelude::*;

/// The colour of one occupied BEV cell with ego-frame velocity `(vx, vy)`.
pub(super) fn velocity_colour(vx: f32, vy: f32) -> RGBColor {
    let speed = f64::from(vx).hypot(f64::from(vy));
    if speed < 0.1 {
        return RGBColor(70, 70, 70);
    }
    // Hue by direction in the image (forward = up): angle measured from "forward".
    let hue = (f64::from(vy).atan2(f64::from(vx)) / std::f64::consts::TAU).rem_euclid(1.0);
    let sat = (0.35 + 0.65 * (speed / 1.5).min(1.0)).min(1.0);
    let (r, g, b) = hsl_to_rgb(hue, sat, 0.45);
    RGBColor(r, g, b)
}

fn hsl_to_rgb(h: f64, s: f64, l: f64) -> (u8, u8, u8) {
    let c = (1.0 - (2.0 * l - 1.0).abs()) * s;
    let hp = h * 6.0;
    let x = c * (1.0 - (hp.rem_euclid(2.0) - 1.0).abs());
    let (r, g, b) = match hp as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = l - 0.5 * c;
    let to = |v: f64| ((v + m) * 255.0).round().clamp(0.0, 255.0) as u8;
    (to(r), to(g), to(b))
}

/// The planner's BEV raster of `agents` around `ego` drawn into `area` (see the module docs:
/// free cells light grey, occupied cells coloured by the direction of their velocity, black
/// velocity arrows, the robot as a red triangle, the hue wheel in the corner), under a
/// `label` line of `label_px` pixels.
pub(crate) fn draw_bev_raster<'b>(
    area: &Area<'b>,
    spec: BevSpec,
    ego: Pose2,
    agents: &[AgentState],
    label: &str,
    label_px: u32,
) -> Result<(), DrawingAreaErrorKind<<BitMapBackend<'b> as DrawingBackend>::ErrorType>> {
    let n = spec.cells;
    let mut raster = vec![0f32; spec.len()];
    bev::rasterize(spec, ego, agents, &mut raster);

    area.fill(&WHITE)?;
    let (w, h) = area.dim_in_pixel();
    let (label_area, grid) = area.split_vertically(label_px + 9);
    label_area.draw(&Text::new(
        label.to_string(),
        (3, 4),
        ("sans-serif", label_px).into_font().color(&BLACK),
    ))?;
    let nf = n as f64;
    // x = column (left of the ego is column 0), y = nf − row (row 0 is farthest ahead).
    let grid = ChartBuilder::on(&grid)
        .margin(1)
        .build_cartesian_2d(0.0..nf, 0.0..nf)?
        .plotting_area()
        .clone();
    let plane = n * n;
    for row in 0..n {
        for col in 0..n {
            let k = row * n + col;
            let colour = if raster[k] > 0.5 {
                velocity_colour(raster[plane + k], raster[2 * plane + k])
            } else {
                RGBColor(240, 240, 240)
            };
            let (x, y) = (col as f64, nf - row as f64);
            grid.draw(&Rectangle::new(
                [(x, y - 1.0), (x + 1.0, y)],
                colour.filled(),
            ))?;
        }
    }
    // Ego-frame point → inset coordinates.
    let to_grid = |p: [f64; 2]| {
        let r = (spec.ahead() - p[0]) / spec.resolution;
        let c = (spec.half_width() - p[1]) / spec.resolution;
        (c, nf - r)
    };
    let in_grid = |q: (f64, f64)| q.0 >= 0.0 && q.0 <= nf && q.1 >= 0.0 && q.1 <= nf;
    for a in agents {
        let p = ego.inverse_act(a.position);
        let v = ego.inverse_rotate(a.velocity);
        let from = to_grid(p);
        let to = to_grid([p[0] + 0.6 * v[0], p[1] + 0.6 * v[1]]);
        if !in_grid(from) {
            continue;
        }
        let (shaft, head) = arrow(from, to, 0.8);
        grid.draw(&PathElement::new(shaft, BLACK.stroke_width(1)))?;
        if !head.is_empty() {
            grid.draw(&Polygon::new(head, BLACK.filled()))?;
        }
    }
    // The robot: a red triangle pointing forward (up).
    let (ex, ey) = to_grid([0.0, 0.0]);
    let s = (0.35 / spec.resolution).max(0.8);
    grid.draw(&Polygon::new(
        vec![
            (ex, ey + s),
            (ex - 0.7 * s, ey - 0.7 * s),
            (ex + 0.7 * s, ey - 0.7 * s),
        ],
        EGO_RED.filled(),
    ))?;
    // Colour wheel of the velocity hue, bottom-right corner of the inset.
    let (wc, wr) = (nf - 3.2, 3.2);
    for i in 0..24 {
        let a0 = std::f64::consts::TAU * i as f64 / 24.0;
        let a1 = std::f64::consts::TAU * (i + 1) as f64 / 24.0;
        // Image direction for ego-frame heading a: forward (a = 0) is up, left (a = π/2) is
        // to the left.
        let pt = |a: f64, r: f64| (wc - r * a.sin(), wr + r * a.cos());
        let colour = velocity_colour(a0.cos() as f32 * 1.5, a0.sin() as f32 * 1.5);
        grid.draw(&Polygon::new(
            vec![pt(a0, 0.0), pt(a0, 2.4), pt(a1, 2.4)],
            colour.filled(),
        ))?;
    }
    area.draw(&Rectangle::new(
        [(0, 0), (w as i32 - 1, h as i32 - 1)],
        RGBColor(120, 120, 120).stroke_width(1),
    ))?;
    Ok(())
}
