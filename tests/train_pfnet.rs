//! PF-net pretraining end to end on a tiny config: the simulated data are deterministic, a run
//! resumed from its checkpoint writes the same next checkpoint, byte for byte, as a run that was
//! never interrupted, and training lowers the validation loss of a fixed batch.

use apfn::nn::adam::AdamConfig;
use apfn::nn::checkpoint::Checkpoint;
use apfn::nn::pfnet::{
    FeatureCacheSpec, GradBuffers, Observation, PfNet, PfNetConfig, Workspaces, is_map_encoder_param,
};
use apfn::particles::MapFeatures;
use apfn::train::pfnet::{
    BatchBuffers, ExtraTrainMaps, TrainPfNetConfig, TrainState, feature_banks, simulate_data,
};
use apfn::world::map::procedural::ApartmentParams;

fn tiny() -> TrainPfNetConfig {
    TrainPfNetConfig {
        train_maps: 2,
        val_maps: 1,
        train_episodes: 12,
        val_episodes: 4,
        steps: 4,
        batch: 3,
        particles: 6,
        train_steps: 4,
        eval_every: 2,
        seed: 5,
        // A decaying rate, so resuming must also pick the schedule up where it stopped; large, so
        // that four steps move the weights measurably.
        adam: AdamConfig { learning_rate: 1e-3, ..AdamConfig::default() },
        final_learning_rate: Some(1e-4),
        ..TrainPfNetConfig::default()
    }
}

#[test]
fn train_pfnet_data_are_deterministic_and_shaped() {
    let config = tiny();
    let [a, _] = simulate_data(&config, |_, _| {}).unwrap();
    let [b, _] = simulate_data(&config, |_, _| {}).unwrap();
    assert_eq!(a.episodes, b.episodes, "the same seed must simulate the same episodes");
    assert_eq!(a.episodes.len(), 12);
    for e in &a.episodes {
        assert_eq!(e.poses.len(), 4, "every episode has `steps` steps");
        assert_eq!(e.grids.len(), 4 * 56 * 56, "one 56 × 56 grid per step");
        assert_eq!(e.depths.len(), 4 * 56, "one 56-column depth strip per step");
    }
}

#[test]
fn train_pfnet_mixes_extra_apartments_into_training_only() {
    let hall = ApartmentParams {
        min_side_m: 12.0,
        max_side_m: 14.0,
        min_rooms: 1,
        max_rooms: 1,
        ..tiny().apartment
    };
    let extra = ExtraTrainMaps { maps: 1, episodes: 5, apartment: hall };
    let config = TrainPfNetConfig { extra_train: vec![extra], ..tiny() };
    let [plain_train, plain_val] = simulate_data(&tiny(), |_, _| {}).unwrap();
    let [train, val] = simulate_data(&config, |_, _| {}).unwrap();
    assert_eq!(val.episodes, plain_val.episodes, "validation stays on the main apartments");
    assert_eq!(train.episodes[..12], plain_train.episodes[..], "the main episodes come first, unchanged");
    assert_eq!((train.episodes.len(), train.maps.len()), (17, 3), "5 more episodes on 1 more map");
    assert!(train.episodes[12..].iter().all(|e| e.map == 2), "extra episodes index the extra map");
    let side = |m: &apfn::world::map::NetworkMap| m.width.max(m.height) as f32 * m.resolution_m;
    assert!(side(&train.maps[2]) > 12.0, "the extra map has its own shape: {} m", side(&train.maps[2]));

    let bad = TrainPfNetConfig {
        extra_train: vec![ExtraTrainMaps { maps: 0, ..config.extra_train[0].clone() }],
        ..tiny()
    };
    let err = bad.check().unwrap_err();
    assert!(err.starts_with("extra_train[0].maps"), "unhelpful error: {err}");
}

