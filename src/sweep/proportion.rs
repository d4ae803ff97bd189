//! A success rate with its 95 % Wilson score interval. Unlike mean ± t·s/√n across seeds, the
//! interval stays inside [0, 1] and does not shrink to nothing at 0 or n successes.

use serde::{Deserialize, Serialize};

/// z(0.975), the two-sided 95 % normal quantile.
const Z975: f64 = 1.959_963_985;

/// `successes` of `trials` episodes, their rate and its 95 % Wilson interval [low95, high95].
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct Proportion {
    pub successes: usize,
    pub trials: usize,
    pub rate: f64,
    pub low95: f64,
    pub high95: f64,
}

impl Proportion {
    /// Wilson (1927): the p whose normal test at 95 % does not reject the observed rate;
    /// `None` without trials.
    pub fn wilson(successes: usize, trials: usize) -> Option<Proportion> {
        if trials == 0 || successes > trials {
            return None;
        }
        let (n, p, z2) = (trials as f64, successes as f64 / trials as f64, Z975 * Z975);
        let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
        let half = Z975 / (1.0 + z2 / n) * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
        let (low95, high95) = ((centre - half).max(0.0), (centre + half).min(1.0));
        Some(Proportion { successes, trials, rate: p, low95, high95 })
    }

    /// "97 % (90–99 %)", in whole percent.
    pub fn percent(&self) -> String {
        let pc = |x: f64| (x * 100.0).round();
        format!("{} % ({}–{} %)", pc(self.rate), pc(self.low95), pc(self.high95))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_published_values_and_stays_in_0_1() {
        // Newcombe (1998), Table I: 81 of 263 → 0.2553–0.3662; 0 of 10 → 0–0.2775.
        let p = Proportion::wilson(81, 263).expect("trials");
        assert!((p.low95 - 0.2553).abs() < 1e-4 && (p.high95 - 0.3662).abs() < 1e-4, "{p:?}");
        let none = Proportion::wilson(0, 10).expect("trials");
        assert!(none.low95 == 0.0 && (none.high95 - 0.2775).abs() < 1e-4, "{none:?}");
        let all = Proportion::wilson(29, 30).expect("trials");
        assert!(all.high95 <= 1.0 && all.low95 > 0.8, "29 of 30 stays below 100 %: {all:?}");
        assert_eq!(Proportion::wilson(3, 0), None);
        assert_eq!(Proportion::wilson(10, 10).expect("trials").percent(), "100 % (72–100 %)");
    }
}
