//! ORCA against hand-computed cases, against a QP solver, and in the symmetric circle scenario.

use approx::assert_relative_eq;
use human2nav_core::{AgentState, Observation, Planner, Pose2, Twist2};
use human2nav_orca::lp::{self, Line, Vec2};
use human2nav_orca::orca::{
    Neighbor, OrcaParams, compute_new_velocity, orca_line, select_neighbors,
};
use human2nav_orca::{OrcaConfig, OrcaPlanner};
use proptest::prelude::*;
use std::f64::consts::PI;

fn params(time_horizon: f64, max_speed: f64) -> OrcaParams {
    OrcaParams {
        neighbor_dist: 15.0,
        max_neighbors: 10,
        time_horizon,
        time_step: 0.1,
        radius: 0.5,
        max_speed,
    }
}

/// Head-on: A at the origin moving +x at 1 m/s, B at (4, 0) moving −x at 1 m/s, both r = 0.5,
/// τ = 5. The relative velocity (2, 0) points straight at B; `w = v − p/τ = (1.2, 0)` has
/// `w·p > 0`, so the closest boundary point is on a leg, and RVO2 breaks the tie
/// `det(p, w) = 0` toward the right leg, direction `(−√15/4, 1/4)`. Then
/// `u = (v·d)d − v = (−1/8, −√15/8)`, the ORCA line passes through `v_A + u/2 =
/// (15/16, −√15/16)` and the preferred velocity (1, 0) projects onto that very point.
#[test]
fn head_on_pair_matches_hand_computation() {
    let s15 = 15f64.sqrt();
    let b = Neighbor {
        position: Vec2::new(4.0, 0.0),
        velocity: Vec2::new(-1.0, 0.0),
        radius: 0.5,
    };
    let line = orca_line(Vec2::ZERO, Vec2::new(1.0, 0.0), 0.5, &b, 5.0, 0.1);
    assert_relative_eq!(line.direction.x, -s15 / 4.0, epsilon = 1e-12);
    assert_relative_eq!(line.direction.y, 0.25, epsilon = 1e-12);
    let p = Vec2::new(15.0 / 16.0, -s15 / 16.0);
    // The line passes through p (zero violation) and p is where the optimum lands.
    assert_relative_eq!(line.violation(p), 0.0, epsilon = 1e-12);
    let v = compute_new_velocity(
        Vec2::ZERO,
        Vec2::new(1.0, 0.0),
        Vec2::new(1.0, 0.0),
        &[b],
        &params(5.0, 2.0),
    );
    assert_relative_eq!(v.x, p.x, epsilon = 1e-12);
    assert_relative_eq!(v.y, p.y, epsilon = 1e-12);

    // B sees the mirrored problem and also swerves to its own right: (−15/16, +√15/16).
    let a = Neighbor {
        position: Vec2::ZERO,
        velocity: Vec2::new(1.0, 0.0),
        radius: 0.5,
    };
    let vb = compute_new_velocity(
        b.position,
        b.velocity,
        Vec2::new(-1.0, 0.0),
        &[a],
        &params(5.0, 2.0),
    );
    assert_relative_eq!(vb.x, -p.x, epsilon = 1e-12);
    assert_relative_eq!(vb.y, -p.y, epsilon = 1e-12);
}

/// Far apart (beyond the time horizon) head-on agents keep their preferred velocity.
#[test]
fn head_on_beyond_horizon_is_unconstrained() {
    // Relative speed 2, gap 9 m − 1 m: contact after 4.5 s > τ = 2 s.
    let b = Neighbor {
        position: Vec2::new(10.0, 0.0),
        velocity: Vec2::new(-1.0, 0.0),
        radius: 0.5,
    };
    let v = compute_new_velocity(
        Vec2::ZERO,
        Vec2::new(1.0, 0.0),
        Vec2::new(1.0, 0.0),
        &[b],
        &params(2.0, 2.0),
    );
    assert_relative_eq!(v.x, 1.0, epsilon = 1e-12);
    assert_relative_eq!(v.y, 0.0, epsilon = 1e-12);
}

