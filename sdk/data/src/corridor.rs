//! Corridor episodes: a crowd in a corridor with walls, pillars and doors, the benchmark's suite
//! with static obstacles (`kind = "corridor"`). They are generated, seeded, in the four flow
//! classes.
//!
//! # Scene
//! The corridor runs along `+x` from `x = −2` to `x = 14`. It is `W` wide (uniform in 3.0–4.0 m):
//! two walls (segments) at `y = ±W/2`. Each wall has a door 1.4 m wide at the same `x_d`
//! (uniform in 4–8 m). Zero to two pillars stand inside, each a 0.4 m square or a disc of
//! radius 0.2–0.3 m. A pillar keeps a passage of at least 1.2 m on one side, and stays 1.2 m
//! from the robot's start and goal. The robot starts at the origin facing `+x`, with its goal
//! 10 m ahead.
//!
//! # Pedestrians
//! Pedestrians walk straight lanes at constant speed; the crowd is replayed, as recorded data
//! is. A lane never meets a wall or a pillar, and two lanes in opposite directions are at
//! least 0.7 m apart:
//! - co-flow pedestrians walk `+x` at 0.5–1.0 m/s, starting 1.5–6 m ahead;
//! - counter-flow pedestrians walk `−x` at 0.8–1.4 m/s, starting 6–15 m ahead, some up to
//!   3 s late;
//! - cross-flow pedestrians walk through the two doors (`±y`) at 0.8–1.3 m/s, timed to cross
//!   the middle of the corridor 1–6 s into the episode (one whose line would meet a pillar is
//!   left out);
//! - multidirection mixes the three.
//!
//! A track ends when its pedestrian leaves the corridor or after 30 s.

use crate::scenario::{AgentTrack, Episode, ScenarioClass};
use human2nav_core::obstacle::Obstacle;
use human2nav_core::se2::Pose2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Where the robot's goal lies along the corridor (m).
pub const GOAL_X: f64 = 10.0;
/// Step of the recorded tracks (s).
const DT: f64 = 0.1;
/// Longest track (steps).
const MAX_STEPS: usize = 300;
/// Pedestrian radius (m), as the synthetic crowd's.
const RADIUS: f64 = 0.3;
/// Width of the doors (m).
const DOOR: f64 = 1.4;

/// The corridor's walls, doors and pillars.
struct Layout {
    width: f64,
    door_x: f64,
    /// Pillars as `(centre, covering radius)`, with their obstacle.
    pillars: Vec<([f64; 2], f64, Obstacle)>,
}

impl Layout {
    fn draw(rng: &mut ChaCha8Rng) -> Self {
        let width = rng.random_range(3.0..4.0);
        let door_x = rng.random_range(4.0..8.0);
        let mut pillars = Vec::new();
        for _ in 0..rng.random_range(0..=2usize) {
            let square = rng.random_bool(0.5);
            let r = if square {
                0.2 * std::f64::consts::SQRT_2
            } else {
                rng.random_range(0.2..0.3)
            };
            // One side keeps a passage of 1.2 m: the pillar's far edge at most W − 1.2 from a wall.
            let half = width / 2.0;
            let y = rng.random_range(-half + 0.3 + r..half - 1.2 - r) * sign(rng);
            let x = rng.random_range(2.5..8.5);
            let clear_of = |p: [f64; 2]| (x - p[0]).hypot(y - p[1]) > 1.2 + r;
            if !(clear_of([0.0, 0.0]) && clear_of([GOAL_X, 0.0])) {
                continue;
            }
            let obstacle = if square {
                Obstacle::Polygon {
                    vertices: vec![
                        [x - 0.2, y - 0.2],
                        [x + 0.2, y - 0.2],
                        [x + 0.2, y + 0.2],
                        [x - 0.2, y + 0.2],
                    ],
                }
            } else {
                Obstacle::Circle {
                    center: [x, y],
                    radius: r,
                }
            };
            pillars.push(([x, y], r, obstacle));
        }
        Self {
            width,
            door_x,
            pillars,
        }
    }

