//! Information-gain active localization (active Markov localization: Burgard, Fox & Thrun 1997;
//! Fox, Burgard & Thrun 1998): drive the candidate motion (a primitive, or a reach plan toward a
//! far view) after which the particle belief is expected to have the lowest entropy, with small
//! costs for collisions and distance.

mod entropy;
mod params;
mod plans;
mod policy;
mod predict;

pub use entropy::histogram_entropy;
pub use params::InfogainParams;
pub use policy::infogain_policy;
pub use predict::{
    CandidateScore, ImaginedStep, MapView, Models, best_action, drive_on_map, score_candidates,
};
