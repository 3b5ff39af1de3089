//! The few kernels the native network is made of, over `[C, B, L]` activations (channel-major,
//! batch, then position): a single-threaded SGEMM, the gather/scatter pair that turns 1-D
//! convolutions (plain and transposed) into matrix products, group normalisation and the
//! activations, each with the backward pass of its data input (no weight gradients: the native
//! path runs a trained model, it does not train one).

use crate::config::Activation;

/// Defines a function whose body is compiled three times, for AVX-512, for AVX2 + FMA and for
/// the baseline target, and calls the best one this CPU runs: the elementwise kernels are
/// plain loops that the compiler vectorises to the width it is allowed.
macro_rules! multiversion {
    ($(#[$m:meta])* $vis:vis fn $name:ident($($arg:ident : $ty:ty),* $(,)?) $body:block) => {
        $(#[$m])*
        $vis fn $name($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
                fn v4($($arg: $ty),*) $body
                #[target_feature(enable = "avx2,fma")]
                fn v3($($arg: $ty),*) $body
                if std::arch::is_x86_feature_detected!("avx512f")
                    && std::arch::is_x86_feature_detected!("avx512vl")
                {
                    // SAFETY: this CPU has the features `v4` is compiled for.
                    return unsafe { v4($($arg),*) };
                }
                if std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    // SAFETY: this CPU has the features `v3` is compiled for.
                    return unsafe { v3($($arg),*) };
                }
            }
            #[allow(unreachable_code)]
            $body
        }
    };
}

pub(crate) use multiversion;

/// `eˣ` for `f32` without a library call, so that loops over it vectorise: Cephes' `expf`
/// (range reduction by `ln 2`, a degree-6 polynomial, relative error about 2·10⁻⁷), with the
/// argument clamped to `[−87, 88]` (the normal range; the activations never need more). The
/// reduction and the polynomial are fused multiply-adds: the kernels that call it are compiled
/// for CPUs with FMA, where this is half the instructions of separate products and sums (and
/// as accurate or more); elsewhere `mul_add` is a library call, slow but exact.
#[inline(always)]
fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.clamp(-87.0, 88.0);
    let n = x.mul_add(LOG2E, 0.5).floor();
    let r = n.mul_add(-LN2_LO, n.mul_add(-LN2_HI, x));
    let p = 1.987_569_1e-4f32
        .mul_add(r, 1.398_199_9e-3)
        .mul_add(r, 8.333_452e-3)
        .mul_add(r, 4.166_579_6e-2)
        .mul_add(r, 1.666_666_5e-1)
        .mul_add(r, 0.5);
    let y = (p * r).mul_add(r, r) + 1.0;
    // 2ⁿ without a float-to-int conversion (Rust's saturating `as` does not vectorise):
    // adding 1.5·2²³ puts the integer n in the low mantissa bits.
    let biased = (n + 12_582_912.0).to_bits().wrapping_sub(0x4B40_0000);
    y * f32::from_bits(biased.wrapping_add(127) << 23)
}

/// `c ← a·b` (or `c ← c + a·b` when `accumulate`) for row-major views with explicit strides:
/// `a` is `m × k` with element `(i, p)` at `a[i·a_rs + p·a_cs]`, `b` is `k × n` likewise and
/// `c` is `m × n`, contiguous row-major.
///
/// # Panics
/// When a view reaches past its slice (a programming error of the caller, checked here so the
/// kernel below never reads or writes out of bounds).
#[allow(clippy::too_many_arguments)]
pub(crate) fn sgemm(
    m: usize,
    n: usize,
    k: usize,
    a: &[f32],
    a_rs: usize,
    a_cs: usize,
    b: &[f32],
    b_rs: usize,
    b_cs: usize,
    c: &mut [f32],
    accumulate: bool,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        c.len() >= m * n,
        "sgemm: output holds {} < {}",
        c.len(),
        m * n
    );
    if k == 0 {
        if !accumulate {
            c[..m * n].fill(0.0);
        }
        return;
    }
    let last = |rows: usize, cols: usize, rs: usize, cs: usize| (rows - 1) * rs + (cols - 1) * cs;
    assert!(
        last(m, k, a_rs, a_cs) < a.len(),
        "sgemm: lhs view out of bounds"
    );
    assert!(
        last(k, n, b_rs, b_cs) < b.len(),
        "sgemm: rhs view out of bounds"
    );
    // SAFETY: every element the views address lies inside its slice (checked above), `c` is a
    // distinct mutable slice of at least m·n elements, and the strides fit in isize because
    // the addressed ranges fit in slices.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            n as isize,
            accumulate,
            a.as_ptr(),
            a_cs as isize,
            a_rs as isize,
            b.as_ptr(),
            b_cs as isize,
            b_rs as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// Shape of a 1-D (transposed) convolution's index map: output column `n` of kernel tap `kk`
/// touches source position `n·stride − pad + kk`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Taps {
    pub k: usize,
    pub stride: usize,
    pub pad: usize,
}

impl Taps {
    /// The source position of column `n`, tap `kk`, if it lies in `0..len`.
    #[inline]
    fn source(self, n: usize, kk: usize, len: usize) -> Option<usize> {
        let p = (n * self.stride + kk).checked_sub(self.pad)?;
        (p < len).then_some(p)
    }

