//! The kidnapped robot (Probabilistic Robotics §8.3.3 / Engelson & McDermott 1992): at one step
//! of every episode the robot is carried to a random pose without its sensors noticing the
//! carrying. Odometry keeps reporting the motion the wheels made; only the scans betray the move.

use crate::act::{MapPhysics, PhysicsBody};
use crate::episode::reset::Episode;
use crate::params::{StepParams, expect_param};
use crate::world::map::TraversableMap;
use crate::world::{OccupancyMap, OnMap, Pose2, PreviousPose, ScenarioRng, TruePose};
use bevy::prelude::*;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Random draws before `kidnap_pose` settles for the farthest one (a small map may hold no pose
/// `min_distance_m` away).
pub const KIDNAP_TRIES: usize = 200;

/// When and how far to kidnap.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct KidnapParams {
    /// The episode step (`Episode::step`, 1 = first) at whose start the robot is moved
    /// (ours: 25, half of the paper's T = 50, so the filter has converged and has time to recover).
    pub at_step: u32,
    /// The new pose is at least this far from the old one when the map allows, metres (ours: 2,
    /// several times the tracking spread of 0.3 m so the old belief cannot explain the scans).
    pub min_distance_m: f32,
}

impl Default for KidnapParams {
    fn default() -> Self {
        Self { at_step: 25, min_distance_m: 2.0 }
    }
}

impl StepParams for KidnapParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.at_step > 0, "at_step", "a step ≥ 1 of the episode")?;
        expect_param(self.min_distance_m >= 0.0, "min_distance_m", "a distance ≥ 0 m")
    }
}

/// A uniform random traversable pose at least `min_distance_m` from `from`; when none of
/// `KIDNAP_TRIES` draws is that far, the farthest draw.
///
/// # Panics
/// If the traversable map has no cell (`TraversableMap::build` never returns such a map).
pub fn kidnap_pose(
    from: &Pose2,
    min_distance_m: f32,
    map: &OccupancyMap,
    traversable: &TraversableMap,
    rng: &mut impl Rng,
) -> Pose2 {
    let mut best = traversable.sample_pose(map, rng);
    for _ in 1..KIDNAP_TRIES {
        if best.distance(from) >= min_distance_m {
            break;
        }
        let next = traversable.sample_pose(map, rng);
        if next.distance(from) > best.distance(from) {
            best = next;
        }
    }
    best
}

/// The previous pose that makes odometry report, from `to`, the same motion as from
/// `previous` to `current`: to ⊕ (current⁻¹ ⊕ previous).
pub fn carried_previous(previous: &Pose2, current: &Pose2, to: &Pose2) -> Pose2 {
    to.compose(&current.between(previous))
}

/// Reads Episode, KidnapParams, the map's OccupancyMap and TraversableMap. Writes TruePose,
/// PreviousPose (carried along, so odometry reports the wheels' motion, not the jump),
/// MapPhysics (teleport), ScenarioRng.
pub fn kidnap(
    params: Res<KidnapParams>,
    mut maps: Query<(&OccupancyMap, &TraversableMap, &mut MapPhysics)>,
    mut robots: Query<(&Episode, &OnMap, &PhysicsBody, &mut TruePose, &mut PreviousPose, &mut ScenarioRng)>,
) {
    for (episode, on_map, body, mut pose, mut previous, mut rng) in &mut robots {
        if episode.step != params.at_step {
            continue;
        }
        let Ok((map, traversable, mut physics)) = maps.get_mut(on_map.0) else { continue };
        let to = kidnap_pose(&pose.0, params.min_distance_m, map, traversable, &mut rng.0);
        physics.teleport(*body, to);
        (pose.0, previous.0) = (to, carried_previous(&previous.0, &pose.0, &to));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sense::{Odometry, OdometryParams, odometry};
    use crate::testing::tiny_room;
    use crate::world::map::procedural::{ApartmentParams, generate_apartment};
    use crate::world::{SensorRng, angle_error};
    use bevy::ecs::system::RunSystemOnce;

    /// A world with one robot at `start` on `map`, at episode step `step`, having moved from
    /// `previous` during the last agent step.
    fn world_with_robot(map: OccupancyMap, previous: Pose2, start: Pose2, step: u32) -> (World, Entity) {
        let traversable = TraversableMap::build(&map, 0.18).expect("map has room");
        let mut physics = MapPhysics::from_map(&map, 0.1);
        let body = physics.add_robot(start, 0.18, false);
        let mut world = World::new();
        world.insert_resource(KidnapParams::default());
        world.insert_resource(OdometryParams { trans_noise_m: 0.0, rot_noise_deg: 0.0 });
        let m = world.spawn((map, traversable, physics)).id();
        let robot = world
            .spawn((
                (Episode { index: 0, step }, OnMap(m), body),
                (
                    TruePose(start),
                    PreviousPose(previous),
                    Odometry::default(),
                    ScenarioRng::seeded(5),
                    SensorRng::seeded(5),
                ),
            ))
            .id();
        (world, robot)
    }

    #[test]
    fn kidnap_moves_the_robot_without_odometry_seeing_it() {
        let map = generate_apartment(0, &ApartmentParams::default());
        let traversable = TraversableMap::build(&map, 0.18).expect("room");
        let start = traversable.sample_pose(&map, &mut crate::world::rng::stream(&[9]));
        let previous = start.compose(&Pose2::new(-0.2, 0.05, -0.3)); // the robot drove 0.2 m, turned 0.3 rad
        let wheel_motion = previous.between(&start);
        let (mut world, robot) = world_with_robot(map, previous, start, 24);
        world.run_system_once(kidnap).expect("kidnap runs");
        assert_eq!(world.get::<TruePose>(robot).expect("pose").0, start, "step 24: not yet");
        world.get_mut::<Episode>(robot).expect("episode").step = 25;
        world.run_system_once(kidnap).expect("kidnap runs");
        let moved = world.get::<TruePose>(robot).expect("pose").0;
        assert!(moved.distance(&start) >= 2.0, "kidnapped {} m, expected ≥ 2", moved.distance(&start));
        let m = world.get::<OnMap>(robot).expect("map").0;
        let body = *world.get::<PhysicsBody>(robot).expect("body");
        let physics_pose = world.get::<MapPhysics>(m).expect("physics").pose(body);
        assert!(physics_pose.distance(&moved) < 1e-4, "physics body teleported too: {physics_pose:?}");
        world.run_system_once(odometry).expect("odometry runs");
        let delta = world.get::<Odometry>(robot).expect("odometry").delta;
        assert!(
            delta.distance(&wheel_motion) < 1e-4 && angle_error(delta.yaw, wheel_motion.yaw) < 1e-4,
            "odometry reports the wheels' motion {wheel_motion:?}, not the jump: {delta:?}"
        );
        assert_eq!(world.get::<PreviousPose>(robot).expect("previous").0, moved, "odometry caught up");
    }

    #[test]
    fn kidnap_settles_for_the_farthest_pose_on_a_small_map() {
        // tiny_room is 2 m × 1.5 m: no traversable pose is 2 m from its centre.
        let start = Pose2::new(1.0, 0.75, 0.0);
        let (mut world, robot) = world_with_robot(tiny_room(), start, start, 25);
        world.run_system_once(kidnap).expect("kidnap runs");
        let moved = world.get::<TruePose>(robot).expect("pose").0;
        let d = moved.distance(&start);
        assert!(d > 0.4 && d < 2.0, "the farthest of {KIDNAP_TRIES} draws, {d} m from the centre");
    }
}
