//! Planar LiDAR: 228 rays over 240°, 0.05–5.6 m (the paper's sensor), cast on the fine grid.

use bevy::prelude::Component;

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
