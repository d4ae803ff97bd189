//! The APFN agent: soft actor-critic on the belief crop, the LiDAR grid and the robot state.

mod learner;
mod observation;
mod policy;
mod replay;
mod reward;
mod update;

pub use learner::{EpisodeReturn, SacAgent, SacAgentConfig};
pub use observation::{ObservationShape, decode, encode_belief, encode_grid, robot_state};
pub use policy::{SacPolicyParams, check_policy_inputs, sac_policy, shared_policy};
pub use replay::{ReplayBuffer, SampledBatch};
pub use reward::{Reward, RewardParams, localization_reward, reward};
pub use update::{SacUpdateParams, sac_update};
