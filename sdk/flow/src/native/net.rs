//! The conditional U-Net of [`crate::net`] rebuilt over plain `f32` buffers: the same layers,
//! the same weights (read by name from the safetensors file), a forward pass and the backward
//! pass of its input, with every activation the backward pass needs kept in a reusable
//! [`Tape`]. Activations are `[C, B, L]` (channel-major), so the U-Net's channel concatenation
//! is a plain append and a convolution is one matrix product over the whole batch.

use super::crowd::Crowd;
use super::kernels::{
    BlockNorm, Taps, activate_in_place, add_bias, add_to, gather, linear, norm_act,
    norm_act_backward, resize_for_overwrite, scatter_add, sgemm,
};
use crate::config::{Activation, NetConfig};
use crate::net::{GOAL_FEATURES, OUT_CHANNELS};
use std::collections::BTreeMap;

/// Where a weight tensor is missing or has the wrong size.
#[derive(Debug)]
pub(crate) struct WeightError {
    pub name: String,
    pub expected: usize,
    pub found: Option<usize>,
}

/// Named weight tensors, flattened (row-major as torch stores them).
pub(crate) type Weights = BTreeMap<String, Vec<f32>>;

/// Removes the tensor `name` of `len` values from `w` (so that what is left afterwards is
/// what the architecture does not use).
pub(crate) fn take(w: &mut Weights, name: &str, len: usize) -> Result<Vec<f32>, WeightError> {
    match w.remove(name) {
        Some(v) if v.len() == len => Ok(v),
        other => Err(WeightError {
            name: name.to_string(),
            expected: len,
            found: other.as_ref().map(Vec::len),
        }),
    }
}

/// A linear layer, `[out, in]` row-major.
#[derive(Debug)]
struct Linear {
    w: Vec<f32>,
    b: Vec<f32>,
}

impl Linear {
    fn load(w: &mut Weights, name: &str, inp: usize, out: usize) -> Result<Self, WeightError> {
        Ok(Self {
            w: take(w, &format!("{name}.weight"), out * inp)?,
            b: take(w, &format!("{name}.bias"), out)?,
        })
    }

    fn out(&self) -> usize {
        self.b.len()
    }

    fn apply(&self, x: &[f32]) -> Vec<f32> {
        let mut y = vec![0f32; self.out()];
        linear(&self.w, &self.b, x, &mut y);
        y
    }
}

/// A 1-D convolution (`weight [cout, cin, k]`, i.e. `[cout, cin·k]` row-major).
#[derive(Debug)]
struct Conv1d {
    w: Vec<f32>,
    b: Vec<f32>,
    cin: usize,
    taps: Taps,
}

impl Conv1d {
    fn load(
        w: &mut Weights,
        name: &str,
        cin: usize,
        cout: usize,
        taps: Taps,
    ) -> Result<Self, WeightError> {
        Ok(Self {
            w: take(w, &format!("{name}.weight"), cout * cin * taps.k)?,
            b: take(w, &format!("{name}.bias"), cout)?,
            cin,
            taps,
        })
    }

    fn cout(&self) -> usize {
        self.b.len()
    }

    fn out_len(&self, len: usize) -> usize {
        (len + 2 * self.taps.pad - self.taps.k) / self.taps.stride + 1
    }

    /// `y = conv(x)`: `x` `[cin, batch, len]` → `y` `[cout, batch, out_len]`.
    fn forward(&self, x: &[f32], batch: usize, len: usize, col: &mut Vec<f32>, y: &mut Vec<f32>) {
        self.forward_unbiased(x, batch, len, col, y);
        add_bias(y, &self.b);
    }

