//! Direct strided 'valid' convolution on AVX-512 with the *channels* in the vector lanes, the path
//! of [`super::Conv2d`]'s strides > 1 where the channel counts allow (SAC's image encoders).
//!
//! Why not `direct.rs` (pixels in lanes) or im2col: SAC's outputs are 24…2 pixels wide, so
//! 16-pixel vectors run mostly empty, and im2col spends more on gathering 2…27-float runs (and on
//! columns that overflow L2) than its GEMM spends on arithmetic. Channels (16, 32 or 64) fill the
//! lanes at any image size, and a stride only changes which scalar is broadcast. Measured with
//! `apfn sac bench --config compact` (batch 256, 2 threads, shared 2-core box under load), min of
//! runs per update: im2col 272 ms; the polyphase rewrite onto `direct.rs` (a 2×2 stride-1 conv
//! over 4·c_in phase channels, 16/9 the work) 404 ms; im2col with vectorised stride-2 gathers
//! 272 ms, with 4× smaller column groups 222 ms; this file ≈ 120 ms.
//!
//! Every kernel walks the pixels of all `n` samples as one sequence, so 2 × 2 outputs still fill
//! whole register tiles. The outputs are pixel-major (`[pixel][channel]`): `forward_strided`
//! transposes them into a channel-major y, `forward_strided_channel_last` hands them on as they
//! are to a next layer that reads its x channel-last (`Plan::channel_last`).

use std::arch::x86_64::{
    __m512, _mm512_add_ps, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_max_ps, _mm512_set1_ps,
    _mm512_setzero_ps, _mm512_storeu_ps,
};

use super::transpose::transpose;
use super::{Conv2d, Geometry, Padding, sum};

const LANES: usize = 16;

/// One call's shapes; every tap lies inside the `h × w` input ('valid' padding).
#[derive(Clone, Copy, Debug)]
pub struct Plan {
    pub c_in: usize,
    pub c_out: usize,
    pub kernel: usize,
    pub stride: usize,
    pub dilation: usize,
    pub h: usize,
    pub w: usize,
    pub oh: usize,
    pub ow: usize,
    /// x (and dy, dx) channel-last, `[n][h][w][c]`, instead of channel-major `[n][c][h][w]`.
    pub channel_last: bool,
}

impl Plan {
    fn taps(&self) -> usize {
        self.c_in * self.kernel * self.kernel
    }

    fn x_len(&self) -> usize {
        self.c_in * self.h * self.w
    }

    fn pixels(&self) -> usize {
        self.oh * self.ow
    }

    /// Steps in x between neighbouring channels and between neighbouring pixels.
    #[inline(always)]
    fn x_strides(&self) -> (usize, usize) {
        if self.channel_last { (1, self.c_in) } else { (self.h * self.w, 1) }
    }

    /// Offset in x_n of tap `(c, ki, kj)` (index `(c·k + ki)·k + kj`) from its output pixel's origin.
    #[inline(always)]
    fn tap_offset(&self, tap: usize) -> usize {
        let (k, d) = (self.kernel, self.dilation);
        let (c, ki, kj) = (tap / (k * k), tap / k % k, tap % k);
        let (channel, pixel) = self.x_strides();
        c * channel + (ki * d * self.w + kj * d) * pixel
    }

    /// (sample, oy, ox) of the call's output pixels q0, q0 + 1, … (`q = i·P + oy·ow + ox`), the
    /// tail past `total` clamped to the last pixel. Counted up from q0, not divided out per pixel:
    /// a first layer's tile does only 9 taps of arithmetic per pixel.
    #[inline(always)]
    fn pixel_coords<const PX: usize>(&self, q0: usize, total: usize) -> [(usize, usize, usize); PX] {
        let (mut i, r) = (q0 / self.pixels(), q0 % self.pixels());
        let (mut oy, mut ox) = (r / self.ow, r % self.ow);
        // A plain loop, not `array::from_fn`: the closure was left out of line in some of the
        // kernels' instances, 3 % of a paper-size SAC update in `perf`.
        let mut coords = [(0, 0, 0); PX];
        for (j, here) in coords.iter_mut().enumerate() {
            *here = (i, oy, ox);
            if q0 + j + 1 < total {
                ox += 1;
                if ox == self.ow {
                    (ox, oy) = (0, oy + 1);
                    if oy == self.oh {
                        (oy, i) = (0, i + 1);
                    }
                }
            }
        }
        coords
    }

