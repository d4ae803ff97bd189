//! The soft actor-critic agent's networks and update (Haarnoja et al. 2018) on our engine.

pub mod config;
pub mod encoder;
mod layer;
pub mod mlp;
pub mod networks;
pub mod saved;
pub mod tanh_gaussian;
pub mod update;
mod widen;

pub use config::{ACTION_LEN, STATE_LEN, SacNetConfig};
pub use networks::{Candidates, Observations, PolicyWorkspace, SacNetworks};
pub use update::{SacHyper, SacLearner, Transitions, UpdateStats};
