//! The APFN agent: one SAC update (batch 256; critics, actor, entropy coefficient, Polyak) of the
//! compact and paper networks, and one whole agent step (`App::update`) with the policy in the
//! loop — sensors, MCL (500 particles, semi-global), belief crop, reward, one batched actor
//! forward for every robot, drive, physics — for 1, 8 and 16 robots on one apartment.
//!
//! `cargo bench --bench sac -- --warm-up-time 1 --measurement-time 5`

use apfn::compose::{Pipeline, Scene, standard_registry};
use apfn::nn::sac::{ACTION_LEN, Observations, SacHyper, SacLearner, SacNetConfig, SacNetworks, Transitions};
use apfn::plugin::headless_app;
use apfn::world::map::procedural::Split;
use apfn::world::rng::stream;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::Rng;
use std::path::Path;

fn update(c: &mut Criterion) {
    let mut group = c.benchmark_group("sac_update");
    group.sample_size(10);
    let n = 256;
    for (name, config) in [("compact", SacNetConfig::compact()), ("paper", SacNetConfig::paper())] {
        let mut learner = SacLearner::new(SacNetworks::new(&config, 0), SacHyper::default());
        let mut rng = stream(&[1]);
        let mut uniform = |len: usize| (0..len).map(|_| rng.random::<f32>()).collect::<Vec<f32>>();
        let (bl, gl) = (config.belief_channels * config.belief_cells.pow(2), config.grid_cells.pow(2));
        let images = [uniform(n * bl), uniform(n * gl), uniform(n * bl), uniform(n * gl)];
        let states = [uniform(n * config.state_len()), uniform(n * config.state_len())];
        let (actions, rewards, dones) = (uniform(n * ACTION_LEN), uniform(n), vec![0.0; n]);
        let noise = uniform(2 * n * ACTION_LEN);
        let obs = |i: usize| Observations {
            n,
            belief: &images[2 * i],
            grid: &images[2 * i + 1],
            state: &states[i],
        };
        let batch = Transitions {
            obs: obs(0),
            actions: &actions,
            rewards: &rewards,
            dones: &dones,
            next_obs: obs(1),
        };
        group.throughput(Throughput::Elements(n as u64));
        group.bench_function(BenchmarkId::new("batch_256", name), |b| {
            b.iter(|| learner.update(&batch, &noise))
        });
    }
    group.finish();
}

fn env_step(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("apfn_bench_sac_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let policy = dir.join("policy.safetensors");
    SacNetworks::new(&SacNetConfig::compact(), 0).save(&policy).unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("systems/apfn_eval.ron"))
        .unwrap()
        .replace("models/apfn_compact.safetensors", &policy.display().to_string())
        .replace("task: tracking", "task: semi_global");
    let pipeline = Pipeline::parse(&text, Path::new("apfn_eval.ron"), &standard_registry()).unwrap();
    let mut group = c.benchmark_group("env_step_with_agent");
    for robots in [1usize, 8, 16] {
        let loaded = Scene::apartments(Split::Seen, 0, 1, robots).into_loaded(Path::new("bench")).unwrap();
        let (mut app, _) = headless_app(&loaded, pipeline.clone()).unwrap();
        app.update();
        group.throughput(Throughput::Elements(robots as u64));
        group.bench_function(BenchmarkId::new("robots", robots), |b| b.iter(|| app.update()));
    }
    group.finish();
    let _ = std::fs::remove_dir_all(dir);
}

criterion_group!(benches, update, env_step);
criterion_main!(benches);
