//! `ApfnSet`, the stages of one agent step: the schedule files' systems are placed in them
//! (`compose`) and the plugin chains them (`plugin`).

use bevy::prelude::*;

/// The stages of one agent step, in order. Every registered system runs in one of them, so a
/// user's own system can be placed with `.in_set(ApfnSet::Agent)` or `.after(ApfnSet::Particles)`.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ApfnSet {
    /// Episode bookkeeping at the start of a step: resets, new start poses.
    Episode,
    /// Odometry and sensors read the world.
    Sense,
    /// The filter: init, transition, likelihood, resampling, estimate.
    Particles,
    /// Belief projection for the agent.
    Belief,
    /// Per-step errors and rewards, on the estimate the agent is about to act on.
    Evaluate,
    /// Policies write the action.
    Agent,
    /// Drive and physics move the robots.
    Act,
}

impl ApfnSet {
    pub const ALL: [ApfnSet; 7] = [
        ApfnSet::Episode,
        ApfnSet::Sense,
        ApfnSet::Particles,
        ApfnSet::Belief,
        ApfnSet::Evaluate,
        ApfnSet::Agent,
        ApfnSet::Act,
    ];
}
