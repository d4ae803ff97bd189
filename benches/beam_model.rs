//! Beam (ray-cast) observation update (`particles::weigh_beam_model`) next to the likelihood field
//! (`particles::weigh_likelihood_field`) on the same input: 300 particles × 60 beams (nav2's
//! `max_beams`) of the paper's 228-ray scan on procedural apartment 0. Throughput counts
//! particles × selected beams; the likelihood field skips max-range readings, so it evaluates at
//! most that many (the count used is printed).

use apfn::particles::{
    BeamModelParams, LikelihoodFieldParams, ParticleSet, beam_readings, weigh_beam_model,
    weigh_likelihood_field,
};
use apfn::sense::{LidarParams, LidarScan, RayGrid, cast_scan};
use apfn::world::map::DistanceField;
use apfn::world::map::procedural::generate_apartment;
use apfn::world::rng::stream;
use apfn::world::{Cell, OccupancyMap, Pose2};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::Rng;
use std::hint::black_box;

const PARTICLES: usize = 300;
const BEAMS: usize = 60;

/// `n` seeded poses in free cells of `map`.
fn free_poses(map: &OccupancyMap, n: usize, seed: u64) -> Vec<Pose2> {
    let (w, h) = map.size_m();
    let mut rng = stream(&[seed]);
    let mut poses = Vec::with_capacity(n);
    while poses.len() < n {
        let (x, y) = map.origin.transform_point(rng.random_range(0.0..w), rng.random_range(0.0..h));
        if map.cell_at_point(x, y) == Cell::Free {
            poses.push(Pose2::new(x, y, rng.random_range(-3.1..3.1)));
        }
    }
    poses
}

fn bench(c: &mut Criterion) {
    let map = generate_apartment(0, &Default::default());
    let (grid, field) = (RayGrid::from_map(&map), DistanceField::build(&map));
    let truth = free_poses(&map, 1, 7)[0];
    let mut scan = LidarScan::default();
    cast_scan(&grid, truth, &[], &LidarParams::default(), &mut scan);
    let poses = free_poses(&map, PARTICLES, 2024);
    let beam = BeamModelParams { max_beams: BEAMS, ..Default::default() };
    let field_params = LikelihoodFieldParams { max_beams: BEAMS, ..Default::default() };
    let used = beam_readings(&scan, BEAMS);
    let hits = used.iter().filter(|&&(_, r)| r < scan.range_max_m).count();
    println!("beam_model bench: {} beams used by the beam model, {hits} by the likelihood field", used.len());

    let mut group = c.benchmark_group("beam_model");
    group.throughput(Throughput::Elements((PARTICLES * BEAMS) as u64));
    group.bench_function("beam_300_particles_x_60_beams", |b| {
        let mut set = ParticleSet::from_poses(&poses);
        b.iter(|| black_box(weigh_beam_model(&mut set, &scan, &grid, &beam)).is_ok())
    });
    group.bench_function("likelihood_field_300_particles_x_60_beams", |b| {
        let mut set = ParticleSet::from_poses(&poses);
        b.iter(|| {
            black_box(weigh_likelihood_field(&mut set, &scan, &field, &map.origin, &field_params)).is_ok()
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
