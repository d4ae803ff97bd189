//! Every baseline schedule (`systems/{turn,avoid,goalnav,random,mcl_passive,infogain}.ron`) runs through
//! the users' entry points (`Scene::into_loaded`, `Pipeline::load`, `headless_app`) for 40 agent
//! steps on one procedural apartment with two robots, and the robots move as the policy says.

use apfn::act::Collided;
use apfn::compose::{Pipeline, Scene, standard_registry};
use apfn::particles::PoseEstimate;
use apfn::plugin::headless_app;
use apfn::world::map::procedural::Split;
use apfn::world::{Pose2, TruePose, angle_error};
use bevy::prelude::*;
use std::path::{Path, PathBuf};

const STEPS: usize = 40;

fn schedule(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("systems").join(format!("{name}.ron"))
}

/// Per robot: the pose after each step and how many steps collided (estimates are checked as it runs).
struct Run {
    poses: Vec<Vec<Pose2>>,
    collisions: Vec<usize>,
}

fn run(name: &str) -> Run {
    let scene = Scene::apartments(Split::Seen, 0, 1, 2);
    let loaded = scene.into_loaded(Path::new("scenes/test.ron")).expect("the in-code scene is valid");
    let pipeline = Pipeline::load(&schedule(name), &standard_registry())
        .unwrap_or_else(|e| panic!("systems/{name}.ron must load: {e}"));
    let (mut app, robots) = headless_app(&loaded, pipeline).expect("the scene spawns");
    assert_eq!(robots.len(), 2, "{name}: two robots on one map");
    let mut out = Run { poses: vec![Vec::new(); robots.len()], collisions: vec![0; robots.len()] };
    for step in 0..STEPS {
        app.update();
        for (k, &robot) in robots.iter().enumerate() {
            let world = app.world();
            out.poses[k].push(world.get::<TruePose>(robot).expect("robots keep a TruePose").0);
            out.collisions[k] += usize::from(world.get::<Collided>(robot).expect("Collided").0);
            let estimate = world.get::<PoseEstimate>(robot).expect("robots keep a PoseEstimate");
            assert!(
                estimate.pose.is_finite() && estimate.cov.iter().flatten().all(|v| v.is_finite()),
                "{name}: robot {k} step {step}: non-finite estimate {estimate:?}"
            );
        }
    }
    out
}

/// Largest distance of any visited position from the first one, metres.
fn spread(poses: &[Pose2]) -> f32 {
    poses.iter().map(|p| p.distance(&poses[0])).fold(0.0, f32::max)
}

fn assert_explores(name: &str) {
    let run = run(name);
    for (k, poses) in run.poses.iter().enumerate() {
        assert!(spread(poses) > 0.3, "{name}: robot {k} moved only {:.2} m in {STEPS} steps", spread(poses));
        let limit = STEPS / 4;
        assert!(
            run.collisions[k] <= limit,
            "{name}: robot {k} collided on {} of {STEPS} steps (limit {limit})",
            run.collisions[k]
        );
    }
}

#[test]
fn turn_spins_in_place() {
    let run = run("turn");
    for (k, poses) in run.poses.iter().enumerate() {
        assert!(spread(poses) <= 0.1, "turn: robot {k} drifted {:.3} m while spinning", spread(poses));
        let turned = poses.windows(2).any(|w| angle_error(w[1].yaw, w[0].yaw) > 0.5);
        assert!(turned, "turn: robot {k}'s yaw never changed by more than 0.5 rad in a step");
    }
}

#[test]
fn avoid_drives_without_hugging_walls() {
    assert_explores("avoid");
}

#[test]
fn goalnav_drives_to_its_goals() {
    assert_explores("goalnav");
}

#[test]
fn mcl_passive_drives_like_goalnav() {
    assert_explores("mcl_passive");
}

#[test]
fn infogain_keeps_off_the_walls() {
    // From a tracking start the belief is tight: the policy may turn or drive, but its collision
    // cost keeps it off the walls.
    let run = run("infogain");
    for (k, collisions) in run.collisions.iter().enumerate() {
        assert!(*collisions <= STEPS / 10, "infogain: robot {k} collided on {collisions} of {STEPS} steps");
    }
}

#[test]
fn random_runs_with_finite_estimates() {
    let run = run("random");
    assert_eq!(run.poses.iter().map(Vec::len).collect::<Vec<_>>(), vec![STEPS; 2], "every step recorded");
}

#[test]
fn baseline_schedules_say_what_they_test() {
    for name in ["turn", "avoid", "goalnav", "random", "mcl_passive", "infogain"] {
        let text = std::fs::read_to_string(schedule(name)).expect("schedule file exists");
        let first = text.lines().next().unwrap_or_default();
        assert!(
            first.starts_with("// ") && first.len() > 10,
            "systems/{name}.ron must open with a `//` comment saying what it tests, got {first:?}"
        );
    }
}
