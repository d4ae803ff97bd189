//! One rapier physics world per map: walls as merged rectangles, robots as dynamic discs driven
//! by velocity, stepped in fixed sub-steps of simulated time.

use crate::act::collision::{Collided, is_touching};
use crate::act::drive::DriveCommand;
use crate::world::{Cell, OccupancyMap, OnMap, Pose2, RobotId, TruePose};
use bevy::prelude::*;
use bevy_rapier2d::rapier::prelude::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// Fixed-step integration: `substeps` steps of `dt_s` make one agent step (paper: 0.6 s).
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct PhysicsParams {
    /// Simulated seconds per physics step; 0.1 s never tunnelled a 5 cm wall at 6 m/s (DESIGN §4b).
    pub dt_s: f32,
    /// Physics steps per agent step; 6 × 0.1 s holds each action 0.6 s as in the paper.
    pub substeps: u32,
}

impl Default for PhysicsParams {
    fn default() -> Self {
        Self { dt_s: 0.1, substeps: 6 }
    }
}

impl PhysicsParams {
    /// Simulated seconds one agent step holds its action (paper: 0.6 s).
    pub fn agent_step_s(&self) -> f32 {
        self.dt_s * self.substeps as f32
    }
}

/// Collision groups: walls in group 1, robots in group 2. Robots always meet walls and meet
/// each other only when the scene asks for it.
const WALLS: Group = Group::GROUP_1;
const ROBOTS: Group = Group::GROUP_2;

/// The physics world of one map, a component on the map entity. Worlds never interact, so
/// many maps can share one bevy `World` and step in parallel.
#[derive(Component)]
pub struct MapPhysics(pub PhysicsWorld);

/// A robot's handles in its map's physics world.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct PhysicsBody {
    pub body: RigidBodyHandle,
    pub collider: ColliderHandle,
}

impl MapPhysics {
    /// A top-down world (no gravity) whose static walls cover every non-free cell.
    pub fn from_map(map: &OccupancyMap, dt_s: f32) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::ZERO;
        world.integration_parameters.dt = dt_s;
        let half = map.resolution_m / 2.0;
        for rect in wall_rectangles(map) {
            let (cx, cy) = map.grid_to_world(
                rect.i as f32 + rect.width as f32 / 2.0,
                rect.j as f32 + rect.height as f32 / 2.0,
            );
            let wall = ColliderBuilder::cuboid(rect.width as f32 * half, rect.height as f32 * half)
                .position(Pose::new(Vector::new(cx, cy), map.origin.yaw))
                .friction(0.0)
                .collision_groups(InteractionGroups::new(WALLS, Group::ALL, InteractionTestMode::And));
            world.insert_collider(wall, None);
        }
        Self(world)
    }

    /// Adds a robot disc at `pose`. It slides along walls (zero friction).
    pub fn add_robot(&mut self, pose: Pose2, radius_m: f32, collide_with_robots: bool) -> PhysicsBody {
        let filter = if collide_with_robots { WALLS | ROBOTS } else { WALLS };
        let collider = ColliderBuilder::ball(radius_m)
            .friction(0.0)
            .friction_combine_rule(CoefficientCombineRule::Min)
            .collision_groups(InteractionGroups::new(ROBOTS, filter, InteractionTestMode::And))
            .build();
        self.insert_robot(pose, collider)
    }

    /// Whether this robot's body collides with other robots (`add_robot`'s `collide_with_robots`).
    pub fn collides_with_robots(&self, robot: PhysicsBody) -> bool {
        self.0.colliders.get(robot.collider).is_some_and(|c| c.collision_groups().filter.contains(ROBOTS))
    }

    /// Moves a robot's body out of this world into `to`, at `pose` and at rest (episodes that
    /// change maps); returns its handles there.
    pub fn transfer(&mut self, robot: PhysicsBody, to: &mut MapPhysics, pose: Pose2) -> PhysicsBody {
        let collider = self.0.colliders[robot.collider].clone();
        self.0.remove_body(robot.body);
        to.insert_robot(pose, collider)
    }

    /// A dynamic body carrying `collider`. It never sleeps: a sleeping body ignores new velocities.
    fn insert_robot(&mut self, pose: Pose2, collider: Collider) -> PhysicsBody {
        let body = RigidBodyBuilder::dynamic()
            .pose(Pose::new(Vector::new(pose.x, pose.y), pose.yaw))
            .gravity_scale(0.0)
            .can_sleep(false)
            .build();
        let body = self.0.insert_body(body);
        let collider = self.0.insert_collider(collider, Some(body));
        PhysicsBody { body, collider }
    }

    /// Moves a robot to `pose` at rest (episode resets).
    pub fn teleport(&mut self, robot: PhysicsBody, pose: Pose2) {
        let body = &mut self.0.bodies[robot.body];
        body.set_position(Pose::new(Vector::new(pose.x, pose.y), pose.yaw), true);
        body.set_linvel(Vector::ZERO, true);
        body.set_angvel(0.0, true);
    }

    pub fn pose(&self, robot: PhysicsBody) -> Pose2 {
        let body = &self.0.bodies[robot.body];
        let t = body.translation();
        Pose2::new(t.x, t.y, body.rotation().angle())
    }

    /// Holds each robot's command for `substeps` steps, re-aiming the linear velocity along the
    /// current heading before every step (a differential drive moves where it faces).
    /// Returns, per robot, its final pose and whether it touched anything.
    pub fn step_robots(
        &mut self,
        robots: &[(PhysicsBody, DriveCommand)],
        substeps: u32,
    ) -> Vec<(Pose2, bool)> {
        let mut touched = vec![false; robots.len()];
        for _ in 0..substeps {
            for (robot, command) in robots {
                let body = &mut self.0.bodies[robot.body];
                let heading = body.rotation().angle();
                let (s, c) = heading.sin_cos();
                body.set_linvel(Vector::new(c, s) * command.linear_mps, true);
                body.set_angvel(command.angular_radps, true);
            }
            self.0.step();
            for (flag, (robot, _)) in touched.iter_mut().zip(robots) {
                *flag |= is_touching(&self.0, robot.collider);
            }
        }
        robots.iter().zip(touched).map(|((robot, _), hit)| (self.pose(*robot), hit)).collect()
    }
}

