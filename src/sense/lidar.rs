//! Planar LiDAR: 228 rays over 240°, 0.05–5.6 m (the paper's sensor), cast on the fine grid.

use crate::params::{StepParams, expect_param};
use crate::sense::raycast::RayGrid;
use crate::world::{OnMap, Pose2, RobotParams, SensorRng, TruePose};
use bevy::prelude::*;
use rand::Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One scan, with the fields of a ROS LaserScan. Rays run counter-clockwise from `angle_min_rad`
/// in the robot frame (0 = straight ahead). A ray that hits nothing reads `range_max_m`.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct LidarScan {
    pub ranges_m: Vec<f32>,
    pub angle_min_rad: f32,
    pub angle_increment_rad: f32,
    pub range_min_m: f32,
    pub range_max_m: f32,
}

/// The simulated planar LiDAR. Ray i points at `−fov/2 + i · fov/(rays − 1)` in the robot frame.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct LidarParams {
    /// Number of rays (paper / reference code: 228).
    pub rays: usize,
    /// Field of view centred on the heading, degrees (paper: 240).
    pub fov_deg: f32,
    /// Shortest reported range, metres (paper: 0.05).
    pub range_min_m: f32,
    /// Longest reported range; misses read this, metres (paper: 5.6).
    pub range_max_m: f32,
    /// Std-dev of additive Gaussian range noise on hits, metres (paper: 0, noise-free).
    pub range_noise_std_m: f32,
    /// Whether the other robots on the same map block rays as discs of `RobotParams::radius_m`
    /// (ours: off, the paper has one robot per map).
    pub robots_block: bool,
}

impl Default for LidarParams {
    fn default() -> Self {
        Self {
            rays: 228,
            fov_deg: 240.0,
            range_min_m: 0.05,
            range_max_m: 5.6,
            range_noise_std_m: 0.0,
            robots_block: false,
        }
    }
}

impl StepParams for LidarParams {
    fn check(&self) -> Result<(), String> {
        crate::limits::BEAMS.check("rays", self.rays)?;
        expect_param(self.fov_deg > 0.0 && self.fov_deg <= 360.0, "fov_deg", "a field of view in (0, 360]")?;
        expect_param(
            self.range_min_m >= 0.0 && self.range_min_m < self.range_max_m,
            "range_min_m, range_max_m",
            "0 ≤ range_min_m < range_max_m",
        )?;
        expect_param(self.range_noise_std_m >= 0.0, "range_noise_std_m", "a std-dev ≥ 0 m")
    }
}

impl LidarParams {
    /// First ray's angle and the spacing between rays, radians, robot frame.
    pub fn angles(&self) -> (f32, f32) {
        let fov = self.fov_deg.to_radians();
        let increment = if self.rays > 1 { fov / (self.rays - 1) as f32 } else { 0.0 };
        (-fov / 2.0, increment)
    }
}

/// Casts one noise-free scan from `pose` into `scan` (ranges and metadata): the kernel of
/// [`lidar`]. `discs` are other robots (x, y, radius), see [`RayGrid::cast_fan`].
pub fn cast_scan(
    grid: &RayGrid,
    pose: Pose2,
    discs: &[(f32, f32, f32)],
    params: &LidarParams,
    scan: &mut LidarScan,
) {
    let (angle_min, increment) = params.angles();
    scan.angle_min_rad = angle_min;
    scan.angle_increment_rad = increment;
    scan.range_min_m = params.range_min_m;
    scan.range_max_m = params.range_max_m;
    scan.ranges_m.resize(params.rays, 0.0);
    grid.cast_fan(pose, angle_min, increment, params.range_max_m, discs, &mut scan.ranges_m);
}

/// Adds N(0, σ²) to every hit (misses stay misses) and clamps all ranges to
/// [range_min, range_max]. Draws nothing when σ = 0, so a noise-free LiDAR leaves the RNG alone.
pub fn noise_and_clamp(scan: &mut LidarScan, std_m: f32, rng: &mut impl Rng) {
    let (lo, hi) = (scan.range_min_m, scan.range_max_m);
    for r in scan.ranges_m.iter_mut() {
        if std_m > 0.0 && *r < hi {
            *r += std_m * rng.sample::<f32, _>(StandardNormal);
        }
        *r = r.clamp(lo, hi.max(lo));
    }
}

