//! What a rollout is scored against: the static obstacles of an observation (its
//! [`Obstacle`]s and the occupied cells of its [`OccupancyGrid`]) and the pedestrians walking
//! on at constant velocity. Shared by the MPPI and the DWA plugins (the DWA crate compiles this
//! file as a module of its own).

use human2nav_core::obstacle::{Obstacle, OccupancyGrid, SHELL};
use human2nav_core::{AgentState, Observation};

/// Edge of a bucket of [`StaticWorld`]'s lookup grid is at least this (m).
const MIN_BUCKET: f64 = 0.5;

/// Largest number of buckets per side of [`StaticWorld`]'s grid (the rest of the window is
/// merged into the edge buckets' neighbours by clamping).
const MAX_BUCKETS_PER_SIDE: usize = 128;

/// The static obstacles near the robot, bucketed so that the distance at a point only looks
/// at the obstacles that can be within `influence` of it.
#[derive(Clone, Debug, Default)]
pub struct StaticWorld {
    obstacles: Vec<Obstacle>,
    /// Lower-left corner of the window (m).
    origin: [f64; 2],
    cell: f64,
    side: usize,
    /// Per bucket, indices into `obstacles`.
    buckets: Vec<Vec<u32>>,
    influence: f64,
}

/// The axis-aligned bounding box of an obstacle: `[min_x, min_y, max_x, max_y]`.
fn bbox(o: &Obstacle) -> [f64; 4] {
    match o {
        Obstacle::Circle { center, radius } => [
            center[0] - radius,
            center[1] - radius,
            center[0] + radius,
            center[1] + radius,
        ],
        Obstacle::Segment { a, b } => [
            a[0].min(b[0]),
            a[1].min(b[1]),
            a[0].max(b[0]),
            a[1].max(b[1]),
        ],
        Obstacle::Polygon { vertices } => vertices.iter().fold(
            [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ],
            |b, v| {
                [
                    b[0].min(v[0]),
                    b[1].min(v[1]),
                    b[2].max(v[0]),
                    b[3].max(v[1]),
                ]
            },
        ),
    }
}

impl StaticWorld {
    /// The obstacles of `obstacles` and `occupancy` that can come within `influence` of a point
    /// within `reach` of `center`. Distances from [`StaticWorld::distance`] are exact up to
    /// `influence` and `+∞` beyond.
    pub fn new(
        obstacles: &[Obstacle],
        occupancy: Option<&OccupancyGrid>,
        center: [f64; 2],
        reach: f64,
        influence: f64,
    ) -> Self {
        let range = reach + influence;
        let mut near: Vec<Obstacle> = obstacles
            .iter()
            .filter(|o| o.distance(center) <= range)
            .cloned()
            .collect();
        if let Some(grid) = occupancy {
            near.extend(grid.obstacles_near(center, range));
        }
        let cell = influence.max(MIN_BUCKET);
        let side = ((2.0 * reach / cell).ceil() as usize).clamp(1, MAX_BUCKETS_PER_SIDE);
        let cell = (2.0 * reach / side as f64).max(cell);
        let origin = [center[0] - reach, center[1] - reach];
        let mut buckets = vec![Vec::new(); side * side];
        let index =
            |v: f64, o: f64| ((v - o) / cell).floor().clamp(0.0, (side - 1) as f64) as usize;
        for (i, o) in near.iter().enumerate() {
            let b = bbox(o);
            let (x0, x1) = (
                index(b[0] - influence, origin[0]),
                index(b[2] + influence, origin[0]),
            );
            let (y0, y1) = (
                index(b[1] - influence, origin[1]),
                index(b[3] + influence, origin[1]),
            );
            for y in y0..=y1 {
                for x in x0..=x1 {
                    buckets[y * side + x].push(i as u32);
                }
            }
        }
        Self {
            obstacles: near,
            origin,
            cell,
            side,
            buckets,
            influence,
        }
    }

    /// True when no static obstacle is near.
    pub fn is_empty(&self) -> bool {
        self.obstacles.is_empty()
    }

