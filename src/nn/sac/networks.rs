//! The agent's networks in one parameter arena: two image encoders (belief crop, LiDAR grid), the
//! twin critics and the actor, in that order, so the target network is a copy of the arena's
//! prefix. The encoders are shared: trained by the critics' loss only, read by the actor with the
//! gradient stopped (the DrQ / SAC-AE arrangement; see `update.rs` for why).

use crate::nn::PARALLEL_SLICE;
use crate::nn::params::Params;
use crate::nn::sac::config::{ACTION_LEN, SacNetConfig};
use crate::nn::sac::encoder::{EncoderActivations, ImageEncoder};
use crate::nn::sac::mlp::{Mlp, MlpActivations};
use crate::nn::sac::tanh_gaussian::{self, HEAD_LEN};
use rand::SeedableRng;
use rayon::prelude::*;

/// Samples per parallel encoder task. Fixed, so gradients sum in the same order on any number
/// of threads.
pub const ENCODER_CHUNK: usize = 32;

/// A batch of observations as network inputs: belief crops `[n][channels][cells][cells]`, LiDAR
/// grids `[n][1][cells][cells]`, robot states ⊕ depth strips `[n][config.state_len()]`.
#[derive(Clone, Copy, Debug)]
pub struct Observations<'a> {
    pub n: usize,
    pub belief: &'a [f32],
    pub grid: &'a [f32],
    pub state: &'a [f32],
}

#[derive(Clone, Debug)]
pub struct SacNetworks {
    pub config: SacNetConfig,
    pub params: Params,
    pub belief: ImageEncoder,
    pub grid: ImageEncoder,
    pub critics: [Mlp; 2],
    pub actor: Mlp,
    /// Arena prefix of the encoders.
    pub encoder_len: usize,
    /// Arena prefix of the encoders and critics: what the target network tracks.
    pub critic_len: usize,
}

#[derive(Clone, Debug, Default)]
struct ChunkActivations {
    belief: EncoderActivations,
    grid: EncoderActivations,
    d_belief: Vec<f32>,
    d_grid: Vec<f32>,
    grads: Vec<f32>,
}

/// Encoder activations of one batch, per chunk; reused from call to call.
#[derive(Clone, Debug, Default)]
pub struct FeatureWorkspace {
    chunks: Vec<ChunkActivations>,
}

