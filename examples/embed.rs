//! A user's own bevy app with apfn inside: `MinimalPlugins` + `ApfnPlugin`, one robot in a
//! procedural apartment, and a hand-written policy — registered next to apfn's own systems —
//! that spins in place while the filter is unsure and explores once it is confident. Prints the
//! localization error every step.
//!
//! `cargo run --release --example embed`

use apfn::agent::Action;
use apfn::compose::{Pipeline, Registry, Scene, SystemSpec, spawn_scene, standard_registry};
use apfn::episode::StepError;
use apfn::params::{NoParams, StepData};
use apfn::particles::PoseEstimate;
use apfn::plugin::{ApfnPlugin, ApfnSet};
use apfn::sense::LidarScan;
use apfn::world::map::procedural::Split;
use bevy::prelude::*;
use std::path::Path;

/// The filter's semi-global start, then our policy instead of a baseline.
const SCHEDULE: &str = r#"// embed: MCL from a semi-global start while the user's own policy drives.
Schedule(steps: [
    ("episode_reset", ()), ("odometry", ()), ("lidar", ()),
    ("init_particles", (task: semi_global)), ("transition", ()), ("mcl_likelihood_field", ()),
    ("resample", ()), ("estimate", ()), ("step_metrics", ()),
    ("confident_explorer", ()),
    ("drive", ()), ("physics", ()),
])"#;

/// Position spread (m) below which the filter counts as confident.
const CONFIDENT_STD_M: f32 = 0.15;

/// Reads PoseEstimate, LidarScan. Writes Action: spin to gather evidence while the estimate's
/// position spread is large; otherwise drive on, turning away from walls ahead.
fn confident_explorer(mut robots: Query<(&PoseEstimate, &LidarScan, &mut Action)>) {
    for (estimate, scan, mut action) in &mut robots {
        let spread = (estimate.cov[0][0] + estimate.cov[1][1]).max(0.0).sqrt();
        let middle = scan.ranges_m.len() / 2;
        let ahead = scan.ranges_m[middle.saturating_sub(10)..(middle + 10).min(scan.ranges_m.len())]
            .iter()
            .copied()
            .fold(f32::INFINITY, f32::min);
        *action = match (spread > CONFIDENT_STD_M, ahead < 0.6) {
            (true, _) => Action::new(0.0, 1.0),
            (false, true) => Action::new(0.0, 0.8),
            (false, false) => Action::new(0.8, 0.0),
        };
    }
}

/// apfn's registry plus our policy, so the schedule above validates like any other.
fn registry() -> Registry {
    let mut registry = standard_registry();
    registry.register::<NoParams, _, _>(
        SystemSpec {
            name: "confident_explorer",
            stage: ApfnSet::Agent,
            summary: "Reads PoseEstimate, LidarScan. Writes Action.",
            needs: vec![StepData::of::<PoseEstimate>(), StepData::of::<LidarScan>()],
            produces: vec![StepData::of::<Action>()],
        },
        confident_explorer,
    );
    registry
}

/// Per-step localization errors of the robot, oldest first.
#[derive(Resource, Default)]
struct ErrorLog(Vec<f32>);

/// Reads StepError. Writes ErrorLog and prints the error.
fn report_error(robots: Query<&StepError>, mut log: ResMut<ErrorLog>) {
    for error in &robots {
        println!(
            "step {:2}: position error {:5.2} m, heading error {:4.2} rad",
            log.0.len(),
            error.pos_err_m,
            error.orient_err_rad
        );
        log.0.push(error.pos_err_m);
    }
}

/// Builds the app, runs `steps` agent steps and returns the position error of each step.
pub fn run(steps: usize) -> Vec<f32> {
    let pipeline =
        Pipeline::parse(SCHEDULE, Path::new("examples/embed.rs"), &registry()).expect("valid schedule");
    let mut scene = Scene::apartments(Split::Unseen, 0, 1, 1);
    scene.seed = 4;
    scene.episode.steps = steps as u32 + 1; // one episode for the whole run
    let scene = scene.into_loaded(Path::new("examples/embed.rs")).expect("procedural scenes always load");

    let mut app = App::new();
    app.add_plugins((MinimalPlugins, ApfnPlugin { pipeline }))
        .init_resource::<ErrorLog>()
        .add_systems(Update, report_error.after(ApfnSet::Evaluate).before(ApfnSet::Agent));
    spawn_scene(app.world_mut(), &scene).expect("a procedural apartment has traversable space");
    for _ in 0..steps {
        app.update();
    }
    app.world_mut().remove_resource::<ErrorLog>().unwrap_or_default().0
}

#[cfg_attr(test, allow(dead_code))]
fn main() {
    let errors = run(40);
    println!("final position error: {:.2} m", errors.last().copied().unwrap_or(f32::NAN));
}
