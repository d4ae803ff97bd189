//! ROS 2 bags: `sensor_msgs/msg/LaserScan` and `nav_msgs/msg/Odometry` from a rosbag2 MCAP file
//! (CDR messages) as the [`LogLine`](crate::replay::LogLine)s the localizer replays, with the
//! odometry interpolated at each scan's stamp. [`parse_bag`] is the entry point on raw bytes.

mod cdr;
mod error;
mod messages;
mod odometry_track;
mod read;
mod write;

pub use cdr::{CdrReader, CdrWriter};
pub use error::{BagError, MessageError};
pub use messages::{Header, LASER_SCAN, LaserScanMsg, ODOMETRY, OdometryMsg};
pub use odometry_track::OdometryTrack;
pub use read::{BagLog, BagTopics, parse_bag, read_bag};
pub use write::{BASE_FRAME, BagWriter, LASER_FRAME, ODOM_FRAME, log_to_bag, scan_message};