    /// [`Self::forward`] without the bias (for a block that folds it into its normalisation).
    fn forward_unbiased(
        &self,
        x: &[f32],
        batch: usize,
        len: usize,
        col: &mut Vec<f32>,
        y: &mut Vec<f32>,
    ) {
        let (lo, ck) = (self.out_len(len), self.cin * self.taps.k);
        resize_for_overwrite(y, self.cout() * batch * lo);
        let pointwise = self.taps.k == 1 && self.taps.stride == 1 && self.taps.pad == 0;
        let src: &[f32] = if pointwise {
            x
        } else {
            gather(x, self.cin, batch, len, lo, self.taps, col);
            col
        };
        let n = batch * lo;
        sgemm(self.cout(), n, ck, &self.w, ck, 1, src, n, 1, y, false);
    }

    /// `dx += convᵀ(dy)`: `dy` `[cout, batch, out_len]` → `dx` `[cin, batch, len]`.
    fn backward(&self, dy: &[f32], batch: usize, len: usize, col: &mut Vec<f32>, dx: &mut [f32]) {
        let (lo, ck) = (self.out_len(len), self.cin * self.taps.k);
        let n = batch * lo;
        let pointwise = self.taps.k == 1 && self.taps.stride == 1 && self.taps.pad == 0;
        if pointwise {
            sgemm(ck, n, self.cout(), &self.w, 1, ck, dy, n, 1, dx, true);
            return;
        }
        resize_for_overwrite(col, ck * n);
        sgemm(ck, n, self.cout(), &self.w, 1, ck, dy, n, 1, col, false);
        scatter_add(col, self.cin, batch, len, lo, self.taps, dx);
    }
}

/// A transposed 1-D convolution (`weight [cin, cout, k]`).
#[derive(Debug)]
struct ConvT1d {
    w: Vec<f32>,
    b: Vec<f32>,
    cin: usize,
    taps: Taps,
}

impl ConvT1d {
    fn cout(&self) -> usize {
        self.b.len()
    }

    fn out_len(&self, len: usize) -> usize {
        (len - 1) * self.taps.stride + self.taps.k - 2 * self.taps.pad
    }

    /// `y = convT(x)`: the products `W[ci, co, kk]·x[ci, b, l]` land on output position
    /// `l·stride − pad + kk`, i.e. a matrix product followed by [`scatter_add`].
    fn forward(&self, x: &[f32], batch: usize, len: usize, col: &mut Vec<f32>, y: &mut Vec<f32>) {
        let (lo, ck) = (self.out_len(len), self.cout() * self.taps.k);
        let n = batch * len;
        resize_for_overwrite(col, ck * n);
        sgemm(ck, n, self.cin, &self.w, 1, ck, x, n, 1, col, false);
        y.clear();
        y.resize(self.cout() * batch * lo, 0.0);
        scatter_add(col, self.cout(), batch, lo, len, self.taps, y);
        add_bias(y, &self.b);
    }

    /// `dx += convTᵀ(dy)`.
    fn backward(&self, dy: &[f32], batch: usize, len: usize, col: &mut Vec<f32>, dx: &mut [f32]) {
        let (lo, ck) = (self.out_len(len), self.cout() * self.taps.k);
        gather(dy, self.cout(), batch, lo, len, self.taps, col);
        sgemm(
            self.cin,
            batch * len,
            ck,
            &self.w,
            ck,
            1,
            col,
            batch * len,
            1,
            dx,
            true,
        );
    }
}

/// GroupNorm's affine parameters.
#[derive(Debug)]
struct Norm {
    gamma: Vec<f32>,
    beta: Vec<f32>,
    groups: usize,
}

impl Norm {
    fn load(w: &mut Weights, name: &str, c: usize, groups: usize) -> Result<Self, WeightError> {
        Ok(Self {
            gamma: take(w, &format!("{name}.weight"), c)?,
            beta: take(w, &format!("{name}.bias"), c)?,
            groups,
        })
    }
}

/// What the backward pass of one Conv → GroupNorm → activation block needs.
#[derive(Debug, Default)]
struct BlockCache {
    /// Normalised conv output `x̂` (the pre-activation is `γ·x̂ + β`).
    xhat: Vec<f32>,
    /// `1/σ` per `(b, group)`.
    inv_std: Vec<f32>,
}

