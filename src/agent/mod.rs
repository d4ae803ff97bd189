//! ④ Agent: the normalised `Action` component and the policies (systems) that write it.

mod action;
mod random;

pub use action::Action;
pub use random::random_policy;