#[test]
fn train_pfnet_observes_the_depth_strip_and_refuses_data_without_it() {
    let config = TrainPfNetConfig { observation: Observation::GridAndDepth, ..tiny() };
    let [train, _] = simulate_data(&config, |_, _| {}).unwrap();
    let mut state = TrainState::new(&config).unwrap();
    assert_eq!(state.model.config.obs_channels, 2, "grid and depth image");
    let (pool, mut buffers, mut grads) =
        (Workspaces::for_current_pool(), BatchBuffers::default(), GradBuffers::default());
    let before = state.model.params.values.clone();
    state.train_step(&config, (&train, &[]), &mut buffers, &mut grads, &pool);
    assert!(state.model.params.values.iter().all(|v| v.is_finite()), "a finite step");
    assert_ne!(state.model.params.values, before, "the step trains");

    let dir = tempfile::tempdir().unwrap();
    let schedule = dir.path().join("no_depth.ron");
    let text = std::fs::read_to_string("systems/collect_pfnet.ron")
        .unwrap()
        .replace("(\"depth\",", "// (\"depth\",");
    std::fs::write(&schedule, text).unwrap();
    let blind = TrainPfNetConfig { collect_schedule: schedule.display().to_string(), ..config };
    let err = simulate_data(&blind, |_, _| {}).unwrap_err().to_string();
    assert!(err.starts_with("observation: `grid_and_depth` reads depth strips"), "unhelpful error: {err}");
}

#[test]
fn train_pfnet_learning_rate_follows_a_half_cosine() {
    let config = TrainPfNetConfig { train_steps: 100, ..tiny() };
    let (start, end) = (config.adam.learning_rate, 1e-4);
    assert_eq!(config.learning_rate_at(0), start);
    assert!((config.learning_rate_at(50) - (start + end) / 2.0).abs() < 1e-7, "halfway is the midpoint");
    assert!((config.learning_rate_at(100) - end).abs() < 1e-9);
    let rates: Vec<f32> = (0..=100).map(|s| config.learning_rate_at(s)).collect();
    assert!(rates.windows(2).all(|w| w[1] <= w[0]), "the rate never rises");
    let constant = TrainPfNetConfig { final_learning_rate: None, ..config.clone() };
    assert!((0..=100).all(|s| constant.learning_rate_at(s) == start));
    let rising = TrainPfNetConfig { final_learning_rate: Some(1.0), ..config };
    let err = rising.check().unwrap_err();
    assert!(err.contains("final_learning_rate"), "{err}");
}

#[test]
fn train_pfnet_resume_may_extend_a_constant_rate_run_and_nothing_else() {
    let saved = TrainPfNetConfig { final_learning_rate: None, ..tiny() };
    let longer = TrainPfNetConfig { train_steps: saved.train_steps * 3, eval_every: 7, ..saved.clone() };
    assert!(longer.continues(&saved), "a constant-rate run extends");
    let other_seed = TrainPfNetConfig { seed: saved.seed + 1, ..longer.clone() };
    assert!(!other_seed.continues(&saved), "another seed is another run");
    let other_rate =
        TrainPfNetConfig { adam: AdamConfig { learning_rate: 1e-2, ..saved.adam }, ..saved.clone() };
    assert!(!other_rate.continues(&saved), "another learning rate is another run");
    let cosine = TrainPfNetConfig { final_learning_rate: Some(1e-5), ..saved };
    let cosine_longer = TrainPfNetConfig { train_steps: cosine.train_steps * 3, ..cosine.clone() };
    assert!(!cosine_longer.continues(&cosine), "a cosine schedule is laid out over train_steps");
    assert!(cosine.continues(&cosine));
}

