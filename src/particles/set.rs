//! The particle set: one component of contiguous arrays (x, y, yaw, log-weight), plus the
//! components it brings (the estimate, the counters of the filter's guard events, the last
//! update's likelihood) and the errors of the particle stage.

use crate::world::Pose2;
use bevy::prelude::Component;
use thiserror::Error;

/// A robot's belief as weighted pose hypotheses, stored structure-of-arrays so kernels and
/// networks stream over contiguous memory. Log-weights are normalised: Σ exp(log_w) = 1.
/// A set is drawn afresh when its robot carries `NeedsInit` (at spawn and at every episode
/// reset), never because it is empty.
#[derive(Component, Clone, Debug, Default, PartialEq)]
#[require(FilterHealth, PoseEstimate, LikelihoodStats)]
pub struct ParticleSet {
    /// Positions, metres (world frame).
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    /// Headings, radians in (−π, π].
    pub yaw: Vec<f32>,
    /// Natural-log weights; Σ exp = 1 after every filter step.
    pub log_w: Vec<f32>,
}

/// Counts of the filter's guard events, so degenerate runs are visible (`apfn localize` reports
/// them).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FilterHealth {
    /// Times the weights were unusable (NaN everywhere or all zero) and were reset to uniform.
    pub degeneracies: u32,
    /// Times `init_particles` could not honour the requested task and drew a global set instead
    /// (semi-global box without a traversable cell).
    pub reinitialisations: u32,
    /// Particles replaced by uniform draws over the traversable map (`augmented_recovery`).
    pub injected: u32,
    /// Steps at which `init_particles` found the set empty mid-episode (without `NeedsInit`):
    /// some step removed every particle; the set is left empty, not redrawn.
    pub emptied: u32,
}

/// What the last observation update measured before normalising: the input of augmented MCL's
/// w_slow / w_fast averages (Probabilistic Robotics Table 8.3, w_avg).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct LikelihoodStats {
    /// log Σ_k w_k·p(z | x_k): the log of the weighted mean observation likelihood, with the
    /// weights w_k as they were before the update (normalised, so this is a mean). −∞ when every
    /// particle got likelihood 0; meaningless while `updates` is 0.
    pub mean_log_likelihood: f32,
    /// Observation updates that wrote `mean_log_likelihood` (0 = none yet).
    pub updates: u32,
    /// The model that weighed the particles, so that a later step (augmented MCL) weighs new
    /// particles on the same scale.
    pub model: ObservationModel,
}

/// The observation models a classical filter step can weigh particles with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ObservationModel {
    /// `mcl_likelihood_field`.
    #[default]
    LikelihoodField,
    /// `mcl_beam_model`.
    BeamModel,
    /// `pfnet_likelihood`: the learned model, which needs the robot's observation grid.
    PfNet,
}

impl ObservationModel {
    /// The system that runs this model.
    pub fn system_name(self) -> &'static str {
        match self {
            ObservationModel::LikelihoodField => "mcl_likelihood_field",
            ObservationModel::BeamModel => "mcl_beam_model",
            ObservationModel::PfNet => "pfnet_likelihood",
        }
    }
}

impl ParticleSet {
    /// log Σ exp(log_w) over the finite log-weights (log-sum-exp in f64); −∞ when none is finite.
    pub fn log_total_weight(&self) -> f32 {
        let finite = || self.log_w.iter().copied().filter(|l| l.is_finite());
        let max = finite().fold(f32::NEG_INFINITY, f32::max);
        if max == f32::NEG_INFINITY {
            return f32::NEG_INFINITY;
        }
        let sum: f64 = finite().map(|l| ((l - max) as f64).exp()).sum();
        max + sum.ln() as f32
    }
}

/// The filter's point estimate and its spread. `cov` rows/columns are (x m, y m, yaw rad).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseEstimate {
    pub pose: Pose2,
    pub cov: [[f32; 3]; 3],
}

/// Books the outcome of [`ParticleSet::weigh_with`] by `model` on the robot: a reset to uniform
/// counts as a degeneracy, a success updates the stats, an error is logged under the model's
/// system name.
pub fn record_observation(
    model: ObservationModel,
    outcome: Result<(Guard, f32), ParticleError>,
    health: &mut FilterHealth,
    stats: &mut LikelihoodStats,
) {
    match outcome {
        Ok((guard, mean_log_likelihood)) => {
            health.degeneracies += u32::from(guard == Guard::ResetToUniform);
            *stats = LikelihoodStats { mean_log_likelihood, updates: stats.updates + 1, model };
        }
        Err(e) => tracing::warn!("{}: {e}", model.system_name()),
    }
}

