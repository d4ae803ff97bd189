//! Direct stride-1 convolution on AVX-512, the forward path of [`super::Conv2d`] where it applies.
//!
//! Why not im2col + GEMM here: PF-net's map encoder has c_in = 1 (a 9…49-row im2col, so the GEMM
//! is bound by writing its output) and a second stage with c_out = 4 (a 4-row GEMM over a 1600-row
//! im2col that does not fit L2). Measured per particle (examples/profile.rs in the perf lab): the
//! five first-stage convs 68 µs → 28 µs, the two second-stage convs 273 µs → 38 µs (best of
//! noisy runs on a shared 2-core Zen 5).
//!
//! Each sample is copied once into a zero-bordered buffer `xpad [c_in][hp][wp]`. The output image
//! is cut into 16-lane "slots" (a row's pixels `16v..16v+16`); a tile of `S` slots × `OB` output
//! channels lives in `OB·S` zmm accumulators while every tap of every input channel adds
//! `w[o][c][ki][kj] · xpad[c][oy + ki·d][16v + kj·d ..]` (one unaligned load per slot, one broadcast
//! per channel). Lanes past a row's end compute garbage from the neighbouring pixels and are masked
//! off at the store.

use std::arch::x86_64::{
    __mmask16, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_mask_storeu_ps, _mm512_maskz_loadu_ps,
    _mm512_reduce_add_ps, _mm512_set1_ps, _mm512_setzero_ps,
};

const LANES: usize = 16;

/// Whether this CPU can run the kernel (cached by std after the first call).
pub fn available() -> bool {
    is_x86_feature_detected!("avx512f")
}

/// One call's shapes: input `h × w`, output `oh × ow`, the padded input `hp × wp`.
#[derive(Clone, Copy, Debug)]
pub struct Plan {
    pub c_in: usize,
    pub c_out: usize,
    pub kernel: usize,
    pub dilation: usize,
    pub h: usize,
    pub w: usize,
    pub oh: usize,
    pub ow: usize,
    pub pad_top: usize,
    pub pad_left: usize,
}

impl Plan {
    fn span(&self) -> usize {
        (self.kernel - 1) * self.dilation
    }

    fn hp(&self) -> usize {
        self.oh + self.span()
    }

    fn wp(&self) -> usize {
        self.ow + self.span()
    }

    fn vectors_per_row(&self) -> usize {
        self.ow.div_ceil(LANES)
    }

    /// Floats of `xpad`, with slack after the last row for the loads of the masked-off lanes.
    pub fn padded_len(&self) -> usize {
        self.c_in * self.hp() * self.wp() + LANES * self.vectors_per_row() + self.span()
    }

    /// xpad ← x_n with a zero border (the whole buffer is rewritten, so stale scratch is harmless).
    pub fn pad_input(&self, x_n: &[f32], xpad: &mut [f32]) {
        assert!(available(), "direct conv needs AVX-512F");
        assert_eq!(x_n.len(), self.c_in * self.h * self.w, "x length");
        assert!(xpad.len() >= self.c_in * self.hp() * self.wp(), "xpad length");
        // SAFETY: AVX-512F checked above.
        unsafe { self.pad_rows(x_n, xpad) }
    }

    /// Rows are copied with masked 16-lane moves: PF-net's are 14…56 floats, where a `memcpy`
    /// call per row cost more than the copy (2.5 % of a training step in `perf`).
    #[target_feature(enable = "avx512f")]
    fn pad_rows(&self, x_n: &[f32], xpad: &mut [f32]) {
        let (hp, wp) = (self.hp(), self.wp());
        let rows = self.h.min(hp - self.pad_top);
        let cols = self.w.min(wp - self.pad_left);
        xpad.fill(0.0);
        for c in 0..self.c_in {
            for iy in 0..rows {
                let dst = &mut xpad[(c * hp + iy + self.pad_top) * wp + self.pad_left..][..cols];
                let src = &x_n[(c * self.h + iy) * self.w..][..cols];
                for v in (0..cols).step_by(LANES) {
                    let m = ((1u32 << (cols - v).min(LANES)) - 1) as __mmask16;
                    // SAFETY: lanes masked to the `cols` floats of both slices.
                    unsafe {
                        let val = _mm512_maskz_loadu_ps(m, src.as_ptr().add(v));
                        _mm512_mask_storeu_ps(dst.as_mut_ptr().add(v), m, val);
                    }
                }
            }
        }
    }

    /// y_n [c_out][oh][ow] ← bias + conv(xpad). `weight` is [c_out][c_in][k][k].
    pub fn forward(&self, weight: &[f32], bias: &[f32], xpad: &[f32], y_n: &mut [f32]) {
        assert_eq!(bias.len(), self.c_out, "bias length");
        self.dispatch(weight, Some(bias), xpad, y_n);
    }

