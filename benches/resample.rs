//! Soft (α = 0.5) and hard (α = 1) resampling, and the pose estimate, for 300 and 3,000 particles
//! (the tracking and global task sizes). Throughput counts particles.

use apfn::particles::{ParticleSet, estimate_pose, resample_soft};
use apfn::world::Pose2;
use apfn::world::rng::stream;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::Rng;
use std::hint::black_box;

fn weighted_set(n: usize) -> ParticleSet {
    let mut rng = stream(&[7, n as u64]);
    let poses: Vec<Pose2> = (0..n)
        .map(|_| {
            Pose2::new(rng.random_range(0.0..10.0), rng.random_range(0.0..8.0), rng.random_range(-3.1..3.1))
        })
        .collect();
    let mut set = ParticleSet::from_poses(&poses);
    set.log_w = (0..n).map(|_| rng.random_range(-8.0..0.0)).collect();
    set.normalise().expect("finite log-weights");
    set
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("resample");
    for n in [300, 3000] {
        let base = weighted_set(n);
        group.throughput(Throughput::Elements(n as u64));
        for (name, alpha) in [("soft", 0.5), ("hard", 1.0)] {
            group.bench_with_input(BenchmarkId::new(name, n), &base, |b, base| {
                let mut rng = stream(&[1]);
                b.iter_batched_ref(
                    || base.clone(),
                    |set| resample_soft(set, alpha, &mut rng),
                    criterion::BatchSize::SmallInput,
                )
            });
        }
        group.bench_with_input(BenchmarkId::new("estimate", n), &base, |b, base| {
            b.iter(|| black_box(estimate_pose(black_box(base))))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
