//! The action every policy writes: normalised base velocities, as the paper's agent outputs.

use bevy::prelude::Component;

/// Normalised command in [−1, 1]²: `linear` scales the robot's top speed, `angular` its top turn rate.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Action {
    pub linear: f32,
    pub angular: f32,
}

impl Action {
    pub fn new(linear: f32, angular: f32) -> Self {
        Self { linear, angular }
    }

    /// The same action with both parts clamped to [−1, 1]; NaN reads as 0 (stop), never as motion.
    pub fn clamped(self) -> Self {
        let clamp = |v: f32| if v.is_nan() { 0.0 } else { v.clamp(-1.0, 1.0) };
        Self { linear: clamp(self.linear), angular: clamp(self.angular) }
    }
}
