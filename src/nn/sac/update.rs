//! One SAC update (Haarnoja et al. 2018), in the paper's order and names, like CleanRL's
//! `sac_continuous_action.py`: the critics' soft Bellman target, the critic loss, the actor
//! loss, the entropy coefficient, then the Polyak average of the target critics.
//!
//! The image encoders are shared (DrQ / SAC-AE): the critic loss trains them, the actor reads
//! their features with the gradient stopped. Separate encoders per network (Stable-Baselines3's
//! default) cost ≈ 3× as much per update on a CPU (the JAX peer: 1,984 vs 772 ms for the paper's
//! networks), and the update, not the simulator, bounds training on two cores. As in the JAX
//! peer's shared variant, one Adam step applies the critic and actor gradients together, the
//! actor's loss seeing the critics as they were before the step.
//!
//! On two cores the twin critics run side by side, and the actor's passes beside the encoders'
//! (`rayon::join`): each writes only its own buffers and slice of the gradient, so no sum's
//! order, and no byte of the result, depends on which thread ran what.

use crate::nn::PARALLEL_SLICE;
use crate::nn::adam::{Adam, AdamConfig};
use crate::nn::buffers::zeroed;
use crate::nn::sac::config::ACTION_LEN;
use crate::nn::sac::mlp::{Mlp, MlpActivations};
use crate::nn::sac::networks::{FeatureWorkspace, Observations, SacNetworks};
use crate::nn::sac::tanh_gaussian::{self, HEAD_LEN};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// SAC's hyper-parameters; defaults are the paper's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SacHyper {
    /// Discount γ.
    pub gamma: f32,
    /// Polyak rate τ of the target critics.
    pub tau: f32,
    /// Adam's learning rate for the networks and the entropy coefficient.
    pub learning_rate: f32,
    /// Entropy target of the learned coefficient α (SAC's heuristic −|A| = −2).
    pub target_entropy: f32,
    /// α before training.
    pub initial_alpha: f32,
}

impl Default for SacHyper {
    fn default() -> Self {
        Self {
            gamma: 0.99,
            tau: 0.005,
            learning_rate: 3e-4,
            target_entropy: -(ACTION_LEN as f32),
            initial_alpha: 1.0,
        }
    }
}

impl SacHyper {
    pub fn check(&self) -> Result<(), String> {
        let unit = |v: f32| (0.0..=1.0).contains(&v);
        if !unit(self.gamma) {
            return Err(format!("gamma: expected a discount in [0, 1], got {}", self.gamma));
        }
        if !unit(self.tau) {
            return Err(format!("tau: expected a Polyak rate in [0, 1], got {}", self.tau));
        }
        if !(self.learning_rate > 0.0 && self.learning_rate.is_finite()) {
            return Err(format!("learning_rate: expected > 0, got {}", self.learning_rate));
        }
        if !self.target_entropy.is_finite() {
            return Err("target_entropy: expected a finite number".into());
        }
        if !(self.initial_alpha > 0.0 && self.initial_alpha.is_finite()) {
            return Err(format!("initial_alpha: expected > 0, got {}", self.initial_alpha));
        }
        Ok(())
    }
}

/// A sampled minibatch of transitions (s, a, r, s′, d).
#[derive(Clone, Copy, Debug)]
pub struct Transitions<'a> {
    pub obs: Observations<'a>,
    /// `[n][2]`, in [−1, 1].
    pub actions: &'a [f32],
    pub rewards: &'a [f32],
    /// 1 where the episode ended with this transition (no bootstrap), else 0.
    pub dones: &'a [f32],
    pub next_obs: Observations<'a>,
}

/// What one update measured, for the training log.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UpdateStats {
    pub critic_loss: f32,
    pub actor_loss: f32,
    pub alpha: f32,
    /// Mean Q₁(s, a) over the batch.
    pub q: f32,
    /// Mean −log π(ã|s): the policy's entropy estimate.
    pub entropy: f32,
}

