//! The two building blocks PF-net's encoders repeat: parallel convolutions concatenated along
//! channels, and LayerNorm followed by ReLU.

use super::config::ConvBranch;
use crate::nn::activation::relu_forward;
use crate::nn::buffers::{sized, zeroed};
use crate::nn::conv::{Conv2d, Padding};
use crate::nn::layer_norm::LayerNorm;
use crate::nn::params::{ParamId, Params};
use crate::nn::pool::MaxPool2d;
use rand::Rng;
use std::ops::Range;

/// Parallel 'same' convolutions over one input, each writing its own channel slice of one output.
#[derive(Clone, Debug)]
pub struct Branches {
    convs: Vec<(Conv2d, ParamId, ParamId)>,
    pub channels: usize,
}

impl Branches {
    /// Registers `{prefix}_c{k}[d{d}]/kernel` ([c_out, c_in, k, k]) and `/bias` for every branch,
    /// Glorot-uniform kernels and zero biases as Keras initialises them.
    pub fn new(
        params: &mut Params,
        prefix: &str,
        c_in: usize,
        branches: &[ConvBranch],
        rng: &mut impl Rng,
    ) -> Self {
        let convs = branches
            .iter()
            .map(|b| {
                let conv = Conv2d {
                    c_in,
                    c_out: b.filters,
                    kernel: b.kernel,
                    stride: 1,
                    dilation: b.dilation,
                    padding: Padding::Same,
                };
                let name = b.name(prefix);
                let w = params.add(&format!("{name}/kernel"), &[b.filters, c_in, b.kernel, b.kernel]);
                let bias = params.add(&format!("{name}/bias"), &[b.filters]);
                let area = (b.kernel * b.kernel) as f32;
                params.fill_uniform(w, (6.0 / (area * (c_in + b.filters) as f32)).sqrt(), rng);
                (conv, w, bias)
            })
            .collect();
        Self { convs, channels: ConvBranch::channels_of(branches) }
    }

    /// x [n][c_in][h][w] → y [n][channels][h][w].
    pub fn forward(
        &self,
        p: &Params,
        x: &[f32],
        n: usize,
        hw: (usize, usize),
        y: &mut [f32],
        scratch: &mut Vec<f32>,
    ) {
        let mut offset = 0;
        for (conv, w, b) in &self.convs {
            conv.forward(p.get(*w), p.get(*b), x, n, hw.0, hw.1, y, self.channels, offset, scratch);
            offset += conv.c_out;
        }
    }

    /// Accumulates every branch's weight gradients into `grads` and, if given, their sum into `dx`.
    #[allow(clippy::too_many_arguments)] // the layer contract: inputs, output grad, param grads, input grad
    pub fn backward(
        &self,
        p: &Params,
        x: &[f32],
        n: usize,
        hw: (usize, usize),
        dy: &[f32],
        grads: &mut [f32],
        mut dx: Option<&mut [f32]>,
        scratch: &mut Vec<f32>,
    ) {
        let mut offset = 0;
        for (conv, w, b) in &self.convs {
            let (dw, db) = p.pair_mut(grads, *w, *b);
            let (weight, channels) = (p.get(*w), self.channels);
            conv.backward(weight, x, n, hw.0, hw.1, dy, channels, offset, dw, db, dx.as_deref_mut(), scratch);
            offset += conv.c_out;
        }
    }
}

/// Buffers of the branches' passes over an image with a margin: a branch's window of the input,
/// one input channel's kernels, a zero bias, the convolution's scratch.
#[derive(Clone, Debug, Default)]
pub struct ChannelScratch {
    window: Vec<f32>,
    weight: Vec<f32>,
    bias: Vec<f32>,
    conv: Vec<f32>,
}

