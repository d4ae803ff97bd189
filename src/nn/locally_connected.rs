//! 2-D locally-connected layer: a convolution whose weights are NOT shared across output positions
//! (PF-net's joint stage). Stride 1, zero padding of `pad` cells on every side, then 'valid'.
//!
//! Each position `p` is a tiny `filters × patch` matrix, so the cost is skinny GEMMs. gemm is fast
//! with the filters as rows and a few hundred samples as columns, so a chunk of samples is first
//! transposed into `xt[(iy·wp + ix)·c_in + c][sample]` (padded, sample innermost). There the patch
//! rows of kernel row `kh` — `(kw, c)`, Keras order — are `k·c_in` consecutive rows of `xt`, so a
//! position is `k` GEMMs over plain views of `xt`, with no per-position gather: forward
//! `Y_p = Σ_kh W_p[:, kh]·P_kh`; backward `dW_p[:, kh] += dY_p·P_khᵀ` and `dxt[P_kh] += W_p[:, kh]ᵀ·dY_p`.

use crate::nn::gemm::{MatMut, MatRef, matmul};

/// Samples per chunk (GEMM columns): enough for gemm's fast path, while the `k` input rows one
/// output row reads (`k·wp·c_in·CHUNK` floats, ≈ 2 MB for PF-net's 5×5) stay near L2.
const CHUNK: usize = 256;

/// gemm 0.19 takes its dot-product ("horizontal") kernel when both operands are contiguous along
/// the inner dimension and the output has at most this many elements.
const DOT_OUTPUTS: usize = 256;

/// Samples per transpose tile: 16 f32 = one cache line of an `xt` row.
const TILE: usize = 16;

/// One chunk of samples in `xt` (`ld` columns, the first `cs` used) over the first `c_own` input channels.
#[derive(Clone, Copy)]
struct Chunk<'a> {
    c_own: usize,
    xt: &'a [f32],
    ld: usize,
    cs: usize,
}

/// What a forward pass adds the patch products to.
#[derive(Clone, Copy)]
enum Start<'a> {
    /// The bias `[pos][filter]`; x holds every input channel.
    Bias(&'a [f32]),
    /// Sample s starts from `base[group[s]]`; x holds the first `c_own` input channels
    /// (see [`LocallyConnected2d::forward_own_channels`]).
    Shared { base: &'a [f32], group: &'a [u32], c_own: usize },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LocallyConnected2d {
    pub c_in: usize,
    pub filters: usize,
    pub kernel: usize,
    pub pad: usize,
    pub h: usize,
    pub w: usize,
}

/// A `rows × cols` view with unit column stride.
fn view(data: &[f32], rows: usize, cols: usize, row_stride: usize) -> MatRef<'_> {
    MatRef { data, rows, cols, row_stride, col_stride: 1 }
}

fn view_mut(data: &mut [f32], rows: usize, cols: usize, row_stride: usize) -> MatMut<'_> {
    MatMut { data, rows, cols, row_stride, col_stride: 1 }
}

impl LocallyConnected2d {
    /// `(oh, ow)` = padded size − kernel + 1.
    pub fn output_size(&self) -> (usize, usize) {
        let (hp, wp) = (self.h + 2 * self.pad, self.w + 2 * self.pad);
        assert!(hp >= self.kernel && wp >= self.kernel, "kernel larger than the padded input");
        (hp - self.kernel + 1, wp - self.kernel + 1)
    }

    pub fn positions(&self) -> usize {
        let (oh, ow) = self.output_size();
        oh * ow
    }

    /// `k·k·c_in`, ordered `(kh, kw, c)` like Keras.
    pub fn patch_len(&self) -> usize {
        self.kernel * self.kernel * self.c_in
    }

    /// Our layout `[pos][filter][patch]` (see [`weight_from_keras`]).
    pub fn weight_len(&self) -> usize {
        self.positions() * self.filters * self.patch_len()
    }

    /// Layout `[pos][filter]`, the same as Keras.
    pub fn bias_len(&self) -> usize {
        self.positions() * self.filters
    }

    /// x: `[n][c_in][h][w]` → overwrites channels `y_offset..y_offset + filters` of
    /// y: `[n][y_channels][oh][ow]`. No activation.
    #[allow(clippy::too_many_arguments)]
    pub fn forward(
        &self,
        weight: &[f32],
        bias: &[f32],
        x: &[f32],
        n: usize,
        y: &mut [f32],
        y_channels: usize,
        y_offset: usize,
        scratch: &mut Vec<f32>,
    ) {
        assert_eq!(bias.len(), self.bias_len(), "bias length");
        self.forward_chunked(weight, Start::Bias(bias), x, n, y, y_channels, y_offset, scratch, CHUNK);
    }

