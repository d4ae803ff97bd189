//! The `turn` baseline: spin in place at the top turn rate, so the sensors sweep the whole room
//! without the robot ever leaving its spot (paper, §V baselines).

use crate::agent::Action;
use crate::params::{StepParams, expect_param};
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// Which way the `turn` baseline spins.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct TurnParams {
    /// Normalised angular action: +1 spins counter-clockwise at the robot's top turn rate, −1
    /// clockwise; values in between spin slower (paper: max ω, direction unspecified; we take CCW).
    pub direction: f32,
}

impl Default for TurnParams {
    fn default() -> Self {
        Self { direction: 1.0 }
    }
}

impl StepParams for TurnParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.direction.is_finite(), "direction", "a finite number (its sign picks the turn)")
    }
}

/// The action of the `turn` baseline: no forward motion, the turn rate the params ask for
/// (clamped to [−1, 1]; NaN stops the robot).
pub fn turn_action(params: &TurnParams) -> Action {
    Action::new(0.0, params.direction).clamped()
}

/// Reads TurnParams. Writes Action.
pub fn turn_policy(params: Res<TurnParams>, mut robots: Query<&mut Action>) {
    let action = turn_action(&params);
    for mut a in &mut robots {
        *a = action;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::ecs::system::RunSystemOnce;

    #[test]
    fn turn_policy_spins_in_place_at_max_rate() {
        let mut world = World::new();
        world.insert_resource(TurnParams::default());
        let robots = [world.spawn(Action::new(0.7, -0.2)).id(), world.spawn(Action::default()).id()];
        world.run_system_once(turn_policy).unwrap();
        for robot in robots {
            let a = *world.get::<Action>(robot).unwrap();
            assert_eq!(a, Action::new(0.0, 1.0), "turn must spin CCW at max ω without moving: {a:?}");
        }
    }

    #[test]
    fn turn_policy_direction_and_clamping() {
        let mut world = World::new();
        world.insert_resource(TurnParams { direction: -3.0 });
        let robot = world.spawn(Action::default()).id();
        world.run_system_once(turn_policy).unwrap();
        assert_eq!(*world.get::<Action>(robot).unwrap(), Action::new(0.0, -1.0), "CW, clamped to −1");
        assert_eq!(turn_action(&TurnParams { direction: f32::NAN }), Action::default(), "NaN stops");
    }
}
