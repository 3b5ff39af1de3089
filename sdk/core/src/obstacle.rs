//! Static obstacles: circles, polygons and line segments, and occupancy grids, with the signed
//! distances the planner's selection and the simulator's collision check use.
//!
//! An [`Obstacle`] lives in the frame of the [`Observation`](crate::Observation) (or of the
//! episode) that holds it. Distances are signed: negative inside a circle or polygon (minus the
//! depth), never negative for a segment (a wall of no thickness). An [`OccupancyGrid`] in the
//! layout of `nav_msgs/OccupancyGrid` is turned into obstacles near the robot, one covering
//! circle per occupied cell ([`OccupancyGrid::obstacles_near`]).

use crate::robot::footprint::{self, FootprintShape};
use crate::se2::Pose2;
use serde::{Deserialize, Serialize};

/// Largest number of vertices of one polygon.
pub const MAX_POLYGON_VERTICES: usize = 4096;

/// Largest number of cells of an occupancy grid (a 4000 × 4000 map: 200 m square at 5 cm).
pub const MAX_GRID_CELLS: usize = 16_000_000;

/// Largest `|coordinate|` of an obstacle (m), the same bound as a dataset's coordinates.
pub const MAX_OBSTACLE_COORDINATE: f64 = 1e6;

/// A static obstacle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Obstacle {
    /// A disc: a pillar, a bin, a standing person who does not move.
    Circle {
        /// Centre `[x, y]`, m.
        center: [f64; 2],
        /// Radius, m (≥ 0).
        radius: f64,
    },
    /// A simple polygon (either orientation, closed implicitly): a table, a parked cart.
    Polygon {
        /// At least three vertices `[x, y]`, m.
        vertices: Vec<[f64; 2]>,
    },
    /// A line segment: a wall or a railing (no thickness).
    Segment {
        /// One end `[x, y]`, m.
        a: [f64; 2],
        /// The other end `[x, y]`, m.
        b: [f64; 2],
    },
}

/// Distance from `p` to the segment `a`–`b`.
pub fn point_segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let [x, y] = from_segment(p, a, b);
    x.hypot(y)
}

/// The vector from the point of the segment `a`–`b` closest to `p` to `p`.
fn from_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let s = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    [p[0] - a[0] - s * dx, p[1] - a[1] - s * dy]
}

fn cross(o: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
}

/// True when the segments `p`–`q` and `r`–`s` share a point (touching counts).
pub fn segments_intersect(p: [f64; 2], q: [f64; 2], r: [f64; 2], s: [f64; 2]) -> bool {
    let (d1, d2) = (cross(r, s, p), cross(r, s, q));
    let (d3, d4) = (cross(p, q, r), cross(p, q, s));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    let on = |a: [f64; 2], b: [f64; 2], c: [f64; 2], d: f64| {
        d == 0.0
            && c[0] >= a[0].min(b[0])
            && c[0] <= a[0].max(b[0])
            && c[1] >= a[1].min(b[1])
            && c[1] <= a[1].max(b[1])
    };
    on(r, s, p, d1) || on(r, s, q, d2) || on(p, q, r, d3) || on(p, q, s, d4)
}

/// Whether `p` is inside the polygon (even-odd rule; a point on an edge may go either way).
pub fn point_in_polygon(p: [f64; 2], vertices: &[[f64; 2]]) -> bool {
    let mut inside = false;
    let n = vertices.len();
    for i in 0..n {
        let (a, b) = (vertices[i], vertices[(i + 1) % n]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
    }
    inside
}

/// The first pair of edges `(i, j)`, `i < j`, of the closed polygon that meet although they
/// are not neighbours (edge `k` runs from `vertices[k]` to the next vertex), or neighbours that
/// fold back over each other; `None` for a simple polygon. Every pair is tested: O(n²), at most
/// 8 million tests at [`MAX_POLYGON_VERTICES`].
pub fn self_intersection(vertices: &[[f64; 2]]) -> Option<(usize, usize)> {
    let n = vertices.len();
    let edge = |k: usize| (vertices[k], vertices[(k + 1) % n]);
    for i in 0..n {
        let (p, q) = edge(i);
        for j in i + 1..n {
            let (r, s) = edge(j);
            let neighbours = j == i + 1 || (i == 0 && j == n - 1);
            if !neighbours {
                if segments_intersect(p, q, r, s) {
                    return Some((i, j));
                }
                continue;
            }
            // Neighbours share a vertex; they overlap only when collinear and turning back.
            let (shared, a, b) = if j == i + 1 { (q, p, s) } else { (p, q, r) };
            let (u, v) = (
                [a[0] - shared[0], a[1] - shared[1]],
                [b[0] - shared[0], b[1] - shared[1]],
            );
            if u[0] * v[1] - u[1] * v[0] == 0.0 && u[0] * v[0] + u[1] * v[1] > 0.0 {
                return Some((i, j));
            }
        }
    }
    None
}

/// The polygon's edges as `(a, b)` pairs, the last closing it.
fn edges(vertices: &[[f64; 2]]) -> impl Iterator<Item = ([f64; 2], [f64; 2])> + '_ {
    let n = vertices.len();
    (0..n).map(move |i| (vertices[i], vertices[(i + 1) % n]))
}