/// Crossing: A at the origin moving +x, B at (3, −3) moving +y, both 1 m/s, r = 0.5, τ = 5
/// (they would meet at (3, 0) after 3 s). `p = (3, −3)`, `v_rel = (1, −1)`, `w = (0.4, −0.4)`,
/// `w·p = 2.4 > 0` → legs; `det(p, w) = 0` → right leg with `leg = √17`:
/// `d = ((1 − √17)/6, (1 + √17)/6)`, `u = (v_rel·d)d − v_rel = (−(1 + √17)/18, (1 − √17)/18)`.
/// The preferred velocity (1, 0) projects exactly onto `v_A + u/2`.
#[test]
fn crossing_pair_matches_hand_computation() {
    let s17 = 17f64.sqrt();
    let b = Neighbor {
        position: Vec2::new(3.0, -3.0),
        velocity: Vec2::new(0.0, 1.0),
        radius: 0.5,
    };
    let line = orca_line(Vec2::ZERO, Vec2::new(1.0, 0.0), 0.5, &b, 5.0, 0.1);
    assert_relative_eq!(line.direction.x, (1.0 - s17) / 6.0, epsilon = 1e-12);
    assert_relative_eq!(line.direction.y, (1.0 + s17) / 6.0, epsilon = 1e-12);
    let expected = Vec2::new(1.0 - (1.0 + s17) / 36.0, (1.0 - s17) / 36.0);
    assert_relative_eq!(line.point.x, expected.x, epsilon = 1e-12);
    assert_relative_eq!(line.point.y, expected.y, epsilon = 1e-12);
    let v = compute_new_velocity(
        Vec2::ZERO,
        Vec2::new(1.0, 0.0),
        Vec2::new(1.0, 0.0),
        &[b],
        &params(5.0, 2.0),
    );
    assert_relative_eq!(v.x, expected.x, epsilon = 1e-12);
    assert_relative_eq!(v.y, expected.y, epsilon = 1e-12);
}

/// Cut-off circle case: B straight ahead at 3 m, both at rest but A prefers 1 m/s toward it with
/// current velocity (1.5, 0): `w = v − p/τ = (1.5 − 3/τ, 0)`; with τ = 1, `w = (−1.5, 0)`,
/// `w·p = −4.5 < 0` and `(w·p)² = 20.25 > R²|w|² = 2.25` → cut-off circle of radius `R/τ = 1`
/// centred at (3, 0): `u = (R/τ − |w|)·ŵ = (0.5, 0)`, line through (1.75, 0) with direction
/// (0, 1) (permitting `x ≤ 1.75`).
#[test]
fn cutoff_circle_case_matches_hand_computation() {
    let b = Neighbor {
        position: Vec2::new(3.0, 0.0),
        velocity: Vec2::ZERO,
        radius: 0.5,
    };
    let line = orca_line(Vec2::ZERO, Vec2::new(1.5, 0.0), 0.5, &b, 1.0, 0.1);
    assert_relative_eq!(line.direction.x, 0.0, epsilon = 1e-12);
    assert_relative_eq!(line.direction.y, 1.0, epsilon = 1e-12);
    assert_relative_eq!(line.point.x, 1.75, epsilon = 1e-12);
    assert_relative_eq!(line.point.y, 0.0, epsilon = 1e-12);
    // The preferred (2, 0.3) is clipped to x = 1.75.
    let v = compute_new_velocity(
        Vec2::ZERO,
        Vec2::new(1.5, 0.0),
        Vec2::new(2.0, 0.3),
        &[b],
        &params(1.0, 5.0),
    );
    assert_relative_eq!(v.x, 1.75, epsilon = 1e-12);
    assert_relative_eq!(v.y, 0.3, epsilon = 1e-12);
}

/// Overlapping agents get a line that separates them within one time step.
#[test]
fn overlapping_agents_are_pushed_apart() {
    // Centres 0.8 m apart with R = 1, both at rest. w = −p/Δt = (−8, 0), u = (R/Δt − 8)·(−1, 0)
    // = (−2, 0): A must move at ≤ −1 m/s along x (half of the 2 m/s separation rate).
    let b = Neighbor {
        position: Vec2::new(0.8, 0.0),
        velocity: Vec2::ZERO,
        radius: 0.5,
    };
    let line = orca_line(Vec2::ZERO, Vec2::ZERO, 0.5, &b, 5.0, 0.1);
    assert_relative_eq!(line.point.x, -1.0, epsilon = 1e-12);
    let v = compute_new_velocity(
        Vec2::ZERO,
        Vec2::ZERO,
        Vec2::new(1.0, 0.0),
        &[b],
        &params(5.0, 2.0),
    );
    assert_relative_eq!(v.x, -1.0, epsilon = 1e-12);
    assert_relative_eq!(v.y, 0.0, epsilon = 1e-12);
}