    /// y_n [c_out][oh][ow] += conv(xpad): the backward pass's dx as a convolution of dy.
    pub fn accumulate(&self, weight: &[f32], xpad: &[f32], y_n: &mut [f32]) {
        self.dispatch(weight, None, xpad, y_n);
    }

    fn dispatch(&self, weight: &[f32], bias: Option<&[f32]>, xpad: &[f32], y_n: &mut [f32]) {
        assert!(available(), "direct conv needs AVX-512F");
        assert!(self.oh > 0 && self.ow > 0 && self.c_out > 0);
        assert_eq!(weight.len(), self.c_out * self.c_in * self.kernel * self.kernel, "weight length");
        assert!(xpad.len() >= self.padded_len(), "xpad length");
        assert_eq!(y_n.len(), self.c_out * self.oh * self.ow, "y length");
        // SAFETY: AVX-512F checked above; the loads stay inside `xpad` (see `padded_len`) and the
        // masked loads and stores inside `y_n` (lanes < ow − 16v of a row of `y_n`).
        unsafe {
            // Register tiles of 8 channels × 3 slots, or 4 × 5 when c_out is not a multiple of 8
            // (PF-net's second stage has 4 channels per branch); 4 × 6 spilled accumulators.
            if self.c_out.is_multiple_of(8) {
                self.run::<8, 3>(weight, bias, xpad, y_n);
            } else {
                self.run::<4, 5>(weight, bias, xpad, y_n);
            }
        }
    }

    /// Tiles of `OB` channels × `S` slots. A tail tile clamps its channel and slot indices to the
    /// last valid one, so it recomputes and rewrites a few identical values rather than branching.
    #[target_feature(enable = "avx512f")]
    /// Accumulators start from the bias, or (`None`) from y's current values.
    fn run<const OB: usize, const S: usize>(
        &self,
        weight: &[f32],
        bias: Option<&[f32]>,
        xpad: &[f32],
        y_n: &mut [f32],
    ) {
        let (k, d, wp, plane) = (self.kernel, self.dilation, self.wp(), self.hp() * self.wp());
        let taps = self.c_in * k * k;
        let vpr = self.vectors_per_row();
        let slots = self.oh * vpr;
        let (x, y) = (xpad.as_ptr(), y_n.as_mut_ptr());
        for o0 in (0..self.c_out).step_by(OB) {
            let o: [usize; OB] = std::array::from_fn(|i| (o0 + i).min(self.c_out - 1));
            // Slot t is vector v of output row oy, walked rather than divided out of t.
            let (mut oy, mut v) = (0, 0);
            let mut x_at = [0usize; S];
            let mut y_at = [0usize; S];
            let mut mask = [0 as __mmask16; S];
            for t0 in (0..slots).step_by(S) {
                for s in 0..S {
                    if t0 + s < slots {
                        x_at[s] = oy * wp + v * LANES;
                        y_at[s] = oy * self.ow + v * LANES;
                        let live = (self.ow - v * LANES).min(LANES);
                        mask[s] = ((1u32 << live) - 1) as __mmask16;
                        v += 1;
                        if v == vpr {
                            (oy, v) = (oy + 1, 0);
                        }
                    } else {
                        // Past the last slot: repeat it (same values written twice).
                        (x_at[s], y_at[s], mask[s]) = (x_at[s - 1], y_at[s - 1], mask[s - 1]);
                    }
                }
                // Plain loops, not `array::from_fn` closures: a closure does not inherit this
                // function's target features, and where one was not inlined its intrinsics became
                // a call per tile.
                let mut acc = [[_mm512_setzero_ps(); S]; OB];
                for i in 0..OB {
                    for s in 0..S {
                        acc[i][s] = match bias {
                            Some(b) => _mm512_set1_ps(b[o[i]]),
                            None => unsafe {
                                _mm512_maskz_loadu_ps(mask[s], y.add(o[i] * self.oh * self.ow + y_at[s]))
                            },
                        };
                    }
                }
                for c in 0..self.c_in {
                    for ki in 0..k {
                        for kj in 0..k {
                            let off = c * plane + ki * d * wp + kj * d;
                            let tap = (c * k + ki) * k + kj;
                            // S loads, then one broadcast at a time: OB·S + S + 1 ≤ 32 zmm, no spills.
                            let mut xv = [_mm512_setzero_ps(); S];
                            for s in 0..S {
                                xv[s] = unsafe { _mm512_loadu_ps(x.add(x_at[s] + off)) };
                            }
                            for i in 0..OB {
                                // Unchecked: o[i] < c_out and tap < taps (the length asserted in
                                // `dispatch`); eight bounds checks per tap cost ≈ 5 % of a training step.
                                let wv = _mm512_set1_ps(unsafe { *weight.get_unchecked(o[i] * taps + tap) });
                                for s in 0..S {
                                    acc[i][s] = _mm512_fmadd_ps(wv, xv[s], acc[i][s]);
                                }
                            }
                        }
                    }
                }
                for i in 0..OB {
                    let base = o[i] * self.oh * self.ow;
                    for s in 0..S {
                        unsafe { _mm512_mask_storeu_ps(y.add(base + y_at[s]), mask[s], acc[i][s]) };
                    }
                }
            }
        }
    }