    /// Input pixel (of the whole call, `[n][h][w]`) of the top-left tap of output pixel (i, oy, ox).
    #[inline(always)]
    fn origin_pixel(&self, (i, oy, ox): (usize, usize, usize)) -> usize {
        (i * self.h + oy * self.stride) * self.w + ox * self.stride
    }

    /// Offset in x of the top-left tap of output pixel (i, oy, ox).
    #[inline(always)]
    fn origin(&self, (i, oy, ox): (usize, usize, usize)) -> usize {
        i * self.x_len() + (oy * self.w + ox) * self.stride * self.x_strides().1
    }

    /// What the kernels' safety rests on: AVX-512F, a `lanes` side (c_out, or c_in for dx) of
    /// whole vectors, and every tap of every output pixel inside the input.
    fn check(&self, n: usize, lanes: usize) {
        assert!(super::direct::available(), "strided conv needs AVX-512F");
        assert!(lanes.is_multiple_of(LANES) && n * self.pixels() > 0, "{lanes} channels, {n} samples");
        let span = (self.kernel - 1) * self.dilation;
        let inside =
            (self.oh - 1) * self.stride + span < self.h && (self.ow - 1) * self.stride + span < self.w;
        assert!(inside, "taps past the input: {self:?}");
    }

    /// yt [n·P][c_out] ← bias[o] + Σ_taps wt[tap][o] · x[i][tap at pixel], for the `n` samples of
    /// x [n][c_in][h][w]; wt is [c_in·k·k][c_out]. With `relu`, negative sums are stored as 0.
    pub fn forward(&self, wt: &[f32], bias: &[f32], x: &[f32], n: usize, yt: &mut [f32], relu: bool) {
        self.check(n, self.c_out);
        assert_eq!((wt.len(), bias.len(), x.len()), (self.taps() * self.c_out, self.c_out, n * self.x_len()));
        assert_eq!(yt.len(), n * self.pixels() * self.c_out, "yt length");
        // SAFETY: `check` and the lengths above: every tap of every pixel lies inside x,
        // every weight and bias load inside a multiple-of-16 channel block, every store inside
        // a pixel's row of yt.
        unsafe {
            // Register tiles of 64 channels × 6 pixels, 32 × 12 or 16 × 24: OB·PX + OB + 1 ≤ 32 zmm.
            match (self.c_out % (4 * LANES), self.c_out % (2 * LANES), relu) {
                (0, _, false) => self.forward_tiles::<4, 6, false>(wt, bias, x, n, yt),
                (0, _, true) => self.forward_tiles::<4, 6, true>(wt, bias, x, n, yt),
                (_, 0, false) => self.forward_tiles::<2, 12, false>(wt, bias, x, n, yt),
                (_, 0, true) => self.forward_tiles::<2, 12, true>(wt, bias, x, n, yt),
                (_, _, false) => self.forward_tiles::<1, 24, false>(wt, bias, x, n, yt),
                (_, _, true) => self.forward_tiles::<1, 24, true>(wt, bias, x, n, yt),
            }
        }
    }

    /// A tile of OB·16 channels × PX pixels: per tap, OB weight vectors times PX broadcast inputs.
    /// The pixel tail clamps to the last pixel, recomputing it rather than branching. RELU clamps
    /// the sums as they are stored, sparing the activation its own pass over y.
    #[target_feature(enable = "avx512f")]
    fn forward_tiles<const OB: usize, const PX: usize, const RELU: bool>(
        &self,
        wt: &[f32],
        bias: &[f32],
        x: &[f32],
        n: usize,
        yt: &mut [f32],
    ) {
        let (total, k, d) = (n * self.pixels(), self.kernel, self.dilation);
        for (ob, block) in output_blocks::<OB>(self.c_out) {
            for q0 in (0..total).step_by(PX) {
                let origin = self.pixel_coords::<PX>(q0, total).map(|at| self.origin(at));
                let mut acc: [[__m512; PX]; OB] =
                    block.map(|o| [unsafe { _mm512_loadu_ps(bias.as_ptr().add(o)) }; PX]);
                // Taps in weight order, their offsets counted up rather than divided out.
                let (channel, pixel) = self.x_strides();
                let mut tap = 0;
                for c in 0..self.c_in {
                    for ki in 0..k {
                        for kj in 0..k {
                            let off = c * channel + (ki * d * self.w + kj * d) * pixel;
                            let mut wv = [_mm512_setzero_ps(); OB];
                            for b in 0..OB {
                                wv[b] =
                                    unsafe { _mm512_loadu_ps(wt.as_ptr().add(tap * self.c_out + block[b])) };
                            }
                            for j in 0..PX {
                                let xv = _mm512_set1_ps(unsafe { *x.get_unchecked(origin[j] + off) });
                                for b in 0..OB {
                                    acc[b][j] = _mm512_fmadd_ps(wv[b], xv, acc[b][j]);
                                }
                            }
                            tap += 1;
                        }
                    }
                }
                for (b, pixels) in acc.iter().enumerate().take(ob) {
                    for (j, &sum) in pixels.iter().enumerate().take(total - q0) {
                        // max(0, NaN) is NaN (the second operand wins), as in `relu_forward`.
                        let sum = if RELU { _mm512_max_ps(_mm512_setzero_ps(), sum) } else { sum };
                        unsafe {
                            _mm512_storeu_ps(yt.as_mut_ptr().add((q0 + j) * self.c_out + block[b]), sum)
                        };
                    }
                }
            }
        }
    }