#[test]
fn neighbour_selection_follows_rvo2() {
    let n = |x: f64| Neighbor {
        position: Vec2::new(x, 0.0),
        velocity: Vec2::ZERO,
        radius: 0.3,
    };
    let others = [n(5.0), n(1.0), n(12.0), n(3.0), n(-2.0)];
    // Strictly inside 10 m, at most 3, closest first.
    assert_eq!(
        select_neighbors(Vec2::ZERO, &others, 10.0, 3),
        vec![1, 4, 3]
    );
    assert_eq!(
        select_neighbors(Vec2::ZERO, &others, 5.0, 10),
        vec![1, 4, 3]
    );
    assert!(select_neighbors(Vec2::ZERO, &others, 10.0, 0).is_empty());
}

/// The QP form of the same program, solved by Clarabel: min ½|v|² − opt·v subject to every
/// half-plane and |v| ≤ max_speed. Returns `None` when Clarabel does not report success.
fn clarabel_solve(lines: &[Line], max_speed: f64, opt: Vec2) -> Option<Vec2> {
    use clarabel::algebra::CscMatrix;
    use clarabel::solver::{
        DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SecondOrderConeT,
        SolverStatus,
    };
    let p = CscMatrix::from(&[[1.0, 0.0], [0.0, 1.0]]);
    let q = vec![-opt.x, -opt.y];
    // Half-plane i: d.y·v.x − d.x·v.y ≤ d.y·p.x − d.x·p.y. Cone rows: s = b − A v.
    let mut rows: Vec<[f64; 2]> = lines
        .iter()
        .map(|l| [l.direction.y, -l.direction.x])
        .collect();
    let mut b: Vec<f64> = lines
        .iter()
        .map(|l| l.direction.y * l.point.x - l.direction.x * l.point.y)
        .collect();
    rows.extend([[0.0, 0.0], [-1.0, 0.0], [0.0, -1.0]]);
    b.extend([max_speed, 0.0, 0.0]);
    let a = CscMatrix::from(rows.iter().map(|r| r.iter()));
    let mut cones = Vec::new();
    if !lines.is_empty() {
        cones.push(NonnegativeConeT(lines.len()));
    }
    cones.push(SecondOrderConeT(3));
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .tol_gap_abs(1e-10)
        .tol_gap_rel(1e-10)
        .build()
        .ok()?;
    let mut solver = DefaultSolver::new(&p, &q, &a, &b, &cones, settings).ok()?;
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved => Some(Vec2::new(solver.solution.x[0], solver.solution.x[1])),
        _ => None,
    }
}

