//! The two ROS 2 messages `apfn localize --bag` reads, decoded from CDR field by field in their
//! `.msg` order (and encoded the same way, for tests and for writing bags):
//! `sensor_msgs/msg/LaserScan` and `nav_msgs/msg/Odometry`, each opening with a
//! `std_msgs/msg/Header` (stamp `sec: int32`, `nanosec: uint32`; `frame_id: string`).

use crate::replay::bag::cdr::{CdrReader, CdrWriter};
use crate::replay::bag::error::MessageError;
use crate::world::Pose2;

/// Schema name of a LaserScan in a rosbag2 MCAP file.
pub const LASER_SCAN: &str = "sensor_msgs/msg/LaserScan";
/// Schema name of an Odometry in a rosbag2 MCAP file.
pub const ODOMETRY: &str = "nav_msgs/msg/Odometry";

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    pub stamp_sec: i32,
    pub stamp_nanosec: u32,
    pub frame_id: String,
}

impl Header {
    /// The stamp in seconds.
    pub fn stamp_s(&self) -> f64 {
        f64::from(self.stamp_sec) + f64::from(self.stamp_nanosec) * 1e-9
    }

    /// A header stamped `t` seconds (rounded to the nanosecond). Whole seconds and the fraction
    /// are split first: `t × 10⁹` of an epoch stamp is past f64's exact integers.
    pub fn at(t: f64, frame_id: &str) -> Self {
        let whole = t.floor();
        let nanos = ((t - whole) * 1e9).round() as i64; // in 0..=10⁹
        let (sec, nanosec) = (whole as i64 + nanos / 1_000_000_000, nanos % 1_000_000_000);
        Self { stamp_sec: sec as i32, stamp_nanosec: nanosec as u32, frame_id: frame_id.into() }
    }

    fn decode(r: &mut CdrReader) -> Result<Self, MessageError> {
        Ok(Self {
            stamp_sec: r.i32("header.stamp.sec")?,
            stamp_nanosec: r.u32("header.stamp.nanosec")?,
            frame_id: r.string("header.frame_id")?,
        })
    }

    fn encode(&self, w: &mut CdrWriter) {
        w.i32(self.stamp_sec);
        w.u32(self.stamp_nanosec);
        w.string(&self.frame_id);
    }
}

/// `sensor_msgs/msg/LaserScan` (intensities are checked to be there, then dropped).
#[derive(Clone, Debug, PartialEq)]
pub struct LaserScanMsg {
    pub header: Header,
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    pub time_increment: f32,
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
    pub ranges: Vec<f32>,
}

impl LaserScanMsg {
    pub fn decode(message: &[u8]) -> Result<Self, MessageError> {
        let r = &mut CdrReader::new(message)?;
        let scan = Self {
            header: Header::decode(r)?,
            angle_min: r.f32("angle_min")?,
            angle_max: r.f32("angle_max")?,
            angle_increment: r.f32("angle_increment")?,
            time_increment: r.f32("time_increment")?,
            scan_time: r.f32("scan_time")?,
            range_min: r.f32("range_min")?,
            range_max: r.f32("range_max")?,
            ranges: r.f32_sequence("ranges")?,
        };
        r.f32_sequence("intensities")?;
        Ok(scan)
    }

    /// CDR bytes (without intensities, as a LiDAR without them publishes).
    pub fn encode(&self, little_endian: bool) -> Vec<u8> {
        let mut w = CdrWriter::new(little_endian);
        self.header.encode(&mut w);
        for v in [
            self.angle_min,
            self.angle_max,
            self.angle_increment,
            self.time_increment,
            self.scan_time,
            self.range_min,
            self.range_max,
        ] {
            w.f32(v);
        }
        w.f32_sequence(&self.ranges);
        w.f32_sequence(&[]);
        w.finish()
    }
}

