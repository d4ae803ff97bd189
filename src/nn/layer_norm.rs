//! Layer normalisation over the channels of each pixel: Keras `LayerNormalization(axis=-1)` on NHWC,
//! which in our NCHW layout normalises each pixel across its `channels` values (strided by `hw`).
//!
//! `y = (x − μ) / sqrt(σ² + eps) · γ + β`, μ and σ² (biased) over the channels of one pixel.
//!
//! Speed: the channels of a pixel are `hw` apart, so we never walk a pixel's channels one by one.
//! Pixels are processed in tiles (a whole sample, or [`TILE`] pixels); per-pixel accumulators for
//! the tile live on the stack and every inner loop runs over a contiguous run of one channel row,
//! so it vectorises. A tile stays in L2 across the passes. No heap scratch is needed.

/// Most pixels per tile: the stack accumulators (4 × MAX_TILE f32 in backward) stay in L1.
const MAX_TILE: usize = 1024;
/// Pixels per tile where a sample is too large to be one (over [`MAX_TILE`] pixels or
/// [`WHOLE_SAMPLE_BYTES`]).
const TILE: usize = 256;
/// A sample up to this size is one tile: its channel rows are then one contiguous run, which the
/// hardware prefetcher streams in (the backward reads x back from memory, long after the forward
/// wrote it), and it stays in L2 for the second pass.
const WHOLE_SAMPLE_BYTES: usize = 512 * 1024;
/// Independent partial sums for the per-channel reductions (dγ, dβ), so they vectorise.
const LANES: usize = 16;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerNorm {
    pub channels: usize,
    /// PF-net uses 1e-3 (the Keras default).
    pub eps: f32,
}

impl LayerNorm {
    /// Pixels per tile for samples of `hw` pixels.
    fn tile(&self, hw: usize) -> usize {
        let whole = hw <= MAX_TILE && self.channels * hw * size_of::<f32>() <= WHOLE_SAMPLE_BYTES;
        if whole { hw.max(1) } else { TILE }
    }

