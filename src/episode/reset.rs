//! Fixed-length episodes: when one ends, the robot restarts at a new random traversable pose.

use crate::act::{Collided, MapPhysics, PhysicsBody};
use crate::agent::Action;
use crate::particles::{NeedsInit, ParticleSet};
use crate::world::map::{START_POSE_TRIES, TraversableMap};
use crate::world::{
    OccupancyMap, OnMap, Pose2, PreviousPose, RobotId, RobotParams, ScenarioRng, TruePose, in_id_order,
};
use bevy::prelude::*;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Episode length (paper: T = 50 agent steps for RL and evaluation).
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct EpisodeParams {
    /// Agent steps per episode.
    pub steps: u32,
    /// In scenes with several maps, start each new episode on a map drawn at random (the
    /// reference samples a new apartment per episode); otherwise robots keep their map.
    pub change_maps: bool,
}

impl Default for EpisodeParams {
    fn default() -> Self {
        Self { steps: 50, change_maps: true }
    }
}

/// Where a robot is in its episodes. `step` counts the agent steps of the current episode,
/// including the one running now (1 during the first step).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Episode {
    pub index: u32,
    pub step: u32,
}

/// Marks a robot whose episode has just (re)started; filter initialisation and metrics key on it.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EpisodeStart;

/// Marks a robot in the last step of its episode: the step's filter update is the episode's
/// last, and whatever it does next is never rewarded (the next step restarts elsewhere).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EpisodeEnd;