    /// dwt [c_in·k·k][c_out] += Σ_pixels dyt[pixel][o] · x[tap at pixel], over the `n` samples of
    /// x; dyt is [n·P][c_out], dy pixel-major.
    pub fn backward_weight(&self, dyt: &[f32], x: &[f32], n: usize, dwt: &mut [f32]) {
        self.check(n, self.c_out);
        assert_eq!(
            (dyt.len(), x.len(), dwt.len()),
            (n * self.pixels() * self.c_out, n * self.x_len(), self.taps() * self.c_out)
        );
        // SAFETY: as in `forward`; dyt and dwt are read and written in whole 16-channel blocks.
        unsafe {
            // Tiles of OB·16 channels × TB taps: OB·TB + OB + 1 ≤ 32 zmm.
            if self.c_out.is_multiple_of(4 * LANES) {
                self.weight_tiles::<4, 6>(dyt, x, n, dwt);
            } else if self.c_out.is_multiple_of(2 * LANES) {
                self.weight_tiles::<2, 12>(dyt, x, n, dwt);
            } else {
                self.weight_tiles::<1, 24>(dyt, x, n, dwt);
            }
        }
    }

    /// A tile of OB·16 channels × TB taps stays in registers over every pixel of the call: per
    /// pixel, OB dy vectors times TB broadcast inputs. Clamped tail taps are computed, not stored.
    #[target_feature(enable = "avx512f")]
    fn weight_tiles<const OB: usize, const TB: usize>(
        &self,
        dyt: &[f32],
        x: &[f32],
        n: usize,
        dwt: &mut [f32],
    ) {
        let taps = self.taps();
        for (ob, block) in output_blocks::<OB>(self.c_out) {
            for t0 in (0..taps).step_by(TB) {
                let tap: [usize; TB] = std::array::from_fn(|t| (t0 + t).min(taps - 1));
                let off = tap.map(|t| self.tap_offset(t));
                let pixel = self.x_strides().1;
                let mut acc = [[_mm512_setzero_ps(); TB]; OB];
                // Pixels in dyt's order, their origins counted up rather than divided out.
                let mut q = 0;
                for i in 0..n {
                    for oy in 0..self.oh {
                        for ox in 0..self.ow {
                            let origin = i * self.x_len() + (oy * self.w + ox) * self.stride * pixel;
                            let mut g = [_mm512_setzero_ps(); OB];
                            for b in 0..OB {
                                g[b] =
                                    unsafe { _mm512_loadu_ps(dyt.as_ptr().add(q * self.c_out + block[b])) };
                            }
                            for t in 0..TB {
                                let xv = _mm512_set1_ps(unsafe { *x.get_unchecked(origin + off[t]) });
                                for b in 0..OB {
                                    acc[b][t] = _mm512_fmadd_ps(g[b], xv, acc[b][t]);
                                }
                            }
                            q += 1;
                        }
                    }
                }
                for t in 0..TB.min(taps - t0) {
                    for b in 0..ob {
                        let at = unsafe { dwt.as_mut_ptr().add(tap[t] * self.c_out + block[b]) };
                        unsafe { _mm512_storeu_ps(at, _mm512_add_ps(_mm512_loadu_ps(at), acc[b][t])) };
                    }
                }
            }
        }
    }