    /// x, y: [n][channels][hw]; stats: [n][hw][2] = (mean, 1/sqrt(var+eps)) kept for backward.
    /// gamma, beta: [channels].
    #[allow(clippy::too_many_arguments)]
    pub fn forward(
        &self,
        gamma: &[f32],
        beta: &[f32],
        x: &[f32],
        n: usize,
        hw: usize,
        y: &mut [f32],
        stats: &mut [f32],
    ) {
        let c = self.channels;
        assert!(c > 0, "LayerNorm: no channels");
        assert!(gamma.len() == c && beta.len() == c, "LayerNorm: gamma/beta length");
        assert!(x.len() == n * c * hw && y.len() == x.len(), "LayerNorm: x/y length");
        assert_eq!(stats.len(), n * hw * 2, "LayerNorm: stats length");
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F.
            return unsafe { self.forward_avx512(gamma, beta, x, n, hw, y, stats) };
        }
        self.forward_impl(gamma, beta, x, n, hw, y, stats);
    }

    /// The same loops compiled for AVX-512 (the crate's baseline is SSE2).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    fn forward_avx512(
        &self,
        gamma: &[f32],
        beta: &[f32],
        x: &[f32],
        n: usize,
        hw: usize,
        y: &mut [f32],
        stats: &mut [f32],
    ) {
        self.forward_impl(gamma, beta, x, n, hw, y, stats);
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn forward_impl(
        &self,
        gamma: &[f32],
        beta: &[f32],
        x: &[f32],
        n: usize,
        hw: usize,
        y: &mut [f32],
        stats: &mut [f32],
    ) {
        let c = self.channels;
        let (inv_c, tile) = (1.0 / c as f32, self.tile(hw));
        let mut mean_buf = [0.0f32; MAX_TILE];
        let mut rstd_buf = [0.0f32; MAX_TILE];
        for s in 0..n {
            let xs = &x[s * c * hw..][..c * hw];
            let ys = &mut y[s * c * hw..][..c * hw];
            let ss = &mut stats[s * hw * 2..][..hw * 2];
            for p0 in (0..hw).step_by(tile) {
                let t = tile.min(hw - p0);
                let mean = &mut mean_buf[..t];
                let rstd = &mut rstd_buf[..t];
                // Two passes (mean, then squared deviations): robust when |μ| ≫ σ.
                mean.fill(0.0);
                for ch in 0..c {
                    for (m, &v) in mean.iter_mut().zip(&xs[ch * hw + p0..][..t]) {
                        *m += v;
                    }
                }
                for m in mean.iter_mut() {
                    *m *= inv_c;
                }
                rstd.fill(0.0);
                for ch in 0..c {
                    for ((q, &v), &m) in rstd.iter_mut().zip(&xs[ch * hw + p0..][..t]).zip(mean.iter()) {
                        let d = v - m;
                        *q += d * d;
                    }
                }
                for q in rstd.iter_mut() {
                    *q = 1.0 / (*q * inv_c + self.eps).sqrt();
                }
                for ch in 0..c {
                    let (g, b) = (gamma[ch], beta[ch]);
                    let xr = &xs[ch * hw + p0..][..t];
                    let yr = &mut ys[ch * hw + p0..][..t];
                    for ((o, &v), (&m, &r)) in yr.iter_mut().zip(xr).zip(mean.iter().zip(rstd.iter())) {
                        *o = (v - m) * (r * g) + b;
                    }
                }
                for ((st, &m), &r) in
                    ss[2 * p0..][..2 * t].chunks_exact_mut(2).zip(mean.iter()).zip(rstd.iter())
                {
                    st[0] = m;
                    st[1] = r;
                }
            }
        }
    }

    /// Accumulates into dgamma, dbeta ([channels]); writes dx ([n][channels][hw]), which every
    /// caller would otherwise have to zero first (a 200 KB fill per particle in the map encoder).
    ///
    /// With x̂ = (x − μ)·r and e = dy·γ: dx = r·(e − mean_c(e) − x̂·mean_c(e·x̂)),
    /// dγ = Σ dy·x̂, dβ = Σ dy.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        gamma: &[f32],
        x: &[f32],
        stats: &[f32],
        dy: &[f32],
        n: usize,
        hw: usize,
        dgamma: &mut [f32],
        dbeta: &mut [f32],
        dx: &mut [f32],
    ) {
        self.backward_dispatch::<false>(gamma, gamma, x, stats, dy, n, hw, dgamma, dbeta, dx);
    }

    /// `backward` of LayerNorm followed by ReLU, `dy` being the gradient at the ReLU's output.
    /// The ReLU's mask is recomputed from x and the stats (the forward's exact arithmetic, so
    /// the same bits), so the normalised activations need not be kept: for the map encoder
    /// that is 200 KB per particle neither stored nor read back.
    #[allow(clippy::too_many_arguments)]
    pub fn backward_relu(
        &self,
        gamma: &[f32],
        beta: &[f32],
        x: &[f32],
        stats: &[f32],
        dy: &[f32],
        n: usize,
        hw: usize,
        dgamma: &mut [f32],
        dbeta: &mut [f32],
        dx: &mut [f32],
    ) {
        assert_eq!(beta.len(), self.channels, "LayerNorm: beta length");
        self.backward_dispatch::<true>(gamma, beta, x, stats, dy, n, hw, dgamma, dbeta, dx);
    }

    #[allow(clippy::too_many_arguments)]
    fn backward_dispatch<const RELU: bool>(
        &self,
        gamma: &[f32],
        beta: &[f32],
        x: &[f32],
        stats: &[f32],
        dy: &[f32],
        n: usize,
        hw: usize,
        dgamma: &mut [f32],
        dbeta: &mut [f32],
        dx: &mut [f32],
    ) {
        let c = self.channels;
        assert!(c > 0, "LayerNorm: no channels");
        assert!(gamma.len() == c && dgamma.len() == c && dbeta.len() == c, "LayerNorm: gamma length");
        assert!(x.len() == n * c * hw && dy.len() == x.len() && dx.len() == x.len(), "LayerNorm: x length");
        assert_eq!(stats.len(), n * hw * 2, "LayerNorm: stats length");
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F.
            return unsafe {
                self.backward_avx512::<RELU>(gamma, beta, x, stats, dy, n, hw, dgamma, dbeta, dx)
            };
        }
        self.backward_impl::<RELU>(gamma, beta, x, stats, dy, n, hw, dgamma, dbeta, dx);
    }

    /// `backward_impl` with explicit AVX-512 (masked tails, ReLU mask as a compare): the
    /// auto-vectorised loops ran at ≈ 6 cycles per element. Measured per filter step
    /// (examples/train_profile.rs, K = 30): ReLU + LayerNorm over 64 × 784 per particle, 5.6 ms →
    /// 1.2 ms with the fused mask.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    fn backward_avx512<const RELU: bool>(
        &self,
        gamma: &[f32],
        beta: &[f32],
        x: &[f32],
        stats: &[f32],
        dy: &[f32],
        n: usize,
        hw: usize,
        dgamma: &mut [f32],
        dbeta: &mut [f32],
        dx: &mut [f32],
    ) {
        use std::arch::x86_64::*;
        let c = self.channels;
        let (inv_c, tile) = (1.0 / c as f32, self.tile(hw));
        let mut mean = [0.0f32; MAX_TILE];
        let mut rstd = [0.0f32; MAX_TILE];
        let mut s1 = [0.0f32; MAX_TILE];
        let mut s2 = [0.0f32; MAX_TILE];
        // SAFETY (every intrinsic below): AVX-512F is enabled; loads and stores are masked to
        // `t − v` lanes of rows of length t that lie inside the sample's slices (checked by the
        // slicing) or inside the MAX_TILE-long stack buffers.
        let zero = _mm512_setzero_ps();
        for smp in 0..n {
            let xs = &x[smp * c * hw..][..c * hw];
            let dys = &dy[smp * c * hw..][..c * hw];
            let dxs = &mut dx[smp * c * hw..][..c * hw];
            let ss = &stats[smp * hw * 2..][..hw * 2];
            for p0 in (0..hw).step_by(tile) {
                let t = tile.min(hw - p0);
                for (i, st) in ss[2 * p0..][..2 * t].chunks_exact(2).enumerate() {
                    mean[i] = st[0];
                    rstd[i] = st[1];
                }
                s1[..t].fill(0.0);
                s2[..t].fill(0.0);
                let lanes = |v: usize| -> __mmask16 { ((1u32 << (t - v).min(16)) - 1) as __mmask16 };
                // dy at lane group v of a row; fused with ReLU, zero where the forward's output
                // (x − μ)·(r·γ) + β (its exact operations, no FMA) was not positive.
                let grad = |dr: *const f32, centred: __m512, v: usize, m: __mmask16, g: __m512, b: __m512| unsafe {
                    let d = _mm512_maskz_loadu_ps(m, dr.add(v));
                    if RELU {
                        let scale = _mm512_mul_ps(_mm512_loadu_ps(rstd.as_ptr().add(v)), g);
                        let y = _mm512_add_ps(_mm512_mul_ps(centred, scale), b);
                        _mm512_maskz_mov_ps(_mm512_cmp_ps_mask::<_CMP_GT_OQ>(y, zero), d)
                    } else {
                        d
                    }
                };
                for ch in 0..c {
                    let (xr, dr) = (xs[ch * hw + p0..][..t].as_ptr(), dys[ch * hw + p0..][..t].as_ptr());
                    let (g, b) =
                        (_mm512_set1_ps(gamma[ch]), _mm512_set1_ps(if RELU { beta[ch] } else { 0.0 }));
                    let (mut dg, mut db) = (zero, zero);
                    for v in (0..t).step_by(16) {
                        let m = lanes(v);
                        unsafe {
                            let centred = _mm512_sub_ps(
                                _mm512_maskz_loadu_ps(m, xr.add(v)),
                                _mm512_loadu_ps(mean.as_ptr().add(v)),
                            );
                            let d = grad(dr, centred, v, m, g, b);
                            let xh = _mm512_mul_ps(centred, _mm512_loadu_ps(rstd.as_ptr().add(v)));
                            let e = _mm512_mul_ps(d, g);
                            let a = _mm512_add_ps(_mm512_loadu_ps(s1.as_ptr().add(v)), e);
                            let b = _mm512_fmadd_ps(e, xh, _mm512_loadu_ps(s2.as_ptr().add(v)));
                            _mm512_storeu_ps(s1.as_mut_ptr().add(v), a);
                            _mm512_storeu_ps(s2.as_mut_ptr().add(v), b);
                            dg = _mm512_fmadd_ps(d, xh, dg);
                            db = _mm512_add_ps(d, db);
                        }
                    }
                    dgamma[ch] += _mm512_reduce_add_ps(dg);
                    dbeta[ch] += _mm512_reduce_add_ps(db);
                }
                // Fold per-pixel constants: s1 → mean_c(e), s2 → r·mean_c(e·x̂).
                for i in 0..t {
                    s1[i] *= inv_c;
                    s2[i] *= rstd[i] * inv_c;
                }
                for ch in 0..c {
                    let (xr, dr) = (xs[ch * hw + p0..][..t].as_ptr(), dys[ch * hw + p0..][..t].as_ptr());
                    let out = dxs[ch * hw + p0..][..t].as_mut_ptr();
                    let (g, b) =
                        (_mm512_set1_ps(gamma[ch]), _mm512_set1_ps(if RELU { beta[ch] } else { 0.0 }));
                    for v in (0..t).step_by(16) {
                        let m = lanes(v);
                        unsafe {
                            let centred = _mm512_sub_ps(
                                _mm512_maskz_loadu_ps(m, xr.add(v)),
                                _mm512_loadu_ps(mean.as_ptr().add(v)),
                            );
                            let d = grad(dr, centred, v, m, g, b);
                            // r·(g·d − a − (x − μ)·b)
                            let inner = _mm512_fnmadd_ps(
                                centred,
                                _mm512_loadu_ps(s2.as_ptr().add(v)),
                                _mm512_fmsub_ps(g, d, _mm512_loadu_ps(s1.as_ptr().add(v))),
                            );
                            let o = _mm512_mul_ps(_mm512_loadu_ps(rstd.as_ptr().add(v)), inner);
                            _mm512_mask_storeu_ps(out.add(v), m, o);
                        }
                    }
                }
            }
        }
    }

    /// With `RELU`, dy is masked where the forward's output was not positive; else `beta` is unused.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn backward_impl<const RELU: bool>(
        &self,
        gamma: &[f32],
        beta: &[f32],
        x: &[f32],
        stats: &[f32],
        dy: &[f32],
        n: usize,
        hw: usize,
        dgamma: &mut [f32],
        dbeta: &mut [f32],
        dx: &mut [f32],
    ) {
        let c = self.channels;
        let (inv_c, tile) = (1.0 / c as f32, self.tile(hw));
        let mut mean_buf = [0.0f32; MAX_TILE];
        let mut rstd_buf = [0.0f32; MAX_TILE];
        let mut s1_buf = [0.0f32; MAX_TILE];
        let mut s2_buf = [0.0f32; MAX_TILE];
        for s in 0..n {
            let xs = &x[s * c * hw..][..c * hw];
            let dys = &dy[s * c * hw..][..c * hw];
            let dxs = &mut dx[s * c * hw..][..c * hw];
            let ss = &stats[s * hw * 2..][..hw * 2];
            for p0 in (0..hw).step_by(tile) {
                let t = tile.min(hw - p0);
                let mean = &mut mean_buf[..t];
                let rstd = &mut rstd_buf[..t];
                let s1 = &mut s1_buf[..t];
                let s2 = &mut s2_buf[..t];
                for ((st, m), r) in
                    ss[2 * p0..][..2 * t].chunks_exact(2).zip(mean.iter_mut()).zip(rstd.iter_mut())
                {
                    *m = st[0];
                    *r = st[1];
                }
                s1.fill(0.0);
                s2.fill(0.0);
                for ch in 0..c {
                    let xr = &xs[ch * hw + p0..][..t];
                    let dr = &dys[ch * hw + p0..][..t];
                    let gb = (gamma[ch], if RELU { beta[ch] } else { 0.0 });
                    let (dg, db) = accumulate_row::<RELU>(gb, xr, dr, mean, rstd, s1, s2);
                    dgamma[ch] += dg;
                    dbeta[ch] += db;
                }
                // Fold per-pixel constants: s1 → mean_c(e), s2 → r·mean_c(e·x̂).
                for ((a, b), &r) in s1.iter_mut().zip(s2.iter_mut()).zip(rstd.iter()) {
                    *a *= inv_c;
                    *b *= r * inv_c;
                }
                for ch in 0..c {
                    let (g, bt) = (gamma[ch], if RELU { beta[ch] } else { 0.0 });
                    let xr = &xs[ch * hw + p0..][..t];
                    let dr = &dys[ch * hw + p0..][..t];
                    let out = &mut dxs[ch * hw + p0..][..t];
                    let per_pixel = mean.iter().zip(rstd.iter()).zip(s1.iter().zip(s2.iter()));
                    for (((o, &v), &d), ((&m, &r), (&a, &b))) in out.iter_mut().zip(xr).zip(dr).zip(per_pixel)
                    {
                        let d = masked::<RELU>(d, v, m, r, (g, bt));
                        *o = r * (g * d - a - (v - m) * b);
                    }
                }
            }
        }
    }
}

