//! PF-net's map encoder: a particle's local map → its map features.
//!
//! 28×28×1 → parallel convs (paper: 24@3×3, 16@5×5, 8@7×7, 8@7×7 d2, 8@7×7 d3) → 28×28×64
//! → LayerNorm → ReLU → max-pool 3×3/2 → 14×14×64 → parallel convs (4@3×3, 4@5×5) → 14×14×8
//! → LayerNorm → ReLU → 14×14×8.

use super::config::PfNetConfig;
use super::stage::{Branches, ChannelScratch, NormRelu};
use crate::nn::buffers::{sized, zeroed};
use crate::nn::conv::Padding;
use crate::nn::params::Params;
use crate::nn::pool::MaxPool2d;
use rand::Rng;

const POOL: MaxPool2d = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };

#[derive(Clone, Debug)]
pub struct MapEncoder {
    /// The local map it reads (0: the paper's, 1: a wide view's), through `channels` input
    /// channels: a particle's input holds each local map's channels in turn.
    view: usize,
    channels: usize,
    side: usize,
    /// Pixels of input beyond the local map on every side (`PfNetConfig::map_margin`).
    margin: usize,
    convs1: Branches,
    norm1: NormRelu,
    convs2: Branches,
    norm2: NormRelu,
}

/// Everything the forward pass keeps for the backward, for a chunk of particles.
#[derive(Clone, Debug, Default)]
pub struct MapActivations {
    conv1: Vec<f32>,
    /// One particle's normalised activations (the pool's input); the backward recomputes the
    /// ReLU mask from conv1, so they are not kept per particle.
    norm1: Vec<f32>,
    stats1: Vec<f32>,
    pooled: Vec<f32>,
    argmax: Vec<u8>,
    conv2: Vec<f32>,
    stats2: Vec<f32>,
    /// The encoder's output, [n][channels][side/2][side/2].
    pub features: Vec<f32>,
    grad_a: Vec<f32>,
    grad_b: Vec<f32>,
    grad_c: Vec<f32>,
    scratch: Vec<f32>,
    margin_scratch: ChannelScratch,
}

impl MapEncoder {
    /// An encoder of `channels` input channels from image `view` of a particle's input on (its
    /// local maps: `config.map_encoder_channels()`; its laid scans: 1), its parameters named
    /// `{prefix}_c…`, `{prefix}_ln1`, `{prefix}2_c…`, `{prefix}_ln2`.
    pub fn new(
        params: &mut Params,
        config: &PfNetConfig,
        (prefix, view, channels): (&str, usize, usize),
        rng: &mut impl Rng,
    ) -> Self {
        let eps = config.layer_norm_eps;
        let convs1 = Branches::new(params, prefix, channels, &config.map_stage1, rng);
        let norm1 = NormRelu::new(params, &format!("{prefix}_ln1"), convs1.channels, eps);
        let convs2 = Branches::new(params, &format!("{prefix}2"), convs1.channels, &config.map_stage2, rng);
        let norm2 = NormRelu::new(params, &format!("{prefix}_ln2"), convs2.channels, eps);
        let (side, margin) = (config.local_map.cells, config.map_margin());
        Self { view, channels, side, margin, convs1, norm1, convs2, norm2 }
    }