    /// The obstacles kept (near the robot).
    pub fn obstacles(&self) -> &[Obstacle] {
        &self.obstacles
    }

    /// The smallest signed distance from `p` to an obstacle (negative inside a circle or
    /// polygon); `+∞` when none is within the influence distance. Points outside the window
    /// use the nearest edge bucket, which is conservative only inside it.
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        if self.obstacles.is_empty() {
            return f64::INFINITY;
        }
        let index = |v: f64, o: f64| {
            let i = ((v - o) / self.cell).floor();
            if i.is_finite() {
                i.clamp(0.0, (self.side - 1) as f64) as usize
            } else {
                0
            }
        };
        let b =
            &self.buckets[index(p[1], self.origin[1]) * self.side + index(p[0], self.origin[0])];
        let d = b
            .iter()
            .map(|&i| self.obstacles[i as usize].distance(p))
            .fold(f64::INFINITY, f64::min);
        if d <= self.influence {
            d
        } else {
            f64::INFINITY
        }
    }
}

/// A pedestrian as the rollouts see it: position, velocity and radius.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Walker {
    /// Position now (m).
    pub position: [f64; 2],
    /// Velocity (m/s), kept for the whole horizon.
    pub velocity: [f64; 2],
    /// Disc radius (m).
    pub radius: f64,
}

impl Walker {
    /// Where the pedestrian is after `t` seconds.
    #[inline]
    pub fn at(&self, t: f64) -> [f64; 2] {
        [
            self.position[0] + self.velocity[0] * t,
            self.position[1] + self.velocity[1] * t,
        ]
    }
}

impl From<&AgentState> for Walker {
    fn from(a: &AgentState) -> Self {
        Self {
            position: a.position,
            velocity: a.velocity,
            radius: a.radius,
        }
    }
}

/// The pedestrians that can come within `influence` of the robot during a rollout of `horizon`
/// seconds at speeds up to `robot_speed` (the others cannot affect any score).
pub fn walkers_near(
    obs: &Observation,
    robot_speed: f64,
    horizon: f64,
    influence: f64,
) -> Vec<Walker> {
    let ego = [obs.ego.x, obs.ego.y];
    obs.agents
        .iter()
        .filter(|a| {
            let speed = a.velocity[0].hypot(a.velocity[1]);
            let d = (a.position[0] - ego[0]).hypot(a.position[1] - ego[1]);
            d - a.radius <= (robot_speed + speed) * horizon + influence
        })
        .map(Walker::from)
        .collect()
}

/// The smallest clearance between a disc of `radius` at `p` and the pedestrians at time `t`
/// (centre distance minus both radii; negative on overlap); `+∞` without pedestrians.
#[inline]
pub fn walker_clearance(walkers: &[Walker], p: [f64; 2], t: f64, radius: f64) -> f64 {
    walker_clearance_below(walkers, p, t, radius, f64::INFINITY)
}

