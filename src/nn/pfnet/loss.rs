//! PF-net's training loss: the squared error of the softmax-weighted mean particle, and beyond the
//! paper an optional mixture term that asks the weights to sit on the particles near the truth.

use serde::{Deserialize, Serialize};
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
    /// Beyond the paper: adds the mixture term (`scale` applies to it too).
    pub mixture: Option<MixtureLoss>,
}

/// −log of the true pose's density under the weighted particles, each a Gaussian kernel of
/// `std_m` and `std_deg` (its constant dropped), as differentiable particle filters score their
/// belief (Jonschkowski et al. 2018). The paper's loss scores only the weighted mean, so weights
/// spread evenly over particles around the truth cost nothing: a network trained on it alone may
/// stay flat over a metre (`apfn pfnet landscape`). This term pays for every bit of weight on
/// particles far from the truth.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MixtureLoss {
    /// Multiplies the term before it joins the paper's.
    pub weight: f32,
    /// Kernel widths in position (metres) and heading (degrees).
    pub std_m: f32,
    pub std_deg: f32,
}

impl MixtureLoss {
    /// `Err("field: expected …")` for a term no run can use.
    pub fn check(&self) -> Result<(), String> {
        let positive = |x: f32| x.is_finite() && x > 0.0;
        if !(self.weight.is_finite() && self.weight >= 0.0) {
            return Err(format!("mixture.weight: expected a number ≥ 0, found {}", self.weight));
        }
        if !(positive(self.std_m) && positive(self.std_deg)) {
            return Err(format!(
                "mixture.std_m, mixture.std_deg: expected widths > 0, found {} m and {}°",
                self.std_m, self.std_deg
            ));
        }
        Ok(())
    }

    /// The term, −log Σ_k w_k κ_k, and its gradient, added into `dloglik`: with w the particles'
    /// weights (softmax of their log-likelihoods) and r ∝ w κ their reweighting by each one's
    /// kernel κ at the truth, d term / d loglik_k = w_k − r_k.
    fn add(
        &self,
        weights: &[f64],
        states: &[[f32; 3]],
        target: [f32; 3],
        scale: f64,
        dloglik: &mut [f64],
    ) -> f64 {
        let (var_m, var_rad) = (f64::from(self.std_m).powi(2), f64::from(self.std_deg.to_radians()).powi(2));
        let log_kernel = |s: &[f32; 3]| {
            let (dx, dy) = (f64::from(s[0] - target[0]), f64::from(s[1] - target[1]));
            let dtheta = f64::from(wrap(s[2] - target[2]));
            -0.5 * ((dx * dx + dy * dy) / var_m + dtheta * dtheta / var_rad)
        };
        // In log space, so that kernels far below f64's range still rank the particles.
        let log_wk: Vec<f64> = weights.iter().zip(states).map(|(w, s)| w.ln() + log_kernel(s)).collect();
        let max = log_wk.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let exp: Vec<f64> = log_wk.iter().map(|x| (x - max).exp()).collect();
        let total: f64 = exp.iter().sum();
        let factor = f64::from(self.weight) * scale;
        for ((d, w), e) in dloglik.iter_mut().zip(weights).zip(exp) {
            *d += factor * (w - e / total);
        }
        -factor * (max + total.ln())
    }
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
        let mut dloglik: Vec<f64> = weights
            .iter()
            .zip(states)
            .map(|(w, s)| (0..3).map(|c| dmean[c] * w * (f64::from(s[c]) - mean[c])).sum::<f64>())
            .collect();
        let mixture = self.mixture.map_or(0.0, |m| m.add(&weights, states, target, scale, &mut dloglik));
        (loss + mixture, dloglik.into_iter().map(|d| d as f32).collect())
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

    const PAPER: PoseLoss =
        PoseLoss { weights: [1.0, 1.0, 0.36], wrap_heading: true, scale: 1.0, mixture: None };

    #[test]
    fn pose_loss_gradient_matches_finite_differences() {
        let states = [[0.1, 0.2, 0.3], [1.0, -0.5, 2.9], [-0.3, 0.4, -2.8], [0.5, 0.5, 0.0]];
        let target = [0.2, 0.1, 3.0];
        let loglik = [0.3f32, -1.2, 0.7, 0.1];
        for loss in [
            PoseLoss { weights: [1.0, 1.0, 0.36], wrap_heading: true, scale: 0.5, mixture: None },
            PoseLoss { weights: [1.0; 3], wrap_heading: false, scale: 1.0 / 3.0, mixture: None },
            PoseLoss { mixture: Some(MixtureLoss { weight: 0.7, std_m: 0.4, std_deg: 20.0 }), ..PAPER },
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
        let loss = PAPER;
        let (at_target, _) = loss.evaluate(&[0.0], &[[1.0, 2.0, 3.1]], [1.0, 2.0, 3.1]);
        assert!(at_target < 1e-12, "a perfect estimate costs nothing");
        let (across_pi, _) = loss.evaluate(&[0.0], &[[0.0, 0.0, 3.1]], [0.0, 0.0, -3.1]);
        let want = 0.36 * f64::from(TAU - 6.2).powi(2);
        assert!((across_pi - want).abs() < 1e-6, "heading error across ±π wraps: {across_pi} vs {want}");
    }

    #[test]
    fn mixture_term_matches_a_hand_calculation_and_rewards_weight_near_the_truth() {
        // Two particles, one at the truth and one 0.5 m off: kernels 1 and e^{-0.5·(0.5/0.5)²}.
        let mixture = MixtureLoss { weight: 1.0, std_m: 0.5, std_deg: 10.0 };
        let loss = PoseLoss { weights: [0.0; 3], mixture: Some(mixture), ..PAPER };
        let states = [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]];
        let (even, grad) = loss.evaluate(&[0.0, 0.0], &states, [0.0, 0.0, 0.0]);
        let want = -(0.5 * (1.0 + (-0.5f64).exp())).ln();
        assert!((even - want).abs() < 1e-9, "{even} vs {want}");
        assert!(grad[0] < 0.0 && grad[1] > 0.0, "more weight on the truth lowers it: {grad:?}");
        let (sharp, _) = loss.evaluate(&[3.0, 0.0], &states, [0.0, 0.0, 0.0]);
        assert!(sharp < even, "weights on the truth cost less: {sharp} vs {even}");
        // The paper's loss alone cannot tell weights spread symmetrically around the truth from
        // weights on it; the mixture term can.
        let around = [[-0.4, 0.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.0, 0.0]];
        let paper = |l: &[f32]| PAPER.evaluate(l, &around, [0.0; 3]).0;
        let with = |l: &[f32]| loss.evaluate(l, &around, [0.0; 3]).0;
        assert!((paper(&[0.0, 0.0, 0.0]) - paper(&[0.0, 0.0, 5.0])).abs() < 1e-9);
        assert!(with(&[0.0, 0.0, 5.0]) < with(&[0.0, 0.0, 0.0]) - 0.1);
    }

    #[test]
    fn mixture_term_rejects_zero_widths_by_name() {
        let bad = MixtureLoss { weight: 1.0, std_m: 0.0, std_deg: 5.0 };
        assert!(bad.check().unwrap_err().starts_with("mixture.std_m"));
        let bad = MixtureLoss { weight: f32::NAN, std_m: 0.1, std_deg: 5.0 };
        assert!(bad.check().unwrap_err().starts_with("mixture.weight"));
    }
}