/// dy, or (`RELU`) dy where the forward's output (x − μ)·(r·γ) + β (the same operations, so the
/// same bits) was positive: a select, so loops stay vectorised.
#[inline(always)]
fn masked<const RELU: bool>(dy: f32, x: f32, mean: f32, rstd: f32, (g, b): (f32, f32)) -> f32 {
    if RELU && (x - mean) * (rstd * g) + b <= 0.0 { 0.0 } else { dy }
}

/// One channel row of a tile: adds e = dy·γ and e·x̂ into the per-pixel sums `s1`, `s2` and returns
/// this row's (Σ dy·x̂, Σ dy) for dγ, dβ. Reductions run in LANES independent partial sums.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn accumulate_row<const RELU: bool>(
    (g, beta): (f32, f32),
    x: &[f32],
    dy: &[f32],
    mean: &[f32],
    rstd: &[f32],
    s1: &mut [f32],
    s2: &mut [f32],
) -> (f32, f32) {
    let mut dg = [0.0f32; LANES];
    let mut db = [0.0f32; LANES];
    let split = x.len() - x.len() % LANES;
    let chunks = x[..split]
        .chunks_exact(LANES)
        .zip(dy[..split].chunks_exact(LANES))
        .zip(mean[..split].chunks_exact(LANES).zip(rstd[..split].chunks_exact(LANES)))
        .zip(s1[..split].chunks_exact_mut(LANES).zip(s2[..split].chunks_exact_mut(LANES)));
    for (((xc, dc), (mc, rc)), (ac, bc)) in chunks {
        for l in 0..LANES {
            let xh = (xc[l] - mc[l]) * rc[l];
            let d = masked::<RELU>(dc[l], xc[l], mc[l], rc[l], (g, beta));
            let e = d * g;
            ac[l] += e;
            bc[l] += e * xh;
            dg[l] += d * xh;
            db[l] += d;
        }
    }
    for i in split..x.len() {
        let xh = (x[i] - mean[i]) * rstd[i];
        let d = masked::<RELU>(dy[i], x[i], mean[i], rstd[i], (g, beta));
        let e = d * g;
        s1[i] += e;
        s2[i] += e * xh;
        dg[0] += d * xh;
        db[0] += d;
    }
    (dg.iter().sum(), db.iter().sum())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad, test_values};

    /// Naive f64 forward: pixel by pixel, channel by channel.
    fn naive(ln: &LayerNorm, gamma: &[f64], beta: &[f64], x: &[f64], n: usize, hw: usize) -> Vec<f64> {
        let c = ln.channels;
        let mut y = vec![0.0; x.len()];
        for s in 0..n {
            for p in 0..hw {
                let at = |ch: usize| (s * c + ch) * hw + p;
                let mean = (0..c).map(|ch| x[at(ch)]).sum::<f64>() / c as f64;
                let var = (0..c).map(|ch| (x[at(ch)] - mean).powi(2)).sum::<f64>() / c as f64;
                for ch in 0..c {
                    y[at(ch)] = (x[at(ch)] - mean) / (var + f64::from(ln.eps)).sqrt() * gamma[ch] + beta[ch];
                }
            }
        }
        y
    }

    fn to64(v: &[f32]) -> Vec<f64> {
        v.iter().map(|&a| f64::from(a)).collect()
    }

    fn dot(a: &[f64], r: &[f32]) -> f64 {
        a.iter().zip(r).map(|(&a, &b)| a * f64::from(b)).sum()
    }

    /// hw = 7 (one partial vector, scalar tail), TILE + 13 (a whole sample as one tile) and
    /// MAX_TILE + 13 (too many pixels for one: tiles of TILE, odd tail).
    #[test]
    fn layer_norm_matches_naive_and_finite_differences() {
        let ln = LayerNorm { channels: 5, eps: 1e-3 };
        let c = ln.channels;
        let n = 2;
        for hw in [7, TILE + 13, MAX_TILE + 13] {
            // An offset on x checks the two-pass statistics; non-trivial γ, β.
            let x: Vec<f32> = test_values(n * c * hw, 1).iter().map(|v| v + 3.0).collect();
            let gamma: Vec<f32> = test_values(c, 2).iter().map(|v| 1.0 + 0.5 * v).collect();
            let beta = test_values(c, 3);
            let r = test_values(n * c * hw, 4);
            let (x64, g64, b64) = (to64(&x), to64(&gamma), to64(&beta));

            let mut y = vec![0.0; x.len()];
            let mut stats = vec![0.0; n * hw * 2];
            ln.forward(&gamma, &beta, &x, n, hw, &mut y, &mut stats);
            assert_close(&y, &naive(&ln, &g64, &b64, &x64, n, hw), 1e-5, "forward");

            let mut dx = vec![0.0; x.len()];
            let mut dgamma = vec![0.0; c];
            let mut dbeta = vec![0.0; c];
            ln.backward(&gamma, &x, &stats, &r, n, hw, &mut dgamma, &mut dbeta, &mut dx);
            let h = 1e-5;
            let want_dx = numerical_grad(&x64, h, |x| dot(&naive(&ln, &g64, &b64, x, n, hw), &r));
            let want_dg = numerical_grad(&g64, h, |g| dot(&naive(&ln, g, &b64, &x64, n, hw), &r));
            let want_db = numerical_grad(&b64, h, |b| dot(&naive(&ln, &g64, b, &x64, n, hw), &r));
            assert_close(&dx, &want_dx, 1e-4, "dx");
            assert_close(&dgamma, &want_dg, 1e-4, "dgamma");
            assert_close(&dbeta, &want_db, 1e-4, "dbeta");

            ln.backward(&gamma, &x, &stats, &r, n, hw, &mut dgamma, &mut dbeta, &mut dx);
            let twice = |v: &[f64]| v.iter().map(|a| 2.0 * a).collect::<Vec<_>>();
            assert_close(&dx, &want_dx, 1e-4, "dx overwritten");
            assert_close(&dgamma, &twice(&want_dg), 1e-4, "dgamma accumulated");
            assert_close(&dbeta, &twice(&want_db), 1e-4, "dbeta accumulated");
        }
    }

    /// backward_relu against finite differences of relu(naive) on a small case, and against
    /// `backward` of the masked gradient over one and several tiles.
    #[test]
    fn layer_norm_relu_matches_finite_differences() {
        let ln = LayerNorm { channels: 6, eps: 1e-3 };
        let c = ln.channels;
        for (n, hw) in [(2, 7), (2, TILE + 21), (2, MAX_TILE + 21)] {
            let x: Vec<f32> = test_values(n * c * hw, 11).iter().map(|v| v - 1.0).collect();
            let gamma: Vec<f32> = test_values(c, 12).iter().map(|v| 1.0 + 0.5 * v).collect();
            let beta = test_values(c, 13);
            let r = test_values(n * c * hw, 14);
            let (x64, g64, b64) = (to64(&x), to64(&gamma), to64(&beta));

            let mut y = vec![0.0; x.len()];
            let mut stats = vec![0.0; n * hw * 2];
            ln.forward(&gamma, &beta, &x, n, hw, &mut y, &mut stats);
            let fd_valid = y.iter().all(|v| v.abs() > 1e-3);
            y.iter_mut().for_each(|v| *v = v.max(0.0));
            let (mut dx, mut dg, mut db) = (vec![0.0; x.len()], vec![0.0; c], vec![0.0; c]);
            ln.backward_relu(&gamma, &beta, &x, &stats, &r, n, hw, &mut dg, &mut db, &mut dx);

            let masked: Vec<f32> = r.iter().zip(&y).map(|(&g, &v)| if v > 0.0 { g } else { 0.0 }).collect();
            let (mut dx2, mut dg2, mut db2) = (vec![0.0; x.len()], vec![0.0; c], vec![0.0; c]);
            ln.backward(&gamma, &x, &stats, &masked, n, hw, &mut dg2, &mut db2, &mut dx2);
            assert_close(&dx, &to64(&dx2), 1e-5, "dx vs masked backward");
            assert_close(&dg, &to64(&dg2), 1e-5, "dgamma vs masked backward");
            assert_close(&db, &to64(&db2), 1e-5, "dbeta vs masked backward");
            // The portable loops (CPUs without AVX-512) agree with the dispatched kernel.
            let (mut dx3, mut dg3, mut db3) = (vec![0.0; x.len()], vec![0.0; c], vec![0.0; c]);
            ln.backward_impl::<true>(&gamma, &beta, &x, &stats, &r, n, hw, &mut dg3, &mut db3, &mut dx3);
            assert_close(&dx3, &to64(&dx), 1e-5, "portable dx");
            assert_close(&dg3, &to64(&dg), 1e-5, "portable dgamma");
            assert_close(&db3, &to64(&db), 1e-5, "portable dbeta");
            if hw > TILE {
                continue;
            }
            // Finite differences need every output away from ReLU's kink (else pick another seed).
            assert!(fd_valid, "an output sits on the kink");
            let relu = |v: Vec<f64>| v.into_iter().map(|a| a.max(0.0)).collect::<Vec<_>>();
            let loss = |g: &[f64], b: &[f64], x: &[f64]| dot(&relu(naive(&ln, g, b, x, n, hw)), &r);
            let h = 1e-5;
            assert_close(&dx, &numerical_grad(&x64, h, |x| loss(&g64, &b64, x)), 1e-4, "dx");
            assert_close(&dg, &numerical_grad(&g64, h, |g| loss(g, &b64, &x64)), 1e-4, "dgamma");
            assert_close(&db, &numerical_grad(&b64, h, |b| loss(&g64, b, &x64)), 1e-4, "dbeta");
        }
    }
}
