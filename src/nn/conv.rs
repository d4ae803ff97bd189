//! 2-D convolution (NCHW, square kernel, stride, dilation, TensorFlow padding) as im2col + one GEMM
//! per sample. The GEMM puts the narrow output-channel side on the rows, `y_n[c_out × P] = W[c_out × K]
//! · cols[K × P]` (K = c_in·k·k taps, P = oh·ow pixels), and writes straight into y's channel slice.
//! Where the CPU has AVX-512, convs run direct kernels instead, forward and backward: stride-1
//! ones with pixels in the lanes (`direct.rs`, several times faster on PF-net's shapes), strided
//! 'valid' ones with channels in the lanes (`strided.rs`, SAC's encoders). im2col is the fallback.

#[cfg(target_arch = "x86_64")]
mod direct;
#[cfg(target_arch = "x86_64")]
mod strided;
#[cfg(target_arch = "x86_64")]
mod transpose;

use crate::nn::gemm::{MatMut, MatRef, matmul};

/// TensorFlow's padding modes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Padding {
    Same,
    Valid,
}

impl Padding {
    /// (output length, padding before) for one spatial axis, TensorFlow's rule.
    pub fn output_and_pad_before(
        self,
        input: usize,
        kernel: usize,
        stride: usize,
        dilation: usize,
    ) -> (usize, usize) {
        assert!(kernel >= 1 && stride >= 1 && dilation >= 1, "kernel, stride and dilation must be ≥ 1");
        let span = (kernel - 1) * dilation + 1;
        match self {
            Padding::Same => {
                let out = input.div_ceil(stride);
                // TF puts the odd pixel of padding after, hence floor for the before side.
                let total = ((out.max(1) - 1) * stride + span).saturating_sub(input);
                (out, total / 2)
            }
            Padding::Valid => (if input >= span { (input - span) / stride + 1 } else { 0 }, 0),
        }
    }
}

/// 2-D convolution, square kernel, NCHW, weights [c_out][c_in][kh][kw], bias [c_out].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Conv2d {
    pub c_in: usize,
    pub c_out: usize,
    pub kernel: usize,
    pub stride: usize,
    pub dilation: usize,
    pub padding: Padding,
}

/// Output size and the top/left padding of one call.
struct Geometry {
    h: usize,
    w: usize,
    oh: usize,
    ow: usize,
    pad_top: usize,
    pad_left: usize,
}

impl Geometry {
    fn pixels(&self) -> usize {
        self.oh * self.ow
    }
}

/// The outputs `o < out` whose tap `o·stride + offset` lands inside `0..input`, as a range.
fn valid_range(out: usize, input: usize, offset: isize, stride: usize) -> (usize, usize) {
    let s = stride as isize;
    let lo = if offset >= 0 { 0 } else { ((-offset + s - 1) / s) as usize };
    let last = input as isize - 1 - offset;
    let hi = if last < 0 { 0 } else { out.min((last / s) as usize + 1) };
    (lo.min(hi), hi)
}

impl Conv2d {
    pub fn output_size(&self, h: usize, w: usize) -> (usize, usize) {
        let g = self.geometry(h, w);
        (g.oh, g.ow)
    }

    pub fn weight_len(&self) -> usize {
        self.c_out * self.c_in * self.kernel * self.kernel
    }

    /// Rows of the im2col matrix: one per (c_in, kh, kw) tap.
    fn taps(&self) -> usize {
        self.c_in * self.kernel * self.kernel
    }

    fn geometry(&self, h: usize, w: usize) -> Geometry {
        let (oh, pad_top) = self.padding.output_and_pad_before(h, self.kernel, self.stride, self.dilation);
        let (ow, pad_left) = self.padding.output_and_pad_before(w, self.kernel, self.stride, self.dilation);
        Geometry { h, w, oh, ow, pad_top, pad_left }
    }

    /// Calls `f(tap, pixel, x, len)` for every run of in-bounds taps of one sample: row `tap` of
    /// the im2col matrix at output pixels `pixel + j` reads `x_n[x + j·stride]` for `j < len`.
    /// Taps not visited fall in the padding (zero).
    fn for_each_run(&self, g: &Geometry, mut f: impl FnMut(usize, usize, usize, usize)) {
        let (k, s, d) = (self.kernel, self.stride, self.dilation);
        for c in 0..self.c_in {
            for ki in 0..k {
                let (oy_lo, oy_hi) = valid_range(g.oh, g.h, (ki * d) as isize - g.pad_top as isize, s);
                for kj in 0..k {
                    let (ox_lo, ox_hi) = valid_range(g.ow, g.w, (kj * d) as isize - g.pad_left as isize, s);
                    if ox_lo == ox_hi {
                        continue;
                    }
                    let tap = (c * k + ki) * k + kj;
                    let ix = ox_lo * s + kj * d - g.pad_left;
                    for oy in oy_lo..oy_hi {
                        let iy = oy * s + ki * d - g.pad_top;
                        f(tap, oy * g.ow + ox_lo, (c * g.h + iy) * g.w + ix, ox_hi - ox_lo);
                    }
                }
            }
        }
    }

    /// Sample `i` of a group's columns: cols [K × stride] ← taps of x_n [c_in][h][w] into
    /// columns `i·P .. (i+1)·P` of every row, zero in the padding.
    fn im2col(&self, g: &Geometry, x_n: &[f32], cols: &mut [f32], (stride, i): (usize, usize)) {
        let (s, p) = (self.stride, g.pixels());
        for row in cols.chunks_exact_mut(stride) {
            row[i * p..(i + 1) * p].fill(0.0);
        }
        self.for_each_run(g, |tap, pixel, x, len| {
            let at = tap * stride + i * p + pixel;
            let dst = &mut cols[at..at + len];
            // Bounded source slice: the strided gather compiles without per-element checks.
            let src = &x_n[x..x + (len - 1) * s + 1];
            for (j, d) in dst.iter_mut().enumerate() {
                *d = src[j * s];
            }
        });
    }

