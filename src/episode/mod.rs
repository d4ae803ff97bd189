//! Episode bookkeeping: fixed-length episodes with random restarts, optional kidnappings,
//! per-step errors and the paper's summary metrics.

mod kidnap;
mod metrics;
mod reset;

pub use kidnap::{KIDNAP_TRIES, KidnapParams, carried_previous, kidnap, kidnap_pose};
pub use metrics::{
    CellMetrics, CompletedEpisodes, CropSnapshot, EpisodeLog, EpisodeRecord, FIGURE_PARTICLES, LOSS_BETA,
    SUCCESS_RADIUS_M, StepError, step_metrics, succeeded, summarize,
};
pub use reset::{Episode, EpisodeEnd, EpisodeParams, EpisodeStart, episode_reset};
