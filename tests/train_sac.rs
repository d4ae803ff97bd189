//! SAC training end to end on a small world: a killed and resumed run writes the same
//! checkpoint as an uninterrupted one.

use apfn::agent::sac::SampledBatch;
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
        depth_columns: 0,
        belief_modes: 1,
        belief_history: 0,
        belief_overview: false,
        agent: apfn::agent::sac::SacAgentConfig {
            buffer: 64,
            batch: 8,
            learning_starts: 8,
            ..Default::default()
        },
        steps: 16,
        checkpoint_every: 8,
        snapshot_every: None,
        init: None,
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
    let config_again = config.clone();
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

    // A state whose step is damaged is refused by name, not resumed mid-episode.
    let mut state = apfn::nn::checkpoint::Checkpoint::load(&split.join(STATE_FILE)).unwrap();
    state.metadata.insert("train_step".into(), "[6]".into());
    state.save(&split.join(STATE_FILE)).unwrap();
    let err =
        SacTrainer::resume(config_again, &path, &split).err().expect("a step off the boundary").to_string();
    assert!(
        err.ends_with("metadata `train_step`: step 6, expected an episode boundary (a multiple of 4)"),
        "{err}"
    );
}

/// Points `config` at a copy of its schedule with the first `step` line replaced by `with`.
fn edit_schedule(dir: &Path, config: &mut TrainSacConfig, step: &str, with: &str, name: &str) {
    let original = std::fs::read_to_string(&config.systems).unwrap();
    let edited = original.replacen(step, with, 1);
    assert_ne!(edited, original, "systems/apfn.ron lists `{step}` as expected");
    config.systems = dir.join(name);
    std::fs::write(&config.systems, edited).unwrap();
}

/// Trains `config` (written to `dir/name`) for 12 world steps; returns two sampled transitions.
fn train_and_sample(dir: &Path, config: TrainSacConfig, name: &str) -> (SacTrainer, SampledBatch) {
    let path = dir.join(name);
    std::fs::write(&path, ron::to_string(&config).unwrap()).unwrap();
    let mut trainer = SacTrainer::new(config, &path).unwrap();
    while trainer.step < 12 {
        trainer.step();
    }
    assert!(trainer.agent().updates > 0, "the run must have trained");
    let mut batch = SampledBatch::default();
    trainer.agent().replay.sample(&[0, 1], &mut batch);
    (trainer, batch)
}

#[test]
fn a_depth_reading_agent_trains_on_the_strip_the_depth_step_writes() {
    let dir = tempfile::tempdir().unwrap();
    let (mut config, _) = config(dir.path());
    let lidar = "(\"lidar\",                ()),";
    edit_schedule(
        dir.path(),
        &mut config,
        lidar,
        "(\"lidar\", ()), (\"depth\", (columns: 8)),",
        "apfn_depth.ron",
    );
    config.depth_columns = 8;
    let (trainer, batch) = train_and_sample(dir.path(), config, "train_depth.ron");
    assert_eq!(trainer.agent().learner.nets.config.depth_columns, 8);
    let state = batch.transitions().obs.state;
    assert_eq!(state.len(), 2 * (4 + 8), "robot state ⊕ 8 depth columns per observation");
    assert!(
        state[4..12].iter().all(|d| (0.0..=1.0).contains(d)) && state[4..12].iter().any(|&d| d > 0.0),
        "{state:?}"
    );
}

#[test]
fn a_multi_crop_agent_trains_on_the_crops_belief_crop_writes() {
    let dir = tempfile::tempdir().unwrap();
    let (mut config, _) = config(dir.path());
    let crop = "(\"belief_crop\",          ()),";
    edit_schedule(dir.path(), &mut config, crop, "(\"belief_crop\", (modes: 3)),", "apfn_modes.ron");

    config.belief_modes = 2;
    let err = SacTrainer::new(config.clone(), &dir.path().join("train_mismatched.ron")).err().unwrap();
    let err = format!("{err:#}");
    assert!(err.contains("belief_modes: expected 3") && err.contains("apfn_modes.ron"), "{err}");

    config.belief_modes = 3;
    let (trainer, batch) = train_and_sample(dir.path(), config, "train_modes.ron");
    assert_eq!(trainer.agent().learner.nets.config.belief_channels, 12, "3 crops of 4 channels");
    assert_eq!(batch.transitions().obs.belief.len(), 2 * 12 * 50 * 50);
}

