//! Soft resampling (PF-net): draw from q(k) = α·w_k + (1−α)/K with a low-variance (systematic)
//! draw and re-weight by w_k / q(k), so the set stays an unbiased weighted sample while gradients
//! (in training) and diversity survive. α = 1 is classical hard resampling with uniform weights after.
//! With `kld` set, the count adapts to the belief's spread (KLD-sampling, as nav2 AMCL does).

use crate::params::{StepParams, pretty_ron};
use crate::particles::kld::{KldHistogram, KldParams};
use crate::particles::set::{ParticleError, ParticleSet};
use crate::world::FilterRng;
use bevy::prelude::*;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// When and how hard to resample.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ResampleParams {
    /// Mix between the importance weights and uniform, in [0, 1] (PF-net soft resampling; paper 0.5).
    /// 1 = hard resampling, 0 = keep every particle once (weights unchanged).
    pub alpha: f32,
    /// Resample only when ESS/N falls below this fraction; `None` = every step (PF-net does).
    pub ess_threshold: Option<f32>,
    /// Adapt the particle count by KLD-sampling; `None` keeps the count (PF-net does).
    pub kld: Option<KldParams>,
}

impl Default for ResampleParams {
    fn default() -> Self {
        Self { alpha: 0.5, ess_threshold: None, kld: None }
    }
}

impl StepParams for ResampleParams {
    fn check(&self) -> Result<(), String> {
        self.validate().map_err(|e| e.to_string())
    }

    fn optional_defaults() -> Vec<(&'static str, String)> {
        vec![("kld", pretty_ron(&KldParams::default()))]
    }
}

impl ResampleParams {
    /// Checks the ranges a RON file could get wrong.
    pub fn validate(&self) -> Result<(), ParticleError> {
        if !(0.0..=1.0).contains(&self.alpha) {
            return Err(ParticleError::InvalidParam {
                field: "resample.alpha",
                expected: "a value in [0, 1]",
            });
        }
        if let Some(t) = self.ess_threshold
            && !(0.0..=1.0).contains(&t)
        {
            return Err(ParticleError::InvalidParam {
                field: "resample.ess_threshold",
                expected: "None or a fraction in [0, 1]",
            });
        }
        self.kld.as_ref().map_or(Ok(()), KldParams::validate)
    }
}

/// Whether the ESS policy fires: always without a threshold, else when ESS/N < threshold.
pub fn should_resample(set: &ParticleSet, ess_threshold: Option<f32>) -> bool {
    match ess_threshold {
        _ if set.is_empty() => false,
        None => true,
        Some(t) => set.effective_sample_size() / (set.len() as f32) < t,
    }
}

/// `n` indices drawn from the normalised distribution `q` with one uniform offset: index k is
/// drawn ⌊n·q_k⌋ or ⌈n·q_k⌉ times (low-variance / systematic resampling).
pub fn systematic_indices(q: &[f64], n: usize, rng: &mut impl Rng) -> Vec<usize> {
    let total: f64 = q.iter().sum();
    let step = total / n as f64;
    let mut u = rng.random::<f64>() * step;
    let (mut k, mut cum) = (0usize, q.first().copied().unwrap_or(0.0));
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        while u >= cum && k + 1 < q.len() {
            k += 1;
            cum += q[k];
        }
        out.push(k);
        u += step;
    }
    out
}

/// Resamples `set` in place (same count) from q = α·w + (1−α)/K; new log-weights log(w/q),
/// normalised. `alpha` is clamped to [0, 1]. Empty or ragged sets (arrays of unequal length)
/// are left alone.
pub fn resample_soft(set: &mut ParticleSet, alpha: f32, rng: &mut impl Rng) {
    let n = set.len();
    if let Some(q) = proposal(set, alpha) {
        let picks = systematic_indices(&q, n, rng);
        rebuild(set, &picks, &q, alpha);
    }
}

/// Soft resampling whose count adapts by KLD-sampling: a systematic draw of `max_particles`,
/// visited in random order (so any prefix is itself an unbiased sample) until the prefix is as
/// large as Fox's bound for the bins it occupies.
pub fn resample_kld(set: &mut ParticleSet, alpha: f32, kld: &KldParams, rng: &mut impl Rng) {
    let Some(q) = proposal(set, alpha) else { return };
    let mut picks = systematic_indices(&q, kld.max_particles.max(1), rng);
    let mut histogram = KldHistogram::new(kld);
    let mut kept = 0;
    while kept < picks.len() {
        let swap = rng.random_range(kept..picks.len());
        picks.swap(kept, swap);
        let k = picks[kept];
        histogram.insert(set.x[k], set.y[k], set.yaw[k]);
        kept += 1;
        if histogram.is_enough(kept) {
            break;
        }
    }
    picks.truncate(kept);
    rebuild(set, &picks, &q, alpha);
}

