//! Common random numbers: schedules that differ only in the filter see the same world. Each robot
//! draws its scenario (policy, start poses), its sensor noise and its filter's samples from three
//! separate streams, and systems whose outcome depends on the order of robots visit them by
//! `RobotId`, so neither a filter step nor an extra component changes what happens to the robots.

use apfn::compose::{Pipeline, Scene, standard_registry};
use apfn::episode::{CompletedEpisodes, EpisodeRecord};
use apfn::particles::PoseEstimate;
use apfn::plugin::headless_app;
use apfn::sense::{LidarScan, Odometry};
use apfn::world::map::procedural::Split;
use apfn::world::{Pose2, TruePose};
use bevy::prelude::*;
use std::path::Path;

/// A schedule with noisy odometry and LiDAR (so both sensor streams draw) around `filter`.
fn schedule(filter: &str) -> Pipeline {
    let text = format!(
        r#"Schedule(steps: [
        ("episode_reset", ()),
        ("odometry", (trans_noise_m: 0.01, rot_noise_deg: 5.0)), ("lidar", (range_noise_std_m: 0.02)),
        ("init_particles", (task: tracking)), ("transition", (trans_noise_m: 0.01, rot_noise_deg: 5.0)),
        {filter}
        ("estimate", ()), ("step_metrics", ()),
        ("random_policy", ()), ("drive", ()), ("physics", ()),
    ])"#
    );
    Pipeline::parse(&text, Path::new("inline.ron"), &standard_registry()).unwrap_or_else(|e| panic!("{e}"))
}

const WITH_RESAMPLING: &str = r#"("mcl_likelihood_field", ()), ("resample", (alpha: 0.5)),"#;

/// What one robot is and reads at one step, and what its filter makes of it.
#[derive(Debug, PartialEq)]
struct Frame {
    truth: Pose2,
    odometry: Pose2,
    scan: Vec<f32>,
    estimate: Pose2,
}

/// Two maps × two robots, 5-step episodes (so episodes restart), `steps` agent steps; per step,
/// every robot's frame in spawn order, plus the finished episodes. `tagged` robots carry an extra
/// component from the start, as a schedule step that tags some robots would leave them.
fn run(pipeline: Pipeline, steps: usize, tagged: &[usize]) -> (Vec<Vec<Frame>>, Vec<EpisodeRecord>) {
    #[derive(Component)]
    struct Tagged;
    let mut scene = Scene::apartments(Split::Seen, 0, 2, 2);
    (scene.seed, scene.episode.steps) = (5, 5);
    let loaded = scene.into_loaded(Path::new("tests/common_random_numbers")).unwrap();
    let (mut app, robots) = headless_app(&loaded, pipeline).unwrap();
    for &k in tagged {
        app.world_mut().entity_mut(robots[k]).insert(Tagged);
    }
    let mut frames = Vec::new();
    for _ in 0..steps {
        app.update();
        let world = app.world();
        frames.push(
            (robots.iter())
                .map(|&r| Frame {
                    truth: world.get::<TruePose>(r).unwrap().0,
                    odometry: world.get::<Odometry>(r).unwrap().delta,
                    scan: world.get::<LidarScan>(r).unwrap().ranges_m.clone(),
                    estimate: world.get::<PoseEstimate>(r).unwrap().pose,
                })
                .collect(),
        );
    }
    let records = std::mem::take(&mut app.world_mut().resource_mut::<CompletedEpisodes>().0);
    (frames, records)
}

/// Asserts identical truth, odometry and scans at every step; returns the largest distance
/// between the two runs' estimates.
fn same_world_max_estimate_gap(a: &[Vec<Frame>], b: &[Vec<Frame>], what: &str) -> f32 {
    let mut gap = 0.0f32;
    for (step, (a, b)) in a.iter().zip(b).enumerate() {
        for (robot, (a, b)) in a.iter().zip(b).enumerate() {
            assert_eq!(a.truth, b.truth, "{what}: step {step}, robot {robot}: true pose differs");
            assert_eq!(a.odometry, b.odometry, "{what}: step {step}, robot {robot}: odometry differs");
            assert_eq!(a.scan, b.scan, "{what}: step {step}, robot {robot}: scan differs");
            gap = gap.max(a.estimate.distance(&b.estimate));
        }
    }
    gap
}

#[test]
fn filter_only_changes_leave_trajectories_and_readings_identical() {
    let steps = 12;
    let (with, _) = run(schedule(WITH_RESAMPLING), steps, &[]);
    let (without, _) = run(schedule(r#"("mcl_likelihood_field", ()),"#), steps, &[]);
    let (beam, _) = run(schedule(r#"("mcl_beam_model", ()), ("resample", (alpha: 0.5)),"#), steps, &[]);
    let moved = with[steps - 1].iter().zip(&with[0]).any(|(last, first)| last.truth != first.truth);
    assert!(moved, "the robots must drive for the comparison to mean anything");
    let gap = same_world_max_estimate_gap(&with, &without, "without resampling");
    println!("largest estimate gap: without resampling {gap:.3} m");
    assert!(gap > 0.01, "removing resampling must change the estimates ({gap} m)");
    let gap = same_world_max_estimate_gap(&with, &beam, "beam model");
    println!("largest estimate gap: beam model {gap:.3} m");
    assert!(gap > 0.01, "another observation model must change the estimates ({gap} m)");
}

#[test]
fn extra_components_change_neither_the_world_nor_the_episode_records() {
    let steps = 15; // three whole episodes per robot
    let (plain, plain_records) = run(schedule(WITH_RESAMPLING), steps, &[]);
    let (tagged, tagged_records) = run(schedule(WITH_RESAMPLING), steps, &[0, 3]);
    assert_eq!(same_world_max_estimate_gap(&plain, &tagged, "tagged robots"), 0.0, "the filter too");
    assert_eq!(plain_records.len(), 12, "3 episodes × 4 robots");
    let summary = |records: &[EpisodeRecord]| -> Vec<_> {
        records.iter().map(|r| (r.robot, r.episode, r.log.truth.clone(), r.log.estimates.clone())).collect()
    };
    assert_eq!(summary(&plain_records), summary(&tagged_records), "records in the same order, same values");
    assert_eq!(plain_records, tagged_records, "down to the logged particles");
}
