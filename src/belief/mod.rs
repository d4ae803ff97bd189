//! ③ Belief: the particle set projected for the agent (paper §III-B), between the filter and the
//! policy: egocentric crops of the belief map around the estimate and further modes.

mod crop;
mod modes;

pub use crop::{BELIEF_CHANNELS, BeliefCrop, BeliefParams, belief_crop, project_crop};
pub use modes::belief_modes;
