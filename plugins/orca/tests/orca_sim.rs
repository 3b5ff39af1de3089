//! The crowd simulation: the k-d tree, the brute-force scan and the per-agent code
//! (`compute_new_velocity` with every other agent) give bit-identical trajectories.

use human2nav_orca::kdtree::{AgentTree, NeighborList, scan_neighbors};
use human2nav_orca::lp::Vec2;
use human2nav_orca::orca::{Neighbor, OrcaParams, compute_new_velocity, select_neighbors};
use human2nav_orca::{NeighborSearch, OrcaSim};
use proptest::prelude::*;
use std::f64::consts::TAU;

const DT: f64 = 0.25;

fn params(radius: f64, neighbor_dist: f64, max_neighbors: usize) -> OrcaParams {
    OrcaParams {
        neighbor_dist,
        max_neighbors,
        time_horizon: 5.0,
        time_step: DT,
        radius,
        max_speed: 2.0,
    }
}

/// An agent's start, goal and parameters.
type Spec = (Vec2, Vec2, OrcaParams);

/// `n` agents on a circle (arc spacing 4 m), each heading to its antipode, RVO2's Circle
/// settings.
fn circle(n: usize) -> Vec<Spec> {
    let rho = (4.0 * n as f64 / TAU).max(10.0);
    (0..n)
        .map(|i| {
            let a = TAU * i as f64 / n as f64;
            let p = Vec2::new(rho * a.cos(), rho * a.sin());
            (p, -p, params(1.5, 15.0, 10))
        })
        .collect()
}

/// `n` agents on a square lattice of spacing 3 m centred on the origin, heading to the mirror
/// image of their start: many neighbours at exactly equal distances (rings of 4 and 8), and at
/// `neighbor_dist` 15 the agents 5 cells or (3, 4) cells away are exactly at range. Radii,
/// ranges and neighbour counts vary per agent so that the cut at `max_neighbors` falls inside
/// a ring of tied agents.
fn lattice(n: usize) -> Vec<Spec> {
    let side = (n as f64).sqrt().ceil() as usize;
    let half = 3.0 * (side as f64 - 1.0) / 2.0;
    (0..n)
        .map(|i| {
            let p = Vec2::new(
                3.0 * (i % side) as f64 - half,
                3.0 * (i / side) as f64 - half,
            );
            let radius = [1.0, 1.2, 0.8][i % 3];
            let max_neighbors = [10, 4, 6, 1, 0, 3][i % 6];
            let neighbor_dist = [15.0, 6.0, 3.0, 9.0][i % 4];
            (p, -p, params(radius, neighbor_dist, max_neighbors))
        })
        .collect()
}

/// RVO2's preferred velocity: the goal vector clipped to unit length.
fn pref(position: Vec2, goal: Vec2) -> Vec2 {
    let g = goal - position;
    if g.norm_sq() > 1.0 { g.normalized() } else { g }
}

fn build(specs: &[Spec], search: NeighborSearch) -> OrcaSim {
    let mut sim = OrcaSim::new(DT)
        .expect("valid time step")
        .with_search(search);
    for (p, _, prm) in specs {
        sim.add_agent(*p, *prm);
    }
    sim
}

/// Steps `steps` times with the given search; returns the positions and velocities after each
/// step. At step `reverse_at` the positions are handed out in reverse order first (agent `i`
/// jumps to agent `n − 1 − i`'s place), which makes last step's neighbours a poor guess.
fn run_sim(
    specs: &[Spec],
    search: NeighborSearch,
    steps: usize,
    reverse_at: Option<usize>,
) -> Vec<(Vec<Vec2>, Vec<Vec2>)> {
    let mut sim = build(specs, search);
    let mut out = Vec::new();
    for step in 0..steps {
        if reverse_at == Some(step) {
            sim.positions_mut().reverse();
        }
        for (i, (_, goal, _)) in specs.iter().enumerate() {
            let p = sim.positions()[i];
            sim.pref_velocities_mut()[i] = pref(p, *goal);
        }
        sim.step();
        out.push((sim.positions().to_vec(), sim.velocities().to_vec()));
    }
    out
}