/// A config that starts from a policy trained here on one crop (`policy.safetensors`) and
/// schedules `belief_crop` with `crop_params` (in `dir/schedule`); its own belief fields still
/// describe one crop.
fn from_a_one_crop_policy(dir: &Path, crop_params: &str, schedule: &str) -> TrainSacConfig {
    let (mut config, _) = config(dir);
    let (first, _) = train_and_sample(dir, config.clone(), "train_first.ron");
    first.agent().learner.nets.save(&dir.join("policy.safetensors")).unwrap();
    let crop = "(\"belief_crop\",          ()),";
    edit_schedule(dir, &mut config, crop, &format!("(\"belief_crop\", {crop_params}),"), schedule);
    config.init = Some("policy.safetensors".into());
    config
}

/// `belief_history` stacks past crops after the present one; a policy trained without them is a
/// valid start (its networks widened with zero weights), and the schedule must agree.
#[test]
fn an_agent_with_history_starts_from_a_policy_without_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = from_a_one_crop_policy(dir.path(), "(history: 2)", "apfn_history.ron");

    let err = SacTrainer::new(config.clone(), &dir.path().join("train_mismatched.ron")).err().unwrap();
    let err = format!("{err:#}");
    assert!(err.contains("belief_history: expected 2") && err.contains("apfn_history.ron"), "{err}");

    config.belief_history = 2;
    let (trainer, _) = train_and_sample(dir.path(), config, "train_history.ron");
    assert_eq!(trainer.agent().learner.nets.config.belief_channels, 12, "the present and 2 past crops");
    let replay = &trainer.agent().replay;
    let mut batch = SampledBatch::default();
    replay.sample(&(0..replay.len()).collect::<Vec<_>>(), &mut batch);
    let crop = 4 * 50 * 50;
    let moved = batch.transitions().obs.belief.chunks_exact(3 * crop).filter(|stack| {
        let (present, last) = stack.split_at(crop);
        present.iter().any(|&v| v > 0.0) && present != &last[..crop]
    });
    assert!(moved.count() > 0, "past crops differ from the present once an episode is under way");
}

/// `belief_overview` adds the coarse crop of the whole belief after the estimate's; a policy
/// trained without it is a valid start, and the schedule must agree.
#[test]
fn an_agent_with_the_overview_starts_from_a_policy_without_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = from_a_one_crop_policy(dir.path(), "(overview_m: Some(0.4))", "apfn_overview.ron");

    let err = SacTrainer::new(config.clone(), &dir.path().join("train_mismatched.ron")).err().unwrap();
    let err = format!("{err:#}");
    assert!(err.contains("belief_overview: expected true") && err.contains("`overview_m`"), "{err}");

    config.belief_overview = true;
    let (trainer, batch) = train_and_sample(dir.path(), config, "train_overview.ron");
    assert_eq!(
        trainer.agent().learner.nets.config.belief_channels,
        8,
        "the estimate's crop and the overview"
    );
    let crop = 4 * 50 * 50;
    let wider = batch.transitions().obs.belief.chunks_exact(2 * crop).filter(|pair| {
        let (fine, overview) = pair.split_at(crop);
        let occupied = |c: &[f32]| c[..crop / 4].iter().filter(|&&free| free < 1.0).count();
        occupied(overview) > occupied(fine)
    });
    assert!(wider.count() > 0, "the 20 m overview holds more of the map's walls than the 5 m crop");
}

#[test]
fn a_belief_mode_count_out_of_range_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let (mut config, _) = config(dir.path());
    for modes in [0, 17] {
        config.belief_modes = modes;
        let err = config.check().unwrap_err();
        assert!(err.contains("belief_modes") && err.contains("1 to 16"), "{err}");
    }
}

/// A run with `init` starts from that policy's networks (critics included, targets copied from
/// them) and trains on from there; a policy of another network is refused by name.
#[test]
fn a_run_starts_from_the_policy_init_names() {
    let dir = tempfile::tempdir().unwrap();
    let (mut config, _) = config(dir.path());
    let (first, _) = train_and_sample(dir.path(), config.clone(), "train_first.ron");
    let policy = dir.path().join("policy.safetensors");
    first.agent().learner.nets.save(&policy).unwrap();
    let trained = first.agent().learner.nets.params.values.clone();

    config.init = Some("policy.safetensors".into());
    let path = dir.path().join("train_init.ron");
    let mut tuned = SacTrainer::new(config.clone(), &path).unwrap();
    let learner = &tuned.agent().learner;
    assert!(learner.nets.params.values == trained, "the networks are the policy's");
    assert!(learner.target == trained, "the target critics start as copies of the critics");
    assert_eq!(learner.alpha(), config.agent.hyper.initial_alpha);
    let fresh = SacTrainer::new(TrainSacConfig { init: None, ..config.clone() }, &path).unwrap();
    assert!(fresh.agent().learner.nets.params.values != trained, "without init the networks are fresh");
    while tuned.step < 12 {
        tuned.step();
    }
    assert!(tuned.agent().updates > 0 && tuned.agent().learner.nets.params.values != trained);

    config.network = "paper".into();
    let err = format!("{:#}", SacTrainer::new(config, &path).err().unwrap());
    assert!(err.contains("train_init.ron: init") && err.contains("policy.safetensors"), "{err}");
}

