//! ① Sense: odometry, LiDAR, scan matching, the local occupancy grid and the depth strip, each a system that
//! reads the robot's true pose and the map and writes one observation component on the robot.
//! All range sensors cast on the map entity's [`RayGrid`] (unknown and off-map cells block).

mod depth;
mod lidar;
mod local_grid;
mod odometry;
mod raycast;
mod scan_matching;

pub use depth::{DepthParams, DepthStrip, depth, depth_strip};
pub use lidar::{LidarParams, LidarScan, cast_scan, lidar, noise_and_clamp};
pub use local_grid::{LocalGrid, LocalGridParams, WideGrid, local_grid, rasterize_scan};
pub use odometry::{Odometry, OdometryParams, noisy_delta, odometry};
pub use raycast::{RayGrid, cast_reference};
pub use scan_matching::{ScanMatchingParams, ScanMemory, match_heading, scan_hits, scan_matching};
