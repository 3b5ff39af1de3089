//! A crowd of ORCA agents stepped together, as RVO2's `RVOSimulator::doStep`: every agent's
//! new velocity is computed from the current state (positions and velocities of everybody),
//! then all velocities are replaced and all positions advanced by `velocity · time_step`.
//!
//! Each agent's velocity is exactly [`crate::orca::compute_new_velocity`] with all the other
//! agents as `others` (in index order, each with its own radius): the same neighbours in the
//! same order, the same half-planes, the same linear program, bit for bit. Only the neighbour
//! search differs: [`NeighborSearch`] picks the brute-force scan or the k-d tree of
//! [`crate::kdtree`], which return identical lists, and the step reuses its buffers, so it does
//! not allocate once the crowd's size is reached.

use crate::kdtree::{AgentTree, NeighborList, scan_neighbors_within};
use crate::lp::{self, Line, Vec2};
use crate::orca::{Neighbor, OrcaParams, orca_line_inv};
use crate::planner::OrcaError;

/// How [`OrcaSim`] finds each agent's neighbours. All choices give identical results.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NeighborSearch {
    /// The k-d tree from [`AUTO_TREE_MIN_AGENTS`] agents, the scan below (where it is as fast).
    #[default]
    Auto,
    /// Every agent checks every other one: `O(N²)` per step.
    BruteForce,
    /// A k-d tree rebuilt every step: `O(N log N)` per step.
    KdTree,
}

/// With [`NeighborSearch::Auto`], crowds of at least this many agents use the k-d tree. On
/// the circle scenario of the `orca` bench the two are within noise of each other up to 64
/// agents (the scan mostly ahead) and the tree is ahead from 100 (by 15 % at 100, 33 % at 200).
pub const AUTO_TREE_MIN_AGENTS: usize = 64;

/// N ORCA agents (agents only, no static obstacles) with RVO2's update.
#[derive(Clone, Debug)]
pub struct OrcaSim {
    time_step: f64,
    search: NeighborSearch,
    positions: Vec<Vec2>,
    velocities: Vec<Vec2>,
    pref_velocities: Vec<Vec2>,
    params: Vec<OrcaParams>,
    /// Each agent's `1 / time_horizon` and the simulation's `1 / time_step`: the divisions
    /// [`orca_line_inv`] takes, done once instead of once per agent and step.
    inv_time_horizons: Vec<f64>,
    inv_time_step: f64,
    // Buffers reused from step to step.
    new_velocities: Vec<Vec2>,
    /// Each agent's neighbours at the last step: agent `i`'s are
    /// `last_neighbors[last_start[i]..last_start[i + 1]]`. When it had its full
    /// `max_neighbors`, their current distances bound this step's `k`-th distance, a guess
    /// that speeds up the search (it never changes the result). Rebuilt every step into the
    /// `next_*` buffers, then swapped.
    last_neighbors: Vec<usize>,
    last_start: Vec<usize>,
    next_neighbors: Vec<usize>,
    next_start: Vec<usize>,
    tree: AgentTree,
    neighbors: NeighborList,
    lines: Vec<Line>,
    lp_scratch: Vec<Line>,
}

impl OrcaSim {
    /// An empty crowd stepped by `time_step` seconds (finite and > 0).
    pub fn new(time_step: f64) -> Result<Self, OrcaError> {
        if !(time_step.is_finite() && time_step > 0.0) {
            return Err(OrcaError::Config {
                field: "time_step",
                message: format!("must be finite and > 0, got {time_step}"),
            });
        }
        Ok(Self {
            time_step,
            search: NeighborSearch::Auto,
            positions: Vec::new(),
            velocities: Vec::new(),
            pref_velocities: Vec::new(),
            params: Vec::new(),
            inv_time_horizons: Vec::new(),
            inv_time_step: 1.0 / time_step,
            new_velocities: Vec::new(),
            last_neighbors: Vec::new(),
            last_start: Vec::new(),
            next_neighbors: Vec::new(),
            next_start: Vec::new(),
            tree: AgentTree::new(),
            neighbors: NeighborList::new(),
            lines: Vec::new(),
            lp_scratch: Vec::new(),
        })
    }

    /// The same crowd with another neighbour search (the results do not change).
    pub fn with_search(mut self, search: NeighborSearch) -> Self {
        self.search = search;
        self
    }

    pub fn search(&self) -> NeighborSearch {
        self.search
    }

    pub fn time_step(&self) -> f64 {
        self.time_step
    }