/// `nav_msgs/msg/Odometry`, reduced to what a 2D filter uses: the pose's position and
/// orientation (covariances and twist are checked to be there, then dropped).
#[derive(Clone, Debug, PartialEq)]
pub struct OdometryMsg {
    pub header: Header,
    pub child_frame_id: String,
    /// `pose.pose.position` x, y, z, metres.
    pub position: [f64; 3],
    /// `pose.pose.orientation` x, y, z, w.
    pub orientation: [f64; 4],
}

/// 6×6 covariance of PoseWithCovariance and TwistWithCovariance.
const COVARIANCE_LEN: usize = 36;

impl OdometryMsg {
    pub fn decode(message: &[u8]) -> Result<Self, MessageError> {
        let r = &mut CdrReader::new(message)?;
        let header = Header::decode(r)?;
        let child_frame_id = r.string("child_frame_id")?;
        let position =
            [r.f64("pose.pose.position.x")?, r.f64("pose.pose.position.y")?, r.f64("pose.pose.position.z")?];
        let orientation = [
            r.f64("pose.pose.orientation.x")?,
            r.f64("pose.pose.orientation.y")?,
            r.f64("pose.pose.orientation.z")?,
            r.f64("pose.pose.orientation.w")?,
        ];
        r.skip_f64s(COVARIANCE_LEN, "pose.covariance")?;
        r.skip_f64s(6, "twist.twist")?;
        r.skip_f64s(COVARIANCE_LEN, "twist.covariance")?;
        Ok(Self { header, child_frame_id, position, orientation })
    }

    /// A planar odometry message at `pose` (zero covariances and twist).
    pub fn planar(header: Header, child_frame_id: &str, pose: Pose2) -> Self {
        let half = f64::from(pose.yaw) / 2.0;
        Self {
            header,
            child_frame_id: child_frame_id.into(),
            position: [f64::from(pose.x), f64::from(pose.y), 0.0],
            orientation: [0.0, 0.0, half.sin(), half.cos()],
        }
    }

    pub fn encode(&self, little_endian: bool) -> Vec<u8> {
        let mut w = CdrWriter::new(little_endian);
        self.header.encode(&mut w);
        w.string(&self.child_frame_id);
        self.position.iter().chain(&self.orientation).for_each(|&v| w.f64(v));
        (0..2 * COVARIANCE_LEN + 6).for_each(|_| w.f64(0.0));
        w.finish()
    }

