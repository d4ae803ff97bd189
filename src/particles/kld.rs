//! KLD-sampling (Fox, "Adapting the sample size in particle filters through KLD-sampling", 2003),
//! as nav2 AMCL uses it: after resampling, keep only as many particles as needed so that, with
//! probability 1 − δ, the KL divergence between the sample and the true posterior stays below
//! `pf_err`. A spread-out belief (a fresh tracking or global start) occupies many histogram bins
//! and keeps up to `max_particles`; a converged one occupies a few and shrinks to `min_particles`.

use crate::particles::set::ParticleError;
use bevy::platform::collections::HashSet;
use serde::{Deserialize, Serialize};

/// KLD-sampling parameters, with nav2 AMCL's names and defaults (histogram bins as AMCL's
/// kd-tree leaves: 0.5 m × 0.5 m × 10°).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct KldParams {
    /// Bound on the KL divergence between sample and posterior (nav2 `pf_err`: 0.05).
    pub pf_err: f32,
    /// The normal quantile z_{1−δ} in Fox's bound (nav2 `pf_z`: 0.99, used as given, as AMCL does).
    pub pf_z: f32,
    /// Fewest particles kept (nav2 `min_particles`: 500).
    pub min_particles: usize,
    /// Most particles kept (nav2 `max_particles`: 2000).
    pub max_particles: usize,
    /// Histogram bin side in x and y, metres.
    pub bin_size_m: f32,
    /// Histogram bin width in heading, degrees.
    pub bin_size_deg: f32,
}

impl Default for KldParams {
    fn default() -> Self {
        Self {
            pf_err: 0.05,
            pf_z: 0.99,
            min_particles: 500,
            max_particles: 2000,
            bin_size_m: 0.5,
            bin_size_deg: 10.0,
        }
    }
}

impl KldParams {
    /// Checks the ranges a RON file could get wrong.
    pub fn validate(&self) -> Result<(), ParticleError> {
        let invalid = |field, expected| Err(ParticleError::InvalidParam { field, expected });
        if !(self.pf_err > 0.0 && self.pf_err.is_finite()) {
            return invalid("resample.kld.pf_err", "a positive KL divergence bound");
        }
        if !(self.pf_z.is_finite() && self.pf_z >= 0.0) {
            return invalid("resample.kld.pf_z", "a non-negative normal quantile");
        }
        if self.min_particles == 0 || self.min_particles > self.max_particles {
            return invalid("resample.kld", "1 ≤ min_particles ≤ max_particles");
        }
        if !crate::limits::PARTICLES.contains(self.max_particles) {
            return invalid("resample.kld.max_particles", crate::limits::PARTICLES.expected);
        }
        if !(self.bin_size_m > 0.0 && self.bin_size_deg > 0.0) {
            return invalid("resample.kld", "positive bin_size_m and bin_size_deg");
        }
        Ok(())
    }

    /// Fox's bound for a sample occupying `bins` histogram bins, clamped to
    /// [min_particles, max_particles]:
    /// n = (k−1)/(2ε) · (1 − 2/(9(k−1)) + √(2/(9(k−1)))·z)³.
    pub fn particles_needed(&self, bins: usize) -> usize {
        if bins <= 1 {
            return self.min_particles;
        }
        let k = (bins - 1) as f64;
        let b = 2.0 / (9.0 * k);
        let cube = (1.0 - b + b.sqrt() * self.pf_z as f64).powi(3);
        let n = (k / (2.0 * self.pf_err as f64) * cube).ceil();
        (n as usize).clamp(self.min_particles, self.max_particles)
    }
}

/// The occupied bins of a growing sample, and the sample size they call for.
pub struct KldHistogram<'a> {
    params: &'a KldParams,
    inv_bin_m: f32,
    inv_bin_rad: f32,
    bins: HashSet<(i32, i32, i32)>,
    /// `params.particles_needed(bins.len())`, recomputed only when a bin opens.
    needed: usize,
}

impl<'a> KldHistogram<'a> {
    pub fn new(params: &'a KldParams) -> Self {
        Self {
            params,
            inv_bin_m: 1.0 / params.bin_size_m,
            inv_bin_rad: 1.0 / params.bin_size_deg.to_radians(),
            bins: HashSet::default(),
            needed: params.particles_needed(0),
        }
    }

    /// Adds one particle's bin.
    pub fn insert(&mut self, x: f32, y: f32, yaw: f32) {
        let bin = |v: f32, inv: f32| (v * inv).floor() as i32;
        if self.bins.insert((bin(x, self.inv_bin_m), bin(y, self.inv_bin_m), bin(yaw, self.inv_bin_rad))) {
            self.needed = self.params.particles_needed(self.bins.len());
        }
    }

    /// Whether a sample of `count` particles is large enough for the bins seen so far.
    pub fn is_enough(&self, count: usize) -> bool {
        count >= self.needed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bound_grows_with_spread_and_stays_within_limits() {
        let kld = KldParams::default();
        assert_eq!(kld.particles_needed(1), 500, "a converged belief keeps min_particles");
        // k = 101: 100/0.1 · (1 − 0.00222 + 0.04714·0.99)³ = 1000 · 1.04445… ³ ≈ 1139.4 → 1140.
        assert_eq!(kld.particles_needed(101), 1140);
        assert_eq!(kld.particles_needed(10_000), 2000, "capped at max_particles");
        let wide = KldParams { max_particles: 1_000_000, ..kld.clone() };
        assert!(wide.particles_needed(400) > wide.particles_needed(200), "more bins, more particles");
    }

    #[test]
    fn histogram_counts_distinct_bins() {
        let kld = KldParams { min_particles: 1, ..Default::default() };
        let mut hist = KldHistogram::new(&kld);
        hist.insert(0.1, 0.1, 0.01);
        hist.insert(0.2, 0.3, 0.02);
        assert!(hist.is_enough(1), "one bin: min_particles = 1 suffices");
        hist.insert(0.6, 0.1, 0.01);
        hist.insert(-0.1, 0.1, 0.01);
        hist.insert(0.1, 0.1, 0.5);
        assert_eq!(hist.bins.len(), 4, "x = 0.6 and x = −0.1 and θ = 0.5 rad open new bins");
        let needed = kld.particles_needed(4);
        assert!(!hist.is_enough(needed - 1) && hist.is_enough(needed));
    }

    #[test]
    fn validate_rejects_bad_ranges() {
        assert!(KldParams::default().validate().is_ok());
        assert!(KldParams { min_particles: 10, max_particles: 5, ..Default::default() }.validate().is_err());
        assert!(KldParams { pf_err: 0.0, ..Default::default() }.validate().is_err());
        assert!(KldParams { bin_size_deg: -1.0, ..Default::default() }.validate().is_err());
    }
}