    /// Adds an agent at rest with preferred velocity zero and returns its index. Its
    /// `params.time_step` is replaced by the simulation's (RVO2 has one time step for all).
    pub fn add_agent(&mut self, position: Vec2, params: OrcaParams) -> usize {
        self.positions.push(position);
        self.velocities.push(Vec2::ZERO);
        self.pref_velocities.push(Vec2::ZERO);
        self.params.push(OrcaParams {
            time_step: self.time_step,
            ..params
        });
        self.inv_time_horizons.push(1.0 / params.time_horizon);
        self.positions.len() - 1
    }

    pub fn num_agents(&self) -> usize {
        self.positions.len()
    }

    pub fn positions(&self) -> &[Vec2] {
        &self.positions
    }

    pub fn positions_mut(&mut self) -> &mut [Vec2] {
        &mut self.positions
    }

    pub fn velocities(&self) -> &[Vec2] {
        &self.velocities
    }

    pub fn velocities_mut(&mut self) -> &mut [Vec2] {
        &mut self.velocities
    }

    /// The velocities the agents would like to have, set before each [`OrcaSim::step`].
    pub fn pref_velocities(&self) -> &[Vec2] {
        &self.pref_velocities
    }

    pub fn pref_velocities_mut(&mut self) -> &mut [Vec2] {
        &mut self.pref_velocities
    }

    pub fn params(&self) -> &[OrcaParams] {
        &self.params
    }

    /// Whether this step uses the k-d tree.
    fn uses_tree(&self) -> bool {
        match self.search {
            NeighborSearch::Auto => self.positions.len() >= AUTO_TREE_MIN_AGENTS,
            NeighborSearch::BruteForce => false,
            NeighborSearch::KdTree => true,
        }
    }

    /// An upper bound of agent `i`'s `k`-th squared neighbour distance: the largest current
    /// squared distance to the `k` agents that were its neighbours at the last step (any `k`
    /// agents bound the `k`-th closest). Infinite (no guess) when it had fewer.
    fn guess(&self, i: usize) -> f64 {
        let k = self.params[i].max_neighbors;
        let last = match (self.last_start.get(i), self.last_start.get(i + 1)) {
            (Some(&a), Some(&b)) if b - a == k && k > 0 => &self.last_neighbors[a..b],
            _ => return f64::INFINITY,
        };
        let position = self.positions[i];
        let mut bound: f64 = 0.0;
        for &j in last {
            let d = (self.positions[j] - position).norm_sq();
            // NaN (a position made non-finite) propagates: the search then covers the range.
            bound = if d > bound || d.is_nan() { d } else { bound };
        }
        bound
    }

    /// One step: all new velocities from the current state, then `v ← v_new`,
    /// `p ← p + v · time_step` for every agent.
    pub fn step(&mut self) {
        let n = self.positions.len();
        let use_tree = self.uses_tree();
        if use_tree {
            self.tree.build(&self.positions);
        }
        self.new_velocities.clear();
        self.next_neighbors.clear();
        self.next_start.clear();
        self.next_start.push(0);
        for i in 0..n {
            let position = self.positions[i];
            let velocity = self.velocities[i];
            let p = &self.params[i];
            self.neighbors.reset(p.neighbor_dist, p.max_neighbors);
            let guess = self.guess(i);
            if use_tree {
                self.tree
                    .query_within(position, Some(i), guess, &mut self.neighbors);
            } else {
                scan_neighbors_within(
                    &self.positions,
                    position,
                    Some(i),
                    guess,
                    &mut self.neighbors,
                );
            }
            self.next_neighbors.extend(self.neighbors.indices());
            self.next_start.push(self.next_neighbors.len());
            self.lines.clear();
            let (inv_tau, inv_dt) = (self.inv_time_horizons[i], self.inv_time_step);
            for j in self.neighbors.indices() {
                let other = Neighbor {
                    position: self.positions[j],
                    velocity: self.velocities[j],
                    radius: self.params[j].radius,
                };
                self.lines.push(orca_line_inv(
                    position, velocity, p.radius, &other, inv_tau, inv_dt,
                ));
            }
            self.new_velocities.push(lp::solve_in(
                &self.lines,
                p.max_speed,
                self.pref_velocities[i],
                &mut self.lp_scratch,
            ));
        }
        let dt = self.time_step;
        for ((p, v), &v_new) in self
            .positions
            .iter_mut()
            .zip(&mut self.velocities)
            .zip(&self.new_velocities)
        {
            *v = v_new;
            *p = *p + v_new * dt;
        }
        std::mem::swap(&mut self.last_neighbors, &mut self.next_neighbors);
        std::mem::swap(&mut self.last_start, &mut self.next_start);
    }
}
