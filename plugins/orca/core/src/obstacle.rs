//! Static obstacles with the semantics of the RVO2 library (`Agent::computeNewVelocity`'s
//! obstacle part, `KdTree::queryObstacleTree`): the observation's obstacles become RVO2
//! obstacles (polygons of linked vertices, counterclockwise), and each obstacle edge the agent
//! can see within range gives one ORCA line for which the agent takes full responsibility.
//! These lines come before the agents' lines and are never relaxed by the linear program.
//!
//! Conversions: a polygon keeps its vertices (made counterclockwise); a segment is RVO2's
//! two-vertex obstacle (both sides are edges); a circle becomes the regular polygon of
//! [`CIRCLE_SIDES`] sides that contains it. The occupancy grid is not used.

use crate::lp::{EPSILON, Line, Vec2};
use human2nav_core::obstacle::Obstacle;

/// Sides of the polygon a circular obstacle becomes (it contains the circle).
pub const CIRCLE_SIDES: usize = 12;

/// One vertex of an RVO2 obstacle: the edge from it to `next` is an obstacle edge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vertex {
    pub point: Vec2,
    /// Unit vector from this vertex to the next one.
    pub unit_dir: Vec2,
    /// Whether the obstacle is convex at this vertex (always true for a two-vertex obstacle).
    pub convex: bool,
    pub next: usize,
    pub prev: usize,
}

/// The obstacles of one observation as RVO2 vertices.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Obstacles {
    pub vertices: Vec<Vertex>,
}

/// `det(b − a, c − a)`: positive when `c` lies left of the line from `a` to `b`.
fn left_of(a: Vec2, b: Vec2, c: Vec2) -> f64 {
    (a - c).det(b - a)
}