/// An axis-aligned block of non-free cells, in cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellRect {
    pub i: usize,
    pub j: usize,
    pub width: usize,
    pub height: usize,
}

/// Covers every non-free cell with few rectangles: greedy row runs grown upwards.
/// One cuboid per cell made physics 3× slower on a real map (DESIGN §4b).
pub fn wall_rectangles(map: &OccupancyMap) -> Vec<CellRect> {
    let blocked = |i: usize, j: usize| map.get(i, j) != Cell::Free;
    let mut used = vec![false; map.width * map.height];
    let mut rects = Vec::new();
    for j in 0..map.height {
        let mut i = 0;
        while i < map.width {
            if !blocked(i, j) || used[map.index(i, j)] {
                i += 1;
                continue;
            }
            let width = (i..map.width).take_while(|&x| blocked(x, j) && !used[map.index(x, j)]).count();
            let row_fits = |y: usize| (i..i + width).all(|x| blocked(x, y) && !used[map.index(x, y)]);
            let height = 1 + (j + 1..map.height).take_while(|&y| row_fits(y)).count();
            for y in j..j + height {
                for x in i..i + width {
                    used[map.index(x, y)] = true;
                }
            }
            rects.push(CellRect { i, j, width, height });
            i += width;
        }
    }
    rects
}