/// How branch `conv` reads one image of `c` channels whose output is `hw` and whose input `x`
/// ([c][h + 2·margin][w + 2·margin]) holds `margin` more pixels on every side: with no margin, `x`
/// through the 'same' convolution; else the centre window reaching as far as the branch does
/// (copied into `window`) through a 'valid' one, so every output reads real pixels where a 'same'
/// convolution would read zero padding. Returns the convolution, its input and that input's size.
fn on_margin<'a>(
    conv: &Conv2d,
    (x, c): (&'a [f32], usize),
    ((h, w), margin): ((usize, usize), usize),
    window: &'a mut Vec<f32>,
) -> (Conv2d, &'a [f32], (usize, usize)) {
    let (outer_h, outer_w) = (h + 2 * margin, w + 2 * margin);
    assert_eq!(x.len(), c * outer_h * outer_w, "one image of {c} channels and its margin");
    if margin == 0 {
        return (*conv, x, (h, w));
    }
    let reach = (conv.kernel - 1) * conv.dilation / 2;
    assert!(reach <= margin, "a margin of {margin} pixels for a reach of {reach}");
    let (wh, ww, skip) = (h + 2 * reach, w + 2 * reach, margin - reach);
    window.clear();
    for plane in x.chunks_exact(outer_h * outer_w) {
        for row in plane.chunks_exact(outer_w).skip(skip).take(wh) {
            window.extend_from_slice(&row[skip..][..ww]);
        }
    }
    (Conv2d { padding: Padding::Valid, ..*conv }, window, (wh, ww))
}

impl Branches {
    /// `forward` over one image holding `margin` pixels beyond its output on every side (see
    /// `on_margin`): x [c_in][h + 2m][w + 2m] → y [channels][h][w].
    pub fn forward_on_margin(
        &self,
        p: &Params,
        (x, margin): (&[f32], usize),
        hw: (usize, usize),
        y: &mut [f32],
        scratch: &mut ChannelScratch,
    ) {
        let mut offset = 0;
        for (conv, w, b) in &self.convs {
            let (conv, input, (ih, iw)) = on_margin(conv, (x, conv.c_in), (hw, margin), &mut scratch.window);
            conv.forward(p.get(*w), p.get(*b), input, 1, ih, iw, y, self.channels, offset, &mut scratch.conv);
            offset += conv.c_out;
        }
    }

    /// The backward of `forward_on_margin`: accumulates every branch's weight gradients into
    /// `grads` (the input is data and gets none).
    pub fn backward_on_margin(
        &self,
        p: &Params,
        (x, margin): (&[f32], usize),
        hw: (usize, usize),
        dy: &[f32],
        grads: &mut [f32],
        scratch: &mut ChannelScratch,
    ) {
        let mut offset = 0;
        for (conv, w, b) in &self.convs {
            let (conv, input, (ih, iw)) = on_margin(conv, (x, conv.c_in), (hw, margin), &mut scratch.window);
            let (dw, db) = p.pair_mut(grads, *w, *b);
            let weight = p.get(*w);
            conv.backward(
                weight,
                input,
                1,
                ih,
                iw,
                dy,
                self.channels,
                offset,
                dw,
                db,
                None,
                &mut scratch.conv,
            );
            offset += conv.c_out;
        }
    }

    /// The branches' response to input channel `channel` alone, its biases added if `with_bias`:
    /// x [h + 2m][w + 2m] (that channel of one image, with `margin` m as in `forward_on_margin`)
    /// → y [channels][h][w]. A convolution is linear in its input, so the response to an image
    /// is the sum of its channels' responses (one of them with the biases): a map encoder reading
    /// the map and the scan laid on it can take each apart.
    #[allow(clippy::too_many_arguments)] // inputs, which channel and bias, the output, scratch
    pub fn forward_input_channel(
        &self,
        p: &Params,
        channel: usize,
        (x, margin): (&[f32], usize),
        hw: (usize, usize),
        with_bias: bool,
        y: &mut [f32],
        scratch: &mut ChannelScratch,
    ) {
        let mut offset = 0;
        for (conv, w, b) in &self.convs {
            assert!(channel < conv.c_in, "input channel {channel} of {}", conv.c_in);
            let taps = conv.kernel * conv.kernel;
            let weight = p.get(*w);
            scratch.weight.clear();
            for out in 0..conv.c_out {
                scratch.weight.extend_from_slice(&weight[(out * conv.c_in + channel) * taps..][..taps]);
            }
            scratch.bias.clear();
            match with_bias {
                true => scratch.bias.extend_from_slice(p.get(*b)),
                false => scratch.bias.resize(conv.c_out, 0.0),
            }
            let one = Conv2d { c_in: 1, ..*conv };
            let (one, input, (ih, iw)) = on_margin(&one, (x, 1), (hw, margin), &mut scratch.window);
            let (weight, bias) = (&scratch.weight, &scratch.bias);
            one.forward(weight, bias, input, 1, ih, iw, y, self.channels, offset, &mut scratch.conv);
            offset += conv.c_out;
        }
    }
}

