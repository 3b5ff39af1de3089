//! Neighbour queries for ORCA crowds: a k-d tree over the agents' positions and the brute-force
//! scan it replaces, both returning exactly what [`crate::orca::select_neighbors`] returns.
//!
//! # Why a k-d tree
//!
//! The query is "the `k` closest agents strictly within `neighbor_dist`", with `k` small (RVO2
//! uses 10) and the range large compared with the agents' spacing (15 m against 3–5 m in the
//! circle scenario). In a dense crowd the `k`-th neighbour is much closer than the range, so a
//! query should only look at the agents near that distance. A k-d tree does this whatever the
//! crowd's density and extent, with no parameter to tune (a uniform grid needs a cell size
//! that suits both a jam and a sparse ring, and hashing when the agents spread over
//! kilometres), each agent may have its own range, and rebuilding it every step costs
//! `O(N log N)` of branch-free partitioning, little next to the ORCA programs. RVO2 also uses
//! one (its agent tree); as there, nodes are boxes holding a contiguous range of agents, split
//! at the middle of the box's longer side.
//!
//! # How a query runs
//!
//! Mispredicted comparisons dominate such small queries, so a query avoids data-dependent
//! branches where it can. Given an upper bound `B` of the `k`-th squared distance (the
//! caller's guess, see [`AgentTree::query_within`]; [`crate::sim::OrcaSim`] takes the current
//! distances to last step's neighbours), it collects every agent with squared distance `≤ B`
//! (and `< neighbor_dist²`) from the leaves whose box is within `B`, appending without a branch
//! per agent, and then orders the candidates: a few by insertion, up to 48 by counting for
//! each the candidates that beat it (no branch either), more with the standard sort. If fewer
//! than `k` were found and `B` was below the range, the guess was too small and the query runs
//! again over the whole range, so the guess only affects the speed, never the answer. Without
//! a guess (`B = ∞`) a query collects every agent in range, which is fine for a few queries
//! but slow in a dense crowd.
//!
//! # Same answer as the scan
//!
//! Neighbours are ordered by `(squared distance, index)`, ties broken by the lower index exactly
//! like the stable sort of [`crate::orca::select_neighbors`], and squared distances are
//! computed with the same operations, `(p_j − p)·(p_j − p)`. Every agent the `k` best can
//! include is collected: when at least `k` candidates are within `B`, the `k` best of the
//! crowd are among them; otherwise the search covers the whole range. A box is skipped only
//! when its squared distance to the query exceeds `B` or reaches the range: that distance is
//! computed with the same rounded operations as the point distances and rounding is monotone,
//! so it never exceeds the squared distance of an agent inside. Agents whose position is not
//! finite are never anybody's neighbour in the scan (their distance is NaN or infinite), so
//! the tree leaves them out.

use crate::lp::Vec2;

/// Agents per leaf: larger nodes are split. Leaves are scanned without branches, so they can
/// be larger than in a tree that is searched point by point.
const LEAF_SIZE: usize = 16;

/// Up to this many candidates are sorted by insertion.
const SORT_MAX: usize = 8;

/// Up to this many candidates the best `k` are picked by counting (`O(m²)` branch-free
/// comparisons); more are sorted.
const RANK_MAX: usize = 48;

/// A query's candidates and its result: the `k` best `(squared distance, index)` pairs,
/// closest first.
#[derive(Clone, Debug, Default)]
pub struct NeighborList {
    entries: Vec<(f64, usize)>,
    /// Candidates: `count` valid entries; the buffers are longer than the largest number of
    /// candidates, so that an append can write before it knows whether it keeps.
    cand_dist: Vec<f64>,
    cand_index: Vec<usize>,
    count: usize,
    range_sq: f64,
    k: usize,
}

impl NeighborList {
    /// An empty list; [`NeighborList::reset`] sets the range and the count before a query.
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts a query for the `max_neighbors` closest agents strictly within `neighbor_dist`.
    pub fn reset(&mut self, neighbor_dist: f64, max_neighbors: usize) {
        self.entries.clear();
        self.count = 0;
        self.range_sq = neighbor_dist * neighbor_dist;
        self.k = max_neighbors;
    }