#[test]
fn train_pfnet_resume_writes_the_same_checkpoint_bytes() {
    let config = tiny();
    let [train, _] = simulate_data(&config, |_, _| {}).unwrap();
    let pool = Workspaces::for_current_pool();
    let dir = tempfile::tempdir().unwrap();
    let run = |state: &mut TrainState, until: u64| {
        let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
        while state.step < until {
            state.train_step(&config, (&train, &[]), &mut buffers, &mut grads, &pool);
        }
    };

    let mut straight = TrainState::new(&config).unwrap();
    run(&mut straight, 4);
    let straight_path = dir.path().join("straight.safetensors");
    straight.to_checkpoint(&config).save(&straight_path).unwrap();

    let mut first_half = TrainState::new(&config).unwrap();
    run(&mut first_half, 2);
    let half_path = dir.path().join("half.safetensors");
    first_half.to_checkpoint(&config).save(&half_path).unwrap();
    drop(first_half); // as if the process had been killed here
    let mut resumed = TrainState::from_checkpoint(&Checkpoint::load(&half_path).unwrap(), &config).unwrap();
    run(&mut resumed, 4);
    let resumed_path = dir.path().join("resumed.safetensors");
    resumed.to_checkpoint(&config).save(&resumed_path).unwrap();

    let (a, b) = (Checkpoint::load(&straight_path).unwrap(), Checkpoint::load(&resumed_path).unwrap());
    for (x, y) in a.tensors.iter().zip(&b.tensors) {
        let differing = x.data.iter().zip(&y.data).filter(|(p, q)| p.to_bits() != q.to_bits()).count();
        assert_eq!(
            differing,
            0,
            "tensor {} differs in {differing} of {} values after resuming",
            x.name,
            x.data.len()
        );
    }
    assert_eq!(a.metadata, b.metadata, "the resumed run's metadata differs");
    let same = std::fs::read(&straight_path).unwrap() == std::fs::read(&resumed_path).unwrap();
    assert!(same, "a resumed run must write the same checkpoint bytes as an uninterrupted one");
}

/// `model` saved as `dir/name.safetensors`, its path as an `init` takes it.
fn saved(model: &PfNet, dir: &std::path::Path, name: &str) -> String {
    let path = dir.join(format!("{name}.safetensors"));
    model.save(&path).unwrap();
    path.display().to_string()
}

#[test]
fn train_pfnet_through_cached_features_keeps_the_map_encoder_frozen() {
    let dir = tempfile::tempdir().unwrap();
    let init = PfNet::new(PfNetConfig::compact(), 9).unwrap();
    let config = TrainPfNetConfig {
        features: MapFeatures::Cached,
        init: Some(saved(&init, dir.path(), "init")),
        cache: FeatureCacheSpec { orientations: 8, ..Default::default() },
        ..tiny()
    };
    let without_init = TrainPfNetConfig { init: None, ..config.clone() };
    assert!(
        without_init.check().unwrap_err().starts_with("init:"),
        "cached features need the encoder's checkpoint"
    );

    let [train, _] = simulate_data(&config, |_, _| {}).unwrap();
    let mut state = TrainState::new(&config).unwrap();
    assert_eq!(state.model.params.values, init.params.values, "training starts from `init`");
    let banks = feature_banks(&config, &state.model, &train, |_| {});
    assert_eq!(banks.len(), train.maps.len(), "one bank per training map");
    let pool = Workspaces::for_current_pool();
    let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
    for _ in 0..3 {
        let loss = state.train_step(&config, (&train, &banks), &mut buffers, &mut grads, &pool);
        assert!(loss.is_finite());
    }
    for (id, spec) in init.params.specs() {
        let (before, after) = (init.params.get(id), state.model.params.get(id));
        assert_eq!(
            before == after,
            is_map_encoder_param(&spec.name),
            "{}: only the map encoder stays as it was",
            spec.name
        );
    }
}