/// One image's branch output between a convolution and its max-pool: the buffer
/// [`Branches::forward_pooled`] and [`Branches::backward_pooled`] reuse for every image and branch.
#[derive(Clone, Debug, Default)]
pub struct PooledScratch {
    conv: Vec<f32>,
    conv_scratch: Vec<f32>,
}

impl Branches {
    /// The branches, each followed by `pool` over its channels: x [n][c_in][h][w] → pooled
    /// [n][channels][oh][ow] and its argmax, without keeping the convolutions' output. One
    /// image's branch (≤ 128 × 56 × 56 floats in the observation encoder, 1.6 MB) stays in L2
    /// from the convolution to the pool, where the whole stage's output (4.8 MB per observation)
    /// would be written to memory, read back by the pool, and zeroed again for the backward.
    #[allow(clippy::too_many_arguments)] // inputs, the pool, its two outputs, scratch
    pub fn forward_pooled(
        &self,
        p: &Params,
        x: &[f32],
        n: usize,
        (h, w): (usize, usize),
        pool: &MaxPool2d,
        (pooled, argmax): (&mut [f32], &mut [u8]),
        scratch: &mut PooledScratch,
    ) {
        let (oh, ow) = pool.output_size(h, w);
        for ((conv, weight, bias), image, out) in self.image_branches(x.len(), n, oh * ow) {
            let c = conv.c_out;
            sized(&mut scratch.conv, c * h * w);
            let (weight, bias, y) = (p.get(*weight), p.get(*bias), &mut scratch.conv[..]);
            conv.forward(weight, bias, &x[image], 1, h, w, y, c, 0, &mut scratch.conv_scratch);
            pool.forward(y, c, h, w, &mut pooled[out.clone()], &mut argmax[out]);
        }
    }

    /// The backward of [`Branches::forward_pooled`] from d loss / d pooled: per image and branch,
    /// the pool's backward into the reused branch buffer, then the branch's weight gradients
    /// (accumulated into `grads`). The inputs get no gradient (the first stage reads the data).
    #[allow(clippy::too_many_arguments)] // the layer contract: inputs, the pool, output grad, param grads
    pub fn backward_pooled(
        &self,
        p: &Params,
        x: &[f32],
        n: usize,
        (h, w): (usize, usize),
        pool: &MaxPool2d,
        (dpooled, argmax): (&[f32], &[u8]),
        grads: &mut [f32],
        scratch: &mut PooledScratch,
    ) {
        let (oh, ow) = pool.output_size(h, w);
        for ((conv, weight, bias), image, out) in self.image_branches(x.len(), n, oh * ow) {
            let c = conv.c_out;
            zeroed(&mut scratch.conv, c * h * w);
            pool.backward(&dpooled[out.clone()], &argmax[out], c, h, w, &mut scratch.conv);
            let (dw, db) = p.pair_mut(grads, *weight, *bias);
            let (dy, conv_scratch) = (&scratch.conv, &mut scratch.conv_scratch);
            conv.backward(p.get(*weight), &x[image], 1, h, w, dy, c, 0, dw, db, None, conv_scratch);
        }
    }

    /// Every (image, branch) pair of `n` images stored in `x_len` floats: the branch, the image's
    /// range in the input, and the branch's channels of that image in a pooled output
    /// [n][channels][plane].
    fn image_branches(
        &self,
        x_len: usize,
        n: usize,
        plane: usize,
    ) -> impl Iterator<Item = (&(Conv2d, ParamId, ParamId), Range<usize>, Range<usize>)> {
        let image_len = x_len / n.max(1);
        (0..n).flat_map(move |i| {
            let image = i * image_len..(i + 1) * image_len;
            self.convs.iter().scan(i * self.channels * plane, move |at, branch| {
                let out = *at..*at + branch.0.c_out * plane;
                *at = out.end;
                Some((branch, image.clone(), out))
            })
        })
    }
}