    /// The neighbours found, closest first, as `(squared distance, index)`.
    pub fn entries(&self) -> &[(f64, usize)] {
        &self.entries
    }

    /// The neighbours' indices, closest first.
    pub fn indices(&self) -> impl ExactSizeIterator<Item = usize> + '_ {
        self.entries.iter().map(|&(_, i)| i)
    }

    /// Prepares for at most `n` candidates.
    fn begin(&mut self, n: usize) {
        self.count = 0;
        // Room for one more (an append writes before it knows whether it keeps) and for the
        // padding of `finish`.
        if self.cand_dist.len() < n + 4 {
            self.cand_dist.resize(n + 4, 0.0);
            self.cand_index.resize(n + 4, 0);
        }
    }

    /// A sink for the candidates (see [`Sink`]).
    fn sink(&mut self) -> Sink<'_> {
        Sink {
            dist: &mut self.cand_dist,
            index: &mut self.cand_index,
            count: self.count,
        }
    }

    /// Moves the `k` best candidates, in order, to `entries`.
    fn finish(&mut self) {
        let m = self.count;
        let k = self.k.min(m);
        self.entries.clear();
        if m <= SORT_MAX {
            // A handful: insertion sort.
            for i in 0..m {
                let (d, id) = (self.cand_dist[i], self.cand_index[i]);
                let mut at = self.entries.len();
                self.entries.push((d, id));
                while at > 0 {
                    let (e, ie) = self.entries[at - 1];
                    if e < d || (e == d && ie < id) {
                        break;
                    }
                    self.entries[at] = (e, ie);
                    at -= 1;
                }
                self.entries[at] = (d, id);
            }
            self.entries.truncate(k);
        } else if m <= RANK_MAX {
            // The rank of a candidate is the number of candidates that beat it: closer ones,
            // and equally close ones with a lower index. Ranks are distinct (indices are), so
            // each candidate goes to its own slot and the first `k` slots are the answer, in
            // order. The counting loops have no data-dependent branch (and vectorise): the
            // candidates are padded to a multiple of 4 with infinite distances, which beat
            // nobody and tie with nobody (every candidate is closer than the range).
            let padded = m.next_multiple_of(4);
            self.cand_dist[m..padded].fill(f64::INFINITY);
            self.entries.resize(m, (0.0, 0));
            let dist = &self.cand_dist[..padded];
            let index = &self.cand_index[..m];
            for i in 0..m {
                let d = dist[i];
                let (mut closer, mut equal) = (0usize, 0usize);
                for &e in dist {
                    closer += (e < d) as usize;
                    equal += (e == d) as usize;
                }
                let mut rank = closer;
                if equal > 1 {
                    // Ties (rare): the lower indices go first.
                    let id = index[i];
                    rank += (0..m).filter(|&j| dist[j] == d && index[j] < id).count();
                }
                self.entries[rank] = (d, index[i]);
            }
            self.entries.truncate(k);
        } else {
            self.entries.extend(
                self.cand_dist[..m]
                    .iter()
                    .copied()
                    .zip(self.cand_index[..m].iter().copied()),
            );
            self.entries
                .sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            self.entries.truncate(k);
        }
    }

    /// Whether a search limited to squared distance `bound_sq` collected enough: at least `k`
    /// candidates, or it covered the whole range.
    fn complete(&self, bound_sq: f64) -> bool {
        self.count >= self.k || bound_sq >= self.range_sq
    }
}

/// Where a search appends its candidates.
struct Sink<'a> {
    dist: &'a mut [f64],
    index: &'a mut [usize],
    count: usize,
}

/// The brute-force scan over `positions`: every agent but `exclude` is a candidate. Fills
/// `out` (after [`NeighborList::reset`]) with what [`crate::orca::select_neighbors`] returns.
pub fn scan_neighbors(
    positions: &[Vec2],
    position: Vec2,
    exclude: Option<usize>,
    out: &mut NeighborList,
) {
    scan_neighbors_within(positions, position, exclude, f64::INFINITY, out);
}

