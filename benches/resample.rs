//! Soft (α = 0.5) and hard (α = 1) resampling, and the pose estimate, for 300 and 3,000 particles
//! (the tracking and global task sizes); KLD-sampling resampling (nav2's 500–2,000) of 2,000
//! particles spread over a 10 × 8 m map (keeps 2,000) and converged within 0.2 m (shrinks to 500).
//! Throughput counts input particles.

use apfn::particles::{KldParams, ParticleSet, estimate_pose, resample_kld, resample_soft};
use apfn::world::Pose2;
use apfn::world::rng::stream;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::Rng;
use std::hint::black_box;

/// `n` particles uniform over `side_m` × 0.8·`side_m` and headings within ±0.31·`side_m` rad (all
/// headings at 10 m, a few degrees at 0.2 m), with random weights.
fn weighted_set(n: usize, side_m: f32) -> ParticleSet {
    let mut rng = stream(&[7, n as u64]);
    let poses: Vec<Pose2> = (0..n)
        .map(|_| {
            let (x, y) = (rng.random_range(0.0..side_m), rng.random_range(0.0..0.8 * side_m));
            Pose2::new(x, y, rng.random_range(-3.1..3.1) * side_m / 10.0)
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
        let base = weighted_set(n, 10.0);
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
    let kld = KldParams::default();
    group.throughput(Throughput::Elements(kld.max_particles as u64));
    for (name, side_m) in [("kld_spread", 10.0), ("kld_converged", 0.2)] {
        let base = weighted_set(kld.max_particles, side_m);
        group.bench_with_input(BenchmarkId::new(name, kld.max_particles), &base, |b, base| {
            let mut rng = stream(&[2]);
            b.iter_batched_ref(
                || base.clone(),
                |set| resample_kld(set, 0.5, &kld, &mut rng),
                criterion::BatchSize::SmallInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