/// LayerNorm over the channels of each pixel, then ReLU, as every PF-net stage ends.
#[derive(Clone, Debug)]
pub struct NormRelu {
    norm: LayerNorm,
    gamma: ParamId,
    beta: ParamId,
}

impl NormRelu {
    /// Registers `{name}/gamma` (ones) and `{name}/beta` (zeros).
    pub fn new(params: &mut Params, name: &str, channels: usize, eps: f32) -> Self {
        let gamma = params.add(&format!("{name}/gamma"), &[channels]);
        let beta = params.add(&format!("{name}/beta"), &[channels]);
        params.fill(gamma, 1.0);
        Self { norm: LayerNorm { channels, eps }, gamma, beta }
    }

    /// x [n][channels][hw] → y = relu(LN(x)); `stats` keeps what the backward needs.
    pub fn forward(&self, p: &Params, x: &[f32], n: usize, hw: usize, y: &mut [f32], stats: &mut [f32]) {
        self.norm.forward(p.get(self.gamma), p.get(self.beta), x, n, hw, y, stats);
        relu_forward(y);
    }

    /// From the gradient at the ReLU's output `dy` to the gradient at the norm's input `x`,
    /// written into `dx`; the ReLU's mask is recomputed, so the output need not be kept
    /// (one fused pass, see `LayerNorm::backward_relu`).
    #[allow(clippy::too_many_arguments)] // the layer contract: inputs, output grad, param grads, input grad
    pub fn backward(
        &self,
        p: &Params,
        x: &[f32],
        stats: &[f32],
        dy: &[f32],
        n: usize,
        hw: usize,
        grads: &mut [f32],
        dx: &mut [f32],
    ) {
        let (gamma, beta) = (p.get(self.gamma), p.get(self.beta));
        let (dgamma, dbeta) = p.pair_mut(grads, self.gamma, self.beta);
        self.norm.backward_relu(gamma, beta, x, stats, dy, n, hw, dgamma, dbeta, dx);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::rng::stream;
    use rand::Rng;
    use rand_pcg::Pcg64Mcg;

    const POOL: MaxPool2d = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };

    /// Two branches over two input channels, 3 filters of 3 × 3 and 2 of `second`, their biases
    /// 0.3 and −0.2 (biases count in the forward), and the random stream after their weights.
    fn two_branches(seed: u64, second: ConvBranch) -> (Params, Branches, Pcg64Mcg) {
        let mut rng = stream(&[seed]);
        let mut params = Params::new();
        let stage = [ConvBranch { filters: 3, kernel: 3, dilation: 1 }, ConvBranch { filters: 2, ..second }];
        let branches = Branches::new(&mut params, "t", 2, &stage, &mut rng);
        for (branch, value) in stage.iter().zip([0.3, -0.2]) {
            let id = params.find(&format!("{}/bias", branch.name("t"))).expect("branch bias");
            params.fill(id, value);
        }
        (params, branches, rng)
    }