/// The actions the critics weigh beside tanh(μ), `[n][k][2]`.
#[derive(Clone, Copy, Debug)]
pub enum Candidates<'a> {
    /// Drawn from the policy with these standard normals.
    Drawn(&'a [f32]),
    /// These actions, in [−1, 1].
    Given(&'a [f32]),
}

/// Buffers of the policy's forward pass in the environment loop.
#[derive(Clone, Debug, Default)]
pub struct PolicyWorkspace {
    encoders: FeatureWorkspace,
    features: Vec<f32>,
    actor: MlpActivations,
    log_prob: Vec<f32>,
    candidates: Vec<f32>,
    critic_input: Vec<f32>,
    critics: [MlpActivations; 2],
}

impl SacNetworks {
    /// Glorot-initialised networks, drawn from `seed`.
    pub fn new(config: &SacNetConfig, seed: u64) -> Self {
        let mut nets = Self::zeros(config);
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        nets.belief.init(&mut nets.params, &mut rng);
        nets.grid.init(&mut nets.params, &mut rng);
        for mlp in nets.critics.iter().chain([&nets.actor]) {
            mlp.init(&mut nets.params, &mut rng);
        }
        nets
    }

    /// The layout with every weight 0 (to be filled from a checkpoint).
    pub fn zeros(config: &SacNetConfig) -> Self {
        let c = config;
        let mut params = Params::new();
        let belief = ImageEncoder::new(
            &mut params,
            "belief",
            c.belief_channels,
            c.belief_cells,
            &c.conv_channels,
            c.encoder_fc,
        );
        let grid = ImageEncoder::new(&mut params, "grid", 1, c.grid_cells, &c.conv_channels, c.encoder_fc);
        let encoder_len = params.len();
        let (f, w) = (c.feature_len(), c.mlp_width);
        let critics =
            [0, 1].map(|i| Mlp::new(&mut params, &format!("critic{}", i + 1), &[f + ACTION_LEN, w, w, 1]));
        let critic_len = params.len();
        let actor = Mlp::new(&mut params, "actor", &[f, w, w, HEAD_LEN]);
        Self { config: config.clone(), params, belief, grid, critics, actor, encoder_len, critic_len }
    }

    pub fn feature_len(&self) -> usize {
        self.config.feature_len()
    }

    /// `features` `[n][F]` = belief features ⊕ grid features ⊕ state (⊕ depth), on weights `values`
    /// (the online arena or the target copy).
    pub fn encode(
        &self,
        values: &[f32],
        obs: &Observations,
        ws: &mut FeatureWorkspace,
        features: &mut Vec<f32>,
    ) {
        let (n, f, fc, sl) = (obs.n, self.feature_len(), self.config.encoder_fc, self.config.state_len());
        let (bl, gl) = (self.belief.input_len(), self.grid.input_len());
        assert!(obs.belief.len() == n * bl && obs.grid.len() == n * gl && obs.state.len() == n * sl);
        ws.chunks.resize(n.div_ceil(ENCODER_CHUNK), ChunkActivations::default());
        features.resize(n * f, 0.0);
        features.par_chunks_mut(ENCODER_CHUNK * f).zip(ws.chunks.par_iter_mut()).enumerate().for_each(
            |(c, (out, acts))| {
                let (start, m) = (c * ENCODER_CHUNK, out.len() / f);
                self.belief.forward(values, &obs.belief[start * bl..(start + m) * bl], m, &mut acts.belief);
                self.grid.forward(values, &obs.grid[start * gl..(start + m) * gl], m, &mut acts.grid);
                for (k, row) in out.chunks_exact_mut(f).enumerate() {
                    row[..fc].copy_from_slice(&acts.belief.features[k * fc..(k + 1) * fc]);
                    row[fc..2 * fc].copy_from_slice(&acts.grid.features[k * fc..(k + 1) * fc]);
                    row[2 * fc..].copy_from_slice(&obs.state[(start + k) * sl..(start + k + 1) * sl]);
                }
            },
        );
    }

    /// Accumulates into `grads[..encoder_len]` the encoders' gradient, given the gradient with
    /// respect to the features of the last [`SacNetworks::encode`] on `obs` with `ws`.
    pub fn encode_backward(
        &self,
        values: &[f32],
        obs: &Observations,
        ws: &mut FeatureWorkspace,
        d_features: &[f32],
        grads: &mut [f32],
    ) {
        let (f, fc, enc) = (self.feature_len(), self.config.encoder_fc, self.encoder_len);
        let (bl, gl) = (self.belief.input_len(), self.grid.input_len());
        assert_eq!(d_features.len(), obs.n * f, "feature gradient length");
        d_features.par_chunks(ENCODER_CHUNK * f).zip(ws.chunks.par_iter_mut()).enumerate().for_each(
            |(c, (d, acts))| {
                let (start, m) = (c * ENCODER_CHUNK, d.len() / f);
                acts.d_belief.clear();
                acts.d_grid.clear();
                for row in d.chunks_exact(f) {
                    acts.d_belief.extend_from_slice(&row[..fc]);
                    acts.d_grid.extend_from_slice(&row[fc..2 * fc]);
                }
                acts.grads.clear();
                acts.grads.resize(enc, 0.0);
                let ChunkActivations { belief, grid, d_belief, d_grid, grads } = acts;
                self.belief.backward(
                    values,
                    &obs.belief[start * bl..(start + m) * bl],
                    m,
                    belief,
                    d_belief,
                    grads,
                );
                self.grid.backward(values, &obs.grid[start * gl..(start + m) * gl], m, grid, d_grid, grads);
            },
        );
        // The chunks' gradients summed in chunk order, over fixed slices of the arena in
        // parallel: the same bytes on any number of threads.
        let chunks = &ws.chunks[..obs.n.div_ceil(ENCODER_CHUNK)];
        grads[..enc].par_chunks_mut(PARALLEL_SLICE).enumerate().for_each(|(k, g)| {
            for chunk in chunks {
                g.iter_mut().zip(&chunk.grads[k * PARALLEL_SLICE..]).for_each(|(g, c)| *g += c);
            }
        });
    }

    /// The actor's heads `[n][4]` (means, log-standard deviations) for a batch of observations.
    pub fn policy_heads<'w>(&self, obs: &Observations, ws: &'w mut PolicyWorkspace) -> &'w [f32] {
        let values = &self.params.values;
        self.encode(values, obs, &mut ws.encoders, &mut ws.features);
        self.actor.forward(values, &ws.features, obs.n, &mut ws.actor);
        ws.actor.output()
    }

    /// Actions `[n][2]`: tanh(μ) when `noise` is None (evaluation), else sampled with that noise `[n][2]`.
    pub fn act(
        &self,
        obs: &Observations,
        noise: Option<&[f32]>,
        ws: &mut PolicyWorkspace,
        actions: &mut [f32],
    ) {
        self.policy_heads(obs, ws);
        let heads = ws.actor.output();
        match noise {
            None => tanh_gaussian::mean_action(heads, actions),
            Some(noise) => {
                ws.log_prob.resize(obs.n, 0.0);
                tanh_gaussian::sample(heads, noise, actions, &mut ws.log_prob);
            }
        }
    }

    /// Actions `[n][2]` chosen by the twin critics: of tanh(μ) and the `others`, the one with the
    /// highest min(Q₁, Q₂), the value SAC's actor is trained to raise; ties go to the earlier
    /// candidate, so tanh(μ) first.
    pub fn act_by_critics(
        &self,
        obs: &Observations,
        others: Candidates,
        ws: &mut PolicyWorkspace,
        actions: &mut [f32],
    ) {
        let n = obs.n;
        if n == 0 {
            return;
        }
        let (Candidates::Drawn(given) | Candidates::Given(given)) = others;
        assert_eq!(given.len() % (n * ACTION_LEN), 0, "candidates: [n][k][2]");
        let draws = given.len() / (n * ACTION_LEN);
        let candidates = 1 + draws;
        self.policy_heads(obs, ws);
        let PolicyWorkspace { features, actor, candidates: cand, critic_input, critics, .. } = ws;
        let f = self.feature_len();
        cand.resize(n * candidates * ACTION_LEN, 0.0);
        for (k, head) in actor.output().chunks_exact(HEAD_LEN).enumerate() {
            let out = &mut cand[k * candidates * ACTION_LEN..(k + 1) * candidates * ACTION_LEN];
            let (mean, drawn) = out.split_at_mut(ACTION_LEN);
            tanh_gaussian::mean_action(head, mean);
            let given = &given[k * draws * ACTION_LEN..(k + 1) * draws * ACTION_LEN];
            match others {
                Candidates::Drawn(_) => {
                    for (a, e) in drawn.chunks_exact_mut(ACTION_LEN).zip(given.chunks_exact(ACTION_LEN)) {
                        tanh_gaussian::sample(head, e, a, &mut [0.0]);
                    }
                }
                Candidates::Given(_) => drawn.copy_from_slice(given),
            }
        }
        critic_input.clear();
        for (row, out) in features.chunks_exact(f).zip(cand.chunks_exact(candidates * ACTION_LEN)) {
            for a in out.chunks_exact(ACTION_LEN) {
                critic_input.extend_from_slice(row);
                critic_input.extend_from_slice(a);
            }
        }
        for (critic, acts) in self.critics.iter().zip(critics.iter_mut()) {
            critic.forward(&self.params.values, critic_input, n * candidates, acts);
        }
        let [q1, q2] = [critics[0].output(), critics[1].output()];
        assert_eq!(actions.len(), n * ACTION_LEN, "actions: [n][2]");
        for (k, chosen) in actions.chunks_exact_mut(ACTION_LEN).enumerate() {
            let value = |c: usize| q1[k * candidates + c].min(q2[k * candidates + c]);
            let best = (1..candidates).fold(0, |best, c| if value(c) > value(best) { c } else { best });
            let at = (k * candidates + best) * ACTION_LEN;
            chosen.copy_from_slice(&cand[at..at + ACTION_LEN]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::test_values;

    #[test]
    fn chunked_encoding_equals_one_sample_at_a_time() {
        let config = SacNetConfig {
            conv_channels: vec![4, 4],
            encoder_fc: 8,
            mlp_width: 16,
            belief_cells: 11,
            belief_channels: 4,
            grid_cells: 9,
            depth_columns: 3,
        };
        let nets = SacNetworks::new(&config, 1);
        let n = ENCODER_CHUNK + 3;
        let belief: Vec<f32> = test_values(n * 4 * 121, 2).iter().map(|v| v.abs()).collect();
        let grid: Vec<f32> = test_values(n * 81, 3).iter().map(|v| v.abs()).collect();
        let sl = config.state_len();
        let state = test_values(n * sl, 4);
        let obs = Observations { n, belief: &belief, grid: &grid, state: &state };
        let (mut ws, mut all) = (FeatureWorkspace::default(), Vec::new());
        nets.encode(&nets.params.values, &obs, &mut ws, &mut all);
        let f = nets.feature_len();
        for k in [0, ENCODER_CHUNK, n - 1] {
            let one = Observations {
                n: 1,
                belief: &belief[k * 484..(k + 1) * 484],
                grid: &grid[k * 81..(k + 1) * 81],
                state: &state[k * sl..(k + 1) * sl],
            };
            let mut single = Vec::new();
            nets.encode(&nets.params.values, &one, &mut FeatureWorkspace::default(), &mut single);
            assert_eq!(single, all[k * f..(k + 1) * f], "sample {k}");
            assert_eq!(
                single[f - sl..],
                state[k * sl..(k + 1) * sl],
                "the state and depth close the features"
            );
        }
        assert!(all.iter().any(|&v| v != 0.0), "features must not all be zero");
    }

    #[test]
    fn the_critics_choose_the_candidate_with_the_highest_lower_q() {
        let config = SacNetConfig::tiny();
        let nets = SacNetworks::new(&config, 5);
        let (n, draws) = (3, 6);
        let belief: Vec<f32> = test_values(n * 100, 6).iter().map(|v| v.abs()).collect();
        let grid: Vec<f32> = test_values(n * 25, 7).iter().map(|v| v.abs()).collect();
        let state = test_values(n * config.state_len(), 8);
        let obs = Observations { n, belief: &belief, grid: &grid, state: &state };
        let noise: Vec<f32> = test_values(n * draws * ACTION_LEN, 9).iter().map(|v| 3.0 * v).collect();
        let given: Vec<f32> = noise.iter().map(|e| (e / 3.0).clamp(-1.0, 1.0)).collect();
        let mut ws = PolicyWorkspace::default();
        let (mut chosen, mut mean) = (vec![0.0; n * ACTION_LEN], vec![0.0; n * ACTION_LEN]);
        nets.act(&obs, None, &mut ws, &mut mean);
        nets.act_by_critics(&obs, Candidates::Drawn(&[]), &mut ws, &mut chosen);
        assert_eq!(chosen, mean, "no draws: tanh(μ)");

        // Each candidate on its own, valued by one critic row each; the first best wins.
        let mut features = Vec::new();
        nets.encode(&nets.params.values, &obs, &mut FeatureWorkspace::default(), &mut features);
        let f = nets.feature_len();
        let lower_q = |k: usize, a: &[f32]| {
            let input = [&features[k * f..(k + 1) * f], a].concat();
            let q = nets.critics.each_ref().map(|critic| {
                let mut acts = MlpActivations::default();
                critic.forward(&nets.params.values, &input, 1, &mut acts);
                acts.output()[0]
            });
            q[0].min(q[1])
        };
        let robot = |actions: &[f32], k: usize| actions[k * ACTION_LEN..(k + 1) * ACTION_LEN].to_vec();
        // (candidate index, action) of robot k's best among tanh(μ) and `others`.
        let best_of = |k: usize, others: Vec<Vec<f32>>| {
            let candidates: Vec<Vec<f32>> = std::iter::once(robot(&mean, k)).chain(others).collect();
            let values: Vec<f32> = candidates.iter().map(|a| lower_q(k, a)).collect();
            let best = (0..values.len()).fold(0, |b, c| if values[c] > values[b] { c } else { b });
            (best, candidates[best].clone())
        };
        let mut picked_another = [false; 2];

        nets.act_by_critics(&obs, Candidates::Given(&given), &mut ws, &mut chosen);
        for k in 0..n {
            let others = (0..draws).map(|j| robot(&given, k * draws + j)).collect();
            let (best, action) = best_of(k, others);
            assert_eq!(robot(&chosen, k), action, "given actions, robot {k}");
            picked_another[0] |= best > 0;
        }

        nets.act_by_critics(&obs, Candidates::Drawn(&noise), &mut ws, &mut chosen);
        for k in 0..n {
            // Draw j of every robot through `act`, which samples one action per robot.
            let others = (0..draws)
                .map(|j| {
                    let e: Vec<f32> = (0..n).flat_map(|r| robot(&noise, r * draws + j)).collect();
                    let mut drawn = vec![0.0; n * ACTION_LEN];
                    nets.act(&obs, Some(&e), &mut PolicyWorkspace::default(), &mut drawn);
                    robot(&drawn, k)
                })
                .collect();
            let (best, action) = best_of(k, others);
            assert_eq!(robot(&chosen, k), action, "drawn actions, robot {k}");
            picked_another[1] |= best > 0;
        }
        assert_eq!(picked_another, [true; 2], "some candidate must beat tanh(μ), or the test shows nothing");
    }
}