    /// For stride 1: the columns `lo..hi` of `0..ln` whose tap `kk` lies in `0..len`, a run of
    /// consecutive source positions from `lo + kk − pad`.
    #[inline]
    fn run(self, kk: usize, len: usize, ln: usize) -> (usize, usize) {
        let lo = self.pad.saturating_sub(kk).min(ln);
        let hi = (len + self.pad).saturating_sub(kk).clamp(lo, ln);
        (lo, hi)
    }

    /// For stride 1 and rows of `len` columns over `len` positions: tap `kk`'s columns
    /// `lo..hi` of every row ([`Self::run`]), and the one run over a whole plane of `batch`
    /// rows that covers them: `n` consecutive columns from column `lo`, at positions from
    /// `start` on (each row's run where a run of its own puts it, and the few columns between
    /// two rows' runs, which [`zero_row_ends`] zeroes).
    #[inline]
    fn plane_run(self, kk: usize, len: usize, batch: usize) -> PlaneRun {
        let (lo, hi) = self.run(kk, len, len);
        PlaneRun {
            lo,
            hi,
            start: (lo + kk).saturating_sub(self.pad),
            n: (batch * len).saturating_sub(lo + len - hi),
        }
    }
}

/// A tap's run over a whole plane ([`Taps::plane_run`]).
struct PlaneRun {
    lo: usize,
    hi: usize,
    start: usize,
    n: usize,
}

/// Zeroes each row's columns outside `lo..hi` (rows of `len` columns).
#[inline]
fn zero_row_ends(row: &mut [f32], len: usize, (lo, hi): (usize, usize)) {
    for r in row.chunks_exact_mut(len) {
        zero_few(&mut r[..lo]);
        zero_few(&mut r[hi..]);
    }
}

/// `col[(c·k + kk), b·ln + n] = src[c, b, n·stride − pad + kk]` (zero outside `0..ls`):
/// `src` is `[channels, batch, ls]`, `col` is `[channels·k, batch·ln]`.
pub(crate) fn gather(
    src: &[f32],
    channels: usize,
    batch: usize,
    ls: usize,
    ln: usize,
    taps: Taps,
    col: &mut Vec<f32>,
) {
    let k = taps.k;
    resize_for_overwrite(col, channels * k * batch * ln);
    for c in 0..channels {
        for kk in 0..k {
            let row = &mut col[(c * k + kk) * batch * ln..(c * k + kk + 1) * batch * ln];
            if taps.stride == 1 && ln == ls {
                // The whole plane shifted by `kk − pad` in one copy, then each row's ends
                // zeroed.
                let plane = &src[c * batch * ls..(c + 1) * batch * ls];
                let PlaneRun { lo, hi, start, n } = taps.plane_run(kk, ls, batch);
                if lo < hi {
                    row[lo..lo + n].copy_from_slice(&plane[start..start + n]);
                }
                zero_row_ends(row, ln, (lo, hi));
                continue;
            }
            for b in 0..batch {
                let s = &src[(c * batch + b) * ls..(c * batch + b + 1) * ls];
                let r = &mut row[b * ln..(b + 1) * ln];
                if taps.stride == 1 {
                    // Contiguous run: positions n − pad + kk for n in 0..ln, zero outside.
                    let (lo, hi) = taps.run(kk, ls, ln);
                    r[..lo].fill(0.0);
                    let s0 = lo + kk - taps.pad;
                    r[lo..hi].copy_from_slice(&s[s0..s0 + (hi - lo)]);
                    r[hi..].fill(0.0);
                } else {
                    for (n, v) in r.iter_mut().enumerate() {
                        *v = taps.source(n, kk, ls).map_or(0.0, |p| s[p]);
                    }
                }
            }
        }
    }
}

/// Zeroes the few values (a convolution's padding, one or two) at a row's end: stores, where
/// `fill` on a slice of unknown length is a library call per row.
#[inline(always)]
fn zero_few(r: &mut [f32]) {
    match r {
        [] => {}
        [a] => *a = 0.0,
        [a, b] => (*a, *b) = (0.0, 0.0),
        _ => r.fill(0.0),
    }
}

/// The adjoint of [`gather`]: `dst[c, b, n·stride − pad + kk] += col[(c·k + kk), b·ln + n]`.
/// `col` is consumed: a same-length convolution's columns whose target lies outside their
/// own row are zeroed, so that each tap adds its whole plane in one pass (every target still
/// receives one addition per tap, in the same order).
pub(crate) fn scatter_add(
    col: &mut [f32],
    channels: usize,
    batch: usize,
    ld: usize,
    ln: usize,
    taps: Taps,
    dst: &mut [f32],
) {
    let k = taps.k;
    for c in 0..channels {
        for kk in 0..k {
            let row = &mut col[(c * k + kk) * batch * ln..(c * k + kk + 1) * batch * ln];
            if taps.stride == 1 && ln == ld {
                let PlaneRun { lo, hi, start, n } = taps.plane_run(kk, ld, batch);
                if lo < hi {
                    zero_row_ends(row, ln, (lo, hi));
                    let plane = &mut dst[c * batch * ld..(c + 1) * batch * ld];
                    add_to(&mut plane[start..start + n], &row[lo..lo + n]);
                }
                continue;
            }
            for b in 0..batch {
                let d = &mut dst[(c * batch + b) * ld..(c * batch + b + 1) * ld];
                let r = &row[b * ln..(b + 1) * ln];
                if taps.stride == 1 {
                    // Contiguous run, as in `gather`.
                    let (lo, hi) = taps.run(kk, ld, ln);
                    if lo < hi {
                        let d0 = lo + kk - taps.pad;
                        add_to(&mut d[d0..d0 + (hi - lo)], &r[lo..hi]);
                    }
                    continue;
                }
                for (n, &v) in r.iter().enumerate() {
                    if let Some(p) = taps.source(n, kk, ld) {
                        d[p] += v;
                    }
                }
            }
        }
    }
}