/// Buffers of one update, sized on first use.
#[derive(Clone, Debug, Default)]
struct UpdateWorkspace {
    encoders: FeatureWorkspace,
    next_encoders: FeatureWorkspace,
    features: Vec<f32>,
    next_features: Vec<f32>,
    target_features: Vec<f32>,
    actor: MlpActivations,
    critics: [CriticBuffers; 2],
    critic_input: Vec<f32>,
    d_critic_input: Vec<f32>,
    next_actions: Vec<f32>,
    next_log_prob: Vec<f32>,
    y: Vec<f32>,
    pi_actions: Vec<f32>,
    log_prob: Vec<f32>,
    /// Per transition, whether Q₁(s, ã) ≤ Q₂(s, ã): the critic the actor's gradient flows through.
    first_smaller: Vec<bool>,
    d_actions: Vec<f32>,
    d_log_prob: Vec<f32>,
    d_head: Vec<f32>,
    d_features: Vec<f32>,
    grads: Vec<f32>,
}

/// One critic's buffers: the critics run side by side, so each writes only its own.
#[derive(Clone, Debug, Default)]
struct CriticBuffers {
    acts: MlpActivations,
    /// Its output of the last forward pass (target, then for the actor's actions).
    q: Vec<f32>,
    d_q: Vec<f32>,
    /// The gradient of its input, `[n][f + 2]`.
    d_input: Vec<f32>,
}

impl CriticBuffers {
    /// `critic`'s forward pass on `input`, its output kept in `q`.
    fn forward(&mut self, critic: &Mlp, weights: &[f32], input: &[f32], n: usize) {
        critic.forward(weights, input, n, &mut self.acts);
        self.q.clear();
        self.q.extend_from_slice(self.acts.output());
    }
}

/// The learner's whole state: networks, target critics, optimizers, entropy coefficient.
#[derive(Clone, Debug)]
pub struct SacLearner {
    pub nets: SacNetworks,
    /// The target network's arena (only `..critic_len`, encoders and critics, is used).
    pub target: Vec<f32>,
    pub adam: Adam,
    pub log_alpha: f32,
    pub alpha_adam: Adam,
    pub hyper: SacHyper,
    ws: UpdateWorkspace,
}

impl SacLearner {
    pub fn new(nets: SacNetworks, hyper: SacHyper) -> Self {
        let adam_config = AdamConfig { learning_rate: hyper.learning_rate, ..AdamConfig::default() };
        Self {
            target: nets.params.values.clone(),
            adam: Adam::new(adam_config.clone(), nets.params.len()),
            log_alpha: hyper.initial_alpha.ln(),
            alpha_adam: Adam::new(adam_config, 1),
            nets,
            hyper,
            ws: UpdateWorkspace::default(),
        }
    }

    pub fn alpha(&self) -> f32 {
        self.log_alpha.exp()
    }

    /// The soft Bellman targets y of the last update.
    pub fn last_targets(&self) -> &[f32] {
        &self.ws.y
    }

    /// One update on `batch`. `noise` `[2n][2]` is N(0, 1): the first `n` rows sample the next
    /// actions a′, the last `n` the actor's actions ã.
    pub fn update(&mut self, batch: &Transitions, noise: &[f32]) -> UpdateStats {
        let stats = self.gradients(batch, noise);
        let Self { nets, target, adam, log_alpha, alpha_adam, hyper, ws } = self;
        adam.update(&mut nets.params.values, &ws.grads);

        // Entropy coefficient: loss −log α · mean(log π(ã|s) + H̄), so α grows while the policy's
        // entropy is below the target H̄ and shrinks above it.
        alpha_adam.update(std::slice::from_mut(log_alpha), &[stats.entropy - hyper.target_entropy]);

        // Target critics: θ̄ ← τ θ + (1 − τ) θ̄ (in fixed slices on the pool: element-wise, so
        // the same bytes on any number of threads).
        let tau = hyper.tau;
        let online = &nets.params.values[..nets.critic_len];
        target[..nets.critic_len]
            .par_chunks_mut(PARALLEL_SLICE)
            .zip(online.par_chunks(PARALLEL_SLICE))
            .for_each(|(t, v)| {
                for (t, &v) in t.iter_mut().zip(v) {
                    *t = tau * v + (1.0 - tau) * *t;
                }
            });
        stats
    }