/// [`scan_neighbors`] given a guess `bound_sq` of the `k`-th squared distance: the same result,
/// found faster when the guess is close (see the module docs).
pub fn scan_neighbors_within(
    positions: &[Vec2],
    position: Vec2,
    exclude: Option<usize>,
    bound_sq: f64,
    out: &mut NeighborList,
) {
    let exclude = exclude.unwrap_or(usize::MAX);
    let scan = |out: &mut NeighborList, bound: f64| {
        out.begin(positions.len());
        let range_sq = out.range_sq;
        let Sink { dist, index, count } = out.sink();
        let mut c = count;
        for (j, p) in positions.iter().enumerate() {
            let d = (*p - position).norm_sq();
            // Branch-free append: the slot after the last candidate is always free.
            dist[c] = d;
            index[c] = j;
            c += ((d <= bound) & (d < range_sq) & (j != exclude)) as usize;
        }
        out.count = c;
    };
    out.begin(0);
    if out.k > 0 {
        scan(out, bound_sq);
        if !out.complete(bound_sq) {
            scan(out, out.range_sq);
        }
    }
    out.finish();
}

/// The larger of two numbers that are not NaN (one instruction, no branch).
#[inline(always)]
fn max(a: f64, b: f64) -> f64 {
    if a > b { a } else { b }
}

#[derive(Clone, Copy, Debug)]
struct Node {
    min: Vec2,
    max: Vec2,
    /// The node's agents are `begin..end` in tree order.
    begin: u32,
    end: u32,
    /// The right child (the left one is the next node); 0 for a leaf.
    right: u32,
}

#[derive(Clone, Copy, Debug)]
struct Point {
    position: Vec2,
    index: usize,
}

/// A k-d tree over agent positions, rebuilt each step by [`AgentTree::build`] (its buffers are
/// reused, so a rebuild does not allocate once the crowd's size is reached).
#[derive(Clone, Debug, Default)]
pub struct AgentTree {
    nodes: Vec<Node>,
    /// Build scratch: the agents being partitioned.
    points: Vec<Point>,
    /// The agents in tree order (each node's agents are contiguous), by coordinate.
    xs: Vec<f64>,
    ys: Vec<f64>,
    indices: Vec<usize>,
}

impl AgentTree {
    /// An empty tree.
    pub fn new() -> Self {
        Self::default()
    }

    /// Rebuilds the tree over `positions` (agent `i` at `positions[i]`); agents with a
    /// non-finite coordinate are left out (they are nobody's neighbour).
    ///
    /// # Panics
    /// If there are more than `u32::MAX` agents.
    pub fn build(&mut self, positions: &[Vec2]) {
        self.points.clear();
        self.points.extend(
            positions
                .iter()
                .enumerate()
                .filter(|(_, p)| p.x.is_finite() && p.y.is_finite())
                .map(|(index, &position)| Point { position, index }),
        );
        assert!(
            u32::try_from(self.points.len()).is_ok(),
            "AgentTree holds at most u32::MAX agents"
        );
        self.nodes.clear();
        if !self.points.is_empty() {
            self.build_node(0, self.points.len());
        }
        self.xs.clear();
        self.ys.clear();
        self.indices.clear();
        self.xs.extend(self.points.iter().map(|p| p.position.x));
        self.ys.extend(self.points.iter().map(|p| p.position.y));
        self.indices.extend(self.points.iter().map(|p| p.index));
    }

