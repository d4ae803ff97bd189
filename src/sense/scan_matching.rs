//! Scan matching (beyond the paper): narrows the wheels' heading change by aligning each LiDAR
//! scan with the one before, as real robots refine wheel odometry with laser odometry. A
//! correlative search (Olson 2009) over the heading alone: the paper's odometry errs by 5° a step
//! in heading and 1 cm in position, and a heading error turns into position error as the robot
//! drives on, fastest where a learned likelihood resolves heading worst (open halls).
//!
//! Only the two scans and the wheels' motion are used, never the map or the true pose. Where the
//! scans overlap too little (open floor out of range, the first step of an episode, a kidnapped
//! robot), the wheels' heading stands and the transition keeps its own noise. Measured: it takes a
//! tenth to a fifth off the wide-view PF-net's error in open halls, and costs the one-view one
//! position in apartments, whose particles' headings it leaves too alike to choose among
//! (`docs/results/scan_matching/`).

use crate::episode::EpisodeStart;
use crate::params::{StepParams, expect_param};
use crate::sense::{LidarScan, Odometry};
use crate::world::{Pose2, wrap_angle};
use bevy::prelude::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Room beyond the previous scan's reach for the next scan's hits after one step's motion, metres.
const MARGIN_M: f32 = 1.0;
/// Most cells a side of a match field (64 MB of f32).
const MAX_FIELD_SIDE: usize = 4096;

/// How far around the wheels' heading change to search, and when a match is trusted.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ScanMatchingParams {
    /// Half-width of the searched heading corrections, degrees (15: three σ of the paper's 5°).
    pub search_deg: f32,
    /// Spacing of the searched corrections, degrees; the best is refined between its neighbours.
    pub resolution_deg: f32,
    /// Cell side of the previous scan's match field, metres: a hit scores by its distance to the
    /// nearest previous hit, on a Gaussian of this width.
    pub cell_m: f32,
    /// Least mean score (0–1) of the scan's hits at the best correction for the match to be used.
    pub min_score: f32,
    /// Least hits in each scan for a match to be tried.
    pub min_hits: usize,
    /// Hits farther than this are left out, metres: the match field spans twice this (plus a
    /// step's motion) at `cell_m`, so a recorded scan's long range cannot make it huge.
    pub max_range_m: f32,
    /// Std-dev of a matched heading change's error, degrees: what the transition draws instead of
    /// its own `rot_noise_deg` at a matched step.
    pub matched_rot_noise_deg: f32,
}

impl Default for ScanMatchingParams {
    fn default() -> Self {
        Self {
            search_deg: 15.0,
            resolution_deg: 0.25,
            cell_m: 0.05,
            min_score: 0.5,
            min_hits: 20,
            max_range_m: 10.0,
            matched_rot_noise_deg: 0.5,
        }
    }
}

impl StepParams for ScanMatchingParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.search_deg > 0.0 && self.search_deg <= 180.0, "search_deg", "a value in (0, 180]")?;
        expect_param(
            self.resolution_deg > 0.0 && self.resolution_deg <= self.search_deg,
            "resolution_deg",
            "a value in (0, search_deg]",
        )?;
        expect_param(self.cell_m >= 0.005 && self.cell_m <= 1.0, "cell_m", "a cell side in [0.005, 1] m")?;
        expect_param((0.0..=1.0).contains(&self.min_score), "min_score", "a value in [0, 1]")?;
        expect_param(self.min_hits >= 3, "min_hits", "at least 3")?;
        expect_param(
            self.max_range_m > 0.0
                && 2.0 * (self.max_range_m + MARGIN_M) / self.cell_m <= MAX_FIELD_SIDE as f32,
            "max_range_m",
            "a range > 0 whose field fits 4,096 cells a side: 2 × (max_range_m + 1 m) / cell_m ≤ 4096",
        )?;
        expect_param(self.matched_rot_noise_deg >= 0.0, "matched_rot_noise_deg", "a std-dev ≥ 0°")
    }
}

/// The previous scan as a match field in that step's robot frame: each cell holds
/// exp(−d² / 2σ²) of its distance d to the nearest hit (σ = one cell), zero beyond three cells.
#[derive(Component, Clone, Debug, Default)]
pub struct ScanMemory {
    field: Vec<f32>,
    /// Cells per side; the field covers ±`half_m` around the robot.
    side: usize,
    half_m: f32,
    cell_m: f32,
    hits: usize,
}

/// Hit points of `scan` in the robot frame: rays that ended before the scan's range limit and
/// within `max_range_m`.
pub fn scan_hits(scan: &LidarScan, max_range_m: f32) -> Vec<[f32; 2]> {
    let (a0, da) = (scan.angle_min_rad, scan.angle_increment_rad);
    let far = (scan.range_max_m - 1e-4).min(max_range_m);
    scan.ranges_m
        .iter()
        .enumerate()
        .filter(|&(_, &r)| r < far && r > scan.range_min_m)
        .map(|(i, &r)| {
            let a = a0 + i as f32 * da;
            [r * a.cos(), r * a.sin()]
        })
        .collect()
}