/// The weights cannot be normalised: a NaN/+∞ log-weight, or every weight is zero.
#[derive(Error, Clone, Copy, Debug, PartialEq, Eq)]
#[error("degenerate particle weights: {reason}")]
pub struct Degenerate {
    pub reason: &'static str,
}

/// Errors of the particle stage.
#[derive(Error, Clone, Debug, PartialEq)]
pub enum ParticleError {
    #[error(transparent)]
    Degenerate(#[from] Degenerate),
    #[error("a particle set needs at least one particle (InitParams.particles = Some(0)?)")]
    ZeroParticles,
    #[error("the traversable map has no cell to draw particles from")]
    NoTraversableCells,
    #[error("map layer `{layer}` is malformed: expected {expected} cells, found {found}")]
    MalformedLayer { layer: &'static str, expected: usize, found: usize },
    #[error("parameter `{field}` out of range: expected {expected}")]
    InvalidParam { field: &'static str, expected: &'static str },
}

/// What the weight guard had to do after an update.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Guard {
    /// The weights normalised as they were.
    Clean,
    /// Some particles had NaN/+∞ log-weights; they were dropped (weight 0) and the rest renormalised.
    Repaired,
    /// Nothing usable was left; weights were reset to uniform.
    ResetToUniform,
}

impl ParticleSet {
    pub fn len(&self) -> usize {
        self.log_w.len()
    }

    pub fn is_empty(&self) -> bool {
        self.log_w.is_empty()
    }

    /// Equally weighted particles at the given poses.
    pub fn from_poses(poses: &[Pose2]) -> Self {
        let log_w0 = -(poses.len().max(1) as f32).ln();
        Self {
            x: poses.iter().map(|p| p.x).collect(),
            y: poses.iter().map(|p| p.y).collect(),
            yaw: poses.iter().map(|p| p.yaw).collect(),
            log_w: vec![log_w0; poses.len()],
        }
    }

    /// Particles with the given (unnormalised, non-negative) weights, for tests elsewhere. Particle
    /// `k` sits at x = k m, y = 0, yaw = 0, so copies made by resampling can be told apart. Weights
    /// that cannot be normalised (all zero) are kept as given.
    pub fn from_weights(weights: &[f32]) -> Self {
        let mut set = Self {
            x: (0..weights.len()).map(|k| k as f32).collect(),
            y: vec![0.0; weights.len()],
            yaw: vec![0.0; weights.len()],
            log_w: weights.iter().map(|w| w.ln()).collect(),
        };
        let _ = set.normalise();
        set
    }

    /// Particle `k` as a pose.
    pub fn pose(&self, k: usize) -> Pose2 {
        Pose2::new(self.x[k], self.y[k], self.yaw[k])
    }

    /// Linear weights exp(log_w).
    pub fn weights(&self) -> Vec<f32> {
        self.log_w.iter().map(|l| l.exp()).collect()
    }

    /// Sets every weight to 1/N.
    pub fn set_uniform(&mut self) {
        let log_w0 = -(self.len().max(1) as f32).ln();
        self.log_w.iter_mut().for_each(|l| *l = log_w0);
    }

    /// Shifts log-weights so Σ exp = 1 (log-sum-exp, accumulated in f64).
    /// Fails on any NaN or +∞ log-weight, or when every weight is zero (all −∞).
    pub fn normalise(&mut self) -> Result<(), Degenerate> {
        if self.log_w.iter().any(|l| l.is_nan() || *l == f32::INFINITY) {
            return Err(Degenerate { reason: "NaN or +inf log-weight" });
        }
        let max = self.log_w.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        if max == f32::NEG_INFINITY {
            return Err(Degenerate { reason: "every weight is zero (or the set is empty)" });
        }
        let sum: f64 = self.log_w.iter().map(|&l| ((l - max) as f64).exp()).sum();
        let log_z = max + sum.ln() as f32;
        self.log_w.iter_mut().for_each(|l| *l -= log_z);
        Ok(())
    }

    /// Normalises, repairing what it can: NaN/+∞ log-weights become zero weights; if nothing
    /// usable remains the weights become uniform. Never leaves the set unnormalised.
    pub fn normalise_guarded(&mut self) -> Guard {
        if self.normalise().is_ok() {
            return Guard::Clean;
        }
        for l in self.log_w.iter_mut().filter(|l| l.is_nan() || **l == f32::INFINITY) {
            *l = f32::NEG_INFINITY;
        }
        if self.normalise().is_ok() {
            return Guard::Repaired;
        }
        self.set_uniform();
        Guard::ResetToUniform
    }

