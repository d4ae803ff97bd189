//! The actor's distribution: a Gaussian squashed by tanh into [−1, 1] (Haarnoja et al. 2018,
//! appendix C). The actor head outputs, per sample, the means of both actions and then their
//! log-standard deviations, clipped to [−20, 2] as in Stable-Baselines3.
//!
//! Samples are reparameterised, u = μ + σ·ε with ε ~ N(0, 1) drawn outside, so gradients flow
//! from the action and its log-probability into μ and log σ:
//! log π(a) = Σ [−ε²/2 − log σ − ½ log 2π − log(1 − a² + δ)], a = tanh(u).

use crate::nn::sac::config::ACTION_LEN;

pub const LOG_STD_MIN: f32 = -20.0;
pub const LOG_STD_MAX: f32 = 2.0;
/// Keeps log(1 − a²) finite where tanh saturates (SB3 and CleanRL use the same 1e-6).
const SQUASH_EPS: f32 = 1e-6;
/// Values per sample of the actor head: means, then log-standard deviations.
pub const HEAD_LEN: usize = 2 * ACTION_LEN;

const HALF_LOG_TWO_PI: f32 = 0.918_938_5;

fn log_std(raw: f32) -> f32 {
    raw.clamp(LOG_STD_MIN, LOG_STD_MAX)
}

/// Samples actions `[n][2]` and their log-probabilities `[n]` from heads `[n][4]` and noise `[n][2]`.
pub fn sample(head: &[f32], noise: &[f32], action: &mut [f32], log_prob: &mut [f32]) {
    let n = log_prob.len();
    assert!(head.len() == n * HEAD_LEN && noise.len() == n * ACTION_LEN && action.len() == n * ACTION_LEN);
    for (((h, e), a), lp) in head
        .chunks_exact(HEAD_LEN)
        .zip(noise.chunks_exact(ACTION_LEN))
        .zip(action.chunks_exact_mut(ACTION_LEN))
        .zip(log_prob)
    {
        *lp = 0.0;
        for j in 0..ACTION_LEN {
            let ls = log_std(h[ACTION_LEN + j]);
            a[j] = (h[j] + ls.exp() * e[j]).tanh();
            *lp += -0.5 * e[j] * e[j] - ls - HALF_LOG_TWO_PI - (1.0 - a[j] * a[j] + SQUASH_EPS).ln();
        }
    }
}

/// The deterministic action tanh(μ), used when evaluating a policy.
pub fn mean_action(head: &[f32], action: &mut [f32]) {
    for (h, a) in head.chunks_exact(HEAD_LEN).zip(action.chunks_exact_mut(ACTION_LEN)) {
        for j in 0..ACTION_LEN {
            a[j] = h[j].tanh();
        }
    }
}

/// Accumulates into `d_head` the gradient of a loss given its gradients with respect to the
/// sampled actions (`d_action`) and log-probabilities (`d_log_prob`), at the same noise.
pub fn backward(
    head: &[f32],
    noise: &[f32],
    action: &[f32],
    d_action: &[f32],
    d_log_prob: &[f32],
    d_head: &mut [f32],
) {
    for (((((h, e), a), da), &dlp), dh) in head
        .chunks_exact(HEAD_LEN)
        .zip(noise.chunks_exact(ACTION_LEN))
        .zip(action.chunks_exact(ACTION_LEN))
        .zip(d_action.chunks_exact(ACTION_LEN))
        .zip(d_log_prob)
        .zip(d_head.chunks_exact_mut(HEAD_LEN))
    {
        for j in 0..ACTION_LEN {
            let raw = h[ACTION_LEN + j];
            let one_minus_a2 = 1.0 - a[j] * a[j];
            // d/du of a = tanh(u) and of −log(1 − a² + δ).
            let d_u = da[j] * one_minus_a2 + dlp * 2.0 * a[j] * one_minus_a2 / (one_minus_a2 + SQUASH_EPS);
            dh[j] += d_u;
            if (LOG_STD_MIN..=LOG_STD_MAX).contains(&raw) {
                // u = μ + e^{log σ}·ε, and log π has −log σ.
                dh[ACTION_LEN + j] += d_u * log_std(raw).exp() * e[j] - dlp;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad};

    /// log π(a) from its definition: the Gaussian density of u = atanh(a), times |du/da|.
    fn closed_form(mean: f64, log_std: f64, a: f64) -> f64 {
        let u = a.atanh();
        let z = (u - mean) / log_std.exp();
        -0.5 * z * z - log_std - 0.5 * (2.0 * std::f64::consts::PI).ln() - (1.0 - a * a).ln()
    }

    #[test]
    fn log_probability_matches_the_closed_form() {
        let head = [0.3, -1.2, -0.5, 0.4];
        let noise = [0.7, -0.2];
        let (mut a, mut lp) = ([0.0; 2], [0.0]);
        sample(&head, &noise, &mut a, &mut lp);
        let want: f64 = (0..2).map(|j| closed_form(head[j] as f64, head[2 + j] as f64, a[j] as f64)).sum();
        assert!((f64::from(lp[0]) - want).abs() < 1e-4, "log π {} vs closed form {want}", lp[0]);
        assert!((a[0] - (0.3f32 + (-0.5f32).exp() * 0.7).tanh()).abs() < 1e-6);
        let mut det = [0.0; 2];
        mean_action(&head, &mut det);
        assert_eq!(det, [0.3f32.tanh(), (-1.2f32).tanh()]);
    }

    #[test]
    fn reparameterised_gradient_matches_finite_differences() {
        // Loss = Σ c·a + k·log π, the shape of SAC's actor loss (α log π − Q(a)).
        let head = [0.3f32, -0.8, -0.5, 0.4, 1.1, 0.2, -30.0, 0.1];
        let noise = [0.7f32, -0.2, 0.1, 1.4];
        let (c, k) = ([0.5f32, -1.5], 0.3f32);
        let loss = |h: &[f64]| -> f64 {
            let h32: Vec<f32> = h.iter().map(|&v| v as f32).collect();
            let (mut a, mut lp) = ([0.0; 4], [0.0; 2]);
            sample(&h32, &noise, &mut a, &mut lp);
            let linear: f32 = a.chunks(2).map(|a| c[0] * a[0] + c[1] * a[1]).sum();
            f64::from(linear + k * (lp[0] + lp[1]))
        };
        let (mut a, mut lp) = ([0.0; 4], [0.0; 2]);
        sample(&head, &noise, &mut a, &mut lp);
        let d_action = [c[0], c[1], c[0], c[1]];
        let mut d_head = [0.0; 8];
        backward(&head, &noise, &a, &d_action, &[k, k], &mut d_head);
        let h64: Vec<f64> = head.iter().map(|&v| f64::from(v)).collect();
        assert_close(&d_head, &numerical_grad(&h64, 1e-3, loss), 1e-3, "tanh-Gaussian gradient");
        assert_eq!(d_head[6], 0.0, "a clipped log σ gets no gradient");
    }
}
