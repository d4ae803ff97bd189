//! The log as a sensor: `log_feed` hands a robot its next recorded reading (the odometry motion
//! and the scan) where the simulator's `odometry` and `lidar` would compute them, so recorded data
//! runs through the very systems that filter simulated data — every localizer, PF-net included.

use crate::replay::log::LogLine;
use crate::sense::{LidarScan, Odometry};
use crate::world::{Pose2, TruePose};
use bevy::prelude::*;
use std::collections::VecDeque;

/// One recorded reading.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Reading {
    /// Odometry motion since the previous reading, in the previous robot frame (zero for the first).
    pub odom_delta: Pose2,
    pub scan: LidarScan,
    /// The true pose, when the log has one (for `step_metrics`; no filter system reads it after
    /// the initial draw).
    pub truth: Option<Pose2>,
}

impl Reading {
    /// Line `line` of a log whose previous line is `previous` (`None` for the first line).
    pub fn from_line(previous: Option<&LogLine>, line: &LogLine) -> Self {
        let odom_delta = previous.map(|p| p.odom_pose().between(&line.odom_pose())).unwrap_or_default();
        Self { odom_delta, scan: line.scan(), truth: line.truth_pose() }
    }
}

/// Readings waiting for a robot, oldest first; `log_feed` takes one per step.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct LogFeed(pub VecDeque<Reading>);

/// Reads LogFeed. Writes Odometry, LidarScan and, where the reading has one, TruePose.
/// A robot whose feed has run dry is told so and left unchanged: re-weighing an old scan as if it
/// were new would be worse than skipping.
pub fn log_feed(mut robots: Query<(Entity, &mut LogFeed, &mut Odometry, &mut LidarScan, &mut TruePose)>) {
    for (robot, mut feed, mut odometry, mut scan, mut truth) in &mut robots {
        let Some(reading) = feed.0.pop_front() else {
            tracing::warn!("log_feed: robot {robot:?} has no reading left; odometry and scan not updated");
            continue;
        };
        odometry.delta = reading.odom_delta;
        *scan = reading.scan;
        if let Some(pose) = reading.truth {
            truth.0 = pose;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::ecs::system::RunSystemOnce;

    fn line(t: f64, odom: [f32; 3], truth: Option<[f32; 3]>) -> LogLine {
        let scan = LidarScan { ranges_m: vec![1.0, t as f32], range_max_m: 5.6, ..Default::default() };
        let mut line = LogLine::new(t, Pose2::new(odom[0], odom[1], odom[2]), &scan, None);
        line.truth = truth;
        line
    }

    #[test]
    fn log_feed_hands_out_readings_in_order_and_leaves_a_dry_robot_alone() {
        let (first, second) =
            (line(0.0, [1.0, 0.0, 0.0], Some([3.0, 2.0, 0.5])), line(0.6, [1.0, 1.0, 0.0], None));
        let readings = [Reading::from_line(None, &first), Reading::from_line(Some(&first), &second)];
        assert_eq!(readings[0].odom_delta, Pose2::default(), "nothing moved before the first scan");
        assert!(readings[1].odom_delta.distance(&Pose2::new(0.0, 1.0, 0.0)) < 1e-6, "{:?}", readings[1]);

        let mut world = World::new();
        let feed = LogFeed(readings.into_iter().collect());
        let parts = (feed, Odometry::default(), LidarScan::default(), TruePose::default());
        let robot = world.spawn(parts).id();
        let scan_t = |world: &World| world.get::<LidarScan>(robot).expect("scan").ranges_m[1];
        world.run_system_once(log_feed).expect("log_feed runs");
        assert_eq!(
            (scan_t(&world), world.get::<TruePose>(robot).expect("pose").0),
            (0.0, Pose2::new(3.0, 2.0, 0.5))
        );
        world.run_system_once(log_feed).expect("log_feed runs");
        assert_eq!(scan_t(&world), 0.6, "the second reading's scan");
        assert_eq!(
            world.get::<TruePose>(robot).expect("pose").0,
            Pose2::new(3.0, 2.0, 0.5),
            "no truth: kept"
        );
        assert_eq!(world.get::<Odometry>(robot).expect("odometry").delta, Pose2::new(0.0, 1.0, 0.0));
        world.run_system_once(log_feed).expect("log_feed runs on an empty feed");
        assert_eq!(scan_t(&world), 0.6, "a dry feed leaves the last scan");
    }
}
