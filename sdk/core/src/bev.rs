//! The ego-centred bird's-eye-view (BEV) raster of the other agents (paper §III-A).
//!
//! The same code runs when the training tuples are built from pedestrian data and when the
//! planner observes a crowd at inference, so the network sees identical inputs in both.
//!
//! # Layout
//! A raster is `[3, H, W]` row-major `f32` with `H = W = `[`BevSpec::cells`]:
//! * channel 0: binary occupancy (1 inside an agent's disc, else 0);
//! * channel 1: the agent's velocity `v_x` in the **ego frame**, m/s, unscaled;
//! * channel 2: the agent's velocity `v_y` in the ego frame, m/s, unscaled.
//!
//! Velocity channels are 0 wherever occupancy is 0.
//!
//! # Geometry
//! The ego frame has `x` forward and `y` to the left. The grid is **ahead-biased**: it covers
//! [`AHEAD_FRACTION`] of its length in front of the ego and the rest behind, and is centred
//! laterally. Row 0 is the farthest ahead and column 0 the farthest to the left, so a raster
//! drawn as an image shows the ego heading "up". With the default 32 × 32 cells of 0.3 m the
//! raster spans 9.6 m × 9.6 m: 7.2 m ahead, 2.4 m behind and 4.8 m to either side, which
//! holds the 3.2 s planning horizon of a pedestrian walking at up to 2.2 m/s.
//!
//! # Discs
//! Every agent is a disc of its radius. A cell is occupied when its centre lies inside a disc
//! or when it holds a disc's centre (so an agent smaller than a cell is never lost). Where
//! discs overlap, the velocity of the agent whose centre is nearest to the cell centre is
//! written (ties go to the earlier agent), which makes the raster independent of the
//! agents' order except for exact ties.

use crate::planner::AgentState;
use crate::se2::Pose2;
use serde::{Deserialize, Serialize};
use std::borrow::Borrow;

/// Fraction of the raster length that lies ahead of the ego.
pub const AHEAD_FRACTION: f64 = 0.75;

/// Number of channels of a BEV raster (occupancy, `v_x`, `v_y`).
pub const CHANNELS: usize = 3;

/// Size and resolution of the square BEV raster.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BevSpec {
    /// Cells per side (`H = W`). Default 32.
    pub cells: usize,
    /// Edge length of one cell in metres. Default 0.3.
    pub resolution: f64,
}

impl Default for BevSpec {
    fn default() -> Self {
        Self {
            cells: 32,
            resolution: 0.3,
        }
    }
}

/// A [`BevSpec`] that cannot describe a raster.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BevError {
    /// `cells` (the value given) is 0 or more than 1024.
    #[error("bev.cells must be between 1 and 1024, got {0}")]
    Cells(usize),
    /// `resolution` (the value given, m) is zero, negative or not finite.
    #[error("bev.resolution must be finite and positive, got {0}")]
    Resolution(f64),
}

/// One agent as the rasterizer needs it: world-frame position and velocity, and its radius.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct BevAgent {
    /// Position `[x, y]`, metres, world frame.
    pub position: [f64; 2],
    /// Velocity `[v_x, v_y]`, m/s, world frame.
    pub velocity: [f64; 2],
    /// Disc radius, metres.
    pub radius: f64,
}

impl From<&AgentState> for BevAgent {
    fn from(a: &AgentState) -> Self {
        Self {
            position: a.position,
            velocity: a.velocity,
            radius: a.radius,
        }
    }
}

impl BevSpec {
    /// Checks the spec describes a usable raster.
    pub fn validate(&self) -> Result<(), BevError> {
        if self.cells == 0 || self.cells > 1024 {
            return Err(BevError::Cells(self.cells));
        }
        if !(self.resolution.is_finite() && self.resolution > 0.0) {
            return Err(BevError::Resolution(self.resolution));
        }
        Ok(())
    }

    /// Number of `f32` values in one raster, `3·H·W`.
    pub fn len(&self) -> usize {
        CHANNELS * self.cells * self.cells
    }

    /// True when the raster holds no cell.
    pub fn is_empty(&self) -> bool {
        self.cells == 0
    }