    /// The observation update every likelihood model shares: `add` adds each particle's
    /// log-likelihood to its log-weight, then the guard normalises (NaN particles dropped; if
    /// nothing usable is left, weights become uniform). Returns the guard's verdict and
    /// log Σ_k w_k·p(z | x_k), the log of the weighted mean likelihood before normalisation (what
    /// augmented MCL averages); −∞ for an empty set or when every likelihood is 0. When `add`
    /// errors, its error is returned and nothing is normalised.
    pub fn weigh_with(
        &mut self,
        add: impl FnOnce(&mut ParticleSet) -> Result<(), ParticleError>,
    ) -> Result<(Guard, f32), ParticleError> {
        if self.is_empty() {
            return Ok((Guard::Clean, f32::NEG_INFINITY));
        }
        let log_total_before = self.log_total_weight();
        add(self)?;
        let mean_log_likelihood = self.log_total_weight() - log_total_before;
        Ok((self.normalise_guarded(), mean_log_likelihood))
    }

    /// The weights' spread of the positions, √(σx² + σy²), metres (0 for an empty set).
    /// Allocates nothing: the filter asks it every step.
    pub fn position_spread_m(&self) -> f32 {
        let weights = || self.log_w.iter().map(|&l| f64::from(l).exp());
        let total: f64 = weights().sum();
        if total <= 0.0 {
            return 0.0;
        }
        let variance = |v: &[f32]| {
            let mean = v.iter().zip(weights()).map(|(&a, w)| w * f64::from(a)).sum::<f64>() / total;
            v.iter().zip(weights()).map(|(&a, w)| w * (f64::from(a) - mean).powi(2)).sum::<f64>() / total
        };
        (variance(&self.x) + variance(&self.y)).sqrt() as f32
    }

    /// Effective sample size 1 / Σ w², in [1, N] for normalised weights (0 for an empty set).
    pub fn effective_sample_size(&self) -> f32 {
        let sum_sq: f64 = self.log_w.iter().map(|&l| (2.0 * l as f64).exp()).sum();
        if sum_sq > 0.0 { (1.0 / sum_sq) as f32 } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_weights_normalises_and_keeps_order() {
        let set = ParticleSet::from_weights(&[2.0, 1.0, 1.0]);
        let w = set.weights();
        assert!((w[0] - 0.5).abs() < 1e-6 && (w[1] - 0.25).abs() < 1e-6, "got {w:?}");
        assert_eq!(set.x, vec![0.0, 1.0, 2.0], "particle k sits at x = k");
    }

    #[test]
    fn position_spread_is_the_weighted_deviation_of_the_positions() {
        // Particles at x = 0, 1, 2 (y = 0), weighted ½, ¼, ¼: mean 0.75, variance 0.6875.
        let set = ParticleSet::from_weights(&[2.0, 1.0, 1.0]);
        assert!((set.position_spread_m() - 0.6875f32.sqrt()).abs() < 1e-6, "{}", set.position_spread_m());
        let one = ParticleSet::from_poses(&[Pose2::new(3.0, -1.0, 0.5)]);
        assert_eq!(one.position_spread_m(), 0.0);
        assert_eq!(ParticleSet::default().position_spread_m(), 0.0);
    }

    #[test]
    fn normalise_survives_huge_log_weights() {
        let mut set = ParticleSet::from_poses(&[Pose2::default(); 2]);
        set.log_w = vec![-1.0e3, -1.0e3 - 2.0f32.ln()];
        set.normalise().expect("finite log-weights normalise");
        let w = set.weights();
        assert!((w[0] - 2.0 / 3.0).abs() < 1e-3, "log-sum-exp must not underflow, got {w:?}");
    }

    #[test]
    fn normalise_detects_nan_and_all_zero() {
        let mut set = ParticleSet::from_weights(&[0.5, 0.5]);
        set.log_w[1] = f32::NAN;
        assert!(set.normalise().is_err(), "NaN must be reported");
        set.log_w = vec![f32::NEG_INFINITY; 2];
        assert!(set.normalise().is_err(), "all-zero weights must be reported");
    }

    #[test]
    fn guard_repairs_then_resets() {
        let mut set = ParticleSet::from_weights(&[0.5, 0.5]);
        set.log_w[1] = f32::NAN;
        assert_eq!(set.normalise_guarded(), Guard::Repaired);
        assert!((set.weights()[0] - 1.0).abs() < 1e-6, "the finite particle keeps all the mass");
        set.log_w = vec![f32::NAN; 2];
        assert_eq!(set.normalise_guarded(), Guard::ResetToUniform);
        assert_eq!(set.weights(), vec![0.5, 0.5], "nothing usable left → uniform");
    }

    #[test]
    fn ess_spans_one_to_n() {
        assert!((ParticleSet::from_weights(&[1.0; 8]).effective_sample_size() - 8.0).abs() < 1e-4);
        let peaked = ParticleSet::from_weights(&[1.0, 0.0, 0.0, 0.0]);
        assert!((peaked.effective_sample_size() - 1.0).abs() < 1e-5, "one live particle → ESS 1");
    }
}