/// A grid checkpoint starts a grid + depth run: every weight it has carries over (the depth
/// channel's start at zero), and one step trains the depth channel too; the reverse is refused,
/// naming `init`.
#[test]
fn train_pfnet_grid_checkpoint_starts_a_grid_and_depth_run() {
    let dir = tempfile::tempdir().unwrap();
    let grid = PfNet::new(PfNetConfig::compact(), 4).unwrap();
    let config = TrainPfNetConfig {
        observation: Observation::GridAndDepth,
        init: Some(saved(&grid, dir.path(), "grid")),
        ..tiny()
    };
    let mut state = TrainState::new(&config).unwrap();
    assert_eq!(state.model.config.observation, Observation::GridAndDepth);
    let depth_kernels = |model: &PfNet| -> Vec<f32> {
        let id = model.params.find("o_c3/kernel").expect("the observation encoder's first 3×3 conv");
        let taps = 9;
        (model.params.get(id).chunks_exact(taps).skip(1).step_by(2)).flatten().copied().collect()
    };
    assert!(depth_kernels(&state.model).iter().all(|&w| w == 0.0), "depth weights start at zero");
    for (id, spec) in grid.params.specs().filter(|(_, s)| !s.name.starts_with("o_c")) {
        let widened = state.model.params.find(&spec.name).unwrap();
        assert_eq!(grid.params.get(id), state.model.params.get(widened), "{} carries over", spec.name);
    }

    let [train, _] = simulate_data(&config, |_, _| {}).unwrap();
    let pool = Workspaces::for_current_pool();
    let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
    let loss = state.train_step(&config, (&train, &[]), &mut buffers, &mut grads, &pool);
    assert!(loss.is_finite());
    assert!(depth_kernels(&state.model).iter().any(|&w| w != 0.0), "the depth channel learns");

    let back = TrainPfNetConfig { init: Some(saved(&state.model, dir.path(), "both")), ..tiny() };
    let e = TrainState::new(&back).err().expect("a grid + depth checkpoint cannot start a grid run");
    assert!(format!("{e:#}").starts_with("init:"), "{e:#}");
}

/// `local_map_cell_m` widens `init`'s local map without touching a weight; the crops, and so
/// the loss, change with it.
#[test]
fn train_pfnet_local_map_cell_m_widens_the_window_of_init() {
    let dir = tempfile::tempdir().unwrap();
    let init = PfNet::new(PfNetConfig::compact(), 6).unwrap();
    let narrow = TrainPfNetConfig { init: Some(saved(&init, dir.path(), "init")), ..tiny() };
    let wide = TrainPfNetConfig { local_map_cell_m: Some(0.18), ..narrow.clone() };
    let [train, _] = simulate_data(&narrow, |_, _| {}).unwrap();
    let pool = Workspaces::for_current_pool();
    let mut losses = vec![];
    for config in [&narrow, &wide] {
        let mut state = TrainState::new(config).unwrap();
        assert_eq!(state.model.params.values, init.params.values, "training starts from `init`");
        let cell_m = config.local_map_cell_m.unwrap_or(0.1);
        assert_eq!(state.model.config.local_map.cell_m, cell_m, "the checkpoint will name its pixel");
        let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
        losses.push(state.train_step(config, (&train, &[]), &mut buffers, &mut grads, &pool));
    }
    assert_ne!(losses[0], losses[1], "the same weights on other crops give another loss");

    let bad = TrainPfNetConfig { local_map_cell_m: Some(0.0), ..narrow };
    assert_eq!(bad.check().unwrap_err(), "local_map_cell_m: expected 0.01 to 1 m, found 0");
}

/// A checkpoint whose map encoder sees the map alone starts a `scan_on_map` run: the first loss is
/// its own (the scan's channel starts at zero), the step then trains that channel, and the feature
/// cache, which cannot hold features that change with the scan, is refused by name.
#[test]
fn train_pfnet_scan_on_map_starts_from_a_checkpoint_without_it() {
    use apfn::nn::pfnet::ScanOnMap;
    let dir = tempfile::tempdir().unwrap();
    let init = PfNet::new(PfNetConfig::compact(), 5).unwrap();
    let plain = TrainPfNetConfig { init: Some(saved(&init, dir.path(), "init")), ..tiny() };
    let laid = TrainPfNetConfig {
        scan_on_map: Some(ScanOnMap { grid_extent_m: 5.0, own_encoder: false }),
        ..plain.clone()
    };
    let [train, _] = simulate_data(&plain, |_, _| {}).unwrap();
    let pool = Workspaces::for_current_pool();
    let mut runs = vec![];
    for config in [&plain, &laid] {
        let mut state = TrainState::new(config).unwrap();
        let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
        let loss = state.train_step(config, (&train, &[]), &mut buffers, &mut grads, &pool);
        runs.push((loss, state.model));
    }
    let ((plain_loss, _), (laid_loss, model)) = (&runs[0], &runs[1]);
    assert!((plain_loss - laid_loss).abs() <= 1e-6 * plain_loss, "{plain_loss} against {laid_loss}");
    let id = model.params.find("m_c3/kernel").expect("the map encoder's first 3×3 conv");
    let scan_taps = model.params.get(id).chunks_exact(9).skip(1).step_by(2);
    assert!(scan_taps.flatten().any(|&w| w != 0.0), "the scan's channel learns");

    let cached = TrainPfNetConfig { features: MapFeatures::Cached, ..laid.clone() };
    assert!(cached.check().unwrap_err().starts_with("scan_on_map: the map features then change"));

    // With the map beyond the local map's edge the same weights train on, as a network saved
    // with it would: the first stage reads a wider input, the loss is another.
    let context = TrainPfNetConfig { map_context: true, ..laid.clone() };
    let start = TrainState::new(&laid).unwrap().model;
    let saved_with = saved(&start.with_map_context(true).unwrap(), dir.path(), "context");
    let mut losses = vec![];
    for config in [&context, &TrainPfNetConfig { init: Some(saved_with), ..context.clone() }] {
        let mut state = TrainState::new(config).unwrap();
        assert!(state.model.config.map_context && state.model.params.values == start.params.values);
        let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
        losses.push(state.train_step(config, (&train, &[]), &mut buffers, &mut grads, &pool));
    }
    assert_eq!(losses[0], losses[1], "gained in the run or saved with it");
    assert!((losses[0] - laid_loss).abs() > 1e-6 * laid_loss, "{losses:?} against {laid_loss}");
}