/// The same simulation with the per-agent code (each agent sees all others in index order),
/// as the crate's callers stepped crowds before `OrcaSim`.
fn run_per_agent(
    specs: &[Spec],
    steps: usize,
    reverse_at: Option<usize>,
) -> Vec<(Vec<Vec2>, Vec<Vec2>)> {
    let n = specs.len();
    let mut pos: Vec<Vec2> = specs.iter().map(|s| s.0).collect();
    let mut vel = vec![Vec2::ZERO; n];
    let mut out = Vec::new();
    for step in 0..steps {
        if reverse_at == Some(step) {
            pos.reverse();
        }
        let mut new_vel = vel.clone();
        for i in 0..n {
            let others: Vec<Neighbor> = (0..n)
                .filter(|&j| j != i)
                .map(|j| Neighbor {
                    position: pos[j],
                    velocity: vel[j],
                    radius: specs[j].2.radius,
                })
                .collect();
            let pv = pref(pos[i], specs[i].1);
            new_vel[i] = compute_new_velocity(pos[i], vel[i], pv, &others, &specs[i].2);
        }
        vel = new_vel;
        for i in 0..n {
            pos[i] = pos[i] + vel[i] * DT;
        }
        out.push((pos.clone(), vel.clone()));
    }
    out
}

fn bits(v: &[Vec2]) -> Vec<(u64, u64)> {
    v.iter().map(|p| (p.x.to_bits(), p.y.to_bits())).collect()
}

fn assert_identical(what: &str, a: &[(Vec<Vec2>, Vec<Vec2>)], b: &[(Vec<Vec2>, Vec<Vec2>)]) {
    assert_eq!(a.len(), b.len());
    for (step, (x, y)) in a.iter().zip(b).enumerate() {
        assert_eq!(
            bits(&x.0),
            bits(&y.0),
            "{what}: positions differ after step {step}"
        );
        assert_eq!(
            bits(&x.1),
            bits(&y.1),
            "{what}: velocities differ after step {step}"
        );
    }
}

/// How many (agent, neighbour-list) pairs of the start state have a tie or an agent exactly at
/// `neighbor_dist`: the lattice must exercise both.
fn ties_and_range_hits(specs: &[Spec]) -> (usize, usize) {
    let (mut ties, mut at_range) = (0, 0);
    for (i, (p, _, prm)) in specs.iter().enumerate() {
        let mut d: Vec<f64> = specs
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, (q, _, _))| (*q - *p).norm_sq())
            .collect();
        d.sort_by(f64::total_cmp);
        let range_sq = prm.neighbor_dist * prm.neighbor_dist;
        at_range += d.iter().filter(|&&x| x == range_sq).count();
        let k = prm.max_neighbors;
        if k > 0 && k < d.len() && d[k - 1] == d[k] && d[k] < range_sq {
            ties += 1;
        }
    }
    (ties, at_range)
}

#[test]
fn tree_scan_and_per_agent_code_give_identical_crowds() {
    for n in [5usize, 37, 200] {
        for (name, specs) in [("circle", circle(n)), ("lattice", lattice(n))] {
            if name == "lattice" {
                let (ties, at_range) = ties_and_range_hits(&specs);
                assert!(
                    ties > 0 && at_range > 0,
                    "n = {n}: {ties} tie cuts, {at_range} agents at range"
                );
            }
            let steps = 80;
            for reverse_at in [None, Some(40)] {
                let reference = run_per_agent(&specs, steps, reverse_at);
                for search in [
                    NeighborSearch::BruteForce,
                    NeighborSearch::KdTree,
                    NeighborSearch::Auto,
                ] {
                    let sim = run_sim(&specs, search, steps, reverse_at);
                    let what = format!("{name} n = {n} {search:?}, reversed at {reverse_at:?}");
                    assert_identical(&what, &sim, &reference);
                }
            }
            let reference = run_per_agent(&specs, steps, None);
            // The crowd moved (the comparison is not between resting agents).
            let (last, _) = &reference[steps - 1];
            let moved = last.iter().zip(&specs).filter(|(p, s)| **p != s.0).count();
            assert!(moved > n / 2, "{name} n = {n}: only {moved} agents moved");
        }
    }
}