    /// dxt [n·h·w][c_in] += Σ_o Σ_(ki,kj) dy[i][o][pixel] · wx[(ki,kj)][o][c], each output pixel
    /// adding into the input pixels its taps read. wx is [k·k][c_out][c_in]; dy [n][y_channels][P]
    /// (channel-last: [n][P][y_channels]) is read at channels y_offset.. .
    pub fn backward_input(
        &self,
        wx: &[f32],
        dy: &[f32],
        n: usize,
        (y_channels, y_offset): (usize, usize),
        dxt: &mut [f32],
    ) {
        self.check(n, self.c_in);
        assert_eq!((wx.len(), dxt.len()), (self.taps() * self.c_out, n * self.x_len()));
        assert!(
            y_offset + self.c_out <= y_channels && dy.len() == n * y_channels * self.pixels(),
            "dy length"
        );
        // SAFETY: `check` and the lengths above: dy reads stay in sample i's channel slice, wx and dxt
        // are read and written in whole 16-channel blocks of rows inside them.
        // 9 pixels × 3 kernel positions: each weight vector, streamed from L2, serves 9 pixels
        // (3 pixels × all 9 positions streamed the weights three times as often; this kernel's
        // share of a paper-size update fell by 28 % in `perf`).
        unsafe { self.input_tiles::<9, 3>(wx, dy, n, (y_channels, y_offset), dxt) }
    }

    /// A tile of 16 input channels × PX output pixels × TB kernel positions: per output channel,
    /// PX broadcast dy values times TB weight vectors. Clamped tails are computed, not stored.
    #[target_feature(enable = "avx512f")]
    fn input_tiles<const PX: usize, const TB: usize>(
        &self,
        wx: &[f32],
        dy: &[f32],
        n: usize,
        (y_channels, y_offset): (usize, usize),
        dxt: &mut [f32],
    ) {
        let (p, total, kk, k, d) =
            (self.pixels(), n * self.pixels(), self.kernel * self.kernel, self.kernel, self.dilation);
        for c0 in (0..self.c_in).step_by(LANES) {
            for q0 in (0..total).step_by(PX) {
                let coords = self.pixel_coords::<PX>(q0, total);
                // dy of output channel o at pixel j: dy[dy_at[j] + o·o_step].
                let (dy_at, o_step) = if self.channel_last {
                    (coords.map(|(i, oy, ox)| (i * p + oy * self.ow + ox) * y_channels + y_offset), 1)
                } else {
                    (coords.map(|(i, oy, ox)| (i * y_channels + y_offset) * p + oy * self.ow + ox), p)
                };
                let origin = coords.map(|at| self.origin_pixel(at));
                for t0 in (0..kk).step_by(TB) {
                    let pos: [usize; TB] = std::array::from_fn(|t| (t0 + t).min(kk - 1));
                    let mut acc = [[_mm512_setzero_ps(); TB]; PX];
                    for o in 0..self.c_out {
                        let mut g = [_mm512_setzero_ps(); PX];
                        for j in 0..PX {
                            g[j] = _mm512_set1_ps(unsafe { *dy.get_unchecked(dy_at[j] + o * o_step) });
                        }
                        for t in 0..TB {
                            let wv = unsafe {
                                _mm512_loadu_ps(wx.as_ptr().add((pos[t] * self.c_out + o) * self.c_in + c0))
                            };
                            for j in 0..PX {
                                acc[j][t] = _mm512_fmadd_ps(g[j], wv, acc[j][t]);
                            }
                        }
                    }
                    for j in 0..PX.min(total - q0) {
                        for t in 0..TB.min(kk - t0) {
                            let pixel = origin[j] + (pos[t] / k * self.w + pos[t] % k) * d;
                            let at = unsafe { dxt.as_mut_ptr().add(pixel * self.c_in + c0) };
                            unsafe { _mm512_storeu_ps(at, _mm512_add_ps(_mm512_loadu_ps(at), acc[j][t])) };
                        }
                    }
                }
            }
        }
    }
}

impl Conv2d {
    /// Whether this call runs here: a stride > 1 'valid' conv whose output channels (and, for dx,
    /// input channels) fill whole vectors, on a CPU with AVX-512.
    pub(super) fn runs_strided(&self, with_dx: bool) -> bool {
        self.stride > 1
            && self.padding == Padding::Valid
            && self.c_out.is_multiple_of(LANES)
            && (!with_dx || self.c_in.is_multiple_of(LANES))
            && super::direct::available()
    }