/// A one-view checkpoint starts a wide-view run: on the same episodes, the widened network's
/// first loss is the one-view network's to the bit (the new channels start at zero), and the
/// step then trains them. Episodes without wide grids of the view's window are refused by name;
/// a collection keeps the wide grids.
#[test]
fn train_pfnet_wide_view_starts_from_a_one_view_checkpoint() {
    use apfn::nn::pfnet::WideView;
    use apfn::train::collect::{CollectConfig, collect, load_collection};
    let dir = tempfile::tempdir().unwrap();
    let init = PfNet::new(PfNetConfig::compact(), 4).unwrap();
    let narrow = TrainPfNetConfig { init: Some(saved(&init, dir.path(), "init")), ..tiny() };
    let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: false };
    let wide = TrainPfNetConfig {
        wide_view: Some(view),
        collect_schedule: "systems/collect_pfnet_wide.ron".into(),
        ..narrow.clone()
    };
    let [narrow_train, _] = simulate_data(&narrow, |_, _| {}).unwrap();
    let [wide_train, _] = simulate_data(&wide, |_, _| {}).unwrap();
    assert_eq!(wide_train.wide_extent_m, Some(10.0));
    for (n, w) in narrow_train.episodes.iter().zip(&wide_train.episodes) {
        assert_eq!((&n.poses, &n.grids), (&w.poses, &w.grids), "the same episodes");
        assert_eq!(w.wide_grids.len(), w.grids.len(), "one wide grid per step");
        assert_ne!(w.wide_grids, w.grids, "over another window");
    }

    let pool = Workspaces::for_current_pool();
    let mut losses = vec![];
    let mut wide_state = None;
    for (config, data) in [(&narrow, &narrow_train), (&wide, &wide_train)] {
        let mut state = TrainState::new(config).unwrap();
        let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
        losses.push(state.train_step(config, (data, &[]), &mut buffers, &mut grads, &pool));
        wide_state = Some(state);
    }
    assert_eq!(losses[0], losses[1], "zero-weight wide channels change no likelihood");
    let model = wide_state.unwrap().model;
    assert_eq!(
        (model.config.wide_view, model.config.map_channels, model.config.obs_channels),
        (Some(view), 2, 2)
    );
    let wide_map_weights = |model: &PfNet| -> Vec<f32> {
        let id = model.params.find("m_c3/kernel").expect("the map encoder's first 3×3 conv");
        (model.params.get(id).chunks_exact(9).skip(1).step_by(2)).flatten().copied().collect()
    };
    assert!(wide_map_weights(&model).iter().any(|&w| w != 0.0), "the wide map channel learns");

    let cached = TrainPfNetConfig { features: MapFeatures::Cached, ..wide.clone() };
    assert!(
        cached
            .check()
            .unwrap_err()
            .starts_with("wide_view: the feature cache holds map encoders of one map channel")
    );
    let unfed = TrainPfNetConfig { collect_schedule: narrow.collect_schedule.clone(), ..wide.clone() };
    let err = simulate_data(&unfed, |_, _| {}).unwrap_err().to_string();
    assert!(err.starts_with("wide_view: expected episodes whose wide grid spans Some(10.0) m"), "{err}");

    let collection = CollectConfig {
        shards: 1,
        maps_per_shard: 1,
        episodes_per_shard: 2,
        steps: 4,
        schedule: wide.collect_schedule.clone(),
        ..Default::default()
    };
    collect(&collection, dir.path(), |_, _| {}).unwrap();
    let set = load_collection(dir.path()).unwrap();
    assert_eq!(set.wide_extent_m, Some(10.0), "the window comes back");
    assert!(set.episodes.iter().all(|e| e.wide_grids.len() == 4 * 56 * 56), "and the wide grids");
}