/// Resamples as `params` say (fixed count, or KLD-adapted).
pub fn resample_with(set: &mut ParticleSet, params: &ResampleParams, rng: &mut impl Rng) {
    match &params.kld {
        Some(kld) => resample_kld(set, params.alpha, kld, rng),
        None => resample_soft(set, params.alpha, rng),
    }
}

/// The proposal q = α·w + (1−α)/K, or `None` for an empty or ragged set.
fn proposal(set: &ParticleSet, alpha: f32) -> Option<Vec<f64>> {
    let n = set.len();
    if n == 0 || set.x.len() != n || set.y.len() != n || set.yaw.len() != n {
        return None;
    }
    let alpha = alpha.clamp(0.0, 1.0) as f64;
    let uniform = (1.0 - alpha) / n as f64;
    Some(set.log_w.iter().map(|&l| alpha * (l as f64).exp() + uniform).collect())
}

/// Replaces `set` by the picked particles with log-weights log(w/q) (uniform for α = 1), normalised.
fn rebuild(set: &mut ParticleSet, picks: &[usize], q: &[f64], alpha: f32) {
    let log_w = |k: usize| if alpha >= 1.0 { 0.0 } else { ((set.log_w[k] as f64) - q[k].ln()) as f32 };
    let next = ParticleSet {
        x: picks.iter().map(|&k| set.x[k]).collect(),
        y: picks.iter().map(|&k| set.y[k]).collect(),
        yaw: picks.iter().map(|&k| set.yaw[k]).collect(),
        log_w: picks.iter().map(|&k| log_w(k)).collect(),
    };
    *set = next;
    if set.normalise().is_err() {
        set.set_uniform();
    }
}

