//! The `random` baseline: a fresh uniform action in [−1, 1]² every agent step.

use crate::agent::Action;
use crate::world::ScenarioRng;
use bevy::prelude::*;
use rand::Rng;

/// Reads ScenarioRng. Writes Action.
pub fn random_policy(mut robots: Query<(&mut Action, &mut ScenarioRng)>) {
    for (mut action, mut rng) in &mut robots {
        *action = Action::new(rng.0.random_range(-1.0..=1.0), rng.0.random_range(-1.0..=1.0));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::ecs::system::RunSystemOnce;

    #[test]
    fn random_policy_writes_bounded_varying_actions() {
        let mut world = World::new();
        let robot = world.spawn((Action::default(), ScenarioRng::seeded(3))).id();
        let mut seen = Vec::new();
        for _ in 0..20 {
            world.run_system_once(random_policy).unwrap();
            let a = *world.get::<Action>(robot).unwrap();
            assert!(a.linear.abs() <= 1.0 && a.angular.abs() <= 1.0, "action out of range: {a:?}");
            seen.push(a);
        }
        assert!(seen.windows(2).any(|w| w[0] != w[1]), "a random policy must vary its actions");
    }
}
