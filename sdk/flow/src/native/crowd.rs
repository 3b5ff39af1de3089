//! The crowd pathway of [`crate::net::CondUnet1d::crowd_features`] on `f32` buffers: per
//! waypoint, a shared two-layer MLP over every (crowd point, waypoint) pair and a max over the
//! points, and the backward pass of its input (the waypoints' positions and headings).
//!
//! The forward pass works through the pairs in tiles of whole waypoints (each tile's pair
//! features and both layers' activations stay in cache, one matrix product per layer and tile)
//! and keeps only which point each output's max picked, with the second layer's
//! pre-activation there. The max passes its gradient to that one point, so the backward pass
//! recomputes the first layer for the picked pairs alone and pulls them back through both: at
//! most `width` of the `points` pairs of a waypoint, where a dense pass would pull every pair
//! back through both layers.

use super::kernels::{
    activate_into, bias_activate_in_place, derivative_in_place, multiversion, resize_for_overwrite,
    sgemm,
};
use super::net::{WeightError, Weights, gather_rows, take};
use crate::config::{Activation, CrowdConfig};
use crate::net::{CROWD_FEATURES, CROWD_PAIR_FEATURES, TRAJ_CHANNELS};

/// Waypoints per tile of the forward pass: the loops along a tile's waypoints fill whole
/// vector registers, and its activations (`2 · width · points · 64` values, 640 KiB for the
/// shipped 32 × 40) stay in the L2 cache.
const TILE_WAYPOINTS: usize = 64;

/// The pathway's weights.
#[derive(Debug)]
pub(crate) struct Crowd {
    /// `[width, 5]`, `[width]`.
    w0: Vec<f32>,
    b0: Vec<f32>,
    /// `[width, width]`, `[width]`.
    w1: Vec<f32>,
    b1: Vec<f32>,
    width: usize,
    step: f32,
    act: Activation,
}

/// What the backward pass needs of one forward pass.
#[derive(Debug, Default)]
pub(crate) struct CrowdTape {
    /// Present points (the first `present` rows of the points).
    present: usize,
    /// Per output `(w, b, j)`: the point the max picked, and the second layer's
    /// pre-activation there (the slope the gradient passes through).
    arg: Vec<u32>,
    pre: Vec<f32>,
    /// The trajectory features `[5, K, T]` the pass read.
    feat: Vec<f32>,
}

impl CrowdTape {
    /// What a pass over rows `rows` of this pass's `batch` rows of `t_len` waypoints records.
    pub(crate) fn gather(&self, (batch, t_len): (usize, usize), rows: &[usize], into: &mut Self) {
        into.present = self.present;
        gather_rows(&self.arg, batch, t_len, rows, &mut into.arg);
        gather_rows(&self.pre, batch, t_len, rows, &mut into.pre);
        gather_rows(&self.feat, batch, t_len, rows, &mut into.feat);
    }
}

/// Buffers of the passes, reused from call to call (no state between calls).
#[derive(Debug, Default)]
pub(crate) struct CrowdScratch {
    pairs: Vec<f32>,
    z0: Vec<f32>,
    z1: Vec<f32>,
    /// Forward: per output of a tile, the largest and smallest pre-activation, activated, and
    /// the points they belong to; each waypoint's time ahead.
    ends: Vec<f32>,
    ends_act: Vec<f32>,
    ends_at: Vec<u32>,
    tau: Vec<f32>,
    /// Backward: the gradient at the first layer's activations, the second layer's gradient,
    /// the picked `(waypoint, point)` pairs, each output's column among them, the column of
    /// each point one waypoint picked, the second activation's slope at each output's pick.
    a0: Vec<f32>,
    dz: Vec<f32>,
    cols: Vec<(u32, u32)>,
    col_of: Vec<u32>,
    picks: Vec<u32>,
    slopes: Vec<f32>,
}

const PAIR: usize = CROWD_PAIR_FEATURES as usize;

impl Crowd {
    pub(crate) fn load(
        cfg: &CrowdConfig,
        act: Activation,
        w: &mut Weights,
    ) -> Result<Self, WeightError> {
        let width = cfg.width;
        Ok(Self {
            w0: take(w, "crowd.fc0.weight", width * PAIR)?,
            b0: take(w, "crowd.fc0.bias", width)?,
            w1: take(w, "crowd.fc1.weight", width * width)?,
            b1: take(w, "crowd.fc1.bias", width)?,
            width,
            step: cfg.step as f32,
            act,
        })
    }

