//! Scan matching's cost per robot and step: remembering the previous scan as a match field and
//! searching ±15° at 0.25° for the heading change, on the real nav2 depot map (the open hall it
//! is for) and on procedural apartment 0, between scans 0.2 m and 6° apart with the wheels 5° off.
//!
//! `cargo bench --bench scan_matching -- --warm-up-time 1 --measurement-time 3`

use apfn::sense::{
    LidarParams, LidarScan, RayGrid, ScanMatchingParams, ScanMemory, cast_scan, match_heading, scan_hits,
};
use apfn::world::map::procedural::{ApartmentParams, generate_apartment};
use apfn::world::map::{TraversableMap, load_ros_map};
use apfn::world::{OccupancyMap, Pose2, RobotParams};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use std::hint::black_box;
use std::path::Path;

const POSES: usize = 64;

/// A scan's hit points in its robot frame.
type Hits = Vec<[f32; 2]>;

/// The nav2 depot, loaded as users load it; `None` (with a message) when ../shared is absent.
fn depot() -> Option<OccupancyMap> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/maps/nav2_depot.yaml");
    load_ros_map(&path).inspect_err(|e| eprintln!("scan_matching/depot skipped: {e}")).ok()
}

fn bench_map(c: &mut Criterion, name: &str, map: &OccupancyMap) {
    let traversable = TraversableMap::build(map, RobotParams::default().radius_m).expect("free space");
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let (grid, lidar, params) =
        (RayGrid::from_map(map), LidarParams::default(), ScanMatchingParams::default());
    let motion = Pose2::new(0.2, 0.0, 6f32.to_radians());
    let wheels = Pose2::new(motion.x, motion.y, motion.yaw + 5f32.to_radians());
    let scans: Vec<(Hits, Hits)> = (0..POSES)
        .map(|_| {
            let pose = traversable.sample_pose(map, &mut rng);
            let scan = |at: Pose2| {
                let mut scan = LidarScan::default();
                cast_scan(&grid, at, &[], &lidar, &mut scan);
                scan_hits(&scan, params.max_range_m)
            };
            (scan(pose), scan(pose.compose(&motion)))
        })
        .collect();
    let mut memory = ScanMemory::default();
    let mut group = c.benchmark_group(format!("scan_matching/{name}"));
    group.throughput(Throughput::Elements(POSES as u64));
    group.bench_function("remember_and_match", |b| {
        b.iter(|| {
            for (before, after) in &scans {
                memory.remember(before, lidar.range_max_m, params.cell_m);
                black_box(match_heading(&memory, black_box(after), &wheels, &params));
            }
        })
    });
    group.finish();
}

fn bench(c: &mut Criterion) {
    if let Some(map) = depot() {
        bench_map(c, "depot", &map);
    }
    bench_map(c, "apartment", &generate_apartment(0, &ApartmentParams::default()));
}

criterion_group!(benches, bench);
criterion_main!(benches);