/// Conv1d → GroupNorm → activation (`Conv1dBlock`).
#[derive(Debug)]
struct ConvBlock {
    conv: Conv1d,
    norm: Norm,
}

impl ConvBlock {
    fn load(
        w: &mut Weights,
        name: &str,
        cin: usize,
        cout: usize,
        cfg: &NetConfig,
    ) -> Result<Self, WeightError> {
        let k = cfg.kernel_size;
        let taps = Taps {
            k,
            stride: 1,
            pad: k / 2,
        };
        Ok(Self {
            conv: Conv1d::load(w, &format!("{name}.conv"), cin, cout, taps)?,
            norm: Norm::load(w, &format!("{name}.norm"), cout, cfg.n_groups)?,
        })
    }

    fn block_norm(&self) -> BlockNorm<'_> {
        BlockNorm {
            groups: self.norm.groups,
            gamma: &self.norm.gamma,
            beta: &self.norm.beta,
            conv_bias: &self.conv.b,
        }
    }

    /// `out = act(GN(conv(x)))`, then `shift + out·scale` with `film = (scale, shift)`; the
    /// length is unchanged.
    fn forward(
        &self,
        act: Activation,
        x: &[f32],
        (batch, len): (usize, usize),
        film: Option<(&[f32], &[f32])>,
        s: &mut Scratch,
        cache: &mut BlockCache,
        out: &mut Vec<f32>,
    ) {
        let mut y = std::mem::take(&mut s.y);
        self.conv
            .forward_unbiased(x, batch, len, &mut s.col, &mut y);
        norm_act(
            act,
            &y,
            self.block_norm(),
            batch,
            len,
            film,
            &mut cache.xhat,
            &mut cache.inv_std,
            out,
        );
        s.y = y;
    }

    /// `dx += ∂out/∂xᵀ·dout` (with the FiLM scale the forward pass had); `dout` is consumed as
    /// scratch.
    fn backward(
        &self,
        act: Activation,
        dout: &mut [f32],
        (batch, len): (usize, usize),
        film_scale: Option<&[f32]>,
        s: &mut Scratch,
        cache: &BlockCache,
        dx: &mut [f32],
    ) {
        norm_act_backward(
            act,
            dout,
            self.block_norm(),
            batch,
            len,
            film_scale,
            &cache.xhat,
            &cache.inv_std,
        );
        self.conv.backward(dout, batch, len, &mut s.col, dx);
    }
}

/// A residual block with FiLM (`ConditionalResidualBlock1D`).
#[derive(Debug)]
struct ResBlock {
    block0: ConvBlock,
    block1: ConvBlock,
    residual: Option<Conv1d>,
    /// Offset of this block's `[scale; bias]` in the FiLM vector.
    film_offset: usize,
}

#[derive(Debug, Default)]
struct ResCache {
    b0: BlockCache,
    b1: BlockCache,
}

impl ResBlock {
    /// Loads the block `name`; its FiLM `[scale; bias]` follows the previous block's at
    /// `film_offset`, which moves past it.
    fn load(
        w: &mut Weights,
        film_offset: &mut usize,
        name: &str,
        cin: usize,
        cout: usize,
        cfg: &NetConfig,
    ) -> Result<Self, WeightError> {
        let residual = if cin != cout {
            let taps = Taps {
                k: 1,
                stride: 1,
                pad: 0,
            };
            Some(Conv1d::load(
                w,
                &format!("{name}.residual"),
                cin,
                cout,
                taps,
            )?)
        } else {
            None
        };
        let block = ResBlock {
            block0: ConvBlock::load(w, &format!("{name}.block0"), cin, cout, cfg)?,
            block1: ConvBlock::load(w, &format!("{name}.block1"), cout, cout, cfg)?,
            residual,
            film_offset: *film_offset,
        };
        *film_offset += 2 * cout;
        Ok(block)
    }