    /// Side length of the raster in metres.
    pub fn extent(&self) -> f64 {
        self.cells as f64 * self.resolution
    }

    /// How far the raster reaches ahead of the ego (metres, ego `x`).
    pub fn ahead(&self) -> f64 {
        AHEAD_FRACTION * self.extent()
    }

    /// How far the raster reaches behind the ego (metres, positive).
    pub fn behind(&self) -> f64 {
        self.extent() - self.ahead()
    }

    /// How far the raster reaches to either side (metres).
    pub fn half_width(&self) -> f64 {
        0.5 * self.extent()
    }

    /// The `(row, col)` of the cell holding an ego-frame point, if it is inside the raster.
    pub fn cell_of(&self, p: [f64; 2]) -> Option<(usize, usize)> {
        let r = (self.ahead() - p[0]) / self.resolution;
        let c = (self.half_width() - p[1]) / self.resolution;
        let n = self.cells as f64;
        if r >= 0.0 && r < n && c >= 0.0 && c < n {
            Some((r as usize, c as usize))
        } else {
            None
        }
    }

    /// The ego-frame centre of cell `(row, col)`.
    pub fn cell_center(&self, row: usize, col: usize) -> [f64; 2] {
        [
            self.ahead() - (row as f64 + 0.5) * self.resolution,
            self.half_width() - (col as f64 + 0.5) * self.resolution,
        ]
    }

    /// True when a disc at ego-frame `p` with radius `r` can touch the raster.
    pub fn touches(&self, p: [f64; 2], r: f64) -> bool {
        p[0] < self.ahead() + r && p[0] > -self.behind() - r && p[1].abs() < self.half_width() + r
    }

    /// Index of `(channel, row, col)` in the flat `[3, H, W]` raster.
    pub fn index(&self, channel: usize, row: usize, col: usize) -> usize {
        (channel * self.cells + row) * self.cells + col
    }
}

/// Rasterizes world-frame agents around the ego pose into `out` (`[3, H, W]`, overwritten).
///
/// `spec` may be passed by value or by reference. Agents with a non-finite field are ignored
/// (the planner validates its observation before it gets here).
///
/// # Panics
/// If `out.len() != spec.len()` (a programming error).
pub fn rasterize(spec: impl Borrow<BevSpec>, ego: Pose2, agents: &[AgentState], out: &mut [f32]) {
    rasterize_agents(spec, ego, agents.iter().map(BevAgent::from), out);
}

/// [`rasterize`] over any iterator of [`BevAgent`]s (no [`AgentState`] needed).
///
/// # Panics
/// If `out.len() != spec.len()` (a programming error).
pub fn rasterize_agents<I>(spec: impl Borrow<BevSpec>, ego: Pose2, agents: I, out: &mut [f32])
where
    I: IntoIterator<Item = BevAgent>,
{
    let spec = spec.borrow();
    assert_eq!(
        out.len(),
        spec.len(),
        "rasterize: output buffer has the wrong length"
    );
    out.fill(0.0);
    let n = spec.cells;
    if n == 0 {
        return;
    }
    // Squared distance from each cell centre to the nearest agent centre written so far.
    let mut nearest = vec![f64::INFINITY; n * n];
    let res = spec.resolution;
    for a in agents {
        let finite = a.position.iter().chain(&a.velocity).all(|v| v.is_finite())
            && a.radius.is_finite()
            && a.radius >= 0.0;
        if !finite {
            continue;
        }
        let p = ego.inverse_act(a.position);
        let r = a.radius;
        if !spec.touches(p, r.max(res)) {
            continue;
        }
        let v = ego.inverse_rotate(a.velocity);
        let own = spec.cell_of(p);
        // Rows and columns the disc can reach (clamped to the grid).
        let row_lo = ((spec.ahead() - p[0] - r) / res).floor().max(0.0) as usize;
        let row_hi = ((spec.ahead() - p[0] + r) / res)
            .floor()
            .min(n as f64 - 1.0);
        let col_lo = ((spec.half_width() - p[1] - r) / res).floor().max(0.0) as usize;
        let col_hi = ((spec.half_width() - p[1] + r) / res)
            .floor()
            .min(n as f64 - 1.0);
        if row_hi < 0.0 || col_hi < 0.0 {
            continue;
        }
        let (row_hi, col_hi) = (row_hi as usize, col_hi as usize);
        let mut write = |row: usize, col: usize, d2: f64| {
            let k = row * n + col;
            if d2 < nearest[k] {
                nearest[k] = d2;
                out[spec.index(0, row, col)] = 1.0;
                out[spec.index(1, row, col)] = v[0] as f32;
                out[spec.index(2, row, col)] = v[1] as f32;
            }
        };
        for row in row_lo..=row_hi {
            for col in col_lo..=col_hi {
                let c = spec.cell_center(row, col);
                let d2 = (c[0] - p[0]).powi(2) + (c[1] - p[1]).powi(2);
                if d2 <= r * r {
                    write(row, col, d2);
                }
            }
        }
        if let Some((row, col)) = own {
            let c = spec.cell_center(row, col);
            let d2 = (c[0] - p[0]).powi(2) + (c[1] - p[1]).powi(2);
            write(row, col, d2);
        }
    }
}