    /// Appends the pathway's features `[width, K, T]` to `feat` (`[5, K, T]` on entry, so
    /// `[5 + width, K, T]` after), reading `points` (`N × 5`, present rows first). Returns the
    /// multiply-accumulates of its matrix products: the MLP on `K · T` times the present
    /// points.
    pub(crate) fn forward(
        &self,
        feat: &mut Vec<f32>,
        (k, t_len): (usize, usize),
        points: &[f32],
        tape: &mut CrowdTape,
        s: &mut CrowdScratch,
    ) -> u64 {
        let plane = k * t_len;
        let traj = TRAJ_CHANNELS as usize * plane;
        tape.feat.clear();
        tape.feat.extend_from_slice(&feat[..traj]);
        let stride = CROWD_FEATURES as usize;
        let present = points
            .chunks_exact(stride)
            .take_while(|p| p[4] > 0.5)
            .count();
        tape.present = present;
        let width = self.width;
        feat.resize(traj + width * plane, 0.0);
        if present == 0 {
            feat[traj..].fill(0.0);
            return 0;
        }
        resize_for_overwrite(&mut tape.arg, width * plane);
        resize_for_overwrite(&mut tape.pre, width * plane);
        s.tau.clear();
        s.tau
            .extend((0..plane).map(|bj| (bj % t_len + 1) as f32 * self.step));
        // A tile's columns run over its waypoints for each point in turn (`n·rows + r`), so
        // that every loop below runs along waypoints, contiguous in the features.
        for bj0 in (0..plane).step_by(TILE_WAYPOINTS) {
            let rows = TILE_WAYPOINTS.min(plane - bj0);
            let m = rows * present;
            resize_for_overwrite(&mut s.pairs, PAIR * m);
            let way = |c: usize| &tape.feat[c * plane + bj0..c * plane + bj0 + rows];
            let waypoints = [way(0), way(1), way(2), way(3), &s.tau[bj0..bj0 + rows]];
            tile_pairs(waypoints, &points[..present * stride], &mut s.pairs);
            product(&self.w0, PAIR, &s.pairs, m, &mut s.z0);
            bias_activate_in_place(self.act, &self.b0, &mut s.z0);
            product(&self.w1, width, &s.z0, m, &mut s.z1);
            // Both activations fall from 0 to a single minimum and rise after it, so an
            // output's largest activation is that of its largest or of its smallest
            // pre-activation: only those two are activated. `ends` is `[width, 2, rows]`.
            // The second layer's bias is added as the extremes are sought.
            resize_for_overwrite(&mut s.ends, 2 * width * rows);
            resize_for_overwrite(&mut s.ends_at, 2 * width * rows);
            for (((z, ends), at), &b) in
                s.z1.chunks_exact(m)
                    .zip(s.ends.chunks_exact_mut(2 * rows))
                    .zip(s.ends_at.chunks_exact_mut(2 * rows))
                    .zip(&self.b1)
            {
                tile_extremes(z, b, rows, ends, at);
            }
            activate_into(self.act, &s.ends, &mut s.ends_act);
            for c in 0..width {
                let span = |i: usize| (2 * c + i) * rows..(2 * c + i + 1) * rows;
                let (hv, lv) = (&s.ends_act[span(0)], &s.ends_act[span(1)]);
                let (ha, la) = (&s.ends_at[span(0)], &s.ends_at[span(1)]);
                let (hp, lp) = (&s.ends[span(0)], &s.ends[span(1)]);
                let out = c * plane + bj0..c * plane + bj0 + rows;
                let best = &mut feat[traj + out.start..traj + out.end];
                let (arg, pre) = (&mut tape.arg[out.clone()], &mut tape.pre[out]);
                for r in 0..rows {
                    // The first point attaining the max, as a search of the activated
                    // outputs picks.
                    let hi = hv[r] > lv[r] || (hv[r] == lv[r] && ha[r] < la[r]);
                    best[r] = if hi { hv[r] } else { lv[r] };
                    arg[r] = if hi { ha[r] } else { la[r] };
                    pre[r] = if hi { hp[r] } else { lp[r] };
                }
            }
        }
        (plane * present * (PAIR + width) * width) as u64
    }

