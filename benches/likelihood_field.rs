//! Likelihood-field observation update (`particles::weigh_likelihood_field`): 1,000 particles ×
//! 100 beams on a synthetic 12 m × 9 m room at 0.05 m/cell. Throughput counts beam evaluations.

use apfn::particles::{LikelihoodFieldParams, ParticleSet, weigh_likelihood_field};
use apfn::sense::LidarScan;
use apfn::world::map::DistanceField;
use apfn::world::rng::stream;
use apfn::world::{Cell, OccupancyMap, Pose2};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::Rng;
use std::hint::black_box;

const PARTICLES: usize = 1000;
const BEAMS: usize = 100;

/// Outer walls, two interior walls with doors, and a few boxes.
fn room() -> OccupancyMap {
    let (w, h) = (240, 180);
    let mut map = OccupancyMap::filled(w, h, 0.05, Cell::Free);
    for i in 0..w {
        map.set(i, 0, Cell::Occupied);
        map.set(i, h - 1, Cell::Occupied);
    }
    for j in 0..h {
        map.set(0, j, Cell::Occupied);
        map.set(w - 1, j, Cell::Occupied);
        if !(40..60).contains(&j) {
            map.set(100, j, Cell::Occupied);
        }
    }
    for i in 100..w {
        if !(170..190).contains(&i) {
            map.set(i, 110, Cell::Occupied);
        }
    }
    for (i0, j0) in [(30, 30), (150, 40), (60, 130), (200, 150)] {
        for j in j0..j0 + 12 {
            for i in i0..i0 + 16 {
                map.set(i, j, Cell::Occupied);
            }
        }
    }
    map
}

/// A 100-ray 240° scan marched in 5 mm steps; range_max is large so every beam is used.
fn scan(map: &OccupancyMap, pose: Pose2) -> LidarScan {
    let fov = 240f32.to_radians();
    let increment = fov / (BEAMS - 1) as f32;
    let ranges_m = (0..BEAMS)
        .map(|i| {
            let (s, c) = (pose.yaw - fov / 2.0 + i as f32 * increment).sin_cos();
            let mut r = 0.0;
            while map.cell_at_point(pose.x + r * c, pose.y + r * s) == Cell::Free {
                r += 0.005;
            }
            r
        })
        .collect();
    LidarScan {
        ranges_m,
        angle_min_rad: -fov / 2.0,
        angle_increment_rad: increment,
        range_min_m: 0.0,
        range_max_m: 100.0,
    }
}

fn bench(c: &mut Criterion) {
    let map = room();
    let field = DistanceField::build(&map);
    let scan = scan(&map, Pose2::new(2.5, 4.0, 0.4));
    let mut rng = stream(&[2024]);
    let poses: Vec<Pose2> = (0..PARTICLES)
        .map(|_| {
            Pose2::new(rng.random_range(0.1..11.9), rng.random_range(0.1..8.9), rng.random_range(-3.1..3.1))
        })
        .collect();
    let params = LikelihoodFieldParams { max_beams: BEAMS, ..Default::default() };
    let mut group = c.benchmark_group("likelihood_field");
    group.throughput(Throughput::Elements((PARTICLES * BEAMS) as u64));
    group.bench_function("1000_particles_x_100_beams", |b| {
        let mut set = ParticleSet::from_poses(&poses);
        b.iter(|| black_box(weigh_likelihood_field(&mut set, &scan, &field, &map.origin, &params)).is_ok())
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