    fn cout(&self) -> usize {
        self.block0.conv.cout()
    }

    fn forward(
        &self,
        net: &Net,
        x: &[f32],
        (batch, len): (usize, usize),
        film: &[f32],
        s: &mut Scratch,
        cache: &mut ResCache,
        out: &mut Vec<f32>,
    ) {
        let c = self.cout();
        let film = film[self.film_offset..self.film_offset + 2 * c].split_at(c);
        let mut h = std::mem::take(&mut s.h);
        let bl = (batch, len);
        self.block0
            .forward(net.act, x, bl, Some(film), s, &mut cache.b0, &mut h);
        self.block1
            .forward(net.act, &h, bl, None, s, &mut cache.b1, out);
        s.h = h;
        match &self.residual {
            Some(r) => {
                let mut res = std::mem::take(&mut s.res);
                r.forward(x, batch, len, &mut s.col, &mut res);
                add_to(out, &res);
                s.res = res;
            }
            None => add_to(out, x),
        }
    }

    /// `dx = ∂out/∂xᵀ·dout` (overwrites `dx`, sized here).
    fn backward(
        &self,
        net: &Net,
        dout: &[f32],
        (batch, len): (usize, usize),
        film: &[f32],
        s: &mut Scratch,
        cache: &ResCache,
        dx: &mut Vec<f32>,
    ) {
        let c = self.cout();
        let cin = self.block0.conv.cin;
        dx.clear();
        dx.resize(cin * batch * len, 0.0);
        match &self.residual {
            Some(r) => r.backward(dout, batch, len, &mut s.col, dx),
            None => dx.copy_from_slice(dout),
        }
        let mut d1 = std::mem::take(&mut s.d1);
        d1.clear();
        d1.extend_from_slice(dout);
        let mut dh = std::mem::take(&mut s.h);
        dh.clear();
        dh.resize(c * batch * len, 0.0);
        let bl = (batch, len);
        self.block1
            .backward(net.act, &mut d1, bl, None, s, &cache.b1, &mut dh);
        let scale = &film[self.film_offset..self.film_offset + c];
        self.block0
            .backward(net.act, &mut dh, bl, Some(scale), s, &cache.b0, dx);
        s.d1 = d1;
        s.h = dh;
    }
}

#[derive(Debug)]
struct DownLevel {
    blocks: Vec<ResBlock>,
    down: Option<Conv1d>,
}

#[derive(Debug)]
struct UpLevel {
    blocks: Vec<ResBlock>,
    up: ConvT1d,
}

/// A 2-D convolution of the BEV encoder (stride 2, padding 1, 3×3), batch 1, `[C, H·W]`.
#[derive(Debug)]
struct Conv2d {
    w: Vec<f32>,
    b: Vec<f32>,
    cin: usize,
}

impl Conv2d {
    /// The convolution without its bias (which the normalisation after it folds in), and the
    /// output side.
    fn forward_unbiased(&self, x: &[f32], side: usize) -> (Vec<f32>, usize) {
        let out_side = (side + 2 - 3) / 2 + 1;
        let ck = self.cin * 9;
        let n = out_side * out_side;
        let mut col = vec![0f32; ck * n];
        for c in 0..self.cin {
            for ky in 0..3 {
                for kx in 0..3 {
                    let row = &mut col[(c * 9 + ky * 3 + kx) * n..(c * 9 + ky * 3 + kx + 1) * n];
                    for oy in 0..out_side {
                        let Some(iy) = (2 * oy + ky).checked_sub(1).filter(|&v| v < side) else {
                            continue;
                        };
                        for ox in 0..out_side {
                            if let Some(ix) = (2 * ox + kx).checked_sub(1).filter(|&v| v < side) {
                                row[oy * out_side + ox] = x[(c * side + iy) * side + ix];
                            }
                        }
                    }
                }
            }
        }
        let mut y = vec![0f32; self.b.len() * n];
        sgemm(
            self.b.len(),
            n,
            ck,
            &self.w,
            ck,
            1,
            &col,
            n,
            1,
            &mut y,
            false,
        );
        add_bias(&mut y, &self.b);
        (y, out_side)
    }
}