    /// Adds to `dfeat[..5·K·T]` the pull-back of `dfeat[5·K·T..]` (the gradient arriving at
    /// the pathway's features) through the pass recorded in `tape`: only the pairs some
    /// output's max picked carry a gradient, so the first layer is recomputed and both are
    /// pulled back for those columns alone, one matrix product each. Returns the
    /// multiply-accumulates of those products.
    pub(crate) fn backward(
        &self,
        dfeat: &mut [f32],
        (k, t_len): (usize, usize),
        points: &[f32],
        tape: &CrowdTape,
        s: &mut CrowdScratch,
    ) -> u64 {
        if tape.present == 0 {
            return 0;
        }
        let (plane, width) = (k * t_len, self.width);
        let traj = TRAJ_CHANNELS as usize * plane;
        let (dtraj, dcrowd) = dfeat.split_at_mut(traj);
        let stride = CROWD_FEATURES as usize;
        // The picked pairs, grouped by waypoint and in point order within one, and the column
        // of each output's pick.
        s.cols.clear();
        s.col_of.clear();
        s.col_of.resize(width * plane, 0);
        // `picks[n]`: the column of point `n` at the current waypoint, or `NONE`.
        const NONE: u32 = u32::MAX;
        s.picks.clear();
        s.picks.resize(tape.present, NONE);
        for bj in 0..plane {
            for c in 0..width {
                s.picks[tape.arg[c * plane + bj] as usize] = 0;
            }
            for (n, col) in s.picks.iter_mut().enumerate() {
                if *col != NONE {
                    *col = s.cols.len() as u32;
                    s.cols.push((bj as u32, n as u32));
                }
            }
            for c in 0..width {
                let out = c * plane + bj;
                s.col_of[out] = s.picks[tape.arg[out] as usize];
            }
            for c in 0..width {
                s.picks[tape.arg[c * plane + bj] as usize] = NONE;
            }
        }
        let m = s.cols.len();
        resize_for_overwrite(&mut s.pairs, PAIR * m);
        for (col, &(bj, n)) in s.cols.iter().enumerate() {
            let (bj, n) = (bj as usize, n as usize);
            let w = Waypoint::of(&tape.feat, plane, bj);
            let tau = (bj % t_len + 1) as f32 * self.step;
            let f = w.pair(&points[n * stride..(n + 1) * stride], tau);
            for (c, v) in f.iter().enumerate() {
                s.pairs[c * m + col] = *v;
            }
        }
        // The first layer on the picked columns: z0 becomes act'(z0). (The second layer's
        // pre-activation at each pick is the forward pass's, kept in the tape.)
        layer(&self.w0, &self.b0, PAIR, &s.pairs, m, &mut s.z0);
        derivative_in_place(self.act, &mut s.z0);
        // dZ1: each output's gradient at its pick, through the second activation, whose
        // slopes are taken in one vectorised pass; output `(c, bj)` writes column
        // `col_of[c·plane + bj]` of channel `c`'s row of `dz`.
        s.dz.clear();
        s.dz.resize(width * m, 0.0);
        s.slopes.clear();
        s.slopes.extend_from_slice(&tape.pre);
        derivative_in_place(self.act, &mut s.slopes);
        let per_channel = s
            .col_of
            .chunks_exact(plane)
            .zip(s.slopes.chunks_exact(plane))
            .zip(dcrowd[..width * plane].chunks_exact(plane))
            .zip(s.dz.chunks_exact_mut(m));
        for (((cols, slopes), g), dz) in per_channel {
            for ((&col, &slope), &g) in cols.iter().zip(slopes).zip(g) {
                dz[col as usize] = g * slope;
            }
        }
        // dZ0 = act'(z0) ⊙ W1ᵀ·dZ1 (into a0), then dF = W0ᵀ·dZ0 (into pairs).
        resize_for_overwrite(&mut s.a0, width * m);
        sgemm(
            width, m, width, &self.w1, 1, width, &s.dz, m, 1, &mut s.a0, false,
        );
        for (d, &da) in s.a0.iter_mut().zip(&s.z0) {
            *d *= da;
        }
        sgemm(
            PAIR,
            m,
            width,
            &self.w0,
            1,
            PAIR,
            &s.a0,
            m,
            1,
            &mut s.pairs,
            false,
        );
        let mut g = [0f32; 4];
        for (col, &(bj, n)) in s.cols.iter().enumerate() {
            let (bj, n) = (bj as usize, n as usize);
            let w = Waypoint::of(&tape.feat, plane, bj);
            let tau = (bj % t_len + 1) as f32 * self.step;
            let df: [f32; PAIR] = std::array::from_fn(|c| s.pairs[c * m + col]);
            w.pull_back(&points[n * stride..(n + 1) * stride], tau, df, &mut g);
            // The waypoint's last pick: its gradient is complete.
            if s.cols.get(col + 1).is_none_or(|next| next.0 as usize != bj) {
                for (c, v) in g.iter().enumerate() {
                    dtraj[c * plane + bj] += v;
                }
                g = [0.0; 4];
            }
        }
        (m * (2 * PAIR + width) * width) as u64
    }
}