    /// Builds the node of `points[begin..end]` (non-empty) and its subtree, depth first.
    fn build_node(&mut self, begin: usize, end: usize) -> usize {
        let first = self.points[begin].position;
        let (mut min, mut max) = (first, first);
        for p in &self.points[begin + 1..end] {
            // The positions are finite: plain comparisons suffice.
            let q = p.position;
            min.x = if q.x < min.x { q.x } else { min.x };
            min.y = if q.y < min.y { q.y } else { min.y };
            max.x = if q.x > max.x { q.x } else { max.x };
            max.y = if q.y > max.y { q.y } else { max.y };
        }
        let node = self.nodes.len();
        // `build` checked that every index into `points` fits in u32.
        self.nodes.push(Node {
            min,
            max,
            begin: begin as u32,
            end: end as u32,
            right: 0,
        });
        let count = end - begin;
        if count <= LEAF_SIZE {
            return node;
        }
        // Split at the middle of the longer side (RVO2's rule), with a branch-free Lomuto
        // partition: `slice[..left]` below the split, `slice[left..i]` at or above it.
        let along_x = max.x - min.x > max.y - min.y;
        let split = 0.5
            * if along_x {
                min.x + max.x
            } else {
                min.y + max.y
            };
        let slice = &mut self.points[begin..end];
        let mut left = 0;
        for i in 0..slice.len() {
            let p = slice[i].position;
            let below = if along_x { p.x < split } else { p.y < split };
            slice.swap(left, i);
            left += below as usize;
        }
        // Coincident or very unevenly spread agents: split by count instead, so that the depth
        // stays logarithmic whatever the positions.
        if left < count / 8 || left > count - count / 8 {
            left = count / 2;
            let coord = |p: &Point| if along_x { p.position.x } else { p.position.y };
            slice.select_nth_unstable_by(left, |a, b| coord(a).total_cmp(&coord(b)));
        }
        self.build_node(begin, begin + left);
        let right = self.build_node(begin + left, end);
        self.nodes[node].right = right as u32;
        node
    }

    /// Fills `out` (after [`NeighborList::reset`]) with the closest agents to `position`, all
    /// agents but `exclude` being candidates: the same list as [`scan_neighbors`] over the
    /// positions the tree was built from.
    pub fn query(&self, position: Vec2, exclude: Option<usize>, out: &mut NeighborList) {
        self.query_within(position, exclude, f64::INFINITY, out);
    }

    /// [`AgentTree::query`] given a guess `bound_sq` of the `k`-th squared distance: the same
    /// result, found faster when the guess is close (see the module docs).
    pub fn query_within(
        &self,
        position: Vec2,
        exclude: Option<usize>,
        bound_sq: f64,
        out: &mut NeighborList,
    ) {
        // A non-finite position has a NaN or infinite distance to everybody: no neighbours.
        let searchable =
            out.k > 0 && !self.nodes.is_empty() && position.x.is_finite() && position.y.is_finite();
        out.begin(self.indices.len());
        if searchable {
            let exclude = exclude.unwrap_or(usize::MAX);
            let range_sq = out.range_sq;
            let mut sink = out.sink();
            self.collect(0, position, bound_sq, range_sq, exclude, &mut sink);
            out.count = sink.count;
            if !out.complete(bound_sq) {
                out.begin(self.indices.len());
                let mut sink = out.sink();
                self.collect(0, position, range_sq, range_sq, exclude, &mut sink);
                out.count = sink.count;
            }
        }
        out.finish();
    }

    /// The squared distance from `q` to node `n`'s box: a lower bound of the squared distance
    /// to any agent in it, computed with the same rounded operations (see the module docs).
    #[inline]
    fn box_dist_sq(&self, n: usize, q: Vec2) -> f64 {
        let node = &self.nodes[n];
        let dx = max(max(node.min.x - q.x, q.x - node.max.x), 0.0);
        let dy = max(max(node.min.y - q.y, q.y - node.max.y), 0.0);
        dx * dx + dy * dy
    }

