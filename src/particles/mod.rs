//! ② Particles: the particle set and the filter steps, in the order a step runs them:
//! init (draws the sets marked NeedsInit) → transition → (recovery before the update) → likelihood_field,
//! beam_model or pfnet → (augmented recovery) →
//! resample (fixed or KLD-adapted count) →
//! estimate. Each step is a plain kernel over a `ParticleSet` plus a small system; weights are
//! log-weights, Σ exp = 1.

mod beam_model;
mod estimate;
mod init;
mod kld;
mod likelihood_field;
mod pfnet;
mod recovery;
mod resample;
mod set;
mod transition;

pub use beam_model::{
    BEAM_CHUNK, BeamModelParams, add_log_beam_likelihoods, beam_probability, beam_readings, mcl_beam_model,
    weigh_beam_model,
};
pub use estimate::{estimate, estimate_pose};
pub use init::{
    InitParams, Initialised, NeedsInit, StartGuess, Task, draw_around_guess, draw_initial_set, init_particles,
};
pub use kld::{KldHistogram, KldParams};
pub use likelihood_field::{
    BeamTerms, LIKELIHOOD_CHUNK, LOG_P_TABLE_LEN, LikelihoodFieldParams, add_log_likelihoods, beam_indices,
    mcl_likelihood_field, selected_beams, weigh_likelihood_field,
};
pub use pfnet::{
    ConvergedScale, MapFeatures, PfNetLikelihoodParams, PfNetState, local_grid_for, map_view,
    pfnet_likelihood, shared_model,
};
pub use recovery::{
    RecoveryBeforeUpdateParams, RecoveryParams, RecoveryState, augmented_recovery, inject_uniform, recover,
    recovery_before_update, update_averages,
};
pub use resample::{
    ResampleParams, resample, resample_kld, resample_soft, resample_with, should_resample, systematic_indices,
};
pub use set::{
    Degenerate, FilterHealth, Guard, LikelihoodStats, ObservationModel, ParticleError, ParticleSet,
    PoseEstimate, record_observation,
};
pub use transition::{TRANSITION_CHUNK, TransitionParams, propagate, transition};
