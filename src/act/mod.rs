//! ⑤ Act: the differential drive turns actions into velocities; one rapier world per map moves
//! the robots and reports collisions.

mod collision;
mod drive;
mod physics;
mod shield;

pub use collision::{Collided, is_touching};
pub use drive::{DriveCommand, command_for, drive};
pub use physics::{CellRect, MapPhysics, PhysicsBody, PhysicsParams, physics, wall_rectangles};
pub use shield::{BumpShieldParams, bump_shield, shielded};
