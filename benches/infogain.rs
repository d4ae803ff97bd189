//! One decision of the information-gain policy (`agent::score_candidates` with the default
//! `InfogainParams`: 10 primitives × 2 steps × 8 hypotheses × 200 particles × 24 beams) for one
//! robot on procedural apartment 0, on one core (a one-thread rayon pool), for the global task's
//! 3,000-particle belief: fresh (uniform) and after one likelihood-field update (multi-modal),
//! and the latter with 8 reach plans of 6 steps added to the primitives.
//! The budget is 10 ms per robot and step.
//!
//! `cargo bench --bench infogain -- --warm-up-time 1 --measurement-time 3`

use apfn::act::PhysicsParams;
use apfn::agent::{InfogainParams, MapView, Models, score_candidates};
use apfn::particles::{
    InitParams, LikelihoodFieldParams, Task, TransitionParams, draw_initial_set, weigh_likelihood_field,
};
use apfn::sense::{LidarParams, LidarScan, RayGrid, cast_scan};
use apfn::world::RobotParams;
use apfn::world::map::procedural::{ApartmentParams, generate_apartment};
use apfn::world::map::{DistanceField, TraversableMap};
use apfn::world::rng::stream;
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let robot = RobotParams::default();
    let map = generate_apartment(0, &ApartmentParams::default());
    let (grid, field) = (RayGrid::from_map(&map), DistanceField::build(&map));
    let traversable = TraversableMap::build(&map, robot.radius_m).expect("apartment 0 has room");
    let view = MapView { map: &map, grid: &grid, field: &field, traversable: &traversable };
    let mut rng = stream(&[2026]);
    let truth = traversable.sample_pose(&map, &mut rng);
    let init = InitParams { task: Task::Global, ..Default::default() };
    let fresh = draw_initial_set(&init, &truth, &map, &traversable, &mut rng).expect("global draw").set;
    assert_eq!(fresh.len(), 3000, "the global task's paper count");
    let (lidar, likelihood, transition, physics) = (
        LidarParams::default(),
        LikelihoodFieldParams::default(),
        TransitionParams::default(),
        PhysicsParams::default(),
    );
    let mut scan = LidarScan::default();
    cast_scan(&grid, truth, &[], &lidar, &mut scan);
    let mut updated = fresh.clone();
    weigh_likelihood_field(&mut updated, &scan, &field, &map.origin, &likelihood).expect("valid field");
    let models = Models {
        lidar: &lidar,
        likelihood: &likelihood,
        transition: &transition,
        robot: &robot,
        physics: &physics,
    };
    let primitives = InfogainParams::default();
    let reach = InfogainParams { reach_headings: 8, ..Default::default() };
    let one_core = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("thread pool");
    let mut group = c.benchmark_group("infogain");
    for (name, set, params) in [
        ("global_3000_fresh", &fresh, &primitives),
        ("global_3000_after_update", &updated, &primitives),
        ("global_3000_after_update_reach_8", &updated, &reach),
    ] {
        group.bench_function(name, |b| {
            let mut key = 0u64;
            b.iter(|| {
                key += 1;
                one_core.install(|| black_box(score_candidates(set, view, models, params, key)).is_ok())
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
