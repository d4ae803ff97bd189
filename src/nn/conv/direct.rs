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
    __m512, __mmask16, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_mask_storeu_ps, _mm512_set1_ps,
};

const LANES: usize = 16;

/// Whether this CPU can run the kernel (cached by std after the first call).
pub fn available() -> bool {
    is_x86_feature_detected!("avx512f")
}

/// One call's shapes: input `h × w`, output `oh × ow`, the padded input `hp × wp`.
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
        let (hp, wp) = (self.hp(), self.wp());
        let rows = self.h.min(hp - self.pad_top);
        let cols = self.w.min(wp - self.pad_left);
        xpad.fill(0.0);
        for c in 0..self.c_in {
            for iy in 0..rows {
                let dst = &mut xpad[(c * hp + iy + self.pad_top) * wp + self.pad_left..][..cols];
                dst.copy_from_slice(&x_n[(c * self.h + iy) * self.w..][..cols]);
            }
        }
    }

    /// y_n [c_out][oh][ow] ← bias + conv(xpad). `weight` is [c_out][c_in][k][k].
    pub fn forward(&self, weight: &[f32], bias: &[f32], xpad: &[f32], y_n: &mut [f32]) {
        assert!(available(), "direct conv needs AVX-512F");
        assert!(self.oh > 0 && self.ow > 0 && self.c_out > 0);
        assert_eq!(weight.len(), self.c_out * self.c_in * self.kernel * self.kernel, "weight length");
        assert_eq!(bias.len(), self.c_out, "bias length");
        assert!(xpad.len() >= self.padded_len(), "xpad length");
        assert_eq!(y_n.len(), self.c_out * self.oh * self.ow, "y length");
        // SAFETY: AVX-512F checked above; the loads stay inside `xpad` (see `padded_len`) and the
        // masked stores inside `y_n` (lanes < ow − 16v of a row of `y_n`).
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
    fn run<const OB: usize, const S: usize>(
        &self,
        weight: &[f32],
        bias: &[f32],
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
            for t0 in (0..slots).step_by(S) {
                let mut x_at = [0usize; S];
                let mut y_at = [0usize; S];
                let mut mask = [0 as __mmask16; S];
                for s in 0..S {
                    let t = (t0 + s).min(slots - 1);
                    let (oy, v) = (t / vpr, t % vpr);
                    x_at[s] = oy * wp + v * LANES;
                    y_at[s] = oy * self.ow + v * LANES;
                    let live = (self.ow - v * LANES).min(LANES);
                    mask[s] = ((1u32 << live) - 1) as __mmask16;
                }
                let mut acc: [[__m512; S]; OB] = std::array::from_fn(|i| [_mm512_set1_ps(bias[o[i]]); S]);
                for c in 0..self.c_in {
                    for ki in 0..k {
                        for kj in 0..k {
                            let off = c * plane + ki * d * wp + kj * d;
                            let tap = (c * k + ki) * k + kj;
                            // S loads, then one broadcast at a time: OB·S + S + 1 ≤ 32 zmm, no spills.
                            let xv: [__m512; S] =
                                std::array::from_fn(|s| unsafe { _mm512_loadu_ps(x.add(x_at[s] + off)) });
                            for i in 0..OB {
                                let wv = _mm512_set1_ps(weight[o[i] * taps + tap]);
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
}
