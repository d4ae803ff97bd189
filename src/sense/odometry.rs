//! Odometry: the robot's motion since the previous agent step, in its previous frame, with noise.

use crate::world::Pose2;
use bevy::prelude::Component;

/// Relative motion reported by wheel odometry for the last agent step (robot frame, m and rad).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Odometry {
    pub delta: Pose2,
}