    /// dx_n [c_in][h][w] += scatter of sample `i`'s columns of dcols [K × stride] (the adjoint of `im2col`).
    fn col2im(&self, g: &Geometry, dcols: &[f32], (stride, i): (usize, usize), dx_n: &mut [f32]) {
        let (s, p) = (self.stride, g.pixels());
        self.for_each_run(g, |tap, pixel, x, len| {
            let at = tap * stride + i * p + pixel;
            let src = &dcols[at..at + len];
            let dst = &mut dx_n[x..x + (len - 1) * s + 1];
            for (j, v) in src.iter().enumerate() {
                dst[j * s] += *v;
            }
        });
    }

    /// Samples per im2col GEMM: enough columns (≈ 4,096) that small outputs (a 2 × 2 map in SAC's
    /// last layer) still make one efficient GEMM, few enough that the columns stay in cache.
    fn group(&self, g: &Geometry, n: usize) -> usize {
        (4096 / g.pixels().max(1)).clamp(1, n.max(1))
    }

    /// Shared length checks of forward/backward; `y_len` is y's (or dy's) length.
    fn check_shapes(
        &self,
        weight: &[f32],
        x: &[f32],
        n: usize,
        g: &Geometry,
        y_len: usize,
        y_slice: (usize, usize),
    ) {
        let (yc, yo) = y_slice;
        assert!(self.kernel >= 1 && self.stride >= 1 && self.dilation >= 1, "degenerate conv {self:?}");
        assert_eq!(weight.len(), self.weight_len(), "weight length");
        assert_eq!(x.len(), n * self.c_in * g.h * g.w, "x length");
        assert!(yo + self.c_out <= yc, "channel slice {yo}+{} exceeds {yc} channels", self.c_out);
        assert_eq!(y_len, n * yc * g.pixels(), "y length");
    }

    /// x [n][c_in][h][w] → writes (overwrites) channels y_offset..y_offset+c_out of y [n][y_channels][oh][ow].
    #[allow(clippy::too_many_arguments)]
    pub fn forward(
        &self,
        weight: &[f32],
        bias: &[f32],
        x: &[f32],
        n: usize,
        h: usize,
        w: usize,
        y: &mut [f32],
        y_channels: usize,
        y_offset: usize,
        scratch: &mut Vec<f32>,
    ) {
        let g = self.geometry(h, w);
        self.check_shapes(weight, x, n, &g, y.len(), (y_channels, y_offset));
        assert_eq!(bias.len(), self.c_out, "bias length");
        #[cfg(target_arch = "x86_64")]
        if self.stride == 1 && direct::available() {
            return self.forward_direct(&g, weight, bias, x, y, y_channels, y_offset, scratch);
        }
        #[cfg(target_arch = "x86_64")]
        if self.runs_strided(false) {
            return self.forward_strided(&g, weight, bias, x, n, y, (y_channels, y_offset), scratch);
        }
        self.forward_im2col(&g, weight, bias, x, y, y_channels, y_offset, scratch);
    }

    /// Whether `forward_channel_last` / `backward_channel_last` (with dx if `with_dx`) run for this
    /// conv on this CPU: AVX-512 and a stride > 1 'valid' conv whose output channels (and, for dx,
    /// input channels) fill whole vectors.
    pub fn runs_channel_last(&self, with_dx: bool) -> bool {
        #[cfg(target_arch = "x86_64")]
        return self.runs_strided(with_dx);
        #[cfg(not(target_arch = "x86_64"))]
        return false;
    }

    /// `weight` [c_out][c_in][k][k] as `forward_channel_last` reads it, [c_in·k·k][c_out]: laid out
    /// once per pass, not once per call, where a caller walks its samples in small groups.
    pub fn channel_last_weight(&self, weight: &[f32], wt: &mut Vec<f32>) {
        assert!(self.runs_channel_last(false), "{self:?} has no channel-last path on this CPU");
        assert_eq!(weight.len(), self.weight_len(), "weight length");
        wt.resize(self.weight_len(), 0.0);
        #[cfg(target_arch = "x86_64")]
        transpose::transpose(weight, self.c_out, self.taps(), wt, false);
    }