#[test]
fn sim_rejects_a_bad_time_step() {
    assert!(OrcaSim::new(0.0).is_err());
    assert!(OrcaSim::new(f64::NAN).is_err());
    assert!(OrcaSim::new(0.1).is_ok());
}

#[test]
fn empty_and_single_agent_crowds_step() {
    let mut sim = OrcaSim::new(DT).expect("valid time step");
    sim.step();
    let i = sim.add_agent(Vec2::new(1.0, 2.0), params(0.5, 10.0, 10));
    sim.pref_velocities_mut()[i] = Vec2::new(1.0, 0.0);
    sim.step();
    assert_eq!(sim.velocities()[0], Vec2::new(1.0, 0.0));
    assert_eq!(sim.positions()[0], Vec2::new(1.25, 2.0));
}

fn arb_positions() -> impl Strategy<Value = Vec<Vec2>> {
    // Coarse coordinates (multiples of 0.5 m in ±10 m) so that exact ties are common.
    prop::collection::vec((-20i32..=20, -20i32..=20), 0..120).prop_map(|v| {
        v.into_iter()
            .map(|(x, y)| Vec2::new(0.5 * x as f64, 0.5 * y as f64))
            .collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// The tree and the scan return `select_neighbors`' list, ties and range included.
    #[test]
    fn tree_query_equals_select_neighbors(
        positions in arb_positions(),
        qx in -24i32..=24,
        qy in -24i32..=24,
        half_range in 0u32..40,
        k in 0usize..14,
    ) {
        let q = Vec2::new(0.5 * qx as f64, 0.5 * qy as f64);
        let range = 0.5 * half_range as f64;
        let others: Vec<Neighbor> = positions
            .iter()
            .map(|&position| Neighbor { position, velocity: Vec2::ZERO, radius: 0.3 })
            .collect();
        let expected = select_neighbors(q, &others, range, k);
        let mut list = NeighborList::new();
        list.reset(range, k);
        scan_neighbors(&positions, q, None, &mut list);
        prop_assert_eq!(list.indices().collect::<Vec<_>>(), expected.clone());
        let mut tree = AgentTree::new();
        tree.build(&positions);
        list.reset(range, k);
        tree.query(q, None, &mut list);
        prop_assert_eq!(list.indices().collect::<Vec<_>>(), expected);
    }
}

/// FNV-1a over the bits of every position and velocity of a run.
fn fingerprint(run: &[(Vec<Vec2>, Vec<Vec2>)]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for (p, v) in run {
        for (x, y) in bits(p).into_iter().chain(bits(v)) {
            for b in x.to_le_bytes().into_iter().chain(y.to_le_bytes()) {
                h = (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    h
}

/// The crowd's trajectories are pinned bit for bit: a change that makes ORCA faster must not
/// change a single result (the lattice's start is exact arithmetic, and the update uses only
/// `+ − × ÷` and `sqrt`, which IEEE 754 rounds the same on every platform). The fingerprints
/// were recorded with the per-agent code; the test also runs that code, so a change to the
/// half-planes or the linear programs shows here even though the other tests compare the
/// simulation against it.
#[test]
fn trajectories_match_their_recorded_fingerprints() {
    let expected: [(usize, u64); 3] = [
        (5, 0x27ba_78fb_ef48_f6ac),
        (37, 0x8895_972a_491f_39ec),
        (200, 0xee08_0afe_ef5d_fc68),
    ];
    for (n, want) in expected {
        let specs = lattice(n);
        let sim = fingerprint(&run_sim(&specs, NeighborSearch::Auto, 80, None));
        let reference = fingerprint(&run_per_agent(&specs, 80, None));
        eprintln!("lattice n = {n}: {sim:#018x} (per-agent code {reference:#018x})");
        assert_eq!(
            sim, want,
            "lattice n = {n}: the simulation's trajectories changed"
        );
        assert_eq!(
            reference, want,
            "lattice n = {n}: the per-agent code's trajectories changed"
        );
    }
}
