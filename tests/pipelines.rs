//! Every schedule in `systems/` runs for a few agent steps through the users' entry point
//! (`apfn::plugin::headless_app`, as `apfn run` does) on a small procedural scene.

use apfn::compose::{Pipeline, Scene, standard_registry};
use apfn::particles::PoseEstimate;
use apfn::plugin::headless_app;
use apfn::world::TruePose;
use apfn::world::map::procedural::Split;
use std::path::{Path, PathBuf};

fn schedules() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("systems");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("systems/ exists")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "ron"))
        .collect();
    files.sort();
    files
}

fn small_scene() -> Scene {
    let mut scene = Scene::apartments(Split::Seen, 3, 1, 2);
    scene.seed = 11;
    scene.episode.steps = 5;
    scene
}

#[test]
fn every_schedule_file_starts_with_a_comment_and_runs() {
    let registry = standard_registry();
    let loaded = small_scene().into_loaded(Path::new("tests/pipelines")).unwrap();
    let files = schedules();
    assert!(!files.is_empty(), "systems/ holds the pipelines");
    for path in files {
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            text.starts_with("//"),
            "{} must open with a one-line comment saying what it tests",
            path.display()
        );
        let pipeline = Pipeline::load(&path, &registry).unwrap_or_else(|e| panic!("{e}"));
        let localizes = pipeline.names().contains(&"estimate");
        let (mut app, robots) = headless_app(&loaded, pipeline).unwrap();
        for _ in 0..12 {
            app.update();
        }
        for robot in robots {
            let pose = app.world().get::<TruePose>(robot).unwrap().0;
            assert!(pose.is_finite(), "{}: true pose became {pose:?}", path.display());
            if localizes {
                let estimate = app.world().get::<PoseEstimate>(robot).unwrap().pose;
                assert!(estimate.is_finite(), "{}: estimate became {estimate:?}", path.display());
            }
        }
    }
}

#[test]
fn same_seed_gives_the_same_trajectory() {
    let registry = standard_registry();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("systems/random.ron");
    let run = || {
        let loaded = small_scene().into_loaded(Path::new("tests/pipelines")).unwrap();
        let (mut app, robots) = headless_app(&loaded, Pipeline::load(&path, &registry).unwrap()).unwrap();
        let mut poses = Vec::new();
        for _ in 0..8 {
            app.update();
            poses.extend(robots.iter().map(|&r| {
                (app.world().get::<TruePose>(r).unwrap().0, app.world().get::<PoseEstimate>(r).unwrap().pose)
            }));
        }
        poses
    };
    assert_eq!(run(), run(), "a seed must fix the whole run");
}

#[test]
fn belief_crop_follows_the_filter_in_a_running_pipeline() {
    let text = r#"Schedule(steps: [
        ("episode_reset", ()), ("odometry", ()), ("lidar", ()),
        ("init_particles", (task: tracking)), ("transition", ()), ("mcl_likelihood_field", ()),
        ("resample", ()), ("estimate", ()),
        ("belief_crop", (cells: 50, modes: 2)),
        ("random_policy", ()), ("drive", ()), ("physics", ()),
    ])"#;
    let pipeline = Pipeline::parse(text, Path::new("belief.ron"), &standard_registry()).unwrap();
    let loaded = small_scene().into_loaded(Path::new("tests/pipelines")).unwrap();
    let (mut app, robots) = headless_app(&loaded, pipeline).unwrap();
    for _ in 0..4 {
        app.update();
    }
    for robot in robots {
        let crop = app.world().get::<apfn::belief::BeliefCrop>(robot).unwrap();
        let estimate = app.world().get::<PoseEstimate>(robot).unwrap().pose;
        assert_eq!(crop.values.len(), 2 * apfn::belief::BELIEF_CHANNELS * 50 * 50);
        assert_eq!(crop.centres[0], estimate, "crop 0 is centred on this step's estimate");
        let weights = crop.channel(0, 1);
        let near: f32 = (20..30).flat_map(|r| (20..30).map(move |c| r * 50 + c)).map(|k| weights[k]).sum();
        assert!(near > 0.5, "a tracking belief sits within 0.5 m of its estimate: {near}");
        let free = crop.channel(0, 0);
        assert_eq!(free[25 * 50 + 25], 1.0, "the estimate stands in free space");
    }
}

/// A policy whose inputs the schedule does not produce (here: the shipped one-crop policy behind a
/// belief_crop stacking two past steps) stops the world from being built, naming the schedule,
/// the step and the field, instead of running with robots that never move.
#[test]
fn a_policy_the_schedule_cannot_feed_is_refused_before_the_first_step() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let policy = repo.join("models/apfn_compact.safetensors");
    let schedule = |crop: &str| {
        format!(
            r#"Schedule(steps: [
            ("episode_reset", ()), ("odometry", ()), ("lidar", ()), ("local_grid", ()),
            ("init_particles", (task: tracking)), ("transition", ()), ("mcl_likelihood_field", ()),
            ("resample", ()), ("estimate", ()), ("belief_crop", {crop}), ("step_metrics", ()),
            ("localization_reward", ()), ("sac_policy", (checkpoint: Some({policy:?}))),
            ("drive", ()), ("physics", ()),
        ])"#
        )
    };
    let loaded = small_scene().into_loaded(Path::new("tests/pipelines")).unwrap();
    let build = |crop: &str| {
        let pipeline =
            Pipeline::parse(&schedule(crop), Path::new("stacked.ron"), &standard_registry()).unwrap();
        headless_app(&loaded, pipeline).map(|_| ())
    };
    let err = build("(history: 2)").unwrap_err().to_string();
    assert!(
        err.starts_with("stacked.ron: step 13 `sac_policy`:")
            && err.contains("history: 2")
            && err.contains("1 belief crop"),
        "{err}"
    );
    build("()").expect("the schedule the policy was trained with builds");
}

#[test]
fn every_shipped_eval_config_loads() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let shared_maps = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/maps");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).expect("scenes/ exists") {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if !(name.starts_with("eval_") && name.ends_with(".ron")) {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        if text.contains("../shared/") && !shared_maps.exists() {
            eprintln!("skipping {name}: ../shared/maps is absent");
            continue;
        }
        apfn::eval::EvalConfig::load(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        checked += 1;
    }
    assert!(checked > 0, "scenes/ holds eval configs");
}
