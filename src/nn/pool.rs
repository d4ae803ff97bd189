//! 2-D max pooling over a square window, TensorFlow semantics: `Same` pads with −∞ (padded taps never
//! win), ties go to the first maximum in window order (row-major over kh, kw). The winner of each window
//! is kept as a u8 index `kh * kernel + kw` so backward needs neither x nor y.

use crate::nn::conv::Padding;

/// Planes the AVX-512 kernel pools side by side (independent dependency chains).
const PLANES: usize = 4;

/// Input columns per pass of the forward's running-maximum buffers (on the stack).
const COLS: usize = 256;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaxPool2d {
    pub kernel: usize,
    pub stride: usize,
    pub padding: Padding,
}

/// One output row or column: first input index (may be negative with `Same`) and the range of taps
/// that fall inside the input.
#[derive(Clone, Copy)]
struct Span {
    start: isize,
    k0: usize,
    k1: usize,
}

impl MaxPool2d {
    /// (oh, ow) for an h × w input.
    pub fn output_size(&self, h: usize, w: usize) -> (usize, usize) {
        (self.axis(h).0, self.axis(w).0)
    }

    fn axis(&self, size: usize) -> (usize, usize) {
        self.padding.output_and_pad_before(size, self.kernel, self.stride, 1)
    }

    fn span(&self, o: usize, pad: usize, size: usize) -> Span {
        let start = (o * self.stride) as isize - pad as isize;
        let k0 = (-start).max(0) as usize;
        let k1 = (size as isize - start).clamp(0, self.kernel as isize) as usize;
        debug_assert!(k0 < k1, "window entirely in padding");
        Span { start, k0, k1 }
    }

    fn check(
        &self,
        planes: usize,
        h: usize,
        w: usize,
        x_len: usize,
        y_len: usize,
        arg_len: usize,
    ) -> [usize; 4] {
        assert!(self.kernel > 0 && self.stride > 0, "MaxPool2d: zero kernel or stride");
        assert!(self.kernel * self.kernel <= 256, "MaxPool2d: window index must fit in u8");
        let (oh, ph) = self.axis(h);
        let (ow, pw) = self.axis(w);
        assert_eq!(x_len, planes * h * w, "MaxPool2d: x length");
        assert!(y_len == planes * oh * ow && arg_len == y_len, "MaxPool2d: y/argmax length");
        [oh, ph, ow, pw]
    }

