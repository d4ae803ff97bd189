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
