//! Belief projection (`belief::project_crop` via the crop centres of `belief::belief_modes`): the
//! agent's 4 × 50 × 50 crop for a tracking-sized (300) and a global-sized (3,000) particle set on
//! apartment 0, one crop (the paper's), three (estimate + 2 modes) and one with the 20 m overview
//! (`overview_m: 0.4`, 4 × 4 map samples per cell). Throughput counts particles.

use apfn::belief::{BELIEF_CHANNELS, BeliefParams, belief_modes, project_crop};
use apfn::particles::{ParticleSet, estimate_pose};
use apfn::world::Pose2;
use apfn::world::map::NetworkMap;
use apfn::world::map::procedural::{ApartmentParams, generate_apartment};
use apfn::world::rng::stream;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::Rng;

/// `n` particles spread uniformly over the map's extent, random weights.
fn spread_set(n: usize, width_m: f32, height_m: f32) -> ParticleSet {
    let mut rng = stream(&[9, n as u64]);
    let poses: Vec<Pose2> = (0..n)
        .map(|_| {
            let (x, y) = (rng.random_range(0.0..width_m), rng.random_range(0.0..height_m));
            Pose2::new(x, y, rng.random_range(-3.1..3.1))
        })
        .collect();
    let mut set = ParticleSet::from_poses(&poses);
    set.log_w = (0..n).map(|_| rng.random_range(-4.0..0.0)).collect();
    set.normalise().expect("finite log-weights");
    set
}

fn bench(c: &mut Criterion) {
    let apartment = generate_apartment(0, &ApartmentParams::default());
    let network = NetworkMap::from_fine(&apartment, 0.1);
    let (width_m, height_m) = apartment.size_m();
    let mut group = c.benchmark_group("belief_crop");
    for n in [300, 3000] {
        let set = spread_set(n, width_m, height_m);
        let estimate = estimate_pose(&set).expect("non-empty").pose;
        group.throughput(Throughput::Elements(n as u64));
        for (label, modes, overview_m) in
            [("modes_1", 1, None), ("modes_3", 3, None), ("overview", 1, Some(0.4))]
        {
            let params = BeliefParams { modes, overview_m, ..Default::default() };
            let per_crop = BELIEF_CHANNELS * params.cells * params.cells;
            let mut out = vec![0.0; params.crops_per_step() * per_crop];
            group.bench_with_input(BenchmarkId::new(label, n), &set, |b, set| {
                b.iter(|| {
                    let weights = set.weights();
                    let centres = belief_modes(set, &weights, &estimate, params.modes, params.mode_bin_m);
                    let fine = centres.iter().map(|&centre| (centre, (params.cells, params.resolution_m)));
                    let coarse = params.overview_m.map(|side| (estimate, (params.cells, side)));
                    for ((centre, geometry), crop) in fine.chain(coarse).zip(out.chunks_mut(per_crop)) {
                        project_crop(set, &weights, &network, &centre, geometry, crop);
                    }
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
