//! Shapes the pictures share: static obstacles, discs, footprints, stars and arrow heads.

use super::text_err;
use human2nav_core::Pose2;
use human2nav_core::obstacle::Obstacle;
use human2nav_core::robot::footprint::FootprintShape;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

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
pub(super) fn arrow_head(from: (f64, f64), to: (f64, f64), len: f64) -> Vec<(f64, f64)> {
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
