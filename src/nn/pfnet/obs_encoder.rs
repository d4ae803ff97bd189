//! PF-net's observation encoder: the 56×56 LiDAR grid → observation features, once per step.
//!
//! 56×56×1 → parallel convs (paper: 128@3×3, 128@5×5, 64@5×5 d2, 64@5×5 d4) → 56×56×384
//! → max-pool 3×3/2 → 28×28×384 → LayerNorm → ReLU → conv 16@3×3 → 28×28×16 → max-pool
//! → 14×14×16 → LayerNorm → ReLU → 14×14×16.

use super::config::PfNetConfig;
use super::stage::{Branches, NormRelu, PooledScratch};
use crate::nn::buffers::{sized, zeroed};
use crate::nn::conv::Padding;
use crate::nn::params::Params;
use crate::nn::pool::MaxPool2d;
use rand::Rng;

const POOL: MaxPool2d = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };

#[derive(Clone, Debug)]
pub struct ObsEncoder {
    side: usize,
    convs1: Branches,
    norm1: NormRelu,
    convs2: Branches,
    norm2: NormRelu,
}

/// Everything the forward pass keeps for the backward, for a chunk of observations. The first
/// stage's convolutions are pooled as they come out (`Branches::forward_pooled`), so only the
/// pooled values and their argmax are kept.
#[derive(Clone, Debug, Default)]
pub struct ObsActivations {
    pooled1: Vec<f32>,
    argmax1: Vec<u8>,
    norm1: Vec<f32>,
    stats1: Vec<f32>,
    conv2: Vec<f32>,
    pooled2: Vec<f32>,
    argmax2: Vec<u8>,
    stats2: Vec<f32>,
    /// The encoder's output, [n][channels][side/4][side/4].
    pub features: Vec<f32>,
    grad_a: Vec<f32>,
    grad_b: Vec<f32>,
    stage1: PooledScratch,
    scratch: Vec<f32>,
}

impl ObsEncoder {
    pub fn new(params: &mut Params, config: &PfNetConfig, rng: &mut impl Rng) -> Self {
        let convs1 = Branches::new(params, "o", config.obs_channels, &config.obs_stage1, rng);
        let norm1 = NormRelu::new(params, "o_ln1", convs1.channels, config.layer_norm_eps);
        let convs2 = Branches::new(params, "o2", convs1.channels, &config.obs_stage2, rng);
        let norm2 = NormRelu::new(params, "o_ln2", convs2.channels, config.layer_norm_eps);
        Self { side: config.obs_cells, convs1, norm1, convs2, norm2 }
    }

    /// Channels × pixels of one observation's features.
    pub fn feature_len(&self) -> usize {
        self.convs2.channels * (self.side / 4) * (self.side / 4)
    }

    /// obs [n][obs_channels][side][side] → acts.features [n][feature_len].
    pub fn forward(&self, p: &Params, obs: &[f32], n: usize, acts: &mut ObsActivations) {
        let (s, h, q) = (self.side, self.side / 2, self.side / 4);
        let (c1, c2) = (self.convs1.channels, self.convs2.channels);
        sized(&mut acts.pooled1, n * c1 * h * h);
        acts.argmax1.resize(n * c1 * h * h, 0);
        let pooled1 = (&mut acts.pooled1[..], &mut acts.argmax1[..]);
        self.convs1.forward_pooled(p, obs, n, (s, s), &POOL, pooled1, &mut acts.stage1);
        sized(&mut acts.norm1, n * c1 * h * h);
        sized(&mut acts.stats1, n * h * h * 2);
        self.norm1.forward(p, &acts.pooled1, n, h * h, &mut acts.norm1, &mut acts.stats1);
        sized(&mut acts.conv2, n * c2 * h * h);
        self.convs2.forward(p, &acts.norm1, n, (h, h), &mut acts.conv2, &mut acts.scratch);
        sized(&mut acts.pooled2, n * c2 * q * q);
        acts.argmax2.resize(n * c2 * q * q, 0);
        POOL.forward(&acts.conv2, n * c2, h, h, &mut acts.pooled2, &mut acts.argmax2);
        sized(&mut acts.features, n * c2 * q * q);
        sized(&mut acts.stats2, n * q * q * 2);
        self.norm2.forward(p, &acts.pooled2, n, q * q, &mut acts.features, &mut acts.stats2);
    }

    /// From d loss / d features to the weight gradients (accumulated into `grads`).
    pub fn backward(
        &self,
        p: &Params,
        obs: &[f32],
        n: usize,
        acts: &mut ObsActivations,
        dfeatures: &[f32],
        grads: &mut [f32],
    ) {
        let (s, h, q) = (self.side, self.side / 2, self.side / 4);
        let (c1, c2) = (self.convs1.channels, self.convs2.channels);
        let a = acts;
        sized(&mut a.grad_a, n * c2 * q * q); // d pooled2 (written by the norm)
        self.norm2.backward(p, &a.pooled2, &a.stats2, dfeatures, n, q * q, grads, &mut a.grad_a);
        zeroed(&mut a.grad_b, n * c2 * h * h); // d conv2
        POOL.backward(&a.grad_a, &a.argmax2, n * c2, h, h, &mut a.grad_b);
        zeroed(&mut a.grad_a, n * c1 * h * h); // d norm1 (after ReLU)
        self.convs2.backward(p, &a.norm1, n, (h, h), &a.grad_b, grads, Some(&mut a.grad_a), &mut a.scratch);
        sized(&mut a.grad_b, n * c1 * h * h); // d pooled1 (written by the norm)
        self.norm1.backward(p, &a.pooled1, &a.stats1, &a.grad_a, n, h * h, grads, &mut a.grad_b);
        let dpooled1 = (&a.grad_b[..], &a.argmax1[..]);
        self.convs1.backward_pooled(p, obs, n, (s, s), &POOL, dpooled1, grads, &mut a.stage1);
    }
}
