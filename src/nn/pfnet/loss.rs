//! PF-net's training loss: the squared error of the softmax-weighted mean particle.

use std::f32::consts::{PI, TAU};

/// How the error of the weighted mean pose is scored.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseLoss {
    /// Weights of the squared (x, y, θ) errors: the paper's (1, 1, β = 0.36); the Keras oracle's
    /// plain mean of squares is (1, 1, 1).
    pub weights: [f32; 3],
    /// Wrap the heading error to (−π, π] (the paper's loss does; the oracle's does not).
    pub wrap_heading: bool,
    /// Multiplies the sum (the oracle averages over B·T·3 terms: scale = 1 / (B·T·3)).
    pub scale: f32,
}

impl PoseLoss {
    /// The loss of one step and d loss / d loglik. `states` [k][3] are the particles' (x, y, θ),
    /// the estimate is Σ softmax(loglik)_k · state_k (the reference's linear mean, which is
    /// what it differentiates), `target` the true pose.
    pub fn evaluate(&self, loglik: &[f32], states: &[[f32; 3]], target: [f32; 3]) -> (f64, Vec<f32>) {
        let max = loglik.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let exp: Vec<f64> = loglik.iter().map(|&l| f64::from(l - max).exp()).collect();
        let total: f64 = exp.iter().sum();
        let weights: Vec<f64> = exp.iter().map(|e| e / total).collect();
        let mut mean = [0.0f64; 3];
        for (w, s) in weights.iter().zip(states) {
            for c in 0..3 {
                mean[c] += w * f64::from(s[c]);
            }
        }
        let mut error = [0.0f64; 3];
        for c in 0..3 {
            error[c] = mean[c] - f64::from(target[c]);
        }
        if self.wrap_heading {
            error[2] = f64::from(wrap(error[2] as f32));
        }
        let scale = f64::from(self.scale);
        let loss: f64 = (0..3).map(|c| f64::from(self.weights[c]) * error[c] * error[c]).sum::<f64>() * scale;
        // d loss / d mean_c, then through the softmax: d mean_c / d loglik_k = w_k (s_kc − mean_c).
        let dmean: Vec<f64> = (0..3).map(|c| 2.0 * f64::from(self.weights[c]) * error[c] * scale).collect();
        let dloglik = weights
            .iter()
            .zip(states)
            .map(|(w, s)| (0..3).map(|c| dmean[c] * w * (f64::from(s[c]) - mean[c])).sum::<f64>() as f32)
            .collect();
        (loss, dloglik)
    }
}

fn wrap(angle: f32) -> f32 {
    let a = (angle + PI).rem_euclid(TAU) - PI;
    if a <= -PI { a + TAU } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad};

    #[test]
    fn pose_loss_gradient_matches_finite_differences() {
        let states = [[0.1, 0.2, 0.3], [1.0, -0.5, 2.9], [-0.3, 0.4, -2.8], [0.5, 0.5, 0.0]];
        let target = [0.2, 0.1, 3.0];
        let loglik = [0.3f32, -1.2, 0.7, 0.1];
        for loss in [
            PoseLoss { weights: [1.0, 1.0, 0.36], wrap_heading: true, scale: 0.5 },
            PoseLoss { weights: [1.0; 3], wrap_heading: false, scale: 1.0 / 3.0 },
        ] {
            let (_, grad) = loss.evaluate(&loglik, &states, target);
            let x: Vec<f64> = loglik.iter().map(|&l| f64::from(l)).collect();
            let numeric = numerical_grad(&x, 1e-3, |l| {
                let l: Vec<f32> = l.iter().map(|&v| v as f32).collect();
                loss.evaluate(&l, &states, target).0
            });
            assert_close(&grad, &numeric, 1e-3, "d loss / d loglik");
        }
    }

    #[test]
    fn pose_loss_is_zero_at_the_target_and_wraps_headings() {
        let loss = PoseLoss { weights: [1.0, 1.0, 0.36], wrap_heading: true, scale: 1.0 };
        let (at_target, _) = loss.evaluate(&[0.0], &[[1.0, 2.0, 3.1]], [1.0, 2.0, 3.1]);
        assert!(at_target < 1e-12, "a perfect estimate costs nothing");
        let (across_pi, _) = loss.evaluate(&[0.0], &[[0.0, 0.0, 3.1]], [0.0, 0.0, -3.1]);
        let want = 0.36 * f64::from(TAU - 6.2).powi(2);
        assert!((across_pi - want).abs() < 1e-6, "heading error across ±π wraps: {across_pi} vs {want}");
    }
}
