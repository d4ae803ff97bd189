//! Fixed-length episodes: when one ends, the robot restarts at a new random traversable pose.

use crate::act::{MapPhysics, PhysicsBody};
use crate::world::map::TraversableMap;
use crate::world::{EpisodeRng, OccupancyMap, OnMap, PreviousPose, TruePose};
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// Episode length (paper: T = 50 agent steps for RL and evaluation).
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct EpisodeParams {
    /// Agent steps per episode.
    pub steps: u32,
}

impl Default for EpisodeParams {
    fn default() -> Self {
        Self { steps: 50 }
    }
}

/// Where a robot is in its episodes. `step` counts the agent steps of the current episode,
/// including the one running now (1 during the first step).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Episode {
    pub index: u32,
    pub step: u32,
}

/// Marks a robot whose episode has just (re)started; filter initialisation and metrics key on it.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EpisodeStart;

/// Reads EpisodeParams, the map's OccupancyMap and TraversableMap. Writes Episode, TruePose,
/// PreviousPose, MapPhysics, EpisodeRng, EpisodeStart.
pub fn episode_reset(
    params: Res<EpisodeParams>,
    mut commands: Commands,
    mut maps: Query<(&OccupancyMap, &TraversableMap, &mut MapPhysics)>,
    mut robots: Query<(Entity, &OnMap, &PhysicsBody, &mut Episode, &mut TruePose, &mut PreviousPose, &mut EpisodeRng)>,
) {
    for (robot, on_map, body, mut episode, mut pose, mut previous, mut rng) in &mut robots {
        commands.entity(robot).remove::<EpisodeStart>();
        if episode.step >= params.steps {
            let Ok((map, traversable, mut physics)) = maps.get_mut(on_map.0) else { continue };
            let start = traversable.sample_pose(map, &mut rng.0);
            physics.teleport(*body, start);
            (pose.0, previous.0) = (start, start);
            *episode = Episode { index: episode.index + 1, step: 0 };
        }
        if episode.step == 0 {
            commands.entity(robot).insert(EpisodeStart);
        }
        episode.step += 1;
    }
}
