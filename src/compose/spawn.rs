//! Turns a loaded scene into entities: one entity per map (grid, layers, ray grid, physics world)
//! and `robots_per_map` robots on each, at random traversable start poses.

use crate::act::{Collided, DriveCommand, MapPhysics};
use crate::agent::Action;
use crate::agent::sac::Reward;
use crate::belief::BeliefCrop;
use crate::compose::error::ComposeError;
use crate::compose::scene::{LoadedScene, NamedMap};
use crate::episode::{Episode, EpisodeLog, StepError};
use crate::particles::{FilterHealth, NeedsInit, ParticleSet, PoseEstimate};
use crate::sense::{DepthStrip, LidarScan, LocalGrid, Odometry, RayGrid};
use crate::world::map::{DistanceField, NetworkMap, START_POSE_TRIES, TraversableMap};
use crate::world::rng::stream;
use crate::world::{OccupancyMap, OnMap, Pose2, PreviousPose, Robot, RobotId, RobotRngs, TruePose};
use bevy::prelude::*;
use rand::Rng;

/// Names a map entity, as results and trajectories refer to it.
#[derive(Component, Clone, Debug, PartialEq, Eq)]
pub struct MapName(pub String);

/// Filter map resolution, metres (reference: 0.1 m cells for PF-net).
pub const NETWORK_RESOLUTION_M: f32 = 0.1;

/// What the sensors, filters and policies read from a map entity: the grid itself, its distance
/// field, ray grid, the networks' coarser grid and the cells a robot of the scene's radius fits in.
pub fn map_layers(map: &OccupancyMap, traversable: TraversableMap) -> impl Bundle {
    (
        NetworkMap::from_fine(map, NETWORK_RESOLUTION_M),
        DistanceField::build(map),
        RayGrid::from_map(map),
        traversable,
        map.clone(),
    )
}

/// Inserts the scene's world resources and spawns its maps and robots; returns the robots in
/// spawn order, which is their `RobotId` order. Each robot's random streams are keyed by (seed,
/// map index, robot index).
pub fn spawn_scene(world: &mut World, loaded: &LoadedScene) -> Result<Vec<Entity>, ComposeError> {
    let scene = &loaded.scene;
    world.insert_resource(scene.robot.clone());
    world.insert_resource(scene.episode.clone());
    world.insert_resource(scene.physics.clone());
    let mut robots = Vec::new();
    for (map_index, NamedMap { name, map }) in loaded.maps.iter().enumerate() {
        let traversable =
            TraversableMap::build(map, scene.robot.radius_m).map_err(|e| ComposeError::Scene {
                path: loaded.path.clone(),
                field: "maps".into(),
                message: format!("map `{name}`: {e}"),
            })?;
        let mut physics = MapPhysics::from_map(map, scene.physics.dt_s);
        let mut starts: Vec<Pose2> = Vec::new();
        let mut new_robots = Vec::new();
        for robot_index in 0..scene.robots_per_map {
            let key = stream(&[scene.seed, map_index as u64, robot_index as u64]).random::<u64>();
            let mut rngs = RobotRngs::seeded(key);
            let min_gap = 2.0 * scene.robot.radius_m;
            let clear = |p: &Pose2| !scene.robots_collide || starts.iter().all(|s| s.distance(p) > min_gap);
            let start = traversable.sample_pose_where(map, &mut rngs.scenario.0, START_POSE_TRIES, clear);
            starts.push(start);
            let body = physics.add_robot(start, scene.robot.radius_m, scene.robots_collide);
            new_robots.push((start, body, rngs));
        }
        let map_entity = world.spawn((MapName(name.clone()), map_layers(map, traversable), physics)).id();
        for (start, body, rngs) in new_robots {
            let id = RobotId(robots.len() as u32);
            let robot = world
                .spawn((
                    (Robot, id, TruePose(start), PreviousPose(start), OnMap(map_entity), body, rngs),
                    (Action::default(), DriveCommand::default(), Collided::default(), Episode::default()),
                    (LidarScan::default(), LocalGrid::default(), DepthStrip::default(), Odometry::default()),
                    (
                        (ParticleSet::default(), NeedsInit),
                        PoseEstimate::default(),
                        FilterHealth::default(),
                        BeliefCrop::default(),
                    ),
                    (StepError::default(), EpisodeLog::default(), Reward::default()),
                ))
                .id();
            robots.push(robot);
        }
    }
    Ok(robots)
}
