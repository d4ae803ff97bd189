//! One image encoder of the agent: 3×3 stride-2 'valid' convolutions with ReLU, flattened, then a
//! dense layer with ReLU (the authors' `rl_architecture 2`).
//!
//! Where every convolution has a channel-last path (AVX-512, channel counts in whole vectors),
//! the activations stay channel-last from the first convolution's output on, so no layer
//! transposes its output, its dy or its dx (they were 14 % of a compact update in `perf`); only
//! the last one, a few pixels per image, is flattened channel-major for the dense layer, the
//! layout the weights are stored in.

use crate::nn::activation::{relu_backward, relu_forward};
use crate::nn::buffers::{sized, zeroed};
use crate::nn::conv::{Conv2d, Padding};
use crate::nn::dense::Dense;
use crate::nn::params::Params;
use crate::nn::sac::layer::WeightBias;

/// Samples taken through every convolution together on the channel-last path: their first layer
/// outputs (≤ 93 KB each for the paper's 56 × 56 grid) stay in a core's L2 for the second.
const LAYER_GROUP: usize = 8;

#[derive(Clone, Debug, PartialEq)]
struct ConvLayer {
    conv: Conv2d,
    /// Input height = width of this layer.
    side: usize,
    wb: WeightBias,
}

impl ConvLayer {
    /// Output values per sample.
    fn output_len(&self) -> usize {
        let (oh, ow) = self.conv.output_size(self.side, self.side);
        self.conv.c_out * oh * ow
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct ImageEncoder {
    convs: Vec<ConvLayer>,
    /// Flattened output of the last convolution.
    flat: usize,
    dense: Dense,
    dense_wb: WeightBias,
    input_len: usize,
    /// Activations channel-last (`Conv2d::forward_channel_last`) rather than channel-major.
    channel_last: bool,
}

/// What a forward pass over `n` images keeps for its backward pass, and the backward's buffers
/// (sized on first use, then reused: no allocation per update).
#[derive(Clone, Debug, Default)]
pub struct EncoderActivations {
    /// Post-ReLU output of every convolution.
    conv_out: Vec<Vec<f32>>,
    /// The last convolution's output channel-major, the dense layer's input (channel-last only).
    flat: Vec<f32>,
    /// Post-ReLU output of the dense layer: the features, `[n][fc]`.
    pub features: Vec<f32>,
    d_pre: Vec<f32>,
    d_input: Vec<f32>,
    scratch: Vec<f32>,
    /// Every convolution's weight as the channel-last kernels read it (channel-last only).
    weights: Vec<Vec<f32>>,
}

impl ImageEncoder {
    /// Adds the encoder's tensors (`name/conv{i}`, `name/fc`) to `params`.
    pub fn new(
        params: &mut Params,
        name: &str,
        channels: usize,
        side: usize,
        conv_channels: &[usize],
        fc: usize,
    ) -> Self {
        let (mut c_in, mut s) = (channels, side);
        let mut convs = Vec::with_capacity(conv_channels.len());
        for (i, &c_out) in conv_channels.iter().enumerate() {
            let conv = Conv2d { c_in, c_out, kernel: 3, stride: 2, dilation: 1, padding: Padding::Valid };
            let wb = WeightBias::add(params, &format!("{name}/conv{i}"), &[c_out, c_in, 3, 3], c_out);
            convs.push(ConvLayer { conv, side: s, wb });
            (c_in, s) = (c_out, conv.output_size(s, s).0);
        }
        let flat = c_in * s * s;
        let dense = Dense { inputs: flat, outputs: fc };
        let dense_wb = WeightBias::add(params, &format!("{name}/fc"), &[flat, fc], fc);
        let channel_last = convs.iter().enumerate().all(|(i, l)| l.conv.runs_channel_last(i > 0));
        Self { convs, flat, dense, dense_wb, input_len: channels * side * side, channel_last }
    }

    /// Pixels and channels of the last convolution's output.
    fn last_shape(&self) -> (usize, usize) {
        let l = self.convs.last().expect("at least one convolution");
        let (oh, ow) = l.conv.output_size(l.side, l.side);
        (oh * ow, l.conv.c_out)
    }

    /// Values per input image.
    pub fn input_len(&self) -> usize {
        self.input_len
    }

    /// Features per image.
    pub fn output_len(&self) -> usize {
        self.dense.outputs
    }

    pub fn init(&self, params: &mut Params, rng: &mut impl rand::Rng) {
        for l in &self.convs {
            let taps = l.conv.kernel * l.conv.kernel;
            l.wb.init(params, l.conv.c_in * taps, l.conv.c_out * taps, rng);
        }
        self.dense_wb.init(params, self.flat, self.dense.outputs, rng);
    }

    /// `x`: `[n][channels][side][side]` → `acts.features` `[n][fc]`.
    pub fn forward(&self, values: &[f32], x: &[f32], n: usize, acts: &mut EncoderActivations) {
        assert_eq!(x.len(), n * self.input_len, "encoder input length");
        acts.conv_out.resize(self.convs.len(), Vec::new());
        for (l, y) in self.convs.iter().zip(&mut acts.conv_out) {
            sized(y, n * l.output_len());
        }
        if self.channel_last {
            self.convs_channel_last(values, x, n, acts);
        } else {
            for (i, l) in self.convs.iter().enumerate() {
                let (done, rest) = acts.conv_out.split_at_mut(i);
                let input = if i == 0 { x } else { &done[i - 1] };
                let (w, b) = (l.wb.weight(values), l.wb.bias(values));
                let y = &mut rest[0];
                l.conv.forward(w, b, input, n, l.side, l.side, y, l.conv.c_out, 0, &mut acts.scratch);
                relu_forward(y);
            }
        }
        acts.features.resize(n * self.dense.outputs, 0.0);
        let mut last = acts.conv_out.last().expect("at least one convolution");
        if self.channel_last {
            let (p, c) = self.last_shape();
            acts.flat.resize(last.len(), 0.0);
            transpose_samples(last, n, p, c, &mut acts.flat);
            last = &acts.flat;
        }
        self.dense.forward(
            self.dense_wb.weight(values),
            self.dense_wb.bias(values),
            last,
            n,
            &mut acts.features,
        );
        relu_forward(&mut acts.features);
    }

    /// The convolutions channel-last, [`LAYER_GROUP`] samples at a time through every layer, so
    /// each layer reads its input from cache, where it was just written (a whole chunk's first
    /// layer output, 2–3 MB, overflowed L2 on its way to the second).
    fn convs_channel_last(&self, values: &[f32], x: &[f32], n: usize, acts: &mut EncoderActivations) {
        acts.weights.resize(self.convs.len(), Vec::new());
        for (l, wt) in self.convs.iter().zip(&mut acts.weights) {
            l.conv.channel_last_weight(l.wb.weight(values), wt);
        }
        for first in (0..n).step_by(LAYER_GROUP) {
            let m = LAYER_GROUP.min(n - first);
            for (i, (l, wt)) in self.convs.iter().zip(&acts.weights).enumerate() {
                let (done, rest) = acts.conv_out.split_at_mut(i);
                let (input, in_len) = match i {
                    0 => (x, self.input_len),
                    _ => (&done[i - 1][..], self.convs[i - 1].output_len()),
                };
                let input = &input[first * in_len..][..m * in_len];
                let y = &mut rest[0][first * l.output_len()..][..m * l.output_len()];
                let (b, sides) = (l.wb.bias(values), (l.side, l.side));
                l.conv.forward_channel_last(wt, b, input, i > 0, m, sides, y, true);
            }
        }
    }

    /// Accumulates into `grads` (laid out like the arena) the gradient of a loss whose gradient
    /// with respect to `acts.features` is `d_features`. The input image gets no gradient.
    pub fn backward(
        &self,
        values: &[f32],
        x: &[f32],
        n: usize,
        acts: &mut EncoderActivations,
        d_features: &[f32],
        grads: &mut [f32],
    ) {
        let EncoderActivations { conv_out, flat, features, d_pre, d_input, scratch, .. } = acts;
        sized(d_pre, features.len());
        relu_backward(features, d_features, d_pre);
        let last = if self.channel_last { &flat[..] } else { conv_out.last().expect("forward ran") };
        zeroed(d_input, last.len());
        let (dw, db) = self.dense_wb.split_mut(grads);
        self.dense.backward(self.dense_wb.weight(values), last, n, d_pre, dw, db, Some(d_input));
        if self.channel_last {
            // d(flat) channel-major → the last convolution's channel-last layout, via d_pre.
            let (p, c) = self.last_shape();
            sized(d_pre, d_input.len());
            transpose_samples(d_input, n, c, p, d_pre);
            std::mem::swap(d_input, d_pre);
        }
        for (i, l) in self.convs.iter().enumerate().rev() {
            // d_input holds d(post-ReLU output of layer i); through the ReLU into d_pre.
            sized(d_pre, conv_out[i].len());
            relu_backward(&conv_out[i], d_input, d_pre);
            let input = if i == 0 { x } else { &conv_out[i - 1] };
            let (dw, db) = l.wb.split_mut(grads);
            let dx = if i == 0 {
                None
            } else {
                zeroed(d_input, input.len());
                Some(&mut d_input[..])
            };
            let weight = l.wb.weight(values);
            if self.channel_last {
                let sides = (l.side, l.side);
                l.conv.backward_channel_last(weight, input, i > 0, n, sides, d_pre, dw, db, dx, scratch);
            } else {
                let (side, c_out) = (l.side, l.conv.c_out);
                l.conv.backward(weight, input, n, side, side, d_pre, c_out, 0, dw, db, dx, scratch);
            }
        }
    }
}

/// dst [n][cols][rows] ← src [n][rows][cols], sample by sample.
fn transpose_samples(src: &[f32], n: usize, rows: usize, cols: usize, dst: &mut [f32]) {
    for (s, d) in src.chunks_exact(rows * cols).zip(dst.chunks_exact_mut(rows * cols)).take(n) {
        for (r, row) in s.chunks_exact(cols).enumerate() {
            for (c, &v) in row.iter().enumerate() {
                d[c * rows + r] = v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad, test_values};

    #[test]
    fn backward_matches_finite_differences() {
        let mut params = Params::new();
        let enc = ImageEncoder::new(&mut params, "enc", 2, 9, &[3, 2], 4);
        params.values = test_values(params.len(), 7).iter().map(|v| v * 0.6).collect();
        let n = 2;
        let x: Vec<f32> = test_values(n * enc.input_len(), 8).iter().map(|v| v.abs()).collect();
        let r = test_values(n * 4, 9);
        let mut acts = EncoderActivations::default();
        let loss = |values: &[f32]| -> f64 {
            let mut a = EncoderActivations::default();
            enc.forward(values, &x, n, &mut a);
            a.features.iter().zip(&r).map(|(f, r)| f64::from(f * r)).sum()
        };
        enc.forward(&params.values, &x, n, &mut acts);
        let mut grads = vec![0.0; params.len()];
        enc.backward(&params.values, &x, n, &mut acts, &r, &mut grads);
        let v64: Vec<f64> = params.values.iter().map(|&v| f64::from(v)).collect();
        let numeric = numerical_grad(&v64, 1e-2, |v| loss(&v.iter().map(|&a| a as f32).collect::<Vec<_>>()));
        assert_close(&grads, &numeric, 2e-2, "encoder gradient");
    }

    /// Channel-last activations give the channel-major features and gradients (16-channel convs
    /// take that path on AVX-512; elsewhere both runs are channel-major), over more samples than
    /// one layer group, the last group short.
    #[test]
    fn channel_last_matches_channel_major() {
        let mut params = Params::new();
        let last = ImageEncoder::new(&mut params, "enc", 3, 15, &[16, 32, 16], 8);
        params.values = test_values(params.len(), 17).iter().map(|v| v * 0.3).collect();
        let major = ImageEncoder { channel_last: false, ..last.clone() };
        let n = LAYER_GROUP + 3;
        let x: Vec<f32> = test_values(n * last.input_len(), 18).iter().map(|v| v.abs()).collect();
        let d_features = test_values(n * 8, 19);
        let run = |enc: &ImageEncoder| {
            let mut acts = EncoderActivations::default();
            enc.forward(&params.values, &x, n, &mut acts);
            let mut grads = vec![0.0; params.len()];
            enc.backward(&params.values, &x, n, &mut acts, &d_features, &mut grads);
            (acts.features, grads)
        };
        let ((f_last, g_last), (f_major, g_major)) = (run(&last), run(&major));
        let f64s = |v: &[f32]| v.iter().map(|&a| f64::from(a)).collect::<Vec<_>>();
        assert_close(&f_last, &f64s(&f_major), 1e-6, "features");
        assert_close(&g_last, &f64s(&g_major), 1e-5, "gradients");
    }
}