/// The obstacles of `obstacles` within `range` (signed distance) of `p`, cloned: what a robot
/// at `p` sees of a static scene.
pub fn within(obstacles: &[Obstacle], p: [f64; 2], range: f64) -> Vec<Obstacle> {
    obstacles
        .iter()
        .filter(|o| o.distance(p) <= range)
        .cloned()
        .collect()
}

impl Obstacle {
    /// Checks the numbers: finite, within [`MAX_OBSTACLE_COORDINATE`] m, a radius ≥ 0, a polygon
    /// of 3 to [`MAX_POLYGON_VERTICES`] vertices. The error says what is wrong.
    pub fn validate(&self) -> Result<(), String> {
        let point = |what: &str, p: &[f64; 2]| {
            if p.iter()
                .all(|v| v.is_finite() && v.abs() <= MAX_OBSTACLE_COORDINATE)
            {
                Ok(())
            } else {
                Err(format!(
                    "{what} {p:?} is not finite or beyond {MAX_OBSTACLE_COORDINATE} m"
                ))
            }
        };
        match self {
            Obstacle::Circle { center, radius } => {
                point("center", center)?;
                if !(radius.is_finite() && *radius >= 0.0 && *radius <= MAX_OBSTACLE_COORDINATE) {
                    return Err(format!("radius {radius} must be finite and ≥ 0"));
                }
                Ok(())
            }
            Obstacle::Polygon { vertices } => {
                if !(3..=MAX_POLYGON_VERTICES).contains(&vertices.len()) {
                    return Err(format!(
                        "a polygon needs 3 to {MAX_POLYGON_VERTICES} vertices, this one has {}",
                        vertices.len()
                    ));
                }
                for (i, v) in vertices.iter().enumerate() {
                    point(&format!("vertices[{i}]"), v)?;
                }
                let n = vertices.len();
                if let Some(k) = (0..n).find(|&k| vertices[k] == vertices[(k + 1) % n]) {
                    return Err(format!(
                        "vertices[{}] repeats vertices[{k}]: an edge of length 0 (the polygon \
                         closes itself; do not repeat the first vertex)",
                        (k + 1) % n
                    ));
                }
                match self_intersection(vertices) {
                    Some((i, j)) => Err(format!(
                        "not a simple polygon: edge {i} (vertices[{i}]–vertices[{}]) meets edge \
                         {j} (vertices[{j}]–vertices[{}])",
                        (i + 1) % vertices.len(),
                        (j + 1) % vertices.len()
                    )),
                    None => Ok(()),
                }
            }
            Obstacle::Segment { a, b } => {
                point("a", a)?;
                point("b", b)
            }
        }
    }