/// Reads TruePose, OnMap, the map's RayGrid, SensorRng. Writes LidarScan.
/// Casting runs in parallel across robots (rayon); noise is drawn afterwards robot by robot from
/// each one's SensorRng, so results never depend on the thread count.
pub fn lidar(
    params: Res<LidarParams>,
    robot_params: Res<RobotParams>,
    maps: Query<&RayGrid>,
    mut robots: Query<(Entity, &TruePose, &OnMap, &mut LidarScan, &mut SensorRng)>,
) {
    let bodies: Vec<(Entity, Entity, Pose2)> = robots.iter().map(|(e, p, m, ..)| (e, m.0, p.0)).collect();
    let mut work: Vec<_> = robots
        .iter_mut()
        .filter_map(|(e, pose, on, scan, rng)| match maps.get(on.0) {
            Ok(grid) => Some((e, on.0, pose.0, grid, scan, rng)),
            Err(_) => {
                tracing::warn!(
                    "lidar: map entity {:?} of robot {e:?} has no RayGrid; scan not updated",
                    on.0
                );
                None
            }
        })
        .collect();
    let radius = robot_params.radius_m;
    work.par_iter_mut().for_each(|(e, map, pose, grid, scan, _)| {
        let others = bodies.iter().filter(|(o, m, _)| params.robots_block && o != e && m == map);
        let discs: Vec<_> = others.map(|(_, _, p)| (p.x, p.y, radius)).collect();
        cast_scan(grid, *pose, &discs, &params, scan);
    });
    for (.., scan, rng) in work.iter_mut() {
        noise_and_clamp(scan, params.range_noise_std_m, &mut rng.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use bevy::ecs::system::RunSystemOnce;
    use std::f32::consts::FRAC_PI_2;

    fn spawn_robot(world: &mut World, map: Entity, pose: Pose2, seed: u64) -> Entity {
        world.spawn((TruePose(pose), OnMap(map), LidarScan::default(), SensorRng::seeded(seed))).id()
    }

    #[test]
    fn lidar_casts_the_paper_scan() {
        let mut world = World::new();
        world.insert_resource(LidarParams::default());
        world.insert_resource(RobotParams::default());
        let map = world.spawn(RayGrid::from_map(&tiny_room())).id();
        // tiny_room: inner free area x ∈ [0.1, 1.9], y ∈ [0.1, 1.4]; facing +x.
        let robot = spawn_robot(&mut world, map, Pose2::new(0.5, 0.5, 0.0), 1);
        world.run_system_once(lidar).unwrap();
        let scan = world.get::<LidarScan>(robot).unwrap();
        assert_eq!(scan.ranges_m.len(), 228, "paper: 228 rays");
        assert!((scan.angle_min_rad + 120f32.to_radians()).abs() < 1e-6, "fov 240°, centred");
        let last = scan.angle_min_rad + 227.0 * scan.angle_increment_rad;
        assert!((last - 120f32.to_radians()).abs() < 1e-5, "last ray at +120°, got {last}");
        // Ray 0 at −120°; the ray straight right (−90°) hits the bottom wall at y = 0.1.
        let right = ((-FRAC_PI_2 - scan.angle_min_rad) / scan.angle_increment_rad).round() as usize;
        let expected = 0.4 / (scan.angle_min_rad + right as f32 * scan.angle_increment_rad).sin().abs();
        assert!((scan.ranges_m[right] - expected).abs() < 1e-3, "right: {}", scan.ranges_m[right]);
        assert!(scan.ranges_m.iter().all(|r| (0.05..=5.6).contains(r)), "ranges within limits");
    }

    #[test]
    fn lidar_other_robots_block_only_when_asked() {
        let mut world = World::new();
        world.insert_resource(RobotParams::default());
        let map = world.spawn(RayGrid::from_map(&tiny_room())).id();
        let a = spawn_robot(&mut world, map, Pose2::new(0.4, 0.4, 0.0), 1);
        spawn_robot(&mut world, map, Pose2::new(0.9, 0.4, 0.0), 2);
        let params = LidarParams { rays: 3, fov_deg: 180.0, ..LidarParams::default() };
        world.insert_resource(params.clone());
        world.run_system_once(lidar).unwrap();
        let ahead = world.get::<LidarScan>(a).unwrap().ranges_m[1];
        assert!((ahead - 1.5).abs() < 1e-4, "without blocking the wall at 1.9 m is seen: {ahead}");
        world.insert_resource(LidarParams { robots_block: true, ..params });
        world.run_system_once(lidar).unwrap();
        let ahead = world.get::<LidarScan>(a).unwrap().ranges_m[1];
        assert!((ahead - 0.32).abs() < 1e-4, "robot 0.5 m ahead, radius 0.18: got {ahead}");
    }

    #[test]
    fn lidar_noise_is_seeded_and_spares_misses() {
        let run = |seed: u64| {
            let mut world = World::new();
            world.insert_resource(RobotParams::default());
            world.insert_resource(LidarParams { range_noise_std_m: 0.05, range_max_m: 1.0, ..default() });
            let map = world.spawn(RayGrid::from_map(&tiny_room())).id();
            let robot = spawn_robot(&mut world, map, Pose2::new(0.5, 0.5, 0.0), seed);
            world.run_system_once(lidar).unwrap();
            world.get::<LidarScan>(robot).unwrap().ranges_m.clone()
        };
        let (a, b, c) = (run(3), run(3), run(4));
        assert_eq!(a, b, "same seed, same noisy scan");
        assert_ne!(a, c, "different seeds give different noise");
        assert!(a.iter().all(|r| (0.05..=1.0).contains(r)), "noisy ranges are clamped");
        // Straight ahead the wall is 1.4 m away, beyond 1.0 m: a miss must stay exactly max range.
        assert_eq!(a[114], 1.0, "misses are not perturbed");
    }

    #[test]
    fn lidar_noise_std_is_right() {
        let mut scan =
            LidarScan { ranges_m: vec![2.0; 20000], range_min_m: 0.05, range_max_m: 5.6, ..default() };
        noise_and_clamp(&mut scan, 0.1, &mut SensorRng::seeded(5).0);
        let n = scan.ranges_m.len() as f32;
        let mean = scan.ranges_m.iter().sum::<f32>() / n;
        let std = (scan.ranges_m.iter().map(|r| (r - mean).powi(2)).sum::<f32>() / n).sqrt();
        assert!((mean - 2.0).abs() < 0.005 && (std - 0.1).abs() < 0.005, "mean {mean}, std {std}");
    }
}
