//! One whole agent step (`App::update`) of the default pipeline — episode reset, odometry, LiDAR,
//! MCL (300 particles, likelihood field, soft resampling, estimate), metrics, random policy,
//! drive and 6 physics sub-steps — for 1, 8 and 64 robots on one procedural apartment.
//!
//! `cargo bench --bench env_step -- --warm-up-time 1 --measurement-time 3`

use apfn::cli::run::DEFAULT_SYSTEMS;
use apfn::compose::{Pipeline, Scene, standard_registry};
use apfn::plugin::headless_app;
use apfn::world::map::procedural::Split;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use std::path::Path;

fn scene(robots: usize) -> Scene {
    Scene::apartments(Split::Seen, 0, 1, robots)
}

fn env_step(c: &mut Criterion) {
    let registry = standard_registry();
    let pipeline = Pipeline::parse(DEFAULT_SYSTEMS.1, Path::new(DEFAULT_SYSTEMS.0), &registry).unwrap();
    let mut group = c.benchmark_group("env_step");
    for robots in [1usize, 8, 64] {
        let loaded = scene(robots).into_loaded(Path::new("bench")).unwrap();
        let (mut app, _) = headless_app(&loaded, pipeline.clone()).unwrap();
        app.update(); // first step draws the particle sets
        group.throughput(Throughput::Elements(robots as u64));
        group.bench_function(BenchmarkId::new("robots", robots), |b| b.iter(|| app.update()));
    }
    group.finish();
}

criterion_group!(benches, env_step);
criterion_main!(benches);
