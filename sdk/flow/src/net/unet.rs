//! [`CondUnet1d`]: the network of [the module](super) as a libtorch module.

use super::{CROWD_PAIR_FEATURES, GOAL_FEATURES, OUT_CHANNELS, TIME_SCALE};
use crate::config::{Activation, NetConfig};
use tch::nn::{self, Module};
use tch::{Kind, Tensor};

fn act(a: Activation, x: &Tensor) -> Tensor {
    match a {
        Activation::Silu => x.silu(),
        Activation::Mish => x.mish(),
    }
}

/// Conv1d → GroupNorm → activation.
#[derive(Debug)]
struct Conv1dBlock {
    conv: nn::Conv1D,
    norm: nn::GroupNorm,
    act: Activation,
}

impl Conv1dBlock {
    fn new(p: nn::Path<'_>, cin: i64, cout: i64, k: i64, groups: i64, act: Activation) -> Self {
        let cfg = nn::ConvConfig {
            padding: k / 2,
            ..Default::default()
        };
        Self {
            conv: nn::conv1d(&p / "conv", cin, cout, k, cfg),
            norm: nn::group_norm(&p / "norm", groups, cout, Default::default()),
            act,
        }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        act(self.act, &self.norm.forward(&self.conv.forward(x)))
    }
}

/// Residual block with FiLM conditioning (`ConditionalResidualBlock1D`). Its FiLM scale and
/// bias come from the network's fused FiLM layer ([`Film`]).
#[derive(Debug)]
struct ResBlock {
    block0: Conv1dBlock,
    block1: Conv1dBlock,
    residual: Option<nn::Conv1D>,
    /// Index of this block's `(scale, bias)` in [`Film`].
    film_index: usize,
}

impl ResBlock {
    fn new(
        p: nn::Path<'_>,
        cin: i64,
        cout: i64,
        (k, groups, a): (i64, i64, Activation),
        film: &mut Vec<i64>,
    ) -> Self {
        let residual =
            (cin != cout).then(|| nn::conv1d(&p / "residual", cin, cout, 1, Default::default()));
        film.push(cout);
        Self {
            block0: Conv1dBlock::new(&p / "block0", cin, cout, k, groups, a),
            block1: Conv1dBlock::new(&p / "block1", cout, cout, k, groups, a),
            residual,
            film_index: film.len() - 1,
        }
    }

    /// `x`: `[B, cin, L]`; FiLM scale and bias `[B or 1, cout, 1]` (broadcast over the batch).
    fn forward(&self, x: &Tensor, film: &Film) -> Tensor {
        let (scale, bias) = &film.per_block[self.film_index];
        let h = bias.addcmul(&self.block0.forward(x), scale);
        let h = self.block1.forward(&h);
        match &self.residual {
            Some(r) => h + r.forward(x),
            None => h + x,
        }
    }
}

/// FiLM parameters of every residual block for one `(t, c)`: `(scale, bias)`, each
/// `[B, C, 1]` (or `[1, C, 1]` when shared by the batch).
#[derive(Debug)]
pub struct Film {
    per_block: Vec<(Tensor, Tensor)>,
}

impl Film {
    /// A shallow copy (the tensors share storage).
    pub fn shallow_clone(&self) -> Film {
        Film {
            per_block: self
                .per_block
                .iter()
                .map(|(s, b)| (s.shallow_clone(), b.shallow_clone()))
                .collect(),
        }
    }
}

#[derive(Debug)]
struct DownLevel {
    blocks: Vec<ResBlock>,
    down: Option<nn::Conv1D>,
}

#[derive(Debug)]
struct UpLevel {
    blocks: Vec<ResBlock>,
    up: nn::ConvTranspose1D,
}

/// The conditional U-Net with its BEV, goal and time encoders.
#[derive(Debug)]
pub struct CondUnet1d {
    cfg: NetConfig,
    time_mlp0: nn::Linear,
    time_mlp1: nn::Linear,
    bev_convs: Vec<(nn::Conv2D, nn::GroupNorm)>,
    bev_fc: nn::Linear,
    goal_fc0: nn::Linear,
    goal_fc1: nn::Linear,
    /// The crowd pathway's two layers and its waypoint step (s), when the architecture has it.
    crowd: Option<(nn::Linear, nn::Linear, f64)>,
    film: nn::Linear,
    /// Channels of each residual block, in [`Film`] order.
    film_channels: Vec<i64>,
    down: Vec<DownLevel>,
    mid: Vec<ResBlock>,
    up: Vec<UpLevel>,
    final_block: Conv1dBlock,
    final_conv: nn::Conv1D,
}

