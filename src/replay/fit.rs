//! Do the estimates explain the scans? A scan taken on the map, seen from a good estimate, ends
//! on walls; seen from a wrong estimate, or recorded on another map, it mostly ends in free space
//! or off the map. `apfn localize` runs this check over the log before a user trusts the output.

use crate::sense::LidarScan;
use crate::world::map::DistanceField;
use crate::world::{OccupancyMap, Pose2};

/// How close to an occupied cell a beam must end to count as fitting (AMCL's `sigma_hit`, m).
pub const FIT_TOLERANCE_M: f32 = 0.2;

/// Below this mean fraction of fitting beams over a log, the scans are reported as not fitting.
/// Measured on two 200-scan simulated logs (aws_small_house, nav2_depot) localized on five maps:
/// 0.99–1.00 where the filter tracked the truth on the log's own map; 0.00–0.74 on another map
/// or when the filter was lost.
pub const MIN_FIT: f32 = 0.9;

/// Fraction of the usable beams of `scan` (finite, in [range_min, range_max)) whose endpoint,
/// seen from `pose`, lies within [`FIT_TOLERANCE_M`] of an occupied cell; `None` when no beam is
/// usable.
pub fn scan_fit(scan: &LidarScan, pose: &Pose2, map: &OccupancyMap, field: &DistanceField) -> Option<f32> {
    let ends: Vec<f32> = scan
        .ranges_m
        .iter()
        .enumerate()
        .filter(|&(_, &r)| r.is_finite() && r >= scan.range_min_m && r < scan.range_max_m)
        .map(|(i, &r)| {
            let (s, c) = (pose.yaw + scan.angle_min_rad + i as f32 * scan.angle_increment_rad).sin_cos();
            field.distance_at(map, pose.x + r * c, pose.y + r * s)
        })
        .collect();
    let fitting = ends.iter().filter(|&&d| d <= FIT_TOLERANCE_M).count();
    (!ends.is_empty()).then(|| fitting as f32 / ends.len() as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sense::{LidarParams, RayGrid, cast_scan};
    use crate::testing::tiny_room;

    #[test]
    fn scan_fit_is_high_at_the_true_pose_and_low_elsewhere() {
        let map = tiny_room();
        let field = DistanceField::build(&map);
        let pose = Pose2::new(0.6, 0.6, 0.3);
        let mut scan = LidarScan::default();
        cast_scan(&RayGrid::from_map(&map), pose, &[], &LidarParams::default(), &mut scan);
        let here = scan_fit(&scan, &pose, &map, &field).expect("beams hit the walls");
        assert!(here > 0.95, "a scan fits where it was taken: {here}");
        let shifted = scan_fit(&scan, &Pose2::new(0.6, 0.6, 0.3 + 1.2), &map, &field).expect("usable beams");
        assert!(shifted < here, "a turned pose fits worse: {shifted} vs {here}");
        let empty = LidarScan { ranges_m: vec![f32::NAN; 10], range_max_m: 5.6, ..Default::default() };
        assert_eq!(scan_fit(&empty, &pose, &map, &field), None, "no usable beam, no verdict");
    }
}