/// `apfn pfnet export` keeps a training checkpoint's network and drops Adam's moments.
/// A wide view with a map encoder of its own starts from a one-view checkpoint as a silent copy
/// of the paper encoder (the first loss is the one-view network's: its features enter the joint
/// stage through zero weights, which one step then trains) and trains through the feature cache
/// too, its banks holding both encoders, the encoders frozen.
#[test]
fn train_pfnet_wide_map_encoder_starts_silent_and_trains_through_the_cache() {
    use apfn::nn::pfnet::WideView;
    let dir = tempfile::tempdir().unwrap();
    let init = PfNet::new(PfNetConfig::compact(), 4).unwrap();
    let narrow = TrainPfNetConfig { init: Some(saved(&init, dir.path(), "init")), ..tiny() };
    let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
    let wide = TrainPfNetConfig {
        wide_view: Some(view),
        collect_schedule: "systems/collect_pfnet_wide.ron".into(),
        ..narrow.clone()
    };
    let cached = TrainPfNetConfig {
        features: MapFeatures::Cached,
        cache: FeatureCacheSpec { orientations: 8, ..Default::default() },
        ..wide.clone()
    };
    cached.check().expect("a wide map encoder of its own is cacheable");
    let [narrow_train, _] = simulate_data(&narrow, |_, _| {}).unwrap();
    let [wide_train, _] = simulate_data(&wide, |_, _| {}).unwrap();
    let pool = Workspaces::for_current_pool();
    let step = |config: &TrainPfNetConfig, data, banks: &[_]| {
        let mut state = TrainState::new(config).unwrap();
        let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
        let loss = state.train_step(config, (data, banks), &mut buffers, &mut grads, &pool);
        (loss, state.model)
    };
    let (narrow_loss, _) = step(&narrow, &narrow_train, &[]);
    let (wide_loss, model) = step(&wide, &wide_train, &[]);
    assert!((wide_loss - narrow_loss).abs() <= 1e-6 * narrow_loss, "{wide_loss} against {narrow_loss}");
    let quarter = 14 * 14;
    let (fine, channels) =
        (init.map_feature_len() / quarter, (model.map_feature_len() + model.obs_feature_len()) / quarter);
    let id = model.params.find("j_lc3/kernel").unwrap();
    let on_wide = model.params.get(id).chunks_exact(channels).flat_map(|tap| &tap[fine..2 * fine]);
    assert!(on_wide.into_iter().any(|&w| w != 0.0), "the joint weights on the wide features learn");

    let state = TrainState::new(&cached).unwrap();
    let banks = feature_banks(&cached, &state.model, &wide_train, |_| {});
    let (loss, model) = step(&cached, &wide_train, &banks);
    assert!(loss.is_finite());
    for (id, spec) in state.model.params.specs() {
        let moved = state.model.params.get(id) != model.params.get(id);
        assert_eq!(moved, !is_map_encoder_param(&spec.name), "{}: only the map encoders stay", spec.name);
    }
}