    /// Signed distance from `p` to the obstacle: positive outside, negative inside a circle or
    /// polygon (minus the depth), the plain distance for a segment.
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        match self {
            Obstacle::Circle { center, radius } => {
                (p[0] - center[0]).hypot(p[1] - center[1]) - radius
            }
            Obstacle::Segment { a, b } => point_segment_distance(p, *a, *b),
            Obstacle::Polygon { vertices } => {
                let d = edges(vertices)
                    .map(|(a, b)| point_segment_distance(p, a, b))
                    .fold(f64::INFINITY, f64::min);
                if point_in_polygon(p, vertices) { -d } else { d }
            }
        }
    }

    /// Whether every point of the obstacle is farther than `r` (≥ 0) from `p`, decided without
    /// a square root: `false` when it is not, and where the test is too coarse to tell (a
    /// polygon is judged by its bounding box) or a coordinate is not finite. A broad phase:
    /// an obstacle this rejects is farther than `r` from `p` up to rounding.
    pub fn farther_than(&self, p: [f64; 2], r: f64) -> bool {
        let beyond = |[x, y]: [f64; 2], r: f64| x * x + y * y > r * r;
        match self {
            Obstacle::Circle { center, radius } => {
                beyond([p[0] - center[0], p[1] - center[1]], r + radius)
            }
            Obstacle::Segment { a, b } => beyond(from_segment(p, *a, *b), r),
            Obstacle::Polygon { vertices } => {
                let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
                for v in vertices {
                    for k in 0..2 {
                        lo[k] = lo[k].min(v[k]);
                        hi[k] = hi[k].max(v[k]);
                    }
                }
                let gap = |k: usize| (lo[k] - p[k]).max(p[k] - hi[k]).max(0.0);
                beyond([gap(0), gap(1)], r)
            }
        }
    }

    /// The obstacle with every point mapped by `f` (a rigid motion: radii are kept).
    pub fn map_points(&self, f: impl Fn([f64; 2]) -> [f64; 2]) -> Obstacle {
        match self {
            Obstacle::Circle { center, radius } => Obstacle::Circle {
                center: f(*center),
                radius: *radius,
            },
            Obstacle::Polygon { vertices } => Obstacle::Polygon {
                vertices: vertices.iter().map(|v| f(*v)).collect(),
            },
            Obstacle::Segment { a, b } => Obstacle::Segment { a: f(*a), b: f(*b) },
        }
    }

    /// The obstacle seen from `frame`: points given in the frame `frame` sits in, returned in
    /// `frame`'s own coordinates (e.g. world → ego with the ego pose).
    pub fn in_frame(&self, frame: Pose2) -> Obstacle {
        // The heading's sine and cosine once, not per point.
        let turn = frame.theta.sin_cos();
        self.map_points(|p| frame.inverse_act_turned(turn, p))
    }

    /// Signed clearance between one footprint shape (base-link frame) and this obstacle given
    /// in the same frame: negative when they overlap (then the value says only that).
    fn shape_clearance(&self, shape: &FootprintShape) -> f64 {
        match *shape {
            FootprintShape::Disc { center, radius } => self.distance(center) - radius,
            FootprintShape::Rect { center, half, yaw } => {
                let corners = footprint::rect_corners(center, half, yaw);
                match self {
                    Obstacle::Circle { center, radius } => shape.signed_distance(*center) - radius,
                    Obstacle::Segment { a, b } => rect_segment_clearance(shape, &corners, *a, *b),
                    Obstacle::Polygon { vertices } => {
                        if corners.iter().any(|c| point_in_polygon(*c, vertices)) {
                            return -f64::EPSILON;
                        }
                        edges(vertices)
                            .map(|(a, b)| rect_segment_clearance(shape, &corners, a, b))
                            .fold(f64::INFINITY, f64::min)
                    }
                }
            }
        }
    }
}

/// Clearance between a rectangle (its shape and corners) and a segment: negative when they
/// touch or overlap, else the exact distance (reached at a corner or a segment end).
fn rect_segment_clearance(
    rect: &FootprintShape,
    corners: &[[f64; 2]; 4],
    a: [f64; 2],
    b: [f64; 2],
) -> f64 {
    let (da, db) = (rect.signed_distance(a), rect.signed_distance(b));
    let crosses = (0..corners.len())
        .any(|k| segments_intersect(corners[k], corners[(k + 1) % corners.len()], a, b));
    if da <= 0.0 || db <= 0.0 || crosses {
        return da.min(db).min(-f64::EPSILON);
    }
    smallest_norm(corners.iter().map(|c| from_segment(*c, a, b)), da.min(db))
}

/// Relative width of the shell around a distance within which comparing squared distances
/// does not decide a comparison of the distances themselves (far wider than the rounding of
/// either).
pub const SHELL: f64 = 1e-9;

/// The smallest of `start` and the lengths (`hypot`) of `vectors`, to the bit, with the square
/// root taken only of the vectors whose squared length comes within [`SHELL`] of the smallest
/// (the others cannot be it). Non-finite lengths are passed over, as `f64::min` does.
pub(crate) fn smallest_norm(vectors: impl Iterator<Item = [f64; 2]> + Clone, start: f64) -> f64 {
    let squared = |[x, y]: [f64; 2]| x * x + y * y;
    let bound = vectors.clone().map(squared).fold(f64::INFINITY, f64::min) * (1.0 + SHELL);
    vectors
        .filter(|&v| squared(v) <= bound)
        .map(|[x, y]| x.hypot(y))
        .fold(start, f64::min)
}

