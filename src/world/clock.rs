//! Simulated time. Physics and episodes advance by fixed agent steps, never by the wall clock.

use bevy::prelude::Resource;

/// Counts agent steps; one step holds the action for `agent_step_s` seconds of simulated time.
#[derive(Resource, Clone, Debug, PartialEq)]
pub struct SimClock {
    pub step: u64,
    /// Seconds of simulated time per agent step (paper: 0.6 s).
    pub agent_step_s: f32,
}

impl Default for SimClock {
    fn default() -> Self {
        Self { step: 0, agent_step_s: 0.6 }
    }
}