    /// Particle i's input: its channels of the i-th particle's input in `maps`.
    fn input<'a>(&self, maps: &'a [f32], n: usize, i: usize) -> &'a [f32] {
        let (stack, pixels) = (maps.len() / n.max(1), (self.side + 2 * self.margin).pow(2));
        &maps[i * stack + self.view * self.channels * pixels..][..self.channels * pixels]
    }

    /// Channels × pixels of one particle's features.
    pub fn feature_len(&self) -> usize {
        self.convs2.channels * (self.side / 2) * (self.side / 2)
    }

    /// maps [n][map_channels][side][side] (its channels read) → acts.features [n][feature_len].
    ///
    /// One particle at a time through every layer: its 64 × 28 × 28 first-stage activations
    /// (200 KB) then stay in L2 from the conv through LayerNorm, ReLU and the pool, rather than
    /// round-tripping through L3 for the whole chunk at every layer (standalone, LayerNorm over a
    /// chunk of 8 takes 25 µs per particle vs 47–67 µs over 128: it is bound by where the data sits).
    pub fn forward(&self, p: &Params, maps: &[f32], n: usize, acts: &mut MapActivations) {
        let s = self.side;
        self.forward_each(p, n, acts, |i, conv1, scratch, margin_scratch| match self.margin {
            0 => self.convs1.forward(p, self.input(maps, n, i), 1, (s, s), conv1, scratch),
            m => self.convs1.forward_on_margin(p, (self.input(maps, n, i), m), (s, s), conv1, margin_scratch),
        });
    }

    /// `forward` with particle i's first-stage convolution output [channels][side][side] written
    /// by `first_stage(i, out)` instead of computed from its local map (the feature cache's
    /// first-stage banks with the scan's share added). No backward: the path is the filter's.
    pub fn forward_from_first_stage(
        &self,
        p: &Params,
        n: usize,
        acts: &mut MapActivations,
        mut first_stage: impl FnMut(usize, &mut [f32]),
    ) {
        self.forward_each(p, n, acts, |i, conv1, _, _| first_stage(i, conv1));
    }

    fn forward_each(
        &self,
        p: &Params,
        n: usize,
        acts: &mut MapActivations,
        mut first_stage: impl FnMut(usize, &mut [f32], &mut Vec<f32>, &mut ChannelScratch),
    ) {
        let (s, h) = (self.side, self.side / 2);
        let (c1, c2) = (self.convs1.channels, self.convs2.channels);
        sized(&mut acts.conv1, n * c1 * s * s);
        sized(&mut acts.norm1, c1 * s * s); // one particle's, the backward recomputes its ReLU mask
        sized(&mut acts.stats1, n * s * s * 2);
        sized(&mut acts.pooled, n * c1 * h * h);
        acts.argmax.resize(n * c1 * h * h, 0);
        sized(&mut acts.conv2, n * c2 * h * h);
        sized(&mut acts.features, n * c2 * h * h);
        sized(&mut acts.stats2, n * h * h * 2);
        for i in 0..n {
            let a = &mut *acts;
            let (big, small, pooled) = (c1 * s * s, c2 * h * h, c1 * h * h);
            let conv1 = &mut a.conv1[i * big..][..big];
            first_stage(i, conv1, &mut a.scratch, &mut a.margin_scratch);
            let norm1 = &mut a.norm1[..big];
            self.norm1.forward(p, conv1, 1, s * s, norm1, &mut a.stats1[i * s * s * 2..][..s * s * 2]);
            let pooled_i = &mut a.pooled[i * pooled..][..pooled];
            POOL.forward(norm1, c1, s, s, pooled_i, &mut a.argmax[i * pooled..][..pooled]);
            let conv2 = &mut a.conv2[i * small..][..small];
            self.convs2.forward(p, pooled_i, 1, (h, h), conv2, &mut a.scratch);
            let features = &mut a.features[i * small..][..small];
            self.norm2.forward(p, conv2, 1, h * h, features, &mut a.stats2[i * h * h * 2..][..h * h * 2]);
        }
    }

    /// Channels of the first-stage convolution's output.
    pub fn first_stage_channels(&self) -> usize {
        self.convs1.channels
    }

    /// Values of one particle's first-stage output, [channels][side][side].
    pub fn first_stage_len(&self) -> usize {
        self.convs1.channels * self.side * self.side
    }

    /// The first-stage convolution's response to input channel `channel` alone (biases added if
    /// `with_bias`): image [h + 2m][w + 2m] with `margin` m → out [first_stage_channels][h][w].
    /// With the scan laid on the map, the map's share (channel 0) of a whole map's window goes
    /// into a feature bank once, the scan's (channel 1, with the biases, over the encoder's own
    /// margin) is computed once per observation.
    #[allow(clippy::too_many_arguments)] // inputs, which channel and bias, the output, scratch
    pub fn first_stage_of_channel(
        &self,
        p: &Params,
        channel: usize,
        image: (&[f32], usize),
        hw: (usize, usize),
        with_bias: bool,
        out: &mut [f32],
        scratch: &mut ChannelScratch,
    ) {
        self.convs1.forward_input_channel(p, channel, image, hw, with_bias, out, scratch);
    }

    /// From d loss / d features to the weight gradients (accumulated into `grads`); the local
    /// maps are inputs, so no gradient flows further.
    ///
    /// One particle at a time through every layer, like the forward: its gradient buffers
    /// (≤ 200 KB each) stay in L2 between layers, and their zero-fills are cheap. Measured
    /// (examples/train_profile.rs, K = 30, with the layer changes of
    /// the same round): the whole backward 43 ms → 6–9 ms per filter step.
    pub fn backward(
        &self,
        p: &Params,
        maps: &[f32],
        n: usize,
        acts: &mut MapActivations,
        dfeatures: &[f32],
        grads: &mut [f32],
    ) {
        let (s, h) = (self.side, self.side / 2);
        let (c1, c2) = (self.convs1.channels, self.convs2.channels);
        let (big, small, pooled) = (c1 * s * s, c2 * h * h, c1 * h * h);
        let a = acts;
        for i in 0..n {
            sized(&mut a.grad_a, small); // d conv2 (written by the norm)
            let (stats2, stats1) =
                (&a.stats2[i * h * h * 2..][..h * h * 2], &a.stats1[i * s * s * 2..][..s * s * 2]);
            let conv2 = &a.conv2[i * small..][..small];
            let dfeatures = &dfeatures[i * small..][..small];
            self.norm2.backward(p, conv2, stats2, dfeatures, 1, h * h, grads, &mut a.grad_a);
            zeroed(&mut a.grad_b, pooled); // d pooled
            let pooled_i = &a.pooled[i * pooled..][..pooled];
            let dpooled = Some(&mut a.grad_b[..]);
            self.convs2.backward(p, pooled_i, 1, (h, h), &a.grad_a, grads, dpooled, &mut a.scratch);
            zeroed(&mut a.grad_c, big); // d norm1 (after ReLU)
            POOL.backward(&a.grad_b, &a.argmax[i * pooled..][..pooled], c1, s, s, &mut a.grad_c);
            sized(&mut a.grad_a, big); // d conv1 (written by the norm)
            let conv1 = &a.conv1[i * big..][..big];
            self.norm1.backward(p, conv1, stats1, &a.grad_c, 1, s * s, grads, &mut a.grad_a);
            let input = self.input(maps, n, i);
            match self.margin {
                0 => self.convs1.backward(p, input, 1, (s, s), &a.grad_a, grads, None, &mut a.scratch),
                m => self.convs1.backward_on_margin(
                    p,
                    (input, m),
                    (s, s),
                    &a.grad_a,
                    grads,
                    &mut a.margin_scratch,
                ),
            }
        }
    }

    /// `forward` over `n` images of `h × w` (even sides, so every pool window starts on an even
    /// pixel as in a local map) instead of the local map's square: the feature cache encodes a
    /// whole map's window at once. → acts.features [n][channels][h/2][w/2].
    pub fn forward_sized(
        &self,
        p: &Params,
        maps: &[f32],
        n: usize,
        (h, w): (usize, usize),
        acts: &mut MapActivations,
    ) {
        assert!(h.is_multiple_of(2) && w.is_multiple_of(2), "forward_sized: even sides");
        let (c1, c2, (ph, pw)) = (self.convs1.channels, self.convs2.channels, (h / 2, w / 2));
        sized(&mut acts.conv1, n * c1 * h * w);
        self.convs1.forward(p, maps, n, (h, w), &mut acts.conv1, &mut acts.scratch);
        sized(&mut acts.norm1, n * c1 * h * w);
        sized(&mut acts.stats1, n * h * w * 2);
        self.norm1.forward(p, &acts.conv1, n, h * w, &mut acts.norm1, &mut acts.stats1);
        sized(&mut acts.pooled, n * c1 * ph * pw);
        acts.argmax.resize(n * c1 * ph * pw, 0);
        POOL.forward(&acts.norm1, n * c1, h, w, &mut acts.pooled, &mut acts.argmax);
        sized(&mut acts.conv2, n * c2 * ph * pw);
        self.convs2.forward(p, &acts.pooled, n, (ph, pw), &mut acts.conv2, &mut acts.scratch);
        sized(&mut acts.features, n * c2 * ph * pw);
        sized(&mut acts.stats2, n * ph * pw * 2);
        self.norm2.forward(p, &acts.conv2, n, ph * pw, &mut acts.features, &mut acts.stats2);
    }
}
