//! ④ Agent: the normalised `Action` component and the policies (systems) that write it.

mod action;
mod avoid;
mod goalnav;
mod infogain;
mod random;
pub mod sac;
mod turn;

pub use action::Action;
pub use avoid::{AvoidParams, avoid_action, avoid_policy};
pub use goalnav::{GoalPlan, GoalnavParams, draw_plan, follow, goalnav_policy, needs_new_plan, new_plan};
pub use infogain::{
    CandidateScore, ImaginedStep, InfogainParams, MapView, Models, best_action, drive_on_map,
    histogram_entropy, infogain_policy, score_candidates,
};
pub use random::random_policy;
pub use turn::{TurnParams, turn_action, turn_policy};
