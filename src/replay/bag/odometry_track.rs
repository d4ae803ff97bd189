//! The odometry pose at any instant between two odometry messages. A JSON Lines log states the
//! odometry *at the time of each scan*; in a bag, odometry (20–50 Hz) and scans (5–40 Hz) are
//! stamped independently, so the pose at a scan's stamp is interpolated between the messages
//! just before and just after it — linearly in x and y, along the shorter arc in yaw — as
//! AMCL gets it from tf2, which interpolates the same way. Taking the message just before would
//! lag by up to one odometry period (2.5 cm at 0.5 m/s and 20 Hz). Outside the recorded span
//! there is nothing to interpolate: AMCL drops such scans, and so does `localize --bag`.

use crate::world::{Pose2, wrap_angle};

/// Odometry poses sorted by stamp.
#[derive(Clone, Debug, Default)]
pub struct OdometryTrack {
    stamps_s: Vec<f64>,
    poses: Vec<Pose2>,
}

impl OdometryTrack {
    /// From (stamp s, pose) samples in any order; equal stamps keep their recorded order.
    pub fn new(mut samples: Vec<(f64, Pose2)>) -> Self {
        samples.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (stamps_s, poses) = samples.into_iter().unzip();
        Self { stamps_s, poses }
    }

    pub fn len(&self) -> usize {
        self.poses.len()
    }

    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// First and last stamp, seconds.
    pub fn span_s(&self) -> Option<(f64, f64)> {
        Some((*self.stamps_s.first()?, *self.stamps_s.last()?))
    }

    /// The pose at `t` seconds: a sample's own pose at its stamp, interpolated between the
    /// samples around `t`, `None` before the first or after the last sample.
    pub fn at(&self, t: f64) -> Option<Pose2> {
        let after = self.stamps_s.partition_point(|&s| s < t);
        let (&t1, &p1) = (self.stamps_s.get(after)?, self.poses.get(after)?);
        if t1 == t {
            return Some(p1);
        }
        let before = after.checked_sub(1)?;
        let (t0, p0) = (self.stamps_s[before], self.poses[before]);
        let s = ((t - t0) / (t1 - t0)) as f32;
        Some(Pose2::new(
            p0.x + s * (p1.x - p0.x),
            p0.y + s * (p1.y - p0.y),
            wrap_angle(p0.yaw + s * wrap_angle(p1.yaw - p0.yaw)),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn odometry_track_interpolates_between_the_neighbouring_samples() {
        let track = OdometryTrack::new(vec![
            (2.0, Pose2::new(1.0, 2.0, 3.0)),
            (1.0, Pose2::new(0.0, 0.0, 2.8)),
            (3.0, Pose2::new(1.0, 3.0, -3.0)),
        ]);
        assert_eq!(track.span_s(), Some((1.0, 3.0)), "samples are sorted by stamp");
        assert_eq!(track.at(2.0), Some(Pose2::new(1.0, 2.0, 3.0)), "a sample's stamp gives its pose");
        let mid = track.at(1.5).expect("inside the span");
        assert!((mid.x - 0.5).abs() < 1e-6 && (mid.y - 1.0).abs() < 1e-6 && (mid.yaw - 2.9).abs() < 1e-6);
        // 3.0 → −3.0 crosses ±π: the shorter arc goes through π, not back through 0.
        let across = track.at(2.5).expect("inside the span").yaw;
        assert!(across.abs() > 3.1, "yaw interpolates across ±π along the short arc: {across}");
        assert_eq!(track.at(0.999), None, "before the first sample");
        assert_eq!(track.at(3.001), None, "after the last sample");
        assert!(track.at(3.0).is_some() && track.at(1.0).is_some(), "the ends are inside");
    }

    #[test]
    fn odometry_track_with_repeated_stamps_and_no_samples() {
        let track =
            OdometryTrack::new(vec![(1.0, Pose2::new(0.0, 0.0, 0.0)), (1.0, Pose2::new(5.0, 0.0, 0.0))]);
        assert_eq!(track.at(1.0).map(|p| p.x), Some(0.0), "the first of equal stamps, no division by zero");
        assert_eq!(OdometryTrack::default().at(0.0), None);
        assert!(OdometryTrack::default().is_empty());
    }
}
