//! ① Sense: odometry, LiDAR, the local occupancy grid and the depth strip, each a system that
//! reads the robot's true pose and the map and writes one observation component on the robot.

mod lidar;
mod odometry;

pub use lidar::LidarScan;
pub use odometry::Odometry;