    /// x: [planes][h][w] (planes = n·c) → y [planes][oh][ow], argmax [planes][oh][ow].
    /// Padded taps never win (TF pads with −∞); a NaN in a window wins, so divergence stays visible.
    pub fn forward(&self, x: &[f32], planes: usize, h: usize, w: usize, y: &mut [f32], argmax: &mut [u8]) {
        let dims = self.check(planes, h, w, x.len(), y.len(), argmax.len());
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has the features both kernels are compiled for.
            unsafe {
                if self.stride <= 2 && self.kernel <= 16 {
                    return self.forward_lanes(x, planes, h, w, y, argmax, dims);
                }
                return self.forward_avx512(x, planes, h, w, y, argmax, dims);
            }
        }
        self.forward_impl(x, planes, h, w, y, argmax, dims);
    }

    /// Strides 1 and 2 with AVX-512 intrinsics, 16 outputs of a row per vector: tap (kh, kw) of
    /// outputs j0..j0+16 lies within 32 consecutive input columns, so two masked loads and one
    /// permute gather it. Same rules as `forward_impl`. Measured on PF-net's 64 × 28 × 28 → 14 × 14
    /// (examples/profile.rs): ≈ 110 µs per particle for the auto-vectorised `forward_impl`, which
    /// spends its time in short loop tails, → ≈ 20 µs.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    fn forward_lanes(
        &self,
        x: &[f32],
        planes: usize,
        h: usize,
        w: usize,
        y: &mut [f32],
        argmax: &mut [u8],
        [oh, ph, ow, pw]: [usize; 4],
    ) {
        use std::arch::x86_64::*;
        let (k, s) = (self.kernel, self.stride);
        debug_assert!(s <= 2 && k <= 16);
        let iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let pick = _mm512_mullo_epi32(iota, _mm512_set1_epi32(s as i32)); // lane jj ← element s·jj
        let none = _mm512_set1_epi32(-1);
        let in_row = |cols: __m512i| {
            _mm512_cmpge_epi32_mask(cols, _mm512_setzero_si512())
                & _mm512_cmplt_epi32_mask(cols, _mm512_set1_epi32(w as i32))
        };
        for j0 in (0..ow).step_by(16) {
            let live: __mmask16 = ((1u32 << (ow - j0).min(16)) - 1) as u16;
            // Per kw: load masks of the 32 input columns from `first`, and the outputs whose tap is real.
            let mut first = [0isize; 16];
            let mut masks = [(0u16, 0u16, 0u16); 16];
            for kw in 0..k {
                first[kw] = (s * j0 + kw) as isize - pw as isize;
                let base = _mm512_add_epi32(iota, _mm512_set1_epi32(first[kw] as i32));
                let hi = _mm512_add_epi32(base, _mm512_set1_epi32(16));
                let out_cols = _mm512_add_epi32(_mm512_set1_epi32(first[kw] as i32), pick);
                masks[kw] = (in_row(base), in_row(hi), in_row(out_cols) & live);
            }
            // PLANES planes side by side: each running maximum is a compare → blend chain across
            // the taps, so one plane alone waits on latency (measured 29 → ≈ 22 µs per particle).
            for p0 in (0..planes).step_by(PLANES) {
                // A tail group repeats the last plane: same values written twice.
                let ps: [usize; PLANES] = std::array::from_fn(|q| (p0 + q).min(planes - 1));
                for i in 0..oh {
                    let row = self.span(i, ph, h);
                    let mut best = [_mm512_set1_ps(f32::NEG_INFINITY); PLANES];
                    let mut arg = [none; PLANES];
                    let mut seen: __mmask16 = 0; // outputs that have had a real tap
                    for kh in row.k0..row.k1 {
                        let r = (row.start + kh as isize) as usize;
                        for kw in 0..k {
                            let (lo_m, hi_m, valid) = masks[kw];
                            let tap = _mm512_set1_epi32((kh * k + kw) as i32);
                            let fresh = valid & !seen;
                            seen |= valid;
                            for q in 0..PLANES {
                                let xr = x[(ps[q] * h + r) * w..][..w].as_ptr();
                                // SAFETY: masked-off lanes are not accessed, and the mask keeps
                                // the others inside this input row.
                                let v = unsafe {
                                    let at = xr.wrapping_offset(first[kw]);
                                    let lo = _mm512_maskz_loadu_ps(lo_m, at);
                                    if s == 1 {
                                        lo
                                    } else {
                                        let hi = _mm512_maskz_loadu_ps(hi_m, at.wrapping_add(16));
                                        _mm512_permutex2var_ps(lo, pick, hi)
                                    }
                                };
                                // First real tap lands; then v > b, or v NaN while b is not:
                                // !(v ≤ b) (true if either is NaN) where b is a number.
                                let (b, a) = (best[q], arg[q]);
                                let number = _mm512_cmp_ps_mask::<_CMP_ORD_Q>(b, b);
                                let take =
                                    fresh | _mm512_mask_cmp_ps_mask::<_CMP_NLE_UQ>(valid & number, v, b);
                                best[q] = _mm512_mask_mov_ps(b, take, v);
                                arg[q] = _mm512_mask_mov_epi32(a, take, tap);
                            }
                        }
                    }
                    let len = (ow - j0).min(16);
                    for q in 0..PLANES {
                        let at = (ps[q] * oh + i) * ow + j0;
                        let (yr, ar) = (&mut y[at..][..len], &mut argmax[at..][..len]);
                        // SAFETY: `live` lanes are exactly the `yr` / `ar` elements.
                        unsafe {
                            _mm512_mask_storeu_ps(yr.as_mut_ptr(), live, best[q]);
                            _mm512_mask_cvtepi32_storeu_epi8(ar.as_mut_ptr().cast(), live, arg[q]);
                        }
                    }
                }
            }
        }
    }

    /// The same code compiled for AVX-512: the compare-and-select loops then run 16 lanes wide.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl")]
    #[allow(clippy::too_many_arguments)]
    fn forward_avx512(
        &self,
        x: &[f32],
        planes: usize,
        h: usize,
        w: usize,
        y: &mut [f32],
        argmax: &mut [u8],
        dims: [usize; 4],
    ) {
        self.forward_impl(x, planes, h, w, y, argmax, dims);
    }

    /// One output row at a time, every tap in window order (row-major over kh, kw) is compared
    /// against the running best of *every* window start `u` of a tile of input columns, not only
    /// the `u = stride·j` that are kept: contiguous, branch-free loops that vectorise. Measured on
    /// PF-net's 64 × 28 × 28 → 14 × 14 (examples/profile.rs): 470 µs → ≈ 110 µs per particle with
    /// AVX-512; the window-by-window loop it replaces ran at 4 ns per tap.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn forward_impl(
        &self,
        x: &[f32],
        planes: usize,
        h: usize,
        w: usize,
        y: &mut [f32],
        argmax: &mut [u8],
        [oh, ph, ow, pw]: [usize; 4],
    ) {
        const NONE: u32 = u32::MAX;
        let (k, s) = (self.kernel, self.stride);
        let outs_per_tile = (COLS - 1) / s + 1;
        let mut best_buf = [0.0f32; COLS];
        let mut arg_buf = [0u32; COLS];
        for p in 0..planes {
            let xp = &x[p * h * w..][..h * w];
            let yp = &mut y[p * oh * ow..][..oh * ow];
            let ap = &mut argmax[p * oh * ow..][..oh * ow];
            for i in 0..oh {
                let row = self.span(i, ph, h);
                for j0 in (0..ow).step_by(outs_per_tile) {
                    let jn = outs_per_tile.min(ow - j0);
                    // Window starts u0..u0 + len in padded coordinates; tap kw reads column u + kw − pw.
                    let (u0, len) = (s * j0, s * (jn - 1) + 1);
                    let best = &mut best_buf[..len];
                    let arg = &mut arg_buf[..len];
                    best.fill(f32::NEG_INFINITY);
                    arg.fill(NONE);
                    for kh in row.k0..row.k1 {
                        let xr = &xp[(row.start + kh as isize) as usize * w..][..w];
                        for kw in 0..k {
                            // u with 0 ≤ u + kw − pw < w, clipped to the tile.
                            let lo = (pw.saturating_sub(kw)).max(u0);
                            let hi = (w + pw).saturating_sub(kw).min(u0 + len);
                            if lo >= hi {
                                continue;
                            }
                            let tap = (kh * k + kw) as u32;
                            let src = &xr[lo + kw - pw..hi + kw - pw];
                            let (bs, as_) = (&mut best[lo - u0..hi - u0], &mut arg[lo - u0..hi - u0]);
                            for ((b, a), &v) in bs.iter_mut().zip(as_.iter_mut()).zip(src) {
                                // The first valid tap always lands; then strict `>` (first maximum
                                // wins ties, as in TF), and a NaN beats any number.
                                let take = (*a == NONE) | (v > *b) | (v.is_nan() & !b.is_nan());
                                *b = if take { v } else { *b };
                                *a = if take { tap } else { *a };
                            }
                        }
                    }
                    let (yr, ar) = (&mut yp[i * ow + j0..][..jn], &mut ap[i * ow + j0..][..jn]);
                    for (jj, (out, a)) in yr.iter_mut().zip(ar.iter_mut()).enumerate() {
                        *out = best[jj * s];
                        *a = arg[jj * s] as u8;
                    }
                }
            }
        }
    }

    /// Accumulates dy ([planes][oh][ow]) into dx ([planes][h][w]) at the argmax positions.
    ///
    /// Each winner's offset from its window's corner comes from a table rather than a division
    /// by the kernel per output. Measured per training step (examples/train_profile.rs): the map
    /// encoder's 30 × 64 planes 28 → 14, 2.9 ms → 0.55 ms; the observation's 384 planes 56 → 28,
    /// 2.1 ms → 0.5 ms (part of it the zero-fill of a smaller, cache-resident dx).
    pub fn backward(&self, dy: &[f32], argmax: &[u8], planes: usize, h: usize, w: usize, dx: &mut [f32]) {
        let [oh, ph, ow, pw] = self.check(planes, h, w, dx.len(), dy.len(), argmax.len());
        let (k, s) = (self.kernel, self.stride);
        let mut offset = [0isize; 256];
        for (a, o) in offset.iter_mut().enumerate().take(k * k) {
            *o = ((a / k) * w + a % k) as isize;
        }
        for p in 0..planes {
            let dxp = &mut dx[p * h * w..][..h * w];
            let dyp = &dy[p * oh * ow..][..oh * ow];
            let ap = &argmax[p * oh * ow..][..oh * ow];
            for i in 0..oh {
                // Flat index of the (possibly padded) top-left tap of window (i, 0).
                let corner = ((i * s) as isize - ph as isize) * w as isize - pw as isize;
                let (dyr, ar) = (&dyp[i * ow..][..ow], &ap[i * ow..][..ow]);
                for (j, (&g, &a)) in dyr.iter().zip(ar).enumerate() {
                    dxp[(corner + (j * s) as isize + offset[usize::from(a)]) as usize] += g;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad};

    /// Distinct values (a permutation of k/len), so no ties and finite differences are valid.
    fn distinct(len: usize) -> Vec<f32> {
        (0..len).map(|i| ((i * 7919 + 13) % len) as f32 / len as f32 - 0.5).collect()
    }

    fn r_values(len: usize) -> Vec<f32> {
        (0..len).map(|i| ((i as f32) * 0.73).sin()).collect()
    }

    /// Naive f64 pooling: every tap of every window, out-of-range taps read as −∞.
    fn naive(pool: &MaxPool2d, x: &[f64], planes: usize, h: usize, w: usize) -> Vec<f64> {
        let (oh, ph) = pool.padding.output_and_pad_before(h, pool.kernel, pool.stride, 1);
        let (ow, pw) = pool.padding.output_and_pad_before(w, pool.kernel, pool.stride, 1);
        let mut y = Vec::with_capacity(planes * oh * ow);
        for p in 0..planes {
            for i in 0..oh {
                for j in 0..ow {
                    let mut best = f64::NEG_INFINITY;
                    for kh in 0..pool.kernel {
                        for kw in 0..pool.kernel {
                            let ih = (i * pool.stride + kh) as isize - ph as isize;
                            let iw = (j * pool.stride + kw) as isize - pw as isize;
                            if (0..h as isize).contains(&ih) && (0..w as isize).contains(&iw) {
                                best = best.max(x[(p * h + ih as usize) * w + iw as usize]);
                            }
                        }
                    }
                    y.push(best);
                }
            }
        }
        y
    }

    fn check(pool: MaxPool2d, planes: usize, h: usize, w: usize) {
        let x = distinct(planes * h * w);
        let x64: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
        let (oh, ow) = pool.output_size(h, w);
        let mut y = vec![0.0; planes * oh * ow];
        let mut arg = vec![0u8; y.len()];
        pool.forward(&x, planes, h, w, &mut y, &mut arg);
        let want = naive(&pool, &x64, planes, h, w);
        assert_close(&y, &want, 1e-7, "forward");

        let r = r_values(y.len());
        let loss =
            |x: &[f64]| naive(&pool, x, planes, h, w).iter().zip(&r).map(|(a, &b)| a * f64::from(b)).sum();
        let want = numerical_grad(&x64, 1e-6, loss);
        let mut dx = vec![0.0; x.len()];
        pool.backward(&r, &arg, planes, h, w, &mut dx);
        assert_close(&dx, &want, 1e-4, "dx");
        pool.backward(&r, &arg, planes, h, w, &mut dx);
        let twice: Vec<f64> = want.iter().map(|a| 2.0 * a).collect();
        assert_close(&dx, &twice, 1e-4, "dx accumulated");
    }

    #[test]
    fn output_sizes_follow_tensorflow() {
        let same = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };
        let valid = MaxPool2d { padding: Padding::Valid, ..same };
        assert_eq!(same.output_size(28, 56), (14, 28));
        assert_eq!(valid.output_size(12, 11), (5, 5));
        // Even sizes: TF pads 0 before, 1 after; odd sizes pad 1 on each side.
        assert_eq!(same.axis(56), (28, 0));
        assert_eq!(same.axis(7), (4, 1));
    }

    #[test]
    fn same_even_and_odd_sizes_match_naive_and_finite_differences() {
        let pool = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };
        check(pool, 3, 8, 6);
        check(pool, 2, 7, 9);
    }

    #[test]
    fn valid_matches_naive_and_finite_differences() {
        check(MaxPool2d { kernel: 3, stride: 2, padding: Padding::Valid }, 3, 12, 11);
        check(MaxPool2d { kernel: 2, stride: 2, padding: Padding::Valid }, 2, 6, 5);
    }

    #[test]
    fn rows_wider_than_one_column_tile() {
        // Stride 3 takes the auto-vectorised kernel, strides 1 and 2 the intrinsics.
        check(MaxPool2d { kernel: 4, stride: 3, padding: Padding::Same }, 2, 5, COLS + 40);
        check(MaxPool2d { kernel: 3, stride: 3, padding: Padding::Valid }, 2, 7, 11);
        let pool = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };
        check(pool, 2, 3, 2 * COLS + 5);
        check(MaxPool2d { kernel: 2, stride: 1, padding: Padding::Valid }, 1, 2, COLS + 3);
    }

    #[test]
    fn nan_wins_and_all_minus_infinity_keeps_the_first_real_tap() {
        let pool = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };
        // 5 × 5, one row/column of padding before: window (0, 0) covers x[0..2][0..2].
        let mut x = vec![f32::NEG_INFINITY; 25];
        x[6] = f32::NAN; // (1, 1)
        x[12] = 5.0; // (2, 2)
        x[13] = f32::NAN; // (2, 3)
        let mut y = vec![0.0; 9];
        let mut arg = vec![0u8; 9];
        pool.forward(&x, 1, 5, 5, &mut y, &mut arg);
        // Window (0, 0): rows −1..1, cols −1..1 → the NaN at (1, 1) = tap (2, 2) = 8.
        assert!(y[0].is_nan() && arg[0] == 8);
        // Window (0, 1): rows −1..1, cols 1..3 → NaN at (1, 1) = tap (2, 0) = 6.
        assert!(y[1].is_nan() && arg[1] == 6);
        // Window (1, 1): rows 1..3, cols 1..3 → NaN (1, 1) is tap 0, before 5.0 and the later NaN.
        assert!(y[4].is_nan() && arg[4] == 0);
        // Window (1, 2): rows 1..3, cols 3..5 → NaN at (2, 3) = tap (1, 0) = 3.
        assert!(y[5].is_nan() && arg[5] == 3);
        // Window (2, 0): rows 3..5, cols −1..1, all −∞ → the first unpadded tap (0, 1) = 1.
        assert!(y[6] == f32::NEG_INFINITY && arg[6] == 1);
        // Window (2, 2): rows 3..5, cols 3..5, all −∞ and no padding → tap 0.
        assert!(y[8] == f32::NEG_INFINITY && arg[8] == 0);
    }

    #[test]
    fn ties_go_to_the_first_unpadded_tap() {
        // Odd size, Same: one row/column of padding before, so the corner window's first real tap is
        // (1, 1) = 4; an interior window's is 0.
        let pool = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };
        let x = vec![-2.0f32; 25];
        let mut y = vec![0.0; 9];
        let mut arg = vec![0u8; 9];
        pool.forward(&x, 1, 5, 5, &mut y, &mut arg);
        assert!(y.iter().all(|&v| v == -2.0));
        assert_eq!(arg, [4, 3, 3, 1, 0, 0, 1, 0, 0]);
    }
}
