//! The selection's broad phase for one planning call: at each waypoint, the agents and static
//! obstacles that some candidate of the call could come within the clearance margin of.
//!
//! At waypoint `j` every candidate is within `R_j` of the robot (the farthest any of them is
//! then), and no point of the footprint is farther than its reach from the candidate's pose.
//! An agent of radius `r` farther than `R_j + reach + r + margin` from the robot at `j`, or an
//! obstacle farther than `R_j + reach + margin`, can neither touch a candidate's footprint nor
//! come within its margin: the clearance term gets nothing from it. Leaving such agents and
//! obstacles out changes no score, not even in its last bit (the term adds nothing for them),
//! and with hundreds of candidates (a car's motion grid) the call does most of its
//! pair tests once per waypoint instead of once per candidate and waypoint.

use crate::forecast::Forecast;
use crate::obstacle::Obstacle;
use crate::se2::Pose2;
use std::ops::Range;

/// Slack on the broad-phase radius against rounding: keeping one agent too many only costs
/// the exact test the selection makes anyway.
const SLACK: f64 = 1e-9;

/// An agent at one waypoint of one scene.
#[derive(Clone, Copy, Debug)]
pub(crate) struct NearAgent {
    /// Its position, ego frame.
    pub q: [f64; 2],
    /// Radius of its disc (m).
    pub radius: f64,
    /// The distance between centres beyond which it cannot matter to a footprint of this
    /// reach: `reach + radius + margin`.
    pub far: f64,
}

/// Agents and obstacles per waypoint of one planning call (module docs).
#[derive(Debug, Default)]
pub(crate) struct Near {
    /// The forecast's scenes.
    scenes: usize,
    /// Their probabilities (`None`: equally likely), as in the forecast.
    weights: Option<Vec<f64>>,
    /// Waypoints covered: as many as the longest candidate has, at most the forecast's.
    steps: usize,
    /// The agents of every (scene, waypoint), scene-major, each in forecast order.
    agents: Vec<NearAgent>,
    /// Where those of (scene `s`, waypoint `j`) are in `agents`: entry `s · steps + j`.
    agent_spans: Vec<Range<usize>>,
    /// Indices into the call's obstacles, for every waypoint, in order.
    obstacles: Vec<usize>,
    /// Where those of waypoint `j` are in `obstacles`.
    obstacle_spans: Vec<Range<usize>>,
    /// The distance from a candidate's pose beyond which an obstacle cannot matter to it:
    /// `reach + margin`, with [`SLACK`].
    obstacle_far: f64,
}

/// The poses of `candidate`, then its last pose `hold` more times (none when it is empty): the
/// waypoints the selection checks for contact with a hold ([`crate::human2nav::SelectionWeights::hold`]).
pub(crate) fn held(candidate: &[Pose2], hold: usize) -> impl Iterator<Item = &Pose2> {
    let standing = candidate
        .last()
        .into_iter()
        .flat_map(move |p| std::iter::repeat_n(p, hold));
    candidate.iter().chain(standing)
}

impl Near {
    /// The broad phase of `candidates` (ego frame, starting at the robot), each also standing
    /// at its last pose for `hold` more waypoints, against `forecast` (ego frame) and
    /// `obstacles` (ego frame), for a footprint of `reach` and the selection's clearance
    /// `margin`.
    pub(crate) fn new(
        candidates: &[Vec<Pose2>],
        hold: usize,
        forecast: &Forecast,
        obstacles: &[Obstacle],
        reach: f64,
        margin: f64,
    ) -> Self {
        let steps = candidates
            .iter()
            .map(|c| c.len() + c.last().map_or(0, |_| hold))
            .max()
            .unwrap_or(0)
            .min(forecast.horizon());
        // R_j²: non-finite waypoints are left out (they fail every exact test as well).
        let mut farthest2 = vec![0.0f64; steps];
        for c in candidates {
            for (r2, p) in farthest2.iter_mut().zip(held(c, hold)) {
                let d2 = p.x * p.x + p.y * p.y;
                if d2 > *r2 {
                    *r2 = d2;
                }
            }
        }
        let farthest: Vec<f64> = farthest2.iter().map(|r2| r2.sqrt()).collect();

        let mut near = Near {
            scenes: forecast.scenes(),
            weights: forecast.weights().map(<[f64]>::to_vec),
            steps,
            obstacle_far: reach + margin + SLACK,
            ..Near::default()
        };
        for scene in 0..forecast.scenes() {
            for (j, &r) in farthest.iter().enumerate() {
                let start = near.agents.len();
                for (i, a) in forecast.agents().iter().enumerate() {
                    let q = forecast.position(i, scene, j);
                    let far = reach + a.radius + margin;
                    if q[0].hypot(q[1]) <= r + far + SLACK {
                        near.agents.push(NearAgent {
                            q,
                            radius: a.radius,
                            far,
                        });
                    }
                }
                near.agent_spans.push(start..near.agents.len());
            }
        }
        let from_robot: Vec<f64> = obstacles.iter().map(|o| o.distance([0.0, 0.0])).collect();
        for &r in &farthest {
            let start = near.obstacles.len();
            near.obstacles.extend(
                from_robot
                    .iter()
                    .enumerate()
                    .filter(|&(_, &d)| d <= r + reach + margin + SLACK)
                    .map(|(k, _)| k),
            );
            near.obstacle_spans.push(start..near.obstacles.len());
        }
        near
    }