    fn strided_plan(&self, g: &Geometry, channel_last: bool) -> Plan {
        let (c_in, c_out, kernel, stride, dilation) =
            (self.c_in, self.c_out, self.kernel, self.stride, self.dilation);
        Plan { c_in, c_out, kernel, stride, dilation, h: g.h, w: g.w, oh: g.oh, ow: g.ow, channel_last }
    }

    /// wx [k·k][c_out][c_in] ← weight [c_out][c_in][k·k]: the layout `backward_input` reads.
    fn weight_by_position(&self, weight: &[f32], wx: &mut [f32]) {
        let kk = self.kernel * self.kernel;
        for (o, w_o) in weight.chunks_exact(self.taps()).enumerate() {
            for (c, w_oc) in w_o.chunks_exact(kk).enumerate() {
                for (pos, &v) in w_oc.iter().enumerate() {
                    wx[(pos * self.c_out + o) * self.c_in + c] = v;
                }
            }
        }
    }

    /// `forward_channel_last` here: the kernel's pixel-major output is y itself.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn forward_strided_channel_last(
        &self,
        g: &Geometry,
        wt: &[f32],
        bias: &[f32],
        x: &[f32],
        x_channel_last: bool,
        n: usize,
        y: &mut [f32],
        relu: bool,
    ) {
        if n * g.pixels() == 0 {
            return;
        }
        self.strided_plan(g, x_channel_last).forward(wt, bias, x, n, y, relu);
    }

    /// `backward_channel_last` here, per group of samples (so x and dy stay in cache across the
    /// weight kernel's tap blocks): dy is already pixel-major for dweight, and dx comes out so.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn backward_strided_channel_last(
        &self,
        g: &Geometry,
        weight: &[f32],
        x: &[f32],
        x_channel_last: bool,
        n: usize,
        dy: &[f32],
        dweight: &mut [f32],
        dbias: &mut [f32],
        mut dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
    ) {
        let (p, x_len) = (g.pixels(), self.c_in * g.h * g.w);
        if n * p == 0 {
            return;
        }
        let plan = self.strided_plan(g, x_channel_last);
        let group = Self::strided_group(p * self.c_out + x_len, n);
        let with_dx = usize::from(dx.is_some());
        let [dwt, wx] = carve(scratch, [self.weight_len(), with_dx * self.weight_len()]);
        dwt.fill(0.0);
        if dx.is_some() {
            self.weight_by_position(weight, wx);
        }
        for (first, x_g) in (0..n).step_by(group).zip(x.chunks(group * x_len)) {
            let m = x_g.len() / x_len;
            let dy_g = &dy[first * p * self.c_out..][..m * p * self.c_out];
            plan.backward_weight(dy_g, x_g, m, dwt);
            for row in dy_g.chunks_exact(self.c_out) {
                dbias.iter_mut().zip(row).for_each(|(b, v)| *b += v);
            }
            if let Some(dx) = dx.as_deref_mut() {
                plan.backward_input(wx, dy_g, m, (self.c_out, 0), &mut dx[first * x_len..][..m * x_len]);
            }
        }
        transpose(dwt, self.taps(), self.c_out, dweight, true);
    }

    /// Samples per kernel call: enough that small outputs still make long pixel sequences, few
    /// enough that a group's pixel-major buffer (`per_sample` floats each, ≤ 64 KB in all) stays in
    /// cache for its transpose (whole-call buffers of up to 1.5 MB left ≈ 10 % on the table).
    pub(super) fn strided_group(per_sample: usize, n: usize) -> usize {
        (16_384 / per_sample.max(1)).clamp(1, n.max(1))
    }

    /// `forward` on this path: the weight transposed to [tap][c_out]; per group of samples, one
    /// kernel call whose pixel-major output is transposed into y's channel slice (scattering each
    /// vector instead cost 3/4 of the kernel's time).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn forward_strided(
        &self,
        g: &Geometry,
        weight: &[f32],
        bias: &[f32],
        x: &[f32],
        n: usize,
        y: &mut [f32],
        (y_channels, y_offset): (usize, usize),
        scratch: &mut Vec<f32>,
    ) {
        let (p, x_len) = (g.pixels(), self.c_in * g.h * g.w);
        if n * p == 0 {
            return;
        }
        let (plan, group) = (self.strided_plan(g, false), Self::strided_group(p * self.c_out, n));
        let [wt, yt] = carve(scratch, [self.weight_len(), group * p * self.c_out]);
        transpose(weight, self.c_out, self.taps(), wt, false);
        for (x_g, y_g) in x.chunks(group * x_len).zip(y.chunks_mut(group * y_channels * p)) {
            let m = x_g.len() / x_len;
            let yt = &mut yt[..m * p * self.c_out];
            plan.forward(wt, bias, x_g, m, yt, false);
            for (yt_n, y_n) in yt.chunks_exact(p * self.c_out).zip(y_g.chunks_exact_mut(y_channels * p)) {
                transpose(yt_n, p, self.c_out, &mut y_n[y_offset * p..][..self.c_out * p], false);
            }
        }
    }

    /// `backward` on this path, per group of samples: dy transposed to pixel-major for dweight;
    /// dx computed pixel-major and transposed back.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn backward_strided(
        &self,
        g: &Geometry,
        weight: &[f32],
        x: &[f32],
        n: usize,
        dy: &[f32],
        (y_channels, y_offset): (usize, usize),
        dweight: &mut [f32],
        dbias: &mut [f32],
        mut dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
    ) {
        let (p, taps, x_len) = (g.pixels(), self.taps(), self.c_in * g.h * g.w);
        if n * p == 0 {
            return;
        }
        let dx_len = if dx.is_some() { x_len } else { 0 };
        let (plan, group) =
            (self.strided_plan(g, false), Self::strided_group((p * self.c_out).max(dx_len), n));
        let [dyt, dwt, wx, dxt] = carve(
            scratch,
            [group * p * self.c_out, self.weight_len(), dx_len.min(1) * self.weight_len(), group * dx_len],
        );
        dwt.fill(0.0);
        if dx.is_some() {
            self.weight_by_position(weight, wx);
        }
        for (first, x_g) in (0..n).step_by(group).zip(x.chunks(group * x_len)) {
            let m = x_g.len() / x_len;
            let dy_g = &dy[first * y_channels * p..][..m * y_channels * p];
            let dyt = &mut dyt[..m * p * self.c_out];
            for (dyt_n, dy_n) in dyt.chunks_exact_mut(p * self.c_out).zip(dy_g.chunks_exact(y_channels * p)) {
                let dy_n = &dy_n[y_offset * p..][..self.c_out * p];
                transpose(dy_n, self.c_out, p, dyt_n, false);
                for (db, row) in dbias.iter_mut().zip(dy_n.chunks_exact(p)) {
                    *db += sum(row);
                }
            }
            plan.backward_weight(dyt, x_g, m, dwt);
            if let Some(dx) = dx.as_deref_mut() {
                let dxt = &mut dxt[..m * x_len];
                dxt.fill(0.0);
                plan.backward_input(wx, dy_g, m, (y_channels, y_offset), dxt);
                let hw = g.h * g.w;
                let dx_g = &mut dx[first * x_len..][..m * x_len];
                for (dxt_n, dx_n) in dxt.chunks_exact(x_len).zip(dx_g.chunks_exact_mut(x_len)) {
                    transpose(dxt_n, hw, self.c_in, dx_n, true);
                }
            }
        }
        transpose(dwt, taps, self.c_out, dweight, true);
    }
}

/// Consecutive buffers of the given lengths from `scratch` (grown as needed, stale contents kept).
/// Output channels in register tiles of up to `OB` × 16 lanes: each tile's live vector count and
/// the first channel of every vector (a short last tile repeats its last vector, never stored).
fn output_blocks<const OB: usize>(c_out: usize) -> impl Iterator<Item = (usize, [usize; OB])> {
    (0..c_out).step_by(OB * LANES).map(move |o0| {
        let ob = OB.min((c_out - o0) / LANES);
        (ob, std::array::from_fn(|b| o0 + b.min(ob - 1) * LANES))
    })
}

fn carve<const N: usize>(scratch: &mut Vec<f32>, lens: [usize; N]) -> [&mut [f32]; N] {
    let need = lens.iter().sum();
    if scratch.len() < need {
        scratch.resize(need, 0.0);
    }
    let mut rest = &mut scratch[..need];
    lens.map(|len| {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(len);
        rest = tail;
        head
    })
}
