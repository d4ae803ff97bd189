//! The robot: a differential-drive disc whose true pose the simulator owns.

use crate::world::pose::Pose2;
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// Marks a robot entity. Spawning one brings its ground truth and per-step state along.
#[derive(Component, Clone, Copy, Debug, Default)]
#[require(TruePose, PreviousPose)]
pub struct Robot;

/// A robot's number in its world, assigned at spawn in spawn order (0, 1, …). Systems whose
/// outcome depends on the order they visit robots (episode restarts, the order finished episodes
/// are recorded in, batched policies) visit them by this id: a query's own order follows the
/// archetypes, so it changes whenever a schedule adds a component to some robots.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct RobotId(pub u32);

/// The given robots, ordered by their [`RobotId`].
pub fn in_id_order<'a>(robots: impl Iterator<Item = (Entity, &'a RobotId)>) -> Vec<Entity> {
    let mut ordered: Vec<(RobotId, Entity)> = robots.map(|(entity, id)| (*id, entity)).collect();
    ordered.sort_unstable();
    ordered.into_iter().map(|(_, entity)| entity).collect()
}

/// Ground-truth pose, written by physics; only metrics and sensors' simulation may read it.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct TruePose(pub Pose2);

/// True pose at the previous agent step; odometry reports the motion between the two.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct PreviousPose(pub Pose2);

/// The map entity a robot lives in (its grid, layers and physics world).
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct OnMap(pub Entity);

/// Body and drive limits (LoCoBot-like base of the paper).
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct RobotParams {
    /// Radius of the circular body, metres (issue spec: ≈ 0.18 m).
    pub radius_m: f32,
    /// Speed at action +1, m/s (paper: 0.5).
    pub max_linear_mps: f32,
    /// Turn rate at action +1, rad/s (paper: π/2).
    pub max_angular_radps: f32,
}

impl Default for RobotParams {
    fn default() -> Self {
        Self { radius_m: 0.18, max_linear_mps: 0.5, max_angular_radps: std::f32::consts::FRAC_PI_2 }
    }
}