impl CondUnet1d {
    /// Creates the network's variables under `p` (the config must be valid).
    pub fn new(p: &nn::Path<'_>, cfg: &NetConfig) -> Self {
        // Variables are created (and randomly initialised) in this order: time, BEV and goal
        // encoders, the U-Net's down, middle and up paths, the FiLM projection, the output.
        let k = cfg.kernel_size as i64;
        let g = cfg.n_groups as i64;
        let a = cfg.activation;
        let kga = (k, g, a);
        let cond = cfg.cond_dim() as i64;
        let tdim = cfg.time_embed_dim as i64;

        let time = p / "time";
        let time_mlp0 = nn::linear(&time / "fc0", tdim, 4 * tdim, Default::default());
        let time_mlp1 = nn::linear(&time / "fc1", 4 * tdim, tdim, Default::default());

        let (bev_convs, bev_fc) = Self::bev_encoder(&(p / "bev"), cfg);

        let goal = p / "goal";
        let gdim = cfg.goal_embed_dim as i64;
        let goal_fc0 = nn::linear(&goal / "fc0", GOAL_FEATURES, gdim, Default::default());
        let goal_fc1 = nn::linear(&goal / "fc1", gdim, gdim, Default::default());
        let crowd = cfg.crowd.as_ref().map(|c| {
            let w = c.width as i64;
            let cp = p / "crowd";
            (
                nn::linear(&cp / "fc0", CROWD_PAIR_FEATURES, w, Default::default()),
                nn::linear(&cp / "fc1", w, w, Default::default()),
                c.step,
            )
        });

        let unet = p / "unet";
        let dims: Vec<i64> = std::iter::once(cfg.unet_in_channels() as i64)
            .chain(cfg.down_dims.iter().map(|&d| d as i64))
            .collect();
        let mut film_channels = Vec::new();
        let down = Self::down_path(&unet, cfg, &dims, kga, &mut film_channels);
        let dmid = dims[cfg.down_dims.len()];
        let mid = (0..cfg.mid_blocks)
            .map(|i| ResBlock::new(&unet / "mid" / i, dmid, dmid, kga, &mut film_channels))
            .collect();
        let up = Self::up_path(&unet, cfg, &dims, kga, &mut film_channels);
        let film_width: i64 = film_channels.iter().map(|c| 2 * c).sum();
        let film = nn::linear(&unet / "film", cond, film_width, Default::default());
        let d0 = dims[1];
        let final_block = Conv1dBlock::new(&unet / "final_block", d0, d0, k, g, a);
        let final_conv = nn::conv1d(
            &unet / "final_conv",
            d0,
            OUT_CHANNELS,
            1,
            Default::default(),
        );

        Self {
            cfg: cfg.clone(),
            time_mlp0,
            time_mlp1,
            bev_convs,
            bev_fc,
            goal_fc0,
            goal_fc1,
            crowd,
            film,
            film_channels,
            down,
            mid,
            up,
            final_block,
            final_conv,
        }
    }

    /// The BEV encoder: stride-2 convolutions with group norms, then a linear layer.
    fn bev_encoder(
        bev: &nn::Path<'_>,
        cfg: &NetConfig,
    ) -> (Vec<(nn::Conv2D, nn::GroupNorm)>, nn::Linear) {
        let g = cfg.n_groups as i64;
        let mut bev_convs = Vec::new();
        let mut cin = 3i64;
        for (i, &c) in cfg.bev_channels.iter().enumerate() {
            let c = c as i64;
            let conv_cfg = nn::ConvConfig {
                stride: 2,
                padding: 1,
                ..Default::default()
            };
            let conv = nn::conv2d(bev / format!("conv{i}"), cin, c, 3, conv_cfg);
            let norm = nn::group_norm(bev / format!("norm{i}"), g, c, Default::default());
            bev_convs.push((conv, norm));
            cin = c;
        }
        let bev_fc = nn::linear(
            bev / "fc",
            cin * 16,
            cfg.bev_embed_dim as i64,
            Default::default(),
        );
        (bev_convs, bev_fc)
    }