impl ScanMemory {
    /// Rebuilds the field from `points` (robot frame, within `range_m` of the robot), reusing its
    /// buffer.
    pub fn remember(&mut self, points: &[[f32; 2]], range_m: f32, cell_m: f32) {
        self.half_m = range_m + MARGIN_M;
        self.cell_m = cell_m;
        self.side = (2.0 * self.half_m / cell_m).ceil() as usize;
        self.hits = points.len();
        self.field.clear();
        self.field.resize(self.side * self.side, 0.0);
        const REACH: i64 = 3;
        for p in points {
            let (cx, cy) = ((p[0] + self.half_m) / cell_m, (p[1] + self.half_m) / cell_m);
            let (ci, cj) = (cy.floor() as i64, cx.floor() as i64);
            for i in ci - REACH..=ci + REACH {
                for j in cj - REACH..=cj + REACH {
                    if i < 0 || j < 0 || i >= self.side as i64 || j >= self.side as i64 {
                        continue;
                    }
                    // Distance, in cells, from the hit to the cell's centre.
                    let (dx, dy) = (j as f32 + 0.5 - cx, i as f32 + 0.5 - cy);
                    let value = (-(dx * dx + dy * dy) / 2.0).exp();
                    let cell = &mut self.field[i as usize * self.side + j as usize];
                    *cell = cell.max(value);
                }
            }
        }
    }

    /// The field at a point of the remembered frame, bilinear between cell centres; 0 outside.
    fn at(&self, p: [f32; 2]) -> f32 {
        let (x, y) = ((p[0] + self.half_m) / self.cell_m - 0.5, (p[1] + self.half_m) / self.cell_m - 0.5);
        let (j, i) = (x.floor(), y.floor());
        if i < 0.0 || j < 0.0 || i + 1.0 >= self.side as f32 || j + 1.0 >= self.side as f32 {
            return 0.0;
        }
        let (fx, fy, i, j) = (x - j, y - i, i as usize, j as usize);
        let row = |i: usize| &self.field[i * self.side + j..i * self.side + j + 2];
        let (top, bottom) = (row(i), row(i + 1));
        (top[0] * (1.0 - fx) + top[1] * fx) * (1.0 - fy) + (bottom[0] * (1.0 - fx) + bottom[1] * fx) * fy
    }

    /// Mean field value of `points` (this step's frame) moved into the remembered frame by `motion`.
    fn score(&self, points: &[[f32; 2]], motion: &Pose2) -> f32 {
        let (s, c) = motion.yaw.sin_cos();
        let sum: f32 = points
            .iter()
            .map(|p| self.at([motion.x + c * p[0] - s * p[1], motion.y + s * p[0] + c * p[1]]))
            .sum();
        sum / points.len() as f32
    }
}

/// The heading correction that best aligns `points` with `memory` given the wheels' `delta`, and
/// its score: a grid search, then the peak of the parabola through the best and its neighbours.
pub fn match_heading(
    memory: &ScanMemory,
    points: &[[f32; 2]],
    delta: &Pose2,
    params: &ScanMatchingParams,
) -> (f32, f32) {
    let (step, half) = (params.resolution_deg.to_radians(), params.search_deg.to_radians());
    let count = (half / step).round() as i64;
    let score_at = |k: i64| memory.score(points, &Pose2::new(delta.x, delta.y, delta.yaw + k as f32 * step));
    let scores: Vec<f32> = (-count..=count).map(score_at).collect();
    let best = scores.iter().enumerate().fold(0, |b, (i, s)| if *s > scores[b] { i } else { b });
    let offset = match (best.checked_sub(1).map(|i| scores[i]), scores.get(best + 1)) {
        (Some(left), Some(&right)) => {
            let curvature = left - 2.0 * scores[best] + right;
            if curvature < 0.0 { 0.5 * (left - right) / curvature } else { 0.0 }
        }
        _ => 0.0,
    };
    let k = (best as i64 - count) as f32 + offset;
    (k * step, scores[best])
}

