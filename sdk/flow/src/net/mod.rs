//! The conditional 1-D temporal U-Net `f_θ(x_t, c, t)` (paper §III-A), in the style of
//! Diffusion Policy's `ConditionalUnet1D`.
//!
//! * Trajectory input `[B, 5, T]`: per waypoint the normalised position `x/s, y/s`, the heading
//!   as `cos θ, sin θ` (continuous across ±π) and the waypoint's place in the horizon
//!   `(i + 1)/T` (convolutions are shift-invariant; the waypoint index matters here).
//! * Output `[B, 3, T]`: the standardised body velocity `(v_x, v_y, ω)` per waypoint.
//! * Conditioning by FiLM: every residual block scales and shifts its first convolution's
//!   output per channel with a linear map of `act(c)`, where `c = [time embedding, BEV
//!   embedding, goal embedding]`.
//! * BEV encoder: three stride-2 3×3 convolutions with GroupNorm and the activation, an adaptive average
//!   pool to 4×4 and a linear layer. The activation is SiLU by default (Mish, as in
//!   Diffusion Policy, is available; see [`Activation`](crate::config::Activation)). Goal encoder: a two-layer MLP on
//!   `(g_x, g_y)/goal_scale, (v_x, v_y)/speed_scale`. Time: sinusoidal embedding of `100·t`
//!   followed by a two-layer MLP.
//!
//! * Crowd pathway (optional, [`crate::config::CrowdConfig`]): per waypoint, `width` features
//!   of the raster's occupied cells carried on at their velocities to the waypoint's time and
//!   seen from the waypoint (a shared MLP per pair, max over the cells), concatenated to the
//!   trajectory input.
//!
//! The BEV and goal embeddings (the "static" part of `c`) depend only on the planning
//! condition, so [`CondUnet1d::encode_condition`] is separate from [`CondUnet1d::forward`] and
//! can be computed once per planning call.
//!
//! The architecture's constants and its [`Complexity`] are here; the libtorch module
//! ([`CondUnet1d`]) is built with the `torch` feature, and [`crate::native`] runs the same
//! layers without it.

use crate::config::NetConfig;

#[cfg(feature = "torch")]
mod unet;
#[cfg(feature = "torch")]
pub(crate) use unet::store_kind;
#[cfg(feature = "torch")]
pub use unet::{CondUnet1d, Film, parameter_count};

/// Input channels of the trajectory: `x/s, y/s, cos θ, sin θ, (i + 1)/T`.
pub const TRAJ_CHANNELS: i64 = 5;
/// Output channels: `v_x, v_y, ω`.
pub const OUT_CHANNELS: i64 = 3;
/// Inputs of the goal encoder: `g_x, g_y, v_x, v_y`.
pub const GOAL_FEATURES: i64 = 4;
/// Values per crowd point ([`crate::model::crowd_points`]): `x/s, y/s, v_x/s, v_y/s, present`.
pub const CROWD_FEATURES: i64 = 5;
/// Inputs of the crowd pathway's MLP per (point, waypoint): the point's offset from the
/// waypoint in the waypoint's frame (2), its distance (1) and its velocity in that frame (2).
pub const CROWD_PAIR_FEATURES: i64 = 5;
/// Frequency multiplier of the sinusoidal time embedding (flow time `t ∈ [0, 1]`).
pub(crate) const TIME_SCALE: f64 = 100.0;

/// Multiply-accumulate counts of one forward pass, from the architecture alone
/// (convolutions and linear layers; normalisations and activations are not counted).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Complexity {
    /// U-Net convolutions and the crowd pathway's MLP at every one of its points, per
    /// trajectory (`conv_macs + points · horizon · crowd_pair_macs`).
    pub unet_macs: u64,
    /// The U-Net's convolutions alone, per trajectory.
    pub conv_macs: u64,
    /// The crowd pathway's MLP per (waypoint, point) pair (0 without the pathway).
    pub crowd_pair_macs: u64,
    /// Time MLP and the fused FiLM layer, once per `(t, c)` (shared by the batch).
    pub film_macs: u64,
    /// BEV and goal encoders, once per condition.
    pub condition_macs: u64,
}

impl Complexity {
    /// Counts the multiply-accumulates of the architecture `cfg`.
    pub fn of(cfg: &NetConfig) -> Self {
        let k = cfg.kernel_size as u64;
        let cond = cfg.cond_dim() as u64;
        let conv1d = |cin: u64, cout: u64, k: u64, len: u64| cin * cout * k * len;
        // FiLM layers depend on (t, c) only and are counted once per call, not per trajectory.
        let res = |cin: u64, cout: u64, len: u64| {
            conv1d(cin, cout, k, len)
                + conv1d(cout, cout, k, len)
                + if cin != cout {
                    conv1d(cin, cout, 1, len)
                } else {
                    0
                }
        };
        let nb = cfg.blocks_per_level as u64;
        let block_run = |cin: u64, cout: u64, len: u64| {
            res(cin, cout, len) + nb.saturating_sub(1) * res(cout, cout, len)
        };
        let tdim = cfg.time_embed_dim as u64;
        let _ = cond;
        let mut unet = 0u64;
        let dims: Vec<u64> = std::iter::once(cfg.unet_in_channels() as u64)
            .chain(cfg.down_dims.iter().map(|&d| d as u64))
            .collect();
        let levels = cfg.down_dims.len();
        let mut len = cfg.horizon as u64;
        for i in 0..levels {
            let (din, dout) = (dims[i], dims[i + 1]);
            unet += block_run(din, dout, len);
            if i + 1 < levels {
                len /= 2;
                unet += conv1d(dout, dout, 3, len);
            }
        }
        unet += cfg.mid_blocks as u64 * res(dims[levels], dims[levels], len);
        for i in (1..levels).rev() {
            let (din, dout) = (dims[i], dims[i + 1]);
            unet += block_run(2 * dout, din, len);
            unet += conv1d(din, din, 4, len);
            len *= 2;
        }
        let d0 = dims[1];
        unet += conv1d(d0, d0, k, len) + conv1d(d0, OUT_CHANNELS as u64, 1, len);
        let conv_macs = unet;
        let mut crowd_pair_macs = 0;
        if let Some(c) = &cfg.crowd {
            let (n, w) = (c.points as u64, c.width as u64);
            crowd_pair_macs = CROWD_PAIR_FEATURES as u64 * w + w * w;
            unet += n * cfg.horizon as u64 * crowd_pair_macs;
        }

        let mut condition = 0u64;
        let mut side = cfg.bev_cells as u64;
        let mut cin = 3u64;
        for &c in &cfg.bev_channels {
            side = side.div_ceil(2);
            condition += side * side * cin * c as u64 * 9;
            cin = c as u64;
        }
        condition += cin * 16 * cfg.bev_embed_dim as u64;
        let gdim = cfg.goal_embed_dim as u64;
        condition += GOAL_FEATURES as u64 * gdim + gdim * gdim;
        let mut film_width = 0u64;
        for i in 0..levels {
            film_width += 2 * dims[i + 1] * nb;
        }
        film_width += 2 * dims[levels] * cfg.mid_blocks as u64;
        for i in 1..levels {
            film_width += 2 * dims[i] * nb;
        }
        let film = tdim * 4 * tdim * 2 + cond * film_width;
        Self {
            unet_macs: unet,
            conv_macs,
            crowd_pair_macs,
            film_macs: film,
            condition_macs: condition,
        }
    }
}