    /// Collects the agents of node `n` within `bound_sq` and closer than `range_sq` to `q`.
    fn collect(
        &self,
        n: usize,
        q: Vec2,
        bound_sq: f64,
        range_sq: f64,
        exclude: usize,
        sink: &mut Sink<'_>,
    ) {
        let box_dist = self.box_dist_sq(n, q);
        if !(box_dist <= bound_sq && box_dist < range_sq) {
            return;
        }
        let node = self.nodes[n];
        if node.right != 0 {
            self.collect(n + 1, q, bound_sq, range_sq, exclude, sink);
            self.collect(node.right as usize, q, bound_sq, range_sq, exclude, sink);
            return;
        }
        let range = node.begin as usize..node.end as usize;
        let (xs, ys, ids) = (
            &self.xs[range.clone()],
            &self.ys[range.clone()],
            &self.indices[range],
        );
        let Sink { dist, index, count } = sink;
        let mut c = *count;
        for t in 0..ids.len() {
            let d = (Vec2::new(xs[t], ys[t]) - q).norm_sq();
            // Branch-free append: the slot after the last candidate is always free.
            dist[c] = d;
            index[c] = ids[t];
            c += ((d <= bound_sq) & (d < range_sq) & (ids[t] != exclude)) as usize;
        }
        *count = c;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::orca::{Neighbor, select_neighbors};

    fn reference(positions: &[Vec2], q: Vec2, dist: f64, k: usize) -> Vec<usize> {
        let others: Vec<Neighbor> = positions
            .iter()
            .map(|&position| Neighbor {
                position,
                velocity: Vec2::ZERO,
                radius: 0.0,
            })
            .collect();
        select_neighbors(q, &others, dist, k)
    }

    /// The scan and the tree, without and with guesses of the bound (too small, exact, large).
    fn all_answers(positions: &[Vec2], q: Vec2, dist: f64, k: usize) -> Vec<Vec<usize>> {
        let mut tree = AgentTree::new();
        tree.build(positions);
        let mut list = NeighborList::new();
        let mut answers = Vec::new();
        for guess in [f64::INFINITY, 0.0, 1.0, 9.0, 50.0, f64::NAN] {
            list.reset(dist, k);
            scan_neighbors_within(positions, q, None, guess, &mut list);
            answers.push(list.indices().collect());
            list.reset(dist, k);
            tree.query_within(q, None, guess, &mut list);
            answers.push(list.indices().collect());
        }
        answers
    }

    #[test]
    fn lattice_with_ties_and_agents_exactly_at_range() {
        // A 21 × 21 lattice of spacing 3: at range 15 the agents at (±15, 0), (±9, ±12), …
        // are exactly at range (excluded), and every ring holds 4 or 8 tied agents.
        let positions: Vec<Vec2> = (0..21 * 21)
            .map(|i| Vec2::new(3.0 * (i % 21) as f64 - 30.0, 3.0 * (i / 21) as f64 - 30.0))
            .collect();
        for q in [Vec2::ZERO, Vec2::new(1.5, 0.0), Vec2::new(-30.0, 30.0)] {
            for k in [0, 1, 3, 4, 5, 10, 50, 500] {
                for dist in [0.0, 3.0, 15.0, 15.000001, 100.0] {
                    let expected = reference(&positions, q, dist, k);
                    for answer in all_answers(&positions, q, dist, k) {
                        assert_eq!(answer, expected, "q {q:?}, k {k}, dist {dist}");
                    }
                }
            }
        }
    }

    #[test]
    fn coincident_and_non_finite_agents() {
        let mut positions = vec![Vec2::new(1.0, 1.0); 40];
        positions.extend([
            Vec2::new(f64::NAN, 0.0),
            Vec2::new(f64::INFINITY, 0.0),
            Vec2::new(2.0, 1.0),
            Vec2::new(0.0, 1.0),
        ]);
        for k in [1, 10, 45] {
            let q = Vec2::new(1.0, 1.0);
            let expected = reference(&positions, q, 5.0, k);
            for answer in all_answers(&positions, q, 5.0, k) {
                assert_eq!(answer, expected);
            }
            for answer in all_answers(&positions, Vec2::new(f64::NAN, 1.0), 5.0, k) {
                assert!(answer.is_empty());
            }
        }
    }

    #[test]
    fn exclude_skips_the_querying_agent() {
        let positions: Vec<Vec2> = (0..30).map(|i| Vec2::new(i as f64, 0.0)).collect();
        let mut tree = AgentTree::new();
        tree.build(&positions);
        let mut list = NeighborList::new();
        list.reset(2.5, 10);
        tree.query(positions[10], Some(10), &mut list);
        assert_eq!(list.indices().collect::<Vec<_>>(), vec![9, 11, 8, 12]);
        list.reset(2.5, 10);
        scan_neighbors(&positions, positions[10], Some(10), &mut list);
        assert_eq!(list.indices().collect::<Vec<_>>(), vec![9, 11, 8, 12]);
    }
}