    #[test]
    fn pooled_branches_match_the_convolutions_then_the_pool() {
        let (params, branches, mut rng) = two_branches(5, ConvBranch { filters: 2, kernel: 5, dilation: 2 });
        let (n, side, c) = (2, 10, branches.channels);
        let x: Vec<f32> = (0..n * 2 * side * side).map(|_| rng.random_range(-1.0..1.0)).collect();
        let pooled_len = n * c * (side / 2) * (side / 2);
        let dpooled: Vec<f32> = (0..pooled_len).map(|_| rng.random_range(-1.0..1.0)).collect();

        // Unfused: every branch into the whole stage's output, the pool over it, and back.
        let mut conv = vec![0.0; n * c * side * side];
        let mut scratch = Vec::new();
        branches.forward(&params, &x, n, (side, side), &mut conv, &mut scratch);
        let (mut pooled, mut argmax) = (vec![0.0; pooled_len], vec![0u8; pooled_len]);
        POOL.forward(&conv, n * c, side, side, &mut pooled, &mut argmax);
        let mut dconv = vec![0.0; conv.len()];
        POOL.backward(&dpooled, &argmax, n * c, side, side, &mut dconv);
        let mut grads = vec![0.0; params.len()];
        branches.backward(&params, &x, n, (side, side), &dconv, &mut grads, None, &mut scratch);

        let (mut fused, mut fused_argmax) = (vec![0.0; pooled_len], vec![0u8; pooled_len]);
        let mut pooled_scratch = PooledScratch::default();
        let outputs = (&mut fused[..], &mut fused_argmax[..]);
        branches.forward_pooled(&params, &x, n, (side, side), &POOL, outputs, &mut pooled_scratch);
        assert_eq!(fused, pooled, "the fused forward computes the same pooled values");
        assert_eq!(fused_argmax, argmax);
        let mut fused_grads = vec![0.0; params.len()];
        let dy = (&dpooled[..], &argmax[..]);
        branches.backward_pooled(
            &params,
            &x,
            n,
            (side, side),
            &POOL,
            dy,
            &mut fused_grads,
            &mut pooled_scratch,
        );
        for (k, (a, b)) in fused_grads.iter().zip(&grads).enumerate() {
            assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "gradient {k}: fused {a}, unfused {b}");
        }
        assert!(grads.iter().any(|&g| g != 0.0), "the test must exercise the gradients");
    }

    #[test]
    fn a_convolution_is_the_sum_of_its_input_channels_responses() {
        let (params, branches, mut rng) = two_branches(6, ConvBranch { filters: 2, kernel: 7, dilation: 3 });
        let (h, w, c) = (9, 12, branches.channels);
        let x: Vec<f32> = (0..2 * h * w).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut whole = vec![0.0; c * h * w];
        branches.forward(&params, &x, 1, (h, w), &mut whole, &mut Vec::new());

        let (mut first, mut second) = (vec![f32::NAN; c * h * w], vec![f32::NAN; c * h * w]);
        let mut scratch = ChannelScratch::default();
        branches.forward_input_channel(&params, 0, (&x[..h * w], 0), (h, w), false, &mut first, &mut scratch);
        branches.forward_input_channel(&params, 1, (&x[h * w..], 0), (h, w), true, &mut second, &mut scratch);
        for (k, ((a, b), want)) in first.iter().zip(&second).zip(&whole).enumerate() {
            assert!((a + b - want).abs() < 1e-5, "output {k}: {a} + {b} against {want}");
        }
        // Without its biases a channel's response differs by exactly them.
        let mut unbiased = vec![0.0; c * h * w];
        branches.forward_input_channel(
            &params,
            1,
            (&x[h * w..], 0),
            (h, w),
            false,
            &mut unbiased,
            &mut scratch,
        );
        assert!(
            (second[0] - unbiased[0] - 0.3).abs() < 1e-6
                && (second[c * h * w - 1] - unbiased[c * h * w - 1] + 0.2).abs() < 1e-6
        );
    }

    #[test]
    fn on_a_margin_each_branch_reads_real_pixels_where_same_padding_reads_zeros() {
        // The centre of a 'same' convolution over the whole image reads no padding where the
        // margin covers the branches' reach (1 and 3 pixels here): the margin-reading pass must
        // compute exactly that centre.
        let (params, branches, mut rng) = two_branches(7, ConvBranch { filters: 2, kernel: 7, dilation: 1 });
        let (h, w, margin, c) = (6, 8, 3, branches.channels);
        let (oh, ow) = (h + 2 * margin, w + 2 * margin);
        let x: Vec<f32> = (0..2 * oh * ow).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut whole = vec![0.0; c * oh * ow];
        branches.forward(&params, &x, 1, (oh, ow), &mut whole, &mut Vec::new());
        let mut got = vec![f32::NAN; c * h * w];
        branches.forward_on_margin(&params, (&x, margin), (h, w), &mut got, &mut ChannelScratch::default());
        for ch in 0..c {
            for r in 0..h {
                for col in 0..w {
                    let (a, b) =
                        (got[(ch * h + r) * w + col], whole[(ch * oh + r + margin) * ow + col + margin]);
                    assert!((a - b).abs() < 1e-5, "channel {ch}, pixel ({r}, {col}): {a} vs {b}");
                }
            }
        }
    }
}