/// Reads ParticleSet weights, FilterRng, ResampleParams. Writes ParticleSet (resampled when the
/// ESS policy fires).
pub fn resample(params: Res<ResampleParams>, mut robots: Query<(&mut ParticleSet, &mut FilterRng)>) {
    robots.par_iter_mut().for_each(|(mut set, mut rng)| {
        if should_resample(&set, params.ess_threshold) {
            resample_with(&mut set, &params, &mut rng.0);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Pose2;
    use crate::world::rng::stream;
    use bevy::ecs::system::RunSystemOnce;

    fn weighted_mean_x(set: &ParticleSet) -> f32 {
        set.weights().iter().zip(&set.x).map(|(w, x)| w * x).sum()
    }

    #[test]
    fn resample_keeps_count_and_normalises() {
        let mut world = World::new();
        world.insert_resource(ResampleParams::default());
        let e = world.spawn((ParticleSet::from_weights(&[0.7, 0.1, 0.1, 0.1]), FilterRng::seeded(7))).id();
        world.run_system_once(resample).expect("resample runs");
        let set = world.get::<ParticleSet>(e).expect("set still there");
        assert_eq!(set.len(), 4, "resampling keeps the particle count");
        assert!((set.weights().iter().sum::<f32>() - 1.0).abs() < 1e-5, "weights must stay normalised");
        let copies = set.x.iter().filter(|&&x| x == 0.0).count();
        assert!((1..=2).contains(&copies), "n·q₀ = 4·0.475 = 1.9 → 1 or 2 copies, got {copies}");
    }

    #[test]
    fn resample_hard_copies_the_only_live_particle() {
        let mut set = ParticleSet::from_weights(&[1.0, 0.0, 0.0, 0.0]);
        resample_soft(&mut set, 1.0, &mut stream(&[3]));
        assert_eq!(set.x, vec![0.0; 4], "α = 1 must copy particle 0 everywhere");
        assert_eq!(set.weights(), vec![0.25; 4], "hard resampling leaves uniform weights");
    }

    #[test]
    fn resample_soft_is_unbiased() {
        let base = ParticleSet::from_weights(&[0.1, 0.2, 0.3, 0.4, 0.0, 0.0, 0.0, 0.0]);
        let before = weighted_mean_x(&base);
        let draws = 4000;
        let mean_after: f32 = (0..draws)
            .map(|d| {
                let mut set = base.clone();
                resample_soft(&mut set, 0.5, &mut stream(&[11, d]));
                weighted_mean_x(&set)
            })
            .sum::<f32>()
            / draws as f32;
        assert!((mean_after - before).abs() < 0.03, "E[mean after] = {mean_after}, before = {before}");
    }

    #[test]
    fn resample_respects_ess_threshold() {
        let mut world = World::new();
        world.insert_resource(ResampleParams { alpha: 1.0, ess_threshold: Some(0.5), kld: None });
        let flat = world.spawn((ParticleSet::from_weights(&[1.0; 4]), FilterRng::seeded(1))).id();
        let peaked =
            world.spawn((ParticleSet::from_weights(&[1.0, 0.0, 0.0, 0.0]), FilterRng::seeded(2))).id();
        world.run_system_once(resample).expect("resample runs");
        let flat_x = &world.get::<ParticleSet>(flat).expect("flat set").x;
        assert_eq!(flat_x, &vec![0.0, 1.0, 2.0, 3.0], "ESS/N = 1 ≥ 0.5: no resampling");
        let peaked_x = &world.get::<ParticleSet>(peaked).expect("peaked set").x;
        assert_eq!(peaked_x, &vec![0.0; 4], "ESS/N = 0.25 < 0.5: resampled");
    }

    #[test]
    fn resample_params_validate_ranges() {
        assert!(ResampleParams::default().validate().is_ok());
        assert!(ResampleParams { alpha: 1.5, ..Default::default() }.validate().is_err(), "α > 1 rejected");
        let inverted = KldParams { min_particles: 9, max_particles: 3, ..Default::default() };
        assert!(
            ResampleParams { kld: Some(inverted), ..Default::default() }.validate().is_err(),
            "bad kld rejected"
        );
    }

    /// `n` particles on a line, uniform weights, spaced `spacing_m` apart.
    fn line_of(n: usize, spacing_m: f32) -> ParticleSet {
        let poses: Vec<Pose2> = (0..n).map(|k| Pose2::new(k as f32 * spacing_m, 0.0, 0.0)).collect();
        ParticleSet::from_poses(&poses)
    }

    #[test]
    fn resample_kld_shrinks_a_converged_set_and_grows_a_spread_one() {
        let kld = KldParams { min_particles: 50, max_particles: 3000, ..Default::default() };
        let params = ResampleParams { alpha: 1.0, ess_threshold: None, kld: Some(kld.clone()) };
        let mut tight = line_of(1000, 0.0001);
        resample_with(&mut tight, &params, &mut stream(&[5]));
        assert_eq!(tight.len(), 50, "one bin → min_particles");
        let mut spread = line_of(300, 0.5);
        resample_with(&mut spread, &params, &mut stream(&[6]));
        let bins = spread
            .x
            .iter()
            .map(|x| (x / 0.5).floor() as i64)
            .collect::<std::collections::BTreeSet<_>>()
            .len();
        assert_eq!(spread.len(), kld.particles_needed(bins), "stops at the bound for the bins it saw");
        assert!(spread.len() > 300, "300 bins need more than 300 particles, got {}", spread.len());
        assert!((spread.weights().iter().sum::<f32>() - 1.0).abs() < 1e-4);
    }

    #[test]
    fn resample_system_adapts_the_count_with_kld() {
        let mut world = World::new();
        let kld = KldParams { min_particles: 5, max_particles: 50, ..Default::default() };
        world.insert_resource(ResampleParams { alpha: 0.5, ess_threshold: None, kld: Some(kld) });
        let converged = world.spawn((line_of(40, 0.001), FilterRng::seeded(4))).id();
        let spread = world.spawn((line_of(40, 0.5), FilterRng::seeded(5))).id();
        world.run_system_once(resample).expect("resample runs");
        assert_eq!(world.get::<ParticleSet>(converged).expect("set").len(), 5, "one bin → min_particles");
        assert_eq!(
            world.get::<ParticleSet>(spread).expect("set").len(),
            50,
            "40 bins → capped at max_particles"
        );
    }

    #[test]
    fn resample_kld_is_unbiased() {
        let base = ParticleSet::from_weights(&[0.1, 0.2, 0.3, 0.4, 0.0, 0.0, 0.0, 0.0]);
        let kld = KldParams { min_particles: 3, max_particles: 16, bin_size_m: 100.0, ..Default::default() };
        let before = weighted_mean_x(&base);
        let draws = 4000;
        let mean_after: f32 = (0..draws)
            .map(|d| {
                let mut set = base.clone();
                resample_kld(&mut set, 0.5, &kld, &mut stream(&[12, d]));
                assert_eq!(set.len(), 3, "one bin → min_particles");
                weighted_mean_x(&set)
            })
            .sum::<f32>()
            / draws as f32;
        assert!((mean_after - before).abs() < 0.05, "E[mean after] = {mean_after}, before = {before}");
    }
}