/// The clearance between a footprint placed at `pose` and `obstacle` (both in the same
/// frame): the smallest over the footprint's shapes, negative on overlap, `+∞` for an empty
/// footprint.
pub fn footprint_clearance(shapes: &[FootprintShape], pose: Pose2, obstacle: &Obstacle) -> f64 {
    let local = obstacle.in_frame(pose);
    shapes
        .iter()
        .map(|s| local.shape_clearance(s))
        .fold(f64::INFINITY, f64::min)
}

/// Value of an occupied cell from which on a cell is an obstacle (the `nav_msgs` scale: 0 free,
/// 100 occupied, −1 unknown). 65, as ROS's map server's `occupied_thresh` of 0.65.
pub const DEFAULT_OCCUPIED_THRESHOLD: i8 = 65;

fn default_occupied_threshold() -> i8 {
    DEFAULT_OCCUPIED_THRESHOLD
}

/// An occupancy grid in the layout of `nav_msgs/OccupancyGrid`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OccupancyGrid {
    /// Pose of the corner of cell `(0, 0)` in the observation's frame (`info.origin`); cell
    /// `(col, row)` covers `[col, col + 1) × [row, row + 1)` cell edges along the grid's axes.
    pub origin: Pose2,
    /// Cell edge, m (> 0).
    pub resolution: f64,
    /// Cells per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major values, `width × height`: −1 unknown, 0 (free) to 100 (occupied). Unknown
    /// cells are treated as free.
    pub data: Vec<i8>,
    /// Cells whose value is at least this are obstacles. Default 65.
    #[serde(default = "default_occupied_threshold")]
    pub occupied_threshold: i8,
}