multiversion! {
    /// `dst += src` elementwise.
    pub(crate) fn add_to(dst: &mut [f32], src: &[f32]) {
        for (d, s) in dst.iter_mut().zip(src) {
            *d += s;
        }
    }
}

/// Adds `bias[c]` to every element of channel `c` of `[channels, rest]`.
pub(crate) fn add_bias(x: &mut [f32], bias: &[f32]) {
    let rest = x.len() / bias.len();
    for (row, &b) in x.chunks_exact_mut(rest).zip(bias) {
        for v in row {
            *v += b;
        }
    }
}

/// Torch's GroupNorm epsilon.
const GN_EPS: f32 = 1e-5;

/// Sums in 16 independent `f32` lanes, so that the loops vectorise (a single running sum would
/// force the additions into order); a group's rows accumulate into the same lanes and are
/// reduced once, in `f64`. A lane holds a few dozen terms at most (a group of 128 values is 8
/// per lane), as torch's own `f32` moments do.
#[inline(always)]
fn lanes(acc: [f32; 16]) -> f64 {
    acc.iter().map(|&v| f64::from(v)).sum()
}

/// `acc += w·x` lane-wise.
#[inline(always)]
fn add_scaled_lanes(acc: &mut [f32; 16], x: &[f32], w: f32) {
    let c = x.chunks_exact(16);
    for (i, v) in c.remainder().iter().enumerate() {
        acc[i] += w * v;
    }
    for ch in c {
        for i in 0..16 {
            acc[i] += w * ch[i];
        }
    }
}

/// `acc += (x − m)²` lane-wise.
#[inline(always)]
fn add_sq_dev_lanes(acc: &mut [f32; 16], x: &[f32], m: f32) {
    let c = x.chunks_exact(16);
    for (i, v) in c.remainder().iter().enumerate() {
        acc[i] += (v - m) * (v - m);
    }
    for ch in c {
        for i in 0..16 {
            let d = ch[i] - m;
            acc[i] += d * d;
        }
    }
}

/// `acc += x·y` lane-wise, scaled by `w`.
#[inline(always)]
fn add_dot_lanes(acc: &mut [f32; 16], x: &[f32], y: &[f32], w: f32) {
    let (cx, cy) = (x.chunks_exact(16), y.chunks_exact(16));
    for (i, (a, b)) in cx.remainder().iter().zip(cy.remainder()).enumerate() {
        acc[i] += w * a * b;
    }
    for (a, b) in cx.zip(cy) {
        for i in 0..16 {
            acc[i] += w * a[i] * b[i];
        }
    }
}