    /// Walls with their doors, then the pillars.
    fn obstacles(&self) -> Vec<Obstacle> {
        let (x0, x1) = (-2.0, 14.0);
        let (d0, d1) = (self.door_x - DOOR / 2.0, self.door_x + DOOR / 2.0);
        let mut out = Vec::new();
        for y in [-self.width / 2.0, self.width / 2.0] {
            out.push(Obstacle::Segment {
                a: [x0, y],
                b: [d0, y],
            });
            out.push(Obstacle::Segment {
                a: [d1, y],
                b: [x1, y],
            });
        }
        out.extend(self.pillars.iter().map(|(_, _, o)| o.clone()));
        out
    }

    /// Whether a lane along x at `y` keeps clear of the walls and every pillar.
    fn lane_is_clear(&self, y: f64) -> bool {
        y.abs() <= self.width / 2.0 - RADIUS - 0.1
            && self
                .pillars
                .iter()
                .all(|(c, r, _)| (y - c[1]).abs() > r + RADIUS + 0.1)
    }
}

fn sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.random_bool(0.5) { 1.0 } else { -1.0 }
}

/// A straight track from `from` at `velocity`, starting at step `start`, until it leaves the
/// corridor's box or after [`MAX_STEPS`].
fn track(id: u64, start: usize, from: [f64; 2], velocity: [f64; 2], width: f64) -> AgentTrack {
    let positions = (0..MAX_STEPS)
        .map(|k| {
            let t = k as f64 * DT;
            [from[0] + velocity[0] * t, from[1] + velocity[1] * t]
        })
        .take_while(|p| (-3.0..=15.0).contains(&p[0]) && p[1].abs() <= width / 2.0 + 3.0 + 1e-9)
        .collect();
    AgentTrack {
        id,
        start_step: start,
        positions,
        radius: RADIUS,
    }
}

/// Lane positions for `n` pedestrians in one direction, clear of pillars and at least 0.7 m
/// from the lanes `taken` by the other direction; fewer when the corridor has no room.
fn lanes(rng: &mut ChaCha8Rng, layout: &Layout, n: usize, taken: &[f64]) -> Vec<f64> {
    let half = layout.width / 2.0 - RADIUS - 0.1;
    let mut out = Vec::new();
    for _ in 0..20 * n {
        if out.len() == n {
            break;
        }
        let y = rng.random_range(-half..half);
        if layout.lane_is_clear(y) && taken.iter().all(|t| (t - y).abs() >= 0.7) {
            out.push(y);
        }
    }
    out
}

/// The pedestrians of one class in `layout`.
fn pedestrians(rng: &mut ChaCha8Rng, layout: &Layout, class: ScenarioClass) -> Vec<AgentTrack> {
    let (co, counter, cross) = match class {
        ScenarioClass::CoFlow => (rng.random_range(3..=6), 0, 0),
        ScenarioClass::CounterFlow => (0, rng.random_range(3..=6), 0),
        ScenarioClass::CrossFlow => (0, 0, rng.random_range(3..=5)),
        ScenarioClass::MultidirectionFlow => (
            rng.random_range(1..=2),
            rng.random_range(1..=2),
            rng.random_range(1..=2),
        ),
    };
    let w = layout.width;
    let mut out = Vec::new();
    let mut id = 1u64;
    let forward = lanes(rng, layout, co, &[]);
    for &y in &forward {
        let speed = rng.random_range(0.5..1.0);
        let x = rng.random_range(1.5..6.0);
        out.push(track(id, 0, [x, y], [speed, 0.0], w));
        id += 1;
    }
    for y in lanes(rng, layout, counter, &forward) {
        let speed = rng.random_range(0.8..1.4);
        let x = rng.random_range(6.0..14.9f64);
        let start = rng.random_range(0..=30usize);
        out.push(track(id, start, [x, y], [-speed, 0.0], w));
        id += 1;
    }
    for _ in 0..cross {
        let speed = rng.random_range(0.8..1.3);
        let dir = sign(rng);
        let clear = |x: f64| {
            layout
                .pillars
                .iter()
                .all(|(c, r, _)| (x - c[0]).abs() > r + RADIUS + 0.1)
        };
        let Some(x) = (0..10)
            .map(|_| layout.door_x + rng.random_range(-0.25..0.25))
            .find(|&x| clear(x))
        else {
            continue;
        };
        // Reaches y = 0 at t_mid: starts (w/2 + 2) m out, so it comes in through the door.
        let t_mid: f64 = rng.random_range(1.0..6.0);
        let from_y = -dir * (w / 2.0 + 2.0);
        let t_travel = (w / 2.0 + 2.0) / speed;
        let start = ((t_mid - t_travel).max(0.0) / DT).round() as usize;
        let y0 = if t_mid >= t_travel {
            from_y
        } else {
            from_y + dir * speed * t_mid.min(t_travel)
        };
        out.push(track(id, start, [x, y0], [0.0, dir * speed], w));
        id += 1;
    }
    out
}

