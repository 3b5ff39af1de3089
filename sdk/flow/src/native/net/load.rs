//! Building [`Net`] from named weights: every layer of the architecture in `cfg`, each tensor
//! taken out of the weights by its torch name and checked for size.

use super::{
    Conv1d, Conv2d, ConvBlock, ConvT1d, DownLevel, Linear, Net, Norm, ResBlock, UpLevel,
    WeightError, Weights, take,
};
use crate::config::NetConfig;
use crate::native::crowd::Crowd;
use crate::native::kernels::Taps;
use crate::net::{GOAL_FEATURES, OUT_CHANNELS};

impl Net {
    /// Builds the network for `cfg` from named weights, taking every tensor the architecture
    /// needs out of `w` (each must be present with the right size).
    pub(crate) fn load(cfg: &NetConfig, w: &mut Weights) -> Result<Self, WeightError> {
        let tdim = cfg.time_embed_dim;
        let (bev, bev_out) = Self::load_bev(cfg, w)?;
        let crowd = match &cfg.crowd {
            Some(c) => Some(Crowd::load(c, cfg.activation, w)?),
            None => None,
        };
        // Channels per U-Net level, the input's own (trajectory and crowd pathway) first.
        let dims: Vec<usize> = std::iter::once(cfg.unet_in_channels())
            .chain(cfg.down_dims.iter().copied())
            .collect();
        // Every residual block takes its FiLM slice from one shared projection, in this order.
        let mut film_offset = 0usize;
        let down = Self::load_down(cfg, w, &dims, &mut film_offset)?;
        let dmid = dims[cfg.down_dims.len()];
        let mid = (0..cfg.mid_blocks)
            .map(|i| {
                ResBlock::load(
                    w,
                    &mut film_offset,
                    &format!("unet.mid.{i}"),
                    dmid,
                    dmid,
                    cfg,
                )
            })
            .collect::<Result<_, _>>()?;
        let up = Self::load_up(cfg, w, &dims, &mut film_offset)?;
        let film_width = film_offset;
        let d0 = dims[1];
        Ok(Self {
            cfg: cfg.clone(),
            act: cfg.activation,
            time0: Linear::load(w, "time.fc0", tdim, 4 * tdim)?,
            time1: Linear::load(w, "time.fc1", 4 * tdim, tdim)?,
            bev,
            bev_fc: Linear::load(w, "bev.fc", bev_out * 16, cfg.bev_embed_dim)?,
            goal0: Linear::load(w, "goal.fc0", GOAL_FEATURES as usize, cfg.goal_embed_dim)?,
            goal1: Linear::load(w, "goal.fc1", cfg.goal_embed_dim, cfg.goal_embed_dim)?,
            film: Linear::load(w, "unet.film", cfg.cond_dim(), film_width)?,
            crowd,
            down,
            mid,
            up,
            final_block: ConvBlock::load(w, "unet.final_block", d0, d0, cfg)?,
            final_conv: Conv1d::load(
                w,
                "unet.final_conv",
                d0,
                OUT_CHANNELS as usize,
                Taps {
                    k: 1,
                    stride: 1,
                    pad: 0,
                },
            )?,
        })
    }

    /// The BEV encoder's convolutions with their norms, and its last channel count.
    fn load_bev(
        cfg: &NetConfig,
        w: &mut Weights,
    ) -> Result<(Vec<(Conv2d, Norm)>, usize), WeightError> {
        let mut bev = Vec::new();
        let mut cin = 3;
        for (i, &c) in cfg.bev_channels.iter().enumerate() {
            let conv = Conv2d {
                w: take(w, &format!("bev.conv{i}.weight"), c * cin * 9)?,
                b: take(w, &format!("bev.conv{i}.bias"), c)?,
                cin,
            };
            bev.push((
                conv,
                Norm::load(w, &format!("bev.norm{i}"), c, cfg.n_groups)?,
            ));
            cin = c;
        }
        Ok((bev, cin))
    }

    /// The U-Net's down path: per level its residual blocks and, but on the last level, a
    /// stride-2 convolution.
    fn load_down(
        cfg: &NetConfig,
        w: &mut Weights,
        dims: &[usize],
        film_offset: &mut usize,
    ) -> Result<Vec<DownLevel>, WeightError> {
        let levels = cfg.down_dims.len();
        let mut down = Vec::new();
        for i in 0..levels {
            let (din, dout) = (dims[i], dims[i + 1]);
            let blocks = (0..cfg.blocks_per_level)
                .map(|b| {
                    let cin = if b == 0 { din } else { dout };
                    let name = format!("unet.down.{i}.res{b}");
                    ResBlock::load(w, film_offset, &name, cin, dout, cfg)
                })
                .collect::<Result<_, _>>()?;
            let down_conv = if i + 1 < levels {
                let taps = Taps {
                    k: 3,
                    stride: 2,
                    pad: 1,
                };
                let name = format!("unet.down.{i}.downsample");
                Some(Conv1d::load(w, &name, dout, dout, taps)?)
            } else {
                None
            };
            down.push(DownLevel {
                blocks,
                down: down_conv,
            });
        }
        Ok(down)
    }

    /// The U-Net's up path: per level (deepest first) its residual blocks, the first of which
    /// takes the skip connection, and a stride-2 transposed convolution.
    fn load_up(
        cfg: &NetConfig,
        w: &mut Weights,
        dims: &[usize],
        film_offset: &mut usize,
    ) -> Result<Vec<UpLevel>, WeightError> {
        let levels = cfg.down_dims.len();
        let mut up = Vec::new();
        for (j, i) in (1..levels).rev().enumerate() {
            let (din, dout) = (dims[i], dims[i + 1]);
            let blocks = (0..cfg.blocks_per_level)
                .map(|b| {
                    let cin = if b == 0 { 2 * dout } else { din };
                    let name = format!("unet.up.{j}.res{b}");
                    ResBlock::load(w, film_offset, &name, cin, din, cfg)
                })
                .collect::<Result<_, _>>()?;
            let name = format!("unet.up.{j}.upsample");
            up.push(UpLevel {
                blocks,
                up: ConvT1d {
                    w: take(w, &format!("{name}.weight"), din * din * 4)?,
                    b: take(w, &format!("{name}.bias"), din)?,
                    cin: din,
                    taps: Taps {
                        k: 4,
                        stride: 2,
                        pad: 1,
                    },
                },
            });
        }
        Ok(up)
    }
}