    /// The forecast's scenes.
    pub(crate) fn scenes(&self) -> usize {
        self.scenes
    }

    /// The probability of scene `scene` (equally likely scenes: `1 / scenes`).
    pub(crate) fn weight(&self, scene: usize) -> f64 {
        self.weights
            .as_ref()
            .map_or(1.0 / self.scenes as f64, |w| w[scene])
    }

    /// The expectation of `f(scene)` over the forecast's scenes ([`Forecast::expectation`]).
    pub(crate) fn expectation(&self, f: impl FnMut(usize) -> f64) -> f64 {
        crate::forecast::expectation(self.weights.as_deref(), self.scenes, f)
    }

    /// The agents that may matter at waypoint `step` of scene `scene` (none past the covered
    /// waypoints).
    pub(crate) fn agents(&self, scene: usize, step: usize) -> &[NearAgent] {
        if step >= self.steps {
            return &[];
        }
        self.agent_spans
            .get(scene * self.steps + step)
            .map_or(&[], |span| &self.agents[span.clone()])
    }

    /// Indices of the obstacles that may matter at waypoint `step`.
    pub(crate) fn obstacles(&self, step: usize) -> &[usize] {
        self.obstacle_spans
            .get(step)
            .map_or(&[], |span| &self.obstacles[span.clone()])
    }