    /// `forward` for inputs whose channels `c_own..c_in` are shared by groups of samples (PF-net's
    /// observation features, the same for every particle of a robot), so the products only cover
    /// the first `c_own`: `x` holds those, `[n][c_own][h][w]`, and sample s starts from
    /// `base[group[s]]` instead of the bias, where `base` (`[groups][y_channels][oh][ow]`) is
    /// `forward` of each group's shared channels with the own ones zero. y is laid out
    /// `[oh·ow][y_channels][n]`, samples innermost: the products land there with no transpose,
    /// and what follows (PF-net's pool and dense head) vectorizes across samples.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_own_channels(
        &self,
        weight: &[f32],
        x: &[f32],
        c_own: usize,
        base: &[f32],
        group: &[u32],
        y: &mut [f32],
        y_channels: usize,
        y_offset: usize,
        scratch: &mut Vec<f32>,
    ) {
        assert!(c_own <= self.c_in, "own channels past c_in");
        let sample = y_channels * self.positions();
        assert!(group.iter().all(|&g| (g as usize + 1) * sample <= base.len()), "group past base");
        let start = Start::Shared { base, group, c_own };
        self.forward_chunked(weight, start, x, group.len(), y, y_channels, y_offset, scratch, CHUNK);
    }

    /// Accumulates into `dweight` `[pos][filter][patch]`, `dbias` `[pos][filter]` and `dx` (if given).
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        weight: &[f32],
        x: &[f32],
        n: usize,
        dy: &[f32],
        y_channels: usize,
        y_offset: usize,
        dweight: &mut [f32],
        dbias: &mut [f32],
        dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
    ) {
        self.backward_chunked(
            weight,
            x,
            n,
            dy,
            y_channels,
            y_offset,
            dweight,
            Some(dbias),
            dx,
            scratch,
            CHUNK,
        );
    }

    /// `backward` of the products `forward_own_channels` computes: x holds the first `c_own`
    /// input channels, `[n][c_own][h][w]`; accumulates their columns of `dweight` and their `dx`
    /// (if given). The bias and the shared channels are the caller's: their gradients come from
    /// each group's dy summed over its samples, a `backward` over the groups alone. `own` holds
    /// the own channels' weights and their gradient, laid out compactly for the GEMMs.
    #[allow(clippy::too_many_arguments)]
    pub fn backward_own_channels(
        &self,
        weight: &[f32],
        x: &[f32],
        c_own: usize,
        n: usize,
        dy: &[f32],
        y_channels: usize,
        y_offset: usize,
        dweight: &mut [f32],
        dx: Option<&mut [f32]>,
        own: &mut Vec<f32>,
        scratch: &mut Vec<f32>,
    ) {
        assert!(c_own <= self.c_in, "own channels past c_in");
        assert_eq!(dweight.len(), self.weight_len(), "dweight length");
        let layer = Self { c_in: c_own, ..*self };
        let len = layer.weight_len();
        own.clear();
        own.resize(2 * len, 0.0);
        let (own_weight, own_dweight) = own.split_at_mut(len);
        // Rows of W_p are [kh][kw][c_in]: every run of c_in columns gives its first c_own.
        for (part, full) in own_weight.chunks_exact_mut(c_own).zip(weight.chunks_exact(self.c_in)) {
            part.copy_from_slice(&full[..c_own]);
        }
        layer.backward_chunked(
            own_weight,
            x,
            n,
            dy,
            y_channels,
            y_offset,
            own_dweight,
            None,
            dx,
            scratch,
            CHUNK,
        );
        for (full, part) in dweight.chunks_exact_mut(self.c_in).zip(own_dweight.chunks_exact(c_own)) {
            full[..c_own].iter_mut().zip(part).for_each(|(d, g)| *d += g);
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn check_shapes(
        &self,
        weight: &[f32],
        x: &[f32],
        x_channels: usize,
        n: usize,
        y: &[f32],
        y_channels: usize,
        y_offset: usize,
    ) {
        assert_eq!(weight.len(), self.weight_len(), "weight length");
        assert_eq!(x.len(), n * x_channels * self.h * self.w, "x length");
        assert!(y_offset + self.filters <= y_channels, "channel slice past y_channels");
        assert_eq!(y.len(), n * y_channels * self.positions(), "y length");
    }

    /// Length of `xt`: one row of `ld` samples per padded cell and channel.
    fn xt_len(&self, ld: usize) -> usize {
        (self.h + 2 * self.pad) * (self.w + 2 * self.pad) * self.c_in * ld
    }

    /// Offset in `xt` of the `k·c_in` patch rows of kernel row `kh` at position `p`.
    fn block_start(&self, ld: usize, p: usize, kh: usize) -> usize {
        let (_, ow) = self.output_size();
        ((p / ow + kh) * (self.w + 2 * self.pad) + p % ow) * self.c_in * ld
    }

    /// Columns `kh·k·c_in ..` of `W_p`: `filters × k·c_in`, row stride `patch_len`.
    fn weight_block<'a>(&self, weight: &'a [f32], p: usize, kh: usize) -> MatRef<'a> {
        let (f, pl, kc) = (self.filters, self.patch_len(), self.kernel * self.c_in);
        view(&weight[p * f * pl + kh * kc..][..(f - 1) * pl + kc], f, kc, pl)
    }

    /// W_p's columns for the first `c_own` input channels, `filters × k·k·c_own` in (kh, kw, c)
    /// order, and its row stride: `weight` itself when that is every channel, else a copy in `buf`.
    fn own_weights<'a>(
        &self,
        weight: &'a [f32],
        p: usize,
        c_own: usize,
        buf: &'a mut [f32],
    ) -> (&'a [f32], usize) {
        let (f, pl) = (self.filters, self.patch_len());
        let w_p = &weight[p * f * pl..][..f * pl];
        if c_own == self.c_in {
            return (w_p, pl);
        }
        // Rows of W_p are [kh][kw][c_in]: every run of c_in columns keeps its first c_own.
        for (dst, src) in buf.chunks_exact_mut(c_own).zip(w_p.chunks_exact(self.c_in)) {
            dst.copy_from_slice(&src[..c_own]);
        }
        (buf, self.kernel * self.kernel * c_own)
    }

    /// Calls `f(xt row, NCHW offset within a sample)` for every interior cell and channel, in `xt`
    /// row order so that `xt` is swept sequentially.
    #[inline(always)]
    fn for_each_cell(&self, mut f: impl FnMut(usize, usize)) {
        let (c_in, h, w, pad) = (self.c_in, self.h, self.w, self.pad);
        for iy in 0..h {
            for ix in 0..w {
                let row0 = ((iy + pad) * (w + 2 * pad) + ix + pad) * c_in;
                for c in 0..c_in {
                    f(row0 + c, (c * h + iy) * w + ix);
                }
            }
        }
    }

    /// `x` samples `s0..s0 + cs` → interior rows of `xt`. Tiles of `TILE` samples write one cache line
    /// per `xt` row and read `TILE` sequential streams of `x`; a sample-at-a-time transpose instead
    /// misses cache and TLB on every write (measured 30× slower).
    fn load_xt(&self, x: &[f32], s0: usize, cs: usize, xt: &mut [f32], ld: usize) {
        let chw = self.c_in * self.h * self.w;
        for j0 in (0..cs).step_by(TILE) {
            let jt = TILE.min(cs - j0);
            let src = &x[(s0 + j0) * chw..][..jt * chw];
            self.for_each_cell(|row, e| {
                for (jj, d) in xt[row * ld + j0..][..jt].iter_mut().enumerate() {
                    *d = src[jj * chw + e];
                }
            });
        }
    }

    /// `dx` samples `s0..s0 + cs` += interior rows of `dxt`, clearing them for the next chunk (no
    /// separate zeroing pass). The padding rows are never read, so their sums are left to pile up.
    fn drain_dxt(&self, dxt: &mut [f32], ld: usize, s0: usize, cs: usize, dx: &mut [f32]) {
        let chw = self.c_in * self.h * self.w;
        for j0 in (0..cs).step_by(TILE) {
            let jt = TILE.min(cs - j0);
            let dst = &mut dx[(s0 + j0) * chw..][..jt * chw];
            self.for_each_cell(|row, e| {
                for (jj, g) in dxt[row * ld + j0..][..jt].iter_mut().enumerate() {
                    dst[jj * chw + e] += *g;
                    *g = 0.0;
                }
            });
        }
    }

    /// Zeroes the `xt` rows that lie in the padding.
    fn zero_padding_rows(&self, xt: &mut [f32], ld: usize) {
        let (hp, wp, pad, row) = (self.h + 2 * self.pad, self.w + 2 * self.pad, self.pad, self.c_in * ld);
        for iy in 0..hp {
            for ix in 0..wp {
                if iy < pad || iy >= hp - pad || ix < pad || ix >= wp - pad {
                    xt[(iy * wp + ix) * row..][..row].fill(0.0);
                }
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn forward_chunked(
        &self,
        weight: &[f32],
        start: Start<'_>,
        x: &[f32],
        n: usize,
        y: &mut [f32],
        y_channels: usize,
        y_offset: usize,
        scratch: &mut Vec<f32>,
        chunk: usize,
    ) {
        let c_own = match start {
            Start::Bias(_) => self.c_in,
            Start::Shared { c_own, .. } => c_own,
        };
        // Both layouts of y hold n × y_channels × positions values.
        self.check_shapes(weight, x, c_own, n, y, y_channels, y_offset);
        if n == 0 {
            return;
        }
        // `own` lays out xt and its patch rows for the channels x holds.
        let own = Self { c_in: c_own, ..*self };
        let (npos, f, k, kc) = (self.positions(), self.filters, self.kernel, self.kernel * c_own);
        let ld = chunk.min(n);
        let xt_len = own.xt_len(ld);
        let yt_len = if matches!(start, Start::Bias(_)) { npos * f * ld } else { 0 };
        let own_weights_len = if c_own < self.c_in { f * k * kc } else { 0 };
        scratch.resize(xt_len + yt_len + own_weights_len, 0.0);
        let (xt, rest) = scratch.split_at_mut(xt_len);
        let (yt, weight_buf) = rest.split_at_mut(yt_len);
        own.zero_padding_rows(xt, ld);
        for s0 in (0..n).step_by(ld) {
            let cs = ld.min(n - s0);
            own.load_xt(x, s0, cs, xt, ld);
            let chunk = Chunk { c_own, xt, ld, cs };
            match start {
                Start::Bias(bias) => {
                    // yt[(p·f + filter)·ld + j], then into NCHW with the bias.
                    self.products(weight, &chunk, weight_buf, yt, |p| (p * f * ld, ld), false);
                    let ys = &mut y[(s0 * y_channels + y_offset) * npos..];
                    self.scatter(yt, ld, cs, ys, y_channels, bias);
                }
                Start::Shared { base, group, .. } => {
                    // y [pos][y_channels][n]: each row starts from its samples' bases and the
                    // products accumulate onto it in place.
                    let sample = y_channels * npos;
                    for p in 0..npos {
                        for fi in 0..f {
                            let mut row = &mut y[(p * y_channels + y_offset + fi) * n + s0..][..cs];
                            let from = (y_offset + fi) * npos + p;
                            // Samples of one group come in runs (a robot's particles).
                            for run in group[s0..s0 + cs].chunk_by(|a, b| a == b) {
                                let (head, tail) = std::mem::take(&mut row).split_at_mut(run.len());
                                head.fill(base[run[0] as usize * sample + from]);
                                row = tail;
                            }
                        }
                    }
                    let block = |p: usize| ((p * y_channels + y_offset) * n + s0, n);
                    self.products(weight, &chunk, weight_buf, y, block, true);
                }
            }
        }
    }

    /// `Σ_kh W_p[:, kh]·P_kh` of one chunk for every position p, into the `filters × cs` block of
    /// `out` at `block(p)` = (offset, row stride); `accumulate` adds to what is there.
    fn products(
        &self,
        weight: &[f32],
        chunk: &Chunk<'_>,
        weight_buf: &mut [f32],
        out: &mut [f32],
        block: impl Fn(usize) -> (usize, usize),
        accumulate: bool,
    ) {
        let Chunk { c_own, xt, ld, cs } = *chunk;
        let own = Self { c_in: c_own, ..*self };
        let (f, k, kc) = (self.filters, self.kernel, self.kernel * c_own);
        for p in 0..self.positions() {
            let (w_p, stride) = self.own_weights(weight, p, c_own, weight_buf);
            let (at, row_stride) = block(p);
            for kh in 0..k {
                let patch = view(&xt[own.block_start(ld, p, kh)..][..kc * ld], kc, cs, ld);
                let c = view_mut(&mut out[at..][..(f - 1) * row_stride + cs], f, cs, row_stride);
                let w = view(&w_p[kh * kc..][..(f - 1) * stride + kc], f, kc, stride);
                matmul(c, w, patch, accumulate || kh > 0);
            }
        }
    }

    /// yt `[(p·f + filter)·ld + j]` + bias → NCHW `ys` (from the chunk's first sample and the
    /// layer's channel slice), a tile of samples at a time like `load_xt`.
    fn scatter(&self, yt: &[f32], ld: usize, cs: usize, ys: &mut [f32], y_channels: usize, bias: &[f32]) {
        let npos = self.positions();
        for j0 in (0..cs).step_by(TILE) {
            for (r, &b) in bias.iter().enumerate() {
                let off = (j0 * y_channels + r % self.filters) * npos + r / self.filters;
                for (jj, &v) in yt[r * ld + j0..][..TILE.min(cs - j0)].iter().enumerate() {
                    ys[off + jj * y_channels * npos] = v + b;
                }
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn backward_chunked(
        &self,
        weight: &[f32],
        x: &[f32],
        n: usize,
        dy: &[f32],
        y_channels: usize,
        y_offset: usize,
        dweight: &mut [f32],
        mut dbias: Option<&mut [f32]>,
        mut dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
        chunk: usize,
    ) {
        self.check_shapes(weight, x, self.c_in, n, dy, y_channels, y_offset);
        assert_eq!(dweight.len(), self.weight_len(), "dweight length");
        if let Some(dbias) = dbias.as_deref() {
            assert_eq!(dbias.len(), self.bias_len(), "dbias length");
        }
        if let Some(dx) = dx.as_deref() {
            assert_eq!(dx.len(), x.len(), "dx length");
        }
        if n == 0 {
            return;
        }
        let (npos, f, k, kc, pl) =
            (self.positions(), self.filters, self.kernel, self.kernel * self.c_in, self.patch_len());
        // dW_p[:, kh] += dY_p·P_khᵀ in slabs of ≤ DOT_OUTPUTS outputs: both operands run along the
        // samples, so gemm takes its dot-product kernel (measured 3× faster than its packed path).
        let slab = if f <= DOT_OUTPUTS { DOT_OUTPUTS / f } else { kc };
        let ld = chunk.min(n);
        let xt_len = self.xt_len(ld);
        let dxt_len = if dx.is_some() { xt_len } else { 0 };
        scratch.resize(xt_len + dxt_len + npos * f * ld, 0.0);
        let (xt, rest) = scratch.split_at_mut(xt_len);
        let (dxt, dyt) = rest.split_at_mut(dxt_len);
        self.zero_padding_rows(xt, ld);
        dxt.fill(0.0); // then kept zero between chunks by `drain_dxt`
        for s0 in (0..n).step_by(ld) {
            let cs = ld.min(n - s0);
            self.load_xt(x, s0, cs, xt, ld);
            // dyt[(p·f + filter)·ld + j]: the transpose of the scatter in `forward`.
            let dys = &dy[(s0 * y_channels + y_offset) * npos..];
            for j0 in (0..cs).step_by(TILE) {
                for r in 0..npos * f {
                    let off = (j0 * y_channels + r % f) * npos + r / f;
                    for (jj, d) in dyt[r * ld + j0..][..TILE.min(cs - j0)].iter_mut().enumerate() {
                        *d = dys[off + jj * y_channels * npos];
                    }
                }
            }
            for p in 0..npos {
                let dyp = view(&dyt[p * f * ld..][..f * ld], f, cs, ld);
                if let Some(dbias) = dbias.as_deref_mut() {
                    for (fi, db) in dbias[p * f..][..f].iter_mut().enumerate() {
                        *db += dyt[(p * f + fi) * ld..][..cs].iter().sum::<f32>();
                    }
                }
                for kh in 0..k {
                    let start = self.block_start(ld, p, kh);
                    for d0 in (0..kc).step_by(slab) {
                        let dn = slab.min(kc - d0);
                        let dw = &mut dweight[p * f * pl + kh * kc + d0..][..(f - 1) * pl + dn];
                        let rows = view(&xt[start + d0 * ld..][..dn * ld], dn, cs, ld);
                        matmul(view_mut(dw, f, dn, pl), dyp, rows.t(), true);
                    }
                    if dx.is_some() {
                        let dxb = view_mut(&mut dxt[start..][..kc * ld], kc, cs, ld);
                        matmul(dxb, self.weight_block(weight, p, kh).t(), dyp, true);
                    }
                }
            }
            if let Some(dx) = dx.as_deref_mut() {
                self.drain_dxt(dxt, ld, s0, cs, dx);
            }
        }
    }
}

/// Keras kernel `[pos][patch][filters]` → ours `[pos][filter][patch]`.
pub fn weight_from_keras(kernel: &[f32], positions: usize, patch_len: usize, filters: usize) -> Vec<f32> {
    assert_eq!(kernel.len(), positions * patch_len * filters, "kernel length");
    let mut out = vec![0.0; kernel.len()];
    for p in 0..positions {
        for d in 0..patch_len {
            for f in 0..filters {
                out[(p * filters + f) * patch_len + d] = kernel[(p * patch_len + d) * filters + f];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad, test_values};

    const SENTINEL: f32 = 7.0;

    fn to64(v: &[f32]) -> Vec<f64> {
        v.iter().map(|&a| f64::from(a)).collect()
    }

    /// x at (sample, channel, padded row, padded col), zero in the padding.
    fn tap(l: &LocallyConnected2d, x: &[f64], s: usize, c: usize, py: usize, px: usize) -> f64 {
        let (iy, ix) = (py as isize - l.pad as isize, px as isize - l.pad as isize);
        if iy < 0 || ix < 0 || iy >= l.h as isize || ix >= l.w as isize {
            return 0.0;
        }
        x[((s * l.c_in + c) * l.h + iy as usize) * l.w + ix as usize]
    }

    /// Whole y `[n][yc][oh][ow]`: the layer's slice computed naively, other channels SENTINEL.
    fn naive(
        l: &LocallyConnected2d,
        w: &[f64],
        b: &[f64],
        x: &[f64],
        n: usize,
        yc: usize,
        yo: usize,
    ) -> Vec<f64> {
        let (oh, ow) = l.output_size();
        let (npos, pl, k) = (oh * ow, l.patch_len(), l.kernel);
        let mut y = vec![f64::from(SENTINEL); n * yc * npos];
        for s in 0..n {
            for f in 0..l.filters {
                for p in 0..npos {
                    let (oy, ox) = (p / ow, p % ow);
                    let mut acc = b[p * l.filters + f];
                    for kh in 0..k {
                        for kw in 0..k {
                            for c in 0..l.c_in {
                                let d = (kh * k + kw) * l.c_in + c;
                                acc += w[(p * l.filters + f) * pl + d] * tap(l, x, s, c, oy + kh, ox + kw);
                            }
                        }
                    }
                    y[(s * yc + yo + f) * npos + p] = acc;
                }
            }
        }
        y
    }

    /// Forward vs naive and backward vs finite differences, with a scratch full of stale NaNs.
    fn check(l: LocallyConnected2d, n: usize, yc: usize, yo: usize, chunk: usize) {
        let (npos, wl, bl) = (l.positions(), l.weight_len(), l.bias_len());
        let (w, b, x) = (test_values(wl, 1), test_values(bl, 2), test_values(n * l.c_in * l.h * l.w, 3));
        let r = test_values(n * yc * npos, 4);
        let mut scratch = vec![f32::NAN; 10_000];
        let mut y = vec![SENTINEL; n * yc * npos];
        l.forward_chunked(&w, Start::Bias(&b), &x, n, &mut y, yc, yo, &mut scratch, chunk);
        let (w64, b64, x64, r64) = (to64(&w), to64(&b), to64(&x), to64(&r));
        assert_close(&y, &naive(&l, &w64, &b64, &x64, n, yc, yo), 1e-5, "lc forward");

        let (mut dw, mut db, mut dx) = (vec![0.0; wl], vec![0.0; bl], vec![0.0; x.len()]);
        scratch.fill(f32::NAN);
        l.backward_chunked(&w, &x, n, &r, yc, yo, &mut dw, Some(&mut db), Some(&mut dx), &mut scratch, chunk);
        let loss = |w: &[f64], b: &[f64], x: &[f64]| -> f64 {
            naive(&l, w, b, x, n, yc, yo).iter().zip(&r64).map(|(y, r)| y * r).sum()
        };
        assert_close(&dw, &numerical_grad(&w64, 1e-2, |w| loss(w, &b64, &x64)), 1e-4, "lc dweight");
        assert_close(&db, &numerical_grad(&b64, 1e-2, |b| loss(&w64, b, &x64)), 1e-4, "lc dbias");
        assert_close(&dx, &numerical_grad(&x64, 1e-2, |x| loss(&w64, &b64, x)), 1e-4, "lc dx");
    }

    #[test]
    fn pad0_into_channel_slice() {
        check(LocallyConnected2d { c_in: 3, filters: 2, kernel: 3, pad: 0, h: 5, w: 6 }, 3, 5, 2, CHUNK);
    }

    #[test]
    fn pad1_into_channel_slice() {
        check(LocallyConnected2d { c_in: 3, filters: 2, kernel: 3, pad: 1, h: 5, w: 6 }, 3, 5, 2, CHUNK);
    }

    #[test]
    fn samples_spanning_several_chunks() {
        // n = 5 with chunk 2: two full chunks and a partial one reusing the same scratch.
        check(LocallyConnected2d { c_in: 3, filters: 2, kernel: 3, pad: 0, h: 5, w: 6 }, 5, 3, 1, 2);
        check(LocallyConnected2d { c_in: 3, filters: 2, kernel: 3, pad: 1, h: 5, w: 6 }, 5, 3, 0, 2);
        check(LocallyConnected2d { c_in: 2, filters: 3, kernel: 5, pad: 1, h: 5, w: 6 }, 5, 4, 1, 2);
    }

    #[test]
    fn many_filters_split_the_weight_gradient_into_slabs() {
        // 20 filters → slabs of 12 patch rows; k·c_in = 15 splits into 12 + 3.
        check(LocallyConnected2d { c_in: 5, filters: 20, kernel: 3, pad: 0, h: 3, w: 4 }, 3, 21, 1, 2);
    }

    /// `forward_own_channels` against the naive layer on the full input (own ⊕ the group's shared
    /// channels), with chunks of 2 so that groups change inside and across chunks.
    fn check_own_channels(l: LocallyConnected2d, c_own: usize, group: &[u32], yc: usize, yo: usize) {
        let (n, groups, hw) = (group.len(), 1 + *group.iter().max().unwrap() as usize, l.h * l.w);
        let c_shared = l.c_in - c_own;
        let (w, b) = (test_values(l.weight_len(), 11), test_values(l.bias_len(), 12));
        let (own, shared) = (test_values(n * c_own * hw, 13), test_values(groups * c_shared * hw, 14));
        let mut full = Vec::new();
        for (s, &g) in group.iter().enumerate() {
            full.extend_from_slice(&own[s * c_own * hw..][..c_own * hw]);
            full.extend_from_slice(&shared[g as usize * c_shared * hw..][..c_shared * hw]);
        }
        let mut zero_own = Vec::new();
        for g in 0..groups {
            zero_own.extend(std::iter::repeat_n(0.0, c_own * hw));
            zero_own.extend_from_slice(&shared[g * c_shared * hw..][..c_shared * hw]);
        }
        let mut scratch = vec![f32::NAN; 10_000];
        let mut base = vec![SENTINEL; groups * yc * l.positions()];
        l.forward(&w, &b, &zero_own, groups, &mut base, yc, yo, &mut scratch);
        let mut y = vec![SENTINEL; n * yc * l.positions()];
        let start = Start::Shared { base: &base, group, c_own };
        l.forward_chunked(&w, start, &own, n, &mut y, yc, yo, &mut scratch, 2);
        let nchw = naive(&l, &to64(&w), &to64(&b), &to64(&full), n, yc, yo);
        let npos = l.positions();
        let mut want = vec![0.0; nchw.len()];
        for (i, v) in nchw.iter().enumerate() {
            let (s, c, p) = (i / (yc * npos), i / npos % yc, i % npos);
            want[(p * yc + c) * n + s] = *v;
        }
        assert_close(&y, &want, 1e-5, "lc forward, own channels, samples innermost");
    }

    #[test]
    fn shared_channels_enter_through_the_base() {
        let l3 = LocallyConnected2d { c_in: 5, filters: 3, kernel: 3, pad: 0, h: 5, w: 6 };
        check_own_channels(l3, 2, &[0, 0, 1, 0, 2], 7, 3);
        let l5 = LocallyConnected2d { c_in: 4, filters: 2, kernel: 5, pad: 1, h: 5, w: 6 };
        check_own_channels(l5, 1, &[1, 1, 0], 2, 0);
        // Every channel own: the base is the bias, whatever the group.
        check_own_channels(l5, 4, &[0, 1], 2, 0);
    }

    /// `backward_own_channels` against `backward` on the full input: the own channels' columns of
    /// dW and their dx agree, the shared channels' columns stay as they were.
    #[test]
    fn own_channels_backward_matches_the_full_backward() {
        let l = LocallyConnected2d { c_in: 5, filters: 3, kernel: 3, pad: 1, h: 5, w: 6 };
        let (n, c_own, hw) = (4, 2, l.h * l.w);
        let w = test_values(l.weight_len(), 21);
        let full = test_values(n * l.c_in * hw, 22);
        let dy = test_values(n * 7 * l.positions(), 23);
        let own: Vec<f32> = full.chunks_exact(l.c_in * hw).flat_map(|s| s[..c_own * hw].to_vec()).collect();
        let mut scratch = vec![f32::NAN; 10_000];
        let (mut dw, mut db, mut dx) =
            (vec![0.0; l.weight_len()], vec![0.0; l.bias_len()], vec![0.0; full.len()]);
        l.backward(&w, &full, n, &dy, 7, 3, &mut dw, &mut db, Some(&mut dx), &mut scratch);
        let (mut dw_own, mut dx_own, mut bufs) =
            (vec![SENTINEL; l.weight_len()], vec![0.0; own.len()], Vec::new());
        l.backward_own_channels(
            &w,
            &own,
            c_own,
            n,
            &dy,
            7,
            3,
            &mut dw_own,
            Some(&mut dx_own),
            &mut bufs,
            &mut scratch,
        );
        for (i, (&got, &want)) in dw_own.iter().zip(&dw).enumerate() {
            let want = if i % l.c_in < c_own { SENTINEL + want } else { SENTINEL };
            assert!((got - want).abs() <= 1e-5, "dweight[{i}]: {got} against {want}");
        }
        let dx_full_own: Vec<f32> =
            dx.chunks_exact(l.c_in * hw).flat_map(|s| s[..c_own * hw].to_vec()).collect();
        assert_close(&dx_own, &to64(&dx_full_own), 1e-5, "lc dx, own channels");
    }

    #[test]
    fn backward_accumulates() {
        let l = LocallyConnected2d { c_in: 3, filters: 2, kernel: 3, pad: 1, h: 5, w: 6 };
        let n = 3;
        let (w, x) = (test_values(l.weight_len(), 5), test_values(n * l.c_in * l.h * l.w, 6));
        let dy = test_values(n * 2 * l.positions(), 7);
        let mut scratch = Vec::new();
        let (mut dw, mut db, mut dx) =
            (vec![0.0; l.weight_len()], vec![0.0; l.bias_len()], vec![0.0; x.len()]);
        l.backward(&w, &x, n, &dy, 2, 0, &mut dw, &mut db, Some(&mut dx), &mut scratch);
        let (dw1, db1, dx1) = (dw.clone(), db.clone(), dx.clone());
        l.backward(&w, &x, n, &dy, 2, 0, &mut dw, &mut db, Some(&mut dx), &mut scratch);
        for (got, once) in [(&dw, &dw1), (&db, &db1), (&dx, &dx1)] {
            assert!(got.iter().zip(once).all(|(g, o)| (g - 2.0 * o).abs() <= 1e-5 * (1.0 + o.abs())));
        }
        // Without dx the parameter gradients still accumulate.
        l.backward(&w, &x, n, &dy, 2, 0, &mut dw, &mut db, None, &mut scratch);
        assert!(dw.iter().zip(&dw1).all(|(g, o)| (g - 3.0 * o).abs() <= 1e-5 * (1.0 + o.abs())));
        assert!(db.iter().zip(&db1).all(|(g, o)| (g - 3.0 * o).abs() <= 1e-5 * (1.0 + o.abs())));
    }

    #[test]
    fn weight_from_keras_by_hand() {
        // One position, patch 2, 3 filters: K[d][f] = 3d + f → ours[f][d].
        let k: Vec<f32> = (0..6).map(|i| i as f32).collect();
        assert_eq!(weight_from_keras(&k, 1, 2, 3), vec![0.0, 3.0, 1.0, 4.0, 2.0, 5.0]);
    }

    #[test]
    fn weight_from_keras_matches_keras_einsum() {
        // y[s,p,f] = Σ_d patch[s,p,d]·K[p,d,f] + b[p,f], patches in (kh, kw, c) order.
        let l = LocallyConnected2d { c_in: 2, filters: 3, kernel: 2, pad: 1, h: 2, w: 3 };
        let (n, (oh, ow)) = (2, l.output_size());
        let (npos, pl, f) = (l.positions(), l.patch_len(), l.filters);
        let (kern, b, x) = (test_values(npos * pl * f, 8), test_values(npos * f, 9), test_values(n * 12, 10));
        let x64 = to64(&x);
        let mut want = vec![0.0; n * f * npos];
        for s in 0..n {
            for p in 0..npos {
                let patch: Vec<f64> = (0..pl)
                    .map(|d| {
                        let (kh, kw, c) = (d / (2 * l.c_in), d / l.c_in % 2, d % l.c_in);
                        tap(&l, &x64, s, c, p / ow + kh, p % ow + kw)
                    })
                    .collect();
                for fi in 0..f {
                    let dot: f64 = (0..pl).map(|d| patch[d] * f64::from(kern[(p * pl + d) * f + fi])).sum();
                    want[(s * f + fi) * npos + p] = dot + f64::from(b[p * f + fi]);
                }
            }
        }
        assert_eq!(npos, oh * ow);
        let mut y = vec![0.0; want.len()];
        l.forward(&weight_from_keras(&kern, npos, pl, f), &b, &x, n, &mut y, f, 0, &mut Vec::new());
        assert_close(&y, &want, 1e-5, "keras einsum");
    }
}
