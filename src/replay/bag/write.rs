//! Writes rosbag2-style MCAP files (profile `ros2`, `ros2msg` schemas with the messages' full
//! definitions, `cdr` messages): test data for the reader, seeds for fuzzing, and a way to hand a
//! simulated [`LogLine`] log to ROS tools.

use crate::replay::LogLine;
use crate::replay::bag::messages::{Header, LASER_SCAN, LaserScanMsg, ODOMETRY, OdometryMsg};
use crate::replay::bag::read::BagTopics;
use mcap::records::MessageHeader;
use mcap::{McapResult, WriteOptions, Writer};
use std::collections::BTreeMap;
use std::io::Cursor;

/// Frame ids written by [`log_to_bag`] (nav2's and TurtleBot's names).
pub const LASER_FRAME: &str = "base_scan";
pub const ODOM_FRAME: &str = "odom";
pub const BASE_FRAME: &str = "base_footprint";

/// An MCAP file being written in memory.
pub struct BagWriter {
    writer: Writer<Cursor<Vec<u8>>>,
    sequence: u32,
}

impl BagWriter {
    /// `zstd`: compress chunks with zstd as `ros2 bag record -s mcap` does by default; else store
    /// them uncompressed.
    pub fn new(zstd: bool) -> McapResult<Self> {
        let compression = zstd.then_some(mcap::Compression::Zstd);
        let options = WriteOptions::new().profile("ros2").compression(compression);
        Ok(Self { writer: options.create(Cursor::new(Vec::new()))?, sequence: 0 })
    }

    /// Adds a topic of type `schema_name` (e.g. `sensor_msgs/msg/LaserScan`) whose `.msg`
    /// definition is `definition`; returns its channel id.
    pub fn add_topic(&mut self, topic: &str, schema_name: &str, definition: &str) -> McapResult<u16> {
        let schema = self.writer.add_schema(schema_name, "ros2msg", definition.as_bytes())?;
        self.writer.add_channel(schema, topic, "cdr", &BTreeMap::new())
    }

    /// Adds a LaserScan topic.
    pub fn add_scan_topic(&mut self, topic: &str) -> McapResult<u16> {
        self.add_topic(topic, LASER_SCAN, &laser_scan_definition())
    }

    /// Adds an Odometry topic.
    pub fn add_odometry_topic(&mut self, topic: &str) -> McapResult<u16> {
        self.add_topic(topic, ODOMETRY, &odometry_definition())
    }

    /// Writes one CDR message received at `log_time_s` seconds.
    pub fn write(&mut self, channel: u16, log_time_s: f64, cdr: &[u8]) -> McapResult<()> {
        let time_ns = (log_time_s.max(0.0) * 1e9).round() as u64;
        self.sequence += 1;
        let header = MessageHeader {
            channel_id: channel,
            sequence: self.sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.writer.write_to_known_channel(&header, cdr)
    }

    /// Writes the summary and returns the file's bytes.
    pub fn finish(mut self) -> McapResult<Vec<u8>> {
        self.writer.finish()?;
        Ok(self.writer.into_inner().into_inner())
    }
}

/// A log as a bag: per line, an odometry message then a LaserScan (little-endian CDR, zstd
/// chunks), both stamped with the line's `t`. Read back with the same topics, it gives the same
/// lines (odometry as f64 and a quaternion, so yaw to within f32 rounding), less `truth`.
pub fn log_to_bag(lines: &[LogLine], topics: &BagTopics) -> McapResult<Vec<u8>> {
    let mut bag = BagWriter::new(true)?;
    let scan_channel = bag.add_scan_topic(&topics.scan)?;
    let odom_channel = bag.add_odometry_topic(&topics.odom)?;
    for line in lines {
        let odom = OdometryMsg::planar(Header::at(line.t, ODOM_FRAME), BASE_FRAME, line.odom_pose());
        bag.write(odom_channel, line.t, &odom.encode(true))?;
        bag.write(scan_channel, line.t, &scan_message(line).encode(true))?;
    }
    bag.finish()
}

/// A log line's scan as a LaserScan message.
pub fn scan_message(line: &LogLine) -> LaserScanMsg {
    let rays = line.ranges.len().saturating_sub(1) as f32;
    LaserScanMsg {
        header: Header::at(line.t, LASER_FRAME),
        angle_min: line.angle_min,
        angle_max: line.angle_min + rays * line.angle_increment,
        angle_increment: line.angle_increment,
        time_increment: 0.0,
        scan_time: 0.0,
        range_min: line.range_min,
        range_max: line.range_max,
        ranges: line.ranges.clone(),
    }
}

/// rosbag2 stores a type's definition followed by those of the types it uses, each after a
/// separator line and `MSG: <type>`.
fn definition(main: &str, dependencies: &[(&str, &str)]) -> String {
    let separator = "=".repeat(80);
    dependencies
        .iter()
        .fold(main.to_string(), |text, (name, fields)| format!("{text}\n{separator}\nMSG: {name}\n{fields}"))
}

const HEADER: (&str, &str) = ("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n");
const TIME: (&str, &str) = ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n");

fn laser_scan_definition() -> String {
    let main = "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\n\
                float32 time_increment\nfloat32 scan_time\nfloat32 range_min\nfloat32 range_max\n\
                float32[] ranges\nfloat32[] intensities\n";
    definition(main, &[HEADER, TIME])
}

fn odometry_definition() -> String {
    let main = "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n\
                geometry_msgs/TwistWithCovariance twist\n";
    let xyz = "float64 x\nfloat64 y\nfloat64 z\n";
    definition(
        main,
        &[
            HEADER,
            TIME,
            ("geometry_msgs/PoseWithCovariance", "Pose pose\nfloat64[36] covariance\n"),
            ("geometry_msgs/Pose", "Point position\nQuaternion orientation\n"),
            ("geometry_msgs/Point", xyz),
            ("geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"),
            ("geometry_msgs/TwistWithCovariance", "Twist twist\nfloat64[36] covariance\n"),
            ("geometry_msgs/Twist", "Vector3 linear\nVector3 angular\n"),
            ("geometry_msgs/Vector3", xyz),
        ],
    )
}
