//! `bump_shield`: a safety layer between any policy and the physics. It replays the drive's next
//! agent step against the LiDAR scan taken at its start and slows the forward speed, keeping the
//! turn, until the swept disc stays clear of every scanned point. A learned policy that
//! misjudges where it is (its belief crop shows the wrong room) would otherwise push into walls
//! its own LiDAR sees.

use crate::act::drive::DriveCommand;
use crate::act::physics::PhysicsParams;
use crate::params::{StepParams, expect_param};
use crate::sense::LidarScan;
use crate::world::RobotParams;
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct BumpShieldParams {
    /// Clearance kept between the body's edge and any scanned point, metres (our choice: 0.05,
    /// the near miss the physics does not count as a collision).
    pub margin_m: f32,
    /// Speeds tried, from the command's down to a stop in this many equal steps (our choice: 8).
    pub speed_steps: u32,
}

impl Default for BumpShieldParams {
    fn default() -> Self {
        Self { margin_m: 0.05, speed_steps: 8 }
    }
}

impl StepParams for BumpShieldParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.margin_m.is_finite() && self.margin_m >= 0.0, "margin_m", "a distance ≥ 0 m")?;
        expect_param((1..=1000).contains(&self.speed_steps), "speed_steps", "a count in 1..=1000")
    }
}

/// The scan's hits as points in the robot frame; misses (at `range_max_m`) block nothing.
fn scan_points(scan: &LidarScan) -> impl Iterator<Item = Vec2> + '_ {
    scan.ranges_m.iter().enumerate().filter(|&(_, &r)| r.is_finite() && r < scan.range_max_m).map(
        |(i, &r)| {
            let angle = scan.angle_min_rad + i as f32 * scan.angle_increment_rad;
            Vec2::from_angle(angle) * r
        },
    )
}

/// Whether holding `command` for `substeps` steps of `dt_s` (the physics' integration: the
/// velocity re-aimed along the heading before each step) brings the body's centre nearer than
/// `clearance_m` to a point it is approaching. Points already within the clearance only block
/// motion toward them, so a robot against a wall can still back or turn away.
fn sweeps_into(points: &[Vec2], command: DriveCommand, dt_s: f32, substeps: u32, clearance_m: f32) -> bool {
    let (mut position, mut heading) = (Vec2::ZERO, 0.0f32);
    for _ in 0..substeps {
        position += Vec2::from_angle(heading) * command.linear_mps * dt_s;
        heading += command.angular_radps * dt_s;
        let hits = |q: &Vec2| {
            let d = position.distance(*q);
            d < clearance_m && d < q.length()
        };
        if points.iter().any(hits) {
            return true;
        }
    }
    false
}

/// The command with its forward speed cut to the fastest of `speed_steps` equal fractions whose
/// sweep stays clear of `points`; a stop with the same turn when none does (a disc turning in
/// place touches nothing new).
pub fn shielded(
    command: DriveCommand,
    points: &[Vec2],
    physics: &PhysicsParams,
    clearance_m: f32,
    speed_steps: u32,
) -> DriveCommand {
    (0..speed_steps)
        .map(|k| DriveCommand {
            linear_mps: command.linear_mps * (speed_steps - k) as f32 / speed_steps as f32,
            ..command
        })
        .find(|c| !sweeps_into(points, *c, physics.dt_s, physics.substeps, clearance_m))
        .unwrap_or(DriveCommand { linear_mps: 0.0, ..command })
}

/// Reads LidarScan, DriveCommand, BumpShieldParams, RobotParams, PhysicsParams. Writes
/// DriveCommand. Runs after `drive` and before `physics`, on the scan of the step's start.
pub fn bump_shield(
    params: Res<BumpShieldParams>,
    limits: Res<RobotParams>,
    physics: Res<PhysicsParams>,
    mut robots: Query<(&LidarScan, &mut DriveCommand)>,
    mut points: Local<Vec<Vec2>>,
) {
    let clearance_m = limits.radius_m + params.margin_m;
    for (scan, mut command) in &mut robots {
        points.clear();
        points.extend(scan_points(scan));
        *command = shielded(*command, &points, &physics, clearance_m, params.speed_steps);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::ecs::system::RunSystemOnce;

    /// A 360° scan of 360 rays that sees a wall `d` metres ahead (rays within ±60° of the
    /// heading hit the plane x = d) and nothing elsewhere.
    fn wall_ahead(d: f32) -> LidarScan {
        let step = std::f32::consts::TAU / 360.0;
        let ranges_m = (0..360)
            .map(|i| {
                let angle = -std::f32::consts::PI + i as f32 * step;
                if angle.cos() > 0.5 { d / angle.cos() } else { 5.6 }
            })
            .collect();
        LidarScan {
            ranges_m,
            angle_min_rad: -std::f32::consts::PI,
            angle_increment_rad: step,
            range_min_m: 0.05,
            range_max_m: 5.6,
        }
    }

    fn run(scan: LidarScan, command: DriveCommand) -> DriveCommand {
        let mut world = World::new();
        world.insert_resource(BumpShieldParams::default());
        world.insert_resource(RobotParams::default());
        world.insert_resource(PhysicsParams::default());
        let robot = world.spawn((scan, command)).id();
        world.run_system_once(bump_shield).unwrap();
        *world.get::<DriveCommand>(robot).unwrap()
    }

    const FULL_AHEAD: DriveCommand = DriveCommand { linear_mps: 0.5, angular_radps: 0.0 };

    #[test]
    fn bump_shield_leaves_a_clear_path_alone() {
        // 0.3 m of travel, 0.23 m of clearance: a wall 1 m ahead is out of reach.
        assert_eq!(run(wall_ahead(1.0), FULL_AHEAD), FULL_AHEAD);
        let turning = DriveCommand { linear_mps: 0.5, angular_radps: 1.5 };
        assert_eq!(run(wall_ahead(1.0), turning), turning);
    }

    #[test]
    fn bump_shield_slows_to_stop_short_of_a_wall() {
        // Wall 0.4 m ahead: the centre may travel at most 0.4 − 0.18 − 0.05 = 0.17 m of the 0.3 m.
        let c = run(wall_ahead(0.4), FULL_AHEAD);
        let travel = c.linear_mps * PhysicsParams::default().agent_step_s();
        assert!(travel <= 0.17 + 1e-4 && travel > 0.17 - 0.3 / 8.0, "travel {travel} m, command {c:?}");
        assert_eq!(c.angular_radps, 0.0, "the turn is kept");
    }

    #[test]
    fn bump_shield_stops_a_robot_touching_a_wall_but_lets_it_back_off_and_turn() {
        let touching = wall_ahead(0.19);
        let c = run(touching.clone(), DriveCommand { linear_mps: 0.5, angular_radps: 1.0 });
        assert_eq!(c, DriveCommand { linear_mps: 0.0, angular_radps: 1.0 }, "no further push, turn kept");
        let back = DriveCommand { linear_mps: -0.5, angular_radps: 0.0 };
        assert_eq!(run(touching, back), back, "moving away from a point is never blocked");
    }

    #[test]
    fn bump_shield_ignores_misses() {
        let empty = LidarScan { ranges_m: vec![5.6; 360], ..wall_ahead(1.0) };
        assert_eq!(run(empty, FULL_AHEAD), FULL_AHEAD);
    }
}