/// `n` corridor episodes of `class`, deterministic in `seed`.
pub fn episodes(class: ScenarioClass, n: usize, seed: u64) -> Vec<Episode> {
    (0..n as u64)
        .map(|i| {
            let mut rng = ChaCha8Rng::seed_from_u64(
                seed ^ ((class.index() as u64) << 40) ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            // Redrawn (from the same stream) in the rare layout that leaves nobody walking.
            let mut layout = Layout::draw(&mut rng);
            let mut agents = pedestrians(&mut rng, &layout, class);
            for _ in 0..100 {
                if !agents.is_empty() {
                    break;
                }
                layout = Layout::draw(&mut rng);
                agents = pedestrians(&mut rng, &layout, class);
            }
            Episode {
                id: format!("corridor/{}_{i:04}", class.name()),
                scene: "corridor".into(),
                source: "synthetic".into(),
                scenario: class,
                dt: DT,
                start: Pose2::IDENTITY,
                goal: [GOAL_X, 0.0],
                // The simulator's rule (a factor on the empty-world time plus a margin)
                // decides; this only sets a floor.
                time_budget: 10.0,
                density: agents.len(),
                agents,
                obstacles: layout.obstacles(),
                human_path: Vec::new(),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use human2nav_core::obstacle::point_segment_distance;

    #[test]
    fn corridor_episodes_are_valid_deterministic_and_walkable() {
        for class in ScenarioClass::ALL {
            let a = episodes(class, 12, 7);
            assert_eq!(a, episodes(class, 12, 7));
            assert_ne!(a, episodes(class, 12, 8));
            for e in &a {
                e.validate().unwrap();
                assert!(e.obstacles.len() >= 4, "four wall segments");
                assert!(!e.agents.is_empty(), "{}", e.id);
                // No pedestrian ever overlaps a wall or pillar, and the start and goal are clear.
                for o in &e.obstacles {
                    for p in [[0.0, 0.0], e.goal] {
                        assert!(o.distance(p) > 0.6, "{}: {o:?} near {p:?}", e.id);
                    }
                    for t in &e.agents {
                        for p in &t.positions {
                            let d = o.distance(*p);
                            assert!(d >= t.radius, "{}: agent {} at {p:?} in {o:?}", e.id, t.id);
                        }
                    }
                }
            }
        }
        // A cross-flow pedestrian comes in through a door.
        let e = &episodes(ScenarioClass::CrossFlow, 1, 3)[0];
        let wall_y = match e.obstacles[0] {
            Obstacle::Segment { a, .. } => a[1].abs(),
            _ => unreachable!(),
        };
        assert!(
            e.agents
                .iter()
                .any(|t| t.positions.iter().any(|p| p[1].abs() > wall_y))
        );
        assert!(point_segment_distance([0.0, 0.0], [1.0, 0.0], [2.0, 0.0]) > 0.9);
    }
}
