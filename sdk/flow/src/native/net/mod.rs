//! The conditional U-Net of [`crate::net`] rebuilt over plain `f32` buffers: the same layers,
//! the same weights (read by name from the safetensors file), a forward pass and the backward
//! pass of its input, with every activation the backward pass needs kept in a reusable
//! [`Tape`]. Activations are `[C, B, L]` (channel-major), so the U-Net's channel concatenation
//! is a plain append and a convolution is one matrix product over the whole batch.

use super::crowd::Crowd;
use super::kernels::{
    BlockNorm, Film, GroupSums, Taps, add_bias, add_to, gather, linear, norm_act,
    norm_act_backward, resize_for_overwrite, scatter_add, sgemm,
};
use crate::config::{Activation, NetConfig};
use std::collections::BTreeMap;

mod load;
mod pass;

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
    /// Normalised conv output `x̂` (the pre-activation is `γ·x̂ + β`), `[C, B, len]`.
    xhat: Vec<f32>,
    /// `1/σ` per `(b, group)`.
    inv_std: Vec<f32>,
    len: usize,
}

impl BlockCache {
    /// The cache of rows `rows` of a pass over `batch` rows.
    fn gather(&self, batch: usize, rows: &[usize], into: &mut Self) {
        gather_rows(&self.xhat, batch, self.len, rows, &mut into.xhat);
        let groups = self.inv_std.len() / batch.max(1);
        gather_rows(&self.inv_std, batch, groups, rows, &mut into.inv_std);
        into.len = self.len;
    }
}

/// Rows `rows` of a `[C, batch, len]` buffer, as `[C, rows.len(), len]`.
pub(crate) fn gather_rows<T: Copy>(
    src: &[T],
    batch: usize,
    len: usize,
    rows: &[usize],
    out: &mut Vec<T>,
) {
    out.clear();
    if batch == 0 || len == 0 {
        return;
    }
    for plane in src.chunks_exact(batch * len) {
        for &r in rows {
            out.extend_from_slice(&plane[r * len..(r + 1) * len]);
        }
    }
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

    /// `out = act(GN(conv(x)))`, then `shift + out·scale` with each row's FiLM; the
    /// length is unchanged.
    fn forward(
        &self,
        act: Activation,
        x: &[f32],
        (batch, len): (usize, usize),
        film: Option<Film<'_>>,
        s: &mut Scratch,
        cache: &mut BlockCache,
        out: &mut Vec<f32>,
    ) {
        let mut y = std::mem::take(&mut s.y);
        self.conv
            .forward_unbiased(x, batch, len, &mut s.col, &mut y);
        cache.len = len;
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
            &mut s.sums,
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
        film: Option<Film<'_>>,
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
            film,
            &cache.xhat,
            &cache.inv_std,
            &mut s.sums,
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
        film: Film<'_>,
        s: &mut Scratch,
        cache: &mut ResCache,
        out: &mut Vec<f32>,
    ) {
        let film = film.at(self.film_offset);
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
        film: Film<'_>,
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
        self.block0.backward(
            net.act,
            &mut dh,
            bl,
            Some(film.at(self.film_offset)),
            s,
            &cache.b0,
            dx,
        );
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
    sums: GroupSums,
}

/// Everything one forward pass keeps for its backward pass (reused across calls).
#[derive(Debug, Default)]
pub(crate) struct Tape {
    batch: usize,
    /// The caches of every residual block (the backward pass of a linear map needs only its
    /// weights, so no layer inputs are kept).
    res: Vec<ResCache>,
    final_block: BlockCache,
    /// Output of each level's blocks (the skip connections), per down level, and its length.
    skips: Vec<Vec<f32>>,
    skip_lens: Vec<usize>,
}

impl Tape {
    /// What a forward pass over rows `rows` of this pass's input records: each row of a pass
    /// is computed on its own (the values equal to the bit).
    pub(crate) fn gather(&self, rows: &[usize], into: &mut Tape) {
        let batch = self.batch;
        into.batch = rows.len();
        into.res.resize_with(self.res.len(), ResCache::default);
        for (from, to) in self.res.iter().zip(&mut into.res) {
            from.b0.gather(batch, rows, &mut to.b0);
            from.b1.gather(batch, rows, &mut to.b1);
        }
        self.final_block.gather(batch, rows, &mut into.final_block);
        into.skips.resize_with(self.skips.len(), Vec::new);
        for ((from, to), &len) in self.skips.iter().zip(&mut into.skips).zip(&self.skip_lens) {
            gather_rows(from, batch, len, rows, to);
        }
        into.skip_lens.clone_from(&self.skip_lens);
    }
}

/// Buffers the passes use between layers and then hand back: shared by every [`Tape`] of a
/// model, so that keeping several tapes does not multiply them.
#[derive(Debug, Default)]
pub(crate) struct Pool {
    acts: Vec<Vec<f32>>,
    scratch: Scratch,
}