/// Reads EpisodeParams, RobotParams, the map's OccupancyMap and TraversableMap, the other robots'
/// TruePose. Writes Episode, TruePose, PreviousPose, MapPhysics, ScenarioRng, EpisodeStart,
/// EpisodeEnd; empties the ParticleSet and marks it `NeedsInit`, so that `init_particles` draws a
/// fresh one for the new episode; clears Action and Collided, so nothing of the last episode
/// leaks into the new one. Robots that collide with each other restart at least two radii apart,
/// as they spawn; robots are visited in `RobotId` order, so who restarts where never depends on
/// which components a schedule adds.
pub fn episode_reset(
    params: Res<EpisodeParams>,
    body_size: Res<RobotParams>,
    mut commands: Commands,
    mut maps: Query<(Entity, &OccupancyMap, &TraversableMap, &mut MapPhysics)>,
    mut robots: Query<(
        (Entity, &RobotId),
        &mut OnMap,
        &mut PhysicsBody,
        &mut Episode,
        (&mut TruePose, &mut PreviousPose),
        &mut ScenarioRng,
        Option<&mut ParticleSet>,
        (Option<&mut Action>, Option<&mut Collided>),
    )>,
) {
    let map_entities: Vec<Entity> = maps.iter().map(|(entity, ..)| entity).collect();
    // Where every robot is (updated as robots restart), to keep colliding robots apart.
    let mut positions: Vec<(Entity, Entity, Pose2)> =
        robots.iter().map(|((robot, _), on_map, _, _, (pose, _), ..)| (robot, on_map.0, pose.0)).collect();
    let min_gap = 2.0 * body_size.radius_m;
    for robot in in_id_order(robots.iter().map(|((robot, id), ..)| (robot, id))) {
        let Ok((
            _,
            mut on_map,
            mut body,
            mut episode,
            (mut pose, mut previous),
            mut rng,
            particles,
            (action, collided),
        )) = robots.get_mut(robot)
        else {
            continue;
        };
        commands.entity(robot).remove::<(EpisodeStart, EpisodeEnd)>();
        if episode.step >= params.steps {
            let next_map = match map_entities.len() {
                n if params.change_maps && n > 1 => map_entities[rng.0.random_range(0..n)],
                _ => on_map.0,
            };
            let clear_of_others = |collides: bool| {
                let others = &positions;
                move |p: &Pose2| {
                    !collides
                        || others
                            .iter()
                            .all(|&(r, m, q)| r == robot || m != next_map || q.distance(p) > min_gap)
                }
            };
            let start = if next_map == on_map.0 {
                let Ok((_, map, traversable, mut physics)) = maps.get_mut(on_map.0) else { continue };
                let clear = clear_of_others(physics.collides_with_robots(*body));
                let start = traversable.sample_pose_where(map, &mut rng.0, START_POSE_TRIES, clear);
                physics.teleport(*body, start);
                start
            } else {
                let Ok([(.., mut from), (_, map, traversable, mut to)]) =
                    maps.get_many_mut([on_map.0, next_map])
                else {
                    continue;
                };
                let clear = clear_of_others(from.collides_with_robots(*body));
                let start = traversable.sample_pose_where(map, &mut rng.0, START_POSE_TRIES, clear);
                *body = from.transfer(*body, &mut to, start);
                on_map.0 = next_map;
                start
            };
            (pose.0, previous.0) = (start, start);
            if let Some(entry) = positions.iter_mut().find(|(r, ..)| *r == robot) {
                (entry.1, entry.2) = (next_map, start);
            }
            *episode = Episode { index: episode.index + 1, step: 0 };
            if let Some(mut particles) = particles {
                *particles = ParticleSet::default();
                commands.entity(robot).insert(NeedsInit);
            }
            if let Some(mut action) = action {
                *action = Action::default();
            }
            if let Some(mut collided) = collided {
                *collided = Collided(false);
            }
        }
        if episode.step == 0 {
            commands.entity(robot).insert(EpisodeStart);
        }
        episode.step += 1;
        if episode.step == params.steps {
            commands.entity(robot).insert(EpisodeEnd);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use crate::world::Pose2;
    use bevy::ecs::system::RunSystemOnce;

    #[test]
    fn episode_reset_restarts_after_the_last_step() {
        let map = tiny_room();
        let traversable = TraversableMap::build(&map, 0.18).unwrap();
        let mut physics = MapPhysics::from_map(&map, 0.1);
        let start = Pose2::new(0.5, 0.5, 0.0);
        let body = physics.add_robot(start, 0.18, false);
        let mut world = World::new();
        world.insert_resource(EpisodeParams { steps: 2, change_maps: true });
        world.insert_resource(RobotParams::default());
        let map_entity = world.spawn((map, traversable, physics)).id();
        let robot = world
            .spawn((
                OnMap(map_entity),
                body,
                Episode::default(),
                TruePose(start),
                PreviousPose(start),
                (RobotId(0), ScenarioRng::seeded(1)),
                ParticleSet::from_poses(&[start]),
                (Action::new(0.5, 0.5), Collided(false)),
            ))
            .id();
        world.run_system_once(episode_reset).unwrap();
        assert!(world.get::<EpisodeStart>(robot).is_some(), "first step starts an episode");
        assert!(world.get::<EpisodeEnd>(robot).is_none(), "and is not its last");
        assert_eq!(*world.get::<Episode>(robot).unwrap(), Episode { index: 0, step: 1 });
        world.run_system_once(episode_reset).unwrap();
        assert!(world.get::<EpisodeStart>(robot).is_none(), "step 2 continues the episode");
        assert!(world.get::<EpisodeEnd>(robot).is_some(), "step 2 of 2 is the last");
        // The last step's action bumps into something: the new episode must not inherit it.
        world.entity_mut(robot).insert(Collided(true));
        world.run_system_once(episode_reset).unwrap();
        assert!(world.get::<EpisodeEnd>(robot).is_none());
        assert_eq!(
            world.get::<Collided>(robot),
            Some(&Collided(false)),
            "a new episode starts without a bump"
        );
        assert_eq!(world.get::<Action>(robot), Some(&Action::default()), "and standing still");
        assert_eq!(
            *world.get::<Episode>(robot).unwrap(),
            Episode { index: 1, step: 1 },
            "after 2 steps a new one"
        );
        assert!(world.get::<EpisodeStart>(robot).is_some());
        assert!(world.get::<ParticleSet>(robot).unwrap().is_empty(), "the filter restarts with the episode");
        assert!(world.get::<NeedsInit>(robot).is_some(), "and is marked for init_particles");
        let pose = world.get::<TruePose>(robot).unwrap().0;
        assert_ne!(pose, start, "a new random start pose");
        assert_eq!(world.get::<PreviousPose>(robot).unwrap().0, pose, "odometry must not see the teleport");
    }

    /// A component some schedule step might add to some robots, moving them to another archetype.
    #[derive(Component)]
    struct Extra;

    /// Four colliding robots in the tiny room with one-step episodes; `extra` robots carry [`Extra`].
    fn four_colliding_robots(extra: &[usize]) -> (World, Vec<Entity>) {
        let map = tiny_room();
        let (traversable, mut physics) =
            (TraversableMap::build(&map, 0.18).unwrap(), MapPhysics::from_map(&map, 0.1));
        let mut world = World::new();
        world.insert_resource(EpisodeParams { steps: 1, change_maps: true });
        world.insert_resource(RobotParams::default());
        let starts = [
            Pose2::new(0.4, 0.4, 0.0),
            Pose2::new(1.5, 0.4, 0.0),
            Pose2::new(0.4, 1.1, 0.0),
            Pose2::new(1.5, 1.1, 0.0),
        ];
        let bodies: Vec<PhysicsBody> = starts.iter().map(|&p| physics.add_robot(p, 0.18, true)).collect();
        assert!(physics.collides_with_robots(bodies[0]));
        let map_entity = world.spawn((map, traversable, physics)).id();
        let robots: Vec<Entity> = (0..4)
            .map(|k| {
                let pose = (TruePose(starts[k]), PreviousPose(starts[k]));
                let id = (RobotId(k as u32), ScenarioRng::seeded(k as u64));
                let mut robot = world.spawn((OnMap(map_entity), bodies[k], Episode::default(), pose, id));
                if extra.contains(&k) {
                    robot.insert(Extra);
                }
                robot.id()
            })
            .collect();
        (world, robots)
    }

    fn poses(world: &World, robots: &[Entity]) -> Vec<Pose2> {
        robots.iter().map(|&r| world.get::<TruePose>(r).unwrap().0).collect()
    }

    #[test]
    fn episode_reset_keeps_colliding_robots_apart() {
        let (mut world, robots) = four_colliding_robots(&[]);
        for _ in 0..30 {
            world.run_system_once(episode_reset).unwrap();
            let poses = poses(&world, &robots);
            for a in 0..4 {
                for b in a + 1..4 {
                    assert!(
                        poses[a].distance(&poses[b]) > 0.36,
                        "robots {a} and {b} restart overlapping: {poses:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn episode_reset_places_robots_independently_of_their_components() {
        let (mut plain, robots) = four_colliding_robots(&[]);
        let (mut tagged, same_robots) = four_colliding_robots(&[0, 2]);
        for step in 0..30 {
            plain.run_system_once(episode_reset).unwrap();
            tagged.run_system_once(episode_reset).unwrap();
            assert_eq!(
                poses(&plain, &robots),
                poses(&tagged, &same_robots),
                "restart {step}: an extra component on robots 0 and 2 must not move anyone"
            );
        }
    }

    #[test]
    fn episode_reset_moves_robots_between_maps() {
        let map = tiny_room();
        let mut world = World::new();
        world.insert_resource(EpisodeParams { steps: 1, change_maps: true });
        world.insert_resource(RobotParams::default());
        let mut maps = Vec::new();
        for _ in 0..2 {
            let traversable = TraversableMap::build(&map, 0.18).unwrap();
            maps.push(world.spawn((map.clone(), traversable, MapPhysics::from_map(&map, 0.1))).id());
        }
        let start = Pose2::new(0.5, 0.5, 0.0);
        let body = world.get_mut::<MapPhysics>(maps[0]).unwrap().add_robot(start, 0.18, false);
        let robot = world
            .spawn((
                OnMap(maps[0]),
                body,
                Episode::default(),
                TruePose(start),
                PreviousPose(start),
                (RobotId(0), ScenarioRng::seeded(3)),
            ))
            .id();
        let mut visited = std::collections::HashSet::new();
        for _ in 0..20 {
            world.run_system_once(episode_reset).unwrap();
            let on_map = world.get::<OnMap>(robot).unwrap().0;
            visited.insert(on_map);
            let body = *world.get::<PhysicsBody>(robot).unwrap();
            let pose = world.get::<TruePose>(robot).unwrap().0;
            let physics = world.get::<MapPhysics>(on_map).unwrap();
            assert!(physics.pose(body).distance(&pose) < 1e-4, "the body lives in the robot's current map");
        }
        assert_eq!(visited.len(), 2, "20 one-step episodes must visit both maps");
        let bodies: usize = maps.iter().map(|&m| world.get::<MapPhysics>(m).unwrap().0.bodies.len()).sum();
        assert_eq!(bodies, 1, "the robot has exactly one body across all worlds");
    }
}