/// `Σ xᵢ·yᵢ` over the common length.
#[inline(always)]
pub(crate) fn dot(x: &[f32], y: &[f32]) -> f32 {
    let n = x.len().min(y.len());
    let (x, y) = (&x[..n], &y[..n]);
    let mut acc = [0f32; 16];
    let (cx, cy) = (x.chunks_exact(16), y.chunks_exact(16));
    let tail: f32 = cx
        .remainder()
        .iter()
        .zip(cy.remainder())
        .map(|(a, b)| a * b)
        .sum();
    for (a, b) in cx.zip(cy) {
        for i in 0..16 {
            acc[i] += a[i] * b[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// Resizes a buffer that the caller overwrites completely (no zeroing when it already has
/// the length).
#[inline]
pub(crate) fn resize_for_overwrite<T: Copy + Default>(v: &mut Vec<T>, n: usize) {
    if v.len() != n {
        v.resize(n, T::default());
    }
}

/// Per-row lanes and statistics of one group of [`norm_act`] and [`norm_act_backward`], reused
/// from call to call.
#[derive(Debug, Default)]
pub(crate) struct GroupSums {
    a1: Vec<[f32; 16]>,
    a2: Vec<[f32; 16]>,
    means: Vec<(f64, f64)>,
}

impl GroupSums {
    /// Zeroes the lanes of `batch` rows.
    fn clear(&mut self, batch: usize) {
        for a in [&mut self.a1, &mut self.a2] {
            a.clear();
            a.resize(batch, [0f32; 16]);
        }
        self.means.resize(batch, (0.0, 0.0));
    }
}

/// A convolution block's normalisation: GroupNorm's groups and affine parameters, and the
/// bias of the convolution before it (folded into the statistics instead of a pass of its own).
#[derive(Clone, Copy, Debug)]
pub(crate) struct BlockNorm<'a> {
    pub groups: usize,
    pub gamma: &'a [f32],
    pub beta: &'a [f32],
    pub conv_bias: &'a [f32],
}

/// The FiLM vectors `[scale; shift]` of a batch's rows: row `b`'s vector for a block of `c`
/// channels starts at `data[start(b) + offset]`, with `start(b)` from `rows` (one vector per
/// condition of a batch of several) or `0` for every row (one shared by the batch).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Film<'a> {
    data: &'a [f32],
    rows: Option<&'a [usize]>,
    offset: usize,
}

impl<'a> Film<'a> {
    /// One FiLM vector for every row.
    pub(crate) fn shared(data: &'a [f32]) -> Self {
        Self {
            data,
            rows: None,
            offset: 0,
        }
    }

    /// Row `b`'s vector at `data[rows[b]..]`.
    pub(crate) fn per_row(data: &'a [f32], rows: &'a [usize]) -> Self {
        Self {
            data,
            rows: Some(rows),
            offset: 0,
        }
    }

    /// The same vectors read `offset` further on (a block's part of them).
    pub(crate) fn at(self, offset: usize) -> Self {
        Self {
            offset: self.offset + offset,
            ..self
        }
    }

    /// Row `b`'s scale and shift of `c` channels.
    #[inline(always)]
    fn row(&self, b: usize, c: usize) -> (&'a [f32], &'a [f32]) {
        let s = self.rows.map_or(0, |r| r[b]) + self.offset;
        (&self.data[s..s + c], &self.data[s + c..s + 2 * c])
    }
}

/// An activation as a scalar function and its derivative.
trait Act {
    fn f(x: f32) -> f32;
    fn df(x: f32) -> f32;
}

struct SiluAct;
struct MishAct;

impl Act for SiluAct {
    #[inline(always)]
    fn f(x: f32) -> f32 {
        x / (1.0 + exp(-x))
    }
    #[inline(always)]
    fn df(x: f32) -> f32 {
        let s = sigmoid(x);
        s * (1.0 + x * (1.0 - s))
    }
}

impl Act for MishAct {
    #[inline(always)]
    fn f(x: f32) -> f32 {
        x * tanh_softplus(x)
    }
    #[inline(always)]
    fn df(x: f32) -> f32 {
        let t = tanh_softplus(x);
        t + x * (1.0 - t * t) * sigmoid(x)
    }
}

/// `acc += x` lane-wise.
#[inline(always)]
fn add_lanes(acc: &mut [f32; 16], x: &[f32]) {
    let c = x.chunks_exact(16);
    for (i, v) in c.remainder().iter().enumerate() {
        acc[i] += v;
    }
    for ch in c {
        for i in 0..16 {
            acc[i] += ch[i];
        }
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn norm_act_impl<A: Act>(
    y: &[f32],
    n: BlockNorm<'_>,
    batch: usize,
    len: usize,
    film: Option<Film<'_>>,
    xhat: &mut [f32],
    inv_std: &mut [f32],
    out: &mut [f32],
    sums: &mut GroupSums,
) {
    if len == 0 {
        return;
    }
    let per = n.gamma.len() / n.groups;
    let count = (per * len) as f64;
    // Each channel's rows of all the batch are one contiguous plane; a group's statistics are
    // summed plane by plane, every row into lanes of its own, so the rows' reductions are
    // independent of each other (and each row's additions keep their order).
    let plane = |c: usize| c * batch * len..(c + 1) * batch * len;
    for g in 0..n.groups {
        let channels = g * per..(g + 1) * per;
        sums.clear(batch);
        for c in channels.clone() {
            for (a, row) in sums.a1.iter_mut().zip(y[plane(c)].chunks_exact(len)) {
                add_lanes(a, row);
            }
        }
        // The convolution's bias, folded in: the group's mean moves by its channels' mean bias.
        let bias = n.conv_bias[channels.clone()]
            .iter()
            .map(|&b| f64::from(b))
            .sum::<f64>()
            / per as f64;
        for (m, a) in sums.means.iter_mut().zip(&sums.a1) {
            m.0 = lanes(*a) / count + bias;
        }
        for c in channels.clone() {
            let bias = f64::from(n.conv_bias[c]);
            let rows = sums.a2.iter_mut().zip(y[plane(c)].chunks_exact(len));
            for ((a, row), m) in rows.zip(&sums.means) {
                add_sq_dev_lanes(a, row, (m.0 - bias) as f32);
            }
        }
        for (b, a) in sums.a2.iter().enumerate() {
            inv_std[b * n.groups + g] =
                (1.0 / (lanes(*a) / count + f64::from(GN_EPS)).sqrt()) as f32;
        }
        for c in channels {
            let (bias, ga, be) = (f64::from(n.conv_bias[c]), n.gamma[c], n.beta[c]);
            let rows = y[plane(c)]
                .chunks_exact(len)
                .zip(xhat[plane(c)].chunks_exact_mut(len))
                .zip(out[plane(c)].chunks_exact_mut(len));
            for (b, ((y, xhat), out)) in rows.enumerate() {
                let m = (sums.means[b].0 - bias) as f32;
                let inv = inv_std[b * n.groups + g];
                let (sc, sh) = film.map_or((1.0, 0.0), |f| {
                    let (s, h) = f.row(b, n.gamma.len());
                    (s[c], h[c])
                });
                for ((&v, h), o) in y.iter().zip(xhat.iter_mut()).zip(out.iter_mut()) {
                    let xh = (v - m) * inv;
                    *h = xh;
                    *o = sh + A::f(xh * ga + be) * sc;
                }
            }
        }
    }
}

multiversion! {
    /// One pass of a convolution block after its matrix product: `out = act(GN(y + bias))`,
    /// followed by FiLM `shift + out·scale` when `film` is given. Keeps `x̂` and `1/σ` per
    /// `(b, group)` for [`norm_act_backward`] (the pre-activation is `γ·x̂ + β`, recomputed
    /// there). Mean and variance in two passes over the group's rows.
    pub(crate) fn norm_act(
        act: Activation,
        y: &[f32],
        n: BlockNorm<'_>,
        batch: usize,
        len: usize,
        film: Option<Film<'_>>,
        xhat: &mut Vec<f32>,
        inv_std: &mut Vec<f32>,
        out: &mut Vec<f32>,
        sums: &mut GroupSums,
    ) {
        resize_for_overwrite(xhat, y.len());
        resize_for_overwrite(inv_std, batch * n.groups);
        resize_for_overwrite(out, y.len());
        match act {
            Activation::Silu => norm_act_impl::<SiluAct>(y, n, batch, len, film, xhat, inv_std, out, sums),
            Activation::Mish => norm_act_impl::<MishAct>(y, n, batch, len, film, xhat, inv_std, out, sums),
        }
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn norm_act_backward_impl<A: Act>(
    d: &mut [f32],
    n: BlockNorm<'_>,
    batch: usize,
    len: usize,
    film: Option<Film<'_>>,
    xhat: &[f32],
    inv_std: &[f32],
    sums: &mut GroupSums,
) {
    if len == 0 {
        return;
    }
    let per = n.gamma.len() / n.groups;
    let count = (per * len) as f64;
    // Plane by plane, every row into lanes of its own, as in `norm_act_impl`.
    let plane = |c: usize| c * batch * len..(c + 1) * batch * len;
    for g in 0..n.groups {
        let channels = g * per..(g + 1) * per;
        sums.clear(batch);
        let GroupSums { a1, a2, means } = &mut *sums;
        for c in channels.clone() {
            let (ga, be) = (n.gamma[c], n.beta[c]);
            let rows = d[plane(c)]
                .chunks_exact_mut(len)
                .zip(xhat[plane(c)].chunks_exact(len));
            for (b, ((d, xhat), (a1, a2))) in rows.zip(a1.iter_mut().zip(a2.iter_mut())).enumerate()
            {
                let sc = film.map_or(1.0, |f| f.row(b, n.gamma.len()).0[c]);
                for (v, &h) in d.iter_mut().zip(xhat) {
                    *v *= sc * A::df(h * ga + be);
                }
                add_scaled_lanes(a1, d, ga);
                add_dot_lanes(a2, d, xhat, ga);
            }
        }
        for ((m, a1), a2) in means.iter_mut().zip(a1.iter()).zip(a2.iter()) {
            *m = (lanes(*a1) / count, lanes(*a2) / count);
        }
        for c in channels {
            let ga = n.gamma[c];
            let rows = d[plane(c)]
                .chunks_exact_mut(len)
                .zip(xhat[plane(c)].chunks_exact(len));
            for (b, (d, xhat)) in rows.enumerate() {
                let (m1, m2) = (means[b].0 as f32, means[b].1 as f32);
                let inv = inv_std[b * n.groups + g];
                for (v, &h) in d.iter_mut().zip(xhat) {
                    *v = inv * (*v * ga - m1 - h * m2);
                }
            }
        }
    }
}

multiversion! {
    /// The data gradient of [`norm_act`]: `d` holds the gradient of `out` and becomes that of
    /// `y`. With `x̂` and `dx̂ = dz·γ` per group:
    /// `dy = (1/σ)·(dx̂ − mean(dx̂) − x̂·mean(dx̂·x̂))`, where `dz = d·scale·act'(γ·x̂ + β)`.
    pub(crate) fn norm_act_backward(
        act: Activation,
        d: &mut [f32],
        n: BlockNorm<'_>,
        batch: usize,
        len: usize,
        film: Option<Film<'_>>,
        xhat: &[f32],
        inv_std: &[f32],
        sums: &mut GroupSums,
    ) {
        match act {
            Activation::Silu => {
                norm_act_backward_impl::<SiluAct>(d, n, batch, len, film, xhat, inv_std, sums)
            }
            Activation::Mish => {
                norm_act_backward_impl::<MishAct>(d, n, batch, len, film, xhat, inv_std, sums)
            }
        }
    }
}

#[inline(always)]
fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// `tanh(softplus(x))` as a rational function of `eˣ`: with `n = eˣ·(eˣ + 2)`,
/// `tanh(ln(1 + eˣ)) = n / (n + 2)`; 1 beyond `x = 20` (torch's softplus threshold).
#[inline(always)]
fn tanh_softplus(x: f32) -> f32 {
    let e = exp(x.min(20.0));
    let n = e * (e + 2.0);
    if x > 20.0 { 1.0 } else { n / (n + 2.0) }
}

multiversion! {
    /// `act(x)` in place.
    pub(crate) fn activate_in_place(act: Activation, x: &mut [f32]) {
        match act {
            Activation::Silu => x.iter_mut().for_each(|v| *v = SiluAct::f(*v)),
            Activation::Mish => x.iter_mut().for_each(|v| *v *= tanh_softplus(*v)),
        }
    }
}

multiversion! {
    /// `out = act(x)`.
    pub(crate) fn activate_into(act: Activation, x: &[f32], out: &mut Vec<f32>) {
        resize_for_overwrite(out, x.len());
        match act {
            Activation::Silu => out.iter_mut().zip(x).for_each(|(o, &v)| *o = SiluAct::f(v)),
            Activation::Mish => out.iter_mut().zip(x).for_each(|(o, &v)| *o = MishAct::f(v)),
        }
    }
}

multiversion! {
    /// `act(x + b)` in place, one bias per row of `x` (`[bias.len(), x.len() / bias.len()]`):
    /// the values of adding the bias and then [`activate_in_place`], in one pass.
    pub(crate) fn bias_activate_in_place(act: Activation, bias: &[f32], x: &mut [f32]) {
        let m = x.len() / bias.len().max(1);
        if m == 0 {
            return;
        }
        for (row, &b) in x.chunks_exact_mut(m).zip(bias) {
            match act {
                Activation::Silu => row.iter_mut().for_each(|v| *v = SiluAct::f(*v + b)),
                Activation::Mish => row.iter_mut().for_each(|v| *v = MishAct::f(*v + b)),
            }
        }
    }
}

multiversion! {
    /// `x ← act'(x)` in place.
    pub(crate) fn derivative_in_place(act: Activation, x: &mut [f32]) {
        match act {
            Activation::Silu => x.iter_mut().for_each(|v| *v = SiluAct::df(*v)),
            Activation::Mish => x.iter_mut().for_each(|v| *v = MishAct::df(*v)),
        }
    }
}

multiversion! {
    /// `y = W·x + b` for one vector (`W` row-major `[out, in]`).
    pub(crate) fn linear(w: &[f32], b: &[f32], x: &[f32], y: &mut [f32]) {
        let n = x.len();
        for ((o, row), &bias) in y.iter_mut().zip(w.chunks_exact(n)).zip(b) {
            *o = dot(row, x) + bias;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::native::net::gather_rows;

    fn naive(m: usize, n: usize, k: usize, a: impl Fn(usize, usize) -> f32, b: &[f32]) -> Vec<f32> {
        let mut c = vec![0f32; m * n];
        for i in 0..m {
            for j in 0..n {
                c[i * n + j] = (0..k).map(|p| a(i, p) * b[p * n + j]).sum();
            }
        }
        c
    }

    #[test]
    fn sgemm_matches_a_naive_product_with_transposed_views() {
        let (m, n, k) = (5, 7, 3);
        let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.11).cos()).collect();
        let mut c = vec![1.0f32; m * n];
        sgemm(m, n, k, &a, k, 1, &b, n, 1, &mut c, false);
        let want = naive(m, n, k, |i, p| a[i * k + p], &b);
        for (x, y) in c.iter().zip(&want) {
            assert!((x - y).abs() < 1e-5, "{x} {y}");
        }
        // a stored as its transpose [k, m]; accumulate onto the previous result.
        let at: Vec<f32> = (0..k * m).map(|i| a[(i % m) * k + i / m]).collect();
        sgemm(m, n, k, &at, 1, m, &b, n, 1, &mut c, true);
        for (x, y) in c.iter().zip(&want) {
            assert!((x - 2.0 * y).abs() < 1e-5, "{x} {y}");
        }
    }

    /// Index maps for [`gather`] and [`scatter_add`], with the length of a row of the source
    /// (of the target) and of the columns: same-length convolutions of several kernel widths
    /// and paddings with rows of one or several positions (the whole-plane paths), and the
    /// row-by-row ones (lengths that differ, strides).
    fn tap_cases() -> [(Taps, usize, usize); 10] {
        let taps = |k, stride, pad| Taps { k, stride, pad };
        [
            (taps(3, 1, 1), 8, 8),
            (taps(5, 1, 2), 6, 6),
            (taps(3, 1, 0), 5, 5),
            (taps(7, 1, 3), 2, 2),
            (taps(3, 1, 1), 1, 1),
            (taps(3, 1, 4), 3, 3),
            (taps(4, 1, 2), 7, 7),
            (taps(3, 1, 1), 6, 8),
            (taps(3, 2, 1), 8, 4),
            (taps(4, 2, 1), 8, 4),
        ]
    }

    /// Every column of [`gather`] is the source element its definition names, or zero.
    #[test]
    fn gather_puts_every_source_element_where_its_definition_says() {
        for (t, ls, ln) in tap_cases() {
            let (ch, batch) = (2, 3);
            let x: Vec<f32> = (0..ch * batch * ls).map(|i| i as f32 + 1.0).collect();
            let mut col = vec![f32::NAN; 7];
            gather(&x, ch, batch, ls, ln, t, &mut col);
            assert_eq!(col.len(), ch * t.k * batch * ln);
            for c in 0..ch {
                for kk in 0..t.k {
                    for b in 0..batch {
                        for n in 0..ln {
                            let want = t
                                .source(n, kk, ls)
                                .map_or(0.0, |p| x[(c * batch + b) * ls + p]);
                            let got = col[(c * t.k + kk) * batch * ln + b * ln + n];
                            assert_eq!(got, want, "{t:?} c {c} tap {kk} row {b} column {n}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn scatter_add_is_the_adjoint_of_gather() {
        // <gather(x), y> = <x, scatter_add(y)> for every stride and padding used.
        for (taps, ls, ln) in [
            (
                Taps {
                    k: 3,
                    stride: 1,
                    pad: 1,
                },
                8,
                8,
            ),
            (
                Taps {
                    k: 3,
                    stride: 2,
                    pad: 1,
                },
                8,
                4,
            ),
            (
                Taps {
                    k: 4,
                    stride: 2,
                    pad: 1,
                },
                8,
                4,
            ),
            (
                Taps {
                    k: 1,
                    stride: 1,
                    pad: 0,
                },
                5,
                5,
            ),
        ] {
            let (ch, batch) = (2, 3);
            let x: Vec<f32> = (0..ch * batch * ls)
                .map(|i| (i as f32 * 0.7).sin())
                .collect();
            let y: Vec<f32> = (0..ch * taps.k * batch * ln)
                .map(|i| (i as f32 * 0.3).cos())
                .collect();
            let mut col = Vec::new();
            gather(&x, ch, batch, ls, ln, taps, &mut col);
            let lhs: f32 = col.iter().zip(&y).map(|(a, b)| a * b).sum();
            let mut back = vec![0f32; x.len()];
            scatter_add(&mut y.clone(), ch, batch, ls, ln, taps, &mut back);
            let rhs: f32 = x.iter().zip(&back).map(|(a, b)| a * b).sum();
            assert!((lhs - rhs).abs() < 1e-4, "{taps:?}: {lhs} vs {rhs}");
        }
    }

    /// [`scatter_add`] adds every column to the target its definition names, in tap order, to
    /// the bit.
    #[test]
    fn scatter_add_adds_every_column_where_its_definition_says() {
        for (t, ld, ln) in tap_cases() {
            let (ch, batch) = (3, 4);
            let col: Vec<f32> = (0..ch * t.k * batch * ln)
                .map(|i| (i as f32 * 0.61).sin())
                .collect();
            let start: Vec<f32> = (0..ch * batch * ld)
                .map(|i| (i as f32 * 0.2).cos())
                .collect();
            let mut want = start.clone();
            for c in 0..ch {
                for kk in 0..t.k {
                    for b in 0..batch {
                        for n in 0..ln {
                            if let Some(p) = t.source(n, kk, ld) {
                                want[(c * batch + b) * ld + p] +=
                                    col[(c * t.k + kk) * batch * ln + b * ln + n];
                            }
                        }
                    }
                }
            }
            let mut got = start;
            scatter_add(&mut col.clone(), ch, batch, ld, ln, t, &mut got);
            assert_eq!(got, want, "{t:?}, {ld} ← {ln}");
        }
    }

    /// A batch's rows are normalised apart: [`norm_act`] and [`norm_act_backward`] give every
    /// row of a batch what a batch of that row alone gives, to the bit (the batch API's
    /// promise), at the lengths the network runs (whole lanes and a remainder).
    #[test]
    fn norm_act_gives_each_row_of_a_batch_what_it_gives_the_row_alone() {
        let (ch, groups, batch) = (8, 4, 5);
        let gamma: Vec<f32> = (0..ch).map(|c| 0.5 + 0.1 * c as f32).collect();
        let beta: Vec<f32> = (0..ch).map(|c| 0.05 * c as f32 - 0.2).collect();
        let conv_bias: Vec<f32> = (0..ch).map(|c| (c as f32 * 1.3).sin()).collect();
        let n = BlockNorm {
            groups,
            gamma: &gamma,
            beta: &beta,
            conv_bias: &conv_bias,
        };
        let films: Vec<f32> = (0..2 * ch * batch)
            .map(|i| (i as f32 * 0.37).cos())
            .collect();
        let starts: Vec<usize> = (0..batch).map(|b| 2 * ch * b).collect();
        let sums = &mut GroupSums::default();
        for len in [16, 32, 21] {
            let y: Vec<f32> = (0..ch * batch * len)
                .map(|i| (i as f32 * 0.77).sin() * 3.0 + 1.0)
                .collect();
            let dout: Vec<f32> = (0..y.len()).map(|i| (i as f32 * 0.29).cos()).collect();
            // Row `b` of a `[ch, batch, len]` buffer, as a `[ch, 1, len]` one.
            let pick = |v: &[f32], b: usize| -> Vec<f32> {
                let mut row = Vec::new();
                gather_rows(v, batch, len, &[b], &mut row);
                row
            };
            for act in [Activation::Silu, Activation::Mish] {
                let (mut h, mut inv, mut out) = (Vec::new(), Vec::new(), Vec::new());
                let film = Film::per_row(&films, &starts);
                norm_act(
                    act,
                    &y,
                    n,
                    batch,
                    len,
                    Some(film),
                    &mut h,
                    &mut inv,
                    &mut out,
                    sums,
                );
                let mut d = dout.clone();
                norm_act_backward(act, &mut d, n, batch, len, Some(film), &h, &inv, sums);
                for b in 0..batch {
                    let (mut h1, mut inv1, mut out1) = (Vec::new(), Vec::new(), Vec::new());
                    let film1 = Film::per_row(&films, &starts[b..=b]);
                    let y1 = pick(&y, b);
                    norm_act(
                        act,
                        &y1,
                        n,
                        1,
                        len,
                        Some(film1),
                        &mut h1,
                        &mut inv1,
                        &mut out1,
                        sums,
                    );
                    let mut d1 = pick(&dout, b);
                    norm_act_backward(act, &mut d1, n, 1, len, Some(film1), &h1, &inv1, sums);
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&pick(&out, b)), bits(&out1), "{act:?} {len} row {b}");
                    assert_eq!(bits(&pick(&h, b)), bits(&h1), "{act:?} {len} row {b}");
                    assert_eq!(bits(&inv[b * groups..(b + 1) * groups]), bits(&inv1));
                    assert_eq!(bits(&pick(&d, b)), bits(&d1), "{act:?} {len} row {b}");
                }
            }
        }
    }

    /// `Σ w·norm_act(y)` and its gradient through [`norm_act_backward`], against central
    /// differences, for both activations, with and without FiLM.
    #[test]
    fn norm_act_backward_matches_finite_differences() {
        let (ch, groups, batch, len) = (4, 2, 2, 3);
        let gamma = [1.0f32, 0.5, -0.7, 2.0];
        let beta = [0.1f32, -0.2, 0.3, 0.0];
        let conv_bias = [0.3f32, -0.1, 0.0, 0.7];
        let (scale, shift) = ([0.8f32, 1.3, -0.4, 1.0], [0.2f32, 0.0, -0.3, 0.1]);
        // Two FiLM vectors: the first shared by both rows, or one per row.
        let films: Vec<f32> = [scale, shift, shift, scale].concat();
        let rows = [0, 2 * ch];
        let n = BlockNorm {
            groups,
            gamma: &gamma,
            beta: &beta,
            conv_bias: &conv_bias,
        };
        let y: Vec<f32> = (0..ch * batch * len)
            .map(|i| (i as f32 * 0.91).sin() * 2.0)
            .collect();
        let w: Vec<f32> = (0..y.len()).map(|i| (i as f32 * 0.43).cos()).collect();
        let mut sums = GroupSums::default();
        for act in [Activation::Silu, Activation::Mish] {
            let per_row = Film::per_row(&films, &rows);
            for film in [None, Some(Film::shared(&films)), Some(per_row)] {
                let f = |y: &[f32]| -> f64 {
                    let (mut h, mut s, mut o) = (Vec::new(), Vec::new(), Vec::new());
                    norm_act(
                        act,
                        y,
                        n,
                        batch,
                        len,
                        film,
                        &mut h,
                        &mut s,
                        &mut o,
                        &mut GroupSums::default(),
                    );
                    o.iter().zip(&w).map(|(a, b)| f64::from(a * b)).sum()
                };
                let (mut h, mut s, mut o) = (Vec::new(), Vec::new(), Vec::new());
                norm_act(
                    act, &y, n, batch, len, film, &mut h, &mut s, &mut o, &mut sums,
                );
                let mut d = w.clone();
                norm_act_backward(act, &mut d, n, batch, len, film, &h, &s, &mut sums);
                for i in 0..y.len() {
                    let e = 1e-2f32;
                    let (mut p, mut m) = (y.clone(), y.clone());
                    p[i] += e;
                    m[i] -= e;
                    let fd = (f(&p) - f(&m)) / (2.0 * f64::from(e));
                    assert!(
                        (fd - f64::from(d[i])).abs() < 3e-3,
                        "{act:?} film {:?}: {i}: {fd} vs {}",
                        film.map(|f| f.rows.is_some()),
                        d[i]
                    );
                }
            }
        }
    }

    #[test]
    fn fast_exp_and_activations_match_the_library() {
        for i in -2000..=2000 {
            let x = i as f32 * 0.04;
            let (a, b) = (exp(x), x.exp());
            assert!((a - b).abs() <= 4e-7 * b, "exp({x}) = {a}, library {b}");
            let silu = x / (1.0 + (-x).exp());
            assert!(
                (SiluAct::f(x) - silu).abs() <= 1e-6 * (1.0 + silu.abs()),
                "silu {x}"
            );
            let mish = x * (x.exp().ln_1p()).tanh();
            assert!(
                (MishAct::f(x) - mish).abs() <= 1e-6 * (1.0 + mish.abs()),
                "mish {x}"
            );
        }
    }
}