    /// The losses of `batch` and their gradient with respect to the networks (into `ws.grads`,
    /// laid out like the arena), without changing any weight.
    fn gradients(&mut self, batch: &Transitions, noise: &[f32]) -> UpdateStats {
        let n = batch.obs.n;
        assert_eq!(noise.len(), 2 * n * ACTION_LEN, "noise: two actions' worth per transition");
        let (next_noise, pi_noise) = noise.split_at(n * ACTION_LEN);
        let Self { nets, target, log_alpha, hyper, ws, .. } = self;
        let (values, f) = (&nets.params.values, nets.feature_len());
        let (alpha, gamma) = (log_alpha.exp(), hyper.gamma);

        // Soft Bellman target, no gradient:
        // y = r + γ (1 − d) (min_i Q̄_i(s′, a′) − α log π(a′|s′)),  a′ ~ π(·|s′).
        // The actor (one thread) beside the target encoders (the pool): neither reads the other.
        nets.encode(values, &batch.next_obs, &mut ws.next_encoders, &mut ws.next_features);
        rayon::join(
            || {
                nets.actor.forward(values, &ws.next_features, n, &mut ws.actor);
                zeroed(&mut ws.next_actions, n * ACTION_LEN);
                zeroed(&mut ws.next_log_prob, n);
                let (mean_log_std, a, log_prob) =
                    (ws.actor.output(), &mut ws.next_actions, &mut ws.next_log_prob);
                tanh_gaussian::sample(mean_log_std, next_noise, a, log_prob);
            },
            || nets.encode(target, &batch.next_obs, &mut ws.next_encoders, &mut ws.target_features),
        );
        concat(&ws.target_features, &ws.next_actions, f, &mut ws.critic_input);
        forward_critics(&nets.critics, &mut ws.critics, target, &ws.critic_input, n);
        let [q1, q2] = [&ws.critics[0].q, &ws.critics[1].q];
        ws.y.clear();
        ws.y.extend((0..n).map(|k| {
            let min_q = q1[k].min(q2[k]);
            batch.rewards[k] + gamma * (1.0 - batch.dones[k]) * (min_q - alpha * ws.next_log_prob[k])
        }));

        // Critic loss: Σ_i mean (Q_i(s, a) − y)², into the critics and the encoders.
        zeroed(&mut ws.grads, values.len());
        nets.encode(values, &batch.obs, &mut ws.encoders, &mut ws.features);
        concat(&ws.features, batch.actions, f, &mut ws.critic_input);
        let (input, y) = (&ws.critic_input, &ws.y);
        let critic_grads = critics_part(nets, &mut ws.grads);
        both_critics(&nets.critics, &mut ws.critics, critic_grads, |critic, c, grads| {
            c.forward(critic, values, input, n);
            c.d_q.clear();
            c.d_q.extend(c.q.iter().zip(y).map(|(q, y)| 2.0 * (q - y) / n as f32));
            zeroed(&mut c.d_input, input.len());
            critic.backward(values, input, n, &mut c.acts, &c.d_q, Some(grads), Some(&mut c.d_input));
        });
        let mse = |q: &[f32]| q.iter().zip(&ws.y).map(|(q, y)| (q - y) * (q - y)).sum::<f32>() / n as f32;
        let critic_loss = mse(&ws.critics[0].q) + mse(&ws.critics[1].q);
        let q_mean = ws.critics[0].q.iter().sum::<f32>() / n as f32;
        sum_critic_input_grads(&ws.critics, &mut ws.d_critic_input);
        ws.d_features.clear();
        ws.d_features.extend(ws.d_critic_input.chunks_exact(f + ACTION_LEN).flat_map(|row| &row[..f]));

        // Actor loss: mean (α log π(ã|s) − min_i Q_i(s, ã)),  ã ~ π(·|s), on stopped features,
        // through the critics without training them.
        nets.actor.forward(values, &ws.features, n, &mut ws.actor);
        zeroed(&mut ws.pi_actions, n * ACTION_LEN);
        zeroed(&mut ws.log_prob, n);
        tanh_gaussian::sample(ws.actor.output(), pi_noise, &mut ws.pi_actions, &mut ws.log_prob);
        concat(&ws.features, &ws.pi_actions, f, &mut ws.critic_input);
        forward_critics(&nets.critics, &mut ws.critics, values, &ws.critic_input, n);
        let input = &ws.critic_input;
        let (critics, log_prob) = (&mut ws.critics, &ws.log_prob);
        let min_q = |k: usize| critics[0].q[k].min(critics[1].q[k]);
        let actor_loss = (0..n).map(|k| alpha * log_prob[k] - min_q(k)).sum::<f32>() / n as f32;
        // The minimum's gradient flows through the smaller critic only.
        ws.first_smaller.clear();
        ws.first_smaller.extend((0..n).map(|k| critics[0].q[k] <= critics[1].q[k]));
        let first_smaller = &ws.first_smaller;
        both_critics(&nets.critics, critics, [true, false], |critic, c, first| {
            c.d_q.clear();
            c.d_q.extend(first_smaller.iter().map(|&f| if f == first { -1.0 / n as f32 } else { 0.0 }));
            zeroed(&mut c.d_input, input.len());
            critic.backward(values, input, n, &mut c.acts, &c.d_q, None, Some(&mut c.d_input));
        });
        sum_critic_input_grads(&ws.critics, &mut ws.d_critic_input);
        ws.d_actions.clear();
        ws.d_actions.extend(ws.d_critic_input.chunks_exact(f + ACTION_LEN).flat_map(|row| &row[f..]));
        ws.d_log_prob.clear();
        ws.d_log_prob.resize(n, alpha / n as f32);
        zeroed(&mut ws.d_head, n * HEAD_LEN);
        tanh_gaussian::backward(
            ws.actor.output(),
            pi_noise,
            &ws.pi_actions,
            &ws.d_actions,
            &ws.d_log_prob,
            &mut ws.d_head,
        );
        // The actor's backward beside the encoders' (the critic loss's): separate gradients.
        let (encoders_and_critics, actor_grads) = ws.grads.split_at_mut(nets.critic_len);
        rayon::join(
            || {
                nets.actor.backward(
                    values,
                    &ws.features,
                    n,
                    &mut ws.actor,
                    &ws.d_head,
                    Some(actor_grads),
                    None,
                )
            },
            || {
                nets.encode_backward(
                    values,
                    &batch.obs,
                    &mut ws.encoders,
                    &ws.d_features,
                    encoders_and_critics,
                )
            },
        );
        let mean_log_prob = ws.log_prob.iter().sum::<f32>() / n as f32;
        UpdateStats { critic_loss, actor_loss, alpha, q: q_mean, entropy: -mean_log_prob }
    }
}