/// Squared distance from `c` to the segment `[a, b]`.
fn dist_sq_point_segment(a: Vec2, b: Vec2, c: Vec2) -> f64 {
    let ab = b - a;
    let len_sq = ab.norm_sq();
    let r = if len_sq > 0.0 {
        ((c - a).dot(ab) / len_sq).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (c - (a + ab * r)).norm_sq()
}

impl Obstacles {
    /// The observation's obstacles as RVO2 obstacles (see the module docs). Degenerate ones (a
    /// zero-length segment, a polygon of zero area, a circle of zero radius) are skipped.
    pub fn from_observation(obstacles: &[Obstacle]) -> Self {
        let mut set = Self::default();
        for o in obstacles {
            match o {
                Obstacle::Circle { center, radius } if *radius > 0.0 => {
                    let r = radius / (std::f64::consts::PI / CIRCLE_SIDES as f64).cos();
                    let points: Vec<Vec2> = (0..CIRCLE_SIDES)
                        .map(|k| {
                            let a = 2.0 * std::f64::consts::PI * k as f64 / CIRCLE_SIDES as f64;
                            Vec2::new(center[0] + r * a.cos(), center[1] + r * a.sin())
                        })
                        .collect();
                    set.add(&points);
                }
                Obstacle::Segment { a, b } if a != b => {
                    set.add(&[Vec2::from_array(*a), Vec2::from_array(*b)]);
                }
                Obstacle::Polygon { vertices } => {
                    let mut points: Vec<Vec2> =
                        vertices.iter().map(|&v| Vec2::from_array(v)).collect();
                    let area2: f64 = (0..points.len())
                        .map(|i| points[i].det(points[(i + 1) % points.len()]))
                        .sum();
                    if area2 == 0.0 || !area2.is_finite() {
                        continue;
                    }
                    if area2 < 0.0 {
                        points.reverse();
                    }
                    set.add(&points);
                }
                _ => {}
            }
        }
        set
    }

    /// RVO2's `addObstacle`: links `points` (counterclockwise, or two points) into vertices.
    fn add(&mut self, points: &[Vec2]) {
        let n = points.len();
        let first = self.vertices.len();
        for i in 0..n {
            let next = (i + 1) % n;
            let prev = (i + n - 1) % n;
            let convex = n == 2 || left_of(points[prev], points[i], points[next]) >= 0.0;
            self.vertices.push(Vertex {
                point: points[i],
                unit_dir: (points[next] - points[i]).normalized(),
                convex,
                next: first + next,
                prev: first + prev,
            });
        }
    }

    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// The obstacle edges an agent at `position` sees within `range` (m): those it is strictly
    /// right of (outside a counterclockwise polygon), closest first (RVO2's obstacle query).
    pub fn neighbors(&self, position: Vec2, range: f64) -> Vec<usize> {
        let range_sq = range * range;
        let mut found: Vec<(f64, usize)> = self
            .vertices
            .iter()
            .enumerate()
            .filter_map(|(i, v)| {
                let b = self.vertices[v.next].point;
                if left_of(v.point, b, position) >= 0.0 {
                    return None;
                }
                let d = dist_sq_point_segment(v.point, b, position);
                (d < range_sq).then_some((d, i))
            })
            .collect();
        found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        found.into_iter().map(|(_, i)| i).collect()
    }

    /// The ORCA lines of the obstacles for an agent (`position`, `velocity`, `radius`) with time
    /// horizon `time_horizon` (s) and maximal speed `max_speed` (m/s): RVO2's obstacle part of
    /// `computeNewVelocity`, edge by edge, closest first, skipping edges whose velocity
    /// obstacle the lines so far already cover.
    pub fn lines(
        &self,
        position: Vec2,
        velocity: Vec2,
        radius: f64,
        time_horizon: f64,
        max_speed: f64,
    ) -> Vec<Line> {
        let inv_tau = 1.0 / time_horizon;
        let mut lines: Vec<Line> = Vec::new();
        let range = time_horizon * max_speed + radius;
        for first in self.neighbors(position, range) {
            if let Some(line) = self.edge_line(first, position, velocity, radius, inv_tau, &lines) {
                lines.push(line);
            }
        }
        lines
    }

    /// The ORCA line of the edge starting at vertex `first`, or `None` when the lines so far
    /// cover its velocity obstacle or it adds no constraint.
    fn edge_line(
        &self,
        first: usize,
        position: Vec2,
        velocity: Vec2,
        radius: f64,
        inv_tau: f64,
        lines: &[Line],
    ) -> Option<Line> {
        let mut o1 = &self.vertices[first];
        let mut o2 = &self.vertices[o1.next];
        let rel1 = o1.point - position;
        let rel2 = o2.point - position;
        // Already covered by an earlier line: both cut-off centres lie far enough on its
        // permitted side.
        let covered = lines.iter().any(|l| {
            (rel1 * inv_tau - l.point).det(l.direction) - inv_tau * radius >= -EPSILON
                && (rel2 * inv_tau - l.point).det(l.direction) - inv_tau * radius >= -EPSILON
        });
        if covered {
            return None;
        }
        let dist_sq1 = rel1.norm_sq();
        let dist_sq2 = rel2.norm_sq();
        let radius_sq = radius * radius;
        let edge = o2.point - o1.point;
        let s = (-rel1).dot(edge) / edge.norm_sq();
        let dist_sq_line = (-rel1 - edge * s).norm_sq();
        let zero_line = |direction: Vec2| Line {
            point: Vec2::ZERO,
            direction,
        };

        // Already in collision with a vertex or the edge.
        if s < 0.0 && dist_sq1 <= radius_sq {
            return o1
                .convex
                .then(|| zero_line(Vec2::new(-rel1.y, rel1.x).normalized()));
        }
        if s > 1.0 && dist_sq2 <= radius_sq {
            return (o2.convex && rel2.det(o2.unit_dir) >= 0.0)
                .then(|| zero_line(Vec2::new(-rel2.y, rel2.x).normalized()));
        }
        if (0.0..1.0).contains(&s) && dist_sq_line <= radius_sq {
            return Some(zero_line(-o1.unit_dir));
        }

        // No collision: the legs of the velocity obstacle.
        let left_leg = |rel: Vec2, dist_sq: f64| {
            let leg = (dist_sq - radius_sq).sqrt();
            Vec2::new(rel.x * leg - rel.y * radius, rel.x * radius + rel.y * leg) * (1.0 / dist_sq)
        };
        let right_leg = |rel: Vec2, dist_sq: f64| {
            let leg = (dist_sq - radius_sq).sqrt();
            Vec2::new(rel.x * leg + rel.y * radius, -rel.x * radius + rel.y * leg) * (1.0 / dist_sq)
        };
        let (mut left_dir, mut right_dir);
        if s < 0.0 && dist_sq_line <= radius_sq {
            // Seen obliquely from the left: the left vertex defines the velocity obstacle.
            if !o1.convex {
                return None;
            }
            o2 = o1;
            left_dir = left_leg(rel1, dist_sq1);
            right_dir = right_leg(rel1, dist_sq1);
        } else if s > 1.0 && dist_sq_line <= radius_sq {
            // Seen obliquely from the right: the right vertex defines it.
            if !o2.convex {
                return None;
            }
            o1 = o2;
            left_dir = left_leg(rel2, dist_sq2);
            right_dir = right_leg(rel2, dist_sq2);
        } else {
            left_dir = if o1.convex {
                left_leg(rel1, dist_sq1)
            } else {
                // A non-convex left vertex: the left leg continues the cut-off line.
                -o1.unit_dir
            };
            right_dir = if o2.convex {
                right_leg(rel2, dist_sq2)
            } else {
                o1.unit_dir
            };
        }

        // A leg never points into the neighbouring edge: take that edge's line instead (and
        // leave the constraint to that edge).
        let left_neighbor = &self.vertices[o1.prev];
        let mut left_foreign = false;
        let mut right_foreign = false;
        if o1.convex && left_dir.det(-left_neighbor.unit_dir) >= 0.0 {
            left_dir = -left_neighbor.unit_dir;
            left_foreign = true;
        }
        if o2.convex && right_dir.det(o2.unit_dir) <= 0.0 {
            right_dir = o2.unit_dir;
            right_foreign = true;
        }

        // The cut-off line and the projection of the current velocity onto the obstacle.
        let left_cutoff = (o1.point - position) * inv_tau;
        let right_cutoff = (o2.point - position) * inv_tau;
        let cutoff = right_cutoff - left_cutoff;
        let same = std::ptr::eq(o1, o2);
        let t = if same {
            0.5
        } else {
            (velocity - left_cutoff).dot(cutoff) / cutoff.norm_sq()
        };
        let t_left = (velocity - left_cutoff).dot(left_dir);
        let t_right = (velocity - right_cutoff).dot(right_dir);
        let on_circle = |centre: Vec2| {
            let unit_w = (velocity - centre).normalized();
            Line {
                direction: Vec2::new(unit_w.y, -unit_w.x),
                point: centre + unit_w * (radius * inv_tau),
            }
        };
        if (t < 0.0 && t_left < 0.0) || (same && t_left < 0.0 && t_right < 0.0) {
            return Some(on_circle(left_cutoff));
        }
        if t > 1.0 && t_right < 0.0 {
            return Some(on_circle(right_cutoff));
        }
        let dist_cutoff = if !(0.0..=1.0).contains(&t) || same {
            f64::INFINITY
        } else {
            (velocity - (left_cutoff + cutoff * t)).norm_sq()
        };
        let dist_left = if t_left < 0.0 {
            f64::INFINITY
        } else {
            (velocity - (left_cutoff + left_dir * t_left)).norm_sq()
        };
        let dist_right = if t_right < 0.0 {
            f64::INFINITY
        } else {
            (velocity - (right_cutoff + right_dir * t_right)).norm_sq()
        };
        let offset = |d: Vec2| Vec2::new(-d.y, d.x) * (radius * inv_tau);
        if dist_cutoff <= dist_left && dist_cutoff <= dist_right {
            let direction = -o1.unit_dir;
            return Some(Line {
                point: left_cutoff + offset(direction),
                direction,
            });
        }
        if dist_left <= dist_right {
            return (!left_foreign).then(|| Line {
                point: left_cutoff + offset(left_dir),
                direction: left_dir,
            });
        }
        (!right_foreign).then(|| {
            let direction = -right_dir;
            Line {
                point: right_cutoff + offset(direction),
                direction,
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lp;

    /// The agent's velocity after one RVO2 solve with only obstacle lines (all fixed).
    fn new_velocity(obs: &Obstacles, position: Vec2, pref: Vec2, radius: f64) -> Vec2 {
        let lines = obs.lines(position, pref, radius, 5.0, 1.0);
        lp::solve_fixed(&lines, lines.len(), 1.0, pref)
    }

    #[test]
    fn conversions_keep_shapes_counterclockwise_and_circles_inside() {
        let set = Obstacles::from_observation(&[
            Obstacle::Polygon {
                vertices: vec![[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]],
            },
            Obstacle::Segment {
                a: [0.0, 3.0],
                b: [2.0, 3.0],
            },
            Obstacle::Circle {
                center: [5.0, 5.0],
                radius: 1.0,
            },
            Obstacle::Segment {
                a: [1.0, 1.0],
                b: [1.0, 1.0],
            },
        ]);
        assert_eq!(set.vertices.len(), 4 + 2 + CIRCLE_SIDES);
        // The clockwise square was reversed: every vertex convex.
        assert!(set.vertices[..4].iter().all(|v| v.convex));
        assert_eq!(set.vertices[4].next, 5);
        assert_eq!(set.vertices[5].next, 4);
        // Every edge of the circle's polygon stays outside the circle.
        for v in &set.vertices[6..] {
            let b = set.vertices[v.next].point;
            let d = dist_sq_point_segment(v.point, b, Vec2::new(5.0, 5.0)).sqrt();
            assert!(d >= 1.0 - 1e-9, "{d}");
        }
    }

    #[test]
    fn an_agent_heading_into_a_wall_stops_short_of_it() {
        // A wall 1 m ahead across the agent's path, seen from below.
        let wall = Obstacles::from_observation(&[Obstacle::Segment {
            a: [-5.0, 1.0],
            b: [5.0, 1.0],
        }]);
        let v = new_velocity(&wall, Vec2::ZERO, Vec2::new(0.0, 1.0), 0.3);
        // Within the 5 s horizon the agent may close at most the 0.7 m of free space.
        assert!(v.y * 5.0 <= 0.7 + 1e-9, "{v:?}");
        // Moving along the wall is still free.
        let v = new_velocity(&wall, Vec2::ZERO, Vec2::new(1.0, 0.0), 0.3);
        assert!((v.x - 1.0).abs() < 1e-9 && v.y.abs() < 1e-9, "{v:?}");
    }

    #[test]
    fn an_agent_steers_around_a_pillar_in_its_way() {
        let pillar = Obstacles::from_observation(&[Obstacle::Circle {
            center: [2.0, 0.0],
            radius: 0.5,
        }]);
        let mut p = Vec2::ZERO;
        let mut closest = f64::INFINITY;
        for _ in 0..60 {
            let pref = (Vec2::new(4.0, 0.0) - p).normalized();
            let v = new_velocity(&pillar, p, pref, 0.3);
            p = p + v * 0.1;
            closest = closest.min((p - Vec2::new(2.0, 0.0)).norm());
        }
        assert!(
            closest >= 0.8 - 1e-6,
            "came within {closest} m of the pillar's centre"
        );
        assert!(p.x > 3.0, "stuck at {p:?}");
    }

    #[test]
    fn edges_the_agent_is_inside_of_or_beyond_range_are_not_neighbours() {
        let square = Obstacles::from_observation(&[Obstacle::Polygon {
            vertices: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        }]);
        // From below, only the bottom edge faces the agent.
        assert_eq!(square.neighbors(Vec2::new(0.5, -1.0), 10.0), vec![0]);
        assert!(square.neighbors(Vec2::new(0.5, -20.0), 10.0).is_empty());
    }
}
