//! The crowd pathway of [`crate::net::CondUnet1d::crowd_features`] on `f32` buffers: per
//! waypoint, a shared two-layer MLP over every (crowd point, waypoint) pair and a max over the
//! points, and the backward pass of its input (the waypoints' positions and headings).
//!
//! Pairs are laid out column-major over `(trajectory, waypoint, point)`, so each layer is one
//! matrix product over the whole batch.

use super::kernels::{activate_in_place, activation_derivative, resize_for_overwrite, sgemm};
use super::net::{WeightError, Weights, take};
use crate::config::{Activation, CrowdConfig};
use crate::net::{CROWD_FEATURES, CROWD_PAIR_FEATURES, TRAJ_CHANNELS};

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
    /// Pair features `[5, M]` and pre-activations `[width, M]` of both layers.
    pairs: Vec<f32>,
    z0: Vec<f32>,
    z1: Vec<f32>,
    /// Per output `(w, b, j)`: the point the max picked.
    arg: Vec<u32>,
    /// The trajectory features `[5, K, T]` the pass read.
    feat: Vec<f32>,
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
    /// `[5 + width, K, T]` after), reading `points` (`N × 5`, present rows first).
    pub(crate) fn forward(
        &self,
        feat: &mut Vec<f32>,
        (k, t_len): (usize, usize),
        points: &[f32],
        tape: &mut CrowdTape,
    ) {
        let traj = TRAJ_CHANNELS as usize * k * t_len;
        tape.feat.clear();
        tape.feat.extend_from_slice(&feat[..traj]);
        let stride = CROWD_FEATURES as usize;
        let present = points
            .chunks_exact(stride)
            .take_while(|p| p[4] > 0.5)
            .count();
        tape.present = present;
        let out_len = self.width * k * t_len;
        if present == 0 {
            feat.resize(traj + out_len, 0.0);
            return;
        }
        let m = k * t_len * present;
        resize_for_overwrite(&mut tape.pairs, PAIR * m);
        let plane = k * t_len;
        for b in 0..k {
            for j in 0..t_len {
                let w = Waypoint::of(&tape.feat, plane, b * t_len + j);
                let tau = (j + 1) as f32 * self.step;
                for (n, p) in points.chunks_exact(stride).take(present).enumerate() {
                    let f = w.pair(p, tau);
                    let col = (b * t_len + j) * present + n;
                    for (c, v) in f.iter().enumerate() {
                        tape.pairs[c * m + col] = *v;
                    }
                }
            }
        }
        let width = self.width;
        layer(&self.w0, &self.b0, PAIR, &tape.pairs, m, &mut tape.z0);
        let mut a0 = tape.z0.clone();
        activate_in_place(self.act, &mut a0);
        layer(&self.w1, &self.b1, width, &a0, m, &mut tape.z1);
        let mut a1 = tape.z1.clone();
        activate_in_place(self.act, &mut a1);
        feat.resize(traj + out_len, 0.0);
        tape.arg.clear();
        tape.arg.resize(out_len, 0);
        for c in 0..width {
            for bj in 0..plane {
                let row = &a1[c * m + bj * present..c * m + (bj + 1) * present];
                let (mut best, mut arg) = (f32::NEG_INFINITY, 0usize);
                for (n, &v) in row.iter().enumerate() {
                    if v > best {
                        best = v;
                        arg = n;
                    }
                }
                feat[traj + c * plane + bj] = best;
                tape.arg[c * plane + bj] = arg as u32;
            }
        }
    }

    /// Adds to `dfeat[..5·K·T]` the pull-back of `dfeat[5·K·T..]` (the gradient arriving at
    /// the pathway's features) through the pass recorded in `tape`.
    pub(crate) fn backward(
        &self,
        dfeat: &mut [f32],
        (k, t_len): (usize, usize),
        points: &[f32],
        tape: &CrowdTape,
    ) {
        let present = tape.present;
        if present == 0 {
            return;
        }
        let (plane, width) = (k * t_len, self.width);
        let traj = TRAJ_CHANNELS as usize * plane;
        let m = plane * present;
        let (dtraj, dcrowd) = dfeat.split_at_mut(traj);
        // The max passes the gradient to the point it picked.
        let mut dz1 = vec![0f32; width * m];
        for c in 0..width {
            for bj in 0..plane {
                let n = tape.arg[c * plane + bj] as usize;
                dz1[c * m + bj * present + n] += dcrowd[c * plane + bj];
            }
        }
        for (d, &z) in dz1.iter_mut().zip(&tape.z1) {
            *d *= activation_derivative(self.act, z);
        }
        // dA0 = W1ᵀ·dZ1, then through the first activation; dF = W0ᵀ·dZ0.
        let mut dz0 = vec![0f32; width * m];
        sgemm(
            width, m, width, &self.w1, 1, width, &dz1, m, 1, &mut dz0, false,
        );
        for (d, &z) in dz0.iter_mut().zip(&tape.z0) {
            *d *= activation_derivative(self.act, z);
        }
        let mut dpairs = vec![0f32; PAIR * m];
        sgemm(
            PAIR,
            m,
            width,
            &self.w0,
            1,
            PAIR,
            &dz0,
            m,
            1,
            &mut dpairs,
            false,
        );
        let stride = CROWD_FEATURES as usize;
        for b in 0..k {
            for j in 0..t_len {
                let bj = b * t_len + j;
                let w = Waypoint::of(&tape.feat, plane, bj);
                let tau = (j + 1) as f32 * self.step;
                let mut g = [0f32; 4];
                for (n, p) in points.chunks_exact(stride).take(present).enumerate() {
                    let col = bj * present + n;
                    let df: [f32; PAIR] = std::array::from_fn(|c| dpairs[c * m + col]);
                    w.pull_back(p, tau, df, &mut g);
                }
                for (c, v) in g.iter().enumerate() {
                    dtraj[c * plane + bj] += v;
                }
            }
        }
    }
}

/// `z = W·x + b` for `m` columns: `W` `[out, inp]`, `x` `[inp, m]`, `z` `[out, m]`.
fn layer(w: &[f32], b: &[f32], inp: usize, x: &[f32], m: usize, z: &mut Vec<f32>) {
    let out = b.len();
    resize_for_overwrite(z, out * m);
    sgemm(out, m, inp, w, inp, 1, x, m, 1, z, false);
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
    fn offset(&self, p: &[f32], tau: f32) -> ([f32; 2], [f32; 2], f32) {
        let dx = p[0] + p[2] * tau - self.px;
        let dy = p[1] + p[3] * tau - self.py;
        let bx = self.cs * dx + self.sn * dy;
        let by = self.cs * dy - self.sn * dx;
        ([dx, dy], [bx, by], (bx * bx + by * by + 1e-6).sqrt())
    }

    /// The point carried on to `tau`, relative to the waypoint in its frame: offset, distance,
    /// and the point's velocity in that frame.
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