/// Runs `step` on both critics at once, each with its own buffers and its `part` (its slice of
/// the gradient, or a flag): the twins write nothing in common, and their MLPs, a third of a
/// one-thread update, would otherwise leave the second core idle. Each critic's arithmetic is
/// the same whichever thread runs it.
fn both_critics<P: Send>(
    critics: &[Mlp; 2],
    buffers: &mut [CriticBuffers; 2],
    [p1, p2]: [P; 2],
    step: impl Fn(&Mlp, &mut CriticBuffers, P) + Sync,
) {
    let [b1, b2] = buffers;
    rayon::join(|| step(&critics[0], b1, p1), || step(&critics[1], b2, p2));
}

/// Both critics' forward passes on `input` with `weights` (online or target), side by side.
fn forward_critics(
    critics: &[Mlp; 2],
    buffers: &mut [CriticBuffers; 2],
    weights: &[f32],
    input: &[f32],
    n: usize,
) {
    both_critics(critics, buffers, [(), ()], |critic, c, ()| c.forward(critic, weights, input, n));
}

/// The two critics' parts of the arena's gradient, side by side.
fn critics_part<'a>(nets: &SacNetworks, grads: &'a mut [f32]) -> [&'a mut [f32]; 2] {
    let [r1, r2] = [nets.critics[0].params(), nets.critics[1].params()];
    assert_eq!(r1.end, r2.start, "the critics' tensors are adjacent in the arena");
    let (g1, g2) = grads[r1.start..r2.end].split_at_mut(r1.len());
    [g1, g2]
}