/// [`walker_clearance`] where it is below `limit`, to the bit; where it is not, some value
/// that is not below `limit` either. The pedestrians whose squared centre distance puts them
/// beyond `limit` (with core's relative [`SHELL`] against rounding) are passed over without a
/// square root: a critic that only acts below a distance needs no more.
#[inline]
pub fn walker_clearance_below(
    walkers: &[Walker],
    p: [f64; 2],
    t: f64,
    radius: f64,
    limit: f64,
) -> f64 {
    walkers
        .iter()
        .filter_map(|w| {
            let q = w.at(t);
            let (dx, dy) = (p[0] - q[0], p[1] - q[1]);
            let reach = (limit + radius + w.radius) * (1.0 + SHELL);
            // NaN and an infinite `limit` fail the test: those take the square root.
            (dx * dx + dy * dy <= reach * reach || reach.is_nan() || reach.is_infinite())
                .then(|| dx.hypot(dy) - radius - w.radius)
        })
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bucketed_distance_matches_the_plain_one_within_the_influence() {
        let obstacles = vec![
            Obstacle::Segment {
                a: [2.0, -3.0],
                b: [2.0, 3.0],
            },
            Obstacle::Circle {
                center: [-1.0, 1.0],
                radius: 0.4,
            },
            Obstacle::Polygon {
                vertices: vec![[0.0, -2.0], [1.0, -2.0], [1.0, -1.0], [0.0, -1.0]],
            },
            Obstacle::Circle {
                center: [40.0, 0.0],
                radius: 1.0,
            },
        ];
        let world = StaticWorld::new(&obstacles, None, [0.0, 0.0], 4.0, 1.0);
        assert_eq!(world.obstacles().len(), 3, "the far circle is left out");
        for i in 0..80 {
            for j in 0..80 {
                let p = [-4.0 + 0.1 * i as f64, -4.0 + 0.1 * j as f64];
                let exact = obstacles
                    .iter()
                    .map(|o| o.distance(p))
                    .fold(f64::INFINITY, f64::min);
                let d = world.distance(p);
                if exact <= 1.0 {
                    assert!((d - exact).abs() < 1e-12, "{p:?}: {d} vs {exact}");
                } else {
                    assert!(d > 1.0, "{p:?}: {d} vs {exact}");
                }
            }
        }
    }

    #[test]
    fn occupied_cells_are_obstacles() {
        let mut data = vec![0i8; 100];
        data[5 * 10 + 5] = 100;
        let grid = OccupancyGrid {
            origin: human2nav_core::Pose2::new(0.0, 0.0, 0.0),
            resolution: 0.2,
            width: 10,
            height: 10,
            data,
            occupied_threshold: 65,
        };
        let world = StaticWorld::new(&[], Some(&grid), [0.0, 0.0], 3.0, 0.5);
        // Cell (5, 5) covers [1.0, 1.2]², covered by a circle of radius 0.2/√2 at (1.1, 1.1).
        let d = world.distance([1.1, 1.5]);
        assert!((d - (0.4 - 0.2 / 2f64.sqrt())).abs() < 1e-9, "{d}");
        assert!(world.distance([-1.0, -1.0]).is_infinite());
    }

    /// Below the limit the thresholded clearance is the clearance to the bit; above it, it is
    /// not below the limit either; with no limit it is the clearance.
    #[test]
    fn the_thresholded_walker_clearance_agrees_below_its_limit() {
        let walkers: Vec<Walker> = (0..7)
            .map(|k| {
                let k = k as f64;
                Walker {
                    position: [1.3 * k - 4.0, 0.7 * (k * 1.7).sin()],
                    velocity: [0.4 * (k * 0.9).cos(), -0.3],
                    radius: 0.2 + 0.05 * k,
                }
            })
            .collect();
        let (mut below, mut above) = (0, 0);
        for i in 0..=60 {
            for j in 0..=30 {
                let p = [-6.0 + 0.2 * i as f64, -3.0 + 0.2 * j as f64];
                let t = 0.1 * (i % 7) as f64;
                let exact = walker_clearance(&walkers, p, t, 0.3);
                for limit in [0.0, 0.25, 0.6, 1.5] {
                    let d = walker_clearance_below(&walkers, p, t, 0.3, limit);
                    if exact < limit {
                        assert_eq!(d.to_bits(), exact.to_bits(), "{p:?} {limit}");
                        below += 1;
                    } else {
                        assert!(d >= limit, "{p:?} {limit}: {d} for {exact}");
                        above += 1;
                    }
                }
            }
        }
        assert!(below > 500 && above > 500, "{below} {above}");
        let p = [0.5, 0.2];
        let exact = walkers
            .iter()
            .map(|w| {
                let q = w.at(0.3);
                (p[0] - q[0]).hypot(p[1] - q[1]) - 0.3 - w.radius
            })
            .fold(f64::INFINITY, f64::min);
        assert_eq!(
            walker_clearance(&walkers, p, 0.3, 0.3).to_bits(),
            exact.to_bits()
        );
        assert!(walker_clearance(&[], p, 0.0, 0.3).is_infinite());
    }
}