/// Reads LidarScan, Odometry, EpisodeStart, ScanMatchingParams. Writes Odometry (its heading
/// change and that change's error where a match is used), ScanMemory (inserted on first sight).
pub fn scan_matching(
    params: Res<ScanMatchingParams>,
    mut robots: Query<(Entity, &LidarScan, &mut Odometry, Option<&mut ScanMemory>, Has<EpisodeStart>)>,
    mut commands: Commands,
) {
    let matched_std = params.matched_rot_noise_deg.to_radians();
    let mut work: Vec<_> = robots.iter_mut().collect();
    let fresh: Vec<(Entity, ScanMemory)> = work
        .par_iter_mut()
        .filter_map(|(robot, scan, odometry, memory, starts)| {
            let points = scan_hits(scan, params.max_range_m);
            odometry.yaw_std_rad = None;
            match memory {
                Some(memory) => {
                    let usable =
                        !*starts && points.len() >= params.min_hits && memory.hits >= params.min_hits;
                    if usable {
                        let (correction, score) = match_heading(memory, &points, &odometry.delta, &params);
                        if score >= params.min_score {
                            odometry.delta.yaw = wrap_angle(odometry.delta.yaw + correction);
                            odometry.yaw_std_rad = Some(matched_std);
                        }
                    }
                    memory.remember(&points, params.max_range_m.min(scan.range_max_m), params.cell_m);
                    None
                }
                None => {
                    let mut memory = ScanMemory::default();
                    memory.remember(&points, params.max_range_m.min(scan.range_max_m), params.cell_m);
                    Some((*robot, memory))
                }
            }
        })
        .collect();
    for (robot, memory) in fresh {
        commands.entity(robot).insert(memory);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sense::{LidarParams, RayGrid, lidar};
    use crate::testing::tiny_room;
    use crate::world::{OnMap, RobotParams, SensorRng, TruePose};
    use bevy::ecs::system::RunSystemOnce;

    /// A robot in `tiny_room` with its LiDAR and wheels, the scan-matching step's resources.
    fn room_world(pose: Pose2) -> (World, Entity) {
        let mut world = World::new();
        world.insert_resource(LidarParams::default());
        world.insert_resource(RobotParams::default());
        world.insert_resource(ScanMatchingParams::default());
        let map = world.spawn(RayGrid::from_map(&tiny_room())).id();
        let robot = world
            .spawn((
                TruePose(pose),
                OnMap(map),
                LidarScan::default(),
                Odometry::default(),
                SensorRng::seeded(3),
            ))
            .id();
        (world, robot)
    }

    /// Moves the robot by `truth`, reports `reported` as the wheels' motion, scans and matches.
    fn drive(world: &mut World, robot: Entity, truth: Pose2, reported: Pose2) -> Odometry {
        let pose = world.get::<TruePose>(robot).expect("pose").0.compose(&truth);
        world.get_mut::<TruePose>(robot).expect("pose").0 = pose;
        world.get_mut::<Odometry>(robot).expect("odometry").delta = reported;
        world.run_system_once(lidar).expect("lidar runs");
        world.run_system_once(scan_matching).expect("scan matching runs");
        *world.get::<Odometry>(robot).expect("odometry")
    }

    #[test]
    fn scan_matching_corrects_the_wheels_heading_change() {
        // tiny_room's free area is x ∈ [0.1, 1.9], y ∈ [0.1, 1.4].
        let (mut world, robot) = room_world(Pose2::new(0.7, 0.6, 0.3));
        world.run_system_once(lidar).expect("lidar runs");
        world.run_system_once(scan_matching).expect("the first scan is remembered");
        assert!(world.get::<ScanMemory>(robot).is_some(), "memory inserted on first sight");
        for (truth, error_deg) in
            [(Pose2::new(0.15, 0.03, 0.07), 7.0), (Pose2::new(0.1, -0.02, -0.12), -11.0)]
        {
            let reported = Pose2::new(truth.x, truth.y, truth.yaw + f32::to_radians(error_deg));
            let odometry = drive(&mut world, robot, truth, reported);
            let residual = (odometry.delta.yaw - truth.yaw).to_degrees();
            assert!(residual.abs() < 0.3, "{error_deg}° off the wheels, {residual}° off after matching");
            assert_eq!(odometry.yaw_std_rad, Some(0.5f32.to_radians()), "a matched step says how well");
        }
    }

    #[test]
    fn without_a_previous_scan_to_match_the_wheels_stand() {
        let (mut world, robot) = room_world(Pose2::new(0.7, 0.6, 0.3));
        world.run_system_once(lidar).expect("lidar runs");
        world.run_system_once(scan_matching).expect("remembered");
        let (truth, reported) = (Pose2::new(0.1, 0.0, 0.05), Pose2::new(0.1, 0.0, 0.15));
        // A new episode: the last scan was taken somewhere else.
        world.entity_mut(robot).insert(EpisodeStart);
        let odometry = drive(&mut world, robot, truth, reported);
        assert_eq!((odometry.delta, odometry.yaw_std_rad), (reported, None), "an episode's first step");
        world.entity_mut(robot).remove::<EpisodeStart>();
        // Every ray out of range (open floor): nothing to align.
        world.insert_resource(LidarParams { range_max_m: 0.08, ..LidarParams::default() });
        drive(&mut world, robot, truth, reported);
        let odometry = drive(&mut world, robot, truth, reported);
        assert_eq!((odometry.delta, odometry.yaw_std_rad), (reported, None), "no hits in either scan");
    }

    #[test]
    fn scan_matching_params_are_checked_by_name() {
        let bad = ScanMatchingParams { resolution_deg: 20.0, ..ScanMatchingParams::default() };
        assert!(bad.check().unwrap_err().contains("resolution_deg"));
        let bad = ScanMatchingParams { min_hits: 1, ..ScanMatchingParams::default() };
        assert!(bad.check().unwrap_err().contains("min_hits"));
        let bad = ScanMatchingParams { max_range_m: 1e9, ..ScanMatchingParams::default() };
        assert!(bad.check().unwrap_err().contains("max_range_m"), "a field of 10¹⁰ cells a side is refused");
        assert_eq!(ScanMatchingParams::default().check(), Ok(()));
    }
}
