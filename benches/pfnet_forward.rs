//! PF-net (`nn::pfnet`): one filter step's likelihoods for K = 30, 300 and 3,000 particles of
//! one robot on apartment 0 — the paper and compact networks, exact (crop + map encoder per
//! particle) and cached (crop of the map's feature banks), and the shipped map-context network
//! through its first-stage banks (K = 300 and 3,000) — and one training step (batch 8 × T 25 ×
//! K 30: forward, backward, Adam). Throughput counts particles. The first two networks' weights
//! are untrained: the cost does not depend on them.

use apfn::nn::adam::{Adam, AdamConfig};
use apfn::nn::pfnet::{
    FeatureBank, FeatureCacheSpec, GradBuffers, LocalMapSpec, MapInput, PfNet, PfNetConfig, PoseLoss,
    StepBatch, Workspaces, crop_local_maps,
};
use apfn::particles::map_view;
use apfn::world::map::NetworkMap;
use apfn::world::map::procedural::{ApartmentParams, generate_apartment};
use apfn::world::rng::stream;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::Rng;
use std::path::Path;
use std::sync::Arc;

fn likelihoods(c: &mut Criterion) {
    let apartment = generate_apartment(0, &ApartmentParams::default());
    let map = NetworkMap::from_fine(&apartment, 0.1);
    let (width_m, height_m) = apartment.size_m();
    let pool = Workspaces::for_current_pool();
    let mut group = c.benchmark_group("pfnet_likelihoods");
    group.sample_size(10);
    for (name, config) in [("paper", PfNetConfig::paper()), ("compact", PfNetConfig::compact())] {
        let model = PfNet::new(config, 0).expect("a valid config");
        let bank = FeatureBank::build(&model, &map_view(&map), &FeatureCacheSpec::default());
        let mut rng = stream(&[5]);
        let obs: Vec<f32> = (0..model.obs_len()).map(|_| rng.random_range(0..3) as f32 / 2.0).collect();
        let mut obs_terms = vec![0.0; model.obs_term_len()];
        for k in [30, 300, 3000] {
            let xs: Vec<f32> = (0..k).map(|_| rng.random_range(0.0..width_m)).collect();
            let ys: Vec<f32> = (0..k).map(|_| rng.random_range(0.0..height_m)).collect();
            let yaws: Vec<f32> = (0..k).map(|_| rng.random_range(-3.1..3.1)).collect();
            let owner = vec![0u32; k];
            let mut loglik = vec![0.0; k];
            let mut maps = vec![0.0; k * model.local_map_len()];
            let mut features = vec![0.0; k * model.map_feature_len()];
            group.throughput(Throughput::Elements(k as u64));
            group.bench_function(BenchmarkId::new(format!("{name}_exact"), k), |b| {
                b.iter(|| {
                    model.observation_terms_par(&obs, &mut obs_terms, &pool);
                    crop_local_maps(&map_view(&map), &xs, &ys, &yaws, &LocalMapSpec::default(), &mut maps);
                    model.log_likelihoods_exact(&obs_terms, &owner, &maps, &mut loglik, &pool);
                })
            });
            group.bench_function(BenchmarkId::new(format!("{name}_cached"), k), |b| {
                b.iter(|| {
                    // As `pfnet_likelihood`: the observation is encoded while the crops are cut.
                    rayon::join(
                        || model.observation_terms_par(&obs, &mut obs_terms, &pool),
                        || bank.crop_features(&xs, &ys, &yaws, &mut features),
                    );
                    model.log_likelihoods_from_features(&obs_terms, &owner, &features, &mut loglik, &pool);
                })
            });
        }
    }
    group.finish();
}

/// The shipped map-context network (scan laid on its local maps, wide view) through its
/// first-stage banks, as `pfnet_likelihood` with `features: cached` runs it: its banks hold the
/// first stage, so each particle's crop of them goes through the rest of the map encoder.
fn banked_likelihoods(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/pfnet_compact_scan_context.safetensors");
    let model = PfNet::load(&path).expect("the shipped map-context checkpoint");
    let apartment = generate_apartment(0, &ApartmentParams::default());
    let map = NetworkMap::from_fine(&apartment, 0.1);
    let banks = [Arc::new(FeatureBank::build(&model, &map_view(&map), &FeatureCacheSpec::default()))];
    let (width_m, height_m) = apartment.size_m();
    let pool = Workspaces::for_current_pool();
    let mut rng = stream(&[7]);
    let obs: Vec<f32> = (0..model.obs_len()).map(|_| rng.random_range(0..3) as f32 / 2.0).collect();
    let (mut obs_terms, mut scan_terms) = (vec![0.0; model.obs_term_len()], vec![0.0; model.scan_term_len()]);
    let mut group = c.benchmark_group("pfnet_likelihoods");
    group.sample_size(10);
    for k in [300, 3000] {
        let poses: Vec<[f32; 3]> = (0..k)
            .map(|_| {
                [rng.random_range(0.0..width_m), rng.random_range(0.0..height_m), rng.random_range(-3.1..3.1)]
            })
            .collect();
        let (owner, mut loglik) = (vec![0u32; k], vec![0.0; k]);
        group.throughput(Throughput::Elements(k as u64));
        group.bench_function(BenchmarkId::new("compact_scan_context_banked", k), |b| {
            b.iter(|| {
                model.observation_terms_par(&obs, &mut obs_terms, &pool);
                model.scan_terms_par(&obs, &mut scan_terms, &pool);
                let terms = (&obs_terms[..], &scan_terms[..]);
                model.log_likelihoods_banked(terms, &owner, (&poses, &banks), &mut loglik, &pool);
            })
        });
    }
    group.finish();
}

fn training_step(c: &mut Criterion) {
    let (batch, steps, k) = (8, 25, 30);
    let mut group = c.benchmark_group("pfnet_train_step");
    group.sample_size(10);
    for (name, config) in [("paper", PfNetConfig::paper()), ("compact", PfNetConfig::compact())] {
        let mut model = PfNet::new(config, 0).expect("a valid config");
        let n = batch * steps;
        let mut rng = stream(&[6]);
        let mut uniform = |len: usize| (0..len).map(|_| rng.random::<f32>()).collect::<Vec<f32>>();
        let (obs, maps) = (uniform(n * model.obs_len()), uniform(n * k * model.local_map_len()));
        let poses = uniform((n * k + n) * 3);
        let states: Vec<[f32; 3]> = poses[..n * k * 3].chunks(3).map(|p| [p[0], p[1], p[2]]).collect();
        let targets: Vec<[f32; 3]> = poses[n * k * 3..].chunks(3).map(|p| [p[0], p[1], p[2]]).collect();
        let data = StepBatch {
            obs: &obs,
            maps: &maps,
            states: &states,
            targets: &targets,
            k,
            sequence: steps,
            input: MapInput::LocalMaps,
        };
        let loss =
            PoseLoss { weights: [1.0, 1.0, 0.36], wrap_heading: true, scale: 1.0 / n as f32, mixture: None };
        let mut adam = Adam::new(AdamConfig::default(), model.params.len());
        let (mut grads, pool) = (GradBuffers::default(), Workspaces::for_current_pool());
        group.bench_function(format!("{name}_b{batch}_t{steps}_k{k}"), |b| {
            b.iter(|| model.train_step(&data, &loss, &mut adam, &mut grads, &pool))
        });
    }
    group.finish();
}

criterion_group!(benches, likelihoods, banked_likelihoods, training_step);
criterion_main!(benches);
