//! The per-step collision flag: did the robot touch a wall (or another robot) during the step?

use bevy::prelude::Component;
use bevy_rapier2d::rapier::prelude::{ColliderHandle, PhysicsWorld};

/// True when the robot touched something during the last agent step (paper: reward −0.1).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Collided(pub bool);

/// Whether the solver pushed `collider` away from anything in the last physics step.
/// Rapier also reports predicted contacts a little before a touch (and keeps resting bodies
/// ≈ 2 cm apart), so distance says little; a non-zero contact impulse means a real push.
pub fn is_touching(world: &PhysicsWorld, collider: ColliderHandle) -> bool {
    world
        .contact_pairs_with(collider)
        .any(|pair| pair.manifolds.iter().flat_map(|m| m.points.iter()).any(|p| p.data.impulse > 0.0))
}
