//! Differential drive: turns the normalised action into body velocities within the robot's limits.

use crate::agent::Action;
use crate::world::RobotParams;
use bevy::prelude::*;

/// Body velocities to hold during this agent step, in the robot frame.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct DriveCommand {
    /// Forward speed, m/s (a differential drive cannot move sideways).
    pub linear_mps: f32,
    /// Turn rate, rad/s, counter-clockwise positive.
    pub angular_radps: f32,
}

/// Scales a normalised action to velocities; out-of-range or NaN actions are clamped first.
pub fn command_for(action: Action, limits: &RobotParams) -> DriveCommand {
    let a = action.clamped();
    DriveCommand {
        linear_mps: a.linear * limits.max_linear_mps,
        angular_radps: a.angular * limits.max_angular_radps,
    }
}

/// Reads Action, RobotParams. Writes DriveCommand.
pub fn drive(limits: Res<RobotParams>, mut robots: Query<(&Action, &mut DriveCommand)>) {
    for (action, mut command) in &mut robots {
        *command = command_for(*action, &limits);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::ecs::system::RunSystemOnce;

    #[test]
    fn drive_scales_and_clamps_actions() {
        let mut world = World::new();
        world.insert_resource(RobotParams::default());
        let full = world.spawn((Action::new(1.0, -1.0), DriveCommand::default())).id();
        let wild = world.spawn((Action::new(7.0, f32::NAN), DriveCommand::default())).id();
        world.run_system_once(drive).unwrap();
        let c = *world.get::<DriveCommand>(full).unwrap();
        assert_eq!(c.linear_mps, 0.5, "action +1 is the paper's 0.5 m/s");
        assert!((c.angular_radps + std::f32::consts::FRAC_PI_2).abs() < 1e-6, "action −1 is −π/2 rad/s");
        let c = *world.get::<DriveCommand>(wild).unwrap();
        assert_eq!((c.linear_mps, c.angular_radps), (0.5, 0.0), "clamped to +1, NaN turns to 0");
    }
}
