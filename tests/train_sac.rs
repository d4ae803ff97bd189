//! SAC training end to end on a small world: a killed and resumed run writes the same
//! checkpoint as an uninterrupted one.

use apfn::train::sac::{STATE_FILE, SacTrainer, TrainSacConfig};
use std::path::{Path, PathBuf};

fn config(dir: &Path) -> (TrainSacConfig, PathBuf) {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = dir.join("scene.ron");
    std::fs::write(
        &scene,
        "Scene(maps: Procedural(split: seen, count: 2, params: (min_side_m: 5.0, max_side_m: 6.0, max_rooms: 2)), \
         robots_per_map: 1, robots_collide: false, seed: 3, episode: (steps: 4))",
    )
    .unwrap();
    let config = TrainSacConfig {
        scene,
        systems: repo.join("systems/apfn.ron"),
        network: "compact".into(),
        agent: apfn::agent::sac::SacAgentConfig {
            buffer: 64,
            batch: 8,
            learning_starts: 8,
            ..Default::default()
        },
        steps: 16,
        checkpoint_every: 8,
        log_every: 4,
        seed: 11,
    };
    let path = dir.join("train.ron");
    std::fs::write(&path, ron::to_string(&config).unwrap()).unwrap();
    (config, path)
}

#[test]
fn resumed_training_writes_the_same_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let (config, path) = config(dir.path());
    let (whole, split) = (dir.path().join("whole"), dir.path().join("split"));
    std::fs::create_dir_all(&whole).unwrap();
    std::fs::create_dir_all(&split).unwrap();

    let mut trainer = SacTrainer::new(config.clone(), &path).unwrap();
    while trainer.step < 16 {
        trainer.step();
    }
    assert!(trainer.agent().updates > 0, "the run must have trained");
    trainer.save_state(&whole).unwrap();

    let mut first = SacTrainer::new(config.clone(), &path).unwrap();
    while first.step < 8 {
        first.step();
    }
    first.save_state(&split).unwrap();
    drop(first);
    let mut resumed = SacTrainer::resume(config, &path, &split).unwrap();
    assert_eq!(resumed.step, 8);
    while resumed.step < 16 {
        resumed.step();
    }
    resumed.save_state(&split).unwrap();
    let (a, b) =
        (std::fs::read(whole.join(STATE_FILE)).unwrap(), std::fs::read(split.join(STATE_FILE)).unwrap());
    assert!(a == b, "resumed state differs from the uninterrupted run ({} vs {} bytes)", a.len(), b.len());
    let replays: Vec<_> = std::fs::read_dir(&split)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("replay_"))
        .collect();
    assert_eq!(replays.len(), 1, "older replay buffers are removed once a newer state names its own");
}