    /// The U-Net's down path: per level its residual blocks and, but on the last level, a
    /// stride-2 convolution.
    fn down_path(
        unet: &nn::Path<'_>,
        cfg: &NetConfig,
        dims: &[i64],
        kga: (i64, i64, Activation),
        film_channels: &mut Vec<i64>,
    ) -> Vec<DownLevel> {
        let levels = cfg.down_dims.len();
        let mut down = Vec::new();
        for i in 0..levels {
            let (din, dout) = (dims[i], dims[i + 1]);
            let lp = unet / "down" / i;
            let last = i + 1 == levels;
            let blocks = (0..cfg.blocks_per_level)
                .map(|b| {
                    let cin = if b == 0 { din } else { dout };
                    ResBlock::new(&lp / format!("res{b}"), cin, dout, kga, film_channels)
                })
                .collect();
            down.push(DownLevel {
                blocks,
                down: (!last).then(|| {
                    let c = nn::ConvConfig {
                        stride: 2,
                        padding: 1,
                        ..Default::default()
                    };
                    nn::conv1d(&lp / "downsample", dout, dout, 3, c)
                }),
            });
        }
        down
    }

    /// The U-Net's up path, levels `levels − 1 … 1`, coarse to fine (`(dim_in, dim_out) =
    /// (dims[i], dims[i+1])`): residual blocks, the first taking the skip connection, then a
    /// stride-2 transposed convolution.
    fn up_path(
        unet: &nn::Path<'_>,
        cfg: &NetConfig,
        dims: &[i64],
        kga: (i64, i64, Activation),
        film_channels: &mut Vec<i64>,
    ) -> Vec<UpLevel> {
        let levels = cfg.down_dims.len();
        let mut up = Vec::new();
        for (j, i) in (1..levels).rev().enumerate() {
            let (din, dout) = (dims[i], dims[i + 1]);
            let lp = unet / "up" / j;
            let c = nn::ConvTransposeConfig {
                stride: 2,
                padding: 1,
                ..Default::default()
            };
            let blocks = (0..cfg.blocks_per_level)
                .map(|b| {
                    let cin = if b == 0 { 2 * dout } else { din };
                    ResBlock::new(&lp / format!("res{b}"), cin, din, kga, film_channels)
                })
                .collect();
            up.push(UpLevel {
                blocks,
                up: nn::conv_transpose1d(&lp / "upsample", din, din, 4, c),
            });
        }
        up
    }

    /// The architecture this network was built with.
    pub fn config(&self) -> &NetConfig {
        &self.cfg
    }

    /// The static part of the conditioning: `[BEV embedding, goal embedding]`, `[B, bev + goal]`.
    ///
    /// `bev`: `[B, 3, H, W]` (velocity channels already divided by the speed scale);
    /// `goal_vel`: `[B, 4]` normalised goal and ego velocity.
    pub fn encode_condition(&self, bev: &Tensor, goal_vel: &Tensor) -> Tensor {
        let a = self.cfg.activation;
        let mut h = bev.shallow_clone();
        for (conv, norm) in &self.bev_convs {
            h = act(a, &norm.forward(&conv.forward(&h)));
        }
        let h = h.adaptive_avg_pool2d([4, 4]).flatten(1, -1);
        let bev_emb = act(a, &self.bev_fc.forward(&h));
        let goal_emb = self
            .goal_fc1
            .forward(&act(a, &self.goal_fc0.forward(goal_vel)));
        Tensor::cat(&[bev_emb, goal_emb], 1)
    }

    /// The embedding of flow time `t` (`[B]` or `[1]`), `[B, time_embed_dim]`.
    pub fn encode_time(&self, t: &Tensor) -> Tensor {
        let half = (self.cfg.time_embed_dim / 2) as i64;
        let step = (10000f64).ln() / (half - 1) as f64;
        let freqs = (Tensor::arange(half, (t.kind(), t.device())) * -step).exp();
        let args = t.view([-1, 1]) * TIME_SCALE * freqs.view([1, -1]);
        let emb = Tensor::cat(&[args.sin(), args.cos()], 1);
        self.time_mlp1
            .forward(&act(self.cfg.activation, &self.time_mlp0.forward(&emb)))
    }

    /// FiLM parameters of every block for flow time `t` (`[B]`, or `[1]` shared by the batch)
    /// and static condition `cond` (from [`Self::encode_condition`], `[B, ·]` or `[1, ·]`).
    /// Depends only on `(t, c)`, so a sampler can cache it per time step.
    pub fn film(&self, t: &Tensor, cond: &Tensor) -> Film {
        let temb = self.encode_time(t);
        let (bt, bc) = (temb.size()[0], cond.size()[0]);
        let c = if bt == bc {
            Tensor::cat(&[&temb, cond], 1)
        } else if bt == 1 {
            Tensor::cat(&[&temb.expand([bc, -1], false), cond], 1)
        } else {
            Tensor::cat(&[&temb, &cond.expand([bt, -1], false)], 1)
        };
        let all = self.film.forward(&act(self.cfg.activation, &c));
        let mut per_block = Vec::with_capacity(self.film_channels.len());
        let mut off = 0;
        for &ch in &self.film_channels {
            let f = all.narrow(1, off, 2 * ch).view([-1, 2, ch, 1]);
            per_block.push((f.select(1, 0), f.select(1, 1)));
            off += 2 * ch;
        }
        Film { per_block }
    }