    /// The pose in the plane: x, y and the yaw of the orientation (roll and pitch ignored);
    /// `None` when a value is not finite or the quaternion is zero. The quaternion need not be
    /// normalised: the yaw formula is scale-free.
    pub fn pose2(&self) -> Option<Pose2> {
        let [x, y, z, w] = self.orientation;
        let norm2 = x * x + y * y + z * z + w * w;
        let finite = self.position.iter().chain(&self.orientation).all(|v| v.is_finite());
        if !finite || norm2 < 1e-12 {
            return None;
        }
        let yaw = (2.0 * (w * z + x * y)).atan2(w * w + x * x - y * y - z * z);
        Some(Pose2::new(self.position[0] as f32, self.position[1] as f32, yaw as f32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan() -> LaserScanMsg {
        LaserScanMsg {
            header: Header::at(12.25, "base_scan"),
            angle_min: -1.0,
            angle_max: 1.0,
            angle_increment: 0.5,
            time_increment: 0.0,
            scan_time: 0.2,
            range_min: 0.1,
            range_max: 8.0,
            ranges: vec![1.0, f32::INFINITY, 2.0, 0.0, f32::NAN],
        }
    }

    #[test]
    fn laser_scan_round_trips_in_both_byte_orders() {
        for little_endian in [true, false] {
            let back = LaserScanMsg::decode(&scan().encode(little_endian)).expect("decodes");
            assert_eq!(back.header, scan().header);
            assert_eq!((back.range_min, back.range_max, back.angle_increment), (0.1, 8.0, 0.5));
            assert_eq!(back.ranges[..4], scan().ranges[..4]);
            assert!(back.ranges[4].is_nan());
            assert!((back.header.stamp_s() - 12.25).abs() < 1e-9);
        }
    }

    #[test]
    fn laser_scan_decodes_bytes_laid_out_by_hand() {
        // Header {sec 3, nanosec 5, frame_id "l"}, seven floats, ranges [2.5], no intensities:
        // "l" + NUL makes the payload 8 + 4 + 2 = 14 bytes, padded to 16 before angle_min.
        let mut bytes = vec![0, 1, 0, 0, 3, 0, 0, 0, 5, 0, 0, 0, 2, 0, 0, 0, b'l', 0, 0, 0];
        for v in [-1.5f32, 1.5, 0.75, 0.0, 0.1, 0.05, 5.6] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        bytes.extend_from_slice(&[1, 0, 0, 0]);
        bytes.extend_from_slice(&2.5f32.to_le_bytes());
        bytes.extend_from_slice(&[0, 0, 0, 0]);
        let msg = LaserScanMsg::decode(&bytes).expect("hand-laid message");
        assert_eq!((msg.header.stamp_sec, msg.header.stamp_nanosec), (3, 5));
        assert_eq!(msg.header.frame_id, "l");
        assert_eq!((msg.angle_min, msg.angle_increment, msg.range_max), (-1.5, 0.75, 5.6));
        assert_eq!(msg.ranges, vec![2.5]);
    }

    #[test]
    fn laser_scan_cut_short_names_the_field() {
        let bytes = scan().encode(true);
        let err = LaserScanMsg::decode(&bytes[..bytes.len() - 8]).expect_err("ranges cut short");
        assert_eq!(err.field, "ranges");
        let err = LaserScanMsg::decode(&bytes[..bytes.len() - 2]).expect_err("no intensities");
        assert_eq!(err.field, "intensities");
    }

    #[test]
    fn odometry_round_trips_and_gives_the_planar_pose() {
        let pose = Pose2::new(1.5, -2.0, 2.9);
        let msg = OdometryMsg::planar(Header::at(3.0, "odom"), "base_footprint", pose);
        for little_endian in [true, false] {
            let back = OdometryMsg::decode(&msg.encode(little_endian)).expect("decodes");
            assert_eq!(back, msg);
            let p = back.pose2().expect("a valid pose");
            assert!(p.distance(&pose) < 1e-6 && (p.yaw - pose.yaw).abs() < 1e-6, "{p:?}");
        }
        let err = OdometryMsg::decode(&msg.encode(true)[..200]).expect_err("cut in the covariance");
        assert_eq!(err.field, "pose.covariance");
    }

    #[test]
    fn odometry_yaw_ignores_scale_and_rejects_a_zero_quaternion() {
        let mut msg = OdometryMsg::planar(Header::at(0.0, "odom"), "base_link", Pose2::new(0.0, 0.0, -1.0));
        msg.orientation.iter_mut().for_each(|q| *q *= 3.0);
        assert!((msg.pose2().expect("scaled quaternion").yaw + 1.0).abs() < 1e-6);
        msg.orientation = [0.0; 4];
        assert_eq!(msg.pose2(), None, "a zero quaternion has no yaw");
        msg.orientation = [0.0, 0.0, 0.0, 1.0];
        msg.position[1] = f64::NAN;
        assert_eq!(msg.pose2(), None, "a NaN position is no pose");
    }

    #[test]
    fn header_at_splits_seconds_and_nanoseconds() {
        let h = Header::at(1_700_000_000.25, "f");
        assert_eq!((h.stamp_sec, h.stamp_nanosec), (1_700_000_000, 250_000_000), "{h:?}");
        assert_eq!(Header::at(-0.25, "f").stamp_s(), -0.25);
        let just_below = Header::at(2.0 - 1e-12, "f");
        assert_eq!((just_below.stamp_sec, just_below.stamp_nanosec), (2, 0), "rounding carries into seconds");
    }
}
