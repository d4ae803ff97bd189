//! `bump_shield`: a safety layer between any policy and the physics. It replays the drive's next
//! agent step against the LiDAR scan taken at its start and slows the forward speed, keeping the
//! turn, until the swept disc stays clear of every scanned point. A learned policy that
//! misjudges where it is (its belief crop shows the wrong room) would otherwise push into walls
//! its own LiDAR sees. What the LiDAR does not cover (the rear 120° of the paper's 240° sensor) is
//! not guarded. For the APFN agent it costs localization (docs/results/sac_shield/).

use crate::act::drive::DriveCommand;
use crate::act::physics::PhysicsParams;
use crate::params::{StepParams, expect_param};
use crate::sense::LidarScan;
use crate::world::RobotParams;
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// The clearance `bump_shield` keeps and how finely it cuts the speed.
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

/// How far the nearest scanned point may come below the robot's present nearest when it is
/// already inside the clearance, metres: the scan samples a wall at discrete rays, so driving
/// along a wall finds points a little nearer than the one it started from.
const ALONG_WALL_TOLERANCE_M: f32 = 0.02;

/// Nearest distance from `position` to any of `points` (∞ without points).
fn nearest(points: &[Vec2], position: Vec2) -> f32 {
    points.iter().map(|q| position.distance(*q)).fold(f32::INFINITY, f32::min)
}

/// Whether holding `command` for `substeps` steps of `dt_s` (the physics' integration: the
/// velocity re-aimed along the heading before each step) brings the body's centre nearer to a
/// scanned point than `floor_m`.
fn sweeps_into(points: &[Vec2], command: DriveCommand, dt_s: f32, substeps: u32, floor_m: f32) -> bool {
    let (mut position, mut heading) = (Vec2::ZERO, 0.0f32);
    (0..substeps).any(|_| {
        position += Vec2::from_angle(heading) * command.linear_mps * dt_s;
        heading += command.angular_radps * dt_s;
        nearest(points, position) < floor_m
    })
}

/// The command with its forward speed cut to the fastest of `speed_steps` equal fractions whose
/// sweep keeps `clearance_m` from every point of `points`, or, when the robot is already nearer
/// than that, comes no nearer than it is (so it can drive along or away from a wall it is close
/// to); a stop with the same turn when none does (a disc turning in place touches nothing new).
pub fn shielded(
    command: DriveCommand,
    points: &[Vec2],
    physics: &PhysicsParams,
    clearance_m: f32,
    speed_steps: u32,
) -> DriveCommand {
    let now = nearest(points, Vec2::ZERO);
    let floor_m = if now < clearance_m { now - ALONG_WALL_TOLERANCE_M } else { clearance_m };
    (0..speed_steps)
        .map(|k| DriveCommand {
            linear_mps: command.linear_mps * (speed_steps - k) as f32 / speed_steps as f32,
            ..command
        })
        .find(|c| !sweeps_into(points, *c, physics.dt_s, physics.substeps, floor_m))
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
    use crate::act::MapPhysics;
    use crate::sense::{LidarParams, RayGrid, cast_scan};
    use crate::testing::tiny_room;
    use crate::world::Pose2;
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
    fn bump_shield_lets_a_robot_drive_along_a_wall_it_is_close_to() {
        // A wall 0.2 m to the right, parallel to the heading: inside the 0.23 m clearance, but
        // driving along it comes no nearer.
        let mut scan = wall_ahead(1.0);
        for (i, r) in scan.ranges_m.iter_mut().enumerate() {
            let angle = scan.angle_min_rad + i as f32 * scan.angle_increment_rad;
            *r = if angle.sin() < -0.05 { (-0.2 / angle.sin()).min(5.6) } else { 5.6 };
        }
        assert_eq!(run(scan, FULL_AHEAD), FULL_AHEAD);
    }

    /// Drives `command` for `steps` agent steps in the tiny room from `start`, each shielded on
    /// a fresh LiDAR scan; returns the final pose and whether the physics ever flagged a touch.
    fn drive_shielded(start: Pose2, command: DriveCommand, steps: usize) -> (Pose2, bool) {
        let map = tiny_room();
        let (grid, physics) = (RayGrid::from_map(&map), PhysicsParams::default());
        let mut world = MapPhysics::from_map(&map, physics.dt_s);
        let robot = world.add_robot(start, RobotParams::default().radius_m, false);
        let (mut pose, mut touched, mut scan) = (start, false, LidarScan::default());
        let clearance = RobotParams::default().radius_m + BumpShieldParams::default().margin_m;
        for _ in 0..steps {
            cast_scan(&grid, pose, &[], &LidarParams::default(), &mut scan);
            let points: Vec<Vec2> = scan_points(&scan).collect();
            let safe = shielded(command, &points, &physics, clearance, 8);
            let [(next, hit)] = world.step_robots(&[(robot, safe)], physics.substeps)[..] else {
                unreachable!()
            };
            (pose, touched) = (next, touched || hit);
        }
        (pose, touched)
    }

    #[test]
    fn bump_shield_keeps_the_physics_from_flagging_a_collision() {
        // Facing the tiny room's east wall (inner face at x = 1.9 m) from 0.3 m away: unshielded,
        // two steps at full speed hit it (`physics_flags_collision_when_driving_into_a_wall`).
        let (pose, touched) = drive_shielded(Pose2::new(1.6, 0.3, 0.0), FULL_AHEAD, 3);
        assert!(!touched, "the shield must stop short of the wall, ended at {pose:?}");
        assert!(pose.x > 1.6 + 0.03, "it still closes in before stopping, ended at x = {}", pose.x);
        // Along the south wall (face at y = 0.1 m), 5 cm clear: full speed all the way.
        let (pose, touched) = drive_shielded(Pose2::new(0.4, 0.1 + 0.18 + 0.05, 0.0), FULL_AHEAD, 2);
        assert!(!touched && (pose.x - 1.0).abs() < 0.03, "two free steps of 0.3 m, ended at {pose:?}");
    }

    #[test]
    fn bump_shield_ignores_misses() {
        let empty = LidarScan { ranges_m: vec![5.6; 360], ..wall_ahead(1.0) };
        assert_eq!(run(empty, FULL_AHEAD), FULL_AHEAD);
    }
}