    /// The crowd pathway's features `[B, width, T]` of trajectory features `x` (`[B, 5, T]`)
    /// and crowd points `points` (`[B or 1, N, 5]`, [`crate::model::crowd_points`]); `None`
    /// without the pathway.
    pub fn crowd_features(&self, x: &Tensor, points: &Tensor) -> Option<Tensor> {
        let (fc0, fc1, step) = self.crowd.as_ref()?;
        let a = self.cfg.activation;
        let t_len = x.size()[2];
        let opts = (x.kind(), x.device());
        // Waypoint times (i + 1)·step, [1, 1, T].
        let tau = ((Tensor::arange(t_len, opts) + 1.0) * *step).view([1, 1, -1]);
        // Waypoints [B, 1, T]; points [Bp, N, 1].
        let ch = |c: i64| x.select(1, c).unsqueeze(1);
        let (px, py, cs, sn) = (ch(0), ch(1), ch(2), ch(3));
        let pt = |c: i64| points.select(2, c).unsqueeze(2);
        let (qx, qy, vx, vy, present) = (pt(0), pt(1), pt(2), pt(3), pt(4));
        // The point at the waypoint's time, relative to the waypoint, in its frame: [B, N, T].
        let dx = &qx + &vx * &tau - &px;
        let dy = &qy + &vy * &tau - &py;
        let bx = &cs * &dx + &sn * &dy;
        let by = &cs * &dy - &sn * &dx;
        let dist = (bx.square() + by.square() + 1e-6).sqrt();
        let ux = &cs * &vx + &sn * &vy;
        let uy = &cs * &vy - &sn * &vx;
        let (b, n) = (bx.size()[0], bx.size()[1]);
        let ux = ux.expand([b, n, t_len], false);
        let uy = uy.expand([b, n, t_len], false);
        let pair = Tensor::stack(&[bx, by, dist, ux, uy], 3);
        let h = act(a, &fc1.forward(&act(a, &fc0.forward(&pair))));
        // Max over the present points; rows without any point get zeros. [B, T, W].
        let present = present.unsqueeze(3);
        let masked = &h + (&present - 1.0) * 1e4;
        let any = present.amax([1], false);
        let pooled = masked.amax([1], false) * any;
        Some(pooled.permute([0, 2, 1]))
    }

    /// The standardised velocity `[B, 3, T]` for trajectory features `x` (`[B, 5, T]`) under
    /// precomputed FiLM parameters; `points` feeds the crowd pathway when the architecture has
    /// one (ignored otherwise).
    pub fn forward_film(&self, x: &Tensor, film: &Film, points: &Tensor) -> Tensor {
        let mut h = match self.crowd_features(x, points) {
            Some(c) => Tensor::cat(&[x, &c], 1),
            None => x.shallow_clone(),
        };
        let mut skips = Vec::with_capacity(self.down.len());
        for lvl in &self.down {
            for b in &lvl.blocks {
                h = b.forward(&h, film);
            }
            skips.push(h.shallow_clone());
            if let Some(d) = &lvl.down {
                h = d.forward(&h);
            }
        }
        for m in &self.mid {
            h = m.forward(&h, film);
        }
        for lvl in &self.up {
            if let Some(skip) = skips.pop() {
                h = Tensor::cat(&[&h, &skip], 1);
            }
            for b in &lvl.blocks {
                h = b.forward(&h, film);
            }
            h = lvl.up.forward(&h);
        }
        self.final_conv.forward(&self.final_block.forward(&h))
    }

    /// [`Self::film`] followed by [`Self::forward_film`].
    pub fn forward(&self, x: &Tensor, t: &Tensor, cond: &Tensor, points: &Tensor) -> Tensor {
        self.forward_film(x, &self.film(t, cond), points)
    }
}

/// Number of scalar parameters of the variables in `vs`.
pub fn parameter_count(vs: &nn::VarStore) -> usize {
    vs.trainable_variables().iter().map(Tensor::numel).sum()
}

