//! `sac_update`: gradient steps interleaved with collection, at a configurable ratio.

use crate::agent::sac::learner::SacAgent;
use crate::params::{StepParams, expect_param};
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct SacUpdateParams {
    /// Gradient steps after every `every` agent steps of the world (all robots together).
    pub updates: u32,
    pub every: u32,
}

impl Default for SacUpdateParams {
    fn default() -> Self {
        Self { updates: 1, every: 1 }
    }
}

impl StepParams for SacUpdateParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.updates <= 1000, "updates", "0 to 1,000 gradient steps")?;
        expect_param(self.every >= 1, "every", "≥ 1 agent step")
    }
}

/// Reads SacUpdateParams. Writes the learning agent's networks (when it has warmed up).
pub fn sac_update(params: Res<SacUpdateParams>, mut agents: Query<&mut SacAgent>) {
    for mut agent in &mut agents {
        agent.steps += 1;
        if agent.steps % u64::from(params.every) != 0 || agent.warming_up() {
            continue;
        }
        for _ in 0..params.updates {
            agent.train_once();
        }
    }
}
