//! PF-net's joint stage: map features ⊕ observation features → one log-likelihood per particle.
//!
//! 14×14×(8 + 16) → locally-connected 8@3×3 'valid' ⊕ 8@5×5 (zero pad 1), each with ReLU
//! → 12×12×16 → max-pool 3×3/2 'valid' → 5×5×16 = 400 → dense → 1.
//!
//! Two forward passes: `forward` on the concatenated features, keeping what `backward` needs
//! (training), and `forward_shared` for the filter, where the particles of one robot share its
//! observation: that enters once per robot through `observation_terms`, and the particles'
//! products cover only the map channels.

use super::config::PfNetConfig;
use crate::nn::activation::{relu_backward, relu_forward};
use crate::nn::buffers::{sized, zeroed};
use crate::nn::conv::Padding;
use crate::nn::dense::Dense;
use crate::nn::locally_connected::LocallyConnected2d;
use crate::nn::params::{ParamId, Params};
use crate::nn::pool::MaxPool2d;
use rand::Rng;

const POOL: MaxPool2d = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Valid };

#[derive(Clone, Debug)]
pub struct Joint {
    /// Side of the input features (paper: 14) and of the locally-connected outputs (12).
    side: usize,
    out_side: usize,
    pooled_side: usize,
    /// Input channels: the map features first, then the observation features.
    pub map_channels: usize,
    pub obs_channels: usize,
    lc3: (LocallyConnected2d, ParamId, ParamId),
    lc5: (LocallyConnected2d, ParamId, ParamId),
    head: (Dense, ParamId, ParamId),
}

/// Everything the forward pass keeps for the backward, for a chunk of particles.
#[derive(Clone, Debug, Default)]
pub struct JointActivations {
    /// The input, [n][map + obs channels][side][side]; callers fill it.
    pub input: Vec<f32>,
    local: Vec<f32>,
    pooled: Vec<f32>,
    argmax: Vec<u8>,
    /// One log-likelihood per particle.
    pub loglik: Vec<f32>,
    /// d loss / d input after the backward pass.
    pub dinput: Vec<f32>,
    grad_local: Vec<f32>,
    grad_pooled: Vec<f32>,
    grad_relu: Vec<f32>,
    scratch: Vec<f32>,
}

impl Joint {
    pub fn new(
        params: &mut Params,
        config: &PfNetConfig,
        map_channels: usize,
        obs_channels: usize,
        rng: &mut impl Rng,
    ) -> Self {
        let side = config.local_map.cells / 2;
        let c_in = map_channels + obs_channels;
        let filters = config.joint_filters;
        let mut lc = |name: &str, kernel: usize, pad: usize| {
            let layer = LocallyConnected2d { c_in, filters, kernel, pad, h: side, w: side };
            let w = params.add(&format!("{name}/kernel"), &[layer.positions(), filters, layer.patch_len()]);
            let b = params.add(&format!("{name}/bias"), &[layer.positions(), filters]);
            params.fill_uniform(w, (6.0 / (layer.patch_len() + filters) as f32).sqrt(), rng);
            (layer, w, b)
        };
        let (lc3, lc5) = (lc("j_lc3", 3, 0), lc("j_lc5", 5, 1));
        let out_side = lc3.0.output_size().0;
        let pooled_side = POOL.output_size(out_side, out_side).0;
        let dense = Dense { inputs: 2 * filters * pooled_side * pooled_side, outputs: 1 };
        let w = params.add("j_out/kernel", &[dense.inputs, 1]);
        let b = params.add("j_out/bias", &[1]);
        params.fill_uniform(w, (6.0 / (dense.inputs + 1) as f32).sqrt(), rng);
        Self { side, out_side, pooled_side, map_channels, obs_channels, lc3, lc5, head: (dense, w, b) }
    }

    /// Values of one particle's input.
    pub fn input_len(&self) -> usize {
        (self.map_channels + self.obs_channels) * self.side * self.side
    }

    /// Values of one observation's terms (`observation_terms`).
    pub fn term_len(&self) -> usize {
        2 * self.lc3.0.filters * self.out_side * self.out_side
    }

    /// acts.input [n][…] → acts.loglik [n].
    pub fn forward(&self, p: &Params, n: usize, acts: &mut JointActivations) {
        let channels = 2 * self.lc3.0.filters;
        sized(&mut acts.local, n * channels * self.out_side * self.out_side);
        for (offset, (layer, w, b)) in self.layers() {
            let (w, b) = (p.get(*w), p.get(*b));
            layer.forward(w, b, &acts.input, n, &mut acts.local, channels, offset, &mut acts.scratch);
        }
        self.head_forward(p, n, acts);
    }

    /// The observation's share of both locally-connected layers, bias included, for `n`
    /// observations: features [n][obs_channels][side][side] → terms [n][term_len], what
    /// `forward_shared` starts the particles of each observation from.
    pub fn observation_terms(
        &self,
        p: &Params,
        features: &[f32],
        n: usize,
        terms: &mut [f32],
        acts: &mut JointActivations,
    ) {
        let (m, o) = (self.map_channels * self.side * self.side, self.obs_channels * self.side * self.side);
        acts.input.clear();
        for one in features.chunks_exact(o).take(n) {
            acts.input.extend(std::iter::repeat_n(0.0, m));
            acts.input.extend_from_slice(one);
        }
        let channels = 2 * self.lc3.0.filters;
        for (offset, (layer, w, b)) in self.layers() {
            let (w, b) = (p.get(*w), p.get(*b));
            layer.forward(
                w,
                b,
                &acts.input,
                n,
                &mut terms[..n * self.term_len()],
                channels,
                offset,
                &mut acts.scratch,
            );
        }
    }

