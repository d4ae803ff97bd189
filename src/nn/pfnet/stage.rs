//! The two building blocks PF-net's encoders repeat: parallel convolutions concatenated along
//! channels, and LayerNorm followed by ReLU.

use super::config::ConvBranch;
use crate::nn::activation::relu_forward;
use crate::nn::conv::{Conv2d, Padding};
use crate::nn::layer_norm::LayerNorm;
use crate::nn::params::{ParamId, Params};
use rand::Rng;

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

/// Resizes `buf` to `len` zeros (the buffer keeps its capacity, so steady state allocates nothing).
pub fn zeroed(buf: &mut Vec<f32>, len: usize) {
    buf.clear();
    buf.resize(len, 0.0);
}

/// Resizes `buf` to `len` without clearing what a forward pass will overwrite anyway.
pub fn sized(buf: &mut Vec<f32>, len: usize) {
    buf.resize(len, 0.0);
}