    /// `forward` for chains of strided convs (SAC's encoders) that keep their activations
    /// channel-last, so no layer transposes its output: x is [n][c_in][h][w], or [n][h][w][c_in]
    /// if `x_channel_last`; writes y [n][oh][ow][c_out], through a ReLU if `relu`. `wt` is the
    /// weight from `channel_last_weight`. Only where `runs_channel_last(false)`.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_channel_last(
        &self,
        wt: &[f32],
        bias: &[f32],
        x: &[f32],
        x_channel_last: bool,
        n: usize,
        (h, w): (usize, usize),
        y: &mut [f32],
        relu: bool,
    ) {
        assert!(self.runs_channel_last(false), "{self:?} has no channel-last path on this CPU");
        let g = self.geometry(h, w);
        self.check_shapes(wt, x, n, &g, y.len(), (self.c_out, 0));
        assert_eq!(bias.len(), self.c_out, "bias length");
        #[cfg(target_arch = "x86_64")]
        self.forward_strided_channel_last(&g, wt, bias, x, x_channel_last, n, y, relu);
    }

    /// `backward` of `forward_channel_last`: dy is [n][oh][ow][c_out]; accumulates (+=) into
    /// dweight, dbias and (if Some, which needs a channel-last x) dx [n][h][w][c_in].
    #[allow(clippy::too_many_arguments)]
    pub fn backward_channel_last(
        &self,
        weight: &[f32],
        x: &[f32],
        x_channel_last: bool,
        n: usize,
        (h, w): (usize, usize),
        dy: &[f32],
        dweight: &mut [f32],
        dbias: &mut [f32],
        dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
    ) {
        assert!(self.runs_channel_last(dx.is_some()), "{self:?} has no channel-last path on this CPU");
        assert!(dx.is_none() || x_channel_last, "dx comes out channel-last, so x must be");
        let g = self.geometry(h, w);
        self.check_shapes(weight, x, n, &g, dy.len(), (self.c_out, 0));
        assert_eq!(dweight.len(), self.weight_len(), "dweight length");
        assert_eq!(dbias.len(), self.c_out, "dbias length");
        if let Some(dx) = dx.as_deref() {
            assert_eq!(dx.len(), x.len(), "dx length");
        }
        #[cfg(target_arch = "x86_64")]
        self.backward_strided_channel_last(&g, weight, x, x_channel_last, n, dy, dweight, dbias, dx, scratch);
    }

    /// Groups of samples share one GEMM: W [c_out × K] · cols [K × G·P], then each sample's
    /// block is copied (plus bias) into its channel slice.
    #[allow(clippy::too_many_arguments)]
    fn forward_im2col(
        &self,
        g: &Geometry,
        weight: &[f32],
        bias: &[f32],
        x: &[f32],
        y: &mut [f32],
        y_channels: usize,
        y_offset: usize,
        scratch: &mut Vec<f32>,
    ) {
        let (k, p, x_len) = (self.taps(), g.pixels(), self.c_in * g.h * g.w);
        let n = x.len() / x_len.max(1);
        let group = self.group(g, n);
        let need = k * group * p + self.c_out * group * p;
        if scratch.len() < need {
            scratch.resize(need, 0.0);
        }
        let (cols, out) = scratch[..need].split_at_mut(k * group * p);
        let wm = MatRef::row_major(weight, self.c_out, k);
        for (x_g, y_g) in x.chunks(group * x_len).zip(y.chunks_mut(group * y_channels * p)) {
            let m = x_g.len() / x_len;
            let stride = m * p;
            for (i, x_n) in x_g.chunks_exact(x_len).enumerate() {
                self.im2col(g, x_n, &mut cols[..k * stride], (stride, i));
            }
            let out = &mut out[..self.c_out * stride];
            matmul(
                MatMut::row_major(out, self.c_out, stride),
                wm,
                MatRef::row_major(&cols[..k * stride], k, stride),
                false,
            );
            for (i, y_n) in y_g.chunks_exact_mut(y_channels * p).enumerate() {
                let y_slice = &mut y_n[y_offset * p..(y_offset + self.c_out) * p];
                for ((dst, src), &b) in y_slice.chunks_exact_mut(p).zip(out.chunks_exact(stride)).zip(bias) {
                    dst.iter_mut().zip(&src[i * p..(i + 1) * p]).for_each(|(d, v)| *d = v + b);
                }
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    fn forward_direct(
        &self,
        g: &Geometry,
        weight: &[f32],
        bias: &[f32],
        x: &[f32],
        y: &mut [f32],
        y_channels: usize,
        y_offset: usize,
        scratch: &mut Vec<f32>,
    ) {
        let p = g.pixels();
        if p == 0 {
            return;
        }
        let plan = self.plan(g);
        let len = plan.padded_len();
        if scratch.len() < len {
            scratch.resize(len, 0.0);
        }
        let xpad = &mut scratch[..len];
        for (x_n, y_n) in x.chunks_exact(self.c_in * g.h * g.w).zip(y.chunks_exact_mut(y_channels * p)) {
            plan.pad_input(x_n, xpad);
            plan.forward(weight, bias, xpad, &mut y_n[y_offset * p..(y_offset + self.c_out) * p]);
        }
    }

    /// Reads dy's channel slice; accumulates (+=) into dweight, dbias and (if Some) dx [n][c_in][h][w].
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        weight: &[f32],
        x: &[f32],
        n: usize,
        h: usize,
        w: usize,
        dy: &[f32],
        y_channels: usize,
        y_offset: usize,
        dweight: &mut [f32],
        dbias: &mut [f32],
        dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
    ) {
        let g = self.geometry(h, w);
        self.check_shapes(weight, x, n, &g, dy.len(), (y_channels, y_offset));
        assert_eq!(dweight.len(), self.weight_len(), "dweight length");
        assert_eq!(dbias.len(), self.c_out, "dbias length");
        if let Some(dx) = dx.as_deref() {
            assert_eq!(dx.len(), x.len(), "dx length");
        }
        let dy_slice = (y_channels, y_offset);
        #[cfg(target_arch = "x86_64")]
        if self.stride == 1 && direct::available() {
            return self.backward_direct(&g, weight, x, dy, dy_slice, dweight, dbias, dx, scratch);
        }
        #[cfg(target_arch = "x86_64")]
        if self.runs_strided(dx.is_some()) {
            return self.backward_strided(&g, weight, x, n, dy, dy_slice, dweight, dbias, dx, scratch);
        }
        self.backward_im2col(&g, weight, x, dy, dy_slice, dweight, dbias, dx, scratch);
    }

    /// Per group of samples: dW += dY [c_out × G·P] · colsᵀ, dcols = Wᵀ · dY, scattered back.
    #[allow(clippy::too_many_arguments)]
    fn backward_im2col(
        &self,
        g: &Geometry,
        weight: &[f32],
        x: &[f32],
        dy: &[f32],
        (y_channels, y_offset): (usize, usize),
        dweight: &mut [f32],
        dbias: &mut [f32],
        mut dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
    ) {
        let (k, p, x_len) = (self.taps(), g.pixels(), self.c_in * g.h * g.w);
        let n = x.len() / x_len.max(1);
        let group = self.group(g, n);
        let cols_len = k * group * p;
        let need = 2 * cols_len + self.c_out * group * p;
        if scratch.len() < need {
            scratch.resize(need, 0.0);
        }
        let (cols, rest) = scratch[..need].split_at_mut(cols_len);
        let (dcols, dy_g) = rest.split_at_mut(cols_len);
        let wm = MatRef::row_major(weight, self.c_out, k);
        for (first, x_g) in (0..n).step_by(group).zip(x.chunks(group * x_len)) {
            let m = x_g.len() / x_len;
            let stride = m * p;
            let dym = &mut dy_g[..self.c_out * stride];
            for (i, x_n) in x_g.chunks_exact(x_len).enumerate() {
                self.im2col(g, x_n, &mut cols[..k * stride], (stride, i));
                let at = ((first + i) * y_channels + y_offset) * p;
                for (o, src) in dy[at..at + self.c_out * p].chunks_exact(p).enumerate() {
                    dym[o * stride + i * p..o * stride + (i + 1) * p].copy_from_slice(src);
                }
            }
            let dy_mat = MatRef::row_major(dym, self.c_out, stride);
            // dW [c_out × K] += dY [c_out × G·P] · colsᵀ [G·P × K]
            matmul(
                MatMut::row_major(dweight, self.c_out, k),
                dy_mat,
                MatRef::row_major(&cols[..k * stride], k, stride).t(),
                true,
            );
            for (db, row) in dbias.iter_mut().zip(dym.chunks_exact(stride)) {
                *db += sum(row);
            }
            if let Some(dx) = dx.as_deref_mut() {
                // dcols [K × G·P] = Wᵀ [K × c_out] · dY, then scattered back onto each sample's pixels.
                matmul(MatMut::row_major(&mut dcols[..k * stride], k, stride), wm.t(), dy_mat, false);
                for i in 0..m {
                    let dx_n = &mut dx[(first + i) * x_len..(first + i + 1) * x_len];
                    self.col2im(g, &dcols[..k * stride], (stride, i), dx_n);
                }
            }
        }
    }
}

impl Conv2d {
    /// The direct kernels' plan of this conv on one call's geometry.
    #[cfg(target_arch = "x86_64")]
    fn plan(&self, g: &Geometry) -> direct::Plan {
        direct::Plan {
            c_in: self.c_in,
            c_out: self.c_out,
            kernel: self.kernel,
            dilation: self.dilation,
            h: g.h,
            w: g.w,
            oh: g.oh,
            ow: g.ow,
            pad_top: g.pad_top,
            pad_left: g.pad_left,
        }
    }

    /// Stride-1 backward without im2col. dweight by `direct::Plan::backward_weight`; dx as the
    /// forward kernel run on dy with the kernel flipped and c_in, c_out swapped (a stride-1
    /// conv's adjoint is the "full" correlation with the flipped kernel), accumulating into dx.
    /// Measured per filter step (examples/train_profile.rs, K = 30, single-threaded): the map
    /// encoder's 4@3×3 + 4@5×5 over 64 channels 28.5 ms → 3.2 ms, its five c_in = 1 convs 6.3 ms
    /// → 1.2 ms; the observation encoder's 16@3×3 over 384 channels 6.5 ms → 2.1 ms.
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    fn backward_direct(
        &self,
        g: &Geometry,
        weight: &[f32],
        x: &[f32],
        dy: &[f32],
        (y_channels, y_offset): (usize, usize),
        dweight: &mut [f32],
        dbias: &mut [f32],
        mut dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
    ) {
        let (p, x_len, k) = (g.pixels(), self.c_in * g.h * g.w, self.kernel);
        if p == 0 {
            return;
        }
        let plan = self.plan(g);
        let span = (k - 1) * self.dilation;
        let adjoint = direct::Plan {
            c_in: self.c_out,
            c_out: self.c_in,
            h: g.oh,
            w: g.ow,
            oh: g.h,
            ow: g.w,
            pad_top: span - g.pad_top,
            pad_left: span - g.pad_left,
            ..plan
        };
        let (x_pad_len, dy_pad_len) = (plan.padded_len(), adjoint.padded_len());
        let need = x_pad_len + if dx.is_some() { dy_pad_len + self.weight_len() } else { 0 };
        if scratch.len() < need {
            scratch.resize(need, 0.0);
        }
        let (xpad, rest) = scratch[..need].split_at_mut(x_pad_len);
        let (dypad, flipped) = rest.split_at_mut(if dx.is_some() { dy_pad_len } else { 0 });
        if dx.is_some() {
            // flipped [c_in][c_out][k][k] = weight [c_out][c_in][k−1−ki][k−1−kj]
            for o in 0..self.c_out {
                for c in 0..self.c_in {
                    let src = &weight[(o * self.c_in + c) * k * k..][..k * k];
                    let dst = &mut flipped[(c * self.c_out + o) * k * k..][..k * k];
                    for (d, v) in dst.iter_mut().zip(src.iter().rev()) {
                        *d = *v;
                    }
                }
            }
        }
        for (i, x_n) in x.chunks_exact(x_len).enumerate() {
            let dy_n = &dy[(i * y_channels + y_offset) * p..][..self.c_out * p];
            plan.pad_input(x_n, xpad);
            plan.backward_weight(dy_n, xpad, dweight);
            for (db, row) in dbias.iter_mut().zip(dy_n.chunks_exact(p)) {
                *db += sum(row);
            }
            if let Some(dx) = dx.as_deref_mut() {
                adjoint.pad_input(dy_n, dypad);
                adjoint.accumulate(flipped, dypad, &mut dx[i * x_len..][..x_len]);
            }
        }
    }
}

/// Σ v in 16 independent partial sums: a plain `iter().sum()` is one serial chain of adds
/// (4 cycles each), which cost more than the direct dweight kernels themselves on PF-net's maps.
fn sum(v: &[f32]) -> f32 {
    let mut acc = [0.0f32; 16];
    let chunks = v.chunks_exact(16);
    let tail: f32 = chunks.remainder().iter().sum();
    for c in chunks {
        for (a, x) in acc.iter_mut().zip(c) {
            *a += x;
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// Keras/TensorFlow kernel [kh][kw][c_in][c_out] (HWIO) → ours [c_out][c_in][kh][kw].
pub fn weight_from_hwio(hwio: &[f32], kernel: usize, c_in: usize, c_out: usize) -> Vec<f32> {
    let k = kernel;
    assert_eq!(hwio.len(), k * k * c_in * c_out, "HWIO kernel length");
    let mut ours = vec![0.0; hwio.len()];
    for ki in 0..k {
        for kj in 0..k {
            for c in 0..c_in {
                for o in 0..c_out {
                    ours[((o * c_in + c) * k + ki) * k + kj] = hwio[((ki * k + kj) * c_in + c) * c_out + o];
                }
            }
        }
    }
    ours
}

/// Our kernel `old` ([c_out][c_in][kh][kw]) in `wide`, a kernel of the same outputs and taps with
/// more input channels: the old channels become channels `first..` of every output, every other
/// weight is 0 — a network widened to a new input that it ignores until trained.
pub fn widen_input_channels(old: &[f32], wide: &mut [f32], c_out: usize, taps: usize, first: usize) {
    let (per_old, per_new) = (old.len() / c_out, wide.len() / c_out);
    assert!(first * taps + per_old <= per_new, "the old channels fit in the wide kernel at `first`");
    wide.fill(0.0);
    for (o, n) in old.chunks_exact(per_old).zip(wide.chunks_exact_mut(per_new)) {
        n[first * taps..][..per_old].copy_from_slice(o);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad, test_values};

    const TOL: f64 = 1e-4;

    fn f64s(v: &[f32]) -> Vec<f64> {
        v.iter().map(|&a| f64::from(a)).collect()
    }

    /// Direct f64 convolution: [n][c_out][oh][ow], skipping taps in the padding.
    fn naive(conv: &Conv2d, wt: &[f64], b: &[f64], x: &[f64], n: usize, h: usize, w: usize) -> Vec<f64> {
        let (k, s, d) = (conv.kernel, conv.stride, conv.dilation);
        let (oh, pt) = conv.padding.output_and_pad_before(h, k, s, d);
        let (ow, pl) = conv.padding.output_and_pad_before(w, k, s, d);
        let mut y = vec![0.0; n * conv.c_out * oh * ow];
        for i in 0..n {
            for o in 0..conv.c_out {
                for oy in 0..oh {
                    for ox in 0..ow {
                        let mut acc = b[o];
                        for c in 0..conv.c_in {
                            for ki in 0..k {
                                for kj in 0..k {
                                    let iy = (oy * s + ki * d) as isize - pt as isize;
                                    let ix = (ox * s + kj * d) as isize - pl as isize;
                                    if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                                        continue;
                                    }
                                    let xi = ((i * conv.c_in + c) * h + iy as usize) * w + ix as usize;
                                    acc += wt[((o * conv.c_in + c) * k + ki) * k + kj] * x[xi];
                                }
                            }
                        }
                        y[((i * conv.c_out + o) * oh + oy) * ow + ox] = acc;
                    }
                }
            }
        }
        y
    }

    /// Forward vs naive, backward (dx, dW, db) vs finite differences of naive with loss = Σ y ⊙ r,
    /// then a second backward must double every gradient.
    fn check(conv: Conv2d, n: usize, h: usize, w: usize, y_channels: usize, y_offset: usize, seed: u64) {
        check_path(conv, n, h, w, (y_channels, y_offset), seed, false);
    }

    /// `check`, with the backward forced through im2col + GEMM when `im2col` (the path of strides
    /// > 1 and of CPUs without AVX-512) instead of the dispatch's choice.
    fn check_path(
        conv: Conv2d,
        n: usize,
        h: usize,
        w: usize,
        (y_channels, y_offset): (usize, usize),
        seed: u64,
        im2col: bool,
    ) {
        type Grads<'a> = (&'a mut [f32], &'a mut [f32], Option<&'a mut [f32]>);
        let backward = |wt: &[f32], x: &[f32], r: &[f32], (dw, db, dx): Grads, scratch: &mut Vec<f32>| {
            if im2col {
                let g = conv.geometry(h, w);
                conv.backward_im2col(&g, wt, x, r, (y_channels, y_offset), dw, db, dx, scratch);
            } else {
                conv.backward(wt, x, n, h, w, r, y_channels, y_offset, dw, db, dx, scratch);
            }
        };
        let (oh, ow) = conv.output_size(h, w);
        let p = oh * ow;
        assert!(p > 0);
        let wt = test_values(conv.weight_len(), seed);
        let b = test_values(conv.c_out, seed + 1);
        let x = test_values(n * conv.c_in * h * w, seed + 2);
        let r = test_values(n * y_channels * p, seed + 3); // dy over the whole output tensor
        // Stale garbage in an oversized scratch must not leak into results.
        let mut scratch = vec![f32::NAN; 7];

        let mut y = vec![f32::NAN; n * y_channels * p];
        conv.forward(&wt, &b, &x, n, h, w, &mut y, y_channels, y_offset, &mut scratch);
        let slice = |t: &[f32], i: usize| t[(i * y_channels + y_offset) * p..][..conv.c_out * p].to_vec();
        let got: Vec<f32> = (0..n).flat_map(|i| slice(&y, i)).collect();
        let want = naive(&conv, &f64s(&wt), &f64s(&b), &f64s(&x), n, h, w);
        assert_close(&got, &want, TOL, "forward");
        let untouched = y.len() - n * conv.c_out * p;
        assert_eq!(y.iter().filter(|v| v.is_nan()).count(), untouched, "wrote outside its channel slice");

        let r_slice = f64s(&(0..n).flat_map(|i| slice(&r, i)).collect::<Vec<_>>());
        let loss = |wt: &[f64], b: &[f64], x: &[f64]| -> f64 {
            naive(&conv, wt, b, x, n, h, w).iter().zip(&r_slice).map(|(a, b)| a * b).sum()
        };
        let (wt64, b64, x64) = (f64s(&wt), f64s(&b), f64s(&x));
        let want_dx = numerical_grad(&x64, 1e-3, |v| loss(&wt64, &b64, v));
        let want_dw = numerical_grad(&wt64, 1e-3, |v| loss(v, &b64, &x64));
        let want_db = numerical_grad(&b64, 1e-3, |v| loss(&wt64, v, &x64));

        let mut dw = vec![0.0; wt.len()];
        let mut db = vec![0.0; b.len()];
        let mut dx = vec![0.0; x.len()];
        scratch.iter_mut().for_each(|v| *v = f32::NAN);
        for pass in 1..=2 {
            let dx_arg = Some(&mut dx[..]);
            backward(&wt, &x, &r, (&mut dw, &mut db, dx_arg), &mut scratch);
            let scale = |v: &[f64]| v.iter().map(|a| a * pass as f64).collect::<Vec<_>>();
            assert_close(&dx, &scale(&want_dx), TOL, &format!("dx pass {pass}"));
            assert_close(&dw, &scale(&want_dw), TOL, &format!("dweight pass {pass}"));
            assert_close(&db, &scale(&want_db), TOL, &format!("dbias pass {pass}"));
        }

        // Without dx the parameter gradients are the same.
        let (mut dw1, mut db1) = (vec![0.0; wt.len()], vec![0.0; b.len()]);
        backward(&wt, &x, &r, (&mut dw1, &mut db1, None), &mut scratch);
        assert_close(&dw1, &want_dw, TOL, "dweight without dx");
        assert_close(&db1, &want_db, TOL, "dbias without dx");
    }

    fn conv(
        c_in: usize,
        c_out: usize,
        kernel: usize,
        stride: usize,
        dilation: usize,
        padding: Padding,
    ) -> Conv2d {
        Conv2d { c_in, c_out, kernel, stride, dilation, padding }
    }

    #[test]
    fn padding_follows_tensorflow() {
        use Padding::{Same, Valid};
        assert_eq!(Same.output_and_pad_before(28, 3, 1, 1), (28, 1));
        assert_eq!(Same.output_and_pad_before(28, 7, 1, 3), (28, 9));
        assert_eq!(Same.output_and_pad_before(56, 5, 1, 4), (56, 8));
        // k=3 s=2 on an even input: total 1, TF pads 0 before and 1 after.
        assert_eq!(Same.output_and_pad_before(6, 3, 2, 1), (3, 0));
        assert_eq!(Same.output_and_pad_before(7, 3, 2, 1), (4, 1));
        assert_eq!(Same.output_and_pad_before(5, 1, 2, 1), (3, 0));
        assert_eq!(Valid.output_and_pad_before(50, 3, 2, 1), (24, 0));
        assert_eq!(Valid.output_and_pad_before(24, 3, 2, 1), (11, 0));
        assert_eq!(Valid.output_and_pad_before(9, 3, 1, 2), (5, 0));
        assert_eq!(Valid.output_and_pad_before(4, 5, 1, 1), (0, 0));
        let c = conv(4, 32, 3, 2, 1, Valid);
        assert_eq!(c.output_size(50, 48), (24, 23));
        assert_eq!(c.weight_len(), 32 * 4 * 9);
    }

    #[test]
    fn same_dilation_2_odd_size() {
        check(conv(3, 4, 3, 1, 2, Padding::Same), 2, 7, 5, 4, 0, 10);
    }

    #[test]
    fn valid_stride_2() {
        check(conv(2, 3, 3, 2, 1, Padding::Valid), 2, 9, 8, 3, 0, 20);
    }

    #[test]
    fn same_stride_2_even_size() {
        assert_eq!(Padding::Same.output_and_pad_before(6, 3, 2, 1), (3, 0));
        check(conv(2, 3, 3, 2, 1, Padding::Same), 2, 6, 6, 3, 0, 30);
        check(conv(2, 2, 5, 2, 2, Padding::Same), 1, 8, 7, 2, 0, 35);
    }

    #[test]
    fn single_channel_into_offset_slice_with_padding_wider_than_input() {
        // Dilated span 9 > 8 input pixels: some taps never land inside the image.
        check(conv(1, 3, 5, 1, 2, Padding::Same), 2, 8, 8, 7, 2, 40);
        check(conv(2, 2, 3, 1, 1, Padding::Same), 2, 5, 5, 6, 4, 50);
    }

    #[test]
    fn direct_kernel_shapes() {
        // Channel and slot tails of both register tiles (c_out 6 → 4×6 tiles, 16 → 8×3), rows wider
        // than one vector with a masked tail (ow 21), dilation 3 with padding wider than the input,
        // 'valid' padding, several input channels.
        check(conv(1, 6, 7, 1, 3, Padding::Same), 2, 21, 19, 9, 2, 60);
        check(conv(3, 16, 5, 1, 1, Padding::Same), 2, 14, 14, 20, 3, 70);
        check(conv(2, 4, 3, 1, 2, Padding::Valid), 1, 11, 37, 4, 0, 80);
    }

    /// The direct backward's tiles: dweight tiles 8 channels × 3 taps (k ≤ 3, c_out a multiple of
    /// 8), 4 × 3, 4 × 5 and 3 × 7 with channel tails and a kernel wider than one tap block (k = 9);
    /// dx (the forward kernel on dy) with c_in a multiple of 8 and not; rows wider than 16 lanes.
    #[test]
    fn direct_backward_tiles() {
        check(conv(9, 8, 3, 1, 1, Padding::Same), 2, 5, 19, 8, 0, 90);
        check(conv(8, 5, 3, 1, 2, Padding::Same), 1, 7, 6, 7, 1, 91);
        check(conv(3, 6, 5, 1, 1, Padding::Valid), 2, 9, 8, 6, 0, 92);
        check(conv(2, 4, 7, 1, 2, Padding::Same), 1, 9, 17, 5, 1, 93);
        check(conv(1, 2, 9, 1, 1, Padding::Same), 2, 10, 9, 2, 0, 94);
        check(conv(2, 3, 2, 1, 1, Padding::Same), 1, 6, 5, 3, 0, 95);
    }

    /// The channels-in-lanes strided path (`strided.rs`): SAC's odd sizes 27 → 13 → 6 → 2 with
    /// c_in = 1 (only its dweight runs there: dx needs c_in in whole vectors, so it takes im2col)
    /// and c_in > 16, 16-channel tiles (c_out 16), a 32-channel tile with a tail (48), a 64-channel
    /// tile (64), pixel tails, dilation 2, stride 3, n up to 3, into channel slices.
    #[test]
    fn strided_kernel_shapes() {
        use Padding::Valid;
        let shapes = [
            (conv(1, 16, 3, 2, 1, Valid), 2, 27, 27, (20, 3)),
            (conv(16, 16, 3, 2, 1, Valid), 2, 13, 13, (16, 0)),
            (conv(32, 16, 3, 2, 1, Valid), 3, 6, 6, (40, 8)),
            (conv(16, 48, 3, 2, 1, Valid), 1, 7, 8, (50, 1)),
            (conv(16, 32, 3, 2, 2, Valid), 2, 11, 9, (32, 0)),
            (conv(16, 16, 2, 3, 1, Valid), 1, 8, 10, (17, 1)),
            (conv(16, 64, 3, 2, 1, Valid), 1, 7, 8, (70, 3)),
        ];
        for (seed, (c, n, h, w, slice)) in (110..).zip(shapes) {
            #[cfg(target_arch = "x86_64")]
            assert!(!direct::available() || c.runs_strided(false), "{c:?} must take the strided path");
            check(c, n, h, w, slice.0, slice.1, seed);
        }
    }

    /// The strided path splits a call into groups of samples; a 3-sample call split 2 + 1 must
    /// give what three 1-sample calls give.
    #[test]
    fn strided_groups_match_single_samples() {
        let (c, n, side) = (conv(16, 16, 3, 2, 1, Padding::Valid), 3, 21);
        #[cfg(target_arch = "x86_64")]
        assert_eq!(Conv2d::strided_group(c.c_in * side * side, n), 2, "the call must split into groups");
        let (x_len, (oh, ow)) = (c.c_in * side * side, c.output_size(side, side));
        let y_len = c.c_out * oh * ow;
        let (wt, b) = (test_values(c.weight_len(), 120), test_values(c.c_out, 121));
        let (x, dy) = (test_values(n * x_len, 122), test_values(n * y_len, 123));
        let mut scratch = Vec::new();
        let run = |x: &[f32], dy: &[f32], m: usize, scratch: &mut Vec<f32>| {
            let mut y = vec![0.0; m * y_len];
            c.forward(&wt, &b, x, m, side, side, &mut y, c.c_out, 0, scratch);
            let (mut dw, mut db, mut dx) = (vec![0.0; wt.len()], vec![0.0; b.len()], vec![0.0; x.len()]);
            c.backward(&wt, x, m, side, side, dy, c.c_out, 0, &mut dw, &mut db, Some(&mut dx), scratch);
            [y, dw, db, dx]
        };
        let whole = run(&x, &dy, n, &mut scratch);
        let mut single = [vec![], vec![0.0; wt.len()], vec![0.0; b.len()], vec![]];
        for i in 0..n {
            let [y, dw, db, dx] = run(&x[i * x_len..][..x_len], &dy[i * y_len..][..y_len], 1, &mut scratch);
            single[0].extend(y);
            single[1].iter_mut().zip(dw).for_each(|(a, v)| *a += v);
            single[2].iter_mut().zip(db).for_each(|(a, v)| *a += v);
            single[3].extend(dx);
        }
        for ((got, want), what) in whole.iter().zip(&single).zip(["y", "dweight", "dbias", "dx"]) {
            assert_close(got, &f64s(want), 1e-6, what);
        }
    }

    /// The channel-last path gives the channel-major path's y, dweight, dbias and dx, transposed:
    /// from a channel-major x (an encoder's first layer, no dx) and from a channel-last one, over
    /// several sample groups, with 16-, 32- and 64-channel tiles and pixel tails.
    #[test]
    fn channel_last_matches_channel_major() {
        use Padding::Valid;
        /// [n][c][p] → [n][p][c]
        fn to_last(v: &[f32], n: usize, c: usize, p: usize) -> Vec<f32> {
            (0..n * p * c).map(|j| v[(j / (p * c) * c + j % c) * p + j / c % p]).collect()
        }
        let shapes = [
            (conv(4, 16, 3, 2, 1, Valid), 3, 27, false),
            (conv(16, 32, 3, 2, 1, Valid), 3, 23, true),
            (conv(32, 64, 3, 2, 1, Valid), 2, 13, true),
        ];
        for (seed, (c, n, side, x_last)) in (130..).zip(shapes) {
            if !c.runs_channel_last(x_last) {
                eprintln!("skipping: no channel-last path on this CPU");
                return;
            }
            let ((oh, ow), hw) = (c.output_size(side, side), side * side);
            let (wt, b) = (test_values(c.weight_len(), seed), test_values(c.c_out, seed + 1));
            let x = test_values(n * c.c_in * hw, seed + 2);
            let dy = test_values(n * c.c_out * oh * ow, seed + 3);
            let mut scratch = Vec::new();
            let mut y = vec![0.0; dy.len()];
            c.forward(&wt, &b, &x, n, side, side, &mut y, c.c_out, 0, &mut scratch);
            let (mut dw, mut db, mut dx) = (vec![0.0; wt.len()], vec![0.0; b.len()], vec![0.0; x.len()]);
            let dx_major = x_last.then_some(&mut dx[..]);
            c.backward(&wt, &x, n, side, side, &dy, c.c_out, 0, &mut dw, &mut db, dx_major, &mut scratch);

            let x_in = if x_last { to_last(&x, n, c.c_in, hw) } else { x.clone() };
            let dy_last = to_last(&dy, n, c.c_out, oh * ow);
            let (mut y_last, mut w_last) = (vec![f32::NAN; y.len()], Vec::new());
            c.channel_last_weight(&wt, &mut w_last);
            c.forward_channel_last(&w_last, &b, &x_in, x_last, n, (side, side), &mut y_last, false);
            let (mut dw_l, mut db_l, mut dx_l) =
                (vec![0.0; wt.len()], vec![0.0; b.len()], vec![0.0; x.len()]);
            let dx_last = x_last.then_some(&mut dx_l[..]);
            c.backward_channel_last(
                &wt,
                &x_in,
                x_last,
                n,
                (side, side),
                &dy_last,
                &mut dw_l,
                &mut db_l,
                dx_last,
                &mut scratch,
            );
            assert_close(&y_last, &f64s(&to_last(&y, n, c.c_out, oh * ow)), 1e-6, "y");
            assert_close(&dw_l, &f64s(&dw), 1e-6, "dweight");
            assert_close(&db_l, &f64s(&db), 1e-6, "dbias");
            if x_last {
                assert_close(&dx_l, &f64s(&to_last(&dx, n, c.c_in, hw)), 1e-6, "dx");
            }
        }
    }

    /// The im2col backward on stride-1 shapes, which the dispatch sends to the direct kernels.
    #[test]
    fn im2col_backward_matches_finite_differences() {
        check_path(conv(3, 4, 3, 1, 2, Padding::Same), 2, 7, 5, (6, 1), 100, true);
        check_path(conv(2, 3, 5, 1, 1, Padding::Valid), 1, 8, 9, (3, 0), 101, true);
    }

    /// The im2col forward (taken for strides > 1 and on CPUs without AVX-512) against naive on
    /// stride-1 shapes, which the dispatch would otherwise send to the direct kernel.
    #[test]
    fn im2col_forward_matches_naive() {
        for (c, h, w) in
            [(conv(3, 5, 3, 1, 2, Padding::Same), 7, 5), (conv(1, 8, 7, 1, 3, Padding::Same), 9, 8)]
        {
            let (n, (oh, ow)) = (2, c.output_size(h, w));
            let wt = test_values(c.weight_len(), 1);
            let b = test_values(c.c_out, 2);
            let x = test_values(n * c.c_in * h * w, 3);
            let mut y = vec![f32::NAN; n * c.c_out * oh * ow];
            c.forward_im2col(&c.geometry(h, w), &wt, &b, &x, &mut y, c.c_out, 0, &mut Vec::new());
            let want = naive(&c, &f64s(&wt), &f64s(&b), &f64s(&x), n, h, w);
            assert_close(&y, &want, TOL, "im2col forward");
        }
    }

    #[test]
    fn hwio_conversion() {
        // k=1, c_in=2, c_out=3: hwio[c][o] = 3c + o → ours[o][c].
        let hwio: Vec<f32> = (0..6).map(|v| v as f32).collect();
        assert_eq!(weight_from_hwio(&hwio, 1, 2, 3), vec![0.0, 3.0, 1.0, 4.0, 2.0, 5.0]);
        // k=2, c_in=1, c_out=2: hwio[kh][kw][0][o] = 2(2kh + kw) + o → ours[o][0][kh][kw].
        let hwio: Vec<f32> = (0..8).map(|v| v as f32).collect();
        assert_eq!(weight_from_hwio(&hwio, 2, 1, 2), vec![0.0, 2.0, 4.0, 6.0, 1.0, 3.0, 5.0, 7.0]);
    }

    #[test]
    fn widened_kernels_keep_each_outputs_old_taps_at_their_channel() {
        // 2 outputs × 1 channel × 2 taps → 2 outputs × 3 channels, the old one as channel 1.
        let mut wide = vec![9.0; 12];
        widen_input_channels(&[1.0, 2.0, 3.0, 4.0], &mut wide, 2, 2, 1);
        assert_eq!(wide, [0.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 3.0, 4.0, 0.0, 0.0]);
    }
}
