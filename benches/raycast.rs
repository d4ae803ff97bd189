//! Ray casting throughput (rays/s): the accelerated grid caster against the plain DDA, on the
//! real nav2 depot map and on a synthetic apartment. Fans of 228 rays (the paper's LiDAR) from
//! seeded random free poses, single-threaded and as a rayon batch of 64 robots.
//!
//! `cargo bench --bench raycast -- --warm-up-time 1 --measurement-time 3`

use apfn::sense::{RayGrid, cast_reference};
use apfn::world::{Cell, OccupancyMap, Pose2};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
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

/// The depot map read straight from its PGM (trinary, 0.05 m, occupied > 0.65, free < 0.25).
fn depot() -> Option<OccupancyMap> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/maps/nav2_depot.pgm");
    let img = match image::open(&path) {
        Ok(img) => img.to_luma8(),
        Err(e) => {
            eprintln!("raycast/depot skipped: cannot read {} ({e})", path.display());
            return None;
        }
    };
    let (w, h) = (img.width() as usize, img.height() as usize);
    let mut map = OccupancyMap::filled(w, h, 0.05, Cell::Unknown);
    for (col, row, px) in img.enumerate_pixels() {
        let occ = (255.0 - f32::from(px.0[0])) / 255.0;
        let cell = if occ > 0.65 {
            Cell::Occupied
        } else if occ < 0.25 {
            Cell::Free
        } else {
            Cell::Unknown
        };
        map.set(col as usize, h - 1 - row as usize, cell);
    }
    Some(map)
}

/// A 12 m × 10 m apartment at 0.05 m: outer walls, four rooms and a corridor with doors,
/// furniture blocks, an unknown closet.
fn apartment() -> OccupancyMap {
    let (w, h) = (240, 200);
    let mut map = OccupancyMap::filled(w, h, 0.05, Cell::Free);
    let mut rect = |i0: usize, j0: usize, i1: usize, j1: usize, cell: Cell| {
        for j in j0..j1 {
            for i in i0..i1 {
                map.set(i, j, cell);
            }
        }
    };
    use Cell::{Occupied as O, Unknown as U};
    rect(0, 0, w, 3, O);
    rect(0, h - 3, w, h, O);
    rect(0, 0, 3, h, O);
    rect(w - 3, 0, w, h, O);
    // Corridor along y ∈ [4.5, 5.5] m between two rows of rooms, doors 0.9 m wide.
    rect(3, 88, 40, 91, O);
    rect(58, 88, 150, 91, O);
    rect(168, 88, w - 3, 91, O);
    rect(3, 110, 60, 113, O);
    rect(78, 110, 180, 113, O);
    rect(198, 110, w - 3, 113, O);
    // Room dividers with doors near the corridor.
    rect(100, 3, 103, 70, O);
    rect(170, 3, 173, 70, O);
    rect(120, 130, 123, h - 3, O);
    // Furniture: a table, a sofa, a bed, a kitchen counter; an unmapped closet.
    rect(40, 30, 64, 46, O);
    rect(130, 20, 160, 30, O);
    rect(20, 150, 70, 185, O);
    rect(140, 180, 230, 196, O);
    rect(200, 20, 235, 50, U);
    map
}

/// Seeded poses on free cells at least `margin` cells from anything non-free.
fn free_poses(map: &OccupancyMap, n: usize, seed: u64) -> Vec<Pose2> {
    let margin = 4i64;
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut poses = Vec::with_capacity(n);
    while poses.len() < n {
        let (i, j) = (rng.random_range(0..map.width) as i64, rng.random_range(0..map.height) as i64);
        let clear = (-margin..=margin).all(|dj| {
            (-margin..=margin).all(|di| {
                let (a, b) = (i + di, j + dj);
                a >= 0
                    && b >= 0
                    && (a as usize) < map.width
                    && (b as usize) < map.height
                    && map.get(a as usize, b as usize) == Cell::Free
            })
        });
        if clear {
            let (x, y) = map.cell_center(i as usize, j as usize);
            poses.push(Pose2::new(x, y, rng.random_range(-PI..PI)));
        }
    }
    poses
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
    bench_map(c, "apartment", &apartment());
    if let Some(map) = depot() {
        bench_map(c, "depot", &map);
    }
}

criterion_group!(benches, raycast);
criterion_main!(benches);