/// Draws `agent` (ego frame) over an existing raster `out`: where its disc lies, its occupancy
/// and velocity replace what was there; elsewhere `out` is unchanged. `scratch` is resized to
/// the raster's length and overwritten.
pub fn overlay_agent(spec: BevSpec, agent: BevAgent, out: &mut [f32], scratch: &mut Vec<f32>) {
    scratch.resize(spec.len(), 0.0);
    rasterize_agents(spec, Pose2::IDENTITY, [agent], scratch);
    let plane = spec.cells * spec.cells;
    for k in 0..plane {
        if scratch[k] > 0.5 {
            for c in 0..CHANNELS {
                out[c * plane + k] = scratch[c * plane + k];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    fn agent(id: u64, position: [f64; 2], velocity: [f64; 2], radius: f64) -> AgentState {
        AgentState {
            id,
            position,
            velocity,
            radius,
            history: Vec::new(),
        }
    }

    #[test]
    fn default_geometry() {
        let s = BevSpec::default();
        s.validate().unwrap();
        assert_eq!(s.len(), 3 * 32 * 32);
        assert_relative_eq!(s.extent(), 9.6, epsilon = 1e-12);
        assert_relative_eq!(s.ahead(), 7.2, epsilon = 1e-12);
        assert_relative_eq!(s.behind(), 2.4, epsilon = 1e-12);
        // The ego sits on the corner between rows 23/24 and columns 15/16.
        assert_eq!(s.cell_of([0.01, 0.01]), Some((23, 15)));
        assert_eq!(s.cell_of([-0.01, -0.01]), Some((24, 16)));
        assert_eq!(s.cell_of([7.3, 0.0]), None);
        assert_eq!(s.cell_of([0.0, -4.9]), None);
        let c = s.cell_center(0, 0);
        assert_relative_eq!(c[0], 7.05, epsilon = 1e-12);
        assert_relative_eq!(c[1], 4.65, epsilon = 1e-12);
    }

    #[test]
    fn validate_rejects_bad_specs() {
        assert_eq!(
            BevSpec {
                cells: 0,
                resolution: 0.3
            }
            .validate(),
            Err(BevError::Cells(0))
        );
        assert!(
            BevSpec {
                cells: 8,
                resolution: 0.0
            }
            .validate()
            .is_err()
        );
        assert!(
            BevSpec {
                cells: 8,
                resolution: f64::NAN
            }
            .validate()
            .is_err()
        );
    }

    #[test]
    fn point_agent_lands_in_its_cell_with_ego_frame_velocity() {
        let s = BevSpec::default();
        // Ego at (1, 2) heading +y (θ = π/2); an agent 3 m ahead of it and 0.6 m to its left.
        let ego = Pose2::new(1.0, 2.0, std::f64::consts::FRAC_PI_2);
        let a = agent(7, [1.0 - 0.6 - 0.05, 2.0 + 3.0 + 0.05], [1.0, 0.0], 0.0);
        let mut out = vec![0.0; s.len()];
        rasterize(s, ego, &[a], &mut out);
        let (row, col) = s.cell_of([3.05, 0.65]).unwrap();
        assert_eq!(out.iter().filter(|&&v| v == 1.0).count(), 1);
        assert_relative_eq!(out[s.index(0, row, col)], 1.0);
        // World +x is the ego's right, i.e. ego -y.
        assert_relative_eq!(out[s.index(1, row, col)], 0.0, epsilon = 1e-7);
        assert_relative_eq!(out[s.index(2, row, col)], -1.0, epsilon = 1e-7);
    }

    #[test]
    fn disc_covers_the_cells_whose_centres_it_contains() {
        let s = BevSpec {
            cells: 20,
            resolution: 0.5,
        };
        // Centre exactly on a cell centre: a disc covers that cell and its 4 neighbours
        // at distance 0.5 (radius 0.55), radius 0.75 the 3x3 block (corners at 0.707).
        let c = s.cell_center(10, 10);
        for (r, expected) in [(0.1, 1), (0.55, 5), (0.75, 9)] {
            let mut out = vec![0.0; s.len()];
            rasterize(s, Pose2::IDENTITY, &[agent(0, c, [0.5, 0.25], r)], &mut out);
            let occ = out[..400].iter().filter(|&&v| v == 1.0).count();
            assert_eq!(occ, expected, "radius {r}");
            let vx_sum: f32 = out[400..800].iter().sum();
            assert_relative_eq!(vx_sum, 0.5 * expected as f32, epsilon = 1e-5);
        }
    }

    #[test]
    fn outside_agents_and_non_finite_agents_leave_zeros() {
        let s = BevSpec::default();
        let mut out = vec![5.0; s.len()];
        let far = agent(1, [20.0, 0.0], [1.0, 1.0], 0.3);
        let bad = agent(2, [1.0, f64::NAN], [1.0, 1.0], 0.3);
        rasterize(s, Pose2::IDENTITY, &[far, bad], &mut out);
        assert!(out.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn nearest_agent_wins_overlaps_regardless_of_order() {
        let s = BevSpec {
            cells: 16,
            resolution: 0.25,
        };
        let a = agent(1, [0.5, 0.0], [1.0, 0.0], 0.6);
        let b = agent(2, [1.0, 0.0], [-1.0, 0.0], 0.6);
        let mut ab = vec![0.0; s.len()];
        let mut ba = vec![0.0; s.len()];
        rasterize(s, Pose2::IDENTITY, &[a.clone(), b.clone()], &mut ab);
        rasterize(s, Pose2::IDENTITY, &[b, a], &mut ba);
        assert_eq!(ab, ba);
        let (row, col) = s.cell_of([0.65, 0.1]).unwrap();
        assert_relative_eq!(ab[s.index(1, row, col)], 1.0);
        let (row, col) = s.cell_of([0.8, 0.1]).unwrap();
        assert_relative_eq!(ab[s.index(1, row, col)], -1.0);
    }

    proptest! {
        /// Rasterizing world agents around an ego pose equals rasterizing the same agents
        /// already expressed in the ego frame around the identity.
        #[test]
        fn frame_invariance(
            ex in -5.0..5.0f64, ey in -5.0..5.0f64, et in -3.1..3.1f64,
            pts in prop::collection::vec((-6.0..8.0f64, -6.0..6.0f64, -2.0..2.0f64, -2.0..2.0f64), 0..12),
        ) {
            let s = BevSpec::default();
            let ego = Pose2::new(ex, ey, et);
            let world: Vec<AgentState> = pts.iter().enumerate().map(|(i, &(x, y, vx, vy))| {
                agent(i as u64, ego.act([x, y]), ego.rotate([vx, vy]), 0.3)
            }).collect();
            let local: Vec<AgentState> = pts.iter().enumerate().map(|(i, &(x, y, vx, vy))| {
                agent(i as u64, [x, y], [vx, vy], 0.3)
            }).collect();
            let mut a = vec![0.0; s.len()];
            let mut b = vec![0.0; s.len()];
            rasterize(s, ego, &world, &mut a);
            rasterize(s, Pose2::IDENTITY, &local, &mut b);
            // Float round-off may move a centre across a cell border; allow a few cells.
            let differ = a[..1024].iter().zip(&b[..1024]).filter(|(x, y)| x != y).count();
            prop_assert!(differ <= 2, "{differ} occupancy cells differ");
        }
    }
}
