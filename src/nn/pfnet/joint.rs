//! PF-net's joint stage: map features ⊕ observation features → one log-likelihood per particle.
//!
//! 14×14×(8 + 16) → locally-connected 8@3×3 'valid' ⊕ 8@5×5 (zero pad 1), each with ReLU
//! → 12×12×16 → max-pool 3×3/2 'valid' → 5×5×16 = 400 → dense → 1.
//!
//! The particles of one robot (in the filter) or of one step (in training) share its
//! observation: that enters once through `observation_terms`, and the particles'
//! locally-connected products cover only the map channels, a third of the paper's. `forward`
//! keeps what `backward` needs (training); there the particles' output gradients are summed per
//! step before the observation's products, so the observation's share costs one backward per
//! step. `forward_shared` is the filter's pass, with nothing kept.

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
    /// The observations with zero map channels, [n][map + obs channels][side][side]: the input
    /// of `observation_terms` and of the observation's share of `backward`.
    input: Vec<f32>,
    /// Each step's observation terms and the step of each particle (`forward`).
    terms: Vec<f32>,
    step_of: Vec<u32>,
    /// The locally-connected outputs as the products leave them, [o·o][channels][n].
    products: Vec<f32>,
    /// The locally-connected outputs, [n][channels][o][o].
    local: Vec<f32>,
    pooled: Vec<f32>,
    argmax: Vec<u8>,
    /// One log-likelihood per particle.
    pub loglik: Vec<f32>,
    /// d loss / d input (the observations' rows).
    dinput: Vec<f32>,
    grad_local: Vec<f32>,
    /// grad_local summed over each step's particles.
    grad_steps: Vec<f32>,
    grad_pooled: Vec<f32>,
    grad_relu: Vec<f32>,
    own_weights: Vec<f32>,
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

    /// Training's pass over `steps · k` particles, particle i seeing step i / k's observation:
    /// map features [n][map_channels][side][side] and observation features
    /// [steps][obs_channels][side][side] → acts.loglik [n], keeping what `backward` needs.
    pub fn forward(
        &self,
        p: &Params,
        map_features: &[f32],
        obs_features: &[f32],
        (steps, k): (usize, usize),
        acts: &mut JointActivations,
    ) {
        let (n, channels, positions) = (steps * k, 2 * self.lc3.0.filters, self.out_side * self.out_side);
        let mut terms = std::mem::take(&mut acts.terms);
        sized(&mut terms, steps * self.term_len());
        self.observation_terms(p, obs_features, steps, &mut terms, acts);
        acts.step_of.clear();
        acts.step_of.extend((0..n).map(|i| (i / k) as u32));
        sized(&mut acts.products, n * channels * positions);
        for (offset, (layer, w, _)) in self.layers() {
            let (w, products) = (p.get(*w), &mut acts.products);
            let (c_map, scratch) = (self.map_channels, &mut acts.scratch);
            layer.forward_own_channels(
                w,
                map_features,
                c_map,
                &terms,
                &acts.step_of,
                products,
                channels,
                offset,
                scratch,
            );
        }
        acts.terms = terms;
        sized(&mut acts.local, n * channels * positions);
        samples_outermost(&acts.products, n, channels * positions, positions, &mut acts.local);
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

    /// The backward pass of `forward` (same map features and `(steps, k)`): from d loss / d loglik
    /// [n] to the weight gradients (accumulated), d map features `dmap` [n][map_channels][side][side]
    /// and d observation features `dobs` [steps][obs_channels][side][side] (both overwritten).
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        p: &Params,
        map_features: &[f32],
        (steps, k): (usize, usize),
        acts: &mut JointActivations,
        dloglik: &[f32],
        grads: &mut [f32],
        dmap: &mut [f32],
        dobs: &mut [f32],
    ) {
        let n = steps * k;
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
        // The map channels' products, particle by particle.
        dmap.fill(0.0);
        for (offset, (layer, w, b)) in self.layers() {
            let weight = p.get(*w);
            let (dw, _) = p.pair_mut(grads, *w, *b);
            let (dy, own, scratch) = (&a.grad_local, &mut a.own_weights, &mut a.scratch);
            let c_map = self.map_channels;
            layer.backward_own_channels(
                weight,
                map_features,
                c_map,
                n,
                dy,
                channels,
                offset,
                dw,
                Some(&mut *dmap),
                own,
                scratch,
            );
        }
        // The observation's products and the bias, once per step from its particles' summed gradient.
        let per_particle = channels * o * o;
        zeroed(&mut a.grad_steps, steps * per_particle);
        for (i, g) in a.grad_local.chunks_exact(per_particle).take(n).enumerate() {
            a.grad_steps[i / k * per_particle..][..per_particle].iter_mut().zip(g).for_each(|(s, g)| *s += g);
        }
        zeroed(&mut a.dinput, steps * self.input_len());
        for (offset, (layer, w, b)) in self.layers() {
            let weight = p.get(*w);
            let (dw, db) = p.pair_mut(grads, *w, *b);
            let dinput = Some(&mut a.dinput[..]);
            layer.backward(
                weight,
                &a.input,
                steps,
                &a.grad_steps,
                channels,
                offset,
                dw,
                db,
                dinput,
                &mut a.scratch,
            );
        }
        let m = self.map_channels * self.side * self.side;
        for (d, row) in
            dobs.chunks_exact_mut(self.input_len() - m).zip(a.dinput.chunks_exact(self.input_len()))
        {
            d.copy_from_slice(&row[m..]);
        }
    }
}

/// `from` [rows][n] (a row per output channel and position, samples innermost, as the shared
/// products leave it; row r = position · channels + channel) → `to` [n][channels][positions], in
/// tiles of 16 samples: a cache line of `from` read at a time, `to` written along its positions.
fn samples_outermost(from: &[f32], n: usize, rows: usize, positions: usize, to: &mut [f32]) {
    let channels = rows / positions;
    for i0 in (0..n).step_by(16) {
        let tile = 16.min(n - i0);
        for c in 0..channels {
            for pos in 0..positions {
                let row = &from[(pos * channels + c) * n + i0..][..tile];
                for (j, &v) in row.iter().enumerate() {
                    to[((i0 + j) * channels + c) * positions + pos] = v;
                }
            }
        }
    }
}