/// The native network: the same layers and weights as [`crate::net::CondUnet1d`].
#[derive(Debug)]
pub(crate) struct Net {
    cfg: NetConfig,
    act: Activation,
    time0: Linear,
    time1: Linear,
    bev: Vec<(Conv2d, Norm)>,
    bev_fc: Linear,
    goal0: Linear,
    goal1: Linear,
    film: Linear,
    /// The crowd pathway, when the architecture has one.
    pub(crate) crowd: Option<Crowd>,
    down: Vec<DownLevel>,
    mid: Vec<ResBlock>,
    up: Vec<UpLevel>,
    final_block: ConvBlock,
    final_conv: Conv1d,
}

/// Reusable buffers of the layers (no allocation once they have grown to the batch size).
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    col: Vec<f32>,
    y: Vec<f32>,
    h: Vec<f32>,
    res: Vec<f32>,
    d1: Vec<f32>,
}

/// Everything one forward pass keeps for its backward pass (reused across calls).
#[derive(Debug, Default)]
pub(crate) struct Tape {
    batch: usize,
    /// The caches of every residual block (the backward pass of a linear map needs only its
    /// weights, so no layer inputs are kept).
    res: Vec<ResCache>,
    final_block: BlockCache,
    /// Output of each level's blocks (the skip connections), per down level.
    skips: Vec<Vec<f32>>,
}

/// Buffers the passes use between layers and then hand back: shared by every [`Tape`] of a
/// model, so that keeping several tapes does not multiply them.
#[derive(Debug, Default)]
pub(crate) struct Pool {
    acts: Vec<Vec<f32>>,
    scratch: Scratch,
}

