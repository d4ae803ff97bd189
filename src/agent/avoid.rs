//! The `avoid` baseline (paper, §V): drive forward; split the depth strip into four quarters;
//! when something ahead (the two middle quarters) is too near, turn toward the more open outer
//! quarter, and back off while turning when both outer quarters are blocked as well.

use crate::agent::Action;
use crate::params::{StepParams, expect_param};
use crate::sense::DepthStrip;
use crate::world::RobotParams;
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// Speeds and the clearance of the `avoid` baseline.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct AvoidParams {
    /// Forward speed in the open, and backing-off speed when boxed in, m/s (our choice: 0.25,
    /// half the top speed).
    pub forward_mps: f32,
    /// A quarter is blocked when anything in it is nearer than this, metres (paper: 0.3). Measured
    /// from the body's edge (depth − `RobotParams::radius_m`): our depth strip is cast from the
    /// robot's centre, the paper's camera looks out from the front of the base.
    pub min_distance_m: f32,
    /// Turn rate while turning away, rad/s (our choice: π/2, the top turn rate).
    pub turn_radps: f32,
}

impl Default for AvoidParams {
    fn default() -> Self {
        Self { forward_mps: 0.25, min_distance_m: 0.3, turn_radps: std::f32::consts::FRAC_PI_2 }
    }
}

impl StepParams for AvoidParams {
    fn check(&self) -> Result<(), String> {
        expect_param(
            self.forward_mps.is_finite() && self.forward_mps >= 0.0,
            "forward_mps",
            "a speed ≥ 0 m/s",
        )?;
        expect_param(self.min_distance_m >= 0.0, "min_distance_m", "a distance ≥ 0 m")?;
        expect_param(self.turn_radps.is_finite(), "turn_radps", "a finite turn rate")
    }
}

/// Outer quarters whose mean depths differ by less than this are equally open, metres; the side
/// is then chosen away from the nearer middle quarter.
const SAME_OPENNESS_M: f32 = 0.05;

/// Nearest and mean depth of one quarter of the strip; an empty quarter is open (∞, ∞).
#[derive(Clone, Copy, Debug)]
struct Quarter {
    nearest_m: f32,
    mean_m: f32,
}

fn quarters(depths: &[f32]) -> [Quarter; 4] {
    let mut sum = [0.0f32; 4];
    let mut count = [0usize; 4];
    let mut nearest = [f32::INFINITY; 4];
    for (c, &d) in depths.iter().enumerate() {
        let q = c * 4 / depths.len();
        sum[q] += d;
        count[q] += 1;
        nearest[q] = nearest[q].min(d);
    }
    std::array::from_fn(|q| Quarter {
        nearest_m: nearest[q],
        mean_m: if count[q] == 0 { f32::INFINITY } else { sum[q] / count[q] as f32 },
    })
}

/// The `avoid` decision for one depth strip (columns left to right, metres). In the open: forward
/// at `forward_mps`. Middle quarters blocked: turn in place toward the side whose outer quarter
/// has the larger mean depth (ties: away from the nearer middle quarter). Outer quarters blocked
/// too: back off at `forward_mps` while turning the same way. An empty strip (no depth sensor
/// ran) stops the robot.
pub fn avoid_action(depths: &[f32], params: &AvoidParams, limits: &RobotParams) -> Action {
    if depths.is_empty() {
        return Action::default();
    }
    let [left, mid_left, mid_right, right] = quarters(depths);
    let blocked = |q: Quarter| q.nearest_m - limits.radius_m < params.min_distance_m;
    let forward = params.forward_mps / limits.max_linear_mps;
    if !blocked(mid_left) && !blocked(mid_right) {
        return Action::new(forward, 0.0).clamped();
    }
    let turn_left = if (left.mean_m - right.mean_m).abs() > SAME_OPENNESS_M {
        left.mean_m > right.mean_m
    } else {
        mid_left.mean_m > mid_right.mean_m
    };
    let turn = params.turn_radps / limits.max_angular_radps;
    let angular = if turn_left { turn } else { -turn };
    let linear = if blocked(left) && blocked(right) { -forward } else { 0.0 };
    Action::new(linear, angular).clamped()
}

/// Reads DepthStrip, AvoidParams, RobotParams. Writes Action.
pub fn avoid_policy(
    params: Res<AvoidParams>,
    limits: Res<RobotParams>,
    mut robots: Query<(&DepthStrip, &mut Action)>,
) {
    for (strip, mut action) in &mut robots {
        *action = avoid_action(&strip.depths_m, &params, &limits);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::ecs::system::RunSystemOnce;

    /// 56 columns (paper) at `open` metres, with columns `near` set to `d`.
    fn strip(open: f32, near: std::ops::Range<usize>, d: f32) -> Vec<f32> {
        (0..56).map(|c| if near.contains(&c) { d } else { open }).collect()
    }

    fn run(depths: Vec<f32>) -> Action {
        let mut world = World::new();
        world.insert_resource(AvoidParams::default());
        world.insert_resource(RobotParams::default());
        let robot = world.spawn((DepthStrip { depths_m: depths }, Action::default())).id();
        world.run_system_once(avoid_policy).unwrap();
        *world.get::<Action>(robot).unwrap()
    }

    #[test]
    fn avoid_policy_drives_forward_in_the_open() {
        let a = run(strip(3.0, 0..0, 0.0));
        assert_eq!(a, Action::new(0.5, 0.0), "0.25 m/s of 0.5 m/s top speed, straight: {a:?}");
        // Something near only in an outer quarter is not in the way.
        let a = run(strip(3.0, 0..14, 0.2));
        assert_eq!(a, Action::new(0.5, 0.0), "outer-quarter obstacles do not stop it: {a:?}");
    }

    #[test]
    fn avoid_policy_turns_right_away_from_a_near_obstacle_on_the_left() {
        let a = run(strip(3.0, 16..26, 0.35));
        assert!(a.angular < -0.99, "obstacle left of centre: turn right (CW) at full rate, got {a:?}");
        assert_eq!(a.linear, 0.0, "turn in place while an outer quarter is open: {a:?}");
        // Left outer quarter wide open, right outer quarter cluttered (but not blocked): turn left.
        let mut depths = strip(1.0, 16..26, 0.35);
        depths[..14].fill(4.0);
        let a = run(depths);
        assert!(a.angular > 0.99 && a.linear == 0.0, "the more open outer quarter wins: {a:?}");
    }

    #[test]
    fn avoid_policy_backs_off_when_boxed_in() {
        let mut depths = strip(0.3, 0..0, 0.0);
        depths[..14].fill(0.4); // left slightly more open than right
        let a = run(depths);
        assert!(a.linear < -0.49, "boxed in: back off at the forward speed, got {a:?}");
        assert!(a.angular > 0.99, "while turning toward the more open left: {a:?}");
        assert_eq!(avoid_action(&[], &AvoidParams::default(), &RobotParams::default()), Action::default());
    }
}