impl OccupancyGrid {
    /// Checks the shape and numbers; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        if !self.origin.is_finite() {
            return Err("origin is not finite".into());
        }
        if !(self.resolution.is_finite() && self.resolution > 0.0 && self.resolution <= 1e3) {
            return Err(format!(
                "resolution {} must be finite and in (0, 1000] m",
                self.resolution
            ));
        }
        let cells = self
            .width
            .checked_mul(self.height)
            .filter(|&c| c <= MAX_GRID_CELLS);
        match cells {
            None => Err(format!(
                "{} × {} cells is more than the limit of {MAX_GRID_CELLS}",
                self.width, self.height
            )),
            Some(c) if c != self.data.len() => Err(format!(
                "data holds {} values for {} × {} cells",
                self.data.len(),
                self.width,
                self.height
            )),
            Some(_) => Ok(()),
        }
    }

    /// Every occupied cell whose centre lies within `range` of `center` (observation frame),
    /// as the circle that covers the cell (radius `resolution/√2`): conservative, so a contact
    /// is never missed.
    pub fn obstacles_near(&self, center: [f64; 2], range: f64) -> Vec<Obstacle> {
        let r = self.resolution;
        let local = self.origin.inverse_act(center);
        let reach = range + r;
        let span = |c: f64, n: usize| {
            let lo = ((c - reach) / r).floor().max(0.0);
            let hi = ((c + reach) / r).ceil().min(n as f64);
            (lo as usize, hi.max(lo) as usize)
        };
        let (c0, c1) = span(local[0], self.width);
        let (r0, r1) = span(local[1], self.height);
        let mut out = Vec::new();
        for row in r0..r1 {
            for col in c0..c1 {
                if self.data[row * self.width + col] < self.occupied_threshold {
                    continue;
                }
                let p = [(col as f64 + 0.5) * r, (row as f64 + 0.5) * r];
                if (p[0] - local[0]).hypot(p[1] - local[1]) <= range {
                    out.push(Obstacle::Circle {
                        center: self.origin.act(p),
                        radius: r * std::f64::consts::FRAC_1_SQRT_2,
                    });
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(c: [f64; 2], h: f64) -> Obstacle {
        Obstacle::Polygon {
            vertices: vec![
                [c[0] - h, c[1] - h],
                [c[0] + h, c[1] - h],
                [c[0] + h, c[1] + h],
                [c[0] - h, c[1] + h],
            ],
        }
    }

    #[test]
    fn only_simple_polygons_pass_validation() {
        let poly = |v: &[[f64; 2]]| Obstacle::Polygon {
            vertices: v.to_vec(),
        };
        assert_eq!(square([0.0, 0.0], 1.0).validate(), Ok(()));
        // A concave L and a triangle are simple.
        let l = [
            [0.0, 0.0],
            [2.0, 0.0],
            [2.0, 1.0],
            [1.0, 1.0],
            [1.0, 2.0],
            [0.0, 2.0],
        ];
        assert_eq!(poly(&l).validate(), Ok(()));
        assert_eq!(
            poly(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]).validate(),
            Ok(())
        );
        // A bow tie: edges 0 and 2 cross.
        let bow = poly(&[[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]);
        let why = bow.validate().unwrap_err();
        assert!(
            why.contains("not a simple polygon") && why.contains("edge 0"),
            "{why}"
        );
        // Two neighbouring edges folding back over each other.
        let fold = poly(&[[0.0, 0.0], [2.0, 0.0], [1.0, 0.0], [1.0, 1.0]]);
        assert!(fold.validate().unwrap_err().contains("edge 0"));
        // Touching itself at a vertex.
        let touch = poly(&[
            [0.0, 0.0],
            [2.0, 0.0],
            [1.0, 1.0],
            [2.0, 2.0],
            [0.0, 2.0],
            [1.0, 1.0],
        ]);
        assert!(
            touch
                .validate()
                .unwrap_err()
                .contains("not a simple polygon")
        );
        // The first vertex repeated at the end.
        let closed = poly(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]);
        let why = closed.validate().unwrap_err();
        assert!(why.contains("vertices[0] repeats vertices[3]"), "{why}");
    }

    #[test]
    fn signed_distances_of_each_kind() {
        let circle = Obstacle::Circle {
            center: [1.0, 0.0],
            radius: 0.5,
        };
        assert!((circle.distance([3.0, 0.0]) - 1.5).abs() < 1e-12);
        assert!((circle.distance([1.0, 0.0]) + 0.5).abs() < 1e-12);
        let wall = Obstacle::Segment {
            a: [0.0, 1.0],
            b: [4.0, 1.0],
        };
        assert!((wall.distance([2.0, 0.0]) - 1.0).abs() < 1e-12);
        assert!((wall.distance([6.0, 1.0]) - 2.0).abs() < 1e-12);
        let sq = square([0.0, 0.0], 1.0);
        assert!((sq.distance([3.0, 0.0]) - 2.0).abs() < 1e-12);
        assert!((sq.distance([0.5, 0.0]) + 0.5).abs() < 1e-12);
    }

    /// `farther_than` never rejects an obstacle within `r` of the point (it is the broad
    /// phase of the clearance term, which must not lose a pair that matters), and does
    /// reject those well beyond it, by the obstacle's own distance.
    #[test]
    fn farther_than_rejects_only_what_is_beyond() {
        let obstacles = [
            Obstacle::Circle {
                center: [1.0, -0.5],
                radius: 0.4,
            },
            Obstacle::Segment {
                a: [-2.0, 1.0],
                b: [3.0, 2.5],
            },
            Obstacle::Segment {
                a: [0.5, 0.5],
                b: [0.5, 0.5],
            },
            square([-1.0, -1.5], 0.7),
            Obstacle::Polygon {
                vertices: vec![[0.0, 0.0], [4.0, 0.0], [0.0, 3.0]],
            },
        ];
        let r = 0.8;
        let mut rejected = [0usize; 5];
        for i in 0..=80 {
            for j in 0..=80 {
                let p = [-4.0 + 0.1 * i as f64, -4.0 + 0.1 * j as f64];
                for (k, o) in obstacles.iter().enumerate() {
                    let d = o.distance(p);
                    if o.farther_than(p, r) {
                        assert!(d > r - 1e-12, "{o:?} at {p:?}: distance {d}");
                        rejected[k] += 1;
                    } else if !matches!(o, Obstacle::Polygon { .. }) {
                        // Exact for discs and segments.
                        assert!(d <= r + 1e-12, "{o:?} at {p:?}: distance {d}");
                    }
                }
            }
        }
        assert!(rejected.iter().all(|&n| n > 1000), "{rejected:?}");
        let nan = [f64::NAN, 0.0];
        assert!(obstacles.iter().all(|o| !o.farther_than(nan, r)));
    }

    #[test]
    fn footprint_clearance_of_a_disc_and_a_box() {
        let disc = [FootprintShape::Disc {
            center: [0.0, 0.0],
            radius: 0.3,
        }];
        let wall = Obstacle::Segment {
            a: [-5.0, 1.0],
            b: [5.0, 1.0],
        };
        let at = |x, y, th| Pose2::new(x, y, th);
        assert!((footprint_clearance(&disc, at(0.0, 0.0, 0.0), &wall) - 0.7).abs() < 1e-12);
        assert!(footprint_clearance(&disc, at(0.0, 0.8, 0.0), &wall) < 0.0);

        // A 1.0 × 0.4 box: facing along the wall it clears it by 0.8, turned across it by 0.5.
        let boxy = [FootprintShape::Rect {
            center: [0.0, 0.0],
            half: [0.5, 0.2],
            yaw: 0.0,
        }];
        let along = footprint_clearance(&boxy, at(0.0, 0.0, 0.0), &wall);
        let across = footprint_clearance(&boxy, at(0.0, 0.0, std::f64::consts::FRAC_PI_2), &wall);
        assert!((along - 0.8).abs() < 1e-12, "{along}");
        assert!((across - 0.5).abs() < 1e-12, "{across}");
        // The wall passes through the box without touching a corner.
        assert!(footprint_clearance(&boxy, at(0.0, 1.0, 0.0), &wall) < 0.0);
        // A pillar inside the box, and a box inside a big polygon.
        let pillar = square([0.1, 0.0], 0.05);
        assert!(footprint_clearance(&boxy, at(0.0, 0.0, 0.0), &pillar) < 0.0);
        let hall = square([0.0, 0.0], 10.0);
        assert!(footprint_clearance(&boxy, at(0.0, 0.0, 0.0), &hall) < 0.0);
        let far = square([3.0, 0.0], 0.5);
        let d = footprint_clearance(&boxy, at(0.0, 0.0, 0.0), &far);
        assert!((d - 2.0).abs() < 1e-12, "{d}");
    }

    #[test]
    fn an_occupancy_grid_gives_the_occupied_cells_near_a_point() {
        // 10 × 10 cells of 0.1 m at (1, 1) turned by 90°; cells (2, 3) and (9, 9) occupied.
        let mut data = vec![0i8; 100];
        data[3 * 10 + 2] = 100;
        data[9 * 10 + 9] = 70;
        data[0] = -1;
        let grid = OccupancyGrid {
            origin: Pose2::new(1.0, 1.0, std::f64::consts::FRAC_PI_2),
            resolution: 0.1,
            width: 10,
            height: 10,
            data,
            occupied_threshold: DEFAULT_OCCUPIED_THRESHOLD,
        };
        grid.validate().unwrap();
        // Cell (2, 3)'s centre (0.25, 0.35) in the grid is (1 − 0.35, 1 + 0.25) outside it.
        let near = grid.obstacles_near([0.65, 1.25], 0.05);
        assert_eq!(near.len(), 1);
        let Obstacle::Circle { center, radius } = &near[0] else {
            panic!("a circle")
        };
        assert!((center[0] - 0.65).abs() < 1e-12 && (center[1] - 1.25).abs() < 1e-12);
        assert!((radius - 0.1 / 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(grid.obstacles_near([0.65, 1.25], 2.0).len(), 2);
        assert!(grid.obstacles_near([50.0, 50.0], 1.0).is_empty());
        let bad = OccupancyGrid {
            data: vec![0; 3],
            ..grid.clone()
        };
        assert!(bad.validate().unwrap_err().contains("data holds 3"));
    }

    #[test]
    fn bad_obstacles_are_refused_with_the_reason() {
        let two = Obstacle::Polygon {
            vertices: vec![[0.0, 0.0], [1.0, 0.0]],
        };
        assert!(two.validate().unwrap_err().contains("3 to"));
        let nan = Obstacle::Segment {
            a: [f64::NAN, 0.0],
            b: [1.0, 0.0],
        };
        assert!(nan.validate().unwrap_err().contains("a "));
        let negative = Obstacle::Circle {
            center: [0.0, 0.0],
            radius: -1.0,
        };
        assert!(negative.validate().unwrap_err().contains("radius"));
    }
}
