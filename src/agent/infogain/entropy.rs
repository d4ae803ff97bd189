//! Entropy of a particle belief over a coarse pose histogram (x, y, heading bins).
//!
//! Why a histogram and not the log-determinant of the weighted covariance: the beliefs that make
//! a motion worth choosing are multi-modal (a global start, a symmetric corridor). A covariance
//! sees two tight modes 5 m apart as one broad blob and keeps most of its volume when a third,
//! nearby mode dies; its log-determinant also runs to −∞ when the weights collapse onto one
//! particle. The histogram's entropy counts modes the way grid Markov localization (Burgard, Fox
//! & Thrun 1997) measures its belief, and stays within [0, ln #bins].
//!
//! The histogram is centred on a given pose (the imagined true pose): a tight mode around it then
//! never straddles a bin edge, which would add up to ln 2 of entropy that only says where the
//! grid happens to lie and would drown the differences between candidate motions.

use crate::world::{Pose2, wrap_angle};
use std::f32::consts::TAU;

/// Log-weights this far below the largest are left out of the histogram.
const NEGLIGIBLE_LOG_W: f32 = -30.0;

/// Entropy −Σ_b W_b ln W_b, in nats, of the weighted poses over bins of `bin_m` × `bin_m` ×
/// `bin_rad` with `centre` in the middle of its bin (heading bins wrap around; `bin_rad` should
/// divide 2π). `log_w` need not be normalised (log-sum-exp inside). Particles with a non-finite
/// pose or log-weight are left out; 0 when nothing is left.
pub fn histogram_entropy(
    x: &[f32],
    y: &[f32],
    yaw: &[f32],
    log_w: &[f32],
    centre: Pose2,
    bin_m: f32,
    bin_rad: f32,
) -> f32 {
    let usable =
        |k: usize| x[k].is_finite() && y[k].is_finite() && yaw[k].is_finite() && log_w[k].is_finite();
    let max = (0..log_w.len()).filter(|&k| usable(k)).map(|k| log_w[k]).fold(f32::NEG_INFINITY, f32::max);
    if max == f32::NEG_INFINITY {
        return 0.0;
    }
    let bin = |offset: f32, size: f32| (offset / size + 0.5).floor() as i32;
    let headings = ((TAU / bin_rad).round() as i32).max(1);
    // One u64 per bin (21 bits per axis, offset to be non-negative): one integer compare per
    // step of the sort instead of three; offsets beyond ±2^20 bins (500 km at 0.5 m) share a bin.
    let field = |b: i32| u64::from((b.clamp(-(1 << 20), (1 << 20) - 1) + (1 << 20)) as u32);
    // Weights below e^−30 of the largest change the entropy by < 1e-11 nats; leaving them out
    // shortens the sort, which was a sixth of a decision (perf on `benches/infogain.rs`).
    let mut mass: Vec<(u64, f64)> = (0..log_w.len())
        .filter(|&k| usable(k) && log_w[k] - max > NEGLIGIBLE_LOG_W)
        .map(|k| {
            let turn = bin(wrap_angle(yaw[k] - centre.yaw), bin_rad).rem_euclid(headings);
            let (i, j) = (bin(x[k] - centre.x, bin_m), bin(y[k] - centre.y, bin_m));
            let key = field(i) << 42 | field(j) << 21 | field(turn);
            (key, f64::from(log_w[k] - max).exp())
        })
        .collect();
    mass.sort_unstable_by_key(|&(key, _)| key);
    let total: f64 = mass.iter().map(|&(_, w)| w).sum();
    let mut entropy = 0.0f64;
    let mut k = 0;
    while k < mass.len() {
        let key = mass[k].0;
        let mut w = 0.0;
        while k < mass.len() && mass[k].0 == key {
            w += mass[k].1;
            k += 1;
        }
        let p = w / total;
        if p > 0.0 {
            entropy -= p * p.ln();
        }
    }
    entropy as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::f32::consts::PI;

    const BIN_M: f32 = 0.5;
    const BIN_RAD: f32 = PI / 6.0;

    fn entropy(poses: &[(f32, f32, f32)], log_w: &[f32]) -> f32 {
        let (x, y, yaw): (Vec<_>, Vec<_>, Vec<_>) = (
            poses.iter().map(|p| p.0).collect(),
            poses.iter().map(|p| p.1).collect(),
            poses.iter().map(|p| p.2).collect(),
        );
        histogram_entropy(&x, &y, &yaw, log_w, Pose2::new(0.2, 0.2, 0.1), BIN_M, BIN_RAD)
    }

    #[test]
    fn histogram_entropy_matches_hand_values() {
        // Two particles in the centre's bin (within ±0.25 m, ±15°): entropy 0.
        assert!(entropy(&[(0.0, 0.1, 0.0), (0.4, 0.3, 0.3)], &[0.0, 0.0]).abs() < 1e-6);
        // Three bins with masses 1/2, 1/4, 1/4 (log-weights unnormalised, offset by 7):
        // H = ½ ln 2 + 2 · ¼ ln 4 = 1.5 ln 2.
        let poses = [(0.1, 0.1, 0.1), (2.0, 0.1, 0.1), (0.1, 0.1, 2.0)];
        let log_w = [0.5f32.ln() + 7.0, 0.25f32.ln() + 7.0, 0.25f32.ln() + 7.0];
        let h = entropy(&poses, &log_w);
        assert!((h - 1.5 * 2f32.ln()).abs() < 1e-5, "H = {h}, by hand 1.5 ln 2 = {}", 1.5 * 2f32.ln());
    }

    #[test]
    fn histogram_entropy_skips_unusable_particles_and_wraps_headings() {
        // Headings on either side of ±π share the bin opposite the centre's; a NaN pose and a
        // zero weight add nothing.
        let poses =
            [(0.1, 0.1, PI), (0.1, 0.1, -PI + 0.2), (0.2, 0.2, 0.1), (f32::NAN, 0.0, 0.0), (5.0, 5.0, 0.0)];
        let h = entropy(&poses, &[0.0, 0.0, 0.0, 0.0, f32::NEG_INFINITY]);
        let by_hand = -(2.0 / 3.0 * (2f32 / 3.0).ln() + 1.0 / 3.0 * (1f32 / 3.0).ln());
        assert!((h - by_hand).abs() < 1e-5, "bins of 2/3 and 1/3: {by_hand}, got {h}");
        assert_eq!(entropy(&[(0.0, 0.0, 0.0)], &[f32::NAN]), 0.0, "nothing usable: 0");
    }
}