/// `d_input` ← the sum of both critics' input gradients, first critic first.
fn sum_critic_input_grads(critics: &[CriticBuffers; 2], d_input: &mut Vec<f32>) {
    d_input.clear();
    d_input.extend(critics[0].d_input.iter().zip(&critics[1].d_input).map(|(a, b)| a + b));
}

/// Rows of `features` `[n][f]` ⊕ `actions` `[n][2]` into `out` `[n][f + 2]`.
fn concat(features: &[f32], actions: &[f32], f: usize, out: &mut Vec<f32>) {
    out.clear();
    for (row, a) in features.chunks_exact(f).zip(actions.chunks_exact(ACTION_LEN)) {
        out.extend_from_slice(row);
        out.extend_from_slice(a);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad, test_values};
    use crate::nn::sac::config::SacNetConfig;

    fn tiny() -> SacNetConfig {
        SacNetConfig {
            conv_channels: vec![3],
            encoder_fc: 4,
            mlp_width: 6,
            belief_cells: 5,
            belief_channels: 4,
            grid_cells: 5,
            depth_columns: 2,
        }
    }

    /// A fixed batch of `n` random transitions.
    struct Batch {
        n: usize,
        belief: [Vec<f32>; 2],
        grid: [Vec<f32>; 2],
        state: [Vec<f32>; 2],
        actions: Vec<f32>,
        rewards: Vec<f32>,
        dones: Vec<f32>,
    }

    impl Batch {
        fn new(n: usize, config: &SacNetConfig) -> Self {
            let image = |len: usize, seed| test_values(len, seed).iter().map(|v| v.abs()).collect::<Vec<_>>();
            let (b, g) =
                (n * config.belief_channels * config.belief_cells.pow(2), n * config.grid_cells.pow(2));
            Self {
                n,
                belief: [image(b, 1), image(b, 2)],
                grid: [image(g, 3), image(g, 4)],
                state: [test_values(n * config.state_len(), 5), test_values(n * config.state_len(), 6)],
                actions: test_values(n * ACTION_LEN, 7),
                rewards: test_values(n, 8),
                dones: (0..n).map(|k| (k % 3 == 0) as u8 as f32).collect(),
            }
        }

        fn transitions(&self) -> Transitions<'_> {
            let obs = |i: usize| Observations {
                n: self.n,
                belief: &self.belief[i],
                grid: &self.grid[i],
                state: &self.state[i],
            };
            Transitions {
                obs: obs(0),
                actions: &self.actions,
                rewards: &self.rewards,
                dones: &self.dones,
                next_obs: obs(1),
            }
        }
    }

    /// Sets the last layer of an MLP (weights 0, the given bias) so that its output is constant.
    fn constant_output(values: &mut [f32], nets: &SacNetworks, prefix: &str, bias: &[f32]) {
        let layers = nets.params.specs().filter(|(_, s)| s.name.starts_with(prefix)).count() / 2;
        let find =
            |suffix: &str| nets.params.find(&format!("{prefix}/dense{}/{suffix}", layers - 1)).unwrap();
        values[nets.params.range(find("kernel"))].fill(0.0);
        values[nets.params.range(find("bias"))].copy_from_slice(bias);
    }

    fn log_prob_closed_form(mean: &[f32; 2], log_std: &[f32; 2], noise: &[f32]) -> f32 {
        (0..2)
            .map(|j| {
                let a = (mean[j] + log_std[j].exp() * noise[j]).tanh();
                -0.5 * noise[j] * noise[j]
                    - log_std[j]
                    - 0.5 * (2.0 * std::f32::consts::PI).ln()
                    - (1.0 - a * a + 1e-6).ln()
            })
            .sum()
    }

    #[test]
    fn critic_target_and_entropy_coefficient_match_hand_computed_values() {
        let config = tiny();
        let mut nets = SacNetworks::new(&config, 3);
        let (mean, log_std) = ([0.2f32, -0.4], [-0.3f32, 0.1]);
        let mut values = nets.params.values.clone();
        constant_output(&mut values, &nets, "actor", &[mean[0], mean[1], log_std[0], log_std[1]]);
        constant_output(&mut values, &nets, "critic1", &[1.5]);
        constant_output(&mut values, &nets, "critic2", &[0.7]);
        nets.params.values = values;
        let hyper = SacHyper { initial_alpha: 0.2, ..SacHyper::default() };
        let mut learner = SacLearner::new(nets, hyper.clone());
        let batch = Batch::new(4, &config);
        let noise = test_values(2 * 4 * ACTION_LEN, 11);
        learner.update(&batch.transitions(), &noise);
        for k in 0..4 {
            let log_pi = log_prob_closed_form(&mean, &log_std, &noise[k * 2..k * 2 + 2]);
            let want = batch.rewards[k] + 0.99 * (1.0 - batch.dones[k]) * (0.7 - 0.2 * log_pi);
            let got = learner.last_targets()[k];
            assert!((got - want).abs() < 1e-5, "y[{k}] = {got}, hand-computed {want}");
        }
        // Adam's first step moves log α by the learning rate against the gradient's sign;
        // gradient = −(mean log π(ã) + H̄).
        let mean_log_pi: f32 =
            (4..8).map(|k| log_prob_closed_form(&mean, &log_std, &noise[k * 2..k * 2 + 2])).sum::<f32>()
                / 4.0;
        let grad = -(mean_log_pi + hyper.target_entropy);
        let want = 0.2f32.ln() - hyper.learning_rate * grad.signum();
        assert!(
            (learner.log_alpha - want).abs() < 1e-6,
            "log α = {}, hand-computed {want}",
            learner.log_alpha
        );
    }

    /// Critic and actor gradients against finite differences of the losses the update reports.
    /// For the critic, the target network is zeroed and α tiny, so that the target y is r and
    /// does not move with the online weights (it is a stopped gradient, which finite differences
    /// cannot stop).
    #[test]
    fn gradients_match_finite_differences_of_the_losses() {
        let config = tiny();
        let batch = Batch::new(5, &config);
        let noise = test_values(2 * 5 * ACTION_LEN, 12);
        let check = |initial_alpha: f32,
                     which: fn(&UpdateStats) -> f32,
                     part: &dyn Fn(&SacNetworks) -> std::ops::Range<usize>,
                     what: &str| {
            let mut nets = SacNetworks::new(&config, 5);
            // Zero biases put ReLUs exactly at their kink for all-zero inputs, where finite
            // differences see half a slope: shift every weight a little.
            let shift = test_values(nets.params.len(), 6);
            nets.params.values.iter_mut().zip(shift).for_each(|(v, s)| *v += 0.05 * s);
            let mut learner = SacLearner::new(nets, SacHyper { initial_alpha, ..SacHyper::default() });
            learner.target.fill(0.0);
            learner.gradients(&batch.transitions(), &noise);
            let range = part(&learner.nets);
            let grads = learner.ws.grads[range.clone()].to_vec();
            let v64: Vec<f64> = learner.nets.params.values.iter().map(|&v| f64::from(v)).collect();
            let numeric = numerical_grad(&v64[range.clone()], 1e-3, |sub| {
                let mut probe = learner.clone();
                let values = &mut probe.nets.params.values;
                values[range.clone()].iter_mut().zip(sub).for_each(|(v, &x)| *v = x as f32);
                f64::from(which(&probe.gradients(&batch.transitions(), &noise)))
            });
            assert_close(&grads, &numeric, 1e-2, what);
        };
        check(1e-8, |s| s.critic_loss, &|nets| 0..nets.critic_len, "critic-loss gradient");
        // The actor's loss trains only the actor (stopped features, frozen critics).
        check(0.5, |s| s.actor_loss, &|nets| nets.critic_len..nets.params.len(), "actor-loss gradient");
    }

    #[test]
    fn one_update_lowers_the_critic_loss() {
        let config = tiny();
        let hyper = SacHyper { initial_alpha: 1e-6, tau: 0.0, learning_rate: 1e-3, ..SacHyper::default() };
        let mut learner = SacLearner::new(SacNetworks::new(&config, 9), hyper);
        let batch = Batch::new(16, &config);
        let noise = test_values(2 * 16 * ACTION_LEN, 13);
        let before = learner.update(&batch.transitions(), &noise).critic_loss;
        let after = learner.update(&batch.transitions(), &noise).critic_loss;
        assert!(after < before, "critic loss {before} → {after}");
    }
}
