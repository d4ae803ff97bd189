//! The candidate motions of `infogain_policy` as plans: the action of each imagined agent step.
//!
//! Two kinds. A *primitive* holds one action for `horizon_steps` steps (1.2 s at the default
//! horizon: it sees round the next corner at most). A *reach* plan turns toward one of
//! `reach_headings` directions and then drives straight ahead, `reach_steps` steps in all: a
//! candidate that looks metres ahead, into the room beyond a door, where a primitive cannot tell
//! the doorway from the wall beside it. The look-ahead imagines a scan after every step of
//! either; the robot drives the first action of the cheapest plan and plans again at the next
//! step.

use crate::act::PhysicsParams;
use crate::agent::Action;
use crate::agent::infogain::params::InfogainParams;
use crate::world::{RobotParams, wrap_angle};
use std::f32::consts::TAU;

/// One candidate motion over the look-ahead.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// The action of each imagined agent step; the robot drives the first.
    pub actions: Vec<Action>,
    /// Imagine the odometry's noise (primitives) or the exact motion (reach plans). Over six
    /// steps the noise spreads a mode over several heading bins, which the filter's scans hold
    /// together but the tempered imagined ones cannot: with it, a reach plan would look worse
    /// for its length alone.
    pub noisy: bool,
}

/// The primitives of `params`, then its reach plans, in that order (so a tie keeps a primitive).
pub fn candidate_plans(params: &InfogainParams, robot: &RobotParams, physics: &PhysicsParams) -> Vec<Plan> {
    let horizon = params.horizon_steps as usize;
    let primitives = params
        .candidates
        .iter()
        .map(|&(linear, angular)| Plan { actions: vec![Action::new(linear, angular); horizon], noisy: true });
    let turn_per_step = robot.max_angular_radps * physics.agent_step_s();
    let reach = (0..params.reach_headings).map(|k| {
        let heading = wrap_angle(TAU * k as f32 / params.reach_headings as f32);
        Plan { actions: turn_then_drive(heading, turn_per_step, params.reach_steps), noisy: false }
    });
    primitives.chain(reach).collect()
}

/// `steps` actions that turn the robot by `heading` (radians, in (−π, π]) and then drive straight
/// at full speed. Turns in place while more than one step's turn (`turn_per_step`) is left; the
/// step that finishes the turn drives the arc that ends on the new heading, so a small turn costs
/// no step.
fn turn_then_drive(heading: f32, turn_per_step: f32, steps: u32) -> Vec<Action> {
    let mut left = heading;
    (0..steps)
        .map(|_| {
            if left.abs() > turn_per_step {
                left -= turn_per_step.copysign(left);
                Action::new(0.0, 1f32.copysign(left))
            } else {
                let angular = left / turn_per_step;
                left = 0.0;
                Action::new(1.0, angular)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::PI;

    #[test]
    fn reach_plans_turn_to_their_heading_then_drive_straight() {
        let (robot, physics) = (RobotParams::default(), PhysicsParams::default());
        let params = InfogainParams { reach_headings: 4, reach_steps: 5, ..Default::default() };
        let plans = candidate_plans(&params, &robot, &physics);
        let primitives = params.candidates.len();
        assert_eq!(plans.len(), primitives + 4, "the primitives, then one plan per heading");
        assert!(plans[..primitives].iter().all(|p| p.noisy && p.actions.len() == 2));
        let reach = &plans[primitives..];
        assert!(reach.iter().all(|p| !p.noisy && p.actions.len() == 5));
        // Heading 0: straight ahead all the way.
        assert!(reach[0].actions.iter().all(|&a| a == Action::new(1.0, 0.0)), "{:?}", reach[0]);
        // The turn each plan imagines adds up to its heading (0.6 s at π/2 rad/s per full step).
        let turn_per_step = robot.max_angular_radps * physics.agent_step_s();
        for (plan, heading) in reach.iter().zip([0.0, PI / 2.0, PI, -PI / 2.0]) {
            let turned: f32 = plan.actions.iter().map(|a| a.angular * turn_per_step).sum();
            assert!((wrap_angle(turned - heading)).abs() < 1e-4, "{plan:?} turns {turned}, not {heading}");
            let driving = plan.actions.iter().position(|a| a.linear > 0.0).expect("it drives");
            assert!(plan.actions[..driving].iter().all(|a| a.linear == 0.0 && a.angular.abs() == 1.0));
            assert!(plan.actions[driving + 1..].iter().all(|&a| a == Action::new(1.0, 0.0)));
        }
        // A quarter turn (1.57 rad) is more than one step's 0.94: one step in place, then an arc.
        assert_eq!(reach[1].actions[0], Action::new(0.0, 1.0));
        assert_eq!(reach[3].actions[0], Action::new(0.0, -1.0));
        assert!(reach[1].actions[1].linear == 1.0 && reach[1].actions[1].angular > 0.0);
    }

    #[test]
    fn without_reach_headings_the_plans_are_the_primitives() {
        let params = InfogainParams::default();
        let plans = candidate_plans(&params, &RobotParams::default(), &PhysicsParams::default());
        let firsts: Vec<(f32, f32)> =
            plans.iter().map(|p| (p.actions[0].linear, p.actions[0].angular)).collect();
        assert_eq!(firsts, params.candidates);
    }
}