/// Kind of the variables in `vs` (Float unless converted with `VarStore::double`).
pub(crate) fn store_kind(vs: &nn::VarStore) -> Kind {
    vs.trainable_variables()
        .first()
        .map(Tensor::kind)
        .unwrap_or(Kind::Float)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::net::{CROWD_FEATURES, Complexity, TRAJ_CHANNELS};
    use tch::Device;

    #[test]
    fn shapes_for_two_and_three_levels() {
        for dims in [vec![32, 64], vec![16, 32, 64]] {
            let cfg = NetConfig {
                down_dims: dims,
                ..NetConfig::default()
            };
            cfg.validate().unwrap();
            let vs = nn::VarStore::new(Device::Cpu);
            let net = CondUnet1d::new(&vs.root(), &cfg);
            let b = 3;
            let x = Tensor::randn([b, TRAJ_CHANNELS, 32], (Kind::Float, Device::Cpu));
            let bev = Tensor::zeros([b, 3, 32, 32], (Kind::Float, Device::Cpu));
            let g = Tensor::ones([b, 4], (Kind::Float, Device::Cpu));
            let cond = net.encode_condition(&bev, &g);
            let none = Tensor::zeros([1, 0, CROWD_FEATURES], (Kind::Float, Device::Cpu));
            assert_eq!(
                cond.size(),
                vec![b, (cfg.bev_embed_dim + cfg.goal_embed_dim) as i64]
            );
            // Per-sample time and condition.
            let t = Tensor::from_slice(&[0.1f32, 0.5, 0.9]);
            assert_eq!(net.forward(&x, &t, &cond, &none).size(), vec![b, 3, 32]);
            // One time and one condition shared by the batch.
            let t1 = Tensor::from_slice(&[0.3f32]);
            let c1 = cond.narrow(0, 0, 1);
            assert_eq!(net.forward(&x, &t1, &c1, &none).size(), vec![b, 3, 32]);
        }
    }

    /// The crowd pathway: output shapes, rows without points get zero features, and a point
    /// on the trajectory changes the velocity.
    #[test]
    fn crowd_pathway_reads_points_per_waypoint() {
        tch::manual_seed(0);
        let cfg = NetConfig {
            crowd: Some(crate::config::CrowdConfig {
                points: 4,
                width: 8,
                ..Default::default()
            }),
            ..NetConfig::default()
        };
        cfg.validate().unwrap();
        let vs = nn::VarStore::new(Device::Cpu);
        let net = CondUnet1d::new(&vs.root(), &cfg);
        let f = (Kind::Float, Device::Cpu);
        // A straight path along x at 1 m/s (normalised positions, heading 0).
        let xs = Tensor::arange(32, f) * 0.1 + 0.1;
        let x = Tensor::stack(
            &[
                xs.shallow_clone(),
                xs.zeros_like(),
                xs.ones_like(),
                xs.zeros_like(),
                (Tensor::arange(32, f) + 1.0) / 32.0,
            ],
            0,
        )
        .unsqueeze(0);
        let absent = Tensor::zeros([1, 4, CROWD_FEATURES], f);
        let feats = net.crowd_features(&x, &absent).unwrap();
        assert_eq!(feats.size(), vec![1, 8, 32]);
        assert_eq!(feats.abs().sum(Kind::Float).double_value(&[]), 0.0);
        let one = |px: f32| {
            let mut p = vec![0f32; 4 * 5];
            p[..5].copy_from_slice(&[px, 0.0, 0.0, 0.0, 1.0]);
            Tensor::from_slice(&p).view([1, 4, 5])
        };
        let bev = Tensor::zeros([1, 3, 32, 32], f);
        let cond = net.encode_condition(&bev, &Tensor::ones([1, 4], f));
        let t = Tensor::from_slice(&[0.5f32]);
        let v0 = net.forward(&x, &t, &cond, &absent);
        let near = (net.forward(&x, &t, &cond, &one(1.5)) - &v0)
            .abs()
            .sum(Kind::Float)
            .double_value(&[]);
        assert!(near > 0.0, "a point on the path changes nothing");
    }

    #[test]
    fn complexity_counts_grow_with_width() {
        let small = Complexity::of(&NetConfig::default());
        let wide = Complexity::of(&NetConfig {
            down_dims: vec![64, 128],
            ..NetConfig::default()
        });
        assert!(small.unet_macs > 0 && small.condition_macs > 0);
        // Doubling every channel roughly quadruples the convolution cost.
        let ratio = wide.unet_macs as f64 / small.unet_macs as f64;
        assert!(ratio > 2.5 && ratio < 4.5, "ratio {ratio}");
    }
}
