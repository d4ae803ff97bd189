//! Mean and 95 % confidence interval across seeds (Student t, n − 1 degrees of freedom).

use serde::{Deserialize, Serialize};

/// A metric across seeds: its mean and the half-width of the 95 % confidence interval of that
/// mean (`None` with a single seed, where the interval is undefined).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct MeanCi {
    pub mean: f64,
    pub ci95: Option<f64>,
}

/// Two-sided 95 % quantiles t(0.975, df) for df = 1..=30, to three decimals, as printed in the
/// NIST/SEMATECH e-Handbook of Statistical Methods, §1.3.6.7.2 (checked by integrating the
/// t density in the tests below).
const T975: [f64; 30] = [
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
    2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
];

/// t(0.975, df): the table up to 30, then the Cornish–Fisher expansion around the normal
/// quantile 1.959964 (Abramowitz & Stegun 26.7.5), which is within 1e-4 there and tends to it.
pub fn t975(df: usize) -> f64 {
    if df == 0 {
        return f64::NAN;
    }
    if df <= T975.len() {
        return T975[df - 1];
    }
    let z: f64 = 1.959_963_985;
    let v = df as f64;
    let g1 = (z.powi(3) + z) / 4.0;
    let g2 = (5.0 * z.powi(5) + 16.0 * z.powi(3) + 3.0 * z) / 96.0;
    let g3 = (3.0 * z.powi(7) + 19.0 * z.powi(5) + 17.0 * z.powi(3) - 15.0 * z) / 384.0;
    let g4 = (79.0 * z.powi(9) + 776.0 * z.powi(7) + 1482.0 * z.powi(5) - 1920.0 * z.powi(3) - 945.0 * z)
        / 92160.0;
    z + g1 / v + g2 / v.powi(2) + g3 / v.powi(3) + g4 / v.powi(4)
}

/// Mean of `xs` and the 95 % CI half-width t(0.975, n−1) · s / √n, s the sample standard
/// deviation. `None` for an empty slice.
pub fn mean_ci(xs: &[f64]) -> Option<MeanCi> {
    let n = xs.len();
    if n == 0 {
        return None;
    }
    let mean = xs.iter().sum::<f64>() / n as f64;
    let ci95 = (n > 1).then(|| {
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        t975(n - 1) * (var / n as f64).sqrt()
    });
    Some(MeanCi { mean, ci95 })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// P(|T| < q) for Student t with `df` degrees of freedom. With x = √df · tan θ the density
    /// becomes ∝ cos^(df−1) θ on [0, π/2), smooth enough for Simpson's rule.
    fn coverage(q: f64, df: usize) -> f64 {
        let simpson = |b: f64| {
            let n = 20_000;
            let h = b / n as f64;
            let f = |t: f64| t.cos().powi(df as i32 - 1);
            let inner: f64 = (1..n).map(|i| f(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 }).sum();
            (f(0.0) + inner + f(b)) * h / 3.0
        };
        simpson((q / (df as f64).sqrt()).atan()) / simpson(std::f64::consts::FRAC_PI_2)
    }

    #[test]
    fn t975_covers_95_percent() {
        for df in (1..=40).chain([60, 120, 1000]) {
            let c = coverage(t975(df), df);
            assert!((c - 0.95).abs() < 2e-4, "df {df}: t975 = {} covers {c}, expected 0.95", t975(df));
        }
    }

    #[test]
    fn t975_decreases_towards_the_normal_quantile() {
        for df in 1..200 {
            assert!(t975(df + 1) < t975(df), "t975 must decrease with df (df {df})");
        }
        assert!((t975(1_000_000) - 1.96).abs() < 1e-3);
    }

    #[test]
    fn mean_ci_of_three_values() {
        let m = mean_ci(&[1.0, 2.0, 3.0]).expect("three values");
        assert_eq!(m.mean, 2.0);
        // s = 1, n = 3: 4.303 / √3.
        let ci = m.ci95.expect("n = 3 has a CI");
        assert!((ci - 4.303 / 3f64.sqrt()).abs() < 1e-9, "ci {ci}");
        assert_eq!(mean_ci(&[5.0]), Some(MeanCi { mean: 5.0, ci95: None }), "one seed: no interval");
        assert_eq!(mean_ci(&[]), None);
    }
}