multiversion! {
    /// The pair features `[5, present·rows]` (column `n·rows + r`) of a tile's `rows`
    /// waypoints (`[x, y, cos θ, sin θ, τ]`, one slice of `rows` each) with every point
    /// (`N × 5`), by [`Waypoint::pair`], laid out so that the loop runs along waypoints.
    fn tile_pairs(waypoints: [&[f32]; 5], points: &[f32], pairs: &mut [f32]) {
        let rows = waypoints[0].len();
        let [px, py, cs, sn, tau] = waypoints.map(|w| &w[..rows]);
        let m = pairs.len() / PAIR;
        let (bx_all, rest) = pairs.split_at_mut(m);
        let (by_all, rest) = rest.split_at_mut(m);
        let (dist_all, rest) = rest.split_at_mut(m);
        let (ux_all, uy_all) = rest.split_at_mut(m);
        for (n, p) in points.chunks_exact(CROWD_FEATURES as usize).enumerate() {
            let span = n * rows..(n + 1) * rows;
            let bx = &mut bx_all[span.clone()];
            let by = &mut by_all[span.clone()];
            let dist = &mut dist_all[span.clone()];
            let ux = &mut ux_all[span.clone()];
            let uy = &mut uy_all[span];
            for r in 0..rows {
                let w = Waypoint {
                    px: px[r],
                    py: py[r],
                    cs: cs[r],
                    sn: sn[r],
                };
                [bx[r], by[r], dist[r], ux[r], uy[r]] = w.pair(p, tau[r]);
            }
        }
    }
}

multiversion! {
    /// Per waypoint `r` of one output channel's tile `z` (`[present, rows]`) plus the
    /// channel's bias `b`, the largest and the smallest value over the points with the first
    /// point attaining each: `ends` and `at` are `[largest; smallest]`, `rows` each.
    fn tile_extremes(z: &[f32], b: f32, rows: usize, ends: &mut [f32], at: &mut [u32]) {
        let (hi, lo) = ends.split_at_mut(rows);
        let (hi_at, lo_at) = at.split_at_mut(rows);
        for (((h, l), &v), (h_at, l_at)) in hi
            .iter_mut()
            .zip(lo.iter_mut())
            .zip(&z[..rows])
            .zip(hi_at.iter_mut().zip(lo_at.iter_mut()))
        {
            (*h, *l, *h_at, *l_at) = (v + b, v + b, 0, 0);
        }
        // Selects and unconditional stores, so that the loops vectorise along the waypoints;
        // four points a pass while four remain, so that each waypoint's extremes are loaded
        // and stored once per four points instead of once per point. The points are taken in
        // order either way: the first point attaining an extreme is the one kept.
        let points = z.len() / rows;
        let quads = (points - 1) / 4;
        for q in 0..quads {
            let n = 1 + 4 * q;
            let point = |i: usize| &z[i * rows..(i + 1) * rows];
            let zs = point(n).iter().zip(point(n + 1));
            let zs = zs.zip(point(n + 2).iter().zip(point(n + 3)));
            let hi = hi.iter_mut().zip(hi_at.iter_mut());
            let lo = lo.iter_mut().zip(lo_at.iter_mut());
            for (((&v0, &v1), (&v2, &v3)), ((h, h_at), (l, l_at))) in zs.zip(hi.zip(lo)) {
                let mut e = (*h, *h_at, *l, *l_at);
                for (i, v) in [v0, v1, v2, v3].into_iter().enumerate() {
                    e = extend(e, v + b, (n + i) as u32);
                }
                (*h, *h_at, *l, *l_at) = e;
            }
        }
        for (n, row) in z.chunks_exact(rows).enumerate().skip(1 + 4 * quads) {
            let hi = hi.iter_mut().zip(hi_at.iter_mut());
            let lo = lo.iter_mut().zip(lo_at.iter_mut());
            for (&v, ((h, h_at), (l, l_at))) in row.iter().zip(hi.zip(lo)) {
                (*h, *h_at, *l, *l_at) = extend((*h, *h_at, *l, *l_at), v + b, n as u32);
            }
        }
    }
}

/// The extremes `(largest, its point, smallest, its point)` with the value `v` of point `i`
/// taken in: a later point replaces an extreme only by passing it.
#[inline(always)]
fn extend((h, h_at, l, l_at): (f32, u32, f32, u32), v: f32, i: u32) -> (f32, u32, f32, u32) {
    let (up, down) = (v > h, v < l);
    (
        if up { v } else { h },
        if up { i } else { h_at },
        if down { v } else { l },
        if down { i } else { l_at },
    )
}