    /// Whether `obstacle` may matter to a candidate at `pose`: the narrow phase before the
    /// footprint's exact clearance, with the pose's position alone ([`Obstacle::farther_than`]
    /// the footprint's reach and the margin).
    pub(crate) fn obstacle_may_matter(&self, obstacle: &Obstacle, pose: &Pose2) -> bool {
        !obstacle.farther_than([pose.x, pose.y], self.obstacle_far)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forecast::ForecastAgent;
    use crate::obstacle::footprint_clearance;
    use crate::robot::footprint::{self, FootprintShape};
    use crate::se2::Twist2;
    use proptest::prelude::*;

    const MARGIN: f64 = 0.3;

    fn footprint() -> Vec<FootprintShape> {
        vec![FootprintShape::Rect {
            center: [0.3, 0.0],
            half: [0.5, 0.35],
            yaw: 0.0,
        }]
    }

    /// Candidates driving from the robot at the given speeds and turn rates.
    fn candidates(twists: &[(f64, f64)], steps: usize) -> Vec<Vec<Pose2>> {
        twists
            .iter()
            .map(|&(vx, omega)| {
                let twist = Twist2 { vx, vy: 0.0, omega };
                let mut pose = Pose2::IDENTITY;
                (0..steps)
                    .map(|_| {
                        pose = pose.euler_step(twist, 0.1);
                        pose
                    })
                    .collect()
            })
            .collect()
    }

    fn obstacles(centres: &[[f64; 2]]) -> Vec<Obstacle> {
        centres
            .iter()
            .enumerate()
            .map(|(k, &[x, y])| match k % 3 {
                0 => Obstacle::Circle {
                    center: [x, y],
                    radius: 0.4,
                },
                1 => Obstacle::Segment {
                    a: [x, y],
                    b: [x + 1.0, y - 0.5],
                },
                _ => Obstacle::Polygon {
                    vertices: vec![[x, y], [x + 0.8, y], [x + 0.8, y + 0.6], [x, y + 0.6]],
                },
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Whatever the broad phase leaves out fails the selection's exact tests for every
        /// candidate, on its waypoints and standing at its last pose for the hold: an agent's
        /// centre is at least `far` from the pose, an obstacle at least the margin from the
        /// footprint.
        #[test]
        fn what_is_left_out_cannot_matter(
            hold in 0usize..12,
            twists in prop::collection::vec((-0.5f64..1.5, -1.0f64..1.0), 1..12),
            starts in prop::collection::vec(((-8.0f64..8.0, -8.0f64..8.0), (-1.5f64..1.5, -1.5f64..1.5)), 0..20),
            centres in prop::collection::vec(prop::array::uniform2(-8.0f64..8.0), 0..8),
        ) {
            let plan = 32;
            let steps = plan + hold;
            let shapes = footprint();
            let reach = footprint::reach(&shapes);
            let cands = candidates(&twists, plan);
            // Candidate `c` at waypoint `j`, standing at its last pose after it.
            let at = |c: &Vec<Pose2>, j: usize| c[j.min(plan - 1)];
            // Two scenes: the second walks at half the speed.
            let agents = starts
                .iter()
                .enumerate()
                .map(|(i, &((x, y), (vx, vy)))| ForecastAgent {
                    id: i as u64,
                    radius: 0.2 + 0.05 * (i % 3) as f64,
                    paths: [1.0, 0.5]
                        .iter()
                        .map(|f| {
                            (1..=steps)
                                .map(|j| {
                                    let t = j as f64 * 0.1 * f;
                                    [x + vx * t, y + vy * t]
                                })
                                .collect()
                        })
                        .collect(),
                })
                .collect();
            let forecast = Forecast::new(steps, 2, agents).unwrap();
            let obstacles = obstacles(&centres);
            let near = Near::new(&cands, hold, &forecast, &obstacles, reach, MARGIN);
            prop_assert_eq!(near.scenes(), 2);
            for scene in 0..2 {
                for j in 0..steps {
                    let kept = near.agents(scene, j);
                    for (i, a) in forecast.agents().iter().enumerate() {
                        let q = forecast.position(i, scene, j);
                        if kept.iter().any(|k| k.q == q) {
                            continue;
                        }
                        let far = reach + a.radius + MARGIN;
                        for c in &cands {
                            let (dx, dy) = (q[0] - at(c, j).x, q[1] - at(c, j).y);
                            prop_assert!(dx * dx + dy * dy >= far * far);
                        }
                    }
                }
            }
            for j in 0..steps {
                for (k, o) in obstacles.iter().enumerate() {
                    if near.obstacles(j).contains(&k) {
                        continue;
                    }
                    for c in &cands {
                        prop_assert!(footprint_clearance(&shapes, at(c, j), o) >= MARGIN);
                    }
                }
            }
            prop_assert!(near.agents(0, steps).is_empty());
        }
    }

    /// Near the robot everything is kept; far away and early in the plan, nothing is.
    #[test]
    fn keeps_the_near_and_drops_the_far() {
        let cands = candidates(&[(1.0, 0.0), (1.0, 0.5)], 10);
        let still = |id, x: f64| ForecastAgent {
            id,
            radius: 0.25,
            paths: vec![vec![[x, 0.0]; 10]],
        };
        let forecast = Forecast::new(10, 1, vec![still(0, 1.5), still(1, 30.0)]).unwrap();
        let obstacles = obstacles(&[[0.5, 1.0], [40.0, 0.0]]);
        let shapes = footprint();
        let near = Near::new(
            &cands,
            0,
            &forecast,
            &obstacles,
            footprint::reach(&shapes),
            MARGIN,
        );
        for j in 0..10 {
            let ids: Vec<f64> = near.agents(0, j).iter().map(|a| a.q[0]).collect();
            assert_eq!(ids, [1.5], "waypoint {j}");
            assert_eq!(near.obstacles(j), [0], "waypoint {j}");
        }
    }
}