fn arb_line() -> impl Strategy<Value = Line> {
    (-2.0..2.0f64, -2.0..2.0f64, 0.0..(2.0 * PI)).prop_map(|(x, y, a)| Line {
        point: Vec2::new(x, y),
        direction: Vec2::new(a.cos(), a.sin()),
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Whenever the program is feasible, RVO2's incremental LP returns the exact optimum of the
    /// QP (closest feasible velocity to the preferred one), within the interior-point solver's
    /// accuracy (1e-5).
    #[test]
    fn incremental_lp_equals_the_qp_optimum(
        lines in prop::collection::vec(arb_line(), 0..6),
        ox in -3.0..3.0f64,
        oy in -3.0..3.0f64,
        max_speed in 0.5..3.0f64,
    ) {
        let opt = Vec2::new(ox, oy);
        let (v, fail) = lp::linear_program2(&lines, max_speed, opt, false);
        if fail == lines.len() {
            for l in &lines {
                prop_assert!(l.violation(v) <= 1e-9, "violated line {l:?} by {}", l.violation(v));
            }
            prop_assert!(v.norm() <= max_speed + 1e-9);
            if let Some(qp) = clarabel_solve(&lines, max_speed, opt) {
                prop_assert!((qp - v).norm() < 1e-5, "lp {v:?} vs qp {qp:?}");
            }
        } else {
            // Infeasible: program 3 returns a velocity inside the disc whose largest violation
            // is no larger than that of the velocity program 2 stopped at.
            let worst = |u: Vec2| lines.iter().map(|l| l.violation(u)).fold(f64::NEG_INFINITY, f64::max);
            let w = lp::linear_program3(&lines, 0, fail, max_speed, v);
            prop_assert!(w.norm() <= max_speed + 1e-9);
            prop_assert!(worst(w) <= worst(v) + 1e-9);
        }
    }
}

/// Simulates `n` ORCA agents on a circle of radius `rho`, each heading to the antipode, with
/// RVO2's update (`v ← v_new`, `p ← p + v·Δt`, Δt = 0.1 s, τ = 5 s, max speed 1 m/s, preferred
/// velocity the goal vector clipped to unit length as in RVO2's examples). Returns the smallest
/// centre distance seen and whether everybody arrived within 0.1 m.
///
/// `noise > 0` perturbs each preferred velocity every step by at most `noise` m/s in a
/// pseudo-random direction (seeded), as RVO2's `Blocks` example does "to avoid deadlocks due to
/// perfect symmetry".
fn circle_scenario(
    n: usize,
    rho: f64,
    radius: f64,
    steps: usize,
    noise: f64,
    seed: u64,
) -> (f64, bool) {
    let dt = 0.1;
    let p = OrcaParams {
        neighbor_dist: 15.0,
        max_neighbors: 10,
        time_horizon: 5.0,
        time_step: dt,
        radius,
        max_speed: 1.0,
    };
    let mut pos: Vec<Vec2> = (0..n)
        .map(|i| {
            let a = 2.0 * PI * i as f64 / n as f64;
            Vec2::new(rho * a.cos(), rho * a.sin())
        })
        .collect();
    let goals: Vec<Vec2> = pos.iter().map(|&q| -q).collect();
    let mut vel = vec![Vec2::ZERO; n];
    let mut min_dist = f64::INFINITY;
    // A 64-bit LCG (Knuth's MMIX constants) for the perturbation.
    let mut state: u64 = seed;
    let mut uniform = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..steps {
        let mut new_vel = vel.clone();
        for i in 0..n {
            let to_goal = goals[i] - pos[i];
            let pref = if to_goal.norm_sq() > 1.0 {
                to_goal.normalized()
            } else {
                to_goal
            };
            let (angle, mag) = (2.0 * PI * uniform(), noise * uniform());
            let pref = pref + Vec2::new(angle.cos(), angle.sin()) * mag;
            let others: Vec<Neighbor> = (0..n)
                .filter(|&j| j != i)
                .map(|j| Neighbor {
                    position: pos[j],
                    velocity: vel[j],
                    radius,
                })
                .collect();
            new_vel[i] = compute_new_velocity(pos[i], vel[i], pref, &others, &p);
        }
        vel = new_vel;
        for i in 0..n {
            pos[i] = pos[i] + vel[i] * dt;
        }
        for i in 0..n {
            for j in (i + 1)..n {
                min_dist = min_dist.min((pos[i] - pos[j]).norm());
            }
        }
    }
    let arrived = pos.iter().zip(&goals).all(|(q, g)| (*q - *g).norm() < 0.1);
    (min_dist, arrived)
}

/// The perfectly symmetric circle: ORCA never lets two agents overlap. (In exact symmetry the
/// agents also never pass each other: every pair's relative velocity stays on the line between
/// them, so the cut-off circles only slow them down and the ring stalls around the centre —
/// the symmetric deadlock RVO2's examples break with a perturbation, tested below.)
#[test]
fn symmetric_circle_is_collision_free() {
    for &(n, rho) in &[(2usize, 4.0), (4, 4.0), (8, 6.0), (16, 8.0)] {
        let radius = 0.3;
        let (min_dist, _) = circle_scenario(n, rho, radius, 600, 0.0, 1);
        assert!(
            min_dist >= 2.0 * radius - 1e-9,
            "n = {n}: agents overlapped, min centre distance {min_dist}"
        );
    }
}

/// With the symmetry broken by a 1 mm/s perturbation of the preferred velocities, the agents
/// also pass each other and all reach their antipodes within 120 s, still without overlap.
#[test]
fn perturbed_circle_is_collision_free_and_everybody_arrives() {
    for &(n, rho) in &[(2usize, 4.0), (8, 6.0), (8, 10.0), (12, 10.0)] {
        for seed in [1u64, 2, 3] {
            let radius = 0.3;
            let seed = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let (min_dist, arrived) = circle_scenario(n, rho, radius, 1200, 1e-3, seed);
            assert!(
                min_dist >= 2.0 * radius - 1e-9,
                "n = {n}, seed {seed}: agents overlapped, min centre distance {min_dist}"
            );
            assert!(
                arrived,
                "n = {n}, seed {seed}: somebody missed the antipode after 120 s"
            );
        }
    }
}

fn obs_at(ego: Pose2, v_body: Twist2, goal: [f64; 2], agents: Vec<AgentState>) -> Observation {
    Observation {
        time: 1.5,
        ego,
        ego_velocity: v_body,
        goal,
        agents,
        ..Default::default()
    }
}

#[test]
fn planner_rolls_out_the_orca_velocity() {
    let cfg = OrcaConfig {
        max_speed: 1.2,
        plan_dt: 0.1,
        horizon: 5,
        ..OrcaConfig::default()
    };
    let mut planner = OrcaPlanner::new(cfg).unwrap();
    assert_eq!(planner.name(), "orca");
    // Empty scene, goal 5 m along +y from a robot facing +x: plan at 1.2 m/s toward +y.
    let ego = Pose2::new(1.0, 2.0, 0.0);
    let plan = planner
        .plan(&obs_at(ego, Twist2::ZERO, [1.0, 7.0], vec![]))
        .unwrap();
    assert_eq!(plan.poses.len(), 5);
    assert_relative_eq!(plan.t0, 1.5);
    assert_eq!(plan.poses[0], ego);
    for (k, p) in plan.poses.iter().enumerate().skip(1) {
        assert_relative_eq!(p.x, 1.0, epsilon = 1e-12);
        assert_relative_eq!(p.y, 2.0 + 0.12 * k as f64, epsilon = 1e-12);
        assert_relative_eq!(p.theta, PI / 2.0, epsilon = 1e-12);
    }
    // Close to the goal the preferred speed is d / arrival_time: 0.4 m → 0.4 m/s.
    let plan = planner
        .plan(&obs_at(ego, Twist2::ZERO, [1.4, 2.0], vec![]))
        .unwrap();
    assert_relative_eq!(plan.poses[1].x, 1.04, epsilon = 1e-12);
    // At the goal the plan stands still and keeps the heading.
    let plan = planner
        .plan(&obs_at(ego, Twist2::ZERO, [1.0, 2.0], vec![]))
        .unwrap();
    assert!(plan.poses.iter().all(|p| *p == Pose2::new(1.0, 2.0, 0.0)));
}

#[test]
fn planner_uses_world_velocity_and_pedestrians() {
    // Robot facing +y, moving forward at 1 m/s (body v_x), i.e. world velocity (0, 1); a
    // pedestrian approaches head-on. The ORCA velocity must equal the free-function result
    // with the world velocity.
    let cfg = OrcaConfig {
        radius: 0.5,
        max_speed: 2.0,
        time_horizon: 5.0,
        ..OrcaConfig::default()
    };
    let planner = OrcaPlanner::new(cfg.clone()).unwrap();
    let ped = AgentState {
        id: 7,
        position: [0.0, 4.0],
        velocity: [0.0, -1.0],
        radius: 0.5,
        history: vec![],
    };
    let obs = obs_at(
        Pose2::new(0.0, 0.0, PI / 2.0),
        Twist2::new(1.0, 0.0, 0.0),
        [0.0, 20.0],
        vec![ped],
    );
    let v = planner.velocity(&obs);
    let expected = compute_new_velocity(
        Vec2::ZERO,
        Vec2::new(0.0, 1.0),
        Vec2::new(0.0, 2.0),
        &[Neighbor {
            position: Vec2::new(0.0, 4.0),
            velocity: Vec2::new(0.0, -1.0),
            radius: 0.5,
        }],
        &cfg.params(),
    );
    assert_relative_eq!(v.x, expected.x, epsilon = 1e-9);
    assert_relative_eq!(v.y, expected.y, epsilon = 1e-9);
    // And it swerves: a non-zero lateral component.
    assert!(v.x.abs() > 0.05);
}

#[test]
fn config_is_validated_and_rejects_unknown_fields() {
    assert!(OrcaConfig::from_toml_str("time_horizon = 3.0\nmax_neighbors = 4").is_ok());
    assert!(matches!(
        OrcaConfig::from_toml_str("radius = -1.0"),
        Err(human2nav_orca::OrcaError::Config {
            field: "radius",
            ..
        })
    ));
    assert!(matches!(
        OrcaConfig::from_toml_str("horizon = 1"),
        Err(human2nav_orca::OrcaError::Config {
            field: "horizon",
            ..
        })
    ));
    assert!(matches!(
        OrcaConfig::from_toml_str("tau = 3.0"),
        Err(human2nav_orca::OrcaError::Parse(_))
    ));
}

#[test]
fn invalid_observation_is_an_error_not_a_plan() {
    let mut planner = OrcaPlanner::new(OrcaConfig::default()).unwrap();
    let obs = obs_at(
        Pose2::new(f64::NAN, 0.0, 0.0),
        Twist2::ZERO,
        [1.0, 0.0],
        vec![],
    );
    assert!(planner.plan(&obs).is_err());
}