    /// dweight [c_out][c_in][k][k] += Σ_pixels dy_n[o][oy][ox] · xpad[c][oy + ki·d][ox + kj·d],
    /// dy_n [c_out][oh][ow] (this plan's output).
    pub fn backward_weight(&self, dy_n: &[f32], xpad: &[f32], dweight: &mut [f32]) {
        assert!(available(), "direct conv needs AVX-512F");
        assert!(self.oh > 0 && self.ow > 0 && self.c_out > 0);
        assert_eq!(dweight.len(), self.c_out * self.c_in * self.kernel * self.kernel, "dweight length");
        assert!(xpad.len() >= self.c_in * self.hp() * self.wp(), "xpad length");
        assert_eq!(dy_n.len(), self.c_out * self.oh * self.ow, "dy length");
        // SAFETY: AVX-512F checked above; every load is masked to the live lanes of a row, which lie
        // inside `dy_n` and inside the padded plane of `xpad`.
        unsafe {
            // Tiles of OB channels × KB taps of a kernel row: OB·KB + KB + 1 ≤ 32 zmm.
            match self.kernel {
                ..=3 if self.c_out.is_multiple_of(8) => self.weight_grad::<8, 3>(dy_n, xpad, dweight),
                ..=3 => self.weight_grad::<4, 3>(dy_n, xpad, dweight),
                4..=5 => self.weight_grad::<4, 5>(dy_n, xpad, dweight),
                _ => self.weight_grad::<3, 7>(dy_n, xpad, dweight),
            }
        }
    }

    /// Vectorised over the pixels of a row (16 per slot): a tile keeps `OB` channels × `KB` taps
    /// `(ki, kj..kj + KB)` in zmm accumulators across the whole image, then reduces each to one
    /// weight. Clamped tail channels and taps are computed but not stored.
    #[target_feature(enable = "avx512f")]
    fn weight_grad<const OB: usize, const KB: usize>(&self, dy_n: &[f32], xpad: &[f32], dweight: &mut [f32]) {
        let (k, d, wp, plane) = (self.kernel, self.dilation, self.wp(), self.hp() * self.wp());
        let (pixels, vpr) = (self.oh * self.ow, self.vectors_per_row());
        let (x, dy) = (xpad.as_ptr(), dy_n.as_ptr());
        for c in 0..self.c_in {
            for o0 in (0..self.c_out).step_by(OB) {
                let o: [usize; OB] = std::array::from_fn(|i| (o0 + i).min(self.c_out - 1));
                for ki in 0..k {
                    for kj0 in (0..k).step_by(KB) {
                        let kj: [usize; KB] = std::array::from_fn(|s| (kj0 + s).min(k - 1));
                        let mut acc = [[_mm512_setzero_ps(); KB]; OB];
                        for oy in 0..self.oh {
                            let x_row = c * plane + (oy + ki * d) * wp;
                            for v in 0..vpr {
                                let live = (self.ow - v * LANES).min(LANES);
                                let m = ((1u32 << live) - 1) as __mmask16;
                                let mut xv = [_mm512_setzero_ps(); KB];
                                for s in 0..KB {
                                    xv[s] = unsafe {
                                        _mm512_maskz_loadu_ps(m, x.add(x_row + v * LANES + kj[s] * d))
                                    };
                                }
                                for i in 0..OB {
                                    let at = o[i] * pixels + oy * self.ow + v * LANES;
                                    let g = unsafe { _mm512_maskz_loadu_ps(m, dy.add(at)) };
                                    for s in 0..KB {
                                        acc[i][s] = _mm512_fmadd_ps(g, xv[s], acc[i][s]);
                                    }
                                }
                            }
                        }
                        for i in 0..OB.min(self.c_out - o0) {
                            for s in 0..KB.min(k - kj0) {
                                dweight[((o[i] * self.c_in + c) * k + ki) * k + kj[s]] +=
                                    _mm512_reduce_add_ps(acc[i][s]);
                            }
                        }
                    }
                }
            }
        }
    }
}