    /// `forward` for particles sharing observations, without what a backward pass would need:
    /// map features [n][map_channels][side][side], particle i's observation terms at row
    /// `owner[i]` of `terms` → acts.loglik [n]. The locally-connected products then cover the map
    /// channels only (a third of the paper's), and the head runs across particles.
    pub fn forward_shared(
        &self,
        p: &Params,
        map_features: &[f32],
        terms: &[f32],
        owner: &[u32],
        acts: &mut JointActivations,
    ) {
        let (n, channels) = (owner.len(), 2 * self.lc3.0.filters);
        sized(&mut acts.local, n * channels * self.out_side * self.out_side);
        for (offset, (layer, w, _)) in self.layers() {
            layer.forward_own_channels(
                p.get(*w),
                map_features,
                self.map_channels,
                terms,
                owner,
                &mut acts.local,
                channels,
                offset,
                &mut acts.scratch,
            );
        }
        self.head_forward_across_samples(p, n, acts);
    }

    /// Both locally-connected layers with the channel slice of `local` each writes.
    fn layers(&self) -> [(usize, &(LocallyConnected2d, ParamId, ParamId)); 2] {
        [(0, &self.lc3), (self.lc3.0.filters, &self.lc5)]
    }

    /// `head_forward` for acts.local laid out [o·o][channels][n] (samples innermost, as
    /// `forward_own_channels` leaves it): the pool's max, the ReLU and the dense head are each a
    /// pass along a row of n samples, and no argmax is kept.
    fn head_forward_across_samples(&self, p: &Params, n: usize, acts: &mut JointActivations) {
        let (o, q, (k, stride)) = (self.out_side, self.pooled_side, (POOL.kernel, POOL.stride));
        let channels = 2 * self.lc3.0.filters;
        let (_, w, b) = &self.head;
        let weight = p.get(*w);
        sized(&mut acts.loglik, n);
        acts.loglik.fill(p.get(*b)[0]);
        sized(&mut acts.pooled, n);
        let pooled = &mut acts.pooled[..n];
        for c in 0..channels {
            for (qy, qx) in (0..q).flat_map(|qy| (0..q).map(move |qx| (qy, qx))) {
                // Starting from 0 makes the max the ReLU's too (ReLU and max commute); the
                // pool is 'valid', so every window lies inside.
                pooled.fill(0.0);
                for (dy, dx) in (0..k).flat_map(|dy| (0..k).map(move |dx| (dy, dx))) {
                    let position = (stride * qy + dy) * o + stride * qx + dx;
                    for (m, &v) in pooled.iter_mut().zip(&acts.local[(position * channels + c) * n..][..n]) {
                        *m = if v > *m { v } else { *m };
                    }
                }
                // The dense input is the pooled map flattened as [channel][row][col].
                let wi = weight[(c * q + qy) * q + qx];
                for (l, &m) in acts.loglik.iter_mut().zip(pooled.iter()) {
                    *l += wi * m;
                }
            }
        }
    }

    /// After the locally-connected layers (acts.local): ReLU, pool, dense → acts.loglik.
    fn head_forward(&self, p: &Params, n: usize, acts: &mut JointActivations) {
        let (o, q) = (self.out_side, self.pooled_side);
        let channels = 2 * self.lc3.0.filters;
        relu_forward(&mut acts.local);
        sized(&mut acts.pooled, n * channels * q * q);
        acts.argmax.resize(n * channels * q * q, 0);
        POOL.forward(&acts.local, n * channels, o, o, &mut acts.pooled, &mut acts.argmax);
        sized(&mut acts.loglik, n);
        let (dense, w, b) = &self.head;
        dense.forward(p.get(*w), p.get(*b), &acts.pooled, n, &mut acts.loglik);
    }

    /// From d loss / d loglik to the weight gradients (accumulated) and acts.dinput (overwritten).
    pub fn backward(
        &self,
        p: &Params,
        n: usize,
        acts: &mut JointActivations,
        dloglik: &[f32],
        grads: &mut [f32],
    ) {
        let (o, q) = (self.out_side, self.pooled_side);
        let channels = 2 * self.lc3.0.filters;
        let a = acts;
        zeroed(&mut a.grad_pooled, n * channels * q * q);
        let (dense, w, b) = &self.head;
        let (dw, db) = p.pair_mut(grads, *w, *b);
        dense.backward(p.get(*w), &a.pooled, n, dloglik, dw, db, Some(&mut a.grad_pooled));
        zeroed(&mut a.grad_relu, n * channels * o * o);
        POOL.backward(&a.grad_pooled, &a.argmax, n * channels, o, o, &mut a.grad_relu);
        sized(&mut a.grad_local, n * channels * o * o);
        relu_backward(&a.local, &a.grad_relu, &mut a.grad_local);
        zeroed(&mut a.dinput, n * self.input_len());
        for (offset, (layer, w, b)) in self.layers() {
            let (dw, db) = p.pair_mut(grads, *w, *b);
            let weight = p.get(*w);
            layer.backward(
                weight,
                &a.input,
                n,
                &a.grad_local,
                channels,
                offset,
                dw,
                db,
                Some(&mut a.dinput),
                &mut a.scratch,
            );
        }
    }
}
