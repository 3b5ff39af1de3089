//! The passes of [`Net`]: the condition encoding, the FiLM vector of a flow time, the forward
//! pass with its [`Tape`] and the backward pass of its input.

use super::{Net, Pool, ResCache, Tape};
use crate::native::kernels::{BlockNorm, Film, GroupSums, activate_in_place, add_to, norm_act};

/// Sinusoidal time frequency multiplier of [`crate::net`].
const TIME_SCALE: f32 = crate::net::TIME_SCALE as f32;

impl Net {
    /// The static condition `[BEV embedding, goal embedding]` of one normalised raster
    /// (`[3, H, W]`) and goal/velocity features.
    pub(crate) fn encode_condition(&self, bev: &[f32], goal_vel: &[f32]) -> Vec<f32> {
        let mut h = bev.to_vec();
        let mut side = self.cfg.bev_cells;
        let sums = &mut GroupSums::default();
        for (conv, norm) in &self.bev {
            let (y, s) = conv.forward_unbiased(&h, side);
            let n = BlockNorm {
                groups: norm.groups,
                gamma: &norm.gamma,
                beta: &norm.beta,
                conv_bias: &conv.b,
            };
            let (mut xh, mut inv) = (Vec::new(), Vec::new());
            norm_act(
                self.act,
                &y,
                n,
                1,
                s * s,
                None,
                &mut xh,
                &mut inv,
                &mut h,
                sums,
            );
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
        film: Film<'_>,
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
        tape.skip_lens.resize(self.down.len(), 0);
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
            tape.skip_lens[i] = len;
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
        film: Film<'_>,
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
