//! Ray casting throughput (rays/s): the accelerated grid caster against the plain DDA, on the
//! real nav2 depot map and on procedural apartment 0. Fans of 228 rays (the paper's LiDAR) from
//! seeded random free poses, single-threaded and as a rayon batch of 64 robots.
//!
//! `cargo bench --bench raycast -- --warm-up-time 1 --measurement-time 3`

use apfn::sense::{RayGrid, cast_reference};
use apfn::world::map::procedural::{ApartmentParams, generate_apartment};
use apfn::world::map::{TraversableMap, load_ros_map};
use apfn::world::{OccupancyMap, Pose2, RobotParams};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use std::f32::consts::PI;
use std::hint::black_box;
use std::path::Path;

const RAYS: usize = 228;
const FOV: f32 = 240.0 * PI / 180.0;
const MAX_RANGE_M: f32 = 5.6;
const POSES: usize = 256;
const BATCH: usize = 64;

/// The nav2 depot, loaded as users load it; `None` (with a message) when ../shared is absent.
fn depot() -> Option<OccupancyMap> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/maps/nav2_depot.yaml");
    load_ros_map(&path).inspect_err(|e| eprintln!("raycast/depot skipped: {e}")).ok()
}

/// Seeded poses where a robot may stand (the traversable map), as the LiDAR sees them.
fn free_poses(map: &OccupancyMap, n: usize, seed: u64) -> Vec<Pose2> {
    let traversable =
        TraversableMap::build(map, RobotParams::default().radius_m).expect("bench maps have free space");
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    (0..n).map(|_| traversable.sample_pose(map, &mut rng)).collect()
}

fn bench_map(c: &mut Criterion, name: &str, map: &OccupancyMap) {
    let grid = RayGrid::from_map(map);
    let poses = free_poses(map, POSES, 7);
    let (amin, inc) = (-FOV / 2.0, FOV / (RAYS - 1) as f32);
    let mut group = c.benchmark_group(format!("raycast/{name}"));

    group.throughput(Throughput::Elements((POSES * RAYS) as u64));
    let mut out = vec![0.0f32; RAYS];
    group.bench_function("fan_228", |b| {
        b.iter(|| {
            for &pose in &poses {
                grid.cast_fan(black_box(pose), amin, inc, MAX_RANGE_M, &[], &mut out);
                black_box(&out);
            }
        })
    });
    group.bench_function("reference_dda", |b| {
        b.iter(|| {
            for &pose in &poses {
                for (k, r) in out.iter_mut().enumerate() {
                    let angle = pose.yaw + amin + k as f32 * inc;
                    *r = cast_reference(map, black_box(pose.x), pose.y, angle, MAX_RANGE_M);
                }
                black_box(&out);
            }
        })
    });

    group.throughput(Throughput::Elements((BATCH * RAYS) as u64));
    let mut scans = vec![vec![0.0f32; RAYS]; BATCH];
    let batch = &poses[..BATCH];
    group.bench_function("batch_64x228_rayon", |b| {
        b.iter(|| {
            scans.par_iter_mut().zip(batch).for_each(|(scan, &pose)| {
                grid.cast_fan(black_box(pose), amin, inc, MAX_RANGE_M, &[], scan);
            });
            black_box(&scans);
        })
    });
    // Other robots as discs (63 per robot) on top of the grid: the `robots_block` LiDAR option.
    let discs: Vec<(f32, f32, f32)> = batch.iter().map(|p| (p.x, p.y, 0.18)).collect();
    group.bench_function("batch_64x228_rayon_discs", |b| {
        b.iter(|| {
            scans.par_iter_mut().zip(batch).for_each(|(scan, &pose)| {
                grid.cast_fan(black_box(pose), amin, inc, MAX_RANGE_M, &discs, scan);
            });
            black_box(&scans);
        })
    });
    group.finish();
}

fn raycast(c: &mut Criterion) {
    bench_map(c, "apartment", &generate_apartment(0, &ApartmentParams::default()));
    if let Some(map) = depot() {
        bench_map(c, "depot", &map);
    }
}

criterion_group!(benches, raycast);
criterion_main!(benches);
