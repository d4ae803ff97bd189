//! The `infogain` policy system: per robot and agent step, score the candidate motions by
//! [`score_candidates`] and drive the cheapest.

use crate::act::PhysicsParams;
use crate::agent::Action;
use crate::agent::infogain::params::InfogainParams;
use crate::agent::infogain::predict::{MapView, Models, best_action, score_candidates};
use crate::particles::{LikelihoodFieldParams, ParticleSet, TransitionParams};
use crate::sense::{LidarParams, RayGrid};
use crate::world::map::{DistanceField, TraversableMap};
use crate::world::{OccupancyMap, OnMap, RobotParams, ScenarioRng};
use bevy::prelude::*;
use rand::Rng;
use rayon::prelude::*;

/// Reads ParticleSet, OnMap → the map's OccupancyMap, RayGrid, DistanceField, TraversableMap,
/// InfogainParams, the pipeline's LidarParams, LikelihoodFieldParams and TransitionParams (their
/// defaults when the schedule runs no such step), RobotParams, PhysicsParams, ScenarioRng (one
/// key per robot and step). Writes Action. Robots are scored in parallel; each one's draws
/// come from its own key, so the thread count never changes an action.
#[allow(clippy::too_many_arguments)]
pub fn infogain_policy(
    params: Res<InfogainParams>,
    lidar: Option<Res<LidarParams>>,
    likelihood: Option<Res<LikelihoodFieldParams>>,
    transition: Option<Res<TransitionParams>>,
    robot: Res<RobotParams>,
    physics: Res<PhysicsParams>,
    maps: Query<(&OccupancyMap, &RayGrid, &DistanceField, &TraversableMap)>,
    mut robots: Query<(Entity, &ParticleSet, &OnMap, &mut ScenarioRng, &mut Action)>,
) {
    let lidar = lidar.map_or_else(LidarParams::default, |p| p.clone());
    let likelihood = likelihood.map_or_else(LikelihoodFieldParams::default, |p| p.clone());
    let transition = transition.map_or_else(TransitionParams::default, |p| p.clone());
    let models = Models {
        lidar: &lidar,
        likelihood: &likelihood,
        transition: &transition,
        robot: &robot,
        physics: &physics,
    };
    let mut work: Vec<_> = robots
        .iter_mut()
        .map(|(e, set, on_map, mut rng, action)| {
            (e, set, maps.get(on_map.0).ok(), rng.0.random::<u64>(), action)
        })
        .collect();
    work.par_iter_mut().for_each(|(e, set, layers, key, action)| {
        let Some((map, grid, field, traversable)) = *layers else {
            tracing::warn!(
                "infogain_policy: robot {e:?}'s map lacks a RayGrid, DistanceField or TraversableMap"
            );
            **action = Action::default();
            return;
        };
        if set.is_empty() {
            **action = Action::default();
            return;
        }
        let view = MapView { map, grid, field, traversable };
        **action = match score_candidates(set, view, models, &params, *key) {
            Ok(scores) => best_action(&scores),
            Err(err) => {
                tracing::warn!("infogain_policy: robot {e:?}: {err}");
                Action::default()
            }
        };
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::act::command_for;
    use crate::agent::infogain::predict::drive_on_map;
    use crate::testing::tiny_room;
    use crate::world::rng::stream;
    use crate::world::{Cell, Pose2, wrap_angle};
    use bevy::ecs::system::RunSystemOnce;
    use rand_distr::{Distribution, Normal};
    use std::f32::consts::PI;

    /// A robot on `map` with a belief of `modes` (each `per_mode` particles, σ 3 cm / 2°), in a
    /// world with the policy's resources; returns the action the policy writes.
    fn decide(map: OccupancyMap, lidar: LidarParams, modes: &[Pose2], per_mode: usize) -> Action {
        decide_with(InfogainParams::default(), map, lidar, modes, per_mode)
    }

    fn decide_with(
        params: InfogainParams,
        map: OccupancyMap,
        lidar: LidarParams,
        modes: &[Pose2],
        per_mode: usize,
    ) -> Action {
        let mut world = World::new();
        world.insert_resource(params);
        world.insert_resource(lidar);
        world.insert_resource(RobotParams::default());
        world.insert_resource(PhysicsParams::default());
        let layers = (
            RayGrid::from_map(&map),
            DistanceField::build(&map),
            TraversableMap::build(&map, RobotParams::default().radius_m).expect("the test map has room"),
        );
        let map_entity = world.spawn((map, layers)).id();
        let mut rng = stream(&[11]);
        let (pos, yaw) = (Normal::new(0.0, 0.03).unwrap(), Normal::new(0.0, 2f32.to_radians()).unwrap());
        let poses: Vec<Pose2> = modes
            .iter()
            .flat_map(|m| vec![*m; per_mode])
            .map(|m| {
                Pose2::new(
                    m.x + pos.sample(&mut rng),
                    m.y + pos.sample(&mut rng),
                    m.yaw + yaw.sample(&mut rng),
                )
            })
            .collect();
        let robot = world
            .spawn((
                ParticleSet::from_poses(&poses),
                OnMap(map_entity),
                ScenarioRng::seeded(4),
                Action::default(),
            ))
            .id();
        world.run_system_once(infogain_policy).expect("infogain_policy runs");
        *world.get::<Action>(robot).expect("robot keeps its Action")
    }

    /// An 8 m × 2 m corridor at 0.1 m/cell, symmetric under a half turn about (4.1, 1.1) but for
    /// one block filling the north half of its east end (x ≥ 6.8 m, y ≥ 1.1 m).
    fn corridor() -> OccupancyMap {
        let (w, h) = (82, 22);
        let mut map = OccupancyMap::filled(w, h, 0.1, Cell::Free);
        for i in 0..w {
            for j in 0..h {
                let wall = i == 0 || j == 0 || i == w - 1 || j == h - 1;
                let block = i >= 68 && j >= 11;
                if wall || block {
                    map.set(i, j, Cell::Occupied);
                }
            }
        }
        map
    }

    #[test]
    fn infogain_policy_drives_toward_the_feature_that_breaks_the_symmetry() {
        // A 2 m LiDAR sees only the side walls from both modes: facing east 2.2 m short of the
        // block, or its mirror image facing west 3.2 m from it. Driving east brings the block
        // into range under the first mode (and the second mode's particles would then see it);
        // turning in place shows neither mode anything new.
        let lidar = LidarParams { range_max_m: 2.0, ..Default::default() };
        let east = Pose2::new(4.6, 1.1, 0.1);
        let west = Pose2::new(8.2 - east.x, 2.2 - east.y, wrap_angle(east.yaw + PI));
        let action = decide(corridor(), lidar, &[east, west], 100);
        assert!(action.linear > 0.0, "a bimodal belief must drive ahead toward the block, got {action:?}");
    }

    #[test]
    fn reach_plans_drive_where_a_feature_beyond_the_primitives_horizon_comes_into_view() {
        // The corridor with a 1.5 m LiDAR, 3.2 m short of the block (the mirror mode 2.2 m from
        // it, facing away): within 2 steps no motion brings the block into range under either
        // mode, so standing still (the one primitive here) is as good as any. A reach plan of 6
        // steps does: driving on under the east mode, or turning round and driving under the west
        // one. The block shows on 3 of 24 beams, which the default tempering (0.2) leaves within
        // the entropy's bin noise; 60 untempered beams let it count.
        let lidar = LidarParams { range_max_m: 1.5, ..Default::default() };
        let east = Pose2::new(3.6, 1.1, 0.1);
        let west = Pose2::new(8.2 - east.x, 2.2 - east.y, wrap_angle(east.yaw + PI));
        let sharp = InfogainParams {
            candidates: vec![(0.0, 0.0)],
            beams: 60,
            likelihood_scale: 1.0,
            ..Default::default()
        };
        let reach = InfogainParams { reach_headings: 8, ..sharp };
        let action = decide_with(reach, corridor(), lidar, &[east, west], 100);
        let (straight_on, turn_round) = (Action::new(1.0, 0.0), Action::new(0.0, 1.0));
        assert!(
            action == straight_on || action == turn_round,
            "a reach plan toward the block under one mode must beat standing still, got {action:?}"
        );
    }

    #[test]
    fn infogain_policy_keeps_a_tight_belief_off_the_walls() {
        // Tight belief 0.3 m from the east wall of the room, facing it: driving ahead would hit it.
        let truth = Pose2::new(1.6, 0.8, 0.0);
        let action = decide(tiny_room(), LidarParams::default(), &[truth], 200);
        let map = tiny_room();
        let traversable = TraversableMap::build(&map, RobotParams::default().radius_m).expect("room");
        let (grid, field) = (RayGrid::from_map(&map), DistanceField::build(&map));
        let view = MapView { map: &map, grid: &grid, field: &field, traversable: &traversable };
        let command = command_for(action, &RobotParams::default());
        let (physics, mut pose) = (PhysicsParams::default(), truth);
        for step in 0..InfogainParams::default().horizon_steps {
            let imagined = drive_on_map(pose, command, &physics, view);
            assert!(!imagined.collided, "step {step}: {action:?} from {truth:?} runs into the wall");
            pose = imagined.pose;
        }
        let ahead =
            drive_on_map(truth, command_for(Action::new(1.0, 0.0), &RobotParams::default()), &physics, view);
        assert!(ahead.collided, "the test must leave a colliding candidate to avoid");
    }
}