/// Sinusoidal time frequency multiplier of [`crate::net`].
const TIME_SCALE: f32 = crate::net::TIME_SCALE as f32;

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

    /// The static condition `[BEV embedding, goal embedding]` of one normalised raster
    /// (`[3, H, W]`) and goal/velocity features.
    pub(crate) fn encode_condition(&self, bev: &[f32], goal_vel: &[f32]) -> Vec<f32> {
        let mut h = bev.to_vec();
        let mut side = self.cfg.bev_cells;
        for (conv, norm) in &self.bev {
            let (y, s) = conv.forward_unbiased(&h, side);
            let n = BlockNorm {
                groups: norm.groups,
                gamma: &norm.gamma,
                beta: &norm.beta,
                conv_bias: &conv.b,
            };
            let (mut xh, mut inv) = (Vec::new(), Vec::new());
            norm_act(self.act, &y, n, 1, s * s, None, &mut xh, &mut inv, &mut h);
            side = s;
        }
        let pooled = adaptive_avg_pool_4x4(&h, side);
        let mut bev_emb = self.bev_fc.apply(&pooled);
        activate_in_place(self.act, &mut bev_emb);
        let mut g = self.goal0.apply(goal_vel);
        activate_in_place(self.act, &mut g);
        let goal_emb = self.goal1.apply(&g);
        bev_emb.extend_from_slice(&goal_emb);
        bev_emb
    }

    /// The FiLM vector (`[scale; bias]` per residual block, in order) for flow time `t` and a
    /// static condition from [`Self::encode_condition`].
    pub(crate) fn film(&self, t: f64, cond: &[f32]) -> Vec<f32> {
        let half = self.cfg.time_embed_dim / 2;
        // The same operations in the same precision as the torch network (f32 throughout).
        let step = (10000f64.ln() / (half - 1) as f64) as f32;
        let t = t as f32;
        let mut emb = vec![0f32; 2 * half];
        for j in 0..half {
            let a = t * TIME_SCALE * (j as f32 * -step).exp();
            emb[j] = a.sin();
            emb[half + j] = a.cos();
        }
        let mut h = self.time0.apply(&emb);
        activate_in_place(self.act, &mut h);
        let mut c = self.time1.apply(&h);
        c.extend_from_slice(cond);
        activate_in_place(self.act, &mut c);
        self.film.apply(&c)
    }

    /// The network output `[3, batch, T]` for features `x` (`[5, batch, T]`, then the crowd
    /// pathway's `[width, batch, T]` when the network has one), recording in
    /// `tape` what [`Self::backward`] needs.
    pub(crate) fn forward(
        &self,
        x: &[f32],
        batch: usize,
        film: &[f32],
        tape: &mut Tape,
        pool: &mut Pool,
        out: &mut Vec<f32>,
    ) {
        let n_res = self.down.iter().map(|l| l.blocks.len()).sum::<usize>()
            + self.mid.len()
            + self.up.iter().map(|l| l.blocks.len()).sum::<usize>();
        tape.batch = batch;
        tape.res.resize_with(n_res, ResCache::default);
        tape.skips.resize_with(self.down.len(), Vec::new);
        let mut acts = std::mem::take(&mut pool.acts);
        let mut next = || -> Vec<f32> { acts.pop().unwrap_or_default() };
        let mut h = next();
        h.clear();
        h.extend_from_slice(x);
        let mut len = self.cfg.horizon;
        let mut r = 0;
        let mut spent: Vec<Vec<f32>> = Vec::new();
        let s = &mut pool.scratch;
        for (i, lvl) in self.down.iter().enumerate() {
            for b in &lvl.blocks {
                let mut o = next();
                b.forward(self, &h, (batch, len), film, s, &mut tape.res[r], &mut o);
                r += 1;
                spent.push(std::mem::replace(&mut h, o));
            }
            tape.skips[i].clear();
            tape.skips[i].extend_from_slice(&h);
            if let Some(d) = &lvl.down {
                let mut o = next();
                d.forward(&h, batch, len, &mut s.col, &mut o);
                len = d.out_len(len);
                spent.push(std::mem::replace(&mut h, o));
            }
        }
        for m in &self.mid {
            let mut o = next();
            m.forward(self, &h, (batch, len), film, s, &mut tape.res[r], &mut o);
            r += 1;
            spent.push(std::mem::replace(&mut h, o));
        }
        for (j, lvl) in self.up.iter().enumerate() {
            // Channel concatenation [h; skip] of [C, B, L] buffers is an append.
            let skip = self.down.len() - 1 - j;
            h.extend_from_slice(&tape.skips[skip]);
            for b in &lvl.blocks {
                let mut o = next();
                b.forward(self, &h, (batch, len), film, s, &mut tape.res[r], &mut o);
                r += 1;
                spent.push(std::mem::replace(&mut h, o));
            }
            let mut o = next();
            lvl.up.forward(&h, batch, len, &mut s.col, &mut o);
            len = lvl.up.out_len(len);
            spent.push(std::mem::replace(&mut h, o));
        }
        let mut o = next();
        let fb = &mut tape.final_block;
        self.final_block
            .forward(self.act, &h, (batch, len), None, s, fb, &mut o);
        spent.push(h);
        self.final_conv.forward(&o, batch, len, &mut s.col, out);
        spent.push(o);
        acts.extend(spent);
        pool.acts = acts;
    }

    /// `dx = ∂out/∂xᵀ·dout` of the forward pass recorded in `tape`, `dx` shaped as the
    /// forward pass's `x`.
    pub(crate) fn backward(
        &self,
        dout: &[f32],
        film: &[f32],
        tape: &Tape,
        pool: &mut Pool,
        dx: &mut Vec<f32>,
    ) {
        let batch = tape.batch;
        let mut lens = Vec::with_capacity(self.down.len());
        let mut len = self.cfg.horizon;
        for lvl in &self.down {
            lens.push(len);
            if let Some(d) = &lvl.down {
                len = d.out_len(len);
            }
        }
        let mut acts = std::mem::take(&mut pool.acts);
        let mut next = || -> Vec<f32> { acts.pop().unwrap_or_default() };
        let s = &mut pool.scratch;
        let mut r = tape.res.len();
        // Final 1×1 conv and final block.
        let final_len = self.cfg.horizon;
        let d0 = self.final_block.conv.cout();
        let mut g = next();
        g.clear();
        g.resize(d0 * batch * final_len, 0.0);
        self.final_conv
            .backward(dout, batch, final_len, &mut s.col, &mut g);
        let mut gh = next();
        gh.clear();
        gh.resize(d0 * batch * final_len, 0.0);
        let fb = &tape.final_block;
        self.final_block
            .backward(self.act, &mut g, (batch, final_len), None, s, fb, &mut gh);
        let mut spent = vec![g];
        // Gradients arriving at each skip connection.
        let mut dskips: Vec<Option<Vec<f32>>> = vec![None; self.down.len()];
        let mut len = final_len;
        for (j, lvl) in self.up.iter().enumerate().rev() {
            // An up level works at the length of the skip connection it joins.
            let skip = self.down.len() - 1 - j;
            let lin = lens[skip];
            let mut gi = next();
            gi.clear();
            gi.resize(lvl.up.cin * batch * lin, 0.0);
            lvl.up.backward(&gh, batch, lin, &mut s.col, &mut gi);
            spent.push(std::mem::replace(&mut gh, gi));
            len = lin;
            for b in lvl.blocks.iter().rev() {
                r -= 1;
                let mut o = next();
                b.backward(self, &gh, (batch, len), film, s, &tape.res[r], &mut o);
                spent.push(std::mem::replace(&mut gh, o));
            }
            // Split the gradient of [h; skip].
            let split = gh.len() - tape.skips[skip].len();
            dskips[skip] = Some(gh[split..].to_vec());
            gh.truncate(split);
        }
        for m in self.mid.iter().rev() {
            r -= 1;
            let mut o = next();
            m.backward(self, &gh, (batch, len), film, s, &tape.res[r], &mut o);
            spent.push(std::mem::replace(&mut gh, o));
        }
        for (i, lvl) in self.down.iter().enumerate().rev() {
            let lin = lens[i];
            if let Some(d) = &lvl.down {
                let mut gi = next();
                gi.clear();
                gi.resize(d.cin * batch * lin, 0.0);
                d.backward(&gh, batch, lin, &mut s.col, &mut gi);
                spent.push(std::mem::replace(&mut gh, gi));
            }
            if let Some(ds) = dskips[i].take() {
                add_to(&mut gh, &ds);
            }
            len = lin;
            for b in lvl.blocks.iter().rev() {
                r -= 1;
                let mut o = next();
                b.backward(self, &gh, (batch, len), film, s, &tape.res[r], &mut o);
                spent.push(std::mem::replace(&mut gh, o));
            }
        }
        dx.clear();
        dx.extend_from_slice(&gh);
        spent.push(gh);
        acts.extend(spent);
        pool.acts = acts;
    }
}

/// Torch's `adaptive_avg_pool2d(·, [4, 4])` of `[C, side, side]`, flattened `[C·16]`.
fn adaptive_avg_pool_4x4(x: &[f32], side: usize) -> Vec<f32> {
    let channels = x.len() / (side * side);
    let bounds = |i: usize| (i * side / 4, ((i + 1) * side).div_ceil(4));
    let mut out = vec![0f32; channels * 16];
    for c in 0..channels {
        for oy in 0..4 {
            let (y0, y1) = bounds(oy);
            for ox in 0..4 {
                let (x0, x1) = bounds(ox);
                let mut s = 0f32;
                for y in y0..y1 {
                    for xx in x0..x1 {
                        s += x[(c * side + y) * side + xx];
                    }
                }
                out[c * 16 + oy * 4 + ox] = s / ((y1 - y0) * (x1 - x0)) as f32;
            }
        }
    }
    out
}