/// Reads DriveCommand, PhysicsParams, OnMap, RobotId. Writes MapPhysics, TruePose, Collided.
/// Maps step in parallel; each map's robots step together in RobotId order (deterministic,
/// whatever components a schedule adds).
pub fn physics(
    params: Res<PhysicsParams>,
    mut maps: Query<(Entity, &mut MapPhysics)>,
    mut robots: Query<(&RobotId, &OnMap, &PhysicsBody, &DriveCommand, &mut TruePose, &mut Collided)>,
) {
    let mut by_map: HashMap<Entity, Vec<_>> = HashMap::new();
    for (id, on_map, body, command, pose, collided) in &mut robots {
        by_map.entry(on_map.0).or_default().push((*id, (*body, *command), pose, collided));
    }
    by_map.values_mut().for_each(|robots| robots.sort_unstable_by_key(|(id, ..)| *id));
    let mut work: Vec<_> =
        maps.iter_mut().filter_map(|(entity, physics)| Some((physics, by_map.remove(&entity)?))).collect();
    work.par_iter_mut().for_each(|(physics, robots)| {
        let commands: Vec<_> = robots.iter().map(|(_, command, _, _)| *command).collect();
        let results = physics.step_robots(&commands, params.substeps);
        for ((_, _, pose, collided), (new_pose, hit)) in robots.iter_mut().zip(results) {
            pose.0 = new_pose;
            collided.0 = hit;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use bevy::ecs::system::RunSystemOnce;

    fn world_with_robot(pose: Pose2, command: DriveCommand) -> (World, Entity) {
        let map = tiny_room();
        let mut world = World::new();
        world.insert_resource(PhysicsParams::default());
        let mut physics = MapPhysics::from_map(&map, 0.1);
        let body = physics.add_robot(pose, 0.18, false);
        let map_entity = world.spawn((map, physics)).id();
        let robot = world
            .spawn((RobotId(0), OnMap(map_entity), body, command, TruePose(pose), Collided::default()))
            .id();
        (world, robot)
    }

    #[test]
    fn wall_rectangles_cover_exactly_the_blocked_cells() {
        let map = tiny_room();
        let rects = wall_rectangles(&map);
        let mut covered = vec![0u8; map.width * map.height];
        for r in &rects {
            for y in r.j..r.j + r.height {
                for x in r.i..r.i + r.width {
                    covered[map.index(x, y)] += 1;
                }
            }
        }
        for (k, cell) in map.cells.iter().enumerate() {
            assert_eq!(covered[k], u8::from(*cell != Cell::Free), "cell {k} covered {} times", covered[k]);
        }
        assert!(rects.len() <= 6, "a room with a pillar needs few rectangles, got {}", rects.len());
    }

    #[test]
    fn physics_drives_forward_in_free_space() {
        let command = DriveCommand { linear_mps: 0.5, angular_radps: 0.0 };
        let (mut world, robot) = world_with_robot(Pose2::new(0.5, 0.3, 0.0), command);
        world.run_system_once(physics).unwrap();
        let pose = world.get::<TruePose>(robot).unwrap().0;
        assert!((pose.x - 0.8).abs() < 0.02, "0.5 m/s for 0.6 s moves 0.3 m, ended at x = {}", pose.x);
        assert!(!world.get::<Collided>(robot).unwrap().0, "no wall within reach");
    }

    #[test]
    fn physics_flags_collision_when_driving_into_a_wall() {
        // Facing the east wall (inner face at x = 1.9 m) from 0.3 m away.
        let command = DriveCommand { linear_mps: 0.5, angular_radps: 0.0 };
        let (mut world, robot) = world_with_robot(Pose2::new(1.6, 0.3, 0.0), command);
        world.run_system_once(physics).unwrap();
        world.run_system_once(physics).unwrap();
        let pose = world.get::<TruePose>(robot).unwrap().0;
        assert!(world.get::<Collided>(robot).unwrap().0, "driving into the wall must set the flag");
        assert!(pose.x <= 1.9 - 0.18 + 0.03, "the wall stops the disc, centre at x = {}", pose.x);
    }

    #[test]
    fn physics_does_not_flag_a_near_miss() {
        // Driving parallel to the south wall, 0.05 m clear of it.
        let command = DriveCommand { linear_mps: 0.5, angular_radps: 0.0 };
        let (mut world, robot) = world_with_robot(Pose2::new(0.4, 0.1 + 0.18 + 0.05, 0.0), command);
        world.run_system_once(physics).unwrap();
        assert!(!world.get::<Collided>(robot).unwrap().0, "a pass 5 cm from the wall is no collision");
    }

    #[test]
    fn physics_transfer_moves_a_robot_between_worlds() {
        let map = tiny_room();
        let (mut a, mut b) = (MapPhysics::from_map(&map, 0.1), MapPhysics::from_map(&map, 0.1));
        let robot = a.add_robot(Pose2::new(0.5, 0.5, 0.0), 0.18, false);
        let walls = a.0.colliders.len() - 1;
        let target = Pose2::new(1.0, 0.8, 1.0);
        let moved = a.transfer(robot, &mut b, target);
        assert_eq!(a.0.colliders.len(), walls, "only the walls stay in world a");
        assert_eq!(b.0.bodies.len(), 1, "the body arrived in world b");
        assert!(b.pose(moved).distance(&target) < 1e-5, "at the requested pose");
        let command = DriveCommand { linear_mps: 0.5, angular_radps: 0.0 };
        let [(pose, _)] = b.step_robots(&[(moved, command)], 6)[..] else { panic!("one robot") };
        assert!(pose.distance(&target) > 0.2, "the moved robot drives in its new world");
    }

    #[test]
    fn physics_turns_in_place() {
        let command = DriveCommand { linear_mps: 0.0, angular_radps: 1.0 };
        let (mut world, robot) = world_with_robot(Pose2::new(0.5, 0.5, 0.0), command);
        world.run_system_once(physics).unwrap();
        let pose = world.get::<TruePose>(robot).unwrap().0;
        assert!((pose.yaw - 0.6).abs() < 0.01, "1 rad/s for 0.6 s, got yaw {}", pose.yaw);
        assert!(pose.distance(&Pose2::new(0.5, 0.5, 0.0)) < 0.01, "turning in place must not translate");
    }
}