/// Every training config in `scenes/` parses, passes its checks and builds its trainer (world,
/// schedule, networks), so a documented `apfn train-sac --config scenes/…` starts.
#[test]
fn every_shipped_training_config_builds_its_trainer() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).expect("scenes/ exists") {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if !(name.starts_with("train_sac_") && name.ends_with(".ron")) || name == "train_sac_world.ron" {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let config: TrainSacConfig = ron::from_str(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
        config.check().unwrap_or_else(|e| panic!("{name}: {e}"));
        SacTrainer::new(config, &path).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        checked += 1;
    }
    assert!(checked >= 2, "scenes/ holds the paper's and the global training configs");
}

fn apfn(args: &[&str]) -> anyhow::Result<()> {
    use clap::Parser;
    apfn::cli::run(apfn::cli::Cli::try_parse_from(std::iter::once("apfn").chain(args.iter().copied()))?)
}

/// `apfn train-sac` keeps a policy every `snapshot_every` steps, extends a finished run exactly
/// when only `steps` grew, and refuses to resume under a config that would train differently.
#[test]
fn train_sac_keeps_snapshots_and_extends_a_finished_run() {
    let dir = tempfile::tempdir().unwrap();
    let (mut config, path) = config(dir.path());
    let out = dir.path().join("run");
    let train = |config: &TrainSacConfig, resume: bool| {
        std::fs::write(&path, ron::to_string(config).unwrap()).unwrap();
        let (path, out) = (path.to_str().unwrap(), out.to_str().unwrap());
        let mut args = vec!["train-sac", "--config", path, "--out", out];
        args.extend(resume.then_some("--resume"));
        apfn(&args)
    };
    config.snapshot_every = Some(4);
    train(&config, false).unwrap();
    let kept = |step: u64| out.join(format!("policy_{step}.safetensors")).exists();
    assert!([4, 8, 12, 16].into_iter().all(kept) && !kept(20), "a policy per 4 steps up to 16");
    assert_eq!(
        std::fs::read(out.join("policy_16.safetensors")).unwrap(),
        std::fs::read(out.join("policy.safetensors")).unwrap(),
        "the last snapshot is the last policy"
    );

    config.steps = 24;
    train(&config, true).unwrap();
    assert!(kept(20) && kept(24));
    let log = std::fs::read_to_string(out.join("train_log.csv")).unwrap();
    let steps: Vec<&str> = log.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(steps, ["4", "8", "12", "16", "20", "24"], "the extended run continues the log");
    let wall: Vec<f64> =
        log.lines().skip(1).map(|l| l.rsplit(',').next().unwrap().parse().unwrap()).collect();
    assert!(wall.windows(2).all(|w| w[0] < w[1]), "the extended run continues the clock: {wall:?}");
    let mut straight = SacTrainer::new(config.clone(), &path).unwrap();
    while straight.step < 24 {
        straight.step();
    }
    let straight_dir = dir.path().join("straight");
    std::fs::create_dir_all(&straight_dir).unwrap();
    straight.save_state(&straight_dir).unwrap();
    assert!(
        std::fs::read(out.join(STATE_FILE)).unwrap() == std::fs::read(straight_dir.join(STATE_FILE)).unwrap(),
        "16 steps extended to 24 must end where 24 steps in one run end"
    );

    config.seed += 1;
    let err = format!("{:#}", train(&config, true).unwrap_err());
    assert!(err.contains("another config") && err.contains("train.ron"), "{err}");

    config.seed -= 1;
    config.steps = 26;
    let err = format!("{:#}", train(&config, false).unwrap_err());
    assert!(err.contains("steps: expected a multiple of the episode length (4 steps), got 26"), "{err}");
}