#[test]
fn pfnet_export_writes_the_network_of_a_training_checkpoint() {
    use apfn::cli::pfnet::{PfNetCommand, run};
    let dir = tempfile::tempdir().unwrap();
    let (last, out) = (dir.path().join("last.safetensors"), dir.path().join("model.safetensors"));
    let state = TrainState::new(&tiny()).unwrap();
    state.to_checkpoint(&tiny()).save(&last).unwrap();
    run(PfNetCommand::Export { checkpoint: last.clone(), out: out.clone(), half: false }).unwrap();
    let model = PfNet::load(&out).unwrap();
    assert_eq!((&model.config, &model.params.values), (&state.model.config, &state.model.params.values));
    let size = |path: &std::path::Path| std::fs::metadata(path).unwrap().len();
    assert!(size(&out) * 2 < size(&last), "no optimizer state: {} against {} bytes", size(&out), size(&last));

    let small = dir.path().join("half.safetensors");
    run(PfNetCommand::Export { checkpoint: last.clone(), out: small.clone(), half: true }).unwrap();
    let rounded = PfNet::load(&small).unwrap();
    assert!(size(&small) * 10 < size(&out) * 6, "F16: {} against {} bytes", size(&small), size(&out));
    let near = (rounded.params.values.iter().zip(&model.params.values))
        .all(|(r, w)| (r - w).abs() <= w.abs() / 2048.0 + 3e-8);
    assert!(near && rounded.config == model.config, "each weight rounded to half precision");

    let missing = dir.path().join("none.safetensors");
    let err = run(PfNetCommand::Export { checkpoint: missing, out, half: false }).unwrap_err();
    assert!(format!("{err:#}").starts_with("--checkpoint"), "{err:#}");
}

#[test]
fn collect_is_deterministic_resumable_and_loads_back() {
    use apfn::train::collect::{CollectConfig, Manifest, collect, load_collection};
    let config = CollectConfig {
        shards: 2,
        maps_per_shard: 1,
        episodes_per_shard: 3,
        steps: 4,
        seed: 7,
        ..Default::default()
    };
    let dir = tempfile::tempdir().unwrap();
    collect(&config, dir.path(), |_, _| {}).unwrap();
    let shard = dir.path().join("shard_00001.safetensors");
    let first = std::fs::read(&shard).unwrap();

    // As if the run had been killed before its second shard: resuming writes the same bytes.
    let manifest_path = dir.path().join("manifest.json");
    let mut manifest: Manifest =
        serde_json::from_str(&std::fs::read_to_string(&manifest_path).unwrap()).unwrap();
    manifest.shards.pop();
    std::fs::write(&manifest_path, serde_json::to_string(&manifest).unwrap()).unwrap();
    std::fs::remove_file(&shard).unwrap();
    collect(&config, dir.path(), |_, _| {}).unwrap();
    assert_eq!(std::fs::read(&shard).unwrap(), first, "a resumed collection writes the same shard bytes");

    let other = CollectConfig { seed: 8, ..config.clone() };
    assert!(collect(&other, dir.path(), |_, _| {}).is_err(), "a folder of another config must be refused");

    let set = load_collection(dir.path()).unwrap();
    assert_eq!(set.episodes.len(), 6, "two shards of three episodes");
    assert_eq!(set.maps.len(), 2);
    assert!(set.episodes.iter().all(|e| e.poses.len() == 4 && e.grids.len() == 4 * 56 * 56));
    assert_eq!(set.depth_columns, 56, "the depth strips come back");
    assert!(
        set.episodes
            .iter()
            .all(|e| e.depths.len() == 4 * 56 && e.depths.iter().all(|d| (0.1..=10.0).contains(d)))
    );
}

#[test]
fn every_shipped_train_pfnet_config_loads_and_checks() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).expect("scenes/ exists") {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with("train_pfnet") && name.ends_with(".ron") {
            let config: TrainPfNetConfig =
                apfn::compose::read_ron(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
            config.check().unwrap_or_else(|e| panic!("{name}: {e}"));
            checked += 1;
        }
    }
    assert!(checked >= 2, "scenes/ holds the pretraining and the cached fine-tuning configs");
}