/// `z = W·x` for `m` columns: `W` `[out, inp]`, `x` `[inp, m]`, `z` `[out, m]`.
fn product(w: &[f32], inp: usize, x: &[f32], m: usize, z: &mut Vec<f32>) {
    let out = w.len() / inp;
    resize_for_overwrite(z, out * m);
    sgemm(out, m, inp, w, inp, 1, x, m, 1, z, false);
}

/// `z = W·x + b` for `m` columns ([`product`] plus the bias of each output row).
fn layer(w: &[f32], b: &[f32], inp: usize, x: &[f32], m: usize, z: &mut Vec<f32>) {
    product(w, inp, x, m, z);
    for (row, &bias) in z.chunks_exact_mut(m).zip(b) {
        row.iter_mut().for_each(|v| *v += bias);
    }
}

/// One waypoint's normalised position and heading (`cos θ, sin θ`).
struct Waypoint {
    px: f32,
    py: f32,
    cs: f32,
    sn: f32,
}

impl Waypoint {
    /// Waypoint `bj` of features `[5, K, T]` (`plane = K·T`).
    fn of(feat: &[f32], plane: usize, bj: usize) -> Self {
        Self {
            px: feat[bj],
            py: feat[plane + bj],
            cs: feat[2 * plane + bj],
            sn: feat[3 * plane + bj],
        }
    }

    /// The point `p` carried on to `tau`: its offset from the waypoint in the world
    /// `(dx, dy)` and in the waypoint's frame `(bx, by)`, and the (smoothed) distance.
    #[inline(always)]
    fn offset(&self, p: &[f32], tau: f32) -> ([f32; 2], [f32; 2], f32) {
        let dx = p[0] + p[2] * tau - self.px;
        let dy = p[1] + p[3] * tau - self.py;
        let bx = self.cs * dx + self.sn * dy;
        let by = self.cs * dy - self.sn * dx;
        ([dx, dy], [bx, by], (bx * bx + by * by + 1e-6).sqrt())
    }

    /// The point carried on to `tau`, relative to the waypoint in its frame: offset, distance,
    /// and the point's velocity in that frame.
    #[inline(always)]
    fn pair(&self, p: &[f32], tau: f32) -> [f32; PAIR] {
        let (_, [bx, by], dist) = self.offset(p, tau);
        let ux = self.cs * p[2] + self.sn * p[3];
        let uy = self.cs * p[3] - self.sn * p[2];
        [bx, by, dist, ux, uy]
    }

    /// Adds to `g` (`px, py, cos θ, sin θ`) the pull-back of the gradient `df` of
    /// [`Self::pair`].
    fn pull_back(&self, p: &[f32], tau: f32, df: [f32; PAIR], g: &mut [f32; 4]) {
        let ([dx, dy], [bx, by], dist) = self.offset(p, tau);
        let gbx = df[0] + df[2] * bx / dist;
        let gby = df[1] + df[2] * by / dist;
        let (gux, guy) = (df[3], df[4]);
        g[0] += -self.cs * gbx + self.sn * gby;
        g[1] += -self.sn * gbx - self.cs * gby;
        g[2] += dx * gbx + dy * gby + p[2] * gux + p[3] * guy;
        g[3] += dy * gbx - dx * gby + p[3] * gux - p[2] * guy;
    }
}

#[cfg(test)]
mod tests {
    use super::tile_extremes;

    /// Against a plain search, for every count of points around the four-point passes (one
    /// point to three passes and a remainder), on values with many ties: the largest and the
    /// smallest with the bias, and the first point attaining each.
    #[test]
    fn tile_extremes_pick_the_first_point_attaining_each_extreme() {
        for points in 1..=14 {
            for rows in [1, 3, 8, 17] {
                // Coarse values: ties between points are common.
                let z: Vec<f32> = (0..points * rows)
                    .map(|i| ((i * 7 + i / rows * 3) % 5) as f32 - 2.0)
                    .collect();
                let (mut ends, mut at) = (vec![0.0; 2 * rows], vec![0; 2 * rows]);
                tile_extremes(&z, 0.5, rows, &mut ends, &mut at);
                for r in 0..rows {
                    let column = (0..points).map(|n| (z[n * rows + r] + 0.5, n as u32));
                    let first = |better: fn(f32, f32) -> bool| {
                        column
                            .clone()
                            .reduce(|a, b| if better(b.0, a.0) { b } else { a })
                            .expect("one point at least")
                    };
                    let (hi, lo) = (first(|a, b| a > b), first(|a, b| a < b));
                    assert_eq!((ends[r], at[r]), hi, "largest: {points} points, row {r}");
                    let got = (ends[rows + r], at[rows + r]);
                    assert_eq!(got, lo, "smallest: {points} points, row {r}");
                }
            }
        }
    }
}
